/* The mesh stage's particle caches (<element>.NNNN.points.vdb, mesh.write_points) against the frame caches they
 * come from: bin/bake and bin/mesh run on small scenes under $TMPDIR, then every point is read back through the
 * vdb shim and matched with its particle or vertex in the frame cache. A liquid's points carry the bake's ids (the
 * same particle, whatever its index), an MPM solid's J = det F, strain and current volume, a hair's strand and
 * width. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdlib.h>
#include <string.h>

#include "core/core.h"
#include "io/io.h"
#include "vdb/vdb.h"

static char g_out[1024];

static int setup(void **state)
{
    (void)state;
    snprintf(g_out, sizeof g_out, "%s/drench_points_XXXXXX", dr_temp_dir());
    return mkdtemp(g_out) ? 0 : -1;
}

static int teardown(void **state)
{
    (void)state;
    char cmd[1200];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_out);
    return system(cmd) == 0 ? 0 : -1;
}

/* bake and mesh frames 1..last of `scene` into g_out (quietly); asserts both succeed. */
static void bake_and_mesh(const char *scene, int last)
{
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "bin/bake %s --frames 1-%d --out '%s' -q -j 2 >/dev/null 2>&1", scene, last, g_out);
    assert_int_equal(system(cmd), 0);
    snprintf(cmd, sizeof cmd, "bin/mesh %s --frames 1-%d --out '%s' -q -j 2 >/dev/null 2>&1", scene, last, g_out);
    assert_int_equal(system(cmd), 0);
}

static double *read_f64(DrH5 *h, const char *path, uint64_t *rows)
{
    int rank;
    uint64_t dims[4];
    double *d = NULL;
    DrError err;
    assert_int_equal(dr_h5_read_f64(h, path, &rank, dims, &d, &err), DR_OK);
    *rows = dims[0];
    return d;
}

/* The points attribute `name` of `path`: n values of width w (doubles, or int64 into *ints). */
static double *points(const char *path, const char *name, long n_expect, int w_expect, int64_t **ints)
{
    long n = -1;
    int w = 0;
    double *f = NULL;
    int64_t *i = NULL;
    DrError err;
    assert_int_equal(dr_vdb_points_read(path, name, &n, &w, &f, &i, &err), DR_OK);
    assert_int_equal(n, n_expect);
    assert_int_equal(w, w_expect);
    if (ints) *ints = i;
    else free(i);
    return f;
}

static bool near(double a, double b, double tol) { return fabs(a - b) <= tol; }

/* 1. Liquid: every particle of frame 3 of the small dam is in water.0003.points.vdb once, under its frame-cache id,
   at its position (to 1e-6 of the 0.025 m point voxel: float offsets within the voxel), with its velocity (32-bit
   floats: 1e-6 relative) and its volume Δx³/per_cell. */
static void test_liquid_points(void **state)
{
    (void)state;
    bake_and_mesh("assets/scenes/small_dam.json", 3);
    char frame[1300], pts[1300], names[256];
    snprintf(frame, sizeof frame, "%s/small_dam/bake/frame.0003.h5", g_out);
    snprintf(pts, sizeof pts, "%s/small_dam/mesh/water.0003.points.vdb", g_out);
    DrError err;
    assert_int_equal(dr_vdb_points_attributes(pts, names, sizeof names, &err), DR_OK);
    assert_string_equal(names, "P,v,id,volume");
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_open(frame, &h, &err), DR_OK);
    uint64_t n, nv;
    double *x = read_f64(h, "/water/position", &n), *v = read_f64(h, "/water/velocity", &nv);
    int rank;
    uint64_t dims[4];
    int64_t *id = NULL;
    assert_int_equal(dr_h5_read_i64(h, "/water/id", &rank, dims, &id, &err), DR_OK);
    assert_int_equal(dims[0], n);
    dr_h5_close(&h);

    /* the frame cache's index of each id (no emitter: ids are 0 .. n−1) */
    long *at = malloc(sizeof(long) * n);
    for (uint64_t p = 0; p < n; p++) at[p] = -1;
    for (uint64_t p = 0; p < n; p++) {
        assert_true(id[p] >= 0 && (uint64_t)id[p] < n);
        at[id[p]] = (long)p;
    }
    int64_t *pid = NULL;
    double *P = points(pts, "P", (long)n, 3, NULL), *V = points(pts, "v", (long)n, 3, NULL);
    double *vol = points(pts, "volume", (long)n, 1, NULL);
    free(points(pts, "id", (long)n, 1, &pid));
    unsigned char *seen = calloc(n, 1);
    long moved = 0;
    for (uint64_t k = 0; k < n; k++) {
        assert_true(pid[k] >= 0 && (uint64_t)pid[k] < n);
        assert_int_equal(seen[pid[k]], 0);
        seen[pid[k]] = 1;
        long p = at[pid[k]];
        moved += (uint64_t)p != k;
        for (int a = 0; a < 3; a++) {
            assert_true(near(P[3 * k + a], x[3 * p + a], 1e-6 * 0.025));
            assert_true(near(V[3 * k + a], v[3 * p + a], 1e-6 * (1.0 + fabs(v[3 * p + a]))));
        }
        assert_true(near(vol[k], 0.025 * 0.025 * 0.025 / 8, 1e-6 * vol[k]));
    }
    print_message("liquid points: %llu, %ld stored in another order than the frame cache's\n",
                  (unsigned long long)n, moved);
    free(at);
    free(seen);
    free(x);
    free(v);
    free(id);
    free(P);
    free(V);
    free(vol);
    free(pid);
}

/* 2. MPM solid: particle k of the frame cache is point id k, with J = det F, the current volume J·V₀ and strain
   √(2/3 dev E : dev E) of E = ½(FᵀF − I), all 32-bit floats (1e-6 relative). Frame 4 of the drop: the sphere has
   landed (strain above 0). */
static void test_mpm_points(void **state)
{
    (void)state;
    bake_and_mesh("tests/data/mpm_drop.json", 4);
    char frame[1300], pts[1300], names[256];
    snprintf(frame, sizeof frame, "%s/mpm_drop/bake/frame.0004.h5", g_out);
    snprintf(pts, sizeof pts, "%s/mpm_drop/mesh/jelly.0004.points.vdb", g_out);
    DrError err;
    assert_int_equal(dr_vdb_points_attributes(pts, names, sizeof names, &err), DR_OK);
    assert_string_equal(names, "P,v,id,volume,J,strain");
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_open(frame, &h, &err), DR_OK);
    uint64_t n, nf, n0;
    double *x = read_f64(h, "/jelly/position", &n), *F = read_f64(h, "/jelly/deformation_gradient", &nf);
    double *V0 = read_f64(h, "/jelly/volume", &n0);
    dr_h5_close(&h);
    assert_int_equal(nf, n);
    assert_int_equal(n0, n);
    int64_t *pid = NULL;
    double *P = points(pts, "P", (long)n, 3, NULL), *J = points(pts, "J", (long)n, 1, NULL);
    double *S = points(pts, "strain", (long)n, 1, NULL), *vol = points(pts, "volume", (long)n, 1, NULL);
    free(points(pts, "id", (long)n, 1, &pid));
    double smax = 0.0;
    for (uint64_t k = 0; k < n; k++) {
        assert_true(pid[k] >= 0 && (uint64_t)pid[k] < n);
        const uint64_t p = (uint64_t)pid[k];
        const double *f = F + 9 * p;
        for (int a = 0; a < 3; a++) assert_true(near(P[3 * k + a], x[3 * p + a], 1e-6 * 0.02));
        double det = f[0] * (f[4] * f[8] - f[5] * f[7]) - f[1] * (f[3] * f[8] - f[5] * f[6]) +
                     f[2] * (f[3] * f[7] - f[4] * f[6]);
        double E[3][3], tr = 0.0, dd = 0.0;
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) {
                double s = 0.0;
                for (int m = 0; m < 3; m++) s += f[3 * m + r] * f[3 * m + c]; /* (FᵀF)_rc */
                E[r][c] = 0.5 * (s - (r == c));
            }
        for (int r = 0; r < 3; r++) tr += E[r][r] / 3.0;
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) dd += (E[r][c] - (r == c) * tr) * (E[r][c] - (r == c) * tr);
        double strain = sqrt(2.0 / 3.0 * dd);
        assert_true(near(J[k], det, 1e-6 * fabs(det)));
        assert_true(near(vol[k], det * V0[p], 1e-6 * fabs(det * V0[p])));
        assert_true(near(S[k], strain, 1e-6 * strain + 1e-7));
        if (S[k] > smax) smax = S[k];
    }
    print_message("mpm points: %llu, largest strain %.3g\n", (unsigned long long)n, smax);
    assert_true(smax > 1e-4);
    free(x);
    free(F);
    free(V0);
    free(P);
    free(J);
    free(S);
    free(vol);
    free(pid);
}

/* 3. Hair: vertex i is point id i, with its strand's index and width 2·radius. */
static void test_hair_points(void **state)
{
    (void)state;
    bake_and_mesh("tests/data/hair_small.json", 2);
    char frame[1300], pts[1300], names[256];
    snprintf(frame, sizeof frame, "%s/hair_small/bake/frame.0002.h5", g_out);
    DrError err;
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_open(frame, &h, &err), DR_OK);
    char **groups = NULL;
    int ng = 0;
    assert_int_equal(dr_h5_list(h, "/", &groups, &ng, &err), DR_OK);
    const char *hair = NULL;
    char path[512];
    for (int g = 0; g < ng && !hair; g++) {
        snprintf(path, sizeof path, "/%s/strand_offsets", groups[g]);
        if (dr_h5_has(h, path)) hair = groups[g];
    }
    assert_non_null(hair);
    uint64_t n, S;
    snprintf(path, sizeof path, "/%s/position", hair);
    double *x = read_f64(h, path, &n);
    snprintf(path, sizeof path, "/%s/radius", hair);
    double *radius = read_f64(h, path, &S);
    int rank;
    uint64_t dims[4];
    int64_t *off = NULL;
    snprintf(path, sizeof path, "/%s/strand_offsets", hair);
    assert_int_equal(dr_h5_read_i64(h, path, &rank, dims, &off, &err), DR_OK);
    dr_h5_close(&h);
    snprintf(pts, sizeof pts, "%s/hair_small/mesh/%s.0002.points.vdb", g_out, hair);
    assert_int_equal(dr_vdb_points_attributes(pts, names, sizeof names, &err), DR_OK);
    assert_string_equal(names, "P,v,id,strand,width");
    int64_t *pid = NULL, *strand = NULL;
    double *P = points(pts, "P", (long)n, 3, NULL), *W = points(pts, "width", (long)n, 1, NULL);
    free(points(pts, "id", (long)n, 1, &pid));
    free(points(pts, "strand", (long)n, 1, &strand));
    for (uint64_t k = 0; k < n; k++) {
        assert_true(pid[k] >= 0 && (uint64_t)pid[k] < n);
        int64_t i = pid[k];
        assert_true(strand[k] >= 0 && (uint64_t)strand[k] < S);
        assert_true(off[strand[k]] <= i && i < off[strand[k] + 1]);
        assert_true(near(W[k], 2.0 * radius[strand[k]], 1e-6 * radius[strand[k]]));
        for (int a = 0; a < 3; a++) assert_true(fabs(P[3 * k + a] - x[3 * i + a]) < 1e-5);
    }
    print_message("hair points: %llu vertices of %llu strands\n", (unsigned long long)n, (unsigned long long)S);
    for (int g = 0; g < ng; g++) free(groups[g]);
    free(groups);
    free(x);
    free(radius);
    free(off);
    free(P);
    free(W);
    free(pid);
    free(strand);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_liquid_points, setup, teardown),
        cmocka_unit_test_setup_teardown(test_mpm_points, setup, teardown),
        cmocka_unit_test_setup_teardown(test_hair_points, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
