/* Benchmark: PCG on the pressure matrix of a box of liquid in a tank (7-point Poisson, solid walls on
 * the sides and bottom as Neumann faces, a free surface on top as a ghost-fluid Dirichlet face) at
 * 32^3, 64^3, 96^3 and 128^3, to rel_tol 1e-6, with the multigrid V-cycle (dr_mg, default desc) and MIC(0)
 * on 1 and 2 threads, and with Jacobi and no preconditioner on the default thread count up to 64^3 (their
 * iteration counts grow linearly with the resolution; 128^3 takes minutes).
 *
 * Usage: bench_pcg [out.csv]   (default out/bench/pcg.csv; parent directories are created)
 * CSV header: resolution,unknowns,preconditioner,threads,iterations,seconds,setup_seconds,solve_seconds,
 * rel_residual. seconds = setup_seconds (building the preconditioner) + solve_seconds (PCG).
 * A markdown table of the same rows goes to stdout. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "core/core.h"
#include "linalg/linalg.h"

/* The tank's matrix and the cell of each row (row i = cell (x, y, z), i = x + res (y + res z)). */
static DrStatus build_tank(int res, DrCsr **out, int *ijk, DrError *err)
{
    int n = res * res * res;
    DR_TRY(dr_csr_create(n, 7 * n, out, err));
    DrCsr *A = *out;
    for (int z = 0; z < res; z++)
        for (int y = 0; y < res; y++)
            for (int x = 0; x < res; x++) {
                int i = x + res * (y + res * z);
                ijk[3 * i] = x, ijk[3 * i + 1] = y, ijk[3 * i + 2] = z;
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

enum { P_MG, P_MIC0, P_JACOBI, P_NONE };
static const char *const names[4] = {"multigrid", "mic0", "jacobi", "none"};

/* One solve from x = 0; fills the row of the table. Returns the status of the failure, if any. */
static DrStatus run(const DrCsr *A, const int *ijk, int res, int p, const double *b, double *x, double *work,
                    FILE *csv, DrError *err)
{
    int n = A->n;
    memset(x, 0, (size_t)n * sizeof(double));
    double t0 = dr_time_now();
    DrMic0 *mic = NULL;
    DrJacobi *jac = NULL;
    DrMg *mg = NULL;
    DrLinearOp op = dr_csr_op(A), m = {0};
    DrStatus s = DR_OK;
    int dims[3] = {res, res, res};
    if (p == P_MG) {
        s = dr_mg_create(A, ijk, dims, NULL, &mg, err);
        if (s == DR_OK) m = dr_mg_op(mg);
    } else if (p == P_MIC0) {
        s = dr_mic0_create(A, DR_MIC0_TAU_DEFAULT, DR_MIC0_SIGMA_DEFAULT, &mic, err);
        if (s == DR_OK) m = dr_mic0_op(mic);
    } else if (p == P_JACOBI) {
        s = dr_jacobi_create(A, &jac, err);
        if (s == DR_OK) m = dr_jacobi_op(jac);
    }
    double t1 = dr_time_now();
    DrPcgDesc d;
    dr_pcg_desc_default(&d);
    d.rel_tol = 1e-6;
    d.max_iter = 20000;
    DrPcgStats st = {0, 0.0, 0.0, false};
    if (s == DR_OK) s = dr_pcg_solve(&op, p == P_NONE ? NULL : &m, b, x, &d, work, &st, err);
    double t2 = dr_time_now();
    dr_mic0_destroy(&mic);
    dr_jacobi_destroy(&jac);
    dr_mg_destroy(&mg);
    if (DR_FAILED(s)) return s;
    fprintf(csv, "%d,%d,%s,%d,%d,%.6f,%.6f,%.6f,%.3e\n", res, n, names[p], dr_threads(), st.iterations, t2 - t0,
            t1 - t0, t2 - t1, st.rel_residual);
    printf("| %d^3 | %d | %s | %d | %d | %.3f | %.3f | %.3f | %.2e |\n", res, n, names[p], dr_threads(),
           st.iterations, t2 - t0, t1 - t0, t2 - t1, st.rel_residual);
    fflush(stdout);
    return DR_OK;
}

int main(int argc, char **argv)
{
    dr_thread_defaults(argv);
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
    fprintf(csv, "resolution,unknowns,preconditioner,threads,iterations,seconds,setup_seconds,solve_seconds,"
                 "rel_residual\n");
    printf("| resolution | unknowns | preconditioner | threads | iterations | seconds | setup | solve | rel. "
           "residual |\n");
    printf("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |\n");

    const int resolutions[4] = {32, 64, 96, 128};
    const int default_threads = dr_threads();
    DrError err;
    int rc = 0;
    for (int r = 0; r < 4 && rc == 0; r++) {
        int res = resolutions[r], n = res * res * res;
        DrCsr *A = NULL;
        int *ijk = NULL;
        double *b = NULL, *x = NULL, *work = NULL;
        if (dr_calloc(3 * (size_t)n, sizeof(int), &ijk, &err) != DR_OK || build_tank(res, &A, ijk, &err) != DR_OK ||
            dr_calloc((size_t)n, sizeof(double), &b, &err) != DR_OK ||
            dr_calloc((size_t)n, sizeof(double), &x, &err) != DR_OK ||
            dr_calloc(4 * (size_t)n, sizeof(double), &work, &err) != DR_OK) {
            dr_error_print("bench_pcg", &err);
            rc = 1;
        }
        /* A divergence-like right-hand side: uniform noise in [-1, 1) from a fixed seed. */
        DrRng rng;
        dr_rng_seed(&rng, 2024);
        for (int i = 0; rc == 0 && i < n; i++) b[i] = 2.0 * dr_rng_uniform(&rng) - 1.0;
        for (int threads = 1; threads <= 2 && rc == 0; threads++) {
            dr_set_threads(threads);
            for (int p = P_MG; p <= P_MIC0 && rc == 0; p++)
                if (run(A, ijk, res, p, b, x, work, csv, &err) != DR_OK) rc = 1;
        }
        dr_set_threads(default_threads);
        for (int p = P_JACOBI; p <= P_NONE && rc == 0 && res <= 64; p++)
            if (run(A, ijk, res, p, b, x, work, csv, &err) != DR_OK) rc = 1;
        if (rc != 0) dr_error_print("bench_pcg", &err);
        free(b), free(x), free(work), free(ijk);
        dr_csr_destroy(&A);
    }
    if (fclose(csv) != 0 && rc == 0) {
        fprintf(stderr, "bench_pcg: error closing %s: %s\n", path, strerror(errno));
        rc = 1;
    }
    if (rc == 0) printf("\nCSV written to %s\n", path);
    return rc;
}
