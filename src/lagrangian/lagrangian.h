/* drench lagrangian: the one solver for Lagrangian vertex objects (hair now, cloth later), fei2017 §S4 and
 * PHYSICS §4.
 *
 * Model. A system holds generalised coordinates q (positions, and rod twists) split into objects: each
 * object owns a contiguous range of DOFs and a half-bandwidth kd (a rod with DOFs x0 θ0 x1 θ1 … has
 * kd = 10). Every force is a constraint group: a few rows φ over a short list of DOFs with a diagonal
 * compliance C, so its energy is ½ φᵀC⁻¹φ (eq. S19); a viscous group acts on velocities, ½ φ_vᵀC_v⁻¹φ_v
 * (eq. S20), with φ_v = J_v q̇ + c (drag, internal damping; ∂φ_v/∂q = J_xv is taken as zero).
 *
 * One step is the linearised implicit Euler of eqs. (S21)–(S27):
 *     (M − h²K) q̇₊ = M q̇ + h [f_e − JᵀC⁻¹φ − J_vᵀC_v⁻¹(φ_v − J_v q̇)]                          (S26)
 *     −K = JᵀC⁻¹J + h⁻¹ J_vᵀC_v⁻¹J_v − Σ_k λ_k ∇²φ_k                                           (S27)
 * where λ are the multipliers of the previous step (the caller passes the geometric stiffness
 * G = Σ_k λ_k ∇²φ_k of a group, evaluated with its own stored λ), and afterwards
 *     λ₊ = −C⁻¹(φ + h J q̇₊)        λ_v₊ = −C_v⁻¹(φ_v + J_v (q̇₊ − q̇))                       (S24, S25)
 * are written back through the group's λ pointer.
 *
 * Solve (Pseudocode S1). A group whose DOFs all lie in one object within its band goes into that
 * object's banded block A_i*; any other (hair–hair contact, cohesion) into the inter-object matrix K_G.
 * Each block is factored once per step by banded Cholesky (LAPACK dpbtrf through src/linalg DrBanded:
 * a rod's block is SPD with a constant small band, so a banded factorisation costs O(n kd²) with no fill
 * and no symbolic phase, where CHOLMOD's supernodal machinery buys nothing). The block solves give the
 * initial guess (intra-object right-hand side b_i*) and precondition conjugate gradients on the whole
 * system. Beyond the paper's A_i*, the part of K_G that falls on one object's own DOFs inside its band (a
 * contact's self terms) joins that object's preconditioner block, making it the block-Jacobi
 * preconditioner of the whole A: one step of a 1,024-hair groom with 29,000 stiff contacts (1e3 N/m, 1e-4 s)
 * took 495 iterations with it against 839 without. Those terms are the in-band part of a positive semidefinite
 * matrix, which can be indefinite when a contact's DOFs on one object spread wider than the band (two edges
 * of one strand); a block whose factorisation fails with them is preconditioned without them (Stats counts
 * those blocks), A itself is untouched.
 * CLUSTER sees K_G too: objects joined through it (strands bridged or in contact) are grouped into clusters, each
 * preconditioned by the sparse Cholesky factor (CHOLMOD, src/linalg DrChol) of its whole part of A, the others by
 * their blocks as BLOCK does: a cluster that holds a connected part of the system solves it exactly (a bundle of
 * 1,024 strands with springs along their length: 1 iteration per step against 120–1,150 with BLOCK; a 1,024-strand
 * groom in dry contact: 1 against 320). Clusters are made at the first solve of a step by union-find over K_G's
 * pairs of objects, strongest coupling first, and cut where needed so that no cluster's factor holds more than
 * desc.cluster_entries entries (the symbolic analysis tells before any numeric work); they depend on that step's
 * K_G and diagonal alone. A cluster whose factorisation fails (A not positive definite in round-off, geometric
 * stiffness in K_G) is preconditioned by its objects' blocks (Stats.clusters_failed). The factorisation is the cost:
 * a cluster of strands coupled along their whole length fills in like a 3-D grid (the 1,024-strand bundle's factor
 * holds 4e7 entries, 320 MB), so for soft couplings, which BLOCK handles in a few hundred iterations, CLUSTER can be
 * slower (tests/bench/bench_hair measures both).
 * Jacobi (diag A) and unpreconditioned CG are there for comparison. A block whose geometric stiffness
 * makes it indefinite drops its geometric stiffness (operator and preconditioner alike, so CG still sees
 * one SPD matrix); Stats counts those blocks.
 *
 * Stopping test: ‖r‖_{M⁻¹} ≤ tol ‖b‖_{M⁻¹}, the mass-weighted residual (a velocity error weighted by
 * mass). The paper's rᵀr mixes momenta of positions and of twists, whose scales differ by ~10¹²; the
 * mass norm treats both in their own units and is the same test for every preconditioner.
 *
 * Prescribed DOFs (hair roots that follow the scalp) take a given velocity; their rows and columns are
 * eliminated symmetrically, so A stays SPD and their velocity enters the right-hand side.
 *
 * Ownership and threads: the system owns its matrices; a group's data are copied at dr_lag_add time
 * except λ, whose storage belongs to the caller and must stay put until dr_lag_solve (or
 * dr_lag_update_multipliers) returns.
 * dr_lag_add may be called concurrently for groups of different objects (each object has its own
 * record buffer); groups that go to K_G must be added from one thread (dr_lag_add_global). Loops run
 * through dr_parallel_for; results are bit-identical for any thread count, and depend on the step's inputs
 * only (never on earlier steps), for every preconditioner.
 *
 * Memory: a step after the first allocates nothing while its groups fit the buffers (the first step leaves room
 * for twice its own) and, with CLUSTER, while every cluster keeps the objects and the pattern it had in the step
 * before (its matrix, analysis and factor are kept; CHOLMOD's own blocks are recycled, dr_alloc_count counts
 * them). A cluster whose pattern changes (contacts come and go) is analysed again, which may allocate. */
#ifndef DR_LAGRANGIAN_H
#define DR_LAGRANGIAN_H

#include "core/core.h"

#define DR_LAG_MAX_ROWS 8  /* rows of one group */
#define DR_LAG_MAX_DOFS 24 /* DOFs of one group (edge–edge contact: 12; a rod's bending: 11) */

typedef enum DrLagPrecond {
    DR_LAG_PRECOND_BLOCK,  /* per-object banded Cholesky (Pseudocode S1) */
    DR_LAG_PRECOND_JACOBI, /* diag(A) */
    DR_LAG_PRECOND_NONE,   /* plain CG */
    DR_LAG_PRECOND_CLUSTER /* objects joined through K_G in clusters, each cluster's part of A factored whole */
} DrLagPrecond;

typedef struct DrLagDesc {
    DrLagPrecond precond; /* default BLOCK */
    double cluster_entries; /* CLUSTER: the most entries (doubles) of one cluster's factor; default 2^26 (512 MiB) */
    double tol;           /* relative mass-weighted residual; default 1e-8 */
    int max_iter;         /* default 1000; reaching it is DR_WARN_NOT_CONVERGED */
    bool local_guess;     /* start from the block solves (S1 lines 1–3); default true. false: q̇₊ = q̇ */
} DrLagDesc;
void dr_lag_desc_default(DrLagDesc *d);

typedef enum DrLagKind { DR_LAG_POSITIONAL, DR_LAG_VISCOUS } DrLagKind;

/* One constraint group, filled by a model (src/hair, src/cloth) every step. */
typedef struct DrLagGroup {
    DrLagKind kind;
    int nrows;                           /* 1..DR_LAG_MAX_ROWS */
    int ndof;                            /* 1..DR_LAG_MAX_DOFS */
    int dof[DR_LAG_MAX_DOFS];            /* global DOF indices, distinct */
    double phi[DR_LAG_MAX_ROWS];         /* φ (positional) or c = φ_v − J_v q̇ (viscous: the part of φ_v not
                                            proportional to the velocity), units of the row */
    double cinv[DR_LAG_MAX_ROWS];        /* C⁻¹ (or C_v⁻¹) per row, > 0 */
    double J[DR_LAG_MAX_ROWS * DR_LAG_MAX_DOFS]; /* row-major nrows × ndof: J (or J_v) */
    const double *G;                     /* NULL or ndof × ndof row-major symmetric Σ λ_k ∇²φ_k */
    double *lambda;                      /* NULL or nrows multipliers, written by dr_lag_solve */
} DrLagGroup;

typedef struct DrLagStats {
    int iterations;        /* CG iterations (0 when the initial guess already meets the tolerance) */
    double residual;       /* final ‖r‖_{M⁻¹} / ‖b‖_{M⁻¹} */
    bool converged;
    int groups_block;      /* groups assembled into the object blocks */
    int groups_global;     /* groups in K_G */
    int indefinite_blocks; /* blocks that dropped their geometric stiffness */
    int contact_blocks_dropped; /* blocks preconditioned without their in-band contact terms (which made the
                                   preconditioner block indefinite; see the header) */
    int clusters;          /* CLUSTER: clusters of two objects or more */
    int cluster_dofs_max;  /* CLUSTER: DOFs of the largest */
    int clusters_failed;   /* CLUSTER: clusters preconditioned by their objects' blocks instead (not positive definite) */
    int cluster_analyses;  /* CLUSTER: symbolic analyses in this solve's factorisations (a cluster whose pattern
                              changed) */
    double cluster_entries; /* CLUSTER: entries of the clusters' factors (doubles) */
    double seconds_assemble, seconds_factor, seconds_solve;
} DrLagStats;

typedef struct DrLag DrLag;

DR_NODISCARD DrStatus dr_lag_create(const DrLagDesc *desc, DrLag **out, DrError *err);
void dr_lag_destroy(DrLag **s);
void dr_lag_set_desc(DrLag *s, const DrLagDesc *desc);

/* Appends an object of ndof DOFs (≥ 1) with half-bandwidth kd (0 ≤ kd < ndof, or 0 for ndof = 1); returns
 * its id (0, 1, …) and, in *dof_begin, the index of its first DOF. Only between steps. */
DR_NODISCARD DrStatus dr_lag_add_object(DrLag *s, int ndof, int kd, int *id, int *dof_begin, DrError *err);
int dr_lag_object_count(const DrLag *s);
int dr_lag_dof_count(const DrLag *s);

/* ---- one system, several models (DESIGN §8 "One Lagrangian system") ---------------------------------------------
 * The world owns one system; every model (the rod set; cloth and wet later) adds its objects to it and fills its own
 * objects' DOF ranges of the per-DOF arrays below, then the owner begins the step with them, every model adds its
 * groups, the owner solves into qdot_out, every model reads its range, the owner updates the multipliers, and every
 * model commits. A model alone in a system of its own does the same by itself. */
typedef struct DrLagDofs {
    double *mass;            /* kg per position DOF, kg m² per twist */
    double *qdot;            /* velocity at the start of the step */
    double *fext;            /* external generalised force over the step (gravity) */
    unsigned char *prescribed; /* nonzero: the DOF moves with qdot_prescribed */
    double *qdot_prescribed;
    double *force;           /* a solve's load (DrLagLoad.force), written by the models that have one */
    double *qdot_out;        /* the solve's result */
} DrLagDofs;
/* The system's per-DOF arrays, each of dr_lag_dof_count values, owned by the system: allocated by the first call after
 * an object was added (zeroed), the same pointers otherwise (no allocation), valid until the next dr_lag_add_object or
 * dr_lag_destroy. */
DR_NODISCARD DrStatus dr_lag_dofs(DrLag *s, DrLagDofs *out, DrError *err);

/* Starts a step of size h > 0: A ← diag(mass), b ← mass ∘ qdot + h f_ext (f_ext NULL: zero).
 * mass (> 0 per DOF; kg or kg m² for a twist), qdot, f_ext: length dr_lag_dof_count.
 * prescribed: NULL or a flag per DOF (nonzero: the DOF moves with the velocity qdot_prescribed[dof]). */
DR_NODISCARD DrStatus dr_lag_begin(DrLag *s, double h, const double *mass, const double *qdot,
                                   const double *f_ext, const unsigned char *prescribed,
                                   const double *qdot_prescribed, DrError *err);

/* Adds a group (see the threading note above). A group outside one object's band is DR_ERR_INPUT here;
 * add it with dr_lag_add_global. Non-finite φ, J, C⁻¹ or G is DR_ERR_RUNTIME naming the DOFs. */
DR_NODISCARD DrStatus dr_lag_add(DrLag *s, const DrLagGroup *g, DrError *err);
/* dr_lag_add of g and, when damping > 0 (s), of its viscous twin: the same rows and Jacobian on the velocities,
   C_v⁻¹ = damping · C⁻¹ (a Kelvin–Voigt time constant: the viscous force is damping times the elastic force's rate),
   no constant, no geometric stiffness, no multipliers kept. */
DR_NODISCARD DrStatus dr_lag_add_with_twin(DrLag *s, const DrLagGroup *g, double damping, DrError *err);
/* Adds a group to K_G (any DOFs); one thread at a time. */
DR_NODISCARD DrStatus dr_lag_add_global(DrLag *s, const DrLagGroup *g, DrError *err);

/* Factors the blocks, solves (S26) for q̇₊ (qdot_out, length dof count; prescribed DOFs get their
 * prescribed velocity) and writes λ₊ of every group with a λ pointer, ending the step (the next call is
 * dr_lag_begin). The same as dr_lag_solve_load(s, NULL, …) then dr_lag_update_multipliers(s, qdot_out), bit
 * for bit. DR_WARN_NOT_CONVERGED when CG stops at max_iter (q̇₊ is the last iterate, λ updated from it);
 * DR_ERR_RUNTIME on a non-finite iterate or a breakdown (A not positive definite even after dropping
 * geometric stiffness). */
DR_NODISCARD DrStatus dr_lag_solve(DrLag *s, double *qdot_out, DrLagStats *stats, DrError *err);

/* External load on one solve: generalised forces, and 3×3 velocity derivatives on triples of DOFs (a vertex's
 * x, y, z), for forces that come from outside the constraint system (drag from a fluid) and change from one
 * solve to the next while the groups stay. Over the step the load's force on the DOFs of block k is
 *     f + D_k q̇₊        (D_k = dforce_dv of block k, row-major, N·s/m for positions),
 * so (S26) becomes (M − h²K − h D) q̇₊ = M q̇ + h [f_e + f − …]: D enters A like extra mass (damping, for D
 * negative definite) on the block's own DOFs; a law f(q̇) linearised about q̇* passes f = f(q̇*) − D q̇*.
 * A needs to stay symmetric, so the symmetric part ½(D + Dᵀ) enters; it must leave A positive definite (D
 * negative semidefinite always does). Forces and blocks on prescribed DOFs are ignored (their velocity is
 * given); a block coupling a free DOF to a prescribed one moves the known velocity to the right-hand side. */
typedef struct DrLagLoad {
    const double *force;     /* NULL or dof count values (N, or N·m on a twist) */
    int nblocks;             /* 0 when dforce_dv is NULL */
    const int *block_dof;    /* nblocks: block k acts on DOFs block_dof[k] + 0, 1, 2, all of one object within its
                                band (kd ≥ 2) */
    const double *dforce_dv; /* NULL or nblocks × 9: ∂f/∂q̇ of block k, row-major */
} DrLagLoad;

/* Solves (S26) with the groups added since dr_lag_begin plus `load` (NULL: none) for q̇₊ (qdot_out) without
 * touching any λ: callable any number of times between one begin and the next (adding groups after the first
 * call is a programmer error), each solve independent of the ones before it (the same load gives the same bits).
 * Stats and failures as dr_lag_solve; after a failure the step can still be solved again. */
DR_NODISCARD DrStatus dr_lag_solve_load(DrLag *s, const DrLagLoad *load, double *qdot_out, DrLagStats *stats,
                                        DrError *err);

/* Writes λ₊ = −C⁻¹(φ + h J q̇₊), λ_v₊ = −C_v⁻¹(φ_v + J_v (q̇₊ − q̇)) (S24, S25) of every group with a λ pointer,
 * for the velocity q̇₊ = qdot (normally the solve's result that is kept). Between begin and the next begin. */
void dr_lag_update_multipliers(DrLag *s, const double *qdot);

/* f += Σ_g J_gᵀ λ_g over every group added since dr_lag_begin, λ_g as dr_lag_update_multipliers computes it for the
 * velocity qdot (whether or not the group keeps its λ): the generalised force the constraints exert over the step (N,
 * or N·m on a twist). For diagnostics, such as the work done on the system through its prescribed DOFs. Between begin
 * and the next begin; serial, in a fixed order. */
void dr_lag_constraint_forces(const DrLag *s, const double *qdot, double *f);

/* y = A x with the matrix the last dr_lag_solve used (prescribed DOFs eliminated, geometric stiffness as kept). */
void dr_lag_apply(const DrLag *s, const double *x, double *y);

#endif
