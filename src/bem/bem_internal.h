/* Private to src/bem: quadrature points on a triangle for one collocation point. */
#ifndef DR_BEM_INTERNAL_H
#define DR_BEM_INTERNAL_H

#include "bem/bem.h"

/* One quadrature point: position y, weight (the point's share of the triangle's area, m², Jacobian
 * included) and the three linear shape functions of the triangle's vertices at y. */
typedef struct BemQuadPoint {
    double y[3];
    double w;
    double phi[3];
} BemQuadPoint;

/* Largest number of points either rule below writes for the given settings. */
int bem_quad_capacity(int levels, int max_levels, int singular_order);

/* A triangle (a, b, c) that does not contain x: the 9-point degree-5 rule on each subtriangle after
 * `levels` 4-way subdivisions, and subtriangles whose centroid lies closer to x than near_factor times their
 * diameter subdivided further, down to max_levels. Returns the point count (≤ cap). */
int bem_quad_regular(const double a[3], const double b[3], const double c[3], const double x[3], int levels,
                     int max_levels, double near_factor, BemQuadPoint *out, int cap);

/* A triangle whose vertex a is the collocation point: polar (Duffy) coordinates about a, order × order
 * Gauss–Legendre points; the Jacobian 2·area·ρ cancels a 1/r singularity. phi is for (a, b, c). */
int bem_quad_singular(const double a[3], const double b[3], const double c[3], int order, BemQuadPoint *out,
                      int cap);

/* Gauss–Legendre nodes and weights on [0, 1], n ≤ 64. */
void bem_gauss_legendre01(int n, double *x, double *w);

/* The Laplace-domain matrices Ĥ(s), Ĝ(s) (ns × n × n) and the integrals of d̂*, q̂* (ns × n × 3, may be NULL)
 * for arbitrary Laplace variables, with the quadrature of dr_bem_matrices_build (validation and benchmarks). */
DR_NODISCARD DrStatus bem_laplace_matrices(const DrTriMesh *mesh, const DrBemDesc *d, int ns, const double complex *s,
                                           double complex *H, double complex *G, double complex *D,
                                           double complex *Q, DrError *err);

/* A compressed matrix's coefficients in single precision with 16-bit columns (3N ≤ 65535), for the history sums
 * of a body's step (bem_compress.c). bem_cmat_compact is false for dense matrices, larger ones, or no memory. */
typedef struct BemCMatF {
    int n;
    int64_t nnz;
    int64_t *row_ptr;
    uint16_t *col;
    float *val;
} BemCMatF;
bool bem_cmat_compact(const DrBemCMat *m, BemCMatF *out);
void bem_cmatf_free(BemCMatF *m);
void bem_cmatf_matvec_acc(const BemCMatF *m, const double *x, double sign, double *y); /* y += sign·M̃x */

/* Row-major 3×3 helpers shared by the runtime and the constraint solver (bem_solid.c): C = AB, y = Ax, the inverse
 * (false when singular), and e^{[v]×} by Rodrigues' formula (eq. 11g). */
void bem_m3_mul(const double *A, const double *B, double *C);
void bem_m3_vec(const double *A, const double *x, double *y);
bool bem_m3_inv(const double *A, double *inv);
void bem_rotation_exp(const double v[3], double *Rm);

/* A body in a shot (bem_solid.c); the constraint solver reads its frame and matrices. */
struct DrBemSolid {
    const DrBemMatrices *m;
    DrBemSolidDesc d;
    int n, nv, nmax;
    bool dense;
    double *ref;            /* x − x̄, 3N */
    double *u;              /* u_n, 3N, body frame */
    double *ut_hist, *pt_hist; /* nmax × 3N: ũ and p̃ of past steps, slot (step − 1) mod nmax */
    double *b_hist, *al_hist;  /* nmax × 3: b = a − g′ and α of past steps */
    long step;
    double R[9], T[3], Tdot[3], omega[3];
    double c0[3], wsum;     /* w-weighted centroid of ref, Σw (§3.2.1) */
    double *E, *F;          /* H₀⁻¹D₀ and H₀⁻¹Q₀, 3N × 3: u = z + E b + F α solves eq. (9) for given b, α */
    double *Epinv, *Fpinv;  /* 3 × 3N least-squares inverses of E and F (§3.2.1) */
    double *s_ht, *s_tmp, *s_h, *s_p, *s_u, *s_z, *s_r, *s_coeff; /* scratch, 3N each (coeff: 2·3N) */
    BemCMatF *Hf, *Gf;      /* compact copies of H_k, G_k (k ≥ 1; index k) for the history sums, or NULL */
    double *hz;             /* H₀⁻¹h of the history sum for step hz_step: trial steps of one step share it */
    long hz_step;           /* 0: none */
};

/* dr_bem_solid_step with commit = true; with commit = false a trial step: V_out (3N) receives the world positions
 * the step would give and the solid is left as it was (the constraint solver's linearisation, eq. 14). */
DR_NODISCARD DrStatus bem_solid_advance(DrBemSolid *s, const double *traction, bool commit, DrBemStepStats *st,
                                        double *V_out, DrError *err);

#endif
