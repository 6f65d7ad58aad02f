/* The implicit viscosity solve (viscosity.h; Batty & Bridson 2008). Assembly is by rows: a face's row gathers the
 * strain-rate terms that hold it (the diagonal rates of the two cells it separates and the shear rates of the four
 * edges around it), each term a short list of (face, coefficient) pairs. */
#include "liquid/viscosity.h"

#include "linalg/linalg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct DrViscosity {
    long *index[3];  /* face → unknown, −1 for a face held fixed */
    long icap[3];
    long *face;      /* unknown → face index within its component */
    unsigned char *comp;
    double *b, *x, *work;
    long ucap;
    DrCsr *A;
    DrMic0 *M;
    int *rowlen;     /* entries per row (assembly pass 1) */
};

DrStatus dr_viscosity_create(DrViscosity **out, DrError *err)
{
    *out = NULL;
    DrViscosity *v = NULL;
    DR_TRY(dr_calloc(1, sizeof *v, &v, err));
    DrStatus s = dr_csr_create(0, 0, &v->A, err);
    if (s != DR_OK) {
        free(v);
        return s;
    }
    *out = v;
    return DR_OK;
}

void dr_viscosity_destroy(DrViscosity **vp)
{
    if (!vp || !*vp) return;
    DrViscosity *v = *vp;
    for (int a = 0; a < 3; a++) free(v->index[a]);
    free(v->face);
    free(v->comp);
    free(v->b);
    free(v->x);
    free(v->work);
    free(v->rowlen);
    dr_csr_destroy(&v->A);
    dr_mic0_destroy(&v->M);
    free(v);
    *vp = NULL;
}

/* One strain-rate term: Σ coef_k u_k over unknowns plus a constant from the faces held fixed, and its weight. */
typedef struct Term {
    long col[4];
    double coef[4];
    int n;
    double cval;
    double w;
} Term;

static int cells_along(const DrMacGrid *g, int d) { return d == 0 ? g->nx : (d == 1 ? g->ny : g->nz); }

static double fill_at(const DrViscosityInput *in, int i, int j, int k)
{
    const DrMacGrid *g = in->g;
    if (i < 0 || j < 0 || k < 0 || i >= g->nx || j >= g->ny || k >= g->nz) return 0.0;
    return in->fill[dr_mac_cell_index(g, i, j, k)];
}

/* Adds coef · u_a(ijk) to t. Off the grid across a wall (an axis other than a), the face inside stands in for it:
   with the same sign on a slip wall (no shear), the opposite on a no-slip wall (0 at the wall between them). */
static void term_add(const DrViscosity *v, const DrViscosityInput *in, Term *t, int a, const int ijk_in[3], double coef)
{
    const DrMacGrid *g = in->g;
    int ijk[3] = {ijk_in[0], ijk_in[1], ijk_in[2]};
    for (int d = 0; d < 3; d++) {
        if (d == a) continue;
        int n = cells_along(g, d);
        if (ijk[d] < 0 || ijk[d] >= n) {
            ijk[d] = ijk[d] < 0 ? 0 : n - 1;
            if (in->no_slip) coef = -coef;
        }
    }
    long f = dr_mac_face_index(g, a, ijk[0], ijk[1], ijk[2]);
    long u = v->index[a][f];
    if (u < 0) {
        t->cval += coef * (in->open[a][f] <= 0.0 ? in->velocity[a][f] : g->f[a][f]);
        return;
    }
    for (int q = 0; q < t->n; q++)
        if (t->col[q] == u) {
            t->coef[q] += coef;
            return;
        }
    t->col[t->n] = u;
    t->coef[t->n++] = coef;
}

/* The diagonal rate of cell c along a: (u_a(c + e_a) − u_a(c))/Δx, weight 2 Δt μ Δx V_c (×Δx² from the rate's
   1/Δx²: the energy Δt μ Δx³ V ε² has the Hessian 2 Δt μ Δx V ĝᵀĝ with ĝ the ±1 coefficients). */
static Term cell_term(const DrViscosity *v, const DrViscosityInput *in, int a, const int c[3])
{
    Term t = {{0}, {0}, 0, 0.0, 0.0};
    t.w = 2.0 * in->dt * in->mu * in->g->dx * fill_at(in, c[0], c[1], c[2]);
    if (!(t.w > 0.0)) return t;
    int hi[3] = {c[0], c[1], c[2]};
    hi[a]++;
    term_add(v, in, &t, a, hi, 1.0);
    term_add(v, in, &t, a, c, -1.0);
    return t;
}

/* The shear rate (doubled) D_b u_a + D_a u_b on the edge at node indices n_a along a and n_b along b, cell kc along
   the third axis; weight Δt μ Δx V_e (energy Δt μ Δx³ V · 2 ε_ab² = ½ Δt μ Δx V (ĥ·u)²). */
static Term edge_term(const DrViscosity *v, const DrViscosityInput *in, int a, int b, int na, int nb, int kc)
{
    int c = 3 - a - b;
    Term t = {{0}, {0}, 0, 0.0, 0.0};
    double fill = 0.0;
    for (int q = 0; q < 4; q++) {
        int x[3];
        x[a] = na - 1 + (q & 1);
        x[b] = nb - 1 + (q >> 1);
        x[c] = kc;
        fill += fill_at(in, x[0], x[1], x[2]);
    }
    t.w = in->dt * in->mu * in->g->dx * 0.25 * fill;
    if (!(t.w > 0.0)) return t;
    int p[3];
    p[c] = kc;
    p[a] = na, p[b] = nb; /* u_a: node na along a, cell nb along b */
    term_add(v, in, &t, a, p, 1.0);
    p[b] = nb - 1;
    term_add(v, in, &t, a, p, -1.0);
    p[b] = nb, p[a] = na; /* u_b: node nb along b, cell na along a */
    term_add(v, in, &t, b, p, 1.0);
    p[a] = na - 1;
    term_add(v, in, &t, b, p, -1.0);
    return t;
}

/* The terms that hold unknown r: at most 2 cells and 4 edges. */
static int row_terms(const DrViscosity *v, const DrViscosityInput *in, long r, Term terms[6])
{
    const DrMacGrid *g = in->g;
    int a = v->comp[r];
    long f = v->face[r];
    int nx = g->fdim[a][0], ny = g->fdim[a][1];
    int ijk[3] = {(int)(f % nx), (int)((f / nx) % ny), (int)(f / ((long)nx * ny))};
    int cnt = 0;
    for (int side = 0; side < 2; side++) {
        int cidx[3] = {ijk[0], ijk[1], ijk[2]};
        cidx[a] -= 1 - side;
        if (cidx[a] < 0 || cidx[a] >= cells_along(g, a)) continue;
        terms[cnt++] = cell_term(v, in, a, cidx);
    }
    for (int b = 0; b < 3; b++) {
        if (b == a) continue;
        int c = 3 - a - b;
        for (int side = 0; side < 2; side++) {
            int nb = ijk[b] + side; /* the edges at the face's two b-boundaries */
            terms[cnt++] = a < b ? edge_term(v, in, a, b, ijk[a], nb, ijk[c]) : edge_term(v, in, b, a, nb, ijk[a], ijk[c]);
        }
    }
    return cnt;
}

typedef struct Entry { long col; double val; } Entry;

/* Row r's entries (sorted, merged) and right-hand side. Returns the entry count (at most 1 + 6·4). */
static int row_entries(const DrViscosity *v, const DrViscosityInput *in, long r, Entry e[25], double *rhs)
{
    Term terms[6];
    int nt = row_terms(v, in, r, terms), n = 0;
    int a = v->comp[r];
    long f = v->face[r];
    double m = in->mass[a][f];
    e[n++] = (Entry){r, m};
    double b = m * in->g->f[a][f];
    for (int q = 0; q < nt; q++) {
        const Term *t = &terms[q];
        double cr = 0.0;
        for (int k = 0; k < t->n; k++)
            if (t->col[k] == r) cr = t->coef[k];
        if (cr == 0.0 || !(t->w > 0.0)) continue;
        b -= t->w * cr * t->cval;
        for (int k = 0; k < t->n; k++) {
            if (t->coef[k] == 0.0) continue;
            double val = t->w * cr * t->coef[k];
            int s = 0;
            while (s < n && e[s].col != t->col[k]) s++;
            if (s == n) e[n++] = (Entry){t->col[k], 0.0};
            e[s].val += val;
        }
    }
    /* insertion sort by column (≤ 25 entries) */
    for (int i = 1; i < n; i++) {
        Entry x = e[i];
        int j = i - 1;
        while (j >= 0 && e[j].col > x.col) e[j + 1] = e[j], j--;
        e[j + 1] = x;
    }
    *rhs = b;
    return n;
}

typedef struct AsmCtx { DrViscosity *v; const DrViscosityInput *in; bool fill; } AsmCtx;

static void assemble_range(long begin, long end, void *vctx)
{
    AsmCtx *c = vctx;
    DrViscosity *v = c->v;
    DrCsr *A = v->A;
    for (long r = begin; r < end; r++) {
        Entry e[25];
        double rhs;
        int n = row_entries(v, c->in, r, e, &rhs);
        if (!c->fill) {
            v->rowlen[r] = n;
            continue;
        }
        int at = A->rowptr[r];
        for (int k = 0; k < n; k++) A->col[at + k] = (int)e[k].col, A->val[at + k] = e[k].val;
        v->b[r] = rhs;
    }
}

static DrStatus reserve(DrViscosity *v, const DrMacGrid *g, long n, DrError *err)
{
    for (int a = 0; a < 3; a++)
        if (g->nfaces[a] > v->icap[a]) {
            free(v->index[a]);
            v->index[a] = NULL;
            v->icap[a] = 0;
            DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(long), &v->index[a], err));
            v->icap[a] = g->nfaces[a];
        }
    if (n > v->ucap) {
        long cap = n + n / 4 + 64;
        DR_TRY(dr_realloc((size_t)cap, sizeof(long), &v->face, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof(unsigned char), &v->comp, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof(double), &v->b, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof(double), &v->x, err));
        DR_TRY(dr_realloc((size_t)cap * 4, sizeof(double), &v->work, err));
        DR_TRY(dr_realloc((size_t)cap + 1, sizeof(int), &v->rowlen, err));
        v->ucap = cap;
    }
    return DR_OK;
}

DrStatus dr_viscosity_solve(DrViscosity *v, const DrViscosityInput *in, DrViscosityStats *stats, DrError *err)
{
    DrMacGrid *g = in->g;
    memset(stats, 0, sizeof *stats);
    /* 1. the unknowns, component by component in face order */
    long n = 0;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++)
            if (in->mass[a][f] > 0.0 && in->open[a][f] > 0.0) n++;
    if (n > 0x7fffffffL / 25)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "liquid viscosity: %ld unknowns exceed the solver's index", n);
    DR_TRY(reserve(v, g, n, err));
    long u = 0;
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            bool free_face = in->mass[a][f] > 0.0 && in->open[a][f] > 0.0;
            v->index[a][f] = free_face ? u : -1;
            if (free_face) v->face[u] = f, v->comp[u] = (unsigned char)a, u++;
        }
    stats->unknowns = n;
    if (n == 0) {
        stats->converged = true;
        return DR_OK;
    }
    /* 2. the matrix by rows (counts, prefix sum, entries): the same for any thread count */
    AsmCtx ac = {v, in, false};
    dr_parallel_for(n, 4096, assemble_range, &ac);
    long nnz = 0;
    for (long r = 0; r < n; r++) nnz += v->rowlen[r];
    DR_TRY(dr_csr_reserve(v->A, (int)n, (int)nnz, err));
    v->A->rowptr[0] = 0;
    for (long r = 0; r < n; r++) v->A->rowptr[r + 1] = v->A->rowptr[r] + v->rowlen[r];
    v->A->nnz = (int)nnz;
    ac.fill = true;
    dr_parallel_for(n, 4096, assemble_range, &ac);
    /* 3. PCG with MIC(0) from u* */
    if (!v->M) DR_TRY(dr_mic0_create(v->A, DR_MIC0_TAU_DEFAULT, DR_MIC0_SIGMA_DEFAULT, &v->M, err));
    else DR_TRY(dr_mic0_update(v->M, v->A, err));
    for (long r = 0; r < n; r++) v->x[r] = g->f[v->comp[r]][v->face[r]];
    DrLinearOp Aop = dr_csr_op(v->A), Mop = dr_mic0_op(v->M);
    DrPcgDesc pd;
    dr_pcg_desc_default(&pd);
    pd.rel_tol = in->tolerance;
    pd.max_iter = in->max_iterations;
    DrPcgStats ps;
    DrStatus s = dr_pcg_solve(&Aop, &Mop, v->b, v->x, &pd, v->work, &ps, err);
    stats->iterations = ps.iterations;
    stats->rel_residual = ps.rel_residual;
    stats->converged = ps.converged;
    if (s == DR_ERR_RUNTIME && isfinite(ps.rel_residual) && ps.rel_residual <= 1e-6) {
        /* a breakdown at round-off (<p, Ap> of a residual near 1e-8 of ||b|| comes out at ±1e-26 when the step is
           many explicit limits long): the iterate has reached what the default tolerance asks, keep it */
        stats->converged = true;
        s = DR_OK;
    }
    if (s < 0) return dr_error_prefix(s, err, "liquid viscosity solve");
    for (long r = 0; r < n; r++) g->f[v->comp[r]][v->face[r]] = v->x[r];
    return DR_OK;
}
