/* Unit tests of src/bem/bem_kernel.c: wave speeds; the Laplace-domain kernels of BEM App. A against the printed
 * formulas evaluated in long double, their symmetry, the traction kernel against finite-difference tractions
 * of the displacement kernel (which fixes the index convention), the displacement kernel against the
 * Laplace-domain Navier equation, the Kelvin limits, continuity where the series hands over to the closed
 * forms, the batch routine and p_dyn; the body-force kernels against the volume integrals they replace
 * (BEM eq. 4); and the convolution-quadrature weights of BEM eq. 15 against the analytic BDF1 weights. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <complex.h>
#include <float.h>
#include <cmocka.h>

#include "bem/bem.h"
#include "bem/bem_internal.h"
#include "core/core.h"

/* ---- helpers ----------------------------------------------------------------------------------- */

static void le_or_fail(double a, double tol, const char *what, const char *file, int line)
{
    if (a <= tol) return;
    print_error("%s: %.3g > tol %.3g\n", what, a, tol);
    _fail(file, line);
}
#define assert_le(a, tol) le_or_fail((a), (tol), #a, __FILE__, __LINE__)

static double uni(DrRng *rng, double a, double b) { return a + (b - a) * dr_rng_uniform(rng); }

static void random_unit(DrRng *rng, double v[3])
{
    for (;;) {
        for (int k = 0; k < 3; k++) v[k] = uni(rng, -1, 1);
        double n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if (n > 0.1 && n <= 1.0) {
            for (int k = 0; k < 3; k++) v[k] /= n;
            return;
        }
    }
}

static double cmax(const double complex *a, int n)
{
    double m = 0.0;
    for (int k = 0; k < n; k++) m = fmax(m, cabs(a[k]));
    return m;
}

/* max |a − b| / max |b| */
static double crel(const double complex *a, const double complex *b, int n)
{
    double d = 0.0;
    for (int k = 0; k < n; k++) d = fmax(d, cabs(a[k] - b[k]));
    return d / cmax(b, n);
}

static double rmax(const double *a, int n)
{
    double m = 0.0;
    for (int k = 0; k < n; k++) m = fmax(m, fabs(a[k]));
    return m;
}

static DrBemWave make_wave(double rho, double mu, double nu)
{
    DrBemMaterial m = {.density = rho, .shear_modulus = mu, .poisson = nu};
    DrBemWave w;
    dr_bem_wave_init(&m, &w);
    return w;
}

/* Materials spanning κ = c2²/c1²: ν = 0.3 (steel-like ratio), 0.45 (rubber-like), 0 and −0.2. */
#define NMAT 4
static DrBemWave material(int k)
{
    static const double nu[NMAT] = {0.3, 0.45, 0.0, -0.2};
    static const double mu[NMAT] = {1e6, 3e5, 8e7, 1.0};
    static const double rho[NMAT] = {1000.0, 1100.0, 7800.0, 1.0};
    return make_wave(rho[k], mu[k], nu[k]);
}

/* s with |s r/c2| = zabs at angle theta from the positive real axis. */
static double complex s_for(const DrBemWave *w, double r, double zabs, double theta)
{
    return zabs * w->c2 / r * CMPLX(cos(theta), sin(theta));
}


/* ---- App. A as printed, in long double (reference) -------------------------------------------- */

typedef long double complex ldc;

static void lit_u(const DrBemWave *w, const double *rv, double complex s, double complex *out)
{
    long double r = sqrtl((long double)rv[0] * rv[0] + (long double)rv[1] * rv[1] + (long double)rv[2] * rv[2]);
    long double c1 = w->c1, c2 = w->c2, pi = 3.14159265358979323846264338327950288L;
    ldc S = s, e1 = cexpl(-r / c1 * S), e2 = cexpl(-r / c2 * S);
    ldc br = ((S * r / c1 + 1) * e1 - (S * r / c2 + 1) * e2) / (S * S);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            long double ri = rv[i], rj = rv[j], d = i == j;
            ldc v = (3 * ri * rj / powl(r, 5) - d / powl(r, 3)) * br +
                    ri * rj / powl(r, 3) * (e1 / (c1 * c1) - e2 / (c2 * c2)) + d / (r * c2 * c2) * e2;
            out[3 * i + j] = (double complex)(v / (4 * pi * (long double)w->rho));
        }
}

static void lit_p(const DrBemWave *w, const double *rv, const double *nv, double complex s, double complex *out)
{
    long double r = sqrtl((long double)rv[0] * rv[0] + (long double)rv[1] * rv[1] + (long double)rv[2] * rv[2]);
    long double c1 = w->c1, c2 = w->c2, pi = 3.14159265358979323846264338327950288L;
    long double rn = (long double)rv[0] * nv[0] + (long double)rv[1] * nv[1] + (long double)rv[2] * nv[2];
    ldc S = s, e1 = cexpl(-r / c1 * S), e2 = cexpl(-r / c2 * S);
    ldc br = e1 / (c1 * c1) * (c1 / (r * S) + c1 * c1 / (r * r * S * S)) -
             e2 / (c2 * c2) * (c2 / (r * S) + c2 * c2 / (r * r * S * S));
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            long double ri = rv[i], rj = rv[j], ni = nv[i], nj = nv[j], d = i == j, r2 = r * r, r3 = r2 * r;
            ldc t1 = 6 * c2 * c2 / r3 * (ri * nj + rj * ni + (d - 5 * ri * rj / r2) * rn) * br;
            ldc t2 = e1 / (r3 * c1 * c1) * (2 * c2 * c2 * (2 * ri * nj + rj * ni - (6 * ri * rj / r2 - d) * rn) - c1 * c1 * ri * nj);
            ldc t3 = e2 / r3 * (12 * ri * rj * rn / r2 - 2 * ri * nj - 3 * rj * ni - 3 * d * rn);
            ldc t4 = -e1 * S / (r2 * c1 * c1 * c1) * (c1 * c1 * ri * nj + 2 * c2 * c2 * (ri * rj * rn / r2 - ri * nj));
            ldc t5 = e2 * S / (r2 * c2) * (2 * ri * rj * rn / r2 - d * rn - rj * ni);
            out[3 * i + j] = (double complex)((t1 + t2 + t3 + t4 + t5) / (4 * pi));
        }
}

/* Kelvin traction kernel in long double (the reference for p_dyn = p̂ − p_static). */
static void lit_p_static(const DrBemWave *w, const double *rv, const double *nv, long double *out)
{
    long double r = sqrtl((long double)rv[0] * rv[0] + (long double)rv[1] * rv[1] + (long double)rv[2] * rv[2]);
    long double nu = w->nu, pi = 3.14159265358979323846264338327950288L, rh[3], rn = 0;
    for (int k = 0; k < 3; k++) rh[k] = rv[k] / r, rn += rh[k] * nv[k];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            out[3 * i + j] = -1 / (8 * pi * (1 - nu) * r * r) *
                             (rn * ((1 - 2 * nu) * (i == j) + 3 * rh[i] * rh[j]) - (1 - 2 * nu) * (rh[i] * nv[j] - rh[j] * nv[i]));
}

static void lit_p_dyn(const DrBemWave *w, const double *rv, const double *nv, double complex s, double complex *out)
{
    long double r = sqrtl((long double)rv[0] * rv[0] + (long double)rv[1] * rv[1] + (long double)rv[2] * rv[2]);
    long double c1 = w->c1, c2 = w->c2, pi = 3.14159265358979323846264338327950288L;
    long double rn = (long double)rv[0] * nv[0] + (long double)rv[1] * nv[1] + (long double)rv[2] * nv[2], st[9];
    lit_p_static(w, rv, nv, st);
    ldc S = s, e1 = cexpl(-r / c1 * S), e2 = cexpl(-r / c2 * S);
    ldc br = e1 / (c1 * c1) * (c1 / (r * S) + c1 * c1 / (r * r * S * S)) -
             e2 / (c2 * c2) * (c2 / (r * S) + c2 * c2 / (r * r * S * S));
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            long double ri = rv[i], rj = rv[j], ni = nv[i], nj = nv[j], d = i == j, r2 = r * r, r3 = r2 * r;
            ldc t1 = 6 * c2 * c2 / r3 * (ri * nj + rj * ni + (d - 5 * ri * rj / r2) * rn) * br;
            ldc t2 = e1 / (r3 * c1 * c1) * (2 * c2 * c2 * (2 * ri * nj + rj * ni - (6 * ri * rj / r2 - d) * rn) - c1 * c1 * ri * nj);
            ldc t3 = e2 / r3 * (12 * ri * rj * rn / r2 - 2 * ri * nj - 3 * rj * ni - 3 * d * rn);
            ldc t4 = -e1 * S / (r2 * c1 * c1 * c1) * (c1 * c1 * ri * nj + 2 * c2 * c2 * (ri * rj * rn / r2 - ri * nj));
            ldc t5 = e2 * S / (r2 * c2) * (2 * ri * rj * rn / r2 - d * rn - rj * ni);
            out[3 * i + j] = (double complex)((t1 + t2 + t3 + t4 + t5) / (4 * pi) - st[3 * i + j]);
        }
}

static void lit_d(const DrBemWave *w, const double *rv, const double *nv, double complex s, double complex *out)
{
    long double r = sqrtl((long double)rv[0] * rv[0] + (long double)rv[1] * rv[1] + (long double)rv[2] * rv[2]);
    long double c1 = w->c1, c2 = w->c2, pi = 3.14159265358979323846264338327950288L;
    long double rn = (long double)rv[0] * nv[0] + (long double)rv[1] * nv[1] + (long double)rv[2] * nv[2];
    ldc S = s, e1 = cexpl(-r / c1 * S), e2 = cexpl(-r / c2 * S), r3s2 = r * r * r * S * S;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            long double d = i == j;
            ldc v = rv[i] * (long double)nv[j] / r3s2 * ((S * r / c2 + 1) * e2 - (S * r / c1 + 1) * e1) +
                    d * rn / r3s2 * (1 - (S * r / c2 + 1) * e2);
            out[3 * i + j] = (double complex)(-v / (4 * pi));
        }
}

static void lit_l(const DrBemWave *w, const double *rv, const double *nv, double complex s, double complex *out)
{
    long double r = sqrtl((long double)rv[0] * rv[0] + (long double)rv[1] * rv[1] + (long double)rv[2] * rv[2]);
    long double c1 = w->c1, c2 = w->c2, pi = 3.14159265358979323846264338327950288L;
    ldc S = s, e1 = cexpl(-r / c1 * S), e2 = cexpl(-r / c2 * S), r3s2 = r * r * r * S * S;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
            long double ri = rv[i];
            ldc v = (ri * rv[j1] * (long double)nv[j2] - ri * rv[j2] * (long double)nv[j1]) / r3s2 *
                        ((S * r / c2 + 1) * e2 - (S * r / c1 + 1) * e1) +
                    ((long double)(i == j1) * nv[j2] - (long double)(i == j2) * nv[j1]) / (c2 * S) * e2;
            out[3 * i + j] = (double complex)(-v / (4 * pi));
        }
}

/* ---- wave speeds ---------------------------------------------------------------------------------- */

static void test_wave_init(void **state)
{
    (void)state;
    /* ν = 1/4 gives λ = μ and c1 = √3 c2; every quantity is a few roundings from exact. */
    DrBemWave w = make_wave(1200.0, 5e6, 0.25);
    assert_le(fabs(w.lambda / 5e6 - 1.0), 1e-15);
    assert_le(fabs(w.c2 / sqrt(5e6 / 1200.0) - 1.0), 1e-15);
    assert_le(fabs(w.c1 / (sqrt(3.0) * w.c2) - 1.0), 1e-15);
    assert_true(w.rho == 1200.0 && w.mu == 5e6 && w.nu == 0.25);
    /* ν = 0: λ = 0, c1² = 2 c2² */
    w = make_wave(1.0, 1.0, 0.0);
    assert_true(w.lambda == 0.0);
    assert_le(fabs(w.c1 * w.c1 - 2.0), 1e-15);
}

/* ---- kernels ---------------------------------------------------------------------------------------- */

/* The printed eqs. 16, 17, 19, 21 (long double, so their own 1/s² cancellation costs ≤ 1e-19/|z|² ≈ 1e-15 at
 * the smallest |z| = 0.01 used) against the rewritten forms, over four materials, |s r/c2| from 0.01 to 300
 * (both sides of the series switch, for both waves, and far out where both F_k tend to −1/(s r)² and only
 * their exponentially small difference is left) and arg s within ±86°. The rewritten forms carry a
 * cancellation of at most ~12 ulp in F near |z| = 0.5 and sums of O(10) terms, and at large |z| the phase of
 * e^{−z} inherits the rounding of z = s·r/c, |z|·ε ≈ 3e-14 at |z| = 300: observed ≤ 3e-14 relative to the
 * largest entry; the tolerance leaves a margin of ~7. */
static void test_kernel_literal(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 11);
    double worst[4] = {0};
    for (int m = 0; m < NMAT; m++) {
        DrBemWave w = material(m);
        for (int t = 0; t < 300; t++) {
            double rv[3], nv[3], rl = pow(10.0, uni(&rng, -2.0, 0.5));
            random_unit(&rng, rv), random_unit(&rng, nv);
            for (int k = 0; k < 3; k++) rv[k] *= rl;
            double complex s = s_for(&w, rl, pow(10.0, uni(&rng, -2.0, 2.5)), uni(&rng, -1.5, 1.5));
            double complex a[9], b[9];
            dr_bem_kernel_u(&w, rv, s, a), lit_u(&w, rv, s, b);
            worst[0] = fmax(worst[0], crel(a, b, 9));
            dr_bem_kernel_p(&w, rv, nv, s, a), lit_p(&w, rv, nv, s, b);
            worst[1] = fmax(worst[1], crel(a, b, 9));
            dr_bem_kernel_d(&w, rv, nv, s, a), lit_d(&w, rv, nv, s, b);
            worst[2] = fmax(worst[2], crel(a, b, 9));
            dr_bem_kernel_l(&w, rv, nv, s, a), lit_l(&w, rv, nv, s, b);
            worst[3] = fmax(worst[3], crel(a, b, 9));
        }
    }
    print_message("kernels vs printed App. A (long double): u %.2g, p %.2g, d %.2g, l %.2g\n", worst[0], worst[1],
                  worst[2], worst[3]);
    for (int k = 0; k < 4; k++) assert_le(worst[k], 2e-13);
}

/* û*(x, y) = û*(y, x) and û*_ij = û*_ji: the kernel is built from r̂_i r̂_j and δ_ij only, so both hold to the
 * last bit; 1e-15 relative allows a different rounding path without hiding an asymmetric term. */
static void test_kernel_symmetry(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 12);
    for (int m = 0; m < NMAT; m++) {
        DrBemWave w = material(m);
        for (int t = 0; t < 50; t++) {
            double rv[3], rm[3], rl = uni(&rng, 0.01, 3.0);
            random_unit(&rng, rv);
            for (int k = 0; k < 3; k++) rv[k] *= rl, rm[k] = -rv[k];
            double complex s = s_for(&w, rl, pow(10.0, uni(&rng, -3.0, 1.5)), uni(&rng, -1.5, 1.5));
            double complex a[9], b[9], at[9];
            dr_bem_kernel_u(&w, rv, s, a);
            dr_bem_kernel_u(&w, rm, s, b);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) at[3 * i + j] = a[3 * j + i];
            assert_le(crel(b, a, 9), 1e-15);
            assert_le(crel(at, a, 9), 1e-15);
        }
    }
}

/* Traction at y of the field v(y) = û*_{i·}(x, y) (load direction i) by fourth-order central differences:
 * t_j = σ_jk n_k, σ = λ tr ε I + 2μ ε. */
static void fd_traction(const DrBemWave *w, const double *rv, const double *nv, double complex s, double h, int i,
                        double complex t[3])
{
    double complex grad[3][3]; /* grad[m][k] = ∂v_m/∂y_k */
    static const double wt[4] = {1.0 / 12.0, -8.0 / 12.0, 8.0 / 12.0, -1.0 / 12.0};
    static const double off[4] = {-2.0, -1.0, 1.0, 2.0};
    for (int k = 0; k < 3; k++) {
        double complex acc[3] = {0};
        for (int q = 0; q < 4; q++) {
            double y[3] = {rv[0], rv[1], rv[2]};
            y[k] += off[q] * h;
            double complex u[9];
            dr_bem_kernel_u(w, y, s, u);
            for (int m = 0; m < 3; m++) acc[m] += wt[q] * u[3 * i + m];
        }
        for (int m = 0; m < 3; m++) grad[m][k] = acc[m] / h;
    }
    double complex tr = grad[0][0] + grad[1][1] + grad[2][2];
    for (int j = 0; j < 3; j++) {
        t[j] = 0.0;
        for (int k = 0; k < 3; k++) {
            double complex sig = w->mu * (grad[j][k] + grad[k][j]) + (j == k ? w->lambda * tr : 0.0);
            t[j] += sig * nv[k];
        }
    }
}

/* p̂* is the traction of û*: row i of dr_bem_kernel_p (the header's convention) equals σ(û*_{i·})n at y.
 * Step h = 1e-3 r/max(1, |z2|) keeps the fourth-order truncation near (1e-3)⁴·O(10²) ≈ 1e-10 (the fifth
 * derivatives of 1/r and of e^{−z}) and the round-off near ε·r/h ≈ 1e-13 relative to the traction; observed
 * ≤ 1e-10. The transpose misses by O(1), which the second assertion documents. */
static void test_kernel_traction_fd(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 13);
    static const double radii[3] = {0.05, 0.4, 2.5};
    static const double zs[6] = {1e-3, 0.1, 0.45, 0.7, 3.0, 8.0};
    double worst = 0.0, best_transposed = INFINITY;
    for (int m = 0; m < NMAT; m++) {
        DrBemWave w = material(m);
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 6; b++) {
                double rv[3], nv[3];
                random_unit(&rng, rv), random_unit(&rng, nv);
                for (int k = 0; k < 3; k++) rv[k] *= radii[a];
                double complex s = s_for(&w, radii[a], zs[b], uni(&rng, -1.4, 1.4));
                double h = 1e-3 * radii[a] / fmax(1.0, zs[b]);
                double complex p[9], t[9], pt[9];
                dr_bem_kernel_p(&w, rv, nv, s, p);
                for (int i = 0; i < 3; i++) fd_traction(&w, rv, nv, s, h, i, t + 3 * i);
                for (int i = 0; i < 3; i++)
                    for (int j = 0; j < 3; j++) pt[3 * i + j] = p[3 * j + i];
                worst = fmax(worst, crel(p, t, 9));
                best_transposed = fmin(best_transposed, crel(pt, t, 9));
            }
    }
    print_message("traction kernel vs FD traction of u: %.2g (transposed: %.2g at best)\n", worst, best_transposed);
    assert_le(worst, 1e-8);
    assert_true(best_transposed > 1e-3);
}

/* û*_{i·} solves the Laplace-domain Navier equation ρ s² v − μ∇²v − (λ + μ)∇∇·v = 0 away from x. Second
 * derivatives by Richardson-extrapolated central differences (h and h/2, error O(h⁴)) with
 * h = 4e-3 r/max(1, |z2|): truncation ~(h/r)⁴·O(10²) ≈ 3e-8 and round-off ~ε(r/h)²·10 ≈ 1e-10 relative to
 * the largest of the three terms; observed 6e-9. */
static void hessian(const DrBemWave *w, const double *rv, double complex s, double h, double complex H[3][3][9])
{
    double complex u0[9];
    dr_bem_kernel_u(w, rv, s, u0);
    for (int a = 0; a < 3; a++)
        for (int b = a; b < 3; b++) {
            double complex acc[9] = {0};
            if (a == b) {
                for (int q = -1; q <= 1; q += 2) {
                    double y[3] = {rv[0], rv[1], rv[2]};
                    y[a] += q * h;
                    double complex u[9];
                    dr_bem_kernel_u(w, y, s, u);
                    for (int e = 0; e < 9; e++) acc[e] += u[e];
                }
                for (int e = 0; e < 9; e++) acc[e] = (acc[e] - 2.0 * u0[e]) / (h * h);
            } else {
                for (int qa = -1; qa <= 1; qa += 2)
                    for (int qb = -1; qb <= 1; qb += 2) {
                        double y[3] = {rv[0], rv[1], rv[2]};
                        y[a] += qa * h, y[b] += qb * h;
                        double complex u[9];
                        dr_bem_kernel_u(w, y, s, u);
                        for (int e = 0; e < 9; e++) acc[e] += qa * qb * u[e];
                    }
                for (int e = 0; e < 9; e++) acc[e] /= 4.0 * h * h;
            }
            for (int e = 0; e < 9; e++) H[a][b][e] = H[b][a][e] = acc[e];
        }
}

static void test_kernel_navier(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 14);
    double worst = 0.0;
    static const double zs[5] = {1e-2, 0.3, 0.8, 2.0, 6.0};
    for (int m = 0; m < NMAT; m++) {
        DrBemWave w = material(m);
        for (int b = 0; b < 5; b++) {
            double rv[3], rl = uni(&rng, 0.1, 2.0);
            random_unit(&rng, rv);
            for (int k = 0; k < 3; k++) rv[k] *= rl;
            double complex s = s_for(&w, rl, zs[b], uni(&rng, -1.4, 1.4));
            double h = 4e-3 * rl / fmax(1.0, zs[b]);
            static double complex H1[3][3][9], H2[3][3][9];
            double complex u[9];
            hessian(&w, rv, s, h, H1);
            hessian(&w, rv, s, 0.5 * h, H2);
            dr_bem_kernel_u(&w, rv, s, u);
            for (int i = 0; i < 3; i++) {
                double complex res[3], t1[3], t2[3], t3[3];
                for (int mm = 0; mm < 3; mm++) {
                    double complex lap = 0.0, gd = 0.0;
                    for (int k = 0; k < 3; k++) {
                        lap += (4.0 * H2[k][k][3 * i + mm] - H1[k][k][3 * i + mm]) / 3.0;
                        gd += (4.0 * H2[mm][k][3 * i + k] - H1[mm][k][3 * i + k]) / 3.0;
                    }
                    t1[mm] = w.rho * s * s * u[3 * i + mm];
                    t2[mm] = -w.mu * lap;
                    t3[mm] = -(w.lambda + w.mu) * gd;
                    res[mm] = t1[mm] + t2[mm] + t3[mm];
                }
                double scale = fmax(cmax(t1, 3), fmax(cmax(t2, 3), cmax(t3, 3)));
                worst = fmax(worst, cmax(res, 3) / scale);
            }
        }
    }
    print_message("Navier residual of u: %.2g\n", worst);
    assert_le(worst, 1e-6);
}

/* |s| = 1e-7 c/r: û* differs from Kelvin by its O(z) rigid term (≈ 1e-7 relative), p̂* by O(z²) ≈ 1e-14; both
 * must be within 1e-6 of the closed forms, and p_dyn, O(z²), within 1e-12 of zero. */
static void test_kernel_static_limit(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 15);
    for (int m = 0; m < NMAT; m++) {
        DrBemWave w = material(m);
        for (int t = 0; t < 40; t++) {
            double rv[3], nv[3], rl = pow(10.0, uni(&rng, -3.0, 1.0));
            random_unit(&rng, rv), random_unit(&rng, nv);
            for (int k = 0; k < 3; k++) rv[k] *= rl;
            double complex s = s_for(&w, rl, 1e-7, uni(&rng, -1.5, 1.5));
            double complex u[9], p[9], pd[9], us[9], ps[9];
            double u0[9], p0[9];
            DrBemKernelOut o = {.u = u, .p = p, .p_dyn = pd};
            dr_bem_kernel_batch(&w, rv, nv, 1, &s, &o);
            dr_bem_kernel_u_static(&w, rv, u0);
            dr_bem_kernel_p_static(&w, rv, nv, p0);
            for (int e = 0; e < 9; e++) us[e] = u0[e], ps[e] = p0[e];
            assert_le(crel(u, us, 9), 1e-6);
            assert_le(crel(p, ps, 9), 1e-6);
            assert_le(cmax(pd, 9) / rmax(p0, 9), 1e-12);
        }
    }
}

/* Either side of |z| = 0.5 (the series' limit), for z1 and for z2 in turn, every output agrees with the printed
 * formulas in long double (whose own cancellation is ≤ 1e-19/|z|⁴·O(30) ≈ 1e-16 there) to the accuracy of the
 * closed forms at the switch: ≈ 12 ulp for F, summed into O(10) terms, and ≈ 240 ulp for the O(z²) parts of
 * p_dyn (G5 = −30F − (12 + 2z)e^{−z} − 3 ≈ −z²/4 from terms of size 15). Observed ≤ 1.1e-14 for u, p, d, l and
 * ≤ 1.1e-13 for p_dyn; the tolerances leave a margin of ~10. (The two sides are not compared
 * with each other: the kernels change by |z|·δs/s ≈ 1e-13 between them, above the round-off sought.) */
static void test_kernel_switch_continuity(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 16);
    double worst = 0.0, worst_dyn = 0.0;
    for (int m = 0; m < NMAT; m++) {
        DrBemWave w = material(m);
        for (int t = 0; t < 40; t++) {
            double rv[3], nv[3], rl = uni(&rng, 0.05, 2.0);
            random_unit(&rng, rv), random_unit(&rng, nv);
            for (int k = 0; k < 3; k++) rv[k] *= rl;
            double c = t % 2 ? w.c1 : w.c2, th = uni(&rng, -1.5, 1.5);
            double complex s[2];
            s[0] = 0.5 * (1.0 - 1e-13) * c / rl * CMPLX(cos(th), sin(th));
            s[1] = 0.5 * (1.0 + 1e-13) * c / rl * CMPLX(cos(th), sin(th));
            double z0 = cabs(s[0] * (rl / c)), z1 = cabs(s[1] * (rl / c));
            assert_true(z0 * z0 < 0.25 && z1 * z1 >= 0.25);
            double complex u[18], p[18], pd[18], d[18], l[18], ref[9];
            DrBemKernelOut o = {.u = u, .p = p, .p_dyn = pd, .d = d, .l = l};
            dr_bem_kernel_batch(&w, rv, nv, 2, s, &o);
            for (int k = 0; k < 2; k++) {
                lit_u(&w, rv, s[k], ref);
                worst = fmax(worst, crel(u + 9 * k, ref, 9));
                lit_p(&w, rv, nv, s[k], ref);
                worst = fmax(worst, crel(p + 9 * k, ref, 9));
                lit_d(&w, rv, nv, s[k], ref);
                worst = fmax(worst, crel(d + 9 * k, ref, 9));
                lit_l(&w, rv, nv, s[k], ref);
                worst = fmax(worst, crel(l + 9 * k, ref, 9));
                lit_p_dyn(&w, rv, nv, s[k], ref);
                worst_dyn = fmax(worst_dyn, crel(pd + 9 * k, ref, 9));
            }
        }
    }
    print_message("series/closed-form switch, both sides vs long double: %.2g (p_dyn %.2g)\n", worst, worst_dyn);
    assert_le(worst, 1e-13);
    assert_le(worst_dyn, 1e-12);
}

/* The batch routine gives every kernel for ns values of s: the same numbers as the single functions (the same
 * operations, so bit-identical; 1e-15 allows a compiler's reordering). p_dyn against p̂ − p_static formed
 * in long double from the printed eq. 17 for |z2| in [0.2, 5]: the reference loses 1/|z1|² in the 1/s² bracket
 * and another 1/|z|² in the subtraction, ≤ 1e-19/|z1|⁴·O(30) ≈ 2e-13 of |p_dyn| at |z1| = 0.06 (observed
 * 6e-14, tolerance 1e-11); and at |z2| = 1e-6, out of the reference's reach, against its
 * leading Taylor term z2²[(−3κ²/4 + κ/2 − 1/4) r̂_i n_j + (κ² + 1)/4 (r̂_j n_i + δ_ij ∂r/∂n)
 * + (1 − κ²)/4 r̂_i r̂_j ∂r/∂n]/(4π r²) to O(z) ≈ 1e-6. */
static void test_kernel_batch(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 17);
    enum { NS = 7 };
    double worst_dyn = 0.0;
    for (int m = 0; m < NMAT; m++) {
        DrBemWave w = material(m);
        for (int t = 0; t < 30; t++) {
            double rv[3], nv[3], rl = pow(10.0, uni(&rng, -2.0, 0.5));
            random_unit(&rng, rv), random_unit(&rng, nv);
            for (int k = 0; k < 3; k++) rv[k] *= rl;
            double complex s[NS];
            for (int k = 0; k < NS; k++) s[k] = s_for(&w, rl, pow(10.0, uni(&rng, -0.7, 0.7)), uni(&rng, -1.5, 1.5));
            double complex u[9 * NS], p[9 * NS], pd[9 * NS], d[9 * NS], l[9 * NS], a[9], ref[9];
            DrBemKernelOut o = {.u = u, .p = p, .p_dyn = pd, .d = d, .l = l};
            dr_bem_kernel_batch(&w, rv, nv, NS, s, &o);
            for (int k = 0; k < NS; k++) {
                dr_bem_kernel_u(&w, rv, s[k], a);
                assert_le(crel(u + 9 * k, a, 9), 1e-15);
                dr_bem_kernel_p(&w, rv, nv, s[k], a);
                assert_le(crel(p + 9 * k, a, 9), 1e-15);
                dr_bem_kernel_d(&w, rv, nv, s[k], a);
                assert_le(crel(d + 9 * k, a, 9), 1e-15);
                dr_bem_kernel_l(&w, rv, nv, s[k], a);
                assert_le(crel(l + 9 * k, a, 9), 1e-15);
                lit_p_dyn(&w, rv, nv, s[k], ref);
                worst_dyn = fmax(worst_dyn, crel(pd + 9 * k, ref, 9));
            }
            /* only p_dyn asked for: the same numbers */
            double complex pd2[9 * NS];
            DrBemKernelOut o2 = {.p_dyn = pd2};
            dr_bem_kernel_batch(&w, rv, nv, NS, s, &o2);
            assert_le(crel(pd2, pd, 9 * NS), 1e-15);

            /* leading order at tiny z */
            double complex s0 = s_for(&w, rl, 1e-6, uni(&rng, -1.5, 1.5)), z2 = s0 * rl / w.c2;
            double kap = w.mu / (w.lambda + 2.0 * w.mu), rh[3], rn = 0.0;
            for (int k = 0; k < 3; k++) rh[k] = rv[k] / rl, rn += rh[k] * nv[k];
            double bp = -0.75 * kap * kap + 0.5 * kap - 0.25, bq = 0.25 * (kap * kap + 1.0), bm = 0.25 * (1.0 - kap * kap);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    ref[3 * i + j] = z2 * z2 / (4.0 * DR_PI * rl * rl) *
                                     (bp * rh[i] * nv[j] + bq * (rh[j] * nv[i] + (i == j) * rn) + bm * rh[i] * rh[j] * rn);
            DrBemKernelOut o3 = {.p_dyn = a};
            dr_bem_kernel_batch(&w, rv, nv, 1, &s0, &o3);
            assert_le(crel(a, ref, 9), 1e-5);
        }
    }
    print_message("p_dyn vs long-double p - p_static: %.2g\n", worst_dyn);
    assert_le(worst_dyn, 1e-11);

    /* ns = 0 and NULL outputs write nothing */
    DrBemWave w = material(0);
    double rv[3] = {0.1, 0.2, 0.3}, nv[3] = {0, 0, 1};
    double complex u[9], s = 1.0;
    for (int e = 0; e < 9; e++) u[e] = 42.0;
    DrBemKernelOut o = {.u = u};
    dr_bem_kernel_batch(&w, rv, nv, 0, &s, &o);
    for (int e = 0; e < 9; e++) assert_true(u[e] == 42.0);
    DrBemKernelOut none = {0};
    dr_bem_kernel_batch(&w, rv, nv, 1, &s, &none);
}

/* ---- body-force kernels (BEM eq. 4) --------------------------------------------------------------- */

/* Gauss–Legendre nodes and weights on [0, 1] (Newton on P_n). */
static void gauss_legendre01(int n, double *x, double *wt)
{
    for (int i = 0; i < n; i++) {
        double t = cos(DR_PI * (i + 0.75) / (n + 0.5)), dp = 0.0;
        for (int it = 0; it < 100; it++) {
            double p0 = 1.0, p1 = t;
            for (int k = 2; k <= n; k++) {
                double p2 = ((2 * k - 1) * t * p1 - (k - 1) * p0) / k;
                p0 = p1, p1 = p2;
            }
            dp = n * (t * p1 - p0) / (t * t - 1.0);
            double dt = p1 / dp;
            t -= dt;
            if (fabs(dt) < 1e-16) break;
        }
        x[i] = 0.5 * (1.0 - t);
        wt[i] = 1.0 / ((1.0 - t * t) * dp * dp);
    }
}

/* [a]×ᵀ (row-major) */
static void cross_t(const double a[3], double m[9])
{
    m[0] = 0.0, m[1] = a[2], m[2] = -a[1];
    m[3] = -a[2], m[4] = 0.0, m[5] = a[0];
    m[6] = a[1], m[7] = -a[0], m[8] = 0.0;
}

enum { BF_NS = 5 };

/* −ρ û*(x, y) w and −ρ û*(x, y)[y − x̄]×ᵀ w added to Vu, Vq for each s. */
static void body_volume_point(const DrBemWave *w, const double *x, const double *xbar, const double *y, double wq,
                              const double complex *s, double complex *Vu, double complex *Vq)
{
    double rv[3] = {y[0] - x[0], y[1] - x[1], y[2] - x[2]}, yc[3] = {y[0] - xbar[0], y[1] - xbar[1], y[2] - xbar[2]};
    double Y[9];
    cross_t(yc, Y);
    double complex u[9 * BF_NS];
    DrBemKernelOut o = {.u = u};
    dr_bem_kernel_batch(w, rv, rv, BF_NS, s, &o);
    for (int k = 0; k < BF_NS; k++)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double complex uy = 0.0;
                for (int t = 0; t < 3; t++) uy += u[9 * k + 3 * i + t] * Y[3 * t + j];
                Vu[9 * k + 3 * i + j] += -w->rho * wq * u[9 * k + 3 * i + j];
                Vq[9 * k + 3 * i + j] += -w->rho * wq * uy;
            }
}

/* For x outside and inside the unit cube Ω: ∫_Γ d̂* dΓ = −ρ ∫_Ω û* dΩ and ∫_Γ q̂* dΓ = −ρ ∫_Ω û* [y − x̄]×ᵀ dΩ
 * with q̂* = l̂* + d̂* [x − x̄]×ᵀ (eqs. 4, 19–21, b = −ρa − ρ[y − x̄]×ᵀα). Faces: 2×2 panels of 16-point
 * Gauss–Legendre per direction; the integrands are analytic on each panel, the nearest complex singularity
 * (x at distance ≥ 0.3 from a panel of size 0.5) giving ρ_Bernstein ≥ 2.7 and an error ≤ 2.7^{−32} ≈ 1e-14.
 * Volume, 16-point Gauss–Legendre per direction: outside, over the cube (x at distance 1.5: ρ ≥ 7.9, error
 * ~1e-28); inside, over the cube split at x into 8 boxes and each box into the 3 pyramids with apex x over its
 * far faces, y = x + t(p − x), dΩ = h t² dt dA_p, which cancels the 1/r of û* so that the rule again
 * converges spectrally (9e-13 with 12 points, 2e-14 with 16). So the comparison is limited by round-off:
 * observed ≤ 2e-14 for d̂* (tolerance 1e-13). For q̂* the 1/s term of l̂*, (e_i × n)_j e^{−z2}/(4π c2 s), is ~5000 times the result at
 * s = 0.01 c2 and cancels over the closed surface (∫_Γ n dΓ = 0 at leading order), which costs ~5000 ulp:
 * observed ≤ 7e-12, tolerance 1e-10. s spans the series (|z| < 0.5) and closed-form regions and complex
 * phases. */
static void test_body_force(void **state)
{
    (void)state;
    enum { NG = 16, NF = 16 };
    double gx[NG], gw[NG], fx[NF], fw[NF];
    gauss_legendre01(NG, gx, gw);
    gauss_legendre01(NF, fx, fw);
    const double xs[2][3] = {{2.5, 0.3, 0.7}, {0.4, 0.55, 0.3}}, xbar[3] = {0.5, 0.5, 0.5};
    double worst_d = 0.0, worst_q = 0.0;
    for (int m = 0; m < 2; m++)
        for (int xi = 0; xi < 2; xi++) {
            const double *x = xs[xi];
            DrBemWave w = m == 0 ? make_wave(1.0, 1.0, 0.3) : make_wave(2.0, 1.0, 0.45);
            const double complex s[BF_NS] = {0.01 * w.c2, 0.2 * w.c2, CMPLX(0.3, 0.5) * w.c2, CMPLX(2.0, 3.0) * w.c2,
                                             CMPLX(0.05, -2.0) * w.c2};
            double complex Sd[9 * BF_NS] = {0}, Sl[9 * BF_NS] = {0}, Vu[9 * BF_NS] = {0}, Vq[9 * BF_NS] = {0};
            /* surface: six faces of 2×2 panels, outward normals */
            for (int ax = 0; ax < 3; ax++)
                for (int side = 0; side < 2; side++)
                    for (int pa = 0; pa < 2; pa++)
                        for (int pb = 0; pb < 2; pb++) {
                            double nv[3] = {0, 0, 0};
                            nv[ax] = side ? 1.0 : -1.0;
                            int a1 = (ax + 1) % 3, a2 = (ax + 2) % 3;
                            for (int p = 0; p < NF; p++)
                                for (int q = 0; q < NF; q++) {
                                    double y[3];
                                    y[ax] = side, y[a1] = 0.5 * (pa + fx[p]), y[a2] = 0.5 * (pb + fx[q]);
                                    double rv[3] = {y[0] - x[0], y[1] - x[1], y[2] - x[2]}, wq = 0.25 * fw[p] * fw[q];
                                    double complex d[9 * BF_NS], l[9 * BF_NS];
                                    DrBemKernelOut o = {.d = d, .l = l};
                                    dr_bem_kernel_batch(&w, rv, nv, BF_NS, s, &o);
                                    for (int e = 0; e < 9 * BF_NS; e++) Sd[e] += wq * d[e], Sl[e] += wq * l[e];
                                }
                        }
            if (xi == 0) {
                for (int a = 0; a < NG; a++)
                    for (int b = 0; b < NG; b++)
                        for (int c = 0; c < NG; c++) {
                            double y[3] = {gx[a], gx[b], gx[c]};
                            body_volume_point(&w, x, xbar, y, gw[a] * gw[b] * gw[c], s, Vu, Vq);
                        }
            } else {
                for (int oct = 0; oct < 8; oct++) {
                    double cc[3] = {oct & 1 ? 1.0 : 0.0, oct & 2 ? 1.0 : 0.0, oct & 4 ? 1.0 : 0.0};
                    for (int ax = 0; ax < 3; ax++) { /* pyramid over the box face y_ax = cc[ax] */
                        int a1 = (ax + 1) % 3, a2 = (ax + 2) % 3;
                        double h = fabs(cc[ax] - x[ax]), area = fabs(cc[a1] - x[a1]) * fabs(cc[a2] - x[a2]);
                        for (int a = 0; a < NG; a++)
                            for (int b = 0; b < NG; b++)
                                for (int c = 0; c < NG; c++) {
                                    double pf[3], t = gx[a], y[3];
                                    pf[ax] = cc[ax];
                                    pf[a1] = x[a1] + gx[b] * (cc[a1] - x[a1]);
                                    pf[a2] = x[a2] + gx[c] * (cc[a2] - x[a2]);
                                    for (int k = 0; k < 3; k++) y[k] = x[k] + t * (pf[k] - x[k]);
                                    double wq = gw[a] * gw[b] * gw[c] * h * area * t * t;
                                    body_volume_point(&w, x, xbar, y, wq, s, Vu, Vq);
                                }
                    }
                }
            }
            double xc[3] = {x[0] - xbar[0], x[1] - xbar[1], x[2] - xbar[2]}, Xc[9];
            cross_t(xc, Xc);
            for (int k = 0; k < BF_NS; k++) {
                double complex Sq[9];
                for (int i = 0; i < 3; i++)
                    for (int j = 0; j < 3; j++) {
                        double complex dx = 0.0;
                        for (int t = 0; t < 3; t++) dx += Sd[9 * k + 3 * i + t] * Xc[3 * t + j];
                        Sq[3 * i + j] = Sl[9 * k + 3 * i + j] + dx;
                    }
                double ed = crel(Sd + 9 * k, Vu + 9 * k, 9), eq = crel(Sq, Vq + 9 * k, 9);
                worst_d = fmax(worst_d, ed);
                worst_q = fmax(worst_q, eq);
            }
        }
    print_message("body force: surface d vs volume u %.2g, surface q vs volume u[y-xbar]x^T %.2g\n", worst_d, worst_q);
    assert_le(worst_d, 1e-13);
    assert_le(worst_q, 1e-10);
}

/* ---- convolution quadrature ------------------------------------------------------------------------ */

static void test_cq_init(void **state)
{
    (void)state;
    DrError err;
    DrBemCq cq;
    /* bad input: the status, a message naming the value, nothing allocated */
    assert_int_equal(dr_bem_cq_init(0, 1e-10, 1e-3, &cq, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "L = 0"));
    assert_null(cq.s);
    assert_int_equal(dr_bem_cq_init(8, 0.0, 1e-3, &cq, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "eps"));
    assert_int_equal(dr_bem_cq_init(8, 1.0, 1e-3, &cq, &err), DR_ERR_INPUT);
    assert_int_equal(dr_bem_cq_init(8, 1e-10, 0.0, &cq, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "dt = 0"));
    assert_int_equal(dr_bem_cq_init(8, 1e-10, NAN, &cq, &err), DR_ERR_INPUT);
    assert_null(cq.s);
    dr_bem_cq_free(&cq);
    dr_bem_cq_free(NULL);

    /* s_l = (1 − R e^{2πil/L})/Δt to round-off, exact conjugate pairs, Re s > 0 */
    static const int Ls[5] = {1, 2, 7, 16, 301};
    for (int t = 0; t < 5; t++) {
        int L = Ls[t];
        double dt = 2.5e-4, eps = 1e-10;
        assert_int_equal(dr_bem_cq_init(L, eps, dt, &cq, &err), DR_OK);
        assert_int_equal(cq.L, L);
        assert_le(fabs(cq.R - pow(eps, 1.0 / (2 * L))), 1e-15);
        for (int l = 0; l < L; l++) {
            double complex ref = (1.0 - cq.R * cexp(2.0 * DR_PI * I * l / L)) / dt;
            assert_le(cabs(cq.s[l] - ref) * dt, 4e-15); /* a few ulp of |1 − Rζ| ≤ 2 */
            assert_true(creal(cq.s[l]) > 0.0);
            if (l > 0) assert_true(cq.s[L - l] == conj(cq.s[l]));
        }
        assert_true(cimag(cq.s[0]) == 0.0);
        if (L % 2 == 0) assert_true(cimag(cq.s[L / 2]) == 0.0);
        dr_bem_cq_free(&cq);
        assert_null(cq.s);
    }
}

static double ln_fact(int n) { return lgamma(n + 1.0); }

/* e^{−sτ}: the generating function f̂((1 − ζ)/Δt) = e^{−τ'} e^{τ'ζ} gives the BDF1 weights e^{−τ'}τ'ⁿ/n!,
 * τ' = τ/Δt. These decay, so the L-point DFT on |ζ| = R returns them up to the aliased tail
 * Σ_{j≥1} ψ_{k+jL} R^{jL} (negligible for τ' well below L) and round-off amplified by R^{−k} ≤ ε^{−1/2} = 1e5:
 * ≤ 1e-11 of max ψ expected, 1e-8 required. The half-spectrum routine sums the same terms in another order
 * and agrees to that round-off: Horner's sum of L terms carries ~L ulp of max|f̂| ≤ 1, amplified by
 * R^{−k} ≤ ε^{−1/2}; the tolerance is L·DBL_EPSILON/√ε (observed 5e-12 of max ψ at L = 64, tolerance 1.4e-9). */
static void test_cq_exp(void **state)
{
    (void)state;
    static const double taus[5] = {0.0, 0.5, 3.0, 10.0, 25.0};
    static const int Ls[5] = {4, 8, 16, 40, 64};
    double dt = 1e-3, worst = 0.0, worst_half = 0.0;
    for (int t = 0; t < 5; t++) {
        int L = Ls[t];
        DrBemCq cq;
        DrError err;
        assert_int_equal(dr_bem_cq_init(L, 1e-10, dt, &cq, &err), DR_OK);
        double complex f[64];
        double psi[64], half[64], ex[64];
        for (int l = 0; l < L; l++) f[l] = cexp(-cq.s[l] * taus[t] * dt);
        dr_bem_cq_weights(&cq, f, psi);
        dr_bem_cq_weights_half(&cq, f, half);
        for (int k = 0; k < L; k++) ex[k] = taus[t] == 0.0 ? (k == 0) : exp(-taus[t] + k * log(taus[t]) - ln_fact(k));
        double mx = rmax(ex, L), e = 0.0, eh = 0.0;
        for (int k = 0; k < L; k++) e = fmax(e, fabs(psi[k] - ex[k])), eh = fmax(eh, fabs(half[k] - psi[k]));
        worst = fmax(worst, e / mx), worst_half = fmax(worst_half, eh / mx);
        dr_bem_cq_free(&cq);
    }
    print_message("CQ e^{-s tau}: %.2g of max psi (half vs full %.2g)\n", worst, worst_half);
    assert_le(worst, 1e-8);
    assert_le(worst_half, 64 * DBL_EPSILON / sqrt(1e-10));
}

/* 1/s and 1/s²: ψ_n = Δt and (n + 1)Δt² never decay, so the DFT returns the aliased sums (q = R^L = √ε)
 *   Δt/(1 − q)   and   Δt²[(k + 1)/(1 − q) + L q/(1 − q)²],
 * matched to round-off (≤ 1e-8 relative required; R^{−k} ≤ 1e5 amplifies ~1e-16). Against the plain weights the
 * error is the aliasing level: q/(1 − q) of Δt for 1/s (asserted ≤ 2√ε), and (2q + 3q² + …) of max ψ = LΔt² at
 * k = L − 1 for 1/s² (asserted ≤ 2√ε(1 + 2√ε)); both also ≥ √ε/2, so the test sees the aliasing it documents.
 * Half against full spectrum: L·DBL_EPSILON/√ε as in test_cq_exp (observed 1.1e-10 at L = 200). */
static void test_cq_aliased(void **state)
{
    (void)state;
    static const int Ls[6] = {1, 2, 3, 10, 32, 200};
    double dt = 0.02, eps = 1e-10, q = sqrt(eps);
    for (int t = 0; t < 6; t++) {
        int L = Ls[t];
        DrBemCq cq;
        DrError err;
        assert_int_equal(dr_bem_cq_init(L, eps, dt, &cq, &err), DR_OK);
        double complex f1[200], f2[200];
        double p1[200], p2[200], h1[200], h2[200];
        for (int l = 0; l < L; l++) f1[l] = 1.0 / cq.s[l], f2[l] = 1.0 / (cq.s[l] * cq.s[l]);
        dr_bem_cq_weights(&cq, f1, p1);
        dr_bem_cq_weights(&cq, f2, p2);
        dr_bem_cq_weights_half(&cq, f1, h1);
        dr_bem_cq_weights_half(&cq, f2, h2);
        double e1 = 0, e2 = 0, a1 = 0, a2 = 0, eh = 0;
        for (int k = 0; k < L; k++) {
            double al1 = dt / (1.0 - q), al2 = dt * dt * ((k + 1) / (1.0 - q) + L * q / ((1.0 - q) * (1.0 - q)));
            e1 = fmax(e1, fabs(p1[k] - al1) / al1);
            e2 = fmax(e2, fabs(p2[k] - al2) / al2);
            a1 = fmax(a1, fabs(p1[k] - dt) / dt);
            a2 = fmax(a2, fabs(p2[k] - (k + 1) * dt * dt) / (L * dt * dt));
            eh = fmax(eh, fmax(fabs(h1[k] - p1[k]) / dt, fabs(h2[k] - p2[k]) / (L * dt * dt)));
        }
        assert_le(e1, 1e-8);
        assert_le(e2, 1e-8);
        assert_le(a1, 2.0 * q);
        assert_le(a2, 2.0 * q * (1.0 + 2.0 * q));
        assert_true(a1 >= 0.5 * q && a2 >= 0.5 * q);
        assert_le(eh, L * DBL_EPSILON / q);
        dr_bem_cq_free(&cq);
    }
}

/* PHYSICS §7: weights of e^{−s r/c}/r with L = n_max = ⌊τ + 2⌋, τ = r/(cΔt), are e^{−τ}τⁿ/(n!·r) up to
 * aliasing. With L this short the tail does not vanish, so the exact statement is
 * ψ̃_k = Σ_j ψ_{k+jL} q^j (matched to 1e-10 of max ψ: round-off ~1e-16·R^{−k}), and the distance to the plain
 * weights is ≤ q/(1 − q)·max ψ ≤ 2√ε of max ψ. */
static void test_cq_scalar_kernel(void **state)
{
    (void)state;
    static const double rs[3] = {0.05, 0.37, 1.3};
    double c = 120.0, dt = 1e-3, eps = 1e-10, q = sqrt(eps);
    for (int t = 0; t < 3; t++) {
        double r = rs[t], tau = r / (c * dt);
        int L = (int)floor(tau + 2.0);
        DrBemCq cq;
        DrError err;
        assert_int_equal(dr_bem_cq_init(L, eps, dt, &cq, &err), DR_OK);
        double complex f[32];
        double psi[32], plain[32], alias[32];
        for (int l = 0; l < L; l++) f[l] = cexp(-cq.s[l] * r / c) / r;
        dr_bem_cq_weights(&cq, f, psi);
        for (int k = 0; k < L; k++) {
            plain[k] = exp(-tau + k * log(tau) - ln_fact(k)) / r;
            alias[k] = 0.0;
            for (int j = 0; j < 60; j++) alias[k] += exp(-tau + (k + j * L) * log(tau) - ln_fact(k + j * L)) / r * pow(q, j);
        }
        double mx = rmax(plain, L), ea = 0.0, ep = 0.0;
        for (int k = 0; k < L; k++) ea = fmax(ea, fabs(psi[k] - alias[k])), ep = fmax(ep, fabs(psi[k] - plain[k]));
        assert_le(ea / mx, 1e-10);
        assert_le(ep / mx, 2.0 * q);
        dr_bem_cq_free(&cq);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_wave_init),
        cmocka_unit_test(test_kernel_literal),
        cmocka_unit_test(test_kernel_symmetry),
        cmocka_unit_test(test_kernel_traction_fd),
        cmocka_unit_test(test_kernel_navier),
        cmocka_unit_test(test_kernel_static_limit),
        cmocka_unit_test(test_kernel_switch_continuity),
        cmocka_unit_test(test_kernel_batch),
        cmocka_unit_test(test_body_force),
        cmocka_unit_test(test_cq_init),
        cmocka_unit_test(test_cq_exp),
        cmocka_unit_test(test_cq_aliased),
        cmocka_unit_test(test_cq_scalar_kernel),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
