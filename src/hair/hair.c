/* Rod sets: discrete elastic rods stepped by the Lagrangian solver (see hair.h; fei2017 §S4, PHYSICS §4).
 *
 * One step, in the phases of hair.h:
 *   predict 1. the reference state is the current one (tangents, time-transported directors a1, reference twists);
 *           2. root DOFs get the velocity that lands them on the scalp pose at the end of the step;
 *           3. per strand (in parallel, one Lagrangian object each): stretching, bending and twisting groups with
 *              last step's λ for the geometric stiffness, their viscous copies for internal damping, and vertex–
 *              collider contacts; then hair–hair contacts (inter-object, K_G) from a spatial hash;
 *   solve   4. the solve (block-preconditioned PCG) with the external load, re-callable;
 *   commit  5. multipliers, then Coulomb friction at collider contacts;
 *           6. positions and twists advance, directors are transported in time, reference twists follow.
 * The DOF vector of a strand interleaves x_j and θ^j (src/hair/rod.h), so its block has half-bandwidth 10. */
#include "hair/hair.h"

#include <stdlib.h>
#include <string.h>

#include "contact/contact.h"
#include "hair/rod.h"

#define ROD_KD 10

/* Phases of a step (hair.h): what the last phase call left. */
enum { PHASE_NONE, PHASE_DOFS, PHASE_PREDICTED, PHASE_SOLVED };

void dr_rod_set_desc_default(DrRodSetDesc *d)
{
    memset(d, 0, sizeof *d);
    d->roots = DR_ROD_ROOTS_CLAMPED;
    d->tips = DR_ROD_ROOTS_FREE;
    d->gravity = dr_v3(0, -9.81, 0);
    d->geometric_stiffness = true;
    dr_lag_desc_default(&d->solver);
    d->hair_contact = false;
    d->collider_stiffness = 1e4;
}


typedef struct HairContact {
    int e0, e1;      /* global edges */
    double s, t;     /* closest-point parameters on each */
    double dist;     /* distance of the closest points */
    DrVec3 n;        /* unit, from edge e1's point towards e0's */
    double rr;       /* contact distance r_a + t_a + r_b + t_b */
    double k, mu;    /* stiffness, friction */
    double damping;  /* s: viscous row along n with coefficient damping·k, 0 = none */
} HairContact;

struct DrRodSet {
    DrRodSetDesc desc;
    int S, V, E, I;            /* strands, vertices, edges, interior vertices */
    int *offsets;              /* S + 1 */
    int nbatches;
    int *batch_offsets;        /* nbatches + 1 (strands) */
    unsigned *batch_group, *batch_mask;
    DrRodPairResponse *pairs;  /* nbatches², or NULL: the batches' own settings (desc.pairs) */
    int *strand_batch;         /* S */
    DrRodMaterial *materials;  /* per batch */
    DrRodBatch *batch;         /* per batch (the groom pointers are not kept past create) */
    DrRodRoots *roots;         /* per batch: how its roots follow its scalp (desc.roots or desc.batch_roots) */

    /* rest */
    double *lbar;              /* E */
    double *kbar;              /* 4 I */
    double *tbar;              /* I */
    double *lv;                /* I, Voronoi lengths */
    double *vmass;             /* V */
    double *tinertia;          /* E, ρ (πr⁴/2) l̄ */
    double *radius;            /* S: the root radius */
    double *vradius;           /* V: the radius at each vertex (tapered from root to tip) */
    double *eks;               /* E: stretching stiffness E π r_e² of each edge (r_e its ends' mean radius) */
    double *ibend, *itwist;    /* I: bending E π r⁴/4 and twisting G π r⁴/2 at each interior vertex */
    bool tapered;              /* some strand's radius varies */
    double *root_rest;         /* S × 2 × 3: rest positions of the first two vertices */
    double *m1_rest;           /* S × 3: rest material director of edge 0 */
    double *tip_rest;          /* S × 2 × 3: starting positions of the last two vertices (desc.tips) */

    /* state */
    double *x, *v, *theta, *theta_dot, *a1, *m, *t, *len;
    double *lambda;            /* E + 4 I + I: stretch, bend, twist */
    long nlambda;

    /* solver */
    DrLag *lag;                /* desc.system, or the set's own */
    bool own_system;
    int *dof0;                 /* S: first DOF of each strand in the system */
    int ndof;                  /* the set's own DOFs */
    /* the system's per-DOF arrays (dr_lag_dofs), indexed by the system's DOFs; fetched by every predict */
    double *dmass, *qdot, *fext, *qdot_p, *qdot_out, *fload;
    unsigned char *pres;
    /* collider contacts (per vertex) */
    unsigned char *cflag;
    double *cnormal, *cvel, *clambda, *cfric;
    /* hair contacts */
    HairContact *hc;
    size_t nhc, cap_hc;
    bool hc_slack;             /* the first step's contacts sized hc */
    DrBroadPhase *bp;        /* hair–hair candidates (src/contact), its buffers kept from step to step */
    /* step scratch to restore on failure */
    double *save;
    double *t_old;             /* 3 E: tangents at the start of the step */
    int *edge_strand, *edge_local; /* E: each edge's strand and its index along it */
    double h_step;             /* the step being taken */
    DrArena *arena;            /* per-step scratch, reset by predict */
    int phase;
    int ncollider_contacts;    /* of the prediction */
    double seconds_build, seconds_contact; /* of the prediction */
    /* the external load of a solve and the samples (hair.h) */
    int *vdof;                 /* V: first DOF of each vertex */
    double *dload;             /* 9V: the last solve's ∂f/∂v per vertex (its load), for the inertia friction sees */
    bool has_dload;
    double *s_v, *s_radius, *s_length, *s_tangent;
    unsigned char *s_held;
};

static inline int edge_index(const DrRodSet *r, int s, int local) { return r->offsets[s] - s + local; }
static inline double dist3(const double *a, const double *b)
{
    return sqrt((b[0] - a[0]) * (b[0] - a[0]) + (b[1] - a[1]) * (b[1] - a[1]) + (b[2] - a[2]) * (b[2] - a[2]));
}
static inline int interior_index(const DrRodSet *r, int s, int i) { return r->offsets[s] - 2 * s + (i - 1); }

/* ---- creation ------------------------------------------------------------------------------------------ */

static DrStatus check_material(const DrRodMaterial *m, int batch, DrError *err)
{
    if (!(m->radius > 0) || !(m->density > 0) || !(m->youngs > 0) || !(m->shear > 0) || !(m->damping >= 0) ||
        !(m->tip_radius >= 0) || !isfinite(m->radius + m->density + m->youngs + m->shear + m->damping + m->tip_radius))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "rod material of groom %d: radius %g m, density %g kg/m³, Young's modulus %g Pa, shear "
                            "modulus %g Pa must be positive and damping %g s non-negative",
                            batch, m->radius, m->density, m->youngs, m->shear, m->damping);
    return DR_OK;
}

void dr_rod_set_destroy(DrRodSet **rp)
{
    if (!rp || !*rp) return;
    DrRodSet *r = *rp;
    void *arrays[] = {r->offsets, r->batch_offsets, r->batch_group, r->batch_mask, r->pairs, r->strand_batch, r->materials, r->batch, r->roots,
                      r->lbar, r->kbar, r->tbar, r->lv, r->vmass, r->tinertia, r->radius, r->vradius, r->eks,
                      r->ibend, r->itwist, r->root_rest,
                      r->m1_rest, r->tip_rest, r->t_old, r->edge_strand, r->edge_local, r->x, r->v, r->theta, r->theta_dot, r->a1, r->m, r->t, r->len, r->lambda,
                      r->dof0, r->cflag, r->cnormal,
                      r->cvel, r->clambda, r->cfric, r->hc, r->save, r->vdof, r->dload, r->s_v, r->s_radius, r->s_length, r->s_tangent, r->s_held};
    for (size_t k = 0; k < sizeof arrays / sizeof arrays[0]; k++) free(arrays[k]);
    if (r->own_system) dr_lag_destroy(&r->lag);
    dr_broad_phase_destroy(&r->bp);
    dr_arena_destroy(&r->arena);
    free(r);
    *rp = NULL;
}

#define ALLOC(ptr, count)                                                                                           \
    do {                                                                                                            \
        s = dr_calloc((size_t)(count) > 0 ? (size_t)(count) : 1, sizeof *(ptr), &(ptr), err);                       \
        if (s != DR_OK) goto fail;                                                                                  \
    } while (0)

DrStatus dr_rod_set_create(const DrRodSetDesc *desc, const DrRodBatch *batches, int nbatches, DrRodSet **out,
                           DrError *err)
{
    *out = NULL;
    DrStatus s = DR_OK;
    if (nbatches < 1) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "a rod set needs at least one groom");
    long S = 0, V = 0;
    for (int b = 0; b < nbatches; b++) {
        DR_TRY(check_material(&batches[b].material, b, err));
        const DrGroom *g = batches[b].groom;
        if (g->nstrands < 1) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom %d has no strands", b);
        for (int k = 0; k < g->nstrands; k++) {
            int nv = g->offsets[k + 1] - g->offsets[k];
            if (nv < 2)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom %d strand %d has %d vertices; a strand needs 2",
                                    b, k, nv);
            for (int j = g->offsets[k]; j + 1 < g->offsets[k + 1]; j++) {
                const double *p = g->x + 3 * j, *q = p + 3;
                double d = sqrt((q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1]) + (q[2] - p[2]) * (q[2] - p[2]));
                if (!(d > 1e-12) || !isfinite(d))
                    return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                        "groom %d strand %d has a zero-length or non-finite edge at vertex %d", b, k,
                                        j - g->offsets[k]);
            }
        }
        S += g->nstrands;
        V += g->offsets[g->nstrands];
    }
    if (4 * V > 2000000000L) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "too many hair vertices (%ld)", V);
    DrRodSet *r = NULL;
    DR_TRY(dr_calloc(1, sizeof *r, &r, err));
    r->desc = *desc;
    r->S = (int)S;
    r->V = (int)V;
    r->E = (int)(V - S);
    r->I = (int)(V - 2 * S);
    r->nbatches = nbatches;
    ALLOC(r->offsets, S + 1);
    ALLOC(r->batch_offsets, nbatches + 1);
    ALLOC(r->batch_group, nbatches);
    ALLOC(r->batch_mask, nbatches);
    if (desc->pairs) ALLOC(r->pairs, (long)nbatches * nbatches);
    ALLOC(r->strand_batch, S);
    ALLOC(r->materials, nbatches);
    ALLOC(r->batch, nbatches);
    ALLOC(r->roots, nbatches);
    ALLOC(r->lbar, r->E);
    ALLOC(r->kbar, 4 * r->I);
    ALLOC(r->tbar, r->I);
    ALLOC(r->lv, r->I);
    ALLOC(r->vmass, V);
    ALLOC(r->tinertia, r->E);
    ALLOC(r->radius, S);
    ALLOC(r->vradius, V);
    ALLOC(r->eks, r->E);
    ALLOC(r->ibend, r->I);
    ALLOC(r->itwist, r->I);
    ALLOC(r->root_rest, 6 * S);
    ALLOC(r->m1_rest, 3 * S);
    ALLOC(r->tip_rest, 6 * S);
    ALLOC(r->x, 3 * V);
    ALLOC(r->v, 3 * V);
    ALLOC(r->theta, r->E);
    ALLOC(r->theta_dot, r->E);
    ALLOC(r->a1, 3 * r->E);
    ALLOC(r->m, r->I);
    ALLOC(r->t, 3 * r->E);
    ALLOC(r->len, r->E);
    r->nlambda = (long)r->E + 5L * r->I;
    ALLOC(r->lambda, r->nlambda);
    ALLOC(r->dof0, S);
    ALLOC(r->cflag, V);
    ALLOC(r->cnormal, 3 * V);
    ALLOC(r->cvel, 3 * V);
    ALLOC(r->clambda, V);
    ALLOC(r->cfric, V);
    ALLOC(r->save, 6 * V + 2 * r->E + 3 * r->E + r->I + r->nlambda);
    ALLOC(r->t_old, 3 * r->E);
    ALLOC(r->edge_strand, r->E);
    ALLOC(r->edge_local, r->E);
    ALLOC(r->vdof, V);
    ALLOC(r->dload, 9 * V);
    ALLOC(r->s_v, 3 * V);
    ALLOC(r->s_radius, V);
    ALLOC(r->s_length, V);
    ALLOC(r->s_tangent, 3 * V);
    ALLOC(r->s_held, V);
    if (desc->hair_contact) { /* an edge's box is no larger than a cell (find_hair_contacts): 8 cells at most */
        s = dr_broad_phase_create(&r->bp, err);
        if (s == DR_OK) s = dr_broad_phase_reserve(r->bp, r->E, 8 * (size_t)r->E, err);
        if (s != DR_OK) goto fail;
    }
    /* the step's scratch: per strand a status, a contact count and an error record pointer */
    s = dr_arena_create(S * (sizeof(DrStatus) + sizeof(int) + sizeof(DrError *)) + 3 * 64, &r->arena, err);
    if (s != DR_OK) goto fail;

    /* strands, in batch order */
    int si = 0, vi = 0;
    for (int b = 0; b < nbatches; b++) {
        const DrGroom *g = batches[b].groom;
        r->batch_offsets[b] = si;
        r->batch_group[b] = batches[b].group;
        r->batch_mask[b] = batches[b].mask;
        r->materials[b] = batches[b].material;
        r->batch[b] = batches[b];
        r->batch[b].groom = NULL;
        if (r->pairs) { /* the batch's thickness is the broad phase's reach: the largest of its pairs' */
            double t = 0.0;
            for (int o = 0; o < nbatches; o++) {
                r->pairs[(long)b * nbatches + o] = desc->pairs[(long)b * nbatches + o];
                t = fmax(t, desc->pairs[(long)b * nbatches + o].thickness);
            }
            r->batch[b].contact_thickness = t;
        }
        r->roots[b] = desc->batch_roots ? desc->batch_roots[b] : desc->roots;
        const DrRodMaterial *mt = &batches[b].material;
        double rad = mt->radius;
        for (int k = 0; k < g->nstrands; k++, si++) {
            int nv = g->offsets[k + 1] - g->offsets[k];
            r->offsets[si] = vi;
            r->strand_batch[si] = b;
            r->radius[si] = rad;
            memcpy(r->x + 3 * vi, g->x + 3 * g->offsets[k], (size_t)nv * 3 * sizeof(double));
            /* the radius at each vertex: linear in arc length from the root's to the tip's (tip_radius 0: none) */
            double rt = mt->tip_radius > 0 ? mt->tip_radius : rad, total = 0, along = 0;
            for (int j = 0; j + 1 < nv; j++) total += dist3(r->x + 3 * (vi + j), r->x + 3 * (vi + j + 1));
            for (int j = 0; j < nv; j++) {
                if (j > 0) along += dist3(r->x + 3 * (vi + j - 1), r->x + 3 * (vi + j));
                r->vradius[vi + j] = rt == rad ? rad : rad + (rt - rad) * (along / total);
            }
            if (rt != rad) r->tapered = true;
            vi += nv;
        }
    }
    r->offsets[S] = vi;
    r->batch_offsets[nbatches] = si;
    for (int k = 0; k < r->S; k++)
        for (int j = 0; j < r->offsets[k + 1] - r->offsets[k] - 1; j++) {
            r->edge_strand[edge_index(r, k, j)] = k;
            r->edge_local[edge_index(r, k, j)] = j;
        }

    /* rest state: tangents, space-parallel frames from each root normal, curvatures, masses, stiffnesses */
    si = 0;
    for (int b = 0; b < nbatches; b++) {
        const DrGroom *g = batches[b].groom;
        const DrRodMaterial *mt = &batches[b].material;
        for (int k = 0; k < g->nstrands; k++, si++) {
            int o = r->offsets[si], nv = r->offsets[si + 1] - o, e0 = edge_index(r, si, 0);
            double *t = r->t + 3 * e0, *len = r->len + e0, *a1 = r->a1 + 3 * e0;
            dr_rod_tangents(nv, r->x + 3 * o, t, len);
            const double *rn = g->root_normal ? g->root_normal + 3 * k : NULL;
            dr_rod_space_frames(nv - 1, t, rn, a1);
            for (int j = 0; j < nv - 1; j++) {
                double re = 0.5 * (r->vradius[o + j] + r->vradius[o + j + 1]);
                double A = M_PI * re * re, J = M_PI * pow(re, 4) / 2.0;
                r->lbar[e0 + j] = len[j];
                r->eks[e0 + j] = mt->youngs * A;
                r->tinertia[e0 + j] = mt->density * J * len[j];
                r->vmass[o + j] += 0.5 * mt->density * A * len[j];
                r->vmass[o + j + 1] += 0.5 * mt->density * A * len[j];
            }
            for (int i = 1; i + 1 < nv; i++) {
                double rv = r->vradius[o + i];
                r->ibend[interior_index(r, si, i)] = mt->youngs * M_PI * pow(rv, 4) / 4.0;
                r->itwist[interior_index(r, si, i)] = mt->shear * M_PI * pow(rv, 4) / 2.0;
            }
            if (nv > 2) {
                int i0 = interior_index(r, si, 1);
                memset(r->m + i0, 0, (size_t)(nv - 2) * sizeof(double));
                dr_rod_reference_twist(nv, t, a1, r->m + i0);
                dr_rod_curvatures(nv, t, a1, r->theta + e0, r->m + i0, r->kbar + 4 * i0, r->tbar + i0);
                for (int i = 1; i < nv - 1; i++) r->lv[i0 + i - 1] = 0.5 * (len[i - 1] + len[i]);
            }
            for (int a = 0; a < 3; a++) {
                r->tip_rest[6 * si + a] = r->x[3 * (o + nv - 1) + a];
                r->tip_rest[6 * si + 3 + a] = r->x[3 * (o + nv - 2) + a];
                r->root_rest[6 * si + a] = r->x[3 * o + a];
                r->root_rest[6 * si + 3 + a] = r->x[3 * (o + 1) + a];
                r->m1_rest[3 * si + a] = a1[a]; /* θ = 0 at rest: m1 = a1 */
            }
        }
    }

    /* the Lagrangian system (the caller's shared one, or the set's own): one object per strand */
    if (desc->system) {
        r->lag = desc->system;
    } else {
        DrLagDesc ld = desc->solver;
        s = dr_lag_create(&ld, &r->lag, err);
        if (s != DR_OK) goto fail;
        r->own_system = true;
    }
    int first = dr_lag_dof_count(r->lag);
    for (int k = 0; k < r->S; k++) {
        int nv = r->offsets[k + 1] - r->offsets[k], nd = 4 * nv - 1;
        s = dr_lag_add_object(r->lag, nd, nd - 1 < ROD_KD ? nd - 1 : ROD_KD, NULL, &r->dof0[k], err);
        if (s != DR_OK) goto fail;
    }
    r->ndof = dr_lag_dof_count(r->lag) - first;
    for (int k = 0; k < r->S; k++)
        for (int j = r->offsets[k]; j < r->offsets[k + 1]; j++) {
            r->vdof[j] = r->dof0[k] + 4 * (j - r->offsets[k]);
            r->s_radius[j] = r->vradius[j];
        }
    *out = r;
    return DR_OK;
fail:
    dr_rod_set_destroy(&r);
    return s;
}

DrRodState dr_rod_set_state(DrRodSet *r)
{
    DrRodState st = {r->S, r->V, r->E, r->offsets, r->x, r->v, r->theta, r->theta_dot, r->a1, r->m, r->lambda,
                     r->nlambda, r->vmass, r->radius, r->batch_offsets, r->nbatches, r->vradius, r->tapered};
    return st;
}

void dr_rod_set_solver(DrRodSet *r, const DrLagDesc *solver)
{
    r->desc.solver = *solver;
    if (r->own_system) dr_lag_set_desc(r->lag, solver);
}

void dr_rod_set_refresh(DrRodSet *r)
{
    for (int k = 0; k < r->S; k++) {
        int o = r->offsets[k], nv = r->offsets[k + 1] - o, e0 = edge_index(r, k, 0);
        dr_rod_tangents(nv, r->x + 3 * o, r->t + 3 * e0, r->len + e0);
    }
}

/* ---- measurement ----------------------------------------------------------------------------------------- */

void dr_rod_set_measure(const DrRodSet *r, DrRodStats *st)
{
    double ke = 0, el = 0, pe = 0;
    DrVec3 p = {0, 0, 0}, L = {0, 0, 0};
    DrVec3 g = r->desc.gravity;
    for (int k = 0; k < r->S; k++) {
        int o = r->offsets[k], nv = r->offsets[k + 1] - o, e0 = edge_index(r, k, 0);
        for (int j = o; j < o + nv; j++) {
            DrVec3 x = dr_v3(r->x[3 * j], r->x[3 * j + 1], r->x[3 * j + 2]);
            DrVec3 v = dr_v3(r->v[3 * j], r->v[3 * j + 1], r->v[3 * j + 2]);
            double mm = r->vmass[j];
            ke += 0.5 * mm * dr_v3_dot(v, v);
            pe -= mm * dr_v3_dot(g, x);
            p = dr_v3_add(p, dr_v3_scale(v, mm));
            L = dr_v3_add(L, dr_v3_scale(dr_v3_cross(x, v), mm));
        }
        for (int e = e0; e < e0 + nv - 1; e++) ke += 0.5 * r->tinertia[e] * r->theta_dot[e] * r->theta_dot[e];
        int i0 = nv > 2 ? interior_index(r, k, 1) : 0;
        DrRodRef ref = {r->t + 3 * e0, r->a1 + 3 * e0, r->m + i0};
        el += dr_rod_energy_varying(nv, r->x + 3 * o, r->theta + e0, &ref, r->lbar + e0,
                                    nv > 2 ? r->kbar + 4 * i0 : NULL, nv > 2 ? r->tbar + i0 : NULL, r->eks + e0,
                                    nv > 2 ? r->ibend + i0 : NULL, nv > 2 ? r->itwist + i0 : NULL);
    }
    st->kinetic = ke;
    st->elastic = el;
    st->gravity_potential = pe;
    st->momentum = p;
    st->angular_momentum = L;
}

/* ---- one step -------------------------------------------------------------------------------------------- */

/* Angle of unit vector u in the frame (a1, a2 = t × a1), continued to the representative nearest `near`. */
static double frame_angle(const double t[3], const double a1[3], const double u[3], double near)
{
    double a2[3] = {t[1] * a1[2] - t[2] * a1[1], t[2] * a1[0] - t[0] * a1[2], t[0] * a1[1] - t[1] * a1[0]};
    double ang = atan2(u[0] * a2[0] + u[1] * a2[1] + u[2] * a2[2], u[0] * a1[0] + u[1] * a1[1] + u[2] * a1[2]);
    return ang + 2 * M_PI * round((near - ang) / (2 * M_PI));
}

/* Velocities that hold the tip DOFs of strand k where they started (desc.tips). */
static void tip_velocities(DrRodSet *r, int k, double h)
{
    int o = r->offsets[k], nv = r->offsets[k + 1] - o, d0 = r->dof0[k], e0 = edge_index(r, k, 0);
    int nfix = r->desc.tips == DR_ROD_ROOTS_CLAMPED ? 2 : (r->desc.tips == DR_ROD_ROOTS_PINNED ? 1 : 0);
    for (int j = 0; j < nfix && j < nv; j++)
        for (int a = 0; a < 3; a++) {
            int vid = nv - 1 - j, dof = d0 + 4 * vid + a;
            r->pres[dof] = 1;
            r->qdot_p[dof] = (r->tip_rest[6 * k + 3 * j + a] - r->x[3 * (o + vid) + a]) / h;
        }
    if (nfix == 2) {
        int dof = d0 + 4 * (nv - 2) + 3;
        r->pres[dof] = 1;
        r->qdot_p[dof] = -r->theta[e0 + nv - 2] / h;
    }
}

/* Velocities that take the root DOFs of strand k to the scalp pose at the end of the step. */
static void root_velocities(DrRodSet *r, int k, double h, const DrXform *pose)
{
    int o = r->offsets[k], d0 = r->dof0[k], e0 = edge_index(r, k, 0);
    DrRodRoots roots = r->roots[r->strand_batch[k]];
    int nfix = roots == DR_ROD_ROOTS_CLAMPED ? 2 : (roots == DR_ROD_ROOTS_PINNED ? 1 : 0);
    for (int j = 0; j < nfix; j++)
        for (int a = 0; a < 3; a++) {
            int dof = d0 + 4 * j + a;
            r->pres[dof] = 1;
            if (!pose) {
                r->qdot_p[dof] = 0;
                continue;
            }
            const double *p = r->root_rest + 6 * k + 3 * j;
            DrVec3 target = dr_xform_apply(*pose, dr_v3(p[0], p[1], p[2]));
            r->qdot_p[dof] = (dr_v3_get(target, a) - r->x[3 * (o + j) + a]) / h;
        }
    if (nfix == 2) {
        int dof = d0 + 3;
        r->pres[dof] = 1;
        if (!pose) {
            r->qdot_p[dof] = 0;
            return;
        }
        /* the first edge's material frame turns with the scalp: its angle in the reference frame that edge 0
           will have at the end of the step (a1 transported to the new tangent) */
        double x0[3], x1[3], tn[3], a1n[3];
        for (int a = 0; a < 3; a++) {
            x0[a] = r->x[3 * o + a] + h * r->qdot_p[d0 + a];
            x1[a] = r->x[3 * (o + 1) + a] + h * r->qdot_p[d0 + 4 + a];
        }
        double l = sqrt((x1[0] - x0[0]) * (x1[0] - x0[0]) + (x1[1] - x0[1]) * (x1[1] - x0[1]) + (x1[2] - x0[2]) * (x1[2] - x0[2]));
        for (int a = 0; a < 3; a++) tn[a] = (x1[a] - x0[a]) / l;
        dr_rod_transport(r->t + 3 * e0, tn, r->a1 + 3 * e0, a1n);
        DrVec3 m1 = dr_m3_apply(pose->R, dr_v3(r->m1_rest[3 * k], r->m1_rest[3 * k + 1], r->m1_rest[3 * k + 2]));
        double u[3] = {m1.x, m1.y, m1.z};
        /* remove the tangential part that rounding leaves */
        double ut = u[0] * tn[0] + u[1] * tn[1] + u[2] * tn[2];
        for (int a = 0; a < 3; a++) u[a] -= ut * tn[a];
        double th = frame_angle(tn, a1n, u, r->theta[e0]);
        r->qdot_p[dof] = (th - r->theta[e0]) / h;
    }
}

typedef struct BuildCtx {
    DrRodSet *r;
    double h;
    const DrRodCollider *col;
    int ncol;
    DrStatus *status;  /* per strand */
    DrError **errs;    /* per strand: NULL, or the error record of a strand that failed (heap, failure only) */
    int *ncontacts;    /* per strand */
} BuildCtx;

static DrStatus build_strand(DrRodSet *r, int k, double h, const DrRodCollider *col, int ncol, int *ncontacts,
                             DrError *err)
{
    int o = r->offsets[k], nv = r->offsets[k + 1] - o, e0 = edge_index(r, k, 0), d0 = r->dof0[k];
    const DrRodMaterial *mt = &r->materials[r->strand_batch[k]];
    bool geo = r->desc.geometric_stiffness;
    const double *x = r->x + 3 * o, *th = r->theta + e0;
    int i0 = nv > 2 ? interior_index(r, k, 1) : 0;
    DrRodRef ref = {r->t + 3 * e0, r->a1 + 3 * e0, r->m + i0};
    DrLagGroup g;
    double G[DR_LAG_MAX_DOFS * DR_LAG_MAX_DOFS];
    for (int j = 0; j < nv - 1; j++) {
        double *lam = r->lambda + e0 + j;
        dr_rod_stretch_group(x, j, r->lbar[e0 + j], r->eks[e0 + j], d0, geo ? lam : NULL, geo ? G : NULL, &g);
        g.lambda = lam;
        DR_TRY(dr_lag_add_with_twin(r->lag, &g, mt->damping, err));
    }
    for (int i = 1; i < nv - 1; i++) {
        int ii = i0 + i - 1;
        double *lb = r->lambda + r->E + 4 * ii, *lt = r->lambda + r->E + 4 * r->I + ii;
        dr_rod_bend_group(x, th, &ref, i, r->kbar + 4 * ii, r->lv[ii], r->ibend[ii], d0, geo ? lb : NULL,
                          geo ? G : NULL, &g);
        g.lambda = lb;
        DR_TRY(dr_lag_add_with_twin(r->lag, &g, mt->damping, err));
        dr_rod_twist_group(x, th, &ref, i, r->tbar[ii], r->lv[ii], r->itwist[ii], d0, geo ? lt : NULL,
                           geo ? G : NULL, &g);
        g.lambda = lt;
        DR_TRY(dr_lag_add_with_twin(r->lag, &g, mt->damping, err));
    }
    /* vertex–collider contacts: a vertex that is inside, or would be within this step at its current velocity,
       gets the constraint φ = d − (r + thickness) ≥ 0 linearised along the collider's normal, relative to the
       collider's own motion: φ₊ = φ + h n·(v₊ − v_c), so c = φ − h n·v_c. */
    int nc = 0;
    for (int j = 0; j < nv; j++) {
        int vid = o + j;
        r->cflag[vid] = 0;
        int dof = d0 + 4 * j;
        if (r->pres[dof]) continue;
        DrVec3 p = dr_v3(x[3 * j], x[3 * j + 1], x[3 * j + 2]);
        DrVec3 v = dr_v3(r->v[3 * vid], r->v[3 * vid + 1], r->v[3 * vid + 2]);
        double best = INFINITY;
        for (int c = 0; c < ncol; c++) {
            DrVec3 n;
            const DrRodBatch *bt = &r->batch[r->strand_batch[k]];
            double d = col[c].sdf(p, &n, col[c].ctx) - (r->vradius[vid] + col[c].thickness + bt->collider_thickness);
            DrVec3 vc = col[c].velocity_at ? col[c].velocity_at(p, col[c].ctx) : dr_v3(0, 0, 0);
            double approach = h * dr_v3_dot(dr_v3_sub(v, vc), n);
            if (d + fmin(approach, 0) >= 0 || d >= best) continue;
            best = d;
            r->cflag[vid] = 1;
            double nn = dr_v3_norm(n);
            if (nn > 0) n = dr_v3_scale(n, 1.0 / nn);
            r->cnormal[3 * vid] = n.x;
            r->cnormal[3 * vid + 1] = n.y;
            r->cnormal[3 * vid + 2] = n.z;
            r->cvel[3 * vid] = vc.x;
            r->cvel[3 * vid + 1] = vc.y;
            r->cvel[3 * vid + 2] = vc.z;
            r->cfric[vid] = fmax(col[c].friction, bt->collider_friction);
        }
        if (!r->cflag[vid]) continue;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 3;
        for (int a = 0; a < 3; a++) {
            g.dof[a] = dof + a;
            g.J[a] = r->cnormal[3 * vid + a];
        }
        double vn = r->cnormal[3 * vid] * r->cvel[3 * vid] + r->cnormal[3 * vid + 1] * r->cvel[3 * vid + 1] +
                    r->cnormal[3 * vid + 2] * r->cvel[3 * vid + 2];
        g.phi[0] = best - h * vn;
        g.cinv[0] = r->desc.collider_stiffness;
        r->clambda[vid] = 0;
        g.lambda = &r->clambda[vid];
        DR_TRY(dr_lag_add(r->lag, &g, err));
        nc++;
    }
    *ncontacts = nc;
    return DR_OK;
}

/* A strand's error goes to a record of its own only when it fails: ~3 KB per strand and step otherwise. */
static void build_range(long begin, long end, void *vctx)
{
    BuildCtx *c = vctx;
    DrError e;
    for (long k = begin; k < end; k++) {
        c->status[k] = build_strand(c->r, (int)k, c->h, c->col, c->ncol, &c->ncontacts[k], &e);
        if (c->status[k] != DR_OK && dr_calloc(1, sizeof e, &c->errs[k], NULL) == DR_OK) *c->errs[k] = e;
    }
}

/* ---- hair–hair contact ------------------------------------------------------------------------------------ */

/* Closest points of segments p0p1 and q0q1 (Ericson, Real-Time Collision Detection §5.1.9). */
static double segment_closest(const double *p0, const double *p1, const double *q0, const double *q1, double *s,
                              double *t, double n[3])
{
    double d1[3], d2[3], rr[3];
    for (int a = 0; a < 3; a++) {
        d1[a] = p1[a] - p0[a];
        d2[a] = q1[a] - q0[a];
        rr[a] = p0[a] - q0[a];
    }
    double A = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2], Ee = d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2];
    double F = d2[0] * rr[0] + d2[1] * rr[1] + d2[2] * rr[2], C = d1[0] * rr[0] + d1[1] * rr[1] + d1[2] * rr[2];
    double B = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2], den = A * Ee - B * B;
    double ss = den > 1e-14 * A * Ee ? fmin(fmax((B * F - C * Ee) / den, 0), 1) : 0;
    double tt = (B * ss + F) / Ee;
    if (tt < 0) {
        tt = 0;
        ss = fmin(fmax(-C / A, 0), 1);
    } else if (tt > 1) {
        tt = 1;
        ss = fmin(fmax((B - C) / A, 0), 1);
    }
    double dd = 0;
    for (int a = 0; a < 3; a++) {
        n[a] = (p0[a] + ss * d1[a]) - (q0[a] + tt * d2[a]);
        dd += n[a] * n[a];
    }
    *s = ss;
    *t = tt;
    return sqrt(dd);
}


static bool may_touch(const DrRodSet *r, int sa, int sb)
{
    int ba = r->strand_batch[sa], bb = r->strand_batch[sb];
    if (ba == bb) return r->batch[ba].self_contact;
    return (r->batch_group[ba] & r->batch_mask[bb]) != 0 && (r->batch_group[bb] & r->batch_mask[ba]) != 0;
}

/* Finds edge pairs closer than their contact distance: each edge's bounding box, inflated by half the largest
   contact distance, goes to the broad phase (src/contact) on cells of the longest edge plus that distance (at most
   2 cells per axis), which gives the overlapping pairs in a fixed order (cells in (x, y, z) order, pairs by edge
   within a cell). Adjacent edges of a strand never count. */
static DrStatus find_hair_contacts(DrRodSet *r, DrError *err)
{
    r->nhc = 0;
    if (!r->desc.hair_contact || r->E == 0) return DR_OK;
    double maxlen = 0, maxr = 0;
    for (int e = 0; e < r->E; e++) maxlen = fmax(maxlen, r->len[e]);
    for (int k = 0; k < r->S; k++) {
        double rk = r->radius[k];
        for (int j = r->offsets[k]; r->tapered && j < r->offsets[k + 1]; j++) rk = fmax(rk, r->vradius[j]);
        maxr = fmax(maxr, rk + r->batch[r->strand_batch[k]].contact_thickness);
    }
    double reach = 2 * maxr;
    double cell = maxlen + reach;
    const int *edge_strand = r->edge_strand, *edge_local = r->edge_local;
    dr_broad_phase_clear(r->bp);
    for (int k = 0; k < r->S; k++) { /* box index = global edge index */
        int o = r->offsets[k], nv = r->offsets[k + 1] - o;
        for (int j = 0; j < nv - 1; j++) {
            const double *p = r->x + 3 * (o + j), *q = p + 3;
            DrVec3 lo = dr_v3(fmin(p[0], q[0]) - 0.5 * reach, fmin(p[1], q[1]) - 0.5 * reach, fmin(p[2], q[2]) - 0.5 * reach);
            DrVec3 hi = dr_v3(fmax(p[0], q[0]) + 0.5 * reach, fmax(p[1], q[1]) + 0.5 * reach, fmax(p[2], q[2]) + 0.5 * reach);
            DR_TRY(dr_broad_phase_add(r->bp, lo, hi, err));
        }
    }
    const DrBroadPair *pairs = NULL;
    long npairs = 0;
    DR_TRY(dr_broad_phase_pairs(r->bp, cell, &pairs, &npairs, err));
    for (long c = 0; c < npairs; c++) {
        int ea = pairs[c].a, eb = pairs[c].b, sa = edge_strand[ea], sb = edge_strand[eb];
        if (sa == sb && abs(edge_local[ea] - edge_local[eb]) < 2) continue;
        if (!may_touch(r, sa, sb)) continue;
        const double *p0 = r->x + 3 * (r->offsets[sa] + edge_local[ea]), *p1 = p0 + 3;
        const double *q0 = r->x + 3 * (r->offsets[sb] + edge_local[eb]), *q1 = q0 + 3;
        double s, t, nv[3];
        double d = segment_closest(p0, p1, q0, q1, &s, &t, nv);
        double ra = r->radius[sa], rb = r->radius[sb];
        if (r->tapered) { /* the radii at the closest points */
            const double *va = r->vradius + r->offsets[sa] + edge_local[ea], *vb = r->vradius + r->offsets[sb] + edge_local[eb];
            ra = va[0] + s * (va[1] - va[0]);
            rb = vb[0] + t * (vb[1] - vb[0]);
        }
        const DrRodBatch *pa = &r->batch[r->strand_batch[sa]], *pb = &r->batch[r->strand_batch[sb]];
        const DrRodPairResponse *pr = r->pairs ? &r->pairs[(long)r->strand_batch[sa] * r->nbatches + r->strand_batch[sb]]
                                               : NULL;
        double rr = pr ? ra + rb + pr->thickness + pr->thickness : ra + rb + pa->contact_thickness + pb->contact_thickness;
        if (d >= rr || d < 1e-12 * rr) continue;
        if (r->nhc == r->cap_hc) { /* doubled and kept */
            size_t cap = r->cap_hc ? 2 * r->cap_hc : 256;
            DR_TRY(dr_realloc(cap, sizeof *r->hc, &r->hc, err));
            r->cap_hc = cap;
        }
        r->hc[r->nhc++] = (HairContact){ea, eb, s, t, d, dr_v3(nv[0] / d, nv[1] / d, nv[2] / d), rr,
                                        pr ? pr->stiffness : fmin(pa->contact_stiffness, pb->contact_stiffness),
                                        pr ? pr->friction : fmax(pa->contact_friction, pb->contact_friction),
                                        pr ? pr->damping : fmax(pa->contact_damping, pb->contact_damping)};
    }
    if (!r->hc_slack && 2 * r->nhc > r->cap_hc) { /* the first step leaves room for twice its contacts */
        DR_TRY(dr_realloc(2 * r->nhc, sizeof *r->hc, &r->hc, err));
        r->cap_hc = 2 * r->nhc;
    }
    r->hc_slack = true;
    return DR_OK;
}

/* The DOF of end `end` (0, 1) of global edge e. */
static int edge_vertex_dof(const DrRodSet *r, int e, int end)
{
    return r->dof0[r->edge_strand[e]] + 4 * (r->edge_local[e] + end);
}

/* Each contact is a positional row φ = d − (r_a + t_a + r_b + t_b) on the 12 DOFs of the two edges' ends,
   weighted by the closest points' parameters, with C⁻¹ = k. Friction is a viscous group on the two tangential
   components of the contact points' relative velocity (φ_v = T (v_a − v_b), c = 0): its coefficient
   μ F_n / max(|v_t|, v_ε), F_n = k |φ| the contact's force at the start of the step, resists sliding with
   μ F_n (Coulomb, the coefficient lagged by a step) and grips viscously below v_ε = μ|φ|/h. That floor caps
   the coefficient at h k, so the grip is never stiffer than the contact itself: an uncapped grip (h·coef ≫
   the strands' masses) leaves the solve ill-conditioned, thousands of CG iterations for a few contacts. A contact
   with damping adds a viscous row along the normal (J the positional row's, coefficient damping·k): it resists the
   strands' approach and separation alike, as a Kelvin–Voigt dashpot beside the contact's spring. */
static DrStatus add_hair_contacts(DrRodSet *r, DrError *err)
{
    for (size_t c = 0; c < r->nhc; c++) {
        const HairContact *hc = &r->hc[c];
        DrLagGroup g;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 12;
        double w[4] = {1 - hc->s, hc->s, -(1 - hc->t), -hc->t};
        int base[4] = {edge_vertex_dof(r, hc->e0, 0), edge_vertex_dof(r, hc->e0, 1), edge_vertex_dof(r, hc->e1, 0),
                       edge_vertex_dof(r, hc->e1, 1)};
        double n[3] = {hc->n.x, hc->n.y, hc->n.z};
        for (int v = 0; v < 4; v++)
            for (int a = 0; a < 3; a++) {
                g.dof[3 * v + a] = base[v] + a;
                g.J[3 * v + a] = w[v] * n[a];
            }
        g.phi[0] = hc->dist - hc->rr; /* < 0 while they overlap */
        g.cinv[0] = hc->k;
        DR_TRY(dr_lag_add_global(r->lag, &g, err));
        if (hc->damping > 0) { /* along the normal: −damping·k times the contact points' relative normal speed */
            DrLagGroup dmp = g;
            dmp.kind = DR_LAG_VISCOUS;
            dmp.phi[0] = 0;
            dmp.cinv[0] = hc->damping * hc->k;
            dmp.lambda = NULL;
            DR_TRY(dr_lag_add_global(r->lag, &dmp, err));
        }
        if (hc->mu <= 0) continue;
        /* relative velocity of the contact points, and a tangent basis */
        double vr[3] = {0, 0, 0};
        for (int v = 0; v < 4; v++)
            for (int a = 0; a < 3; a++) vr[a] += w[v] * r->qdot[base[v] + a];
        double vn = vr[0] * n[0] + vr[1] * n[1] + vr[2] * n[2];
        double vt[3] = {vr[0] - vn * n[0], vr[1] - vn * n[1], vr[2] - vn * n[2]};
        double vtn = sqrt(vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2]);
        double t1[3], t2[3];
        dr_tangent_basis(n, t1, t2);
        DrLagGroup f = g;
        f.kind = DR_LAG_VISCOUS;
        f.nrows = 2;
        double h = r->h_step;
        double coef = hc->mu * hc->k * fabs(g.phi[0]) / fmax(vtn, fmax(hc->mu * fabs(g.phi[0]) / h, 1e-12));
        for (int v = 0; v < 4; v++)
            for (int a = 0; a < 3; a++) {
                f.J[3 * v + a] = w[v] * t1[a];
                f.J[12 + 3 * v + a] = w[v] * t2[a];
            }
        f.phi[0] = f.phi[1] = 0;
        f.cinv[0] = f.cinv[1] = coef;
        f.lambda = NULL;
        DR_TRY(dr_lag_add_global(r->lag, &f, err));
    }
    return DR_OK;
}

/* ---- the step ------------------------------------------------------------------------------------------------ */

double dr_rod_set_stable_dt(const DrRodSet *r)
{
    (void)r;
    return INFINITY;
}

DrStatus dr_rod_set_predict_dofs(DrRodSet *r, double h, const DrXform *scalp_end, DrError *err)
{
    assert(h > 0);
    r->phase = PHASE_NONE;
    r->h_step = h;
    r->has_dload = false;
    dr_arena_reset(r->arena);
    r->seconds_build = -dr_time_now();
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(r->lag, &d, err));
    r->dmass = d.mass;
    r->qdot = d.qdot;
    r->fext = d.fext;
    r->pres = d.prescribed;
    r->qdot_p = d.qdot_prescribed;
    r->fload = d.force;
    r->qdot_out = d.qdot_out;
    /* 1–2. DOF vectors, masses, gravity, roots */
    for (int k = 0; k < r->S; k++) {
        int o = r->offsets[k], nv = r->offsets[k + 1] - o, e0 = edge_index(r, k, 0), d0 = r->dof0[k];
        for (int j = 0; j < nv; j++) {
            for (int a = 0; a < 3; a++) {
                int dof = d0 + 4 * j + a;
                r->dmass[dof] = r->vmass[o + j];
                r->qdot[dof] = r->v[3 * (o + j) + a];
                r->fext[dof] = r->vmass[o + j] * dr_v3_get(r->desc.gravity, a);
                r->pres[dof] = 0;
            }
            if (j < nv - 1) {
                int dof = d0 + 4 * j + 3;
                r->dmass[dof] = r->tinertia[e0 + j];
                r->qdot[dof] = r->theta_dot[e0 + j];
                r->fext[dof] = 0;
                r->pres[dof] = 0;
            }
        }
        const DrXform *pose = scalp_end ? &scalp_end[r->strand_batch[k]] : NULL;
        tip_velocities(r, k, h);
        root_velocities(r, k, h, pose);
    }
    r->seconds_build += dr_time_now();
    r->phase = PHASE_DOFS;
    return DR_OK;
}

DrStatus dr_rod_set_predict_groups(DrRodSet *r, const DrRodCollider *col, int ncol, DrError *err)
{
    assert(r->phase == PHASE_DOFS);
    double h = r->h_step;
    double t0 = dr_time_now();
    /* the multipliers the groups take their geometric stiffness from, to restore if the step fails */
    memcpy(r->save + 6 * r->V + 5 * r->E + r->I, r->lambda, (size_t)r->nlambda * sizeof(double));

    /* 3. groups, per strand in parallel */
    DrStatus *status = dr_arena_alloc(r->arena, (size_t)r->S, sizeof *status);
    DrError **errs = dr_arena_alloc(r->arena, (size_t)r->S, sizeof *errs);
    int *ncont = dr_arena_alloc(r->arena, (size_t)r->S, sizeof *ncont);
    if (!status || !errs || !ncont)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "out of memory for the scratch of a hair step (%d strands)",
                            r->S);
    BuildCtx bc = {r, h, col, ncol, status, errs, ncont};
    dr_parallel_for(r->S, 8, build_range, &bc);
    DrStatus s = DR_OK;
    int total = 0;
    for (int k = 0; k < r->S && s == DR_OK; k++) {
        if (status[k] != DR_OK) {
            s = status[k];
            if (errs[k]) *err = *errs[k];
            else dr_error_set(err, s, NULL, 0, 0, "hair strand %d: its constraints could not be built", k);
        }
        total += ncont[k];
    }
    for (int k = 0; k < r->S; k++) free(errs[k]);
    if (s != DR_OK) return s;
    r->ncollider_contacts = total;
    double t1 = dr_time_now();
    DR_TRY(find_hair_contacts(r, err));
    DR_TRY(add_hair_contacts(r, err));
    double t2 = dr_time_now();
    r->seconds_build += t1 - t0;
    r->seconds_contact = t2 - t1;
    r->phase = PHASE_PREDICTED;
    return DR_OK;
}

DrStatus dr_rod_set_predict(DrRodSet *r, double h, const DrXform *scalp_end, const DrRodCollider *col, int ncol,
                            DrError *err)
{
    assert(r->own_system);
    DR_TRY(dr_rod_set_predict_dofs(r, h, scalp_end, err));
    DR_TRY(dr_lag_begin(r->lag, h, r->dmass, r->qdot, r->fext, r->pres, r->qdot_p, err));
    return dr_rod_set_predict_groups(r, col, ncol, err);
}

DrRodSamples dr_rod_set_samples(DrRodSet *r)
{
    assert(r->phase == PHASE_PREDICTED || r->phase == PHASE_SOLVED);
    /* velocities: the last solve's, or the prediction's (held DOFs at their prescribed velocity) */
    const double *q = r->phase == PHASE_SOLVED ? r->qdot_out : r->qdot;
    for (int k = 0; k < r->S; k++) {
        int o = r->offsets[k], nv = r->offsets[k + 1] - o, e0 = edge_index(r, k, 0);
        for (int j = 0; j < nv; j++) {
            int vid = o + j, dof = r->vdof[vid];
            r->s_held[vid] = r->pres[dof];
            for (int a = 0; a < 3; a++) {
                bool held = r->pres[dof + a] && r->phase != PHASE_SOLVED;
                r->s_v[3 * vid + a] = held ? r->qdot_p[dof + a] : q[dof + a];
            }
            /* edges j − 1 and j meet at vertex j */
            const double *ta = j > 0 ? r->t + 3 * (e0 + j - 1) : NULL, *tb = j < nv - 1 ? r->t + 3 * (e0 + j) : NULL;
            double la = ta ? r->len[e0 + j - 1] : 0, lb = tb ? r->len[e0 + j] : 0;
            r->s_length[vid] = 0.5 * (la + lb);
            DrVec3 d = dr_v3(0, 0, 0);
            if (ta) d = dr_v3_add(d, dr_v3(ta[0], ta[1], ta[2]));
            if (tb) d = dr_v3_add(d, dr_v3(tb[0], tb[1], tb[2]));
            double dn = dr_v3_norm(d);
            if (dn < 1e-12) d = dr_v3(tb ? tb[0] : ta[0], tb ? tb[1] : ta[1], tb ? tb[2] : ta[2]), dn = 1; /* folded */
            r->s_tangent[3 * vid] = d.x / dn;
            r->s_tangent[3 * vid + 1] = d.y / dn;
            r->s_tangent[3 * vid + 2] = d.z / dn;
        }
    }
    DrRodSamples sm = {r->V, r->x, r->s_v, r->vmass, r->s_radius, r->s_length, r->s_tangent, r->s_held};
    return sm;
}

int dr_rod_set_load_blocks(const DrRodSet *r) { return r->V; }
const int *dr_rod_set_vertex_dofs(const DrRodSet *r) { return r->vdof; }

void dr_rod_set_fill_load(DrRodSet *r, const double *force, const double *dforce_dv, double *gforce,
                          int *block_dof, double *block)
{
    /* vertex forces as generalised forces (the twists get none) */
    if (force)
        for (int k = 0; k < r->S; k++) {
            int d0 = r->dof0[k], nv = r->offsets[k + 1] - r->offsets[k];
            for (int j = 0; j < nv; j++) {
                for (int a = 0; a < 3; a++) gforce[d0 + 4 * j + a] = force[3 * (r->offsets[k] + j) + a];
                if (j < nv - 1) gforce[d0 + 4 * j + 3] = 0;
            }
        }
    if (dforce_dv) {
        memcpy(block_dof, r->vdof, (size_t)r->V * sizeof(int));
        memcpy(block, dforce_dv, 9 * (size_t)r->V * sizeof(double));
    }
    /* the load's inertia, which commit's collider friction must see */
    r->has_dload = dforce_dv != NULL;
    if (dforce_dv) memcpy(r->dload, dforce_dv, 9 * (size_t)r->V * sizeof(double));
}

void dr_rod_set_add_velocity(DrRodSet *r, const double *dv)
{
    assert(r->phase == PHASE_SOLVED);
    for (int vid = 0; vid < r->V; vid++) {
        int dof = r->vdof[vid];
        for (int a = 0; a < 3; a++)
            if (!r->pres[dof + a]) r->qdot_out[dof + a] += dv[3 * vid + a];
    }
}

void dr_rod_set_take(DrRodSet *r)
{
    assert(r->phase == PHASE_PREDICTED || r->phase == PHASE_SOLVED);
    r->phase = PHASE_SOLVED;
}

DrStatus dr_rod_set_solve(DrRodSet *r, const double *force, const double *dforce_dv, DrRodStats *stats,
                          DrError *err)
{
    assert(r->own_system && (r->phase == PHASE_PREDICTED || r->phase == PHASE_SOLVED));
    r->phase = PHASE_PREDICTED;
    double t2 = dr_time_now();
    /* 4. the solve */
    DrLagLoad load = {NULL, 0, NULL, NULL};
    if (force) {
        dr_rod_set_fill_load(r, force, NULL, r->fload, NULL, NULL);
        load.force = r->fload;
    }
    r->has_dload = dforce_dv != NULL;
    if (dforce_dv) memcpy(r->dload, dforce_dv, 9 * (size_t)r->V * sizeof(double));
    if (dforce_dv) {
        load.nblocks = r->V;
        load.block_dof = r->vdof;
        load.dforce_dv = dforce_dv;
    }
    DrLagStats ls;
    DrStatus solved = dr_lag_solve_load(r->lag, force || dforce_dv ? &load : NULL, r->qdot_out, &ls, err);
    if (solved < 0) return solved;
    r->phase = PHASE_SOLVED;
    if (stats) {
        stats->iterations += ls.iterations;
        stats->residual = ls.residual;
        stats->not_converged += ls.converged ? 0 : 1;
        stats->indefinite_blocks += ls.indefinite_blocks;
        stats->seconds_solve += dr_time_now() - t2;
    }
    if (solved == DR_WARN_NOT_CONVERGED)
        return dr_error_set(err, DR_WARN_NOT_CONVERGED, NULL, 0, 0,
                            "hair solve stopped at its iteration cap (%d) with relative residual %.2e",
                            r->desc.solver.max_iter, ls.residual);
    return DR_OK;
}

DrStatus dr_rod_set_commit(DrRodSet *r, DrRodStats *stats, DrError *err)
{
    assert(r->phase == PHASE_SOLVED);
    r->phase = PHASE_NONE;
    double h = r->h_step;
    /* 5. multipliers (eqs. S24, S25, kept for the next step's geometric stiffness, and the collider contacts'
       force for friction), then Coulomb friction at the collider contacts: the tangential velocity relative to
       the collider loses up to μ times the normal velocity change the contact force λ gave (h λ / m) */
    double *save = r->save;
    if (r->own_system) dr_lag_update_multipliers(r->lag, r->qdot_out); /* else the system's owner did */

    /* 6. advance (keeping the old state to restore if it turns non-finite) */
    memcpy(save, r->x, 3 * (size_t)r->V * sizeof(double));
    memcpy(save + 3 * r->V, r->v, 3 * (size_t)r->V * sizeof(double));
    memcpy(save + 6 * r->V, r->theta, (size_t)r->E * sizeof(double));
    memcpy(save + 6 * r->V + r->E, r->theta_dot, (size_t)r->E * sizeof(double));
    memcpy(save + 6 * r->V + 2 * r->E, r->a1, 3 * (size_t)r->E * sizeof(double));
    memcpy(save + 6 * r->V + 5 * r->E, r->m, (size_t)r->I * sizeof(double));
    bool finite = true;
    for (int k = 0; k < r->S; k++) {
        int o = r->offsets[k], nv = r->offsets[k + 1] - o, e0 = edge_index(r, k, 0), d0 = r->dof0[k];
        for (int j = 0; j < nv; j++) {
            int vid = o + j;
            double v[3];
            for (int a = 0; a < 3; a++) v[a] = r->qdot_out[d0 + 4 * j + a];
            if (r->cflag[vid]) {
                const double *n = r->cnormal + 3 * vid, *vc = r->cvel + 3 * vid;
                double rel[3] = {v[0] - vc[0], v[1] - vc[1], v[2] - vc[2]};
                double vn = rel[0] * n[0] + rel[1] * n[1] + rel[2] * n[2];
                double vt[3] = {rel[0] - vn * n[0], rel[1] - vn * n[1], rel[2] - vn * n[2]};
                double vtn = sqrt(vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2]);
                /* the vertex's inertia along n in the solve: its mass, and what the load added (−h nᵀ D n) */
                double mn = r->vmass[vid];
                if (r->has_dload) {
                    const double *D = r->dload + 9 * vid;
                    double Dn = 0;
                    for (int a = 0; a < 3; a++)
                        for (int b = 0; b < 3; b++) Dn += n[a] * D[3 * a + b] * n[b];
                    mn -= h * Dn;
                }
                double dvn = fmax(r->clambda[vid], 0) * h / mn;
                double keep = vtn > 0 ? fmax(0, 1 - r->cfric[vid] * dvn / vtn) : 0;
                for (int a = 0; a < 3; a++) v[a] = vc[a] + vn * n[a] + keep * vt[a];
            }
            for (int a = 0; a < 3; a++) {
                r->v[3 * vid + a] = v[a];
                r->x[3 * vid + a] += h * v[a];
                finite = finite && isfinite(r->x[3 * vid + a]);
            }
        }
        for (int j = 0; j < nv - 1; j++) {
            r->theta_dot[e0 + j] = r->qdot_out[d0 + 4 * j + 3];
            r->theta[e0 + j] += h * r->theta_dot[e0 + j];
            finite = finite && isfinite(r->theta[e0 + j]);
        }
    }
    if (finite) {
        memcpy(r->t_old, r->t, 3 * (size_t)r->E * sizeof(double));
        for (int k = 0; k < r->S; k++) {
            int o = r->offsets[k], nv = r->offsets[k + 1] - o, e0 = edge_index(r, k, 0);
            dr_rod_tangents(nv, r->x + 3 * o, r->t + 3 * e0, r->len + e0);
            dr_rod_time_transport(nv - 1, r->t_old + 3 * e0, r->t + 3 * e0, r->a1 + 3 * e0);
            if (nv > 2) dr_rod_reference_twist(nv, r->t + 3 * e0, r->a1 + 3 * e0, r->m + interior_index(r, k, 1));
            for (int j = 0; j < nv - 1; j++) finite = finite && r->len[e0 + j] > 0 && isfinite(r->len[e0 + j]);
        }
    }
    if (!finite) {
        memcpy(r->x, save, 3 * (size_t)r->V * sizeof(double));
        memcpy(r->v, save + 3 * r->V, 3 * (size_t)r->V * sizeof(double));
        memcpy(r->theta, save + 6 * r->V, (size_t)r->E * sizeof(double));
        memcpy(r->theta_dot, save + 6 * r->V + r->E, (size_t)r->E * sizeof(double));
        memcpy(r->a1, save + 6 * r->V + 2 * r->E, 3 * (size_t)r->E * sizeof(double));
        memcpy(r->m, save + 6 * r->V + 5 * r->E, (size_t)r->I * sizeof(double));
        memcpy(r->lambda, save + 6 * r->V + 5 * r->E + r->I, (size_t)r->nlambda * sizeof(double));
        dr_rod_set_refresh(r);
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "hair state became non-finite (time step %g s too large for the stiffness, or a collider "
                            "pushed a vertex through a strand); the state before the step is kept",
                            h);
    }
    if (stats) {
        stats->steps++;
        stats->collider_contacts = r->ncollider_contacts;
        stats->hair_contacts = (int)r->nhc;
        stats->seconds_build += r->seconds_build;
        stats->seconds_contact += r->seconds_contact;
        dr_rod_set_measure(r, stats);
    }
    return DR_OK;
}

DrStatus dr_rod_set_step(DrRodSet *r, double h, const DrXform *scalp_end, const DrRodCollider *col, int ncol,
                         DrRodStats *stats, DrError *err)
{
    DR_TRY(dr_rod_set_predict(r, h, scalp_end, col, ncol, err));
    DrStatus solved = dr_rod_set_solve(r, NULL, NULL, stats, err);
    if (solved < 0) return solved;
    DR_TRY(dr_rod_set_commit(r, stats, err));
    return solved;
}
