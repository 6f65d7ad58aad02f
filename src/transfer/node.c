/* Particle–grid transfers on the collocated node grid (MPM); see transfer.h for the contract. */
#include "transfer/transfer.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

/* Particle or node count below which a loop runs serially: a parallel region's fork and barrier would
   cost more than the work (as in transfer.c). */
#define NODE_PAR_MIN 16384
/* Bins per slab along the slab axis (z in 3-D, y in 2-D). A bin's block spans K nodes, so the nodes of a
   slab of T bins reach T + K − 1 node layers; the next slab of the same colour starts 2T layers further,
   so same-colour slabs never share a node when T ≥ K − 1 (3 for the cubic kernel). 4 leaves a margin. */
#define NODE_SLAB 4

#define DR_INLINE static inline __attribute__((always_inline))
/* The stencil loops have compile-time trip counts (2–4 nodes, 2–3 components); unrolled, their
   accumulators live in registers instead of memory. */
#define UNROLL _Pragma("GCC unroll 16")

/* The scatters and gathers work on lane vectors of 4 doubles: a node's velocity components (x, y, z and a
   zero pad lane), or P2G's (mass, momentum x, y, z). Every lane does the scalar arithmetic of its component
   in the order of a loop over the components, so results are those of that loop bit for bit, whatever width
   the compiler gives the vector operations: two SSE2 halves in the baseline x86-64 build, one AVX register
   in the AVX2 build of each kernel, chosen at run time (cpu_avx2). The AVX2 build holds a vector in one of
   16 registers, where SSE2 needs two and spills; it adds no fused multiply-add (no "fma" target, and
   -ffp-contract=off), so both builds do the same IEEE operations and give the same bits. */
typedef double V4 __attribute__((vector_size(4 * sizeof(double))));
static bool cpu_avx2(void) { return __builtin_cpu_supports("avx2"); }

/* ==== kernels ==================================================================================== */

static int kernel_nodes(DrKernel k) { return k == DR_KERNEL_LINEAR ? 2 : (k == DR_KERNEL_QUADRATIC ? 3 : 4); }

/* One axis of a K-node B-spline stencil at s (grid units): returns the base node, fills the K weights and
   their derivatives per grid unit. The quadratic case is dr_kernel_quadratic (grid.h), bit for bit. */
DR_INLINE int axis_stencil(int K, double s, double *w, double *dw)
{
    if (K == 2) {
        double fb = floor(s), f = s - fb;
        w[0] = 1.0 - f;
        w[1] = f;
        dw[0] = -1.0;
        dw[1] = 1.0;
        return (int)fb;
    }
    if (K == 3) {
        DrStencil3 st = dr_kernel_quadratic(s);
        for (int q = 0; q < 3; q++) {
            w[q] = st.w[q];
            dw[q] = st.dw[q];
        }
        return st.base;
    }
    /* cubic B-spline N(t) = ½|t|³ − t² + ⅔ (|t| < 1), (2 − |t|)³/6 (1 ≤ |t| < 2), at t = s − node for the
       nodes ⌊s⌋ − 1 … ⌊s⌋ + 2, i.e. t = 1 + f, f, f − 1, f − 2 with f = s − ⌊s⌋ */
    double fb = floor(s), f = s - fb, g = 1.0 - f;
    w[0] = g * g * g / 6.0;
    w[1] = 0.5 * f * f * f - f * f + 2.0 / 3.0;
    w[2] = 0.5 * g * g * g - g * g + 2.0 / 3.0;
    w[3] = f * f * f / 6.0;
    dw[0] = -0.5 * g * g;
    dw[1] = 1.5 * f * f - 2.0 * f;
    dw[2] = 2.0 * g - 1.5 * g * g;
    dw[3] = 0.5 * f * f;
    return (int)fb - 1;
}

/* Base node of the stencil only (binning); the same floor expressions as axis_stencil. */
static inline int axis_base(int K, double s)
{
    if (K == 2) return (int)floor(s);
    if (K == 3) return (int)floor(s - 0.5);
    return (int)floor(s) - 1;
}

DrStencil dr_kernel_eval(DrKernel k, double s)
{
    DrStencil st;
    memset(&st, 0, sizeof st);
    st.n = kernel_nodes(k);
    st.base = axis_stencil(st.n, s, st.w, st.dw);
    return st;
}

double dr_kernel_dinv(DrKernel k, double dx)
{
    if (k == DR_KERNEL_QUADRATIC) return 4.0 / (dx * dx);
    if (k == DR_KERNEL_CUBIC) return 3.0 / (dx * dx);
    return 0.0;
}

int dr_kernel_reach(DrKernel k) { return k == DR_KERNEL_LINEAR ? 1 : 2; }

/* D of the kernel (quadratic Δx²/4, cubic Δx²/3), 0 for linear: the affine angular momentum weight. */
static double kernel_d(DrKernel k, double dx)
{
    if (k == DR_KERNEL_QUADRATIC) return 0.25 * dx * dx;
    if (k == DR_KERNEL_CUBIC) return dx * dx / 3.0;
    return 0.0;
}

/* ==== grid ========================================================================================= */

DrStatus dr_node_grid_create(int dim, const int n[3], double dx, DrVec3 origin, DrKernel kernel, DrNodeGrid **out,
                             DrError *err)
{
    *out = NULL;
    if (dim != 2 && dim != 3)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "node grid dimension %d is not supported; use 2 or 3", dim);
    if (kernel != DR_KERNEL_LINEAR && kernel != DR_KERNEL_QUADRATIC && kernel != DR_KERNEL_CUBIC)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "unknown interpolation kernel %d", (int)kernel);
    if (!(dx > 0.0) || !isfinite(dx))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "node grid spacing dx = %g m must be positive and finite", dx);
    if (!dr_v3_isfinite(origin))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "node grid origin must be finite");
    int K = kernel_nodes(kernel);
    for (int d = 0; d < dim; d++)
        if (n[d] < K)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "node grid has %d node(s) along axis %c; the kernel's stencil needs at least %d", n[d],
                                "xyz"[d], K);
    if (dim == 2 && n[2] != 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "a 2-D node grid has one node layer along z (n[2] = 1), not %d", n[2]);
    size_t nn, bytes;
    if (dr_mul_overflows((size_t)n[0], (size_t)n[1], &nn) || dr_mul_overflows(nn, (size_t)n[2], &nn) ||
        dr_mul_overflows(nn, 4 * sizeof(double), &bytes) || nn > (size_t)(LONG_MAX / 16))
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "node grid %d×%d×%d is too large", n[0], n[1], n[2]);
    DrNodeGrid *g = NULL;
    DR_TRY(dr_calloc(1, sizeof *g, &g, err));
    g->dim = dim;
    for (int d = 0; d < 3; d++) g->n[d] = n[d];
    g->dx = dx;
    g->origin = origin;
    g->kernel = kernel;
    g->nnodes = (long)nn;
    DrStatus s = dr_calloc(nn, sizeof(double), &g->mass, err);
    if (s >= 0) s = dr_calloc(nn, 3 * sizeof(double), &g->vel, err);
    if (s < 0) {
        dr_node_grid_destroy(&g);
        return s;
    }
    *out = g;
    return DR_OK;
}

void dr_node_grid_destroy(DrNodeGrid **g)
{
    if (!g || !*g) return;
    free((*g)->mass);
    free((*g)->vel);
    free(*g);
    *g = NULL;
}

DrVec3 dr_node_position(const DrNodeGrid *g, long node)
{
    long i = node % g->n[0], j = (node / g->n[0]) % g->n[1], k = node / ((long)g->n[0] * g->n[1]);
    return dr_v3(g->origin.x + g->dx * (double)i, g->origin.y + g->dx * (double)j, g->origin.z + g->dx * (double)k);
}

/* ==== bins ========================================================================================= */

/* A bin is a stencil base: the particles of bin (bx, by, bz) all reach exactly the nodes bx … bx+K−1
   (and likewise along y, z). For the linear and cubic kernels that is the cell containing the particle;
   for the quadratic one the cell of the lattice shifted by half a cell (the node nearest the particle is
   the middle of its stencil). Bins are x fastest, so a slab along the last axis is a contiguous range. */
struct DrNodeBins {
    int dim, K, n[3], nb[3];
    double dx;
    DrVec3 origin;
    long nbins, np, cap;
    long *start;  /* nbins + 1 offsets into order */
    long *order;  /* np particle indices, by bin then by particle index */
    long *bin_of; /* np bin indices (−1: stencil outside the grid) */
};

DrStatus dr_node_bins_create(const DrNodeGrid *g, long n_capacity, DrNodeBins **out, DrError *err)
{
    *out = NULL;
    DrNodeBins *b = NULL;
    DR_TRY(dr_calloc(1, sizeof *b, &b, err));
    b->dim = g->dim;
    b->K = kernel_nodes(g->kernel);
    b->dx = g->dx;
    b->origin = g->origin;
    b->nbins = 1;
    for (int d = 0; d < 3; d++) {
        b->n[d] = g->n[d];
        b->nb[d] = d < g->dim ? g->n[d] - b->K + 1 : 1;
        if (b->nb[d] < 0) b->nb[d] = 0;
        b->nbins *= b->nb[d];
    }
    if (n_capacity < 1) n_capacity = 1;
    DrStatus s = dr_calloc((size_t)b->nbins + 1, sizeof(long), &b->start, err);
    if (s >= 0) s = dr_calloc((size_t)n_capacity, sizeof(long), &b->order, err);
    if (s >= 0) s = dr_calloc((size_t)n_capacity, sizeof(long), &b->bin_of, err);
    if (s < 0) {
        dr_node_bins_destroy(&b);
        return s;
    }
    b->cap = n_capacity;
    *out = b;
    return DR_OK;
}

void dr_node_bins_destroy(DrNodeBins **b)
{
    if (!b || !*b) return;
    free((*b)->start);
    free((*b)->order);
    free((*b)->bin_of);
    free(*b);
    *b = NULL;
}

static void bins_match(const DrNodeBins *b, const DrNodeGrid *g)
{
    assert(b->dim == g->dim && b->K == kernel_nodes(g->kernel) && b->dx == g->dx);
    assert(b->n[0] == g->n[0] && b->n[1] == g->n[1] && b->n[2] == g->n[2]);
    (void)b;
    (void)g;
}

/* Bin of a position, or −1 when its stencil leaves the grid (non-finite positions included). */
static inline long particle_bin(const DrNodeBins *b, const double *xp)
{
    double inv = 1.0 / b->dx;
    long idx = 0, stride = 1;
    for (int d = 0; d < b->dim; d++) {
        double s = (xp[d] - dr_v3_get(b->origin, d)) * inv;
        if (!(s > -4.0 && s < (double)b->n[d] + 4.0)) return -1;
        int base = axis_base(b->K, s);
        if (base < 0 || base >= b->nb[d]) return -1;
        idx += (long)base * stride;
        stride *= b->nb[d];
    }
    return idx;
}

typedef struct BinCtx { const DrNodeBins *b; const double *x; long *bin_of; } BinCtx;

static void bin_range(long begin, long end, void *vctx)
{
    BinCtx *c = vctx;
    for (long p = begin; p < end; p++) c->bin_of[p] = particle_bin(c->b, c->x + 3 * p);
}

DrStatus dr_node_bins_build(const DrNodeGrid *g, long n, const double *x, DrNodeBins *b, DrError *err)
{
    bins_match(b, g);
    if (n > b->cap) {
        long cap = n + n / 4 + 16;
        DR_TRY(dr_realloc((size_t)cap, sizeof(long), &b->order, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof(long), &b->bin_of, err));
        b->cap = cap;
    }
    b->np = 0;
    memset(b->start, 0, ((size_t)b->nbins + 1) * sizeof(long));
    BinCtx ctx = {b, x, b->bin_of};
    dr_parallel_for(n, NODE_PAR_MIN, bin_range, &ctx);
    for (long p = 0; p < n; p++) {
        if (b->bin_of[p] >= 0) continue;
        /* the holdable interval along an axis: base ≥ 0 and base + K − 1 ≤ n − 1 with the base rules of
           axis_stencil, i.e. s in [0, n−1) linear, [½, n − 1½) quadratic, [1, n − 2) cubic */
        int K = b->K, axis = 0;
        double lo = K == 2 ? 0.0 : (K == 3 ? 0.5 : 1.0), hi_off = K == 2 ? 1.0 : (K == 3 ? 1.5 : 2.0);
        for (int d = 0; d < g->dim; d++) {
            double s = (x[3 * p + d] - dr_v3_get(g->origin, d)) / g->dx;
            if (!(s >= lo && s < g->n[d] - hi_off)) {
                axis = d;
                break;
            }
        }
        double a = dr_v3_get(g->origin, axis) + lo * g->dx, z = dr_v3_get(g->origin, axis) + (g->n[axis] - hi_off) * g->dx;
        const char *kname = K == 2 ? "linear" : (K == 3 ? "quadratic" : "cubic");
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "particle %ld at (%g, %g, %g) m is outside the region the node grid can hold: with the %s "
                            "kernel its %c coordinate must be finite and in [%g, %g) m so that its stencil stays on the "
                            "grid; pad the grid by dr_kernel_reach = %d nodes around the particles' box, or keep the "
                            "particles inside it",
                            p, x[3 * p], x[3 * p + 1], g->dim == 3 ? x[3 * p + 2] : g->origin.z, kname, "xyz"[axis], a,
                            z, dr_kernel_reach(g->kernel));
    }
    /* counting sort, stable (as dr_bins_build): particles of a bin stay in index order */
    for (long p = 0; p < n; p++) b->start[b->bin_of[p] + 1]++;
    for (long c = 0; c < b->nbins; c++) b->start[c + 1] += b->start[c];
    for (long p = n - 1; p >= 0; p--) b->order[--b->start[b->bin_of[p] + 1]] = p;
    for (long c = 0; c < b->nbins; c++) b->start[c] = b->start[c + 1];
    b->start[b->nbins] = n;
    b->np = n;
    return DR_OK;
}

const long *dr_node_bins_order(const DrNodeBins *b, long *n)
{
    if (n) *n = b->np;
    return b->order;
}

/* ==== scatters (P2G and the two weighted scatters) ================================================== */

typedef enum ScatterOp { OP_P2G, OP_GRADIENT, OP_VECTOR } ScatterOp;

typedef struct ScatterCtx {
    const DrNodeBins *b;
    const DrNodeGrid *g;
    const double *x;
    const double *v, *C, *mass; /* P2G */
    const double *in;           /* OP_GRADIENT: M (9n); OP_VECTOR: f (3n) */
    double *acc0, *acc3;        /* P2G: mass (nnodes), momentum (3·nnodes); others: acc3 = out */
    int parity;
    void (*bin_fn)(const struct ScatterCtx *, long);
} ScatterCtx;

/* One bin: its particles are summed into a local K^dim block of nodes (one lane vector of 4 accumulators
   each), which is then added to the grid once: every grid value is read and written once per bin instead
   of once per particle. The block's order of summation depends on the particle data only, and every lane
   does the scalar arithmetic of its accumulator in the order of a loop over them (see V4). */
DR_INLINE void scatter_bin(const ScatterCtx *c, long bin, int K, int D3, ScatterOp op)
{
    const DrNodeBins *b = c->b;
    const DrNodeGrid *g = c->g;
    const int KZ = D3 ? K : 1, NA = D3 ? 3 : 2;
    const double dx = g->dx, inv = 1.0 / dx;
    const double ox = g->origin.x, oy = g->origin.y, oz = g->origin.z;
    const int bx = (int)(bin % b->nb[0]), by = (int)((bin / b->nb[0]) % b->nb[1]),
              bz = (int)(bin / ((long)b->nb[0] * b->nb[1]));
    const V4 zero = {0, 0, 0, 0};
    V4 blk[64];
    UNROLL
    for (int q = 0; q < K * K * KZ; q++) blk[q] = zero;
    for (long q = b->start[bin]; q < b->start[bin + 1]; q++) {
        long p = b->order[q];
        const double *xp = c->x + 3 * p;
        double wx[4], dwx[4], wy[4], dwy[4], wz[4] = {1, 0, 0, 0}, dwz[4] = {0, 0, 0, 0};
        double sx = (xp[0] - ox) * inv, sy = (xp[1] - oy) * inv, sz = 0.0;
        int ax = axis_stencil(K, sx, wx, dwx), ay = axis_stencil(K, sy, wy, dwy), az = 0;
        if (D3) {
            sz = (xp[2] - oz) * inv;
            az = axis_stencil(K, sz, wz, dwz);
        }
        /* the bins must come from this x (transfer.h) */
        assert(ax == bx && ay == by && az == bz);
        (void)ax, (void)ay, (void)az;
        if (op == OP_P2G) {
            /* eqs. (24)–(26) with C_p = B_p D_p⁻¹ (or the lagged C of §5.9): node momentum
               w m (v_p + C_p (x_i − x_p)); the affine part is separable along the axes. Lanes (mass,
               momentum x, y, z): lane 0 carries 1 through the sums, so it adds w m. */
            const double m = c->mass[p];
            const double *vp = c->v + 3 * p;
            V4 c0 = zero, c1 = zero, c2 = zero; /* columns of C_p in lanes 1–3 */
            if (c->C) {
                const double *Cp = c->C + 9 * p;
                c0 = (V4){0, Cp[0], Cp[3], Cp[6]};
                c1 = (V4){0, Cp[1], Cp[4], Cp[7]};
                c2 = (V4){0, Cp[2], Cp[5], Cp[8]};
            }
            const V4 v1 = {1, vp[0], vp[1], D3 ? vp[2] : 0.0};
            V4 cx[4];
            double ry[4], rz[4];
            UNROLL
            for (int i = 0; i < K; i++) {
                double rx = dx * ((double)i - (sx - bx));
                ry[i] = dx * ((double)i - (sy - by));
                rz[i] = D3 ? dx * ((double)i - (sz - bz)) : 0.0;
                cx[i] = c0 * rx;
            }
            UNROLL
            for (int kk = 0; kk < KZ; kk++) {
                double wzm = wz[kk] * m;
                V4 vz = D3 ? v1 + c2 * rz[kk] : v1;
                UNROLL
                for (int jj = 0; jj < K; jj++) {
                    double wyz = wy[jj] * wzm;
                    V4 vyz = vz + c1 * ry[jj];
                    V4 *row = blk + K * (jj + K * kk);
                    UNROLL
                    for (int ii = 0; ii < K; ii++) row[ii] += (wx[ii] * wyz) * (vyz + cx[ii]);
                }
            }
        } else if (op == OP_GRADIENT) {
            /* out_i += M_p ∇w_ip, ∇w = (w'_x w_y w_z, w_x w'_y w_z, w_x w_y w'_z)/Δx: per row of nodes along
               x, M ∇w = α_r w'_x + β_r w_x (lanes: the rows r of M) */
            const double *M = c->in + 9 * p;
            const V4 m0 = {M[0], M[3], D3 ? M[6] : 0.0, 0}, m1 = {M[1], M[4], D3 ? M[7] : 0.0, 0},
                     m2 = {M[2], M[5], D3 ? M[8] : 0.0, 0};
            UNROLL
            for (int kk = 0; kk < KZ; kk++)
                UNROLL
                for (int jj = 0; jj < K; jj++) {
                    double wyz = wy[jj] * wz[kk] * inv;
                    double dy = dwy[jj] * wz[kk] * inv, dz = wy[jj] * dwz[kk] * inv;
                    V4 al = m0 * wyz, be = D3 ? m1 * dy + m2 * dz : m1 * dy;
                    V4 *row = blk + K * (jj + K * kk);
                    UNROLL
                    for (int ii = 0; ii < K; ii++) row[ii] += al * dwx[ii] + be * wx[ii];
                }
        } else {
            const double *f = c->in + 3 * p;
            const V4 fv = {f[0], f[1], D3 ? f[2] : 0.0, 0};
            UNROLL
            for (int kk = 0; kk < KZ; kk++)
                UNROLL
                for (int jj = 0; jj < K; jj++) {
                    double wyz = wy[jj] * wz[kk];
                    V4 *row = blk + K * (jj + K * kk);
                    UNROLL
                    for (int ii = 0; ii < K; ii++) row[ii] += (wx[ii] * wyz) * fv;
                }
        }
    }
    /* flush the block to the grid */
    const long n0 = g->n[0], n1 = g->n[1];
    UNROLL
    for (int kk = 0; kk < KZ; kk++)
        UNROLL
        for (int jj = 0; jj < K; jj++) {
            long node = bx + n0 * ((long)(by + jj) + n1 * (long)(bz + kk));
            const V4 *row = blk + K * (jj + K * kk);
            if (op == OP_P2G) {
                double *m = c->acc0 + node, *mv = c->acc3 + 3 * node;
                UNROLL
                for (int ii = 0; ii < K; ii++) {
                    m[ii] += row[ii][0];
                    UNROLL
                    for (int a = 0; a < NA; a++) mv[3 * ii + a] += row[ii][1 + a];
                }
            } else {
                double *o = c->acc3 + 3 * node;
                UNROLL
                for (int ii = 0; ii < K; ii++)
                    UNROLL
                    for (int a = 0; a < NA; a++) o[3 * ii + a] += row[ii][a];
            }
        }
}

/* Each scatter is built for SSE2 and for AVX2 (same bits; see V4). */
#define SCATTER_FN(name, K, D3, OP) \
    static void name(const ScatterCtx *c, long bin) { scatter_bin(c, bin, K, D3, OP); } \
    __attribute__((target("avx2"))) static void name##_avx2(const ScatterCtx *c, long bin) \
    { \
        scatter_bin(c, bin, K, D3, OP); \
    }
SCATTER_FN(p2g_l2, 2, 0, OP_P2G)
SCATTER_FN(p2g_l3, 2, 1, OP_P2G)
SCATTER_FN(p2g_q2, 3, 0, OP_P2G)
SCATTER_FN(p2g_q3, 3, 1, OP_P2G)
SCATTER_FN(p2g_c2, 4, 0, OP_P2G)
SCATTER_FN(p2g_c3, 4, 1, OP_P2G)
SCATTER_FN(grad_l2, 2, 0, OP_GRADIENT)
SCATTER_FN(grad_l3, 2, 1, OP_GRADIENT)
SCATTER_FN(grad_q2, 3, 0, OP_GRADIENT)
SCATTER_FN(grad_q3, 3, 1, OP_GRADIENT)
SCATTER_FN(grad_c2, 4, 0, OP_GRADIENT)
SCATTER_FN(grad_c3, 4, 1, OP_GRADIENT)
SCATTER_FN(vec_l2, 2, 0, OP_VECTOR)
SCATTER_FN(vec_l3, 2, 1, OP_VECTOR)
SCATTER_FN(vec_q2, 3, 0, OP_VECTOR)
SCATTER_FN(vec_q3, 3, 1, OP_VECTOR)
SCATTER_FN(vec_c2, 4, 0, OP_VECTOR)
SCATTER_FN(vec_c3, 4, 1, OP_VECTOR)

static void (*const scatter_table[2][3][3][2])(const ScatterCtx *, long) = {
    {
        {{p2g_l2, p2g_l3}, {p2g_q2, p2g_q3}, {p2g_c2, p2g_c3}},
        {{grad_l2, grad_l3}, {grad_q2, grad_q3}, {grad_c2, grad_c3}},
        {{vec_l2, vec_l3}, {vec_q2, vec_q3}, {vec_c2, vec_c3}},
    },
    {
        {{p2g_l2_avx2, p2g_l3_avx2}, {p2g_q2_avx2, p2g_q3_avx2}, {p2g_c2_avx2, p2g_c3_avx2}},
        {{grad_l2_avx2, grad_l3_avx2}, {grad_q2_avx2, grad_q3_avx2}, {grad_c2_avx2, grad_c3_avx2}},
        {{vec_l2_avx2, vec_l3_avx2}, {vec_q2_avx2, vec_q3_avx2}, {vec_c2_avx2, vec_c3_avx2}},
    },
};

static void scatter_slabs(long begin, long end, void *vctx)
{
    const ScatterCtx *c = vctx;
    const DrNodeBins *b = c->b;
    long slab_bins = (long)NODE_SLAB * b->nb[0] * (b->dim == 3 ? b->nb[1] : 1);
    for (long si = begin; si < end; si++) {
        long s = 2 * si + c->parity, b0 = s * slab_bins, b1 = b0 + slab_bins;
        if (b1 > b->nbins) b1 = b->nbins;
        for (long bin = b0; bin < b1; bin++)
            if (b->start[bin + 1] > b->start[bin]) c->bin_fn(c, bin);
    }
}

typedef struct NodeCtx { double *a, *b; const double *mass; } NodeCtx;

static void zero_range(long begin, long end, void *vctx)
{
    NodeCtx *c = vctx;
    if (c->a) memset(c->a + begin, 0, (size_t)(end - begin) * sizeof(double));
    memset(c->b + 3 * begin, 0, 3 * (size_t)(end - begin) * sizeof(double));
}

/* v_i = (m v)_i / m_i; nodes without mass get 0 */
static void normalize_range(long begin, long end, void *vctx)
{
    NodeCtx *c = vctx;
    for (long i = begin; i < end; i++) {
        double m = c->mass[i];
        for (int a = 0; a < 3; a++) c->b[3 * i + a] = m > 0.0 ? c->b[3 * i + a] / m : 0.0;
    }
}

/* Zeroes the outputs, then scatters even slabs in parallel and odd ones after them: each node sums its
   contributions in slab order and, within a slab, in bin order, whatever the thread count. */
static void scatter(ScatterCtx *c, ScatterOp op)
{
    const DrNodeBins *b = c->b;
    const DrNodeGrid *g = c->g;
    bins_match(b, g);
    long ngrain = g->nnodes >= 4 * NODE_PAR_MIN ? NODE_PAR_MIN : g->nnodes;
    NodeCtx z = {c->acc0, c->acc3, c->acc0};
    dr_parallel_for(g->nnodes, ngrain, zero_range, &z);
    c->bin_fn = scatter_table[cpu_avx2()][op][b->K - 2][b->dim == 3];
    long nslab_axis = b->nb[b->dim - 1];
    long nslabs = (nslab_axis + NODE_SLAB - 1) / NODE_SLAB;
    for (int parity = 0; parity < 2; parity++) {
        c->parity = parity;
        long count = (nslabs - parity + 1) / 2;
        dr_parallel_for(count, b->np >= NODE_PAR_MIN ? 1 : (count > 0 ? count : 1), scatter_slabs, c);
    }
    if (op == OP_P2G) dr_parallel_for(g->nnodes, ngrain, normalize_range, &z);
}

void dr_node_p2g(const DrNodeBins *b, const double *x, const double *v, const double *C, const double *mass,
                 DrNodeGrid *g)
{
    ScatterCtx c = {b, g, x, v, C, mass, NULL, g->mass, g->vel, 0, NULL};
    scatter(&c, OP_P2G);
}

void dr_node_scatter_gradient(const DrNodeBins *b, const double *x, const double *M, DrNodeGrid *g, double *out)
{
    ScatterCtx c = {b, g, x, NULL, NULL, NULL, M, NULL, out, 0, NULL};
    scatter(&c, OP_GRADIENT);
}

void dr_node_scatter_vector(const DrNodeBins *b, const double *x, const double *f, DrNodeGrid *g, double *out)
{
    ScatterCtx c = {b, g, x, NULL, NULL, NULL, f, NULL, out, 0, NULL};
    scatter(&c, OP_VECTOR);
}

/* ==== gathers (G2P and the two weighted gathers) ===================================================== */

/* What a gather sums for one particle, over its stencil, for a node field A (ṽ^{n+1} in G2P) and
   optionally a second field O (v^n): */
enum {
    G_B = 1,  /* B = Σ w A δᵀ (δ = node − s, grid units) */
    G_GA = 2, /* Σ A ŵ'ᵀ (gradient per grid unit) */
    G_O = 4,  /* Σ w O */
    G_GO = 8, /* Σ O ŵ'ᵀ */
    G_T = 16, /* T = Σ w A Oᵀ */
};
/* Sums over the stencil, as columns: B[c] holds B[3a + c] in lane a, likewise gA, gO, and T[e] holds
   T[3a + e] (T = Σ w A Oᵀ). */
typedef struct Sums { V4 vA, vO, B[3], gA[3], gO[3], T[3]; } Sums;

typedef struct GatherCtx {
    const DrNodeGrid *g;
    const double *A, *O;
    int flags;
    long n;
    /* G2P */
    DrTransferScheme scheme;
    double lambda, dt, blend;
    double *x, *v, *C, *grad_u;
    const double *xin; /* the gathers' positions (read only) */
    double *out;
    int mode; /* 0 G2P, 1 gather_gradient, 2 gather_vector */
} GatherCtx;

/* The K^dim node values of one stencil, copied into lane form (z lane 0 in 2-D, pad lane 0). Consecutive
   particles of one bin (particles stored in bin order) reach the same nodes and reuse the copy. */
typedef struct Block {
    long base; /* node index of the stencil's low corner, −1 = empty */
    V4 A[64], O[64];
} Block;

DR_INLINE void block_load(const GatherCtx *c, long base, int K, int D3, Block *blk)
{
    const DrNodeGrid *g = c->g;
    const int KZ = D3 ? K : 1;
    const long n0 = g->n[0], n01 = (long)g->n[0] * g->n[1];
    const bool two = c->O && (c->flags & (G_O | G_GO | G_T));
    UNROLL
    for (int kk = 0; kk < KZ; kk++)
        UNROLL
        for (int jj = 0; jj < K; jj++) {
            long node = base + n0 * jj + n01 * kk;
            const double *a = c->A + 3 * node;
            V4 *ra = blk->A + K * (jj + K * kk);
            UNROLL
            for (int ii = 0; ii < K; ii++) ra[ii] = (V4){a[3 * ii], a[3 * ii + 1], D3 ? a[3 * ii + 2] : 0.0, 0.0};
            if (two) {
                const double *o = c->O + 3 * node;
                V4 *ro = blk->O + K * (jj + K * kk);
                UNROLL
                for (int ii = 0; ii < K; ii++) ro[ii] = (V4){o[3 * ii], o[3 * ii + 1], D3 ? o[3 * ii + 2] : 0.0, 0.0};
            }
        }
    blk->base = base;
}

/* The sums of one particle. Order of every lane's arithmetic (kept from the scalar form, so results do not
   change): per row of K nodes along x, r = Σ_i w_x,i A_i summed from i = 0, then S += (w_y w_z) r row by row,
   z outer, y inner. */
DR_INLINE void gather_sums(const GatherCtx *c, const double *xp, int K, int D3, Block *blk, Sums *S)
{
    const DrNodeGrid *g = c->g;
    const int KZ = D3 ? K : 1, fl = c->flags;
    const double inv = 1.0 / g->dx;
    const V4 zero = {0, 0, 0, 0};
    /* only what the flags ask for is summed; everything is zeroed (vector stores the compiler drops where
       the sums overwrite them) */
    S->vA = S->vO = zero;
    UNROLL
    for (int q = 0; q < 3; q++) S->B[q] = S->gA[q] = S->gO[q] = S->T[q] = zero;
    double wx[4], dwx[4], wy[4], dwy[4], wz[4] = {1, 0, 0, 0}, dwz[4] = {0, 0, 0, 0};
    double sx = (xp[0] - g->origin.x) * inv, sy = (xp[1] - g->origin.y) * inv, sz = 0.0;
    int bx = axis_stencil(K, sx, wx, dwx), by = axis_stencil(K, sy, wy, dwy), bz = 0;
    if (D3) {
        sz = (xp[2] - g->origin.z) * inv;
        bz = axis_stencil(K, sz, wz, dwz);
    }
    /* positions must be those the bins accepted (transfer.h): stencil inside the grid */
    assert(bx >= 0 && by >= 0 && bz >= 0 && bx + K <= g->n[0] && by + K <= g->n[1] && bz + KZ <= g->n[2]);
    long base = bx + (long)g->n[0] * ((long)by + (long)g->n[1] * (long)bz);
    if (base != blk->base) block_load(c, base, K, D3, blk);
    double wdx[4], wdy[4], wdz[4] = {0, 0, 0, 0};
    UNROLL
    for (int i = 0; i < K; i++) {
        wdx[i] = wx[i] * ((double)(bx + i) - sx);
        wdy[i] = wy[i] * ((double)(by + i) - sy);
        if (D3) wdz[i] = wz[i] * ((double)(bz + i) - sz);
    }
    UNROLL
    for (int kk = 0; kk < KZ; kk++)
        UNROLL
        for (int jj = 0; jj < K; jj++) {
            const V4 *A = blk->A + K * (jj + K * kk);
            /* sums along the row of K nodes in x, then weighted by the row's y, z factors */
            V4 r0 = wx[0] * A[0], r1 = zero, rd = zero;
            UNROLL
            for (int ii = 1; ii < K; ii++) r0 += wx[ii] * A[ii];
            if (fl & G_B) {
                r1 = wdx[0] * A[0];
                UNROLL
                for (int ii = 1; ii < K; ii++) r1 += wdx[ii] * A[ii];
            }
            if (fl & G_GA) {
                rd = dwx[0] * A[0];
                UNROLL
                for (int ii = 1; ii < K; ii++) rd += dwx[ii] * A[ii];
            }
            double wyz = wy[jj] * wz[kk];
            S->vA += wyz * r0;
            if (fl & G_B) {
                S->B[0] += wyz * r1;
                S->B[1] += wdy[jj] * wz[kk] * r0;
                if (D3) S->B[2] += wy[jj] * wdz[kk] * r0;
            }
            if (fl & G_GA) {
                S->gA[0] += wyz * rd;
                S->gA[1] += dwy[jj] * wz[kk] * r0;
                if (D3) S->gA[2] += wy[jj] * dwz[kk] * r0;
            }
            if (fl & (G_O | G_GO | G_T)) {
                const V4 *O = blk->O + K * (jj + K * kk);
                V4 o0 = wx[0] * O[0];
                UNROLL
                for (int ii = 1; ii < K; ii++) o0 += wx[ii] * O[ii];
                S->vO += wyz * o0;
                if (fl & G_GO) {
                    V4 od = dwx[0] * O[0];
                    UNROLL
                    for (int ii = 1; ii < K; ii++) od += dwx[ii] * O[ii];
                    S->gO[0] += wyz * od;
                    S->gO[1] += dwy[jj] * wz[kk] * o0;
                    if (D3) S->gO[2] += wy[jj] * dwz[kk] * o0;
                }
                if (fl & G_T) {
                    /* rt[e] lane a = Σ_i (w_x,i A_i,a) O_i,e */
                    const int NE = D3 ? 3 : 2;
                    UNROLL
                    for (int e = 0; e < NE; e++) {
                        V4 rt = (wx[0] * A[0]) * O[0][e];
                        UNROLL
                        for (int ii = 1; ii < K; ii++) rt += (wx[ii] * A[ii]) * O[ii][e];
                        S->T[e] += wyz * rt;
                    }
                }
            }
        }
}

/* G2P of one particle from its sums ([APIC] eqs. 37–39 with the grid motion of eq. 30). With
   u_i = λ v_i^n + (1 − λ) ṽ_i and r_i = x_i − x_p, eq. (38) expands (x̃_i − x_p^{n+1} = r_i + Δt(u_i − ū))
   to B = Σ w ṽ r_iᵀ + (Δt/2) Σ w [ṽ (u_i − ū)ᵀ − (u_i − ū) ṽᵀ], ū = Σ w u_i. The second term, written
   with T = Σ w ṽ v^nᵀ, v_p = Σ w ṽ and v_o = Σ w v^n, is (λΔt/2)(T − Tᵀ + v_o v_pᵀ − v_p v_oᵀ): the
   ṽṽᵀ parts are symmetric and cancel, so it vanishes for λ = 0 (the original APIC, §5.7). */
DR_INLINE void g2p_particle(const GatherCtx *c, long p, int K, int D3, Block *blk)
{
    const DrNodeGrid *g = c->g;
    const int NA = D3 ? 3 : 2;
    const double inv = 1.0 / g->dx, lam = c->lambda, dt = c->dt;
    Sums S;
    gather_sums(c, c->x + 3 * p, K, D3, blk, &S);
    double *vp = c->v + 3 * p, *xp = c->x + 3 * p;
    /* ū (eq. 39) and grad u */
    double ubar[3], gu[9];
    UNROLL
    /* v_o is summed whenever Δt ≠ 0 and λ ≠ 0, the only case where ū differs from v_p and is used */
    for (int a = 0; a < 3; a++) ubar[a] = lam == 0.0 || !(c->flags & G_O) ? S.vA[a] : lam * S.vO[a] + (1.0 - lam) * S.vA[a];
    if (c->grad_u)
        UNROLL
        for (int a = 0; a < 3; a++)
            UNROLL
            for (int e = 0; e < 3; e++)
                gu[3 * a + e] = (lam == 0.0 ? S.gA[e][a] : lam * S.gO[e][a] + (1.0 - lam) * S.gA[e][a]) * inv;
    /* C */
    if (c->C) {
        double *Cp = c->C + 9 * p;
        if (c->scheme == DR_TRANSFER_APIC || c->scheme == DR_TRANSFER_RPIC) {
            if (K == 2) {
                /* lagged C for the multilinear kernel (§5.9): C = Σ ṽ ∇wᵀ */
                UNROLL
                for (int a = 0; a < 3; a++)
                    UNROLL
                    for (int e = 0; e < 3; e++) Cp[3 * a + e] = S.gA[e][a] * inv;
            } else {
                /* C = B D⁻¹, D⁻¹ = dinv; δ in grid units, so Σ w ṽ rᵀ = Δx·S.B */
                double dinv = dr_kernel_dinv(g->kernel, g->dx), sb = dinv * g->dx;
                UNROLL
                for (int a = 0; a < 3; a++)
                    UNROLL
                    for (int e = 0; e < 3; e++) Cp[3 * a + e] = sb * S.B[e][a];
                if (c->flags & G_T) {
                    double h = 0.5 * lam * dt * dinv;
                    UNROLL
                    for (int a = 0; a < 3; a++)
                        UNROLL
                        for (int e = 0; e < 3; e++)
                            Cp[3 * a + e] += h * (S.T[e][a] - S.T[a][e] + S.vO[a] * S.vA[e] - S.vA[a] * S.vO[e]);
                }
            }
            if (c->scheme == DR_TRANSFER_RPIC) {
                /* RPIC (§2.1): ω = K_p⁻¹ l̂_p with K_p = m(tr D·I − D) = 2m D for isotropic D, i.e. ω× is the
                   skew part of the APIC C; for the lagged linear C the same projection is used */
                UNROLL
                for (int r = 0; r < 3; r++)
                    UNROLL
                    for (int e = r + 1; e < 3; e++) {
                        double w = 0.5 * (Cp[3 * r + e] - Cp[3 * e + r]);
                        Cp[3 * r + e] = w;
                        Cp[3 * e + r] = -w;
                    }
                Cp[0] = Cp[4] = Cp[8] = 0.0;
            }
        } else {
            memset(Cp, 0, 9 * sizeof(double));
        }
    }
    /* v (eq. 37; FLIP eq. 3 with the PIC blend) */
    UNROLL
    for (int a = 0; a < NA; a++) {
        if (c->scheme == DR_TRANSFER_FLIP) vp[a] = c->blend * S.vA[a] + (1.0 - c->blend) * (vp[a] + (S.vA[a] - S.vO[a]));
        else vp[a] = S.vA[a];
    }
    if (!D3) vp[2] = 0.0;
    /* x_p^{n+1} = Σ w x̃_i = x_p + Δt ū (eqs. 21, 30, 39) */
    if (dt != 0.0)
        UNROLL
        for (int a = 0; a < NA; a++) xp[a] += dt * ubar[a];
    if (c->grad_u) memcpy(c->grad_u + 9 * p, gu, sizeof gu);
}

DR_INLINE void gather_range(const GatherCtx *c, long begin, long end, int K, int D3)
{
    Block blk = {.base = -1}; /* zeroed whole: 4 KB once per range of particles */
    for (long p = begin; p < end; p++) {
        if (c->mode == 0) {
            g2p_particle(c, p, K, D3, &blk);
        } else {
            Sums S;
            gather_sums(c, c->xin + 3 * p, K, D3, &blk, &S);
            if (c->mode == 1)
                for (int a = 0; a < 3; a++)
                    for (int e = 0; e < 3; e++) c->out[9 * p + 3 * a + e] = S.gA[e][a] / c->g->dx;
            else
                for (int a = 0; a < 3; a++) c->out[3 * p + a] = S.vA[a];
        }
    }
}

/* Each gather is built for SSE2 and for AVX2 (same bits; see V4). */
#define GATHER_FN(name, K, D3) \
    static void name(long begin, long end, void *c) { gather_range(c, begin, end, K, D3); } \
    __attribute__((target("avx2"))) static void name##_avx2(long begin, long end, void *c) \
    { \
        gather_range(c, begin, end, K, D3); \
    }
GATHER_FN(gather_l2, 2, 0)
GATHER_FN(gather_l3, 2, 1)
GATHER_FN(gather_q2, 3, 0)
GATHER_FN(gather_q3, 3, 1)
GATHER_FN(gather_c2, 4, 0)
GATHER_FN(gather_c3, 4, 1)
static const DrRangeFn gather_table[2][3][2] = {
    {{gather_l2, gather_l3}, {gather_q2, gather_q3}, {gather_c2, gather_c3}},
    {{gather_l2_avx2, gather_l3_avx2}, {gather_q2_avx2, gather_q3_avx2}, {gather_c2_avx2, gather_c3_avx2}},
};

static void gather(GatherCtx *c)
{
    int K = kernel_nodes(c->g->kernel);
    dr_parallel_for(c->n, NODE_PAR_MIN / 4, gather_table[cpu_avx2()][K - 2][c->g->dim == 3], c);
}

void dr_node_g2p(const DrNodeGrid *g, const double *vel_new, const double *vel_old, double lambda, double dt,
                 DrTransferScheme scheme, double flip_blend, long n, double *x, double *v, double *C,
                 double *grad_u)
{
    bool affine = scheme == DR_TRANSFER_APIC || scheme == DR_TRANSFER_RPIC;
    bool linear = g->kernel == DR_KERNEL_LINEAR;
    assert(!affine || C);
    int fl = 0;
    if (affine && !linear) fl |= G_B;
    if ((affine && linear) || grad_u) fl |= G_GA;
    if (scheme == DR_TRANSFER_FLIP || (lambda != 0.0 && dt != 0.0)) fl |= G_O;
    if (grad_u && lambda != 0.0) fl |= G_GO;
    if (affine && !linear && lambda != 0.0 && dt != 0.0) fl |= G_T;
    assert(!(fl & (G_O | G_GO | G_T)) || vel_old);
    GatherCtx c = {g, vel_new, vel_old, fl, n, scheme, lambda, dt, flip_blend, x, v, C, grad_u, NULL, NULL, 0};
    gather(&c);
}

void dr_node_gather_gradient(const DrNodeGrid *g, const double *u, long n, const double *x, double *out)
{
    GatherCtx c = {g, u, NULL, G_GA, n, DR_TRANSFER_PIC, 0.0, 0.0, 0.0, NULL, NULL, NULL, NULL, x, out, 1};
    gather(&c);
}

void dr_node_gather_vector(const DrNodeGrid *g, const double *u, long n, const double *x, double *out)
{
    GatherCtx c = {g, u, NULL, 0, n, DR_TRANSFER_PIC, 0.0, 0.0, 0.0, NULL, NULL, NULL, NULL, x, out, 2};
    gather(&c);
}

/* ==== totals ======================================================================================= */

void dr_node_particle_totals(DrKernel k, double dx, long n, const double *x, const double *v, const double *C,
                             const double *mass, DrVec3 *momentum, DrVec3 *angular, double *kinetic)
{
    DrVec3 P = dr_v3(0, 0, 0), L = dr_v3(0, 0, 0);
    double KE = 0.0, D = kernel_d(k, dx);
    for (long p = 0; p < n; p++) {
        DrVec3 xp = dr_v3(x[3 * p], x[3 * p + 1], x[3 * p + 2]);
        DrVec3 vp = dr_v3(v[3 * p], v[3 * p + 1], v[3 * p + 2]);
        DrVec3 mv = dr_v3_scale(vp, mass[p]);
        P = dr_v3_add(P, mv);
        L = dr_v3_add(L, dr_v3_cross(xp, mv));
        KE += 0.5 * mass[p] * dr_v3_dot(vp, vp);
        if (C && D > 0.0) {
            /* m ε:(Bᵀ) with B = C D ([APIC] §5.3.1): (B₂₁ − B₁₂, B₀₂ − B₂₀, B₁₀ − B₀₁) */
            const double *cp = C + 9 * p;
            L = dr_v3_add(L, dr_v3_scale(dr_v3(cp[7] - cp[5], cp[2] - cp[6], cp[3] - cp[1]), mass[p] * D));
        }
    }
    if (momentum) *momentum = P;
    if (angular) *angular = L;
    if (kinetic) *kinetic = KE;
}

void dr_node_grid_totals(const DrNodeGrid *g, const double *vel, DrVec3 *momentum, DrVec3 *angular, double *kinetic)
{
    DrVec3 P = dr_v3(0, 0, 0), L = dr_v3(0, 0, 0);
    double KE = 0.0;
    for (long i = 0; i < g->nnodes; i++) {
        double m = g->mass[i];
        if (m == 0.0) continue;
        DrVec3 vi = dr_v3(vel[3 * i], vel[3 * i + 1], vel[3 * i + 2]);
        DrVec3 mv = dr_v3_scale(vi, m);
        P = dr_v3_add(P, mv);
        L = dr_v3_add(L, dr_v3_cross(dr_node_position(g, i), mv));
        KE += 0.5 * m * dr_v3_dot(vi, vi);
    }
    if (momentum) *momentum = P;
    if (angular) *angular = L;
    if (kinetic) *kinetic = KE;
}
