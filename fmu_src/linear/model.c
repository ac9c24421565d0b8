/* Linear state-space plant; the dimensions and the first value reference of each block
 * (LIN_*) come from the generated header, the matrices are parameters stored row-major. */
#include "model_api.h"

#define NX N_STATES
#define MAT(first, cols, i, j) (values->r[(first) + (i) * (cols) + (j)])
#define U(j) (values->r[LIN_U0 + (j)])

static void state_rate(const ModelValues *values, const double *x, double *out) {
    int i, j;
    for (i = 0; i < NX; i++) {
        double sum = values->r[LIN_V0 + i];
        for (j = 0; j < NX; j++) sum += MAT(LIN_A0, NX, i, j) * x[j];
        for (j = 0; j < LIN_NU; j++) sum += MAT(LIN_B0, LIN_NU, i, j) * U(j);
        out[i] = sum;
    }
}

#if MODEL_DISCRETE
void model_update(ModelValues *values) {
    double x[NX], next[NX];
    int k;
    for (k = 0; k < NX; k++) x[k] = values->r[STATE_VR[k]];
    state_rate(values, x, next);
    for (k = 0; k < NX; k++) values->r[STATE_VR[k]] = next[k];
}
#else
void model_derivatives(const ModelValues *values, const double *x, double *dx) {
    state_rate(values, x, dx);
}

/* a linear plant's substeps are its file's (its eigenvalues are not computed here) */
double model_fastest(const ModelValues *values) {
    (void)values;
    return 0.0;
}
#endif

void model_outputs(ModelValues *values) {
    int i, j;
    for (i = 0; i < LIN_NY; i++) {
        double sum = 0.0;
        for (j = 0; j < NX; j++) sum += MAT(LIN_C0, NX, i, j) * values->r[STATE_VR[j]];
        for (j = 0; j < LIN_NU; j++) sum += MAT(LIN_D0, LIN_NU, i, j) * U(j);
        values->r[LIN_Y0 + i] = sum;
    }
}

int model_check(const ModelValues *values, char *message, size_t size) {
    (void)values;
    (void)message;
    (void)size;
    return 0;
}
