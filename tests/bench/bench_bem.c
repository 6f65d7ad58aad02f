/* BEM precompute benchmark, two parts, each a markdown table on stdout and a CSV:
 *  1. precompute cost against the vertex count (the first csv, default out/bench/bem.csv): closed boxes
 *     0.1 m on a side with 9, 13 and 22 segments per edge (488, 1,016 and 2,906 vertices; the paper's bumpy cube
 *     has 3,000), jelly (ρ = 1000 kg/m³, μ = 1e5 Pa, ν = 0.4) at Δt = 1/200 s, so n_max = 5 as in the paper's
 *     Table 1, compression 32× (vertex order + xyz blocks). Each size runs in its own process so that its peak
 *     resident memory (getrusage) is its own: seconds of quadrature (kernels, integration and the CQ weights),
 *     of H₀⁻¹ and H₀⁻¹G′, of compression, in total, peak memory, and the rigid-translation residual of the
 *     truncated history; then the seconds of an unconstrained step of a body at 32× (1 and 2 threads) and of a
 *     constrained step of the box resting on a floor (its bottom face in contact, friction 0.4) by phase: trial
 *     steps, collision detection, assembly of the contact response, projected Gauss–Seidel, final step, and error
 *     correction.
 *  2. compression (out/bench/bem_compression.csv, next to the first): the 2,906-vertex box built once with
 *     dense matrices, then every matrix compressed at ratios 1 (dense), 8, 32 and 128: storage of the whole set
 *     (H_k, G_k for k = 0..n_max, H₀⁻¹, H₀⁻¹G′), the relative Frobenius error of H_1, the relative error of
 *     H_1 x against the dense product for a smooth and a random x, and the seconds of one product and of the
 *     history sum of one step (2·n_max products plus H₀⁻¹G′ and H₀⁻¹) on 1 and 2 threads — the analogue of
 *     the paper's Table 1 and Fig. 7; and the seconds of a body's unconstrained step (history sums, eq. 12,
 *     error correction) on that set, 1 and 2 threads (issue goal: ≤ 0.011 s at 32× on 2 cores). Part 1 also
 *     times the step at 32× for each size.
 *  3. (--dense only, not part of `make bench`) the dense-traction step on the three boxes, their matrices built once
 *     into CACHE_ROOT and read from there afterwards: 1 and 2 threads interleaved in rounds, median and spread, and
 *     the error the compact copies add (part_dense).
 * Targets from the issue: N ≈ 3,000 precomputed within 20 minutes on 2 cores.
 * usage: bench_bem [csv = out/bench/bem.csv] [part = all | precompute | compression]
 *        bench_bem --one SEGMENTS   (one precompute, one CSV line on stdout; used by part 1)
 *        bench_bem --dense CACHE_ROOT [ROUNDS = 5] [STEPS = 30] [SEGMENTS = all] */
#include <errno.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include "bem/bem.h"
#include "bem/bem_internal.h"
#include "core/core.h"

static DrBemDesc bench_desc(void)
{
    DrBemDesc d;
    dr_bem_desc_default(&d);
    d.material = (DrBemMaterial){.density = 1000, .shear_modulus = 1e5, .poisson = 0.4};
    d.dt = 1.0 / 200.0;
    d.compression_ratio = 32;
    return d;
}

static DrTriMesh box_mesh(int seg)
{
    double lo[3] = {-0.05, -0.05, -0.05}, hi[3] = {0.05, 0.05, 0.05};
    int n[3] = {seg, seg, seg};
    DrTriMesh m = {0};
    DrError err;
    if (dr_bem_mesh_box(lo, hi, n, &m, &err) != DR_OK) {
        fprintf(stderr, "bench_bem: %s\n", err.message);
        exit(1);
    }
    return m;
}


/* A body at rest at the origin under gravity, on the benchmark's matrices. */
static DrBemSolid *bench_solid(const DrBemMatrices *bm)
{
    DrBemSolidDesc d;
    dr_bem_solid_desc_default(&d);
    DrBemSolid *s = NULL;
    DrError err;
    if (dr_bem_solid_create(bm, &d, &s, &err) != DR_OK) {
        fprintf(stderr, "bench_bem: %s\n", err.message);
        exit(1);
    }
    return s;
}

/* Seconds per unconstrained step of a body, on `threads` threads, over `steps` steps after as many warm-up steps
   (the history window fills): out = {median total, mean history, mean solve, mean error correction}. The median
   keeps a step disturbed by other work on the machine out of the figure. LOAD_THIRD: a traction along y on every
   third vertex, so every history matrix is multiplied, the traction matrices by column (a fifth of their columns
   are touched); LOAD_DENSE: an uneven traction on every vertex and axis, which touches every column, so they go by
   row; LOAD_FREE (free flight): the G_k products are skipped. */
enum { LOAD_FREE, LOAD_THIRD, LOAD_DENSE };

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static void time_steps(const DrBemMatrices *bm, int threads, int steps, int load, double out[4])
{
    omp_set_num_threads(threads);
    DrBemSolid *s = bench_solid(bm);
    DrError err;
    bool loaded = load != LOAD_FREE;
    double *p = calloc((size_t)bm->n, sizeof(double)), *t = calloc((size_t)steps, sizeof(double));
    for (int v = 0; v < bm->nv; v++)
        for (int c = 0; c < 3; c++)
            p[3 * v + c] = load == LOAD_DENSE          ? 50.0 * (1.0 + 0.5 * sin(0.37 * v + c))
                           : c == 1 && v % 3 == 0 ? 50.0
                                                   : 0.0;
    memset(out, 0, sizeof(double) * 4);
    for (int k = 0; k < 2 * steps; k++) {
        DrBemStepStats st;
        double t0 = dr_time_now();
        if (dr_bem_solid_step(s, loaded ? p : NULL, &st, &err) != DR_OK) {
            fprintf(stderr, "bench_bem: %s\n", err.message);
            exit(1);
        }
        double dt = dr_time_now() - t0;
        if (k < steps) continue;
        t[k - steps] = dt;
        out[1] += st.seconds_history / steps;
        out[2] += st.seconds_solve / steps;
        out[3] += st.seconds_correction / steps;
    }
    qsort(t, (size_t)steps, sizeof *t, cmp_double);
    out[0] = t[steps / 2];
    free(p);
    free(t);
    dr_bem_solid_destroy(&s);
    omp_set_num_threads(2);
}


/* The floor y = −0.05 − 1e-4 m under the box (its bottom face rests on it). */
static double floor_sdf(const double x[3], double grad[3], void *ctx)
{
    (void)ctx;
    grad[0] = 0;
    grad[1] = 1;
    grad[2] = 0;
    return x[1] + 0.05 + 1e-4;
}

/* Mean seconds per constrained step of the box resting on a floor under gravity (its bottom face in contact),
   by phase: out = {total, trial, detection, assembly, PGS, final step, contacts, PGS sweeps}. */
static void time_contact_steps(const DrBemMatrices *bm, int threads, int steps, double out[8])
{
    omp_set_num_threads(threads);
    DrBemSolid *s = bench_solid(bm);
    DrError err;
    DrBemCollider floor = {.sdf = floor_sdf, .friction = 0.4};
    DrBemConstraints c;
    dr_bem_constraints_default(&c);
    c.colliders = &floor;
    c.collider_count = 1;
    memset(out, 0, sizeof(double) * 8);
    DrBemSolid *const list[1] = {s};
    for (int k = 0; k < 2 * steps; k++) {
        DrBemConstraintStats st;
        double t0 = dr_time_now();
        DrStatus r = dr_bem_solids_step(list, 1, &c, &st, &err);
        if (r < 0) {
            fprintf(stderr, "bench_bem: %s\n", err.message);
            exit(1);
        }
        double t = dr_time_now() - t0;
        if (k < steps) continue;
        double v[8] = {t, st.seconds_trial, st.seconds_detect, st.seconds_assembly, st.seconds_pgs, st.seconds_final,
                       st.contacts, st.iterations};
        for (int q = 0; q < 8; q++) out[q] += v[q] / steps;
    }
    dr_bem_solid_destroy(&s);
    omp_set_num_threads(2);
}

static int run_one(int seg)
{
    DrTriMesh m = box_mesh(seg);
    DrBemDesc d = bench_desc();
    DrBemMatrices *bm = NULL;
    DrError err;
    double t0 = dr_time_now();
    if (dr_bem_matrices_build(&m, &d, NULL, &bm, &err) != DR_OK) {
        fprintf(stderr, "bench_bem: %s\n", err.message);
        return 1;
    }
    double total = dr_time_now() - t0;
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    int threads = omp_get_max_threads();
    double st1[4], st2[4], stf[4], std2[4];
    time_steps(bm, 1, 40, LOAD_THIRD, st1);
    time_steps(bm, 2, 40, LOAD_THIRD, st2);
    time_steps(bm, 2, 40, LOAD_FREE, stf);
    time_steps(bm, 2, 40, LOAD_DENSE, std2);
    double ct[2][8];
    time_contact_steps(bm, 1, 3, ct[0]);
    time_contact_steps(bm, 2, 3, ct[1]);
    for (int th = 0; th < 2; th++)
        fprintf(stderr, "contact %d vertices %d thread(s): %.3f s/step (trial %.3f, detection %.3f, assembly %.3f, "
                        "PGS %.3f, final %.3f), %.0f contacts, %.0f sweeps\n",
                m.nv, th + 1, ct[th][0], ct[th][1], ct[th][2], ct[th][3], ct[th][4], ct[th][5], ct[th][6], ct[th][7]);
    printf("%d,%d,%d,%.3f,%.3f,%.3f,%.3f,%.1f,%.1f,%.1f,%.3e,%.5f,%.5f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,"
           "%.0f,%.0f,%.5f,%.5f\n",
           m.nv, threads, bm->n_max,
           bm->stats.seconds_quadrature, bm->stats.seconds_inverse, bm->stats.seconds_compress, total,
           ru.ru_maxrss / 1024.0, bm->stats.bytes_dense / 1e6, bm->stats.bytes_compressed / 1e6,
           bm->stats.rigid_residual, st1[0], st2[0], ct[0][0], ct[1][0], ct[1][1], ct[1][2], ct[1][3], ct[1][4],
           ct[1][5], st2[3], ct[1][6], ct[1][7], stf[0], std2[0]);
    dr_bem_matrices_destroy(&bm);
    dr_trimesh_free(&m);
    return 0;
}

static void part_precompute(const char *csv)
{
    FILE *f = fopen(csv, "w");
    if (!f) {
        fprintf(stderr, "bench_bem: cannot write %s: %s\n", csv, strerror(errno));
        exit(1);
    }
    const char *head = "vertices,threads,n_max,s_quadrature,s_inverse,s_compress,s_total,peak_mb,dense_mb,"
                       "compressed_mb,rigid_residual,s_step_1t,s_step_2t,s_contact_step_1t,s_contact_step_2t,s_trial_2t,"
                       "s_detect_2t,s_assembly_2t,s_pgs_2t,s_final_2t,s_correction_2t,contacts,pgs_sweeps,s_step_free_2t,"
                       "s_step_dense_2t";
    fprintf(f, "%s\n", head);
    printf("### precompute against N (boxes, n_max as listed, 32x, %d threads)\n\n", omp_get_max_threads());
    printf("| vertices | n_max | quadrature s | H0 inverse s | compression s | total s | peak MB | dense MB | "
           "kept MB | rigid residual | loaded step s (1 / 2 threads) | traction-free step s (2 threads) | dense "
           "traction step s (2 threads) | step on the floor s (1 / 2 threads) | on the floor, 2 threads: trial / "
           "detection / assembly / PGS / final / error correction s | contacts |\n"
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    int segs[] = {9, 13, 22};
    char self[1024];
    ssize_t len = readlink("/proc/self/exe", self, sizeof self - 1);
    if (len <= 0) {
        fprintf(stderr, "bench_bem: cannot find its own executable: %s\n", strerror(errno));
        exit(1);
    }
    self[len] = '\0';
    for (int i = 0; i < 3; i++) {
        char cmd[1200];
        snprintf(cmd, sizeof cmd, "'%s' --one %d", self, segs[i]);
        FILE *p = popen(cmd, "r");
        char line[512] = "";
        if (!p || !fgets(line, sizeof line, p)) {
            fprintf(stderr, "bench_bem: run with %d segments failed\n", segs[i]);
            if (p) pclose(p);
            continue;
        }
        pclose(p);
        fputs(line, f);
        fflush(f);
        int nv, th, nmax;
        double q, inv, comp, tot, peak, dmb, kmb, rr, s1, s2, c1, c2, tr, de, as, pg, fi, co, nc, sw, sf, sd;
        if (sscanf(line,
                   "%d,%d,%d,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf",
                   &nv, &th, &nmax, &q, &inv, &comp, &tot, &peak, &dmb, &kmb, &rr, &s1, &s2, &c1, &c2, &tr, &de, &as,
                   &pg, &fi, &co, &nc, &sw, &sf, &sd) == 25)
            printf("| %d | %d | %.1f | %.1f | %.1f | %.1f | %.0f | %.0f | %.0f | %.2e | %.4f / %.4f | %.4f | %.4f | "
                   "%.3f / %.3f | %.3f / %.4f / %.3f / %.3f / %.3f / %.4f | %.0f |\n",
                   nv, nmax, q, inv, comp, tot, peak, dmb, kmb, rr, s1, s2, sf, sd, c1, c2, tr, de, as, pg, fi, co, nc);
        fflush(stdout);
    }
    fclose(f);
}

static double rel_err(int n, const double *a, const double *b)
{
    double num = 0, den = 0;
    for (int i = 0; i < n; i++) {
        num += (a[i] - b[i]) * (a[i] - b[i]);
        den += b[i] * b[i];
    }
    return sqrt(num / den);
}

static void dense_matvec(int n, const double *M, const double *x, double *y)
{
#pragma omp parallel for schedule(static)
    for (int r = 0; r < n; r++) {
        double a = 0;
        for (int c = 0; c < n; c++) a += M[(size_t)r * n + c] * x[c];
        y[r] = a;
    }
}

static void part_compression(const char *csv)
{
    DrTriMesh m = box_mesh(22);
    DrBemDesc d = bench_desc();
    d.compression_ratio = 1;
    d.keep_dense = true;
    DrBemMatrices *bm = NULL;
    DrError err;
    if (dr_bem_matrices_build(&m, &d, NULL, &bm, &err) != DR_OK) {
        fprintf(stderr, "bench_bem: %s\n", err.message);
        exit(1);
    }
    int n = bm->n, nk = bm->n_max + 1;
    size_t nn = (size_t)n * n;
    const double *H1 = bm->H_dense + nn;
    double *x1 = malloc(sizeof(double) * n), *x2 = malloc(sizeof(double) * n), *ref1 = malloc(sizeof(double) * n),
           *ref2 = malloc(sizeof(double) * n), *y = malloc(sizeof(double) * n), *sc = malloc(sizeof(double) * 2 * n);
    uint64_t rng = 12345;
    for (int v = 0; v < m.nv; v++)
        for (int c = 0; c < 3; c++) {
            x1[3 * v + c] = sin(20 * m.v[3 * v]) * cos(15 * m.v[3 * v + 1] + c); /* a smooth field */
            rng = rng * 6364136223846793005ULL + 1442695040888963407ULL;
            x2[3 * v + c] = (double)(rng >> 11) / 9007199254740992.0 - 0.5;
        }
    dense_matvec(n, H1, x1, ref1);
    dense_matvec(n, H1, x2, ref2);
    double norm = 0;
    for (size_t q = 0; q < nn; q++) norm += H1[q] * H1[q];
    norm = sqrt(norm);

    FILE *f = fopen(csv, "w");
    if (!f) {
        fprintf(stderr, "bench_bem: cannot write %s: %s\n", csv, strerror(errno));
        exit(1);
    }
    fprintf(f, "ratio,vertices,n_max,set_mb,h1_frobenius_err,matvec_err_smooth,matvec_err_random,threads,"
               "s_matvec,s_step_history,s_step,s_step_history_part,s_step_solve,s_step_correction,s_step_free\n");
    printf("\n### compression (%d vertices, n_max %d; one product of H_1, and a step's history: %d products)\n\n",
           m.nv, bm->n_max, 2 * nk);
    printf("| ratio | set MB | H_1 Frobenius err | H_1 x err (smooth) | H_1 x err (random) | threads | s per product "
           "| s per 12 products | s per loaded step (history + solve + correction) | s per traction-free step |\n"
           "|---|---|---|---|---|---|---|---|---|---|\n");
    double ratios[] = {1, 8, 32, 128};
    double *back = malloc(sizeof(double) * nn);
    for (int r = 0; r < 4; r++) {
        /* the whole set at this ratio: storage; H_1 alone: error and product time */
        DrBemCMat *set = calloc((size_t)2 * nk + 2, sizeof(DrBemCMat));
        size_t bytes = 0;
        for (int k = 0; k < nk; k++) {
            if (dr_bem_compress(&bm->layout, bm->H_dense + (size_t)k * nn, ratios[r], &set[2 * k], &err) != DR_OK ||
                dr_bem_compress(&bm->layout, bm->G_dense + (size_t)k * nn, ratios[r], &set[2 * k + 1], &err) != DR_OK) {
                fprintf(stderr, "bench_bem: %s\n", err.message);
                exit(1);
            }
            bytes += dr_bem_cmat_bytes(&set[2 * k]) + dr_bem_cmat_bytes(&set[2 * k + 1]);
        }
        /* H₀⁻¹ and H₀⁻¹G′ at this ratio: the same storage per entry as H_0 and G_0 (dense inverses) */
        bytes += dr_bem_cmat_bytes(&set[0]) + dr_bem_cmat_bytes(&set[1]);
        const DrBemCMat *c1 = &set[2];
        /* the body's step on this set: a view of the dense build with the recompressed matrices */
        DrBemMatrices view = *bm;
        view.runtime = NULL; /* its bodies make their own copies of these matrices */
        DrBemCMat *H = calloc((size_t)nk, sizeof(DrBemCMat)), *G = calloc((size_t)nk, sizeof(DrBemCMat));
        for (int k = 0; k < nk; k++) {
            H[k] = set[2 * k];
            G[k] = set[2 * k + 1];
        }
        view.H = H;
        view.G = G;
        double *inv = malloc(sizeof(double) * nn);
        dr_bem_cmat_decompress(&bm->layout, &bm->H0inv, inv);
        if (dr_bem_compress(&bm->layout, inv, ratios[r], &view.H0inv, &err) != DR_OK) exit(1);
        dr_bem_cmat_decompress(&bm->layout, &bm->H0inv_Gp, inv);
        if (dr_bem_compress(&bm->layout, inv, ratios[r], &view.H0inv_Gp, &err) != DR_OK) exit(1);
        free(inv);
        double stp[2][4], stfree[4];
        time_steps(&view, 1, 30, LOAD_THIRD, stp[0]);
        time_steps(&view, 2, 30, LOAD_THIRD, stp[1]);
        time_steps(&view, 2, 30, LOAD_FREE, stfree);
        dr_bem_cmat_free(&view.H0inv);
        dr_bem_cmat_free(&view.H0inv_Gp);
        free(H);
        free(G);
        dr_bem_cmat_decompress(&bm->layout, c1, back);
        double fe = 0;
        for (size_t q = 0; q < nn; q++) fe += (back[q] - H1[q]) * (back[q] - H1[q]);
        fe = sqrt(fe) / norm;
        dr_bem_cmat_matvec(&bm->layout, c1, x1, y, sc);
        double e1 = rel_err(n, y, ref1);
        dr_bem_cmat_matvec(&bm->layout, c1, x2, y, sc);
        double e2 = rel_err(n, y, ref2);
        for (int th = 1; th <= 2; th++) {
            omp_set_num_threads(th);
            int reps = 0;
            double t0 = dr_time_now();
            while (dr_time_now() - t0 < 1.0 || reps < 3) {
                dr_bem_cmat_matvec(&bm->layout, c1, x1, y, sc);
                reps++;
            }
            double per = (dr_time_now() - t0) / reps;
            t0 = dr_time_now();
            for (int k = 0; k < 2 * nk; k++) dr_bem_cmat_matvec(&bm->layout, &set[k], x1, y, sc);
            double step = dr_time_now() - t0;
            const double *sp = stp[th - 1];
            double free_step = th == 2 ? stfree[0] : NAN;
            fprintf(f, "%g,%d,%d,%.1f,%.3e,%.3e,%.3e,%d,%.5f,%.5f,%.5f,%.5f,%.5f,%.5f,%.5f\n", ratios[r], m.nv,
                    bm->n_max, bytes / 1e6, fe, e1, e2, th, per, step, sp[0], sp[1], sp[2], sp[3], free_step);
            printf("| %g | %.0f | %.2e | %.2e | %.2e | %d | %.4f | %.4f | %.4f (%.4f + %.4f + %.4f) | %.4f |\n",
                   ratios[r], bytes / 1e6, fe, e1, e2, th, per, step, sp[0], sp[1], sp[2], sp[3], free_step);
            fflush(stdout);
        }
        omp_set_num_threads(2);
        for (int k = 0; k < 2 * nk; k++) dr_bem_cmat_free(&set[k]);
        free(set);
    }
    fclose(f);
    free(back);
    free(x1);
    free(x2);
    free(ref1);
    free(ref2);
    free(y);
    free(sc);
    dr_bem_matrices_destroy(&bm);
    dr_trimesh_free(&m);
}

/* The matrices of the box with `seg` segments per edge at `ratio`, from cache_root when an earlier run left them there
   (keyed like precompute's, on a name for the box instead of a mesh file's hash), else built and written there. */
static DrBemMatrices *cached_box(const char *cache_root, int seg, double ratio)
{
    DrTriMesh m = box_mesh(seg);
    DrBemDesc d = bench_desc();
    d.compression_ratio = ratio;
    char name[33], key[33];
    snprintf(name, sizeof name, "bench-box-%d", seg);
    dr_bem_cache_key(name, &d, key);
    DrBemMatrices *bm = NULL;
    bool found = false;
    DrError err;
    if (dr_bem_cache_read(cache_root, key, &bm, &found, NULL, &err) != DR_OK) {
        fprintf(stderr, "bench_bem: %s\n", err.message);
        exit(1);
    }
    if (!found) {
        fprintf(stderr, "bench_bem: building the %d-segment box at %gx (cache %s)\n", seg, ratio, cache_root);
        if (dr_bem_matrices_build(&m, &d, NULL, &bm, &err) != DR_OK ||
            dr_bem_cache_write(cache_root, key, "{}", name, bm, &err) != DR_OK) {
            fprintf(stderr, "bench_bem: %s\n", err.message);
            exit(1);
        }
    }
    dr_trimesh_free(&m);
    return bm;
}

/* The displacement after `steps` steps of the dense traction on a body over bm (a view of its own, so that its compact
   copies are made afresh): with the compact copies, or with none (the double products) when `doubles`. */
static void dense_displacement(const DrBemMatrices *bm, int steps, bool doubles, double *u)
{
    DrBemMatrices view = *bm;
    view.runtime = NULL;
    BemRuntime *none = NULL;
    DrError err;
    if (doubles) { /* a set's runtime that was made and holds no copies: the double products serve */
        if (bem_runtime_new(&none, &err) != DR_OK) exit(1);
        none->made = true;
        none->made_for[0] = view.H, none->made_for[1] = view.G, none->made_for[2] = view.H0inv.val;
        view.runtime = none;
    }
    DrBemSolid *s = bench_solid(&view);
    double *p = malloc(sizeof(double) * (size_t)bm->n);
    for (int v = 0; v < bm->nv; v++)
        for (int c = 0; c < 3; c++) p[3 * v + c] = 50.0 * (1.0 + 0.5 * sin(0.37 * v + c));
    for (int k = 0; k < steps; k++)
        if (dr_bem_solid_step(s, p, NULL, &err) != DR_OK) {
            fprintf(stderr, "bench_bem: %s\n", err.message);
            exit(1);
        }
    memcpy(u, dr_bem_solid_displacement(s), sizeof(double) * (size_t)bm->n);
    free(p);
    dr_bem_solid_destroy(&s);
    bem_runtime_free(&none);
}

/* Dense traction (an uneven traction on every vertex and axis: every column of the traction matrices, which then go by
   rows) on the cached boxes at 32×: `rounds` rounds of 1 and 2 threads interleaved, each the median of `steps` steps
   after as many warm-up steps; the median over the rounds and their spread (min–max). The error: ‖u − u_ref‖/‖u_ref‖
   of the displacement after 60 steps, u_ref on the double products of the same compressed matrices (what the
   compact copies add to the compression error). only: one box (its segments per edge), 0 for all three. */
static void part_dense(const char *cache_root, int rounds, int steps, int only)
{
    int segs[] = {9, 13, 22};
    if (rounds > 64) rounds = 64;
    printf("### dense-traction step (boxes, n_max 5, 32x; median of %d steps, %d rounds interleaved)\n\n", steps,
           rounds);
    printf("| vertices | coefficients per step | threads | median s | min s | max s | err vs doubles |\n"
           "|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < 3; i++) {
        if (only && segs[i] != only) continue;
        DrBemMatrices *bm = cached_box(cache_root, segs[i], 32);
        int n = bm->n;
        double t[2][64], *ud = malloc(sizeof(double) * n), *uq = malloc(sizeof(double) * n);
        omp_set_num_threads(2);
        dense_displacement(bm, 60, true, ud);
        dense_displacement(bm, 60, false, uq);
        double err = rel_err(n, uq, ud);
        int64_t coefficients = bm->H0inv.nnz + bm->H0inv_Gp.nnz;
        for (int k = 1; k <= bm->n_max; k++) coefficients += bm->H[k].nnz + bm->G[k].nnz;
        for (int r = 0; r < rounds; r++)
            for (int th = 1; th <= 2; th++) {
                double out[4];
                time_steps(bm, th, steps, LOAD_DENSE, out);
                t[th - 1][r] = out[0];
            }
        for (int th = 1; th <= 2; th++) {
            double *tt = t[th - 1];
            qsort(tt, (size_t)rounds, sizeof(double), cmp_double);
            printf("| %d | %.1f M | %d | %.4f | %.4f | %.4f | %.1e |\n", bm->nv, coefficients / 1e6, th, tt[rounds / 2],
                   tt[0], tt[rounds - 1], err);
            fflush(stdout);
        }
        free(ud);
        free(uq);
        dr_bem_matrices_destroy(&bm);
    }
}

int main(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "--one") == 0) return run_one(atoi(argv[2]));
    if (argc >= 3 && strcmp(argv[1], "--dense") == 0) {
        part_dense(argv[2], argc > 3 ? atoi(argv[3]) : 5, argc > 4 ? atoi(argv[4]) : 30, argc > 5 ? atoi(argv[5]) : 0);
        return 0;
    }
    const char *csv = argc > 1 ? argv[1] : "out/bench/bem.csv";
    const char *part = argc > 2 ? argv[2] : "all";
    if (strcmp(part, "all") == 0 || strcmp(part, "precompute") == 0) part_precompute(csv);
    if (strcmp(part, "all") == 0 || strcmp(part, "compression") == 0) {
        char csv2[1024];
        snprintf(csv2, sizeof csv2, "%.*s_compression.csv", (int)(strlen(csv) - 4), csv);
        part_compression(csv2);
    }
    return 0;
}
