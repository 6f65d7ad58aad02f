/* DrWorld: builds only the solvers a scene's elements need and advances the shot one frame at a time on one clock
 * (README "How a frame is stepped"); frame caches and checkpoints (DESIGN §4). The command-line plumbing the four
 * stage executables share is src/stage's.
 *
 * Time: the initial state is t = 0; shot frame f holds the state at t = (f − f_first + 1)/fps, so a 48-frame
 * shot at 24 fps ends at t = 2 s. Motion keys use the same frame numbering (frame f_first − 1 is t = 0).
 * Thread safety: one world per thread; the solvers inside use dr_parallel_for themselves. */
#ifndef DR_WORLD_H
#define DR_WORLD_H

#include "bem/bem.h"
#include "core/core.h"
#include "io/io.h"
#include "scene/scene.h"

typedef struct DrWorld DrWorld;

/* What one frame cost and did (progress.jsonl, report.json, the frame cache's diagnostics): a common part, then one
 * block per solver kind, each written by that solver's adapter (all zero, present false, when the scene has none). */
typedef struct DrLiquidFrameStats {
    bool present;
    int substeps;            /* the largest substep count of a liquid element */
    long particles;          /* every liquid element's */
    int pressure_iterations_max;
    long pressure_iterations_total;
    int pressure_not_converged;
    double volume, volume0;  /* m³: liquid cells × dx³ now and in the first frame (a cheap frame-to-frame estimate) */
    double drift;            /* volume / volume0 − 1 */
    double particle_volume;  /* m³: Σ of the particles' own volumes (DrLiquidState.vol: dx³ / Particles.per_cell as
                                seeded or emitted, less what a caller took from them): the liquid's volume as the
                                particles carry it, which emitters and kill boxes change */
    double emitted_volume, killed_volume; /* m³: what emitters added and kill boxes removed in the frame */
    double kinetic_energy;   /* J */
    double seconds_p2g, seconds_pressure, seconds_g2p, seconds_advect, seconds_other;
    /* the MPM solids two-way with the first liquid: the momentum they gained from it in the frame (N·s, the ledger:
       what their particles received), the momentum the liquid's grid phases gave the liquid (DrLiquidStats'
       grid_linear_impulse; with no gravity, walls or colliders the two add to the projection's residual), and the
       liquid particles pushed out of the solids */
    DrVec3 mpm_impulse, grid_impulse;
    long mpm_pushed;
} DrLiquidFrameStats;

typedef struct DrMpmFrameStats {
    bool present;
    long particles;
    int substeps;
    long newton_iterations, cg_iterations; /* summed over the frame's substeps */
    double newton_residual;  /* last relative Newton residual */
    int not_converged;       /* 1 when a Newton iteration of the frame stopped at its cap (a warning) */
    double kinetic_energy, elastic_energy, gravity_energy; /* J: ½Σmv², ΣV₀Ψ(F), −Σm g·x */
    DrVec3 momentum, angular_momentum; /* kg·m/s, kg·m²/s about the origin (with the affine part) */
    double seconds_transfer, seconds_solve;
} DrMpmFrameStats;

typedef struct DrHairFrameStats {
    bool present;
    long vertices;
    int substeps;
    long cg_iterations;      /* summed over the frame's substeps */
    double residual;         /* last relative residual */
    int not_converged;       /* substeps whose solve stopped at its cap (a warning) */
    int collider_contacts, contacts; /* of the last substep */
    bool meets_cloth;        /* a collision element pairs the hair with cloth */
    int cloth_contacts;      /* rows between hair vertices and cloth triangles of the last substep */
    double kinetic_energy, elastic_energy, gravity_energy; /* J */
    double scalp_work;       /* J: done on the strands through their held roots (and tips) over the frame */
    double max_speed;        /* m/s: the largest |v| of a vertex at the frame's end */
    double max_speed_growth; /* the largest ratio of a step's max |v| to the step before's over the frame (the first
                                from the frame's start; steps from rest, max |v| = 0, are not counted; 0 if none) */
    double seconds;
    /* wet hair (all zero without a Wetting component): at the frame's end */
    bool wet;
    double film_volume, pool_volume;   /* m³ on the strands and gathered at their ends */
    double film_max_ratio;             /* the largest H/r */
    int bridges, solid_bridges;        /* of the last substep */
    int film_substeps;                 /* summed over the frame */
    double cross_flow;                 /* m³ moved across bridges in the frame */
    DrVec3 film_pressure_impulse;      /* N·s: the bulk's pressure on the film and pools over the frame (coupled) */
    double film_kinetic_energy;        /* J */
    double film_gravity_energy;        /* J: −Σ ρ V g·x of the film and the pools */
    double seconds_film;               /* the film's steps along the strands */
    double seconds_bridges;            /* finding the bridges, their rows in the system, the film's load on it */
    double seconds_cross_flow;         /* the film's flow across bridges and its exchange with the strands */
    /* capture and dripping with the first liquid (Capture, Dripping; all zero without): the frame's transfers and
       the volume ledger at its end, m³. bulk + film + pools + removed − emitted is the initial volume (bulk: the
       liquid's particles; removed: by kill boxes since the bake's start; emitted: by emitters since then) */
    bool exchange;
    double captured, dripped;          /* m³ moved in the frame */
    DrVec3 captured_momentum, dripped_momentum; /* kg m/s the bulk gave the film with it, the drops took from the film */
    long drops, captured_particles;    /* drops made, particles wholly captured (removed from the liquid) */
    double held_back;                  /* m³ the drop budget kept on the strands in the frame (a warning) */
    double ledger_bulk, ledger_emitted, ledger_removed, ledger_total, ledger_initial;
    double ledger_error;               /* (total − initial) / max(initial, bulk + film + pools + removed) */
    double seconds_exchange;           /* capture and dripping (not part of `seconds`) */
} DrHairFrameStats;

typedef struct DrBemFrameStats {
    bool present;
    int bodies;
    int substeps;            /* the most steps a body took in the frame */
    long steps;              /* steps of every body in the frame */
    double kinetic_energy, potential_energy; /* J: of the bodies' rigid frames, −Σ m g·T */
    DrVec3 momentum;         /* kg·m/s, Σ m Ṫ */
    double max_displacement; /* m: the largest |u| of any body's vertex */
    double translation_error, rotation_error; /* m, rad: the largest drift error correction moved in a step */
    double seconds_history, seconds_solve, seconds_correction;
    /* their constraints (BEM §3.4; all zero when no group of bodies has any): counts of the frame's last step */
    int contacts, body_contacts, fixed, joints;
    long pgs_iterations;     /* PGS sweeps, summed over the frame's steps */
    double residual;         /* m: the largest after a step */
    int not_converged;       /* steps kept above the tolerance (a warning) */
    double seconds_trial, seconds_detect, seconds_assembly, seconds_pgs, seconds_final;
    DrVec3 liquid_impulse;   /* N s: what the liquid's pressure gave the two-way bodies in the frame */
} DrBemFrameStats;

typedef struct DrClothFrameStats {
    bool present;
    int panels;
    long vertices;
    int substeps;            /* cloth steps in the frame (every panel takes the same) */
    long cg_iterations;      /* summed over the panels' solves in the frame */
    int not_converged;       /* solves stopped at ClothSolver.max_iterations (a warning) */
    int collider_contacts;   /* vertex contacts of the last step, every panel */
    int self_contacts;       /* vertex–triangle contacts of the panels with themselves, last step */
    double kinetic_energy, membrane_energy, bending_energy, gravity_energy; /* J, at the frame's end */
    double max_speed;        /* m/s, the fastest vertex at the frame's end */
    double seconds;
} DrClothFrameStats;

typedef struct DrFrameStats {
    int frame;
    double time;             /* s, at the end of the frame */
    int substeps;            /* largest substep count of any solver this frame */
    int clock_steps;         /* steps of the world's clock (every solver's steps land on its times) */
    double kinetic_energy;   /* J, every solver (liquid, MPM, hair, the BEM bodies' frames) */
    double seconds;          /* wall time of the frame */
    double seconds_io;       /* set by the caller that writes the frame */
    DrLiquidFrameStats liquid;
    DrMpmFrameStats mpm;
    DrHairFrameStats hair;
    DrBemFrameStats bem;
    DrClothFrameStats cloth;
    /* The coupled loop between hair with a Drag component and the liquid (src/couple), over the frame: steps,
       iterations (solid solves), steps that stopped at solver.coupling_iterations with the change above
       solver.coupling_tolerance, the largest final relative change, and the momentum ledger: what the hair received
       (drag, lift, buoyancy) and what the liquid was given, N·s, whose sum is zero to round-off. */
    struct {
        int steps, iterations_max, not_converged;
        long iterations, elements;
        double change_max, seconds;
        DrVec3 solid_impulse, fluid_impulse;
    } coupling;
} DrFrameStats;

/* Loads every asset the scene references (meshes through assimp, collider SDFs through OpenVDB) and builds
 * the solvers. All bad input (broken asset, empty or open mesh, NaN, a body outside its domain) is reported
 * here, before anything is written. A scene without liquid creates no liquid grid; a scene without
 * mpm_solid elements creates no MPM solver; a scene without hair creates no rod solver (and a scene with hair
 * but neither liquid nor MPM creates no grid: its colliders' SDFs are sampled at the hair's segment length). Every mpm_solid shares one DrMpm: its grid spans the bounding
 * box of their Domain boxes at their (equal) voxel_size; the scene colliders act on its grid velocities.
 * Every bem_solid reads its matrices from the precompute cache (bodies with one cache key share one set); a body
 * whose matrices are not there is DR_ERR_INPUT naming the element and the key (run precompute first). A scene
 * of bem_solid bodies (and colliders) builds no grid. */
typedef struct DrWorldDesc {
    const char *cache_root; /* precompute cache: <cache_root>/bem/<key>.h5 (default "cache") */
} DrWorldDesc;
void dr_world_desc_default(DrWorldDesc *d);
DR_NODISCARD DrStatus dr_world_create_desc(const DrScene *scene, const DrWorldDesc *d, DrWorld **out, DrError *err);
/* dr_world_create_desc with dr_world_desc_default. */
DR_NODISCARD DrStatus dr_world_create(const DrScene *scene, DrWorld **out, DrError *err);
void dr_world_destroy(DrWorld **world);

int dr_world_first_frame(const DrWorld *w);
int dr_world_last_frame(const DrWorld *w);
int dr_world_frame(const DrWorld *w);      /* last completed frame; first_frame − 1 before any step */
double dr_world_frame_time(const DrWorld *w, int frame);
int dr_world_liquid_count(const DrWorld *w);
long dr_world_hair_vertex_count(const DrWorld *w); /* 0 when the scene has no hair */
long dr_world_cloth_vertex_count(const DrWorld *w); /* 0 when the scene has no cloth */
long dr_world_mpm_particle_count(const DrWorld *w); /* 0 when the scene has no MPM solver */
typedef struct DrMpm DrMpm;
const DrMpm *dr_world_mpm(const DrWorld *w);        /* the MPM solver, NULL when there is none */
/* The i-th liquid solver (element order) and its element, for diagnostics and tests. */
typedef struct DrLiquid DrLiquid;
const DrLiquid *dr_world_liquid(const DrWorld *w, int i);
const DrElement *dr_world_liquid_element(const DrWorld *w, int i);
/* The bem_solid bodies in element order (0 and NULL without any). */
int dr_world_bem_count(const DrWorld *w);
const DrBemSolid *dr_world_bem_solid(const DrWorld *w, int i);
/* Colliders whose SDF was built (none when no solver samples colliders). */
int dr_world_live_collider_count(const DrWorld *w);

/* Advances to the next frame. Warnings (a pressure solve that did not converge) are logged and counted in
 * stats; DR_ERR_RUNTIME when a solver produced non-finite values. */
DR_NODISCARD DrStatus dr_world_step_frame(DrWorld *w, DrFrameStats *stats, DrError *err);

/* Frame cache (DESIGN §4), written into h, a write handle (dr_h5_create, or dr_h5_create_deferred to have it
 * written later or on another thread) that the caller commits, or closes on failure, so the file appears
 * atomically or not at all. Its datasets are stored as DR_H5_COMPRESS_ONE_VALUE says (contiguous, except those
 * of one value). Root attributes drench_version, frame, time, substeps,
 * scene_key; one group per element; /diagnostics. An mpm_solid element's group holds its particles:
 * position (N×3, m), velocity (N×3, m/s), affine (N×3×3, 1/s: the APIC matrix C, zero for PIC/FLIP),
 * deformation_gradient (N×3×3, 1), volume (N, m³: rest volume V₀; the current one is det(F)·V₀), with
 * attributes type "mpm_solid" and particle_spacing (m); /diagnostics/<element> its totals and
 * /diagnostics/mpm_* those of the solver. A hair element's group holds position (V×3, m), velocity (V×3, m/s),
 * twist (E, rad: each edge's material angle from its reference frame), strand_offsets (S+1, int64: strand s
 * is vertices offsets[s] .. offsets[s+1]−1, root first) and radius (S, m), with attribute type "hair";
 * /diagnostics/hair_* the solver's figures. A bem_solid element's group holds its frame and displacement, so that
 * the surface is V = R·(reference + displacement) + translation with nothing else: rotation (3×3, 1: R, row-major),
 * translation (3, m: T, where the centre of mass is), velocity (3, m/s: Ṫ), angular_velocity (3, rad/s: ω, world
 * frame), displacement (N×3, m: u in the body frame), reference (N×3, m: rest vertices about the centre of mass,
 * x − x̄), triangles (M×3, int32: counter-clockwise seen from outside), with attributes type "bem_solid" and
 * time_step (s); /diagnostics/<element> the body's linear_momentum, angular_momentum (about its centre of mass),
 * kinetic_energy and potential_energy of its frame, volume (m³, of the deformed surface), max_displacement, steps
 * (this frame) and time_step; /diagnostics/bem_* their sums (the largest max_displacement, angular momentum about
 * the origin). */
DR_NODISCARD DrStatus dr_world_write_frame(const DrWorld *w, const DrFrameStats *stats, const char *bake_key,
                                           DrH5 *h, DrError *err);
/* Checkpoint: everything a bit-identical continuation needs (particles in their current order, rng states,
 * MPM positions, velocities, affine matrices and deformation gradients, hair state, each bem_solid's
 * dr_bem_solid_state_get array and step count, frame), written into h as the frame cache is. Read refuses a checkpoint whose bake key differs, or whose
 * arrays or step counts do not fit the scene (DR_ERR_INPUT, with what to do). */
DR_NODISCARD DrStatus dr_world_write_checkpoint(const DrWorld *w, const char *bake_key, DrH5 *h, DrError *err);
DR_NODISCARD DrStatus dr_world_read_checkpoint(DrWorld *w, const char *path, const char *bake_key,
                                               DrError *err);
/* Hash of the whole simulation state (for determinism tests and logs). */
DrHash dr_world_state_hash(const DrWorld *w);

#endif
