/* drench cloth: thin shells on triangle meshes as Lagrangian vertex objects (PHYSICS §4 "Shells"; seed weta_avatar
 * §1–§3: hair and cloth alike on one constrained-dynamics solver).
 *
 * Model. A panel is a triangle mesh whose vertices carry position DOFs (3 each) of one object of the Lagrangian
 * system (src/lagrangian). Its forces are constraint groups (shell.h): three StVK membrane rows per triangle, the
 * bending rows (up to three per triangle on the dihedral angles of its edges, or one per hinge), and a viscous twin of
 * each (damping, C_v⁻¹ = damping · C⁻¹). Mass is lumped: each triangle gives ρ h A/3 to each of its vertices.
 *
 * Vertex order. The object's block is banded: its vertices are numbered in reverse Cuthill–McKee order (George and
 * Liu 1981) over the mesh's edge graph, or by a sweep of the rest positions along a coordinate axis when that is
 * narrower, so every group's vertices lie within `band` of each other and the block's half-bandwidth is 3·band + 2
 * DOFs. A bending group reaches across two rows of a regular mesh: a panel of w × w vertices has band ≈ 2w. The
 * banded Cholesky factor costs O(n (3 band)²), with no fill outside the band and no symbolic phase.
 * tests/bench/bench_cloth measures it against a sparse factorisation (CHOLMOD with its AMD order) of the same matrix:
 * one panel's step, factor and solve, is 1.6–8× faster banded from 16 × 16 to 96 × 96 vertices (the README's
 * table), so a panel is one banded object.
 *
 * Attachments. A pinned vertex follows a prescribed velocity (zero by default): its DOFs are eliminated from the
 * solve, so it moves exactly by h v at every step.
 *
 * Colliders. A collider is a signed distance with an outward normal and a surface velocity (the same callbacks the
 * hair takes); a vertex that is inside, or would enter within the step at its current velocity, gets the one-row
 * constraint φ = d − thickness ≥ 0 along the normal with stiffness collider_stiffness, and Coulomb friction at
 * commit (the tangential velocity relative to the collider loses up to μ times the normal velocity the contact
 * gave).
 *
 * Self contact (the material's self_contact, on by default). A vertex and a triangle of the same panel that does not
 * contain it keep the material's self_thickness apart: the one-row constraint φ = n·(x_v − Σ b_i x_i) −
 * thickness ≥ 0 over the four vertices, n the triangle's unit normal at the step's start turned towards the vertex's
 * side, b the barycentric coordinates of the vertex's projection on the triangle (both held for the step), stiffness
 * self_stiffness (with a viscous twin when self_damping > 0), and Coulomb friction at commit with self_friction on the
 * vertex's velocity relative to
 * the triangle's point Σ b_i v_i, applied to both sides (the panel's momentum is conserved). Pairs are found by the
 * broad phase of src/contact at the step's start (a vertex within the thickness of a triangle, or coming within it at
 * the current velocities) and in the active-set passes (a vertex that the solve takes through a triangle, or within
 * the thickness of it). A vertex meets a triangle only where its projection falls on the triangle (or within the
 * thickness of its edges); edge–edge crossings are not detected (src/cloth/self_contact.h says when that suffices),
 * and pairs within the thickness of each other in the rest shape never touch. The group goes into the panel's banded
 * block when its four vertices lie within the band, else into the system's coupling matrix (a fold brings
 * far-numbered vertices together there, and the solve then takes CG iterations).
 *
 * Each panel steps a Lagrangian system of its own (dr_cloth_step = predict + commit, or the phases below); joining
 * the world's one system with the hair (DESIGN §8) is still to come. Results are bit-identical for any thread count. */
#ifndef DR_CLOTH_H
#define DR_CLOTH_H

#include "core/core.h"
#include "lagrangian/lagrangian.h"

/* How bending is discretised (shell.h): the discrete shape operator of each triangle from its edges' dihedral angles
   (the default: Kirchhoff's energy with the material's Poisson ratio on any regular mesh), or one row per hinge
   (Grinspun et al.'s discrete shells: cheaper, but its energy depends on how the mesh is cut). */
typedef enum DrClothBending { DR_CLOTH_BEND_SHAPE_OPERATOR, DR_CLOTH_BEND_HINGE } DrClothBending;

typedef struct DrClothMaterial {
    double density;        /* kg/m³ of the fabric (areal density ρ h), > 0; default 400 */
    double thickness;      /* m, > 0; default 5e-4 */
    double youngs_modulus; /* Pa, > 0; default 1e6 */
    double poisson;        /* in [0, 0.5); default 0.3 */
    double bend_scale;     /* multiplies the plate's bending stiffness E h³/(24(1 − ν²)), ≥ 0; default 1 */
    double damping;        /* s, ≥ 0: each group's viscous twin has C_v⁻¹ = damping · C⁻¹; default 0 */
    double friction;       /* Coulomb coefficient against colliders (the larger of this and the collider's); default 0 */
    double collision_thickness; /* m, ≥ 0: distance kept from colliders (with the collider's own); default 1e-3 */
    bool self_contact;          /* vertex–triangle contact of the panel with itself (see above); default true */
    double self_stiffness;      /* N/m of a self contact, > 0; default 1e4 (the default collider_stiffness) */
    double self_friction;       /* Coulomb coefficient between the panel's own layers, ≥ 0; default 0 */
    double self_thickness;      /* m, ≥ 0: distance kept between the panel's own layers; default 1e-3 */
    double self_damping;        /* s, ≥ 0: a self contact's viscous twin along its normal has C_v⁻¹ = self_damping ·
                                   self_stiffness; default 0 (none) */
    DrClothBending bending;     /* default DR_CLOTH_BEND_SHAPE_OPERATOR */
} DrClothMaterial;
void dr_cloth_material_default(DrClothMaterial *m);

typedef double (*DrClothSdfFn)(DrVec3 x, DrVec3 *normal, void *ctx);
typedef DrVec3 (*DrClothVelocityFn)(DrVec3 x, void *ctx);
typedef struct DrClothCollider {
    DrClothSdfFn sdf;               /* signed distance (negative inside), outward unit normal */
    DrClothVelocityFn velocity_at;  /* NULL: at rest */
    void *ctx;
    double friction, thickness;
} DrClothCollider;

typedef struct DrClothDesc {
    DrVec3 gravity;              /* m/s², default (0, −9.81, 0) */
    DrLagDesc solver;            /* the panel's own system's */
    bool geometric_stiffness;    /* the membrane's λ-weighted Hessians (eq. S27); default true */
    double collider_stiffness;   /* N/m of a vertex–collider contact; default 1e4 */
    DrLag *system;               /* NULL (default): the panel makes a system of its own and steps it itself. Else the
                                    shared system (DESIGN §8) the panel adds its object to, after those already there;
                                    the caller owns it and drives the step (see "in a shared system" below) */
} DrClothDesc;
void dr_cloth_desc_default(DrClothDesc *d);

typedef struct DrCloth DrCloth;

/* A panel at rest in the mesh's shape (its rest shape). Every edge must border one or two triangles, the two
   triangles of an edge wound consistently (they traverse it in opposite directions), and no triangle degenerate:
   DR_ERR_INPUT naming the triangle or the edge (by its vertices, 0-based) otherwise. `name` prefixes messages. */
DR_NODISCARD DrStatus dr_cloth_create(const DrClothDesc *desc, const DrTriMesh *mesh, const DrClothMaterial *material,
                                      const char *name, DrCloth **out, DrError *err);
void dr_cloth_destroy(DrCloth **c);

int dr_cloth_vertex_count(const DrCloth *c);
int dr_cloth_triangle_count(const DrCloth *c);
int dr_cloth_hinge_count(const DrCloth *c); /* interior edges */
/* The half-bandwidth of the panel's block in vertices, and each vertex's place in the block's order (V values). */
int dr_cloth_band(const DrCloth *c);
const int *dr_cloth_vertex_order(const DrCloth *c);
const int *dr_cloth_triangles(const DrCloth *c);   /* 3 per triangle, the mesh's */
const double *dr_cloth_positions(const DrCloth *c); /* 3 per vertex, mesh order, m */
double *dr_cloth_positions_mut(DrCloth *c);         /* to place the panel before its first step */
const double *dr_cloth_velocities(const DrCloth *c);
double *dr_cloth_velocities_mut(DrCloth *c);
const double *dr_cloth_masses(const DrCloth *c);    /* kg per vertex */

/* Pins vertex v (mesh index) to move with velocity vel (m/s, NULL: at rest) from the next step on; pinned false
   frees it. DR_ERR_INPUT for a vertex out of range. */
DR_NODISCARD DrStatus dr_cloth_pin(DrCloth *c, int v, bool pinned, const double *vel, DrError *err);

/* Slide attachments: vertices held on a curve (a polyline of npoints ≥ 2 distinct points, m; copied), free to move
   along it (a curtain on its rail). Each sliding vertex gets two stiff rows (1e8 N/m), its distance from the nearest
   point of the curve across the curve's tangent there: it stays within its load over 1e8 N/m of the curve (plus the
   step's chord on a curved rail). A pinned vertex's pin wins. DR_ERR_INPUT for a curve with fewer than 2 points,
   coinciding neighbours or a non-finite point, a vertex out of range, or a vertex made to slide without a curve. */
DR_NODISCARD DrStatus dr_cloth_set_slide_curve(DrCloth *c, const double *points, int npoints, DrError *err);
DR_NODISCARD DrStatus dr_cloth_slide(DrCloth *c, int v, bool on, DrError *err);

typedef struct DrClothStats {
    int iterations;          /* CG iterations of the step (every solve) */
    bool converged;
    int collider_contacts;   /* vertex–collider contacts of the last step */
    int self_contacts;       /* vertex–triangle self contacts of the last step (its final active set) */
    double seconds;
} DrClothStats;

/* One step of h > 0 s alone . DR_WARN_NOT_CONVERGED when CG stopped at its cap; DR_ERR_RUNTIME
   when the state turned non-finite (the state is then left as it was before the step). */
DR_NODISCARD DrStatus dr_cloth_step(DrCloth *c, double h, const DrClothCollider *colliders, int ncolliders,
                                    DrClothStats *stats, DrError *err);

/* ---- the step in phases (DESIGN §8), for the coupled loop -------------------------------------------------------------
 * predict: the step's groups and contacts (an active set settled by solves without load), the predicted velocities;
 * solve: with a load on the vertices (force 3V, N; dforce_dv 9V row-major ∂f/∂v, symmetric negative semidefinite;
 * either NULL), callable any number of times, each from the prediction; commit: the last solve's velocities (the
 * prediction's without a solve), friction at the contacts, positions. dr_cloth_step is predict + commit. */
DR_NODISCARD DrStatus dr_cloth_predict(DrCloth *c, double h, const DrClothCollider *colliders, int ncolliders,
                                       DrError *err);
DR_NODISCARD DrStatus dr_cloth_solve(DrCloth *c, const double *force, const double *dforce_dv, DrError *err);
const double *dr_cloth_solved_velocities(const DrCloth *c); /* 3V, mesh order: the last solve's (or prediction's) */
DR_NODISCARD DrStatus dr_cloth_commit(DrCloth *c, DrClothStats *stats, DrError *err);

/* ---- in a shared system (desc.system set) -------------------------------------------------------------------------
 * The system's owner steps every model in it together, as for the rod set (hair.h):
 *     dr_cloth_predict_dofs (every panel)         its DOF ranges of dr_lag_dofs's arrays, and its contacts found
 *     repeat up to 8 times:
 *         dr_lag_begin(system, h, dofs.mass, dofs.qdot, dofs.fext, dofs.prescribed, dofs.qdot_prescribed)
 *         dr_cloth_predict_groups (every panel), the other models' groups and those between models
 *         dr_lag_solve_load(system, …, dofs.qdot_out)
 *         dr_cloth_update_contacts (every panel): the active set from that solve; stop when no panel's changed
 *     dr_cloth_take (every panel); dr_lag_update_multipliers(system, dofs.qdot_out); dr_cloth_commit (every panel)
 * A panel alone in a shared system, stepped so, takes the bits of dr_cloth_step on a system of its own.
 * dr_cloth_predict, dr_cloth_solve and dr_cloth_step are for a panel with a system of its own only. */
DR_NODISCARD DrStatus dr_cloth_predict_dofs(DrCloth *c, double h, const DrClothCollider *colliders, int ncolliders,
                                            DrError *err);
DR_NODISCARD DrStatus dr_cloth_predict_groups(DrCloth *c, DrError *err);
DR_NODISCARD DrStatus dr_cloth_update_contacts(DrCloth *c, const DrClothCollider *colliders, int ncolliders, int pass,
                                               bool *changed, DrError *err);
void dr_cloth_take(DrCloth *c);
/* The first DOF of each vertex in the system (3 each, mesh order; fixed from create on). */
int dr_cloth_vertex_dof(const DrCloth *c, int v);

/* The panel's vertices as the coupled loop sees them between predict and commit (borrowed): positions at the step's
   start, the last solve's velocities, masses, pinned flags. */
typedef struct DrClothSamples {
    int n;
    const double *x, *v, *mass;
    const unsigned char *pinned;
} DrClothSamples;
void dr_cloth_samples(const DrCloth *c, DrClothSamples *out);

/* The membrane rows' multipliers (3 per triangle), which the next step's geometric stiffness uses: a checkpoint keeps
   them for a bit-identical resume. */
double *dr_cloth_multipliers(DrCloth *c, int *count);

typedef struct DrClothEnergy {
    double kinetic, membrane, bending, gravity; /* J; gravity: −Σ m g·x */
} DrClothEnergy;
void dr_cloth_energy(const DrCloth *c, DrClothEnergy *e);

/* Vertex normals (3 per vertex, unit): area-weighted triangle normals. */
void dr_cloth_normals(const DrCloth *c, double *n);

#endif
