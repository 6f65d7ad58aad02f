/* BLAS-1 helpers with thread-count-independent reductions, and preconditioned conjugate gradients. */
#include "linalg/linalg.h"

#include <stdlib.h>
#include <string.h>

/* ---- fixed-order block reductions ------------------------------------------------------------ */

/* Reductions split [0, n) into at most DR_RED_MAX_BLOCKS blocks of at least DR_RED_MIN_BLOCK entries.
 * The split depends on n only; blocks are summed sequentially and their partials added in block order,
 * so the result does not depend on how dr_parallel_for hands blocks to threads. The partials live on the
 * stack (2 KiB), which keeps dr_dot allocation-free. */
#define DR_RED_MAX_BLOCKS 256
#define DR_RED_MIN_BLOCK 2048
/* Entries a thread should get at least before going parallel pays: a parallel region costs a few µs
 * on an idle machine and far more on a loaded one, while 32k entries of a dot product take ~20 µs. */
#define DR_PAR_MIN_ENTRIES 32768

typedef double (*BlockFn)(long begin, long end, void *ctx);

typedef struct Reduction {
    BlockFn fn;
    void *ctx;
    long n, block;
    double *partials;
} Reduction;

static void reduction_range(long begin, long end, void *vctx)
{
    Reduction *red = vctx;
    for (long blk = begin; blk < end; blk++) {
        long b = blk * red->block, e = b + red->block;
        if (e > red->n) e = red->n;
        red->partials[blk] = red->fn(b, e, red->ctx);
    }
}

static double reduce_blocks(long n, BlockFn fn, void *ctx)
{
    if (n <= 0) return 0.0;
    long block = (n + DR_RED_MAX_BLOCKS - 1) / DR_RED_MAX_BLOCKS;
    if (block < DR_RED_MIN_BLOCK) block = DR_RED_MIN_BLOCK;
    long nblocks = (n + block - 1) / block;
    double partials[DR_RED_MAX_BLOCKS];
    Reduction red = {fn, ctx, n, block, partials};
    long grain = (DR_PAR_MIN_ENTRIES + block - 1) / block;
    dr_parallel_for(nblocks, grain, reduction_range, &red);
    double sum = 0.0;
    for (long blk = 0; blk < nblocks; blk++) sum += partials[blk];
    return sum;
}

/* Four interleaved accumulators: without -ffast-math the compiler keeps one accumulator's additions in
 * order and cannot vectorise them; four independent chains let it overlap the latency. The order is
 * still fixed by the code, so the result is reproducible. */
static double dot_kernel(const double *a, const double *b, long begin, long end)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    long i = begin;
    for (; i + 4 <= end; i += 4) {
        s0 += a[i] * b[i];
        s1 += a[i + 1] * b[i + 1];
        s2 += a[i + 2] * b[i + 2];
        s3 += a[i + 3] * b[i + 3];
    }
    for (; i < end; i++) s0 += a[i] * b[i];
    return (s0 + s1) + (s2 + s3);
}

typedef struct DotCtx { const double *a, *b; } DotCtx;

static double dot_block(long begin, long end, void *vctx)
{
    const DotCtx *c = vctx;
    return dot_kernel(c->a, c->b, begin, end);
}

double dr_dot(const double *a, const double *b, int n)
{
    DotCtx c = {a, b};
    return reduce_blocks(n, dot_block, &c);
}

typedef struct AxpyCtx { double a; const double *x; double *y; } AxpyCtx;

static void axpy_range(long begin, long end, void *vctx)
{
    const AxpyCtx *c = vctx;
    for (long i = begin; i < end; i++) c->y[i] += c->a * c->x[i];
}

void dr_axpy(double a, const double *x, double *y, int n)
{
    AxpyCtx c = {a, x, y};
    dr_parallel_for(n, DR_PAR_MIN_ENTRIES, axpy_range, &c);
}

/* ---- fused vector kernels used by PCG ---------------------------------------------------------- */

typedef struct PcgVecs {
    const double *b;
    double *x, *r, *z, *p, *q;
    double alpha, beta;
} PcgVecs;

/* r = b - q (q holds A x) */
static void residual_range(long begin, long end, void *vctx)
{
    PcgVecs *v = vctx;
    for (long i = begin; i < end; i++) v->r[i] = v->b[i] - v->q[i];
}

/* x += α p, r -= α q (the two CG updates in one pass over memory); returns Σ r_i² of the new r so the
 * Euclidean norm costs no extra pass. */
static double update_block(long begin, long end, void *vctx)
{
    PcgVecs *v = vctx;
    double a = v->alpha;
    for (long i = begin; i < end; i++) {
        v->x[i] += a * v->p[i];
        v->r[i] -= a * v->q[i];
    }
    return dot_kernel(v->r, v->r, begin, end);
}

/* p = z + β p */
static void direction_range(long begin, long end, void *vctx)
{
    PcgVecs *v = vctx;
    double beta = v->beta;
    for (long i = begin; i < end; i++) v->p[i] = v->z[i] + beta * v->p[i];
}

static void zero_range(long begin, long end, void *vctx)
{
    double *x = vctx;
    memset(x + begin, 0, (size_t)(end - begin) * sizeof(double));
}

static void copy_range(long begin, long end, void *vctx)
{
    PcgVecs *v = vctx;
    memcpy(v->p + begin, v->z + begin, (size_t)(end - begin) * sizeof(double));
}

/* ---- PCG --------------------------------------------------------------------------------------- */

void dr_pcg_desc_default(DrPcgDesc *d)
{
    d->rel_tol = 1e-6;
    d->abs_tol = 0.0;
    d->max_iter = 2000;
    d->dot = NULL;
    d->dot_ctx = NULL;
}

static double inner(const DrPcgDesc *d, const double *a, const double *b, int n)
{
    return d->dot ? d->dot(a, b, n, d->dot_ctx) : dr_dot(a, b, n);
}

static long first_nonfinite(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return i;
    return -1;
}

static void fill_stats(DrPcgStats *stats, int it, double rnorm, double bnorm, bool converged)
{
    if (!stats) return;
    stats->iterations = it;
    stats->residual = rnorm;
    stats->rel_residual = bnorm > 0.0 ? rnorm / bnorm : 0.0;
    stats->converged = converged;
}

/* Algorithm: Saad, "Iterative Methods for Sparse Linear Systems" (2nd ed.), Algorithm 9.1 (PCG), with
 * every inner product taken from the hook so that CG in a weighted inner product (MPM's mass product)
 * uses the same code. */
static DrStatus pcg_run(const DrLinearOp *A, const DrLinearOp *M, const double *b, double *x,
                        const DrPcgDesc *d, double *work, DrPcgStats *stats, DrError *err)
{
    const int n = A->n;
    PcgVecs v = {.b = b, .x = x};
    v.r = work;
    v.p = work + (size_t)n;
    v.q = work + 2 * (size_t)n;
    v.z = M ? work + 3 * (size_t)n : v.r; /* unpreconditioned: z = r, no copy */

    double bb = inner(d, b, b, n);
    if (!isfinite(bb)) {
        long i = first_nonfinite(b, n);
        fill_stats(stats, 0, NAN, NAN, false);
        if (i >= 0)
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "PCG: right-hand side b[%ld] = %g is not finite; the assembled system holds a "
                                "NaN or Inf (check the quantities it was built from)", i, b[i]);
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "PCG: the inner product <b, b> = %g is not finite; check the inner-product "
                            "weights and the magnitude of b", bb);
    }
    double bnorm = sqrt(bb > 0.0 ? bb : 0.0);
    if (bnorm == 0.0) {
        /* x = 0 solves A x = 0 for every A; iterating from a nonzero guess could only approach it. */
        dr_parallel_for(n, DR_PAR_MIN_ENTRIES, zero_range, x);
        fill_stats(stats, 0, 0.0, 0.0, true);
        return DR_OK;
    }
    double tol = fmax(d->rel_tol * bnorm, d->abs_tol);

    /* 1. initial residual r = b - A x */
    A->apply(x, v.q, A->ctx);
    dr_parallel_for(n, DR_PAR_MIN_ENTRIES, residual_range, &v);
    double rr = inner(d, v.r, v.r, n);
    if (!isfinite(rr)) {
        long i = first_nonfinite(x, n);
        fill_stats(stats, 0, NAN, bnorm, false);
        if (i >= 0)
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "PCG: initial guess x[%ld] = %g is not finite; start from zero or the "
                                "previous step's finite solution", i, x[i]);
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "PCG: the initial residual is not finite (the operator produced NaN or Inf); "
                            "check the matrix or operator for non-finite coefficients");
    }
    double rnorm = sqrt(rr > 0.0 ? rr : 0.0);
    if (rnorm <= tol) {
        fill_stats(stats, 0, rnorm, bnorm, true);
        return DR_OK;
    }

    /* 2. z = M r, p = z, ρ = <r, z> */
    if (M) M->apply(v.r, v.z, M->ctx);
    dr_parallel_for(n, DR_PAR_MIN_ENTRIES, copy_range, &v);
    double rho = M ? inner(d, v.r, v.z, n) : rr;
    if (!(rho > 0.0) || !isfinite(rho)) {
        fill_stats(stats, 0, rnorm, bnorm, false);
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "PCG breakdown before the first iteration: <r, M r> = %g with ||r|| = %g; the "
                            "preconditioner is not positive definite (or produced NaN)", rho, rnorm);
    }

    /* 3. iterate */
    for (int it = 1; it <= d->max_iter; it++) {
        A->apply(v.p, v.q, A->ctx);
        double pq = inner(d, v.p, v.q, n);
        if (!isfinite(pq)) {
            fill_stats(stats, it - 1, rnorm, bnorm, false);
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "PCG: <p, A p> = %g is not finite at iteration %d; the operator produced NaN "
                                "or Inf (check its coefficients)", pq, it);
        }
        if (pq <= 0.0) {
            fill_stats(stats, it - 1, rnorm, bnorm, false);
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "PCG breakdown at iteration %d: <p, A p> = %g <= 0 with ||r|| = %g; the "
                                "operator is not positive definite (or the right-hand side is incompatible "
                                "with a singular one)", it, pq, rnorm);
        }
        v.alpha = rho / pq;
        if (d->dot) {
            reduce_blocks(n, update_block, &v);
            rr = inner(d, v.r, v.r, n);
        } else {
            rr = reduce_blocks(n, update_block, &v);
        }
        if (!isfinite(rr)) {
            fill_stats(stats, it, NAN, bnorm, false);
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "PCG: the residual became non-finite at iteration %d; the operator or the "
                                "inner product overflowed", it);
        }
        rnorm = sqrt(rr > 0.0 ? rr : 0.0);
        if (rnorm <= tol) {
            fill_stats(stats, it, rnorm, bnorm, true);
            return DR_OK;
        }
        if (M) M->apply(v.r, v.z, M->ctx);
        double rho_new = M ? inner(d, v.r, v.z, n) : rr;
        if (!(rho_new > 0.0) || !isfinite(rho_new)) {
            fill_stats(stats, it, rnorm, bnorm, false);
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "PCG breakdown at iteration %d: <r, M r> = %g with ||r|| = %g; the "
                                "preconditioner is not positive definite (or produced NaN)", it, rho_new, rnorm);
        }
        v.beta = rho_new / rho;
        rho = rho_new;
        dr_parallel_for(n, DR_PAR_MIN_ENTRIES, direction_range, &v);
    }
    fill_stats(stats, d->max_iter, rnorm, bnorm, false);
    dr_error_set(err, DR_WARN_NOT_CONVERGED, NULL, 0, 0,
                 "PCG did not converge in %d iterations: ||r|| = %g, ||r||/||b|| = %g (tolerance %g); raise "
                 "max_iter or use a stronger preconditioner", d->max_iter, rnorm, rnorm / bnorm, tol);
    return DR_WARN_NOT_CONVERGED;
}

DrStatus dr_pcg_solve(const DrLinearOp *A, const DrLinearOp *M, const double *b, double *x,
                      const DrPcgDesc *desc, double *work, DrPcgStats *stats, DrError *err)
{
    assert(A && A->apply && A->n >= 0 && b && x);
    assert(!M || (M->apply && M->n == A->n));
    DrPcgDesc d;
    if (desc) d = *desc;
    else dr_pcg_desc_default(&d);
    if (!(d.rel_tol >= 0.0) || !(d.abs_tol >= 0.0) || d.max_iter < 0) {
        fill_stats(stats, 0, NAN, NAN, false);
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "PCG: rel_tol = %g, abs_tol = %g must be >= 0 and max_iter = %d >= 0", d.rel_tol,
                            d.abs_tol, d.max_iter);
    }
    if (A->n == 0) {
        fill_stats(stats, 0, 0.0, 0.0, true);
        return DR_OK;
    }
    double *owned = NULL;
    if (!work) {
        DR_TRY(dr_calloc(4 * (size_t)A->n, sizeof(double), &owned, err));
        work = owned;
    }
    DrStatus s = pcg_run(A, M, b, x, &d, work, stats, err);
    free(owned);
    return s;
}
