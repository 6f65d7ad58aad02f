/* Validation of the liquid's viscosity (src/liquid/viscosity.c, liquid.c: grid_begin): the implicit, variational
 * solve (Batty & Bridson 2008) against the analytic decay of a Taylor–Green vortex, its first-order convergence in
 * the step, honey-like viscosities that move visibly differently in a dam break, and the explicit update kept for
 * viscosities within its stability limit. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <cmocka.h>
#include <stdio.h>

#include "liquid/liquid.h"

/* A box of side Lb filled with liquid (no gravity) up to Lb/4 along z (a free surface above: a box filled to its
   lid leaves the pressure only up to a constant, which PCG meets at round-off), set moving as the Taylor–Green vortex
   of the box,
     u = A (sin(πx/Lb) cos(πy/Lb), −cos(πx/Lb) sin(πy/Lb), 0):
   divergence-free, no flow through the slip walls, no shear on them, an eigenfunction of the Laplacian with
   eigenvalue −2(π/Lb)², its advection is balanced by pressure (whose ~0.6 Pa lift the free surface by well under a
   millimetre in the test's time) and it has no shear across the free surface. So it decays as exp(−2ν(π/Lb)² t)
   and its kinetic energy as exp(−4ν(π/Lb)² t). */
#define LB 0.2
static DrLiquid *make_vortex(double mu, double cfl)
{
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = dr_v3(LB, LB, LB / 2);
    d.dx = LB / 16;
    d.gravity = dr_v3(0, 0, 0);
    d.viscosity = mu;
    d.cfl = cfl;
    d.max_substeps = 100000;
    d.pressure_tol = 1e-9;
    d.volume_correction = 0.0;
    d.jitter = 0.0;
    DrBoxVel box = {d.domain_lo, dr_v3(LB, LB, LB / 4), dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &box;
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, NULL, 0, &liq, &err), DR_OK);
    DrLiquidState *s = dr_liquid_state_mut(liq);
    for (long p = 0; p < s->n; p++) {
        double x = s->x[3 * p] * M_PI / LB, y = s->x[3 * p + 1] * M_PI / LB, A = 0.05;
        s->v[3 * p] = A * sin(x) * cos(y);
        s->v[3 * p + 1] = -A * cos(x) * sin(y);
        s->v[3 * p + 2] = 0.0;
        /* the affine part of the field (APIC): C = ∇v */
        double *c = s->c + 9 * p, k = M_PI / LB;
        for (int q = 0; q < 9; q++) c[q] = 0.0;
        c[0] = A * k * cos(x) * cos(y), c[1] = -A * k * sin(x) * sin(y);
        c[3] = A * k * sin(x) * sin(y), c[4] = -A * k * cos(x) * cos(y);
    }
    return liq;
}

/* The kinetic energy ratio after T = 0.25 s, stepping by dr_liquid_advance in calls of `dt` (one substep each:
   the CFL step of 0.05 m/s at cfl 1 is 0.25 s). */
static double vortex_decay(double mu, double dt, long *visc_iterations)
{
    DrLiquid *liq = make_vortex(mu, 1.0);
    double ke0, ke;
    dr_liquid_totals(liq, NULL, NULL, NULL, &ke0);
    DrError err;
    *visc_iterations = 0;
    int n = (int)lround(0.25 / dt);
    for (int k = 0; k < n; k++) {
        DrLiquidStats st;
        DrStatus rc = dr_liquid_advance(liq, NULL, 0, k * dt, (k + 1) * dt, &st, &err);
        if (rc != DR_OK) printf("%s\n", err.message);
        assert_int_equal(rc, DR_OK);
        assert_int_equal(st.substeps, 1);
        *visc_iterations += st.viscosity_iterations;
    }
    dr_liquid_totals(liq, NULL, NULL, NULL, &ke);
    dr_liquid_destroy(&liq);
    return ke / ke0;
}

/* μ = 10 Pa·s (ν = 0.01 m²/s; the explicit limit Δx²/6ν is 2.6 ms, so steps of 12.5–50 ms are implicit): the energy
   falls to exp(−4ν(π/Lb)² T) = 0.085 in T = 0.25 s. Backward Euler's factor per step, 1/(1 + ν k² Δt)² with
   k² = 2(π/Lb)², instead of exp(−2νk²Δt), predicts 0.110, 0.098 and 0.091 at Δt = 50, 25 and 12.5 ms (the grid
   operator alone reproduces it to 1e-8: tests/unit/test_liquid_viscosity_operator.c). Measured through the particles:
   0.118, 0.105, 0.098, about 7 % above that prediction at every step (the transfers and the projection each
   substep), so 15 %, 24 % and 38 % above the analytic value, falling with the step. Asserted: within 10 % of
   backward Euler's prediction at each step, the error to the analytic decay falling as the step halves, below 20 %
   at 12.5 ms, and every step through the implicit solve. */
static void test_vortex_decay(void **state)
{
    (void)state;
    double k2 = 2.0 * (M_PI / LB) * (M_PI / LB), nu = 10.0 / 1000.0, T = 0.25;
    double exact = exp(-2.0 * nu * k2 * T);
    double err[3];
    double steps[3] = {0.05, 0.025, 0.0125};
    for (int i = 0; i < 3; i++) {
        long it;
        double r = vortex_decay(10.0, steps[i], &it);
        double be = pow(1.0 / (1.0 + nu * k2 * steps[i]), 2.0 * T / steps[i]);
        err[i] = fabs(r - exact) / exact;
        printf("Taylor-Green, mu 10 Pa s, dt %.4f s: KE ratio %.5f (analytic %.5f, backward Euler %.5f), error to "
               "the analytic %.3f, %ld viscosity iterations\n", steps[i], r, exact, be, err[i], it);
        assert_true(it > 0);
        assert_true(fabs(r - be) < 0.10 * be);
        if (i > 0) assert_true(err[i] < err[i - 1]);
    }
    assert_true(err[2] < 0.20);
}

/* Water (1e-3 Pa·s) stays on the explicit update: ν Δt/Δx² = 1e-6 · 0.04 / 1.56e-4 ≪ 1/6, no viscosity solve. */
static void test_low_viscosity_explicit(void **state)
{
    (void)state;
    long it;
    double r = vortex_decay(1e-3, 0.04, &it);
    printf("Taylor-Green, water: KE ratio %.5f, %ld viscosity iterations\n", r, it);
    assert_int_equal(it, 0);
    assert_true(r > 0.95 && r <= 1.0);
}

/* A dam break of honey-like liquids: a 0.1 × 0.1 m column (0.1 m deep) released in a 0.4 m long tank, 0.5 s. The
   front (the largest x of any particle) travels the less the more viscous the liquid. Measured front advance:
   1 Pa·s 0.21 m, 100 Pa·s 0.05 m, 10000 Pa·s 0.002 m (with the old explicit step, capped at its stability limit,
   100 and 10000 Pa·s moved identically). The test asserts strict order with a factor of 2 between neighbours and
   that 10000 Pa·s barely moves (< Δx). */
static double dam_front(double mu)
{
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = dr_v3(0.4, 0.2, 0.05);
    d.dx = 0.0125;
    d.viscosity = mu;
    d.max_substeps = 64;
    DrBoxVel box = {dr_v3(0, 0, 0), dr_v3(0.1, 0.1, 0.05), dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &box;
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, NULL, 0, &liq, &err), DR_OK);
    const DrLiquidState *s = dr_liquid_state(liq);
    double x0 = 0.0;
    for (long p = 0; p < s->n; p++) x0 = fmax(x0, s->x[3 * p]);
    long it = 0;
    for (int f = 0; f < 12; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, NULL, 0, f / 24.0, (f + 1) / 24.0, &st, &err), DR_OK);
        it += st.viscosity_iterations;
    }
    s = dr_liquid_state(liq);
    double x1 = 0.0;
    for (long p = 0; p < s->n; p++) {
        for (int a = 0; a < 3; a++) assert_true(isfinite(s->x[3 * p + a]) && isfinite(s->v[3 * p + a]));
        x1 = fmax(x1, s->x[3 * p]);
    }
    printf("dam break, mu %g Pa s: front advanced %.4f m in 0.5 s (%ld viscosity iterations)\n", mu, x1 - x0, it);
    dr_liquid_destroy(&liq);
    return x1 - x0;
}

static void test_honey_dam_break(void **state)
{
    (void)state;
    double a = dam_front(1.0), b = dam_front(100.0), c = dam_front(10000.0);
    assert_true(a > 2.0 * b);
    assert_true(b > 2.0 * c);
    assert_true(c < 0.0125);
}

int main(void)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_vortex_decay),
        cmocka_unit_test(test_low_viscosity_explicit),
        cmocka_unit_test(test_honey_dam_break),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
