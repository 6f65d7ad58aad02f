/* The air adapter: the scene's air element (at most one) on the world's clock, its substeps from dr_air_stable_dt,
 * each one begin, project and end, with the scene's colliders; its frame cache group and its checkpoint.
 *
 * Frame cache, per frame, under /<air>/ (type "air"): max_speed (m/s), kinetic_energy (J), linear_momentum (kg·m/s),
 * mass (kg), inflow_flux and outflow_flux (m³/s, after the frame's last substep), divergence_max (1/s), substeps,
 * pressure_iterations_max and _total, pressure_residual_max, pressure_not_converged. The face velocities are not
 * written to frame caches (three grids of doubles every frame; the checkpoint holds them): /<air>/velocity_u, _v, _w
 * (m/s, the grid's face order, liquid.h's DrMacGrid) in checkpoint.h5 are the whole state a resume needs. */
#include "world_adapter.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "liquid/liquid.h"

typedef struct WorldAir {
    const DrElement *element;
    DrAir *air;
    DrAirStats frame;        /* the frame being advanced, summed over its substeps */
    DrAirStats last;         /* the last completed frame's */
    double from, h;          /* the substep dr_air_stable_dt proposed from t = from */
} WorldAir;

static const char *const velocity_names[3] = {"velocity_u", "velocity_v", "velocity_w"};

static DrStatus build_air(const WorldCtx *c, const DrElement *e, WorldAir *wa, DrError *err)
{
    const DrComponent *solver = dr_scene_section(c->scene, "solver");
    const DrComponent *dom = dr_element_component(e, "AirDomain");
    const DrComponent *mat = dr_element_component(e, "AirMaterial");
    const DrComponent *wind = dr_element_component(e, "Wind");
    wa->element = e;
    DrAirDesc d;
    dr_air_desc_default(&d);
    dr_component_box(dom, "box", &d.domain_lo, &d.domain_hi);
    d.dx = dr_component_num(dom, "voxel_size");
    d.density = dr_component_num(mat, "density");
    d.viscosity = dr_component_num(mat, "viscosity");
    const char *face = dr_component_str(wind, "face"); /* "-x" … "+z", checked by the scene */
    d.inflow_axis = face[1] - 'x';
    d.inflow_side = face[0] == '+';
    d.inflow_velocity = dr_component_vec3(wind, "velocity");
    d.ramp = dr_component_num(wind, "ramp");
    d.initial_stream = strcmp(dr_component_str(wind, "initial"), "stream") == 0;
    d.cfl = dr_component_num(solver, "cfl");
    d.max_substeps = dr_component_int(solver, "max_substeps");
    d.pressure_tol = dr_component_num(solver, "pressure_tolerance");
    d.pressure_max_iter = dr_component_int(solver, "pressure_max_iterations");
    return dr_error_prefix(dr_air_create(&d, &wa->air, err), err, "%s", e->name);
}

static DrStatus air_next_time(void *self, const WorldCtx *c, double t, double *t_next, DrError *err)
{
    WorldAir *wa = self;
    const DrCollider *const *cols = NULL;
    int n = world_kinematics_colliders(c->kin, &cols);
    DR_TRY(dr_air_stable_dt(wa->air, cols, n, t, c->t1, &wa->h, err));
    wa->from = t;
    *t_next = wa->h == c->t1 - t ? c->t1 : t + wa->h;
    return DR_OK;
}

/* The substep the clock chose (the one proposed when it ends where the proposal ended, else shorter) begun. */
static DrStatus begin_substep(WorldAir *wa, const WorldCtx *c, double t, double t_next, DrError *err)
{
    assert(t == wa->from);
    double proposed_end = wa->h == c->t1 - t ? c->t1 : t + wa->h;
    double h = t_next == proposed_end ? wa->h : t_next - t;
    const DrCollider *const *cols = NULL;
    int n = world_kinematics_colliders(c->kin, &cols);
    return dr_air_begin(wa->air, cols, n, t, h, err);
}

static DrStatus air_step(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    WorldAir *wa = self;
    DR_TRY(begin_substep(wa, c, t, t_next, err));
    DR_TRY(dr_air_project(wa->air, NULL, &wa->frame, err));
    return dr_air_end(wa->air, &wa->frame, err);
}

/* ---- the coupled step: the air as the fluid of the loop (src/couple) ---- */

static DrStatus fluid_project(void *ctx, const DrFaceCoupling *extra, DrError *err)
{
    WorldAir *wa = ctx;
    return dr_air_project(wa->air, extra, &wa->frame, err);
}
static void fluid_pressure(void *ctx, long n, const double *points, double *p, double *wet)
{
    dr_air_sample(((WorldAir *)ctx)->air, n, points, NULL, p);
    for (long i = 0; i < n; i++) wet[i] = 1.0; /* the air fills its box */
}
static const unsigned char *fluid_faces(void *ctx, int a) { return dr_air_coupled_faces(((WorldAir *)ctx)->air, a); }

static const double *fluid_mass(void *ctx, int a) { return dr_air_face_mass(((WorldAir *)ctx)->air, a); }

static void air_fluid_properties(const void *self, double *density, double *viscosity)
{
    const DrComponent *mat = dr_element_component(((const WorldAir *)self)->element, "AirMaterial");
    *density = dr_component_num(mat, "density");
    *viscosity = dr_component_num(mat, "viscosity");
}

static DrStatus air_fluid_begin(void *self, const WorldCtx *c, double t, double t_next, DrCoupleFluid *fluid,
                                DrError *err)
{
    WorldAir *wa = self;
    DR_TRY(begin_substep(wa, c, t, t_next, err));
    double density, viscosity;
    air_fluid_properties(wa, &density, &viscosity);
    *fluid = (DrCoupleFluid){wa, density, viscosity, dr_air_grid(wa->air), fluid_project, fluid_pressure, fluid_faces,
                             fluid_mass};
    return DR_OK;
}


static DrStatus air_fluid_end(void *self, const WorldCtx *c, DrError *err)
{
    (void)c;
    return dr_air_end(((WorldAir *)self)->air, &((WorldAir *)self)->frame, err);
}

static void air_begin_frame(void *self, const WorldCtx *c)
{
    (void)c;
    WorldAir *wa = self;
    memset(&wa->frame, 0, sizeof wa->frame);
}

static DrStatus air_end_frame(void *self, const WorldCtx *c, DrFrameStats *stats, DrError *err)
{
    (void)stats; /* the air has no block of the frame's stats yet: its figures go to the frame cache */
    WorldAir *wa = self;
    double mass, ke;
    DrVec3 p;
    dr_air_totals(wa->air, &mass, &p, &ke);
    if (!isfinite(ke) || !dr_v3_isfinite(p))
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "air '%s' became non-finite in frame %d; lower solver.cfl or raise solver.max_substeps",
                            wa->element->name, c->frame);
    wa->last = wa->frame;
    dr_log_debug("frame %d: air '%s': %d substeps, max speed %.4g m/s, kinetic energy %.6g J, flux in %.6g out %.6g "
                 "m^3/s", c->frame, wa->element->name, wa->last.substeps, wa->last.max_speed, ke, wa->last.inflow_flux,
                 wa->last.outflow_flux);
    return DR_OK;
}

static DrStatus air_write(const void *self, const WorldCtx *c, DrH5 *h, bool frame_cache, DrError *err)
{
    (void)c;
    const WorldAir *wa = self;
    const DrMacGrid *g = dr_air_grid(wa->air);
    char p[512];
    if (!frame_cache) {
        for (int a = 0; a < 3; a++) {
            uint64_t d[1] = {(uint64_t)g->nfaces[a]};
            PATHF(p, "/%s/%s", wa->element->name, velocity_names[a]);
            DR_TRY(dr_h5_write_f64(h, p, 1, d, g->f[a], "m/s", false, err));
        }
        return DR_OK;
    }
    PATHF(p, "/%s", wa->element->name);
    DR_TRY(dr_h5_attr_str(h, p, "type", "air", err));
    double mass, ke;
    DrVec3 mom;
    dr_air_totals(wa->air, &mass, &mom, &ke);
    const DrAirStats *s = &wa->last;
    DR_TRY(dr_h5_write_scalar(h, p, "max_speed", s->max_speed, "m/s", err));
    DR_TRY(dr_h5_write_scalar(h, p, "kinetic_energy", ke, "J", err));
    DR_TRY(dr_h5_write_vec3(h, p, "linear_momentum", mom, "kg*m/s", err));
    DR_TRY(dr_h5_write_scalar(h, p, "mass", mass, "kg", err));
    DR_TRY(dr_h5_write_scalar(h, p, "inflow_flux", s->inflow_flux, "m^3/s", err));
    DR_TRY(dr_h5_write_scalar(h, p, "outflow_flux", s->outflow_flux, "m^3/s", err));
    DR_TRY(dr_h5_write_scalar(h, p, "divergence_max", s->divergence_max, "1/s", err));
    DR_TRY(dr_h5_write_scalar(h, p, "substeps", s->substeps, "1", err));
    DR_TRY(dr_h5_write_scalar(h, p, "pressure_iterations_max", s->pressure_iterations_max, "1", err));
    DR_TRY(dr_h5_write_scalar(h, p, "pressure_iterations_total", (double)s->pressure_iterations_total, "1", err));
    DR_TRY(dr_h5_write_scalar(h, p, "pressure_residual_max", s->pressure_residual_max, "1", err));
    return dr_h5_write_scalar(h, p, "pressure_not_converged", s->pressure_not_converged, "1", err);
}

static DrStatus air_read(void *self, const WorldCtx *c, DrH5 *h, const char *path, int frame, DrError *err)
{
    (void)c;
    (void)frame;
    WorldAir *wa = self;
    const DrMacGrid *g = dr_air_grid(wa->air);
    double *f[3] = {NULL, NULL, NULL};
    DrStatus s = DR_OK;
    for (int a = 0; a < 3 && s == DR_OK; a++) {
        char p[512];
        int rank;
        uint64_t dims[4];
        PATHF(p, "/%s/%s", wa->element->name, velocity_names[a]);
        s = dr_h5_read_f64(h, p, &rank, dims, &f[a], err);
        if (s == DR_OK && (rank != 1 || dims[0] != (uint64_t)g->nfaces[a]))
            s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "the checkpoint's %s holds %llu values, the air '%s' has %ld "
                             "faces (the scene changed); delete the checkpoint and bake without --resume", p,
                             (unsigned long long)dims[0], wa->element->name, g->nfaces[a]);
    }
    if (s == DR_OK) s = dr_air_restore(wa->air, (const double *const *)f, err);
    for (int a = 0; a < 3; a++) free(f[a]);
    return s;
}

static void air_hash(const void *self, DrHasher *h)
{
    const WorldAir *wa = self;
    const DrMacGrid *g = dr_air_grid(wa->air);
    for (int a = 0; a < 3; a++) dr_hasher_update(h, g->f[a], sizeof(double) * (size_t)g->nfaces[a]);
}

static void air_destroy(void *self)
{
    WorldAir *wa = self;
    if (!wa) return;
    dr_air_destroy(&wa->air);
    free(wa);
}

DrStatus world_air_adapter(const WorldCtx *c, WorldSolver *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    const DrElement *e = NULL;
    for (int i = 0; i < dr_scene_element_count(c->scene) && !e; i++)
        if (dr_scene_element(c->scene, i)->kind == DR_ELEMENT_AIR) e = dr_scene_element(c->scene, i);
    if (!e) return DR_OK;
    WorldAir *wa = NULL;
    DR_TRY(dr_calloc(1, sizeof *wa, &wa, err));
    DrStatus s = build_air(c, e, wa, err);
    if (s < 0) {
        air_destroy(wa);
        return s;
    }
    *out = (WorldSolver){.name = "air",
                         .self = wa,
                         .begin_frame = air_begin_frame,
                         .next_time = air_next_time,
                         .step = air_step,
                         .end_frame = air_end_frame,
                         .write = air_write,
                         .read = air_read,
                         .hash = air_hash,
                         .destroy = air_destroy,
                         .fluid_begin = air_fluid_begin,
                         .fluid_end = air_fluid_end,
                         .fluid_properties = air_fluid_properties};
    return DR_OK;
}

DrAir *world_air_solver(const WorldSolver *s) { return s && s->self ? ((WorldAir *)s->self)->air : NULL; }
