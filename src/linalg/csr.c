/* CSR storage, validation and the parallel matrix-vector product. */
#include "linalg/linalg.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

DrStatus dr_csr_create(int n, int nnz_capacity, DrCsr **out, DrError *err)
{
    *out = NULL;
    if (n < 0 || nnz_capacity < 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "CSR matrix of size %d with capacity %d: sizes must be >= 0", n, nnz_capacity);
    DrCsr *A = NULL;
    DR_TRY(dr_calloc(1, sizeof(DrCsr), &A, err));
    DrStatus s = dr_calloc((size_t)n + 1, sizeof(int), &A->rowptr, err);
    if (s == DR_OK) s = dr_calloc((size_t)nnz_capacity, sizeof(int), &A->col, err);
    if (s == DR_OK) s = dr_calloc((size_t)nnz_capacity, sizeof(double), &A->val, err);
    if (s != DR_OK) {
        dr_csr_destroy(&A);
        return s;
    }
    A->n = n;
    A->nnz = 0;
    A->n_capacity = n;
    A->nnz_capacity = nnz_capacity;
    *out = A;
    return DR_OK;
}

void dr_csr_destroy(DrCsr **A)
{
    if (!A || !*A) return;
    free((*A)->rowptr);
    free((*A)->col);
    free((*A)->val);
    free(*A);
    *A = NULL;
}

/* Grows a request by a quarter so that a liquid whose cell count creeps up each substep does not
 * reallocate every substep; saturates at INT_MAX (indices are int). */
static int grown(int request)
{
    long g = (long)request + request / 4;
    return g > INT_MAX ? INT_MAX : (int)g;
}

DrStatus dr_csr_reserve(DrCsr *A, int n, int nnz_capacity, DrError *err)
{
    assert(A);
    if (n < 0 || nnz_capacity < 0 || n == INT_MAX)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "CSR reserve of size %d with capacity %d: sizes must be >= 0 and < INT_MAX", n,
                            nnz_capacity);
    if (n > A->n_capacity) {
        int cap = grown(n);
        if (cap == INT_MAX) cap = INT_MAX - 1;
        DR_TRY(dr_realloc((size_t)cap + 1, sizeof(int), &A->rowptr, err));
        A->n_capacity = cap;
    }
    if (nnz_capacity > A->nnz_capacity) {
        int cap = grown(nnz_capacity);
        /* If val fails after col grew, col is merely larger than nnz_capacity records: still valid. */
        DR_TRY(dr_realloc((size_t)cap, sizeof(int), &A->col, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof(double), &A->val, err));
        A->nnz_capacity = cap;
    }
    A->n = n;
    A->nnz = 0;
    memset(A->rowptr, 0, ((size_t)n + 1) * sizeof(int));
    return DR_OK;
}

DrStatus dr_csr_check(const DrCsr *A, DrError *err)
{
    assert(A);
    if (A->n < 0 || A->n > A->n_capacity || A->nnz < 0 || A->nnz > A->nnz_capacity)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "CSR matrix: n = %d, nnz = %d exceed the reserved capacity (%d rows, %d entries); "
                            "call dr_csr_reserve before filling it", A->n, A->nnz, A->n_capacity,
                            A->nnz_capacity);
    if (A->rowptr[0] != 0 || A->rowptr[A->n] != A->nnz)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "CSR matrix: rowptr[0] = %d and rowptr[n] = %d must be 0 and nnz = %d",
                            A->rowptr[0], A->rowptr[A->n], A->nnz);
    for (int i = 0; i < A->n; i++) {
        int b = A->rowptr[i], e = A->rowptr[i + 1];
        if (e < b)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "CSR matrix: rowptr decreases at row %d (%d > %d)", i, b, e);
        for (int k = b; k < e; k++) {
            int c = A->col[k];
            if (c < 0 || c >= A->n)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "CSR matrix: row %d has column %d outside [0, %d)", i, c, A->n);
            if (k > b && c <= A->col[k - 1])
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "CSR matrix: row %d columns not strictly increasing (%d after %d); sort "
                                    "each row and merge duplicates", i, c, A->col[k - 1]);
            if (!isfinite(A->val[k]))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "CSR matrix: entry (%d, %d) = %g is not finite", i, c, A->val[k]);
        }
    }
    return DR_OK;
}

typedef struct MatvecCtx { const DrCsr *A; const double *x; double *y; } MatvecCtx;

static void matvec_range(long begin, long end, void *vctx)
{
    const MatvecCtx *c = vctx;
    const int *rowptr = c->A->rowptr, *col = c->A->col;
    const double *val = c->A->val, *x = c->x;
    for (long i = begin; i < end; i++) {
        double s = 0.0;
        for (int k = rowptr[i]; k < rowptr[i + 1]; k++) s += val[k] * x[col[k]];
        c->y[i] = s;
    }
}

void dr_csr_matvec(const DrCsr *A, const double *x, double *y)
{
    MatvecCtx c = {A, x, y};
    /* 8192 rows (about 57k nonzeros for a 7-point stencil) per thread at least: below that the
     * parallel region costs as much as it saves. */
    dr_parallel_for(A->n, 8192, matvec_range, &c);
}

static void csr_apply(const double *x, double *y, void *ctx) { dr_csr_matvec(ctx, x, y); }

DrLinearOp dr_csr_op(const DrCsr *A)
{
    DrLinearOp op = {A->n, csr_apply, (void *)A};
    return op;
}
