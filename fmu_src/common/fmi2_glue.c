/* Generic FMI 2.0 glue: instances, modes, get/set, fixed-step RK4 (or sample-period updates)
 * in doStep, model exchange for linearization, FMU state, reset and logging.
 *
 * Nothing here knows a plant: the plant's equations come through model_api.h and its
 * variables through the generated model_vars.h. All state is per instance. */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model_api.h"

/* the longest RK4 substep on the model's fastest time constant tau, in units of tau (the
 * stability limit on a decaying mode is 2.785), and the most substeps a step is cut into so */
#define RK4_REACH 2.5
#define MAX_AUTO_SUBSTEPS 1000000L

#ifndef DIVERGENCE_BOUND
/* A state beyond this magnitude means the fixed-step integration has blown up. */
#define DIVERGENCE_BOUND 1e10
#endif

typedef enum {
    MODE_INSTANTIATED,
    MODE_INITIALIZATION,
    MODE_STEP_COMPLETE,     /* co-simulation, between steps */
    MODE_EVENT,             /* model exchange */
    MODE_CONTINUOUS_TIME,   /* model exchange */
    MODE_TERMINATED,
    MODE_ERROR,
    N_MODES
} Mode;

/* Which modes each function is allowed in, as bit masks (the FMI 2.0 state machines). */
#define IN(mode) (1u << (mode))
#define SETUP (IN(MODE_INSTANTIATED) | IN(MODE_INITIALIZATION))
#define RUNNING (IN(MODE_STEP_COMPLETE) | IN(MODE_EVENT) | IN(MODE_CONTINUOUS_TIME))
#define AFTER (IN(MODE_TERMINATED) | IN(MODE_ERROR))
#define ANY_MODE ((1u << N_MODES) - 1u)

/* Marks a snapshot of this model, so that a serialized state from elsewhere is refused. */
#define SNAPSHOT_MAGIC 0x46435331u /* "FCS1" */
#define SNAPSHOT_VERSION 1u

typedef struct {
    unsigned magic;
    unsigned version;
    unsigned model; /* a hash of the instantiation token */
    int type;
    ModelValues values;
    double time;
    double start_time;
    int mode;
} Snapshot;

typedef struct {
    Snapshot s;
    fmi2Type type;
    char *name;
    fmi2CallbackFunctions callbacks;
} Instance;

/* Reports an error through the logger callback and returns fmi2Error. The message is passed
 * pre-formatted, so it must not contain a percent sign. */
static fmi2Status fail(const Instance *inst, const char *format, ...) {
    char buffer[512];
    va_list args;
    if (!inst->callbacks.logger) return fmi2Error;
    va_start(args, format);
    vsnprintf(buffer, sizeof buffer, format, args);
    va_end(args);
    inst->callbacks.logger(inst->callbacks.componentEnvironment, inst->name, fmi2Error,
                           "logStatusError", buffer);
    return fmi2Error;
}

static fmi2Status not_allowed(Instance *inst, const char *function) {
    static const char *const names[] = {"instantiated", "initialization", "step complete",
                                        "event", "continuous time", "terminated", "error"};
    const char *name = inst->s.mode >= 0 && inst->s.mode < N_MODES ? names[inst->s.mode] : "?";
    return fail(inst, "%s is not allowed in mode '%s'", function, name);
}

/* fmi2OK when the instance exists and may call `function` in its current mode. */
static fmi2Status allowed(Instance *inst, const char *function, unsigned modes) {
    if (!inst) return fmi2Error;
    if (inst->s.mode < 0 || inst->s.mode >= N_MODES || !(IN(inst->s.mode) & modes))
        return not_allowed(inst, function);
    return fmi2OK;
}

static unsigned token_hash(void) {
    const char *p;
    unsigned h = 2166136261u; /* FNV-1a */
    for (p = INSTANTIATION_TOKEN; *p; p++) h = (h ^ (unsigned char)*p) * 16777619u;
    return h;
}

static void apply_start_values(ModelValues *values) {
    int k;
    for (k = 0; k < N_REALS; k++) values->r[k] = REAL_START[k];
    for (k = 0; k < N_INTEGERS; k++) values->i[k] = INTEGER_START[k];
}

/* States take their start parameters while the instance is being set up. */
static void apply_state_starts(ModelValues *values) {
    int k;
    for (k = 0; k < N_STATES; k++) values->r[STATE_VR[k]] = values->r[STATE_START_VR[k]];
    model_outputs(values);
}

static fmi2Status check_real(Instance *inst, int vr, double value) {
    if (!isfinite(value))
        return fail(inst, "%s = %g is not finite", REAL_NAMES[vr], value);
    if (REAL_POSITIVE[vr] && !(value > 0.0))
        return fail(inst, "%s = %g must be > 0", REAL_NAMES[vr], value);
    return fmi2OK;
}

static fmi2Status check_integer(Instance *inst, int k, int value) {
    if (value < INTEGER_MIN[k] || value > INTEGER_MAX[k])
        return fail(inst, "%s = %d must be in [%d, %d]", INTEGER_NAMES[k], value, INTEGER_MIN[k],
                     INTEGER_MAX[k]);
    return fmi2OK;
}

static fmi2Status check_all(Instance *inst) {
    char reason[256];
    int k;
    for (k = 0; k < N_REALS; k++)
        if (REAL_KIND[k] == KIND_PARAMETER || REAL_KIND[k] == KIND_INPUT)
            if (check_real(inst, k, inst->s.values.r[k]) != fmi2OK) return fmi2Error;
    for (k = 0; k < N_INTEGERS; k++)
        if (check_integer(inst, k, inst->s.values.i[k]) != fmi2OK) return fmi2Error;
    if (model_check(&inst->s.values, reason, sizeof reason) != 0)
        return fail(inst, "%s", reason);
    return fmi2OK;
}

/* Every value of a snapshot, as fmi2SetFMUstate would take it: the mark of this model, a mode
 * that exists and fits the instance's interface, finite times, and parameters and inputs
 * the model accepts. Outputs and states must be finite. */
static fmi2Status check_snapshot(Instance *inst, const Snapshot *snapshot) {
    int k;
    Instance probe;
    if (snapshot->magic != SNAPSHOT_MAGIC || snapshot->version != SNAPSHOT_VERSION ||
        snapshot->model != token_hash())
        return fail(inst, "the FMU state was not made by this model (%s)", MODEL_IDENTIFIER_STRING);
    if (snapshot->type != (int)inst->type)
        return fail(inst, "the FMU state is of the other interface (co-simulation/model exchange)");
    if (snapshot->mode < 0 || snapshot->mode >= N_MODES)
        return fail(inst, "the FMU state has an invalid mode %d", snapshot->mode);
    if ((inst->type == fmi2CoSimulation &&
         (snapshot->mode == MODE_EVENT || snapshot->mode == MODE_CONTINUOUS_TIME)) ||
        (inst->type == fmi2ModelExchange && snapshot->mode == MODE_STEP_COMPLETE))
        return fail(inst, "the FMU state's mode %d does not exist in this interface", snapshot->mode);
    if (!isfinite(snapshot->time) || !isfinite(snapshot->start_time))
        return fail(inst, "the FMU state's time is not finite");
    for (k = 0; k < N_REALS; k++)
        if (!isfinite(snapshot->values.r[k]))
            return fail(inst, "the FMU state's %s is not finite", REAL_NAMES[k]);
    /* parameters and inputs against the model's own checks, without touching the instance */
    probe = *inst;
    probe.s = *snapshot;
    if (check_all(&probe) != fmi2OK) return fail(inst, "the FMU state holds invalid values");
    return fmi2OK;
}

static int states_diverged(const double *x) {
    int k;
    for (k = 0; k < N_STATES; k++)
        if (!isfinite(x[k]) || fabs(x[k]) > DIVERGENCE_BOUND) return 1;
    return 0;
}

/* ---------------------------------------------------------------- common functions */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    /* only errors are ever reported, and always */
    (void)loggingOn;
    (void)nCategories;
    (void)categories;
    return c ? fmi2OK : fmi2Error;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Instance *inst;
    Instance probe;
    (void)fmuResourceLocation;
    (void)visible;
    (void)loggingOn;
    memset(&probe, 0, sizeof probe);
    probe.name = (char *)(instanceName ? instanceName : "?");
    if (functions) probe.callbacks = *functions;
    if (!fmuGUID || strcmp(fmuGUID, INSTANTIATION_TOKEN) != 0) {
        fail(&probe, "the GUID %s does not match this binary (%s)", fmuGUID ? fmuGUID : "NULL",
              INSTANTIATION_TOKEN);
        return NULL;
    }
    if (fmuType == fmi2ModelExchange && (MODEL_DISCRETE || N_STATES == 0)) {
        fail(&probe, "%s has no model exchange interface", MODEL_IDENTIFIER_STRING);
        return NULL;
    }
    inst = (Instance *)calloc(1, sizeof *inst);
    if (!inst) return NULL;
    inst->name = (char *)malloc(strlen(probe.name) + 1);
    if (!inst->name) {
        free(inst);
        return NULL;
    }
    strcpy(inst->name, probe.name);
    inst->callbacks = probe.callbacks;
    inst->type = fmuType;
    apply_start_values(&inst->s.values);
    apply_state_starts(&inst->s.values);
    inst->s.mode = MODE_INSTANTIATED;
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return;
    free(inst->name);
    free(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    Instance *inst = (Instance *)c;
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!inst) return fmi2Error;
    if (inst->s.mode != MODE_INSTANTIATED) return not_allowed(inst, "fmi2SetupExperiment");
    if (!isfinite(startTime)) return fail(inst, "startTime = %g is not finite", startTime);
    inst->s.start_time = startTime;
    inst->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    if (inst->s.mode != MODE_INSTANTIATED) return not_allowed(inst, "fmi2EnterInitializationMode");
    inst->s.mode = MODE_INITIALIZATION;
    apply_state_starts(&inst->s.values);
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    if (inst->s.mode != MODE_INITIALIZATION) return not_allowed(inst, "fmi2ExitInitializationMode");
    if (check_all(inst) != fmi2OK) return fmi2Error;
    apply_state_starts(&inst->s.values);
    inst->s.mode = inst->type == fmi2CoSimulation ? MODE_STEP_COMPLETE : MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (allowed(inst, "fmi2Terminate", RUNNING) != fmi2OK) return fmi2Error;
    inst->s.mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    memset(&inst->s, 0, sizeof inst->s);
    apply_start_values(&inst->s.values);
    apply_state_starts(&inst->s.values);
    inst->s.mode = MODE_INSTANTIATED;
    return fmi2OK;
}

/* ---------------------------------------------------------------- get and set */

static fmi2Status check_vrs(Instance *inst, const fmi2ValueReference vr[], size_t nvr, int first,
                            int count, const char *type) {
    size_t k;
    if (nvr > 0 && !vr) return fail(inst, "vr is NULL");
    for (k = 0; k < nvr; k++)
        if ((int)vr[k] < first || (int)vr[k] >= first + count)
            return fail(inst, "%u is not the value reference of a %s variable", vr[k], type);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    size_t k;
    if (!inst) return fmi2Error;
    if (check_vrs(inst, vr, nvr, 0, N_REALS, "Real") != fmi2OK) return fmi2Error;
    if (inst->s.mode == MODE_INITIALIZATION || inst->s.mode == MODE_INSTANTIATED)
        apply_state_starts(&inst->s.values);
    for (k = 0; k < nvr; k++) value[k] = inst->s.values.r[vr[k]];
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    size_t k;
    int setup;
    if (!inst) return fmi2Error;
    if (check_vrs(inst, vr, nvr, 0, N_REALS, "Real") != fmi2OK) return fmi2Error;
    if (inst->s.mode == MODE_TERMINATED || inst->s.mode == MODE_ERROR)
        return not_allowed(inst, "fmi2SetReal");
    setup = inst->s.mode == MODE_INSTANTIATED || inst->s.mode == MODE_INITIALIZATION;
    /* all or nothing: check every value before any is written */
    for (k = 0; k < nvr; k++) {
        int kind = REAL_KIND[vr[k]];
        if (kind == KIND_OUTPUT || kind == KIND_LOCAL)
            return fail(inst, "%s is computed by the model and cannot be set", REAL_NAMES[vr[k]]);
        if (kind == KIND_PARAMETER && !setup)
            return fail(inst, "parameter %s can only be set before initialization ends",
                         REAL_NAMES[vr[k]]);
        if (check_real(inst, (int)vr[k], value[k]) != fmi2OK) return fmi2Error;
    }
    for (k = 0; k < nvr; k++) inst->s.values.r[vr[k]] = value[k];
    if (!setup) model_outputs(&inst->s.values);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    Instance *inst = (Instance *)c;
    size_t k;
    if (!inst) return fmi2Error;
    if (check_vrs(inst, vr, nvr, INTEGER_VR_OFFSET, N_INTEGERS, "Integer") != fmi2OK)
        return fmi2Error;
    for (k = 0; k < nvr; k++) value[k] = inst->s.values.i[vr[k] - INTEGER_VR_OFFSET];
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    Instance *inst = (Instance *)c;
    size_t k;
    if (!inst) return fmi2Error;
    if (check_vrs(inst, vr, nvr, INTEGER_VR_OFFSET, N_INTEGERS, "Integer") != fmi2OK)
        return fmi2Error;
    if (inst->s.mode != MODE_INSTANTIATED && inst->s.mode != MODE_INITIALIZATION)
        return not_allowed(inst, "fmi2SetInteger");
    for (k = 0; k < nvr; k++)
        if (check_integer(inst, (int)vr[k] - INTEGER_VR_OFFSET, value[k]) != fmi2OK)
            return fmi2Error;
    for (k = 0; k < nvr; k++) inst->s.values.i[vr[k] - INTEGER_VR_OFFSET] = value[k];
    return fmi2OK;
}

/* This glue declares no Boolean or String variables: only empty requests succeed. */
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    (void)value;
    return c ? check_vrs((Instance *)c, vr, nvr, 0, 0, "Boolean") : fmi2Error;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    (void)value;
    return c ? check_vrs((Instance *)c, vr, nvr, 0, 0, "Boolean") : fmi2Error;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)value;
    return c ? check_vrs((Instance *)c, vr, nvr, 0, 0, "String") : fmi2Error;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)value;
    return c ? check_vrs((Instance *)c, vr, nvr, 0, 0, "String") : fmi2Error;
}

/* ---------------------------------------------------------------- FMU state */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Instance *inst = (Instance *)c;
    Snapshot *snapshot;
    if (allowed(inst, "fmi2GetFMUstate", ANY_MODE) != fmi2OK) return fmi2Error;
    if (!state) return fail(inst, "fmi2GetFMUstate: state is NULL");
    snapshot = (Snapshot *)(*state ? *state : malloc(sizeof(Snapshot)));
    if (!snapshot) return fail(inst, "out of memory");
    *snapshot = inst->s;
    snapshot->magic = SNAPSHOT_MAGIC;
    snapshot->version = SNAPSHOT_VERSION;
    snapshot->model = token_hash();
    snapshot->type = (int)inst->type;
    *state = snapshot;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    Instance *inst = (Instance *)c;
    if (allowed(inst, "fmi2SetFMUstate", ANY_MODE & ~IN(MODE_ERROR)) != fmi2OK) return fmi2Error;
    if (!state) return fail(inst, "fmi2SetFMUstate: state is NULL");
    if (check_snapshot(inst, (const Snapshot *)state) != fmi2OK) return fmi2Error;
    inst->s = *(const Snapshot *)state;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    if (!c || !state) return fmi2Error;
    free(*state);
    *state = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)state;
    if (!c || !size) return fmi2Error;
    *size = sizeof(Snapshot);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[],
                                 size_t size) {
    Instance *inst = (Instance *)c;
    if (!inst || !state || !bytes) return fmi2Error;
    if (size != sizeof(Snapshot))
        return fail(inst, "serialized FMU state needs %u bytes, got %u",
                     (unsigned)sizeof(Snapshot), (unsigned)size);
    memcpy(bytes, state, sizeof(Snapshot));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *state) {
    Instance *inst = (Instance *)c;
    if (!inst || !bytes || !state) return fmi2Error;
    Snapshot copy;
    if (size != sizeof(Snapshot))
        return fail(inst, "serialized FMU state has %u bytes, expected %u", (unsigned)size,
                     (unsigned)sizeof(Snapshot));
    memcpy(&copy, bytes, sizeof copy);
    if (check_snapshot(inst, &copy) != fmi2OK) return fmi2Error;
    if (!*state) *state = malloc(sizeof(Snapshot));
    if (!*state) return fail(inst, "out of memory");
    memcpy(*state, &copy, sizeof copy);
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return c ? fail((Instance *)c, "directional derivatives are not provided") : fmi2Error;
}

/* ---------------------------------------------------------------- co-simulation */

#if !MODEL_DISCRETE
static void rk4(const ModelValues *values, double *x, double h) {
    double k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], y[N_STATES];
    int k;
    model_derivatives(values, x, k1);
    for (k = 0; k < N_STATES; k++) y[k] = x[k] + 0.5 * h * k1[k];
    model_derivatives(values, y, k2);
    for (k = 0; k < N_STATES; k++) y[k] = x[k] + 0.5 * h * k2[k];
    model_derivatives(values, y, k3);
    for (k = 0; k < N_STATES; k++) y[k] = x[k] + h * k3[k];
    model_derivatives(values, y, k4);
    for (k = 0; k < N_STATES; k++) x[k] += h / 6.0 * (k1[k] + 2.0 * (k2[k] + k3[k]) + k4[k]);
}
#endif

static fmi2Status advance(Instance *inst, double H) {
    ModelValues *values = &inst->s.values;
    double x[N_STATES > 0 ? N_STATES : 1];
    long n, j;
    int k;
#if MODEL_DISCRETE
    double periods = H / values->r[SAMPLE_PERIOD_VR];
    n = lround(periods);
    if (n < 1 || fabs(periods - (double)n) > 1e-9 * periods)
        return fail(inst, "step %g is not a whole number of sample periods %s = %g", H,
                     REAL_NAMES[SAMPLE_PERIOD_VR], values->r[SAMPLE_PERIOD_VR]);
    for (j = 0; j < n; j++) model_update(values);
    for (k = 0; k < N_STATES; k++) x[k] = values->r[STATE_VR[k]];
#else
    double h, fastest = model_fastest(values);
    n = values->i[SUBSTEPS_VR - INTEGER_VR_OFFSET];
    /* RK4 is stable on a decaying mode while h / tau < 2.785: a step the plant's substeps
     * cut too coarsely for its fastest time constant is cut finer (at most MAX_AUTO_SUBSTEPS) */
    if (fastest > 0.0 && H / (double)n > RK4_REACH * fastest) {
        double needed = ceil(H / (RK4_REACH * fastest));
        n = needed > MAX_AUTO_SUBSTEPS ? MAX_AUTO_SUBSTEPS : (long)needed;
    }
    h = H / (double)n;
    for (k = 0; k < N_STATES; k++) x[k] = values->r[STATE_VR[k]];
    for (j = 0; j < n; j++) {
        rk4(values, x, h);
        if (states_diverged(x)) break;
        /* a state that decays below the smallest normal double becomes 0: subnormal numbers
         * made every later step several times slower (a long run whose state settles) */
        for (k = 0; k < N_STATES; k++)
            if (fabs(x[k]) < DBL_MIN) x[k] = 0.0;
    }
    for (k = 0; k < N_STATES; k++) values->r[STATE_VR[k]] = x[k];
#endif
    if (states_diverged(x)) {
        inst->s.mode = MODE_ERROR;
#if MODEL_DISCRETE
        return fail(inst, "the states diverged in the step from t = %g of size %g (%ld updates): a state left "
                          "[-%g, %g]", inst->s.time, H, n, DIVERGENCE_BOUND, DIVERGENCE_BOUND);
#else
        return fail(inst,
                     "the integration diverged in the step from t = %g of size %g (%ld substeps):"
                     " a state left [-%g, %g]; raise the parameter %s (now %d) or take a smaller step",
                     inst->s.time, H, n, DIVERGENCE_BOUND, DIVERGENCE_BOUND,
                     INTEGER_NAMES[SUBSTEPS_VR - INTEGER_VR_OFFSET], values->i[SUBSTEPS_VR - INTEGER_VR_OFFSET]);
#endif
    }
    model_outputs(values);
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *inst = (Instance *)c;
    double tolerance;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!inst) return fmi2Error;
    if (inst->s.mode != MODE_STEP_COMPLETE) return not_allowed(inst, "fmi2DoStep");
    if (!(communicationStepSize > 0.0) || !isfinite(communicationStepSize))
        return fail(inst, "communication step size %g must be finite and > 0",
                     communicationStepSize);
    if (!isfinite(currentCommunicationPoint) ||
        !isfinite(currentCommunicationPoint + communicationStepSize))
        return fail(inst, "communication point %g is not finite", currentCommunicationPoint);
    tolerance = 1e-9 * fmax(1.0, fabs(inst->s.time));
    if (fabs(currentCommunicationPoint - inst->s.time) > tolerance)
        return fail(inst, "communication point %.17g does not match the model time %.17g",
                     currentCommunicationPoint, inst->s.time);
    if (advance(inst, communicationStepSize) != fmi2OK) return fmi2Error;
    /* the next point is computed from the importer's point, so rounding does not accumulate */
    inst->s.time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    /* doStep always completes synchronously: there is never a step to cancel */
    return c ? fail((Instance *)c, "fmi2CancelStep: no asynchronous step is pending")
             : fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return c ? fail((Instance *)c, "input derivatives are not supported") : fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return c ? fail((Instance *)c, "output derivatives are not supported") : fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s;
    if (!c || !value) return fmi2Error;
    *value = fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    Instance *inst = (Instance *)c;
    if (!inst || !value) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return fail(inst, "fmi2GetRealStatus: unsupported kind");
    *value = inst->s.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s;
    (void)value;
    return c ? fail((Instance *)c, "fmi2GetIntegerStatus: no integer status") : fmi2Error;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    Instance *inst = (Instance *)c;
    if (!inst || !value) return fmi2Error;
    if (s != fmi2Terminated) return fail(inst, "fmi2GetBooleanStatus: unsupported kind");
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s;
    (void)value;
    return c ? fail((Instance *)c, "fmi2GetStringStatus: no string status") : fmi2Error;
}

/* ---------------------------------------------------------------- model exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    if (inst->s.mode != MODE_CONTINUOUS_TIME) return not_allowed(inst, "fmi2EnterEventMode");
    inst->s.mode = MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    Instance *inst = (Instance *)c;
    if (!inst || !info) return fmi2Error;
    if (inst->s.mode != MODE_EVENT) return not_allowed(inst, "fmi2NewDiscreteStates");
    info->newDiscreteStatesNeeded = fmi2False;
    info->terminateSimulation = fmi2False;
    info->nominalsOfContinuousStatesChanged = fmi2False;
    info->valuesOfContinuousStatesChanged = fmi2False;
    info->nextEventTimeDefined = fmi2False;
    info->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    if (inst->s.mode != MODE_EVENT) return not_allowed(inst, "fmi2EnterContinuousTimeMode");
    inst->s.mode = MODE_CONTINUOUS_TIME;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!c || !enterEventMode || !terminateSimulation) return fmi2Error;
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    Instance *inst = (Instance *)c;
    if (allowed(inst, "fmi2SetTime", IN(MODE_EVENT) | IN(MODE_CONTINUOUS_TIME)) != fmi2OK)
        return fmi2Error;
    if (!isfinite(time)) return fail(inst, "time %g is not finite", time);
    inst->s.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    Instance *inst = (Instance *)c;
    size_t k;
    if (allowed(inst, "fmi2SetContinuousStates", IN(MODE_CONTINUOUS_TIME)) != fmi2OK)
        return fmi2Error;
    if (nx > 0 && !x) return fail(inst, "fmi2SetContinuousStates: x is NULL");
    if (nx != N_STATES) return fail(inst, "expected %d states, got %u", N_STATES, (unsigned)nx);
    for (k = 0; k < nx; k++)
        if (!isfinite(x[k]))
            return fail(inst, "state %s = %g is not finite", REAL_NAMES[STATE_VR[k]], x[k]);
    for (k = 0; k < nx; k++) inst->s.values.r[STATE_VR[k]] = x[k];
    model_outputs(&inst->s.values);
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    Instance *inst = (Instance *)c;
    if (allowed(inst, "fmi2GetDerivatives",
                IN(MODE_INITIALIZATION) | IN(MODE_EVENT) | IN(MODE_CONTINUOUS_TIME) | AFTER) != fmi2OK)
        return fmi2Error;
    if (nx > 0 && !derivatives) return fail(inst, "fmi2GetDerivatives: derivatives is NULL");
    if (nx != N_STATES) return fail(inst, "expected %d states, got %u", N_STATES, (unsigned)nx);
#if MODEL_DISCRETE
    return fail(inst, "a discrete-time model has no derivatives");
#else
    {
        double x[N_STATES > 0 ? N_STATES : 1];
        size_t k;
        for (k = 0; k < nx; k++) x[k] = inst->s.values.r[STATE_VR[k]];
        model_derivatives(&inst->s.values, x, derivatives);
        for (k = 0; k < nx; k++)
            if (!isfinite(derivatives[k]))
                return fail(inst, "the derivative of %s is not finite (%g) at this state and these "
                             "parameters", REAL_NAMES[STATE_VR[k]], derivatives[k]);
        for (k = 0; k < nx; k++) inst->s.values.r[STATE_DER_VR[k]] = derivatives[k];
        return fmi2OK;
    }
#endif
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    if (!c) return fmi2Error;
    return ni == 0 ? fmi2OK : fail((Instance *)c, "this model has no event indicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    Instance *inst = (Instance *)c;
    size_t k;
    if (allowed(inst, "fmi2GetContinuousStates",
                IN(MODE_INITIALIZATION) | IN(MODE_EVENT) | IN(MODE_CONTINUOUS_TIME) | AFTER) != fmi2OK)
        return fmi2Error;
    if (nx > 0 && !x) return fail(inst, "fmi2GetContinuousStates: x is NULL");
    if (nx != N_STATES) return fail(inst, "expected %d states, got %u", N_STATES, (unsigned)nx);
    for (k = 0; k < nx; k++) x[k] = inst->s.values.r[STATE_VR[k]];
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    size_t k;
    if (!c || (nx > 0 && !x_nominal)) return fmi2Error;
    for (k = 0; k < nx; k++) x_nominal[k] = 1.0;
    return fmi2OK;
}
