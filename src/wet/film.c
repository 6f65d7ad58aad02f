/* drench wet: the film of liquid on every strand (wet.h, "the film on every strand"; fei2017 §S2 eqs. S5–S17,
 * PHYSICS §5).
 *
 * A step (dr_film_step) runs per strand, in parallel over strands: a strand and its film exchange nothing with
 * other strands, so the bits do not depend on the thread count. Per strand:
 *   1. realign: the film's momentum at the start of the step, ρ V̂_e (v̄_e + u_e t_e) on the old tangents with the
 *      strands' new velocities (the solve carried the part across the strand through B_i), is written on the new
 *      tangents: its component along the new tangent stays the film's, the rest goes to the strand's vertices;
 *   2. film substeps until h is covered, each: transport (continuity and momentum, pools, the max_ratio limit), then
 *      gravity along the strand and the Laplace pressure, then implicit friction with the strand.
 * Every exchange with the strand is an impulse J_i per vertex applied as (m_i I + B_i) Δv_i = J_i (B_i the film's
 * inertia of wet.h, from the volumes after the exchange). Σ_i B_i Δv_i is exactly the change Δv makes to the film's
 * momentum across the strand, so strand + film momentum changes only by gravity and by what held vertices absorb.
 * The film's working variable is its speed along the strand in space, w_e = u_e + v̄_e·t_e: that is what its own
 * forces change and what transport carries; u_e = w_e − v̄_e·t_e is stored at the end, so the strand's acceleration
 * along itself (its solve changed v̄_e·t_e without the film) appears in u_e with the opposite sign: the fictitious
 * force of the strand's frame, exactly. DrFilmState.strand_speed keeps v̄_e·t_e between steps for that.
 *
 * Modelling choices, and why.
 *  - Friction with the strand: the wall shear of a thin viscous film with a free surface (the half-Poiseuille,
 *    Nusselt profile), 3μū/h per unit area over the wetted perimeter 2πr, so per unit length 6πμrū/h; over the
 *    film's mass per unit length ρA: du/dt = −c u with c = friction · 6πμr/(ρ A h), h = H − r, A = π(H² − r²). For a
 *    held strand the terminal speed is g_t/c = g_t ρ (H² − r²) h / (6μr): water on r = 50 µm at H = 2r, 12.3 mm/s
 *    falling. Thick films (h ≳ r) are outside the thin-film profile; the law stays the same function of h there (it
 *    keeps the right limits: no film, no motion; more film, faster flow). It is implicit and two-body: a pair of
 *    film edge (mass m_f = ρ V̂_e) and strand (inverse inertia along t_e at the edge k = ¼ tᵀ(K_i⁻¹ + K_{i+1}⁻¹)t,
 *    K_i = m_i I + B_i; 0 at held vertices) relaxes its relative speed r = w − v̄·t to r' = r/(1 + δt c (1 + m_f k)),
 *    the impulse j = m_f (r − r')/(1 + m_f k) moving film and strand equal and opposite; the energy change
 *    −j(r + r')/2 is never positive. Edges go in two colours (even, odd), which share no vertex, so each pair's
 *    update is exact. A held strand gets w ← (w + g_t δt)/(1 + c δt), whose fixed point is g_t/c for every δt. This
 *    replaces the reference code's film momentum update that could create momentum (libWetHair PR #20, issue #18).
 *  - Laplace pressure p = −σ ∂²h/∂s² (PHYSICS §5; the azimuthal curvature 1/H, which drives the Plateau–Rayleigh
 *    break-up, is left out as in the paper), at the vertices, with zero slope at the strand's ends; it acts on each
 *    edge's film as −(V̂_e/l_e)(p_{i+1} − p_i) along t_e, and its reaction on the strand (film and strand together
 *    feel no net capillary force). Explicit: the volumes move first, then the velocities (symplectic Euler), stable
 *    for δt √λ < 2 with λ the largest eigenvalue of the linearised capillary-wave operator; each substep keeps
 *    δt ≤ 1/√λ̄ with λ̄ ≥ λ the product of the row-sum norms of the operator's four factors, times (1 + the largest
 *    film-to-strand mass ratio) for the strand's recoil. At grooms' edge lengths (millimetres) that limit is 1–100 ms
 *    and rarely beats the CFL; an implicit pressure would need a non-symmetric pentadiagonal solve per strand per
 *    substep.
 *  - Continuity (S9) in finite volumes: edge fluxes q_e = V_up δt u_e / l_up, upwind in the vertex volumes, and at
 *    each end the flux of the end vertex into its pool at the end edge's speed. A substep lets no vertex send out
 *    more than 0.9 of what it holds, so volumes stay ≥ 0 by construction and are never clamped; Σ V_i + pools is kept
 *    to round-off.
 *  - Momentum transport (S16/S17): V̂_e is linear in the V_i, so its change over a substep is carried by fluxes G_i
 *    across the vertices, derived from the q_e (G_i = β_{i−1} q_i + α_i q_{i−1}, α and β the shares of a vertex's
 *    volume on its right and left edge; at the ends the pool fluxes). Each G_i carries the film velocity of the edge
 *    it leaves (v̄ + u t there: the strand velocity where it came from, eq. S17, plus its own speed). The edge's new w
 *    is the volume-weighted mean of what stayed and what came, never outside their range because a substep also lets
 *    no edge lose more than 0.9 of V̂_e; the arriving momentum's part across the edge goes to the strand.
 *  - Pools are sinks: liquid reaching an end joins that end's pool and moves with the end vertex (its full inertia
 *    ρ V_pool I in B_i); a pool never flows back (dripping from it belongs to capture and dripping). A vertex above
 *    max_ratio after transport sends the excess, with its momentum, to the nearer pool by arc length (the root pool
 *    when strictly nearer the root).
 *  - Substeps: per strand, re-evaluated every substep (the film accelerates within a step): the largest δt that meets
 *    the two CFL conditions above, the capillary limit and h/desc.substeps, evened out over what is left of h.
 * Memory: everything a step touches is sized at create; a step allocates nothing. */
#include <stdlib.h>
#include <string.h>

#include "wet/wet.h"

#define FILM_CFL 0.9             /* the largest share of a vertex's (or an edge's) volume a substep moves out */
#define FILM_MAX_SUBSTEPS 1000000 /* per strand step: beyond this the film cannot follow the strand (non-finite) */

struct DrFilm {
    DrFilmDesc desc;
    int S, V, E;
    int *offsets;        /* S + 1 */
    double *radius;      /* V, m */
    /* state (DrFilmState) */
    double *volume, *u, *pool, *strand_speed;
    double *lv;          /* V: the vertices' Voronoi lengths on the last geometry the film saw (dr_film_heights) */
    /* workspace, sized at create */
    double *t0, *le0, *lv0; /* geometry at the start of a step: tangents 3E, edge lengths E, vertex lengths V */
    double *t1, *le1, *lv1; /* at the end */
    double *hat;         /* E: V̂_e */
    double *w;           /* E: the film's speed along the strand in space, w_e = u_e + v̄_e·t_e */
    double *fv;          /* 3E: the film's velocity on each edge, v̄_e + u_e t_e */
    double *ur;          /* E: the film's speed relative to the strand during a substep */
    double *q;           /* E: fluxes through the edges (m³ per substep, + toward the tip) */
    double *G;           /* V: fluxes across the vertices between edges (m³ per substep, + toward the tip) */
    double *hh, *p;      /* V: film thickness h and Laplace pressure */
    double *J;           /* 3V: impulses on the strands' vertices, N s */
    double *Kinv;        /* 9V: (m_i I + B_i)⁻¹, 0 for held vertices */
    double *save;        /* a step's inputs, restored on failure: V + 2E + 2S + V + 3V */
    int *nsub;           /* S: substeps of the last step */
    double *to_pools;    /* S */
    DrStatus *status;    /* S */
    double *partial;     /* 4S: dr_film_exchange's per-strand sums (momentum that left, volume that arrives) */
    double *pacc, *pimp; /* E each: the bulk's pressure along each edge over the next step (dr_film_pressure): the
                            acceleration −(t⁰·∇p̄)/ρ it gives the film (m/s²) and the impulse booked for it along t⁰,
                            h ρ V̂⁰ a (N·s); consumed by dr_film_step */
};

void dr_film_desc_default(DrFilmDesc *d)
{
    d->density = 1000;
    d->viscosity = 1e-3;
    d->surface_tension = 0.072;
    d->max_ratio = 6;
    d->friction = 1;
    d->substeps = 1;
    d->gravity = dr_v3(0, -9.81, 0);
}

/* ---- small helpers --------------------------------------------------------------------------------------------- */

static inline DrVec3 ld3(const double *a) { return dr_v3(a[0], a[1], a[2]); }
static inline void add3(double *a, DrVec3 b)
{
    a[0] += b.x;
    a[1] += b.y;
    a[2] += b.z;
}
static inline DrVec3 perp(DrVec3 a, DrVec3 t) { return dr_v3_sub(a, dr_v3_scale(t, dr_v3_dot(a, t))); }
/* The share of a vertex's volume that lies on one of its edges: half the edge over the vertex's Voronoi length. */
static inline double share(double le, double lv) { return 0.5 * le / lv; }
static inline DrVec3 vmean(const double *v, int i) { return dr_v3_scale(dr_v3_add(ld3(v + 3 * i), ld3(v + 3 * i + 3)), 0.5); }

/* Edge e of a strand whose vertices start at x: its length, and its unit tangent into *t (may be NULL). */
static inline double edge_len(const double *x, int e, DrVec3 *t)
{
    DrVec3 d = dr_v3_sub(ld3(x + 3 * e + 3), ld3(x + 3 * e));
    double l = dr_v3_norm(d);
    if (t) *t = dr_v3(d.x / l, d.y / l, d.z / l);
    return l;
}
/* The Voronoi length of vertex i of an n-vertex strand: half of each adjacent edge. */
static inline double voronoi(double le_prev, double le_next, int n, int i)
{
    return 0.5 * ((i > 0 ? le_prev : 0) + (i < n - 1 ? le_next : 0));
}

/* Edge tangents, edge lengths and vertex Voronoi lengths of the n-vertex strand at x (all local to the strand). */
static void strand_geometry(const double *x, int n, double *t, double *le, double *lv)
{
    for (int e = 0; e < n - 1; e++) {
        DrVec3 te;
        le[e] = edge_len(x, e, &te);
        t[3 * e] = te.x;
        t[3 * e + 1] = te.y;
        t[3 * e + 2] = te.z;
    }
    for (int i = 0; i < n; i++) lv[i] = voronoi(i > 0 ? le[i - 1] : 0, i < n - 1 ? le[i] : 0, n, i);
}

/* V̂_e of every edge from the vertex volumes (local arrays). */
static void edge_volumes(const double *V, const double *le, const double *lv, int n, double *hat)
{
    for (int e = 0; e < n - 1; e++) hat[e] = V[e] * share(le[e], lv[e]) + V[e + 1] * share(le[e], lv[e + 1]);
}

/* Cross-section h (film thickness, m) of area A on a strand of radius r: H − r written without cancellation. */
static inline double thickness(double A, double r)
{
    double a = A / DR_PI;
    return a / (sqrt(r * r + a) + r);
}

/* B += m (I − t tᵀ): the inertia of film mass m that the strand carries across itself. */
static inline void add_across(double B[9], double m, DrVec3 t)
{
    double P[9] = {1 - t.x * t.x, -t.x * t.y, -t.x * t.z, -t.y * t.x, 1 - t.y * t.y,
                   -t.y * t.z, -t.z * t.x, -t.z * t.y, 1 - t.z * t.z};
    for (int q = 0; q < 9; q++) B[q] += m * P[q];
}

/* ---- create, destroy, state ------------------------------------------------------------------------------------- */

void dr_film_destroy(DrFilm **fp)
{
    if (!fp || !*fp) return;
    DrFilm *f = *fp;
    void *arrays[] = {f->offsets, f->radius, f->volume, f->u, f->pool, f->strand_speed, f->lv, f->t0, f->le0,
                      f->lv0, f->t1, f->le1, f->lv1, f->hat, f->w, f->fv, f->ur, f->q, f->G, f->hh, f->p, f->J, f->Kinv,
                      f->save, f->nsub, f->to_pools, f->status, f->partial, f->pacc, f->pimp};
    for (size_t k = 0; k < sizeof arrays / sizeof arrays[0]; k++) free(arrays[k]);
    free(f);
    *fp = NULL;
}

static DrStatus check_desc(const DrFilmDesc *d, DrError *err)
{
#define BAD(field, cond, range)                                                                                      \
    if (!(cond))                                                                                                     \
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,                                                           \
                            "wet film: DrFilmDesc." #field " = %g is out of range; it must be " range, (double)(d->field))
    BAD(density, d->density > 0 && isfinite(d->density), "> 0 (kg/m³; water 1000)");
    BAD(viscosity, d->viscosity > 0 && isfinite(d->viscosity), "> 0 (Pa·s; water 1e-3)");
    BAD(surface_tension, d->surface_tension >= 0 && isfinite(d->surface_tension), ">= 0 (N/m; water 0.072)");
    BAD(max_ratio, d->max_ratio > 1 && isfinite(d->max_ratio), "> 1 (the largest H/r a vertex holds; default 6)");
    BAD(friction, d->friction >= 0 && isfinite(d->friction), ">= 0 (a scale on the friction law; default 1)");
    BAD(substeps, d->substeps >= 1 && d->substeps <= FILM_MAX_SUBSTEPS, "in [1, 1000000]");
#undef BAD
    if (!dr_v3_isfinite(d->gravity))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "wet film: DrFilmDesc.gravity is not finite; give m/s²");
    return DR_OK;
}

#define ALLOC(p, n)                                                                                                  \
    do {                                                                                                             \
        s = dr_calloc((size_t)(n) > 0 ? (size_t)(n) : 1, sizeof *(p), &(p), err);                                    \
        if (s != DR_OK) goto fail;                                                                                   \
    } while (0)

DrStatus dr_film_create(const DrFilmDesc *desc, int nstrands, const int *offsets, const double *radius,
                        const double *rest_x, const double *initial_ratio, DrFilm **out, DrError *err)
{
    *out = NULL;
    DR_TRY(check_desc(desc, err));
    if (nstrands < 0 || offsets[0] != 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "wet film: %d strands with offsets[0] = %d; give nstrands >= 0 and offsets from 0",
                            nstrands, nstrands >= 0 ? offsets[0] : 0);
    for (int k = 0; k < nstrands; k++) {
        int o = offsets[k], n = offsets[k + 1] - o;
        if (n < 2)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "wet film: strand %d has %d vertices; a strand needs at least 2 (check offsets)", k, n);
        if (offsets[k + 1] > 1000000000)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "wet film: too many vertices (%d)", offsets[k + 1]);
        double R = initial_ratio[k];
        if (!(R >= 1 && R <= desc->max_ratio))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "wet film: initial_ratio[%d] = %g is out of range; it must be in [1, max_ratio = %g] "
                                "(H/r: 1 is a dry strand)",
                                k, R, desc->max_ratio);
        for (int i = o; i < o + n; i++) {
            if (!(radius[i] > 0 && isfinite(radius[i])))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "wet film: radius[%d] = %g (strand %d); a strand's radius must be > 0 and finite", i,
                                    radius[i], k);
            if (i + 1 < o + n) {
                const double *a = rest_x + 3 * i, *b = a + 3;
                double d = sqrt((b[0] - a[0]) * (b[0] - a[0]) + (b[1] - a[1]) * (b[1] - a[1]) + (b[2] - a[2]) * (b[2] - a[2]));
                if (!(d > 0 && isfinite(d)))
                    return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                        "wet film: strand %d has a zero-length or non-finite edge at vertex %d of rest_x",
                                        k, i - o);
            }
        }
    }
    DrStatus s = DR_OK;
    DrFilm *f = NULL;
    DR_TRY(dr_calloc(1, sizeof *f, &f, err));
    f->desc = *desc;
    f->S = nstrands;
    f->V = offsets[nstrands];
    f->E = f->V - nstrands;
    long V = f->V, E = f->E, S = f->S;
    ALLOC(f->offsets, S + 1);
    ALLOC(f->radius, V);
    ALLOC(f->volume, V);
    ALLOC(f->u, E);
    ALLOC(f->pool, 2 * S);
    ALLOC(f->strand_speed, E);
    ALLOC(f->lv, V);
    ALLOC(f->t0, 3 * E);
    ALLOC(f->le0, E);
    ALLOC(f->lv0, V);
    ALLOC(f->t1, 3 * E);
    ALLOC(f->le1, E);
    ALLOC(f->lv1, V);
    ALLOC(f->hat, E);
    ALLOC(f->w, E);
    ALLOC(f->fv, 3 * E);
    ALLOC(f->ur, E);
    ALLOC(f->q, E);
    ALLOC(f->G, V);
    ALLOC(f->hh, V);
    ALLOC(f->p, V);
    ALLOC(f->J, 3 * V);
    ALLOC(f->Kinv, 9 * V);
    ALLOC(f->save, 5 * V + 2 * E + 2 * S);
    ALLOC(f->nsub, S);
    ALLOC(f->to_pools, S);
    ALLOC(f->status, S);
    ALLOC(f->partial, 4 * S);
    ALLOC(f->pacc, E);
    ALLOC(f->pimp, E);
    memcpy(f->offsets, offsets, (size_t)(S + 1) * sizeof(int));
    if (V > 0) memcpy(f->radius, radius, (size_t)V * sizeof(double));
    for (int k = 0; k < f->S; k++) {
        int o = offsets[k], n = offsets[k + 1] - o, e0 = o - k;
        strand_geometry(rest_x + 3 * o, n, f->t1 + 3 * e0, f->le1 + e0, f->lv + o);
        double R = initial_ratio[k];
        for (int i = o; i < o + n; i++) f->volume[i] = DR_PI * radius[i] * radius[i] * (R * R - 1) * f->lv[i];
    }
    *out = f;
    return DR_OK;
fail:
    dr_film_destroy(&f);
    return s;
}

DrFilmState dr_film_state(DrFilm *f)
{
    DrFilmState st = {f->S, f->V, f->E, f->volume, f->u, f->pool, f->strand_speed};
    return st;
}

void dr_film_heights(const DrFilm *f, double *H)
{
    for (int i = 0; i < f->V; i++) {
        double r = f->radius[i];
        H[i] = sqrt(r * r + f->volume[i] / (DR_PI * f->lv[i]));
    }
}

/* ---- the film's share of the strands' solve ------------------------------------------------------------------- */

typedef struct LoadCtx {
    const DrFilm *f;
    const double *x, *v;
    double h;
    double *force, *dfdv;
} LoadCtx;

/* The Voronoi length of vertex i of the strand at x, computed as strand_geometry does (the same operations, so B_i
   here and a step's V̂ agree bit for bit). */
static double voronoi_at(const double *x, int n, int i)
{
    return voronoi(i > 0 ? edge_len(x, i - 1, NULL) : 0, i < n - 1 ? edge_len(x, i, NULL) : 0, n, i);
}

static void load_range(long begin, long end, void *vctx)
{
    const LoadCtx *c = vctx;
    const DrFilm *f = c->f;
    double rho = f->desc.density;
    DrVec3 g = f->desc.gravity;
    for (long k = begin; k < end; k++) {
        int o = f->offsets[k], n = f->offsets[k + 1] - o;
        const double *x = c->x + 3 * o, *V = f->volume + o;
        for (int i = 0; i < n; i++) {
            double B[9] = {0};
            DrVec3 W = dr_v3(0, 0, 0);
            for (int e = i - 1; e <= i; e++) { /* the edges on either side of vertex i */
                if (e < 0 || e > n - 2) continue;
                DrVec3 t;
                double le = edge_len(x, e, &t);
                double hat = V[e] * share(le, voronoi_at(x, n, e)) + V[e + 1] * share(le, voronoi_at(x, n, e + 1));
                double m = 0.5 * rho * hat;
                add_across(B, m, t);
                W = dr_v3_add(W, dr_v3_scale(perp(g, t), m));
            }
            double pool = (i == 0 ? f->pool[2 * k] : 0) + (i == n - 1 ? f->pool[2 * k + 1] : 0);
            for (int a = 0; a < 3; a++) B[4 * a] += rho * pool;
            W = dr_v3_add(W, dr_v3_scale(g, rho * pool));
            double Bv[3];
            dr_m3a_apply(B, c->v + 3 * (o + i), Bv);
            double *fo = c->force + 3 * (o + i), *D = c->dfdv + 9 * (o + i);
            fo[0] += Bv[0] / c->h + W.x;
            fo[1] += Bv[1] / c->h + W.y;
            fo[2] += Bv[2] / c->h + W.z;
            for (int q = 0; q < 9; q++) D[q] += -B[q] / c->h;
        }
    }
}

void dr_film_hair_load(const DrFilm *f, const double *x, const double *v, double h, double *force, double *dforce_dv)
{
    assert(h > 0);
    assert(f->V == 0 || (x && v && force && dforce_dv));
    LoadCtx c = {f, x, v, h, force, dforce_dv};
    dr_parallel_for(f->S, 16, load_range, &c);
}

/* ---- the bulk's pressure on the film (wet.h) -------------------------------------------------------------------- */

typedef struct PressureCtx {
    DrFilm *f;
    const double *x, *gradp;
    double h, *force, *impulse;
} PressureCtx;

static void pressure_range(long begin, long end, void *vctx)
{
    const PressureCtx *c = vctx;
    DrFilm *f = c->f;
    double rho = f->desc.density, h = c->h;
    for (long k = begin; k < end; k++) {
        int o = f->offsets[k], n = f->offsets[k + 1] - o, e0 = o - (int)k;
        const double *x = c->x + 3 * o, *V = f->volume + o, *gp = c->gradp + 3 * o;
        double *J = c->impulse + 3 * o, *fo = c->force + 3 * o;
        memset(J, 0, 3 * (size_t)n * sizeof(double));
        for (int e = 0; e < n - 1; e++) {
            DrVec3 t;
            double le = edge_len(x, e, &t);
            /* V̂_e on the step's starting shape, as the film's step and its load weigh it */
            double hat = V[e] * share(le, voronoi_at(x, n, e)) + V[e + 1] * share(le, voronoi_at(x, n, e + 1));
            DrVec3 ga = ld3(gp + 3 * e), gb = ld3(gp + 3 * e + 3);
            /* across the edge: half its film's −V̂ ∇p at each vertex, as its weight in the load */
            DrVec3 Fa = dr_v3_scale(perp(ga, t), -0.5 * hat), Fb = dr_v3_scale(perp(gb, t), -0.5 * hat);
            add3(fo + 3 * e, Fa);
            add3(fo + 3 * e + 3, Fb);
            add3(J + 3 * e, dr_v3_scale(Fa, h));
            add3(J + 3 * e + 3, dr_v3_scale(Fb, h));
            /* along it: the film's own speed, with the mean gradient of its two vertices */
            double gt = 0.5 * (dr_v3_dot(ga, t) + dr_v3_dot(gb, t));
            f->pacc[e0 + e] = -gt / rho;
            f->pimp[e0 + e] = -h * hat * gt;
            DrVec3 Pt = dr_v3_scale(t, -0.5 * h * hat * gt);
            add3(J + 3 * e, Pt);
            add3(J + 3 * e + 3, Pt);
        }
        /* the pools move with their end vertex: all of −V ∇p */
        for (int end = 0; end < 2; end++) {
            int i = end ? n - 1 : 0;
            double pv = f->pool[2 * k + end];
            if (!(pv > 0)) continue;
            DrVec3 F = dr_v3_scale(ld3(gp + 3 * i), -pv);
            add3(fo + 3 * i, F);
            add3(J + 3 * i, dr_v3_scale(F, h));
        }
    }
}

void dr_film_pressure(DrFilm *f, const double *x, const double *gradp, double h, double *force, double *impulse)
{
    assert(h > 0);
    assert(f->V == 0 || (x && gradp && force && impulse));
    PressureCtx c = {f, x, gradp, h, force, impulse};
    dr_parallel_for(f->S, 16, pressure_range, &c);
}

/* ---- a strand's step ------------------------------------------------------------------------------------------- */

/* One strand's view of the film's and the strands' arrays (local indices: vertices 0 … n − 1, edges 0 … n − 2). */
typedef struct Strand {
    const DrFilm *f;
    int k, n;
    double *V, *hat, *w, *fv, *ur, *q, *G, *hh, *p, *J, *Kinv, *pool;
    const double *t, *le, *lv, *r; /* geometry at the end of the step, radii */
    double *v;
    const double *m;
    const unsigned char *held;
    double to_pools;
    const double *t0, *pacc, *pimp; /* a step's: the tangents at its start, the bulk's pressure (DrFilm.pacc, pimp) */
    double h;                       /* the step */
} Strand;

static Strand strand_view(DrFilm *f, int k, double *v, const double *mass, const unsigned char *held)
{
    int o = f->offsets[k], e0 = o - k;
    Strand st = {f, k, f->offsets[k + 1] - o, f->volume + o, f->hat + e0, f->w + e0, f->fv + 3 * e0, f->ur + e0,
                 f->q + e0, f->G + o, f->hh + o, f->p + o, f->J + 3 * o, f->Kinv + 9 * o, f->pool + 2 * k,
                 f->t1 + 3 * e0, f->le1 + e0, f->lv1 + o, f->radius + o, v + 3 * o, mass ? mass + o : NULL,
                 held ? held + o : NULL, 0, NULL, NULL, NULL, 0};
    return st;
}

static inline DrVec3 tangent(const Strand *st, int e) { return ld3(st->t + 3 * e); }
/* The strand's speed along edge e, v̄_e·t_e. */
static inline double strand_speed(const Strand *st, int e) { return dr_v3_dot(tangent(st, e), vmean(st->v, e)); }

/* K_i⁻¹ = (m_i I + B_i)⁻¹ at every vertex from the current V̂ and pools; 0 at held vertices (their velocity is
   prescribed: what they receive is external). A singular K (a vertex without mass or film) gives NaN, which the
   step reports as non-finite. */
static void inverse_inertia(Strand *st)
{
    double rho = st->f->desc.density;
    for (int i = 0; i < st->n; i++) {
        double *Ki = st->Kinv + 9 * i;
        if (st->held && st->held[i]) {
            memset(Ki, 0, 9 * sizeof(double));
            continue;
        }
        double K[9] = {0};
        for (int e = i - 1; e <= i; e++)
            if (e >= 0 && e < st->n - 1) add_across(K, 0.5 * rho * st->hat[e], tangent(st, e));
        double pool = (i == 0 ? st->pool[0] : 0) + (i == st->n - 1 ? st->pool[1] : 0);
        for (int a = 0; a < 3; a++) K[4 * a] += rho * pool + st->m[i];
        if (!dr_m3a_inverse(K, Ki))
            for (int q = 0; q < 9; q++) Ki[q] = NAN;
    }
}

/* v_i += K_i⁻¹ J_i at every vertex, and J = 0. */
static void apply_impulses(Strand *st)
{
    for (int i = 0; i < st->n; i++) {
        double dv[3], *J = st->J + 3 * i;
        dr_m3a_apply(st->Kinv + 9 * i, J, dv);
        for (int a = 0; a < 3; a++) {
            st->v[3 * i + a] += dv[a];
            J[a] = 0;
        }
    }
}

/* Half of impulse P to each vertex of edge e. */
static inline void impulse_edge(Strand *st, int e, DrVec3 P)
{
    DrVec3 hP = dr_v3_scale(P, 0.5);
    add3(st->J + 3 * e, hP);
    add3(st->J + 3 * e + 3, hP);
}

/* 1. The film's momentum on the old tangents (x_old: t0, le0, lv0) with the strands' new velocities, written on the new
   ones: per edge M = ρ V̂⁰ (v̄ − (v̄·t⁰) t⁰ + w⁰ t⁰), w⁰ = u + strand_speed; the film keeps M·t¹ as its own momentum along
   t¹ (w¹ = M·t¹ / ρ V̂¹) and the rest, M − ρ V̂¹ (v̄ − (v̄·t¹) t¹ + w¹ t¹), goes to the edge's vertices. */
static void realign(Strand *st, const double *u, const double *speed, const double *t0, const double *le0,
                    const double *lv0)
{
    double rho = st->f->desc.density;
    for (int e = 0; e < st->n - 1; e++) {
        DrVec3 vb = vmean(st->v, e), ta = ld3(t0 + 3 * e), tb = tangent(st, e);
        double hat0 = st->V[e] * share(le0[e], lv0[e]) + st->V[e + 1] * share(le0[e], lv0[e + 1]);
        double hat1 = st->hat[e], w0 = u[e] + speed[e];
        DrVec3 M = dr_v3_scale(dr_v3_add(perp(vb, ta), dr_v3_scale(ta, w0)), rho * hat0);
        double w1 = hat1 > 0 ? dr_v3_dot(M, tb) / (rho * hat1) : dr_v3_dot(vb, tb);
        DrVec3 kept = dr_v3_scale(dr_v3_add(perp(vb, tb), dr_v3_scale(tb, w1)), rho * hat1);
        impulse_edge(st, e, dr_v3_sub(M, kept));
        st->w[e] = w1;
    }
    inverse_inertia(st);
    apply_impulses(st);
}

/* The film's speed relative to the strand on every edge (into ur). */
static void relative_speeds(Strand *st)
{
    for (int e = 0; e < st->n - 1; e++) st->ur[e] = st->w[e] - strand_speed(st, e);
}

/* The fluxes of a substep of dt (dt = 1: rates): through the edges (q), into the pools (*qr, *qt) and across the
   vertices between edges (G; G[0] = −qr, G[n−1] = qt), from ur. */
static void fluxes(Strand *st, double dt, double *qr, double *qt)
{
    int n = st->n;
    const double *V = st->V, *lv = st->lv, *le = st->le;
    for (int e = 0; e < n - 1; e++) {
        double u = st->ur[e];
        st->q[e] = u > 0 ? V[e] * (dt * u / lv[e]) : V[e + 1] * (dt * u / lv[e + 1]);
    }
    *qr = st->ur[0] < 0 ? V[0] * (dt * -st->ur[0] / lv[0]) : 0;
    *qt = st->ur[n - 2] > 0 ? V[n - 1] * (dt * st->ur[n - 2] / lv[n - 1]) : 0;
    st->G[0] = -*qr;
    st->G[n - 1] = *qt;
    for (int i = 1; i < n - 1; i++) st->G[i] = share(le[i - 1], lv[i]) * st->q[i] + share(le[i], lv[i]) * st->q[i - 1];
}

/* The largest substep the transport allows from the current speeds: no vertex sends out, and no edge loses, more
   than FILM_CFL of its volume; and the capillary limit (see the file's comment). INFINITY when nothing limits. */
static double substep_limit(Strand *st)
{
    const DrFilm *f = st->f;
    int n = st->n;
    relative_speeds(st);
    double rate = 0, qr, qt;
    for (int i = 0; i < n; i++) {
        if (!(st->V[i] > 0)) continue;
        double out = 0;
        if (i < n - 1) out += st->ur[i] > 0 ? st->ur[i] : (i == 0 ? -st->ur[i] : 0);
        if (i > 0) out += st->ur[i - 1] < 0 ? -st->ur[i - 1] : (i == n - 1 ? st->ur[i - 1] : 0);
        rate = fmax(rate, out / st->lv[i]);
    }
    fluxes(st, 1.0, &qr, &qt);
    for (int b = 0; b < n - 1; b++) {
        double out = (st->G[b] < 0 ? -st->G[b] : 0) + (st->G[b + 1] > 0 ? st->G[b + 1] : 0);
        if (out > 0) rate = fmax(rate, out / st->hat[b]);
    }
    double dt = rate > 0 ? FILM_CFL / rate : INFINITY;
    if (!isfinite(rate)) return NAN;
    double sigma = f->desc.surface_tension, rho = f->desc.density;
    if (sigma > 0) {
        double c1 = 0, c2 = 0, c3 = 0, mr = 0;
        for (int e = 0; e < n - 1; e++) c1 = fmax(c1, 2 / st->le[e]);
        for (int i = 0; i < n; i++) {
            double A = st->V[i] / st->lv[i], H = sqrt(st->r[i] * st->r[i] + A / DR_PI), s3 = 0, film = 0;
            int deg = 0;
            for (int e = i - 1; e <= i; e++) {
                if (e < 0 || e > n - 2) continue;
                deg++;
                s3 += fmax(st->V[e] / st->lv[e], st->V[e + 1] / st->lv[e + 1]);
                film += 0.5 * rho * st->hat[e];
            }
            c2 = fmax(c2, deg / st->lv[i]);
            c3 = fmax(c3, s3 / (2 * DR_PI * H * st->lv[i]));
            if (!(st->held && st->held[i])) {
                film += rho * ((i == 0 ? st->pool[0] : 0) + (i == n - 1 ? st->pool[1] : 0));
                mr = fmax(mr, film / st->m[i]);
            }
        }
        double lambda = sigma / rho * c1 * c1 * c2 * c3 * (1 + mr);
        if (lambda > 0) dt = fmin(dt, 1 / sqrt(lambda));
    }
    return dt;
}

/* 2a. Transport over dt: continuity by upwind edge fluxes and the pools' fluxes, the edges' momentum by the fluxes
   across the vertices (each carrying the film velocity of the edge it leaves), then the max_ratio limit; the
   momentum that arrives across a strand goes to the strand. Leaves hat, K⁻¹ and v updated. */
static void transport(Strand *st, double dt)
{
    const DrFilm *f = st->f;
    int n = st->n;
    double rho = f->desc.density, qr, qt;
    double *V = st->V;
    /* the film velocity of every edge before the substep */
    for (int e = 0; e < n - 1; e++) {
        DrVec3 vb = vmean(st->v, e), t = tangent(st, e);
        DrVec3 fv = dr_v3_add(perp(vb, t), dr_v3_scale(t, st->w[e]));
        st->fv[3 * e] = fv.x;
        st->fv[3 * e + 1] = fv.y;
        st->fv[3 * e + 2] = fv.z;
    }
    relative_speeds(st);
    fluxes(st, dt, &qr, &qt);
    /* continuity (S9): what leaves a vertex is taken from what it held, then what arrives is added */
    for (int i = 0; i < n; i++) {
        double out = 0, in = 0;
        if (i < n - 1) {
            if (st->q[i] > 0) out += st->q[i];
            else in += -st->q[i];
        }
        if (i > 0) {
            if (st->q[i - 1] > 0) in += st->q[i - 1];
            else out += -st->q[i - 1];
        }
        if (i == 0) out += qr;
        if (i == n - 1) out += qt;
        V[i] = (V[i] - out) + in;
    }
    /* momentum (S16, S17): each edge keeps what did not leave at its own w and takes in what arrives */
    for (int b = 0; b < n - 1; b++) {
        double Gl = st->G[b], Gr = st->G[b + 1];
        double keep = st->hat[b] - ((Gl < 0 ? -Gl : 0) + (Gr > 0 ? Gr : 0));
        double num = keep * st->w[b], den = keep;
        DrVec3 vb = vmean(st->v, b), t = tangent(st, b);
        for (int side = 0; side < 2; side++) {
            double d = side == 0 ? (Gl > 0 ? Gl : 0) : (Gr < 0 ? -Gr : 0);
            if (!(d > 0)) continue;
            int a = side == 0 ? b - 1 : b + 1;
            DrVec3 fa = ld3(st->fv + 3 * a);
            num += d * dr_v3_dot(fa, t);
            den += d;
            impulse_edge(st, b, dr_v3_scale(perp(dr_v3_sub(fa, vb), t), rho * d));
        }
        st->w[b] = den > 0 ? num / den : dr_v3_dot(vb, t);
    }
    /* the pools: what reaches an end joins its pool, which moves with the end vertex */
    if (qr > 0) {
        st->pool[0] += qr;
        add3(st->J, dr_v3_scale(dr_v3_sub(ld3(st->fv), ld3(st->v)), rho * qr));
    }
    if (qt > 0) {
        st->pool[1] += qt;
        add3(st->J + 3 * (n - 1), dr_v3_scale(dr_v3_sub(ld3(st->fv + 3 * (n - 2)), ld3(st->v + 3 * (n - 1))), rho * qt));
    }
    st->to_pools += qr + qt;
    /* the max_ratio limit: the excess of a vertex, with the momentum of the edges it leaves, to the nearer pool */
    double R2 = f->desc.max_ratio * f->desc.max_ratio - 1, L = 0, s = 0;
    for (int e = 0; e < n - 1; e++) L += st->le[e];
    for (int i = 0; i < n; i++) {
        if (i > 0) s += st->le[i - 1];
        double vmax = DR_PI * st->r[i] * st->r[i] * R2 * st->lv[i];
        if (!(V[i] > vmax)) continue;
        double ex = V[i] - vmax;
        V[i] -= ex;
        int end = s < L - s ? 0 : n - 1;
        DrVec3 vend = ld3(st->v + 3 * end), P = dr_v3(0, 0, 0);
        for (int e = i - 1; e <= i; e++) {
            if (e < 0 || e > n - 2) continue;
            DrVec3 vb = vmean(st->v, e), t = tangent(st, e);
            DrVec3 fv = dr_v3_add(perp(vb, t), dr_v3_scale(t, st->w[e]));
            P = dr_v3_add(P, dr_v3_scale(dr_v3_sub(fv, vend), rho * ex * share(st->le[e], st->lv[i])));
        }
        add3(st->J + 3 * end, P);
        st->pool[end == 0 ? 0 : 1] += ex;
        st->to_pools += ex;
    }
    edge_volumes(V, st->le, st->lv, n, st->hat);
    inverse_inertia(st);
    apply_impulses(st);
}

/* 2b. Gravity along the strand (external) and the Laplace pressure p = −σ ∂²h/∂s² (its reaction on the strand). */
static void forces(Strand *st, double dt)
{
    const DrFilm *f = st->f;
    int n = st->n;
    double rho = f->desc.density, sigma = f->desc.surface_tension;
    for (int e = 0; e < n - 1; e++) st->w[e] += dt * dr_v3_dot(f->desc.gravity, tangent(st, e));
    /* the bulk's pressure (dr_film_pressure): an acceleration of the film along each edge, as gravity's, with the
       strand taking the difference between the impulse booked for the substep (its share dt/h, along t⁰ with V̂⁰) and
       the one the film got (along t, with V̂ now): film and strand get exactly what was booked */
    bool pushed = false;
    for (int e = 0; st->pacc && e < n - 1; e++) {
        if (st->pacc[e] == 0.0 && st->pimp[e] == 0.0) continue;
        double given = st->hat[e] > 0 ? dt * st->pacc[e] : 0.0;
        st->w[e] += given;
        DrVec3 booked = dr_v3_scale(ld3(st->t0 + 3 * e), dt / st->h * st->pimp[e]);
        impulse_edge(st, e, dr_v3_sub(booked, dr_v3_scale(tangent(st, e), rho * st->hat[e] * given)));
        pushed = true;
    }
    if (!(sigma > 0)) {
        if (pushed) apply_impulses(st);
        return;
    }
    for (int i = 0; i < n; i++) st->hh[i] = thickness(st->V[i] / st->lv[i], st->r[i]);
    for (int i = 0; i < n; i++) {
        double d2 = 0; /* ∂²h/∂s² in the vertex's control volume, zero slope beyond the ends */
        if (i < n - 1) d2 += (st->hh[i + 1] - st->hh[i]) / st->le[i];
        if (i > 0) d2 -= (st->hh[i] - st->hh[i - 1]) / st->le[i - 1];
        st->p[i] = -sigma * d2 / st->lv[i];
    }
    for (int e = 0; e < n - 1; e++) {
        if (!(st->hat[e] > 0)) continue;
        double dp = st->p[e + 1] - st->p[e];
        st->w[e] -= dt * dp / (rho * st->le[e]);
        impulse_edge(st, e, dr_v3_scale(tangent(st, e), dt * (st->hat[e] / st->le[e]) * dp));
    }
    apply_impulses(st);
}

/* 2c. Implicit two-body friction between each edge's film and the strand (see the file's comment), even edges then
   odd ones. A dry edge's film is at rest relative to the strand. */
static void friction(Strand *st, double dt)
{
    const DrFilm *f = st->f;
    int n = st->n;
    double rho = f->desc.density, scale = f->desc.friction * 6 * DR_PI * f->desc.viscosity;
    if (!(scale > 0)) return;
    for (int colour = 0; colour < 2; colour++)
        for (int e = colour; e < n - 1; e += 2) {
            DrVec3 t = tangent(st, e);
            double s = strand_speed(st, e);
            if (!(st->hat[e] > 0)) {
                st->w[e] = s;
                continue;
            }
            double mf = rho * st->hat[e], r = st->w[e] - s;
            double ta[3] = {t.x, t.y, t.z}, ka[3], kb[3];
            dr_m3a_apply(st->Kinv + 9 * e, ta, ka);
            dr_m3a_apply(st->Kinv + 9 * (e + 1), ta, kb);
            double k = 0.25 * ((ta[0] * ka[0] + ta[1] * ka[1] + ta[2] * ka[2]) + (ta[0] * kb[0] + ta[1] * kb[1] + ta[2] * kb[2]));
            double A = st->hat[e] / st->le[e], re = 0.5 * (st->r[e] + st->r[e + 1]);
            double c = scale * re / (rho * A * thickness(A, re));
            double rn = r / (1 + dt * c * (1 + mf * k));
            double j = (r - rn) * mf / (1 + mf * k); /* on the strand, along t */
            st->w[e] -= j / mf;
            for (int a = 0; a < 3; a++) {
                st->v[3 * e + a] += 0.5 * j * ka[a];
                st->v[3 * (e + 1) + a] += 0.5 * j * kb[a];
            }
        }
}

typedef struct StepCtx {
    DrFilm *f;
    const double *x_old, *x, *mass;
    double *v;
    const unsigned char *held;
    double h;
} StepCtx;

static bool strand_finite(const Strand *st, const double *u)
{
    bool ok = isfinite(st->pool[0]) && isfinite(st->pool[1]);
    for (int i = 0; i < st->n; i++)
        ok = ok && isfinite(st->V[i]) && isfinite(st->v[3 * i]) && isfinite(st->v[3 * i + 1]) && isfinite(st->v[3 * i + 2]);
    for (int e = 0; e < st->n - 1; e++) ok = ok && isfinite(u[e]);
    return ok;
}

static DrStatus strand_step(const StepCtx *c, int k, int *nsub, double *to_pools)
{
    DrFilm *f = c->f;
    int o = f->offsets[k], n = f->offsets[k + 1] - o, e0 = o - k;
    Strand st = strand_view(f, k, c->v, c->mass, c->held);
    st.t0 = f->t0 + 3 * e0;
    st.pacc = f->pacc + e0;
    st.pimp = f->pimp + e0;
    st.h = c->h;
    double *u = f->u + e0, *speed = f->strand_speed + e0;
    strand_geometry(c->x_old + 3 * o, n, f->t0 + 3 * e0, f->le0 + e0, f->lv0 + o);
    strand_geometry(c->x + 3 * o, n, f->t1 + 3 * e0, f->le1 + e0, f->lv1 + o);
    edge_volumes(st.V, st.le, st.lv, n, st.hat);
    /* 1. the film's momentum onto the new tangents */
    realign(&st, u, speed, f->t0 + 3 * e0, f->le0 + e0, f->lv0 + o);
    /* 2. substeps until h is covered */
    double rem = c->h, cap = c->h / f->desc.substeps;
    int count = 0;
    while (rem > 0) {
        double lim = fmin(cap, substep_limit(&st));
        double want = rem / lim;
        if (!(lim > 0) || !(want < FILM_MAX_SUBSTEPS - count)) return DR_ERR_RUNTIME;
        long left = (long)ceil(want * (1 - 1e-12));
        if (left < 1) left = 1;
        double dt = left == 1 ? rem : rem / (double)left;
        transport(&st, dt);
        forces(&st, dt);
        friction(&st, dt);
        rem = left == 1 ? 0 : rem - dt;
        count++;
    }
    /* the film's speed relative to the strand, and the strand's speed it is relative to */
    for (int e = 0; e < n - 1; e++) {
        double s = strand_speed(&st, e);
        u[e] = st.w[e] - s;
        speed[e] = s;
    }
    memcpy(f->lv + o, f->lv1 + o, (size_t)n * sizeof(double));
    *nsub = count;
    *to_pools = st.to_pools;
    return strand_finite(&st, u) ? DR_OK : DR_ERR_RUNTIME;
}

static void step_range(long begin, long end, void *vctx)
{
    const StepCtx *c = vctx;
    for (long k = begin; k < end; k++) c->f->status[k] = strand_step(c, (int)k, &c->f->nsub[k], &c->f->to_pools[k]);
}

/* The step's inputs (state, lengths, velocities), to restore when it fails. */
static void save_state(DrFilm *f, const double *v, bool restore, double *vout)
{
    size_t V = (size_t)f->V, E = (size_t)f->E, S = (size_t)f->S;
    struct { double *a; size_t n; } parts[] = {{f->volume, V}, {f->u, E}, {f->pool, 2 * S}, {f->strand_speed, E},
                                               {f->lv, V}, {vout, 3 * V}};
    double *p = f->save;
    for (size_t k = 0; k < sizeof parts / sizeof parts[0]; k++) {
        if (parts[k].n == 0) continue;
        if (restore) memcpy(parts[k].a, p, parts[k].n * sizeof(double));
        else memcpy(p, k == 5 ? v : parts[k].a, parts[k].n * sizeof(double));
        p += parts[k].n;
    }
}

DrStatus dr_film_step(DrFilm *f, const double *x_old, const double *x, double *v, const double *hair_mass,
                      const unsigned char *held, double h, DrFilmStats *stats, DrError *err)
{
    assert(h > 0 && isfinite(h));
    assert(f->V == 0 || (x_old && x && v && hair_mass));
    save_state(f, v, false, v);
    StepCtx c = {f, x_old, x, hair_mass, v, held, h};
    dr_parallel_for(f->S, 8, step_range, &c);
    for (int k = 0; k < f->S; k++)
        if (f->status[k] != DR_OK) {
            save_state(f, v, true, v); /* the pressure is kept: the step may be taken again */
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "wet film: strand %d's film became non-finite over a step of %g s (a non-finite hair "
                                "position, velocity or mass, or more than %d film substeps); the film and the hair "
                                "velocities are left as they were before the step",
                                k, h, FILM_MAX_SUBSTEPS);
        }
    memset(f->pacc, 0, (size_t)f->E * sizeof(double));
    memset(f->pimp, 0, (size_t)f->E * sizeof(double));
    if (stats) {
        int most = 0;
        double to_pools = 0;
        for (int k = 0; k < f->S; k++) {
            most = f->nsub[k] > most ? f->nsub[k] : most;
            to_pools += f->to_pools[k];
        }
        stats->substeps += most;
        stats->to_pools += to_pools;
        dr_film_measure(f, x, v, stats);
    }
    return DR_OK;
}

/* ---- measure ---------------------------------------------------------------------------------------------------- */

void dr_film_measure(const DrFilm *f, const double *x, const double *v, DrFilmStats *stats)
{
    double rho = f->desc.density, vol = 0, pools = 0, ratio = 0, ke = 0;
    DrVec3 P = dr_v3(0, 0, 0);
    for (int k = 0; k < f->S; k++) {
        int o = f->offsets[k], n = f->offsets[k + 1] - o, e0 = o - k;
        const double *xs = x + 3 * o, *vs = v + 3 * o, *V = f->volume + o;
        for (int i = 0; i < n; i++) {
            double r = f->radius[o + i];
            vol += V[i];
            ratio = fmax(ratio, sqrt(r * r + V[i] / (DR_PI * voronoi_at(xs, n, i))) / r);
        }
        for (int e = 0; e < n - 1; e++) {
            DrVec3 t;
            double le = edge_len(xs, e, &t);
            double hat = V[e] * share(le, voronoi_at(xs, n, e)) + V[e + 1] * share(le, voronoi_at(xs, n, e + 1));
            DrVec3 fv = dr_v3_add(vmean(vs, e), dr_v3_scale(t, f->u[e0 + e]));
            P = dr_v3_add(P, dr_v3_scale(fv, rho * hat));
            ke += 0.5 * rho * hat * dr_v3_dot(fv, fv);
        }
        for (int end = 0; end < 2; end++) {
            double pv = f->pool[2 * k + end];
            DrVec3 ve = ld3(vs + 3 * (end == 0 ? 0 : n - 1));
            pools += pv;
            P = dr_v3_add(P, dr_v3_scale(ve, rho * pv));
            ke += 0.5 * rho * pv * dr_v3_dot(ve, ve);
        }
    }
    stats->volume = vol;
    stats->pools = pools;
    stats->max_ratio = ratio;
    stats->momentum = P;
    stats->kinetic = ke;
}

/* ---- exchange between vertices ---------------------------------------------------------------------------------- */

typedef struct ExchangeCtx {
    DrFilm *f;
    const double *x, *dV, *mass;
    double *v;
    DrVec3 vmix;        /* the velocity of what arrives (P_in NULL) */
    const double *P_in; /* 3V or NULL: the momentum of what arrives at each vertex */
    double *P_out;      /* 3V or NULL: the momentum of what leaves each vertex */
} ExchangeCtx;

/* Pass 1, per strand: the geometry at x, the edges' V̂ and w, and what leaves: the volume each edge loses (into q)
   and the momentum it takes with it (partial[4k..4k+2]); the volume that arrives (partial[4k+3]). */
static void exchange_leave(long begin, long end, void *vctx)
{
    const ExchangeCtx *c = vctx;
    DrFilm *f = c->f;
    double rho = f->desc.density;
    for (long k = begin; k < end; k++) {
        int o = f->offsets[k], n = f->offsets[k + 1] - o, e0 = o - (int)k;
        strand_geometry(c->x + 3 * o, n, f->t1 + 3 * e0, f->le1 + e0, f->lv1 + o);
        Strand st = strand_view(f, (int)k, c->v, c->mass, NULL);
        edge_volumes(st.V, st.le, st.lv, n, st.hat);
        const double *dV = c->dV + o;
        DrVec3 P = dr_v3(0, 0, 0);
        double in = 0;
        for (int e = 0; e < n - 1; e++) {
            st.w[e] = f->u[e0 + e] + strand_speed(&st, e);
            st.q[e] = 0;
        }
        for (int i = 0; i < n; i++) {
            if (dV[i] > 0) in += dV[i];
            if (!(dV[i] < 0)) continue;
            /* a non-finite film (a blow-up elsewhere) is left as it is: the frame's end reports it by name */
            if (!isfinite(st.V[i]) || !isfinite(dV[i])) continue;
            assert(st.V[i] + dV[i] >= 0);
            DrVec3 Pi = dr_v3(0, 0, 0);
            for (int e = i - 1; e <= i; e++) {
                if (e < 0 || e > n - 2) continue;
                double d = -dV[i] * share(st.le[e], st.lv[i]);
                DrVec3 vb = vmean(st.v, e), t = tangent(&st, e);
                Pi = dr_v3_add(Pi, dr_v3_scale(dr_v3_add(perp(vb, t), dr_v3_scale(t, st.w[e])), rho * d));
                st.q[e] += d;
            }
            P = dr_v3_add(P, Pi);
            if (c->P_out) {
                double *po = c->P_out + 3 * (o + i);
                po[0] = Pi.x, po[1] = Pi.y, po[2] = Pi.z;
            }
            st.V[i] += dV[i];
        }
        double *pk = f->partial + 4 * k;
        pk[0] = P.x;
        pk[1] = P.y;
        pk[2] = P.z;
        pk[3] = in;
    }
}

/* Pass 2, per strand: what arrives, at the velocity vmix; the new w, the strands' share of the momentum, u. */
static void exchange_arrive(long begin, long end, void *vctx)
{
    const ExchangeCtx *c = vctx;
    DrFilm *f = c->f;
    double rho = f->desc.density;
    for (long k = begin; k < end; k++) {
        int o = f->offsets[k], n = f->offsets[k + 1] - o, e0 = o - (int)k;
        Strand st = strand_view(f, (int)k, c->v, c->mass, NULL);
        const double *dV = c->dV + o;
        for (int e = 0; e < n - 1; e++) {
            double keep = st.hat[e] - st.q[e], in = 0;
            DrVec3 M = dr_v3(0, 0, 0); /* the momentum arriving on the edge (P_in) */
            for (int i = e; i <= e + 1; i++)
                if (dV[i] > 0) {
                    double sh = share(st.le[e], st.lv[i]);
                    in += dV[i] * sh;
                    if (c->P_in) M = dr_v3_add(M, dr_v3_scale(ld3(c->P_in + 3 * (o + i)), sh));
                }
            if (!(in > 0)) continue;
            DrVec3 vb = vmean(st.v, e), t = tangent(&st, e);
            if (c->P_in) {
                st.w[e] = (keep * st.w[e] + dr_v3_dot(M, t) / rho) / (keep + in);
                impulse_edge(&st, e, perp(dr_v3_sub(M, dr_v3_scale(vb, rho * in)), t));
                continue;
            }
            st.w[e] = (keep * st.w[e] + in * dr_v3_dot(c->vmix, t)) / (keep + in);
            impulse_edge(&st, e, dr_v3_scale(perp(dr_v3_sub(c->vmix, vb), t), rho * in));
        }
        for (int i = 0; i < n; i++)
            if (dV[i] > 0) st.V[i] += dV[i];
        edge_volumes(st.V, st.le, st.lv, n, st.hat);
        inverse_inertia(&st);
        apply_impulses(&st);
        for (int e = 0; e < n - 1; e++) {
            double s = strand_speed(&st, e);
            f->u[e0 + e] = st.w[e] - s;
            f->strand_speed[e0 + e] = s;
        }
        memcpy(f->lv + o, f->lv1 + o, (size_t)n * sizeof(double));
    }
}

void dr_film_exchange(DrFilm *f, const double *x, const double *dV, double *v, const double *hair_mass)
{
    assert(f->V == 0 || (x && dV && v && hair_mass));
    ExchangeCtx c = {f, x, dV, hair_mass, v, dr_v3(0, 0, 0), NULL, NULL};
    dr_parallel_for(f->S, 16, exchange_leave, &c);
    DrVec3 P = dr_v3(0, 0, 0);
    double in = 0;
    for (int k = 0; k < f->S; k++) {
        P = dr_v3_add(P, ld3(f->partial + 4 * k));
        in += f->partial[4 * k + 3];
    }
    c.vmix = in > 0 ? dr_v3_scale(P, 1 / (f->desc.density * in)) : dr_v3(0, 0, 0);
    dr_parallel_for(f->S, 16, exchange_arrive, &c);
}

void dr_film_transfer(DrFilm *f, const double *x, const double *dV, const double *P_in, double *P_out, double *v,
                      const double *hair_mass)
{
    assert(f->V == 0 || (x && dV && P_in && P_out && v && hair_mass));
    ExchangeCtx c = {f, x, dV, hair_mass, v, dr_v3(0, 0, 0), P_in, P_out};
    if (f->V > 0) memset(P_out, 0, 3 * (size_t)f->V * sizeof(double));
    dr_parallel_for(f->S, 16, exchange_leave, &c);
    dr_parallel_for(f->S, 16, exchange_arrive, &c);
}

const DrFilmDesc *dr_film_desc(const DrFilm *f) { return &f->desc; }
const int *dr_film_offsets(const DrFilm *f) { return f->offsets; }
const double *dr_film_radius(const DrFilm *f) { return f->radius; }
const double *dr_film_lengths(const DrFilm *f) { return f->lv; }
