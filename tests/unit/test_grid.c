/* Unit tests of src/grid: keyed collider poses, phi/gradient/velocity of a moving sphere SDF, face
 * fractions, MAC indexing and kernels. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <cmocka.h>

#include <string.h>

#include "grid/grid.h"

#define RADIUS 0.3
/* cmocka's assert_float_equal works in float: compare doubles directly */
#define NEAR(a, b, tol) assert_true(fabs((double)(a) - (double)(b)) <= (tol))
static DrCollider *sphere(int nkeys, const double *keys, double thickness)
{
    int n = 41;
    double h = 0.025; /* box [-0.5, 0.5]³ around the rest-frame origin */
    float *phi = malloc(sizeof(float) * n * n * n);
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++)
                phi[i + n * (j + n * k)] = (float)(dr_v3_norm(dr_v3(-0.5 + i * h, -0.5 + j * h, -0.5 + k * h)) - RADIUS);
    DrColliderDesc d = {phi, n, n, n, dr_v3(-0.5, -0.5, -0.5), h, 0.2, false, thickness, nkeys, keys};
    DrCollider *c = NULL;
    DrError err;
    assert_int_equal(dr_collider_create(&d, &c, &err), DR_OK);
    free(phi);
    return c;
}

static void test_pose_interpolation(void **state)
{
    (void)state;
    double keys[14] = {1.0, 0, 0, 0, 0, 0, 0, 3.0, 2.0, -4.0, 1.0, 0, 0, 1.0};
    DrCollider *c = sphere(2, keys, 0.0);
    DrXform x = dr_collider_pose(c, 2.5); /* 3/4 of the way */
    NEAR(x.t.x, 1.5, 1e-15);
    NEAR(x.t.y, -3.0, 1e-15);
    NEAR(x.t.z, 0.75, 1e-15);
    DrMat3 Rz = dr_m3_from_euler_xyz(dr_v3(0, 0, 0.75));
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) NEAR(x.R.m[i][j], Rz.m[i][j], 1e-15);
    /* constant outside the key range, zero velocity there */
    NEAR(dr_collider_pose(c, 0.0).t.x, 0.0, 0.0);
    NEAR(dr_collider_pose(c, 9.0).t.y, -4.0, 0.0);
    DrVec3 v0 = dr_collider_velocity(c, 5.0, dr_v3(1, 1, 1));
    assert_true(dr_v3_norm(v0) == 0.0);
    dr_collider_destroy(&c);
    /* invalid keys are refused */
    double bad[14] = {1.0, 0, 0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0};
    float phi[8] = {1, 1, 1, 1, 1, 1, 1, 1};
    DrColliderDesc d = {phi, 2, 2, 2, dr_v3(0, 0, 0), 1.0, 0, false, 0, 2, bad};
    DrError err;
    assert_int_equal(dr_collider_create(&d, &c, &err), DR_ERR_INPUT);
    assert_null(c);
}

static void test_moving_sphere(void **state)
{
    (void)state;
    /* translating at (1, 2, 0) m/s and spinning about z at 0.5 rad/s between t = 0 and 2 */
    double keys[14] = {0.0, 0, 0, 0, 0, 0, 0, 2.0, 2.0, 4.0, 0, 0, 0, 1.0};
    DrCollider *c = sphere(2, keys, 0.01);
    double t = 1.0;
    DrVec3 ctr = dr_v3(1.0, 2.0, 0.0);
    DrVec3 dir = dr_v3_normalize(dr_v3(0.3, -0.2, 0.5));
    for (int s = 0; s < 5; s++) {
        double r = 0.1 + 0.12 * s;
        DrVec3 x = dr_v3_add(ctr, dr_v3_scale(dir, r));
        DrVec3 g;
        double phi = dr_collider_phi(c, t, x, &g);
        /* trilinear interpolation of |x| − R on a 0.025 m lattice: error ≤ h²/(8r)·3 ≈ 1e-3 near r = 0.1 */
        NEAR(phi, r - RADIUS - 0.01, 2e-3);
        /* unit gradient points radially (central differences of a smooth field: < 2 % direction error) */
        NEAR(dr_v3_norm(g), 1.0, 1e-12);
        assert_true(dr_v3_dot(g, dir) > 0.98);
    }
    /* outside the SDF box: distance to the box plus the boundary value */
    DrVec3 far = dr_v3_add(ctr, dr_v3(0, 0, 2.0));
    NEAR(dr_collider_phi(c, t, far, NULL), 1.5 + (0.5 - RADIUS) - 0.01, 1e-6);
    /* rigid velocity v = ṫ + ω × (x − t(t)) */
    DrVec3 x = dr_v3(1.3, 2.1, 0.2);
    DrVec3 v = dr_collider_velocity(c, t, x);
    DrVec3 expect = dr_v3_add(dr_v3(1, 2, 0), dr_v3_cross(dr_v3(0, 0, 0.5), dr_v3_sub(x, ctr)));
    NEAR(v.x, expect.x, 1e-9); /* central-difference ω: O(h²) ≈ 1e-10 */
    NEAR(v.y, expect.y, 1e-9);
    NEAR(v.z, expect.z, 1e-9);
    dr_collider_destroy(&c);
}

static void test_face_fraction(void **state)
{
    (void)state;
    NEAR(dr_face_fraction_outside(1, 1, 1, 1), 1.0, 0);
    NEAR(dr_face_fraction_outside(-1, -1, -1, -1), 0.0, 0);
    /* a straight interface x = 0.25 across the unit face: φ = x − 0.25 at the corners → 3/4 outside,
       exact because φ is linear on every sub-triangle */
    NEAR(dr_face_fraction_outside(-0.25, 0.75, 0.75, -0.25), 0.75, 1e-14);
    /* a diagonal plane through the centre: half */
    NEAR(dr_face_fraction_outside(-1, 0, 1, 0), 0.5, 1e-14);
}

static void test_mac_layout_and_kernel(void **state)
{
    (void)state;
    DrMacGrid *g = NULL;
    DrError err;
    assert_int_equal(dr_mac_grid_create(3, 4, 5, 0.1, dr_v3(1, 2, 3), &g, &err), DR_OK);
    assert_int_equal(g->nfaces[0], 4 * 4 * 5);
    assert_int_equal(g->nfaces[1], 3 * 5 * 5);
    assert_int_equal(g->nfaces[2], 3 * 4 * 6);
    DrVec3 p = dr_mac_face_position(g, 1, 2, 4, 1);
    NEAR(p.x, 1.25, 1e-14);
    NEAR(p.y, 2.4, 1e-14);
    NEAR(p.z, 3.15, 1e-14);
    assert_true(g->f[1] == g->v);
    dr_mac_grid_destroy(&g);
    assert_null(g);
    assert_int_equal(dr_mac_grid_create(0, 1, 1, 0.1, dr_v3(0, 0, 0), &g, &err), DR_ERR_INPUT);
    /* quadratic B-spline: partition of unity, linear reproduction, second moment 1/4 */
    for (int i = 0; i < 50; i++) {
        double s = -3.0 + 0.137 * i;
        DrStencil3 st = dr_kernel_quadratic(s);
        double m0 = 0, m1 = 0, m2 = 0, d0 = 0;
        for (int q = 0; q < 3; q++) {
            double dxn = st.base + q - s;
            m0 += st.w[q];
            m1 += st.w[q] * dxn;
            m2 += st.w[q] * dxn * dxn;
            d0 += st.dw[q];
        }
        NEAR(m0, 1.0, 1e-14);
        NEAR(m1, 0.0, 1e-14);
        NEAR(m2, 0.25, 1e-14);
        NEAR(d0, 0.0, 1e-14);
    }
}

/* dr_collider_static: at most one key; dr_collider_id: never the same twice, also when a new collider takes
   the memory of a destroyed one (the liquid keeps static colliders' samples by id). */
/* A face coupling is sized like the grid's faces and starts as no solid: open 1, velocity 0, impulse 0. */
static void test_face_coupling(void **state)
{
    (void)state;
    DrMacGrid *g = NULL;
    DrError err;
    assert_int_equal(dr_mac_grid_create(2, 3, 4, 0.5, dr_v3(0, 0, 0), &g, &err), DR_OK);
    DrFaceCoupling *fc = NULL;
    assert_int_equal(dr_face_coupling_create(g, &fc, &err), DR_OK);
    for (int a = 0; a < 3; a++) {
        assert_int_equal(fc->nfaces[a], g->nfaces[a]);
        for (long f = 0; f < fc->nfaces[a]; f++) {
            assert_true(fc->open[a][f] == 1.0 && fc->velocity[a][f] == 0.0 && fc->impulse[a][f] == 0.0);
            fc->open[a][f] = 0.5; fc->velocity[a][f] = 2.0; fc->impulse[a][f] = 3.0;
        }
    }
    dr_face_coupling_clear(fc);
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < fc->nfaces[a]; f++)
            assert_true(fc->open[a][f] == 1.0 && fc->velocity[a][f] == 0.0 && fc->impulse[a][f] == 0.0);
    dr_face_coupling_destroy(&fc);
    assert_null(fc);
    dr_face_coupling_destroy(&fc);
    dr_mac_grid_destroy(&g);
}

static void test_static_and_id(void **state)
{
    (void)state;
    double one[7] = {0.0, 0.1, 0, 0, 0, 0, 0}, two[14] = {0.0, 0, 0, 0, 0, 0, 0, 1.0, 0.1, 0, 0, 0, 0, 0};
    DrCollider *a = sphere(0, NULL, 0.0), *b = sphere(1, one, 0.0), *c = sphere(2, two, 0.0);
    assert_true(dr_collider_static(a));
    assert_true(dr_collider_static(b));
    assert_false(dr_collider_static(c));
    uint64_t ia = dr_collider_id(a), ib = dr_collider_id(b), ic = dr_collider_id(c);
    assert_true(ia != ib && ib != ic && ia != ic);
    dr_collider_destroy(&a);
    DrCollider *d = sphere(0, NULL, 0.0);
    assert_true(dr_collider_id(d) != ia && dr_collider_id(d) != ib && dr_collider_id(d) != ic);
    dr_collider_destroy(&b);
    dr_collider_destroy(&c);
    dr_collider_destroy(&d);
}

/* Keys replaced on a collider pose it as a collider created with them, give it a new id, and bad keys are refused
   (the keys there stay). */
static void test_set_keys(void **state)
{
    (void)state;
    double one[7] = {0.0, 0.1, 0, 0, 0, 0, 0};
    double three[21] = {0.0, 0, 0, 0, 0, 0, 0, 1.0, 0.2, 0, 0, 0, 0, 0.3, 2.0, 0.2, 0.5, 0, 0.1, 0, 0.3};
    DrCollider *a = sphere(1, one, 0.0), *b = sphere(3, three, 0.0);
    uint64_t id = dr_collider_id(a);
    DrError err;
    assert_int_equal(dr_collider_set_keys(a, three, 3, &err), DR_OK);
    assert_true(dr_collider_id(a) != id);
    assert_false(dr_collider_static(a));
    for (double t = -0.5; t <= 2.5; t += 0.125) {
        DrXform xa = dr_collider_pose(a, t), xb = dr_collider_pose(b, t);
        assert_memory_equal(&xa, &xb, sizeof xa);
        DrVec3 va = dr_collider_velocity(a, t, dr_v3(0.1, 0.2, 0.3)), vb = dr_collider_velocity(b, t, dr_v3(0.1, 0.2, 0.3));
        assert_memory_equal(&va, &vb, sizeof va);
    }
    double bad[14] = {1.0, 0, 0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0};
    assert_int_equal(dr_collider_set_keys(a, bad, 2, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "increase strictly"));
    DrXform xa = dr_collider_pose(a, 1.5), xb = dr_collider_pose(b, 1.5);
    assert_memory_equal(&xa, &xb, sizeof xa);
    dr_collider_destroy(&a);
    dr_collider_destroy(&b);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_pose_interpolation), cmocka_unit_test(test_moving_sphere),
                                       cmocka_unit_test(test_face_fraction), cmocka_unit_test(test_mac_layout_and_kernel),
                                       cmocka_unit_test(test_static_and_id), cmocka_unit_test(test_set_keys),
                                       cmocka_unit_test(test_face_coupling)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
