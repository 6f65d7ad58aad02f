/* Unit tests of src/core: errors, checked allocation, math (rotation exp and log, 3×3 matrices in flat arrays), meshes,
 * arena, hashing, parallel-for, rng. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "core/core.h"

static void test_error_format_and_exit_codes(void **state)
{
    (void)state;
    DrError err;
    dr_error_clear(&err);
    DrStatus s = dr_error_set(&err, DR_ERR_INPUT, "scene.json", 3, 7, "bad %s", "thing");
    assert_int_equal(s, DR_ERR_INPUT);
    char buf[256];
    dr_error_format(&err, buf, sizeof buf);
    assert_string_equal(buf, "scene.json:3:7: error: bad thing");
    dr_error_set(&err, DR_ERR_IO, "a.h5", 0, 0, "disk full");
    dr_error_format(&err, buf, sizeof buf);
    assert_string_equal(buf, "a.h5: error: disk full");
    /* a prefix names the element and field, keeping status and file; a success passes through untouched */
    assert_int_equal(dr_error_prefix(DR_ERR_IO, &err, "%s.%s", "jelly", "Mesh.file"), DR_ERR_IO);
    dr_error_format(&err, buf, sizeof buf);
    assert_string_equal(buf, "a.h5: error: jelly.Mesh.file: disk full");
    assert_int_equal(dr_error_prefix(DR_OK, &err, "other"), DR_OK);
    assert_string_equal(err.message, "jelly.Mesh.file: disk full");
    char longer[sizeof err.message + 10];
    memset(longer, 'x', sizeof longer - 1);
    longer[sizeof longer - 1] = 0;
    dr_error_prefix(DR_ERR_IO, &err, "%s", longer);
    assert_int_equal(strlen(err.message), sizeof err.message - 1);
    assert_int_equal(err.message[sizeof err.message - 2], '.');
    assert_int_equal(dr_exit_code(DR_OK), 0);
    assert_int_equal(dr_exit_code(DR_WARN_NOT_CONVERGED), 0);
    assert_int_equal(dr_exit_code(DR_ERR_INPUT), 2);
    assert_int_equal(dr_exit_code(DR_ERR_RUNTIME), 1);
    assert_int_equal(dr_exit_code(DR_ERR_IO), 1);
}

static void test_checked_alloc(void **state)
{
    (void)state;
    DrError err;
    double *p = NULL;
    assert_int_equal(dr_calloc(SIZE_MAX / 2, 16, &p, &err), DR_ERR_NOMEM);
    assert_null(p);
    assert_non_null(strstr(err.message, "overflows"));
    assert_int_equal(dr_calloc(10, sizeof(double), &p, &err), DR_OK);
    for (int i = 0; i < 10; i++) assert_true(p[i] == 0.0);
    assert_int_equal(dr_realloc(20, sizeof(double), &p, &err), DR_OK);
    double *keep = p;
    assert_int_equal(dr_realloc(SIZE_MAX / 4, 8, &p, &err), DR_ERR_NOMEM);
    assert_ptr_equal(p, keep); /* failed realloc keeps the old block */
    free(p);
}

static void test_math_and_xform(void **state)
{
    (void)state;
    DrVec3 a = dr_v3(1, 2, 3), b = dr_v3(-2, 0.5, 4);
    DrVec3 c = dr_v3_cross(a, b);
    assert_true(fabs(dr_v3_dot(c, a)) < 1e-14 && fabs(dr_v3_dot(c, b)) < 1e-14);
    DrMat3 R = dr_m3_from_euler_xyz(dr_v3(0.3, -1.1, 2.0));
    DrMat3 I = dr_m3_mul(R, dr_m3_transpose(R));
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) assert_true(fabs(I.m[i][j] - (i == j)) < 1e-14);
    /* rotation by 90 degrees about z maps x to y */
    DrVec3 y = dr_m3_apply(dr_m3_from_euler_xyz(dr_v3(0, 0, DR_PI / 2)), dr_v3(1, 0, 0));
    assert_true(fabs(y.x) < 1e-15 && fabs(y.y - 1) < 1e-15);
    DrXform X = {R, dr_v3(0.5, -2, 3)};
    DrVec3 p = dr_xform_apply_inverse(X, dr_xform_apply(X, a));
    assert_true(dr_v3_norm(dr_v3_sub(p, a)) < 1e-14);
}

static double m3_max_diff(DrMat3 a, DrMat3 b)
{
    double d = 0.0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) d = fmax(d, fabs(a.m[i][j] - b.m[i][j]));
    return d;
}

static double m3_det(DrMat3 a)
{
    double f[9];
    dr_m3_store(a, f);
    return dr_m3a_det(f);
}

/* A rotation vector of norm th along a uniformly random direction. */
static DrVec3 random_rotation_vector(DrRng *rng, double th)
{
    DrVec3 d;
    do d = dr_v3(2 * dr_rng_uniform(rng) - 1, 2 * dr_rng_uniform(rng) - 1, 2 * dr_rng_uniform(rng) - 1);
    while (dr_v3_dot(d, d) > 1.0 || dr_v3_dot(d, d) < 1e-6);
    return dr_v3_scale(dr_v3_normalize(d), th);
}

/* Rodrigues and its inverse. Every tolerance is a small multiple of ε = 2.2e-16 over entries of size ≤ 1: exp sums
   three terms of products, log's angle and axis keep the round-off of R's entries (the maxima are printed).
   Angles: uniform on [0, π], then the ends, θ = 10⁻ᵏ and θ = π − 10⁻ᵏ for k = 1…16 and θ = 0, π exactly, where a
   log by acos alone loses up to half its digits (δθ ≈ ε/sin θ). */
static void test_rotation_exp_log(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 7);
    double orth = 0.0, det = 0.0, roundtrip = 0.0, logexp = 0.0, euler = 0.0;
    const int n = 100000;
    for (int t = 0; t < n + 34; t++) {
        double th;
        if (t < n) th = DR_PI * dr_rng_uniform(&rng);
        else if (t < n + 16) th = pow(10.0, -(t - n + 1));
        else if (t < n + 32) th = DR_PI - pow(10.0, -(t - n - 15));
        else th = t == n + 32 ? 0.0 : DR_PI;
        DrVec3 w = random_rotation_vector(&rng, th);
        DrMat3 R = dr_m3_rotation_exp(w);
        orth = fmax(orth, m3_max_diff(dr_m3_mul(dr_m3_transpose(R), R), dr_m3_identity()));
        det = fmax(det, fabs(m3_det(R) - 1.0));
        DrVec3 l = dr_m3_rotation_log(R);
        assert_true(dr_v3_norm(l) <= DR_PI * (1.0 + 1e-15));
        roundtrip = fmax(roundtrip, m3_max_diff(dr_m3_rotation_exp(l), R));
        /* log(exp w) = w while the half turn's sign is still decided: sin θ ≫ ε */
        if (th < DR_PI - 1e-9) logexp = fmax(logexp, dr_v3_norm(dr_v3_sub(l, w)));
        /* a rotation not made by exp */
        DrVec3 e = dr_v3(6.3 * dr_rng_uniform(&rng), 6.3 * dr_rng_uniform(&rng), 6.3 * dr_rng_uniform(&rng));
        DrMat3 Q = dr_m3_from_euler_xyz(e);
        euler = fmax(euler, m3_max_diff(dr_m3_rotation_exp(dr_m3_rotation_log(Q)), Q));
    }
    /* beyond a half turn: still a rotation, and log gives the equivalent vector of norm ≤ π */
    for (int t = 0; t < 1000; t++) {
        DrMat3 R = dr_m3_rotation_exp(random_rotation_vector(&rng, DR_PI + 100.0 * dr_rng_uniform(&rng)));
        orth = fmax(orth, m3_max_diff(dr_m3_mul(dr_m3_transpose(R), R), dr_m3_identity()));
        det = fmax(det, fabs(m3_det(R) - 1.0));
        DrVec3 l = dr_m3_rotation_log(R);
        assert_true(dr_v3_norm(l) <= DR_PI * (1.0 + 1e-15));
        roundtrip = fmax(roundtrip, m3_max_diff(dr_m3_rotation_exp(l), R));
    }
    print_message("rotation exp/log over %d angles: |RᵀR − I| %.1e, |det R − 1| %.1e, |exp(log R) − R| %.1e "
                  "(Euler-angle R %.1e), |log(exp w) − w| %.1e\n",
                  n + 1034, orth, det, roundtrip, euler, logexp);
    assert_true(orth < 1e-14);
    assert_true(det < 1e-14);
    assert_true(roundtrip < 1e-14);
    assert_true(euler < 1e-14);
    assert_true(logexp < 1e-14);
    /* a quarter turn about z takes x to y; exp keeps its axis; log of I is 0 */
    DrVec3 y = dr_m3_apply(dr_m3_rotation_exp(dr_v3(0, 0, DR_PI / 2)), dr_v3(1, 0, 0));
    assert_true(fabs(y.x) < 1e-15 && fabs(y.y - 1) < 1e-15 && y.z == 0.0);
    DrVec3 w = dr_v3(0.3, -1.2, 0.7);
    assert_true(dr_v3_norm(dr_v3_sub(dr_m3_apply(dr_m3_rotation_exp(w), w), w)) < 1e-15);
    DrVec3 z = dr_m3_rotation_log(dr_m3_identity());
    assert_true(z.x == 0.0 && z.y == 0.0 && z.z == 0.0);
}

/* The flat-array forms: the bits of the DrMat3 functions (the header's claim, so exact equality), outputs that alias
   inputs, and the inverse, cofactor and determinant against each other. */
static void test_m3_flat_arrays(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 11);
    double inv_res = 0.0, cof_res = 0.0;
    for (int t = 0; t < 1000; t++) {
        double a[9], b[9], x[3], r[9], s[9];
        for (int k = 0; k < 9; k++) a[k] = 4 * dr_rng_uniform(&rng) - 2, b[k] = 4 * dr_rng_uniform(&rng) - 2;
        for (int k = 0; k < 3; k++) x[k] = 4 * dr_rng_uniform(&rng) - 2;
        DrMat3 A = dr_m3_load(a), B = dr_m3_load(b);
        DrVec3 X = dr_v3(x[0], x[1], x[2]);
        dr_m3a_mul(a, b, r);
        dr_m3_store(dr_m3_mul(A, B), s);
        assert_memory_equal(r, s, sizeof r);
        dr_m3a_mul_tn(a, b, r);
        dr_m3_store(dr_m3_mul(dr_m3_transpose(A), B), s);
        assert_memory_equal(r, s, sizeof r);
        dr_m3a_mul_nt(a, b, r);
        dr_m3_store(dr_m3_mul(A, dr_m3_transpose(B)), s);
        assert_memory_equal(r, s, sizeof r);
        dr_m3a_transpose(a, r);
        dr_m3_store(dr_m3_transpose(A), s);
        assert_memory_equal(r, s, sizeof r);
        double y[3], z[3];
        dr_m3a_apply(a, x, y);
        DrVec3 Y = dr_m3_apply(A, X);
        assert_true(y[0] == Y.x && y[1] == Y.y && y[2] == Y.z);
        dr_m3a_apply_t(a, x, y);
        Y = dr_m3_apply(dr_m3_transpose(A), X);
        assert_true(y[0] == Y.x && y[1] == Y.y && y[2] == Y.z);
        /* aliasing: out = an input */
        dr_m3a_mul(a, b, s);
        memcpy(r, a, sizeof r);
        dr_m3a_mul(r, b, r);
        assert_memory_equal(r, s, sizeof r);
        memcpy(r, b, sizeof r);
        dr_m3a_mul(a, r, r);
        assert_memory_equal(r, s, sizeof r);
        memcpy(r, a, sizeof r);
        dr_m3a_transpose(r, r);
        dr_m3a_transpose(a, s);
        assert_memory_equal(r, s, sizeof r);
        memcpy(z, x, sizeof z);
        dr_m3a_apply(a, z, z);
        dr_m3a_apply(a, x, y);
        assert_memory_equal(y, z, sizeof y);
        /* a a⁻¹ = I and cof(a) = det(a) a⁻ᵀ, scaled by the condition |a||a⁻¹| (entries ≤ 2, det ≠ 0 here) */
        double inv[9], ai[9], cof[9], d = dr_m3a_det(a);
        assert_true(dr_m3a_inverse(a, inv));
        dr_m3a_mul(a, inv, ai);
        double cond = sqrt(dr_m3a_ddot(a, a) * dr_m3a_ddot(inv, inv));
        for (int k = 0; k < 9; k++) inv_res = fmax(inv_res, fabs(ai[k] - (k % 4 == 0)) / cond);
        dr_m3a_cofactor(a, cof);
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                cof_res = fmax(cof_res, fabs(cof[3 * i + j] - d * inv[3 * j + i]) / (fabs(d) * cond));
    }
    print_message("flat 3×3: |a a⁻¹ − I|/cond %.1e, |cof − det a⁻ᵀ|/(|det| cond) %.1e\n", inv_res, cof_res);
    assert_true(inv_res < 1e-15);
    assert_true(cof_res < 1e-15);
    /* singular, and not finite: false, out untouched */
    double sing[9] = {1, 2, 3, 2, 4, 6, 0, 1, 5}, nan[9] = {NAN, 0, 0, 0, 1, 0, 0, 0, 1}, out[9], keep[9];
    for (int k = 0; k < 9; k++) out[k] = keep[k] = k;
    assert_false(dr_m3a_inverse(sing, out));
    assert_false(dr_m3a_inverse(nan, out));
    assert_memory_equal(out, keep, sizeof out);
    double cof[9];
    dr_m3a_cofactor(sing, cof); /* defined for singular a: a cof(a)ᵀ = det(a) I = 0 */
    double acT[9];
    dr_m3a_mul_nt(sing, cof, acT);
    for (int k = 0; k < 9; k++) assert_true(fabs(acT[k]) < 1e-14);
    double I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    assert_true(dr_m3a_det(I) == 1.0 && dr_m3a_ddot(I, I) == 3.0);
}

static DrTriMesh unit_cube(void)
{
    static const double v[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1};
    static const int t[] = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                            1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7};
    DrTriMesh m = {8, 12, NULL, NULL, NULL, NULL};
    m.v = malloc(sizeof v);
    m.tri = malloc(sizeof t);
    memcpy(m.v, v, sizeof v);
    memcpy(m.tri, t, sizeof t);
    return m;
}

static void test_trimesh_measures(void **state)
{
    (void)state;
    DrTriMesh m = unit_cube();
    assert_true(fabs(dr_trimesh_volume(&m) - 1.0) < 1e-14);
    assert_true(dr_trimesh_is_closed(&m));
    DrVec3 lo, hi;
    assert_true(dr_trimesh_bounds(&m, &lo, &hi));
    assert_true(lo.x == 0 && hi.z == 1);
    m.nt = 11; /* a missing face opens the mesh */
    assert_false(dr_trimesh_is_closed(&m));
    m.nt = 12;
    int tmp = m.tri[1]; /* flipping one triangle breaks consistent orientation */
    m.tri[1] = m.tri[2];
    m.tri[2] = tmp;
    assert_false(dr_trimesh_is_closed(&m));
    dr_trimesh_free(&m);
    assert_null(m.v);
    DrTriMesh empty = {0};
    assert_false(dr_trimesh_is_closed(&empty));
    assert_false(dr_trimesh_bounds(&empty, &lo, &hi));
}

static void test_arena(void **state)
{
    (void)state;
    DrError err;
    DrArena *a = NULL;
    assert_int_equal(dr_arena_create(4096, &a, &err), DR_OK);
    char *p = dr_arena_alloc(a, 100, 1);
    double *q = dr_arena_alloc(a, 1000, sizeof(double)); /* larger than a block: own block */
    assert_non_null(p);
    assert_non_null(q);
    assert_int_equal((uintptr_t)p % 64, 0);
    assert_int_equal((uintptr_t)q % 64, 0);
    for (int i = 0; i < 1000; i++) assert_true(q[i] == 0.0);
    q[999] = 1;
    assert_null(dr_arena_alloc(a, SIZE_MAX / 2, 4)); /* overflow refused */
    size_t used = dr_arena_used(a);
    assert_true(used >= 8000 + 100);
    dr_arena_reset(a);
    assert_int_equal(dr_arena_used(a), 0);
    uint64_t before = dr_alloc_count();
    double *r = dr_arena_alloc(a, 1000, sizeof(double)); /* reuses a block, zeroed, allocating nothing */
    assert_true(r[999] == 0.0);
    assert_true(dr_arena_alloc(a, 100, 1) != NULL);
    assert_true(dr_alloc_count() == before);
    assert_non_null(dr_arena_alloc(a, 10000, 1)); /* a new block is counted */
    assert_true(dr_alloc_count() == before + 1);
    dr_arena_destroy(&a);
    /* the checked allocators count every call */
    before = dr_alloc_count();
    double *d = NULL;
    assert_int_equal(dr_calloc(4, sizeof *d, &d, &err), DR_OK);
    assert_int_equal(dr_realloc(8, sizeof *d, &d, &err), DR_OK);
    char *c = dr_strdup("x");
    assert_true(dr_alloc_count() == before + 3);
    free(d);
    free(c);
    assert_null(a);
    dr_arena_destroy(&a); /* NULL is a no-op */
}

static void test_hashing(void **state)
{
    (void)state;
    DrHash h1 = dr_hash_bytes("drench", 6), h2 = dr_hash_bytes("drench", 6), h3 = dr_hash_bytes("drencH", 6);
    assert_true(h1.hi == h2.hi && h1.lo == h2.lo);
    assert_false(h1.hi == h3.hi && h1.lo == h3.lo);
    DrHasher s;
    dr_hasher_init(&s);
    dr_hasher_update(&s, "dre", 3);
    dr_hasher_update(&s, "nch", 3);
    DrHash h4 = dr_hasher_final(&s); /* streaming equals one-shot */
    assert_true(h4.hi == h1.hi && h4.lo == h1.lo);
    char hex[33];
    dr_hash_hex(h1, hex);
    assert_int_equal(strlen(hex), 32);
    char path[1024];
    snprintf(path, sizeof path, "%s/drench_hash_XXXXXX", dr_temp_dir());
    int fd = mkstemp(path);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, "drench", 6), 6);
    close(fd);
    DrHash hf;
    DrError err;
    assert_int_equal(dr_hash_file(path, &hf, &err), DR_OK);
    assert_true(hf.hi == h1.hi && hf.lo == h1.lo);
    unlink(path);
    assert_int_equal(dr_hash_file(path, &hf, &err), DR_ERR_INPUT);
    assert_string_equal(err.file, path);
}

typedef struct { long *hits; } CoverCtx;
static void cover(long b, long e, void *ctx)
{
    CoverCtx *c = ctx;
    for (long i = b; i < e; i++) c->hits[i]++;
}

static void test_parallel_for_covers_once(void **state)
{
    (void)state;
    for (int threads = 1; threads <= 2; threads++) {
        dr_set_threads(threads);
        for (long n = 0; n < 200; n += 37) {
            long hits[200] = {0};
            CoverCtx c = {hits};
            dr_parallel_for(n, 1, cover, &c);
            for (long i = 0; i < n; i++) assert_int_equal(hits[i], 1);
        }
    }
    dr_set_threads(0);
}

static void test_rng(void **state)
{
    (void)state;
    DrRng a, b;
    dr_rng_seed(&a, 42);
    dr_rng_seed(&b, 42);
    double mean = 0;
    for (int i = 0; i < 100000; i++) {
        double x = dr_rng_uniform(&a);
        assert_true(x >= 0 && x < 1);
        assert_true(x == dr_rng_uniform(&b));
        mean += x;
    }
    mean /= 100000;
    /* standard error of the mean of U(0,1) over 1e5 samples is 9e-4: 5 sigma */
    assert_true(fabs(mean - 0.5) < 5e-3);
    DrRng c = a; /* the state is plain data: copying it continues the same sequence */
    assert_true(dr_rng_next(&c) == dr_rng_next(&a));
}

/* The scratch directory: $TMPDIR when set and not empty, /tmp otherwise. */
static void test_temp_dir(void **state)
{
    (void)state;
    const char *saved = getenv("TMPDIR");
    char keep[1024] = "";
    if (saved) snprintf(keep, sizeof keep, "%s", saved);
    setenv("TMPDIR", "/scratch/farm", 1);
    assert_string_equal(dr_temp_dir(), "/scratch/farm");
    setenv("TMPDIR", "", 1);
    assert_string_equal(dr_temp_dir(), "/tmp");
    unsetenv("TMPDIR");
    assert_string_equal(dr_temp_dir(), "/tmp");
    if (saved) setenv("TMPDIR", keep, 1);
}

/* The ETA follows the recent cost per frame: 3 frames of 1 s then 5 of 10 s leave 12 frames at 10 s = 120 s,
 * where the mean since the start (53 s / 8 frames) would say 79.5 s. Progress is silenced (log level below
 * INFO, no ALF lines) so the test prints nothing. */
static void test_progress_eta_and_rss(void **state)
{
    (void)state;
    DrLogLevel level = dr_log_level();
    dr_log_set_level(DR_LOG_WARN);
    setenv("DRENCH_ALF_PROGRESS", "0", 1);
    DrProgress p;
    dr_progress_begin(&p, "test", 20);
    assert_false(p.bar || p.lines || p.alf);
    assert_true(dr_progress_eta(&p) == 0.0);
    p.t_start = p.t_last = 100.0;
    double t = 100.0;
    for (int i = 0; i < 3; i++) dr_progress_step_at(&p, t += 1.0, NULL);
    assert_true(fabs(dr_progress_eta(&p) - 17.0) < 1e-9); /* 17 frames at 1 s */
    for (int i = 0; i < 5; i++) dr_progress_step_at(&p, t += 10.0, NULL);
    assert_true(fabs(dr_progress_eta(&p) - 120.0) < 1e-9);
    for (int i = 0; i < 12; i++) dr_progress_step_at(&p, t += 10.0, NULL);
    assert_true(dr_progress_eta(&p) == 0.0);
    dr_progress_end(&p);
    unsetenv("DRENCH_ALF_PROGRESS");
    dr_log_set_level(level);

    /* a running process holds at least a megabyte */
    assert_true(dr_peak_rss_bytes() > 1024 * 1024);
    char buf[32];
    dr_format_bytes(812LL * 1024 * 1024, buf, sizeof buf);
    assert_string_equal(buf, "812 MiB");
    dr_format_bytes(3LL * 1024 * 1024 * 1024 / 2, buf, sizeof buf);
    assert_string_equal(buf, "1.5 GiB");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_error_format_and_exit_codes), cmocka_unit_test(test_checked_alloc),
        cmocka_unit_test(test_math_and_xform),  cmocka_unit_test(test_rotation_exp_log),
        cmocka_unit_test(test_m3_flat_arrays),  cmocka_unit_test(test_trimesh_measures),
        cmocka_unit_test(test_arena),           cmocka_unit_test(test_hashing),
        cmocka_unit_test(test_parallel_for_covers_once), cmocka_unit_test(test_rng),
        cmocka_unit_test(test_temp_dir), cmocka_unit_test(test_progress_eta_and_rss),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
