/* Banded symmetric positive definite matrices: storage, assembly, and LAPACK's banded Cholesky (see
 * linalg.h). LAPACK rather than CHOLMOD: a hair's block is a narrow band (a rod couples a vertex to its
 * neighbours two edges away), for which dpbtrf's O(n kd²) dense-band kernel beats a general sparse
 * factorisation's symbolic analysis and indexing, and one block per hair is factored every step. */
#include "linalg/linalg.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>

/* LAPACK (Fortran) through OpenBLAS; the trailing size_t is the hidden length of the `uplo` string that
   gfortran-built LAPACK expects. */
extern void dpbtrf_(const char *uplo, const int *n, const int *kd, double *ab, const int *ldab, int *info, size_t);

/* OpenBLAS's own threads are turned off: the callers factor many small blocks in parallel themselves (one
   per hair), and OpenBLAS threads inside those parallel loops oversubscribe the cores (measured: a 576-hair
   step took 2.0 s on 2 threads against 0.48 s on one, 0.38 s with OpenBLAS single-threaded). */
extern void openblas_set_num_threads(int);
static pthread_once_t blas_once = PTHREAD_ONCE_INIT;
static void blas_single_thread(void) { openblas_set_num_threads(1); }

DrStatus dr_banded_create(int n, int kd, DrBanded **out, DrError *err)
{
    pthread_once(&blas_once, blas_single_thread);
    *out = NULL;
    if (n < 1 || kd < 0 || kd >= n)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "banded matrix of size %d with bandwidth %d: need n >= 1 and 0 <= kd < n", n, kd);
    DrBanded *b = NULL;
    DR_TRY(dr_calloc(1, sizeof *b, &b, err));
    DrStatus s = dr_calloc((size_t)(kd + 1) * (size_t)n, sizeof(double), &b->ab, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof(double), &b->inv_diag, err);
    if (s < 0) {
        free(b->ab);
        free(b);
        return s;
    }
    b->n = n;
    b->kd = kd;
    *out = b;
    return DR_OK;
}

void dr_banded_destroy(DrBanded **b)
{
    if (!b || !*b) return;
    free((*b)->ab);
    free((*b)->inv_diag);
    free(*b);
    *b = NULL;
}

void dr_banded_zero(DrBanded *b)
{
    memset(b->ab, 0, (size_t)(b->kd + 1) * (size_t)b->n * sizeof(double));
    b->factored = false;
}

void dr_banded_add(DrBanded *b, int i, int j, double v)
{
    if (i < j) {
        int t = i;
        i = j;
        j = t;
    }
    assert(!b->factored && j >= 0 && i < b->n && i - j <= b->kd);
    b->ab[(i - j) + (b->kd + 1) * j] += v;
}

DrStatus dr_banded_factor(DrBanded *b, DrError *err)
{
    assert(!b->factored);
    int info = 0, ldab = b->kd + 1;
    dpbtrf_("L", &b->n, &b->kd, b->ab, &ldab, &info, 1);
    assert(info >= 0); /* a negative info is an argument our own code got wrong */
    if (info > 0)
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "banded matrix (n %d, bandwidth %d) is not positive definite: its leading minor of order "
                            "%d is not",
                            b->n, b->kd, info);
    for (int j = 0; j < b->n; j++) b->inv_diag[j] = 1.0 / b->ab[(size_t)(b->kd + 1) * (size_t)j];
    b->factored = true;
    return DR_OK;
}

/* The two triangular solves with the factor, written out: for the narrow bands of this project (kd ≈ 10, n of
   tens to hundreds) dpbtrs's per-column BLAS calls cost more than the arithmetic (measured: a 576-hair step
   spent 30 % of its time in OpenBLAS's dtbsv/daxpy call overhead). The loops visit L by columns as stored, and
   multiply by the stored reciprocals of the diagonal: a division's latency sits on the substitution's
   dependency chain. */
void dr_banded_solve(const DrBanded *b, double *x, int nrhs)
{
    assert(b->factored && nrhs >= 0);
    int n = b->n, kd = b->kd, ld = kd + 1;
    const double *L = b->ab;
    for (int r = 0; r < nrhs; r++) {
        double *y = x + (size_t)n * (size_t)r;
        /* L y = rhs */
        for (int j = 0; j < n; j++) {
            const double *c = L + (size_t)ld * (size_t)j;
            double yj = y[j] * b->inv_diag[j];
            y[j] = yj;
            int top = j + kd < n - 1 ? j + kd : n - 1;
            for (int i = j + 1; i <= top; i++) y[i] -= c[i - j] * yj;
        }
        /* Lᵀ x = y */
        for (int j = n - 1; j >= 0; j--) {
            const double *c = L + (size_t)ld * (size_t)j;
            double acc = y[j];
            int top = j + kd < n - 1 ? j + kd : n - 1;
            for (int i = j + 1; i <= top; i++) acc -= c[i - j] * y[i];
            y[j] = acc * b->inv_diag[j];
        }
    }
}
