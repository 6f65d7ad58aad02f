/* Particle–grid transfers on the MAC grid; see transfer.h for the equations and guarantees. */
#include "transfer/transfer.h"

#include <stdlib.h>
#include <string.h>

/* Smallest particle or face count worth a parallel chunk (see dr_transfer_p2g_mac). */
#define DR_TRANSFER_PAR_MIN 16384

/* ---- bins ------------------------------------------------------------------------------------- */

DrStatus dr_bins_create(const DrMacGrid *g, long n_capacity, DrParticleBins **out, DrError *err)
{
    *out = NULL;
    DrParticleBins *b = NULL;
    DR_TRY(dr_calloc(1, sizeof *b, &b, err));
    b->ncells = (long)g->nx * g->ny * g->nz;
    if (n_capacity < 1) n_capacity = 1;
    DrStatus s = dr_calloc((size_t)b->ncells + 1, sizeof(long), &b->cell_start, err);
    if (s >= 0) s = dr_calloc((size_t)n_capacity, sizeof(long), &b->order, err);
    if (s >= 0) s = dr_calloc((size_t)n_capacity, sizeof(long), &b->cell_of, err);
    for (int a = 0; a < 3 && s >= 0; a++) s = dr_calloc(2 * (size_t)g->nfaces[a], sizeof(double), &b->acc[a], err);
    if (s < 0) { dr_bins_destroy(&b); return s; }
    b->cap = n_capacity;
    *out = b;
    return DR_OK;
}

void dr_bins_destroy(DrParticleBins **b)
{
    if (!b || !*b) return;
    free((*b)->cell_start);
    free((*b)->order);
    free((*b)->cell_of);
    for (int a = 0; a < 3; a++) free((*b)->acc[a]);
    free(*b);
    *b = NULL;
}

typedef struct BinCtx { const DrMacGrid *g; const double *x; long *cell_of; } BinCtx;

static void bin_cells(long begin, long end, void *vctx)
{
    BinCtx *ctx = vctx;
    const DrMacGrid *g = ctx->g;
    double inv = 1.0 / g->dx;
    int n[3] = {g->nx, g->ny, g->nz};
    for (long p = begin; p < end; p++) {
        int ijk[3];
        for (int d = 0; d < 3; d++) {
            double s = (ctx->x[3 * p + d] - dr_v3_get(g->origin, d)) * inv;
            int i = (int)floor(s);
            if (!(s >= 0.0)) i = 0;
            if (i > n[d] - 1) i = n[d] - 1;
            ijk[d] = i;
        }
        ctx->cell_of[p] = dr_mac_cell_index(g, ijk[0], ijk[1], ijk[2]);
    }
}

DrStatus dr_bins_build(const DrMacGrid *g, long n, const double *x, DrParticleBins *b, DrError *err)
{
    if (n > b->cap) {
        long cap = n + n / 4 + 16;
        DR_TRY(dr_realloc((size_t)cap, sizeof(long), &b->order, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof(long), &b->cell_of, err));
        b->cap = cap;
    }
    b->n = n;
    BinCtx ctx = {g, x, b->cell_of};
    dr_parallel_for(n, DR_TRANSFER_PAR_MIN, bin_cells, &ctx);
    /* counting sort: stable, so particles of a cell stay in index order */
    memset(b->cell_start, 0, ((size_t)b->ncells + 1) * sizeof(long));
    for (long p = 0; p < n; p++) b->cell_start[b->cell_of[p] + 1]++;
    for (long c = 0; c < b->ncells; c++) b->cell_start[c + 1] += b->cell_start[c];
    /* cell_start[c+1] is now the end of cell c; filling from the ends in reverse particle order leaves
       ascending particle order within each cell and moves cell_start[c+1] to the start of cell c */
    for (long p = n - 1; p >= 0; p--) {
        long c = b->cell_of[p];
        b->order[--b->cell_start[c + 1]] = p;
    }
    for (long c = 0; c < b->ncells; c++) b->cell_start[c] = b->cell_start[c + 1];
    b->cell_start[b->ncells] = n;
    return DR_OK;
}

/* ---- P2G ---------------------------------------------------------------------------------------- */

/* Maps a stencil index to the stored face and the sign of the mirrored value (transfer.h). */
static inline int mirror(int i, int n, bool normal, double tsign, double *sign)
{
    if (i < 0) {
        if (normal) { *sign *= -1.0; i = -i; }
        else { *sign *= tsign; i = -1 - i; }
    } else if (i >= n) {
        if (normal) { *sign *= -1.0; i = 2 * (n - 1) - i; }
        else { *sign *= tsign; i = 2 * n - 1 - i; }
    }
    if (i < 0) i = 0;
    if (i > n - 1) i = n - 1;
    return i;
}

/* One axis of a face component's stencil, resolved against the walls: stored node index, mirror sign,
   weight and offset Δx·(node − sample) of each of the three nodes. */
typedef struct AxisStencil { int idx[3]; double sgn[3], w[3], off[3]; } AxisStencil;

static inline AxisStencil axis_stencil(double s, int n, bool normal, double tsign, double dx)
{
    AxisStencil as;
    DrStencil3 st = dr_kernel_quadratic(s);
    for (int q = 0; q < 3; q++) {
        as.sgn[q] = 1.0;
        as.idx[q] = mirror(st.base + q, n, normal, tsign, &as.sgn[q]);
        as.w[q] = st.w[q];
        as.off[q] = dx * (st.base + q - s);
    }
    return as;
}


typedef struct P2gCtx {
    const DrParticleBins *b;
    const double *x, *v, *c;
    double mass;
    const double *scale; /* per-particle mass factor, NULL: 1 */
    const DrMacGrid *g;
    double tsign;
    int parity;
} P2gCtx;

/* Scatters one particle's component a directly into the accumulators (the general path: used when
   the particle lies outside its bin's cell, which only positions beyond the grid box can cause). */
static void p2g_direct(const P2gCtx *ctx, long p, const double X[3], int a)
{
    const DrMacGrid *g = ctx->g;
    const double dx = g->dx, m = ctx->scale ? ctx->mass * ctx->scale[p] : ctx->mass;
    const int *dim = g->fdim[a];
    AxisStencil ax[3];
    for (int d = 0; d < 3; d++) ax[d] = axis_stencil(X[d] - dr_mac_face_offset(a, d), dim[d], a == d, ctx->tsign, dx);
    double va = ctx->v[3 * p + a];
    const double *ca = ctx->c ? ctx->c + 9 * p + 3 * a : NULL;
    double *acc = ctx->b->acc[a];
    for (int kk = 0; kk < 3; kk++)
        for (int jj = 0; jj < 3; jj++) {
            long row = (long)dim[0] * (ax[1].idx[jj] + (long)dim[1] * ax[2].idx[kk]);
            for (int ii = 0; ii < 3; ii++) {
                double wm = ax[0].w[ii] * ax[1].w[jj] * ax[2].w[kk] * m;
                double vel = va;
                if (ca) vel += ca[0] * ax[0].off[ii] + ca[1] * ax[1].off[jj] + ca[2] * ax[2].off[kk];
                long f = row + ax[0].idx[ii];
                acc[2 * f] += wm;
                acc[2 * f + 1] += ax[0].sgn[ii] * ax[1].sgn[jj] * ax[2].sgn[kk] * wm * vel;
            }
        }
}

/* A cell's particles all reach the same nodes: along the face axis a the stencil starts at the cell's
   low face or the one before (4 nodes in all), along the other axes at the node before the cell's
   (3 nodes). The particles of a cell are summed into a local 4×3×3 block, which is then added to the
   accumulators once, with the wall mirror resolved per node: 72 global updates per cell and component
   instead of 54 per particle. */
static void p2g_slab(long begin, long end, void *vctx)
{
    P2gCtx *ctx = vctx;
    const DrMacGrid *g = ctx->g;
    const DrParticleBins *b = ctx->b;
    const double inv = 1.0 / g->dx, dx = g->dx;
    long slab_cells = (long)g->nx * g->ny * DR_TRANSFER_SLAB;
    for (long si = begin; si < end; si++) {
        long s = 2 * si + ctx->parity;
        long c0 = s * slab_cells, c1 = c0 + slab_cells;
        if (c1 > b->ncells) c1 = b->ncells;
        for (long c = c0; c < c1; c++) {
            long q0 = b->cell_start[c], q1 = b->cell_start[c + 1];
            if (q0 == q1) continue;
            int cell[3] = {(int)(c % g->nx), (int)((c / g->nx) % g->ny), (int)(c / ((long)g->nx * g->ny))};
            for (int a = 0; a < 3; a++) {
                const int *dim = g->fdim[a];
                int nb[3]; /* block extent per axis */
                for (int d = 0; d < 3; d++) nb[d] = d == a ? 4 : 3;
                double blk[36][2];
                memset(blk, 0, sizeof blk);
                for (long q = q0; q < q1; q++) {
                    long p = b->order[q];
                    double X[3];
                    for (int d = 0; d < 3; d++) X[d] = (ctx->x[3 * p + d] - dr_v3_get(g->origin, d)) * inv;
                    DrStencil3 st[3];
                    double sa[3];
                    int lo[3];
                    bool inside = true;
                    for (int d = 0; d < 3; d++) {
                        sa[d] = X[d] - dr_mac_face_offset(a, d);
                        st[d] = dr_kernel_quadratic(sa[d]);
                        lo[d] = st[d].base - (cell[d] - 1);
                        inside = inside && lo[d] >= 0 && lo[d] + 3 <= nb[d];
                    }
                    if (!inside) {
                        p2g_direct(ctx, p, X, a);
                        continue;
                    }
                    double va = ctx->v[3 * p + a], m = ctx->scale ? ctx->mass * ctx->scale[p] : ctx->mass;
                    const double *ca = ctx->c ? ctx->c + 9 * p + 3 * a : NULL;
                    /* affine velocity v + c·(x_i − x_p), separable along the axes */
                    double cx[3] = {0, 0, 0}, cy[3] = {0, 0, 0}, cz[3] = {0, 0, 0};
                    if (ca)
                        for (int k = 0; k < 3; k++) {
                            cx[k] = ca[0] * dx * (st[0].base + k - sa[0]);
                            cy[k] = ca[1] * dx * (st[1].base + k - sa[1]);
                            cz[k] = ca[2] * dx * (st[2].base + k - sa[2]);
                        }
                    for (int kk = 0; kk < 3; kk++) {
                        double wz = st[2].w[kk] * m;
                        for (int jj = 0; jj < 3; jj++) {
                            double wyz = st[1].w[jj] * wz, vyz = va + cy[jj] + cz[kk];
                            double (*row)[2] = blk + nb[0] * ((lo[1] + jj) + nb[1] * (lo[2] + kk)) + lo[0];
                            for (int ii = 0; ii < 3; ii++) {
                                double wm = st[0].w[ii] * wyz;
                                row[ii][0] += wm;
                                row[ii][1] += wm * (vyz + cx[ii]);
                            }
                        }
                    }
                }
                /* flush: each block node to its stored face (mirrored across walls) */
                int idx[3][4];
                double sgn[3][4];
                for (int d = 0; d < 3; d++)
                    for (int l = 0; l < nb[d]; l++) {
                        sgn[d][l] = 1.0;
                        idx[d][l] = mirror(cell[d] - 1 + l, dim[d], a == d, ctx->tsign, &sgn[d][l]);
                    }
                double *acc = b->acc[a];
                for (int lz = 0; lz < nb[2]; lz++)
                    for (int ly = 0; ly < nb[1]; ly++) {
                        long row = (long)dim[0] * (idx[1][ly] + (long)dim[1] * idx[2][lz]);
                        double syz = sgn[1][ly] * sgn[2][lz];
                        const double (*brow)[2] = blk + nb[0] * (ly + nb[1] * lz);
                        for (int lx = 0; lx < nb[0]; lx++) {
                            if (brow[lx][0] == 0.0) continue;
                            long f = row + idx[0][lx];
                            acc[2 * f] += brow[lx][0];
                            acc[2 * f + 1] += syz * sgn[0][lx] * brow[lx][1];
                        }
                    }
            }
        }
    }
}

typedef struct NormCtx { const DrParticleBins *b; DrMacGrid *g; double *const *fm; } NormCtx;

/* u = momentum / mass from the accumulators; faces without mass get u = 0 */
static void p2g_normalize(long begin, long end, void *vctx)
{
    NormCtx *ctx = vctx;
    for (int a = 0; a < 3; a++) {
        long nf = ctx->g->nfaces[a];
        long b = begin * nf / 1024, e = end * nf / 1024;
        double *u = ctx->g->f[a], *m = ctx->fm[a];
        const double *acc = ctx->b->acc[a];
        for (long f = b; f < e; f++) {
            double mf = acc[2 * f];
            m[f] = mf;
            u[f] = mf > 0.0 ? acc[2 * f + 1] / mf : 0.0;
        }
    }
}

static void zero_faces(long begin, long end, void *vctx)
{
    NormCtx *ctx = vctx;
    for (int a = 0; a < 3; a++) {
        long nf = ctx->g->nfaces[a];
        long b = begin * nf / 1024, e = end * nf / 1024;
        memset(ctx->b->acc[a] + 2 * b, 0, 2 * (size_t)(e - b) * sizeof(double));
    }
}

void dr_transfer_p2g_mac(const DrParticleBins *b, const double *x, const double *v, const double *c,
                         double mass, const double *scale, bool wall_no_slip, DrMacGrid *g,
                         double *const face_mass[3])
{
    assert(b->ncells == (long)g->nx * g->ny * g->nz);
    NormCtx nctx = {b, g, face_mass};
    /* small grids and particle sets run serially: a parallel region's fork and barrier would cost more
       than the work, and far more when another process holds a core */
    long nf = g->nfaces[0] + g->nfaces[1] + g->nfaces[2];
    long fgrain = nf >= 4 * DR_TRANSFER_PAR_MIN ? 1 : 1024;
    dr_parallel_for(1024, fgrain, zero_faces, &nctx);
    long nslabs = (g->nz + DR_TRANSFER_SLAB - 1) / DR_TRANSFER_SLAB;
    P2gCtx ctx = {b, x, v, c, mass, scale, g, wall_no_slip ? -1.0 : 1.0, 0};
    for (int parity = 0; parity < 2; parity++) {
        ctx.parity = parity;
        long count = (nslabs - parity + 1) / 2;
        dr_parallel_for(count, b->n >= DR_TRANSFER_PAR_MIN ? 1 : count, p2g_slab, &ctx);
    }
    dr_parallel_for(1024, fgrain, p2g_normalize, &nctx);
}

/* ---- G2P ---------------------------------------------------------------------------------------- */

typedef struct G2pCtx {
    const DrMacGrid *g;
    const double *const *old;
    DrTransferScheme scheme;
    double blend, tsign;
    const double *x;
    double *v, *c;
} G2pCtx;

/* Grid values of one component around a cell, mirror signs applied: the 4×3×3 nodes a particle of the
   cell can reach (see p2g_slab), u and the old u (FLIP). */
typedef struct G2pBlock { double u[36], uo[36]; int nb[3]; } G2pBlock;

static void g2p_load_block(const G2pCtx *ctx, int a, const int cell[3], G2pBlock *blk)
{
    const DrMacGrid *g = ctx->g;
    const int *dim = g->fdim[a];
    int idx[3][4];
    double sgn[3][4];
    for (int d = 0; d < 3; d++) {
        blk->nb[d] = d == a ? 4 : 3;
        for (int l = 0; l < blk->nb[d]; l++) {
            sgn[d][l] = 1.0;
            idx[d][l] = mirror(cell[d] - 1 + l, dim[d], a == d, ctx->tsign, &sgn[d][l]);
        }
    }
    const double *u = g->f[a], *uo = ctx->old ? ctx->old[a] : NULL;
    int n = 0;
    for (int lz = 0; lz < blk->nb[2]; lz++)
        for (int ly = 0; ly < blk->nb[1]; ly++) {
            long row = (long)dim[0] * (idx[1][ly] + (long)dim[1] * idx[2][lz]);
            for (int lx = 0; lx < blk->nb[0]; lx++, n++) {
                double sg = sgn[0][lx] * sgn[1][ly] * sgn[2][lz];
                long f = row + idx[0][lx];
                blk->u[n] = sg * u[f];
                blk->uo[n] = uo ? sg * uo[f] : 0.0;
            }
        }
}

/* Interpolated velocity, FLIP change and APIC moments of component a at grid coordinates X. With a
   block (particle inside the block's cell) the values come from it; otherwise straight from the grid.
   Both give bit-identical results: mirror signs are exact. */
static void g2p_component(const G2pCtx *ctx, int a, const double X[3], const int cell[3], const G2pBlock *blk,
                          double *vel_out, double *dvel_out, double moment[3])
{
    const DrMacGrid *g = ctx->g;
    const double dx = g->dx;
    bool apic = ctx->scheme == DR_TRANSFER_APIC || ctx->scheme == DR_TRANSFER_RPIC, flip = ctx->old != NULL;
    AxisStencil ax[3];
    int lo[3];
    bool inside = blk != NULL;
    for (int d = 0; d < 3; d++) {
        double sa = X[d] - dr_mac_face_offset(a, d);
        DrStencil3 st = dr_kernel_quadratic(sa);
        for (int q = 0; q < 3; q++) {
            ax[d].w[q] = st.w[q];
            ax[d].off[q] = dx * (st.base + q - sa);
        }
        lo[d] = st.base - (cell[d] - 1);
        if (!(lo[d] >= 0 && blk && lo[d] + 3 <= blk->nb[d])) inside = false;
    }
    if (!inside)
        for (int d = 0; d < 3; d++)
            ax[d] = axis_stencil(X[d] - dr_mac_face_offset(a, d), g->fdim[a][d], a == d, ctx->tsign, dx);
    const int *dim = g->fdim[a];
    const double *u = g->f[a], *uo = ctx->old ? ctx->old[a] : NULL;
    double vel = 0.0, dvel = 0.0, cx = 0.0, cy = 0.0, cz = 0.0;
    for (int kk = 0; kk < 3; kk++)
        for (int jj = 0; jj < 3; jj++) {
            double wyz = ax[1].w[jj] * ax[2].w[kk];
            /* along x: Σ w u and Σ w u Δx(i − s) of this row, then the row's weight */
            double r0 = 0.0, r1 = 0.0, rd = 0.0;
            if (inside) {
                int n0 = lo[0] + blk->nb[0] * ((lo[1] + jj) + blk->nb[1] * (lo[2] + kk));
                for (int ii = 0; ii < 3; ii++) {
                    double wu = ax[0].w[ii] * blk->u[n0 + ii];
                    r0 += wu;
                    r1 += wu * ax[0].off[ii];
                    if (flip) rd += ax[0].w[ii] * (blk->u[n0 + ii] - blk->uo[n0 + ii]);
                }
            } else {
                double syz = ax[1].sgn[jj] * ax[2].sgn[kk];
                long row = (long)dim[0] * (ax[1].idx[jj] + (long)dim[1] * ax[2].idx[kk]);
                for (int ii = 0; ii < 3; ii++) {
                    long f = row + ax[0].idx[ii];
                    double sg = syz * ax[0].sgn[ii];
                    double wu = ax[0].w[ii] * (sg * u[f]);
                    r0 += wu;
                    r1 += wu * ax[0].off[ii];
                    if (flip) rd += ax[0].w[ii] * (sg * u[f] - sg * uo[f]);
                }
            }
            vel += wyz * r0;
            dvel += wyz * rd;
            if (apic) {
                cx += wyz * r1;
                cy += wyz * r0 * ax[1].off[jj];
                cz += wyz * r0 * ax[2].off[kk];
            }
        }
    *vel_out = vel;
    *dvel_out = dvel;
    moment[0] = cx; moment[1] = cy; moment[2] = cz;
}

/* Particles sorted by cell (as the liquid keeps them) reuse each cell's blocks for all its particles. */
static void g2p_range(long begin, long end, void *vctx)
{
    G2pCtx *ctx = vctx;
    const DrMacGrid *g = ctx->g;
    const double inv = 1.0 / g->dx, dx = g->dx, dinv = 4.0 / (dx * dx); /* D⁻¹ = 4/Δx² */
    int n[3] = {g->nx, g->ny, g->nz};
    G2pBlock blk[3];
    int cached[3] = {-1, -1, -1};
    for (long p = begin; p < end; p++) {
        double X[3];
        int cell[3];
        for (int d = 0; d < 3; d++) {
            X[d] = (ctx->x[3 * p + d] - dr_v3_get(g->origin, d)) * inv;
            int i = (int)floor(X[d]);
            if (!(X[d] >= 0.0)) i = 0;
            if (i > n[d] - 1) i = n[d] - 1;
            cell[d] = i;
        }
        if (cell[0] != cached[0] || cell[1] != cached[1] || cell[2] != cached[2]) {
            for (int a = 0; a < 3; a++) g2p_load_block(ctx, a, cell, &blk[a]);
            memcpy(cached, cell, sizeof cached);
        }
        for (int a = 0; a < 3; a++) {
            double vel, dvel, mom[3];
            g2p_component(ctx, a, X, cell, &blk[a], &vel, &dvel, mom);
            if (ctx->scheme == DR_TRANSFER_FLIP)
                ctx->v[3 * p + a] = ctx->blend * vel + (1.0 - ctx->blend) * (ctx->v[3 * p + a] + dvel);
            else
                ctx->v[3 * p + a] = vel;
            if (ctx->c) {
                double *ca = ctx->c + 9 * p + 3 * a;
                if (ctx->scheme == DR_TRANSFER_APIC || ctx->scheme == DR_TRANSFER_RPIC) {
                    ca[0] = dinv * mom[0]; ca[1] = dinv * mom[1]; ca[2] = dinv * mom[2];
                } else {
                    ca[0] = ca[1] = ca[2] = 0.0;
                }
            }
        }
        /* RPIC ([APIC] §2.1): ω = K⁻¹ l̂ with K = m(tr D·I − D) = 2m·D for the isotropic D, which makes
           ω× the skew part of the APIC C = B D⁻¹; the affine rows are the skew part of the full matrix */
        if (ctx->scheme == DR_TRANSFER_RPIC) {
            double *cp = ctx->c + 9 * p;
            for (int r = 0; r < 3; r++)
                for (int q = r + 1; q < 3; q++) {
                    double w = 0.5 * (cp[3 * r + q] - cp[3 * q + r]);
                    cp[3 * r + q] = w;
                    cp[3 * q + r] = -w;
                }
            cp[0] = cp[4] = cp[8] = 0.0;
        }
    }
}

void dr_transfer_g2p_mac(const DrMacGrid *g, const double *const old[3], DrTransferScheme scheme,
                         double flip_blend, bool wall_no_slip, long n, const double *x, double *v, double *c)
{
    assert((scheme != DR_TRANSFER_APIC && scheme != DR_TRANSFER_RPIC) || c);
    assert(scheme != DR_TRANSFER_FLIP || old);
    G2pCtx ctx = {g, scheme == DR_TRANSFER_FLIP ? old : NULL, scheme, flip_blend, wall_no_slip ? -1.0 : 1.0,
                  x, v, c};
    dr_parallel_for(n, DR_TRANSFER_PAR_MIN / 4, g2p_range, &ctx);
}

/* ---- totals ----------------------------------------------------------------------------------- */

void dr_transfer_particle_totals(long n, const double *x, const double *v, const double *c, double mass,
                                 const double *scale, double dx, DrVec3 *momentum, DrVec3 *angular)
{
    DrVec3 P = dr_v3(0, 0, 0), L = dr_v3(0, 0, 0);
    double D = 0.25 * dx * dx;
    for (long p = 0; p < n; p++) {
        DrVec3 xp = dr_v3(x[3 * p], x[3 * p + 1], x[3 * p + 2]);
        double m = scale ? mass * scale[p] : mass;
        DrVec3 mv = dr_v3_scale(dr_v3(v[3 * p], v[3 * p + 1], v[3 * p + 2]), m);
        P = dr_v3_add(P, mv);
        L = dr_v3_add(L, dr_v3_cross(xp, mv));
        if (c) {
            /* m ε:(Bᵀ), B[b][a] = D c[3b + a] (see the derivation from eq. 26 in §5.3) */
            const double *cp = c + 9 * p;
            L = dr_v3_add(L, dr_v3_scale(dr_v3(cp[7] - cp[5], cp[2] - cp[6], cp[3] - cp[1]), m * D));
        }
    }
    if (momentum) *momentum = P;
    if (angular) *angular = L;
}

void dr_transfer_grid_totals(const DrMacGrid *g, const double *const face_mass[3], const double *const vel[3],
                             DrVec3 *momentum, DrVec3 *angular)
{
    DrVec3 P = dr_v3(0, 0, 0), L = dr_v3(0, 0, 0);
    for (int a = 0; a < 3; a++) {
        const int *dim = g->fdim[a];
        for (int k = 0; k < dim[2]; k++)
            for (int j = 0; j < dim[1]; j++)
                for (int i = 0; i < dim[0]; i++) {
                    long f = dr_mac_face_index(g, a, i, j, k);
                    if (face_mass[a][f] == 0.0) continue;
                    double mu = face_mass[a][f] * vel[a][f];
                    DrVec3 e = dr_v3(a == 0 ? mu : 0, a == 1 ? mu : 0, a == 2 ? mu : 0);
                    P = dr_v3_add(P, e);
                    L = dr_v3_add(L, dr_v3_cross(dr_mac_face_position(g, a, i, j, k), e));
                }
    }
    if (momentum) *momentum = P;
    if (angular) *angular = L;
}
