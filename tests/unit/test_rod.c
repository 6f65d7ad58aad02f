/* Unit tests of src/hair/rod: parallel transport, space and time frames, the reference twist and its
 * continuity, the constraint groups' Jacobians against central differences at the reference state and away
 * from it, the geometric stiffness against second differences, the energy's gradient against the groups,
 * analytic curvatures and twists (straight rod, circular arc, uniform twist), the groups against the
 * frame-update functions a step uses, and degenerate input (two vertices, antiparallel edges). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "core/core.h"
#include "hair/rod.h"

/* ---- helpers ----------------------------------------------------------------------------------- */

static void near_or_fail(double a, double b, double tol, const char *file, int line)
{
    if (fabs(a - b) <= tol) return;
    print_error("%.17g != %.17g (|diff| %.3g > tol %.3g)\n", a, b, fabs(a - b), tol);
    _fail(file, line);
}
#define assert_near(a, b, tol) near_or_fail((a), (b), (tol), __FILE__, __LINE__)

static DrVec3 ld3(const double *p) { return dr_v3(p[0], p[1], p[2]); }
static void st3(double *p, DrVec3 v) { p[0] = v.x, p[1] = v.y, p[2] = v.z; }

static double uni(DrRng *rng, double a, double b) { return a + (b - a) * dr_rng_uniform(rng); }

static DrVec3 random_unit(DrRng *rng)
{
    for (;;) {
        DrVec3 v = dr_v3(uni(rng, -1, 1), uni(rng, -1, 1), uni(rng, -1, 1));
        double n = dr_v3_norm(v);
        if (n > 0.1 && n <= 1.0) return dr_v3_scale(v, 1.0 / n);
    }
}

/* Rotation of v about the unit axis k by angle a (Rodrigues). */
static DrVec3 rotate(DrVec3 v, DrVec3 k, double a)
{
    return dr_v3_add(dr_v3_add(dr_v3_scale(v, cos(a)), dr_v3_scale(dr_v3_cross(k, v), sin(a))),
                     dr_v3_scale(k, dr_v3_dot(k, v) * (1.0 - cos(a))));
}

static DrVec3 transport3(DrVec3 u, DrVec3 v, DrVec3 w)
{
    double a[3], b[3], c[3], o[3];
    st3(a, u), st3(b, v), st3(c, w);
    dr_rod_transport(a, b, c, o);
    return ld3(o);
}

#define NVMAX 8

/* A strand with its rest values and a reference state, DOFs packed as in rod.h (x_0, θ^0, x_1, …). */
typedef struct Strand {
    int nv;
    double L; /* shortest edge of the reference shape */
    double q[4 * NVMAX];
    double lbar[NVMAX], kbar[4 * NVMAX], tbar[NVMAX];
    double tref[3 * NVMAX], a1ref[3 * NVMAX], mref[NVMAX];
} Strand;

static void unpack(int nv, const double *q, double *x, double *theta)
{
    for (int j = 0; j < nv; j++) {
        for (int k = 0; k < 3; k++) x[3 * j + k] = q[4 * j + k];
        if (j + 1 < nv) theta[j] = q[4 * j + 3];
    }
}

/* A random curved polyline: edges of length L·[0.7, 1.3], each turned from the last by up to `turn` rad. */
static void random_shape(DrRng *rng, int nv, double L, double turn, double *x)
{
    DrVec3 p = dr_v3(uni(rng, -L, L), uni(rng, -L, L), uni(rng, -L, L)), d = random_unit(rng);
    st3(x, p);
    for (int j = 1; j < nv; j++) {
        DrVec3 k = dr_v3_normalize(dr_v3_cross(d, random_unit(rng)));
        d = rotate(d, k, uni(rng, 0.0, turn));
        p = dr_v3_add(p, dr_v3_scale(d, L * uni(rng, 0.7, 1.3)));
        st3(x + 3 * j, p);
    }
}

/* Rest values from one random shape and twists, the reference state (space-parallel frames, reference
 * twist) from another; q = the reference shape with random twists. */
static void random_strand(DrRng *rng, int nv, double L, Strand *s)
{
    memset(s, 0, sizeof *s);
    s->nv = nv;
    double x[3 * NVMAX], th[NVMAX], t[3 * NVMAX], a1[3 * NVMAX], len[NVMAX], m[NVMAX] = {0};
    double root[3];
    /* rest */
    random_shape(rng, nv, L, 0.9, x);
    for (int j = 0; j + 1 < nv; j++) th[j] = uni(rng, -DR_PI, DR_PI);
    dr_rod_tangents(nv, x, t, s->lbar);
    st3(root, random_unit(rng));
    dr_rod_space_frames(nv - 1, t, root, a1);
    dr_rod_reference_twist(nv, t, a1, m);
    dr_rod_curvatures(nv, t, a1, th, m, s->kbar, s->tbar);
    /* reference */
    random_shape(rng, nv, L, 0.9, x);
    dr_rod_tangents(nv, x, s->tref, len);
    st3(root, random_unit(rng));
    dr_rod_space_frames(nv - 1, s->tref, root, s->a1ref);
    for (int i = 0; i + 2 < nv; i++) s->mref[i] = uni(rng, -1.0, 1.0);
    dr_rod_reference_twist(nv, s->tref, s->a1ref, s->mref);
    s->L = len[0];
    for (int j = 0; j + 1 < nv; j++) s->L = fmin(s->L, len[j]);
    for (int j = 0; j < nv; j++) {
        for (int k = 0; k < 3; k++) s->q[4 * j + k] = x[3 * j + k];
        if (j + 1 < nv) s->q[4 * j + 3] = uni(rng, -DR_PI, DR_PI);
    }
}

/* Perturbs positions by up to amp·L per coordinate and twists by up to amp rad. */
static void perturb(DrRng *rng, const Strand *s, double amp, double *q)
{
    for (int d = 0; d < 4 * s->nv - 1; d++) q[d] = s->q[d] + uni(rng, -amp, amp) * (d % 4 == 3 ? 1.0 : s->L);
}

static const DrRodStiffness STIFF = {2.0, 3.0, 5.0};
static const int DOF0 = 40;

typedef enum GroupKind { G_STRETCH, G_BEND, G_TWIST } GroupKind;
static int group_count(GroupKind kind, int nv) { return kind == G_STRETCH ? nv - 1 : nv - 2; }

/* Evaluates group `idx` (edge for stretching, interior vertex − 1 otherwise) of strand s at DOFs q. */
static void eval_group(GroupKind kind, const Strand *s, const double *q, int idx, const double *lambda, double *G,
                       DrLagGroup *g)
{
    double x[3 * NVMAX], th[NVMAX];
    unpack(s->nv, q, x, th);
    DrRodRef ref = {s->tref, s->a1ref, s->mref};
    memset(g, 0xff, sizeof *g); /* every field the call owns must be written */
    if (kind == G_STRETCH) {
        dr_rod_stretch_group(x, idx, s->lbar[idx], STIFF.ks, DOF0, lambda, G, g);
        return;
    }
    int i = idx + 1;
    double lv = 0.5 * (s->lbar[i - 1] + s->lbar[i]);
    if (kind == G_BEND)
        dr_rod_bend_group(x, th, &ref, i, s->kbar + 4 * (i - 1), lv, STIFF.bend, DOF0, lambda, G, g);
    else
        dr_rod_twist_group(x, th, &ref, i, s->tbar[i - 1], lv, STIFF.twist, DOF0, lambda, G, g);
}

/* Unit of a local strand DOF: positions are measured in L, twists in rad, so scaled entries are
 * dimensionless and comparable within a row. */
static double dof_scale(const Strand *s, int d) { return d % 4 == 3 ? 1.0 : s->L; }

/* Largest scaled error of J against central differences of φ over every group of a strand at q, relative to
   each row's largest scaled entry. */
static double jacobian_error(const Strand *s, const double *q)
{
    double worst = 0.0;
    for (int kind = G_STRETCH; kind <= G_TWIST; kind++)
        for (int idx = 0; idx < group_count(kind, s->nv); idx++) {
            DrLagGroup g, gp, gm;
            eval_group(kind, s, q, idx, NULL, NULL, &g);
            assert_int_equal(g.kind, DR_LAG_POSITIONAL);
            assert_null(g.G);
            assert_null(g.lambda);
            int base = 4 * idx;
            assert_int_equal(g.ndof, kind == G_STRETCH ? 6 : 11);
            assert_int_equal(g.nrows, kind == G_BEND ? 4 : 1);
            for (int r = 0; r < g.nrows; r++) assert_true(g.cinv[r] > 0.0);
            double rowscale[DR_LAG_MAX_ROWS] = {0};
            for (int c = 0; c < g.ndof; c++) {
                int d = g.dof[c] - DOF0;
                assert_true(d >= base && d < 4 * s->nv - 1);
                for (int r = 0; r < g.nrows; r++)
                    rowscale[r] = fmax(rowscale[r], fabs(g.J[r * g.ndof + c]) * dof_scale(s, d));
            }
            for (int c = 0; c < g.ndof; c++) {
                int d = g.dof[c] - DOF0;
                /* h = 1e-6 in units of L or rad: truncation ~h² ≈ 1e-12, round-off ~ε/h ≈ 1e-10 (relative) */
                double h = 1e-6 * dof_scale(s, d), qp[4 * NVMAX], qm[4 * NVMAX];
                memcpy(qp, q, sizeof qp), memcpy(qm, q, sizeof qm);
                qp[d] += h, qm[d] -= h;
                eval_group(kind, s, qp, idx, NULL, NULL, &gp);
                eval_group(kind, s, qm, idx, NULL, NULL, &gm);
                for (int r = 0; r < g.nrows; r++) {
                    double fd = (gp.phi[r] - gm.phi[r]) / (qp[d] - qm[d]);
                    double e = fabs(fd - g.J[r * g.ndof + c]) * dof_scale(s, d) / rowscale[r];
                    worst = fmax(worst, e);
                }
            }
        }
    return worst;
}

/* ---- 1. transport -------------------------------------------------------------------------------- */

static void test_transport(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 1);
    for (int trial = 0; trial < 200; trial++) {
        DrVec3 u = random_unit(&rng), v = random_unit(&rng);
        DrVec3 w1 = dr_v3_scale(random_unit(&rng), 2.5), w2 = random_unit(&rng);
        DrVec3 pu = transport3(u, v, u), p1 = transport3(u, v, w1), p2 = transport3(u, v, w2);
        /* a rotation evaluated in a few dozen flops: round-off ~1e-15 */
        assert_true(dr_v3_norm(dr_v3_sub(pu, v)) < 1e-14);
        assert_near(dr_v3_norm(p1), 2.5, 1e-14);
        assert_near(dr_v3_dot(p1, p2), dr_v3_dot(w1, w2), 1e-14);
        /* a rotation, not a reflection: it keeps the orientation of (u, w1, w2) */
        assert_near(dr_v3_dot(pu, dr_v3_cross(p1, p2)), dr_v3_dot(u, dr_v3_cross(w1, w2)), 1e-14);
        /* about u × v: vectors along the axis stay */
        DrVec3 b = dr_v3_normalize(dr_v3_cross(u, v));
        assert_true(dr_v3_norm(dr_v3_sub(transport3(u, v, b), b)) < 1e-14);
        /* P(u → u) = I */
        assert_true(dr_v3_norm(dr_v3_sub(transport3(u, u, w1), w1)) < 1e-14);
        /* P(v → u) undoes P(u → v) */
        assert_true(dr_v3_norm(dr_v3_sub(transport3(v, u, p1), w1)) < 1e-13);
    }
    /* antiparallel: a rotation by π about an axis perpendicular to u */
    for (int trial = 0; trial < 50; trial++) {
        DrVec3 u = random_unit(&rng), v = dr_v3_scale(u, -1.0), w = random_unit(&rng);
        DrVec3 pu = transport3(u, v, u), pw = transport3(u, v, w), ppw = transport3(u, v, pw);
        assert_true(dr_v3_norm(dr_v3_sub(pu, v)) < 1e-14);
        assert_near(dr_v3_norm(pw), 1.0, 1e-14);
        assert_near(dr_v3_dot(pw, u), -dr_v3_dot(w, u), 1e-14);
        assert_true(dr_v3_norm(dr_v3_sub(ppw, w)) < 1e-14); /* a half turn twice is the identity */
    }
}

/* ---- 2. frames ------------------------------------------------------------------------------------- */

static void check_frames(int ne, const double *t, const double *a1)
{
    for (int j = 0; j < ne; j++) {
        DrVec3 tj = ld3(t + 3 * j), a = ld3(a1 + 3 * j), b = dr_v3_cross(tj, a);
        assert_near(dr_v3_norm(a), 1.0, 1e-14);
        assert_near(dr_v3_dot(a, tj), 0.0, 1e-14);
        assert_near(dr_v3_norm(b), 1.0, 1e-14);
    }
}

static void test_frames(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 2);
    for (int trial = 0; trial < 50; trial++) {
        int nv = NVMAX;
        double x[3 * NVMAX], t[3 * NVMAX], len[NVMAX], a1[3 * NVMAX], root[3];
        random_shape(&rng, nv, 0.01, 1.2, x);
        dr_rod_tangents(nv, x, t, len);
        for (int j = 0; j + 1 < nv; j++) {
            DrVec3 e = dr_v3_sub(ld3(x + 3 * j + 3), ld3(x + 3 * j));
            assert_near(len[j], dr_v3_norm(e), 1e-18);
            assert_true(dr_v3_norm(dr_v3_sub(dr_v3_scale(ld3(t + 3 * j), len[j]), e)) < 1e-17);
        }
        st3(root, random_unit(&rng));
        dr_rod_space_frames(nv - 1, t, root, a1);
        check_frames(nv - 1, t, a1);
        /* a1^0 is the root director made perpendicular to t^0 */
        DrVec3 r = ld3(root), t0 = ld3(t);
        DrVec3 want = dr_v3_normalize(dr_v3_sub(r, dr_v3_scale(t0, dr_v3_dot(r, t0))));
        assert_true(dr_v3_norm(dr_v3_sub(ld3(a1), want)) < 1e-14);
        /* space parallel: a1^{j+1} = P(t^j → t^{j+1}) a1^j */
        for (int j = 0; j + 2 < nv; j++) {
            DrVec3 p = transport3(ld3(t + 3 * j), ld3(t + 3 * j + 3), ld3(a1 + 3 * j));
            assert_true(dr_v3_norm(dr_v3_sub(p, ld3(a1 + 3 * j + 3))) < 1e-14);
        }
        /* root NULL or parallel to t^0: any perpendicular unit vector */
        dr_rod_space_frames(nv - 1, t, NULL, a1);
        check_frames(nv - 1, t, a1);
        dr_rod_space_frames(nv - 1, t, t, a1);
        check_frames(nv - 1, t, a1);
        /* time transport through a sequence of deformations stays orthonormal */
        for (int step = 0; step < 20; step++) {
            double x2[3 * NVMAX], t2[3 * NVMAX];
            for (int k = 0; k < 3 * nv; k++) x2[k] = x[k] + uni(&rng, -0.004, 0.004);
            dr_rod_tangents(nv, x2, t2, len);
            dr_rod_time_transport(nv - 1, t, t2, a1);
            check_frames(nv - 1, t2, a1);
            memcpy(x, x2, sizeof x), memcpy(t, t2, sizeof t);
        }
    }
}

/* ---- 3. reference twist ----------------------------------------------------------------------------- */

static void test_reference_twist(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 3);
    /* planar strand, space-parallel frames: the transport keeps a1 in or out of the plane, m = 0 */
    int nv = NVMAX;
    double x[3 * NVMAX], t[3 * NVMAX], len[NVMAX], a1[3 * NVMAX], m[NVMAX] = {0};
    for (int j = 0; j < nv; j++) {
        double a = 0.4 * j + 0.1 * j * j;
        x[3 * j] = cos(a), x[3 * j + 1] = sin(a), x[3 * j + 2] = 0.0;
    }
    dr_rod_tangents(nv, x, t, len);
    double root[3] = {0.3, -0.2, 1.0};
    dr_rod_space_frames(nv - 1, t, root, a1);
    dr_rod_reference_twist(nv, t, a1, m);
    for (int i = 0; i < nv - 2; i++) assert_near(m[i], 0.0, 1e-14);
    /* space-parallel frames on any curve: m = 0 */
    random_shape(&rng, nv, 1.0, 1.0, x);
    dr_rod_tangents(nv, x, t, len);
    dr_rod_space_frames(nv - 1, t, NULL, a1);
    for (int i = 0; i < nv - 2; i++) m[i] = 0.0;
    dr_rod_reference_twist(nv, t, a1, m);
    for (int i = 0; i < nv - 2; i++) assert_near(m[i], 0.0, 1e-14);

    /* continuity: a1^1 turning steadily about t^1 by 0.3 rad a call, through ±π and on to ~4 turns */
    dr_rod_space_frames(2, t, NULL, a1);
    DrVec3 t1 = ld3(t + 3), base = ld3(a1 + 3);
    double mm = 0.0;
    for (int k = 1; k <= 80; k++) {
        double ang = 0.3 * k;
        st3(a1 + 3, rotate(base, t1, ang));
        dr_rod_reference_twist(3, t, a1, &mm);
        assert_near(mm, ang, 1e-12);
    }
    for (int k = 79; k >= -80; k--) { /* and back, to negative angles */
        double ang = 0.3 * k;
        st3(a1 + 3, rotate(base, t1, ang));
        dr_rod_reference_twist(3, t, a1, &mm);
        assert_near(mm, ang, 1e-12);
    }

    /* the twist group continues from m_ref: m_ref = 3.1, the angle now 3.18 (not −3.10) */
    double a1r[6], mref = 3.1, th[2] = {0.0, 0.0};
    memcpy(a1r, a1, 3 * sizeof(double));
    st3(a1r + 3, rotate(base, t1, 3.18));
    DrRodRef ref = {t, a1r, &mref};
    DrLagGroup g;
    dr_rod_twist_group(x, th, &ref, 1, 0.0, 1.0, 1.0, 0, NULL, NULL, &g);
    assert_near(g.phi[0], 3.18, 1e-12);
    mref = -3.1; /* the same frames seen from −3.1: the nearest representative is 3.18 − 2π */
    dr_rod_twist_group(x, th, &ref, 1, 0.0, 1.0, 1.0, 0, NULL, NULL, &g);
    assert_near(g.phi[0], 3.18 - 2.0 * DR_PI, 1e-12);
}

/* ---- 4. Jacobians ------------------------------------------------------------------------------------ */

/* Every group of random 5-vertex strands (two length scales), at q_ref and at q_ref + random perturbations
   of 1e-2 (edge lengths and rad) and 1e-1. Measured worst scaled error: 1.1e-9 at q_ref, 1.0e-9 perturbed
   (the differencing's round-off). Tolerance 1e-6: a missing transport term is an O(perturbation) error; the
   frozen-frame (textbook) Jacobian differs from the exact one at a 1e-2 perturbation by ≥ 5.8e-5 (measured). */
static void test_jacobians(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 4);
    double worst_ref = 0.0, worst_pert = 0.0, min_gap = INFINITY;
    for (int trial = 0; trial < 40; trial++) {
        Strand s;
        random_strand(&rng, 5, trial % 2 ? 1e-3 : 1.0, &s);
        worst_ref = fmax(worst_ref, jacobian_error(&s, s.q));
        for (int p = 0; p < 2; p++) {
            double q[4 * NVMAX];
            perturb(&rng, &s, p ? 1e-1 : 1e-2, q);
            worst_pert = fmax(worst_pert, jacobian_error(&s, q));
            if (p) continue;
            /* the textbook gradients (frames re-based at q, ψ = 0) differ from the exact ones at q by the
               transport terms: much more than the tolerance */
            Strand b = s;
            double x[3 * NVMAX], th[NVMAX], len[NVMAX];
            unpack(s.nv, q, x, th);
            dr_rod_tangents(s.nv, x, b.tref, len);
            dr_rod_time_transport(s.nv - 1, s.tref, b.tref, b.a1ref);
            dr_rod_reference_twist(s.nv, b.tref, b.a1ref, b.mref);
            for (int kind = G_BEND; kind <= G_TWIST; kind++) {
                DrLagGroup ge, gb;
                eval_group(kind, &s, q, 1, NULL, NULL, &ge);
                eval_group(kind, &b, q, 1, NULL, NULL, &gb);
                double gap = 0.0, scale = 0.0;
                for (int k = 0; k < ge.nrows * ge.ndof; k++) {
                    double sc = dof_scale(&s, ge.dof[k % ge.ndof] - DOF0);
                    gap = fmax(gap, fabs(ge.J[k] - gb.J[k]) * sc);
                    scale = fmax(scale, fabs(ge.J[k]) * sc);
                    /* the values agree: the constraint functions are the same at q */
                    if (k < ge.nrows) assert_near(ge.phi[k], gb.phi[k], 1e-12);
                }
                min_gap = fmin(min_gap, gap / scale);
            }
        }
    }
    print_message("jacobian: worst scaled error %.2e at q_ref, %.2e perturbed; frozen-frame gap >= %.2e\n",
                  worst_ref, worst_pert, min_gap);
    assert_true(worst_ref < 1e-6);
    assert_true(worst_pert < 1e-6);
    assert_true(min_gap > 1e-5);
}

/* ---- 5. geometric stiffness ---------------------------------------------------------------------------- */

/* Σ λ_k φ_k of a group at q. */
static double weighted_phi(GroupKind kind, const Strand *s, const double *q, int idx, const double *lambda)
{
    DrLagGroup g;
    eval_group(kind, s, q, idx, NULL, NULL, &g);
    double S = 0.0;
    for (int r = 0; r < g.nrows; r++) S += lambda[r] * g.phi[r];
    return S;
}

/* ∂²S/∂q_a∂q_b by the second central difference with steps ha, hb (the diagonal with ±2h about q). */
static double second_difference(GroupKind kind, const Strand *s, const double *q, int idx, const double *lambda,
                                int da, int db, double ha, double hb)
{
    double S[4];
    for (int c = 0; c < 4; c++) {
        double qq[4 * NVMAX];
        memcpy(qq, q, sizeof qq);
        qq[da] += (c & 1) ? -ha : ha;
        qq[db] += (c & 2) ? -hb : hb;
        S[c] = weighted_phi(kind, s, qq, idx, lambda);
    }
    if (da == db) return (S[0] - 2.0 * weighted_phi(kind, s, q, idx, lambda) + S[3]) / (4.0 * ha * hb);
    return (S[0] - S[1] - S[2] + S[3]) / (4.0 * ha * hb);
}

/* G against second central differences of S = Σ λ_k φ_k, Richardson-extrapolated from steps h and 2h with
   h = 1e-3 (units of L and rad): truncation ~h⁴ ≈ 1e-12, round-off ~ε|S|/h² ≈ 1e-10 |S| relative to the
   group's largest scaled entry (|S| up to ~50 of those: θ of a few rad against a small curvature). A plain
   second difference cannot do better than ~ε^{1/2} ≈ 1e-8 (measured 2e-7 at its best step, 3e-4). Measured
   worst: 5e-9; tolerance 1e-6. Against differences of the exact J (below): measured 1.4e-10, tolerance 1e-8. */
static void test_geometric_stiffness(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 5);
    double worst = 0.0, worst_sym = 0.0, worst_j = 0.0;
    for (int trial = 0; trial < 40; trial++) {
        Strand s;
        random_strand(&rng, 5, trial % 2 ? 1e-3 : 1.0, &s);
        double q[4 * NVMAX];
        perturb(&rng, &s, trial % 4 < 2 ? 0.0 : 5e-2, q);
        for (int kind = G_STRETCH; kind <= G_TWIST; kind++)
            for (int idx = 0; idx < group_count(kind, s.nv); idx++) {
                double lambda[4], G[DR_LAG_MAX_DOFS * DR_LAG_MAX_DOFS];
                for (int k = 0; k < 4; k++) lambda[k] = uni(&rng, -1, 1);
                DrLagGroup g;
                eval_group(kind, &s, q, idx, lambda, G, &g);
                assert_ptr_equal(g.G, G);
                assert_null(g.lambda);
                int n = g.ndof;
                double scale = 0.0, asym = 0.0;
                for (int a = 0; a < n; a++)
                    for (int b = 0; b < n; b++) {
                        double sab = dof_scale(&s, g.dof[a] - DOF0) * dof_scale(&s, g.dof[b] - DOF0);
                        scale = fmax(scale, fabs(G[a * n + b]) * sab);
                        asym = fmax(asym, fabs(G[a * n + b] - G[b * n + a]) * sab);
                    }
                worst_sym = fmax(worst_sym, asym / scale);
                for (int a = 0; a < n; a++)
                    for (int b = a; b < n; b++) {
                        int da = g.dof[a] - DOF0, db = g.dof[b] - DOF0;
                        double ha = 1e-3 * dof_scale(&s, da), hb = 1e-3 * dof_scale(&s, db);
                        double d1 = second_difference(kind, &s, q, idx, lambda, da, db, ha, hb);
                        double d2 = second_difference(kind, &s, q, idx, lambda, da, db, 2.0 * ha, 2.0 * hb);
                        double fd = (4.0 * d1 - d2) / 3.0;
                        double e = fabs(fd - G[a * n + b]) * dof_scale(&s, da) * dof_scale(&s, db) / scale;
                        worst = fmax(worst, e);
                    }
                /* column b of G against central differences of Σ λ_k ∇φ_k (the exact Jacobian), also
                   Richardson-extrapolated from h = 1e-3 and 2h: ~h⁴ + ε/h ≈ 1e-12, so this measures the
                   error of G's own differencing */
                for (int b = 0; b < n; b++) {
                    int db = g.dof[b] - DOF0;
                    double D[2][DR_LAG_MAX_DOFS];
                    for (int lev = 0; lev < 2; lev++) {
                        double h = (lev ? 2e-3 : 1e-3) * dof_scale(&s, db), qp[4 * NVMAX], qm[4 * NVMAX];
                        memcpy(qp, q, sizeof qp), memcpy(qm, q, sizeof qm);
                        qp[db] += h, qm[db] -= h;
                        DrLagGroup gp, gm;
                        eval_group(kind, &s, qp, idx, NULL, NULL, &gp);
                        eval_group(kind, &s, qm, idx, NULL, NULL, &gm);
                        for (int a = 0; a < n; a++) {
                            D[lev][a] = 0.0;
                            for (int r = 0; r < g.nrows; r++) D[lev][a] += lambda[r] * (gp.J[r * n + a] - gm.J[r * n + a]);
                            D[lev][a] /= qp[db] - qm[db];
                        }
                    }
                    for (int a = 0; a < n; a++) {
                        double fd = (4.0 * D[0][a] - D[1][a]) / 3.0;
                        double e = fabs(fd - G[a * n + b]) * dof_scale(&s, g.dof[a] - DOF0) * dof_scale(&s, db) / scale;
                        worst_j = fmax(worst_j, e);
                    }
                }
            }
    }
    print_message("geometric stiffness: worst scaled error %.2e against differences of φ, %.2e against differences "
                  "of J; asymmetry %.2e\n", worst, worst_j, worst_sym);
    assert_true(worst_sym <= 1e-15);
    assert_true(worst < 1e-6);
    assert_true(worst_j < 1e-8);

    /* without λ or G: no G */
    Strand s;
    random_strand(&rng, 4, 1.0, &s);
    double G[DR_LAG_MAX_DOFS * DR_LAG_MAX_DOFS], lambda[4] = {1, 1, 1, 1};
    DrLagGroup g;
    for (int kind = G_STRETCH; kind <= G_TWIST; kind++) {
        eval_group(kind, &s, s.q, 0, NULL, G, &g);
        assert_null(g.G);
        eval_group(kind, &s, s.q, 0, lambda, NULL, &g);
        assert_null(g.G);
    }
}

/* ---- 6. energy -------------------------------------------------------------------------------------- */

/* ∂E/∂q = Σ_groups Jᵀ diag(C⁻¹) φ, each energy term alone and all together, with l_i = (l̄^{i−1} + l̄^i)/2.
   Central differences of E with h = 1e-6 (L, rad): ~1e-10 relative; measured 7e-10, tolerance 1e-6. */
static void test_energy_gradient(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 6);
    double worst = 0.0;
    const DrRodStiffness parts[4] = {{STIFF.ks, 0, 0}, {0, STIFF.bend, 0}, {0, 0, STIFF.twist}, STIFF};
    for (int trial = 0; trial < 10; trial++) {
        Strand s;
        random_strand(&rng, 6, trial % 2 ? 1e-3 : 1.0, &s);
        double q[4 * NVMAX];
        perturb(&rng, &s, 5e-2, q);
        int n = 4 * s.nv - 1;
        double x[3 * NVMAX], th[NVMAX];
        DrRodRef ref = {s.tref, s.a1ref, s.mref};
        for (int p = 0; p < 4; p++) {
            DrRodStiffness k = parts[p];
            double grad[4 * NVMAX] = {0}, E = 0.0;
            for (int kind = G_STRETCH; kind <= G_TWIST; kind++) {
                double w = kind == G_STRETCH ? k.ks / STIFF.ks : kind == G_BEND ? k.bend / STIFF.bend : k.twist / STIFF.twist;
                for (int idx = 0; idx < group_count(kind, s.nv); idx++) {
                    DrLagGroup g;
                    eval_group(kind, &s, q, idx, NULL, NULL, &g);
                    for (int r = 0; r < g.nrows; r++) {
                        E += 0.5 * w * g.cinv[r] * g.phi[r] * g.phi[r];
                        for (int c = 0; c < g.ndof; c++) grad[g.dof[c] - DOF0] += w * g.J[r * g.ndof + c] * g.cinv[r] * g.phi[r];
                    }
                }
            }
            unpack(s.nv, q, x, th);
            double E0 = dr_rod_energy(s.nv, x, th, &ref, s.lbar, s.kbar, s.tbar, k);
            assert_near(E0, E, 1e-13 * E);
            double gscale = 0.0, err = 0.0;
            for (int d = 0; d < n; d++) gscale = fmax(gscale, fabs(grad[d]) * dof_scale(&s, d));
            for (int d = 0; d < n; d++) {
                double h = 1e-6 * dof_scale(&s, d), qp[4 * NVMAX], qm[4 * NVMAX];
                memcpy(qp, q, sizeof qp), memcpy(qm, q, sizeof qm);
                qp[d] += h, qm[d] -= h;
                unpack(s.nv, qp, x, th);
                double Ep = dr_rod_energy(s.nv, x, th, &ref, s.lbar, s.kbar, s.tbar, k);
                unpack(s.nv, qm, x, th);
                double Em = dr_rod_energy(s.nv, x, th, &ref, s.lbar, s.kbar, s.tbar, k);
                err = fmax(err, fabs((Ep - Em) / (qp[d] - qm[d]) - grad[d]) * dof_scale(&s, d) / gscale);
            }
            worst = fmax(worst, err);
        }
    }
    print_message("energy gradient: worst scaled error %.2e\n", worst);
    assert_true(worst < 1e-6);
}

/* ---- 7. analytic values ---------------------------------------------------------------------------------- */

static void test_analytic_values(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 7);
    int nv = NVMAX, ne = nv - 1;
    double x[3 * NVMAX], t[3 * NVMAX], len[NVMAX], a1[3 * NVMAX], th[NVMAX], m[NVMAX] = {0};
    double kappa[4 * NVMAX], tau[NVMAX];
    /* straight rod, random twists: zero curvature in every frame */
    DrVec3 d = random_unit(&rng);
    for (int j = 0; j < nv; j++) st3(x + 3 * j, dr_v3_scale(d, 0.01 * j));
    for (int j = 0; j < ne; j++) th[j] = uni(&rng, -3, 3);
    dr_rod_tangents(nv, x, t, len);
    dr_rod_space_frames(ne, t, NULL, a1);
    dr_rod_reference_twist(nv, t, a1, m);
    dr_rod_curvatures(nv, t, a1, th, m, kappa, tau);
    for (int k = 0; k < 4 * (nv - 2); k++) assert_near(kappa[k], 0.0, 1e-15);
    /* uniformly twisted straight rod: τ = Δθ */
    for (int j = 0; j < ne; j++) th[j] = 0.7 + 0.25 * j;
    dr_rod_curvatures(nv, t, a1, th, m, kappa, tau);
    for (int i = 0; i < nv - 2; i++) assert_near(tau[i], 0.25, 1e-15);

    /* circular arc of radius R in a tilted plane, n equal edges turning by α: |κb| = 2 tan(α/2) in both
       frames; |κb|/l_i = 1/(R cos(α/2)) → 1/R at second order in α */
    double R = 0.02, prev_err = 0.0;
    DrVec3 ex = dr_v3_normalize(dr_v3(1, 0.2, -0.1)), ez = dr_v3_normalize(dr_v3_cross(ex, dr_v3(0, 1, 0)));
    DrVec3 ey = dr_v3_cross(ez, ex);
    for (int level = 0; level < 4; level++) {
        double alpha = 0.4 / (1 << level);
        for (int j = 0; j < nv; j++)
            st3(x + 3 * j, dr_v3_add(dr_v3_scale(ex, R * cos(alpha * j)), dr_v3_scale(ey, R * sin(alpha * j))));
        for (int j = 0; j < ne; j++) th[j] = uni(&rng, -3, 3);
        dr_rod_tangents(nv, x, t, len);
        dr_rod_space_frames(ne, t, NULL, a1);
        for (int i = 0; i < nv - 2; i++) m[i] = 0.0;
        dr_rod_reference_twist(nv, t, a1, m);
        dr_rod_curvatures(nv, t, a1, th, m, kappa, tau);
        double err = 0.0;
        for (int i = 0; i < nv - 2; i++) {
            for (int j = 0; j < 2; j++) {
                double k = hypot(kappa[4 * i + 2 * j], kappa[4 * i + 2 * j + 1]);
                assert_near(k, 2.0 * tan(alpha / 2), 1e-14);
                double lv = 0.5 * (len[i] + len[i + 1]);
                err = fmax(err, fabs(k / lv - 1.0 / R) * R);
            }
        }
        /* 1/cos(α/2) − 1 ≈ α²/8 */
        assert_near(err, 1.0 / cos(alpha / 2) - 1.0, 1e-12);
        if (level > 0) assert_near(prev_err / err, 4.0, 0.1); /* second order: 4(1 + 15α²/192) */
        prev_err = err;
    }

    /* the groups' values at their own reference state are the curvature functions' values */
    Strand s;
    random_strand(&rng, 6, 0.01, &s);
    unpack(s.nv, s.q, x, th);
    dr_rod_curvatures(s.nv, s.tref, s.a1ref, th, s.mref, kappa, tau);
    for (int idx = 0; idx < s.nv - 2; idx++) {
        DrLagGroup g;
        eval_group(G_BEND, &s, s.q, idx, NULL, NULL, &g);
        for (int r = 0; r < 4; r++) assert_near(g.phi[r], kappa[4 * idx + r] - s.kbar[4 * idx + r], 1e-14);
        eval_group(G_TWIST, &s, s.q, idx, NULL, NULL, &g);
        assert_near(g.phi[0], tau[idx] - s.tbar[idx], 1e-14);
    }
}

/* At q ≠ q_ref the groups are the state after one step's frame update (time transport, reference twist),
   and at the rest state with rest values φ = 0. */
static void test_groups_match_frame_update(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 8);
    for (int trial = 0; trial < 20; trial++) {
        Strand s;
        random_strand(&rng, 6, 0.01, &s);
        int nv = s.nv;
        double q[4 * NVMAX], x[3 * NVMAX], th[NVMAX], t[3 * NVMAX], len[NVMAX], a1[3 * NVMAX], m[NVMAX];
        double kappa[4 * NVMAX], tau[NVMAX];
        perturb(&rng, &s, 0.1, q);
        unpack(nv, q, x, th);
        dr_rod_tangents(nv, x, t, len);
        memcpy(a1, s.a1ref, sizeof a1), memcpy(m, s.mref, sizeof m);
        dr_rod_time_transport(nv - 1, s.tref, t, a1);
        dr_rod_reference_twist(nv, t, a1, m);
        dr_rod_curvatures(nv, t, a1, th, m, kappa, tau);
        for (int idx = 0; idx < nv - 2; idx++) {
            DrLagGroup g;
            eval_group(G_BEND, &s, q, idx, NULL, NULL, &g);
            /* the update re-normalises a1; the groups do not: differences at round-off */
            for (int r = 0; r < 4; r++) assert_near(g.phi[r], kappa[4 * idx + r] - s.kbar[4 * idx + r], 1e-13);
            eval_group(G_TWIST, &s, q, idx, NULL, NULL, &g);
            assert_near(g.phi[0], tau[idx] - s.tbar[idx], 1e-13);
        }
        /* rest values taken at the reference state itself: zero */
        unpack(nv, s.q, x, th);
        dr_rod_curvatures(nv, s.tref, s.a1ref, th, s.mref, s.kbar, s.tbar);
        dr_rod_tangents(nv, x, t, s.lbar);
        for (int kind = G_STRETCH; kind <= G_TWIST; kind++)
            for (int idx = 0; idx < group_count(kind, nv); idx++) {
                DrLagGroup g;
                eval_group(kind, &s, s.q, idx, NULL, NULL, &g);
                for (int r = 0; r < g.nrows; r++) assert_near(g.phi[r], 0.0, 1e-15);
            }
        DrRodRef ref = {s.tref, s.a1ref, s.mref};
        /* φ at round-off: ≲ 1e-14 (twists of a few rad), C⁻¹ ≲ 5/0.007: E ≲ 12 · ½ · 700 · 1e-28 ≈ 4e-25 */
        assert_near(dr_rod_energy(nv, x, th, &ref, s.lbar, s.kbar, s.tbar, STIFF), 0.0, 1e-24);
    }
}

/* ---- 8. degenerate input ----------------------------------------------------------------------------- */

static void test_degenerate(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 9);
    /* two vertices: one edge, stretching only */
    Strand s;
    random_strand(&rng, 2, 0.01, &s);
    double err = jacobian_error(&s, s.q);
    assert_true(err < 1e-6);
    double x[6], th[1], t[3], len[1], a1[3];
    unpack(2, s.q, x, th);
    dr_rod_tangents(2, x, t, len);
    dr_rod_space_frames(1, t, NULL, a1);
    check_frames(1, t, a1);
    dr_rod_reference_twist(2, t, a1, NULL); /* no interior vertex: nothing read or written */
    dr_rod_curvatures(2, t, a1, th, NULL, NULL, NULL);
    DrRodRef ref = {t, a1, NULL};
    double E = dr_rod_energy(2, x, th, &ref, s.lbar, NULL, NULL, STIFF);
    assert_near(E, 0.5 * STIFF.ks * pow(len[0] - s.lbar[0], 2) / s.lbar[0], 1e-15 * E);
    DrLagGroup g;
    double G[36], lambda = 0.7;
    dr_rod_stretch_group(x, 0, s.lbar[0], STIFF.ks, 7, &lambda, G, &g);
    assert_int_equal(g.dof[0], 7), assert_int_equal(g.dof[2], 9), assert_int_equal(g.dof[3], 11), assert_int_equal(g.dof[5], 13);
    assert_near(g.cinv[0], STIFF.ks / s.lbar[0], 1e-12 * g.cinv[0]);
    for (int r = 0; r < 6; r++)
        for (int c = 0; c < 6; c++) {
            double tt = t[r % 3] * t[c % 3], v = lambda * ((r % 3 == c % 3) - tt) / len[0];
            assert_near(G[r * 6 + c], (r < 3) == (c < 3) ? v : -v, 1e-12 / len[0]);
        }

    /* zero-length edge: t = 0, len = 0 */
    double xz[9] = {0, 0, 0, 0, 0, 0, 1, 0, 0}, tz[6], lz[2];
    dr_rod_tangents(3, xz, tz, lz);
    assert_true(lz[0] == 0.0 && tz[0] == 0.0 && tz[1] == 0.0 && tz[2] == 0.0);

    /* near-antiparallel transport: finite, a rotation, u mapped to v within the conditioning */
    for (int k = 0; k < 200; k++) {
        DrVec3 u = random_unit(&rng);
        double eps = pow(10.0, -uni(&rng, 0.0, 17.0));
        DrVec3 v = dr_v3_normalize(dr_v3_add(dr_v3_scale(u, -1.0), dr_v3_scale(random_unit(&rng), eps)));
        DrVec3 w = random_unit(&rng), pw = transport3(u, v, w), pu = transport3(u, v, u);
        assert_true(dr_v3_isfinite(pw) && dr_v3_isfinite(pu));
        assert_near(dr_v3_norm(pw), 1.0, 1e-13);
        assert_true(dr_v3_norm(dr_v3_sub(pu, v)) < 1e-11);
    }
    /* a strand folded back on itself: frames stay finite and orthonormal */
    double xf[9] = {0, 0, 0, 1, 0, 0, 1e-17, 0, 1e-20}, tf[6], lf[2], af[6], mf[1] = {0};
    dr_rod_tangents(3, xf, tf, lf);
    dr_rod_space_frames(2, tf, NULL, af);
    check_frames(2, tf, af);
    dr_rod_reference_twist(3, tf, af, mf);
    assert_true(isfinite(mf[0]));
    dr_rod_time_transport(1, tf, tf + 3, af);
    check_frames(1, tf + 3, af);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_transport),
        cmocka_unit_test(test_frames),
        cmocka_unit_test(test_reference_twist),
        cmocka_unit_test(test_jacobians),
        cmocka_unit_test(test_geometric_stiffness),
        cmocka_unit_test(test_energy_gradient),
        cmocka_unit_test(test_analytic_values),
        cmocka_unit_test(test_groups_match_frame_update),
        cmocka_unit_test(test_degenerate),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
