/* DrWorld: the orchestrator. It builds the solvers a scene needs (an adapter each, world_<solver>.c) and the
 * kinematics (world_kinematics.c), and advances the shot one frame at a time on one clock, in the order README's
 * "How a frame is stepped" gives; frame caches and checkpoints gather what each adapter writes. */
#include "world_adapter.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "liquid/liquid.h"
#include "vdb/vdb.h"

enum { MAX_SOLVERS_FIXED = 5 }; /* MPM, hair, cloth, air, BEM: one adapter each; the liquids come before them, one per element */

struct DrWorld {
    const DrScene *scene;
    int first_frame, last_frame, frame;
    double fps;
    DrVec3 gravity;
    WorldKinematics *kin;
    /* the adapters in the order they are stepped, written and hashed: the liquids (element order), MPM, hair, cloth, air,
       BEM */
    WorldSolver *solvers;
    int nsolvers;
    int nliquids;
    WorldSolver *mpm, *hair, *cloth, *bem; /* into solvers, NULL when the scene has none */
    WorldSolver bem_built;         /* built first (the liquid seeds no particle inside a body), placed last */
    double *at, *proposal;         /* per solver during a frame: the time it stands at, its next step's end */
    /* the coupled step (DESIGN §8 step 3): the fluid and the solids of src/couple's loop (hair, cloth), -1 and 0 when
       there is none */
    int couple_fluid, couple_solid[2], ncouple_solids;
    DrCouple *couple;
    DrCoupleDesc couple_desc;
};

int dr_world_first_frame(const DrWorld *w) { return w->first_frame; }
int dr_world_last_frame(const DrWorld *w) { return w->last_frame; }
int dr_world_frame(const DrWorld *w) { return w->frame; }
int dr_world_liquid_count(const DrWorld *w) { return w->nliquids; }
const DrLiquid *dr_world_liquid(const DrWorld *w, int i) { return world_liquid_solver(&w->solvers[i]); }
const DrElement *dr_world_liquid_element(const DrWorld *w, int i)
{
    int k = 0;
    for (int e = 0; e < dr_scene_element_count(w->scene); e++) {
        const DrElement *el = dr_scene_element(w->scene, e);
        if (el->kind == DR_ELEMENT_LIQUID && k++ == i) return el;
    }
    return NULL;
}
int dr_world_live_collider_count(const DrWorld *w)
{
    const DrCollider *const *c = NULL;
    return world_kinematics_colliders(w->kin, &c);
}
const DrMpm *dr_world_mpm(const DrWorld *w) { return w->mpm ? world_mpm_solver(w->mpm) : NULL; }
long dr_world_mpm_particle_count(const DrWorld *w) { return w->mpm ? world_mpm_particles(w->mpm) : 0; }
long dr_world_cloth_vertex_count(const DrWorld *w) { return w->cloth ? world_cloth_vertex_count(w->cloth) : 0; }
long dr_world_hair_vertex_count(const DrWorld *w)
{
    int strands = 0, verts = 0;
    if (w->hair) world_lagrangian_hair_counts(w->hair, &strands, &verts);
    return verts;
}

int dr_world_bem_count(const DrWorld *w)
{
    const DrBemSolid *const *s = NULL;
    const DrElement *const *e = NULL;
    return w->bem ? world_bem_solids(w->bem, &s, &e) : 0;
}

const DrBemSolid *dr_world_bem_solid(const DrWorld *w, int i)
{
    const DrBemSolid *const *s = NULL;
    const DrElement *const *e = NULL;
    int n = w->bem ? world_bem_solids(w->bem, &s, &e) : 0;
    return i >= 0 && i < n ? s[i] : NULL;
}

double dr_world_frame_time(const DrWorld *w, int frame) { return (double)(frame - w->first_frame + 1) / w->fps; }

/* The context every adapter reads: the frame being advanced is w->frame + 1 (or, when writing, w->frame). */
static WorldCtx context(const DrWorld *w, int frame)
{
    return (WorldCtx){.scene = w->scene,
                      .first_frame = w->first_frame,
                      .fps = w->fps,
                      .gravity = w->gravity,
                      .frame = frame,
                      .t0 = dr_world_frame_time(w, frame - 1),
                      .t1 = dr_world_frame_time(w, frame),
                      .kin = w->kin};
}

void dr_world_desc_default(DrWorldDesc *d) { *d = (DrWorldDesc){.cache_root = "cache"}; }

DrStatus dr_world_create(const DrScene *scene, DrWorld **out, DrError *err)
{
    DrWorldDesc d;
    dr_world_desc_default(&d);
    return dr_world_create_desc(scene, &d, out, err);
}

/* ---- failures: who, where, when --------------------------------------------------------------------------------
 * A solver's failure (a blow-up, running out of memory) is told with the elements it simulates, the scene file and
 * the frame, whatever the solver's own message names: "scene.json: error: hair 'fur', frame 5: ...". */

/* "<type> 'a', 'b'": the elements of one kind (e NULL), or element e alone. */
static void describe_elements(const DrScene *scene, DrElementKind kind, const DrElement *e, char *buf, size_t size)
{
    size_t n = 0;
    buf[0] = '\0';
    for (int i = 0; i < dr_scene_element_count(scene) && n < size; i++) {
        const DrElement *x = dr_scene_element(scene, i);
        if (e ? x != e : x->kind != kind) continue;
        n += (size_t)snprintf(buf + n, size - n, n ? ", '%s'" : "%s '%s'", x->type, x->name);
    }
}

/* Adds what the failure's message does not say yet (the elements, and with frame > 0 the frame) in front of it, and
 * the scene file when it names no file. */
static DrStatus failed(const DrWorld *w, DrElementKind kind, const DrElement *e, int frame, DrStatus s, DrError *err)
{
    if (s >= 0 || !err) return s;
    char who[512], when[32] = "";
    describe_elements(w->scene, kind, e, who, sizeof who);
    if (frame > 0) snprintf(when, sizeof when, "frame %d", frame);
    /* named when the message names the first of them, quoted or leading ("jelly: ..." or "... 'jelly' ...") */
    const char *q = strchr(who, '\'');
    char name[160] = "", quoted[164] = "";
    if (q) snprintf(name, sizeof name, "%.*s", (int)strcspn(q + 1, "'"), q + 1);
    snprintf(quoted, sizeof quoted, "'%s'", name);
    bool named = !name[0] || strstr(err->message, quoted) || strncmp(err->message, name, strlen(name)) == 0;
    bool dated = !when[0] || strstr(err->message, when) != NULL;
    if (!err->file[0]) {
        snprintf(err->file, sizeof err->file, "%s", dr_scene_path(w->scene));
        err->line = err->col = 0;
    }
    if (!named && !dated) return dr_error_prefix(s, err, "%s, %s", who, when);
    if (!named) return dr_error_prefix(s, err, "%s", who);
    if (!dated) return dr_error_prefix(s, err, "%s", when);
    return s;
}

/* failed() for the solver at w->solvers[i]: a liquid element of its own, or every element of its kind. */
static DrStatus solver_failed(const DrWorld *w, int i, int frame, DrStatus s, DrError *err)
{
    if (s >= 0) return s;
    const WorldSolver *sv = &w->solvers[i];
    if (sv == w->mpm) return failed(w, DR_ELEMENT_MPM_SOLID, NULL, frame, s, err);
    if (sv == w->hair) return failed(w, DR_ELEMENT_HAIR, NULL, frame, s, err);
    if (sv == w->cloth) return failed(w, DR_ELEMENT_CLOTH, NULL, frame, s, err);
    if (sv == w->bem) return failed(w, DR_ELEMENT_BEM_SOLID, NULL, frame, s, err);
    if (strcmp(sv->name, "air") == 0) return failed(w, DR_ELEMENT_AIR, NULL, frame, s, err);
    for (int k = 0, liquid = 0; k < dr_scene_element_count(w->scene); k++) {
        const DrElement *e = dr_scene_element(w->scene, k);
        if (e->kind == DR_ELEMENT_LIQUID && liquid++ == i) return failed(w, e->kind, e, frame, s, err);
    }
    return s;
}
/* A solver's constructor: bad input (a file, a field) is told without a frame, anything else with the first. */
#define BUILD_TRY(kind, e, expr)                                                                                       \
    do {                                                                                                           \
        DrStatus build_status_ = (expr);                                                                           \
        if (build_status_ < 0)                                                                                     \
            return failed(w, (kind), (e), build_status_ == DR_ERR_INPUT ? 0 : c.frame, build_status_, err);        \
    } while (0)
#define SOLVER_TRY(i, frame, expr)                                                                                     \
    do {                                                                                                           \
        DrStatus solver_status_ = (expr);                                                                          \
        if (solver_status_ < 0) return solver_failed(w, (i), (frame), solver_status_, err);                        \
    } while (0)

static DrStatus build(DrWorld *w, const DrWorldDesc *desc, DrError *err)
{
    const DrScene *scene = w->scene;
    DR_TRY(dr_vdb_init(err));
    DR_TRY(world_kinematics_create(scene, w->first_frame, w->fps, &w->kin, err));
    WorldCtx c = context(w, w->frame + 1);
    /* the bodies before the liquid: it seeds no particle inside them */
    BUILD_TRY(DR_ELEMENT_BEM_SOLID, NULL, world_bem_adapter(&c, desc->cache_root, &w->bem_built, err));
    const DrBemSolid *const *solids = NULL;
    const DrElement *const *elements = NULL;
    int nbodies = w->bem_built.self ? world_bem_solids(&w->bem_built, &solids, &elements) : 0;
    DR_TRY(world_kinematics_add_bodies(w->kin, scene, solids, elements, nbodies, err));

    int nl = dr_scene_count_kind(scene, DR_ELEMENT_LIQUID);
    DR_TRY(dr_calloc((size_t)nl + MAX_SOLVERS_FIXED, sizeof(WorldSolver), &w->solvers, err));
    DR_TRY(dr_calloc((size_t)nl + MAX_SOLVERS_FIXED, sizeof(double), &w->at, err));
    DR_TRY(dr_calloc((size_t)nl + MAX_SOLVERS_FIXED, sizeof(double), &w->proposal, err));
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_LIQUID) continue;
        BUILD_TRY(e->kind, e, world_liquid_adapter(&c, e, &w->solvers[w->nsolvers], err));
        w->nsolvers++;
        w->nliquids++;
    }
    WorldSolver s;
    BUILD_TRY(DR_ELEMENT_MPM_SOLID, NULL, world_mpm_adapter(&c, &s, err));
    if (s.self) {
        w->solvers[w->nsolvers] = s;
        w->mpm = &w->solvers[w->nsolvers++];
    }
    BUILD_TRY(DR_ELEMENT_HAIR, NULL, world_lagrangian_adapter(&c, desc->cache_root, &s, err));
    if (s.self) {
        w->solvers[w->nsolvers] = s;
        w->hair = &w->solvers[w->nsolvers++];
    }
    BUILD_TRY(DR_ELEMENT_CLOTH, NULL, world_cloth_adapter(&c, &s, err));
    if (s.self) {
        w->solvers[w->nsolvers] = s;
        w->cloth = &w->solvers[w->nsolvers++];
    }
    BUILD_TRY(DR_ELEMENT_AIR, NULL, world_air_adapter(&c, &s, err));
    if (s.self) w->solvers[w->nsolvers++] = s;
    /* two-way bodies: the first liquid's projections move them, so it steps at every clock step (every BEM step end) */
    for (int i = 0; i < nbodies; i++)
        if (world_bem_coupled(&w->bem_built, i)) {
            BUILD_TRY(DR_ELEMENT_BEM_SOLID, elements[i], world_kinematics_body_couple(w->kin, i, err));
            if (w->nliquids > 0) w->solvers[0].lockstep = true;
        }
    /* capture and dripping between the first liquid and the wet hair: both stand at every clock step's end */
    if (world_kinematics_wet(w->kin)->on && w->nliquids > 0) {
        w->solvers[0].lockstep = true;
        if (w->hair) w->hair->lockstep = true;
    }
    /* hair against cloth: the hair adapter steps the panels it meets with the hair, in one system, at every clock
       step; the cloth adapter counts their steps at the same clock steps */
    if (world_kinematics_cloth_link(w->kin)->n > 0 && w->hair && w->cloth) w->hair->lockstep = w->cloth->lockstep = true;
    /* MPM solids two-way with the first liquid: its substep hands them the pressure's impulse at every clock step */
    if (world_kinematics_mpm_coupled(w->kin) && w->nliquids > 0) w->solvers[0].lockstep = true;
    if (w->bem_built.self) {
        w->solvers[w->nsolvers] = w->bem_built;
        w->bem = &w->solvers[w->nsolvers++];
        memset(&w->bem_built, 0, sizeof w->bem_built);
    }
    /* the coupled loop: the first fluid and the Lagrangian solids that take part (hair with Drag, cloth with
       ClothDrag) */
    w->couple_fluid = -1;
    w->ncouple_solids = 0;
    for (int i = 0; i < w->nsolvers; i++) {
        const WorldSolver *sv = &w->solvers[i];
        if (sv->fluid_begin && w->couple_fluid < 0) w->couple_fluid = i;
        if (sv->couples && sv->couples(sv->self)) w->couple_solid[w->ncouple_solids++] = i;
    }
    if (w->couple_fluid < 0 || w->ncouple_solids == 0) {
        w->couple_fluid = -1;
        w->ncouple_solids = 0;
    } else if (world_kinematics_mpm_coupled(w->kin)) {
        return dr_error_set(err, DR_ERR_INPUT, dr_scene_path(scene), 0, 0,
                            "the scene couples hair (Drag) or cloth (ClothDrag) and MPM solids "
                            "(Integrator.liquid_coupling \"two_way\") with the liquid; both in one scene is not "
                            "supported yet: set the mpm_solids' Integrator.liquid_coupling to \"none\" or remove the "
                            "Drag and ClothDrag components");
    } else {
        const DrComponent *solver = dr_scene_section(scene, "solver");
        dr_couple_desc_default(&w->couple_desc);
        w->couple_desc.iterations = dr_component_int(solver, "coupling_iterations");
        w->couple_desc.tolerance = dr_component_num(solver, "coupling_tolerance");
        DR_TRY(dr_couple_create(&w->couple, err));
    }
    return DR_OK;
}

static void log_solvers(const DrWorld *w)
{
    char hair[128] = "no hair";
    if (w->hair) {
        int strands, verts;
        world_lagrangian_hair_counts(w->hair, &strands, &verts);
        snprintf(hair, sizeof hair, "%d strand(s) of hair with %d vertices", strands, verts);
    }
    char cloth[96] = "";
    if (w->cloth) snprintf(cloth, sizeof cloth, ", cloth with %ld vertices", world_cloth_vertex_count(w->cloth));
    char bem[160] = "";
    if (w->bem) {
        int bodies, sets;
        long nv;
        world_bem_counts(w->bem, &bodies, &nv, &sets);
        snprintf(bem, sizeof bem, ", %d BEM bod%s with %ld vertices (%d matrix set%s)", bodies,
                 bodies == 1 ? "y" : "ies", nv, sets, sets == 1 ? "" : "s");
    }
    int nlive = dr_world_live_collider_count(w);
    if (w->mpm) {
        int nb = world_mpm_bodies(w->mpm);
        dr_log_info("world: %d liquid grid(s), one MPM grid with %ld particles in %d bod%s, %s%s%s, %d collider SDF(s)",
                    w->nliquids, world_mpm_particles(w->mpm), nb, nb == 1 ? "y" : "ies", hair, cloth, bem, nlive);
    } else {
        dr_log_info("world: %d liquid grid(s), no MPM solver, %s%s%s, %d collider SDF(s)", w->nliquids, hair, cloth, bem,
                    nlive);
    }
}

DrStatus dr_world_create_desc(const DrScene *scene, const DrWorldDesc *desc, DrWorld **out, DrError *err)
{
    DrWorld *w = NULL;
    DR_TRY(dr_calloc(1, sizeof *w, &w, err));
    w->scene = scene;
    const DrComponent *shot = dr_scene_section(scene, "shot");
    int fr[2];
    dr_component_int2(shot, "frames", fr);
    w->first_frame = fr[0];
    w->last_frame = fr[1];
    w->frame = fr[0] - 1;
    w->fps = dr_component_num(shot, "fps");
    w->gravity = dr_component_vec3(shot, "gravity");
    DrStatus s = build(w, desc, err);
    if (s < 0) {
        dr_world_destroy(&w);
        return s;
    }
    log_solvers(w);
    *out = w;
    return DR_OK;
}

void dr_world_destroy(DrWorld **world)
{
    if (!world || !*world) return;
    DrWorld *w = *world;
    for (int i = 0; i < w->nsolvers; i++) w->solvers[i].destroy(w->solvers[i].self);
    if (w->bem_built.self) w->bem_built.destroy(w->bem_built.self);
    free(w->solvers);
    free(w->at);
    free(w->proposal);
    dr_couple_destroy(&w->couple);
    world_kinematics_destroy(&w->kin);
    free(w);
    *world = NULL;
}

/* ---- one frame ------------------------------------------------------------------------------------------------
 * One clock for every solver: each clock step ends at the earliest of the solvers' proposals (each its own stable
 * step from where it stands, evened out towards the frame end), of the BEM bodies' step ends and of the frame end.
 * Within a step:
 *   1. BEM bodies at the start of one of their steps take it (one-way: nothing acts on them but their constraints),
 *      and the kinematics carry each body's collider of the liquid and the hair through it;
 *   2. kinematics: every scene collider posed at the step's end, once, for every solver;
 *   3. each other solver whose own step ends there, or every solver at the frame end, steps to it from where it
 *      stands (predict, solve, commit), the liquids first. A solver whose step ends later waits: with nothing
 *      exchanged between the solvers yet, it takes the steps it took alone, and a cheap hair step is not cut into a
 *      fast liquid's substeps nor a liquid substep at each BEM step end (the bodies' colliders are keyed over the
 *      frame so far, so a step may span several BEM steps).
 * After the last step each adapter checks its state and writes its block of the frame's stats. */

/* Step 3 of a clock step for the fluid and the solids of the coupled loop, which step together at every clock step:
   the fluid begins, the solids predict, the loop (src/couple) makes them agree, the solids commit, the fluid ends. */
static DrStatus coupled_step(DrWorld *w, const WorldCtx *c, double t, double t_next, DrFrameStats *stats,
                             DrError *err)
{
    int fi = w->couple_fluid, ns = w->ncouple_solids;
    WorldSolver *f = &w->solvers[fi];
    DrCoupleFluid fluid;
    DrCoupleSolid solids[2];
    double t0 = dr_time_now();
    SOLVER_TRY(fi, c->frame, f->fluid_begin(f->self, c, t, t_next, &fluid, err));
    for (int k = 0; k < ns; k++) {
        WorldSolver *s = &w->solvers[w->couple_solid[k]];
        assert(w->at[w->couple_solid[k]] == t);
        SOLVER_TRY(w->couple_solid[k], c->frame, s->solid_predict(s->self, c, t, t_next, &solids[k], err));
    }
    DrCoupleStats cs = {0};
    DR_TRY(dr_couple_step(w->couple, &w->couple_desc, &fluid, solids, ns, t_next - t, &cs, err));
    for (int k = 0; k < ns; k++) {
        WorldSolver *s = &w->solvers[w->couple_solid[k]];
        SOLVER_TRY(w->couple_solid[k], c->frame, s->solid_commit(s->self, c, t, t_next, err));
    }
    SOLVER_TRY(fi, c->frame, f->fluid_end(f->self, c, err));
    stats->coupling.steps += cs.steps;
    stats->coupling.iterations += cs.iterations_total;
    if (cs.iterations_max > stats->coupling.iterations_max) stats->coupling.iterations_max = cs.iterations_max;
    stats->coupling.not_converged += cs.not_converged;
    if (cs.change_max > stats->coupling.change_max) stats->coupling.change_max = cs.change_max;
    stats->coupling.elements = cs.elements;
    stats->coupling.solid_impulse = dr_v3_add(stats->coupling.solid_impulse, cs.solid_impulse);
    stats->coupling.fluid_impulse = dr_v3_add(stats->coupling.fluid_impulse, cs.fluid_impulse);
    stats->coupling.seconds += dr_time_now() - t0;
    for (int i = 0; i <= ns; i++) {
        int k = i < ns ? w->couple_solid[i] : fi;
        w->at[k] = t_next;
        w->proposal[k] = NAN;
    }
    return DR_OK;
}

/* Whether solver i takes part in the coupled loop. */
static bool in_couple(const DrWorld *w, int i)
{
    if (i == w->couple_fluid) return true;
    for (int k = 0; k < w->ncouple_solids; k++)
        if (w->couple_solid[k] == i) return true;
    return false;
}

DrStatus dr_world_step_frame(DrWorld *w, DrFrameStats *stats, DrError *err)
{
    assert(w->frame < w->last_frame);
    double t_start = dr_time_now();
    WorldCtx c = context(w, w->frame + 1);
    memset(stats, 0, sizeof *stats);
    stats->frame = c.frame;
    stats->time = c.t1;
    for (int i = 0; i < w->nsolvers; i++)
        if (w->solvers[i].begin_frame) w->solvers[i].begin_frame(w->solvers[i].self, &c);
    double tol = 1e-9 * (c.t1 - c.t0);
    for (int i = 0; i < w->nsolvers; i++) {
        w->at[i] = c.t0;
        w->proposal[i] = NAN; /* asked for when the clock first needs it */
    }
    double t = c.t0;
    while (t < c.t1) {
        for (int i = 0; i < w->nsolvers; i++)
            if (w->solvers[i].step_first)
                SOLVER_TRY(i, c.frame, w->solvers[i].step_first(w->solvers[i].self, &c, t, c.t1, err));
        double land = c.t1;
        for (int i = 0; i < w->nsolvers; i++) {
            const WorldSolver *s = &w->solvers[i];
            if (s->landing) land = fmin(land, s->landing(s->self, &c, t));
        }
        double t_next = land;
        for (int i = 0; i < w->nsolvers; i++) {
            WorldSolver *s = &w->solvers[i];
            if (!s->next_time) continue;
            if (isnan(w->proposal[i])) SOLVER_TRY(i, c.frame, s->next_time(s->self, &c, w->at[i], &w->proposal[i], err));
            t_next = fmin(t_next, w->proposal[i]);
        }
        if (w->couple) {
            /* the coupled solids' explicit forces (lift) limit the coupled step */
            const WorldSolver *f = &w->solvers[w->couple_fluid];
            double rho = 0.0, mu = 0.0, lim = INFINITY;
            f->fluid_properties(f->self, &rho, &mu);
            for (int k = 0; k < w->ncouple_solids; k++) {
                const WorldSolver *sd = &w->solvers[w->couple_solid[k]];
                if (sd->solid_stable_dt) lim = fmin(lim, sd->solid_stable_dt(sd->self, rho, mu));
            }
            if (t + lim < t_next) {
                double n = ceil((t_next - t) / lim);
                t_next = t + (t_next - t) / n;
            }
        }
        /* a proposal a rounding error short of a landing time lands on it (no step of a few ulps after it) */
        if (land - t_next <= tol) t_next = land;
        world_kinematics_pose(w->kin, t_next);
        if (w->couple) DR_TRY(coupled_step(w, &c, t, t_next, stats, err));
        for (int i = 0; i < w->nsolvers; i++) {
            WorldSolver *s = &w->solvers[i];
            if (!s->step || in_couple(w, i)) continue;
            if (!s->lockstep && t_next < c.t1 && s->next_time && t_next < w->proposal[i]) continue; /* its own step ends later */
            SOLVER_TRY(i, c.frame, s->step(s->self, &c, w->at[i], t_next, err));
            w->at[i] = t_next;
            w->proposal[i] = NAN;
        }
        for (int i = 0; i < w->nsolvers; i++)
            if (w->solvers[i].step_last)
                SOLVER_TRY(i, c.frame, w->solvers[i].step_last(w->solvers[i].self, &c, t, t_next, err));
        stats->clock_steps++;
        t = t_next;
    }
    /* the blocks in the order the kinetic energies were summed before: BEM, liquids, MPM, hair */
    if (w->bem) SOLVER_TRY((int)(w->bem - w->solvers), c.frame, w->bem->end_frame(w->bem->self, &c, stats, err));
    for (int i = 0; i < w->nsolvers; i++)
        if (&w->solvers[i] != w->bem) SOLVER_TRY(i, c.frame, w->solvers[i].end_frame(w->solvers[i].self, &c, stats, err));
    stats->kinetic_energy = stats->bem.kinetic_energy;
    stats->kinetic_energy += stats->liquid.kinetic_energy;
    stats->kinetic_energy += stats->mpm.kinetic_energy;
    stats->kinetic_energy += stats->hair.kinetic_energy;
    stats->kinetic_energy += stats->cloth.kinetic_energy;
    int k = stats->bem.substeps;
    if (stats->liquid.substeps > k) k = stats->liquid.substeps;
    if (stats->mpm.substeps > k) k = stats->mpm.substeps;
    if (stats->hair.substeps > k) k = stats->hair.substeps;
    if (stats->cloth.substeps > k) k = stats->cloth.substeps;
    stats->substeps = k;
    w->frame = c.frame;
    stats->seconds = dr_time_now() - t_start;
    return DR_OK;
}

/* ---- frame caches and checkpoints --------------------------------------------------------------------------- */

static DrStatus write_frame_body(const DrWorld *w, const DrFrameStats *stats, DrH5 *h, const char *bake_key,
                                 DrError *err)
{
    WorldCtx c = context(w, w->frame);
    DR_TRY(dr_h5_attr_str(h, "/", "drench_version", DR_VERSION, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "frame", w->frame, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "time", dr_world_frame_time(w, w->frame), err));
    DR_TRY(dr_h5_attr_i64(h, "/", "substeps", stats->substeps, err));
    DR_TRY(dr_h5_attr_str(h, "/", "scene_key", bake_key, err));
    DR_TRY(dr_h5_attr_str(h, "/", "units", "SI: m, s, kg", err));
    for (int i = 0; i < w->nliquids; i++) DR_TRY(w->solvers[i].write(w->solvers[i].self, &c, h, true, err));
    DR_TRY(world_kinematics_write(w->kin, h, dr_world_frame_time(w, w->frame), err));
    for (int i = w->nliquids; i < w->nsolvers; i++) DR_TRY(w->solvers[i].write(w->solvers[i].self, &c, h, true, err));
    const char *g = "/diagnostics";
    DR_TRY(dr_h5_write_scalar(h, g, "substeps", stats->substeps, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "liquid_volume_cells", stats->liquid.volume, "m^3", err));
    if (world_kinematics_mpm_coupled(w->kin) && w->nliquids > 0) {
        /* the MPM solids two-way with the liquid: what they gained from it (their particles received exactly this) */
        DR_TRY(dr_h5_write_vec3(h, g, "mpm_liquid_impulse", stats->liquid.mpm_impulse, "N*s", err));
        DR_TRY(dr_h5_write_scalar(h, g, "mpm_liquid_pushed_out", (double)stats->liquid.mpm_pushed, "1", err));
    }
    if (w->couple) {
        /* the coupled loop's figures and its momentum ledger: what the coupled solids received (hair and cloth; the
           datasets keep the name coupling_impulse_hair_*) + what the fluid was given = 0 */
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_steps", stats->coupling.steps, "1", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_iterations", (double)stats->coupling.iterations, "1", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_iterations_max", stats->coupling.iterations_max, "1", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_not_converged", stats->coupling.not_converged, "1", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_change_max", stats->coupling.change_max, "1", err));
        double ledger[6] = {stats->coupling.solid_impulse.x, stats->coupling.solid_impulse.y,
                            stats->coupling.solid_impulse.z, stats->coupling.fluid_impulse.x,
                            stats->coupling.fluid_impulse.y, stats->coupling.fluid_impulse.z};
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_impulse_hair_x", ledger[0], "N s", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_impulse_hair_y", ledger[1], "N s", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_impulse_hair_z", ledger[2], "N s", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_impulse_liquid_x", ledger[3], "N s", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_impulse_liquid_y", ledger[4], "N s", err));
        DR_TRY(dr_h5_write_scalar(h, g, "coupling_impulse_liquid_z", ledger[5], "N s", err));
    }
    /* Wall-clock seconds per phase are not written here: frame caches are bit-identical between runs
       (a determinism test compares them); timings go to progress.jsonl and report.json. */
    return DR_OK;
}

DrStatus dr_world_write_frame(const DrWorld *w, const DrFrameStats *stats, const char *bake_key, DrH5 *h,
                              DrError *err)
{
    dr_h5_set_compress(h, DR_H5_COMPRESS_ONE_VALUE); /* written every frame: see src/io/io_h5.c */
    return write_frame_body(w, stats, h, bake_key, err);
}

DrStatus dr_world_write_checkpoint(const DrWorld *w, const char *bake_key, DrH5 *h, DrError *err)
{
    WorldCtx c = context(w, w->frame);
    DR_TRY(dr_h5_attr_str(h, "/", "scene_key", bake_key, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "frame", w->frame, err));
    DR_TRY(dr_h5_attr_str(h, "/", "drench_version", DR_VERSION, err));
    for (int i = 0; i < w->nsolvers; i++) DR_TRY(w->solvers[i].write(w->solvers[i].self, &c, h, false, err));
    return DR_OK;
}

/* Every dataset of the checkpoint against its checksum, every number finite, before any solver takes a value from
 * it: a damaged checkpoint is named as such (with the element whose data is wrong), not left to surface frames later
 * as a solver's blow-up. */
static DrStatus check_checkpoint_data(const DrWorld *w, DrH5 *h, const char *path, int frame, DrError *err)
{
    char bad[512] = "";
    DrStatus s = dr_h5_verify(h, true, bad, sizeof bad, err);
    if (s != DR_ERR_INPUT) return s;
    /* the first component of a dataset's path is an element's group, or a solver's own (hair_solver) */
    char group[256] = "";
    if (bad[0] == '/') snprintf(group, sizeof group, "%.*s", (int)strcspn(bad + 1, "/"), bad + 1);
    const DrElement *e = group[0] ? dr_scene_find(w->scene, group) : NULL;
    char who[320];
    if (e) snprintf(who, sizeof who, "%s '%s'", e->type, e->name);
    else snprintf(who, sizeof who, "solver state '%s'", group[0] ? group : "/");
    dr_h5_drop_fix(err);
    char msg[sizeof err->message];
    snprintf(msg, sizeof msg, "%s", err->message);
    return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                        "the checkpoint after frame %d is damaged (%s of %s): %s; it cannot be resumed from: bake "
                        "without --resume to bake every frame again (pipeline.sh does it)",
                        frame, who, dr_scene_path(w->scene), msg);
}

DrStatus dr_world_read_checkpoint(DrWorld *w, const char *path, const char *bake_key, DrError *err)
{
    DrH5 *h = NULL;
    DR_TRY(dr_h5_open(path, &h, err));
    char *key = NULL;
    int64_t frame = 0;
    DrStatus s = dr_h5_read_attr_str(h, "/", "scene_key", &key, err);
    if (s == DR_OK && strcmp(key, bake_key) != 0)
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "checkpoint was written for another version of the scene (key %s, now %s); bake without "
                         "--resume to start over", key, bake_key);
    if (s == DR_OK) s = dr_h5_read_attr_i64(h, "/", "frame", &frame, err);
    if (s == DR_OK && (frame < w->first_frame - 1 || frame > w->last_frame))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "checkpoint frame %lld is outside the shot's frames %d-%d",
                         (long long)frame, w->first_frame, w->last_frame);
    if (s == DR_OK) s = check_checkpoint_data(w, h, path, (int)frame, err);
    WorldCtx c = context(w, (int)frame);
    for (int i = 0; s == DR_OK && i < w->nsolvers; i++)
        s = w->solvers[i].read(w->solvers[i].self, &c, h, path, (int)frame, err);
    if (s == DR_OK) w->frame = (int)frame;
    free(key);
    dr_h5_close(&h);
    return s;
}

DrHash dr_world_state_hash(const DrWorld *w)
{
    DrHasher h;
    dr_hasher_init(&h);
    dr_hasher_update(&h, &w->frame, sizeof w->frame);
    for (int i = 0; i < w->nsolvers; i++) w->solvers[i].hash(w->solvers[i].self, &h);
    return dr_hasher_final(&h);
}
