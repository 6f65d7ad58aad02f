/* Private to src/cloth: vertex–triangle contact of a panel with itself (cloth.h, "Self contact").
 *
 * A contact joins a vertex v and a triangle t = (x0, x1, x2) of the same panel that does not contain v, as one
 * positional row over the 12 DOFs of the four vertices:
 *     φ = n·(x_v − Σ b_i x_i) − thickness,   C⁻¹ = stiffness,
 * n the triangle's unit normal at the step's start turned towards the side v was on, b the barycentric coordinates of
 * the closest point (v's projection on the triangle's plane), both held for the step, so φ is linear in the positions
 * and the solver's φ₊ = φ + h J q̇₊ is exact (no geometric stiffness). J's weights (1, −b0, −b1, −b2) sum to zero: the
 * contact's forces on the four vertices sum to zero and conserve the panel's momentum.
 *
 * Which pairs. Candidates come from the broad phase (src/contact) on boxes inflated by how far their vertices may
 * travel in the step: r_v = 1.5 h|v_v| + thickness, a vertex's box by thickness + r_v, a triangle's by the largest r_i
 * of its vertices. A candidate is a contact when v's projection on the triangle's plane lies in the triangle or within
 * the thickness outside its edges (then clamped to it and renormalised: a vertex over another layer's free edge, or
 * exactly over one of its vertices, is held there) and v is within the thickness of the plane or would come within it
 * during the step at the current relative velocity (detect, at the step's start), or, after a solve, when v ends the
 * step (x + h q̇₊) over the triangle and within the thickness of it, or beyond, on the side where it started (update,
 * the active-set passes, which reuse the start's candidates while every vertex's travel stays within r_v). Of the
 * triangles round one spot a vertex keeps one: the one its projection lies deepest in, and no other that shares a
 * vertex with it (a vertex over a vertex of the other layer, as on a sheet folded onto itself, is over six triangles).
 * Pairs within the thickness of each other in the rest shape never touch: on a mesh finer than the contact distance a
 * vertex would otherwise push its own neighbours' triangles apart. A vertex past the other layer's free edge by more
 * than the thickness makes no contact, and an edge that crosses an edge while no vertex comes near a triangle is not
 * seen: at the resolutions tested (cells of 2 cm, a contact distance of 1 mm, steps of 1/240 s) the layers meet vertex
 * first (tests/validation/test_cloth: a folded sheet dropped on the floor keeps its layers 0.97 mm apart at the least).
 *
 * Active set. As for the collider contacts (cloth.c update_contacts): a contact that pulls after the first solve is let
 * go, later passes only add. update also reports which vertices are in self contact (`touch`), so that the collider
 * contacts can give way where a vertex is held by both.
 *
 * Order and threads: contacts are kept in the broad phase's pair order (detect), new ones appended in that order
 * (update), removals keep the order: everything runs on the calling thread in a fixed order, so a step is
 * bit-identical for any thread count. Memory: the broad phase's and the contacts' buffers are kept between steps and
 * grown geometrically; once the largest step was seen a step allocates nothing. */
#ifndef DR_CLOTH_SELF_CONTACT_H
#define DR_CLOTH_SELF_CONTACT_H

#include "lagrangian/lagrangian.h"

/* The panel as self contact sees it: borrowed arrays that stay put for the lifetime of the DrClothSelf. */
typedef struct DrClothSelfPanel {
    int V, T;
    const int *tri;              /* 3T, mesh order */
    const double *rest;          /* 3V rest positions, m */
    const double *mass;          /* V, kg */
    const unsigned char *pinned; /* V */
    const int *rank;             /* V: place in the object's block */
    int band, dof0;              /* the block's half-bandwidth in vertices; the object's first DOF */
    double thickness;            /* contact distance, m (the material's self_thickness) */
    double stiffness;            /* C⁻¹, N/m */
    double friction;             /* Coulomb coefficient */
    double damping;              /* s: a viscous twin along the normal with C_v⁻¹ = damping · stiffness; 0 = none */
} DrClothSelfPanel;

typedef struct DrClothSelf DrClothSelf;

DR_NODISCARD DrStatus dr_cloth_self_create(const DrClothSelfPanel *panel, DrClothSelf **out, DrError *err);
void dr_cloth_self_destroy(DrClothSelf **s);

/* The step's contacts at its start: positions x and velocities v (3V each, mesh order), step h > 0 s. Replaces the
   previous set. DR_ERR_INPUT from the broad phase when a box is not finite. */
DR_NODISCARD DrStatus dr_cloth_self_detect(DrClothSelf *s, double h, const double *x, const double *v, DrError *err);

/* After a solve with DOF velocities qdot (the system's array), x the positions at the step's start: with `release`,
   drops the contacts whose force pulls (λ = −C⁻¹(φ + h J q̇₊) < 0); then adds the pairs that end the step through (or
   within the thickness of) a triangle. DR_ERR_INPUT from the broad phase when a box is not finite.
   *changed tells whether the set changed; touch (V) is 2 on the four vertices of every contact added here, 1 on those
   of the others, 0 elsewhere. */
DR_NODISCARD DrStatus dr_cloth_self_update(DrClothSelf *s, double h, const double *x, const double *qdot, bool release,
                                           bool *changed, unsigned char *touch, DrError *err);

/* Adds each contact's group (after dr_lag_begin), and its viscous twin when the panel has damping: to the panel's block
   (dr_lag_add) when its four vertices lie within the band, else to K_G (dr_lag_add_global). Its multiplier is kept
   here for the friction at commit. */
DR_NODISCARD DrStatus dr_cloth_self_add(DrClothSelf *s, DrLag *lag, DrError *err);

/* Coulomb friction at commit on the velocities v (3V, mesh order, in place), contact by contact in order: the
   tangential velocity of v relative to the triangle's point Σ b_i v_i loses up to what an impulse of μ λ h can take,
   applied to the vertex and, against it, to the triangle's vertices by their weights b_i (momentum is conserved;
   pinned vertices do not move). */
void dr_cloth_self_friction(const DrClothSelf *s, double h, double *v);

int dr_cloth_self_count(const DrClothSelf *s);

#endif
