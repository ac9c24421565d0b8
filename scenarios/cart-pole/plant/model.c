/* Cart-pole (Quanser IP02 + SIP): the cart x_c driven by the force F of a DC motor through a
 * gearbox and a pinion on the track's rack, the pendulum alpha (0 upright) free on the cart.
 *
 * Lagrange's equations with the pendulum's centre of mass at (x_c + l_p sin alpha, l_p cos alpha):
 *   (M_eq + M_p) x'' + M_p l_p cos(alpha) alpha'' = F - B_eq x' + M_p l_p sin(alpha) alpha'^2 + F_d
 *   M_p l_p cos(alpha) x'' + (J_p + M_p l_p^2) alpha'' = M_p g l_p sin(alpha) - B_p alpha' + tau_d
 * with the rotor's inertia reflected to the cart, M_eq = M_c + eta_g K_g^2 J_m / r_mp^2, and the
 * motor's force with its inductance neglected (as the manual's model does):
 *   F = eta_g K_g eta_m K_t (V - K_g K_m x' / r_mp) / (R_m r_mp). */
#include <math.h>
#include <stdio.h>

#include "model_api.h"

void model_derivatives(const ModelValues *values, const double *x, double *dx) {
    const double dx_c = x[1], alpha = x[2], dalpha = x[3];
    const double s = sin(alpha), c = cos(alpha);
    const double Kg = R(K_g), r = R(r_mp), mp = R(M_p), lp = R(l_p);
    double V = R(V);
    double force, m11, m12, m22, rhs0, rhs1, det;

    if (R(V_max) > 0.0) V = fmax(-R(V_max), fmin(R(V_max), V));
    force = R(eta_g) * Kg * R(eta_m) * R(K_t) * (V - Kg * R(K_m) * dx_c / r) / (R(R_m) * r);

    m11 = R(M_c) + R(eta_g) * Kg * Kg * R(J_m) / (r * r) + mp;
    m12 = mp * lp * c;
    m22 = R(J_p) + mp * lp * lp;
    rhs0 = force - R(B_eq) * dx_c + mp * lp * s * dalpha * dalpha + R(F_d);
    rhs1 = mp * R(g) * lp * s - R(B_p) * dalpha + R(tau_d);
    det = m11 * m22 - m12 * m12;   /* > 0: m11 > mp and m22 > mp lp^2 */

    dx[0] = dx_c;
    dx[1] = (m22 * rhs0 - m12 * rhs1) / det;
    dx[2] = dalpha;
    dx[3] = (m11 * rhs1 - m12 * rhs0) / det;
}

/* no electrical state: the mechanics' time constants are tens of ms, far above any substep */
double model_fastest(const ModelValues *values) { (void)values; return 0.0; }

void model_outputs(ModelValues *values) { (void)values; }

int model_check(const ModelValues *values, char *message, size_t size) {
    if (R(eta_g) > 1.0 || R(eta_m) > 1.0) {
        snprintf(message, size, "efficiencies eta_g = %g and eta_m = %g must be <= 1", R(eta_g), R(eta_m));
        return 1;
    }
    if (R(B_eq) < 0.0 || R(B_p) < 0.0 || R(V_max) < 0.0) {
        snprintf(message, size, "B_eq = %g, B_p = %g and V_max = %g must be >= 0", R(B_eq), R(B_p), R(V_max));
        return 1;
    }
    return 0;
}
