/* The Lagrangian constrained-dynamics solver (fei2017 §S4, Pseudocode S1; see lagrangian.h).
 *
 * Storage. Each object keeps two lower bands of its block, LAPACK layout ab[(i − j) + (kd + 1) j]: the
 * material part (mass, h s JᵀC⁻¹J) and the geometric part (−h² G), so a block that turns indefinite can
 * drop the geometric part alone, and a DrBanded for the factor. Groups are recorded per object (J, c, C⁻¹,
 * λ pointer) for the multiplier update after the solve. Inter-object groups become triplets of K_G,
 * compressed to CSR once per step.
 *
 * Pseudocode S1 as printed solves A_i z_i = S_i b in line 6 and forms w from q̇₊ in line 11; read as
 * standard PCG (z from the residual r, w = A p), which is what the text around it describes. */
#include "lagrangian/lagrangian.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

#include "core/sort.h"
#include "linalg/linalg.h"

typedef struct LagRecords {
    int *ints;        /* per group: nrows, ndof, dof[ndof] */
    size_t nints, cap_ints;
    double *reals;    /* per group: s, c[nrows], cinv[nrows], J[nrows·ndof] */
    size_t nreals, cap_reals;
    double **lambda;  /* per group */
    size_t ngroups, cap_groups;
} LagRecords;

typedef struct LagObject {
    int dof0, ndof, kd;
    double *mat;      /* (kd + 1) × ndof lower band: mass + material stiffness */
    double *geo;      /* (kd + 1) × ndof lower band: −h² G */
    double *pre;      /* (kd + 1) × ndof lower band: the in-band part of K_G on this object's DOFs, for the
                         preconditioner only (the operator takes K_G whole) */
    double *ext;      /* (kd + 1) × ndof lower band: −h ½(D + Dᵀ) of the current solve's load blocks */
    double *op;       /* (kd + 1) × ndof lower band of the operator: mat + geo (+ ext), or mat (+ ext) when geo
                         was dropped */
    DrBanded *factor;
    bool dropped;     /* geometric part dropped in the last solve */
    bool has_pre;     /* pre holds contact terms this step */
    bool has_ext;     /* ext holds load blocks in the current solve */
    LagRecords rec;
} LagObject;

typedef struct LagTriplet { int i, j; double v; } LagTriplet;

/* CLUSTER preconditioner (make_clusters): a pair of objects coupled in K_G with its strength; a unit of the
   preconditioner (one object and its banded factor, or a cluster and its sparse factor in a slot). */
typedef struct LagPair { int a, b; double w; } LagPair;
#define LAG_PROBES 8 /* analyses of oversized patterns kept, so that a fixed one is not analysed at every step */
typedef struct LagUnit {
    int first, nobj; /* objects unit_obj[first .. first + nobj), by id */
    int ndof;
    int slot;        /* the cluster's slot, -1 for a unit of one object */
} LagUnit;
typedef struct LagSlot {
    DrCsr *A;        /* the cluster's part of A: lower triangle, the cluster's DOFs in object order */
    DrChol *chol;
    double *buf;     /* cap_buf: a right-hand side gathered in the cluster's order */
    size_t cap_buf;
    DrStatus status; /* of the last analysis or factorisation */
    int unit;
    int probe;       /* make_clusters: the probe that holds the analysis of this pattern, or -1 */
    double entries;  /* make_clusters: entries of the factor */
} LagSlot;

struct DrLag {
    DrLagDesc desc;
    LagObject *obj;
    int nobj, cap_obj;
    int ndof;
    int *dof_object;          /* object of each DOF */
    int *obj_status;          /* cap_obj: per object, the outcome of its factorisation in a solve */

    /* per step */
    double h;
    bool begun;
    const double *mass, *qdot;
    const unsigned char *prescribed;
    const double *qdot_prescribed;
    bool assembled;           /* K_G built by the first solve since begin: no more groups this step */
    bool slack;               /* reserve_slack done (after the first assembly) */
    double *b, *b_local;      /* right-hand side; the part of it from intra-object terms only */
    double *rhs, *rhs_local;  /* b and b_local with a solve's load */
    double *diag;             /* diag(A) for Jacobi */
    double *inv_mass;
    LagTriplet *trip;
    size_t ntrip, cap_trip;
    LagTriplet *trip_tmp;     /* cap_trip_tmp: scratch of the triplet sort */
    size_t cap_trip_tmp;
    LagRecords grec;          /* records of the K_G groups */
    DrCsr *kg;
    int groups_block, groups_global;
    double t_assemble0;
    double *work;             /* 5 n: r, z, p, w, tmp */
    /* CLUSTER: clusters made at the first solve of a step (make_clusters), factored at every solve */
    bool clustered;           /* this step's clusters are made */
    int cap_cl;               /* objects the per-object arrays below hold */
    int *uf, *uf_dofs, *uf_cap; /* union-find: parent of each object, DOFs of each root's set, DOF cap of each
                                   object's cluster */
    int *pair_mark, *pair_at; /* pair extraction: the object whose pairs are gathered, and where its pair with
                                 each object is */
    int *obj_local;           /* first DOF of each object in its unit's numbering */
    int *unit_obj;            /* objects by unit */
    int *singles;             /* the objects in no cluster */
    int nsingles;
    LagUnit *units;
    int nunits;
    LagPair *pairs, *pairs_tmp;
    size_t npairs, cap_pairs, cap_pairs_tmp;
    bool pairs_slack;
    int *obj_unit;            /* unit of each object */
    LagSlot *slots;
    int nslots, cap_slots;    /* slots in use (clusters this step), slots made */
    DrChol *probes[LAG_PROBES]; /* analyses of patterns found too large for a cluster, newest last */
    int nprobes;
    DrLagDofs dofs;           /* dr_lag_dofs: the models' per-DOF arrays */
    int ndof_dofs;            /* the DOF count dofs is sized for (0: none yet) */
    size_t cap_work;
    size_t cap_dof;
};

void dr_lag_desc_default(DrLagDesc *d)
{
    d->precond = DR_LAG_PRECOND_BLOCK;
    d->tol = 1e-8;
    d->max_iter = 1000;
    d->local_guess = true;
    d->cluster_entries = 67108864.0;
}

DrStatus dr_lag_create(const DrLagDesc *desc, DrLag **out, DrError *err)
{
    *out = NULL;
    DrLag *s = NULL;
    DR_TRY(dr_calloc(1, sizeof *s, &s, err));
    if (desc) s->desc = *desc;
    else dr_lag_desc_default(&s->desc);
    *out = s;
    return DR_OK;
}

static void records_free(LagRecords *r)
{
    free(r->ints);
    free(r->reals);
    free(r->lambda);
    memset(r, 0, sizeof *r);
}

void dr_lag_destroy(DrLag **sp)
{
    if (!sp || !*sp) return;
    DrLag *s = *sp;
    for (int i = 0; i < s->nobj; i++) {
        free(s->obj[i].mat);
        free(s->obj[i].geo);
        free(s->obj[i].pre);
        free(s->obj[i].ext);
        free(s->obj[i].op);
        dr_banded_destroy(&s->obj[i].factor);
        records_free(&s->obj[i].rec);
    }
    free(s->obj);
    free(s->dof_object);
    free(s->obj_status);
    free(s->b);
    free(s->b_local);
    free(s->rhs);
    free(s->rhs_local);
    free(s->diag);
    free(s->inv_mass);
    free(s->trip);
    free(s->trip_tmp);
    records_free(&s->grec);
    dr_csr_destroy(&s->kg);
    free(s->work);
    free(s->dofs.mass);
    free(s->dofs.qdot);
    free(s->dofs.fext);
    free(s->dofs.prescribed);
    free(s->dofs.qdot_prescribed);
    free(s->dofs.force);
    free(s->dofs.qdot_out);
    free(s->uf);
    free(s->uf_dofs);
    free(s->uf_cap);
    for (int k = 0; k < s->nprobes; k++) dr_chol_destroy(&s->probes[k]);
    free(s->pair_mark);
    free(s->pair_at);
    free(s->obj_local);
    free(s->unit_obj);
    free(s->obj_unit);
    free(s->singles);
    free(s->units);
    free(s->pairs);
    free(s->pairs_tmp);
    for (int k = 0; k < s->cap_slots; k++) {
        dr_csr_destroy(&s->slots[k].A);
        dr_chol_destroy(&s->slots[k].chol);
        free(s->slots[k].buf);
    }
    free(s->slots);
    free(s);
    *sp = NULL;
}

void dr_lag_set_desc(DrLag *s, const DrLagDesc *desc) { s->desc = *desc; }
int dr_lag_object_count(const DrLag *s) { return s->nobj; }
int dr_lag_dof_count(const DrLag *s) { return s->ndof; }

/* Grows *p (elements of size `size`) to hold at least `need`, by half again when it must grow. The buffer is
   kept from step to step, so a step that fits what an earlier one reserved allocates nothing (see
   reserve_slack for the first step's). */
static DrStatus grow(void **p, size_t *cap, size_t need, size_t size, DrError *err)
{
    if (need <= *cap) return DR_OK;
    size_t n = *cap + *cap / 2;
    if (n < need) n = need;
    if (n < 16) n = 16;
    DR_TRY(dr_realloc(n, size, p, err));
    *cap = n;
    return DR_OK;
}

DrStatus dr_lag_add_object(DrLag *s, int ndof, int kd, int *id, int *dof_begin, DrError *err)
{
    if (ndof < 1 || kd < 0 || (kd >= ndof && !(ndof == 1 && kd == 0)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "Lagrangian object with %d DOFs and half-bandwidth %d: need ndof >= 1 and 0 <= kd < ndof",
                            ndof, kd);
    if (s->ndof > 2147483647 - ndof)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "too many DOFs in one Lagrangian system (over 2^31)");
    size_t cap = (size_t)s->cap_obj;
    DR_TRY(grow((void **)&s->obj, &cap, (size_t)s->nobj + 1, sizeof *s->obj, err));
    if (cap > (size_t)s->cap_obj) DR_TRY(dr_realloc(cap, sizeof(int), &s->obj_status, err));
    s->cap_obj = (int)cap;
    LagObject *o = &s->obj[s->nobj];
    memset(o, 0, sizeof *o);
    o->dof0 = s->ndof;
    o->ndof = ndof;
    o->kd = kd;
    size_t band = (size_t)(kd + 1) * (size_t)ndof;
    DrStatus st = dr_calloc(band, sizeof(double), &o->mat, err);
    if (st == DR_OK) st = dr_calloc(band, sizeof(double), &o->geo, err);
    if (st == DR_OK) st = dr_calloc(band, sizeof(double), &o->pre, err);
    if (st == DR_OK) st = dr_calloc(band, sizeof(double), &o->ext, err);
    if (st == DR_OK) st = dr_calloc(band, sizeof(double), &o->op, err);
    if (st == DR_OK) st = dr_banded_create(ndof, kd, &o->factor, err);
    if (st == DR_OK) {
        size_t c = s->cap_dof;
        st = grow((void **)&s->dof_object, &c, (size_t)s->ndof + (size_t)ndof, sizeof(int), err);
        s->cap_dof = c;
    }
    if (st != DR_OK) {
        free(o->mat);
        free(o->geo);
        free(o->pre);
        free(o->ext);
        free(o->op);
        dr_banded_destroy(&o->factor);
        return st;
    }
    for (int k = 0; k < ndof; k++) s->dof_object[s->ndof + k] = s->nobj;
    if (id) *id = s->nobj;
    if (dof_begin) *dof_begin = s->ndof;
    s->nobj++;
    s->ndof += ndof;
    return DR_OK;
}

DrStatus dr_lag_dofs(DrLag *s, DrLagDofs *out, DrError *err)
{
    if (s->ndof_dofs != s->ndof) {
        DrLagDofs d = {0};
        size_t n = s->ndof > 0 ? (size_t)s->ndof : 1;
        DrStatus st = dr_calloc(n, sizeof(double), &d.mass, err);
        if (st == DR_OK) st = dr_calloc(n, sizeof(double), &d.qdot, err);
        if (st == DR_OK) st = dr_calloc(n, sizeof(double), &d.fext, err);
        if (st == DR_OK) st = dr_calloc(n, sizeof(unsigned char), &d.prescribed, err);
        if (st == DR_OK) st = dr_calloc(n, sizeof(double), &d.qdot_prescribed, err);
        if (st == DR_OK) st = dr_calloc(n, sizeof(double), &d.force, err);
        if (st == DR_OK) st = dr_calloc(n, sizeof(double), &d.qdot_out, err);
        void *fresh[] = {d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, d.force, d.qdot_out};
        void *old[] = {s->dofs.mass, s->dofs.qdot, s->dofs.fext, s->dofs.prescribed, s->dofs.qdot_prescribed,
                       s->dofs.force, s->dofs.qdot_out};
        void **drop = st == DR_OK ? old : fresh;
        for (size_t k = 0; k < sizeof old / sizeof old[0]; k++) free(drop[k]);
        if (st != DR_OK) return st;
        s->dofs = d;
        s->ndof_dofs = s->ndof;
    }
    *out = s->dofs;
    return DR_OK;
}

DrStatus dr_lag_begin(DrLag *s, double h, const double *mass, const double *qdot, const double *f_ext,
                      const unsigned char *prescribed, const double *qdot_prescribed, DrError *err)
{
    assert(h > 0 && mass && qdot && (!prescribed || qdot_prescribed));
    int n = s->ndof;
    size_t cap = (size_t)n > s->cap_work ? (size_t)n : s->cap_work;
    if ((size_t)n > s->cap_work || !s->b) {
        free(s->b);
        free(s->b_local);
        free(s->rhs);
        free(s->rhs_local);
        free(s->diag);
        free(s->inv_mass);
        free(s->work);
        s->b = s->b_local = s->rhs = s->rhs_local = s->diag = s->inv_mass = s->work = NULL;
        s->cap_work = 0;
        size_t m = cap ? cap : 1;
        DR_TRY(dr_calloc(m, sizeof(double), &s->b, err));
        DR_TRY(dr_calloc(m, sizeof(double), &s->b_local, err));
        DR_TRY(dr_calloc(m, sizeof(double), &s->rhs, err));
        DR_TRY(dr_calloc(m, sizeof(double), &s->rhs_local, err));
        DR_TRY(dr_calloc(m, sizeof(double), &s->diag, err));
        DR_TRY(dr_calloc(m, sizeof(double), &s->inv_mass, err));
        DR_TRY(dr_calloc(5 * m, sizeof(double), &s->work, err));
        s->cap_work = m;
    }
    for (int k = 0; k < n; k++) {
        if (!(mass[k] > 0) || !isfinite(mass[k]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "DOF %d has mass %g; every DOF needs a positive mass", k,
                                mass[k]);
        bool p = prescribed && prescribed[k];
        double v = p ? qdot_prescribed[k] : qdot[k];
        double f = (!p && f_ext) ? f_ext[k] : 0.0;
        s->b[k] = s->b_local[k] = mass[k] * v + h * f;
        s->inv_mass[k] = 1.0 / mass[k];
    }
    for (int i = 0; i < s->nobj; i++) {
        LagObject *o = &s->obj[i];
        size_t band = (size_t)(o->kd + 1) * (size_t)o->ndof;
        memset(o->mat, 0, band * sizeof(double));
        memset(o->geo, 0, band * sizeof(double));
        memset(o->pre, 0, band * sizeof(double));
        o->has_pre = false;
        for (int k = 0; k < o->ndof; k++) o->mat[(size_t)(o->kd + 1) * (size_t)k] = mass[o->dof0 + k];
        o->dropped = false;
        o->rec.nints = o->rec.nreals = o->rec.ngroups = 0;
    }
    s->grec.nints = s->grec.nreals = s->grec.ngroups = 0;
    s->ntrip = 0;
    s->h = h;
    s->mass = mass;
    s->qdot = qdot;
    s->prescribed = prescribed;
    s->qdot_prescribed = qdot_prescribed;
    s->groups_block = s->groups_global = 0;
    s->begun = true;
    s->assembled = false;
    s->clustered = false;
    s->t_assemble0 = dr_time_now();
    return DR_OK;
}

static bool is_prescribed(const DrLag *s, int dof) { return s->prescribed && s->prescribed[dof]; }

static DrStatus check_group(const DrLag *s, const DrLagGroup *g, DrError *err)
{
    assert(g->nrows >= 1 && g->nrows <= DR_LAG_MAX_ROWS && g->ndof >= 1 && g->ndof <= DR_LAG_MAX_DOFS);
    for (int a = 0; a < g->ndof; a++) assert(g->dof[a] >= 0 && g->dof[a] < s->ndof);
    bool ok = true;
    for (int r = 0; r < g->nrows; r++) {
        ok = ok && isfinite(g->phi[r]) && isfinite(g->cinv[r]) && g->cinv[r] >= 0;
        for (int a = 0; a < g->ndof; a++) ok = ok && isfinite(g->J[r * g->ndof + a]);
    }
    if (g->G)
        for (int a = 0; a < g->ndof * g->ndof; a++) ok = ok && isfinite(g->G[a]);
    if (!ok)
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "a constraint over DOFs %d..%d has a non-finite value, compliance or Jacobian (the "
                            "configuration has blown up or is degenerate: a zero-length edge?)",
                            g->dof[0], g->dof[g->ndof - 1]);
    return DR_OK;
}

/* Room for twice what the records hold. */
static DrStatus records_slack(LagRecords *r, DrError *err)
{
    DR_TRY(grow((void **)&r->ints, &r->cap_ints, 2 * r->nints, sizeof(int), err));
    DR_TRY(grow((void **)&r->reals, &r->cap_reals, 2 * r->nreals, sizeof(double), err));
    DR_TRY(grow((void **)&r->lambda, &r->cap_groups, 2 * r->ngroups, sizeof(double *), err));
    return DR_OK;
}

static DrStatus record(LagRecords *r, const DrLagGroup *g, double sc, DrError *err)
{
    DR_TRY(grow((void **)&r->ints, &r->cap_ints, r->nints + 2 + (size_t)g->ndof, sizeof(int), err));
    DR_TRY(grow((void **)&r->reals, &r->cap_reals, r->nreals + 1 + 2 * (size_t)g->nrows + (size_t)(g->nrows * g->ndof),
                sizeof(double), err));
    DR_TRY(grow((void **)&r->lambda, &r->cap_groups, r->ngroups + 1, sizeof(double *), err));
    int *pi = r->ints + r->nints;
    pi[0] = g->nrows;
    pi[1] = g->ndof;
    memcpy(pi + 2, g->dof, (size_t)g->ndof * sizeof(int));
    r->nints += 2 + (size_t)g->ndof;
    double *pd = r->reals + r->nreals;
    pd[0] = sc;
    memcpy(pd + 1, g->phi, (size_t)g->nrows * sizeof(double));
    memcpy(pd + 1 + g->nrows, g->cinv, (size_t)g->nrows * sizeof(double));
    memcpy(pd + 1 + 2 * g->nrows, g->J, (size_t)(g->nrows * g->ndof) * sizeof(double));
    r->nreals += 1 + 2 * (size_t)g->nrows + (size_t)(g->nrows * g->ndof);
    r->lambda[r->ngroups++] = g->lambda;
    return DR_OK;
}

/* The group's local matrix h s JᵀC⁻¹J (material, into mat) and −h² G (geometric, into geo), both ndof×ndof,
   and its right-hand side −h JᵀC⁻¹c (rhs). s = h for positional rows, 1 for viscous rows. */
static void local_terms(const DrLag *s, const DrLagGroup *g, double *mat, double *geo, double *rhs)
{
    int nd = g->ndof;
    double h = s->h, sc = g->kind == DR_LAG_POSITIONAL ? h : 1.0;
    for (int a = 0; a < nd; a++) {
        double acc = 0;
        for (int r = 0; r < g->nrows; r++) acc += g->J[r * nd + a] * g->cinv[r] * g->phi[r];
        rhs[a] = -h * acc;
        for (int b = 0; b <= a; b++) {
            double m = 0;
            for (int r = 0; r < g->nrows; r++) m += g->J[r * nd + a] * g->cinv[r] * g->J[r * nd + b];
            mat[a * nd + b] = mat[b * nd + a] = h * sc * m;
            double gg = (g->G && g->kind == DR_LAG_POSITIONAL) ? -h * h * 0.5 * (g->G[a * nd + b] + g->G[b * nd + a]) : 0;
            geo[a * nd + b] = geo[b * nd + a] = gg;
        }
    }
}

DrStatus dr_lag_add(DrLag *s, const DrLagGroup *g, DrError *err)
{
    assert(s->begun && !s->assembled);
    DR_TRY(check_group(s, g, err));
    int obj = s->dof_object[g->dof[0]];
    LagObject *o = &s->obj[obj];
    int lo = g->dof[0], hi = g->dof[0];
    for (int a = 0; a < g->ndof; a++) {
        if (s->dof_object[g->dof[a]] != obj)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "constraint over DOFs of objects %d and %d added as a block group; use dr_lag_add_global",
                                obj, s->dof_object[g->dof[a]]);
        if (g->dof[a] < lo) lo = g->dof[a];
        if (g->dof[a] > hi) hi = g->dof[a];
    }
    if (hi - lo > o->kd)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "constraint spans DOFs %d..%d, wider than object %d's band (%d); use dr_lag_add_global", lo,
                            hi, obj, o->kd);
    double mat[DR_LAG_MAX_DOFS * DR_LAG_MAX_DOFS], geo[DR_LAG_MAX_DOFS * DR_LAG_MAX_DOFS], rhs[DR_LAG_MAX_DOFS];
    local_terms(s, g, mat, geo, rhs);
    int nd = g->ndof, ld = o->kd + 1;
    for (int a = 0; a < nd; a++) {
        int da = g->dof[a];
        if (is_prescribed(s, da)) continue;
        s->b[da] += rhs[a];
        s->b_local[da] += rhs[a];
        for (int b = 0; b < nd; b++) {
            int db = g->dof[b];
            if (is_prescribed(s, db)) {
                /* symmetric elimination: the known velocity moves to the right-hand side */
                double v = s->qdot_prescribed[db];
                s->b[da] -= (mat[a * nd + b] + geo[a * nd + b]) * v;
                s->b_local[da] -= (mat[a * nd + b] + geo[a * nd + b]) * v;
                continue;
            }
            if (db > da) continue; /* lower triangle (and diagonal) only */
            size_t at = (size_t)(da - db) + (size_t)ld * (size_t)(db - o->dof0);
            o->mat[at] += mat[a * nd + b];
            o->geo[at] += geo[a * nd + b];
        }
    }
    return record(&o->rec, g, g->kind == DR_LAG_POSITIONAL ? s->h : 1.0, err);
}

DrStatus dr_lag_add_with_twin(DrLag *s, const DrLagGroup *g, double damping, DrError *err)
{
    DR_TRY(dr_lag_add(s, g, err));
    if (!(damping > 0)) return DR_OK;
    DrLagGroup gv = *g;
    gv.kind = DR_LAG_VISCOUS;
    gv.G = NULL;
    gv.lambda = NULL;
    for (int k = 0; k < g->nrows; k++) {
        gv.phi[k] = 0;
        gv.cinv[k] = damping * g->cinv[k];
    }
    return dr_lag_add(s, &gv, err);
}

DrStatus dr_lag_add_global(DrLag *s, const DrLagGroup *g, DrError *err)
{
    assert(s->begun && !s->assembled);
    DR_TRY(check_group(s, g, err));
    double mat[DR_LAG_MAX_DOFS * DR_LAG_MAX_DOFS], geo[DR_LAG_MAX_DOFS * DR_LAG_MAX_DOFS], rhs[DR_LAG_MAX_DOFS];
    local_terms(s, g, mat, geo, rhs);
    int nd = g->ndof;
    DR_TRY(grow((void **)&s->trip, &s->cap_trip, s->ntrip + (size_t)(nd * nd), sizeof(LagTriplet), err));
    for (int a = 0; a < nd; a++) {
        int da = g->dof[a];
        if (is_prescribed(s, da)) continue;
        s->b[da] += rhs[a];
        for (int b = 0; b < nd; b++) {
            int db = g->dof[b];
            double v = mat[a * nd + b] + geo[a * nd + b];
            if (is_prescribed(s, db)) {
                s->b[da] -= v * s->qdot_prescribed[db];
                continue;
            }
            if (v == 0) continue;
            s->trip[s->ntrip++] = (LagTriplet){da, db, v};
            /* the part on one object's DOFs within its band also goes into that block of the preconditioner */
            LagObject *oa = &s->obj[s->dof_object[da]];
            if (db <= da && s->dof_object[db] == s->dof_object[da] && da - db <= oa->kd) {
                oa->pre[(size_t)(da - db) + (size_t)(oa->kd + 1) * (size_t)(db - oa->dof0)] += v;
                oa->has_pre = true;
            }
        }
    }
    s->groups_global++;
    return record(&s->grec, g, g->kind == DR_LAG_POSITIONAL ? s->h : 1.0, err);
}

static inline bool trip_less(const LagTriplet *a, const LagTriplet *b)
{
    return a->i != b->i ? a->i < b->i : a->j < b->j;
}

DR_DEFINE_STABLE_SORT(trip_sort, LagTriplet, trip_less) /* by (i, j), duplicates in the order they came */

/* K_G triplets → CSR (sorted stably, so duplicates are summed in the order they were added; the triplets are
   generated in a fixed order for any thread count). */
static DrStatus build_kg(DrLag *s, DrError *err)
{
    int n = s->ndof;
    /* K_G has at most one entry per triplet: sized by the triplets' capacity, it grows when they do */
    int cap = s->cap_trip > 0 ? (s->cap_trip < INT_MAX ? (int)s->cap_trip : INT_MAX - 1) : 1;
    if (!s->kg) DR_TRY(dr_csr_create(n, cap, &s->kg, err));
    if (s->cap_trip_tmp < s->cap_trip) {
        DR_TRY(dr_realloc(s->cap_trip, sizeof(LagTriplet), &s->trip_tmp, err));
        s->cap_trip_tmp = s->cap_trip;
    }
    trip_sort(s->trip, s->trip_tmp, s->ntrip);
    DR_TRY(dr_csr_reserve(s->kg, n, cap, err));
    DrCsr *A = s->kg;
    int nnz = 0;
    for (size_t t = 0; t < s->ntrip;) {
        size_t u = t;
        double v = 0;
        while (u < s->ntrip && s->trip[u].i == s->trip[t].i && s->trip[u].j == s->trip[t].j) v += s->trip[u++].v;
        A->col[nnz] = s->trip[t].j;
        A->val[nnz] = v;
        A->rowptr[s->trip[t].i + 1]++;
        nnz++;
        t = u;
    }
    for (int i = 0; i < n; i++) A->rowptr[i + 1] += A->rowptr[i];
    A->nnz = nnz;
    return DR_OK;
}

/* ---- the operator, the preconditioners ------------------------------------------------------------------ */

typedef struct ApplyCtx {
    const DrLag *s;
    const double *x;
    double *y;
} ApplyCtx;

/* y_i = A_i x_i for objects [begin, end): symmetric band product from the lower band. */
static void apply_blocks(long begin, long end, void *vctx)
{
    ApplyCtx *c = vctx;
    for (long oi = begin; oi < end; oi++) {
        const LagObject *o = &c->s->obj[oi];
        const double *x = c->x + o->dof0;
        double *y = c->y + o->dof0;
        int n = o->ndof, ld = o->kd + 1;
        for (int i = 0; i < n; i++) y[i] = 0;
        for (int j = 0; j < n; j++) {
            const double *col = o->op + (size_t)ld * (size_t)j;
            double xj = x[j], acc = col[0] * xj;
            int top = j + o->kd < n - 1 ? j + o->kd : n - 1;
            for (int i = j + 1; i <= top; i++) {
                y[i] += col[i - j] * xj;
                acc += col[i - j] * x[i];
            }
            y[j] += acc;
        }
    }
}

/* Element-wise vector kernels of the PCG loop, run in parallel: each element is computed alone, so the result
   does not depend on the thread count. */
typedef enum VecOp { VEC_ADD, VEC_STEP, VEC_DIRECTION, VEC_JACOBI } VecOp;
typedef struct VecCtx {
    VecOp op;
    double a;
    double *x, *r, *p, *q;
    const double *u, *v, *w;
} VecCtx;

static void vec_range(long begin, long end, void *vctx)
{
    VecCtx *c = vctx;
    switch (c->op) {
    case VEC_ADD: /* x += u */
        for (long k = begin; k < end; k++) c->x[k] += c->u[k];
        break;
    case VEC_STEP: /* x += a p, r −= a w, q = r ∘ M⁻¹ (for the mass-weighted norm) */
        for (long k = begin; k < end; k++) {
            c->x[k] += c->a * c->p[k];
            c->r[k] -= c->a * c->w[k];
            c->q[k] = c->r[k] * c->v[k];
        }
        break;
    case VEC_DIRECTION: /* p = u + a p */
        for (long k = begin; k < end; k++) c->p[k] = c->u[k] + c->a * c->p[k];
        break;
    case VEC_JACOBI: /* q = u / v */
        for (long k = begin; k < end; k++) c->q[k] = c->u[k] / c->v[k];
        break;
    }
}

static void vec(VecCtx c, int n) { dr_parallel_for(n, 4096, vec_range, &c); }

void dr_lag_apply(const DrLag *s, const double *x, double *y)
{
    ApplyCtx c = {s, x, y};
    dr_parallel_for(s->nobj, 64, apply_blocks, &c);
    if (s->kg && s->ntrip > 0) {
        /* K_G x by rows in parallel (dr_csr_matvec: each row summed in column order) */
        double *t = s->work + 4 * (size_t)s->ndof;
        dr_csr_matvec(s->kg, x, t);
        vec((VecCtx){.op = VEC_ADD, .x = y, .u = t}, s->ndof);
    }
}

typedef struct FactorCtx {
    DrLag *s;
    int *status;  /* per object: 0 ok, 1 dropped geometric part, 2 failed; | 4: preconditioned without pre */
} FactorCtx;

/* Positive definiteness is decided on the block's own operator (mat + geo): with it positive definite and
   K_G positive semidefinite the whole A is. Testing op + pre instead is not enough: the in-band part of K_G
   can hide an indefinite op whose off-block remainder then makes A indefinite (seen as a CG breakdown on a
   contact-rich groom). A block with contact terms is then factored again with them for the preconditioner. */
static void factor_blocks(long begin, long end, void *vctx)
{
    FactorCtx *c = vctx;
    for (long oi = begin; oi < end; oi++) {
        LagObject *o = &c->s->obj[oi];
        size_t band = (size_t)(o->kd + 1) * (size_t)o->ndof;
        DrError e;
        o->dropped = false;
        if (o->has_ext)
            for (size_t k = 0; k < band; k++) o->factor->ab[k] = o->op[k] = o->mat[k] + o->geo[k] + o->ext[k];
        else
            for (size_t k = 0; k < band; k++) o->factor->ab[k] = o->op[k] = o->mat[k] + o->geo[k];
        o->factor->factored = false;
        c->status[oi] = 0;
        if (dr_banded_factor(o->factor, &e) != DR_OK) {
            if (o->has_ext)
                for (size_t k = 0; k < band; k++) o->factor->ab[k] = o->op[k] = o->mat[k] + o->ext[k];
            else
                for (size_t k = 0; k < band; k++) o->factor->ab[k] = o->op[k] = o->mat[k];
            o->factor->factored = false;
            o->dropped = true;
            c->status[oi] = dr_banded_factor(o->factor, &e) == DR_OK ? 1 : 2;
            if (c->status[oi] == 2) continue;
        }
        if (!o->has_pre) continue;
        for (size_t k = 0; k < band; k++) o->factor->ab[k] = o->op[k] + o->pre[k];
        o->factor->factored = false;
        if (dr_banded_factor(o->factor, &e) == DR_OK) continue;
        /* pre need not be positive semidefinite: a contact between two edges of one strand that lie further apart
           than the band leaves only part of its (PSD) self terms in the band, and a PSD matrix cut to a band can
           be indefinite, enough to outweigh a soft block's smallest eigenvalues (a twist's inertia). The block is
           then preconditioned by its own operator, factored above. */
        for (size_t k = 0; k < band; k++) o->factor->ab[k] = o->op[k];
        o->factor->factored = false;
        c->status[oi] = dr_banded_factor(o->factor, &e) == DR_OK ? c->status[oi] | 4 : 2;
    }
}

typedef struct SolveCtx {
    const DrLag *s;
    const double *r;
    double *z;
} SolveCtx;

static void solve_blocks(long begin, long end, void *vctx)
{
    SolveCtx *c = vctx;
    for (long oi = begin; oi < end; oi++) {
        const LagObject *o = &c->s->obj[oi];
        memcpy(c->z + o->dof0, c->r + o->dof0, (size_t)o->ndof * sizeof(double));
        dr_banded_solve(o->factor, c->z + o->dof0, 1);
    }
}

/* ---- the cluster preconditioner -------------------------------------------------------------------------------
 * The block preconditioner sees each object alone; couplings in K_G stiffer than the objects themselves (bridges,
 * contacts) leave it blind to the neighbours, and CG pays in iterations. CLUSTER groups objects joined through K_G
 * into clusters and preconditions each by the Cholesky factor of its whole part of A (its objects' blocks and every
 * K_G entry between its DOFs), an object without pairs by its banded factor as BLOCK does: block Jacobi over
 * clusters. A cluster that holds a whole connected part of the system solves it exactly.
 *
 * Why whole clusters and not small ones: what costs iterations are the smooth modes across many coupled strands (a
 * bundle swinging as one), which no block of bounded size sees: in a bundle of 12 × 12 strands joined by 1e3 N/m
 * springs along their length (tests/bench/bench_hair, part 3), clusters of 16 strands took about as many
 * iterations as single strands (456–516 against 257–487 per step), clusters of 2 up to three times as many (the
 * smallest eigenvalue of the preconditioned matrix stayed where it was, more of them gathered near it), and the
 * whole bundle as one cluster takes 1. In dry contact the factor of a whole groom is hardly larger than its matrix.
 *
 * Clusters (make_clusters, once per step, at the first solve): every pair of objects with an entry in K_G gets the
 * strength max |A_ij| / sqrt(A_ii A_jj) over its entries; pairs are taken from the strongest down (ties in the
 * order of their objects) and joined by union-find, so a clump of bridged strands is one cluster. The size cap is
 * the factor's: a cluster whose factor would hold more than desc.cluster_entries entries (CHOLMOD's symbolic
 * analysis tells before any numeric work) is cut, by union-find again within it under a DOF cap scaled to fit
 * (fill grows about as DOFs^(4/3) for strands coupled along their length), until every cluster fits. So a groom
 * in sparse contact stays whole, and a large soaked mass of strands is cut where its couplings are weakest. The
 * clusters depend on the step's K_G and diagonal only (never on the thread count, nor on earlier steps: a resumed
 * run makes the same ones); what is kept from step to step (factors, analyses, the analyses of patterns found too
 * large) saves time only.
 *
 * Factors (factor_clusters, every solve: a load changes A): the part of A on a cluster's DOFs is a principal
 * submatrix of A, so it is positive definite whenever A is, and its factor exists; one that fails all the same (A
 * not positive definite in round-off, geometric stiffness in K_G) leaves the cluster to its objects' banded factors
 * (Stats.clusters_failed), and CG goes on. A cluster with the same objects and pattern as the step before keeps its
 * analysis and allocates nothing. */

static DrStatus cluster_arrays(DrLag *s, DrError *err)
{
    if (s->cap_cl >= s->nobj && s->uf) return DR_OK;
    size_t n = (size_t)s->cap_obj;
    int **arrays[] = {&s->uf,        &s->uf_dofs,  &s->uf_cap,   &s->pair_mark, &s->pair_at,
                      &s->obj_local, &s->unit_obj, &s->obj_unit, &s->singles};
    for (size_t k = 0; k < sizeof arrays / sizeof arrays[0]; k++) DR_TRY(dr_realloc(n, sizeof(int), arrays[k], err));
    DR_TRY(dr_realloc(n, sizeof(LagUnit), &s->units, err));
    s->cap_cl = s->cap_obj;
    return DR_OK;
}

static int uf_find(int *uf, int x)
{
    while (uf[x] != x) {
        uf[x] = uf[uf[x]];
        x = uf[x];
    }
    return x;
}

static inline bool pair_stronger(const LagPair *a, const LagPair *b) { return a->w > b->w; }
DR_DEFINE_STABLE_SORT(pair_sort, LagPair, pair_stronger) /* strongest first; ties keep the order of their objects */

/* 1. The pairs of objects in K_G and their strength, each pair once (from its object of lower id), strongest first. */
static DrStatus cluster_pairs(DrLag *s, DrError *err)
{
    const DrCsr *kg = s->kg;
    s->npairs = 0;
    for (int o = 0; o < s->nobj; o++) s->pair_mark[o] = -1;
    if (kg && s->ntrip > 0)
        for (int a = 0; a < s->nobj; a++) {
            const LagObject *oa = &s->obj[a];
            for (int i = oa->dof0; i < oa->dof0 + oa->ndof; i++)
                for (int k = kg->rowptr[i]; k < kg->rowptr[i + 1]; k++) {
                    int j = kg->col[k], b = s->dof_object[j];
                    if (b <= a) continue;
                    /* |·| under the root: K_G with geometric stiffness can leave a diagonal entry negative */
                    double dd = fabs(s->diag[i] * s->diag[j]), w = dd > 0 ? fabs(kg->val[k]) / sqrt(dd) : INFINITY;
                    if (s->pair_mark[b] == a) {
                        LagPair *p = &s->pairs[s->pair_at[b]];
                        if (w > p->w) p->w = w;
                        continue;
                    }
                    DR_TRY(grow((void **)&s->pairs, &s->cap_pairs, s->npairs + 1, sizeof(LagPair), err));
                    s->pair_mark[b] = a;
                    s->pair_at[b] = (int)s->npairs;
                    s->pairs[s->npairs++] = (LagPair){a, b, w};
                }
        }
    if (!s->pairs_slack) { /* as reserve_slack: room for twice the first step's pairs */
        DR_TRY(grow((void **)&s->pairs, &s->cap_pairs, 2 * s->npairs, sizeof(LagPair), err));
        s->pairs_slack = true;
    }
    if (s->cap_pairs_tmp < s->cap_pairs) {
        DR_TRY(dr_realloc(s->cap_pairs, sizeof(LagPair), &s->pairs_tmp, err));
        s->cap_pairs_tmp = s->cap_pairs;
    }
    pair_sort(s->pairs, s->pairs_tmp, s->npairs);
    return DR_OK;
}

/* 2. Union-find from the strongest pair down, a pair joined unless the joined set would hold more DOFs than either
   object's cap (uf_cap); a set's root is its object of lowest id. Then the units in the order of their first
   object, their objects in id order, and a slot for each cluster of two objects or more. */
static DrStatus cluster_units(DrLag *s, DrError *err)
{
    int nobj = s->nobj;
    for (int o = 0; o < nobj; o++) {
        s->uf[o] = o;
        s->uf_dofs[o] = s->obj[o].ndof;
    }
    for (size_t k = 0; k < s->npairs; k++) {
        int a = s->pairs[k].a, b = s->pairs[k].b, ra = uf_find(s->uf, a), rb = uf_find(s->uf, b);
        int cap = s->uf_cap[a] < s->uf_cap[b] ? s->uf_cap[a] : s->uf_cap[b];
        if (ra == rb || (long)s->uf_dofs[ra] + s->uf_dofs[rb] > cap) continue;
        int lo = ra < rb ? ra : rb, hi = ra < rb ? rb : ra;
        s->uf[hi] = lo;
        s->uf_dofs[lo] += s->uf_dofs[hi];
    }
    int *unit_of = s->obj_unit;
    s->nunits = 0;
    for (int o = 0; o < nobj; o++) {
        int r = uf_find(s->uf, o);
        if (r == o) s->units[s->nunits++] = (LagUnit){0, 0, 0, -1};
        unit_of[o] = r == o ? s->nunits - 1 : unit_of[r];
        s->units[unit_of[o]].nobj++;
    }
    for (int u = 0, first = 0; u < s->nunits; u++) {
        s->units[u].first = first;
        first += s->units[u].nobj;
        s->units[u].nobj = 0;
    }
    for (int o = 0; o < nobj; o++) {
        LagUnit *u = &s->units[unit_of[o]];
        s->unit_obj[u->first + u->nobj++] = o;
        s->obj_local[o] = u->ndof;
        u->ndof += s->obj[o].ndof;
    }
    s->nslots = s->nsingles = 0;
    for (int u = 0; u < s->nunits; u++) {
        if (s->units[u].nobj < 2) {
            s->singles[s->nsingles++] = s->unit_obj[s->units[u].first];
            continue;
        }
        if (s->nslots == s->cap_slots) {
            int cap = s->cap_slots ? 2 * s->cap_slots : 16;
            DR_TRY(dr_realloc((size_t)cap, sizeof(LagSlot), &s->slots, err));
            memset(s->slots + s->cap_slots, 0, (size_t)(cap - s->cap_slots) * sizeof(LagSlot));
            s->cap_slots = cap;
        }
        LagSlot *sl = &s->slots[s->nslots];
        if (!sl->A) DR_TRY(dr_csr_create(0, 0, &sl->A, err));
        if (!sl->chol) DR_TRY(dr_chol_create(&sl->chol, err));
        DR_TRY(grow((void **)&sl->buf, &sl->cap_buf, (size_t)s->units[u].ndof, sizeof(double), err));
        sl->unit = u;
        sl->probe = -1;
        s->units[u].slot = s->nslots++;
    }
    return DR_OK;
}

/* The cluster's part of A, lower triangle by rows in the cluster's numbering (objects in id order, each one's
   DOFs in order: monotone in the global numbering, so K_G's column order is kept): per row the K_G entries
   left of the object's band (other objects of the cluster, or the object's own beyond its band), then the band
   of the operator with the K_G entries on it added. */
static DrStatus cluster_assemble(const DrLag *s, LagSlot *sl, DrError *err)
{
    const LagUnit *u = &s->units[sl->unit];
    const DrCsr *kg = s->ntrip > 0 ? s->kg : NULL;
    const int *unit_of = s->obj_unit;
    int me = sl->unit;
    size_t bound = 0;
    for (int q = 0; q < u->nobj; q++) {
        const LagObject *o = &s->obj[s->unit_obj[u->first + q]];
        bound += (size_t)(o->kd + 1) * (size_t)o->ndof;
        if (kg) bound += (size_t)(kg->rowptr[o->dof0 + o->ndof] - kg->rowptr[o->dof0]);
    }
    if (bound > INT_MAX)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "a cluster of %d DOFs has over 2^31 entries", u->ndof);
    DR_TRY(dr_csr_reserve(sl->A, u->ndof, (int)bound, err));
    DrCsr *A = sl->A;
    int nnz = 0, row = 0;
    A->rowptr[0] = 0;
    for (int q = 0; q < u->nobj; q++) {
        int oi = s->unit_obj[u->first + q];
        const LagObject *o = &s->obj[oi];
        int ld = o->kd + 1, base = s->obj_local[oi];
        for (int r = 0; r < o->ndof; r++, row++) {
            int g = o->dof0 + r, lo = r - o->kd > 0 ? r - o->kd : 0;
            int k = kg ? kg->rowptr[g] : 0, ke = kg ? kg->rowptr[g + 1] : 0;
            for (; k < ke && kg->col[k] < o->dof0 + lo; k++) {
                int j = kg->col[k], b = s->dof_object[j];
                if (unit_of[b] != me) continue;
                A->col[nnz] = s->obj_local[b] + (j - s->obj[b].dof0);
                A->val[nnz++] = kg->val[k];
            }
            for (int c = lo; c <= r; c++) {
                double v = o->op[(size_t)(r - c) + (size_t)ld * (size_t)c];
                if (k < ke && kg->col[k] == o->dof0 + c) v += kg->val[k++];
                A->col[nnz] = base + c;
                A->val[nnz++] = v;
            }
            A->rowptr[row + 1] = nnz;
        }
    }
    A->n = u->ndof;
    A->nnz = nnz;
    return DR_OK;
}

/* Per slot, in parallel: its matrix, and the size of its factor, from the slot's own analysis when the pattern is
   the one it analysed last, from a kept analysis of an oversized pattern (probe), or from a new analysis. */
static void analyse_slots(long begin, long end, void *vctx)
{
    DrLag *s = vctx;
    for (long k = begin; k < end; k++) {
        LagSlot *sl = &s->slots[k];
        DrError e;
        sl->probe = -1;
        sl->status = cluster_assemble(s, sl, &e);
        if (sl->status != DR_OK) continue;
        if (!dr_chol_analysed(sl->chol, sl->A))
            for (int p = 0; p < s->nprobes; p++)
                if (dr_chol_analysed(s->probes[p], sl->A)) {
                    sl->probe = p;
                    sl->entries = dr_chol_factor_entries(s->probes[p]);
                    break;
                }
        if (sl->probe >= 0) continue;
        sl->status = dr_chol_analyse(sl->chol, sl->A, &e);
        sl->entries = dr_chol_factor_entries(sl->chol);
    }
}

static DrStatus make_clusters(DrLag *s, DrError *err)
{
    DR_TRY(cluster_arrays(s, err));
    DR_TRY(cluster_pairs(s, err));
    for (int o = 0; o < s->nobj; o++) s->uf_cap[o] = INT_MAX;
    double budget = s->desc.cluster_entries;
    for (;;) {
        DR_TRY(cluster_units(s, err));
        dr_parallel_for(s->nslots, 1, analyse_slots, s);
        bool cut = false;
        for (int k = 0; k < s->nslots; k++) {
            LagSlot *sl = &s->slots[k];
            const LagUnit *u = &s->units[sl->unit];
            if (sl->status == DR_ERR_NOMEM)
                return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                                    "out of memory analysing a cluster of %d objects (%d DOFs); lower cluster_entries",
                                    u->nobj, u->ndof);
            if (sl->status != DR_OK || sl->entries <= budget) continue;
            /* too large: its objects' cap scaled to fit (entries ~ DOFs^(4/3)), by a quarter at least */
            double f = fmin(0.75, 0.9 * pow(budget / sl->entries, 0.75));
            int cap = (int)(f * u->ndof);
            for (int q = 0; q < u->nobj; q++) s->uf_cap[s->unit_obj[u->first + q]] = cap;
            cut = true;
            if (sl->probe >= 0) continue;
            /* keep its analysis as a probe (the slot takes a fresh factor, or the oldest probe's) */
            DrChol *old = NULL;
            if (s->nprobes == LAG_PROBES) {
                old = s->probes[0];
                memmove(s->probes, s->probes + 1, (LAG_PROBES - 1) * sizeof(DrChol *));
                s->nprobes--;
            }
            s->probes[s->nprobes++] = sl->chol;
            sl->chol = old;
            if (!sl->chol) DR_TRY(dr_chol_create(&sl->chol, err));
        }
        if (!cut) break;
    }
    s->clustered = true;
    return DR_OK;
}

typedef struct ClusterCtx {
    DrLag *s;
    int *analyses; /* per slot, in the factorisation */
} ClusterCtx;

static void factor_slots(long begin, long end, void *vctx)
{
    ClusterCtx *c = vctx;
    for (long k = begin; k < end; k++) {
        LagSlot *sl = &c->s->slots[k];
        DrError e;
        c->analyses[k] = dr_chol_analyses(sl->chol);
        sl->status = cluster_assemble(c->s, sl, &e);
        if (sl->status == DR_OK) sl->status = dr_chol_factor(sl->chol, sl->A, &e);
        c->analyses[k] = dr_chol_analyses(sl->chol) - c->analyses[k];
    }
}

/* Factors every cluster; fills the cluster figures of st. Out of memory is an error; a factorisation that fails
   otherwise leaves the cluster to its objects' blocks. */
static DrStatus factor_clusters(DrLag *s, DrLagStats *st, DrError *err)
{
    int *analyses = s->obj_status; /* free after factor_blocks: one int per object, more than the slots */
    ClusterCtx c = {s, analyses};
    dr_parallel_for(s->nslots, 1, factor_slots, &c);
    for (int k = 0; k < s->nslots; k++) {
        const LagSlot *sl = &s->slots[k];
        const LagUnit *u = &s->units[sl->unit];
        if (sl->status == DR_ERR_NOMEM)
            return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                                "out of memory factoring a cluster of %d objects (%d DOFs); lower cluster_entries",
                                u->nobj, u->ndof);
        st->clusters++;
        if (u->ndof > st->cluster_dofs_max) st->cluster_dofs_max = u->ndof;
        if (sl->status != DR_OK) st->clusters_failed++;
        else st->cluster_entries += dr_chol_factor_entries(sl->chol);
        st->cluster_analyses += analyses[k];
    }
    return DR_OK;
}

/* The clusters, each by its factor (or its objects' blocks when the factorisation failed); then the objects in no
   cluster by their blocks. Two loops, so that the threads share the clusters, which hold most of the work. */
static void solve_slots(long begin, long end, void *vctx)
{
    SolveCtx *c = vctx;
    const DrLag *s = c->s;
    for (long k = begin; k < end; k++) {
        LagSlot *sl = &s->slots[k];
        const LagUnit *u = &s->units[sl->unit];
        const int *objs = s->unit_obj + u->first;
        if (sl->status != DR_OK) {
            for (int q = 0; q < u->nobj; q++) solve_blocks(objs[q], objs[q] + 1, c);
            continue;
        }
        for (int q = 0; q < u->nobj; q++) {
            const LagObject *o = &s->obj[objs[q]];
            memcpy(sl->buf + s->obj_local[objs[q]], c->r + o->dof0, (size_t)o->ndof * sizeof(double));
        }
        dr_chol_solve(sl->chol, sl->buf);
        for (int q = 0; q < u->nobj; q++) {
            const LagObject *o = &s->obj[objs[q]];
            memcpy(c->z + o->dof0, sl->buf + s->obj_local[objs[q]], (size_t)o->ndof * sizeof(double));
        }
    }
}

static void solve_singles(long begin, long end, void *vctx)
{
    SolveCtx *c = vctx;
    for (long k = begin; k < end; k++) solve_blocks(c->s->singles[k], c->s->singles[k] + 1, c);
}

static void precondition(const DrLag *s, const double *r, double *z)
{
    int n = s->ndof;
    switch (s->desc.precond) {
    case DR_LAG_PRECOND_BLOCK: {
        SolveCtx c = {s, r, z};
        dr_parallel_for(s->nobj, 16, solve_blocks, &c);
        break;
    }
    case DR_LAG_PRECOND_CLUSTER: {
        SolveCtx c = {s, r, z};
        dr_parallel_for(s->nslots, 1, solve_slots, &c);
        dr_parallel_for(s->nsingles, 16, solve_singles, &c);
        break;
    }
    case DR_LAG_PRECOND_JACOBI:
        vec((VecCtx){.op = VEC_JACOBI, .q = z, .u = r, .v = s->diag}, n);
        break;
    case DR_LAG_PRECOND_NONE:
        memcpy(z, r, (size_t)n * sizeof(double));
        break;
    }
}

/* Σ a_k b_k w_k, sequential in DOF order (bit-identical for any thread count). */
static double wdot(const double *a, const double *b, const double *w, int n)
{
    double acc = 0;
    for (int k = 0; k < n; k++) acc += a[k] * b[k] * w[k];
    return acc;
}

/* ---- the solve -------------------------------------------------------------------------------------------- */

static void update_lambdas(const LagRecords *r, const double *v)
{
    size_t pi = 0, pd = 0;
    for (size_t g = 0; g < r->ngroups; g++) {
        int nrows = r->ints[pi], ndof = r->ints[pi + 1];
        const int *dof = r->ints + pi + 2;
        const double *d = r->reals + pd;
        double sc = d[0];
        const double *c = d + 1, *cinv = d + 1 + nrows, *J = d + 1 + 2 * nrows;
        if (r->lambda[g])
            for (int k = 0; k < nrows; k++) {
                double jv = 0;
                for (int a = 0; a < ndof; a++) jv += J[k * ndof + a] * v[dof[a]];
                r->lambda[g][k] = -cinv[k] * (c[k] + sc * jv); /* eqs. (S24), (S25) */
            }
        pi += 2 + (size_t)ndof;
        pd += 1 + 2 * (size_t)nrows + (size_t)(nrows * ndof);
    }
}

/* f += Σ_g J_gᵀ λ_g(v) over the groups of r. */
static void add_forces(const LagRecords *r, const double *v, double *f)
{
    size_t pi = 0, pd = 0;
    for (size_t g = 0; g < r->ngroups; g++) {
        int nrows = r->ints[pi], ndof = r->ints[pi + 1];
        const int *dof = r->ints + pi + 2;
        const double *d = r->reals + pd;
        double sc = d[0];
        const double *c = d + 1, *cinv = d + 1 + nrows, *J = d + 1 + 2 * nrows;
        for (int k = 0; k < nrows; k++) {
            double jv = 0;
            for (int a = 0; a < ndof; a++) jv += J[k * ndof + a] * v[dof[a]];
            double lam = -cinv[k] * (c[k] + sc * jv);
            for (int a = 0; a < ndof; a++) f[dof[a]] += J[k * ndof + a] * lam;
        }
        pi += 2 + (size_t)ndof;
        pd += 1 + 2 * (size_t)nrows + (size_t)(nrows * ndof);
    }
}

void dr_lag_constraint_forces(const DrLag *s, const double *qdot, double *f)
{
    assert(s->begun);
    for (int i = 0; i < s->nobj; i++) add_forces(&s->obj[i].rec, qdot, f);
    add_forces(&s->grec, qdot, f);
}

typedef struct LambdaCtx {
    const DrLag *s;
    const double *v;
} LambdaCtx;

static void lambda_blocks(long begin, long end, void *vctx)
{
    LambdaCtx *c = vctx;
    for (long oi = begin; oi < end; oi++) update_lambdas(&c->s->obj[oi].rec, c->v);
}

/* After the first step's groups: room for twice as many, in every buffer whose use follows the number of groups
   (records, K_G triplets and their sort). Contacts come and go from step to step; with this slack a step after
   the first allocates only when it needs more than twice what the first one did, and the buffers grow by half
   again from there. */
static DrStatus reserve_slack(DrLag *s, DrError *err)
{
    for (int i = 0; i < s->nobj; i++) DR_TRY(records_slack(&s->obj[i].rec, err));
    DR_TRY(records_slack(&s->grec, err));
    DR_TRY(grow((void **)&s->trip, &s->cap_trip, 2 * s->ntrip, sizeof(LagTriplet), err));
    s->slack = true;
    return DR_OK;
}

/* The load's share of the right-hand side (h f on free DOFs, the known velocities of prescribed columns of its
   blocks) into rhs and rhs_local, and its blocks −h ½(D + Dᵀ) into the objects' ext bands. */
static void apply_load(DrLag *s, const DrLagLoad *load)
{
    int n = s->ndof;
    double h = s->h;
    memcpy(s->rhs, s->b, (size_t)n * sizeof(double));
    memcpy(s->rhs_local, s->b_local, (size_t)n * sizeof(double));
    if (load->force)
        for (int k = 0; k < n; k++) {
            if (is_prescribed(s, k)) continue;
            s->rhs[k] += h * load->force[k];
            s->rhs_local[k] += h * load->force[k];
        }
    if (!load->dforce_dv) return;
    for (int k = 0; k < load->nblocks; k++) {
        int d0 = load->block_dof[k];
        assert(d0 >= 0 && d0 + 2 < n);
        LagObject *o = &s->obj[s->dof_object[d0]];
        assert(s->dof_object[d0 + 2] == s->dof_object[d0] && o->kd >= 2);
        const double *D = load->dforce_dv + 9 * (size_t)k;
        int ld = o->kd + 1;
        for (int a = 0; a < 3; a++) {
            int da = d0 + a;
            if (is_prescribed(s, da)) continue;
            for (int c = 0; c < 3; c++) {
                int dc = d0 + c;
                double v = -h * 0.5 * (D[3 * a + c] + D[3 * c + a]);
                if (is_prescribed(s, dc)) {
                    s->rhs[da] -= v * s->qdot_prescribed[dc];
                    s->rhs_local[da] -= v * s->qdot_prescribed[dc];
                    continue;
                }
                if (dc > da) continue;
                o->ext[(size_t)(da - dc) + (size_t)ld * (size_t)(dc - o->dof0)] += v;
                o->has_ext = true;
            }
        }
    }
}

DrStatus dr_lag_solve_load(DrLag *s, const DrLagLoad *load, double *x, DrLagStats *stats, DrError *err)
{
    assert(s->begun);
    DrLagStats st = {0};
    int n = s->ndof;
    for (int i = 0; i < s->nobj; i++) st.groups_block += (int)s->obj[i].rec.ngroups;
    st.groups_global = s->groups_global;
    if (!s->assembled) {
        if (!s->slack) DR_TRY(reserve_slack(s, err));
        DR_TRY(build_kg(s, err));
        s->assembled = true;
    }
    double t1 = dr_time_now();
    st.seconds_assemble = t1 - s->t_assemble0;
    s->t_assemble0 = t1; /* a further solve from this assembly reports no assembly time */

    /* 0. the load: a right-hand side of its own (b stays that of the groups), blocks in ext */
    for (int i = 0; i < s->nobj; i++) {
        LagObject *o = &s->obj[i];
        if (!o->has_ext) continue;
        memset(o->ext, 0, (size_t)(o->kd + 1) * (size_t)o->ndof * sizeof(double));
        o->has_ext = false;
    }
    bool loaded = load && (load->force || (load->dforce_dv && load->nblocks > 0));
    if (loaded) apply_load(s, load);
    const double *b = loaded ? s->rhs : s->b, *b_local = loaded ? s->rhs_local : s->b_local;

    /* 1. factor every block: the block preconditioner and the local guess need the factors, and every
       preconditioner needs the same decision on which blocks keep their geometric stiffness (Cholesky is
       the test of positive definiteness), so that all three solve one and the same system. */
    bool clusters = s->desc.precond == DR_LAG_PRECOND_CLUSTER;
    bool need_factor = s->desc.precond == DR_LAG_PRECOND_BLOCK || clusters;
    int *status = s->obj_status;
    FactorCtx fc = {s, status};
    dr_parallel_for(s->nobj, 16, factor_blocks, &fc);
    for (int i = 0; i < s->nobj; i++) {
        if (status[i] != 2 && (status[i] & 1)) st.indefinite_blocks++;
        if (status[i] != 2 && (status[i] & 4)) st.contact_blocks_dropped++;
        if (status[i] == 2)
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "object %d's block is not positive definite even without geometric stiffness "
                                "(non-positive compliance, or a degenerate configuration)",
                                i);
    }
    /* diag(A) for Jacobi */
    for (int oi = 0; oi < s->nobj; oi++) {
        const LagObject *o = &s->obj[oi];
        int ld = o->kd + 1;
        for (int k = 0; k < o->ndof; k++)
            s->diag[o->dof0 + k] = o->mat[(size_t)ld * k] + (o->dropped ? 0 : o->geo[(size_t)ld * k]);
        if (o->has_ext)
            for (int k = 0; k < o->ndof; k++) s->diag[o->dof0 + k] += o->ext[(size_t)ld * k];
    }
    if (s->kg)
        for (int i = 0; i < n; i++)
            for (int k = s->kg->rowptr[i]; k < s->kg->rowptr[i + 1]; k++)
                if (s->kg->col[k] == i) s->diag[i] += s->kg->val[k];
    if (clusters) {
        if (!s->clustered) DR_TRY(make_clusters(s, err));
        DR_TRY(factor_clusters(s, &st, err));
    }
    double t2 = dr_time_now();
    st.seconds_factor = t2 - t1;

    /* 2. initial guess: the local solves A_i* q̇_i = b_i* (S1 lines 1–3), or the current velocity */
    double *r = s->work, *z = r + n, *p = z + n, *w = p + n;
    if (need_factor && s->desc.local_guess) {
        SolveCtx c = {s, b_local, x};
        dr_parallel_for(s->nobj, 16, solve_blocks, &c);
    } else {
        for (int k = 0; k < n; k++) x[k] = is_prescribed(s, k) ? s->qdot_prescribed[k] : s->qdot[k];
    }
    for (int k = 0; k < n; k++)
        if (is_prescribed(s, k)) x[k] = s->qdot_prescribed[k];

    /* 3. PCG on the whole system (S1 lines 4–22) */
    dr_lag_apply(s, x, w);
    for (int k = 0; k < n; k++) r[k] = b[k] - w[k];
    double bnorm = sqrt(wdot(b, b, s->inv_mass, n));
    double target = s->desc.tol * (bnorm > 0 ? bnorm : 1.0);
    double rnorm = sqrt(wdot(r, r, s->inv_mass, n));
    precondition(s, r, z);
    memcpy(p, z, (size_t)n * sizeof(double));
    double gamma = dr_dot(r, z, n);
    int it = 0;
    DrStatus result = DR_OK;
    while (rnorm > target) {
        if (it >= s->desc.max_iter) {
            result = DR_WARN_NOT_CONVERGED;
            break;
        }
        dr_lag_apply(s, p, w);
        double pw = dr_dot(p, w, n);
        if (!(pw > 0) || !(gamma > 0))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "conjugate gradients broke down after %d iterations (pᵀAp = %g, rᵀz = %g): the "
                                "system is not positive definite or holds non-finite values",
                                it, pw, gamma);
        double alpha = gamma / pw;
        double *rm = s->work + 4 * (size_t)n; /* r ∘ M⁻¹ */
        vec((VecCtx){.op = VEC_STEP, .a = alpha, .x = x, .r = r, .p = p, .w = w, .q = rm, .v = s->inv_mass}, n);
        precondition(s, r, z);
        double gamma1 = dr_dot(r, z, n);
        double beta = gamma1 / gamma;
        gamma = gamma1;
        vec((VecCtx){.op = VEC_DIRECTION, .a = beta, .p = p, .u = z}, n);
        rnorm = sqrt(dr_dot(r, rm, n));
        it++;
        if (!isfinite(rnorm))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "conjugate gradients produced a non-finite residual after %d iterations", it);
    }
    st.iterations = it;
    st.residual = bnorm > 0 ? rnorm / bnorm : rnorm;
    st.converged = result == DR_OK;
    st.seconds_solve = dr_time_now() - t2;
    if (stats) *stats = st;
    return result;
}

void dr_lag_update_multipliers(DrLag *s, const double *qdot)
{
    assert(s->begun);
    LambdaCtx lc = {s, qdot};
    dr_parallel_for(s->nobj, 64, lambda_blocks, &lc);
    update_lambdas(&s->grec, qdot);
}

DrStatus dr_lag_solve(DrLag *s, double *x, DrLagStats *stats, DrError *err)
{
    DrStatus result = dr_lag_solve_load(s, NULL, x, stats, err);
    if (result >= 0) {
        double t = dr_time_now();
        dr_lag_update_multipliers(s, x);
        if (stats) stats->seconds_solve += dr_time_now() - t;
    }
    s->begun = false;
    return result;
}
