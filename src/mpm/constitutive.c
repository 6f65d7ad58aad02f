/* Hyperelastic energy densities for MPM ([APIC] §3.1, eqs. 9–11): Neo-Hookean and fixed corotated
 * (Stomakhin et al. 2012), their first Piola–Kirchhoff stress and its differential, and the polar
 * decomposition fixed corotated needs.
 *
 * Every routine works on 3×3 row-major matrices. In 2-D the z row and column of F are those of the
 * identity: the 3-D formulas then give the 2-D energy exactly (tr FᵀF − 3 = tr F₂ᵀF₂ − 2, J = J₂, and
 * F − R has a zero z row and column), and P, dP equal the 2-D ones on the xy block; only their zz entry
 * (the out-of-plane stress that a per-unit-depth model has no use for) differs, so it is zeroed. The
 * polar decomposition is the one place that needs its own 2-D form: a 3-D sign-fixed SVD of diag(F₂, 1)
 * could flip the z axis instead of the smallest in-plane singular value.
 *
 * Polar decomposition (3-D): a rotation-variant SVD F = U Σ Vᵀ with det U = det V = +1 and the sign of
 * det F on the smallest singular value, as fixed corotated requires for inverted elements. V comes from
 * cyclic Jacobi on FᵀF (converged to round-off, a few sweeps), U from a Givens QR of F V (the columns of
 * F V are orthogonal, so R is diagonal up to round-off and carries the signed singular values). QR rather
 * than U = F V Σ⁻¹ keeps U orthonormal when singular values vanish (McAdams et al. 2011, "Computing the
 * singular value decomposition of 3×3 matrices with minimal branching"). LAPACK's dgesvd was not used:
 * it returns det U = −1 for reflections (needing the same sign fix afterwards), costs a library call
 * and workspace query per particle, and its reductions are not guaranteed to be order-fixed across
 * OpenBLAS builds. */
#include "mpm/mpm.h"

#include <string.h>

void dr_mpm_lame(const DrMpmMaterial *m, double *mu, double *lambda)
{
    *mu = m->youngs / (2.0 * (1.0 + m->poisson));
    *lambda = m->youngs * m->poisson / ((1.0 + m->poisson) * (1.0 - 2.0 * m->poisson));
}

/* ---- 3×3 helpers of the energies alone (row-major; the common ones are core's dr_m3a_*) ------- */

/* d cof(A)[dA]: cof is quadratic in A, so its differential is the polarised form cof(A, dA). */
static void dcof3(const double A[9], const double dA[9], double out[9])
{
#define BIL(a, b, c, d) (A[a] * dA[b] + dA[a] * A[b] - A[c] * dA[d] - dA[c] * A[d])
    out[0] = BIL(4, 8, 5, 7);
    out[1] = BIL(5, 6, 3, 8);
    out[2] = BIL(3, 7, 4, 6);
    out[3] = BIL(2, 7, 1, 8);
    out[4] = BIL(0, 8, 2, 6);
    out[5] = BIL(1, 6, 0, 7);
    out[6] = BIL(1, 5, 2, 4);
    out[7] = BIL(2, 3, 0, 5);
    out[8] = BIL(0, 4, 1, 3);
#undef BIL
}

static void zero_z(int dim, double A[9])
{
    if (dim == 2) A[2] = A[5] = A[6] = A[7] = A[8] = 0.0;
}

/* ---- polar decomposition -------------------------------------------------------------------- */


static void swap_cols(double V[9], double e[3], int a, int b)
{
    double t = e[a];
    e[a] = e[b], e[b] = t;
    for (int k = 0; k < 3; k++) {
        t = V[3 * k + a];
        V[3 * k + a] = V[3 * k + b], V[3 * k + b] = t;
    }
}

/* F = U diag(sig) Vᵀ with U, V rotations, sig[0] >= sig[1] >= |sig[2]|, sign(sig[2]) = sign(det F). */
static void svd3(const double F[9], double U[9], double sig[3], double V[9])
{
    double A[9], e[3];
    dr_m3a_mul_tn(F, F, A);
    dr_m3a_sym_eigen(A, e, V);
    if (e[0] < e[1]) swap_cols(V, e, 0, 1);
    if (e[0] < e[2]) swap_cols(V, e, 0, 2);
    if (e[1] < e[2]) swap_cols(V, e, 1, 2);
    if (dr_m3a_det(V) < 0.0)
        for (int k = 0; k < 3; k++) V[3 * k + 2] = -V[3 * k + 2];
    double R[9];
    dr_m3a_mul(F, V, R);
    for (int k = 0; k < 9; k++) U[k] = (k % 4 == 0) ? 1.0 : 0.0;
    /* Givens QR: zero (1,0), (2,0), (2,1); U accumulates the transposed rotations so F V = U R. */
    static const int G[3][3] = {{0, 1, 0}, {0, 2, 0}, {1, 2, 1}};
    for (int g = 0; g < 3; g++) {
        int i = G[g][0], j = G[g][1], col = G[g][2];
        double a = R[3 * i + col], b = R[3 * j + col], r = hypot(a, b);
        double c = 1.0, s = 0.0;
        if (r > 0.0) c = a / r, s = b / r;
        for (int k = 0; k < 3; k++) {
            double ri = R[3 * i + k], rj = R[3 * j + k];
            R[3 * i + k] = c * ri + s * rj;
            R[3 * j + k] = -s * ri + c * rj;
        }
        for (int k = 0; k < 3; k++) {
            double ui = U[3 * k + i], uj = U[3 * k + j];
            U[3 * k + i] = c * ui + s * uj;
            U[3 * k + j] = -s * ui + c * uj;
        }
    }
    sig[0] = R[0], sig[1] = R[4], sig[2] = R[8];
}

void dr_mpm_polar_parts(int dim, const double F[9], DrMpmPolar *out)
{
    assert(dim == 2 || dim == 3);
    if (dim == 2) {
        /* the rotation maximising tr(RᵀF): angle of (F00 + F11, F10 − F01) */
        double a = F[0] + F[4], b = F[3] - F[1], r = hypot(a, b);
        double c = r > 0.0 ? a / r : 1.0, s = r > 0.0 ? b / r : 0.0;
        double Rr[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
        memcpy(out->R, Rr, sizeof Rr);
        memset(out->V, 0, sizeof out->V);
        memset(out->sig, 0, sizeof out->sig);
    } else {
        double U[9];
        svd3(F, U, out->sig, out->V);
        dr_m3a_mul_nt(U, out->V, out->R);
    }
}

void dr_mpm_polar(int dim, const double F[9], double R[9], double S[9])
{
    DrMpmPolar pol;
    dr_mpm_polar_parts(dim, F, &pol);
    memcpy(R, pol.R, sizeof pol.R);
    if (S) dr_m3a_mul_tn(R, F, S);
}

/* dR for F = R S: RᵀdR = [w]× with (tr S·I − S) w = axial(RᵀdF − dFᵀR), solved in the eigenbasis of S
   (the V of the SVD, in pol), where tr S·I − S is diagonal with entries σ_i + σ_j. A vanishing σ_i + σ_j (two
   singular values cancelling in an inverted element) makes dR singular; it is clamped to ±1e-12 of
   the largest singular value, a branch cut no smooth path crosses except through that set. */
static void polar_diff(int dim, const double F[9], const DrMpmPolar *pol, const double dF[9], double dR[9])
{
    if (dim == 2) {
        (void)pol;
        double a = F[0] + F[4], b = F[3] - F[1], r2 = a * a + b * b, r = sqrt(r2);
        double c = r > 0.0 ? a / r : 1.0, s = r > 0.0 ? b / r : 0.0;
        double da = dF[0] + dF[4], db = dF[3] - dF[1];
        double dth = r2 > 0.0 ? (a * db - b * da) / r2 : 0.0;
        double d[9] = {-s * dth, -c * dth, 0, c * dth, -s * dth, 0, 0, 0, 0};
        memcpy(dR, d, sizeof d);
        return;
    }
    const double *R = pol->R, *V = pol->V, *sig = pol->sig;
    double M[9];
    dr_m3a_mul_tn(R, dF, M);
    double a[3] = {M[7] - M[5], M[2] - M[6], M[3] - M[1]};
    double ap[3], w[3];
    for (int k = 0; k < 3; k++) ap[k] = V[k] * a[0] + V[3 + k] * a[1] + V[6 + k] * a[2]; /* Vᵀ a */
    double floor_ = 1e-12 * fmax(fabs(sig[0]), 1e-300);
    for (int k = 0; k < 3; k++) {
        double den = sig[(k + 1) % 3] + sig[(k + 2) % 3];
        if (fabs(den) < floor_) den = den < 0 ? -floor_ : floor_;
        ap[k] /= den;
    }
    for (int k = 0; k < 3; k++) w[k] = V[3 * k] * ap[0] + V[3 * k + 1] * ap[1] + V[3 * k + 2] * ap[2];
    double W[9] = {0, -w[2], w[1], w[2], 0, -w[0], -w[1], w[0], 0};
    dr_m3a_mul(R, W, dR);
}

/* ---- energy, stress, stress differential ------------------------------------------------------ */

bool dr_mpm_energy_density_polar(DrMpmModel model, int dim, double mu, double lambda, const double F[9],
                                 const DrMpmPolar *pol, double *psi)
{
    assert(dim == 2 || dim == 3);
    double J = dr_m3a_det(F);
    if (model == DR_MPM_NEOHOOKEAN) {
        if (!(J > 0.0)) return false;
        double lnJ = log(J);
        *psi = 0.5 * mu * (dr_m3a_ddot(F, F) - 3.0) - mu * lnJ + 0.5 * lambda * lnJ * lnJ;
        return isfinite(*psi);
    }
    DrMpmPolar own;
    if (!pol) dr_mpm_polar_parts(dim, F, &own), pol = &own;
    const double *R = pol->R;
    double s = 0.0;
    for (int k = 0; k < 9; k++) s += (F[k] - R[k]) * (F[k] - R[k]);
    *psi = mu * s + 0.5 * lambda * (J - 1.0) * (J - 1.0);
    return isfinite(*psi);
}

bool dr_mpm_energy_density(DrMpmModel model, int dim, double mu, double lambda, const double F[9], double *psi)
{
    return dr_mpm_energy_density_polar(model, dim, mu, lambda, F, NULL, psi);
}

bool dr_mpm_pk1_polar(DrMpmModel model, int dim, double mu, double lambda, const double F[9], const DrMpmPolar *pol,
                      double P[9])
{
    assert(dim == 2 || dim == 3);
    double C[9];
    dr_m3a_cofactor(F, C);
    double J = dr_m3a_det(F);
    if (model == DR_MPM_NEOHOOKEAN) {
        /* P = μ(F − F⁻ᵀ) + λ ln J F⁻ᵀ */
        if (!(J > 0.0)) return false;
        double lnJ = log(J), iJ = 1.0 / J;
        for (int k = 0; k < 9; k++) P[k] = mu * F[k] + (lambda * lnJ - mu) * iJ * C[k];
    } else {
        /* P = 2μ(F − R) + λ(J − 1) J F⁻ᵀ */
        DrMpmPolar own;
        if (!pol) dr_mpm_polar_parts(dim, F, &own), pol = &own;
        for (int k = 0; k < 9; k++) P[k] = 2.0 * mu * (F[k] - pol->R[k]) + lambda * (J - 1.0) * C[k];
    }
    zero_z(dim, P);
    for (int k = 0; k < 9; k++)
        if (!isfinite(P[k])) return false;
    return true;
}

bool dr_mpm_pk1(DrMpmModel model, int dim, double mu, double lambda, const double F[9], double P[9])
{
    return dr_mpm_pk1_polar(model, dim, mu, lambda, F, NULL, P);
}

bool dr_mpm_dpk1_polar(DrMpmModel model, int dim, double mu, double lambda, const double F[9], const DrMpmPolar *pol,
                       const double dF[9], double dP[9])
{
    assert(dim == 2 || dim == 3);
    double dFz[9];
    memcpy(dFz, dF, sizeof dFz);
    zero_z(dim, dFz);
    double C[9], dC[9];
    dr_m3a_cofactor(F, C);
    dcof3(F, dFz, dC);
    double J = dr_m3a_det(F), dJ = dr_m3a_ddot(C, dFz);
    if (model == DR_MPM_NEOHOOKEAN) {
        /* dP = μ dF + (μ − λ ln J) F⁻ᵀ dFᵀ F⁻ᵀ + λ tr(F⁻¹dF) F⁻ᵀ, written with F⁻ᵀ = cof/J:
           d(F⁻ᵀ) = dC/J − C dJ/J² */
        if (!(J > 0.0)) return false;
        double lnJ = log(J), iJ = 1.0 / J, dlnJ = dJ * iJ;
        double a = lambda * lnJ - mu;
        for (int k = 0; k < 9; k++)
            dP[k] = mu * dFz[k] + a * (dC[k] * iJ - C[k] * dJ * iJ * iJ) + lambda * dlnJ * iJ * C[k];
    } else {
        /* dP = 2μ(dF − dR) + λ dJ cof + λ(J − 1) d cof */
        DrMpmPolar own;
        if (!pol) dr_mpm_polar_parts(dim, F, &own), pol = &own;
        double dR[9];
        polar_diff(dim, F, pol, dFz, dR);
        for (int k = 0; k < 9; k++)
            dP[k] = 2.0 * mu * (dFz[k] - dR[k]) + lambda * dJ * C[k] + lambda * (J - 1.0) * dC[k];
    }
    zero_z(dim, dP);
    for (int k = 0; k < 9; k++)
        if (!isfinite(dP[k])) return false;
    return true;
}

bool dr_mpm_dpk1(DrMpmModel model, int dim, double mu, double lambda, const double F[9], const double dF[9],
                 double dP[9])
{
    return dr_mpm_dpk1_polar(model, dim, mu, lambda, F, NULL, dF, dP);
}
