/* Position-level constraints on boundary-element bodies (BEM §3.4): fixed vertices, non-penetration with Coulomb
 * friction against signed-distance colliders and between bodies, and point joints between bodies.
 *
 * Each step:
 *  1. a trial step of every body with zero traction gives the unconstrained end-of-step positions V_free;
 *  2. the active set: fixed vertices, joints, vertices whose V_free lies closer to a collider than 2·thickness, and
 *     (body contact) vertices closer than that to, or slightly inside, another body's surface: the nearest triangle
 *     is found through the broad phase (contact.h) and the constraint acts on y = x − Σ_a w_a V_a (w the
 *     barycentric weights of the nearest point), its force split onto the triangle's vertices by the same weights;
 *  3. the response of the active vertices to forces at the active vertices, linearised as in eq. (14): a force f_j
 *     (world) at vertex j is the body-frame traction Δp_j = R_{k−1}ᵀ f_j / area_j and moves vertex i by
 *       ΔV_i = R̃ (H₀⁻¹G′)_ij Δp_j + Δt (Δω × q_i) + Δt² R_{k−1} A_j Δp_j,   Δω = Δt R_{k−1} C_j Δp_j,
 *     with R̃ = e^{Δt[ω_{k−1}]×} R_{k−1} and q_i = V_free,i − T̃ the lever arm about the predicted centre of mass
 *     (u = H₀⁻¹G′p + H₀⁻¹h by eq. 12, T by eq. 11d–f, R by eq. 11e–g; without the frame update u alone moves, by
     (H₀⁻¹G′ − EA − FC)Δp, and the step is exactly linear in p). These dense blocks are assembled once per
 *     step for the active vertices only (3 columns of H₀⁻¹G′ per active vertex), so a Gauss–Seidel sweep costs
 *     O(K²) and never touches an N-sized matrix;
 *  4. projected Gauss–Seidel over the constraints: fixed vertices and joints by a 3 × 3 block solve (equalities),
 *     contacts by a normal update projected on f_n ≥ 0 (gap ≥ 0, complementary) followed by a tangential update
 *     projected on the disk |f_t| ≤ μ f_n (a staggered normal/friction projection per contact). Friction acts at
 *     position level: the slip of a contact vertex over the step, measured from its position at the start of the
 *     step carried along by the collider's velocity, is driven to zero inside the cone;
 *  5. the linearisation misses the error correction of §3.2.1, the rotation's nonlinearity and curved colliders, so
 *     the forces found are tried (a trial step with them); where a constraint is still violated by more than the
 *     tolerance, the measured positions replace the linear prediction and the contacts are re-linearised at them
 *     (a chord iteration with the same response blocks), and Gauss–Seidel continues from the current forces. With the
     frame update a single pass (the paper's solve) leaves errors of order 1e-5 m on a held beam end; a second pass
     brings them to 1e-7 m;
 *  6. the real step of every body with the final tractions: the last trial of step 5 had them, so each body commits
 *     that trial (bem_solid.c keeps a solve until commit) and the step costs no solve of its own.
 * A vertex that is not active in step 2 gets no force in this step. */
#include "bem_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact.h"

void dr_bem_constraints_default(DrBemConstraints *c)
{
    *c = (DrBemConstraints){
        .thickness = 1e-4,
        .body_friction = 0.5,
        .max_iterations = 200,
        .max_passes = 8,
        .tolerance = 1e-7,
    };
}

/* ---- columns of H₀⁻¹G′ ------------------------------------------------------------------------------------
 * The compressed H₀⁻¹G′ stands for y = Pᵀ Wᵀ M̃ W P x (bem.h). For a unit vector x = e_i, W P e_i is nonzero only
 * in the Haar segment that holds the permuted index, at one place per level (about log₂ N + 1 values), so the
 * column is Pᵀ Wᵀ Σ_q x̃_q M̃_{·q}: a few columns of M̃ and one inverse transform, where a product with all of
 * M̃ would read every kept coefficient (2.4 M of them for 2906 vertices at 32×) for each column. The assembly needs
 * 3 columns per active vertex, so M̃ is kept by column as well (12 bytes per coefficient). */
struct BemColumns {
    int n;            /* 3N */
    int64_t *col_ptr; /* n + 1 */
    int32_t *row;     /* kept coefficients by column, rows ascending within a column */
    double *val;
    int *pos;         /* n: perm⁻¹, the coefficient-order position of each natural index */
};

void bem_columns_free(BemColumns **c)
{
    if (!c || !*c) return;
    free((*c)->col_ptr);
    free((*c)->row);
    free((*c)->val);
    free((*c)->pos);
    free(*c);
    *c = NULL;
}

/* The column copy of a compressed (not dense) matrix: a counting pass, then the rows in order, so the copy does
   not depend on the thread count. */
static DrStatus columns_build(const DrBemLayout *l, const DrBemCMat *m, BemColumns **out, DrError *err)
{
    assert(!m->dense && m->n == 3 * l->nv);
    int n = m->n;
    size_t nnz = (size_t)m->nnz, cap = nnz > 0 ? nnz : 1;
    BemColumns *g = NULL;
    int64_t *next = NULL;
    DR_TRY(dr_calloc(1, sizeof *g, &g, err));
    g->n = n;
    DrStatus st = dr_calloc((size_t)n + 1, sizeof(int64_t), &g->col_ptr, err);
    if (st == DR_OK) st = dr_calloc(cap, sizeof(int32_t), &g->row, err);
    if (st == DR_OK) st = dr_calloc(cap, sizeof(double), &g->val, err);
    if (st == DR_OK) st = dr_calloc((size_t)n, sizeof(int), &g->pos, err);
    if (st == DR_OK) st = dr_calloc((size_t)n, sizeof(int64_t), &next, err);
    if (st != DR_OK) {
        bem_columns_free(&g);
        return st;
    }
    for (int64_t k = 0; k < m->nnz; k++) g->col_ptr[m->col[k] + 1]++;
    for (int q = 0; q < n; q++) g->col_ptr[q + 1] += g->col_ptr[q];
    memcpy(next, g->col_ptr, sizeof(int64_t) * (size_t)n);
    for (int i = 0; i < n; i++)
        for (int64_t k = m->row_ptr[i]; k < m->row_ptr[i + 1]; k++) {
            int64_t d = next[m->col[k]]++;
            g->row[d] = i;
            g->val[d] = m->val[k];
        }
    for (int i = 0; i < n; i++) g->pos[l->perm[i]] = i;
    free(next);
    *out = g;
    return DR_OK;
}

/* y = H₀⁻¹G′ e_i (natural order) for the compressed matrix m with column copy g; work holds 4n doubles. The
   Haar segments are those of bem.h: the coordinate blocks of length N in the xyz orders, all 3N otherwise. */
static void columns_unit_product(const DrBemLayout *l, const BemColumns *g, int i, double *y, double *work)
{
    int n = g->n, p = g->pos[i];
    int seglen = l->ordering != DR_BEM_ORDER_NONE ? l->nv : n;
    int q0 = l->wavelet ? p - p % seglen : p, len = l->wavelet ? seglen : 1; /* where x̃ = W P e_i may be nonzero */
    double *xt = work, *yt = work + n, *scratch = work + 2 * n;
    memset(xt + q0, 0, sizeof(double) * (size_t)len);
    xt[p] = 1;
    if (l->wavelet) dr_bem_haar_forward(xt + q0, seglen, scratch);
    memset(yt, 0, sizeof(double) * (size_t)n);
    for (int q = q0; q < q0 + len; q++) {
        double x = xt[q];
        if (x == 0) continue;
        for (int64_t k = g->col_ptr[q]; k < g->col_ptr[q + 1]; k++) yt[g->row[k]] += x * g->val[k];
    }
    dr_bem_layout_from_coeff(l, false, yt, y, scratch);
}

/* ---- small 3-vector and 3×3 helpers ----------------------------------------------------------------------- */

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* Two unit tangents completing the unit normal n to an orthonormal basis. */
static void tangent_basis(const double n[3], double t1[3], double t2[3])
{
    double a[3] = {0, 0, 0};
    a[fabs(n[0]) < 0.57 ? 0 : (fabs(n[1]) < 0.57 ? 1 : 2)] = 1;
    double d = dot3(a, n);
    for (int c = 0; c < 3; c++) t1[c] = a[c] - d * n[c];
    double l = sqrt(dot3(t1, t1));
    for (int c = 0; c < 3; c++) t1[c] /= l;
    t2[0] = n[1] * t1[2] - n[2] * t1[1];
    t2[1] = n[2] * t1[0] - n[0] * t1[2];
    t2[2] = n[0] * t1[1] - n[1] * t1[0];
}

/* ---- step data -------------------------------------------------------------------------------------------- */

enum { CON_FIXED, CON_CONTACT, CON_JOINT, CON_BODY }; /* CON_BODY: a vertex against another body */

/* One active constraint: a relation on y = Σ_e w_e V(end e), with the force w_e f at end e (w = ±1 for fixed vertices
   and joints; 1 and −barycentric weights for a vertex against another body's triangle, BEM §3.4). */
typedef struct Con {
    int type, ne;
    int body[4], vertex[4], local[4]; /* ends: body, mesh vertex, index into the body's active vertex list */
    double wt[4];
    double target[3];      /* fixed: the position; joint: 0 */
    int collider;
    double mu;
    double g0, vref[3];    /* contact: sdf at the linearisation point vref */
    double n[3], t1[3], t2[3];
    double slip0[3];       /* contact: where a sticking vertex ends the step (start position + collider motion) */
    double f[3];           /* world force, N */
    double Kinv[9];        /* fixed/joint: inverse of the 3 × 3 diagonal block of the response */
    double K[9];           /* contact: the 3 × 3 diagonal block of the response */
    double knn, Ktt[4];    /* contact: nᵀKn and the tangential 2 × 2 block's inverse */
} Con;

/* One body of a group step. Its arrays are kept from step to step (in the group's BemGroupWork) and grow only when a
   step needs more than any before, with headroom (grow below). */
typedef struct Body {
    DrBemSolid *s;
    int na;           /* active vertices */
    int *act;         /* active vertex → mesh vertex, room for nv */
    int *map;         /* mesh vertex → active index or −1, nv */
    double *V0;       /* 3N positions of the zero-force trial */
    double *Vstart;   /* 3N positions at the start of the step */
    double *Vt;       /* 3N positions of the latest trial */
    double *p;        /* 3N tractions, body frame */
    float *W;         /* (3·na)², by column: ΔV_active = W F_active, element (r, c) at W[c·3·na + r]; single
                         precision halves the sweeps' memory traffic (see "the predictions during a sweep") */
    double *F;        /* 3·na summed vertex forces, world */
    double *P;        /* 3·na predicted positions of the active vertices */
    const double *force; /* 3N external forces of the current solve (world, N), or NULL */
    size_t map_cap, act_cap, v_cap, w_cap, f_cap, p_cap; /* capacities of map, act (ints), V0/Vstart/Vt/p, W
                                                            (floats), F, P */
} Body;

/* *ptr holds at least `need` elements of `size` bytes (contents kept); a growth takes half as much again, so a step
   needing slightly more than the last does not allocate. */
static DrStatus grow(void *ptr, size_t *cap, size_t need, size_t size, DrError *err)
{
    if (need <= *cap) return DR_OK;
    size_t want = need + need / 2 + 16;
    DR_TRY(dr_realloc(want, size, ptr, err));
    *cap = want;
    return DR_OK;
}

static void body_add_active(Body *b, int v)
{
    if (b->map[v] >= 0) return;
    b->map[v] = b->na;
    b->act[b->na++] = v;
}

/* What the response blocks of one body's active vertices share (step 3 of the banner). */
typedef struct Assembly {
    Body *b;
    bool frame;
    double Rt_[9], Rtil[9], Ttil[3]; /* Rᵀ_{k−1}, R̃ and T̃ */
    int slots;                       /* ranges of active vertices, one per thread */
    size_t stride;                   /* doubles of work per slot: 3·k3 for a block column, 5n for a column of H₀⁻¹G′ */
    double *work;
} Assembly;

/* Columns 3jj..3jj+2 of W: the response of every active vertex to a force at active vertex jj. */
static void assemble_vertex(const Assembly *as, int jj, double *work)
{
    const Body *b = as->b;
    const DrBemSolid *s = b->s;
    const DrBemMatrices *m = s->m;
    int n = s->n, na = b->na, k3 = 3 * na, j = b->act[jj];
    double dt = m->desc.dt;
    double *Mblk = work, *y = work + (size_t)3 * k3; /* Mblk: 3·na × 3, rows = active vertices */
    /* column j·3+c of the displacement response to body-frame tractions: H₀⁻¹G′ with the frame, and
       H₀⁻¹G′ − E A − F C without it (u = z + E b + F α with b, α independent of p, bem_solid.c step 2) */
    for (int c = 0; c < 3; c++) {
        int cj = 3 * j + c;
        if (m->H0inv_Gp.dense) {
            for (int ii = 0; ii < na; ii++)
                for (int r = 0; r < 3; r++)
                    Mblk[(3 * ii + r) * 3 + c] = m->H0inv_Gp.val[(size_t)(3 * b->act[ii] + r) * n + cj];
        } else {
            columns_unit_product(&m->layout, s->rt->gp_cols, cj, y, y + n);
            for (int ii = 0; ii < na; ii++)
                for (int r = 0; r < 3; r++) Mblk[(3 * ii + r) * 3 + c] = y[3 * b->act[ii] + r];
        }
        if (!as->frame)
            for (int ii = 0; ii < na; ii++)
                for (int r = 0; r < 3; r++) {
                    int row = 3 * b->act[ii] + r;
                    double ea = 0;
                    for (int q = 0; q < 3; q++)
                        ea += s->E[3 * row + q] * m->A[(size_t)q * n + cj] +
                              s->F[3 * row + q] * m->C[(size_t)q * n + cj];
                    Mblk[(3 * ii + r) * 3 + c] -= ea;
                }
    }
    double inv_area = 1.0 / m->area[j];
    double Aj[9], Cj[9], RA[9], RC[9];
    for (int q = 0; q < 3; q++)
        for (int c = 0; c < 3; c++) {
            Aj[3 * q + c] = m->A[(size_t)q * n + 3 * j + c];
            Cj[3 * q + c] = m->C[(size_t)q * n + 3 * j + c];
        }
    dr_m3a_mul(s->R, Aj, RA);
    dr_m3a_mul(s->R, Cj, RC);
    float *W0 = &b->W[(size_t)(3 * jj) * k3];
    for (int ii = 0; ii < na; ii++) {
        int i = b->act[ii];
        double blk[9], tmp[9];
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) tmp[3 * r + c] = Mblk[(3 * ii + r) * 3 + c];
        dr_m3a_mul(as->Rtil, tmp, blk); /* R̃ M_ij */
        if (as->frame) {
            double q[3], Q[9];
            for (int c = 0; c < 3; c++) q[c] = b->V0[3 * i + c] - as->Ttil[c];
            double X[9] = {0, -q[2], q[1], q[2], 0, -q[0], -q[1], q[0], 0};
            dr_m3a_mul(X, RC, Q); /* Δω × q = −[q]× Δω */
            for (int t = 0; t < 9; t++) blk[t] += dt * dt * (RA[t] - Q[t]);
        }
        dr_m3a_mul(blk, as->Rt_, tmp); /* f (world) → p = Rᵀ f / area */
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) W0[(size_t)c * k3 + 3 * ii + r] = (float)(tmp[3 * r + c] * inv_area);
    }
}

/* Slots [begin, end): each works through its own range of active vertices with its own work space, so every column
   of W is computed by one thread in a fixed order and W does not depend on the thread count. */
static void assemble_slots(long begin, long end, void *ctx)
{
    const Assembly *as = ctx;
    long na = as->b->na;
    for (long t = begin; t < end; t++)
        for (long jj = na * t / as->slots; jj < na * (t + 1) / as->slots; jj++)
            assemble_vertex(as, (int)jj, as->work + (size_t)t * as->stride);
}

/* The response blocks W of the active vertices (step 3 of the banner), stored by column: element (r, c) of the
   k3 × k3 matrix at W[c·k3 + r], so a force at one vertex updates the predictions from 3 contiguous columns. */
static DrStatus body_assemble(Body *b, double **work, size_t *work_cap, DrError *err)
{
    DrBemSolid *s = b->s;
    const DrBemMatrices *m = s->m;
    int n = s->n, na = b->na, k3 = 3 * na;
    double dt = m->desc.dt;
    if ((size_t)k3 * k3 > b->w_cap) { /* headroom in active vertices: W grows with their square */
        size_t k3h = 3 * ((size_t)na + (size_t)na / 2 + 8);
        DR_TRY(dr_realloc(k3h * k3h, sizeof(float), &b->W, err));
        b->w_cap = k3h * k3h;
    }
    DR_TRY(grow(&b->F, &b->f_cap, (size_t)k3, sizeof(double), err));
    DR_TRY(grow(&b->P, &b->p_cap, (size_t)k3, sizeof(double), err));
    if (na == 0) return DR_OK;
    if (!m->H0inv_Gp.dense && !s->rt->gp_cols) DR_TRY(columns_build(&m->layout, &m->H0inv_Gp, &s->rt->gp_cols, err));
    Assembly as = {.b = b, .frame = s->d.frame_update};
    const double *R = s->R;
    dr_m3a_transpose(R, as.Rt_);
    if (as.frame) {
        double E[9]; /* e^{Δt[ω]×} (eq. 11g) */
        dr_m3_store(dr_m3_rotation_exp(dr_v3(dt * s->omega[0], dt * s->omega[1], dt * s->omega[2])), E);
        dr_m3a_mul(E, R, as.Rtil);
        for (int c = 0; c < 3; c++) as.Ttil[c] = s->T[c] + dt * (s->Tdot[c] + dt * s->d.gravity[c]);
    } else {
        memcpy(as.Rtil, R, sizeof as.Rtil);
    }
    int threads = dr_threads();
    as.slots = threads < 1 ? 1 : (threads < na ? threads : na);
    as.stride = (size_t)3 * k3 + (m->H0inv_Gp.dense ? 0 : (size_t)5 * n);
    DR_TRY(grow(work, work_cap, (size_t)as.slots * as.stride, sizeof(double), err)); /* every entry written before read */
    as.work = *work;
    dr_parallel_for(as.slots, 1, assemble_slots, &as);
    return DR_OK;
}

/* The tractions of the summed active-vertex forces (body frame, start-of-step rotation as in eqs. 11d–e). */
static void body_tractions(Body *b)
{
    const DrBemSolid *s = b->s;
    memset(b->p, 0, sizeof(double) * s->n);
    for (int a = 0; a < b->na; a++) {
        int v = b->act[a];
        double pw[3];
        for (int c = 0; c < 3; c++) pw[c] = 0;
        for (int c = 0; c < 3; c++)
            for (int r = 0; r < 3; r++) pw[c] += s->R[3 * r + c] * b->F[3 * a + r]; /* Rᵀ F */
        for (int c = 0; c < 3; c++) b->p[3 * v + c] = pw[c] / s->m->area[v];
    }
}

/* ---- the predictions during a sweep ---------------------------------------------------------------------------
 * A force change at active vertex a moves every prediction, P += W[:, 3a..3a+2] δ: a pass over 3 columns of W, and
 * a sweep passes over all of W, which memory bandwidth bounds. W is therefore held in single precision (10 MB for
 * 529 active vertices, not 20): its rounding, 6e-8 relative, moves the linear prediction far less than the
 * linearisation itself does, and the trial steps of step 5 measure the positions the forces give, so the tolerance
 * the solve meets is unchanged (2,906 vertices resting on 529: the same 337 sweeps and pose; the sweeps 1.6× faster
 * on 2 threads). The changes of a block of consecutive constraints (at most PGS_BLOCK ends) are also collected and
 * applied to P together, split over threads by rows. A constraint inside the block sees the block's earlier changes
 * through the 3 × 3 blocks of W that couple its ends to theirs, copied once per step into a panel in the order the
 * sweep reads them (picked out of W in every sweep they would cost a cache miss each). Every entry of P and every
 * constraint value receives the same terms in the same order as when each change is applied at once, so the result
 * depends on neither the blocking nor the thread count. */
#define PGS_BLOCK 64
_Static_assert(PGS_BLOCK >= 4, "a block holds the ends of at least one constraint");

/* Values of W a range of rows must hold to be worth a thread (a team start costs some microseconds, a pass over
   64 K doubles some tens). */
#define PAR_VALUES 65536

static bool force_blocks;

void bem_constraints_force_blocks(bool on) { force_blocks = on; }

typedef struct Update {
    int body, a;  /* active vertex a of body */
    double de[3]; /* force change, world */
} Update;

typedef struct Block {
    int n;
    Update upd[PGS_BLOCK];
} Block;

/* The blocks of a step's constraints and their panel. */
typedef struct Sweep {
    int nblocks;
    int *start;      /* nblocks + 1: the first constraint of each block */
    int64_t *offset; /* nc: where each constraint's part of the panel begins */
    double *panel;   /* per constraint, end e, earlier end f of the block on the same body: W(rows of e, columns of f),
                        3 × 3 row-major */
    size_t start_cap, offset_cap, panel_cap; /* kept from step to step */
} Sweep;

static void sweep_free(Sweep *sw)
{
    free(sw->start);
    free(sw->offset);
    free(sw->panel);
    memset(sw, 0, sizeof *sw);
}

/* The blocks and the panel for the assembled W (step 3). Blocks pay only where a block's changes are split over
   threads; elsewhere each constraint is a block of its own and the panel is empty. */
static DrStatus sweep_init(const Body *bodies, int count, const Con *cons, int nc, Sweep *sw, DrError *err)
{
    sw->nblocks = 0;
    long rows = 0;
    for (int i = 0; i < count; i++) rows = bodies[i].na > rows ? bodies[i].na : rows;
    rows *= 3;
    int max_ends = force_blocks || (dr_threads() > 1 && 3 * PGS_BLOCK * rows >= 2 * PAR_VALUES) ? PGS_BLOCK : 1;
    DR_TRY(grow(&sw->start, &sw->start_cap, (size_t)nc + 1, sizeof(int), err));
    for (int i = 0, ends = max_ends; i < nc; i++) {
        if (ends + cons[i].ne > max_ends) {
            sw->start[sw->nblocks++] = i;
            ends = 0;
        }
        ends += cons[i].ne;
    }
    sw->start[sw->nblocks] = nc;
    DR_TRY(grow(&sw->offset, &sw->offset_cap, (size_t)nc + 1, sizeof(int64_t), err));
    int64_t len = 0;
    for (int bl = 0; bl < sw->nblocks; bl++)
        for (int i = sw->start[bl]; i < sw->start[bl + 1]; i++) {
            sw->offset[i] = len;
            for (int e = 0; e < cons[i].ne; e++)
                for (int j = sw->start[bl]; j < i; j++)
                    for (int f = 0; f < cons[j].ne; f++) len += 9 * (cons[j].body[f] == cons[i].body[e]);
        }
    sw->offset[nc] = len;
    DR_TRY(grow(&sw->panel, &sw->panel_cap, len > 0 ? (size_t)len : 1, sizeof(double), err)); /* filled below */
    for (int bl = 0; bl < sw->nblocks; bl++)
        for (int i = sw->start[bl]; i < sw->start[bl + 1]; i++) {
            double *pn = &sw->panel[sw->offset[i]];
            for (int e = 0; e < cons[i].ne; e++) {
                const Body *b = &bodies[cons[i].body[e]];
                int row = 3 * cons[i].local[e], k3 = 3 * b->na;
                for (int j = sw->start[bl]; j < i; j++)
                    for (int f = 0; f < cons[j].ne; f++) {
                        if (cons[j].body[f] != cons[i].body[e]) continue;
                        const float *w = &b->W[(size_t)(3 * cons[j].local[f]) * k3 + row];
                        for (int r = 0; r < 3; r++)
                            for (int c = 0; c < 3; c++) pn[3 * r + c] = w[(size_t)c * k3 + r];
                        pn += 9;
                    }
            }
        }
    return DR_OK;
}

/* Record a force change δ of constraint k (w_e δ at end e) and add it to the summed vertex forces. */
static void block_add(Body *bodies, Block *blk, const Con *k, const double d[3])
{
    for (int e = 0; e < k->ne; e++) {
        Body *b = &bodies[k->body[e]];
        int a = k->local[e];
        Update *u = &blk->upd[blk->n++];
        *u = (Update){.body = k->body[e], .a = a, .de = {k->wt[e] * d[0], k->wt[e] * d[1], k->wt[e] * d[2]}};
        for (int c = 0; c < 3; c++) b->F[3 * a + c] += u->de[c];
    }
}

/* y = Σ_e w_e P_e for constraint i, with the block's changes so far added to P_e. */
static void block_value(const Body *bodies, const Sweep *sw, const Block *blk, const Con *cons, int i, double y[3])
{
    const Con *k = &cons[i];
    const double *pn = &sw->panel[sw->offset[i]];
    y[0] = y[1] = y[2] = 0;
    for (int e = 0; e < k->ne; e++) {
        const double *P = &bodies[k->body[e]].P[3 * k->local[e]];
        double p[3] = {P[0], P[1], P[2]};
        for (int q = 0; q < blk->n; q++) {
            const Update *u = &blk->upd[q];
            if (u->body != k->body[e]) continue;
            for (int r = 0; r < 3; r++)
                p[r] += pn[3 * r] * u->de[0] + pn[3 * r + 1] * u->de[1] + pn[3 * r + 2] * u->de[2];
            pn += 9;
        }
        for (int c = 0; c < 3; c++) y[c] += k->wt[e] * p[c];
    }
}

typedef struct Flush {
    Body *b;
    int body;
    const Block *blk;
} Flush;

/* Rows [8·begin, 8·end) of one body's predictions take the block's changes (ranges of whole cache lines). */
static void flush_rows(long begin, long end, void *ctx)
{
    const Flush *f = ctx;
    int k3 = 3 * f->b->na, r0 = (int)(8 * begin), r1 = (int)(8 * end < k3 ? 8 * end : k3);
    double *restrict P = f->b->P;
    for (int i = 0; i < f->blk->n; i++) {
        const Update *u = &f->blk->upd[i];
        if (u->body != f->body) continue;
        const float *restrict w0 = &f->b->W[(size_t)(3 * u->a) * k3], *restrict w1 = w0 + k3, *restrict w2 = w1 + k3;
        double d0 = u->de[0], d1 = u->de[1], d2 = u->de[2];
#pragma omp simd
        for (int r = r0; r < r1; r++) P[r] += w0[r] * d0 + w1[r] * d1 + w2[r] * d2;
    }
}

/* Apply the block's changes to the predictions of every body and empty it. */
static void block_flush(Body *bodies, int count, Block *blk)
{
    for (int i = 0; i < count; i++) {
        int nu = 0;
        for (int q = 0; q < blk->n; q++) nu += blk->upd[q].body == i;
        if (nu == 0) continue;
        Flush f = {.b = &bodies[i], .body = i, .blk = blk};
        long lines = (3L * bodies[i].na + 7) / 8, grain = PAR_VALUES / (8 * 3 * (long)nu) + 1;
        dr_parallel_for(lines, grain, flush_rows, &f);
    }
    blk->n = 0;
}

/* The 3 × 3 diagonal block of the constraint response: Σ_e Σ_e' s_e s_e' W(e, e') over ends on one body. */
static void con_block(const Body *bodies, const Con *k, double K[9])
{
    memset(K, 0, sizeof(double) * 9);
    for (int e = 0; e < k->ne; e++)
        for (int f = 0; f < k->ne; f++) {
            if (k->body[e] != k->body[f]) continue;
            const Body *b = &bodies[k->body[e]];
            int k3 = 3 * b->na;
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++)
                    K[3 * r + c] +=
                        k->wt[e] * k->wt[f] * b->W[(size_t)(3 * k->local[f] + c) * k3 + 3 * k->local[e] + r];
        }
}

static void contact_prepare(const Body *bodies, Con *k)
{
    double *K = k->K, Kn[3], Kt[4];
    con_block(bodies, k, K);
    dr_m3a_apply(K, k->n, Kn);
    k->knn = dot3(k->n, Kn);
    const double *ts[2] = {k->t1, k->t2};
    for (int a = 0; a < 2; a++)
        for (int c = 0; c < 2; c++) {
            double Kc[3];
            dr_m3a_apply(K, ts[c], Kc);
            Kt[2 * a + c] = dot3(ts[a], Kc);
        }
    double det = Kt[0] * Kt[3] - Kt[1] * Kt[2];
    k->Ktt[0] = Kt[3] / det;
    k->Ktt[1] = -Kt[1] / det;
    k->Ktt[2] = -Kt[2] / det;
    k->Ktt[3] = Kt[0] / det;
}

/* One projected Gauss–Seidel sweep. Returns the largest force change; *viol the largest linearised violation met. */
static double pgs_sweep(Body *bodies, int count, Con *cons, const Sweep *sw, double thickness, double *viol)
{
    double dmax = 0, vmax = 0;
    int nc = sw->start[sw->nblocks];
    Block blk = {0};
    for (int i = 0, bl = 0; i < nc; i++) {
        if (i == sw->start[bl + 1]) {
            block_flush(bodies, count, &blk);
            bl++;
        }
        Con *k = &cons[i];
        double y[3], d[3];
        block_value(bodies, sw, &blk, cons, i, y);
        if (k->type == CON_FIXED || k->type == CON_JOINT) {
            double r[3];
            for (int c = 0; c < 3; c++) r[c] = k->target[c] - y[c];
            vmax = fmax(vmax, sqrt(dot3(r, r)));
            dr_m3a_apply(k->Kinv, r, d);
            for (int c = 0; c < 3; c++) k->f[c] += d[c];
            block_add(bodies, &blk, k, d);
            dmax = fmax(dmax, sqrt(dot3(d, d)));
            continue;
        }
        /* normal: gap = g0 + n·(y − vref) − thickness ≥ 0, f_n ≥ 0, gap·f_n = 0 */
        double dy[3] = {y[0] - k->vref[0], y[1] - k->vref[1], y[2] - k->vref[2]};
        double gap = k->g0 + dot3(k->n, dy) - thickness;
        double fn = dot3(k->f, k->n);
        if (fn > 0 || gap < 0) vmax = fmax(vmax, fmax(-gap, 0));
        double fn_new = fmax(0.0, fn - gap / k->knn), dfn = fn_new - fn;
        double dn[3], Kdn[3];
        for (int c = 0; c < 3; c++) dn[c] = dfn * k->n[c];
        double change = fabs(dfn);
        /* friction: drive the slip y − slip0 in the tangent plane to zero, then project on |f_t| ≤ μ f_n. The value
           after the normal update is y + K δn (K this constraint's own block), so both updates reach the predictions
           as one change and a sweep reads W once, not twice */
        dr_m3a_apply(k->K, dn, Kdn);
        for (int c = 0; c < 3; c++) y[c] += Kdn[c];
        double sl[3] = {y[0] - k->slip0[0], y[1] - k->slip0[1], y[2] - k->slip0[2]};
        double s1 = dot3(sl, k->t1), s2 = dot3(sl, k->t2);
        double ft1 = dot3(k->f, k->t1) , ft2 = dot3(k->f, k->t2);
        double n1 = ft1 - (k->Ktt[0] * s1 + k->Ktt[1] * s2), n2 = ft2 - (k->Ktt[2] * s1 + k->Ktt[3] * s2);
        double lim = k->mu * fn_new, len = sqrt(n1 * n1 + n2 * n2);
        if (len > lim) {
            double sc = len > 0 ? lim / len : 0;
            n1 *= sc;
            n2 *= sc;
        }
        for (int c = 0; c < 3; c++) d[c] = (n1 - ft1) * k->t1[c] + (n2 - ft2) * k->t2[c];
        double dsum[3] = {dn[0] + d[0], dn[1] + d[1], dn[2] + d[2]};
        block_add(bodies, &blk, k, dsum);
        for (int c = 0; c < 3; c++) k->f[c] += d[c] + dfn * k->n[c];
        dmax = fmax(dmax, fmax(change, sqrt(dot3(d, d))));
    }
    block_flush(bodies, count, &blk);
    *viol = vmax;
    return dmax;
}

static void body_free(Body *b)
{
    free(b->act);
    free(b->map);
    free(b->V0);
    free(b->Vstart);
    free(b->Vt);
    free(b->p);
    free(b->W);
    free(b->F);
    free(b->P);
}

static DrStatus check_input(DrBemSolid *const *solids, int count, const DrBemConstraints *c, DrError *err)
{
    const char *fix = "fix the constraint description";
    if (count < 0 || (count > 0 && !solids))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "BEM constraints: %d bodies given; %s", count, fix);
    for (int i = 0; i < count; i++)
        if (solids[i]->m->desc.dt != solids[0]->m->desc.dt)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "BEM constraints: body %d has time step %g s where body 0 has %g s; precompute all "
                                "bodies of one solve with the same time step",
                                i, solids[i]->m->desc.dt, solids[0]->m->desc.dt);
    if (!c) return DR_OK;
    if (!(c->thickness >= 0) || c->max_iterations < 1 || c->max_passes < 1 || !(c->tolerance > 0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "BEM constraints: thickness %g m, %d iterations, %d passes, tolerance %g m; need "
                            "thickness >= 0, at least one iteration and pass, and a positive tolerance",
                            c->thickness, c->max_iterations, c->max_passes, c->tolerance);
    if (c->body_contact && !(c->body_friction >= 0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "BEM constraints: body friction %g; give a coefficient >= 0", c->body_friction);
    for (int i = 0; i < c->collider_count; i++)
        if (!c->colliders[i].sdf || !(c->colliders[i].friction >= 0))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "BEM constraints: collider %d has %s; give a signed distance function and a "
                                "friction coefficient >= 0",
                                i,
                                c->colliders[i].sdf ? "a negative or NaN friction coefficient"
                                                    : "no signed distance function");
    for (int i = 0; i < c->fixed_count; i++) {
        const DrBemFixed *f = &c->fixed[i];
        if (f->body < 0 || f->body >= count || f->vertex < 0 || f->vertex >= solids[f->body]->nv ||
            !isfinite(f->target[0]) || !isfinite(f->target[1]) || !isfinite(f->target[2]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "BEM constraints: fixed vertex %d names body %d vertex %d (or a non-finite target); "
                                "there are %d bodies; %s",
                                i, f->body, f->vertex, count, fix);
    }
    for (int i = 0; i < c->joint_count; i++) {
        const DrBemJoint *j = &c->joints[i];
        for (int e = 0; e < 2; e++)
            if (j->body[e] < 0 || j->body[e] >= count || j->vertex[e] < 0 || j->vertex[e] >= solids[j->body[e]]->nv)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "BEM constraints: joint %d end %d names body %d vertex %d; there are %d bodies; %s",
                                    i, e, j->body[e], j->vertex[e], count, fix);
    }
    return DR_OK;
}

/* The unit normal of triangle (a, b, c) (outward for the checked, outward-oriented meshes). */
static void tri_normal(const double *a, const double *b, const double *c, double n[3])
{
    double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double l = sqrt(dot3(n, n));
    for (int q = 0; q < 3; q++) n[q] = l > 0 ? n[q] / l : 0;
}

/* The relation value y = Σ_e w_e V(end e) at full-mesh positions (V[b] the 3N positions of body b). */
static void con_value_at(const Con *k, double *const *V, double y[3])
{
    y[0] = y[1] = y[2] = 0;
    for (int e = 0; e < k->ne; e++)
        for (int q = 0; q < 3; q++) y[q] += k->wt[e] * V[k->body[e]][3 * k->vertex[e] + q];
}

/* A vertex against a triangle of another body, linearised at the positions V: the triangle's normal, and the gap
   n·(x − c) at the fixed barycentric point c = Σ w V_tri (y = x − c). */
static void body_linearise(Con *k, double *const *V)
{
    const double *a = &V[k->body[1]][3 * k->vertex[1]], *b = &V[k->body[2]][3 * k->vertex[2]],
                 *cc = &V[k->body[3]][3 * k->vertex[3]];
    tri_normal(a, b, cc, k->n);
    tangent_basis(k->n, k->t1, k->t2);
    con_value_at(k, V, k->vref);
    k->g0 = dot3(k->n, k->vref);
}

/* Largest fixed/joint error and penetration at the trial positions Vt; contacts are re-linearised there. */
static double measure(Con *cons, int nc, const DrBemConstraints *c, double *const *Vt, bool relinearise)
{
    double res = 0;
    for (int i = 0; i < nc; i++) {
        Con *k = &cons[i];
        double y[3];
        con_value_at(k, Vt, y);
        if (k->type == CON_FIXED || k->type == CON_JOINT) {
            double r[3] = {y[0] - k->target[0], y[1] - k->target[1], y[2] - k->target[2]};
            res = fmax(res, sqrt(dot3(r, r)));
            continue;
        }
        if (k->type == CON_BODY) {
            double dy[3] = {y[0] - k->vref[0], y[1] - k->vref[1], y[2] - k->vref[2]};
            double gap = k->g0 + dot3(k->n, dy);
            if (relinearise) body_linearise(k, Vt);
            res = fmax(res, c->thickness - gap);
            continue;
        }
        const double *x = y;
        double g[3] = {0, 0, 0};
        const DrBemCollider *col = &c->colliders[k->collider];
        double phi = col->sdf(x, g, col->ctx);
        res = fmax(res, c->thickness - phi);
        double gl = sqrt(dot3(g, g));
        if (relinearise && gl > 0 && isfinite(phi)) {
            k->g0 = phi;
            memcpy(k->vref, x, sizeof k->vref);
            for (int q = 0; q < 3; q++) k->n[q] = g[q] / gl;
            tangent_basis(k->n, k->t1, k->t2);
        }
    }
    return res;
}

/* ---- body–body detection: vertices against triangles in the broad phase ----------------------------------- */

/* What detection keeps from step to step: the broad phase (created on first use) and, per vertex of the body being
   tested, where its candidates lie in the broad phase's pair list. */
typedef struct CandidateSpan { long begin, end; } CandidateSpan;

typedef struct Detect {
    DrBroadPhase *bp;
    CandidateSpan *span; /* span_cap */
    size_t span_cap;
} Detect;

/* The point of triangle (a, b, c) closest to x, as barycentric weights w. */
static void closest_on_triangle(const double *x, const double *a, const double *b, const double *c, double w[3])
{
    double e1[3], e2[3], r[3];
    for (int q = 0; q < 3; q++) e1[q] = b[q] - a[q], e2[q] = c[q] - a[q], r[q] = x[q] - a[q];
    double d11 = dot3(e1, e1), d12 = dot3(e1, e2), d22 = dot3(e2, e2), r1 = dot3(r, e1), r2 = dot3(r, e2);
    double det = d11 * d22 - d12 * d12;
    double s = (d22 * r1 - d12 * r2) / det, t = (d11 * r2 - d12 * r1) / det;
    if (s >= 0 && t >= 0 && s + t <= 1) {
        w[0] = 1 - s - t, w[1] = s, w[2] = t;
        return;
    }
    /* outside: the nearest of the three edges */
    const double *p[3] = {a, b, c};
    double best = INFINITY;
    for (int e = 0; e < 3; e++) {
        const double *p0 = p[e], *p1 = p[(e + 1) % 3];
        double d[3], q0[3];
        for (int q = 0; q < 3; q++) d[q] = p1[q] - p0[q], q0[q] = x[q] - p0[q];
        double u = fmin(1, fmax(0, dot3(q0, d) / dot3(d, d))), dist = 0;
        for (int q = 0; q < 3; q++) dist += pow(q0[q] - u * d[q], 2);
        if (dist < best) {
            best = dist;
            w[e] = 1 - u, w[(e + 1) % 3] = u, w[(e + 2) % 3] = 0;
        }
    }
}

/* Vertices of body a within 2·thickness of (or at most h inside) the surface of body b, at the trial positions.
 *
 * The candidates of a vertex are the triangles of b whose bounding box, grown by h, holds it: the broad phase's
 * pairs between the vertices of a (points, boxes 0 .. nv_a − 1) and those boxes (nv_a + t), taken across the split
 * so that the triangles' pairs among themselves are never tested. A vertex is a point, so it lies in one cell and
 * owns all its pairs there; within a cell the pairs come by increasing first box, then second (contact.h), so a
 * vertex's candidates are one run of the pair list in increasing triangle order, which the nearest-triangle search
 * below needs: its tie rule depends on the order of visits.
 *
 * The contacts do not depend on how generous the candidate lists are: any lists in increasing triangle order that
 * hold at least the triangles within h of the vertex (say, every triangle whose grown box touches the vertex's cell
 * on a grid of edge h, or those plus a hash's collisions) give the same contacts in the same order, unless some
 * triangle of b lies within tie = 1e-6 h of the cut-off h. These lists hold every triangle within h (its nearest
 * point lies in its box, so the vertex lies within h of the box on each axis). A visit changes nothing unless it
 * makes the triangle the nearest so far; outside that band, a triangle beyond h can do so only while the nearest
 * so far is beyond h + tie (nearer by more than tie, or within tie of it), and a triangle within h then always
 * takes over from it. So after every visit the two searches hold the same triangle, or both hold one beyond
 * h + tie and reject the vertex. */
static DrStatus detect_body_pair(Body *bodies, int ia, int ib, double *const *V0, double *const *Vs,
                                 const DrBemConstraints *c, Detect *det, Con *cons, int *nc,
                                 DrBemConstraintStats *stats, DrError *err)
{
    const DrBemMatrices *mb = bodies[ib].s->m;
    int nva = bodies[ia].s->nv;
    double h = 0; /* the mean edge length of b */
    for (int t = 0; t < mb->nt; t++)
        for (int a = 0; a < 3; a++) {
            const double *p = &V0[ib][3 * mb->tri[3 * t + a]], *q = &V0[ib][3 * mb->tri[3 * t + (a + 1) % 3]];
            h += sqrt(pow(p[0] - q[0], 2) + pow(p[1] - q[1], 2) + pow(p[2] - q[2], 2));
        }
    h = fmax(h / (3.0 * mb->nt), 4 * c->thickness);
    if (!det->bp) DR_TRY(dr_broad_phase_create(&det->bp, err));
    DR_TRY(grow(&det->span, &det->span_cap, (size_t)nva, sizeof(CandidateSpan), err));
    DrShape verts = {.kind = DR_SHAPE_POINTS, .x = V0[ia], .nverts = nva, .nelements = nva};
    DrShape tris = {.kind = DR_SHAPE_TRIANGLES, .x = V0[ib], .nverts = bodies[ib].s->nv, .elements = mb->tri,
                    .nelements = mb->nt};
    dr_broad_phase_clear(det->bp);
    for (int v = 0; v < nva; v++) {
        DrVec3 lo, hi;
        dr_shape_element_box(&verts, v, 0.0, &lo, &hi);
        DR_TRY(dr_broad_phase_add(det->bp, lo, hi, err));
    }
    for (int t = 0; t < mb->nt; t++) {
        DrVec3 lo, hi;
        dr_shape_element_box(&tris, t, h, &lo, &hi);
        DR_TRY(dr_broad_phase_add(det->bp, lo, hi, err));
    }
    /* a box is a triangle's extent, rarely above an edge length h, plus 2h: cells of 3h keep a typical box within 2
       cells per axis, and a long triangle costs only its own extra cells */
    const DrBroadPair *pairs = NULL;
    long np = 0;
    DR_TRY(dr_broad_phase_pairs_across(det->bp, 3 * h, nva, &pairs, &np, err));
    CandidateSpan *span = det->span;
    for (int v = 0; v < nva; v++) span[v] = (CandidateSpan){0, 0};
    for (long q = 0; q < np; q++) {
        CandidateSpan *sp = &span[pairs[q].a];
        if (sp->end == sp->begin) sp->begin = q;
        assert(sp->begin == q || (sp->end == q && pairs[q - 1].b < pairs[q].b)); /* one run, increasing */
        sp->end = q + 1;
    }
    for (int v = 0; v < nva; v++) {
        const double *x = &V0[ia][3 * v];
        /* the nearest triangle; among triangles equally near (a vertex over an edge of a box lies in the plane of
           the side face too), the one facing the vertex's approach over the step, so a body landing on a face
           is pushed back along the face normal and not sideways off the edge */
        int best_t = -1;
        double best_d2 = INFINITY, best_w[3] = {0, 0, 0}, best_face = INFINITY, tie = 1e-6 * h;
        const double *xs = &Vs[ia][3 * v];
        for (long q = span[v].begin; q < span[v].end; q++) {
            int t = pairs[q].b - nva;
            const int *tri = &mb->tri[3 * t];
            double w[3], d2 = 0, appr[3], nt[3];
            closest_on_triangle(x, &V0[ib][3 * tri[0]], &V0[ib][3 * tri[1]], &V0[ib][3 * tri[2]], w);
            for (int r = 0; r < 3; r++) {
                double cp = 0, cs = 0;
                for (int a = 0; a < 3; a++) cp += w[a] * V0[ib][3 * tri[a] + r], cs += w[a] * Vs[ib][3 * tri[a] + r];
                d2 += (x[r] - cp) * (x[r] - cp);
                appr[r] = (x[r] - cp) - (xs[r] - cs);
            }
            tri_normal(&V0[ib][3 * tri[0]], &V0[ib][3 * tri[1]], &V0[ib][3 * tri[2]], nt);
            double face = dot3(nt, appr), d = sqrt(d2), bd = sqrt(best_d2);
            bool nearer = d < bd - tie, tied = fabs(d - bd) <= tie;
            if (nearer || (tied && face < best_face))
                best_d2 = d2, best_t = t, best_face = face, memcpy(best_w, w, sizeof w);
        }
        if (best_t < 0 || best_d2 > h * h) continue;
        const int *tri = &mb->tri[3 * best_t];
        Con *k = &cons[(*nc)++];
        *k = (Con){.type = CON_BODY, .ne = 4, .body = {ia, ib, ib, ib}, .vertex = {v, tri[0], tri[1], tri[2]},
                   .wt = {1, -best_w[0], -best_w[1], -best_w[2]}, .mu = c->body_friction};
        body_linearise(k, V0);
        if (!(k->g0 < 2 * c->thickness) || k->g0 < -h) {
            (*nc)--;
            continue;
        }
        con_value_at(k, Vs, k->slip0); /* where the relative position was at the start of the step */
        for (int en = 0; en < k->ne; en++) body_add_active(&bodies[k->body[en]], k->vertex[en]);
        stats->body_contacts++;
    }
    return DR_OK;
}

/* ---- the group step in phases -----------------------------------------------------------------------------------
 * Predict is steps 1–3 of the banner (the zero-force trial, the active set, the response blocks), solve steps 4–5
 * (Gauss–Seidel and the trial passes, with the external forces in every trial), commit step 6 (the bodies take their
 * last trial: the forces of the last pass, so the final step of the banner needs no solve of its own). */

/* What a group step keeps between its phases and from step to step, held by the group's first solid. */
struct BemGroupWork {
    int phase;                  /* BEM_PHASE_* of the group step */
    int count;                  /* bodies of the prediction */
    size_t bodies_cap, lists_cap;
    Body *bodies;               /* bodies_cap, zeroed past the used ones */
    DrBemSolid **solids;        /* the prediction's solids (not owned) */
    double **V0s, **Vts, **Vss; /* per body: trial, latest trial and start positions */
    const DrBemConstraints *c;  /* the prediction's constraints (not owned) */
    bool any;                   /* something to solve (else every body steps alone) */
    int nc;
    size_t cons_cap;
    Con *cons, *cons0;          /* the active constraints; as predicted, where every solve starts */
    Sweep sweep;
    Detect detect;              /* body–body detection */
    double *work;               /* the assembly's */
    size_t work_cap;
    DrBemConstraintStats pred, stats; /* the prediction's figures; the step's so far */
};

void bem_group_work_free(BemGroupWork **pw)
{
    BemGroupWork *w = pw ? *pw : NULL;
    if (!w) return;
    for (size_t i = 0; i < w->bodies_cap; i++) body_free(&w->bodies[i]);
    free(w->bodies);
    free(w->solids);
    free(w->V0s);
    free(w->Vts);
    free(w->Vss);
    free(w->cons);
    free(w->cons0);
    sweep_free(&w->sweep);
    dr_broad_phase_destroy(&w->detect.bp);
    free(w->detect.span);
    free(w->work);
    free(w);
    *pw = NULL;
}

void bem_group_work_drop(BemGroupWork *w) { w->phase = BEM_PHASE_NONE; }

/* Room for `count` bodies (new ones zeroed: no arrays yet). */
static DrStatus group_reserve(BemGroupWork *w, int count, DrError *err)
{
    size_t need = (size_t)count;
    if (need > w->bodies_cap) {
        DR_TRY(dr_realloc(need, sizeof(Body), &w->bodies, err));
        memset(w->bodies + w->bodies_cap, 0, sizeof(Body) * (need - w->bodies_cap));
        w->bodies_cap = need;
    }
    if (need > w->lists_cap) {
        DR_TRY(dr_realloc(need, sizeof(DrBemSolid *), &w->solids, err));
        DR_TRY(dr_realloc(need, sizeof(double *), &w->V0s, err));
        DR_TRY(dr_realloc(need, sizeof(double *), &w->Vts, err));
        DR_TRY(dr_realloc(need, sizeof(double *), &w->Vss, err));
        w->lists_cap = need;
    }
    return DR_OK;
}

/* A body's arrays for a step of solid s, no vertex active. */
static DrStatus body_begin(Body *b, DrBemSolid *s, DrError *err)
{
    b->s = s;
    b->na = 0;
    b->force = NULL;
    size_t n = (size_t)s->n;
    DR_TRY(grow(&b->map, &b->map_cap, (size_t)s->nv, sizeof(int), err));
    DR_TRY(grow(&b->act, &b->act_cap, (size_t)s->nv, sizeof(int), err));
    if (n > b->v_cap) {
        double **arr[] = {&b->V0, &b->Vstart, &b->Vt, &b->p};
        for (int a = 0; a < 4; a++) DR_TRY(dr_realloc(n, sizeof(double), arr[a], err));
        b->v_cap = n;
    }
    for (int v = 0; v < s->nv; v++) b->map[v] = -1;
    return DR_OK;
}

/* A trial step of the body with the traction (body frame; NULL: none) and its external forces: V receives the world
   positions it gives; the solid keeps it as its last solve. */
static DrStatus trial(Body *b, const double *traction, double *V, DrError *err)
{
    DR_TRY(dr_bem_solid_solve(b->s, traction, b->force, NULL, err));
    if (V) bem_solid_solved_positions(b->s, V);
    return DR_OK;
}

DrStatus dr_bem_solids_predict(DrBemSolid *const *solids, int count, const DrBemConstraints *c,
                               DrBemConstraintStats *st, DrError *err)
{
    DrBemConstraintStats stats = {0};
    if (st) *st = stats;
    DR_TRY(check_input(solids, count, c, err));
    if (count == 0) return DR_OK;
    if (!solids[0]->group) DR_TRY(dr_calloc(1, sizeof(BemGroupWork), &solids[0]->group, err));
    BemGroupWork *w = solids[0]->group;
    w->phase = BEM_PHASE_NONE;
    DR_TRY(group_reserve(w, count, err));
    w->count = count;
    memcpy(w->solids, solids, sizeof(DrBemSolid *) * (size_t)count);
    w->c = c;
    w->nc = 0;
    w->any = c && (c->collider_count > 0 || c->fixed_count > 0 || c->joint_count > 0 || (c->body_contact && count > 1));
    if (!w->any) { /* nothing to solve: plain steps */
        double t0 = dr_time_now();
        for (int i = 0; i < count; i++) DR_TRY(dr_bem_solid_predict(solids[i], err));
        stats.seconds_final = dr_time_now() - t0;
        w->pred = w->stats = stats;
        w->phase = BEM_PHASE_PREDICTED;
        if (st) *st = stats;
        return DR_OK;
    }

    DrStatus status = DR_OK;
    Body *bodies = w->bodies;
    double **V0s = w->V0s, **Vss = w->Vss;
    double dt = solids[0]->m->desc.dt;

    /* 1. start positions and the zero-force trial (not kept as the bodies' solve: their samples stay at the start) */
    for (int i = 0; i < count && status == DR_OK; i++) {
        Body *b = &bodies[i];
        status = body_begin(b, solids[i], err);
        if (status != DR_OK) break;
        V0s[i] = b->V0, w->Vts[i] = b->Vt, Vss[i] = b->Vstart;
        dr_bem_solid_positions(b->s, b->Vstart);
        double t0 = dr_time_now();
        status = dr_bem_solid_predict(b->s, err);
        if (status == DR_OK) status = trial(b, NULL, b->V0, err);
        b->s->phase = BEM_PHASE_PREDICTED;
        stats.seconds_trial += dr_time_now() - t0;
    }

    /* 2. the active set */
    double t_det = dr_time_now();
    size_t want = (size_t)c->fixed_count + (size_t)c->joint_count;
    for (int i = 0; i < count && status == DR_OK; i++)
        want += (size_t)(c->collider_count + (c->body_contact ? count - 1 : 0)) * (size_t)bodies[i].s->nv;
    if (status == DR_OK && want > w->cons_cap) {
        status = dr_realloc(want, sizeof(Con), &w->cons, err);
        if (status == DR_OK) status = dr_realloc(want, sizeof(Con), &w->cons0, err);
        if (status == DR_OK) w->cons_cap = want;
    }
    Con *cons = w->cons;
    int nc = 0;
    for (int i = 0; i < c->fixed_count && status == DR_OK; i++) {
        const DrBemFixed *f = &c->fixed[i];
        Con *k = &cons[nc++];
        *k = (Con){.type = CON_FIXED, .ne = 1, .body = {f->body}, .vertex = {f->vertex}, .wt = {1}};
        memcpy(k->target, f->target, sizeof k->target);
        body_add_active(&bodies[f->body], f->vertex);
        stats.fixed++;
    }
    for (int i = 0; i < c->joint_count && status == DR_OK; i++) {
        const DrBemJoint *j = &c->joints[i];
        Con *k = &cons[nc++];
        *k = (Con){.type = CON_JOINT, .ne = 2, .body = {j->body[0], j->body[1]}, .vertex = {j->vertex[0], j->vertex[1]},
                   .wt = {1, -1}};
        for (int e = 0; e < 2; e++) body_add_active(&bodies[j->body[e]], j->vertex[e]);
        stats.joints++;
    }
    for (int i = 0; i < count && status == DR_OK; i++) {
        Body *b = &bodies[i];
        for (int v = 0; v < b->s->nv && status == DR_OK; v++)
            for (int ci = 0; ci < c->collider_count && status == DR_OK; ci++) {
                const DrBemCollider *col = &c->colliders[ci];
                const double *x = &b->V0[3 * v];
                double g[3] = {0, 0, 0};
                double phi = col->sdf(x, g, col->ctx), gl = sqrt(dot3(g, g));
                if (!(phi < 2 * c->thickness) || !(gl > 0)) continue;
                Con *k = &cons[nc++];
                *k = (Con){.type = CON_CONTACT, .ne = 1, .body = {i}, .vertex = {v}, .wt = {1}, .collider = ci,
                           .mu = col->friction, .g0 = phi};
                memcpy(k->vref, x, sizeof k->vref);
                for (int q = 0; q < 3; q++) k->n[q] = g[q] / gl;
                tangent_basis(k->n, k->t1, k->t2);
                double vc[3] = {0, 0, 0};
                if (col->velocity) col->velocity(x, vc, col->ctx);
                for (int q = 0; q < 3; q++) k->slip0[q] = b->Vstart[3 * v + q] + dt * vc[q];
                body_add_active(b, v);
                stats.contacts++;
            }
    }
    for (int ia = 0; c->body_contact && ia < count && status == DR_OK; ia++)
        for (int ib = 0; ib < count && status == DR_OK; ib++)
            if (ia != ib)
                status = detect_body_pair(bodies, ia, ib, V0s, Vss, c, &w->detect, cons, &nc, &stats, err);
    for (int i = 0; i < nc; i++) /* local indices, now that every active list is final */
        for (int e = 0; e < cons[i].ne; e++) cons[i].local[e] = bodies[cons[i].body[e]].map[cons[i].vertex[e]];
    stats.seconds_detect = dr_time_now() - t_det;

    /* 3. response blocks and each constraint's diagonal block */
    double t_as = dr_time_now();
    for (int i = 0; i < count && status == DR_OK; i++) status = body_assemble(&bodies[i], &w->work, &w->work_cap, err);
    for (int i = 0; i < nc && status == DR_OK; i++) {
        Con *k = &cons[i];
        if (k->type == CON_CONTACT || k->type == CON_BODY) {
            contact_prepare(bodies, k);
        } else {
            double K[9];
            con_block(bodies, k, K);
            if (!dr_m3a_inverse(K, k->Kinv))
                status = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                      "BEM constraints: %s %d has a singular response (the same vertex joined to "
                                      "itself?); %s",
                                      k->type == CON_FIXED ? "fixed vertex" : "joint",
                                      k->type == CON_FIXED ? i : i - c->fixed_count, "fix the constraint description");
        }
    }
    if (status == DR_OK && nc > 0) status = sweep_init(bodies, count, cons, nc, &w->sweep, err);
    stats.seconds_assembly = dr_time_now() - t_as;
    if (status != DR_OK) return status;
    if (nc > 0) memcpy(w->cons0, cons, sizeof(Con) * (size_t)nc);
    w->nc = nc;
    w->pred = w->stats = stats;
    w->phase = BEM_PHASE_PREDICTED;
    if (st) *st = stats;
    return DR_OK;
}

DrStatus dr_bem_solids_solve(DrBemSolid *const *solids, int count, const double *const *force,
                             DrBemConstraintStats *st, DrError *err)
{
    if (count == 0) {
        if (st) *st = (DrBemConstraintStats){0};
        return DR_OK;
    }
    BemGroupWork *w = solids[0]->group;
    assert(w && w->phase != BEM_PHASE_NONE && w->count == count &&
           memcmp(w->solids, solids, sizeof(DrBemSolid *) * (size_t)count) == 0 &&
           "dr_bem_solids_solve: no prediction of these solids (dr_bem_solids_predict first)");
    w->phase = BEM_PHASE_PREDICTED; /* until this solve succeeds */
    DrBemConstraintStats stats = w->pred;
    DrStatus status = DR_OK;
    if (!w->any) {
        double t0 = dr_time_now();
        for (int i = 0; i < count && status == DR_OK; i++)
            status = dr_bem_solid_solve(solids[i], NULL, force ? force[i] : NULL, NULL, err);
        stats.seconds_final += dr_time_now() - t0;
        w->stats = stats;
        if (status == DR_OK) w->phase = BEM_PHASE_SOLVED;
        if (st) *st = stats;
        return status;
    }
    const DrBemConstraints *c = w->c;
    Body *bodies = w->bodies;
    Con *cons = w->cons;
    int nc = w->nc;
    double *const *Vts = w->Vts;

    /* the prediction again: the constraints as detected and no constraint force; the positions the constraints start
       from are those of the zero-force trial, or of a trial with the external forces */
    if (nc > 0) memcpy(cons, w->cons0, sizeof(Con) * (size_t)nc);
    double t_x = dr_time_now();
    for (int i = 0; i < count && status == DR_OK; i++) {
        Body *b = &bodies[i];
        b->force = force ? force[i] : NULL;
        if (b->na == 0) continue;
        const double *V = b->V0;
        if (b->force) {
            status = trial(b, NULL, b->Vt, err);
            V = b->Vt;
        }
        memset(b->F, 0, sizeof(double) * 3 * (size_t)b->na);
        for (int a = 0; a < b->na; a++)
            for (int q = 0; q < 3; q++) b->P[3 * a + q] = V[3 * b->act[a] + q];
    }
    stats.seconds_trial += dr_time_now() - t_x;

    /* 4–5. Gauss–Seidel, then trial steps with the forces found until the measured error is within tolerance */
    double residual = INFINITY;
    for (int pass = 0; pass < c->max_passes && status == DR_OK && nc > 0; pass++) {
        double t_p = dr_time_now();
        for (int it = 0; it < c->max_iterations; it++) {
            double viol, dmax = pgs_sweep(bodies, count, cons, &w->sweep, c->thickness, &viol);
            stats.iterations++;
            double fmax_ = 0;
            for (int i = 0; i < nc; i++) fmax_ = fmax(fmax_, sqrt(dot3(cons[i].f, cons[i].f)));
            if (viol < 0.1 * c->tolerance && dmax <= 1e-9 * fmax_ + 1e-300) break;
        }
        stats.seconds_pgs += dr_time_now() - t_p;
        stats.passes = pass + 1;
        double t_t = dr_time_now();
        for (int i = 0; i < count && status == DR_OK; i++) {
            body_tractions(&bodies[i]);
            status = trial(&bodies[i], bodies[i].p, bodies[i].Vt, err);
        }
        stats.seconds_trial += dr_time_now() - t_t;
        if (status != DR_OK) break;
        double t_d = dr_time_now();
        residual = measure(cons, nc, c, Vts, false);
        stats.seconds_detect += dr_time_now() - t_d;
        if (residual <= c->tolerance || pass + 1 == c->max_passes) break;
        t_d = dr_time_now();
        measure(cons, nc, c, Vts, true); /* contacts linearised at the measured positions */
        stats.seconds_detect += dr_time_now() - t_d;
        for (int i = 0; i < nc; i++)
            if (cons[i].type == CON_CONTACT || cons[i].type == CON_BODY) contact_prepare(bodies, &cons[i]);
        for (int i = 0; i < count; i++) { /* the measured positions replace the linear prediction */
            Body *b = &bodies[i];
            for (int a = 0; a < b->na; a++)
                for (int q = 0; q < 3; q++) b->P[3 * a + q] = b->Vt[3 * b->act[a] + q];
        }
    }
    if (nc == 0) { /* nothing active: the bodies' steps with their external forces alone */
        residual = 0;
        double t_t = dr_time_now();
        for (int i = 0; i < count && status == DR_OK; i++) status = trial(&bodies[i], NULL, NULL, err);
        stats.seconds_trial += dr_time_now() - t_t;
    }
    for (int i = 0; i < nc; i++) {
        const Con *k = &cons[i];
        if (k->type != CON_CONTACT && k->type != CON_BODY) continue;
        double fn = dot3(k->f, k->n), ft[3];
        for (int q = 0; q < 3; q++) ft[q] = k->f[q] - fn * k->n[q];
        if (fn > 0 && sqrt(dot3(ft, ft)) < k->mu * fn * (1 - 1e-9)) stats.sticking++;
    }
    stats.residual = residual;
    if (status == DR_OK && residual > c->tolerance)
        status = dr_error_set(err, DR_WARN_NOT_CONVERGED, NULL, 0, 0,
                              "BEM constraints: the constraint error is %.3g m after %d passes (tolerance %.3g m); "
                              "raise max_passes or max_iterations, or take a smaller time step",
                              residual, stats.passes, c->tolerance);
    if (status >= 0) w->phase = BEM_PHASE_SOLVED;
    w->stats = stats;
    if (st) *st = stats;
    return status;
}

void dr_bem_solids_commit(DrBemSolid *const *solids, int count, DrBemConstraintStats *st)
{
    if (count == 0) {
        if (st) *st = (DrBemConstraintStats){0};
        return;
    }
    BemGroupWork *w = solids[0]->group;
    assert(w && w->phase == BEM_PHASE_SOLVED && w->count == count &&
           memcmp(w->solids, solids, sizeof(DrBemSolid *) * (size_t)count) == 0 &&
           "dr_bem_solids_commit: no successful solve of these solids since predict");
    /* 6. every body takes its last trial */
    double t_f = dr_time_now();
    for (int i = 0; i < count; i++) dr_bem_solid_commit(solids[i], NULL);
    w->stats.seconds_final += dr_time_now() - t_f;
    w->phase = BEM_PHASE_NONE;
    if (st) *st = w->stats;
}

DrStatus dr_bem_solids_step(DrBemSolid *const *solids, int count, const DrBemConstraints *c,
                            DrBemConstraintStats *st, DrError *err)
{
    DR_TRY(dr_bem_solids_predict(solids, count, c, st, err));
    DrStatus status = dr_bem_solids_solve(solids, count, NULL, st, err);
    if (status < 0) return status;
    dr_bem_solids_commit(solids, count, st);
    return status;
}
