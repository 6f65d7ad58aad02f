/* drench cloth: the discrete-shell kernels of one triangle and one hinge (shell.h; PHYSICS §4 "Shells").
 *
 * The hinge gradient is the classical one (Bridson et al. 2003, "Simulation of clothing with folds and wrinkles";
 * Tamstorf and Grinspun 2013): a wing vertex moved along its triangle's normal turns the triangle about the edge by
 * its displacement over the wing's height; the edge vertices take what keeps the sum zero and the hinge invariant to
 * rotation about the edge. test_cloth checks it against central differences. */
#include "cloth/shell.h"

#include <math.h>
#include <string.h>

static inline DrVec3 ld3(const double *p) { return dr_v3(p[0], p[1], p[2]); }

bool dr_shell_rest(const double *X0, const double *X1, const double *X2, double Bm[4], double *area)
{
    DrVec3 a = dr_v3_sub(ld3(X1), ld3(X0)), b = dr_v3_sub(ld3(X2), ld3(X0));
    DrVec3 N = dr_v3_cross(a, b);
    double nN = dr_v3_norm(N), la = dr_v3_norm(a);
    double lmax = fmax(la, fmax(dr_v3_norm(b), dr_v3_norm(dr_v3_sub(b, a))));
    *area = 0.5 * nN;
    if (!(nN > 1e-14 * lmax * lmax) || !(la > 0)) {
        memset(Bm, 0, 4 * sizeof(double));
        return false;
    }
    DrVec3 e1 = dr_v3_scale(a, 1.0 / la);
    DrVec3 e2 = dr_v3_cross(dr_v3_scale(N, 1.0 / nN), e1);
    /* Dm = [a·e1 b·e1; 0 b·e2] (a·e2 = 0), inverted */
    double d00 = la, d01 = dr_v3_dot(b, e1), d11 = dr_v3_dot(b, e2);
    Bm[0] = 1.0 / d00;
    Bm[1] = -d01 / (d00 * d11);
    Bm[2] = 0.0;
    Bm[3] = 1.0 / d11;
    return true;
}

/* The coefficients c[i][a] with f_a = Σ_i c[i][a] x_i the columns of F. */
static void coefficients(const double Bm[4], double c[3][2])
{
    for (int a = 0; a < 2; a++) {
        c[1][a] = Bm[a];
        c[2][a] = Bm[2 + a];
        c[0][a] = -(Bm[a] + Bm[2 + a]);
    }
}

static void columns(const double *x0, const double *x1, const double *x2, const double c[3][2], DrVec3 f[2])
{
    const double *x[3] = {x0, x1, x2};
    for (int a = 0; a < 2; a++) {
        f[a] = dr_v3(0, 0, 0);
        for (int i = 0; i < 3; i++) f[a] = dr_v3_add(f[a], dr_v3_scale(ld3(x[i]), c[i][a]));
    }
}

void dr_shell_green(const double *x0, const double *x1, const double *x2, const double Bm[4], double E[3])
{
    double c[3][2];
    DrVec3 f[2];
    coefficients(Bm, c);
    columns(x0, x1, x2, c, f);
    E[0] = 0.5 * (dr_v3_dot(f[0], f[0]) - 1.0);
    E[1] = 0.5 * (dr_v3_dot(f[1], f[1]) - 1.0);
    E[2] = 0.5 * dr_v3_dot(f[0], f[1]);
}

double dr_shell_membrane_energy(const double *x0, const double *x1, const double *x2, const double Bm[4], double area,
                                double k, double nu)
{
    double E[3];
    dr_shell_green(x0, x1, x2, Bm, E);
    return 0.5 * area * k * (E[0] * E[0] + E[1] * E[1] + 2.0 * nu * E[0] * E[1] + 2.0 * (1.0 - nu) * E[2] * E[2]);
}

void dr_shell_membrane_group(const double *x0, const double *x1, const double *x2, const double Bm[4], double area,
                             double k, double nu, const int dof[3], const double *lambda, bool project, double *G,
                             DrLagGroup *g)
{
    const double r2 = 1.0 / sqrt(2.0);
    double c[3][2], E[3];
    DrVec3 f[2];
    coefficients(Bm, c);
    columns(x0, x1, x2, c, f);
    E[0] = 0.5 * (dr_v3_dot(f[0], f[0]) - 1.0);
    E[1] = 0.5 * (dr_v3_dot(f[1], f[1]) - 1.0);
    E[2] = 0.5 * dr_v3_dot(f[0], f[1]);
    memset(g, 0, sizeof *g);
    g->kind = DR_LAG_POSITIONAL;
    g->nrows = 3;
    g->ndof = 9;
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++) g->dof[3 * i + a] = dof[i] + a;
    g->phi[0] = (E[0] + E[1]) * r2;
    g->phi[1] = (E[0] - E[1]) * r2;
    g->phi[2] = 2.0 * E[2] * r2;
    g->cinv[0] = area * k * (1.0 + nu);
    g->cinv[1] = area * k * (1.0 - nu);
    g->cinv[2] = area * k * (1.0 - nu);
    for (int i = 0; i < 3; i++) {
        DrVec3 d0 = dr_v3_scale(dr_v3_add(dr_v3_scale(f[0], c[i][0]), dr_v3_scale(f[1], c[i][1])), r2);
        DrVec3 d1 = dr_v3_scale(dr_v3_sub(dr_v3_scale(f[0], c[i][0]), dr_v3_scale(f[1], c[i][1])), r2);
        DrVec3 d2 = dr_v3_scale(dr_v3_add(dr_v3_scale(f[1], c[i][0]), dr_v3_scale(f[0], c[i][1])), r2);
        const DrVec3 d[3] = {d0, d1, d2};
        for (int r = 0; r < 3; r++) {
            g->J[r * 9 + 3 * i + 0] = d[r].x;
            g->J[r * 9 + 3 * i + 1] = d[r].y;
            g->J[r * 9 + 3 * i + 2] = d[r].z;
        }
    }
    if (lambda && G) {
        /* Σ_r λ_r ∇²φ_r = S ⊗ I₃ with S the 3×3 (vertex by vertex) sum of the rows' constant Hessians */
        double S[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double h0 = (c[i][0] * c[j][0] + c[i][1] * c[j][1]) * r2;
                double h1 = (c[i][0] * c[j][0] - c[i][1] * c[j][1]) * r2;
                double h2 = (c[i][0] * c[j][1] + c[i][1] * c[j][0]) * r2;
                S[3 * i + j] = lambda[0] * h0 + lambda[1] * h1 + lambda[2] * h2;
            }
        if (project) {
            /* keep the part that stiffens (S's negative eigenvalues: −h²G adds to the matrix); the rest would soften
               it, and a compressed triangle's would make it indefinite */
            double e[3], V[9], P[9] = {0};
            dr_m3a_sym_eigen(S, e, V);
            for (int k = 0; k < 3; k++) {
                double ek = fmin(e[k], 0.0);
                for (int i = 0; i < 3; i++)
                    for (int j = 0; j < 3; j++) P[3 * i + j] += ek * V[3 * i + k] * V[3 * j + k];
            }
            memcpy(S, P, sizeof S);
        }
        memset(G, 0, 81 * sizeof(double));
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                for (int a = 0; a < 3; a++) G[(3 * i + a) * 9 + 3 * j + a] = S[3 * i + j];
        g->G = G;
    }
}

double dr_shell_hinge_angle(const double *x0, const double *x1, const double *x2, const double *x3, double *grad)
{
    DrVec3 p0 = ld3(x0), p1 = ld3(x1), p2 = ld3(x2), p3 = ld3(x3);
    DrVec3 e = dr_v3_sub(p2, p1);
    DrVec3 NA = dr_v3_cross(dr_v3_sub(p1, p0), dr_v3_sub(p2, p0));
    DrVec3 NB = dr_v3_cross(dr_v3_sub(p2, p3), dr_v3_sub(p1, p3));
    double le = dr_v3_norm(e), a2 = dr_v3_dot(NA, NA), b2 = dr_v3_dot(NB, NB);
    if (grad) memset(grad, 0, 12 * sizeof(double));
    if (!(le > 0) || !(a2 > 0) || !(b2 > 0)) return 0.0;
    DrVec3 eh = dr_v3_scale(e, 1.0 / le);
    double na = sqrt(a2), nb = sqrt(b2);
    double s = dr_v3_dot(dr_v3_cross(NA, NB), eh) / (na * nb), c = dr_v3_dot(NA, NB) / (na * nb);
    double theta = atan2(s, c);
    if (grad) {
        DrVec3 ua = dr_v3_scale(NA, 1.0 / a2), ub = dr_v3_scale(NB, 1.0 / b2);
        DrVec3 g0 = dr_v3_scale(ua, -le);
        DrVec3 g3 = dr_v3_scale(ub, -le);
        DrVec3 g1 = dr_v3_scale(dr_v3_add(dr_v3_scale(ua, dr_v3_dot(dr_v3_sub(p0, p2), eh)),
                                          dr_v3_scale(ub, dr_v3_dot(dr_v3_sub(p3, p2), eh))),
                                -1.0);
        DrVec3 g2 = dr_v3_add(dr_v3_scale(ua, dr_v3_dot(dr_v3_sub(p0, p1), eh)),
                              dr_v3_scale(ub, dr_v3_dot(dr_v3_sub(p3, p1), eh)));
        const DrVec3 gv[4] = {g0, g1, g2, g3};
        for (int v = 0; v < 4; v++) {
            grad[3 * v] = gv[v].x;
            grad[3 * v + 1] = gv[v].y;
            grad[3 * v + 2] = gv[v].z;
        }
    }
    return theta;
}

void dr_shell_hinge_group(const double *x0, const double *x1, const double *x2, const double *x3, double theta_bar,
                          double cinv, const int dof[4], DrLagGroup *g)
{
    double grad[12];
    double theta = dr_shell_hinge_angle(x0, x1, x2, x3, grad);
    double d = theta - theta_bar;
    if (d > DR_PI) d -= 2.0 * DR_PI;
    if (d < -DR_PI) d += 2.0 * DR_PI;
    memset(g, 0, sizeof *g);
    g->kind = DR_LAG_POSITIONAL;
    g->nrows = 1;
    g->ndof = 12;
    for (int v = 0; v < 4; v++)
        for (int a = 0; a < 3; a++) g->dof[3 * v + a] = dof[v] + a;
    memcpy(g->J, grad, sizeof grad);
    g->phi[0] = d;
    g->cinv[0] = cinv;
}

int dr_shell_bend_rest(const double *X0, const double *X1, const double *X2, double area, const bool interior[3],
                       double kb, double nu, double u[9], double cinv[3])
{
    memset(u, 0, 9 * sizeof(double));
    memset(cinv, 0, 3 * sizeof(double));
    if (!(kb > 0) || !(area > 0)) return 0;
    const double *X[3] = {X0, X1, X2};
    DrVec3 N = dr_v3_cross(dr_v3_sub(ld3(X1), ld3(X0)), dr_v3_sub(ld3(X2), ld3(X0)));
    DrVec3 n[3];
    double c[3];
    for (int i = 0; i < 3; i++) {
        DrVec3 e = dr_v3_sub(ld3(X[(i + 2) % 3]), ld3(X[(i + 1) % 3]));
        c[i] = interior[i] ? dr_v3_norm(e) / (2.0 * area) : 0.0;
        n[i] = dr_v3_normalize(dr_v3_cross(e, N));
    }
    double Q[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double d = dr_v3_dot(n[i], n[j]);
            Q[3 * i + j] = 2.0 * kb * area * c[i] * c[j] * (nu + (1.0 - nu) * d * d);
        }
    double e[3], V[9];
    dr_m3a_sym_eigen(Q, e, V);
    double emax = fmax(e[0], fmax(e[1], e[2]));
    int rows = 0;
    for (int r = 0; r < 3; r++) {
        if (!(e[r] > 1e-12 * emax)) continue;
        for (int i = 0; i < 3; i++) u[3 * rows + i] = interior[i] ? V[3 * i + r] : 0.0;
        cinv[rows++] = e[r];
    }
    return rows;
}
