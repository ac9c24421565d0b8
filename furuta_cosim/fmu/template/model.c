/* IDENTIFIER: m x'' = F - k x - c x'. The state vector x[] and its derivative dx[] follow the
 * order in which model.py registers the states; R(name) is any declared Real (a parameter, an
 * input). See model_api.h (in the project's fmu_src/common) for the whole contract. */
#include <stdio.h>

#include "model_api.h"

void model_derivatives(const ModelValues *values, const double *x, double *dx) {
    dx[0] = x[1];
    dx[1] = (R(F) - R(k) * x[0] - R(c) * x[1]) / R(m);
}

/* the fastest time constant (s) the RK4 substeps must resolve, or 0 when none is known */
double model_fastest(const ModelValues *values) { (void)values; return 0.0; }

/* outputs that are not states (none here) */
void model_outputs(ModelValues *values) { (void)values; }

/* checks across parameters (each one's own range is checked from the declaration) */
int model_check(const ModelValues *values, char *message, size_t size) {
    (void)values; (void)message; (void)size;
    return 0;
}
