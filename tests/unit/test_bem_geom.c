/* Unit tests of the surface-mesh part of src/bem (bem_geom.c): generated meshes, the validity check and its
 * messages, welding, mass properties, the frame operators of BEM eq. (10), the shape-matching weights and
 * the Hilbert vertex order. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "bem/bem.h"

#include <stdlib.h>
#include <string.h>

/* ---- helpers ---- */

static DrTriMesh ico(int level, double radius, double bump, double freq)
{
    DrTriMesh m;
    DrError err;
    assert_int_equal(dr_bem_mesh_icosphere(level, radius, bump, freq, &m, &err), DR_OK);
    return m;
}

static DrTriMesh box(double x0, double y0, double z0, double x1, double y1, double z1, int nx, int ny, int nz)
{
    const double lo[3] = {x0, y0, z0}, hi[3] = {x1, y1, z1};
    const int n[3] = {nx, ny, nz};
    DrTriMesh m;
    DrError err;
    assert_int_equal(dr_bem_mesh_box(lo, hi, n, &m, &err), DR_OK);
    return m;
}

/* A mesh with room for `extra_v` more vertices and `extra_t` more triangles (counts unchanged). */
static DrTriMesh copy_mesh(const DrTriMesh *m, int extra_v, int extra_t)
{
    DrTriMesh c = {m->nv, m->nt, NULL, NULL, NULL, NULL};
    c.v = calloc(3 * (size_t)(m->nv + extra_v) + 1, sizeof(double));
    c.tri = calloc(3 * (size_t)(m->nt + extra_t) + 1, sizeof(int));
    assert_non_null(c.v);
    assert_non_null(c.tri);
    if (m->nv > 0) memcpy(c.v, m->v, 3 * (size_t)m->nv * sizeof(double));
    if (m->nt > 0) memcpy(c.tri, m->tri, 3 * (size_t)m->nt * sizeof(int));
    return c;
}

static int add_vertex(DrTriMesh *m, double x, double y, double z)
{
    double *p = m->v + 3 * (size_t)m->nv;
    p[0] = x, p[1] = y, p[2] = z;
    return m->nv++;
}

static void add_tri(DrTriMesh *m, int a, int b, int c)
{
    int *f = m->tri + 3 * (size_t)m->nt++;
    f[0] = a, f[1] = b, f[2] = c;
}

/* Adds triangle (a, b, c) wound counter-clockwise seen from outside a body that contains the origin. */
static void add_tri_outward(DrTriMesh *m, int a, int b, int c)
{
    const double *A = m->v + 3 * a, *B = m->v + 3 * b, *C = m->v + 3 * c;
    double det =
        A[0] * (B[1] * C[2] - B[2] * C[1]) - A[1] * (B[0] * C[2] - B[2] * C[0]) + A[2] * (B[0] * C[1] - B[1] * C[0]);
    if (det > 0)
        add_tri(m, a, b, c);
    else
        add_tri(m, a, c, b);
}

static void translate(DrTriMesh *m, double dx, double dy, double dz)
{
    for (int i = 0; i < m->nv; i++) {
        m->v[3 * i] += dx;
        m->v[3 * i + 1] += dy;
        m->v[3 * i + 2] += dz;
    }
}

/* Renumbers the vertices by a random permutation (the same surface, scrambled indices). */
static void shuffle_vertices(DrTriMesh *m, uint64_t seed)
{
    int *perm = malloc((size_t)m->nv * sizeof(int)); /* perm[old] = new */
    double *v = malloc(3 * (size_t)m->nv * sizeof(double));
    assert_non_null(perm);
    assert_non_null(v);
    for (int i = 0; i < m->nv; i++) perm[i] = i;
    DrRng rng;
    dr_rng_seed(&rng, seed);
    for (int i = m->nv - 1; i > 0; i--) {
        int j = (int)(dr_rng_next(&rng) % (uint64_t)(i + 1));
        int t = perm[i];
        perm[i] = perm[j];
        perm[j] = t;
    }
    for (int i = 0; i < m->nv; i++) memcpy(v + 3 * perm[i], m->v + 3 * i, 3 * sizeof(double));
    for (int s = 0; s < 3 * m->nt; s++) m->tri[s] = perm[m->tri[s]];
    memcpy(m->v, v, 3 * (size_t)m->nv * sizeof(double));
    free(perm);
    free(v);
}

static double tri_area(const DrTriMesh *m, int t)
{
    const int *f = m->tri + 3 * t;
    DrVec3 a = dr_v3(m->v[3 * f[0]], m->v[3 * f[0] + 1], m->v[3 * f[0] + 2]);
    DrVec3 b = dr_v3(m->v[3 * f[1]], m->v[3 * f[1] + 1], m->v[3 * f[1] + 2]);
    DrVec3 c = dr_v3(m->v[3 * f[2]], m->v[3 * f[2] + 1], m->v[3 * f[2] + 2]);
    return 0.5 * dr_v3_norm(dr_v3_cross(dr_v3_sub(b, a), dr_v3_sub(c, a)));
}

static DrStatus check(const DrTriMesh *m, const char *path, DrError *err)
{
    dr_error_clear(err);
    return dr_bem_mesh_check(m, path, err);
}

/* The check fails with DR_ERR_INPUT, names `path` in the error and its formatted line, and the message holds
 * every one of the NULL-terminated `words`. */
static void expect_failure(const DrTriMesh *m, const char *path, const char *const *words)
{
    DrError err;
    assert_int_equal(check(m, path, &err), DR_ERR_INPUT);
    assert_int_equal(err.status, DR_ERR_INPUT);
    assert_string_equal(err.file, path);
    char line[4096];
    dr_error_format(&err, line, sizeof line);
    assert_non_null(strstr(line, path));
    for (const char *const *w = words; *w; w++) {
        if (!strstr(err.message, *w)) print_message("missing \"%s\" in: %s\n", *w, err.message);
        assert_non_null(strstr(err.message, *w));
    }
}

static double rel(double got, double want) { return fabs(got - want) / fabs(want); }

/* ---- generated meshes ---- */

static void test_generated_meshes_pass_check(void **state)
{
    (void)state;
    DrError err;
    for (int level = 0; level <= 4; level++) {
        DrTriMesh m = ico(level, 0.7, 0.0, 0.0);
        assert_int_equal(m.nv, 10 * (1 << (2 * level)) + 2);
        assert_int_equal(m.nt, 20 * (1 << (2 * level)));
        assert_null(m.n);
        assert_int_equal(check(&m, "ico.obj", &err), DR_OK);
        assert_true(dr_trimesh_is_closed(&m));
        /* Vertices on the sphere to round-off (a few ulps of the radius after normalising and scaling). */
        for (int i = 0; i < m.nv; i++)
            assert_true(fabs(dr_v3_norm(dr_v3(m.v[3 * i], m.v[3 * i + 1], m.v[3 * i + 2])) - 0.7) < 1e-14);
        dr_trimesh_free(&m);
    }
    /* The bumpy sphere: x = r (1 + b sin(f u_x) sin(f u_y) sin(f u_z)) u for the unit-sphere vertex u. */
    DrTriMesh s = ico(3, 2.0, 0.3, 4.0), u = ico(3, 1.0, 0.0, 0.0);
    assert_int_equal(check(&s, "bumpy.obj", &err), DR_OK);
    for (int i = 0; i < s.nv; i++) {
        const double *p = u.v + 3 * i;
        double g = 2.0 * (1.0 + 0.3 * sin(4.0 * p[0]) * sin(4.0 * p[1]) * sin(4.0 * p[2]));
        /* the generator's own arithmetic, bar the order of one product: a few ulps of coordinates ~2 */
        for (int a = 0; a < 3; a++) assert_true(fabs(s.v[3 * i + a] - g * p[a]) < 1e-14);
    }
    dr_trimesh_free(&s);
    dr_trimesh_free(&u);

    const int ns[4][3] = {{1, 1, 1}, {2, 3, 4}, {5, 1, 2}, {7, 7, 7}};
    for (int k = 0; k < 4; k++) {
        const int *n = ns[k];
        DrTriMesh b = box(-1, 0, 2, 1, 3, 2.5, n[0], n[1], n[2]);
        int lattice = (n[0] + 1) * (n[1] + 1) * (n[2] + 1), inner = (n[0] - 1) * (n[1] - 1) * (n[2] - 1);
        assert_int_equal(b.nv, lattice - inner);
        assert_int_equal(b.nt, 4 * (n[0] * n[1] + n[1] * n[2] + n[2] * n[0]));
        assert_int_equal(check(&b, "box.obj", &err), DR_OK);
        dr_trimesh_free(&b);
    }
}

static void test_generators_reject_bad_arguments(void **state)
{
    (void)state;
    DrTriMesh m;
    DrError err;
    assert_int_equal(dr_bem_mesh_icosphere(-1, 1.0, 0.0, 0.0, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "level"));
    assert_null(m.v);
    assert_int_equal(dr_bem_mesh_icosphere(13, 1.0, 0.0, 0.0, &m, &err), DR_ERR_INPUT);
    assert_int_equal(dr_bem_mesh_icosphere(1, 0.0, 0.0, 0.0, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "radius"));
    assert_int_equal(dr_bem_mesh_icosphere(1, 1.0, 1.0, 3.0, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "bump"));
    const double lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1}, flat[3] = {1, 0, 1};
    const int n[3] = {1, 1, 1}, zero[3] = {1, 0, 1};
    assert_int_equal(dr_bem_mesh_box(lo, hi, zero, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "segments"));
    assert_int_equal(dr_bem_mesh_box(lo, flat, n, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "lo < hi"));
    assert_null(m.v);
    assert_null(m.tri);
}

/* ---- mass properties ---- */

static void test_icosphere_volume_converges(void **state)
{
    (void)state;
    const double r = 1.3, exact = 4.0 / 3.0 * DR_PI * r * r * r;
    double prev = 0.0;
    for (int level = 1; level <= 6; level++) {
        DrTriMesh m = ico(level, r, 0.0, 0.0);
        DrBemBody b;
        dr_bem_body_compute(&m, 1.0, &b);
        double e = (exact - b.volume) / exact; /* inscribed polyhedron: always below the ball */
        assert_true(e > 0.0);
        /* the same sum about another point (bounds centre vs origin): round-off of ≤ 80k terms ~1e-14 */
        assert_true(rel(b.volume, dr_trimesh_volume(&m)) < 1e-13);
        print_message("icosphere level %d: volume error %.3e%s", level, e, level == 1 ? "\n" : "");
        if (level > 1) print_message(" (ratio %.3f)\n", prev / e);
        /* Second order in the edge length h ~ 2^-level: the ratio tends to 4 (3.9 to 4.0 measured). */
        if (level >= 3) assert_true(prev / e > 3.8 && prev / e < 4.2);
        prev = e;
        dr_trimesh_free(&m);
    }
    assert_true(prev < 1e-3);
}

static void test_box_mass_properties_exact(void **state)
{
    (void)state;
    /* Off-centre box [1,3]×[−2,1]×[0.5,4.5]: sides 2, 3, 4; ρ = 7. Every vertex coordinate is a small binary
     * fraction and the sums have a few hundred terms of size ~10², so round-off is ~1e-14 relative; 1e-13
     * fails on any wrong formula. */
    DrTriMesh m = box(1, -2, 0.5, 3, 1, 4.5, 2, 3, 4);
    DrBemBody b;
    dr_bem_body_compute(&m, 7.0, &b);
    const double a = 2, bb = 3, c = 4, V = a * bb * c, M = 7 * V;
    assert_true(rel(b.volume, V) < 1e-13);
    assert_true(rel(b.mass, M) < 1e-13);
    const double xc[3] = {2.0, -0.5, 2.5};
    for (int i = 0; i < 3; i++) assert_true(fabs(b.centroid[i] - xc[i]) < 1e-13);
    const double Id[3] = {M / 12 * (bb * bb + c * c), M / 12 * (a * a + c * c), M / 12 * (a * a + bb * bb)};
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            if (i == j)
                assert_true(rel(b.inertia[3 * i + j], Id[i]) < 1e-13);
            else
                assert_true(fabs(b.inertia[3 * i + j]) < 1e-13 * Id[0]);
        }
    assert_true(rel(b.r_max, sqrt(a * a + bb * bb + c * c)) < 1e-15);

    /* Same body 1000 m away: the sums run about the bounds' centre, so the results move with it and lose only
     * the ~1e-13 relative rounding of coordinates of size 10³ against sides of size 1. */
    translate(&m, 1000.0, -700.0, 1500.0);
    DrBemBody f;
    dr_bem_body_compute(&m, 7.0, &f);
    assert_true(rel(f.volume, V) < 1e-11);
    assert_true(fabs(f.centroid[0] - 1002.0) < 1e-10 && fabs(f.centroid[2] - 1502.5) < 1e-10);
    for (int i = 0; i < 3; i++) assert_true(rel(f.inertia[4 * i], Id[i]) < 1e-11);
    dr_trimesh_free(&m);

    DrTriMesh empty = {0};
    dr_bem_body_compute(&empty, 7.0, &b);
    assert_true(b.volume == 0.0 && b.mass == 0.0 && b.r_max == 0.0);
}

static void test_icosphere_inertia_converges(void **state)
{
    (void)state;
    const double r = 0.8, rho = 1100.0;
    const double exact = 0.4 * rho * (4.0 / 3.0 * DR_PI * r * r * r) * r * r; /* (2/5) m r² of the ball */
    double prev = 0.0;
    for (int level = 1; level <= 5; level++) {
        DrTriMesh m = ico(level, r, 0.0, 0.0);
        translate(&m, 3.0, -1.0, 2.0);
        DrBemBody b;
        dr_bem_body_compute(&m, rho, &b);
        double e = (exact - b.inertia[0]) / exact;
        /* Icosahedral symmetry makes the polyhedron's inertia isotropic: equal diagonal and zero off-diagonal
         * to round-off (1e-12 of the diagonal for sums of ~10⁴ terms). */
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                if (i == j)
                    assert_true(rel(b.inertia[4 * i], b.inertia[0]) < 1e-12);
                else
                    assert_true(fabs(b.inertia[3 * i + j]) < 1e-12 * b.inertia[0]);
            }
        assert_true(fabs(b.centroid[0] - 3.0) < 1e-13 && fabs(b.centroid[1] + 1.0) < 1e-13 &&
                    fabs(b.centroid[2] - 2.0) < 1e-13);
        /* Opposite vertices are antipodal: r_max = 2r to round-off. */
        assert_true(rel(b.r_max, 2 * r) < 1e-14);
        print_message("icosphere level %d: inertia error %.3e%s", level, e, level == 1 ? "\n" : "");
        if (level > 1) print_message(" (ratio %.3f)\n", prev / e);
        if (level >= 3) assert_true(prev / e > 3.8 && prev / e < 4.2); /* second order, like the volume */
        prev = e;
        dr_trimesh_free(&m);
    }
    assert_true(prev > 0.0 && prev < 5e-3);
}

/* r_max is the exact largest vertex distance (all pairs), the same for one and two threads. */
static void test_r_max_exact(void **state)
{
    (void)state;
    DrTriMesh m = ico(3, 1.0, 0.4, 5.0);
    /* Stretch along a slanted axis so the farthest pair is not found by the coordinate extremes. */
    for (int i = 0; i < m.nv; i++) {
        double *p = m.v + 3 * i;
        double s = 0.6 * p[0] + 0.8 * p[1];
        p[0] += 1.5 * 0.6 * s;
        p[1] += 1.5 * 0.8 * s;
    }
    double want = 0.0;
    for (int i = 0; i < m.nv; i++)
        for (int j = 0; j < m.nv; j++) {
            double d = dr_v3_norm(
                dr_v3(m.v[3 * i] - m.v[3 * j], m.v[3 * i + 1] - m.v[3 * j + 1], m.v[3 * i + 2] - m.v[3 * j + 2]));
            want = fmax(want, d);
        }
    int threads = dr_threads();
    DrBemBody b1, b2;
    dr_set_threads(1);
    dr_bem_body_compute(&m, 1.0, &b1);
    dr_set_threads(2);
    dr_bem_body_compute(&m, 1.0, &b2);
    dr_set_threads(threads);
    assert_true(b1.r_max == want); /* the same pair's distance, computed the same way: bit-identical */
    assert_true(b2.r_max == want);
    dr_trimesh_free(&m);
}

/* ---- frame operators ---- */

static void test_shape_weights_sum_to_three_volumes(void **state)
{
    (void)state;
    DrTriMesh meshes[2] = {ico(3, 1.0, 0.3, 4.0), box(1, -2, 0.5, 3, 1, 4.5, 2, 3, 4)};
    translate(&meshes[0], 5.0, 0.0, -2.0);
    for (int k = 0; k < 2; k++) {
        DrTriMesh *m = &meshes[k];
        DrBemBody b;
        dr_bem_body_compute(m, 2.0, &b);
        size_t n = 3 * (size_t)m->nv;
        double *A = malloc(3 * n * sizeof(double)), *C = malloc(3 * n * sizeof(double));
        double *w = malloc((size_t)m->nv * sizeof(double)), *w2 = malloc((size_t)m->nv * sizeof(double));
        assert_true(A && C && w && w2);
        dr_bem_frame_operators(m, &b, A, C, w);
        double sum = 0.0;
        for (int j = 0; j < m->nv; j++) sum += w[j];
        /* Σ w = ∫ (y − x̄)·n dΓ = 3V exactly for a closed polyhedron; round-off of ~10³ terms: 1e-13. */
        assert_true(rel(sum, 3.0 * b.volume) < 1e-13);
        /* Each weight against an independent quadrature: Φ_j(y) (y − x̄)·n is linear on a triangle, so the
         * edge-midpoint rule (Φ_j = 1/2 at the midpoints of its two edges, 0 at the third) is exact.
         * Round-off of sums of a few terms: 1e-13 of the largest weight. */
        double *wq = calloc((size_t)m->nv, sizeof(double)), wmax = 0.0;
        assert_non_null(wq);
        for (int t = 0; t < m->nt; t++) {
            const int *f = m->tri + 3 * t;
            const double *P[3] = {m->v + 3 * f[0], m->v + 3 * f[1], m->v + 3 * f[2]};
            DrVec3 e1 = dr_v3(P[1][0] - P[0][0], P[1][1] - P[0][1], P[1][2] - P[0][2]);
            DrVec3 e2 = dr_v3(P[2][0] - P[0][0], P[2][1] - P[0][1], P[2][2] - P[0][2]);
            DrVec3 nrm = dr_v3_normalize(dr_v3_cross(e1, e2));
            double area = tri_area(m, t);
            for (int e = 0; e < 3; e++) {
                const double *a = P[e], *c = P[(e + 1) % 3];
                DrVec3 mid = dr_v3(0.5 * (a[0] + c[0]) - b.centroid[0], 0.5 * (a[1] + c[1]) - b.centroid[1],
                                   0.5 * (a[2] + c[2]) - b.centroid[2]);
                double g = area / 3.0 * dr_v3_dot(mid, nrm) * 0.5;
                wq[f[e]] += g;
                wq[f[(e + 1) % 3]] += g;
            }
        }
        for (int j = 0; j < m->nv; j++) wmax = fmax(wmax, fabs(w[j]));
        for (int j = 0; j < m->nv; j++) assert_true(fabs(wq[j] - w[j]) < 1e-13 * wmax);
        free(wq);
        /* Star-shaped about x̄ (both bodies): every weight is a positive cone volume. */
        for (int j = 0; j < m->nv; j++) assert_true(w[j] > 0.0);
        /* Measured from x̄, the weights do not depend on where the body sits (round-off of coordinates of
         * size 10² against weights of size ~1e-3 relative: 1e-10). */
        translate(m, -40.0, 100.0, 7.0);
        dr_bem_body_compute(m, 2.0, &b);
        dr_bem_frame_operators(m, &b, A, C, w2);
        for (int j = 0; j < m->nv; j++) assert_true(fabs(w2[j] - w[j]) < 1e-10 * fabs(w[j]));
        free(A);
        free(C);
        free(w);
        free(w2);
        dr_trimesh_free(m);
    }
}

static void test_translation_operator(void **state)
{
    (void)state;
    /* Box [1,3]×[−2,1]×[0.5,4.5]: area 2(2·3 + 3·4 + 4·2) = 52 m²; a uniform traction p on every node gives the
     * force 52 p and the acceleration A p = 52 p / m. */
    DrTriMesh m = box(1, -2, 0.5, 3, 1, 4.5, 3, 2, 5);
    DrBemBody b;
    dr_bem_body_compute(&m, 7.0, &b);
    const int nv = m.nv;
    const size_t n = 3 * (size_t)nv;
    double *A = malloc(3 * n * sizeof(double)), *C = malloc(3 * n * sizeof(double));
    double *w = malloc((size_t)nv * sizeof(double)), *p = malloc(n * sizeof(double));
    double *area = malloc((size_t)nv * sizeof(double));
    assert_true(A && C && w && p && area);
    dr_bem_frame_operators(&m, &b, A, C, w);
    const double P[3] = {3.0, -1.5, 0.25};
    for (int j = 0; j < nv; j++) memcpy(p + 3 * j, P, sizeof P);
    for (int r = 0; r < 3; r++) {
        double acc = 0.0;
        for (size_t c = 0; c < n; c++) acc += A[r * n + c] * p[c];
        /* a few hundred terms of size ~1e-3: round-off 1e-14 relative */
        assert_true(rel(acc, 52.0 * P[r] / b.mass) < 1e-13);
    }
    /* A's structure: A[a][3j+b] = δ_ab ∫Φ_j / m, with ∫Φ_j the vertex areas. */
    dr_bem_vertex_areas(&m, area);
    double total = 0.0;
    for (int j = 0; j < nv; j++) {
        total += area[j];
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)
                assert_true(fabs(A[r * n + 3 * j + c] - (r == c ? area[j] / b.mass : 0.0)) <= 1e-14 * area[j] / b.mass);
    }
    assert_true(rel(total, 52.0) < 1e-13); /* a sum of 300 exact-ish areas: round-off ~1e-15 */
    /* Vertex areas sum to the triangle areas on a curved mesh as well. */
    DrTriMesh s = ico(3, 1.0, 0.3, 4.0);
    double *as = malloc((size_t)s.nv * sizeof(double));
    assert_non_null(as);
    dr_bem_vertex_areas(&s, as);
    double sa = 0.0, st = 0.0;
    for (int j = 0; j < s.nv; j++) sa += as[j];
    for (int t = 0; t < s.nt; t++) st += tri_area(&s, t);
    assert_true(rel(sa, st) < 1e-13); /* two orders of summing 1280 areas: round-off ~1e-15 */
    free(as);
    dr_trimesh_free(&s);
    free(A);
    free(C);
    free(w);
    free(p);
    free(area);
    dr_trimesh_free(&m);
}

/* Torque ∫ (y − x̄) × p(y) dΓ of the traction field p(y) = Mp (y − x̄), which the nodal values p_j = Mp (x_j − x̄)
 * interpolate exactly; the integrand is quadratic, so the edge-midpoint rule on each triangle is exact. This
 * shares nothing with dr_bem_frame_operators' closed-form moments. */
static void torque_of_linear_traction(const DrTriMesh *m, const double xc[3], const double Mp[9], double tau[3])
{
    tau[0] = tau[1] = tau[2] = 0.0;
    for (int t = 0; t < m->nt; t++) {
        const int *f = m->tri + 3 * t;
        double A = tri_area(m, t);
        for (int e = 0; e < 3; e++) {
            const double *a = m->v + 3 * f[e], *b = m->v + 3 * f[(e + 1) % 3];
            DrVec3 r = dr_v3(0.5 * (a[0] + b[0]) - xc[0], 0.5 * (a[1] + b[1]) - xc[1], 0.5 * (a[2] + b[2]) - xc[2]);
            DrVec3 p = dr_v3(Mp[0] * r.x + Mp[1] * r.y + Mp[2] * r.z, Mp[3] * r.x + Mp[4] * r.y + Mp[5] * r.z,
                             Mp[6] * r.x + Mp[7] * r.y + Mp[8] * r.z);
            DrVec3 c = dr_v3_cross(r, p);
            tau[0] += A / 3 * c.x;
            tau[1] += A / 3 * c.y;
            tau[2] += A / 3 * c.z;
        }
    }
}

static void test_rotation_operator(void **state)
{
    (void)state;
    DrTriMesh meshes[2] = {ico(3, 1.0, 0.3, 4.0), box(1, -2, 0.5, 3, 1, 4.5, 2, 3, 4)};
    translate(&meshes[0], 2.0, -3.0, 1.0);
    /* Mp[0]: the field ω × (y − x̄) of a rigid rotation, ω = (0.3, −1, 2); Mp[1]: a general linear field;
     * Mp[2]: a twist about +z, whose torque (and so α) must point along +z. */
    const double Mp[3][9] = {{0, -2, -1, 2, 0, -0.3, 1, 0.3, 0},
                             {0.4, -1.0, 2.0, 0.7, 1.5, -0.2, -0.9, 0.3, 0.6},
                             {0, -1, 0, 1, 0, 0, 0, 0, 0}};
    for (int k = 0; k < 2; k++) {
        DrTriMesh *m = &meshes[k];
        DrBemBody b;
        dr_bem_body_compute(m, 900.0, &b);
        const size_t n = 3 * (size_t)m->nv;
        double *A = malloc(3 * n * sizeof(double)), *C = malloc(3 * n * sizeof(double));
        double *w = malloc((size_t)m->nv * sizeof(double)), *p = malloc(n * sizeof(double));
        assert_true(A && C && w && p);
        dr_bem_frame_operators(m, &b, A, C, w);
        for (int f = 0; f < 3; f++) {
            for (int j = 0; j < m->nv; j++) {
                double r[3];
                for (int i = 0; i < 3; i++) r[i] = m->v[3 * j + i] - b.centroid[i];
                for (int i = 0; i < 3; i++)
                    p[3 * j + i] = Mp[f][3 * i] * r[0] + Mp[f][3 * i + 1] * r[1] + Mp[f][3 * i + 2] * r[2];
            }
            double alpha[3] = {0, 0, 0}, tau[3], Ia[3] = {0, 0, 0};
            for (int r = 0; r < 3; r++)
                for (size_t c = 0; c < n; c++) alpha[r] += C[r * n + c] * p[c];
            torque_of_linear_traction(m, b.centroid, Mp[f], tau);
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++) Ia[r] += b.inertia[3 * r + c] * alpha[c];
            /* I (C p) = τ: both sides are sums of ~10³ terms of size ~1 with mild cancellation; 1e-11 of |τ|
             * leaves room for the round-off of I⁻¹ and still fails on any wrong sign or factor. */
            double tn = sqrt(tau[0] * tau[0] + tau[1] * tau[1] + tau[2] * tau[2]);
            for (int r = 0; r < 3; r++) assert_true(fabs(Ia[r] - tau[r]) < 1e-11 * tn);
            if (f == 2) assert_true(alpha[2] > 0.0 && tau[2] > 0.0);
        }
        free(A);
        free(C);
        free(w);
        free(p);
        dr_trimesh_free(m);
    }
}

/* ---- vertex order ---- */

static bool is_permutation(const int *order, int n)
{
    char *seen = calloc((size_t)n + 1, 1);
    bool ok = seen != NULL;
    for (int i = 0; i < n && ok; i++) {
        ok = order[i] >= 0 && order[i] < n && !seen[order[i]];
        if (ok) seen[order[i]] = 1;
    }
    free(seen);
    return ok;
}

static double mean_step(const DrTriMesh *m, const int *order)
{
    double s = 0.0;
    for (int i = 1; i < m->nv; i++) {
        const double *a = m->v + 3 * (order ? order[i - 1] : i - 1), *b = m->v + 3 * (order ? order[i] : i);
        s += dr_v3_norm(dr_v3(a[0] - b[0], a[1] - b[1], a[2] - b[2]));
    }
    return s / (m->nv - 1);
}

/* On an 8×8×8 lattice filling the bounding cube each point has a cell of its own at the curve's third level,
 * and a Hilbert curve steps between face-adjacent cells: consecutive points must be lattice neighbours.
 * Any error in the curve's rotations breaks this. */
static void test_vertex_order_is_a_hilbert_curve(void **state)
{
    (void)state;
    DrTriMesh m = {512, 0, calloc(3 * 512, sizeof(double)), NULL, NULL, NULL};
    assert_non_null(m.v);
    for (int i = 0; i < 512; i++) {
        m.v[3 * i] = 0.5 * (i % 8);
        m.v[3 * i + 1] = 0.5 * ((i / 8) % 8) - 3.0;
        m.v[3 * i + 2] = 0.5 * (i / 64) + 10.0;
    }
    shuffle_vertices(&m, 7);
    int order[512];
    dr_bem_vertex_order(&m, order);
    assert_true(is_permutation(order, 512));
    for (int i = 1; i < 512; i++) {
        const double *a = m.v + 3 * order[i - 1], *b = m.v + 3 * order[i];
        double d = dr_v3_norm(dr_v3(a[0] - b[0], a[1] - b[1], a[2] - b[2]));
        assert_true(fabs(d - 0.5) < 1e-12); /* lattice spacing; coordinates are exact binary fractions */
    }
    free(m.v);

    /* One vertex and coincident vertices: the input order. */
    double one[6] = {1, 2, 3, 1, 2, 3};
    DrTriMesh p = {2, 0, one, NULL, NULL, NULL};
    int o2[2];
    dr_bem_vertex_order(&p, o2);
    assert_true(o2[0] == 0 && o2[1] == 1);
}

static void test_vertex_order_locality(void **state)
{
    (void)state;
    DrTriMesh m = ico(5, 1.0, 0.2, 3.0);
    shuffle_vertices(&m, 42);
    int *order = malloc((size_t)m.nv * sizeof(int)), *again = malloc((size_t)m.nv * sizeof(int));
    assert_true(order && again);
    double t0 = dr_time_now();
    dr_bem_vertex_order(&m, order);
    double secs = dr_time_now() - t0;
    dr_bem_vertex_order(&m, again);
    assert_true(is_permutation(order, m.nv));
    assert_memory_equal(order, again, (size_t)m.nv * sizeof(int)); /* deterministic */
    double shuffled = mean_step(&m, NULL), hilbert = mean_step(&m, order);
    print_message("vertex order (%d vertices, %.3f s): mean step %.4f shuffled, %.4f Hilbert (ratio %.3f)\n", m.nv,
                  secs, shuffled, hilbert, hilbert / shuffled);
    /* Random order steps 4/3 r on average; the curve mostly steps to a neighbour (edges ~0.03 r here) with
     * occasional longer jumps (measured mean 0.053 r, ratio 0.04). 0.1 is far from both. */
    assert_true(hilbert < 0.1 * shuffled);
    free(order);
    free(again);
    dr_trimesh_free(&m);
}

/* ---- welding ---- */

/* Splits an icosphere along the plane x = 0: triangles whose centroid has x > 0 get their own copies of the
 * vertices they share with the other side (appended after the originals, moved by `jitter`), as an OBJ export
 * does along a UV seam. Returns the number of copies. */
static int split_seam(const DrTriMesh *src, double jitter, DrTriMesh *out)
{
    *out = copy_mesh(src, src->nv, 0);
    int *side = calloc((size_t)src->nv, sizeof(int)), *copy = calloc((size_t)src->nv, sizeof(int));
    assert_true(side && copy);
    for (int t = 0; t < src->nt; t++) {
        const int *f = src->tri + 3 * t;
        double cx = (src->v[3 * f[0]] + src->v[3 * f[1]] + src->v[3 * f[2]]) / 3.0;
        for (int c = 0; c < 3; c++) side[f[c]] |= cx > 0.0 ? 1 : 2;
    }
    int copies = 0;
    for (int i = 0; i < src->nv; i++) {
        copy[i] = i;
        if (side[i] == 3) {
            const double *p = src->v + 3 * i;
            copy[i] = add_vertex(out, p[0] + jitter, p[1] - jitter, p[2] + 0.5 * jitter);
            copies++;
        }
    }
    for (int t = 0; t < out->nt; t++) {
        int *f = out->tri + 3 * t;
        double cx = (src->v[3 * f[0]] + src->v[3 * f[1]] + src->v[3 * f[2]]) / 3.0;
        if (cx > 0.0)
            for (int c = 0; c < 3; c++) f[c] = copy[f[c]];
    }
    free(side);
    free(copy);
    return copies;
}

static void test_weld_closes_a_seam(void **state)
{
    (void)state;
    DrTriMesh ref = ico(3, 1.0, 0.0, 0.0);
    const double jitters[2] = {0.0, 1e-9};
    for (int k = 0; k < 2; k++) {
        DrTriMesh m;
        int copies = split_seam(&ref, jitters[k], &m);
        assert_true(copies > 10);
        m.n = calloc(3 * (size_t)m.nv, sizeof(double));
        assert_non_null(m.n);
        const char *open[] = {"open boundary edge", "closed, watertight", NULL};
        expect_failure(&m, "seam.obj", open);
        DrError err;
        int removed = -1;
        /* tol: far above the jitter and far below the edge length (~0.1) */
        assert_int_equal(dr_bem_mesh_weld(&m, 1e-6, &removed, &err), DR_OK);
        assert_int_equal(removed, copies);
        assert_null(m.n);
        assert_int_equal(check(&m, "seam.obj", &err), DR_OK);
        /* Lowest index kept: the originals, so the mesh is the input again, bit for bit. */
        assert_int_equal(m.nv, ref.nv);
        assert_int_equal(m.nt, ref.nt);
        assert_memory_equal(m.v, ref.v, 3 * (size_t)ref.nv * sizeof(double));
        assert_memory_equal(m.tri, ref.tri, 3 * (size_t)ref.nt * sizeof(int));
        dr_trimesh_free(&m);
    }
    /* A seam wider than tol stays open. */
    DrTriMesh m;
    split_seam(&ref, 1e-3, &m);
    DrError err;
    int removed = -1;
    assert_int_equal(dr_bem_mesh_weld(&m, 1e-4, &removed, &err), DR_OK);
    assert_int_equal(removed, 0);
    assert_int_equal(check(&m, "seam.obj", &err), DR_ERR_INPUT);
    dr_trimesh_free(&m);
    dr_trimesh_free(&ref);
}

static void test_weld_details(void **state)
{
    (void)state;
    DrError err;
    int removed = -1;
    /* Vertices 0..4 on a line 0.6 apart, vertex 5 at vertex 1's position, vertex 6 unused. tol 1: vertex 1 joins
     * 0, vertex 2 is 1.2 from 0 so it stays (chains are not collapsed), 3 joins 2, 4 stays, 5 joins 0 (1's
     * representative is 0 and 5 is within tol of it). Triangle (0, 1, 5) collapses; (0, 2, 4) and (1, 3, 4)
     * become (0, 2, 4) and (0, 2, 4). */
    DrTriMesh m = {0};
    m.v = calloc(3 * 8, sizeof(double));
    m.tri = calloc(3 * 4, sizeof(int));
    m.n = calloc(3 * 8, sizeof(double));
    for (int i = 0; i < 5; i++) add_vertex(&m, 0.6 * i, 0.1 * (i % 2), 0.0);
    add_vertex(&m, 0.6, 0.1, 0.0);
    add_vertex(&m, 9.0, 9.0, 9.0);
    add_tri(&m, 0, 1, 5);
    add_tri(&m, 0, 2, 4);
    add_tri(&m, 1, 3, 4);
    assert_int_equal(dr_bem_mesh_weld(&m, 1.0, &removed, &err), DR_OK);
    assert_int_equal(removed, 4); /* 1, 3, 5 merged; 6 unused */
    assert_int_equal(m.nv, 3);
    assert_int_equal(m.nt, 2);
    assert_null(m.n);
    const int want[6] = {0, 1, 2, 0, 1, 2};
    assert_memory_equal(m.tri, want, sizeof want);
    assert_true(m.v[3] == 1.2 && m.v[6] == 2.4);
    /* tol 0 joins equal positions only. */
    m.nv = 0, m.nt = 0;
    add_vertex(&m, 1, 1, 1);
    add_vertex(&m, 1, 1, 1 + 1e-15);
    add_vertex(&m, 1, 1, 1);
    add_vertex(&m, 0, 0, 0);
    add_tri(&m, 0, 1, 3);
    add_tri(&m, 2, 1, 3);
    assert_int_equal(dr_bem_mesh_weld(&m, 0.0, &removed, &err), DR_OK);
    assert_int_equal(removed, 1);
    assert_int_equal(m.nt, 2);
    /* Bad input */
    assert_int_equal(dr_bem_mesh_weld(&m, -1.0, &removed, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "tolerance"));
    assert_int_equal(dr_bem_mesh_weld(&m, NAN, &removed, &err), DR_ERR_INPUT);
    m.v[0] = INFINITY;
    assert_int_equal(dr_bem_mesh_weld(&m, 1e-6, &removed, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "non-finite"));
    assert_int_equal(m.nv, 3); /* untouched on failure */
    dr_trimesh_free(&m);
    /* Empty mesh */
    DrTriMesh e = {0};
    assert_int_equal(dr_bem_mesh_weld(&e, 1e-6, &removed, &err), DR_OK);
    assert_int_equal(removed, 0);
}

/* ---- the check's failures ---- */

static void test_check_failures(void **state)
{
    (void)state;
    DrTriMesh ref = ico(2, 1.0, 0.0, 0.0);
    DrTriMesh m;
    char buf[64];

    /* one triangle missing: its three edges are open */
    m = copy_mesh(&ref, 0, 0);
    m.nt--;
    const char *missing[] = {"3 open boundary edges", "closed, watertight", "fill the holes", NULL};
    expect_failure(&m, "holes.obj", missing);
    dr_trimesh_free(&m);

    /* three triangles on one edge: a fin on edge (a, b) of triangle 0 (its two new edges are open too) */
    m = copy_mesh(&ref, 1, 1);
    int apex = add_vertex(&m, 2.0, 2.0, 2.0);
    add_tri(&m, ref.tri[0], ref.tri[1], apex);
    snprintf(buf, sizeof buf, "between vertices %d and %d", ref.tri[0] < ref.tri[1] ? ref.tri[0] + 1 : ref.tri[1] + 1,
             ref.tri[0] < ref.tri[1] ? ref.tri[1] + 1 : ref.tri[0] + 1);
    const char *fin[] = {"1 non-manifold edge ",           "shared by 3 triangles", buf,
                         "also has 2 open boundary edges", "closed, watertight",    NULL};
    expect_failure(&m, "fin.obj", fin);
    dr_trimesh_free(&m);

    /* three triangles on each equator edge and no open edge: a bipyramid with its equator triangle inside */
    m = copy_mesh(&(DrTriMesh){0}, 5, 7);
    int N = add_vertex(&m, 0, 0, 1), S = add_vertex(&m, 0, 0, -1), c[3];
    for (int k = 0; k < 3; k++) c[k] = add_vertex(&m, cos(2 * DR_PI * k / 3), sin(2 * DR_PI * k / 3), 0);
    for (int k = 0; k < 3; k++) {
        add_tri_outward(&m, N, c[k], c[(k + 1) % 3]);
        add_tri_outward(&m, S, c[k], c[(k + 1) % 3]);
    }
    add_tri(&m, c[0], c[1], c[2]);
    const char *pages[] = {"3 non-manifold edges", "shared by 3 triangles", "closed, watertight", NULL};
    expect_failure(&m, "pages.obj", pages);
    DrError err;
    check(&m, "pages.obj", &err);
    assert_null(strstr(err.message, "also has"));
    dr_trimesh_free(&m);

    /* one flipped triangle: its three edges run the same way as their neighbours' */
    m = copy_mesh(&ref, 0, 0);
    int t = m.tri[3 * 5 + 1];
    m.tri[3 * 5 + 1] = m.tri[3 * 5 + 2];
    m.tri[3 * 5 + 2] = t;
    const char *flipped[] = {"inconsistent", "3 edges are traversed in the same direction", "flipped", NULL};
    expect_failure(&m, "flip1.obj", flipped);
    dr_trimesh_free(&m);

    /* every triangle flipped: consistent but inward */
    m = copy_mesh(&ref, 0, 0);
    for (int k = 0; k < m.nt; k++) {
        t = m.tri[3 * k + 1];
        m.tri[3 * k + 1] = m.tri[3 * k + 2];
        m.tri[3 * k + 2] = t;
    }
    const char *inward[] = {"normals point inward", "flip the winding", NULL};
    expect_failure(&m, "inward.obj", inward);
    dr_trimesh_free(&m);

    /* a zero-area triangle that keeps the surface closed: triangle 0 = (a, b, c) split at the midpoint m of
     * (a, b) into (a, m, c), (m, b, c), with the flat triangle (m, a, b) closing the gap to the neighbour */
    m = copy_mesh(&ref, 1, 2);
    int a = ref.tri[0], b = ref.tri[1], cc = ref.tri[2];
    int mid = add_vertex(&m, 0.5 * (ref.v[3 * a] + ref.v[3 * b]), 0.5 * (ref.v[3 * a + 1] + ref.v[3 * b + 1]),
                         0.5 * (ref.v[3 * a + 2] + ref.v[3 * b + 2]));
    m.tri[1] = mid;
    add_tri(&m, mid, b, cc);
    add_tri(&m, mid, a, b);
    const char *zero[] = {"1 zero-area triangle ", "normal", "Degenerate Dissolve", NULL};
    expect_failure(&m, "flat.obj", zero);
    snprintf(buf, sizeof buf, "triangle %d ", m.nt);
    check(&m, "flat.obj", &err);
    assert_non_null(strstr(err.message, buf));
    dr_trimesh_free(&m);

    /* an unused vertex */
    m = copy_mesh(&ref, 1, 0);
    add_vertex(&m, 0.1, 0.2, 0.3);
    snprintf(buf, sizeof buf, "vertex %d ", m.nv);
    const char *unused[] = {"1 vertex is used by no triangle", buf, "weld / remove unreferenced vertices", NULL};
    expect_failure(&m, "loose.obj", unused);
    dr_trimesh_free(&m);

    /* a triangle using a vertex twice */
    m = copy_mesh(&ref, 0, 0);
    m.tri[3 * 7 + 2] = m.tri[3 * 7];
    const char *twice[] = {"1 triangle uses the same vertex twice", "triangle 8 ", NULL};
    expect_failure(&m, "twice.obj", twice);
    dr_trimesh_free(&m);

    /* two tetrahedra touching at one vertex: every edge is fine, the shared vertex is not */
    m = copy_mesh(&(DrTriMesh){0}, 7, 8);
    int o = add_vertex(&m, 0, 0, 0);
    for (int s = -1; s <= 1; s += 2) {
        int p0 = add_vertex(&m, s * 1.0, 0, 0), p1 = add_vertex(&m, s * 1.0, 1, 0), p2 = add_vertex(&m, s * 1.0, 0, 1);
        /* outward by the tetrahedron's own centroid */
        double cen[3] = {0.75 * s, 0.25, 0.25};
        int q[4][3] = {{o, p0, p1}, {o, p1, p2}, {o, p2, p0}, {p0, p2, p1}};
        for (int k = 0; k < 4; k++) {
            const double *A = m.v + 3 * q[k][0], *B = m.v + 3 * q[k][1], *C = m.v + 3 * q[k][2];
            DrVec3 e1 = dr_v3(B[0] - A[0], B[1] - A[1], B[2] - A[2]), e2 = dr_v3(C[0] - A[0], C[1] - A[1], C[2] - A[2]);
            DrVec3 out = dr_v3(A[0] - cen[0], A[1] - cen[1], A[2] - cen[2]);
            if (dr_v3_dot(dr_v3_cross(e1, e2), out) > 0)
                add_tri(&m, q[k][0], q[k][1], q[k][2]);
            else
                add_tri(&m, q[k][0], q[k][2], q[k][1]);
        }
    }
    const char *bowtie[] = {"1 non-manifold vertex ", "vertex 1 ", "touch at a point", NULL};
    expect_failure(&m, "bowtie.obj", bowtie);
    dr_trimesh_free(&m);

    /* two boxes of opposite orientation: closed, consistent, but no volume */
    DrTriMesh b1 = box(0, 0, 0, 1, 1, 1, 1, 1, 1), b2 = box(3, 0, 0, 4, 1, 1, 1, 1, 1);
    m = copy_mesh(&b1, b2.nv, b2.nt);
    for (int k = 0; k < b2.nv; k++) add_vertex(&m, b2.v[3 * k], b2.v[3 * k + 1], b2.v[3 * k + 2]);
    for (int k = 0; k < b2.nt; k++)
        add_tri(&m, b1.nv + b2.tri[3 * k], b1.nv + b2.tri[3 * k + 2], b1.nv + b2.tri[3 * k + 1]);
    const char *hollow[] = {"encloses no volume", NULL};
    expect_failure(&m, "twin.obj", hollow);
    dr_trimesh_free(&m);
    dr_trimesh_free(&b1);
    dr_trimesh_free(&b2);

    /* too small, empty, out-of-range index, non-finite coordinate */
    m = copy_mesh(&ref, 0, 0);
    m.nt = 2;
    const char *small[] = {"at least 4 triangles", "closed, watertight", NULL};
    expect_failure(&m, "sheet.obj", small);
    DrTriMesh empty = {0};
    expect_failure(&empty, "empty.obj", small);
    m.nt = ref.nt;
    m.tri[10] = ref.nv;
    snprintf(buf, sizeof buf, "the mesh has %d vertices", ref.nv);
    const char *range[] = {buf, NULL};
    expect_failure(&m, "range.obj", range);
    m.tri[10] = ref.tri[10];
    m.v[4] = NAN;
    const char *nan_[] = {"vertex 2 ", "non-finite", NULL};
    expect_failure(&m, "nan.obj", nan_);
    dr_trimesh_free(&m);
    dr_trimesh_free(&ref);
}

/* The check is O(M log M): 81,920 triangles well under a second. */
static void test_check_large_mesh(void **state)
{
    (void)state;
    DrTriMesh m = ico(6, 1.0, 0.1, 6.0);
    DrError err;
    double t0 = dr_time_now();
    assert_int_equal(check(&m, "big.obj", &err), DR_OK);
    double secs = dr_time_now() - t0;
    print_message("check of %d triangles: %.3f s\n", m.nt, secs);
    assert_true(secs < 2.0);
    dr_trimesh_free(&m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_generated_meshes_pass_check),
        cmocka_unit_test(test_generators_reject_bad_arguments),
        cmocka_unit_test(test_icosphere_volume_converges),
        cmocka_unit_test(test_box_mass_properties_exact),
        cmocka_unit_test(test_icosphere_inertia_converges),
        cmocka_unit_test(test_r_max_exact),
        cmocka_unit_test(test_shape_weights_sum_to_three_volumes),
        cmocka_unit_test(test_translation_operator),
        cmocka_unit_test(test_rotation_operator),
        cmocka_unit_test(test_vertex_order_is_a_hilbert_curve),
        cmocka_unit_test(test_vertex_order_locality),
        cmocka_unit_test(test_weld_closes_a_seam),
        cmocka_unit_test(test_weld_details),
        cmocka_unit_test(test_check_failures),
        cmocka_unit_test(test_check_large_mesh),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
