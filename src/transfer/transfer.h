/* drench transfer: particle ↔ grid transfers PIC, FLIP and APIC ([APIC] §2–3, §5.9) on the MAC grid of
 * the liquid, with the quadratic B-spline kernel of grid.h (D = Δx²/4·I, so C = B D⁻¹).
 *
 * MAC form of APIC ([APIC] §5.9 / PHYSICS §1): each face component a has its own node lattice and
 * weights w_aip, and each particle carries one affine vector c_pa per component (the rows of C_p):
 *   P2G  m_ai = Σ_p w_aip m_p,  m_ai u_ai = Σ_p w_aip m_p (v_pa + c_pa·(x_ai − x_p))      (eqs. 24–26)
 *   G2P  v_pa = Σ_i w_aip u_ai,  c_pa = D⁻¹ Σ_i w_aip u_ai (x_ai − x_p)                   (eqs. 37–39)
 * PIC is the same with c = 0; FLIP adds the grid change to the particle velocity and blends with PIC.
 *
 * Boundary nodes. Stencil nodes outside the face arrays (at most one layer beyond the domain box when
 * particles lie inside it) stand for the mirror image of a stored node across the domain wall: odd (−u)
 * for the wall-normal component, even (+u, slip) or odd (no-slip) for tangential ones. G2P reads the
 * image; P2G, its adjoint, adds the node's mass to the image node and its momentum with the mirror sign.
 * Folding keeps the face masses next to walls those of the unbounded lattice (uniform seeding gives
 * uniform masses on every face not lying on a wall), which the mass-weighted pressure needs to keep
 * still water still (a face density falling off towards a wall is a horizontal density gradient, which
 * drives flow).
 *
 * Performance: the particles of one cell reach the same 4×3×3 nodes of each component, so P2G sums a
 * cell's particles into a local block and adds the block to the grid once, and G2P loads the block once
 * for consecutive particles of one cell (fastest when the particles are stored in cell order, as the
 * liquid keeps them; any order gives the same results). Small inputs (under ~16k particles or faces) run
 * serially: a parallel region would cost more than the work.
 *
 * Determinism: P2G sorts particles by cell (counting sort, stable) and scatters by slabs of
 * DR_TRANSFER_SLAB cells along z, even slabs in parallel then odd ones, without atomics; every face sums
 * its contributions in an order that depends only on the particle data, so P2G is bit-identical for any
 * thread count. G2P is a gather, parallel over particles, also independent of the thread count.
 * Thread safety: functions may run concurrently on distinct outputs. */
#ifndef DR_TRANSFER_H
#define DR_TRANSFER_H

#include "core/core.h"
#include "grid/grid.h"

typedef enum DrTransferScheme { DR_TRANSFER_APIC, DR_TRANSFER_FLIP, DR_TRANSFER_PIC } DrTransferScheme;

/* Slab thickness (cells along z) of the coloured P2G scatter: a quadratic stencil reaches one node
   beyond its cell on each side, so slabs at least 3 thick never share a face with the next same-colour
   slab. */
#define DR_TRANSFER_SLAB 4

/* Particles bucketed by grid cell (counting sort), with P2G's accumulators sized for the grid given to
   dr_bins_create (use the bins with that grid only). Reused between substeps: buffers grow only when the
   particle count exceeds the capacity. */
typedef struct DrParticleBins {
    long n, ncells;
    long *cell_start; /* ncells + 1 offsets into order */
    long *order;      /* n particle indices, by cell then by particle index */
    long *cell_of;    /* n cell indices (scratch of the sort) */
    long cap;         /* capacity of order/cell_of */
    double *acc[3];   /* P2G accumulators: (mass, momentum) interleaved per face of component a */
} DrParticleBins;
DR_NODISCARD DrStatus dr_bins_create(const DrMacGrid *g, long n_capacity, DrParticleBins **out, DrError *err);
void dr_bins_destroy(DrParticleBins **b);
/* Sorts n particles (3n positions, metres) into the grid's cells; positions outside the grid box count
   in the nearest cell. Grows the buffers when n exceeds the capacity (DR_ERR_NOMEM on exhaustion). */
DR_NODISCARD DrStatus dr_bins_build(const DrMacGrid *g, long n, const double *x, DrParticleBins *b, DrError *err);

/* P2G on the MAC grid. x, v: 3n arrays; c: 9n affine vectors (c[9p + 3a + b] = component b of c_pa) or
   NULL (PIC/FLIP: c = 0); mass per particle (kg). Writes the face masses face_mass[a] (kg, nfaces[a]
   each) and the face velocities g->f[a] (m/s; 0 where the mass is 0). `b` must be built from the same x.
   wall_no_slip selects the tangential mirror as in G2P. */
void dr_transfer_p2g_mac(const DrParticleBins *b, const double *x, const double *v, const double *c,
                         double mass, bool wall_no_slip, DrMacGrid *g, double *const face_mass[3]);

/* G2P on the MAC grid for n particles at x (in the grid box). scheme selects the update:
   APIC: v_p and c_p from the grid (c required); PIC: v_p from the grid, c (if non-NULL) zeroed;
   FLIP: v_p ← flip_blend·v_PIC + (1 − flip_blend)·(v_p + Σ w (u − u_old)), u_old = the grid velocity
   right after P2G (old[a], required), c (if non-NULL) zeroed. wall_no_slip selects the tangential mirror. */
void dr_transfer_g2p_mac(const DrMacGrid *g, const double *const old[3], DrTransferScheme scheme,
                         double flip_blend, bool wall_no_slip, long n, const double *x, double *v, double *c);

/* Particle totals: momentum Σ m v and angular momentum about the origin including the affine part,
   L = Σ x_p × m v_p + m ε:(B_pᵀ) with B_p rows D c_pa, D = dx²/4 ([APIC] §5.3). c may be NULL. */
void dr_transfer_particle_totals(long n, const double *x, const double *v, const double *c, double mass,
                                 double dx, DrVec3 *momentum, DrVec3 *angular);
/* Grid totals of face momenta: Σ m_f u_f e_a and Σ x_f × m_f u_f e_a about the origin. */
void dr_transfer_grid_totals(const DrMacGrid *g, const double *const face_mass[3], const double *const vel[3],
                             DrVec3 *momentum, DrVec3 *angular);

#endif
