/* Unit tests of the film on every strand (wet.h, "the film on every strand"; src/wet/film.c), water on human hair
 * (σ 0.072 N/m, ρ 1000 kg/m³, μ 1e-3 Pa·s, r = 50 µm) unless a test says otherwise:
 *  - volume: Σ V + pools kept to 1e-12 relative over 10,000 film steps of a swinging, curved strand, no vertex ever
 *    negative (nothing clamps them);
 *  - a uniform film on a held vertical hair reaches the friction law's terminal speed g/c to 1e-6 at three Δt;
 *  - a free hair in zero gravity whose film moves keeps hair + film + pools momentum to 1e-12 of |P|, the hair
 *    taking up a good part of it (it recoils), the tip pool filling;
 *  - a hair whose root accelerates along its axis (film friction 0) leaves its film behind by −at²/2 within 1 %;
 *  - a Gaussian bump spreads with a peak that falls at every step;
 *  - a strand shaken hard with a thick film: the max_ratio limit is reached, the excess goes to the pools, volume is
 *    still exact and no vertex goes negative; a vertex above max_ratio sends its excess to the nearer pool;
 *  - pools move with their end vertex (dr_film_measure, dr_film_hair_load's inertia);
 *  - dr_film_exchange keeps volume and hair + film momentum;
 *  - a non-finite input is DR_ERR_RUNTIME with the film and the velocities left as they were;
 *  - no allocation after the first step; 1 and 2 threads give the same bits; bad descs and degenerate strands;
 *  - the bulk's pressure (dr_film_pressure): under still liquid a film on a held vertical hair does not drain and a free
 *    wet hair sinks as if dry; in a varying gradient hair + film momentum changes by exactly the reported impulse. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/core.h"
#include "hair/hair.h"
#include "wet/wet.h"

#define CHECK(expr)                                                                                                \
    do {                                                                                                           \
        DrError err_;                                                                                              \
        DrStatus s_ = (expr);                                                                                      \
        if (s_ < 0) fail_msg("%s: status %d: %s", #expr, s_, err_.message);                                       \
    } while (0)
#define ERR (&err_)

static const double RHO = 1000, MU = 1e-3, R = 5e-5;

/* ---- strands and a rig: a rod set with a film, stepped as the world will step it ------------------------------- */

/* n vertices from p0 along the unit direction d, total length L. */
static void straight(double *x, int n, DrVec3 p0, DrVec3 d, double L)
{
    for (int j = 0; j < n; j++) {
        DrVec3 p = dr_v3_add(p0, dr_v3_scale(d, L * j / (n - 1)));
        x[3 * j] = p.x, x[3 * j + 1] = p.y, x[3 * j + 2] = p.z;
    }
}

/* n vertices on an arc of radius rad in the x–y plane from angle 0 to ang about c, then lifted in z by lift·j/n. */
static void arc(double *x, int n, DrVec3 c, double rad, double ang, double lift)
{
    for (int j = 0; j < n; j++) {
        double a = ang * j / (n - 1);
        x[3 * j] = c.x + rad * cos(a), x[3 * j + 1] = c.y + rad * sin(a), x[3 * j + 2] = c.z + lift * j / n;
    }
}

static double *radii(int V)
{
    double *r = malloc((size_t)V * sizeof(double));
    for (int i = 0; i < V; i++) r[i] = R;
    return r;
}

static double total_volume(DrFilm *f)
{
    DrFilmState s = dr_film_state(f);
    double v = 0;
    for (int i = 0; i < s.nverts; i++) v += s.volume[i];
    for (int k = 0; k < 2 * s.nstrands; k++) v += s.pool[k];
    return v;
}

static double min_volume(DrFilm *f)
{
    DrFilmState s = dr_film_state(f);
    double m = INFINITY;
    for (int i = 0; i < s.nverts; i++) m = fmin(m, s.volume[i]);
    return m;
}

typedef struct Rig {
    DrGroom g;
    DrRodSet *r;
    DrFilm *f;
    int V;
    double *force, *dfdv, *xold, *rad;
    unsigned char *held;
} Rig;

/* S strands of n vertices at x (S n × 3), roots as given, tips free, the rods' gravity g; a film of fd with H/r =
   ratio on every strand. */
static double g_rig_tol = 0;    /* the rod solve's tolerance when > 0 (else its default) */
static double g_rig_youngs = 0; /* the rods' Young's modulus when > 0 (else human hair's) */
static void rig_make(Rig *rg, int S, int n, const double *x, DrRodRoots roots, DrVec3 g, const DrFilmDesc *fd,
                     double ratio)
{
    memset(rg, 0, sizeof *rg);
    rg->V = S * n;
    rg->g.nstrands = S;
    rg->g.offsets = calloc((size_t)S + 1, sizeof(int));
    rg->g.x = malloc(3 * (size_t)rg->V * sizeof(double));
    rg->g.root_normal = NULL;
    for (int s = 0; s <= S; s++) rg->g.offsets[s] = s * n;
    memcpy(rg->g.x, x, 3 * (size_t)rg->V * sizeof(double));
    DrRodSetDesc d;
    dr_rod_set_desc_default(&d);
    d.roots = roots;
    d.gravity = g;
    if (g_rig_tol > 0) d.solver.tol = g_rig_tol;
    DrRodMaterial m;
    dr_rod_material_default(&m);
    if (g_rig_youngs > 0) m.youngs = g_rig_youngs, m.shear = g_rig_youngs / 3;
    DrRodBatch b = {&rg->g, m, 1, 1, false, 10, 0, 0, 0, 0, 0};
    CHECK(dr_rod_set_create(&d, &b, 1, &rg->r, ERR));
    rg->rad = radii(rg->V);
    double *ratios = malloc((size_t)S * sizeof(double));
    for (int s = 0; s < S; s++) ratios[s] = ratio;
    CHECK(dr_film_create(fd, S, rg->g.offsets, rg->rad, x, ratios, &rg->f, ERR));
    free(ratios);
    rg->force = calloc(3 * (size_t)rg->V, sizeof(double));
    rg->dfdv = calloc(9 * (size_t)rg->V, sizeof(double));
    rg->xold = calloc(3 * (size_t)rg->V, sizeof(double));
    rg->held = calloc((size_t)rg->V, 1);
}

static void rig_free(Rig *rg)
{
    dr_film_destroy(&rg->f);
    dr_rod_set_destroy(&rg->r);
    dr_groom_free(&rg->g);
    free(rg->force), free(rg->dfdv), free(rg->xold), free(rg->rad), free(rg->held);
}

/* One strand step with the film: the film's load (and, for gradp not NULL, the bulk's pressure on it, its impulse into
   impulse), predict, solve with it, commit, the film's step. */
static DrStatus rig_step_p(Rig *rg, double h, const DrXform *scalp, const double *gradp, double *impulse,
                           DrFilmStats *fs, DrError *err)
{
    DrRodState st = dr_rod_set_state(rg->r);
    memset(rg->force, 0, 3 * (size_t)rg->V * sizeof(double));
    memset(rg->dfdv, 0, 9 * (size_t)rg->V * sizeof(double));
    dr_film_hair_load(rg->f, st.x, st.v, h, rg->force, rg->dfdv);
    if (gradp) dr_film_pressure(rg->f, st.x, gradp, h, rg->force, impulse);
    DR_TRY(dr_rod_set_predict(rg->r, h, scalp, NULL, 0, err));
    memcpy(rg->held, dr_rod_set_samples(rg->r).held, (size_t)rg->V);
    DR_TRY(dr_rod_set_solve(rg->r, rg->force, rg->dfdv, NULL, err));
    memcpy(rg->xold, st.x, 3 * (size_t)rg->V * sizeof(double));
    DR_TRY(dr_rod_set_commit(rg->r, NULL, err));
    return dr_film_step(rg->f, rg->xold, st.x, st.v, st.mass, rg->held, h, fs, err);
}

static DrStatus rig_step(Rig *rg, double h, const DrXform *scalp, DrFilmStats *fs, DrError *err)
{
    return rig_step_p(rg, h, scalp, NULL, NULL, fs, err);
}

/* Σ m v of the hair plus the film's momentum (film and pools). */
static DrVec3 rig_momentum(Rig *rg, DrVec3 *hair)
{
    DrRodState st = dr_rod_set_state(rg->r);
    DrVec3 P = dr_v3(0, 0, 0);
    for (int i = 0; i < st.nverts; i++)
        P = dr_v3_add(P, dr_v3_scale(dr_v3(st.v[3 * i], st.v[3 * i + 1], st.v[3 * i + 2]), st.mass[i]));
    if (hair) *hair = P;
    DrFilmStats fs = {0};
    dr_film_measure(rg->f, st.x, st.v, &fs);
    return dr_v3_add(P, fs.momentum);
}

/* The friction law of film.c, for the terminal speed: c = 6 μ r / (ρ (H² − r²) h). */
static double friction_rate(double A, double r)
{
    double a = A / DR_PI, H = sqrt(r * r + a);
    return 6 * MU * r / (RHO * a * (H - r));
}

/* ---- volume over 10,000 steps ------------------------------------------------------------------------------------ */

/* The rest arc turned by θ(t) = 0.7 sin(2π 1.5 t) about the z axis through its root, all vertices held. */
static void swing(const double *rest, int n, double t, double *x)
{
    double th = 0.7 * sin(2 * DR_PI * 1.5 * t), c = cos(th), s = sin(th);
    for (int j = 0; j < n; j++) {
        double px = rest[3 * j] - rest[0], py = rest[3 * j + 1] - rest[1];
        x[3 * j] = rest[0] + c * px - s * py;
        x[3 * j + 1] = rest[1] + s * px + c * py;
        x[3 * j + 2] = rest[3 * j + 2];
    }
}

static void test_volume_exact(void **state)
{
    (void)state;
    enum { N = 21, STEPS = 10000 };
    double rest[3 * N], x0[3 * N], x1[3 * N], v[3 * N], m[N];
    unsigned char held[N];
    arc(rest, N, dr_v3(-0.02, 0, 0), 0.02, 1.2, 0.002);
    int off[2] = {0, N};
    double *rad = radii(N), ratio = 2.5;
    DrFilmDesc d;
    dr_film_desc_default(&d);
    DrFilm *f;
    CHECK(dr_film_create(&d, 1, off, rad, rest, &ratio, &f, ERR));
    DrFilmState fs = dr_film_state(f);
    for (int i = 0; i < N; i++) { /* an uneven film: thicker in the middle */
        fs.volume[i] *= 1 + 0.8 * sin(DR_PI * i / (N - 1));
        m[i] = 1300 * DR_PI * R * R * 0.001, held[i] = 1;
    }
    double V0 = total_volume(f), h = 1e-3, worst = INFINITY;
    DrFilmStats st = {0};
    for (int k = 0; k < STEPS; k++) {
        swing(rest, N, k * h, x0);
        swing(rest, N, (k + 1) * h, x1);
        for (int q = 0; q < 3 * N; q++) v[q] = (x1[q] - x0[q]) / h;
        CHECK(dr_film_step(f, x0, x1, v, m, held, h, &st, ERR));
        worst = fmin(worst, min_volume(f));
    }
    double drift = fabs(total_volume(f) - V0) / V0;
    print_message("volume drift after %d steps (%d substeps): %.3e; smallest vertex volume %.3e m³; pools %.3e m³\n",
                  STEPS, st.substeps, drift, worst, st.pools);
    assert_true(drift <= 1e-12);
    assert_true(worst >= 0);
    assert_true(st.pools > 0.01 * V0); /* the film moved: liquid reached the ends */
    dr_film_destroy(&f);
    free(rad);
}

/* ---- terminal speed --------------------------------------------------------------------------------------------- */

static void test_terminal_velocity(void **state)
{
    (void)state;
    enum { N = 41, MID = 20 };
    const double dts[3] = {1e-3, 1.0 / 240, 1.0 / 48};
    double x[3 * N], v[3 * N] = {0}, m[N];
    unsigned char held[N];
    straight(x, N, dr_v3(0, 0.1, 0), dr_v3(0, -1, 0), 0.04); /* root at the top */
    for (int i = 0; i < N; i++) m[i] = 1e-8, held[i] = 1;
    int off[2] = {0, N};
    double *rad = radii(N), ratio = 2, u_t[3];
    for (int c = 0; c < 3; c++) {
        DrFilmDesc d;
        dr_film_desc_default(&d);
        DrFilm *f;
        CHECK(dr_film_create(&d, 1, off, rad, x, &ratio, &f, ERR));
        double h = dts[c];
        int steps = (int)ceil(0.1 / h);
        for (int k = 0; k < steps; k++) CHECK(dr_film_step(f, x, x, v, m, held, h, NULL, ERR));
        DrFilmState fs = dr_film_state(f);
        /* the middle edge's film is still uniform: A = V / l */
        double le = 0.04 / (N - 1), A = 0.5 * (fs.volume[MID] + fs.volume[MID + 1]) / le;
        double want = 9.81 / friction_rate(A, R);
        u_t[c] = fs.u[MID];
        print_message("dt %.5f s: u = %.12e m/s, g/c = %.12e m/s, relative error %.2e\n", h, fs.u[MID], want,
                      fabs(fs.u[MID] - want) / want);
        assert_true(fabs(fs.u[MID] - want) <= 1e-6 * want);
        assert_true(want > 0.012 && want < 0.0125); /* 12.3 mm/s for water at H = 2r */
        dr_film_destroy(&f);
    }
    assert_true(fabs(u_t[0] - u_t[2]) <= 1e-6 * u_t[0]);
    free(rad);
}

/* ---- momentum of a free hair in zero gravity ---------------------------------------------------------------------- */

static void test_free_hair_momentum(void **state)
{
    (void)state;
    enum { N = 21 };
    double x[3 * N];
    arc(x, N, dr_v3(0, 0, 0), 0.01, 1.5, 0.001);
    DrFilmDesc d;
    dr_film_desc_default(&d);
    d.gravity = dr_v3(0, 0, 0);
    Rig rg;
    /* The rods keep momentum to their solve's tolerance and round-off: Σ (M − h²K) v₊ loses ε h²|K| |v₊| to rounding,
       h²|K|/m ≈ 5e6 for human hair (E 3.9 GPa) at 1 ms, so the rods alone drift ~1e-10 of |P| per step whatever the
       film does. A soft fibre (E 1 MPa: h²|K|/m ≈ 1) solved to round-off leaves the film's exchanges to be measured. */
    g_rig_tol = 1e-15, g_rig_youngs = 1e6;
    rig_make(&rg, 1, N, x, DR_ROD_ROOTS_FREE, dr_v3(0, 0, 0), &d, 2.5);
    g_rig_tol = 0, g_rig_youngs = 0;
    DrFilmState fs = dr_film_state(rg.f);
    for (int i = 0; i < N; i++) fs.volume[i] *= 1 + 0.5 * cos(3.0 * i / N);
    for (int e = 0; e < N - 1; e++) fs.u[e] = 0.05; /* the film flows toward the tip on a hair at rest */
    DrVec3 P0 = rig_momentum(&rg, NULL), hair;
    double P0n = dr_v3_norm(P0), worst = 0;
    for (int k = 0; k < 100; k++) {
        CHECK(rig_step(&rg, 1e-3, NULL, NULL, ERR));
        DrVec3 P = rig_momentum(&rg, &hair);
        worst = fmax(worst, dr_v3_norm(dr_v3_sub(P, P0)) / P0n);
    }
    print_message("|P| %.6e kg m/s, largest drift %.3e of |P|; hair %.3f of |P|; tip pool %.3e m³\n", P0n, worst,
                  dr_v3_norm(hair) / P0n, fs.pool[1]);
    assert_true(worst <= 1e-12);
    assert_true(dr_v3_norm(hair) > 0.1 * P0n); /* the hair took up momentum from its film */
    assert_true(fs.pool[1] > 0);               /* and the ledger held while the tip pool filled */
    rig_free(&rg);
}

/* ---- a root accelerated along the hair --------------------------------------------------------------------------- */

static void test_accelerated_hair(void **state)
{
    (void)state;
    enum { N = 41, MID = 20 };
    const double a = 2.0, h = 1.0 / 2000, L = 0.04;
    double x[3 * N];
    straight(x, N, dr_v3(0, 0, 0), dr_v3(1, 0, 0), L);
    DrFilmDesc d;
    dr_film_desc_default(&d);
    d.friction = 0;
    d.gravity = dr_v3(0, 0, 0);
    Rig rg;
    rig_make(&rg, 1, N, x, DR_ROD_ROOTS_CLAMPED, dr_v3(0, 0, 0), &d, 2.0);
    DrFilmState fs = dr_film_state(rg.f);
    double lv = L / (N - 1), A = fs.volume[MID] / lv, tip0 = 0;
    for (int i = MID + 1; i < N; i++) tip0 += fs.volume[i];
    int steps = 200;
    for (int k = 0; k < steps; k++) {
        double t = (k + 1) * h;
        DrXform X = dr_xform_identity();
        X.t = dr_v3(0.5 * a * t * t, 0, 0);
        CHECK(rig_step(&rg, h, &X, NULL, ERR));
    }
    double t = steps * h, tip = fs.pool[1];
    for (int i = MID + 1; i < N; i++) tip += fs.volume[i];
    double moved = (tip - tip0) / A, want = -0.5 * a * t * t;
    DrRodState rs = dr_rod_set_state(rg.r);
    print_message("film moved %.6e m along the hair, −at²/2 = %.6e m (%.3f %%); hair moved %.6e m; u_mid %.5e, −at %.5e\n",
                  moved, want, 100 * fabs(moved - want) / fabs(want), rs.x[3 * MID] - x[3 * MID], fs.u[MID], -a * t);
    assert_true(fabs(moved - want) <= 0.01 * fabs(want));
    assert_true(fabs(fs.u[MID] + a * t) <= 0.01 * a * t);
    rig_free(&rg);
}

/* ---- the bulk's pressure on the film (dr_film_pressure) ------------------------------------------------------------ */

/* Under still bulk liquid (∇p = ρ g) a film is neutral: on a held vertical hair it does not drain (in air it reaches
   g/c, test_terminal_velocity), and a free, tilted wet hair sinks as if dry: hair + film momentum grows by the hair's
   weight alone (the film's weight is carried by the pressure), to the solves' tolerance. */
static void test_submerged_film_neutral(void **state)
{
    (void)state;
    enum { N = 21 };
    DrFilmDesc d;
    dr_film_desc_default(&d);
    double x[3 * N], gradp[3 * N], imp[3 * N];
    for (int i = 0; i < N; i++) gradp[3 * i] = 0, gradp[3 * i + 1] = RHO * d.gravity.y, gradp[3 * i + 2] = 0;
    /* held vertical: the film stays */
    straight(x, N, dr_v3(0, 0.1, 0), dr_v3(0, -1, 0), 0.04);
    Rig rg;
    rig_make(&rg, 1, N, x, DR_ROD_ROOTS_CLAMPED, d.gravity, &d, 2.0);
    DrFilmState fs = dr_film_state(rg.f);
    double V0 = fs.volume[N / 2], umax = 0;
    for (int k = 0; k < 100; k++) {
        CHECK(rig_step_p(&rg, 1e-3, NULL, gradp, imp, NULL, ERR));
        for (int e = 0; e < N - 1; e++) umax = fmax(umax, fabs(fs.u[e]));
    }
    double gc = 9.81 / friction_rate(V0 / (0.04 / (N - 1)), R);
    print_message("held vertical hair under still liquid: largest film speed %.3e m/s (in air %.3e), tip pool %.3e m³\n",
                  umax, gc, fs.pool[1]);
    assert_true(umax <= 1e-3 * gc);       /* what is left: the strand's own settling under gravity (its fictitious force) */
    assert_true(fs.pool[1] <= 1e-4 * V0);
    rig_free(&rg);
    /* free and tilted: sinks as if dry */
    straight(x, N, dr_v3(0, 0.1, 0), dr_v3(0.8, -0.6, 0), 0.04);
    g_rig_tol = 1e-15;
    rig_make(&rg, 1, N, x, DR_ROD_ROOTS_FREE, d.gravity, &d, 3.0);
    g_rig_tol = 0;
    DrRodState rs = dr_rod_set_state(rg.r);
    double m_hair = 0, h = 1e-3;
    for (int i = 0; i < N; i++) m_hair += rs.mass[i];
    int steps = 50;
    for (int k = 0; k < steps; k++) CHECK(rig_step_p(&rg, h, NULL, gradp, imp, NULL, ERR));
    DrVec3 P = rig_momentum(&rg, NULL);
    double want = m_hair * d.gravity.y * h * steps;
    print_message("free wet hair under still liquid: momentum %.9e (x %.2e) kg m/s, its dry weight's impulse %.9e (%.2e); "
                  "with the film's weight it would be %.3f× that\n", P.y, P.x, want, fabs(P.y - want) / fabs(want),
                  1 + RHO * 3 * DR_PI * R * R * 8 * 0.04 / m_hair / 3);
    /* not to round-off: within a step the film's weight along the strand acts on the film as it flows (its volumes and
       the strand's tangents at each substep), the pressure's as booked at the step's start; the two differ by the
       strand's turn and the film's flow over a step */
    assert_true(fabs(P.y - want) <= 2e-3 * fabs(want));
    assert_true(fabs(P.x) <= 2e-3 * fabs(want));
    rig_free(&rg);
}

/* In zero gravity, a pressure gradient that varies along a curved free hair: every step hair + film + pools momentum
   changes by exactly the impulse dr_film_pressure reports (what the bulk must give up), while the film flows. */
static void test_pressure_impulse_exact(void **state)
{
    (void)state;
    enum { N = 21 };
    double x[3 * N], gradp[3 * N], imp[3 * N];
    arc(x, N, dr_v3(0, 0, 0), 0.01, 1.5, 0.001);
    DrFilmDesc d;
    dr_film_desc_default(&d);
    d.gravity = dr_v3(0, 0, 0);
    Rig rg;
    g_rig_tol = 1e-15, g_rig_youngs = 1e6;
    rig_make(&rg, 1, N, x, DR_ROD_ROOTS_FREE, dr_v3(0, 0, 0), &d, 2.5);
    g_rig_tol = 0, g_rig_youngs = 0;
    DrFilmState fs = dr_film_state(rg.f);
    fs.pool[1] = 2 * fs.volume[N - 1]; /* a tip pool too */
    for (int i = 0; i < N; i++)
        gradp[3 * i] = 400 + 60 * i, gradp[3 * i + 1] = -900 + 30 * sin(i), gradp[3 * i + 2] = 150 * cos(0.5 * i);
    double worst = 0, total = 0;
    for (int k = 0; k < 100; k++) {
        DrVec3 P0 = rig_momentum(&rg, NULL);
        CHECK(rig_step_p(&rg, 1e-3, NULL, gradp, imp, NULL, ERR));
        DrVec3 J = dr_v3(0, 0, 0);
        for (int i = 0; i < N; i++) J = dr_v3_add(J, dr_v3(imp[3 * i], imp[3 * i + 1], imp[3 * i + 2]));
        DrVec3 dP = dr_v3_sub(rig_momentum(&rg, NULL), P0);
        worst = fmax(worst, dr_v3_norm(dr_v3_sub(dP, J)) / dr_v3_norm(J));
        total += dr_v3_norm(J);
    }
    print_message("pressure on a flowing film: momentum change against the reported impulse, largest error %.3e of the "
                  "impulse (%.3e N s over 100 steps)\n", worst, total);
    assert_true(worst <= 1e-9);
    assert_true(total > 0);
    rig_free(&rg);
}

/* ---- a Gaussian bump --------------------------------------------------------------------------------------------- */

static double peak(DrFilm *f, double *H, int n)
{
    dr_film_heights(f, H);
    double p = 0;
    for (int i = 0; i < n; i++) p = fmax(p, H[i]);
    return p;
}

static void test_bump_spreads(void **state)
{
    (void)state;
    enum { N = 81 };
    const double L = 0.04, le = L / (N - 1), w = 0.002;
    double x[3 * N], v[3 * N] = {0}, m[N], H[N];
    unsigned char held[N];
    straight(x, N, dr_v3(0, 0, 0), dr_v3(1, 0, 0), L); /* horizontal: gravity has no part along it */
    for (int i = 0; i < N; i++) m[i] = 1e-8, held[i] = 1;
    int off[2] = {0, N};
    double *rad = radii(N), ratio = 1.5;
    DrFilmDesc d;
    dr_film_desc_default(&d);
    DrFilm *f;
    CHECK(dr_film_create(&d, 1, off, rad, x, &ratio, &f, ERR));
    DrFilmState fs = dr_film_state(f);
    for (int i = 0; i < N; i++) {
        double s = i * le - 0.5 * L, Hr = 1.5 + 1.5 * exp(-s * s / (2 * w * w));
        fs.volume[i] = DR_PI * R * R * (Hr * Hr - 1) * (i == 0 || i == N - 1 ? 0.5 * le : le);
    }
    double V0 = total_volume(f), p0 = peak(f, H, N), prev = p0;
    bool falls = true;
    int steps = 240;
    for (int k = 0; k < steps; k++) {
        CHECK(dr_film_step(f, x, x, v, m, held, 1.0 / 240, NULL, ERR));
        double p = peak(f, H, N);
        if (!(p < prev)) {
            print_error("step %d: peak %.12e after %.12e\n", k, p, prev);
            falls = false;
        }
        prev = p;
    }
    print_message("peak H/r %.4f -> %.4f over 1 s; volume drift %.2e\n", p0 / R, prev / R,
                  fabs(total_volume(f) - V0) / V0);
    assert_true(falls);
    assert_true(prev < 0.9 * p0); /* it did spread */
    assert_true(fabs(total_volume(f) - V0) <= 1e-13 * V0);
    dr_film_destroy(&f);
    free(rad);
}

/* ---- violent shaking, the max_ratio limit and the pools --------------------------------------------------------- */

static DrXform shaken(double t)
{
    double ang = 1.2 * sin(2 * DR_PI * 6 * t);
    DrXform X;
    X.R = dr_m3_from_euler_xyz(dr_v3(0.3 * ang, 0, ang));
    X.t = dr_v3(0.01 * sin(2 * DR_PI * 6 * t), 0.005 * cos(2 * DR_PI * 9 * t), 0);
    return X;
}

static void test_violent_shake(void **state)
{
    (void)state;
    enum { N = 16 };
    double x[3 * N];
    arc(x, N, dr_v3(-0.02, 0, 0), 0.02, -1.0, 0.003);
    DrFilmDesc d;
    dr_film_desc_default(&d);
    Rig rg;
    rig_make(&rg, 1, N, x, DR_ROD_ROOTS_CLAMPED, d.gravity, &d, 5.9);
    double V0 = total_volume(rg.f), worst = INFINITY, top = 0, drift = 0;
    DrFilmStats st = {0};
    for (int k = 0; k < 240; k++) {
        DrXform X = shaken((k + 1) / 480.0);
        CHECK(rig_step(&rg, 1 / 480.0, &X, &st, ERR));
        worst = fmin(worst, min_volume(rg.f));
        top = fmax(top, st.max_ratio);
        drift = fmax(drift, fabs(total_volume(rg.f) - V0) / V0);
    }
    print_message("smallest vertex volume %.3e m³, largest H/r %.15f, volume drift %.2e, to pools %.3e of the film, "
                  "%d substeps\n",
                  worst, top, drift, st.to_pools / V0, st.substeps);
    assert_true(worst >= 0);
    assert_true(drift <= 1e-12);
    assert_true(top <= d.max_ratio * (1 + 1e-12));
    assert_true(top >= d.max_ratio * (1 - 1e-9)); /* the limit was reached */
    assert_true(st.pools > 0.05 * V0);
    rig_free(&rg);
}

static void test_max_ratio_nearer_pool(void **state)
{
    (void)state;
    enum { N = 11 };
    double x[3 * N], v[3 * N] = {0}, m[N];
    unsigned char held[N];
    straight(x, N, dr_v3(0, 0, 0), dr_v3(1, 0, 0), 0.01);
    for (int i = 0; i < N; i++) m[i] = 1e-8, held[i] = 1;
    int off[2] = {0, N};
    double *rad = radii(N), ratio = 2, lv = 0.001;
    DrFilmDesc d;
    dr_film_desc_default(&d);
    d.surface_tension = 0; /* nothing moves: only the limit acts */
    d.gravity = dr_v3(0, 0, 0);
    DrFilm *f;
    CHECK(dr_film_create(&d, 1, off, rad, x, &ratio, &f, ERR));
    DrFilmState fs = dr_film_state(f);
    double vmax = DR_PI * R * R * (36 - 1) * lv;
    fs.volume[2] = DR_PI * R * R * (49 - 1) * lv;   /* H/r 7, nearer the root */
    fs.volume[8] = DR_PI * R * R * (42.25 - 1) * lv; /* H/r 6.5, nearer the tip */
    double ex2 = fs.volume[2] - vmax, ex8 = fs.volume[8] - vmax, V0 = total_volume(f);
    DrFilmStats st = {0};
    CHECK(dr_film_step(f, x, x, v, m, held, 1e-3, &st, ERR));
    assert_true(fabs(fs.pool[0] - ex2) <= 1e-12 * ex2);
    assert_true(fabs(fs.pool[1] - ex8) <= 1e-12 * ex8);
    assert_true(fabs(fs.volume[2] - vmax) <= 1e-12 * vmax && fabs(fs.volume[8] - vmax) <= 1e-12 * vmax);
    assert_true(fabs(st.to_pools - (ex2 + ex8)) <= 1e-12 * (ex2 + ex8));
    assert_true(fabs(total_volume(f) - V0) <= 1e-14 * V0);
    assert_true(st.max_ratio <= 6 * (1 + 1e-12));
    dr_film_destroy(&f);
    free(rad);
}

/* ---- pools move with their end vertex ---------------------------------------------------------------------------- */

static void test_pools_move_with_end(void **state)
{
    (void)state;
    enum { N = 6 };
    double x[3 * N], v[3 * N];
    straight(x, N, dr_v3(0, 0, 0), dr_v3(0, 0, 1), 0.005);
    int off[2] = {0, N};
    double *rad = radii(N), ratio = 1.0, h = 1e-3;
    DrFilmDesc d;
    dr_film_desc_default(&d);
    DrFilm *f;
    CHECK(dr_film_create(&d, 1, off, rad, x, &ratio, &f, ERR)); /* dry: only the pools carry liquid */
    DrFilmState fs = dr_film_state(f);
    fs.pool[0] = 2e-11, fs.pool[1] = 5e-11;
    for (int i = 0; i < N; i++) v[3 * i] = 0.1 * i, v[3 * i + 1] = -0.2, v[3 * i + 2] = 0.05 * i * i;
    DrFilmStats st = {0};
    dr_film_measure(f, x, v, &st);
    DrVec3 want = dr_v3_add(dr_v3_scale(dr_v3(v[0], v[1], v[2]), RHO * fs.pool[0]),
                            dr_v3_scale(dr_v3(v[3 * N - 3], v[3 * N - 2], v[3 * N - 1]), RHO * fs.pool[1]));
    assert_true(dr_v3_norm(dr_v3_sub(st.momentum, want)) <= 1e-14 * dr_v3_norm(want));
    assert_true(fabs(st.pools - 7e-11) <= 1e-24);
    /* the solve carries a pool with its vertex in every direction: ρ V_pool I, and its weight */
    double *force = calloc(3 * N, sizeof(double)), *dfdv = calloc(9 * N, sizeof(double));
    dr_film_hair_load(f, x, v, h, force, dfdv);
    double *Dt = dfdv + 9 * (N - 1);
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) assert_true(fabs(Dt[3 * a + b] - (a == b ? -RHO * fs.pool[1] / h : 0)) <= 1e-18);
    assert_true(fabs(force[3 * (N - 1) + 1] - (RHO * fs.pool[1] * (v[3 * N - 2] / h - 9.81))) <= 1e-18);
    for (int i = 1; i < N - 1; i++)
        for (int q = 0; q < 9; q++) assert_true(dfdv[9 * i + q] == 0);
    free(force), free(dfdv);
    dr_film_destroy(&f);
    free(rad);
}

/* ---- exchange between strands ------------------------------------------------------------------------------------ */

static void test_exchange_conserves(void **state)
{
    (void)state;
    enum { N = 8, V = 2 * N };
    double x[3 * V], v[3 * V], m[V], dV[V] = {0};
    arc(x, N, dr_v3(0, 0, 0), 0.01, 0.8, 0);
    straight(x + 3 * N, N, dr_v3(0, 0.001, 0), dr_v3(0.6, 0.8, 0), 0.008);
    int off[3] = {0, N, V};
    double *rad = radii(V), ratio[2] = {3, 1.5};
    DrFilmDesc d;
    dr_film_desc_default(&d);
    DrFilm *f;
    CHECK(dr_film_create(&d, 2, off, rad, x, ratio, &f, ERR));
    DrFilmState fs = dr_film_state(f);
    for (int i = 0; i < V; i++) {
        m[i] = 1e-8 * (1 + 0.1 * i);
        v[3 * i] = i < N ? 0.3 : -0.2, v[3 * i + 1] = 0.01 * i, v[3 * i + 2] = i < N ? 0.0 : 0.1;
    }
    for (int e = 0; e < fs.nedges; e++) fs.u[e] = 0.02 * (e % 3) - 0.01;
    /* from strand 0's vertices 2–5 to strand 1's vertices 3–6 */
    for (int j = 0; j < 4; j++) {
        double q = 0.3 * fs.volume[2 + j];
        dV[2 + j] = -q;
        dV[N + 3 + j] = q;
    }
    double V0 = total_volume(f);
    DrFilmStats a = {0}, b = {0};
    dr_film_measure(f, x, v, &a);
    DrVec3 P0 = a.momentum;
    for (int i = 0; i < V; i++) P0 = dr_v3_add(P0, dr_v3_scale(dr_v3(v[3 * i], v[3 * i + 1], v[3 * i + 2]), m[i]));
    dr_film_exchange(f, x, dV, v, m);
    dr_film_measure(f, x, v, &b);
    DrVec3 P1 = b.momentum;
    for (int i = 0; i < V; i++) P1 = dr_v3_add(P1, dr_v3_scale(dr_v3(v[3 * i], v[3 * i + 1], v[3 * i + 2]), m[i]));
    print_message("exchange: volume drift %.2e, momentum drift %.2e of |P|\n", fabs(total_volume(f) - V0) / V0,
                  dr_v3_norm(dr_v3_sub(P1, P0)) / dr_v3_norm(P0));
    assert_true(fabs(total_volume(f) - V0) <= 1e-14 * V0);
    assert_true(dr_v3_norm(dr_v3_sub(P1, P0)) <= 1e-12 * dr_v3_norm(P0));
    assert_true(v[3 * (N + 4)] > -0.2); /* the liquid from the faster strand pushed the receiving one */
    dr_film_destroy(&f);
    free(rad);
}

/* ---- failures, allocation, threads, bad input, degenerate strands ------------------------------------------------- */

static void test_non_finite(void **state)
{
    (void)state;
    enum { N = 10 };
    double x[3 * N], v[3 * N] = {0}, m[N];
    straight(x, N, dr_v3(0, 0, 0), dr_v3(0, -1, 0), 0.01);
    for (int i = 0; i < N; i++) m[i] = 1e-8;
    int off[2] = {0, N};
    double *rad = radii(N), ratio = 2;
    DrFilmDesc d;
    dr_film_desc_default(&d);
    DrFilm *f;
    CHECK(dr_film_create(&d, 1, off, rad, x, &ratio, &f, ERR));
    CHECK(dr_film_step(f, x, x, v, m, NULL, 1e-3, NULL, ERR)); /* a film in motion */
    DrFilmState fs = dr_film_state(f);
    double vol[N], u[N], pool[2], speed[N], vs[3 * N], x2[3 * N];
    memcpy(vol, fs.volume, sizeof vol), memcpy(u, fs.u, (N - 1) * sizeof(double)), memcpy(pool, fs.pool, sizeof pool);
    memcpy(speed, fs.strand_speed, (N - 1) * sizeof(double));
    for (int which = 0; which < 3; which++) {
        memcpy(x2, x, sizeof x);
        if (which == 0) v[3 * 4 + 1] = NAN;
        if (which == 1) v[3 * 4 + 1] = 0, x2[3 * 7] = NAN;
        if (which == 2) x2[3 * 7] = 0, m[3] = NAN;
        memcpy(vs, v, sizeof v);
        DrError err;
        DrStatus s = dr_film_step(f, x, x2, v, m, NULL, 1e-3, NULL, &err);
        assert_int_equal(s, DR_ERR_RUNTIME);
        assert_non_null(strstr(err.message, "non-finite"));
        assert_memory_equal(vol, fs.volume, sizeof vol);
        assert_memory_equal(u, fs.u, (N - 1) * sizeof(double));
        assert_memory_equal(pool, fs.pool, sizeof pool);
        assert_memory_equal(speed, fs.strand_speed, (N - 1) * sizeof(double));
        assert_memory_equal(vs, v, sizeof v);
    }
    m[3] = 1e-8;
    CHECK(dr_film_step(f, x, x, v, m, NULL, 1e-3, NULL, ERR)); /* and it goes on */
    dr_film_destroy(&f);
    free(rad);
}

static void test_no_allocation(void **state)
{
    (void)state;
    enum { S = 4, N = 12 };
    double x[3 * S * N];
    for (int s = 0; s < S; s++) arc(x + 3 * s * N, N, dr_v3(0.01 * s, 0, 0), 0.015, -1.2, 0.001);
    DrFilmDesc d;
    dr_film_desc_default(&d);
    Rig rg;
    rig_make(&rg, S, N, x, DR_ROD_ROOTS_CLAMPED, d.gravity, &d, 3);
    double dV[S * N] = {0};
    dV[3] = -1e-13, dV[N + 5] = 1e-13;
    DrFilmStats st = {0};
    CHECK(rig_step(&rg, 1 / 480.0, NULL, &st, ERR));
    uint64_t film = 0;
    for (int k = 1; k < 12; k++) {
        DrXform X = shaken(k / 480.0);
        DrRodState rs = dr_rod_set_state(rg.r);
        uint64_t before = dr_alloc_count();
        memset(rg.force, 0, 3 * (size_t)rg.V * sizeof(double));
        dr_film_hair_load(rg.f, rs.x, rs.v, 1 / 480.0, rg.force, rg.dfdv);
        film += dr_alloc_count() - before;
        CHECK(dr_rod_set_predict(rg.r, 1 / 480.0, &X, NULL, 0, ERR));
        CHECK(dr_rod_set_solve(rg.r, rg.force, rg.dfdv, NULL, ERR));
        memcpy(rg.xold, rs.x, 3 * (size_t)rg.V * sizeof(double));
        CHECK(dr_rod_set_commit(rg.r, NULL, ERR));
        before = dr_alloc_count();
        CHECK(dr_film_step(rg.f, rg.xold, rs.x, rs.v, rs.mass, rg.held, 1 / 480.0, &st, ERR));
        dr_film_exchange(rg.f, rs.x, dV, rs.v, rs.mass);
        dr_film_measure(rg.f, rs.x, rs.v, &st);
        film += dr_alloc_count() - before;
    }
    assert_int_equal(film, 0);
    rig_free(&rg);
}

static void run_threads(int threads, DrFilm **out_f, double **out_v)
{
    enum { S = 40, N = 14 };
    dr_set_threads(threads);
    double *x = malloc(3 * S * N * sizeof(double));
    for (int s = 0; s < S; s++) arc(x + 3 * s * N, N, dr_v3(0.004 * s, 0.001 * (s % 5), 0), 0.01 + 0.0002 * s, -1.0 - 0.01 * s, 0.001);
    DrFilmDesc d;
    dr_film_desc_default(&d);
    Rig *rg = malloc(sizeof *rg);
    rig_make(rg, S, N, x, DR_ROD_ROOTS_CLAMPED, d.gravity, &d, 4);
    DrFilmState fs = dr_film_state(rg->f);
    for (int i = 0; i < fs.nverts; i++) fs.volume[i] *= 1 + 0.3 * sin(0.7 * i);
    for (int k = 0; k < 30; k++) {
        DrXform X = shaken((k + 1) / 480.0);
        CHECK(rig_step(rg, 1 / 480.0, &X, NULL, ERR));
    }
    DrRodState rs = dr_rod_set_state(rg->r);
    *out_v = malloc(3 * S * N * sizeof(double));
    memcpy(*out_v, rs.v, 3 * S * N * sizeof(double));
    *out_f = rg->f;
    rg->f = NULL;
    rig_free(rg);
    free(rg);
    free(x);
    dr_set_threads(0);
}

static void test_threads_same_bits(void **state)
{
    (void)state;
    DrFilm *a, *b;
    double *va, *vb;
    run_threads(1, &a, &va);
    run_threads(2, &b, &vb);
    DrFilmState sa = dr_film_state(a), sb = dr_film_state(b);
    assert_memory_equal(sa.volume, sb.volume, (size_t)sa.nverts * sizeof(double));
    assert_memory_equal(sa.u, sb.u, (size_t)sa.nedges * sizeof(double));
    assert_memory_equal(sa.pool, sb.pool, 2 * (size_t)sa.nstrands * sizeof(double));
    assert_memory_equal(sa.strand_speed, sb.strand_speed, (size_t)sa.nedges * sizeof(double));
    assert_memory_equal(va, vb, 3 * (size_t)sa.nverts * sizeof(double));
    dr_film_destroy(&a), dr_film_destroy(&b);
    free(va), free(vb);
}

static void test_bad_input(void **state)
{
    (void)state;
    double x[9] = {0, 0, 0, 0, 0, 0.001, 0, 0, 0.002}, rad[3] = {R, R, R}, ratio = 2;
    int off[2] = {0, 3};
    DrFilm *f = NULL;
    DrError err;
    const char *fields[6] = {"density", "viscosity", "surface_tension", "max_ratio", "friction", "substeps"};
    for (int c = 0; c < 6; c++) {
        DrFilmDesc d;
        dr_film_desc_default(&d);
        if (c == 0) d.density = 0;
        if (c == 1) d.viscosity = -1;
        if (c == 2) d.surface_tension = NAN;
        if (c == 3) d.max_ratio = 1;
        if (c == 4) d.friction = -0.5;
        if (c == 5) d.substeps = 0;
        assert_int_equal(dr_film_create(&d, 1, off, rad, x, &ratio, &f, &err), DR_ERR_INPUT);
        assert_null(f);
        assert_non_null(strstr(err.message, fields[c]));
    }
    DrFilmDesc d;
    dr_film_desc_default(&d);
    double big = 7;
    assert_int_equal(dr_film_create(&d, 1, off, rad, x, &big, &f, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "initial_ratio"));
    int off1[2] = {0, 1};
    assert_int_equal(dr_film_create(&d, 1, off1, rad, x, &ratio, &f, &err), DR_ERR_INPUT);
    double xz[9] = {0, 0, 0, 0, 0, 0, 0, 0, 1};
    assert_int_equal(dr_film_create(&d, 1, off, rad, xz, &ratio, &f, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "zero-length"));
    double r0[3] = {R, 0, R};
    assert_int_equal(dr_film_create(&d, 1, off, r0, x, &ratio, &f, &err), DR_ERR_INPUT);
    assert_null(f);
}

static void test_degenerate(void **state)
{
    (void)state;
    DrFilmDesc d;
    dr_film_desc_default(&d);
    DrFilm *f;
    int off0[1] = {0};
    CHECK(dr_film_create(&d, 0, off0, NULL, NULL, NULL, &f, ERR)); /* no strands */
    DrFilmStats st = {0};
    CHECK(dr_film_step(f, NULL, NULL, NULL, NULL, NULL, 1e-3, &st, ERR));
    assert_true(st.volume == 0 && st.substeps == 0);
    dr_film_destroy(&f);
    /* one edge, falling, wet; and a dry strand beside it */
    double x[12] = {0, 0, 0, 0, -0.002, 0, 0.01, 0, 0, 0.01, -0.002, 0}, v[12] = {0}, m[4] = {1e-8, 1e-8, 1e-8, 1e-8};
    double rad[4] = {R, R, R, R}, ratio[2] = {3, 1};
    int off[3] = {0, 2, 4};
    CHECK(dr_film_create(&d, 2, off, rad, x, ratio, &f, ERR));
    double V0 = total_volume(f);
    unsigned char held[4] = {1, 0, 1, 0};
    for (int k = 0; k < 50; k++) CHECK(dr_film_step(f, x, x, v, m, held, 1e-3, &st, ERR));
    DrFilmState fs = dr_film_state(f);
    assert_true(fabs(total_volume(f) - V0) <= 1e-14 * V0);
    assert_true(fs.pool[1] > 0 && min_volume(f) >= 0);
    assert_true(fs.volume[2] == 0 && fs.volume[3] == 0 && fs.pool[2] == 0 && fs.pool[3] == 0 && fs.u[1] == 0);
    dr_film_destroy(&f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_volume_exact),        cmocka_unit_test(test_terminal_velocity),
        cmocka_unit_test(test_free_hair_momentum),  cmocka_unit_test(test_accelerated_hair),
        cmocka_unit_test(test_bump_spreads),        cmocka_unit_test(test_violent_shake),
        cmocka_unit_test(test_max_ratio_nearer_pool), cmocka_unit_test(test_pools_move_with_end),
        cmocka_unit_test(test_exchange_conserves),  cmocka_unit_test(test_non_finite),
        cmocka_unit_test(test_no_allocation),       cmocka_unit_test(test_threads_same_bits),
        cmocka_unit_test(test_bad_input),           cmocka_unit_test(test_degenerate),
        cmocka_unit_test(test_submerged_film_neutral), cmocka_unit_test(test_pressure_impulse_exact),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
