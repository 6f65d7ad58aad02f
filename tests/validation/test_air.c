/* Validation of the air (liquid.h, "air"): a uniform stream stays uniform bit for bit; flow around a box collider
 * keeps out of it and conserves volume; the face coupling's impulses and implicit drag masses act as documented and
 * balance the momentum ledger; a projection repeats bit for bit, the phases give dr_air_advance's bits, 1 and 2
 * threads agree, a restore continues bit-identically; the advection's dissipation of a shear flow is measured and
 * converges at first order; a strong wind past a collider stays finite and bounded. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "liquid/liquid.h"

/* Exact signed distance of an axis-aligned box (negative inside). */
static double box_sdf(DrVec3 p, DrVec3 lo, DrVec3 hi)
{
    double outside = 0.0, inside = -INFINITY;
    for (int d = 0; d < 3; d++) {
        double c = 0.5 * (dr_v3_get(lo, d) + dr_v3_get(hi, d)), h = 0.5 * (dr_v3_get(hi, d) - dr_v3_get(lo, d));
        double q = fabs(dr_v3_get(p, d) - c) - h;
        if (q > 0) outside += q * q;
        if (q > inside) inside = q;
    }
    return outside > 0 ? sqrt(outside) : inside;
}

static DrCollider *make_box(DrVec3 lo, DrVec3 hi, double h)
{
    DrVec3 o = dr_v3_sub(lo, dr_v3(3 * h, 3 * h, 3 * h));
    int n[3];
    for (int d = 0; d < 3; d++) n[d] = (int)ceil((dr_v3_get(hi, d) - dr_v3_get(lo, d)) / h) + 7;
    float *phi = malloc(sizeof(float) * (size_t)n[0] * n[1] * n[2]);
    for (int k = 0; k < n[2]; k++)
        for (int j = 0; j < n[1]; j++)
            for (int i = 0; i < n[0]; i++)
                phi[i + n[0] * (j + n[1] * k)] = (float)box_sdf(dr_v3_add(o, dr_v3(i * h, j * h, k * h)), lo, hi);
    DrColliderDesc cd = {phi, n[0], n[1], n[2], o, h, 0.0, false, 0.0, 0, NULL};
    DrCollider *c = NULL;
    DrError err;
    assert_int_equal(dr_collider_create(&cd, &c, &err), DR_OK);
    free(phi);
    return c;
}

static void copy_grid(const DrMacGrid *g, double *out[3])
{
    for (int a = 0; a < 3; a++) {
        out[a] = malloc((size_t)g->nfaces[a] * sizeof(double));
        memcpy(out[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
    }
}
static void free_grid(double *f[3])
{
    for (int a = 0; a < 3; a++) free(f[a]);
}
static void assert_same_grid(const DrMacGrid *g, double *const f[3])
{
    for (int a = 0; a < 3; a++) assert_memory_equal(g->f[a], f[a], (size_t)g->nfaces[a] * sizeof(double));
}

/* A channel 1 × 0.5 × 0.5 m with the wind along +x through the −x face. */
static void channel_desc(DrAirDesc *d, double dx, double wind)
{
    dr_air_desc_default(d);
    d->domain_hi = dr_v3(1.0, 0.5, 0.5);
    d->dx = dx;
    d->inflow_axis = 0;
    d->inflow_side = 0;
    d->inflow_velocity = dr_v3(wind, 0, 0);
}

static DrVec3 momentum_of(const DrAir *air)
{
    DrVec3 p;
    dr_air_totals(air, NULL, &p, NULL);
    return p;
}

/* ---- a uniform stream ------------------------------------------------------------------------------------ */

/* The stream the wind blows, everywhere from the start, through an empty box: every advection sample, viscosity
   update and the pressure's right-hand side see a constant field, which the a + f(b − a) sampling reproduces
   exactly; the projection's right-hand side is exactly 0 and PCG returns q = 0. Checked for the wind through the −x
   face and through the +y face (a negative normal component), with viscosity on. */
static void test_uniform_stream(void **state)
{
    (void)state;
    for (int cfg = 0; cfg < 2; cfg++) {
        DrAirDesc d;
        channel_desc(&d, 1.0 / 16.0, 2.5);
        if (cfg == 1) {
            d.domain_hi = dr_v3(0.5, 1.0, 0.5);
            d.inflow_axis = 1;
            d.inflow_side = 1;
            d.inflow_velocity = dr_v3(0, -1.75, 0);
            d.viscosity = 0.05; /* ν h/Δx² above 1/6: the subcycled explicit update sees a constant field too */
        }
        d.initial_stream = true;
        DrAir *air = NULL;
        DrError err;
        assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
        DrAirStats st;
        assert_int_equal(dr_air_advance(air, NULL, 0, 0.0, 0.3, &st, &err), DR_OK);
        assert_true(st.substeps >= 9);
        const DrMacGrid *g = dr_air_grid(air);
        int ax = d.inflow_axis;
        double U = dr_v3_get(d.inflow_velocity, ax);
        for (int a = 0; a < 3; a++)
            for (long f = 0; f < g->nfaces[a]; f++) assert_true(fabs(g->f[a][f] - (a == ax ? U : 0.0)) <= 1e-10);
        assert_true(st.divergence_max <= 1e-10);
        double area = (ax == 0 ? 0.5 * 0.5 : 0.5 * 0.5);
        assert_true(fabs(st.inflow_flux - fabs(U) * area) <= 1e-12);
        assert_true(fabs(st.outflow_flux - fabs(U) * area) <= 1e-12);
        if (cfg == 1) assert_true(st.viscosity_subcycles > 1);
        double x[6] = {0.2, 0.3, 0.1, 0.45, 0.95, 0.4}, v[6], p[2];
        DrAirStats s2;
        memset(&s2, 0, sizeof s2);
        double h;
        assert_int_equal(dr_air_stable_dt(air, NULL, 0, 0.3, 0.4, &h, &err), DR_OK);
        assert_int_equal(dr_air_begin(air, NULL, 0, 0.3, h, &err), DR_OK);
        assert_int_equal(dr_air_project(air, NULL, &s2, &err), DR_OK);
        dr_air_sample(air, 2, x, v, p);
        for (int i = 0; i < 2; i++) {
            for (int a = 0; a < 3; a++) assert_true(fabs(v[3 * i + a] - (a == ax ? U : 0.0)) <= 1e-12);
            assert_true(p[i] == 0.0);
        }
        assert_int_equal(dr_air_end(air, &s2, &err), DR_OK);
        dr_air_destroy(&air);
    }
}

/* The wind ramps linearly: the inflow flux after a substep ending at t is U·min(1, t/ramp)·area. */
static void test_ramp(void **state)
{
    (void)state;
    DrAirDesc d;
    channel_desc(&d, 1.0 / 16.0, 3.0);
    d.ramp = 0.5;
    DrAir *air = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    DrAirStats st;
    double times[3] = {0.1, 0.25, 0.8};
    double t = 0.0;
    for (int i = 0; i < 3; i++) {
        assert_int_equal(dr_air_advance(air, NULL, 0, t, times[i], &st, &err), DR_OK);
        t = times[i];
        double expect = 3.0 * fmin(1.0, t / 0.5) * 0.25;
        assert_true(fabs(st.inflow_flux - expect) <= 1e-12 * expect);
        /* incompressible: what comes in leaves, to the solver's tolerance (1e-6 of the right-hand side) */
        assert_true(fabs(st.outflow_flux - expect) <= 1e-5 * expect);
    }
    dr_air_destroy(&air);
}

/* ---- flow around a box collider ------------------------------------------------------------------------- */

/* A static box in the channel's middle: faces whose four corners lie inside the box (more than round-off) are
   closed at its velocity, 0; the divergence after the projection is at the solver's tolerance; the volume flux in
   equals the flux out. Tolerance 1e-10: PCG stops at ‖r‖ ≤ 1e-10 ‖b‖, so the divergence (the residual per cell,
   /Δx²) is far below 1e-6 U/Δx. */
static void test_box_collider(void **state)
{
    (void)state;
    DrAirDesc d;
    double dx = 1.0 / 20.0;
    channel_desc(&d, dx, 2.0);
    d.initial_stream = true;
    d.pressure_tol = 1e-10;
    DrVec3 lo = dr_v3(0.4, 0.15, 0.15), hi = dr_v3(0.6, 0.35, 0.35);
    DrCollider *box = make_box(lo, hi, dx * 0.5);
    const DrCollider *cols[1] = {box};
    DrAir *air = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    DrAirStats st;
    assert_int_equal(dr_air_advance(air, cols, 1, 0.0, 0.25, &st, &err), DR_OK);
    assert_int_equal(st.pressure_not_converged, 0);
    const DrMacGrid *g = dr_air_grid(air);
    int blocked = 0;
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < g->fdim[a][2]; k++)
            for (int j = 0; j < g->fdim[a][1]; j++)
                for (int i = 0; i < g->fdim[a][0]; i++) {
                    DrVec3 x = dr_mac_face_position(g, a, i, j, k);
                    /* all four corners of the face inside: half a cell within the box on the two other axes */
                    bool inside = true;
                    for (int e = 0; e < 3; e++) {
                        double margin = e == a ? 1e-9 : 0.5 * dx + 1e-9;
                        inside = inside && dr_v3_get(x, e) > dr_v3_get(lo, e) + margin &&
                                 dr_v3_get(x, e) < dr_v3_get(hi, e) - margin;
                    }
                    if (!inside) continue;
                    blocked++;
                    assert_true(g->f[a][dr_mac_face_index(g, a, i, j, k)] == 0.0);
                }
    assert_int_equal(blocked, 36); /* 3 × 2 × 2 faces of each component */
    assert_true(st.divergence_max * dx / 2.0 <= 1e-6);
    assert_true(fabs(st.inflow_flux - 0.5) <= 1e-14);
    assert_true(fabs(st.outflow_flux - st.inflow_flux) <= 1e-8 * st.inflow_flux);
    /* the flow goes around: faster beside the box than the wind */
    double x[3] = {0.5, 0.07, 0.25}, v[3];
    dr_air_sample(air, 1, x, v, NULL);
    assert_true(v[0] > 2.0);
    dr_air_destroy(&air);
    dr_collider_destroy(&box);
}

/* ---- the face coupling --------------------------------------------------------------------------------- */

/* A Taylor–Green cell field in the x–y plane of the unit box: u = sin(πx) cos(πy), v = −cos(πx) sin(πy), w = 0;
   its discrete MAC divergence vanishes up to round-off (both differences equal 2 sin(πΔx/2) cos(πx_c) cos(πy_c)),
   and it is 0 on the walls. */
static void taylor_green(const DrMacGrid *g, double amp, double *f[3])
{
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < g->fdim[a][2]; k++)
            for (int j = 0; j < g->fdim[a][1]; j++)
                for (int i = 0; i < g->fdim[a][0]; i++) {
                    DrVec3 x = dr_mac_face_position(g, a, i, j, k);
                    double val = 0.0;
                    if (a == 0) val = sin(DR_PI * x.x) * cos(DR_PI * x.y);
                    if (a == 1) val = -cos(DR_PI * x.x) * sin(DR_PI * x.y);
                    f[a][dr_mac_face_index(g, a, i, j, k)] = amp * val;
                }
}

static DrFaceCoupling *open_coupling(const DrAir *air)
{
    DrFaceCoupling *fc = NULL;
    DrError err;
    assert_int_equal(dr_face_coupling_create(dr_air_grid(air), &fc, &err), DR_OK);
    return fc;
}

/* Closed box at rest, a uniform drag mass β on every face pulling towards a divergence-free V (the Taylor–Green
   field): the pressure has nothing to do, and every face takes u = (m·0 + β V)/(m + β) (to round-off of the
   divergence, 1e-13 of |V|); the drag's momentum Σ β(V − u) plus the pressure's equals the air's momentum change
   to round-off. */
static void test_drag_divergence_free(void **state)
{
    (void)state;
    DrAirDesc d;
    dr_air_desc_default(&d);
    d.dx = 1.0 / 16.0;
    d.pressure_tol = 1e-12;
    DrAir *air = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    DrFaceCoupling *fc = open_coupling(air);
    const DrMacGrid *g = dr_air_grid(air);
    taylor_green(g, 1.5, fc->velocity);
    double beta = 0.7 * dr_air_face_mass(air, 0)[dr_mac_face_index(g, 0, 3, 3, 3)];
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) fc->drag[a][f] = beta;
    DrVec3 p0 = momentum_of(air);
    double h;
    DrAirStats st;
    memset(&st, 0, sizeof st);
    assert_int_equal(dr_air_stable_dt(air, NULL, 0, 0.0, 0.01, &h, &err), DR_OK);
    assert_true(h == 0.01);
    assert_int_equal(dr_air_begin(air, NULL, 0, 0.0, h, &err), DR_OK);
    assert_int_equal(dr_air_project(air, fc, &st, &err), DR_OK);
    for (int a = 0; a < 3; a++) {
        const double *m = dr_air_face_mass(air, a);
        for (long f = 0; f < g->nfaces[a]; f++) {
            if (m[f] == 0.0) {
                assert_true(g->f[a][f] == 0.0);
                continue;
            }
            double expect = beta * fc->velocity[a][f] / (m[f] + beta);
            assert_true(fabs(g->f[a][f] - expect) <= 1e-13 * 1.5);
        }
    }
    assert_int_equal(dr_air_end(air, &st, &err), DR_OK);
    DrVec3 dp = dr_v3_sub(momentum_of(air), p0);
    DrVec3 ledger = dr_v3_add(dr_v3_add(st.added_impulse, st.drag_impulse), st.pressure_impulse);
    double scale = beta * 1.5 * (double)g->nfaces[0];
    assert_true(dr_v3_norm(dr_v3_sub(dp, ledger)) <= 1e-14 * scale);
    assert_true(dr_v3_norm(st.added_impulse) == 0.0);
    dr_face_coupling_destroy(&fc);
    dr_air_destroy(&air);
}

/* A uniform stream U through the channel with a uniform drag mass β on every face pulling towards V ≠ U along x. The
   inflow fixes the volume flux, so the projection keeps u = U and the drag is held by a uniform pressure gradient:
   per face β(V − U) = m Δq/Δx, i.e. dp/dx = ρβ(V − U)/(m h), with p = 0 on the outflow face. Checked: u = U (1e-9),
   the sampled pressure at cell centres against the line (1e-8 relative), the drag's momentum Σ β(V − U) over the
   x-faces that are unknowns, and the ledger Δ(momentum) = drag + pressure (= 0 here) to round-off. */
static void test_drag_stream(void **state)
{
    (void)state;
    DrAirDesc d;
    double dx = 1.0 / 16.0, U = 2.0, V = 0.5;
    channel_desc(&d, dx, U);
    d.initial_stream = true;
    d.viscosity = 0.0;
    d.pressure_tol = 1e-13;
    DrAir *air = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    DrFaceCoupling *fc = open_coupling(air);
    const DrMacGrid *g = dr_air_grid(air);
    const double *m0 = dr_air_face_mass(air, 0);
    double m = m0[dr_mac_face_index(g, 0, 3, 3, 3)];
    assert_true(fabs(m - 1.2 * dx * dx * dx) <= 1e-18);
    double beta = 2.0 * m;
    long unknowns = 0;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            fc->drag[a][f] = beta;
            fc->velocity[a][f] = a == 0 ? V : 0.0;
            if (a == 0 && dr_air_face_mass(air, 0)[f] > 0.0) unknowns++;
        }
    assert_int_equal(unknowns, (long)g->nx * g->ny * g->nz); /* nx interior-or-outflow faces per row */
    DrVec3 p0 = momentum_of(air);
    double h;
    DrAirStats st;
    memset(&st, 0, sizeof st);
    assert_int_equal(dr_air_stable_dt(air, NULL, 0, 0.0, 0.01, &h, &err), DR_OK);
    assert_int_equal(dr_air_begin(air, NULL, 0, 0.0, h, &err), DR_OK);
    assert_int_equal(dr_air_project(air, fc, &st, &err), DR_OK);
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) assert_true(fabs(g->f[a][f] - (a == 0 ? U : 0.0)) <= 1e-9);
    double slope = 1.2 * beta * (V - U) / (m * h); /* dp/dx, Pa/m */
    for (int i = 0; i < g->nx; i += 3) {
        DrVec3 c = dr_mac_cell_center(g, i, 4, 3);
        double x[3] = {c.x, c.y, c.z}, p;
        dr_air_sample(air, 1, x, NULL, &p);
        double expect = slope * (c.x - 1.0);
        assert_true(fabs(p - expect) <= 1e-8 * fabs(slope));
    }
    assert_int_equal(dr_air_end(air, &st, &err), DR_OK);
    double drag_x = (double)unknowns * beta * (V - U);
    assert_true(fabs(st.drag_impulse.x - drag_x) <= 1e-8 * fabs(drag_x));
    assert_true(fabs(st.drag_impulse.y) <= 1e-12 * fabs(drag_x) && fabs(st.drag_impulse.z) <= 1e-12 * fabs(drag_x));
    DrVec3 dp = dr_v3_sub(momentum_of(air), p0);
    DrVec3 ledger = dr_v3_add(st.drag_impulse, st.pressure_impulse);
    assert_true(dr_v3_norm(dr_v3_sub(dp, ledger)) <= 1e-12 * fabs(drag_x));
    dr_face_coupling_destroy(&fc);
    dr_air_destroy(&air);
}

/* Closed box at rest, impulses on a scattered set of faces (walls included, where they are dropped): the reported
   added impulse is Σ J over the faces that are unknowns; the air's momentum gain equals added + pressure to
   round-off, and is itself 0 to round-off (a divergence-free field inside closed walls carries no momentum: the
   walls' pressure takes back every net impulse). */
static void test_closed_impulse_ledger(void **state)
{
    (void)state;
    DrAirDesc d;
    dr_air_desc_default(&d);
    d.dx = 1.0 / 12.0;
    d.pressure_tol = 1e-12;
    DrAir *air = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    DrFaceCoupling *fc = open_coupling(air);
    const DrMacGrid *g = dr_air_grid(air);
    double sumJ[3] = {0};
    uint64_t s = 12345;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            s = s * 6364136223846793005ULL + 1442695040888963407ULL;
            if ((s >> 60) != 3) continue;
            double J = 1e-4 * ((double)(s >> 11) / 9007199254740992.0 - 0.3);
            fc->impulse[a][f] = J;
            if (dr_air_face_mass(air, a)[f] > 0.0) sumJ[a] += J;
        }
    DrVec3 p0 = momentum_of(air);
    double h;
    DrAirStats st;
    memset(&st, 0, sizeof st);
    assert_int_equal(dr_air_stable_dt(air, NULL, 0, 0.0, 0.02, &h, &err), DR_OK);
    assert_int_equal(dr_air_begin(air, NULL, 0, 0.0, h, &err), DR_OK);
    assert_int_equal(dr_air_project(air, fc, &st, &err), DR_OK);
    assert_int_equal(dr_air_end(air, &st, &err), DR_OK);
    double scale = fabs(sumJ[0]) + fabs(sumJ[1]) + fabs(sumJ[2]);
    assert_true(scale > 1e-4);
    for (int a = 0; a < 3; a++) assert_true(fabs(dr_v3_get(st.added_impulse, a) - sumJ[a]) <= 1e-15);
    DrVec3 dp = dr_v3_sub(momentum_of(air), p0);
    DrVec3 ledger = dr_v3_add(st.added_impulse, st.pressure_impulse);
    assert_true(dr_v3_norm(dr_v3_sub(dp, ledger)) <= 1e-12 * scale);
    assert_true(dr_v3_norm(dp) <= 1e-9 * scale);
    assert_true(st.divergence_max <= 1e-8);
    dr_face_coupling_destroy(&fc);
    dr_air_destroy(&air);
}

/* ---- repeatability and determinism --------------------------------------------------------------------- */

static void wind_past_box(DrAirDesc *d, double dx)
{
    channel_desc(d, dx, 3.0);
    d->ramp = 0.1;
    d->viscosity = 0.05; /* a viscous gas, so the explicit update has work */
}

/* The phases with a projection repeated: extra A, extra B, extra A again gives the first bits; then without extra
   the substep gives dr_air_advance's bits. */
static void test_project_repeats(void **state)
{
    (void)state;
    DrAirDesc d;
    double dx = 1.0 / 16.0;
    wind_past_box(&d, dx);
    DrCollider *box = make_box(dr_v3(0.4, 0.1, 0.1), dr_v3(0.6, 0.3, 0.35), dx * 0.5);
    const DrCollider *cols[1] = {box};
    DrAir *a1 = NULL, *a2 = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &a1, &err), DR_OK);
    assert_int_equal(dr_air_create(&d, &a2, &err), DR_OK);
    DrFaceCoupling *fa = open_coupling(a1), *fb = open_coupling(a1);
    const DrMacGrid *g = dr_air_grid(a1);
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f += 7) {
            fa->open[a][f] = 0.6;
            fa->velocity[a][f] = 0.3;
            fa->impulse[a][f] = 1e-6;
            fa->drag[a][f] = 1e-5;
            fb->drag[a][f] = 3e-5;
        }
    DrAirStats s1, s2, scratch;
    memset(&s1, 0, sizeof s1);
    memset(&scratch, 0, sizeof scratch);
    double t = 0.0, t1 = 0.2;
    while (t < t1) {
        double h;
        assert_int_equal(dr_air_stable_dt(a1, cols, 1, t, t1, &h, &err), DR_OK);
        assert_int_equal(dr_air_begin(a1, cols, 1, t, h, &err), DR_OK);
        assert_int_equal(dr_air_project(a1, fa, &scratch, &err), DR_OK);
        double *first[3];
        copy_grid(g, first);
        double x[3] = {0.7, 0.2, 0.2}, p1, p2;
        dr_air_sample(a1, 1, x, NULL, &p1);
        assert_int_equal(dr_air_project(a1, fb, &scratch, &err), DR_OK);
        assert_int_equal(dr_air_project(a1, fa, &scratch, &err), DR_OK);
        assert_same_grid(g, first);
        dr_air_sample(a1, 1, x, NULL, &p2);
        assert_memory_equal(&p1, &p2, sizeof p1);
        free_grid(first);
        assert_int_equal(dr_air_project(a1, NULL, &s1, &err), DR_OK);
        assert_int_equal(dr_air_end(a1, &s1, &err), DR_OK);
        t = h == t1 - t ? t1 : t + h;
    }
    assert_int_equal(dr_air_advance(a2, cols, 1, 0.0, t1, &s2, &err), DR_OK);
    double *f2[3];
    copy_grid(dr_air_grid(a2), f2);
    assert_same_grid(g, f2);
    free_grid(f2);
    assert_int_equal(s1.substeps, s2.substeps);
    assert_int_equal(s1.pressure_iterations_total, s2.pressure_iterations_total);
    assert_memory_equal(&s1.pressure_impulse, &s2.pressure_impulse, sizeof(DrVec3));
    dr_face_coupling_destroy(&fa);
    dr_face_coupling_destroy(&fb);
    dr_air_destroy(&a1);
    dr_air_destroy(&a2);
    dr_collider_destroy(&box);
}

/* 1 and 2 threads give the same bits (grid and stats), and a restore from the state at 0.15 s continues to the bits
   of an uninterrupted run. */
static void test_threads_and_restore(void **state)
{
    (void)state;
    DrAirDesc d;
    double dx = 1.0 / 24.0;
    wind_past_box(&d, dx);
    DrCollider *box = make_box(dr_v3(0.3, 0.1, 0.15), dr_v3(0.5, 0.3, 0.3), dx * 0.5);
    const DrCollider *cols[1] = {box};
    double *res[2][3];
    DrAirStats st[2];
    DrError err;
    for (int th = 1; th <= 2; th++) {
        dr_set_threads(th);
        DrAir *air = NULL;
        assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
        assert_int_equal(dr_air_advance(air, cols, 1, 0.0, 0.15, &st[th - 1], &err), DR_OK);
        assert_int_equal(dr_air_advance(air, cols, 1, 0.15, 0.3, &st[th - 1], &err), DR_OK);
        copy_grid(dr_air_grid(air), res[th - 1]);
        dr_air_destroy(&air);
    }
    dr_set_threads(0);
    DrAir *ref = NULL;
    assert_int_equal(dr_air_create(&d, &ref, &err), DR_OK);
    for (int a = 0; a < 3; a++)
        assert_memory_equal(res[0][a], res[1][a], (size_t)dr_air_grid(ref)->nfaces[a] * sizeof(double));
    assert_int_equal(st[0].pressure_iterations_total, st[1].pressure_iterations_total);
    assert_memory_equal(&st[0].pressure_impulse, &st[1].pressure_impulse, sizeof(DrVec3));
    assert_memory_equal(&st[0].divergence_max, &st[1].divergence_max, sizeof(double));
    /* restore: a fresh air given the state at 0.15 s */
    DrAirStats s;
    assert_int_equal(dr_air_advance(ref, cols, 1, 0.0, 0.15, &s, &err), DR_OK);
    double *mid[3];
    copy_grid(dr_air_grid(ref), mid);
    DrAir *resumed = NULL;
    assert_int_equal(dr_air_create(&d, &resumed, &err), DR_OK);
    assert_int_equal(dr_air_restore(resumed, (const double *const *)mid, &err), DR_OK);
    assert_int_equal(dr_air_advance(resumed, cols, 1, 0.15, 0.3, &s, &err), DR_OK);
    assert_same_grid(dr_air_grid(resumed), res[0]);
    mid[0][5] = NAN;
    assert_int_equal(dr_air_restore(resumed, (const double *const *)mid, &err), DR_ERR_INPUT);
    free_grid(mid);
    free_grid(res[0]);
    free_grid(res[1]);
    dr_air_destroy(&ref);
    dr_air_destroy(&resumed);
    dr_collider_destroy(&box);
}

/* ---- dissipation of a shear flow ----------------------------------------------------------------------- */

/* The Taylor–Green cells (inviscid, closed box, one cell deep) are a steady solution of the Euler equations: all the
   kinetic energy they lose is the scheme's. Measured over 1 s at CFL 1: the loss must shrink at least as a
   first-order scheme's does from n = 16 to 32 cells (ratio ≤ 0.6 against the ideal 0.5), and no substep may add
   energy (semi-Lagrangian linear sampling is a convex combination, the projection removes energy). */
static double tg_loss(int n, bool print)
{
    DrAirDesc d;
    dr_air_desc_default(&d);
    d.dx = 1.0 / n;
    d.domain_hi = dr_v3(1, 1, d.dx);
    d.viscosity = 0.0;
    d.pressure_tol = 1e-10;
    DrAir *air = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    double *f[3];
    copy_grid(dr_air_grid(air), f);
    taylor_green(dr_air_grid(air), 1.0, f);
    for (int a = 0; a < 3; a++)
        for (long i = 0; i < dr_air_grid(air)->nfaces[a]; i++)
            if (dr_air_face_mass(air, a)[i] == 0.0) f[a][i] = 0.0;
    assert_int_equal(dr_air_restore(air, (const double *const *)f, &err), DR_OK);
    free_grid(f);
    double ke0, ke, prev;
    dr_air_totals(air, NULL, NULL, &ke0);
    prev = ke0;
    double t = 0.0;
    int steps = 0;
    while (t < 1.0) {
        DrAirStats st;
        double t1 = fmin(1.0, t + 0.05);
        assert_int_equal(dr_air_advance(air, NULL, 0, t, t1, &st, &err), DR_OK);
        steps += st.substeps;
        dr_air_totals(air, NULL, NULL, &ke);
        assert_true(ke <= prev * (1.0 + 1e-12));
        prev = ke;
        t = t1;
    }
    if (print) printf("# air: Taylor-Green %d^2, 1 s, %d substeps: kinetic energy kept %.4f\n", n, steps, ke / ke0);
    dr_air_destroy(&air);
    return 1.0 - ke / ke0;
}

static void test_shear_dissipation(void **state)
{
    (void)state;
    double l16 = tg_loss(16, true), l32 = tg_loss(32, true), l64 = tg_loss(64, true);
    assert_true(l16 > 0.0 && l32 > 0.0 && l64 > 0.0);
    assert_true(l32 <= 0.6 * l16);
    assert_true(l64 <= 0.6 * l32);
}

/* ---- stress: a strong wind past a collider ------------------------------------------------------------- */

/* 30 m/s past a box for 0.5 s (hundreds of substeps): finite, and the kinetic energy stays below that of the whole
   box moving at twice the wind (flow around a bluff body speeds up to about twice the stream beside it). */
static void test_strong_wind(void **state)
{
    (void)state;
    DrAirDesc d;
    double dx = 1.0 / 24.0;
    channel_desc(&d, dx, 30.0);
    d.max_substeps = 1000;
    DrCollider *box = make_box(dr_v3(0.3, 0.15, 0.1), dr_v3(0.45, 0.35, 0.4), dx * 0.5);
    const DrCollider *cols[1] = {box};
    DrAir *air = NULL;
    DrError err;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    double bound = 0.5 * 1.2 * 0.25 * 60.0 * 60.0;
    int substeps = 0;
    for (int fr = 0; fr < 10; fr++) {
        DrAirStats st;
        assert_int_equal(dr_air_advance(air, cols, 1, fr * 0.05, (fr + 1) * 0.05, &st, &err), DR_OK);
        substeps += st.substeps;
        double ke;
        DrVec3 p;
        dr_air_totals(air, NULL, &p, &ke);
        assert_true(isfinite(ke) && dr_v3_isfinite(p));
        assert_true(ke <= bound);
        assert_true(st.max_speed < 120.0);
        assert_true(fabs(st.outflow_flux - st.inflow_flux) <= 1e-4 * st.inflow_flux);
    }
    printf("# air: 30 m/s past a box, 0.5 s: %d substeps\n", substeps);
    assert_true(substeps > 300);
    dr_air_destroy(&air);
    dr_collider_destroy(&box);
}

/* ---- bad input ------------------------------------------------------------------------------------------ */

static void test_bad_desc(void **state)
{
    (void)state;
    DrAirDesc d;
    DrAir *air = NULL;
    DrError err;
    channel_desc(&d, 0.1, -1.0); /* out of the box through its inflow face */
    assert_int_equal(dr_air_create(&d, &air, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "points out of the box"));
    channel_desc(&d, 0.1, 0.0);
    d.inflow_velocity = dr_v3(0, 1, 0); /* no normal component, yet a wind */
    assert_int_equal(dr_air_create(&d, &air, &err), DR_ERR_INPUT);
    channel_desc(&d, 0.1, 1.0);
    d.density = 0.0;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_ERR_INPUT);
    channel_desc(&d, 0.1, 1.0);
    d.ramp = -1.0;
    assert_int_equal(dr_air_create(&d, &air, &err), DR_ERR_INPUT);
    assert_null(air);
    /* a coupling with a negative drag mass */
    channel_desc(&d, 0.1, 1.0);
    assert_int_equal(dr_air_create(&d, &air, &err), DR_OK);
    DrFaceCoupling *fc = open_coupling(air);
    fc->drag[1][3] = -1.0;
    double h;
    DrAirStats st;
    memset(&st, 0, sizeof st);
    assert_int_equal(dr_air_stable_dt(air, NULL, 0, 0.0, 0.1, &h, &err), DR_OK);
    assert_int_equal(dr_air_begin(air, NULL, 0, 0.0, 2 * h, &err), DR_ERR_INPUT);
    assert_int_equal(dr_air_begin(air, NULL, 0, 0.0, h, &err), DR_OK);
    assert_int_equal(dr_air_project(air, fc, &st, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "negative drag mass"));
    dr_face_coupling_destroy(&fc);
    dr_air_destroy(&air);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_uniform_stream),
        cmocka_unit_test(test_ramp),
        cmocka_unit_test(test_box_collider),
        cmocka_unit_test(test_drag_divergence_free),
        cmocka_unit_test(test_drag_stream),
        cmocka_unit_test(test_closed_impulse_ledger),
        cmocka_unit_test(test_project_repeats),
        cmocka_unit_test(test_threads_and_restore),
        cmocka_unit_test(test_shear_dissipation),
        cmocka_unit_test(test_strong_wind),
        cmocka_unit_test(test_bad_desc),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
