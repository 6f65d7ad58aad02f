/* The BEM matrix cache (DESIGN §4, §5): cache/bem/<key>.h5 holds one DrBemMatrices, self-describing for h5dump,
 * written through a temporary file and trusted only when its recorded key is the one asked for and every
 * dataset has the shape the recorded sizes imply.
 *
 * File layout (n = 3N unknowns, K = n_max + 1 history matrices):
 *   root attributes   kind, key, inputs, asset_hash, drench_version, created (dr_io_precache_create), and
 *                     bem_version, units, n_vertices, n_triangles, n, n_max, dt, density, shear_modulus,
 *                     poisson, lame_lambda, longitudinal_wave_speed, shear_wave_speed, history_margin,
 *                     cq_epsilon, compression_ratio, ordering, wavelet, quad_levels, near_factor, singular_order
 *   /mesh/x (N×3), /mesh/tri (nt×3)        the welded rest mesh the matrices belong to
 *   /layout/perm (n)                       perm[new] = old natural index, of the compression layout
 *   /body/volume, mass, centroid (3), inertia (3×3), r_max
 *   /A, /C (3×n), /w, /area (N), /D, /Q (K×n×3)
 *   /H/<k>, /G/<k> for k = 0..n_max, /H0inv, /H0inv_Gp: one matrix each, attribute storage = "dense" (val n×n,
 *                     natural order) or "csr" (row_ptr n+1, col nnz, val nnz: kept Haar coefficients)
 *   /stats            attributes: what the build measured
 * One dataset per matrix (rather than all K concatenated) lets the reader hand each array it reads straight to
 * the result, so loading never holds two copies of the largest data. */
#include "bem/bem.h"
#include "bem_internal.h"

#include <stdlib.h>
#include <string.h>

#define CACHE_KIND "bem"
#define PATH_LEN 96

/* ---- write ---------------------------------------------------------------------------------------------- */

static DrStatus put_f64(DrH5 *h, const char *path, int rank, const uint64_t *dims, const double *data,
                        const char *units, const char *description, DrError *err)
{
    DR_TRY(dr_h5_write_f64(h, path, rank, dims, data, units, true, err));
    return description ? dr_h5_attr_str(h, path, "description", description, err) : DR_OK;
}

static DrStatus put_indices(DrH5 *h, const char *path, int rank, const uint64_t *dims, const int *data,
                            const char *description, DrError *err)
{
    /* int is int32_t on every platform this builds on; the file type is fixed at 32 bits either way */
    _Static_assert(sizeof(int) == sizeof(int32_t), "indices are stored as int32");
    DR_TRY(dr_h5_write_i32(h, path, rank, dims, (const int32_t *)data, "1", true, err));
    return description ? dr_h5_attr_str(h, path, "description", description, err) : DR_OK;
}

/* One matrix under group `g`: dense (val n×n) or compressed (row_ptr, col, val). */
static DrStatus put_cmat(DrH5 *h, const char *g, const DrBemCMat *c, int n, const char *units, DrError *err)
{
    assert(c->n == n);
    char path[PATH_LEN];
    DR_TRY(dr_h5_attr_str(h, g, "storage", c->dense ? "dense" : "csr", err));
    if (c->dense) {
        snprintf(path, sizeof path, "%s/val", g);
        return dr_h5_write_f64(h, path, 2, (uint64_t[]){(uint64_t)n, (uint64_t)n}, c->val, units, true, err);
    }
    assert(c->nnz >= 0 && c->row_ptr[0] == 0 && c->row_ptr[n] == c->nnz);
    snprintf(path, sizeof path, "%s/row_ptr", g);
    DR_TRY(dr_h5_write_i64(h, path, 1, (uint64_t[]){(uint64_t)n + 1}, c->row_ptr, "1", true, err));
    snprintf(path, sizeof path, "%s/col", g);
    DR_TRY(dr_h5_write_i32(h, path, 1, (uint64_t[]){(uint64_t)c->nnz}, c->col, "1", true, err));
    snprintf(path, sizeof path, "%s/val", g);
    return dr_h5_write_f64(h, path, 1, (uint64_t[]){(uint64_t)c->nnz}, c->val, units, true, err);
}

static DrStatus put_cmat_set(DrH5 *h, const char *g, const DrBemCMat *set, int count, int n, const char *units,
                             const char *description, DrError *err)
{
    DR_TRY(dr_h5_attr_i64(h, g, "count", count, err));
    DR_TRY(dr_h5_attr_str(h, g, "description", description, err));
    for (int k = 0; k < count; k++) {
        char sub[PATH_LEN];
        snprintf(sub, sizeof sub, "%s/%d", g, k);
        DR_TRY(put_cmat(h, sub, &set[k], n, units, err));
    }
    return DR_OK;
}

static DrStatus put_root_attrs(DrH5 *h, const DrBemMatrices *m, DrError *err)
{
    const DrBemDesc *d = &m->desc;
    DrBemWave wave;
    dr_bem_wave_init(&d->material, &wave);
    DR_TRY(dr_h5_attr_str(h, "/", "bem_version", DR_BEM_VERSION, err));
    DR_TRY(dr_h5_attr_str(h, "/", "units", "SI: m, s, kg, Pa", err));
    DR_TRY(dr_h5_attr_i64(h, "/", "n_vertices", m->nv, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "n_triangles", m->nt, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "n", m->n, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "n_max", m->n_max, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "dt", d->dt, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "density", d->material.density, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "shear_modulus", d->material.shear_modulus, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "poisson", d->material.poisson, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "lame_lambda", wave.lambda, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "longitudinal_wave_speed", wave.c1, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "shear_wave_speed", wave.c2, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "history_margin", d->history_margin, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "cq_epsilon", d->cq_epsilon, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "compression_ratio", d->compression_ratio, err));
    DR_TRY(dr_h5_attr_str(h, "/", "ordering", dr_bem_ordering_name(d->ordering), err));
    DR_TRY(dr_h5_attr_i64(h, "/", "wavelet", d->wavelet ? 1 : 0, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "quad_levels", d->quad_levels, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "near_factor", d->near_factor, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "singular_order", d->singular_order, err));

    const DrBemStats *st = &m->stats;
    DR_TRY(dr_h5_attr_f64(h, "/stats", "seconds_quadrature", st->seconds_quadrature, err));
    DR_TRY(dr_h5_attr_f64(h, "/stats", "seconds_inverse", st->seconds_inverse, err));
    DR_TRY(dr_h5_attr_f64(h, "/stats", "seconds_compress", st->seconds_compress, err));
    DR_TRY(dr_h5_attr_i64(h, "/stats", "frequencies_evaluated", st->frequencies_evaluated, err));
    DR_TRY(dr_h5_attr_f64(h, "/stats", "rigid_residual", st->rigid_residual, err));
    DR_TRY(dr_h5_attr_i64(h, "/stats", "bytes_dense", (int64_t)st->bytes_dense, err));
    return dr_h5_attr_i64(h, "/stats", "bytes_compressed", (int64_t)st->bytes_compressed, err);
}

static DrStatus put_all(DrH5 *h, const DrBemMatrices *m, DrError *err)
{
    const uint64_t nv = (uint64_t)m->nv, nt = (uint64_t)m->nt, n = (uint64_t)m->n, K = (uint64_t)m->n_max + 1;
    const DrBemBody *b = &m->body;
    DR_TRY(put_root_attrs(h, m, err));
    DR_TRY(put_f64(h, "/mesh/x", 2, (uint64_t[]){nv, 3}, m->x, "m", "rest positions of the vertices", err));
    DR_TRY(put_indices(h, "/mesh/tri", 2, (uint64_t[]){nt, 3}, m->tri,
                       "vertex indices (0-based) of each triangle, counter-clockwise seen from outside", err));
    DR_TRY(put_indices(h, "/layout/perm", 1, (uint64_t[]){n}, m->layout.perm,
                       "perm[new] = old: the natural unknown (3 vertex + axis) at each position of the compressed "
                       "order",
                       err));
    DR_TRY(dr_h5_attr_str(h, "/layout", "ordering", dr_bem_ordering_name(m->layout.ordering), err));
    DR_TRY(dr_h5_attr_i64(h, "/layout", "wavelet", m->layout.wavelet ? 1 : 0, err));
    DR_TRY(put_f64(h, "/body/volume", 1, (uint64_t[]){1}, &b->volume, "m^3", NULL, err));
    DR_TRY(put_f64(h, "/body/mass", 1, (uint64_t[]){1}, &b->mass, "kg", NULL, err));
    DR_TRY(put_f64(h, "/body/centroid", 1, (uint64_t[]){3}, b->centroid, "m", NULL, err));
    DR_TRY(put_f64(h, "/body/inertia", 2, (uint64_t[]){3, 3}, b->inertia, "kg*m^2", "about the centroid", err));
    DR_TRY(put_f64(h, "/body/r_max", 1, (uint64_t[]){1}, &b->r_max, "m", "largest distance between two vertices",
                   err));
    DR_TRY(put_f64(h, "/A", 2, (uint64_t[]){3, n}, m->A, "m^2/kg",
                   "A = (1/m) int Phi dGamma: frame acceleration per nodal traction (BEM eq. 10)", err));
    DR_TRY(put_f64(h, "/C", 2, (uint64_t[]){3, n}, m->C, "m/kg",
                   "C = I^-1 int (y - centroid) x Phi dGamma: angular acceleration per nodal traction (BEM eq. 10)",
                   err));
    DR_TRY(put_f64(h, "/w", 1, (uint64_t[]){nv}, m->w, "m^3", "shape-matching weights int y.n Phi_j dGamma", err));
    DR_TRY(put_f64(h, "/area", 1, (uint64_t[]){nv}, m->area, "m^2", "vertex areas int Phi_j dGamma", err));
    DR_TRY(put_f64(h, "/D", 3, (uint64_t[]){K, n, 3}, m->D, "s^2", "D_k, k = 0..n_max (BEM eq. 9)", err));
    DR_TRY(put_f64(h, "/Q", 3, (uint64_t[]){K, n, 3}, m->Q, "m*s^2", "Q_k, k = 0..n_max (BEM eq. 9)", err));
    DR_TRY(put_cmat_set(h, "/H", m->H, (int)K, m->n, "1", "H_k, k = 0..n_max (BEM eq. 9)", err));
    DR_TRY(put_cmat_set(h, "/G", m->G, (int)K, m->n, "m/Pa", "G_k, k = 0..n_max (BEM eq. 9)", err));
    DR_TRY(dr_h5_attr_str(h, "/H0inv", "description", "inverse of H_0 (BEM eq. 12)", err));
    DR_TRY(put_cmat(h, "/H0inv", &m->H0inv, m->n, "1", err));
    DR_TRY(dr_h5_attr_str(h, "/H0inv_Gp", "description", "H_0^-1 G', G' = G_0 + D_0 A + Q_0 C (BEM eq. 12)", err));
    return put_cmat(h, "/H0inv_Gp", &m->H0inv_Gp, m->n, "m/Pa", err);
}

DrStatus dr_bem_cache_write(const char *cache_root, const char *key_hex, const char *inputs_json,
                            const char *mesh_hash_hex, const DrBemMatrices *m, DrError *err)
{
    assert(m && m->nv > 0 && m->n == 3 * m->nv && m->nt > 0 && m->n_max >= 0);
    assert(m->layout.nv == m->nv && m->H && m->G);
    DrH5 *h;
    DR_TRY(dr_io_precache_create(cache_root, CACHE_KIND, key_hex, inputs_json, mesh_hash_hex, &h, err));
    DrStatus s = put_all(h, m, err);
    if (s != DR_OK) {
        dr_h5_close(&h); /* removes the temporary file: nothing is left that a later run could trust */
        return s;
    }
    return dr_h5_commit(&h, err);
}

/* ---- read ----------------------------------------------------------------------------------------------- */

/* Every check below fails with DR_ERR_INPUT and a message saying what does not fit; dr_bem_cache_read turns
 * that into "not found" with the reason in `rejected`, and only running out of memory into a failure. */

static DrStatus bad(DrH5 *h, DrError *err, const char *fmt, const char *what, long long a, long long b)
{
    char msg[512];
    snprintf(msg, sizeof msg, fmt, what, a, b);
    return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0, "%s", msg);
}

static DrStatus check_dims(DrH5 *h, const char *path, int rank, const uint64_t *dims, int want_rank,
                           const uint64_t *want, DrError *err)
{
    if (rank != want_rank) return bad(h, err, "dataset %s has rank %lld; expected %lld", path, rank, want_rank);
    for (int i = 0; i < rank; i++)
        if (dims[i] != want[i])
            return bad(h, err, "dataset %s has %lld entries along a dimension where the sizes recorded in the file "
                               "imply %lld",
                       path, (long long)dims[i], (long long)want[i]);
    return DR_OK;
}

/* Reads a float dataset of exactly the given shape into *out (malloc'd). */
static DrStatus get_f64(DrH5 *h, const char *path, int want_rank, const uint64_t *want, double **out, DrError *err)
{
    int rank;
    uint64_t dims[4];
    DR_TRY(dr_h5_read_f64(h, path, &rank, dims, out, err));
    return check_dims(h, path, rank, dims, want_rank, want, err);
}

/* Into a caller array of prod(want) doubles. */
static DrStatus get_f64_into(DrH5 *h, const char *path, int want_rank, const uint64_t *want, double *dst, size_t count,
                             DrError *err)
{
    double *tmp = NULL;
    DrStatus s = get_f64(h, path, want_rank, want, &tmp, err);
    if (s == DR_OK) memcpy(dst, tmp, count * sizeof *dst);
    free(tmp);
    return s;
}

static DrStatus get_i32(DrH5 *h, const char *path, int want_rank, const uint64_t *want, int32_t **out, DrError *err)
{
    int rank;
    uint64_t dims[4];
    DR_TRY(dr_h5_read_i32(h, path, &rank, dims, out, err));
    return check_dims(h, path, rank, dims, want_rank, want, err);
}

static DrStatus get_int_attr(DrH5 *h, const char *obj, const char *name, int64_t lo, int64_t hi, int64_t *out,
                             DrError *err)
{
    DR_TRY(dr_h5_read_attr_i64(h, obj, name, out, err));
    if (*out < lo || *out > hi) {
        char what[128];
        snprintf(what, sizeof what, "%s of %s", name, obj);
        return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0, "attribute %s = %lld is outside [%lld, %lld]",
                            what, (long long)*out, (long long)lo, (long long)hi);
    }
    return DR_OK;
}

static DrStatus get_str_attr(DrH5 *h, const char *obj, const char *name, char *buf, size_t size, DrError *err)
{
    char *v = NULL;
    DR_TRY(dr_h5_read_attr_str(h, obj, name, &v, err));
    snprintf(buf, size, "%s", v);
    free(v);
    return DR_OK;
}

static DrStatus get_ordering(DrH5 *h, const char *obj, DrBemOrdering *out, DrError *err)
{
    char s[32];
    DR_TRY(get_str_attr(h, obj, "ordering", s, sizeof s, err));
    if (!dr_bem_ordering_parse(s, out))
        return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0, "attribute ordering of %s is '%s'; expected "
                            "vertex_xyz, xyz or none", obj, s);
    return DR_OK;
}

/* Indices in [0, limit). */
static DrStatus check_indices(DrH5 *h, const char *path, const int32_t *v, uint64_t count, int64_t limit,
                              DrError *err)
{
    for (uint64_t i = 0; i < count; i++)
        if (v[i] < 0 || v[i] >= limit)
            return bad(h, err, "dataset %s holds index %lld, outside [0, %lld)", path, v[i], limit);
    return DR_OK;
}

static DrStatus get_cmat(DrH5 *h, const char *g, int n, DrBemCMat *c, DrError *err)
{
    char storage[16], path[PATH_LEN];
    c->n = n;
    DR_TRY(get_str_attr(h, g, "storage", storage, sizeof storage, err));
    const uint64_t un = (uint64_t)n;
    if (strcmp(storage, "dense") == 0) {
        c->dense = true;
        c->nnz = (int64_t)n * n;
        snprintf(path, sizeof path, "%s/val", g);
        return get_f64(h, path, 2, (uint64_t[]){un, un}, &c->val, err);
    }
    if (strcmp(storage, "csr") != 0)
        return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0, "attribute storage of %s is '%s'; expected dense "
                            "or csr", g, storage);
    c->dense = false;
    int rank;
    uint64_t dims[4];
    snprintf(path, sizeof path, "%s/row_ptr", g);
    DR_TRY(dr_h5_read_i64(h, path, &rank, dims, &c->row_ptr, err));
    DR_TRY(check_dims(h, path, rank, dims, 1, (uint64_t[]){un + 1}, err));
    const int64_t *rp = c->row_ptr;
    if (rp[0] != 0) return bad(h, err, "dataset %s starts at %lld; expected %lld", path, rp[0], 0);
    for (int i = 0; i < n; i++)
        if (rp[i + 1] < rp[i] || rp[i + 1] - rp[i] > n)
            return bad(h, err, "dataset %s is not a row pointer: row %lld holds %lld entries", path, i,
                       rp[i + 1] - rp[i]);
    c->nnz = rp[n];
    snprintf(path, sizeof path, "%s/col", g);
    DR_TRY(get_i32(h, path, 1, (uint64_t[]){(uint64_t)c->nnz}, &c->col, err));
    DR_TRY(check_indices(h, path, c->col, (uint64_t)c->nnz, n, err));
    snprintf(path, sizeof path, "%s/val", g);
    return get_f64(h, path, 1, (uint64_t[]){(uint64_t)c->nnz}, &c->val, err);
}

static DrStatus get_cmat_set(DrH5 *h, const char *g, DrBemCMat *set, int count, int n, DrError *err)
{
    int64_t recorded;
    DR_TRY(get_int_attr(h, g, "count", count, count, &recorded, err));
    for (int k = 0; k < count; k++) {
        char sub[PATH_LEN];
        snprintf(sub, sizeof sub, "%s/%d", g, k);
        DR_TRY(get_cmat(h, sub, n, &set[k], err));
    }
    return DR_OK;
}

/* A permutation of 0..n-1. */
static DrStatus check_perm(DrH5 *h, const int32_t *perm, int n, DrError *err)
{
    bool *seen = NULL;
    DR_TRY(dr_calloc((size_t)n, sizeof *seen, &seen, err));
    DrStatus s = DR_OK;
    for (int i = 0; i < n && s == DR_OK; i++) {
        if (perm[i] < 0 || perm[i] >= n || seen[perm[i]])
            s = bad(h, err, "dataset %s is not a permutation: entry %lld is %lld", "/layout/perm", i, perm[i]);
        else
            seen[perm[i]] = true;
    }
    free(seen);
    return s;
}

/* The attributes that size everything else, and the parameters the matrices were built with. A DrBemDesc field
 * added later that changes the matrices belongs in the key, in put_root_attrs and here, with a new
 * DR_BEM_VERSION; until then it reads back as its dr_bem_desc_default value. */
static DrStatus get_header(DrH5 *h, DrBemMatrices *m, DrError *err)
{
    char version[64];
    DR_TRY(get_str_attr(h, "/", "bem_version", version, sizeof version, err));
    if (strcmp(version, DR_BEM_VERSION) != 0)
        return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0, "written by BEM code version '%s'; this is '%s'",
                            version, DR_BEM_VERSION);
    int64_t nv, nt, n, n_max, v;
    /* bounds keep every size product below int and 3N·3N below int64 */
    DR_TRY(get_int_attr(h, "/", "n_vertices", 1, 100000000, &nv, err));
    DR_TRY(get_int_attr(h, "/", "n_triangles", 1, 200000000, &nt, err));
    DR_TRY(get_int_attr(h, "/", "n", 3, 300000000, &n, err));
    if (n != 3 * nv)
        return bad(h, err, "attribute %s = %lld is not 3 n_vertices = %lld", "n of /", n, 3 * nv);
    DR_TRY(get_int_attr(h, "/", "n_max", 0, 1000000, &n_max, err));
    m->nv = (int)nv;
    m->nt = (int)nt;
    m->n = (int)n;
    m->n_max = (int)n_max;

    DrBemDesc *d = &m->desc;
    dr_bem_desc_default(d);
    d->keep_dense = false; /* the dense copies are never cached */
    DR_TRY(dr_h5_read_attr_f64(h, "/", "dt", &d->dt, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/", "density", &d->material.density, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/", "shear_modulus", &d->material.shear_modulus, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/", "poisson", &d->material.poisson, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/", "history_margin", &d->history_margin, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/", "cq_epsilon", &d->cq_epsilon, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/", "compression_ratio", &d->compression_ratio, err));
    DR_TRY(get_ordering(h, "/", &d->ordering, err));
    DR_TRY(get_int_attr(h, "/", "wavelet", 0, 1, &v, err));
    d->wavelet = v != 0;
    DR_TRY(get_int_attr(h, "/", "quad_levels", 0, 64, &v, err));
    d->quad_levels = (int)v;
    DR_TRY(dr_h5_read_attr_f64(h, "/", "near_factor", &d->near_factor, err));
    DR_TRY(get_int_attr(h, "/", "singular_order", 0, 1024, &v, err));
    d->singular_order = (int)v;

    DrBemStats *st = &m->stats;
    DR_TRY(dr_h5_read_attr_f64(h, "/stats", "seconds_quadrature", &st->seconds_quadrature, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/stats", "seconds_inverse", &st->seconds_inverse, err));
    DR_TRY(dr_h5_read_attr_f64(h, "/stats", "seconds_compress", &st->seconds_compress, err));
    DR_TRY(get_int_attr(h, "/stats", "frequencies_evaluated", 0, INT32_MAX, &v, err));
    st->frequencies_evaluated = (int)v;
    DR_TRY(dr_h5_read_attr_f64(h, "/stats", "rigid_residual", &st->rigid_residual, err));
    DR_TRY(get_int_attr(h, "/stats", "bytes_dense", 0, INT64_MAX, &v, err));
    st->bytes_dense = (size_t)v;
    DR_TRY(get_int_attr(h, "/stats", "bytes_compressed", 0, INT64_MAX, &v, err));
    st->bytes_compressed = (size_t)v;
    return DR_OK;
}

static DrStatus get_body(DrH5 *h, DrBemBody *b, DrError *err)
{
    DR_TRY(get_f64_into(h, "/body/volume", 1, (uint64_t[]){1}, &b->volume, 1, err));
    DR_TRY(get_f64_into(h, "/body/mass", 1, (uint64_t[]){1}, &b->mass, 1, err));
    DR_TRY(get_f64_into(h, "/body/centroid", 1, (uint64_t[]){3}, b->centroid, 3, err));
    DR_TRY(get_f64_into(h, "/body/inertia", 2, (uint64_t[]){3, 3}, b->inertia, 9, err));
    return get_f64_into(h, "/body/r_max", 1, (uint64_t[]){1}, &b->r_max, 1, err);
}

static DrStatus get_all(DrH5 *h, DrBemMatrices *m, DrError *err)
{
    DR_TRY(get_header(h, m, err));
    const uint64_t nv = (uint64_t)m->nv, nt = (uint64_t)m->nt, n = (uint64_t)m->n, K = (uint64_t)m->n_max + 1;
    /* the matrix arrays first, zeroed, so that the destructor finds every slot it walks */
    DR_TRY(dr_calloc(K, sizeof *m->H, &m->H, err));
    DR_TRY(dr_calloc(K, sizeof *m->G, &m->G, err));

    DR_TRY(get_f64(h, "/mesh/x", 2, (uint64_t[]){nv, 3}, &m->x, err));
    int32_t *tri = NULL;
    DR_TRY(get_i32(h, "/mesh/tri", 2, (uint64_t[]){nt, 3}, &tri, err));
    m->tri = (int *)tri;
    DR_TRY(check_indices(h, "/mesh/tri", tri, 3 * nt, m->nv, err));

    DrBemLayout *l = &m->layout;
    l->nv = m->nv;
    DR_TRY(get_ordering(h, "/layout", &l->ordering, err));
    int64_t wavelet;
    DR_TRY(get_int_attr(h, "/layout", "wavelet", 0, 1, &wavelet, err));
    l->wavelet = wavelet != 0;
    int32_t *perm = NULL;
    DR_TRY(get_i32(h, "/layout/perm", 1, (uint64_t[]){n}, &perm, err));
    l->perm = (int *)perm;
    DR_TRY(check_perm(h, perm, m->n, err));
    if (l->ordering != m->desc.ordering || l->wavelet != m->desc.wavelet)
        return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                            "the layout's ordering or wavelet flag differs from the parameters recorded at the root");

    DR_TRY(get_body(h, &m->body, err));
    DR_TRY(get_f64(h, "/A", 2, (uint64_t[]){3, n}, &m->A, err));
    DR_TRY(get_f64(h, "/C", 2, (uint64_t[]){3, n}, &m->C, err));
    DR_TRY(get_f64(h, "/w", 1, (uint64_t[]){nv}, &m->w, err));
    DR_TRY(get_f64(h, "/area", 1, (uint64_t[]){nv}, &m->area, err));
    DR_TRY(get_f64(h, "/D", 3, (uint64_t[]){K, n, 3}, &m->D, err));
    DR_TRY(get_f64(h, "/Q", 3, (uint64_t[]){K, n, 3}, &m->Q, err));
    DR_TRY(get_cmat_set(h, "/H", m->H, (int)K, m->n, err));
    DR_TRY(get_cmat_set(h, "/G", m->G, (int)K, m->n, err));
    DR_TRY(get_cmat(h, "/H0inv", m->n, &m->H0inv, err));
    return get_cmat(h, "/H0inv_Gp", m->n, &m->H0inv_Gp, err);
}

DrStatus dr_bem_cache_read(const char *cache_root, const char *key_hex, DrBemMatrices **out, bool *found,
                           DrError *rejected, DrError *err)
{
    *out = NULL;
    *found = false;
    DrH5 *h;
    bool opened;
    DR_TRY(dr_io_precache_open(cache_root, CACHE_KIND, key_hex, &h, &opened, rejected, err));
    if (!opened) return DR_OK;

    DrBemMatrices *m = NULL;
    DrError why;
    dr_error_clear(&why);
    DrStatus s = dr_calloc(1, sizeof *m, &m, &why);
    if (s == DR_OK) s = bem_runtime_new(&m->runtime, &why);
    if (s == DR_OK) s = get_all(h, m, &why);
    if (s != DR_OK) {
        dr_bem_matrices_destroy(&m);
        if (s == DR_ERR_NOMEM) {
            *err = why;
            dr_h5_close(&h);
            return s;
        }
        /* A file that opens and carries the right key but does not hold what it says (edited, written by a
         * foreign tool, damaged on disk: its checksums tell) is not trusted; what follows is the caller's. */
        if (rejected) {
            *rejected = why;
            rejected->status = DR_ERR_INPUT;
            if (!rejected->file[0]) snprintf(rejected->file, sizeof rejected->file, "%s", dr_h5_path(h));
        }
        dr_h5_close(&h);
        return DR_OK;
    }
    dr_h5_close(&h);
    *out = m;
    *found = true;
    return DR_OK;
}
