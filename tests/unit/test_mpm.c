/* Unit tests of src/mpm: the constitutive models (P = ∂Ψ/∂F and dP = ∂P/∂F : dF against central finite
 * differences, zero stress at rest, rotation invariance, Neo-Hookean's J > 0 domain, fixed corotated on
 * inverted F), the polar decomposition, and the solver's contracts: input checks, sampling, CFL, wall
 * and collider conditions, anchors, momentum kept by an early-stopped CG (§4.2), Newton's quadratic
 * convergence (a check on the force differential of eqs. 35–36 for both F rules), the F update of
 * eqs. (109)–(111), advance's substeps, and bit-identical runs for 1 and 2 threads and after restore. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "mpm/mpm.h"

static const DrMpmModel MODELS[2] = {DR_MPM_NEOHOOKEAN, DR_MPM_FIXED_COROTATED};
static const double MU = 3.0, LAM = 7.0;

static void random_F(DrRng *rng, int dim, double amp, double F[9])
{
    for (int k = 0; k < 9; k++) F[k] = ((k % 4 == 0) ? 1.0 : 0.0) + amp * (2.0 * dr_rng_uniform(rng) - 1.0);
    if (dim == 2) F[2] = F[5] = F[6] = F[7] = 0.0, F[8] = 1.0;
}

static void random_rotation(DrRng *rng, int dim, double Q[9])
{
    DrVec3 e = dr_v3(6.3 * dr_rng_uniform(rng), 6.3 * dr_rng_uniform(rng), 6.3 * dr_rng_uniform(rng));
    if (dim == 2) e.x = e.y = 0.0;
    dr_m3_store(dr_m3_from_euler_xyz(e), Q);
}

static double norm9(const double *a)
{
    double s = 0;
    for (int k = 0; k < 9; k++) s += a[k] * a[k];
    return sqrt(s);
}

static void test_lame_and_rest(void **state)
{
    (void)state;
    DrMpmMaterial mat = {DR_MPM_NEOHOOKEAN, 2.0, 1000.0, 0.3};
    double mu, lam;
    dr_mpm_lame(&mat, &mu, &lam);
    assert_true(fabs(mu - 1000.0 / 2.6) < 1e-12 * mu);
    assert_true(fabs(lam - 300.0 / (1.3 * 0.4)) < 1e-12 * lam);
    double I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    for (int dim = 2; dim <= 3; dim++)
        for (int m = 0; m < 2; m++) {
            double psi = -1, P[9];
            assert_true(dr_mpm_energy_density(MODELS[m], dim, MU, LAM, I, &psi));
            assert_true(dr_mpm_pk1(MODELS[m], dim, MU, LAM, I, P));
            /* exact zeros up to the round-off of log(1) and the polar decomposition of I */
            assert_true(fabs(psi) < 1e-14);
            assert_true(norm9(P) < 1e-13);
        }
}

/* P against central differences of Ψ and dP against central differences of P, for random F of moderate
   deformation (entries I ± 0.4), both models, 2-D and 3-D. Step h = 1e-6: the truncation error O(h²)
   ~1e-12 relative, round-off ~ε/h ~ 1e-10 relative; the 1e-6 bound leaves room for unlucky conditioning
   while any wrong term (a sign, a missing factor) gives O(1) errors. */
static void test_stress_finite_differences(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 11);
    double worstP = 0, worstdP = 0;
    for (int dim = 2; dim <= 3; dim++)
        for (int m = 0; m < 2; m++)
            for (int trial = 0; trial < 50; trial++) {
                double F[9];
                do random_F(&rng, dim, 0.4, F);
                while (dr_m3a_det(F) < 0.2);
                double P[9], fdP[9];
                assert_true(dr_mpm_pk1(MODELS[m], dim, MU, LAM, F, P));
                const double h = 1e-6;
                for (int k = 0; k < 9; k++) {
                    fdP[k] = 0.0;
                    if (dim == 2 && (k % 3 == 2 || k >= 6)) continue;
                    double Fp[9], Fm[9], ep, em;
                    memcpy(Fp, F, sizeof Fp), memcpy(Fm, F, sizeof Fm);
                    Fp[k] += h, Fm[k] -= h;
                    assert_true(dr_mpm_energy_density(MODELS[m], dim, MU, LAM, Fp, &ep));
                    assert_true(dr_mpm_energy_density(MODELS[m], dim, MU, LAM, Fm, &em));
                    fdP[k] = (ep - em) / (2 * h);
                }
                double diff[9];
                for (int k = 0; k < 9; k++) diff[k] = P[k] - fdP[k];
                double e = norm9(diff) / fmax(norm9(P), 1.0);
                if (e > worstP) worstP = e;
                assert_true(e < 1e-6);
                /* dP along a random direction */
                double dF[9];
                random_F(&rng, dim, 1.0, dF);
                for (int k = 0; k < 9; k += 4) dF[k] -= 1.0;
                if (dim == 2) dF[8] = 0.0;
                double dP[9], Pp[9], Pm[9], Fp[9], Fm[9];
                assert_true(dr_mpm_dpk1(MODELS[m], dim, MU, LAM, F, dF, dP));
                for (int k = 0; k < 9; k++) Fp[k] = F[k] + h * dF[k], Fm[k] = F[k] - h * dF[k];
                assert_true(dr_mpm_pk1(MODELS[m], dim, MU, LAM, Fp, Pp));
                assert_true(dr_mpm_pk1(MODELS[m], dim, MU, LAM, Fm, Pm));
                for (int k = 0; k < 9; k++) diff[k] = dP[k] - (Pp[k] - Pm[k]) / (2 * h);
                e = norm9(diff) / fmax(norm9(dP), 1.0);
                if (e > worstdP) worstdP = e;
                assert_true(e < 1e-6);
            }
    printf("finite differences: worst relative error P %.2e, dP %.2e\n", worstP, worstdP);
}

/* dP is the Hessian of Ψ: dF₂ : dP(dF₁) = dF₁ : dP(dF₂) (checks the symmetry the CG operator relies on) */
static void test_dpk1_symmetric(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 5);
    for (int dim = 2; dim <= 3; dim++)
        for (int m = 0; m < 2; m++)
            for (int trial = 0; trial < 20; trial++) {
                double F[9], A[9], B[9], dA[9], dB[9];
                do random_F(&rng, dim, 0.5, F);
                while (dr_m3a_det(F) < 0.2);
                random_F(&rng, dim, 1.0, A), random_F(&rng, dim, 1.0, B);
                if (dim == 2) A[8] = B[8] = 0;
                assert_true(dr_mpm_dpk1(MODELS[m], dim, MU, LAM, F, A, dA));
                assert_true(dr_mpm_dpk1(MODELS[m], dim, MU, LAM, F, B, dB));
                double ab = 0, ba = 0;
                for (int k = 0; k < 9; k++) ab += B[k] * dA[k], ba += A[k] * dB[k];
                assert_true(fabs(ab - ba) <= 1e-12 * (fabs(ab) + fabs(ba) + 1.0));
            }
}

/* Ψ(QF) = Ψ(F), P(QF) = Q P(F) (frame indifference), also for inverted F with fixed corotated. */
static void test_rotation_invariance(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 3);
    for (int dim = 2; dim <= 3; dim++)
        for (int m = 0; m < 2; m++)
            for (int trial = 0; trial < 40; trial++) {
                double F[9], Q[9], QF[9], P[9], PQ[9], QP[9], a, b;
                random_F(&rng, dim, 0.8, F);
                if (m == 0 && dr_m3a_det(F) <= 0.05) continue;
                random_rotation(&rng, dim, Q);
                dr_m3a_mul(Q, F, QF);
                assert_true(dr_mpm_energy_density(MODELS[m], dim, MU, LAM, F, &a));
                assert_true(dr_mpm_energy_density(MODELS[m], dim, MU, LAM, QF, &b));
                assert_true(fabs(a - b) <= 1e-12 * (fabs(a) + 1.0));
                assert_true(dr_mpm_pk1(MODELS[m], dim, MU, LAM, F, P));
                assert_true(dr_mpm_pk1(MODELS[m], dim, MU, LAM, QF, PQ));
                dr_m3a_mul(Q, P, QP);
                double d[9];
                for (int k = 0; k < 9; k++) d[k] = PQ[k] - QP[k];
                assert_true(norm9(d) <= 1e-11 * (norm9(P) + 1.0));
            }
}

static void test_neohookean_domain_and_inverted_corotated(void **state)
{
    (void)state;
    double Finv[9] = {1, 0, 0, 0, -0.5, 0, 0, 0, 1}, Fsing[9] = {1, 0, 0, 0, 0, 0, 0, 0, 1}, psi, P[9], dP[9];
    double dF[9] = {0.1, 0.2, 0, 0.3, 0.4, 0, 0, 0, 0};
    for (int dim = 2; dim <= 3; dim++) {
        assert_false(dr_mpm_energy_density(DR_MPM_NEOHOOKEAN, dim, MU, LAM, Finv, &psi));
        assert_false(dr_mpm_pk1(DR_MPM_NEOHOOKEAN, dim, MU, LAM, Finv, P));
        assert_false(dr_mpm_dpk1(DR_MPM_NEOHOOKEAN, dim, MU, LAM, Finv, dF, dP));
        assert_false(dr_mpm_pk1(DR_MPM_NEOHOOKEAN, dim, MU, LAM, Fsing, P));
        /* fixed corotated is defined through inversion: finite, and pushes J back towards 1 */
        assert_true(dr_mpm_energy_density(DR_MPM_FIXED_COROTATED, dim, MU, LAM, Finv, &psi));
        assert_true(dr_mpm_pk1(DR_MPM_FIXED_COROTATED, dim, MU, LAM, Finv, P));
        assert_true(dr_mpm_dpk1(DR_MPM_FIXED_COROTATED, dim, MU, LAM, Finv, dF, dP));
        assert_true(dr_mpm_pk1(DR_MPM_FIXED_COROTATED, dim, MU, LAM, Fsing, P));
        /* R for diag(1, −0.5, 1) is diag(1, 1, 1) with Σ = diag(1, −0.5, 1) in 2-D, so Ψ = μ·1.5² + λ/2·1.5² */
        double expect = MU * 2.25 + 0.5 * LAM * 2.25;
        if (dim == 2) assert_true(fabs(psi - expect) < 1e-12 * expect);
    }
}

/* F = R S with R a rotation (also for det F < 0 and singular F), S symmetric. */
static void test_polar(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 21);
    for (int dim = 2; dim <= 3; dim++)
        for (int trial = 0; trial < 200; trial++) {
            double F[9], R[9], S[9], RS[9], RtR[9];
            random_F(&rng, dim, trial < 100 ? 0.6 : 3.0, F);
            if (trial % 10 == 0) /* singular: a repeated column */
                for (int k = 0; k < 3; k++) F[3 * k + 1] = F[3 * k];
            if (dim == 2 && trial % 10 == 0) F[2] = F[5] = 0, F[8] = 1;
            dr_mpm_polar(dim, F, R, S);
            dr_m3a_mul(R, S, RS);
            double Rt[9];
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) Rt[3 * i + j] = R[3 * j + i];
            dr_m3a_mul(Rt, R, RtR);
            double e = 0, o = 0, sy = 0;
            for (int k = 0; k < 9; k++) {
                e = fmax(e, fabs(RS[k] - F[k]));
                o = fmax(o, fabs(RtR[k] - ((k % 4 == 0) ? 1.0 : 0.0)));
            }
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) sy = fmax(sy, fabs(S[3 * i + j] - S[3 * j + i]));
            assert_true(e < 1e-12 * (norm9(F) + 1));
            assert_true(o < 1e-12);
            assert_true(fabs(dr_m3a_det(R) - 1.0) < 1e-12);
            assert_true(sy < 1e-11 * (norm9(F) + 1));
        }
}

/* ---- solver ------------------------------------------------------------------------------------ */

static DrMpmMaterial MAT = {DR_MPM_NEOHOOKEAN, 2.0, 1000.0, 0.3};

typedef struct Disk { double cx, cy, cz, r; } Disk;
static bool in_disk(DrVec3 x, void *ctx)
{
    const Disk *d = ctx;
    double dx = x.x - d->cx, dy = x.y - d->cy;
    return dx * dx + dy * dy < d->r * d->r;
}
static bool in_ball(DrVec3 x, void *ctx)
{
    const Disk *d = ctx;
    double dx = x.x - d->cx, dy = x.y - d->cy, dz = x.z - d->cz;
    return dx * dx + dy * dy + dz * dz < d->r * d->r;
}

static DrMpm *make(int dim, DrMpmIntegrator integ, DrTransferScheme scheme)
{
    DrMpmDesc d;
    dr_mpm_desc_default(&d);
    d.dim = dim;
    d.dx = 1.0 / 16.0;
    d.integrator = integ;
    d.scheme = scheme;
    DrMpm *m = NULL;
    DrError err;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
    return m;
}

static void test_create_rejects_bad_desc(void **state)
{
    (void)state;
    DrMpmDesc d;
    DrMpm *m = NULL;
    DrError err;
    dr_mpm_desc_default(&d);
    d.dim = 4;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "dim"));
    assert_null(m);
    dr_mpm_desc_default(&d);
    d.dx = 0;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "dx"));
    dr_mpm_desc_default(&d);
    d.hi = dr_v3(-1, 1, 1);
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "box"));
    dr_mpm_desc_default(&d);
    d.f_update_order = 3;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_ERR_INPUT);
    dr_mpm_desc_default(&d);
    d.flip_blend = 1.5;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_ERR_INPUT);
    dr_mpm_destroy(&m);
    dr_mpm_destroy(NULL);
}

static void test_add_particles_checks(void **state)
{
    (void)state;
    DrMpm *m = make(3, DR_MPM_SYMPLECTIC_EULER, DR_TRANSFER_APIC);
    DrError err;
    double x[6] = {0.5, 0.5, 0.5, 1.5, 0.5, 0.5}, v[6] = {0}, vol[2] = {1e-4, 1e-4};
    int body = -1;
    assert_int_equal(dr_mpm_add_particles(m, 2, x, v, vol, NULL, &MAT, &body, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "outside"));
    assert_int_equal(dr_mpm_state(m).n, 0); /* nothing added */
    x[3] = 0.6;
    v[1] = NAN;
    assert_int_equal(dr_mpm_add_particles(m, 2, x, v, vol, NULL, &MAT, &body, &err), DR_ERR_INPUT);
    v[1] = 0;
    DrMpmMaterial bad = MAT;
    bad.poisson = 0.5;
    assert_int_equal(dr_mpm_add_particles(m, 2, x, v, vol, NULL, &bad, &body, &err), DR_ERR_INPUT);
    assert_int_equal(dr_mpm_add_particles(m, 2, x, v, vol, NULL, &MAT, &body, &err), DR_OK);
    assert_int_equal(body, 0);
    assert_int_equal(dr_mpm_add_particles(m, 1, x, v, vol, NULL, &MAT, &body, &err), DR_OK);
    assert_int_equal(body, 1);
    DrMpmState s = dr_mpm_state(m);
    assert_int_equal(s.n, 3);
    assert_int_equal(s.body[2], 1);
    assert_true(fabs(s.mass[0] - 2e-4) < 1e-18);
    for (int k = 0; k < 9; k++) assert_true(s.F[9 * 2 + k] == ((k % 4 == 0) ? 1.0 : 0.0));
    /* zero particles: a step is a no-op, totals are zero */
    DrMpm *e = make(2, DR_MPM_MIDPOINT, DR_TRANSFER_APIC);
    DrMpmStats st;
    assert_int_equal(dr_mpm_step(e, 0.01, &st, &err), DR_OK);
    DrMpmTotals t = dr_mpm_totals(e, -1);
    assert_true(t.kinetic == 0.0 && t.elastic == 0.0);
    assert_true(isinf(dr_mpm_cfl_dt(e)));
    assert_int_equal(dr_mpm_step(e, -1.0, &st, &err), DR_ERR_INPUT);
    dr_mpm_destroy(&e);
    dr_mpm_destroy(&m);
}

/* Lattice aligned with the grid, (per_cell)^dim points per full cell, velocity v0 + ω × r, C0 = [ω]×
   for APIC and 0 for PIC. */
static void test_sample_body(void **state)
{
    (void)state;
    for (int sc = 0; sc < 2; sc++) {
        DrMpm *m = make(2, DR_MPM_SYMPLECTIC_EULER, sc ? DR_TRANSFER_PIC : DR_TRANSFER_APIC);
        Disk disk = {0.5, 0.5, 0, 0.3};
        int body;
        long count;
        DrError err;
        DrVec3 omega = dr_v3(0, 0, 0.4), v0 = dr_v3(0.1, -0.2, 0);
        assert_int_equal(dr_mpm_sample_body(m, in_disk, &disk, dr_v3(0.2, 0.2, 0), dr_v3(0.8, 0.8, 0), 2, v0, omega,
                                            dr_v3(0.5, 0.5, 0), &MAT, &body, &count, &err),
                         DR_OK);
        DrMpmState s = dr_mpm_state(m);
        assert_int_equal(s.n, count);
        double h = (1.0 / 16.0) / 2.0;
        /* the count of lattice points within the disk is its area over h² to within the boundary layer
           2πR·h/h² = 2πR/h ≈ 60 points */
        assert_true(fabs(count - DR_PI * 0.09 / (h * h)) < 2 * DR_PI * 0.3 / h);
        for (long p = 0; p < s.n; p++) {
            double fx = s.x[3 * p] / h - 0.5, fy = s.x[3 * p + 1] / h - 0.5;
            assert_true(fabs(fx - round(fx)) < 1e-9 && fabs(fy - round(fy)) < 1e-9);
            assert_true(fabs(s.vol0[p] - h * h) < 1e-18);
            double rx = s.x[3 * p] - 0.5, ry = s.x[3 * p + 1] - 0.5;
            assert_true(fabs(s.v[3 * p] - (0.1 - 0.4 * ry)) < 1e-14);
            assert_true(fabs(s.v[3 * p + 1] - (-0.2 + 0.4 * rx)) < 1e-14);
            assert_true(s.C[9 * p + 1] == (sc ? 0.0 : -0.4) && s.C[9 * p + 3] == (sc ? 0.0 : 0.4));
            assert_true(s.C[9 * p] == 0.0 && s.C[9 * p + 4] == 0.0);
        }
        dr_mpm_destroy(&m);
    }
}

/* §4.3: ν Δx / max_p(‖v_p‖ + 6√d/Δx ‖B_p‖_F), B = C D with D = Δx²/4 (quadratic). */
static void test_cfl(void **state)
{
    (void)state;
    DrMpm *m = make(3, DR_MPM_MIDPOINT, DR_TRANSFER_APIC);
    DrError err;
    double x[6] = {0.5, 0.5, 0.5, 0.3, 0.3, 0.3}, v[6] = {3, 4, 0, 1, 0, 0}, vol[2] = {1e-4, 1e-4};
    double C0[9] = {0, -2, 0, 2, 0, 0, 0, 0, 0};
    assert_int_equal(dr_mpm_add_particles(m, 2, x, v, vol, C0, &MAT, NULL, &err), DR_OK);
    double dx = 1.0 / 16.0, D = dx * dx / 4;
    double expect = dx / (5.0 + 6.0 * sqrt(3.0) / dx * D * sqrt(8.0));
    assert_true(fabs(dr_mpm_cfl_dt(m) - expect) < 1e-14 * expect);
    dr_mpm_destroy(&m);
}

static void totals_rel(DrMpm *m, DrVec3 *P, DrVec3 *L)
{
    DrMpmTotals t = dr_mpm_totals(m, -1);
    *P = t.momentum, *L = t.angular;
}

/* Two disks spinning and translating into each other (3-D balls): after one step of each integrator the
   total momentum is unchanged (APIC, no walls touched, no gravity); angular momentum for the conserving
   schemes. Here Newton runs to its tolerance, so §4.2 is not what is being tested (see the next test). */
static void setup_balls(DrMpm *m)
{
    Disk a = {0.35, 0.5, 0.5, 0.12}, b = {0.62, 0.55, 0.5, 0.12};
    DrError err;
    assert_int_equal(dr_mpm_sample_body(m, in_ball, &a, dr_v3(0.2, 0.35, 0.35), dr_v3(0.5, 0.65, 0.65), 2,
                                        dr_v3(1, 0.1, 0), dr_v3(0.5, 2, 1), dr_v3(0.35, 0.5, 0.5), &MAT, NULL, NULL, &err),
                     DR_OK);
    assert_int_equal(dr_mpm_sample_body(m, in_ball, &b, dr_v3(0.45, 0.4, 0.35), dr_v3(0.8, 0.7, 0.65), 2,
                                        dr_v3(-1, 0, 0.2), dr_v3(0, 0, -3), dr_v3(0.62, 0.55, 0.5), &MAT, NULL, NULL, &err),
                     DR_OK);
}

static void test_step_conserves_momentum(void **state)
{
    (void)state;
    DrMpmIntegrator ints[3] = {DR_MPM_SYMPLECTIC_EULER, DR_MPM_MIDPOINT, DR_MPM_BACKWARD_EULER};
    for (int k = 0; k < 3; k++) {
        DrMpm *m = make(3, ints[k], DR_TRANSFER_APIC);
        setup_balls(m);
        DrVec3 P0, L0, P1, L1;
        totals_rel(m, &P0, &L0);
        DrError err;
        DrMpmStats st;
        for (int s = 0; s < 3; s++) assert_int_equal(dr_mpm_step(m, 2e-3, &st, &err), DR_OK);
        totals_rel(m, &P1, &L1);
        double eP = dr_v3_norm(dr_v3_sub(P1, P0)) / dr_v3_norm(P0), eL = dr_v3_norm(dr_v3_sub(L1, L0)) / dr_v3_norm(L0);
        printf("%d: momentum drift %.2e, angular %.2e (newton %d, cg %d)\n", k, eP, eL, st.newton_iterations,
               st.cg_iterations);
        /* sums over ~10⁴ particles and nodes: round-off ~1e-14; Newton tolerance 1e-10 on a step whose
           velocity change is a small part of v bounds the rest */
        assert_true(eP < 1e-12);
        if (k < 2) assert_true(eL < 1e-10);
        dr_mpm_destroy(&m);
    }
}

/* §4.2: CG in the mass inner product keeps linear momentum when stopped early. One Newton iteration with
   two CG iterations is far from converged (DR_WARN_NOT_CONVERGED), yet Σ m v is unchanged to round-off. */
static void test_early_stop_keeps_momentum(void **state)
{
    (void)state;
    DrMpmDesc d;
    dr_mpm_desc_default(&d);
    d.dx = 1.0 / 16.0;
    d.newton_max_iterations = 1;
    d.cg_max_iterations = 2;
    DrMpm *m = NULL;
    DrError err;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
    setup_balls(m);
    DrVec3 P0, L0, P1, L1;
    totals_rel(m, &P0, &L0);
    DrMpmStats st;
    DrStatus s = DR_OK;
    for (int k = 0; k < 3; k++) s = dr_mpm_step(m, 0.02, &st, &err);
    assert_int_equal(s, DR_WARN_NOT_CONVERGED);
    assert_true(st.newton_residual > 1e-6);
    totals_rel(m, &P1, &L1);
    double eP = dr_v3_norm(dr_v3_sub(P1, P0)) / dr_v3_norm(P0);
    printf("early stop: residual %.2e, momentum drift %.2e\n", st.newton_residual, eP);
    assert_true(eP < 1e-12);
    dr_mpm_destroy(&m);
}

/* A correct force differential (eqs. 35–36 and the order-2 terms) gives Newton its quadratic convergence:
   a few iterations to 1e-10. With a wrong Hessian Newton degrades to linear convergence and needs tens. */
static void test_newton_converges_quadratically(void **state)
{
    (void)state;
    for (int order = 1; order <= 2; order++)
        for (int integ = 1; integ <= 2; integ++)
            for (int model = 0; model < 2; model++) {
                DrMpmDesc d;
                dr_mpm_desc_default(&d);
                d.dx = 1.0 / 16.0;
                d.f_update_order = order;
                d.integrator = integ == 1 ? DR_MPM_MIDPOINT : DR_MPM_BACKWARD_EULER;
                DrMpm *m = NULL;
                DrError err;
                assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
                DrMpmMaterial mat = MAT;
                mat.model = MODELS[model];
                Disk a = {0.5, 0.5, 0.5, 0.15};
                assert_int_equal(dr_mpm_sample_body(m, in_ball, &a, dr_v3(0.3, 0.3, 0.3), dr_v3(0.7, 0.7, 0.7), 2,
                                                    dr_v3(0, 0, 0), dr_v3(3, 5, 4), dr_v3(0.5, 0.5, 0.5), &mat, NULL,
                                                    NULL, &err),
                                 DR_OK);
                DrMpmStats st;
                int worst = 0;
                for (int s = 0; s < 4; s++) {
                    assert_int_equal(dr_mpm_step(m, 0.01, &st, &err), DR_OK);
                    if (st.newton_iterations > worst) worst = st.newton_iterations;
                }
                printf("order %d integrator %d model %d: max Newton iterations %d\n", order, integ, model, worst);
                assert_true(worst <= 8);
                dr_mpm_destroy(&m);
            }
}

/* eqs. (109)–(111): for an affine velocity field v = A x (APIC reproduces it on the grid exactly, E = 0 so
   no forces) one step gives F = I + ΔtA + ½Δt²A² with order 2 and I + ΔtA with order 1. */
static void test_f_update_order(void **state)
{
    (void)state;
    double A[9] = {0.3, -1.0, 0.2, 0.7, -0.2, 0.1, 0.4, 0.5, 0.1};
    for (int order = 1; order <= 2; order++) {
        DrMpmDesc d;
        dr_mpm_desc_default(&d);
        d.dx = 1.0 / 16.0;
        d.integrator = DR_MPM_SYMPLECTIC_EULER;
        d.f_update_order = order;
        DrMpm *m = NULL;
        DrError err;
        assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
        DrMpmMaterial mat = {DR_MPM_NEOHOOKEAN, 1.0, 0.0, 0.0};
        Disk a = {0.5, 0.5, 0.5, 0.25};
        assert_int_equal(dr_mpm_sample_body(m, in_ball, &a, dr_v3(0.2, 0.2, 0.2), dr_v3(0.8, 0.8, 0.8), 2,
                                            dr_v3(0, 0, 0), dr_v3(0, 0, 0), dr_v3(0.5, 0.5, 0.5), &mat, NULL, NULL, &err),
                         DR_OK);
        DrMpmState s = dr_mpm_state(m);
        double *v = malloc(sizeof(double) * 3 * s.n), *C = malloc(sizeof(double) * 9 * s.n);
        for (long p = 0; p < s.n; p++) {
            for (int i = 0; i < 3; i++) {
                v[3 * p + i] = 0;
                for (int j = 0; j < 3; j++) v[3 * p + i] += A[3 * i + j] * (s.x[3 * p + j] - 0.5);
            }
            memcpy(C + 9 * p, A, sizeof A);
        }
        assert_int_equal(dr_mpm_restore(m, s.n, s.x, v, C, s.F, &err), DR_OK);
        double dt = 0.05;
        DrMpmStats st;
        assert_int_equal(dr_mpm_step(m, dt, &st, &err), DR_OK);
        s = dr_mpm_state(m);
        double A2[9], worst = 0;
        dr_m3a_mul(A, A, A2);
        for (long p = 0; p < s.n; p++)
            for (int k = 0; k < 9; k++) {
                double e = ((k % 4 == 0) ? 1.0 : 0.0) + dt * A[k] + (order == 2 ? 0.5 * dt * dt * A2[k] : 0.0);
                worst = fmax(worst, fabs(s.F[9 * p + k] - e));
            }
        printf("order %d: max |F - expected| = %.2e\n", order, worst);
        assert_true(worst < 1e-12);
        free(v), free(C);
        dr_mpm_destroy(&m);
    }
}

/* Walls: a disk pressed against the −x wall by gravity along −x while moving along y (backward Euler,
   so the bounce decays). Slip keeps the tangential velocity of the nodes on the wall (the disk slides at
   its initial 0.5 m/s), no-slip stops it there (the contact layer is held); with either, no particle
   crosses the wall plane by more than a small fraction of a cell. */
static void test_walls(void **state)
{
    (void)state;
    for (int w = 0; w < 2; w++) {
        DrMpmDesc d;
        dr_mpm_desc_default(&d);
        d.dim = 2;
        d.dx = 1.0 / 16.0;
        d.integrator = DR_MPM_BACKWARD_EULER;
        d.gravity = dr_v3(-5.0, 0, 0);
        for (int f = 0; f < 6; f++) d.wall[f] = w ? DR_MPM_WALL_NO_SLIP : DR_MPM_WALL_SLIP;
        DrMpm *m = NULL;
        DrError err;
        assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
        Disk a = {0.11, 0.3, 0, 0.1};
        assert_int_equal(dr_mpm_sample_body(m, in_disk, &a, dr_v3(0, 0.1, 0), dr_v3(0.3, 0.5, 0), 2,
                                            dr_v3(0.0, 0.5, 0), dr_v3(0, 0, 0), dr_v3(0.11, 0.3, 0), &MAT, NULL, NULL,
                                            &err),
                         DR_OK);
        DrMpmStats st;
        for (int s = 0; s < 20; s++) assert_true(dr_mpm_step(m, 0.01, &st, &err) >= 0);
        DrMpmState s = dr_mpm_state(m);
        double xmin = 1, vy = 0, mass = 0;
        for (long p = 0; p < s.n; p++) {
            xmin = fmin(xmin, s.x[3 * p]);
            if (s.x[3 * p] < 0.5 / 16.0) vy += s.mass[p] * s.v[3 * p + 1], mass += s.mass[p];
        }
        vy /= mass;
        printf("%s wall: min x %.4f, mean vy of particles within half a cell of it %.3f\n", w ? "no-slip" : "slip",
               xmin, vy);
        assert_true(xmin > -0.25 / 16.0);
        if (w == 0) assert_true(fabs(vy - 0.5) < 0.01); /* slides along the wall */
        else assert_true(fabs(vy) < 0.1);              /* held by the wall */
        dr_mpm_destroy(&m);
    }
}

static double ground_sdf(DrVec3 x, DrVec3 *n, void *ctx)
{
    (void)ctx;
    *n = dr_v3(0, 1, 0);
    return x.y - 0.3;
}

/* A ball dropped on a slip collider plane at y = 0.3 comes to rest on it instead of falling through; a
   sticky collider moving sideways drags the contact layer along with it. */
static void test_collider(void **state)
{
    (void)state;
    for (int sticky = 0; sticky < 2; sticky++) {
        DrMpmDesc d;
        dr_mpm_desc_default(&d);
        d.dim = 2;
        d.dx = 1.0 / 16.0;
        d.integrator = DR_MPM_BACKWARD_EULER;
        d.gravity = dr_v3(0, -9.81, 0);
        DrMpm *m = NULL;
        DrError err;
        assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
        DrMpmCollider c = {ground_sdf, NULL, dr_v3(sticky ? 0.3 : 0.0, 0, 0), 0.0, sticky == 1, NULL};
        assert_int_equal(dr_mpm_add_collider(m, &c, &err), DR_OK);
        Disk a = {0.5, 0.5, 0, 0.1};
        assert_int_equal(dr_mpm_sample_body(m, in_disk, &a, dr_v3(0.3, 0.3, 0), dr_v3(0.7, 0.7, 0), 2, dr_v3(0, 0, 0),
                                            dr_v3(0, 0, 0), dr_v3(0.5, 0.5, 0), &MAT, NULL, NULL, &err),
                         DR_OK);
        DrMpmStats st;
        assert_true(dr_mpm_advance(m, 0.6, 200, &st, &err) >= 0);
        DrMpmState s = dr_mpm_state(m);
        double ymin = 1, vx = 0, mass = 0;
        for (long p = 0; p < s.n; p++) {
            ymin = fmin(ymin, s.x[3 * p + 1]);
            vx += s.mass[p] * s.v[3 * p], mass += s.mass[p];
        }
        printf("collider (sticky %d): min y %.4f, mean vx %.3f\n", sticky, ymin, vx / mass);
        /* the collider acts on nodes, and the particles of the lowest layer interpolate nodes on both
           sides of the surface: MPM lets them sink up to about a cell into it, never through it */
        assert_true(ymin > 0.3 - 1.0 / 16.0);
        if (sticky) assert_true(vx / mass > 0.05);
        else assert_true(fabs(vx / mass) < 1e-12);
        dr_mpm_destroy(&m);
    }
}

/* Anchors: a block hanging on anchors at every particle settles at target − m g/k (backward Euler damps
   the spring), i.e. anchors act through the grid as ½k‖x_p − target‖². */
static void test_anchors(void **state)
{
    (void)state;
    DrMpmDesc d;
    dr_mpm_desc_default(&d);
    d.dim = 2;
    d.dx = 1.0 / 16.0;
    d.integrator = DR_MPM_BACKWARD_EULER;
    d.gravity = dr_v3(0, -2.0, 0);
    DrMpm *m = NULL;
    DrError err;
    assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
    Disk a = {0.5, 0.5, 0, 0.1};
    assert_int_equal(dr_mpm_sample_body(m, in_disk, &a, dr_v3(0.3, 0.3, 0), dr_v3(0.7, 0.7, 0), 2, dr_v3(0, 0, 0),
                                        dr_v3(0, 0, 0), dr_v3(0.5, 0.5, 0), &MAT, NULL, NULL, &err),
                     DR_OK);
    DrMpmState s = dr_mpm_state(m);
    double *k = malloc(sizeof(double) * s.n), *t = malloc(sizeof(double) * 3 * s.n);
    double kk = 2500.0 * s.mass[0]; /* ω = 50 rad/s: backward Euler at ωΔt = 1 damps 30 % per step */
    for (long p = 0; p < s.n; p++) k[p] = kk, memcpy(t + 3 * p, s.x + 3 * p, 3 * sizeof(double));
    assert_int_equal(dr_mpm_set_anchors(m, k, t, &err), DR_OK);
    DrMpmStats st;
    for (int f = 0; f < 60; f++) assert_true(dr_mpm_step(m, 0.02, &st, &err) >= 0);
    s = dr_mpm_state(m);
    double sag = 0, mass = 0;
    for (long p = 0; p < s.n; p++) sag += s.mass[p] * (s.x[3 * p + 1] - t[3 * p + 1]), mass += s.mass[p];
    sag /= mass;
    double expect = -s.mass[0] * 2.0 / kk; /* −mg/k = −0.8 mm */
    printf("anchors: mean sag %.5f, expected %.5f\n", sag, expect);
    /* the elastic body adds no net force at equilibrium; the grid spreads each spring over nodes, which
       changes only the distribution: the mean offset is exact up to the settling left after 1.2 s */
    assert_true(fabs(sag - expect) < 0.02 * fabs(expect));
    k[0] = -1;
    assert_int_equal(dr_mpm_set_anchors(m, k, t, &err), DR_ERR_INPUT);
    free(k), free(t);
    dr_mpm_destroy(&m);
}

/* advance: substeps from the CFL, capped by max_substeps; the whole duration is covered. */
static void test_advance_substeps(void **state)
{
    (void)state;
    DrMpm *m = make(2, DR_MPM_MIDPOINT, DR_TRANSFER_APIC);
    Disk a = {0.5, 0.5, 0, 0.15};
    DrError err;
    assert_int_equal(dr_mpm_sample_body(m, in_disk, &a, dr_v3(0.2, 0.2, 0), dr_v3(0.8, 0.8, 0), 2, dr_v3(1.0, 0, 0),
                                        dr_v3(0, 0, 0), dr_v3(0.5, 0.5, 0), &MAT, NULL, NULL, &err),
                     DR_OK);
    double cfl = dr_mpm_cfl_dt(m); /* Δx / 1 m/s */
    assert_true(fabs(cfl - 1.0 / 16.0) < 1e-12);
    DrMpmState s = dr_mpm_state(m);
    double x0 = s.x[0];
    DrMpmStats st;
    assert_true(dr_mpm_advance(m, 0.1, 100, &st, &err) >= 0);
    assert_int_equal(st.substeps, 2); /* ceil(0.1 / 0.0625) */
    assert_true(dr_mpm_advance(m, 0.1, 1, &st, &err) >= 0);
    assert_int_equal(st.substeps, 1);
    /* a free body keeps its momentum and moves by v·t = 0.2 m (up to its elastic wobble) */
    DrMpmTotals t = dr_mpm_totals(m, 0);
    double mass = 0;
    for (long p = 0; p < s.n; p++) mass += s.mass[p];
    assert_true(fabs(t.momentum.x / mass - 1.0) < 1e-12);
    assert_true(fabs(s.x[0] - x0 - 0.2) < 1e-3);
    assert_int_equal(dr_mpm_advance(m, -1, 2, &st, &err), DR_ERR_INPUT);
    dr_mpm_destroy(&m);
}

static DrHash run_hash(int threads, int steps, bool resume)
{
    dr_set_threads(threads);
    DrMpm *m = make(3, DR_MPM_MIDPOINT, DR_TRANSFER_APIC);
    setup_balls(m);
    DrError err;
    DrMpmStats st;
    int first = resume ? steps / 2 : steps;
    for (int s = 0; s < first; s++) assert_int_equal(dr_mpm_step(m, 5e-3, &st, &err), DR_OK);
    if (resume) {
        DrMpmState s = dr_mpm_state(m);
        double *x = malloc(24 * s.n * sizeof(double));
        memcpy(x, s.x, 3 * s.n * sizeof(double));
        memcpy(x + 3 * s.n, s.v, 3 * s.n * sizeof(double));
        memcpy(x + 6 * s.n, s.C, 9 * s.n * sizeof(double));
        memcpy(x + 15 * s.n, s.F, 9 * s.n * sizeof(double));
        DrMpm *m2 = make(3, DR_MPM_MIDPOINT, DR_TRANSFER_APIC);
        setup_balls(m2);
        assert_int_equal(dr_mpm_restore(m2, s.n, x, x + 3 * s.n, x + 6 * s.n, x + 15 * s.n, &err), DR_OK);
        assert_int_equal(dr_mpm_restore(m2, s.n - 1, x, x + 3 * s.n, x + 6 * s.n, x + 15 * s.n, &err), DR_ERR_INPUT);
        free(x);
        dr_mpm_destroy(&m);
        m = m2;
        for (int s2 = first; s2 < steps; s2++) assert_int_equal(dr_mpm_step(m, 5e-3, &st, &err), DR_OK);
    }
    DrMpmState s = dr_mpm_state(m);
    DrHasher h;
    dr_hasher_init(&h);
    dr_hasher_update(&h, s.x, 3 * s.n * sizeof(double));
    dr_hasher_update(&h, s.v, 3 * s.n * sizeof(double));
    dr_hasher_update(&h, s.C, 9 * s.n * sizeof(double));
    dr_hasher_update(&h, s.F, 9 * s.n * sizeof(double));
    dr_mpm_destroy(&m);
    dr_set_threads(0);
    return dr_hasher_final(&h);
}

/* A body large enough (~29k particles) for every parallel path: the solver's per-particle loops (chunks
   of 2048) and the transfers' coloured scatter and gathers (above 16k particles). Two symplectic Euler
   steps and one midpoint step (loose tolerances: the point is the arithmetic, not convergence). */
static DrHash big_hash(int threads)
{
    dr_set_threads(threads);
    DrHash out = {0, 0};
    for (int integ = 0; integ < 2; integ++) {
        DrMpmDesc d;
        dr_mpm_desc_default(&d);
        d.dx = 1.0 / 32.0;
        d.integrator = integ ? DR_MPM_MIDPOINT : DR_MPM_SYMPLECTIC_EULER;
        d.newton_tolerance = 1e-3;
        d.cg_tolerance = 1e-3;
        DrMpm *m = NULL;
        DrError err;
        assert_int_equal(dr_mpm_create(&d, &m, &err), DR_OK);
        Disk a = {0.5, 0.5, 0.5, 0.3};
        long n;
        assert_int_equal(dr_mpm_sample_body(m, in_ball, &a, dr_v3(0.2, 0.2, 0.2), dr_v3(0.8, 0.8, 0.8), 2,
                                            dr_v3(0.3, 0, 0), dr_v3(1, 2, 3), dr_v3(0.5, 0.5, 0.5), &MAT, NULL, &n, &err),
                         DR_OK);
        assert_true(n > 20000);
        DrMpmStats st;
        for (int s = 0; s < (integ ? 1 : 2); s++) assert_true(dr_mpm_step(m, integ ? 5e-3 : 5e-4, &st, &err) >= 0);
        DrMpmState s = dr_mpm_state(m);
        DrHasher h;
        dr_hasher_init(&h);
        dr_hasher_update(&h, &out, sizeof out);
        dr_hasher_update(&h, s.x, 3 * s.n * sizeof(double));
        dr_hasher_update(&h, s.v, 3 * s.n * sizeof(double));
        dr_hasher_update(&h, s.C, 9 * s.n * sizeof(double));
        dr_hasher_update(&h, s.F, 9 * s.n * sizeof(double));
        out = dr_hasher_final(&h);
        dr_mpm_destroy(&m);
    }
    dr_set_threads(0);
    return out;
}

static void test_determinism(void **state)
{
    (void)state;
    DrHash a = run_hash(1, 6, false), b = run_hash(2, 6, false), c = run_hash(2, 6, true);
    assert_true(a.hi == b.hi && a.lo == b.lo);
    assert_true(a.hi == c.hi && a.lo == c.lo);
    DrHash d = big_hash(1), e = big_hash(2);
    assert_true(d.hi == e.hi && d.lo == e.lo);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_lame_and_rest),
        cmocka_unit_test(test_stress_finite_differences),
        cmocka_unit_test(test_dpk1_symmetric),
        cmocka_unit_test(test_rotation_invariance),
        cmocka_unit_test(test_neohookean_domain_and_inverted_corotated),
        cmocka_unit_test(test_polar),
        cmocka_unit_test(test_create_rejects_bad_desc),
        cmocka_unit_test(test_add_particles_checks),
        cmocka_unit_test(test_sample_body),
        cmocka_unit_test(test_cfl),
        cmocka_unit_test(test_step_conserves_momentum),
        cmocka_unit_test(test_early_stop_keeps_momentum),
        cmocka_unit_test(test_newton_converges_quadratically),
        cmocka_unit_test(test_f_update_order),
        cmocka_unit_test(test_walls),
        cmocka_unit_test(test_collider),
        cmocka_unit_test(test_anchors),
        cmocka_unit_test(test_advance_substeps),
        cmocka_unit_test(test_determinism),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
