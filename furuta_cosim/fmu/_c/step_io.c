/* One call per control step: set the inputs, doStep, get the outputs.
 * Each foreign call from Python costs about 0.4 us, more than half the plant's own step; the
 * session prepares this struct once and then crosses into C once per step. */
#include <stddef.h>

typedef int (*set_real_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*do_step_t)(void *, double, double, int);
typedef int (*get_real_t)(void *, const unsigned int *, size_t, double *);

typedef struct {
    set_real_t set_real;
    do_step_t do_step;
    get_real_t get_real;
    void *component;
    const unsigned int *in_vr;
    size_t n_in;
    const double *in;
    const unsigned int *out_vr;
    size_t n_out;
    double *out;
} StepCall;

/* 0 when all went well, else 8 * (1, 2 or 3 for the call that failed: set, step, get) plus
 * the fmi2Status it returned (an fmi2Fatal instance must not be called again). */
__attribute__((visibility("default"))) int step_io(const StepCall *call, double t, double h) {
    int status;
    if (call->n_in && (status = call->set_real(call->component, call->in_vr, call->n_in, call->in)) >= 2)
        return 8 + status;
    if ((status = call->do_step(call->component, t, h, 1)) >= 2) return 16 + status;
    if (call->n_out && (status = call->get_real(call->component, call->out_vr, call->n_out, call->out)) >= 2)
        return 24 + status;
    return 0;
}
