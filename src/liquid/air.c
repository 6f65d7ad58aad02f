/* Air: a single-phase incompressible gas on a MAC grid with a wind inflow (liquid.h, "air"). The substep's
 * phases mirror the liquid's; every cell of the box is a pressure unknown unless colliders block it entirely. */
#include "liquid/liquid.h"

#include "linalg/linalg.h"

#include <stdlib.h>
#include <string.h>

#define MAX_COLLIDERS_FRAME 64
#define MAX_VISCOSITY_PARTS 8
/* Smallest number of faces or cells worth a parallel chunk (as the liquid's: a parallel region costs a fork and
   a barrier, small grids run serially). */
#define PAR_MIN_ITEMS 16384
/* Per z-slice partial sums of the projection's passes, added in slice order: the extra coupling's impulse taken,
   the drag's and the pressure's momentum, inflow and outflow volume flux, the largest |u_f|, a bad-input flag. */
enum { P_ADDED, P_DRAG, P_PRESS, P_IN, P_OUT, P_SPEED, P_BAD, PARTS };

/* What a face is: a velocity unknown inside the box, one on the open outflow face, a wall, the inflow face. */
enum { FACE_INNER, FACE_OUTFLOW, FACE_WALL, FACE_INFLOW };

enum { PHASE_IDLE, PHASE_READY, PHASE_BEGUN, PHASE_PROJECTED };

struct DrAir {
    DrAirDesc d;
    DrMacGrid *g;
    long ncells;
    bool closed;             /* the wind's normal component is 0: six walls, pure Neumann */
    double *fm[3];           /* m_f, kg: ρΔx³ on velocity unknowns, 0 on walls and the inflow face */
    unsigned char *take[3];  /* the faces that took the last extra coupling (m_f > 0, open); allocated with one */
    unsigned char *kind[3];  /* FACE_* */
    double *ustar[3];        /* the velocities every projection starts from (begin) */
    double *tmp[3];          /* advection and viscosity output */
    DrFaceCoupling own;      /* the colliders: open (walls 0), solid velocity; no impulse, no drag */
    DrFaceCoupling mix;      /* own combined with a projection's extra coupling */
    const DrFaceCoupling *cpl; /* &own or &mix for the current projection */
    double *coef[3];         /* c_f = m_f/(m_f + β_f) of the current projection (1 without drag) */
    double *wsol[3];         /* fraction of each face outside every collider (walls ignored): the cells' open volume */
    double *nphi;            /* collider-union phi at the grid nodes */
    int *row;                /* cell → pressure unknown, −1 if blocked */
    long *cells_of_row;
    int *row_ijk;            /* 3 per row: its cell (the multigrid preconditioner's geometry) */
    DrMg *mg;
    long nrow;
    DrCsr *A;
    DrMic0 *M;
    double *rhs, *q, *work;
    double *part;            /* PARTS per z-slice of faces (nz + 1 slices) */
    DrColliderFrame frames[MAX_COLLIDERS_FRAME];
    int nframes;
    double ival_t0, ival_t1; /* the interval the substeps land on (stable_dt); ival_t1 NaN: none */
    int ival_substeps;
    bool ival_warned, visc_warned;
    int phase;
    double t_step, h_step, h_stable;
    bool step_lands;
    /* the last projection's figures */
    DrVec3 added, drag, press;
    double flux_in, flux_out, div_max, speed_max;
    int visc_parts;
    double pend_advect, pend_other;
};

/* ---- set-up -------------------------------------------------------------------------------------------- */

void dr_air_desc_default(DrAirDesc *d)
{
    memset(d, 0, sizeof *d);
    d->domain_lo = dr_v3(0, 0, 0);
    d->domain_hi = dr_v3(1, 1, 1);
    d->dx = 1.0 / 32.0;
    d->density = 1.2;
    d->viscosity = 1.8e-5;
    d->inflow_axis = 0;
    d->inflow_side = 0;
    d->inflow_velocity = dr_v3(0, 0, 0);
    d->ramp = 0.0;
    d->initial_stream = false;
    d->cfl = 1.0;
    d->max_substeps = 64;
    d->pressure_tol = 1e-6;
    d->pressure_max_iter = 1000;
}

static long slice_grain(const DrMacGrid *g, int a) { return dr_mac_slice_grain(g, a, PAR_MIN_ITEMS); }

static inline long face_stride(const DrMacGrid *g, int a)
{
    return a == 0 ? 1 : (a == 1 ? g->fdim[1][0] : (long)g->fdim[2][0] * g->fdim[2][1]);
}

/* The wind at time t: the inflow velocity times the ramp's linear growth. */
static DrVec3 wind(const DrAir *A, double t)
{
    double s = A->d.ramp > 0.0 ? fmin(1.0, fmax(0.0, t / A->d.ramp)) : 1.0;
    return dr_v3_scale(A->d.inflow_velocity, s);
}

/* The wind's normal component as a face velocity on the inflow face (positive along +axis). */
static double inflow_normal(const DrAir *A, double t) { return dr_v3_get(wind(A, t), A->d.inflow_axis); }

static DrStatus check_desc(const DrAirDesc *d, DrError *err)
{
#define BAD(...) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, __VA_ARGS__)
    if (!dr_v3_isfinite(d->domain_lo) || !dr_v3_isfinite(d->domain_hi) || !(d->domain_hi.x > d->domain_lo.x) ||
        !(d->domain_hi.y > d->domain_lo.y) || !(d->domain_hi.z > d->domain_lo.z))
        BAD("air: the domain box must have hi > lo on every axis (finite).");
    if (!(d->dx > 0.0) || !isfinite(d->dx)) BAD("air: dx must be positive (got %g).", d->dx);
    if (!(d->density > 0.0) || !isfinite(d->density)) BAD("air: density must be positive (got %g kg/m^3).", d->density);
    if (!(d->viscosity >= 0.0) || !isfinite(d->viscosity))
        BAD("air: viscosity must be >= 0 (got %g Pa*s).", d->viscosity);
    if (d->inflow_axis < 0 || d->inflow_axis > 2) BAD("air: inflow_axis must be 0, 1 or 2 (got %d).", d->inflow_axis);
    if (d->inflow_side != 0 && d->inflow_side != 1) BAD("air: inflow_side must be 0 or 1 (got %d).", d->inflow_side);
    if (!dr_v3_isfinite(d->inflow_velocity)) BAD("air: the inflow velocity must be finite.");
    double un = dr_v3_get(d->inflow_velocity, d->inflow_axis);
    if (un != 0.0 && (un > 0.0) != (d->inflow_side == 0))
        BAD("air: the inflow velocity's normal component (%g m/s) points out of the box through its inflow face; "
            "reverse it or take the opposite face.", un);
    if (un == 0.0 && dr_v3_norm(d->inflow_velocity) > 0.0)
        BAD("air: an inflow velocity without a normal component closes the box and cannot blow along its walls; give "
            "it a component into the box or set it to 0.");
    if (!(d->ramp >= 0.0) || !isfinite(d->ramp)) BAD("air: ramp must be >= 0 s (got %g).", d->ramp);
    if (!(d->cfl > 0.0) || !isfinite(d->cfl)) BAD("air: cfl must be positive (got %g).", d->cfl);
    if (d->max_substeps < 1) BAD("air: max_substeps must be >= 1 (got %d).", d->max_substeps);
    if (!(d->pressure_tol > 0.0) || !(d->pressure_tol < 1.0))
        BAD("air: pressure_tol must be in (0, 1) (got %g).", d->pressure_tol);
    if (d->pressure_max_iter < 1) BAD("air: pressure_max_iter must be >= 1 (got %d).", d->pressure_max_iter);
#undef BAD
    return DR_OK;
}

static DrStatus alloc_faces(const DrMacGrid *g, double *f[3], DrError *err)
{
    for (int a = 0; a < 3; a++) DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), &f[a], err));
    return DR_OK;
}

static DrStatus create(DrAir *A, DrError *err)
{
    const DrAirDesc *d = &A->d;
    int n[3];
    for (int a = 0; a < 3; a++) {
        double cells = ceil((dr_v3_get(d->domain_hi, a) - dr_v3_get(d->domain_lo, a)) / d->dx - 1e-9);
        if (!(cells >= 1.0) || cells > 1 << 20)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "air: the domain is %g cells along axis %d; choose dx "
                                "so that it spans 1 to 2^20 cells.", cells, a);
        n[a] = (int)cells;
    }
    double ncells = (double)n[0] * n[1] * n[2];
    if (ncells > 3e8)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "air: %.3g cells exceed the pressure solver's index range; "
                            "use a larger dx.", ncells);
    DR_TRY(dr_mac_grid_create(n[0], n[1], n[2], d->dx, d->domain_lo, &A->g, err));
    const DrMacGrid *g = A->g;
    A->ncells = (long)ncells;
    A->closed = dr_v3_get(d->inflow_velocity, d->inflow_axis) == 0.0;
    DR_TRY(alloc_faces(g, A->fm, err));
    DR_TRY(alloc_faces(g, A->ustar, err));
    DR_TRY(alloc_faces(g, A->tmp, err));
    DR_TRY(alloc_faces(g, A->coef, err));
    DR_TRY(alloc_faces(g, A->wsol, err));
    DR_TRY(alloc_faces(g, A->own.open, err));
    DR_TRY(alloc_faces(g, A->own.velocity, err));
    DR_TRY(alloc_faces(g, A->mix.open, err));
    DR_TRY(alloc_faces(g, A->mix.velocity, err));
    for (int a = 0; a < 3; a++) {
        A->own.nfaces[a] = A->mix.nfaces[a] = g->nfaces[a];
        DR_TRY(dr_calloc((size_t)g->nfaces[a], 1, &A->kind[a], err));
    }
    DR_TRY(dr_calloc((size_t)(n[0] + 1) * (n[1] + 1) * (n[2] + 1), sizeof(double), &A->nphi, err));
    DR_TRY(dr_calloc((size_t)A->ncells, sizeof(int), &A->row, err));
    DR_TRY(dr_calloc((size_t)A->ncells, sizeof(long), &A->cells_of_row, err));
    DR_TRY(dr_calloc((size_t)A->ncells * 3, sizeof(int), &A->row_ijk, err));
    DR_TRY(dr_calloc((size_t)A->ncells, sizeof(double), &A->rhs, err));
    DR_TRY(dr_calloc((size_t)A->ncells, sizeof(double), &A->q, err));
    DR_TRY(dr_calloc((size_t)A->ncells * 4, sizeof(double), &A->work, err));
    DR_TRY(dr_calloc((size_t)(n[2] + 1) * PARTS, sizeof(double), &A->part, err));
    DR_TRY(dr_csr_create((int)A->ncells, (int)A->ncells * 7, &A->A, err));

    double mass = d->density * d->dx * d->dx * d->dx;
    DrVec3 u0 = d->initial_stream ? d->inflow_velocity : dr_v3(0, 0, 0);
    for (int a = 0; a < 3; a++) {
        const int *dim = g->fdim[a];
        for (int k = 0; k < dim[2]; k++)
            for (int j = 0; j < dim[1]; j++)
                for (int i = 0; i < dim[0]; i++) {
                    long f = dr_mac_face_index(g, a, i, j, k);
                    int ijk[3] = {i, j, k};
                    int kd = FACE_INNER;
                    if (ijk[a] == 0 || ijk[a] == n[a]) {
                        int side = ijk[a] == 0 ? 0 : 1;
                        if (A->closed || a != d->inflow_axis) kd = FACE_WALL;
                        else kd = side == d->inflow_side ? FACE_INFLOW : FACE_OUTFLOW;
                    }
                    A->kind[a][f] = (unsigned char)kd;
                    A->fm[a][f] = kd == FACE_INNER || kd == FACE_OUTFLOW ? mass : 0.0;
                    A->own.open[a][f] = kd == FACE_WALL ? 0.0 : 1.0;
                    A->wsol[a][f] = 1.0;
                    A->coef[a][f] = 1.0;
                    A->g->f[a][f] = kd == FACE_WALL ? 0.0 : dr_v3_get(u0, a);
                }
    }
    for (long c = 0; c < A->ncells; c++) A->row[c] = -1;
    A->cpl = &A->own;
    A->ival_t0 = A->ival_t1 = NAN;
    A->visc_parts = 1;
    return DR_OK;
}

DrStatus dr_air_create(const DrAirDesc *desc, DrAir **out, DrError *err)
{
    *out = NULL;
    DR_TRY(check_desc(desc, err));
    DrAir *A = NULL;
    DR_TRY(dr_calloc(1, sizeof *A, &A, err));
    A->d = *desc;
    DrStatus s = create(A, err);
    if (s < 0) {
        dr_air_destroy(&A);
        return s;
    }
    *out = A;
    return DR_OK;
}

static void free_faces(double *f[3])
{
    for (int a = 0; a < 3; a++) free(f[a]);
}

void dr_air_destroy(DrAir **air)
{
    if (!air || !*air) return;
    DrAir *A = *air;
    dr_mac_grid_destroy(&A->g);
    for (int a = 0; a < 3; a++) free(A->take[a]);
    free_faces(A->fm);
    free_faces(A->ustar);
    free_faces(A->tmp);
    free_faces(A->coef);
    free_faces(A->wsol);
    free_faces(A->own.open);
    free_faces(A->own.velocity);
    free_faces(A->mix.open);
    free_faces(A->mix.velocity);
    for (int a = 0; a < 3; a++) free(A->kind[a]);
    free(A->nphi);
    free(A->row);
    free(A->cells_of_row);
    free(A->row_ijk);
    dr_mg_destroy(&A->mg);
    free(A->rhs);
    free(A->q);
    free(A->work);
    free(A->part);
    dr_csr_destroy(&A->A);
    dr_mic0_destroy(&A->M);
    free(A);
    *air = NULL;
}

const DrMacGrid *dr_air_grid(const DrAir *air) { return air->g; }
const unsigned char *dr_air_coupled_faces(const DrAir *air, int a) { return air->take[a]; }
const double *dr_air_face_mass(const DrAir *air, int a)
{
    assert(a >= 0 && a < 3);
    return air->fm[a];
}

/* ---- 1. colliders: face fractions and solid velocities --------------------------------------------------- */

typedef struct FaceCtx { DrAir *A; int a; double h; double alpha; } FaceCtx;

static void node_phi_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrAir *A = ctx->A;
    const DrMacGrid *g = A->g;
    int nx1 = g->nx + 1, ny1 = g->ny + 1;
    DrVec3 blo[MAX_COLLIDERS_FRAME], bhi[MAX_COLLIDERS_FRAME];
    DrVec3 pad = dr_v3(2 * g->dx, 2 * g->dx, 2 * g->dx);
    for (int c = 0; c < A->nframes; c++) {
        dr_collider_frame_bounds(&A->frames[c], &blo[c], &bhi[c]);
        blo[c] = dr_v3_sub(blo[c], pad);
        bhi[c] = dr_v3_add(bhi[c], pad);
    }
    for (long k = begin; k < end; k++)
        for (int j = 0; j < ny1; j++)
            for (int i = 0; i < nx1; i++) {
                DrVec3 x = dr_v3(g->origin.x + i * g->dx, g->origin.y + j * g->dx, g->origin.z + k * g->dx);
                double phi = INFINITY;
                for (int c = 0; c < A->nframes; c++) {
                    if (x.x < blo[c].x || x.y < blo[c].y || x.z < blo[c].z || x.x > bhi[c].x || x.y > bhi[c].y ||
                        x.z > bhi[c].z)
                        continue;
                    double p = dr_collider_frame_phi(&A->frames[c], x, NULL);
                    if (p < phi) phi = p;
                }
                A->nphi[i + (long)nx1 * (j + (long)ny1 * k)] = phi;
            }
}

/* wsol: the fraction of the face outside every collider (dr_face_fraction_outside of its corners' phi, within Δx of
   a collider); own.open the same with walls closed; own.velocity: the nearest collider's velocity (by phi at the face
   centre) on faces with a corner within 2Δx of one, 0 elsewhere and on walls. */
static void weight_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrAir *A = ctx->A;
    const DrMacGrid *g = A->g;
    int a = ctx->a, b = (a + 1) % 3, c = (a + 2) % 3;
    const int *dim = g->fdim[a];
    long nx1 = g->nx + 1, ny1 = g->ny + 1;
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int ijk[3] = {i, j, (int)k};
                double w = 1.0, vs = 0.0;
                if (A->nframes > 0) {
                    double p[4];
                    for (int q = 0; q < 4; q++) {
                        int nn[3] = {ijk[0], ijk[1], ijk[2]};
                        nn[b] += (q == 1 || q == 2);
                        nn[c] += (q >= 2);
                        p[q] = A->nphi[nn[0] + nx1 * (nn[1] + ny1 * nn[2])];
                    }
                    double pmin = fmin(fmin(p[0], p[1]), fmin(p[2], p[3]));
                    if (pmin < g->dx) w = dr_face_fraction_outside(p[0], p[1], p[2], p[3]);
                    if (pmin < 2.0 * g->dx) {
                        DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                        double best = INFINITY;
                        for (int cc = 0; cc < A->nframes; cc++) {
                            double ph = dr_collider_frame_phi(&A->frames[cc], x, NULL);
                            if (ph < best) {
                                best = ph;
                                vs = dr_v3_get(dr_collider_frame_velocity(&A->frames[cc], x), a);
                            }
                        }
                    }
                }
                A->wsol[a][f] = w;
                if (A->kind[a][f] == FACE_WALL) {
                    w = 0.0;
                    vs = 0.0;
                }
                A->own.open[a][f] = w;
                A->own.velocity[a][f] = vs;
            }
}

static void run_faces(DrAir *A, DrRangeFn fn, int a, double h, double alpha)
{
    FaceCtx ctx = {A, a, h, alpha};
    dr_parallel_for(A->g->fdim[a][2], slice_grain(A->g, a), fn, &ctx);
}

static void pose_colliders(DrAir *A, const DrCollider *const *colliders, int n, double t)
{
    A->nframes = n;
    for (int c = 0; c < n; c++) A->frames[c] = dr_collider_frame(colliders[c], t);
    if (n > 0) {
        FaceCtx ctx = {A, 0, 0, 0};
        dr_parallel_for(A->g->nz + 1, slice_grain(A->g, 2), node_phi_slices, &ctx);
    }
    for (int a = 0; a < 3; a++) run_faces(A, weight_slices, a, 0, 0);
}

/* ---- 2. advection --------------------------------------------------------------------------------------- */

static inline double lerp(double a, double b, double f) { return a + f * (b - a); }

/* Component a of the field f at x, trilinear on its face lattice, clamped at the box (zero gradient beyond it); a
   point beyond the inflow plane reads the wind (inflow, at the substep's start). lerp's a + f (b − a) returns a
   exactly when b == a, so a uniform field is sampled exactly. */
static double sample_field(const DrAir *A, double *const f[3], int a, DrVec3 x, DrVec3 inflow)
{
    const DrMacGrid *g = A->g;
    if (!A->closed) {
        int ax = A->d.inflow_axis;
        double xa = dr_v3_get(x, ax);
        if (A->d.inflow_side == 0 ? xa < dr_v3_get(A->d.domain_lo, ax)
                                  : xa > dr_v3_get(g->origin, ax) + (ax == 0 ? g->nx : ax == 1 ? g->ny : g->nz) * g->dx)
            return dr_v3_get(inflow, a);
    }
    int i0[3], i1[3];
    double w[3];
    for (int d = 0; d < 3; d++) {
        double s = (dr_v3_get(x, d) - dr_v3_get(g->origin, d)) / g->dx - dr_mac_face_offset(a, d);
        int hi = g->fdim[a][d] - 1;
        if (!(s > 0.0)) s = 0.0;
        if (s > hi) s = hi;
        int b0 = (int)floor(s);
        if (b0 > hi - 1) b0 = hi > 0 ? hi - 1 : 0;
        i0[d] = b0;
        i1[d] = b0 + 1 > hi ? hi : b0 + 1;
        w[d] = s - b0;
    }
    const double *v = f[a];
    double cz[2];
    for (int kk = 0; kk < 2; kk++) {
        int k = kk ? i1[2] : i0[2];
        double cy[2];
        for (int jj = 0; jj < 2; jj++) {
            int j = jj ? i1[1] : i0[1];
            cy[jj] = lerp(v[dr_mac_face_index(g, a, i0[0], j, k)], v[dr_mac_face_index(g, a, i1[0], j, k)], w[0]);
        }
        cz[kk] = lerp(cy[0], cy[1], w[1]);
    }
    return lerp(cz[0], cz[1], w[2]);
}

static DrVec3 sample_velocity(const DrAir *A, double *const f[3], DrVec3 x, DrVec3 inflow)
{
    return dr_v3(sample_field(A, f, 0, x, inflow), sample_field(A, f, 1, x, inflow), sample_field(A, f, 2, x, inflow));
}

/* Semi-Lagrangian with an RK2 (midpoint) backtrace: x_mid = x − ½h u(x), x_dep = x − h u(x_mid), u_new = u(x_dep),
   from the grid's velocities into tmp, on the velocity unknowns (the others are set by set_boundary). */
static void advect_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrAir *A = ctx->A;
    const DrMacGrid *g = A->g;
    int a = ctx->a;
    double h = ctx->h;
    const int *dim = g->fdim[a];
    DrVec3 inflow = wind(A, A->t_step);
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                if (A->kind[a][f] == FACE_WALL || A->kind[a][f] == FACE_INFLOW) {
                    A->tmp[a][f] = g->f[a][f];
                    continue;
                }
                DrVec3 x = dr_mac_face_position(g, a, i, j, (int)k);
                DrVec3 u0 = sample_velocity(A, g->f, x, inflow);
                DrVec3 xm = dr_v3_sub(x, dr_v3_scale(u0, 0.5 * h));
                DrVec3 u1 = sample_velocity(A, g->f, xm, inflow);
                DrVec3 xd = dr_v3_sub(x, dr_v3_scale(u1, h));
                A->tmp[a][f] = sample_field(A, g->f, a, xd, inflow);
            }
}

/* Explicit viscosity u += α Σ_nb (u_nb − u) over the six lattice neighbours, α = ν h/Δx² (≤ 1/6), from tmp into
   the grid; a neighbour beyond the lattice is the face itself (zero gradient: slip). */
static void viscosity_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrAir *A = ctx->A;
    DrMacGrid *g = A->g;
    int a = ctx->a;
    double alpha = ctx->alpha;
    const int *dim = g->fdim[a];
    const double *u = A->tmp[a];
    long st[3] = {1, dim[0], (long)dim[0] * dim[1]};
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int ijk[3] = {i, j, (int)k};
                double c = u[f], lap = 0.0;
                for (int d = 0; d < 3; d++) {
                    double lo = ijk[d] > 0 ? u[f - st[d]] : c, hi = ijk[d] < dim[d] - 1 ? u[f + st[d]] : c;
                    lap += (lo - c) + (hi - c);
                }
                g->f[a][f] = c + alpha * lap;
            }
}

/* Boundary values of the substep ending at t1: walls 0, the inflow face the wind's normal component, the outflow face
   the value of the face one cell inside (zero gradient), faces the colliders block entirely their velocity. */
static void boundary_slices(long begin, long end, void *vctx)
{
    FaceCtx *ctx = vctx;
    DrAir *A = ctx->A;
    DrMacGrid *g = A->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    double un = inflow_normal(A, A->t_step + A->h_step);
    long st = face_stride(g, a);
    for (long k = begin; k < end; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                int kd = A->kind[a][f];
                double *u = &g->f[a][f];
                if (kd == FACE_WALL) *u = 0.0;
                else if (kd == FACE_INFLOW) *u = un;
                else if (kd == FACE_OUTFLOW) *u = A->d.inflow_side == 0 ? g->f[a][f - st] : g->f[a][f + st];
                if (kd != FACE_WALL && !(A->own.open[a][f] > 0.0)) *u = A->own.velocity[a][f];
            }
}

/* ---- 3. pressure ---------------------------------------------------------------------------------------- */

/* The projection's coupling: own, with the extra coupling's solid shares added (liquid.c's rule) and its drag turned
   into the Poisson scale c_f = m_f/(m_f + β_f); flags a slice with bad values (P_BAD). */
typedef struct MixCtx { DrAir *A; int a; const DrFaceCoupling *x; } MixCtx;

static void mix_slices(long begin, long end, void *vctx)
{
    MixCtx *ctx = vctx;
    DrAir *A = ctx->A;
    const DrMacGrid *g = A->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    const double *wo = A->own.open[a], *vo = A->own.velocity[a];
    const double *we = ctx->x ? ctx->x->open[a] : NULL, *ve = ctx->x ? ctx->x->velocity[a] : NULL;
    const double *J = ctx->x ? ctx->x->impulse[a] : NULL, *beta = ctx->x ? ctx->x->drag[a] : NULL;
    double *wm = A->mix.open[a], *vm = A->mix.velocity[a];
    for (long k = begin; k < end; k++) {
        bool bad = false;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                A->coef[a][f] = 1.0;
                if (!we) continue;
                if (!(we[f] >= 0.0 && we[f] <= 1.0) || !isfinite(ve[f]) || (J && !isfinite(J[f])) ||
                    (beta && !(beta[f] >= 0.0 && isfinite(beta[f]))))
                    bad = true;
                if (beta && beta[f] > 0.0 && A->fm[a][f] > 0.0) A->coef[a][f] = A->fm[a][f] / (A->fm[a][f] + beta[f]);
                if (A->kind[a][f] == FACE_WALL) { /* domain walls stay closed and at rest */
                    wm[f] = wo[f];
                    vm[f] = vo[f];
                    continue;
                }
                dr_face_mix(wo[f], vo[f], we[f], ve[f], &wm[f], &vm[f]);
            }
        A->part[PARTS * k + P_BAD] = bad;
    }
}

/* û_f = (m u* + J + β V)/(m + β) (u* + J/m without drag) on the velocity unknowns the coupling leaves open; faces it
   blocks entirely take its solid velocity. P_ADDED: Σ J over the faces taking it. */
static void hat_slices(long begin, long end, void *vctx)
{
    MixCtx *ctx = vctx;
    DrAir *A = ctx->A;
    DrMacGrid *g = A->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    const double *J = ctx->x ? ctx->x->impulse[a] : NULL, *beta = ctx->x ? ctx->x->drag[a] : NULL;
    const double *V = A->cpl->velocity[a], *w = A->cpl->open[a];
    const double *Vd = ctx->x ? ctx->x->velocity[a] : NULL; /* what the drag pulls towards: the extra solid's */
    for (long k = begin; k < end; k++) {
        double sum = 0.0;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                double m = A->fm[a][f];
                double u = A->ustar[a][f];
                if (A->take[a] && ctx->x) A->take[a][f] = m > 0.0 && w[f] > 0.0;
                if (m > 0.0 && !(w[f] > 0.0)) u = V[f];
                else if (m > 0.0) {
                    double Jf = J ? J[f] : 0.0, bf = beta ? beta[f] : 0.0;
                    if (bf > 0.0) u = (m * u + Jf + bf * Vd[f]) / (m + bf);
                    else if (Jf != 0.0) u += Jf / m;
                    sum += Jf;
                }
                g->f[a][f] = u;
            }
        A->part[PARTS * k + P_ADDED] = sum;
    }
}

/* Volume flux through face f (m/s, times Δx² for m³/s): the open part with the air, the blocked part with the solid. */
static inline double face_flux(const DrAir *A, int a, long f)
{
    double w = A->cpl->open[a][f];
    return w * A->g->f[a][f] + (1.0 - w) * A->cpl->velocity[a][f];
}

/* Row r of A q = −Δx Σ_f ±flux_f (q = pΔt/ρ): coefficient w_f c_f per open face between two unknowns, 2 w_f c_f on
   the outflow face (p = 0 on the face: the ghost pressure is −p), nothing on walls and the inflow face. */
static int pressure_row(const DrAir *A, int r, int col[7], double val[7], double *rhs_out)
{
    const DrMacGrid *g = A->g;
    long cstride[3] = {1, g->nx, (long)g->nx * g->ny};
    long c = A->cells_of_row[r];
    int idx[3] = {(int)(c % g->nx), (int)((c / g->nx) % g->ny), (int)(c / cstride[2])};
    double diag = 0.0, off[6] = {0}, rhs = 0.0;
    int offcol[6];
    for (int a = 0; a < 3; a++) {
        long flo = dr_mac_face_index(g, a, idx[0], idx[1], idx[2]), fhi = flo + face_stride(g, a);
        rhs -= face_flux(A, a, fhi);
        rhs += face_flux(A, a, flo);
        for (int side = 0; side < 2; side++) {
            long f = side ? fhi : flo;
            int slot = side ? 3 + a : 2 - a;
            offcol[slot] = -1;
            double w = A->cpl->open[a][f] * A->coef[a][f];
            int kd = A->kind[a][f];
            if (!(w > 0.0) || kd == FACE_WALL || kd == FACE_INFLOW) continue;
            if (kd == FACE_OUTFLOW) {
                diag += 2.0 * w;
                continue;
            }
            long nb = c + (side ? cstride[a] : -cstride[a]);
            if (A->row[nb] < 0) continue;
            diag += w;
            off[slot] = -w;
            offcol[slot] = A->row[nb];
        }
    }
    *rhs_out = rhs * g->dx;
    int cnt = 0;
    for (int q = 0; q < 3; q++)
        if (offcol[q] >= 0) { col[cnt] = offcol[q]; val[cnt++] = off[q]; }
    col[cnt] = r;
    val[cnt++] = diag;
    for (int q = 3; q < 6; q++)
        if (offcol[q] >= 0) { col[cnt] = offcol[q]; val[cnt++] = off[q]; }
    return cnt;
}

typedef struct AssembleCtx { DrAir *A; bool fill; } AssembleCtx;

static void assemble_rows(long begin, long end, void *vctx)
{
    AssembleCtx *ctx = vctx;
    DrCsr *M = ctx->A->A;
    for (long r = begin; r < end; r++) {
        int col[7];
        double val[7], rhs;
        int cnt = pressure_row(ctx->A, (int)r, col, val, &rhs);
        if (!ctx->fill) {
            M->rowptr[r + 1] = cnt;
            continue;
        }
        int at = M->rowptr[r];
        for (int q = 0; q < cnt; q++) { M->col[at + q] = col[q]; M->val[at + q] = val[q]; }
        ctx->A->rhs[r] = rhs;
    }
}

/* The one place the pressure system is solved, so that its preconditioner can be swapped: PCG with MIC(0). */
static DrStatus solve_pressure(DrAir *A, DrPcgStats *ps, DrError *err)
{
    /* multigrid-preconditioned CG (src/linalg DrMg: iterations flat in the resolution), as the liquid's default */
    const DrMacGrid *g = A->g;
    for (long r = 0; r < A->nrow; r++) {
        long c = A->cells_of_row[r];
        A->row_ijk[3 * r] = (int)(c % g->nx);
        A->row_ijk[3 * r + 1] = (int)((c / g->nx) % g->ny);
        A->row_ijk[3 * r + 2] = (int)(c / ((long)g->nx * g->ny));
    }
    int dims[3] = {g->nx, g->ny, g->nz};
    if (!A->mg) DR_TRY(dr_mg_create(A->A, A->row_ijk, dims, NULL, &A->mg, err));
    else DR_TRY(dr_mg_update(A->mg, A->A, A->row_ijk, dims, err));
    DrLinearOp Aop = dr_csr_op(A->A), Mop = dr_mg_op(A->mg);
    DrPcgDesc pd;
    dr_pcg_desc_default(&pd);
    pd.rel_tol = A->d.pressure_tol;
    pd.max_iter = A->d.pressure_max_iter;
    memset(A->q, 0, (size_t)A->nrow * sizeof(double));
    return dr_pcg_solve(&Aop, &Mop, A->rhs, A->q, &pd, A->work, ps, err);
}

/* The unknowns: every cell with an open face that is not a wall or the inflow face. */
static void number_cells(DrAir *A)
{
    const DrMacGrid *g = A->g;
    long nrow = 0;
    for (int k = 0; k < g->nz; k++)
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                long c = dr_mac_cell_index(g, i, j, k);
                A->row[c] = -1;
                bool open = false;
                for (int a = 0; a < 3 && !open; a++)
                    for (int side = 0; side < 2 && !open; side++) {
                        long f = dr_mac_face_index(g, a, i, j, k) + (side ? face_stride(g, a) : 0);
                        int kd = A->kind[a][f];
                        open = A->cpl->open[a][f] > 0.0 && kd != FACE_WALL && kd != FACE_INFLOW;
                    }
                if (open) {
                    A->row[c] = (int)nrow;
                    A->cells_of_row[nrow++] = c;
                }
            }
    A->nrow = nrow;
}

static inline double q_cell(const DrAir *A, long c) { return c >= 0 && A->row[c] >= 0 ? A->q[A->row[c]] : 0.0; }

/* u_f = û_f − c_f (q_hi − q_lo)/Δx on the open velocity unknowns (the outflow face's outer q is −q of its cell);
   partials: the pressure's momentum −m_f Δq/Δx (P_PRESS), the drag's β_f (V_f − u_f) (P_DRAG), the largest |u_f|. */
static void project_slices(long begin, long end, void *vctx)
{
    MixCtx *ctx = vctx;
    DrAir *A = ctx->A;
    DrMacGrid *g = A->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    int n[3] = {g->nx, g->ny, g->nz};
    long cs = a == 0 ? 1 : a == 1 ? g->nx : (long)g->nx * g->ny;
    const double *beta = ctx->x ? ctx->x->drag[a] : NULL;
    const double *V = ctx->x ? ctx->x->velocity[a] : NULL, *w = A->cpl->open[a];
    double inv = 1.0 / g->dx;
    for (long k = begin; k < end; k++) {
        double press = 0.0, drag = 0.0, vmax = 0.0;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                double m = A->fm[a][f];
                if (!(m > 0.0)) continue;
                if (w[f] > 0.0) {
                    int ijk[3] = {i, j, (int)k};
                    double qlo, qhi;
                    if (ijk[a] == 0) { /* the outflow face on the low side */
                        qhi = q_cell(A, dr_mac_cell_index(g, i, j, (int)k));
                        qlo = -qhi;
                    } else if (ijk[a] == n[a]) {
                        int lo[3] = {i, j, (int)k};
                        lo[a]--;
                        qlo = q_cell(A, dr_mac_cell_index(g, lo[0], lo[1], lo[2]));
                        qhi = -qlo;
                    } else {
                        long chi = dr_mac_cell_index(g, i, j, (int)k);
                        qhi = q_cell(A, chi);
                        qlo = q_cell(A, chi - cs);
                    }
                    double dq = (qhi - qlo) * inv;
                    g->f[a][f] -= A->coef[a][f] * dq;
                    press -= m * dq;
                    if (beta && beta[f] > 0.0) drag += beta[f] * (V[f] - g->f[a][f]);
                }
                double s = fabs(g->f[a][f]);
                if (s > vmax) vmax = s;
            }
        A->part[PARTS * k + P_PRESS] = press;
        A->part[PARTS * k + P_DRAG] = drag;
        A->part[PARTS * k + P_SPEED] = vmax;
    }
}

/* Volume flux through the inflow and outflow faces (P_IN, P_OUT; m³/s, positive into and out of the box). */
static void flux_slices(long begin, long end, void *vctx)
{
    MixCtx *ctx = vctx;
    DrAir *A = ctx->A;
    const DrMacGrid *g = A->g;
    int a = ctx->a;
    const int *dim = g->fdim[a];
    double area = g->dx * g->dx, sign = A->d.inflow_side == 0 ? 1.0 : -1.0;
    for (long k = begin; k < end; k++) {
        double in = 0.0, out = 0.0;
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                long f = dr_mac_face_index(g, a, i, j, (int)k);
                if (A->kind[a][f] == FACE_INFLOW) in += sign * face_flux(A, a, f) * area;
                else if (A->kind[a][f] == FACE_OUTFLOW) out += sign * face_flux(A, a, f) * area;
            }
        A->part[PARTS * k + P_IN] = in;
        A->part[PARTS * k + P_OUT] = out;
    }
}

/* Largest |Σ_f ±flux_f|/Δx over the pressure cells (1/s), per z-slice of cells (into the P_BAD slot, free once the
   coupling is checked). */
static void divergence_slices(long begin, long end, void *vctx)
{
    MixCtx *ctx = vctx;
    DrAir *A = ctx->A;
    const DrMacGrid *g = A->g;
    for (long k = begin; k < end; k++) {
        double dmax = 0.0;
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                long c = dr_mac_cell_index(g, i, j, (int)k);
                if (A->row[c] < 0) continue;
                double div = 0.0;
                for (int a = 0; a < 3; a++) {
                    long flo = dr_mac_face_index(g, a, i, j, (int)k);
                    div += face_flux(A, a, flo + face_stride(g, a)) - face_flux(A, a, flo);
                }
                div = fabs(div) / g->dx;
                if (div > dmax) dmax = div;
            }
        A->part[PARTS * k + P_BAD] = dmax;
    }
}

static double sum_part(const DrAir *A, long nslices, int slot)
{
    double s = 0.0;
    for (long k = 0; k < nslices; k++) s += A->part[PARTS * k + slot];
    return s;
}

static double max_part(const DrAir *A, long nslices, int slot)
{
    double s = 0.0;
    for (long k = 0; k < nslices; k++) s = fmax(s, A->part[PARTS * k + slot]);
    return s;
}

static DrStatus project(DrAir *A, const DrFaceCoupling *extra, DrAirStats *stats, DrError *err)
{
    DrMacGrid *g = A->g;
    double t0 = dr_time_now();
    A->cpl = extra ? &A->mix : &A->own;
    double added[3] = {0}, drag[3] = {0}, press[3] = {0};
    for (int a = 0; a < 3; a++) {
        if (extra) assert(extra->nfaces[a] == g->nfaces[a] && extra->open[a] && extra->velocity[a]);
        MixCtx ctx = {A, a, extra};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), mix_slices, &ctx);
        if (extra)
            for (int k = 0; k < g->fdim[a][2]; k++)
                if (A->part[PARTS * k + P_BAD] != 0.0)
                    return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "air project: the face coupling of component "
                                        "%d has an open fraction outside [0, 1], a negative drag mass or a non-finite "
                                        "value in face layer %d.", a, k);
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), hat_slices, &ctx);
        added[a] = sum_part(A, g->fdim[a][2], P_ADDED);
    }
    number_cells(A);
    long nrow = A->nrow;
    if (nrow > 0) {
        DR_TRY(dr_csr_reserve(A->A, (int)nrow, (int)nrow * 7, err));
        AssembleCtx actx = {A, false};
        long grain = PAR_MIN_ITEMS / 4;
        dr_parallel_for(nrow, grain, assemble_rows, &actx);
        A->A->rowptr[0] = 0;
        for (long r = 0; r < nrow; r++) A->A->rowptr[r + 1] += A->A->rowptr[r];
        actx.fill = true;
        dr_parallel_for(nrow, grain, assemble_rows, &actx);
        A->A->nnz = A->A->rowptr[nrow];
        if (A->closed) {
            /* pure Neumann: the right-hand side onto the range (its mean removed, in row order) */
            double mean = 0.0;
            for (long r = 0; r < nrow; r++) mean += A->rhs[r];
            mean /= (double)nrow;
            for (long r = 0; r < nrow; r++) A->rhs[r] -= mean;
        }
        DrPcgStats ps;
        DrStatus s = solve_pressure(A, &ps, err);
        if (s < 0) return s;
        if (A->closed) {
            double mean = 0.0;
            for (long r = 0; r < nrow; r++) mean += A->q[r];
            mean /= (double)nrow;
            for (long r = 0; r < nrow; r++) A->q[r] -= mean;
        }
        if (ps.iterations > stats->pressure_iterations_max) stats->pressure_iterations_max = ps.iterations;
        stats->pressure_iterations_total += ps.iterations;
        if (ps.rel_residual > stats->pressure_residual_max) stats->pressure_residual_max = ps.rel_residual;
        if (s == DR_WARN_NOT_CONVERGED) {
            stats->pressure_not_converged++;
            dr_log_warn("air: pressure solve stopped at %d iterations with relative residual %.3e (tolerance %.1e); "
                        "raise solver.pressure_max_iterations", ps.iterations, ps.rel_residual, A->d.pressure_tol);
        }
    }
    stats->pressure_cells = nrow;
    double speed = 0.0;
    for (int a = 0; a < 3; a++) {
        MixCtx ctx = {A, a, extra};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), project_slices, &ctx);
        press[a] = sum_part(A, g->fdim[a][2], P_PRESS);
        drag[a] = sum_part(A, g->fdim[a][2], P_DRAG);
        speed = fmax(speed, max_part(A, g->fdim[a][2], P_SPEED));
    }
    A->added = dr_v3(added[0], added[1], added[2]);
    A->drag = dr_v3(drag[0], drag[1], drag[2]);
    A->press = dr_v3(press[0], press[1], press[2]);
    A->speed_max = speed;
    A->flux_in = A->flux_out = 0.0;
    if (!A->closed) {
        int a = A->d.inflow_axis;
        MixCtx ctx = {A, a, extra};
        dr_parallel_for(g->fdim[a][2], slice_grain(g, a), flux_slices, &ctx);
        A->flux_in = sum_part(A, g->fdim[a][2], P_IN);
        A->flux_out = sum_part(A, g->fdim[a][2], P_OUT);
    }
    MixCtx dctx = {A, 2, extra};
    long cgrain = (PAR_MIN_ITEMS + (long)g->nx * g->ny - 1) / ((long)g->nx * g->ny);
    dr_parallel_for(g->nz, cgrain, divergence_slices, &dctx);
    A->div_max = max_part(A, g->nz, P_BAD);
    stats->seconds_pressure += dr_time_now() - t0;
    return DR_OK;
}

/* ---- the phases ------------------------------------------------------------------------------------------ */

static DrStatus check_colliders(int n, DrError *err)
{
    if (n < 0 || n > MAX_COLLIDERS_FRAME)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "air: between 0 and %d colliders.", MAX_COLLIDERS_FRAME);
    return DR_OK;
}

static double grid_speed(const DrAir *A)
{
    const DrMacGrid *g = A->g;
    double m = 0.0;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            double s = fabs(g->f[a][f]);
            if (!(s <= m)) m = s; /* NaN propagates */
        }
    return m;
}

DrStatus dr_air_stable_dt(DrAir *air, const DrCollider *const *colliders, int ncolliders, double t, double t_end,
                          double *h, DrError *err)
{
    (void)colliders;
    *h = 0.0;
    DR_TRY(check_colliders(ncolliders, err));
    if (!isfinite(t) || !isfinite(t_end) || !(t_end > t))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "air stable_dt: t_end (%g) must be finite and after t (%g).",
                            t_end, t);
    if (!(t_end == air->ival_t1) || !(t >= air->ival_t0)) {
        air->ival_t0 = t;
        air->ival_t1 = t_end;
        air->ival_substeps = 0;
        air->ival_warned = false;
    }
    double umax = fmax(grid_speed(air), dr_v3_norm(air->d.inflow_velocity));
    if (!isfinite(umax))
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "air: velocities became non-finite at t = %g s; lower cfl or raise max_substeps.", t);
    double dt = umax > 0.0 ? air->d.cfl * air->g->dx / umax : INFINITY;
    double remaining = t_end - t;
    double nneed = ceil(remaining / dt);
    int left = air->d.max_substeps - air->ival_substeps;
    if (!(nneed <= left)) {
        nneed = left;
        if (!air->ival_warned) {
            dr_log_warn("air: the CFL condition needs more than max_substeps = %d substeps in [%g, %g] s; clamping "
                        "(raise solver.max_substeps for accuracy)", air->d.max_substeps, air->ival_t0, t_end);
            air->ival_warned = true;
        }
    }
    if (nneed < 1) nneed = 1;
    dt = remaining / nneed;
    air->t_step = t;
    air->h_stable = dt;
    air->step_lands = nneed <= 1;
    air->phase = PHASE_READY;
    *h = dt;
    return DR_OK;
}

DrStatus dr_air_begin(DrAir *air, const DrCollider *const *colliders, int ncolliders, double t, double h, DrError *err)
{
    assert(air->phase == PHASE_READY && t == air->t_step); /* dr_air_stable_dt(t) first */
    DR_TRY(check_colliders(ncolliders, err));
    if (!(h > 0.0) || !(h <= air->h_stable * (1.0 + 1e-9)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "air begin: h (%g s) must be positive and at most the stable step %g s.", h, air->h_stable);
    DrMacGrid *g = air->g;
    double t0 = dr_time_now();
    air->h_step = h;
    pose_colliders(air, colliders, ncolliders, t + h);
    double t1 = dr_time_now();
    for (int a = 0; a < 3; a++) run_faces(air, advect_slices, a, h, 0);
    double nu = air->d.viscosity / air->d.density;
    double alpha = nu * h / (g->dx * g->dx);
    int parts = 1;
    if (alpha > 0.0) {
        parts = (int)fmin(ceil(6.0 * alpha * (1.0 - 1e-12)), (double)MAX_VISCOSITY_PARTS);
        if (parts < 1) parts = 1;
        double ap = alpha / parts;
        if (ap > 1.0 / 6.0) {
            ap = 1.0 / 6.0;
            if (!air->visc_warned) {
                dr_log_warn("air: viscosity %g Pa*s needs more than %d explicit parts per substep at dx %g m; it is "
                            "under-applied (diffusion number held at 1/6)", air->d.viscosity, MAX_VISCOSITY_PARTS,
                            g->dx);
                air->visc_warned = true;
            }
        }
        for (int p = 0; p < parts; p++) {
            if (p > 0)
                for (int a = 0; a < 3; a++) memcpy(air->tmp[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
            for (int a = 0; a < 3; a++) run_faces(air, viscosity_slices, a, h, ap);
        }
    } else {
        for (int a = 0; a < 3; a++) memcpy(g->f[a], air->tmp[a], (size_t)g->nfaces[a] * sizeof(double));
    }
    air->visc_parts = parts;
    double t2 = dr_time_now();
    for (int a = 0; a < 3; a++) run_faces(air, boundary_slices, a, h, 0);
    for (int a = 0; a < 3; a++) memcpy(air->ustar[a], g->f[a], (size_t)g->nfaces[a] * sizeof(double));
    air->pend_advect += t2 - t1;
    air->pend_other += (t1 - t0) + (dr_time_now() - t2);
    air->phase = PHASE_BEGUN;
    return DR_OK;
}

DrStatus dr_air_project(DrAir *air, const DrFaceCoupling *extra, DrAirStats *stats, DrError *err)
{
    assert(air->phase == PHASE_BEGUN || air->phase == PHASE_PROJECTED); /* dr_air_begin first */
    air->phase = PHASE_BEGUN;
    for (int a = 0; extra && a < 3; a++)
        if (!air->take[a]) DR_TRY(dr_calloc((size_t)air->g->nfaces[a], 1, &air->take[a], err));
    DR_TRY(project(air, extra, stats, err));
    air->phase = PHASE_PROJECTED;
    return DR_OK;
}

DrStatus dr_air_end(DrAir *air, DrAirStats *stats, DrError *err)
{
    (void)err;
    assert(air->phase == PHASE_PROJECTED); /* dr_air_project first */
    stats->substeps++;
    stats->added_impulse = dr_v3_add(stats->added_impulse, air->added);
    stats->drag_impulse = dr_v3_add(stats->drag_impulse, air->drag);
    stats->pressure_impulse = dr_v3_add(stats->pressure_impulse, air->press);
    stats->max_speed = air->speed_max;
    stats->divergence_max = air->div_max;
    stats->inflow_flux = air->flux_in;
    stats->outflow_flux = air->flux_out;
    if (air->visc_parts > stats->viscosity_subcycles) stats->viscosity_subcycles = air->visc_parts;
    stats->seconds_advect += air->pend_advect;
    stats->seconds_other += air->pend_other;
    air->pend_advect = air->pend_other = 0.0;
    air->ival_substeps++;
    air->phase = PHASE_IDLE;
    return DR_OK;
}

DrStatus dr_air_advance(DrAir *air, const DrCollider *const *colliders, int ncolliders, double t0, double t1,
                        DrAirStats *stats, DrError *err)
{
    memset(stats, 0, sizeof *stats);
    DR_TRY(check_colliders(ncolliders, err));
    if (!(t1 >= t0) || !isfinite(t0) || !isfinite(t1))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "air advance: t1 (%g) must not precede t0 (%g).", t1, t0);
    double t = t0;
    while (t < t1) {
        double h;
        DR_TRY(dr_air_stable_dt(air, colliders, ncolliders, t, t1, &h, err));
        bool last = h == t1 - t;
        DR_TRY(dr_air_begin(air, colliders, ncolliders, t, h, err));
        DR_TRY(dr_air_project(air, NULL, stats, err));
        DR_TRY(dr_air_end(air, stats, err));
        t = last ? t1 : t + h;
    }
    return DR_OK;
}

/* ---- sampling, totals, checkpoints ----------------------------------------------------------------------- */

static double sample_pressure(const DrAir *A, DrVec3 x)
{
    const DrMacGrid *g = A->g;
    int n[3] = {g->nx, g->ny, g->nz}, i0[3], i1[3];
    double w[3];
    for (int d = 0; d < 3; d++) {
        double s = (dr_v3_get(x, d) - dr_v3_get(g->origin, d)) / g->dx - 0.5;
        if (!(s > 0.0)) s = 0.0;
        if (s > n[d] - 1) s = n[d] - 1;
        DrStencil2 st = dr_kernel_linear(s);
        i0[d] = st.base;
        i1[d] = st.base + 1 > n[d] - 1 ? n[d] - 1 : st.base + 1;
        w[d] = st.w[1];
    }
    if (!(A->h_step > 0.0)) return 0.0;
    double scale = A->d.density / A->h_step, sum = 0.0;
    for (int kk = 0; kk < 2; kk++)
        for (int jj = 0; jj < 2; jj++)
            for (int ii = 0; ii < 2; ii++) {
                double wt = (ii ? w[0] : 1.0 - w[0]) * (jj ? w[1] : 1.0 - w[1]) * (kk ? w[2] : 1.0 - w[2]);
                long c = dr_mac_cell_index(g, ii ? i1[0] : i0[0], jj ? i1[1] : i0[1], kk ? i1[2] : i0[2]);
                sum += wt * q_cell(A, c);
            }
    return scale * sum;
}

typedef struct SampleCtx { const DrAir *A; const double *x; double *v, *p; } SampleCtx;

static void sample_range(long begin, long end, void *vctx)
{
    SampleCtx *ctx = vctx;
    for (long i = begin; i < end; i++) {
        DrVec3 x = dr_v3(ctx->x[3 * i], ctx->x[3 * i + 1], ctx->x[3 * i + 2]);
        if (ctx->v)
            for (int a = 0; a < 3; a++) ctx->v[3 * i + a] = dr_mac_sample_face(ctx->A->g, a, x);
        if (ctx->p) ctx->p[i] = sample_pressure(ctx->A, x);
    }
}

void dr_air_sample(const DrAir *air, long n, const double *points, double *vel_out, double *pressure_out)
{
    assert(air->phase == PHASE_PROJECTED || air->phase == PHASE_IDLE);
    SampleCtx ctx = {air, points, vel_out, pressure_out};
    dr_parallel_for(n, 1024, sample_range, &ctx);
}

void dr_air_totals(const DrAir *air, double *mass, DrVec3 *momentum, double *kinetic)
{
    const DrMacGrid *g = air->g;
    double p[3] = {0}, ke = 0.0;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            double m = air->fm[a][f], u = g->f[a][f];
            p[a] += m * u;
            ke += 0.5 * m * u * u;
        }
    double open = 0.0;
    for (int k = 0; k < g->nz; k++)
        for (int j = 0; j < g->ny; j++)
            for (int i = 0; i < g->nx; i++) {
                double s = 0.0;
                for (int a = 0; a < 3; a++) {
                    long f = dr_mac_face_index(g, a, i, j, k);
                    s += air->wsol[a][f] + air->wsol[a][f + face_stride(g, a)];
                }
                open += s / 6.0;
            }
    if (mass) *mass = air->d.density * open * g->dx * g->dx * g->dx;
    if (momentum) *momentum = dr_v3(p[0], p[1], p[2]);
    if (kinetic) *kinetic = ke;
}

DrStatus dr_air_restore(DrAir *air, const double *const velocity[3], DrError *err)
{
    const DrMacGrid *g = air->g;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++)
            if (!isfinite(velocity[a][f]))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "air restore: face velocity %ld of component %d is "
                                    "not finite; the checkpoint is damaged: bake without --resume.", f, a);
    for (int a = 0; a < 3; a++) memcpy(g->f[a], velocity[a], (size_t)g->nfaces[a] * sizeof(double));
    for (long c = 0; c < air->ncells; c++) air->row[c] = -1;
    air->phase = PHASE_IDLE;
    air->ival_t0 = air->ival_t1 = NAN;
    return DR_OK;
}
