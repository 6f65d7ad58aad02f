/* Geometric multigrid V-cycle for 7-point cell-centred Poisson-type matrices on a subset of a regular grid,
 * applied as a preconditioner (linalg.h: DrMg). */
#include "linalg/linalg.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Rows a thread should get at least before a stencil loop goes parallel (a row is ~7 loads and ~15 flops). */
#define MG_PAR_MIN_ROWS 8192
/* A coarsest-level pivot below this fraction of its diagonal entry is taken as the rounding left of a zero
 * pivot (a pure-Neumann island's last unknown gives ~1e-16 A_jj) and replaced by A_jj. */
#define MG_PIVOT_FLOOR 1e-10

/* Face order of the stencil: −x, +x, −y, +y, −z, +z (face f is along axis f/2, on the side f%2). */
typedef struct MgLevel {
    int n;           /* rows (unknown cells) */
    int dims[3];     /* grid cells per axis */
    long ncell;      /* dims[0]·dims[1]·dims[2] */
    int *map;        /* ncell: the row of each grid cell, −1 if none */
    long *cell;      /* n: linear grid index i + dims0 (j + dims1 k) of each row (rows in increasing cell order
                        on coarse levels; in the matrix's order on the finest) */
    int *nb;         /* 6n: the row across each face; the row itself where there is none (with off = 0) */
    double *off;     /* 6n: the matrix entry to that row (≤ 0 for a Poisson matrix) */
    double *diag;    /* n */
    double *inv_diag; /* n: 1/diag, 1 where diag = 0 (a decoupled unknown: identity) */
    int *order;      /* n: red rows ((i+j+k) even) then black rows, each in increasing row order */
    int nred;
    int *parent;     /* n: the row of the parent cell on the next coarser level */
    double *x, *b;   /* n each: solution and right-hand side on coarse levels (the finest uses the caller's) */
    int n_capacity;
    long cell_capacity;
} MgLevel;

struct DrMg {
    DrMgDesc d;
    int nlevels, level_capacity; /* levels in use; levels whose storage exists */
    MgLevel lv[DR_MG_MAX_LEVELS];
    double *band;    /* coarsest level: lower band of its Cholesky factor, row i at band[i (kd+1)] */
    size_t band_capacity;
    int kd;          /* bandwidth of the coarsest level (rows in increasing cell order) */
    int fallbacks;   /* coarsest pivots replaced by the diagonal entry in the last update */
    int *bad;        /* per block of MG_PAR_MIN_ROWS finest rows: its first row failing a check, or −1 */
    long bad_capacity;
};

void dr_mg_desc_default(DrMgDesc *d)
{
    d->sweeps = 2;
    d->coarsest_rows = 512;
    d->coarse_scale = 0.5;
}

/* ---- storage ------------------------------------------------------------------------------------ */

static void level_free(MgLevel *l)
{
    free(l->map), free(l->cell), free(l->nb), free(l->off), free(l->diag), free(l->inv_diag);
    free(l->order), free(l->parent), free(l->x), free(l->b);
    memset(l, 0, sizeof *l);
}

static DrStatus level_reserve(MgLevel *l, int n, long ncell, DrError *err)
{
    if (ncell > l->cell_capacity || !l->map) {
        DR_TRY(dr_realloc((size_t)ncell, sizeof(int), &l->map, err));
        l->cell_capacity = ncell;
        for (long c = 0; c < ncell; c++) l->map[c] = -1;
    }
    if (n > l->n_capacity || !l->cell) {
        size_t m = n > 0 ? (size_t)n : 1;
        DR_TRY(dr_realloc(m, sizeof(long), &l->cell, err));
        DR_TRY(dr_realloc(6 * m, sizeof(int), &l->nb, err));
        DR_TRY(dr_realloc(6 * m, sizeof(double), &l->off, err));
        DR_TRY(dr_realloc(m, sizeof(double), &l->diag, err));
        DR_TRY(dr_realloc(m, sizeof(double), &l->inv_diag, err));
        DR_TRY(dr_realloc(m, sizeof(int), &l->order, err));
        DR_TRY(dr_realloc(m, sizeof(int), &l->parent, err));
        DR_TRY(dr_realloc(m, sizeof(double), &l->x, err));
        DR_TRY(dr_realloc(m, sizeof(double), &l->b, err));
        l->n_capacity = (int)m;
    }
    return DR_OK;
}

/* Clears the map entries the level's rows set (the rest of the map is −1 already). */
static void level_unmap(MgLevel *l)
{
    for (int r = 0; r < l->n; r++) l->map[l->cell[r]] = -1;
}

/* ---- level construction ----------------------------------------------------------------------- */

static inline void cell_ijk(const MgLevel *l, long c, int ijk[3])
{
    ijk[0] = (int)(c % l->dims[0]);
    ijk[1] = (int)((c / l->dims[0]) % l->dims[1]);
    ijk[2] = (int)(c / ((long)l->dims[0] * l->dims[1]));
}

static void level_colour(MgLevel *l)
{
    int nred = 0;
    for (int r = 0; r < l->n; r++) {
        int ijk[3];
        cell_ijk(l, l->cell[r], ijk);
        if (((ijk[0] + ijk[1] + ijk[2]) & 1) == 0) l->order[nred++] = r;
    }
    l->nred = nred;
    int k = nred;
    for (int r = 0; r < l->n; r++) {
        int ijk[3];
        cell_ijk(l, l->cell[r], ijk);
        if ((ijk[0] + ijk[1] + ijk[2]) & 1) l->order[k++] = r;
    }
}

static void level_inverse_diagonal(MgLevel *l)
{
    for (int r = 0; r < l->n; r++) l->inv_diag[r] = l->diag[r] > 0.0 ? 1.0 / l->diag[r] : 1.0;
}

/* Row r of the finest level from row r of A (the map holds every row's cell). Returns the failure
 * (err may be NULL: then only the status). */
static DrStatus fine_row(MgLevel *l, const DrCsr *A, int r, DrError *err)
{
    const int *dims = l->dims;
    long stride[3] = {1, dims[0], (long)dims[0] * dims[1]};
    int *nb = l->nb + 6 * (size_t)r;
    double *off = l->off + 6 * (size_t)r;
    for (int f = 0; f < 6; f++) nb[f] = r, off[f] = 0.0;
    l->diag[r] = 0.0;
    int ci[3];
    cell_ijk(l, l->cell[r], ci);
    int prev = -1;
    for (int k = A->rowptr[r]; k < A->rowptr[r + 1]; k++) {
        int c = A->col[k];
        double v = A->val[k];
        if (c < 0 || c >= A->n || c <= prev)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "multigrid: row %d: column %d out of range [0, %d) or not increasing; check the "
                                "matrix with dr_csr_check", r, c, A->n);
        prev = c;
        if (!isfinite(v))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "multigrid: entry (%d, %d) of the matrix is %g; the assembly produced a non-finite "
                                "coefficient", r, c, v);
        if (c == r) {
            if (v < 0.0)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "multigrid: diagonal entry (%d, %d) = %g is negative, so the matrix is not "
                                    "positive semidefinite; check the sign convention of the assembly", r, r, v);
            l->diag[r] = v;
            continue;
        }
        long d = l->cell[c] - l->cell[r];
        int face = -1;
        for (int a = 0; a < 3 && face < 0; a++) {
            if (d == stride[a] && ci[a] + 1 < dims[a]) face = 2 * a + 1;
            else if (d == -stride[a] && ci[a] > 0) face = 2 * a;
        }
        if (face < 0)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "multigrid: entry (%d, %d) couples cells that are not face neighbours; the matrix "
                                "must be a 7-point stencil on the rows' cells", r, c);
        nb[face] = c;
        off[face] = v;
    }
    return DR_OK;
}

/* The V-cycle is a symmetric preconditioner only for a symmetric matrix. */
static DrStatus symmetric_row(const MgLevel *l, int r, DrError *err)
{
    for (int f = 0; f < 6; f++) {
        int c = l->nb[6 * (size_t)r + f];
        if (c == r) continue;
        double v = l->off[6 * (size_t)r + f], w = l->off[6 * (size_t)c + (f ^ 1)];
        if (!(fabs(v - w) <= 1e-12 * fmax(fabs(v), fabs(w))))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "multigrid: the matrix is not symmetric: entry (%d, %d) = %.17g but (%d, %d) = "
                                "%.17g", r, c, v, c, r, w);
    }
    return DR_OK;
}

/* Blocks of MG_PAR_MIN_ROWS rows in parallel; bad[block] = the block's first failing row or −1. Pass 0
 * reads the rows, pass 1 checks symmetry (it reads other rows' entries: after pass 0 has finished). */
typedef struct FineCtx { MgLevel *l; const DrCsr *A; int *bad; int pass; } FineCtx;

static void fine_blocks(long begin, long end, void *vctx)
{
    const FineCtx *x = vctx;
    for (long blk = begin; blk < end; blk++) {
        x->bad[blk] = -1;
        int r0 = (int)(blk * MG_PAR_MIN_ROWS), r1 = r0 + MG_PAR_MIN_ROWS < x->l->n ? r0 + MG_PAR_MIN_ROWS : x->l->n;
        for (int r = r0; r < r1; r++) {
            DrStatus s = x->pass == 0 ? fine_row(x->l, x->A, r, NULL) : symmetric_row(x->l, r, NULL);
            if (s != DR_OK) {
                x->bad[blk] = r;
                break;
            }
        }
    }
}

/* The finest level from the CSR matrix and the cells of its rows. Structure problems are DR_ERR_INPUT,
 * non-finite values DR_ERR_RUNTIME; both name the row. */
static DrStatus level_from_csr(DrMg *M, const DrCsr *A, const int *ijk, const int dims[3], DrError *err)
{
    MgLevel *l = &M->lv[0];
    if (l->map) level_unmap(l);
    l->n = 0;
    long ncell = 1;
    for (int a = 0; a < 3; a++) {
        if (dims[a] < 1 || ncell > LONG_MAX / dims[a] || (long)dims[a] * ncell > INT_MAX)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "multigrid: grid dimensions %d × %d × %d must be >= 1 each with fewer than "
                                "2^31 cells in all", dims[0], dims[1], dims[2]);
        ncell *= dims[a];
    }
    if (A->n > ncell)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "multigrid: the matrix has %d rows but the %d × %d × %d grid only %ld cells; pass "
                            "the grid the rows' cells come from", A->n, dims[0], dims[1], dims[2], ncell);
    if (A->rowptr[0] != 0 || A->nnz < 0 || A->rowptr[A->n] != A->nnz)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "multigrid: the matrix's rowptr runs from %d to %d but nnz = %d; rowptr must run "
                            "from 0 to nnz", A->rowptr[0], A->rowptr[A->n], A->nnz);
    for (int r = 0; r < A->n; r++)
        if (A->rowptr[r + 1] < A->rowptr[r])
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "multigrid: rowptr decreases at row %d (%d then %d)", r, A->rowptr[r],
                                A->rowptr[r + 1]);
    DR_TRY(level_reserve(l, A->n, ncell, err));
    long nbad = A->n / MG_PAR_MIN_ROWS + 1;
    if (nbad > M->bad_capacity) {
        DR_TRY(dr_realloc((size_t)nbad, sizeof(int), &M->bad, err));
        M->bad_capacity = nbad;
    }
    for (int a = 0; a < 3; a++) l->dims[a] = dims[a];
    l->ncell = ncell;
    for (int r = 0; r < A->n; r++) {
        const int *p = ijk + 3 * (size_t)r;
        if (p[0] < 0 || p[0] >= dims[0] || p[1] < 0 || p[1] >= dims[1] || p[2] < 0 || p[2] >= dims[2]) {
            level_unmap(l);
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "multigrid: row %d sits in cell (%d, %d, %d), outside the %d × %d × %d grid", r,
                                p[0], p[1], p[2], dims[0], dims[1], dims[2]);
        }
        long c = p[0] + (long)dims[0] * (p[1] + (long)dims[1] * p[2]);
        if (l->map[c] >= 0) {
            int other = l->map[c];
            level_unmap(l);
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "multigrid: rows %d and %d both sit in cell (%d, %d, %d); each row must have a "
                                "cell of its own", other, r, p[0], p[1], p[2]);
        }
        l->map[c] = r;
        l->cell[r] = c;
        l->n = r + 1;
    }
    FineCtx fc = {l, A, M->bad, 0};
    long nblocks = (l->n + MG_PAR_MIN_ROWS - 1) / MG_PAR_MIN_ROWS;
    DrStatus s = DR_OK;
    for (int pass = 0; pass < 2 && s == DR_OK; pass++) {
        fc.pass = pass;
        dr_parallel_for(nblocks, 1, fine_blocks, &fc);
        for (long blk = 0; blk < nblocks; blk++)
            if (M->bad[blk] >= 0) { /* again on one row, for the message */
                s = pass == 0 ? fine_row(l, A, M->bad[blk], err) : symmetric_row(l, M->bad[blk], err);
                assert(s != DR_OK);
                break;
            }
    }
    if (s != DR_OK) {
        level_unmap(l);
        l->n = 0;
        return s;
    }
    level_inverse_diagonal(l);
    level_colour(l);
    return DR_OK;
}

/* Coarse operator of one coarse row, gathered from its (at most 8) children in a fixed order: the
 * piecewise-constant Galerkin product Pᵀ A P scaled by coarse_scale (see linalg.h). */
typedef struct CoarseCtx { const MgLevel *f; MgLevel *c; double scale; } CoarseCtx;

static void coarse_rows(long begin, long end, void *vctx)
{
    const CoarseCtx *x = vctx;
    const MgLevel *f = x->f;
    MgLevel *c = x->c;
    for (long R = begin; R < end; R++) {
        int cc[3];
        cell_ijk(c, c->cell[R], cc);
        double diag = 0.0, off[6] = {0};
        for (int dz = 0; dz < 2; dz++)
            for (int dy = 0; dy < 2; dy++)
                for (int dx = 0; dx < 2; dx++) {
                    int i = 2 * cc[0] + dx, j = 2 * cc[1] + dy, k = 2 * cc[2] + dz;
                    if (i >= f->dims[0] || j >= f->dims[1] || k >= f->dims[2]) continue;
                    int r = f->map[i + (long)f->dims[0] * (j + (long)f->dims[1] * k)];
                    if (r < 0) continue;
                    diag += f->diag[r];
                    for (int q = 0; q < 6; q++) {
                        int nbr = f->nb[6 * (size_t)r + q];
                        double v = f->off[6 * (size_t)r + q];
                        if (f->parent[nbr] == R) diag += v; /* coupling inside the coarse cell */
                        else off[q] += v;
                    }
                }
        c->diag[R] = x->scale * diag;
        for (int q = 0; q < 6; q++) {
            int a = q / 2, side = q % 2;
            int n = cc[a] + (side ? 1 : -1);
            int nbr = (int)R;
            if (n >= 0 && n < c->dims[a]) {
                int m[3] = {cc[0], cc[1], cc[2]};
                m[a] = n;
                int row = c->map[m[0] + (long)c->dims[0] * (m[1] + (long)c->dims[1] * m[2])];
                if (row >= 0) nbr = row;
            }
            c->nb[6 * R + q] = nbr;
            c->off[6 * R + q] = nbr == R ? 0.0 : x->scale * off[q];
        }
    }
}

typedef struct ParentCtx { MgLevel *f; const MgLevel *c; } ParentCtx;

static void parent_rows(long begin, long end, void *vctx)
{
    const ParentCtx *x = vctx;
    MgLevel *f = x->f;
    const MgLevel *c = x->c;
    for (long r = begin; r < end; r++) {
        int ijk[3];
        cell_ijk(f, f->cell[r], ijk);
        f->parent[r] = c->map[ijk[0] / 2 + (long)c->dims[0] * (ijk[1] / 2 + (long)c->dims[1] * (ijk[2] / 2))];
    }
}

/* Level l+1 from level l: a coarse cell for every 2×2×2 block holding a row, rows numbered in increasing
 * cell order. */
static DrStatus level_coarsen(DrMg *M, int l, DrError *err)
{
    MgLevel *f = &M->lv[l], *c = &M->lv[l + 1];
    if (c->map) level_unmap(c);
    c->n = 0;
    int dims[3];
    long ncell = 1;
    for (int a = 0; a < 3; a++) dims[a] = (f->dims[a] + 1) / 2, ncell *= dims[a];
    DR_TRY(level_reserve(c, 0, ncell, err));
    for (int a = 0; a < 3; a++) c->dims[a] = dims[a];
    c->ncell = ncell;
    /* mark with −2, then number in cell order */
    int n = 0;
    for (int r = 0; r < f->n; r++) {
        int ijk[3];
        cell_ijk(f, f->cell[r], ijk);
        long cc = ijk[0] / 2 + (long)dims[0] * (ijk[1] / 2 + (long)dims[1] * (ijk[2] / 2));
        if (c->map[cc] == -1) c->map[cc] = -2, n++;
    }
    DrStatus s = level_reserve(c, n, ncell, err);
    if (s != DR_OK) {
        for (long q = 0; q < ncell; q++) c->map[q] = -1;
        return s;
    }
    n = 0;
    for (long q = 0; q < ncell; q++)
        if (c->map[q] == -2) {
            c->map[q] = n;
            c->cell[n++] = q;
        }
    c->n = n;
    ParentCtx pctx = {f, c};
    dr_parallel_for(f->n, MG_PAR_MIN_ROWS, parent_rows, &pctx);
    CoarseCtx cctx = {f, c, M->d.coarse_scale};
    dr_parallel_for(c->n, MG_PAR_MIN_ROWS / 8, coarse_rows, &cctx);
    for (int r = 0; r < c->n; r++)
        if (!isfinite(c->diag[r]))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "multigrid: coarse level %d, row %d: diagonal %g is not finite (the matrix's "
                                "coefficients overflow when summed); scale the matrix", l + 1, r, c->diag[r]);
    level_inverse_diagonal(c);
    level_colour(c);
    return DR_OK;
}

/* ---- coarsest level: banded Cholesky ----------------------------------------------------------- */

/* L Lᵀ = A_coarsest on the band of width kd (rows in increasing cell order, so kd ≤ dims0·dims1). A
 * pivot that falls to MG_PIVOT_FLOOR·A_ii or below (the last unknown of a pure-Neumann island: singular)
 * is replaced by A_ii, which keeps the coarse solve symmetric positive definite. */
static DrStatus coarsest_factor(DrMg *M, DrError *err)
{
    const MgLevel *l = &M->lv[M->nlevels - 1];
    int n = l->n, kd = 0;
    for (int r = 0; r < n; r++)
        for (int q = 0; q < 6; q++) {
            int d = r - l->nb[6 * (size_t)r + q];
            if (d > kd) kd = d;
        }
    size_t w = (size_t)kd + 1, need;
    if (dr_mul_overflows(w, n > 0 ? (size_t)n : 1, &need))
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "multigrid: coarsest band %zu × %d overflows", w, n);
    if (need > M->band_capacity) {
        DR_TRY(dr_realloc(need, sizeof(double), &M->band, err));
        M->band_capacity = need;
    }
    M->kd = kd;
    double *B = M->band;
    memset(B, 0, need * sizeof(double));
    /* B[i w + (j − i + kd)] = A(i, j) for i − kd <= j <= i */
    for (int r = 0; r < n; r++) {
        B[r * w + kd] = l->diag[r];
        for (int q = 0; q < 6; q++) {
            int c = l->nb[6 * (size_t)r + q];
            if (c < r) B[r * w + (size_t)(c - r + kd)] += l->off[6 * (size_t)r + q];
        }
    }
    int fallbacks = 0;
    for (int i = 0; i < n; i++) {
        double *Li = B + (size_t)i * w;
        int j0 = i - kd > 0 ? i - kd : 0;
        for (int j = j0; j <= i; j++) {
            const double *Lj = B + (size_t)j * w;
            int k0 = j0 > j - kd ? j0 : j - kd;
            double s = Li[j - i + kd];
            for (int k = k0; k < j; k++) s -= Li[k - i + kd] * Lj[k - j + kd];
            if (j < i) {
                Li[j - i + kd] = s / Lj[kd];
                continue;
            }
            double a = l->diag[i];
            if (a == 0.0) {
                s = 1.0; /* decoupled unknown (its row is zero): identity */
            } else if (!(s > MG_PIVOT_FLOOR * a)) {
                s = a;
                fallbacks++;
            }
            if (!isfinite(s))
                return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                    "multigrid: the coarsest level's Cholesky pivot %d is not finite; the "
                                    "matrix's coefficients are too large or not finite", i);
            Li[kd] = sqrt(s);
        }
    }
    M->fallbacks = fallbacks;
    return DR_OK;
}

static void coarsest_solve(const DrMg *M, const double *b, double *x)
{
    const MgLevel *l = &M->lv[M->nlevels - 1];
    int n = l->n, kd = M->kd;
    size_t w = (size_t)kd + 1;
    const double *B = M->band;
    for (int i = 0; i < n; i++) {
        const double *Li = B + (size_t)i * w;
        double s = b[i];
        for (int k = i - kd > 0 ? i - kd : 0; k < i; k++) s -= Li[k - i + kd] * x[k];
        x[i] = s / Li[kd];
    }
    for (int i = n - 1; i >= 0; i--) {
        x[i] /= B[(size_t)i * w + kd];
        const double *Li = B + (size_t)i * w;
        for (int k = i - kd > 0 ? i - kd : 0; k < i; k++) x[k] -= Li[k - i + kd] * x[i];
    }
}

/* ---- create / update / destroy ---------------------------------------------------------------- */

DrStatus dr_mg_update(DrMg *M, const DrCsr *A, const int *cell_ijk_rows, const int dims[3], DrError *err)
{
    assert(M && A && dims && (cell_ijk_rows || A->n == 0));
    M->nlevels = 0; /* unusable until the update completes */
    if (A->n < 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "multigrid: the matrix has %d rows", A->n);
    DR_TRY(level_from_csr(M, A, cell_ijk_rows, dims, err));
    if (M->level_capacity < 1) M->level_capacity = 1;
    int nl = 1;
    while (nl < DR_MG_MAX_LEVELS && M->lv[nl - 1].n > M->d.coarsest_rows) {
        const MgLevel *f = &M->lv[nl - 1];
        if (f->dims[0] == 1 && f->dims[1] == 1 && f->dims[2] == 1) break;
        DR_TRY(level_coarsen(M, nl - 1, err));
        nl++;
        if (nl > M->level_capacity) M->level_capacity = nl;
    }
    M->nlevels = nl;
    DrStatus s = coarsest_factor(M, err);
    if (s != DR_OK) M->nlevels = 0;
    return s;
}

DrStatus dr_mg_create(const DrCsr *A, const int *cell_ijk_rows, const int dims[3], const DrMgDesc *desc, DrMg **out,
                      DrError *err)
{
    *out = NULL;
    DrMgDesc d;
    if (desc) d = *desc;
    else dr_mg_desc_default(&d);
    if (d.sweeps < 1 || d.sweeps > 64 || d.coarsest_rows < 1 || d.coarsest_rows > 100000 ||
        !(d.coarse_scale > 0.0 && d.coarse_scale <= 1.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "multigrid: sweeps = %d must be in [1, 64], coarsest_rows = %d in [1, 100000] and "
                            "coarse_scale = %g in (0, 1] (dr_mg_desc_default gives 2, 512, 0.5)", d.sweeps,
                            d.coarsest_rows, d.coarse_scale);
    DrMg *M = NULL;
    DR_TRY(dr_calloc(1, sizeof(DrMg), &M, err));
    M->d = d;
    DrStatus s = dr_mg_update(M, A, cell_ijk_rows, dims, err);
    if (s != DR_OK) {
        dr_mg_destroy(&M);
        return s;
    }
    *out = M;
    return DR_OK;
}

void dr_mg_destroy(DrMg **M)
{
    if (!M || !*M) return;
    for (int l = 0; l < DR_MG_MAX_LEVELS; l++) level_free(&(*M)->lv[l]);
    free((*M)->band);
    free((*M)->bad);
    free(*M);
    *M = NULL;
}

int dr_mg_levels(const DrMg *M) { return M->nlevels; }
int dr_mg_rows(const DrMg *M, int level) { return level >= 0 && level < M->nlevels ? M->lv[level].n : 0; }
int dr_mg_fallbacks(const DrMg *M) { return M->fallbacks; }

/* ---- the V-cycle ------------------------------------------------------------------------------- */

/* One red or black Gauss–Seidel half-sweep: rows of one colour couple only to rows of the other, so the
 * rows of a colour are updated independently (in parallel, same bits for any thread count). */
typedef struct SweepCtx { const MgLevel *l; const int *rows; const double *b; double *x; } SweepCtx;

static void sweep_rows(long begin, long end, void *vctx)
{
    const SweepCtx *s = vctx;
    const int *nb = s->l->nb;
    const double *off = s->l->off, *inv = s->l->inv_diag, *b = s->b;
    double *x = s->x;
    for (long k = begin; k < end; k++) {
        int r = s->rows[k];
        const int *n = nb + 6 * (size_t)r;
        const double *o = off + 6 * (size_t)r;
        double t = b[r] - (o[0] * x[n[0]] + o[1] * x[n[1]]) - (o[2] * x[n[2]] + o[3] * x[n[3]]) -
                   (o[4] * x[n[4]] + o[5] * x[n[5]]);
        x[r] = t * inv[r];
    }
}

static void half_sweep(const MgLevel *l, bool red, const double *b, double *x)
{
    SweepCtx s = {l, red ? l->order : l->order + l->nred, b, x};
    dr_parallel_for(red ? l->nred : l->n - l->nred, MG_PAR_MIN_ROWS, sweep_rows, &s);
}

/* b_c[R] = Σ over the children r of R of (b − A x)_r, in a fixed child order. */
typedef struct RestrictCtx { const MgLevel *f, *c; const double *b, *x; double *bc; } RestrictCtx;

static void restrict_rows(long begin, long end, void *vctx)
{
    const RestrictCtx *s = vctx;
    const MgLevel *f = s->f, *c = s->c;
    for (long R = begin; R < end; R++) {
        int cc[3];
        cell_ijk(c, c->cell[R], cc);
        double sum = 0.0;
        for (int dz = 0; dz < 2; dz++)
            for (int dy = 0; dy < 2; dy++)
                for (int dx = 0; dx < 2; dx++) {
                    int i = 2 * cc[0] + dx, j = 2 * cc[1] + dy, k = 2 * cc[2] + dz;
                    if (i >= f->dims[0] || j >= f->dims[1] || k >= f->dims[2]) continue;
                    int r = f->map[i + (long)f->dims[0] * (j + (long)f->dims[1] * k)];
                    if (r < 0) continue;
                    const int *n = f->nb + 6 * (size_t)r;
                    const double *o = f->off + 6 * (size_t)r;
                    const double *x = s->x;
                    double ax = f->diag[r] * x[r] + (o[0] * x[n[0]] + o[1] * x[n[1]]) +
                                (o[2] * x[n[2]] + o[3] * x[n[3]]) + (o[4] * x[n[4]] + o[5] * x[n[5]]);
                    sum += s->b[r] - ax;
                }
        s->bc[R] = sum;
    }
}

typedef struct ProlongCtx { const MgLevel *f; const double *xc; double *x; } ProlongCtx;

static void prolong_rows(long begin, long end, void *vctx)
{
    const ProlongCtx *s = vctx;
    for (long r = begin; r < end; r++) s->x[r] += s->xc[s->f->parent[r]];
}

static void vcycle(const DrMg *M, const double *b0, double *x0)
{
    const int nl = M->nlevels, nu = M->d.sweeps;
    if (nl == 1) {
        coarsest_solve(M, b0, x0);
        return;
    }
    for (int l = 0; l < nl - 1; l++) {
        const MgLevel *f = &M->lv[l], *c = &M->lv[l + 1];
        const double *b = l == 0 ? b0 : f->b;
        double *x = l == 0 ? x0 : f->x;
        memset(x, 0, (size_t)f->n * sizeof(double));
        for (int s = 0; s < nu; s++) {
            half_sweep(f, true, b, x);
            half_sweep(f, false, b, x);
        }
        RestrictCtx rc = {f, c, b, x, c->b};
        dr_parallel_for(c->n, MG_PAR_MIN_ROWS / 8, restrict_rows, &rc);
    }
    const MgLevel *bottom = &M->lv[nl - 1];
    coarsest_solve(M, bottom->b, bottom->x);
    for (int l = nl - 2; l >= 0; l--) {
        const MgLevel *f = &M->lv[l], *c = &M->lv[l + 1];
        const double *b = l == 0 ? b0 : f->b;
        double *x = l == 0 ? x0 : f->x;
        ProlongCtx pc = {f, c->x, x};
        dr_parallel_for(f->n, MG_PAR_MIN_ROWS, prolong_rows, &pc);
        for (int s = 0; s < nu; s++) {
            half_sweep(f, false, b, x);
            half_sweep(f, true, b, x);
        }
    }
}

static void mg_apply(const double *r, double *z, void *ctx) { vcycle(ctx, r, z); }

DrLinearOp dr_mg_op(const DrMg *M)
{
    DrLinearOp op = {M->nlevels > 0 ? M->lv[0].n : 0, mg_apply, (void *)M};
    return op;
}
