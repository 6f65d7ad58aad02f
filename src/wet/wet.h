/* drench wet: liquid carried on hair (fei2017 §S1–S3, §S5; PHYSICS §5): the cohesion tables of capillary bridges,
 * the film on every strand, the bridges between strands and against solids, and the flow of film across bridged
 * strands. `wet` never includes the liquid (DESIGN §8): bulk liquid reaches it only as neutral batches of particles.
 *
 * Units SI throughout: m, s, kg; σ in N/m, μ in Pa·s, angles in radians. Thread safety: one object per thread of
 * control; loops run through dr_parallel_for, bit-identically for any thread count. */
#ifndef DR_WET_H
#define DR_WET_H

#include "core/core.h"
#include "io/io.h"
#include "hair/hair.h"
#include "lagrangian/lagrangian.h"

/* ---- cohesion tables (fei2017 §S1, §S3) -----------------------------------------------------------------------
 * A liquid bridge between two parallel cylinders of radius r whose axes are d apart (or between a cylinder whose axis
 * is d above a plane and the plane), seen in the plane across them: bounded by the solids and by two circular menisci
 * of radius R meeting each solid at the contact angle θ at the wetting half-angle α (the angle, at a cylinder's axis,
 * between the line to the other solid and the contact line). Its cross-section area A(α, d) and surface energy per
 * unit length E(α, d) = σ (l_A + l_S cos θ) (eq. S4: l_A the menisci's arc length, l_S the dry solid perimeter) are
 * closed forms. The table holds F = ∂E/∂d at constant A over a grid of (d, A): the force per unit length pulling the
 * two together (N/m; > 0 attracts), ∂E/∂d|_A = ∂E/∂d + ∂E/∂α · dα/dd|_A, dα/dd|_A = −(∂A/∂d)/(∂A/∂α). F is not
 * clamped: a bridge that nearly engulfs two touching solids (convex menisci) pushes them apart (F < 0).
 *
 * Scaling: with d = r d̃, A = r² Ã, E = σ r Ẽ, the geometry depends on (θ, d̃, Ã) only and F = σ F̃(d̃, Ã): one table per
 * contact angle serves every radius and every surface tension. What does not scale: the contact angle (one table
 * each); two cylinders of different radii (their bridge is not symmetric): drench evaluates such a pair on the table
 * at the mean radius, exact for equal radii and, the force being symmetric in the two radii, second-order accurate in
 * their difference; and gravity, which circular menisci leave out: a bridge must be small against the capillary length
 * √(σ/(ρ g)) (2.7 mm for water; Ã_max below at r = 50 µm is a bridge about 0.75 mm across). The table is stored
 * nondimensional.
 *
 * The grid: resolution columns d̃_i = d̃_min + (d̃_max − d̃_min) s_i² and rows Ã_j = Ã_max s_j², s_k = k/(resolution − 1):
 * quadratic axes, finest at small gaps and small bridges, where F̃ changes fastest (and diverges at the corner of
 * touching solids and a vanishing bridge). */

#define DR_COHESION_VERSION "cohesion-2" /* changes whenever a table's numbers would change */

typedef enum DrCohesionShape {
    DR_COHESION_CYLINDERS, /* two parallel cylinders of one radius, axes d apart: d̃ ≥ 2 */
    DR_COHESION_PLANE      /* a cylinder whose axis is d above a plane: d̃ ≥ 1 */
} DrCohesionShape;

typedef struct DrCohesionDesc {
    DrCohesionShape shape;
    double contact_angle; /* θ, rad, in [0, π/2); default 40° */
    int resolution;       /* samples per axis of the (d̃, Ã) grid, in [16, 4096]; default 256 */
    double max_area;      /* Ã_max, the largest bridge area in units of r²; > 0; default 2π(6² − 1) (two films at
                             H/r = 6) */
    double max_gap;       /* d̃_max − d̃_min, the range of gaps in units of r; > 0, or 0 (the default) for the rupture
                             gap at Ã_max and this desc's θ, (1 + θ/2)√Ã_max (0 rather than a number, so that setting θ
                             after dr_cohesion_desc_default leaves no stale range) */
} DrCohesionDesc;
void dr_cohesion_desc_default(DrCohesionDesc *d);

typedef struct DrCohesionTable DrCohesionTable;

/* Builds the table: per d̃ column, A(α) on [α_0, π − θ] where α_0 is the smallest angle at which the bridge closes
 * (its neck has positive height), inverted at each Ã by Newton within a bisection bracket; F̃ from the derivatives of
 * the closed forms (complex step). A column keeps only the part of [α_0, π − θ] where A increases with α, so A(α) is
 * monotone in every column; (d̃, Ã) with too little area to span the gap get F̃ = 0 and are marked invalid (0), and
 * those with more liquid than the largest bridge at that gap holds (Ã above A(α_1)) get that bridge's force, marked
 * saturated (2): the liquid beyond it wets the pair no further (it stays in the films), and the force stays smooth
 * across the edge instead of falling to zero where a thick film meets a close neighbour. The table records a self-check (the interpolation error at cell
 * centres, in the file). Bit-identical for any thread count. DR_ERR_INPUT for a desc out of range (naming the field).
 * Takes well under a second at 256². */
DR_NODISCARD DrStatus dr_cohesion_build(const DrCohesionDesc *desc, DrCohesionTable **out, DrError *err);
void dr_cohesion_destroy(DrCohesionTable **t);
/* The table's desc, max_gap resolved (> 0). */
const DrCohesionDesc *dr_cohesion_desc(const DrCohesionTable *t);

/* F̃(d̃, Ã), bilinear in the table (in the fractional column and row indices); 0 outside the table's range. Invalid
 * nodes hold 0, so over the last cell at the edge of the bridge region F̃ falls linearly to 0 (rupture smoothed over
 * one cell; under 1 % of the region at 256²) and is 0 beyond it. Within cells whose four nodes hold bridges a 256²
 * table (θ from 20° to 60°, default ranges) is within 1 % of F̃ (of max(|F̃|, 1), as F̃ changes sign) and 4× closer at
 * 512², except in the corner of nearly touching solids and a vanishing bridge, Ã < 0.2 with d̃ < d̃_min + 0.5 (films
 * thinner than H ≈ 1.03 r), where F̃ grows without bound (≈ 4 cos θ / α) and the first cells err by up to 13 %
 * (tests/unit/test_cohesion.c). */
double dr_cohesion_eval(const DrCohesionTable *t, double d_nd, double area_nd);
/* The force per unit length (N/m) of a bridge of area A (m²) between solids of radius r (m) at distance d (m), surface
 * tension σ (N/m): σ F̃(d/r, A/r²). */
double dr_cohesion_force(const DrCohesionTable *t, double r, double sigma, double d, double area);

/* The closed forms, nondimensional (r = 1, σ = 1), for tests and for building: the bridge area Ã and energy Ẽ at
 * wetting half-angle α and gap d̃ (Ẽ up to a constant that does not depend on α or d̃). Returns false where the
 * geometry has no bridge (the menisci cross, the solids overlap, or α out of [0, π − θ]). */
bool dr_cohesion_geometry(DrCohesionShape shape, double theta, double alpha, double d_nd, double *area_nd,
                          double *energy_nd);

/* The cache key (DESIGN §5): a hash of shape, θ, resolution, Ã_max, gap range (max_gap resolved) and the table code's
 * version (DR_COHESION_VERSION), as 32 hex digits (+ NUL): the XXH3-128 of dr_cohesion_inputs_json, the canonical
 * JSON of those inputs (keys sorted, numbers %.17g, no spaces) that the file records as its "inputs" attribute. Any
 * desc gives a key (a desc out of range is refused by dr_cohesion_build, not here). */
#define DR_COHESION_JSON_MAX 256
void dr_cohesion_key(const DrCohesionDesc *desc, char key_hex[33]);
void dr_cohesion_inputs_json(const DrCohesionDesc *desc, char json[DR_COHESION_JSON_MAX]);
/* Writes the table into a precompute cache file (io.h dr_io_precache_create, kind "cohesion", the key and inputs
 * above, no asset hash): group /cohesion with datasets force (resolution² F̃, row-major d̃ slowest), valid (int32,
 * 1 where a bridge exists), gap and area (the axes: d̃ of each column, Ã of each row), and self-describing attributes
 * (cohesion_version, shape, contact angle in degrees and radians, ranges, resolution, units "1": nondimensional, how
 * to scale, the grid's formula, the self-check). The caller commits the file. */
DR_NODISCARD DrStatus dr_cohesion_write(const DrCohesionTable *t, DrH5 *h, DrError *err);
/* Reads a table written by dr_cohesion_write (bit-identical); DR_ERR_INPUT naming the file (path) for a file of
 * another version, a shape, resolution or range out of range, datasets of other sizes than the resolution, or values
 * that cannot be (non-finite, a force where no bridge is). */
DR_NODISCARD DrStatus dr_cohesion_read(DrH5 *h, const char *path, DrCohesionTable **out, DrError *err);
/* The table of desc from cache_root/cohesion/<key>.h5; DR_ERR_INPUT "run precompute" naming the file when it is
 * missing (or unreadable, or of another key), DR_ERR_INPUT naming the file when it records other parameters than
 * desc; a bad desc as dr_cohesion_build. */
DR_NODISCARD DrStatus dr_cohesion_load(const char *cache_root, const DrCohesionDesc *desc, DrCohesionTable **out,
                                       DrError *err);

/* ---- the film on every strand (fei2017 §S2, eqs. S9–S17) ------------------------------------------------------
 * Per strand s (vertices o = offsets[s] .. offsets[s+1] − 1, edges one fewer, numbered as in hair.h): film volume per
 * vertex V_i (m³; the vertex's control volume is its Voronoi length l_i = half of each adjacent edge, and its
 * cross-section area A_i = V_i / l_i = π (H_i² − r_i²), H the film's outer radius), and per edge the film's tangential
 * speed relative to the strand u_e (m/s, positive from root to tip), and a pool at the root and one at the tip (m³):
 * liquid gathered at an end, moving with that end vertex.
 *
 * Momentum. The film's mass on edge e is ρ V̂_e, V̂_e = V_i l_e/(2 l_i) + V_{i+1} l_e/(2 l_{i+1}) (the parts of the
 * two vertices' control volumes that lie on the edge: Σ_e V̂_e = Σ_i V_i), moving with the strand across it and with
 * its own speed along it: velocity v̄_e + u_e t_e (v̄_e the mean of the edge's vertex velocities, t_e its unit tangent).
 * The strand carries the film across itself: in the strand's solve each vertex i gets the extra inertia
 * B_i = Σ_{e∋i} ½ ρ V̂_e (I − t_e t_eᵀ) + ρ (pool volume at i) I and the film's (and pools') weight across the strand
 * (dr_film_hair_load); along the strand the film moves only by its own forces (gravity along t, the Laplace pressure
 * −σ ∂²h/∂s², friction with the strand). The momentum of strands + film,
 *     P = Σ_i m_i v_i + Σ_e ρ V̂_e (v̄_e + u_e t_e) + Σ_pools ρ V_pool v_end,
 * changes only by external forces: every exchange below (friction, a strand turning under its film, film flowing
 * from one vertex to the next and carrying the strand velocity where it came from, eq. S17, liquid reaching a pool)
 * is applied as equal and opposite momentum through per-vertex 3×3 solves. The film's speed relative to the strand
 * then follows the strand's own acceleration with the opposite sign: the fictitious force of the strand's frame.
 *
 * Volume. Continuity (S9) is solved in finite-volume form (edge fluxes, upwind), so Σ V_i + pools changes only by
 * what is added or removed; the film step is subcycled so that no vertex sends out more than it holds (the height
 * never goes negative and is never clamped). A vertex whose film would exceed the largest the strand holds
 * (H/r above max_ratio) sends the excess to the nearer pool. */

typedef struct DrFilmDesc {
    double density;         /* ρ_L, kg/m³, > 0; default 1000 */
    double viscosity;       /* μ, Pa·s, > 0; default 1e-3 */
    double surface_tension; /* σ, N/m, ≥ 0; default 0.072 */
    double max_ratio;       /* largest H/r a vertex holds, > 1; default 6 */
    double friction;        /* scale on the film–strand friction law, ≥ 0; default 1 */
    int substeps;           /* film substeps per strand step at least, ≥ 1; default 1 (more when the film's CFL
                               needs them) */
    DrVec3 gravity;         /* m/s², default (0, −9.81, 0) */
} DrFilmDesc;
void dr_film_desc_default(DrFilmDesc *d);

typedef struct DrFilm DrFilm;

/* A film on the strands described by offsets (nstrands + 1, as hair.h) and the vertex radii radius (per vertex, m), at
 * rest relative to the strands, with the initial outer radius H = initial_ratio · r at every vertex (per strand:
 * initial_ratio[s] ≥ 1; 1 is a dry strand). Copies what it keeps. DR_ERR_INPUT for a desc or ratio out of range. */
DR_NODISCARD DrStatus dr_film_create(const DrFilmDesc *desc, int nstrands, const int *offsets, const double *radius,
                                     const double *rest_x, const double *initial_ratio, DrFilm **out, DrError *err);
void dr_film_destroy(DrFilm **f);

/* The hot arrays (owned by the film; the caller may overwrite them between steps, e.g. from a checkpoint). */
typedef struct DrFilmState {
    int nstrands, nverts, nedges;
    double *volume;   /* nverts, m³ */
    double *u;        /* nedges, m/s */
    double *pool;     /* 2 nstrands: root pool, tip pool of each strand, m³ */
    double *strand_speed; /* nedges, m/s: the strands' speed along each edge, v̄_e·t_e, when the film last saw them (the
                             end of its last step or exchange; 0 at create: strands start at rest). The strands' solve
                             changes v̄_e·t_e without the film, so a step needs the value before it to keep the film's
                             own speed along the strand, u_e + v̄_e·t_e, and turn the change into the fictitious force.
                             Part of the state a checkpoint keeps. */
} DrFilmState;
DrFilmState dr_film_state(DrFilm *f);

/* The film's share of the strands' next solve, for hair positions x and velocities v (nverts × 3) at the start of a
 * step of h seconds: per vertex the extra inertia B_i (above) as the load of dr_rod_set_solve,
 *     force_i += B_i v_i / h + (the film's and pool's weight across the strand),  dforce_dv_i += −B_i / h,
 * added into force (3 nverts) and dforce_dv (9 nverts). */
void dr_film_hair_load(const DrFilm *f, const double *x, const double *v, double h, double *force, double *dforce_dv);

/* The bulk liquid's pressure on the film and pools over the next step of h seconds (fei2017 §4.3: the pressure's
 * impulse on the film and, through the film, on the strand), for the gradient gradp (nverts × 3, Pa/m; 0 where no bulk
 * is) at the strands' positions x at the step's start (as dr_film_hair_load's): each vertex's film and pools feel
 * −V ∇p, split as their weight is, so that a film under still bulk liquid is neutral (∇p = ρ g: it neither drains
 * along the strand nor weighs it down):
 *  - across each edge, half of the edge's −V̂_e ∇p_i (I − t_e t_eᵀ) at each vertex i, and a pool's whole −V ∇p, added
 *    into force (3 nverts) as the load of the strands' solve;
 *  - along each edge, −V̂_e (t_e·∇p̄_e) t_e (∇p̄_e the mean of its two vertices'), kept by the film as a change of its
 *    speed along the strand that dr_film_step applies before it flows (at the start of the step, like the momentum
 *    the step realigns: exactly that impulse, whatever the step then does; a second call before the step replaces it).
 * impulse (3 nverts, overwritten) takes every vertex's share of the whole, h F_i with half of each edge's along part:
 * what the strands and film receive from the bulk over the step, for the bulk's reaction (the coupled loop's
 * DrCoupleSamples.impulse). Call after dr_film_hair_load and before the strands' solve. */
void dr_film_pressure(DrFilm *f, const double *x, const double *gradp, double h, double *force, double *impulse);

typedef struct DrFilmStats {
    int substeps;          /* film substeps taken, summed over steps (strands substep independently: per step the
                              largest count of any strand) */
    double volume;         /* Σ V_i, m³ */
    double pools;          /* Σ pools, m³ */
    double to_pools;       /* m³ sent to the pools by ends and by the max_ratio limit, summed */
    double max_ratio;      /* the largest H/r after the step */
    DrVec3 momentum;       /* the film's momentum Σ_e ρ V̂_e (v̄_e + u_e t_e) + pools, kg m/s */
    double kinetic;        /* the film's kinetic energy, J */
} DrFilmStats;

/* Advances the film over a strand step of h seconds that took the strands from x_old to x (nverts × 3), leaving them
 * with velocities v (nverts × 3, in/out): first the film's momentum is carried onto the strands' new tangents (the
 * part across them goes to the strands), then film substeps (tangential forces, implicit friction with the strand,
 * continuity and momentum transport, pools, the max_ratio limit), each exchange moving the strands' velocities in v
 * (mass: hair_mass per vertex, kg, plus the film's own inertia). held (nverts, or NULL) marks vertices whose motion is
 * prescribed: their velocity is not changed (the exchange with them is external, like the scalp's push). stats (may be
 * NULL) accumulates substeps and to_pools and takes the rest after the step. DR_ERR_RUNTIME on a non-finite result
 * (the film and v are then left as they were). */
DR_NODISCARD DrStatus dr_film_step(DrFilm *f, const double *x_old, const double *x, double *v,
                                   const double *hair_mass, const unsigned char *held, double h, DrFilmStats *stats,
                                   DrError *err);

/* The film's outer radius H per vertex (m) into H (nverts), on the strands' shape of the film's last step or exchange
 * (at create: rest_x); and its volume, pools, max_ratio, momentum and kinetic energy at x, v into stats (measure
 * only: substeps and to_pools are left as they are). */
void dr_film_heights(const DrFilm *f, double *H);
void dr_film_measure(const DrFilm *f, const double *x, const double *v, DrFilmStats *stats);

/* Moves volume between vertices (cross-hair flow, bridges): dV (nverts, Σ dV = 0 up to round-off) added to the
 * vertices' volume with its momentum carried at the velocities v (exact, as a film flux); a vertex may not go negative
 * (asserted: the caller limits the flow). dV says how much each vertex gains or loses, not from whom: what leaves
 * carries the film velocity of the edges it leaves, and what arrives the mean velocity of all that left (for one
 * donor, its velocity); a caller that moves liquid between separate groups of strands in one go and wants each
 * group's momentum kept apart calls this once per group. Every vertex's velocity in v may change (held vertices
 * too: the strands' next step prescribes them again). x: positions (nverts × 3) of the film's last step. */
void dr_film_exchange(DrFilm *f, const double *x, const double *dV, double *v, const double *hair_mass);

/* Bulk liquid into the film and back (capture and dripping below): dV (nverts) the volume each vertex gains (> 0: it
 * arrives from the bulk with momentum P_in[3i..3i+2], kg m/s) or loses (< 0: it leaves with the film's velocity on the
 * vertex's edges, as a film flux; its momentum is written into P_out[3i..], 0 elsewhere); a vertex may not go negative
 * (asserted). Strands + film change their momentum by exactly Σ P_in − Σ P_out: what arrives across a strand goes to
 * its vertices through the per-vertex 3×3 solves, what arrives along it to the film's speed. Every vertex's velocity in
 * v may change. x: positions (nverts × 3) of the film's last step. */
void dr_film_transfer(DrFilm *f, const double *x, const double *dV, const double *P_in, double *P_out, double *v,
                      const double *hair_mass);

/* The film's desc, strands (offsets, nstrands + 1), radii (nverts) and the vertices' Voronoi lengths on the strands'
 * shape of its last step or exchange (nverts, m): borrowed, valid for the film's life. */
const DrFilmDesc *dr_film_desc(const DrFilm *f);
const int *dr_film_offsets(const DrFilm *f);
const double *dr_film_radius(const DrFilm *f);
const double *dr_film_lengths(const DrFilm *f);

/* ---- capture and dripping: the film and the bulk liquid (PHYSICS §5; fei2017 §4.3–4.4) --------------------------
 * The bulk liquid reaches wet as a neutral set of particles (DrBulk: positions, velocities, and each particle's own
 * volume, which capture lowers in place); what drips leaves as new particles (DrDrops) that the caller adds to the
 * liquid. Every transfer is booked exactly: the volume a particle loses is the volume the film gains, and the momentum
 * with it; a drop carries exactly the volume and momentum its film lost. Nothing is rescaled and nothing is deleted:
 * a particle that gives its last share (its remnant under 1e-3 of the nominal particle volume, when the film has room
 * for it) leaves with volume 0 for the caller to remove.
 *
 * Capture (bulk → film), over a step of h seconds. A particle of volume V_p (radius r_p = (3V_p/4π)^⅓) is within
 * reach of edge e when its distance from the edge's segment is at most H_e + reach·r_p (H_e the larger film radius
 * of the edge's vertices), and it is captured by the nearest such edge (ties: the lower edge) whose vertices have
 * room: vertex i holds at most capacity · π r_i² (max_ratio² − 1) l_i (l_i its Voronoi length). It offers the share
 * 1 − e^{−rate·h} of its volume (a rate in 1/s: the same capture for any step), split between the edge's vertices by
 * the closest point's position along it; a vertex offered more than its room takes the same fraction of every offer.
 *
 * Dripping (film → bulk).
 *  - Middle: per cell of the bulk's lattice (cells of dx from `lo`), the film of the vertices in the cell holds at most
 *    V_max = 4π r̄ κ⁻² c², κ⁻² = σ/(ρ ā_n) (c = radius_scale; r̄ and ā_n the Voronoi-length weighted mean radius and
 *    normal acceleration of those vertices; a_n = |(g − a)⊥| with a the strand's solved acceleration over its last
 *    step and ⊥ across its tangent). A cell whose excess E exceeds min_drop times the nominal particle volume V₀ loses
 *    exactly E, every vertex the same share of its volume, as ⌈E/V₀⌉ equal drops carrying the momentum the film lost
 *    there, placed along the cell's mean tangent below the film (along g − a), beyond the reach of capture.
 *  - Ends: a pool (root, tip: each switchable) of at least pool_release·V₀ is released whole as ⌈V/V₀⌉ equal drops
 *    moving with its end vertex, beyond the end along the strand.
 *  - Budget: at most `budget` drops per call. A cell or pool that would go beyond it keeps its liquid (stats->held
 *    counts it) so that a blow-up cannot flood the bake with particles; the caller warns. */
typedef struct DrCaptureDesc {
    double rate;     /* 1/s, ≥ 0; default 10 (0: no capture) */
    double capacity; /* the share of the largest film (H/r = max_ratio) up to which capture fills a vertex, in [0, 1];
                        default 1 */
    double reach;    /* in particle radii beyond the film's surface, ≥ 0; default 1 */
} DrCaptureDesc;
void dr_capture_desc_default(DrCaptureDesc *d);

typedef struct DrDripDesc {
    double radius_scale;  /* c of V_max, > 0; default 0.5 */
    bool middle;          /* middle dripping; default true */
    bool root, tip;       /* release the root and the tip pools; default false, true */
    double min_drop;      /* a cell drips once its excess reaches this times V₀, ≥ 0; default 0.5 */
    double pool_release;  /* a pool is released once it reaches this times V₀, > 0; default 1 */
    long budget;          /* drops per call at most, ≥ 1; default 20000 */
} DrDripDesc;
void dr_drip_desc_default(DrDripDesc *d);

/* The bulk liquid as capture and dripping see it (borrowed for a call). */
typedef struct DrBulk {
    long n;
    const double *x, *v;     /* 3n: m, m/s */
    double *vol;             /* n: m³; capture lowers it (to 0 for a particle wholly captured) */
    double particle_volume;  /* V₀, the nominal particle volume, m³ */
    double dx;               /* the lattice of middle dripping, m (the liquid's cells) */
    DrVec3 lo, hi;           /* the domain box: drops are placed inside it (lo is the lattice's origin) */
} DrBulk;

/* The strands as capture and dripping see them (borrowed for a call): positions of the film's last step, velocities
   (in/out: exchanges move them, as dr_film_transfer), the strands' acceleration over their last step (m/s², NULL:
   none), the hair's mass per vertex (kg). */
typedef struct DrWetStrands {
    const double *x;
    double *v;
    const double *accel;
    const double *mass;
} DrWetStrands;

/* The drops of a dripping call (owned by the exchange object; valid until its next call). */
typedef struct DrDrops {
    long n;
    double *x, *v, *vol; /* 3n, 3n, n */
} DrDrops;

typedef struct DrExchangeStats {
    double captured;        /* m³ from the bulk into the film */
    DrVec3 captured_momentum; /* kg m/s with it */
    long captured_particles; /* particles wholly captured (volume 0) */
    double dripped;         /* m³ from the film and pools into drops */
    DrVec3 dripped_momentum;
    long drops;             /* drops made */
    double held;            /* m³ a cell or pool kept because of the budget */
    /* J: the energy the volume carried, Σ ρ ΔV (½|v|² − g·x) (g the film's gravity): what capture took from the bulk
       and what the drops brought to it */
    double captured_energy, dripped_energy;
} DrExchangeStats;

typedef struct DrExchange DrExchange;
/* DR_ERR_INPUT for a desc out of range (naming the field). */
DR_NODISCARD DrStatus dr_exchange_create(const DrCaptureDesc *capture, const DrDripDesc *drip, DrExchange **out,
                                         DrError *err);
void dr_exchange_destroy(DrExchange **e);
/* Capture over a step of h seconds; stats (may be NULL) accumulate. DR_ERR_NOMEM. Bit-identical for any thread count. */
DR_NODISCARD DrStatus dr_exchange_capture(DrExchange *e, DrFilm *f, const DrWetStrands *s, DrBulk *b, double h,
                                          DrExchangeStats *stats, DrError *err);
/* How far each of the film's vertices at x (nverts × 3) lies under the bulk's free surface, into out (nverts):
   s = clamp(2φ − 1, 0, 1) with φ the particles' volume fraction (Σ vol over the cell's volume, per cell of the bulk's
   lattice) interpolated trilinearly between cell centres: 0 at the surface and above it (φ ≤ ½), 1 from half a cell
   under it (φ ≥ 1). DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_exchange_submersion(DrExchange *e, const double *x, long nverts, const DrBulk *b, double *out,
                                             DrError *err);
/* Dripping: the drops into *drops (owned by e, valid until its next call); stats accumulate. DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_exchange_drip(DrExchange *e, DrFilm *f, const DrWetStrands *s, const DrBulk *b,
                                       DrDrops *drops, DrExchangeStats *stats, DrError *err);

/* ---- bridges between strands and against solids (fei2017 §S1, eq. S28; §S5) ------------------------------------
 * A bridge joins a vertex p of one strand to the nearest point c of another strand (on its edge q0 q1, c = q0 + t (q1 −
 * q0)): per vertex and per other strand at most one. It forms when the two films touch within the Lian rupture
 * distance, d ≤ d_new = min(H_p + H_c, d_L), and an existing bridge holds while d ≤ d_keep = max(H_p + H_c, d_L),
 * d_L = (1 + θ/2) √(A_p + A_c) + r_p + r_c (PHYSICS §5): hysteresis, so a pulled bridge breaks at d_keep and reforms
 * only below d_new. A_p is the film's cross-section area at p (V_p / l_p), A_c the film's at c (interpolated); H the
 * film's outer radius, r the strand's. The set of bridges is the state kept across steps (and in the checkpoint).
 *
 * Force. The bridge's liquid is the film shared among the bridges at each end: A_L = A_p/n_p + A_c/n_c (n the number
 * of bridges leaving each vertex). The table gives the force per unit length F(d, A_L) (attracting); each bridge
 * stands for half of p's Voronoi length l_p (a pair of strands has bridges both ways), so its force is ½ l_p F. It is
 * one positional row of the Lagrangian system (eq. S28) over the 9 DOFs of p, q0, q1: φ = d − d*, J = n (p) and
 * −(1 − t) n, −t n (q0, q1), C⁻¹ = ½ l_p F(d) / (d − d*), the spring whose force is the table's at d. d* =
 * radius_multiplier · d_c is the rest distance of a wet pair (d_c = r_p + r_c plus the contact thicknesses, where the
 * strands touch): the spring's stiffness is held at its value at d̂ = (2 radius_multiplier − 1) d_c below d̂, so the
 * force falls linearly to zero at d* and pushes the strands apart below it (the table's force grows without bound as
 * the gap closes; a spring with C⁻¹ = F/(d − d*) would be infinitely stiff at d*). Below d_c the strands' dry contact
 * (hair.h) acts as well. Cohesion between a wet vertex and a collider uses the cylinder–plane table the same way, over
 * the vertex's 3 DOFs along the collider's normal, at d = the distance of the vertex's axis from the surface, with d_c
 * = r + thicknesses and its own radius multiplier.
 *
 * Cross-hair flow (S5). Film flows along the bridges: every bridge links p to q0 and q1 (weights 1 − t and t), and
 * over a step of δt the areas relax implicitly, (L + δt K) A⁺ = L A, L = diag(l), K the graph Laplacian with
 * conductance rate · ½ l_p · weight on each link. The volume moved across each link is δt times its conductance times
 * the difference of A⁺ at its ends, applied as equal and opposite film fluxes (dr_film_exchange): the total is exact
 * whatever the linear solve's accuracy, the areas equalise monotonically, and nothing moves between strands without
 * a bridge. */

typedef struct DrBridgeDesc {
    double contact_angle;     /* θ, rad (the tables' own) */
    double surface_tension;   /* σ, N/m */
    double scale;             /* multiplies every strand–strand bridge force, ≥ 0; default 1 */
    double solid_scale;       /* multiplies every strand–collider bridge force, ≥ 0; default 1 */
    double radius_multiplier; /* d* / d_c between strands, > 1; default 1.6 */
    double solid_radius_multiplier; /* d* / d_c against a collider, > 1; default 1.1 */
    bool cross_flow;          /* film flows along bridges; default true */
    double cross_flow_rate;   /* 1/s, > 0; default 1 */
} DrBridgeDesc;
void dr_bridge_desc_default(DrBridgeDesc *d);

/* The strands as the bridges see them (borrowed for one call). */
typedef struct DrBridgeStrands {
    int nstrands, nverts;
    const int *offsets;       /* nstrands + 1 */
    const double *x;          /* nverts × 3, m */
    const double *radius;     /* nverts, m */
    const double *volume;     /* nverts, film volume, m³ (dr_film_state) */
    const int *vertex_dof;    /* nverts: the first of the vertex's 3 DOFs in the Lagrangian system */
    const unsigned char *held; /* nverts or NULL: vertices whose motion is prescribed */
    const double *thickness;  /* nstrands or NULL: contact thickness added to each strand's radius */
    const double *submerged;  /* nverts or NULL: how far each vertex lies under the bulk liquid's surface, in [0, 1] (0:
                                 in air, 1: half a cell or more under it; dr_exchange_submersion): cohesion acts where
                                 films meet air, so a bridge's force is scaled by 1 − the mean of its ends' (the
                                 other end interpolated on its edge) and a bridge to a collider by 1 − its vertex's */
    /* which strands may bridge, as hair.h's contact rule: strands of one batch when its self flag is set, of batches a
       and b when (group_a & mask_b) && (group_b & mask_a). batch NULL: every pair of strands may. */
    const int *batch;         /* nstrands: each strand's batch */
    const unsigned *group, *mask; /* per batch */
    const unsigned char *self;    /* per batch */
} DrBridgeStrands;

typedef struct DrBridges DrBridges;
/* pair: the cylinders table (required); plane: the cylinder–plane table (NULL: no cohesion with colliders). Both
 * borrowed for the object's life. DR_ERR_INPUT for a desc out of range or tables of different contact angles. */
DR_NODISCARD DrStatus dr_bridges_create(const DrBridgeDesc *desc, const DrCohesionTable *pair,
                                        const DrCohesionTable *plane, DrBridges **out, DrError *err);
void dr_bridges_destroy(DrBridges **b);

/* Finds this step's bridges from the strands at the start of a step (hysteresis against the bridges kept), and the
 * bridges to colliders (hair.h's DrRodCollider: signed distance, normal, surface velocity, thickness; its friction is
 * not used). After the first call with its largest sizes it allocates nothing. */
DR_NODISCARD DrStatus dr_bridges_update(DrBridges *b, const DrBridgeStrands *s, const DrRodCollider *colliders,
                                        int ncolliders, DrError *err);
/* Adds the bridges' rows to a Lagrangian system that has begun a step of h seconds (strand–strand rows with
 * dr_lag_add_global, collider rows too); the collider rows are relative to the collider's motion over the step. */
DR_NODISCARD DrStatus dr_bridges_add_groups(const DrBridges *b, const DrBridgeStrands *s, DrLag *lag, double h,
                                            DrError *err);
/* Cross-hair flow over the bridges for δt seconds: dV (nverts) receives the volume each vertex gains (Σ dV = 0 to
 * round-off, no vertex below zero), for dr_film_exchange. No bridge, or cross_flow off: dV all zero, bit for bit. */
DR_NODISCARD DrStatus dr_bridges_cross_flow(DrBridges *b, const DrBridgeStrands *s, double dt, double *dV,
                                            DrError *err);

typedef struct DrBridgeStats {
    int bridges;        /* strand–strand bridges */
    int solid_bridges;  /* strand–collider bridges */
    int formed, broken; /* since the previous update */
    double cross_flow;  /* m³ moved across bridges by the last cross-flow call */
} DrBridgeStats;
void dr_bridges_stats(const DrBridges *b, DrBridgeStats *stats);

/* The bridge set (the checkpoint's part): n pairs (vertex, other strand) in increasing order. */
int dr_bridges_count(const DrBridges *b);
void dr_bridges_get(const DrBridges *b, int *vertex, int *strand);
DR_NODISCARD DrStatus dr_bridges_set(DrBridges *b, int n, const int *vertex, const int *strand, DrError *err);

#endif
