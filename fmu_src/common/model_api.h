/* The contract between the generic FMI 2.0 glue (fmi2_glue.c) and one plant (model.c).
 *
 * A plant supplies its equations only. Its variables, value references and start values
 * come from the generated header model_vars.h, which the exporter writes from the plant's
 * Python declaration. Every variable of type Real lives in values->r[vr], every Integer in
 * values->i[vr - INTEGER_VR_OFFSET]. */
#ifndef MODEL_API_H
#define MODEL_API_H

#include <stddef.h>

enum { KIND_PARAMETER = 0, KIND_INPUT = 1, KIND_OUTPUT = 2, KIND_LOCAL = 3 };

#include "model_vars.h"

typedef struct {
    double r[N_REALS];
    int i[N_INTEGERS > 0 ? N_INTEGERS : 1];
} ModelValues;

#define R(name) (values->r[VR_##name])
#define I(name) (values->i[VR_##name - INTEGER_VR_OFFSET])

#if MODEL_DISCRETE
/* Advance the states (values->r[STATE_VR[k]]) by one sample period, inputs held. */
void model_update(ModelValues *values);
#else
/* dx = f(x, inputs, parameters); x and dx are ordered as STATE_VR. */
void model_derivatives(const ModelValues *values, const double *x, double *dx);

/* The model's fastest time constant (s) at these parameters, or 0 when it does not know one:
 * the glue takes RK4 substeps short enough to integrate it stably, more than the plant's
 * substep parameter asks where that is too few. */
double model_fastest(const ModelValues *values);
#endif

/* Outputs that are not states, from states, inputs and parameters. */
void model_outputs(ModelValues *values);

/* Checks that relate several parameters; per-variable checks (finite, positive, minimum)
 * are done by the glue from the declaration. Returns 0 when the values are usable, else
 * writes a one-line reason into message. */
int model_check(const ModelValues *values, char *message, size_t size);

#endif
