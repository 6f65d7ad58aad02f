/* Validation of wet hair's bridges (src/wet): cohesion through the Lagrangian solve against beam theory, bridge
 * hysteresis, and the film's flow across bridges. Water: σ 0.072 N/m, ρ 1000, μ 1e-3; strands r = 50 µm.
 *
 * The strands are stepped as the world steps them (src/world/world_lagrangian.c): the rod set in a shared
 * Lagrangian system, the bridges' rows added after its groups, the film's inertia as the solve's load, then the film
 * step and the cross-hair flow. */
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

static const double R = 5e-5, SIGMA = 0.072, THETA = 40.0 * DR_PI / 180.0;

/* ---- a small wet world: strands, film, bridges, one system ------------------------------------------------------ */

typedef struct Wet {
    DrGroom groom;
    DrLag *sys;
    DrRodSet *rods;
    DrFilm *film;
    DrCohesionTable *tables[2];
    DrBridges *bridges;
    double *radius, *force, *dfdv, *block, *x_old, *dV;
    int *block_dof;
    unsigned char *held;
    double *submerged; /* NULL, or per vertex: under the bulk liquid's surface (cohesion scaled by 1 − it) */
} Wet;

/* Two straight strands along x, L long with n edges, their axes `gap` apart along z, at height y = 0. */
static DrGroom two_strands(double L, int n, double gap)
{
    DrGroom g = {0};
    g.nstrands = 2;
    g.offsets = calloc(3, sizeof(int));
    g.x = calloc(2 * (size_t)(n + 1) * 3, sizeof(double));
    g.root_normal = calloc(6, sizeof(double));
    for (int s = 0; s < 2; s++) {
        g.offsets[s] = s * (n + 1);
        for (int j = 0; j <= n; j++) {
            double *p = g.x + 3 * (g.offsets[s] + j);
            p[0] = L * j / n;
            p[1] = 0;
            p[2] = s * gap;
        }
        g.root_normal[3 * s + 1] = 1; /* any direction off the axis */
    }
    g.offsets[2] = 2 * (n + 1);
    return g;
}

static void wet_make(Wet *w, DrGroom g, DrRodRoots roots, DrRodRoots tips, DrVec3 gravity, double ratio,
                     const DrBridgeDesc *bd)
{
    memset(w, 0, sizeof *w);
    w->groom = g;
    DrRodMaterial m;
    dr_rod_material_default(&m);
    m.radius = R;
    DrLagDesc ld;
    dr_lag_desc_default(&ld);
    ld.tol = 1e-12;
    CHECK(dr_lag_create(&ld, &w->sys, ERR));
    DrRodSetDesc d;
    dr_rod_set_desc_default(&d);
    d.roots = roots;
    d.tips = tips;
    d.gravity = gravity;
    d.solver = ld;
    d.system = w->sys;
    DrRodBatch b = {&w->groom, m, 1, 1, true, 10, 0, 0, 0, 0, 0};
    CHECK(dr_rod_set_create(&d, &b, 1, &w->rods, ERR));
    DrRodState rs = dr_rod_set_state(w->rods);
    int V = rs.nverts;
    w->radius = calloc((size_t)V, sizeof(double));
    for (int i = 0; i < V; i++) w->radius[i] = R;
    DrFilmDesc fd;
    dr_film_desc_default(&fd);
    fd.gravity = gravity;
    double ratios[2] = {ratio, ratio};
    CHECK(dr_film_create(&fd, rs.nstrands, rs.offsets, w->radius, rs.x, ratios, &w->film, ERR));
    for (int k = 0; k < 2; k++) {
        DrCohesionDesc cd;
        dr_cohesion_desc_default(&cd);
        cd.shape = k ? DR_COHESION_PLANE : DR_COHESION_CYLINDERS;
        cd.contact_angle = THETA;
        CHECK(dr_cohesion_build(&cd, &w->tables[k], ERR));
    }
    CHECK(dr_bridges_create(bd, w->tables[0], w->tables[1], &w->bridges, ERR));
    w->force = calloc(3 * (size_t)V, sizeof(double));
    w->dfdv = calloc(9 * (size_t)V, sizeof(double));
    w->block = calloc(9 * (size_t)V, sizeof(double));
    w->block_dof = calloc((size_t)V, sizeof(int));
    w->x_old = calloc(3 * (size_t)V, sizeof(double));
    w->dV = calloc((size_t)V, sizeof(double));
    w->held = calloc((size_t)V, 1);
}

static void wet_free(Wet *w)
{
    dr_bridges_destroy(&w->bridges);
    for (int k = 0; k < 2; k++) dr_cohesion_destroy(&w->tables[k]);
    dr_film_destroy(&w->film);
    dr_rod_set_destroy(&w->rods);
    dr_lag_destroy(&w->sys);
    dr_groom_free(&w->groom);
    free(w->radius), free(w->force), free(w->dfdv), free(w->block), free(w->block_dof), free(w->x_old);
    free(w->dV), free(w->held), free(w->submerged);
}

static DrBridgeStrands strands_of(Wet *w)
{
    DrRodState rs = dr_rod_set_state(w->rods);
    DrFilmState fs = dr_film_state(w->film);
    return (DrBridgeStrands){.nstrands = rs.nstrands, .nverts = rs.nverts, .offsets = rs.offsets, .x = rs.x,
                             .radius = w->radius, .volume = fs.volume, .vertex_dof = dr_rod_set_vertex_dofs(w->rods),
                             .held = w->held, .submerged = w->submerged};
}

/* One step as the world takes it. */
static void wet_step(Wet *w, double h)
{
    DrRodState rs = dr_rod_set_state(w->rods);
    int V = rs.nverts;
    CHECK(dr_rod_set_predict_dofs(w->rods, h, NULL, ERR));
    DrLagDofs d;
    CHECK(dr_lag_dofs(w->sys, &d, ERR));
    CHECK(dr_lag_begin(w->sys, h, d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, ERR));
    CHECK(dr_rod_set_predict_groups(w->rods, NULL, 0, ERR));
    DrRodSamples sm = dr_rod_set_samples(w->rods);
    memcpy(w->held, sm.held, (size_t)V);
    DrBridgeStrands bs = strands_of(w);
    CHECK(dr_bridges_update(w->bridges, &bs, NULL, 0, ERR));
    CHECK(dr_bridges_add_groups(w->bridges, &bs, w->sys, h, ERR));
    memset(w->force, 0, 3 * (size_t)V * sizeof(double));
    memset(w->dfdv, 0, 9 * (size_t)V * sizeof(double));
    dr_film_hair_load(w->film, rs.x, rs.v, h, w->force, w->dfdv);
    dr_rod_set_fill_load(w->rods, w->force, w->dfdv, d.force, w->block_dof, w->block);
    DrLagLoad load = {d.force, dr_rod_set_load_blocks(w->rods), w->block_dof, w->block};
    DrLagStats ls;
    CHECK(dr_lag_solve_load(w->sys, &load, d.qdot_out, &ls, ERR));
    dr_rod_set_take(w->rods);
    dr_lag_update_multipliers(w->sys, d.qdot_out);
    memcpy(w->x_old, rs.x, 3 * (size_t)V * sizeof(double));
    CHECK(dr_rod_set_commit(w->rods, NULL, ERR));
    CHECK(dr_film_step(w->film, w->x_old, rs.x, rs.v, rs.mass, w->held, h, NULL, ERR));
    bs = strands_of(w);
    CHECK(dr_bridges_cross_flow(w->bridges, &bs, h, w->dV, ERR));
    dr_film_exchange(w->film, rs.x, w->dV, rs.v, rs.mass);
}

/* ---- cohesion against beam theory ------------------------------------------------------------------------------ */

/* Two parallel strands clamped at both ends (L = 2.5 mm, 25 edges, axes 250 µm = 5 r apart), bridged along their whole
   length (the bridges exist: they formed when the strands were closer and hold, by hysteresis, up to d_keep = 5.8 r),
   with films at H = 1.5 r (each vertex's bridge holds A_L = 2 π (1.5² − 1) r² = 7.9 r²), pull each other by the
   table's force per unit length q; each deflects at midspan like a clamped–clamped beam under a uniform load,
   δ = q L⁴/(384 E I), I = π r⁴/4. The gap is above d̂ = (2·1.6 − 1)·2r = 4.4 r, where the bridge's spring gives the
   table's force exactly; δ (~0.6 µm) is far below r, so the beam is linear; q varies along the span with the gap (the
   table's slope over 2δ, under 1 %): the mean over the bridged vertices is taken. The span is L − Δ (Δ = L/n, an edge):
   clamping holds each end edge, and the beam's clamp falls at the middle of it (a clamped strand under its weight
   deflects as a beam of L − Δ: 4.559e-8 m against 4.59e-8 at n = 24, and converges to L as 1/n). No gravity; the
   implicit steps damp the beam's vibration (its first mode, 40 kHz, is far above 1/h). Under the bulk liquid's surface
   cohesion fades out: with the strands half submerged (s = ½) the beams deflect half as far, fully submerged (s = 1)
   not at all. */
static void test_bridged_beams_deflect(void **state)
{
    (void)state;
    const double L = 2.5e-3, gap = 2.5e-4;
    const int n = 50;
    double delta0 = 0;
    for (int pass = 0; pass < 4; pass++) { /* pass 1: σ = 0; 2: half submerged; 3: submerged */
        DrBridgeDesc bd;
        dr_bridge_desc_default(&bd);
        bd.surface_tension = pass == 1 ? 0.0 : SIGMA;
        bd.cross_flow = false;
        Wet w;
        wet_make(&w, two_strands(L, n, gap), DR_ROD_ROOTS_CLAMPED, DR_ROD_ROOTS_CLAMPED, dr_v3(0, 0, 0), 1.5, &bd);
        DrRodState rs = dr_rod_set_state(w.rods);
        if (pass >= 2) {
            w.submerged = calloc((size_t)rs.nverts, sizeof(double));
            for (int i = 0; i < rs.nverts; i++) w.submerged[i] = pass == 2 ? 0.5 : 1.0;
        }
        int nb = 0, pv[2 * 51], ps[2 * 51];
        for (int i = 0; i < rs.nverts; i++, nb++) {
            pv[nb] = i;
            ps[nb] = i < n + 1 ? 1 : 0;
        }
        CHECK(dr_bridges_set(w.bridges, nb, pv, ps, ERR));
        double h = 2e-4;
        for (int k = 0; k < 400; k++) wet_step(&w, h);
        int mid0 = n / 2, mid1 = (n + 1) + n / 2;
        double d_mid = rs.x[3 * mid1 + 2] - rs.x[3 * mid0 + 2];
        double delta = 0.5 * (gap - d_mid);
        DrBridgeStats bst;
        dr_bridges_stats(w.bridges, &bst);
        if (pass == 1 || pass == 3) {
            print_message("%s: %d bridges, midspan moved %.3e m\n", pass == 1 ? "sigma = 0" : "submerged",
                          bst.bridges, delta);
            assert_true(fabs(delta) < 1e-12);
        } else if (pass == 2) {
            print_message("half submerged: midspan deflection %.4e m, %.4f of the dry pair's\n", delta, delta / delta0);
            assert_true(fabs(delta / delta0 - 0.5) < 0.01);
        } else {
            double H = 1.5 * R, A = 2 * DR_PI * (H * H - R * R);
            double qsum = 0, qmin = INFINITY, qmax = -INFINITY;
            for (int j = 1; j < n; j++) {
                double dj = rs.x[3 * (n + 1 + j) + 2] - rs.x[3 * j + 2];
                double q = dr_cohesion_force(w.tables[0], R, SIGMA, dj, A);
                qsum += q;
                qmin = fmin(qmin, q);
                qmax = fmax(qmax, q);
            }
            double q = qsum / (n - 1);
            double EI = 3.9e9 * DR_PI * pow(R, 4) / 4;
            double expect = q * pow(L - L / n, 4) / (384 * EI);
            double vmax = 0;
            for (int i = 0; i < 3 * rs.nverts; i++) vmax = fmax(vmax, fabs(rs.v[i]));
            print_message("%d bridges; q = %.5f N/m (from %.5f to %.5f along the span); midspan deflection %.4e m, "
                          "beam theory %.4e m (%+.2f %%); |v| max %.2e m/s\n",
                          bst.bridges, q, qmin, qmax, delta, expect, 100 * (delta / expect - 1), vmax);
            assert_true(bst.bridges == 2 * (n + 1));
            assert_true(qmin > 0 && (qmax - qmin) < 0.01 * q);
            assert_true(fabs(delta / expect - 1) < 0.03);
            delta0 = delta;
        }
        wet_free(&w);
    }
}

/* Two parallel strands pulled apart, their positions set by hand step after step (no dynamics): the bridges hold up
   to d_keep = max(H_p + H_c, d_L) and, once broken, form again only below d_new = min(H_p + H_c, d_L). */
static void test_bridge_hysteresis(void **state)
{
    (void)state;
    DrBridgeDesc bd;
    dr_bridge_desc_default(&bd);
    Wet w;
    const double H = 3 * R;
    wet_make(&w, two_strands(2e-3, 10, 2.5e-4), DR_ROD_ROOTS_FREE, DR_ROD_ROOTS_FREE, dr_v3(0, 0, 0), 3.0, &bd);
    DrRodState rs = dr_rod_set_state(w.rods);
    double A = DR_PI * (H * H - R * R);
    double dL = (1 + 0.5 * THETA) * sqrt(2 * A) + 2 * R;
    double d_new = fmin(2 * H, dL), d_keep = fmax(2 * H, dL);
    print_message("d_new %.4e m, d_keep %.4e m\n", d_new, d_keep);
    assert_true(d_keep > d_new * 1.2); /* the two thresholds are apart at this film */
    double broke = -1, reformed = -1;
    int steps = 200;
    for (int k = 0; k <= 2 * steps; k++) { /* out to 1.5 d_keep, then back to 0.5 d_new */
        double f = k <= steps ? (double)k / steps : (double)(2 * steps - k) / steps;
        double gap = 0.5 * d_new + f * (1.5 * d_keep - 0.5 * d_new);
        for (int i = rs.offsets[1]; i < rs.offsets[2]; i++) rs.x[3 * i + 2] = gap;
        DrBridgeStrands bs = strands_of(&w);
        CHECK(dr_bridges_update(w.bridges, &bs, NULL, 0, ERR));
        DrBridgeStats st;
        dr_bridges_stats(w.bridges, &st);
        if (k <= steps && broke < 0 && st.bridges == 0) broke = gap;
        if (k > steps && reformed < 0 && st.bridges > 0) reformed = gap;
        if (k == 0) assert_int_equal(st.bridges, 2 * 11); /* every vertex, both ways */
    }
    double step = (1.5 * d_keep - 0.5 * d_new) / steps;
    print_message("broke at %.4e m (d_keep %.4e), formed again at %.4e m (d_new %.4e)\n", broke, d_keep, reformed,
                  d_new);
    assert_true(broke > d_keep && broke <= d_keep + step * 1.0001);
    assert_true(reformed <= d_new && reformed > d_new - step * 1.0001);
    wet_free(&w);
}

/* ---- cross-hair flow -------------------------------------------------------------------------------------------- */

static double strand_volume(Wet *w, int s)
{
    DrRodState rs = dr_rod_set_state(w->rods);
    DrFilmState fs = dr_film_state(w->film);
    double v = fs.pool[2 * s] + fs.pool[2 * s + 1];
    for (int i = rs.offsets[s]; i < rs.offsets[s + 1]; i++) v += fs.volume[i];
    return v;
}

/* Two bridged parallel strands held in place (both ends clamped, no gravity), one with twice the other's film: the
   cross-hair flow evens them out monotonically and keeps their total to 1e-12; with CrossFlow off nothing crosses,
   bit for bit; pulled apart (no bridge) nothing crosses either. */
static void test_cross_flow(void **state)
{
    (void)state;
    for (int mode = 0; mode < 3; mode++) { /* 0 on, 1 off, 2 apart */
        DrBridgeDesc bd;
        dr_bridge_desc_default(&bd);
        bd.cross_flow = mode != 1;
        bd.cross_flow_rate = 20;
        bd.scale = 0; /* no cohesion force: the strands stay where they are held */
        Wet w;
        double gap = mode == 2 ? 3e-3 : 2.5e-4;
        wet_make(&w, two_strands(2e-3, 10, gap), DR_ROD_ROOTS_CLAMPED, DR_ROD_ROOTS_CLAMPED, dr_v3(0, 0, 0), 3.0,
                 &bd);
        DrFilmState fs = dr_film_state(w.film);
        DrRodState rs = dr_rod_set_state(w.rods);
        for (int i = rs.offsets[1]; i < rs.offsets[2]; i++) fs.volume[i] *= 0.5;
        double v0 = strand_volume(&w, 0), v1 = strand_volume(&w, 1), total = v0 + v1;
        double *before = malloc((size_t)rs.nverts * sizeof(double));
        memcpy(before, fs.volume, (size_t)rs.nverts * sizeof(double));
        double diff = v0 - v1, worst = 0;
        bool monotone = true;
        for (int k = 0; k < 200; k++) {
            wet_step(&w, 1e-3);
            double a = strand_volume(&w, 0), b = strand_volume(&w, 1);
            worst = fmax(worst, fabs((a + b) - total) / total);
            if (a - b > diff * (1 + 1e-12)) monotone = false;
            diff = a - b;
        }
        print_message("%s: difference %.3e -> %.3e m^3 of %.3e, total drift %.2e\n",
                      mode == 0 ? "on" : mode == 1 ? "off" : "apart", v0 - v1, diff, total, worst);
        assert_true(worst < 1e-12);
        if (mode == 0) {
            assert_true(monotone);
            assert_true(diff < 0.05 * (v0 - v1));
        } else {
            assert_true(diff == v0 - v1 || fabs(diff - (v0 - v1)) < 1e-15 * total);
        }
        free(before);
        wet_free(&w);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bridged_beams_deflect),
        cmocka_unit_test(test_bridge_hysteresis),
        cmocka_unit_test(test_cross_flow),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
