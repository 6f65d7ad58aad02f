/* Private to src/world: what the orchestrator (world.c) and the per-solver adapters (world_liquid.c, world_mpm.c,
 * world_lagrangian.c, world_bem.c) and the kinematics (world_kinematics.c) share: the read-only context of a step, the
 * posed colliders, and the adapter table. An adapter file includes this header only; it never calls into world.c
 * or into another adapter: the orchestrator hands each one its own struct and the context. */
#ifndef DR_WORLD_ADAPTER_H
#define DR_WORLD_ADAPTER_H

#include "world/world.h"

#include "bem/bem.h"
#include "cloth/cloth.h"
#include "contact/contact.h"
#include "couple/couple.h"
#include "grid/grid.h"
#include "io/io.h"
#include "liquid/liquid.h"

/* snprintf into an array that must hold the result: element names are at most 128 characters, so the
 * HDF5 paths built here always fit; a truncation would be a programming error. */
#define PATHF(buf, ...)                                                                                     \
    do {                                                                                                    \
        int n_ = snprintf(buf, sizeof buf, __VA_ARGS__);                                                    \
        assert(n_ >= 0 && (size_t)n_ < sizeof buf);                                                         \
    } while (0)

/* ---- kinematics: every scene collider, and each bem_solid body as the liquid sees it (world_kinematics.c) ---- */

/* A scene collider as the MPM grid and the hair see it: its SDF and surface velocity posed at the end time of the
   clock step being taken, once for every solver. */
typedef struct WorldPosedCollider {
    const DrCollider *collider;
    DrColliderFrame frame;
    bool moving;
} WorldPosedCollider;
/* Callbacks on a WorldPosedCollider (ctx): signed distance with the outward unit normal, and surface velocity. */
double world_posed_sdf(DrVec3 x, DrVec3 *normal, void *ctx);
DrVec3 world_posed_velocity(DrVec3 x, void *ctx);

/* A collider from a closed mesh: its SDF at spacing dx (OpenVDB) with optional motion keys (rows of 7, s and rad). */
DR_NODISCARD DrStatus world_make_collider(const DrTriMesh *mesh, double dx, double friction, bool no_slip,
                                          double thickness, int nkeys, const double *keys, DrCollider **out,
                                          DrError *err);

typedef struct WorldKinematics WorldKinematics;
/* Loads every collider element's mesh (errors name element and field); builds their SDFs at half the smallest cell
   of any solver that samples colliders (none when nothing does). */
DR_NODISCARD DrStatus world_kinematics_create(const DrScene *scene, int first_frame, double fps, WorldKinematics **out,
                                              DrError *err);
void world_kinematics_destroy(WorldKinematics **k);
/* The bem_solid bodies as colliders of the liquid, the hair and the cloth: one SDF per body, of its deformed surface
   in the body frame, carried by the body's rigid frame; built only when the scene has a liquid, hair or cloth. */
DR_NODISCARD DrStatus world_kinematics_add_bodies(WorldKinematics *k, const DrScene *scene,
                                                  const DrBemSolid *const *solids, const DrElement *const *elements,
                                                  int n, DrError *err);
/* Every collider element (element order) and its SDF, NULL when the kinematics built none (no solver but the BEM
   bodies samples colliders: they build their own at their own resolution). */
int world_kinematics_collider_count(const WorldKinematics *k);
const DrCollider *world_kinematics_collider(const WorldKinematics *k, int i, const DrElement **element);
/* The SDF spacing of the scene's colliders (m), 0 when no solver samples colliders. */
double world_kinematics_dx(const WorldKinematics *k);
/* The live colliders (those with an SDF), in element order, and what the liquid takes: those, then the bodies. */
int world_kinematics_colliders(const WorldKinematics *k, const DrCollider *const **out);
int world_kinematics_liquid_colliders(const WorldKinematics *k, const DrCollider *const **out);
/* Every live collider posed at t (the shared array the MPM, hair and cloth colliders point into), and the bodies. */
WorldPosedCollider *world_kinematics_posed(WorldKinematics *k);
void world_kinematics_pose(WorldKinematics *k, double t);
/* The rigid motion that carries what is attached to `target` (a collider or bem_solid element) from the placed rest
   pose to time t: a collider's Motion pose at t; a body's frame at t (as its keys so far carry it) composed with the
   inverse of its frame at t = 0, so that a point q of the rest pose goes to R(t) R₀ᵀ (q − T₀) + T(t). False when the
   kinematics keep no collider for it. t within the clock step being taken. */
bool world_kinematics_carry(const WorldKinematics *k, const DrElement *target, double t, DrXform *out);
/* Hair against cloth (DESIGN §8, one Lagrangian system): each cloth element that a vertex_face collision element pairs
   with a hair element is an object of the hair's system, stepped with the hair by the hair adapter at every clock step
   (both step in lockstep), with the rows between the hair's vertices and its triangles (contact.h). The hair adapter
   publishes its system when it builds; the cloth adapter then makes the panel in it and publishes the panel and its
   colliders; the hair adapter leaves each step's figures for the cloth adapter to count. */
typedef struct WorldClothPanelLink {
    const DrElement *element; /* the cloth element */
    DrCloth *cloth;           /* the panel (the cloth adapter's), NULL until it is built */
    DrTriField *field;        /* the panel at a step's start, as the hair's rows find it (the hair adapter's) */
    int *dof;                 /* per vertex: its first DOF in the system (the hair adapter's) */
    DrClothStats last;        /* the panel's last step (hair adapter), and how many steps since the cloth adapter */
    int steps;                /* last counted them */
    long iterations;
    int not_converged;
} WorldClothPanelLink;
typedef struct WorldClothLink {
    int n;                    /* 0: no hair meets any cloth */
    WorldClothPanelLink *panels;
    DrLag *system;            /* the hair's system */
    const DrClothCollider *colliders; /* what the panels meet (the cloth adapter's) */
    int ncolliders;
} WorldClothLink;
WorldClothLink *world_kinematics_cloth_link(WorldKinematics *k);

/* The bem_solid bodies as the hair and the cloth see them (their deformed surface, posed with the colliders); 0
   without hair, cloth and liquid. The array stays in place; each entry's collider changes at every BEM step. */
int world_kinematics_bodies_posed(WorldKinematics *k, WorldPosedCollider **out);
/* The MPM solids' particles as a surface the hair and the cloth meet (contact.h's point field), kept only when the
   scene has MPM solids and hair or cloth: the MPM adapter hands its particles after each of its steps (a no-op when
   nobody wants them); the hair and the cloth take the field's callbacks (false: there is none). */
bool world_kinematics_wants_mpm_surface(const WorldKinematics *k);
DR_NODISCARD DrStatus world_kinematics_set_mpm_surface(WorldKinematics *k, long n, const double *x, const double *v,
                                                       const double *volume, DrError *err);
bool world_kinematics_mpm_surface(WorldKinematics *k, double (**sdf)(DrVec3, DrVec3 *, void *),
                                  DrVec3 (**velocity)(DrVec3, void *), void **ctx);
/* The MPM solids two-way with the first liquid (Integrator.liquid_coupling; world_liquid.c explains the scheme). The
   MPM adapter turns it on when it builds, hands its particles after building, restoring and each of its steps, and
   takes the velocity changes the liquid left (pending) as forces m_p dv_p / Δt over its next step; the liquid's
   substep, which comes first in the clock step, lumps the particles onto its faces and leaves them dv. */
typedef struct WorldMpmParticles {
    bool on;
    long n, cap;
    double *x, *v;           /* 3n: where the MPM's last step left them */
    double *mass, *volume;   /* n: kg, m³ (V₀ det F) */
    double *dv;              /* 3n: the velocity change the liquid's pressure gave them since, when pending; the MPM
                                adapter turns it into the force m_p dv_p/Δt in place over the step that takes it */
    bool pending;
} WorldMpmParticles;
void world_kinematics_mpm_couple(WorldKinematics *k);
bool world_kinematics_mpm_coupled(const WorldKinematics *k);
/* Copies the particles (a no-op when not coupled) and clears pending. DR_ERR_NOMEM. */
DR_NODISCARD DrStatus world_kinematics_set_mpm_particles(WorldKinematics *k, long n, const double *x, const double *v,
                                                         const double *mass, const double *vol0, const double *F,
                                                         DrError *err);
/* The coupled particles, NULL when not coupled. */
WorldMpmParticles *world_kinematics_mpm_particles(WorldKinematics *k);
/* Capture and dripping between the first liquid and the wet hair (DESIGN §8 step 4; world_wet.c explains the step).
   The liquid adapter sets `liquid` when it builds (the first liquid only); the hair adapter, when a wet hair element
   has Capture or Dripping enabled and the scene has a liquid, creates the exchange, points at its film and strands
   and turns it on (both then step at every clock step). The liquid's step runs the exchange at its start, when the
   hair stands where its last step left it, at the same time. The ledger's figures are the bake's, kept in the hair's
   checkpoint. */
typedef struct WorldWetLink {
    bool on;
    DrLiquid *liquid;
    struct DrFilm *film;
    struct DrExchange *exchange;
    const double *x;          /* the strands now (3 nverts) */
    double *v;                /* their velocities (exchanges change them) */
    const double *accel;      /* their acceleration over their last step, m/s² (NULL before the first) */
    const double *mass;       /* the hair's mass per vertex, kg */
    double *submerged;        /* per vertex: how far under the liquid's surface at the last exchange (the bridges) */
    long nverts;
    double t_last;            /* the last exchange's time, s (the bake's start before the first) */
    /* the frame's, m³: what moved between the bulk and the film, and what the drop budget kept back; drops made; the
       exchange's wall time */
    double captured, dripped, held;
    DrVec3 captured_momentum, dripped_momentum; /* kg m/s: what the captured volume took from the bulk, the drops gave */
    long drops, captured_particles;
    double seconds;
    double liquid_work;       /* J: the energy the exchanges brought the liquid since its watch last took it (drops in,
                                 captured volume out), for its stability watch */
    /* the ledger since the bake's start, m³: bulk + film + pools then, and what the liquid's emitters added and its
       kill boxes removed since (the liquid adapter adds its frame's at every frame end) */
    double initial, emitted, removed;
} WorldWetLink;
/* The ledger starts at time t (building a bake from its first frame): its initial volume from the state now, and the
   strands' submersion. DR_ERR_NOMEM. */
DR_NODISCARD DrStatus world_wet_start(WorldWetLink *w, double t, DrError *err);
WorldWetLink *world_kinematics_wet(WorldKinematics *k);
/* The exchange at time t (a no-op unless on): capture over the time since the last one, the particles wholly
   captured removed, then dripping, the drops added to the liquid. DR_ERR_NOMEM, or the liquid's DR_ERR_INPUT. */
DR_NODISCARD DrStatus world_wet_exchange(WorldWetLink *w, double t, DrError *err);
/* The volume of the liquid's particles, of the film on the strands and of their pools, m³. */
void world_wet_volumes(const WorldWetLink *w, double *bulk, double *film, double *pools);

/* Before body i (in the order given to world_kinematics_add_bodies) takes a step from t0: its frame there. After it
   (to t1): its collider carries it through the frame so far, keyed from the frame's start t_frame to t1 (and one key
   past t1 along its velocity), so a solver's step may span several BEM steps; its SDF follows the deformed surface
   when that moved by more than a quarter of an SDF cell since the SDF was built. No-ops without a liquid or hair. */
void world_kinematics_body_begin(WorldKinematics *k, int i);
DR_NODISCARD DrStatus world_kinematics_body_end(WorldKinematics *k, int i, double t_frame, double t0, double t1,
                                                DrError *err);
int world_kinematics_body_rebuilds(const WorldKinematics *k); /* SDF rebuilds of the bodies so far */
/* Two-way bodies (world_kinematics.c explains the scheme): body i is pushed by the first liquid; call once after
   world_kinematics_add_bodies (a no-op when the kinematics keep no collider for it). */
DR_NODISCARD DrStatus world_kinematics_body_couple(WorldKinematics *k, int i, DrError *err);
bool world_kinematics_body_coupled(const WorldKinematics *k, int i);
/* Before the liquid's substep [t, t + h] begins: the two-way bodies predicted over it under gravity, their colliders
   keyed along that motion, and the bodies as the projection takes them (*out: borrowed until the next call; give
   them to dr_liquid_set_bodies after dr_liquid_begin). Returns how many; DR_ERR_NOMEM. */
int world_kinematics_liquid_bodies(WorldKinematics *k, double t, double h, DrLiquidBody **out, DrError *err);
/* After the substep's last projection (before dr_liquid_end): the bodies take the velocities and impulses it gave,
   and their vertices the pressure around them. */
void world_kinematics_liquid_bodies_done(WorldKinematics *k, const DrLiquid *liquid);
/* At the end of body i's step of dt: the traction (3N, body axes at the step's start, Pa) the liquid gave over the
   step, whose resultant force and moment are exactly the gathered impulses over dt, and those (impulse, N s). */
void world_kinematics_body_load(WorldKinematics *k, int i, double dt, double *traction, DrVec3 *impulse);
/* After body i's step ending at t1: its proxy from the body, nothing gathered, its SDF rebuilt if it deformed by more
   than a quarter of an SDF cell since the last build, or if `rebuild` (at every frame end and on resume: the SDF then
   depends on the frame's state alone, so a resumed bake sees the same surface). */
DR_NODISCARD DrStatus world_kinematics_body_synced(WorldKinematics *k, int i, double t1, bool rebuild, DrError *err);
/* The frame cache's collider groups: rotation and translation of each live collider at t. */
DR_NODISCARD DrStatus world_kinematics_write(const WorldKinematics *k, DrH5 *h, double t, DrError *err);

/* ---- the adapters ------------------------------------------------------------------------------------------- */

/* What every adapter may read during a frame. */
typedef struct WorldCtx {
    const DrScene *scene;
    int first_frame;
    double fps;
    DrVec3 gravity;
    int frame;                 /* the frame being advanced (or, writing, the last one completed) */
    double t0, t1;             /* its start and end, s */
    WorldKinematics *kin;      /* colliders posed at the end of the clock step being taken */
} WorldCtx;

/* ---- the stability watch (world_watch.c) ---------------------------------------------------------------------
 * Each adapter measures at the end of every frame its solver's energy (kinetic + elastic + gravitational potential,
 * J), the part of it that could turn into motion (`available`: kinetic, elastic and the potential above the lowest
 * point the solver can reach), and the work done on it in the frame by what moves it from outside (moving colliders
 * and scalps, emitters; gravity is in the potential). world_watch_energy raises an alarm when the energy grew beyond
 * that work by more than 10 % of what was available at the frame's start, or, since the first frame checked, by
 * more than 10 % of what was available then (plus `floor`, an absolute allowance for round-off near rest). An alarm
 * is a warning naming the element, the frame and the fix, or, with solver.on_instability "fail", DR_ERR_RUNTIME with
 * that message (bake exits 1). */
typedef struct WorldEnergy {
    double energy;           /* J */
    double available;        /* J, >= 0 */
    double work;             /* J, done on the solver within the frame (world_watch_energy) */
    double floor;            /* J, absolute allowance */
} WorldEnergy;
typedef struct WorldWatch {
    bool fail;               /* solver.on_instability is "fail" */
    bool have;               /* a frame was checked since world_watch_start */
    int first_frame;         /* the frame whose start is the cumulative reference */
    WorldEnergy start;       /* the energy at the start of the frame being advanced */
    WorldEnergy first;       /* ... and at the start of first_frame */
    double work_total;       /* J, the work summed since then */
    bool cumulative_only;    /* check against first only (a solver whose measured energy leaves a part out that may
                                turn back into it: the BEM bodies' rigid motion after a bounce) */
} WorldWatch;
void world_watch_init(WorldWatch *w, const DrScene *scene);
/* The state at the start of frame `frame` (after building or restoring): the reference of the next check. */
void world_watch_start(WorldWatch *w, int frame, const WorldEnergy *e);
/* Checks a frame's end (e->work: the work of the frame); the frame's end becomes the next frame's start. `element`
   names what is checked (e.g. "mpm_solid 'ball'"), `fix` says what to change. */
DR_NODISCARD DrStatus world_watch_energy(WorldWatch *w, const WorldCtx *c, const WorldEnergy *e, const char *element,
                                         const char *fix, DrError *err);
/* The frame against the solver's step: DR_ERR_INPUT naming shot.fps and solver.max_substeps when a frame of 1/fps
   needs more than max_substeps substeps of `step` (s; the step the solver cannot exceed as soon as anything moves,
   `why` says which), which the solver would otherwise stretch until it falls through its domain. */
DR_NODISCARD DrStatus world_watch_frame_length(const WorldCtx *c, const char *element, double step, const char *why,
                                               DrError *err);
/* A warning, or with solver.on_instability "fail" DR_ERR_RUNTIME, carrying message (for other watches: volume). */
DR_NODISCARD DrStatus world_watch_alarm(const WorldWatch *w, const char *message, DrError *err);

/* One solver of the scene as the orchestrator drives it. Every callback gets `self`, the adapter's own struct. */
typedef struct WorldSolver {
    const char *name;
    void *self;
    bool lockstep;           /* steps at every clock step (the liquid that two-way BEM bodies take part in) */
    /* The frame begins: per-frame sums are zeroed. */
    void (*begin_frame)(void *self, const WorldCtx *c);
    /* The end time of the solver's next step from t towards the frame end (its stable_dt turned into steps that
       land on c->t1); exactly c->t1 when it can reach it. NULL: no limit of its own. */
    DR_NODISCARD DrStatus (*next_time)(void *self, const WorldCtx *c, double t, double *t_next, DrError *err);
    /* The first time after t the clock must land on (a BEM step end), INFINITY if none. NULL: none. */
    double (*landing)(const void *self, const WorldCtx *c, double t);
    /* Called before the kinematics of a clock step from t to t_next (BEM bodies take their whole step here, at its
       start, so that the solvers stepped after them see the bodies' motion through the step). NULL: nothing. */
    DR_NODISCARD DrStatus (*step_first)(void *self, const WorldCtx *c, double t, double t_next, DrError *err);
    /* Called after every solver stepped a clock step from t to t_next (two-way BEM bodies take the step that ends
       there, loaded with what the liquid gave them over it). NULL: nothing. */
    DR_NODISCARD DrStatus (*step_last)(void *self, const WorldCtx *c, double t, double t_next, DrError *err);
    /* Advances from t to t_next (predict, solve without coupling forces, commit). NULL: nothing. */
    DR_NODISCARD DrStatus (*step)(void *self, const WorldCtx *c, double t, double t_next, DrError *err);
    /* The frame ended: non-finite checks, warnings, the solver's block of stats. */
    DR_NODISCARD DrStatus (*end_frame)(void *self, const WorldCtx *c, DrFrameStats *stats, DrError *err);
    /* Frame cache (frame_cache) or checkpoint contents; restore from a checkpoint taken after `frame`. */
    DR_NODISCARD DrStatus (*write)(const void *self, const WorldCtx *c, DrH5 *h, bool frame_cache, DrError *err);
    DR_NODISCARD DrStatus (*read)(void *self, const WorldCtx *c, DrH5 *h, const char *path, int frame, DrError *err);
    void (*hash)(const void *self, DrHasher *h);
    void (*destroy)(void *self);
    /* ---- the coupled step (DESIGN §8 step 3, world.c; src/couple): NULL for a solver that does not take part ---- */
    /* A fluid: begins its step from t (where its next_time was asked) to t_next and describes itself in *fluid for
       the loop; fluid_end ends the step with the loop's last projection. */
    DR_NODISCARD DrStatus (*fluid_begin)(void *self, const WorldCtx *c, double t, double t_next, DrCoupleFluid *fluid,
                                         DrError *err);
    DR_NODISCARD DrStatus (*fluid_end)(void *self, const WorldCtx *c, DrError *err);
    /* A fluid's density (kg/m³) and dynamic viscosity (Pa·s), for the solids' step limits. */
    void (*fluid_properties)(const void *self, double *density, double *viscosity);
    /* A solid: whether it takes part in this scene; predicts its step from t to t_next and describes itself in *solid;
       solid_commit commits the loop's last solve. */
    bool (*couples)(const void *self);
    DR_NODISCARD DrStatus (*solid_predict)(void *self, const WorldCtx *c, double t, double t_next,
                                           DrCoupleSolid *solid, DrError *err);
    DR_NODISCARD DrStatus (*solid_commit)(void *self, const WorldCtx *c, double t, double t_next, DrError *err);
    /* A solid's limit on the coupled step in that fluid (its explicit forces: lift), s; INFINITY if none. */
    double (*solid_stable_dt)(const void *self, double density, double viscosity);
} WorldSolver;

/* The adapters' constructors: each fills *out (out->self NULL when the scene has nothing for it) and logs nothing.
   The BEM bodies are built first (the liquid seeds no particle inside them), then the liquids, MPM, hair, cloth and
   air. */
DR_NODISCARD DrStatus world_bem_adapter(const WorldCtx *c, const char *cache_root, WorldSolver *out, DrError *err);
/* The bodies' solids and elements (borrowed), for the kinematics; 0 without bodies. */
/* Whether body i (world_bem_solids' order) is two-way with the liquid (BemSolver.liquid_coupling, a liquid present). */
bool world_bem_coupled(const WorldSolver *bem, int i);
int world_bem_solids(const WorldSolver *bem, const DrBemSolid *const **solids, const DrElement *const **elements);
DR_NODISCARD DrStatus world_liquid_adapter(const WorldCtx *c, const DrElement *e, WorldSolver *out, DrError *err);
const DrLiquid *world_liquid_solver(const WorldSolver *s);
DR_NODISCARD DrStatus world_mpm_adapter(const WorldCtx *c, WorldSolver *out, DrError *err);
long world_mpm_particles(const WorldSolver *s);
const DrMpm *world_mpm_solver(const WorldSolver *s);
int world_mpm_bodies(const WorldSolver *s);
DR_NODISCARD DrStatus world_lagrangian_adapter(const WorldCtx *c, const char *cache_root, WorldSolver *out,
                                                DrError *err);
void world_lagrangian_hair_counts(const WorldSolver *s, int *strands, int *vertices);
/* The scene's cloth elements, each a panel of src/cloth (out->self NULL without any), and their vertices. */
DR_NODISCARD DrStatus world_cloth_adapter(const WorldCtx *c, WorldSolver *out, DrError *err);
long world_cloth_vertex_count(const WorldSolver *s);
void world_bem_counts(const WorldSolver *s, int *bodies, long *vertices, int *sets);
/* The scene's air element (at most one; out->self NULL without one), stepped alone with the scene's colliders (not the
   bem_solid bodies), and its solver for a coupling loop or a test (NULL when s holds none). */
DR_NODISCARD DrStatus world_air_adapter(const WorldCtx *c, WorldSolver *out, DrError *err);
typedef struct DrAir DrAir;
DrAir *world_air_solver(const WorldSolver *s);

#endif
