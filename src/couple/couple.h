/* drench couple: drag, lift and buoyancy between Lagrangian solids (hair; cloth later) and a fluid on a MAC grid
 * (liquid or air), and the coupled loop that makes them agree within a step (PHYSICS §6, DESIGN §8; [AV] §2).
 *
 * ---- the laws, per solid element ([AV] eqs. 1–4) -----------------------------------------------------------------
 * An element (a rod vertex with the half edges beside it) of diameter D, volume V and unit direction e_∥, moving at
 * Δv relative to the fluid (density ρ, dynamic viscosity μ) feels
 *     f_drag = −(μV/D²) R C Rᵀ Δv,   R C Rᵀ = C_⊥ (I − e_∥e_∥ᵀ) + C_∥ e_∥e_∥ᵀ        (rods: C = diag(C_⊥, C_⊥, C_∥))
 *     C_l = 1/k_l + ξ_N · 1.75/√(150 k_l) · (1 − γ)^(−3/2) · (ρ D |Δv| / μ)^c,     l ∈ {⊥, ∥}
 * with γ the solid fraction around the element, ξ_N and c the nonlinear scale and degree, and the dimensionless
 * inverse permeabilities 1/k_l from one of two models:
 *   DR_DRAG_SCALES (default): 1/k_l = ξ_D ξ_l · C_S. The paper writes 1/k_l = ξ_D ξ_l/10⁴ ("chosen arbitrarily");
 *     with every ξ = 1 that puts a 1 mm piece of 100 µm hair in water at 7.9e-11 N per m/s, about 1e4–1e5 below
 *     the low-Reynolds drag on a thin cylinder. drench makes the scales relative to that drag instead: C_S =
 *     16/(ln(2Λ) + ½), Λ = L/D the strand's slenderness (its length over its diameter), so that with ξ_D = ξ_⊥ = 1 a
 *     rod moving across itself in the linear regime feels the slender-body (resistive-force) Stokes drag per unit
 *     length f/L = 4πμ|Δv|/(ln(2Λ) + ½) (Cox 1970, leading order in 1/ln Λ); lengthwise it feels ξ_∥ times that
 *     (slender-body theory gives about ½: the default ξ_∥ = 0.5). reference DR_DRAG_LITERAL restores the paper's
 *     C_S = 1e-4 for scenes tuned to it.
 *   DR_DRAG_PERMEABILITY: the Drummond–Tahir permeabilities of a fibre array of solid fraction γ (Fei et al. 2018),
 *     k̃_∥ = (−ln γ − 1.476 + 2γ − ½γ²)/(16γ), k̃_⊥ = (−ln γ − 1.476 + 2γ − 1.774γ² + 4.078γ³)/(32γ) (k = k̃ D²), and
 *     since Darcy's law gives the force per volume of the medium (the element's V/γ), 1/k_l = ξ_D ξ_l/(γ k̃_l); γ is
 *     clamped into [1e-4, 0.5].
 *     The nonlinear term is Ergun's inertial one with either model.
 *     f_lift = −ξ_L (Q − (Q·Δv/|Δv|²) Δv),  Q = e_∥ × (e_∥ × f_drag)                                     (eq. 4)
 * orthogonal to Δv, zero along and across the rod, ½ ξ_L (μV/D²) C_⊥ |Δv| sin 2φ at angle φ between them. It is
 * explicit (it does no work on Δv but can feed energy through the solid's response): dr_couple_stable_dt bounds the
 * step so that it turns an element's relative velocity by at most a radian per step, m/(½ ξ_L (μV/D²) C_⊥) with the
 * linear C_⊥.
 * Faces (cloth, [AV] §2: C = diag(C_⊥, C_∥, C_∥) in the frame of the face's normal n): an element of area A and
 * thickness D (V = A D) feels f_drag = −(μV/D²) (C_⊥ n nᵀ + C_∥ (I − n nᵀ)) Δv, where ⊥ is now across the surface and
 * ∥ along it; with DR_DRAG_SCALES, 1/k_l = ξ_D ξ_l, the inverse of the fabric's permeability in units of D² (Darcy:
 * a layer of permeability k across a flow U loses μ U D/k of pressure, the force (μ A/D)(D²/k) U); the reference and
 * the permeability model are rod laws and do not apply. The lift takes e_∥ = n: Q = n × (n × f_drag) is minus the
 * drag's part along the surface, so a sheet at an angle to the flow is lifted across it.
 *     f_buoyancy = −V ∇p                                                                       (PHYSICS §6)
 * with ∇p the fluid pressure's gradient at the element (a hydrostatic pool: −V ρ g, Archimedes). Liquid an element
 * carries (a strand's film) feels −V_c ∇p too; the solid applies it (DrCoupleSolid.pressure_gradient, with ∇p from
 * the step's first projection), as the film's share along the strand belongs to the film, and the loop books it
 * (DrCoupleSamples.impulse). The film moves with its strand across the fluid: it is part of the porous solid the
 * projection sees (φ_s), with the film's mass already in the element's (the porous choice for film mass on the grid:
 * the film's momentum reaches the fluid through φ_s, drag and pressure, not through the grid's P2G).
 *
 * ---- the loop (one step of h) -------------------------------------------------------------------------------------
 * The caller predicts every solid and begins the fluid's substep; dr_couple_step then
 *   0. rasterises the solids' elements onto the MAC faces (trilinear weights w_if on each face component's lattice,
 *      fixed for the step): the solid fraction φ_s,f = Σ_i w_if V_i/Δx³ (at most ½) as a porous blocked share moving
 *      at the solids' velocity; projects the fluid with it (no drag yet) and samples the fluid velocity ũ_i at each
 *      element with the same weights restricted to the faces that take part (the fluid's coupled faces, normalised);
 *   k = 1, 2, …: every solid solves with the drag linearised about its last velocity and the fluid's iterate ũ
 *      (force f_i(v*) − D_i v* and ∂f/∂v₊ = D_i = −K_i, K_i = (μV/D²) R C Rᵀ with C at |v* − ũ|; with
 *      position_derivative the fluid velocity's change along the element's motion over the step, x₊ = x + h v₊, adds
 *      h K_i ∇ũ_i, of which the symmetric part that keeps the solve positive definite enters), lift and buoyancy
 *      explicit; then, unless this is the last iteration, the negated drag and its derivative go to the faces as an
 *      implicit drag mass β_f = h Σ_i w_if (K_i)_aa pulling the fluid towards the solids' velocity (grid.h) and the
 *      fluid projects again: block Gauss–Seidel on the monolithic fluid–solid system, whose fixed point is its
 *      solution for linear drag. The loop ends when the relative change of the solids' velocities and of the sampled
 *      fluid velocity and pressure falls below the tolerance, or at the iteration cap. The last projection settles
 *      what each element and the fluid exchanged, exactly, for any iteration count (the momentum ledger,
 *      DrCoupleStats), the lighter side taking the explicit part, so that an unconverged step cannot blow up:
 *      - an element lighter than the fluid around it (its mass below Σ w_if m_f, and on every face it reaches the
 *        fluid's mass above all the free elements' there, Σ_j w_jf m_j): the fluid takes the impulse
 *        g_i = h (f_i + D_i v_i) the element received in its solve, negated and spread over the coupled faces in
 *        proportion to w_if m_f (an explicit reaction: every face it reaches changes by the same velocity, bounded by
 *        the element's own velocity change; spread by w_if alone, a face holding a sliver of liquid would be given
 *        an unbounded one);
 *      - any other element, or a held one (a root: its reaction goes to what holds it): the fluid takes the same
 *        reaction but also keeps the element's implicit drag mass β = h K_aa pulling it towards the last iterate
 *        (as in the iterations before), and the element receives in addition exactly what that pull gave,
 *        h K_aa (ũ_a − ũ_a^prev), handed to its solid (DrCoupleSolid.correct), which may apply it at once or, as the hair
 *        does, as a force over its next step's implicit solve, where the same drag keeps the velocity change below
 *        the fluid's (added at once, h K_aa/m can be ≫ 1 for a thin strand at high Reynolds number). It vanishes at
 *        convergence: both forms have the loop's fixed point.
 *      One iteration is the staggered step (solid with drag from the fluid, reaction, pressure); at convergence the
 *      corrections vanish and both sides hold the monolithic solution.
 * The caller then commits every solid (their last solve) and ends the fluid's substep (its last projection).
 *
 * Units SI. Determinism: every sum runs in a fixed order; bit-identical for any thread count. Memory: scratch grows
 * with the elements and is kept (a step after the first allocates nothing while the counts fit). */
#ifndef DR_COUPLE_H
#define DR_COUPLE_H

#include "core/core.h"
#include "grid/grid.h"

typedef enum DrDragModel { DR_DRAG_SCALES, DR_DRAG_PERMEABILITY } DrDragModel;
typedef enum DrDragReference { DR_DRAG_STOKES, DR_DRAG_LITERAL } DrDragReference;

typedef struct DrDragLaw {
    DrDragModel model;         /* default DR_DRAG_SCALES */
    DrDragReference reference; /* DR_DRAG_SCALES only: default DR_DRAG_STOKES */
    double global;             /* ξ_D ≥ 0, default 1 (0: no drag) */
    double normal, tangent;    /* ξ_⊥, ξ_∥ ≥ 0, default 1 and 0.5 */
    double nonlinear;          /* ξ_N ≥ 0, default 1 */
    double degree;             /* c ≥ 0, default 1 */
    double lift;               /* ξ_L ≥ 0, default 0 */
    bool buoyancy;             /* default true */
} DrDragLaw;
void dr_drag_law_default(DrDragLaw *law);

/* One element as the laws see it. */
typedef struct DrDragSite {
    DrVec3 tangent;   /* e_∥, unit */
    double diameter;  /* D, m, > 0 */
    double volume;    /* V, m³, ≥ 0 */
    double slender;   /* Λ = L/D of its strand, > 1 */
    double gamma;     /* solid fraction around it, [0, 1) */
    bool face;        /* a face element (cloth): `tangent` is its unit normal (below) */
} DrDragSite;

/* C_l (dimensionless) for l = 0 (⊥) or 1 (∥) at relative speed `speed` (m/s) in a fluid of density rho, viscosity mu. */
double dr_drag_coefficient(const DrDragLaw *law, int l, double rho, double mu, const DrDragSite *site, double speed);
/* K (row-major 3×3, N·s/m) with f_drag = −K Δv, C evaluated at |Δv|. */
void dr_drag_tensor(const DrDragLaw *law, double rho, double mu, const DrDragSite *site, DrVec3 dv, double K[9]);
/* Eq. 4 for the drag f_drag = −K Δv (K from dr_drag_tensor); zero for Δv = 0. */
DrVec3 dr_drag_lift(const DrDragLaw *law, const DrDragSite *site, const double K[9], DrVec3 dv);

/* ---- participants ------------------------------------------------------------------------------------------------ */

/* A solid's elements, borrowed from it between its predict and its commit; x stays put for the step (the positions
   at its start), v is its last solve's (the prediction's before any). */
typedef struct DrCoupleSamples {
    int n;
    const double *x;          /* 3n, m */
    const double *v;          /* 3n, m/s */
    const double *mass;       /* n, kg: the inertia the element moves with (for a wet strand vertex, with its film) */
    const double *volume;     /* n, m³ */
    const double *diameter;   /* n, m */
    const double *slender;    /* n: Λ of the element's strand */
    const double *tangent;    /* 3n, unit */
    const unsigned char *held;/* n or NULL: 1 for an element whose motion is prescribed (a root): it drags the fluid
                                 with its prescribed velocity, and what it receives goes to what holds it (the solid
                                 ignores forces on it; the ledger counts them) */
    const int *law;           /* n or NULL (all law 0): index into DrCoupleSolid.laws */
    const double *carried;    /* n or NULL (none): m³ of liquid the element carries with it (a wet strand vertex's film
                                 and pools): it moves with the element across the fluid, so it blocks the fluid with
                                 the element (φ_s and γ count V + carried); the laws' V stays the element's own */
    const double *impulse;    /* 3n or NULL (none): N·s the element receives from the fluid over the step besides the
                                 laws, applied by the solid itself (the pressure on what it carries, below); the loop
                                 counts it as received and gives the fluid its reaction with the element's, always
                                 spread by w_if m_f as an explicit reaction is (no drag mass bounds it) */
    const unsigned char *face;/* n or NULL (none): 1 for a face element (a cloth vertex with its share of the panel):
                                 its `tangent` is the surface's unit normal, `diameter` the fabric's thickness and
                                 `slender` unused (the face laws above) */
} DrCoupleSamples;

typedef struct DrCoupleSolid {
    void *ctx;
    int nlaws;
    const DrDragLaw *laws;
    /* Its elements (after its predict; re-read after each solve). */
    DrCoupleSamples (*samples)(void *ctx);
    /* Solves its predicted step with force_i + dforce_dv_i v₊_i on element i (3n N; 9n row-major 3×3 N·s/m,
       symmetric negative semidefinite), from the prediction (as dr_rod_set_solve). Warnings (not converged) are the
       solid's to report; a negative status stops the step. */
    DrStatus (*solve)(void *ctx, const double *force, const double *dforce_dv, DrError *err);
    /* NULL, or takes dv (3n, m/s; the impulse over the element's mass): the loop's correction of an implicit element
       (below), applied to the last solve's velocities or kept for the next step. */
    void (*correct)(void *ctx, const double *dv);
    /* NULL, or takes ∇p (3n, Pa/m) at its elements from the step's first projection (0 outside the fluid and where the
       element's law has no buoyancy), once per step before its first solve: a solid that carries liquid (a strand's
       film) applies the pressure's force on it itself (the film's share along the strand is the film's, not the
       strand's) and reports it in DrCoupleSamples.impulse. */
    void (*pressure_gradient)(void *ctx, const double *gradp);
} DrCoupleSolid;

typedef struct DrCoupleFluid {
    void *ctx;
    double density, viscosity;   /* kg/m³, Pa·s */
    const DrMacGrid *grid;       /* its grid: after project, grid->f holds the velocities the coupling samples */
    /* dr_liquid_project-like: re-callable from the substep's begin with the extra face coupling. */
    DrStatus (*project)(void *ctx, const DrFaceCoupling *extra, DrError *err);
    /* Pressure (Pa) at n points (3n, m), and in wet (n) how much of each point's stencil is in the fluid, in [0, 1]
       (1 inside it, 0 inside a solid or in air: dr_liquid_sample_wet_pressure). */
    void (*pressure)(void *ctx, long n, const double *points, double *p, double *wet);
    /* The faces that took the extra coupling in the last project (dr_liquid_coupled_faces). */
    const unsigned char *(*coupled_faces)(void *ctx, int a);
    /* Its face masses m_f, kg (dr_liquid_face_mass), valid after the substep's begin. */
    const double *(*face_mass)(void *ctx, int a);
} DrCoupleFluid;

typedef struct DrCoupleDesc {
    int iterations;            /* ≥ 1, default 3 (solver.coupling_iterations) */
    double tolerance;          /* > 0, default 1e-2: relative change of v, ũ and p that ends the loop */
    bool position_derivative;  /* default true */
    bool explicit_reaction;    /* default false. true: every element's reaction is explicit in the last projection
                                  (the plain staggered exchange, for comparison: unstable where h K exceeds the fluid's
                                  face mass, e.g. stiff drag of roots in air) */
} DrCoupleDesc;
void dr_couple_desc_default(DrCoupleDesc *d);

typedef struct DrCoupleStats {
    int steps;                 /* coupled steps */
    long iterations_total;     /* solid solves over them */
    int iterations_max;
    int not_converged;         /* steps that stopped at the cap with the change above the tolerance */
    double change_max;         /* the largest final relative change of a step */
    long elements;             /* elements in the fluid (with coupled faces) at the last step */
    DrVec3 solid_impulse;      /* N·s: Σ g_i, what the solids received (drag, lift, buoyancy, the impulses of
                                  DrCoupleSamples.impulse) */
    DrVec3 fluid_impulse;      /* N·s: what the coupled faces gave the fluid; solid + fluid = 0 to round-off */
    double seconds_laws, seconds_solid, seconds_fluid;
} DrCoupleStats;

typedef struct DrCouple DrCouple;
DR_NODISCARD DrStatus dr_couple_create(DrCouple **out, DrError *err);
void dr_couple_destroy(DrCouple **c);

/* The lift's limit on the step (INFINITY without lift) for the solids' elements as they are now. */
double dr_couple_stable_dt(const DrCoupleFluid *fluid, const DrCoupleSolid *solids, int nsolids);

/* One coupled step of h (above). stats accumulates (zero it first). DR_ERR_INPUT for bad arguments (a solid's law
   index out of range, a non-positive h); a participant's failure is passed on; DR_ERR_RUNTIME for non-finite laws;
   DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_couple_step(DrCouple *c, const DrCoupleDesc *desc, const DrCoupleFluid *fluid,
                                     const DrCoupleSolid *solids, int nsolids, double h, DrCoupleStats *stats,
                                     DrError *err);

/* The coupling's momentum ledger of the last dr_couple_step: *solid (what the solids received) and *fluid (what the
   fluid's coupled faces were given), N·s. */
void dr_couple_last_ledger(const DrCouple *c, DrVec3 *solid, DrVec3 *fluid);
/* The last step's relative change after each of its iterations (up to max values; returns the iterations taken), and
   its fixed-point residual: the relative difference between the fluid velocity at the elements after the last
   projection and the one the solids last solved with (0 at the monolithic solution: then the solids' solve and the
   fluid's projection hold together). */
int dr_couple_last_changes(const DrCouple *c, double *out, int max);
double dr_couple_last_residual(const DrCouple *c);

/* ---- deformable solids lumped onto the faces (the MPM solids' two-way coupling with the liquid) ---------------------
 * A solid given as particles (position, velocity, mass, volume) becomes a moving solid of a fluid's projection
 * (DrFaceCoupling.solid_mass, grid.h; dr_liquid_solid_momentum): with the quadratic B-spline weights w_pf of each face
 * component's lattice (the liquid's P2G kernel), the face's solid mass m^s_f = Σ_p w_pf m_p, its velocity
 * V_f = Σ_p w_pf m_p v_p / m^s_f and its blocked share σ_f = min(1, Σ_p w_pf V_p/Δx³) (open = 1 − σ_f): a filled region
 * reads σ = 1, its flat surface σ = ½ on the surface. Stencil nodes outside the face lattice are skipped (their
 * weight is lost from both sums alike). The momentum P_f (N s) the projection gave face f goes back to the particles
 * with the same weights, δv_p = Σ_f w_pf P_f/m^s_f e_a, so Σ_p m_p δv_p = Σ_f P_f exactly (to round-off), whatever
 * the P_f. Serial, in particle order: the same bits for any thread count. */
/* Sets fc's open, velocity and solid_mass (allocated by dr_face_coupling_add_solid_mass) from the n particles and
   clears its impulse and drag; faces no particle reaches are open with no mass. */
void dr_couple_particles_to_faces(const DrMacGrid *g, long n, const double *x, const double *v, const double *mass,
                                  const double *volume, DrFaceCoupling *fc);
/* dv (3n) = Σ_f w_pf P_f/m^s_f e_a over the faces with m^s_f > 0, P = momentum[a] (NULL: none on component a), with
   fc the coupling dr_couple_particles_to_faces made from the same positions x. */
void dr_couple_faces_to_particles(const DrMacGrid *g, long n, const double *x, const double *const momentum[3],
                                  const DrFaceCoupling *fc, double *dv);
/* The solid fraction of each cell (ncells, cell order, in [0, 1]): Σ_p w_pc V_p/Δx³ on the cell-centre lattice, clamped.
   For the push-out of fluid particles (dr_couple_push_out). */
void dr_couple_particle_fraction(const DrMacGrid *g, long n, const double *x, const double *volume, double *frac);
/* Moves each of the n points (3n, m) whose trilinear solid fraction exceeds ½ along the fraction's falling gradient
   until it reads ½ (a few secant steps, at most 2Δx in all): out of the solid's surface σ = ½. Returns how many
   points moved. */
long dr_couple_push_out(const DrMacGrid *g, const double *frac, long n, double *x);
/* The trilinear solid fraction at x (cell-centre lattice, clamped to it) and its gradient (1/m; grad may be NULL). */
double dr_couple_fraction_at(const DrMacGrid *g, const double *frac, const double *x, double grad[3]);

#endif
