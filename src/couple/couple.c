/* drench couple: the laws and the coupled loop (couple.h). */
#include "couple/couple.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void dr_drag_law_default(DrDragLaw *law)
{
    law->model = DR_DRAG_SCALES;
    law->reference = DR_DRAG_STOKES;
    law->global = 1.0;
    law->normal = 1.0;
    law->tangent = 0.5;
    law->nonlinear = 1.0;
    law->degree = 1.0;
    law->lift = 0.0;
    law->buoyancy = true;
}

void dr_couple_desc_default(DrCoupleDesc *d)
{
    d->iterations = 3;
    d->tolerance = 1e-2;
    d->position_derivative = true;
    d->explicit_reaction = false;
}

/* Dimensionless permeability k̃_l (k = k̃ D²) of the Drummond–Tahir fits, γ clamped into [1e-4, 0.5]. */
static double drummond_tahir(int l, double gamma)
{
    double g = gamma < 1e-4 ? 1e-4 : (gamma > 0.5 ? 0.5 : gamma);
    if (l == 1) return (-log(g) - 1.476 + 2.0 * g - 0.5 * g * g) / (16.0 * g);
    return (-log(g) - 1.476 + 2.0 * g - 1.774 * g * g + 4.078 * g * g * g) / (32.0 * g);
}

/* 1/k_l of the law (couple.h). */
static double inverse_permeability(const DrDragLaw *law, int l, const DrDragSite *site)
{
    double xi = law->global * (l == 0 ? law->normal : law->tangent);
    if (site->face) return xi;
    if (law->model == DR_DRAG_PERMEABILITY) {
        double g = site->gamma < 1e-4 ? 1e-4 : (site->gamma > 0.5 ? 0.5 : site->gamma);
        return xi / (g * drummond_tahir(l, site->gamma));
    }
    if (law->reference == DR_DRAG_LITERAL) return xi * 1e-4;
    double lam = site->slender > 1.0 ? site->slender : 1.0;
    return xi * 16.0 / (log(2.0 * lam) + 0.5);
}

double dr_drag_coefficient(const DrDragLaw *law, int l, double rho, double mu, const DrDragSite *site, double speed)
{
    double ik = inverse_permeability(law, l, site);
    if (!(ik > 0.0)) return 0.0;
    double c = ik;
    if (law->nonlinear > 0.0 && speed > 0.0) {
        double g = site->gamma < 0.0 ? 0.0 : (site->gamma > 0.5 ? 0.5 : site->gamma);
        double re = rho * site->diameter * speed / mu;
        c += law->nonlinear * 1.75 / sqrt(150.0 / ik) / pow(1.0 - g, 1.5) * pow(re, law->degree);
    }
    return c;
}

void dr_drag_tensor(const DrDragLaw *law, double rho, double mu, const DrDragSite *site, DrVec3 dv, double K[9])
{
    double speed = dr_v3_norm(dv);
    double s = mu * site->volume / (site->diameter * site->diameter);
    double cp = s * dr_drag_coefficient(law, 0, rho, mu, site, speed);
    double ct = s * dr_drag_coefficient(law, 1, rho, mu, site, speed);
    double t[3] = {site->tangent.x, site->tangent.y, site->tangent.z};
    /* a rod: C_∥ along its tangent, C_⊥ across; a face: C_⊥ along its normal, C_∥ in its plane */
    double across = site->face ? ct : cp, along = site->face ? cp : ct;
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++) K[3 * r + q] = (r == q ? across : 0.0) + (along - across) * t[r] * t[q];
}

DrVec3 dr_drag_lift(const DrDragLaw *law, const DrDragSite *site, const double K[9], DrVec3 dv)
{
    double d2 = dr_v3_dot(dv, dv);
    if (!(law->lift > 0.0) || !(d2 > 0.0)) return dr_v3(0, 0, 0);
    DrVec3 f = dr_v3(-(K[0] * dv.x + K[1] * dv.y + K[2] * dv.z), -(K[3] * dv.x + K[4] * dv.y + K[5] * dv.z),
                     -(K[6] * dv.x + K[7] * dv.y + K[8] * dv.z));
    DrVec3 e = site->tangent;
    DrVec3 Q = dr_v3_cross(e, dr_v3_cross(e, f));
    DrVec3 L = dr_v3_sub(Q, dr_v3_scale(dv, dr_v3_dot(Q, dv) / d2));
    return dr_v3_scale(L, -law->lift);
}

/* ---- the loop ------------------------------------------------------------------------------------------------------ */

/* One element's trilinear stencil on face component a's lattice. */
typedef struct Stencil { long f[8]; double w[8]; } Stencil;

typedef struct Element {
    const DrDragLaw *law;
    DrDragSite site;
    double mass;
    int solid, index;        /* owner and its element index */
    bool active;             /* inside the fluid (every component has coupled faces) */
    bool held;               /* its motion is prescribed */
    bool implicit;           /* the last projection holds its drag implicit (held, or heavier than its fluid) */
    Stencil st[3];           /* raw trilinear weights */
    double wn[3][8];         /* weights over the coupled faces, normalised (0 elsewhere) */
} Element;

struct DrCouple {
    int cap;                 /* elements */
    Element *el;
    double *x, *v, *vprev, *u, *uprev, *p, *pprev, *gradp, *force, *dfdv, *kf, *dv, *g, *pts, *psamp, *pwet;
    double *carried;         /* per element: the liquid it carries, m³ (DrCoupleSamples.carried) */
    double *imp;             /* 3 per element: what it receives outside the laws, N·s (DrCoupleSamples.impulse) */
    int ncap_faces[3];
    DrFaceCoupling fc;       /* the extra coupling handed to the fluid (arrays sized to the grid) */
    double *phi[3], *num[3], *den[3];
    DrVec3 ledger_solid, ledger_fluid;
    double changes[64];      /* the last step's, per iteration */
    int nchanges;
    double residual;
};

DrStatus dr_couple_create(DrCouple **out, DrError *err)
{
    *out = NULL;
    DrCouple *c = NULL;
    DR_TRY(dr_calloc(1, sizeof *c, &c, err));
    *out = c;
    return DR_OK;
}

void dr_couple_destroy(DrCouple **cp)
{
    if (!cp || !*cp) return;
    DrCouple *c = *cp;
    free(c->el);
    double **arr[] = {&c->x, &c->v, &c->vprev, &c->u, &c->uprev, &c->p, &c->pprev, &c->gradp, &c->force, &c->dfdv,
                      &c->kf, &c->dv, &c->g, &c->pts, &c->psamp, &c->pwet, &c->carried, &c->imp};
    for (size_t i = 0; i < sizeof arr / sizeof arr[0]; i++) free(*arr[i]);
    for (int a = 0; a < 3; a++) {
        free(c->fc.open[a]); free(c->fc.velocity[a]); free(c->fc.impulse[a]); free(c->fc.drag[a]);
        free(c->phi[a]); free(c->num[a]); free(c->den[a]);
    }
    free(c);
    *cp = NULL;
}

int dr_couple_last_changes(const DrCouple *c, double *out, int max)
{
    for (int k = 0; k < c->nchanges && k < max && k < 64; k++) out[k] = c->changes[k];
    return c->nchanges;
}
double dr_couple_last_residual(const DrCouple *c) { return c->residual; }

void dr_couple_last_ledger(const DrCouple *c, DrVec3 *solid, DrVec3 *fluid)
{
    *solid = c->ledger_solid;
    *fluid = c->ledger_fluid;
}

static DrStatus reserve(DrCouple *c, int n, const DrMacGrid *g, DrError *err)
{
    if (n > c->cap) {
        int cap = n + n / 4 + 16;
        Element *el = realloc(c->el, (size_t)cap * sizeof *el);
        if (!el) return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "couple: out of memory for %d elements.", cap);
        c->el = el;
        struct { double **p; int w; } arr[] = {{&c->x, 3}, {&c->v, 3}, {&c->vprev, 3}, {&c->u, 3}, {&c->uprev, 3},
                                               {&c->p, 1}, {&c->pprev, 1}, {&c->gradp, 3}, {&c->force, 3},
                                               {&c->dfdv, 9}, {&c->kf, 9}, {&c->dv, 3}, {&c->g, 3}, {&c->pts, 21}, {&c->psamp, 7}, {&c->pwet, 7},
                                               {&c->carried, 1}, {&c->imp, 3}};
        for (size_t i = 0; i < sizeof arr / sizeof arr[0]; i++) {
            double *q = realloc(*arr[i].p, (size_t)cap * arr[i].w * sizeof(double));
            if (!q) return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "couple: out of memory for %d elements.", cap);
            *arr[i].p = q;
        }
        c->cap = cap;
    }
    for (int a = 0; a < 3; a++) {
        if (c->ncap_faces[a] >= g->nfaces[a]) { c->fc.nfaces[a] = g->nfaces[a]; continue; }
        double **arr[] = {&c->fc.open[a], &c->fc.velocity[a], &c->fc.impulse[a], &c->fc.drag[a], &c->phi[a],
                          &c->num[a], &c->den[a]};
        for (size_t i = 0; i < sizeof arr / sizeof arr[0]; i++) {
            free(*arr[i]);
            *arr[i] = NULL;
            DR_TRY(dr_calloc((size_t)g->nfaces[a], sizeof(double), arr[i], err));
        }
        c->ncap_faces[a] = (int)g->nfaces[a];
        c->fc.nfaces[a] = g->nfaces[a];
    }
    return DR_OK;
}

/* The cell of face component a's lattice holding x (its lowest corner b, the fractions fr within it), clamped into the
   lattice; per axis, whether x lies outside it (then fr is 0 or 1). False when the lattice has a single node along an
   axis (b 0 and fr 0 there: every weight on it; no gradient). */
static bool lattice_cell(const DrMacGrid *g, int a, DrVec3 x, int b[3], double fr[3], bool outside[3])
{
    double s[3] = {(x.x - g->origin.x) / g->dx - dr_mac_face_offset(a, 0),
                   (x.y - g->origin.y) / g->dx - dr_mac_face_offset(a, 1),
                   (x.z - g->origin.z) / g->dx - dr_mac_face_offset(a, 2)};
    bool full = true;
    for (int d = 0; d < 3; d++) {
        int hi = g->fdim[a][d] - 2;
        double fb = floor(s[d]);
        outside[d] = fb < 0.0 || fb > hi;
        if (hi < 0) { b[d] = 0; fr[d] = 0.0; full = false; } /* one node along d: all weight on it */
        else if (fb < 0.0) { b[d] = 0; fr[d] = 0.0; }
        else if (fb > hi) { b[d] = hi; fr[d] = 1.0; }
        else { b[d] = (int)fb; fr[d] = s[d] - fb; }
    }
    return full;
}

static Stencil face_stencil(const DrMacGrid *g, int a, DrVec3 x)
{
    Stencil st;
    int b[3];
    double fr[3];
    bool out[3];
    (void)lattice_cell(g, a, x, b, fr, out);
    int q = 0;
    for (int dk = 0; dk < 2; dk++)
        for (int dj = 0; dj < 2; dj++)
            for (int di = 0; di < 2; di++, q++) {
                int i = b[0] + di, j = b[1] + dj, k = b[2] + dk;
                if (i >= g->fdim[a][0]) i = g->fdim[a][0] - 1;
                if (j >= g->fdim[a][1]) j = g->fdim[a][1] - 1;
                if (k >= g->fdim[a][2]) k = g->fdim[a][2] - 1;
                st.f[q] = dr_mac_face_index(g, a, i, j, k);
                st.w[q] = (di ? fr[0] : 1.0 - fr[0]) * (dj ? fr[1] : 1.0 - fr[1]) * (dk ? fr[2] : 1.0 - fr[2]);
            }
    return st;
}

/* The derivative of the trilinear interpolation of component a along axis d at x, per metre (0 outside the
   lattice along d). */
static double face_gradient(const DrMacGrid *g, int a, int d, DrVec3 x)
{
    int b[3];
    double fr[3];
    bool out[3];
    if (!lattice_cell(g, a, x, b, fr, out) || out[d]) return 0.0;
    double sum = 0.0;
    for (int dk = 0; dk < 2; dk++)
        for (int dj = 0; dj < 2; dj++)
            for (int di = 0; di < 2; di++) {
                int o[3] = {di, dj, dk};
                double w = 1.0;
                for (int e = 0; e < 3; e++) w *= e == d ? (o[e] ? 1.0 : -1.0) : (o[e] ? fr[e] : 1.0 - fr[e]);
                sum += w * g->f[a][dr_mac_face_index(g, a, b[0] + di, b[1] + dj, b[2] + dk)];
            }
    return sum / g->dx;
}

/* D ← the negative semidefinite part of sym(D). */
static void nsd_part(double D[9])
{
    double S[9];
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++) S[3 * r + q] = 0.5 * (D[3 * r + q] + D[3 * q + r]);
    double w[3], V[9];
    dr_m3a_sym_eigen(S, w, V);
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++) {
            double s = 0.0;
            for (int e = 0; e < 3; e++)
                if (w[e] < 0.0) s += V[3 * r + e] * w[e] * V[3 * q + e];
            D[3 * r + q] = s;
        }
    for (int r = 0; r < 3; r++)
        for (int q = r + 1; q < 3; q++) D[3 * q + r] = D[3 * r + q];
}

double dr_couple_stable_dt(const DrCoupleFluid *fluid, const DrCoupleSolid *solids, int nsolids)
{
    double h = INFINITY;
    for (int s = 0; s < nsolids; s++) {
        bool any = false;
        for (int l = 0; l < solids[s].nlaws; l++) any = any || solids[s].laws[l].lift > 0.0;
        if (!any) continue;
        DrCoupleSamples sm = solids[s].samples(solids[s].ctx);
        for (int i = 0; i < sm.n; i++) {
            if (sm.held && sm.held[i]) continue;
            const DrDragLaw *law = &solids[s].laws[sm.law ? sm.law[i] : 0];
            if (!(law->lift > 0.0)) continue;
            DrDragSite site = {dr_v3(sm.tangent[3 * i], sm.tangent[3 * i + 1], sm.tangent[3 * i + 2]), sm.diameter[i],
                               sm.volume[i], sm.slender[i], 0.0, sm.face && sm.face[i]};
            /* the lift is largest through the coefficient across the direction e (a rod's C_⊥, a face's C_∥) */
            double cp = fluid->viscosity * site.volume / (site.diameter * site.diameter) *
                        dr_drag_coefficient(law, site.face ? 1 : 0, fluid->density, fluid->viscosity, &site, 0.0);
            double l = 0.5 * law->lift * cp;
            if (l > 0.0 && sm.mass[i] / l < h) h = sm.mass[i] / l;
        }
    }
    return h;
}

/* Gathers every solid's elements into c->el / c->x / c->v (the order: solids in order, their elements in order). */
static DrStatus gather(DrCouple *c, const DrCoupleFluid *fluid, const DrCoupleSolid *solids, int nsolids, int *nout,
                       DrError *err)
{
    int n = 0;
    for (int s = 0; s < nsolids; s++) n += solids[s].samples(solids[s].ctx).n;
    DR_TRY(reserve(c, n, fluid->grid, err));
    int at = 0;
    for (int s = 0; s < nsolids; s++) {
        DrCoupleSamples sm = solids[s].samples(solids[s].ctx);
        for (int i = 0; i < sm.n; i++, at++) {
            Element *e = &c->el[at];
            int li = sm.law ? sm.law[i] : 0;
            if (li < 0 || li >= solids[s].nlaws)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "couple: element %d of solid %d names drag law %d "
                                    "of %d.", i, s, li, solids[s].nlaws);
            e->law = &solids[s].laws[li];
            e->site.tangent = dr_v3(sm.tangent[3 * i], sm.tangent[3 * i + 1], sm.tangent[3 * i + 2]);
            e->site.diameter = sm.diameter[i];
            e->site.volume = sm.volume[i];
            e->site.slender = sm.slender[i];
            e->site.gamma = 0.0;
            e->site.face = sm.face && sm.face[i];
            e->mass = sm.mass[i];
            e->solid = s;
            e->index = i;
            e->active = true; /* a held element drags the fluid too, its reaction going to what holds it */
            e->held = sm.held && sm.held[i];
            e->implicit = false;
            c->carried[at] = sm.carried ? sm.carried[i] : 0.0;
            for (int d = 0; d < 3; d++) {
                c->x[3 * at + d] = sm.x[3 * i + d];
                c->v[3 * at + d] = sm.v[3 * i + d];
                c->imp[3 * at + d] = sm.impulse ? sm.impulse[3 * i + d] : 0.0;
            }
        }
    }
    *nout = n;
    return DR_OK;
}

static void read_velocities(DrCouple *c, const DrCoupleSolid *solids, int nsolids)
{
    int at = 0;
    for (int s = 0; s < nsolids; s++) {
        DrCoupleSamples sm = solids[s].samples(solids[s].ctx);
        memcpy(c->v + 3 * at, sm.v, (size_t)sm.n * 3 * sizeof(double));
        at += sm.n;
    }
}

/* The solid fraction φ_s and the solids' velocity on the faces: fc.open = 1 − min(φ_s, ½) (weights w V, V the
   element's volume with the liquid it carries), fc.velocity the mean of the elements' velocities (weights w V),
   fc.impulse and fc.drag zero. Sets each element's γ. */
static void rasterise(DrCouple *c, const DrMacGrid *g, int n)
{
    double cell = g->dx * g->dx * g->dx;
    for (int a = 0; a < 3; a++) {
        memset(c->phi[a], 0, (size_t)g->nfaces[a] * sizeof(double));
        memset(c->num[a], 0, (size_t)g->nfaces[a] * sizeof(double));
        memset(c->fc.impulse[a], 0, (size_t)g->nfaces[a] * sizeof(double));
        memset(c->fc.drag[a], 0, (size_t)g->nfaces[a] * sizeof(double));
    }
    for (int i = 0; i < n; i++) {
        const Element *e = &c->el[i];
        for (int a = 0; a < 3; a++)
            for (int q = 0; q < 8; q++) {
                double wv = e->st[a].w[q] * (e->site.volume + c->carried[i]);
                c->phi[a][e->st[a].f[q]] += wv;
                c->num[a][e->st[a].f[q]] += wv * c->v[3 * i + a];
            }
    }
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            double vol = c->phi[a][f], ph = vol / cell;
            c->fc.velocity[a][f] = vol > 0.0 ? c->num[a][f] / vol : 0.0;
            c->phi[a][f] = ph;
            c->fc.open[a][f] = 1.0 - (ph < 0.5 ? ph : 0.5);
        }
    for (int i = 0; i < n; i++) { /* γ around each element: the mean of its components' sampled φ_s */
        double gm = 0.0;
        for (int a = 0; a < 3; a++)
            for (int q = 0; q < 8; q++) gm += c->el[i].st[a].w[q] * c->phi[a][c->el[i].st[a].f[q]];
        gm /= 3.0;
        c->el[i].site.gamma = gm < 0.5 ? gm : 0.5;
    }
}

/* After a projection: each element's weights over the coupled faces (normalised; an element with a component
   without any is outside the fluid: inactive for the step), and the fluid velocity ũ with them. */
static void sample_velocity(DrCouple *c, const DrCoupleFluid *fluid, int n, bool weights)
{
    const DrMacGrid *g = fluid->grid;
    const unsigned char *take[3];
    for (int a = 0; a < 3; a++) take[a] = fluid->coupled_faces(fluid->ctx, a);
    for (int i = 0; i < n; i++) {
        Element *e = &c->el[i];
        for (int a = 0; a < 3; a++) {
            if (weights) {
                double sum = 0.0;
                for (int q = 0; q < 8; q++) sum += take[a] && take[a][e->st[a].f[q]] ? e->st[a].w[q] : 0.0;
                for (int q = 0; q < 8; q++)
                    e->wn[a][q] = sum > 0.0 && take[a][e->st[a].f[q]] ? e->st[a].w[q] / sum : 0.0;
                if (!(sum > 0.0)) e->active = false;
            }
            double u = 0.0;
            for (int q = 0; q < 8; q++) u += e->wn[a][q] * g->f[a][e->st[a].f[q]];
            c->u[3 * i + a] = e->active ? u : 0.0;
        }
    }
}

/* The pressure and its gradient at every element (central differences over ±Δx/2), when any law has buoyancy. The
   gradient is weighted by min(1, 2 w), w the least share of the seven samples' stencils in the fluid: full inside the
   fluid and where every sample's stencil is at least half in it, fading to 0 where one reaches into a solid or the
   air, where the fluid's pressure reads 0 and a difference across the boundary is no gradient (beside a collider it
   read up to 1e6 Pa/m, which flung the film of a wet strand there). */
static void sample_pressure(DrCouple *c, const DrCoupleFluid *fluid, int n)
{
    double d = 0.5 * fluid->grid->dx;
    for (int i = 0; i < n; i++)
        for (int q = 0; q < 7; q++)
            for (int a = 0; a < 3; a++)
                c->pts[21 * i + 3 * q + a] = c->x[3 * i + a] + (q > 0 && (q - 1) / 2 == a ? ((q - 1) % 2 ? d : -d) : 0.0);
    fluid->pressure(fluid->ctx, 7L * n, c->pts, c->psamp, c->pwet);
    for (int i = 0; i < n; i++) {
        const double *ps = c->psamp + 7 * i, *pw = c->pwet + 7 * i;
        double w = 1.0;
        for (int q = 0; q < 7; q++) w = fmin(w, pw[q]);
        w = c->el[i].active ? fmin(1.0, 2.0 * fmax(w, 0.0)) : 0.0;
        c->p[i] = c->el[i].active ? ps[0] : 0.0;
        for (int a = 0; a < 3; a++) c->gradp[3 * i + a] = w * (ps[2 + 2 * a] - ps[1 + 2 * a]) / (2.0 * d);
    }
}

/* Every solid that takes it (DrCoupleSolid.pressure_gradient) gets ∇p at its elements, 0 where the element's law
   has no buoyancy (c->dv as scratch); then its impulses (DrCoupleSamples.impulse) are read again, for the step. */
static void pressure_to_solids(DrCouple *c, const DrCoupleSolid *solids, int nsolids, int n)
{
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) c->dv[3 * i + a] = c->el[i].law->buoyancy ? c->gradp[3 * i + a] : 0.0;
    int at = 0;
    for (int s = 0; s < nsolids; s++) {
        int ns = solids[s].samples(solids[s].ctx).n;
        if (solids[s].pressure_gradient) {
            solids[s].pressure_gradient(solids[s].ctx, c->dv + 3 * at);
            const double *imp = solids[s].samples(solids[s].ctx).impulse;
            if (imp) memcpy(c->imp + 3 * at, imp, (size_t)ns * 3 * sizeof(double));
        }
        at += ns;
    }
}

/* The laws at the current iterate: K (kf), D = ∂f/∂v₊ (dfdv) and the load force f(v*) − D v* (force). */
static DrStatus laws(DrCouple *c, const DrCoupleDesc *desc, const DrCoupleFluid *fluid, int n, double h, DrError *err)
{
    const DrMacGrid *g = fluid->grid;
    for (int i = 0; i < n; i++) {
        const Element *e = &c->el[i];
        double *F = c->force + 3 * i, *D = c->dfdv + 9 * i;
        if (!e->active) {
            memset(F, 0, 3 * sizeof(double));
            memset(D, 0, 9 * sizeof(double));
            memset(c->kf + 9 * i, 0, 9 * sizeof(double));
            continue;
        }
        DrVec3 v = dr_v3(c->v[3 * i], c->v[3 * i + 1], c->v[3 * i + 2]);
        DrVec3 u = dr_v3(c->u[3 * i], c->u[3 * i + 1], c->u[3 * i + 2]);
        DrVec3 dv = dr_v3_sub(v, u);
        double K[9];
        dr_drag_tensor(e->law, fluid->density, fluid->viscosity, &e->site, dv, K);
        memcpy(c->kf + 9 * i, K, 9 * sizeof(double));
        for (int q = 0; q < 9; q++) D[q] = -K[q];
        if (desc->position_derivative) {
            /* f = −K (v₊ − ũ(x + h v₊)): ∂f/∂v₊ = −K + h K ∇ũ, its symmetric part kept where it leaves the solve
               positive definite */
            double G[9];
            DrVec3 x = dr_v3(c->x[3 * i], c->x[3 * i + 1], c->x[3 * i + 2]);
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) G[3 * a + b] = face_gradient(g, a, b, x);
            for (int r = 0; r < 3; r++)
                for (int q = 0; q < 3; q++) {
                    double s = 0.0;
                    for (int m = 0; m < 3; m++) s += K[3 * r + m] * G[3 * m + q];
                    D[3 * r + q] += h * s;
                }
            nsd_part(D);
        }
        DrVec3 lift = dr_drag_lift(e->law, &e->site, K, dv);
        double vv[3] = {v.x, v.y, v.z}, dvv[3] = {dv.x, dv.y, dv.z}, fl[3] = {lift.x, lift.y, lift.z};
        for (int r = 0; r < 3; r++) {
            double f = fl[r];
            for (int q = 0; q < 3; q++) f += -K[3 * r + q] * dvv[q] - D[3 * r + q] * vv[q];
            if (e->law->buoyancy) f -= e->site.volume * c->gradp[3 * i + r];
            F[r] = f;
            if (!isfinite(f))
                return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "couple: a non-finite drag on element %d of solid "
                                    "%d (relative velocity %g m/s); lower the time step or the drag scales.",
                                    e->index, e->solid, dr_v3_norm(dv));
        }
    }
    return DR_OK;
}

/* What each element received over the step, g_i = h (f_i + D_i v_i) + its impulse outside the laws (the pressure on
   what it carries), for the velocities the solids solved for. */
static void received(DrCouple *c, int n, double h)
{
    for (int i = 0; i < n; i++)
        for (int r = 0; r < 3; r++) {
            double f = c->force[3 * i + r];
            for (int q = 0; q < 3; q++) f += c->dfdv[9 * i + 3 * r + q] * c->v[3 * i + q];
            c->g[3 * i + r] = c->el[i].active ? h * f + c->imp[3 * i + r] : 0.0;
        }
}

/* The reaction −g_i spread over each element's coupled faces (fc.impulse), and the drag mass β_f = h Σ_i wn_if K_aa of
   every element in an iteration before the last, of the implicit ones (Element.implicit) in the last, with
   an explicit element's reaction (the last projection, no drag mass to bound it) spread in proportion to wn_if m_f,
   m_f the fluid's face mass (fm, NULL: by wn alone), not to wn_if: every face it reaches then changes its velocity
   by the same −g_i,a wn_if / Σ_f wn_if m_f, at most what the element itself lost over the mass around it, where
   spreading by wn alone would give a face holding a sliver of liquid (a lone small drop) a velocity change
   without bound; the total is the same; with
   β_f (u_f − V_f) added to the impulse, u_f the last projection's velocity: the fluid then solves
   (m + β) u = m u* − Σ wn g + β u^prev, whose fixed point carries exactly the reaction. Returns Σ_f J_f over the spread
   reaction alone, and in *pull Σ_f β_f u_f (the ledger's fluid side is the first plus *pull less Σ_f β_f u_f after the
   projection). */
static DrVec3 spread(DrCouple *c, const DrMacGrid *g, int n, double h, bool last, const double *const fm[3],
                     DrVec3 *pull)
{
    double t[3] = {0, 0, 0}, pl[3] = {0, 0, 0};
    for (int i = 0; i < n; i++) {
        const Element *e = &c->el[i];
        if (!e->active) continue;
        bool drag = !last || e->implicit;
        for (int a = 0; a < 3; a++) {
            /* by wn m_f (scale: the same total as by wn): an explicit reaction, and always the impulse the element
               received outside the laws (it has no drag mass to bound it either) */
            double scale = 0.0;
            if (fm && fm[a]) {
                double wsum = 0.0, wm = 0.0;
                for (int q = 0; q < 8; q++) {
                    wsum += e->wn[a][q];
                    if (e->wn[a][q] != 0.0) wm += e->wn[a][q] * fm[a][e->st[a].f[q]];
                }
                if (wm > 0.0 && isfinite(wm)) scale = wsum / wm;
            }
            double gi = c->imp[3 * i + a], gl = c->g[3 * i + a] - gi; /* outside the laws; the laws' */
            double sl = drag ? 0.0 : scale;
            for (int q = 0; q < 8; q++) {
                double w = e->wn[a][q];
                if (w == 0.0) continue;
                long f = e->st[a].f[q];
                c->fc.impulse[a][f] -= (sl > 0.0 ? w * fm[a][f] * sl : w) * gl + (scale > 0.0 ? w * fm[a][f] * scale : w) * gi;
                if (drag) c->fc.drag[a][f] += w * h * c->kf[9 * i + 4 * a];
            }
        }
    }
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            t[a] += c->fc.impulse[a][f];
            double b = c->fc.drag[a][f];
            if (b > 0.0) {
                c->fc.impulse[a][f] += b * (g->f[a][f] - c->fc.velocity[a][f]);
                pl[a] += b * g->f[a][f];
            }
        }
    *pull = dr_v3(pl[0], pl[1], pl[2]);
    return dr_v3(t[0], t[1], t[2]);
}

static double rel_change(const double *now, const double *before, long n, double floor_abs);

/* The last projection (couple.h): explicit reactions of the elements lighter than their fluid, implicit drag of the
   others; then what those received, and their velocity corrections. *got and *gave: the ledger. */
static DrStatus final_exchange(DrCouple *c, const DrCoupleFluid *fluid, const DrCoupleSolid *solids, int nsolids,
                               int n, double h, bool all_explicit, DrVec3 *got, DrVec3 *gave, DrError *err)
{
    const DrMacGrid *g = fluid->grid;
    const double *fm[3];
    for (int a = 0; a < 3; a++) fm[a] = fluid->face_mass ? fluid->face_mass(fluid->ctx, a) : NULL;
    /* the free elements' mass on each face, by the weights they take the fluid with (c->num, zeroed by the caller) */
    for (int i = 0; i < n && !all_explicit && fm[0]; i++) {
        const Element *e = &c->el[i];
        if (!e->active || e->held) continue;
        for (int a = 0; a < 3; a++)
            for (int q = 0; q < 8; q++)
                if (e->wn[a][q] != 0.0) c->num[a][e->st[a].f[q]] += e->wn[a][q] * e->mass;
    }
    for (int i = 0; i < n; i++) {
        Element *e = &c->el[i];
        e->implicit = false;
        if (!e->active || all_explicit) continue;
        if (e->held) { e->implicit = true; continue; }
        if (!solids[e->solid].correct || !fm[0]) continue;
        /* explicit only where the fluid outweighs the element and, on every face it reaches, all the free elements
           there together: a fur whose strands crowd a sliver of liquid stays implicit */
        double mf = 0.0;
        bool outweighs = true;
        for (int a = 0; a < 3; a++)
            for (int q = 0; q < 8; q++) {
                if (e->wn[a][q] == 0.0) continue;
                long f = e->st[a].f[q];
                mf += e->wn[a][q] * fm[a][f] / 3.0;
                if (!(fm[a][f] > c->num[a][f])) outweighs = false;
            }
        e->implicit = e->mass >= mf || !outweighs;
    }
    /* the faces: every element's reaction spread, the implicit ones' drag masses pulling towards the last iterate */
    DrVec3 pv;
    DrVec3 ev = spread(c, g, n, h, true, fm, &pv);
    double expl[3] = {ev.x, ev.y, ev.z}, pull[3] = {pv.x, pv.y, pv.z};
    DR_TRY(fluid->project(fluid->ctx, &c->fc, err));
    /* the fluid gained the spread reactions and Σ β (u^prev − u) */
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < g->nfaces[a]; f++) {
            double b = c->fc.drag[a][f];
            if (b > 0.0) pull[a] -= b * g->f[a][f];
        }
    *gave = dr_v3(expl[0] + pull[0], expl[1] + pull[1], expl[2] + pull[2]);
    /* what the implicit elements received besides their solve's impulse: h K_aa (ũ − ũ^prev), what their drag masses
       took from the fluid in this projection (Σ_i is exactly the fluid's loss, the ledger); a free element's solid
       takes it (DrCoupleSolid.correct) */
    memcpy(c->uprev, c->u, (size_t)n * 3 * sizeof(double));
    sample_velocity(c, fluid, n, false);
    c->residual = rel_change(c->u, c->uprev, 3L * n, 1e-12);
    memset(c->dv, 0, (size_t)n * 3 * sizeof(double));
    bool any = false;
    for (int i = 0; i < n; i++) {
        const Element *e = &c->el[i];
        if (!e->implicit) continue;
        for (int a = 0; a < 3; a++) {
            double dg = h * c->kf[9 * i + 4 * a] * (c->u[3 * i + a] - c->uprev[3 * i + a]);
            if (!e->held) {
                c->dv[3 * i + a] = dg / e->mass;
                any = true;
            }
            c->g[3 * i + a] += dg;
        }
    }
    double t[3] = {0, 0, 0};
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) t[a] += c->g[3 * i + a];
    *got = dr_v3(t[0], t[1], t[2]);
    if (any) {
        int at = 0;
        for (int s = 0; s < nsolids; s++) {
            int ns = solids[s].samples(solids[s].ctx).n;
            if (solids[s].correct) solids[s].correct(solids[s].ctx, c->dv + 3 * at);
            at += ns;
        }
    }
    return DR_OK;
}

static double rel_change(const double *now, const double *before, long n, double floor_abs)
{
    double d = 0.0, s = 0.0;
    for (long i = 0; i < n; i++) {
        d += (now[i] - before[i]) * (now[i] - before[i]);
        s += now[i] * now[i];
    }
    double den = sqrt(s);
    if (den < floor_abs) den = floor_abs;
    return sqrt(d) / den;
}

DrStatus dr_couple_step(DrCouple *c, const DrCoupleDesc *desc, const DrCoupleFluid *fluid,
                        const DrCoupleSolid *solids, int nsolids, double h, DrCoupleStats *stats, DrError *err)
{
    if (!(h > 0.0) || !isfinite(h) || desc->iterations < 1 || !(desc->tolerance > 0.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "couple: step %g s, %d iterations, tolerance %g: the step "
                            "must be positive, the iterations at least 1 and the tolerance positive.", h,
                            desc->iterations, desc->tolerance);
    const DrMacGrid *g = fluid->grid;
    int n = 0;
    DR_TRY(gather(c, fluid, solids, nsolids, &n, err));
    bool buoyancy = false;
    for (int s = 0; s < nsolids; s++)
        for (int l = 0; l < solids[s].nlaws; l++) buoyancy = buoyancy || solids[s].laws[l].buoyancy;
    double t0 = dr_time_now();
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++)
            c->el[i].st[a] = face_stencil(g, a, dr_v3(c->x[3 * i], c->x[3 * i + 1], c->x[3 * i + 2]));
    rasterise(c, g, n);
    double t1 = dr_time_now();
    DR_TRY(fluid->project(fluid->ctx, &c->fc, err));
    double t2 = dr_time_now();
    sample_velocity(c, fluid, n, true);
    memset(c->gradp, 0, (size_t)n * 3 * sizeof(double));
    memset(c->p, 0, (size_t)n * sizeof(double));
    if (buoyancy) {
        sample_pressure(c, fluid, n);
        pressure_to_solids(c, solids, nsolids, n);
    }
    long active = 0;
    for (int i = 0; i < n; i++) active += c->el[i].active;
    double ufloor = 1e-12, change = INFINITY, change_fluid = INFINITY;
    double sec_laws = t1 - t0, sec_solid = 0.0, sec_fluid = t2 - t1;
    int k = 1;
    for (;; k++) {
        double a0 = dr_time_now();
        DR_TRY(laws(c, desc, fluid, n, h, err));
        double a1 = dr_time_now();
        int at = 0;
        for (int s = 0; s < nsolids; s++) {
            DrCoupleSamples sm = solids[s].samples(solids[s].ctx);
            DR_TRY(solids[s].solve(solids[s].ctx, c->force + 3 * at, c->dfdv + 9 * at, err));
            at += sm.n;
        }
        double a2 = dr_time_now();
        memcpy(c->vprev, c->v, (size_t)n * 3 * sizeof(double));
        read_velocities(c, solids, nsolids);
        received(c, n, h);
        double cv = rel_change(c->v, c->vprev, 3L * n, ufloor);
        change = k == 1 ? cv : (cv > change_fluid ? cv : change_fluid);
        if (k <= 64) c->changes[k - 1] = change;
        c->nchanges = k;
        bool last = k >= desc->iterations || (k > 1 && change < desc->tolerance);
        rasterise(c, g, n);
        double a3 = dr_time_now();
        if (last) {
            DrVec3 got, gave;
            memset(c->num[0], 0, (size_t)g->nfaces[0] * sizeof(double));
            memset(c->num[1], 0, (size_t)g->nfaces[1] * sizeof(double));
            memset(c->num[2], 0, (size_t)g->nfaces[2] * sizeof(double));
            DR_TRY(final_exchange(c, fluid, solids, nsolids, n, h, desc->explicit_reaction, &got, &gave, err));
            double a4 = dr_time_now();
            sec_laws += a1 - a0 + a3 - a2;
            sec_solid += a2 - a1;
            sec_fluid += a4 - a3;
            c->ledger_solid = got;
            c->ledger_fluid = gave;
            break;
        }
        DrVec3 unused;
        (void)spread(c, g, n, h, false, NULL, &unused);
        DR_TRY(fluid->project(fluid->ctx, &c->fc, err));
        double a4 = dr_time_now();
        sec_laws += a1 - a0 + a3 - a2;
        sec_solid += a2 - a1;
        sec_fluid += a4 - a3;
        memcpy(c->uprev, c->u, (size_t)n * 3 * sizeof(double));
        memcpy(c->pprev, c->p, (size_t)n * sizeof(double));
        sample_velocity(c, fluid, n, false);
        if (buoyancy) sample_pressure(c, fluid, n);
        double cu = rel_change(c->u, c->uprev, 3L * n, ufloor);
        double cp = buoyancy ? rel_change(c->p, c->pprev, n, 1e-9) : 0.0;
        change_fluid = cu > cp ? cu : cp;
    }
    if (stats) {
        stats->steps++;
        stats->iterations_total += k;
        if (k > stats->iterations_max) stats->iterations_max = k;
        if (change >= desc->tolerance && k >= desc->iterations && desc->iterations > 1) stats->not_converged++;
        if (change > stats->change_max && isfinite(change)) stats->change_max = change;
        stats->elements = active;
        stats->solid_impulse = dr_v3_add(stats->solid_impulse, c->ledger_solid);
        stats->fluid_impulse = dr_v3_add(stats->fluid_impulse, c->ledger_fluid);
        stats->seconds_laws += sec_laws;
        stats->seconds_solid += sec_solid;
        stats->seconds_fluid += sec_fluid;
    }
    return DR_OK;
}

/* ---- deformable solids lumped onto the faces (couple.h) ------------------------------------------------------- */

/* The quadratic-kernel weights of point x on the lattice of face component a (a = 3: the cell centres): the index
   (face or cell order) and weight of each of its up to 27 nodes inside the lattice, in a fixed order; returns how
   many. */
static int lattice_weights(const DrMacGrid *g, int a, const double *x, long idx[27], double w[27])
{
    double o[3] = {g->origin.x, g->origin.y, g->origin.z};
    int dim[3];
    DrStencil3 st[3];
    for (int d = 0; d < 3; d++) {
        dim[d] = a == 3 ? (d == 0 ? g->nx : d == 1 ? g->ny : g->nz) : g->fdim[a][d];
        double off = a == 3 ? 0.5 : dr_mac_face_offset(a, d);
        st[d] = dr_kernel_quadratic((x[d] - o[d]) / g->dx - off);
    }
    int n = 0;
    for (int k = 0; k < 3; k++) {
        int kk = st[2].base + k;
        if (kk < 0 || kk >= dim[2]) continue;
        for (int j = 0; j < 3; j++) {
            int jj = st[1].base + j;
            if (jj < 0 || jj >= dim[1]) continue;
            double wjk = st[1].w[j] * st[2].w[k];
            for (int i = 0; i < 3; i++) {
                int ii = st[0].base + i;
                if (ii < 0 || ii >= dim[0]) continue;
                idx[n] = a == 3 ? dr_mac_cell_index(g, ii, jj, kk) : dr_mac_face_index(g, a, ii, jj, kk);
                w[n++] = st[0].w[i] * wjk;
            }
        }
    }
    return n;
}

void dr_couple_particles_to_faces(const DrMacGrid *g, long n, const double *x, const double *v, const double *mass,
                                  const double *volume, DrFaceCoupling *fc)
{
    double cell = g->dx * g->dx * g->dx;
    for (int a = 0; a < 3; a++) {
        double *open = fc->open[a], *vel = fc->velocity[a], *ms = fc->solid_mass[a];
        for (long f = 0; f < g->nfaces[a]; f++) {
            open[f] = 0.0; /* the volume sum first */
            vel[f] = 0.0;
            ms[f] = 0.0;
            if (fc->impulse[a]) fc->impulse[a][f] = 0.0;
            if (fc->drag[a]) fc->drag[a][f] = 0.0;
        }
        for (long p = 0; p < n; p++) {
            long idx[27];
            double w[27], mv = mass[p] * v[3 * p + a];
            int cnt = lattice_weights(g, a, x + 3 * p, idx, w);
            for (int q = 0; q < cnt; q++) {
                open[idx[q]] += w[q] * volume[p];
                vel[idx[q]] += w[q] * mv;
                ms[idx[q]] += w[q] * mass[p];
            }
        }
        for (long f = 0; f < g->nfaces[a]; f++) {
            double sigma = open[f] / cell;
            open[f] = sigma >= 1.0 ? 0.0 : 1.0 - sigma;
            vel[f] = ms[f] > 0.0 ? vel[f] / ms[f] : 0.0;
        }
    }
}

void dr_couple_faces_to_particles(const DrMacGrid *g, long n, const double *x, const double *const momentum[3],
                                  const DrFaceCoupling *fc, double *dv)
{
    for (long p = 0; p < 3 * n; p++) dv[p] = 0.0;
    for (int a = 0; a < 3; a++) {
        if (!momentum[a]) continue;
        const double *P = momentum[a], *ms = fc->solid_mass[a];
        for (long p = 0; p < n; p++) {
            long idx[27];
            double w[27], sum = 0.0;
            int cnt = lattice_weights(g, a, x + 3 * p, idx, w);
            for (int q = 0; q < cnt; q++)
                if (ms[idx[q]] > 0.0 && P[idx[q]] != 0.0) sum += w[q] * P[idx[q]] / ms[idx[q]];
            dv[3 * p + a] = sum;
        }
    }
}

void dr_couple_particle_fraction(const DrMacGrid *g, long n, const double *x, const double *volume, double *frac)
{
    long nc = (long)g->nx * g->ny * g->nz;
    double cell = g->dx * g->dx * g->dx;
    for (long c = 0; c < nc; c++) frac[c] = 0.0;
    for (long p = 0; p < n; p++) {
        long idx[27];
        double w[27];
        int cnt = lattice_weights(g, 3, x + 3 * p, idx, w);
        for (int q = 0; q < cnt; q++) frac[idx[q]] += w[q] * volume[p] / cell;
    }
    for (long c = 0; c < nc; c++)
        if (frac[c] > 1.0) frac[c] = 1.0;
}

/* Trilinear fraction at x on the cell-centre lattice (clamped to it) and its gradient (per m). */
static double fraction_at(const DrMacGrid *g, const double *frac, const double *x, double grad[3])
{
    double o[3] = {g->origin.x, g->origin.y, g->origin.z};
    int n[3] = {g->nx, g->ny, g->nz}, b[3];
    double t[3];
    for (int d = 0; d < 3; d++) {
        double s = (x[d] - o[d]) / g->dx - 0.5;
        if (s < 0.0) s = 0.0;
        if (s > n[d] - 1) s = n[d] - 1;
        b[d] = (int)floor(s);
        if (b[d] > n[d] - 2) b[d] = n[d] - 2;
        if (b[d] < 0) b[d] = 0;
        t[d] = s - b[d];
    }
    double c[2][2][2];
    for (int k = 0; k < 2; k++)
        for (int j = 0; j < 2; j++)
            for (int i = 0; i < 2; i++) {
                int ii = b[0] + i < n[0] ? b[0] + i : n[0] - 1, jj = b[1] + j < n[1] ? b[1] + j : n[1] - 1;
                int kk = b[2] + k < n[2] ? b[2] + k : n[2] - 1;
                c[k][j][i] = frac[dr_mac_cell_index(g, ii, jj, kk)];
            }
    double val = 0.0;
    for (int d = 0; d < 3; d++) grad[d] = 0.0;
    for (int k = 0; k < 2; k++)
        for (int j = 0; j < 2; j++)
            for (int i = 0; i < 2; i++) {
                double wx = i ? t[0] : 1.0 - t[0], wy = j ? t[1] : 1.0 - t[1], wz = k ? t[2] : 1.0 - t[2];
                double cv = c[k][j][i];
                val += wx * wy * wz * cv;
                grad[0] += (i ? 1.0 : -1.0) * wy * wz * cv / g->dx;
                grad[1] += (j ? 1.0 : -1.0) * wx * wz * cv / g->dx;
                grad[2] += (k ? 1.0 : -1.0) * wx * wy * cv / g->dx;
            }
    return val;
}

long dr_couple_push_out(const DrMacGrid *g, const double *frac, long n, double *x)
{
    long moved = 0;
    for (long p = 0; p < n; p++) {
        double *xp = x + 3 * p, grad[3];
        double f = fraction_at(g, frac, xp, grad);
        if (!(f > 0.5)) continue;
        double travelled = 0.0;
        for (int it = 0; it < 6 && f > 0.5; it++) {
            double gn = sqrt(grad[0] * grad[0] + grad[1] * grad[1] + grad[2] * grad[2]);
            if (!(gn > 1e-9 / g->dx)) break;
            /* a step to the ½ level along −∇f, at least a tenth of a cell, at most what is left of 2Δx */
            double step = (f - 0.5) / gn + 1e-6 * g->dx;
            if (step < 0.1 * g->dx) step = 0.1 * g->dx;
            if (step > 2.0 * g->dx - travelled) step = 2.0 * g->dx - travelled;
            if (!(step > 0.0)) break;
            for (int d = 0; d < 3; d++) xp[d] -= step * grad[d] / gn;
            travelled += step;
            f = fraction_at(g, frac, xp, grad);
        }
        moved++;
    }
    return moved;
}

double dr_couple_fraction_at(const DrMacGrid *g, const double *frac, const double *x, double grad_out[3])
{
    double grad[3];
    double f = fraction_at(g, frac, x, grad);
    if (grad_out) memcpy(grad_out, grad, sizeof grad);
    return f;
}
