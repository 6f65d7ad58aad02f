/* drench mpm: hyperelastic solids on the material point method with the transfers of src/transfer
 * ([APIC] §3–4, PHYSICS §2).
 *
 * One DrMpm owns one collocated node grid (src/transfer DrNodeGrid) and every MPM particle of a shot,
 * whatever body it belongs to: bodies on one grid collide with each other through the grid as MPM does.
 * A step: bin particles, P2G (eqs. 24–26), grid update by the chosen integrator (eqs. 27–36; midpoint as
 * the minimisation of §4.1 by Newton with a backtracking line search, each Newton system solved by CG
 * on A₂ = I + ζ M⁻¹ ∂f/∂x with the mass inner product of §4.2, so momentum is conserved even when CG
 * stops early), grid boundary conditions, G2P (eqs. 37–39) and the F update (eq. 40, or eqs. 109–111).
 *
 * Units SI. dim = 2 simulates in the xy plane (per-unit-depth masses and volumes: kg/m and m²).
 * Ownership: the solver owns its particle arrays; pointers from dr_mpm_state stay valid until the next
 * dr_mpm_add_* call. Thread safety: one solver per thread of control; the solver itself runs its loops
 * in parallel through dr_parallel_for, bit-identically for any thread count. */
#ifndef DR_MPM_H
#define DR_MPM_H

#include "core/core.h"
#include "transfer/transfer.h"

typedef enum DrMpmModel { DR_MPM_NEOHOOKEAN, DR_MPM_FIXED_COROTATED } DrMpmModel;
typedef enum DrMpmIntegrator {
    DR_MPM_SYMPLECTIC_EULER, /* λ = 0, explicit */
    DR_MPM_MIDPOINT,         /* λ = ½, implicit (§4.1) */
    DR_MPM_BACKWARD_EULER    /* for comparison; not momentum-conserving in angular momentum */
} DrMpmIntegrator;
typedef enum DrMpmWall { DR_MPM_WALL_NONE, DR_MPM_WALL_SLIP, DR_MPM_WALL_NO_SLIP } DrMpmWall;

typedef struct DrMpmMaterial {
    DrMpmModel model;
    double density;       /* ρ, kg/m³ (kg/m² in 2-D) */
    double youngs;        /* E, Pa */
    double poisson;       /* ν, [0, 0.5) */
} DrMpmMaterial;

/* Lamé parameters μ = E/(2(1+ν)), λ = Eν/((1+ν)(1−2ν)). */
void dr_mpm_lame(const DrMpmMaterial *m, double *mu, double *lambda);
/* Energy density Ψ(F), first Piola–Kirchhoff stress P = ∂Ψ/∂F and its differential dP = ∂P/∂F : dF, all
   3×3 row-major (2-D: the z row and column of F are those of the identity, and so are P's consistently).
   Neo-Hookean Ψ = μ/2 (tr FᵀF − d) − μ ln J + λ/2 ln² J; fixed corotated Ψ = μ‖F − R‖² + λ/2 (J − 1)².
   Neo-Hookean needs J > 0: returns false (and leaves the outputs unspecified) otherwise. */
bool dr_mpm_energy_density(DrMpmModel model, int dim, double mu, double lambda, const double F[9], double *psi);
bool dr_mpm_pk1(DrMpmModel model, int dim, double mu, double lambda, const double F[9], double P[9]);
bool dr_mpm_dpk1(DrMpmModel model, int dim, double mu, double lambda, const double F[9], const double dF[9],
                 double dP[9]);
/* In 2-D (the note above): F's z row and column are the identity's, dF's z row and column are ignored,
   and P, dP are returned with a zero z row and column (the out-of-plane stress of the 3-D formula is of
   no use to a per-unit-depth model; the xy block is the 2-D model's exactly). Fixed corotated's dP
   includes dR; where two singular values cancel (σ_i + σ_j = 0, an inverted element) dR is clamped.
   Polar decomposition F = R S with R a rotation (det R = +1, also for det F < 0: the smallest singular
   value carries the sign, as fixed corotated needs) and S = RᵀF (S may be NULL). 2-D: F's xy block. */
void dr_mpm_polar(int dim, const double F[9], double R[9], double S[9]);
/* The parts of F's polar decomposition fixed corotated needs: R, and in 3-D the SVD's V and signed σ (F = U Σ Vᵀ,
   R = U Vᵀ; zero in 2-D). The _polar forms of the energy, stress and differential take them (NULL: computed), so a
   solver computes them once per iterate and every product of its linear solve reuses them, bit for bit what the
   plain forms give; Neo-Hookean ignores them. */
typedef struct DrMpmPolar { double R[9], V[9], sig[3]; } DrMpmPolar;
void dr_mpm_polar_parts(int dim, const double F[9], DrMpmPolar *out);
bool dr_mpm_energy_density_polar(DrMpmModel model, int dim, double mu, double lambda, const double F[9],
                                 const DrMpmPolar *pol, double *psi);
bool dr_mpm_pk1_polar(DrMpmModel model, int dim, double mu, double lambda, const double F[9], const DrMpmPolar *pol,
                      double P[9]);
bool dr_mpm_dpk1_polar(DrMpmModel model, int dim, double mu, double lambda, const double F[9], const DrMpmPolar *pol,
                       const double dF[9], double dP[9]);

typedef struct DrMpmDesc {
    int dim;                    /* 2 or 3 */
    DrVec3 lo, hi;              /* simulation box, m; the grid adds the kernel's padding around it */
    double dx;                  /* Δx, m */
    DrKernel kernel;            /* default quadratic */
    DrTransferScheme scheme;    /* default APIC */
    double flip_blend;          /* PIC fraction of FLIP, [0, 1]; default 0 (pure FLIP) */
    DrMpmIntegrator integrator; /* default midpoint */
    int f_update_order;         /* 1: eq. (40); 2: eqs. (109)–(111). Default 1 */
    DrVec3 gravity;             /* m/s², default 0 */
    DrMpmWall wall[6];          /* boundary condition on the box faces −x, +x, −y, +y, −z, +z; default slip */
    double cfl;                 /* ν of §4.3, default 1 */
    double newton_tolerance;    /* stop when ‖g‖_M⁻¹ / ‖initial g‖ below this; default 1e-10 */
    int newton_max_iterations;  /* default 50 */
    double cg_tolerance;        /* relative residual in the mass norm; default 1e-10. The floor of the
                                   inexact-Newton forcing term: Newton iteration k asks CG for
                                   max(cg_tolerance, 1e-2·min(1, ‖r_k‖/‖r_0‖)) */
    int cg_max_iterations;      /* default 1000 */
} DrMpmDesc;
void dr_mpm_desc_default(DrMpmDesc *d);

typedef struct DrMpm DrMpm;
DR_NODISCARD DrStatus dr_mpm_create(const DrMpmDesc *desc, DrMpm **out, DrError *err);
void dr_mpm_destroy(DrMpm **mpm);

/* Adds n particles of one body: positions x (3n, inside the box), velocities v (3n), volumes vol (n, m³;
   m² in 2-D), mass = ρ·vol. C starts at the rigid-motion affine matrix C0 (9 values, may be NULL = 0)
   for APIC/RPIC and 0 otherwise; F = I. Returns the body id (0, 1, …) in *body. DR_ERR_INPUT for a
   particle outside the box or a non-finite value. */
DR_NODISCARD DrStatus dr_mpm_add_particles(DrMpm *mpm, long n, const double *x, const double *v, const double *vol,
                                           const double *C0, const DrMpmMaterial *mat, int *body, DrError *err);
/* Samples a body on a lattice of `per_cell` particles per axis per cell aligned with the grid (particle
   spacing Δx/per_cell, first particle at half a spacing from a cell corner), keeping the points where
   inside(x, ctx) is true; velocity v0 + ω × (x − centre) with the matching APIC C0 = [ω]× for rigid
   rotation. vol = (Δx/per_cell)^dim. */
typedef bool (*DrMpmInsideFn)(DrVec3 x, void *ctx);
DR_NODISCARD DrStatus dr_mpm_sample_body(DrMpm *mpm, DrMpmInsideFn inside, void *ctx, DrVec3 box_lo, DrVec3 box_hi,
                                         int per_cell, DrVec3 v0, DrVec3 omega, DrVec3 centre,
                                         const DrMpmMaterial *mat, int *body, long *count, DrError *err);

/* Zero-length springs pulling particles to fixed targets: energy ½ k ‖x_p^{n+1} − target‖² with x_p^{n+1}
   = Σ w x̃_i, part of Φ (implicit with midpoint and backward Euler, explicit with symplectic Euler).
   k per particle (N/m; N/m per metre depth in 2-D), 0 = none. Used for pinned particle sets. */
DR_NODISCARD DrStatus dr_mpm_set_anchors(DrMpm *mpm, const double *k, const double *target, DrError *err);

/* A collider for grid velocities: signed distance (negative inside the solid) and outward normal at x,
   moving with velocity vel. Nodes inside or on the surface after P2G lose their approaching normal
   velocity (relative to the collider) and keep the rest of their normal velocity through the step's
   solve, as a constraint of it like the walls (sticky: all of the relative velocity); a contact the
   solution pulls away from is released and the step solved again, so bodies bounce and lift off. Coulomb
   friction takes up to `friction` times the normal velocity change the contact absorbed from the
   tangential velocity. Nodes that were outside and end the step moving into the collider lose their
   approaching normal component afterwards. */
typedef double (*DrMpmSdfFn)(DrVec3 x, DrVec3 *normal, void *ctx);
/* Velocity of a collider's surface at x (a moving or spinning collider); NULL means the constant velocity. */
typedef DrVec3 (*DrMpmVelocityFn)(DrVec3 x, void *ctx);
typedef struct DrMpmCollider {
    DrMpmSdfFn sdf;
    void *ctx;                   /* passed to sdf and velocity_at */
    DrVec3 velocity;             /* m/s, used when velocity_at is NULL */
    double friction;             /* Coulomb coefficient */
    bool sticky;
    DrMpmVelocityFn velocity_at; /* optional, per point */
} DrMpmCollider;
DR_NODISCARD DrStatus dr_mpm_add_collider(DrMpm *mpm, const DrMpmCollider *c, DrError *err);

typedef struct DrMpmStats {
    int newton_iterations, cg_iterations; /* summed over the step(s) */
    double newton_residual;               /* last relative residual */
    int substeps;
    double seconds_transfer, seconds_solve;
    double collider_work;                 /* J, summed: the work the colliders' surfaces did on the bodies, Σ over
                                             the grid nodes that met a collider of the constraint impulse times the
                                             collider's surface velocity (0 for static colliders and walls) */
} DrMpmStats;
/* The largest step §4.3 allows: ν Δx / max_p(‖v_p‖ + (6√d/Δx)·‖B_p‖_F), with B_p = C_p D. */
double dr_mpm_cfl_dt(const DrMpm *mpm);
/* The solver's own step limit for the current state, s (INFINITY when nothing limits it: no particle
   moves, no gravity, and an implicit integrator): §4.3's with the speed gravity adds within the step,
   Δt (S + |g| Δt) <= ν Δx with S = ν Δx / dr_mpm_cfl_dt, i.e. Δt = 2νΔx / (S + √(S² + 4|g|νΔx)); for
   symplectic Euler also the explicit stability limits ν Δx/c (c = √((λ+2μ)/ρ), the fastest body) and
   2ν/√(k/m) for anchors; for midpoint also Δt ≤ √(4νΔx / (c ‖∇v‖)) over the particles (c the particle's
   dilatational wave speed √((λ+2μ)/ρ), ∇v its velocity gradient: the affine matrix C of APIC and RPIC, the P2G
   grid velocity's gradient for FLIP and PIC): the grid moves nodes on straight lines through a step, which
   stretches a turning body by (Δt‖∇v‖)², and a stiff body's undamped fast modes then grow under the midpoint rule
   (mpm.c: rotation_dt). For FLIP and PIC it uses the grid as scratch: call it between a commit and the next
   predict. dr_mpm_advance substeps by exactly this limit. */
double dr_mpm_stable_dt(const DrMpm *mpm);
/* One step of dt. Returns DR_OK, DR_WARN_NOT_CONVERGED (positive: Newton stopped at its iteration cap;
   the step is kept) or a negative status (non-finite state: DR_ERR_RUNTIME, naming the particle). */
DR_NODISCARD DrStatus dr_mpm_step(DrMpm *mpm, double dt, DrMpmStats *stats, DrError *err);
/* Details of dr_mpm_step:
   - Walls: a slip wall fixes the normal velocity component of the nodes on or beyond its plane, no-slip
     all of it; the projection is applied to the P2G velocity and kept on ṽ inside the implicit solve
     (residual and CG vectors projected), so walls are exact constraints of the λ-family update.
     DR_MPM_WALL_NONE leaves a face open: the grid extends dr_kernel_reach + 2 nodes beyond the box, and
     a particle whose stencil leaves the grid fails the step with DR_ERR_RUNTIME.
   - Implicit solves start from Δv = 0 (with an external force, from its impulse: dr_mpm_solve); if that
     configuration inverts a Neo-Hookean particle they start from the one of F^n instead (u = 0). Only a state whose F^n itself is outside Ψ's domain fails
     (DR_ERR_RUNTIME naming the particle); symplectic Euler fails the same way.
   - On a negative status the particle state (x, v, C, F) is the one before the step.
   - f_update_order = 2 applies eqs. (109)–(111) both to the F update and, with F^{n+λ} built from the
     same rule, to the implicit energy, forces and force differentials.
   - 2-D: z velocities and the z row and column of C are kept at 0.
   - FLIP: particles also receive the change the wall and collider projection made to the P2G velocity. */

/* The step opened into phases (DESIGN §8), for a caller that exchanges forces with other solvers within
   one step: dr_mpm_step(dt) is dr_mpm_predict(dt) + dr_mpm_solve(NULL, NULL) + dr_mpm_commit, bit for bit.
   The phases must come in that order: predict, then one or more solves, then commit (a commit needs the
   last solve to have succeeded; misuse asserts). A solve never changes what the next solve
   reads, so solving again from the same prediction with other forces gives what that solve alone would
   have given. Adding particles or colliders, setting anchors or restoring a state drops a prediction.

   Predict: bins the particles, P2G (eqs. 24–26), the wall projection and the collider contacts of the
   P2G velocity. Fails like dr_mpm_step (DR_ERR_INPUT for a step h that is not positive and finite,
   DR_ERR_RUNTIME for a particle that left the grid); the particle state is never changed. */
DR_NODISCARD DrStatus dr_mpm_predict(DrMpm *mpm, double h, DrError *err);

/* The points where the solids meet other solvers: the particles, borrowed (valid until the next phase
   call or any call that changes the particles). Between predict and commit: x, v the particle state at
   the start of the step (m, m/s), mass (kg), volume the current volume V₀ det F^n (m³); v_solved the
   grid velocity of the last dr_mpm_solve interpolated at x (Σ_i w_ip ṽ_i, what G2P hands APIC and PIC
   particles), NULL before the first solve. 2-D: per unit depth (kg/m, m²), z velocities 0. */
typedef struct DrMpmSamples {
    long n;
    const double *x, *v;     /* 3n */
    const double *mass;      /* n */
    const double *volume;    /* n */
    const double *v_solved;  /* 3n or NULL */
} DrMpmSamples;
DrMpmSamples dr_mpm_samples(const DrMpm *mpm);

/* The grid solve of the predicted step (eqs. 27–36 by the chosen integrator, contacts, friction) with
   external point forces at the samples: force (3n, N; N/m in 2-D, z ignored) or NULL for none, spread to
   the nodes by the transfer weights (f_i = Σ_p w_ip force_p, which keeps Σ force). dforce_dv (9n, a
   row-major 3×3 per sample, N·s/m, symmetric; NULL for none) makes the force implicit: the force acting
   is force_p + D_p (ṽ_p − v_p) with ṽ_p = Σ_i w_ip ṽ_i the solved velocity at the sample and v_p the
   sample velocity of the prediction (dr_mpm_samples' v), the drag term taken at the end-of-step velocity
   for both implicit integrators (unconditionally stable for a dissipative D, negative semidefinite).
   It enters the minimisation of §4.1 as the energy −β Σ_p (force_p·s_p + ½ s_p·D_p s_p), s_p = ṽ_p − v_p,
   and A₂ as −Δt M⁻¹ Wᵀ D W (W the weights), so it must be symmetric (to 1e-9 of its largest entry).
   Implicit solves start from Δv = Δt M⁻¹ f (f the spread force at Δv = 0, walls and contacts projected):
   the remaining Newton and CG corrections then have zero momentum (§4.2), so away from walls, colliders
   and anchors a force without dforce_dv changes the total momentum by Δt Σ force to round-off, even when
   CG or Newton stop early.
   Symplectic Euler adds the force explicitly and rejects dforce_dv (DR_ERR_INPUT: an explicit step has
   no implicit drag; use midpoint or backward Euler). dforce_dv without force is DR_ERR_INPUT too.
   Returns DR_OK, DR_WARN_NOT_CONVERGED (the result is kept and may be committed), DR_ERR_INPUT for
   non-finite or asymmetric inputs, or DR_ERR_RUNTIME (an undefined stress or energy, as dr_mpm_step);
   after a negative status another solve may be tried but not a commit. stats (may be NULL) receives this
   solve's Newton and CG iterations, last relative residual and seconds_solve (substeps 0). */
DR_NODISCARD DrStatus dr_mpm_solve(DrMpm *mpm, const double *force, const double *dforce_dv, DrMpmStats *stats,
                                   DrError *err);

/* G2P (eqs. 37–39), the F update (eq. 40 or 109–111) and advection with the last solve's grid velocity.
   DR_ERR_RUNTIME if a particle became non-finite; the state is then the one before the step. Either way
   the prediction is used up. */
DR_NODISCARD DrStatus dr_mpm_commit(DrMpm *mpm, DrError *err);

/* Advances by `duration` in substeps of at most dr_mpm_stable_dt (recomputed before each substep from
   what is left, evened out over it: k = ⌈left / limit⌉ equal substeps, at most max_substeps in all). */
DR_NODISCARD DrStatus dr_mpm_advance(DrMpm *mpm, double duration, int max_substeps, DrMpmStats *stats, DrError *err);

/* Hot per-particle arrays (read-only view; n particles). */
typedef struct DrMpmState {
    long n;
    const double *x, *v, *C, *F;  /* 3n, 3n, 9n, 9n */
    const double *mass, *vol0;    /* n */
    const int *body;              /* n */
} DrMpmState;
DrMpmState dr_mpm_state(const DrMpm *mpm);
/* Replaces the dynamic state (x, v, C, F) from a checkpoint; n must match. */
DR_NODISCARD DrStatus dr_mpm_restore(DrMpm *mpm, long n, const double *x, const double *v, const double *C,
                                     const double *F, DrError *err);

typedef struct DrMpmTotals {
    DrVec3 momentum, angular;   /* particles, about the origin, angular including the affine part */
    double kinetic, elastic;    /* ½Σ m v², Σ V₀ Ψ(F) */
    double gravity_potential;   /* −Σ m g·x */
} DrMpmTotals;
/* Totals over all particles (body < 0) or one body. */
DrMpmTotals dr_mpm_totals(const DrMpm *mpm, int body);

#endif
