/* Benchmark: PCG on the pressure matrix of a box of liquid in a tank (7-point Poisson, solid walls on
 * the sides and bottom as Neumann faces, a free surface on top as a ghost-fluid Dirichlet face) at
 * 32^3, 64^3 and 128^3, with MIC(0), Jacobi and no preconditioner, to rel_tol 1e-6.
 *
 * Usage: bench_pcg [out.csv]   (default out/bench/pcg.csv; parent directories are created)
 * CSV header: resolution,unknowns,preconditioner,iterations,seconds,rel_residual
 * A markdown table of the same rows goes to stdout. Seconds include building the preconditioner. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "core/core.h"
#include "linalg/linalg.h"

static DrStatus build_tank(int res, DrCsr **out, DrError *err)
{
    int n = res * res * res;
    DR_TRY(dr_csr_create(n, 7 * n, out, err));
    DrCsr *A = *out;
    for (int z = 0; z < res; z++)
        for (int y = 0; y < res; y++)
            for (int x = 0; x < res; x++) {
                int i = x + res * (y + res * z);
                double diag = 0.0;
                int nb[6] = {z > 0 ? i - res * res : -1, y > 0 ? i - res : -1, x > 0 ? i - 1 : -1,
                             x < res - 1 ? i + 1 : -1, y < res - 1 ? i + res : -1,
                             z < res - 1 ? i + res * res : -1};
                for (int f = 0; f < 6; f++)
                    if (nb[f] >= 0) diag += 1.0;
                if (y == res - 1) diag += 1.0; /* air above the top layer: p = 0 one cell up */
                int k = A->nnz;
                for (int f = 0; f < 3; f++)
                    if (nb[f] >= 0) A->col[k] = nb[f], A->val[k++] = -1.0;
                A->col[k] = i, A->val[k++] = diag;
                for (int f = 3; f < 6; f++)
                    if (nb[f] >= 0) A->col[k] = nb[f], A->val[k++] = -1.0;
                A->nnz = k;
                A->rowptr[i + 1] = k;
            }
    return dr_csr_check(A, err);
}

static int make_parent_dirs(const char *path)
{
    char buf[4096];
    if (strlen(path) >= sizeof buf) return -1;
    strcpy(buf, path);
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/') continue;
        *p = '\0';
        if (mkdir(buf, 0777) != 0 && errno != EEXIST) return -1;
        *p = '/';
    }
    return 0;
}

int main(int argc, char **argv)
{
    const char *path = argc > 1 ? argv[1] : "out/bench/pcg.csv";
    if (make_parent_dirs(path) != 0) {
        fprintf(stderr, "bench_pcg: cannot create the directories of %s: %s\n", path, strerror(errno));
        return 1;
    }
    FILE *csv = fopen(path, "w");
    if (!csv) {
        fprintf(stderr, "bench_pcg: cannot write %s: %s\n", path, strerror(errno));
        return 1;
    }
    fprintf(csv, "resolution,unknowns,preconditioner,iterations,seconds,rel_residual\n");
    printf("| resolution | unknowns | preconditioner | iterations | seconds | rel. residual |\n");
    printf("| --- | ---: | --- | ---: | ---: | ---: |\n");

    const int resolutions[3] = {32, 64, 128};
    const char *names[3] = {"mic0", "jacobi", "none"};
    DrError err;
    int rc = 0;
    for (int r = 0; r < 3 && rc == 0; r++) {
        int res = resolutions[r], n = res * res * res;
        DrCsr *A = NULL;
        double *b = NULL, *x = NULL, *work = NULL;
        if (build_tank(res, &A, &err) != DR_OK || dr_calloc((size_t)n, sizeof(double), &b, &err) != DR_OK ||
            dr_calloc((size_t)n, sizeof(double), &x, &err) != DR_OK ||
            dr_calloc(4 * (size_t)n, sizeof(double), &work, &err) != DR_OK) {
            dr_error_print("bench_pcg", &err);
            rc = 1;
        }
        /* A divergence-like right-hand side: uniform noise in [-1, 1) from a fixed seed. */
        DrRng rng;
        dr_rng_seed(&rng, 2024);
        for (int i = 0; rc == 0 && i < n; i++) b[i] = 2.0 * dr_rng_uniform(&rng) - 1.0;
        for (int p = 0; p < 3 && rc == 0; p++) {
            memset(x, 0, (size_t)n * sizeof(double));
            double t0 = dr_time_now();
            DrMic0 *mic = NULL;
            DrJacobi *jac = NULL;
            DrLinearOp op = dr_csr_op(A), m = {0};
            DrStatus s = DR_OK;
            if (p == 0) {
                s = dr_mic0_create(A, DR_MIC0_TAU_DEFAULT, DR_MIC0_SIGMA_DEFAULT, &mic, &err);
                if (s == DR_OK) m = dr_mic0_op(mic);
            } else if (p == 1) {
                s = dr_jacobi_create(A, &jac, &err);
                if (s == DR_OK) m = dr_jacobi_op(jac);
            }
            DrPcgDesc d;
            dr_pcg_desc_default(&d);
            d.rel_tol = 1e-6;
            d.max_iter = 20000;
            DrPcgStats st = {0, 0.0, 0.0, false};
            if (s == DR_OK) s = dr_pcg_solve(&op, p == 2 ? NULL : &m, b, x, &d, work, &st, &err);
            double secs = dr_time_now() - t0;
            dr_mic0_destroy(&mic);
            dr_jacobi_destroy(&jac);
            if (DR_FAILED(s)) {
                dr_error_print("bench_pcg", &err);
                rc = 1;
                break;
            }
            fprintf(csv, "%d,%d,%s,%d,%.6f,%.3e\n", res, n, names[p], st.iterations, secs, st.rel_residual);
            printf("| %d^3 | %d | %s | %d | %.3f | %.2e |\n", res, n, names[p], st.iterations, secs,
                   st.rel_residual);
            fflush(stdout);
        }
        free(b), free(x), free(work);
        dr_csr_destroy(&A);
    }
    if (fclose(csv) != 0 && rc == 0) {
        fprintf(stderr, "bench_pcg: error closing %s: %s\n", path, strerror(errno));
        rc = 1;
    }
    if (rc == 0) printf("\nthreads: %d; CSV written to %s\n", dr_threads(), path);
    return rc;
}
