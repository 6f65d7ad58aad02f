/* Transfer benchmark: throughput of the collocated-grid (MPM) transfers, one particle-step being one P2G
 * (bins build included) plus one G2P of that particle (APIC, λ = 0, with the velocity gradient an MPM step
 * needs for its F update; one row with λ = ½, the midpoint rule MPM uses by default, whose G2P also gathers
 * v^n for the grid motion and the affine correction of eq. 38). 3-D, 1,048,576 particles: 8 per cell (2×2×2 jittered) in a block of
 * 64×64×32 cells, for the quadratic, cubic and linear kernels, with the particle arrays in bin order
 * ("sorted", as a solver gets by permuting with dr_node_bins_order) and, for the quadratic kernel, in the
 * order of the particle lattice, x fastest ("lattice": how dr_mpm_sample_body stores a body, and how an
 * elastic body's particles stay, neighbours remaining neighbours) and in a random order ("unsorted"), each
 * with 1 and 2 threads (dr_set_threads).
 * Each configuration runs a warm-up step and REPEATS timed steps; the fastest is kept (another process
 * taking a core for a while must not distort the table). Rates are particle-steps per second per core
 * (threads used). Writes the CSV given as argv[1] (default out/bench/transfer.csv) and a markdown table. */
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "transfer/transfer.h"

#define REPEATS 4
#define NX 64
#define NY 64
#define NZ 32

typedef struct Times { double bins, p2g, g2p; } Times;

static void die(const char *what, const DrError *err)
{
    if (err) dr_error_print("bench_transfer", err);
    else fprintf(stderr, "bench_transfer: %s\n", what);
    exit(1);
}

static void *xmalloc(size_t n)
{
    void *p = malloc(n);
    if (!p) die("out of memory", NULL);
    return p;
}

/* Permutes the 3-, 3-, 9-, 1-value particle records by perm (new p = old perm[p]). */
static void permute(long n, const long *perm, double *x, double *v, double *C, double *m)
{
    double *tx = xmalloc(sizeof(double) * 3 * (size_t)n), *tv = xmalloc(sizeof(double) * 3 * (size_t)n);
    double *tc = xmalloc(sizeof(double) * 9 * (size_t)n), *tm = xmalloc(sizeof(double) * (size_t)n);
    for (long p = 0; p < n; p++) {
        long q = perm[p];
        memcpy(tx + 3 * p, x + 3 * q, 3 * sizeof(double));
        memcpy(tv + 3 * p, v + 3 * q, 3 * sizeof(double));
        memcpy(tc + 9 * p, C + 9 * q, 9 * sizeof(double));
        tm[p] = m[q];
    }
    memcpy(x, tx, sizeof(double) * 3 * (size_t)n);
    memcpy(v, tv, sizeof(double) * 3 * (size_t)n);
    memcpy(C, tc, sizeof(double) * 9 * (size_t)n);
    memcpy(m, tm, sizeof(double) * (size_t)n);
    free(tx), free(tv), free(tc), free(tm);
}

typedef enum Order { ORDER_BINS, ORDER_LATTICE, ORDER_RANDOM } Order;

static Times run(DrKernel k, Order order, double lambda, int threads, long *np_out)
{
    const double dx = 1.0 / NX;
    int reach = dr_kernel_reach(k);
    int n[3] = {NX + 1 + 2 * reach, NY + 1 + 2 * reach, NZ + 1 + 2 * reach};
    DrNodeGrid *g = NULL;
    DrError err;
    if (dr_node_grid_create(3, n, dx, dr_v3(-reach * dx, -reach * dx, -reach * dx), k, &g, &err) != DR_OK) die(NULL, &err);
    long np = 8L * NX * NY * NZ, p = 0;
    double *x = xmalloc(sizeof(double) * 3 * (size_t)np), *v = xmalloc(sizeof(double) * 3 * (size_t)np);
    double *C = xmalloc(sizeof(double) * 9 * (size_t)np), *m = xmalloc(sizeof(double) * (size_t)np);
    double *gu = xmalloc(sizeof(double) * 9 * (size_t)np);
    DrRng rng;
    dr_rng_seed(&rng, 2024);
    for (int kz = 0; kz < NZ; kz++)
        for (int jy = 0; jy < NY; jy++)
            for (int ix = 0; ix < NX; ix++)
                for (int s = 0; s < 8; s++, p++) {
                    int c[3] = {ix, jy, kz};
                    for (int d = 0; d < 3; d++) {
                        double sub = (s >> d) & 1;
                        x[3 * p + d] = dx * (c[d] + 0.5 * (sub + 0.5 + 0.5 * (dr_rng_uniform(&rng) - 0.5)));
                        v[3 * p + d] = dr_rng_uniform(&rng) - 0.5;
                    }
                    for (int q = 0; q < 9; q++) C[9 * p + q] = dr_rng_uniform(&rng) - 0.5;
                    m[p] = 1e-6;
                }
    DrNodeBins *b = NULL;
    if (dr_node_bins_create(g, np, &b, &err) != DR_OK) die(NULL, &err);
    long *perm = xmalloc(sizeof(long) * (size_t)np);
    if (order == ORDER_BINS) {
        if (dr_node_bins_build(g, np, x, b, &err) != DR_OK) die(NULL, &err);
        memcpy(perm, dr_node_bins_order(b, NULL), sizeof(long) * (size_t)np);
    } else if (order == ORDER_LATTICE) {
        /* particle s of cell (ix, jy, kz) is lattice point (2ix + s₀, 2jy + s₁, 2kz + s₂); x fastest */
        p = 0;
        for (int kz = 0; kz < NZ; kz++)
            for (int jy = 0; jy < NY; jy++)
                for (int ix = 0; ix < NX; ix++)
                    for (int s = 0; s < 8; s++, p++) {
                        long i2 = 2 * ix + (s & 1), j2 = 2 * jy + ((s >> 1) & 1), k2 = 2 * kz + ((s >> 2) & 1);
                        perm[(k2 * 2 * NY + j2) * 2 * NX + i2] = p;
                    }
    } else {
        for (long q = 0; q < np; q++) perm[q] = q;
        for (long q = np - 1; q > 0; q--) {
            long r = (long)(dr_rng_uniform(&rng) * (double)(q + 1)), t = perm[q];
            perm[q] = perm[r];
            perm[r] = t;
        }
    }
    permute(np, perm, x, v, C, m);
    free(perm);
    double *vold = xmalloc(sizeof(double) * 3 * (size_t)g->nnodes);
    dr_set_threads(threads);
    Times best = {INFINITY, INFINITY, INFINITY};
    double best_total = INFINITY;
    for (int rep = 0; rep <= REPEATS; rep++) {
        double t0 = dr_time_now();
        if (dr_node_bins_build(g, np, x, b, &err) != DR_OK) die(NULL, &err);
        double t1 = dr_time_now();
        dr_node_p2g(b, x, v, C, m, g);
        double t2 = dr_time_now();
        memcpy(vold, g->vel, sizeof(double) * 3 * (size_t)g->nnodes); /* the grid update would go here */
        double t3 = dr_time_now();
        dr_node_g2p(g, g->vel, vold, lambda, 1e-4, DR_TRANSFER_APIC, 0.0, np, x, v, C, gu);
        double t4 = dr_time_now();
        Times t = {t1 - t0, t2 - t1, t4 - t3};
        if (rep > 0 && t.bins + t.p2g + t.g2p < best_total) {
            best = t;
            best_total = t.bins + t.p2g + t.g2p;
        }
    }
    dr_set_threads(0);
    free(vold), free(x), free(v), free(C), free(m), free(gu);
    dr_node_bins_destroy(&b);
    dr_node_grid_destroy(&g);
    *np_out = np;
    return best;
}

int main(int argc, char **argv)
{
    const char *csv = argc > 1 ? argv[1] : "out/bench/transfer.csv";
    mkdir("out", 0755);
    mkdir("out/bench", 0755);
    FILE *f = fopen(csv, "w");
    if (!f) die("cannot write the csv", NULL);
    struct { DrKernel k; Order order; double lambda; const char *name; } cfg[6] = {
        {DR_KERNEL_QUADRATIC, ORDER_BINS, 0.0, "quadratic sorted"},
        {DR_KERNEL_QUADRATIC, ORDER_LATTICE, 0.0, "quadratic lattice"},
        {DR_KERNEL_QUADRATIC, ORDER_RANDOM, 0.0, "quadratic unsorted"},
        {DR_KERNEL_QUADRATIC, ORDER_BINS, 0.5, "quadratic sorted midpoint"},
        {DR_KERNEL_CUBIC, ORDER_BINS, 0.0, "cubic sorted"},
        {DR_KERNEL_LINEAR, ORDER_BINS, 0.0, "linear sorted"},
    };
    fprintf(f, "config,particles,t1_bins,t1_p2g,t1_g2p,t1_msteps_per_core,t2_bins,t2_p2g,t2_g2p,t2_msteps_per_core\n");
    printf("threads available: %d; 3-D APIC, λ = 0 unless named, with grad_u; %d×%d×%d cells, 8 particles per cell\n\n", dr_threads(), NX,
           NY, NZ);
    printf("| kernel, particle order | threads | particles | bins (s) | P2G (s) | G2P (s) | M particle-steps/s | per core |\n");
    printf("|---|---|---|---|---|---|---|---|\n");
    for (int c = 0; c < 6; c++) {
        fprintf(f, "\"%s\"", cfg[c].name);
        for (int th = 1; th <= 2; th++) {
            long np;
            Times t = run(cfg[c].k, cfg[c].order, cfg[c].lambda, th, &np);
            double rate = np / (t.bins + t.p2g + t.g2p) / 1e6;
            if (th == 1) fprintf(f, ",%ld", np);
            fprintf(f, ",%.4f,%.4f,%.4f,%.3f", t.bins, t.p2g, t.g2p, rate / th);
            printf("| %s | %d | %ld | %.3f | %.3f | %.3f | %.2f | %.2f |\n", cfg[c].name, th, np, t.bins, t.p2g, t.g2p, rate,
                   rate / th);
            fflush(stdout);
        }
        fprintf(f, "\n");
    }
    fclose(f);
    return 0;
}
