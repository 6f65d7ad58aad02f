/* Incompressible liquid: APIC/FLIP/PIC on a MAC grid with a variational, ghost-fluid pressure
 * projection. The phases of a substep follow liquid.h; each is a function below. */
#include "liquid/liquid.h"

#include "linalg/linalg.h"
#include "liquid/viscosity.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

#define MAX_COLLIDERS_FRAME 64
#define EXTRAP_LAYERS 4
/* Per z-slice partials of the grid passes (impulse_partial): momentum, angular momentum (3), largest speed gain
   and the moving solids' pressure work (grid_impulse); largest face speed and the x, y range of faces with mass
   (grid_speed). */
#define IMPULSE_PARTS 6
/* Smallest amount of work (faces, cells or particles) worth a parallel chunk. A parallel region costs a
   fork and a barrier, and when another process holds a core the barrier waits for a descheduled thread
   (up to a scheduler time slice): small grids run their loops serially instead. */
#define PAR_MIN_ITEMS 16384

/* A face coupling a rigid body (dr_liquid_set_bodies): its solid share σ, its row J = (e_a, (x_f − c) × e_a) and the
   pressure rows on its two sides (−1: none). */
typedef struct BodyFace {
    long f;
    int a;
    int lo, hi;
    double sigma;
    double J[6];
} BodyFace;

struct DrLiquid {
    DrLiquidDesc d;          /* copy; pointer fields below are owned copies, sources are cleared */
    DrBoxVel *emitters;
    DrVec3 *kill_lo, *kill_hi;
    DrMacGrid *g;
    long ncells, nnodes;
    double *fm[3];           /* face masses from P2G, kg */
    double *uold[3];         /* face velocities right after P2G */
    DrFaceCoupling own;      /* the colliders' face coupling (weight_slices): open = the fraction of each face
                                open to liquid (variational weights; 0 on domain walls), velocity = the solid
                                velocity (component a) on faces near a collider (0 elsewhere); no impulse */
    DrFaceCoupling mix;      /* own combined with a projection's extra coupling (mix_coupling); open and
                                velocity allocated on first use, no impulse */
    const DrFaceCoupling *cpl; /* the coupling the current projection uses: &own or &mix */
    float *wsol[3];          /* fraction of each face outside every collider (walls ignored) */
    double *ustar[3];        /* face velocities before the projection (dr_liquid_begin), so that a projection
                                can be repeated from them; allocated on first use */
    double *tmp[3], *tmp2[3];
    unsigned char *valid[3], *valid2[3], *valid3[3];
    unsigned char *shut[3];  /* face closed at the solid velocity in this substep's projection (shut_faces) */
    double *nphi;            /* collider union phi at grid nodes (cell corners) */
    double *nphi_static;     /* the same for the static colliders alone (dr_collider_static), kept while the
                                set of static colliders (static_ids) stays the same */
    uint64_t static_ids[MAX_COLLIDERS_FRAME];
    float *dsum[3];          /* summed-volume tables of the uncut cells' phi differences (phi_direction_tables),
                                (nx+1)(ny+1)(nz+1) each; created on first use */
    int nstatic;             /* -1: nphi_static not computed */
    float *open;             /* per cell: fraction of its volume outside every collider, ω ∈ [0, 1] */
    unsigned char *near;     /* per cell: a cell within one cell of it is cut by a collider (ω < 1) */
    /* mass-weighted pressure next to colliders (virtual_mass): the virtual liquid inside the colliders,
       its face masses vfm, and the grid, bins and particle arrays its P2G uses; created on first use */
    DrMacGrid *vg;
    DrParticleBins *vbins;
    double *vfm[3];
    double *vx, *vv;
    long vn, vcap;
    double *cphi;            /* liquid phi at cell centres */
    double *dens;            /* per cell: P2G face masses / (6ρΔx³), 0 in cells without particles */
    double *div_target;      /* per pressure row: Δx·D, the volume-correction divergence target (m/s) */
    double span;             /* duration of the current dr_liquid_advance call (a frame), s */
    int *blocks;             /* particle count per 2×2×2 block of cells (dr_liquid_particle_volume), on first use */
    double *bvol;            /* ... and their volume, when some particle is not nominal, on first use */
    DrViscosity *visc;       /* the implicit viscosity solve and its cells' liquid fractions, on first use */
    float *vfill;
    int *row;                /* cell → pressure unknown, −1 if not a fluid cell */
    long nrow;               /* pressure unknowns of the last projection */
    long *cells_of_row;
    DrCsr *A;
    DrMic0 *M;
    DrMg *mg;                /* the multigrid V-cycle (pressure_precond DR_PRECOND_MULTIGRID), on first use */
    int *row_ijk;            /* 3 per pressure row: its cell (i, j, k), for the multigrid */
    double *rhs, *q, *work;
    double *impulse_partial; /* IMPULSE_PARTS per z-slice of faces: grid-impulse partial sums, speed maxima */
    double accel;            /* a⁺, the largest speed gain per second of a face in the last substep (CFL) */
    bool accel_known;        /* a⁺ has been measured (a substep ran, or a checkpoint restored it) */
    DrParticleBins *bins;
    DrLiquidState st;
    double *sx, *sv, *sc, *svol; /* scratch particle arrays (same capacity) for the sort by cell */
    int64_t *sid;
    double *pscale;          /* per particle: its mass factor vol/V0 in the substep's order (same capacity) */
    bool scaled;             /* the substep's P2G found a particle that is not nominal: the sort moved the volumes and
                                pscale holds the factors (else every volume is V0, the sort leaves them, every factor
                                is 1 and the uniform paths run) */
    bool retransfer;         /* particles were added or removed after dr_liquid_stable_dt: begin transfers again */
    long cap;
    int64_t next_id;         /* the id the next seeded or emitted particle takes */
    DrRng rng;
    double pmass;            /* the nominal particle's mass, density·V0 */
    double vol0;             /* V0 = dx³/per_cell, the nominal particle's volume */
    double vol_density;      /* density·dx³: the face mass of a full face (mass-weighted pressure) */
    DrColliderFrame frames[MAX_COLLIDERS_FRAME];
    int nframes;
    /* the interval of the clock the substeps land on (a frame; dr_liquid_stable_dt) */
    double ival_t0, ival_t1; /* ival_t1 NaN: none open */
    int ival_substeps;       /* substeps ended in it (max_substeps) */
    bool ival_warned;        /* its max_substeps warning was logged */
    /* the open substep */
    int phase;               /* PHASE_* below */
    double t_step, h_step;   /* its start and length (dr_liquid_begin) */
    double h_stable;         /* the length dr_liquid_stable_dt gave */
    bool step_lands;         /* that length ends the interval */
    bool step_clamped;       /* max_substeps clamped it */
    int nproj;               /* projections since dr_liquid_begin */
    bool sample_ok;          /* the grid holds a projection's velocities and pressure (dr_liquid_sample) */
    DrVec3 added;            /* momentum the extra coupling's impulses gave in the last projection, N·s */
    DrVec3 drag_added;       /* ... and its drag masses, β_f (V_f − u_f) with the projected u_f, N·s */
    signed char *owner[3];   /* per face: the index (into frames) of the nearest moving collider, on the faces that
                                take a collider velocity (weight_slices); −1 elsewhere */
    DrLiquidBody *bodies;    /* the rigid participants of the substep (dr_liquid_set_bodies), borrowed */
    int nbodies;
    int frame_body[MAX_COLLIDERS_FRAME]; /* the body each posed collider is, −1 */
    struct BodyFace *bface;  /* the faces coupling the bodies in the projection, body by body (body_faces) */
    long nbface, cap_bface;
    long *bface_start;       /* nbodies + 1 offsets into bface */
    double *bimp[3];         /* per face: the momentum m_f Δu that setting a body's velocity on it gave the liquid
                                (blocked faces, the collider constraint), N s, and the body (bwho, −1: none) */
    signed char *bwho[3];
    double *pdv;             /* per particle: the velocity the push-out out of a body took (3 each), and the body
                                (pwho, −1: none); capacity pcap */
    signed char *pwho;
    long pcap;
    unsigned char *take[3];  /* faces that took the extra coupling's impulse and drag in the last projection */
    double *porous[3];       /* m_f/(m_f + β_f) on faces taking a drag mass, 1 elsewhere (porous_on) */
    bool porous_on;          /* the last projection's extra coupling had a drag mass */
    /* the extra coupling's moving solid (DrFaceCoupling.solid_mass; soft_faces), allocated on first use */
    bool soft_on;            /* the projection in progress has one */
    const DrFaceCoupling *soft; /* that coupling */
    double *smul[3];         /* per face: s_f, the weight of the solid's velocity in the face's flux (0: none) */
    double *sshare[3];       /* per face: the solid's part of the mixed solid velocity, σ_e/(σ_own + σ_e) */
    double *sdp[3];          /* per face: the momentum the solid gained in the last projection, N s */
    DrVec3 soft_gain;        /* Σ sdp of the last projection (face order), N s */
    double pend_p2g, pend_other; /* seconds spent before the stats of dr_liquid_end can take them */
    long pend_visc_iterations;   /* the implicit viscosity solve's figures, likewise */
    int pend_visc_not_converged;
    double pend_visc_seconds;
};

/* The phases of a substep, in order; each public phase function asserts the one before it. */
enum { PHASE_IDLE, PHASE_READY, PHASE_BEGUN, PHASE_PROJECTED };

/* Grain (z-slices per chunk) of a loop over the faces of component a: at least PAR_MIN_ITEMS faces. */
static long slice_grain(const DrMacGrid *g, int a) { return dr_mac_slice_grain(g, a, PAR_MIN_ITEMS); }

/* Face index of the low face of cell (i,j,k) along axis a (the high face is +1 along a). */
static inline long low_face(const DrMacGrid *g, int a, int i, int j, int k) { return dr_mac_face_index(g, a, i, j, k); }
static inline long face_stride(const DrMacGrid *g, int a)
{
    return a == 0 ? 1 : (a == 1 ? g->fdim[1][0] : (long)g->fdim[2][0] * g->fdim[2][1]);
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
    d->pressure_precond = DR_PRECOND_MULTIGRID;
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
    DR_TRY(dr_realloc((size_t)cap, sizeof(double), &L->st.vol, err));
    DR_TRY(dr_realloc((size_t)cap, sizeof(double), &L->svol, err));
    DR_TRY(dr_realloc((size_t)cap, sizeof(double), &L->pscale, err));
    DR_TRY(dr_realloc((size_t)cap, sizeof(int64_t), &L->st.id, err));
    DR_TRY(dr_realloc((size_t)cap, sizeof(int64_t), &L->sid, err));
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
    L->st.vol[p] = L->vol0;
    L->st.id[p] = L->next_id++;
    return DR_OK;
}

/* Particle p's row copied to row w (compaction: w < p). */
static void move_particle(DrLiquid *L, long p, long w)
{
    memcpy(L->st.x + 3 * w, L->st.x + 3 * p, 3 * sizeof(double));
    memcpy(L->st.v + 3 * w, L->st.v + 3 * p, 3 * sizeof(double));
    memcpy(L->st.c + 9 * w, L->st.c + 9 * p, 9 * sizeof(double));
    L->st.vol[w] = L->st.vol[p];
    L->st.id[w] = L->st.id[p];
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
    if (d->pressure_precond != DR_PRECOND_MULTIGRID && d->pressure_precond != DR_PRECOND_MIC0)
        BAD("liquid pressure preconditioner %d is unknown (multigrid, mic0).", (int)d->pressure_precond);
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
        if ((s = dr_calloc(nf, sizeof(double), &L->own.open[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(float), &L->wsol[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->owner[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(double), &L->own.velocity[a], err)) < 0) goto fail;
        L->own.nfaces[a] = L->mix.nfaces[a] = (long)nf;
        if ((s = dr_calloc(nf, sizeof(double), &L->tmp[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, sizeof(double), &L->tmp2[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->valid[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->valid2[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->valid3[a], err)) < 0) goto fail;
        if ((s = dr_calloc(nf, 1, &L->shut[a], err)) < 0) goto fail;
    }
    if ((s = dr_calloc((size_t)L->nnodes, sizeof(double), &L->nphi, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->nnodes, sizeof(double), &L->nphi_static, err)) < 0) goto fail;
    L->nstatic = -1;
    L->cpl = &L->own;
    L->ival_t0 = L->ival_t1 = NAN;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->cphi, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(float), &L->open, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, 1, &L->near, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->dens, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->div_target, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(int), &L->row, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(long), &L->cells_of_row, err)) < 0) goto fail;
    if (L->d.pressure_precond == DR_PRECOND_MULTIGRID &&
        (s = dr_calloc((size_t)L->ncells * 3, sizeof(int), &L->row_ijk, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->rhs, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells, sizeof(double), &L->q, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)L->ncells * 4, sizeof(double), &L->work, err)) < 0) goto fail;
    if ((s = dr_calloc((size_t)(n[2] + 1) * IMPULSE_PARTS, sizeof(double), &L->impulse_partial, err)) < 0) goto fail;
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
    L->vol0 = desc->dx * desc->dx * desc->dx / desc->per_cell;
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
        free(L->fm[a]); free(L->uold[a]); free(L->own.open[a]); free(L->wsol[a]); free(L->own.velocity[a]);
        free(L->owner[a]); free(L->bimp[a]); free(L->bwho[a]);
        free(L->mix.open[a]); free(L->mix.velocity[a]); free(L->ustar[a]);
        free(L->tmp[a]); free(L->tmp2[a]); free(L->valid[a]); free(L->valid2[a]); free(L->valid3[a]); free(L->shut[a]);
        free(L->take[a]); free(L->porous[a]);
        free(L->smul[a]); free(L->sshare[a]); free(L->sdp[a]);
    }
    for (int a = 0; a < 3; a++) free(L->dsum[a]);
    free(L->nphi); free(L->nphi_static); free(L->open); free(L->near); free(L->cphi); free(L->dens);
    free(L->bface); free(L->bface_start); free(L->pdv); free(L->pwho);
    free(L->div_target); free(L->row); free(L->cells_of_row); free(L->blocks); free(L->bvol); free(L->vfill);
    dr_viscosity_destroy(&L->visc);
    free(L->rhs); free(L->q); free(L->work); free(L->impulse_partial);
    dr_csr_destroy(&L->A);
    dr_mic0_destroy(&L->M);
    dr_mg_destroy(&L->mg);
    free(L->row_ijk);
    dr_bins_destroy(&L->bins);
    dr_bins_destroy(&L->vbins);
    dr_mac_grid_destroy(&L->vg);
    for (int a = 0; a < 3; a++) free(L->vfm[a]);
    free(L->vx); free(L->vv);
    dr_mac_grid_destroy(&L->g);
    free(L->st.x); free(L->st.v); free(L->st.c); free(L->sx); free(L->sv); free(L->sc);
    free(L->st.vol); free(L->svol); free(L->pscale);
    free(L->st.id); free(L->sid);
    free(L->emitters); free(L->kill_lo); free(L->kill_hi);
    free(L);
    *liq = NULL;
}

const DrLiquidState *dr_liquid_state(const DrLiquid *liq) { return &liq->st; }
DrLiquidState *dr_liquid_state_mut(DrLiquid *liq) { return &liq->st; }
double dr_liquid_particle_mass(const DrLiquid *liq) { return liq->pmass; }
double dr_liquid_nominal_volume(const DrLiquid *liq) { return liq->vol0; }

/* Every particle carries the nominal volume (the common case, which takes the uniform paths). */
static bool all_nominal(const DrLiquid *L)
{
    const double *vol = L->st.vol;
    for (long p = 0; p < L->st.n; p++)
        if (vol[p] != L->vol0) return false;
    return true;
}

/* Particle p's mass, the nominal one times vol/V0 (exactly the nominal one for a nominal particle: x/x = 1). */
static inline double particle_mass(const DrLiquid *L, long p) { return L->pmass * (L->st.vol[p] / L->vol0); }

/* DR_ERR_INPUT naming the particle unless its volume is finite and > 0. */
static DrStatus check_volume(const char *who, long p, double vol, DrError *err)
{
    if (isfinite(vol) && vol > 0.0) return DR_OK;
    return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid %s: particle %ld has volume %g m^3; a particle's volume "
                        "must be finite and > 0.", who, p, vol);
}
const DrMacGrid *dr_liquid_grid(const DrLiquid *liq) { return liq->g; }
const unsigned char *dr_liquid_coupled_faces(const DrLiquid *liq, int a) { return liq->take[a]; }
const double *dr_liquid_face_mass(const DrLiquid *liq, int a)
{
    assert(a >= 0 && a < 3);
    return liq->fm[a];
}
void dr_liquid_resume_state(const DrLiquid *liq, DrLiquidResume *out)
{
    memcpy(out->rng, liq->rng.s, sizeof liq->rng.s);
    out->cfl_accel = liq->accel;
    out->next_id = liq->next_id;
}

static int cmp_id(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* DR_ERR_INPUT unless the n ids lie in [0, next_id) and no two are equal (checked on a sorted copy in scratch, which
   must hold n). */
static DrStatus check_ids(const int64_t *id, long n, int64_t next_id, int64_t *scratch, DrError *err)
{
    if (n == 0) return DR_OK;
    for (long p = 0; p < n; p++)
        if (id[p] < 0 || id[p] >= next_id)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid restore: particle %ld has id %lld, outside [0, "
                                "%lld) (the next id to give).", p, (long long)id[p], (long long)next_id);
    memcpy(scratch, id, (size_t)n * sizeof *id);
    qsort(scratch, (size_t)n, sizeof *scratch, cmp_id);
    for (long p = 1; p < n; p++)
        if (scratch[p] == scratch[p - 1])
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid restore: two particles have id %lld.",
                                (long long)scratch[p]);
    return DR_OK;
}

DrStatus dr_liquid_restore(DrLiquid *liq, long n, const double *x, const double *v, const double *c,
                           const double *vol, const int64_t *id, const DrLiquidResume *resume, DrError *err)
{
    if (n < 0 || (n > 0 && (!x || !v || !c || !id)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid restore: %ld particles but missing arrays.", n);
    if (!(resume->cfl_accel >= 0.0) || !isfinite(resume->cfl_accel))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid restore: CFL acceleration %g is not a finite "
                            "value >= 0.", resume->cfl_accel);
    for (long i = 0; i < 3 * n; i++)
        if (!isfinite(x[i]) || !isfinite(v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid restore: particle %ld is not finite.", i / 3);
    for (long p = 0; vol && p < n; p++) DR_TRY(check_volume("restore", p, vol[p], err));
    DR_TRY(reserve_particles(liq, n, err));
    DR_TRY(check_ids(id, n, resume->next_id, liq->sid, err));
    memcpy(liq->st.x, x, (size_t)n * 3 * sizeof(double));
    memcpy(liq->st.v, v, (size_t)n * 3 * sizeof(double));
    memcpy(liq->st.c, c, (size_t)n * 9 * sizeof(double));
    if (vol) memcpy(liq->st.vol, vol, (size_t)n * sizeof *vol);
    else
        for (long p = 0; p < n; p++) liq->st.vol[p] = liq->vol0;
    memcpy(liq->st.id, id, (size_t)n * sizeof *id);
    liq->st.n = n;
    liq->next_id = resume->next_id;
    memcpy(liq->rng.s, resume->rng, sizeof liq->rng.s);
    liq->accel = resume->cfl_accel;
    liq->accel_known = true;
    liq->phase = PHASE_IDLE;
    liq->sample_ok = false;
    liq->ival_t0 = liq->ival_t1 = NAN;
    return DR_OK;
}

/* Particles may be added or removed between substeps; between stable_dt and begin, begin transfers them again. */
static void particles_changed(DrLiquid *L)
{
    assert(L->phase == PHASE_IDLE || L->phase == PHASE_READY); /* not within begin/project/end */
    if (L->phase == PHASE_READY) L->retransfer = true;
}

DrStatus dr_liquid_add_particles(DrLiquid *liq, long n, const double *x, const double *v, const double *vol,
                                 DrError *err)
{
    if (n < 0 || (n > 0 && (!x || !v || !vol)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid add_particles: %ld particles but missing arrays.", n);
    static const char axis[3] = {'x', 'y', 'z'};
    for (long p = 0; p < n; p++) {
        for (int d = 0; d < 3; d++) {
            if (!isfinite(x[3 * p + d]))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid add_particles: particle %ld: position %c is "
                                    "%g, not finite.", p, axis[d], x[3 * p + d]);
            if (!isfinite(v[3 * p + d]))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid add_particles: particle %ld: velocity %c is "
                                    "%g, not finite.", p, axis[d], v[3 * p + d]);
            double lo = dr_v3_get(liq->d.domain_lo, d), hi = dr_v3_get(liq->d.domain_hi, d);
            if (!(x[3 * p + d] >= lo && x[3 * p + d] <= hi))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid add_particles: particle %ld: position %c = "
                                    "%g m lies outside the domain box [%g, %g].", p, axis[d], x[3 * p + d], lo, hi);
        }
        DR_TRY(check_volume("add_particles", p, vol[p], err));
    }
    if (n == 0) return DR_OK;
    DR_TRY(reserve_particles(liq, liq->st.n + n, err));
    particles_changed(liq);
    DrLiquidState *s = &liq->st;
    for (long p = 0; p < n; p++) {
        long q = s->n++;
        memcpy(s->x + 3 * q, x + 3 * p, 3 * sizeof(double));
        memcpy(s->v + 3 * q, v + 3 * p, 3 * sizeof(double));
        memset(s->c + 9 * q, 0, 9 * sizeof(double));
        s->vol[q] = vol[p];
        s->id[q] = liq->next_id++;
    }
    return DR_OK;
}

long dr_liquid_remove_empty(DrLiquid *liq)
{
    long w = 0, n = liq->st.n;
    for (long p = 0; p < n; p++) {
        if (liq->st.vol[p] == 0.0) continue;
        if (w != p) move_particle(liq, p, w);
        w++;
    }
    if (w < n) particles_changed(liq);
    liq->st.n = w;
    return n - w;
}

DrStatus dr_liquid_particle_volume(DrLiquid *liq, double *volume, double *nominal, DrError *err)
{
    DrLiquid *L = liq;
    const DrMacGrid *g = L->g;
    int nb[3] = {(g->nx + 1) / 2, (g->ny + 1) / 2, (g->nz + 1) / 2};
    long nblocks = (long)nb[0] * nb[1] * nb[2];
    bool nominal_all = all_nominal(L);
    if (!L->blocks) DR_TRY(dr_calloc((size_t)nblocks, sizeof(int), &L->blocks, err));
    if (!nominal_all && !L->bvol) DR_TRY(dr_calloc((size_t)nblocks, sizeof(double), &L->bvol, err));
    memset(L->blocks, 0, (size_t)nblocks * sizeof(int));
    if (!nominal_all) memset(L->bvol, 0, (size_t)nblocks * sizeof(double));
    for (long p = 0; p < L->st.n; p++) {
        long b = 0, stride = 1;
        for (int a = 0; a < 3; a++) {
            double f = (L->st.x[3 * p + a] - dr_v3_get(g->origin, a)) / (2.0 * g->dx);
            long i = (long)floor(f);
            i = i < 0 ? 0 : (i >= nb[a] ? nb[a] - 1 : i);
            b += i * stride;
            stride *= nb[a];
        }
        L->blocks[b]++;
        if (!nominal_all) L->bvol[b] += L->st.vol[p];
    }
    /* a block holds at most 8 cells of seeded liquid: particles beyond that are liquid squeezed into less space */
    if (!nominal_all) {
        double full = 8.0 * g->dx * g->dx * g->dx, counted = 0.0, sum = 0.0;
        for (long b = 0; b < nblocks; b++) counted += L->bvol[b] < full ? L->bvol[b] : full;
        for (long p = 0; p < L->st.n; p++) sum += L->st.vol[p];
        *volume = counted;
        *nominal = sum;
        return DR_OK;
    }
    long full = 8L * L->d.per_cell, counted = 0;
    for (long b = 0; b < nblocks; b++) counted += L->blocks[b] < full ? L->blocks[b] : full;
    double per = g->dx * g->dx * g->dx / L->d.per_cell;
    *volume = (double)counted * per;
    *nominal = (double)L->st.n * per;
    return DR_OK;
}

void dr_liquid_totals(const DrLiquid *liq, double *mass, DrVec3 *momentum, DrVec3 *angular, double *kinetic)
{
    const DrLiquidState *s = &liq->st;
    const double *c = liq->d.scheme == DR_TRANSFER_APIC ? s->c : NULL;
    if (all_nominal(liq)) {
        if (mass) *mass = liq->pmass * (double)s->n;
        dr_transfer_particle_totals(s->n, s->x, s->v, c, liq->pmass, NULL, liq->g->dx, momentum, angular);
        if (kinetic) {
            double ke = 0.0;
            for (long i = 0; i < 3 * s->n; i++) ke += s->v[i] * s->v[i];
            *kinetic = 0.5 * liq->pmass * ke;
        }
        return;
    }
    /* per-particle masses: the factors vol/V0 a chunk at a time (no scratch of the liquid's: this only reads it), the
       chunks' sums added in order */
    enum { CHUNK = 256 };
    double m = 0.0, ke = 0.0, f[CHUNK];
    DrVec3 P = dr_v3(0, 0, 0), L = dr_v3(0, 0, 0);
    for (long p0 = 0; p0 < s->n; p0 += CHUNK) {
        long k = s->n - p0 < CHUNK ? s->n - p0 : CHUNK;
        for (long q = 0; q < k; q++) {
            const double *v = s->v + 3 * (p0 + q);
            f[q] = s->vol[p0 + q] / liq->vol0;
            m += liq->pmass * f[q];
            ke += liq->pmass * f[q] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        }
        DrVec3 dp, dl;
        dr_transfer_particle_totals(k, s->x + 3 * p0, s->v + 3 * p0, c ? c + 9 * p0 : NULL, liq->pmass, f, liq->g->dx,
                                    &dp, &dl);
        P = dr_v3_add(P, dp);
        L = dr_v3_add(L, dl);
    }
    if (mass) *mass = m;
    if (momentum) *momentum = P;
    if (angular) *angular = L;
    if (kinetic) *kinetic = 0.5 * ke;
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
   a convex combination, hence stable in the max norm. Mass-weighted, each pair of faces f, g exchanges the momentum
   α min(m_f, m_g) (u_g − u_f) (the same where the masses agree, as inside the liquid), so that the faces at the
   surface, whose masses differ, lose to their neighbours exactly what these gain: the liquid's momentum is kept
   (Δu_f = α Σ_g (u_g − u_f) would change it by α Σ_pairs (u_g − u_f)(m_f − m_g)); still a convex combination. */
static void viscosity_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    const double *u = L->tmp[a], *m = L->fm[a];
    double *out = g->f[a];
    bool mw = L->d.pressure == DR_PRESSURE_MASS_WEIGHTED;
    long sx = 1, sy = dim[0], sz = (long)dim[0] * dim[1];
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = i + sy * j + sz * k;
                if (!(m[f] > 0.0)) continue;
                double c = u[f], lap = 0.0;
                long nb[6] = {i > 0 ? f - sx : -1, i < dim[0] - 1 ? f + sx : -1, j > 0 ? f - sy : -1,
                              j < dim[1] - 1 ? f + sy : -1, k > 0 ? f - sz : -1, k < dim[2] - 1 ? f + sz : -1};
                for (int q = 0; q < 6; q++) {
                    if (nb[q] < 0 || !(m[nb[q]] > 0.0)) continue;
                    if (mw && m[nb[q]] < m[f]) lap += (u[nb[q]] - c) * (m[nb[q]] / m[f]);
                    else lap += u[nb[q]] - c;
                }
                out[f] = c + ctx->alpha * lap;
            }
}

/* ---- 3. boundary conditions ---------------------------------------------------------------------- */

typedef struct BcCtx { DrLiquid *L; int a; } BcCtx;

/* Runs fn over the z-slices of component a's faces, in parallel. */
static void run_faces(DrLiquid *L, DrRangeFn fn, int a)
{
    BcCtx ctx = {L, a};
    dr_parallel_for(L->g->fdim[a][2], slice_grain(L->g, a), fn, &ctx);
}

/* Collider-union phi at the grid nodes: ctx->a = 1 writes the static colliders' union into nphi_static,
   ctx->a = 0 the union of all into nphi, taking the static part from nphi_static. A collider's phi is
   evaluated only within its box padded by two cells (beyond, it exceeds every threshold used here). */
static void node_phi_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    bool statics = ctx->a == 1;
    int nx1 = g->nx + 1, ny1 = g->ny + 1;
    DrVec3 blo[MAX_COLLIDERS_FRAME], bhi[MAX_COLLIDERS_FRAME];
    bool use[MAX_COLLIDERS_FRAME];
    for (int c = 0; c < L->nframes; c++) {
        use[c] = dr_collider_static(L->frames[c].c) == statics;
        dr_collider_frame_bounds(&L->frames[c], &blo[c], &bhi[c]);
        DrVec3 pad = dr_v3(2 * g->dx, 2 * g->dx, 2 * g->dx);
        blo[c] = dr_v3_sub(blo[c], pad);
        bhi[c] = dr_v3_add(bhi[c], pad);
    }
    double *out = statics ? L->nphi_static : L->nphi;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < ny1; j++)
            for (int i = 0; i < nx1; i++) {
                long node = i + (long)nx1 * (j + (long)ny1 * k);
                DrVec3 x = dr_v3(g->origin.x + i * g->dx, g->origin.y + j * g->dx, g->origin.z + k * g->dx);
                double phi = statics || L->nstatic == 0 ? INFINITY : L->nphi_static[node];
                for (int c = 0; c < L->nframes; c++) {
                    if (!use[c] || !in_box(x, blo[c], bhi[c])) continue;
                    double p = dr_collider_frame_phi(&L->frames[c], x, NULL);
                    if (p < phi) phi = p;
                }
                out[node] = phi;
            }
}

/* nphi for this substep's collider poses; the static colliders' part is computed again only when their
   set changes (a scene's tank or bowl is sampled once, not every substep). */
static void node_phi(DrLiquid *L)
{
    const DrMacGrid *g = L->g;
    uint64_t ids[MAX_COLLIDERS_FRAME];
    int n = 0;
    for (int c = 0; c < L->nframes; c++)
        if (dr_collider_static(L->frames[c].c)) ids[n++] = dr_collider_id(L->frames[c].c);
    if (n != L->nstatic || memcmp(ids, L->static_ids, (size_t)n * sizeof ids[0]) != 0) {
        L->nstatic = n;
        memcpy(L->static_ids, ids, (size_t)n * sizeof ids[0]);
        if (n > 0) {
            BcCtx ctx = {L, 1};
            dr_parallel_for(g->nz + 1, slice_grain(g, 2), node_phi_slices, &ctx);
        }
    }
    BcCtx ctx = {L, 0};
    dr_parallel_for(g->nz + 1, slice_grain(g, 2), node_phi_slices, &ctx);
}

static double node_phi_at(const DrLiquid *L, int i, int j, int k)
{
    return L->nphi[i + (long)(L->g->nx + 1) * (j + (long)(L->g->ny + 1) * k)];
}

/* Face weights and solid velocities. wsol is the fraction of the face outside every collider, from the
   collider-union phi at its four corners (dr_face_fraction_outside); own.open is the same with domain-boundary
   faces closed (walls: weight 0, at rest). Faces with a corner closer than 2Δx to a collider take the
   velocity of the nearest collider at their centre as the solid velocity own.velocity: the partly blocked faces
   (weight < 1), and the open faces next to them that may carry no liquid mass and are then closed at
   that velocity (pressure_row). */
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
                int owner = -1;
                if (L->nframes > 0) {
                    double p[4];
                    for (int q = 0; q < 4; q++) {
                        int nn[3] = {ijk[0], ijk[1], ijk[2]};
                        nn[b] += (q == 1 || q == 2);
                        nn[c] += (q >= 2);
                        p[q] = node_phi_at(L, nn[0], nn[1], nn[2]);
                    }
                    double pmin = fmin(fmin(p[0], p[1]), fmin(p[2], p[3]));
                    if (pmin < g->dx) w = dr_face_fraction_outside(p[0], p[1], p[2], p[3]);
                    if (pmin < 2.0 * g->dx && L->nstatic < L->nframes) {
                        /* the nearest collider's velocity; a static one's is 0, and its phi at the centre
                           is taken as the mean of the face's corners (it only decides which is nearest) */
                        DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                        double best = INFINITY;
                        if (L->nstatic > 0) {
                            best = 0.0;
                            for (int q = 0; q < 4; q++) {
                                int nn[3] = {ijk[0], ijk[1], ijk[2]};
                                nn[b] += (q == 1 || q == 2);
                                nn[c] += (q >= 2);
                                best += 0.25 * L->nphi_static[nn[0] + (long)(g->nx + 1) * (nn[1] + (long)(g->ny + 1) * nn[2])];
                            }
                        }
                        for (int cc = 0; cc < L->nframes; cc++) {
                            if (dr_collider_static(L->frames[cc].c)) continue;
                            double ph = dr_collider_frame_phi(&L->frames[cc], x, NULL);
                            if (ph < best) {
                                best = ph;
                                vs = dr_v3_get(dr_collider_frame_velocity(&L->frames[cc], x), a);
                                owner = cc;
                            }
                        }
                    }
                }
                L->wsol[a][f] = (float)w;
                if (ijk[a] == 0 || ijk[a] == dim[a] - 1) {
                    w = 0.0;
                    vs = 0.0;
                    owner = -1;
                }
                L->owner[a][f] = (signed char)owner;
                L->own.open[a][f] = w;
                L->own.velocity[a][f] = vs;
            }
}

/* Open volume fraction ω of each cell: the mean of its six faces' collider fractions (1 away from
   colliders). It normalises the particle count of cut cells (a half-blocked cell holding half the seeded
   particles is full) and marks the cells whose liquid phi comes from the extension below. */
static void open_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                double sum = 0.0;
                for (int a = 0; a < 3; a++) {
                    long flo = low_face(g, a, i, j, (int)k), fhi = flo + face_stride(g, a);
                    sum += (double)L->wsol[a][flo] + (double)L->wsol[a][fhi];
                }
                L->open[dr_mac_cell_index(g, i, j, (int)k)] = sum >= 6.0 ? 1.0f : (float)(sum / 6.0);
            }
}

/* near[c]: some cell of the 3×3×3 block around c is partly open (0 < ω < 1): c is at a collider's
   surface, where the P2G support of its faces may reach into the collider and find no particles. */
static void near_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                bool cut = false;
                for (int dk = -1; dk <= 1 && !cut; dk++)
                    for (int dj = -1; dj <= 1 && !cut; dj++)
                        for (int di = -1; di <= 1 && !cut; di++) {
                            int ii = i + di, jj = j + dj, kk = (int)k + dk;
                            if (ii < 0 || jj < 0 || kk < 0 || ii >= g->nx || jj >= g->ny || kk >= g->nz) continue;
                            float om = L->open[dr_mac_cell_index(g, ii, jj, kk)];
                            cut = om > 0.0f && om < 1.0f;
                        }
                L->near[dr_mac_cell_index(g, i, j, (int)k)] = cut;
            }
}

/* ---- 4. pressure --------------------------------------------------------------------------------- */

static inline double cell_theta(const DrLiquid *L, long fluid, long air)
{
    double pf = L->cphi[fluid], pa = L->cphi[air];
    double th = pf < 0.0 ? pf / (pf - pa) : 0.0;
    return th < 0.01 ? 0.01 : (th > 1.0 ? 1.0 : th);
}

/* A face holds next to nothing when P2G gave it at most TINY_MASS of a full face's mass, as a particle at
   the edge of the kernel's reach does (down to round-off: 1e-20 was seen). Such a face between two
   pressure cells would couple them with the mass-weighted coefficient ρΔx³/m_f (1e19 there) and make the
   matrix unsolvable, so it is shut (shut_faces); next to a cell with p = 0 it stays open, where the
   coefficient only pins the other cell's pressure, and the mass-weighted projection keeps its exact
   momentum. A cell holding particles gives each of its faces at least ~4e-3 of a full face's mass, so
   only cells without particles (next to colliders, or constrained mass-weighted cells) meet such faces. */
#define TINY_MASS 1e-6
static inline double face_mass(const DrLiquid *L, int a, long f)
{
    return L->fm[a][f] + (L->vn > 0 ? L->vfm[a][f] : 0.0);
}

/* Poisson coefficient of face f relative to the ghost-fluid one, ρ/ρ_f (liquid.h): 0 on a shut face (no
   liquid reaches it: it takes no pressure impulse and is closed at the solid velocity, face_flux); else 1
   for the ghost-fluid formulation and ρΔx³/(m_f + m_f^virtual) for the mass-weighted one, m_f^virtual the
   virtual liquid's inside colliders (virtual_mass; 0 away from them). */
/* The body (dr_liquid_set_bodies) that owns face f, −1 if none. */
static inline int face_body(const DrLiquid *L, int a, long f)
{
    if (L->nbodies == 0) return -1;
    int o = L->owner[a][f];
    return o < 0 ? -1 : L->frame_body[o];
}

/* The Poisson coefficient the extra coupling's moving solid adds on face f: s_f² ρΔx³/m^s_f (soft_faces), 0 without. */
static inline double soft_coef(const DrLiquid *L, int a, long f)
{
    if (!L->soft_on) return 0.0;
    double s = L->smul[a][f];
    return s > 0.0 ? s * s * L->vol_density / L->soft->solid_mass[a][f] : 0.0;
}

static inline double porous_scale(const DrLiquid *L, int a, long f)
{
    return L->porous_on ? L->porous[a][f] : 1.0;
}
static inline double face_inv_density(const DrLiquid *L, int a, long f)
{
    if (L->shut[a][f]) return 0.0;
    if (L->d.pressure == DR_PRESSURE_GHOST_FLUID) return porous_scale(L, a, f);
    return L->vol_density / face_mass(L, a, f) * porous_scale(L, a, f);
}

/* Velocity through face f as the divergence sees it (m/s): w u + (1 − w) u_solid on an open face (the
   variational boundary: the open part moves with the liquid, the blocked part with the solid), u_solid on
   a shut one (closed: no liquid reaches it, so its open part is given the solid's velocity rather than
   the zero P2G leaves there, and a collider carrying liquid carries it exactly). */
static inline double face_flux(const DrLiquid *L, int a, long f)
{
    const DrFaceCoupling *k = L->cpl;
    double w = k->open[a][f];
    return L->shut[a][f] ? k->velocity[a][f] : w * L->g->f[a][f] + (1.0 - w) * k->velocity[a][f];
}

/* shut[a][f]: the face carries no liquid mass, or next to nothing between two pressure cells (TINY_MASS). */
static void shut_slices(long begin, long end, void *vctx)
{
    BcCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    int n[3] = {g->nx, g->ny, g->nz};
    double tiny = TINY_MASS * L->vol_density;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                unsigned char shut = !(L->fm[a][f] > 0.0);
                int ijk[3] = {i, j, (int)k};
                if (!shut && ijk[a] > 0 && ijk[a] < n[a] && face_mass(L, a, f) <= tiny) {
                    long chi = dr_mac_cell_index(g, i, j, (int)k), clo = chi - cstride[a];
                    shut = L->row[chi] >= 0 && L->row[clo] >= 0;
                }
                L->shut[a][f] = shut;
            }
}

/* The projection's coupling with another participant's (dr_liquid_project): on each face that the extra
   coupling blocks in part (open < 1), the solid shares add (the solids are taken as disjoint, as contact
   keeps them apart): open = 1 − (1 − w_own) − (1 − w_extra), at least 0, and the solid velocity is the
   share-weighted mean of the two. Faces the extra coupling leaves open keep the colliders' values exactly,
   and domain walls stay closed and at rest. Flags (impulse_partial[IMPULSE_PARTS·k + 5]) a slice holding
   an open fraction outside [0, 1], a non-finite velocity or impulse, or a negative or non-finite solid mass. */
typedef struct MixCtx { DrLiquid *L; int a; const DrFaceCoupling *x; } MixCtx;

/* Where the extra coupling's moving solid (solid mass > 0) and a collider both claim a face, the solid keeps its share
   and the collider's shrinks to what is left, σ_own ≤ 1 − σ_e: the bodies' own contact (the MPM grid's) settles how a
   solid meets a collider, and the projection must not do it again (a body resting on a collider, its cells pressure
   cells, would else be held up by the pressure as well as by its contact). The colliders' open fraction so taken. */
static inline double soft_own_open(double w_own, double w_extra, double solid_mass)
{
    if (!(solid_mass > 0.0) || !(w_extra < 1.0)) return w_own;
    return w_own > w_extra ? w_own : w_extra; /* 1 − min(σ_own, 1 − σ_e) */
}

static void mix_slices(long begin, long end, void *vctx)
{
    MixCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    const double *wo = L->own.open[a], *vo = L->own.velocity[a], *we = ctx->x->open[a], *ve = ctx->x->velocity[a];
    const double *J = ctx->x->impulse[a];
    const double *ms = ctx->x->solid_mass[a];
    double *wm = L->mix.open[a], *vm = L->mix.velocity[a];
    for (long k = begin; k < end; k++) {
        bool bad = false;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int ijk[3] = {i, j, (int)k};
                if (!(we[f] >= 0.0 && we[f] <= 1.0) || !isfinite(ve[f]) || (J && !isfinite(J[f])) ||
                    (ms && !(ms[f] >= 0.0 && isfinite(ms[f]))))
                    bad = true;
                if (ijk[a] == 0 || ijk[a] == dim[a] - 1) { /* domain walls stay closed and at rest */
                    wm[f] = wo[f];
                    vm[f] = vo[f];
                    continue;
                }
                dr_face_mix(soft_own_open(wo[f], we[f], ms ? ms[f] : 0.0), vo[f], we[f], ve[f], &wm[f], &vm[f]);
            }
        L->impulse_partial[IMPULSE_PARTS * k + 5] = bad;
    }
}

static DrStatus mix_coupling(DrLiquid *L, const DrFaceCoupling *x, DrError *err)
{
    const DrMacGrid *g = L->g;
    for (int a = 0; a < 3; a++) {
        assert(x->nfaces[a] == g->nfaces[a] && x->open[a] && x->velocity[a]);
        if (!L->mix.open[a]) {
            DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->mix.open[a], err));
            DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->mix.velocity[a], err));
        }
    }
    for (int a = 0; a < 3; a++) {
        MixCtx ctx = {L, a, x};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), mix_slices, &ctx);
        for (int k = 0; k < g->fdim[a][2]; k++)
            if (L->impulse_partial[IMPULSE_PARTS * k + 5] != 0.0)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid project: the face coupling of component "
                                    "%d has an open fraction outside [0, 1], a non-finite velocity or impulse, or a "
                                    "negative or non-finite solid mass in face layer %d.", a, k);
    }
    return DR_OK;
}

/* The extra coupling's impulses J_f (N·s) as velocity increments J_f/m_f and its drag masses β_f (kg) as the
   implicit pull towards the solid's velocity V_f (grid.h): u_f ← (m_f u_f + J_f + β_f V_f)/(m_f + β_f), with the
   face's pressure coefficient scaled by m_f/(m_f + β_f) (porous_scale), m_f the face's P2G mass, on the faces
   that take part in the projection as liquid faces (take): open, not shut, not a domain wall, more than
   TINY_MASS of a full face's mass (a smaller one would turn a finite impulse into an unbounded velocity),
   and, ghost fluid, next to a pressure cell (the others are overwritten by the extrapolation). So the
   liquid's momentum gains exactly Σ J_f over these faces before the pressure acts; L->added holds that
   sum (slice partials added in slice order). After shut_slices. */
typedef struct AddCtx { DrLiquid *L; int a; const double *J, *beta, *V; } AddCtx;

static void add_impulse_slices(long begin, long end, void *vctx)
{
    AddCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    bool mw = L->d.pressure == DR_PRESSURE_MASS_WEIGHTED;
    double tiny = TINY_MASS * L->vol_density;
    for (long k = begin; k < end; k++) {
        double sum = 0.0;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int ijk[3] = {i, j, (int)k};
                bool takes = ijk[a] > 0 && ijk[a] < dim[a] - 1 && L->cpl->open[a][f] > 0.0 && !L->shut[a][f] &&
                             L->fm[a][f] > tiny;
                if (takes && !mw) {
                    long chi = dr_mac_cell_index(g, i, j, (int)k), clo = chi - cstride[a];
                    takes = L->row[chi] >= 0 || L->row[clo] >= 0;
                }
                L->take[a][f] = takes;
                if (L->porous_on) L->porous[a][f] = 1.0;
                if (!takes) continue;
                double J = ctx->J ? ctx->J[f] : 0.0, m = L->fm[a][f];
                if (J != 0.0) {
                    g->f[a][f] += J / m;
                    sum += J;
                }
                double beta = ctx->beta ? ctx->beta[f] : 0.0;
                if (beta > 0.0) {
                    g->f[a][f] = (m * g->f[a][f] + beta * ctx->V[f]) / (m + beta);
                    L->porous[a][f] = m / (m + beta);
                }
            }
        L->impulse_partial[IMPULSE_PARTS * k] = sum;
    }
}

static DrStatus add_impulse(DrLiquid *L, const DrFaceCoupling *x, DrError *err)
{
    const DrMacGrid *g = L->g;
    double tot[3] = {0.0, 0.0, 0.0};
    L->porous_on = false;
    for (int a = 0; a < 3; a++) {
        if (!L->take[a]) DR_TRY(dr_calloc((size_t)g->nfaces[a], 1, &L->take[a], err));
        if (x->drag[a]) {
            if (!L->porous[a]) DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->porous[a], err));
            L->porous_on = true;
        }
    }
    for (int a = 0; a < 3 && L->porous_on; a++)
        if (!L->porous[a]) DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->porous[a], err));
    for (int a = 0; a < 3; a++) {
        AddCtx ctx = {L, a, x->impulse[a], x->drag[a], x->velocity[a]};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), add_impulse_slices, &ctx);
        for (int k = 0; k < g->fdim[a][2]; k++) tot[a] += L->impulse_partial[IMPULSE_PARTS * k];
    }
    L->added = dr_v3(tot[0], tot[1], tot[2]);
    return DR_OK;
}

/* The momentum the drag masses gave in the projection just made: Σ β_f (V_f − u_f) over the faces taking them,
   u_f projected (slice partials in slice order). */
typedef struct DragSumCtx { DrLiquid *L; int a; const double *beta, *V; } DragSumCtx;

static void drag_sum_slices(long begin, long end, void *vctx)
{
    DragSumCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    for (long k = begin; k < end; k++) {
        double sum = 0.0;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                if (L->take[a][f] && ctx->beta[f] > 0.0) sum += ctx->beta[f] * (ctx->V[f] - g->f[a][f]);
            }
        L->impulse_partial[IMPULSE_PARTS * k + 1] = sum;
    }
}

static void drag_sum(DrLiquid *L, const DrFaceCoupling *x)
{
    const DrMacGrid *g = L->g;
    double tot[3] = {0.0, 0.0, 0.0};
    for (int a = 0; a < 3; a++) {
        if (!x->drag[a]) continue;
        DragSumCtx ctx = {L, a, x->drag[a], x->velocity[a]};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), drag_sum_slices, &ctx);
        for (int k = 0; k < g->fdim[a][2]; k++) tot[a] += L->impulse_partial[IMPULSE_PARTS * k + 1];
    }
    L->drag_added = dr_v3(tot[0], tot[1], tot[2]);
}

/* ---- the extra coupling's moving solid (DrFaceCoupling.solid_mass) ---------------------------------------------
 * A face's blocked share mixes the colliders' σ_o = 1 − w_own and the extra solid's σ_e = 1 − w_extra (mix_coupling:
 * open w = 1 − σ_o − σ_e, the solid velocity their share-weighted mean), so the extra solid's velocity V enters the
 * face's flux (face_flux) with the weight s = (1 − w) σ_e/(σ_o + σ_e), or σ_e/(σ_o + σ_e) on a shut face (closed at
 * the solid velocity). With V a point mass m^s along e_a that the pressure moves, V⁺ = V + s ρΔx² (q_lo − q_hi)/m^s
 * (q = 0 outside the pressure cells), eliminating V⁺ adds s² ρΔx³/m^s to the face's Poisson coefficient (soft_coef):
 * a diagonal term per face, so the matrix keeps its 7-point stencil and the multigrid sees the whole operator. */
typedef struct SoftCtx { DrLiquid *L; int a; } SoftCtx;

static void soft_faces_slices(long begin, long end, void *vctx)
{
    SoftCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    const DrFaceCoupling *x = L->soft;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int ijk[3] = {i, j, (int)k};
                double s = 0.0, share = 0.0;
                double se = 1.0 - x->open[a][f], ms = x->solid_mass[a][f];
                if (ijk[a] > 0 && ijk[a] < dim[a] - 1 && se > 0.0 && ms > 0.0) {
                    double so = 1.0 - soft_own_open(L->own.open[a][f], x->open[a][f], ms);
                    share = se / (so + se);
                    s = (L->shut[a][f] ? 1.0 : 1.0 - L->mix.open[a][f]) * share;
                }
                L->smul[a][f] = s;
                L->sshare[a][f] = share;
                L->sdp[a][f] = 0.0;
            }
}

/* After shut_slices, before the rows are assembled: s_f and the share on every face (soft_on), or nothing. */
static DrStatus soft_faces(DrLiquid *L, const DrFaceCoupling *x, DrError *err)
{
    const DrMacGrid *g = L->g;
    L->soft_on = false;
    L->soft = NULL;
    L->soft_gain = dr_v3(0, 0, 0);
    if (!x || !x->solid_mass[0] || !x->solid_mass[1] || !x->solid_mass[2]) return DR_OK; /* checked in mix_slices */
    for (int a = 0; a < 3; a++) {
        if (!L->smul[a]) {
            DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->smul[a], err));
            DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->sshare[a], err));
            DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->sdp[a], err));
        }
    }
    L->soft = x;
    L->soft_on = true;
    for (int a = 0; a < 3; a++) {
        SoftCtx ctx = {L, a};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), soft_faces_slices, &ctx);
    }
    return DR_OK;
}

/* After the solve (before project_slices, which sets the blocked faces to the solid velocity): the solid's momentum
   gain m^s ΔV = s ρΔx² (q_lo − q_hi) on each face, and the mixed solid velocity moved by share·ΔV. */
static void soft_results_slices(long begin, long end, void *vctx)
{
    SoftCtx *ctx = vctx;
    DrLiquid *L = ctx->L;
    const DrMacGrid *g = L->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    double scale = L->vol_density / g->dx; /* ρΔx² */
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                double s = L->smul[a][f];
                if (!(s > 0.0) || L->nrow == 0) continue;
                long chi = dr_mac_cell_index(g, i, j, (int)k), clo = chi - cstride[a];
                double qlo = L->row[clo] >= 0 ? L->q[L->row[clo]] : 0.0, qhi = L->row[chi] >= 0 ? L->q[L->row[chi]] : 0.0;
                double gain = s * scale * (qlo - qhi);
                L->sdp[a][f] = gain;
                L->mix.velocity[a][f] += L->sshare[a][f] * gain / L->soft->solid_mass[a][f];
            }
}

static void soft_results(DrLiquid *L)
{
    for (int a = 0; a < 3; a++) {
        SoftCtx ctx = {L, a};
        dr_parallel_for(L->g->fdim[a][2], slice_grain(L->g, a), soft_results_slices, &ctx);
    }
}

/* After project_slices: Σ sdp in face order. */
static void soft_sum(DrLiquid *L)
{
    double tot[3] = {0.0, 0.0, 0.0};
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < L->g->nfaces[a]; f++) tot[a] += L->sdp[a][f];
    L->soft_gain = dr_v3(tot[0], tot[1], tot[2]);
}

const double *dr_liquid_solid_momentum(const DrLiquid *liq, int a)
{
    return liq->soft_on ? liq->sdp[a] : NULL;
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
        /* −Δx·Σ sign (face flux): the right-hand side of A q = −Δx² div u (q = pΔt/ρ) */
        rhs -= face_flux(L, a, fhi);
        rhs += face_flux(L, a, flo);
        for (int side = 0; side < 2; side++) {
            long f = side ? fhi : flo;
            double w = L->cpl->open[a][f];
            int slot = side ? 3 + a : 2 - a; /* -z,-y,-x | +x,+y,+z: ascending cell index */
            offcol[slot] = -1;
            int nbi = idx[a] + (side ? 1 : -1);
            if (nbi < 0 || nbi >= n[a]) continue;
            long nb = c + (side ? cstride[a] : -cstride[a]);
            /* the extra coupling's moving solid on the face: its own coefficient, p = 0 (not the ghost value) in
               a cell without pressure */
            double cs = soft_coef(L, a, f);
            if (w > 0.0) {
                /* mass-weighted, a body's face takes the variational form: the liquid on it moves by w of the
                   pressure impulse and the body by the rest (1 − w), so the two add up to the face's whole impulse */
                if (!gf && (face_body(L, a, f) >= 0 || cs > 0.0)) w *= w;
                w *= face_inv_density(L, a, f);
            } else {
                w = 0.0;
            }
            if (w <= 0.0 && cs <= 0.0) continue;
            if (L->row[nb] >= 0) {
                diag += w + cs;
                off[slot] = -(w + cs);
                offcol[slot] = L->row[nb];
            } else if (gf) {
                diag += w / cell_theta(L, c, nb) + cs; /* ghost fluid: p_air = p_F (1 − 1/θ) */
            } else {
                diag += w + cs; /* mass-weighted: p = 0 at the air cell's centre */
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

/* The particles in cell c after the substep's P2G, each counting vol/V0 of one (their number while all are
   nominal). */
static inline double cell_count(const DrLiquid *L, long c)
{
    long q0 = L->bins->cell_start[c], q1 = L->bins->cell_start[c + 1];
    if (!L->scaled) return (double)(q1 - q0);
    double sum = 0.0;
    for (long q = q0; q < q1; q++) sum += L->pscale[L->bins->order[q]];
    return sum;
}

/* ---- liquid phi and the pressure cells ------------------------------------------------------------------
 * The liquid phi at a cell centre comes from the cell's particle count n (cell_count), relative to what the
 * open part of the cell holds when full: φ = (½ − min(1, n / (per_cell·ω)))·Δx, ω the cell's open fraction
 * (ω clamped at 1/per_cell). A cell cut by a collider holds a number of particles that depends on where
 * the collider surface crosses the seeding lattice, so its count is not a reliable measure of where the
 * free surface is, and a cut cell may hold no particle at all while liquid surrounds it (its open part is
 * too small for one): as an air cell it would put p = 0 next to liquid at depth, a pressure sink that sets
 * a still pool moving. So every cut cell takes the liquid phi of the liquid next to it instead: the uncut
 * cells' phi continued into the collider along the liquid surface (extend_phi_slices). A cut cell holding
 * particles takes the smaller (fuller) of its own and the extended value. Pressure cells are the cells
 * with a face the liquid reaches that hold particles or whose phi is negative, and, mass-weighted, the
 * cells whose every open face carries mass (liquid.h). */
static double count_phi(const DrLiquid *L, long c)
{
    double om = fmax((double)L->open[c], 1.0 / L->d.per_cell);
    double frac = cell_count(L, c) / (L->d.per_cell * om);
    return (0.5 - (frac > 1.0 ? 1.0 : frac)) * L->g->dx;
}

typedef struct PhiCtx { DrLiquid *L; } PhiCtx;

static void count_phi_slices(long begin, long end, void *vctx)
{
    DrLiquid *L = ((PhiCtx *)vctx)->L;
    const DrMacGrid *g = L->g;
    long per = (long)g->nx * g->ny;
    for (long c = begin * per; c < end * per; c++) L->cphi[c] = count_phi(L, c);
}

/* The uncut cells' phi interpolated trilinearly at x, the weights renormalised over the uncut cells among
   the eight around x; returns the share of the weights on uncut cells (1: all eight uncut; 0: none, and
   *out untouched). With `held`, cut cells holding particles count too, with their count phi (a corner
   where two walls meet has no uncut cell near it). */
static double uncut_phi_at(const DrLiquid *L, DrVec3 x, bool held, double *out)
{
    const DrMacGrid *g = L->g;
    int n[3] = {g->nx, g->ny, g->nz};
    int base[3];
    double fr[3];
    for (int d = 0; d < 3; d++) {
        double sd = (dr_v3_get(x, d) - dr_v3_get(g->origin, d)) / g->dx - 0.5;
        double fb = floor(sd);
        base[d] = (int)fb;
        fr[d] = sd - fb;
    }
    double sum = 0.0, wsum = 0.0;
    for (int q = 0; q < 8; q++) {
        int ijk[3] = {base[0] + (q & 1), base[1] + ((q >> 1) & 1), base[2] + ((q >> 2) & 1)};
        double w = 1.0;
        bool inside = true;
        for (int d = 0; d < 3; d++) {
            if (ijk[d] < 0 || ijk[d] >= n[d]) inside = false;
            w *= ((q >> d) & 1) ? fr[d] : 1.0 - fr[d];
        }
        if (!inside || w <= 0.0) continue;
        long c = dr_mac_cell_index(g, ijk[0], ijk[1], ijk[2]);
        if (L->open[c] < 1.0f && !(held && L->bins->cell_start[c + 1] > L->bins->cell_start[c])) continue;
        sum += w * count_phi(L, c);
        wsum += w;
    }
    if (!(wsum > 1e-6)) return 0.0;
    *out = sum / wsum;
    return wsum;
}

/* Direction in which the uncut cells' phi grows around cut cell (i,j,k): per axis, the sum of the
   differences of phi between neighbouring uncut cells of the 5×5×5 block along that axis (a curved
   collider cuts a band of cells up to two wide), from the tables of phi_direction_tables. Only pairs of
   uncut cells count, so in a pool at rest, whose uncut cells have one value per layer, the horizontal
   components vanish exactly and the direction is exactly vertical wherever the block reaches across the
   surface; it is zero where it does not (deep in the liquid or in the air). */
#define EXT_BLOCK 2
static DrVec3 uncut_phi_direction(const DrLiquid *L, int i, int j, int k)
{
    const DrMacGrid *g = L->g;
    int n[3] = {g->nx, g->ny, g->nz}, c[3] = {i, j, k};
    long sy = g->nx + 1, sz = (long)(g->nx + 1) * (g->ny + 1);
    double gr[3];
    for (int a = 0; a < 3; a++) {
        /* the pairs (u, u + e_a) inside the block: u_a in [c_a − B, c_a + B − 1], the others in [c − B, c + B] */
        int lo[3], hi[3];
        for (int d = 0; d < 3; d++) {
            lo[d] = c[d] - EXT_BLOCK < 0 ? 0 : c[d] - EXT_BLOCK;
            hi[d] = c[d] + EXT_BLOCK + (d == a ? 0 : 1);
            if (hi[d] > n[d]) hi[d] = n[d];
        }
        const float *S = L->dsum[a];
        /* inclusion–exclusion over the table's corners: S[x,y,z] sums the cells below (x, y, z) */
        double sum = 0.0;
        for (int q = 0; q < 8; q++) {
            long x = (q & 1) ? hi[0] : lo[0], y = (q & 2) ? hi[1] : lo[1], z = (q & 4) ? hi[2] : lo[2];
            int sign = ((q & 1) ? 1 : -1) * ((q & 2) ? 1 : -1) * ((q & 4) ? 1 : -1);
            sum += sign * (double)S[x + sy * y + sz * z];
        }
        gr[a] = sum;
    }
    return dr_v3(gr[0], gr[1], gr[2]);
}

/* The tables of uncut_phi_direction: for each axis a, D_a(u) = phi(u + e_a) − phi(u) where both cells are
   uncut (else 0), summed over every box of cells from the origin (a summed-volume table), so that the sum
   over a block is eight lookups. In float: the sums it is used for are of differences of the saturated
   phi (±Δx/2 in full and empty cells), exact in either precision, and a direction needs no more. */
static DrStatus phi_direction_tables(DrLiquid *L, DrError *err)
{
    const DrMacGrid *g = L->g;
    long sy = g->nx + 1, sz = (long)(g->nx + 1) * (g->ny + 1);
    int n[3] = {g->nx, g->ny, g->nz};
    for (int a = 0; a < 3; a++) {
        if (!L->dsum[a]) DR_TRY(dr_calloc((size_t)L->nnodes, sizeof(float), &L->dsum[a], err));
        float *S = L->dsum[a];
        for (int k = 0; k < g->nz; k++)
            for (int j = 0; j < g->ny; j++)
                for (int i = 0; i < g->nx; i++) {
                    int u[3] = {i, j, k};
                    long cu = dr_mac_cell_index(g, i, j, k);
                    double d = 0.0;
                    if (u[a] + 1 < n[a] && L->open[cu] >= 1.0f) {
                        long cv = cu + (a == 0 ? 1 : (a == 1 ? g->nx : (long)g->nx * g->ny));
                        if (L->open[cv] >= 1.0f) d = L->cphi[cv] - L->cphi[cu];
                    }
                    long o = (i + 1) + sy * (j + 1) + sz * (k + 1);
                    S[o] = (float)(d + S[o - 1] + S[o - sy] + S[o - sz] - S[o - 1 - sy] - S[o - 1 - sz] -
                                   S[o - sy - sz] + S[o - 1 - sy - sz]);
                }
    }
    return DR_OK;
}

/* Writes the extended phi of the cut cells into L->tmp2[0] (the count phi of the uncut cells is read from
   cphi and never written here, so the slices run in parallel). The extension continues the liquid
   surface into the collider as it is: from the cell centre it samples the uncut cells' phi along the
   collider normal n projected onto the surface's tangent plane (n − (n·ĝ)ĝ, ĝ = uncut_phi_direction),
   far enough to leave the collider and one cell more, and on, half a cell at a time up to three cells
   further, until the sample's eight cells are all uncut (a curved collider cuts a band of cells); where
   no uncut cell is found that way, cut cells holding particles are sampled too. Extending along n
   itself (a 90° contact angle) would bend a still surface that meets a sloping wall, and the bend would
   drive flow. Where the surface is not near (ĝ = 0 around the cell and around the point one cell
   outside the collider along n) or lies parallel to the wall, the sample is taken along n. Cells inside
   a collider (ω = 0) are skipped: they have no open face. */
static void extend_phi_slices(long begin, long end, void *vctx)
{
    DrLiquid *L = ((PhiCtx *)vctx)->L;
    const DrMacGrid *g = L->g;
    double *ext = L->tmp2[0];
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    int n[3] = {g->nx, g->ny, g->nz};
    for (long k = begin; k < end; k++)
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                long c = dr_mac_cell_index(g, i, j, (int)k);
                if (L->open[c] >= 1.0f) continue;
                if (L->open[c] <= 0.0f) { /* inside a collider: never a pressure cell (no open face) */
                    ext[c] = 0.5 * g->dx;
                    continue;
                }
                DrVec3 x = dr_mac_cell_center(g, i, j, (int)k);
                double phs = INFINITY;
                int near_c = 0;
                for (int cc = 0; cc < L->nframes; cc++) {
                    double p = dr_collider_frame_phi(&L->frames[cc], x, NULL);
                    if (p < phs) { phs = p; near_c = cc; }
                }
                DrVec3 nrm;
                (void)dr_collider_frame_phi(&L->frames[near_c], x, &nrm); /* the nearest one's normal */
                double depth = fmax(0.0, -phs);
                DrVec3 dir = nrm;
                double reach = depth + g->dx;
                DrVec3 gl = uncut_phi_direction(L, i, j, (int)k);
                if (!(dr_v3_norm(gl) > 0.0)) {
                    /* a wide band of cut cells (a wall sloping gently through the surface): look again
                       around the point one cell outside the collider along its normal */
                    DrVec3 p1 = dr_v3_add(x, dr_v3_scale(nrm, reach));
                    int q[3];
                    for (int d = 0; d < 3; d++) {
                        q[d] = (int)floor((dr_v3_get(p1, d) - dr_v3_get(g->origin, d)) / g->dx);
                        q[d] = q[d] < 0 ? 0 : (q[d] >= n[d] ? n[d] - 1 : q[d]);
                    }
                    gl = uncut_phi_direction(L, q[0], q[1], q[2]);
                }
                double gn = dr_v3_norm(gl);
                if (gn > 0.0) gl = dr_v3_scale(gl, 1.0 / gn);
                if (gn > 0.0) {
                    DrVec3 t = dr_v3_sub(nrm, dr_v3_scale(gl, dr_v3_dot(nrm, gl)));
                    double tn = dr_v3_norm(t);
                    if (tn > 0.2) {
                        dir = dr_v3_scale(t, 1.0 / tn);
                        reach = fmin(depth / tn, 2.0 * g->dx) + g->dx; /* n·dir = tn */
                    }
                }
                double v = 0.0, share = 0.0;
                for (int held = 0; held < 2 && !(share > 0.0); held++)
                    for (int step = 0; step <= 6 && share < 1.0 - 1e-9; step++) {
                        double vs = 0.0;
                        double sh = uncut_phi_at(L, dr_v3_add(x, dr_v3_scale(dir, reach + 0.5 * step * g->dx)),
                                                 held, &vs);
                        if (sh > share) { share = sh; v = vs; }
                    }
                if (!(share > 0.0)) {
                    /* no uncut cell there (a gap narrower than a cell between colliders): the fullest
                       neighbour across an open face, else air */
                    v = 0.5 * g->dx;
                    int idx[3] = {i, j, (int)k};
                    for (int a = 0; a < 3; a++)
                        for (int side = 0; side < 2; side++) {
                            int nb = idx[a] + (side ? 1 : -1);
                            long f = low_face(g, a, i, j, (int)k) + (side ? face_stride(g, a) : 0);
                            if (nb < 0 || nb >= n[a] || !(L->cpl->open[a][f] > 0.0)) continue;
                            long cn = c + (side ? cstride[a] : -cstride[a]);
                            if (L->bins->cell_start[cn + 1] > L->bins->cell_start[cn]) v = fmin(v, count_phi(L, cn));
                        }
                }
                if (L->bins->cell_start[c + 1] > L->bins->cell_start[c]) v = fmin(v, count_phi(L, c));
                ext[c] = v;
            }
}

/* Virtual liquid for the mass-weighted pressure next to colliders. A face whose P2G support reaches into
   a collider collects less mass than one in open liquid, as no particle is inside the collider; its face
   density m_f/Δx³ then falls towards the collider, and a face density falling sideways is a horizontal
   density gradient that gravity turns into flow (liquid.h). So the colliders' part of every cell near them
   (within one cell of a cut cell) that lies under the liquid is filled with virtual particles at the
   seeding lattice's points inside the collider, splatted like the real ones: real and virtual mass
   together are those of the lattice without the collider, as the walls' mirror nodes make them at the
   domain walls. The virtual mass enters the face densities only: no momentum, no face opened, nothing
   moved. Without a k³ lattice (per_cell not a cube) the points are a 2×2×2 lattice carrying per_cell/8
   particles' mass. "Under the liquid": the cell's phi is negative, or the nearest cell of the 5×5×5 block
   around it that holds particles lies deep in the liquid or no lower along the surface normal ĝ there
   (uncut_phi_direction): the far side of a wall two cells thick, whose own phi is that of the air outside
   the tank, lies under the liquid in it. */
static bool under_liquid(const DrLiquid *L, int i, int j, int k)
{
    const DrMacGrid *g = L->g;
    long c = dr_mac_cell_index(g, i, j, k);
    if (L->cphi[c] < 0.0) return true;
    if (L->open[c] >= 1.0f) return false; /* an uncut cell's phi is its own */
    /* the nearest cell holding particles (first in block order among the nearest) */
    int best = INT_MAX, src[3] = {0, 0, 0};
    for (int dk = -EXT_BLOCK; dk <= EXT_BLOCK; dk++)
        for (int dj = -EXT_BLOCK; dj <= EXT_BLOCK; dj++)
            for (int di = -EXT_BLOCK; di <= EXT_BLOCK; di++) {
                int u[3] = {i + di, j + dj, k + dk}, d2 = di * di + dj * dj + dk * dk;
                if (d2 >= best) continue;
                if (u[0] < 0 || u[1] < 0 || u[2] < 0 || u[0] >= g->nx || u[1] >= g->ny || u[2] >= g->nz) continue;
                long cu = dr_mac_cell_index(g, u[0], u[1], u[2]);
                if (!(L->bins->cell_start[cu + 1] > L->bins->cell_start[cu])) continue;
                best = d2;
                src[0] = di; src[1] = dj; src[2] = dk;
            }
    if (best == INT_MAX) return false;
    /* ĝ at the source points from the liquid into the air; deep in the liquid it is zero */
    DrVec3 gl = uncut_phi_direction(L, i + src[0], j + src[1], k + src[2]);
    double gn = dr_v3_norm(gl);
    if (!(gn > 0.0)) return true;
    return (src[0] * gl.x + src[1] * gl.y + src[2] * gl.z) / gn >= -0.5;
}

static DrStatus virtual_mass(DrLiquid *L, DrError *err)
{
    const DrMacGrid *g = L->g;
    L->vn = 0;
    int m = seed_lattice(L->d.per_cell);
    double mass = L->pmass;
    if (m == 0) {
        m = 2;
        mass = L->pmass * L->d.per_cell / 8.0;
    }
    for (int k = 0; k < g->nz; k++)
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                long c = dr_mac_cell_index(g, i, j, k);
                if (!L->near[c] || !under_liquid(L, i, j, k)) continue;
                /* the points of seed_cell with jitter 0, computed the same way to the last bit */
                DrVec3 lo = dr_v3(g->origin.x + i * g->dx, g->origin.y + j * g->dx, g->origin.z + k * g->dx);
                for (int s = 0; s < m * m * m; s++) {
                    double h = 1.0 / m;
                    DrVec3 x = dr_v3(lo.x + (s % m + 0.5) * h * g->dx, lo.y + ((s / m) % m + 0.5) * h * g->dx,
                                     lo.z + (s / (m * m) + 0.5) * h * g->dx);
                    if (!inside_colliders(L->frames, L->nframes, x)) continue;
                    if (L->vn == L->vcap) {
                        long cap = L->vcap + L->vcap / 2 + 4096;
                        DR_TRY(dr_realloc((size_t)cap * 3, sizeof(double), &L->vx, err));
                        DR_TRY(dr_realloc((size_t)cap * 3, sizeof(double), &L->vv, err));
                        memset(L->vv + 3 * L->vcap, 0, (size_t)(cap - L->vcap) * 3 * sizeof(double));
                        L->vcap = cap;
                    }
                    L->vx[3 * L->vn] = x.x; L->vx[3 * L->vn + 1] = x.y; L->vx[3 * L->vn + 2] = x.z;
                    L->vn++;
                }
            }
    if (L->vn == 0) return DR_OK;
    if (!L->vg) {
        DR_TRY(dr_mac_grid_create(g->nx, g->ny, g->nz, g->dx, g->origin, &L->vg, err));
        for (int a = 0; a < 3; a++) DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->vfm[a], err));
        DR_TRY(dr_bins_create(g, L->vn, &L->vbins, err));
    }
    DR_TRY(dr_bins_build(L->vg, L->vn, L->vx, L->vbins, err));
    dr_transfer_p2g_mac(L->vbins, L->vx, L->vv, NULL, mass, NULL, L->d.wall_no_slip, L->vg, L->vfm);
    return DR_OK;
}

/* ---- rigid bodies in the projection (dr_liquid_set_bodies) ----------------------------------------------------- */

/* V + ω × (x − c) with the body's velocity after the last projection. */
static DrVec3 body_point_velocity(const DrLiquidBody *b, DrVec3 x)
{
    double r[3] = {x.x - b->center[0], x.y - b->center[1], x.z - b->center[2]};
    const double *v = b->velocity_out, *w = b->angular_velocity_out;
    return dr_v3(v[0] + w[1] * r[2] - w[2] * r[1], v[1] + w[2] * r[0] - w[0] * r[2], v[2] + w[0] * r[1] - w[1] * r[0]);
}

/* The solid velocity array of component a the projection in progress reads (the colliders' own, or their mix with
   an extra coupling): L's own storage either way. */
static double *coupling_velocity(DrLiquid *L, int a)
{
    return L->cpl == &L->own ? L->own.velocity[a] : L->mix.velocity[a];
}

static inline double body_face_velocity(const BodyFace *bf, const double v[3], const double w[3])
{
    return bf->J[0] * v[0] + bf->J[1] * v[1] + bf->J[2] * v[2] + bf->J[3] * w[0] + bf->J[4] * w[1] + bf->J[5] * w[2];
}

/* J_f = (e_a, r × e_a): the row of a face of component a at r from the body's centre. */
static void face_row(int a, const double r[3], double J[6])
{
    J[0] = a == 0, J[1] = a == 1, J[2] = a == 2;
    J[3] = a == 0 ? 0.0 : (a == 1 ? -r[2] : r[1]);
    J[4] = a == 0 ? r[2] : (a == 1 ? 0.0 : -r[0]);
    J[5] = a == 0 ? -r[1] : (a == 1 ? r[0] : 0.0);
}

/* The body loses the generalised momentum J (N s, N m s about its centre) the liquid gained: from its impulse, and from
   its velocity unless it is held. */
static void body_take(DrLiquidBody *B, const double J[6]);

/* The faces each body owns with a solid share σ > 0, body by body in face order, with their rows and J; their solid
   velocity becomes the body's rigid velocity before the pressure (so the right-hand side carries σ J V). After the
   rows and shut_slices. */
static DrStatus body_faces(DrLiquid *L, DrError *err)
{
    const DrMacGrid *g = L->g;
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    if (!L->bface_start) DR_TRY(dr_calloc(MAX_COLLIDERS_FRAME + 1, sizeof(long), &L->bface_start, err));
    L->nbface = 0;
    for (int b = 0; b < L->nbodies; b++) {
        DrLiquidBody *B = &L->bodies[b];
        memcpy(B->velocity_out, B->velocity, sizeof B->velocity_out);
        memcpy(B->angular_velocity_out, B->angular_velocity, sizeof B->angular_velocity_out);
        memset(B->impulse, 0, sizeof B->impulse);
        memset(B->angular_impulse, 0, sizeof B->angular_impulse);
        L->bface_start[b] = L->nbface;
        for (int a = 0; a < 3; a++) {
            double *vel = coupling_velocity(L, a);
            const int *dim = g->fdim[a];
            for (int k = 0; k < dim[2]; k++)
                for (int j = 0; j < dim[1]; j++)
                    for (int i = 0; i < dim[0]; i++) {
                        long f = dr_mac_face_index(g, a, i, j, k);
                        int o = L->owner[a][f];
                        if (o < 0 || L->frame_body[o] != b) continue;
                        double sigma = L->shut[a][f] ? 1.0 : 1.0 - L->cpl->open[a][f];
                        if (!(sigma > 0.0)) continue;
                        if (L->nbface == L->cap_bface) {
                            long cap = L->cap_bface + L->cap_bface / 2 + 1024;
                            DR_TRY(dr_realloc((size_t)cap, sizeof(BodyFace), &L->bface, err));
                            L->cap_bface = cap;
                        }
                        BodyFace *bf = &L->bface[L->nbface++];
                        long chi = dr_mac_cell_index(g, i, j, k), clo = chi - cstride[a];
                        bf->f = f;
                        bf->a = a;
                        bf->lo = L->row[clo];
                        bf->hi = L->row[chi];
                        bf->sigma = sigma;
                        DrVec3 x = dr_mac_face_position(g, a, i, j, k);
                        double r[3] = {x.x - B->center[0], x.y - B->center[1], x.z - B->center[2]};
                        face_row(a, r, bf->J);
                        vel[f] = body_face_velocity(bf, B->velocity, B->angular_velocity);
                    }
        }
        B->faces = L->nbface - L->bface_start[b];
    }
    L->bface_start[L->nbodies] = L->nbface;
    return DR_OK;
}

/* K q for body b: Σ_f σ_f J_fᵀ (q_lo − q_hi), q = 0 outside the pressure rows. Serial over the body's faces in their
   order: the same bits for any thread count. */
static void body_kq(const DrLiquid *L, int b, const double *q, double k6[6])
{
    for (int i = 0; i < 6; i++) k6[i] = 0.0;
    for (long n = L->bface_start[b]; n < L->bface_start[b + 1]; n++) {
        const BodyFace *bf = &L->bface[n];
        double d = (bf->lo >= 0 ? q[bf->lo] : 0.0) - (bf->hi >= 0 ? q[bf->hi] : 0.0);
        if (d == 0.0) continue;
        for (int i = 0; i < 6; i++) k6[i] += bf->sigma * bf->J[i] * d;
    }
}

/* The velocity change M⁻¹ ρΔx² K q of body b (linear in v, angular in w). */
static void body_dv(const DrLiquid *L, int b, const double k6[6], double v[3], double w[3])
{
    const DrLiquidBody *B = &L->bodies[b];
    double s = L->d.density * L->g->dx * L->g->dx;
    for (int i = 0; i < 3; i++) {
        v[i] = s * B->inv_mass * k6[i];
        w[i] = s * (B->inv_inertia[3 * i] * k6[3] + B->inv_inertia[3 * i + 1] * k6[4] + B->inv_inertia[3 * i + 2] * k6[5]);
    }
}

static bool body_free(const DrLiquidBody *b)
{
    if (b->inv_mass != 0.0) return true;
    for (int i = 0; i < 9; i++)
        if (b->inv_inertia[i] != 0.0) return true;
    return false;
}

static void body_take(DrLiquidBody *B, const double J[6])
{
    for (int i = 0; i < 3; i++) {
        B->impulse[i] -= J[i];
        B->angular_impulse[i] -= J[3 + i];
    }
    if (!body_free(B)) return;
    for (int i = 0; i < 3; i++) {
        B->velocity_out[i] -= B->inv_mass * J[i];
        B->angular_velocity_out[i] -= B->inv_inertia[3 * i] * J[3] + B->inv_inertia[3 * i + 1] * J[4] +
                                      B->inv_inertia[3 * i + 2] * J[5];
    }
}

/* Whether any body moves with the pressure (a held one adds nothing to the system). */
static bool bodies_free(const DrLiquid *L)
{
    for (int b = 0; b < L->nbodies; b++)
        if (body_free(&L->bodies[b]) && L->bface_start[b + 1] > L->bface_start[b]) return true;
    return false;
}

/* y = (A + ρΔx³ Σ_b K_bᵀ M_b⁻¹ K_b) x. */
typedef struct BodyOp { const DrLiquid *L; const DrCsr *A; } BodyOp;

static void body_apply(const double *x, double *y, void *vctx)
{
    const BodyOp *op = vctx;
    const DrLiquid *L = op->L;
    dr_csr_matvec(op->A, x, y);
    for (int b = 0; b < L->nbodies; b++) {
        if (!body_free(&L->bodies[b])) continue;
        double k6[6], v[3], w[3];
        body_kq(L, b, x, k6);
        body_dv(L, b, k6, v, w);
        for (long n = L->bface_start[b]; n < L->bface_start[b + 1]; n++) {
            const BodyFace *bf = &L->bface[n];
            double s = L->g->dx * bf->sigma * body_face_velocity(bf, v, w);
            if (bf->lo >= 0) y[bf->lo] += s;
            if (bf->hi >= 0) y[bf->hi] -= s;
        }
    }
}

/* After the solve: each body's impulse ρΔx² K q, its velocity after the pressure, and that velocity on its faces. */
static void body_results(DrLiquid *L)
{
    double s = L->d.density * L->g->dx * L->g->dx;
    for (int b = 0; b < L->nbodies; b++) {
        DrLiquidBody *B = &L->bodies[b];
        double k6[6] = {0}, v[3] = {0}, w[3] = {0};
        if (L->nrow > 0) {
            body_kq(L, b, L->q, k6);
            if (body_free(B)) body_dv(L, b, k6, v, w);
        }
        for (int i = 0; i < 3; i++) {
            B->impulse[i] = s * k6[i];
            B->angular_impulse[i] = s * k6[3 + i];
            B->velocity_out[i] = B->velocity[i] + v[i];
            B->angular_velocity_out[i] = B->angular_velocity[i] + w[i];
        }
        for (long n = L->bface_start[b]; n < L->bface_start[b + 1]; n++) {
            const BodyFace *bf = &L->bface[n];
            coupling_velocity(L, bf->a)[bf->f] = body_face_velocity(bf, B->velocity_out, B->angular_velocity_out);
        }
    }
}

DrStatus dr_liquid_set_bodies(DrLiquid *liq, DrLiquidBody *bodies, int n, DrError *err)
{
    assert(liq->phase == PHASE_BEGUN || liq->phase == PHASE_PROJECTED); /* dr_liquid_begin first */
    if (n < 0 || n > MAX_COLLIDERS_FRAME)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid bodies: between 0 and %d bodies.", MAX_COLLIDERS_FRAME);
    for (int c = 0; c < liq->nframes; c++) liq->frame_body[c] = -1;
    for (int b = 0; b < n; b++) {
        const DrLiquidBody *B = &bodies[b];
        int found = -1;
        for (int c = 0; c < liq->nframes && found < 0; c++)
            if (liq->frames[c].c == B->collider) found = c;
        bool ok = found >= 0 && isfinite(B->inv_mass) && B->inv_mass >= 0.0;
        for (int i = 0; i < 9 && ok; i++) ok = isfinite(B->inv_inertia[i]);
        for (int i = 0; i < 3 && ok; i++) ok = isfinite(B->velocity[i]) && isfinite(B->angular_velocity[i]) &&
                                               isfinite(B->center[i]);
        if (!ok) {
            for (int c = 0; c < liq->nframes; c++) liq->frame_body[c] = -1;
            liq->nbodies = 0;
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                found < 0 ? "liquid bodies: body %d's collider was not given to dr_liquid_begin."
                                          : "liquid bodies: body %d has a negative or non-finite mass, inertia, "
                                            "velocity or centre.", b);
        }
        liq->frame_body[found] = b;
    }
    liq->bodies = bodies;
    liq->nbodies = n;
    for (int b = 0; b < n; b++) { /* until a projection: moving as given */
        memcpy(bodies[b].velocity_out, bodies[b].velocity, sizeof bodies[b].velocity_out);
        memcpy(bodies[b].angular_velocity_out, bodies[b].angular_velocity, sizeof bodies[b].angular_velocity_out);
        memset(bodies[b].impulse, 0, sizeof bodies[b].impulse);
        memset(bodies[b].angular_impulse, 0, sizeof bodies[b].angular_impulse);
        bodies[b].faces = 0;
    }
    return DR_OK;
}

static DrStatus pressure_solve(DrLiquid *L, const DrFaceCoupling *extra, DrLiquidStats *stats, DrError *err)
{
    const DrMacGrid *g = L->g;
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    const long *cs = L->bins->cell_start;
    bool gf = L->d.pressure == DR_PRESSURE_GHOST_FLUID;
    PhiCtx pctx = {L};
    long cgrain = (PAR_MIN_ITEMS + cstride[2] - 1) / cstride[2];
    dr_parallel_for(g->nz, cgrain, count_phi_slices, &pctx);
    if (L->nframes > 0) {
        DR_TRY(phi_direction_tables(L, err));
        dr_parallel_for(g->nz, 1, extend_phi_slices, &pctx);
        for (long c = 0; c < L->ncells; c++)
            if (L->open[c] < 1.0f) L->cphi[c] = L->tmp2[0][c];
    }
    L->vn = 0;
    if (!gf && L->nframes > 0) DR_TRY(virtual_mass(L, err));
    int nrow = 0;
    const DrFaceCoupling *sx = extra && extra->solid_mass[0] && extra->solid_mass[1] && extra->solid_mass[2] ? extra
                                                                                                               : NULL;
    for (long c = 0; c < L->ncells; c++) {
        L->row[c] = -1;
        bool has = cs[c + 1] > cs[c] || L->cphi[c] < 0.0;
        int i = (int)(c % g->nx), j = (int)((c / g->nx) % g->ny), k = (int)(c / cstride[2]);
        /* the extra coupling's moving solid fills more than half of the cell (its faces' mean blocked share): a
           pressure cell too, so that the pressure continues through the solid (it feels the pressure's gradient over
           its volume, not a jump to 0 at its surface) and the solid moves with the liquid as one incompressible
           mixture there */
        bool solid = false;
        if (sx) {
            double sum = 0.0;
            for (int a = 0; a < 3; a++)
                for (int side = 0; side < 2; side++) {
                    long f = low_face(g, a, i, j, k) + (side ? face_stride(g, a) : 0);
                    if (sx->solid_mass[a][f] > 0.0) sum += 1.0 - sx->open[a][f];
                }
            solid = sum > 3.0;
        }
        has = has || solid;
        if (!has && gf) continue;
        bool open = false, massive = true;
        double tiny = TINY_MASS * L->vol_density;
        for (int a = 0; a < 3; a++)
            for (int side = 0; side < 2; side++) {
                long f = low_face(g, a, i, j, k) + (side ? face_stride(g, a) : 0);
                if (!(L->cpl->open[a][f] > 0.0)) continue;
                if (L->fm[a][f] > tiny) open = true; /* a face no shut_faces can shut: the row is not empty */
                if (!(face_mass(L, a, f) > tiny)) massive = false;
            }
        if (!open && !solid) continue;
        /* mass-weighted: a cell whose every open face carries mass (with the virtual liquid's next to
           colliders; more than TINY_MASS) is constrained too (liquid.h) */
        bool liquid = has || (!gf && massive);
        if (liquid) {
            L->row[c] = nrow;
            L->cells_of_row[nrow++] = c;
        }
    }
    stats->liquid_cells = nrow;
    L->nrow = nrow;
    for (int a = 0; a < 3; a++) run_faces(L, shut_slices, a);
    L->porous_on = false;
    if (extra) DR_TRY(add_impulse(L, extra, err));
    DR_TRY(soft_faces(L, extra, err));
    if (L->nbodies > 0) DR_TRY(body_faces(L, err));
    if (nrow == 0) {
        body_results(L);
        return DR_OK;
    }
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
    DrLinearOp Mop;
    if (L->d.pressure_precond == DR_PRECOND_MULTIGRID) {
        for (int r = 0; r < nrow; r++) {
            long c = L->cells_of_row[r];
            L->row_ijk[3 * r] = (int)(c % g->nx);
            L->row_ijk[3 * r + 1] = (int)((c / g->nx) % g->ny);
            L->row_ijk[3 * r + 2] = (int)(c / cstride[2]);
        }
        int dims[3] = {g->nx, g->ny, g->nz};
        if (!L->mg) DR_TRY(dr_mg_create(A, L->row_ijk, dims, NULL, &L->mg, err));
        else DR_TRY(dr_mg_update(L->mg, A, L->row_ijk, dims, err));
        Mop = dr_mg_op(L->mg);
    } else {
        if (!L->M) DR_TRY(dr_mic0_create(A, DR_MIC0_TAU_DEFAULT, DR_MIC0_SIGMA_DEFAULT, &L->M, err));
        else DR_TRY(dr_mic0_update(L->M, A, err));
        Mop = dr_mic0_op(L->M);
    }
    memset(L->q, 0, (size_t)nrow * sizeof(double));
    DrLinearOp Aop = dr_csr_op(A);
    BodyOp bop = {L, A};
    if (bodies_free(L)) Aop = (DrLinearOp){nrow, body_apply, &bop};
    DrPcgDesc pd;
    dr_pcg_desc_default(&pd);
    pd.rel_tol = L->d.pressure_tol;
    pd.max_iter = L->d.pressure_max_iter;
    DrPcgStats ps;
    DrStatus s = dr_pcg_solve(&Aop, &Mop, L->rhs, L->q, &pd, L->work, &ps, err);
    if (s < 0) return s;
    if (L->nbodies > 0) body_results(L);
    if (L->soft_on) soft_results(L);
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
                int body = face_body(L, a, f);
                double before = g->f[a][f];
                if (L->cpl->open[a][f] <= 0.0) {
                    g->f[a][f] = L->cpl->velocity[a][f];
                    val = 1;
                } else if (L->shut[a][f]) {
                    /* no liquid reaches it: closed at the solid velocity next to a pressure cell (face_flux) */
                    if (flo || fhi) {
                        g->f[a][f] = L->cpl->velocity[a][f];
                        val = 1;
                    }
                } else if (mw) {
                    /* every face with mass: u −= (ρ/ρ_f) Δq/Δx with q = 0 in air cells (air–air: no change); on a
                       body's face the liquid's share w of it (pressure_row) */
                    double qlo = flo ? L->q[L->row[clo]] : 0.0, qhi = fhi ? L->q[L->row[chi]] : 0.0;
                    double share = body >= 0 || (L->soft_on && L->smul[a][f] > 0.0) ? L->cpl->open[a][f] : 1.0;
                    g->f[a][f] -= share * face_inv_density(L, a, f) * (qhi - qlo) * inv;
                    val = 1;
                    if (body >= 0) {
                        /* the liquid's share w of the face's impulse ρΔx²(q_lo − q_hi) that its real mass did not
                           take (the virtual liquid's part of the face mass) goes to the body, which took 1 − w */
                        double full = share * L->d.density * g->dx * g->dx * (qlo - qhi);
                        L->bimp[a][f] = -(full - L->fm[a][f] * (g->f[a][f] - before));
                        L->bwho[a][f] = (signed char)body;
                    }
                } else if (flo || fhi) {
                    double qlo = q_of(L, clo, chi), qhi = q_of(L, chi, clo);
                    g->f[a][f] -= porous_scale(L, a, f) * (qhi - qlo) * inv;
                    val = 1;
                }
                L->valid[a][f] = val;
                if (val && L->soft_on && L->smul[a][f] > 0.0 && (L->cpl->open[a][f] <= 0.0 || L->shut[a][f]))
                    /* setting the face to the mixed solid velocity gave its liquid m_f (u_s − u) (as for a body,
                       below): the extra solid gives its share of it */
                    L->sdp[a][f] -= L->sshare[a][f] * L->fm[a][f] * (g->f[a][f] - (mw ? before : L->uold[a][f]));
                if (body >= 0 && (L->cpl->open[a][f] <= 0.0 || L->shut[a][f])) {
                    /* a face the body blocks takes its velocity: the liquid mass the kernel put there (particles
                       just outside the surface) changes momentum by m_f (u_s − u), which the body gives. Ghost
                       fluid, u is the P2G velocity: the gravity this substep added to that mass is left out, or the
                       body would carry the weight of liquid standing around it (a held sphere's buoyancy 2–3.5 %
                       short at 4–8 cells a radius, measured). Mass-weighted, u is the velocity before the projection,
                       gravity included: the virtual liquid inside the body takes pressure (its share of the face's
                       impulse goes to the body, below), whose weight that balances (so the ledger closes with
                       gravity too) */
                    L->bimp[a][f] = L->fm[a][f] * (g->f[a][f] - (mw ? before : L->uold[a][f]));
                    L->bwho[a][f] = (signed char)body;
                }
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
                dv += face_flux(L, a, fhi) - face_flux(L, a, flo);
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
        /* the sources are the valid faces the projection left open: on a face set to a solid's velocity
           without liquid next to it, u − u_P2G is that velocity, not a change of the liquid's */
        for (long f = 0; f < nf; f++) {
            v0[f] = L->valid[a][f] && !L->shut[a][f];
            d0[f] = v0[f] ? g->f[a][f] - L->uold[a][f] : 0.0;
        }
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
                    double p = node_phi_at(L, nn[0], nn[1], nn[2]);
                    if (p < pmin) pmin = p;
                }
                if (!(pmin < g->dx)) continue;
                DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                int best = -1;
                double phi = INFINITY;
                DrVec3 n = dr_v3(0, 0, 0);
                for (int cc = 0; cc < L->nframes; cc++) {
                    double p = dr_collider_frame_phi(&L->frames[cc], x, NULL);
                    if (p < phi) { phi = p; best = cc; }
                }
                if (best < 0 || phi >= 0.5 * g->dx) continue;
                (void)dr_collider_frame_phi(&L->frames[best], x, &n); /* the gradient: six more samples */
                const DrColliderFrame *fr = &L->frames[best];
                DrVec3 vs = L->frame_body[best] >= 0 ? body_point_velocity(&L->bodies[L->frame_body[best]], x)
                                                     : dr_collider_frame_velocity(fr, x);
                DrVec3 vrel = dr_v3_sub(face_full_velocity(L, a, i, j, (int)k), vs);
                double before = g->f[a][f];
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
                if (L->frame_body[best] >= 0) {
                    L->bimp[a][f] += L->fm[a][f] * (g->f[a][f] - before);
                    L->bwho[a][f] = (signed char)L->frame_body[best];
                }
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
    const double *open = L->cpl->open[a], *vs = L->cpl->velocity[a];
    long cstride = a == 0 ? 1 : (a == 1 ? g->nx : (long)g->nx * g->ny);
    int n = a == 0 ? g->nx : (a == 1 ? g->ny : g->nz);
    double inv_rho_dx2 = 1.0 / (L->d.density * g->dx * g->dx);
    for (long k = begin; k < end; k++) {
        double P = 0.0, Lx = 0.0, Ly = 0.0, Lz = 0.0, gain = 0.0, work = 0.0;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                if (vs[f] != 0.0 && open[f] < 1.0) {
                    /* the blocked part of the face moves at vs into the cell above it and out of the one below:
                       the pressure there does the work (1 − w) vs Δx² (p_hi − p_lo) Δt, Δt p = ρ q (×ρΔx² below) */
                    int ijk[3] = {i, j, (int)k};
                    long chi = ijk[a] < n ? dr_mac_cell_index(g, i, j, (int)k) : -1;
                    long clo = ijk[a] > 0 ? (ijk[a] < n ? chi - cstride : dr_mac_cell_index(g, i, j, (int)k) - cstride) : -1;
                    double qhi = chi >= 0 && L->row[chi] >= 0 ? L->q[L->row[chi]] : 0.0;
                    double qlo = clo >= 0 && L->row[clo] >= 0 ? L->q[L->row[clo]] : 0.0;
                    work += (1.0 - open[f]) * vs[f] * (qhi - qlo);
                }
                if (m[f] == 0.0) continue;
                /* the collider velocity constraint after the projection (slip, friction, no-slip) moved the face from
                   tmp to u: its impulse times the solid's velocity, scaled back by 1/(ρΔx²) like the term above */
                if (vs[f] != 0.0 && L->nframes > 0) work += m[f] * (u[f] - L->tmp[a][f]) * vs[f] * inv_rho_dx2;
                double gf = fabs(u[f]) - fabs(u0[f]);
                if (!(gf <= gain)) gain = gf; /* NaN propagates */
                double mu = m[f] * (u[f] - u0[f]);
                DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                DrVec3 e = dr_v3(a == 0 ? mu : 0, a == 1 ? mu : 0, a == 2 ? mu : 0);
                DrVec3 t = dr_v3_cross(x, e);
                P += mu;
                Lx += t.x; Ly += t.y; Lz += t.z;
            }
        double *out = ctx->partial + IMPULSE_PARTS * k;
        out[0] = P; out[1] = Lx; out[2] = Ly; out[3] = Lz; out[4] = gain; out[5] = work;
    }
}

/* Also sets L->accel, the CFL's acceleration a⁺ for the next substep: the largest gain of |u_a| of a face
   with mass in this substep divided by Δt, combined over the components as a vector (decelerations do
   not move a particle further, so they do not count). */
static void grid_impulse(DrLiquid *L, double dt, DrLiquidStats *stats)
{
    const DrMacGrid *g = L->g;
    double gain2 = 0.0, work = 0.0;
    for (int a = 0; a < 3; a++) {
        ImpulseCtx ctx = {L, a, L->impulse_partial};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), impulse_slices, &ctx);
        double P = 0.0, gain = 0.0;
        DrVec3 Lm = dr_v3(0, 0, 0);
        for (int k = 0; k < g->fdim[a][2]; k++) {
            const double *p = L->impulse_partial + IMPULSE_PARTS * k;
            P += p[0];
            Lm = dr_v3_add(Lm, dr_v3(p[1], p[2], p[3]));
            if (!(p[4] <= gain)) gain = p[4];
        }
        gain2 += gain * gain;
        for (int k = 0; k < g->fdim[a][2]; k++) work += L->impulse_partial[IMPULSE_PARTS * k + 5];
        double *lin = a == 0 ? &stats->grid_linear_impulse.x : (a == 1 ? &stats->grid_linear_impulse.y
                                                                         : &stats->grid_linear_impulse.z);
        *lin += P;
        stats->grid_angular_impulse = dr_v3_add(stats->grid_angular_impulse, Lm);
    }
    L->accel = sqrt(gain2) / dt;
    /* the work of the last projection's sources, J: the moving solids' faces (impulse_slices: their pressure and their
       velocity constraint) and the volume correction's divergence target D in compressed cells, p D Δx³ Δt =
       ρ q (Δx·D) Δx² (pressure_row) */
    for (long r = 0; r < L->nrow && L->d.volume_correction > 0.0; r++)
        work += L->q[r] * volume_target(L, L->cells_of_row[r]);
    stats->source_work += L->d.density * g->dx * g->dx * work;
}

/* Largest face speed after P2G per component (faces with mass), combined as a vector: the bound of every
   particle's speed after G2P (its velocity components are convex combinations of face values). NaN
   propagates. */
typedef struct SpeedCtx { const DrLiquid *L; int a; double *partial; } SpeedCtx;

static void grid_speed_slices(long begin, long end, void *vctx)
{
    SpeedCtx *ctx = vctx;
    const DrLiquid *L = ctx->L;
    const int *dim = L->g->fdim[ctx->a];
    const double *m = L->fm[ctx->a], *u = L->g->f[ctx->a];
    for (long k = begin; k < end; k++) {
        double mx = 0.0, lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = i + (long)dim[0] * (j + (long)dim[1] * k);
                if (!(m[f] > 0.0)) continue;
                if (!(fabs(u[f]) <= mx)) mx = fabs(u[f]);
                lo[0] = fmin(lo[0], i); hi[0] = fmax(hi[0], i);
                lo[1] = fmin(lo[1], j); hi[1] = fmax(hi[1], j);
            }
        double *out = ctx->partial + IMPULSE_PARTS * k;
        out[0] = mx; out[1] = lo[0]; out[2] = hi[0]; out[3] = lo[1]; out[4] = hi[1];
    }
}

/* Also sets *lo, *hi to the world box of the faces with mass (the liquid and the kernel's reach around
   it; an empty box when there is none). */
static double grid_speed(const DrLiquid *L, DrVec3 *lo, DrVec3 *hi)
{
    const DrMacGrid *g = L->g;
    double s2 = 0.0, ilo[3] = {INFINITY, INFINITY, INFINITY}, ihi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int a = 0; a < 3; a++) {
        SpeedCtx ctx = {L, a, L->impulse_partial};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), grid_speed_slices, &ctx);
        double mx = 0.0;
        for (int k = 0; k < g->fdim[a][2]; k++) {
            const double *p = L->impulse_partial + IMPULSE_PARTS * k;
            if (!(p[0] <= mx)) mx = p[0];
            if (a == 1 && p[1] <= p[2]) { /* v faces: node j is at y = j·Δx, i and k at cell centres */
                ilo[0] = fmin(ilo[0], p[1] + 0.5); ihi[0] = fmax(ihi[0], p[2] + 0.5);
                ilo[1] = fmin(ilo[1], p[3]); ihi[1] = fmax(ihi[1], p[4]);
                ilo[2] = fmin(ilo[2], k + 0.5); ihi[2] = fmax(ihi[2], k + 0.5);
            }
        }
        s2 += mx * mx;
    }
    *lo = dr_v3_add(g->origin, dr_v3_scale(dr_v3(ilo[0], ilo[1], ilo[2]), g->dx));
    *hi = dr_v3_add(g->origin, dr_v3_scale(dr_v3(ihi[0], ihi[1], ihi[2]), g->dx));
    return sqrt(s2);
}

/* The largest surface speed in [t0, t1] of a collider whose box (padded by two cells) meets the box
   [lo, hi]: at each of three times (just after t0, the middle, just before t1: keyed motion is linear
   between keys and its rate is that of the interval, 0 exactly at a first key) the speed at the box's
   centre plus |ω| times its half diagonal, a bound for every point of it. */
static double collider_speed(const DrLiquid *L, const DrCollider *const *colliders, int n, double t0, double t1,
                             DrVec3 lo, DrVec3 hi)
{
    double mx = 0.0;
    DrVec3 pad = dr_v3(2 * L->g->dx, 2 * L->g->dx, 2 * L->g->dx);
    for (int c = 0; c < n; c++)
        for (int q = 0; q < 3; q++) {
            double t = t0 + (t1 - t0) * (q == 0 ? 1e-6 : (q == 1 ? 0.5 : 1.0 - 1e-6));
            DrColliderFrame f = dr_collider_frame(colliders[c], t);
            if (!(dr_v3_norm(f.lin_vel) > 0.0) && !(dr_v3_norm(f.omega) > 0.0)) continue;
            DrVec3 blo, bhi;
            dr_collider_frame_bounds(&f, &blo, &bhi);
            blo = dr_v3_sub(blo, pad);
            bhi = dr_v3_add(bhi, pad);
            if (!(blo.x <= hi.x && lo.x <= bhi.x && blo.y <= hi.y && lo.y <= bhi.y && blo.z <= hi.z && lo.z <= bhi.z))
                continue;
            DrVec3 ctr = dr_v3_scale(dr_v3_add(blo, bhi), 0.5);
            double sp = dr_v3_norm(dr_collider_frame_velocity(&f, ctr)) +
                        dr_v3_norm(f.omega) * 0.5 * dr_v3_norm(dr_v3_sub(bhi, blo));
            if (sp > mx) mx = sp;
        }
    return mx;
}

/* ---- 9. particles: advection, push-out, clamp -------------------------------------------------------- */

typedef struct AdvCtx {
    DrLiquid *L;
    double dt;
    DrVec3 blo[MAX_COLLIDERS_FRAME], bhi[MAX_COLLIDERS_FRAME]; /* each collider's SDF box at this pose */
} AdvCtx;

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
            if (!in_box(xp, ctx->blo[c], ctx->bhi[c])) continue; /* outside its SDF box phi > 0 */
            for (int it = 0; it < 24; it++) {
                DrVec3 n;
                if (dr_collider_frame_phi(fr, xp, NULL) >= 0.0) break; /* the gradient costs six more samples */
                double phi = dr_collider_frame_phi(fr, xp, &n);
                /* remove the inward relative velocity, then push out along ∇φ a little beyond the surface;
                   components of ∇φ that point out of the domain at a wall the particle touches are dropped
                   (a collider standing on the floor pushes sideways or up, never through the wall) */
                int body = L->frame_body[c];
                DrVec3 vs = body >= 0 ? body_point_velocity(&L->bodies[body], xp) : dr_collider_frame_velocity(fr, xp);
                double vn = dr_v3_dot(dr_v3_sub(vp, vs), n);
                if (vn < 0.0) {
                    vp = dr_v3_sub(vp, dr_v3_scale(n, vn));
                    if (body >= 0) { /* the body takes what the particle lost (body_pushout_impulses) */
                        for (int d = 0; d < 3; d++) L->pdv[3 * p + d] -= dr_v3_get(n, d) * vn;
                        L->pwho[p] = (signed char)body;
                    }
                }
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

/* ½ m |v|² − m g·x of particle p, J */
static double particle_energy(const DrLiquid *L, long p)
{
    const double *x = L->st.x + 3 * p, *v = L->st.v + 3 * p;
    DrVec3 g = L->d.gravity;
    return particle_mass(L, p) * (0.5 * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) - (g.x * x[0] + g.y * x[1] + g.z * x[2]));
}

static void kill(DrLiquid *L, DrLiquidStats *stats)
{
    if (L->d.nkill_boxes == 0) return;
    long w = 0, n = L->st.n;
    for (long p = 0; p < n; p++) {
        DrVec3 x = dr_v3(L->st.x[3 * p], L->st.x[3 * p + 1], L->st.x[3 * p + 2]);
        bool dead = false;
        for (int b = 0; b < L->d.nkill_boxes && !dead; b++) dead = in_box(x, L->kill_lo[b], L->kill_hi[b]);
        if (dead) {
            stats->killed_energy += particle_energy(L, p);
            stats->killed_volume += L->st.vol[p];
            continue;
        }
        if (w != p) move_particle(L, p, w);
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
        if (L->scaled) L->svol[q] = L->st.vol[p];
        L->sid[q] = L->st.id[p];
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
    if (L->scaled) { t = L->st.vol; L->st.vol = L->svol; L->svol = t; } /* else every value is V0: no need to move */
    int64_t *ti = L->st.id; L->st.id = L->sid; L->sid = ti;
}


/* 1. P2G: particles sorted by cell, then splatted; uold keeps the transferred face velocities. The particles' mass
   factors vol/V0 go to pscale (and the substep's level set counts them) only when some particle is not nominal. */
static DrStatus substep_p2g(DrLiquid *L, DrError *err)
{
    DrMacGrid *g = L->g;
    DrLiquidState *s = &L->st;
    double t_0 = dr_time_now();
    DR_TRY(dr_bins_build(g, s->n, s->x, L->bins, err));
    L->scaled = !all_nominal(L);
    sort_particles(L);
    if (L->scaled)
        for (long p = 0; p < s->n; p++) L->pscale[p] = s->vol[p] / L->vol0;
    L->retransfer = false;
    dr_transfer_p2g_mac(L->bins, s->x, s->v, L->d.scheme == DR_TRANSFER_APIC ? s->c : NULL, L->pmass,
                        L->scaled ? L->pscale : NULL, L->d.wall_no_slip, g, L->fm);
    for (int a = 0; a < 3; a++) memcpy(L->uold[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
    L->pend_p2g += dr_time_now() - t_0;
    return DR_OK;
}

/* The implicit viscosity step (viscosity.h) of a substep over dt, after the boundary conditions: the cells' liquid
   fractions from their particle counts (as the free surface's count_phi: the count over what the open part of the
   cell holds when full), closed faces at the colliders' velocities. */
static DrStatus implicit_viscosity(DrLiquid *L, double dt, bool count, DrError *err)
{
    DrMacGrid *g = L->g;
    if (!L->visc) DR_TRY(dr_viscosity_create(&L->visc, err));
    if (!L->vfill) DR_TRY(dr_calloc((size_t)L->ncells, sizeof(float), &L->vfill, err));
    for (long c = 0; c < L->ncells; c++) {
        double om = fmax((double)L->open[c], 1.0 / L->d.per_cell);
        double frac = cell_count(L, c) / (L->d.per_cell * om);
        L->vfill[c] = (float)(frac > 1.0 ? 1.0 : frac);
    }
    DrViscosityInput in = {.g = g,
                           .mass = {L->fm[0], L->fm[1], L->fm[2]},
                           .open = {L->own.open[0], L->own.open[1], L->own.open[2]},
                           .velocity = {L->own.velocity[0], L->own.velocity[1], L->own.velocity[2]},
                           .fill = L->vfill,
                           .mu = L->d.viscosity,
                           .dt = dt,
                           .no_slip = L->d.wall_no_slip,
                           .tolerance = L->d.pressure_tol,
                           .max_iterations = L->d.pressure_max_iter};
    DrViscosityStats vs;
    DR_TRY(dr_viscosity_solve(L->visc, &in, &vs, err));
    if (count) L->pend_visc_iterations += vs.iterations;
    if (!vs.converged && count) {
        L->pend_visc_not_converged++;
        dr_log_warn("liquid: the viscosity solve stopped at solver.pressure_max_iterations = %d with relative residual "
                    "%.3e (tolerance solver.pressure_tolerance = %.1e); the step is kept", vs.iterations,
                    vs.rel_residual, L->d.pressure_tol);
    }
    return DR_OK;
}

/* 2.–3. of a substep from t to t + dt, after substep_p2g: the colliders posed at t + dt, the forces, the
   colliders' face coupling (own) and the cells' open fractions. Viscosity: explicit ν∇²u while νΔt/Δx² ≤ 1/6 (its
   stability limit), else the implicit solve after the boundary conditions (implicit_viscosity). */
static DrStatus grid_begin(DrLiquid *L, const DrCollider *const *colliders, int ncolliders, double t, double dt,
                           bool count, DrError *err)
{
    DrMacGrid *g = L->g;
    double t_1 = dr_time_now();
    L->nframes = ncolliders;
    for (int c = 0; c < ncolliders; c++) L->frames[c] = dr_collider_frame(colliders[c], t + dt);
    for (int c = 0; c < MAX_COLLIDERS_FRAME; c++) L->frame_body[c] = -1;
    L->nbodies = 0; /* dr_liquid_set_bodies gives the substep's */

    /* 2. forces: gravity, then explicit viscosity within its stability limit */
    for (int a = 0; a < 3; a++) {
        FaceCtx fc = {L, a, dt, 0.0};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), gravity_slices, &fc);
    }
    double nu = L->d.viscosity / L->d.density;
    double alpha = nu * dt / (g->dx * g->dx);
    bool implicit = alpha > (1.0 / 6.0) * (1.0 - 1e-9);
    if (nu > 0.0 && !implicit) {
        for (int a = 0; a < 3; a++) {
            memcpy(L->tmp[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
            FaceCtx fc = {L, a, dt, alpha};
            dr_parallel_for(g->fdim[a][2], slice_grain(g, a), viscosity_slices, &fc);
        }
    }

    /* 3. boundary conditions: walls and collider face fractions, the cells' open fractions */
    BcCtx bctx = {L, 0};
    if (L->nframes > 0) node_phi(L);
    for (int a = 0; a < 3; a++) run_faces(L, weight_slices, a);
    long cgrain = (PAR_MIN_ITEMS + (long)g->nx * g->ny - 1) / ((long)g->nx * g->ny);
    dr_parallel_for(g->nz, cgrain, open_slices, &bctx);
    if (L->nframes > 0 && L->d.pressure == DR_PRESSURE_MASS_WEIGHTED)
        dr_parallel_for(g->nz, cgrain, near_slices, &bctx);
    if (nu > 0.0 && implicit) {
        double t_v = dr_time_now();
        DR_TRY(implicit_viscosity(L, dt, count, err));
        if (count) L->pend_visc_seconds += dr_time_now() - t_v;
    }
    L->pend_other += dr_time_now() - t_1;
    return DR_OK;
}

/* What setting a body's velocity on faces gave the liquid (blocked and shut faces in the projection, the collider
   constraint), taken from the body: its impulse and velocity lose it, so liquid and body together keep their momentum.
   Serial over the faces in order: the same bits for any thread count. */
static void body_constraint_impulses(DrLiquid *L)
{
    const DrMacGrid *g = L->g;
    for (int b = 0; b < L->nbodies; b++) {
        DrLiquidBody *B = &L->bodies[b];
        double J[6] = {0};
        for (int a = 0; a < 3; a++) {
            const int *dim = g->fdim[a];
            for (int k = 0; k < dim[2]; k++)
                for (int j = 0; j < dim[1]; j++)
                    for (int i = 0; i < dim[0]; i++) {
                        long f = dr_mac_face_index(g, a, i, j, k);
                        if (L->bwho[a][f] != b || L->bimp[a][f] == 0.0) continue;
                        DrVec3 x = dr_mac_face_position(g, a, i, j, k);
                        double r[3] = {x.x - B->center[0], x.y - B->center[1], x.z - B->center[2]};
                        double row[6];
                        face_row(a, r, row);
                        for (int q = 0; q < 6; q++) J[q] += L->bimp[a][f] * row[q];
                    }
        }
        body_take(B, J);
    }
}

/* The momentum the extrapolation gives the faces with liquid mass that a body owns and the projection left
   (sign −1 before it, +1 after): the body loses it too (body_constraint_impulses). */
static void body_extrapolated(DrLiquid *L, double sign)
{
    const DrMacGrid *g = L->g;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            int b = face_body(L, a, f);
            if (b < 0 || L->valid[a][f] || !(L->fm[a][f] > 0.0)) continue;
            L->bimp[a][f] += sign * L->fm[a][f] * g->f[a][f];
            L->bwho[a][f] = (signed char)b;
        }
}

/* The velocity the push-out took from particles leaving a body (their inward velocity relative to it), taken from the
   body as well; serial over the particles in order (their positions after the push-out as the lever arms). */
static void body_pushout_impulses(DrLiquid *L)
{
    const DrLiquidState *st = &L->st;
    for (int b = 0; b < L->nbodies; b++) {
        DrLiquidBody *B = &L->bodies[b];
        double J[6] = {0};
        for (long p = 0; p < st->n; p++) {
            if (L->pwho[p] != b) continue;
            double mp = particle_mass(L, p);
            double m[3] = {mp * L->pdv[3 * p], mp * L->pdv[3 * p + 1], mp * L->pdv[3 * p + 2]};
            double r[3] = {st->x[3 * p] - B->center[0], st->x[3 * p + 1] - B->center[1], st->x[3 * p + 2] - B->center[2]};
            J[0] += m[0], J[1] += m[1], J[2] += m[2];
            J[3] += r[1] * m[2] - r[2] * m[1];
            J[4] += r[2] * m[0] - r[0] * m[2];
            J[5] += r[0] * m[1] - r[1] * m[0];
        }
        body_take(B, J);
    }
}

/* 4.–6. of a substep, after grid_begin: the pressure projection with the coupling `extra` added to the
   colliders' (NULL: theirs alone), the extrapolation of the grid change, the collider velocity constraint
   (domain walls stay at rest). */
static DrStatus grid_project(DrLiquid *L, const DrFaceCoupling *extra, DrLiquidStats *stats, DrError *err)
{
    DrMacGrid *g = L->g;
    double t_2 = dr_time_now();
    L->added = dr_v3(0, 0, 0);
    L->drag_added = dr_v3(0, 0, 0);
    L->porous_on = false;
    L->soft_on = false;
    L->soft_gain = dr_v3(0, 0, 0);
    L->sample_ok = false;
    L->cpl = &L->own;
    if (extra) {
        DR_TRY(mix_coupling(L, extra, err));
        L->cpl = &L->mix;
    }

    if (L->nbodies > 0)
        for (int a = 0; a < 3; a++) {
            if (!L->bimp[a]) {
                DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &L->bimp[a], err));
                DR_TRY(dr_calloc((size_t)g->nfaces[a], 1, &L->bwho[a], err));
            }
            memset(L->bimp[a], 0, (size_t)g->nfaces[a] * sizeof(double));
            memset(L->bwho[a], 0xff, (size_t)g->nfaces[a]);
        }

    /* 4. pressure projection */
    DR_TRY(pressure_solve(L, extra, stats, err));
    for (int a = 0; a < 3; a++) run_faces(L, project_slices, a);
    if (extra && L->porous_on) drag_sum(L, extra);
    if (L->soft_on) soft_sum(L);
    stats->divergence_mean = divergence_mean(L, stats->liquid_cells);
    double t_3 = dr_time_now();
    stats->seconds_pressure += t_3 - t_2;

    /* 5. extrapolation; 6. collider velocity constraint */
    if (L->nbodies > 0) body_extrapolated(L, -1.0);
    extrapolate(L);
    if (L->nbodies > 0) body_extrapolated(L, 1.0);
    if (L->nframes > 0) {
        for (int a = 0; a < 3; a++) memcpy(L->tmp[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
        for (int a = 0; a < 3; a++) run_faces(L, collider_slices, a);
    }
    if (L->nbodies > 0) body_constraint_impulses(L);
    L->sample_ok = true;
    stats->seconds_other += dr_time_now() - t_3;
    return DR_OK;
}

/* CFL step ([APIC] §4.3): no particle should travel more than cfl·Δx in a step. The paper bounds the
   grid velocity after P2G by max_p(|v_p| + (6√d/Δx)‖B_p‖_F); the grid velocity U itself is the tighter
   bound it majorises (G2P makes every particle's velocity a convex combination of face values), and it
   does not let one particle with a large affine matrix — one pressed against a collider — shrink the step
   of the whole liquid. What the step itself adds is the usual √(5Δx|g|) (the speed gained by falling 2.5
   cells), but with the part of gravity the liquid actually follows: Δt ≤ cfl·Δx/(U + √(5Δx·min(a⁺, |g|))),
   a⁺ the largest speed gain per second of a face in the last substep (grid_impulse). Still water, which the
   pressure holds against gravity, has U = a⁺ = 0 and takes whole frames; falling and splashing water takes
   the steps the constant term always gave it (larger steps cost volume: the quadratic bound
   (U + a⁺Δt)Δt ≤ cfl·Δx lost 6.0 % of a dam break in 2 s against 4.7 %, test_world). Accelerations
   beyond gravity's (impacts, jets) are left to U at the next substep, as with the constant term. */
static double cfl_step(const DrLiquid *L, double umax)
{
    double den = umax + sqrt(5.0 * L->g->dx * fmin(L->accel, dr_v3_norm(L->d.gravity)));
    return den > 0.0 ? L->d.cfl * L->g->dx / den : INFINITY;
}

/* The interval [t0, t1] the substeps land on: its duration is the volume correction's T, and max_substeps
   counts the substeps in it. */
static void interval_start(DrLiquid *L, double t0, double t1)
{
    L->ival_t0 = t0;
    L->ival_t1 = t1;
    L->ival_substeps = 0;
    L->ival_warned = false;
    L->span = t1 > t0 ? t1 - t0 : 1.0;
}

/* The next substep's length from t in the open interval (liquid.h: dr_liquid_stable_dt), after P2G. */
static DrStatus stable_step(DrLiquid *L, const DrCollider *const *colliders, int ncolliders, double t, double *h,
                            DrError *err)
{
    double t1 = L->ival_t1;
    L->phase = PHASE_IDLE;
    L->sample_ok = false;
    DR_TRY(substep_p2g(L, err));
    DrVec3 llo, lhi;
    double umax = grid_speed(L, &llo, &lhi);
    /* a collider moving through the liquid moves it at its own speed within this substep: a step the
       liquid's own speed allows could carry the collider across cells the pressure never sees it in */
    umax = fmax(umax, collider_speed(L, colliders, ncolliders, t, t1, llo, lhi));
    if (!L->accel_known && isfinite(umax)) {
        /* the first substep of a liquid: a⁺ of the initial state, from a trial of the grid phases over
           the step gravity alone would allow, then discarded (the grid is transferred again) */
        DrLiquidStats trial;
        memset(&trial, 0, sizeof trial);
        L->accel = dr_v3_norm(L->d.gravity);
        double ht = fmin(cfl_step(L, umax), t1 - t);
        DR_TRY(grid_begin(L, colliders, ncolliders, t, ht, false, err));
        DR_TRY(grid_project(L, NULL, &trial, err));
        grid_impulse(L, ht, &trial);
        L->sample_ok = false;
        DR_TRY(substep_p2g(L, err));
    }
    L->accel_known = true;
    if (!isfinite(umax) || !isfinite(L->accel))
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "liquid: velocities became non-finite at t = %g s; lower cfl or raise max_substeps.", t);
    double dt = cfl_step(L, umax); /* viscosity takes any step: explicit within its limit, else implicit */
    double remaining = t1 - t;
    double nneed = ceil(remaining / dt);
    int left = L->d.max_substeps - L->ival_substeps;
    bool clamped = false;
    if (!(nneed <= left)) {
        nneed = left;
        clamped = true;
        if (!L->ival_warned) {
            dr_log_warn("liquid: the CFL condition needs more than max_substeps = %d substeps in [%g, %g] s; "
                        "clamping (raise solver.max_substeps for accuracy)", L->d.max_substeps, L->ival_t0, t1);
            L->ival_warned = true;
        }
    }
    if (nneed < 1) nneed = 1;
    dt = remaining / nneed;
    L->t_step = t;
    L->h_stable = dt;
    L->step_lands = nneed <= 1;
    L->step_clamped = clamped;
    L->phase = PHASE_READY;
    *h = dt;
    return DR_OK;
}

/* 2.–3. from t over h, after stable_step at t; keep: save the velocities the projection starts from. */
static DrStatus step_begin(DrLiquid *L, const DrCollider *const *colliders, int ncolliders, double t, double h,
                           bool keep, DrError *err)
{
    DR_TRY(grid_begin(L, colliders, ncolliders, t, h, true, err));
    L->t_step = t;
    L->h_step = h;
    L->nproj = 0;
    if (keep) {
        double t_0 = dr_time_now();
        for (int a = 0; a < 3; a++) memcpy(L->ustar[a], L->g->f[a], (size_t)L->g->nfaces[a] * sizeof(double));
        L->pend_other += dr_time_now() - t_0;
    }
    L->phase = PHASE_BEGUN;
    return DR_OK;
}

/* 4.–6.; from the second call on, from the velocities step_begin saved. */
static DrStatus step_project(DrLiquid *L, const DrFaceCoupling *extra, DrLiquidStats *stats, DrError *err)
{
    if (L->nproj++ > 0) {
        assert(L->ustar[0]);
        for (int a = 0; a < 3; a++) memcpy(L->g->f[a], L->ustar[a], (size_t)L->g->nfaces[a] * sizeof(double));
    }
    L->phase = PHASE_BEGUN;
    DR_TRY(grid_project(L, extra, stats, err));
    L->phase = PHASE_PROJECTED;
    return DR_OK;
}

static void report_particles(const DrLiquid *L, DrLiquidStats *stats)
{
    stats->particles = L->st.n;
    double vmax = 0.0;
    for (long p = 0; p < L->st.n; p++) {
        const double *v = L->st.v + 3 * p;
        double sp = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if (sp > vmax) vmax = sp;
    }
    stats->max_speed = vmax;
}

/* 7.–10. of the substep, after step_project: the grid impulse and a⁺ from the projected grid, G2P,
   advection, push-out, emitters, kill boxes. */
static DrStatus step_end(DrLiquid *L, DrLiquidStats *stats, bool report, DrError *err)
{
    DrMacGrid *g = L->g;
    DrLiquidState *s = &L->st;
    double t_4 = dr_time_now();
    grid_impulse(L, L->h_step, stats);
    stats->added_impulse = dr_v3_add(stats->added_impulse, L->added);
    stats->drag_impulse = dr_v3_add(stats->drag_impulse, L->drag_added);
    stats->solid_gain = dr_v3_add(stats->solid_gain, L->soft_gain);
    stats->seconds_p2g += L->pend_p2g;
    stats->seconds_other += L->pend_other;
    stats->viscosity_iterations += L->pend_visc_iterations;
    stats->viscosity_not_converged += L->pend_visc_not_converged;
    stats->seconds_viscosity += L->pend_visc_seconds;
    L->pend_p2g = L->pend_other = L->pend_visc_seconds = 0.0;
    L->pend_visc_iterations = 0;
    L->pend_visc_not_converged = 0;
    double t_5 = dr_time_now();
    stats->seconds_other += t_5 - t_4;

    /* 7. G2P */
    dr_transfer_g2p_mac(g, (const double *const *)L->uold, L->d.scheme, L->d.flip_blend, L->d.wall_no_slip, s->n,
                        s->x, s->v, s->c);
    double t_6 = dr_time_now();
    stats->seconds_g2p += t_6 - t_5;

    /* 8. advection x += Δt v^{n+1} ([APIC] §5.3), push-out, clamp */
    AdvCtx actx;
    actx.L = L;
    actx.dt = L->h_step;
    for (int c = 0; c < L->nframes; c++) dr_collider_frame_bounds(&L->frames[c], &actx.blo[c], &actx.bhi[c]);
    if (L->nbodies > 0) {
        if (s->n > L->pcap) {
            long cap = s->n + s->n / 4 + 1024;
            DR_TRY(dr_realloc((size_t)cap * 3, sizeof(double), &L->pdv, err));
            DR_TRY(dr_realloc((size_t)cap, 1, &L->pwho, err));
            L->pcap = cap;
        }
        memset(L->pdv, 0, (size_t)s->n * 3 * sizeof(double));
        memset(L->pwho, 0xff, (size_t)s->n);
    }
    dr_parallel_for(s->n, L->nframes > 0 ? 2048 : PAR_MIN_ITEMS, advect_range, &actx);
    if (L->nbodies > 0) body_pushout_impulses(L);
    double t_7 = dr_time_now();
    stats->seconds_advect += t_7 - t_6;

    /* 9. emitters, kill boxes */
    long n_before = s->n;
    DR_TRY(emit(L, L->t_step, stats, err));
    for (long p = n_before; p < s->n; p++) {
        stats->emitted_energy += particle_energy(L, p);
        stats->emitted_volume += s->vol[p];
    }
    kill(L, stats);
    stats->seconds_other += dr_time_now() - t_7;
    stats->substeps++;
    L->ival_substeps++;
    L->phase = PHASE_IDLE;
    if (report) report_particles(L, stats);
    return DR_OK;
}

static DrStatus check_colliders(int ncolliders, DrError *err)
{
    if (ncolliders < 0 || ncolliders > MAX_COLLIDERS_FRAME)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid: between 0 and %d colliders.", MAX_COLLIDERS_FRAME);
    return DR_OK;
}

DrStatus dr_liquid_advance(DrLiquid *liq, const DrCollider *const *colliders, int ncolliders, double t0, double t1,
                           DrLiquidStats *stats, DrError *err)
{
    memset(stats, 0, sizeof *stats);
    DR_TRY(check_colliders(ncolliders, err));
    if (!(t1 >= t0) || !isfinite(t0) || !isfinite(t1))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "liquid advance: t1 (%g) must not precede t0 (%g).", t1, t0);
    interval_start(liq, t0, t1);
    double t = t0;
    while (t < t1) {
        double dt;
        DR_TRY(stable_step(liq, colliders, ncolliders, t, &dt, err));
        bool last = liq->step_lands;
        DR_TRY(step_begin(liq, colliders, ncolliders, t, dt, false, err));
        DR_TRY(step_project(liq, NULL, stats, err));
        DR_TRY(step_end(liq, stats, false, err));
        t = last ? t1 : t + dt;
    }
    report_particles(liq, stats);
    return DR_OK;
}

/* ---- the substep in phases (liquid.h) ---------------------------------------------------------------- */

DrStatus dr_liquid_stable_dt(DrLiquid *liq, const DrCollider *const *colliders, int ncolliders, double t,
                             double t_end, double *h, DrError *err)
{
    *h = 0.0;
    DR_TRY(check_colliders(ncolliders, err));
    if (!isfinite(t) || !isfinite(t_end) || !(t_end > t))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "liquid stable_dt: t_end (%g) must be finite and after t (%g).", t_end, t);
    if (!(t_end == liq->ival_t1) || !(t >= liq->ival_t0)) interval_start(liq, t, t_end);
    return stable_step(liq, colliders, ncolliders, t, h, err);
}

DrStatus dr_liquid_begin(DrLiquid *liq, const DrCollider *const *colliders, int ncolliders, double t, double h,
                         DrError *err)
{
    assert(liq->phase == PHASE_READY && t == liq->t_step); /* dr_liquid_stable_dt(t) first */
    DR_TRY(check_colliders(ncolliders, err));
    /* a clock that lands on another solver's step end may ask for a rounding error more than the stable step */
    if (!(h > 0.0) || !(h <= liq->h_stable * (1.0 + 1e-9)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "liquid begin: h (%g s) must be positive and at most the stable step %g s.", h,
                            liq->h_stable);
    for (int a = 0; a < 3; a++)
        if (!liq->ustar[a]) DR_TRY(dr_calloc((size_t)liq->g->nfaces[a], sizeof(double), &liq->ustar[a], err));
    if (liq->retransfer) DR_TRY(substep_p2g(liq, err)); /* particles added or removed since stable_dt */
    DR_TRY(step_begin(liq, colliders, ncolliders, t, h, true, err));
    return DR_OK;
}

DrStatus dr_liquid_project(DrLiquid *liq, const DrFaceCoupling *extra, DrLiquidStats *stats, DrError *err)
{
    assert(liq->phase == PHASE_BEGUN || liq->phase == PHASE_PROJECTED); /* dr_liquid_begin first */
    return step_project(liq, extra, stats, err);
}

DrStatus dr_liquid_end(DrLiquid *liq, DrLiquidStats *stats, DrError *err)
{
    assert(liq->phase == PHASE_PROJECTED); /* dr_liquid_project first */
    return step_end(liq, stats, true, err);
}

/* The trilinear stencil at world position x on the lattice of cell centres, clamped to it: cells idx[axis][0..1] with
   weights w[axis][0..1]. */
static void cell_stencil(const DrLiquid *L, DrVec3 x, int idx[3][2], double w[3][2])
{
    const DrMacGrid *g = L->g;
    int n[3] = {g->nx, g->ny, g->nz};
    for (int d = 0; d < 3; d++) {
        double s = (dr_v3_get(x, d) - dr_v3_get(g->origin, d)) / g->dx - 0.5;
        int hi = n[d] - 1;
        if (s < 0.0) s = 0.0;
        if (s > hi) s = hi;
        DrStencil2 st = dr_kernel_linear(s);
        idx[d][0] = st.base;
        idx[d][1] = st.base + 1 > hi ? hi : st.base + 1;
        w[d][0] = st.w[0];
        w[d][1] = st.w[1];
    }
}

/* Trilinear interpolation at world position x of the cell-centred pressure (p = ρq/Δt on pressure cells,
   0 elsewhere), clamped to the lattice of cell centres like dr_mac_sample_face. */
static double sample_pressure(const DrLiquid *L, DrVec3 x)
{
    const DrMacGrid *g = L->g;
    int idx[3][2];
    double w[3][2];
    cell_stencil(L, x, idx, w);
    double sum = 0.0;
    for (int kk = 0; kk < 2; kk++)
        for (int jj = 0; jj < 2; jj++)
            for (int ii = 0; ii < 2; ii++) {
                int r = L->row[dr_mac_cell_index(g, idx[0][ii], idx[1][jj], idx[2][kk])];
                if (r >= 0) sum += w[0][ii] * w[1][jj] * w[2][kk] * L->q[r];
            }
    return sum * L->d.density / L->h_step;
}

/* The same over the pressure cells alone, renormalised by their weight (dr_liquid_sample_wet_pressure). */
static double sample_wet_pressure(const DrLiquid *L, DrVec3 x, double *wet)
{
    const DrMacGrid *g = L->g;
    int idx[3][2];
    double w[3][2];
    cell_stencil(L, x, idx, w);
    double sum = 0.0, wsum = 0.0;
    for (int kk = 0; kk < 2; kk++)
        for (int jj = 0; jj < 2; jj++)
            for (int ii = 0; ii < 2; ii++) {
                int r = L->row[dr_mac_cell_index(g, idx[0][ii], idx[1][jj], idx[2][kk])];
                double ww = w[0][ii] * w[1][jj] * w[2][kk];
                if (r >= 0) {
                    sum += ww * L->q[r];
                    wsum += ww;
                }
            }
    *wet = wsum;
    return wsum > 0.0 ? sum / wsum * L->d.density / L->h_step : 0.0;
}

void dr_liquid_sample_wet_pressure(const DrLiquid *liq, long n, const double *points, double *pressure_out,
                                   double *wet_out)
{
    assert(liq->sample_ok);
    for (long i = 0; i < n; i++) {
        double wet;
        double p = sample_wet_pressure(liq, dr_v3(points[3 * i], points[3 * i + 1], points[3 * i + 2]), &wet);
        if (pressure_out) pressure_out[i] = p;
        if (wet_out) wet_out[i] = wet;
    }
}

typedef struct SampleCtx { const DrLiquid *L; const double *x; double *v, *p; } SampleCtx;

static void sample_range(long begin, long end, void *vctx)
{
    const SampleCtx *ctx = vctx;
    for (long i = begin; i < end; i++) {
        DrVec3 x = dr_v3(ctx->x[3 * i], ctx->x[3 * i + 1], ctx->x[3 * i + 2]);
        if (ctx->v)
            for (int a = 0; a < 3; a++) ctx->v[3 * i + a] = dr_mac_sample_face(ctx->L->g, a, x);
        if (ctx->p) ctx->p[i] = sample_pressure(ctx->L, x);
    }
}

void dr_liquid_sample(const DrLiquid *liq, long n, const double *points, double *vel_out, double *pressure_out)
{
    assert(liq->sample_ok); /* a projection since the last dr_liquid_stable_dt */
    SampleCtx ctx = {liq, points, vel_out, pressure_out};
    dr_parallel_for(n, 4096, sample_range, &ctx);
}
