/* Preconditioners: modified incomplete Cholesky MIC(0) and Jacobi. */
#include "linalg/linalg.h"

#include <stdlib.h>
#include <string.h>

/* Shared validation: structure, finite values, and a non-negative diagonal (a negative A_ii rules out
 * positive semidefiniteness, so neither preconditioner could be positive definite). */
static DrStatus check_spd_candidate(const DrCsr *A, const char *who, DrError *err)
{
    DR_TRY(dr_csr_check(A, err));
    for (int i = 0; i < A->n; i++)
        for (int k = A->rowptr[i]; k < A->rowptr[i + 1]; k++)
            if (A->col[k] == i && A->val[k] < 0.0)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "%s: diagonal entry A[%d][%d] = %g is negative, so the matrix is not "
                                    "positive semidefinite; check the sign convention of the assembly", who, i,
                                    i, A->val[k]);
    return DR_OK;
}

/* ---- MIC(0) ------------------------------------------------------------------------------------ */

struct DrMic0 {
    int n;
    double tau;   /* τ: fraction of dropped fill moved to the diagonal (Bridson: 0.97) */
    double sigma; /* σ: safety, pivots below σ A_jj fall back to A_jj (Bridson: 0.25) */
    int fallbacks;
    int n_capacity, nnz_capacity;
    int *uptr;     /* n+1: rows of U (strict upper triangle, unit diagonal implied) */
    int *ucol;     /* columns of U, increasing per row */
    double *uval;  /* during factorisation the working values of A's upper triangle, then U */
    double *d;     /* pivots being accumulated (the D of Uᵀ D U) */
    double *inv_d; /* 1 / d_j used by the application */
    double *adiag; /* A_jj for the σ test */
};

static void mic0_free_arrays(DrMic0 *M)
{
    free(M->uptr);
    free(M->ucol);
    free(M->uval);
    free(M->d);
    free(M->inv_d);
    free(M->adiag);
    M->uptr = M->ucol = NULL;
    M->uval = M->d = M->inv_d = M->adiag = NULL;
    M->n_capacity = M->nnz_capacity = 0;
}

static DrStatus mic0_reserve(DrMic0 *M, int n, int nnz, DrError *err)
{
    if (n > M->n_capacity || !M->uptr) {
        DR_TRY(dr_realloc((size_t)n + 1, sizeof(int), &M->uptr, err));
        DR_TRY(dr_realloc((size_t)n, sizeof(double), &M->d, err));
        DR_TRY(dr_realloc((size_t)n, sizeof(double), &M->inv_d, err));
        DR_TRY(dr_realloc((size_t)n, sizeof(double), &M->adiag, err));
        M->n_capacity = n;
    }
    if (nnz > M->nnz_capacity) {
        DR_TRY(dr_realloc((size_t)nnz, sizeof(int), &M->ucol, err));
        DR_TRY(dr_realloc((size_t)nnz, sizeof(double), &M->uval, err));
        M->nnz_capacity = nnz;
    }
    return DR_OK;
}

/* Right-looking incomplete factorisation A ≈ Uᵀ D U on the pattern of A's upper triangle.
 * Eliminating unknown j updates the trailing matrix by w_jm1 w_jm2 / d_j for every pair m1 <= m2 of
 * upper neighbours of j (w the working values). On the pattern the update is applied exactly (IC(0));
 * off the pattern it is dropped and, for MIC, τ times it is taken off both diagonals so that M's row
 * sums match A's. For a 7-point stencil in lexicographic order no fill lands on the pattern, the
 * off-diagonals of U stay A_jm / d_j, and the pivots reduce to Bridson's formula (Fluid Simulation for
 * Computer Graphics, MIC(0) pseudocode of the pressure chapter, with d_i = E_i²):
 *   d_i = A_ii − Σ_{j<i} A_ij² / d_j − τ Σ_{j<i} A_ij (Σ_{k>j, k≠i} A_jk) / d_j. */
static void mic0_factor(DrMic0 *M)
{
    const int n = M->n;
    const int *uptr = M->uptr, *ucol = M->ucol;
    double *uval = M->uval, *d = M->d;
    const double tau = M->tau, sigma = M->sigma;
    int fallbacks = 0;
    for (int j = 0; j < n; j++) {
        double a = M->adiag[j], dj = d[j];
        if (a == 0.0) {
            dj = 1.0; /* decoupled unknown (PSD ⇒ its row is zero): identity */
        } else if (!(dj >= sigma * a) || !(dj > 0.0)) {
            dj = a;
            fallbacks++;
        }
        double inv = 1.0 / dj;
        int b = uptr[j], e = uptr[j + 1];
        for (int k1 = b; k1 < e; k1++) {
            int m1 = ucol[k1];
            double w1 = uval[k1] * inv;
            d[m1] -= w1 * uval[k1];
            /* Merge-walk row m1 of U against the remaining columns m2 > m1 of row j. */
            int p = uptr[m1], pe = uptr[m1 + 1];
            for (int k2 = k1 + 1; k2 < e; k2++) {
                int m2 = ucol[k2];
                double upd = w1 * uval[k2];
                while (p < pe && ucol[p] < m2) p++;
                if (p < pe && ucol[p] == m2) {
                    uval[p] -= upd;
                } else {
                    d[m1] -= tau * upd;
                    d[m2] -= tau * upd;
                }
            }
        }
        for (int k = b; k < e; k++) uval[k] *= inv;
        d[j] = dj;
        M->inv_d[j] = inv;
    }
    M->fallbacks = fallbacks;
}

/* Copies A's lower triangle, transposed, into U's storage (row j of U = column j of the lower
 * triangle), and A's diagonal into d and adiag. Rows of A are walked in increasing order, so each row
 * of U receives its columns in increasing order. uptr doubles as the fill cursor. */
static void mic0_load(DrMic0 *M, const DrCsr *A)
{
    const int n = A->n;
    int *uptr = M->uptr;
    memset(uptr, 0, ((size_t)n + 1) * sizeof(int));
    for (int i = 0; i < n; i++) {
        M->adiag[i] = 0.0;
        for (int k = A->rowptr[i]; k < A->rowptr[i + 1]; k++) {
            int c = A->col[k];
            if (c < i) uptr[c + 1]++;
            else if (c == i) M->adiag[i] = A->val[k];
        }
    }
    for (int j = 0; j < n; j++) uptr[j + 1] += uptr[j];
    for (int i = 0; i < n; i++) {
        for (int k = A->rowptr[i]; k < A->rowptr[i + 1]; k++) {
            int c = A->col[k];
            if (c >= i) break;
            int pos = uptr[c]++;
            M->ucol[pos] = i;
            M->uval[pos] = A->val[k];
        }
    }
    /* The cursors advanced each uptr[c] to the start of row c+1: shift back. */
    for (int j = n; j > 0; j--) uptr[j] = uptr[j - 1];
    uptr[0] = 0;
    for (int i = 0; i < n; i++) M->d[i] = M->adiag[i];
}

static int lower_count(const DrCsr *A)
{
    int count = 0;
    for (int i = 0; i < A->n; i++)
        for (int k = A->rowptr[i]; k < A->rowptr[i + 1] && A->col[k] < i; k++) count++;
    return count;
}

DrStatus dr_mic0_update(DrMic0 *M, const DrCsr *A, DrError *err)
{
    assert(M && A);
    M->n = 0; /* unusable until the factorisation below completes */
    DR_TRY(check_spd_candidate(A, "MIC(0)", err));
    DR_TRY(mic0_reserve(M, A->n, lower_count(A), err));
    M->n = A->n;
    mic0_load(M, A);
    mic0_factor(M);
    return DR_OK;
}

DrStatus dr_mic0_create(const DrCsr *A, double tau, double sigma, DrMic0 **out, DrError *err)
{
    *out = NULL;
    if (!(tau >= 0.0 && tau <= 1.0) || !(sigma >= 0.0 && sigma <= 1.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "MIC(0): tau = %g must be in [0, 1] and sigma = %g in [0, 1] (Bridson uses 0.97 "
                            "and 0.25)", tau, sigma);
    DrMic0 *M = NULL;
    DR_TRY(dr_calloc(1, sizeof(DrMic0), &M, err));
    M->tau = tau;
    M->sigma = sigma;
    DrStatus s = dr_mic0_update(M, A, err);
    if (s != DR_OK) {
        dr_mic0_destroy(&M);
        return s;
    }
    *out = M;
    return DR_OK;
}

void dr_mic0_destroy(DrMic0 **M)
{
    if (!M || !*M) return;
    mic0_free_arrays(*M);
    free(*M);
    *M = NULL;
}

int dr_mic0_fallbacks(const DrMic0 *M) { return M->fallbacks; }

/* z = (Uᵀ D U)⁻¹ r: forward substitution with Uᵀ by columns (scatter), scaling by D⁻¹ folded in, then
 * backward substitution with U by rows. Each step depends on the previous one: sequential. */
static void mic0_apply(const double *r, double *z, void *ctx)
{
    const DrMic0 *M = ctx;
    const int n = M->n;
    const int *uptr = M->uptr, *ucol = M->ucol;
    const double *uval = M->uval, *inv_d = M->inv_d;
    memcpy(z, r, (size_t)n * sizeof(double));
    for (int j = 0; j < n; j++) {
        double yj = z[j];
        for (int k = uptr[j]; k < uptr[j + 1]; k++) z[ucol[k]] -= uval[k] * yj;
        z[j] = yj * inv_d[j];
    }
    for (int j = n - 1; j >= 0; j--) {
        double s = z[j];
        for (int k = uptr[j]; k < uptr[j + 1]; k++) s -= uval[k] * z[ucol[k]];
        z[j] = s;
    }
}

DrLinearOp dr_mic0_op(const DrMic0 *M)
{
    DrLinearOp op = {M->n, mic0_apply, (void *)M};
    return op;
}

/* ---- Jacobi ------------------------------------------------------------------------------------ */

struct DrJacobi {
    int n, capacity;
    double *inv_diag;
};

DrStatus dr_jacobi_update(DrJacobi *M, const DrCsr *A, DrError *err)
{
    assert(M && A);
    M->n = 0;
    DR_TRY(check_spd_candidate(A, "Jacobi", err));
    if (A->n > M->capacity) {
        DR_TRY(dr_realloc((size_t)A->n, sizeof(double), &M->inv_diag, err));
        M->capacity = A->n;
    }
    for (int i = 0; i < A->n; i++) {
        double a = 0.0;
        for (int k = A->rowptr[i]; k < A->rowptr[i + 1]; k++)
            if (A->col[k] == i) a = A->val[k];
        M->inv_diag[i] = a > 0.0 ? 1.0 / a : 1.0;
    }
    M->n = A->n;
    return DR_OK;
}

DrStatus dr_jacobi_create(const DrCsr *A, DrJacobi **out, DrError *err)
{
    *out = NULL;
    DrJacobi *M = NULL;
    DR_TRY(dr_calloc(1, sizeof(DrJacobi), &M, err));
    DrStatus s = dr_jacobi_update(M, A, err);
    if (s != DR_OK) {
        dr_jacobi_destroy(&M);
        return s;
    }
    *out = M;
    return DR_OK;
}

void dr_jacobi_destroy(DrJacobi **M)
{
    if (!M || !*M) return;
    free((*M)->inv_diag);
    free(*M);
    *M = NULL;
}

typedef struct JacobiCtx { const double *inv, *r; double *z; } JacobiCtx;

static void jacobi_range(long begin, long end, void *vctx)
{
    const JacobiCtx *c = vctx;
    for (long i = begin; i < end; i++) c->z[i] = c->inv[i] * c->r[i];
}

static void jacobi_apply(const double *r, double *z, void *ctx)
{
    const DrJacobi *M = ctx;
    JacobiCtx c = {M->inv_diag, r, z};
    dr_parallel_for(M->n, 32768, jacobi_range, &c);
}

DrLinearOp dr_jacobi_op(const DrJacobi *M)
{
    DrLinearOp op = {M->n, jacobi_apply, (void *)M};
    return op;
}
