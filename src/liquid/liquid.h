/* drench liquid: incompressible bulk liquid on a MAC grid with APIC/FLIP/PIC particles (PHYSICS §3).
 *
 * One substep: P2G (transfer.h) → step size (CFL, dr_liquid_advance) → gravity and explicit viscosity →
 * boundary conditions (domain walls; colliders as variational face fractions with their velocity on
 * blocked faces) → implicit viscosity, for a substep whose explicit step would be unstable (ν Δt/Δx² > 1/6:
 * the variational solve of Batty & Bridson 2008, liquid/viscosity.h) → pressure projection (DrPressureFormulation below; PCG + multigrid or MIC(0)) → extrapolation of the
 * grid's velocity change into the faces the projection did not update → collider velocity constraint
 * (slip with Coulomb friction, or no-slip) → G2P → x += Δt v_p^{n+1} → push out of colliders, clamp into
 * the domain → emitters, kill boxes.
 *
 * Free surface. The liquid level set at a cell centre is φ = (½ − min(1, n_c / (per_cell·ω_c)))·Δx from
 * the cell's particle count n_c (each particle counting vol/V0, DrLiquidState) and its open fraction ω_c (the part of the cell outside every collider):
 * a full cell puts the surface on its faces (a flat, face-aligned surface is exactly flat whatever the
 * jitter), a partly filled one moves it inward. θ = φ_F/(φ_F − φ_A) ≥ 0.01.
 *
 * Colliders. A face's weight is its open fraction (from the collider phi at its corners); its blocked
 * part moves with the collider (the variational boundary). A face that no particle reaches (no P2G mass)
 * is closed and moves with the collider: a pool next to a collider keeps no spurious velocity on faces
 * inside it, and a closed collider carrying liquid carries it at its own velocity (< 5e-4 m/s relative).
 * A cell cut by a collider counts particles unreliably (where the surface crosses the seeding lattice
 * decides how many it holds, and a small open part may hold none while liquid surrounds it: as an air
 * cell it would put p = 0 into the liquid at depth), so its liquid phi is the liquid's around it,
 * continued into the collider along the liquid surface (liquid.c: extend_phi_slices): still water next to
 * a sphere, a bowl, a sloping box or a plate, or inside a tank that is a collider, stays still (to ~1e-8
 * m/s) and takes one substep per frame. Colliders thinner than about a cell are not resolved by the face
 * fractions (their corners miss them): the particles are still pushed out of what the collider's field
 * resolves, but the pressure sees them partly open.
 *
 * Units SI. Determinism: a run is bit-identical for any thread count (fixed-order reductions, coloured
 * P2G). Thread safety: one DrLiquid belongs to one thread at a time (it parallelises internally).
 * Memory: everything is sized in dr_liquid_create; particle arrays (and their scratch copies for the
 * sort below) grow (by 1/4 + slack) only when emitters add particles.
 * Particle order: every substep sorts the particles by grid cell (stable: ties keep their order) so the
 * transfers walk memory in grid order (each particle's volume and id go with it); the order, and the array pointers
 * of DrLiquidState, change in dr_liquid_advance, dr_liquid_stable_dt, dr_liquid_restore, dr_liquid_add_particles and
 * dr_liquid_remove_empty: re-read them after each call. */
#ifndef DR_LIQUID_H
#define DR_LIQUID_H

#include "core/core.h"
#include "grid/grid.h"
#include "transfer/transfer.h"

/* DrTransferScheme { DR_TRANSFER_APIC, DR_TRANSFER_FLIP, DR_TRANSFER_PIC } comes from transfer.h. */

/* Pressure projection. Both solve A q = −Δx·div u* for q = pΔt/ρ with preconditioned CG (DrPressurePrecond
 * below: multigrid or MIC(0)), use the
 * collider face weights w_f of the variational boundary, and treat domain walls as closed faces; they
 * differ in what they minimise and where the free-surface condition p = 0 sits.
 *
 * DR_PRESSURE_GHOST_FLUID (default): uniform density ρ on every face, Poisson coefficients w_f, unknowns
 *   on the cells holding particles, p = 0 on the level-set surface between a fluid and an air cell (ghost
 *   fluid, θ from the particle-count level set), the velocity change extrapolated into the faces not next
 *   to a fluid cell. Keeps still water still for any seeding jitter (a full, face-aligned surface lies
 *   exactly on the faces: hydrostatic tank ~1e-9 m/s). Conserves neither linear nor angular momentum
 *   exactly at a free surface (θ ≠ 1 and the extrapolated faces carry momentum the solve did not
 *   balance): an APIC rotating free blob in zero gravity drifts by 8.4e-3 of |L| per 100 steps.
 * DR_PRESSURE_MASS_WEIGHTED: the kinetic-energy projection with the P2G face masses m_f: minimises
 *   Σ_f m_f |u_f − u*_f|² subject to the discrete divergence constraint, i.e. u_f = u*_f − Δt/ρ_f (G p)_f,
 *   ρ_f = m_f/Δx³, Poisson coefficients w_f/ρ_f, applied to EVERY face with mass (no extrapolation into
 *   them). The constraint holds on the cells holding particles and on the cells whose six faces all carry
 *   mass (the kernel's reach just outside the liquid; with the virtual liquid below, next to colliders);
 *   p = 0 at the centres of the remaining cells. Next to a collider part of a face's P2G support lies
 *   inside it, where no particle is: the face densities there count a virtual liquid filling the
 *   collider's part of the cells under the liquid at the seeding lattice's points (mass only; liquid.c:
 *   virtual_mass), so that they stay uniform as the walls' mirror nodes keep them at the domain walls.
 *   Since m_f Δu_f = −Δt Δx² (G p)_f does not depend on m_f, summation by parts turns Σ_f m_f Δu_f e_a
 *   and Σ_f x_f × m_f Δu_f e_a into sums over cells of p_c times the moments of the faces of c that carry
 *   mass: zero for every cell with six such faces, and p = 0 on the others. So, away from walls and
 *   colliders (w_f = 1), the projection conserves linear and angular momentum exactly whatever p (an
 *   unconverged solve included); with APIC and no gravity or viscosity a whole step conserves angular
 *   momentum to round-off (the rotating blob: ~4e-15 of |L| per 100 steps), and with viscosity linear momentum
 *   (the explicit viscosity exchanges it between faces in pairs, weighted by the smaller face mass). The price: the face densities
 *   follow the particle distribution, and a face density varying sideways is a horizontal density
 *   gradient that gravity turns into flow. Unjittered seeding (jitter 0) gives uniform face masses (walls
 *   fold the kernel back, transfer.h) and still water stays still (~5e-8 m/s, next to colliders ~5e-6
 *   m/s after 2 s); fully jittered seeding
 *   does not (~0.24 m/s of slow circulation in the same tank). Faces with little mass get large
 *   coefficients (ρ/ρ_f), which costs PCG iterations (a small dam break: at most 74 against 18). Use it
 *   where momentum matters more than resting water (splashes, free rotating bodies of liquid); use the
 *   default for tanks and pools. */
typedef enum DrPressureFormulation { DR_PRESSURE_GHOST_FLUID, DR_PRESSURE_MASS_WEIGHTED } DrPressureFormulation;

/* Preconditioner of the pressure solve's PCG (either formulation; both reach pressure_tol, so they differ in
 * the solution only at that level).
 * DR_PRECOND_MULTIGRID (default): a geometric multigrid V-cycle on the grid's cells (linalg.h: DrMg; 2×2×2
 *   coarsening, coarse operators summed from the fine coefficients so collider fractions, θ and 1/ρ_f carry
 *   over; red-black Gauss–Seidel smoothing in parallel). Iterations stay nearly flat as the grid is refined
 *   (the tank of bench_pcg: 6 at 32³, 8 at 128³; MIC(0) 34 and 106) and it is the faster from 64³ on.
 * DR_PRECOND_MIC0: modified incomplete Cholesky (linalg.h: DrMic0): cheap to build, but its iterations grow
 *   ~1.8× per doubling of the resolution and its triangular solves run on one thread. */
typedef enum DrPressurePrecond { DR_PRECOND_MULTIGRID, DR_PRECOND_MIC0 } DrPressurePrecond;

typedef struct DrBoxVel { DrVec3 lo, hi, velocity; double start, end; } DrBoxVel; /* emitter: active start<=t<end */
typedef struct DrLiquidDesc {
    DrVec3 domain_lo, domain_hi; double dx; bool wall_no_slip;   /* grid = ceil((hi - lo)/dx) cells from lo */
    double density, viscosity;                                    /* kg/m³, Pa·s (dynamic) */
    DrTransferScheme scheme; double flip_blend;                   /* flip_blend: PIC fraction of FLIP, [0,1] */
    int per_cell; double jitter; uint64_t seed;                   /* seeding: per_cell particles per cell (8 =
                                                                      2x2x2 sub-cells; a cube k³ uses k³
                                                                      sub-cells, other counts uniform random
                                                                      positions), jitter in [0,1] of a sub-cell */
    DrVec3 gravity; double cfl; int max_substeps; double pressure_tol; int pressure_max_iter;
    DrPressureFormulation pressure;                               /* default DR_PRESSURE_GHOST_FLUID */
    DrPressurePrecond pressure_precond;                           /* default DR_PRECOND_MULTIGRID */
    double volume_correction;     /* κ ≥ 0, default 4 (0 = off). Particles drift together where the flow
                                     converges or meets a wall (advection is not divergence-free), and the
                                     liquid loses volume: a dam break loses ~8 % in 2 s without this. The
                                     pressure solve targets a divergence D = κ·(ρ̃ − 1 − 0.04)/T, T the
                                     duration of the dr_liquid_advance call (a frame), in cells whose smoothed
                                     particle density ρ̃ exceeds the seeded one by more than 4 %, expanding
                                     them back at κ of the excess per frame (compression only; never a sink).
                                     ρ̃ = the mean over the 3×3×3 block of cells of the P2G face masses of
                                     each cell / ρΔx³ (0 for empty cells, so the surface never triggers it).
                                     4 % is above the spread of freshly jittered seeding (ρ̃ ≤ 1.03), so
                                     still water stays exactly still. Either formulation keeps its
                                     conservation property: the sources change p, and p = 0 in air. */
    int nsource_boxes; const DrBoxVel *source_boxes;              /* liquid at t=0 (start/end unused) */
    int nsource_shapes; const DrCollider *const *source_shapes; const DrVec3 *source_shape_velocity;
                                       /* liquid at t=0 inside these SDFs (phi(x, 0) < 0) — closed meshes;
                                          velocity array may be NULL (at rest) */
    int nemitters; const DrBoxVel *emitters;                      /* fill their box every substep where empty
                                                                      (in cells whose centre is inside, the
                                                                      seeding sub-cells holding no particle;
                                                                      without a k³ lattice, empty cells); copied */
    int nkill_boxes; const DrVec3 *kill_lo, *kill_hi;             /* copied */
} DrLiquidDesc;
/* Water (1000 kg/m³, 1e-3 Pa·s), APIC, flip_blend 0.05, 8 per cell, jitter 1, seed 1, gravity −9.81 y,
   cfl 1, 64 substeps, tolerance 1e-6, 1000 iterations, ghost-fluid pressure, multigrid preconditioner, volume
   correction 4, unit box
   domain, dx 1/32,
   no sources. */
void dr_liquid_desc_default(DrLiquidDesc *d);

typedef struct DrLiquidState { long n; double *x, *v, *c, *vol; int64_t *id; } /* 3n positions (m), 3n velocities
      (m/s), 9n affine: c[9p + 3a + b] = component b of c_pa, the affine vector of face component a (APIC; zero for
      PIC/FLIP);
      n volumes (m³): the liquid each particle carries. Seeded and emitted particles carry the nominal volume
      V0 = Δx³/per_cell (dr_liquid_nominal_volume) exactly; a caller may change them between substeps (through
      dr_liquid_state_mut, to a finite value > 0, or 0 to drop the particle with dr_liquid_remove_empty before the
      next substep). Particle p's mass is m_p = dr_liquid_particle_mass·(vol[p]/V0): it weighs P2G, the count of
      the free-surface level set (a particle counts vol[p]/V0 of one), the totals and the energies. While every
      particle is nominal (vol == V0) the liquid takes the uniform paths, bit-identical to a liquid without volumes;
      the sort carries each volume with its particle.
      n ids: a particle's id is its own for its whole life. Seeding gives 0, 1, 2 … in seeding order and every
      emitted or added particle the next unused one (a counter in DrLiquidResume, so a resumed bake goes on with
      the same ids); the sort carries each id with its particle and a killed or removed particle's id is never
      given again. Ids feed nothing back into the simulation (the other arrays' bits are the same without them). */
      DrLiquidState;

typedef struct DrLiquidStats {
    int substeps; int pressure_iterations_max; long pressure_iterations_total; double pressure_residual_max;
    int pressure_not_converged;   /* substeps whose solve stopped at max_iter (each also logged as a warning) */
    long particles; long liquid_cells; double max_speed; double divergence_mean; /* mean |div u − D|·dx/|u|max
                                   after projection over liquid cells, D the volume-correction target
                                   (dimensionless; last substep) */
    double density_max;           /* largest smoothed relative particle density ρ̃ seen (volume correction) */
    double seconds_p2g, seconds_pressure, seconds_g2p, seconds_advect, seconds_other;
    long emitted, killed;
    /* m³: the volume the particles emitters added and kill boxes removed carried (Σ vol), summed like emitted and
       killed. Kill boxes are the only way particles leave the liquid (the domain walls clamp them in);
       dr_liquid_add_particles and dr_liquid_remove_empty are the caller's to book. */
    double emitted_volume, killed_volume;
    /* Momentum the grid phases (forces, projection, boundaries, extrapolation, collider constraint) gave
       the liquid: Σ over substeps of Σ_f m_f (u_f^final − u_f^P2G) e_a and of the same times x_f ×.
       With APIC and particles away from the domain walls, transfers and advection conserve both exactly
       ([APIC] §5.3), so the change of dr_liquid_totals' momentum/angular equals these (before the
       push-out/clamp/emitter/kill phases, which the caller avoids when checking). */
    DrVec3 grid_linear_impulse, grid_angular_impulse;
    /* Σ over substeps of the momentum the extra face coupling's impulses gave the liquid in the substep's
       last dr_liquid_project (N·s; the faces that took them, dr_liquid_project); part of the grid impulse
       above. 0 without an extra coupling (dr_liquid_advance). */
    DrVec3 added_impulse;
    /* Σ over substeps of the momentum the extra face coupling's drag masses gave the liquid in the substep's last
       dr_liquid_project, β_f (V_f − u_f) with the projected u_f (N·s; grid.h); part of the grid impulse too. */
    DrVec3 drag_impulse;
    /* Σ over substeps of the momentum the extra coupling's moving solid (DrFaceCoupling.solid_mass) gained in the
       substep's last dr_liquid_project (N·s; Σ of dr_liquid_solid_momentum). */
    DrVec3 solid_gain;
    /* The energy ledger (J), for a caller watching the liquid's energy E = Σ ½m|v|² − m g·x (dr_liquid_totals'
       kinetic plus the potential): what entered and left it besides gravity. source_work: Σ over substeps of the
       work of the last projection's sources, the moving solids (each face's blocked part, (1 − w) u_solid Δx²,
       pushing against the pressure difference across it, Δt (p_hi − p_lo), and the impulse their velocity
       constraint gave the faces near them times u_solid) and the volume correction (p D Δx³ Δt in compressed
       cells); emitted_energy and killed_energy: E of the particles emitters added and kill boxes
       removed. The pressure projection, viscosity and the transfers only take energy away, so a stable liquid's
       E grows by at most source_work + emitted_energy − killed_energy plus its time-stepping error. */
    double source_work, emitted_energy, killed_energy;
    /* The implicit viscosity solve (substeps whose explicit viscosity step would be unstable): PCG iterations
       summed, solves stopped at pressure_max_iter (each also logged as a warning), seconds (part of
       seconds_other). */
    long viscosity_iterations;
    int viscosity_not_converged;
    double seconds_viscosity;
} DrLiquidStats;

typedef struct DrLiquid DrLiquid;
/* Creates the grid and seeds particles (no particle seeded where any collider has phi < 0 at t=0).
   Allocates the grid ONLY here (a scene without liquid never calls it). DR_ERR_INPUT naming the field for
   out-of-range parameters; DR_ERR_NOMEM. colliders are borrowed for the call only. */
DR_NODISCARD DrStatus dr_liquid_create(const DrLiquidDesc *desc, const DrCollider *const *colliders, int ncolliders,
                                       DrLiquid **out, DrError *err);
void dr_liquid_destroy(DrLiquid **liq);
/* Advances from t0 to t1 with adaptive substeps. CFL: dt <= cfl·dx/(U + √(5·dx·a⁺)), U the largest face
   speed after the substep's P2G (every particle's velocity after G2P is a convex combination of face
   values, so U bounds it; [APIC] §4.3 bounds U by max_p(|v_p| + (6√3/dx)‖B_p‖_F), which one particle
   with a large affine matrix inflates for the whole liquid), a⁺ the largest speed gain per second of a
   face in the previous substep (measured before a liquid's first substep by a trial of the grid phases,
   then discarded): still water takes whole frames, falling water the steps of the usual √(5·dx·|g|)
   term. Viscosity does not limit the step: within its explicit limit (ν Δt/Δx² ≤ 1/6) the explicit update,
   beyond it the implicit solve. At most max_substeps — if the CFL would need more, the substeps are
   clamped and a warning is logged once per call. Fills *stats (zeroed first) with the sums/maxima over all
   substeps.
   A pressure solve that does not converge is a warning (stats), never a failure. DR_ERR_RUNTIME if the
   solver breaks down (non-finite values); DR_ERR_NOMEM if growing for emitters fails. */
DR_NODISCARD DrStatus dr_liquid_advance(DrLiquid *liq, const DrCollider *const *colliders, int ncolliders,
                                        double t0, double t1, DrLiquidStats *stats, DrError *err);
/* ---- the substep in phases (DESIGN §8) ----------------------------------------------------------------
 * dr_liquid_advance is the loop
 *     while (t < t1) { stable_dt(t, t1, &h); begin(t, h); project(NULL); end(); t = h == t1 − t ? t1 : t + h; }
 * and gives the same bits as that loop (tests/validation/test_liquid_phases.c). A coupled step calls the
 * phases itself: between begin and end it may project several times with other participants' face
 * coupling and sample the grid after each projection. One substep's calls come in this order; a call out
 * of order is a programming error (assert). Particles are re-sorted in stable_dt: indices of particles
 * are good for one substep only.
 *
 * stable_dt: the length h of the substep from t that dr_liquid_advance would take next towards t_end: the
 *   CFL bound (above; on the liquid's first substep a⁺ comes from a trial of the grid phases) and
 *   max_substeps, with the interval [t, t_end] split into equal substeps, so h ≤ t_end −
 *   t and h == t_end − t when the substep lands on t_end (then take t_end as the next t: t + h may differ
 *   in the last bit). The interval: the first call with a given t_end (or with t before the interval's
 *   start) opens [t, t_end]; its duration is the volume correction's T and max_substeps counts the
 *   substeps ended in it (dr_liquid_advance opens [t0, t1]). Transfers the particles to the grid (P2G),
 *   which begin uses: the particles must not change between the two calls. Never INFINITY (the step always
 *   lands on t_end). DR_ERR_INPUT for a bad collider count or t_end not after t (both finite);
 *   DR_ERR_RUNTIME for non-finite velocities; DR_ERR_NOMEM. *h is 0 on failure. */
DR_NODISCARD DrStatus dr_liquid_stable_dt(DrLiquid *liq, const DrCollider *const *colliders, int ncolliders,
                                          double t, double t_end, double *h, DrError *err);
/* begin: the substep from t (the t of the stable_dt call just before) over h, 0 < h ≤ (1 + 1e-9)·the stable_dt
   result: the colliders posed at t + h, gravity and viscosity on the grid (implicit beyond the explicit
   limit, after the colliders' face coupling, whose closed faces it holds at their velocity), the colliders'
   face coupling (their face weights and velocities) and the cells' open fractions; keeps a copy of the face
   velocities the projection starts from. DR_ERR_INPUT for h out of range or a bad collider count;
   DR_ERR_RUNTIME if the viscosity solve breaks down; DR_ERR_NOMEM (the copy, and the viscosity solve's
   storage, are allocated on the first call). */
DR_NODISCARD DrStatus dr_liquid_begin(DrLiquid *liq, const DrCollider *const *colliders, int ncolliders, double t,
                                      double h, DrError *err);
/* project: the pressure solve, the velocity update, the extrapolation of the grid change into the faces the
   projection does not update and the colliders' velocity constraint. extra (NULL: none, which is what
   dr_liquid_advance does) is another participant's face coupling (grid.h), sized like the liquid's grid
   (dr_liquid_grid), borrowed for the call: its solid shares add to the colliders' (the solids taken as
   disjoint; a face the extra coupling leaves fully open keeps the colliders' values exactly), its solid
   velocity joins theirs weighted by share, and its impulse J_f (N·s) is added as the velocity increment
   J_f/m_f (m_f the face's P2G mass) before the solve, on the faces that take part as liquid faces: open,
   neither a domain wall nor without liquid (at most 1e-6 of a full face's mass), and, ghost fluid, next
   to a pressure cell; impulses elsewhere are dropped. The momentum so given (Σ J_f over the faces taking
   it) goes to stats->added_impulse at end. Its drag mass β_f (grid.h) pulls the same faces towards the extra
   coupling's velocity within the solve (a porous face: the pressure coefficient scaled by m_f/(m_f + β_f)); what
   it gives goes to stats->drag_impulse. The extra solid fractions enter the projection only: the
   cells' open fractions (free-surface level set), the particles' push-out and the slip/friction
   constraint stay the colliders' (an extra solid keeps the liquid out through its blocked faces, as the
   pressure sees them; particles are not pushed out of it). Re-callable: every call starts from the
   velocities begin kept, so the same extra gives the same bits again, and only the last call's grid goes
   on to end. Adds the solve's figures (iterations, residual, non-convergence, seconds) of every call to
   *stats and sets liquid_cells and divergence_mean. A pressure solve that does not converge is a warning
   (stats), never a failure. DR_ERR_INPUT for an extra coupling with an open fraction outside [0, 1] or
   non-finite values; DR_ERR_RUNTIME if the solver breaks down; DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_liquid_project(DrLiquid *liq, const DrFaceCoupling *extra, DrLiquidStats *stats,
                                        DrError *err);
/* Rigid participants of the projection: bodies that the liquid pushes and that push it within one pressure solve
   (the variational solid–fluid coupling of PHYSICS §6: the body's velocity is eliminated into the pressure system,
   which stays symmetric positive semi-definite and keeps the multigrid preconditioner of the liquid alone). Each body
   is one of the colliders given to dr_liquid_begin; the faces whose nearest moving collider it is (the faces that take
   a collider velocity: within 2Δx of it) let it through at its rigid velocity V + ω × (x − c). On those faces the solid
   share σ_f = 1 − w_f (1 on a face the projection shuts) moves with the body; the body's velocity after the solve is
   V⁺ = V + M⁻¹ Σ_f σ_f J_fᵀ ρΔx² (q_lo − q_hi), q the pressure unknowns (0 outside the pressure cells), J_f the face's
   row (e_a, (x_f − c) × e_a), and the pressure system gains ρΔx³ Kᵀ M⁻¹ K (K the 6 × rows matrix of those σ_f J_f).
   velocity/angular_velocity are read on every dr_liquid_project as the body's velocity before the pressure (its
   other forces over the substep included) and left untouched; the results go to the _out fields. A body with zero
   inverse mass and inverse inertia is held: it moves as given and receives the impulse it would feel. */
typedef struct DrLiquidBody {
    const DrCollider *collider;  /* among the colliders of dr_liquid_begin */
    double center[3];            /* c: centre of mass at the end of the substep, m */
    double inv_mass;             /* 1/m, 1/kg (0: held) */
    double inv_inertia[9];       /* I⁻¹ about c, world axes, row-major, 1/(kg m²) (0: no rotation) */
    double velocity[3];          /* V before the pressure, m/s */
    double angular_velocity[3];  /* ω before the pressure, rad/s */
    double velocity_out[3], angular_velocity_out[3]; /* after the last projection */
    double impulse[3];           /* the pressure's impulse on the body in the last projection, N s */
    double angular_impulse[3];   /* ... and its moment about c, N m s */
    long faces;                  /* faces that coupled it in the last projection */
} DrLiquidBody;
/* The bodies of the substep begun (borrowed until dr_liquid_end; n = 0 clears). DR_ERR_INPUT naming the body when its
   collider was not given to dr_liquid_begin, or its mass or inertia is negative or not finite. */
DR_NODISCARD DrStatus dr_liquid_set_bodies(DrLiquid *liq, DrLiquidBody *bodies, int n, DrError *err);
/* Pressure (Pa) at n points (3n, m) from the pressure cells alone: trilinear over the cell centres that are pressure
   cells, renormalised by their weight; wet_out[i] (may be NULL) that weight in [0, 1], and p = 0 where it is 0 (a
   point with no pressure cell around it: dry, or inside a solid). pressure_out may be NULL (the weights alone). After
   a project, like dr_liquid_sample. */
void dr_liquid_sample_wet_pressure(const DrLiquid *liq, long n, const double *points, double *pressure_out,
                                   double *wet_out);
/* sample: after a project (and until the next stable_dt), the grid velocity (m/s; trilinear on each face
   component's lattice, dr_mac_sample_face) and the pressure (Pa; p = ρq/Δt at the pressure cells' centres,
   0 at every other cell centre — air and solids —, trilinear on the lattice of cell centres) at n points
   (3n, m). Both lattices are clamped at the domain: beyond the outermost centres the value is that of the
   nearest. In the half cell below the free surface the pressure tends to the air cells' 0 at their
   centres, not at the surface (a hydrostatic pool reads ρ g depth below the top liquid cells' centres,
   ρ g Δx/4 too much at the surface). vel_out (3n) or pressure_out (n) may be NULL. Reads only: may run
   while nothing writes the liquid. */
void dr_liquid_sample(const DrLiquid *liq, long n, const double *points, double *vel_out, double *pressure_out);
/* The P2G face masses of component a (kg; nfaces[a] values in dr_liquid_grid's face order) of the substep
   the last dr_liquid_stable_dt opened, valid until the next one; borrowed. An extra coupling's impulse J_f
   becomes the velocity increment J_f/m_f, so a face holding little liquid turns a small impulse into a
   large velocity: a participant spreading a reaction over faces weights it by these masses (J_f = m_f δu
   for a velocity increment δu). */
const double *dr_liquid_face_mass(const DrLiquid *liq, int a);
/* The faces (nfaces[a] flags in dr_liquid_grid's face order) that took the extra coupling's impulse and drag mass in
   the last dr_liquid_project given one (dr_liquid_project lists the conditions), valid until the next
   dr_liquid_stable_dt; NULL before any. A participant that spreads a reaction over faces with these alone gives the
   liquid exactly the momentum it meant to (an impulse elsewhere is dropped). */
const unsigned char *dr_liquid_coupled_faces(const DrLiquid *liq, int a);
/* The extra coupling's moving solid (DrFaceCoupling.solid_mass, grid.h): per face of component a, the momentum along
   e_a (N·s) it gained in the last dr_liquid_project: the pressure's impulse on its share s_f of the face (s_f the
   weight of its velocity in the face's flux: (1 − w_f) σ_e/(σ_own + σ_e) on an open face, σ_e/(σ_own + σ_e) on one
   the projection shuts; σ_e = 1 − its open fraction, σ_own the colliders' share), s_f ρΔx² (q_lo − q_hi), less its
   share of what setting a blocked face's liquid to the solid velocity gave that liquid. The projection takes the
   solid's velocity V_f after the pressure as V_f + s_f ρΔx² (q_lo − q_hi)/m^s_f (eliminated into the pressure system,
   which gains s_f² ρΔx³/m^s_f on the face's coefficient: implicit in the solid's inertia, so a light solid cannot
   take more than the pressure gives it). NULL when the last projection had no solid mass. Valid until the next
   dr_liquid_stable_dt. A participant spreading these over its particles with the weights that made m^s gives them
   exactly the momentum (Σ over faces) the liquid reports in stats->solid_gain. */
const double *dr_liquid_solid_momentum(const DrLiquid *liq, int a);
/* end: the grid impulse (and a⁺ of the next CFL step) of the last projection, G2P, advection, push-out out
   of the colliders, the domain clamp, emitters and kill boxes; adds the substep to *stats (substeps,
   impulses, seconds of every phase) and sets particles and max_speed. DR_ERR_NOMEM if growing for emitters
   fails. */
DR_NODISCARD DrStatus dr_liquid_end(DrLiquid *liq, DrLiquidStats *stats, DrError *err);
/* The phase functions add to *stats: zero it before a sequence (dr_liquid_advance zeroes it itself). */

const DrLiquidState *dr_liquid_state(const DrLiquid *liq);
DrLiquidState *dr_liquid_state_mut(DrLiquid *liq);  /* for initial conditions and, between substeps, the particles'
                                                       volumes (DrLiquidState.vol); keep arrays' length n and the ids
                                                       as they are */
/* Appends n particles (3n positions in the domain box, m; 3n velocities, m/s; n volumes, m³, finite and > 0) with
   affine c = 0 and the next unused ids, in order. Between substeps: before dr_liquid_stable_dt or after dr_liquid_end
   (never within a begin/project/end; between stable_dt and begin, begin transfers the particles again and keeps the
   step length stable_dt gave). Not counted in DrLiquidStats.emitted (the caller books them). DR_ERR_INPUT naming the
   particle and the field for non-finite x or v, a volume not finite or ≤ 0, or a position outside the domain box
   (closed); DR_ERR_NOMEM when the arrays cannot grow. Nothing is added on failure. */
DR_NODISCARD DrStatus dr_liquid_add_particles(DrLiquid *liq, long n, const double *x, const double *v, const double *vol,
                                              DrError *err);
/* Removes the particles whose volume is exactly 0 (the whole particle went elsewhere), keeping the others' order; their
   ids are never given again. Between substeps, as dr_liquid_add_particles. Returns how many it removed. */
long dr_liquid_remove_empty(DrLiquid *liq);
/* Checkpoint support: everything besides the particle arrays that a bit-identical continuation needs. */
typedef struct DrLiquidResume {
    uint64_t rng[4];     /* the seeding rng (emitters) */
    double cfl_accel;    /* a⁺ of the CFL step (dr_liquid_advance), m/s² */
    int64_t next_id;     /* the id the next seeded or emitted particle takes (DrLiquidState.id) */
} DrLiquidResume;
void dr_liquid_resume_state(const DrLiquid *liq, DrLiquidResume *out);
/* Replaces the particles (copies n rows of x, v, c, vol and id; vol NULL: every particle nominal, V0) and the resume
   state. DR_ERR_INPUT for n < 0, non-finite data (a⁺ negative or non-finite too), a volume not finite or ≤ 0 (naming
   the particle), an id outside [0, next_id) or one held by two particles; DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_liquid_restore(DrLiquid *liq, long n, const double *x, const double *v, const double *c,
                                        const double *vol, const int64_t *id, const DrLiquidResume *resume,
                                        DrError *err);
/* Diagnostics: total mass Σ m_p, linear momentum, angular momentum about the origin INCLUDING the affine part
   (APIC: L_p = x_p × m_p v_p + m_p ε:(B_pᵀ), B_p = C_p D), kinetic energy ½ Σ m_p |v_p|²; m_p = the particle mass
   times vol[p]/V0 (DrLiquidState). */
void dr_liquid_totals(const DrLiquid *liq, double *mass, DrVec3 *momentum, DrVec3 *angular, double *kinetic);
double dr_liquid_particle_mass(const DrLiquid *liq);   /* the nominal particle's, density·dx³/per_cell, kg */
double dr_liquid_nominal_volume(const DrLiquid *liq);  /* V0 = dx³/per_cell, m³ */
/* The volume the particles fill, m³: each stands for its vol (DrLiquidState), summed per block of 2×2×2 cells up to the
   block's 8 cells (particles squeezed beyond the seeded density add nothing), and *nominal, what they would fill at
   the seeded density (Σ vol; n V0 when all are nominal). A liquid freshly seeded fills its nominal volume;
   well-mixed particles about 95 % of it (the count per block scatters around its mean); liquid that collapses, its
   particles piled into a few cells, far less. Uses scratch of its own (allocated on the first call: DR_ERR_NOMEM). */
DR_NODISCARD DrStatus dr_liquid_particle_volume(DrLiquid *liq, double *volume, double *nominal, DrError *err);
const DrMacGrid *dr_liquid_grid(const DrLiquid *liq);

/* ==== air: a single-phase incompressible gas on a MAC grid with a wind inflow (liquid/air.c) ==================
 *
 * The air fills the whole box: every cell is a pressure unknown except those a collider blocks entirely. One
 * substep: semi-Lagrangian advection of the face velocities (an RK2 backtrace, trilinear sampling written as
 * a + f (b − a), so a uniform field is reproduced bit for bit) → explicit viscosity → boundary values →
 * pressure projection (variational collider face fractions, the extra face coupling with impulses and implicit
 * drag masses; PCG + MIC(0)). No particles: the state is the face velocities alone.
 *
 * Boundaries. The inflow face (axis inflow_axis, side inflow_side) holds the wind's normal component, ramped
 * linearly from 0 over `ramp` seconds; backtraces that leave the box through it read the whole wind vector (its
 * tangential part too). The opposite face is open: p = 0 on it (a ghost pressure −p mirrored across the face)
 * and the velocity has zero gradient (its normal faces start each projection from the face one cell inside,
 * backtraces beyond it read the nearest values). The other four faces are slip walls (normal velocity 0,
 * zero-gradient tangential velocity). A wind whose normal component is 0 closes the box: six slip walls, a pure
 * Neumann problem whose constant null space is removed (the right-hand side's mean is subtracted, the solution's
 * mean too: a moving collider whose discrete face fractions change its volume by round-off cannot make the
 * system incompatible; the box is taken as one connected region).
 *
 * Gravity is not applied: a gas of uniform density is held by its hydrostatic pressure ρ g·x, which the
 * projection would cancel exactly; the pressure reported by dr_air_sample is the dynamic part.
 *
 * Numerical dissipation. Semi-Lagrangian linear sampling damps a resolved shear flow: an inviscid Taylor–Green
 * cell (steady under the Euler equations) loses kinetic energy at a rate tests/validation/test_air.c measures
 * and the README records. Viscosity (μ/ρ = ν) is explicit; when ν h/Δx² exceeds 1/6 the explicit update is
 * subcycled (at most 8 parts: beyond that the diffusion number of each part is held at 1/6, which under-applies
 * viscosity, and a warning is logged once). Air (ν = 1.5e-5 m²/s) on grids of millimetres or more never needs it.
 *
 * Face masses: m_f = ρΔx³ on every face that is a velocity unknown (interior faces and the outflow face,
 * whatever the colliders' open fraction: the open fraction scales the face's flux and its Poisson
 * coefficient, not its inertia); 0 on walls and on the inflow face (prescribed). Momentum (dr_air_totals) is
 * Σ_f m_f u_f e_a, kinetic energy ½ Σ_f m_f u_f².
 *
 * Units SI. Determinism: bit-identical for any thread count (z-slices with dr_parallel_for, per-slice partial
 * sums added in slice order; PCG's reductions are thread-count independent). Thread safety: one DrAir belongs
 * to one thread at a time. Memory: everything is allocated in dr_air_create; the phases allocate nothing except
 * the pressure matrix's growth when a collider uncovers cells. */
typedef struct DrAirDesc {
    DrVec3 domain_lo, domain_hi; double dx; /* grid = ceil((hi − lo)/dx) cells from lo */
    double density, viscosity;              /* kg/m³ (default 1.2), Pa·s dynamic (default 1.8e-5), both > 0 / ≥ 0 */
    int inflow_axis;                        /* 0, 1, 2: the axis normal to the inflow face */
    int inflow_side;                        /* 0: the low face (−axis), 1: the high face (+axis) */
    DrVec3 inflow_velocity;                 /* m/s; its normal component points into the box, or is 0 (closed box) */
    double ramp;                            /* s ≥ 0: the wind grows linearly from 0 over it (0: at once) */
    bool initial_stream;                    /* start with the full inflow velocity everywhere (else at rest) */
    double cfl; int max_substeps; double pressure_tol; int pressure_max_iter;
} DrAirDesc;
/* Unit box, dx 1/32, air (1.2 kg/m³, 1.8e-5 Pa·s), inflow on −x at 0 m/s (a closed box), ramp 0, at rest, cfl 1,
   64 substeps, tolerance 1e-6, 1000 iterations. */
void dr_air_desc_default(DrAirDesc *d);

typedef struct DrAirStats {
    int substeps;
    int pressure_iterations_max; long pressure_iterations_total; double pressure_residual_max;
    int pressure_not_converged;   /* projections whose solve stopped at max_iter (each logged as a warning) */
    long pressure_cells;          /* unknowns of the last projection */
    double max_speed;             /* largest |u_f| over the velocity unknowns after the last projection, m/s */
    double divergence_max;        /* largest |Σ_f ±flux_f|/Δx³ over the pressure cells after the last projection, 1/s */
    double inflow_flux, outflow_flux; /* volume flux into the box through the inflow face and out through the outflow
                                     face after the last projection, m³/s (flux_f = (w u + (1 − w) u_solid) Δx²) */
    int viscosity_subcycles;      /* the most explicit viscosity parts of a substep (1 within the limit) */
    /* Momentum (N·s) the last projection of each substep gave the air, summed over substeps, per face and e_a:
       added_impulse Σ J_f over the faces taking the extra coupling's impulses; drag_impulse Σ β_f (V_f − u_f) with the
       projected u_f; pressure_impulse Σ −m_f (q_hi − q_lo)/Δx, q = pΔt/ρ, the pressure's momentum, which sums to the
       forces of the walls, the colliders and the outflow face. The projection's change Σ_f m_f (u_f − u*_f) e_a equals
       added + drag + pressure to round-off (a closed box's pressure takes back whatever net momentum the others give:
       no divergence-free field with closed walls carries momentum). */
    DrVec3 added_impulse, drag_impulse, pressure_impulse;
    double seconds_advect, seconds_pressure, seconds_other;
} DrAirStats;

typedef struct DrAir DrAir;
/* Creates the grid and the face velocities (at rest or the stream; colliders borrowed for the call only: the initial
   state is not projected around them, the first substep does it). DR_ERR_INPUT naming the field for out-of-range
   parameters; DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_air_create(const DrAirDesc *desc, DrAir **out, DrError *err);
void dr_air_destroy(DrAir **air);
/* The loop while (t < t1) { stable_dt(t, t1, &h); begin(t, h); project(NULL); end(); t = h == t1 − t ? t1 : t + h; },
   bit-identical to calling the phases. Zeroes *stats first. Errors as the phases'. */
DR_NODISCARD DrStatus dr_air_advance(DrAir *air, const DrCollider *const *colliders, int ncolliders, double t0,
                                     double t1, DrAirStats *stats, DrError *err);
/* ---- the substep in phases (as the liquid's: one substep's calls come in this order, asserted) ----
 * stable_dt: h ≤ cfl·Δx/max(U, |wind|), U the largest |u_f| (the full wind, not the ramped one), at most max_substeps
 *   in the interval, the interval [t, t_end] split into equal substeps; h == t_end − t when it lands (take t_end as the
 *   next t). The first call with a given t_end (or t before the interval's start) opens [t, t_end]. DR_ERR_INPUT for
 *   a bad collider count or t_end not after t; DR_ERR_RUNTIME for non-finite velocities. *h is 0 on failure. */
DR_NODISCARD DrStatus dr_air_stable_dt(DrAir *air, const DrCollider *const *colliders, int ncolliders, double t,
                                       double t_end, double *h, DrError *err);
/* begin: 0 < h ≤ (1 + 1e-9)·the stable step: colliders posed at t + h (face open fractions from their phi at the
   face corners, their velocity on faces within 2Δx of them), advection over h, viscosity, the boundary values (the
   wind at t + h); keeps the velocities every projection starts from. DR_ERR_INPUT for h out of range or a bad
   collider count. */
DR_NODISCARD DrStatus dr_air_begin(DrAir *air, const DrCollider *const *colliders, int ncolliders, double t, double h,
                                   DrError *err);
/* project: from the velocities begin kept (re-callable: the same extra gives the same bits), with extra (NULL: none;
   sized like dr_air_grid; borrowed) added to the colliders' coupling exactly as dr_liquid_project documents: its
   solid share adds to the colliders' (open = max(0, w_own + w_extra − 1), solid velocity share-weighted; faces it
   leaves fully open keep the colliders' values), its impulse J_f becomes the velocity increment J_f/m_f on the
   faces that are velocity unknowns with open > 0 (elsewhere dropped), and its drag mass β_f (≥ 0, same faces) pulling
   towards its velocity V_f (extra->velocity, read wherever β_f > 0) gives u_f = (m_f u*_f + J_f + β_f V_f)/(m_f + β_f) before the pressure and scales the face's Poisson coefficient by
   m_f/(m_f + β_f). Adds the solve's figures and the impulses to *stats (the impulses at end, of the last call).
   DR_ERR_INPUT for an open fraction outside [0, 1], a negative drag mass or non-finite values; DR_ERR_RUNTIME if
   PCG breaks down; a solve that does not converge is a warning (stats). */
DR_NODISCARD DrStatus dr_air_project(DrAir *air, const DrFaceCoupling *extra, DrAirStats *stats, DrError *err);
/* sample: after a project (until the next stable_dt): velocity (trilinear on each face lattice, dr_mac_sample_face)
   and pressure (Pa, p = ρq/h at the pressure cells' centres, 0 in blocked cells, trilinear on the cell centres,
   clamped at the box) at n points (3n). vel_out or pressure_out may be NULL. Reads only. */
void dr_air_sample(const DrAir *air, long n, const double *points, double *vel_out, double *pressure_out);
/* m_f of component a (kg; nfaces[a] values, grid face order): ρΔx³ on velocity unknowns, 0 on walls and the inflow
   face. Constant for the air's life; borrowed. */
const double *dr_air_face_mass(const DrAir *air, int a);
/* The faces that took the extra coupling's impulse and drag in the last dr_air_project given one (velocity unknowns
   the colliders leave open), as dr_liquid_coupled_faces; NULL before any. */
const unsigned char *dr_air_coupled_faces(const DrAir *air, int a);
/* end: closes the substep: adds it to *stats (substeps, impulses of the last projection, max speed, fluxes,
   seconds). */
DR_NODISCARD DrStatus dr_air_end(DrAir *air, DrAirStats *stats, DrError *err);

const DrMacGrid *dr_air_grid(const DrAir *air);  /* face velocities, m/s */
/* Mass ρ × the open volume (cells' open fractions, the colliders of the last begin), momentum Σ m_f u_f e_a, kinetic
   energy ½ Σ m_f u_f². */
void dr_air_totals(const DrAir *air, double *mass, DrVec3 *momentum, double *kinetic);
/* Checkpoint: the face velocities (dr_air_grid) are the whole state; restore copies them back (nfaces[a] values each)
   and closes any open substep. DR_ERR_INPUT for non-finite values. */
DR_NODISCARD DrStatus dr_air_restore(DrAir *air, const double *const velocity[3], DrError *err);

#endif
