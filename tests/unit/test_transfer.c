/* Unit tests of src/transfer: APIC conservation identities on the MAC grid, exact affine round trip,
 * PIC's loss of it, bins, thread-count independence of P2G, and the wall mirror (P2G folds, adjoint of
 * G2P's mirror read). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "transfer/transfer.h"

#define N 4000
static double X[3 * N], V[3 * N], C[9 * N];

/* Random particles in the interior [4, 12)·dx of a 16³ grid (stencils never reach the walls). */
static DrMacGrid *setup(uint64_t seed, double **fm)
{
    DrMacGrid *g = NULL;
    DrError err;
    assert_int_equal(dr_mac_grid_create(16, 16, 16, 0.1, dr_v3(-0.3, 0.2, 0.5), &g, &err), DR_OK);
    DrRng rng;
    dr_rng_seed(&rng, seed);
    for (int p = 0; p < N; p++) {
        for (int d = 0; d < 3; d++) {
            X[3 * p + d] = dr_v3_get(g->origin, d) + g->dx * (4.0 + 8.0 * dr_rng_uniform(&rng));
            V[3 * p + d] = 2.0 * dr_rng_uniform(&rng) - 1.0;
        }
        for (int q = 0; q < 9; q++) C[9 * p + q] = 10.0 * (2.0 * dr_rng_uniform(&rng) - 1.0);
    }
    for (int a = 0; a < 3; a++) fm[a] = calloc((size_t)g->nfaces[a], sizeof(double));
    return g;
}

static void teardown(DrMacGrid **g, double **fm)
{
    for (int a = 0; a < 3; a++) free(fm[a]);
    dr_mac_grid_destroy(g);
}

static void p2g(DrMacGrid *g, double **fm, const double *c)
{
    DrParticleBins *b = NULL;
    DrError err;
    assert_int_equal(dr_bins_create(g, 16, &b, &err), DR_OK);
    assert_int_equal(dr_bins_build(g, N, X, b, &err), DR_OK);
    /* bins: every particle once, cells in order */
    assert_int_equal(b->cell_start[b->ncells], N);
    dr_transfer_p2g_mac(b, X, V, c, 0.37, false, g, fm);
    dr_bins_destroy(&b);
}

static double rel(DrVec3 a, DrVec3 b) { return dr_v3_norm(dr_v3_sub(a, b)) / dr_v3_norm(b); }

/* Σ_f m_f u_f = Σ_p m v_p and Σ_f x_f × m_f u_f = Σ_p L_p (incl. affine part) to round-off, both ways. */
static void test_apic_conservation(void **state)
{
    (void)state;
    double *fm[3];
    DrMacGrid *g = setup(7, fm);
    DrVec3 Pp, Lp, Pg, Lg;
    dr_transfer_particle_totals(N, X, V, C, 0.37, g->dx, &Pp, &Lp);
    p2g(g, fm, C);
    dr_transfer_grid_totals(g, (const double *const *)fm, (const double *const *)g->f, &Pg, &Lg);
    /* sums of ~10⁵ terms of O(1): relative round-off ~1e-15; 1e-13 as the brief requires */
    printf("P2G: momentum rel %.2e, angular rel %.2e\n", rel(Pg, Pp), rel(Lg, Lp));
    assert_true(rel(Pg, Pp) <= 1e-13);
    assert_true(rel(Lg, Lp) <= 1e-13);
    /* G2P of an arbitrary grid field: the particles' totals equal the grid's (same mass weights) */
    DrRng rng;
    dr_rng_seed(&rng, 99);
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) g->f[a][f] = fm[a][f] > 0 ? 2.0 * dr_rng_uniform(&rng) - 1.0 : 0.0;
    dr_transfer_grid_totals(g, (const double *const *)fm, (const double *const *)g->f, &Pg, &Lg);
    dr_transfer_g2p_mac(g, NULL, DR_TRANSFER_APIC, 0.0, false, N, X, V, C);
    dr_transfer_particle_totals(N, X, V, C, 0.37, g->dx, &Pp, &Lp);
    printf("G2P: momentum rel %.2e, angular rel %.2e\n", rel(Pp, Pg), rel(Lp, Lg));
    assert_true(rel(Pp, Pg) <= 1e-13);
    assert_true(rel(Lp, Lg) <= 1e-13);
    teardown(&g, fm);
}

/* An affine velocity field survives APIC P2G→G2P exactly (to round-off); PIC loses its gradient. */
static void test_affine_round_trip(void **state)
{
    (void)state;
    double *fm[3];
    DrMacGrid *g = setup(11, fm);
    double A[3][3] = {{0.3, -1.2, 0.5}, {0.7, 0.1, -0.4}, {-0.2, 0.9, -0.4}};
    double b0[3] = {1.0, -2.0, 0.5};
    for (int p = 0; p < N; p++)
        for (int a = 0; a < 3; a++) {
            V[3 * p + a] = b0[a];
            for (int d = 0; d < 3; d++) {
                V[3 * p + a] += A[a][d] * X[3 * p + d];
                C[9 * p + 3 * a + d] = A[a][d];
            }
        }
    double V0[3 * N];
    memcpy(V0, V, sizeof V0);
    p2g(g, fm, C);
    dr_transfer_g2p_mac(g, NULL, DR_TRANSFER_APIC, 0.0, false, N, X, V, C);
    double ev = 0, ec = 0;
    for (int p = 0; p < N; p++)
        for (int a = 0; a < 3; a++) {
            ev = fmax(ev, fabs(V[3 * p + a] - V0[3 * p + a]));
            for (int d = 0; d < 3; d++) ec = fmax(ec, fabs(C[9 * p + 3 * a + d] - A[a][d]));
        }
    printf("APIC affine round trip: max |dv| %.2e, max |dC| %.2e\n", ev, ec);
    assert_true(ev < 1e-12); /* |v| ~ 3 m/s: round-off */
    assert_true(ec < 1e-10); /* C involves D⁻¹ = 4/Δx² = 400: round-off amplified accordingly */
    /* PIC of the same field: v_p smoothed by the kernel's second moment (Σ w x x − x x ≠ 0 for the PIC
       grid field), C dropped: the gradient is lost entirely */
    memcpy(V, V0, sizeof V0);
    p2g(g, fm, NULL);
    dr_transfer_g2p_mac(g, NULL, DR_TRANSFER_PIC, 0.0, false, N, X, V, C);
    double cmax = 0;
    for (int q = 0; q < 9 * N; q++) cmax = fmax(cmax, fabs(C[q]));
    double ep = 0;
    for (int p = 0; p < 3 * N; p++) ep = fmax(ep, fabs(V[p] - V0[p]));
    printf("PIC round trip: max |dv| %.2e\n", ep);
    assert_true(cmax == 0.0);
    assert_true(ep > 1e-3); /* PIC's P2G averages particle velocities: not exact for random positions */
    teardown(&g, fm);
}

/* P2G is bit-identical for 1 and 2 threads (coloured slabs, fixed order per face). */
static void test_p2g_thread_independent(void **state)
{
    (void)state;
    double *fm[3];
    DrMacGrid *g = setup(5, fm);
    dr_set_threads(1);
    p2g(g, fm, C);
    DrHash h1 = dr_hash_bytes(g->u, sizeof(double) * (size_t)g->nfaces[0]);
    DrHash m1 = dr_hash_bytes(fm[2], sizeof(double) * (size_t)g->nfaces[2]);
    dr_set_threads(2);
    p2g(g, fm, C);
    DrHash h2 = dr_hash_bytes(g->u, sizeof(double) * (size_t)g->nfaces[0]);
    DrHash m2 = dr_hash_bytes(fm[2], sizeof(double) * (size_t)g->nfaces[2]);
    assert_true(h1.hi == h2.hi && h1.lo == h2.lo);
    assert_true(m1.hi == m2.hi && m1.lo == m2.lo);
    teardown(&g, fm);
}

/* Walls: 2 particles per axis per cell at ¼ and ¾ of the cell (the unjittered seeding) fill a 6³ grid;
   with the kernel folded at the walls every face that is not itself on a wall gets the same mass, 8 m_p
   (each half-spacing sub-lattice sums the B-spline weights to one per axis, and the mirror image of one
   sub-lattice is the other). And P2G is G2P's adjoint with the mirror: for random particle velocities v
   and grid values G, Σ_f (m_f u_f) G_f = Σ_p m v_p · (G2P_PIC G)_p, for slip and no-slip signs. */
static void test_wall_fold(void **state)
{
    (void)state;
    enum { M = 6, NP = 8 * M * M * M };
    static double x[3 * NP], v[3 * NP], vg[3 * NP];
    DrMacGrid *g = NULL;
    DrError err;
    assert_int_equal(dr_mac_grid_create(M, M, M, 0.5, dr_v3(1.0, -2.0, 0.25), &g, &err), DR_OK);
    double *fm[3];
    for (int a = 0; a < 3; a++) fm[a] = calloc((size_t)g->nfaces[a], sizeof(double));
    long p = 0;
    for (int k = 0; k < 2 * M; k++)
        for (int j = 0; j < 2 * M; j++)
            for (int i = 0; i < 2 * M; i++, p++) {
                int ijk[3] = {i, j, k};
                for (int d = 0; d < 3; d++) x[3 * p + d] = dr_v3_get(g->origin, d) + g->dx * (0.25 + 0.5 * ijk[d]);
            }
    DrRng rng;
    dr_rng_seed(&rng, 3);
    for (long q = 0; q < 3 * NP; q++) v[q] = 2.0 * dr_rng_uniform(&rng) - 1.0;
    DrParticleBins *b = NULL;
    assert_int_equal(dr_bins_create(g, NP, &b, &err), DR_OK);
    assert_int_equal(dr_bins_build(g, NP, x, b, &err), DR_OK);
    for (int no_slip = 0; no_slip < 2; no_slip++) {
        double mp = 0.37;
        dr_transfer_p2g_mac(b, x, v, NULL, mp, no_slip, g, fm);
        double dev = 0.0;
        for (int a = 0; a < 3; a++)
            for (long f = 0; f < g->nfaces[a]; f++) {
                long ia = a == 0 ? f % (M + 1) : (a == 1 ? (f / M) % (M + 1) : f / (M * M));
                /* a wall face of the normal component lies on the mirror plane: it gets the particles'
                   weights once (its image is itself), half the interior mass; walls close it anyway */
                double expect = (ia == 0 || ia == M) ? 4.0 * mp : 8.0 * mp;
                dev = fmax(dev, fabs(fm[a][f] - expect));
            }
        /* weights are sums of a few dyadic products: exact up to round-off of 8·0.37 */
        assert_true(dev < 1e-13);
        double lhs = 0.0, scale = 0.0;
        double *G[3];
        for (int a = 0; a < 3; a++) {
            G[a] = malloc(sizeof(double) * (size_t)g->nfaces[a]);
            for (long f = 0; f < g->nfaces[a]; f++) {
                G[a][f] = 2.0 * dr_rng_uniform(&rng) - 1.0;
                lhs += fm[a][f] * g->f[a][f] * G[a][f];
                scale += fabs(fm[a][f] * g->f[a][f] * G[a][f]);
            }
        }
        for (int a = 0; a < 3; a++) memcpy(g->f[a], G[a], sizeof(double) * (size_t)g->nfaces[a]);
        dr_transfer_g2p_mac(g, NULL, DR_TRANSFER_PIC, 0.0, no_slip, NP, x, vg, NULL);
        double rhs = 0.0;
        for (long q = 0; q < 3 * NP; q++) rhs += mp * v[q] * vg[q];
        printf("wall fold (%s): face-mass deviation %.2e, adjoint mismatch %.2e of %.2e\n",
               no_slip ? "no-slip" : "slip", dev, fabs(lhs - rhs), scale);
        assert_true(fabs(lhs - rhs) <= 1e-13 * scale); /* same products summed in another order */
        for (int a = 0; a < 3; a++) free(G[a]);
    }
    dr_bins_destroy(&b);
    for (int a = 0; a < 3; a++) free(fm[a]);
    dr_mac_grid_destroy(&g);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_apic_conservation), cmocka_unit_test(test_affine_round_trip),
                                       cmocka_unit_test(test_p2g_thread_independent),
                                       cmocka_unit_test(test_wall_fold)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
