/* The liquid adapter: one liquid element's solver on the world's clock (its substeps from dr_liquid_stable_dt, each
 * one begin, project and end), its frame cache and checkpoint groups and its block of the frame's stats. */
#include "world_adapter.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "liquid/liquid.h"

typedef struct WorldLiquid {
    const DrElement *element;
    DrLiquid *liquid;
    DrCollider **shapes;     /* LiquidSource mesh volumes, needed at creation only */
    int nshapes;
    double volume0;          /* first frame's liquid-cell volume, for the drift diagnostic */
    DrLiquidStats frame;     /* the frame being advanced, summed over its substeps */
    DrLiquidStats last;      /* the last completed frame's */
    double from, h;          /* the substep dr_liquid_stable_dt proposed from t = from */
    /* the stability watch: energy, and the particles' volume against the first frame checked */
    WorldWatch watch;
    double low;              /* J/kg: the least potential −g·x in the domain (a corner of its box) */
    double fill0;            /* dr_liquid_particle_volume over nominal at the watch's start */
    bool volume_alarm;       /* the volume alarm was raised (once per bake) */
    double volume, nominal;  /* m³: dr_liquid_particle_volume at the end of the last frame (diagnostics) */
    double density, viscosity; /* kg/m³, Pa·s: what the coupled loop's laws read */
    bool bodies;             /* the first liquid: the two-way BEM bodies take part in its projections */
    double h_cur;            /* the length of the substep begun */
    /* the MPM solids two-way with the first liquid (mpm_project): their particles on the faces, where they stand at
       the substep's end, the solid fraction of the cells for the push-out; allocated on first use */
    DrFaceCoupling *mfc;
    double *mx, *mv;         /* 3n */
    long mcap;
    double *mfrac;           /* per cell */
    long mpm_pushed;         /* the frame's liquid particles pushed out of them */
    double mpm_work;         /* J, the frame's work of the MPM solids on the liquid (the stability watch): minus the
                                work of the momentum they took, at their velocity mid-way through taking it */
    WorldWetLink *wet;       /* the first liquid: capture and dripping with the wet hair (world_wet.c; when on) */
    bool carved;             /* the liquid seeded inside them was removed (at the first substep of a bake; a
                                resumed bake restores particles that never held it) */
} WorldLiquid;

static void box_of(const DrComponent *c, const char *field, DrVec3 *lo, DrVec3 *hi) { dr_component_box(c, field, lo, hi); }

/* ---- the stability watch ------------------------------------------------------------------------------------- */

/* The liquid's energy (kinetic + potential −Σ m g·x), the part above the domain's lowest corner, and a floor of a
   thousandth of its weight lifted by a cell. */
static WorldEnergy liquid_energy(const WorldLiquid *wl, DrVec3 gravity)
{
    const DrLiquidState *st = dr_liquid_state(wl->liquid);
    double mass, ke;
    DrVec3 p, l;
    dr_liquid_totals(wl->liquid, &mass, &p, &l, &ke);
    double pe = 0.0, pm = dr_liquid_particle_mass(wl->liquid), v0 = dr_liquid_nominal_volume(wl->liquid);
    for (long i = 0; i < st->n; i++)
        pe -= pm * (st->vol[i] / v0) * (gravity.x * st->x[3 * i] + gravity.y * st->x[3 * i + 1] + gravity.z * st->x[3 * i + 2]);
    WorldEnergy e = {0};
    e.energy = ke + pe;
    e.available = fmax(0.0, e.energy - mass * wl->low);
    e.floor = 1e-12 + 1e-3 * mass * dr_v3_norm(gravity) * dr_liquid_grid(wl->liquid)->dx;
    return e;
}

static DrStatus watch_start(WorldLiquid *wl, const WorldCtx *c, int frame, DrError *err)
{
    WorldEnergy e = liquid_energy(wl, c->gravity);
    world_watch_start(&wl->watch, frame, &e);
    double v, nominal;
    DR_TRY(dr_liquid_particle_volume(wl->liquid, &v, &nominal, err));
    wl->fill0 = nominal > 0.0 ? v / nominal : 1.0;
    return DR_OK;
}

/* The liquid loses volume when its particles pile into fewer cells than they fill (steps far beyond the CFL
   condition, a pressure solve that does not hold them apart). Well-mixed particles fill ~95 % of their nominal
   volume and a dam break's stay above 90 %, measured over the shipped shots; an alarm at 20 % below the start leaves
   room for that and catches a collapse (fps 0.001 piled 98 % of a dam break into one cell). */
#define VOLUME_LOSS 0.20

static DrStatus watch_frame(WorldLiquid *wl, const WorldCtx *c, DrError *err)
{
    WorldEnergy e = liquid_energy(wl, c->gravity);
    const DrLiquidStats *ls = &wl->frame;
    e.work = ls->source_work + ls->emitted_energy - ls->killed_energy + wl->mpm_work;
    wl->mpm_work = 0.0;
    if (wl->wet) {
        /* capture and dripping: what the drops brought and the captured volume took */
        e.work += wl->wet->liquid_work;
        wl->wet->liquid_work = 0.0;
    }
    char who[200];
    snprintf(who, sizeof who, "liquid '%s'", wl->element->name);
    DR_TRY(world_watch_energy(&wl->watch, c, &e, who,
                              "lower solver.cfl or raise solver.max_substeps (smaller substeps)", err));
    double v, nominal;
    DR_TRY(dr_liquid_particle_volume(wl->liquid, &v, &nominal, err));
    wl->volume = v, wl->nominal = nominal;
    double fill = nominal > 0.0 ? v / nominal : 1.0;
    dr_log_debug("frame %d: liquid '%s': particle volume %.6g m^3 of %.6g (%.4f, at the start %.4f); energy %.6g J, "
                 "available %.6g J, work %.4g J", c->frame, wl->element->name, v, nominal, fill, wl->fill0, e.energy,
                 e.available, e.work);
    if (!wl->volume_alarm && fill < (1.0 - VOLUME_LOSS) * wl->fill0) {
        wl->volume_alarm = true;
        char msg[sizeof err->message];
        snprintf(msg, sizeof msg,
                 "frame %d: liquid '%s': its particles fill %.0f %% of their volume, against %.0f %% at the start: the "
                 "liquid collapsed (lost %.0f %% of its volume); lower solver.cfl or raise solver.max_substeps "
                 "(smaller substeps)",
                 c->frame, wl->element->name, 100.0 * fill, 100.0 * wl->fill0, 100.0 * (1.0 - fill / wl->fill0));
        DR_TRY(world_watch_alarm(&wl->watch, msg, err));
    }
    return DR_OK;
}

static DrStatus build_liquid(const WorldCtx *c, const DrElement *e, WorldLiquid *wl, DrError *err)
{
    const DrScene *scene = c->scene;
    const DrComponent *solver = dr_scene_section(scene, "solver");
    const DrComponent *shot = dr_scene_section(scene, "shot");
    const DrComponent *dom = dr_element_component(e, "Domain");
    const DrComponent *src = dr_element_component(e, "LiquidSource");
    const DrComponent *emit = dr_element_component(e, "Emitter");
    const DrComponent *kill = dr_element_component(e, "KillBox");
    const DrComponent *mat = dr_element_component(e, "LiquidMaterial");
    const DrComponent *tr = dr_element_component(e, "Transfer");
    const DrComponent *par = dr_element_component(e, "Particles");
    wl->element = e;
    for (int i = 0; i < dr_scene_element_count(c->scene); i++) {
        const DrElement *x = dr_scene_element(c->scene, i);
        if (x->kind == DR_ELEMENT_LIQUID) {
            wl->bodies = x == e;
            break;
        }
    }

    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    box_of(dom, "box", &d.domain_lo, &d.domain_hi);
    d.dx = dr_component_num(dom, "voxel_size");
    d.wall_no_slip = strcmp(dr_component_str(dom, "wall_boundary"), "no_slip") == 0;
    d.density = dr_component_num(mat, "density");
    d.viscosity = dr_component_num(mat, "viscosity");
    const char *scheme = dr_component_str(tr, "scheme");
    d.scheme = !strcmp(scheme, "pic") ? DR_TRANSFER_PIC : !strcmp(scheme, "flip") ? DR_TRANSFER_FLIP : DR_TRANSFER_APIC;
    /* the scene gives the FLIP fraction of the blend; the liquid takes the PIC fraction */
    d.flip_blend = 1.0 - dr_component_num(tr, "flip_blend");
    d.pressure = strcmp(dr_component_str(dr_element_component(e, "Pressure"), "formulation"), "mass_weighted") == 0
                     ? DR_PRESSURE_MASS_WEIGHTED
                     : DR_PRESSURE_GHOST_FLUID;
    d.volume_correction = dr_component_num(dr_element_component(e, "Pressure"), "volume_correction");
    d.per_cell = dr_component_int(par, "per_cell");
    d.jitter = dr_component_num(par, "jitter");
    /* the element's seed mixed with the shot's so two shots of one asset differ only if asked to */
    d.seed = (uint64_t)dr_component_int(par, "seed") * 0x9e3779b97f4a7c15ULL + (uint64_t)dr_component_int(shot, "seed");
    d.gravity = c->gravity;
    d.cfl = dr_component_num(solver, "cfl");
    d.max_substeps = dr_component_int(solver, "max_substeps");
    d.pressure_tol = dr_component_num(solver, "pressure_tolerance");
    d.pressure_max_iter = dr_component_int(solver, "pressure_max_iterations");
    d.pressure_precond = strcmp(dr_component_str(solver, "pressure_preconditioner"), "mic0") == 0 ? DR_PRECOND_MIC0
                                                                                                : DR_PRECOND_MULTIGRID;

    DrBoxVel source = {0}, emitter = {0};
    DrVec3 kill_lo, kill_hi, shape_vel = dr_v3(0, 0, 0);
    if (dr_component_present(src)) {
        shape_vel = dr_component_vec3(src, "velocity");
        if (dr_component_is_set(src, "box")) {
            box_of(src, "box", &source.lo, &source.hi);
            source.velocity = shape_vel;
            d.nsource_boxes = 1;
            d.source_boxes = &source;
        }
        if (dr_component_is_set(src, "mesh")) {
            DrTriMesh mesh = {0};
            DR_TRY(dr_error_prefix(dr_io_load_mesh(dr_component_str(src, "mesh"), &mesh, err), err, "%s.LiquidSource.mesh",
                                   e->name));
            DR_TRY(dr_calloc(1, sizeof(DrCollider *), &wl->shapes, err));
            DrStatus s = world_make_collider(&mesh, d.dx * 0.5, 0, false, 0, 0, NULL, &wl->shapes[0], err);
            dr_trimesh_free(&mesh);
            DR_TRY(dr_error_prefix(s, err, "%s.LiquidSource.mesh", e->name));
            wl->nshapes = 1;
            d.nsource_shapes = 1;
            d.source_shapes = (const DrCollider *const *)wl->shapes;
            d.source_shape_velocity = &shape_vel;
        }
    }
    if (dr_component_present(emit)) {
        box_of(emit, "box", &emitter.lo, &emitter.hi);
        emitter.velocity = dr_component_vec3(emit, "velocity");
        emitter.start = dr_component_num(emit, "start");
        emitter.end = dr_component_num(emit, "end");
        d.nemitters = 1;
        d.emitters = &emitter;
    }
    if (dr_component_present(kill)) {
        box_of(kill, "box", &kill_lo, &kill_hi);
        d.nkill_boxes = 1;
        d.kill_lo = &kill_lo;
        d.kill_hi = &kill_hi;
    }
    /* a frame must hold the substeps of liquid that falls or moves as it starts (the CFL step of liquid.h without
       the collider term): a longer substep carries it through the floor */
    double u0 = fmax(dr_v3_norm(source.velocity), dr_v3_norm(emitter.velocity));
    char what[200];
    snprintf(what, sizeof what, "liquid '%s'", e->name);
    DR_TRY(world_watch_frame_length(c, what, d.cfl * d.dx / (u0 + sqrt(5.0 * d.dx * dr_v3_norm(d.gravity))),
                                    "its CFL step as it starts to fall or move, cfl*dx/(|v0| + sqrt(5 dx |g|))", err));
    const DrCollider *const *cols = NULL;
    int ncols = world_kinematics_liquid_colliders(c->kin, &cols);
    world_watch_init(&wl->watch, scene);
    wl->low = INFINITY;
    for (int k = 0; k < 8; k++) {
        DrVec3 x = dr_v3(k & 1 ? d.domain_hi.x : d.domain_lo.x, k & 2 ? d.domain_hi.y : d.domain_lo.y,
                         k & 4 ? d.domain_hi.z : d.domain_lo.z);
        wl->low = fmin(wl->low, -dr_v3_dot(d.gravity, x));
    }
    wl->density = d.density;
    wl->viscosity = d.viscosity;
    DR_TRY(dr_liquid_create(&d, cols, ncols, &wl->liquid, err));
    return watch_start(wl, c, c->frame, err);
}

static DrStatus mpm_carve(WorldLiquid *wl, const WorldMpmParticles *mp, DrError *err);

static DrStatus liquid_next_time(void *self, const WorldCtx *c, double t, double *t_next, DrError *err)
{
    WorldLiquid *wl = self;
    WorldMpmParticles *mp = wl->bodies ? world_kinematics_mpm_particles(c->kin) : NULL;
    if (mp && mp->n > 0 && !wl->carved) DR_TRY(mpm_carve(wl, mp, err));
    const DrCollider *const *cols = NULL;
    int n = world_kinematics_liquid_colliders(c->kin, &cols);
    DR_TRY(dr_liquid_stable_dt(wl->liquid, cols, n, t, c->t1, &wl->h, err));
    wl->from = t;
    *t_next = wl->h == c->t1 - t ? c->t1 : t + wl->h;
    return DR_OK;
}

/* The substep the clock chose (the one proposed when it ends where the proposal ended, else shorter) begun. */
static DrStatus begin_substep(WorldLiquid *wl, const WorldCtx *c, double t, double t_next, DrError *err)
{
    assert(t == wl->from);
    double proposed_end = wl->h == c->t1 - t ? c->t1 : t + wl->h;
    double h = t_next == proposed_end ? wl->h : t_next - t;
    DrLiquidBody *lb = NULL;
    int nb = wl->bodies ? world_kinematics_liquid_bodies(c->kin, t, h, &lb, err) : 0;
    if (nb < 0) return nb;
    const DrCollider *const *cols = NULL;
    int n = world_kinematics_liquid_colliders(c->kin, &cols);
    wl->h_cur = h;
    DR_TRY(dr_liquid_begin(wl->liquid, cols, n, t, h, err));
    return nb > 0 ? dr_liquid_set_bodies(wl->liquid, lb, nb, err) : DR_OK;
}

/* The substep's end: the liquid ends (its push-out out of a body gives that body what it takes), then the two-way
   bodies take what the substep gave them. */
static DrStatus end_substep(WorldLiquid *wl, const WorldCtx *c, DrError *err)
{
    DR_TRY(dr_liquid_end(wl->liquid, &wl->frame, err));
    if (wl->bodies) world_kinematics_liquid_bodies_done(c->kin, wl->liquid);
    return DR_OK;
}

/* ---- the MPM solids two-way with the first liquid ----------------------------------------------------------------
 * A shared-grid mixture on the liquid's faces, chosen over a coupling on the MPM's own grid because the liquid's
 * pressure solve can then take the solids' inertia implicitly while keeping its 7-point matrix and multigrid:
 *   1. the liquid's substep [t, t + h] comes first in the clock step; the MPM particles where their last step left
 *      them are predicted to its end (x + h v, v + h g) and lumped onto the liquid's faces (dr_couple_particles_to_
 *      faces: blocked share, velocity, solid mass);
 *   2. the projection moves that solid with the pressure (dr_liquid_solid_momentum: each face's solid a point mass
 *      within the solve, so a light body cannot be given more than the pressure gives it: no added-mass
 *      instability) and the momentum each face's solid gained goes back to the particles with the same weights
 *      (dr_couple_faces_to_particles: exactly what the liquid reports in solid_gain);
 *   3. the liquid ends its substep and its particles are pushed out of the solid (fraction above ½, from the
 *      predicted positions);
 *   4. the MPM then steps over the same [t, t + h] (both step at every clock step) with that change as a force
 *      m_p δv_p / h on each particle within its step's solve (world_mpm.c), beside gravity and its contacts.
 * The bodies' elasticity stays explicit against the pressure within a substep (lagged by one substep). The cells they
 * fill are pressure cells of the projection (liquid.c), so the pressure runs on through a body, which moves with the
 * liquid there as one incompressible mixture. */
static DrStatus mpm_project(WorldLiquid *wl, const WorldCtx *c, WorldMpmParticles *mp, DrError *err)
{
    const DrMacGrid *g = dr_liquid_grid(wl->liquid);
    if (!wl->mfc) {
        DR_TRY(dr_face_coupling_create(g, &wl->mfc, err));
        DR_TRY(dr_face_coupling_add_solid_mass(wl->mfc, err));
        DR_TRY(dr_calloc((size_t)g->nx * g->ny * g->nz, sizeof(double), &wl->mfrac, err));
    }
    if (mp->n > wl->mcap) {
        DR_TRY(dr_realloc((size_t)(3 * mp->n), sizeof(double), &wl->mx, err));
        DR_TRY(dr_realloc((size_t)(3 * mp->n), sizeof(double), &wl->mv, err));
        wl->mcap = mp->n;
    }
    double h = wl->h_cur, gv[3] = {c->gravity.x, c->gravity.y, c->gravity.z};
    for (long i = 0; i < 3 * mp->n; i++) {
        wl->mv[i] = mp->v[i] + h * gv[i % 3];
        wl->mx[i] = mp->x[i] + h * mp->v[i];
    }
    dr_couple_particles_to_faces(g, mp->n, wl->mx, wl->mv, mp->mass, mp->volume, wl->mfc);
    DR_TRY(dr_liquid_project(wl->liquid, wl->mfc, &wl->frame, err));
    const double *mom[3];
    for (int a = 0; a < 3; a++) mom[a] = dr_liquid_solid_momentum(wl->liquid, a);
    dr_couple_faces_to_particles(g, mp->n, wl->mx, mom, wl->mfc, mp->dv);
    mp->pending = true;
    double w = 0.0;
    for (long i = 0; i < 3 * mp->n; i++) w -= mp->mass[i / 3] * mp->dv[i] * (wl->mv[i] + 0.5 * mp->dv[i]);
    wl->mpm_work += w;
    return DR_OK;
}

/* After the substep's end: the liquid's particles out of the solids where the substep left them. */
static void mpm_push_out(WorldLiquid *wl, const WorldMpmParticles *mp)
{
    const DrMacGrid *g = dr_liquid_grid(wl->liquid);
    dr_couple_particle_fraction(g, mp->n, wl->mx, mp->volume, wl->mfrac);
    DrLiquidState *st = dr_liquid_state_mut(wl->liquid);
    wl->mpm_pushed += dr_couple_push_out(g, wl->mfrac, st->n, st->x);
}

/* The liquid seeded where the MPM solids stand (a LiquidSource box around a body) removed before the first substep:
   the particles whose cell-centre solid fraction reads more than ½, as the push-out sees them. */
static DrStatus mpm_carve(WorldLiquid *wl, const WorldMpmParticles *mp, DrError *err)
{
    wl->carved = true;
    const DrMacGrid *g = dr_liquid_grid(wl->liquid);
    double *frac = NULL;
    DR_TRY(dr_calloc((size_t)g->nx * g->ny * g->nz, sizeof(double), &frac, err));
    dr_couple_particle_fraction(g, mp->n, mp->x, mp->volume, frac);
    const DrLiquidState *st = dr_liquid_state(wl->liquid);
    long n = st->n, kept = 0;
    double *x = NULL, *v = NULL, *cc = NULL, *vol = NULL;
    int64_t *id = NULL;
    DrStatus s = dr_calloc((size_t)(3 * n + 1), sizeof(double), &x, err);
    if (s == DR_OK) s = dr_calloc((size_t)(3 * n + 1), sizeof(double), &v, err);
    if (s == DR_OK) s = dr_calloc((size_t)(9 * n + 1), sizeof(double), &cc, err);
    if (s == DR_OK) s = dr_calloc((size_t)(n + 1), sizeof(double), &vol, err);
    if (s == DR_OK) s = dr_calloc((size_t)(n + 1), sizeof(int64_t), &id, err);
    for (long p = 0; s == DR_OK && p < n; p++) {
        if (dr_couple_fraction_at(g, frac, st->x + 3 * p, NULL) > 0.5) continue;
        memcpy(x + 3 * kept, st->x + 3 * p, 3 * sizeof(double));
        memcpy(v + 3 * kept, st->v + 3 * p, 3 * sizeof(double));
        memcpy(cc + 9 * kept, st->c + 9 * p, 9 * sizeof(double));
        vol[kept] = st->vol[p];
        id[kept++] = st->id[p];
    }
    if (s == DR_OK && kept < n) {
        DrLiquidResume rs;
        dr_liquid_resume_state(wl->liquid, &rs);
        s = dr_liquid_restore(wl->liquid, kept, x, v, cc, vol, id, &rs, err);
        if (s == DR_OK)
            dr_log_info("liquid '%s': %ld particles seeded inside the MPM solids removed", wl->element->name, n - kept);
    }
    free(x), free(v), free(cc), free(vol), free(id), free(frac);
    return s;
}

static DrStatus liquid_step(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    WorldLiquid *wl = self;
    DR_TRY(begin_substep(wl, c, t, t_next, err));
    WorldMpmParticles *mp = wl->bodies ? world_kinematics_mpm_particles(c->kin) : NULL;
    if (mp && mp->n > 0) DR_TRY(mpm_project(wl, c, mp, err));
    else DR_TRY(dr_liquid_project(wl->liquid, NULL, &wl->frame, err));
    DR_TRY(end_substep(wl, c, err));
    if (mp && mp->n > 0) mpm_push_out(wl, mp);
    return DR_OK;
}

/* ---- the coupled step: the liquid as the fluid of the loop (src/couple) ---- */

static DrStatus fluid_project(void *ctx, const DrFaceCoupling *extra, DrError *err)
{
    WorldLiquid *wl = ctx;
    return dr_liquid_project(wl->liquid, extra, &wl->frame, err);
}
/* The pressure as the liquid's sample gives it (0 at air and solid cell centres) and how much of each point's stencil
   is in the liquid (the pressure cells' weight of dr_liquid_sample_wet_pressure). The pressure extrapolated into solids
   was tried instead: strands starting inside tree_structure's solids then read gradients that fed back through the
   loop and blew the hair up in its first steps. */
static void fluid_pressure(void *ctx, long n, const double *points, double *p, double *wet)
{
    const DrLiquid *liq = ((WorldLiquid *)ctx)->liquid;
    dr_liquid_sample(liq, n, points, NULL, p);
    dr_liquid_sample_wet_pressure(liq, n, points, NULL, wet);
}
static const unsigned char *fluid_faces(void *ctx, int a)
{
    return dr_liquid_coupled_faces(((WorldLiquid *)ctx)->liquid, a);
}

static const double *fluid_mass(void *ctx, int a) { return dr_liquid_face_mass(((WorldLiquid *)ctx)->liquid, a); }

static DrStatus liquid_fluid_begin(void *self, const WorldCtx *c, double t, double t_next, DrCoupleFluid *fluid,
                                   DrError *err)
{
    WorldLiquid *wl = self;
    DR_TRY(begin_substep(wl, c, t, t_next, err));
    *fluid = (DrCoupleFluid){wl, wl->density, wl->viscosity, dr_liquid_grid(wl->liquid), fluid_project, fluid_pressure,
                             fluid_faces, fluid_mass};
    return DR_OK;
}

static void liquid_fluid_properties(const void *self, double *density, double *viscosity)
{
    const WorldLiquid *wl = self;
    *density = wl->density;
    *viscosity = wl->viscosity;
}

/* After every solver stepped to t_next (the liquid and the hair both stand there): capture and dripping, before the
   liquid's next stable_dt transfers its particles. */
static DrStatus liquid_step_last(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    (void)c, (void)t;
    WorldLiquid *wl = self;
    return wl->wet ? world_wet_exchange(wl->wet, t_next, err) : DR_OK;
}

static DrStatus liquid_fluid_end(void *self, const WorldCtx *c, DrError *err)
{
    WorldLiquid *wl = self;
    return end_substep(wl, c, err);
}

static void liquid_begin_frame(void *self, const WorldCtx *c)
{
    (void)c;
    WorldLiquid *wl = self;
    memset(&wl->frame, 0, sizeof wl->frame);
    wl->mpm_work = 0.0;
}

static bool all_finite(const double *a, long n)
{
    for (long i = 0; i < n; i++)
        if (!isfinite(a[i])) return false;
    return true;
}

static DrStatus liquid_end_frame(void *self, const WorldCtx *c, DrFrameStats *stats, DrError *err)
{
    WorldLiquid *wl = self;
    const DrLiquidState *st = dr_liquid_state(wl->liquid);
    if (!all_finite(st->x, 3 * st->n) || !all_finite(st->v, 3 * st->n))
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "liquid '%s' became non-finite in frame %d; lower solver.cfl or raise solver.max_substeps",
                            wl->element->name, c->frame);
    const DrLiquidStats *ls = &wl->frame;
    wl->last = *ls;
    if (wl->wet && wl->wet->on) {
        /* the volume ledger of capture and dripping: what the emitters added and the kill boxes removed */
        wl->wet->emitted += ls->emitted_volume;
        wl->wet->removed += ls->killed_volume;
    }
    double dx = dr_liquid_grid(wl->liquid)->dx;
    double vol = (double)ls->liquid_cells * dx * dx * dx;
    if (wl->volume0 == 0.0) wl->volume0 = vol;
    double mass, ke;
    DrVec3 p, l;
    dr_liquid_totals(wl->liquid, &mass, &p, &l, &ke);
    /* the block sums over liquid elements; the drift is of their summed volumes */
    DrLiquidFrameStats *b = &stats->liquid;
    b->present = true;
    b->volume += vol;
    b->volume0 += wl->volume0;
    b->drift = b->volume0 > 0 ? b->volume / b->volume0 - 1.0 : 0.0;
    for (long i = 0; i < st->n; i++) b->particle_volume += st->vol[i];
    b->emitted_volume += ls->emitted_volume;
    b->killed_volume += ls->killed_volume;
    b->kinetic_energy += ke;
    b->grid_impulse = dr_v3_add(b->grid_impulse, ls->grid_linear_impulse);
    if (wl->mfc) {
        b->mpm_impulse = dr_v3_add(b->mpm_impulse, ls->solid_gain);
        b->mpm_pushed += wl->mpm_pushed;
    }
    wl->mpm_pushed = 0;
    if (ls->substeps > b->substeps) b->substeps = ls->substeps;
    b->particles += ls->particles;
    if (ls->pressure_iterations_max > b->pressure_iterations_max) b->pressure_iterations_max = ls->pressure_iterations_max;
    b->pressure_iterations_total += ls->pressure_iterations_total;
    b->pressure_not_converged += ls->pressure_not_converged;
    b->seconds_p2g += ls->seconds_p2g;
    b->seconds_pressure += ls->seconds_pressure;
    b->seconds_g2p += ls->seconds_g2p;
    b->seconds_advect += ls->seconds_advect;
    b->seconds_other += ls->seconds_other;
    return watch_frame(wl, c, err);
}

/* position, velocity, affine (dr_h5_write_particles), id (N, int64: a particle's own for its life, liquid.h) and
   volume (N, m³: each particle's own, DrLiquidState.vol) */
static DrStatus write_liquid_arrays(DrH5 *h, const WorldLiquid *wl, bool compress, DrError *err)
{
    const DrLiquidState *st = dr_liquid_state(wl->liquid);
    DR_TRY(dr_h5_write_particles(h, wl->element->name, st->n, st->x, st->v, st->c, compress, err));
    char g[512];
    uint64_t d[1] = {(uint64_t)st->n};
    PATHF(g, "/%s/id", wl->element->name);
    DR_TRY(dr_h5_write_i64(h, g, 1, d, st->id, "1", compress, err));
    PATHF(g, "/%s/volume", wl->element->name);
    return dr_h5_write_f64(h, g, 1, d, st->vol, "m^3", compress, err);
}

static DrStatus liquid_write(const void *self, const WorldCtx *c, DrH5 *h, bool frame_cache, DrError *err)
{
    (void)c;
    const WorldLiquid *wl = self;
    char g[512];
    if (!frame_cache) {
        /* uncompressed: a checkpoint is written every frame and read rarely */
        DR_TRY(write_liquid_arrays(h, wl, false, err));
        DrLiquidResume rs;
        dr_liquid_resume_state(wl->liquid, &rs);
        uint64_t d[1] = {4}, d1[1] = {1};
        PATHF(g, "/%s/rng", wl->element->name);
        DR_TRY(dr_h5_write_u64(h, g, 1, d, rs.rng, false, err));
        PATHF(g, "/%s/cfl_acceleration", wl->element->name);
        DR_TRY(dr_h5_write_f64(h, g, 1, d1, &rs.cfl_accel, "m/s^2", false, err));
        PATHF(g, "/%s/next_id", wl->element->name);
        DR_TRY(dr_h5_write_i64(h, g, 1, d1, &rs.next_id, "1", false, err));
        PATHF(g, "/%s/volume0", wl->element->name);
        return dr_h5_write_f64(h, g, 1, d1, &wl->volume0, "m^3", false, err);
    }
    PATHF(g, "/%s", wl->element->name);
    DR_TRY(write_liquid_arrays(h, wl, true, err));
    DR_TRY(dr_h5_attr_str(h, g, "type", "liquid", err));
    double mass, ke;
    DrVec3 p, l;
    dr_liquid_totals(wl->liquid, &mass, &p, &l, &ke);
    const DrLiquidStats *ls = &wl->last;
    double dx = dr_liquid_grid(wl->liquid)->dx;
    PATHF(g, "/diagnostics/%s", wl->element->name);
    DR_TRY(dr_h5_write_scalar(h, g, "particles", (double)ls->particles, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mass", mass, "kg", err));
    DR_TRY(dr_h5_write_scalar(h, g, "kinetic_energy", ke, "J", err));
    DR_TRY(dr_h5_write_vec3(h, g, "linear_momentum", p, "kg*m/s", err));
    DR_TRY(dr_h5_write_vec3(h, g, "angular_momentum", l, "kg*m^2/s", err));
    DR_TRY(dr_h5_write_scalar(h, g, "volume_cells", (double)ls->liquid_cells * dx * dx * dx, "m^3", err));
    DR_TRY(dr_h5_write_scalar(h, g, "particle_volume", wl->volume, "m^3", err));
    DR_TRY(dr_h5_write_scalar(h, g, "particle_volume_nominal", wl->nominal, "m^3", err));
    DR_TRY(dr_h5_write_scalar(h, g, "max_speed", ls->max_speed, "m/s", err));
    DR_TRY(dr_h5_write_scalar(h, g, "divergence_mean", ls->divergence_mean, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "pressure_iterations_max", ls->pressure_iterations_max, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "pressure_iterations_total", (double)ls->pressure_iterations_total, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "pressure_residual_max", ls->pressure_residual_max, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "emitted", (double)ls->emitted, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "killed", (double)ls->killed, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "emitted_volume", ls->emitted_volume, "m^3", err));
    return dr_h5_write_scalar(h, g, "killed_volume", ls->killed_volume, "m^3", err);
}

static DrStatus read_liquid(DrH5 *h, const char *path, WorldLiquid *wl, const WorldCtx *ctx, int frame, DrError *err)
{
    const char *name = wl->element->name;
    char p[512];
    int rank;
    uint64_t dx[4], dv[4], dc[4], dr[4], d0[4], da[4], di[4], dn[4], dw[4];
    double *x = NULL, *v = NULL, *c = NULL, *v0 = NULL, *acc = NULL, *vol = NULL;
    uint64_t *rng = NULL;
    int64_t *id = NULL, *next_id = NULL;
    DrStatus s;
    PATHF(p, "/%s/position", name);
    s = dr_h5_read_f64(h, p, &rank, dx, &x, err);
    PATHF(p, "/%s/velocity", name);
    if (s == DR_OK) s = dr_h5_read_f64(h, p, &rank, dv, &v, err);
    PATHF(p, "/%s/affine", name);
    if (s == DR_OK) s = dr_h5_read_f64(h, p, &rank, dc, &c, err);
    PATHF(p, "/%s/rng", name);
    if (s == DR_OK) s = dr_h5_read_u64(h, p, &rank, dr, &rng, err);
    PATHF(p, "/%s/volume0", name);
    if (s == DR_OK) s = dr_h5_read_f64(h, p, &rank, d0, &v0, err);
    PATHF(p, "/%s/cfl_acceleration", name);
    if (s == DR_OK) s = dr_h5_read_f64(h, p, &rank, da, &acc, err);
    PATHF(p, "/%s/id", name);
    if (s == DR_OK && !dr_h5_has(h, p))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "the checkpoint holds no particle ids of '%s' (%s: written "
                         "by an older drench); delete the checkpoint and bake without --resume", name, p);
    if (s == DR_OK) s = dr_h5_read_i64(h, p, &rank, di, &id, err);
    PATHF(p, "/%s/volume", name);
    if (s == DR_OK && !dr_h5_has(h, p))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "the checkpoint holds no particle volumes of '%s' (%s: written "
                         "by an older drench); delete the checkpoint and bake without --resume", name, p);
    if (s == DR_OK) s = dr_h5_read_f64(h, p, &rank, dw, &vol, err);
    PATHF(p, "/%s/next_id", name);
    if (s == DR_OK) s = dr_h5_read_i64(h, p, &rank, dn, &next_id, err);
    if (s == DR_OK && (dx[0] != dv[0] || dx[0] != dc[0] || dx[0] != di[0] || dx[0] != dw[0] || dr[0] != 4 || d0[0] != 1 ||
                       da[0] != 1 || dn[0] != 1))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "checkpoint arrays of '%s' disagree in size; delete the "
                         "checkpoint and bake without --resume", name);
    if (s == DR_OK) {
        DrLiquidResume rs;
        memcpy(rs.rng, rng, sizeof rs.rng);
        rs.cfl_accel = acc[0];
        rs.next_id = next_id[0];
        s = dr_liquid_restore(wl->liquid, (long)dx[0], x, v, c, vol, id, &rs, err);
        if (s < 0 && err && !err->file[0]) snprintf(err->file, sizeof err->file, "%s", path); /* the checkpoint's */
    }
    if (s == DR_OK) wl->volume0 = v0[0];
    if (s == DR_OK) s = watch_start(wl, ctx, frame + 1, err);
    free(x);
    free(v);
    free(c);
    free(rng);
    free(v0);
    free(acc);
    free(id);
    free(vol);
    free(next_id);
    return s;
}

static DrStatus liquid_read(void *self, const WorldCtx *c, DrH5 *h, const char *path, int frame, DrError *err)
{
    ((WorldLiquid *)self)->carved = true;
    return read_liquid(h, path, self, c, frame, err);
}

static void liquid_hash(const void *self, DrHasher *h)
{
    const WorldLiquid *wl = self;
    const DrLiquidState *st = dr_liquid_state(wl->liquid);
    dr_hasher_update(h, &st->n, sizeof st->n);
    dr_hasher_update(h, st->x, 3 * sizeof(double) * (size_t)st->n);
    dr_hasher_update(h, st->v, 3 * sizeof(double) * (size_t)st->n);
    dr_hasher_update(h, st->c, 9 * sizeof(double) * (size_t)st->n);
    /* the volumes once a particle is not nominal (a liquid of nominal particles hashes as it did before they had one) */
    double v0 = dr_liquid_nominal_volume(wl->liquid);
    for (long i = 0; i < st->n; i++)
        if (st->vol[i] != v0) {
            dr_hasher_update(h, st->vol, sizeof(double) * (size_t)st->n);
            break;
        }
    DrLiquidResume rs;
    dr_liquid_resume_state(wl->liquid, &rs);
    dr_hasher_update(h, rs.rng, sizeof rs.rng);
    dr_hasher_update(h, &rs.cfl_accel, sizeof rs.cfl_accel);
}

static void liquid_destroy(void *self)
{
    WorldLiquid *wl = self;
    if (!wl) return;
    dr_liquid_destroy(&wl->liquid);
    dr_face_coupling_destroy(&wl->mfc);
    free(wl->mx), free(wl->mv), free(wl->mfrac);
    for (int k = 0; k < wl->nshapes; k++) dr_collider_destroy(&wl->shapes[k]);
    free(wl->shapes);
    free(wl);
}

DrStatus world_liquid_adapter(const WorldCtx *c, const DrElement *e, WorldSolver *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    WorldLiquid *wl = NULL;
    DR_TRY(dr_calloc(1, sizeof *wl, &wl, err));
    DrStatus s = build_liquid(c, e, wl, err);
    if (s < 0) {
        liquid_destroy(wl);
        return s;
    }
    WorldWetLink *link = world_kinematics_wet(c->kin);
    if (!link->liquid) {
        link->liquid = wl->liquid;
        wl->wet = link;
    }
    *out = (WorldSolver){.name = "liquid",
                         .self = wl,
                         .step_last = liquid_step_last,
                         .begin_frame = liquid_begin_frame,
                         .next_time = liquid_next_time,
                         .step = liquid_step,
                         .end_frame = liquid_end_frame,
                         .write = liquid_write,
                         .read = liquid_read,
                         .hash = liquid_hash,
                         .destroy = liquid_destroy,
                         .fluid_begin = liquid_fluid_begin,
                         .fluid_end = liquid_fluid_end,
                         .fluid_properties = liquid_fluid_properties};
    return DR_OK;
}

const DrLiquid *world_liquid_solver(const WorldSolver *s) { return ((const WorldLiquid *)s->self)->liquid; }
