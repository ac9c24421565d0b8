/* A scenario's source: one row of a table per sample (model.py says what the table is).
 * The table and its size come from the generated header (SRC_*). */
#include "model_api.h"

static const double TABLE[SRC_ROWS * SRC_COLS] = SRC_TABLE;

void model_update(ModelValues *values) {
    values->r[STATE_VR[0]] += 1.0;
}

void model_outputs(ModelValues *values) {
    double sample = values->r[STATE_VR[0]];
    long row = sample <= 0.0 ? 0 : (long)(sample + 0.5);
    int j;
    if (row > SRC_ROWS - 1) row = SRC_ROWS - 1;
    for (j = 0; j < SRC_COLS; j++) values->r[SRC_Y0 + j] = TABLE[row * SRC_COLS + j];
}

int model_check(const ModelValues *values, char *message, size_t size) {
    (void)values;
    (void)message;
    (void)size;
    return 0;
}
