/* Validation of the liquid's collider boundary (src/liquid): still water stays still next to static
 * colliders of several shapes and inside a tank that is a collider, for both pressure formulations; a
 * closed collider moving at constant velocity carries its liquid exactly; no particle is ever inside a
 * collider through a dam break on an obstacle. Colliders are analytic signed distance fields sampled at
 * half the liquid's cell, as the world samples collider meshes. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <cmocka.h>

#include "liquid/liquid.h"

/* ---- analytic shapes (negative inside the solid) ------------------------------------------------ */

typedef enum Shape { SPHERE, BOWL, BOX, TANK, HOLLOW_BOX } Shape;
typedef struct ShapeDesc {
    Shape kind;
    DrVec3 c;           /* centre */
    DrVec3 h;           /* box half extents (BOX, TANK outer, HOLLOW_BOX outer) */
    double r;           /* sphere / bowl cavity radius */
    double wall;        /* TANK and HOLLOW_BOX wall thickness */
    double rot_z;       /* BOX rotation about z, radians */
} ShapeDesc;

static double box_sdf(DrVec3 p, DrVec3 c, DrVec3 h)
{
    double outside = 0.0, inside = -INFINITY;
    for (int d = 0; d < 3; d++) {
        double q = fabs(dr_v3_get(p, d) - dr_v3_get(c, d)) - dr_v3_get(h, d);
        if (q > 0) outside += q * q;
        if (q > inside) inside = q;
    }
    return outside > 0 ? sqrt(outside) : inside;
}

static double shape_sdf(const ShapeDesc *s, DrVec3 p)
{
    switch (s->kind) {
    case SPHERE: return dr_v3_norm(dr_v3_sub(p, s->c)) - s->r;
    case BOWL: /* a block whose top face has a hemispherical hollow of radius r centred on it */
        return fmax(box_sdf(p, s->c, s->h), -(dr_v3_norm(dr_v3_sub(p, dr_v3(s->c.x, s->c.y + s->h.y, s->c.z))) - s->r));
    case BOX: {
        double cz = cos(-s->rot_z), sz = sin(-s->rot_z);
        DrVec3 d = dr_v3_sub(p, s->c);
        DrVec3 q = dr_v3(cz * d.x - sz * d.y, sz * d.x + cz * d.y, d.z);
        return box_sdf(q, dr_v3(0, 0, 0), s->h);
    }
    case TANK: { /* walls and floor of thickness `wall`, open at the top */
        DrVec3 ih = dr_v3(s->h.x - s->wall, s->h.y, s->h.z - s->wall);
        DrVec3 ic = dr_v3(s->c.x, s->c.y + s->wall, s->c.z);
        return fmax(box_sdf(p, s->c, s->h), -box_sdf(p, ic, ih));
    }
    case HOLLOW_BOX: { /* closed on every side */
        DrVec3 ih = dr_v3(s->h.x - s->wall, s->h.y - s->wall, s->h.z - s->wall);
        return fmax(box_sdf(p, s->c, s->h), -box_sdf(p, s->c, ih));
    }
    }
    return INFINITY;
}

/* The shape sampled at spacing h over [lo, hi] with a margin of 3h (rest frame), moving by keys. */
static DrCollider *make_shape(const ShapeDesc *s, DrVec3 lo, DrVec3 hi, double h, int nkeys, const double *keys,
                              bool no_slip)
{
    DrVec3 o = dr_v3_sub(lo, dr_v3(3 * h, 3 * h, 3 * h));
    int n[3];
    for (int d = 0; d < 3; d++) n[d] = (int)ceil((dr_v3_get(hi, d) - dr_v3_get(lo, d)) / h) + 7;
    float *phi = malloc(sizeof(float) * (size_t)n[0] * n[1] * n[2]);
    assert_non_null(phi);
    for (int k = 0; k < n[2]; k++)
        for (int j = 0; j < n[1]; j++)
            for (int i = 0; i < n[0]; i++)
                phi[i + n[0] * (j + n[1] * k)] = (float)shape_sdf(s, dr_v3_add(o, dr_v3(i * h, j * h, k * h)));
    DrColliderDesc cd = {phi, n[0], n[1], n[2], o, h, 0.0, no_slip, 0.0, nkeys, keys};
    DrCollider *c = NULL;
    DrError err;
    assert_int_equal(dr_collider_create(&cd, &c, &err), DR_OK);
    free(phi);
    return c;
}

static double max_speed(const DrLiquidState *s)
{
    double m = 0.0;
    for (long p = 0; p < s->n; p++) {
        const double *v = s->v + 3 * p;
        double sp = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if (!(sp <= m)) m = sp;
    }
    return m;
}

/* Particles with phi < 0 of any collider at time t. */
static long count_inside(const DrLiquidState *s, const DrCollider *const *cols, int ncols, double t)
{
    long in = 0;
    for (long p = 0; p < s->n; p++) {
        DrVec3 x = dr_v3(s->x[3 * p], s->x[3 * p + 1], s->x[3 * p + 2]);
        for (int c = 0; c < ncols; c++)
            if (dr_collider_phi(cols[c], t, x, NULL) < 0.0) { in++; break; }
    }
    return in;
}

/* ---- 1. hydrostatic rest next to static colliders ---------------------------------------------------
 * A pool at rest, 2 s at 24 fps with CFL 1 and the grid velocity CFL of liquid.h: max |v_p| must stay
 * below 1e-3 m/s and every frame must take one substep. Gravity adds 9.81·Δt ≈ 0.41 m/s to every face
 * each substep, so the bound demands that the projection cancel it to 2.5e-3 relative everywhere next to
 * the collider (cut cells, cut cells without particles, the contact line where the free surface meets the
 * collider). The pool's surface lies on a face layer (as in test_liquid's tank) so that the particle-count
 * level set is exactly flat. Ghost fluid uses fully jittered seeding; the mass-weighted projection uses
 * jitter 0, the seeding under which its face densities are uniform (liquid.h: with jitter they are not,
 * even without colliders). */
typedef struct PoolCase {
    const char *name;
    ShapeDesc shape;
    DrVec3 domain_hi;
    DrVec3 water_lo, water_hi; /* source box; the collider's inside is never seeded */
} PoolCase;

static void run_pool(const PoolCase *pc, DrPressureFormulation pressure)
{
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.dx = 0.02;
    d.domain_hi = pc->domain_hi;
    d.pressure = pressure;
    d.jitter = pressure == DR_PRESSURE_GHOST_FLUID ? 1.0 : 0.0;
    d.pressure_tol = 1e-8;
    d.viscosity = 0.0;
    DrBoxVel water = {pc->water_lo, pc->water_hi, dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    DrCollider *col = make_shape(&pc->shape, dr_v3(0, 0, 0), pc->domain_hi, 0.5 * d.dx, 0, NULL, false);
    const DrCollider *cols[1] = {col};
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, cols, 1, &liq, &err), DR_OK);
    const DrLiquidState *s = dr_liquid_state(liq);
    long n0 = s->n;
    assert_true(n0 > 1000);
    assert_int_equal(count_inside(s, cols, 1, 0.0), 0);
    double worst = 0.0;
    int substeps_max = 0, iters = 0;
    for (int f = 0; f < 48; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, cols, 1, f / 24.0, (f + 1) / 24.0, &st, &err), DR_OK);
        assert_int_equal(st.pressure_not_converged, 0);
        if (st.substeps > substeps_max) substeps_max = st.substeps;
        if (st.pressure_iterations_max > iters) iters = st.pressure_iterations_max;
        s = dr_liquid_state(liq);
        double m = max_speed(s);
        if (m > worst) worst = m;
    }
    long inside = count_inside(s, cols, 1, 2.0);
    printf("pool %-12s (%s): %ld particles, substeps per frame <= %d, PCG <= %d, max |v| over 2 s %.3e m/s, "
           "inside %ld\n",
           pc->name, pressure == DR_PRESSURE_GHOST_FLUID ? "ghost fluid" : "mass weighted", n0, substeps_max, iters,
           worst, inside);
    assert_int_equal(s->n, n0);
    assert_int_equal(inside, 0);
    assert_true(worst < 1e-3);
    assert_int_equal(substeps_max, 1);
    dr_liquid_destroy(&liq);
    dr_collider_destroy(&col);
}

/* The cases: 0.4 m tanks of 20 cells; pools 0.2 m deep (10 cells: the surface on a face layer). */
static const PoolCase POOLS[] = {
    {"sphere", {SPHERE, {0.2, 0.1, 0.2}, {0, 0, 0}, 0.07, 0, 0}, {0.4, 0.32, 0.4}, {0, 0, 0}, {0.4, 0.2, 0.4}},
    /* the bowl's rim at y = 0.3, its hollow holding water up to y = 0.24: the surface meets the curved wall */
    {"bowl", {BOWL, {0.2, 0.15, 0.2}, {0.2, 0.15, 0.2}, 0.16, 0, 0}, {0.4, 0.4, 0.4}, {0, 0.1, 0}, {0.4, 0.24, 0.4}},
    /* a box at 30° about z piercing the surface */
    {"box_30deg", {BOX, {0.2, 0.14, 0.2}, {0.1, 0.05, 0.1}, 0, 0, 30.0 * DR_PI / 180.0}, {0.4, 0.32, 0.4}, {0, 0, 0},
     {0.4, 0.2, 0.4}},
    /* plates one cell and about half a cell thick (0.55: no seeding point lies on its surface, where the sign
       of the interpolated phi is round-off), one lying under water, one standing through the surface */
    {"plate_flat", {BOX, {0.2, 0.1, 0.2}, {0.12, 0.01, 0.12}, 0, 0, 0}, {0.4, 0.32, 0.4}, {0, 0, 0}, {0.4, 0.2, 0.4}},
    {"plate_upright", {BOX, {0.2, 0.15, 0.2}, {0.0055, 0.12, 0.14}, 0, 0, 0}, {0.4, 0.32, 0.4}, {0, 0, 0},
     {0.4, 0.2, 0.4}},
    /* a tank that is a collider, standing inside a larger domain: walls and floor 2 cells thick */
    {"tank", {TANK, {0.24, 0.16, 0.24}, {0.2, 0.14, 0.2}, 0, 0.04, 0}, {0.48, 0.4, 0.48}, {0.08, 0.06, 0.08},
     {0.40, 0.26, 0.40}},
};

#define POOL_TEST(idx, fname)                                                                                  \
    static void fname(void **state)                                                                            \
    {                                                                                                          \
        (void)state;                                                                                           \
        run_pool(&POOLS[idx], DR_PRESSURE_GHOST_FLUID);                                                        \
        run_pool(&POOLS[idx], DR_PRESSURE_MASS_WEIGHTED);                                                      \
    }
POOL_TEST(0, test_pool_sphere)
POOL_TEST(1, test_pool_bowl)
POOL_TEST(2, test_pool_box_30deg)
POOL_TEST(3, test_pool_plate_flat)
POOL_TEST(4, test_pool_plate_upright)
POOL_TEST(5, test_pool_tank)

/* ---- 2. a closed collider carrying liquid ---------------------------------------------------------------
 * A closed box (walls two cells thick) half full of liquid moves at a constant (1, 0.5, -0.25) m/s in zero
 * gravity, the liquid starting at the box's velocity: it must move with the box, every particle's velocity
 * relative to the box below 1e-3 m/s, and stay inside it. */
static void test_moving_closed_box(void **state)
{
    (void)state;
    DrVec3 V = dr_v3(1.0, 0.5, -0.25);
    for (int form = 0; form < 2; form++) {
        DrLiquidDesc d;
        dr_liquid_desc_default(&d);
        d.dx = 0.02;
        d.domain_hi = dr_v3(1.2, 0.8, 0.8);
        d.gravity = dr_v3(0, 0, 0);
        d.viscosity = 0.0;
        d.pressure = form ? DR_PRESSURE_MASS_WEIGHTED : DR_PRESSURE_GHOST_FLUID;
        d.pressure_tol = 1e-8;
        ShapeDesc box = {HOLLOW_BOX, {0.2, 0.3, 0.5}, {0.14, 0.14, 0.14}, 0, 0.04, 0};
        /* keys: constant velocity V until t = 1 s, past the 0.5 s of the test */
        double keys[14] = {0.0, 0, 0, 0, 0, 0, 0, 1.0, V.x, V.y, V.z, 0, 0, 0};
        DrCollider *col = make_shape(&box, dr_v3(0.0, 0.1, 0.3), dr_v3(0.4, 0.5, 0.7), 0.5 * d.dx, 2, keys, false);
        const DrCollider *cols[1] = {col};
        DrBoxVel water = {dr_v3(0.1, 0.2, 0.4), dr_v3(0.3, 0.3, 0.6), V, 0, 0};
        d.nsource_boxes = 1;
        d.source_boxes = &water;
        DrLiquid *liq = NULL;
        DrError err;
        assert_int_equal(dr_liquid_create(&d, cols, 1, &liq, &err), DR_OK);
        long n0 = dr_liquid_state(liq)->n;
        assert_true(n0 > 1000);
        double worst = 0.0;
        long inside = 0;
        for (int f = 0; f < 12; f++) {
            DrLiquidStats st;
            assert_int_equal(dr_liquid_advance(liq, cols, 1, f / 24.0, (f + 1) / 24.0, &st, &err), DR_OK);
            const DrLiquidState *s = dr_liquid_state(liq);
            for (long p = 0; p < s->n; p++) {
                DrVec3 v = dr_v3_sub(dr_v3(s->v[3 * p], s->v[3 * p + 1], s->v[3 * p + 2]), V);
                double r = dr_v3_norm(v);
                if (!(r <= worst)) worst = r;
            }
            inside += count_inside(s, cols, 1, (f + 1) / 24.0);
        }
        const DrLiquidState *s = dr_liquid_state(liq);
        /* every particle is still inside the hollow, which has moved by V·0.5 s */
        DrVec3 c = dr_v3_add(box.c, dr_v3_scale(V, 0.5));
        long out = 0;
        for (long p = 0; p < s->n; p++)
            if (box_sdf(dr_v3(s->x[3 * p], s->x[3 * p + 1], s->x[3 * p + 2]), c, dr_v3(0.1, 0.1, 0.1)) > 1e-9) out++;
        printf("moving closed box (%s): %ld particles, max |v - V| over 0.5 s %.3e m/s, outside the hollow %ld, "
               "inside the walls %ld\n",
               form ? "mass weighted" : "ghost fluid", n0, worst, out, inside);
        assert_int_equal(s->n, n0);
        assert_true(worst < 1e-3);
        assert_int_equal(out, 0);
        assert_int_equal(inside, 0);
        dr_liquid_destroy(&liq);
        dr_collider_destroy(&col);
    }
}

/* ---- 3. no particle inside a collider, through a dam break on an obstacle ------------------------------
 * A column of water collapses onto a box standing on the floor at 30° and a sphere: after every substep
 * (advanced one substep per call: intervals of 1/480 s, shorter than the CFL step at these speeds) no
 * particle may have phi < 0 for any collider. */
static void test_dam_break_obstacles(void **state)
{
    (void)state;
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.dx = 0.025;
    d.domain_hi = dr_v3(1.0, 0.5, 0.4);
    d.cfl = 1.0;
    DrBoxVel water = {dr_v3(0, 0, 0), dr_v3(0.3, 0.4, 0.4), dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    ShapeDesc box = {BOX, {0.6, 0.05, 0.2}, {0.08, 0.1, 0.08}, 0, 0, 30.0 * DR_PI / 180.0};
    ShapeDesc ball = {SPHERE, {0.8, 0.08, 0.12}, {0, 0, 0}, 0.06, 0, 0};
    DrCollider *cb = make_shape(&box, dr_v3(0.4, -0.1, 0.05), dr_v3(0.8, 0.2, 0.35), 0.5 * d.dx, 0, NULL, false);
    DrCollider *cs = make_shape(&ball, dr_v3(0.7, 0.0, 0.04), dr_v3(0.9, 0.16, 0.2), 0.5 * d.dx, 0, NULL, true);
    const DrCollider *cols[2] = {cb, cs};
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, cols, 2, &liq, &err), DR_OK);
    long n0 = dr_liquid_state(liq)->n, worst = 0;
    int calls = 0, substeps = 0;
    double vmax = 0.0;
    for (int f = 0; f < 480; f++) { /* 1 s */
        DrLiquidStats st;
        double t1 = (f + 1) / 480.0;
        assert_int_equal(dr_liquid_advance(liq, cols, 2, f / 480.0, t1, &st, &err), DR_OK);
        calls++;
        substeps += st.substeps;
        const DrLiquidState *s = dr_liquid_state(liq);
        long in = count_inside(s, cols, 2, t1);
        if (in > worst) worst = in;
        if (st.max_speed > vmax) vmax = st.max_speed;
    }
    printf("dam break on obstacles: %ld particles, %d substeps in %d calls, max speed %.2f m/s, "
           "most particles inside a collider after a substep %ld\n",
           n0, substeps, calls, vmax, worst);
    assert_int_equal(dr_liquid_state(liq)->n, n0);
    assert_int_equal(worst, 0);
    dr_liquid_destroy(&liq);
    dr_collider_destroy(&cb);
    dr_collider_destroy(&cs);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_pool_sphere),        cmocka_unit_test(test_pool_bowl),
        cmocka_unit_test(test_pool_box_30deg),     cmocka_unit_test(test_pool_plate_flat),
        cmocka_unit_test(test_pool_plate_upright), cmocka_unit_test(test_pool_tank),
        cmocka_unit_test(test_moving_closed_box),  cmocka_unit_test(test_dam_break_obstacles),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
