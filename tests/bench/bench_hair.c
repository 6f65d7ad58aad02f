/* Hair benchmark, three parts, each a markdown table on stdout and a CSV:
 *  1. cost of a step with hair–hair contact (the first csv, default out/bench/hair.csv): 1,024 and 10,000
 *     strands × 30 vertices, 3 cm long, rooted on a square patch at 0.97 mm spacing (3 cm for 1,024, 9.6 cm
 *     for 10,000: the same density, so the contacts per strand stay the same) and tilted at random by up to
 *     14° so that neighbours cross; human hair (r = 50 µm), contact thickness 50 µm (strands touch at
 *     200 µm), contact stiffness 10 N/m, friction 0.2, gravity, roots clamped to a scalp at rest. For
 *     h = 1e-3 s and 1/240 s, each preconditioner (block, cluster, jacobi, none) to the default tolerance 1e-8
 *     with an iteration cap of 5,000, on 1 and 2 threads: a few steps from the same start (the rest groom),
 *     reported as the mean per step with its split (DrRodStats: groups, contact search with K_G assembly,
 *     factorisation with PCG). A step that stops at the cap is kept and counted in `not_converged`; a step
 *     that fails ends its run, reported as `failed`. The state after the steps is hashed: `identical` tells
 *     whether 2 threads reproduce the 1-thread run bit for bit; `hair_contacts` counts the edge–edge contacts
 *     of the last step.
 *  2. run time against error (out/bench/hair_error.csv, next to the first csv): 8×8 strands × 30 vertices,
 *     5 cm, on a 1.5 cm patch, with contact as above, on a scalp that shakes (±2 cm along x and ±20° about
 *     the vertical y axis, both at 2 Hz) for 0.25 s, on one thread. Error: RMS and max distance of the
 *     strand tips at the end from a reference run (block, tol 1e-12, Δt = 1/7680 s). Sweeps Δt = 1/24 …
 *     1/3840 s at tol 1e-12 (block), and tol = 1e-2 … 1e-10 at Δt = 1/240 s for each preconditioner; the
 *     tolerance rows also give the error against the tol-1e-12 run at 1/240 s (the solver's own error,
 *     without the time discretisation's). A run stops at its first step that reaches the iteration cap
 *     (`capped`: its tolerance is out of reach, and so are the tighter ones, which are then skipped) or
 *     fails (`failed`).
 *  3. strands joined by stiff springs along their length, the stand-in for capillary bridges
 *     (out/bench/hair_springs.csv): 1,024 strands × 30 vertices as one bundle of 32 × 32 or as 64 clumps of
 *     4 × 4, each strand joined to its neighbours by a spring at every free vertex (55,552 or 43,008 springs),
 *     k = 10, 100, 1e3, 1e4 N/m, on the shaking scalp of part 2 at Δt 1e-3 s: block and cluster on 1 and 2
 *     threads, CG iterations and seconds per step (with the factorisation and PCG split), the clusters and the
 *     entries of their factors, and the velocities' difference from block's (the same answer to the tolerance).
 * Scope. The default scope fits ~15 minutes on an idle 2-core machine: every configuration at 1,024
 * strands (block and cluster 2 steps, jacobi and none 1 step each: they run to the cap), but at 10,000 strands
 * only block and cluster at h = 1e-3 s for 1 step (one block step there takes 30–50 s; jacobi and none would
 * take 5,000 iterations of ~50 ms each per step); part 3 2 steps per run. `full` runs the whole matrix at 10,000
 * strands, part 2 with 16×16 strands over 0.5 s (hours) and part 3 with 5 steps. The skipped rows are listed after
 * the table.
 * Times are wall-clock seconds; creating the rod set is not timed. `other CPUs` is the mean number of CPUs
 * that other processes kept busy during a run (from /proc/stat, less this process's own CPU time). A run
 * whose threads had to share a core with them is repeated once and the faster of the two kept (`runs` = 2;
 * the results themselves are bit-identical): a 2-thread run is only meaningful when `other CPUs` is near 0.
 * usage: bench_hair [csv = out/bench/hair.csv] [scope = default | full] [part = all | cost | error | springs] */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include "core/core.h"
#include "hair/hair.h"

#define SEGMENTS 29         /* 30 vertices per strand */
#define SPACING (0.03 / 31) /* root spacing of part 1, m */
#define MAX_ITER 5000

static const DrLagPrecond PRECONDS[4] = {DR_LAG_PRECOND_BLOCK, DR_LAG_PRECOND_JACOBI, DR_LAG_PRECOND_NONE,
                                         DR_LAG_PRECOND_CLUSTER};
static const char *PNAMES[4] = {"block", "jacobi", "none", "cluster"};

static void die(const char *what, const DrError *err)
{
    if (err) dr_error_print("bench_hair", err);
    else fprintf(stderr, "bench_hair: %s\n", what);
    exit(1);
}

static void *xcalloc(size_t n, size_t size)
{
    void *p = calloc(n, size);
    if (!p) die("out of memory", NULL);
    return p;
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

static FILE *open_csv(const char *path)
{
    if (make_parent_dirs(path) != 0) {
        fprintf(stderr, "bench_hair: cannot create the folder of %s\n", path);
        exit(1);
    }
    FILE *f = fopen(path, "w");
    if (!f) {
        fprintf(stderr, "bench_hair: cannot write %s\n", path);
        exit(1);
    }
    return f;
}

/* ---- load of the machine ----------------------------------------------------------------------------------- */

/* CPU seconds the whole machine and this process have used so far; the first is NAN without /proc/stat. */
typedef struct CpuMark { double wall, machine, self; } CpuMark;

static CpuMark cpu_mark(void)
{
    CpuMark m = {dr_time_now(), NAN, 0};
    FILE *f = fopen("/proc/stat", "r");
    if (f) {
        unsigned long long v[8] = {0};
        if (fscanf(f, "cpu %llu %llu %llu %llu %llu %llu %llu %llu", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5], &v[6],
                   &v[7]) == 8) {
            /* user, nice, system, (idle, iowait skipped), irq, softirq, steal */
            double hz = (double)sysconf(_SC_CLK_TCK);
            m.machine = (double)(v[0] + v[1] + v[2] + v[5] + v[6] + v[7]) / hz;
        }
        fclose(f);
    }
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) == 0)
        m.self = (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec + (double)ru.ru_stime.tv_sec +
                 1e-6 * (double)ru.ru_stime.tv_usec;
    return m;
}

/* The mean number of CPUs other processes kept busy between the marks. */
static double other_cpus(CpuMark a, CpuMark b)
{
    double wall = b.wall - a.wall;
    if (!(wall > 0) || isnan(a.machine) || isnan(b.machine)) return NAN;
    return fmax(0.0, ((b.machine - a.machine) - (b.self - a.self)) / wall);
}

/* Whether a run of `threads` threads had to share a core: other processes kept more than the CPUs it left
   idle busy (a 1-thread run on 2 cores is not slowed by one busy CPU; a 2-thread run is, several times over,
   since every parallel loop waits for its slowest thread). Such runs are repeated once, the faster kept. */
static bool oversubscribed(double other, int threads)
{
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    return !(other <= (double)(cores > 0 ? cores : 1) - threads + 0.25);
}

/* ---- grooms ---------------------------------------------------------------------------------------------- */

/* n×n straight strands of `segments` edges and length L rooted on a square patch of side `patch` in the
   plane y = 0, hanging down and tilted from −y by up to `tilt` rad in a random direction, so neighbours
   cross (the validation test's groom). */
static DrGroom crossing_groom(int n, int segments, double L, double patch, double tilt, uint64_t seed)
{
    int S = n * n, nv = segments + 1;
    DrGroom g = {0};
    g.nstrands = S;
    g.offsets = xcalloc((size_t)S + 1, sizeof(int));
    g.x = xcalloc((size_t)S * (size_t)nv * 3, sizeof(double));
    g.root_normal = xcalloc((size_t)S * 3, sizeof(double));
    DrRng rng;
    dr_rng_seed(&rng, seed);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            int s = i * n + j;
            double root[3] = {patch * i / (n - 1), 0, patch * j / (n - 1)};
            double a = tilt * dr_rng_uniform(&rng), ph = 2 * M_PI * dr_rng_uniform(&rng);
            double dir[3] = {sin(a) * cos(ph), -cos(a), sin(a) * sin(ph)};
            g.offsets[s] = s * nv;
            for (int k = 0; k < nv; k++)
                for (int c = 0; c < 3; c++) g.x[3 * ((size_t)s * nv + k) + c] = root[c] + dir[c] * L * k / segments;
            g.root_normal[3 * s + 2] = 1; /* not parallel to any strand: they are within 14° of vertical */
        }
    g.offsets[S] = S * nv;
    return g;
}

static DrRodSet *make_set(const DrGroom *g, DrLagPrecond pc, double tol)
{
    DrRodMaterial m;
    dr_rod_material_default(&m);
    DrRodSetDesc d;
    dr_rod_set_desc_default(&d);
    d.hair_contact = true;
    d.solver.precond = pc;
    d.solver.tol = tol;
    d.solver.max_iter = MAX_ITER;
    DrRodBatch b;
    memset(&b, 0, sizeof b);
    b.groom = g;
    b.material = m;
    b.group = b.mask = 1;
    b.self_contact = true;
    b.contact_stiffness = 10.0;
    b.contact_friction = 0.2;
    b.contact_thickness = 5e-5;
    DrRodSet *r = NULL;
    DrError err;
    if (dr_rod_set_create(&d, &b, 1, &r, &err) != DR_OK) die(NULL, &err);
    return r;
}

static DrHash state_hash(DrRodSet *r)
{
    DrRodState s = dr_rod_set_state(r);
    DrHasher h;
    dr_hasher_init(&h);
    dr_hasher_update(&h, s.x, 3 * (size_t)s.nverts * sizeof(double));
    dr_hasher_update(&h, s.v, 3 * (size_t)s.nverts * sizeof(double));
    dr_hasher_update(&h, s.theta, (size_t)s.nedges * sizeof(double));
    return dr_hasher_final(&h);
}

/* ---- 1. cost of a step ----------------------------------------------------------------------------------- */

typedef struct CostCase { int side, hi, precond, steps; } CostCase;

/* One configuration run: steps from a fresh rod set, with the per-step maximum of CG iterations. */
typedef struct CostRun {
    DrRodStats st;
    int done, itmax;
    double secs, other; /* wall seconds per step; other processes' CPUs */
    DrStatus rc;
    DrError err;
    DrHash hash;
} CostRun;

static CostRun cost_run(const DrGroom *g, DrLagPrecond pc, double h, int steps)
{
    CostRun c;
    memset(&c, 0, sizeof c);
    DrRodSet *r = make_set(g, pc, 1e-8);
    CpuMark m0 = cpu_mark();
    for (; c.done < steps; c.done++) {
        int before = c.st.iterations;
        c.rc = dr_rod_set_step(r, h, NULL, NULL, 0, &c.st, &c.err);
        if (c.rc < 0) break;
        if (c.st.iterations - before > c.itmax) c.itmax = c.st.iterations - before;
    }
    CpuMark m1 = cpu_mark();
    c.secs = (m1.wall - m0.wall) / (c.done > 0 ? c.done : 1);
    c.other = other_cpus(m0, m1);
    c.hash = state_hash(r);
    dr_rod_set_destroy(&r);
    return c;
}

static void cost(const char *path, bool full)
{
    FILE *f = open_csv(path);
    fprintf(f, "strands,vertices,dofs,dt,preconditioner,threads,steps,status,hair_contacts,seconds_per_step,"
               "seconds_build,seconds_contact,seconds_solve,iterations_per_step,iterations_max,not_converged,"
               "residual,identical,other_cpus,runs\n");
    printf("## 1. step cost with hair-hair contact (tol 1e-8, cap %d iterations; seconds are means per step)\n\n",
           MAX_ITER);
    printf("| strands | Δt (s) | precond | threads | steps | contacts | s/step | groups | contact | solve | "
           "CG it./step | max | not conv. | residual | = 1 thread | other CPUs | runs |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    const double hs[2] = {1e-3, 1.0 / 240};
    const char *hnames[2] = {"1e-3", "1/240"};
    CostCase cases[16];
    int ncases = 0;
    const int order[4] = {0, 3, 1, 2}; /* block, cluster, jacobi, none */
    for (int hi = 0; hi < 2; hi++)
        for (int q = 0; q < 4; q++) {
            int p = order[q];
            cases[ncases++] = (CostCase){32, hi, p, p == 0 || p == 3 ? 2 : 1};
        }
    for (int hi = 0; hi < 2; hi++)
        for (int q = 0; q < 4; q++) {
            int p = order[q];
            if (full || (hi == 0 && (p == 0 || p == 3))) cases[ncases++] = (CostCase){100, hi, p, 1};
        }
    DrGroom g = {0};
    int side = 0;
    for (int ci = 0; ci < ncases; ci++) {
        CostCase cc = cases[ci];
        if (cc.side != side) {
            dr_groom_free(&g);
            side = cc.side;
            g = crossing_groom(side, SEGMENTS, 0.03, SPACING * (side - 1), 0.25, 3);
        }
        int S = side * side, V = S * (SEGMENTS + 1), ndof = 3 * V + (V - S); /* x per vertex, θ per edge */
        DrHash h1 = {0, 0};
        for (int threads = 1; threads <= 2; threads++) {
            dr_set_threads(threads);
            CostRun c = cost_run(&g, PRECONDS[cc.precond], hs[cc.hi], cc.steps);
            int runs = 1;
            if (oversubscribed(c.other, threads)) {
                CostRun c2 = cost_run(&g, PRECONDS[cc.precond], hs[cc.hi], cc.steps);
                runs = 2;
                if (c2.secs < c.secs) c = c2;
            }
            const DrRodStats *st = &c.st;
            int n = c.done > 0 ? c.done : 1;
            char status[32] = "ok";
            if (c.rc < 0) {
                snprintf(status, sizeof status, "failed@step%d", c.done + 1);
                dr_error_print("bench_hair", &c.err);
            }
            const char *same = "-";
            if (threads == 1) h1 = c.hash;
            else same = (c.hash.hi == h1.hi && c.hash.lo == h1.lo) ? "yes" : "NO";
            double b = st->seconds_build / n, cs = st->seconds_contact / n, s = st->seconds_solve / n;
            double itm = (double)st->iterations / n;
            fprintf(f, "%d,%d,%d,%s,%s,%d,%d,%s,%d,%.4f,%.4f,%.4f,%.4f,%.1f,%d,%d,%.3e,%s,%.2f,%d\n", S, V, ndof,
                    hnames[cc.hi], PNAMES[cc.precond], threads, c.done, status, st->hair_contacts, c.secs, b, cs, s,
                    itm, c.itmax, st->not_converged, st->residual, same, c.other, runs);
            fflush(f);
            char nc[48];
            if (c.rc < 0) snprintf(nc, sizeof nc, "**%s**", status);
            else if (st->not_converged) snprintf(nc, sizeof nc, "**%d/%d**", st->not_converged, c.done);
            else snprintf(nc, sizeof nc, "0/%d", c.done);
            printf("| %d | %s | %s | %d | %d | %d | %.3f | %.3f | %.3f | %.3f | %.1f | %d | %s | %.1e | %s | %.2f | %d |\n",
                   S, hnames[cc.hi], PNAMES[cc.precond], threads, c.done, st->hair_contacts, c.secs, b, cs, s, itm,
                   c.itmax, nc, st->residual, same, c.other, runs);
            fflush(stdout);
        }
    }
    dr_groom_free(&g);
    dr_set_threads(0);
    if (!full)
        printf("\nnot run in the default scope (`bench_hair CSV full` runs them): 10000 strands with jacobi and none, "
               "and at 1/240 s; 10000-strand rows are 1 step each.\n");
    printf("\ncluster: block Jacobi over clusters of strands joined by contacts, each factored whole (CHOLMOD); "
           "block: each strand's banded factor.\n");
    fclose(f);
}

/* ---- 2. run time against error ----------------------------------------------------------------------------- */

#define SHAKE_HZ 2.0

typedef struct Run {
    double seconds, other;
    long steps, iterations;
    int contacts;
    int runs;
    char status[32]; /* ok, capped@t=…, failed@t=… */
    DrError err;     /* when failed */
    double *tips;    /* nstrands × 3 at the end; NULL unless ok */
} Run;

/* The scalp pose at time t: ±2 cm along x and ±20° about y, both sin(2π f t). */
static DrXform shake(double t)
{
    double s = sin(2 * M_PI * SHAKE_HZ * t);
    DrXform x = {dr_m3_from_euler_xyz(dr_v3(0, 0.35 * s, 0)), dr_v3(0.02 * s, 0, 0)};
    return x;
}

static Run simulate_once(const DrGroom *g, DrLagPrecond pc, double tol, double t_end, int steps_total)
{
    DrRodSet *r = make_set(g, pc, tol);
    DrRodStats st;
    memset(&st, 0, sizeof st);
    Run run;
    memset(&run, 0, sizeof run);
    strcpy(run.status, "ok");
    double h = t_end / steps_total;
    CpuMark m0 = cpu_mark();
    for (int k = 1; k <= steps_total; k++) {
        DrXform pose = shake(k * h);
        DrStatus rc = dr_rod_set_step(r, h, &pose, NULL, 0, &st, &run.err);
        run.steps = k;
        if (rc == DR_WARN_NOT_CONVERGED) {
            snprintf(run.status, sizeof run.status, "capped@t=%.4f", k * h);
            break;
        }
        if (rc < 0) {
            snprintf(run.status, sizeof run.status, "failed@t=%.4f", k * h);
            break;
        }
    }
    CpuMark m1 = cpu_mark();
    run.seconds = m1.wall - m0.wall;
    run.other = other_cpus(m0, m1);
    run.iterations = st.iterations;
    run.contacts = st.hair_contacts;
    if (strcmp(run.status, "ok") == 0) {
        DrRodState s = dr_rod_set_state(r);
        run.tips = xcalloc(3 * (size_t)s.nstrands, sizeof(double));
        for (int k = 0; k < s.nstrands; k++)
            memcpy(run.tips + 3 * k, s.x + 3 * (size_t)(s.offsets[k + 1] - 1), 3 * sizeof(double));
    }
    dr_rod_set_destroy(&r);
    return run;
}

/* On one thread; repeated once when the machine was oversubscribed (the faster kept: the results are the same). */
static Run simulate(const DrGroom *g, DrLagPrecond pc, double tol, double t_end, int steps_total)
{
    Run run = simulate_once(g, pc, tol, t_end, steps_total);
    run.runs = 1;
    if (oversubscribed(run.other, 1)) {
        Run again = simulate_once(g, pc, tol, t_end, steps_total);
        if (again.seconds < run.seconds) {
            free(run.tips);
            run = again;
        } else {
            free(again.tips);
        }
        run.runs = 2;
    }
    if (strncmp(run.status, "failed", 6) == 0) dr_error_print("bench_hair", &run.err);
    return run;
}

static void tip_error(const Run *a, const Run *ref, int n, double *rms, double *max)
{
    *rms = *max = NAN;
    if (!a->tips || !ref || !ref->tips) return;
    double sum = 0;
    *max = 0;
    for (int k = 0; k < n; k++) {
        double d2 = 0;
        for (int c = 0; c < 3; c++) {
            double d = a->tips[3 * k + c] - ref->tips[3 * k + c];
            d2 += d * d;
        }
        sum += d2;
        *max = fmax(*max, sqrt(d2));
    }
    *rms = sqrt(sum / n);
}

static void error_row(FILE *f, const char *sweep, const char *pname, int per_s, double tol, const Run *run,
                      const Run *ref, const Run *same_dt, int n)
{
    double rms, mx, rms_s, mx_s;
    tip_error(run, ref, n, &rms, &mx);
    tip_error(run, same_dt, n, &rms_s, &mx_s);
    fprintf(f, "%s,%s,%s,%d,%.6e,%.0e,%ld,%ld,%d,%.4f,%.4e,%.4e,%.4e,%.4e,%.2f,%d\n", sweep, pname, run->status,
            per_s, 1.0 / per_s, tol, run->steps, run->iterations, run->contacts, run->seconds, rms, mx, rms_s, mx_s,
            run->other, run->runs);
    fflush(f);
    printf("| %s | %s | 1/%d | %.0e | %s | %ld | %ld | %d | %.2f | %.2e | %.2e | %.2e | %.2e | %.2f | %d |\n", sweep,
           pname, per_s, tol, run->status, run->steps, run->iterations, run->contacts, run->seconds, rms, mx, rms_s,
           mx_s, run->other, run->runs);
    fflush(stdout);
}

static void error_sweep(const char *path, bool full)
{
    FILE *f = open_csv(path);
    fprintf(f, "sweep,preconditioner,status,steps_per_s,dt,tol,steps,iterations,hair_contacts,seconds,"
               "tip_rms_m,tip_max_m,tip_rms_same_dt_m,tip_max_same_dt_m,other_cpus,runs\n");
    const int n = full ? 16 : 8, ref_per_s = 7680;
    const double t_end = full ? 0.5 : 0.25;
    DrGroom g = crossing_groom(n, SEGMENTS, 0.05, 0.015, 0.25, 7);
    int S = n * n;
    dr_set_threads(1);
    printf("\n## 2. run time against error: %d strands on a scalp shaking at %.0f Hz for %.2f s, 1 thread; error of "
           "the tips against block, tol 1e-12, Δt 1/%d s (tol rows: also against tol 1e-12 at the same Δt)\n\n",
           S, SHAKE_HZ, t_end, ref_per_s);
    printf("| sweep | precond | Δt (s) | tol | status | steps | CG it. | contacts | seconds | tip RMS (m) | "
           "tip max (m) | RMS, same Δt | max, same Δt | other CPUs | runs |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    Run ref = simulate(&g, DR_LAG_PRECOND_BLOCK, 1e-12, t_end, (int)lround(t_end * ref_per_s));
    error_row(f, "reference", "block", ref_per_s, 1e-12, &ref, &ref, NULL, S);
    const int dts[8] = {24, 48, 96, 240, 480, 960, 1920, 3840};
    Run tight240 = {0};
    for (int i = 0; i < 8; i++) {
        Run run = simulate(&g, DR_LAG_PRECOND_BLOCK, 1e-12, t_end, (int)lround(t_end * dts[i]));
        error_row(f, "dt", "block", dts[i], 1e-12, &run, &ref, NULL, S);
        if (dts[i] == 240) tight240 = run;
        else free(run.tips);
    }
    for (int p = 0; p < 4; p++)
        for (int e = 2; e <= 10; e++) {
            double tol = pow(10.0, -e);
            Run run = simulate(&g, PRECONDS[p], tol, t_end, (int)lround(t_end * 240));
            error_row(f, "tol", PNAMES[p], 240, tol, &run, &ref, &tight240, S);
            free(run.tips);
            if (strncmp(run.status, "capped", 6) == 0) {
                printf("| tol | %s | 1/240 | ≤ %.0e | skipped: the cap was reached at %.0e | | | | | | | | | | |\n",
                       PNAMES[p], tol / 10, tol);
                break;
            }
        }
    printf("\nimplicit Euler is first order: against a reference at Δt_ref the measured error of Δt is about "
           "(1 − Δt_ref/Δt) of the true one (1/2 at 1/3840 s, 3/4 at 1/1920 s).\n");
    free(tight240.tips);
    free(ref.tips);
    dr_groom_free(&g);
    dr_set_threads(0);
    fclose(f);
}


/* ---- 3. strands joined by stiff springs along their length ------------------------------------------------------- */

/* Straight parallel strands (30 vertices, 3 cm) hanging from roots on square grids of SPRING_SPACING: one bundle of
   32 × 32, or 64 clumps of 4 × 4 set 1 mm apart. Every strand is joined to its grid neighbours in its clump (±x, ±z)
   by a spring at every free vertex (2..29; the first two are clamped), rest length the starting distance: the
   stand-in for capillary bridges, which join wet strands along their whole length. A spring is one positional row
   φ = |x_a − x_b| − l₀, J = (n, −n), C⁻¹ = k, added to K_G (dr_lag_add_global) between the set's groups and the solve,
   as the owner of a shared system adds another model's (hair.h, "in a shared system"); no geometric stiffness, no
   hair–hair contact. The scalp shakes as in part 2 (from rest, Δt 1e-3 s). */
#define SPRING_SPACING 2e-4 /* m between neighbouring roots of a clump: 2 radii and a 100 µm gap */
#define CLUMP_GAP 1e-3      /* m between clumps */

typedef struct Springs {
    DrGroom groom;
    DrLag *sys;
    DrRodSet *rods;
    int nsprings;
    int *va, *vb;   /* nsprings: the two vertices */
    double *rest;   /* nsprings: l₀ */
    double *lambda; /* nsprings */
    int *vdof;      /* V: first DOF of each vertex in the system (as the set fills a load's blocks) */
    double k;
} Springs;

/* clumps × clumps clumps of side × side strands */
static void springs_make(Springs *b, int clumps, int side, DrLagPrecond pc, double k)
{
    memset(b, 0, sizeof *b);
    int nv = SEGMENTS + 1, S = clumps * clumps * side * side;
    double pitch = (side - 1) * SPRING_SPACING + CLUMP_GAP;
    DrGroom *g = &b->groom;
    g->nstrands = S;
    g->offsets = xcalloc((size_t)S + 1, sizeof(int));
    g->x = xcalloc((size_t)S * (size_t)nv * 3, sizeof(double));
    g->root_normal = xcalloc((size_t)S * 3, sizeof(double));
    for (int s = 0; s < S; s++) { /* strand s: clump s / side², (i, j) in it */
        int c = s / (side * side), i = (s % (side * side)) / side, j = s % side;
        double root[3] = {(c / clumps) * pitch + i * SPRING_SPACING, 0, (c % clumps) * pitch + j * SPRING_SPACING};
        g->offsets[s] = s * nv;
        for (int v = 0; v < nv; v++)
            for (int a = 0; a < 3; a++) g->x[3 * ((size_t)s * nv + v) + a] = root[a] - (a == 1 ? 0.03 * v / SEGMENTS : 0);
        g->root_normal[3 * s + 2] = 1;
    }
    g->offsets[S] = S * nv;
    b->k = k;
    DrError err;
    DrLagDesc ld;
    dr_lag_desc_default(&ld);
    ld.precond = pc;
    ld.max_iter = MAX_ITER;
    if (dr_lag_create(&ld, &b->sys, &err) != DR_OK) die(NULL, &err);
    DrRodSetDesc d;
    dr_rod_set_desc_default(&d);
    d.solver = ld;
    d.system = b->sys;
    DrRodBatch bt;
    memset(&bt, 0, sizeof bt);
    bt.groom = g;
    dr_rod_material_default(&bt.material);
    bt.group = bt.mask = 1;
    bt.contact_stiffness = 10;
    if (dr_rod_set_create(&d, &bt, 1, &b->rods, &err) != DR_OK) die(NULL, &err);
    int V = dr_rod_set_load_blocks(b->rods);
    b->vdof = xcalloc((size_t)V, sizeof(int));
    double *zeros = xcalloc(9 * (size_t)V, sizeof(double)), *scratch = xcalloc(9 * (size_t)V, sizeof(double));
    dr_rod_set_fill_load(b->rods, NULL, zeros, NULL, b->vdof, scratch);
    free(zeros);
    free(scratch);
    int cap = 2 * S * nv;
    b->va = xcalloc((size_t)cap, sizeof(int));
    b->vb = xcalloc((size_t)cap, sizeof(int));
    b->rest = xcalloc((size_t)cap, sizeof(double));
    b->lambda = xcalloc((size_t)cap, sizeof(double));
    for (int s = 0; s < S; s++)
        for (int dir = 0; dir < 2; dir++) {
            int i = (s % (side * side)) / side, j = s % side;
            if ((dir == 0 && i + 1 >= side) || (dir == 1 && j + 1 >= side)) continue;
            int t = s + (dir == 0 ? side : 1);
            for (int v = 2; v < nv; v++) {
                int a = s * nv + v, c = t * nv + v;
                double dd = 0;
                for (int q = 0; q < 3; q++) dd += (g->x[3 * a + q] - g->x[3 * c + q]) * (g->x[3 * a + q] - g->x[3 * c + q]);
                b->va[b->nsprings] = a;
                b->vb[b->nsprings] = c;
                b->rest[b->nsprings++] = sqrt(dd);
            }
        }
}

static void springs_free(Springs *b)
{
    dr_rod_set_destroy(&b->rods);
    dr_lag_destroy(&b->sys);
    dr_groom_free(&b->groom);
    free(b->va);
    free(b->vb);
    free(b->rest);
    free(b->lambda);
    free(b->vdof);
}

static DrStatus springs_step(Springs *b, double h, const DrXform *pose, DrLagStats *ls, DrError *err)
{
    DR_TRY(dr_rod_set_predict_dofs(b->rods, h, pose, err));
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(b->sys, &d, err));
    DR_TRY(dr_lag_begin(b->sys, h, d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, err));
    DR_TRY(dr_rod_set_predict_groups(b->rods, NULL, 0, err));
    DrRodState st = dr_rod_set_state(b->rods);
    for (int s = 0; s < b->nsprings; s++) {
        const double *xa = st.x + 3 * (size_t)b->va[s], *xb = st.x + 3 * (size_t)b->vb[s];
        double dv[3] = {xa[0] - xb[0], xa[1] - xb[1], xa[2] - xb[2]};
        double l = sqrt(dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]);
        DrLagGroup g;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 6;
        for (int q = 0; q < 3; q++) {
            g.dof[q] = b->vdof[b->va[s]] + q;
            g.dof[3 + q] = b->vdof[b->vb[s]] + q;
            g.J[q] = dv[q] / l;
            g.J[3 + q] = -dv[q] / l;
        }
        g.phi[0] = l - b->rest[s];
        g.cinv[0] = b->k;
        g.lambda = &b->lambda[s];
        DR_TRY(dr_lag_add_global(b->sys, &g, err));
    }
    DrStatus solved = dr_lag_solve_load(b->sys, NULL, d.qdot_out, ls, err);
    if (solved < 0) return solved;
    dr_rod_set_take(b->rods);
    dr_lag_update_multipliers(b->sys, d.qdot_out);
    DR_TRY(dr_rod_set_commit(b->rods, NULL, err));
    return solved;
}

typedef struct SpringRun {
    int done, itmax, iterations, not_converged, nsprings;
    int clusters, cluster_dofs_max;
    double cluster_entries;
    double secs, factor, pcg, other, residual;
    DrStatus rc;
    DrError err;
    DrHash hash;
    double *v; /* V × 3 velocities at the end (for the difference between preconditioners) */
    int nv;
} SpringRun;

static SpringRun springs_once(int clumps, int side, DrLagPrecond pc, double k, double h, int steps)
{
    SpringRun c;
    memset(&c, 0, sizeof c);
    Springs b;
    springs_make(&b, clumps, side, pc, k);
    c.nsprings = b.nsprings;
    CpuMark m0 = cpu_mark();
    for (; c.done < steps; c.done++) {
        DrXform pose = shake((c.done + 1) * h);
        DrLagStats ls;
        memset(&ls, 0, sizeof ls);
        c.rc = springs_step(&b, h, &pose, &ls, &c.err);
        if (c.rc < 0) break;
        c.iterations += ls.iterations;
        if (ls.iterations > c.itmax) c.itmax = ls.iterations;
        c.factor += ls.seconds_factor;
        c.pcg += ls.seconds_solve;
        c.residual = ls.residual;
        c.not_converged += ls.converged ? 0 : 1;
        c.clusters = ls.clusters;
        c.cluster_dofs_max = ls.cluster_dofs_max;
        c.cluster_entries = ls.cluster_entries;
    }
    CpuMark m1 = cpu_mark();
    int n = c.done > 0 ? c.done : 1;
    c.secs = (m1.wall - m0.wall) / n;
    c.factor /= n;
    c.pcg /= n;
    c.other = other_cpus(m0, m1);
    c.hash = state_hash(b.rods);
    DrRodState st = dr_rod_set_state(b.rods);
    c.nv = st.nverts;
    c.v = xcalloc(3 * (size_t)st.nverts, sizeof(double));
    memcpy(c.v, st.v, 3 * (size_t)st.nverts * sizeof(double));
    springs_free(&b);
    return c;
}

/* max |v − v_ref| / max |v_ref| over the vertices' velocity components */
static double velocity_difference(const SpringRun *a, const SpringRun *ref)
{
    if (!a->v || !ref->v || a->nv != ref->nv) return NAN;
    double d = 0, m = 0;
    for (size_t q = 0; q < 3 * (size_t)a->nv; q++) {
        d = fmax(d, fabs(a->v[q] - ref->v[q]));
        m = fmax(m, fabs(ref->v[q]));
    }
    return m > 0 ? d / m : d;
}

static void springs_sweep(const char *path, bool full)
{
    FILE *f = open_csv(path);
    fprintf(f, "layout,strands,springs,stiffness,dt,preconditioner,threads,steps,status,seconds_per_step,seconds_factor,"
               "seconds_pcg,iterations_per_step,iterations_max,not_converged,residual,clusters,cluster_dofs_max,"
               "cluster_entries,difference_vs_block,identical,other_cpus,runs\n");
    const int steps = full ? 5 : 2;
    const double h = 1e-3;
    printf("\n## 3. strands joined by springs at every vertex (bridges), shaking scalp, Δt %g s, tol 1e-8, cap %d; "
           "%d steps from rest, means per step\n\n",
           h, MAX_ITER, steps);
    printf("| layout | k (N/m) | precond | threads | s/step | factor | PCG | CG it./step | max | not conv. | clusters | "
           "largest (DOFs) | factor entries | Δv vs block | = 1 thread | other CPUs | runs |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    const struct { const char *name; int clumps, side; } layouts[2] = {{"bundle 32x32", 1, 32}, {"64 clumps 4x4", 8, 4}};
    const double ks[4] = {10, 1e2, 1e3, 1e4};
    const int pcs[2] = {0, 3};
    for (int li = 0; li < 2; li++)
        for (int ki = 0; ki < 4; ki++) {
            SpringRun ref = {0};
            for (int q = 0; q < 2; q++) {
                DrHash h1 = {0, 0};
                for (int threads = 1; threads <= 2; threads++) {
                    dr_set_threads(threads);
                    SpringRun c = springs_once(layouts[li].clumps, layouts[li].side, PRECONDS[pcs[q]], ks[ki], h, steps);
                    int runs = 1;
                    if (oversubscribed(c.other, threads)) {
                        SpringRun c2 = springs_once(layouts[li].clumps, layouts[li].side, PRECONDS[pcs[q]], ks[ki], h,
                                                    steps);
                        runs = 2;
                        if (c2.secs < c.secs) {
                            free(c.v);
                            c = c2;
                        } else {
                            free(c2.v);
                        }
                    }
                    char status[32] = "ok";
                    if (c.rc < 0) {
                        snprintf(status, sizeof status, "failed@step%d", c.done + 1);
                        dr_error_print("bench_hair", &c.err);
                    }
                    const char *same = "-";
                    if (threads == 1) h1 = c.hash;
                    else same = (c.hash.hi == h1.hi && c.hash.lo == h1.lo) ? "yes" : "NO";
                    double diff = pcs[q] == 0 ? 0 : velocity_difference(&c, &ref);
                    int n = c.done > 0 ? c.done : 1, S = layouts[li].clumps * layouts[li].clumps * layouts[li].side *
                                                         layouts[li].side;
                    fprintf(f, "%s,%d,%d,%g,%g,%s,%d,%d,%s,%.4f,%.4f,%.4f,%.1f,%d,%d,%.3e,%d,%d,%.4g,%.3e,%s,%.2f,%d\n",
                            layouts[li].name, S, c.nsprings, ks[ki], h, PNAMES[pcs[q]], threads, c.done, status, c.secs,
                            c.factor, c.pcg, (double)c.iterations / n, c.itmax, c.not_converged, c.residual, c.clusters,
                            c.cluster_dofs_max, c.cluster_entries, diff, same, c.other, runs);
                    fflush(f);
                    printf("| %s | %g | %s | %d | %.3f | %.3f | %.3f | %.1f | %d | %d/%d | %d | %d | %.3g | %.1e | %s | "
                           "%.2f | %d |\n",
                           layouts[li].name, ks[ki], PNAMES[pcs[q]], threads, c.secs, c.factor, c.pcg,
                           (double)c.iterations / n, c.itmax, c.not_converged, c.done, c.clusters, c.cluster_dofs_max,
                           c.cluster_entries, diff, same, c.other, runs);
                    fflush(stdout);
                    if (pcs[q] == 0 && threads == 1) ref = c;
                    else free(c.v);
                }
            }
            free(ref.v);
        }
    printf("\nΔv vs block: max |v − v_block| / max |v_block| of the vertices' velocities after the steps (both solved "
           "to the tolerance); factor: clusters made and factored (cluster) or blocks factored, per step.\n");
    dr_set_threads(0);
    fclose(f);
}

/* hair.csv → hair_error.csv */
static void sibling(const char *csv, const char *suffix, char *out, size_t size)
{
    size_t len = strlen(csv);
    if (len > 4 && strcmp(csv + len - 4, ".csv") == 0) len -= 4;
    if (len + strlen(suffix) + 1 > size) die("csv path too long", NULL);
    memcpy(out, csv, len);
    strcpy(out + len, suffix);
}

int main(int argc, char **argv)
{
    const char *csv = argc > 1 ? argv[1] : "out/bench/hair.csv";
    const char *scope = argc > 2 ? argv[2] : "default";
    const char *part = argc > 3 ? argv[3] : "all";
    bool full = strcmp(scope, "full") == 0;
    if (!full && strcmp(scope, "default") != 0) die("scope must be default or full", NULL);
    if (strcmp(part, "all") != 0 && strcmp(part, "cost") != 0 && strcmp(part, "error") != 0 &&
        strcmp(part, "springs") != 0)
        die("part must be all, cost, error or springs", NULL);
    char err_csv[4096], springs_csv[4096];
    sibling(csv, "_error.csv", err_csv, sizeof err_csv);
    sibling(csv, "_springs.csv", springs_csv, sizeof springs_csv);
    printf("threads available: %d; scope %s\n\n", dr_threads(), scope);
    CpuMark m0 = cpu_mark();
    bool all = strcmp(part, "all") == 0;
    if (all || strcmp(part, "cost") == 0) cost(csv, full);
    if (all || strcmp(part, "error") == 0) error_sweep(err_csv, full);
    if (all || strcmp(part, "springs") == 0) springs_sweep(springs_csv, full);
    CpuMark m1 = cpu_mark();
    printf("\ntotal %.0f s; other processes kept %.2f CPUs busy on average\n", m1.wall - m0.wall, other_cpus(m0, m1));
    return 0;
}
