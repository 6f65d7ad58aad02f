/* Hair against cloth in one Lagrangian system (DESIGN §8): a rod set and a cloth panel share a DrLag, stepped by the
 * test as the system's owner, and src/contact adds the rows between hair vertices and the panel's triangles.
 *   - a panel alone in a shared system takes the bits of its own system's steps;
 *   - a sheet dropped on a patch of upright fur comes to rest on the tips, at the contact distance above them, without
 *     a vertex passing between the strands, and the fur holds its weight; pushed sideways, friction stops it;
 *   - without gravity a sheet thrown at a tuft of loose strands keeps the two's total momentum to round-off. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "cloth/cloth.h"
#include "contact/contact.h"
#include "core/core.h"
#include "hair/hair.h"
#include "lagrangian/lagrangian.h"
#include "cloth_grid.h"

static void check(DrStatus s, const DrError *e)
{
    if (s < 0) fail_msg("%s", e->message);
}

/* nx × nx upright strands of `nv` vertices and length L on a square of side `side` centred on the origin, roots at
   y = 0. */
static DrGroom patch(int nx, double side, int nv, double L)
{
    DrGroom g = {0};
    g.nstrands = nx * nx;
    g.offsets = calloc((size_t)g.nstrands + 1, sizeof(int));
    g.x = calloc(3 * (size_t)g.nstrands * (size_t)nv, sizeof(double));
    g.root_normal = calloc(3 * (size_t)g.nstrands, sizeof(double));
    for (int s = 0; s < g.nstrands; s++) {
        double x0 = -0.5 * side + side * (s % nx) / (nx - 1), z0 = -0.5 * side + side * (s / nx) / (nx - 1);
        g.offsets[s + 1] = g.offsets[s] + nv;
        for (int j = 0; j < nv; j++) {
            double *p = g.x + 3 * ((size_t)s * nv + j);
            p[0] = x0, p[1] = L * j / (nv - 1), p[2] = z0;
        }
        g.root_normal[3 * s + 1] = 1.0;
    }
    return g;
}

typedef struct Pair {
    DrLag *sys;
    DrRodSet *rods;
    DrCloth *cloth;
    DrTriField *field;
    int *cloth_dof;
    DrContactResponse response;
    int contacts, iterations;
} Pair;

static void pair_create(Pair *p, const DrGroom *g, DrRodRoots roots, const DrTriMesh *sheet, DrVec3 gravity)
{
    DrError e;
    memset(p, 0, sizeof *p);
    DrLagDesc ld;
    dr_lag_desc_default(&ld);
    ld.tol = 1e-12;
    check(dr_lag_create(&ld, &p->sys, &e), &e);
    DrRodSetDesc rd;
    dr_rod_set_desc_default(&rd);
    rd.roots = roots;
    rd.gravity = gravity;
    rd.system = p->sys;
    DrRodBatch b;
    memset(&b, 0, sizeof b);
    b.groom = g;
    dr_rod_material_default(&b.material);
    b.material.radius = 1e-4;
    b.material.youngs = 3e9;
    b.material.damping = 0.01;
    b.group = b.mask = 1;
    b.contact_stiffness = 10;
    check(dr_rod_set_create(&rd, &b, 1, &p->rods, &e), &e);
    DrClothDesc cd;
    dr_cloth_desc_default(&cd);
    cd.gravity = gravity;
    cd.system = p->sys;
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    mat.self_contact = false;
    mat.damping = 0.01;
    check(dr_cloth_create(&cd, sheet, &mat, "sheet", &p->cloth, &e), &e);
    check(dr_tri_field_create(&p->field, &e), &e);
    p->cloth_dof = calloc((size_t)sheet->nv, sizeof(int));
    for (int v = 0; v < sheet->nv; v++) p->cloth_dof[v] = dr_cloth_vertex_dof(p->cloth, v);
    p->response = (DrContactResponse){1e-3, 1e4, 0.0, 0.0};
}

static void pair_destroy(Pair *p)
{
    dr_rod_set_destroy(&p->rods);
    dr_cloth_destroy(&p->cloth);
    dr_tri_field_destroy(&p->field);
    dr_lag_destroy(&p->sys);
    free(p->cloth_dof);
}

/* One step of h as the system's owner: both models' DOFs, then passes of begin, groups (the rods', the panel's, the
   rows between them), solve and the panel's active set, then the multipliers and both commits. */
static void pair_step(Pair *p, double h)
{
    DrError e;
    check(dr_rod_set_predict_dofs(p->rods, h, NULL, &e), &e);
    check(dr_cloth_predict_dofs(p->cloth, h, NULL, 0, &e), &e);
    int V = dr_cloth_vertex_count(p->cloth);
    check(dr_tri_field_build(p->field, dr_cloth_triangle_count(p->cloth), dr_cloth_triangles(p->cloth),
                             dr_cloth_positions(p->cloth), dr_cloth_velocities(p->cloth), 0.02, &e), &e);
    DrLagDofs d;
    check(dr_lag_dofs(p->sys, &d, &e), &e);
    DrRodState rs = dr_rod_set_state(p->rods);
    const int *vdof = dr_rod_set_vertex_dofs(p->rods);
    unsigned char *held = malloc((size_t)rs.nverts);
    for (int i = 0; i < rs.nverts; i++) held[i] = d.prescribed[vdof[i]]; /* roots */
    DrContactPoints pts = {rs.nverts, rs.x, rs.v, rs.vertex_radius, vdof, held};
    DrContactSheet sh = {p->field, dr_cloth_triangles(p->cloth), dr_cloth_positions(p->cloth),
                         dr_cloth_velocities(p->cloth), p->cloth_dof};
    for (int pass = 0; pass < 8; pass++) {
        check(dr_lag_begin(p->sys, h, d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, &e), &e);
        check(dr_rod_set_predict_groups(p->rods, NULL, 0, &e), &e);
        check(dr_cloth_predict_groups(p->cloth, &e), &e);
        check(dr_contact_points_sheet(p->sys, h, &pts, &sh, &p->response, &p->contacts, &e), &e);
        DrLagStats ls;
        check(dr_lag_solve_load(p->sys, NULL, d.qdot_out, &ls, &e), &e);
        p->iterations += ls.iterations;
        bool changed = false;
        check(dr_cloth_update_contacts(p->cloth, NULL, 0, pass, &changed, &e), &e);
        if (!changed) break;
    }
    free(held);
    (void)V;
    dr_rod_set_take(p->rods);
    dr_cloth_take(p->cloth);
    dr_lag_update_multipliers(p->sys, d.qdot_out);
    DrRodStats rst;
    memset(&rst, 0, sizeof rst);
    check(dr_rod_set_commit(p->rods, &rst, &e), &e);
    DrClothStats cst;
    check(dr_cloth_commit(p->cloth, &cst, &e), &e);
}

/* A panel alone in a shared system steps as with its own: 40 steps of a sheet falling onto a sphere collider. */
static double ball_sdf(DrVec3 x, DrVec3 *n, void *ctx)
{
    (void)ctx;
    DrVec3 c = dr_v3(0.2, -0.1, 0.2);
    DrVec3 d = dr_v3_sub(x, c);
    double l = dr_v3_norm(d);
    *n = dr_v3_scale(d, 1.0 / l);
    return l - 0.15;
}

static void test_panel_alone_in_shared_system(void **state)
{
    (void)state;
    DrError e;
    DrTriMesh m;
    assert_int_equal(cloth_grid(11, 11, 0.4, 0.4, 0.1, &m), 0);
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    DrClothCollider col = {ball_sdf, NULL, NULL, 0.3, 0};
    DrCloth *own = NULL, *shared = NULL;
    DrClothDesc cd;
    dr_cloth_desc_default(&cd);
    check(dr_cloth_create(&cd, &m, &mat, "own", &own, &e), &e);
    DrLag *sys = NULL;
    check(dr_lag_create(&cd.solver, &sys, &e), &e);
    cd.system = sys;
    check(dr_cloth_create(&cd, &m, &mat, "shared", &shared, &e), &e);
    const double h = 1.0 / 240;
    for (int k = 0; k < 40; k++) {
        DrClothStats st;
        check(dr_cloth_step(own, h, &col, 1, &st, &e), &e);
        check(dr_cloth_predict_dofs(shared, h, &col, 1, &e), &e);
        DrLagDofs d;
        check(dr_lag_dofs(sys, &d, &e), &e);
        for (int pass = 0; pass < 8; pass++) {
            check(dr_lag_begin(sys, h, d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, &e), &e);
            check(dr_cloth_predict_groups(shared, &e), &e);
            DrLagStats ls;
            check(dr_lag_solve_load(sys, NULL, d.qdot_out, &ls, &e), &e);
            if (pass + 1 == 8) break;
            bool changed = false;
            check(dr_cloth_update_contacts(shared, &col, 1, pass, &changed, &e), &e);
            if (!changed) break;
        }
        dr_cloth_take(shared);
        dr_lag_update_multipliers(sys, d.qdot_out);
        check(dr_cloth_commit(shared, &st, &e), &e);
    }
    const double *a = dr_cloth_positions(own), *b = dr_cloth_positions(shared);
    double lowest = INFINITY;
    for (int i = 0; i < 3 * m.nv; i++) {
        if (a[i] != b[i]) fail_msg("coordinate %d: own %.17g, shared %.17g", i, a[i], b[i]);
        if (i % 3 == 1) lowest = fmin(lowest, a[i]);
    }
    assert_true(lowest < 0.06); /* it reached the ball (top at 0.05) */
    dr_cloth_destroy(&own);
    dr_cloth_destroy(&shared);
    dr_lag_destroy(&sys);
    dr_trimesh_free(&m);
}

/* A sheet of 13 × 13 vertices (0.12 m, 0.2 kg/m²) dropped from 5 mm above the tips of a patch of 15 × 15 upright
   strands 2 cm long (r = 0.1 mm, E = 3 GPa) rests on them after 0.5 s. */
static void test_sheet_rests_on_fur(void **state)
{
    (void)state;
    const double L = 0.02, r = 1e-4;
    DrGroom g = patch(15, 0.16, 6, L);
    DrTriMesh m;
    assert_int_equal(cloth_grid(13, 13, 0.12, 0.12, L + 0.005, &m), 0);
    for (int v = 0; v < m.nv; v++) m.v[3 * v] -= 0.06, m.v[3 * v + 2] -= 0.06;
    Pair p;
    pair_create(&p, &g, DR_ROD_ROOTS_CLAMPED, &m, dr_v3(0, -9.81, 0));
    const double h = 1.0 / 480;
    int most = 0;
    for (int k = 0; k < 240; k++) {
        pair_step(&p, h);
        most = p.contacts > most ? p.contacts : most;
    }
    const double *x = dr_cloth_positions(p.cloth), *v = dr_cloth_velocities(p.cloth);
    const double *mass = dr_cloth_masses(p.cloth);
    double low = INFINITY, high = -INFINITY, ke = 0, weight = 0;
    for (int i = 0; i < m.nv; i++) {
        low = fmin(low, x[3 * i + 1]);
        high = fmax(high, x[3 * i + 1]);
        ke += 0.5 * mass[i] * (v[3 * i] * v[3 * i] + v[3 * i + 1] * v[3 * i + 1] + v[3 * i + 2] * v[3 * i + 2]);
        weight += 9.81 * mass[i];
    }
    DrRodState rs = dr_rod_set_state(p.rods);
    double tips = -INFINITY;
    for (int s = 0; s < rs.nstrands; s++) tips = fmax(tips, rs.x[3 * (rs.offsets[s + 1] - 1) + 1]);
    print_message("sheet rests between %.5f and %.5f m over tips up to %.5f m (contact distance %.4f m), "
                  "kinetic energy %.3g J (weight %.3g N), %d contacts at the end, %d at most, %d CG iterations\n",
                  low, high, tips, r + p.response.thickness, ke, weight, p.contacts, most, p.iterations);
    assert_true(p.contacts > 50);
    assert_true(low > tips + 0.8 * (r + p.response.thickness)); /* on the tips, not between the strands */
    assert_true(high < tips + 3 * (r + p.response.thickness)); /* held there: not floating */
    assert_true(ke < 1e-8);
    assert_true(tips > 0.98 * L); /* the fur holds the sheet's weight, barely bent */
    pair_destroy(&p);
    dr_groom_free(&g);
    dr_trimesh_free(&m);
}

/* Friction between hair and cloth: the sheet of test_sheet_rests_on_fur, resting on the tips, pushed sideways at
   0.2 m/s. With μ = 0.5 the tips stop it as Coulomb's μ g (4.9 m/s², 0.04 s); without friction it slides on. */
static double slide_speed(double mu)
{
    const double L = 0.02;
    DrGroom g = patch(15, 0.16, 6, L);
    DrTriMesh m;
    assert_int_equal(cloth_grid(9, 9, 0.06, 0.06, L + 0.0012, &m), 0);
    for (int v = 0; v < m.nv; v++) m.v[3 * v] -= 0.03, m.v[3 * v + 2] -= 0.03;
    Pair p;
    pair_create(&p, &g, DR_ROD_ROOTS_CLAMPED, &m, dr_v3(0, -9.81, 0));
    p.response.friction = mu;
    const double h = 1.0 / 480;
    for (int k = 0; k < 24; k++) pair_step(&p, h); /* settle on the tips */
    double *v = dr_cloth_velocities_mut(p.cloth);
    for (int i = 0; i < m.nv; i++) v[3 * i] += 0.2;
    for (int k = 0; k < 48; k++) pair_step(&p, h); /* 0.1 s */
    const double *mass = dr_cloth_masses(p.cloth);
    double P = 0, M = 0;
    for (int i = 0; i < m.nv; i++) P += mass[i] * v[3 * i], M += mass[i];
    pair_destroy(&p);
    dr_groom_free(&g);
    dr_trimesh_free(&m);
    return P / M;
}

static void test_friction_on_fur(void **state)
{
    (void)state;
    double with = slide_speed(0.5), without = slide_speed(0.0);
    print_message("a sheet pushed at 0.2 m/s over fur tips moves at %.4f m/s after 0.1 s with friction 0.5, %.4f m/s "
                  "without\n", with, without);
    assert_true(fabs(with) < 0.02);
    assert_true(without > 0.1);
}

/* Without gravity: a sheet moving at 0.5 m/s into a tuft of 5 × 5 loose strands; the rows between them (with friction
   and damping) are the only forces from outside either model, so the total momentum stays what it was. */
static void test_momentum_between_hair_and_cloth(void **state)
{
    (void)state;
    DrGroom g = patch(5, 0.04, 5, 0.02);
    DrTriMesh m;
    assert_int_equal(cloth_grid(9, 9, 0.08, 0.08, 0.025, &m), 0);
    for (int v = 0; v < m.nv; v++) m.v[3 * v] -= 0.04, m.v[3 * v + 2] -= 0.04;
    Pair p;
    pair_create(&p, &g, DR_ROD_ROOTS_FREE, &m, dr_v3(0, 0, 0));
    p.response.friction = 0.3; /* friction and damping act between the two as well */
    p.response.damping = 0.01;
    double *cv = dr_cloth_velocities_mut(p.cloth);
    for (int v = 0; v < m.nv; v++) cv[3 * v + 1] = -0.5;
    DrVec3 P0 = dr_v3(0, 0, 0);
    double scale = 0;
    int touched = 0;
    double worst = 0;
    for (int k = 0; k <= 60; k++) {
        DrRodState rs = dr_rod_set_state(p.rods);
        const double *x = dr_cloth_velocities(p.cloth), *mc = dr_cloth_masses(p.cloth);
        double P[3] = {0, 0, 0};
        for (int i = 0; i < rs.nverts; i++)
            for (int a = 0; a < 3; a++) P[a] += rs.mass[i] * rs.v[3 * i + a];
        for (int i = 0; i < m.nv; i++)
            for (int a = 0; a < 3; a++) P[a] += mc[i] * x[3 * i + a];
        if (k == 0) {
            P0 = dr_v3(P[0], P[1], P[2]);
            scale = dr_v3_norm(P0);
        } else {
            worst = fmax(worst, dr_v3_norm(dr_v3_sub(dr_v3(P[0], P[1], P[2]), P0)) / scale);
        }
        if (k == 60) break;
        pair_step(&p, 1.0 / 480);
        touched += p.contacts;
    }
    DrRodState rs = dr_rod_set_state(p.rods);
    double hair_vy = 0, hm = 0;
    for (int i = 0; i < rs.nverts; i++) hair_vy += rs.mass[i] * rs.v[3 * i + 1], hm += rs.mass[i];
    print_message("%d contact rows over 60 steps; the tuft moves at %.4f m/s; total momentum kept to %.2g of it (%.2g N s)\n",
                  touched, hair_vy / hm, worst, worst * scale);
    assert_true(touched > 100);
    assert_true(hair_vy / hm < -0.05); /* the sheet pushed the tuft along */
    assert_true(worst < 1e-10);        /* round-off: about 1e-16 N s a step */
    pair_destroy(&p);
    dr_groom_free(&g);
    dr_trimesh_free(&m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_panel_alone_in_shared_system),
        cmocka_unit_test(test_sheet_rests_on_fur),
        cmocka_unit_test(test_friction_on_fur),
        cmocka_unit_test(test_momentum_between_hair_and_cloth),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
