/* What a user sees of a collider with an enclosed cavity: a closed block with a spherical hollow
 * (tests/data/cavity_block.obj, scaled to a 0.4 m block with a hollow of radius 0.12 m) whose liquid
 * source covers the whole block. Liquid is seeded in the hollow and nowhere in the block's material.
 * Before the collider SDF counted crossings, OpenVDB's flood fill made the hollow solid and no
 * particle was seeded at all. Run from the repository root. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "liquid/liquid.h"
#include "scene/scene.h"
#include "world/world.h"

#define SCENE "tests/data/collider_cavity.json"

static const DrVec3 kCentre = {0.3, 0.3, 0.3};
static const double kHalf = 0.2;    /* half the block's edge, m */
static const double kHollow = 0.12; /* the hollow's radius, m */

/* Signed distance to the block less the hollow, negative in the material. */
static double tank_exact(DrVec3 x)
{
    const DrVec3 p = dr_v3_sub(x, kCentre);
    const double q[3] = {fabs(p.x) - kHalf, fabs(p.y) - kHalf, fabs(p.z) - kHalf};
    double out2 = 0.0, in = -1e300;
    for (int a = 0; a < 3; a++) {
        if (q[a] > 0) out2 += q[a] * q[a];
        if (q[a] > in) in = q[a];
    }
    const double box = sqrt(out2) + (in < 0 ? in : 0.0);
    return fmax(box, kHollow - dr_v3_norm(p));
}

static void test_liquid_fills_the_hollow_not_the_material(void **state)
{
    (void)state;
    DrScene *scene = NULL;
    DrWorld *w = NULL;
    DrError err;
    const double t0 = dr_time_now();
    if (dr_scene_load(SCENE, &scene, &err) < 0) fail_msg("%s: %s", SCENE, err.message);
    if (dr_world_create(scene, &w, &err) < 0) fail_msg("%s: %s", SCENE, err.message);
    const double t1 = dr_time_now();
    assert_int_equal(dr_world_live_collider_count(w), 1);

    const DrLiquid *liq = dr_world_liquid(w, 0);
    const DrLiquidState *st = dr_liquid_state(liq);
    const double cell = dr_liquid_grid(liq)->dx, sdf_dx = 0.5 * cell; /* the world's collider SDF spacing */
    long hollow = 0, material = 0, outside = 0;
    double deepest = 0.0; /* most negative exact distance of a particle, m */
    for (long p = 0; p < st->n; p++) {
        const DrVec3 x = dr_v3(st->x[3 * p], st->x[3 * p + 1], st->x[3 * p + 2]);
        const double e = tank_exact(x);
        deepest = fmin(deepest, e);
        if (dr_v3_norm(dr_v3_sub(x, kCentre)) < kHollow) hollow++;
        else if (e < 0.0) material++;
        else outside++;
    }
    /* 8 particles per cell, so the hollow's volume holds this many candidates */
    const double expected = 4.0 / 3.0 * DR_PI * kHollow * kHollow * kHollow / (cell * cell * cell) * 8.0;
    print_message("%ld particles: %ld in the hollow (its volume holds %.0f), %ld in the material (deepest %.4f m), "
                  "%ld outside the block; world built in %.2f s\n",
                  st->n, hollow, expected, material, deepest, outside, t1 - t0);

    /* The seeding rejects candidates where the collider's trilinearly interpolated SDF is negative.
     * Within a voxel of the hollow's wall the interpolated field and the icosphere (up to 0.2 % of
     * the radius inside the sphere) differ from the analytic solid by a fraction of an SDF voxel, so
     * a particle may sit there; none lies a whole voxel deep in the material. */
    assert_true(deepest > -sdf_dx);
    assert_int_equal(outside, 0); /* the source box is the block */
    /* Candidates in the hollow are kept unless within a fraction of a voxel of its wall. */
    assert_true(hollow > 0.85 * expected && hollow < 1.05 * expected);

    dr_world_destroy(&w);
    dr_scene_destroy(&scene);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_liquid_fills_the_hollow_not_the_material),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
