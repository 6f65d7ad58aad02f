/* Private to src/liquid: the implicit (variational) viscosity solve of the liquid's MAC grid (liquid.c calls it for
 * a substep whose explicit viscosity step would be unstable).
 *
 * Batty & Bridson 2008 ("Accurate viscous free surfaces for buckling, coiling, and rotating liquids"): the new face
 * velocities u minimise
 *     E(u) = Σ_f ½ m_f (u_f − u*_f)²  +  Δt μ Δx³ [ Σ_cells V_c Σ_a ε_aa²  +  Σ_edges V_e · 2 ε_ab² ],
 * the kinetic energy of the change plus Δt times the viscous dissipation μ|D|² of the rate of strain D = ½(∇u + ∇uᵀ),
 * whose gradient is the backward Euler step m (u − u*) = Δt ∇·(2μD). The diagonal strain rates ε_aa live at cell
 * centres, the shear rates ε_ab on the cell edges parallel to the third axis, each weighted by the liquid fraction of
 * its control volume (V_c the cell's fill, V_e the mean fill of the four cells around the edge): stress vanishes in
 * the air, which is the traction-free surface condition, and a half-filled cell carries half the stress. m_f is the
 * face's P2G mass. The system is symmetric positive definite; PCG with MIC(0) (src/linalg) solves it.
 *
 * Unknowns are the faces holding mass (m_f > 0) that are open to the liquid (open > 0: not a domain wall's normal
 * face nor fully inside a collider); closed faces hold their solid velocity (walls 0, colliders theirs: the liquid
 * sticks to them, as a viscous liquid does); a face outside the domain, met by a shear rate on a wall, mirrors the
 * face inside (slip walls: no shear stress; no-slip walls: the wall's velocity 0 midway, so −u). Unconditionally
 * stable: used at any ν Δt / Δx². */
#ifndef DR_LIQUID_VISCOSITY_H
#define DR_LIQUID_VISCOSITY_H

#include "core/core.h"
#include "grid/grid.h"

typedef struct DrViscosityInput {
    DrMacGrid *g;              /* face velocities: u* on entry, u on return (unknown faces only) */
    const double *mass[3];     /* P2G face masses, kg */
    const double *open[3];     /* open fraction per face: <= 0 closed (held at velocity[]) */
    const double *velocity[3]; /* solid velocity per face (read where closed), m/s */
    const float *fill;         /* liquid fraction of each cell, [0, 1] */
    double mu;                 /* dynamic viscosity, Pa·s */
    double dt;                 /* s */
    bool no_slip;              /* domain walls */
    double tolerance;          /* PCG relative residual */
    int max_iterations;
} DrViscosityInput;

typedef struct DrViscosityStats {
    long unknowns;
    int iterations;
    double rel_residual;
    bool converged;
} DrViscosityStats;

typedef struct DrViscosity DrViscosity;
DR_NODISCARD DrStatus dr_viscosity_create(DrViscosity **out, DrError *err);
void dr_viscosity_destroy(DrViscosity **v);
/* One implicit viscosity step. A solve that stops at max_iterations keeps its last iterate (stats->converged
   false; the caller warns). DR_ERR_RUNTIME on a breakdown or non-finite values, DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_viscosity_solve(DrViscosity *v, const DrViscosityInput *in, DrViscosityStats *stats,
                                         DrError *err);

#endif
