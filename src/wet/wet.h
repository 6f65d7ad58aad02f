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

/* ---- cohesion tables (fei2017 §S1, §S3) -----------------------------------------------------------------------
 * A liquid bridge between two parallel cylinders of radius r whose axes are d apart (or between a cylinder whose axis
 * is d above a plane and the plane), seen in the plane across them: bounded by the solids and by two circular menisci
 * of radius R meeting each solid at the contact angle θ at the wetting half-angle α (the angle, at a cylinder's axis,
 * between the line to the other solid and the contact line). Its cross-section area A(α, d) and surface energy per
 * unit length E(α, d) = σ (l_A + l_S cos θ) (eq. S4: l_A the menisci's arc length, l_S the dry solid perimeter) are
 * closed forms. The table holds F = ∂E/∂d at constant A over a grid of (d, A): the force per unit length pulling the
 * two together (N/m; > 0 attracts), ∂E/∂d|_A = ∂E/∂d + ∂E/∂α · dα/dd|_A, dα/dd|_A = −(∂A/∂d)/(∂A/∂α).
 *
 * Scaling: with d = r d̃, A = r² Ã, E = σ r Ẽ, the geometry depends on (θ, d̃, Ã) only and F = σ F̃(d̃, Ã): one table per
 * contact angle serves every radius and every surface tension. What does not scale: two cylinders of different radii
 * (their bridge is not symmetric); drench evaluates such a pair on the table at the mean radius, which is exact for
 * equal radii and first-order accurate in the radius difference. The table is stored nondimensional. */

typedef enum DrCohesionShape {
    DR_COHESION_CYLINDERS, /* two parallel cylinders of one radius, axes d apart: d̃ ≥ 2 */
    DR_COHESION_PLANE      /* a cylinder whose axis is d above a plane: d̃ ≥ 1 */
} DrCohesionShape;

typedef struct DrCohesionDesc {
    DrCohesionShape shape;
    double contact_angle; /* θ, rad, in [0, π/2) */
    int resolution;       /* samples per axis of the (d̃, Ã) grid, in [16, 4096]; default 256 */
    double max_area;      /* Ã_max, the largest bridge area in units of r²; > 0; default 2π(6² − 1) (two films at
                             H/r = 6) */
    double max_gap;       /* d̃_max − d̃_min, the range of gaps in units of r; > 0; default: the rupture gap at
                             Ã_max, (1 + θ/2)√Ã_max */
} DrCohesionDesc;
void dr_cohesion_desc_default(DrCohesionDesc *d);

typedef struct DrCohesionTable DrCohesionTable;

/* Builds the table: per d̃ column, A(α) on [α_0, π − θ] where α_0 is the smallest angle at which the bridge closes
 * (its neck has positive height), inverted at each Ã by bisection; F̃ from the derivatives of the closed forms. A
 * column keeps only the part of [α_0, π − θ] where A increases with α, so A(α) is monotone in every column; (d̃, Ã)
 * outside what a bridge can have (too little area to span the gap, or more than it can hold) get F̃ = 0 and are
 * marked invalid. DR_ERR_INPUT for a desc out of range (naming the field). Takes well under a second at 256². */
DR_NODISCARD DrStatus dr_cohesion_build(const DrCohesionDesc *desc, DrCohesionTable **out, DrError *err);
void dr_cohesion_destroy(DrCohesionTable **t);
const DrCohesionDesc *dr_cohesion_desc(const DrCohesionTable *t);

/* F̃(d̃, Ã), bilinear in the table; 0 outside the table's range or where no bridge exists. */
double dr_cohesion_eval(const DrCohesionTable *t, double d_nd, double area_nd);
/* The force per unit length (N/m) of a bridge of area A (m²) between solids of radius r (m) at distance d (m), surface
 * tension σ (N/m): σ F̃(d/r, A/r²). */
double dr_cohesion_force(const DrCohesionTable *t, double r, double sigma, double d, double area);

/* The closed forms, nondimensional (r = 1, σ = 1), for tests and for building: the bridge area Ã and energy Ẽ at
 * wetting half-angle α and gap d̃ (Ẽ up to a constant that does not depend on α or d̃). Returns false where the
 * geometry has no bridge (the menisci cross, or α out of [0, π − θ]). */
bool dr_cohesion_geometry(DrCohesionShape shape, double theta, double alpha, double d_nd, double *area_nd,
                          double *energy_nd);

/* The cache key (DESIGN §5): a hash of shape, θ, resolution, Ã_max, gap range and the table code's version, as 32 hex
 * digits (+ NUL), and the canonical JSON of those inputs the file records. */
void dr_cohesion_key(const DrCohesionDesc *desc, char key_hex[33]);
/* Writes the table into a precompute cache file (io.h dr_io_precache_create, kind "cohesion"): datasets
 * /cohesion/force (resolution² F̃, row-major d̃ slowest), /cohesion/valid, and self-describing attributes (shape,
 * contact angle in degrees and radians, ranges, resolution, units "1": nondimensional, how to scale). */
DR_NODISCARD DrStatus dr_cohesion_write(const DrCohesionTable *t, DrH5 *h, DrError *err);
/* Reads a table written by dr_cohesion_write; DR_ERR_INPUT naming the file for a file of another shape, resolution
 * or version. */
DR_NODISCARD DrStatus dr_cohesion_read(DrH5 *h, const char *path, DrCohesionTable **out, DrError *err);
/* The table of desc from cache_root/cohesion/<key>.h5; DR_ERR_INPUT "run precompute" naming the file when it is
 * missing. */
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

#endif
