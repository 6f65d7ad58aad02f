/* drench bem: surface-only elastic bodies by the convolution-quadrature boundary element method
 * (seed sugimoto_surface_only_bem, "BEM" below; PHYSICS.md §7).
 *
 * Public: the assembled time-domain matrices H_k, G_k, D_k, Q_k of eq. (9), the rigid frame's operators A and C
 * (eq. 10), H₀⁻¹ and H₀⁻¹G′ (eq. 12), their wavelet compression (§3.3) and
 * the content-keyed cache under cache/bem/, and the runtime of a body in a shot with its constraints. The
 * complex-valued Laplace-domain kernels and convolution-quadrature weights are private (bem_internal.h).
 *
 * Conventions: SI units; a body's unknowns are the 3N nodal displacements and tractions in the
 * natural interleaved order 3·vertex + axis of the input mesh; dense matrices are row-major. */
#ifndef DR_BEM_H
#define DR_BEM_H

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
/* Products in the coefficient domain x̃ = W P x (x̃ = x when the set is dense), so that sums of many products
 * pay one transform: y = from_coeff(Σ M̃_k x̃_k). scratch holds 2n doubles. */
void dr_bem_layout_to_coeff(const DrBemLayout *l, bool dense, const double *x, double *xt, double *scratch);
void dr_bem_layout_from_coeff(const DrBemLayout *l, bool dense, const double *yt, double *y, double *scratch);
void dr_bem_cmat_matvec_coeff(const DrBemCMat *m, const double *xt, double *yt); /* ỹ = M̃ x̃ */
size_t dr_bem_cmat_bytes(const DrBemCMat *m); /* storage of the kept values and indices */
/* The Haar coefficients a compressed 3N × 3N matrix of an N-vertex body keeps per row on average, 3N/ratio (all 3N at
   ratio 1), and the fewest that keep the body's response close: a sphere under sudden pressure (tests/validation/
   test_bem_solid) settles within 3 % of Lamé's solution with ~120 per row, 10 % with 60 and 41 % with 15, whatever
   N; so a small body needs a smaller ratio than a large one (3N/100: at most 19 at 642 vertices, 87 at 2,906).
   precompute warns below it. */
#define DR_BEM_MIN_COEFFICIENTS_PER_ROW 100.0
double dr_bem_coefficients_per_row(int nv, double ratio);

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
    struct BemRuntime *runtime; /* what the bodies on the set share (bem_solid.c), owned; NULL in a set made by hand */
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
 * compression, quadrature) and DR_BEM_VERSION. A file is trusted only if it records that key and every
 * dataset matches its checksum (io.h). bem-2: files carry checksums, so files of bem-1 (which have none)
 * are not looked up: the new key makes precompute compute them again. */
#define DR_BEM_VERSION "bem-2"
void dr_bem_cache_key(const char *mesh_hash_hex, const DrBemDesc *d, char key_hex[33]);
/* Write atomically (temporary file renamed into place); inputs_json describes the parameters. */
DR_NODISCARD DrStatus dr_bem_cache_write(const char *cache_root, const char *key_hex, const char *inputs_json,
                                         const char *mesh_hash_hex, const DrBemMatrices *m, DrError *err);
/* found = false (and *out NULL) when no trusted file holds the key: none is there, or the one there is not trusted,
 * and then `rejected` (NULL: not wanted; cleared otherwise) says why, naming the file: unreadable, another key,
 * a dataset that does not match its checksum (damaged or edited), sizes that disagree. Nothing is logged: the
 * caller says what follows. The cache never holds H_dense/G_dense: a read returns them NULL with desc.keep_dense
 * false. */
DR_NODISCARD DrStatus dr_bem_cache_read(const char *cache_root, const char *key_hex, DrBemMatrices **out,
                                        bool *found, DrError *rejected, DrError *err);

/* ---- a body's mesh as the matrices take it (bem_asset.c) ----------------------------------------------------
 * The mesh file loaded, welded (vertices closer than 1e-9 of the bounding-box diagonal merged: OBJ files split them
 * along seams) and checked closed, manifold and outward (dr_bem_mesh_check), in the file's own coordinates; the
 * hash of the file's bytes and the cache key of its matrices under desc (dr_bem_cache_key). precompute builds the
 * matrices under that key and the world reads them with it: both take it from here (src/stage makes desc from a
 * bem_solid element), so they cannot disagree. */
typedef struct DrBemAsset {
    const char *path;        /* the mesh file, the caller's string (not copied) */
    DrTriMesh mesh;          /* welded and checked, owned */
    int vertices_in_file;    /* before the weld */
    int welded;              /* vertices the weld merged */
    double weld_tolerance;   /* m */
    DrBemDesc desc;          /* a copy of desc */
    char mesh_hash[33], key[33];
} DrBemAsset;
/* DR_ERR_INPUT for a missing, unreadable, open, non-manifold or inward mesh, err->file then the mesh file (unless
 * the failure named another); *out holds nothing to free after any failure. */
DR_NODISCARD DrStatus dr_bem_asset_load(const char *path, const DrBemDesc *desc, DrBemAsset *out, DrError *err);
void dr_bem_asset_free(DrBemAsset *a);

/* ---- runtime: one body in a shot (BEM §3.1–3.2) ----------------------------------------------------------
 * The body's vertices are V = R (x − x̄ + u) + T: a rigid frame (rotation R, position T of the centre of mass x̄)
 * carries the rest shape x and the displacement u of eq. (9), which the boundary element matrices advance one
 * step of Δt = matrices->desc.dt at a time. Tractions are given per vertex in the body frame (Pa). */
typedef struct DrBemSolidDesc {
    double gravity[3];          /* g in the inertial frame, m/s² */
    double rotation[9];         /* R at t = 0, row-major */
    double position[3];         /* T at t = 0: where the centre of mass x̄ is, m */
    double velocity[3];         /* Ṫ at t = 0, m/s */
    double angular_velocity[3]; /* ω at t = 0 in the inertial frame, rad/s */
    bool frame_update;          /* move the frame by eqs. (10)–(11); false: R, T stay and u carries all motion */
    bool error_correction;      /* §3.2.1: move drift of u into the frame (only with frame_update) */
} DrBemSolidDesc;
void dr_bem_solid_desc_default(DrBemSolidDesc *d); /* identity pose at the origin, at rest, g = (0, −9.81, 0) */

typedef struct DrBemSolid DrBemSolid;
/* The solid keeps a pointer to m, which must outlive it (several solids may share one matrix set). */
DR_NODISCARD DrStatus dr_bem_solid_create(const DrBemMatrices *m, const DrBemSolidDesc *d, DrBemSolid **out,
                                          DrError *err);
void dr_bem_solid_destroy(DrBemSolid **s);

typedef struct DrBemStepStats {
    double seconds_history;    /* the history sums of eq. (9) */
    double seconds_solve;      /* eq. (12) and the frame (11) */
    double seconds_correction; /* §3.2.1 */
    double translation_error;  /* drift moved from u into the frame by error correction, m */
    double rotation_error;     /* its rotation angle, rad */
} DrBemStepStats;

/* One step with nodal tractions p (3N, body frame, Pa; NULL = traction-free). DR_ERR_RUNTIME if the state
 * turns non-finite (the step is refused and the previous state kept). st may be NULL. The same, bit for bit, as
 * dr_bem_solid_predict + dr_bem_solid_solve(traction, NULL) + dr_bem_solid_commit below. */
DR_NODISCARD DrStatus dr_bem_solid_step(DrBemSolid *s, const double *traction, DrBemStepStats *st, DrError *err);

/* ---- the step in phases (DESIGN §8) ------------------------------------------------------------------------------
 * predict → samples → solve(load) … solve(load) → commit. What eq. (9) sums over past steps (the history of u, p and
 * the frame accelerations) does not depend on this step's load, so predict computes it once; a solve is the rest of
 * the step for one load: eq. (12) for u, the error correction of §3.2.1 and the frame of eqs. (10)–(11); commit
 * takes the last solve into the state and the history window. Between predict and commit the state
 * (dr_bem_solid_state_get, the readers below) stays that of the start of the step; each solve starts again from
 * the prediction, so solving again with another load gives what that solve alone would have given. Misuse (a solve
 * without a prediction, a commit without a successful solve since predict) asserts; dr_bem_solid_state_set drops a
 * prediction. No phase allocates. */

/* The body's time step: matrices->desc.dt, not a limit but the only step it can take. The convolution quadrature
 * weights H_k, G_k, D_k, Q_k are built for it, and every phase advances by exactly one such step, so a clock shared
 * with other solvers must land on this body's step ends (t = k·dt from the body's start): take smaller steps for the
 * others in between and hand the body the load gathered over its step (DESIGN §8, step 5). */
double dr_bem_solid_stable_dt(const DrBemSolid *s);

/* Starts step s->step + 1: the history sums of eq. (9) and their H₀⁻¹ product (seconds in the solve's
 * seconds_history). Always DR_OK; a second predict of the same step reuses the sums. */
DR_NODISCARD DrStatus dr_bem_solid_predict(DrBemSolid *s, DrError *err);

/* The points where the body meets other solvers: its N surface vertices, borrowed (the solid's own arrays, filled by
 * this call and valid until the next call of it or of any phase). SI units, world frame. */
typedef struct DrBemSamples {
    int n;                /* N */
    const double *x;      /* 3N positions at the start of the step (between steps: now), m */
    const double *v;      /* 3N velocities Ṫ + ω × R(x − x̄ + u) + R u̇: of the last solve since predict (the end of
                             the step it would commit, u̇ = (u₊ − u)/Δt); else of the start of the step (u̇ from the
                             history window; the frame's motion alone when the window holds one step), m/s */
    const double *normal; /* 3N unit outward normals at x (the normalised sum of the vertex's triangle areas) */
    const double *area;   /* N: ∫Φ_j over the rest surface, m²: a force f at vertex j acts as the traction f/area_j */
} DrBemSamples;
DrBemSamples dr_bem_solid_samples(DrBemSolid *s);

/* Solves the predicted step for the load p = traction + Rᵀ f / area_j (R the rotation at the start of the step):
 * traction 3N, body frame, Pa, and force 3N, world frame, N at the vertices (either NULL: none; both NULL: the
 * traction-free step). The load acts over the whole step (eqs. 10–12 are linear in it); there is no implicit
 * force derivative, so a velocity-dependent law is applied explicitly, from the samples. Commits nothing:
 * callable several times after one predict, each from the prediction alone. DR_ERR_RUNTIME if the state would turn
 * non-finite (then a commit needs another solve). st (may be NULL) receives this solve's figures, seconds_history
 * those of the prediction. */
DR_NODISCARD DrStatus dr_bem_solid_solve(DrBemSolid *s, const double *traction, const double *force,
                                         DrBemStepStats *st, DrError *err);

/* Ends the step with the last solve: u, the frame, and the step's entry of the history window (ũ, p̃, b, α).
 * st (may be NULL) receives that solve's figures. */
void dr_bem_solid_commit(DrBemSolid *s, DrBemStepStats *st);

const DrBemMatrices *dr_bem_solid_matrices(const DrBemSolid *s);
long dr_bem_solid_steps(const DrBemSolid *s);                         /* steps taken */
void dr_bem_solid_pose(const DrBemSolid *s, double R[9], double T[3]); /* the frame */
void dr_bem_solid_frame_velocity(const DrBemSolid *s, double v[3], double w[3]); /* Ṫ and ω, inertial */
const double *dr_bem_solid_displacement(const DrBemSolid *s);         /* u, 3N, body frame */
void dr_bem_solid_positions(const DrBemSolid *s, double *V);          /* 3N world positions */
/* x − x̄, 3N: the rest shape about the centre of mass (what R and u act on). */
const double *dr_bem_solid_reference(const DrBemSolid *s);

typedef struct DrBemSolidDiag {
    double momentum[3];         /* m Ṫ, kg m/s */
    double angular_momentum[3]; /* R I Rᵀ ω about the centre of mass, kg m²/s */
    double kinetic;             /* ½ m |Ṫ|² + ½ ωᵀ R I Rᵀ ω of the frame, J */
    double potential;           /* −m g·T, J */
    double volume;              /* enclosed volume of the deformed surface, m³ */
    double max_displacement;    /* max |u_i|, m */
} DrBemSolidDiag;
void dr_bem_solid_diagnostics(const DrBemSolid *s, DrBemSolidDiag *out);

/* The whole state for a bit-identical resume: the history window of u, p and the frame accelerations, the frame
 * and the step count, as one flat array of dr_bem_solid_state_size() doubles. */
size_t dr_bem_solid_state_size(const DrBemSolid *s);
void dr_bem_solid_state_get(const DrBemSolid *s, double *state);
DR_NODISCARD DrStatus dr_bem_solid_state_set(DrBemSolid *s, const double *state, size_t size, DrError *err);

/* ---- runtime: constraints, contact and friction (BEM §3.4) ----------------------------------------------------
 * dr_bem_solids_step advances every body one step with position-level constraints solved for nodal forces: a force
 * f at a vertex acts as the traction f / area_j (area_j = ∫Φ_j) on it. Constraints live at vertices: fixed vertices
 * held at world positions, vertices kept outside colliders (signed distance callbacks) with Coulomb friction, point
 * joints holding a vertex of one body on a vertex of another, and optionally contact with friction between bodies (a
 * vertex of one body kept outside the triangles of another, found through the broad phase of src/contact; its force
 * is shared by the triangle's vertices with barycentric weights). All positions are world positions (m) at the end of the step;
 * forces are world-frame newtons. Bodies in one call are stepped with the same Δt (each solid's
 * matrices must share desc.dt). Not thread-safe for the same solids; callbacks are called from the calling thread. */

/* Signed distance to a collider at x (m, negative inside); grad, if not NULL, receives its gradient (the outward
 * normal where the distance is exact). */
typedef double (*DrBemSdfFn)(const double x[3], double grad[3], void *ctx);
/* The collider's velocity at x (m/s, world frame). */
typedef void (*DrBemVelocityFn)(const double x[3], double v[3], void *ctx);

typedef struct DrBemCollider {
    DrBemSdfFn sdf;           /* required */
    DrBemVelocityFn velocity; /* NULL: the collider is at rest */
    void *ctx;                /* passed to both callbacks, not owned */
    double friction;          /* Coulomb μ ≥ 0 */
} DrBemCollider;

typedef struct DrBemFixed {
    int body, vertex;  /* index into the solids array, vertex of that body's mesh */
    double target[3];  /* world position the vertex is held at, m */
} DrBemFixed;

typedef struct DrBemJoint {
    int body[2], vertex[2]; /* the two vertices held together (equal and opposite forces) */
} DrBemJoint;

typedef struct DrBemConstraints {
    const DrBemCollider *colliders;
    int collider_count;
    double thickness;       /* contact offset: a vertex is kept at sdf ≥ thickness, and is active once its
                               unconstrained position comes closer than 2·thickness, m */
    const DrBemFixed *fixed;
    int fixed_count;
    const DrBemJoint *joints;
    int joint_count;
    bool body_contact;      /* keep every vertex of each body outside every other body (no self-contact; a vertex
                               found deeper than the other body's mean edge length is left alone) */
    double body_friction;   /* Coulomb μ ≥ 0 between bodies */
    int max_iterations;     /* projected Gauss–Seidel sweeps per pass */
    int max_passes;         /* re-linearisations: trial step with the current forces, solve again */
    double tolerance;       /* position error accepted for fixed vertices, joints and penetration, m */
} DrBemConstraints;
/* No constraints, no body contact; thickness 1e-4 m, body friction 0.5, 200 sweeps, 8 passes, tolerance 1e-7 m. */
void dr_bem_constraints_default(DrBemConstraints *c);

typedef struct DrBemConstraintStats {
    int fixed, contacts, joints; /* active constraints this step (contacts: against colliders) */
    int body_contacts;           /* vertex–triangle contacts between bodies */
    int sticking;                /* contacts whose friction force is inside the cone */
    int iterations;              /* PGS sweeps, all passes */
    int passes;                  /* linearisations solved (1 = the paper's single solve) */
    double residual;             /* largest fixed/joint position error or penetration after the step, m (0 when
                                    nothing was active) */
    double seconds_trial;        /* trial steps (zero-force, external-force and re-linearisation passes) */
    double seconds_detect;       /* collider queries, body-pair detection, and measuring each pass's trial */
    double seconds_assembly;     /* the dense response blocks */
    double seconds_pgs;
    double seconds_final;        /* the commit (bodies without constraints: their whole steps) */
} DrBemConstraintStats;

/* One step of every solid. Fails with DR_ERR_INPUT (nothing stepped) on an out-of-range body or vertex index, a
 * collider without sdf, negative friction or thickness, a non-positive tolerance, or solids with different Δt;
 * DR_ERR_RUNTIME (nothing stepped) if a body's step would turn non-finite. DR_WARN_NOT_CONVERGED (all bodies stepped)
 * when the residual is still above the tolerance after max_passes. st may be NULL. The same, bit for bit, as
 * dr_bem_solids_predict + dr_bem_solids_solve(NULL) + dr_bem_solids_commit below.
 *
 * What the constrained step needs from step to step (the active lists, the response blocks, the constraints, the
 * sweep's panel, the broad phase) is kept by solids[0] and grows only when a step needs more than any before it, by
 * half as much again: once the first step of a scene has run, a step whose active set stays within that headroom
 * makes no heap allocation (the first constrained step of a body on a compressed set also builds the set's column
 * copy of H₀⁻¹G′, once). */
DR_NODISCARD DrStatus dr_bem_solids_step(DrBemSolid *const *solids, int count, const DrBemConstraints *c,
                                         DrBemConstraintStats *st, DrError *err);

/* ---- the constrained step in phases (DESIGN §8) --------------------------------------------------------------------
 * predict → samples (dr_bem_solid_samples of each solid) → solve(forces) … solve(forces) → commit, for one list of
 * solids (the same pointers in the same order in every phase; solids[0] holds the prediction, a solid leads one at a
 * time, and a new predict replaces one not committed). Between predict and commit every solid's state stays that of
 * the start of the step; each solve starts again from the prediction (the constraints as detected, no constraint
 * force), so it gives what that solve alone would have given, and commits nothing. c and what it points to must stay
 * unchanged until commit (a solve calls the colliders' sdf again). Misuse asserts; dr_bem_solid_state_set on
 * solids[0] drops the prediction.
 *
 * Predict: each body's history sums (dr_bem_solid_predict) and the trial step without forces that gives its
 * unconstrained end-of-step positions; the active set found there (fixed vertices, joints, collider and body
 * contacts); the dense response blocks of the active vertices and each constraint's own block. Fails as
 * dr_bem_solids_step (DR_ERR_INPUT, DR_ERR_RUNTIME), nothing stepped. st (may be NULL) receives its counts and
 * seconds. */
DR_NODISCARD DrStatus dr_bem_solids_predict(DrBemSolid *const *solids, int count, const DrBemConstraints *c,
                                            DrBemConstraintStats *st, DrError *err);

/* Projected Gauss–Seidel and the trial passes of the predicted step, with external point forces: force NULL (none) or
 * count pointers, force[i] NULL or 3N_i world-frame newtons at the vertices of solids[i]. They act over the whole step
 * with the constraint forces (the solid's load is traction + Rᵀ(f_constraint + f_external)/area_j, see
 * dr_bem_solid_solve); with them, the constraints start from a trial step with the external forces alone. The active
 * set is the prediction's: a vertex the external forces push into a collider that the force-free trial kept clear of
 * it gets no contact this step. Every solid ends with the solve of its last trial (dr_bem_solid_samples: the solved
 * velocities). DR_WARN_NOT_CONVERGED as dr_bem_solids_step (the result may be committed); DR_ERR_RUNTIME if a trial
 * would turn non-finite (no commit before another solve succeeds). st (may be NULL) receives the step's figures:
 * the prediction's and this solve's. */
DR_NODISCARD DrStatus dr_bem_solids_solve(DrBemSolid *const *solids, int count, const double *const *force,
                                          DrBemConstraintStats *st, DrError *err);

/* Every solid commits its last trial (the forces of the solve's last pass). st (may be NULL) receives the step's
 * figures, seconds_final those of the commit. */
void dr_bem_solids_commit(DrBemSolid *const *solids, int count, DrBemConstraintStats *st);

#endif
