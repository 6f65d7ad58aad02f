/* Vertex–triangle self contact of a cloth panel (self_contact.h). */
#include "cloth/self_contact.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact.h"
#include "core/sort.h"

/* How far outside its triangle a vertex's projection may fall and still count, beyond the thickness (in barycentric
   coordinates): a vertex over the edge two triangles share must not slip between them by round-off. */
#define BARY_SLACK 1e-9

typedef struct SelfContact {
    int v, t;      /* the vertex and the triangle (mesh indices) */
    double b[3];   /* barycentric coordinates of the triangle's point, fixed for the step */
    double n[3];   /* unit normal at the step's start, towards the vertex's side */
    double phi;    /* φ at the step's start, m */
    double lambda; /* the solver's multiplier, N (positive pushes apart) */
    double inside; /* how far inside the triangle the vertex's projection lies, m (negative: outside) */
} SelfContact;

struct DrClothSelf {
    DrClothSelfPanel p;
    DrBroadPhase *bp;
    SelfContact *c, *tmp; /* cap each: the contacts, the sort's scratch */
    int n, cap;
    int *head, *next;     /* V and cap: each vertex's contacts as a list (keep_nearest) */
    double *reach;        /* V: the travel allowance of the last broad-phase query, m (candidates) */
    const DrBroadPair *pairs; /* that query's pairs (the broad phase's storage) */
    long npairs;
};

DrStatus dr_cloth_self_create(const DrClothSelfPanel *panel, DrClothSelf **out, DrError *err)
{
    *out = NULL;
    DrClothSelf *s = NULL;
    DR_TRY(dr_calloc(1, sizeof *s, &s, err));
    s->p = *panel;
    int V = panel->V, T = panel->T;
    /* room for a contact per vertex, and for every box in at most 8 cells (a box no larger than a cell) */
    s->cap = V > 0 ? V : 1;
    DrStatus st = dr_calloc((size_t)s->cap, sizeof *s->c, &s->c, err);
    if (st == DR_OK) st = dr_calloc((size_t)s->cap, sizeof *s->tmp, &s->tmp, err);
    if (st == DR_OK) st = dr_calloc((size_t)s->cap, sizeof(int), &s->next, err);
    if (st == DR_OK) st = dr_calloc((size_t)(V > 0 ? V : 1), sizeof(int), &s->head, err);
    if (st == DR_OK) st = dr_calloc((size_t)(V > 0 ? V : 1), sizeof(double), &s->reach, err);
    if (st == DR_OK) st = dr_broad_phase_create(&s->bp, err);
    if (st == DR_OK) st = dr_broad_phase_reserve(s->bp, V + T, 8 * ((size_t)V + (size_t)T), err);
    if (st != DR_OK) {
        dr_cloth_self_destroy(&s);
        return st;
    }
    *out = s;
    return DR_OK;
}

void dr_cloth_self_destroy(DrClothSelf **sp)
{
    if (!sp || !*sp) return;
    DrClothSelf *s = *sp;
    dr_broad_phase_destroy(&s->bp);
    free(s->c);
    free(s->tmp);
    free(s->head);
    free(s->reach);
    free(s->next);
    free(s);
    *sp = NULL;
}

int dr_cloth_self_count(const DrClothSelf *s) { return s->n; }

/* ---- geometry ----------------------------------------------------------------------------------------------------- */

static inline void sub3(const double *a, const double *b, double *o)
{
    o[0] = a[0] - b[0], o[1] = a[1] - b[1], o[2] = a[2] - b[2];
}
static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static inline void cross3(const double *a, const double *b, double *o)
{
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

/* The unit normal n of triangle (a, b, c) and the barycentric coordinates of p's projection on its plane, clamped to
   the triangle and renormalised: β_a = n·((b − p) × (c − p))/|N| (the component of p − p' along n drops out of the
   triple product), N = (b − a) × (c − a). β_k |N|/|e_k| is the projection's distance inside the edge e_k opposite
   vertex k: a projection outside an edge by up to `reach` (m) counts, so that a vertex over another layer's free edge,
   or over a vertex of it, is held by the triangles there. False for a degenerate triangle (|N| below 1e-12 of its
   longest edge squared) or a projection farther out. */
static bool project(const double *p, const double *a, const double *b, const double *c, double reach, double n[3],
                    double bary[3], double *inside)
{
    double ab[3], ac[3], bc[3], N[3];
    sub3(b, a, ab);
    sub3(c, a, ac);
    sub3(c, b, bc);
    cross3(ab, ac, N);
    double area2 = sqrt(dot3(N, N));
    double len[3] = {sqrt(dot3(bc, bc)), sqrt(dot3(ac, ac)), sqrt(dot3(ab, ab))}; /* opposite a, b, c */
    double lmax = fmax(len[0], fmax(len[1], len[2]));
    if (!(area2 > 1e-12 * lmax * lmax)) return false;
    for (int k = 0; k < 3; k++) n[k] = N[k] / area2;
    const double *q[3] = {a, b, c};
    double sum = 0;
    *inside = INFINITY;
    for (int k = 0; k < 3; k++) {
        double u[3], w[3], x[3];
        sub3(q[(k + 1) % 3], p, u);
        sub3(q[(k + 2) % 3], p, w);
        cross3(u, w, x);
        bary[k] = dot3(n, x) / area2;
        if (!(bary[k] >= -BARY_SLACK - reach * len[k] / area2)) return false;
        *inside = fmin(*inside, bary[k] * area2 / len[k]);
        bary[k] = fmax(bary[k], 0.0);
        sum += bary[k];
    }
    if (!(sum > 0)) return false;
    for (int k = 0; k < 3; k++) bary[k] /= sum;
    return true;
}

/* Squared distance from p to the triangle (a, b, c) (its closest point, by Ericson's regions). */
static double triangle_dist2(const double *p, const double *a, const double *b, const double *c)
{
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    sub3(b, a, ab), sub3(c, a, ac), sub3(p, a, ap);
    double d1 = dot3(ab, ap), d2 = dot3(ac, ap);
    double q[3];
    if (d1 <= 0 && d2 <= 0) {
        memcpy(q, a, sizeof q);
    } else {
        sub3(p, b, bp);
        double d3 = dot3(ab, bp), d4 = dot3(ac, bp);
        sub3(p, c, cp);
        double d5 = dot3(ab, cp), d6 = dot3(ac, cp);
        double vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
        if (d3 >= 0 && d4 <= d3) {
            memcpy(q, b, sizeof q);
        } else if (d6 >= 0 && d5 <= d6) {
            memcpy(q, c, sizeof q);
        } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
            double t = d1 / (d1 - d3);
            for (int k = 0; k < 3; k++) q[k] = a[k] + t * ab[k];
        } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
            double t = d2 / (d2 - d6);
            for (int k = 0; k < 3; k++) q[k] = a[k] + t * ac[k];
        } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
            double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
            for (int k = 0; k < 3; k++) q[k] = b[k] + t * (c[k] - b[k]);
        } else {
            double den = 1.0 / (va + vb + vc), v = vb * den, w = vc * den;
            for (int k = 0; k < 3; k++) q[k] = a[k] + v * ab[k] + w * ac[k];
        }
    }
    double d[3];
    sub3(p, q, d);
    return dot3(d, d);
}

/* ---- candidates ---------------------------------------------------------------------------------------------------- */

/* The broad phase's pairs of a vertex box (x_v inflated by thickness + r_v) and a triangle box (its vertices' box
   inflated by the largest r_i of its vertices), r_v = 1.5 h|u_v| + thickness the distance vertex v is allowed to travel
   in the step at velocity u (ux: 3V, mesh order; or, when ux is NULL, the DOF velocities qdot). The allowance exceeds
   the travel at u so that the solves of the step, whose velocities differ from the step's start by the step's forces,
   mostly stay within it and reuse these pairs (dr_cloth_self_update). Cells as large as the largest box, so a box
   meets at most 8 cells. The pairs stay in s (pairs, npairs) until the next query. */
static DrStatus candidates(DrClothSelf *s, double h, const double *x, const double *ux, const double *qdot,
                           DrError *err)
{
    const DrClothSelfPanel *p = &s->p;
    dr_broad_phase_clear(s->bp);
    double cell = 0;
    for (int v = 0; v < p->V; v++) {
        const double *u = ux ? ux + 3 * v : qdot + p->dof0 + 3 * p->rank[v];
        s->reach[v] = 1.5 * h * sqrt(dot3(u, u)) + p->thickness;
        double pad = p->thickness + s->reach[v];
        const double *q = x + 3 * v;
        DR_TRY(dr_broad_phase_add(s->bp, dr_v3(q[0] - pad, q[1] - pad, q[2] - pad),
                                  dr_v3(q[0] + pad, q[1] + pad, q[2] + pad), err));
        cell = fmax(cell, 2 * pad);
    }
    for (int t = 0; t < p->T; t++) {
        const int *tv = p->tri + 3 * t;
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY}, pad = 0;
        for (int k = 0; k < 3; k++) {
            const double *q = x + 3 * tv[k];
            pad = fmax(pad, s->reach[tv[k]]);
            for (int a = 0; a < 3; a++) {
                lo[a] = fmin(lo[a], q[a]);
                hi[a] = fmax(hi[a], q[a]);
            }
        }
        for (int a = 0; a < 3; a++) {
            lo[a] -= pad;
            hi[a] += pad;
            cell = fmax(cell, hi[a] - lo[a]);
        }
        DR_TRY(dr_broad_phase_add(s->bp, dr_v3(lo[0], lo[1], lo[2]), dr_v3(hi[0], hi[1], hi[2]), err));
    }
    if (!(cell > 0)) cell = 1.0; /* every box a point: any cell */
    return dr_broad_phase_pairs_across(s->bp, cell, p->V, &s->pairs, &s->npairs, err);
}

/* Whether every vertex's travel at the DOF velocities qdot stays within the allowance of the last query: its pairs
   then hold every pair these velocities can bring together. */
static bool within_reach(const DrClothSelf *s, double h, const double *qdot)
{
    const DrClothSelfPanel *p = &s->p;
    for (int v = 0; v < p->V; v++) {
        const double *u = qdot + p->dof0 + 3 * p->rank[v];
        if (!(h * sqrt(dot3(u, u)) <= s->reach[v])) return false;
    }
    return true;
}

/* Whether pair (v, t) may touch at all: v not a vertex of t, and not all four vertices pinned. */
static bool pair_allowed(const DrClothSelfPanel *p, int v, int t)
{
    const int *tv = p->tri + 3 * t;
    if (tv[0] == v || tv[1] == v || tv[2] == v) return false;
    if (p->pinned[v] && p->pinned[tv[0]] && p->pinned[tv[1]] && p->pinned[tv[2]]) return false;
    return true;
}

/* Whether v is farther from t than the thickness in the rest shape (else the pair never touches; self_contact.h). */
static bool rest_apart(const DrClothSelfPanel *p, int v, int t)
{
    const int *tv = p->tri + 3 * t;
    double d2 = triangle_dist2(p->rest + 3 * v, p->rest + 3 * tv[0], p->rest + 3 * tv[1], p->rest + 3 * tv[2]);
    return d2 > p->thickness * p->thickness;
}

static DrStatus push_contact(DrClothSelf *s, const SelfContact *c, DrError *err)
{
    if (s->n == s->cap) { /* doubled and kept */
        int cap = 2 * s->cap;
        DR_TRY(dr_realloc((size_t)cap, sizeof *s->c, &s->c, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof *s->tmp, &s->tmp, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof(int), &s->next, err));
        s->cap = cap;
    }
    s->c[s->n++] = *c;
    return DR_OK;
}

/* n·(x_v − Σ b_i x_i) for positions x (3V) */
static double gap(const DrClothSelfPanel *p, const SelfContact *c, const double *x)
{
    const int *tv = p->tri + 3 * c->t;
    double d = 0;
    for (int a = 0; a < 3; a++)
        d += c->n[a] * (x[3 * c->v + a] - c->b[0] * x[3 * tv[0] + a] - c->b[1] * x[3 * tv[1] + a] -
                        c->b[2] * x[3 * tv[2] + a]);
    return d;
}

/* Whether triangle t and the triangle with vertices tv share a vertex (or are the same). */
static bool shares_vertex(const DrClothSelfPanel *p, int t, const int tv[3])
{
    const int *a = p->tri + 3 * t;
    for (int i = 0; i < 3; i++)
        if (a[i] == tv[0] || a[i] == tv[1] || a[i] == tv[2]) return true;
    return false;
}

/* Whether vertex v holds a contact (in head/next) on a triangle that shares a vertex with triangle t. */
static bool held_near(const DrClothSelf *s, int v, int t)
{
    const int *tv = s->p.tri + 3 * t;
    for (int j = s->head[v]; j >= 0; j = s->next[j])
        if (shares_vertex(&s->p, s->c[j].t, tv)) return true;
    return false;
}

static inline bool contact_less(const SelfContact *a, const SelfContact *b)
{
    if (a->v != b->v) return a->v < b->v;
    if (a->inside != b->inside) return a->inside > b->inside;
    return a->t < b->t;
}
DR_DEFINE_STABLE_SORT(contacts_sort, SelfContact, contact_less)

/* One contact per vertex and patch of the other layer: the candidates [first, n) sorted by vertex, the triangle whose
   interior the vertex's projection is deepest in first, each kept unless its vertex already holds a contact (listed in
   head/next, or kept here) on a triangle that shares a vertex with its own. Without it a vertex over a vertex of the
   other layer (a sheet folded onto itself puts every vertex there) is held by all six triangles round it, six times
   the stiffness, and the active-set passes catch them one at a time. head/next list [0, first) on entry, [0, n) on
   return. */
static void keep_nearest(DrClothSelf *s, int first)
{
    contacts_sort(s->c + first, s->tmp, (size_t)(s->n - first));
    int kept = first;
    for (int k = first; k < s->n; k++) {
        SelfContact c = s->c[k];
        if (held_near(s, c.v, c.t)) continue;
        s->c[kept] = c;
        s->next[kept] = s->head[c.v];
        s->head[c.v] = kept;
        kept++;
    }
    s->n = kept;
}

/* ---- the step ------------------------------------------------------------------------------------------------------ */

/* A contact when v is within the thickness of t's plane, or would come within it at the relative velocity of the step's
   start (the collider contacts' rule, cloth.c detect_contacts). */
DrStatus dr_cloth_self_detect(DrClothSelf *s, double h, const double *x, const double *v, DrError *err)
{
    const DrClothSelfPanel *p = &s->p;
    s->n = 0;
    DR_TRY(candidates(s, h, x, v, NULL, err));
    const DrBroadPair *pairs = s->pairs;
    for (long k = 0; k < s->npairs; k++) {
        int vi = pairs[k].a, t = pairs[k].b - p->V;
        if (!pair_allowed(p, vi, t)) continue;
        const int *tv = p->tri + 3 * t;
        SelfContact c = {.v = vi, .t = t};
        if (!project(x + 3 * vi, x + 3 * tv[0], x + 3 * tv[1], x + 3 * tv[2], p->thickness, c.n, c.b, &c.inside))
            continue;
        double side = gap(p, &c, x);
        if (side < 0)
            for (int a = 0; a < 3; a++) c.n[a] = -c.n[a];
        double vrel = 0;
        for (int a = 0; a < 3; a++)
            vrel += c.n[a] * (v[3 * vi + a] - c.b[0] * v[3 * tv[0] + a] - c.b[1] * v[3 * tv[1] + a] -
                              c.b[2] * v[3 * tv[2] + a]);
        c.phi = fabs(side) - p->thickness;
        if (c.phi + fmin(h * vrel, 0.0) >= 0) continue;
        if (!rest_apart(p, vi, t)) continue;
        DR_TRY(push_contact(s, &c, err));
    }
    for (int k = 0; k < p->V; k++) s->head[k] = -1;
    keep_nearest(s, 0);
    return DR_OK;
}

/* φ + h J q̇₊: the contact's φ at the step's end for DOF velocities qdot */
static double phi_end(const DrClothSelfPanel *p, const SelfContact *c, double h, const double *qdot)
{
    const int *tv = p->tri + 3 * c->t;
    const double *w[4] = {qdot + p->dof0 + 3 * p->rank[c->v], qdot + p->dof0 + 3 * p->rank[tv[0]],
                          qdot + p->dof0 + 3 * p->rank[tv[1]], qdot + p->dof0 + 3 * p->rank[tv[2]]};
    double d = 0;
    for (int a = 0; a < 3; a++) d += c->n[a] * (w[0][a] - c->b[0] * w[1][a] - c->b[1] * w[2][a] - c->b[2] * w[3][a]);
    return c->phi + h * d;
}

/* The collider contacts' rule (cloth.c update_contacts): release after the first solve only, then only add, so the set
   settles. A new pair is placed by v's projection at the step's end, x* = x + h q̇₊ (over the triangle there), and
   linearised at the step's start with the triangle's normal then, turned towards v's side then: it is a contact when
   v ends within the thickness of the triangle on that side or beyond it, and v holds no contact on a triangle next to
   it (keep_nearest). */
DrStatus dr_cloth_self_update(DrClothSelf *s, double h, const double *x, const double *qdot, bool release,
                              bool *changed, unsigned char *touch, DrError *err)
{
    const DrClothSelfPanel *p = &s->p;
    *changed = false;
    if (release) {
        int kept = 0;
        for (int k = 0; k < s->n; k++) {
            if (-p->stiffness * phi_end(p, &s->c[k], h, qdot) < 0) continue;
            s->c[kept++] = s->c[k];
        }
        *changed = kept != s->n;
        s->n = kept;
    }
    for (int v = 0; v < p->V; v++) s->head[v] = -1;
    for (int k = s->n - 1; k >= 0; k--) {
        s->next[k] = s->head[s->c[k].v];
        s->head[s->c[k].v] = k;
    }
    int first = s->n;
    if (!within_reach(s, h, qdot)) DR_TRY(candidates(s, h, x, NULL, qdot, err));
    const DrBroadPair *pairs = s->pairs;
    for (long k = 0; k < s->npairs; k++) {
        int vi = pairs[k].a, t = pairs[k].b - p->V;
        if (!pair_allowed(p, vi, t)) continue;
        if (held_near(s, vi, t)) continue;
        const int *tv = p->tri + 3 * t;
        int vs[4] = {vi, tv[0], tv[1], tv[2]};
        double xe[12], xs[12];
        for (int q = 0; q < 4; q++) {
            const double *w = qdot + p->dof0 + 3 * p->rank[vs[q]];
            for (int a = 0; a < 3; a++) {
                xs[3 * q + a] = x[3 * vs[q] + a];
                xe[3 * q + a] = xs[3 * q + a] + h * w[a];
            }
        }
        SelfContact c = {.v = vi, .t = t};
        double nend[3];
        if (!project(xe, xe + 3, xe + 6, xe + 9, p->thickness, nend, c.b, &c.inside)) continue;
        /* the normal at the start */
        double e1[3], e2[3], N[3];
        sub3(xs + 6, xs + 3, e1);
        sub3(xs + 9, xs + 3, e2);
        cross3(e1, e2, N);
        double len = sqrt(dot3(N, N));
        if (!(len > 0)) continue;
        double side = 0, end = 0;
        for (int a = 0; a < 3; a++) {
            c.n[a] = N[a] / len;
            side += c.n[a] * (xs[a] - c.b[0] * xs[3 + a] - c.b[1] * xs[6 + a] - c.b[2] * xs[9 + a]);
            end += c.n[a] * (xe[a] - c.b[0] * xe[3 + a] - c.b[1] * xe[6 + a] - c.b[2] * xe[9 + a]);
        }
        if (side < 0) {
            for (int a = 0; a < 3; a++) c.n[a] = -c.n[a];
            side = -side, end = -end;
        }
        if (end >= p->thickness) continue;
        if (!rest_apart(p, vi, t)) continue;
        c.phi = side - p->thickness;
        DR_TRY(push_contact(s, &c, err));
    }
    keep_nearest(s, first);
    *changed = *changed || s->n > first;
    memset(touch, 0, (size_t)p->V);
    for (int k = 0; k < s->n; k++) {
        const int *tv = p->tri + 3 * s->c[k].t;
        unsigned char mark = k >= first ? 2 : 1;
        touch[s->c[k].v] = touch[s->c[k].v] > mark ? touch[s->c[k].v] : mark;
        for (int q = 0; q < 3; q++) touch[tv[q]] = touch[tv[q]] > mark ? touch[tv[q]] : mark;
    }
    return DR_OK;
}

DrStatus dr_cloth_self_add(DrClothSelf *s, DrLag *lag, DrError *err)
{
    const DrClothSelfPanel *p = &s->p;
    for (int k = 0; k < s->n; k++) {
        SelfContact *c = &s->c[k];
        const int *tv = p->tri + 3 * c->t;
        int vs[4] = {c->v, tv[0], tv[1], tv[2]};
        double w[4] = {1.0, -c->b[0], -c->b[1], -c->b[2]};
        DrLagGroup g;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 12;
        int rlo = p->rank[vs[0]], rhi = rlo;
        for (int q = 0; q < 4; q++) {
            int r = p->rank[vs[q]];
            rlo = r < rlo ? r : rlo;
            rhi = r > rhi ? r : rhi;
            for (int a = 0; a < 3; a++) {
                g.dof[3 * q + a] = p->dof0 + 3 * r + a;
                g.J[3 * q + a] = w[q] * c->n[a];
            }
        }
        g.phi[0] = c->phi;
        g.cinv[0] = p->stiffness;
        c->lambda = 0;
        g.lambda = &c->lambda;
        bool in_band = rhi - rlo <= p->band;
        if (in_band) DR_TRY(dr_lag_add(lag, &g, err));
        else DR_TRY(dr_lag_add_global(lag, &g, err));
        if (!(p->damping > 0)) continue;
        DrLagGroup d = g; /* the dashpot beside the contact's spring */
        d.kind = DR_LAG_VISCOUS;
        d.phi[0] = 0;
        d.cinv[0] = p->damping * p->stiffness;
        d.lambda = NULL;
        if (in_band) DR_TRY(dr_lag_add(lag, &d, err));
        else DR_TRY(dr_lag_add_global(lag, &d, err));
    }
    return DR_OK;
}

/* The impulse P along the relative tangential velocity's direction changes that velocity by P W, W = 1/m_v + Σ b_i²/m_i
   (pinned vertices weigh nothing here): P = min(|v_t|/W, μ λ h) stops the sliding or spends the Coulomb bound. */
void dr_cloth_self_friction(const DrClothSelf *s, double h, double *v)
{
    const DrClothSelfPanel *p = &s->p;
    if (!(p->friction > 0)) return;
    for (int k = 0; k < s->n; k++) {
        const SelfContact *c = &s->c[k];
        if (!(c->lambda > 0)) continue;
        const int *tv = p->tri + 3 * c->t;
        int vs[4] = {c->v, tv[0], tv[1], tv[2]};
        double w[4] = {1.0, -c->b[0], -c->b[1], -c->b[2]}, im[4];
        double rel[3] = {0, 0, 0}, W = 0;
        for (int q = 0; q < 4; q++) {
            im[q] = p->pinned[vs[q]] ? 0.0 : 1.0 / p->mass[vs[q]];
            W += w[q] * w[q] * im[q];
            for (int a = 0; a < 3; a++) rel[a] += w[q] * v[3 * vs[q] + a];
        }
        double vn = dot3(rel, c->n);
        double vt[3] = {rel[0] - vn * c->n[0], rel[1] - vn * c->n[1], rel[2] - vn * c->n[2]};
        double vtn = sqrt(dot3(vt, vt));
        if (!(vtn > 0) || !(W > 0)) continue;
        double P = fmin(vtn / W, p->friction * c->lambda * h);
        for (int q = 0; q < 4; q++)
            for (int a = 0; a < 3; a++) v[3 * vs[q] + a] -= P * w[q] * im[q] * vt[a] / vtn;
    }
}
