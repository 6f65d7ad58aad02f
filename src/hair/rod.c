/* drench hair: discrete-elastic-rod kernels of one strand (rod.h; Bergou et al. 2008 "Discrete Elastic Rods",
 * 2010 "Discrete Viscous Threads"; fei2017 §S4).
 *
 * Derivatives. Every constraint is a function of the edge vectors e^0 = x_i − x_{i−1}, e^1 = x_{i+1} − x_i and
 * the twists, for a fixed reference state. Three variations make up all of them (dt = (I − t tᵀ) de / l):
 *   - a reference director moved by time-parallel transport, a1(t) = P(t_ref → t) a1_ref, turns as
 *         da1 = −t (a1·dt) + ψ a2,   ψ = −h·de,   h = (t_ref × t) / ((1 + t_ref·t) l)                  (1)
 *     (ψ is the rate at which the transported frame turns about t: zero at t = t_ref, where it reduces to
 *     the textbook gradients, and the holonomy of the geodesic triangle t_ref, t, t + dt elsewhere); the
 *     material directors turn by ψ + dθ;
 *   - the space transport P(t^0 → t^1) between the two edges of a vertex turns its image about t^1 by
 *     −(κb/2)·(dt^0 + dt^1) (the same holonomy argument with both ends moving), so the reference twist
 *     m, the angle from P(t^0 → t^1) a1^0 to a1^1 about t^1, varies as
 *         dm = ψ^1 − ψ^0 + (κb/2)·(dt^0 + dt^1)                                                        (2)
 *     (Bergou 2010 §4.2's ∇m = κb/(2l) at t = t_ref);
 *   - the curvature binormal κb = 2 t^0 × t^1 / χ, χ = 1 + t^0·t^1, contracted with any vector N:
 *         d(κb·N) = [2 (t^1 × N)·dt^0 + 2 (N × t^0)·dt^1 − (κb·N)(t^1·dt^0 + t^0·dt^1)] / χ          (3)
 * With κ1^j = κb·m2^j, κ2^j = −κb·m1^j and κb ⟂ t^j, (1) gives dκ1^j = d(κb·N)|_{N=m2} + κ2^j (ψ^j + dθ^j)
 * and dκ2^j = d(κb·N)|_{N=−m1} − κ1^j (ψ^j + dθ^j). Positions enter through e only, so gradients are formed
 * per edge (g^0, g^1) and spread to the vertices as (−g^0, g^0 − g^1, g^1).
 *
 * Geometric stiffness. The position block of Σ_k λ_k ∇²φ_k is the central difference, in edge space, of the
 * λ-weighted exact gradient (12 evaluations that each re-transport one edge), symmetrised and mapped to the
 * vertices by the same (−, +) spreading, which is exact because φ depends on x through e only. Rows and
 * columns of the twists are closed-form: ∂κ1^j/∂θ^j = κ2^j and ∂κ2^j/∂θ^j = −κ1^j hold identically in q, so
 * ∂(Σ λ ∇φ)/∂θ^j = λ_{κ1^j} ∇κ2^j − λ_{κ2^j} ∇κ1^j; the twist τ is linear in θ. */
#include "hair/rod.h"

#include <math.h>
#include <string.h>

/* Step of the central differences for G, relative to each edge's length (so the same relative accuracy for
 * any strand scale). The weighted gradient is O(|λ|/l) and analytic in e: truncation ~η² and round-off ~ε/η
 * relative to G, balanced near η = ε^{1/3} ≈ 6e-6. Against Richardson-extrapolated differences of the
 * exact Jacobian on random bent strands (test_rod), the worst relative error is 2e-8 at η = 1e-4, 2e-10 at
 * 1e-5 and 9e-10 at 1e-6 (round-off already dominating). */
#define ROD_FD_REL 1e-5

/* Local DOF offsets of a vertex group: x_{i−1}, θ^{i−1}, x_i, θ^i, x_{i+1}. */
enum { ROD_X0 = 0, ROD_T0 = 3, ROD_X1 = 4, ROD_T1 = 7, ROD_X2 = 8, ROD_NDOF = 11 };

static inline DrVec3 ld3(const double *p) { return dr_v3(p[0], p[1], p[2]); }
static inline void st3(double *p, DrVec3 v) { p[0] = v.x, p[1] = v.y, p[2] = v.z; }

/* A unit vector perpendicular to u (zero for u = 0): u crossed with the axis it is least aligned with. */
static DrVec3 any_perpendicular(DrVec3 u)
{
    double ax = fabs(u.x), ay = fabs(u.y), az = fabs(u.z);
    DrVec3 axis = (ax <= ay && ax <= az) ? dr_v3(1, 0, 0) : (ay <= az ? dr_v3(0, 1, 0) : dr_v3(0, 0, 1));
    return dr_v3_normalize(dr_v3_cross(u, axis));
}

/* P(u → v) w given b = u × v and c = u·v. For c > −1/2 the form R = I + [b]× + [b]×²/(1 + c), i.e.
 * c w + b × w + (b·w) b/(1 + c), costs no square root. Closer to antiparallel, 1 + c loses its digits
 * while |b|² still holds them, so the rotation is written with the unit axis k = b/|b| and
 * (cos, sin) = (c, |b|) (Rodrigues), which stays a rotation to round-off. b's round-off (~ε) tilts k out of
 * the plane perpendicular to u by ε/|b|, so k is projected back into it: P u then stays within ~ε of v.
 * Below |b| = 1e-12 the axis is undetermined and any axis perpendicular to u does (a rotation by π, which
 * maps u to −u within 1e-12 of v). */
static inline DrVec3 transport_bc(DrVec3 u, DrVec3 b, double c, DrVec3 w)
{
    if (c > -0.5)
        return dr_v3_add(dr_v3_add(dr_v3_scale(w, c), dr_v3_cross(b, w)), dr_v3_scale(b, dr_v3_dot(b, w) / (1.0 + c)));
    b = dr_v3_sub(b, dr_v3_scale(u, dr_v3_dot(b, u)));
    double s = dr_v3_norm(b);
    DrVec3 k;
    if (s > 1e-12) {
        k = dr_v3_scale(b, 1.0 / s);
    } else {
        k = any_perpendicular(u);
        s = 0.0, c = -1.0;
    }
    return dr_v3_add(dr_v3_add(dr_v3_scale(w, c), dr_v3_scale(dr_v3_cross(k, w), s)),
                     dr_v3_scale(k, (1.0 - c) * dr_v3_dot(k, w)));
}

static inline DrVec3 transport(DrVec3 u, DrVec3 v, DrVec3 w)
{
    return transport_bc(u, dr_v3_cross(u, v), dr_v3_dot(u, v), w);
}

void dr_rod_transport(const double u[3], const double v[3], const double w[3], double out[3])
{
    st3(out, transport(ld3(u), ld3(v), ld3(w)));
}

void dr_rod_tangents(int nv, const double *x, double *t, double *len)
{
    for (int j = 0; j + 1 < nv; j++) {
        DrVec3 e = dr_v3_sub(ld3(x + 3 * (j + 1)), ld3(x + 3 * j));
        double l = dr_v3_norm(e);
        st3(t + 3 * j, l > 0.0 ? dr_v3_scale(e, 1.0 / l) : dr_v3(0, 0, 0));
        len[j] = l;
    }
}

/* The component of a perpendicular to unit t, normalised; any perpendicular unit vector when a is (nearly)
 * parallel to t. */
static DrVec3 perpendicular_unit(DrVec3 a, DrVec3 t)
{
    DrVec3 p = dr_v3_sub(a, dr_v3_scale(t, dr_v3_dot(a, t)));
    double n = dr_v3_norm(p);
    return n > 1e-12 * dr_v3_norm(a) ? dr_v3_scale(p, 1.0 / n) : any_perpendicular(t);
}

void dr_rod_space_frames(int ne, const double *t, const double *a1_root, double *a1)
{
    if (ne < 1) return;
    DrVec3 a = a1_root ? perpendicular_unit(ld3(a1_root), ld3(t)) : any_perpendicular(ld3(t));
    st3(a1, a);
    for (int j = 0; j + 1 < ne; j++) {
        DrVec3 tn = ld3(t + 3 * (j + 1));
        a = perpendicular_unit(transport(ld3(t + 3 * j), tn, a), tn); /* re-orthonormalised: no drift */
        st3(a1 + 3 * (j + 1), a);
    }
}

void dr_rod_time_transport(int ne, const double *t_old, const double *t_new, double *a1)
{
    for (int j = 0; j < ne; j++) {
        DrVec3 tn = ld3(t_new + 3 * j);
        st3(a1 + 3 * j, perpendicular_unit(transport(ld3(t_old + 3 * j), tn, ld3(a1 + 3 * j)), tn));
    }
}

/* The angle about t1 from P(t0 → t1) a1_0 to a1_1 (a2_1 = t1 × a1_1), the representative nearest to m_prev:
 * with a1_1 = cos m p + sin m (t1 × p), p·a1_1 = cos m and p·a2_1 = −sin m. */
static inline double reference_twist(DrVec3 t0, DrVec3 t1, DrVec3 a1_0, DrVec3 a1_1, DrVec3 a2_1, double m_prev)
{
    DrVec3 p = transport(t0, t1, a1_0);
    double ang = atan2(-dr_v3_dot(p, a2_1), dr_v3_dot(p, a1_1));
    return m_prev + remainder(ang - m_prev, 2.0 * DR_PI);
}

void dr_rod_reference_twist(int nv, const double *t, const double *a1, double *m)
{
    for (int i = 1; i + 1 < nv; i++) {
        DrVec3 t1 = ld3(t + 3 * i), a1_1 = ld3(a1 + 3 * i);
        m[i - 1] = reference_twist(ld3(t + 3 * (i - 1)), t1, ld3(a1 + 3 * (i - 1)), a1_1, dr_v3_cross(t1, a1_1), m[i - 1]);
    }
}

/* κb = 2 t0 × t1 / χ, χ = 1 + t0·t1; 1/χ returned through ichi. */
static inline DrVec3 curvature_binormal(DrVec3 t0, DrVec3 t1, double *ichi)
{
    *ichi = 1.0 / (1.0 + dr_v3_dot(t0, t1));
    return dr_v3_scale(dr_v3_cross(t0, t1), 2.0 * *ichi);
}

void dr_rod_curvatures(int nv, const double *t, const double *a1, const double *theta, const double *m,
                       double *kappa, double *tau)
{
    for (int i = 1; i + 1 < nv; i++) {
        double ichi;
        DrVec3 kb = curvature_binormal(ld3(t + 3 * (i - 1)), ld3(t + 3 * i), &ichi);
        for (int j = 0; j < 2; j++) {
            int e = i - 1 + j;
            DrVec3 tj = ld3(t + 3 * e), a = ld3(a1 + 3 * e), b = dr_v3_cross(tj, a);
            double c = cos(theta[e]), s = sin(theta[e]);
            DrVec3 m1 = dr_v3_add(dr_v3_scale(a, c), dr_v3_scale(b, s));
            DrVec3 m2 = dr_v3_sub(dr_v3_scale(b, c), dr_v3_scale(a, s));
            kappa[4 * (i - 1) + 2 * j] = dr_v3_dot(kb, m2);
            kappa[4 * (i - 1) + 2 * j + 1] = -dr_v3_dot(kb, m1);
        }
        tau[i - 1] = theta[i] - theta[i - 1] + m[i - 1];
    }
}

/* ---- constraint groups ---------------------------------------------------------------------------------- */

/* Per edge of a group: the reference tangent and director, and the twist's (cos θ, sin θ), which stay
 * put while the positions are differenced. */
typedef struct RodEdgeRef {
    DrVec3 tref, a1ref;
    double c, s;
} RodEdgeRef;

/* One edge of a vertex group at the current positions, its frame transported from the reference state. */
typedef struct RodEdge {
    DrVec3 e;      /* edge vector */
    DrVec3 t;      /* unit tangent */
    double l, il;  /* length and 1/length */
    DrVec3 h;      /* h = (t_ref × t)/((1 + t_ref·t) l): the frame's turning rate about t is ψ = −h·de (eq. 1) */
    DrVec3 a1, a2; /* a1 = P(t_ref → t) a1_ref, a2 = t × a1 (only when the frame is asked for) */
    DrVec3 m1, m2; /* m1 = cos θ a1 + sin θ a2, m2 = −sin θ a1 + cos θ a2 (idem) */
} RodEdge;

/* Fills E for edge vector e; the frame (a1, a2, m1, m2) only when `frame` (the twist's gradient does not
 * need it). With s = l + t_ref·e = (1 + c) l, one division r = 1/(l s) gives 1/l = r s and h = (t_ref × e) r:
 * this runs 24 times per vertex group with G, and the square root and divisions are its latency. */
static inline void rod_edge(DrVec3 e, const RodEdgeRef *R, bool frame, RodEdge *E)
{
    E->e = e;
    E->l = dr_v3_norm(e);
    double s = E->l + dr_v3_dot(R->tref, e), r = 1.0 / (E->l * s);
    E->il = r * s;
    E->t = dr_v3_scale(e, E->il);
    DrVec3 be = dr_v3_cross(R->tref, e);
    E->h = dr_v3_scale(be, r);
    if (!frame) return;
    E->a1 = transport_bc(R->tref, dr_v3_scale(be, E->il), s * E->il - 1.0, R->a1ref);
    E->a2 = dr_v3_cross(E->t, E->a1);
    E->m1 = dr_v3_add(dr_v3_scale(E->a1, R->c), dr_v3_scale(E->a2, R->s));
    E->m2 = dr_v3_sub(dr_v3_scale(E->a2, R->c), dr_v3_scale(E->a1, R->s));
}

/* The two edges of interior vertex i, with their frames. */
static inline void rod_vertex(const double *x, const double *theta, const DrRodRef *ref, int i, RodEdgeRef R[2],
                              RodEdge E[2])
{
    DrVec3 x0 = ld3(x + 3 * (i - 1)), x1 = ld3(x + 3 * i), x2 = ld3(x + 3 * (i + 1));
    for (int j = 0; j < 2; j++) {
        R[j].tref = ld3(ref->t + 3 * (i - 1 + j));
        R[j].a1ref = ld3(ref->a1 + 3 * (i - 1 + j));
        R[j].c = cos(theta[i - 1 + j]);
        R[j].s = sin(theta[i - 1 + j]);
    }
    rod_edge(dr_v3_sub(x1, x0), &R[0], true, &E[0]);
    rod_edge(dr_v3_sub(x2, x1), &R[1], true, &E[1]);
}

/* Gradients of κb·N (N held fixed) with respect to e^0 and e^1, eq. (3) with dt = (I − t tᵀ) de / l;
 * s = κb·N, ichi = 1/χ. */
static inline void kb_dot_gradient(const RodEdge *E0, const RodEdge *E1, double ichi, DrVec3 N, double s, DrVec3 g[2])
{
    DrVec3 t0 = E0->t, t1 = E1->t;
    DrVec3 g0 = dr_v3_sub(dr_v3_scale(dr_v3_cross(t1, N), 2.0), dr_v3_scale(t1, s));
    DrVec3 g1 = dr_v3_sub(dr_v3_scale(dr_v3_cross(N, t0), 2.0), dr_v3_scale(t0, s));
    g[0] = dr_v3_scale(dr_v3_sub(g0, dr_v3_scale(t0, dr_v3_dot(t0, g0))), ichi * E0->il);
    g[1] = dr_v3_scale(dr_v3_sub(g1, dr_v3_scale(t1, dr_v3_dot(t1, g1))), ichi * E1->il);
}

/* Σ_k λ_k ∂φ_k/∂e for the bending rows (4 λ) or the twist row (1 λ), the quantity differenced for G. */
typedef enum RodKind { ROD_BEND, ROD_TWIST } RodKind;

static inline void weighted_edge_gradient(RodKind kind, const RodEdge *E0, const RodEdge *E1, const double *lambda,
                                          DrVec3 g[2])
{
    double ichi;
    DrVec3 kb = curvature_binormal(E0->t, E1->t, &ichi);
    if (kind == ROD_TWIST) { /* eq. (2): κb ⟂ t^j, so κb·dt^j = κb·de^j / l_j */
        g[0] = dr_v3_scale(dr_v3_add(dr_v3_scale(kb, 0.5 * E0->il), E0->h), lambda[0]);
        g[1] = dr_v3_scale(dr_v3_sub(dr_v3_scale(kb, 0.5 * E1->il), E1->h), lambda[0]);
        return;
    }
    /* Σ_j λ1^j κ1^j + λ2^j κ2^j = κb·N with N = Σ_j (λ1^j m2^j − λ2^j m1^j), plus the frames' turning
       c^j ψ^j with c^j = λ1^j κ2^j − λ2^j κ1^j */
    const RodEdge *E[2] = {E0, E1};
    DrVec3 N = dr_v3(0, 0, 0);
    double c[2];
    for (int j = 0; j < 2; j++) {
        double k1 = dr_v3_dot(kb, E[j]->m2), k2 = -dr_v3_dot(kb, E[j]->m1);
        N = dr_v3_add(N, dr_v3_sub(dr_v3_scale(E[j]->m2, lambda[2 * j]), dr_v3_scale(E[j]->m1, lambda[2 * j + 1])));
        c[j] = lambda[2 * j] * k2 - lambda[2 * j + 1] * k1;
    }
    kb_dot_gradient(E0, E1, ichi, N, dr_v3_dot(kb, N), g);
    for (int j = 0; j < 2; j++) g[j] = dr_v3_sub(g[j], dr_v3_scale(E[j]->h, c[j]));
}

/* Writes the positional part of a row from its edge gradients: x_{i−1}: −g^0, x_i: g^0 − g^1, x_{i+1}: g^1. */
static inline void spread_row(const DrVec3 g[2], double *row)
{
    st3(row + ROD_X0, dr_v3_scale(g[0], -1.0));
    st3(row + ROD_X1, dr_v3_sub(g[0], g[1]));
    st3(row + ROD_X2, g[1]);
}

/* The position block of G: central differences of the weighted edge gradient in edge space (each
 * re-evaluates the perturbed edge only), symmetrised, then spread to the vertices, G_x = Dᵀ G_e D with
 * e^0 = x_i − x_{i−1}, e^1 = x_{i+1} − x_i. The step actually taken, (e + h) − (e − h), is the one divided
 * by. Leaves the twist rows and columns alone. */
static void position_hessian(RodKind kind, const RodEdge E[2], const RodEdgeRef R[2], const double *lambda, double *G)
{
    double Ge[6][6];
    for (int a = 0; a < 2; a++) {
        double h = ROD_FD_REL * E[a].l;
        for (int k = 0; k < 3; k++) {
            double ep[3], em[3];
            st3(ep, E[a].e), st3(em, E[a].e);
            ep[k] += h, em[k] -= h;
            double step = ep[k] - em[k];
            RodEdge P, M;
            rod_edge(ld3(ep), &R[a], kind == ROD_BEND, &P);
            rod_edge(ld3(em), &R[a], kind == ROD_BEND, &M);
            DrVec3 gp[2], gm[2];
            weighted_edge_gradient(kind, a == 0 ? &P : &E[0], a == 1 ? &P : &E[1], lambda, gp);
            weighted_edge_gradient(kind, a == 0 ? &M : &E[0], a == 1 ? &M : &E[1], lambda, gm);
            for (int b = 0; b < 2; b++) {
                Ge[3 * b][3 * a + k] = (gp[b].x - gm[b].x) / step;
                Ge[3 * b + 1][3 * a + k] = (gp[b].y - gm[b].y) / step;
                Ge[3 * b + 2][3 * a + k] = (gp[b].z - gm[b].z) / step;
            }
        }
    }
    for (int r = 0; r < 6; r++)
        for (int c = r + 1; c < 6; c++) Ge[r][c] = Ge[c][r] = 0.5 * (Ge[r][c] + Ge[c][r]);
    /* blocks A = ∂²/∂e⁰∂e⁰, B = ∂²/∂e⁰∂e¹, C = Bᵀ, D = ∂²/∂e¹∂e¹; each entry is formed so that its mirror
       is the same operation on the same operands, which keeps G exactly symmetric */
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double A = Ge[r][c], B = Ge[r][3 + c], C = Ge[3 + r][c], D = Ge[3 + r][3 + c];
            double *g0 = G + (ROD_X0 + r) * ROD_NDOF, *g1 = G + (ROD_X1 + r) * ROD_NDOF, *g2 = G + (ROD_X2 + r) * ROD_NDOF;
            g0[ROD_X0 + c] = A;
            g0[ROD_X1 + c] = B - A;
            g0[ROD_X2 + c] = -B;
            g1[ROD_X0 + c] = C - A;
            g1[ROD_X1 + c] = (A + D) - (B + C);
            g1[ROD_X2 + c] = B - D;
            g2[ROD_X0 + c] = -C;
            g2[ROD_X1 + c] = C - D;
            g2[ROD_X2 + c] = D;
        }
}

static void group_header(int i, int dof0, int nrows, const double *lambda, double *G, DrLagGroup *g)
{
    g->kind = DR_LAG_POSITIONAL;
    g->nrows = nrows;
    g->ndof = ROD_NDOF;
    for (int k = 0; k < ROD_NDOF; k++) g->dof[k] = dof0 + 4 * (i - 1) + k;
    g->G = (lambda && G) ? G : NULL;
    g->lambda = NULL;
}

void dr_rod_stretch_group(const double *x, int j, double lbar, double ks, int dof0, const double *lambda,
                          double *G, DrLagGroup *g)
{
    assert(lbar > 0.0 && g);
    DrVec3 e = dr_v3_sub(ld3(x + 3 * (j + 1)), ld3(x + 3 * j));
    double l = dr_v3_norm(e);
    DrVec3 t = dr_v3_scale(e, 1.0 / l);
    g->kind = DR_LAG_POSITIONAL;
    g->nrows = 1;
    g->ndof = 6;
    for (int k = 0; k < 3; k++) g->dof[k] = dof0 + 4 * j + k, g->dof[3 + k] = dof0 + 4 * j + 4 + k;
    g->phi[0] = l - lbar;
    g->cinv[0] = ks / lbar;
    st3(g->J, dr_v3_scale(t, -1.0)); /* ∂l/∂x_j = −t, ∂l/∂x_{j+1} = t */
    st3(g->J + 3, t);
    g->lambda = NULL;
    g->G = NULL;
    if (!(lambda && G)) return;
    double tt[3] = {t.x, t.y, t.z}, s = lambda[0] / l;
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double v = s * ((r == c ? 1.0 : 0.0) - tt[r] * tt[c]); /* ∇²l = ±(I − t tᵀ)/l */
            G[r * 6 + c] = G[(r + 3) * 6 + c + 3] = v;
            G[r * 6 + c + 3] = G[(r + 3) * 6 + c] = -v;
        }
    g->G = G;
}

void dr_rod_bend_group(const double *x, const double *theta, const DrRodRef *ref, int i, const double *kappa_bar,
                       double lv, double bend, int dof0, const double *lambda, double *G, DrLagGroup *g)
{
    assert(i >= 1 && lv > 0.0 && g);
    RodEdgeRef R[2];
    RodEdge E[2];
    rod_vertex(x, theta, ref, i, R, E);
    group_header(i, dof0, 4, lambda, G, g);
    double ichi;
    DrVec3 kb = curvature_binormal(E[0].t, E[1].t, &ichi);
    static const int T[2] = {ROD_T0, ROD_T1};
    for (int j = 0; j < 2; j++) {
        DrVec3 gr[2];
        double k1 = dr_v3_dot(kb, E[j].m2), k2 = -dr_v3_dot(kb, E[j].m1);
        double *r1 = g->J + (2 * j) * ROD_NDOF, *r2 = r1 + ROD_NDOF;
        g->phi[2 * j] = k1 - kappa_bar[2 * j];
        g->phi[2 * j + 1] = k2 - kappa_bar[2 * j + 1];
        g->cinv[2 * j] = g->cinv[2 * j + 1] = bend / (2.0 * lv);
        /* κ1^j: d(κb·m2) + κ2^j (ψ^j + dθ^j) */
        kb_dot_gradient(&E[0], &E[1], ichi, E[j].m2, k1, gr);
        gr[j] = dr_v3_sub(gr[j], dr_v3_scale(E[j].h, k2));
        spread_row(gr, r1);
        r1[T[j]] = k2;
        r1[T[1 - j]] = 0.0;
        /* κ2^j: −d(κb·m1) − κ1^j (ψ^j + dθ^j) */
        kb_dot_gradient(&E[0], &E[1], ichi, dr_v3_scale(E[j].m1, -1.0), k2, gr);
        gr[j] = dr_v3_add(gr[j], dr_v3_scale(E[j].h, k1));
        spread_row(gr, r2);
        r2[T[j]] = -k1;
        r2[T[1 - j]] = 0.0;
    }
    if (!(lambda && G)) return;
    position_hessian(ROD_BEND, E, R, lambda, G);
    /* twist rows and columns, exact: ∂(Σ λ ∇φ)/∂θ^j = λ_{κ1^j} ∇κ2^j − λ_{κ2^j} ∇κ1^j */
    for (int j = 0; j < 2; j++) {
        const double *r1 = g->J + (2 * j) * ROD_NDOF, *r2 = r1 + ROD_NDOF;
        for (int c = 0; c < ROD_NDOF; c++) {
            double v = lambda[2 * j] * r2[c] - lambda[2 * j + 1] * r1[c];
            G[T[j] * ROD_NDOF + c] = G[c * ROD_NDOF + T[j]] = v;
        }
    }
}

void dr_rod_twist_group(const double *x, const double *theta, const DrRodRef *ref, int i, double tau_bar,
                        double lv, double twist, int dof0, const double *lambda, double *G, DrLagGroup *g)
{
    assert(i >= 1 && lv > 0.0 && g);
    RodEdgeRef R[2];
    RodEdge E[2];
    rod_vertex(x, theta, ref, i, R, E);
    group_header(i, dof0, 1, lambda, G, g);
    double m = reference_twist(E[0].t, E[1].t, E[0].a1, E[1].a1, E[1].a2, ref->m[i - 1]);
    g->phi[0] = theta[i] - theta[i - 1] + m - tau_bar;
    g->cinv[0] = twist / lv;
    DrVec3 gr[2];
    const double one = 1.0;
    weighted_edge_gradient(ROD_TWIST, &E[0], &E[1], &one, gr);
    spread_row(gr, g->J);
    g->J[ROD_T0] = -1.0;
    g->J[ROD_T1] = 1.0;
    if (!(lambda && G)) return;
    position_hessian(ROD_TWIST, E, R, lambda, G);
    for (int c = 0; c < ROD_NDOF; c++) /* τ is linear in the twists */
        G[ROD_T0 * ROD_NDOF + c] = G[c * ROD_NDOF + ROD_T0] = G[ROD_T1 * ROD_NDOF + c] = G[c * ROD_NDOF + ROD_T1] = 0.0;
}

/* The energy with the stiffnesses read at ks[j·sks], bend[(i − 1)·sb], twist[(i − 1)·st]: stride 0 for one value. */
static double energy(int nv, const double *x, const double *theta, const DrRodRef *ref, const double *lbar,
                     const double *kappa_bar, const double *tau_bar, const double *ks, int sks, const double *bend,
                     int sb, const double *twist, int st)
{
    double E = 0.0;
    for (int j = 0; j + 1 < nv; j++) {
        double d = dr_v3_norm(dr_v3_sub(ld3(x + 3 * (j + 1)), ld3(x + 3 * j))) - lbar[j];
        E += 0.5 * ks[j * sks] * d * d / lbar[j];
    }
    for (int i = 1; i + 1 < nv; i++) {
        RodEdgeRef R[2];
        RodEdge V[2];
        rod_vertex(x, theta, ref, i, R, V);
        double lv = 0.5 * (lbar[i - 1] + lbar[i]), ichi;
        DrVec3 kb = curvature_binormal(V[0].t, V[1].t, &ichi);
        double sum = 0.0;
        for (int j = 0; j < 2; j++) {
            double d1 = dr_v3_dot(kb, V[j].m2) - kappa_bar[4 * (i - 1) + 2 * j];
            double d2 = -dr_v3_dot(kb, V[j].m1) - kappa_bar[4 * (i - 1) + 2 * j + 1];
            sum += d1 * d1 + d2 * d2;
        }
        double m = reference_twist(V[0].t, V[1].t, V[0].a1, V[1].a1, V[1].a2, ref->m[i - 1]);
        double dt = theta[i] - theta[i - 1] + m - tau_bar[i - 1];
        E += bend[(i - 1) * sb] * sum / (4.0 * lv) + twist[(i - 1) * st] * dt * dt / (2.0 * lv);
    }
    return E;
}

double dr_rod_energy(int nv, const double *x, const double *theta, const DrRodRef *ref, const double *lbar,
                     const double *kappa_bar, const double *tau_bar, DrRodStiffness k)
{
    return energy(nv, x, theta, ref, lbar, kappa_bar, tau_bar, &k.ks, 0, &k.bend, 0, &k.twist, 0);
}

double dr_rod_energy_varying(int nv, const double *x, const double *theta, const DrRodRef *ref, const double *lbar,
                             const double *kappa_bar, const double *tau_bar, const double *ks, const double *bend,
                             const double *twist)
{
    return energy(nv, x, theta, ref, lbar, kappa_bar, tau_bar, ks, 1, bend, 1, twist, 1);
}
