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

/* PIC: C = 0. FLIP: grid change added to the particle velocity, blended with PIC (eq. 3). RPIC: only the
   skew part of C is kept ([APIC] §2.1). APIC: full affine C ([APIC] §2.2, §3). */
typedef enum DrTransferScheme { DR_TRANSFER_APIC, DR_TRANSFER_FLIP, DR_TRANSFER_PIC, DR_TRANSFER_RPIC } DrTransferScheme;

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
   NULL (PIC/FLIP: c = 0); particle p's mass (kg) is m_p = mass·scale[p], scale n factors (≥ 0) or NULL
   (every factor 1: m_p = mass; a factor 1.0 gives the same bits as NULL). Writes the face masses
   face_mass[a] (kg, nfaces[a] each) and the face velocities g->f[a] (m/s; 0 where the mass is 0). `b` must
   be built from the same x. wall_no_slip selects the tangential mirror as in G2P. */
void dr_transfer_p2g_mac(const DrParticleBins *b, const double *x, const double *v, const double *c,
                         double mass, const double *scale, bool wall_no_slip, DrMacGrid *g,
                         double *const face_mass[3]);

/* G2P on the MAC grid for n particles at x (in the grid box). scheme selects the update:
   APIC: v_p and c_p from the grid (c required); PIC: v_p from the grid, c (if non-NULL) zeroed;
   FLIP: v_p ← flip_blend·v_PIC + (1 − flip_blend)·(v_p + Σ w (u − u_old)), u_old = the grid velocity
   right after P2G (old[a], required), c (if non-NULL) zeroed. wall_no_slip selects the tangential mirror. */
void dr_transfer_g2p_mac(const DrMacGrid *g, const double *const old[3], DrTransferScheme scheme,
                         double flip_blend, bool wall_no_slip, long n, const double *x, double *v, double *c);

/* Particle totals: momentum Σ m_p v_p and angular momentum about the origin including the affine part,
   L = Σ x_p × m_p v_p + m_p ε:(B_pᵀ) with B_p rows D c_pa, D = dx²/4 ([APIC] §5.3), m_p = mass·scale[p]
   (scale NULL: m_p = mass, as in P2G). c may be NULL. */
void dr_transfer_particle_totals(long n, const double *x, const double *v, const double *c, double mass,
                                 const double *scale, double dx, DrVec3 *momentum, DrVec3 *angular);
/* Grid totals of face momenta: Σ m_f u_f e_a and Σ x_f × m_f u_f e_a about the origin. */
void dr_transfer_grid_totals(const DrMacGrid *g, const double *const face_mass[3], const double *const vel[3],
                             DrVec3 *momentum, DrVec3 *angular);

/* ==== Collocated grid (MPM) ==========================================================================
 * One node lattice for every velocity component, nodes at origin + Δx·(i, j, k). The same schemes as the
 * MAC variant above, with a choice of kernel:
 *   quadratic and cubic B-splines: D = Δx²/4·I and Δx²/3·I (constant), C_p = B_p D⁻¹;
 *   multilinear: D is not invertible, so C is lagged ([APIC] §5.9): C_p^{n+1} = Σ_i ṽ_i ∇w_ipᵀ.
 * dim = 2 runs the same code with a single node layer along z (weight 1, gradient 0): the particles' z
 * coordinate is ignored (G2P leaves it unchanged), z components of node and particle velocities, of the
 * scatters' and gathers' outputs and of grad_u are written 0, and C has no z row or column. Angular
 * momentum in 2-D is the z component (the x, y components of the totals depend on where the particles' z
 * coordinates sit; they match the grid's when particles carry z = origin.z).
 *
 * Equations ([APIC] §3): P2G eqs. (24)–(26); G2P eqs. (37)–(39) with the general-λ affine update (38)
 * (λ = 0 symplectic Euler, λ = ½ midpoint; for λ = 0 it reduces to B = Σ w ṽ (x_i − x_p)ᵀ); grid motion
 * x̃_i − x_i = Δt (λ v_i + (1 − λ) ṽ_i) (30); the F update (40) is the caller's, from the velocity
 * gradient G2P returns. Forces f_i = Σ_p M_p ∇w_ip (eq. 34 with M_p = −V_p P F₀ᵀ) and the gradient
 * gather Σ_i u_i ∇w_ipᵀ (eqs. 35–36, 40) are the two other grid operations an MPM step needs; all of them
 * use the weights of x_p at the start of the step.
 *
 * Conservation ([APIC] §5.1–5.3), to round-off, for quadratic and cubic kernels and APIC or RPIC:
 *   P2G: grid Σ m_i v_i and Σ x_i × m_i v_i equal the particle totals of dr_node_particle_totals;
 *   G2P: the particle totals after G2P (moved x_p, new v_p and C_p) equal Σ m_i ṽ_i and Σ x̃_i × m_i ṽ_i
 *   with x̃_i = x_i + Δt(λ v_i + (1 − λ) ṽ_i); for λ = 0 (or Δt = 0) x̃_i × ṽ_i = x_i × ṽ_i, so they equal
 *   dr_node_grid_totals of ṽ. Linear momentum is conserved by every scheme and kernel. The lagged linear
 *   kernel's P2G adds m ε:(C D_p)ᵀ with the per-particle D_p = Σ w r rᵀ, which the totals do not count.
 * An affine grid field v_i = b + A x_i survives G2P → P2G (Δt = 0) exactly with APIC for every kernel
 * (C_p = A), not with PIC. An isolated particle without forces keeps v_p and B_p through P2G → G2P for
 * any λ and moves by Δt v_p (§5.4).
 *
 * Performance and determinism: scatters (P2G, dr_node_scatter_*) sum each bin's particles into a local
 * block of K^dim nodes and add it to the grid once; bins are processed in slabs along the last axis (z in
 * 3-D, y in 2-D), even slabs in parallel then odd ones, without atomics, so every node sums in an order
 * fixed by the particle data: bit-identical for any thread count. Gathers (G2P, dr_node_gather_*) run in
 * parallel over particles in index order, each particle independent, and copy a stencil's K^dim node values
 * once for consecutive particles of one bin; they are fastest when particles are stored in bin order
 * (dr_node_bins_order). Inputs under ~16k particles run serially. No allocation happens in any transfer;
 * the bins grow only in dr_node_bins_build.
 * Scatters and gathers do their arithmetic on vectors of 4 lanes (a node's x, y, z velocity and a pad, or
 * P2G's mass and momentum), each lane in the order of the scalar loop over components, in a baseline
 * x86-64 (SSE2) build and an AVX2 build chosen at run time, without fused multiply-add: both builds do the
 * same IEEE operations in the same order, those of the scalar loops the recorded MPM hashes were made
 * with. On 1M particles (tests/bench/bench_transfer), 3-D quadratic APIC with the velocity gradient runs
 * at about 9 M particle-steps/s per core in bin order (a P2G with its bins build, plus a G2P); in the
 * order of a particle lattice (x fastest), as an MPM body is sampled and keeps it, about 10 % slower.
 * Thread safety: functions may run concurrently on distinct outputs. */

typedef enum DrKernel { DR_KERNEL_LINEAR, DR_KERNEL_QUADRATIC, DR_KERNEL_CUBIC } DrKernel;

/* One axis of a kernel stencil: n nodes base .. base+n−1 (2, 3 or 4), weights w (sum 1) and their
   derivatives dw per grid unit (d w / d s); entries beyond n are 0. s is the sample in grid units relative
   to node 0; base is ⌊s⌋ (linear), ⌊s − ½⌋ (quadratic, the numbers of dr_kernel_quadratic), ⌊s⌋ − 1
   (cubic). Each kernel reproduces linear functions: Σ w = 1, Σ w·node = s, Σ dw·node = 1 ([APIC]
   eqs. 20–23); Σ w (node − s)² = ¼ (quadratic), ⅓ (cubic), (s − ⌊s⌋)(1 − s + ⌊s⌋) (linear). */
typedef struct DrStencil { int base, n; double w[4], dw[4]; } DrStencil;
DrStencil dr_kernel_eval(DrKernel k, double s);
/* D⁻¹ as a scalar (4/Δx² quadratic, 3/Δx² cubic); 0 for linear (lagged C, no D). */
double dr_kernel_dinv(DrKernel k, double dx);
/* Nodes a stencil reaches beyond the sample's cell on the low and high side (linear 0/1, quadratic 1/2,
   cubic 1/2 counting the cell's own high node); returns the larger (linear 1, quadratic 2, cubic 2): a grid
   whose nodes extend this many spacings beyond a box on every side holds particles anywhere in the closed
   box, faces included. */
int dr_kernel_reach(DrKernel k);

/* A collocated node grid and its per-node fields. Owned by the caller (the MPM solver); the transfer
   functions read and write the arrays, never reallocate them. */
typedef struct DrNodeGrid {
    int dim;          /* 2 or 3 */
    int n[3];         /* node counts; n[2] == 1 when dim == 2 */
    double dx;        /* Δx, metres */
    DrVec3 origin;    /* position of node (0,0,0) */
    DrKernel kernel;
    long nnodes;
    double *mass;     /* m_i, kg (nnodes) */
    double *vel;      /* v_i, m/s (3·nnodes): after P2G the transferred velocity */
} DrNodeGrid;
DR_NODISCARD DrStatus dr_node_grid_create(int dim, const int n[3], double dx, DrVec3 origin, DrKernel kernel,
                                          DrNodeGrid **out, DrError *err);
void dr_node_grid_destroy(DrNodeGrid **g);
static inline long dr_node_index(const DrNodeGrid *g, int i, int j, int k)
{
    return (long)i + (long)g->n[0] * ((long)j + (long)g->n[1] * (long)k);
}
DrVec3 dr_node_position(const DrNodeGrid *g, long node);

/* Particles bucketed by the cell containing them, for the coloured scatter (no atomics, bit-identical for
   any thread count) and cache-friendly gathers. A bin is a stencil base node (dr_kernel_eval's base per
   axis): for the linear and cubic kernels the cell containing the particle, for the quadratic kernel the
   cell of the lattice shifted by half a spacing. Positions must lie where their whole stencil is inside
   the grid (dr_kernel_reach nodes from every face is enough); dr_node_bins_build returns DR_ERR_INPUT
   naming the first (lowest-index) particle that does not, or whose position is not finite, and leaves
   the bins empty. Bins belong to the grid they were created for (same dims, spacing, kernel). */
typedef struct DrNodeBins DrNodeBins;
DR_NODISCARD DrStatus dr_node_bins_create(const DrNodeGrid *g, long n_capacity, DrNodeBins **out, DrError *err);
void dr_node_bins_destroy(DrNodeBins **b);
DR_NODISCARD DrStatus dr_node_bins_build(const DrNodeGrid *g, long n, const double *x, DrNodeBins *b, DrError *err);
/* The particle indices of the last build in bin order (stable: ascending index within a bin) and their
   count. A solver that permutes its particle arrays into this order keeps the gathers cache-friendly.
   Valid until the next build or destroy. */
const long *dr_node_bins_order(const DrNodeBins *b, long *n);

/* P2G: node masses and velocities from particles. x, v: 3n; C: 9n row-major (C[9p + 3r + c]) affine
   matrices or NULL (PIC/FLIP); mass: n (kg). RPIC and APIC pass C (RPIC's C is skew already, G2P keeps it
   so). Every kernel uses m_i v_i = Σ_p w_ip m_p (v_p + C_p (x_i − x_p)) (eq. 26 with C = B D⁻¹; for the
   linear kernel C is the lagged matrix of §5.9). Overwrites g->mass (kg) and g->vel (m/s); nodes without
   mass get v = 0. `b` must be built from this x (checked by assertion). */
void dr_node_p2g(const DrNodeBins *b, const double *x, const double *v, const double *C, const double *mass,
                 DrNodeGrid *g);

/* G2P after the grid update. vel_new = ṽ^{n+1} (3·nnodes), vel_old = v^n (the P2G result), lambda the
   integrator's λ (grid displacement x̃_i − x_i = Δt(λ v_i + (1 − λ) ṽ_i)), dt the step.
   Updates in place, per particle: v (scheme rule; FLIP blends v_PIC with v + Σ w (ṽ − v^n) by
   flip_blend), C (APIC: eq. 38 times D⁻¹, or the lagged form for linear; RPIC: its skew part; PIC/FLIP:
   0; C may be NULL for PIC/FLIP), x ← Σ w x̃_i = x_p + Δt Σ w u_i (eq. 39, using Σ w x_i = x_p), and
   if grad_u != NULL writes grad_u[9p..] = Σ_i u_i ∇w_ipᵀ (row-major, 1/s), u_i = (x̃_i − x_i)/Δt =
   λ v_i + (1 − λ) ṽ_i (defined for Δt = 0 too), so the caller's eq. (40) is F ← (I + Δt·grad_u) F.
   The general-λ eq. (38) is B = Σ w ṽ r_iᵀ + (Δt/2) Σ w [ṽ (u_i − ū)ᵀ − (u_i − ū) ṽᵀ] with r_i = x_i − x_p,
   ū = Σ w u_i; then C = B D⁻¹. The lagged linear C = Σ ṽ ∇wᵀ does not depend on λ. vel_old may be NULL
   when it is not read: scheme other than FLIP, and λ = 0 or (Δt = 0 and grad_u == NULL).
   Positions must be those the bins accepted (stencils inside the grid; checked by assertion). */
void dr_node_g2p(const DrNodeGrid *g, const double *vel_new, const double *vel_old, double lambda, double dt,
                 DrTransferScheme scheme, double flip_blend, long n, double *x, double *v, double *C,
                 double *grad_u);

/* Scatter of per-particle 3×3 matrices through the weight gradients: out_i = Σ_p M_p ∇w_ip (3·nnodes,
   overwritten). With M_p = −V_p P_p F_pᵀ this is the force of eq. (34); with M_p = −V_p A_p F_pᵀ the force
   differential of eq. (36). Same colouring as P2G. It is the adjoint of dr_node_gather_gradient:
   Σ_i out_i·u_i = Σ_p M_p : (Σ_i u_i ∇w_ipᵀ). By eqs. (20) and (23), Σ_i out_i = 0 and
   Σ_i x_i × out_i = Σ_p (M₂₁ − M₁₂, M₀₂ − M₂₀, M₁₀ − M₀₁)_p, zero for symmetric M_p (P Fᵀ of an isotropic
   material, §5.3.2). */
void dr_node_scatter_gradient(const DrNodeBins *b, const double *x, const double *M, DrNodeGrid *g, double *out);
/* Gather of a node vector field through the weight gradients: out[9p..] = Σ_i u_i ∇w_ipᵀ (row-major). */
void dr_node_gather_gradient(const DrNodeGrid *g, const double *u, long n, const double *x, double *out);
/* Weighted scatter and gather of per-particle vectors (external particle forces, positional anchors):
   out_i = Σ_p w_ip f_p (3·nnodes, overwritten); out_p = Σ_i w_ip u_i. Adjoint to each other; the scatter
   conserves Σ f (partition of unity). */
void dr_node_scatter_vector(const DrNodeBins *b, const double *x, const double *f, DrNodeGrid *g, double *out);
void dr_node_gather_vector(const DrNodeGrid *g, const double *u, long n, const double *x, double *out);

/* Totals: particles Σ m v and Σ (x × m v + m ε:(C D)ᵀ) about the origin (affine part with the kernel's D;
   linear kernels carry no affine angular momentum term), grid Σ m_i v_i and Σ x_i × m_i v_i over nodes
   with mass, using g->mass and the given node velocities (e.g. ṽ after the grid update). KE ½Σ m v².
   Any output pointer may be NULL. Sums run serially in index order (reproducible). */
void dr_node_particle_totals(DrKernel k, double dx, long n, const double *x, const double *v, const double *C,
                             const double *mass, DrVec3 *momentum, DrVec3 *angular, double *kinetic);
void dr_node_grid_totals(const DrNodeGrid *g, const double *vel, DrVec3 *momentum, DrVec3 *angular,
                         double *kinetic);

#endif
