/* Cloth in a fluid through the coupled loop (src/couple's face elements, a DrCloth as the solid): a sheet held across a
 * channel of water with a uniform inflow loses a pressure drop equal to the drag on it over the channel's area (within
 * 2 %), the force on the sheet minus the force on the water to round-off; a sheet falling flat through still liquid
 * (one-way, linear drag) follows v_{n+1} = (v_n − g h)/(1 + h/τ) to round-off and reaches the linear-drag terminal
 * velocity −g τ, τ = m D²/(μ V C_⊥) = ρ h²/(μ ξ_⊥) for every vertex of a fabric of density ρ and thickness h. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "cloth/cloth.h"
#include "core/core.h"
#include "couple/couple.h"
#include "liquid/liquid.h"
#include "cloth_grid.h"
#include "couple_fluids.h"

static void check(DrStatus s, const DrError *e)
{
    if (s < 0) fail_msg("status %d: %s", (int)s, e->message);
}
static void near_or_fail(double a, double b, double tol, const char *file, int line)
{
    if (fabs(a - b) <= tol) return;
    print_error("%.17g != %.17g (|diff| %.3g > tol %.3g)\n", a, b, fabs(a - b), tol);
    _fail(file, line);
}
#define assert_near(a, b, tol) near_or_fail((a), (b), (tol), __FILE__, __LINE__)

/* ---- a panel as the loop's solid: one face element per vertex (area a third of its triangles', its normal) ---- */

typedef struct Sheet {
    DrCloth *c;
    int n;
    double thickness;
    double *x, *v, *mass, *volume, *diameter, *slender, *normal;
    unsigned char *held, *face;
} Sheet;

static void sheet_make(Sheet *s, const DrTriMesh *m, DrCloth *c, double thickness)
{
    memset(s, 0, sizeof *s);
    s->c = c;
    s->n = m->nv;
    s->thickness = thickness;
    size_t n = (size_t)m->nv;
    s->x = calloc(3 * n, sizeof(double)), s->v = calloc(3 * n, sizeof(double)), s->normal = calloc(3 * n, sizeof(double));
    s->mass = calloc(n, sizeof(double)), s->volume = calloc(n, sizeof(double)), s->diameter = calloc(n, sizeof(double));
    s->slender = calloc(n, sizeof(double)), s->held = calloc(n, 1), s->face = calloc(n, 1);
    for (int t = 0; t < m->nt; t++) {
        const int *tv = m->tri + 3 * t;
        DrVec3 p[3];
        for (int k = 0; k < 3; k++) p[k] = dr_v3(m->v[3 * tv[k]], m->v[3 * tv[k] + 1], m->v[3 * tv[k] + 2]);
        double a = 0.5 * dr_v3_norm(dr_v3_cross(dr_v3_sub(p[1], p[0]), dr_v3_sub(p[2], p[0])));
        for (int k = 0; k < 3; k++) s->volume[tv[k]] += a / 3.0 * thickness;
    }
    for (int v = 0; v < s->n; v++) {
        s->mass[v] = dr_cloth_masses(c)[v];
        s->diameter[v] = thickness;
        s->slender[v] = 2.0;
        s->face[v] = 1;
    }
}

static void sheet_free(Sheet *s)
{
    free(s->x), free(s->v), free(s->normal), free(s->mass), free(s->volume), free(s->diameter), free(s->slender);
    free(s->held), free(s->face);
}

static DrCoupleSamples sheet_samples(void *ctx)
{
    Sheet *s = ctx;
    return (DrCoupleSamples){s->n, s->x, s->v, s->mass, s->volume, s->diameter, s->slender, s->normal, s->held, NULL,
                             NULL, NULL, s->face};
}

static DrStatus sheet_solve(void *ctx, const double *force, const double *dfdv, DrError *err)
{
    Sheet *s = ctx;
    DrStatus st = dr_cloth_solve(s->c, force, dfdv, err);
    memcpy(s->v, dr_cloth_solved_velocities(s->c), 3 * (size_t)s->n * sizeof(double));
    return st == DR_WARN_NOT_CONVERGED ? DR_OK : st;
}

static void sheet_predict(Sheet *s, double h)
{
    DrError err;
    check(dr_cloth_predict(s->c, h, NULL, 0, &err), &err);
    memcpy(s->x, dr_cloth_positions(s->c), 3 * (size_t)s->n * sizeof(double));
    memcpy(s->v, dr_cloth_solved_velocities(s->c), 3 * (size_t)s->n * sizeof(double));
    dr_cloth_normals(s->c, s->normal);
    DrClothSamples sm;
    dr_cloth_samples(s->c, &sm);
    for (int v = 0; v < s->n; v++) s->held[v] = sm.pinned[v];
}

/* ---- a sheet across a channel (acceptance 3) ---------------------------------------------------------------------- */

/* A square sheet of 17 × 17 vertices filling the 0.16 m section of a channel of water (to 0.5 mm of its walls) (the air solver as a
   single-phase fluid of water's density and viscosity: inflow U = 5 cm/s on −x, open on +x), every vertex pinned (held:
   its reaction goes to the pin), fabric ξ_⊥ = 200 of thickness 1 mm, linear drag: in steady state the pressure drop
   across it times the channel's area equals the total drag within 2 % (measured 0.06 %), the drag equals
   (μ A/h) ξ_⊥ U/(1 − φ) within 2 % (φ the share of the faces the sheet blocks), and what the sheet received is minus
   what the water was given to round-off at every step. */
static void test_sheet_across_channel(void **state)
{
    (void)state;
    DrError err;
    DrAirDesc d;
    dr_air_desc_default(&d);
    d.domain_lo = dr_v3(0, 0, 0);
    d.domain_hi = dr_v3(0.32, 0.16, 0.16);
    d.dx = 0.01;
    d.density = 1000.0;
    d.viscosity = 1e-3;
    d.inflow_axis = 0;
    d.inflow_side = 0;
    d.inflow_velocity = dr_v3(0.05, 0, 0);
    d.initial_stream = true;
    d.pressure_tol = 1e-12;
    DrAir *air = NULL;
    check(dr_air_create(&d, &air, &err), &err);
    /* the sheet in the plane x = 0.155, spanning y and z to half a millimetre from the walls (a vertex on a wall
       samples no coupled face of the wall-normal component, and the loop leaves it out): the grid's panel lies in
       xz, so it is turned about z */
    const double inset = 5e-4, span = 0.16 - 2 * inset;
    DrTriMesh m;
    assert_int_equal(cloth_grid(17, 17, span, span, 0.0, &m), 0);
    for (int v = 0; v < m.nv; v++) {
        double x = m.v[3 * v], z = m.v[3 * v + 2];
        m.v[3 * v] = 0.155, m.v[3 * v + 1] = inset + x, m.v[3 * v + 2] = inset + z;
    }
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    mat.thickness = 1e-3;
    DrClothDesc cd0;
    dr_cloth_desc_default(&cd0);
    cd0.gravity = dr_v3(0, 0, 0);
    DrCloth *c = NULL;
    check(dr_cloth_create(&cd0, &m, &mat, "sheet", &c, &err), &err);
    for (int v = 0; v < m.nv; v++) check(dr_cloth_pin(c, v, true, NULL, &err), &err);
    Sheet s;
    sheet_make(&s, &m, c, mat.thickness);
    DrDragLaw law;
    dr_drag_law_default(&law);
    law.normal = 200, law.tangent = 5, law.nonlinear = 0.0, law.buoyancy = false;
    DrCoupleFluid fluid = {air, d.density, d.viscosity, dr_air_grid(air), air_project_cb, air_pressure_cb, air_faces_cb,
                           air_mass_cb};
    DrCoupleSolid solid = {&s, 1, &law, sheet_samples, sheet_solve, NULL, NULL};
    DrCouple *cp = NULL;
    check(dr_couple_create(&cp, &err), &err);
    DrCoupleDesc desc;
    dr_couple_desc_default(&desc);
    double t = 0.0, h = 0.0;
    DrVec3 gs = dr_v3(0, 0, 0), gf = dr_v3(0, 0, 0);
    double worst = 0.0;
    long active = 0;
    for (int step = 0; step < 20; step++) {
        check(dr_air_stable_dt(air, NULL, 0, t, t + 0.02, &h, &err), &err);
        check(dr_air_begin(air, NULL, 0, t, h, &err), &err);
        sheet_predict(&s, h);
        DrCoupleStats st = {0};
        check(dr_couple_step(cp, &desc, &fluid, &solid, 1, h, &st, &err), &err);
        check(dr_cloth_commit(c, NULL, &err), &err);
        active = st.elements;
        dr_couple_last_ledger(cp, &gs, &gf);
        worst = fmax(worst, dr_v3_norm(dr_v3_add(gs, gf)) / dr_v3_norm(gs));
        if (step < 19) {
            DrAirStats ast;
            memset(&ast, 0, sizeof ast);
            check(dr_air_end(air, &ast, &err), &err);
            t += h;
        }
    }
    double dp = 0.0;
    for (int j = 0; j < 16; j++)
        for (int k = 0; k < 16; k++) {
            double pts[6] = {0.075, 0.005 + 0.01 * j, 0.005 + 0.01 * k, 0.245, 0.005 + 0.01 * j, 0.005 + 0.01 * k};
            double p[2];
            dr_air_sample(air, 2, pts, NULL, p);
            dp += (p[0] - p[1]) / 256.0;
        }
    double area = 0.16 * 0.16, drag = gs.x / h;
    /* the law's drag at the speed of the water through the sheet's faces: the sheet midway between two x-faces blocks
       φ = h/(2Δx) of each (its volume spread by the trilinear weights), so the water crosses them at U/(1 − φ) */
    double phi = mat.thickness / (2.0 * d.dx);
    double analytic = d.viscosity * span * span / mat.thickness * law.normal * 0.05 / (1.0 - phi);
    print_message("sheet across a channel: dp %.6g Pa, dp*A %.6g N, drag %.6g N (analytic (mu A/h) xi U/(1 - phi): %.6g N), "
                  "ratio %.5f; ledger |sheet + water| / |sheet| at most %.2e\n",
                  dp, dp * area, drag, analytic, dp * area / drag, worst);
    print_message("elements in the fluid: %ld of %d\n", active, m.nv);
    assert_int_equal(active, m.nv);
    assert_true(drag > 0.0);
    assert_true(fabs(dp * area / drag - 1.0) < 0.02);
    assert_true(fabs(drag / analytic - 1.0) < 0.02);
    assert_true(worst <= 1e-13);
    DrAirStats ast;
    memset(&ast, 0, sizeof ast);
    check(dr_air_end(air, &ast, &err), &err);
    dr_couple_destroy(&cp);
    dr_air_destroy(&air);
    sheet_free(&s);
    dr_cloth_destroy(&c);
    dr_trimesh_free(&m);
}

/* ---- a sheet falling through still liquid (acceptance 3) ------------------------------------------------------------- */

static void test_falling_sheet_terminal_velocity(void **state)
{
    (void)state;
    DrError err;
    Still fl;
    check(still_make(&fl, &err), &err);
    const double rho_f = 1000.0, mu = 1e-3;
    DrTriMesh m;
    assert_int_equal(cloth_grid(9, 9, 0.2, 0.2, 0.0, &m), 0);
    for (int v = 0; v < m.nv; v++) m.v[3 * v] -= 0.1, m.v[3 * v + 2] -= 0.1;
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    mat.density = 400, mat.thickness = 1e-3;
    DrClothDesc cd0;
    dr_cloth_desc_default(&cd0);
    cd0.solver.tol = 1e-13;
    DrCloth *c = NULL;
    check(dr_cloth_create(&cd0, &m, &mat, "sheet", &c, &err), &err);
    Sheet s;
    sheet_make(&s, &m, c, mat.thickness);
    DrDragLaw law;
    dr_drag_law_default(&law);
    law.normal = 50, law.tangent = 5, law.nonlinear = 0.0, law.buoyancy = false;
    DrCoupleFluid fluid = {&fl, rho_f, mu, fl.g, still_project, still_pressure, still_faces, NULL};
    DrCoupleSolid solid = {&s, 1, &law, sheet_samples, sheet_solve, NULL, NULL};
    DrCouple *cp = NULL;
    check(dr_couple_create(&cp, &err), &err);
    DrCoupleDesc desc;
    dr_couple_desc_default(&desc);
    desc.iterations = 1;
    desc.position_derivative = false;
    double tau = mat.density * mat.thickness * mat.thickness / (mu * law.normal), h = 2e-3, v = 0.0, worst = 0.0;
    for (int n = 0; n < 100; n++) {
        sheet_predict(&s, h);
        DrCoupleStats st = {0};
        check(dr_couple_step(cp, &desc, &fluid, &solid, 1, h, &st, &err), &err);
        check(dr_cloth_commit(c, NULL, &err), &err);
        v = (v - 9.81 * h) / (1.0 + h / tau);
        const double *w = dr_cloth_velocities(c);
        for (int i = 0; i < m.nv; i++) {
            worst = fmax(worst, fabs(w[3 * i + 1] - v));
            worst = fmax(worst, fabs(w[3 * i]) + fabs(w[3 * i + 2]));
        }
    }
    print_message("falling sheet: tau %.4g s, velocity after 100 steps of 2 ms %.9g m/s (terminal -g tau %.9g m/s), "
                  "largest departure from the discrete sequence %.2e m/s\n",
                  tau, dr_cloth_velocities(c)[3 * 40 + 1], -9.81 * tau, worst);
    assert_true(worst <= 1e-10 * 9.81 * tau);
    assert_near(v, -9.81 * tau, 1e-6 * 9.81 * tau);
    dr_couple_destroy(&cp);
    sheet_free(&s);
    dr_cloth_destroy(&c);
    dr_trimesh_free(&m);
    still_free(&fl);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sheet_across_channel),
        cmocka_unit_test(test_falling_sheet_terminal_velocity),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
