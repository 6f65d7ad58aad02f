/* The BEM matrix cache (src/bem/bem_cache.c): the key covers exactly what changes the matrices; a written set
 * reads back bit for bit, dense and compressed alike; a file is trusted only under its own key and only when
 * its datasets agree with each other; writing is all or nothing. The matrix sets are made by hand (no
 * assembly), small enough to compare every bit. Also the 32-bit integer datasets the cache stores indices in, and
 * an asset's key (src/bem/bem_asset.c: the welded, checked mesh and the key of its file and desc). Run from the
 * repository root. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "bem/bem.h"

#include <hdf5.h>

#include <dirent.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static char g_dir[256]; /* scratch directory of this run */

static int group_setup(void **state)
{
    (void)state;
    dr_log_set_level(DR_LOG_ERROR); /* the refused files below are logged as warnings by design */
    snprintf(g_dir, sizeof g_dir, "%s/drench_test_bem_cache.XXXXXX", dr_temp_dir());
    return mkdtemp(g_dir) ? 0 : -1;
}

static int group_teardown(void **state)
{
    (void)state;
    char cmd[512];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    return system(cmd) == 0 ? 0 : -1;
}

/* A fresh cache root per test, so files of one test never answer another. */
static void cache_root(const char *name, char *buf, size_t size) { snprintf(buf, size, "%s/%s", g_dir, name); }

static void file_path(const char *root, const char *key, char *buf, size_t size)
{
    dr_io_precache_path(root, "bem", key, buf, size);
}

/* Entries of dir (0 when it does not exist). */
static int count_entries(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d) return 0;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) n += strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0;
    closedir(d);
    return n;
}

static void copy_file(const char *from, const char *to, long keep_bytes)
{
    FILE *a = fopen(from, "rb"), *b = fopen(to, "wb");
    assert_non_null(a);
    assert_non_null(b);
    char buf[4096];
    long copied = 0;
    size_t got;
    while ((got = fread(buf, 1, sizeof buf, a)) > 0) {
        if (keep_bytes >= 0 && copied + (long)got > keep_bytes) got = (size_t)(keep_bytes - copied);
        assert_int_equal(fwrite(buf, 1, got, b), got);
        copied += (long)got;
        if (keep_bytes >= 0 && copied >= keep_bytes) break;
    }
    fclose(a);
    assert_int_equal(fclose(b), 0);
}

static long file_size(const char *path)
{
    struct stat st;
    assert_int_equal(stat(path, &st), 0);
    return (long)st.st_size;
}

/* ---- a hand-made matrix set ------------------------------------------------------------------------------ */

/* Values that exercise every bit: signs, magnitudes from 1e-300 to 1e300, -0, a subnormal. */
static double value(uint64_t *state)
{
    *state = *state * 6364136223846793005ULL + 1442695040888963407ULL;
    uint64_t r = *state >> 11;
    switch (r % 16) {
    case 0: return -0.0;
    case 1: return 4.9e-324;
    case 2: return 1e300 * (double)(r % 7);
    case 3: return -1e-300 * (double)(r % 5);
    default: return ((double)(r % 2000001) - 1000000.0) / 7.0;
    }
}

static double *values(size_t count, uint64_t *state)
{
    double *v = calloc(count ? count : 1, sizeof *v);
    assert_non_null(v);
    for (size_t i = 0; i < count; i++) v[i] = value(state);
    return v;
}

static void make_dense(int n, uint64_t *state, DrBemCMat *c)
{
    memset(c, 0, sizeof *c);
    c->n = n;
    c->dense = true;
    c->nnz = (int64_t)n * n;
    c->val = values((size_t)n * n, state);
}

/* A CSR matrix whose row i keeps `pattern(i)` entries: empty rows, full rows and everything between. */
static void make_csr(int n, int variant, uint64_t *state, DrBemCMat *c)
{
    memset(c, 0, sizeof *c);
    c->n = n;
    c->dense = false;
    c->row_ptr = calloc((size_t)n + 1, sizeof *c->row_ptr);
    assert_non_null(c->row_ptr);
    for (int i = 0; i < n; i++) {
        int count = variant == 0 ? 0 : (i * 7 + variant * 3) % (n + 1); /* variant 0: an all-zero matrix */
        c->row_ptr[i + 1] = c->row_ptr[i] + count;
    }
    c->nnz = c->row_ptr[n];
    c->col = calloc(c->nnz ? (size_t)c->nnz : 1, sizeof *c->col);
    assert_non_null(c->col);
    for (int i = 0; i < n; i++)
        for (int64_t p = c->row_ptr[i]; p < c->row_ptr[i + 1]; p++) c->col[p] = (int32_t)((p - c->row_ptr[i]) * 5 % n);
    c->val = values((size_t)c->nnz, state);
}

static void free_cmat(DrBemCMat *c)
{
    free(c->row_ptr);
    free(c->col);
    free(c->val);
    memset(c, 0, sizeof *c);
}

static void free_by_hand(DrBemMatrices **mp)
{
    DrBemMatrices *m = *mp;
    if (!m) return;
    free(m->x);
    free(m->tri);
    free(m->A);
    free(m->C);
    free(m->w);
    free(m->area);
    free(m->D);
    free(m->Q);
    free(m->layout.perm);
    for (int k = 0; k <= m->n_max; k++) {
        if (m->H) free_cmat(&m->H[k]);
        if (m->G) free_cmat(&m->G[k]);
    }
    free(m->H);
    free(m->G);
    free_cmat(&m->H0inv);
    free_cmat(&m->H0inv_Gp);
    free(m->H_dense);
    free(m->G_dense);
    free(m);
    *mp = NULL;
}

/* A tetrahedron's worth of unknowns (N = 4, n = 12) with n_max = 2. h_dense / g_dense choose the storage of
 * each set; H₀⁻¹ is stored the other way from H, H₀⁻¹G′ the other way from G, so one set holds both kinds. */
static DrBemMatrices *make_set(bool h_dense, bool g_dense, uint64_t seed)
{
    uint64_t st = seed;
    DrBemMatrices *m = calloc(1, sizeof *m);
    assert_non_null(m);
    m->nv = 4;
    m->n = 12;
    m->nt = 4;
    m->n_max = 2;
    dr_bem_desc_default(&m->desc);
    m->desc.material = (DrBemMaterial){1100, 2.5e5, 0.3};
    m->desc.dt = 1.0 / 300.0;
    m->desc.history_margin = 2.5;
    m->desc.compression_ratio = h_dense && g_dense ? 1.0 : 8.0;
    m->desc.ordering = DR_BEM_ORDER_XYZ;
    m->desc.keep_dense = false;
    m->x = values(12, &st);
    static const int tri[12] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
    m->tri = malloc(sizeof tri);
    assert_non_null(m->tri);
    memcpy(m->tri, tri, sizeof tri);
    m->body = (DrBemBody){.volume = value(&st), .mass = value(&st), .r_max = value(&st)};
    for (int i = 0; i < 3; i++) m->body.centroid[i] = value(&st);
    for (int i = 0; i < 9; i++) m->body.inertia[i] = value(&st);
    m->layout.nv = 4;
    m->layout.ordering = DR_BEM_ORDER_XYZ;
    m->layout.wavelet = m->desc.wavelet;
    m->layout.perm = malloc(12 * sizeof(int));
    assert_non_null(m->layout.perm);
    for (int i = 0; i < 12; i++) m->layout.perm[i] = (i % 4) * 3 + i / 4; /* xyz blocks */
    m->A = values(36, &st);
    m->C = values(36, &st);
    m->w = values(4, &st);
    m->area = values(4, &st);
    m->D = values(3 * 12 * 3, &st);
    m->Q = values(3 * 12 * 3, &st);
    m->H = calloc(3, sizeof *m->H);
    m->G = calloc(3, sizeof *m->G);
    assert_non_null(m->H);
    assert_non_null(m->G);
    for (int k = 0; k < 3; k++) {
        if (h_dense) make_dense(12, &st, &m->H[k]);
        else make_csr(12, k, &st, &m->H[k]);
        if (g_dense) make_dense(12, &st, &m->G[k]);
        else make_csr(12, k + 1, &st, &m->G[k]);
    }
    if (h_dense) make_csr(12, 4, &st, &m->H0inv);
    else make_dense(12, &st, &m->H0inv);
    if (g_dense) make_csr(12, 5, &st, &m->H0inv_Gp);
    else make_dense(12, &st, &m->H0inv_Gp);
    m->stats = (DrBemStats){.seconds_quadrature = 1.25, .seconds_inverse = 0.5, .seconds_compress = 0.125,
                            .frequencies_evaluated = 5, .rigid_residual = 3e-4, .bytes_dense = 13824,
                            .bytes_compressed = 777};
    return m;
}

static void assert_same_bits(const void *a, const void *b, size_t bytes, const char *what)
{
    if (bytes && memcmp(a, b, bytes) != 0) fail_msg("%s differs after the round trip", what);
}

static void assert_same_cmat(const DrBemCMat *a, const DrBemCMat *b, const char *what)
{
    assert_int_equal(a->n, b->n);
    if (a->dense != b->dense) fail_msg("%s: storage changed", what);
    assert_int_equal(a->nnz, b->nnz);
    if (a->dense) {
        assert_null(b->row_ptr);
        assert_null(b->col);
        assert_same_bits(a->val, b->val, (size_t)a->n * (size_t)a->n * sizeof(double), what);
        return;
    }
    assert_same_bits(a->row_ptr, b->row_ptr, ((size_t)a->n + 1) * sizeof(int64_t), what);
    assert_same_bits(a->col, b->col, (size_t)a->nnz * sizeof(int32_t), what);
    assert_same_bits(a->val, b->val, (size_t)a->nnz * sizeof(double), what);
}

static void assert_same_set(const DrBemMatrices *a, const DrBemMatrices *b)
{
    assert_int_equal(a->nv, b->nv);
    assert_int_equal(a->n, b->n);
    assert_int_equal(a->nt, b->nt);
    assert_int_equal(a->n_max, b->n_max);
    size_t n = (size_t)a->n, K = (size_t)a->n_max + 1;
    assert_same_bits(a->x, b->x, n * sizeof(double), "x");
    assert_same_bits(a->tri, b->tri, 3 * (size_t)a->nt * sizeof(int), "tri");
    assert_same_bits(&a->desc.material, &b->desc.material, sizeof a->desc.material, "desc.material");
    assert_true(a->desc.dt == b->desc.dt && a->desc.history_margin == b->desc.history_margin);
    assert_true(a->desc.cq_epsilon == b->desc.cq_epsilon && a->desc.compression_ratio == b->desc.compression_ratio);
    assert_int_equal(a->desc.ordering, b->desc.ordering);
    assert_int_equal(a->desc.wavelet, b->desc.wavelet);
    assert_int_equal(a->desc.quad_levels, b->desc.quad_levels);
    assert_true(a->desc.near_factor == b->desc.near_factor);
    assert_int_equal(a->desc.singular_order, b->desc.singular_order);
    assert_false(b->desc.keep_dense);
    assert_same_bits(&a->body, &b->body, sizeof a->body, "body");
    assert_int_equal(a->layout.nv, b->layout.nv);
    assert_int_equal(a->layout.ordering, b->layout.ordering);
    assert_int_equal(a->layout.wavelet, b->layout.wavelet);
    assert_same_bits(a->layout.perm, b->layout.perm, n * sizeof(int), "layout.perm");
    assert_same_bits(a->A, b->A, 3 * n * sizeof(double), "A");
    assert_same_bits(a->C, b->C, 3 * n * sizeof(double), "C");
    assert_same_bits(a->w, b->w, (size_t)a->nv * sizeof(double), "w");
    assert_same_bits(a->area, b->area, (size_t)a->nv * sizeof(double), "area");
    assert_same_bits(a->D, b->D, K * n * 3 * sizeof(double), "D");
    assert_same_bits(a->Q, b->Q, K * n * 3 * sizeof(double), "Q");
    for (size_t k = 0; k < K; k++) {
        assert_same_cmat(&a->H[k], &b->H[k], "H_k");
        assert_same_cmat(&a->G[k], &b->G[k], "G_k");
    }
    assert_same_cmat(&a->H0inv, &b->H0inv, "H0inv");
    assert_same_cmat(&a->H0inv_Gp, &b->H0inv_Gp, "H0inv_Gp");
    assert_null(b->H_dense);
    assert_null(b->G_dense);
    assert_same_bits(&a->stats, &b->stats, sizeof a->stats, "stats");
}

static const char *const MESH_HASH = "0123456789abcdef0123456789abcdef";

static void write_set(const char *root, const DrBemMatrices *m, char key[33])
{
    dr_bem_cache_key(MESH_HASH, &m->desc, key);
    DrError err;
    DrStatus s = dr_bem_cache_write(root, key, "{\"test\":true}", MESH_HASH, m, &err);
    if (s != DR_OK) fail_msg("dr_bem_cache_write: %s", err.message);
}

/* Why the last read_set did not trust its file (status DR_OK when it did, or found none). */
static DrError g_rejected;

/* Reads key from root and asserts whether it was trusted. */
static DrBemMatrices *read_set(const char *root, const char *key, bool expect_found)
{
    DrBemMatrices *m = (DrBemMatrices *)(uintptr_t)1;
    bool found = !expect_found;
    DrError err;
    DrStatus s = dr_bem_cache_read(root, key, &m, &found, &g_rejected, &err);
    if (s != DR_OK) fail_msg("dr_bem_cache_read: %s", err.message);
    if (found != expect_found) fail_msg("found = %d, expected %d", found, expect_found);
    if (!found) assert_null(m);
    else assert_non_null(m);
    return m;
}

/* ---- key ------------------------------------------------------------------------------------------------ */

static void assert_hex32(const char *k)
{
    assert_int_equal(strlen(k), 32);
    for (const char *c = k; *c; c++) assert_true((*c >= '0' && *c <= '9') || (*c >= 'a' && *c <= 'f'));
}

static void test_key_covers_what_changes_the_matrices(void **state)
{
    (void)state;
    DrBemDesc base;
    dr_bem_desc_default(&base);
    base.material = (DrBemMaterial){1000, 1e5, 0.4};
    base.dt = 1.0 / 240.0;
    char k0[33], k1[33];
    dr_bem_cache_key(MESH_HASH, &base, k0);
    assert_hex32(k0);
    dr_bem_cache_key(MESH_HASH, &base, k1);
    assert_string_equal(k0, k1); /* a function of its inputs only */

    /* every parameter that enters the matrices moves the key */
    DrBemDesc d;
#define CHANGED(stmt)                                                                                                 \
    do {                                                                                                              \
        d = base;                                                                                                     \
        stmt;                                                                                                         \
        dr_bem_cache_key(MESH_HASH, &d, k1);                                                                          \
        if (strcmp(k0, k1) == 0) fail_msg("the key ignores: %s", #stmt);                                              \
    } while (0)
    CHANGED(d.material.density = 1001);
    CHANGED(d.material.shear_modulus = 2e5);
    CHANGED(d.material.poisson = 0.3);
    CHANGED(d.dt = 1.0 / 120.0);
    CHANGED(d.history_margin += 1);
    CHANGED(d.cq_epsilon *= 10);
    CHANGED(d.compression_ratio += 1);
    CHANGED(d.ordering = d.ordering == DR_BEM_ORDER_NONE ? DR_BEM_ORDER_XYZ : DR_BEM_ORDER_NONE);
    CHANGED(d.wavelet = !d.wavelet);
    CHANGED(d.quad_levels += 1);
    CHANGED(d.near_factor += 0.5);
    CHANGED(d.singular_order += 1);
#undef CHANGED
    dr_bem_cache_key("fedcba9876543210fedcba9876543210", &base, k1);
    assert_string_not_equal(k0, k1);

    /* the dense copies are never cached: keeping them does not change which file serves */
    d = base;
    d.keep_dense = !d.keep_dense;
    dr_bem_cache_key(MESH_HASH, &d, k1);
    assert_string_equal(k0, k1);
    /* -0 and +0 are one value */
    d = base;
    d.history_margin = 0.0;
    dr_bem_cache_key(MESH_HASH, &d, k0);
    d.history_margin = -0.0;
    dr_bem_cache_key(MESH_HASH, &d, k1);
    assert_string_equal(k0, k1);
}

/* ---- round trip ----------------------------------------------------------------------------------------- */

static void round_trip(const char *name, bool h_dense, bool g_dense)
{
    char root[512], key[33], path[1024];
    cache_root(name, root, sizeof root);
    DrBemMatrices *m = make_set(h_dense, g_dense, 42 + (uint64_t)h_dense * 2 + g_dense);
    write_set(root, m, key);
    file_path(root, key, path, sizeof path);
    assert_true(dr_io_exists(path));
    char dir[600];
    snprintf(dir, sizeof dir, "%s/bem", root);
    assert_int_equal(count_entries(dir), 1); /* no temporary file left beside it */

    DrBemMatrices *r = read_set(root, key, true);
    assert_same_set(m, r);
    dr_bem_matrices_destroy(&r);
    assert_null(r);
    free_by_hand(&m);
}

static void test_round_trip_dense_and_compressed(void **state)
{
    (void)state;
    round_trip("mixed", true, false);  /* H dense, G compressed, H0inv compressed, H0inv_Gp dense */
    round_trip("mixed2", false, true); /* the other way round */
    round_trip("dense", true, true);   /* ratio 1: H and G dense (the inverses compressed by construction) */
}

/* The file describes itself: the attributes a reader of h5dump needs are there, with units on the datasets. */
static void test_file_describes_itself(void **state)
{
    (void)state;
    char root[512], key[33], path[1024];
    cache_root("describe", root, sizeof root);
    DrBemMatrices *m = make_set(true, false, 7);
    write_set(root, m, key);
    file_path(root, key, path, sizeof path);
    DrH5 *h;
    DrError err;
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    char *s = NULL;
    assert_int_equal(dr_h5_read_attr_str(h, "/", "kind", &s, &err), DR_OK);
    assert_string_equal(s, "bem");
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/", "key", &s, &err), DR_OK);
    assert_string_equal(s, key);
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/", "asset_hash", &s, &err), DR_OK);
    assert_string_equal(s, MESH_HASH);
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/", "inputs", &s, &err), DR_OK);
    assert_string_equal(s, "{\"test\":true}");
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/", "ordering", &s, &err), DR_OK);
    assert_string_equal(s, "xyz");
    free(s);
    int64_t v;
    assert_int_equal(dr_h5_read_attr_i64(h, "/", "n_vertices", &v, &err), DR_OK);
    assert_int_equal(v, 4);
    assert_int_equal(dr_h5_read_attr_i64(h, "/", "n_triangles", &v, &err), DR_OK);
    assert_int_equal(v, 4);
    assert_int_equal(dr_h5_read_attr_i64(h, "/", "n_max", &v, &err), DR_OK);
    assert_int_equal(v, 2);
    double x;
    assert_int_equal(dr_h5_read_attr_f64(h, "/", "dt", &x, &err), DR_OK);
    assert_true(x == 1.0 / 300.0);
    assert_int_equal(dr_h5_read_attr_f64(h, "/", "shear_modulus", &x, &err), DR_OK);
    assert_true(x == 2.5e5);
    assert_int_equal(dr_h5_read_attr_f64(h, "/", "compression_ratio", &x, &err), DR_OK);
    assert_true(x == 8.0);
    /* c₂ = √(μ/ρ), c₁ = √((λ + 2μ)/ρ) with λ = 2μν/(1 − 2ν): for ν = 0.3, c₁/c₂ = √(2(1 − ν)/(1 − 2ν)) */
    double c1, c2;
    assert_int_equal(dr_h5_read_attr_f64(h, "/", "shear_wave_speed", &c2, &err), DR_OK);
    assert_int_equal(dr_h5_read_attr_f64(h, "/", "longitudinal_wave_speed", &c1, &err), DR_OK);
    assert_true(fabs(c2 - sqrt(2.5e5 / 1100)) < 1e-12 * c2);
    assert_true(fabs(c1 / c2 - sqrt(1.4 / 0.4)) < 1e-12);
    const char *units[][2] = {{"/mesh/x", "m"},    {"/D", "s^2"},          {"/Q", "m*s^2"},
                              {"/A", "m^2/kg"},    {"/C", "m/kg"},         {"/H/0/val", "1"},
                              {"/G/1/val", "m/Pa"}, {"/H0inv_Gp/val", "m/Pa"}, {"/body/mass", "kg"}};
    for (size_t i = 0; i < sizeof units / sizeof units[0]; i++) {
        assert_int_equal(dr_h5_read_attr_str(h, units[i][0], "units", &s, &err), DR_OK);
        assert_string_equal(s, units[i][1]);
        free(s);
    }
    assert_int_equal(dr_h5_read_attr_str(h, "/H/2", "storage", &s, &err), DR_OK);
    assert_string_equal(s, "dense");
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/G/2", "storage", &s, &err), DR_OK);
    assert_string_equal(s, "csr");
    free(s);
    dr_h5_close(&h);
    free_by_hand(&m);
}

/* ---- what is not trusted -------------------------------------------------------------------------------- */

static void test_missing_file_is_not_found(void **state)
{
    (void)state;
    char root[512];
    cache_root("empty", root, sizeof root);
    read_set(root, "00000000000000000000000000000000", false);
    DrBemMatrices *m = NULL;
    bool found;
    DrError err;
    /* a key that is not hex never becomes a path */
    assert_int_equal(dr_bem_cache_read(root, "../../etc/passwd", &m, &found, NULL, &err), DR_ERR_INPUT);
    assert_false(found);
}

static void test_other_key_is_not_trusted(void **state)
{
    (void)state;
    char root[512], key[33], path[1024], other_path[1024];
    cache_root("other", root, sizeof root);
    DrBemMatrices *m = make_set(true, false, 9);
    write_set(root, m, key);
    file_path(root, key, path, sizeof path);
    /* the same bytes under the name of another key: the recorded key decides */
    const char *other = "ffffffffffffffffffffffffffffffff";
    file_path(root, other, other_path, sizeof other_path);
    copy_file(path, other_path, -1);
    read_set(root, other, false);
    DrBemMatrices *r = read_set(root, key, true); /* the original still serves its own key */
    dr_bem_matrices_destroy(&r);
    free_by_hand(&m);
}

static void test_truncated_or_garbage_is_not_trusted(void **state)
{
    (void)state;
    char root[512], key[33], path[1024], tmp[1100];
    cache_root("damaged", root, sizeof root);
    DrBemMatrices *m = make_set(false, true, 11);
    write_set(root, m, key);
    file_path(root, key, path, sizeof path);
    snprintf(tmp, sizeof tmp, "%s.orig", path);
    copy_file(path, tmp, -1);
    long size = file_size(path);
    /* cut at several points: in the superblock, in the middle, just before the end */
    long cuts[] = {0, 100, size / 2, size - 16};
    for (size_t i = 0; i < sizeof cuts / sizeof cuts[0]; i++) {
        copy_file(tmp, path, cuts[i]);
        read_set(root, key, false);
    }
    /* garbage of the right length */
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    uint64_t st = 5;
    for (long i = 0; i < size; i++) fputc((int)(value(&st) == 0.0 ? 0 : (st >> 33) & 0xff), f);
    fclose(f);
    read_set(root, key, false);
    /* restored, it serves again */
    copy_file(tmp, path, -1);
    DrBemMatrices *r = read_set(root, key, true);
    assert_same_set(m, r);
    dr_bem_matrices_destroy(&r);
    free_by_hand(&m);
}

/* Files that open, carry the right key, and still do not hold what they claim are refused, whatever is wrong. */
static void test_inconsistent_datasets_are_not_trusted(void **state)
{
    (void)state;
    char root[512], key[33];
    cache_root("inconsistent", root, sizeof root);

    /* a compressed column index outside the matrix */
    DrBemMatrices *m = make_set(true, false, 13);
    m->G[1].col[0] = 12;
    write_set(root, m, key);
    read_set(root, key, false);
    free_by_hand(&m);

    /* a layout that is not a permutation */
    m = make_set(true, false, 14);
    m->layout.perm[3] = m->layout.perm[4];
    write_set(root, m, key);
    read_set(root, key, false);
    free_by_hand(&m);

    /* a triangle naming a vertex the file does not have */
    m = make_set(true, false, 15);
    m->tri[5] = 4;
    write_set(root, m, key);
    read_set(root, key, false);
    free_by_hand(&m);

    /* a row pointer that runs backwards */
    m = make_set(false, false, 16);
    int64_t *rp = m->H[2].row_ptr;
    int64_t t = rp[3];
    rp[3] = rp[4] + 1;
    write_set(root, m, key);
    rp[3] = t;
    read_set(root, key, false);
    free_by_hand(&m);

    /* the right key and kind but nothing else: every dataset missing */
    DrH5 *h;
    DrError err;
    const char *bare = "abcdefabcdefabcdefabcdefabcdef01";
    assert_int_equal(dr_io_precache_create(root, "bem", bare, "{}", "", &h, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    read_set(root, bare, false);

    /* edits after writing (HDF5 directly, the way another tool would): a recorded size the datasets do not
     * have, a dataset removed, a dataset of another shape */
    struct {
        const char *what;
        const char *attr; /* root integer attribute to overwrite, or NULL */
        int64_t value;
        const char *unlink; /* dataset to remove, or NULL */
    } edits[] = {
        {"n_max larger than the matrices written", "n_max", 3, NULL},
        {"n_max smaller than D and Q", "n_max", 1, NULL},
        {"n_vertices that is not n / 3", "n_vertices", 5, NULL},
        {"a missing matrix", NULL, 0, "/G/1/val"},
        {"a missing row pointer", NULL, 0, "/H/2/row_ptr"},
        {"missing rest positions", NULL, 0, "/mesh/x"},
    };
    /* a value edited in place (an uncompressed dataset, its shape unchanged): its checksum no longer matches */
    m = make_set(true, false, 23);
    write_set(root, m, key);
    free_by_hand(&m);
    {
        char path[1024];
        file_path(root, key, path, sizeof path);
        hid_t f = H5Fopen(path, H5F_ACC_RDWR, H5P_DEFAULT);
        assert_true(f >= 0);
        hid_t d = H5Dopen2(f, "/body/volume", H5P_DEFAULT);
        assert_true(d >= 0);
        double v = 12.5;
        assert_true(H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, &v) >= 0);
        H5Dclose(d);
        assert_true(H5Fclose(f) >= 0);
        read_set(root, key, false);
        assert_int_equal(g_rejected.status, DR_ERR_INPUT);
        assert_string_equal(g_rejected.file, path);
        assert_non_null(strstr(g_rejected.message, "/body/volume does not match its checksum"));
    }

    for (size_t i = 0; i < sizeof edits / sizeof edits[0]; i++) {
        m = make_set(i % 2 == 1, false, 17 + i); /* H compressed where its row pointer is removed */
        write_set(root, m, key);
        free_by_hand(&m);
        char path[1024];
        file_path(root, key, path, sizeof path);
        hid_t f = H5Fopen(path, H5F_ACC_RDWR, H5P_DEFAULT);
        assert_true(f >= 0);
        if (edits[i].attr) {
            hid_t a = H5Aopen(f, edits[i].attr, H5P_DEFAULT);
            assert_true(a >= 0);
            assert_true(H5Awrite(a, H5T_NATIVE_INT64, &edits[i].value) >= 0);
            H5Aclose(a);
        }
        if (edits[i].unlink) assert_true(H5Ldelete(f, edits[i].unlink, H5P_DEFAULT) >= 0);
        assert_true(H5Fclose(f) >= 0);
        DrBemMatrices *r = (DrBemMatrices *)(uintptr_t)1;
        bool found = true;
        assert_int_equal(dr_bem_cache_read(root, key, &r, &found, NULL, &err), DR_OK);
        if (found) fail_msg("a file with %s was trusted", edits[i].what);
        assert_null(r);
    }
}

/* ---- writing is all or nothing -------------------------------------------------------------------------- */

static void test_failed_write_leaves_nothing(void **state)
{
    (void)state;
    char root[512], key[33];
    /* a cache root that is a regular file: the bem folder cannot be made */
    cache_root("not_a_dir", root, sizeof root);
    FILE *f = fopen(root, "w");
    assert_non_null(f);
    fclose(f);
    DrBemMatrices *m = make_set(true, false, 21);
    dr_bem_cache_key(MESH_HASH, &m->desc, key);
    DrError err;
    assert_int_equal(dr_bem_cache_write(root, key, "{}", MESH_HASH, m, &err), DR_ERR_IO);
    assert_true(strstr(err.file, "not_a_dir") != NULL);
    assert_int_equal(file_size(root), 0);
    free_by_hand(&m);

    /* a bad key is refused before anything is created */
    cache_root("bad_key", root, sizeof root);
    m = make_set(true, false, 22);
    assert_int_equal(dr_bem_cache_write(root, "not/hex", "{}", MESH_HASH, m, &err), DR_ERR_INPUT);
    assert_false(dr_io_exists(root));
    free_by_hand(&m);
}

/* ---- 32-bit integer datasets ---------------------------------------------------------------------------- */

static void test_i32_datasets(void **state)
{
    (void)state;
    char path[512];
    snprintf(path, sizeof path, "%s/i32.h5", g_dir);
    DrH5 *h;
    DrError err;
    assert_int_equal(dr_h5_create(path, &h, &err), DR_OK);
    const int32_t v[6] = {0, -1, INT32_MAX, INT32_MIN, 7, 42};
    const int64_t w[2] = {1, 2};
    assert_int_equal(dr_h5_write_i32(h, "/a/idx", 2, (uint64_t[]){2, 3}, v, "1", true, &err), DR_OK);
    assert_int_equal(dr_h5_write_i32(h, "/a/none", 1, (uint64_t[]){0}, NULL, NULL, true, &err), DR_OK);
    assert_int_equal(dr_h5_write_i64(h, "/a/wide", 1, (uint64_t[]){2}, w, NULL, false, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);

    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    int rank;
    uint64_t dims[4];
    int32_t *r = NULL;
    assert_int_equal(dr_h5_read_i32(h, "/a/idx", &rank, dims, &r, &err), DR_OK);
    assert_int_equal(rank, 2);
    assert_true(dims[0] == 2 && dims[1] == 3);
    assert_memory_equal(r, v, sizeof v);
    free(r);
    char *u = NULL;
    assert_int_equal(dr_h5_read_attr_str(h, "/a/idx", "units", &u, &err), DR_OK);
    assert_string_equal(u, "1");
    free(u);
    assert_int_equal(dr_h5_read_i32(h, "/a/none", &rank, dims, &r, &err), DR_OK);
    assert_non_null(r);
    assert_true(rank == 1 && dims[0] == 0);
    free(r);
    /* the element type is checked both ways */
    assert_int_equal(dr_h5_read_i32(h, "/a/wide", &rank, dims, &r, &err), DR_ERR_INPUT);
    assert_null(r);
    assert_true(strstr(err.message, "signed 32-bit integer") != NULL);
    int64_t *r64 = NULL;
    assert_int_equal(dr_h5_read_i64(h, "/a/idx", &rank, dims, &r64, &err), DR_ERR_INPUT);
    assert_null(r64);
    dr_h5_close(&h);
}

/* An asset: the mesh welded and checked, its file's hash, and the key of that hash and desc; a seam welded shut;
   a bad mesh or file fails as DR_ERR_INPUT naming the file, with nothing to free. */
static void test_asset(void **state)
{
    (void)state;
    DrBemDesc d;
    dr_bem_desc_default(&d);
    d.dt = 1e-3;
    DrBemAsset a;
    DrError err;
    const char *path = "tests/data/bem_ico1.obj";
    assert_int_equal(dr_bem_asset_load(path, &d, &a, &err), DR_OK);
    assert_ptr_equal(a.path, path);
    assert_int_equal(a.mesh.nv, 42);
    assert_int_equal(a.mesh.nt, 80);
    assert_int_equal(a.vertices_in_file, 42);
    assert_int_equal(a.welded, 0);
    DrVec3 lo, hi;
    assert_true(dr_trimesh_bounds(&a.mesh, &lo, &hi));
    assert_true(fabs(a.weld_tolerance - 1e-9 * dr_v3_norm(dr_v3_sub(hi, lo))) <= 1e-15 * a.weld_tolerance);
    assert_memory_equal(&a.desc, &d, sizeof d);
    DrHash h;
    char hex[33], key[33];
    assert_int_equal(dr_hash_file(path, &h, &err), DR_OK);
    dr_hash_hex(h, hex);
    assert_string_equal(a.mesh_hash, hex);
    dr_bem_cache_key(hex, &d, key);
    assert_string_equal(a.key, key);
    DrBemAsset b; /* another Δt: the same file, another key */
    d.dt = 2e-3;
    assert_int_equal(dr_bem_asset_load(path, &d, &b, &err), DR_OK);
    assert_string_equal(b.mesh_hash, a.mesh_hash);
    assert_string_not_equal(b.key, a.key);
    dr_bem_asset_free(&b);
    dr_bem_asset_free(&a);

    /* a tetrahedron with a corner written twice, 1e-12 m apart (as an exporter may split a seam with different
       digits; the loader joins only identical points): welded to 4 vertices */
    char seam[512];
    snprintf(seam, sizeof seam, "%s/seam.obj", g_dir);
    FILE *fp = fopen(seam, "w");
    assert_non_null(fp);
    fputs("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1e-12 0 0\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 5 4\n", fp);
    fclose(fp);
    assert_int_equal(dr_bem_asset_load(seam, &d, &a, &err), DR_OK);
    assert_int_equal(a.vertices_in_file, 5);
    assert_int_equal(a.welded, 1);
    assert_int_equal(a.mesh.nv, 4);
    dr_bem_asset_free(&a);

    const char *bad[] = {"tests/data/bad/bem_open.obj", "tests/data/bad/bem_inward.obj", "tests/data/no_such_mesh.obj"};
    for (int i = 0; i < 3; i++) {
        dr_error_clear(&err);
        assert_int_equal(dr_bem_asset_load(bad[i], &d, &a, &err), DR_ERR_INPUT);
        assert_string_equal(err.file, bad[i]);
        assert_null(a.mesh.v);
        assert_null(a.mesh.tri);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_key_covers_what_changes_the_matrices),
        cmocka_unit_test(test_round_trip_dense_and_compressed),
        cmocka_unit_test(test_file_describes_itself),
        cmocka_unit_test(test_missing_file_is_not_found),
        cmocka_unit_test(test_other_key_is_not_trusted),
        cmocka_unit_test(test_truncated_or_garbage_is_not_trusted),
        cmocka_unit_test(test_inconsistent_datasets_are_not_trusted),
        cmocka_unit_test(test_failed_write_leaves_nothing),
        cmocka_unit_test(test_i32_datasets),
        cmocka_unit_test(test_asset),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
