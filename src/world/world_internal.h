/* Private to src/world: the world's layout and the helpers that world.c (liquid, colliders, files),
 * world_mpm.c (MPM solids), world_hair.c (hair) and world_bem.c (boundary-element bodies) share. */
#ifndef DR_WORLD_INTERNAL_H
#define DR_WORLD_INTERNAL_H

#include "world/world.h"

#include "bem/bem.h"
#include "grid/grid.h"
#include "hair/hair.h"
#include "io/io.h"
#include "liquid/liquid.h"
#include "mpm/mpm.h"
#include "stage/stage.h"

/* snprintf into an array that must hold the result: element names are at most 128 characters, so the
 * HDF5 paths built here always fit; a truncation would be a programming error. */
#define PATHF(buf, ...)                                                                                     \
    do {                                                                                                    \
        int n_ = snprintf(buf, sizeof buf, __VA_ARGS__);                                                    \
        assert(n_ >= 0 && (size_t)n_ < sizeof buf);                                                         \
    } while (0)

typedef struct WorldCollider {
    const DrElement *element;
    DrCollider *collider;    /* NULL when no solver needs an SDF (a scene with neither liquid nor MPM) */
} WorldCollider;

typedef struct WorldLiquid {
    const DrElement *element;
    DrLiquid *liquid;
    DrCollider **shapes;     /* LiquidSource mesh volumes, needed at creation only */
    int nshapes;
    double volume0;          /* first frame's liquid-cell volume, for the drift diagnostic */
    DrLiquidStats last;
} WorldLiquid;

/* One mpm_solid element: a body of the shared DrMpm. */
typedef struct WorldMpmBody {
    const DrElement *element;
    int body;                /* DrMpm body id */
    long count;              /* its particles */
} WorldMpmBody;

/* A scene collider as a solver sees it (the MPM grid, the hair): its SDF and surface velocity posed at the time
   of the substep being taken (the solver's world file moves the frame between substeps). */
typedef struct WorldPosedCollider {
    const DrCollider *collider;
    DrColliderFrame frame;
    bool moving;
} WorldPosedCollider;
/* Callbacks on a WorldPosedCollider (ctx): signed distance with the outward unit normal, and surface velocity. */
double dr_world_posed_sdf_(DrVec3 x, DrVec3 *normal, void *ctx);
DrVec3 dr_world_posed_velocity_(DrVec3 x, void *ctx);

/* Everything MPM; NULL in a world whose scene has no mpm_solid (nothing of it is allocated then). */
typedef struct WorldMpm {
    DrMpm *mpm;
    WorldMpmBody *bodies;
    int nbodies;
    WorldPosedCollider *colliders;
    int ncolliders;
    bool any_moving;
    int max_substeps;
    double time;             /* s, start of the frame being advanced (poses moving colliders) */
    DrMpmStats last;         /* the last frame's stats, summed over its substeps */
    int not_converged;       /* 1 when a Newton iteration of the last frame stopped at its cap */
} WorldMpm;

/* Everything hair; NULL in a world whose scene has no hair element. All hair elements are batches of one rod
   set, in element order. */
typedef struct WorldHair {
    DrRodSet *rods;
    const DrElement **elements;
    int nelements;
    double **keys;           /* per element: scalp motion keys (rows of 7: s, m, rad) */
    int *nkeys;
    bool any_motion;
    DrXform *poses;          /* per element, the substep's end pose */
    DrRodCollider *colliders;
    WorldPosedCollider *ctx;
    int ncolliders;
    int substeps;            /* HairSolver.substeps */
    double time;
    DrRodStats last;         /* the last frame's, summed over its substeps */
    int not_converged;
} WorldHair;

/* One bem_solid element: a DrBemSolid on a shared matrix set. */
typedef struct WorldBemBody {
    const DrElement *element;
    DrBemSolid *solid;
    int steps_per_frame;     /* (1/fps) / BemSolver.time_step, whole (the scene checks it) */
    double *state;           /* dr_bem_solid_state_size() doubles: scratch of checkpoints and hashes */
    size_t state_size;
    long last_steps;         /* steps of the last frame */
    DrBemStepStats last;     /* the last frame's: seconds summed, errors the largest of its steps */
} WorldBemBody;

/* The bem_solid bodies with one BemSolver.time_step, stepped together by dr_bem_solids_step with the constraints the
   scene gives them (bodies of different steps never meet each other; each group meets every collider). */
typedef struct WorldBemGroup {
    int *members;            /* indices into WorldBem.bodies, in element order: the constraints' body indices */
    DrBemSolid **solids;     /* the members' solids, in that order */
    int count;
    double dt;               /* s */
    int steps_per_frame;
    DrBemConstraints constraints; /* points into colliders, fixed and joints */
    DrBemCollider *colliders;     /* one per scene collider, on WorldBem.posed */
    DrBemFixed *fixed;
    DrBemJoint *joints;
    bool constrained;        /* anything to solve; else each member is stepped alone, as without contact */
} WorldBemGroup;

/* Everything BEM; NULL in a world whose scene has no bem_solid. */
typedef struct WorldBem {
    WorldBemBody *bodies;
    int nbodies;
    DrBemMatrices **sets;    /* one per distinct cache key, read once */
    char (*keys)[33];
    int nsets;
    WorldBemGroup *groups;
    int ngroups;
    WorldPosedCollider *posed; /* every scene collider, posed at the end time of the step being taken */
    DrCollider **own;        /* SDFs built here when the world built none (no liquid, MPM or hair); else NULL */
    int ncolliders;
    DrBemConstraintStats contact; /* the last frame's, all groups: counts of its last step, iterations and passes
                                     summed, residual the largest, seconds summed */
    int not_converged;       /* steps of the last frame that returned DR_WARN_NOT_CONVERGED */
} WorldBem;

/* A bem_solid body as the liquid sees it (one-way: the liquid does not push back). The signed distance of its rest
   shape x − x̄ (the reference of V = R(x − x̄ + u) + T, without u) is built once; every frame it becomes a DrCollider
   whose motion keys carry the body's rigid frame R, T through that frame (world.c, body_keys). */
typedef struct WorldBodyCollider {
    const WorldBemBody *body;
    float *phi;              /* rest-frame SDF nodes, x fastest */
    int nx, ny, nz;
    DrVec3 origin;
    double dx;
    DrXform start;           /* the body's frame (R, T) at the start of the frame being advanced */
    DrVec3 start_velocity;   /* and its Ṫ */
    double *keys;            /* the frame's key rows (7 each) */
    int nkeys;
    DrCollider *collider;    /* the SDF posed by keys; rebuilt every frame */
} WorldBodyCollider;

struct DrWorld {
    const DrScene *scene;
    int first_frame, last_frame, frame;
    double fps;
    DrVec3 gravity;
    WorldCollider *colliders;
    int ncolliders;
    const DrCollider **collider_ptrs; /* the live colliders, in element order, as the solvers take them */
    int nlive;
    WorldLiquid *liquids;
    int nliquids;
    WorldMpm *mpm;
    WorldHair *hair;
    WorldBem *bem;
    WorldBodyCollider *body_colliders; /* one per bem_solid when the scene has a liquid, else none */
    int nbody_colliders;
    const DrCollider **liquid_colliders; /* what the liquid sees: the live colliders, then the bodies */
    int nliquid_colliders;
};

/* Prefixes an asset error with the element and field it came from ("jelly.MpmShape.mesh: ..."), keeping the
   file name. Returns s. */
DrStatus dr_world_asset_context_(DrStatus s, const char *element, const char *field, DrError *err);
/* SDF of a mesh as a collider (or a shape to fill) with optional motion keys (rows of 7, times in s). */
/* /<name>/position (n×3, m), velocity (m/s) and affine (n×3×3, 1/s) of a particle set (DESIGN §4). */
DR_NODISCARD DrStatus dr_world_write_particles_(DrH5 *h, const char *name, long n, const double *x, const double *v,
                                                const double *affine, bool compress, DrError *err);
/* One diagnostic value (dims {1}) or vector (dims {3}) at <group>/<name> of a frame cache, with its units. */
DR_NODISCARD DrStatus dr_world_write_scalar_(DrH5 *h, const char *group, const char *name, double v, const char *units,
                                             DrError *err);
DR_NODISCARD DrStatus dr_world_write_vec_(DrH5 *h, const char *group, const char *name, DrVec3 v, const char *units,
                                          DrError *err);
DR_NODISCARD DrStatus dr_world_make_collider_(const DrTriMesh *mesh, double dx, double friction, bool no_slip,
                                              double thickness, int nkeys, const double *keys, DrCollider **out,
                                              DrError *err);
/* Element e's Transform component without its scale (R from the XYZ Euler angles, t the translation), and the
   scale: a point p of its mesh is placed at R·(scale·p) + t. */
DrXform dr_world_transform_(const DrElement *e, double *scale);
static inline DrStatus dr_world_load_collider_mesh(const DrElement *e, DrTriMesh *mesh, DrError *err)
{
    return dr_stage_load_collider_mesh(e, mesh, err);
}
/* Loads the mesh file `path` (referenced by element e's `field`) and applies e's Transform component. */
DR_NODISCARD DrStatus dr_world_load_posed_mesh_(const DrElement *e, const char *path, const char *field,
                                                DrTriMesh *mesh, DrError *err);

/* ---- world_mpm.c: the MPM solids (each a no-op when w->mpm is NULL) ---- */

/* Builds the one DrMpm of the scene's mpm_solid elements after the colliders exist; leaves w->mpm NULL
   when there are none. */
DR_NODISCARD DrStatus dr_world_mpm_create_(DrWorld *w, DrError *err);
void dr_world_mpm_destroy_(WorldMpm **m);
/* Advances the bodies from t0 to t1 and adds the frame's MPM figures to stats. */
DR_NODISCARD DrStatus dr_world_mpm_step_(DrWorld *w, double t0, double t1, DrFrameStats *stats, DrError *err);
/* Per element: position, velocity, affine, deformation_gradient, volume (+ diagnostics when `frame_cache`). */
DR_NODISCARD DrStatus dr_world_mpm_write_(const DrWorld *w, DrH5 *h, bool frame_cache, DrError *err);
DR_NODISCARD DrStatus dr_world_mpm_read_(DrWorld *w, DrH5 *h, const char *path, DrError *err);
void dr_world_mpm_hash_(const DrWorld *w, DrHasher *h);

/* ---- world_hair.c: the hair elements (each a no-op when w->hair is NULL) ---- */

DR_NODISCARD DrStatus dr_world_hair_create_(DrWorld *w, DrError *err);
void dr_world_hair_destroy_(WorldHair **h);
DR_NODISCARD DrStatus dr_world_hair_step_(DrWorld *w, double t0, double t1, DrFrameStats *stats, DrError *err);
/* Per element: position, velocity, twist, strand_offsets, radius (+ diagnostics in a frame cache; + twist rates,
   reference directors, reference twists and multipliers in a checkpoint). */
DR_NODISCARD DrStatus dr_world_hair_write_(const DrWorld *w, DrH5 *h, bool frame_cache, DrError *err);
DR_NODISCARD DrStatus dr_world_hair_read_(DrWorld *w, DrH5 *h, const char *path, DrError *err);
void dr_world_hair_hash_(const DrWorld *w, DrHasher *h);

/* ---- world_bem.c: the boundary-element bodies (each a no-op when w->bem is NULL) ---- */

/* Reads every bem_solid's matrices from cache_root and places the bodies; leaves w->bem NULL when there are none. */
DR_NODISCARD DrStatus dr_world_bem_create_(DrWorld *w, const char *cache_root, DrError *err);
void dr_world_bem_destroy_(WorldBem **b);
/* Advances every body by one frame (steps_per_frame steps each) and adds the frame's BEM figures to stats. */
DR_NODISCARD DrStatus dr_world_bem_step_(DrWorld *w, int frame, DrFrameStats *stats, DrError *err);
/* Frame cache: per element rotation, translation, velocity, angular_velocity, displacement, reference, triangles
   and diagnostics; checkpoint: per element the solid's state array and step count. */
DR_NODISCARD DrStatus dr_world_bem_write_(const DrWorld *w, DrH5 *h, bool frame_cache, DrError *err);
/* Restores the bodies from a checkpoint taken after `frame`. */
DR_NODISCARD DrStatus dr_world_bem_read_(DrWorld *w, DrH5 *h, const char *path, int frame, DrError *err);
void dr_world_bem_hash_(const DrWorld *w, DrHasher *h);

#endif
