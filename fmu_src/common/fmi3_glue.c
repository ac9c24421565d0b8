/* FMI 3.0 on top of the FMI 2.0 glue (fmi2_glue.c, compiled into the same binary): every
 * fmi3 function translates its arguments and calls the fmi2 function that does the work, so
 * the two versions of an FMU share one implementation of modes, checks, integration and
 * FMU state, and give the same numbers.
 *
 * What FMI 3.0 adds and this glue does not offer (clocks, scheduled execution, event mode in
 * co-simulation, early return, intermediate update, directional and adjoint derivatives,
 * configuration mode, variable types other than Float64 and Int32) is refused with a logged
 * error. The independent variable `time` has the value reference TIME_VR. */
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"
#include "model_api.h"

#define TIME_VR (INTEGER_VR_OFFSET + N_INTEGERS)

/* Many FMI 3.0 arguments mean nothing to this model (clocks, early return, the values of
 * types it never declares): they are not used. */
#pragma GCC diagnostic ignored "-Wunused-parameter"

typedef struct {
    fmi2Component c;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi2CallbackFunctions callbacks;
    int model_exchange;
    double time;
} Wrapper;

/* fmi2's logger, forwarded to the importer's fmi3 logger (the glue pre-formats messages) */
static void relay(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                  fmi2String category, fmi2String message, ...) {
    const Wrapper *w = (const Wrapper *)env;
    if (w && w->log) w->log(w->env, (fmi3Status)status, category, message);
}

static fmi3Status refuse(fmi3Instance instance, const char *what) {
    const Wrapper *w = (const Wrapper *)instance;
    if (!w) return fmi3Error;
    if (w->log) w->log(w->env, fmi3Error, "logStatusError", what);
    return fmi3Error;
}

#define C(instance) (((Wrapper *)(instance))->c)
#define FORWARD(instance, call) ((instance) ? (fmi3Status)(call) : fmi3Error)

static fmi3Instance instantiate(fmi3String name, fmi3String token, int model_exchange,
                                fmi3InstanceEnvironment env, fmi3LogMessageCallback log) {
    Wrapper *w = (Wrapper *)calloc(1, sizeof *w);
    if (!w) return NULL;
    w->env = env;
    w->log = log;
    w->model_exchange = model_exchange;
    w->callbacks.logger = relay;
    w->callbacks.allocateMemory = calloc;
    w->callbacks.freeMemory = free;
    w->callbacks.componentEnvironment = w;
    w->c = fmi2Instantiate(name, model_exchange ? fmi2ModelExchange : fmi2CoSimulation, token, "",
                           &w->callbacks, fmi2False, fmi2False);
    if (!w->c) {
        free(w);
        return NULL;
    }
    return w;
}

/* ---------------------------------------------------------------- common functions */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    return instance ? fmi3OK : fmi3Error;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    return instantiate(instanceName, instantiationToken, 1, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible,
                                         fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "event mode and intermediate variables are not supported (hasEventMode is false)");
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, 0, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "this FMU has no scheduled execution interface");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    Wrapper *w = (Wrapper *)instance;
    if (!w) return;
    fmi2FreeInstance(w->c);
    free(w);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    fmi3Status status;
    if (!instance) return fmi3Error;
    status = (fmi3Status)fmi2SetupExperiment(C(instance), toleranceDefined, tolerance, startTime,
                                             stopTimeDefined, stopTime);
    if (status > fmi3Warning) return status;
    ((Wrapper *)instance)->time = startTime;
    return (fmi3Status)fmi2EnterInitializationMode(C(instance));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    return FORWARD(instance, fmi2ExitInitializationMode(C(instance)));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    if (instance && !((Wrapper *)instance)->model_exchange)
        return refuse(instance, "fmi3EnterEventMode: co-simulation runs without event mode");
    return FORWARD(instance, fmi2EnterEventMode(C(instance)));
}

fmi3Status fmi3Terminate(fmi3Instance instance) { return FORWARD(instance, fmi2Terminate(C(instance))); }

fmi3Status fmi3Reset(fmi3Instance instance) {
    if (instance) ((Wrapper *)instance)->time = 0.0;
    return FORWARD(instance, fmi2Reset(C(instance)));
}

/* ---------------------------------------------------------------- get and set */

static int holds_time(const fmi3ValueReference vr[], size_t n) {
    size_t k;
    for (k = 0; k < n; k++)
        if (vr && vr[k] == TIME_VR) return 1;
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    size_t k;
    if (!instance) return fmi3Error;
    if (nValues != nValueReferences) return refuse(instance, "fmi3GetFloat64: nValues must equal nValueReferences");
    if (!holds_time(valueReferences, nValueReferences))
        return (fmi3Status)fmi2GetReal(C(instance), valueReferences, nValueReferences, values);
    for (k = 0; k < nValueReferences; k++) {
        fmi3Status status;
        if (valueReferences[k] == TIME_VR) {
            values[k] = ((Wrapper *)instance)->time;
            continue;
        }
        status = (fmi3Status)fmi2GetReal(C(instance), &valueReferences[k], 1, &values[k]);
        if (status > fmi3Warning) return status;
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    if (!instance) return fmi3Error;
    if (nValues != nValueReferences) return refuse(instance, "fmi3SetFloat64: nValues must equal nValueReferences");
    if (holds_time(valueReferences, nValueReferences))
        return refuse(instance, "time is the independent variable: it cannot be set");
    return (fmi3Status)fmi2SetReal(C(instance), valueReferences, nValueReferences, values);
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Int32 values[], size_t nValues) {
    if (!instance) return fmi3Error;
    if (nValues != nValueReferences) return refuse(instance, "fmi3GetInt32: nValues must equal nValueReferences");
    return (fmi3Status)fmi2GetInteger(C(instance), valueReferences, nValueReferences, (fmi2Integer *)values);
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Int32 values[], size_t nValues) {
    if (!instance) return fmi3Error;
    if (nValues != nValueReferences) return refuse(instance, "fmi3SetInt32: nValues must equal nValueReferences");
    return (fmi3Status)fmi2SetInteger(C(instance), valueReferences, nValueReferences, (const fmi2Integer *)values);
}

/* The types this model never declares: only empty requests succeed. */
#define NO_VARIABLES(function, type, ...)                                                         \
    fmi3Status function(fmi3Instance instance, const fmi3ValueReference valueReferences[],         \
                        size_t nValueReferences, __VA_ARGS__) {                                     \
        (void)valueReferences;                                                                      \
        if (!instance) return fmi3Error;                                                            \
        return nValueReferences == 0 ? fmi3OK : refuse(instance, #function ": this model has no " type " variables"); \
    }

NO_VARIABLES(fmi3GetFloat32, "Float32", fmi3Float32 values[], size_t nValues)
NO_VARIABLES(fmi3GetInt8, "Int8", fmi3Int8 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt8, "UInt8", fmi3UInt8 values[], size_t nValues)
NO_VARIABLES(fmi3GetInt16, "Int16", fmi3Int16 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt16, "UInt16", fmi3UInt16 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt32, "UInt32", fmi3UInt32 values[], size_t nValues)
NO_VARIABLES(fmi3GetInt64, "Int64", fmi3Int64 values[], size_t nValues)
NO_VARIABLES(fmi3GetUInt64, "UInt64", fmi3UInt64 values[], size_t nValues)
NO_VARIABLES(fmi3GetBoolean, "Boolean", fmi3Boolean values[], size_t nValues)
NO_VARIABLES(fmi3GetString, "String", fmi3String values[], size_t nValues)
NO_VARIABLES(fmi3GetBinary, "Binary", size_t valueSizes[], fmi3Binary values[], size_t nValues)
NO_VARIABLES(fmi3GetClock, "Clock", fmi3Clock values[])
NO_VARIABLES(fmi3SetFloat32, "Float32", const fmi3Float32 values[], size_t nValues)
NO_VARIABLES(fmi3SetInt8, "Int8", const fmi3Int8 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt8, "UInt8", const fmi3UInt8 values[], size_t nValues)
NO_VARIABLES(fmi3SetInt16, "Int16", const fmi3Int16 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt16, "UInt16", const fmi3UInt16 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt32, "UInt32", const fmi3UInt32 values[], size_t nValues)
NO_VARIABLES(fmi3SetInt64, "Int64", const fmi3Int64 values[], size_t nValues)
NO_VARIABLES(fmi3SetUInt64, "UInt64", const fmi3UInt64 values[], size_t nValues)
NO_VARIABLES(fmi3SetBoolean, "Boolean", const fmi3Boolean values[], size_t nValues)
NO_VARIABLES(fmi3SetString, "String", const fmi3String values[], size_t nValues)
NO_VARIABLES(fmi3SetBinary, "Binary", const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
NO_VARIABLES(fmi3SetClock, "Clock", const fmi3Clock values[])
NO_VARIABLES(fmi3GetIntervalDecimal, "Clock", fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
NO_VARIABLES(fmi3GetIntervalFraction, "Clock", fmi3UInt64 counters[], fmi3UInt64 resolutions[],
             fmi3IntervalQualifier qualifiers[])
NO_VARIABLES(fmi3GetShiftDecimal, "Clock", fmi3Float64 shifts[])
NO_VARIABLES(fmi3GetShiftFraction, "Clock", fmi3UInt64 counters[], fmi3UInt64 resolutions[])
NO_VARIABLES(fmi3SetIntervalDecimal, "Clock", const fmi3Float64 intervals[])
NO_VARIABLES(fmi3SetIntervalFraction, "Clock", const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
NO_VARIABLES(fmi3SetShiftDecimal, "Clock", const fmi3Float64 shifts[])
NO_VARIABLES(fmi3SetShiftFraction, "Clock", const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    return refuse(instance, "variable dependencies are not provided");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    return refuse(instance, "variable dependencies are not provided");
}

/* ---------------------------------------------------------------- FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return FORWARD(instance, fmi2GetFMUstate(C(instance), FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return FORWARD(instance, fmi2SetFMUstate(C(instance), FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return FORWARD(instance, fmi2FreeFMUstate(C(instance), FMUState));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    return FORWARD(instance, fmi2SerializedFMUstateSize(C(instance), FMUState, size));
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    return FORWARD(instance, fmi2SerializeFMUstate(C(instance), FMUState, (fmi2Byte *)serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    return FORWARD(instance, fmi2DeSerializeFMUstate(C(instance), (const fmi2Byte *)serializedState, size,
                                                     FMUState));
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    return refuse(instance, "directional derivatives are not provided");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                    const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                    size_t nSensitivity) {
    return refuse(instance, "adjoint derivatives are not provided");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return refuse(instance, "this model has no structural parameters (no configuration mode)");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return refuse(instance, "this model has no structural parameters (no configuration mode)");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) { return instance ? fmi3OK : fmi3Error; }

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    fmi2EventInfo info;
    fmi3Status status;
    if (!instance) return fmi3Error;
    memset(&info, 0, sizeof info);
    status = (fmi3Status)fmi2NewDiscreteStates(C(instance), &info);
    if (status > fmi3Warning) return status;
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = info.newDiscreteStatesNeeded ? fmi3True : fmi3False;
    if (terminateSimulation) *terminateSimulation = info.terminateSimulation ? fmi3True : fmi3False;
    if (nominalsOfContinuousStatesChanged)
        *nominalsOfContinuousStatesChanged = info.nominalsOfContinuousStatesChanged ? fmi3True : fmi3False;
    if (valuesOfContinuousStatesChanged)
        *valuesOfContinuousStatesChanged = info.valuesOfContinuousStatesChanged ? fmi3True : fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = info.nextEventTimeDefined ? fmi3True : fmi3False;
    if (nextEventTime) *nextEventTime = info.nextEventTime;
    return status;
}

/* ---------------------------------------------------------------- model exchange */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return FORWARD(instance, fmi2EnterContinuousTimeMode(C(instance)));
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    fmi2Boolean enter = fmi2False, stop = fmi2False;
    fmi3Status status;
    if (!instance || !enterEventMode || !terminateSimulation) return fmi3Error;
    status = (fmi3Status)fmi2CompletedIntegratorStep(C(instance), noSetFMUStatePriorToCurrentPoint, &enter, &stop);
    *enterEventMode = enter ? fmi3True : fmi3False;
    *terminateSimulation = stop ? fmi3True : fmi3False;
    return status;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    fmi3Status status;
    if (!instance) return fmi3Error;
    status = (fmi3Status)fmi2SetTime(C(instance), time);
    if (status <= fmi3Warning) ((Wrapper *)instance)->time = time;
    return status;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return FORWARD(instance, fmi2SetContinuousStates(C(instance), continuousStates, nContinuousStates));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    return FORWARD(instance, fmi2GetDerivatives(C(instance), derivatives, nContinuousStates));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    return FORWARD(instance, fmi2GetEventIndicators(C(instance), eventIndicators, nEventIndicators));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return FORWARD(instance, fmi2GetContinuousStates(C(instance), continuousStates, nContinuousStates));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    return FORWARD(instance, fmi2GetNominalsOfContinuousStates(C(instance), nominals, nContinuousStates));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    if (!instance || !nEventIndicators) return fmi3Error;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    if (!instance || !nContinuousStates) return fmi3Error;
    *nContinuousStates = MODEL_DISCRETE ? 0 : N_STATES;
    return fmi3OK;
}

/* ---------------------------------------------------------------- co-simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    return refuse(instance, "fmi3EnterStepMode: co-simulation runs without event mode");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    return refuse(instance, "output derivatives are not supported");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    Wrapper *w = (Wrapper *)instance;
    fmi3Status status;
    if (!w) return fmi3Error;
    status = (fmi3Status)fmi2DoStep(w->c, currentCommunicationPoint, communicationStepSize,
                                    noSetFMUStatePriorToCurrentPoint);
    if (status <= fmi3Warning) w->time = currentCommunicationPoint + communicationStepSize;
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = w->time;
    return status;
}

/* ---------------------------------------------------------------- scheduled execution */

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    return refuse(instance, "this FMU has no scheduled execution interface");
}
