/* One boundary-element body in a shot: eq. (9) stepped by eq. (12) inside a rigid frame moved by eqs. (10)–(11),
 * with the error correction of BEM §3.2.1.
 *
 * The history sums of eq. (9) run over the last n_max steps. Their displacement and traction vectors are kept in
 * the coefficient domain of the compressed matrices (x̃ = W P x), so the sum Σ_k (−H̃_k ũ_{n−k} + G̃_k p̃_{n−k})
 * costs one sparse product per matrix and a single inverse transform. The frame accelerations b = a − g′ and α
 * of past steps enter through the 3N × 3 matrices D_k and Q_k.
 *
 * Omitted as in the paper: the centrifugal and Coriolis forces of the rotating frame (a body spinning freely does
 * not bulge), and the momentum of the deformation itself in the frame's dynamics; error correction returns the
 * drift these leave in u to the frame. */
#include "bem_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>


void dr_bem_solid_desc_default(DrBemSolidDesc *d)
{
    *d = (DrBemSolidDesc){
        .gravity = {0, -9.81, 0},
        .rotation = {1, 0, 0, 0, 1, 0, 0, 0, 1},
        .frame_update = true,
        .error_correction = true,
    };
}

/* The rotation of the polar decomposition A = R S (det R = +1) by Higham's scaled Newton iteration; the shape-
   matching matrices it meets are near rotations, so a handful of iterations reach round-off. */
static void polar_rotation(const double *A, double *Rm)
{
    double X[9];
    memcpy(X, A, sizeof X);
    for (int it = 0; it < 30; it++) {
        double Xi[9];
        if (!dr_m3a_inverse(X, Xi)) {
            memcpy(Rm, (double[9]){1, 0, 0, 0, 1, 0, 0, 0, 1}, sizeof X);
            return;
        }
        double g = pow(fabs(dr_m3a_det(X)), -1.0 / 3.0), next[9], change = 0;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) next[3 * i + j] = 0.5 * (g * X[3 * i + j] + Xi[3 * j + i] / g);
        for (int q = 0; q < 9; q++) change = fmax(change, fabs(next[q] - X[q]));
        memcpy(X, next, sizeof X);
        if (change < 1e-15) break;
    }
    memcpy(Rm, X, sizeof X);
}

/* ---- creation --------------------------------------------------------------------------------------------- */

/* (MᵀM)⁻¹Mᵀ for an n × 3 row-major M: the least-squares solve of §3.2.1 as a 3 × n matrix. */
static bool pinv_n3(const double *M, int n, double *P)
{
    double G[9] = {0}, Gi[9];
    for (int r = 0; r < n; r++)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) G[3 * i + j] += M[3 * r + i] * M[3 * r + j];
    if (!dr_m3a_inverse(G, Gi)) return false;
    for (int r = 0; r < n; r++)
        for (int i = 0; i < 3; i++)
            P[(size_t)i * n + r] = Gi[3 * i] * M[3 * r] + Gi[3 * i + 1] * M[3 * r + 1] + Gi[3 * i + 2] * M[3 * r + 2];
    return true;
}

static void runtime_copies_free(BemRuntime *rt)
{
    if (rt->Hq)
        for (int k = 1; k <= rt->nmax; k++) {
            bem_cmatq_free(&rt->Hq[k]);
            bem_cmatq_free(&rt->Gq[k]);
        }
    free(rt->Hq);
    free(rt->Gq);
    rt->Hq = rt->Gq = NULL;
    bem_cmatq_free(&rt->H0q);
    bem_cmatq_free(&rt->Gpq);
}

DrStatus bem_runtime_new(BemRuntime **out, DrError *err)
{
    return dr_calloc(1, sizeof **out, out, err);
}

void bem_runtime_free(BemRuntime **prt)
{
    BemRuntime *rt = prt ? *prt : NULL;
    if (!rt) return;
    runtime_copies_free(rt);
    bem_columns_free(&rt->gp_cols);
    free(rt);
    *prt = NULL;
}

/* The compact copies every product of a step reads (bem_compress.c), made once per set; when one cannot be made,
   none are kept and the double products serve. The matrices that multiply tractions also get their column form
   (a traction's products then read only the columns it touches); without memory for it they go by rows. */
static void runtime_make(BemRuntime *rt, const DrBemMatrices *m)
{
    if (rt->made) return;
    rt->made = true;
    rt->made_for[0] = m->H, rt->made_for[1] = m->G, rt->made_for[2] = m->H0inv.val;
    if (m->H0inv.dense) return;
    rt->nmax = m->n_max;
    DrError err; /* no room for the copies is no failure: the double products serve */
    bool ok = dr_calloc((size_t)rt->nmax + 1, sizeof(BemCMatQ), &rt->Hq, &err) == DR_OK &&
              dr_calloc((size_t)rt->nmax + 1, sizeof(BemCMatQ), &rt->Gq, &err) == DR_OK && bem_cmat_compact(&m->H0inv, &rt->H0q) && bem_cmat_compact(&m->H0inv_Gp, &rt->Gpq);
    for (int k = 1; ok && k <= rt->nmax; k++)
        ok = bem_cmat_compact(&m->H[k], &rt->Hq[k]) && bem_cmat_compact(&m->G[k], &rt->Gq[k]);
    if (!ok) {
        runtime_copies_free(rt);
        return;
    }
    (void)bem_cmatq_add_columns(&rt->Gpq);
    for (int k = 1; k <= rt->nmax; k++) (void)bem_cmatq_add_columns(&rt->Gq[k]);
}

void dr_bem_solid_destroy(DrBemSolid **ps)
{
    DrBemSolid *s = ps ? *ps : NULL;
    if (!s) return;
    free(s->ref);
    free(s->u);
    free(s->ut_hist);
    free(s->pt_hist);
    free(s->b_hist);
    free(s->al_hist);
    free(s->E);
    free(s->F);
    free(s->Epinv);
    free(s->Fpinv);
    free(s->s_ht);
    free(s->s_tmp);
    free(s->s_h);
    free(s->hz);
    bem_runtime_free(&s->own_rt);
    free(s->sum_mats);
    free(s->sum_x);
    free(s->sum_sign);
    free(s->s_p);
    free(s->s_u);
    free(s->s_z);
    free(s->s_r);
    free(s->s_coeff);
    free(s->smp_x);
    free(s->smp_v);
    free(s->smp_n);
    free(s->smp_w);
    bem_group_work_free(&s->group);
    free(s);
    *ps = NULL;
}

/* y = M x (natural order) through M's compact copy Mq when the solid has them, using the solid's transform
   scratch. */
static void apply(const DrBemSolid *s, const DrBemCMat *M, const BemCMatQ *Mq, const double *x, double *y)
{
    if (s->rt->Hq) bem_cmatq_matvec(&s->m->layout, Mq, x, y, s->s_coeff);
    else dr_bem_cmat_matvec(&s->m->layout, M, x, y, s->s_coeff);
}

static bool nonzero(const double *x, int n)
{
    for (int i = 0; i < n; i++)
        if (x[i] != 0.0) return true;
    return false;
}

DrStatus dr_bem_solid_create(const DrBemMatrices *m, const DrBemSolidDesc *d, DrBemSolid **out, DrError *err)
{
    *out = NULL;
    DrBemSolid *s = NULL;
    DR_TRY(dr_calloc(1, sizeof *s, &s, err));
    s->m = m;
    s->d = *d;
    s->n = m->n;
    s->nv = m->nv;
    s->nmax = m->n_max;
    s->dense = m->H0inv.dense;
    size_t n = (size_t)s->n, nh = (size_t)s->nmax;
    DrStatus st = dr_calloc(n, sizeof(double), &s->ref, err);
    if (st == DR_OK) st = dr_calloc(n, sizeof(double), &s->u, err);
    if (st == DR_OK) st = dr_calloc(nh * n, sizeof(double), &s->ut_hist, err);
    if (st == DR_OK) st = dr_calloc(nh * n, sizeof(double), &s->pt_hist, err);
    if (st == DR_OK) st = dr_calloc(nh * 3, sizeof(double), &s->b_hist, err);
    if (st == DR_OK) st = dr_calloc(nh * 3, sizeof(double), &s->al_hist, err);
    double **n3[] = {&s->E, &s->F, &s->Epinv, &s->Fpinv};
    for (int i = 0; st == DR_OK && i < 4; i++) st = dr_calloc(3 * n, sizeof(double), n3[i], err);
    double **scratch[] = {&s->s_ht, &s->s_tmp, &s->s_h,   &s->s_p,   &s->s_u,   &s->s_z,
                          &s->s_r,  &s->smp_x, &s->smp_v, &s->smp_n, &s->smp_w};
    for (int i = 0; st == DR_OK && i < 11; i++) st = dr_calloc(n, sizeof(double), scratch[i], err);
    if (st == DR_OK) st = dr_calloc((2 + BEM_COLUMN_GROUPS) * n, sizeof(double), &s->s_coeff, err);
    if (st == DR_OK) st = dr_calloc(n, sizeof(double), &s->hz, err);
    if (st == DR_OK) st = dr_calloc(2 * nh, sizeof *s->sum_mats, &s->sum_mats, err);
    if (st == DR_OK) st = dr_calloc(2 * nh, sizeof *s->sum_x, &s->sum_x, err);
    if (st == DR_OK) st = dr_calloc(2 * nh, sizeof *s->sum_sign, &s->sum_sign, err);
    if (st != DR_OK) {
        dr_bem_solid_destroy(&s);
        return st;
    }
    /* compact copies of every matrix a step multiplies by, 4 bytes per coefficient against 12 (bem_compress.c),
       shared by the bodies on the set */
    s->rt = m->runtime;
    if (s->rt && s->rt->made &&
        (s->rt->made_for[0] != m->H || s->rt->made_for[1] != m->G || s->rt->made_for[2] != m->H0inv.val))
        s->rt = NULL;
    if (!s->rt && bem_runtime_new(&s->own_rt, err) != DR_OK) {
        dr_bem_solid_destroy(&s);
        return DR_ERR_NOMEM;
    }
    if (!s->rt) s->rt = s->own_rt;
    runtime_make(s->rt, m);
    const double *xb = m->body.centroid;
    for (int v = 0; v < s->nv; v++)
        for (int c = 0; c < 3; c++) s->ref[3 * v + c] = m->x[3 * v + c] - xb[c];
    s->wsum = 0;
    for (int v = 0; v < s->nv; v++) {
        s->wsum += m->w[v];
        for (int c = 0; c < 3; c++) s->c0[c] += m->w[v] * s->ref[3 * v + c];
    }
    for (int c = 0; c < 3; c++) s->c0[c] /= s->wsum;
    /* E = H₀⁻¹D₀ and F = H₀⁻¹Q₀ with the same (compressed) H₀⁻¹ the steps use */
    for (int c = 0; c < 3; c++) {
        for (int r = 0; r < s->n; r++) s->s_tmp[r] = m->D[3 * r + c];
        apply(s, &m->H0inv, &s->rt->H0q, s->s_tmp, s->s_u);
        for (int r = 0; r < s->n; r++) s->E[3 * r + c] = s->s_u[r];
        for (int r = 0; r < s->n; r++) s->s_tmp[r] = m->Q[3 * r + c];
        apply(s, &m->H0inv, &s->rt->H0q, s->s_tmp, s->s_u);
        for (int r = 0; r < s->n; r++) s->F[3 * r + c] = s->s_u[r];
    }
    if (!pinv_n3(s->E, s->n, s->Epinv) || !pinv_n3(s->F, s->n, s->Fpinv)) {
        dr_bem_solid_destroy(&s);
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "BEM: the body-force matrices H0^-1 D0 or H0^-1 Q0 are rank-deficient; the matrices are "
                            "damaged or the mesh is degenerate: run precompute again");
    }
    memcpy(s->R, d->rotation, sizeof s->R);
    memcpy(s->T, d->position, sizeof s->T);
    if (d->frame_update) {
        memcpy(s->Tdot, d->velocity, sizeof s->Tdot);
        memcpy(s->omega, d->angular_velocity, sizeof s->omega);
    }
    *out = s;
    return DR_OK;
}

/* ---- one step ---------------------------------------------------------------------------------------------- */

static int slot(const DrBemSolid *s, long j) { return (int)((j - 1) % s->nmax); } /* step j ≥ 1 */


/* out += Σ_c M[r][c] v[c] for an n × 3 row-major M. */
static void add_n3(const double *M, int n, const double v[3], double *out)
{
    for (int r = 0; r < n; r++) out[r] += M[3 * r] * v[0] + M[3 * r + 1] * v[1] + M[3 * r + 2] * v[2];
}

static void mul_3n(const double *P, int n, const double *x, double out[3])
{
    for (int i = 0; i < 3; i++) {
        double acc = 0;
        for (int r = 0; r < n; r++) acc += P[(size_t)i * n + r] * x[r];
        out[i] = acc;
    }
}

/* h += Σ_{k=1}^{n_max} (D_k b_{n−k} + Q_k α_{n−k}) in one pass over the rows, each taking the terms in the order of k.
   On one thread: 0.1 ms at 2,906 vertices, less than a thread team costs to start and join on a busy machine. */
static void add_history_forces(const DrBemSolid *s, long step, double *h)
{
    const DrBemMatrices *m = s->m;
    int n = s->n, kmax = step - 1 < s->nmax ? (int)(step - 1) : s->nmax;
    for (int r = 0; r < n; r++) {
        double acc = h[r];
        for (int k = 1; k <= kmax; k++) {
            int sl = slot(s, step - k);
            const double *D = m->D + ((size_t)k * n + r) * 3, *Q = m->Q + ((size_t)k * n + r) * 3;
            const double *b = s->b_hist + 3 * sl, *al = s->al_hist + 3 * sl;
            acc += D[0] * b[0] + D[1] * b[1] + D[2] * b[2];
            acc += Q[0] * al[0] + Q[1] * al[1] + Q[2] * al[2];
        }
        h[r] = acc;
    }
}

/* ---- the step in phases: predict (the history), solve (eqs. 9–12 and §3.2.1 for a traction), commit ---------- */

double dr_bem_solid_stable_dt(const DrBemSolid *s) { return s->m->desc.dt; }

DrStatus dr_bem_solid_predict(DrBemSolid *s, DrError *err)
{
    (void)err;
    const DrBemMatrices *m = s->m;
    int n = s->n;
    size_t nb = sizeof(double) * (size_t)n;
    double t0 = dr_time_now();
    long step = s->step + 1; /* the step being taken */

    /* h = Σ_{k=1}^{n_max} (−H_k u_{n−k} + G_k p_{n−k} + D_k b_{n−k} + Q_k α_{n−k}) (eq. 9), and H₀⁻¹h. It depends on
       past steps only, so every solve of the step shares it (and a second predict of the same step reuses it). */
    double *tmp = s->s_tmp;
    if (s->hz_step != step) {
        double *ht = s->s_ht, *h = s->s_h;
        memset(ht, 0, nb);
        memset(h, 0, nb);
        const BemCMatQ **mats = s->sum_mats;
        const double **xs = s->sum_x;
        double *signs = s->sum_sign;
        int count = 0;
        for (int k = 1; k <= s->nmax && k < step; k++) {
            int sl = slot(s, step - k);
            const double *uk = s->ut_hist + (size_t)sl * n, *pk = s->pt_hist + (size_t)sl * n;
            bool loaded_k = nonzero(pk, n); /* a traction-free past step adds nothing through G_k */
            if (s->rt->Hq) {
                mats[count] = &s->rt->Hq[k], xs[count] = uk, signs[count++] = -1.0;
                if (loaded_k) mats[count] = &s->rt->Gq[k], xs[count] = pk, signs[count++] = 1.0;
                continue;
            }
            dr_bem_cmat_matvec_coeff(&m->H[k], uk, tmp);
            for (int i = 0; i < n; i++) ht[i] -= tmp[i];
            if (!loaded_k) continue;
            dr_bem_cmat_matvec_coeff(&m->G[k], pk, tmp);
            for (int i = 0; i < n; i++) ht[i] += tmp[i];
        }
        (void)bem_cmatq_sum(mats, xs, signs, count, ht, s->s_coeff);
        if (step > 1) dr_bem_layout_from_coeff(&m->layout, s->dense, ht, h, s->s_coeff);
        add_history_forces(s, step, h);
        if (step > 1) apply(s, &m->H0inv, &s->rt->H0q, h, s->hz);
        else memset(s->hz, 0, nb);
        s->hz_step = step;
    }
    s->pred_seconds = dr_time_now() - t0;
    s->phase = BEM_PHASE_PREDICTED;
    return DR_OK;
}

DrStatus dr_bem_solid_solve(DrBemSolid *s, const double *traction, const double *force, DrBemStepStats *st,
                            DrError *err)
{
    assert(s->phase != BEM_PHASE_NONE && "dr_bem_solid_solve: no prediction (dr_bem_solid_predict first)");
    s->phase = BEM_PHASE_PREDICTED; /* until this solve succeeds */
    const DrBemMatrices *m = s->m;
    int n = s->n;
    size_t nb = sizeof(double) * (size_t)n;
    double dt = m->desc.dt;
    DrBemStepStats stats = {.seconds_history = s->pred_seconds};
    double t1 = dr_time_now();
    long step = s->step + 1;

    /* 1. the load: p = traction + Rᵀ f / area_j (body frame, the start-of-step rotation as in eqs. 11d–e) */
    double *p = s->s_p;
    bool loaded = false;
    if (traction) memcpy(p, traction, nb);
    else memset(p, 0, nb);
    if (force)
        for (int v = 0; v < s->nv; v++) {
            double fb[3];
            dr_m3a_apply_t(s->R, &force[3 * v], fb);
            for (int c = 0; c < 3; c++) p[3 * v + c] += fb[c] / m->area[v];
        }
    if (traction || force)
        for (int i = 0; i < n && !loaded; i++) loaded = p[i] != 0.0;

    /* 2. eq. (9) solved for u given the frame accelerations b = a − g′ and α: u = z + E b + F α with
          z = H₀⁻¹(G₀p + h) = H₀⁻¹G′p − E A p − F C p + H₀⁻¹h (G′ = G₀ + D₀A + Q₀C, eq. 12) */
    double gp[3], b0[3] = {0, 0, 0}, al0[3] = {0, 0, 0};
    dr_m3a_apply_t(s->R, s->d.gravity, gp); /* g′ = Rᵀ g (11a) */
    double *u = s->s_u, *z = s->s_z, *r = s->s_r;
    memset(z, 0, nb);
    if (loaded) {
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < n; c++) {
                b0[i] += m->A[(size_t)i * n + c] * p[c]; /* a_ext = A p, α = C p (eq. 10) */
                al0[i] += m->C[(size_t)i * n + c] * p[c];
            }
        apply(s, &m->H0inv_Gp, &s->rt->Gpq, p, z);
        double nb0[3] = {-b0[0], -b0[1], -b0[2]}, nal0[3] = {-al0[0], -al0[1], -al0[2]};
        add_n3(s->E, n, nb0, z);
        add_n3(s->F, n, nal0, z);
    }
    for (int i = 0; i < n; i++) z[i] += s->hz[i];
    double b[3], al[3];
    if (s->d.frame_update) { /* a = g′ + A p (11b), α = C p (11c): g′ cancels in b */
        memcpy(b, b0, sizeof b);
        memcpy(al, al0, sizeof al);
    } else { /* a fixed frame: a = 0, so b = −g′ and α = 0, and u carries all motion */
        for (int c = 0; c < 3; c++) b[c] = -gp[c];
        al[0] = al[1] = al[2] = 0;
    }
    memcpy(u, z, nb);
    add_n3(s->E, n, b, u);
    add_n3(s->F, n, al, u);
    double t2 = dr_time_now();
    stats.seconds_solve = t2 - t1;

    /* 3. error correction (§3.2.1): the translation and rotation left in u go to the frame's accelerations. The
          least-squares solves of eq. (9) for b and α are taken in its H₀⁻¹-multiplied form u = z + E b + F α, which
          needs no product with H₀ or G₀ themselves. */
    if (s->d.frame_update && s->d.error_correction) {
        double te[3] = {0, 0, 0};
        for (int v = 0; v < s->nv; v++)
            for (int c = 0; c < 3; c++) te[c] += m->w[v] * u[3 * v + c];
        for (int c = 0; c < 3; c++) te[c] /= s->wsum;
        for (int v = 0; v < s->nv; v++)
            for (int c = 0; c < 3; c++) u[3 * v + c] -= te[c];
        stats.translation_error = sqrt(te[0] * te[0] + te[1] * te[1] + te[2] * te[2]);
        /* b: E b ≈ u − z − F α */
        for (int i = 0; i < n; i++) r[i] = u[i] - z[i];
        double nal[3] = {-al[0], -al[1], -al[2]};
        add_n3(s->F, n, nal, r);
        mul_3n(s->Epinv, n, r, b);
        /* the rotation by shape matching with the weights w: A_pq = Σ w (ref + u − c0)(ref − c0)ᵀ */
        double Apq[9] = {0}, Re[9];
        for (int v = 0; v < s->nv; v++) {
            double q[3], y[3];
            for (int c = 0; c < 3; c++) {
                q[c] = s->ref[3 * v + c] - s->c0[c];
                y[c] = q[c] + u[3 * v + c];
            }
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) Apq[3 * i + j] += m->w[v] * y[i] * q[j];
        }
        polar_rotation(Apq, Re);
        double tr = Re[0] + Re[4] + Re[8];
        stats.rotation_error = acos(fmax(-1.0, fmin(1.0, 0.5 * (tr - 1.0))));
        for (int v = 0; v < s->nv; v++) { /* u ← Reᵀ(ref + u − c0) + c0 − ref */
            double y[3], w3[3];
            for (int c = 0; c < 3; c++) y[c] = s->ref[3 * v + c] + u[3 * v + c] - s->c0[c];
            dr_m3a_apply_t(Re, y, w3);
            for (int c = 0; c < 3; c++) u[3 * v + c] = w3[c] + s->c0[c] - s->ref[3 * v + c];
        }
        /* α: F α ≈ u − z − E b; then u from (9) with both */
        for (int i = 0; i < n; i++) r[i] = u[i] - z[i];
        double nb3[3] = {-b[0], -b[1], -b[2]};
        add_n3(s->E, n, nb3, r);
        mul_3n(s->Fpinv, n, r, al);
        memcpy(u, z, nb);
        add_n3(s->E, n, b, u);
        add_n3(s->F, n, al, u);
    }
    stats.seconds_correction = dr_time_now() - t2;

    /* 4. the frame (eqs. 11d–g) with a = g′ + b in the body frame */
    double R[9], T[3], Tdot[3], omega[3];
    memcpy(R, s->R, sizeof R);
    memcpy(T, s->T, sizeof T);
    memcpy(Tdot, s->Tdot, sizeof Tdot);
    memcpy(omega, s->omega, sizeof omega);
    if (s->d.frame_update) {
        double a[3] = {gp[0] + b[0], gp[1] + b[1], gp[2] + b[2]}, Ra[3], Ral[3], rot[9];
        dr_m3a_apply(s->R, a, Ra);
        dr_m3a_apply(s->R, al, Ral);
        for (int c = 0; c < 3; c++) {
            Tdot[c] += dt * Ra[c];
            omega[c] += dt * Ral[c];
            T[c] += dt * Tdot[c];
        }
        dr_m3_store(dr_m3_rotation_exp(dr_v3(dt * omega[0], dt * omega[1], dt * omega[2])), rot); /* eq. 11g */
        dr_m3a_mul(rot, s->R, R);
    }
    bool finite = true;
    for (int i = 0; i < n && finite; i++) finite = isfinite(u[i]);
    for (int c = 0; c < 9 && finite; c++) finite = isfinite(R[c]);
    for (int c = 0; c < 3 && finite; c++) finite = isfinite(T[c]) && isfinite(Tdot[c]) && isfinite(omega[c]);
    if (!finite)
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "BEM body: step %ld produced a non-finite state (the step was refused); check the "
                            "tractions applied to it and its time step",
                            step);

    /* 5. kept for commit (and the samples): the state stays that of the start of the step */
    memcpy(s->pR, R, sizeof R);
    memcpy(s->pT, T, sizeof T);
    memcpy(s->pTdot, Tdot, sizeof Tdot);
    memcpy(s->pomega, omega, sizeof omega);
    memcpy(s->pb, b, sizeof b);
    memcpy(s->pal, al, sizeof al);
    s->pstats = stats;
    s->phase = BEM_PHASE_SOLVED;
    if (st) *st = stats;
    return DR_OK;
}

void dr_bem_solid_commit(DrBemSolid *s, DrBemStepStats *st)
{
    assert(s->phase == BEM_PHASE_SOLVED && "dr_bem_solid_commit: no successful solve since predict");
    const DrBemMatrices *m = s->m;
    int n = s->n;
    long step = s->step + 1;
    memcpy(s->u, s->s_u, sizeof(double) * (size_t)n);
    memcpy(s->R, s->pR, sizeof s->R);
    memcpy(s->T, s->pT, sizeof s->T);
    memcpy(s->Tdot, s->pTdot, sizeof s->Tdot);
    memcpy(s->omega, s->pomega, sizeof s->omega);
    int sl = slot(s, step); /* this step's entry of the history window */
    dr_bem_layout_to_coeff(&m->layout, s->dense, s->u, s->ut_hist + (size_t)sl * n, s->s_coeff);
    dr_bem_layout_to_coeff(&m->layout, s->dense, s->s_p, s->pt_hist + (size_t)sl * n, s->s_coeff);
    memcpy(s->b_hist + 3 * sl, s->pb, sizeof s->pb);
    memcpy(s->al_hist + 3 * sl, s->pal, sizeof s->pal);
    s->step = step;
    s->phase = BEM_PHASE_NONE;
    if (st) *st = s->pstats;
}

DrStatus dr_bem_solid_step(DrBemSolid *s, const double *traction, DrBemStepStats *st, DrError *err)
{
    DR_TRY(dr_bem_solid_predict(s, err));
    DR_TRY(dr_bem_solid_solve(s, traction, NULL, st, err));
    dr_bem_solid_commit(s, st);
    return DR_OK;
}

/* V = R (ref + u) + T for a frame and displacement. */
static void world_positions(const DrBemSolid *s, const double *R, const double *T, const double *u, double *V)
{
    for (int v = 0; v < s->nv; v++) {
        double y[3];
        for (int c = 0; c < 3; c++) y[c] = s->ref[3 * v + c] + u[3 * v + c];
        dr_m3a_apply(R, y, &V[3 * v]);
        for (int c = 0; c < 3; c++) V[3 * v + c] += T[c];
    }
}

void bem_solid_solved_positions(const DrBemSolid *s, double *V)
{
    assert(s->phase == BEM_PHASE_SOLVED);
    world_positions(s, s->pR, s->pT, s->s_u, V);
}

/* Vertex velocities V̇ = Ṫ + ω × R y + R u̇ (y = ref + u) of a frame, a displacement u and its rate u̇ (NULL: 0). */
static void world_velocities(const DrBemSolid *s, const double *R, const double *Tdot, const double *omega,
                             const double *u, const double *udot, double *Vd)
{
    for (int v = 0; v < s->nv; v++) {
        double y[3], Ry[3], Rud[3] = {0, 0, 0};
        for (int c = 0; c < 3; c++) y[c] = s->ref[3 * v + c] + u[3 * v + c];
        dr_m3a_apply(R, y, Ry);
        if (udot) dr_m3a_apply(R, &udot[3 * v], Rud);
        double wx[3] = {omega[1] * Ry[2] - omega[2] * Ry[1], omega[2] * Ry[0] - omega[0] * Ry[2],
                        omega[0] * Ry[1] - omega[1] * Ry[0]};
        for (int c = 0; c < 3; c++) Vd[3 * v + c] = Tdot[c] + wx[c] + Rud[c];
    }
}

DrBemSamples dr_bem_solid_samples(DrBemSolid *s)
{
    const DrBemMatrices *m = s->m;
    int n = s->n;
    double dt = m->desc.dt, *w = s->smp_w;
    world_positions(s, s->R, s->T, s->u, s->smp_x);
    /* u̇ over the step: solved (u₊ − u_n)/Δt, else (u_n − u_{n−1})/Δt with u_{n−1} from the history window (u_0 = 0;
       a window of one step holds u_n alone) */
    const double *udot = w;
    if (s->phase == BEM_PHASE_SOLVED) {
        for (int i = 0; i < n; i++) w[i] = (s->s_u[i] - s->u[i]) / dt;
        world_velocities(s, s->pR, s->pTdot, s->pomega, s->s_u, udot, s->smp_v);
    } else {
        if (s->step >= 2 && s->nmax >= 2)
            dr_bem_layout_from_coeff(&m->layout, s->dense, s->ut_hist + (size_t)slot(s, s->step - 1) * n, w,
                                     s->s_coeff);
        else
            memset(w, 0, sizeof(double) * (size_t)n);
        if (s->step >= 1 && (s->step == 1 || s->nmax >= 2))
            for (int i = 0; i < n; i++) w[i] = (s->u[i] - w[i]) / dt;
        else
            udot = NULL;
        world_velocities(s, s->R, s->Tdot, s->omega, s->u, udot, s->smp_v);
    }
    /* normals: the sum of the area vectors of a vertex's triangles, normalised */
    double *nrm = s->smp_n;
    memset(nrm, 0, sizeof(double) * (size_t)n);
    for (int t = 0; t < m->nt; t++) {
        const int *tt = &m->tri[3 * t];
        const double *a = &s->smp_x[3 * tt[0]], *b = &s->smp_x[3 * tt[1]], *c = &s->smp_x[3 * tt[2]];
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double cr[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        for (int k = 0; k < 3; k++)
            for (int q = 0; q < 3; q++) nrm[3 * tt[k] + q] += cr[q];
    }
    for (int v = 0; v < s->nv; v++) {
        double *q = &nrm[3 * v], l = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        for (int c = 0; c < 3; c++) q[c] = l > 0 ? q[c] / l : 0.0;
    }
    return (DrBemSamples){.n = s->nv, .x = s->smp_x, .v = s->smp_v, .normal = nrm, .area = m->area};
}

/* ---- readers ----------------------------------------------------------------------------------------------- */

const DrBemMatrices *dr_bem_solid_matrices(const DrBemSolid *s) { return s->m; }
long dr_bem_solid_steps(const DrBemSolid *s) { return s->step; }
const double *dr_bem_solid_displacement(const DrBemSolid *s) { return s->u; }
const double *dr_bem_solid_reference(const DrBemSolid *s) { return s->ref; }

void dr_bem_solid_pose(const DrBemSolid *s, double R[9], double T[3])
{
    memcpy(R, s->R, sizeof s->R);
    memcpy(T, s->T, sizeof s->T);
}

void dr_bem_solid_frame_velocity(const DrBemSolid *s, double v[3], double w[3])
{
    memcpy(v, s->Tdot, sizeof s->Tdot);
    memcpy(w, s->omega, sizeof s->omega);
}

void dr_bem_solid_positions(const DrBemSolid *s, double *V) { world_positions(s, s->R, s->T, s->u, V); }

void dr_bem_solid_diagnostics(const DrBemSolid *s, DrBemSolidDiag *out)
{
    const DrBemMatrices *m = s->m;
    double mass = m->body.mass, Iw[9], tmp[9], Lw[3];
    dr_m3a_mul(s->R, m->body.inertia, tmp);
    dr_m3a_mul_nt(tmp, s->R, Iw);
    dr_m3a_apply(Iw, s->omega, Lw);
    double v2 = 0, gT = 0;
    for (int c = 0; c < 3; c++) {
        out->momentum[c] = mass * s->Tdot[c];
        out->angular_momentum[c] = Lw[c];
        v2 += s->Tdot[c] * s->Tdot[c];
        gT += s->d.gravity[c] * s->T[c];
    }
    out->kinetic = 0.5 * mass * v2 + 0.5 * (s->omega[0] * Lw[0] + s->omega[1] * Lw[1] + s->omega[2] * Lw[2]);
    out->potential = -mass * gT;
    double vol = 0, umax = 0;
    for (int t = 0; t < m->nt; t++) {
        const int *tt = &m->tri[3 * t];
        double p[3][3];
        for (int k = 0; k < 3; k++)
            for (int c = 0; c < 3; c++) p[k][c] = s->ref[3 * tt[k] + c] + s->u[3 * tt[k] + c];
        vol += (p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1]) - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0]) +
                p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0])) /
               6.0;
    }
    for (int v = 0; v < s->nv; v++) {
        const double *uv = &s->u[3 * v];
        umax = fmax(umax, sqrt(uv[0] * uv[0] + uv[1] * uv[1] + uv[2] * uv[2]));
    }
    out->volume = vol;
    out->max_displacement = umax;
}

/* ---- checkpoint -------------------------------------------------------------------------------------------- */

size_t dr_bem_solid_state_size(const DrBemSolid *s)
{
    return (size_t)s->n * (1 + 2 * (size_t)s->nmax) + 6 * (size_t)s->nmax + 18 + 1;
}

void dr_bem_solid_state_get(const DrBemSolid *s, double *st)
{
    size_t n = (size_t)s->n, nh = (size_t)s->nmax;
    memcpy(st, s->u, sizeof(double) * n);
    st += n;
    memcpy(st, s->ut_hist, sizeof(double) * nh * n);
    st += nh * n;
    memcpy(st, s->pt_hist, sizeof(double) * nh * n);
    st += nh * n;
    memcpy(st, s->b_hist, sizeof(double) * nh * 3);
    st += nh * 3;
    memcpy(st, s->al_hist, sizeof(double) * nh * 3);
    st += nh * 3;
    memcpy(st, s->R, sizeof s->R);
    memcpy(st + 9, s->T, sizeof s->T);
    memcpy(st + 12, s->Tdot, sizeof s->Tdot);
    memcpy(st + 15, s->omega, sizeof s->omega);
    st[18] = (double)s->step;
}

DrStatus dr_bem_solid_state_set(DrBemSolid *s, const double *st, size_t size, DrError *err)
{
    if (size != dr_bem_solid_state_size(s))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "BEM body: the checkpoint holds %zu state values where this body needs %zu (another mesh "
                            "or history length); bake again without --resume",
                            size, dr_bem_solid_state_size(s));
    size_t n = (size_t)s->n, nh = (size_t)s->nmax;
    memcpy(s->u, st, sizeof(double) * n);
    st += n;
    memcpy(s->ut_hist, st, sizeof(double) * nh * n);
    st += nh * n;
    memcpy(s->pt_hist, st, sizeof(double) * nh * n);
    st += nh * n;
    memcpy(s->b_hist, st, sizeof(double) * nh * 3);
    st += nh * 3;
    memcpy(s->al_hist, st, sizeof(double) * nh * 3);
    st += nh * 3;
    memcpy(s->R, st, sizeof s->R);
    memcpy(s->T, st + 9, sizeof s->T);
    memcpy(s->Tdot, st + 12, sizeof s->Tdot);
    memcpy(s->omega, st + 15, sizeof s->omega);
    s->step = (long)st[18];
    s->hz_step = 0;
    s->phase = BEM_PHASE_NONE; /* a prediction of the old state is dropped */
    if (s->group) bem_group_work_drop(s->group);
    return DR_OK;
}
