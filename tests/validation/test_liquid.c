/* Validation of the bulk-liquid solver (src/liquid): hydrostatic rest, conservation through a dam
 * break, APIC angular momentum of a rotating blob (both pressure formulations), static and moving
 * colliders, emitters/kill boxes. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <cmocka.h>

#include "liquid/liquid.h"

/* Exact signed distance of an axis-aligned box (negative inside). */
static double box_sdf(DrVec3 p, DrVec3 lo, DrVec3 hi)
{
    double q[3], outside = 0.0, inside = -INFINITY;
    for (int d = 0; d < 3; d++) {
        double c = 0.5 * (dr_v3_get(lo, d) + dr_v3_get(hi, d)), h = 0.5 * (dr_v3_get(hi, d) - dr_v3_get(lo, d));
        q[d] = fabs(dr_v3_get(p, d) - c) - h;
        if (q[d] > 0) outside += q[d] * q[d];
        if (q[d] > inside) inside = q[d];
    }
    return outside > 0 ? sqrt(outside) : inside;
}

/* A collider from an analytic box (rest frame) sampled at spacing h with a margin of 3h. */
static DrCollider *make_box(DrVec3 lo, DrVec3 hi, double h, int nkeys, const double *keys, bool no_slip,
                            double friction)
{
    DrVec3 o = dr_v3_sub(lo, dr_v3(3 * h, 3 * h, 3 * h));
    int n[3];
    for (int d = 0; d < 3; d++) n[d] = (int)ceil((dr_v3_get(hi, d) - dr_v3_get(lo, d)) / h) + 7;
    float *phi = malloc(sizeof(float) * (size_t)n[0] * n[1] * n[2]);
    for (int k = 0; k < n[2]; k++)
        for (int j = 0; j < n[1]; j++)
            for (int i = 0; i < n[0]; i++)
                phi[i + n[0] * (j + n[1] * k)] = (float)box_sdf(dr_v3_add(o, dr_v3(i * h, j * h, k * h)), lo, hi);
    DrColliderDesc cd = {phi, n[0], n[1], n[2], o, h, friction, no_slip, 0.0, nkeys, keys};
    DrCollider *c = NULL;
    DrError err;
    assert_int_equal(dr_collider_create(&cd, &c, &err), DR_OK);
    free(phi);
    return c;
}

static DrCollider *make_sphere(DrVec3 center, double r, double h)
{
    int n = (int)ceil(2 * r / h) + 7;
    DrVec3 o = dr_v3_sub(center, dr_v3(0.5 * (n - 1) * h, 0.5 * (n - 1) * h, 0.5 * (n - 1) * h));
    float *phi = malloc(sizeof(float) * (size_t)n * n * n);
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++)
                phi[i + n * (j + n * k)] =
                    (float)(dr_v3_norm(dr_v3_sub(dr_v3_add(o, dr_v3(i * h, j * h, k * h)), center)) - r);
    DrColliderDesc cd = {phi, n, n, n, o, h, 0.0, false, 0.0, 0, NULL};
    DrCollider *c = NULL;
    DrError err;
    assert_int_equal(dr_collider_create(&cd, &c, &err), DR_OK);
    free(phi);
    return c;
}

static double max_speed(const DrLiquidState *s)
{
    double m = 0.0;
    for (long p = 0; p < s->n; p++) {
        double v = sqrt(s->v[3 * p] * s->v[3 * p] + s->v[3 * p + 1] * s->v[3 * p + 1] + s->v[3 * p + 2] * s->v[3 * p + 2]);
        if (v > m) m = v;
    }
    return m;
}

/* 1. Hydrostatic tank: 24³ cells, water 12 cells deep, surface on a face layer, 2 s. The acceptance
   criterion is max |v_p| < 1e-3 m/s. Gravity gives 9.81·Δt ≈ 0.3 m/s per substep before projection, so
   the bound demands that the projection cancel gravity to better than 0.3 %; with a flat level set and
   tolerance 1e-8 it does so to round-off plus the solver residual. */
static double run_tank(DrPressureFormulation pressure, double jitter)
{
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.dx = 1.0 / 24.0;
    d.pressure_tol = 1e-8;
    d.pressure = pressure;
    d.jitter = jitter;
    DrBoxVel water = {dr_v3(0, 0, 0), dr_v3(1, 0.5, 1), dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, NULL, 0, &liq, &err), DR_OK);
    long n0 = dr_liquid_state(liq)->n;
    assert_int_equal(n0, 24L * 12 * 24 * 8);
    double worst = 0.0;
    int substeps = 0, iters = 0;
    for (int f = 0; f < 48; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, NULL, 0, f / 24.0, (f + 1) / 24.0, &st, &err), DR_OK);
        assert_int_equal(st.pressure_not_converged, 0);
        substeps += st.substeps;
        if (st.pressure_iterations_max > iters) iters = st.pressure_iterations_max;
        double m = max_speed(dr_liquid_state(liq));
        if (m > worst) worst = m;
    }
    printf("tank (%s, jitter %g): %ld particles, %d substeps, max PCG iterations %d, max |v| over 2 s = %.3e m/s\n",
           pressure == DR_PRESSURE_GHOST_FLUID ? "ghost fluid" : "mass weighted", jitter, n0, substeps, iters, worst);
    dr_liquid_destroy(&liq);
    return worst;
}

static void test_hydrostatic_tank(void **state)
{
    (void)state;
    /* the default: ghost fluid with fully jittered seeding; measured ~1.3e-9 m/s */
    assert_true(run_tank(DR_PRESSURE_GHOST_FLUID, 1.0) < 1e-3);
}

/* The mass-weighted projection weights each face by its P2G mass, so still water stays still only where
   the face masses are uniform: a face density varying sideways is a horizontal density gradient, which
   gravity turns into flow. Unjittered seeding (two half-spacing sub-lattices per axis, on which the
   B-spline weights sum to one; walls fold the kernel back, transfer.h) gives uniform masses, and the
   faces with mass above the surface lie in the constrained cells (liquid.h): the same < 1e-3 m/s bound
   holds (measured ~5e-8 m/s). Fully jittered seeding leaves random face-mass variations, which drive a
   slow circulation (measured ~0.24 m/s): only printed, it is the documented price of the formulation. */
static void test_hydrostatic_tank_mass_weighted(void **state)
{
    (void)state;
    assert_true(run_tank(DR_PRESSURE_MASS_WEIGHTED, 0.0) < 1e-3);
    double jittered = run_tank(DR_PRESSURE_MASS_WEIGHTED, 1.0);
    assert_true(isfinite(jittered));
}

/* 2. Dam break with a static obstacle: count and mass exact, every particle in the domain and outside the
   obstacle after every frame, projected divergence tied to the tolerance. */
static void run_dam_break(DrPressureFormulation pressure)
{
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.pressure = pressure;
    d.domain_hi = dr_v3(1.0, 0.5, 0.25);
    d.dx = 1.0 / 32.0;
    DrBoxVel water = {dr_v3(0, 0, 0), dr_v3(0.3, 0.35, 0.25), dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    DrVec3 olo = dr_v3(0.55, 0.0, 0.05), ohi = dr_v3(0.65, 0.12, 0.2);
    DrCollider *obst = make_box(olo, ohi, 0.01, 0, NULL, false, 0.3);
    const DrCollider *cols[1] = {obst};
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, cols, 1, &liq, &err), DR_OK);
    long n0 = dr_liquid_state(liq)->n;
    double m0;
    dr_liquid_totals(liq, &m0, NULL, NULL, NULL);
    double divmax = 0.0;
    int iters = 0, substeps = 0;
    for (int f = 0; f < 24; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, cols, 1, f / 48.0, (f + 1) / 48.0, &st, &err), DR_OK);
        const DrLiquidState *s = dr_liquid_state(liq);
        assert_int_equal(s->n, n0);
        double m;
        dr_liquid_totals(liq, &m, NULL, NULL, NULL);
        assert_true(m == m0); /* n·m_p with n unchanged: exact */
        for (long p = 0; p < s->n; p++) {
            DrVec3 x = dr_v3(s->x[3 * p], s->x[3 * p + 1], s->x[3 * p + 2]);
            assert_true(x.x >= d.domain_lo.x && x.x <= d.domain_hi.x && x.y >= d.domain_lo.y &&
                        x.y <= d.domain_hi.y && x.z >= d.domain_lo.z && x.z <= d.domain_hi.z);
            /* the push-out leaves particles 1e-4·dx beyond the surface; none may be inside */
            assert_true(dr_collider_phi(obst, (f + 1) / 48.0, x, NULL) >= 0.0);
        }
        if (st.divergence_mean > divmax) divmax = st.divergence_mean;
        if (st.pressure_iterations_max > iters) iters = st.pressure_iterations_max;
        substeps += st.substeps;
    }
    /* ‖r‖₂ ≤ tol‖b‖₂ gives mean|Δx·div u| ≤ tol·max|Δx·div u*| ≤ 6·tol·|u*|max; with |u*|max ≲ 2|u|max
       after projection the bound is 12·tol; 20·tol leaves room for the recursive-residual drift. */
    printf("dam break (%s): %ld particles, %d substeps, max PCG iterations %d, max mean divergence %.3e (tol %.1e)\n",
           pressure == DR_PRESSURE_GHOST_FLUID ? "ghost fluid" : "mass weighted", n0, substeps, iters, divmax,
           d.pressure_tol);
    assert_true(divmax < 20.0 * d.pressure_tol);
    dr_liquid_destroy(&liq);
    dr_collider_destroy(&obst);
}

static void test_dam_break_conservation(void **state)
{
    (void)state;
    run_dam_break(DR_PRESSURE_GHOST_FLUID);
}

static void test_dam_break_conservation_mass_weighted(void **state)
{
    (void)state;
    run_dam_break(DR_PRESSURE_MASS_WEIGHTED);
}

/* 3. Rotating blob, zero gravity, no walls touched, viscosity 0 (explicit viscosity is not torque-free
   at a free surface: zero-flux neighbours), 100 single-substep steps. Outputs relative to |L0|: total
   drift, the part not explained by the grid phases' impulse, the grid impulse; and the linear-momentum
   drift relative to M·|ω|·R. */
typedef struct BlobResult { double drift, unexplained, grid, linear; } BlobResult;

static BlobResult run_blob(DrTransferScheme scheme, DrPressureFormulation pressure)
{
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.dx = 1.0 / 32.0;
    d.gravity = dr_v3(0, 0, 0);
    d.viscosity = 0.0;
    d.scheme = scheme;
    d.pressure = pressure;
    d.pressure_tol = 1e-10;
    DrVec3 ctr = dr_v3(0.5, 0.5, 0.5);
    double radius = 0.15;
    DrCollider *sphere = make_sphere(ctr, radius, 0.01);
    const DrCollider *shapes[1] = {sphere};
    d.nsource_shapes = 1;
    d.source_shapes = shapes;
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, NULL, 0, &liq, &err), DR_OK);
    DrLiquidState *s = dr_liquid_state_mut(liq);
    DrVec3 w = dr_v3(0.4, -0.3, 1.0);
    double W[3][3] = {{0, -w.z, w.y}, {w.z, 0, -w.x}, {-w.y, w.x, 0}}; /* skew(ω): ω × r = W r */
    for (long p = 0; p < s->n; p++) {
        DrVec3 r = dr_v3_sub(dr_v3(s->x[3 * p], s->x[3 * p + 1], s->x[3 * p + 2]), ctr);
        DrVec3 v = dr_v3_cross(w, r);
        s->v[3 * p] = v.x; s->v[3 * p + 1] = v.y; s->v[3 * p + 2] = v.z;
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) s->c[9 * p + 3 * a + b] = scheme == DR_TRANSFER_APIC ? W[a][b] : 0.0;
    }
    DrVec3 L0, L1, P0, P1, imp = dr_v3(0, 0, 0);
    double mass;
    dr_liquid_totals(liq, &mass, &P0, &L0, NULL);
    for (int step = 0; step < 100; step++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, NULL, 0, step * 0.01, (step + 1) * 0.01, &st, &err), DR_OK);
        assert_int_equal(st.substeps, 1);
        imp = dr_v3_add(imp, st.grid_angular_impulse);
    }
    dr_liquid_totals(liq, NULL, &P1, &L1, NULL);
    double l0 = dr_v3_norm(L0);
    BlobResult r;
    r.drift = dr_v3_norm(dr_v3_sub(L1, L0)) / l0;
    r.unexplained = dr_v3_norm(dr_v3_sub(dr_v3_sub(L1, L0), imp)) / l0;
    r.grid = dr_v3_norm(imp) / l0;
    r.linear = dr_v3_norm(dr_v3_sub(P1, P0)) / (mass * dr_v3_norm(w) * radius);
    dr_liquid_destroy(&liq);
    dr_collider_destroy(&sphere);
    return r;
}

/* The acceptance criterion: mass-weighted pressure + APIC keeps L to <= 1e-10 relative per 100 steps.
   APIC transfers and x += Δt v^{n+1} conserve L exactly ([APIC] §5.3) and the mass-weighted projection
   is torque-free by summation by parts (liquid.h), so only round-off remains: ~100 steps of sums over
   ~3·10³ particles and ~10⁴ faces at relative 1e-16 each (measured ~4e-15). The same argument conserves
   linear momentum (measured ~1e-15 of M|ω|R). */
static void test_rotating_blob_mass_weighted_apic(void **state)
{
    (void)state;
    BlobResult r = run_blob(DR_TRANSFER_APIC, DR_PRESSURE_MASS_WEIGHTED);
    printf("blob mass weighted APIC: |ΔL|/|L0| %.3e (grid phases %.3e), |ΔP|/(M|ω|R) %.3e\n", r.drift, r.grid,
           r.linear);
    assert_true(r.drift <= 1e-10);
    assert_true(r.linear <= 1e-10);
}

/* PIC drops the affine part, so each P2G→G2P round trip averages the rotation away at the kernel scale
   (a rigid rotation resolved by ~10 cells across loses a large share every step): measured ~0.99 of L
   lost over 100 steps with the same torque-free projection, so the loss is the transfer's. Bound 0.5:
   visibly lost, with margin. */
static void test_rotating_blob_mass_weighted_pic(void **state)
{
    (void)state;
    BlobResult r = run_blob(DR_TRANSFER_PIC, DR_PRESSURE_MASS_WEIGHTED);
    printf("blob mass weighted PIC: |ΔL|/|L0| %.3e (grid phases %.3e)\n", r.drift, r.grid);
    assert_true(r.drift > 0.5);
    /* the projection itself still gives no torque: the loss is all in the transfers */
    assert_true(r.grid <= 1e-10);
}

static void test_rotating_blob_ghost_fluid(void **state)
{
    (void)state;
    BlobResult apic = run_blob(DR_TRANSFER_APIC, DR_PRESSURE_GHOST_FLUID);
    BlobResult pic = run_blob(DR_TRANSFER_PIC, DR_PRESSURE_GHOST_FLUID);
    BlobResult flip = run_blob(DR_TRANSFER_FLIP, DR_PRESSURE_GHOST_FLUID);
    printf("blob ghost fluid |ΔL|/|L0| over 100 steps: APIC %.3e (transfers+advection %.3e, grid phases %.3e), "
           "PIC %.3e, FLIP %.3e\n", apic.drift, apic.unexplained, apic.grid, pic.drift, flip.drift);
    /* APIC transfers and x += Δt v^{n+1} conserve L exactly ([APIC] §5.3): all change must come from the
       grid phases, to round-off accumulated over 100 steps of ~10⁴ sums (1e-10 relative). */
    assert_true(apic.unexplained <= 1e-10);
    /* The ghost-fluid projection is not torque-free on a free-surface blob: rigid rotation advected along
       straight lines leaves a centripetal divergence 2Δt|ω|² that the projection removes, and with a
       ghost-fluid surface (θ ≠ 1) and extrapolated faces its discrete torque is not exactly zero.
       Measured 8.4e-3 over 100 steps (Δtω ≈ 0.011 per step); bounded at 3e-2. */
    assert_true(apic.drift <= 3e-2);
    /* PIC damps the rotation at the particle scale: measured loss ~1.0 (nearly all of it) */
    assert_true(pic.drift > 0.5);
    assert_true(pic.drift > 10.0 * apic.drift);
}

/* 4. Liquid falling onto a static box collider never enters it. */
static void test_static_collider(void **state)
{
    (void)state;
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = dr_v3(0.5, 0.6, 0.5);
    d.dx = 1.0 / 40.0;
    DrBoxVel water = {dr_v3(0.15, 0.35, 0.15), dr_v3(0.35, 0.5, 0.35), dr_v3(0, -1.0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    DrVec3 blo = dr_v3(0.1, 0.1, 0.1), bhi = dr_v3(0.4, 0.2, 0.4);
    DrCollider *box = make_box(blo, bhi, 0.0125, 0, NULL, false, 0.5);
    const DrCollider *cols[1] = {box};
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, cols, 1, &liq, &err), DR_OK);
    long n0 = dr_liquid_state(liq)->n;
    int resting_on_top = 0;
    for (int f = 0; f < 20; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, cols, 1, f / 48.0, (f + 1) / 48.0, &st, &err), DR_OK);
        const DrLiquidState *s = dr_liquid_state(liq);
        assert_int_equal(s->n, n0);
        resting_on_top = 0;
        for (long p = 0; p < s->n; p++) {
            DrVec3 x = dr_v3(s->x[3 * p], s->x[3 * p + 1], s->x[3 * p + 2]);
            assert_true(dr_collider_phi(box, (f + 1) / 48.0, x, NULL) >= 0.0);
            if (x.y < 0.2 + 2 * d.dx && x.y > 0.2 && x.x > 0.1 && x.x < 0.4 && x.z > 0.1 && x.z < 0.4) resting_on_top++;
        }
    }
    printf("static collider: %d of %ld particles within 2 cells above the box top\n", resting_on_top, n0);
    assert_true(resting_on_top > 0); /* the liquid did reach the box and stays outside it */
    dr_liquid_destroy(&liq);
    dr_collider_destroy(&box);
}

/* 5. A paddle moved by keys through a pool pushes the liquid along +x. */
static void test_moving_paddle(void **state)
{
    (void)state;
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = dr_v3(1.0, 0.4, 0.25);
    d.dx = 1.0 / 32.0;
    DrBoxVel water = {dr_v3(0, 0, 0), dr_v3(1.0, 0.15625, 0.25), dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    double keys[14] = {0.0, 0, 0, 0, 0, 0, 0, 0.5, 0.3, 0, 0, 0, 0, 0}; /* +0.6 m/s along x for 0.5 s */
    DrCollider *paddle = make_box(dr_v3(0.1, 0.03125, 0.03125), dr_v3(0.15, 0.3, 0.21875), 0.01, 2, keys, false, 0.0);
    const DrCollider *cols[1] = {paddle};
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, cols, 1, &liq, &err), DR_OK);
    double mass;
    DrVec3 P;
    for (int f = 0; f < 12; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, cols, 1, f / 48.0, (f + 1) / 48.0, &st, &err), DR_OK);
        const DrLiquidState *s = dr_liquid_state(liq);
        for (long p = 0; p < s->n; p++) {
            double ph = dr_collider_phi(paddle, (f + 1) / 48.0, dr_v3(s->x[3 * p], s->x[3 * p + 1], s->x[3 * p + 2]), NULL);
            assert_true(ph >= 0.0);
        }
    }
    dr_liquid_totals(liq, &mass, &P, NULL, NULL);
    /* reference scale: the liquid mass the paddle's immersed section (0.125 × 0.1875 m²) sweeps in 0.25 s,
       times its speed; the liquid must gain a clear +x momentum of at least a fifth of it, and the
       z-symmetric setup must not produce a comparable z momentum */
    double ref = 0.125 * 0.1875 * 0.6 * 0.25 * d.density * 0.6;
    printf("paddle: liquid momentum x %.4f kg m/s (reference scale %.4f), y %.4f, z %.4f\n", P.x, ref, P.y, P.z);
    assert_true(P.x > 0.2 * ref);
    assert_true(fabs(P.z) < 0.2 * P.x);
    dr_liquid_destroy(&liq);
    dr_collider_destroy(&paddle);
}

/* 6. Emitter only inside its time range; kill box removes particles; counts add up. */
static void test_emitter_and_kill(void **state)
{
    (void)state;
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = dr_v3(0.5, 0.5, 0.25);
    d.dx = 1.0 / 32.0;
    DrBoxVel em = {dr_v3(0.2, 0.35, 0.1), dr_v3(0.3, 0.45, 0.15), dr_v3(0, -1, 0), 0.1, 0.3};
    d.nemitters = 1;
    d.emitters = &em;
    DrVec3 klo = dr_v3(0.0, 0.0, 0.0), khi = dr_v3(0.5, 0.1, 0.25);
    d.nkill_boxes = 1;
    d.kill_lo = &klo;
    d.kill_hi = &khi;
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, NULL, 0, &liq, &err), DR_OK);
    assert_int_equal(dr_liquid_state(liq)->n, 0);
    long emitted = 0, killed = 0;
    for (int f = 0; f < 30; f++) {
        double t0 = f / 48.0, t1 = (f + 1) / 48.0;
        long before = dr_liquid_state(liq)->n;
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, NULL, 0, t0, t1, &st, &err), DR_OK);
        long after = dr_liquid_state(liq)->n;
        assert_int_equal(after, before + st.emitted - st.killed);
        assert_int_equal(st.particles, after);
        if (t1 <= em.start || t0 >= em.end) assert_int_equal(st.emitted, 0); /* outside the time range */
        if (t0 >= em.start && t1 <= em.end) assert_true(st.emitted > 0);
        emitted += st.emitted;
        killed += st.killed;
        const DrLiquidState *s = dr_liquid_state(liq);
        for (long p = 0; p < s->n; p++) assert_false(s->x[3 * p + 1] < khi.y);
    }
    printf("emitter: emitted %ld, killed %ld, left %ld\n", emitted, killed, dr_liquid_state(liq)->n);
    assert_true(killed > 0);
    assert_int_equal(dr_liquid_state(liq)->n, emitted - killed);
    dr_liquid_destroy(&liq);
}

/* 7. Determinism: the dam break with its obstacle, 6 frames, gives bit-identical particles (positions,
   velocities, affine vectors, order) with 1 and 2 threads, for both pressure formulations (liquid.h: fixed-
   order reductions, coloured P2G, parallel assembly by rows, the sort by cell). */
static DrHash dam_break_hash(DrPressureFormulation pressure, int threads)
{
    dr_set_threads(threads);
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.pressure = pressure;
    d.domain_hi = dr_v3(1.0, 0.5, 0.25);
    d.dx = 1.0 / 32.0;
    DrBoxVel water = {dr_v3(0, 0, 0), dr_v3(0.3, 0.35, 0.25), dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    DrCollider *obst = make_box(dr_v3(0.55, 0.0, 0.05), dr_v3(0.65, 0.12, 0.2), 0.01, 0, NULL, false, 0.3);
    const DrCollider *cols[1] = {obst};
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, cols, 1, &liq, &err), DR_OK);
    for (int f = 0; f < 6; f++) {
        DrLiquidStats st;
        assert_int_equal(dr_liquid_advance(liq, cols, 1, f / 24.0, (f + 1) / 24.0, &st, &err), DR_OK);
    }
    const DrLiquidState *s = dr_liquid_state(liq);
    DrHasher h;
    dr_hasher_init(&h);
    dr_hasher_update(&h, &s->n, sizeof s->n);
    dr_hasher_update(&h, s->x, 3 * sizeof(double) * (size_t)s->n);
    dr_hasher_update(&h, s->v, 3 * sizeof(double) * (size_t)s->n);
    dr_hasher_update(&h, s->c, 9 * sizeof(double) * (size_t)s->n);
    DrHash out = dr_hasher_final(&h);
    dr_liquid_destroy(&liq);
    dr_collider_destroy(&obst);
    dr_set_threads(0);
    return out;
}

static void test_thread_count_independence(void **state)
{
    (void)state;
    for (int q = 0; q < 2; q++) {
        DrPressureFormulation pressure = q ? DR_PRESSURE_MASS_WEIGHTED : DR_PRESSURE_GHOST_FLUID;
        DrHash h1 = dam_break_hash(pressure, 1), h2 = dam_break_hash(pressure, 2);
        assert_true(h1.hi == h2.hi && h1.lo == h2.lo);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_hydrostatic_tank),
        cmocka_unit_test(test_hydrostatic_tank_mass_weighted),
        cmocka_unit_test(test_dam_break_conservation),
        cmocka_unit_test(test_dam_break_conservation_mass_weighted),
        cmocka_unit_test(test_rotating_blob_mass_weighted_apic),
        cmocka_unit_test(test_rotating_blob_mass_weighted_pic),
        cmocka_unit_test(test_rotating_blob_ghost_fluid),
        cmocka_unit_test(test_static_collider),
        cmocka_unit_test(test_moving_paddle),          cmocka_unit_test(test_emitter_and_kill),
        cmocka_unit_test(test_thread_count_independence),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
