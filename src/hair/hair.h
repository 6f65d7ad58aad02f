/* drench hair: elastic rods (discrete elastic rods: stretching, bending with rest curvature, twisting on
 * parallel-transported reference frames) as constraint groups of the src/lagrangian solver, grooms grown
 * from a scalp mesh or read from OBJ polylines, roots attached to a moving scalp, collisions with collider
 * SDFs and between hairs (fei2017 §S4, PHYSICS §4).
 *
 * Layout. A rod set holds S strands; strand s has vertices offsets[s] .. offsets[s+1]−1 (≥ 2 each) and one
 * edge fewer. Arrays are flat: positions V×3 (m), velocities V×3 (m/s), twists θ per edge (rad, the
 * material frame's angle from the reference frame), twist rates per edge (rad/s). Edge e of strand s is
 * numbered offsets[s] − s + local edge index (E = V − S edges in all).
 *
 * Units SI. Thread safety: one rod set per thread of control; it runs its loops through dr_parallel_for,
 * bit-identically for any thread count. */
#ifndef DR_HAIR_H
#define DR_HAIR_H

#include "core/core.h"
#include "lagrangian/lagrangian.h"

/* ---- grooms ---------------------------------------------------------------------------------------- */

/* Strands as polylines in the scene's rest pose. Owned arrays; dr_groom_free releases them. */
typedef struct DrGroom {
    int nstrands;
    int *offsets;       /* nstrands + 1 */
    double *x;          /* offsets[nstrands] × 3, m; vertex offsets[s] is strand s's root */
    double *root_normal;/* nstrands × 3: scalp normal at the root (the root frame's first director is
                           made perpendicular to the first edge from it) */
} DrGroom;
void dr_groom_free(DrGroom *g);

typedef struct DrGroomDesc {
    int count;          /* strands, ≥ 1 */
    double length;      /* m, > 0 */
    int segments;       /* edges per strand, ≥ 1 */
    double curl_radius; /* m; 0 = straight strands along the scalp normal */
    double curl_pitch;  /* m per turn of the helix (along the normal) */
    double length_jitter; /* relative, [0, 1): each strand's length is length·(1 ± jitter) */
    uint64_t seed;      /* root placement, curl phase and length jitter */
} DrGroomDesc;
void dr_groom_desc_default(DrGroomDesc *d);

/* Grows strands from a closed or open triangle mesh (the scalp, already posed): roots sampled uniformly by
 * area with the seeded rng, each strand along the area-weighted vertex normal interpolated at its root, or
 * a helix about it when curl_radius > 0. DR_ERR_INPUT for a mesh without area or a desc out of range.
 * Details: the normals are computed from the triangles (scalp->n is not used); where the interpolated field
 * vanishes (opposed vertex normals) the triangle's own normal is taken. Strand s is vertices s·(segments+1)
 * … with equal steps of arc length; `length` is the arc length (for a helix: of the helix, whose chords the
 * edges are). A curled strand is a right-handed helix starting at the root, its axis parallel to the normal
 * at distance curl_radius, its phase random per strand; it rises curl_pitch along the normal per turn.
 * Every strand draws the same random numbers whatever curl and jitter are, so the roots depend on the mesh,
 * count and seed only; the same inputs give bit-identical output. On failure *out is left empty. */
DR_NODISCARD DrStatus dr_groom_grow(const DrTriMesh *scalp, const DrGroomDesc *desc, DrGroom *out, DrError *err);

/* Reads polylines ("v" and "l" records) from an OBJ file through dr_io_read_polylines_obj (io.h), with
 * "# radius" lines optional and their values unused: each "l" record is one strand, its first vertex the
 * root; the root normal is the direction of the first edge. Other records are skipped. Indices are 1-based
 * (negative: back from the last "v" before the record; "i/t" takes i; forward references are allowed).
 * DR_ERR_INPUT at file:line:col for: a line with fewer than 2 vertices, an index out of range, index 0,
 * repeated consecutive vertices (a zero-length edge), a "v" without three finite numbers, a token that is
 * not a number or index, a control byte (not a text file), a record continued with '\', a "# radius" line
 * without one finite number >= 0. DR_ERR_INPUT naming the file for a file without "l" records and for a
 * missing or unopenable file; DR_ERR_IO when reading fails. On failure *out is left empty. */
DR_NODISCARD DrStatus dr_groom_read_obj(const char *path, DrGroom *out, DrError *err);

/* ---- rod material ------------------------------------------------------------------------------------ */

typedef struct DrRodMaterial {
    double radius;      /* r, m */
    double density;     /* ρ, kg/m³ */
    double youngs;      /* E, Pa */
    double shear;       /* G, Pa */
    double damping;     /* internal viscosity as a Kelvin–Voigt time, s (viscous groups with C_v⁻¹ = damping·C⁻¹);
                           0 = none */
    double tip_radius;  /* m; 0 (default) = `radius` all along. Else the radius falls linearly in arc length from
                           `radius` at the root to this at the tip (a tapered strand): masses, stiffnesses (each edge at
                           its ends' mean radius, bending and twisting at each vertex's) and contact follow it */
} DrRodMaterial;
void dr_rod_material_default(DrRodMaterial *m); /* human hair: r = 50 µm, ρ = 1300, E = 3.9 GPa, G = 1.3 GPa */

/* ---- rod sets: the dynamics ------------------------------------------------------------------------------- */

/* A collider as the hair sees it: signed distance (negative inside) and outward unit normal at x, and the
 * surface velocity there (NULL: at rest). Evaluated at the start of each step. */
typedef double (*DrRodSdfFn)(DrVec3 x, DrVec3 *normal, void *ctx);
typedef DrVec3 (*DrRodVelocityFn)(DrVec3 x, void *ctx);
typedef struct DrRodCollider {
    DrRodSdfFn sdf;
    DrRodVelocityFn velocity_at;
    void *ctx;
    double friction;  /* Coulomb coefficient */
    double thickness; /* m, added to the hair radius */
} DrRodCollider;

typedef enum DrRodRoots {
    DR_ROD_ROOTS_FREE,    /* no vertex attached (a free rod) */
    DR_ROD_ROOTS_PINNED,  /* the root vertex follows the scalp */
    DR_ROD_ROOTS_CLAMPED  /* the root vertex, the next one and the first edge's twist follow the scalp */
} DrRodRoots;

typedef struct DrRodSetDesc {
    DrRodRoots roots;           /* default CLAMPED */
    const DrRodRoots *batch_roots; /* NULL (default): `roots` for every batch; else one per batch (a groom's own
                                   choice: loose strands beside rooted ones), read at create only */
    DrRodRoots tips;            /* the other end, held where it starts (tests, tethered strands); default FREE */
    DrVec3 gravity;             /* m/s², default (0, −9.81, 0) */
    bool geometric_stiffness;   /* eq. (S27)'s λ-weighted Hessians; default true */
    DrLagDesc solver;           /* preconditioner, tolerance, iteration cap */
    bool hair_contact;          /* search strand–strand contacts (spatial hash); default false */
    double collider_stiffness;  /* N/m of a vertex–collider contact; default 1e4 */
    const struct DrRodPairResponse *pairs; /* NULL (default): strand–strand contacts take the batches' own settings
                                   (see DrRodBatch). Else nbatches² entries, row-major and symmetric, read at create
                                   only: entry a·nbatches + b is the response of contacts between batches a and b (a
                                   collision element's); which pairs touch is still the batches' group, mask and
                                   self_contact. */
    DrLag *system;              /* NULL (default): the set makes a system of its own and steps it itself. Else the
                                   shared system (DESIGN §8) the set adds its strands to as objects, one per strand,
                                   after those already there; the caller owns it and drives the step (see "in a shared
                                   system" below), and `solver` is then the caller's business (dr_lag_set_desc). */
} DrRodSetDesc;
void dr_rod_set_desc_default(DrRodSetDesc *d);

/* The response of strand–strand contacts between two batches: stiffness (N/m, > 0), Coulomb friction, the extra
 * thickness around each strand (they touch at r_a + thickness + r_b + thickness) and damping (s, a time constant:
 * a viscous row along the normal with coefficient damping·stiffness; 0 = none). */
typedef struct DrRodPairResponse {
    double stiffness, friction, thickness, damping;
} DrRodPairResponse;

/* One groom of the set (a hair element) with its material and contact settings. When desc.hair_contact is on,
 * strands of one batch touch each other when self_contact; strands of batches a and b when
 * (group_a & mask_b) != 0 and (group_b & mask_a) != 0. Two strands touch at r_a + t_a + r_b + t_b (t the
 * batches' contact_thickness); a contact has the smaller stiffness and the larger friction and damping of the two
 * (unless desc.pairs gives the pair's response). */
typedef struct DrRodBatch {
    const DrGroom *groom;
    DrRodMaterial material;
    unsigned group, mask;       /* collision group bits and the groups it collides with */
    bool self_contact;
    double contact_stiffness;   /* N/m per contact, > 0 */
    double contact_friction;    /* Coulomb coefficient of strand–strand contact */
    double contact_thickness;   /* m */
    double collider_friction;   /* against colliders: the larger of this and the collider's own coefficient */
    double collider_thickness;  /* m, added to the radius against colliders (with the collider's own) */
    double contact_damping;     /* s: a viscous row along a strand–strand contact's normal, damping·stiffness (the
                                   larger of the two batches'); 0 = none */
} DrRodBatch;

typedef struct DrRodSet DrRodSet;

/* The rods start at rest in the groom's shape, which is their rest shape (rest lengths, curvatures,
 * twist zero on frames space-transported from each root normal). DR_ERR_INPUT for a strand of fewer than
 * 2 vertices, a zero-length edge, or material values out of range (radius, density, moduli > 0). A failure
 * with desc.system set may leave some of the set's objects in that system: destroy it too. */
DR_NODISCARD DrStatus dr_rod_set_create(const DrRodSetDesc *desc, const DrRodBatch *batches, int nbatches,
                                        DrRodSet **out, DrError *err);
void dr_rod_set_destroy(DrRodSet **rods);

/* The hot arrays (the set owns them; valid until destroy). Tests and the world read and may overwrite
 * x, v, theta, theta_dot between steps (then call dr_rod_set_refresh). */
typedef struct DrRodState {
    int nstrands, nverts, nedges;
    const int *offsets;     /* nstrands + 1 */
    double *x, *v;          /* nverts × 3 */
    double *theta, *theta_dot; /* nedges */
    double *a1;             /* nedges × 3 reference directors (time-parallel transported) */
    double *ref_twist;      /* interior vertices (nverts − 2 nstrands), rad */
    double *lambda;         /* multipliers of the elastic groups (checkpoint) */
    long nlambda;
    const double *mass;     /* per vertex, kg */
    const double *radius;   /* per strand, m */
    const int *batch_offsets; /* nbatches + 1: the strands of batch b are batch_offsets[b] .. [b+1] − 1 */
    int nbatches;
    const double *vertex_radius; /* per vertex, m (equal to the strand's radius unless tapered) */
    bool tapered;               /* some strand's radius varies along it */
} DrRodState;
DrRodState dr_rod_set_state(DrRodSet *rods);
/* Recomputes the tangents and reference twists after the caller changed x or a1 (a resumed checkpoint). */
void dr_rod_set_refresh(DrRodSet *rods);


typedef struct DrRodStats {
    int steps;
    int iterations;          /* CG iterations, summed over solves */
    double residual;         /* last relative residual */
    int not_converged;       /* solves that hit the iteration cap */
    int collider_contacts;   /* vertex–collider contacts of the last step */
    int hair_contacts;       /* edge–edge contacts of the last step */
    int indefinite_blocks;   /* summed */
    double kinetic, elastic, gravity_potential; /* J, after the last step */
    DrVec3 momentum;         /* kg m/s */
    DrVec3 angular_momentum; /* kg m²/s about the origin (positions only) */
    double seconds_build, seconds_solve, seconds_contact;
} DrRodStats;

/* Advances by h: the roots of batch b move to scalp_end[b] (a rigid transform of the rest groom; NULL: they
 * stay), colliders act through constraints in the
 * solve and Coulomb friction after it, hair–hair contacts when desc.hair_contact. stats accumulates (zero
 * it first). DR_WARN_NOT_CONVERGED when the solve hit its cap (the step is kept); DR_ERR_RUNTIME when the
 * state becomes non-finite (the state is then left as it was before the step). The same, bit for bit, as
 * dr_rod_set_predict + dr_rod_set_solve(NULL, NULL) + dr_rod_set_commit below. */
DR_NODISCARD DrStatus dr_rod_set_step(DrRodSet *rods, double h, const DrXform *scalp_end,
                                      const DrRodCollider *colliders, int ncolliders, DrRodStats *stats,
                                      DrError *err);

/* ---- the step in phases (DESIGN §8) ------------------------------------------------------------------------
 * predict(h) → samples → solve(forces) … solve(forces) → commit. Between predict and commit the state
 * (dr_rod_set_state: x, v, θ, θ̇, a1, reference twists, λ) stays that of the start of the step; each solve
 * starts again from the prediction, and commit keeps the last one. After the first step, a step allocates
 * nothing on the heap while its contacts fit the buffers: the first step leaves room for twice its own, and a
 * step that needs more grows them geometrically (they are kept). Per-step scratch comes from an arena the
 * set owns, reset by predict. */

/* The set's own limit on the step: INFINITY. Every elastic, damping and contact force is implicit (the
 * linearised backward Euler of src/lagrangian), so no step makes the solve unstable; the step is chosen for
 * accuracy by the caller: the world steps the hair at (1/fps) / HairSolver.substeps (world_lagrangian.c). */
double dr_rod_set_stable_dt(const DrRodSet *rods);

/* Starts a step of h > 0 seconds: the root (and held tip) velocities that land them on scalp_end (as in
 * dr_rod_set_step) at t + h, the elastic and damping groups on the current state with the last λ, the
 * vertex–collider contacts (colliders evaluated now) and the hair–hair contacts. A prediction not committed
 * is simply replaced by the next predict. Failures as dr_rod_set_step's (DR_ERR_RUNTIME: non-finite groups). */
DR_NODISCARD DrStatus dr_rod_set_predict(DrRodSet *rods, double h, const DrXform *scalp_end,
                                         const DrRodCollider *colliders, int ncolliders, DrError *err);

/* The points where the hair meets other solvers: its vertices, n = nverts, vertex j of strand s at
 * offsets[s] + j as everywhere else. Borrowed: the set's own arrays, filled by dr_rod_set_samples and valid
 * until the next call of any phase. SI units. */
typedef struct DrRodSamples {
    int n;
    const double *x;        /* n × 3, m: positions at the start of the step (at its end: x + h v) */
    const double *v;        /* n × 3, m/s: velocities of the last solve since predict (before collider
                               friction, which commit applies); before any solve, the velocities at the start
                               of the step, held vertices at the velocity that lands them on the scalp */
    const double *mass;     /* n, kg */
    const double *radius;   /* n, m: the strand's radius */
    const double *length;   /* n, m: the length of strand a vertex stands for (half of each adjacent edge, at
                               the start of the step): the vertex's volume is π r² length */
    const double *tangent;  /* n × 3, unit: the strand's direction at the vertex (mean of the adjacent edges'
                               tangents, from root to tip) */
    const unsigned char *held; /* n: 1 for a vertex whose motion is prescribed (roots, held tips): forces on it
                               are ignored */
} DrRodSamples;
/* Between predict and commit. */
DrRodSamples dr_rod_set_samples(DrRodSet *rods);

/* Solves the predicted step with external forces at the vertices: force (NULL: none) 3 nverts N and dforce_dv
 * (NULL: none) 9 nverts, a row-major 3×3 per vertex, N·s/m. Over the step the force on vertex i is
 *     force_i + dforce_dv_i · v₊_i        (v₊ the solved velocity),
 * so −h dforce_dv enters the implicit system on the vertex's own 3×3 block like extra mass (damping when
 * negative definite): a law f(v) linearised about v* passes force = f(v*) − (∂f/∂v) v*; a drag −c (v − u)
 * passes c u and −c I. Only the symmetric part of dforce_dv enters (the solve is symmetric); it must keep
 * the system positive definite. Held vertices ignore both; twists get no external torque. Callable several
 * times after one predict, each from the prediction alone (never from an earlier solve) and committing
 * nothing: with the same arguments it gives the same bits. stats (may be NULL) accumulates iterations,
 * residual, not_converged, indefinite_blocks, seconds_solve. DR_WARN_NOT_CONVERGED when the solve hit its
 * cap (the result is usable); DR_ERR_RUNTIME on a breakdown (the prediction stays and can be solved again). */
DR_NODISCARD DrStatus dr_rod_set_solve(DrRodSet *rods, const double *force, const double *dforce_dv,
                                       DrRodStats *stats, DrError *err);

/* Between a solve (or dr_rod_set_take) and commit: adds dv (3 nverts, m/s) to the solved velocities of the vertices'
 * free DOFs (held ones keep their prescribed velocity). An explicit correction by a caller that learns after the solve
 * what an external force finally was (src/couple: the fluid's drag on a vertex heavier than the fluid around it);
 * samples and commit (its multipliers included) then see the corrected velocities. */
void dr_rod_set_add_velocity(DrRodSet *rods, const double *dv);

/* Ends the step with the last solve: multipliers λ₊, Coulomb friction at the collider contacts, positions,
 * twists, time-transported directors and reference twists; stats (may be NULL) counts the step and takes its
 * contacts, timings, energies and momenta. DR_ERR_RUNTIME when the state becomes non-finite (the state,
 * multipliers included, is then left as it was before the step). Needs a solve that did not fail since
 * predict. */
DR_NODISCARD DrStatus dr_rod_set_commit(DrRodSet *rods, DrRodStats *stats, DrError *err);

/* ---- in a shared system (desc.system set) -------------------------------------------------------------------------
 * The system's owner steps every model in it together (src/world/world_lagrangian.c):
 *     dr_rod_set_predict_dofs (every model)       fill the set's DOF ranges of dr_lag_dofs's arrays
 *     dr_lag_begin(system, h, dofs.mass, dofs.qdot, dofs.fext, dofs.prescribed, dofs.qdot_prescribed)
 *     dr_rod_set_predict_groups (every model)     add the groups
 *     dr_rod_set_samples, dr_rod_set_fill_load    the load of a solve, if any
 *     dr_lag_solve_load(system, load, dofs.qdot_out); dr_rod_set_take   re-callable, as dr_rod_set_solve
 *     dr_lag_update_multipliers(system, dofs.qdot_out); dr_rod_set_commit (every model)
 * dr_rod_set_predict is dr_rod_set_predict_dofs + dr_lag_begin + dr_rod_set_predict_groups on the set's own system, and
 * dr_rod_set_solve the load, the solve and the take: a set alone in a shared system gives the same bits as with its
 * own. dr_rod_set_predict and dr_rod_set_solve are for a set with a system of its own only. */

/* Step 1–2 of a predict of h > 0 seconds: the set's DOF ranges of the system's per-DOF arrays (masses, velocities,
 * gravity, held DOFs with the velocities that land them on scalp_end). DR_ERR_NOMEM when the arrays cannot be sized. */
DR_NODISCARD DrStatus dr_rod_set_predict_dofs(DrRodSet *rods, double h, const DrXform *scalp_end, DrError *err);
/* The rest of a predict, after the owner's dr_lag_begin: elastic, damping and contact groups. Failures as
 * dr_rod_set_predict's. */
DR_NODISCARD DrStatus dr_rod_set_predict_groups(DrRodSet *rods, const DrRodCollider *colliders, int ncolliders,
                                                DrError *err);
/* The number of 3×3 load blocks the set needs in a DrLagLoad (one per vertex), and the load of a solve (as
 * dr_rod_set_solve takes it) written into the owner's arrays: the set's DOFs of gforce (system DOFs), and, when
 * dforce_dv is given, dr_rod_set_load_blocks entries of block_dof and 9 times as many of block. The set keeps the
 * blocks for commit: a vertex's Coulomb friction against a collider is limited by the impulse its contact gave over
 * its inertia in the solve, its mass plus what the load's −h ∂f/∂v added along the contact normal (a film's weight). */
int dr_rod_set_load_blocks(const DrRodSet *rods);
void dr_rod_set_fill_load(DrRodSet *rods, const double *force, const double *dforce_dv, double *gforce,
                          int *block_dof, double *block);
/* The first of each vertex's 3 DOFs in the system (nverts entries; fixed from create on). */
const int *dr_rod_set_vertex_dofs(const DrRodSet *rods);
/* The owner solved the system into dr_lag_dofs's qdot_out: the set takes its range as its solve (for samples and
 * commit). */
void dr_rod_set_take(DrRodSet *rods);

/* Energies and momenta of the current state (what stats reports after a step). */
void dr_rod_set_measure(const DrRodSet *rods, DrRodStats *stats);
/* Sets the solver options (preconditioner, tolerance) for the following steps. */
void dr_rod_set_solver(DrRodSet *rods, const DrLagDesc *solver);

#endif
