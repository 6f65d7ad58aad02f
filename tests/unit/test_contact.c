/* The contact module: the broad phase finds exactly the overlapping box pairs (against all pairs tested directly),
 * once each, in its stated order, allocating nothing once warm; the pairs across a split are the crossing ones in
 * the same order; bad boxes are refused; group/mask bits; a particle lattice as a surface. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact.h"

static bool overlap(const double *p, const double *q)
{
    for (int c = 0; c < 3; c++)
        if (p[c] > q[3 + c] || q[c] > p[3 + c]) return false;
    return true;
}

/* n random boxes of edge up to `size` in a cube of edge `extent`, some touching exactly (shared faces). */
static void random_boxes(DrRng *rng, int n, double extent, double size, double *box)
{
    for (int i = 0; i < n; i++) {
        for (int a = 0; a < 3; a++) {
            double lo = dr_rng_uniform(rng) * extent - 0.5 * extent;
            box[6 * i + a] = lo;
            box[6 * i + 3 + a] = lo + dr_rng_uniform(rng) * size;
        }
        if (i > 0 && i % 7 == 0) { /* moved to touch the previous box's high x face */
            double shift = box[6 * (i - 1) + 3] - box[6 * i];
            box[6 * i] += shift;
            box[6 * i + 3] += shift;
        }
    }
}

static void check_against_all_pairs(int n, double extent, double size, double cell, uint64_t seed)
{
    DrRng rng;
    dr_rng_seed(&rng, seed);
    double *box = malloc(6 * sizeof(double) * (size_t)n);
    random_boxes(&rng, n, extent, size, box);
    DrBroadPhase *bp = NULL;
    DrError err;
    assert_int_equal(dr_broad_phase_create(&bp, &err), DR_OK);
    for (int i = 0; i < n; i++)
        assert_int_equal(dr_broad_phase_add(bp, dr_v3(box[6 * i], box[6 * i + 1], box[6 * i + 2]),
                                            dr_v3(box[6 * i + 3], box[6 * i + 4], box[6 * i + 5]), &err),
                         DR_OK);
    assert_int_equal(dr_broad_phase_count(bp), n);
    const DrBroadPair *pairs = NULL;
    long np = 0;
    assert_int_equal(dr_broad_phase_pairs(bp, cell, &pairs, &np, &err), DR_OK);
    /* every reported pair overlaps, is ordered a < b, and appears once */
    char *seen = calloc((size_t)n * (size_t)n, 1);
    for (long k = 0; k < np; k++) {
        int a = pairs[k].a, b = pairs[k].b;
        assert_true(a < b);
        assert_true(overlap(box + 6 * a, box + 6 * b));
        assert_int_equal(seen[(size_t)a * n + b], 0);
        seen[(size_t)a * n + b] = 1;
    }
    /* every overlapping pair is reported */
    long expected = 0;
    for (int a = 0; a < n; a++)
        for (int b = a + 1; b < n; b++)
            if (overlap(box + 6 * a, box + 6 * b)) {
                expected++;
                assert_int_equal(seen[(size_t)a * n + b], 1);
            }
    assert_int_equal(np, expected);
    /* the same boxes again: the same pairs in the same order, and no allocation */
    DrBroadPair *first = malloc(sizeof *first * (size_t)(np + 1));
    memcpy(first, pairs, sizeof *first * (size_t)np);
    dr_broad_phase_clear(bp);
    for (int i = 0; i < n; i++)
        assert_int_equal(dr_broad_phase_add(bp, dr_v3(box[6 * i], box[6 * i + 1], box[6 * i + 2]),
                                            dr_v3(box[6 * i + 3], box[6 * i + 4], box[6 * i + 5]), &err),
                         DR_OK);
    uint64_t before = dr_alloc_count();
    assert_int_equal(dr_broad_phase_pairs(bp, cell, &pairs, &np, &err), DR_OK);
    assert_true(dr_alloc_count() == before);
    assert_int_equal(np, expected);
    assert_memory_equal(first, pairs, sizeof *first * (size_t)np);
    free(first);
    free(seen);
    free(box);
    dr_broad_phase_destroy(&bp);
}

static void test_pairs_equal_all_pairs_tested(void **state)
{
    (void)state;
    check_against_all_pairs(400, 1.0, 0.08, 0.1, 1);   /* cell larger than every box */
    check_against_all_pairs(400, 1.0, 0.3, 0.05, 2);   /* boxes spanning many cells */
    check_against_all_pairs(200, 0.1, 0.1, 1.0, 3);    /* everything in one cell */
    check_against_all_pairs(1, 1.0, 0.1, 0.1, 4);      /* one box: no pair */
}

/* The order: cells by increasing (x, y, z), pairs within a cell by increasing box index. Two boxes in cell
   (1, 0, 0) come after two in cell (0, 5, 0), although their indices are smaller. */
static void test_pair_order(void **state)
{
    (void)state;
    DrBroadPhase *bp = NULL;
    DrError err;
    assert_int_equal(dr_broad_phase_create(&bp, &err), DR_OK);
    assert_int_equal(dr_broad_phase_add(bp, dr_v3(1.1, 0.1, 0.1), dr_v3(1.2, 0.2, 0.2), &err), DR_OK); /* 0 */
    assert_int_equal(dr_broad_phase_add(bp, dr_v3(1.15, 0.1, 0.1), dr_v3(1.3, 0.2, 0.2), &err), DR_OK); /* 1 */
    assert_int_equal(dr_broad_phase_add(bp, dr_v3(0.1, 5.1, 0.1), dr_v3(0.2, 5.2, 0.2), &err), DR_OK); /* 2 */
    assert_int_equal(dr_broad_phase_add(bp, dr_v3(0.1, 5.1, 0.1), dr_v3(0.2, 5.2, 0.2), &err), DR_OK); /* 3 */
    assert_int_equal(dr_broad_phase_add(bp, dr_v3(9, 9, 9), dr_v3(9.1, 9.1, 9.1), &err), DR_OK);       /* 4: alone */
    const DrBroadPair *p = NULL;
    long n = 0;
    assert_int_equal(dr_broad_phase_pairs(bp, 1.0, &p, &n, &err), DR_OK);
    assert_int_equal(n, 2);
    assert_int_equal(p[0].a, 2);
    assert_int_equal(p[0].b, 3);
    assert_int_equal(p[1].a, 0);
    assert_int_equal(p[1].b, 1);
    dr_broad_phase_destroy(&bp);
}

/* Pairs across a split: exactly the full query's pairs with a < split ≤ b, in the full query's order, for splits at
   both ends and inside, with points (lo = hi) among the boxes; a repeat allocates nothing; a bad cell is refused. */
static void check_across(int n, double extent, double size, double cell, uint64_t seed)
{
    DrRng rng;
    dr_rng_seed(&rng, seed);
    double *box = malloc(6 * sizeof(double) * (size_t)n);
    random_boxes(&rng, n, extent, size, box);
    for (int i = 0; i < n; i += 3) /* every third box a point */
        for (int a = 0; a < 3; a++) box[6 * i + 3 + a] = box[6 * i + a];
    DrBroadPhase *bp = NULL;
    DrError err;
    assert_int_equal(dr_broad_phase_create(&bp, &err), DR_OK);
    for (int i = 0; i < n; i++)
        assert_int_equal(dr_broad_phase_add(bp, dr_v3(box[6 * i], box[6 * i + 1], box[6 * i + 2]),
                                            dr_v3(box[6 * i + 3], box[6 * i + 4], box[6 * i + 5]), &err),
                         DR_OK);
    const DrBroadPair *pairs = NULL;
    long np = 0;
    assert_int_equal(dr_broad_phase_pairs(bp, cell, &pairs, &np, &err), DR_OK);
    long nall = np;
    DrBroadPair *all = malloc(sizeof *all * (size_t)(nall + 1)), *want = malloc(sizeof *want * (size_t)(nall + 1));
    memcpy(all, pairs, sizeof *all * (size_t)nall);
    int splits[] = {0, 1, n / 3, n / 2, n - 1, n};
    for (size_t k = 0; k < sizeof splits / sizeof *splits; k++) {
        int split = splits[k];
        long nwant = 0;
        for (long q = 0; q < nall; q++)
            if (all[q].a < split && all[q].b >= split) want[nwant++] = all[q];
        assert_int_equal(dr_broad_phase_pairs_across(bp, cell, split, &pairs, &np, &err), DR_OK);
        assert_int_equal(np, nwant);
        assert_memory_equal(want, pairs, sizeof *want * (size_t)nwant);
        uint64_t before = dr_alloc_count();
        assert_int_equal(dr_broad_phase_pairs_across(bp, cell, split, &pairs, &np, &err), DR_OK);
        assert_true(dr_alloc_count() == before);
        assert_int_equal(np, nwant);
        assert_memory_equal(want, pairs, sizeof *want * (size_t)nwant);
        if (split == n / 2 && n > 10) assert_true(nwant > 0); /* the comparison is not empty */
    }
    assert_int_equal(dr_broad_phase_pairs_across(bp, -1.0, n / 2, &pairs, &np, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "cell size"));
    assert_int_equal(np, 0);
    free(want);
    free(all);
    free(box);
    dr_broad_phase_destroy(&bp);
}

static void test_pairs_across_a_split(void **state)
{
    (void)state;
    check_across(400, 1.0, 0.08, 0.1, 5); /* cell larger than every box */
    check_across(400, 1.0, 0.3, 0.05, 6); /* boxes spanning many cells */
    check_across(200, 0.1, 0.1, 1.0, 7);  /* everything in one cell */
    check_across(1, 1.0, 0.1, 0.1, 8);    /* one box: no pair */
}

static void test_bad_boxes_and_cells(void **state)
{
    (void)state;
    DrBroadPhase *bp = NULL;
    DrError err;
    const DrBroadPair *p = NULL;
    long n = 0;
    assert_int_equal(dr_broad_phase_create(&bp, &err), DR_OK);
    assert_int_equal(dr_broad_phase_add(bp, dr_v3(0, 0, 0), dr_v3(1, 1, 1), &err), DR_OK);
    assert_int_equal(dr_broad_phase_pairs(bp, 0.0, &p, &n, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "cell size"));
    assert_int_equal(dr_broad_phase_pairs(bp, 1e-12, &p, &n, &err), DR_ERR_INPUT); /* 1e12 cells: refused */
    assert_non_null(strstr(err.message, "2^30 cells"));
    dr_broad_phase_clear(bp);
    assert_int_equal(dr_broad_phase_add(bp, dr_v3(0, NAN, 0), dr_v3(1, 1, 1), &err), DR_OK);
    assert_int_equal(dr_broad_phase_pairs(bp, 1.0, &p, &n, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "box 0"));
    dr_broad_phase_destroy(&bp);
}

static void test_shape_bits_and_boxes(void **state)
{
    (void)state;
    DrShape hair = {.kind = DR_SHAPE_SEGMENTS, .group = 1u, .mask = ~0u};
    DrShape body = {.kind = DR_SHAPE_TRIANGLES, .group = 2u, .mask = ~0u};
    DrShape shy = {.kind = DR_SHAPE_POINTS, .group = 4u, .mask = 4u}; /* meets only its own group */
    assert_true(dr_shape_pair_allowed(&hair, &body));
    assert_false(dr_shape_pair_allowed(&hair, &shy));
    assert_false(dr_shape_pair_allowed(&shy, &body));
    assert_true(dr_shape_pair_allowed(&shy, &shy));
    const double x[] = {0, 0, 0, 1, 2, 3, -1, 0.5, 0};
    const int tri[] = {0, 1, 2}, seg[] = {2, 1};
    DrShape t = {.kind = DR_SHAPE_TRIANGLES, .x = x, .nverts = 3, .elements = tri, .nelements = 1};
    DrShape s = {.kind = DR_SHAPE_SEGMENTS, .x = x, .nverts = 3, .elements = seg, .nelements = 1};
    DrShape pt = {.kind = DR_SHAPE_POINTS, .x = x, .nverts = 3, .nelements = 3};
    DrVec3 lo, hi;
    dr_shape_element_box(&t, 0, 0.5, &lo, &hi);
    assert_true(lo.x == -1.5 && lo.y == -0.5 && lo.z == -0.5 && hi.x == 1.5 && hi.y == 2.5 && hi.z == 3.5);
    dr_shape_element_box(&s, 0, 0.0, &lo, &hi);
    assert_true(lo.x == -1 && lo.y == 0.5 && lo.z == 0 && hi.x == 1 && hi.y == 2 && hi.z == 3);
    dr_shape_element_box(&pt, 1, 0.0, &lo, &hi);
    assert_true(lo.x == 1 && hi.x == 1 && lo.z == 3 && hi.z == 3);
}

/* A particle lattice as a surface: a slab of 10 × 3 × 10 particles of spacing s (radius s/2). Above its top face,
   outside the surface and within 1.6r of it, the field is the height above the face at r over the top particles'
   centres to within 0.1 r, wherever over the face (above a particle or between particles), with the normal within
   0.05 rad of straight up and the particles' velocity; far
   away it is +∞; a rebuild of the same size allocates nothing. */
static void test_point_field_flat_face(void **state)
{
    (void)state;
    enum { NX = 10, NY = 3, NZ = 10, N = NX * NY * NZ };
    double s = 0.01, r = 0.5 * s;
    static double x[3 * N], v[3 * N], vol[N];
    for (int i = 0, p = 0; i < NX; i++)
        for (int j = 0; j < NY; j++)
            for (int k = 0; k < NZ; k++, p++) {
                x[3 * p] = (i + 0.5) * s;
                x[3 * p + 1] = (j + 0.5) * s;
                x[3 * p + 2] = (k + 0.5) * s;
                v[3 * p] = 0.1, v[3 * p + 1] = -0.2, v[3 * p + 2] = 0.3;
                vol[p] = s * s * s;
            }
    DrPointField *pf = NULL;
    DrError err;
    assert_int_equal(dr_point_field_create(&pf, &err), DR_OK);
    assert_int_equal(dr_point_field_build(pf, N, x, v, vol, &err), DR_OK);
    double top = (NY - 0.5) * s + r; /* the face: r above the top layer's centres */
    double worst = 0, tilt = 0;
    for (int a = 0; a <= 10; a++)
        for (int b = 0; b <= 10; b++) {
            /* over the middle of the face, from on it to 1.6r above it, over particles and between them */
            DrVec3 q = dr_v3(0.04 + 0.002 * a, top + 0.0008 * b, 0.05 + 0.0005 * a);
            DrVec3 n;
            double phi = dr_point_field_phi(pf, q, &n);
            worst = fmax(worst, fabs(phi - (q.y - top)));
            tilt = fmax(tilt, acos(fmin(1.0, n.y)));
            DrVec3 u = dr_point_field_velocity(pf, q);
            if (!(fabs(u.x - 0.1) < 1e-12 && fabs(u.y + 0.2) < 1e-12 && fabs(u.z - 0.3) < 1e-12)) fail_msg("velocity (%g %g %g) at (%g %g %g)", u.x, u.y, u.z, q.x, q.y, q.z);
        }
    print_message("point field over a flat face: largest error %.2e m of the height above it (r = %.0e m), normal "
                  "tilted by %.2e rad at most\n", worst, r, tilt);
    assert_true(worst < 0.1 * r); /* the kernel's mean over a lattice is flat to within this, not exactly */
    assert_true(tilt < 0.05);
    DrVec3 n;
    assert_true(isinf(dr_point_field_phi(pf, dr_v3(0.05, 1.0, 0.05), &n)));
    long before = dr_alloc_count();
    assert_int_equal(dr_point_field_build(pf, N, x, v, vol, &err), DR_OK);
    assert_int_equal(dr_alloc_count(), before);
    vol[7] = 0.0;
    assert_int_equal(dr_point_field_build(pf, N, x, v, vol, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "particle 7"));
    dr_point_field_destroy(&pf);
}

/* The triangle field against brute force: for random points near a random soup of triangles, the nearest distance,
   the nearest point's barycentric weights, the normal and the velocity match the minimum over every triangle within
   reach (the first of equally near ones); beyond reach nothing is seen. */
static double tri_distance(const double *p, const double *a, const double *b, const double *c, double w[3])
{
    /* a search over the triangle's barycentric grid, refined six times: a check independent of the field's Voronoi
       tests, exact to about 1e-7 m */
    double best = INFINITY, bu = 0, bv = 0, step = 1.0 / 32;
    for (int round = 0; round < 6; round++) {
        double cu = bu, cv = bv;
        for (int i = -32; i <= 32; i++)
            for (int j = -32; j <= 32; j++) {
                double u = (round ? cu : 0) + i * step, v = (round ? cv : 0) + j * step;
                if (u < 0 || v < 0 || u + v > 1) continue;
                double d2 = 0;
                for (int k = 0; k < 3; k++) {
                    double q = (1 - u - v) * a[k] + u * b[k] + v * c[k] - p[k];
                    d2 += q * q;
                }
                if (d2 < best) best = d2, bu = u, bv = v;
            }
        step /= 16;
    }
    w[0] = 1 - bu - bv, w[1] = bu, w[2] = bv;
    return sqrt(best);
}

static void test_tri_field_nearest(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 7);
    enum { NT = 60 };
    double x[9 * NT], v[9 * NT];
    int tri[3 * NT];
    for (int i = 0; i < 9 * NT; i++) x[i] = dr_rng_uniform(&rng) * 0.3, v[i] = dr_rng_uniform(&rng) - 0.5;
    for (int t = 0; t < NT; t++) /* small triangles: each vertex within 5 cm of the first */
        for (int k = 1; k < 3; k++)
            for (int a = 0; a < 3; a++) x[9 * t + 3 * k + a] = x[9 * t + a] + 0.1 * (dr_rng_uniform(&rng) - 0.5);
    for (int i = 0; i < 3 * NT; i++) tri[i] = i;
    DrTriField *tf = NULL;
    DrError e;
    assert_int_equal(dr_tri_field_create(&tf, &e), DR_OK);
    const double reach = 0.04;
    assert_int_equal(dr_tri_field_build(tf, NT, tri, x, v, reach, &e), DR_OK);
    int seen = 0;
    for (int q = 0; q < 400; q++) {
        double p[3] = {dr_rng_uniform(&rng) * 0.4 - 0.05, dr_rng_uniform(&rng) * 0.4 - 0.05,
                       dr_rng_uniform(&rng) * 0.4 - 0.05};
        double best = INFINITY, bw[3] = {0, 0, 0};
        int bt = -1;
        for (int t = 0; t < NT; t++) {
            double w[3];
            double d = tri_distance(p, x + 9 * t, x + 9 * t + 3, x + 9 * t + 6, w);
            if (d < best - 1e-9) best = d, bt = t, memcpy(bw, w, sizeof bw);
        }
        DrVec3 n;
        double phi = dr_tri_field_phi(tf, dr_v3(p[0], p[1], p[2]), &n);
        double w[3];
        int t = dr_tri_field_nearest(tf, dr_v3(p[0], p[1], p[2]), w);
        if (best >= reach) { /* not seen beyond reach (or just within it: either way no nearer triangle) */
            if (best > reach * (1 + 1e-6)) assert_true(t < 0 && isinf(phi));
            continue;
        }
        seen++;
        assert_int_equal(t, bt);
        assert_true(phi <= best + 1e-15 && phi > best - 1e-9); /* never farther than the dense search's point */
        double c[3], len = 0;
        for (int a = 0; a < 3; a++) { /* the same nearest point (its weights are ill-conditioned on thin triangles) */
            c[a] = w[0] * x[9 * t + a] + w[1] * x[9 * t + 3 + a] + w[2] * x[9 * t + 6 + a];
            double cb = bw[0] * x[9 * t + a] + bw[1] * x[9 * t + 3 + a] + bw[2] * x[9 * t + 6 + a];
            assert_true(fabs(c[a] - cb) < 1e-5); /* the search converges to ~1e-7 m */
            len += (p[a] - c[a]) * (p[a] - c[a]);
        }
        len = sqrt(len);
        assert_true(fabs(n.x - (p[0] - c[0]) / len) < 1e-9 && fabs(n.y - (p[1] - c[1]) / len) < 1e-9 &&
                    fabs(n.z - (p[2] - c[2]) / len) < 1e-9);
        DrVec3 u = dr_tri_field_velocity(tf, dr_v3(p[0], p[1], p[2]));
        double ue[3];
        for (int a = 0; a < 3; a++) ue[a] = w[0] * v[9 * t + a] + w[1] * v[9 * t + 3 + a] + w[2] * v[9 * t + 6 + a];
        assert_true(fabs(u.x - ue[0]) < 1e-12 && fabs(u.y - ue[1]) < 1e-12 && fabs(u.z - ue[2]) < 1e-12);
    }
    print_message("%d of 400 points within reach matched the brute force\n", seen);
    assert_true(seen > 50);
    dr_tri_field_destroy(&tf);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_pairs_equal_all_pairs_tested),
        cmocka_unit_test(test_pair_order),
        cmocka_unit_test(test_pairs_across_a_split),
        cmocka_unit_test(test_bad_boxes_and_cells),
        cmocka_unit_test(test_shape_bits_and_boxes),
        cmocka_unit_test(test_point_field_flat_face),
        cmocka_unit_test(test_tri_field_nearest),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
