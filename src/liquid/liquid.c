/* Incompressible liquid: APIC/FLIP/PIC on a MAC grid with a variational, ghost-fluid pressure
 * projection. The phases of a substep follow liquid.h; each is a function below. */
#include "liquid/liquid.h"

#include "linalg/linalg.h"

#include <stdlib.h>
#include <string.h>

#define MAX_COLLIDERS_FRAME 64
#define EXTRAP_LAYERS 4
/* Smallest amount of work (faces, cells or particles) worth a parallel chunk. A parallel region costs a
   fork and a barrier, and when another process holds a core the barrier waits for a descheduled thread
   (up to a scheduler time slice): small grids run their loops serially instead. */
#define PAR_MIN_ITEMS 16384

struct DrLiquid {
    DrLiquidDesc d;          /* copy; pointer fields below are owned copies, sources are cleared */
    DrBoxVel *emitters;
    DrVec3 *kill_lo, *kill_hi;
    DrMacGrid *g;
    long ncells, nnodes;
    double *fm[3];           /* face masses from P2G, kg */
    double *uold[3];         /* face velocities right after P2G */
    double *wgt[3];          /* fraction of each face open to liquid (variational weights) */
    double *us[3];           /* solid velocity (component a) on faces with wgt < 1 */
    double *tmp[3], *tmp2[3];
    unsigned char *valid[3], *valid2[3], *valid3[3];
    double *nphi;            /* collider union phi at grid nodes (cell corners) */
    double *cphi;            /* liquid phi at cell centres */
    double *dens;            /* per cell: P2G face masses / (6ρΔx³), 0 in cells without particles */
    double *div_target;      /* per pressure row: Δx·D, the volume-correction divergence target (m/s) */
    double span;             /* duration of the current dr_liquid_advance call (a frame), s */
    int *row;                /* cell → pressure unknown, −1 if not a fluid cell */
    long *cells_of_row;
    DrCsr *A;
    DrMic0 *M;
    double *rhs, *q, *work;
    double *impulse_partial; /* 4 per z-slice of faces: grid-impulse partial sums */
    DrParticleBins *bins;
    DrLiquidState st;
    double *sx, *sv, *sc;    /* scratch particle arrays (same capacity) for the sort by cell */
    long cap;
    DrRng rng;
    double pmass;
    double vol_density;      /* density·dx³: the face mass of a full face (mass-weighted pressure) */
    DrColliderFrame frames[MAX_COLLIDERS_FRAME];
    int nframes;
};

/* Grain (z-slices per chunk) of a loop over the faces of component a: at least PAR_MIN_ITEMS faces. */
static long slice_grain(const DrMacGrid *g, int a)
{
    long per = (long)g->fdim[a][0] * g->fdim[a][1];
    long grain = (PAR_MIN_ITEMS + per - 1) / per;
    return grain < 1 ? 1 : grain;
}

void dr_liquid_desc_default(DrLiquidDesc *d)
{
    memset(d, 0, sizeof *d);
    d->domain_lo = dr_v3(0, 0, 0);
    d->domain_hi = dr_v3(1, 1, 1);
    d->dx = 1.0 / 32.0;
    d->wall_no_slip = false;
    d->density = 1000.0;
    d->viscosity = 1e-3;
    d->scheme = DR_TRANSFER_APIC;
    d->flip_blend = 0.05;
    d->volume_correction = 4.0;
    d->per_cell = 8;
    d->jitter = 1.0;
    d->seed = 1;
    d->gravity = dr_v3(0, -9.81, 0);
    d->cfl = 1.0;
    d->max_substeps = 64;
    d->pressure_tol = 1e-6;
    d->pressure_max_iter = 1000;
    d->pressure = DR_PRESSURE_GHOST_FLUID;
}

/* ---- particles storage ---------------------------------------------------------------------- */

static DrStatus reserve_particles(DrLiquid *L, long n, DrError *err)
{
    if (n <= L->cap) return DR_OK;
    long cap = n + n / 4 + 1024;
    DR_TRY(dr_realloc((size_t)cap * 3, sizeof(double), &L->st.x, err));
    DR_TRY(dr_realloc((size_t)cap * 3, sizeof(double), &L->st.v, err));
    DR_TRY(dr_realloc((size_t)cap * 9, sizeof(double), &L->st.c, err));
    DR_TRY(dr_realloc((size_t)cap * 3, sizeof(double), &L->sx, err));
    DR_TRY(dr_realloc((size_t)cap * 3, sizeof(double), &L->sv, err));
    DR_TRY(dr_realloc((size_t)cap * 9, sizeof(double), &L->sc, err));
    L->cap = cap;
    return DR_OK;
}

static DrStatus add_particle(DrLiquid *L, DrVec3 x, DrVec3 v, DrError *err)
{
    DR_TRY(reserve_particles(L, L->st.n + 1, err));
    long p = L->st.n++;
    L->st.x[3 * p] = x.x; L->st.x[3 * p + 1] = x.y; L->st.x[3 * p + 2] = x.z;
    L->st.v[3 * p] = v.x; L->st.v[3 * p + 1] = v.y; L->st.v[3 * p + 2] = v.z;
    memset(L->st.c + 9 * p, 0, 9 * sizeof(double));
    return DR_OK;
}

/* Sub-cell lattice of seeding: k³ sub-cells when per_cell is a cube, else 0 (random positions). */
static int seed_lattice(int per_cell)
{
    for (int k = 1; k * k * k <= per_cell; k++)
        if (k * k * k == per_cell) return k;
    return 0;
}

static bool inside_colliders(const DrColliderFrame *fr, int nfr, DrVec3 x)
{
    for (int c = 0; c < nfr; c++)
        if (dr_collider_frame_phi(&fr[c], x, NULL) < 0.0) return true;
    return false;
}

/* Seeds per_cell candidates in cell (i,j,k); `accept` decides and gives the velocity. Always draws the
   same number of random numbers per candidate so the stream does not depend on acceptance. */
typedef bool (*AcceptFn)(const DrLiquid *L, DrVec3 x, DrVec3 *v, const void *ctx);

static DrStatus seed_cell(DrLiquid *L, int i, int j, int k, AcceptFn accept, const void *actx,
                          const DrColliderFrame *fr, int nfr, uint64_t skip, long *added, DrError *err)
{
    const DrMacGrid *g = L->g;
    int per = L->d.per_cell, m = seed_lattice(per);
    DrVec3 lo = dr_v3(g->origin.x + i * g->dx, g->origin.y + j * g->dx, g->origin.z + k * g->dx);
    for (int s = 0; s < per; s++) {
        double r[3] = {dr_rng_uniform(&L->rng), dr_rng_uniform(&L->rng), dr_rng_uniform(&L->rng)};
        double sub[3];
        if (m > 0) {
            int si = s % m, sj = (s / m) % m, sk = s / (m * m);
            double h = 1.0 / m;
            sub[0] = (si + 0.5 + L->d.jitter * (r[0] - 0.5)) * h;
            sub[1] = (sj + 0.5 + L->d.jitter * (r[1] - 0.5)) * h;
            sub[2] = (sk + 0.5 + L->d.jitter * (r[2] - 0.5)) * h;
        } else {
            for (int d = 0; d < 3; d++) sub[d] = 0.5 + L->d.jitter * (r[d] - 0.5);
        }
        DrVec3 x = dr_v3(lo.x + sub[0] * g->dx, lo.y + sub[1] * g->dx, lo.z + sub[2] * g->dx);
        DrVec3 v;
        if ((skip >> s) & 1u) continue;
        if (!accept(L, x, &v, actx)) continue;
        if (inside_colliders(fr, nfr, x)) continue;
        DR_TRY(add_particle(L, x, v, err));
        if (added) (*added)++;
    }
    return DR_OK;
}

static bool in_box(DrVec3 x, DrVec3 lo, DrVec3 hi)
{
    return x.x >= lo.x && x.x < hi.x && x.y >= lo.y && x.y < hi.y && x.z >= lo.z && x.z < hi.z;
}

typedef struct SourceCtx { const DrColliderFrame *shapes; } SourceCtx;

static bool accept_source(const DrLiquid *L, DrVec3 x, DrVec3 *v, const void *vctx)
{
    const SourceCtx *ctx = vctx;
    for (int b = 0; b < L->d.nsource_boxes; b++)
        if (in_box(x, L->d.source_boxes[b].lo, L->d.source_boxes[b].hi)) {
            *v = L->d.source_boxes[b].velocity;
            return true;
        }
    for (int s = 0; s < L->d.nsource_shapes; s++)
        if (dr_collider_frame_phi(&ctx->shapes[s], x, NULL) < 0.0) {
            *v = L->d.source_shape_velocity ? L->d.source_shape_velocity[s] : dr_v3(0, 0, 0);
            return true;
        }
    return false;
}

static bool accept_box(const DrLiquid *L, DrVec3 x, DrVec3 *v, const void *vctx)
{
    (void)L;
    const DrBoxVel *b = vctx;
    *v = b->velocity;
    return in_box(x, b->lo, b->hi);
}

static bool boxes_overlap(DrVec3 alo, DrVec3 ahi, DrVec3 blo, DrVec3 bhi)
{
    return alo.x < bhi.x && blo.x < ahi.x && alo.y < bhi.y && blo.y < ahi.y && alo.z < bhi.z && blo.z < ahi.z;
}

/* ---- create / destroy ------------------------------------------------------------------------- */

static DrStatus check_desc(const DrLiquidDesc *d, int ncolliders, DrError *err)
{
#define BAD(...) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, __VA_ARGS__)
    if (!(d->dx > 0.0) || !isfinite(d->dx)) BAD("liquid dx must be positive (got %g).", d->dx);
    if (!dr_v3_isfinite(d->domain_lo) || !dr_v3_isfinite(d->domain_hi) || !(d->domain_hi.x > d->domain_lo.x) ||
        !(d->domain_hi.y > d->domain_lo.y) || !(d->domain_hi.z > d->domain_lo.z))
        BAD("liquid domain must be a non-empty box (domain_hi > domain_lo on every axis).");
    for (int a = 0; a < 3; a++)
        if ((dr_v3_get(d->domain_hi, a) - dr_v3_get(d->domain_lo, a)) / d->dx > 4096.0)
            BAD("liquid domain spans more than 4096 cells along axis %d; use a larger dx.", a);
    if (!(d->density > 0.0) || !isfinite(d->density)) BAD("liquid density must be positive (got %g).", d->density);
    if (!(d->viscosity >= 0.0) || !isfinite(d->viscosity)) BAD("liquid viscosity must be >= 0 (got %g).", d->viscosity);
    if (d->scheme != DR_TRANSFER_APIC && d->scheme != DR_TRANSFER_FLIP && d->scheme != DR_TRANSFER_PIC)
        BAD("liquid transfer scheme %d is unknown (apic, flip, pic).", (int)d->scheme);
    if (!(d->flip_blend >= 0.0 && d->flip_blend <= 1.0)) BAD("liquid flip_blend must be in [0, 1] (got %g).", d->flip_blend);
    if (d->per_cell < 1 || d->per_cell > 64) BAD("liquid per_cell must be in [1, 64] (got %d).", d->per_cell);
    if (!(d->jitter >= 0.0 && d->jitter <= 1.0)) BAD("liquid jitter must be in [0, 1] (got %g).", d->jitter);
    if (!dr_v3_isfinite(d->gravity)) BAD("liquid gravity must be finite.");
    if (!(d->cfl > 0.0) || !isfinite(d->cfl)) BAD("liquid cfl must be positive (got %g).", d->cfl);
    if (d->max_substeps < 1) BAD("liquid max_substeps must be >= 1 (got %d).", d->max_substeps);
    if (!(d->pressure_tol > 0.0 && d->pressure_tol < 1.0)) BAD("liquid pressure_tol must be in (0, 1) (got %g).", d->pressure_tol);
    if (d->pressure != DR_PRESSURE_GHOST_FLUID && d->pressure != DR_PRESSURE_MASS_WEIGHTED)
        BAD("liquid pressure formulation %d is unknown (ghost_fluid, mass_weighted).", (int)d->pressure);
    if (!(d->volume_correction >= 0.0) || !isfinite(d->volume_correction))
        BAD("liquid volume_correction must be >= 0 (got %g).", d->volume_correction);
    if (d->pressure_max_iter < 1) BAD("liquid pressure_max_iter must be >= 1 (got %d).", d->pressure_max_iter);
    if (d->nsource_boxes < 0 || (d->nsource_boxes > 0 && !d->source_boxes)) BAD("liquid source boxes missing.");
    if (d->nsource_shapes < 0 || (d->nsource_shapes > 0 && !d->source_shapes)) BAD("liquid source shapes missing.");
    if (d->nsource_shapes > MAX_COLLIDERS_FRAME) BAD("liquid: at most %d source shapes.", MAX_COLLIDERS_FRAME);
    if (d->nemitters < 0 || (d->nemitters > 0 && !d->emitters)) BAD("liquid emitters missing.");
    if (d->nkill_boxes < 0 || (d->nkill_boxes > 0 && (!d->kill_lo || !d->kill_hi))) BAD("liquid kill boxes missing.");
    if (ncolliders < 0 || ncolliders > MAX_COLLIDERS_FRAME) BAD("liquid: between 0 and %d colliders.", MAX_COLLIDERS_FRAME);
#undef BAD
    return DR_OK;
}

DrStatus dr_liquid_create(const DrLiquidDesc *desc, const DrCollider *const *colliders, int ncolliders,
                          DrLiquid **out, DrError *err)
{
    *out = NULL;
    DR_TRY(check_desc(desc, ncolliders, err));
    DrLiquid *L = NULL;
    DR_TRY(dr_calloc(1, sizeof *L, &L, err));
    L->d = *desc;
    DrStatus s = DR_OK;
    int n[3];
    for (int a = 0; a < 3; a++) {
        double ext = (dr_v3_get(desc->domain_hi, a) - dr_v3_get(desc->domain_lo, a)) / desc->dx;
        n[a] = (int)ceil(ext - 1e-9);
        if (n[a] < 1) n[a] = 1;
    }
    s = dr_mac_grid_create(n[0], n[1], n[2], desc->dx, desc->domain_lo, &L->g, err);
    if (s < 0) goto fail;
    /* the domain is the grid box: particles are clamped into it */
    L->d.domain_hi = dr_v3_add(desc->domain_lo, dr_v3(n[0] * desc->dx, n[1] * desc->dx, n[2] * desc->dx));
    L->ncells = (long)n[0] * n[1] * n[2];
    L->nnodes = (long)(n[0] + 1) * (n[1] + 1) * (n[2] + 1);
    for (int a = 0; a < 3; a++) {
        size_t nf = (size_t)L->g->nfaces[a];
        if ((s = dr_calloc(nf, sizeof(double), &L->fm[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(double), &L->uold[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(double), &L->wgt[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(double), &L->us[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(double), &L->tmp[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(double), &L->tmp2[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->valid[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->valid2[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->valid3[a], err)) < 0) goto fail;
    }
    if ((s = dr_calloc((size_t)L->nnodes, sizeof(double), &L->nphi, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->cphi, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->dens, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->div_target, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(int), &L->row, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(long), &L->cells_of_row, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->rhs, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->q, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells * 4, sizeof(double), &L->work, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)(n[2] + 1) * 4, sizeof(double), &L->impulse_partial, err)) < 0) goto fail;
    if (L->ncells * 7 > 2147483647L) {
        s = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid grid too large for the pressure matrix; use a larger dx.");
        goto fail;
    }
    if ((s = dr_csr_create((int)L->ncells, (int)(L->ncells * 7), &L->A, err)) < 0) goto fail;
    if (desc->nemitters > 0) {
        if ((s = dr_calloc((size_t)desc->nemitters, sizeof(DrBoxVel), &L->emitters, err)) < 0) goto fail;
        memcpy(L->emitters, desc->emitters, (size_t)desc->nemitters * sizeof(DrBoxVel));
    }
    if (desc->nkill_boxes > 0) {
        if ((s = dr_calloc((size_t)desc->nkill_boxes, sizeof(DrVec3), &L->kill_lo, err)) < 0) goto fail;
        if ((s = dr_calloc((size_t)desc->nkill_boxes, sizeof(DrVec3), &L->kill_hi, err)) < 0) goto fail;
        memcpy(L->kill_lo, desc->kill_lo, (size_t)desc->nkill_boxes * sizeof(DrVec3));
        memcpy(L->kill_hi, desc->kill_hi, (size_t)desc->nkill_boxes * sizeof(DrVec3));
    }
    L->d.emitters = L->emitters; L->d.kill_lo = L->kill_lo; L->d.kill_hi = L->kill_hi;
    L->pmass = desc->density * desc->dx * desc->dx * desc->dx / desc->per_cell;
    L->vol_density = desc->density * desc->dx * desc->dx * desc->dx;
    dr_rng_seed(&L->rng, desc->seed);

    /* seeding at t = 0 */
    {
        DrColliderFrame cf[MAX_COLLIDERS_FRAME], sf[MAX_COLLIDERS_FRAME];
        for (int c = 0; c < ncolliders; c++) cf[c] = dr_collider_frame(colliders[c], 0.0);
        DrVec3 slo = dr_v3(INFINITY, INFINITY, INFINITY), shi = dr_v3(-INFINITY, -INFINITY, -INFINITY);
        for (int b = 0; b < desc->nsource_boxes; b++) {
            slo = dr_v3_min(slo, desc->source_boxes[b].lo);
            shi = dr_v3_max(shi, desc->source_boxes[b].hi);
        }
        for (int c = 0; c < desc->nsource_shapes; c++) {
            sf[c] = dr_collider_frame(desc->source_shapes[c], 0.0);
            DrVec3 lo, hi;
            dr_collider_frame_bounds(&sf[c], &lo, &hi);
            slo = dr_v3_min(slo, lo);
            shi = dr_v3_max(shi, hi);
        }
        SourceCtx sctx = {sf};
        const DrMacGrid *g = L->g;
        for (int k = 0; k < g->nz && s >= 0; k++)
            for (int j = 0; j < g->ny && s >= 0; j++)
                for (int i = 0; i < g->nx && s >= 0; i++) {
                    DrVec3 lo = dr_v3(g->origin.x + i * g->dx, g->origin.y + j * g->dx, g->origin.z + k * g->dx);
                    DrVec3 hi = dr_v3_add(lo, dr_v3(g->dx, g->dx, g->dx));
                    if (!boxes_overlap(lo, hi, slo, shi)) continue;
                    s = seed_cell(L, i, j, k, accept_source, &sctx, cf, ncolliders, 0, NULL, err);
                }
        if (s < 0) goto fail;
    }
    /* the sources are borrowed for this call only */
    L->d.source_boxes = NULL; L->d.source_shapes = NULL; L->d.source_shape_velocity = NULL;
    L->d.nsource_boxes = 0; L->d.nsource_shapes = 0;
    if ((s = dr_bins_create(L->g, L->st.n > 0 ? L->st.n : 1, &L->bins, err)) < 0) goto fail;
    if ((s = reserve_particles(L, 1, err)) < 0) goto fail;
    *out = L;
    return DR_OK;
fail:
    dr_liquid_destroy(&L);
    return s;
}

void dr_liquid_destroy(DrLiquid **liq)
{
    if (!liq || !*liq) return;
    DrLiquid *L = *liq;
    for (int a = 0; a < 3; a++) {
        free(L->fm[a]); free(L->uold[a]); free(L->wgt[a]); free(L->us[a]);
        free(L->tmp[a]); free(L->tmp2[a]); free(L->valid[a]); free(L->valid2[a]); free(L->valid3[a]);
    }
    free(L->nphi); free(L->cphi); free(L->dens); free(L->div_target); free(L->row); free(L->cells_of_row);
    free(L->rhs); free(L->q); free(L->work); free(L->impulse_partial);
    dr_csr_destroy(&L->A);
    dr_mic0_destroy(&L->M);
    dr_bins_destroy(&L->bins);
    dr_mac_grid_destroy(&L->g);
    free(L->st.x); free(L->st.v); free(L->st.c); free(L->sx); free(L->sv); free(L->sc);
    free(L->emitters); free(L->kill_lo); free(L->kill_hi);
    free(L);
    *liq = NULL;
}

const DrLiquidState *dr_liquid_state(const DrLiquid *liq) { return &liq->st; }
DrLiquidState *dr_liquid_state_mut(DrLiquid *liq) { return &liq->st; }
double dr_liquid_particle_mass(const DrLiquid *liq) { return liq->pmass; }
const DrMacGrid *dr_liquid_grid(const DrLiquid *liq) { return liq->g; }
void dr_liquid_rng_state(const DrLiquid *liq, uint64_t out[4]) { memcpy(out, liq->rng.s, sizeof liq->rng.s); }

DrStatus dr_liquid_restore(DrLiquid *liq, long n, const double *x, const double *v, const double *c,
                           const uint64_t rng[4], DrError *err)
{
    if (n < 0 || (n > 0 && (!x || !v || !c)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid restore: %ld particles but missing arrays.", n);
    for (long i = 0; i < 3 * n; i++)
        if (!isfinite(x[i]) || !isfinite(v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid restore: particle %ld is not finite.", i / 3);
    DR_TRY(reserve_particles(liq, n, err));
    memcpy(liq->st.x, x, (size_t)n * 3 * sizeof(double));
    memcpy(liq->st.v, v, (size_t)n * 3 * sizeof(double));
    memcpy(liq->st.c, c, (size_t)n * 9 * sizeof(double));
    liq->st.n = n;
    memcpy(liq->rng.s, rng, sizeof liq->rng.s);
    return DR_OK;
}

void dr_liquid_totals(const DrLiquid *liq, double *mass, DrVec3 *momentum, DrVec3 *angular, double *kinetic)
{
    const DrLiquidState *s = &liq->st;
    if (mass) *mass = liq->pmass * (double)s->n;
    dr_transfer_particle_totals(s->n, s->x, s->v, liq->d.scheme == DR_TRANSFER_APIC ? s->c : NULL, liq->pmass,
                                liq->g->dx, momentum, angular);
    if (kinetic) {
        double ke = 0.0;
        for (long i = 0; i < 3 * s->n; i++) ke += s->v[i] * s->v[i];
        *kinetic = 0.5 * liq->pmass * ke;
    }
}

/* ---- 2. forces ---------------------------------------------------------------------------------- */

typedef struct FaceCtx { DrLiquid *L; int a; double dt; double alpha; } FaceCtx;

static void gravity_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    int a = ctx->a;
    double dg = ctx->dt * dr_v3_get(L->d.gravity, a);
    long per = (long)L->g->fdim[a][0] * L->g->fdim[a][1];
    for (long f = begin * per; f < end * per; f++)
        if (L->fm[a][f] > 0.0) L->g->f[a][f] += dg;
}

/* Explicit ν∇²u (7-point Laplacian per component) among faces holding liquid mass; a neighbour without
   mass (or beyond the domain) counts as the face itself (zero flux). α = νΔt/Δx² ≤ 1/6 makes the update
   a convex combination, hence stable in the max norm. */
static void viscosity_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    const double *u = L->tmp[a], *m = L->fm[a];
    double *out = g->f[a];
    long sx = 1, sy = dim[0], sz = (long)dim[0] * dim[1];
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = i + sy * j + sz * k;
                if (!(m[f] > 0.0)) continue;
                double c = u[f], lap = 0.0;
                long nb[6] = {i > 0 ? f - sx : -1, i < dim[0] - 1 ? f + sx : -1, j > 0 ? f - sy : -1,
                              j < dim[1] - 1 ? f + sy : -1, k > 0 ? f - sz : -1, k < dim[2] - 1 ? f + sz : -1};
                for (int q = 0; q < 6; q++)
                    if (nb[q] >= 0 && m[nb[q]] > 0.0) lap += u[nb[q]] - c;
                out[f] = c + ctx->alpha * lap;
            }
}

/* ---- 3. boundary conditions ---------------------------------------------------------------------- */

typedef struct BcCtx { DrLiquid *L; int a; } BcCtx;

static void node_phi_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int nx1 = g->nx + 1, ny1 = g->ny + 1;
    DrVec3 blo[MAX_COLLIDERS_FRAME], bhi[MAX_COLLIDERS_FRAME];
    for (int c = 0; c < L->nframes; c++) {
        dr_collider_frame_bounds(&L->frames[c], &blo[c], &bhi[c]);
        DrVec3 pad = dr_v3(2 * g->dx, 2 * g->dx, 2 * g->dx);
        blo[c] = dr_v3_sub(blo[c], pad);
        bhi[c] = dr_v3_add(bhi[c], pad);
    }
    for (long k = begin; k < end; k++)
        for (int j = 0; j < ny1; j++)
            for (int i = 0; i < nx1; i++) {
                DrVec3 x = dr_v3(g->origin.x + i * g->dx, g->origin.y + j * g->dx, g->origin.z + k * g->dx);
                double phi = INFINITY;
                for (int c = 0; c < L->nframes; c++) {
                    if (!in_box(x, blo[c], bhi[c])) continue;
                    double p = dr_collider_frame_phi(&L->frames[c], x, NULL);
                    if (p < phi) phi = p;
                }
                L->nphi[i + (long)nx1 * (j + (long)ny1 * k)] = phi;
            }
}

static double node_phi(const DrLiquid *L, int i, int j, int k)
{
    return L->nphi[i + (long)(L->g->nx + 1) * (j + (long)(L->g->ny + 1) * k)];
}

/* Face weights (fraction open) and solid velocities. Domain-boundary faces are walls (weight 0, at rest);
   the others take the open fraction of the collider union from the phi at their four corners. */
static void weight_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a, b = (a + 1) % 3, c = (a + 2) % 3;
    const int *dim = g->fdim[a];
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int ijk[3] = {i, j, (int)k};
                double w = 1.0, vs = 0.0;
                if (ijk[a] == 0 || ijk[a] == dim[a] - 1) {
                    w = 0.0;
                } else if (L->nframes > 0) {
                    int n0[3] = {ijk[0], ijk[1], ijk[2]};
                    double p[4];
                    for (int q = 0; q < 4; q++) {
                        int nn[3] = {n0[0], n0[1], n0[2]};
                        nn[b] += (q == 1 || q == 2);
                        nn[c] += (q >= 2);
                        p[q] = node_phi(L, nn[0], nn[1], nn[2]);
                    }
                    if (p[0] < g->dx || p[1] < g->dx || p[2] < g->dx || p[3] < g->dx) {
                        w = dr_face_fraction_outside(p[0], p[1], p[2], p[3]);
                        if (w < 1.0) {
                            DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                            double best = INFINITY;
                            for (int cc = 0; cc < L->nframes; cc++) {
                                double ph = dr_collider_frame_phi(&L->frames[cc], x, NULL);
                                if (ph < best) {
                                    best = ph;
                                    vs = dr_v3_get(dr_collider_frame_velocity(&L->frames[cc], x), a);
                                }
                            }
                        }
                    }
                }
                L->wgt[a][f] = w;
                L->us[a][f] = vs;
            }
}

/* ---- 4. pressure --------------------------------------------------------------------------------- */

static inline double cell_theta(const DrLiquid *L, long fluid, long air)
{
    double pf = L->cphi[fluid], pa = L->cphi[air];
    double th = pf < 0.0 ? pf / (pf - pa) : 0.0;
    return th < 0.01 ? 0.01 : (th > 1.0 ? 1.0 : th);
}

/* Face index of the low face of cell (i,j,k) along axis a (the high face is +1 along a). */
static inline long low_face(const DrMacGrid *g, int a, int i, int j, int k) { return dr_mac_face_index(g, a, i, j, k); }
static inline long face_stride(const DrMacGrid *g, int a)
{
    return a == 0 ? 1 : (a == 1 ? g->fdim[1][0] : (long)g->fdim[2][0] * g->fdim[2][1]);
}

/* Poisson coefficient of face f relative to the ghost-fluid one, ρ/ρ_f (liquid.h): 1 for the ghost-fluid
   formulation; ρΔx³/m_f for the mass-weighted one, 0 on a face without mass (it takes no pressure
   impulse, so its velocity enters the divergence as a constant). */
static inline double face_inv_density(const DrLiquid *L, int a, long f)
{
    if (L->d.pressure == DR_PRESSURE_GHOST_FLUID) return 1.0;
    double m = L->fm[a][f];
    return m > 0.0 ? L->vol_density / m : 0.0;
}

/* Volume correction (liquid.h): Δx·D for cell c, D = κ·(ρ̃ − 1 − band)/T where the smoothed density ρ̃
   exceeds 1 + band and T is the advance interval (a frame), not the substep: a rate tied to the substep
   would grow as the CFL condition shortens it and speed the flow up further. A q = −Δx²(div u* − D), so
   the row's right-hand side gains Δx·(Δx·D). */
#define VOLUME_BAND 0.04
static double smoothed_density(const DrLiquid *L, long c)
{
    const DrMacGrid *g = L->g;
    int i = (int)(c % g->nx), j = (int)((c / g->nx) % g->ny), k = (int)(c / ((long)g->nx * g->ny));
    double sum = 0.0;
    int n = 0;
    for (int dk = -1; dk <= 1; dk++)
        for (int dj = -1; dj <= 1; dj++)
            for (int di = -1; di <= 1; di++) {
                int ii = i + di, jj = j + dj, kk = k + dk;
                if (ii < 0 || jj < 0 || kk < 0 || ii >= g->nx || jj >= g->ny || kk >= g->nz) continue;
                sum += L->dens[ii + (long)g->nx * (jj + (long)g->ny * kk)];
                n++;
            }
    return sum / n;
}

static inline double volume_target(const DrLiquid *L, long c)
{
    if (L->d.volume_correction <= 0.0) return 0.0;
    double excess = smoothed_density(L, c) - 1.0 - VOLUME_BAND;
    return excess > 0.0 ? L->g->dx * L->d.volume_correction * excess / L->span : 0.0;
}

/* Row r of the pressure matrix (ascending column order: −z, −y, −x, diagonal, +x, +y, +z) and its
   right-hand side −Δx²·div u*. Returns the number of entries. */
static int pressure_row(const DrLiquid *L, int r, int col[7], double val[7], double *rhs_out)
{
    const DrMacGrid *g = L->g;
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    bool gf = L->d.pressure == DR_PRESSURE_GHOST_FLUID;
    long c = L->cells_of_row[r];
    int i = (int)(c % g->nx), j = (int)((c / g->nx) % g->ny), k = (int)(c / cstride[2]);
    int idx[3] = {i, j, k};
    int n[3] = {g->nx, g->ny, g->nz};
    double diag = 0.0, off[6] = {0};
    int offcol[6];
    double rhs = 0.0;
    for (int a = 0; a < 3; a++) {
        long flo = low_face(g, a, i, j, k), fhi = flo + face_stride(g, a);
        /* −Δx·Σ sign (w u + (1 − w) u_solid): the right-hand side of A q = −Δx² div u (q = pΔt/ρ) */
        rhs -= L->wgt[a][fhi] * g->f[a][fhi] + (1.0 - L->wgt[a][fhi]) * L->us[a][fhi];
        rhs += L->wgt[a][flo] * g->f[a][flo] + (1.0 - L->wgt[a][flo]) * L->us[a][flo];
        for (int side = 0; side < 2; side++) {
            long f = side ? fhi : flo;
            double w = L->wgt[a][f];
            int slot = side ? 3 + a : 2 - a; /* -z,-y,-x | +x,+y,+z: ascending cell index */
            offcol[slot] = -1;
            if (w <= 0.0) continue;
            w *= face_inv_density(L, a, f);
            if (w <= 0.0) continue;
            int nbi = idx[a] + (side ? 1 : -1);
            if (nbi < 0 || nbi >= n[a]) continue;
            long nb = c + (side ? cstride[a] : -cstride[a]);
            if (L->row[nb] >= 0) {
                diag += w;
                off[slot] = -w;
                offcol[slot] = L->row[nb];
            } else if (gf) {
                diag += w / cell_theta(L, c, nb); /* ghost fluid: p_air = p_F (1 − 1/θ) */
            } else {
                diag += w; /* mass-weighted: p = 0 at the air cell's centre */
            }
        }
    }
    *rhs_out = (rhs + volume_target(L, c)) * g->dx;
    int cnt = 0;
    for (int q = 0; q < 3; q++)
        if (offcol[q] >= 0) { col[cnt] = offcol[q]; val[cnt++] = off[q]; }
    col[cnt] = r; val[cnt++] = diag;
    for (int q = 3; q < 6; q++)
        if (offcol[q] >= 0) { col[cnt] = offcol[q]; val[cnt++] = off[q]; }
    return cnt;
}

/* Pass 1 (fill = false): rowptr[r + 1] = entry count of row r. Pass 2: rows written at rowptr[r]. */
typedef struct AssembleCtx { DrLiquid *L; DrCsr *A; bool fill; } AssembleCtx;

static void assemble_rows(long begin, long end, void *vctx)
{
    AssembleCtx *ctx = vctx;
    DrCsr *A = ctx->A;
    for (long r = begin; r < end; r++) {
        int col[7];
        double val[7], rhs;
        int cnt = pressure_row(ctx->L, (int)r, col, val, &rhs);
        if (!ctx->fill) {
            A->rowptr[r + 1] = cnt;
            continue;
        }
        int at = A->rowptr[r];
        for (int q = 0; q < cnt; q++) { A->col[at + q] = col[q]; A->val[at + q] = val[q]; }
        ctx->L->rhs[r] = rhs;
        ctx->L->div_target[r] = volume_target(ctx->L, ctx->L->cells_of_row[r]);
    }
}

/* Relative particle density of every cell from the P2G face masses (z-slices in parallel). */
typedef struct DensCtx { DrLiquid *L; double unused; } DensCtx;

static void density_slices(long begin, long end, void *vctx)
{
    DensCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    const long *cs = L->bins->cell_start;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                long c = i + (long)g->nx * (j + (long)g->ny * k);
                double m = 0.0;
                if (cs[c + 1] > cs[c])
                    for (int a = 0; a < 3; a++) {
                        long f = low_face(g, a, i, j, (int)k);
                        m += L->fm[a][f] + L->fm[a][f + face_stride(g, a)];
                    }
                L->dens[c] = m / (6.0 * L->vol_density);
            }
}

static DrStatus pressure_solve(DrLiquid *L, DrLiquidStats *stats, DrError *err)
{
    const DrMacGrid *g = L->g;
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    /* pressure unknowns and the liquid phi (liquid.h: from the particle count of each cell) */
    const long *cs = L->bins->cell_start;
    int nrow = 0;
    bool gf = L->d.pressure == DR_PRESSURE_GHOST_FLUID;
    for (long c = 0; c < L->ncells; c++) {
        long cnt = cs[c + 1] - cs[c];
        double frac = (double)cnt / L->d.per_cell;
        if (frac > 1.0) frac = 1.0;
        L->cphi[c] = (0.5 - frac) * g->dx;
        L->row[c] = -1;
        bool liquid = cnt > 0;
        if (!gf && !liquid) {
            /* mass-weighted: a cell whose six faces all carry mass is constrained too (liquid.h) */
            int i = (int)(c % g->nx), j = (int)((c / g->nx) % g->ny), k = (int)(c / cstride[2]);
            liquid = true;
            for (int a = 0; a < 3 && liquid; a++) {
                long f = low_face(g, a, i, j, k);
                liquid = L->fm[a][f] > 0.0 && L->fm[a][f + face_stride(g, a)] > 0.0;
            }
        }
        if (liquid) {
            int i = (int)(c % g->nx), j = (int)((c / g->nx) % g->ny), k = (int)(c / cstride[2]);
            bool open = false;
            for (int a = 0; a < 3 && !open; a++) {
                long f = low_face(g, a, i, j, k);
                open = L->wgt[a][f] > 0.0 || L->wgt[a][f + face_stride(g, a)] > 0.0;
            }
            if (open) {
                L->row[c] = nrow;
                L->cells_of_row[nrow++] = c;
            }
        }
    }
    stats->liquid_cells = nrow;
    if (nrow == 0) return DR_OK;
    if (L->d.volume_correction > 0.0) {
        DensCtx dctx = {L, 0.0};
        dr_parallel_for(g->nz, 1, density_slices, &dctx);
        for (int r = 0; r < nrow; r++) {
            double rho = smoothed_density(L, L->cells_of_row[r]);
            if (rho > stats->density_max) stats->density_max = rho;
        }
    }
    DR_TRY(dr_csr_reserve(L->A, nrow, nrow * 7, err));
    DrCsr *A = L->A;
    /* rows in parallel: count the entries of each row, prefix-sum the counts (serial, in row order),
       then write the rows; the matrix does not depend on the thread count */
    AssembleCtx actx = {L, A, false};
    long grain = PAR_MIN_ITEMS / 4;
    dr_parallel_for(nrow, grain, assemble_rows, &actx);
    A->rowptr[0] = 0;
    for (int r = 0; r < nrow; r++) A->rowptr[r + 1] += A->rowptr[r];
    actx.fill = true;
    dr_parallel_for(nrow, grain, assemble_rows, &actx);
    A->nnz = A->rowptr[nrow];
    if (!L->M) DR_TRY(dr_mic0_create(A, DR_MIC0_TAU_DEFAULT, DR_MIC0_SIGMA_DEFAULT, &L->M, err));
    else DR_TRY(dr_mic0_update(L->M, A, err));
    memset(L->q, 0, (size_t)nrow * sizeof(double));
    DrLinearOp Aop = dr_csr_op(A), Mop = dr_mic0_op(L->M);
    DrPcgDesc pd;
    dr_pcg_desc_default(&pd);
    pd.rel_tol = L->d.pressure_tol;
    pd.max_iter = L->d.pressure_max_iter;
    DrPcgStats ps;
    DrStatus s = dr_pcg_solve(&Aop, &Mop, L->rhs, L->q, &pd, L->work, &ps, err);
    if (s < 0) return s;
    if (ps.iterations > stats->pressure_iterations_max) stats->pressure_iterations_max = ps.iterations;
    stats->pressure_iterations_total += ps.iterations;
    if (ps.rel_residual > stats->pressure_residual_max) stats->pressure_residual_max = ps.rel_residual;
    if (s == DR_WARN_NOT_CONVERGED) {
        stats->pressure_not_converged++;
        dr_log_warn("liquid: pressure solve stopped at %d iterations with relative residual %.3e (tolerance %.1e)",
                    ps.iterations, ps.rel_residual, L->d.pressure_tol);
    }
    return DR_OK;
}

/* Pressure value seen across face f from cell c (fluid or air; air takes the ghost-fluid value). */
static inline double q_of(const DrLiquid *L, long c, long other)
{
    int r = L->row[c];
    if (r >= 0) return L->q[r];
    int ro = L->row[other];
    if (ro < 0) return 0.0;
    return L->q[ro] * (1.0 - 1.0 / cell_theta(L, other, c));
}

/* Velocity update u −= ∇q on faces next to a fluid cell; marks them valid. Faces with weight 0 take the
   solid velocity. */
static void project_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    int n[3] = {g->nx, g->ny, g->nz};
    double inv = 1.0 / g->dx;
    bool mw = L->d.pressure == DR_PRESSURE_MASS_WEIGHTED;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int ijk[3] = {i, j, (int)k};
                bool has_lo = ijk[a] > 0, has_hi = ijk[a] < n[a];
                long chi = has_hi ? dr_mac_cell_index(g, i, j, (int)k) : -1;
                long clo = has_lo ? (has_hi ? chi - cstride[a] : dr_mac_cell_index(g, i, j, (int)k) - cstride[a]) : -1;
                bool flo = clo >= 0 && L->row[clo] >= 0, fhi = chi >= 0 && L->row[chi] >= 0;
                unsigned char val = 0;
                if (L->wgt[a][f] <= 0.0) {
                    g->f[a][f] = L->us[a][f];
                    val = 1;
                } else if (mw) {
                    /* every face with mass: u −= (ρ/ρ_f) Δq/Δx with q = 0 in air cells (air–air: no change);
                       a massless face next to a fluid cell keeps its velocity (constant in the solve) */
                    if (L->fm[a][f] > 0.0) {
                        double qlo = flo ? L->q[L->row[clo]] : 0.0, qhi = fhi ? L->q[L->row[chi]] : 0.0;
                        g->f[a][f] -= face_inv_density(L, a, f) * (qhi - qlo) * inv;
                        val = 1;
                    } else {
                        val = flo || fhi;
                    }
                } else if (flo || fhi) {
                    double qlo = q_of(L, clo, chi), qhi = q_of(L, chi, clo);
                    g->f[a][f] -= (qhi - qlo) * inv;
                    val = 1;
                }
                L->valid[a][f] = val;
            }
}

/* Mean |div u|·Δx/|u|max over the pressure rows after projection (the discrete divergence the solve
   drives to zero). Parallel: the maximum is exact in any order; the sum goes by DIV_CHUNKS fixed row
   ranges added in order, so it does not depend on the thread count. */
#define DIV_CHUNKS 64
typedef struct DivCtx { const DrLiquid *L; long nrow; double part[DIV_CHUNKS]; double umax[DIV_CHUNKS]; } DivCtx;

static void divergence_chunks(long begin, long end, void *vctx)
{
    DivCtx *ctx = vctx;
    const DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    for (long ch = begin; ch < end; ch++) {
        /* the same chunk covers rows [r0, r1) and a share of every face array for the maximum */
        long r0 = ctx->nrow * ch / DIV_CHUNKS, r1 = ctx->nrow * (ch + 1) / DIV_CHUNKS;
        double umax = 0.0, sum = 0.0;
        for (int a = 0; a < 3; a++) {
            long f0 = g->nfaces[a] * ch / DIV_CHUNKS, f1 = g->nfaces[a] * (ch + 1) / DIV_CHUNKS;
            for (long f = f0; f < f1; f++)
                if (L->valid[a][f] && fabs(g->f[a][f]) > umax) umax = fabs(g->f[a][f]);
        }
        for (long r = r0; r < r1; r++) {
            long c = L->cells_of_row[r];
            int i = (int)(c % g->nx), j = (int)((c / g->nx) % g->ny), k = (int)(c / ((long)g->nx * g->ny));
            double dv = 0.0;
            for (int a = 0; a < 3; a++) {
                long flo = low_face(g, a, i, j, k), fhi = flo + face_stride(g, a);
                dv += L->wgt[a][fhi] * g->f[a][fhi] + (1.0 - L->wgt[a][fhi]) * L->us[a][fhi];
                dv -= L->wgt[a][flo] * g->f[a][flo] + (1.0 - L->wgt[a][flo]) * L->us[a][flo];
            }
            sum += fabs(dv - L->div_target[r]);
        }
        ctx->part[ch] = sum;
        ctx->umax[ch] = umax;
    }
}

static double divergence_mean(const DrLiquid *L, long nrow)
{
    DivCtx ctx;
    ctx.L = L;
    ctx.nrow = nrow;
    const DrMacGrid *g = L->g;
    long work = nrow + g->nfaces[0] + g->nfaces[1] + g->nfaces[2];
    dr_parallel_for(DIV_CHUNKS, work >= 4 * PAR_MIN_ITEMS ? 1 : DIV_CHUNKS, divergence_chunks, &ctx);
    double umax = 0.0, sum = 0.0;
    for (int ch = 0; ch < DIV_CHUNKS; ch++) {
        sum += ctx.part[ch];
        if (ctx.umax[ch] > umax) umax = ctx.umax[ch];
    }
    return (nrow > 0 && umax > 0.0) ? sum / (double)nrow / umax : 0.0;
}

/* ---- 5. extrapolation of the grid change ---------------------------------------------------------- */

/* Faces not updated by the projection keep their P2G velocity plus the change (forces + pressure)
   averaged from valid neighbours, layer by layer. Extrapolating the change rather than the velocity
   leaves a P2G field that needed no correction untouched (an APIC affine field stays exact) while air
   faces next to the surface feel the same gravity and pressure as the liquid beside them. */
typedef struct ExtrapCtx { DrLiquid *L; int a; const double *din; double *dout;
                           const unsigned char *vin; unsigned char *vout; } ExtrapCtx;

static void extrap_slices(long begin, long end, void *vctx)
{
    ExtrapCtx *ctx = vctx;
    const DrMacGrid *g = ctx->L->g;
    const int *dim = g->fdim[ctx->a];
    long sy = dim[0], sz = (long)dim[0] * dim[1];
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = i + sy * j + sz * k;
                if (ctx->vin[f]) { ctx->dout[f] = ctx->din[f]; ctx->vout[f] = 1; continue; }
                long nb[6] = {i > 0 ? f - 1 : -1, i < dim[0] - 1 ? f + 1 : -1, j > 0 ? f - sy : -1,
                              j < dim[1] - 1 ? f + sy : -1, k > 0 ? f - sz : -1, k < dim[2] - 1 ? f + sz : -1};
                double sum = 0.0;
                int cnt = 0;
                for (int q = 0; q < 6; q++)
                    if (nb[q] >= 0 && ctx->vin[nb[q]]) { sum += ctx->din[nb[q]]; cnt++; }
                ctx->dout[f] = cnt ? sum / cnt : 0.0;
                ctx->vout[f] = cnt > 0;
            }
}

static void extrapolate(DrLiquid *L)
{
    DrMacGrid *g = L->g;
    for (int a = 0; a < 3; a++) {
        long nf = g->nfaces[a];
        double *d0 = L->tmp[a], *d1 = L->tmp2[a];
        unsigned char *v0 = L->valid2[a], *v1 = L->valid3[a];
        memcpy(v0, L->valid[a], (size_t)nf);
        for (long f = 0; f < nf; f++) d0[f] = v0[f] ? g->f[a][f] - L->uold[a][f] : 0.0;
        for (int layer = 0; layer < EXTRAP_LAYERS; layer++) {
            ExtrapCtx ctx = {L, a, d0, d1, v0, v1};
            dr_parallel_for(g->fdim[a][2], slice_grain(g, a), extrap_slices, &ctx);
            double *td = d0; d0 = d1; d1 = td;
            unsigned char *tv = v0; v0 = v1; v1 = tv;
        }
        for (long f = 0; f < nf; f++)
            if (!L->valid[a][f]) g->f[a][f] = L->uold[a][f] + d0[f];
    }
}

/* ---- 6. collider velocity constraint ---------------------------------------------------------------- */

/* Full velocity at face (a; i,j,k): its own component plus the other two averaged from the four
   surrounding faces of each (read from the copy in tmp). */
static DrVec3 face_full_velocity(const DrLiquid *L, int a, int i, int j, int k)
{
    const DrMacGrid *g = L->g;
    double comp[3];
    int ijk[3] = {i, j, k};
    comp[a] = L->tmp[a][dr_mac_face_index(g, a, i, j, k)];
    for (int b = 0; b < 3; b++) {
        if (b == a) continue;
        /* faces of component b around face a: shift −1/0 along a, 0/+1 along b */
        double s = 0.0;
        int cnt = 0;
        for (int da = -1; da <= 0; da++)
            for (int db = 0; db <= 1; db++) {
                int q[3] = {ijk[0], ijk[1], ijk[2]};
                q[a] += da;
                q[b] += db;
                if (q[0] < 0 || q[1] < 0 || q[2] < 0 || q[0] >= g->fdim[b][0] || q[1] >= g->fdim[b][1] ||
                    q[2] >= g->fdim[b][2])
                    continue;
                s += L->tmp[b][dr_mac_face_index(g, b, q[0], q[1], q[2])];
                cnt++;
            }
        comp[b] = cnt ? s / cnt : 0.0;
    }
    return dr_v3(comp[0], comp[1], comp[2]);
}

static void collider_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    DrMacGrid *g = L->g;
    int a = ctx->a, b = (a + 1) % 3, c = (a + 2) % 3;
    const int *dim = g->fdim[a];
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                if (!(L->fm[a][f] > 0.0)) continue;
                int ijk[3] = {i, j, (int)k};
                if (ijk[a] == 0 || ijk[a] == dim[a] - 1) continue;
                double pmin = INFINITY;
                for (int q = 0; q < 4; q++) {
                    int nn[3] = {ijk[0], ijk[1], ijk[2]};
                    nn[b] += (q == 1 || q == 2);
                    nn[c] += (q >= 2);
                    double p = node_phi(L, nn[0], nn[1], nn[2]);
                    if (p < pmin) pmin = p;
                }
                if (!(pmin < g->dx)) continue;
                DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                int best = -1;
                double phi = INFINITY;
                DrVec3 n = dr_v3(0, 0, 0);
                for (int cc = 0; cc < L->nframes; cc++) {
                    DrVec3 gr;
                    double p = dr_collider_frame_phi(&L->frames[cc], x, &gr);
                    if (p < phi) { phi = p; best = cc; n = gr; }
                }
                if (best < 0 || phi >= 0.5 * g->dx) continue;
                const DrColliderFrame *fr = &L->frames[best];
                DrVec3 vs = dr_collider_frame_velocity(fr, x);
                DrVec3 vrel = dr_v3_sub(face_full_velocity(L, a, i, j, (int)k), vs);
                DrVec3 out;
                if (dr_collider_no_slip(fr->c)) {
                    out = vs;
                } else {
                    double vn = dr_v3_dot(vrel, n);
                    if (vn >= 0.0) continue; /* separating: free */
                    DrVec3 vt = dr_v3_sub(vrel, dr_v3_scale(n, vn));
                    double vtn = dr_v3_norm(vt);
                    double red = dr_collider_friction(fr->c) * (-vn); /* Coulomb: |Δv_t| ≤ μ|Δv_n| */
                    double scale = vtn > red ? (vtn - red) / vtn : 0.0;
                    out = dr_v3_add(vs, dr_v3_scale(vt, scale));
                }
                g->f[a][f] = dr_v3_get(out, a);
            }
}

/* ---- diagnostics -------------------------------------------------------------------------------- */

/* Grid impulse of the grid phases (liquid.h): Σ_f m_f (u_f − u_f^P2G) e_a and its moment x_f × about the
   origin. Summing the change directly (rather than differencing two totals) keeps the round-off at the
   size of the impulse. Parallel over z-slices of faces; the slice partials are added in slice order, so
   the result does not depend on the thread count. */
typedef struct ImpulseCtx { const DrLiquid *L; int a; double *partial; } ImpulseCtx;

static void impulse_slices(long begin, long end, void *vctx)
{
    ImpulseCtx *ctx = vctx;
    const DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    const double *m = L->fm[a], *u = g->f[a], *u0 = L->uold[a];
    for (long k = begin; k < end; k++) {
        double P = 0.0, Lx = 0.0, Ly = 0.0, Lz = 0.0;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                if (m[f] == 0.0) continue;
                double mu = m[f] * (u[f] - u0[f]);
                DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                DrVec3 e = dr_v3(a == 0 ? mu : 0, a == 1 ? mu : 0, a == 2 ? mu : 0);
                DrVec3 t = dr_v3_cross(x, e);
                P += mu;
                Lx += t.x; Ly += t.y; Lz += t.z;
            }
        double *out = ctx->partial + 4 * k;
        out[0] = P; out[1] = Lx; out[2] = Ly; out[3] = Lz;
    }
}

static void grid_impulse(DrLiquid *L, DrLiquidStats *stats)
{
    const DrMacGrid *g = L->g;
    for (int a = 0; a < 3; a++) {
        ImpulseCtx ctx = {L, a, L->impulse_partial};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), impulse_slices, &ctx);
        double P = 0.0;
        DrVec3 Lm = dr_v3(0, 0, 0);
        for (int k = 0; k < g->fdim[a][2]; k++) {
            const double *p = L->impulse_partial + 4 * k;
            P += p[0];
            Lm = dr_v3_add(Lm, dr_v3(p[1], p[2], p[3]));
        }
        double *lin = a == 0 ? &stats->grid_linear_impulse.x : (a == 1 ? &stats->grid_linear_impulse.y
                                                                         : &stats->grid_linear_impulse.z);
        *lin += P;
        stats->grid_angular_impulse = dr_v3_add(stats->grid_angular_impulse, Lm);
    }
}

/* ---- 9. particles: advection, push-out, clamp -------------------------------------------------------- */

typedef struct AdvCtx { DrLiquid *L; double dt; double *partial_max; long nchunks; } AdvCtx;

static void advect_range(long begin, long end, void *vctx)
{
    AdvCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    double *x = L->st.x, *v = L->st.v;
    const double dt = ctx->dt, eps = 1e-3 * L->g->dx;
    DrVec3 lo = L->d.domain_lo, hi = L->d.domain_hi;
    double margin = 1e-6 * L->g->dx;
    for (long p = begin; p < end; p++) {
        DrVec3 xp = dr_v3(x[3 * p] + dt * v[3 * p], x[3 * p + 1] + dt * v[3 * p + 1], x[3 * p + 2] + dt * v[3 * p + 2]);
        DrVec3 vp = dr_v3(v[3 * p], v[3 * p + 1], v[3 * p + 2]);
        xp = dr_v3(fmin(fmax(xp.x, lo.x + margin), hi.x - margin), fmin(fmax(xp.y, lo.y + margin), hi.y - margin),
                   fmin(fmax(xp.z, lo.z + margin), hi.z - margin));
        for (int c = 0; c < L->nframes; c++) {
            const DrColliderFrame *fr = &L->frames[c];
            for (int it = 0; it < 24; it++) {
                DrVec3 n;
                double phi = dr_collider_frame_phi(fr, xp, &n);
                if (phi >= 0.0) break;
                /* remove the inward relative velocity, then push out along ∇φ a little beyond the surface;
                   components of ∇φ that point out of the domain at a wall the particle touches are dropped
                   (a collider standing on the floor pushes sideways or up, never through the wall) */
                DrVec3 vs = dr_collider_frame_velocity(fr, xp);
                double vn = dr_v3_dot(dr_v3_sub(vp, vs), n);
                if (vn < 0.0) vp = dr_v3_sub(vp, dr_v3_scale(n, vn));
                double gd[3] = {n.x, n.y, n.z};
                for (int d = 0; d < 3; d++) {
                    double xd = dr_v3_get(xp, d);
                    if ((gd[d] < 0.0 && xd <= dr_v3_get(lo, d) + 2.0 * margin) ||
                        (gd[d] > 0.0 && xd >= dr_v3_get(hi, d) - 2.0 * margin))
                        gd[d] = 0.0;
                }
                DrVec3 gt = dr_v3(gd[0], gd[1], gd[2]);
                double len = dr_v3_norm(gt);
                if (len < 0.5) {
                    /* the way out is mostly through a wall: take the open axis direction along which φ
                       grows most over one cell */
                    double best = -INFINITY;
                    for (int q = 0; q < 6; q++) {
                        int d = q / 2;
                        double sg = (q & 1) ? 1.0 : -1.0;
                        double xd = dr_v3_get(xp, d);
                        if ((sg < 0 && xd <= dr_v3_get(lo, d) + 2.0 * margin) || (sg > 0 && xd >= dr_v3_get(hi, d) - 2.0 * margin))
                            continue;
                        DrVec3 dir = dr_v3(d == 0 ? sg : 0, d == 1 ? sg : 0, d == 2 ? sg : 0);
                        double ph = dr_collider_frame_phi(fr, dr_v3_add(xp, dr_v3_scale(dir, L->g->dx)), NULL);
                        if (ph > best) { best = ph; gt = dir; }
                    }
                    len = 1.0;
                }
                /* a Newton step on φ; where the interpolated field is flatter than a true distance (edges,
                   corners) it falls short, so the step doubles every fourth try */
                double mult = (double)(1 << (it / 4));
                xp = dr_v3_add(xp, dr_v3_scale(gt, mult * (-phi + eps) / (len * len)));
                xp = dr_v3(fmin(fmax(xp.x, lo.x + margin), hi.x - margin), fmin(fmax(xp.y, lo.y + margin), hi.y - margin),
                           fmin(fmax(xp.z, lo.z + margin), hi.z - margin));
            }
        }
        x[3 * p] = xp.x; x[3 * p + 1] = xp.y; x[3 * p + 2] = xp.z;
        v[3 * p] = vp.x; v[3 * p + 1] = vp.y; v[3 * p + 2] = vp.z;
    }
}

/* CFL speed per particle ([APIC] §4.3): |v_p| + (6√3/Δx)‖B_p‖_F with B_p = C_p Δx²/4. */
typedef struct SpeedCtx { const DrLiquid *L; double *partial; long nchunks; } SpeedCtx;

static void speed_chunks(long begin, long end, void *vctx)
{
    SpeedCtx *ctx = vctx;
    const DrLiquid *L = ctx->L;
    long n = L->st.n;
    double k = 6.0 * sqrt(3.0) / L->g->dx * 0.25 * L->g->dx * L->g->dx;
    bool apic = L->d.scheme == DR_TRANSFER_APIC;
    for (long ch = begin; ch < end; ch++) {
        long b = n * ch / ctx->nchunks, e = n * (ch + 1) / ctx->nchunks;
        double mx = 0.0;
        for (long p = b; p < e; p++) {
            const double *v = L->st.v + 3 * p;
            double s = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            if (apic) {
                const double *c = L->st.c + 9 * p;
                double cf = 0.0;
                for (int q = 0; q < 9; q++) cf += c[q] * c[q];
                s += k * sqrt(cf);
            }
            if (!(s <= mx)) mx = s; /* NaN propagates */
        }
        ctx->partial[ch] = mx;
    }
}

static double max_particle_speed(const DrLiquid *L)
{
    enum { NCH = 64 };
    double partial[NCH];
    SpeedCtx ctx = {L, partial, NCH};
    dr_parallel_for(NCH, L->st.n >= 4 * PAR_MIN_ITEMS ? 1 : NCH, speed_chunks, &ctx);
    double mx = 0.0;
    for (int c = 0; c < NCH; c++)
        if (!(partial[c] <= mx)) mx = partial[c];
    return mx;
}

/* ---- 10. emitters and kill boxes ------------------------------------------------------------------- */

static DrStatus emit(DrLiquid *L, double t, DrLiquidStats *stats, DrError *err)
{
    bool any = false;
    for (int e = 0; e < L->d.nemitters; e++)
        if (t >= L->emitters[e].start && t < L->emitters[e].end) any = true;
    if (!any) return DR_OK;
    DR_TRY(dr_bins_build(L->g, L->st.n, L->st.x, L->bins, err));
    const DrMacGrid *g = L->g;
    for (int e = 0; e < L->d.nemitters; e++) {
        const DrBoxVel *b = &L->emitters[e];
        if (!(t >= b->start && t < b->end)) continue;
        int lo[3], hi[3];
        for (int d = 0; d < 3; d++) {
            double o = dr_v3_get(g->origin, d);
            int n = d == 0 ? g->nx : (d == 1 ? g->ny : g->nz);
            lo[d] = (int)ceil((dr_v3_get(b->lo, d) - o) / g->dx - 0.5);
            hi[d] = (int)floor((dr_v3_get(b->hi, d) - o) / g->dx - 0.5);
            if (lo[d] < 0) lo[d] = 0;
            if (hi[d] > n - 1) hi[d] = n - 1;
        }
        for (int k = lo[2]; k <= hi[2]; k++)
            for (int j = lo[1]; j <= hi[1]; j++)
                for (int i = lo[0]; i <= hi[0]; i++) {
                    long c = dr_mac_cell_index(g, i, j, k);
                    DrVec3 ctr = dr_mac_cell_center(g, i, j, k);
                    if (!in_box(ctr, b->lo, b->hi)) continue;
                    /* sub-cells already holding a particle are skipped (a lattice of m³ sub-cells);
                       without a lattice the cell must be empty */
                    uint64_t skip = 0;
                    int m = seed_lattice(L->d.per_cell);
                    for (long q = L->bins->cell_start[c]; q < L->bins->cell_start[c + 1]; q++) {
                        if (m == 0) { skip = ~(uint64_t)0; break; }
                        const double *xp = L->st.x + 3 * L->bins->order[q];
                        int sub[3];
                        for (int dd = 0; dd < 3; dd++) {
                            double f = (xp[dd] - dr_v3_get(g->origin, dd)) / g->dx - (dd == 0 ? i : (dd == 1 ? j : k));
                            int si = (int)floor(f * m);
                            sub[dd] = si < 0 ? 0 : (si > m - 1 ? m - 1 : si);
                        }
                        skip |= (uint64_t)1 << (sub[0] + m * (sub[1] + m * sub[2]));
                    }
                    if (m > 0 && skip == ((m * m * m == 64) ? ~(uint64_t)0 : (((uint64_t)1 << (m * m * m)) - 1))) continue;
                    DrBoxVel full = *b;
                    full.lo = dr_v3(-INFINITY, -INFINITY, -INFINITY);
                    full.hi = dr_v3(INFINITY, INFINITY, INFINITY);
                    DR_TRY(seed_cell(L, i, j, k, accept_box, &full, L->frames, L->nframes, skip, &stats->emitted,
                                             err));
                }
    }
    return DR_OK;
}

static void kill(DrLiquid *L, DrLiquidStats *stats)
{
    if (L->d.nkill_boxes == 0) return;
    long w = 0, n = L->st.n;
    for (long p = 0; p < n; p++) {
        DrVec3 x = dr_v3(L->st.x[3 * p], L->st.x[3 * p + 1], L->st.x[3 * p + 2]);
        bool dead = false;
        for (int b = 0; b < L->d.nkill_boxes && !dead; b++) dead = in_box(x, L->kill_lo[b], L->kill_hi[b]);
        if (dead) continue;
        if (w != p) {
            memcpy(L->st.x + 3 * w, L->st.x + 3 * p, 3 * sizeof(double));
            memcpy(L->st.v + 3 * w, L->st.v + 3 * p, 3 * sizeof(double));
            memcpy(L->st.c + 9 * w, L->st.c + 9 * p, 9 * sizeof(double));
        }
        w++;
    }
    stats->killed += n - w;
    L->st.n = w;
}

/* ---- substep ------------------------------------------------------------------------------------ */

/* Particles are kept in the order of their grid cells (the stable counting sort of the bins, so ties
   keep their previous order): P2G then reads them sequentially and G2P, parallel over particle ranges,
   touches the grid slab by slab. The new order depends only on the current positions and order, so a
   run stays bit-identical for a given thread count and a restored checkpoint continues identically. */
typedef struct SortCtx { DrLiquid *L; } SortCtx;

static void sort_range(long begin, long end, void *vctx)
{
    DrLiquid *L = ((SortCtx *)vctx)->L;
    long *order = L->bins->order;
    for (long q = begin; q < end; q++) {
        long p = order[q];
        memcpy(L->sx + 3 * q, L->st.x + 3 * p, 3 * sizeof(double));
        memcpy(L->sv + 3 * q, L->st.v + 3 * p, 3 * sizeof(double));
        memcpy(L->sc + 9 * q, L->st.c + 9 * p, 9 * sizeof(double));
        order[q] = q;
    }
}

static void sort_particles(DrLiquid *L)
{
    SortCtx ctx = {L};
    dr_parallel_for(L->st.n, PAR_MIN_ITEMS, sort_range, &ctx);
    double *t;
    t = L->st.x; L->st.x = L->sx; L->sx = t;
    t = L->st.v; L->st.v = L->sv; L->sv = t;
    t = L->st.c; L->st.c = L->sc; L->sc = t;
}

static void run_faces(DrLiquid *L, DrRangeFn fn, int a)
{
    BcCtx ctx = {L, a};
    dr_parallel_for(L->g->fdim[a][2], slice_grain(L->g, a), fn, &ctx);
}

static DrStatus substep(DrLiquid *L, double t, double dt, bool visc_clamped, DrLiquidStats *stats, DrError *err)
{
    DrMacGrid *g = L->g;
    DrLiquidState *s = &L->st;
    bool apic = L->d.scheme == DR_TRANSFER_APIC;
    double t_0 = dr_time_now();
    for (int c = 0; c < L->nframes; c++) L->frames[c] = dr_collider_frame(L->frames[c].c, t + dt);

    /* 1. P2G */
    DR_TRY(dr_bins_build(g, s->n, s->x, L->bins, err));
    sort_particles(L);
    dr_transfer_p2g_mac(L->bins, s->x, s->v, apic ? s->c : NULL, L->pmass, L->d.wall_no_slip, g, L->fm);
    for (int a = 0; a < 3; a++) memcpy(L->uold[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
    double t_1 = dr_time_now();
    stats->seconds_p2g += t_1 - t_0;

    /* 2. forces: gravity, then explicit viscosity within its stability limit */
    for (int a = 0; a < 3; a++) {
        FaceCtx fc = {L, a, dt, 0.0};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), gravity_slices, &fc);
    }
    double nu = L->d.viscosity / L->d.density;
    if (nu > 0.0) {
        double alpha = nu * dt / (g->dx * g->dx);
        double amax = (1.0 / 6.0) * (1.0 - 1e-9);
        if (alpha > amax) {
            if (!visc_clamped)
                dr_log_debug("liquid: viscosity step clamped to its stability limit (nu*dt/dx^2 = %g)", alpha);
            alpha = amax;
        }
        for (int a = 0; a < 3; a++) {
            memcpy(L->tmp[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
            FaceCtx fc = {L, a, dt, alpha};
            dr_parallel_for(g->fdim[a][2], slice_grain(g, a), viscosity_slices, &fc);
        }
    }

    /* 3. boundary conditions: walls and collider face fractions */
    if (L->nframes > 0) {
        BcCtx ctx = {L, 0};
        dr_parallel_for(g->nz + 1, slice_grain(g, 2), node_phi_slices, &ctx);
    }
    for (int a = 0; a < 3; a++) run_faces(L, weight_slices, a);
    double t_2 = dr_time_now();

    /* 4. pressure projection */
    DR_TRY(pressure_solve(L, stats, err));
    for (int a = 0; a < 3; a++) run_faces(L, project_slices, a);
    stats->divergence_mean = divergence_mean(L, stats->liquid_cells);
    double t_3 = dr_time_now();
    stats->seconds_pressure += t_3 - t_2;

    /* 5. extrapolation; 6. collider velocity constraint; domain walls stay at rest */
    extrapolate(L);
    if (L->nframes > 0) {
        for (int a = 0; a < 3; a++) memcpy(L->tmp[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
        for (int a = 0; a < 3; a++) run_faces(L, collider_slices, a);
    }
    grid_impulse(L, stats);
    double t_4 = dr_time_now();
    stats->seconds_other += (t_2 - t_1) + (t_4 - t_3);

    /* 7. G2P */
    dr_transfer_g2p_mac(g, (const double *const *)L->uold, L->d.scheme, L->d.flip_blend, L->d.wall_no_slip, s->n,
                        s->x, s->v, s->c);
    double t_5 = dr_time_now();
    stats->seconds_g2p += t_5 - t_4;

    /* 8. advection x += Δt v^{n+1} ([APIC] §5.3), push-out, clamp */
    AdvCtx actx = {L, dt, NULL, 0};
    dr_parallel_for(s->n, L->nframes > 0 ? 2048 : PAR_MIN_ITEMS, advect_range, &actx);
    double t_6 = dr_time_now();
    stats->seconds_advect += t_6 - t_5;

    /* 9. emitters, kill boxes */
    DR_TRY(emit(L, t, stats, err));
    kill(L, stats);
    stats->seconds_other += dr_time_now() - t_6;
    stats->substeps++;
    return DR_OK;
}

DrStatus dr_liquid_advance(DrLiquid *liq, const DrCollider *const *colliders, int ncolliders, double t0, double t1,
                           DrLiquidStats *stats, DrError *err)
{
    memset(stats, 0, sizeof *stats);
    if (ncolliders < 0 || ncolliders > MAX_COLLIDERS_FRAME)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid: between 0 and %d colliders.", MAX_COLLIDERS_FRAME);
    if (!(t1 >= t0) || !isfinite(t0) || !isfinite(t1))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid advance: t1 (%g) must not precede t0 (%g).", t1, t0);
    liq->nframes = ncolliders;
    for (int c = 0; c < ncolliders; c++) liq->frames[c] = dr_collider_frame(colliders[c], t0);
    liq->span = t1 > t0 ? t1 - t0 : 1.0;
    const DrMacGrid *g = liq->g;
    double nu = liq->d.viscosity / liq->d.density;
    double gspeed = sqrt(5.0 * g->dx * dr_v3_norm(liq->d.gravity));
    double t = t0;
    bool warned = false;
    while (t < t1) {
        double smax = max_particle_speed(liq);
        if (!isfinite(smax))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "liquid: particle velocities became non-finite at t = %g s; lower cfl or raise "
                                "max_substeps.", t);
        double dt = INFINITY;
        double sp = smax + gspeed;
        if (sp > 0.0) dt = liq->d.cfl * g->dx / sp;
        if (nu > 0.0) dt = fmin(dt, g->dx * g->dx / (6.0 * nu));
        double remaining = t1 - t;
        double nneed = ceil(remaining / dt);
        int left = liq->d.max_substeps - stats->substeps;
        bool clamped = false;
        if (!(nneed <= left)) {
            nneed = left;
            clamped = true;
            if (!warned) {
                dr_log_warn("liquid: the CFL condition needs more than max_substeps = %d substeps in [%g, %g] s; "
                            "clamping (raise max_substeps for accuracy)", liq->d.max_substeps, t0, t1);
                warned = true;
            }
        }
        if (nneed < 1) nneed = 1;
        dt = remaining / nneed;
        bool last = nneed <= 1;
        DR_TRY(substep(liq, t, dt, clamped, stats, err));
        t = last ? t1 : t + dt;
    }
    stats->particles = liq->st.n;
    double vmax = 0.0;
    for (long p = 0; p < liq->st.n; p++) {
        const double *v = liq->st.v + 3 * p;
        double sp = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if (sp > vmax) vmax = sp;
    }
    stats->max_speed = vmax;
    return DR_OK;
}
