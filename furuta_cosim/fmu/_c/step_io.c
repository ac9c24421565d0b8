/* One call per control step: set the inputs, doStep, get the outputs.
 * Each foreign call from Python costs about 0.4 us, more than half the plant's own step; the
 * session prepares this struct once and then crosses into C once per step: step_io for an
 * FMI 2.0 instance, step_io3 for an FMI 3.0 one (whose calls take array sizes and whose
 * doStep reports through flags). */
#include <stdbool.h>
#include <stddef.h>

typedef int (*set_real_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*do_step_t)(void *, double, double, int);
typedef int (*get_real_t)(void *, const unsigned int *, size_t, double *);
typedef int (*set_float64_t)(void *, const unsigned int *, size_t, const double *, size_t);
typedef int (*do_step3_t)(void *, double, double, bool, bool *, bool *, bool *, double *);
typedef int (*get_float64_t)(void *, const unsigned int *, size_t, double *, size_t);

typedef struct {
    void *set_real; /* fmi2SetReal or fmi3SetFloat64 */
    void *do_step;  /* fmi2DoStep or fmi3DoStep */
    void *get_real; /* fmi2GetReal or fmi3GetFloat64 */
    void *component;
    const unsigned int *in_vr;
    size_t n_in;
    const double *in;
    const unsigned int *out_vr;
    size_t n_out;
    double *out;
    bool flags[3]; /* FMI 3.0: event handling needed, terminate, early return */
    double last;   /* FMI 3.0: the last successful time */
} StepCall;

/* 0 when all went well, else 8 * (1, 2 or 3 for the call that failed: set, step, get) plus
 * the status it returned (a fatal instance must not be called again). */
__attribute__((visibility("default"))) int step_io(const StepCall *call, double t, double h) {
    int status;
    if (call->n_in &&
        (status = ((set_real_t)call->set_real)(call->component, call->in_vr, call->n_in, call->in)) >= 2)
        return 8 + status;
    if ((status = ((do_step_t)call->do_step)(call->component, t, h, 1)) >= 2) return 16 + status;
    if (call->n_out &&
        (status = ((get_real_t)call->get_real)(call->component, call->out_vr, call->n_out, call->out)) >= 2)
        return 24 + status;
    return 0;
}

/* The same for FMI 3.0; besides, 32 when the FMU asks to end the simulation and 33 when the
 * step returned early (call->last: the time it reached). */
__attribute__((visibility("default"))) int step_io3(StepCall *call, double t, double h) {
    int status;
    if (call->n_in && (status = ((set_float64_t)call->set_real)(call->component, call->in_vr, call->n_in,
                                                                 call->in, call->n_in)) >= 2)
        return 8 + status;
    if ((status = ((do_step3_t)call->do_step)(call->component, t, h, true, &call->flags[0],
                                               &call->flags[1], &call->flags[2], &call->last)) >= 2)
        return 16 + status;
    if (call->flags[1]) return 32;
    if (call->flags[2]) return 33;
    if (call->n_out && (status = ((get_float64_t)call->get_real)(call->component, call->out_vr, call->n_out,
                                                                  call->out, call->n_out)) >= 2)
        return 24 + status;
    return 0;
}
