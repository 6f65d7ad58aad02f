/* Unit tests for the compression of src/bem (BEM §3.3): the 1-D Haar transform, the layouts, exact
 * selection of the largest coefficients, compressed products against the reconstructed matrix, the error
 * of the full scheme against its simpler variants on a smooth kernel, thread-count determinism,
 * the runtime's compact 16-bit copies, degenerate sizes and bad input. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdlib.h>
#include <string.h>

#include "bem/bem.h"
#include "bem/bem_internal.h"
#include "core/core.h"

/* ---- helpers ----------------------------------------------------------------------------------- */

/* |a − b| <= tol, reporting both values on failure (cmocka's float assertion works in float). */
static void near_or_fail(double a, double b, double tol, const char *file, int line)
{
    if (fabs(a - b) <= tol) return;
    print_error("%.17g != %.17g (|diff| %.3g > tol %.3g)\n", a, b, fabs(a - b), tol);
    _fail(file, line);
}
#define assert_near(a, b, tol) near_or_fail((a), (b), (tol), __FILE__, __LINE__)

static double norm2(const double *x, size_t n)
{
    double s = 0.0;
    for (size_t i = 0; i < n; i++) s += x[i] * x[i];
    return sqrt(s);
}

static double diff_norm2(const double *a, const double *b, size_t n)
{
    double s = 0.0;
    for (size_t i = 0; i < n; i++) s += (a[i] - b[i]) * (a[i] - b[i]);
    return sqrt(s);
}

static void fill_uniform(DrRng *rng, double *x, size_t n)
{
    for (size_t i = 0; i < n; i++) x[i] = 2.0 * dr_rng_uniform(rng) - 1.0;
}

/* A random vertex order (Fisher–Yates): order[new] = old. */
static void random_order(DrRng *rng, int nv, int *order)
{
    for (int i = 0; i < nv; i++) order[i] = i;
    for (int i = nv - 1; i > 0; i--) {
        int j = (int)(dr_rng_uniform(rng) * (i + 1));
        int t = order[i];
        order[i] = order[j];
        order[j] = t;
    }
}

static void plain_matvec(const double *a, int n, const double *x, double *y)
{
    for (int i = 0; i < n; i++) {
        double s = 0.0;
        for (int j = 0; j < n; j++) s += a[(size_t)i * n + j] * x[j];
        y[i] = s;
    }
}

static int64_t expected_kept(int n, double ratio)
{
    int64_t k = (int64_t)ceil((double)n * n / ratio);
    return k < 1 ? 1 : k;
}

static DrBemLayout make_layout(int nv, DrBemOrdering ordering, bool wavelet, const int *order)
{
    DrBemLayout l;
    DrError err;
    assert_int_equal(dr_bem_layout_init(nv, ordering, wavelet, order, &l, &err), DR_OK);
    return l;
}

/* ---- 1-D Haar ------------------------------------------------------------------------------------ */

/* The stated storage order, by hand: n = 3 carries the odd element once, n = 5 twice, n = 8 has no tail. */
static void test_haar_layout_by_hand(void **state)
{
    (void)state;
    const double h = 1.0 / sqrt(2.0);
    double tmp[8];
    /* Each expected value is at most three levels of one add and one multiply away from exact: 1e-15 is
     * a few ulps of values of order 10. */
    const double tol = 1e-15 * 16;

    double x3[3] = {1, 2, 4};
    dr_bem_haar_forward(x3, 3, tmp);
    double a3 = (1 + 2) * h;
    assert_near(x3[0], (a3 + 4) * h, tol);
    assert_near(x3[1], (a3 - 4) * h, tol);
    assert_near(x3[2], (1 - 2) * h, tol);

    double x5[5] = {1, 2, 4, 8, 16};
    dr_bem_haar_forward(x5, 5, tmp);
    double A0 = (1 + 2) * h, A1 = (4 + 8) * h, D0 = (1 - 2) * h, D1 = (4 - 8) * h;
    double B0 = (A0 + A1) * h, C0 = (A0 - A1) * h;
    assert_near(x5[0], (B0 + 16) * h, tol);
    assert_near(x5[1], (B0 - 16) * h, tol);
    assert_near(x5[2], C0, tol);
    assert_near(x5[3], D0, tol);
    assert_near(x5[4], D1, tol);

    /* a constant of length 8 is one coarsest average √8·c and no detail */
    double x8[8];
    for (int i = 0; i < 8; i++) x8[i] = 3.0;
    dr_bem_haar_forward(x8, 8, tmp);
    assert_near(x8[0], 3.0 * sqrt(8.0), tol);
    for (int i = 1; i < 8; i++) assert_near(x8[i], 0.0, tol);

    /* n = 0 and n = 1 are the identity */
    double x1 = 5.0;
    dr_bem_haar_forward(&x1, 1, tmp);
    assert_true(x1 == 5.0);
    dr_bem_haar_inverse(&x1, 1, tmp);
    assert_true(x1 == 5.0);
    dr_bem_haar_forward(NULL, 0, tmp);
}

/* Round trip, norm preservation and orthonormality for lengths with and without odd tails. Every value
 * passes through at most L = ⌈log₂ n⌉ ≤ 10 levels of one add and one multiply each way, so the round trip
 * and norm errors are bounded by about 4·L·u‖x‖ ≈ 4.4e-15‖x‖ (u = 1.1e-16); 1e-14 leaves a factor 2.
 * Entries of W Wᵀ − I are sums of at most L+1 products of such values: also within 1e-14. */
static void test_haar_round_trip_orthonormal(void **state)
{
    (void)state;
    const int sizes[] = {1, 2, 3, 5, 8, 17, 1000, 1001};
    const double tol = 1e-14;
    DrRng rng;
    dr_rng_seed(&rng, 11);
    for (size_t t = 0; t < sizeof sizes / sizeof *sizes; t++) {
        int n = sizes[t];
        double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y), *tmp = malloc(n * sizeof *tmp);
        double *W = calloc((size_t)n * n, sizeof *W), *G = calloc((size_t)n * n, sizeof *G);
        fill_uniform(&rng, x, n);
        memcpy(y, x, n * sizeof *x);
        dr_bem_haar_forward(y, n, tmp);
        double nx = norm2(x, n);
        assert_near(norm2(y, n), nx, tol * nx);
        dr_bem_haar_inverse(y, n, tmp);
        assert_true(diff_norm2(x, y, n) <= tol * nx);

        /* column j of W is W e_j; W Wᵀ accumulated column by column over each column's nonzeros */
        int *nz = malloc(n * sizeof *nz);
        for (int j = 0; j < n; j++) {
            memset(y, 0, n * sizeof *y);
            y[j] = 1.0;
            dr_bem_haar_forward(y, n, tmp);
            int cnt = 0;
            for (int i = 0; i < n; i++) {
                W[(size_t)i * n + j] = y[i];
                if (y[i] != 0.0) nz[cnt++] = i;
            }
            for (int a = 0; a < cnt; a++)
                for (int b = 0; b < cnt; b++) G[(size_t)nz[a] * n + nz[b]] += y[nz[a]] * y[nz[b]];
        }
        double worst = 0.0;
        for (int i = 0; i < n; i++)
            for (int k = 0; k < n; k++) worst = fmax(worst, fabs(G[(size_t)i * n + k] - (i == k ? 1.0 : 0.0)));
        assert_true(worst <= tol);

        /* the inverse is Wᵀ: inverse(e_i) is row i of W */
        for (int i = 0; i < n; i += (n > 64 ? 37 : 1)) {
            memset(y, 0, n * sizeof *y);
            y[i] = 1.0;
            dr_bem_haar_inverse(y, n, tmp);
            for (int j = 0; j < n; j++) assert_near(y[j], W[(size_t)i * n + j], tol);
        }
        free(nz);
        free(x);
        free(y);
        free(tmp);
        free(W);
        free(G);
    }
}

/* ---- layouts ----------------------------------------------------------------------------------------- */

static void test_layout_permutations(void **state)
{
    (void)state;
    const int nv = 4, order[4] = {2, 0, 3, 1};
    DrBemLayout l = make_layout(nv, DR_BEM_ORDER_VERTEX_XYZ, true, order);
    for (int c = 0; c < 3; c++)
        for (int v = 0; v < nv; v++) assert_int_equal(l.perm[c * nv + v], 3 * order[v] + c);
    assert_int_equal(l.nv, nv);
    dr_bem_layout_free(&l);
    assert_null(l.perm);
    dr_bem_layout_free(&l);
    dr_bem_layout_free(NULL);

    l = make_layout(nv, DR_BEM_ORDER_XYZ, true, order);
    for (int c = 0; c < 3; c++)
        for (int v = 0; v < nv; v++) assert_int_equal(l.perm[c * nv + v], 3 * v + c);
    dr_bem_layout_free(&l);

    l = make_layout(nv, DR_BEM_ORDER_NONE, false, NULL);
    for (int i = 0; i < 3 * nv; i++) assert_int_equal(l.perm[i], i);
    assert_false(l.wavelet);
    dr_bem_layout_free(&l);
}

/* ---- compressed products ---------------------------------------------------------------------------- */

/* A test matrix with a smooth part and a rough part: 1/(1 + |i − j|/4) plus uniform noise of 0.1. */
static double *test_matrix(DrRng *rng, int n)
{
    double *m = malloc((size_t)n * n * sizeof *m);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++)
            m[(size_t)i * n + j] = 1.0 / (1.0 + abs(i - j) / 4.0) + 0.1 * (2.0 * dr_rng_uniform(rng) - 1.0);
    return m;
}

/* For every ordering, with and without the wavelet, at ratios 1, 4 and 32: the compressed product equals
 * the product with the reconstructed matrix, the kept count is exactly ⌈n²/ratio⌉, ratio 1 keeps the
 * matrix itself, and the storage is what dr_bem_cmat_bytes states. The two products differ only by the
 * rounding of the Haar transforms (≤ 2·L·u relative, L ≤ 6 here) and of the sums (n·u), all relative to
 * ‖M̂‖_F‖x‖: about 7e-15, so 1e-12 is a loose bound that still catches any wrong index or sign. */
static void test_matvec_matches_decompressed(void **state)
{
    (void)state;
    const int nv = 17, n = 3 * nv; /* odd N: every block length has an odd tail */
    const double ratios[] = {1.0, 4.0, 32.0};
    const DrBemOrdering orderings[] = {DR_BEM_ORDER_VERTEX_XYZ, DR_BEM_ORDER_XYZ, DR_BEM_ORDER_NONE};
    DrRng rng;
    dr_rng_seed(&rng, 5);
    double *m = test_matrix(&rng, n);
    double *dec = malloc((size_t)n * n * sizeof *dec);
    double x[3 * 17], y[3 * 17], yref[3 * 17], scratch[2 * 3 * 17];
    int order[17];
    random_order(&rng, nv, order);
    fill_uniform(&rng, x, n);
    DrError err;
    for (int o = 0; o < 3; o++)
        for (int w = 0; w < 2; w++) {
            DrBemLayout l = make_layout(nv, orderings[o], w == 1, order);
            for (int r = 0; r < 3; r++) {
                DrBemCMat c;
                assert_int_equal(dr_bem_compress(&l, m, ratios[r], &c, &err), DR_OK);
                assert_int_equal(c.n, n);
                dr_bem_cmat_decompress(&l, &c, dec);
                if (ratios[r] == 1.0) {
                    /* ratio 1 is a copy: bit-identical by contract, so exact comparison is the claim */
                    assert_true(c.dense);
                    assert_int_equal(c.nnz, (int64_t)n * n);
                    assert_int_equal(dr_bem_cmat_bytes(&c), (size_t)n * n * sizeof(double));
                    assert_memory_equal(dec, m, (size_t)n * n * sizeof *m);
                } else {
                    assert_false(c.dense);
                    assert_int_equal(c.nnz, expected_kept(n, ratios[r]));
                    assert_int_equal(c.row_ptr[n], c.nnz);
                    assert_int_equal(dr_bem_cmat_bytes(&c), (size_t)c.nnz * 12 + (size_t)(n + 1) * 8);
                    for (int i = 0; i < n; i++)
                        for (int64_t k = c.row_ptr[i]; k < c.row_ptr[i + 1]; k++) {
                            assert_true(c.col[k] >= 0 && c.col[k] < n);
                            if (k > c.row_ptr[i]) assert_true(c.col[k] > c.col[k - 1]);
                        }
                }
                plain_matvec(dec, n, x, yref);
                dr_bem_cmat_matvec(&l, &c, x, y, scratch);
                double scale = norm2(dec, (size_t)n * n) * norm2(x, n);
                assert_true(diff_norm2(y, yref, n) <= 1e-12 * scale);
                dr_bem_cmat_free(&c);
                assert_null(c.val);
            }
            dr_bem_layout_free(&l);
        }
    free(m);
    free(dec);
}

/* Keeping every coefficient reconstructs the matrix through P, W and their inverses, and by orthonormality
 * the coefficients carry the matrix's Frobenius norm. Two 1-D transforms each way with L ≤ 7 levels bound
 * the relative error by about 8·L·u ≈ 6e-15; 1e-13 leaves margin. Then at ratio 8 the kept coefficients
 * are exactly the largest of these same coefficients (bit-identical values at the same positions: the
 * transform is computed the same way), and no dropped one is larger than a kept one. */
static void test_all_kept_and_largest_kept(void **state)
{
    (void)state;
    const int nv = 30, n = 3 * nv;
    const double ratio_all = 1.0 + 1e-9; /* ⌈n²/ratio⌉ = n² since n²·1e-9 < 1 */
    DrRng rng;
    dr_rng_seed(&rng, 9);
    double *m = test_matrix(&rng, n);
    double *dec = malloc((size_t)n * n * sizeof *dec), *full = calloc((size_t)n * n, sizeof *full);
    unsigned char *kept = calloc((size_t)n * n, 1);
    int order[30];
    random_order(&rng, nv, order);
    DrError err;
    for (int o = 0; o < 3; o++) {
        DrBemLayout l = make_layout(nv, (DrBemOrdering)o, true, order);
        DrBemCMat c, s;
        assert_int_equal(dr_bem_compress(&l, m, ratio_all, &c, &err), DR_OK);
        assert_false(c.dense);
        assert_int_equal(c.nnz, (int64_t)n * n);
        dr_bem_cmat_decompress(&l, &c, dec);
        double nm = norm2(m, (size_t)n * n);
        assert_true(diff_norm2(dec, m, (size_t)n * n) <= 1e-13 * nm);
        assert_near(norm2(c.val, (size_t)c.nnz), nm, 1e-13 * nm);

        for (int i = 0; i < n; i++)
            for (int64_t k = c.row_ptr[i]; k < c.row_ptr[i + 1]; k++) full[(size_t)i * n + c.col[k]] = c.val[k];
        assert_int_equal(dr_bem_compress(&l, m, 8.0, &s, &err), DR_OK);
        memset(kept, 0, (size_t)n * n);
        double min_kept = INFINITY, max_dropped = 0.0;
        for (int i = 0; i < n; i++)
            for (int64_t k = s.row_ptr[i]; k < s.row_ptr[i + 1]; k++) {
                size_t at = (size_t)i * n + s.col[k];
                assert_true(s.val[k] == full[at]);
                kept[at] = 1;
                min_kept = fmin(min_kept, fabs(s.val[k]));
            }
        for (size_t at = 0; at < (size_t)n * n; at++)
            if (!kept[at]) max_dropped = fmax(max_dropped, fabs(full[at]));
        assert_true(max_dropped <= min_kept);
        dr_bem_cmat_free(&c);
        dr_bem_cmat_free(&s);
        dr_bem_layout_free(&l);
    }
    free(m);
    free(dec);
    free(full);
    free(kept);
}

/* Ties at the threshold are kept in row-major order, so exactly k survive and the choice is reproducible:
 * a matrix of ones without the wavelet at ratio 4 keeps the first ⌈36/4⌉ = 9 entries, the first row and
 * the start of the second. */
static void test_ties_row_major(void **state)
{
    (void)state;
    const int nv = 2, n = 6;
    double m[36];
    for (int i = 0; i < 36; i++) m[i] = (i % 2) ? 1.0 : -1.0;
    DrBemLayout l = make_layout(nv, DR_BEM_ORDER_NONE, false, NULL);
    DrBemCMat c;
    DrError err;
    assert_int_equal(dr_bem_compress(&l, m, 4.0, &c, &err), DR_OK);
    assert_int_equal(c.nnz, 9);
    assert_int_equal(c.row_ptr[1], 6);
    assert_int_equal(c.row_ptr[2], 9);
    for (int i = 2; i <= n; i++) assert_int_equal(c.row_ptr[i], 9);
    for (int k = 0; k < 9; k++) assert_int_equal(c.col[k], k % 6);
    dr_bem_cmat_free(&c);
    dr_bem_layout_free(&l);
}

/* ---- the smooth kernel: the full scheme against its variants ------------------------------------------ */

/* Bits of q spread to every third position (10 bits in, 30 out). */
static uint32_t spread3(uint32_t q)
{
    uint32_t r = 0;
    for (int b = 0; b < 10; b++) r |= ((q >> b) & 1u) << (3 * b);
    return r;
}

typedef struct MortonKey { uint32_t key; int vertex; } MortonKey;

static int morton_cmp(const void *a, const void *b)
{
    const MortonKey *p = a, *q = b;
    if (p->key != q->key) return p->key < q->key ? -1 : 1;
    return p->vertex < q->vertex ? -1 : (p->vertex > q->vertex);
}

/* A spatially coherent order for the test: vertices sorted along the Morton (Z-order) curve of their
 * positions quantised to 2¹⁰ cells per axis of the bounding box. */
static void morton_order(const double *pos, int nv, int *order)
{
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int v = 0; v < nv; v++)
        for (int a = 0; a < 3; a++) lo[a] = fmin(lo[a], pos[3 * v + a]), hi[a] = fmax(hi[a], pos[3 * v + a]);
    MortonKey *keys = malloc(nv * sizeof *keys);
    for (int v = 0; v < nv; v++) {
        uint32_t key = 0;
        for (int a = 0; a < 3; a++) {
            double t = (pos[3 * v + a] - lo[a]) / (hi[a] - lo[a] + 1e-300);
            uint32_t q = (uint32_t)fmin(1023.0, t * 1024.0);
            key |= spread3(q) << a;
        }
        keys[v] = (MortonKey){key, v};
    }
    qsort(keys, nv, sizeof *keys, morton_cmp);
    for (int p = 0; p < nv; p++) order[p] = keys[p].vertex;
    free(keys);
}

/* N points of a Fibonacci sphere pushed out radially by 1 + 0.15 sin(3x) sin(3y) sin(3z), listed in a random
 * order (a mesh file's vertex order need not be spatially coherent). */
static double *bumpy_sphere(DrRng *rng, int nv)
{
    const double golden = DR_PI * (3.0 - sqrt(5.0));
    double *p = malloc(3 * (size_t)nv * sizeof *p), *q = malloc(3 * (size_t)nv * sizeof *q);
    for (int i = 0; i < nv; i++) {
        double z = 1.0 - (2.0 * i + 1.0) / nv, rho = sqrt(1.0 - z * z), phi = golden * i;
        double x = rho * cos(phi), y = rho * sin(phi);
        double r = 1.0 + 0.15 * sin(3 * x) * sin(3 * y) * sin(3 * z);
        p[3 * i] = r * x, p[3 * i + 1] = r * y, p[3 * i + 2] = r * z;
    }
    int *shuffle = malloc(nv * sizeof *shuffle);
    random_order(rng, nv, shuffle);
    for (int i = 0; i < nv; i++) memcpy(q + 3 * i, p + 3 * shuffle[i], 3 * sizeof *p);
    free(shuffle);
    free(p);
    return q;
}

/* A softened Kelvin-like 3×3 block kernel: K_ij = (δ_ij + r_i r_j/(r² + h²))/(r + h), smooth away from the
 * diagonal blocks and decaying like 1/r, as the static fundamental solution u* does. */
static double *kelvin_matrix(const double *pos, int nv, double h)
{
    int n = 3 * nv;
    double *m = malloc((size_t)n * n * sizeof *m);
    for (int a = 0; a < nv; a++)
        for (int b = 0; b < nv; b++) {
            double r[3], rr = 0.0;
            for (int i = 0; i < 3; i++) r[i] = pos[3 * b + i] - pos[3 * a + i], rr += r[i] * r[i];
            double len = sqrt(rr);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    m[(size_t)(3 * a + i) * n + 3 * b + j] =
                        ((i == j ? 1.0 : 0.0) + r[i] * r[j] / (rr + h * h)) / (len + h);
        }
    return m;
}

/* Relative Frobenius error of the reconstruction, ‖M − M̂‖_F/‖M‖_F, by ratio and variant. It falls as
 * the ratio falls for every variant (a larger ratio keeps a subset of the same coefficients: the orthonormal
 * W makes the error the norm of the dropped ones), and at ratios 8 and 32 the full scheme — vertex order
 * along a space-filling curve, xyz blocks, Haar — beats the interleaved input order and naive pruning. The
 * errors compared differ by factors, far above their rounding (1e-15). */
static void test_smooth_kernel_error_table(void **state)
{
    (void)state;
    enum { FULL, XYZ, NONE, NAIVE, NVAR };
    const char *names[NVAR] = {"vertex+xyz", "xyz (input order)", "none (input order)", "naive pruning"};
    const int nv = 600, n = 3 * nv;
    const double ratios[] = {2, 4, 8, 16, 32, 64};
    const int nr = sizeof ratios / sizeof *ratios;
    DrRng rng;
    dr_rng_seed(&rng, 3);
    double *pos = bumpy_sphere(&rng, nv);
    double *m = kelvin_matrix(pos, nv, 0.1);
    double *dec = malloc((size_t)n * n * sizeof *dec);
    int *order = malloc(nv * sizeof *order);
    morton_order(pos, nv, order);
    DrBemLayout layouts[NVAR] = {
        make_layout(nv, DR_BEM_ORDER_VERTEX_XYZ, true, order),
        make_layout(nv, DR_BEM_ORDER_XYZ, true, NULL),
        make_layout(nv, DR_BEM_ORDER_NONE, true, NULL),
        make_layout(nv, DR_BEM_ORDER_VERTEX_XYZ, false, order),
    };
    double e[6][NVAR];
    double nm = norm2(m, (size_t)n * n);
    DrError err;
    for (int r = 0; r < nr; r++)
        for (int v = 0; v < NVAR; v++) {
            DrBemCMat c;
            assert_int_equal(dr_bem_compress(&layouts[v], m, ratios[r], &c, &err), DR_OK);
            dr_bem_cmat_decompress(&layouts[v], &c, dec);
            e[r][v] = diff_norm2(dec, m, (size_t)n * n) / nm;
            dr_bem_cmat_free(&c);
        }
    printf("relative Frobenius error, N = %d bumpy-sphere points, softened Kelvin kernel (n = %d)\n", nv, n);
    printf("%6s", "ratio");
    for (int v = 0; v < NVAR; v++) printf("  %18s", names[v]);
    printf("\n");
    for (int r = 0; r < nr; r++) {
        printf("%6g", ratios[r]);
        for (int v = 0; v < NVAR; v++) printf("  %18.3e", e[r][v]);
        printf("\n");
    }
    for (int v = 0; v < NVAR; v++)
        for (int r = 1; r < nr; r++) assert_true(e[r - 1][v] < e[r][v]);
    for (int r = 0; r < nr; r++)
        if (ratios[r] == 8 || ratios[r] == 32) {
            assert_true(e[r][FULL] < e[r][NONE]);
            assert_true(e[r][FULL] < e[r][NAIVE]);
        }
    for (int v = 0; v < NVAR; v++) dr_bem_layout_free(&layouts[v]);
    free(pos);
    free(m);
    free(dec);
    free(order);
}

/* ---- determinism --------------------------------------------------------------------------------------- */

/* Compression, products and reconstruction are bit-identical on 1 and 2 threads (every sum runs in a fixed
 * order on one thread; the selection counts integers). The size is above the serial cutoff. */
static void test_threads_bit_identical(void **state)
{
    (void)state;
    const int nv = 300, n = 3 * nv;
    DrRng rng;
    dr_rng_seed(&rng, 21);
    double *m = test_matrix(&rng, n);
    int *order = malloc(nv * sizeof *order);
    random_order(&rng, nv, order);
    double *x = malloc(n * sizeof *x), *y[2], *scratch = malloc(2 * n * sizeof *scratch), *dec[2];
    fill_uniform(&rng, x, n);
    int saved = dr_threads();
    DrError err;
    for (int o = 0; o < 3; o++) {
        DrBemLayout l = make_layout(nv, (DrBemOrdering)o, true, order);
        DrBemCMat c[2];
        for (int t = 0; t < 2; t++) {
            dr_set_threads(t + 1);
            assert_int_equal(dr_bem_compress(&l, m, 8.0, &c[t], &err), DR_OK);
            y[t] = malloc(n * sizeof *x);
            dec[t] = malloc((size_t)n * n * sizeof *m);
            dr_bem_cmat_matvec(&l, &c[t], x, y[t], scratch);
            dr_bem_cmat_decompress(&l, &c[t], dec[t]);
        }
        assert_int_equal(c[0].nnz, c[1].nnz);
        assert_memory_equal(c[0].row_ptr, c[1].row_ptr, (n + 1) * sizeof(int64_t));
        assert_memory_equal(c[0].col, c[1].col, c[0].nnz * sizeof(int32_t));
        assert_memory_equal(c[0].val, c[1].val, c[0].nnz * sizeof(double));
        assert_memory_equal(y[0], y[1], n * sizeof *x);
        assert_memory_equal(dec[0], dec[1], (size_t)n * n * sizeof *m);
        for (int t = 0; t < 2; t++) {
            dr_bem_cmat_free(&c[t]);
            free(y[t]);
            free(dec[t]);
        }
        dr_bem_layout_free(&l);
    }
    /* the dense product too */
    {
        DrBemLayout l = make_layout(nv, DR_BEM_ORDER_NONE, true, NULL);
        DrBemCMat c;
        assert_int_equal(dr_bem_compress(&l, m, 1.0, &c, &err), DR_OK);
        for (int t = 0; t < 2; t++) {
            dr_set_threads(t + 1);
            y[t] = malloc(n * sizeof *x);
            dr_bem_cmat_matvec(&l, &c, x, y[t], scratch);
        }
        assert_memory_equal(y[0], y[1], n * sizeof *x);
        free(y[0]);
        free(y[1]);
        dr_bem_cmat_free(&c);
        dr_bem_layout_free(&l);
    }
    dr_set_threads(saved);
    free(m);
    free(order);
    free(x);
    free(scratch);
}

/* ---- the runtime's compact copies ------------------------------------------------------------------------------ */

/* The 16-bit copy against the double coefficients it was made from, on a 900 × 900 matrix at 8× and 32×, with
 * rows of mixed signs, an empty row and a row of one coefficient. Each value is rounded to the nearest multiple of
 * its row's scale (row maximum / 32767), so a row's product differs from the double one by at most
 * ½·scale·Σ|x̃_j| over its coefficients, plus the rounding of two sums of a few hundred terms (1e-13 of the row's
 * Σ|m̃_ij x̃_j| is far above that and far below the bound). Both kernels (vector and scalar) and both thread
 * counts give the same bits, and so does a sum over several matrices in one pass; the natural-order product goes
 * through the same transforms as the double one; a dense set or 3N > 65535 gets no copy. */
static void test_compact_copy(void **state)
{
    (void)state;
    const int nv = 300, n = 3 * nv;
    DrRng rng;
    dr_rng_seed(&rng, 33);
    double *m = test_matrix(&rng, n);
    for (int j = 0; j < n; j++) m[(size_t)7 * n + j] *= (j % 2 ? -1e-6 : 3e-6); /* a row of small values */
    int *order = malloc(nv * sizeof *order);
    random_order(&rng, nv, order);
    double *x = malloc(n * sizeof *x), *xt = malloc(n * sizeof *x), *yd = malloc(n * sizeof *x),
           *yq[4], *scratch = malloc((2 + BEM_COLUMN_GROUPS) * n * sizeof *x);
    fill_uniform(&rng, x, n);
    DrBemLayout l = make_layout(nv, DR_BEM_ORDER_VERTEX_XYZ, true, order);
    dr_bem_layout_to_coeff(&l, false, x, xt, scratch);
    int saved = dr_threads();
    DrError err;
    const double ratios[] = {8.0, 32.0};
    for (int r = 0; r < 2; r++) {
        DrBemCMat c;
        assert_int_equal(dr_bem_compress(&l, m, ratios[r], &c, &err), DR_OK);
        BemCMatQ q;
        assert_true(bem_cmat_compact(&c, &q));
        assert_int_equal(q.nnz, c.nnz);
        dr_bem_cmat_matvec_coeff(&c, xt, yd);
        for (int v = 0; v < 4; v++) { /* scalar/vector × 1/2 threads */
            yq[v] = calloc(n, sizeof *x);
            bem_cmatq_scalar_only(v % 2 == 1);
            dr_set_threads(v / 2 + 1);
            bem_cmatq_matvec_acc(&q, xt, 1.0, yq[v], NULL);
        }
        bem_cmatq_scalar_only(false);
        dr_set_threads(saved);
        for (int v = 1; v < 4; v++) assert_memory_equal(yq[0], yq[v], n * sizeof *x);
        double err2 = 0, ref2 = 0;
        for (int i = 0; i < n; i++) {
            double big = 0, sx = 0, sm = 0;
            for (int64_t k = c.row_ptr[i]; k < c.row_ptr[i + 1]; k++) {
                big = fmax(big, fabs(c.val[k]));
                sx += fabs(xt[c.col[k]]);
                sm += fabs(c.val[k] * xt[c.col[k]]);
            }
            assert_true(fabs(yq[0][i] - yd[i]) <= 0.5 * big / 32767.0 * sx + 1e-13 * sm);
            err2 += (yq[0][i] - yd[i]) * (yq[0][i] - yd[i]);
            ref2 += yd[i] * yd[i];
        }
        assert_true(sqrt(err2 / ref2) <= 1e-4);
        /* y += sign·M̃x accumulates */
        bem_cmatq_matvec_acc(&q, xt, -1.0, yq[0], NULL);
        for (int i = 0; i < n; i++) assert_near(yq[0][i], 0.0, 1e-12 * (fabs(yd[i]) + 1));
        /* the natural-order product */
        double *y1 = malloc(n * sizeof *x), *y2 = malloc(n * sizeof *x);
        dr_bem_cmat_matvec(&l, &c, x, y1, scratch);
        bem_cmatq_matvec(&l, &q, x, y2, scratch);
        assert_true(diff_norm2(y1, y2, n) <= 1e-4 * norm2(y1, n));
        free(y1);
        free(y2);
        for (int v = 0; v < 4; v++) free(yq[v]);
        bem_cmatq_free(&q);
        assert_null(q.val);
        dr_bem_cmat_free(&c);
    }
    /* a sum over several matrices in one pass equals the products one after the other, bit for bit, on 1 to 4
       threads (each row is summed by one thread, matrix after matrix, whichever thread takes its range) */
    {
        DrBemCMat c[2];
        BemCMatQ q[2];
        double *x2 = malloc(n * sizeof *x), *yseq = calloc(n, sizeof *x), *ysum = malloc(n * sizeof *x);
        fill_uniform(&rng, x2, n);
        for (int r = 0; r < 2; r++) {
            assert_int_equal(dr_bem_compress(&l, m, ratios[r], &c[r], &err), DR_OK);
            assert_true(bem_cmat_compact(&c[r], &q[r]));
        }
        bem_cmatq_matvec_acc(&q[0], xt, 1.0, yseq, NULL);
        bem_cmatq_matvec_acc(&q[1], x2, -0.5, yseq, NULL);
        const BemCMatQ *mats[2] = {&q[0], &q[1]};
        const double *xs[2] = {xt, x2};
        const double signs[2] = {1.0, -0.5};
        for (int t = 1; t <= 4; t++) {
            dr_set_threads(t);
            memset(ysum, 0, n * sizeof *x);
            bem_cmatq_sum(mats, xs, signs, 2, ysum, NULL);
            assert_memory_equal(ysum, yseq, n * sizeof *x);
        }
        dr_set_threads(saved);
        for (int r = 0; r < 2; r++) {
            bem_cmatq_free(&q[r]);
            dr_bem_cmat_free(&c[r]);
        }
        free(x2);
        free(yseq);
        free(ysum);
    }
    /* by hand: an empty row, a row of one coefficient, a row of mixed signs and magnitudes */
    {
        int64_t rp[4] = {0, 0, 1, 4};
        int32_t cl[4] = {2, 0, 1, 2};
        double vl[4] = {-2.5, 4.0, -1e-3, 2.0};
        DrBemCMat c = {.n = 3, .nnz = 4, .row_ptr = rp, .col = cl, .val = vl};
        BemCMatQ q;
        assert_true(bem_cmat_compact(&c, &q));
        double xs[3] = {1.0, 2.0, 3.0}, ys[3] = {0, 0, 0};
        bem_cmatq_matvec_acc(&q, xs, 1.0, ys, NULL);
        assert_true(ys[0] == 0.0);
        assert_near(ys[1], -7.5, 1e-14);
        assert_near(ys[2], 4.0 - 2e-3 + 6.0, 0.5 * 4.0 / 32767 * 6.0 + 1e-14);
        bem_cmatq_free(&q);
    }
    /* no copy for a dense set, nor past 16-bit columns */
    {
        DrBemCMat c;
        BemCMatQ q;
        assert_int_equal(dr_bem_compress(&l, m, 1.0, &c, &err), DR_OK);
        assert_false(bem_cmat_compact(&c, &q));
        dr_bem_cmat_free(&c);
        DrBemCMat big = {.n = 65538, .nnz = 0};
        big.row_ptr = calloc(65539, sizeof(int64_t));
        assert_false(bem_cmat_compact(&big, &q));
        free(big.row_ptr);
    }
    dr_bem_layout_free(&l);
    free(m);
    free(order);
    free(x);
    free(xt);
    free(yd);
    free(scratch);
}

/* The column form of a compact copy (bem_cmatq_add_columns): a product with a vector whose nonzero coefficients
 * touch few columns goes by columns and agrees with the row form up to the order of the sums; it gives the same
 * bits with the scalar and vector loops and on 1 and 2 threads; a vector that touches most columns, or a call
 * without work, goes by rows and gives the row form's bits; a zero vector adds nothing. */
static void test_column_products(void **state)
{
    (void)state;
    const int nv = 300, n = 3 * nv;
    DrRng rng;
    dr_rng_seed(&rng, 34);
    double *m = test_matrix(&rng, n);
    int *order = malloc(nv * sizeof *order);
    random_order(&rng, nv, order);
    DrBemLayout l = make_layout(nv, DR_BEM_ORDER_VERTEX_XYZ, true, order);
    /* a traction on a patch of 20 vertices, in the coefficient domain */
    double *p = calloc(n, sizeof *p), *pt = malloc(n * sizeof *p), *dense = malloc(n * sizeof *p),
           *scratch = malloc((2 + BEM_COLUMN_GROUPS) * n * sizeof *p),
           *work = malloc(BEM_COLUMN_GROUPS * n * sizeof *p);
    for (int v = 0; v < 20; v++)
        for (int c = 0; c < 3; c++) p[3 * order[v] + c] = dr_rng_uniform(&rng) - 0.5;
    dr_bem_layout_to_coeff(&l, false, p, pt, scratch);
    fill_uniform(&rng, dense, n);
    int touched = 0;
    for (int i = 0; i < n; i++) touched += pt[i] != 0.0;
    assert_true(touched > 0 && touched < n / 4);
    int saved = dr_threads();
    DrError err;
    DrBemCMat c;
    assert_int_equal(dr_bem_compress(&l, m, 8.0, &c, &err), DR_OK);
    BemCMatQ q;
    assert_true(bem_cmat_compact(&c, &q));
    assert_true(bem_cmatq_add_columns(&q));
    assert_int_equal(q.col_ptr[n], q.nnz);
    double *yr = calloc(n, sizeof *p), *yc[4];
    const BemCMatQ *one[1] = {&q};
    const double *xs[1] = {pt};
    const double sg[1] = {-0.75};
    assert_int_equal(bem_cmatq_sum(one, xs, sg, 1, yr, NULL), 0); /* no work: by rows */
    for (int v = 0; v < 4; v++) { /* scalar/vector × 1/2 threads */
        yc[v] = calloc(n, sizeof *p);
        bem_cmatq_scalar_only(v % 2 == 1);
        dr_set_threads(v / 2 + 1);
        assert_int_equal(bem_cmatq_sum(one, xs, sg, 1, yc[v], work), 1);
    }
    bem_cmatq_scalar_only(false);
    dr_set_threads(saved);
    for (int v = 1; v < 4; v++) assert_memory_equal(yc[0], yc[v], n * sizeof *p);
    bool differs = false;
    for (int i = 0; i < n; i++) {
        double terms = 0;
        for (int64_t k = q.row_ptr[i]; k < q.row_ptr[i + 1]; k++)
            terms += fabs(q.scale[i] * q.val[k] * pt[q.col[k]]);
        assert_true(fabs(yc[0][i] - yr[i]) <= 1e-14 * terms);
        differs |= yc[0][i] != yr[i];
    }
    assert_true(differs); /* the sums did go another way */
    /* a dense vector goes by rows even with work */
    double *yd = calloc(n, sizeof *p), *yd2 = calloc(n, sizeof *p);
    const double *xd[1] = {dense};
    assert_int_equal(bem_cmatq_sum(one, xd, sg, 1, yd, work), 0);
    assert_int_equal(bem_cmatq_sum(one, xd, sg, 1, yd2, NULL), 0);
    assert_memory_equal(yd, yd2, n * sizeof *p);
    /* a zero vector adds nothing */
    double *zero = calloc(n, sizeof *p);
    const double *xz[1] = {zero};
    memcpy(yd2, yd, n * sizeof *p);
    assert_int_equal(bem_cmatq_sum(one, xz, sg, 1, yd2, work), 1);
    assert_memory_equal(yd, yd2, n * sizeof *p);
    /* a sum of row and column products: the same bits on 1 to 4 threads (whichever thread takes which row range or
       column group), and within round-off of the products one after the other */
    {
        BemCMatQ r;
        assert_true(bem_cmat_compact(&c, &r)); /* no column form */
        const BemCMatQ *mats[3] = {&q, &r, &q};
        const double *vx[3] = {pt, dense, pt};
        const double signs[3] = {1.0, -0.5, 2.0};
        double *ys[4], *yseq = calloc(n, sizeof *p);
        for (int t = 1; t <= 4; t++) {
            dr_set_threads(t);
            ys[t - 1] = calloc(n, sizeof *p);
            assert_int_equal(bem_cmatq_sum(mats, vx, signs, 3, ys[t - 1], work), 2);
        }
        dr_set_threads(saved);
        for (int t = 1; t < 4; t++) assert_memory_equal(ys[0], ys[t], n * sizeof *p);
        for (int j = 0; j < 3; j++) bem_cmatq_matvec_acc(mats[j], vx[j], signs[j], yseq, NULL);
        assert_true(diff_norm2(ys[0], yseq, n) <= 1e-13 * norm2(yseq, n));
        /* the natural-order product takes its work from the scratch */
        double *y1 = malloc(n * sizeof *p), *y2 = malloc(n * sizeof *p);
        bem_cmatq_matvec(&l, &q, p, y1, scratch);
        bem_cmatq_matvec(&l, &r, p, y2, scratch);
        assert_true(diff_norm2(y1, y2, n) <= 1e-13 * norm2(y2, n));
        free(y1);
        free(y2);
        for (int t = 0; t < 4; t++) free(ys[t]);
        free(yseq);
        bem_cmatq_free(&r);
    }
    bem_cmatq_free(&q);
    assert_null(q.col_ptr);
    dr_bem_cmat_free(&c);
    for (int v = 0; v < 4; v++) free(yc[v]);
    free(yr);
    free(yd);
    free(yd2);
    free(zero);
    free(p);
    free(pt);
    free(dense);
    free(scratch);
    free(work);
    free(m);
    free(order);
    dr_bem_layout_free(&l);
}

/* ---- degenerate and bad input ---------------------------------------------------------------------------- */

/* One vertex (n = 3) in every variant: ratio 1, 2 (⌈9/2⌉ = 5) and ratios beyond n² (one coefficient, the
 * largest). Products match the reconstruction to the rounding of a 3×3 product and two 2-level Haar
 * transforms (1e-14 relative is a few ulps). */
static void test_one_vertex(void **state)
{
    (void)state;
    const int order[1] = {0};
    const double m[9] = {4, -1, 0.5, 2, 3, -0.25, 1, 0.125, 5};
    const double ratios[] = {1.0, 2.0, 100.0, 1e300};
    const int64_t kept[] = {9, 5, 1, 1};
    double x[3] = {1, -2, 0.5}, y[3], yref[3], scratch[6], dec[9];
    DrError err;
    for (int o = 0; o < 3; o++)
        for (int w = 0; w < 2; w++) {
            DrBemLayout l = make_layout(1, (DrBemOrdering)o, w == 1, order);
            for (int r = 0; r < 4; r++) {
                DrBemCMat c;
                assert_int_equal(dr_bem_compress(&l, m, ratios[r], &c, &err), DR_OK);
                assert_int_equal(c.n, 3);
                assert_int_equal(c.nnz, kept[r]);
                dr_bem_cmat_decompress(&l, &c, dec);
                plain_matvec(dec, 3, x, yref);
                dr_bem_cmat_matvec(&l, &c, x, y, scratch);
                assert_true(diff_norm2(y, yref, 3) <= 1e-14 * norm2(dec, 9) * norm2(x, 3));
                if (r >= 2) {
                    /* the one kept coefficient is the largest in magnitude: without the wavelet, 5 at (2, 2),
                     * copied unchanged, so the reconstruction is exact */
                    assert_int_equal(c.row_ptr[3], 1);
                    if (w == 0) {
                        for (int i = 0; i < 9; i++) assert_near(dec[i], i == 8 ? 5.0 : 0.0, 0.0);
                    }
                }
                dr_bem_cmat_free(&c);
            }
            dr_bem_layout_free(&l);
        }
}

/* Bad sizes, orders, ratios and matrices are DR_ERR_INPUT with a message naming the problem, and leave the
 * output empty. */
static void test_bad_input(void **state)
{
    (void)state;
    DrBemLayout l;
    DrError err;
    assert_int_equal(dr_bem_layout_init(0, DR_BEM_ORDER_NONE, true, NULL, &l, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "0 vertices"));
    assert_null(l.perm);
    assert_int_equal(dr_bem_layout_init(3, DR_BEM_ORDER_VERTEX_XYZ, true, NULL, &l, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "no vertex order"));
    const int dup[3] = {0, 2, 0}, range[3] = {0, 3, 1};
    assert_int_equal(dr_bem_layout_init(3, DR_BEM_ORDER_VERTEX_XYZ, true, dup, &l, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "vertex 0 appears twice"));
    assert_null(l.perm);
    assert_int_equal(dr_bem_layout_init(3, DR_BEM_ORDER_VERTEX_XYZ, true, range, &l, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "entry 1 is 3"));

    l = make_layout(1, DR_BEM_ORDER_XYZ, true, NULL);
    double m[9] = {1, 2, 3, 4, 5, 6, 7, 8, 9};
    const double bad_ratios[] = {0.5, NAN, INFINITY, -2.0};
    DrBemCMat c;
    for (int r = 0; r < 4; r++) {
        assert_int_equal(dr_bem_compress(&l, m, bad_ratios[r], &c, &err), DR_ERR_INPUT);
        assert_non_null(strstr(err.message, "compression ratio"));
        assert_null(c.val);
        assert_null(c.row_ptr);
        assert_int_equal(c.nnz, 0);
    }
    m[5] = NAN;
    for (int r = 0; r < 2; r++) {
        assert_int_equal(dr_bem_compress(&l, m, r == 0 ? 1.0 : 4.0, &c, &err), DR_ERR_INPUT);
        assert_non_null(strstr(err.message, "1 non-finite entries, the first at row 1, column 2"));
        assert_null(c.val);
        assert_int_equal(c.nnz, 0);
    }
    dr_bem_cmat_free(&c);
    dr_bem_cmat_free(NULL);
    dr_bem_layout_free(&l);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_haar_layout_by_hand),
        cmocka_unit_test(test_haar_round_trip_orthonormal),
        cmocka_unit_test(test_layout_permutations),
        cmocka_unit_test(test_matvec_matches_decompressed),
        cmocka_unit_test(test_all_kept_and_largest_kept),
        cmocka_unit_test(test_ties_row_major),
        cmocka_unit_test(test_smooth_kernel_error_table),
        cmocka_unit_test(test_threads_bit_identical),
        cmocka_unit_test(test_compact_copy),
        cmocka_unit_test(test_column_products),
        cmocka_unit_test(test_one_vertex),
        cmocka_unit_test(test_bad_input),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
