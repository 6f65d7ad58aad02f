/* Contact between solids: one shape vocabulary and one deterministic broad phase that every solid uses.
 *
 * Shapes. A DrShape names what a solid offers to contact: a posed signed distance field (a collider), a triangle
 * set (a deformed surface), a segment set (hair strands) or a point set (particles), each with a thickness (the
 * distance at which contact begins, m) and group/mask bits: two shapes meet when each one's group bits meet the
 * other's mask. Geometry is borrowed (plain SI arrays the owning solver keeps), so a shape costs nothing to pose
 * again: the owner updates its arrays and the broad phase reads them.
 *
 * Broad phase. Axis-aligned boxes (one per element of a shape, already inflated by whatever reach the caller's
 * narrow phase needs) are binned on a uniform grid of cubic cells; a pair of boxes is a candidate when the boxes
 * overlap (closed intervals), reported once, in the cell holding the low corner of the boxes' overlap. Pairs come
 * out in a fixed order that depends on the boxes alone: cells in increasing (x, y, z) cell index, and within a
 * cell the pairs (i, j), i < j, in increasing box order, i before j. Nothing depends on the thread count, on the
 * address of anything or on a hash function. A cell at least as large as the largest box keeps each box in at
 * most 2 cells per axis.
 *
 * Memory: a DrBroadPhase keeps its buffers between queries, growing them geometrically, and its first query
 * leaves room for twice its pairs: once it has seen its largest query, a query allocates nothing (dr_alloc_count
 * does not move). A caller that knows a bound on its boxes' cell entries (a box no larger than a cell meets at
 * most 8) reserves it (dr_broad_phase_reserve).
 * Thread safety: one DrBroadPhase per thread; queries on different objects may run concurrently. */
#ifndef DR_CONTACT_H
#define DR_CONTACT_H

#include "core/core.h"
#include "grid/grid.h"

typedef enum DrShapeKind {
    DR_SHAPE_SDF,       /* a posed collider: collider + frame */
    DR_SHAPE_TRIANGLES, /* x (3 per vertex) and elements (3 vertex indices per triangle) */
    DR_SHAPE_SEGMENTS,  /* x and elements (2 vertex indices per segment) */
    DR_SHAPE_POINTS,    /* x only */
} DrShapeKind;

typedef struct DrShape {
    DrShapeKind kind;
    int owner;                 /* the solver's own index of the object (body, strand batch, collider) */
    uint32_t group, mask;      /* meets another shape when (group & other.mask) && (other.group & mask) */
    double thickness;          /* m, ≥ 0 */
    const double *x;           /* 3·nverts, m (not for DR_SHAPE_SDF) */
    int nverts;
    const int *elements;       /* 3 or 2 per element (triangles, segments); NULL for points */
    int nelements;             /* elements, or points for DR_SHAPE_POINTS */
    const DrCollider *collider; /* DR_SHAPE_SDF: the field, posed by frame */
    DrColliderFrame frame;
} DrShape;

/* Whether shapes a and b may touch by their group and mask bits. */
bool dr_shape_pair_allowed(const DrShape *a, const DrShape *b);
/* The box of element k of a triangle, segment or point shape, inflated by `pad` on every side. */
void dr_shape_element_box(const DrShape *s, int k, double pad, DrVec3 *lo, DrVec3 *hi);

typedef struct DrBroadPair { int a, b; } DrBroadPair; /* box indices, a < b */

typedef struct DrBroadPhase DrBroadPhase;
DR_NODISCARD DrStatus dr_broad_phase_create(DrBroadPhase **out, DrError *err);
void dr_broad_phase_destroy(DrBroadPhase **bp);
/* Forgets the boxes (keeps the memory). */
void dr_broad_phase_clear(DrBroadPhase *bp);
/* Adds a box (lo ≤ hi componentwise, finite); its index is the number of boxes added before it. */
DR_NODISCARD DrStatus dr_broad_phase_add(DrBroadPhase *bp, DrVec3 lo, DrVec3 hi, DrError *err);
int dr_broad_phase_count(const DrBroadPhase *bp);
/* Room for `boxes` boxes and `cell_entries` box–cell entries, so that queries within them never allocate. */
DR_NODISCARD DrStatus dr_broad_phase_reserve(DrBroadPhase *bp, int boxes, size_t cell_entries, DrError *err);
/* The candidate pairs of the boxes added since the last clear, on cells of edge `cell` (m, > 0), in the order the
 * header describes; *pairs stays valid until the next query, clear or destroy. DR_ERR_INPUT when a box is not
 * finite or lies more than 2^30 cells from the origin (a cell far too small for the scene: say which). */
DR_NODISCARD DrStatus dr_broad_phase_pairs(DrBroadPhase *bp, double cell, const DrBroadPair **pairs, long *npairs,
                                           DrError *err);
/* The pairs between two sets of boxes: those added first, indices [0, split), and the rest, [split, count) (0 ≤ split
 * ≤ count). Exactly the pairs of dr_broad_phase_pairs with a < split ≤ b, in its order, but the pairs within one set
 * are never tested, so a query between a small set and a large one does not pay for the large set's own pairs. Same
 * validity and failures as dr_broad_phase_pairs. */
DR_NODISCARD DrStatus dr_broad_phase_pairs_across(DrBroadPhase *bp, double cell, int split, const DrBroadPair **pairs,
                                                  long *npairs, DrError *err);

/* ---- a point set as a surface -----------------------------------------------------------------------------------
 * The surface of a body sampled by particles (an MPM solid), for a solid that meets it through a signed distance
 * (hair): φ(x) = |x − x̄(x)| − r̄(x), x̄ and r̄ the kernel-weighted mean position and radius of the particles within R
 * of x (k = (1 − d²/R²)³; Zhu and Bridson 2005), the normal (x − x̄)/|x − x̄|, the velocity the kernel-weighted mean
 * of the particles'. A particle's radius r is half the edge of the cube of its volume (the rest volume for an MPM solid), so particles on a lattice of
 * spacing s = 2r touch. R = 4r: over a lattice's flat face the field is within 0.1 r of the height above the face
 * (r over the top particles' centres) and its normal within 2° of the face's, over particles and between them
 * alike (a union of spheres dips by r between neighbours; R = 3r tilts the normal by up to 18° between particles,
 * R = 6r draws the face in by 0.55 r: tests/unit/test_contact.c). The field reaches at least ~2r beyond a face and
 * is +∞ where no particle is within R: a contact distance beyond that is not seen. Particles are binned on cells of edge R, sorted (no hash), so a query
 * reads 27 cells and the result does not depend on the thread count. Rebuilding keeps the buffers: after the
 * largest set seen, a build allocates nothing. */
typedef struct DrPointField DrPointField;
DR_NODISCARD DrStatus dr_point_field_create(DrPointField **out, DrError *err);
void dr_point_field_destroy(DrPointField **pf);
/* From n particles: positions x and velocities v (3n each, m, m/s) and volumes (n, m³, > 0); borrowed until the next
   build. DR_ERR_INPUT on a non-finite position or a non-positive volume. */
DR_NODISCARD DrStatus dr_point_field_build(DrPointField *pf, long n, const double *x, const double *v,
                                           const double *volume, DrError *err);
long dr_point_field_count(const DrPointField *pf);
double dr_point_field_phi(const DrPointField *pf, DrVec3 x, DrVec3 *normal);
DrVec3 dr_point_field_velocity(const DrPointField *pf, DrVec3 x);

/* ---- a triangle mesh as a surface ----------------------------------------------------------------------------------
 * A moving sheet (a cloth panel) for a solid that meets it through a distance (hair): φ(x) = the distance from x to the
 * nearest triangle within `reach` (unsigned: a sheet has two sides), the normal from that nearest point towards x, the
 * velocity there the barycentric mean of its triangle's vertex velocities; +∞ (normal +y, velocity 0) where no
 * triangle is within reach. Triangles are binned on cells of edge `reach`, each into every cell its box inflated by
 * `reach` overlaps, sorted (no hash), so a query reads one cell, the nearest of equally near triangles is the one of
 * lowest index, and the result does not depend on the thread count. Queries are read-only (safe from several threads);
 * rebuilding keeps the buffers. */
typedef struct DrTriField DrTriField;
DR_NODISCARD DrStatus dr_tri_field_create(DrTriField **out, DrError *err);
void dr_tri_field_destroy(DrTriField **tf);
/* From nt triangles (3 nt vertex indices) over vertex positions x and velocities v (3 per vertex; v may be NULL),
   borrowed until the next build, and reach > 0 (m). DR_ERR_INPUT on a non-finite position or reach. */
DR_NODISCARD DrStatus dr_tri_field_build(DrTriField *tf, int nt, const int *tri, const double *x, const double *v,
                                         double reach, DrError *err);
double dr_tri_field_phi(const DrTriField *tf, DrVec3 x, DrVec3 *normal);
DrVec3 dr_tri_field_velocity(const DrTriField *tf, DrVec3 x);
/* The nearest triangle within reach and the barycentric coordinates of the nearest point on it; −1 when none. */
int dr_tri_field_nearest(const DrTriField *tf, DrVec3 x, double bary[3]);

/* ---- points against a sheet, in one Lagrangian system ------------------------------------------------------------
 * Hair vertices against a cloth panel whose DOFs are in the same system (DESIGN §8: contact adds pairs between any of
 * its models). A point within reach of the sheet's field (built from the sheet's positions at the step's start) meets
 * the nearest triangle as one positional row over the point's 3 DOFs and the triangle's 9:
 *     φ = n·(x_p − Σ b_i x_i) − (r_p + thickness),   C⁻¹ = stiffness,
 * n the unit normal from the nearest point towards the point and b its barycentric weights, both held for the step, so
 * φ is linear in the positions (no geometric stiffness) and the row's forces on the four sum to zero: the two models
 * exchange momentum exactly. A point is a contact when φ < 0 or when it would be by the step's end at the current
 * relative velocity (φ + h n·(v_p − Σ b_i v_i) < 0); points on prescribed DOFs (held roots) are skipped, and a sheet's
 * vertex that is prescribed (pinned) takes no force. With damping, a viscous row along n (coefficient damping ·
 * stiffness) beside it; with friction, a viscous group on the two tangential components of the relative velocity
 * whose coefficient μ F_n / max(|v_t|, μ|φ|/h), F_n = stiffness·|φ| the contact's force at the step's start, resists
 * sliding with μ F_n (Coulomb, lagged by the step) and grips below μ|φ|/h (as the hair's strand–strand contacts,
 * hair.c). The groups go to the system's coupling matrix (dr_lag_add_global), in point order. */
typedef struct DrContactResponse {
    double thickness, stiffness, friction, damping; /* m, N/m, 1, s */
} DrContactResponse;
typedef struct DrContactPoints {
    int n;
    const double *x, *v;    /* 3n, m and m/s */
    const double *radius;   /* n, m */
    const int *dof;         /* n: each point's first of 3 DOFs in the system */
    const unsigned char *held; /* n or NULL: points that do not move freely (skipped) */
} DrContactPoints;
typedef struct DrContactSheet {
    const DrTriField *field; /* built on the sheet's positions x with its triangles tri */
    const int *tri;
    const double *x, *v;     /* 3 per vertex */
    const int *dof;          /* per vertex: its first of 3 DOFs in the system */
} DrContactSheet;
struct DrLag;
DR_NODISCARD DrStatus dr_contact_points_sheet(struct DrLag *lag, double h, const DrContactPoints *p,
                                              const DrContactSheet *s, const DrContactResponse *r, int *count,
                                              DrError *err);

#endif
