/* Unit tests of src/transfer: APIC conservation identities on the MAC grid, exact affine round trip,
 * PIC's loss of it, bins, thread-count independence of P2G, the wall mirror (P2G folds, adjoint of
 * G2P's mirror read), MAC RPIC; and for the collocated node grid: kernels, grid creation, the G2P rule of
 * every scheme and λ, the lone-particle property of §5.4, scatter/gather adjointness and identities,
 * degenerate inputs and the bins' order. tests/validation/test_apic_transfer.c holds the node grid's
 * conservation, round-trip and determinism checks. */
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
    dr_transfer_p2g_mac(b, X, V, c, 0.37, NULL, false, g, fm);
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
    dr_transfer_particle_totals(N, X, V, C, 0.37, NULL, g->dx, &Pp, &Lp);
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
    dr_transfer_particle_totals(N, X, V, C, 0.37, NULL, g->dx, &Pp, &Lp);
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

/* The per-particle mass factor of P2G (scale): all ones gives the bits of NULL; ½ for every particle gives exactly half
   the face masses (scaling by a power of two is exact in every product and sum) and the same face velocities, and ½
   for one particle alone half its face masses at its own velocity; random factors keep the conservation identity
   with the particle totals weighted the same way. */
static void test_p2g_scale(void **state)
{
    (void)state;
    double *fm[3], *ref[3], *uref[3];
    DrMacGrid *g = setup(13, fm);
    DrParticleBins *b = NULL;
    DrError err;
    double *scale = malloc(sizeof(double) * N);
    assert_int_equal(dr_bins_create(g, N, &b, &err), DR_OK);
    assert_int_equal(dr_bins_build(g, N, X, b, &err), DR_OK);
    dr_transfer_p2g_mac(b, X, V, C, 0.37, NULL, false, g, fm);
    for (int a = 0; a < 3; a++) {
        size_t bytes = sizeof(double) * (size_t)g->nfaces[a];
        ref[a] = malloc(bytes), uref[a] = malloc(bytes);
        memcpy(ref[a], fm[a], bytes);
        memcpy(uref[a], g->f[a], bytes);
    }
    for (int p = 0; p < N; p++) scale[p] = 1.0;
    dr_transfer_p2g_mac(b, X, V, C, 0.37, scale, false, g, fm);
    for (int a = 0; a < 3; a++) {
        assert_memory_equal(fm[a], ref[a], sizeof(double) * (size_t)g->nfaces[a]);
        assert_memory_equal(g->f[a], uref[a], sizeof(double) * (size_t)g->nfaces[a]);
    }
    for (int p = 0; p < N; p++) scale[p] = 0.5;
    dr_transfer_p2g_mac(b, X, V, C, 0.37, scale, false, g, fm);
    long faces = 0;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            assert_true(fm[a][f] == 0.5 * ref[a][f]);
            assert_true(g->f[a][f] == uref[a][f]);
            faces += ref[a][f] > 0.0;
        }
    assert_true(faces > 1000);

    /* one particle alone, at ½: half the face masses, its own velocity on every face it reaches (PIC) */
    double half = 0.5;
    assert_int_equal(dr_bins_build(g, 1, X, b, &err), DR_OK);
    dr_transfer_p2g_mac(b, X, V, NULL, 0.37, NULL, false, g, ref);
    dr_transfer_p2g_mac(b, X, V, NULL, 0.37, &half, false, g, fm);
    faces = 0;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            assert_true(fm[a][f] == 0.5 * ref[a][f]);
            if (fm[a][f] > 0.0) {
                assert_true(fabs(g->f[a][f] - V[a]) <= 1e-15 * fabs(V[a])); /* (w m v)/(w m): one rounding each */
                faces++;
            }
        }
    assert_int_equal(faces, 3 * 27);

    /* random factors: Σ m_f u_f and Σ x_f × m_f u_f equal the particle totals with m_p = 0.37·scale[p] */
    DrRng rng;
    dr_rng_seed(&rng, 17);
    for (int p = 0; p < N; p++) scale[p] = 0.1 + 1.9 * dr_rng_uniform(&rng);
    assert_int_equal(dr_bins_build(g, N, X, b, &err), DR_OK);
    dr_transfer_p2g_mac(b, X, V, C, 0.37, scale, false, g, fm);
    DrVec3 Pp, Lp, Pg, Lg;
    dr_transfer_particle_totals(N, X, V, C, 0.37, scale, g->dx, &Pp, &Lp);
    dr_transfer_grid_totals(g, (const double *const *)fm, (const double *const *)g->f, &Pg, &Lg);
    double msum = 0.0, mface = 0.0;
    for (int p = 0; p < N; p++) msum += 0.37 * scale[p];
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) mface += fm[a][f];
    printf("P2G with mass factors: mass rel %.2e, momentum rel %.2e, angular rel %.2e\n",
           fabs(mface / 3.0 - msum) / msum, rel(Pg, Pp), rel(Lg, Lp));
    /* as test_apic_conservation: sums of ~10⁵ terms, round-off ~1e-15 */
    assert_true(fabs(mface / 3.0 - msum) <= 1e-13 * msum);
    assert_true(rel(Pg, Pp) <= 1e-13);
    assert_true(rel(Lg, Lp) <= 1e-13);
    for (int a = 0; a < 3; a++) free(ref[a]), free(uref[a]);
    free(scale);
    dr_bins_destroy(&b);
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
        dr_transfer_p2g_mac(b, x, v, NULL, mp, NULL, no_slip, g, fm);
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

/* MAC RPIC: c is the skew part of the APIC c from the same grid, and G2P still conserves angular momentum
   (ε:Bᵀ sees only the skew part of B). */
static void test_mac_rpic(void **state)
{
    (void)state;
    double *fm[3];
    DrMacGrid *g = setup(23, fm);
    p2g(g, fm, C);
    DrVec3 Pg, Lg, Pp, Lp;
    dr_transfer_grid_totals(g, (const double *const *)fm, (const double *const *)g->f, &Pg, &Lg);
    static double v2[3 * N], c2[9 * N];
    memcpy(v2, V, sizeof v2);
    memcpy(c2, C, sizeof c2);
    dr_transfer_g2p_mac(g, NULL, DR_TRANSFER_APIC, 0.0, false, N, X, V, C);
    dr_transfer_g2p_mac(g, NULL, DR_TRANSFER_RPIC, 0.0, false, N, X, v2, c2);
    double e = 0.0;
    for (int p = 0; p < N; p++) {
        for (int a = 0; a < 3; a++) {
            assert_true(v2[3 * p + a] == V[3 * p + a]);
            for (int b = 0; b < 3; b++)
                e = fmax(e, fabs(c2[9 * p + 3 * a + b] - 0.5 * (C[9 * p + 3 * a + b] - C[9 * p + 3 * b + a])));
        }
    }
    dr_transfer_particle_totals(N, X, v2, c2, 0.37, NULL, g->dx, &Pp, &Lp);
    printf("MAC RPIC: |c − skew(c_APIC)| %.1e, momentum rel %.1e, angular rel %.1e\n", e, rel(Pp, Pg), rel(Lp, Lg));
    assert_true(e == 0.0); /* the same numbers, halved differences */
    assert_true(rel(Pp, Pg) <= 1e-13 && rel(Lp, Lg) <= 1e-13);
    teardown(&g, fm);
}

/* ==== collocated node grid ============================================================================ */

static const char *kn(DrKernel k) { return k == DR_KERNEL_LINEAR ? "linear" : (k == DR_KERNEL_QUADRATIC ? "quadratic" : "cubic"); }

/* dr_kernel_eval: node count and base, partition of unity, linear reproduction (eqs. 20–23 per axis:
   Σ w = 1, Σ w·i = s, Σ dw = 0, Σ dw·i = 1), second moment D (¼, ⅓, f(1 − f)), derivatives against central
   differences, the quadratic kernel equal to dr_kernel_quadratic bit for bit; dinv and reach values. */
static void test_kernels(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 8);
    for (int k = DR_KERNEL_LINEAR; k <= DR_KERNEL_CUBIC; k++) {
        double worst[5] = {0, 0, 0, 0, 0};
        for (int t = 0; t < 20000; t++) {
            double s = t < 8 ? (double)(t - 3) * 0.5 : -5.0 + 40.0 * dr_rng_uniform(&rng);
            DrStencil st = dr_kernel_eval((DrKernel)k, s);
            assert_int_equal(st.n, k + 2);
            double f = s - floor(s);
            int base = k == DR_KERNEL_LINEAR ? (int)floor(s) : (k == DR_KERNEL_QUADRATIC ? (int)floor(s - 0.5) : (int)floor(s) - 1);
            assert_int_equal(st.base, base);
            double sw = 0, swx = 0, sdw = 0, sdwx = 0, sd2 = 0;
            for (int q = 0; q < st.n; q++) {
                double xi = st.base + q;
                assert_true(st.w[q] >= 0.0);
                sw += st.w[q], swx += st.w[q] * xi, sdw += st.dw[q], sdwx += st.dw[q] * xi;
                sd2 += st.w[q] * (xi - s) * (xi - s);
            }
            for (int q = st.n; q < 4; q++) assert_true(st.w[q] == 0.0 && st.dw[q] == 0.0);
            double D = k == DR_KERNEL_LINEAR ? f * (1.0 - f) : (k == DR_KERNEL_QUADRATIC ? 0.25 : 1.0 / 3.0);
            double e[5] = {fabs(sw - 1), fabs(swx - s) / fmax(1.0, fabs(s)), fabs(sdw), fabs(sdwx - 1), fabs(sd2 - D)};
            for (int q = 0; q < 5; q++) worst[q] = fmax(worst[q], e[q]);
            if (k == DR_KERNEL_QUADRATIC) {
                DrStencil3 q3 = dr_kernel_quadratic(s);
                assert_int_equal(q3.base, st.base);
                for (int q = 0; q < 3; q++) assert_true(q3.w[q] == st.w[q] && q3.dw[q] == st.dw[q]);
            }
            /* derivative: central difference away from the knots (where the linear kernel's derivative
               jumps and the others' higher derivatives do), h = 1e-6: truncation O(h²), round-off 1e-10 */
            double h = 1e-6, knot = k == DR_KERNEL_QUADRATIC ? fabs(f - 0.5) : fmin(f, 1.0 - f);
            if (t >= 8 && knot > 1e-4) {
                DrStencil a = dr_kernel_eval((DrKernel)k, s + h), b = dr_kernel_eval((DrKernel)k, s - h);
                assert_int_equal(a.base, st.base);
                assert_int_equal(b.base, st.base);
                for (int q = 0; q < st.n; q++) assert_true(fabs((a.w[q] - b.w[q]) / (2 * h) - st.dw[q]) < 1e-8);
            }
        }
        printf("%-9s Σw−1 %.1e, Σw x−s %.1e, Σw' %.1e, Σw' x−1 %.1e, Σw r²−D %.1e\n", kn((DrKernel)k), worst[0], worst[1],
               worst[2], worst[3], worst[4]);
        for (int q = 0; q < 5; q++) assert_true(worst[q] < 1e-14); /* sums of 2–4 O(1) terms */
    }
    assert_true(dr_kernel_dinv(DR_KERNEL_QUADRATIC, 0.5) == 16.0);
    assert_true(dr_kernel_dinv(DR_KERNEL_CUBIC, 0.5) == 12.0);
    assert_true(dr_kernel_dinv(DR_KERNEL_LINEAR, 0.5) == 0.0);
    assert_int_equal(dr_kernel_reach(DR_KERNEL_LINEAR), 1);
    assert_int_equal(dr_kernel_reach(DR_KERNEL_QUADRATIC), 2);
    assert_int_equal(dr_kernel_reach(DR_KERNEL_CUBIC), 2);
}

/* Bad grid parameters are input errors naming what is wrong; node positions and indices. */
static void test_node_grid_create(void **state)
{
    (void)state;
    DrNodeGrid *g = NULL;
    DrError err;
    int n3[3] = {5, 6, 7}, n2[3] = {5, 6, 1}, bad2[3] = {5, 6, 2}, small[3] = {3, 6, 7};
    assert_int_equal(dr_node_grid_create(4, n3, 0.1, dr_v3(0, 0, 0), DR_KERNEL_QUADRATIC, &g, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "dimension 4"));
    assert_int_equal(dr_node_grid_create(3, n3, 0.0, dr_v3(0, 0, 0), DR_KERNEL_QUADRATIC, &g, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "spacing"));
    assert_int_equal(dr_node_grid_create(3, n3, NAN, dr_v3(0, 0, 0), DR_KERNEL_QUADRATIC, &g, &err), DR_ERR_INPUT);
    assert_int_equal(dr_node_grid_create(2, bad2, 0.1, dr_v3(0, 0, 0), DR_KERNEL_QUADRATIC, &g, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "n[2] = 1"));
    assert_int_equal(dr_node_grid_create(3, small, 0.1, dr_v3(0, 0, 0), DR_KERNEL_CUBIC, &g, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "at least 4"));
    assert_int_equal(dr_node_grid_create(3, n3, 0.1, dr_v3(INFINITY, 0, 0), DR_KERNEL_CUBIC, &g, &err), DR_ERR_INPUT);
    assert_null(g);
    assert_int_equal(dr_node_grid_create(3, n3, 0.1, dr_v3(1, 2, 3), DR_KERNEL_CUBIC, &g, &err), DR_OK);
    assert_int_equal(g->nnodes, 5 * 6 * 7);
    long i = dr_node_index(g, 4, 2, 6);
    DrVec3 x = dr_node_position(g, i);
    assert_true(fabs(x.x - 1.4) < 1e-15 && fabs(x.y - 2.2) < 1e-15 && fabs(x.z - 3.6) < 1e-15);
    dr_node_grid_destroy(&g);
    assert_null(g);
    dr_node_grid_destroy(&g); /* NULL: no-op */
    assert_int_equal(dr_node_grid_create(2, n2, 0.1, dr_v3(0, 0, 0), DR_KERNEL_LINEAR, &g, &err), DR_OK);
    assert_int_equal(g->nnodes, 30);
    dr_node_grid_destroy(&g);
}

typedef struct NodeSet {
    DrNodeGrid *g;
    DrNodeBins *b;
    long n;
    double *x, *v, *C, *m;
} NodeSet;

/* n random particles at least 3 spacings inside a grid of 16 nodes per axis (one layer in 2-D). */
static NodeSet node_set(int dim, DrKernel k, long n, uint64_t seed)
{
    NodeSet s = {NULL, NULL, n, NULL, NULL, NULL, NULL};
    DrError err;
    int nn[3] = {16, 16, dim == 3 ? 16 : 1};
    assert_int_equal(dr_node_grid_create(dim, nn, 0.2, dr_v3(0.3, -0.5, 0.1), k, &s.g, &err), DR_OK);
    s.x = calloc(3 * (size_t)n + 1, sizeof(double));
    s.v = calloc(3 * (size_t)n + 1, sizeof(double));
    s.C = calloc(9 * (size_t)n + 1, sizeof(double));
    s.m = calloc((size_t)n + 1, sizeof(double));
    DrRng r;
    dr_rng_seed(&r, seed);
    for (long p = 0; p < n; p++) {
        for (int d = 0; d < 3; d++) {
            s.x[3 * p + d] = dr_v3_get(s.g->origin, d) + (d < dim ? s.g->dx * (3.0 + 9.0 * dr_rng_uniform(&r)) : 0.0);
            s.v[3 * p + d] = d < dim ? 2.0 * dr_rng_uniform(&r) - 1.0 : 0.0;
        }
        for (int a = 0; a < dim; a++)
            for (int e = 0; e < dim; e++) s.C[9 * p + 3 * a + e] = 2.0 * dr_rng_uniform(&r) - 1.0;
        s.m[p] = 0.5 + dr_rng_uniform(&r);
    }
    assert_int_equal(dr_node_bins_create(s.g, 1, &s.b, &err), DR_OK);
    assert_int_equal(dr_node_bins_build(s.g, n, s.x, s.b, &err), DR_OK);
    return s;
}

static void node_free(NodeSet *s)
{
    dr_node_bins_destroy(&s->b);
    dr_node_grid_destroy(&s->g);
    free(s->x), free(s->v), free(s->C), free(s->m);
}

/* Affine node field b + A x. */
static double *affine_field(const DrNodeGrid *g, const double A[9], const double b0[3])
{
    double *f = malloc(sizeof(double) * 3 * (size_t)g->nnodes);
    for (long i = 0; i < g->nnodes; i++) {
        DrVec3 xi = dr_node_position(g, i);
        for (int a = 0; a < 3; a++) f[3 * i + a] = b0[a] + A[3 * a] * xi.x + A[3 * a + 1] * xi.y + A[3 * a + 2] * xi.z;
    }
    return f;
}

/* G2P rules of each scheme for grid fields ṽ = b + A x and v^n = b' + A' x (exact for every kernel):
   PIC v = b + A x_p, C zeroed; FLIP v ← β v_PIC + (1 − β)(v + Σ w (ṽ − v^n)); APIC C = A + (λΔt/2)(A A'ᵀ −
   A' Aᵀ) for B-splines (eq. 38; the affine field is preserved only for Δt = 0, §5.5), C = A for the lagged
   linear kernel; RPIC the skew part of that;
   grad_u = λ A' + (1 − λ) A; x ← x + Δt (λ(b' + A' x_p) + (1 − λ)(b + A x_p)); vel_old may be NULL for
   λ = 0. 2-D: z of v, C, grad_u written 0, x_z untouched. */
static void test_node_g2p_rules(void **state)
{
    (void)state;
    for (int dim = 2; dim <= 3; dim++)
        for (int k = DR_KERNEL_LINEAR; k <= DR_KERNEL_CUBIC; k++) {
            NodeSet s = node_set(dim, (DrKernel)k, 500, 3 + (uint64_t)k);
            double A[9] = {0.3, -1.2, 0.5, 0.7, 0.1, -0.4, -0.2, 0.9, -0.4}, b0[3] = {1.0, -2.0, 0.5};
            double A2[9] = {-0.1, 0.4, 0.2, 0.3, -0.6, 0.1, 0.5, 0.2, 0.3}, b2[3] = {0.2, 0.1, -0.3};
            if (dim == 2) A[2] = A[5] = A[6] = A[7] = A[8] = b0[2] = A2[2] = A2[5] = A2[6] = A2[7] = A2[8] = b2[2] = 0.0;
            double *vn = affine_field(s.g, A, b0), *vo = affine_field(s.g, A2, b2);
            long n = s.n;
            double *x = malloc(sizeof(double) * 3 * (size_t)n), *v = malloc(sizeof(double) * 3 * (size_t)n);
            double *C = malloc(sizeof(double) * 9 * (size_t)n), *gu = malloc(sizeof(double) * 9 * (size_t)n);
            const DrTransferScheme sch[4] = {DR_TRANSFER_PIC, DR_TRANSFER_FLIP, DR_TRANSFER_APIC, DR_TRANSFER_RPIC};
            const double lams[2] = {0.0, 0.5}, dt = 0.01, beta = 0.25;
            double worst = 0.0;
            for (int si = 0; si < 4; si++)
                for (int li = 0; li < 2; li++) {
                    double lam = lams[li];
                    memcpy(x, s.x, sizeof(double) * 3 * (size_t)n);
                    memcpy(v, s.v, sizeof(double) * 3 * (size_t)n);
                    for (long q = 0; q < 9 * n; q++) C[q] = 7.0;
                    for (long p = 0; p < n; p++) x[3 * p + 2] = dim == 2 ? 0.123 : x[3 * p + 2];
                    dr_node_g2p(s.g, vn, lam == 0.0 && sch[si] != DR_TRANSFER_FLIP ? NULL : vo, lam, dt, sch[si], beta, n,
                                x, v, C, gu);
                    for (long p = 0; p < n; p++) {
                        const double *xp = s.x + 3 * p;
                        for (int a = 0; a < 3; a++) {
                            double vpic = b0[a], vold = b2[a];
                            for (int e = 0; e < dim; e++) vpic += A[3 * a + e] * xp[e], vold += A2[3 * a + e] * xp[e];
                            double ve = sch[si] == DR_TRANSFER_FLIP ? beta * vpic + (1 - beta) * (s.v[3 * p + a] + vpic - vold) : vpic;
                            if (a >= dim) ve = 0.0;
                            worst = fmax(worst, fabs(v[3 * p + a] - ve));
                            double ub = lam * vold + (1 - lam) * vpic;
                            double xe = a < dim ? xp[a] + dt * ub : (dim == 2 ? 0.123 : xp[a]);
                            worst = fmax(worst, fabs(x[3 * p + a] - xe));
                            for (int e = 0; e < 3; e++) {
                                /* eq. (38)'s λ-term for affine fields: T = Σ w ṽ v^nᵀ = v_p v_oᵀ + A D A'ᵀ, so
                                   (λΔt/2)(T − Tᵀ + v_o v_pᵀ − v_p v_oᵀ) D⁻¹ = (λΔt/2)(A A'ᵀ − A' Aᵀ) (skew) */
                                double sk = 0.0;
                                for (int q = 0; q < 3; q++) sk += A[3 * a + q] * A2[3 * e + q] - A2[3 * a + q] * A[3 * e + q];
                                sk *= k == DR_KERNEL_LINEAR ? 0.0 : 0.5 * lam * dt;
                                double Ce = 0.0;
                                if (sch[si] == DR_TRANSFER_APIC) Ce = A[3 * a + e] + sk;
                                if (sch[si] == DR_TRANSFER_RPIC) Ce = 0.5 * (A[3 * a + e] - A[3 * e + a]) + sk;
                                worst = fmax(worst, fabs(C[9 * p + 3 * a + e] - Ce));
                                double ge = lam * A2[3 * a + e] + (1 - lam) * A[3 * a + e];
                                worst = fmax(worst, fabs(gu[9 * p + 3 * a + e] - ge));
                            }
                        }
                    }
                }
            printf("%dD %-9s G2P rules (PIC, FLIP, APIC, RPIC × λ 0, ½): max deviation %.1e\n", dim, kn((DrKernel)k), worst);
            /* exact in exact arithmetic for affine fields; round-off of sums scaled by D⁻¹Δx ~ 20–100 */
            assert_true(worst < 1e-11);
            free(vn), free(vo), free(x), free(v), free(C), free(gu);
            node_free(&s);
        }
}

/* [APIC] §5.4: a lone particle without forces keeps v_p and B_p (so C_p) and moves by Δt v_p for any λ;
   here P2G, ṽ = v (no force), G2P. A wrong eq. (38) term shows up as a change of C. */
static void test_isolated_particle(void **state)
{
    (void)state;
    for (int dim = 2; dim <= 3; dim++)
        for (int k = DR_KERNEL_QUADRATIC; k <= DR_KERNEL_CUBIC; k++)
            for (int li = 0; li < 3; li++) {
                double lam = 0.5 * li, dt = 0.05;
                NodeSet s = node_set(dim, (DrKernel)k, 1, 40 + (uint64_t)li);
                double x0[3], v0[3], C0[9];
                memcpy(x0, s.x, sizeof x0), memcpy(v0, s.v, sizeof v0), memcpy(C0, s.C, sizeof C0);
                dr_node_p2g(s.b, s.x, s.v, s.C, s.m, s.g);
                double *vo = malloc(sizeof(double) * 3 * (size_t)s.g->nnodes);
                memcpy(vo, s.g->vel, sizeof(double) * 3 * (size_t)s.g->nnodes);
                dr_node_g2p(s.g, s.g->vel, vo, lam, dt, DR_TRANSFER_APIC, 0.0, 1, s.x, s.v, s.C, NULL);
                double e = 0.0;
                for (int a = 0; a < 3; a++) {
                    e = fmax(e, fabs(s.v[a] - v0[a]));
                    e = fmax(e, fabs(s.x[a] - (x0[a] + (a < dim ? dt * v0[a] : 0.0))));
                    /* C = B D⁻¹ with D⁻¹Δx = 20/m: round-off of B scaled accordingly */
                    for (int b = 0; b < 3; b++) e = fmax(e, fabs(s.C[3 * a + b] - C0[3 * a + b]) * 1e-2);
                }
                printf("%dD %-9s λ=%.1f lone particle: max change %.1e\n", dim, kn((DrKernel)k), lam, e);
                assert_true(e < 1e-13);
                free(vo);
                node_free(&s);
            }
}

/* The weighted scatters are the adjoints of the gathers, Σ out = 0 for the gradient scatter (eq. 20),
   Σ_i x_i × out_i = Σ_p (M₂₁ − M₁₂, M₀₂ − M₂₀, M₁₀ − M₀₁) (eq. 23), the vector scatter keeps Σ f; the
   gradient gather of an affine field is its matrix, the vector gather its value. */
static void test_scatter_gather(void **state)
{
    (void)state;
    for (int dim = 2; dim <= 3; dim++)
        for (int k = DR_KERNEL_LINEAR; k <= DR_KERNEL_CUBIC; k++) {
            NodeSet s = node_set(dim, (DrKernel)k, 3000, 77);
            DrNodeGrid *g = s.g;
            long n = s.n, nn = g->nnodes;
            double *M = malloc(sizeof(double) * 9 * (size_t)n), *out = malloc(sizeof(double) * 3 * (size_t)nn);
            double *u = malloc(sizeof(double) * 3 * (size_t)nn), *G = malloc(sizeof(double) * 9 * (size_t)n);
            double *uv = malloc(sizeof(double) * 3 * (size_t)n);
            DrRng r;
            dr_rng_seed(&r, 4);
            for (long q = 0; q < 9 * n; q++) M[q] = (q % 9) / 3 < dim && (q % 3) < dim ? 2.0 * dr_rng_uniform(&r) - 1.0 : 0.0;
            for (long q = 0; q < 3 * nn; q++) u[q] = q % 3 < dim ? 2.0 * dr_rng_uniform(&r) - 1.0 : 0.0;
            dr_node_scatter_gradient(s.b, s.x, M, g, out);
            dr_node_gather_gradient(g, u, n, s.x, G);
            double lhs = 0, rhs = 0, scale = 0;
            DrVec3 sum = dr_v3(0, 0, 0), ang = dr_v3(0, 0, 0), angp = dr_v3(0, 0, 0);
            for (long i = 0; i < nn; i++) {
                DrVec3 o = dr_v3(out[3 * i], out[3 * i + 1], out[3 * i + 2]);
                if (dim == 2) assert_true(o.z == 0.0);
                lhs += dr_v3_dot(o, dr_v3(u[3 * i], u[3 * i + 1], u[3 * i + 2]));
                sum = dr_v3_add(sum, o);
                ang = dr_v3_add(ang, dr_v3_cross(dr_node_position(g, i), o));
            }
            for (long p = 0; p < n; p++) {
                const double *m = M + 9 * p;
                for (int q = 0; q < 9; q++) rhs += m[q] * G[9 * p + q], scale += fabs(m[q] * G[9 * p + q]);
                angp = dr_v3_add(angp, dr_v3(m[7] - m[5], m[2] - m[6], m[3] - m[1]));
            }
            double ea = dim == 3 ? rel(ang, angp) : fabs(ang.z - angp.z) / fabs(angp.z);
            printf("%dD %-9s gradient scatter/gather: adjoint %.1e, |Σ out| %.1e, angular rel %.1e\n", dim, kn((DrKernel)k),
                   fabs(lhs - rhs) / scale, dr_v3_norm(sum), ea);
            assert_true(fabs(lhs - rhs) <= 1e-13 * scale);
            assert_true(dr_v3_norm(sum) < 1e-11); /* Σ of ~10⁵ terms of O(10) (∇w ~ 1/Δx) */
            assert_true(ea < 1e-12);
            /* vector pair */
            double *f = malloc(sizeof(double) * 3 * (size_t)n);
            for (long q = 0; q < 3 * n; q++) f[q] = q % 3 < dim ? 2.0 * dr_rng_uniform(&r) - 1.0 : 0.0;
            dr_node_scatter_vector(s.b, s.x, f, g, out);
            dr_node_gather_vector(g, u, n, s.x, uv);
            lhs = rhs = scale = 0;
            DrVec3 fs = dr_v3(0, 0, 0), fo = dr_v3(0, 0, 0);
            for (long i = 0; i < 3 * nn; i++) lhs += out[i] * u[i];
            for (long i = 0; i < nn; i++) fo = dr_v3_add(fo, dr_v3(out[3 * i], out[3 * i + 1], out[3 * i + 2]));
            for (long q = 0; q < 3 * n; q++) rhs += f[q] * uv[q], scale += fabs(f[q] * uv[q]);
            for (long p = 0; p < n; p++) fs = dr_v3_add(fs, dr_v3(f[3 * p], f[3 * p + 1], f[3 * p + 2]));
            assert_true(fabs(lhs - rhs) <= 1e-13 * scale);
            assert_true(dr_v3_norm(dr_v3_sub(fs, fo)) < 1e-12);
            if (dim == 2)
                for (long p = 0; p < n; p++) assert_true(uv[3 * p + 2] == 0.0 && G[9 * p + 2] == 0.0 && G[9 * p + 8] == 0.0);
            /* affine field through the gathers */
            double A[9] = {0.3, -1.2, 0.5, 0.7, 0.1, -0.4, -0.2, 0.9, -0.4}, b0[3] = {1.0, -2.0, 0.5};
            if (dim == 2) A[2] = A[5] = A[6] = A[7] = A[8] = b0[2] = 0.0;
            double *af = affine_field(g, A, b0), e = 0.0;
            dr_node_gather_gradient(g, af, n, s.x, G);
            dr_node_gather_vector(g, af, n, s.x, uv);
            for (long p = 0; p < n; p++)
                for (int a = 0; a < 3; a++) {
                    double ve = b0[a];
                    for (int d = 0; d < dim; d++) ve += A[3 * a + d] * s.x[3 * p + d];
                    for (int d = 0; d < 3; d++) e = fmax(e, fabs(G[9 * p + 3 * a + d] - A[3 * a + d]));
                    e = fmax(e, fabs(uv[3 * p + a] - ve));
                }
            assert_true(e < 1e-12);
            free(af), free(f), free(M), free(out), free(u), free(G), free(uv);
            node_free(&s);
        }
}

/* Degenerate inputs: zero particles give an empty grid (mass and velocity 0); G2P and the gathers of zero
   particles write nothing. The bins' order is a permutation of the particles sorted by bin, stable within
   a bin. */
static void test_node_degenerate_and_order(void **state)
{
    (void)state;
    NodeSet s = node_set(3, DR_KERNEL_QUADRATIC, 2000, 12);
    DrError err;
    dr_node_p2g(s.b, s.x, s.v, s.C, s.m, s.g);
    long cnt = 0;
    const long *ord = dr_node_bins_order(s.b, &cnt);
    assert_int_equal(cnt, 2000);
    char *seen = calloc(2000, 1);
    long prev_bin = -1, prev_p = -1;
    for (long q = 0; q < cnt; q++) {
        long p = ord[q];
        assert_true(p >= 0 && p < 2000 && !seen[p]);
        seen[p] = 1;
        long bin = 0, stride = 1;
        for (int d = 0; d < 3; d++) {
            DrStencil st = dr_kernel_eval(DR_KERNEL_QUADRATIC, (s.x[3 * p + d] - dr_v3_get(s.g->origin, d)) / s.g->dx);
            bin += st.base * stride;
            stride *= s.g->n[d] - 2;
        }
        assert_true(bin > prev_bin || (bin == prev_bin && p > prev_p));
        prev_bin = bin, prev_p = p;
    }
    free(seen);
    assert_int_equal(dr_node_bins_build(s.g, 0, s.x, s.b, &err), DR_OK);
    dr_node_p2g(s.b, s.x, s.v, s.C, s.m, s.g);
    for (long i = 0; i < s.g->nnodes; i++)
        assert_true(s.g->mass[i] == 0.0 && s.g->vel[3 * i] == 0.0 && s.g->vel[3 * i + 1] == 0.0 && s.g->vel[3 * i + 2] == 0.0);
    double before = s.v[0];
    dr_node_g2p(s.g, s.g->vel, NULL, 0.0, 0.1, DR_TRANSFER_APIC, 0.0, 0, s.x, s.v, s.C, NULL);
    dr_node_gather_vector(s.g, s.g->vel, 0, s.x, NULL);
    assert_true(s.v[0] == before);
    node_free(&s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_apic_conservation), cmocka_unit_test(test_affine_round_trip),
                                       cmocka_unit_test(test_p2g_thread_independent), cmocka_unit_test(test_p2g_scale),
                                       cmocka_unit_test(test_wall_fold), cmocka_unit_test(test_mac_rpic),
                                       cmocka_unit_test(test_kernels), cmocka_unit_test(test_node_grid_create),
                                       cmocka_unit_test(test_node_g2p_rules), cmocka_unit_test(test_isolated_particle),
                                       cmocka_unit_test(test_scatter_gather),
                                       cmocka_unit_test(test_node_degenerate_and_order)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
