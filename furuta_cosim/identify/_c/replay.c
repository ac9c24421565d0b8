/* A replay's closed loop in C (identify/native.py): the loop identify/replay.py closed_loop
 * runs in Python, for a log whose controller is linear (a controller file's law on the
 * angles as the encoders count them or as a balancing log's smoother has them, the rates by
 * the loop's filter, the current; or a law in the logger's own words, a discrete state space
 * on what the log recorded), its feedforward, voltage limit and delay in the loop (whole
 * samples and a part of one), on its clock as it ran (a uniform one, or the instants a log
 * records its samples read and its commands written, jittered). The same events in the same order as the
 * Python loop, which stays the reference (tests/test_native_replay.py: within 1e-12). The
 * plant is stepped through the session's own step_io, its clock kept as the session keeps it
 * (start + k * h while h stays the same). */
#include <math.h>
#include <stddef.h>

typedef int (*step_t)(void *call, double t, double h);

typedef struct {
    void *step; void *call; double *in; const double *out;
    const double *first;                        /* the outputs at the window's start */
    double time, start, h; long long k;          /* the session's clock */
    int n_out, n_names;                         /* outputs read; the first n_names are recorded */
    const double *scale, *offset;               /* per output: SI = value * scale + offset */
    double v_scale, v_offset;                   /* the plant's input: value = (V - offset) / scale */
    long long n;                                /* samples */
    double period;                              /* h of the log */
    int counted; double zero, per_count;        /* the encoders' rounding (1), or: */
    const double *noise0, *noise1;              /* the smoother's departure (n each) */
    const double *feedforward;                  /* n */
    int limited; double limit;
    int whole; double part;                     /* the delay: whole samples and a part of one */
    const double *logged; long long n_logged;   /* the commands before the window (lead-in) */
    /* the command: kind 1, a controller file's law with the rate filter */
    int kind;
    double F; const double *reference;          /* n */
    int n_xc; double *xc; const double *feedback; const double *update;  /* [Cc Dc], [Ac Bc] */
    double ra, rb;                              /* the rate filter */
    long long n_lead; const double *lead_angles, *lead_current, *lead_reference;
    double first0, first1;                      /* the angles logged at the window's first sample */
    /* kind 2, a law: x' = A x + B v, u = (C x + D v + offset) * factor */
    int n_x, n_v; double *x; const double *A, *B, *C, *D; double law_offset, law_factor;
    int varying;                                /* 1: A, B, C, D hold one set per sample (a jittered clock) */
    const int *source;                          /* per v: 0 theta0, 1 theta1, 2 i, 3 a column */
    const double *c0, *c1;                      /* per v: seen / c0 - c1 */
    const double *columns;                      /* n_v x n: a column's value by sample */
    /* a log that records when each sample was read and its command written, or a jittered
     * clock: the plant stepped to each reading, its voltage switched at each arrival */
    int timed;
    const double *read, *arrive;                /* n each */
    double *when, *value; long long capacity;   /* the commands on their way (a queue) */
    long long n_pending; double level;          /* the queue as the loop starts; the voltage then */
    /* records */
    double *raw;                                /* n x n_names */
    double *volts;                              /* n */
    long long stopped_at;                       /* the sample whose outputs were not finite, else -1 */
    long long failed_at;                        /* the sample whose step failed */
    double failed_input;
} Replay;

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

static int plant_step(Replay *R, double value, double h) {
    if (h != R->h) { R->start = R->time; R->k = 0; R->h = h; }
    R->in[0] = value;
    int failed = ((step_t)R->step)(R->call, R->time, h);
    if (failed) { R->failed_input = value; return failed; }
    R->k++;
    R->time = R->start + (double)R->k * h;
    return 0;
}

static double written(const Replay *R, long long j) {
    if (j >= 0) return R->volts[j];
    return (-j <= R->n_logged) ? R->logged[R->n_logged + j] : 0.0;
}

/* the controller file's law: rates filtered (the first call's rates 0), then the generalized
 * controller; ``started`` says whether the filter has a last sample */
static double control(Replay *R, double a0, double a1, double current, double r, int *started,
                      double *last, double *rates) {
    if (*started) {
        double r0 = R->ra * rates[0] + R->rb * (a0 - last[0]);
        double r1 = R->ra * rates[1] + R->rb * (a1 - last[1]);
        rates[0] = r0; rates[1] = r1;
    }
    *started = 1;
    last[0] = a0; last[1] = a1;
    double s[5] = {a0, rates[0], a1, rates[1], current};
    double next[64];
    double u = R->F * r - dot(R->feedback, R->xc, R->n_xc, s, 5);
    for (int i = 0; i < R->n_xc; i++) next[i] = dot(R->update + (size_t)i * (R->n_xc + 5), R->xc, R->n_xc, s, 5);
    for (int i = 0; i < R->n_xc; i++) R->xc[i] = next[i];
    return u;
}

static double law(Replay *R, long long k, double a0, double a1, double current) {
    double v[64], next[64];
    size_t nx = (size_t)R->n_x, nv = (size_t)R->n_v, at = R->varying ? (size_t)k : 0;
    const double *A = R->A + at * nx * nx, *B = R->B + at * nx * nv, *C = R->C + at * nx, *D = R->D + at * nv;
    double seen[3] = {a0, a1, current};
    for (int j = 0; j < R->n_v; j++)
        v[j] = R->source[j] < 3 ? seen[R->source[j]] / R->c0[j] - R->c1[j] : R->columns[(size_t)j * R->n + k];
    double u = 0.0;
    for (int i = 0; i < R->n_x; i++) u += C[i] * R->x[i];
    double dv = 0.0;
    for (int j = 0; j < R->n_v; j++) dv += D[j] * v[j];
    u = u + dv;
    for (int i = 0; i < R->n_x; i++) {
        double a = 0.0, b = 0.0;
        for (int m = 0; m < R->n_x; m++) a += A[(size_t)i * nx + m] * R->x[m];
        for (int j = 0; j < R->n_v; j++) b += B[(size_t)i * nv + j] * v[j];
        next[i] = a + b;
    }
    for (int i = 0; i < R->n_x; i++) R->x[i] = next[i];
    return (u + R->law_offset) * R->law_factor;
}

/* as replay.py _held: ``seconds`` at ``value`` in steps no longer than ``longest``; 1 when it
 * stepped (the outputs are the last step's), 0 when ``seconds`` is no time, else -failure */
static int held(Replay *R, double value, double seconds, double longest) {
    if (seconds <= 1e-9 * longest) return 0;
    long long pieces = (long long)ceil(seconds / longest - 1e-9);
    if (pieces < 1) pieces = 1;
    for (long long p = 0; p < pieces; p++) {
        int failed = plant_step(R, value, seconds / (double)pieces);
        if (failed) return -failed;
    }
    return 1;
}

static double counted(double angle, double zero, double per_count) {
    return zero + nearbyint((angle - zero) / per_count) * per_count;
}

/* 0 when the window ran (or stopped at a sample that is not finite: stopped_at), -1 when set
 * up beyond its buffers, else what step_io returned for the step that failed (failed_at). */
__attribute__((visibility("default"))) int run_replay(Replay *R) {
    double si[64];
    int started = 0;
    double last[2] = {0.0, 0.0}, rates[2] = {0.0, 0.0};
    const double pi = 3.14159265358979323846;
    if (R->n_out > 64 || R->n_xc > 64 || R->n_x > 64 || R->n_v > 64) return -1;
    double kept[64];                  /* the outputs the loop reads: the window's start, then a step's */
    for (int j = 0; j < R->n_out; j++) kept[j] = R->first[j];
    const double *y = kept;
    long long head = 0, tail = R->n_pending;   /* the queue: when[head .. tail) */
    double level = R->level, now_t = R->read[0];
    R->stopped_at = -1;
    for (long long k = 0; k < R->n; k++) {
        int finite = 1;
        for (int j = 0; j < R->n_out; j++) {
            si[j] = y[j] * R->scale[j] + R->offset[j];
            if (!isfinite(si[j])) finite = 0;
        }
        for (int j = 0; j < R->n_names; j++) R->raw[k * R->n_names + j] = si[j];
        if (!finite) { R->stopped_at = k; return 0; }
        double theta0 = si[R->n_names], theta1 = si[R->n_names + 1], current = si[R->n_names + 2];
        double a0, a1;
        if (R->counted) {
            a0 = counted(theta0, R->zero, R->per_count);
            a1 = counted(theta1, pi + R->zero, R->per_count);
        } else {
            a0 = theta0 + R->noise0[k];
            a1 = theta1 + R->noise1[k];
        }
        double u;
        if (R->kind == 1) {
            if (k == 0 && R->n_lead) {   /* the rows before the window, moved as the replay departs */
                double shift0 = a0 - R->first0, shift1 = a1 - R->first1;
                for (long long j = 0; j < R->n_lead; j++)
                    control(R, R->lead_angles[2 * j] + shift0, R->lead_angles[2 * j + 1] + shift1,
                            R->lead_current[j], R->lead_reference[j], &started, last, rates);
            }
            u = control(R, a0, a1, current, R->reference[k], &started, last, rates);
        } else {
            u = law(R, k, a0, a1, current);
        }
        u = u + R->feedforward[k];
        if (R->limited) {   /* as Python's max(-limit, min(limit, u)), a NaN included */
            double low = (u < R->limit) ? u : R->limit;
            u = (low > -R->limit) ? low : -R->limit;
        }
        R->volts[k] = u;
        if (R->timed && k < R->n - 1) {
            double arrives = R->arrive[k];
            double latest = (tail > head) ? R->when[tail - 1] : now_t;
            if (tail >= R->capacity) return -1;
            R->when[tail] = (latest > arrives) ? latest : arrives;   /* Python's max(arrives, latest) */
            R->value[tail] = u;
            tail++;
            double end = R->read[k + 1];
            while (tail > head && R->when[head] < end - 1e-12) {
                double at = R->when[head], v = R->value[head];
                head++;
                if (at - now_t > 1e-12) {
                    int done = held(R, (level - R->v_offset) / R->v_scale, at - now_t, R->period);
                    if (done < 0) { R->failed_at = k; return -done; }
                    now_t = at;
                }
                level = v;
            }
            int done = held(R, (level - R->v_offset) / R->v_scale, end - now_t, R->period);
            if (done < 0) { R->failed_at = k; return -done; }
            if (done) {
                for (int j = 0; j < R->n_out; j++) kept[j] = R->out[j];
            }
            if (end > now_t) now_t = end;
        } else if (k < R->n - 1) {
            double now = written(R, k - R->whole);
            int failed;
            if (R->part > 0.0 &&
                (failed = plant_step(R, (written(R, k - R->whole - 1) - R->v_offset) / R->v_scale, R->part))) {
                R->failed_at = k;
                return failed;
            }
            if ((failed = plant_step(R, (now - R->v_offset) / R->v_scale, R->period - R->part))) {
                R->failed_at = k;
                return failed;
            }
            for (int j = 0; j < R->n_out; j++) kept[j] = R->out[j];
        }
    }
    return 0;
}
