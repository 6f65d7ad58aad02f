/* drench bem: surface-only elastic bodies by the convolution-quadrature boundary element method
 * (seed sugimoto_surface_only_bem, "BEM" below; PHYSICS.md §7).
 *
 * This header is the precompute side: Laplace-domain kernels (BEM App. A), convolution-quadrature
 * weights (BEM eq. 15), the assembled time-domain matrices H_k, G_k, D_k, Q_k of eq. (9), the rigid
 * frame's operators A and C (eq. 10), H₀⁻¹ and H₀⁻¹G′ (eq. 12), their wavelet compression (§3.3) and
 * the content-keyed cache under cache/bem/.
 *
 * Conventions: SI units; a body's unknowns are the 3N nodal displacements and tractions in the
 * natural interleaved order 3·vertex + axis of the input mesh; dense matrices are row-major. */
#ifndef DR_BEM_H
#define DR_BEM_H

#include <complex.h>
#include <stdint.h>

#include "core/core.h"
#include "io/io.h"

/* ---- material and wave speeds ------------------------------------------------------------------ */

typedef struct DrBemMaterial {
    double density;       /* ρ, kg/m³ */
    double shear_modulus; /* μ, Pa */
    double poisson;       /* ν, in (-1, 0.5) */
} DrBemMaterial;

typedef struct DrBemWave {
    double rho, mu, lambda, nu; /* ρ, Lamé μ and λ, Poisson ν */
    double c1, c2;              /* longitudinal and shear wave speeds, BEM eq. (18) */
} DrBemWave;
void dr_bem_wave_init(const DrBemMaterial *m, DrBemWave *out);

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

/* ---- surface meshes: checks, mass properties, frame operators, orderings ------------------------ */

/* A closed, manifold, consistently and outward oriented triangle mesh with no degenerate triangle, else
 * DR_ERR_INPUT naming `path`, the problem and counts (open boundary edges, non-manifold edges,
 * inconsistently oriented edges, inward orientation, zero-area triangles) and the fix. */
DR_NODISCARD DrStatus dr_bem_mesh_check(const DrTriMesh *m, const char *path, DrError *err);

/* Merge vertices closer than tol (OBJ files split vertices along normal and texture seams; a BEM body
 * needs one node per surface point), drop unused vertices, and remap triangles. Returns how many
 * vertices were removed. Per-vertex normals are dropped (set to NULL). */
DR_NODISCARD DrStatus dr_bem_mesh_weld(DrTriMesh *m, double tol, int *removed, DrError *err);

/* Rigid-body properties of the undeformed body by boundary integrals (Mirtich 1996). */
typedef struct DrBemBody {
    double volume, mass;
    double centroid[3]; /* x̄ */
    double inertia[9];  /* about x̄, row-major, kg m² */
    double r_max;       /* largest distance between two vertices, m */
} DrBemBody;
void dr_bem_body_compute(const DrTriMesh *m, double density, DrBemBody *out);

/* The frame operators of BEM eq. (10): A = (1/m) ∫ Φ dΓ and C = I⁻¹ ∫ (y − x̄) × Φ dΓ, both 3 × 3N row-major,
 * and the shape-matching weights w_j = ∫ (y − x̄)·n Φ_j dΓ (§3.2.1 writes y·n; about x̄ the weights do not depend on
 * where the mesh sits and are positive for star-shaped bodies), N entries (Σ w = 3·volume). Needs a checked mesh. */
void dr_bem_frame_operators(const DrTriMesh *m, const DrBemBody *b, double *A, double *C, double *w);

/* ∫ Φ_j dΓ, the area attributed to each vertex (a third of its triangles' areas). */
void dr_bem_vertex_areas(const DrTriMesh *m, double *area);

/* A spatially coherent vertex order (a 3-D Hilbert curve through the vertices): order[new] = old. */
void dr_bem_vertex_order(const DrTriMesh *m, int *order);

/* Closed test and asset meshes: an icosphere (subdivision level ≥ 0, 20·4^level triangles),
 * x = radius·(1 + bump·sin(f u_x) sin(f u_y) sin(f u_z))·u for the unit-sphere vertex u, bump in (−1, 1);
 * and an axis-aligned box [lo, hi] with n[a] segments per edge along axis a. */
DR_NODISCARD DrStatus dr_bem_mesh_icosphere(int level, double radius, double bump, double freq, DrTriMesh *out,
                                            DrError *err);
DR_NODISCARD DrStatus dr_bem_mesh_box(const double lo[3], const double hi[3], const int n[3], DrTriMesh *out,
                                      DrError *err);

/* ---- compression (BEM §3.3) ----------------------------------------------------------------------
 * A 3N × 3N matrix M in natural order is permuted to P M Pᵀ (P: the vertex order, then optionally the
 * xyz-blocked coordinate order c·N + v), transformed by the orthonormal 2-D Haar transform W (per
 * coordinate block of length N when blocked, over all 3N otherwise; any length, an odd tail is carried
 * to the next level), and only the `ratio`⁻¹ fraction of largest-magnitude coefficients is kept, as CSR.
 * y = M x is then Pᵀ Wᵀ M̃ W P x: one forward Haar of x, a sparse product, one inverse Haar. */
typedef enum DrBemOrdering {
    DR_BEM_ORDER_VERTEX_XYZ = 0, /* vertex reordering and xyz blocks (the full scheme) */
    DR_BEM_ORDER_XYZ,            /* xyz blocks in the input's vertex order */
    DR_BEM_ORDER_NONE,           /* interleaved, input order */
} DrBemOrdering;
/* "vertex_xyz", "xyz", "none": the names the scene's Compression.ordering and the cache files use. */
const char *dr_bem_ordering_name(DrBemOrdering o);
/* The ordering of a name above; false for any other string. */
bool dr_bem_ordering_parse(const char *name, DrBemOrdering *out);

typedef struct DrBemLayout {
    int nv;             /* N */
    DrBemOrdering ordering;
    bool wavelet;       /* false: keep the largest entries of P M Pᵀ itself (naive pruning, for comparison) */
    int *perm;          /* 3N: perm[new] = old natural index, owned */
} DrBemLayout;
/* order: the vertex order for DR_BEM_ORDER_VERTEX_XYZ (order[new] = old), ignored otherwise. */
DR_NODISCARD DrStatus dr_bem_layout_init(int nv, DrBemOrdering ordering, bool wavelet, const int *order,
                                         DrBemLayout *out, DrError *err);
void dr_bem_layout_free(DrBemLayout *l);

typedef struct DrBemCMat {
    int n;             /* 3N */
    bool dense;        /* ratio 1: `val` is the n×n row-major matrix in natural order, no transform */
    int64_t nnz;       /* kept coefficients (n·n when dense) */
    int64_t *row_ptr;  /* n+1 (compressed only) */
    int32_t *col;      /* nnz (compressed only) */
    double *val;       /* nnz, or n·n when dense */
} DrBemCMat;
/* dense: n×n row-major, natural order (not modified). ratio ≥ 1; exactly 1 keeps the dense matrix. */
DR_NODISCARD DrStatus dr_bem_compress(const DrBemLayout *l, const double *dense, double ratio, DrBemCMat *out,
                                      DrError *err);
/* y = M x (natural order); scratch holds 2n doubles. Thread-safe for distinct scratch. */
void dr_bem_cmat_matvec(const DrBemLayout *l, const DrBemCMat *m, const double *x, double *y, double *scratch);
/* The matrix the compressed form stands for, n×n row-major natural order. */
void dr_bem_cmat_decompress(const DrBemLayout *l, const DrBemCMat *m, double *dense);
void dr_bem_cmat_free(DrBemCMat *m);
size_t dr_bem_cmat_bytes(const DrBemCMat *m); /* storage of the kept values and indices */

/* 1-D orthonormal Haar transform of x[0..n) in place (forward: averages first, details after, level by
 * level; inverse undoes it exactly); scratch holds n doubles. */
void dr_bem_haar_forward(double *x, int n, double *scratch);
void dr_bem_haar_inverse(double *x, int n, double *scratch);

/* ---- the precomputed matrix set -------------------------------------------------------------------- */

typedef struct DrBemDesc {
    DrBemMaterial material;
    double dt;                /* Δt the matrices are built for, s */
    double history_margin;    /* n_max = ⌊r_max/(c₂Δt) + margin⌋ (BEM §4 uses 2) */
    double cq_epsilon;        /* ε of R = ε^{1/(2L)}, 1e-10 */
    double compression_ratio; /* ≥ 1; 1 = dense */
    DrBemOrdering ordering;   /* compression variant (VERTEX_XYZ in production) */
    bool wavelet;             /* false: naive pruning (comparison only) */
    int quad_levels;          /* subdivision levels of regular triangles: 1 = the 4-way split of BEM §4 */
    double near_factor;       /* a triangle closer than near_factor × its diameter is subdivided further */
    int singular_order;       /* Gauss points per direction of the singular (polar) rule */
    bool keep_dense;          /* keep the uncompressed H_k, G_k in the result (tests, benchmarks) */
} DrBemDesc;
void dr_bem_desc_default(DrBemDesc *d);

typedef struct DrBemStats {
    double seconds_quadrature, seconds_inverse, seconds_compress;
    int frequencies_evaluated;
    double rigid_residual; /* ‖Σ_k H_k m‖ / ‖H_0 m‖ for the rigid translations m (history truncation) */
    size_t bytes_dense, bytes_compressed;
} DrBemStats;

typedef struct DrBemMatrices {
    int nv, n;       /* N vertices, n = 3N */
    int nt;          /* triangles */
    double *x;       /* 3N rest positions (the mesh the matrices were built for) */
    int *tri;        /* 3·nt vertex indices */
    int n_max;       /* history length: matrices k = 0..n_max */
    DrBemDesc desc;
    DrBemBody body;
    DrBemLayout layout;
    double *A, *C;   /* 3 × n each, eq. (10) */
    double *w;       /* N shape-matching weights */
    double *area;    /* N vertex areas ∫Φ_j */
    double *D, *Q;   /* (n_max+1) × n × 3, D_k and Q_k of eq. (9), row-major per k */
    DrBemCMat *H, *G;      /* n_max+1 each; H[0] and G[0] included */
    DrBemCMat H0inv;       /* H₀⁻¹ */
    DrBemCMat H0inv_Gp;    /* H₀⁻¹G′, G′ = G₀ + D₀A + Q₀C (eq. 12) */
    double *H_dense, *G_dense; /* (n_max+1) × n × n when desc.keep_dense, else NULL */
    DrBemStats stats;
} DrBemMatrices;

/* Assemble everything above for a checked mesh (dr_bem_mesh_check). Parallel over collocation vertices;
 * deterministic for a given thread count. Progress on stderr with `label` when not NULL. */
DR_NODISCARD DrStatus dr_bem_matrices_build(const DrTriMesh *m, const DrBemDesc *d, const char *label,
                                            DrBemMatrices **out, DrError *err);
void dr_bem_matrices_destroy(DrBemMatrices **m);

/* n_max for a body of extent r_max (BEM §4 with the margin of d). */
int dr_bem_history_length(const DrBemDesc *d, double r_max);

/* ---- cache (cache/bem/<key>.h5) ---------------------------------------------------------------------
 * The key hashes the mesh file's bytes, the parameters that enter the matrices (material, Δt, margin, ε,
 * compression, quadrature) and DR_BEM_VERSION. A file is trusted only if it records that key. */
#define DR_BEM_VERSION "bem-1"
void dr_bem_cache_key(const char *mesh_hash_hex, const DrBemDesc *d, char key_hex[33]);
/* Write atomically (temporary file renamed into place); inputs_json describes the parameters. */
DR_NODISCARD DrStatus dr_bem_cache_write(const char *cache_root, const char *key_hex, const char *inputs_json,
                                         const char *mesh_hash_hex, const DrBemMatrices *m, DrError *err);
/* found = false (and *out NULL) when no trusted file holds the key. The cache never holds H_dense/G_dense: a read
 * returns them NULL with desc.keep_dense false. */
DR_NODISCARD DrStatus dr_bem_cache_read(const char *cache_root, const char *key_hex, DrBemMatrices **out,
                                        bool *found, DrError *err);

#endif
