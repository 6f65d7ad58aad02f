/* Private to src/bem: quadrature points on a triangle for one collocation point. */
#ifndef DR_BEM_INTERNAL_H
#define DR_BEM_INTERNAL_H

#include <complex.h>

#include "bem/bem.h"

/* ---- Laplace-domain kernels (BEM App. A) ---------------------------------------------------------
 * r = y − x (field point y minus collocation point x), n = unit outward normal at y, s the Laplace
 * variable (Re s > 0). Outputs are 3×3 row-major, out[3i+j] = kernel_ij: row i is the direction of the
 * unit point load at x, column j the component at y, so that the boundary integral equation reads
 * c_ij u_j(x) + ∫ p*_ij u_j dΓ = ∫ u*_ij p_j dΓ + body terms. All four are evaluated without the
 * cancellation of their 1/s² forms when |s r/c| is small (a series for ((1+z)e^{−z} − 1)/z²). */
void dr_bem_kernel_u(const DrBemWave *w, const double r[3], double complex s, double complex u[9]); /* eq. 16 */
void dr_bem_kernel_p(const DrBemWave *w, const double r[3], const double n[3], double complex s,
                     double complex p[9]); /* eq. 17 */
void dr_bem_kernel_d(const DrBemWave *w, const double r[3], const double n[3], double complex s,
                     double complex d[9]); /* eq. 19 */
/* l̂* of eq. (21); q̂* = l̂* + d̂*·[x − x̄]×ᵀ (eq. 20) is formed by the caller, which knows x − x̄. */
void dr_bem_kernel_l(const DrBemWave *w, const double r[3], const double n[3], double complex s,
                     double complex l[9]);
/* The elastostatic (Kelvin) limits s → 0 of û* and p̂*, closed form. */
void dr_bem_kernel_u_static(const DrBemWave *w, const double r[3], double u[9]);
void dr_bem_kernel_p_static(const DrBemWave *w, const double r[3], const double n[3], double p[9]);

/* Every kernel at one point for ns Laplace variables at once (the geometry is shared), the assembly's
 * inner loop. Any output pointer may be NULL to skip that kernel. Layout: out[k*9 + 3i + j] for s[k].
 * p_dyn, if not NULL, receives p̂*(s) − p*_static (bounded near r = 0: of order |s r/c|² times the static kernel),
 * for the singular triangles; each wave's s = 0 value is removed analytically, not by subtraction. */
typedef struct DrBemKernelOut {
    double complex *u, *p, *p_dyn, *d, *l;
} DrBemKernelOut;
void dr_bem_kernel_batch(const DrBemWave *w, const double r[3], const double n[3], int ns, const double complex *s,
                         const DrBemKernelOut *out);

/* ---- convolution quadrature (BEM eq. 15, BDF1) --------------------------------------------------
 * s_l = γ(R e^{2πil/L})/Δt with γ(ζ) = 1 − ζ, and ψ_k(f̂) = R^{−k}/L Σ_l f̂(s_l) e^{−2πikl/L} for
 * k = 0..L−1. s_{L−l} = conj(s_l), so a real time function needs f̂ at l = 0..⌊L/2⌋ only. */
typedef struct DrBemCq {
    int L;              /* number of frequencies = number of weights */
    double R, dt;       /* R = ε^{1/(2L)}, time step */
    double complex *s;  /* L Laplace variables, owned */
} DrBemCq;
DR_NODISCARD DrStatus dr_bem_cq_init(int L, double eps, double dt, DrBemCq *out, DrError *err);
void dr_bem_cq_free(DrBemCq *cq);
/* psi[k], k = 0..L−1, from fhat[l] = f̂(s_l) for all l (complex input, real part of the result). */
void dr_bem_cq_weights(const DrBemCq *cq, const double complex *fhat, double *psi);
/* Same from l = 0..⌊L/2⌋ only, using f̂(conj s) = conj f̂(s). */
void dr_bem_cq_weights_half(const DrBemCq *cq, const double complex *fhat_half, double *psi);


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

/* A compressed matrix's coefficients in the runtime's compact form (bem_compress.c): 16-bit fixed-point values
 * with one scale per row and 16-bit columns (3N ≤ 65535), 4 bytes per coefficient against 12; products within
 * about 2e-4 of the double ones. bem_cmat_compact is false for dense matrices, larger ones, or no memory.
 *
 * A copy may also hold the same 16-bit values by column (bem_cmatq_add_columns). The matrices that multiply
 * tractions have one: a traction is zero away from contacts and fixed vertices, and so are most of its Haar
 * coefficients, so a product over the columns it touches reads a fraction of the matrix. */
#define BEM_COLUMN_GROUPS 4 /* a column product's share-out among threads; its work holds this many 3N vectors */
typedef struct BemCMatQ {
    int n;
    int64_t nnz;
    int64_t *row_ptr;
    uint16_t *col;
    int16_t *val;
    double *scale;      /* row i's coefficients are scale[i]·val */
    int64_t *col_ptr;   /* by column (NULL when none): column c's entries from col_ptr[c], */
    uint32_t *centry;   /* each its row in the low 16 bits and its value in the high 16 */
} BemCMatQ;
bool bem_cmat_compact(const DrBemCMat *m, BemCMatQ *out);
/* Adds the column form; false without memory (the row form then serves alone). */
bool bem_cmatq_add_columns(BemCMatQ *m);
void bem_cmatq_free(BemCMatQ *m);
/* ỹ += sign·M̃x̃; work holds BEM_COLUMN_GROUPS·3N doubles, or NULL to use the row form only. */
void bem_cmatq_matvec_acc(const BemCMatQ *m, const double *x, double sign, double *y, double *work);
/* ỹ += Σ_j sign_j·M̃_j x̃_j over `count` matrices of one size, in one pass of the threads (the history sum). A
   product whose vector's nonzero coefficients touch less than 45 % of the matrix goes by columns when the copy has
   them and work (BEM_COLUMN_GROUPS·3N doubles) is given. The result does not depend on the thread count. */
int bem_cmatq_sum(const BemCMatQ *const *mats, const double *const *x, const double *sign, int count, double *y,
                  double *work); /* returns how many products went by columns */
/* y = M x in natural order (a compressed set's layout); scratch holds (2 + BEM_COLUMN_GROUPS)·3N doubles. */
void bem_cmatq_matvec(const DrBemLayout *l, const BemCMatQ *m, const double *x, double *y, double *scratch);
/* Tests: true forces the scalar loop where the vector one would run (both give the same bits). */
void bem_cmatq_scalar_only(bool on);

/* The kept coefficients of H₀⁻¹G′ by column, built on the first constrained step of a body on the set by the
 * constraint solver (bem_constraint.c), which needs single columns of the response; shared like the copies below. */
typedef struct BemColumns BemColumns;
void bem_columns_free(BemColumns **c);

/* What the bodies on one matrix set share, made when the first of them is created (bem_solid.c) and freed with the
 * set: the compact copies of every matrix a step multiplies by, and the constraint solver's columns. */
struct BemRuntime {
    bool made;              /* the copies were attempted */
    const void *made_for[3]; /* the set's H, G and H₀⁻¹ storage then: a copy of the set's struct holding other
                                matrices (a view) gets its bodies their own copies */
    int nmax;
    BemCMatQ *Hq, *Gq;      /* compact copies of H_k, G_k (k ≥ 1; index k), or NULL (dense sets, 3N > 65535, no
                               memory): the double products serve */
    BemCMatQ H0q, Gpq;      /* compact copies of H₀⁻¹ and H₀⁻¹G′; G_k and H₀⁻¹G′ also by column */
    BemColumns *gp_cols;    /* NULL until a body on the set is first constrained */
};
typedef struct BemRuntime BemRuntime;
DR_NODISCARD DrStatus bem_runtime_new(BemRuntime **out, DrError *err);
void bem_runtime_free(BemRuntime **rt);

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
    /* scratch, 3N each; s_coeff (2 + BEM_COLUMN_GROUPS)·3N */
    double *s_ht, *s_tmp, *s_h, *s_p, *s_u, *s_z, *s_r, *s_coeff;
    BemRuntime *rt;         /* the set's shared copies (rt->Hq NULL: none), or own_rt (a set made by hand, or a view
                               of one) */
    BemRuntime *own_rt;
    const BemCMatQ **sum_mats; /* 2·nmax: the history sum's matrices, vectors and signs (bem_cmatq_sum) */
    const double **sum_x;
    double *sum_sign;
    double *hz;             /* H₀⁻¹h of the history sum for step hz_step: every solve of one step shares it */
    long hz_step;           /* 0: none */
    /* the step in phases (bem.h): predict fills hz; a solve leaves its u in s_u and its p in s_p, and the rest
       below; commit takes them */
    int phase;              /* BEM_PHASE_* */
    double pred_seconds;    /* the prediction's history sums, s */
    double pR[9], pT[3], pTdot[3], pomega[3]; /* the frame at the end of the solved step */
    double pb[3], pal[3];   /* its b = a − g′ and α, for the history window */
    DrBemStepStats pstats;
    double *smp_x, *smp_v, *smp_n, *smp_w; /* 3N each: the samples (dr_bem_solid_samples) and their scratch */
    struct BemGroupWork *group; /* the constraint solver's scratch and prediction for the groups this solid leads
                                   (is solids[0] of), bem_constraint.c; NULL until its first constrained step */
};

enum { BEM_PHASE_NONE = 0, BEM_PHASE_PREDICTED, BEM_PHASE_SOLVED };

/* World positions V (3N) of the last solve since predict: the end of the step it would commit. */
void bem_solid_solved_positions(const DrBemSolid *s, double *V);

/* The constraint solver's kept scratch (bem_constraint.c): freed with the solid that holds it; dropped (its
   prediction forgotten) when that solid's state is set. */
typedef struct BemGroupWork BemGroupWork;
void bem_group_work_free(BemGroupWork **w);
void bem_group_work_drop(BemGroupWork *w);

/* Tests: true makes every Gauss–Seidel sweep collect its changes in blocks (bem_constraint.c), as it does on several
 * threads for large contact sets; the results must not change. */
void bem_constraints_force_blocks(bool on);


#endif
