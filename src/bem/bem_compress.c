/* Matrix compression of BEM §3.3: the vertex and xyz-blocked coordinate order, the orthonormal 2-D Haar
 * transform, exact selection of the largest coefficients into CSR, and products and reconstruction in
 * the compressed form. */
#include "bem/bem.h"
#include "bem_internal.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

/* 1/√2, the weight of both taps of the orthonormal Haar pair. */
#define HAAR_H 0.70710678118654752440

/* Columns per block of the column transform: sixteen doubles are two whole 64-byte cache lines of a row of
 * a 64-byte aligned matrix when 3N is a multiple of 8, and a block this wide also spreads each row's page
 * lookup over more values (n = 9000, one thread: 0.55 s for the column pass with 8 columns, 0.41 s with 16,
 * 0.40 s with 32; the buffer for 16 still fits the cache). */
#define COL_BLOCK 16

/* Below this many matrix entries (or kept coefficients) a loop runs on one thread: starting a team costs
 * more than the work. */
#define PAR_MIN 32768

/* Histogram width of the radix selection: 16 bits of the magnitude's bit pattern per pass. */
#define RADIX_BITS 16
#define RADIX_BINS (1 << RADIX_BITS)

static int max_threads(void)
{
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

static int thread_id(void)
{
#ifdef _OPENMP
    return omp_get_thread_num();
#else
    return 0;
#endif
}

/* ---- layout -------------------------------------------------------------------------------------- */

DrStatus dr_bem_layout_init(int nv, DrBemOrdering ordering, bool wavelet, const int *order, DrBemLayout *out,
                            DrError *err)
{
    assert(out);
    assert(ordering == DR_BEM_ORDER_VERTEX_XYZ || ordering == DR_BEM_ORDER_XYZ || ordering == DR_BEM_ORDER_NONE);
    memset(out, 0, sizeof *out);
    /* 3N must be an int (the CSR column index is int32). */
    if (nv < 1 || nv > INT_MAX / 3)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "compression layout for %d vertices: a body needs between 1 and %d vertices", nv,
                            INT_MAX / 3);
    if (ordering == DR_BEM_ORDER_VERTEX_XYZ) {
        if (!order)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "compression layout with vertex reordering but no vertex order: pass the order "
                                "from dr_bem_vertex_order, or use DR_BEM_ORDER_XYZ");
        int *seen = NULL;
        DR_TRY(dr_calloc((size_t)nv, sizeof(int), &seen, err));
        for (int p = 0; p < nv; p++) {
            int v = order[p];
            if (v < 0 || v >= nv) {
                free(seen);
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "vertex order entry %d is %d, outside [0, %d): the order must be a "
                                    "permutation of the body's vertices",
                                    p, v, nv);
            }
            if (seen[v]) {
                int first = seen[v] - 1;
                free(seen);
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "vertex %d appears twice in the vertex order (entries %d and %d): the order "
                                    "must be a permutation of the body's vertices",
                                    v, first, p);
            }
            seen[v] = p + 1;
        }
        free(seen);
    }
    int n = 3 * nv;
    DR_TRY(dr_calloc((size_t)n, sizeof(int), &out->perm, err));
    for (int c = 0; c < 3; c++)
        for (int v = 0; v < nv; v++) {
            switch (ordering) {
            case DR_BEM_ORDER_VERTEX_XYZ: out->perm[c * nv + v] = 3 * order[v] + c; break;
            case DR_BEM_ORDER_XYZ: out->perm[c * nv + v] = 3 * v + c; break;
            case DR_BEM_ORDER_NONE: out->perm[3 * v + c] = 3 * v + c; break;
            }
        }
    out->nv = nv;
    out->ordering = ordering;
    out->wavelet = wavelet;
    return DR_OK;
}

void dr_bem_layout_free(DrBemLayout *l)
{
    if (!l) return;
    free(l->perm);
    memset(l, 0, sizeof *l);
}

/* The Haar transform runs over `nseg` independent segments of length `seglen`: the three coordinate
 * blocks of length N in the xyz orders, the whole 3N otherwise. */
static void haar_segments(const DrBemLayout *l, int *nseg, int *seglen)
{
    bool blocked = l->ordering != DR_BEM_ORDER_NONE;
    *nseg = blocked ? 3 : 1;
    *seglen = blocked ? l->nv : 3 * l->nv;
}

/* ---- 1-D Haar ------------------------------------------------------------------------------------
 * A level of length m maps the pairs (x₂ᵢ, x₂ᵢ₊₁) to the average (x₂ᵢ + x₂ᵢ₊₁)/√2 at i and the detail
 * (x₂ᵢ − x₂ᵢ₊₁)/√2 at ⌈m/2⌉ + i; an odd last element is carried unchanged as the last average. Each
 * level is an orthogonal map, so the whole transform is orthonormal for any length. The next level works
 * on the ⌈m/2⌉ averages, leaving the coarsest average first and the finest details last. */

static void haar_forward_level(double *restrict x, int m, double *restrict tmp)
{
    int half = m / 2, a = m - half;
    for (int i = 0; i < half; i++) {
        double p = x[2 * i], q = x[2 * i + 1];
        tmp[i] = (p + q) * HAAR_H;
        tmp[a + i] = (p - q) * HAAR_H;
    }
    if (a > half) tmp[half] = x[m - 1];
    memcpy(x, tmp, (size_t)m * sizeof *x);
}

static void haar_inverse_level(double *restrict x, int m, double *restrict tmp)
{
    int half = m / 2, a = m - half;
    for (int i = 0; i < half; i++) {
        double s = x[i], d = x[a + i];
        tmp[2 * i] = (s + d) * HAAR_H;
        tmp[2 * i + 1] = (s - d) * HAAR_H;
    }
    if (a > half) tmp[m - 1] = x[half];
    memcpy(x, tmp, (size_t)m * sizeof *x);
}

void dr_bem_haar_forward(double *x, int n, double *scratch)
{
    assert(n >= 0);
    for (int m = n; m > 1; m -= m / 2) haar_forward_level(x, m, scratch);
}

void dr_bem_haar_inverse(double *x, int n, double *scratch)
{
    assert(n >= 0);
    int len[40], levels = 0; /* an int length has at most 31 levels */
    for (int m = n; m > 1; m -= m / 2) len[levels++] = m;
    for (int k = levels - 1; k >= 0; k--) haar_inverse_level(x, len[k], scratch);
}

/* The same transform on w columns at once: t holds len rows of w values (row stride w), s as much
 * scratch. Every value goes through exactly the arithmetic of the 1-D version. */
static void haar_forward_cols(double *restrict t, int len, int w, double *restrict s)
{
    for (int m = len; m > 1; m -= m / 2) {
        int half = m / 2, a = m - half;
        for (int i = 0; i < half; i++) {
            const double *p = t + (size_t)(2 * i) * w, *q = p + w;
            double *avg = s + (size_t)i * w, *det = s + (size_t)(a + i) * w;
            for (int c = 0; c < w; c++) {
                avg[c] = (p[c] + q[c]) * HAAR_H;
                det[c] = (p[c] - q[c]) * HAAR_H;
            }
        }
        if (a > half) memcpy(s + (size_t)half * w, t + (size_t)(m - 1) * w, (size_t)w * sizeof *t);
        memcpy(t, s, (size_t)m * w * sizeof *t);
    }
}

static void haar_inverse_cols(double *restrict t, int len, int w, double *restrict s)
{
    int lens[40], levels = 0;
    for (int m = len; m > 1; m -= m / 2) lens[levels++] = m;
    for (int k = levels - 1; k >= 0; k--) {
        int m = lens[k], half = m / 2, a = m - half;
        for (int i = 0; i < half; i++) {
            const double *avg = t + (size_t)i * w, *det = t + (size_t)(a + i) * w;
            double *p = s + (size_t)(2 * i) * w, *q = p + w;
            for (int c = 0; c < w; c++) {
                p[c] = (avg[c] + det[c]) * HAAR_H;
                q[c] = (avg[c] - det[c]) * HAAR_H;
            }
        }
        if (a > half) memcpy(s + (size_t)(m - 1) * w, t + (size_t)half * w, (size_t)w * sizeof *t);
        memcpy(t, s, (size_t)m * w * sizeof *t);
    }
}

/* ---- 2-D Haar on an n×n matrix -------------------------------------------------------------------
 * Row i of the (permuted) matrix lives at a + map[i]·n, or a + i·n when map is NULL; within a row the
 * columns are in permuted order. `buf` holds 2·seglen·COL_BLOCK doubles per thread of `nthreads`. */

typedef struct HaarGrid {
    double *a;
    int n, nseg, seglen;
    const int *map;
    double *buf;
    int nthreads;
} HaarGrid;

static double *grid_row(const HaarGrid *g, int i)
{
    return g->a + (size_t)(g->map ? g->map[i] : i) * (size_t)g->n;
}

/* Rows: the inverse 1-D transform of every row segment, in place (M W). The forward row transform is done
 * by dr_bem_compress while it forms each row. */
static void haar_rows_inverse(const HaarGrid *g)
{
    bool par = (size_t)g->n * (size_t)g->n >= PAR_MIN;
#pragma omp parallel for schedule(static) num_threads(g->nthreads) if (par)
    for (int i = 0; i < g->n; i++) {
        double *tmp = g->buf + (size_t)thread_id() * 2 * (size_t)g->seglen * COL_BLOCK;
        double *row = grid_row(g, i);
        for (int s = 0; s < g->nseg; s++) dr_bem_haar_inverse(row + (size_t)s * g->seglen, g->seglen, tmp);
    }
}

/* Columns (W M, or Wᵀ M for the inverse): a block of COL_BLOCK columns of one row segment is gathered into
 * a contiguous buffer, transformed there and written back, so every pass over the matrix reads whole cache
 * lines instead of striding down single columns. */
static void haar_cols(const HaarGrid *g, bool inverse)
{
    int nblk = (g->n + COL_BLOCK - 1) / COL_BLOCK;
    long ntask = (long)g->nseg * nblk;
    bool par = (size_t)g->n * (size_t)g->n >= PAR_MIN;
#pragma omp parallel for schedule(static) num_threads(g->nthreads) if (par)
    for (long task = 0; task < ntask; task++) {
        int seg = (int)(task / nblk), j0 = (int)(task % nblk) * COL_BLOCK;
        int w = g->n - j0 < COL_BLOCK ? g->n - j0 : COL_BLOCK;
        double *t = g->buf + (size_t)thread_id() * 2 * (size_t)g->seglen * COL_BLOCK;
        double *s = t + (size_t)g->seglen * COL_BLOCK;
        int r0 = seg * g->seglen;
        for (int i = 0; i < g->seglen; i++) memcpy(t + (size_t)i * w, grid_row(g, r0 + i) + j0, (size_t)w * sizeof *t);
        if (inverse)
            haar_inverse_cols(t, g->seglen, w, s);
        else
            haar_forward_cols(t, g->seglen, w, s);
        for (int i = 0; i < g->seglen; i++) memcpy(grid_row(g, r0 + i) + j0, t + (size_t)i * w, (size_t)w * sizeof *t);
    }
}

/* ---- selection -------------------------------------------------------------------------------------
 * For finite values the bit pattern of |v| read as an unsigned integer orders like |v|, so the k-th
 * largest magnitude is found exactly by a radix selection: passes that histogram 16 bits at a time among
 * the entries agreeing with the bits fixed so far. It needs no copy of the n² magnitudes (a quickselect
 * would need one) and the counts are integers, so the result does not depend on the thread count. Once
 * the entries that still agree are few (16 bits fix the magnitude to 1/16 of its octave, 32 bits to
 * 1e-6), their keys are gathered and the remaining passes run over them instead of the whole matrix. */

/* At most n²/CAND_FRACTION keys are gathered (n = 9000: 40 MB); a larger tie, such as many zeros at the
 * threshold, keeps the passes over the matrix. */
#define CAND_FRACTION 16

static inline uint64_t mag_key(double v)
{
    uint64_t u;
    memcpy(&u, &v, sizeof u);
    return u & 0x7fffffffffffffffULL;
}

/* Fixes the next 16 bits from a summed histogram: the bin holding the entry of rank `rank` from the top. */
static int64_t radix_pick(const uint64_t *hist, int shift, uint64_t *prefix, uint64_t *mask, int64_t *rank)
{
    int64_t acc = 0;
    int bin = RADIX_BINS - 1;
    for (; bin >= 0; bin--) {
        if (acc + (int64_t)hist[bin] >= *rank) break;
        acc += (int64_t)hist[bin];
    }
    assert(bin >= 0);
    *rank -= acc;
    *prefix |= (uint64_t)bin << shift;
    *mask |= (uint64_t)(RADIX_BINS - 1) << shift;
    return (int64_t)hist[bin];
}

/* Returns the key of the k-th largest magnitude (1 ≤ k ≤ n²); *above receives how many entries have a
 * strictly larger key. hist holds RADIX_BINS counts per thread. */
static uint64_t select_kth(const double *a, int n, int64_t k, uint64_t *hist, int nthreads, int64_t *above)
{
    uint64_t prefix = 0, mask = 0;
    int64_t rank = k; /* rank from the top among the entries that match `prefix` under `mask` */
    size_t nn = (size_t)n * (size_t)n;
    bool par = nn >= PAR_MIN;
    uint64_t *cand = NULL;
    int64_t ncand = 0;
    int shift = 64 - RADIX_BITS;
    for (; shift >= 0; shift -= RADIX_BITS) {
        memset(hist, 0, (size_t)nthreads * RADIX_BINS * sizeof *hist);
#pragma omp parallel for schedule(static) num_threads(nthreads) if (par)
        for (int i = 0; i < n; i++) {
            uint64_t *h = hist + (size_t)thread_id() * RADIX_BINS;
            const double *row = a + (size_t)i * n;
            for (int j = 0; j < n; j++) {
                uint64_t key = mag_key(row[j]);
                if ((key & mask) == prefix) h[(key >> shift) & (RADIX_BINS - 1)]++;
            }
        }
        for (int t = 1; t < nthreads; t++)
            for (int b = 0; b < RADIX_BINS; b++) hist[b] += hist[(size_t)t * RADIX_BINS + b];
        int64_t count = radix_pick(hist, shift, &prefix, &mask, &rank);
        if (shift == 0 || (size_t)count > nn / CAND_FRACTION) continue;
        cand = malloc((size_t)count * sizeof *cand);
        if (!cand) continue; /* not an error: the passes over the matrix need no memory */
        /* Rows append their matching keys at a shared cursor; the order of the keys varies with the
         * threads, the selection over them does not. */
        int64_t cursor = 0;
#pragma omp parallel for schedule(static) num_threads(nthreads) if (par)
        for (int i = 0; i < n; i++) {
            const double *row = a + (size_t)i * n;
            int64_t c = 0;
            for (int j = 0; j < n; j++) c += (mag_key(row[j]) & mask) == prefix;
            if (c == 0) continue;
            int64_t at;
#pragma omp atomic capture
            {
                at = cursor;
                cursor += c;
            }
            for (int j = 0; j < n; j++) {
                uint64_t key = mag_key(row[j]);
                if ((key & mask) == prefix) cand[at++] = key;
            }
        }
        assert(cursor == count);
        ncand = count;
        shift -= RADIX_BITS;
        break;
    }
    for (; cand && shift >= 0; shift -= RADIX_BITS) {
        memset(hist, 0, RADIX_BINS * sizeof *hist);
        for (int64_t e = 0; e < ncand; e++)
            if ((cand[e] & mask) == prefix) hist[(cand[e] >> shift) & (RADIX_BINS - 1)]++;
        radix_pick(hist, shift, &prefix, &mask, &rank);
    }
    free(cand);
    *above = k - rank;
    return prefix;
}

/* ---- compression ------------------------------------------------------------------------------------ */

/* Matrices of n² doubles are written once right after allocation, and touching fresh 4 KiB pages one at a
 * time cost as much as the whole permutation pass (n = 9000: 1.2–2 s for 648 MB on the test machine, half
 * that with 2 MiB pages). Large buffers are therefore 2 MiB aligned and advised as huge pages where the
 * kernel offers them; small ones are cache-line aligned for the column blocks. */
#define HUGE_ALIGN ((size_t)2 << 20)

static DrStatus alloc_aligned(size_t count, size_t size, void *out_ptr, DrError *err)
{
    size_t bytes;
    if (dr_mul_overflows(count, size, &bytes) || bytes > SIZE_MAX - HUGE_ALIGN)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "allocation of %zu × %zu bytes overflows", count, size);
    size_t align = bytes >= 2 * HUGE_ALIGN ? HUGE_ALIGN : 64;
    bytes = (bytes + align - 1) & ~(align - 1);
    void *p = aligned_alloc(align, bytes ? bytes : align);
    if (!p)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                            "out of memory allocating %zu bytes for matrix compression, which needs about "
                            "twice the dense matrix: free memory or compress smaller bodies",
                            bytes);
#ifdef MADV_HUGEPAGE
    if (align == HUGE_ALIGN) (void)madvise(p, bytes, MADV_HUGEPAGE); /* advice only: failure changes nothing */
#endif
    *(void **)out_ptr = p;
    return DR_OK;
}

static DrStatus nonfinite_error(int n, int64_t bad, size_t first, DrError *err)
{
    return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                        "the %d×%d matrix to compress has %lld non-finite entries, the first at row %zu, column "
                        "%zu: the assembly or inversion that produced it failed; check the mesh "
                        "(dr_bem_mesh_check) and the time step",
                        n, n, (long long)bad, first / (size_t)n, first % (size_t)n);
}

/* Fails on a NaN or infinity (the dense copy of ratio 1; the compressed path checks while permuting). */
static DrStatus check_finite(const double *a, int n, DrError *err)
{
    int64_t bad = 0;
    size_t first = SIZE_MAX;
    bool par = (size_t)n * (size_t)n >= PAR_MIN;
#pragma omp parallel for schedule(static) if (par) reduction(+ : bad) reduction(min : first)
    for (int i = 0; i < n; i++) {
        const double *row = a + (size_t)i * n;
        for (int j = 0; j < n; j++)
            if (!isfinite(row[j])) {
                bad++;
                size_t at = (size_t)i * n + (size_t)j;
                if (at < first) first = at;
            }
    }
    return bad == 0 ? DR_OK : nonfinite_error(n, bad, first, err);
}

DrStatus dr_bem_compress(const DrBemLayout *l, const double *dense, double ratio, DrBemCMat *out, DrError *err)
{
    assert(l && l->perm && dense && out);
    memset(out, 0, sizeof *out);
    int n = 3 * l->nv;
    size_t nn;
    if (dr_mul_overflows((size_t)n, (size_t)n, &nn) || dr_mul_overflows(nn, sizeof(double), NULL))
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "a %d×%d matrix does not fit in memory", n, n);
    if (!(ratio >= 1.0) || !isfinite(ratio))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "compression ratio %g: it must be a finite number >= 1 (1 keeps the dense matrix)",
                            ratio);

    /* 1. ratio 1: the dense matrix itself, no transform (its products are exact) */
    if (ratio == 1.0) {
        DR_TRY(check_finite(dense, n, err));
        DR_TRY(alloc_aligned(nn, sizeof(double), &out->val, err));
        memcpy(out->val, dense, nn * sizeof(double));
        out->n = n;
        out->dense = true;
        out->nnz = (int64_t)nn;
        return DR_OK;
    }

    /* k = ⌈n²/ratio⌉, at least one; n² < 2⁶², and the quotient is exact enough that ⌈·⌉ is the intended
     * count for the ratios in use (n² is exact in double for n < 2²⁶). */
    double kd = ceil((double)nn / ratio);
    int64_t k = kd < 1.0 ? 1 : (kd >= (double)nn ? (int64_t)nn : (int64_t)kd);

    int nthreads = max_threads();
    int nseg, seglen;
    haar_segments(l, &nseg, &seglen);
    double *b = NULL, *buf = NULL;
    uint64_t *hist = NULL;
    int64_t *eq = NULL;
    DrStatus st = alloc_aligned(nn, sizeof(double), &b, err);
    if (st == DR_OK) st = alloc_aligned((size_t)nthreads * 2 * (size_t)seglen * COL_BLOCK, sizeof(double), &buf, err);
    if (st == DR_OK) st = dr_calloc((size_t)nthreads * RADIX_BINS, sizeof(uint64_t), &hist, err);
    if (st == DR_OK) st = dr_calloc((size_t)n, sizeof(int64_t), &eq, err);
    if (st == DR_OK) st = dr_calloc((size_t)n + 1, sizeof(int64_t), &out->row_ptr, err);
    if (st != DR_OK) goto fail;

    /* 2. B = P M Pᵀ with M Wᵀ applied to each row while it is in cache, then W on column blocks. A NaN or
     * infinity would order above every finite coefficient: it is an input error, reported at its first
     * natural position. */
    const int *perm = l->perm;
    bool par = nn >= PAR_MIN;
    int64_t bad = 0;
    size_t first_bad = SIZE_MAX;
#pragma omp parallel for schedule(static) num_threads(nthreads) if (par) reduction(+ : bad) reduction(min : first_bad)
    for (int i = 0; i < n; i++) {
        const double *src = dense + (size_t)perm[i] * n;
        double *dst = b + (size_t)i * n;
        for (int j = 0; j < n; j++) dst[j] = src[perm[j]];
        for (int j = 0; j < n; j++)
            if (!isfinite(dst[j])) {
                bad++;
                size_t at = (size_t)perm[i] * n + (size_t)perm[j];
                if (at < first_bad) first_bad = at;
            }
        if (l->wavelet) {
            double *tmp = buf + (size_t)thread_id() * 2 * (size_t)seglen * COL_BLOCK;
            for (int sg = 0; sg < nseg; sg++) dr_bem_haar_forward(dst + (size_t)sg * seglen, seglen, tmp);
        }
    }
    if (bad > 0) {
        st = nonfinite_error(n, bad, first_bad, err);
        goto fail;
    }
    if (l->wavelet) {
        HaarGrid g = {.a = b, .n = n, .nseg = nseg, .seglen = seglen, .map = NULL, .buf = buf, .nthreads = nthreads};
        haar_cols(&g, false);
    }

    /* 3. the k-th largest magnitude; ties at it are kept in row-major order until k are kept */
    int64_t above;
    uint64_t thr = select_kth(b, n, k, hist, nthreads, &above);
    int64_t *gt = out->row_ptr + 1;
#pragma omp parallel for schedule(static) num_threads(nthreads) if (par)
    for (int i = 0; i < n; i++) {
        const double *row = b + (size_t)i * n;
        int64_t cg = 0, ce = 0;
        for (int j = 0; j < n; j++) {
            uint64_t key = mag_key(row[j]);
            cg += key > thr;
            ce += key == thr;
        }
        gt[i] = cg;
        eq[i] = ce;
    }
    int64_t ties = k - above;
    out->row_ptr[0] = 0;
    for (int i = 0; i < n; i++) {
        int64_t take = eq[i] < ties ? eq[i] : ties;
        ties -= take;
        eq[i] = take;
        out->row_ptr[i + 1] = out->row_ptr[i] + gt[i] + take;
    }
    assert(ties == 0 && out->row_ptr[n] == k);

    /* 4. CSR of the kept coefficients, columns ascending within a row */
    st = alloc_aligned((size_t)k, sizeof(int32_t), &out->col, err);
    if (st == DR_OK) st = alloc_aligned((size_t)k, sizeof(double), &out->val, err);
    if (st != DR_OK) goto fail;
#pragma omp parallel for schedule(static) num_threads(nthreads) if (par)
    for (int i = 0; i < n; i++) {
        const double *row = b + (size_t)i * n;
        int64_t pos = out->row_ptr[i], take = eq[i];
        for (int j = 0; j < n; j++) {
            uint64_t key = mag_key(row[j]);
            bool keep = key > thr;
            if (!keep && key == thr && take > 0) {
                take--;
                keep = true;
            }
            if (keep) {
                out->col[pos] = j;
                out->val[pos] = row[j];
                pos++;
            }
        }
    }
    out->n = n;
    out->dense = false;
    out->nnz = k;
    free(b);
    free(buf);
    free(hist);
    free(eq);
    return DR_OK;

fail:
    free(b);
    free(buf);
    free(hist);
    free(eq);
    dr_bem_cmat_free(out);
    return st;
}

/* ---- products and reconstruction ----------------------------------------------------------------- */

/* Four partial sums in a fixed order: a single running sum is bound by the add latency, not by memory. */
static void dense_matvec(const double *a, int n, const double *x, double *y)
{
    bool par = (size_t)n * (size_t)n >= PAR_MIN;
#pragma omp parallel for schedule(static) if (par)
    for (int i = 0; i < n; i++) {
        const double *restrict row = a + (size_t)i * n;
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
        int j = 0;
        for (; j + 4 <= n; j += 4) {
            s0 += row[j] * x[j];
            s1 += row[j + 1] * x[j + 1];
            s2 += row[j + 2] * x[j + 2];
            s3 += row[j + 3] * x[j + 3];
        }
        for (; j < n; j++) s0 += row[j] * x[j];
        y[i] = (s0 + s1) + (s2 + s3);
    }
}

/* First row r with row_ptr[r] ≥ target. */
static int row_at(const int64_t *row_ptr, int n, int64_t target)
{
    int lo = 0, hi = n;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (row_ptr[mid] < target)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* Rows [r0, r1) of part p of `parts`, each part holding about the same number of coefficients. */
static void row_range(const int64_t *row_ptr, int n, int64_t nnz, int p, int parts, int *r0, int *r1)
{
    *r0 = p == 0 ? 0 : row_at(row_ptr, n, nnz * p / parts);
    *r1 = p == parts - 1 ? n : row_at(row_ptr, n, nnz * (p + 1) / parts);
}

/* The coarse-level rows of M̃ hold far more coefficients than the fine ones, so the rows are split into one
 * range per thread of equal coefficient count. Each row is summed by one thread in a fixed order, so the
 * split does not change the result. */
static void csr_matvec(const DrBemCMat *m, const double *restrict x, double *restrict y)
{
    int n = m->n, parts = m->nnz >= PAR_MIN ? max_threads() : 1;
    const int64_t *row_ptr = m->row_ptr;
    const int32_t *col = m->col;
    const double *val = m->val;
#pragma omp parallel for schedule(static) num_threads(parts) if (parts > 1)
    for (int p = 0; p < parts; p++) {
        int r0, r1;
        row_range(row_ptr, n, m->nnz, p, parts, &r0, &r1);
        for (int i = r0; i < r1; i++) {
            int64_t k = row_ptr[i], end = row_ptr[i + 1];
            double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
            for (; k + 4 <= end; k += 4) {
                s0 += val[k] * x[col[k]];
                s1 += val[k + 1] * x[col[k + 1]];
                s2 += val[k + 2] * x[col[k + 2]];
                s3 += val[k + 3] * x[col[k + 3]];
            }
            for (; k < end; k++) s0 += val[k] * x[col[k]];
            y[i] = (s0 + s1) + (s2 + s3);
        }
    }
}

/* ---- the runtime's compact copies ------------------------------------------------------------------------------
 * A body's step reads every kept coefficient of 2·n_max + 2 matrices once. Stored as 12 bytes (double, int32 column)
 * that is memory traffic at the machine's bandwidth; the compact copy holds 4 bytes: a 16-bit fixed-point value with
 * one scale per row (row maximum / 32767) and a 16-bit column. The rounding, at most 1.5e-5 of the row's largest
 * coefficient, gives products within about 2e-4 of the double ones, far below the compression error it rides on
 * (1e-2 to 1e-1 at 8–32×). With 4 bytes the product is bound by arithmetic instead, so on x86 with AVX2 a row is
 * summed eight coefficients at a time in two vector registers whose lanes are exactly the scalar loop's eight
 * accumulators: both give the same bits. */
bool bem_cmat_compact(const DrBemCMat *m, BemCMatQ *out)
{
    memset(out, 0, sizeof *out);
    if (m->dense || m->n > 65535) return false;
    out->n = m->n;
    out->nnz = m->nnz;
    size_t nz = (size_t)(m->nnz > 0 ? m->nnz : 1);
    DrError err; /* no room for the copy only means the double products serve */
    out->row_ptr = malloc(sizeof(int64_t) * ((size_t)m->n + 1));
    out->scale = malloc(sizeof(double) * (size_t)(m->n > 0 ? m->n : 1));
    /* huge pages where offered: every step streams these arrays once */
    if (alloc_aligned(nz, sizeof(uint16_t), &out->col, &err) != DR_OK) out->col = NULL;
    if (alloc_aligned(nz, sizeof(int16_t), &out->val, &err) != DR_OK) out->val = NULL;
    if (!out->row_ptr || !out->col || !out->val || !out->scale) {
        bem_cmatq_free(out);
        return false;
    }
    memcpy(out->row_ptr, m->row_ptr, sizeof(int64_t) * ((size_t)m->n + 1));
    for (int i = 0; i < m->n; i++) {
        double big = 0;
        for (int64_t k = m->row_ptr[i]; k < m->row_ptr[i + 1]; k++) big = fmax(big, fabs(m->val[k]));
        double scale = big > 0 ? big / 32767.0 : 1.0;
        out->scale[i] = scale;
        for (int64_t k = m->row_ptr[i]; k < m->row_ptr[i + 1]; k++) {
            long q = lrint(m->val[k] / scale);
            out->val[k] = (int16_t)(q > 32767 ? 32767 : q < -32767 ? -32767 : q);
            out->col[k] = (uint16_t)m->col[k];
        }
    }
    return true;
}

void bem_cmatq_free(BemCMatQ *m)
{
    free(m->row_ptr);
    free(m->col);
    free(m->val);
    free(m->scale);
    free(m->col_ptr);
    free(m->centry);
    memset(m, 0, sizeof *m);
}

/* The column form: a counting pass, then the rows in order, so each column lists its rows ascending. */
bool bem_cmatq_add_columns(BemCMatQ *m)
{
    int n = m->n;
    size_t nz = (size_t)(m->nnz > 0 ? m->nnz : 1);
    DrError err;
    int64_t *pos = malloc(sizeof(int64_t) * ((size_t)n + 1));
    m->col_ptr = calloc((size_t)n + 1, sizeof(int64_t));
    if (alloc_aligned(nz, sizeof(uint32_t), &m->centry, &err) != DR_OK) m->centry = NULL;
    if (!pos || !m->col_ptr || !m->centry) {
        free(pos);
        free(m->col_ptr);
        free(m->centry);
        m->col_ptr = NULL, m->centry = NULL;
        return false;
    }
    for (int64_t k = 0; k < m->nnz; k++) m->col_ptr[m->col[k] + 1]++;
    for (int c = 0; c < n; c++) m->col_ptr[c + 1] += m->col_ptr[c];
    memcpy(pos, m->col_ptr, sizeof(int64_t) * (size_t)n);
    for (int r = 0; r < n; r++)
        for (int64_t k = m->row_ptr[r]; k < m->row_ptr[r + 1]; k++) {
            int64_t q = pos[m->col[k]]++;
            m->centry[q] = (uint32_t)r | (uint32_t)(uint16_t)m->val[k] << 16;
        }
    free(pos);
    return true;
}

static bool cmatq_scalar_only;

void bem_cmatq_scalar_only(bool on) { cmatq_scalar_only = on; }

/* A row's sum in a fixed order: accumulator j (0..7) takes the coefficients j, j + 8, …; the last (fewer than 8)
   go to accumulators 0, 1, … in turn; then ((s0 + s4) + (s1 + s5)) + ((s2 + s6) + (s3 + s7)). Eight independent
   sums keep the adds from waiting on each other. */
static double cmatq_row_sum(double s[8])
{
    return ((s[0] + s[4]) + (s[1] + s[5])) + ((s[2] + s[6]) + (s[3] + s[7]));
}

static void cmatq_rows(const BemCMatQ *m, int r0, int r1, const double *restrict x, double sign, double *restrict y)
{
    const int64_t *row_ptr = m->row_ptr;
    const uint16_t *col = m->col;
    const int16_t *val = m->val;
    for (int i = r0; i < r1; i++) {
        int64_t k = row_ptr[i], end = row_ptr[i + 1];
        double s[8] = {0, 0, 0, 0, 0, 0, 0, 0};
        for (; k + 8 <= end; k += 8)
            for (int j = 0; j < 8; j++) s[j] += (double)val[k + j] * x[col[k + j]];
        for (int j = 0; k < end; k++, j++) s[j] += (double)val[k] * x[col[k]];
        y[i] += sign * m->scale[i] * cmatq_row_sum(s);
    }
}

#if defined(__x86_64__) || defined(__i386__)
#define CMATQ_AVX2 1
/* The same sums with accumulators 0–3 and 4–7 as the lanes of two vector registers. Each coefficient loads its x̃ and
   moves it into a lane, so the columns are not loaded one by one as well: the four of each 64-bit word are taken
   apart by shifts in registers (11 loads per eight coefficients instead of 17; 3 % off the 2,906-vertex box's
   dense-traction step on one thread, the same bits). */
__attribute__((target("avx2"))) static void cmatq_rows_avx2(const BemCMatQ *m, int r0, int r1,
                                                             const double *restrict x, double sign,
                                                             double *restrict y)
{
    const int64_t *row_ptr = m->row_ptr;
    const uint16_t *col = m->col;
    const int16_t *val = m->val;
    for (int i = r0; i < r1; i++) {
        int64_t k = row_ptr[i], end = row_ptr[i + 1];
        __m256d a0 = _mm256_setzero_pd(), a1 = _mm256_setzero_pd();
        for (; k + 8 <= end; k += 8) {
            uint64_t c, d; /* columns k..k+3 and k+4..k+7 (little-endian x86: the first in the low bits) */
            memcpy(&c, col + k, sizeof c);
            memcpy(&d, col + k + 4, sizeof d);
            __m128d l0 = _mm_loadh_pd(_mm_load_sd(x + (c & 0xffff)), x + (c >> 16 & 0xffff));
            __m128d h0 = _mm_loadh_pd(_mm_load_sd(x + (c >> 32 & 0xffff)), x + (c >> 48));
            __m128d l1 = _mm_loadh_pd(_mm_load_sd(x + (d & 0xffff)), x + (d >> 16 & 0xffff));
            __m128d h1 = _mm_loadh_pd(_mm_load_sd(x + (d >> 32 & 0xffff)), x + (d >> 48));
            __m256d x0 = _mm256_insertf128_pd(_mm256_castpd128_pd256(l0), h0, 1);
            __m256d x1 = _mm256_insertf128_pd(_mm256_castpd128_pd256(l1), h1, 1);
            __m128i q = _mm_loadu_si128((const __m128i *)(val + k));
            __m256d v0 = _mm256_cvtepi32_pd(_mm_cvtepi16_epi32(q));
            __m256d v1 = _mm256_cvtepi32_pd(_mm_cvtepi16_epi32(_mm_srli_si128(q, 8)));
            a0 = _mm256_add_pd(a0, _mm256_mul_pd(v0, x0));
            a1 = _mm256_add_pd(a1, _mm256_mul_pd(v1, x1));
        }
        double s[8];
        _mm256_storeu_pd(s, a0);
        _mm256_storeu_pd(s + 4, a1);
        for (int j = 0; k < end; k++, j++) s[j] += (double)val[k] * x[col[k]];
        y[i] += sign * m->scale[i] * cmatq_row_sum(s);
    }
}
#endif

/* ---- products by column ----
 * acc[r] += x_c·q over the entries of column c: one product and one sum per coefficient, so the vector loop (eight
 * products at a time) gives the scalar loop's bits. The row's scale is applied once per row at the end, so both
 * forms of a product differ only in the order of the sums. */
static void cmatq_column(const BemCMatQ *m, int c, double xc, double *restrict acc)
{
    const uint32_t *e = m->centry;
    for (int64_t k = m->col_ptr[c], end = m->col_ptr[c + 1]; k < end; k++)
        acc[e[k] & 0xffff] += xc * (double)(int16_t)(e[k] >> 16);
}

#ifdef CMATQ_AVX2
__attribute__((target("avx2"))) static void cmatq_column_avx2(const BemCMatQ *m, int c, double xc,
                                                              double *restrict acc)
{
    const uint32_t *e = m->centry;
    int64_t k = m->col_ptr[c], end = m->col_ptr[c + 1];
    __m256d xv = _mm256_set1_pd(xc);
    for (; k + 8 <= end; k += 8) { /* the products leave by register: a reload of a vector store would stall */
        __m256i q = _mm256_srai_epi32(_mm256_loadu_si256((const __m256i *)(e + k)), 16); /* the values */
        __m256d p0 = _mm256_mul_pd(xv, _mm256_cvtepi32_pd(_mm256_castsi256_si128(q)));
        __m256d p1 = _mm256_mul_pd(xv, _mm256_cvtepi32_pd(_mm256_extracti128_si256(q, 1)));
        __m128d l0 = _mm256_castpd256_pd128(p0), h0 = _mm256_extractf128_pd(p0, 1);
        __m128d l1 = _mm256_castpd256_pd128(p1), h1 = _mm256_extractf128_pd(p1, 1);
        const uint16_t *r = (const uint16_t *)(e + k); /* the rows: the low halves (little-endian x86) */
        acc[r[0]] += _mm_cvtsd_f64(l0);
        acc[r[2]] += _mm_cvtsd_f64(_mm_unpackhi_pd(l0, l0));
        acc[r[4]] += _mm_cvtsd_f64(h0);
        acc[r[6]] += _mm_cvtsd_f64(_mm_unpackhi_pd(h0, h0));
        acc[r[8]] += _mm_cvtsd_f64(l1);
        acc[r[10]] += _mm_cvtsd_f64(_mm_unpackhi_pd(l1, l1));
        acc[r[12]] += _mm_cvtsd_f64(h1);
        acc[r[14]] += _mm_cvtsd_f64(_mm_unpackhi_pd(h1, h1));
    }
    for (; k < end; k++) acc[e[k] & 0xffff] += xc * (double)(int16_t)(e[k] >> 16);
}
#endif

static int next_nonzero(const double *x, int c, int n)
{
    while (c < n && x[c] == 0.0) c++;
    return c;
}

/* Column c on its way into the cache: a column product jumps from column to column, which the hardware cannot
   foresee. */
static void prefetch_column(const BemCMatQ *m, int c)
{
    for (int64_t k = m->col_ptr[c], end = m->col_ptr[c + 1]; k < end; k += 16) __builtin_prefetch(m->centry + k);
}

/* How many columns ahead of the product their entries are fetched: a column is a few hundred cycles of work, a
   fetch from memory about as long. */
#define CMATQ_PREFETCH_COLUMNS 4

/* acc = M̃ restricted to the columns c0..c1−1 where x̃ is not zero, times x̃ (before the rows' scales). */
static void cmatq_columns(const BemCMatQ *m, int c0, int c1, const double *x, double *restrict acc, bool avx2)
{
    (void)avx2;
    memset(acc, 0, sizeof(double) * (size_t)m->n);
    int ahead = next_nonzero(x, c0, c1); /* the last column fetched */
    for (int i = 0; i < CMATQ_PREFETCH_COLUMNS && ahead < c1; i++) {
        prefetch_column(m, ahead);
        if (i + 1 < CMATQ_PREFETCH_COLUMNS) ahead = next_nonzero(x, ahead + 1, c1);
    }
    for (int c = next_nonzero(x, c0, c1); c < c1; c = next_nonzero(x, c + 1, c1)) {
        if (ahead < c1) ahead = next_nonzero(x, ahead + 1, c1);
        if (ahead < c1) prefetch_column(m, ahead);
#ifdef CMATQ_AVX2
        if (avx2)
            cmatq_column_avx2(m, c, x[c], acc);
        else
#endif
            cmatq_column(m, c, x[c], acc);
    }
}

/* A product goes by columns when the coefficients in the columns its vector touches are less than this share of the
 * matrix. Per coefficient read, the column loop costs about twice the row loop (its sums go to memory, and it jumps
 * from column to column). Five products at 2,906 vertices, 32×, 2 threads: 0.0029 s by column against 0.0044 s by
 * row with 22 % of the coefficients touched, 0.0032 against 0.0044 with 30 %, 0.0053 against 0.0046 with 56 %. */
#define CMATQ_COLUMN_SHARE 0.45

/* The coefficients in the columns x touches when the product goes by columns, else −1. */
static int64_t by_columns(const BemCMatQ *m, const double *x)
{
    if (!m->col_ptr) return -1;
    int64_t touched = 0, limit = (int64_t)(CMATQ_COLUMN_SHARE * (double)m->nnz);
    for (int c = 0; c < m->n; c++)
        if (x[c] != 0.0 && (touched += m->col_ptr[c + 1] - m->col_ptr[c]) >= limit) return -1;
    return touched;
}

/* Cost of the first r rows of the row-form products in a sum (those not in `skip`), in coefficients: the kept
   coefficients plus a row's fixed work (its sum's setup and reduction, about eight coefficients' worth) per matrix. */
#define CMATQ_ROW_COST 8

static int64_t cmatq_cost(const BemCMatQ *const *mats, int count, const bool *skip, int r)
{
    int64_t c = 0;
    for (int j = 0; j < count; j++)
        if (!skip[j]) c += mats[j]->row_ptr[r] + (int64_t)CMATQ_ROW_COST * r;
    return c;
}

/* Products in a sum with more matrices than this all go by rows. */
#define CMATQ_SUM_MAX 64

/* Row ranges of a sum's row-form products, of equal cost, that the threads take one at a time. The machine may be
 * shared: a thread that starts late (its core busy with other work) or is interrupted leaves its share to the others
 * instead of holding back the step by a whole share. The 2,906-vertex box's dense-traction step on 2 threads of a
 * busy 2-core machine, 6 rounds interleaved: a median 32 ms against 50 ms with one fixed range per thread (idle:
 * 5.5 ms either way). A range is 1/CMATQ_CHUNKS of the sum (0.1 ms at 2,906 vertices), so taking one costs nothing by
 * comparison (8 ranges measured the same). */
#define CMATQ_CHUNKS 32

/* y += Σ_j sign_j·M̃_j x̃_j in the coefficient domain, for matrices of one size. The row-form products come first:
 * CMATQ_CHUNKS row ranges of equal cost over all of them, each serving every product, so the threads go through
 * them without waiting on each other; each row is summed by one thread, matrix after matrix in the order given. Then
 * the column-form products one after another: the columns x̃_j touches are cut into BEM_COLUMN_GROUPS groups of
 * about equal work, which depend on x̃_j alone; each group is summed into its own part of the work by one thread, and
 * the groups are added in order. Every y_r thus gets the same terms in the same order whatever the thread count and
 * whichever thread takes which range. */
int bem_cmatq_sum(const BemCMatQ *const *mats, const double *const *x, const double *sign, int count, double *y,
                  double *work)
{
    if (count == 0) return 0;
    int n = mats[0]->n;
    bool skip[CMATQ_SUM_MAX] = {false};
    int64_t all = 0, touched[CMATQ_SUM_MAX];
    int columns = 0;
    for (int j = 0; j < count; j++) {
        all += mats[j]->nnz;
        if (work && j < CMATQ_SUM_MAX && (touched[j] = by_columns(mats[j], x[j])) >= 0) skip[j] = true, columns++;
    }
    bool any_columns = columns > 0;
    int64_t total = cmatq_cost(mats, count, skip, n);
    int parts = all >= PAR_MIN ? max_threads() : 1;
    int group[CMATQ_SUM_MAX][BEM_COLUMN_GROUPS + 1]; /* group g of product j: columns group[j][g] .. group[j][g+1]−1 */
    for (int j = 0; j < count && any_columns; j++) {
        if (!skip[j]) continue;
        const BemCMatQ *m = mats[j];
        int64_t done = 0;
        int g = 1;
        group[j][0] = 0;
        for (int c = next_nonzero(x[j], 0, n); c < n && g < BEM_COLUMN_GROUPS; c = next_nonzero(x[j], c + 1, n)) {
            done += m->col_ptr[c + 1] - m->col_ptr[c];
            while (g < BEM_COLUMN_GROUPS && done * BEM_COLUMN_GROUPS >= touched[j] * g) group[j][g++] = c + 1;
        }
        while (g <= BEM_COLUMN_GROUPS) group[j][g++] = n;
    }
#ifdef CMATQ_AVX2
    bool avx2 = !cmatq_scalar_only && __builtin_cpu_supports("avx2");
#else
    bool avx2 = false;
#endif
    int chunks = parts > 1 ? CMATQ_CHUNKS : 1;
#pragma omp parallel num_threads(parts) if (parts > 1)
    {
#pragma omp for schedule(dynamic, 1) nowait
        for (int p = 0; p < chunks; p++) {
            int bound[2];
            for (int e = 0; e < 2; e++) { /* the first row whose cost reaches total·(p + e)/chunks */
                int64_t target = total * (p + e) / chunks;
                int lo = 0, hi = n;
                while (lo < hi) {
                    int mid = lo + (hi - lo) / 2;
                    if (cmatq_cost(mats, count, skip, mid) < target)
                        lo = mid + 1;
                    else
                        hi = mid;
                }
                bound[e] = e == 1 && p == chunks - 1 ? n : lo;
            }
            for (int j = 0; j < count; j++) {
                if (skip[j]) continue;
#ifdef CMATQ_AVX2
                if (avx2) {
                    cmatq_rows_avx2(mats[j], bound[0], bound[1], x[j], sign[j], y);
                    continue;
                }
#endif
                cmatq_rows(mats[j], bound[0], bound[1], x[j], sign[j], y);
            }
        }
        for (int j = 0; j < count && any_columns; j++) {
            if (!skip[j]) continue;
#pragma omp for schedule(dynamic, 1)
            for (int g = 0; g < BEM_COLUMN_GROUPS; g++)
                cmatq_columns(mats[j], group[j][g], group[j][g + 1], x[j], work + (size_t)g * (size_t)n, avx2);
            const double *scale = mats[j]->scale;
            double sg = sign[j];
#pragma omp for schedule(dynamic, 512)
            for (int r = 0; r < n; r++) {
                double a = 0.0;
                for (int g = 0; g < BEM_COLUMN_GROUPS; g++) a += work[(size_t)g * (size_t)n + r];
                y[r] += sg * scale[r] * a;
            }
        }
    }
    return columns;
}

void bem_cmatq_matvec_acc(const BemCMatQ *m, const double *x, double sign, double *y, double *work)
{
    (void)bem_cmatq_sum(&m, &x, &sign, 1, y, work);
}

void bem_cmatq_matvec(const DrBemLayout *l, const BemCMatQ *m, const double *x, double *y, double *scratch)
{
    int n = m->n;
    double *xt = scratch, *yt = scratch + n;
    dr_bem_layout_to_coeff(l, false, x, xt, yt);
    memset(yt, 0, sizeof(double) * (size_t)n);
    bem_cmatq_matvec_acc(m, xt, 1.0, yt, scratch + 2 * (size_t)n);
    dr_bem_layout_from_coeff(l, false, yt, y, scratch + 2 * (size_t)n);
}

void dr_bem_cmat_matvec(const DrBemLayout *l, const DrBemCMat *m, const double *x, double *y, double *scratch)
{
    assert(m && x && y);
    int n = m->n;
    if (m->dense) {
        dense_matvec(m->val, n, x, y);
        return;
    }
    assert(l && l->perm && n == 3 * l->nv && scratch);
    int nseg, seglen;
    haar_segments(l, &nseg, &seglen);
    double *u = scratch, *v = scratch + n;
    const int *perm = l->perm;
    /* y = Pᵀ Wᵀ M̃ W P x */
    for (int i = 0; i < n; i++) u[i] = x[perm[i]];
    if (l->wavelet)
        for (int s = 0; s < nseg; s++) dr_bem_haar_forward(u + (size_t)s * seglen, seglen, v);
    csr_matvec(m, u, v);
    if (l->wavelet)
        for (int s = 0; s < nseg; s++) dr_bem_haar_inverse(v + (size_t)s * seglen, seglen, u);
    for (int i = 0; i < n; i++) y[perm[i]] = v[i];
}

/* The coefficient domain of the products: x̃ = W P x (identity for dense sets). A runtime keeps its history vectors
   there, so a step is one sparse product per history matrix and one inverse transform (BEM §3.3). */
void dr_bem_layout_to_coeff(const DrBemLayout *l, bool dense, const double *x, double *xt, double *scratch)
{
    int n = 3 * l->nv;
    if (dense) {
        memcpy(xt, x, sizeof(double) * (size_t)n);
        return;
    }
    int nseg, seglen;
    haar_segments(l, &nseg, &seglen);
    for (int i = 0; i < n; i++) xt[i] = x[l->perm[i]];
    if (l->wavelet)
        for (int s = 0; s < nseg; s++) dr_bem_haar_forward(xt + (size_t)s * seglen, seglen, scratch);
}

void dr_bem_layout_from_coeff(const DrBemLayout *l, bool dense, const double *yt, double *y, double *scratch)
{
    int n = 3 * l->nv;
    if (dense) {
        memcpy(y, yt, sizeof(double) * (size_t)n);
        return;
    }
    int nseg, seglen;
    haar_segments(l, &nseg, &seglen);
    double *v = scratch, *tmp = scratch + n;
    memcpy(v, yt, sizeof(double) * (size_t)n);
    if (l->wavelet)
        for (int s = 0; s < nseg; s++) dr_bem_haar_inverse(v + (size_t)s * seglen, seglen, tmp);
    for (int i = 0; i < n; i++) y[l->perm[i]] = v[i];
}

void dr_bem_cmat_matvec_coeff(const DrBemCMat *m, const double *xt, double *yt)
{
    if (m->dense) dense_matvec(m->val, m->n, xt, yt);
    else csr_matvec(m, xt, yt);
}

void dr_bem_cmat_decompress(const DrBemLayout *l, const DrBemCMat *m, double *dense)
{
    assert(m && dense);
    int n = m->n;
    size_t nn = (size_t)n * (size_t)n;
    if (m->dense) {
        memcpy(dense, m->val, nn * sizeof *dense);
        return;
    }
    assert(l && l->perm && n == 3 * l->nv);
    int nseg, seglen;
    haar_segments(l, &nseg, &seglen);
    int nthreads = max_threads();
    /* The header's contract has no error path here: the few rows of scratch per thread are the only
     * allocation, and running out of them leaves nothing sensible to return. */
    size_t per = 2 * (size_t)seglen * COL_BLOCK;
    if (per < (size_t)n) per = (size_t)n;
    double *buf = NULL;
    DrError err;
    if (alloc_aligned((size_t)nthreads * per, sizeof(double), &buf, &err) != DR_OK) {
        dr_log_error("%s", err.message);
        abort();
    }

    /* Row i of Wᵀ M̃ W lives at dense row perm[i] while its columns are still in permuted order; the
     * columns are put in natural order last, one row at a time. */
    const int *perm = l->perm;
    bool par = nn >= PAR_MIN;
#pragma omp parallel for schedule(static) num_threads(nthreads) if (par)
    for (int i = 0; i < n; i++) {
        double *row = dense + (size_t)perm[i] * n;
        memset(row, 0, (size_t)n * sizeof *row);
        for (int64_t k = m->row_ptr[i]; k < m->row_ptr[i + 1]; k++) row[m->col[k]] = m->val[k];
    }
    if (l->wavelet) {
        HaarGrid g = {.a = dense, .n = n, .nseg = nseg, .seglen = seglen, .map = perm, .buf = buf, .nthreads = nthreads};
        haar_rows_inverse(&g);
        haar_cols(&g, true);
    }
#pragma omp parallel for schedule(static) num_threads(nthreads) if (par)
    for (int r = 0; r < n; r++) {
        double *tmp = buf + (size_t)thread_id() * per;
        double *row = dense + (size_t)r * n;
        for (int j = 0; j < n; j++) tmp[perm[j]] = row[j];
        memcpy(row, tmp, (size_t)n * sizeof *row);
    }
    free(buf);
}

void dr_bem_cmat_free(DrBemCMat *m)
{
    if (!m) return;
    free(m->row_ptr);
    free(m->col);
    free(m->val);
    memset(m, 0, sizeof *m);
}

double dr_bem_coefficients_per_row(int nv, double ratio) { return 3.0 * nv / (ratio > 1.0 ? ratio : 1.0); }

size_t dr_bem_cmat_bytes(const DrBemCMat *m)
{
    assert(m);
    if (m->dense) return (size_t)m->n * (size_t)m->n * sizeof(double);
    return (size_t)m->nnz * (sizeof(double) + sizeof(int32_t)) + ((size_t)m->n + 1) * sizeof(int64_t);
}
