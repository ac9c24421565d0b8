/* Rotary inverted (Furuta) pendulum driven by a DC motor: Solis & Thomas (2021), Sec. III,
 * with the readings of docs/paper-readings.md §1: one effective gear ratio N in motor torque,
 * back-EMF and reflected rotor inertia, and the centripetal matrix M2 with lp^2.
 *
 * State x = [theta0, dtheta0, theta1, dtheta1, i]; theta1 = 0 is the upright position.
 *   M1(theta1) q'' = T - M2(theta1, q') q' - M3(theta1)
 *   L_a di/dt = V - R_a i - M_f N dtheta0
 * with T = [M_f N i + tau0 + tau_rig0, tau1 + tau_rig1].
 *
 * tau_rig holds what a real rig adds (docs: "The model a real rig needs"), each absent while
 * its parameter is 0, and then not computed at all, so a plant without them gives the same
 * numbers to the bit:
 *   Coulomb friction  -Tc tanh(dtheta / w_c) on the arm (Tc0) and the pendulum (Tc1): smoothed
 *                     below the speed w_c so that the right-hand side stays smooth for RK4;
 *   the encoder cable -K_c (theta0 - theta0_rest) on the arm;
 *   end stops         beyond theta0_min or theta0_max a spring-damper K_stop, D_stop that only
 *                     ever pushes the arm back (it never pulls it into the stop). */
#include <math.h>
#include <stdio.h>

#include "model_api.h"

/* the stops' push on the arm: zero inside [theta0_min, theta0_max], never pulling */
static double end_stop(const ModelValues *values, double theta0, double dtheta0) {
    double push = 0.0;
    if (theta0 > R(theta0_max)) {
        push = -R(K_stop) * (theta0 - R(theta0_max)) - R(D_stop) * dtheta0;
        push = fmin(push, 0.0);
    } else if (theta0 < R(theta0_min)) {
        push = -R(K_stop) * (theta0 - R(theta0_min)) - R(D_stop) * dtheta0;
        push = fmax(push, 0.0);
    }
    return push;
}

void model_derivatives(const ModelValues *values, const double *x, double *dx) {
    const double theta0 = x[0], dtheta0 = x[1], theta1 = x[2], dtheta1 = x[3], current = x[4];
    const double s = sin(theta1), c = cos(theta1), s2 = 2.0 * s * c;
    const double mp = R(m_p), lp = R(l_p), r = R(r), N = R(N);
    const double J0 = R(I_a) + r * r * (mp + R(m_c)) + N * N * R(I_m);
    const double J1 = R(I_p) + mp * lp * lp;
    const double coupling = mp * r * lp;
    double V = R(V);
    double m11, m12, m22, rhs0, rhs1, det;

    if (R(V_max) > 0.0) V = fmax(-R(V_max), fmin(R(V_max), V));

    m11 = J0 + mp * lp * lp * s * s;
    m12 = -coupling * c;
    m22 = J1;
    rhs0 = R(M_f) * N * current + R(tau0)
         - (mp * lp * lp * dtheta1 * s2 + R(C0)) * dtheta0 - coupling * dtheta1 * s * dtheta1;
    rhs1 = R(tau1) + 0.5 * mp * lp * lp * dtheta0 * s2 * dtheta0 - R(C1) * dtheta1
         + mp * R(g) * lp * s;
    if (R(Tc0) != 0.0) rhs0 -= R(Tc0) * tanh(dtheta0 / R(w_c));
    if (R(K_c) != 0.0) rhs0 -= R(K_c) * (theta0 - R(theta0_rest));
    if (R(K_stop) != 0.0 || R(D_stop) != 0.0) rhs0 += end_stop(values, theta0, dtheta0);
    if (R(Tc1) != 0.0) rhs1 -= R(Tc1) * tanh(dtheta1 / R(w_c));
    det = m11 * m22 - m12 * m12;

    dx[0] = dtheta0;
    dx[1] = (m22 * rhs0 - m12 * rhs1) / det;
    dx[2] = dtheta1;
    dx[3] = (m11 * rhs1 - m12 * rhs0) / det;
    dx[4] = (V - R(R_a) * current - R(M_f) * N * dtheta0) / R(L_a);
}

/* the armature's electrical time constant L_a / R_a: far faster than the mechanics (0.15 ms on
 * a QUBE-Servo 3 against tens of ms), it sets the longest stable RK4 substep */
double model_fastest(const ModelValues *values) {
    return R(R_a) > 0.0 ? R(L_a) / R(R_a) : 0.0;
}

void model_outputs(ModelValues *values) { (void)values; }

int model_check(const ModelValues *values, char *message, size_t size) {
    /* positivity of masses, inertias, lengths and L_a is checked by the glue; with those the
     * mass matrix is always invertible, since J0 J1 > (m_p r l_p)^2 */
    if (R(C0) < 0.0 || R(C1) < 0.0 || R(R_a) < 0.0 || R(V_max) < 0.0) {
        snprintf(message, size, "C0 = %g, C1 = %g, R_a = %g and V_max = %g must be >= 0", R(C0),
                 R(C1), R(R_a), R(V_max));
        return 1;
    }
    if (R(Tc0) < 0.0 || R(Tc1) < 0.0 || R(K_c) < 0.0 || R(K_stop) < 0.0 || R(D_stop) < 0.0) {
        snprintf(message, size, "Tc0 = %g, Tc1 = %g, K_c = %g, K_stop = %g and D_stop = %g must "
                 "be >= 0", R(Tc0), R(Tc1), R(K_c), R(K_stop), R(D_stop));
        return 1;
    }
    if ((R(K_stop) != 0.0 || R(D_stop) != 0.0) && !(R(theta0_min) < R(theta0_max))) {
        snprintf(message, size, "end stops need theta0_min < theta0_max, got %g and %g",
                 R(theta0_min), R(theta0_max));
        return 1;
    }
    return 0;
}
