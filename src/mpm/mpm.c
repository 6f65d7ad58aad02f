/* The MPM solver ([APIC] §3–4): particle storage, one step (P2G, grid update, boundary conditions, G2P,
 * F update), the implicit solves of §4.1–4.2, CFL (§4.3), sampling and diagnostics.
 *
 * Grid update in one form for the three integrators. With u_i the grid displacement at which forces are
 * evaluated and Δv_i = ṽ_i − v_i:
 *   symplectic Euler  u = 0                      (forces at x^n and F^n, λ = 0 of eqs. 27–30)
 *   midpoint          u = Δt/2 v + Δt/4 Δv       (§4.1: x^n + ½(x̃ − x^n), λ = ½)
 *   backward Euler    u = Δt v + Δt Δv           (x̃ itself)
 * and m_i Δv_i = Δt f_i(u). The implicit ones are the minimisation of
 *   E(Δv) = Σ_i c m_i ‖Δv_i‖²/2 + Φ(u(Δv)),  u = α v + β Δv,  c = β/Δt
 * (midpoint α = Δt/2, β = Δt/4, c = 1/4: the m/8 of §4.1; backward Euler α = β = Δt, c = 1). [APIC] prints
 * E_be with Φ(x + Δt v + Δt² Δv); its gradient would then be mΔv − Δt² f, which is not backward Euler, so
 * the Δt² is read as Δt. Φ = Σ_p V_p Ψ(F_p(u)) + anchors + gravity (−Σ m_i g·u_i).
 * ∇E = c M r with the velocity-like residual r = Δv − Δt M⁻¹ f(u); the Hessian is c M A₂ with
 * A₂ = I + βΔt M⁻¹ K (K = −∂f/∂u, ζ = −βΔt in the paper's notation). Each Newton step solves A₂ δ = −r by
 * CG in the mass inner product (dr_pcg_solve's DrDotFn hook): A₂ is self-adjoint there and every CG
 * vector is velocity-like, so an early CG stop keeps Σ m Δv = Δt Σ f (§4.2). A backtracking line search
 * on E accepts the step; a configuration where Ψ is undefined (Neo-Hookean J ≤ 0) has E = +∞ and is
 * rejected.
 *
 * Deformation gradient at u: F_p(u) = (I + G_p + q G_p²) F_p^n, G_p = Σ_i u_i ∇w_ipᵀ. q = 0 is eq. (28)
 * with eq. (27). q = 1/(2λ) (λ = ½ midpoint, 1 backward Euler) is the same F^{n+λ} built from eqs.
 * (109)–(111), so the implicit energy, forces and F update use one rule for f_update_order = 2:
 *   P : dF = Q : dG + q (Q Gᵀ + Gᵀ Q) : dG,   Q = P F^nᵀ,
 * hence the force f_i = Σ_p M_p ∇w_ip with M_p = −V_p (Q + q(Q Gᵀ + Gᵀ Q)) (eq. 34 for q = 0), applied
 * through dr_node_scatter_gradient, and its differential (eqs. 35–36) likewise with
 *   δM_p = −V_p (δQ + q(δQ Gᵀ + Gᵀ δQ + Q δGᵀ + δGᵀ Q)),  δQ = dP(F_p; δF_p) F^nᵀ,
 *   δF_p = (δG + q(δG G + G δG)) F^n,  δG from dr_node_gather_gradient.
 *
 * Boundary conditions. Box walls constrain components of whole nodes (slip: the normal component of nodes
 * on or beyond the wall plane; no-slip: all of it). They are a fixed linear projection Π, applied to v
 * after P2G and kept on ṽ by projecting the Newton residual and every CG vector, so ṽ = Π ṽ exactly and
 * the grid motion Δt(λ v + (1 − λ) ṽ) that G2P uses is the one the solve saw. Π is per node and
 * orthogonal, hence self-adjoint in the mass inner product, and Π A₂ Π stays a CG operator. Colliders
 * (one-sided, possibly moving) act as in mpm.h: on v after P2G and on ṽ after the solve.
 * FLIP sees the projection of v as part of the grid change: its particles get Σ w (Π v − v) too.
 *
 * Phases (mpm.h): dr_mpm_predict is 1–2 of the step, dr_mpm_solve 3 and dr_mpm_commit 4. A solve reads only
 * what the prediction wrote: it releases contacts in con, which the next solve copies from con0 again, and
 * it overwrites every scratch vector before reading it. External point forces enter the grid update like
 * gravity, as a force with the potential −Σ_i f_i·u_i, or, with a velocity derivative D, through the
 * energy of `external` and the operator term −Δt M⁻¹ Wᵀ D W of A₂. Newton then starts from their impulse
 * Δt M⁻¹ f, so its corrections carry no momentum and the ledger holds however early CG or Newton stop.
 *
 * Determinism: per-particle loops run through dr_parallel_for and write disjoint entries; every sum over
 * particles or nodes is sequential in index order (the solve's vectors hold 3 entries per active node,
 * small next to the particle work), and the transfer functions are thread-count independent. */
#include "mpm/mpm.h"

#include "linalg/linalg.h"

#include <float.h>
#include <stdlib.h>
#include <string.h>

/* Particles per parallel chunk: a stress evaluation or differential costs ~1 µs, so below ~2k particles a
   parallel region (a few µs idle, far more on a loaded machine) costs more than it saves. */
#define GRAIN 2048

struct DrMpm {
    DrMpmDesc d;
    int dim, pad;
    DrNodeGrid *grid;
    DrNodeBins *bins;
    long bins_cap;
    /* particles */
    long n, cap;
    double *x, *v, *C, *F, *mass, *vol0, *mu, *lam, *ak, *at;
    unsigned char *model;
    int *body;
    bool anchors;
    /* per-particle scratch */
    double *G, *Fu, *Q, *dG, *dM, *px, *pf, *bx, *bv, *bC, *bF;
    DrMpmPolar *pol;    /* Fu's polar parts (fixed corotated), set with Fu: every CG product of the iterate reuses them */
    double *psi;
    double *pvol;       /* samples: current volume V₀ det F^n (n) */
    double *sv;         /* samples: solved grid velocity at the particles (3n) */
    double *xf, *xs;    /* external force per particle and solved velocity offset ṽ_p − v_p (3n each) */
    /* bodies */
    int nbodies;
    long *body_start;
    DrMpmMaterial *mats;
    /* colliders */
    int ncol;
    DrMpmCollider *cols;
    /* grid scratch (3·nnodes) */
    double *vn, *v0, *vnew, *uf, *ff, *tf;
    double *fe, *fv;    /* external force on the nodes; node velocities v0 + Δv for the drag gather */
    unsigned char *fix; /* per node: bit a set = component a fixed by a wall */
    unsigned char *con; /* per node, this step: CON_NONE, CON_NORMAL (cnrm) or CON_FULL, from colliders */
    unsigned char *con0; /* con as the prediction recorded it (a solve releases contacts in con only) */
    double *cnrm;       /* per node (3): contact normal, orthogonal to the wall-fixed axes, unit length */
    double *cinfo;      /* per node (4): friction coefficient and velocity of the collider in contact */
    double *cvel;       /* per node (3): surface velocity of the last collider the node met in this step */
    unsigned char *touch; /* per node: it met a collider in this step (cvel is set) */
    /* compact solve vectors, 3 per active node */
    long *act;
    long nact;
    double *mact, *dv, *res, *del, *tmp, *cgw;
    /* the open step (dr_mpm_predict … dr_mpm_commit) */
    int phase;          /* PHASE_NONE, PHASE_PREDICTED or PHASE_SOLVED */
    double h;           /* its step, s */
    bool projected;     /* the wall and collider projection changed the P2G velocity */
    bool sv_valid;      /* sv holds the last solve's velocities */
};

enum { PHASE_NONE = 0, PHASE_PREDICTED = 1, PHASE_SOLVED = 2 };

static const char *integrator_name(DrMpmIntegrator i)
{
    return i == DR_MPM_SYMPLECTIC_EULER ? "symplectic Euler" : (i == DR_MPM_MIDPOINT ? "midpoint" : "backward Euler");
}

void dr_mpm_desc_default(DrMpmDesc *d)
{
    memset(d, 0, sizeof *d);
    d->dim = 3;
    d->lo = dr_v3(0, 0, 0);
    d->hi = dr_v3(1, 1, 1);
    d->dx = 1.0 / 32.0;
    d->kernel = DR_KERNEL_QUADRATIC;
    d->scheme = DR_TRANSFER_APIC;
    d->flip_blend = 0.0;
    d->integrator = DR_MPM_MIDPOINT;
    d->f_update_order = 1;
    d->gravity = dr_v3(0, 0, 0);
    for (int f = 0; f < 6; f++) d->wall[f] = DR_MPM_WALL_SLIP;
    d->cfl = 1.0;
    d->newton_tolerance = 1e-10;
    d->newton_max_iterations = 50;
    d->cg_tolerance = 1e-10;
    d->cg_max_iterations = 1000;
}

/* ---- creation and storage ----------------------------------------------------------------- */

DrStatus dr_mpm_create(const DrMpmDesc *desc, DrMpm **out, DrError *err)
{
    assert(desc && out);
    *out = NULL;
    const DrMpmDesc *d = desc;
    if (d->dim != 2 && d->dim != 3)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: dim = %d must be 2 or 3", d->dim);
    if (!(d->dx > 0.0) || !isfinite(d->dx))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: dx = %g must be positive and finite", d->dx);
    for (int a = 0; a < d->dim; a++) {
        double lo = dr_v3_get(d->lo, a), hi = dr_v3_get(d->hi, a);
        if (!isfinite(lo) || !isfinite(hi) || !(hi > lo))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "mpm: box axis %d is [%g, %g]; give finite bounds with hi > lo", a, lo, hi);
        if ((hi - lo) / d->dx > 4096.0)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "mpm: box axis %d spans %.0f cells (more than 4096); raise dx", a, (hi - lo) / d->dx);
    }
    if (d->kernel != DR_KERNEL_LINEAR && d->kernel != DR_KERNEL_QUADRATIC && d->kernel != DR_KERNEL_CUBIC)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: unknown kernel %d", (int)d->kernel);
    if (d->scheme != DR_TRANSFER_APIC && d->scheme != DR_TRANSFER_FLIP && d->scheme != DR_TRANSFER_PIC &&
        d->scheme != DR_TRANSFER_RPIC)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: unknown transfer scheme %d", (int)d->scheme);
    if (d->integrator != DR_MPM_SYMPLECTIC_EULER && d->integrator != DR_MPM_MIDPOINT &&
        d->integrator != DR_MPM_BACKWARD_EULER)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: unknown integrator %d", (int)d->integrator);
    if (!(d->flip_blend >= 0.0 && d->flip_blend <= 1.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: flip_blend = %g must lie in [0, 1]", d->flip_blend);
    if (d->f_update_order != 1 && d->f_update_order != 2)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: f_update_order = %d must be 1 or 2",
                            d->f_update_order);
    if (!dr_v3_isfinite(d->gravity))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: gravity is not finite");
    if (!(d->cfl > 0.0) || !isfinite(d->cfl))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: cfl = %g must be positive", d->cfl);
    if (!(d->newton_tolerance >= 0.0) || !(d->cg_tolerance >= 0.0) || d->newton_max_iterations < 1 ||
        d->cg_max_iterations < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "mpm: tolerances (%g, %g) must be >= 0 and iteration caps (%d, %d) >= 1",
                            d->newton_tolerance, d->cg_tolerance, d->newton_max_iterations, d->cg_max_iterations);
    for (int f = 0; f < 6; f++)
        if (d->wall[f] != DR_MPM_WALL_NONE && d->wall[f] != DR_MPM_WALL_SLIP && d->wall[f] != DR_MPM_WALL_NO_SLIP)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: wall[%d] = %d is not a DrMpmWall", f,
                                (int)d->wall[f]);

    DrMpm *m = NULL;
    DR_TRY(dr_calloc(1, sizeof *m, &m, err));
    m->d = *d;
    m->dim = d->dim;
    /* the stencil reach plus two nodes: particles may drift a little past a slip wall (their positions
       interpolate the grid motion) without their stencil leaving the grid */
    m->pad = dr_kernel_reach(d->kernel) + 2;
    int n[3] = {1, 1, 1};
    for (int a = 0; a < d->dim; a++)
        n[a] = (int)ceil((dr_v3_get(d->hi, a) - dr_v3_get(d->lo, a)) / d->dx - 1e-9) + 1 + 2 * m->pad;
    DrVec3 origin = dr_v3_sub(d->lo, dr_v3(m->pad * d->dx, m->pad * d->dx, d->dim == 3 ? m->pad * d->dx : 0.0));
    DrStatus s = dr_node_grid_create(d->dim, n, d->dx, origin, d->kernel, &m->grid, err);
    if (s == DR_OK) s = dr_node_bins_create(m->grid, 1024, &m->bins, err);
    m->bins_cap = 1024;
    long nn = m->grid ? m->grid->nnodes : 0;
    double **grid_arrays[] = {&m->vn, &m->v0, &m->vnew, &m->uf, &m->ff, &m->tf, &m->fe, &m->fv,
                              &m->mact, &m->dv, &m->res, &m->del, &m->tmp};
    for (size_t k = 0; s == DR_OK && k < sizeof grid_arrays / sizeof *grid_arrays; k++)
        s = dr_calloc(3 * (size_t)nn, sizeof(double), grid_arrays[k], err);
    if (s == DR_OK) s = dr_calloc(12 * (size_t)nn, sizeof(double), &m->cgw, err);
    if (s == DR_OK) s = dr_calloc((size_t)nn, sizeof(unsigned char), &m->fix, err);
    if (s == DR_OK) s = dr_calloc((size_t)nn, sizeof(unsigned char), &m->con, err);
    if (s == DR_OK) s = dr_calloc((size_t)nn, sizeof(unsigned char), &m->con0, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)nn, sizeof(double), &m->cnrm, err);
    if (s == DR_OK) s = dr_calloc(4 * (size_t)nn, sizeof(double), &m->cinfo, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)nn, sizeof(double), &m->cvel, err);
    if (s == DR_OK) s = dr_calloc((size_t)nn, sizeof(unsigned char), &m->touch, err);
    if (s == DR_OK) s = dr_calloc((size_t)nn, sizeof(long), &m->act, err);
    if (s != DR_OK) {
        dr_mpm_destroy(&m);
        return s;
    }
    /* wall layers: nodes on or beyond each wall plane */
    for (long i = 0; i < nn; i++) {
        DrVec3 p = dr_node_position(m->grid, i);
        unsigned char fx = 0;
        for (int a = 0; a < d->dim; a++) {
            double c = dr_v3_get(p, a), eps = 1e-9 * d->dx;
            DrMpmWall lo = d->wall[2 * a], hi = d->wall[2 * a + 1];
            DrMpmWall w = c <= dr_v3_get(d->lo, a) + eps ? lo : (c >= dr_v3_get(d->hi, a) - eps ? hi : DR_MPM_WALL_NONE);
            if (w == DR_MPM_WALL_SLIP) fx |= (unsigned char)(1u << a);
            if (w == DR_MPM_WALL_NO_SLIP) fx |= 7u;
        }
        if (d->dim == 2) fx |= 4u; /* z velocity is not a degree of freedom in 2-D */
        m->fix[i] = fx;
    }
    *out = m;
    return DR_OK;
}

void dr_mpm_destroy(DrMpm **mpm)
{
    if (!mpm || !*mpm) return;
    DrMpm *m = *mpm;
    dr_node_bins_destroy(&m->bins);
    dr_node_grid_destroy(&m->grid);
    void *arrays[] = {m->x, m->v, m->C, m->F, m->mass, m->vol0, m->mu, m->lam, m->ak, m->at, m->model, m->body,
                      m->G, m->Fu, m->Q, m->dG, m->dM, m->px, m->pf, m->bx, m->bv, m->bC, m->bF, m->psi,
                      m->pol, m->pvol, m->sv, m->xf, m->xs, m->body_start, m->mats, m->cols, m->vn, m->v0, m->vnew,
                      m->uf, m->ff, m->tf, m->fe, m->fv, m->fix, m->con, m->con0, m->cnrm, m->cinfo, m->cvel, m->touch, m->act,
                      m->mact, m->dv, m->res, m->del, m->tmp, m->cgw};
    for (size_t k = 0; k < sizeof arrays / sizeof *arrays; k++) free(arrays[k]);
    free(m);
    *mpm = NULL;
}

static DrStatus reserve(DrMpm *m, long need, DrError *err)
{
    if (need <= m->cap) return DR_OK;
    long cap = m->cap > 0 ? m->cap : 256;
    while (cap < need) cap *= 2;
    struct { void *p; size_t per; } arr[] = {
        {&m->x, 3 * sizeof(double)},  {&m->v, 3 * sizeof(double)},  {&m->C, 9 * sizeof(double)},
        {&m->F, 9 * sizeof(double)},  {&m->mass, sizeof(double)},   {&m->vol0, sizeof(double)},
        {&m->mu, sizeof(double)},     {&m->lam, sizeof(double)},    {&m->ak, sizeof(double)},
        {&m->at, 3 * sizeof(double)}, {&m->model, 1},               {&m->body, sizeof(int)},
        {&m->G, 9 * sizeof(double)},  {&m->Fu, 9 * sizeof(double)}, {&m->Q, 9 * sizeof(double)},
        {&m->dG, 9 * sizeof(double)}, {&m->dM, 9 * sizeof(double)}, {&m->px, 3 * sizeof(double)},
        {&m->pf, 3 * sizeof(double)}, {&m->bx, 3 * sizeof(double)}, {&m->bv, 3 * sizeof(double)},
        {&m->bC, 9 * sizeof(double)}, {&m->bF, 9 * sizeof(double)}, {&m->psi, sizeof(double)},
        {&m->pvol, sizeof(double)},   {&m->sv, 3 * sizeof(double)}, {&m->xf, 3 * sizeof(double)},
        {&m->xs, 3 * sizeof(double)}, {&m->pol, sizeof(DrMpmPolar)},
    };
    for (size_t k = 0; k < sizeof arr / sizeof *arr; k++) DR_TRY(dr_realloc((size_t)cap, arr[k].per, arr[k].p, err));
    /* anchors of particles added later are "none" */
    memset(m->ak + m->cap, 0, (size_t)(cap - m->cap) * sizeof(double));
    memset(m->at + 3 * m->cap, 0, (size_t)(cap - m->cap) * 3 * sizeof(double));
    m->cap = cap;
    if (cap > m->bins_cap) {
        DrNodeBins *nb = NULL;
        DR_TRY(dr_node_bins_create(m->grid, cap, &nb, err));
        dr_node_bins_destroy(&m->bins);
        m->bins = nb;
        m->bins_cap = cap;
    }
    return DR_OK;
}

static bool inside_box(const DrMpm *m, const double *x)
{
    for (int a = 0; a < m->dim; a++)
        if (!(x[a] >= dr_v3_get(m->d.lo, a) && x[a] <= dr_v3_get(m->d.hi, a))) return false;
    return true;
}

static bool affine_scheme(const DrMpm *m)
{
    return m->d.scheme == DR_TRANSFER_APIC || m->d.scheme == DR_TRANSFER_RPIC;
}

DrStatus dr_mpm_add_particles(DrMpm *mpm, long n, const double *x, const double *v, const double *vol,
                              const double *C0, const DrMpmMaterial *mat, int *body, DrError *err)
{
    assert(mpm && mat);
    DrMpm *m = mpm;
    m->phase = PHASE_NONE;
    if (n < 0 || (n > 0 && (!x || !v || !vol)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: %ld particles with missing arrays", n);
    if (mat->model != DR_MPM_NEOHOOKEAN && mat->model != DR_MPM_FIXED_COROTATED)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: unknown material model %d", (int)mat->model);
    if (!(mat->density > 0.0) || !isfinite(mat->density) || !(mat->youngs >= 0.0) || !isfinite(mat->youngs) ||
        !(mat->poisson >= 0.0 && mat->poisson < 0.5))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "mpm: material density %g, Young's modulus %g, Poisson ratio %g: need density > 0, "
                            "E >= 0 and 0 <= nu < 0.5", mat->density, mat->youngs, mat->poisson);
    if (C0)
        for (int k = 0; k < 9; k++)
            if (!isfinite(C0[k])) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: C0[%d] is not finite", k);
    for (long p = 0; p < n; p++) {
        bool fin = isfinite(vol[p]) && vol[p] > 0.0;
        for (int a = 0; a < 3; a++) fin = fin && isfinite(x[3 * p + a]) && isfinite(v[3 * p + a]);
        if (!fin)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "mpm: particle %ld has a non-finite position or velocity or a volume <= 0", p);
        if (!inside_box(m, x + 3 * p))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "mpm: particle %ld at (%g, %g, %g) lies outside the simulation box; enlarge the box "
                                "or move the body", p, x[3 * p], x[3 * p + 1], x[3 * p + 2]);
    }
    DR_TRY(reserve(m, m->n + n, err));
    DR_TRY(dr_realloc((size_t)m->nbodies + 2, sizeof(long), &m->body_start, err));
    DR_TRY(dr_realloc((size_t)m->nbodies + 1, sizeof(DrMpmMaterial), &m->mats, err));
    double mu, lam;
    dr_mpm_lame(mat, &mu, &lam);
    int b = m->nbodies;
    for (long k = 0; k < n; k++) {
        long p = m->n + k;
        for (int a = 0; a < 3; a++) {
            m->x[3 * p + a] = x[3 * k + a];
            m->v[3 * p + a] = (a == 2 && m->dim == 2) ? 0.0 : v[3 * k + a];
        }
        for (int q = 0; q < 9; q++) {
            double c = (C0 && affine_scheme(m)) ? C0[q] : 0.0;
            if (m->dim == 2 && (q % 3 == 2 || q >= 6)) c = 0.0;
            m->C[9 * p + q] = c;
            m->F[9 * p + q] = (q % 4 == 0) ? 1.0 : 0.0;
        }
        if (m->d.scheme == DR_TRANSFER_RPIC) {
            double *c = m->C + 9 * p; /* RPIC keeps the skew part only (§2.1) */
            for (int i = 0; i < 3; i++)
                for (int j = i + 1; j < 3; j++) {
                    double s = 0.5 * (c[3 * i + j] - c[3 * j + i]);
                    c[3 * i + j] = s, c[3 * j + i] = -s;
                }
            c[0] = c[4] = c[8] = 0.0;
        }
        m->vol0[p] = vol[k];
        m->mass[p] = mat->density * vol[k];
        m->mu[p] = mu, m->lam[p] = lam;
        m->model[p] = (unsigned char)mat->model;
        m->body[p] = b;
    }
    m->body_start[b] = m->n;
    m->n += n;
    m->body_start[b + 1] = m->n;
    m->mats[b] = *mat;
    m->nbodies++;
    if (body) *body = b;
    return DR_OK;
}

DrStatus dr_mpm_sample_body(DrMpm *mpm, DrMpmInsideFn inside, void *ctx, DrVec3 box_lo, DrVec3 box_hi,
                            int per_cell, DrVec3 v0, DrVec3 omega, DrVec3 centre, const DrMpmMaterial *mat,
                            int *body, long *count, DrError *err)
{
    assert(mpm && inside && mat);
    DrMpm *m = mpm;
    if (per_cell < 1 || per_cell > 16)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: per_cell = %d must lie in [1, 16]", per_cell);
    if (!dr_v3_isfinite(box_lo) || !dr_v3_isfinite(box_hi) || !dr_v3_isfinite(v0) || !dr_v3_isfinite(omega) ||
        !dr_v3_isfinite(centre))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: sample_body got a non-finite box or velocity");
    double h = m->d.dx / per_cell;
    long j0[3] = {0, 0, 0}, j1[3] = {0, 0, 0};
    for (int a = 0; a < m->dim; a++) {
        double lo = dr_v3_get(m->d.lo, a);
        j0[a] = (long)ceil((dr_v3_get(box_lo, a) - lo) / h - 0.5);
        j1[a] = (long)floor((dr_v3_get(box_hi, a) - lo) / h - 0.5);
        if (j1[a] - j0[a] > 100000)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: sample_body box is too large for the spacing");
    }
    long cnt = 0;
    double *x = NULL, *v = NULL, *vol = NULL;
    for (int pass = 0; pass < 2; pass++) {
        long k = 0;
        for (long jz = j0[2]; jz <= j1[2]; jz++)
            for (long jy = j0[1]; jy <= j1[1]; jy++)
                for (long jx = j0[0]; jx <= j1[0]; jx++) {
                    long jj[3] = {jx, jy, jz};
                    double p[3];
                    for (int a = 0; a < 3; a++)
                        p[a] = a < m->dim ? dr_v3_get(m->d.lo, a) + (jj[a] + 0.5) * h : dr_v3_get(centre, a);
                    DrVec3 pv = dr_v3(p[0], p[1], p[2]);
                    if (!inside(pv, ctx)) continue;
                    if (pass == 1) {
                        DrVec3 vel = dr_v3_add(v0, dr_v3_cross(omega, dr_v3_sub(pv, centre)));
                        for (int a = 0; a < 3; a++) x[3 * k + a] = p[a], v[3 * k + a] = dr_v3_get(vel, a);
                        vol[k] = pow(h, m->dim);
                    }
                    k++;
                }
        if (pass == 0) {
            cnt = k;
            DrStatus s = dr_calloc((size_t)(cnt > 0 ? cnt : 1), 3 * sizeof(double), &x, err);
            if (s == DR_OK) s = dr_calloc((size_t)(cnt > 0 ? cnt : 1), 3 * sizeof(double), &v, err);
            if (s == DR_OK) s = dr_calloc((size_t)(cnt > 0 ? cnt : 1), sizeof(double), &vol, err);
            if (s != DR_OK) {
                free(x), free(v), free(vol);
                return s;
            }
        }
    }
    /* C0 = [ω]×: the velocity gradient of the rigid rotation v0 + ω × (x − centre) */
    double C0[9] = {0, -omega.z, omega.y, omega.z, 0, -omega.x, -omega.y, omega.x, 0};
    DrStatus s = dr_mpm_add_particles(m, cnt, x, v, vol, C0, mat, body, err);
    free(x), free(v), free(vol);
    if (count) *count = s == DR_OK ? cnt : 0;
    return s;
}

DrStatus dr_mpm_set_anchors(DrMpm *mpm, const double *k, const double *target, DrError *err)
{
    assert(mpm);
    DrMpm *m = mpm;
    m->phase = PHASE_NONE;
    if (m->n > 0 && (!k || !target))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: set_anchors needs k and target arrays");
    for (long p = 0; p < m->n; p++) {
        bool ok = isfinite(k[p]) && k[p] >= 0.0;
        for (int a = 0; a < 3; a++) ok = ok && isfinite(target[3 * p + a]);
        if (!ok)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "mpm: anchor of particle %ld has k = %g (need finite, >= 0) or a non-finite target", p,
                                k[p]);
    }
    bool any = false;
    for (long p = 0; p < m->n; p++) {
        m->ak[p] = k[p];
        for (int a = 0; a < 3; a++) m->at[3 * p + a] = target[3 * p + a];
        any = any || k[p] > 0.0;
    }
    m->anchors = any;
    return DR_OK;
}

DrStatus dr_mpm_add_collider(DrMpm *mpm, const DrMpmCollider *c, DrError *err)
{
    assert(mpm && c);
    mpm->phase = PHASE_NONE;
    if (!c->sdf || !dr_v3_isfinite(c->velocity) || !(c->friction >= 0.0) || !isfinite(c->friction))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "mpm: a collider needs an sdf, a finite velocity and friction >= 0");
    DR_TRY(dr_realloc((size_t)mpm->ncol + 1, sizeof(DrMpmCollider), &mpm->cols, err));
    mpm->cols[mpm->ncol++] = *c;
    return DR_OK;
}

DrMpmState dr_mpm_state(const DrMpm *mpm)
{
    DrMpmState s = {mpm->n, mpm->x, mpm->v, mpm->C, mpm->F, mpm->mass, mpm->vol0, mpm->body};
    return s;
}

DrStatus dr_mpm_restore(DrMpm *mpm, long n, const double *x, const double *v, const double *C, const double *F,
                        DrError *err)
{
    assert(mpm);
    mpm->phase = PHASE_NONE;
    if (n != mpm->n)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: restore of %ld particles into a solver holding %ld",
                            n, mpm->n);
    for (long i = 0; i < 3 * n; i++)
        if (!isfinite(x[i]) || !isfinite(v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: restore: particle %ld is not finite", i / 3);
    for (long i = 0; i < 9 * n; i++)
        if (!isfinite(C[i]) || !isfinite(F[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: restore: C or F of particle %ld is not finite",
                                i / 9);
    memcpy(mpm->x, x, 3 * (size_t)n * sizeof(double));
    memcpy(mpm->v, v, 3 * (size_t)n * sizeof(double));
    memcpy(mpm->C, C, 9 * (size_t)n * sizeof(double));
    memcpy(mpm->F, F, 9 * (size_t)n * sizeof(double));
    return DR_OK;
}

/* ---- diagnostics -------------------------------------------------------------------------- */

static double kernel_d(DrKernel k, double dx)
{
    double dinv = dr_kernel_dinv(k, dx);
    return dinv > 0.0 ? 1.0 / dinv : 0.0;
}

DrMpmTotals dr_mpm_totals(const DrMpm *mpm, int body)
{
    const DrMpm *m = mpm;
    DrMpmTotals t;
    memset(&t, 0, sizeof t);
    long b0 = 0, b1 = m->n;
    if (body >= 0) {
        if (body >= m->nbodies) return t;
        b0 = m->body_start[body], b1 = m->body_start[body + 1];
    }
    if (b1 <= b0) return t;
    dr_node_particle_totals(m->d.kernel, m->d.dx, b1 - b0, m->x + 3 * b0, m->v + 3 * b0, m->C + 9 * b0, m->mass + b0,
                            &t.momentum, &t.angular, &t.kinetic);
    for (long p = b0; p < b1; p++) {
        double psi = 0.0;
        if (!dr_mpm_energy_density((DrMpmModel)m->model[p], m->dim, m->mu[p], m->lam[p], m->F + 9 * p, &psi))
            psi = INFINITY;
        t.elastic += m->vol0[p] * psi;
        const double *x = m->x + 3 * p;
        t.gravity_potential -= m->mass[p] * (m->d.gravity.x * x[0] + m->d.gravity.y * x[1] + m->d.gravity.z * x[2]);
    }
    return t;
}

double dr_mpm_cfl_dt(const DrMpm *mpm)
{
    const DrMpm *m = mpm;
    double D = kernel_d(m->d.kernel, m->d.dx), worst = 0.0;
    for (long p = 0; p < m->n; p++) {
        const double *v = m->v + 3 * p, *c = m->C + 9 * p;
        double cn = 0.0;
        for (int k = 0; k < 9; k++) cn += c[k] * c[k];
        cn = sqrt(cn);
        /* B = C D; the linear kernel has no D (lagged C): bound the velocity spread over a cell by ‖C‖ Δx */
        double spread = D > 0.0 ? 6.0 * sqrt((double)m->dim) / m->d.dx * D * cn : cn * m->d.dx;
        double s = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + spread;
        if (s > worst) worst = s;
    }
    return worst > 0.0 ? m->d.cfl * m->d.dx / worst : INFINITY;
}

/* Explicit stability limit of symplectic Euler: ν Δx / c with the dilatational wave speed
   c = √((λ + 2μ)/ρ), and 2/ω for the stiffest anchor (ω² = k/m, a particle's own spring). */
static double explicit_dt(const DrMpm *m)
{
    double worst = 0.0;
    for (int b = 0; b < m->nbodies; b++) {
        double mu, lam;
        dr_mpm_lame(&m->mats[b], &mu, &lam);
        double c = sqrt((lam + 2.0 * mu) / m->mats[b].density);
        if (c > worst) worst = c;
    }
    double dt = worst > 0.0 ? m->d.cfl * m->d.dx / worst : INFINITY;
    for (long p = 0; p < m->n && m->anchors; p++)
        if (m->ak[p] > 0.0) dt = fmin(dt, m->d.cfl * 2.0 / sqrt(m->ak[p] / m->mass[p]));
    return dt;
}

/* The midpoint rule's limit for stiff, turning bodies: Δt ≤ √(4ν Δx / (c_p ‖∇v_p‖_F)) over the particles, c_p the
   dilatational wave speed √((λ+2μ)/ρ) of the particle's material and ∇v_p its velocity gradient: APIC's and RPIC's
   affine matrix C_p, or for FLIP and PIC (whose particles carry none) the gradient of the P2G grid velocity at the
   particle. Why: the grid moves its nodes on straight lines through a step, so the deformation it hands the solve
   and the F update, I + Δt∇v, is not a rotation where the body turns: it stretches the body by about (Δt‖∇v‖)², a
   strain that costs energy in proportion to the stiffness. The midpoint rule keeps energy only for quadratic
   energies; with that stretch, a stiff body's fastest modes (a period of Δx/c, far below Δt) are driven at every
   step and, undamped by the midpoint rule, grow. The number of wave crossings of a cell in a step times the rotation
   in it, Q = (cΔt/Δx)(Δt‖∇v‖), decides: measured on spheres of E = 1e8–1e10 Pa turning at 30–360°/s and landing on
   a wall, Q ≤ 4 kept the energy within 2 %, Q ≤ 8 within 17 %, and the §4.3 step alone (Q up to 150) let it grow ×8
   in four frames (tests/stress/test_mpm_stress.c). Soft bodies (cΔt/Δx of a few cells) never reach it: §4.3 already
   bounds Δt‖C‖ by about 0.4ν. Backward Euler damps those modes and symplectic Euler has its own wave limit: midpoint
   only. For FLIP and PIC this transfers the particles to the grid's scratch. */
static double rotation_dt(const DrMpm *m)
{
    if (m->d.integrator != DR_MPM_MIDPOINT || m->n == 0) return INFINITY;
    bool affine = affine_scheme(m);
    if (!affine) {
        DrError e;
        if (dr_node_bins_build(m->grid, m->n, m->x, m->bins, &e) != DR_OK) return INFINITY; /* predict reports it */
        dr_node_p2g(m->bins, m->x, m->v, NULL, m->mass, m->grid);
        dr_node_gather_gradient(m->grid, m->grid->vel, m->n, m->x, m->G);
    }
    double worst = 0.0; /* max over particles of c_p ‖∇v_p‖ */
    for (long p = 0; p < m->n; p++) {
        const double *c = (affine ? m->C : m->G) + 9 * p;
        double cn = 0.0;
        for (int k = 0; k < 9; k++) cn += c[k] * c[k];
        double rho = m->mass[p] / m->vol0[p];
        double s = sqrt((m->lam[p] + 2.0 * m->mu[p]) / rho) * sqrt(cn);
        if (s > worst) worst = s;
    }
    return worst > 0.0 ? sqrt(4.0 * m->d.cfl * m->d.dx / worst) : INFINITY;
}

/* ---- per-particle kernels ------------------------------------------------------------------- */

typedef struct Eval {
    DrMpm *m;
    double q;       /* F rule (see the banner) */
    bool ok;        /* per range: all Ψ and P defined (written only on failure, read after the loop) */
    long bad;
} Eval;

/* Fu = (I + G + qG²) F^n, ψ_p = V Ψ(Fu), Q = P(Fu) F^nᵀ and the force matrix M_p in dM. */
static void eval_range(long b, long e, void *vctx)
{
    Eval *ev = vctx;
    DrMpm *m = ev->m;
    for (long p = b; p < e; p++) {
        const double *G = m->G + 9 * p, *Fn = m->F + 9 * p;
        double N[9], G2[9];
        dr_m3a_mul(G, G, G2);
        for (int k = 0; k < 9; k++) N[k] = ((k % 4 == 0) ? 1.0 : 0.0) + G[k] + ev->q * G2[k];
        double *Fu = m->Fu + 9 * p;
        dr_m3a_mul(N, Fn, Fu);
        double psi, P[9];
        DrMpmModel model = (DrMpmModel)m->model[p];
        const DrMpmPolar *pol = NULL;
        if (model == DR_MPM_FIXED_COROTATED) dr_mpm_polar_parts(m->dim, Fu, &m->pol[p]), pol = &m->pol[p];
        if (!dr_mpm_energy_density_polar(model, m->dim, m->mu[p], m->lam[p], Fu, pol, &psi) ||
            !dr_mpm_pk1_polar(model, m->dim, m->mu[p], m->lam[p], Fu, pol, P)) {
            m->psi[p] = INFINITY;
#pragma omp critical(dr_mpm_eval_bad)
            {
                if (ev->ok || p < ev->bad) ev->bad = p;
                ev->ok = false;
            }
            continue;
        }
        m->psi[p] = m->vol0[p] * psi;
        double *Q = m->Q + 9 * p, *M = m->dM + 9 * p;
        dr_m3a_mul_nt(P, Fn, Q);
        double QGt[9], GtQ[9];
        dr_m3a_mul_nt(Q, G, QGt);
        dr_m3a_mul_tn(G, Q, GtQ);
        for (int k = 0; k < 9; k++) M[k] = -m->vol0[p] * (Q[k] + ev->q * (QGt[k] + GtQ[k]));
    }
}

/* Force differential per particle: dM from dG (δG), with G, Fu, its polar parts and Q of the current iterate. */
typedef struct DiffCtx { DrMpm *m; double q; } DiffCtx;
static void diff_range(long b, long e, void *vctx)
{
    DiffCtx *c = vctx;
    DrMpm *m = c->m;
    double q = c->q;
    for (long p = b; p < e; p++) {
        const double *G = m->G + 9 * p, *dG = m->dG + 9 * p, *Fn = m->F + 9 * p, *Q = m->Q + 9 * p;
        double dN[9], t1[9], t2[9];
        if (q != 0.0) {
            dr_m3a_mul(dG, G, t1);
            dr_m3a_mul(G, dG, t2);
            for (int k = 0; k < 9; k++) dN[k] = dG[k] + q * (t1[k] + t2[k]);
        } else {
            memcpy(dN, dG, sizeof dN);
        }
        double dF[9], dP[9];
        dr_m3a_mul(dN, Fn, dF);
        DrMpmModel model = (DrMpmModel)m->model[p];
        if (!dr_mpm_dpk1_polar(model, m->dim, m->mu[p], m->lam[p], m->Fu + 9 * p,
                               model == DR_MPM_FIXED_COROTATED ? &m->pol[p] : NULL, dF, dP))
            memset(dP, 0, sizeof dP); /* only reachable where E = +∞, which the line search never accepts */
        double dQ[9], *M = m->dM + 9 * p;
        dr_m3a_mul_nt(dP, Fn, dQ);
        /* K δu = −δf: the sign of eq. (36) flipped, so the operator is positive */
        if (q == 0.0) {
            for (int k = 0; k < 9; k++) M[k] = m->vol0[p] * dQ[k];
            continue;
        }
        double a[9], bb[9], cc[9], dd[9];
        dr_m3a_mul_nt(dQ, G, a);
        dr_m3a_mul_tn(G, dQ, bb);
        dr_m3a_mul_nt(Q, dG, cc);
        dr_m3a_mul_tn(dG, Q, dd);
        for (int k = 0; k < 9; k++) M[k] = m->vol0[p] * (dQ[k] + q * (a[k] + bb[k] + cc[k] + dd[k]));
    }
}

/* anchors: pf = −k (x_p + px − target) (force) or k·px (stiffness product), per particle */
typedef struct AnchorCtx { DrMpm *m; bool product; } AnchorCtx;
static void anchor_range(long b, long e, void *vctx)
{
    AnchorCtx *c = vctx;
    DrMpm *m = c->m;
    for (long p = b; p < e; p++)
        for (int a = 0; a < 3; a++) {
            double k = m->ak[p], d = m->px[3 * p + a];
            m->pf[3 * p + a] = c->product ? k * d : -k * (m->x[3 * p + a] + d - m->at[3 * p + a]);
        }
}

/* ---- grid helpers ---------------------------------------------------------------------------- */

enum { CON_NONE = 0, CON_NORMAL = 1, CON_FULL = 2 };

/* Π of one node: wall-fixed components to 0, then the collider contact (the normal component, or all of
   it). cnrm is orthogonal to the wall-fixed axes, so the two projections commute and Π is the orthogonal
   projection onto what both allow (self-adjoint in the mass inner product: one mass per node). */
static void project_fixed(const DrMpm *m, long i, double *u)
{
    unsigned char f = m->fix[i];
    for (int a = 0; a < 3; a++)
        if (f & (1u << a)) u[a] = 0.0;
    if (m->con[i] == CON_FULL) {
        u[0] = u[1] = u[2] = 0.0;
    } else if (m->con[i] == CON_NORMAL) {
        const double *n = m->cnrm + 3 * i;
        double d = u[0] * n[0] + u[1] * n[1] + u[2] * n[2];
        for (int a = 0; a < 3; a++) u[a] -= d * n[a];
    }
}

/* mass inner product over the active nodes (sequential: bit-identical for any thread count) */
static double mdot(const double *a, const double *b, int n, void *ctx)
{
    const DrMpm *m = ctx;
    double s = 0.0;
    for (int k = 0; k < n; k++) s += m->mact[k] * a[k] * b[k];
    return s;
}

/* A node inside a collider at the start of the step keeps its normal velocity (relative to the collider,
   after the approaching part was removed) through the solve: a constraint of Π like the walls', so the
   elastic solve sees the contact instead of having it imposed on its result afterwards, which strains
   the layer next to the contact by the whole step's approach and injects energy (a box resting on a
   plane collider gained 200 % energy in 2 s that way, 0.45 % with contacts in Π). Every node inside
   starts constrained, separating or not (leaving separating nodes free and projecting them after the
   solve injected 28 %); contact_release then lets go of those the solution pulls away. A sticky collider,
   or a second collider with another normal, fixes the node. The normal is made orthogonal to the node's
   wall-fixed axes; nothing is left of it when the walls already hold that direction. */
static void record_contact(DrMpm *m, long i, const DrMpmCollider *col, DrVec3 cv, const DrVec3 *normal)
{
    double *info = m->cinfo + 4 * i;
    info[0] = col->friction, info[1] = cv.x, info[2] = cv.y, info[3] = cv.z;
    if (!normal) {
        m->con[i] = CON_FULL;
        return;
    }
    if (m->con[i] == CON_FULL) return;
    double n[3] = {normal->x, normal->y, normal->z}, len = 0.0;
    for (int a = 0; a < 3; a++) {
        if (m->fix[i] & (1u << a)) n[a] = 0.0;
        len += n[a] * n[a];
    }
    len = sqrt(len);
    if (len < 1e-6) return;
    for (int a = 0; a < 3; a++) n[a] /= len;
    if (m->con[i] == CON_NORMAL) {
        const double *o = m->cnrm + 3 * i;
        if (fabs(o[0] * n[0] + o[1] * n[1] + o[2] * n[2]) < 1.0 - 1e-9) m->con[i] = CON_FULL;
        return;
    }
    m->con[i] = CON_NORMAL;
    memcpy(m->cnrm + 3 * i, n, sizeof n);
}

/* Collider projection of one node velocity (relative to the collider): remove the approaching normal
   component, then Coulomb friction on the tangential part, or zero it all for sticky colliders. With
   `record`, contacts become constraints of the step (record_contact). */
static bool collide_node(DrMpm *m, long node, DrVec3 xi, double *vel, bool record)
{
    bool hit = false;
    for (int c = 0; c < m->ncol; c++) {
        const DrMpmCollider *col = m->cols + c;
        DrVec3 n;
        double phi = col->sdf(xi, &n, col->ctx);
        if (!(phi <= 0.0)) continue;
        n = dr_v3_normalize(n);
        if (m->dim == 2) n = dr_v3_normalize(dr_v3(n.x, n.y, 0.0));
        DrVec3 cv = col->velocity_at ? col->velocity_at(xi, col->ctx) : col->velocity;
        if (m->dim == 2) cv.z = 0.0;
        m->touch[node] = 1;
        m->cvel[3 * node] = cv.x, m->cvel[3 * node + 1] = cv.y, m->cvel[3 * node + 2] = cv.z;
        DrVec3 vr = dr_v3_sub(dr_v3(vel[0], vel[1], vel[2]), cv);
        if (record) record_contact(m, node, col, cv, col->sticky ? NULL : &n);
        if (col->sticky) {
            vr = dr_v3(0, 0, 0);
        } else {
            double vn = dr_v3_dot(vr, n);
            if (vn >= 0.0) continue;
            DrVec3 vt = dr_v3_sub(vr, dr_v3_scale(n, vn));
            double vtn = dr_v3_norm(vt);
            if (col->friction > 0.0 && vtn > 0.0) {
                double keep = fmax(0.0, 1.0 + col->friction * vn / vtn);
                vt = dr_v3_scale(vt, keep);
            }
            vr = vt;
        }
        DrVec3 out = dr_v3_add(vr, cv);
        vel[0] = out.x, vel[1] = out.y, vel[2] = m->dim == 2 ? 0.0 : out.z;
        hit = true;
    }
    return hit;
}

/* ---- the implicit solve ---------------------------------------------------------------------- */

typedef struct Solve {
    DrMpm *m;
    double dt, alpha, beta, c, q;
    DrStatus status;
    DrError *err;
    const double *force; /* external point forces at the particles (3n) or NULL */
    const double *dfdv;  /* their velocity derivative D_p (9n) or NULL; only with force */
} Solve;

/* The external force on the nodes at Δv, into fe, and its part of E. A constant force (no D) was spread
   once by the solve (fe = Σ_p w_ip F_p) and is a potential like gravity's: −Σ_i fe_i·u_i. With D the
   force at the particles is F_p + D_p s_p, s_p = ṽ_p − v_p the solved velocity offset at the particle
   (ṽ_p = Σ_i w_ip (v0_i + Δv_i)); its potential in Δv is −β Σ_p (F_p·s_p + ½ s_p·D_p s_p) (∂/∂Δv gives
   −β times the spread force, as ∂Φ/∂Δv = −β f; D symmetric). */
static double external(Solve *s, const double *dv)
{
    DrMpm *m = s->m;
    DrNodeGrid *g = m->grid;
    double E = 0.0;
    if (!s->dfdv) {
        for (long k = 0; k < m->nact; k++) {
            const double *u = m->uf + 3 * m->act[k], *f = m->fe + 3 * m->act[k];
            E -= f[0] * u[0] + f[1] * u[1] + f[2] * u[2];
        }
        return E;
    }
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        for (int a = 0; a < 3; a++) m->fv[3 * i + a] = m->v0[3 * i + a] + dv[3 * k + a];
    }
    dr_node_gather_vector(g, m->fv, m->n, m->x, m->xs);
    for (long p = 0; p < m->n; p++) {
        double *sp = m->xs + 3 * p, *f = m->xf + 3 * p, Ds[3];
        for (int a = 0; a < 3; a++) sp[a] -= m->v[3 * p + a];
        dr_m3a_apply(s->dfdv + 9 * p, sp, Ds);
        const double *F = s->force + 3 * p;
        for (int a = 0; a < 3; a++) {
            f[a] = F[a] + Ds[a];
            E += F[a] * sp[a] + 0.5 * sp[a] * Ds[a];
        }
    }
    dr_node_scatter_vector(m->bins, m->x, m->xf, g, m->fe);
    return -s->beta * E;
}

/* Fills uf (grid displacement α v0 + β Δv on active nodes), G, Fu, ψ, Q, dM and ff (force f(u)).
   Returns E(Δv) (+∞ where Ψ is undefined), and in *bad the first such particle. */
static double evaluate(Solve *s, const double *dv, bool with_force, long *bad)
{
    DrMpm *m = s->m;
    DrNodeGrid *g = m->grid;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        for (int a = 0; a < 3; a++) m->uf[3 * i + a] = s->alpha * m->v0[3 * i + a] + s->beta * dv[3 * k + a];
    }
    dr_node_gather_gradient(g, m->uf, m->n, m->x, m->G);
    Eval ev = {m, s->q, true, -1};
    dr_parallel_for(m->n, GRAIN, eval_range, &ev);
    if (bad) *bad = ev.bad;
    if (!ev.ok) return INFINITY;
    double E = 0.0;
    for (long p = 0; p < m->n; p++) E += m->psi[p];
    if (m->anchors) {
        dr_node_gather_vector(g, m->uf, m->n, m->x, m->px);
        for (long p = 0; p < m->n; p++) {
            double d2 = 0.0;
            for (int a = 0; a < 3; a++) {
                double d = m->x[3 * p + a] + m->px[3 * p + a] - m->at[3 * p + a];
                d2 += d * d;
            }
            E += 0.5 * m->ak[p] * d2;
        }
    }
    DrVec3 gr = m->d.gravity;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        double mi = m->mact[3 * k];
        const double *u = m->uf + 3 * i, *d = dv + 3 * k;
        E += 0.5 * s->c * mi * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        E -= mi * (gr.x * u[0] + gr.y * u[1] + gr.z * u[2]);
    }
    if (s->force) E += external(s, dv);
    if (with_force) {
        dr_node_scatter_gradient(m->bins, m->x, m->dM, g, m->ff);
        if (m->anchors) {
            AnchorCtx ac = {m, false};
            dr_parallel_for(m->n, GRAIN, anchor_range, &ac);
            dr_node_scatter_vector(m->bins, m->x, m->pf, g, m->tf);
            for (long k = 0; k < m->nact; k++)
                for (int a = 0; a < 3; a++) m->ff[3 * m->act[k] + a] += m->tf[3 * m->act[k] + a];
        }
        if (s->force)
            for (long k = 0; k < m->nact; k++)
                for (int a = 0; a < 3; a++) m->ff[3 * m->act[k] + a] += m->fe[3 * m->act[k] + a];
    }
    return E;
}

/* r = Π(Δv − Δt M⁻¹ f) on the compact vector */
static void residual(Solve *s, const double *dv, double *r)
{
    DrMpm *m = s->m;
    DrVec3 gr = m->d.gravity;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        double mi = m->mact[3 * k];
        for (int a = 0; a < 3; a++)
            r[3 * k + a] = dv[3 * k + a] - s->dt * (m->ff[3 * i + a] / mi + dr_v3_get(gr, a));
        project_fixed(m, i, r + 3 * k);
    }
}

/* y = Π A₂ Π x = Π(x + βΔt M⁻¹ K Π x − Δt M⁻¹ Wᵀ D W Π x), the last term for an implicit external force
   (W the weights, D per particle) */
static void apply_a2(const double *x, double *y, void *ctx)
{
    Solve *s = ctx;
    DrMpm *m = s->m;
    DrNodeGrid *g = m->grid;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        double u[3] = {x[3 * k], x[3 * k + 1], x[3 * k + 2]};
        project_fixed(m, i, u);
        for (int a = 0; a < 3; a++) m->uf[3 * i + a] = u[a], y[3 * k + a] = u[a];
    }
    dr_node_gather_gradient(g, m->uf, m->n, m->x, m->dG);
    DiffCtx dc = {m, s->q};
    dr_parallel_for(m->n, GRAIN, diff_range, &dc);
    dr_node_scatter_gradient(m->bins, m->x, m->dM, g, m->ff);
    if (m->anchors) {
        dr_node_gather_vector(g, m->uf, m->n, m->x, m->px);
        AnchorCtx ac = {m, true};
        dr_parallel_for(m->n, GRAIN, anchor_range, &ac);
        dr_node_scatter_vector(m->bins, m->x, m->pf, g, m->tf);
        for (long k = 0; k < m->nact; k++)
            for (int a = 0; a < 3; a++) m->ff[3 * m->act[k] + a] += m->tf[3 * m->act[k] + a];
    }
    if (s->dfdv) {
        dr_node_gather_vector(g, m->uf, m->n, m->x, m->xs);
        for (long p = 0; p < m->n; p++) dr_m3a_apply(s->dfdv + 9 * p, m->xs + 3 * p, m->xf + 3 * p);
        dr_node_scatter_vector(m->bins, m->x, m->xf, g, m->fe);
    }
    double z = s->beta * s->dt;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        double mi = m->mact[3 * k];
        for (int a = 0; a < 3; a++) y[3 * k + a] += z * m->ff[3 * i + a] / mi;
        if (s->dfdv)
            for (int a = 0; a < 3; a++) y[3 * k + a] -= s->dt * m->fe[3 * i + a] / mi;
        project_fixed(m, i, y + 3 * k);
    }
}

/* Newton on E (§4.1) from Δv = 0, or with an external force from its impulse Δt M⁻¹ f (projected) so
   that every later correction has zero momentum (§4.2); leaves Δv in m->dv. */
static DrStatus newton(Solve *s, DrMpmStats *st)
{
    DrMpm *m = s->m;
    const int n3 = (int)(3 * m->nact);
    double *dv = m->dv, *r = m->res, *del = m->del, *trial = m->tmp;
    memset(dv, 0, (size_t)n3 * sizeof(double));
    if (s->force) {
        if (s->dfdv) external(s, dv); /* the force at Δv = 0 */
        for (long k = 0; k < m->nact; k++) {
            long i = m->act[k];
            for (int a = 0; a < 3; a++) dv[3 * k + a] = s->dt * m->fe[3 * i + a] / m->mact[3 * k];
            project_fixed(m, i, dv + 3 * k);
        }
    }
    long bad = -1;
    double E = evaluate(s, dv, true, &bad);
    if (!isfinite(E)) {
        /* Δv = 0 (grid moving with v for the step) already inverts a particle. Δv = −(α/β) v makes u = 0,
           the configuration of F^n, which is admissible whenever the state is: start there instead.
           v is wall-projected, so this start satisfies the constraints too. */
        for (long k = 0; k < m->nact; k++)
            for (int a = 0; a < 3; a++) dv[3 * k + a] = -(s->alpha / s->beta) * m->v0[3 * m->act[k] + a];
        E = evaluate(s, dv, true, &bad);
    }
    if (!isfinite(E)) {
        /* the start itself (α v of the midpoint) inverts a particle: no descent direction is defined */
        const double *x = m->x + 3 * bad;
        return dr_error_set(s->err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "mpm: particle %ld at (%g, %g, %g) has an undefined energy (Neo-Hookean J <= 0) in its "
                            "current state (F^n), so the %s solve cannot start; reduce the time step", bad, x[0], x[1], x[2],
                            integrator_name(m->d.integrator));
    }
    residual(s, dv, r);
    double r0 = sqrt(mdot(r, r, n3, m)), rn = r0;
    double vscale = 0.0;
    for (long k = 0; k < m->nact; k++)
        for (int a = 0; a < 3; a++) vscale += m->mact[3 * k] * m->v0[3 * m->act[k] + a] * m->v0[3 * m->act[k] + a];
    vscale = sqrt(vscale) + r0;
    /* the round-off of E: Ψ sums terms of size μ‖F‖², μ, λ that cancel to a much smaller Ψ near rest, so
       E is known to ε times Σ V (μ + λ)(3 + ‖F‖²) (plus |E|), not to ε|E| */
    double escale = 0.0;
    for (long p = 0; p < m->n; p++) {
        double f2 = 0.0;
        for (int k = 0; k < 9; k++) f2 += m->Fu[9 * p + k] * m->Fu[9 * p + k];
        escale += m->vol0[p] * (m->mu[p] + m->lam[p]) * (3.0 + f2);
    }
    DrPcgDesc pd;
    dr_pcg_desc_default(&pd);
    pd.rel_tol = m->d.cg_tolerance;
    pd.max_iter = m->d.cg_max_iterations;
    pd.dot = mdot;
    pd.dot_ctx = m;
    DrLinearOp op = {n3, apply_a2, s};
    bool converged = r0 == 0.0 || r0 <= 64.0 * DBL_EPSILON * vscale;
    int it = 0;
    while (!converged && it < m->d.newton_max_iterations) {
        it++;
        /* 1. Newton direction: A₂ δ = −r in the mass inner product */
        for (int k = 0; k < n3; k++) trial[k] = -r[k];
        memset(del, 0, (size_t)n3 * sizeof(double));
        /* inexact Newton: CG to η_k = 1e-2·‖r_k‖/‖r_0‖ (relative to ‖r_k‖), at most 1e-2 and at least
           cg_tolerance. η_k ∝ ‖r_k‖ keeps Newton's quadratic convergence, while the early, far-off
           iterations do not pay for digits the next linearisation discards. */
        pd.rel_tol = fmax(m->d.cg_tolerance, 1e-2 * fmin(1.0, rn / r0));
        DrPcgStats ps;
        DrError cgerr;
        DrStatus cs = dr_pcg_solve(&op, NULL, trial, del, &pd, m->cgw, &ps, &cgerr);
        st->cg_iterations += ps.iterations;
        if (cs < 0) {
            /* an indefinite A₂ (a material past its stability, e.g. fixed corotated far inverted): fall back
               to the steepest-descent direction −r, still velocity-like, and let the line search decide */
            for (int k = 0; k < n3; k++) del[k] = -r[k];
        }
        double slope = s->c * mdot(r, del, n3, m); /* ∇E·δ = c ⟨r, δ⟩_M */
        if (!(slope < 0.0)) {
            for (int k = 0; k < n3; k++) del[k] = -r[k];
            slope = -s->c * rn * rn;
        }
        /* 2. backtracking line search on E (Armijo), rejecting undefined energies. Near convergence the
           decrease Newton predicts (−slope) falls to the round-off of E itself and Armijo's test turns
           into noise; there the step is judged by the residual instead (it still must decrease). */
        double t = 1.0, Et = INFINITY, rt = INFINITY;
        double slack = 64.0 * DBL_EPSILON * (fabs(E) + escale);
        bool accepted = false;
        for (int ls = 0; ls < 40 && !accepted; ls++) {
            for (int k = 0; k < n3; k++) trial[k] = dv[k] + t * del[k];
            Et = evaluate(s, trial, true, &bad);
            if (isfinite(Et)) {
                if (Et <= E + 1e-4 * t * slope + slack) accepted = true;
                if (!accepted && -slope <= 1e3 * slack) {
                    residual(s, trial, r);
                    rt = sqrt(mdot(r, r, n3, m));
                    accepted = rt < rn;
                }
            }
            if (!accepted) t *= 0.5;
        }
        if (!accepted) {
            /* E is finite at Δv, so a short enough step is finite too: no step of 40 halvings being
               accepted means no descent is left at round-off. Stop with the current iterate (the
               convergence test below decides between DR_OK and the warning). */
            evaluate(s, dv, true, NULL);
            residual(s, dv, r);
            break;
        }
        double step2 = 0.0;
        for (int k = 0; k < n3; k++) step2 += m->mact[k] * (t * del[k]) * (t * del[k]);
        memcpy(dv, trial, (size_t)n3 * sizeof(double));
        E = Et;
        residual(s, dv, r);
        rn = sqrt(mdot(r, r, n3, m));
        if (rn <= m->d.newton_tolerance * r0) converged = true;
        /* a step below round-off of the velocities cannot improve the residual any further */
        if (sqrt(step2) <= 16.0 * DBL_EPSILON * vscale) converged = true;
    }
    st->newton_iterations += it;
    st->newton_residual = r0 > 0.0 ? rn / r0 : 0.0;
    if (!converged) {
        dr_error_set(s->err, DR_WARN_NOT_CONVERGED, NULL, 0, 0,
                     "mpm: %s Newton stopped after %d iterations at relative residual %g (tolerance %g); the step "
                     "is kept. Raise newton_max_iterations or reduce the time step",
                     integrator_name(m->d.integrator), it, rn / (r0 > 0 ? r0 : 1), m->d.newton_tolerance);
        return DR_WARN_NOT_CONVERGED;
    }
    return DR_OK;
}

/* ---- contacts after the solve ------------------------------------------------------------------ */

/* u = v0 + Δt(M⁻¹ f + g) on the active nodes, f the force (with anchors) of the last evaluation, which
   Newton leaves at its solution. */
static void unconstrained_update(const Solve *s, double *u)
{
    const DrMpm *m = s->m;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        for (int a = 0; a < 3; a++)
            u[3 * i + a] = m->v0[3 * i + a] + s->dt * (m->ff[3 * i + a] / m->mact[3 * k] + dr_v3_get(m->d.gravity, a));
    }
}

/* n·(u − v0): the normal velocity change a normal contact absorbs from the unconstrained update u
   (negative: the node is pushed into the collider). */
static double contact_push(const DrMpm *m, long i, const double *u)
{
    const double *n = m->cnrm + 3 * i, *v0 = m->v0 + 3 * i, *ui = u + 3 * i;
    return n[0] * (ui[0] - v0[0]) + n[1] * (ui[1] - v0[1]) + n[2] * (ui[2] - v0[2]);
}

/* Lets go of the normal contacts the update u pulls away from the collider; true if any. */
static bool contact_release(DrMpm *m, const double *u)
{
    bool any = false;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        if (m->con[i] == CON_NORMAL && contact_push(m, i, u) > 0.0) {
            m->con[i] = CON_NONE;
            any = true;
        }
    }
    return any;
}

/* Coulomb friction on the normal contacts: the tangential velocity relative to the collider loses up to
   μ times the normal velocity change the contact absorbed (the normal impulse per unit mass). */
static void contact_friction(const DrMpm *m, const double *u, double *vnew)
{
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        const double *info = m->cinfo + 4 * i;
        if (m->con[i] != CON_NORMAL || !(info[0] > 0.0)) continue;
        double push = contact_push(m, i, u);
        if (!(push < 0.0)) continue;
        const double *n = m->cnrm + 3 * i;
        double vr[3], vn = 0.0, vt[3], vtn = 0.0;
        for (int a = 0; a < 3; a++) vr[a] = vnew[3 * i + a] - info[1 + a], vn += vr[a] * n[a];
        for (int a = 0; a < 3; a++) vt[a] = vr[a] - vn * n[a], vtn += vt[a] * vt[a];
        vtn = sqrt(vtn);
        if (vtn == 0.0) continue;
        double keep = fmax(0.0, 1.0 + info[0] * push / vtn);
        for (int a = 0; a < 3; a++) vnew[3 * i + a] = info[1 + a] + vn * n[a] + keep * vt[a];
        if (m->dim == 2) vnew[3 * i + 2] = 0.0;
    }
}

/* The work the colliders did on the grid in the solved step, J: Σ over the nodes that met one of J_i · V_i, V_i that
   collider's surface velocity and J_i = m_i (ṽ_i − v_i) − Δt (f_i + m_i g) the impulse the constraints gave the node
   (its velocity change beyond what its forces f_i, taken where the solve took them, and gravity gave). A static
   collider (V = 0) and a wall do no work; the projections only take energy away from the motion relative to a
   collider, so the bodies' energy may grow by at most this in a step (the energy watch of src/world). */
static double collider_work(const DrMpm *m, double dt, bool explicit_step, bool external)
{
    double W = 0.0;
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        if (!m->touch[i]) continue;
        double mi = m->mact[3 * k], Ji[3];
        for (int a = 0; a < 3; a++) {
            double f = m->ff[3 * i + a];
            if (explicit_step && m->anchors) f += m->tf[3 * i + a];
            if (explicit_step && external) f += m->fe[3 * i + a];
            Ji[a] = mi * (m->vnew[3 * i + a] - m->vn[3 * i + a]) - dt * (f + mi * dr_v3_get(m->d.gravity, a));
        }
        W += Ji[0] * m->cvel[3 * i] + Ji[1] * m->cvel[3 * i + 1] + Ji[2] * m->cvel[3 * i + 2];
    }
    return W;
}

/* ---- one step -------------------------------------------------------------------------------- */

typedef struct FCtx { DrMpm *m; double dt; bool order2; } FCtx;
static void fupdate_range(long b, long e, void *vctx)
{
    FCtx *c = vctx;
    DrMpm *m = c->m;
    for (long p = b; p < e; p++) {
        double H[9], N[9], H2[9];
        for (int k = 0; k < 9; k++) H[k] = c->dt * m->G[9 * p + k];
        dr_m3a_mul(H, H, H2);
        for (int k = 0; k < 9; k++) N[k] = ((k % 4 == 0) ? 1.0 : 0.0) + H[k] + (c->order2 ? 0.5 * H2[k] : 0.0);
        if (m->dim == 2) N[2] = N[5] = N[6] = N[7] = 0.0, N[8] = 1.0;
        dr_m3a_mul(N, m->F + 9 * p, m->F + 9 * p);
    }
}

static long first_nonfinite_particle(const DrMpm *m)
{
    for (long p = 0; p < m->n; p++) {
        bool ok = true;
        for (int a = 0; a < 3; a++) ok = ok && isfinite(m->x[3 * p + a]) && isfinite(m->v[3 * p + a]);
        for (int k = 0; k < 9; k++) ok = ok && isfinite(m->C[9 * p + k]) && isfinite(m->F[9 * p + k]);
        if (!ok) return p;
    }
    return -1;
}

static void restore_backup(DrMpm *m)
{
    memcpy(m->x, m->bx, 3 * (size_t)m->n * sizeof(double));
    memcpy(m->v, m->bv, 3 * (size_t)m->n * sizeof(double));
    memcpy(m->C, m->bC, 9 * (size_t)m->n * sizeof(double));
    memcpy(m->F, m->bF, 9 * (size_t)m->n * sizeof(double));
}

DrStatus dr_mpm_predict(DrMpm *mpm, double h, DrError *err)
{
    assert(mpm);
    DrMpm *m = mpm;
    m->phase = PHASE_NONE;
    m->sv_valid = false;
    if (!(h > 0.0) || !isfinite(h))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: time step %g must be positive and finite", h);
    m->h = h;
    if (m->n == 0) {
        m->phase = PHASE_PREDICTED;
        return DR_OK;
    }
    DrNodeGrid *g = m->grid;
    const long nn = g->nnodes;

    /* 1. bin and P2G (eqs. 24–26) */
    DrError berr;
    if (dr_node_bins_build(g, m->n, m->x, m->bins, &berr) != DR_OK)
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "mpm: a particle left the grid (%s); keep bodies inside the box (walls) or enlarge it",
                            berr.message);
    dr_node_p2g(m->bins, m->x, m->v, affine_scheme(m) ? m->C : NULL, m->mass, g);
    memcpy(m->vn, g->vel, 3 * (size_t)nn * sizeof(double));
    memcpy(m->v0, g->vel, 3 * (size_t)nn * sizeof(double));
    m->nact = 0;
    for (long i = 0; i < nn; i++)
        if (g->mass[i] > 0.0) {
            long k = m->nact++;
            m->act[k] = i;
            for (int a = 0; a < 3; a++) m->mact[3 * k + a] = g->mass[i];
        }
    /* 2. boundary conditions on v (walls: projection Π; colliders: approaching part) */
    bool projected = false;
    memset(m->con, CON_NONE, (size_t)nn);
    for (long k = 0; k < m->nact; k++) {
        long i = m->act[k];
        double *u = m->v0 + 3 * i;
        m->touch[i] = 0;
        project_fixed(m, i, u);
        if (m->ncol) collide_node(m, i, dr_node_position(g, i), u, true);
        projected = projected || u[0] != m->vn[3 * i] || u[1] != m->vn[3 * i + 1] || u[2] != m->vn[3 * i + 2];
    }
    m->projected = projected;
    memcpy(m->con0, m->con, (size_t)nn);
    for (long p = 0; p < m->n; p++) m->pvol[p] = m->vol0[p] * dr_m3a_det(m->F + 9 * p);
    m->phase = PHASE_PREDICTED;
    return DR_OK;
}

DrMpmSamples dr_mpm_samples(const DrMpm *mpm)
{
    assert(mpm && mpm->phase != PHASE_NONE);
    const DrMpm *m = mpm;
    DrMpmSamples s = {m->n, m->x, m->v, m->mass, m->pvol, m->sv_valid ? m->sv : NULL};
    return s;
}

/* 3. the grid update of the predicted step: ṽ in m->vnew. Adds its iterations and seconds to st. */
static DrStatus grid_solve(DrMpm *m, const double *force, const double *dfdv, DrMpmStats *st, DrError *err)
{
    assert(m->phase != PHASE_NONE);
    m->phase = PHASE_PREDICTED;
    m->sv_valid = false;
    if (m->n == 0) {
        m->phase = PHASE_SOLVED;
        return DR_OK;
    }
    DrNodeGrid *g = m->grid;
    const long nn = g->nnodes;
    const double dt = m->h;
    double t1 = dr_time_now();
    memcpy(m->con, m->con0, (size_t)nn);
    Solve s = {m, dt, 0, 0, 0, 0, DR_OK, err, force, dfdv};
    DrStatus status = DR_OK;
    memset(m->uf, 0, 3 * (size_t)nn * sizeof(double));
    if (force && !dfdv) dr_node_scatter_vector(m->bins, m->x, force, g, m->fe);
    if (m->d.integrator == DR_MPM_SYMPLECTIC_EULER) {
        /* forces at F^n (u = 0) and anchors at x^n */
        memset(m->G, 0, 9 * (size_t)m->n * sizeof(double));
        Eval ev = {m, 0.0, true, -1};
        dr_parallel_for(m->n, GRAIN, eval_range, &ev);
        if (!ev.ok) {
            const double *x = m->x + 3 * ev.bad;
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "mpm: particle %ld at (%g, %g, %g) has an undefined stress (Neo-Hookean J <= 0); the "
                                "explicit step was too large for this material: reduce the time step", ev.bad, x[0],
                                x[1], x[2]);
        }
        dr_node_scatter_gradient(m->bins, m->x, m->dM, g, m->ff);
        if (m->anchors) {
            memset(m->px, 0, 3 * (size_t)m->n * sizeof(double));
            AnchorCtx ac = {m, false};
            dr_parallel_for(m->n, GRAIN, anchor_range, &ac);
            dr_node_scatter_vector(m->bins, m->x, m->pf, g, m->tf);
        }
        memset(m->vnew, 0, 3 * (size_t)nn * sizeof(double));
        for (long k = 0; k < m->nact; k++) {
            long i = m->act[k];
            double mi = m->mact[3 * k];
            for (int a = 0; a < 3; a++) {
                double f = m->ff[3 * i + a] + (m->anchors ? m->tf[3 * i + a] : 0.0);
                if (force) f += m->fe[3 * i + a];
                m->vnew[3 * i + a] = m->v0[3 * i + a] + dt * (f / mi + dr_v3_get(m->d.gravity, a));
            }
        }
        /* contacts: those the step pushes into the collider hold (Π) with friction; the others let go */
        if (m->ncol) {
            memcpy(m->uf, m->vnew, 3 * (size_t)nn * sizeof(double));
            contact_release(m, m->uf);
        }
        for (long k = 0; k < m->nact; k++) project_fixed(m, m->act[k], m->vnew + 3 * m->act[k]);
        if (m->ncol) contact_friction(m, m->uf, m->vnew);
    } else {
        bool mid = m->d.integrator == DR_MPM_MIDPOINT;
        s.alpha = mid ? 0.5 * dt : dt;
        s.beta = mid ? 0.25 * dt : dt;
        s.c = s.beta / dt;
        s.q = m->d.f_update_order == 2 ? (mid ? 1.0 : 0.5) : 0.0;
        status = newton(&s, st);
        if (status < 0) return status;
        if (m->ncol) {
            /* one active-set pass: contacts that would hold the body back from leaving the collider (the
               unconstrained update v0 + Δt(M⁻¹f + g) of the solution moves away from it) are let go and the
               step is solved again without them */
            unconstrained_update(&s, m->uf);
            if (contact_release(m, m->uf)) {
                status = newton(&s, st);
                if (status < 0) return status;
                unconstrained_update(&s, m->uf);
            }
        }
        memset(m->vnew, 0, 3 * (size_t)nn * sizeof(double));
        for (long k = 0; k < m->nact; k++) {
            long i = m->act[k];
            for (int a = 0; a < 3; a++) m->vnew[3 * i + a] = m->v0[3 * i + a] + m->dv[3 * k + a];
            project_fixed(m, i, m->vnew + 3 * i);
        }
        if (m->ncol) contact_friction(m, m->uf, m->vnew);
    }
    if (m->ncol) {
        for (long k = 0; k < m->nact; k++)
            collide_node(m, m->act[k], dr_node_position(g, m->act[k]), m->vnew + 3 * m->act[k], false);
        st->collider_work += collider_work(m, dt, m->d.integrator == DR_MPM_SYMPLECTIC_EULER, force != NULL);
    }
    st->seconds_solve += dr_time_now() - t1;
    m->phase = PHASE_SOLVED;
    return status;
}

DrStatus dr_mpm_solve(DrMpm *mpm, const double *force, const double *dforce_dv, DrMpmStats *stats, DrError *err)
{
    assert(mpm && mpm->phase != PHASE_NONE);
    DrMpm *m = mpm;
    DrMpmStats local;
    DrMpmStats *st = stats ? stats : &local;
    memset(st, 0, sizeof *st);
    m->phase = PHASE_PREDICTED;
    m->sv_valid = false;
    if (dforce_dv && !force)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "mpm: dforce_dv without force; pass the force at the samples' velocity (zeros if none)");
    if (dforce_dv && m->d.integrator == DR_MPM_SYMPLECTIC_EULER)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "mpm: symplectic Euler is explicit and takes no force derivative (dforce_dv); pass NULL, or "
                            "use the midpoint or backward Euler integrator for an implicit drag");
    for (long i = 0; force && i < 3 * m->n; i++)
        if (!isfinite(force[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: external force on particle %ld is not finite",
                                i / 3);
    for (long p = 0; dforce_dv && p < m->n; p++) {
        const double *D = dforce_dv + 9 * p;
        double big = 0.0, asym = 0.0;
        for (int k = 0; k < 9; k++) {
            if (!isfinite(D[k]))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "mpm: dforce_dv of particle %ld is not finite", p);
            big = fmax(big, fabs(D[k]));
            asym = fmax(asym, fabs(D[k] - D[3 * (k % 3) + k / 3]));
        }
        /* the implicit solve is a minimisation (§4.1): a non-symmetric D has no energy */
        if (asym > 1e-9 * big)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "mpm: dforce_dv of particle %ld is not symmetric (|D - D^T| = %g of %g); give the "
                                "symmetric velocity derivative of the force (a drag law's R C R^T)", p, asym, big);
    }
    DrStatus s = grid_solve(m, force, dforce_dv, st, err);
    if (s >= 0 && m->n > 0) {
        dr_node_gather_vector(m->grid, m->vnew, m->n, m->x, m->sv);
        m->sv_valid = true;
    }
    return s;
}

DrStatus dr_mpm_commit(DrMpm *mpm, DrError *err)
{
    assert(mpm && mpm->phase == PHASE_SOLVED);
    DrMpm *m = mpm;
    m->phase = PHASE_NONE;
    m->sv_valid = false;
    if (m->n == 0) return DR_OK;
    DrNodeGrid *g = m->grid;
    const long nn = g->nnodes;
    const double dt = m->h;

    /* 4. G2P (eqs. 37–39) and the F update (eq. 40 or 109–111) */
    memcpy(m->bx, m->x, 3 * (size_t)m->n * sizeof(double));
    memcpy(m->bv, m->v, 3 * (size_t)m->n * sizeof(double));
    memcpy(m->bC, m->C, 9 * (size_t)m->n * sizeof(double));
    memcpy(m->bF, m->F, 9 * (size_t)m->n * sizeof(double));
    bool flip_fix = m->d.scheme == DR_TRANSFER_FLIP && m->projected;
    if (flip_fix) {
        for (long i = 0; i < 3 * nn; i++) m->tf[i] = m->v0[i] - m->vn[i];
        dr_node_gather_vector(g, m->tf, m->n, m->x, m->pf);
    }
    double lambda = m->d.integrator == DR_MPM_MIDPOINT ? 0.5 : 0.0;
    dr_node_g2p(g, m->vnew, m->v0, lambda, dt, m->d.scheme, m->d.flip_blend, m->n, m->x, m->v, m->C, m->G);
    if (flip_fix)
        for (long i = 0; i < 3 * m->n; i++) m->v[i] += (1.0 - m->d.flip_blend) * m->pf[i];
    if (m->dim == 2)
        for (long p = 0; p < m->n; p++) m->v[3 * p + 2] = 0.0;
    FCtx fc = {m, dt, m->d.f_update_order == 2};
    dr_parallel_for(m->n, GRAIN, fupdate_range, &fc);
    long bad = first_nonfinite_particle(m);
    if (bad >= 0) {
        restore_backup(m);
        const double *x = m->x + 3 * bad;
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "mpm: particle %ld (at (%g, %g, %g) before the step) became non-finite; the state is "
                            "left as it was before the step: reduce the time step", bad, x[0], x[1], x[2]);
    }
    return DR_OK;
}

DrStatus dr_mpm_step(DrMpm *mpm, double dt, DrMpmStats *stats, DrError *err)
{
    assert(mpm);
    DrMpmStats local;
    DrMpmStats *st = stats ? stats : &local;
    memset(st, 0, sizeof *st);
    st->substeps = 1;
    double t0 = dr_time_now();
    DR_TRY(dr_mpm_predict(mpm, dt, err));
    double t1 = dr_time_now();
    st->seconds_transfer += t1 - t0;
    DrStatus status = grid_solve(mpm, NULL, NULL, st, err);
    if (status < 0) {
        mpm->phase = PHASE_NONE;
        return status;
    }
    double t2 = dr_time_now();
    DrStatus c = dr_mpm_commit(mpm, err);
    st->seconds_transfer += dr_time_now() - t2;
    return c < 0 ? c : status;
}

double dr_mpm_stable_dt(const DrMpm *mpm)
{
    /* §4.3 with the speed gravity adds over the step: Δt (S + |g| Δt) <= ν Δx, S the §4.3 speed bound (a
       body at rest under gravity would otherwise be given the whole duration in one step) */
    double nudx = mpm->d.cfl * mpm->d.dx, cfl = dr_mpm_cfl_dt(mpm);
    double S = isfinite(cfl) ? nudx / cfl : 0.0, gn = dr_v3_norm(mpm->d.gravity);
    double lim = (S > 0.0 || gn > 0.0) ? 2.0 * nudx / (S + sqrt(S * S + 4.0 * gn * nudx)) : INFINITY;
    if (mpm->d.integrator == DR_MPM_SYMPLECTIC_EULER) lim = fmin(lim, explicit_dt(mpm));
    return fmin(lim, rotation_dt(mpm));
}

DrStatus dr_mpm_advance(DrMpm *mpm, double duration, int max_substeps, DrMpmStats *stats, DrError *err)
{
    assert(mpm);
    DrMpmStats local, acc;
    memset(&acc, 0, sizeof acc);
    if (!(duration >= 0.0) || !isfinite(duration) || max_substeps < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "mpm: advance by %g s with at most %d substeps: need duration >= 0 and >= 1 substep",
                            duration, max_substeps);
    double left = duration;
    DrStatus worst = DR_OK;
    int done = 0;
    while (left > 0.0 && done < max_substeps) {
        double lim = dr_mpm_stable_dt(mpm);
        double need = isfinite(lim) ? ceil(left / lim - 1e-9) : 1.0;
        int budget = max_substeps - done;
        double k = need < 1.0 ? 1.0 : (need > budget ? budget : need);
        double dt = (k <= 1.0) ? left : left / k;
        DrStatus s = dr_mpm_step(mpm, dt, &local, err);
        acc.newton_iterations += local.newton_iterations;
        acc.cg_iterations += local.cg_iterations;
        acc.newton_residual = local.newton_residual;
        acc.seconds_transfer += local.seconds_transfer;
        acc.seconds_solve += local.seconds_solve;
        acc.collider_work += local.collider_work;
        acc.substeps++;
        done++;
        if (s < 0) {
            if (stats) *stats = acc;
            return s;
        }
        if (s > worst) worst = s;
        left = (k <= 1.0) ? 0.0 : left - dt;
    }
    if (stats) *stats = acc;
    return worst;
}
