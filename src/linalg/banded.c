/* Banded symmetric positive definite matrices: storage, assembly, and LAPACK's banded Cholesky (see
 * linalg.h). LAPACK rather than CHOLMOD: a hair's block is a narrow band (a rod couples a vertex to its
 * neighbours two edges away), for which dpbtrf's O(n kd²) dense-band kernel beats a general sparse
 * factorisation's symbolic analysis and indexing, and one block per hair is factored every step. */
#include "linalg/linalg.h"

#include <stdlib.h>
#include <string.h>

/* LAPACK (Fortran) through OpenBLAS; the trailing size_t is the hidden length of the `uplo` string that
   gfortran-built LAPACK expects. */
extern void dpbtrf_(const char *uplo, const int *n, const int *kd, double *ab, const int *ldab, int *info, size_t);
extern void dpbtrs_(const char *uplo, const int *n, const int *kd, const int *nrhs, const double *ab, const int *ldab,
                    double *b, const int *ldb, int *info, size_t);

DrStatus dr_banded_create(int n, int kd, DrBanded **out, DrError *err)
{
    *out = NULL;
    if (n < 1 || kd < 0 || kd >= n)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "banded matrix of size %d with bandwidth %d: need n >= 1 and 0 <= kd < n", n, kd);
    DrBanded *b = NULL;
    DR_TRY(dr_calloc(1, sizeof *b, &b, err));
    DrStatus s = dr_calloc((size_t)(kd + 1) * (size_t)n, sizeof(double), &b->ab, err);
    if (s < 0) {
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
    b->factored = true;
    return DR_OK;
}

void dr_banded_solve(const DrBanded *b, double *x, int nrhs)
{
    assert(b->factored && nrhs >= 0);
    if (nrhs == 0) return;
    int info = 0, ldab = b->kd + 1, ldb = b->n;
    dpbtrs_("L", &b->n, &b->kd, &nrhs, b->ab, &ldab, x, &ldb, &info, 1);
    assert(info == 0);
}
