/* Unit tests of src/stage helpers that need no scene file: the radius along tapered strands. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "stage/stage.h"

/* Radii as the rod set tapers its strands: the root's radius at the root, the tip's at the tip, linear in arc
 * length between (uneven edges: by length, not by vertex count); untapered strands (tip 0, or a tip equal to the
 * root) keep the strand's radius exactly; a strand of no length keeps its root's. */
static void test_vertex_radii(void **state)
{
    (void)state;
    /* strand 0: edges of 1, 3 and 4 m along x (total 8); strand 1: two vertices at one point */
    double x[3 * 6] = {0, 0, 0, 1, 0, 0, 4, 0, 0, 8, 0, 0, 2, 2, 2, 2, 2, 2};
    int off[3] = {0, 4, 6};
    double r[2] = {1e-4, 3e-5}, out[6];
    dr_stage_vertex_radii(x, off, 2, r, 2e-5, out);
    double want[4] = {1e-4, 1e-4 - 8e-5 / 8, 1e-4 - 8e-5 * 4 / 8, 2e-5};
    for (int i = 0; i < 4; i++) assert_true(fabs(out[i] - want[i]) <= 1e-15 * 1e-4); /* a few roundings of 1e-4 */
    assert_true(out[4] == 3e-5 && out[5] == 3e-5);
    dr_stage_vertex_radii(x, off, 2, r, 0.0, out);
    for (int i = 0; i < 4; i++) assert_true(out[i] == 1e-4);
    assert_true(out[4] == 3e-5 && out[5] == 3e-5);
    double same[2] = {2e-5, 2e-5};
    dr_stage_vertex_radii(x, off, 2, same, 2e-5, out);
    for (int i = 0; i < 6; i++) assert_true(out[i] == 2e-5);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_vertex_radii),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
