/* Assembly of the convolution-quadrature BEM matrices of BEM eq. (9) and the operators the runtime needs.
 *
 * For every collocation vertex x_i (one row block, computed independently and in parallel) the Laplace-domain
 * rows Ĥ(s_l), Ĝ(s_l), D̂(s_l), Q̂(s_l) are integrated over every triangle for the frequencies l = 0..⌊L/2⌋
 * (the others are their conjugates), then turned into time-domain rows for k = 0..n_max by the weights of
 * eq. (15), written as one small real matrix product per row.
 *
 * Strong singularity. The diagonal block needs c(x_i) + PV∫ p̂*(s) Φ_i. p̂*(s) − p*_static is only weakly
 * singular, so  c + PV∫ p̂*(s)Φ_i = [c + PV∫ p*_static Φ_i] + ∫ (p̂*(s) − p*_static) Φ_i,  and the bracket follows
 * from the rigid-body identity of elastostatics: a rigid translation with zero traction solves the static
 * problem on a closed body, so c_i + PV∫ p*_static dΓ = 0, i.e. with Σ_j Φ_j = 1 the bracket equals
 * −Σ_{j≠i} ∫ p*_static Φ_j. Every integral left is regular or weakly singular (Φ_j vanishes at x_i), so no
 * principal value and no explicit free term is evaluated: the identity supplies both, at any corner, and
 * makes the static matrix annihilate rigid translations exactly. It holds for closed bodies only, which is
 * what dr_bem_mesh_check admits.
 *
 * Number of weights. Eq. (9) sums k = 0..n_max, n_max + 1 weights; an L-point transform (15) yields L of them,
 * so L = n_max + 1 here (the paper's L = n_max would make ψ_{n_max} = R^{−L}ψ_0, off by ε^{−1/2}). */
#include "bem_internal.h"

#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

extern void openblas_set_num_threads(int);
extern void dgetrf_(const int *m, const int *n, double *a, const int *lda, int *ipiv, int *info);
extern void dgetri_(const int *n, double *a, const int *lda, const int *ipiv, double *work, const int *lwork,
                    int *info);
extern void dgetrs_(const char *trans, const int *n, const int *nrhs, const double *a, const int *lda,
                    const int *ipiv, double *b, const int *ldb, int *info, size_t);

int dr_bem_history_length(const DrBemDesc *d, double r_max)
{
    double c2 = sqrt(d->material.shear_modulus / d->material.density);
    double n = floor(r_max / (c2 * d->dt) + d->history_margin);
    return n < 1.0 ? 1 : n > 1e6 ? 1000000 : (int)n;
}

void dr_bem_matrices_destroy(DrBemMatrices **pm)
{
    DrBemMatrices *m = pm ? *pm : NULL;
    if (!m) return;
    if (m->H)
        for (int k = 0; k <= m->n_max; k++) dr_bem_cmat_free(&m->H[k]);
    if (m->G)
        for (int k = 0; k <= m->n_max; k++) dr_bem_cmat_free(&m->G[k]);
    dr_bem_cmat_free(&m->H0inv);
    dr_bem_cmat_free(&m->H0inv_Gp);
    free(m->H);
    free(m->G);
    dr_bem_layout_free(&m->layout);
    free(m->x);
    free(m->tri);
    free(m->A);
    free(m->C);
    free(m->w);
    free(m->area);
    free(m->D);
    free(m->Q);
    free(m->H_dense);
    free(m->G_dense);
    bem_runtime_free(&m->runtime);
    free(m);
    *pm = NULL;
}

static DrStatus check_desc(const DrBemDesc *d, DrError *err)
{
    const DrBemMaterial *mat = &d->material;
    const char *bad = NULL;
    if (!(mat->density > 0) || !isfinite(mat->density)) bad = "density must be positive";
    else if (!(mat->shear_modulus > 0) || !isfinite(mat->shear_modulus)) bad = "shear modulus must be positive";
    else if (!(mat->poisson > -1.0 && mat->poisson < 0.5)) bad = "Poisson's ratio must lie in (-1, 0.5)";
    else if (!(d->dt > 0) || !isfinite(d->dt)) bad = "the time step must be positive";
    else if (!(d->history_margin >= 0)) bad = "the history margin must be >= 0";
    else if (!(d->cq_epsilon > 0 && d->cq_epsilon < 1)) bad = "the quadrature epsilon must lie in (0, 1)";
    else if (!(d->compression_ratio >= 1)) bad = "the compression ratio must be >= 1";
    else if (d->quad_levels < 0 || d->quad_levels > 6) bad = "quadrature levels must lie in [0, 6]";
    else if (d->singular_order < 2 || d->singular_order > 64) bad = "the singular rule order must lie in [2, 64]";
    else if (!(d->near_factor >= 0)) bad = "the near-field factor must be >= 0";
    if (bad) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "BEM parameters: %s", bad);
    return DR_OK;
}

/* The weights of eq. (15) as a real (n_max+1) × 2Lh matrix acting on (Re f̂_l, Im f̂_l), l = 0..Lh−1: with
   f̂_{L−l} = conj f̂_l, ψ_k = R^{−k}/L [f̂_0 + 2 Σ_{0<l<L/2} Re(f̂_l e^{−2πikl/L}) + (L even) f̂_{L/2}(−1)^k]. */
static void cq_real_weights(const DrBemCq *cq, int nk, int lh, double *alpha, double *beta)
{
    int L = cq->L;
    for (int k = 0; k < nk; k++) {
        double scale = pow(cq->R, -k) / L;
        for (int l = 0; l < lh; l++) {
            double c = (l == 0 || 2 * l == L) ? 1.0 : 2.0;
            double th = 2.0 * M_PI * (double)((long)k * l % L) / L;
            alpha[k * lh + l] = c * scale * cos(th);
            beta[k * lh + l] = c * scale * sin(th);
        }
    }
}

/* Per-thread scratch of one row block. */
typedef struct RowWork {
    BemQuadPoint *pts;
    double complex *ku, *kp, *kpd, *kd, *kl; /* kernel values, lh × 9 each */
    double complex *tri;                     /* per-triangle sums: [vertex 3][H, G][lh][9] */
    double *hre, *him, *gre, *gim;           /* lh × 3 × n */
    double *hs;                              /* 3 × n static H row block */
    double complex dacc[64 * 9], lacc[64 * 9], qacc[64 * 9]; /* ∫d̂*, ∫l̂*, ∫q̂* per frequency */
} RowWork;

static void rowwork_free(RowWork *w)
{
    free(w->pts);
    free(w->ku);
    free(w->kp);
    free(w->kpd);
    free(w->kd);
    free(w->kl);
    free(w->tri);
    free(w->hre);
    free(w->him);
    free(w->gre);
    free(w->gim);
    free(w->hs);
}

static bool rowwork_alloc(RowWork *w, int cap, int lh, int n)
{
    memset(w, 0, sizeof *w);
    size_t row = (size_t)lh * 3 * (size_t)n;
    w->pts = malloc(sizeof(BemQuadPoint) * (size_t)cap);
    w->ku = malloc(sizeof(double complex) * 9 * (size_t)lh);
    w->kp = malloc(sizeof(double complex) * 9 * (size_t)lh);
    w->kpd = malloc(sizeof(double complex) * 9 * (size_t)lh);
    w->kd = malloc(sizeof(double complex) * 9 * (size_t)lh);
    w->kl = malloc(sizeof(double complex) * 9 * (size_t)lh);
    w->tri = malloc(sizeof(double complex) * 3 * 2 * 9 * (size_t)lh);
    w->hre = malloc(sizeof(double) * row);
    w->him = malloc(sizeof(double) * row);
    w->gre = malloc(sizeof(double) * row);
    w->gim = malloc(sizeof(double) * row);
    w->hs = malloc(sizeof(double) * 3 * (size_t)n);
    return w->pts && w->ku && w->kp && w->kpd && w->kd && w->kl && w->tri && w->hre && w->him && w->gre && w->gim &&
           w->hs;
}

typedef struct Assembly {
    const DrTriMesh *mesh;
    const DrBemDesc *d;
    DrBemWave wave;
    const DrBemCq *cq;
    const double complex *s; /* the lh Laplace variables integrated */
    const double *tn; /* unit normal per triangle */
    int n, lh, nk, cap, max_levels;
    const double *alpha, *beta; /* nk × lh */
    double xbar[3];
    double *H, *G, *D, *Q; /* outputs: nk × n × n, nk × n × 3 */
} Assembly;

/* Adds the triangle sums of one triangle to the row block: vertex slot v ↔ mesh vertex tv[v]. */
static void scatter_tri(const Assembly *as, RowWork *w, const int tv[3])
{
    int lh = as->lh, n = as->n;
    for (int v = 0; v < 3; v++) {
        const double complex *th = w->tri + ((size_t)v * 2 + 0) * 9 * lh;
        const double complex *tg = w->tri + ((size_t)v * 2 + 1) * 9 * lh;
        for (int l = 0; l < lh; l++)
            for (int a = 0; a < 3; a++) {
                size_t o = ((size_t)l * 3 + a) * n + 3 * (size_t)tv[v];
                for (int b = 0; b < 3; b++) {
                    w->hre[o + b] += creal(th[l * 9 + 3 * a + b]);
                    w->him[o + b] += cimag(th[l * 9 + 3 * a + b]);
                    w->gre[o + b] += creal(tg[l * 9 + 3 * a + b]);
                    w->gim[o + b] += cimag(tg[l * 9 + 3 * a + b]);
                }
            }
    }
}

/* The Laplace-domain row block of vertex i for the lh variables as->s: w->hre/him/gre/gim, qacc, dacc. */
static void integrate_row(const Assembly *as, RowWork *w, int i)
{
    const DrTriMesh *m = as->mesh;
    const DrBemDesc *d = as->d;
    int n = as->n, lh = as->lh;
    const double *xi = &m->v[3 * i];
    size_t row = (size_t)lh * 3 * (size_t)n;
    memset(w->hre, 0, sizeof(double) * row);
    memset(w->him, 0, sizeof(double) * row);
    memset(w->gre, 0, sizeof(double) * row);
    memset(w->gim, 0, sizeof(double) * row);
    memset(w->hs, 0, sizeof(double) * 3 * (size_t)n);
    for (int q = 0; q < lh * 9; q++) w->dacc[q] = w->lacc[q] = 0;

    DrBemKernelOut ko_reg = {.u = w->ku, .p = w->kp, .d = w->kd, .l = w->kl};
    DrBemKernelOut ko_sing = {.u = w->ku, .p = w->kp, .p_dyn = w->kpd, .d = w->kd, .l = w->kl};
    const double complex *s = as->s;

    for (int t = 0; t < m->nt; t++) {
        const int *tt = &m->tri[3 * t];
        int tv[3] = {tt[0], tt[1], tt[2]};
        int self = tv[0] == i ? 0 : tv[1] == i ? 1 : tv[2] == i ? 2 : -1;
        if (self > 0) { /* rotate so that the collocation vertex is slot 0 (keeps the winding) */
            int r0 = tv[self], r1 = tv[(self + 1) % 3], r2 = tv[(self + 2) % 3];
            tv[0] = r0;
            tv[1] = r1;
            tv[2] = r2;
        }
        const double *a = &m->v[3 * tv[0]], *b = &m->v[3 * tv[1]], *c = &m->v[3 * tv[2]];
        const double *nrm = &as->tn[3 * t];
        int np = self >= 0 ? bem_quad_singular(a, b, c, d->singular_order, w->pts, as->cap)
                           : bem_quad_regular(a, b, c, xi, d->quad_levels, as->max_levels, d->near_factor, w->pts,
                                              as->cap);
        for (int q = 0; q < 3 * 2 * 9 * lh; q++) w->tri[q] = 0;
        double hs_tri[3][9] = {{0}};
        for (int p = 0; p < np; p++) {
            const BemQuadPoint *pt = &w->pts[p];
            double r[3] = {pt->y[0] - xi[0], pt->y[1] - xi[1], pt->y[2] - xi[2]};
            dr_bem_kernel_batch(&as->wave, r, nrm, lh, s, self >= 0 ? &ko_sing : &ko_reg);
            double ps[9];
            dr_bem_kernel_p_static(&as->wave, r, nrm, ps);
            for (int q = 0; q < lh * 9; q++) {
                w->dacc[q] += pt->w * w->kd[q];
                w->lacc[q] += pt->w * w->kl[q];
            }
            for (int v = 0; v < 3; v++) {
                double wf = pt->w * pt->phi[v];
                double complex *th = w->tri + ((size_t)v * 2 + 0) * 9 * lh;
                double complex *tg = w->tri + ((size_t)v * 2 + 1) * 9 * lh;
                /* The collocation vertex's own shape function takes the weakly singular dynamic part only;
                   its static part comes from the rigid-body identity below. */
                const double complex *kp = (self >= 0 && v == 0) ? w->kpd : w->kp;
                for (int q = 0; q < lh * 9; q++) {
                    th[q] += wf * kp[q];
                    tg[q] += wf * w->ku[q];
                }
                if (!(self >= 0 && v == 0))
                    for (int q = 0; q < 9; q++) hs_tri[v][q] += wf * ps[q];
            }
        }
        scatter_tri(as, w, tv);
        for (int v = 0; v < 3; v++)
            for (int a2 = 0; a2 < 3; a2++)
                for (int b2 = 0; b2 < 3; b2++) w->hs[(size_t)a2 * n + 3 * (size_t)tv[v] + b2] += hs_tri[v][3 * a2 + b2];
    }

    /* Rigid-body identity: c_i + PV∫p*_static Φ_i = −Σ_{j≠i} ∫p*_static Φ_j, added to every frequency. */
    double diag[9] = {0};
    for (int a2 = 0; a2 < 3; a2++)
        for (int j = 0; j < m->nv; j++) {
            if (j == i) continue;
            for (int b2 = 0; b2 < 3; b2++) diag[3 * a2 + b2] -= w->hs[(size_t)a2 * n + 3 * (size_t)j + b2];
        }
    for (int l = 0; l < lh; l++)
        for (int a2 = 0; a2 < 3; a2++)
            for (int b2 = 0; b2 < 3; b2++) w->hre[((size_t)l * 3 + a2) * n + 3 * (size_t)i + b2] += diag[3 * a2 + b2];

    /* q̂* = l̂* + d̂*[x − x̄]×ᵀ (eq. 20): x is the collocation point, constant over the integral. */
    double e[3] = {xi[0] - as->xbar[0], xi[1] - as->xbar[1], xi[2] - as->xbar[2]};
    double cxT[9] = {0, e[2], -e[1], -e[2], 0, e[0], e[1], -e[0], 0}; /* [e]×ᵀ = −[e]× */
    double complex *qacc = w->qacc;
    for (int l = 0; l < lh; l++)
        for (int a2 = 0; a2 < 3; a2++)
            for (int b2 = 0; b2 < 3; b2++) {
                double complex sum = w->lacc[l * 9 + 3 * a2 + b2];
                for (int c2 = 0; c2 < 3; c2++) sum += w->dacc[l * 9 + 3 * a2 + c2] * cxT[3 * c2 + b2];
                qacc[l * 9 + 3 * a2 + b2] = sum;
            }
}

/* Time-domain rows of vertex i, eq. (15): ψ_k = Σ_l α_kl Re f̂_l + β_kl Im f̂_l. */
static void time_row(const Assembly *as, const RowWork *w, int i)
{
    int n = as->n, lh = as->lh;
    const double complex *qacc = w->qacc;

    for (int k = 0; k < as->nk; k++) {
        const double *al = &as->alpha[k * lh], *be = &as->beta[k * lh];
        for (int a2 = 0; a2 < 3; a2++) {
            double *hrow = as->H + ((size_t)k * n + 3 * (size_t)i + a2) * n;
            double *grow = as->G + ((size_t)k * n + 3 * (size_t)i + a2) * n;
            for (int col = 0; col < n; col++) {
                hrow[col] = 0;
                grow[col] = 0;
            }
            for (int l = 0; l < lh; l++) {
                const double *hr = &w->hre[((size_t)l * 3 + a2) * n], *hi = &w->him[((size_t)l * 3 + a2) * n];
                const double *gr = &w->gre[((size_t)l * 3 + a2) * n], *gi = &w->gim[((size_t)l * 3 + a2) * n];
                double al_ = al[l], be_ = be[l];
                for (int col = 0; col < n; col++) {
                    hrow[col] += al_ * hr[col] + be_ * hi[col];
                    grow[col] += al_ * gr[col] + be_ * gi[col];
                }
            }
            for (int b2 = 0; b2 < 3; b2++) {
                double dv = 0, qv = 0;
                for (int l = 0; l < lh; l++) {
                    double complex dd = w->dacc[l * 9 + 3 * a2 + b2], qq = qacc[l * 9 + 3 * a2 + b2];
                    dv += al[l] * creal(dd) + be[l] * cimag(dd);
                    qv += al[l] * creal(qq) + be[l] * cimag(qq);
                }
                as->D[((size_t)k * n + 3 * (size_t)i + a2) * 3 + b2] = dv;
                as->Q[((size_t)k * n + 3 * (size_t)i + a2) * 3 + b2] = qv;
            }
        }
    }
}

static DrStatus alloc_doubles(size_t count, double **out, DrError *err)
{
    return dr_calloc(count, sizeof(double), out, err);
}

/* Row-major square matrix to column-major (its transpose), blocked for the cache. */
static void transpose(const double *src, double *dst, int n)
{
    const int B = 64;
#pragma omp parallel for schedule(static)
    for (int ib = 0; ib < n; ib += B)
        for (int jb = 0; jb < n; jb += B)
            for (int i = ib; i < ib + B && i < n; i++)
                for (int j = jb; j < jb + B && j < n; j++) dst[(size_t)j * n + i] = src[(size_t)i * n + j];
}

/* H₀⁻¹ and H₀⁻¹G′ by LU (LAPACK dgetrf/dgetri/dgetrs), with OpenBLAS threads on for the duration. */
static DrStatus invert_h0(const double *H0, const double *Gp, int n, double *H0inv, double *X, DrError *err)
{
    double *lu = NULL, *work = NULL;
    int *ipiv = NULL;
    DrStatus s = alloc_doubles((size_t)n * n, &lu, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof(int), &ipiv, err);
    if (s != DR_OK) goto done;
    transpose(H0, lu, n); /* column-major H₀ */
    openblas_set_num_threads(omp_get_max_threads());
    int info = 0;
    dgetrf_(&n, &n, lu, &n, ipiv, &info);
    if (info != 0) {
        s = dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                         "BEM: H0 is singular (LU pivot %d is zero); the mesh may be degenerate or the time step far "
                         "outside the range the matrices can represent",
                         info);
        goto done;
    }
    transpose(Gp, X, n); /* column-major G′ → solve in place */
    dgetrs_("N", &n, &n, lu, &n, ipiv, X, &n, &info, 1);
    assert(info == 0);
    memcpy(H0inv, lu, sizeof(double) * (size_t)n * n);
    int lwork = -1;
    double wq = 0;
    dgetri_(&n, H0inv, &n, ipiv, &wq, &lwork, &info);
    lwork = (int)wq;
    s = alloc_doubles((size_t)(lwork > 1 ? lwork : 1), &work, err);
    if (s != DR_OK) goto done;
    dgetri_(&n, H0inv, &n, ipiv, work, &lwork, &info);
    assert(info == 0);
    /* both are column-major now: back to row-major */
    transpose(H0inv, lu, n);
    memcpy(H0inv, lu, sizeof(double) * (size_t)n * n);
    transpose(X, lu, n);
    memcpy(X, lu, sizeof(double) * (size_t)n * n);
done:
    openblas_set_num_threads(1);
    free(lu);
    free(work);
    free(ipiv);
    return s;
}

/* Unit normal of every triangle (3·nt). */
static void triangle_normals(const DrTriMesh *mesh, double *tn)
{
    for (int t = 0; t < mesh->nt; t++) {
        const double *a = &mesh->v[3 * mesh->tri[3 * t]], *b = &mesh->v[3 * mesh->tri[3 * t + 1]],
                     *c = &mesh->v[3 * mesh->tri[3 * t + 2]];
        DrVec3 nr = dr_v3_normalize(
            dr_v3_cross(dr_v3(b[0] - a[0], b[1] - a[1], b[2] - a[2]), dr_v3(c[0] - a[0], c[1] - a[1], c[2] - a[2])));
        tn[3 * t] = nr.x;
        tn[3 * t + 1] = nr.y;
        tn[3 * t + 2] = nr.z;
    }
}

/* What is done with a row block once integrated: written as time-domain rows, or copied out as it is. */
typedef void (*RowSink)(const Assembly *as, const RowWork *w, int i, void *ctx);

/* Every collocation vertex's row block in parallel (rows are independent: the result does not depend on the
   thread count), each handed to `sink`; progress on stderr when `prog` is not NULL. */
static DrStatus for_each_row(const Assembly *as, RowSink sink, void *ctx, DrProgress *prog, DrError *err)
{
    bool oom = false;
    int nv = as->mesh->nv;
#pragma omp parallel
    {
        RowWork w;
        bool ok = rowwork_alloc(&w, as->cap, as->lh, as->n);
        if (!ok) {
#pragma omp atomic write
            oom = true;
        }
#pragma omp for schedule(dynamic, 1)
        for (int i = 0; i < nv; i++) {
            if (!ok) continue;
            integrate_row(as, &w, i);
            sink(as, &w, i, ctx);
            if (prog) {
#pragma omp critical(dr_bem_progress)
                dr_progress_step(prog, NULL);
            }
        }
        rowwork_free(&w);
    }
    if (oom) return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "BEM: out of memory for the per-thread row scratch");
    return DR_OK;
}

static void time_row_sink(const Assembly *as, const RowWork *w, int i, void *ctx)
{
    (void)ctx;
    time_row(as, w, i);
}

DrStatus dr_bem_matrices_build(const DrTriMesh *mesh, const DrBemDesc *d, const char *label, DrBemMatrices **out,
                               DrError *err)
{
    *out = NULL;
    DR_TRY(check_desc(d, err));
    if (mesh->nv < 4 || mesh->nt < 4)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "BEM: a body needs a closed mesh of at least 4 triangles");
    double t0 = dr_time_now();
    DrBemMatrices *m = NULL;
    DR_TRY(dr_calloc(1, sizeof *m, &m, err));
    DrStatus s = bem_runtime_new(&m->runtime, err);
    int nv = mesh->nv, n = 3 * nv;
    m->nv = nv;
    m->n = n;
    m->nt = mesh->nt;
    m->desc = *d;
    double *tn = NULL, *alpha = NULL, *beta = NULL;
    int *order = NULL;
    DrBemCq cq = {0};
    if (s != DR_OK) goto fail;

    dr_bem_body_compute(mesh, d->material.density, &m->body);
    m->n_max = dr_bem_history_length(d, m->body.r_max);
    int nk = m->n_max + 1, L = nk, lh = L / 2 + 1;
    if (lh > 64) {
        s = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                         "BEM: the history would hold %d steps (r_max %.3g m, shear wave speed %.3g m/s, time step "
                         "%.3g s); at most 126 are supported: use a larger time_step or a stiffer material",
                         nk, m->body.r_max, sqrt(d->material.shear_modulus / d->material.density), d->dt);
        goto fail;
    }
    /* Dense storage while assembling: 2·(n_max+1) matrices of n² doubles. */
    size_t nn = (size_t)n * (size_t)n;
    if (nn / (size_t)n != (size_t)n || nn > SIZE_MAX / 8 / (size_t)(2 * nk + 4)) {
        s = dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "BEM: %d vertices with %d history steps overflow memory", nv,
                         nk);
        goto fail;
    }

    s = dr_calloc((size_t)3 * nv, sizeof(double), &m->x, err);
    if (s == DR_OK) s = dr_calloc((size_t)3 * mesh->nt, sizeof(int), &m->tri, err);
    if (s == DR_OK) s = alloc_doubles((size_t)3 * n, &m->A, err);
    if (s == DR_OK) s = alloc_doubles((size_t)3 * n, &m->C, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nv, &m->w, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nv, &m->area, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nk * n * 3, &m->D, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nk * n * 3, &m->Q, err);
    if (s == DR_OK) s = alloc_doubles((size_t)3 * mesh->nt, &tn, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nk * lh, &alpha, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nk * lh, &beta, err);
    if (s == DR_OK) s = dr_calloc((size_t)nv, sizeof(int), &order, err);
    if (s == DR_OK) s = dr_calloc((size_t)nk, sizeof(DrBemCMat), &m->H, err);
    if (s == DR_OK) s = dr_calloc((size_t)nk, sizeof(DrBemCMat), &m->G, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nk * nn, &m->H_dense, err);
    if (s == DR_OK) s = alloc_doubles((size_t)nk * nn, &m->G_dense, err);
    if (s == DR_OK) s = dr_bem_cq_init(L, d->cq_epsilon, d->dt, &cq, err);
    if (s != DR_OK) goto fail;
    memcpy(m->x, mesh->v, sizeof(double) * 3 * (size_t)nv);
    memcpy(m->tri, mesh->tri, sizeof(int) * 3 * (size_t)mesh->nt);
    dr_bem_vertex_areas(mesh, m->area);
    dr_bem_frame_operators(mesh, &m->body, m->A, m->C, m->w);
    dr_bem_vertex_order(mesh, order);
    s = dr_bem_layout_init(nv, d->ordering, d->wavelet, order, &m->layout, err);
    if (s != DR_OK) goto fail;
    triangle_normals(mesh, tn);
    cq_real_weights(&cq, nk, lh, alpha, beta);

    /* 1. rows: Laplace-domain integrals and their time-domain weights */
    Assembly as = {.mesh = mesh, .d = d, .cq = &cq, .s = cq.s, .tn = tn, .n = n, .lh = lh, .nk = nk,
                   .max_levels = d->quad_levels + 3, .alpha = alpha, .beta = beta,
                   .H = m->H_dense, .G = m->G_dense, .D = m->D, .Q = m->Q};
    dr_bem_wave_init(&d->material, &as.wave);
    as.cap = bem_quad_capacity(d->quad_levels, as.max_levels, d->singular_order);
    memcpy(as.xbar, m->body.centroid, sizeof as.xbar);
    m->stats.frequencies_evaluated = lh;

    DrProgress prog;
    char plabel[256];
    snprintf(plabel, sizeof plabel, "bem %s: %d vertices, %d history steps", label ? label : "", nv, m->n_max);
    if (label) dr_progress_begin(&prog, plabel, nv);
    s = for_each_row(&as, time_row_sink, NULL, label ? &prog : NULL, err);
    if (label) dr_progress_end(&prog);
    if (s != DR_OK) goto fail;
    double t1 = dr_time_now();
    m->stats.seconds_quadrature = t1 - t0;

    /* 2. how much of a rigid translation the truncated history leaves: Σ_k H_k m → 0 for a complete history */
    {
        double worst = 0;
        for (int ax = 0; ax < 3; ax++) {
            double num = 0, den = 0;
            for (int r = 0; r < n; r++) {
                double sum = 0, h0 = 0;
                for (int k = 0; k < nk; k++) {
                    const double *row = m->H_dense + ((size_t)k * n + r) * n;
                    double acc = 0;
                    for (int j = 0; j < nv; j++) acc += row[3 * j + ax];
                    sum += acc;
                    if (k == 0) h0 = acc;
                }
                num += sum * sum;
                den += h0 * h0;
            }
            double rel = den > 0 ? sqrt(num / den) : 0;
            if (rel > worst) worst = rel;
        }
        m->stats.rigid_residual = worst;
    }

    /* 3. G′ = G₀ + D₀A + Q₀C (eq. 12), then H₀⁻¹ and H₀⁻¹G′ */
    double *Gp = NULL, *H0inv = NULL, *X = NULL;
    s = alloc_doubles(nn, &Gp, err);
    if (s == DR_OK) s = alloc_doubles(nn, &H0inv, err);
    if (s == DR_OK) s = alloc_doubles(nn, &X, err);
    if (s == DR_OK) {
#pragma omp parallel for schedule(static)
        for (int r = 0; r < n; r++) {
            const double *d0 = &m->D[(size_t)r * 3], *q0 = &m->Q[(size_t)r * 3];
            for (int c = 0; c < n; c++) {
                double v = m->G_dense[(size_t)r * n + c];
                for (int b = 0; b < 3; b++) v += d0[b] * m->A[(size_t)b * n + c] + q0[b] * m->C[(size_t)b * n + c];
                Gp[(size_t)r * n + c] = v;
            }
        }
        s = invert_h0(m->H_dense, Gp, n, H0inv, X, err);
    }
    double t2 = dr_time_now();
    m->stats.seconds_inverse = t2 - t1;

    /* 4. compression (§3.3) */
    if (s == DR_OK) s = dr_bem_compress(&m->layout, H0inv, d->compression_ratio, &m->H0inv, err);
    if (s == DR_OK) s = dr_bem_compress(&m->layout, X, d->compression_ratio, &m->H0inv_Gp, err);
    free(Gp);
    free(H0inv);
    free(X);
    for (int k = 0; s == DR_OK && k < nk; k++) {
        s = dr_bem_compress(&m->layout, m->H_dense + (size_t)k * nn, d->compression_ratio, &m->H[k], err);
        if (s == DR_OK) s = dr_bem_compress(&m->layout, m->G_dense + (size_t)k * nn, d->compression_ratio, &m->G[k], err);
    }
    if (s != DR_OK) goto fail;
    m->stats.seconds_compress = dr_time_now() - t2;
    m->stats.bytes_dense = (size_t)(2 * nk + 2) * nn * sizeof(double);
    size_t bytes = dr_bem_cmat_bytes(&m->H0inv) + dr_bem_cmat_bytes(&m->H0inv_Gp);
    for (int k = 0; k < nk; k++) bytes += dr_bem_cmat_bytes(&m->H[k]) + dr_bem_cmat_bytes(&m->G[k]);
    m->stats.bytes_compressed = bytes;
    if (!d->keep_dense) {
        free(m->H_dense);
        free(m->G_dense);
        m->H_dense = m->G_dense = NULL;
    }
    free(tn);
    free(alpha);
    free(beta);
    free(order);
    dr_bem_cq_free(&cq);
    *out = m;
    return DR_OK;

fail:
    free(tn);
    free(alpha);
    free(beta);
    free(order);
    dr_bem_cq_free(&cq);
    dr_bem_matrices_destroy(&m);
    return s;
}

typedef struct LaplaceOut {
    double complex *H, *G, *D, *Q;
} LaplaceOut;

static void laplace_sink(const Assembly *as, const RowWork *w, int i, void *ctx)
{
    const LaplaceOut *o = ctx;
    int n = as->n;
    for (int l = 0; l < as->lh; l++)
        for (int a = 0; a < 3; a++) {
            size_t src = ((size_t)l * 3 + a) * n, dst = ((size_t)l * n + 3 * (size_t)i + a) * n;
            for (int c = 0; c < n; c++) {
                o->H[dst + c] = w->hre[src + c] + I * w->him[src + c];
                o->G[dst + c] = w->gre[src + c] + I * w->gim[src + c];
            }
            for (int b = 0; b < 3; b++) {
                size_t q = ((size_t)l * n + 3 * (size_t)i + a) * 3 + b;
                if (o->D) o->D[q] = w->dacc[l * 9 + 3 * a + b];
                if (o->Q) o->Q[q] = w->qacc[l * 9 + 3 * a + b];
            }
        }
}

DrStatus bem_laplace_matrices(const DrTriMesh *mesh, const DrBemDesc *d, int ns, const double complex *s,
                              double complex *H, double complex *G, double complex *D, double complex *Q,
                              DrError *err)
{
    DR_TRY(check_desc(d, err));
    assert(ns >= 1 && ns <= 64);
    int n = 3 * mesh->nv;
    DrBemBody body;
    dr_bem_body_compute(mesh, d->material.density, &body);
    double *tn = NULL;
    DR_TRY(alloc_doubles((size_t)3 * mesh->nt, &tn, err));
    triangle_normals(mesh, tn);
    Assembly as = {.mesh = mesh, .d = d, .s = s, .tn = tn, .n = n, .lh = ns, .max_levels = d->quad_levels + 3};
    dr_bem_wave_init(&d->material, &as.wave);
    as.cap = bem_quad_capacity(d->quad_levels, as.max_levels, d->singular_order);
    memcpy(as.xbar, body.centroid, sizeof as.xbar);
    LaplaceOut lo = {H, G, D, Q};
    DrStatus st = for_each_row(&as, laplace_sink, &lo, NULL, err);
    free(tn);
    return st;
}

