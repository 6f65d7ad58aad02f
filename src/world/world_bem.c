/* The world's boundary-element bodies (seed sugimoto_surface_only_bem, "BEM"). Each bem_solid element is one
 * DrBemSolid on the matrices precompute left in the cache (bodies with one key share one set), posed by its
 * Transform, launched by its InitialVelocity, pulled by the shot's gravity, and advanced by whole steps of its own
 * Δt, BemSolver.time_step, every frame. The bodies do not touch anything yet (contact comes with constraints), so
 * each is stepped on its own, one after the other.
 *
 * Also the one preparation of a bem_solid element (mesh, build parameters, cache key) that precompute and the
 * world share. */
#include "world_internal.h"

#include <stdlib.h>
#include <string.h>

/* ---- the element as the BEM takes it ------------------------------------------------------------------------ */

/* Welding merges vertices closer than this fraction of the bounding-box diagonal: far below any real feature,
 * far above the float rounding of the loader (6e-8 relative) only where a file holds the same point twice with
 * different digits. A change here changes the matrices: it goes with a new DR_BEM_VERSION. */
#define WELD_RELATIVE 1e-9

/* Prefixes "<element>.Mesh.file: " to a failure's message, so it names the element as well as the file. */
static DrStatus in_element(DrStatus s, const DrWorldBemAsset *a, DrError *err)
{
    if (s >= 0) return s;
    char msg[sizeof err->message];
    int n = snprintf(msg, sizeof msg, "%s.Mesh.file: %s", a->element->name, err->message);
    if (n >= (int)sizeof msg) msg[sizeof msg - 2] = '.';
    memcpy(err->message, msg, sizeof msg);
    if (!err->file[0]) snprintf(err->file, sizeof err->file, "%s", a->path);
    return s;
}

static DrBemOrdering ordering_of(const char *name)
{
    DrBemOrdering o = DR_BEM_ORDER_VERTEX_XYZ;
    bool known = dr_bem_ordering_parse(name, &o);
    assert(known); /* the scene's enum admits nothing else */
    (void)known;
    return o;
}

/* The element's components as build parameters; what the scene does not set keeps dr_bem_desc_default. */
static void desc_of(const DrElement *e, DrBemDesc *d)
{
    dr_bem_desc_default(d);
    const DrComponent *mat = dr_element_component(e, "LinearElastic");
    const DrComponent *cmp = dr_element_component(e, "Compression");
    const DrComponent *sol = dr_element_component(e, "BemSolver");
    d->material.density = dr_component_num(mat, "density");
    d->material.shear_modulus = dr_component_num(mat, "shear_modulus");
    d->material.poisson = dr_component_num(mat, "poisson");
    d->compression_ratio = dr_component_num(cmp, "ratio");
    d->ordering = ordering_of(dr_component_str(cmp, "ordering"));
    d->dt = dr_component_num(sol, "time_step");
    d->history_margin = dr_component_num(sol, "history_margin");
    d->quad_levels = dr_component_int(sol, "quadrature_levels");
    d->keep_dense = false;
}

DrStatus dr_world_bem_asset_load(const DrElement *e, DrWorldBemAsset *a, DrError *err)
{
    memset(a, 0, sizeof *a);
    a->element = e;
    a->path = dr_component_str(dr_element_component(e, "Mesh"), "file");
    DR_TRY(in_element(dr_io_load_mesh(a->path, &a->mesh, err), a, err));
    DrVec3 lo, hi;
    double diag = dr_trimesh_bounds(&a->mesh, &lo, &hi) ? dr_v3_norm(dr_v3_sub(hi, lo)) : 0.0;
    a->vertices_in_file = a->mesh.nv;
    a->weld_tolerance = WELD_RELATIVE * diag;
    DrStatus s = in_element(dr_bem_mesh_weld(&a->mesh, a->weld_tolerance, &a->welded, err), a, err);
    if (s == DR_OK) s = in_element(dr_bem_mesh_check(&a->mesh, a->path, err), a, err);
    DrHash h;
    if (s == DR_OK) s = in_element(dr_hash_file(a->path, &h, err), a, err);
    if (s != DR_OK) {
        dr_world_bem_asset_free(a);
        return s;
    }
    dr_hash_hex(h, a->mesh_hash);
    desc_of(e, &a->desc);
    dr_bem_cache_key(a->mesh_hash, &a->desc, a->key);
    return DR_OK;
}

void dr_world_bem_asset_free(DrWorldBemAsset *a) { dr_trimesh_free(&a->mesh); }

/* ---- the bodies --------------------------------------------------------------------------------------------- */

void dr_world_bem_destroy_(WorldBem **bp)
{
    if (!bp || !*bp) return;
    WorldBem *b = *bp;
    for (int i = 0; i < b->nbodies; i++) {
        dr_bem_solid_destroy(&b->bodies[i].solid);
        free(b->bodies[i].state);
    }
    for (int k = 0; k < b->nsets; k++) dr_bem_matrices_destroy(&b->sets[k]);
    free(b->bodies);
    free(b->sets);
    free(b->keys);
    free(b);
    *bp = NULL;
}

/* Prefixes "bem_solid '<name>'" context to a failure the BEM runtime reported. */
static DrStatus body_context(DrStatus s, const char *name, const char *what, DrError *err)
{
    if (s >= 0) return s;
    char msg[sizeof err->message];
    int n = snprintf(msg, sizeof msg, "bem_solid '%s' %s: %s", name, what, err->message);
    if (n >= (int)sizeof msg) msg[sizeof msg - 2] = '.';
    memcpy(err->message, msg, sizeof msg);
    return s;
}

/* The matrix set of the asset's key: one already read, or read now. No trusted file under the key is bad input:
   precompute has not run for this version of the body. */
static DrStatus matrices_of(WorldBem *b, const DrScene *scene, const DrWorldBemAsset *a, const char *cache_root,
                            const DrBemMatrices **out, DrError *err)
{
    for (int k = 0; k < b->nsets; k++)
        if (strcmp(b->keys[k], a->key) == 0) {
            *out = b->sets[k];
            return DR_OK;
        }
    DrBemMatrices *m = NULL;
    bool found = false;
    DR_TRY(body_context(dr_bem_cache_read(cache_root, a->key, &m, &found, err), a->element->name,
                        "cannot read its matrices", err));
    char path[DR_IO_PATH_MAX];
    dr_io_precache_path(cache_root, "bem", a->key, path, sizeof path);
    if (!found)
        return dr_error_set(err, DR_ERR_INPUT, dr_scene_path(scene), 0, 0,
                            "%s: no precomputed BEM matrices for its cache key %s (%s is missing or unfinished); run "
                            "precompute on this scene first (pipeline.sh runs it)",
                            a->element->name, a->key, path);
    /* the key covers the mesh file's bytes and the weld: a disagreement means a file not made by this code */
    if (m->nv != a->mesh.nv || m->nt != a->mesh.nt) {
        DrStatus s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                                  "%s: the cached matrices are for %d vertices and %d triangles but %s welds to %d and "
                                  "%d; delete %s and run precompute again",
                                  a->element->name, m->nv, m->nt, a->path, a->mesh.nv, a->mesh.nt, path);
        dr_bem_matrices_destroy(&m);
        return s;
    }
    b->sets[b->nsets] = m;
    snprintf(b->keys[b->nsets], sizeof b->keys[b->nsets], "%s", a->key);
    b->nsets++;
    *out = m;
    return DR_OK;
}

/* The body's state at t = 0. The cached rest mesh x is in the mesh file's coordinates; the Transform (scale 1,
   a scene rule) places it at R₀x + t, so with V = R(x − x̄ + u) + T the frame starts at R = R₀ and T = R₀x̄ + t. */
static void solid_desc_of(const DrWorld *w, const DrElement *e, const DrBemMatrices *m, DrBemSolidDesc *d)
{
    dr_bem_solid_desc_default(d);
    double scale;
    DrXform X = dr_world_transform_(e, &scale);
    assert(scale == 1.0);
    DrVec3 c = dr_v3(m->body.centroid[0], m->body.centroid[1], m->body.centroid[2]);
    DrVec3 T = dr_v3_add(dr_m3_apply(X.R, c), X.t);
    const DrComponent *iv = dr_element_component(e, "InitialVelocity");
    DrVec3 v = dr_component_vec3(iv, "velocity");
    DrVec3 omega = dr_v3_scale(dr_component_vec3(iv, "angular_velocity"), DR_PI / 180.0);
    const DrComponent *sol = dr_element_component(e, "BemSolver");
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) d->rotation[3 * i + j] = X.R.m[i][j];
    double Ta[3] = {T.x, T.y, T.z}, va[3] = {v.x, v.y, v.z}, wa[3] = {omega.x, omega.y, omega.z};
    double ga[3] = {w->gravity.x, w->gravity.y, w->gravity.z};
    memcpy(d->position, Ta, sizeof Ta);
    memcpy(d->velocity, va, sizeof va);
    memcpy(d->angular_velocity, wa, sizeof wa);
    memcpy(d->gravity, ga, sizeof ga);
    d->frame_update = dr_component_bool(sol, "frame_update");
    d->error_correction = dr_component_bool(sol, "error_correction");
}

static DrStatus add_body(DrWorld *w, WorldBem *b, const DrElement *e, const char *cache_root, WorldBemBody *wb,
                         DrError *err)
{
    wb->element = e;
    DrWorldBemAsset a;
    DR_TRY(dr_world_bem_asset_load(e, &a, err));
    const DrBemMatrices *m = NULL;
    DrStatus s = matrices_of(b, w->scene, &a, cache_root, &m, err);
    char key[33];
    memcpy(key, a.key, sizeof key);
    dr_world_bem_asset_free(&a); /* the matrices hold the welded mesh */
    DR_TRY(s);
    /* whole steps per frame: the scene refuses a time_step that does not divide 1/fps */
    double ratio = 1.0 / (w->fps * m->desc.dt);
    wb->steps_per_frame = (int)floor(ratio + 0.5);
    assert(wb->steps_per_frame >= 1 && fabs(ratio - wb->steps_per_frame) <= 1e-6 * ratio);
    DrBemSolidDesc d;
    solid_desc_of(w, e, m, &d);
    DR_TRY(body_context(dr_bem_solid_create(m, &d, &wb->solid, err), e->name, "cannot start", err));
    wb->state_size = dr_bem_solid_state_size(wb->solid);
    DR_TRY(dr_calloc(wb->state_size + 1, sizeof(double), &wb->state, err));
    dr_log_info("bem: %s: %d vertices, matrices %s (n_max %d), %d steps of %.6g s per frame%s", e->name, m->nv, key,
                m->n_max, wb->steps_per_frame, m->desc.dt,
                d.frame_update ? (d.error_correction ? "" : ", no error correction") : ", fixed frame");
    return DR_OK;
}

DrStatus dr_world_bem_create_(DrWorld *w, const char *cache_root, DrError *err)
{
    int n = dr_scene_count_type(w->scene, "bem_solid");
    if (n == 0) return DR_OK;
    WorldBem *b = NULL;
    DR_TRY(dr_calloc(1, sizeof *b, &b, err));
    w->bem = b;
    DR_TRY(dr_calloc((size_t)n, sizeof *b->bodies, &b->bodies, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *b->sets, &b->sets, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *b->keys, &b->keys, err));
    for (int i = 0; i < dr_scene_element_count(w->scene); i++) {
        const DrElement *e = dr_scene_element(w->scene, i);
        if (strcmp(e->type, "bem_solid") != 0) continue;
        DR_TRY(add_body(w, b, e, cache_root, &b->bodies[b->nbodies++], err));
    }
    return DR_OK;
}

static bool finite_array(const double *a, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(a[i])) return false;
    return true;
}

DrStatus dr_world_bem_step_(DrWorld *w, int frame, DrFrameStats *stats, DrError *err)
{
    WorldBem *b = w->bem;
    if (!b) return DR_OK;
    stats->bem = true;
    stats->bem_bodies = b->nbodies;
    for (int i = 0; i < b->nbodies; i++) {
        WorldBemBody *wb = &b->bodies[i];
        const char *name = wb->element->name;
        DrBemStepStats sum = {0};
        wb->last_steps = 0;
        for (int k = 0; k < wb->steps_per_frame; k++) {
            DrBemStepStats st;
            DrStatus s = dr_bem_solid_step(wb->solid, NULL, &st, err);
            if (s < 0) {
                char what[64];
                snprintf(what, sizeof what, "failed in frame %d", frame);
                return body_context(s, name, what, err);
            }
            if (s > 0) dr_log_warn("bem: %s: frame %d: %s", name, frame, err->message);
            sum.seconds_history += st.seconds_history;
            sum.seconds_solve += st.seconds_solve;
            sum.seconds_correction += st.seconds_correction;
            sum.translation_error = fmax(sum.translation_error, st.translation_error);
            sum.rotation_error = fmax(sum.rotation_error, st.rotation_error);
            wb->last_steps++;
        }
        wb->last = sum;
        /* the runtime refuses a non-finite step; the pose is checked here as well because everything downstream
           (frame cache, mesh, render) is built from it */
        double R[9], T[3];
        dr_bem_solid_pose(wb->solid, R, T);
        const DrBemMatrices *m = dr_bem_solid_matrices(wb->solid);
        if (!finite_array(R, 9) || !finite_array(T, 3) || !finite_array(dr_bem_solid_displacement(wb->solid), (size_t)m->n))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "bem_solid '%s' became non-finite in frame %d; lower %s.BemSolver.time_step (and run "
                                "precompute again) or check its LinearElastic material",
                                name, frame, name);
        DrBemSolidDiag dg;
        dr_bem_solid_diagnostics(wb->solid, &dg);
        stats->bem_steps += wb->last_steps;
        stats->bem_kinetic_energy += dg.kinetic;
        stats->bem_potential_energy += dg.potential;
        stats->bem_momentum = dr_v3_add(stats->bem_momentum, dr_v3(dg.momentum[0], dg.momentum[1], dg.momentum[2]));
        stats->bem_max_displacement = fmax(stats->bem_max_displacement, dg.max_displacement);
        stats->bem_translation_error = fmax(stats->bem_translation_error, sum.translation_error);
        stats->bem_rotation_error = fmax(stats->bem_rotation_error, sum.rotation_error);
        stats->seconds_bem_history += sum.seconds_history;
        stats->seconds_bem_solve += sum.seconds_solve;
        stats->seconds_bem_correction += sum.seconds_correction;
        stats->kinetic_energy += dg.kinetic;
        if (wb->steps_per_frame > stats->substeps) stats->substeps = wb->steps_per_frame;
    }
    return DR_OK;
}

/* ---- files -------------------------------------------------------------------------------------------------- */

static DrStatus write_vec3(DrH5 *h, const char *name, const char *what, const double v[3], const char *units,
                           DrError *err)
{
    char path[512];
    PATHF(path, "/%s/%s", name, what);
    return dr_h5_write_f64(h, path, 1, (uint64_t[]){3}, v, units, false, err);
}

/* The body's surface data (DESIGN §4): V = R·(reference + displacement) + translation. */
static DrStatus write_body(DrH5 *h, const WorldBemBody *wb, DrError *err)
{
    const char *name = wb->element->name;
    const DrBemMatrices *m = dr_bem_solid_matrices(wb->solid);
    double R[9], T[3], v[3], omega[3];
    dr_bem_solid_pose(wb->solid, R, T);
    dr_bem_solid_frame_velocity(wb->solid, v, omega);
    char path[512];
    PATHF(path, "/%s/rotation", name);
    DR_TRY(dr_h5_write_f64(h, path, 2, (uint64_t[]){3, 3}, R, "1", false, err));
    DR_TRY(write_vec3(h, name, "translation", T, "m", err));
    DR_TRY(write_vec3(h, name, "velocity", v, "m/s", err));
    DR_TRY(write_vec3(h, name, "angular_velocity", omega, "rad/s", err));
    uint64_t dn[2] = {(uint64_t)m->nv, 3}, dt[2] = {(uint64_t)m->nt, 3};
    PATHF(path, "/%s/displacement", name);
    DR_TRY(dr_h5_write_f64(h, path, 2, dn, dr_bem_solid_displacement(wb->solid), "m", true, err));
    PATHF(path, "/%s/reference", name);
    DR_TRY(dr_h5_write_f64(h, path, 2, dn, dr_bem_solid_reference(wb->solid), "m", true, err));
    int32_t *tri = NULL;
    DR_TRY(dr_calloc(3 * (size_t)m->nt + 1, sizeof *tri, &tri, err));
    for (long k = 0; k < 3L * m->nt; k++) tri[k] = m->tri[k];
    PATHF(path, "/%s/triangles", name);
    DrStatus s = dr_h5_write_i32(h, path, 2, dt, tri, "1", true, err);
    free(tri);
    DR_TRY(s);
    PATHF(path, "/%s", name);
    DR_TRY(dr_h5_attr_str(h, path, "type", "bem_solid", err));
    return dr_h5_attr_f64(h, path, "time_step", m->desc.dt, err);
}

static DrStatus write_body_diagnostics(DrH5 *h, const WorldBemBody *wb, const DrBemSolidDiag *dg, DrError *err)
{
    char g[512];
    PATHF(g, "/diagnostics/%s", wb->element->name);
    const DrBemMatrices *m = dr_bem_solid_matrices(wb->solid);
    DR_TRY(dr_world_write_vec_(h, g, "linear_momentum", dr_v3(dg->momentum[0], dg->momentum[1], dg->momentum[2]),
                               "kg*m/s", err));
    DR_TRY(dr_world_write_vec_(h, g, "angular_momentum",
                               dr_v3(dg->angular_momentum[0], dg->angular_momentum[1], dg->angular_momentum[2]),
                               "kg*m^2/s", err));
    DR_TRY(dr_world_write_scalar_(h, g, "kinetic_energy", dg->kinetic, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "potential_energy", dg->potential, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "volume", dg->volume, "m^3", err));
    DR_TRY(dr_world_write_scalar_(h, g, "max_displacement", dg->max_displacement, "m", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mass", m->body.mass, "kg", err));
    DR_TRY(dr_world_write_scalar_(h, g, "steps", (double)wb->last_steps, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "time_step", m->desc.dt, "s", err));
    DR_TRY(dr_world_write_scalar_(h, g, "translation_error", wb->last.translation_error, "m", err));
    DR_TRY(dr_world_write_scalar_(h, g, "rotation_error", wb->last.rotation_error, "rad", err));
    return DR_OK;
}

/* Frame cache: surfaces and diagnostics. Wall-clock seconds stay out (frame caches are bit-identical between runs);
   progress.jsonl has them. */
static DrStatus write_frame(const WorldBem *b, DrH5 *h, DrError *err)
{
    DrBemSolidDiag tot = {0};
    long steps = 0;
    DrVec3 L = dr_v3(0, 0, 0); /* about the origin: Σ (T × m Ṫ + L_c) */
    for (int i = 0; i < b->nbodies; i++) {
        const WorldBemBody *wb = &b->bodies[i];
        DrBemSolidDiag dg;
        dr_bem_solid_diagnostics(wb->solid, &dg);
        DR_TRY(write_body(h, wb, err));
        DR_TRY(write_body_diagnostics(h, wb, &dg, err));
        double R[9], T[3];
        dr_bem_solid_pose(wb->solid, R, T);
        DrVec3 p = dr_v3(dg.momentum[0], dg.momentum[1], dg.momentum[2]);
        L = dr_v3_add(L, dr_v3_add(dr_v3_cross(dr_v3(T[0], T[1], T[2]), p),
                                   dr_v3(dg.angular_momentum[0], dg.angular_momentum[1], dg.angular_momentum[2])));
        for (int a = 0; a < 3; a++) tot.momentum[a] += dg.momentum[a];
        tot.kinetic += dg.kinetic;
        tot.potential += dg.potential;
        tot.volume += dg.volume;
        tot.max_displacement = fmax(tot.max_displacement, dg.max_displacement);
        steps += wb->last_steps;
    }
    const char *g = "/diagnostics";
    DR_TRY(dr_world_write_scalar_(h, g, "bem_bodies", b->nbodies, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "bem_steps", (double)steps, "1", err));
    DR_TRY(dr_world_write_vec_(h, g, "bem_linear_momentum", dr_v3(tot.momentum[0], tot.momentum[1], tot.momentum[2]),
                               "kg*m/s", err));
    DR_TRY(dr_world_write_vec_(h, g, "bem_angular_momentum", L, "kg*m^2/s", err));
    DR_TRY(dr_world_write_scalar_(h, g, "bem_kinetic_energy", tot.kinetic, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "bem_potential_energy", tot.potential, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "bem_total_energy", tot.kinetic + tot.potential, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "bem_volume", tot.volume, "m^3", err));
    DR_TRY(dr_world_write_scalar_(h, g, "bem_max_displacement", tot.max_displacement, "m", err));
    return DR_OK;
}

DrStatus dr_world_bem_write_(const DrWorld *w, DrH5 *h, bool frame_cache, DrError *err)
{
    const WorldBem *b = w->bem;
    if (!b) return DR_OK;
    if (frame_cache) return write_frame(b, h, err);
    for (int i = 0; i < b->nbodies; i++) {
        const WorldBemBody *wb = &b->bodies[i];
        dr_bem_solid_state_get(wb->solid, wb->state);
        char path[512];
        PATHF(path, "/%s/state", wb->element->name);
        DR_TRY(dr_h5_write_f64(h, path, 1, (uint64_t[]){wb->state_size}, wb->state, NULL, false, err));
        int64_t steps = dr_bem_solid_steps(wb->solid);
        PATHF(path, "/%s/steps", wb->element->name);
        DR_TRY(dr_h5_write_i64(h, path, 1, (uint64_t[]){1}, &steps, "1", false, err));
    }
    return DR_OK;
}

DrStatus dr_world_bem_read_(DrWorld *w, DrH5 *h, const char *file, int frame, DrError *err)
{
    WorldBem *b = w->bem;
    if (!b) return DR_OK;
    for (int i = 0; i < b->nbodies; i++) {
        WorldBemBody *wb = &b->bodies[i];
        const char *name = wb->element->name;
        char path[512], spath[512];
        PATHF(path, "/%s/state", name);
        PATHF(spath, "/%s/steps", name);
        int rank, srank;
        uint64_t dims[4], sdims[4];
        double *state = NULL;
        int64_t *steps = NULL;
        DrStatus s = dr_h5_read_f64(h, path, &rank, dims, &state, err);
        if (s == DR_OK) s = dr_h5_read_i64(h, spath, &srank, sdims, &steps, err);
        /* the checkpoint's frame fixes how many steps the body has taken */
        long expect = (long)(frame - w->first_frame + 1) * wb->steps_per_frame;
        if (s == DR_OK && (rank != 1 || dims[0] != wb->state_size))
            s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                             "checkpoint dataset %s holds %llu numbers where bem_solid '%s' has %zu; delete the "
                             "checkpoint and bake without --resume",
                             path, (unsigned long long)dims[0], name, wb->state_size);
        if (s == DR_OK && (srank != 1 || sdims[0] != 1 || steps[0] != expect))
            s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                             "checkpoint of bem_solid '%s' after frame %d holds %lld steps where %ld steps of %d per "
                             "frame are due; delete the checkpoint and bake without --resume",
                             name, frame, sdims[0] == 1 ? (long long)steps[0] : -1LL, expect, wb->steps_per_frame);
        if (s == DR_OK) s = body_context(dr_bem_solid_state_set(wb->solid, state, wb->state_size, err), name,
                                         "cannot resume from the checkpoint", err);
        if (s == DR_OK && dr_bem_solid_steps(wb->solid) != expect)
            s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                             "checkpoint state of bem_solid '%s' is at step %ld where frame %d needs step %ld; delete "
                             "the checkpoint and bake without --resume",
                             name, dr_bem_solid_steps(wb->solid), frame, expect);
        if (s == DR_ERR_INPUT && !err->file[0]) snprintf(err->file, sizeof err->file, "%s", file);
        free(state);
        free(steps);
        DR_TRY(s);
    }
    return DR_OK;
}

void dr_world_bem_hash_(const DrWorld *w, DrHasher *h)
{
    const WorldBem *b = w->bem;
    if (!b) return;
    for (int i = 0; i < b->nbodies; i++) {
        const WorldBemBody *wb = &b->bodies[i];
        dr_bem_solid_state_get(wb->solid, wb->state);
        dr_hasher_update(h, wb->state, wb->state_size * sizeof(double));
    }
}
