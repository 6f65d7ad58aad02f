/* Validation of the MPM solver against [APIC] §6 (parameters of PHYSICS §2):
 *   rotating elastic disk (§6.1): initial L and KE, angular momentum per scheme and integrator, curves;
 *   rebound between two slip walls (§6.2) and skew impact of two disks (§6.3): initial energies, the
 *     momenta the setting conserves, no energy growth;
 *   ringing (§6.7): FLIP keeps high-frequency particle velocity noise that PIC and APIC remove;
 *   3-D skew impact of two spheres (§6.5) at a CI resolution: linear and angular momentum.
 * Curves go to CSV files under out/validation, and to PNG when gnuplot is installed. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <cmocka.h>

#include "mpm/mpm.h"

typedef struct Ball { double cx, cy, cz, r; } Ball;
static bool in_disk(DrVec3 x, void *ctx)
{
    const Ball *b = ctx;
    return (x.x - b->cx) * (x.x - b->cx) + (x.y - b->cy) * (x.y - b->cy) < b->r * b->r;
}
static bool in_ball(DrVec3 x, void *ctx)
{
    const Ball *b = ctx;
    return (x.x - b->cx) * (x.x - b->cx) + (x.y - b->cy) * (x.y - b->cy) + (x.z - b->cz) * (x.z - b->cz) < b->r * b->r;
}
typedef struct Rect { double x0, y0, x1, y1; } Rect;
static bool in_rect(DrVec3 x, void *ctx)
{
    const Rect *r = ctx;
    return x.x >= r->x0 && x.x <= r->x1 && x.y >= r->y0 && x.y <= r->y1;
}

static void ensure_out(void)
{
    mkdir("out", 0777);
    mkdir("out/validation", 0777);
}

static bool have_gnuplot(void) { return system("command -v gnuplot >/dev/null 2>&1") == 0; }

static double total_energy(const DrMpmTotals *t) { return t->kinetic + t->elastic + t->gravity_potential; }

/* Kinetic energy of the particles' affine velocity fields, ½ Σ m tr(C D Cᵀ) = ½ Σ m D ‖C‖²_F (quadratic
   kernel, D = Δx²/4): part of APIC's state, as the angular momentum's affine term is ([APIC] §6.1 counts
   it: "the energy and angular momentum for APIC is slightly higher"). Zero for PIC and FLIP (C = 0). */
static double affine_energy(const DrMpm *m, double dx)
{
    DrMpmState s = dr_mpm_state(m);
    double e = 0;
    for (long p = 0; p < s.n; p++) {
        double c2 = 0;
        for (int k = 0; k < 9; k++) c2 += s.C[9 * p + k] * s.C[9 * p + k];
        e += 0.5 * s.mass[p] * dx * dx / 4.0 * c2;
    }
    return e;
}

/* ==== 2. rotating disk (§6.1) ======================================================================= */

#define DISK_FRAMES 120
typedef struct DiskRun {
    const char *name;
    DrTransferScheme scheme;
    DrMpmIntegrator integ;
    double E[DISK_FRAMES + 1], L[DISK_FRAMES + 1];
    double seconds;
    long newton, cg;
} DiskRun;

static DrMpm *make_disk(DrTransferScheme scheme, DrMpmIntegrator integ, double newton_tol)
{
    DrMpmDesc d;
    dr_mpm_desc_default(&d);
    d.dim = 2;
    d.lo = dr_v3(0, 0, 0);
    d.hi = dr_v3(1, 1, 0);
    d.dx = 1.0 / 32.0;
    d.scheme = scheme;
    d.integrator = integ;
    d.newton_tolerance = newton_tol;
    d.cg_tolerance = 1e-12;
    DrMpm *m = NULL;
    DrError err;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
    DrMpmMaterial mat = {DR_MPM_NEOHOOKEAN, 2.0, 1000.0, 0.3};
    Ball b = {0.5, 0.5, 0, 0.3};
    long count;
    assert_int_equal(dr_mpm_sample_body(m, in_disk, &b, dr_v3(0.2, 0.2, 0), dr_v3(0.8, 0.8, 0), 2, dr_v3(0, 0, 0),
                                        dr_v3(0, 0, 0.4), dr_v3(0.5, 0.5, 0), &mat, NULL, &count, &err),
                     DR_OK);
    return m;
}

/* Symplectic Euler is explicit: the step must resolve the dilatational wave, c = √((λ+2μ)/ρ) = 25.9 m/s,
   Δx/c = 1.2 ms; 1/24 s over 84 steps (0.5 ms, ν = 0.4) is used. The implicit
   integrators take the CFL step of §4.3 (ν = 1), capped at one frame: one step per frame here. */
static void run_disk(DiskRun *r, double newton_tol)
{
    DrMpm *m = make_disk(r->scheme, r->integ, newton_tol);
    DrError err;
    DrMpmTotals t = dr_mpm_totals(m, -1);
    r->E[0] = total_energy(&t) + affine_energy(m, 1.0 / 32.0), r->L[0] = t.angular.z;
    double t0 = dr_time_now();
    r->newton = r->cg = 0;
    for (int f = 1; f <= DISK_FRAMES; f++) {
        DrMpmStats st;
        if (r->integ == DR_MPM_SYMPLECTIC_EULER) {
            for (int s = 0; s < 84; s++) assert_int_equal(dr_mpm_step(m, 1.0 / 24.0 / 84.0, &st, &err), DR_OK);
        } else {
            assert_int_equal(dr_mpm_advance(m, 1.0 / 24.0, 16, &st, &err), DR_OK);
            r->newton += st.newton_iterations, r->cg += st.cg_iterations;
        }
        t = dr_mpm_totals(m, -1);
        r->E[f] = total_energy(&t) + affine_energy(m, 1.0 / 32.0), r->L[f] = t.angular.z;
    }
    r->seconds = dr_time_now() - t0;
    dr_mpm_destroy(&m);
}

static void test_rotating_disk(void **state)
{
    (void)state;
    /* initial state against the continuum: L = ρωπR⁴/2, KE = ρω²πR⁴/4 */
    const double L_exact = 2.0 * 0.4 * DR_PI * pow(0.3, 4) / 2.0, KE_exact = 2.0 * 0.16 * DR_PI * pow(0.3, 4) / 4.0;
    DrMpm *m = make_disk(DR_TRANSFER_PIC, DR_MPM_MIDPOINT, 1e-10);
    DrMpmTotals t = dr_mpm_totals(m, -1);
    double L_pic = t.angular.z, KE = t.kinetic;
    dr_mpm_destroy(&m);
    m = make_disk(DR_TRANSFER_APIC, DR_MPM_MIDPOINT, 1e-10);
    DrMpmTotals ta = dr_mpm_totals(m, -1);
    DrMpmState s = dr_mpm_state(m);
    double mass = 0;
    for (long p = 0; p < s.n; p++) mass += s.mass[p];
    dr_mpm_destroy(&m);
    /* the affine part of APIC: Σ m ε:(C D)ᵀ = M·2ω·Δx²/4 for C = [ω]×, D = Δx²/4 */
    double L_affine = mass * 2.0 * 0.4 * (1.0 / 32.0) * (1.0 / 32.0) / 4.0;
    printf("rotating disk: %ld particles; L (no affine part) %.6f vs %.6f exact (%.2f%%), KE %.5e vs %.5e (%.2f%%); "
           "APIC L %.6f = +%.2f%% (affine part %.6f)\n",
           s.n, L_pic, L_exact, 100 * (L_pic / L_exact - 1), KE, KE_exact, 100 * (KE / KE_exact - 1), ta.angular.z,
           100 * (ta.angular.z / L_pic - 1), L_affine);
    /* Lattice quadrature of ∫r² over the disk: the error comes from the cells the rim cuts, a layer of
       area 2πR·h with an r² weight R², relative 4h/R = 0.2 as a bound; with 2-per-axis sampling the rim
       errors largely cancel (measured 0.3 %). 1 % is the tolerance. */
    assert_true(fabs(L_pic / L_exact - 1) < 0.01);
    assert_true(fabs(KE / KE_exact - 1) < 0.01);
    /* the APIC total is exactly the translational part plus the affine term (the paper's "about 1 %") */
    assert_true(fabs(ta.angular.z - (L_pic + L_affine)) < 1e-14);

    DiskRun runs[] = {
        {"APIC symplectic Euler", DR_TRANSFER_APIC, DR_MPM_SYMPLECTIC_EULER, {0}, {0}, 0, 0, 0},
        {"APIC midpoint", DR_TRANSFER_APIC, DR_MPM_MIDPOINT, {0}, {0}, 0, 0, 0},
        {"APIC backward Euler", DR_TRANSFER_APIC, DR_MPM_BACKWARD_EULER, {0}, {0}, 0, 0, 0},
        {"PIC midpoint", DR_TRANSFER_PIC, DR_MPM_MIDPOINT, {0}, {0}, 0, 0, 0},
    };
    const int nrun = sizeof runs / sizeof *runs;
    for (int k = 0; k < nrun; k++) {
        run_disk(&runs[k], k < 2 ? 1e-12 : 1e-8); /* tight where conservation is asserted */
        double worst = 0, grow = 0;
        for (int f = 0; f <= DISK_FRAMES; f++) worst = fmax(worst, fabs(runs[k].L[f] / runs[k].L[0] - 1));
        for (int f = 0; f <= DISK_FRAMES; f++) grow = fmax(grow, runs[k].E[f] / runs[k].E[0] - 1);
        printf("  %-22s max E(t)/E0 - 1 = %.3e\n", runs[k].name, grow);
        printf("  %-22s L0 %.8f, L(5 s) %.8f: max |ΔL|/L %.3e, E0 %.6e, E(5 s) %.6e (%+.3f%%); %.2f s, Newton %ld, "
               "CG %ld\n",
               runs[k].name, runs[k].L[0], runs[k].L[DISK_FRAMES], worst, runs[k].E[0], runs[k].E[DISK_FRAMES],
               100 * (runs[k].E[DISK_FRAMES] / runs[k].E[0] - 1), runs[k].seconds, runs[k].newton, runs[k].cg);
    }
    /* APIC with the two λ-family integrators: conserved to the round-off of ~10⁵ steps of sums over ~10³
       particles (symplectic Euler) and to the Newton tolerance 1e-12 (midpoint) */
    for (int k = 0; k < 2; k++)
        for (int f = 0; f <= DISK_FRAMES; f++) assert_true(fabs(runs[k].L[f] / runs[k].L[0] - 1) <= 1e-10);
    /* PIC loses a clear fraction of its angular momentum; backward Euler some */
    double pic_loss = 1 - runs[3].L[DISK_FRAMES] / runs[3].L[0];
    double be_loss = 1 - runs[2].L[DISK_FRAMES] / runs[2].L[0];
    printf("  PIC loses %.1f%% of L over 5 s, APIC backward Euler %.2f%%\n", 100 * pic_loss, 100 * be_loss);
    assert_true(pic_loss > 0.10);
    assert_true(be_loss > 1e-4);
    /* Energy (kinetic incl. APIC's affine part + elastic). The dissipative runs (backward Euler, PIC)
       never gain energy beyond round-off. The λ-family runs keep it bounded without drift: symplectic
       Euler to 3e-7, midpoint to 1.3e-3 at one step per frame. Midpoint conserves the energy of its grid
       update only where F follows the grid motion exactly; eq. (40)'s first-order F ← (I + Δt∇v)F stretches
       a rigidly rotating particle by O((ωΔt)²) = 3e-4 per step, which the elastic energy then carries
       (the likely source of the growth; not separately verified). 2e-3 bounds it. */
    for (int k = 0; k < nrun; k++)
        for (int f = 0; f <= DISK_FRAMES; f++) {
            if (k < 2) assert_true(fabs(runs[k].E[f] / runs[k].E[0] - 1) <= 2e-3);
            else assert_true(runs[k].E[f] <= runs[k].E[0] * (1 + 1e-10));
        }

    ensure_out();
    FILE *fp = fopen("out/validation/rotating_disk.csv", "w");
    assert_non_null(fp);
    fprintf(fp, "time");
    for (int k = 0; k < nrun; k++) fprintf(fp, ",E %s,L %s", runs[k].name, runs[k].name);
    fprintf(fp, "\n");
    for (int f = 0; f <= DISK_FRAMES; f++) {
        fprintf(fp, "%.6f", f / 24.0);
        for (int k = 0; k < nrun; k++) fprintf(fp, ",%.12e,%.12e", runs[k].E[f], runs[k].L[f]);
        fprintf(fp, "\n");
    }
    fclose(fp);
    if (have_gnuplot()) {
        fp = fopen("out/validation/rotating_disk.gp", "w");
        assert_non_null(fp);
        fprintf(fp, "set datafile separator ','\nset terminal pngcairo size 1100,420 noenhanced\n"
                    "set output 'out/validation/rotating_disk.png'\nset multiplot layout 1,2 title 'rotating disk "
                    "(APIC paper 6.1)'\nset key bottom left\nset xlabel 'time (s)'\nset ylabel 'total energy (J/m)'\n"
                    "plot for [k=0:%d] 'out/validation/rotating_disk.csv' using 1:(column(2+2*k)) with lines "
                    "title columnheader(2+2*k)\nset ylabel 'angular momentum (kg m^2/s per m)'\n"
                    "plot for [k=0:%d] 'out/validation/rotating_disk.csv' using 1:(column(3+2*k)) with lines "
                    "title columnheader(3+2*k)\nunset multiplot\n",
                nrun - 1, nrun - 1);
        fclose(fp);
        assert_int_equal(system("gnuplot out/validation/rotating_disk.gp"), 0);
    } else {
        printf("SKIP rotating_disk.png: gnuplot not installed (CSV written)\n");
    }
}

/* ==== 3. rebound (§6.2) and skew impact (§6.3) ======================================================== */

typedef struct Hist { double E, Px, Py, Lz; } Hist;

static DrMpm *make_box2(double w, double h, double dx, DrMpmWall xwall)
{
    DrMpmDesc d;
    dr_mpm_desc_default(&d);
    d.dim = 2;
    d.lo = dr_v3(0, 0, 0);
    d.hi = dr_v3(w, h, 0);
    d.dx = dx;
    d.integrator = DR_MPM_MIDPOINT;
    d.newton_tolerance = 1e-12;
    d.cg_tolerance = 1e-12;
    d.wall[0] = d.wall[1] = xwall;
    d.wall[2] = d.wall[3] = xwall;
    DrMpm *m = NULL;
    DrError err;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
    return m;
}

/* A disk on the lattice of dr_mpm_sample_body (spacing Δx/2 from the box corner, first point half a
   spacing in) with the particle volume πR²/count instead of h²: the body then has the continuum's mass
   ρπR² exactly, as the drivers' KE₀ and L₀ assume. With vol = h² the lattice area of these coarse disks
   (R = 6 and 4 spacings) is off by −1.0 % (rebound, 112 points) and +3.5 % (skew impact, 52 points). */
static void add_disk_exact(DrMpm *m, double dx, double cx, double cy, double R, double vx, const DrMpmMaterial *mat)
{
    double h = dx / 2, *x = malloc(sizeof(double) * 3 * 4096), *v = calloc(3 * 4096, sizeof(double)),
           *vol = malloc(sizeof(double) * 4096);
    long n = 0;
    for (long j = 0; j < 4096; j++)
        for (long i = 0; i < 4096; i++) {
            double px = (i + 0.5) * h, py = (j + 0.5) * h;
            if (px > cx + R || py > cy + R) continue;
            if ((px - cx) * (px - cx) + (py - cy) * (py - cy) >= R * R) continue;
            assert_true(n < 4096);
            x[3 * n] = px, x[3 * n + 1] = py, x[3 * n + 2] = 0, v[3 * n] = vx;
            n++;
        }
    for (long p = 0; p < n; p++) vol[p] = DR_PI * R * R / n;
    DrError err;
    assert_int_equal(dr_mpm_add_particles(m, n, x, v, vol, NULL, mat, NULL, &err), DR_OK);
    free(x), free(v), free(vol);
}

static Hist hist(const DrMpm *m)
{
    DrMpmTotals t = dr_mpm_totals(m, -1);
    Hist h = {total_energy(&t), t.momentum.x, t.momentum.y, t.angular.z};
    return h;
}

static void test_rebound(void **state)
{
    (void)state;
    DrMpm *m = make_box2(15, 5, 0.5, DR_MPM_WALL_SLIP);
    DrMpmMaterial mat = {DR_MPM_NEOHOOKEAN, 4.0, 85.5, 0.425};
    DrError err;
    add_disk_exact(m, 0.5, 2.5, 2.5, 1.5, 0.5, &mat);
    Hist h0 = hist(m);
    printf("rebound: KE0 %.4f (PHYSICS 3.534), P0 %.4f\n", h0.E, h0.Px);
    /* ½ρπR²v² = 3.5343; the printed value has 4 digits */
    assert_true(fabs(h0.E / 3.534 - 1) < 2e-4);
    /* The slip walls at x = 0 and x = 15 push along x only: P_y is conserved. Their pressure on the disk
       is symmetric about y = 2.5 (disk, lattice and grid are mirror-symmetric there), so its resultant
       acts on that line and the angular momentum about any point of it, L_c = L_z + 2.5 P_x, is
       conserved. Before the disk's stencil reaches the wall layer (x ≥ 14.5 − 1.5Δx = 13.75 for the
       particles, t ≈ 19.5 s) everything is conserved. */
    double tmax = 30.0, Emax = h0.E, Lc0 = h0.Lz + 2.5 * h0.Px, wPy = 0, wLc = 0, wfree = 0;
    int frames = (int)(tmax * 24), contact = -1;
    ensure_out();
    FILE *fp = fopen("out/validation/rebound.csv", "w");
    assert_non_null(fp);
    fprintf(fp, "time,E,Px,Py,Lz\n");
    for (int f = 1; f <= frames; f++) {
        DrMpmStats st;
        assert_int_equal(dr_mpm_advance(m, 1.0 / 24.0, 16, &st, &err), DR_OK);
        Hist h = hist(m);
        fprintf(fp, "%.5f,%.12e,%.12e,%.12e,%.12e\n", f / 24.0, h.E, h.Px, h.Py, h.Lz);
        DrMpmState s = dr_mpm_state(m);
        double xmax = 0;
        for (long p = 0; p < s.n; p++) xmax = fmax(xmax, s.x[3 * p]);
        if (contact < 0 && xmax > 15 - 0.5 - 1.5 * 0.5) contact = f;
        if (contact < 0) wfree = fmax(wfree, fmax(fabs(h.Px / h0.Px - 1), fabs(h.Lz / h0.Lz - 1)));
        Emax = fmax(Emax, h.E);
        wPy = fmax(wPy, fabs(h.Py) / h0.Px);
        wLc = fmax(wLc, fabs(h.Lz + 2.5 * h.Px - Lc0) / (1.5 * h0.Px));
    }
    fclose(fp);
    Hist h1 = hist(m);
    printf("rebound: contact from t = %.2f s; before it max drift of P_x, L_z %.2e; through it |P_y|/P0 %.2e, "
           "|ΔL_c|/(R P0) %.2e; P_x(%.0f s) = %.4f; E max %.6f, E(%.0f s) = %.6f (%.3f%%)\n",
           contact / 24.0, wfree, wPy, wLc, tmax, h1.Px, Emax, tmax, h1.E, 100 * (h1.E / h0.E - 1));
    assert_true(contact > 0);
    assert_true(wfree < 1e-10);
    assert_true(wPy < 1e-10);
    assert_true(wLc < 1e-10);
    assert_true(h1.Px < -0.5 * h0.Px); /* it bounced */
    /* midpoint conserves the energy of a linear system exactly and this one up to the transfers'
       dissipation; "never grows" holds to the Newton tolerance (1e-12 of the residual) */
    assert_true(Emax <= h0.E * (1 + 1e-8));
    dr_mpm_destroy(&m);
}

static void test_skew_impact(void **state)
{
    (void)state;
    DrMpm *m = make_box2(20, 12, 1.0, DR_MPM_WALL_NONE);
    DrMpmMaterial mat = {DR_MPM_NEOHOOKEAN, 5.0, 31.685, 0.44022};
    DrError err;
    add_disk_exact(m, 1.0, 3, 3, 2, 0.75, &mat);
    add_disk_exact(m, 1.0, 16, 5, 2, -0.75, &mat);
    Hist h0 = hist(m);
    double pscale = 0.75 * 5.0 * DR_PI * 4.0; /* |P| of one disk */
    printf("skew impact: KE0 %.4f (PHYSICS 35.34), L0 %.4f (94.25)\n", h0.E, h0.Lz);
    /* ρπR²v² = 35.343, ρπR²·0.75·(5 − 3) = 94.248; the printed values have 4 digits */
    assert_true(fabs(h0.E / 35.34 - 1) < 2e-4);
    assert_true(fabs(h0.Lz / 94.25 - 1) < 2e-4);
    double tmax = 12.0, Emax = h0.E, wP = 0, wL = 0, dmin = 1e9;
    int frames = (int)(tmax * 24);
    ensure_out();
    FILE *fp = fopen("out/validation/skew_impact.csv", "w");
    assert_non_null(fp);
    fprintf(fp, "time,E,Px,Py,Lz\n");
    for (int f = 1; f <= frames; f++) {
        DrMpmStats st;
        assert_int_equal(dr_mpm_advance(m, 1.0 / 24.0, 16, &st, &err), DR_OK);
        Hist h = hist(m);
        fprintf(fp, "%.5f,%.12e,%.12e,%.12e,%.12e\n", f / 24.0, h.E, h.Px, h.Py, h.Lz);
        Emax = fmax(Emax, h.E);
        wP = fmax(wP, fmax(fabs(h.Px - h0.Px), fabs(h.Py - h0.Py)) / pscale);
        wL = fmax(wL, fabs(h.Lz / h0.Lz - 1));
        DrMpmTotals ta = dr_mpm_totals(m, 0);
        dmin = fmin(dmin, ta.momentum.x); /* disk 0's momentum drops through the impact */
    }
    fclose(fp);
    Hist h1 = hist(m);
    printf("skew impact: max |ΔP|/|P_disk| %.2e, max |ΔL|/L %.2e; disk 0 P_x min %.3f (from %.3f); E max %.6f, "
           "E(%.0f s) %.6f (%.3f%%)\n",
           wP, wL, dmin, pscale, Emax, tmax, h1.E, 100 * (h1.E / h0.E - 1));
    assert_true(dmin < 0.5 * pscale); /* the impact happened */
    assert_true(wP < 1e-10);
    assert_true(wL < 1e-10);
    assert_true(Emax <= h0.E * (1 + 1e-8));
    dr_mpm_destroy(&m);
}

/* ==== 4. ringing (§6.7) =============================================================================== */

static double ground_sdf(DrVec3 x, DrVec3 *n, void *ctx)
{
    (void)ctx;
    *n = dr_v3(0, 1, 0);
    return x.y - 0.35;
}
static double left_sdf(DrVec3 x, DrVec3 *n, void *ctx)
{
    (void)ctx;
    *n = dr_v3(1, 0, 0);
    return x.x - 0.1;
}

typedef struct Ring { double rms, noise, seconds; int steps; } Ring;

/* High-frequency noise of the target's particle velocities: v_p minus the local mean of its neighbours'
   velocities, v̄_p = Σ_q ω_pq m_q v_q / Σ_q ω_pq m_q over target particles within 1.5 Δx (ω = (1 − d²/r²)²),
   RMS over the target, mass-weighted. The mean over ~25 neighbours is what the grid can represent; what
   remains is the particle-to-particle variation that only particles carry: FLIP's null modes. It is
   computed from particle data alone, the same way for every scheme (APIC's particle velocities are not
   the grid-interpolated ones plus nothing by construction: this measure does not favour it). */
static Ring run_ringing(DrTransferScheme scheme)
{
    DrMpmDesc d;
    dr_mpm_desc_default(&d);
    d.dim = 2;
    d.lo = dr_v3(0, 0, 0);
    d.hi = dr_v3(1, 1, 0);
    d.dx = 1.0 / 21.0;
    d.kernel = DR_KERNEL_CUBIC;
    d.scheme = scheme;
    d.integrator = DR_MPM_BACKWARD_EULER;
    d.gravity = dr_v3(0, -2.0, 0);
    d.newton_tolerance = 1e-8;
    d.cg_tolerance = 1e-8;
    DrMpm *m = NULL;
    DrError err;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
    DrMpmCollider ground = {ground_sdf, NULL, dr_v3(0, 0, 0), 0.0, false, NULL},
                  left = {left_sdf, NULL, dr_v3(0, 0, 0), 0.0, false, NULL};
    assert_int_equal(dr_mpm_add_collider(m, &ground, &err), DR_OK);
    assert_int_equal(dr_mpm_add_collider(m, &left, &err), DR_OK);
    DrMpmMaterial mat = {DR_MPM_FIXED_COROTATED, 4.0, 10.0, 0.3};
    Rect proj = {0.15, 0.45, 0.25, 0.55}, targ = {0.6, 0.35, 0.8, 0.65};
    int bp, bt;
    assert_int_equal(dr_mpm_sample_body(m, in_rect, &proj, dr_v3(0.15, 0.45, 0), dr_v3(0.25, 0.55, 0), 2,
                                        dr_v3(3, 0, 0), dr_v3(0, 0, 0), dr_v3(0.2, 0.5, 0), &mat, &bp, NULL, &err),
                     DR_OK);
    assert_int_equal(dr_mpm_sample_body(m, in_rect, &targ, dr_v3(0.6, 0.35, 0), dr_v3(0.8, 0.65, 0), 2,
                                        dr_v3(0, 0, 0), dr_v3(0, 0, 0), dr_v3(0.7, 0.5, 0), &mat, &bt, NULL, &err),
                     DR_OK);
    DrMpmState s = dr_mpm_state(m);
    /* pin the top and bottom rows of the target with zero-length springs, c = 1e5 kg/s² */
    double *k = calloc((size_t)s.n, sizeof(double)), *tg = malloc(sizeof(double) * 3 * (size_t)s.n);
    double ylo = 1, yhi = 0;
    for (long p = 0; p < s.n; p++)
        if (s.body[p] == bt) ylo = fmin(ylo, s.x[3 * p + 1]), yhi = fmax(yhi, s.x[3 * p + 1]);
    for (long p = 0; p < s.n; p++) {
        memcpy(tg + 3 * p, s.x + 3 * p, 3 * sizeof(double));
        if (s.body[p] == bt && (s.x[3 * p + 1] == ylo || s.x[3 * p + 1] == yhi)) k[p] = 1e5;
    }
    assert_int_equal(dr_mpm_set_anchors(m, k, tg, &err), DR_OK);
    free(k), free(tg);
    /* the paper's step rule: Δt* = clamp(ν Δx / max(v_max, v_τ), 1e-6, 5e-3), ν = 0.1, v_τ = 0.01, then
       frame boundaries every 1/24 s without sliver steps. v_max is taken over particle speeds (the grid
       speeds are bounded by them). */
    double t = 0, t_end = 40.0 / 24.0, t0 = dr_time_now();
    int frame = 1, steps = 0;
    while (t < t_end - 1e-12) {
        s = dr_mpm_state(m);
        double vmax = 0;
        for (long p = 0; p < s.n; p++)
            vmax = fmax(vmax, sqrt(s.v[3 * p] * s.v[3 * p] + s.v[3 * p + 1] * s.v[3 * p + 1]));
        double dts = fmax(1e-6, fmin(5e-3, 0.1 * d.dx / fmax(vmax, 0.01)));
        double tf = frame / 24.0 - t, dt = dts;
        if (tf < 1.001 * dts) dt = tf;
        else if (tf < 2 * dts) dt = tf / 2;
        DrMpmStats st;
        DrStatus rc = dr_mpm_step(m, dt, &st, &err);
        assert_true(rc >= 0);
        t += dt, steps++;
        if (fabs(t - frame / 24.0) < 1e-12) t = frame / 24.0, frame++;
    }
    s = dr_mpm_state(m);
    double r = 1.5 * d.dx, sm = 0, sv2 = 0, sn2 = 0;
    for (long p = 0; p < s.n; p++) {
        if (s.body[p] != bt) continue;
        double wsum = 0, vb[2] = {0, 0};
        for (long q = 0; q < s.n; q++) {
            if (s.body[q] != bt) continue;
            double dx = s.x[3 * q] - s.x[3 * p], dy = s.x[3 * q + 1] - s.x[3 * p + 1], d2 = (dx * dx + dy * dy) / (r * r);
            if (d2 >= 1) continue;
            double w = (1 - d2) * (1 - d2) * s.mass[q];
            wsum += w, vb[0] += w * s.v[3 * q], vb[1] += w * s.v[3 * q + 1];
        }
        double ex = s.v[3 * p] - vb[0] / wsum, ey = s.v[3 * p + 1] - vb[1] / wsum;
        sm += s.mass[p];
        sv2 += s.mass[p] * (s.v[3 * p] * s.v[3 * p] + s.v[3 * p + 1] * s.v[3 * p + 1]);
        sn2 += s.mass[p] * (ex * ex + ey * ey);
    }
    Ring out = {sqrt(sv2 / sm), sqrt(sn2 / sm), dr_time_now() - t0, steps};
    dr_mpm_destroy(&m);
    return out;
}

static void test_ringing(void **state)
{
    (void)state;
    Ring flip = run_ringing(DR_TRANSFER_FLIP), pic = run_ringing(DR_TRANSFER_PIC), apic = run_ringing(DR_TRANSFER_APIC);
    printf("ringing at t = 40/24 s (target): RMS speed / RMS high-frequency noise [m/s]: FLIP %.3e / %.3e, PIC %.3e / "
           "%.3e, APIC %.3e / %.3e; noise ratio FLIP/APIC %.1f (steps %d/%d/%d, %.1f/%.1f/%.1f s)\n",
           flip.rms, flip.noise, pic.rms, pic.noise, apic.rms, apic.noise, flip.noise / apic.noise, flip.steps,
           pic.steps, apic.steps, flip.seconds, pic.seconds, apic.seconds);
    assert_true(flip.noise >= 10.0 * apic.noise);
    /* "come to rest": the target's RMS speed under 1 % of the projectile's 3 m/s */
    assert_true(pic.rms < 0.03);
    assert_true(apic.rms < 0.03);
}

/* ==== 6. 3-D skew impact of two spheres (§6.5) ======================================================== */

static void test_spheres_3d(void **state)
{
    (void)state;
    DrMpmIntegrator ints[2] = {DR_MPM_SYMPLECTIC_EULER, DR_MPM_MIDPOINT};
    for (int k = 0; k < 2; k++) {
        DrMpmDesc d;
        dr_mpm_desc_default(&d);
        d.dim = 3;
        d.lo = dr_v3(6, 8, 10);
        d.hi = dr_v3(24, 20, 20);
        d.dx = 30.0 / 64.0;
        d.integrator = ints[k];
        d.newton_tolerance = 1e-12;
        d.cg_tolerance = 1e-12;
        for (int f = 0; f < 6; f++) d.wall[f] = DR_MPM_WALL_NONE;
        DrMpm *m = NULL;
        DrError err;
        assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
        DrMpmMaterial mat = {DR_MPM_NEOHOOKEAN, 5.0, 31.685, 0.44022};
        /* the paper's spheres (R 2, centres 2 apart in y) started 7 apart in x instead of 10: contact from
           t ≈ 1.6 s instead of 3.6 s */
        Ball a = {11.5, 13, 15, 2}, b = {18.5, 15, 15, 2};
        long na, nb;
        assert_int_equal(dr_mpm_sample_body(m, in_ball, &a, dr_v3(9, 10, 12), dr_v3(14, 16, 18), 2, dr_v3(0.75, 0, 0),
                                            dr_v3(0, 0, 0), dr_v3(11.5, 13, 15), &mat, NULL, &na, &err),
                         DR_OK);
        assert_int_equal(dr_mpm_sample_body(m, in_ball, &b, dr_v3(16, 12, 12), dr_v3(21, 18, 18), 2,
                                            dr_v3(-0.75, 0, 0), dr_v3(0, 0, 0), dr_v3(18.5, 15, 15), &mat, NULL, &nb,
                                            &err),
                         DR_OK);
        DrMpmTotals t0 = dr_mpm_totals(m, -1);
        double pscale = dr_v3_norm(dr_mpm_totals(m, 0).momentum), lscale = dr_v3_norm(t0.angular);
        double wP = 0, wL = 0, pmin = 1e9, E0 = total_energy(&t0), Emax = E0, tstart = dr_time_now();
        /* symplectic Euler: c = √((λ+2μ)/ρ) = 4.5 m/s, Δx/c = 0.14 s; 4 steps per 1/24 s frame = 0.0104 s */
        int frames = 4 * 24;
        for (int f = 0; f < frames; f++) {
            DrMpmStats st;
            if (ints[k] == DR_MPM_SYMPLECTIC_EULER)
                for (int s = 0; s < 4; s++) assert_int_equal(dr_mpm_step(m, 1.0 / 96.0, &st, &err), DR_OK);
            else
                assert_int_equal(dr_mpm_advance(m, 1.0 / 24.0, 4, &st, &err), DR_OK);
            DrMpmTotals t = dr_mpm_totals(m, -1);
            wP = fmax(wP, dr_v3_norm(dr_v3_sub(t.momentum, t0.momentum)) / pscale);
            wL = fmax(wL, dr_v3_norm(dr_v3_sub(t.angular, t0.angular)) / lscale);
            pmin = fmin(pmin, dr_mpm_totals(m, 0).momentum.x);
            Emax = fmax(Emax, total_energy(&t));
        }
        printf("3-D spheres (%s): %ld + %ld particles, Δx %.4f; over 4 s max |ΔP|/|P_sphere| %.2e, |ΔL|/|L| %.2e; "
               "sphere 0 P_x min %.3f of %.3f; E max/E0 - 1 = %.2e; %.1f s\n",
               k ? "midpoint" : "symplectic Euler", na, nb, d.dx, wP, wL, pmin, pscale, Emax / E0 - 1,
               dr_time_now() - tstart);
        assert_true(pmin < 0.9 * pscale); /* contact happened */
        assert_true(wP < 1e-10);
        assert_true(wL < 1e-10);
        dr_mpm_destroy(&m);
    }
}

int main(void)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rotating_disk), cmocka_unit_test(test_rebound),     cmocka_unit_test(test_skew_impact),
        cmocka_unit_test(test_ringing),       cmocka_unit_test(test_spheres_3d),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
