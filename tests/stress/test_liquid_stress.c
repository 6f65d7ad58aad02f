/* Stress: the liquid solver at the edge of stability (cfl 5, few substeps, 50 m/s into a wall, a very
 * viscous liquid) must stay finite, keep every particle in the domain and not gain energy. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "liquid/liquid.h"

static void test_fast_viscous_impact(void **state)
{
    (void)state;
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = dr_v3(1.0, 0.5, 0.25);
    d.dx = 1.0 / 32.0;
    d.cfl = 5.0;
    d.max_substeps = 4;
    d.viscosity = 1e3; /* ν = 1 m²/s: explicit limit dx²/6ν ≈ 1.6e-4 s, far below the substeps taken */
    DrBoxVel water = {dr_v3(0.3, 0.0, 0.0), dr_v3(0.6, 0.25, 0.25), dr_v3(50.0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, NULL, 0, &liq, &err), DR_OK);
    double m, ke0;
    dr_liquid_totals(liq, &m, NULL, NULL, &ke0);
    const DrLiquidState *s = dr_liquid_state(liq);
    double pe0 = 0.0, ymin = d.domain_lo.y;
    for (long p = 0; p < s->n; p++) pe0 += dr_liquid_particle_mass(liq) * 9.81 * (s->x[3 * p + 1] - ymin);
    for (int f = 0; f < 12; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, NULL, 0, f / 24.0, (f + 1) / 24.0, &st, &err), DR_OK);
        assert_true(st.substeps <= d.max_substeps);
        double ke;
        dr_liquid_totals(liq, NULL, NULL, NULL, &ke);
        assert_true(isfinite(ke));
        for (long p = 0; p < s->n; p++) {
            for (int a = 0; a < 3; a++) {
                assert_true(isfinite(s->x[3 * p + a]) && isfinite(s->v[3 * p + a]));
                assert_true(s->x[3 * p + a] >= dr_v3_get(d.domain_lo, a) && s->x[3 * p + a] <= dr_v3_get(d.domain_hi, a));
            }
        }
        /* energy bound: initial kinetic + the potential energy available above the floor; 1 % tolerance
           for the transfer's round-off and the clamped substeps */
        assert_true(ke <= 1.01 * (ke0 + pe0));
        printf("frame %d: substeps %d, KE %.4g J (bound %.4g J), max speed %.3g m/s\n", f, st.substeps, ke,
               ke0 + pe0, st.max_speed);
    }
    dr_liquid_destroy(&liq);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_fast_viscous_impact)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
