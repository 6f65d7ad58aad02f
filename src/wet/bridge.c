/* Liquid bridges between wet strands and between wet strands and colliders, and the film's flow across them (see
 * wet.h; fei2017 §S1, eq. S28, §S5; PHYSICS §5).
 *
 * One update, in order:
 *   1. each vertex's Voronoi length l, film area A = V/l and outer radius H = √(r² + A/π);
 *   2. candidates: every vertex against every edge of another strand within the largest distance a bridge can hold
 *      (src/contact's broad phase, vertex boxes against edge boxes), the closest point on the edge;
 *   3. per (vertex, other strand) the nearest edge (a stable sort by vertex, strand, distance, edge: the result does
 *      not depend on the broad phase's pair order);
 *   4. hysteresis: a pair kept from the last update holds to d_keep, a new one forms below d_new;
 *   5. the bridges' shares of film (A_p/n_p + A_c/n_c) for the force, and the wet vertices' bridges to colliders.
 * Rows are added to the Lagrangian system by dr_bridges_add_groups from what the update found. */
#include "wet/wet.h"

#include <stdlib.h>
#include <string.h>

#include "contact/contact.h"
#include "core/sort.h"
#include "linalg/linalg.h"

void dr_bridge_desc_default(DrBridgeDesc *d)
{
    memset(d, 0, sizeof *d);
    d->contact_angle = 40.0 * DR_PI / 180.0;
    d->surface_tension = 0.072;
    d->scale = 1.0;
    d->solid_scale = 1.0;
    d->radius_multiplier = 1.6;
    d->solid_radius_multiplier = 1.1;
    d->cross_flow = true;
    d->cross_flow_rate = 1.0;
}

typedef struct Cand {
    int p, s, e; /* vertex, the other strand, its edge (global edge index) */
    double t, d; /* closest point parameter on the edge, distance */
} Cand;

typedef struct Bridge {
    int p, s;       /* vertex, other strand */
    int q0;         /* the edge's first vertex (q1 = q0 + 1) */
    double t, d;    /* closest point parameter, distance of the axes */
    double n[3];    /* unit, from the closest point towards p */
    double area;    /* A_L, the bridge's film: A_p/n_p + A_c/n_c, m² */
    double w;       /* the strand length it stands for: ½ l_p, m */
    double dc;      /* contact distance r_p + r_c + thicknesses, m */
    double r;       /* the mean radius of the pair, m (the table's scale) */
} Bridge;

typedef struct SolidBridge {
    int p;
    double d;       /* distance of the vertex's axis from the collider surface, m */
    double n[3];    /* the collider's outward unit normal */
    double vn;      /* the collider's surface velocity along n, m/s */
    double area, w, dc, r;
} SolidBridge;

struct DrBridges {
    DrBridgeDesc desc;
    const DrCohesionTable *pair, *plane;
    /* the bridges kept (vertex, strand) in increasing order */
    int *kp, *ks;
    int nk, capk;
    /* scratch of an update, kept */
    Cand *cand, *cand_tmp;
    size_t ncand;
    int capc, capc_tmp;
    Bridge *br;
    int nbr, capbr;
    SolidBridge *sb;
    int nsb, capsb;
    int capv, cape;
    double *lv, *area, *H; /* per vertex */
    int *nleave;           /* per vertex: bridges leaving it */
    int *vstrand;          /* per vertex: its strand */
    int *edge_v0, *edge_s; /* per edge: first vertex, strand */
    DrBroadPhase *bp;
    int formed, broken;
    double moved;
    /* cross flow scratch */
    double *cf_diag, *cf_b, *cf_x, *cf_work;
    int *cf_index;         /* per vertex: its row in the flow system, −1 if unlinked */
    int *cf_vertex;        /* per row: its vertex */
    int cf_n;
};

static inline bool cand_less(const Cand *a, const Cand *b)
{
    if (a->p != b->p) return a->p < b->p;
    if (a->s != b->s) return a->s < b->s;
    if (a->d != b->d) return a->d < b->d;
    return a->e < b->e;
}
DR_DEFINE_STABLE_SORT(sort_cands, Cand, cand_less)

DrStatus dr_bridges_create(const DrBridgeDesc *desc, const DrCohesionTable *pair, const DrCohesionTable *plane,
                           DrBridges **out, DrError *err)
{
    *out = NULL;
    const char *bad = NULL;
    if (!(desc->surface_tension >= 0) || !isfinite(desc->surface_tension)) bad = "surface_tension";
    else if (!(desc->scale >= 0) || !isfinite(desc->scale)) bad = "scale";
    else if (!(desc->solid_scale >= 0) || !isfinite(desc->solid_scale)) bad = "solid_scale";
    else if (!(desc->radius_multiplier > 1) || !isfinite(desc->radius_multiplier)) bad = "radius_multiplier";
    else if (!(desc->solid_radius_multiplier > 1) || !isfinite(desc->solid_radius_multiplier))
        bad = "solid_radius_multiplier";
    else if (!(desc->cross_flow_rate > 0) || !isfinite(desc->cross_flow_rate)) bad = "cross_flow_rate";
    if (bad) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "bridges: %s out of range", bad);
    if (!pair || dr_cohesion_desc(pair)->shape != DR_COHESION_CYLINDERS ||
        (plane && dr_cohesion_desc(plane)->shape != DR_COHESION_PLANE))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "bridges need a two-cylinder cohesion table (and, for colliders, a cylinder-plane one)");
    if (plane && dr_cohesion_desc(plane)->contact_angle != dr_cohesion_desc(pair)->contact_angle)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "bridges: the two cohesion tables were built for different contact angles (%g and %g rad)",
                            dr_cohesion_desc(pair)->contact_angle, dr_cohesion_desc(plane)->contact_angle);
    DrBridges *b = NULL;
    DR_TRY(dr_calloc(1, sizeof *b, &b, err));
    b->desc = *desc;
    b->desc.contact_angle = dr_cohesion_desc(pair)->contact_angle;
    b->pair = pair;
    b->plane = plane;
    DrStatus s = dr_broad_phase_create(&b->bp, err);
    if (s != DR_OK) {
        dr_bridges_destroy(&b);
        return s;
    }
    *out = b;
    return DR_OK;
}

void dr_bridges_destroy(DrBridges **bp)
{
    if (!bp || !*bp) return;
    DrBridges *b = *bp;
    void *arrays[] = {b->kp, b->ks, b->cand, b->cand_tmp, b->br, b->sb, b->lv, b->area, b->H, b->nleave,
                      b->vstrand, b->edge_v0, b->edge_s, b->cf_diag, b->cf_b, b->cf_x, b->cf_work, b->cf_index,
                      b->cf_vertex};
    for (size_t k = 0; k < sizeof arrays / sizeof arrays[0]; k++) free(arrays[k]);
    dr_broad_phase_destroy(&b->bp);
    free(b);
    *bp = NULL;
}

/* Grows *p (elements of `size`) to hold `need`, by half again (kept from update to update). */
static DrStatus grow(void *pp, int *cap, size_t need, size_t size, DrError *err)
{
    if (need <= (size_t)*cap) return DR_OK;
    size_t n = (size_t)*cap + (size_t)*cap / 2;
    if (n < need) n = need;
    if (n < 16) n = 16;
    if (n > 2147483647u) return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "too many bridges (%zu)", need);
    DR_TRY(dr_realloc(n, size, pp, err));
    *cap = (int)n;
    return DR_OK;
}

/* Room for n kept bridges in both arrays of the kept set. */
static DrStatus grow_kept(DrBridges *b, int n, DrError *err)
{
    int cap = b->capk;
    DR_TRY(grow(&b->kp, &cap, (size_t)n, sizeof(int), err));
    cap = b->capk;
    DR_TRY(grow(&b->ks, &cap, (size_t)n, sizeof(int), err));
    b->capk = cap;
    return DR_OK;
}

static DrStatus size_vertices(DrBridges *b, int V, int E, DrError *err)
{
    if (V > b->capv) {
        int cap = b->capv;
        double **d[] = {&b->lv, &b->area, &b->H, &b->cf_diag, &b->cf_b, &b->cf_x};
        for (size_t k = 0; k < sizeof d / sizeof d[0]; k++) {
            cap = b->capv;
            DR_TRY(grow(d[k], &cap, (size_t)V, sizeof(double), err));
        }
        int **ip[] = {&b->nleave, &b->vstrand, &b->cf_index, &b->cf_vertex};
        for (size_t k = 0; k < sizeof ip / sizeof ip[0]; k++) {
            cap = b->capv;
            DR_TRY(grow(ip[k], &cap, (size_t)V, sizeof(int), err));
        }
        int capw = b->capv * 4;
        DR_TRY(grow(&b->cf_work, &capw, 4 * (size_t)V, sizeof(double), err));
        b->capv = cap;
    }
    if (E > b->cape) {
        int cap = b->cape;
        DR_TRY(grow(&b->edge_v0, &cap, (size_t)E, sizeof(int), err));
        cap = b->cape;
        DR_TRY(grow(&b->edge_s, &cap, (size_t)E, sizeof(int), err));
        b->cape = cap;
    }
    return DR_OK;
}

static inline DrVec3 vtx(const double *x, int i) { return dr_v3(x[3 * i], x[3 * i + 1], x[3 * i + 2]); }

static bool strands_pair(const DrBridgeStrands *s, int a, int c)
{
    if (!s->batch) return true;
    int ba = s->batch[a], bc = s->batch[c];
    if (ba == bc) return s->self[ba] != 0;
    return (s->group[ba] & s->mask[bc]) != 0 && (s->group[bc] & s->mask[ba]) != 0;
}

static double strand_thickness(const DrBridgeStrands *s, int k) { return s->thickness ? s->thickness[k] : 0.0; }

/* Binary search of (p, s) in the kept set. */
static bool was_kept(const DrBridges *b, int p, int s)
{
    int lo = 0, hi = b->nk;
    while (lo < hi) {
        int mid = (lo + hi) / 2;
        if (b->kp[mid] < p || (b->kp[mid] == p && b->ks[mid] < s)) lo = mid + 1;
        else hi = mid;
    }
    return lo < b->nk && b->kp[lo] == p && b->ks[lo] == s;
}

DrStatus dr_bridges_update(DrBridges *b, const DrBridgeStrands *s, const DrRodCollider *col, int ncol,
                           DrError *err)
{
    int S = s->nstrands, V = s->nverts, E = V - S;
    DR_TRY(size_vertices(b, V, E, err));
    double theta = b->desc.contact_angle;
    /* 1. Voronoi lengths, film areas and outer radii */
    double amax = 0, rmax = 0, tmax = 0, lmax = 0;
    for (int k = 0; k < S; k++) {
        int o = s->offsets[k], nv = s->offsets[k + 1] - o;
        for (int j = 0; j < nv; j++) {
            int i = o + j;
            double l = 0;
            if (j > 0) l += 0.5 * dr_v3_norm(dr_v3_sub(vtx(s->x, i), vtx(s->x, i - 1)));
            if (j < nv - 1) {
                double le = dr_v3_norm(dr_v3_sub(vtx(s->x, i + 1), vtx(s->x, i)));
                l += 0.5 * le;
                lmax = fmax(lmax, le);
                int e = o - k + j;
                b->edge_v0[e] = i;
                b->edge_s[e] = k;
            }
            b->lv[i] = l;
            b->vstrand[i] = k;
            b->area[i] = l > 0 ? s->volume[i] / l : 0.0;
            double r = s->radius[i];
            b->H[i] = sqrt(r * r + b->area[i] / DR_PI);
            amax = fmax(amax, b->area[i]);
            rmax = fmax(rmax, r);
        }
        tmax = fmax(tmax, strand_thickness(s, k));
    }
    int nk_old = b->nk;
    b->nbr = 0;
    b->nsb = 0;
    b->ncand = 0;
    if (amax <= 0) { /* no film anywhere: no bridge */
        b->broken = nk_old;
        b->formed = 0;
        b->nk = 0;
        return DR_OK;
    }
    /* 2. candidates within the largest distance any bridge holds */
    double Hmax = sqrt(rmax * rmax + amax / DR_PI);
    double reach = fmax(2 * Hmax, (1 + 0.5 * theta) * sqrt(2 * amax) + 2 * rmax) + 2 * tmax;
    dr_broad_phase_clear(b->bp);
    DrVec3 half = dr_v3(0.5 * reach, 0.5 * reach, 0.5 * reach);
    for (int i = 0; i < V; i++) {
        DrVec3 p = vtx(s->x, i);
        DR_TRY(dr_broad_phase_add(b->bp, dr_v3_sub(p, half), dr_v3_add(p, half), err));
    }
    for (int e = 0; e < E; e++) {
        DrVec3 p = vtx(s->x, b->edge_v0[e]), q = vtx(s->x, b->edge_v0[e] + 1);
        DrVec3 lo = dr_v3(fmin(p.x, q.x), fmin(p.y, q.y), fmin(p.z, q.z));
        DrVec3 hi = dr_v3(fmax(p.x, q.x), fmax(p.y, q.y), fmax(p.z, q.z));
        DR_TRY(dr_broad_phase_add(b->bp, dr_v3_sub(lo, half), dr_v3_add(hi, half), err));
    }
    const DrBroadPair *pairs = NULL;
    long npairs = 0;
    DR_TRY(dr_broad_phase_pairs_across(b->bp, lmax + reach, V, &pairs, &npairs, err));
    for (long c = 0; c < npairs; c++) {
        int p = pairs[c].a, e = pairs[c].b - V, sp = b->vstrand[p], se = b->edge_s[e];
        if (sp == se || !strands_pair(s, sp, se)) continue;
        if (b->area[p] <= 0 && b->area[b->edge_v0[e]] <= 0 && b->area[b->edge_v0[e] + 1] <= 0) continue;
        DrVec3 x = vtx(s->x, p), q0 = vtx(s->x, b->edge_v0[e]), q1 = vtx(s->x, b->edge_v0[e] + 1);
        DrVec3 dq = dr_v3_sub(q1, q0);
        double ll = dr_v3_dot(dq, dq);
        double t = ll > 0 ? fmin(fmax(dr_v3_dot(dr_v3_sub(x, q0), dq) / ll, 0.0), 1.0) : 0.0;
        double d = dr_v3_norm(dr_v3_sub(x, dr_v3_add(q0, dr_v3_scale(dq, t))));
        if (d > reach) continue;
        DR_TRY(grow(&b->cand, &b->capc, b->ncand + 1, sizeof(Cand), err));
        b->cand[b->ncand++] = (Cand){p, se, e, t, d};
    }
    DR_TRY(grow(&b->cand_tmp, &b->capc_tmp, b->ncand, sizeof(Cand), err)); /* the sort's scratch */
    /* 3. the nearest edge per (vertex, strand) */
    sort_cands(b->cand, b->cand_tmp, b->ncand);
    /* 4. hysteresis; the new kept set is built in place of the candidates' firsts */
    int formed = 0, kept = 0;
    memset(b->nleave, 0, (size_t)V * sizeof(int));
    for (size_t c = 0; c < b->ncand; c++) {
        const Cand *cd = &b->cand[c];
        if (c > 0 && b->cand[c - 1].p == cd->p && b->cand[c - 1].s == cd->s) continue;
        int p = cd->p, q0 = b->edge_v0[cd->e];
        double t = cd->t, d = cd->d;
        double rc = (1 - t) * s->radius[q0] + t * s->radius[q0 + 1];
        double Ac = (1 - t) * b->area[q0] + t * b->area[q0 + 1];
        double Hc = sqrt(rc * rc + Ac / DR_PI);
        double dL = (1 + 0.5 * theta) * sqrt(b->area[p] + Ac) + s->radius[p] + rc;
        bool old = was_kept(b, p, cd->s);
        double limit = old ? fmax(b->H[p] + Hc, dL) : fmin(b->H[p] + Hc, dL);
        limit += strand_thickness(s, b->vstrand[p]) + strand_thickness(s, cd->s);
        if (!(d <= limit) || !(d > 0)) continue;
        if (old) kept++;
        else formed++;
        DR_TRY(grow(&b->br, &b->capbr, (size_t)b->nbr + 1, sizeof(Bridge), err));
        Bridge *br = &b->br[b->nbr++];
        DrVec3 x = vtx(s->x, p), c0 = vtx(s->x, q0), c1 = vtx(s->x, q0 + 1);
        DrVec3 cpt = dr_v3_add(c0, dr_v3_scale(dr_v3_sub(c1, c0), t));
        DrVec3 n = dr_v3_scale(dr_v3_sub(x, cpt), 1.0 / d);
        *br = (Bridge){.p = p, .s = cd->s, .q0 = q0, .t = t, .d = d, .n = {n.x, n.y, n.z}, .area = 0,
                       .w = 0.5 * b->lv[p],
                       .dc = s->radius[p] + rc + strand_thickness(s, b->vstrand[p]) + strand_thickness(s, cd->s),
                       .r = 0.5 * (s->radius[p] + rc)};
        b->nleave[p]++;
    }
    b->formed = formed;
    b->broken = nk_old - kept;
    DR_TRY(grow_kept(b, b->nbr, err));
    for (int k = 0; k < b->nbr; k++) {
        b->kp[k] = b->br[k].p;
        b->ks[k] = b->br[k].s;
    }
    b->nk = b->nbr;
    /* 5. each bridge's film: the shares of its two ends */
    for (int k = 0; k < b->nbr; k++) {
        Bridge *br = &b->br[k];
        int q0 = br->q0;
        double a0 = b->area[q0] / (b->nleave[q0] > 0 ? b->nleave[q0] : 1);
        double a1 = b->area[q0 + 1] / (b->nleave[q0 + 1] > 0 ? b->nleave[q0 + 1] : 1);
        br->area = b->area[br->p] / b->nleave[br->p] + (1 - br->t) * a0 + br->t * a1;
    }
    /* wet vertices and colliders: the nearest collider within the distance a bridge holds */
    for (int i = 0; b->plane && i < V; i++) {
        if (b->area[i] <= 0 || (s->held && s->held[i])) continue;
        DrVec3 x = vtx(s->x, i);
        double r = s->radius[i], tk = strand_thickness(s, b->vstrand[i]);
        double best = INFINITY;
        int bc = -1;
        DrVec3 bn = {0, 0, 0};
        for (int c = 0; c < ncol; c++) {
            DrVec3 n;
            double d = col[c].sdf(x, &n, col[c].ctx);
            double limit = fmax(b->H[i], (1 + 0.5 * theta) * sqrt(b->area[i]) + r) + tk + col[c].thickness;
            if (!(d <= limit) || !(d > 0) || d >= best) continue;
            best = d;
            bc = c;
            double nn = dr_v3_norm(n);
            bn = nn > 0 ? dr_v3_scale(n, 1.0 / nn) : dr_v3(0, 1, 0);
        }
        if (bc < 0) continue;
        DR_TRY(grow(&b->sb, &b->capsb, (size_t)b->nsb + 1, sizeof(SolidBridge), err));
        DrVec3 vc = col[bc].velocity_at ? col[bc].velocity_at(x, col[bc].ctx) : dr_v3(0, 0, 0);
        b->sb[b->nsb++] = (SolidBridge){.p = i, .d = best, .n = {bn.x, bn.y, bn.z}, .vn = dr_v3_dot(vc, bn),
                                        .area = b->area[i], .w = b->lv[i],
                                        .dc = r + tk + col[bc].thickness, .r = r};
    }
    return DR_OK;
}

/* The spring of a bridge (wet.h): C⁻¹ = w F(d)/(d − d*) at d ≥ d̂, held at its value at d̂ below. */
static double bridge_cinv(const DrCohesionTable *t, double sigma, double scale, double mult, double r, double area,
                          double w, double dc, double d)
{
    double dstar = mult * dc, dhat = (2 * mult - 1) * dc;
    double de = fmax(d, dhat);
    /* more film than the table covers (two films above Film.max_ratio, which the film keeps from lasting): the table's
       largest, where the force has saturated anyway */
    double amax = dr_cohesion_desc(t)->max_area * r * r;
    double F = dr_cohesion_force(t, r, sigma, de, fmin(area, amax));
    if (!(F > 0)) return 0.0;
    return scale * w * F / (de - dstar);
}

DrStatus dr_bridges_add_groups(const DrBridges *b, const DrBridgeStrands *s, DrLag *lag, double h, DrError *err)
{
    double sigma = b->desc.surface_tension;
    for (int k = 0; k < b->nbr; k++) {
        const Bridge *br = &b->br[k];
        double cinv = bridge_cinv(b->pair, sigma, b->desc.scale, b->desc.radius_multiplier, br->r, br->area, br->w,
                                  br->dc, br->d);
        if (s->submerged) /* under the bulk's surface there is no meniscus */
            cinv *= 1.0 - 0.5 * (s->submerged[br->p] + (1 - br->t) * s->submerged[br->q0] +
                                 br->t * s->submerged[br->q0 + 1]);
        if (!(cinv > 0)) continue;
        DrLagGroup g;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 9;
        int v[3] = {br->p, br->q0, br->q0 + 1};
        double wgt[3] = {1.0, -(1 - br->t), -br->t};
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 3; c++) {
                g.dof[3 * a + c] = s->vertex_dof[v[a]] + c;
                g.J[3 * a + c] = wgt[a] * br->n[c];
            }
        g.phi[0] = br->d - b->desc.radius_multiplier * br->dc;
        g.cinv[0] = cinv;
        DR_TRY(dr_lag_add_global(lag, &g, err));
    }
    for (int k = 0; k < b->nsb; k++) {
        const SolidBridge *sb = &b->sb[k];
        double cinv = bridge_cinv(b->plane, sigma, b->desc.solid_scale, b->desc.solid_radius_multiplier, sb->r,
                                  sb->area, sb->w, sb->dc, sb->d);
        if (s->submerged) cinv *= 1.0 - s->submerged[sb->p];
        if (!(cinv > 0)) continue;
        DrLagGroup g;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 3;
        for (int c = 0; c < 3; c++) {
            g.dof[c] = s->vertex_dof[sb->p] + c;
            g.J[c] = sb->n[c];
        }
        /* relative to the collider's motion over the step: φ₊ = φ + h n·(v₊ − v_c) */
        g.phi[0] = sb->d - b->desc.solid_radius_multiplier * sb->dc - h * sb->vn;
        g.cinv[0] = cinv;
        DR_TRY(dr_lag_add_global(lag, &g, err));
    }
    return DR_OK;
}

/* ---- cross-hair flow ------------------------------------------------------------------------------------------ */

typedef struct FlowCtx {
    const DrBridges *b;
    double dt;
} FlowCtx;

/* y = (L + δt K) x over the flow system's rows: K the graph Laplacian of the links. */
static void flow_apply(const double *x, double *y, void *vctx)
{
    const FlowCtx *c = vctx;
    const DrBridges *b = c->b;
    for (int r = 0; r < b->cf_n; r++) y[r] = b->lv[b->cf_vertex[r]] * x[r];
    double rate = b->desc.cross_flow_rate;
    for (int k = 0; k < b->nbr; k++) {
        const Bridge *br = &b->br[k];
        int rp = b->cf_index[br->p];
        for (int end = 0; end < 2; end++) {
            double wl = end ? br->t : 1 - br->t;
            if (wl <= 0) continue;
            int rq = b->cf_index[br->q0 + end];
            double g = c->dt * rate * br->w * wl * (x[rp] - x[rq]);
            y[rp] += g;
            y[rq] -= g;
        }
    }
}

static void flow_precond(const double *x, double *y, void *vctx)
{
    const FlowCtx *c = vctx;
    for (int r = 0; r < c->b->cf_n; r++) y[r] = x[r] / c->b->cf_diag[r];
}

DrStatus dr_bridges_cross_flow(DrBridges *b, const DrBridgeStrands *s, double dt, double *dV, DrError *err)
{
    int V = s->nverts;
    memset(dV, 0, (size_t)V * sizeof(double));
    b->moved = 0;
    if (!b->desc.cross_flow || b->nbr == 0 || !(dt > 0)) return DR_OK;
    /* the rows: every vertex on a link, in vertex order */
    for (int i = 0; i < V; i++) b->cf_index[i] = -1;
    for (int k = 0; k < b->nbr; k++) {
        const Bridge *br = &b->br[k];
        b->cf_index[br->p] = 0;
        if (br->t < 1) b->cf_index[br->q0] = 0;
        if (br->t > 0) b->cf_index[br->q0 + 1] = 0;
    }
    int n = 0;
    for (int i = 0; i < V; i++)
        if (b->cf_index[i] == 0) {
            b->cf_vertex[n] = i;
            b->cf_index[i] = n++;
        }
    b->cf_n = n;
    double rate = b->desc.cross_flow_rate;
    for (int r = 0; r < n; r++) {
        int i = b->cf_vertex[r];
        b->cf_diag[r] = b->lv[i];
        b->cf_b[r] = b->lv[i] * b->area[i];
        b->cf_x[r] = b->area[i];
    }
    for (int k = 0; k < b->nbr; k++) {
        const Bridge *br = &b->br[k];
        for (int end = 0; end < 2; end++) {
            double wl = end ? br->t : 1 - br->t;
            if (wl <= 0) continue;
            double g = dt * rate * br->w * wl;
            b->cf_diag[b->cf_index[br->p]] += g;
            b->cf_diag[b->cf_index[br->q0 + end]] += g;
        }
    }
    FlowCtx fc = {b, dt};
    DrLinearOp A = {n, flow_apply, &fc}, M = {n, flow_precond, &fc};
    DrPcgDesc pd;
    dr_pcg_desc_default(&pd);
    pd.rel_tol = 1e-12;
    pd.max_iter = 10 * n + 100;
    DrPcgStats ps;
    DrStatus st = dr_pcg_solve(&A, &M, b->cf_b, b->cf_x, &pd, b->cf_work, &ps, err);
    if (st < 0) return st;
    /* the volume moved along each link, from the relaxed areas: equal and opposite, so Σ dV = 0 whatever the solve's
       accuracy; a vertex sends at most what it holds (the exact solution never asks for more; an inexact one could by
       a rounding error, so the sends of a vertex are scaled down to its volume) */
    double *out = b->cf_work; /* per row: total sent */
    memset(out, 0, (size_t)n * sizeof(double));
    for (int k = 0; k < b->nbr; k++) {
        const Bridge *br = &b->br[k];
        int rp = b->cf_index[br->p];
        for (int end = 0; end < 2; end++) {
            double wl = end ? br->t : 1 - br->t;
            if (wl <= 0) continue;
            int rq = b->cf_index[br->q0 + end];
            double f = dt * rate * br->w * wl * (b->cf_x[rp] - b->cf_x[rq]);
            if (f > 0) out[rp] += f;
            else out[rq] -= f;
        }
    }
    for (int k = 0; k < b->nbr; k++) {
        const Bridge *br = &b->br[k];
        int rp = b->cf_index[br->p];
        for (int end = 0; end < 2; end++) {
            double wl = end ? br->t : 1 - br->t;
            if (wl <= 0) continue;
            int q = br->q0 + end, rq = b->cf_index[q];
            double f = dt * rate * br->w * wl * (b->cf_x[rp] - b->cf_x[rq]);
            int from = f > 0 ? br->p : q, rf = f > 0 ? rp : rq;
            double have = s->volume[from];
            if (out[rf] > have) f *= have / out[rf];
            dV[br->p] -= f;
            dV[q] += f;
            b->moved += fabs(f);
        }
    }
    return DR_OK;
}

void dr_bridges_stats(const DrBridges *b, DrBridgeStats *st)
{
    st->bridges = b->nbr;
    st->solid_bridges = b->nsb;
    st->formed = b->formed;
    st->broken = b->broken;
    st->cross_flow = b->moved;
}

int dr_bridges_count(const DrBridges *b) { return b->nk; }

void dr_bridges_get(const DrBridges *b, int *vertex, int *strand)
{
    memcpy(vertex, b->kp, (size_t)b->nk * sizeof(int));
    memcpy(strand, b->ks, (size_t)b->nk * sizeof(int));
}

DrStatus dr_bridges_set(DrBridges *b, int n, const int *vertex, const int *strand, DrError *err)
{
    for (int k = 0; k < n; k++)
        if (vertex[k] < 0 || strand[k] < 0 ||
            (k > 0 && (vertex[k] < vertex[k - 1] || (vertex[k] == vertex[k - 1] && strand[k] <= strand[k - 1]))))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "bridge list entry %d (vertex %d, strand %d) is not in increasing order", k,
                                vertex[k], strand[k]);
    DR_TRY(grow_kept(b, n, err));
    if (n) {
        memcpy(b->kp, vertex, (size_t)n * sizeof(int));
        memcpy(b->ks, strand, (size_t)n * sizeof(int));
    }
    b->nk = n;
    return DR_OK;
}
