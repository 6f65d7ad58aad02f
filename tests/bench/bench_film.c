/* Film benchmark (src/wet/film.c), water on human hair (σ 0.072 N/m, ρ 1000, μ 1e-3, r = 50 µm), two parts, each a
 * markdown table on stdout and a CSV:
 *  1. cost (the first csv, default out/bench/film.csv): 600 strands × 15 vertices, 6 cm long, hanging from a 2 cm
 *     square patch, H/r = 3, swung as one rigid body about the vertical axis through the patch (0.6 rad at 2 Hz) and
 *     tilted with it (0.3 rad at 3 Hz) by prescribed positions and velocities: the roots held, the other vertices
 *     taking the film's exchanges (their velocity is prescribed again at the next step, so the strands' own solve is
 *     not part of the timing). 48 steps of h = 1/240 s (24 fps, 10 hair substeps a frame); timed: the film's load
 *     (dr_film_hair_load) and step (dr_film_step), per step, on 1 and 2 threads; `substeps` is the mean per step;
 *     `identical` whether 2 threads reproduce the film state of 1 thread bit for bit.
 *  2. error against substeps (film_error.csv beside the first), on one thread, at h = 1/24 s with desc.substeps
 *     = 1 … 256 (the film takes more where its CFL or capillary limit asks; `taken` is the mean per step):
 *     - terminal: a uniform film (H/r 2) on a held vertical hair of 41 vertices over 4 cm, after 0.125 s (100
 *       friction times; later, the film thinning from the draining root reaches the middle edge): the relative
 *       error of the middle edge's speed against the friction law's g/c; and Σ V + pools' drift;
 *     - bump: a Gaussian bump (H/r 1.5 + 1.5, width 2 mm) on a held horizontal hair of 81 vertices over 4 cm,
 *       after 0.25 s: the relative error of the peak H against a run with 4096 substeps per step;
 *     - swing: a curved hair of 21 vertices, held, swung about its root (0.7 rad at 1.5 Hz) for 2 s, H/r 2.5: the
 *       relative drift of Σ V + pools.
 * Times are wall-clock seconds (creating the film is not timed); nothing here is asserted (tests/unit/test_film.c
 * asserts the physics).
 * usage: bench_film [csv = out/bench/film.csv] */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "core/core.h"
#include "wet/wet.h"

static const double R = 5e-5, RHO = 1000, MU = 1e-3;

static void die(const char *what, const DrError *err)
{
    if (err) dr_error_print("bench_film", err);
    else fprintf(stderr, "bench_film: %s\n", what);
    exit(1);
}

static void *xcalloc(size_t n, size_t size)
{
    void *p = calloc(n, size);
    if (!p) die("out of memory", NULL);
    return p;
}

static FILE *open_csv(const char *path)
{
    char buf[4096];
    if (strlen(path) >= sizeof buf) die("path too long", NULL);
    strcpy(buf, path);
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/') continue;
        *p = '\0';
        if (mkdir(buf, 0777) != 0 && errno != EEXIST) die("cannot create the csv's folder", NULL);
        *p = '/';
    }
    FILE *f = fopen(path, "w");
    if (!f) die("cannot write the csv", NULL);
    return f;
}

static DrFilm *make_film(const DrFilmDesc *d, int S, const int *off, const double *x, double ratio)
{
    int V = off[S];
    double *rad = xcalloc((size_t)V, sizeof(double)), *ratios = xcalloc((size_t)S, sizeof(double));
    for (int i = 0; i < V; i++) rad[i] = R;
    for (int s = 0; s < S; s++) ratios[s] = ratio;
    DrFilm *f;
    DrError err;
    if (dr_film_create(d, S, off, rad, x, ratios, &f, &err) != DR_OK) die("film", &err);
    free(rad), free(ratios);
    return f;
}

static DrHash state_hash(DrFilm *f)
{
    DrFilmState s = dr_film_state(f);
    DrHasher h;
    dr_hasher_init(&h);
    dr_hasher_update(&h, s.volume, (size_t)s.nverts * sizeof(double));
    dr_hasher_update(&h, s.u, (size_t)s.nedges * sizeof(double));
    dr_hasher_update(&h, s.pool, 2 * (size_t)s.nstrands * sizeof(double));
    return dr_hasher_final(&h);
}

static double total_volume(DrFilm *f)
{
    DrFilmState s = dr_film_state(f);
    double v = 0;
    for (int i = 0; i < s.nverts; i++) v += s.volume[i];
    for (int k = 0; k < 2 * s.nstrands; k++) v += s.pool[k];
    return v;
}

/* ---- 1. cost ----------------------------------------------------------------------------------------------------- */

enum { CS = 600, CN = 15 };

/* The groom turned by the swing at time t (positions into x). */
static void groom_pose(const double *rest, double t, double *x)
{
    double a = 0.6 * sin(2 * DR_PI * 2 * t), b = 0.3 * sin(2 * DR_PI * 3 * t);
    DrMat3 Rm = dr_m3_from_euler_xyz(dr_v3(b, a, 0));
    for (int i = 0; i < CS * CN; i++) {
        DrVec3 p = dr_m3_apply(Rm, dr_v3(rest[3 * i], rest[3 * i + 1], rest[3 * i + 2]));
        x[3 * i] = p.x, x[3 * i + 1] = p.y, x[3 * i + 2] = p.z;
    }
}

static void cost(const char *csv)
{
    int off[CS + 1];
    double *rest = xcalloc(3 * CS * CN, sizeof(double)), *x0 = xcalloc(3 * CS * CN, sizeof(double));
    double *x1 = xcalloc(3 * CS * CN, sizeof(double)), *v = xcalloc(3 * CS * CN, sizeof(double));
    double *m = xcalloc(CS * CN, sizeof(double)), *force = xcalloc(3 * CS * CN, sizeof(double));
    double *dfdv = xcalloc(9 * CS * CN, sizeof(double));
    unsigned char *held = xcalloc(CS * CN, 1);
    int side = 25; /* 25 × 24 = 600 roots */
    for (int s = 0; s < CS; s++) {
        off[s] = s * CN;
        double px = -0.01 + 0.02 * (s % side) / (side - 1), pz = -0.01 + 0.02 * (s / side) / (CS / side - 1);
        for (int j = 0; j < CN; j++) {
            double u = (double)j / (CN - 1), ph = 0.37 * s;
            double *p = rest + 3 * (s * CN + j);
            p[0] = px + 0.003 * sin(5 * u + ph), p[1] = -0.06 * u, p[2] = pz + 0.003 * (1 - cos(5 * u + ph));
            m[s * CN + j] = 1300 * DR_PI * R * R * 0.06 / (CN - 1);
        }
        held[s * CN] = 1;
    }
    off[CS] = CS * CN;
    FILE *f = open_csv(csv);
    fprintf(f, "strands,vertices,threads,dt,steps,seconds_per_step,substeps_per_step,identical\n");
    printf("| strands × vertices | threads | Δt (s) | steps | s/step (load + step) | substeps/step | identical |\n");
    printf("|---|---|---|---|---|---|---|\n");
    const double h = 1.0 / 240;
    const int steps = 48;
    DrHash one = {0, 0};
    for (int threads = 1; threads <= 2; threads++) {
        dr_set_threads(threads);
        DrFilmDesc d;
        dr_film_desc_default(&d);
        DrFilm *film = make_film(&d, CS, off, rest, 3);
        DrFilmStats st = {0};
        double secs = 0;
        for (int k = 0; k < steps; k++) {
            groom_pose(rest, k * h, x0);
            groom_pose(rest, (k + 1) * h, x1);
            for (int q = 0; q < 3 * CS * CN; q++) v[q] = (x1[q] - x0[q]) / h;
            memset(force, 0, 3 * CS * CN * sizeof(double));
            memset(dfdv, 0, 9 * CS * CN * sizeof(double));
            double t0 = dr_time_now();
            dr_film_hair_load(film, x0, v, h, force, dfdv);
            DrError err;
            if (dr_film_step(film, x0, x1, v, m, held, h, &st, &err) != DR_OK) die("step", &err);
            secs += dr_time_now() - t0;
        }
        DrHash hs = state_hash(film);
        if (threads == 1) one = hs;
        bool same = hs.hi == one.hi && hs.lo == one.lo;
        fprintf(f, "%d,%d,%d,%.6f,%d,%.6e,%.2f,%s\n", CS, CN, threads, h, steps, secs / steps,
                (double)st.substeps / steps, same ? "yes" : "no");
        printf("| %d × %d | %d | 1/240 | %d | %.2e | %.1f | %s |\n", CS, CN, threads, steps, secs / steps,
               (double)st.substeps / steps, same ? "yes" : "no");
        dr_film_destroy(&film);
    }
    dr_set_threads(0);
    fclose(f);
    free(rest), free(x0), free(x1), free(v), free(m), free(force), free(dfdv), free(held);
}

/* ---- 2. error against substeps ------------------------------------------------------------------------------------ */

static void line(double *x, int n, DrVec3 p0, DrVec3 dir, double L)
{
    for (int j = 0; j < n; j++) {
        DrVec3 p = dr_v3_add(p0, dr_v3_scale(dir, L * j / (n - 1)));
        x[3 * j] = p.x, x[3 * j + 1] = p.y, x[3 * j + 2] = p.z;
    }
}

typedef struct Run { double error, drift, seconds, taken; } Run;

/* A held strand stepped for `time` s at h; `setup` shapes the film, `swing` moves the strand (NULL: still). */
static Run run_held(int n, const double *rest, double ratio, int substeps, double h, double time,
                    void (*setup)(DrFilm *, int), void (*swing)(const double *, int, double, double *),
                    DrFilm **keep)
{
    int off[2] = {0, n};
    DrFilmDesc d;
    dr_film_desc_default(&d);
    d.substeps = substeps;
    DrFilm *f = make_film(&d, 1, off, rest, ratio);
    if (setup) setup(f, n);
    double *x0 = xcalloc(3 * (size_t)n, sizeof(double)), *x1 = xcalloc(3 * (size_t)n, sizeof(double));
    double *v = xcalloc(3 * (size_t)n, sizeof(double)), *m = xcalloc((size_t)n, sizeof(double));
    unsigned char *held = xcalloc((size_t)n, 1);
    for (int i = 0; i < n; i++) m[i] = 1e-8, held[i] = 1;
    memcpy(x0, rest, 3 * (size_t)n * sizeof(double));
    memcpy(x1, rest, 3 * (size_t)n * sizeof(double));
    double V0 = total_volume(f), t0 = dr_time_now();
    int steps = (int)llround(time / h);
    DrFilmStats st = {0};
    for (int k = 0; k < steps; k++) {
        if (swing) {
            swing(rest, n, k * h, x0);
            swing(rest, n, (k + 1) * h, x1);
            for (int q = 0; q < 3 * n; q++) v[q] = (x1[q] - x0[q]) / h;
        }
        DrError err;
        if (dr_film_step(f, x0, x1, v, m, held, h, &st, &err) != DR_OK) die("step", &err);
    }
    Run r = {0, fabs(total_volume(f) - V0) / V0, dr_time_now() - t0, (double)st.substeps / steps};
    free(x0), free(x1), free(v), free(m), free(held);
    *keep = f;
    return r;
}

static void bump_setup(DrFilm *f, int n)
{
    DrFilmState s = dr_film_state(f);
    double L = 0.04, le = L / (n - 1), w = 0.002;
    for (int i = 0; i < n; i++) {
        double x = i * le - 0.5 * L, Hr = 1.5 + 1.5 * exp(-x * x / (2 * w * w));
        s.volume[i] = DR_PI * R * R * (Hr * Hr - 1) * (i == 0 || i == n - 1 ? 0.5 * le : le);
    }
}

static double bump_peak(DrFilm *f, int n)
{
    double *H = xcalloc((size_t)n, sizeof(double)), p = 0;
    dr_film_heights(f, H);
    for (int i = 0; i < n; i++) p = fmax(p, H[i]);
    free(H);
    return p;
}

static void swing_pose(const double *rest, int n, double t, double *x)
{
    double th = 0.7 * sin(2 * DR_PI * 1.5 * t), c = cos(th), s = sin(th);
    for (int j = 0; j < n; j++) {
        double px = rest[3 * j] - rest[0], py = rest[3 * j + 1] - rest[1];
        x[3 * j] = rest[0] + c * px - s * py, x[3 * j + 1] = rest[1] + s * px + c * py, x[3 * j + 2] = rest[3 * j + 2];
    }
}

static void error_sweep(const char *csv)
{
    FILE *f = open_csv(csv);
    fprintf(f, "case,substeps,taken,dt_effective,seconds,error,volume_drift\n");
    printf("\n| case | substeps ≥ | taken/step | δt (s) | seconds | error | volume drift |\n|---|---|---|---|---|---|---|\n");
    const double h = 1.0 / 24;
    double vert[3 * 41], horiz[3 * 81], arc[3 * 21];
    line(vert, 41, dr_v3(0, 0.1, 0), dr_v3(0, -1, 0), 0.04);
    line(horiz, 81, dr_v3(0, 0, 0), dr_v3(1, 0, 0), 0.04);
    for (int j = 0; j < 21; j++) {
        double a = 1.2 * j / 20;
        arc[3 * j] = -0.02 + 0.02 * cos(a), arc[3 * j + 1] = 0.02 * sin(a), arc[3 * j + 2] = 0.002 * j / 21;
    }
    DrFilm *film;
    Run ref = run_held(81, horiz, 1.5, 4096, h, 0.25, bump_setup, NULL, &film);
    double peak_ref = bump_peak(film, 81);
    dr_film_destroy(&film);
    for (int sub = 1; sub <= 256; sub *= 2) {
        /* terminal speed of a uniform film on a held vertical hair */
        Run r = run_held(41, vert, 2, sub, h, 0.125, NULL, NULL, &film);
        DrFilmState s = dr_film_state(film);
        double A = 0.5 * (s.volume[20] + s.volume[21]) / 0.001, a = A / DR_PI, Hh = sqrt(R * R + a);
        double c = 6 * MU * R / (RHO * a * (Hh - R));
        r.error = fabs(s.u[20] - 9.81 / c) / (9.81 / c);
        dr_film_destroy(&film);
        /* the Gaussian bump's peak against the reference */
        Run b = run_held(81, horiz, 1.5, sub, h, 0.25, bump_setup, NULL, &film);
        b.error = fabs(bump_peak(film, 81) - peak_ref) / peak_ref;
        dr_film_destroy(&film);
        /* volume of a swung hair */
        Run w = run_held(21, arc, 2.5, sub, h, 2.0, NULL, swing_pose, &film);
        dr_film_destroy(&film);
        const char *names[3] = {"terminal", "bump", "swing"};
        Run *runs[3] = {&r, &b, &w};
        for (int q = 0; q < 3; q++) {
            Run *x = runs[q];
            fprintf(f, "%s,%d,%.2f,%.6e,%.6e,%.6e,%.6e\n", names[q], sub, x->taken, h / x->taken, x->seconds,
                    q == 2 ? NAN : x->error, x->drift);
            printf("| %s | %d | %.1f | %.2e | %.3f | %s%.2e | %.1e |\n", names[q], sub, x->taken, h / x->taken,
                   x->seconds, q == 2 ? "— " : "", q == 2 ? 0.0 : x->error, x->drift);
        }
    }
    printf("\nbump reference: %.1f substeps per step (δt %.2e s), peak H/r %.6f\n", ref.taken, h / ref.taken,
           peak_ref / R);
    fclose(f);
}

int main(int argc, char **argv)
{
    const char *csv = argc > 1 ? argv[1] : "out/bench/film.csv";
    char err_csv[4096];
    size_t n = strlen(csv);
    if (n < 4 || n + 16 > sizeof err_csv || strcmp(csv + n - 4, ".csv") != 0) die("the csv must end in .csv", NULL);
    memcpy(err_csv, csv, n - 4);
    strcpy(err_csv + n - 4, "_error.csv");
    printf("threads available: %d (2-thread timings mean something only on an otherwise idle machine)\n\n",
           dr_threads());
    double t0 = dr_time_now();
    cost(csv);
    error_sweep(err_csv);
    printf("\ntotal %.0f s\n", dr_time_now() - t0);
    return 0;
}
