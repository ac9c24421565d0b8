/* The sample loop in C, for the common case: a linear controller on the fed-back outputs
 * (no estimator, no unit conversion). The same order of events, and the same arithmetic in
 * the same order, as the Python loop that cosim/loop.py generates: a zero coefficient is
 * left out as there, products are summed left to right, and nothing is contracted into a
 * fused multiply-add (-std=c99 implies -ffp-contract=off), so both loops give the same
 * bits (tests/test_native.py). The plant is stepped through the session's own step_io,
 * whose address and call the session hands over. */
#include <stddef.h>

typedef int (*step_t)(void *call, double t, double h);

typedef struct {
    void *step;            /* the session's step_io or step_io3 */
    void *call;            /* and its StepCall */
    double *in;            /* the call's inputs: u, then the disturbances */
    const double *out;     /* the call's outputs, read after each step */
    double start, h;       /* plant time start + k * h, as the session keeps it */
    long long k;           /* advanced by each successful step */
    int substeps;          /* communication steps per control sample */
    int n_out;             /* outputs read per step */
    int n_s;               /* fed-back signals */
    const int *pick;       /* their positions among the outputs */
    int n_noisy;           /* fed-back signals with measurement noise */
    const int *noisy;      /* their positions among the fed-back signals */
    const double *noise;   /* samples x n_noisy */
    int n_d;               /* disturbance inputs */
    const double *disturbance; /* samples x n_d */
    const double *rbar;    /* the prefiltered reference, by sample */
    int n_xc;              /* controller states */
    double *xc;            /* their values, carried from chunk to chunk */
    const double *feedback; /* [Cc Dc]: n_xc + n_s coefficients */
    const double *update;  /* [Ac Bc]: n_xc rows of n_xc + n_s coefficients */
    double F;              /* prefilter gain */
    int delay;             /* 1: the command of sample k is applied at k + 1 */
    double held;           /* the command held back by the delay */
    int limited;           /* actuator limit on */
    double limit;
    double *values;        /* n_out: the outputs of the last step */
    double *rows;          /* records by sample: outputs (n_out each), */
    double *us;            /* applied input, */
    double *commands;      /* command before the limit (when limited), */
    double *xcs;           /* controller state before the sample (n_xc each, when n_xc) */
    long long failed_at;   /* the sample whose step failed */
} Loop;

/* sum of coefficient * value over the nonzero coefficients, left to right; 0.0 when none */
static double dot(const double *a, const double *xc, int n_xc, const double *s, int n_s) {
    double acc = 0.0;
    int any = 0;
    for (int i = 0; i < n_xc + n_s; i++) {
        if (a[i] != 0.0) {
            double term = a[i] * (i < n_xc ? xc[i] : s[i - n_xc]);
            acc = any ? acc + term : term;
            any = 1;
        }
    }
    return acc;
}

/* Samples first .. last-1. 0 when all went well, else what step_io returned for the step
 * that failed (at sample failed_at, whose records are written). */
__attribute__((visibility("default"))) int run_loop(Loop *L, long long first, long long last) {
    step_t step = (step_t)L->step;
    double s[64], next[64];
    if (L->n_s > 64 || L->n_xc > 64) return -1;
    for (long long k = first; k < last; k++) {
        for (int j = 0; j < L->n_s; j++) s[j] = L->values[L->pick[j]];
        for (int p = 0; p < L->n_noisy; p++) s[L->noisy[p]] = s[L->noisy[p]] + L->noise[k * L->n_noisy + p];
        for (int i = 0; i < L->n_xc; i++) L->xcs[k * L->n_xc + i] = L->xc[i];
        double c = L->F * L->rbar[k] - dot(L->feedback, L->xc, L->n_xc, s, L->n_s);
        if (L->delay) {
            double now = c;
            c = L->held;
            L->held = now;
        }
        for (int i = 0; i < L->n_xc; i++)
            next[i] = dot(L->update + (size_t)i * (L->n_xc + L->n_s), L->xc, L->n_xc, s, L->n_s);
        for (int i = 0; i < L->n_xc; i++) L->xc[i] = next[i];
        double u = c;
        if (L->limited) {
            L->commands[k] = c;
            u = (-L->limit <= c && c <= L->limit) ? c : (c > 0 ? L->limit : -L->limit);
        }
        for (int j = 0; j < L->n_out; j++) L->rows[k * L->n_out + j] = L->values[j];
        L->us[k] = u;
        L->in[0] = u;
        for (int j = 0; j < L->n_d; j++) L->in[1 + j] = L->disturbance[k * L->n_d + j];
        for (int m = 0; m < L->substeps; m++) {
            int failed = step(L->call, L->start + (double)L->k * L->h, L->h);
            if (failed) {
                L->failed_at = k;
                return failed;
            }
            L->k++;
            for (int j = 0; j < L->n_out; j++) L->values[j] = L->out[j];
        }
    }
    return 0;
}
