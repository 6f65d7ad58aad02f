/* Private to src/hair: the discrete-elastic-rod kernels of one strand (Bergou et al. 2008/2010, as used by
 * fei2017 §S4; PHYSICS §4). Pure functions on flat arrays; no allocation; thread-safe.
 *
 * A strand has nv ≥ 2 vertices x_0..x_{nv−1} and ne = nv − 1 edges e^j = x_{j+1} − x_j with unit tangents
 * t^j. Each edge carries a reference frame (t^j, a1^j, a2^j = t^j × a1^j) and a twist θ^j; its material
 * frame is m1^j = cos θ^j a1^j + sin θ^j a2^j, m2^j = −sin θ^j a1^j + cos θ^j a2^j.
 *
 * Reference frames move by time-parallel transport: when the tangents change from t_ref to t, a1 becomes
 * P(t_ref → t) a1_ref, P the rotation about t_ref × t taking t_ref to t. Every constraint below is a
 * function of the strand's DOFs q (vertex positions and edge twists) for a fixed reference state
 * (t_ref, a1_ref of each edge, and the reference twist m_ref of each interior vertex), with the frames
 * transported from that reference state. The Jacobians are the exact derivatives of that function (they
 * equal the textbook DER gradients at q = q_ref); the geometric stiffness G = Σ_k λ_k ∇²φ_k is the
 * central difference of the exact Jacobian.
 *
 * Strand DOF layout (local numbering inside a strand's block): x_0 (3), θ^0, x_1 (3), θ^1, …, θ^{ne−1},
 * x_{nv−1} (3): 4 nv − 1 DOFs, vertex j at 4j, twist of edge j at 4j + 3. Interior vertex i (1 ≤ i ≤ nv−2)
 * couples DOFs 4(i−1) … 4(i+1)+2: 11 DOFs, half-bandwidth 10.
 *
 * Curvature binormal at interior vertex i: κb_i = 2 t^{i−1} × t^i / (1 + t^{i−1}·t^i). Material curvatures
 * in the frame of edge j ∈ {i−1, i}: κ_i^j = (κb_i·m2^j, −κb_i·m1^j). Reference twist m_i: the signed angle
 * about t^i from P(t^{i−1} → t^i) a1^{i−1} to a1^i, continued from m_ref (no 2π jumps). Twist
 * τ_i = θ^i − θ^{i−1} + m_i. Voronoi length l_i = (l̄^{i−1} + l̄^i)/2 from the rest lengths. */
#ifndef DR_HAIR_ROD_H
#define DR_HAIR_ROD_H

#include <stdbool.h>

#include "lagrangian/lagrangian.h"

/* Unit tangents t (ne×3) and lengths len (ne) of the edges of positions x (nv×3). A zero-length edge gives
 * t = 0 and len = 0 (callers reject those at creation). */
void dr_rod_tangents(int nv, const double *x, double *t, double *len);

/* Space-parallel transport along the strand: a1^0 = the component of `a1_root` perpendicular to t^0
 * (normalised; any perpendicular unit vector when a1_root is parallel to t^0 or NULL), then a1^{j+1} =
 * P(t^j → t^{j+1}) a1^j. Used to set up the rest frames. */
void dr_rod_space_frames(int ne, const double *t, const double *a1_root, double *a1);

/* Time-parallel transport of each edge's a1 from tangents t_old to t_new (in place, re-orthonormalised). */
void dr_rod_time_transport(int ne, const double *t_old, const double *t_new, double *a1);

/* P(u → v) w for unit u, v (u = −v: the rotation by π about any axis perpendicular to u). */
void dr_rod_transport(const double u[3], const double v[3], const double w[3], double out[3]);

/* Reference twist m_i of every interior vertex (nv − 2 values) for tangents t and frames a1; m holds the
 * previous values on entry (for continuity: the result is the representative nearest to it) and the new
 * ones on exit. */
void dr_rod_reference_twist(int nv, const double *t, const double *a1, double *m);

/* Material curvatures κ_i^{i−1}, κ_i^i (4 values per interior vertex: κ1, κ2 in the frame of edge i−1,
 * then κ1, κ2 in the frame of edge i) and twists τ_i (nv − 2 values) of a strand: the rest values when
 * called on the rest state. */
void dr_rod_curvatures(int nv, const double *t, const double *a1, const double *theta, const double *m,
                       double *kappa, double *tau);

/* ---- constraint groups ---------------------------------------------------------------------------------- */

/* Stiffnesses of a strand: k_s = Eπr² (N), B = Eπr⁴/4 (N m²), k_t = Gπr⁴/2 (N m²). */
typedef struct DrRodStiffness { double ks, bend, twist; } DrRodStiffness;

/* The reference state the constraint functions are built on (one strand, pointers into its arrays):
 * t_ref (ne×3), a1_ref (ne×3), m_ref (nv−2). */
typedef struct DrRodRef { const double *t, *a1, *m; } DrRodRef;

/* Stretching of edge j: one row φ = l − l̄ (m), C⁻¹ = k_s / l̄, over the 6 DOFs of x_j, x_{j+1} (global
 * indices dof0 + 4j + {0,1,2, 4,5,6}). G (when lambda and G are non-NULL) = λ (I − t tᵀ)/l on both
 * vertices with the signs of ∇²l, 36 entries written to G and linked from g->G. */
void dr_rod_stretch_group(const double *x, int j, double lbar, double ks, int dof0, const double *lambda,
                          double *G, DrLagGroup *g);

/* Bending at interior vertex i: four rows φ = κ_i^{i−1} − κ̄, κ_i^i − κ̄ (dimensionless), each with
 * C⁻¹ = B / (2 l_i) (the average of the two frames' energies, Bergou 2008 eq. 5 with l_i the Voronoi
 * length), over the 11 DOFs of x_{i−1}, θ^{i−1}, x_i, θ^i, x_{i+1} (global dof0 + 4(i−1) … dof0 + 4(i+1)+2).
 * kappa_bar: the 4 rest values. lambda (4, may be NULL) and G (121, may be NULL) as above. */
void dr_rod_bend_group(const double *x, const double *theta, const DrRodRef *ref, int i, const double *kappa_bar,
                       double lv, double bend, int dof0, const double *lambda, double *G, DrLagGroup *g);

/* Twisting at interior vertex i: one row φ = τ_i − τ̄_i (rad), C⁻¹ = k_t / l_i, same 11 DOFs. */
void dr_rod_twist_group(const double *x, const double *theta, const DrRodRef *ref, int i, double tau_bar,
                        double lv, double twist, int dof0, const double *lambda, double *G, DrLagGroup *g);

/* Elastic energy of a strand (J): Σ ½ k_s (l − l̄)²/l̄ + Σ_i Σ_j B |κ_i^j − κ̄|² / (4 l_i) + Σ_i k_t (τ_i − τ̄_i)² / (2 l_i),
 * frames transported from ref to the tangents of x. lbar (ne), kappa_bar (4(nv−2)), tau_bar (nv−2). */
double dr_rod_energy(int nv, const double *x, const double *theta, const DrRodRef *ref, const double *lbar,
                     const double *kappa_bar, const double *tau_bar, DrRodStiffness k);
/* The same with a stiffness per element (a tapered strand): ks per edge (nv − 1), bend and twist per interior vertex
 * (nv − 2); with every entry equal to k's, the same bits as dr_rod_energy. */
double dr_rod_energy_varying(int nv, const double *x, const double *theta, const DrRodRef *ref, const double *lbar,
                             const double *kappa_bar, const double *tau_bar, const double *ks, const double *bend,
                             const double *twist);

#endif
