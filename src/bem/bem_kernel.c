/* drench bem: Laplace-domain elastodynamic kernels (BEM App. A, eqs. 16–21) and convolution-quadrature
 * weights (BEM eq. 15, BDF1).
 *
 * Notation. r = y − x, r = |r|, r̂ = r/r, ∂r/∂n = r̂·n, κ = c2²/c1² = μ/(λ + 2μ). For each wave speed c_k
 * (k = 1 longitudinal, k = 2 shear): z_k = s r/c_k, E_k = e^{−z_k} and
 *     F(z) = ((1 + z) e^{−z} − 1)/z²,   F(0) = −1/2.                                                   (A)
 * Every 1/s² bracket of App. A is built from (1 + z_k)e^{−z_k}/s², and z_k²/s² = r²/c_k², so with
 *     D = F(z1)/c1² − F(z2)/c2² = ((1 + z1)e^{−z1} − (1 + z2)e^{−z2})/(s r)²                              (B)
 * the bracket of eq. 16 and the first of eq. 17 (e^{−z}/c² (c/(r s) + c²/(r² s²)) = (1 + z)e^{−z}/(r s)² per
 * wave) are r² D and D, that of eqs. 19 and 21 is −r² D, and (1 − (s r/c2 + 1)e^{−z2})/s² = −r² F(z2)/c2².
 * The left form of (B) cancels the 1/s² constants exactly (small |z|), the right one the −1/(s r)² that both
 * F_k tend to (large |z|); each is used where it is exact. Collecting the printed terms by tensor:
 *   eq. 16  û_ij = [r̂_i r̂_j (3D + E1/c1² − E2/c2²) + δ_ij (E2/c2² − D)] / (4πρ r);
 *   eq. 17  p̂_ij = [α_P r̂_i n_j + α_Q (r̂_j n_i + δ_ij ∂r/∂n) + α_M r̂_i r̂_j ∂r/∂n] / (4π r²),
 *           α_P = 6c2²D + κ(4 + 2z1)E1 − (1 + z1)E1 − 2E2 = κ(6F1 + (4 + 2z1)E1) − (1 + z1)E1 − 6F2 − 2E2,
 *           α_Q = 6c2²D + 2κE1 − (3 + z2)E2            = κ(6F1 + 2E1) − 6F2 − (3 + z2)E2,
 *           α_M = −30c2²D − κ(12 + 2z1)E1 + (12 + 2z2)E2 = −κ(30F1 + (12 + 2z1)E1) + 30F2 + (12 + 2z2)E2;
 *   eq. 19  d̂_ij = [D r̂_i n_j + δ_ij ∂r/∂n F2/c2²] / (4π);
 *   eq. 21  l̂_ij = [D r_i (r̂ × n)_j − (e_i × n)_j e^{−z2}/(c2 s)] / (4π),
 * using r_{j+1} n_{j+2} − r_{j+2} n_{j+1} = (r × n)_j and δ_{i(j+1)} n_{j+2} − δ_{i(j+2)} n_{j+1} = (e_i × n)_j.
 * Eq. 17 is printed with i the load direction and j the traction component at y, the header's order: row i
 * is the traction σ(û_{i·}) n of the displacement field û_{i·}(y) (test_bem_kernel checks it by finite
 * differences). At s → 0 (F → −1/2, E → 1) α_P → κ, α_Q → −κ, α_M → −3(1 − κ), which is the Kelvin traction
 * kernel of dr_bem_kernel_p_static with κ = (1 − 2ν)/(2(1 − ν)).
 *
 * p_dyn. p̂ − p_static is O(z²) relative to p_static; subtracting the two loses 1/|z|² of the digits near the
 * collocation point, exactly where the singular rule samples. So each wave's share of α is taken minus its own
 * s = 0 value, analytically:
 *     α_P − κ = κ G1(z1) − z1²F1 − G3(z2),   α_Q + κ = κ G3(z1) + G4(z2),   α_M + 3(1 − κ) = κ G5(z1) − G5(z2),
 *     G1 = 6F + 4E + 2zE − 1,  G3 = 6F + 2E + 1,  G4 = −6F − (3 + z)E,  G5 = −30F − (12 + 2z)E − 3,
 * each O(z²).
 *
 * Small |z|. With w = −z and φ_k(w) = Σ_n wⁿ/(n + k)! (φ_0 = e^w, φ_{k−1} = 1/(k−1)! + w φ_k):
 *     E = φ_0,  F = φ_2 − φ_1,  G1 = z²(6φ_4 − 6φ_3 + 4φ_2 − 2φ_1),  G3 = z²(6φ_4 − 6φ_3 + 2φ_2),
 *     G4 = z²(−6φ_4 + 6φ_3 − 3φ_2 + φ_1),  G5 = z²(−30φ_4 + 30φ_3 − 12φ_2 + 2φ_1),
 * one truncated series for φ_4 and the (cancellation-free) downward recurrence for the rest. */
#include "bem_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Below |z| = 0.5 the series; above, the closed forms. At |z| = 0.5 the closed form of F loses a factor
 * ~|1 + z|/|z² F| ≈ 12 to cancellation (≈ 3e-15) and that of G5 ≈ 240 (≈ 5e-14, relative to the O(z²)
 * p_dyn only); the 13 terms of φ_4 leave a truncation of (1/2)^13 · 4!/17! ≈ 1e-17 there. */
#define SERIES_Z2 0.25
#define SERIES_TERMS 13

static const double inv_int[SERIES_TERMS + 4] = {
    0.0,        1.0,        1.0 / 2.0,  1.0 / 3.0,  1.0 / 4.0,  1.0 / 5.0,  1.0 / 6.0,  1.0 / 7.0,  1.0 / 8.0,
    1.0 / 9.0,  1.0 / 10.0, 1.0 / 11.0, 1.0 / 12.0, 1.0 / 13.0, 1.0 / 14.0, 1.0 / 15.0, 1.0 / 16.0,
};

/* ---- material and wave speeds ------------------------------------------------------------------ */

void dr_bem_wave_init(const DrBemMaterial *m, DrBemWave *out)
{
    double mu = m->shear_modulus, nu = m->poisson, rho = m->density;
    out->rho = rho;
    out->mu = mu;
    out->nu = nu;
    out->lambda = 2.0 * mu * nu / (1.0 - 2.0 * nu);
    out->c1 = sqrt((out->lambda + 2.0 * mu) / rho); /* BEM eq. 18 */
    out->c2 = sqrt(mu / rho);
}

/* ---- one wave: e^{−z}, F(z) and the O(z²) parts of p_dyn ------------------------------------- */

/* Complex product without C99 Annex G's recovery of infinite results (a __muldc3 call behind every product):
 * every operand in this file is finite. */
static inline double complex cmul(double complex a, double complex b)
{
    double ar = creal(a), ai = cimag(a), br = creal(b), bi = cimag(b);
    return CMPLX(ar * br - ai * bi, ar * bi + ai * br);
}

typedef struct WaveTerms {
    double complex e;              /* e^{−z} */
    double complex ze;             /* z e^{−z} */
    double complex h;              /* (1 + z) e^{−z} */
    double complex f;              /* F(z), (A) */
    double complex z2f;            /* z² F(z) = (1 + z)e^{−z} − 1 */
    double complex g1, g3, g4, g5; /* the static-free parts above (only when asked for) */
    double complex iz2;            /* 1/z² (closed forms only) */
    bool series;                   /* |z| below the switch */
} WaveTerms;

static inline void wave_terms(double complex z, bool dyn, WaveTerms *o)
{
    double x = creal(z), y = cimag(z), m2 = x * x + y * y;
    if (m2 < SERIES_Z2) {
        double complex w = -z;
        double complex t = 1.0;
        for (int j = SERIES_TERMS + 3; j >= 5; j--) t = 1.0 + cmul(w, t) * inv_int[j];
        double complex ph4 = t * (1.0 / 24.0);
        double complex ph3 = (1.0 / 6.0) + cmul(w, ph4);
        double complex ph2 = 0.5 + cmul(w, ph3);
        double complex ph1 = 1.0 + cmul(w, ph2);
        double complex ph0 = 1.0 + cmul(w, ph1);
        o->series = true;
        o->e = ph0;
        o->ze = cmul(z, ph0);
        o->h = ph0 + o->ze;
        o->f = ph2 - ph1;
        o->z2f = cmul(cmul(z, z), o->f);
        if (dyn) {
            double complex z2 = cmul(z, z), a = 6.0 * (ph4 - ph3);
            o->g1 = cmul(z2, a + 4.0 * ph2 - 2.0 * ph1);
            o->g3 = cmul(z2, a + 2.0 * ph2);
            o->g4 = cmul(z2, ph1 - a - 3.0 * ph2);
            o->g5 = cmul(z2, 2.0 * ph1 - 5.0 * a - 12.0 * ph2);
        }
        return;
    }
    double ex = exp(-x);
    double complex e = CMPLX(ex * cos(y), -ex * sin(y));
    double inv = 1.0 / m2;
    double complex iz = CMPLX(x * inv, -y * inv);
    o->series = false;
    o->e = e;
    o->ze = cmul(z, e);
    o->h = e + o->ze;
    o->iz2 = cmul(iz, iz);
    o->z2f = (e - 1.0) + o->ze;
    o->f = cmul(o->z2f, o->iz2);
    if (dyn) {
        o->g1 = 6.0 * o->f + 4.0 * e + 2.0 * o->ze - 1.0;
        o->g3 = 6.0 * o->f + 2.0 * e + 1.0;
        o->g4 = -6.0 * o->f - 3.0 * e - o->ze;
        o->g5 = -30.0 * o->f - 12.0 * e - 2.0 * o->ze - 3.0;
    }
}

/* ---- Laplace-domain kernels ------------------------------------------------------------------- */

void dr_bem_kernel_batch(const DrBemWave *w, const double r[3], const double n[3], int ns, const double complex *s,
                         const DrBemKernelOut *out)
{
    double complex *ou = out->u, *op = out->p, *opd = out->p_dyn, *od = out->d, *ol = out->l;
    double r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    assert(r2 > 0.0 && ns >= 0);
    double rl = sqrt(r2), ir = 1.0 / rl;
    double rh[3] = {r[0] * ir, r[1] * ir, r[2] * ir};
    double rn = rh[0] * n[0] + rh[1] * n[1] + rh[2] * n[2]; /* ∂r/∂n */
    double a1 = rl / w->c1, a2 = rl / w->c2;                  /* z_k = s a_k */
    double ic1 = 1.0 / (w->c1 * w->c1), ic2 = 1.0 / (w->c2 * w->c2);
    double irho = 1.0 / w->rho, c2sq = w->c2 * w->c2;
    double kappa = w->mu / (w->lambda + 2.0 * w->mu);
    const double k4 = 1.0 / (4.0 * DR_PI);

    /* Geometry shared by every s, with the 1/(4π rᵏ) factors folded in; only what the outputs need. */
    double RR[9] = {0}, TP[9] = {0}, TQ[9] = {0}, TM[9] = {0}, TD[9] = {0}, TL[9] = {0}, TN[9] = {0};
    double ku = k4 * ir, kp = k4 * ir * ir, kd = k4 * rn; /* kd: δ_ij ∂r/∂n/(4π) of eq. 19 */
    if (ou)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) RR[3 * i + j] = ku * rh[i] * rh[j];
    if (op || opd)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                TP[3 * i + j] = kp * rh[i] * n[j];
                TQ[3 * i + j] = kp * (rh[j] * n[i] + (i == j ? rn : 0.0));
                TM[3 * i + j] = kp * rh[i] * rh[j] * rn;
            }
    if (od)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) TD[3 * i + j] = k4 * rh[i] * n[j];
    if (ol) {
        double rxn[3] = {rh[1] * n[2] - rh[2] * n[1], rh[2] * n[0] - rh[0] * n[2], rh[0] * n[1] - rh[1] * n[0]};
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) TL[3 * i + j] = k4 * r[i] * rxn[j];
        /* (e_i × n)_j/(4π) = [n]×/(4π) */
        TN[1] = -k4 * n[2], TN[2] = k4 * n[1];
        TN[3] = k4 * n[2], TN[5] = -k4 * n[0];
        TN[6] = -k4 * n[1], TN[7] = k4 * n[0];
    }

    bool dyn = opd != NULL;
    for (int k = 0; k < ns; k++) {
        WaveTerms v1, v2;
        wave_terms(s[k] * a1, dyn, &v1);
        wave_terms(s[k] * a2, dyn, &v2);
        /* D = F1/c1² − F2/c2² = ((1 + z1)e^{−z1} − (1 + z2)e^{−z2})/(s r)². Once |z1| passes the switch both
         * F_k approach −1/(s r)² and their difference is the exponentially small e^{−z} part: it is formed
         * from the (1 + z)e^{−z} terms directly. Below it F1/c1² is near −1/(2c1²) and F2/c2² lies between
         * −1/(2c2²) (c2² ≤ 3c1²/4) and −1/(s r)² (|s r|⁻² > 4/c1²): the difference loses a few bits at most. */
        double complex D = v1.series ? v1.f * ic1 - v2.f * ic2 : cmul(v1.h - v2.h, v1.iz2) * ic1;
        if (ou) {
            double complex e1c = v1.e * ic1, e2c = v2.e * ic2;
            double complex crr = irho * (3.0 * D + e1c - e2c);
            double complex cd = ku * irho * (e2c - D);
            double complex *o = ou + 9 * k;
            for (int e = 0; e < 9; e++) o[e] = crr * RR[e];
            o[0] += cd, o[4] += cd, o[8] += cd;
        }
        if (op) {
            double complex d6 = 6.0 * c2sq * D; /* 6(κF1 − F2) */
            double complex ap = d6 + kappa * (4.0 * v1.e + 2.0 * v1.ze) - v1.h - 2.0 * v2.e;
            double complex aq = d6 + 2.0 * kappa * v1.e - 3.0 * v2.e - v2.ze;
            double complex am = -5.0 * d6 - kappa * (12.0 * v1.e + 2.0 * v1.ze) + 12.0 * v2.e + 2.0 * v2.ze;
            double complex *o = op + 9 * k;
            for (int e = 0; e < 9; e++) o[e] = ap * TP[e] + aq * TQ[e] + am * TM[e];
        }
        if (opd) {
            double complex bp = kappa * v1.g1 - v1.z2f - v2.g3;
            double complex bq = kappa * v1.g3 + v2.g4;
            double complex bm = kappa * v1.g5 - v2.g5;
            double complex *o = opd + 9 * k;
            for (int e = 0; e < 9; e++) o[e] = bp * TP[e] + bq * TQ[e] + bm * TM[e];
        }
        if (od) {
            double complex cdd = kd * ic2 * v2.f;
            double complex *o = od + 9 * k;
            for (int e = 0; e < 9; e++) o[e] = D * TD[e];
            o[0] += cdd, o[4] += cdd, o[8] += cdd;
        }
        if (ol) {
            /* e^{−z2}/(c2 s): 1/s as conj(s)/|s|² */
            double sx = creal(s[k]), sy = cimag(s[k]), is = 1.0 / ((sx * sx + sy * sy) * w->c2);
            double complex ce = cmul(v2.e, CMPLX(sx * is, -sy * is));
            double complex *o = ol + 9 * k;
            for (int e = 0; e < 9; e++) o[e] = D * TL[e] - ce * TN[e];
        }
    }
}

void dr_bem_kernel_u(const DrBemWave *w, const double r[3], double complex s, double complex u[9])
{
    static const double n0[3] = {0.0, 0.0, 0.0};
    DrBemKernelOut o = {.u = u};
    dr_bem_kernel_batch(w, r, n0, 1, &s, &o);
}

void dr_bem_kernel_p(const DrBemWave *w, const double r[3], const double n[3], double complex s, double complex p[9])
{
    DrBemKernelOut o = {.p = p};
    dr_bem_kernel_batch(w, r, n, 1, &s, &o);
}

void dr_bem_kernel_d(const DrBemWave *w, const double r[3], const double n[3], double complex s, double complex d[9])
{
    DrBemKernelOut o = {.d = d};
    dr_bem_kernel_batch(w, r, n, 1, &s, &o);
}

void dr_bem_kernel_l(const DrBemWave *w, const double r[3], const double n[3], double complex s, double complex l[9])
{
    DrBemKernelOut o = {.l = l};
    dr_bem_kernel_batch(w, r, n, 1, &s, &o);
}

/* Kelvin's solution: u_ij = [(3 − 4ν)δ_ij + r̂_i r̂_j]/(16πμ(1 − ν) r). */
void dr_bem_kernel_u_static(const DrBemWave *w, const double r[3], double u[9])
{
    double rl = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
    assert(rl > 0.0);
    double rh[3] = {r[0] / rl, r[1] / rl, r[2] / rl};
    double k = 1.0 / (16.0 * DR_PI * w->mu * (1.0 - w->nu) * rl), a = 3.0 - 4.0 * w->nu;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) u[3 * i + j] = k * ((i == j ? a : 0.0) + rh[i] * rh[j]);
}

/* p_ij = −[∂r/∂n ((1 − 2ν)δ_ij + 3 r̂_i r̂_j) − (1 − 2ν)(r̂_i n_j − r̂_j n_i)] / (8π(1 − ν) r²), i the load
 * direction: the s → 0 limit of eq. 17 as printed (α_P = κ, α_Q = −κ, α_M = −3(1 − κ) above). */
void dr_bem_kernel_p_static(const DrBemWave *w, const double r[3], const double n[3], double p[9])
{
    double r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2], rl = sqrt(r2);
    assert(rl > 0.0);
    double rh[3] = {r[0] / rl, r[1] / rl, r[2] / rl};
    double rn = rh[0] * n[0] + rh[1] * n[1] + rh[2] * n[2];
    double b = 1.0 - 2.0 * w->nu, k = -1.0 / (8.0 * DR_PI * (1.0 - w->nu) * r2);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            p[3 * i + j] = k * (rn * ((i == j ? b : 0.0) + 3.0 * rh[i] * rh[j]) - b * (rh[i] * n[j] - rh[j] * n[i]));
}

/* ---- convolution quadrature ------------------------------------------------------------------- */

DrStatus dr_bem_cq_init(int L, double eps, double dt, DrBemCq *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    if (L < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "convolution quadrature needs at least one frequency, got L = %d; use the history "
                            "length n_max >= 1",
                            L);
    if (!(eps > 0.0 && eps < 1.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "convolution quadrature accuracy eps = %g must lie in (0, 1); 1e-10 is usual", eps);
    if (!(dt > 0.0) || !isfinite(dt))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "convolution quadrature time step dt = %g s must be positive and finite", dt);
    DR_TRY(dr_calloc((size_t)L, sizeof *out->s, &out->s, err));
    double lr = log(eps) / (2.0 * L); /* ln R */
    double R = exp(lr), omr = -expm1(lr); /* R = ε^{1/(2L)} and 1 − R without cancellation */
    out->L = L;
    out->R = R;
    out->dt = dt;
    /* s_l = (1 − R e^{iθ})/Δt, θ = 2πl/L; Re: 1 − R cos θ = (1 − R) + 2R sin²(θ/2), accurate for small θ.
     * The upper half is set to the exact conjugates of the lower, so f̂(s_{L−l}) = conj f̂(s_l) holds bit for
     * bit for a real time function and dr_bem_cq_weights_half agrees with the full sum. */
    for (int l = 0; 2 * l <= L; l++) {
        double h = DR_PI * l / L, sh = sin(h);
        out->s[l] = CMPLX((omr + 2.0 * R * sh * sh) / dt, 2 * l == L ? 0.0 : -R * sin(2.0 * h) / dt);
        if (l > 0 && L - l != l) out->s[L - l] = conj(out->s[l]);
    }
    return DR_OK;
}

void dr_bem_cq_free(DrBemCq *cq)
{
    if (!cq) return;
    free(cq->s);
    memset(cq, 0, sizeof *cq);
}

/* e^{−2πik/L}, from the angle reduced to [0, π] so that k and L − k give exact conjugates. */
static inline double complex cq_twiddle(int k, int L)
{
    int m = k <= L - k ? k : L - k;
    double a = 2.0 * DR_PI * m / L;
    double complex t = CMPLX(cos(a), -sin(a));
    return m == k ? t : conj(t);
}

/* ψ_k = R^{−k}/L Σ_l f̂_l ζ^l, ζ = e^{−2πik/L}: the polynomial Σ_l f̂_l ζ^l by Horner's rule at each of the L
 * points of the unit circle, O(L²) without a table of twiddles. */
void dr_bem_cq_weights(const DrBemCq *cq, const double complex *fhat, double *psi)
{
    int L = cq->L;
    for (int k = 0; k < L; k++) {
        double complex zeta = cq_twiddle(k, L), acc = fhat[L - 1];
        for (int l = L - 2; l >= 0; l--) acc = cmul(acc, zeta) + fhat[l];
        psi[k] = creal(acc) * pow(cq->R, -(double)k) / L;
    }
}

/* With f̂_{L−l} = conj f̂_l and ζ^{L−l} = conj ζ^l: Re Σ_l f̂_l ζ^l = Re f̂_0 + 2 Re Σ_{0<l<L/2} f̂_l ζ^l
 * + Re f̂_{L/2} (−1)^k (L even). */
void dr_bem_cq_weights_half(const DrBemCq *cq, const double complex *fhat_half, double *psi)
{
    int L = cq->L, m = (L - 1) / 2; /* pairs l, L − l with l ≠ L − l */
    for (int k = 0; k < L; k++) {
        double sum = creal(fhat_half[0]);
        if (m > 0) {
            double complex zeta = cq_twiddle(k, L), acc = fhat_half[m];
            for (int l = m - 1; l >= 1; l--) acc = cmul(acc, zeta) + fhat_half[l];
            sum += 2.0 * creal(cmul(acc, zeta));
        }
        if (L % 2 == 0 && L > 1) sum += (k % 2 ? -1.0 : 1.0) * creal(fhat_half[L / 2]);
        psi[k] = sum * pow(cq->R, -(double)k) / L;
    }
}
