/* Unit tests of src/hair/groom.c: the desc and material defaults; grown grooms (counts, lengths, roots on the
 * scalp surface, uniform by area, strands along the interpolated normals, the face-normal fallback, curl
 * radius and pitch measured on the output, length jitter, bit-identical per seed, roots independent of curl
 * and jitter, bad descs and meshes); OBJ polylines (records, index forms, skipped records, optional radius
 * lines, a file written by dr_io_write_polylines_obj) and every documented bad input with its file:line:col.
 * Runs from the repository root (tests/run_tests.sh). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "hair/hair.h"
#include "io/io.h"

static char g_dir[256]; /* scratch directory of this run */

static int group_setup(void **state)
{
    (void)state;
    snprintf(g_dir, sizeof g_dir, "%s/drench_test_groom_XXXXXX", dr_temp_dir());
    return mkdtemp(g_dir) ? 0 : -1;
}

static int group_teardown(void **state)
{
    (void)state;
    char cmd[512];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    return system(cmd) == 0 ? 0 : -1;
}

static void assert_contains(const char *hay, const char *needle)
{
    if (!strstr(hay, needle)) fail_msg("expected \"%s\" in \"%s\"", needle, hay);
}

static DrVec3 at(const double *a, int i) { return dr_v3(a[3 * i], a[3 * i + 1], a[3 * i + 2]); }

static void assert_empty(const DrGroom *g)
{
    assert_int_equal(g->nstrands, 0);
    assert_null(g->offsets);
    assert_null(g->x);
    assert_null(g->root_normal);
}

static DrTriMesh load_sphere(void)
{
    DrTriMesh m = {0};
    DrError err;
    if (dr_io_load_mesh("assets/meshes/sphere.obj", &m, &err) != DR_OK)
        fail_msg("assets/meshes/sphere.obj: %s (run from the repository root)", err.message);
    return m;
}

/* The regular octahedron |x| + |y| + |z| = R, counter-clockwise from outside. Every vertex's four triangles
 * are symmetric about it, so its area-weighted normal is exactly radial (sums of ±1 components). */
static DrTriMesh octahedron(double R)
{
    DrTriMesh m = {.nv = 6, .nt = 8};
    m.v = calloc(18, sizeof(double));
    m.tri = calloc(24, sizeof(int));
    assert_non_null(m.v);
    assert_non_null(m.tri);
    for (int i = 0; i < 3; i++) {
        m.v[3 * (2 * i) + i] = R;       /* vertex 2i: +e_i */
        m.v[3 * (2 * i + 1) + i] = -R;  /* vertex 2i+1: −e_i */
    }
    int t = 0;
    for (int sx = 0; sx < 2; sx++)
        for (int sy = 0; sy < 2; sy++)
            for (int sz = 0; sz < 2; sz++) {
                int a = sx, b = 2 + sy, c = 4 + sz;
                /* (b − a) × (c − a) ∝ (sy sz, sx sz, sx sy): outward when the octant's sign product is positive */
                bool outward = ((sx + sy + sz) % 2) == 0;
                m.tri[3 * t] = a;
                m.tri[3 * t + 1] = outward ? b : c;
                m.tri[3 * t + 2] = outward ? c : b;
                t++;
            }
    return m;
}

static DrGroom grow(const DrTriMesh *m, const DrGroomDesc *d)
{
    DrGroom g;
    DrError err;
    if (dr_groom_grow(m, d, &g, &err) != DR_OK) fail_msg("dr_groom_grow: %s", err.message);
    return g;
}

/* Distance from p to triangle abc (Ericson, Real-Time Collision Detection §5.1.5: closest point by regions). */
static double point_triangle_distance(DrVec3 p, DrVec3 a, DrVec3 b, DrVec3 c)
{
    DrVec3 ab = dr_v3_sub(b, a), ac = dr_v3_sub(c, a), ap = dr_v3_sub(p, a), q;
    double d1 = dr_v3_dot(ab, ap), d2 = dr_v3_dot(ac, ap);
    DrVec3 bp = dr_v3_sub(p, b), cp = dr_v3_sub(p, c);
    double d3 = dr_v3_dot(ab, bp), d4 = dr_v3_dot(ac, bp), d5 = dr_v3_dot(ab, cp), d6 = dr_v3_dot(ac, cp);
    double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    if (d1 <= 0 && d2 <= 0) q = a;
    else if (d3 >= 0 && d4 <= d3) q = b;
    else if (d6 >= 0 && d5 <= d6) q = c;
    else if (vc <= 0 && d1 >= 0 && d3 <= 0) q = dr_v3_add(a, dr_v3_scale(ab, d1 / (d1 - d3)));
    else if (vb <= 0 && d2 >= 0 && d6 <= 0) q = dr_v3_add(a, dr_v3_scale(ac, d2 / (d2 - d6)));
    else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
        q = dr_v3_add(b, dr_v3_scale(dr_v3_sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))));
    else {
        double den = 1.0 / (va + vb + vc);
        q = dr_v3_add(a, dr_v3_add(dr_v3_scale(ab, vb * den), dr_v3_scale(ac, vc * den)));
    }
    return dr_v3_norm(dr_v3_sub(p, q));
}

static double distance_to_mesh(const DrTriMesh *m, DrVec3 p)
{
    double best = INFINITY;
    for (int t = 0; t < m->nt; t++) {
        double d = point_triangle_distance(p, at(m->v, m->tri[3 * t]), at(m->v, m->tri[3 * t + 1]),
                                           at(m->v, m->tri[3 * t + 2]));
        if (d < best) best = d;
    }
    return best;
}

static double polyline_length(const DrGroom *g, int s)
{
    double L = 0;
    for (int k = g->offsets[s]; k + 1 < g->offsets[s + 1]; k++) L += dr_v3_norm(dr_v3_sub(at(g->x, k + 1), at(g->x, k)));
    return L;
}

/* ---- defaults --------------------------------------------------------------------------------------------- */

static void test_defaults(void **state)
{
    (void)state;
    DrGroomDesc d;
    memset(&d, 0xab, sizeof d);
    dr_groom_desc_default(&d);
    assert_int_equal(d.count, 100);
    assert_true(d.length == 0.05);
    assert_int_equal(d.segments, 12);
    assert_true(d.curl_radius == 0.0 && d.curl_pitch == 0.01 && d.length_jitter == 0.0);
    assert_true(d.seed == 1);
    DrRodMaterial m;
    memset(&m, 0xab, sizeof m);
    dr_rod_material_default(&m);
    assert_true(m.radius == 5e-5 && m.density == 1300.0 && m.youngs == 3.9e9 && m.shear == 1.3e9);
    assert_true(m.damping == 0.0);
    DrGroom g = {0};
    dr_groom_free(&g); /* an empty groom frees as a no-op */
    dr_groom_free(NULL);
}

/* ---- growing ------------------------------------------------------------------------------------------------ */

static void test_counts_and_lengths(void **state)
{
    (void)state;
    DrTriMesh m = load_sphere();
    DrGroomDesc d;
    dr_groom_desc_default(&d);
    DrGroom g = grow(&m, &d);
    assert_int_equal(g.nstrands, 100);
    for (int s = 0; s <= g.nstrands; s++) assert_int_equal(g.offsets[s], 13 * s);
    /* straight strands: every edge L/12 up to rounding of coordinates of size 0.5 m (a few 1e-17 m) */
    for (int s = 0; s < g.nstrands; s++) {
        for (int k = g.offsets[s]; k + 1 < g.offsets[s + 1]; k++) {
            double e = dr_v3_norm(dr_v3_sub(at(g.x, k + 1), at(g.x, k)));
            assert_true(fabs(e - 0.05 / 12) < 1e-14);
        }
        assert_true(fabs(polyline_length(&g, s) - 0.05) < 1e-13);
        assert_true(fabs(dr_v3_norm(at(g.root_normal, s)) - 1.0) < 1e-15);
    }
    dr_groom_free(&g);
    assert_empty(&g);

    /* the smallest groom: one strand of one edge */
    d.count = 1;
    d.segments = 1;
    g = grow(&m, &d);
    assert_int_equal(g.nstrands, 1);
    assert_int_equal(g.offsets[1], 2);
    assert_true(fabs(polyline_length(&g, 0) - 0.05) < 1e-15);
    dr_groom_free(&g);
    dr_trimesh_free(&m);
}

static void test_roots_on_the_scalp(void **state)
{
    (void)state;
    DrTriMesh m = load_sphere();
    DrGroomDesc d;
    dr_groom_desc_default(&d);
    d.count = 300;
    DrGroom g = grow(&m, &d);
    /* a barycentric mix of three vertices lies in their plane to rounding: coordinates 0.5 m, eps 1.1e-16 */
    double worst = 0;
    for (int s = 0; s < g.nstrands; s++) {
        double dist = distance_to_mesh(&m, at(g.x, g.offsets[s]));
        if (dist > worst) worst = dist;
    }
    if (worst > 1e-12) fail_msg("a root is %g m off the scalp", worst);
    dr_groom_free(&g);
    dr_trimesh_free(&m);
}

/* Two separate triangles of areas 1 and 3: a quarter of the roots on the first. 40000 roots give a standard
 * deviation of sqrt(0.25·0.75/40000) = 0.0022 on that fraction, so 0.01 is 4.6σ. Within a triangle the mean
 * root is its centroid: a coordinate's spread over the unit right triangle is below 0.25, so its mean over
 * ~10000 roots is within 0.0025 (1σ) and 0.012 is ~5σ. */
static void test_uniform_by_area(void **state)
{
    (void)state;
    double v[] = {0, 0, 0, 1, 0, 0, 0, 2, 0, /* area 1 */ 5, 0, 0, 8, 0, 0, 5, 2, 0 /* area 3 */};
    int tri[] = {0, 1, 2, 3, 4, 5};
    DrTriMesh m = {.nv = 6, .nt = 2, .v = v, .tri = tri};
    DrGroomDesc d;
    dr_groom_desc_default(&d);
    d.count = 40000;
    d.segments = 1;
    DrGroom g = grow(&m, &d);
    int small = 0;
    DrVec3 mean = dr_v3(0, 0, 0);
    for (int s = 0; s < g.nstrands; s++) {
        DrVec3 r = at(g.x, g.offsets[s]);
        if (r.x < 2.5) {
            small++;
            mean = dr_v3_add(mean, r);
        }
    }
    double frac = (double)small / g.nstrands;
    if (fabs(frac - 0.25) > 0.01) fail_msg("%.4f of the roots on the quarter-area triangle", frac);
    mean = dr_v3_scale(mean, 1.0 / small);
    if (fabs(mean.x - 1.0 / 3.0) > 0.012 || fabs(mean.y - 2.0 / 3.0) > 0.024 || mean.z != 0.0)
        fail_msg("mean root (%g, %g, %g) is not the centroid (1/3, 2/3, 0)", mean.x, mean.y, mean.z);
    dr_groom_free(&g);
}

/* Largest angle (degrees) between a vertex's area-weighted normal and its radial direction. */
static double vertex_normal_deviation(const DrTriMesh *m)
{
    DrVec3 *vn = calloc((size_t)m->nv, sizeof(DrVec3));
    assert_non_null(vn);
    for (int t = 0; t < m->nt; t++) {
        const int *tri = &m->tri[3 * t];
        DrVec3 a = at(m->v, tri[0]), b = at(m->v, tri[1]), c = at(m->v, tri[2]);
        DrVec3 n = dr_v3_cross(dr_v3_sub(b, a), dr_v3_sub(c, a));
        for (int k = 0; k < 3; k++) vn[tri[k]] = dr_v3_add(vn[tri[k]], n);
    }
    double worst = 0;
    for (int i = 0; i < m->nv; i++) {
        double c = dr_v3_dot(dr_v3_normalize(vn[i]), dr_v3_normalize(at(m->v, i)));
        worst = fmax(worst, acos(fmin(1.0, c)) * 180.0 / DR_PI);
    }
    free(vn);
    return worst;
}

/* Straight strands run along their root normal. On the octahedron (radial vertex normals) that normal is the
 * root's radial direction to rounding. On the icosphere the vertex normals are up to 0.68° off radial (its
 * valence-5 and valence-6 vertices), and the normalised mix of them at a root is no further off than the
 * worst of them, whereas a face normal would be up to ~4.6° off (the facets' angular circumradius). */
static void test_strands_along_normals(void **state)
{
    (void)state;
    DrTriMesh oct = octahedron(0.5), sph = load_sphere();
    DrTriMesh *meshes[2] = {&oct, &sph};
    for (int mi = 0; mi < 2; mi++) {
        DrGroomDesc d;
        dr_groom_desc_default(&d);
        d.count = 500;
        DrGroom g = grow(meshes[mi], &d);
        double worst_axis = 0, worst_radial = 0;
        for (int s = 0; s < g.nstrands; s++) {
            DrVec3 root = at(g.x, g.offsets[s]), n = at(g.root_normal, s);
            for (int k = g.offsets[s] + 1; k < g.offsets[s + 1]; k++) {
                DrVec3 d0 = dr_v3_sub(at(g.x, k), root);
                double off = dr_v3_norm(dr_v3_cross(d0, n)) / dr_v3_norm(d0);
                if (off > worst_axis) worst_axis = off;
                assert_true(dr_v3_dot(d0, n) > 0);
            }
            double c = dr_v3_dot(n, dr_v3_normalize(root));
            double ang = acos(fmin(1.0, c)) * 180.0 / DR_PI;
            if (ang > worst_radial) worst_radial = ang;
        }
        /* root + s·n rounds each coordinate (0.5 m) to 1.1e-16: over 4 mm that is ~1e-13 of direction */
        if (worst_axis > 1e-12) fail_msg("mesh %d: a strand leaves its normal by %g", mi, worst_axis);
        if (mi == 0) { /* compare vectors: acos near 1 would lose half the digits */
            for (int s = 0; s < g.nstrands; s++) {
                DrVec3 r = dr_v3_normalize(at(g.x, g.offsets[s]));
                assert_true(dr_v3_norm(dr_v3_sub(at(g.root_normal, s), r)) < 1e-14);
            }
        } else {
            double bound = vertex_normal_deviation(&sph);
            assert_true(bound > 0.5 && bound < 1.0);
            if (worst_radial > bound * (1 + 1e-6))
                fail_msg("icosphere: a normal is %g degrees from radial, the vertex normals at most %g", worst_radial,
                         bound);
        }
        dr_groom_free(&g);
    }
    dr_trimesh_free(&oct);
    dr_trimesh_free(&sph);
}

/* The mesh's own normals are not used; where the vertex normals cancel (a double-sided sheet) the triangle's
 * normal is taken. */
static void test_normals_from_the_triangles(void **state)
{
    (void)state;
    DrTriMesh oct = octahedron(1.0);
    DrGroomDesc d;
    dr_groom_desc_default(&d);
    DrGroom a = grow(&oct, &d);
    oct.n = calloc(18, sizeof(double));
    assert_non_null(oct.n);
    for (int i = 0; i < 6; i++) oct.n[3 * i] = 1.0; /* all wrong */
    DrGroom b = grow(&oct, &d);
    assert_memory_equal(a.x, b.x, sizeof(double) * 3 * (size_t)a.offsets[a.nstrands]);
    assert_memory_equal(a.root_normal, b.root_normal, sizeof(double) * 3 * (size_t)a.nstrands);
    dr_groom_free(&a);
    dr_groom_free(&b);
    dr_trimesh_free(&oct);

    double v[] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    int tri[] = {0, 1, 2, 0, 2, 1};
    DrTriMesh sheet = {.nv = 3, .nt = 2, .v = v, .tri = tri};
    d.count = 200;
    DrGroom g = grow(&sheet, &d);
    int up = 0;
    for (int s = 0; s < g.nstrands; s++) {
        DrVec3 n = at(g.root_normal, s);
        assert_true(n.x == 0.0 && n.y == 0.0 && fabs(n.z) == 1.0);
        up += n.z > 0;
    }
    assert_true(up > 50 && up < 150); /* both faces are picked */
    dr_groom_free(&g);
}

/* A helix of radius r: the strand's points projected on the plane perpendicular to the normal lie on a circle
 * of radius r, so three consecutive ones have circumradius r; the rise along the normal after arc length s is
 * pitch·s/turn with turn = sqrt((2πr)² + pitch²); the edges are equal chords. Tolerances: coordinates of
 * size 1 m give differences of chords ~2 mm good to ~1e-13 relative; the circumradius divides by an area of
 * such differences, so 1e-9 relative leaves ample room. */
static void test_curl(void **state)
{
    (void)state;
    DrTriMesh oct = octahedron(1.0);
    DrGroomDesc d;
    dr_groom_desc_default(&d);
    d.count = 50;
    d.segments = 48;
    d.curl_radius = 0.004;
    d.curl_pitch = 0.01;
    DrGroom g = grow(&oct, &d);
    const double r = d.curl_radius, p = d.curl_pitch;
    const double turn = sqrt(4 * DR_PI * DR_PI * r * r + p * p);
    const double dphi = 2 * DR_PI * (d.length / d.segments) / turn;
    const double chord = sqrt(pow(2 * r * sin(dphi / 2), 2) + pow(p * dphi / (2 * DR_PI), 2));
    for (int s = 0; s < g.nstrands; s++) {
        DrVec3 n = at(g.root_normal, s), root = at(g.x, g.offsets[s]);
        int o = g.offsets[s];
        for (int k = 0; k + 1 < d.segments + 1; k++) {
            double e = dr_v3_norm(dr_v3_sub(at(g.x, o + k + 1), at(g.x, o + k)));
            assert_true(fabs(e - chord) < 1e-12);
            double rise = dr_v3_dot(dr_v3_sub(at(g.x, o + k + 1), root), n);
            assert_true(fabs(rise - p * (k + 1) * (d.length / d.segments) / turn) < 1e-12);
        }
        for (int k = 1; k + 1 < d.segments + 1; k++) {
            DrVec3 q[3];
            for (int j = 0; j < 3; j++) {
                DrVec3 y = dr_v3_sub(at(g.x, o + k - 1 + j), root);
                q[j] = dr_v3_sub(y, dr_v3_scale(n, dr_v3_dot(y, n)));
            }
            double a = dr_v3_norm(dr_v3_sub(q[1], q[0])), b = dr_v3_norm(dr_v3_sub(q[2], q[1]));
            double c = dr_v3_norm(dr_v3_sub(q[2], q[0]));
            double area = 0.5 * dr_v3_norm(dr_v3_cross(dr_v3_sub(q[1], q[0]), dr_v3_sub(q[2], q[0])));
            double R = a * b * c / (4 * area);
            if (fabs(R - r) > 1e-9 * r) fail_msg("strand %d: circumradius %.15g, curl radius %g", s, R, r);
        }
        /* the helix is right-handed about n: (x1 − x0) × (x2 − x1) has a positive component along n */
        DrVec3 e0 = dr_v3_sub(at(g.x, o + 1), at(g.x, o)), e1 = dr_v3_sub(at(g.x, o + 2), at(g.x, o + 1));
        assert_true(dr_v3_dot(dr_v3_cross(e0, e1), n) > 0);
        /* the chords are shorter than the arc they span (by 0.2 % here: 1.85 turns in 48 segments) */
        double L = polyline_length(&g, s);
        assert_true(L < d.length && fabs(L - d.segments * chord) < 1e-12);
    }
    dr_groom_free(&g);
    dr_trimesh_free(&oct);
}

static void test_length_jitter(void **state)
{
    (void)state;
    DrTriMesh oct = octahedron(1.0);
    DrGroomDesc d;
    dr_groom_desc_default(&d);
    d.count = 1000;
    d.length_jitter = 0.3;
    DrGroom g = grow(&oct, &d);
    double lo = INFINITY, hi = 0;
    for (int s = 0; s < g.nstrands; s++) {
        double L = polyline_length(&g, s);
        assert_true(L >= 0.7 * d.length - 1e-15 && L < 1.3 * d.length);
        lo = fmin(lo, L);
        hi = fmax(hi, L);
        double e0 = dr_v3_norm(dr_v3_sub(at(g.x, g.offsets[s] + 1), at(g.x, g.offsets[s])));
        assert_true(fabs(e0 - L / d.segments) < 1e-14); /* equal edges within a strand */
    }
    /* 1000 uniform draws: the extreme tenths of the range are hit with probability 1 − 0.9^1000 */
    assert_true(lo < 0.76 * d.length && hi > 1.24 * d.length);
    dr_groom_free(&g);
    dr_trimesh_free(&oct);
}

static void test_deterministic_per_seed(void **state)
{
    (void)state;
    DrTriMesh m = load_sphere();
    DrGroomDesc d;
    dr_groom_desc_default(&d);
    d.curl_radius = 0.003;
    d.length_jitter = 0.2;
    DrGroom a = grow(&m, &d), b = grow(&m, &d);
    size_t nx = sizeof(double) * 3 * (size_t)a.offsets[a.nstrands];
    assert_memory_equal(a.x, b.x, nx);
    assert_memory_equal(a.root_normal, b.root_normal, sizeof(double) * 3 * (size_t)a.nstrands);
    assert_memory_equal(a.offsets, b.offsets, sizeof(int) * (size_t)(a.nstrands + 1));
    dr_groom_free(&b);

    d.seed = 2;
    b = grow(&m, &d);
    int same = 0;
    for (int s = 0; s < a.nstrands; s++) same += memcmp(&a.x[3 * a.offsets[s]], &b.x[3 * b.offsets[s]], 24) == 0;
    assert_int_equal(same, 0);
    dr_groom_free(&b);

    /* the roots depend on mesh, count and seed only: not on curl, jitter, length or segments */
    d.seed = 1;
    d.curl_radius = 0.0;
    d.length_jitter = 0.0;
    d.length = 0.2;
    d.segments = 3;
    b = grow(&m, &d);
    for (int s = 0; s < a.nstrands; s++) {
        assert_memory_equal(&a.x[3 * a.offsets[s]], &b.x[3 * b.offsets[s]], 24);
        assert_memory_equal(&a.root_normal[3 * s], &b.root_normal[3 * s], 24);
    }
    dr_groom_free(&a);
    dr_groom_free(&b);
    dr_trimesh_free(&m);
}

static void test_grow_bad_input(void **state)
{
    (void)state;
    DrTriMesh oct = octahedron(1.0);
    DrGroomDesc base, bad[8];
    dr_groom_desc_default(&base);
    for (int i = 0; i < 8; i++) bad[i] = base;
    bad[0].count = 0;
    bad[1].segments = 0;
    bad[2].length = 0.0;
    bad[3].length = NAN;
    bad[4].curl_radius = -1e-3;
    bad[5].curl_radius = 1e-3;
    bad[5].curl_pitch = 0.0;
    bad[6].length_jitter = 1.0;
    bad[7].count = 1000000;
    bad[7].segments = 5000;
    const char *expect[8] = {"groom: count = 0; grow at least one strand",
                             "groom: segments = 0",
                             "groom: length = 0 m; give a positive strand length",
                             "groom: length = nan m",
                             "groom: curl_radius = -0.001 m",
                             "groom: curl_pitch = 0 m",
                             "groom: length_jitter = 1; give a fraction in [0, 1)",
                             "make more than 2147483647 vertices"};
    for (int i = 0; i < 8; i++) {
        DrGroom g;
        memset(&g, 0xab, sizeof g);
        DrError err;
        assert_int_equal(dr_groom_grow(&oct, &bad[i], &g, &err), DR_ERR_INPUT);
        assert_contains(err.message, expect[i]);
        assert_empty(&g);
    }

    DrGroom g;
    DrError err;
    DrTriMesh empty = {0};
    assert_int_equal(dr_groom_grow(&empty, &base, &g, &err), DR_ERR_INPUT);
    assert_contains(err.message, "the scalp mesh has no triangles (0 vertices, 0 triangles)");
    assert_empty(&g);
    double line[] = {0, 0, 0, 1, 0, 0, 2, 0, 0};
    int tri[] = {0, 1, 2};
    DrTriMesh flat = {.nv = 3, .nt = 1, .v = line, .tri = tri};
    assert_int_equal(dr_groom_grow(&flat, &base, &g, &err), DR_ERR_INPUT);
    assert_contains(err.message, "the scalp mesh has no area (1 triangles, all degenerate)");
    assert_empty(&g);
    line[4] = INFINITY;
    assert_int_equal(dr_groom_grow(&flat, &base, &g, &err), DR_ERR_INPUT);
    assert_contains(err.message, "scalp vertex 1 has a non-finite coordinate");
    assert_empty(&g);
    dr_trimesh_free(&oct);
}

/* ---- OBJ polylines ------------------------------------------------------------------------------------------- */

static void write_text(const char *name, const char *text, size_t len, char *path, size_t size)
{
    snprintf(path, size, "%s/%s", g_dir, name);
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(text, 1, len, f), len);
    assert_int_equal(fclose(f), 0);
}

static void assert_vec(DrVec3 v, double x, double y, double z)
{
    if (fabs(v.x - x) > 1e-15 || fabs(v.y - y) > 1e-15 || fabs(v.z - z) > 1e-15)
        fail_msg("(%g, %g, %g) != (%g, %g, %g)", v.x, v.y, v.z, x, y, z);
}

static void test_read_obj(void **state)
{
    (void)state;
    DrGroom g;
    DrError err;
    if (dr_groom_read_obj("tests/data/hair_curves.obj", &g, &err) != DR_OK) fail_msg("%s", err.message);
    assert_int_equal(g.nstrands, 3);
    int off[] = {0, 4, 6, 9};
    for (int s = 0; s <= 3; s++) assert_int_equal(g.offsets[s], off[s]);
    assert_vec(at(g.x, 0), 0, 0, 0);
    assert_vec(at(g.x, 3), 0, 0.03, 0);
    assert_vec(at(g.x, 4), 0.1, 0, 0); /* "5/1": the vertex index */
    assert_vec(at(g.x, 5), 0.1, 0, 0.01);
    assert_vec(at(g.x, 6), 0.2, 0, 0); /* "-3": three back from the last vertex */
    assert_vec(at(g.x, 8), 0.21, -0.02, 0);
    assert_vec(at(g.root_normal, 0), 0, 1, 0); /* the first edge's direction */
    assert_vec(at(g.root_normal, 1), 0, 0, 1);
    assert_vec(at(g.root_normal, 2), 0, -1, 0);
    dr_groom_free(&g);
    assert_empty(&g);

    /* CRLF, tabs, an inline comment, a forward reference, 'v' with w, a shared vertex, skipped 'f' and 'p' */
    const char *text = "# curves\r\nv 0 0 0\r\nv\t0 0 2 1\r\nl 1 2 3 # root first\r\nf 1 2 3\r\np 1\r\n"
                       "v 0 3 0\r\nl 3 1\r\n";
    char path[512];
    write_text("forms.obj", text, strlen(text), path, sizeof path);
    if (dr_groom_read_obj(path, &g, &err) != DR_OK) fail_msg("%s", err.message);
    assert_int_equal(g.nstrands, 2);
    assert_int_equal(g.offsets[1], 3);
    assert_int_equal(g.offsets[2], 5);
    assert_vec(at(g.x, 2), 0, 3, 0);
    assert_vec(at(g.x, 4), 0, 0, 0);
    assert_vec(at(g.root_normal, 0), 0, 0, 1);
    assert_vec(at(g.root_normal, 1), 0, -1, 0);
    dr_groom_free(&g);

    /* "# radius" lines are optional: a strand before the first and the mesh stage's own files both read */
    text = "v 0 0 0\nv 0 0 2\nl 1 2\n# radius 5e-05\nl 2 1\n";
    write_text("radius.obj", text, strlen(text), path, sizeof path);
    if (dr_groom_read_obj(path, &g, &err) != DR_OK) fail_msg("%s", err.message);
    assert_int_equal(g.nstrands, 2);
    assert_vec(at(g.root_normal, 1), 0, 0, -1);
    dr_groom_free(&g);
    double wx[] = {0, 0, 0, 0, 1, 0, 0, 3, 0, 1, 0, 0, 2, 0, 0};
    int woff[] = {0, 3, 5};
    double wr[] = {5e-5, 1e-4};
    DrPolylines p = {2, woff, wx, wr, NULL};
    snprintf(path, sizeof path, "%s/written.obj", g_dir);
    if (dr_io_write_polylines_obj(path, &p, "strands", &err) != DR_OK) fail_msg("%s", err.message);
    if (dr_groom_read_obj(path, &g, &err) != DR_OK) fail_msg("%s", err.message);
    assert_int_equal(g.nstrands, 2);
    assert_memory_equal(g.offsets, woff, sizeof woff);
    assert_memory_equal(g.x, wx, sizeof wx); /* small integers: exact through %.9g */
    assert_vec(at(g.root_normal, 0), 0, 1, 0);
    assert_vec(at(g.root_normal, 1), 1, 0, 0);
    dr_groom_free(&g);
}

typedef struct BadObj {
    const char *name, *text; /* a file under tests/data/bad/ (text NULL), or written here */
    size_t len;              /* bytes of text; 0: strlen */
    int line, col;           /* expected position (col 0: not checked) */
    const char *expect;
} BadObj;

static void test_read_obj_bad(void **state)
{
    (void)state;
    static const char nul[] = "v 0 0 0\nv 0 1 0\nl 1\0 2\n";
    const BadObj cases[] = {
        {"hair_curves_short.obj", NULL, 0, 5, 1, "'l' record with 1 vertex; a strand needs at least 2 (root first)"},
        {"hair_curves_index.obj", NULL, 0, 6, 5, "vertex index 4 is out of range: the file has 3 'v' records"},
        {"hair_curves_zero_edge.obj", NULL, 0, 5, 7,
         "zero-length edge: vertices 2 and 3 of this strand (OBJ indices 2 and 3) are at the same position; remove "
         "the repeated vertex"},
        {"hair_curves_none.obj", NULL, 0, 0, 0,
         "no 'l' records (polylines) among 5 lines: each strand is an 'l' record listing its 'v' indices, root first"},
        {"index0.obj", "v 0 0 0\nv 1 0 0\nl 0 1\n", 0, 3, 3, "vertex index 0: OBJ indices start at 1"},
        {"relative.obj", "v 0 0 0\nl -1 -2\nv 1 0 0\n", 0, 2, 6,
         "vertex index -2 is out of range: only 1 'v' records come before this line"},
        {"word.obj", "v 0 0 0\nv 1 0 0\nl 1 two\n", 0, 3, 5, "'two' is not a vertex index"},
        {"short_v.obj", "v 0 0 0\nv 1 0\n", 0, 2, 1, "'v' record with 2 numbers; a vertex is \"v x y z\" in metres"},
        {"bad_num.obj", "v 0 0 0\nv 1 0 0x\n", 0, 2, 7, "'0x' is not a number"},
        {"nan.obj", "v 0 0 0\nv 1 nan 0\nl 1 2\n", 0, 2, 5, "vertex coordinate 'nan' is not finite"},
        {"ctrl.obj", "v 0 0 0\nv 1 0 0\nl 1 2\x01\n", 0, 3, 6, "control byte 0x01: this is not a text OBJ file"},
        {"nul.obj", nul, sizeof nul - 1, 3, 4, "a NUL byte: this is not a text OBJ file"},
        {"cont.obj", "v 0 0 0\nv 1 0 0\nl 1 \\\n 2\n", 0, 3, 5, "'l' record continued on the next line ('\\')"},
        {"empty.obj", "", 0, 0, 0, "no 'l' records (polylines) among 0 lines"},
        {"bad_radius.obj", "v 0 0 0\nv 1 0 0\n# radius -1\nl 1 2\n", 0, 3, 10,
         "strand radius -1 is not a finite number >= 0"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        const BadObj *c = &cases[i];
        char path[512];
        if (c->text)
            write_text(c->name, c->text, c->len ? c->len : strlen(c->text), path, sizeof path);
        else
            snprintf(path, sizeof path, "tests/data/bad/%s", c->name);
        DrGroom g;
        memset(&g, 0xab, sizeof g);
        DrError err;
        dr_error_clear(&err);
        assert_int_equal(dr_groom_read_obj(path, &g, &err), DR_ERR_INPUT);
        assert_empty(&g);
        if (!strstr(err.message, c->expect)) fail_msg("%s: expected \"%s\" in \"%s\"", c->name, c->expect, err.message);
        assert_string_equal(err.file, path);
        if (err.line != c->line || (c->col && err.col != c->col))
            fail_msg("%s: reported at %d:%d, expected %d:%d", c->name, err.line, err.col, c->line, c->col);
        char buf[4096], want[600];
        dr_error_format(&err, buf, sizeof buf);
        if (c->line) snprintf(want, sizeof want, "%s:%d:", path, c->line);
        else snprintf(want, sizeof want, "%s: error: ", path);
        assert_contains(buf, want);
    }

    DrGroom g;
    DrError err;
    char missing[512];
    snprintf(missing, sizeof missing, "%s/no_such_curves.obj", g_dir);
    assert_int_equal(dr_groom_read_obj(missing, &g, &err), DR_ERR_INPUT);
    assert_empty(&g);
    assert_string_equal(err.file, missing);
    assert_contains(err.message, "cannot open the polyline file: No such file or directory");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_defaults),
        cmocka_unit_test(test_counts_and_lengths),
        cmocka_unit_test(test_roots_on_the_scalp),
        cmocka_unit_test(test_uniform_by_area),
        cmocka_unit_test(test_strands_along_normals),
        cmocka_unit_test(test_normals_from_the_triangles),
        cmocka_unit_test(test_curl),
        cmocka_unit_test(test_length_jitter),
        cmocka_unit_test(test_deterministic_per_seed),
        cmocka_unit_test(test_grow_bad_input),
        cmocka_unit_test(test_read_obj),
        cmocka_unit_test(test_read_obj_bad),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
