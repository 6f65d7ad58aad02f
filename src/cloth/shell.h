/* Private to src/cloth: the discrete-shell kernels of one triangle and one hinge (PHYSICS §4 "Shells"). Pure
 * functions on flat arrays; no allocation; thread-safe.
 *
 * Membrane (StVK in plane stress). A triangle's rest shape is kept as the inverse Bm of its 2×2 rest edge matrix in a
 * rest frame of its own (e1 along the first edge, e2 in the plane), and its rest area A. The deformation gradient
 * F = [x1 − x0, x2 − x0] Bm (3×2) gives the Green strain E = ½(FᵀF − I). The plane-stress energy
 *     W = ½ A εᵀ D ε,   ε = (E11, E22, 2E12),   D = k [1 ν 0; ν 1 0; 0 0 (1−ν)/2],   k = E h/(1 − ν²)
 * is split along D's eigenvectors into three rows with a diagonal compliance each (what the Lagrangian solver takes):
 *     φ0 = (E11 + E22)/√2,  C⁻¹ = A k (1 + ν)           (area change)
 *     φ1 = (E11 − E22)/√2,  C⁻¹ = A k (1 − ν)           (shear, two rows that together are rotation invariant)
 *     φ2 = √2 E12,           C⁻¹ = A k (1 − ν)
 * so that W = ½ Σ C⁻¹ φ² exactly. E is quadratic in x, so each row's Hessian is a constant (from Bm alone) times
 * the 3×3 identity: the geometric stiffness Σ λ ∇²φ is exact and cheap.
 *
 * Bending (hinge). An interior edge x1x2 shared by triangle (x0, x1, x2) and triangle (x3, x2, x1) (both wound the
 * same way round the mesh) bends by the signed dihedral angle θ between their normals, positive when the hinge
 * folds towards the normals' side. One row φ = θ − θ̄ with C⁻¹ = 2 k_b |ē|²/(Ā0 + Ā1), k_b = E h³/(24(1 − ν²))
 * (rest edge length ē, rest areas Ā), so the hinge's energy is k_b (θ − θ̄)² |ē|²/(Ā0 + Ā1). For a flat sheet bent
 * to curvature κ across the edge, θ = κ (Ā0 + Ā1)/|ē| (the jump of the linear interpolant's slope), so a sheet of
 * quad-split cells bent about a cell axis stores k_b κ² per unit area: ½ D κ², Kirchhoff's energy with
 * D = E h³/(12(1 − ν²)). The hinge energy depends on the mesh (Wardetzky et al. 2007): Grinspun et al.'s weight
 * 3|ē|²/(Ā0 + Ā1) stores three times that on such a sheet. The geometric stiffness of a hinge is not formed (the
 * dihedral angle's Hessian): the solver linearises bending by JᵀC⁻¹J alone, which keeps its matrix positive definite.
 *
 * One row per hinge cannot hold a plate's bending energy on every mesh. On quad-split cells with all diagonals one
 * way, a hinge's two wings sit at opposite ends of its edge, so twisting bends the cell edges as bending does:
 * the per-hinge energy is (κxx + κxz)² + (κzz + κxz)² + 4κxz² (in k_b per unit area) against Kirchhoff's
 * κxx² + κzz² + 2κxz² at ν = 0, and a cantilever relaxes into twist and sags 20 % more than Kirchhoff's at any
 * resolution (tests/validation/test_cloth measures it); on equilateral meshes it is a plate with ν = −1/3.
 *
 * Bending (shape operator), the default. Each triangle T combines the dihedral angles of its interior edges into
 * the discrete shape operator (Grinspun et al. 2006, "Computing discrete shape operators on general meshes")
 *     S = Σ_i (θ_i − θ̄_i) c_i n_i n_iᵀ,   c_i = |ē_i|/(2 Ā),   n_i the in-plane unit normal of edge i,
 * exact for every uniform curvature tensor on lattice meshes (equilateral, quad-split with parallel diagonals); on
 * quad-split cells with alternating diagonals it is exact for bending and saddles and stores the twisting
 * energy times 2/(1 − ν) (test_cloth measures both). It stores
 * Kirchhoff's energy with the material's own Poisson ratio:
 *     W_T = k_b Ā [ν (tr S)² + (1 − ν) |S|²] = ½ (θ − θ̄)ᵀ Q (θ − θ̄),  Q_ij = 2 k_b Ā c_i c_j [ν + (1 − ν)(n_i·n_j)²]
 * (½ D [(tr K)² − 2(1 − ν) det K] per unit area, D = 2 k_b). Q, over the triangle's interior edges only (a
 * boundary edge bends freely), is factored once at rest, Q = U Λ Uᵀ: the triangle's rows are φ_r = u_rᵀ(θ − θ̄)
 * with C⁻¹ = Λ_r, over the triangle's vertices and the wings across its edges (up to 6 vertices, 18 DOFs).
 */
#ifndef DR_CLOTH_SHELL_H
#define DR_CLOTH_SHELL_H

#include "lagrangian/lagrangian.h"

/* Rest data of a triangle from its rest positions X0, X1, X2 (9 values): Bm (2×2 row-major) and area. False when the
   triangle is degenerate (area below 1e-14 of its longest edge squared). */
bool dr_shell_rest(const double *X0, const double *X1, const double *X2, double Bm[4], double *area);

/* Green strain (E11, E22, E12) of a triangle at positions x0, x1, x2. */
void dr_shell_green(const double *x0, const double *x1, const double *x2, const double Bm[4], double E[3]);

/* Membrane energy (J) of a triangle: ½ A εᵀ D ε. */
double dr_shell_membrane_energy(const double *x0, const double *x1, const double *x2, const double Bm[4], double area,
                                double k, double nu);

/* The three membrane rows of a triangle over its vertices' DOFs dof[0..2] (each vertex's x, y, z at dof[v] + 0, 1, 2):
   φ, J, C⁻¹ as the header says. When lambda and G are non-NULL, G (81 values) = Σ λ_r ∇²φ_r is written and linked
   from g->G; with `project`, only its negative semidefinite part (the 3×3 vertex matrix S of G = S ⊗ I₃ with its
   positive eigenvalues set to zero): the solver's matrix has −h²G, so the part kept only stiffens it, and a
   compressed triangle (λ > 0 on its area row) cannot make the panel's block indefinite, which would drop the whole
   panel's geometric stiffness for the step (a sheet of 33 × 33 vertices hanging from two corners gains energy at
   1/96 s steps then; with the projection it loses it, tests/validation/test_cloth). */
void dr_shell_membrane_group(const double *x0, const double *x1, const double *x2, const double Bm[4], double area,
                             double k, double nu, const int dof[3], const double *lambda, bool project, double *G,
                             DrLagGroup *g);

/* Signed dihedral angle θ of the hinge x1x2 with wings x0 (triangle x0 x1 x2) and x3 (triangle x3 x2 x1); when grad
   is non-NULL, ∂θ/∂(x0, x1, x2, x3) (12 values). 0 for a degenerate wing. */
double dr_shell_hinge_angle(const double *x0, const double *x1, const double *x2, const double *x3, double *grad);

/* The hinge row over the DOFs of x0, x1, x2, x3 (dof[0..3]): φ = θ − θ̄ (with θ continued past ±π from θ̄), C⁻¹ =
   2 k_b |ē|²/(Ā0 + Ā1) passed in as `cinv`. */
void dr_shell_hinge_group(const double *x0, const double *x1, const double *x2, const double *x3, double theta_bar,
                          double cinv, const int dof[4], DrLagGroup *g);

/* Rest data of a triangle's shape-operator bending: its rest vertices X0, X1, X2, area, which of its edges are
   interior (edge i joins vertices i + 1 and i + 2, mod 3), k_b and ν. Writes the rows' weights u (row-major 3 × 3:
   row r's weight on edge i at u[3 r + i], zero on boundary edges) and C⁻¹ (3), and returns the number of rows
   (those with C⁻¹ above 1e-12 of the largest; 0 when no edge is interior or k_b is 0). */
int dr_shell_bend_rest(const double *X0, const double *X1, const double *X2, double area, const bool interior[3],
                       double kb, double nu, double u[9], double cinv[3]);

#endif
