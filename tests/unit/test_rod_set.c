/* Unit tests of the rod set's step in phases (hair.h): predict + solve(no forces) + commit equals
 * dr_rod_set_step bit for bit with moving roots, colliders and hair–hair contacts, on 1 and 2 threads;
 * re-solving from one prediction (twice, or with a load first) changes nothing; the samples describe the
 * prediction and then the last solve; a load's momentum ledger (Σ m Δv = h Σ (f + D v₊)) on a free strand;
 * a drag D = −c I damps a uniform velocity to v/(1 + h c/m); no heap allocation after the first substep; the
 * documented stable_dt; a set in a shared system (alone: the same bits as in its own; two sets: what each solves
 * alone). */
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

static void near_or_fail(double a, double b, double tol, const char *file, int line)
{
    if (fabs(a - b) <= tol) return;
    print_error("%.17g != %.17g (|diff| %.3g > tol %.3g)\n", a, b, fabs(a - b), tol);
    _fail(file, line);
}
#define assert_near(a, b, tol) near_or_fail((a), (b), (tol), __FILE__, __LINE__)

#define CHECK(expr)                                                                                                \
    do {                                                                                                           \
        DrError err_;                                                                                              \
        DrStatus s_ = (expr);                                                                                      \
        if (s_ != DR_OK) fail_msg("%s: status %d: %s", #expr, s_, err_.message);                                  \
    } while (0)
#define ERR (&err_)

/* ---- a furry ball like tests/data/hair_small.json: a shaken scalp, a head and a sliding floor ---------- */

static const DrVec3 CENTRE = {0, 0.2, 0};

/* S strands of nseg edges rooted on a sphere of radius R about CENTRE (a spiral of roots), curling about their
   normal with an amplitude of a tenth of their length L. */
static DrGroom ball_groom(int S, int nseg, double R, double L, double phase)
{
    DrGroom g = {0};
    g.nstrands = S;
    g.offsets = calloc((size_t)S + 1, sizeof(int));
    g.x = calloc((size_t)S * (size_t)(nseg + 1) * 3, sizeof(double));
    g.root_normal = calloc((size_t)S * 3, sizeof(double));
    for (int s = 0; s < S; s++) {
        g.offsets[s] = s * (nseg + 1);
        double z = 1 - 2 * (s + 0.5) / S, rr = sqrt(1 - z * z), ph = s * 2.399963 + phase;
        DrVec3 n = dr_v3(rr * cos(ph), z, rr * sin(ph));
        DrVec3 a = dr_v3_normalize(dr_v3_cross(n, dr_v3(0.3, 0.2, 1))), b = dr_v3_cross(n, a);
        DrVec3 p = dr_v3_add(CENTRE, dr_v3_scale(n, R));
        for (int j = 0; j <= nseg; j++) {
            double u = (double)j / nseg;
            DrVec3 q = dr_v3_add(p, dr_v3_scale(n, L * u));
            q = dr_v3_add(q, dr_v3_scale(a, 0.1 * L * sin(6 * u + s)));
            q = dr_v3_add(q, dr_v3_scale(b, 0.1 * L * (1 - cos(6 * u + s))));
            memcpy(g.x + 3 * (g.offsets[s] + j), &q, sizeof q);
        }
        memcpy(g.root_normal + 3 * s, &a, sizeof a);
    }
    g.offsets[S] = S * (nseg + 1);
    return g;
}

/* The scalp turned about y (and a little about z) by 0.6 sin(6π t) rad about CENTRE. */
static DrXform shake(double t)
{
    double ang = 0.6 * sin(2 * DR_PI * 3 * t);
    DrXform X;
    X.R = dr_m3_from_euler_xyz(dr_v3(0, ang, 0.3 * ang));
    X.t = dr_v3_sub(CENTRE, dr_m3_apply(X.R, CENTRE));
    return X;
}

typedef struct Ball { DrVec3 c; double R, omega; } Ball;
static double ball_sdf(DrVec3 x, DrVec3 *n, void *ctx)
{
    const Ball *b = ctx;
    DrVec3 d = dr_v3_sub(x, b->c);
    double l = dr_v3_norm(d);
    *n = dr_v3_scale(d, 1.0 / l);
    return l - b->R;
}
static DrVec3 ball_velocity(DrVec3 x, void *ctx)
{
    const Ball *b = ctx;
    return dr_v3_cross(dr_v3(0, b->omega, 0), dr_v3_sub(x, b->c));
}

typedef struct Floor { double y; DrVec3 v; } Floor;
static double floor_sdf(DrVec3 x, DrVec3 *n, void *ctx)
{
    const Floor *f = ctx;
    *n = dr_v3(0, 1, 0);
    return x.y - f->y;
}
static DrVec3 floor_velocity(DrVec3 x, void *ctx)
{
    (void)x;
    return ((const Floor *)ctx)->v;
}

static Ball g_ball = {{0, 0.2, 0}, 0.0495, 2.0};
static Floor g_floor = {0.125, {0.2, 0, 0.05}};    /* the lower strands start 25 mm through it */
static Floor g_low_floor = {0.11, {0.2, 0, 0.05}}; /* touched by a few tips */

static DrRodCollider g_colliders[2] = {{ball_sdf, ball_velocity, &g_ball, 0.3, 0.0002},
                                       {floor_sdf, floor_velocity, &g_floor, 0.5, 0}};
static DrRodCollider g_low_colliders[2] = {{ball_sdf, ball_velocity, &g_ball, 0.3, 0.0002},
                                           {floor_sdf, floor_velocity, &g_low_floor, 0.5, 0}};

/* Two grooms on the ball (so two batches with their own contact settings), damping, hair contact on. */
typedef struct Furry {
    DrGroom g[2];
    DrRodSet *r;
} Furry;

static void furry_make(Furry *f, const DrRodSetDesc *d)
{
    f->g[0] = ball_groom(40, 8, 0.05, 0.05, 0.0);
    f->g[1] = ball_groom(20, 6, 0.05, 0.04, 1.0);
    DrRodMaterial m;
    dr_rod_material_default(&m);
    m.radius = 1e-4;
    m.youngs = 1e8;
    m.damping = 0.002;
    DrRodBatch b[2] = {{&f->g[0], m, 1, 3, true, 10, 0.3, 0.002, 0.3, 0.0005, 0},
                       {&f->g[1], m, 2, 3, true, 20, 0.1, 0.001, 0.2, 0, 0}};
    CHECK(dr_rod_set_create(d, b, 2, &f->r, ERR));
}

static void furry_desc(DrRodSetDesc *d)
{
    dr_rod_set_desc_default(d);
    d->hair_contact = true;
}

static void furry_free(Furry *f)
{
    dr_rod_set_destroy(&f->r);
    dr_groom_free(&f->g[0]);
    dr_groom_free(&f->g[1]);
}

/* The whole state a continuation reads, compared byte for byte. */
static void assert_same_state(DrRodSet *a, DrRodSet *b)
{
    DrRodState s = dr_rod_set_state(a), t = dr_rod_set_state(b);
    assert_int_equal(s.nverts, t.nverts);
    assert_memory_equal(s.x, t.x, 3 * sizeof(double) * (size_t)s.nverts);
    assert_memory_equal(s.v, t.v, 3 * sizeof(double) * (size_t)s.nverts);
    assert_memory_equal(s.theta, t.theta, sizeof(double) * (size_t)s.nedges);
    assert_memory_equal(s.theta_dot, t.theta_dot, sizeof(double) * (size_t)s.nedges);
    assert_memory_equal(s.a1, t.a1, 3 * sizeof(double) * (size_t)s.nedges);
    assert_memory_equal(s.ref_twist, t.ref_twist, sizeof(double) * (size_t)(s.nverts - 2 * s.nstrands));
    assert_memory_equal(s.lambda, t.lambda, sizeof(double) * (size_t)s.nlambda);
}

static const double H = 1.0 / 96; /* hair_small: 24 fps, 4 substeps */

/* A load for the furry ball: a wind-like force and a drag on every vertex, varying along the set. */
static void furry_load(DrRodSet *r, double scale, double **force, double **dfdv)
{
    DrRodSamples sm = dr_rod_set_samples(r);
    *force = calloc(3 * (size_t)sm.n, sizeof(double));
    *dfdv = calloc(9 * (size_t)sm.n, sizeof(double));
    for (int i = 0; i < sm.n; i++) {
        double c = scale * 50 * sm.mass[i] * (1 + 0.5 * sin(i));
        (*force)[3 * i] = scale * 3 * sm.mass[i] * 9.81;
        (*force)[3 * i + 2] = -scale * sm.mass[i] * 9.81 * cos(0.3 * i);
        for (int a = 0; a < 3; a++) (*dfdv)[9 * i + 4 * a] = -c;
        (*dfdv)[9 * i + 1] = (*dfdv)[9 * i + 3] = 0.2 * c; /* symmetric, still negative definite */
    }
}

/* ---- tests -------------------------------------------------------------------------------------------- */

static void test_stable_dt(void **state)
{
    (void)state;
    DrRodSetDesc d;
    furry_desc(&d);
    Furry f;
    furry_make(&f, &d);
    /* the implicit solver has no limit of its own: the world's substeps set the hair's step */
    double dt = dr_rod_set_stable_dt(f.r);
    assert_true(isinf(dt) && dt > 0);
    furry_free(&f);
}

/* predict + samples + solve(NULL, NULL) + commit against dr_rod_set_step: every byte of the state after each of
   8 substeps of a shaken ball with a head, a sliding floor and hair–hair contact. */
static void test_phases_equal_step(void **state)
{
    (void)state;
    for (int threads = 1; threads <= 2; threads++) {
        dr_set_threads(threads);
        DrRodSetDesc d;
        furry_desc(&d);
        Furry a, b;
        furry_make(&a, &d);
        furry_make(&b, &d);
        DrRodStats sa = {0}, sb = {0};
        int collider = 0, hair = 0;
        for (int k = 0; k < 8; k++) {
            DrXform pose[2] = {shake((k + 1) * H), shake((k + 1) * H)};
            CHECK(dr_rod_set_step(a.r, H, pose, g_colliders, 2, &sa, ERR));
            CHECK(dr_rod_set_predict(b.r, H, pose, g_colliders, 2, ERR));
            (void)dr_rod_set_samples(b.r);
            CHECK(dr_rod_set_solve(b.r, NULL, NULL, &sb, ERR));
            (void)dr_rod_set_samples(b.r);
            CHECK(dr_rod_set_commit(b.r, &sb, ERR));
            assert_same_state(a.r, b.r);
            assert_int_equal(sa.iterations, sb.iterations);
            assert_int_equal(sa.collider_contacts, sb.collider_contacts);
            assert_int_equal(sa.hair_contacts, sb.hair_contacts);
            collider += sb.collider_contacts;
            hair += sb.hair_contacts;
        }
        print_message("%d thread(s): %d collider and %d hair contacts over 8 substeps, %d CG iterations\n", threads,
                      collider, hair, sb.iterations);
        assert_true(collider > 0 && hair > 0); /* the scene exercises both */
        assert_int_equal(sb.steps, 8);
        furry_free(&a);
        furry_free(&b);
    }
    dr_set_threads(0);
}

/* Solving twice from one prediction, or with a load first and then without, ends where one solve does. */
static void test_resolve_from_one_prediction(void **state)
{
    (void)state;
    DrRodSetDesc d;
    furry_desc(&d);
    Furry a, b, c;
    furry_make(&a, &d);
    furry_make(&b, &d);
    furry_make(&c, &d);
    int n = dr_rod_set_state(a.r).nverts;
    double *v1 = malloc(3 * sizeof(double) * (size_t)n);
    bool differs = false;
    for (int k = 0; k < 6; k++) {
        DrXform pose[2] = {shake((k + 1) * H), shake((k + 1) * H)};
        CHECK(dr_rod_set_step(a.r, H, pose, g_colliders, 2, NULL, ERR));
        /* b: two solves without forces, each the same velocities */
        CHECK(dr_rod_set_predict(b.r, H, pose, g_colliders, 2, ERR));
        CHECK(dr_rod_set_solve(b.r, NULL, NULL, NULL, ERR));
        memcpy(v1, dr_rod_set_samples(b.r).v, 3 * sizeof(double) * (size_t)n);
        CHECK(dr_rod_set_solve(b.r, NULL, NULL, NULL, ERR));
        assert_memory_equal(dr_rod_set_samples(b.r).v, v1, 3 * sizeof(double) * (size_t)n);
        CHECK(dr_rod_set_commit(b.r, NULL, ERR));
        assert_same_state(a.r, b.r);
        /* c: a solve with a wind and a drag, then one without */
        CHECK(dr_rod_set_predict(c.r, H, pose, g_colliders, 2, ERR));
        double *force, *dfdv;
        furry_load(c.r, 1.0, &force, &dfdv);
        CHECK(dr_rod_set_solve(c.r, force, dfdv, NULL, ERR));
        const double *vl = dr_rod_set_samples(c.r).v;
        for (int i = 0; i < 3 * n; i++) differs = differs || vl[i] != v1[i];
        CHECK(dr_rod_set_solve(c.r, NULL, NULL, NULL, ERR));
        assert_memory_equal(dr_rod_set_samples(c.r).v, v1, 3 * sizeof(double) * (size_t)n);
        CHECK(dr_rod_set_commit(c.r, NULL, ERR));
        assert_same_state(a.r, c.r);
        free(force);
        free(dfdv);
    }
    assert_true(differs); /* the load did change the solve it was given to */
    free(v1);
    furry_free(&a);
    furry_free(&b);
    furry_free(&c);
}

/* The samples: the vertices with their masses, radii, lengths and tangents; held roots at the velocity that
   lands them on the scalp; before a solve the step's start velocities, after it the solve's. */
static void test_samples(void **state)
{
    (void)state;
    DrRodSetDesc d;
    furry_desc(&d);
    Furry f;
    furry_make(&f, &d);
    for (int k = 0; k < 2; k++) CHECK(dr_rod_set_step(f.r, H, NULL, NULL, 0, NULL, ERR));
    DrRodState st = dr_rod_set_state(f.r);
    DrXform pose[2] = {shake(3 * H), shake(3 * H)};
    CHECK(dr_rod_set_predict(f.r, H, pose, NULL, 0, ERR));
    DrRodSamples sm = dr_rod_set_samples(f.r);
    assert_int_equal(sm.n, st.nverts);
    assert_ptr_equal(sm.x, st.x);
    double len_edges = 0, len_samples = 0;
    for (int s = 0; s < st.nstrands; s++) {
        int o = st.offsets[s], nv = st.offsets[s + 1] - o;
        for (int j = 0; j < nv; j++) {
            int i = o + j;
            assert_true(sm.mass[i] == st.mass[i]);
            assert_true(sm.radius[i] == st.radius[s]);
            DrVec3 t = dr_v3(sm.tangent[3 * i], sm.tangent[3 * i + 1], sm.tangent[3 * i + 2]);
            assert_near(dr_v3_norm(t), 1.0, 1e-14);
            len_samples += sm.length[i];
            if (j + 1 < nv) {
                DrVec3 e = dr_v3_sub(dr_v3(st.x[3 * i + 3], st.x[3 * i + 4], st.x[3 * i + 5]),
                                     dr_v3(st.x[3 * i], st.x[3 * i + 1], st.x[3 * i + 2]));
                len_edges += dr_v3_norm(e);
                assert_true(dr_v3_dot(e, t) > 0); /* from root to tip */
            }
            assert_int_equal(sm.held[i], j < 2); /* clamped roots: the first two vertices */
            for (int a = 0; a < 3; a++) {
                if (j < 2) continue;
                assert_true(sm.v[3 * i + a] == st.v[3 * i + a]);
            }
        }
        /* a held root lands on the posed rest root at the end of the step */
        DrVec3 end = dr_v3(sm.x[3 * o] + H * sm.v[3 * o], sm.x[3 * o + 1] + H * sm.v[3 * o + 1],
                           sm.x[3 * o + 2] + H * sm.v[3 * o + 2]);
        int b = s < st.batch_offsets[1] ? 0 : 1, sb = s - st.batch_offsets[b];
        const double *rest = f.g[b].x + 3 * f.g[b].offsets[sb];
        DrVec3 target = dr_xform_apply(pose[b], dr_v3(rest[0], rest[1], rest[2]));
        assert_near(dr_v3_norm(dr_v3_sub(end, target)), 0, 1e-15);
    }
    assert_near(len_samples, len_edges, 1e-12 * len_edges);
    /* after the solve: the solve's velocities, which commit keeps (no collider, so no friction after it) */
    CHECK(dr_rod_set_solve(f.r, NULL, NULL, NULL, ERR));
    sm = dr_rod_set_samples(f.r);
    double *v = malloc(3 * sizeof(double) * (size_t)sm.n);
    memcpy(v, sm.v, 3 * sizeof(double) * (size_t)sm.n);
    CHECK(dr_rod_set_commit(f.r, NULL, ERR));
    assert_memory_equal(dr_rod_set_state(f.r).v, v, 3 * sizeof(double) * (size_t)sm.n);
    free(v);
    furry_free(&f);
}

/* A free strand: bent at rest, no held vertex, no gravity, tumbling after a kick. */
static DrRodSet *free_strand(DrGroom *g, double tol)
{
    *g = ball_groom(1, 10, 0.05, 0.05, 0.3);
    DrRodMaterial m;
    dr_rod_material_default(&m);
    m.radius = 1e-4;
    m.youngs = 1e8;
    m.damping = 0.001;
    DrRodBatch b = {g, m, 1, 1, false, 10, 0, 0, 0, 0, 0};
    DrRodSetDesc d;
    dr_rod_set_desc_default(&d);
    d.roots = DR_ROD_ROOTS_FREE;
    d.gravity = dr_v3(0, 0, 0);
    d.solver.tol = tol;
    DrRodSet *r = NULL;
    CHECK(dr_rod_set_create(&d, &b, 1, &r, ERR));
    return r;
}

static DrVec3 momentum(const DrRodSamples *sm)
{
    DrVec3 p = {0, 0, 0};
    for (int i = 0; i < sm->n; i++)
        p = dr_v3_add(p, dr_v3_scale(dr_v3(sm->v[3 * i], sm->v[3 * i + 1], sm->v[3 * i + 2]), sm->mass[i]));
    return p;
}

/* The momentum ledger of a load: internal forces (stretching, bending, twisting, damping, with geometric
   stiffness) are translation invariant, so over one solve Σ m (v₊ − v) = h Σ (f_i + D_i v₊_i) exactly; what
   is left is the solver's residual. With tol = 1e-12 on ‖r‖_{M⁻¹}/‖b‖_{M⁻¹} the ledger closes to ~1e-12 of
   the momentum in play; 1e-9 leaves room for the round-off of sums over the strand. */
static void test_load_momentum_ledger(void **state)
{
    (void)state;
    DrGroom g;
    DrRodSet *r = free_strand(&g, 1e-12);
    DrRodState st = dr_rod_set_state(r);
    for (int i = 0; i < st.nverts; i++) { /* a kick that bends and turns the strand */
        st.v[3 * i] = 0.3 * sin(i);
        st.v[3 * i + 1] = 0.2 * cos(2.0 * i);
        st.v[3 * i + 2] = 0.1;
    }
    for (int k = 0; k < 5; k++) CHECK(dr_rod_set_step(r, H, NULL, NULL, 0, NULL, ERR));
    int n = st.nverts;
    double *force = calloc(3 * (size_t)n, sizeof(double)), *dfdv = calloc(9 * (size_t)n, sizeof(double));
    for (int pass = 0; pass < 2; pass++) {
        CHECK(dr_rod_set_predict(r, H, NULL, NULL, 0, ERR));
        DrRodSamples sm = dr_rod_set_samples(r);
        DrVec3 p0 = momentum(&sm), F = dr_v3(2e-5, -1e-5, 3e-5); /* N per vertex: ~g on a 3 µg vertex */
        for (int i = 0; i < n; i++) {
            force[3 * i] = F.x, force[3 * i + 1] = F.y, force[3 * i + 2] = F.z;
            if (pass == 1) /* and a drag −c_i I */
                for (int a = 0; a < 3; a++) dfdv[9 * i + 4 * a] = -20 * sm.mass[i] * (1 + 0.3 * cos(i));
        }
        DrRodStats rs = {0};
        CHECK(dr_rod_set_solve(r, force, pass ? dfdv : NULL, &rs, ERR));
        sm = dr_rod_set_samples(r);
        DrVec3 impulse = {0, 0, 0};
        for (int i = 0; i < n; i++) {
            DrVec3 v = dr_v3(sm.v[3 * i], sm.v[3 * i + 1], sm.v[3 * i + 2]);
            DrVec3 f = dr_v3(force[3 * i], force[3 * i + 1], force[3 * i + 2]);
            if (pass == 1) f = dr_v3_add(f, dr_v3_scale(v, dfdv[9 * i]));
            impulse = dr_v3_add(impulse, dr_v3_scale(f, H));
        }
        DrVec3 dp = dr_v3_sub(momentum(&sm), p0);
        double scale = dr_v3_norm(impulse) + dr_v3_norm(p0);
        double gap = dr_v3_norm(dr_v3_sub(dp, impulse));
        print_message("%s: impulse %.4e N s, momentum change off by %.2e (%d iterations)\n",
                      pass ? "force and drag" : "uniform force", dr_v3_norm(impulse), gap, rs.iterations);
        assert_true(dr_v3_norm(impulse) > 1e-3 * dr_v3_norm(p0)); /* the load matters at this scale */
        assert_true(gap <= 1e-9 * scale);
        CHECK(dr_rod_set_commit(r, NULL, ERR));
        /* the committed state carries that momentum */
        DrRodStats ms;
        dr_rod_set_measure(r, &ms);
        assert_near(ms.momentum.x, dp.x + p0.x, 1e-14 * scale);
        assert_near(ms.momentum.y, dp.y + p0.y, 1e-14 * scale);
        assert_near(ms.momentum.z, dp.z + p0.z, 1e-14 * scale);
    }
    free(force);
    free(dfdv);
    dr_rod_set_destroy(&r);
    dr_groom_free(&g);
}

/* A free strand in its rest shape moving at a uniform v: every internal force vanishes on a rigid translation,
   so a drag −c_i I with c_i/m_i = k on each vertex gives (m_i + h c_i) v₊ = m_i v, v₊ = v/(1 + h k) at every
   vertex; to the solver's tolerance (1e-12 relative), checked at 1e-10. The twist rates stay 0 to what that
   tolerance allows a DOF of inertia I: 1e-12 ‖b‖_{M⁻¹}/√I ≈ 2e-8 rad/s here (I ≈ 1e-15 kg m²), against a
   natural scale |v|/r = 6e3 rad/s; checked at 1e-10 |v|/r. */
static void test_drag_damps_uniform_velocity(void **state)
{
    (void)state;
    DrGroom g;
    DrRodSet *r = free_strand(&g, 1e-12);
    DrRodState st = dr_rod_set_state(r);
    DrVec3 v0 = dr_v3(0.4, -0.3, 0.25);
    for (int i = 0; i < st.nverts; i++) memcpy(st.v + 3 * i, &v0, sizeof v0);
    int n = st.nverts;
    double k = 35, *dfdv = calloc(9 * (size_t)n, sizeof(double));
    CHECK(dr_rod_set_predict(r, H, NULL, NULL, 0, ERR));
    DrRodSamples sm = dr_rod_set_samples(r);
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) dfdv[9 * i + 4 * a] = -k * sm.mass[i];
    CHECK(dr_rod_set_solve(r, NULL, dfdv, NULL, ERR));
    sm = dr_rod_set_samples(r);
    double expect[3] = {v0.x / (1 + H * k), v0.y / (1 + H * k), v0.z / (1 + H * k)};
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) assert_near(sm.v[3 * i + a], expect[a], 1e-10 * dr_v3_norm(v0));
    CHECK(dr_rod_set_commit(r, NULL, ERR));
    for (int e = 0; e < st.nedges; e++) assert_near(st.theta_dot[e], 0, 1e-10 * dr_v3_norm(v0) / st.radius[0]);
    free(dfdv);
    dr_rod_set_destroy(&r);
    dr_groom_free(&g);
}

/* A commit whose state turns non-finite (here: forces of ±1e158 N, alternating along the strand, tear its vertices
   ~1e155 m apart, where an edge's squared length overflows) leaves the whole state as it was before the step,
   multipliers included. */
static void test_commit_restores_on_failure(void **state)
{
    (void)state;
    DrGroom g;
    DrRodSet *r = free_strand(&g, 1e-8);
    DrRodState st = dr_rod_set_state(r);
    for (int i = 0; i < st.nverts; i++) st.v[3 * i + 1] = 0.2 * sin(i);
    for (int k = 0; k < 3; k++) CHECK(dr_rod_set_step(r, H, NULL, NULL, 0, NULL, ERR));
    size_t nx = 3 * sizeof(double) * (size_t)st.nverts, ne = sizeof(double) * (size_t)st.nedges;
    size_t ni = sizeof(double) * (size_t)(st.nverts - 2 * st.nstrands), nl = sizeof(double) * (size_t)st.nlambda;
    char *before = malloc(2 * nx + 5 * ne + ni + nl), *p = before;
    memcpy(p, st.x, nx), p += nx;
    memcpy(p, st.v, nx), p += nx;
    memcpy(p, st.theta, ne), p += ne;
    memcpy(p, st.theta_dot, ne), p += ne;
    memcpy(p, st.a1, 3 * ne), p += 3 * ne;
    memcpy(p, st.ref_twist, ni), p += ni;
    memcpy(p, st.lambda, nl);
    double *force = calloc(3 * (size_t)st.nverts, sizeof(double));
    for (int i = 0; i < st.nverts; i++) force[3 * i] = i % 2 ? 1e158 : -1e158;
    CHECK(dr_rod_set_predict(r, H, NULL, NULL, 0, ERR));
    DrError err;
    DrStatus s = dr_rod_set_solve(r, force, NULL, NULL, &err);
    assert_true(s >= 0);
    assert_int_equal(dr_rod_set_commit(r, NULL, &err), DR_ERR_RUNTIME);
    assert_non_null(strstr(err.message, "non-finite"));
    p = before;
    assert_memory_equal(p, st.x, nx), p += nx;
    assert_memory_equal(p, st.v, nx), p += nx;
    assert_memory_equal(p, st.theta, ne), p += ne;
    assert_memory_equal(p, st.theta_dot, ne), p += ne;
    assert_memory_equal(p, st.a1, 3 * ne), p += 3 * ne;
    assert_memory_equal(p, st.ref_twist, ni), p += ni;
    assert_memory_equal(p, st.lambda, nl);
    /* and the set steps on from there */
    CHECK(dr_rod_set_step(r, H, NULL, NULL, 0, NULL, ERR));
    free(force);
    free(before);
    dr_rod_set_destroy(&r);
    dr_groom_free(&g);
}

/* After the first substep, a substep allocates nothing: dr_alloc_count stays put over substeps 2..12, both for
   dr_rod_set_step and for predict / samples / two solves with a load / commit, on 1 and 2 threads. (The
   contact buffers hold twice the first substep's contacts; this scene stays within that.) */
static void test_no_allocation_after_first_substep(void **state)
{
    (void)state;
    for (int threads = 1; threads <= 2; threads++) {
        dr_set_threads(threads);
        for (int phased = 0; phased < 2; phased++) {
            DrRodSetDesc d;
            furry_desc(&d);
            Furry f;
            furry_make(&f, &d);
            double *force = NULL, *dfdv = NULL;
            DrRodStats st = {0};
            int cmin = 1 << 30, cmax = 0, hmin = 1 << 30, hmax = 0, csum = 0;
            for (int k = 0; k < 12; k++) {
                DrXform pose[2] = {shake((k + 1) * H), shake((k + 1) * H)};
                uint64_t before = dr_alloc_count();
                if (!phased) {
                    CHECK(dr_rod_set_step(f.r, H, pose, g_low_colliders, 2, &st, ERR));
                } else {
                    CHECK(dr_rod_set_predict(f.r, H, pose, g_low_colliders, 2, ERR));
                    (void)dr_rod_set_samples(f.r);
                    if (!force) { /* the test's own buffers, made before the count starts */
                        furry_load(f.r, 0.05, &force, &dfdv);
                        before = dr_alloc_count();
                    }
                    CHECK(dr_rod_set_solve(f.r, force, dfdv, &st, ERR));
                    (void)dr_rod_set_samples(f.r);
                    CHECK(dr_rod_set_solve(f.r, force, dfdv, &st, ERR));
                    CHECK(dr_rod_set_commit(f.r, &st, ERR));
                }
                uint64_t made = dr_alloc_count() - before;
                if (k > 0) {
                    if (made != 0)
                        fail_msg("substep %d allocated %llu times (%d collider, %d hair contacts)", k + 1,
                                 (unsigned long long)made, st.collider_contacts, st.hair_contacts);
                    csum += st.collider_contacts;
                    cmin = st.collider_contacts < cmin ? st.collider_contacts : cmin;
                    cmax = st.collider_contacts > cmax ? st.collider_contacts : cmax;
                    hmin = st.hair_contacts < hmin ? st.hair_contacts : hmin;
                    hmax = st.hair_contacts > hmax ? st.hair_contacts : hmax;
                } else {
                    assert_true(made > 0); /* the first substep sizes the buffers (the count works) */
                }
            }
            print_message("%d thread(s), %s: no allocation in substeps 2-12 with %d-%d collider and %d-%d hair "
                          "contacts\n",
                          threads, phased ? "phases with a load" : "dr_rod_set_step", cmin, cmax, hmin, hmax);
            assert_true(csum > 0 && hmin > 0); /* collider contacts come and go, hair contacts stay */
            free(force);
            free(dfdv);
            furry_free(&f);
        }
    }
    dr_set_threads(0);
}


/* ---- a shared system (DESIGN §8 "One Lagrangian system") ----------------------------------------------------- */

/* One step of the sets in `sys` as its owner drives it (hair.h, "in a shared system"): every set fills its DOFs, the
   system begins, every set adds its groups, then `solves` solves with the sets' loads (force, dfdv per set, NULL:
   none), the multipliers, every set commits. */
static DrStatus shared_step(DrLag *sys, DrRodSet **sets, int n, const DrXform *const *poses,
                            const DrRodCollider *col, int ncol, double *const *force, double *const *dfdv, int solves,
                            int *block_dof, double *block, DrRodStats *st, DrError *err)
{
    for (int i = 0; i < n; i++) DR_TRY(dr_rod_set_predict_dofs(sets[i], H, poses ? poses[i] : NULL, err));
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(sys, &d, err));
    DR_TRY(dr_lag_begin(sys, H, d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, err));
    for (int i = 0; i < n; i++) DR_TRY(dr_rod_set_predict_groups(sets[i], col, ncol, err));
    for (int k = 0; k < solves; k++) {
        DrLagLoad load = {NULL, 0, NULL, NULL};
        int nb = 0;
        for (int i = 0; i < n; i++) {
            if (!force || !force[i]) continue;
            dr_rod_set_fill_load(sets[i], force[i], dfdv[i], d.force, block_dof + nb, block + 9 * (size_t)nb);
            nb += dr_rod_set_load_blocks(sets[i]);
        }
        if (nb) load = (DrLagLoad){d.force, nb, block_dof, block};
        DrLagStats ls;
        DrStatus s = dr_lag_solve_load(sys, nb ? &load : NULL, d.qdot_out, &ls, err);
        if (s < 0) return s;
        if (st) st->iterations += ls.iterations;
        for (int i = 0; i < n; i++) dr_rod_set_take(sets[i]);
    }
    dr_lag_update_multipliers(sys, d.qdot_out);
    for (int i = 0; i < n; i++) DR_TRY(dr_rod_set_commit(sets[i], st, err));
    return DR_OK;
}

/* A set alone in a shared system, stepped by its owner, equals the set with a system of its own bit for bit: 8
   substeps of the shaken furry ball with colliders and hair contact, with a load solved twice per step, on 1 and 2
   threads; and after the first substep the shared step allocates nothing. */
static void test_shared_system_alone_equals_own(void **state)
{
    (void)state;
    for (int threads = 1; threads <= 2; threads++) {
        dr_set_threads(threads);
        DrRodSetDesc d;
        furry_desc(&d);
        Furry a, b;
        furry_make(&a, &d);
        DrLag *sys = NULL;
        CHECK(dr_lag_create(&d.solver, &sys, ERR));
        d.system = sys;
        furry_make(&b, &d);
        assert_int_equal(dr_lag_object_count(sys), dr_rod_set_state(b.r).nstrands);
        double *force = NULL, *dfdv = NULL;
        int *block_dof = NULL;
        double *block = NULL;
        DrRodStats sa = {0}, sb = {0};
        for (int k = 0; k < 8; k++) {
            DrXform pose[2] = {shake((k + 1) * H), shake((k + 1) * H)};
            const DrXform *poses[1] = {pose};
            CHECK(dr_rod_set_predict(a.r, H, pose, g_low_colliders, 2, ERR));
            if (!force) {
                furry_load(a.r, 0.05, &force, &dfdv);
                block_dof = calloc((size_t)dr_rod_set_load_blocks(a.r), sizeof(int));
                block = calloc(9 * (size_t)dr_rod_set_load_blocks(a.r), sizeof(double));
            }
            CHECK(dr_rod_set_solve(a.r, force, dfdv, &sa, ERR));
            CHECK(dr_rod_set_solve(a.r, force, dfdv, &sa, ERR));
            CHECK(dr_rod_set_commit(a.r, &sa, ERR));
            uint64_t before = dr_alloc_count();
            CHECK(shared_step(sys, &b.r, 1, poses, g_low_colliders, 2, &force, &dfdv, 2, block_dof, block, &sb, ERR));
            if (k > 0 && dr_alloc_count() != before)
                fail_msg("shared substep %d allocated %llu times", k + 1,
                         (unsigned long long)(dr_alloc_count() - before));
            assert_same_state(a.r, b.r);
            assert_int_equal(sa.iterations, sb.iterations);
            assert_int_equal(sa.hair_contacts, sb.hair_contacts);
        }
        print_message("%d thread(s): 8 shared substeps bit-identical to the set's own system, %d CG iterations, %d "
                      "hair contacts in the last\n",
                      threads, sb.iterations, sb.hair_contacts);
        assert_true(sb.hair_contacts > 0);
        free(force);
        free(dfdv);
        free(block_dof);
        free(block);
        furry_free(&a);
        furry_free(&b);
        dr_lag_destroy(&sys);
    }
    dr_set_threads(0);
}

/* Two sets in one system (objects one after the other, disjoint DOF ranges) solve together what each solves alone:
   without contact between them the system is block diagonal over the sets, so 6 substeps of each agree with the
   set stepped in its own system to the solvers' tolerance (1e-12 relative, mass-weighted; positions checked at
   1e-9 of the strand length after 6 steps, velocities at 1e-7 m/s against ~0.1 m/s of shaking). Without
   inter-object terms the per-strand blocks are the exact inverse, so both usually stop at the local solves with the
   same bits; the tolerance is what the contract promises. */
static void test_two_sets_in_one_system(void **state)
{
    (void)state;
    DrGroom g[2] = {ball_groom(30, 8, 0.05, 0.05, 0.0), ball_groom(12, 6, 0.05, 0.04, 1.0)};
    DrRodMaterial m;
    dr_rod_material_default(&m);
    m.radius = 1e-4;
    m.youngs = 1e8;
    m.damping = 0.002;
    DrRodSetDesc d;
    dr_rod_set_desc_default(&d);
    d.solver.tol = 1e-12;
    DrLag *sys = NULL;
    CHECK(dr_lag_create(&d.solver, &sys, ERR));
    DrRodSet *alone[2] = {NULL, NULL}, *shared[2] = {NULL, NULL};
    for (int i = 0; i < 2; i++) {
        DrRodBatch b = {&g[i], m, 1, 1, false, 10, 0, 0, 0.3, 0, 0};
        d.system = NULL;
        CHECK(dr_rod_set_create(&d, &b, 1, &alone[i], ERR));
        d.system = sys;
        CHECK(dr_rod_set_create(&d, &b, 1, &shared[i], ERR));
    }
    assert_int_equal(dr_lag_object_count(sys), 42);
    DrXform pose[2];
    const DrXform *poses[2] = {&pose[0], &pose[1]};
    for (int k = 0; k < 6; k++) {
        pose[0] = pose[1] = shake((k + 1) * H);
        for (int i = 0; i < 2; i++) CHECK(dr_rod_set_step(alone[i], H, &pose[i], g_low_colliders, 2, NULL, ERR));
        CHECK(shared_step(sys, shared, 2, poses, g_low_colliders, 2, NULL, NULL, 1, NULL, NULL, NULL, ERR));
    }
    double dx = 0, dv = 0, vmax = 0;
    for (int i = 0; i < 2; i++) {
        DrRodState a = dr_rod_set_state(alone[i]), b = dr_rod_set_state(shared[i]);
        for (int j = 0; j < 3 * a.nverts; j++) {
            dx = fmax(dx, fabs(a.x[j] - b.x[j]));
            dv = fmax(dv, fabs(a.v[j] - b.v[j]));
            vmax = fmax(vmax, fabs(a.v[j]));
        }
    }
    print_message("two sets in one system against each alone: |dx| %.2e m, |dv| %.2e m/s (max |v| %.3f m/s)\n", dx,
                  dv, vmax);
    assert_true(vmax > 0.05);
    assert_true(dx <= 1e-9 * 0.05);
    assert_true(dv <= 1e-7);
    for (int i = 0; i < 2; i++) {
        dr_rod_set_destroy(&alone[i]);
        dr_rod_set_destroy(&shared[i]);
        dr_groom_free(&g[i]);
    }
    dr_lag_destroy(&sys);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_stable_dt),
        cmocka_unit_test(test_phases_equal_step),
        cmocka_unit_test(test_resolve_from_one_prediction),
        cmocka_unit_test(test_samples),
        cmocka_unit_test(test_load_momentum_ledger),
        cmocka_unit_test(test_drag_damps_uniform_velocity),
        cmocka_unit_test(test_commit_restores_on_failure),
        cmocka_unit_test(test_no_allocation_after_first_substep),
        cmocka_unit_test(test_shared_system_alone_equals_own),
        cmocka_unit_test(test_two_sets_in_one_system),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
