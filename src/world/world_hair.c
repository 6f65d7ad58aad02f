/* The world's hair: every hair element of a scene is one batch of a single DrRodSet (they are solved together,
 * so strands of different elements can touch), stepped with the scene colliders and the scalp motion. */
#include "world_internal.h"

#include <stdlib.h>
#include <string.h>

void dr_world_hair_destroy_(WorldHair **hp)
{
    if (!hp || !*hp) return;
    WorldHair *h = *hp;
    dr_rod_set_destroy(&h->rods);
    for (int i = 0; i < h->nelements; i++) free(h->keys[i]);
    free(h->keys);
    free(h->nkeys);
    free(h->elements);
    free(h->poses);
    free(h->colliders);
    free(h->ctx);
    free(h);
    *hp = NULL;
}

/* The strands of one hair element in its scene pose: grown from its Transform-posed scalp, or read from its
   curves file and moved by its Transform. */
static DrStatus load_groom(const DrElement *e, DrGroom *g, DrError *err)
{
    const DrComponent *gc = dr_element_component(e, "Groom");
    if (dr_component_is_set(gc, "scalp")) {
        DrTriMesh scalp = {0};
        DR_TRY(dr_world_load_posed_mesh_(e, dr_component_str(gc, "scalp"), "Groom.scalp", &scalp, err));
        DrGroomDesc d;
        dr_groom_desc_default(&d);
        d.count = dr_component_int(gc, "count");
        d.length = dr_component_num(gc, "length");
        d.segments = dr_component_int(gc, "segments");
        d.curl_radius = dr_component_num(gc, "curl_radius");
        d.curl_pitch = dr_component_num(gc, "curl_pitch");
        d.length_jitter = dr_component_num(gc, "length_jitter");
        d.seed = (uint64_t)dr_component_int(gc, "seed");
        DrStatus s = dr_groom_grow(&scalp, &d, g, err);
        dr_trimesh_free(&scalp);
        return dr_world_asset_context_(s, e->name, "Groom.scalp", err);
    }
    DR_TRY(dr_world_asset_context_(dr_groom_read_obj(dr_component_str(gc, "curves"), g, err), e->name, "Groom.curves",
                                   err));
    double sc;
    DrXform X = dr_world_transform_(e, &sc);
    DrMat3 R = X.R;
    DrVec3 t = X.t;
    for (int i = 0; i < g->offsets[g->nstrands]; i++) {
        DrVec3 p = dr_v3_add(dr_m3_apply(R, dr_v3_scale(dr_v3(g->x[3 * i], g->x[3 * i + 1], g->x[3 * i + 2]), sc)), t);
        g->x[3 * i] = p.x;
        g->x[3 * i + 1] = p.y;
        g->x[3 * i + 2] = p.z;
    }
    for (int k = 0; g->root_normal && k < g->nstrands; k++) {
        DrVec3 n = dr_m3_apply(R, dr_v3(g->root_normal[3 * k], g->root_normal[3 * k + 1], g->root_normal[3 * k + 2]));
        g->root_normal[3 * k] = n.x;
        g->root_normal[3 * k + 1] = n.y;
        g->root_normal[3 * k + 2] = n.z;
    }
    return DR_OK;
}

DrStatus dr_world_hair_create_(DrWorld *w, DrError *err)
{
    const DrScene *scene = w->scene;
    int n = dr_scene_count_type(scene, "hair");
    if (n == 0) return DR_OK;
    WorldHair *h = NULL;
    DR_TRY(dr_calloc(1, sizeof *h, &h, err));
    w->hair = h;
    DR_TRY(dr_calloc((size_t)n, sizeof *h->elements, &h->elements, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *h->keys, &h->keys, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *h->nkeys, &h->nkeys, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *h->poses, &h->poses, err));
    DrGroom *grooms = NULL;
    DrRodBatch *batches = NULL;
    DR_TRY(dr_calloc((size_t)n, sizeof *grooms, &grooms, err));
    DrStatus s = dr_calloc((size_t)n, sizeof *batches, &batches, err);
    const DrComponent *solver = NULL;
    bool contact = false;
    for (int i = 0; s == DR_OK && i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (strcmp(e->type, "hair") != 0) continue;
        int b = h->nelements++;
        h->elements[b] = e;
        solver = dr_element_component(e, "HairSolver"); /* equal on every hair element (scene rule) */
        s = load_groom(e, &grooms[b], err);
        if (s != DR_OK) break;
        const DrComponent *rm = dr_element_component(e, "RodMaterial");
        const DrComponent *cg = dr_element_component(e, "CollisionGroup");
        const DrComponent *cr = dr_element_component(e, "CollisionResponse");
        const DrComponent *co = dr_element_component(e, "Collider");
        DrRodBatch *bt = &batches[b];
        bt->groom = &grooms[b];
        bt->material = (DrRodMaterial){dr_component_num(rm, "radius"), dr_component_num(rm, "density"),
                                       dr_component_num(rm, "youngs_modulus"), dr_component_num(rm, "shear_modulus"),
                                       dr_component_num(rm, "damping")};
        bt->group = 1u << dr_component_int(cg, "group");
        bt->mask = (unsigned)dr_component_int(cg, "collides_with");
        bt->self_contact = dr_component_bool(cg, "self_collision");
        bt->contact_stiffness = dr_component_num(cr, "stiffness");
        bt->contact_friction = dr_component_num(cr, "friction");
        bt->contact_thickness = dr_component_num(cr, "thickness");
        bt->collider_friction = dr_component_num(co, "friction");
        bt->collider_thickness = dr_component_num(co, "thickness");
        contact = contact || bt->self_contact || n > 1;
        /* scalp motion keys: times in s, angles in radians, as the colliders take them */
        const double *rows = NULL;
        int nrows = dr_component_table(dr_element_component(e, "Motion"), "keys", &rows);
        h->nkeys[b] = nrows;
        if (nrows > 0) {
            s = dr_calloc((size_t)nrows * 7, sizeof(double), &h->keys[b], err);
            for (int k = 0; s == DR_OK && k < nrows; k++) {
                h->keys[b][7 * k] = (rows[7 * k] - w->first_frame + 1) / w->fps;
                for (int j = 1; j < 4; j++) h->keys[b][7 * k + j] = rows[7 * k + j];
                for (int j = 4; j < 7; j++) h->keys[b][7 * k + j] = rows[7 * k + j] * DR_PI / 180.0;
            }
            h->any_motion = true;
        }
    }
    if (s == DR_OK) {
        DrRodSetDesc d;
        dr_rod_set_desc_default(&d);
        d.gravity = w->gravity;
        d.hair_contact = contact;
        d.geometric_stiffness = dr_component_bool(solver, "geometric_stiffness");
        const char *pc = dr_component_str(solver, "preconditioner");
        d.solver.precond = strcmp(pc, "jacobi") == 0 ? DR_LAG_PRECOND_JACOBI
                           : strcmp(pc, "none") == 0 ? DR_LAG_PRECOND_NONE
                                                     : DR_LAG_PRECOND_BLOCK;
        d.solver.tol = dr_component_num(solver, "tolerance");
        d.solver.max_iter = dr_component_int(solver, "max_iterations");
        h->substeps = dr_component_int(solver, "substeps");
        s = dr_rod_set_create(&d, batches, h->nelements, &h->rods, err);
        if (s != DR_OK && h->nelements == 1) s = dr_world_asset_context_(s, h->elements[0]->name, "Groom", err);
    }
    for (int b = 0; b < n; b++) dr_groom_free(&grooms[b]);
    free(grooms);
    free(batches);
    if (s != DR_OK) return s;
    /* the live colliders, posed per substep */
    if (w->nlive > 0) {
        DR_TRY(dr_calloc((size_t)w->nlive, sizeof *h->colliders, &h->colliders, err));
        DR_TRY(dr_calloc((size_t)w->nlive, sizeof *h->ctx, &h->ctx, err));
        for (int c = 0; c < w->nlive; c++) {
            h->ctx[c].collider = w->collider_ptrs[c];
            h->colliders[c] = (DrRodCollider){dr_world_posed_sdf_, dr_world_posed_velocity_, &h->ctx[c],
                                              dr_collider_friction(w->collider_ptrs[c]), 0};
        }
        h->ncolliders = w->nlive;
    }
    h->time = 0;
    return DR_OK;
}

DrStatus dr_world_hair_step_(DrWorld *w, double t0, double t1, DrFrameStats *stats, DrError *err)
{
    WorldHair *h = w->hair;
    if (!h) return DR_OK;
    double t_start = dr_time_now();
    int n = h->substeps;
    double dt = (t1 - t0) / n;
    DrRodStats st = {0};
    int not_converged = 0;
    for (int k = 0; k < n; k++) {
        double ta = t0 + k * dt, tb = (k + 1 == n) ? t1 : t0 + (k + 1) * dt;
        for (int c = 0; c < h->ncolliders; c++) h->ctx[c].frame = dr_collider_frame(h->ctx[c].collider, ta);
        for (int b = 0; b < h->nelements; b++) h->poses[b] = dr_motion_pose(h->keys[b], h->nkeys[b], tb);
        DrStatus s = dr_rod_set_step(h->rods, tb - ta, h->any_motion ? h->poses : NULL, h->colliders, h->ncolliders,
                                     &st, err);
        if (s == DR_WARN_NOT_CONVERGED) {
            not_converged++;
            continue;
        }
        if (s != DR_OK) return s;
    }
    if (not_converged)
        dr_log_warn("hair: %d of %d solves stopped at HairSolver.max_iterations (last relative residual %.2e); raise "
                    "max_iterations or substeps",
                    not_converged, n, st.residual);
    h->last = st;
    h->not_converged = not_converged;
    h->time = t1;
    DrRodState rs = dr_rod_set_state(h->rods);
    stats->hair = true;
    stats->hair_vertices = rs.nverts;
    stats->hair_substeps = n;
    stats->hair_cg_iterations = st.iterations;
    stats->hair_residual = st.residual;
    stats->hair_not_converged = not_converged;
    stats->hair_collider_contacts = st.collider_contacts;
    stats->hair_contacts = st.hair_contacts;
    stats->hair_kinetic_energy = st.kinetic;
    stats->hair_elastic_energy = st.elastic;
    stats->hair_gravity_energy = st.gravity_potential;
    stats->kinetic_energy += st.kinetic;
    if (n > stats->substeps) stats->substeps = n;
    stats->seconds_hair = dr_time_now() - t_start;
    return DR_OK;
}

/* ---- files ------------------------------------------------------------------------------------------------- */

/* Where hair element b's strands lie in the rod set's arrays: first strand, vertex and edge, and their counts. */
typedef struct BatchSpan { int s0, v0, e0; uint64_t ns, nv, ne; } BatchSpan;

static BatchSpan batch_span(const DrRodState *rs, int b)
{
    int s0 = rs->batch_offsets[b], s1 = rs->batch_offsets[b + 1];
    int v0 = rs->offsets[s0], v1 = rs->offsets[s1];
    BatchSpan sp = {s0, v0, v0 - s0, (uint64_t)(s1 - s0), (uint64_t)(v1 - v0), (uint64_t)((v1 - s1) - (v0 - s0))};
    return sp;
}

DrStatus dr_world_hair_write_(const DrWorld *w, DrH5 *hf, bool frame_cache, DrError *err)
{
    const WorldHair *h = w->hair;
    if (!h) return DR_OK;
    DrRodState rs = dr_rod_set_state(h->rods);
    for (int b = 0; b < h->nelements; b++) {
        const char *name = h->elements[b]->name;
        BatchSpan sp = batch_span(&rs, b);
        int s0 = sp.s0, v0 = sp.v0, e0 = sp.e0;
        uint64_t nv = sp.nv, ne = sp.ne, ns = sp.ns;
        char path[512];
        PATHF(path, "/%s/position", name);
        DR_TRY(dr_h5_write_f64(hf, path, 2, (uint64_t[]){nv, 3}, rs.x + 3 * v0, "m", frame_cache, err));
        PATHF(path, "/%s/velocity", name);
        DR_TRY(dr_h5_write_f64(hf, path, 2, (uint64_t[]){nv, 3}, rs.v + 3 * v0, "m/s", frame_cache, err));
        PATHF(path, "/%s/twist", name);
        DR_TRY(dr_h5_write_f64(hf, path, 1, (uint64_t[]){ne}, rs.theta + e0, "rad", frame_cache, err));
        int64_t *off = NULL;
        DR_TRY(dr_calloc(ns + 1, sizeof *off, &off, err));
        for (uint64_t k = 0; k <= ns; k++) off[k] = rs.offsets[s0 + (int)k] - v0;
        PATHF(path, "/%s/strand_offsets", name);
        DrStatus s = dr_h5_write_i64(hf, path, 1, (uint64_t[]){ns + 1}, off, "1", frame_cache, err);
        free(off);
        DR_TRY(s);
        PATHF(path, "/%s/radius", name);
        DR_TRY(dr_h5_write_f64(hf, path, 1, (uint64_t[]){ns}, rs.radius + s0, "m", frame_cache, err));
        PATHF(path, "/%s", name);
        DR_TRY(dr_h5_attr_str(hf, path, "type", "hair", err));
        if (!frame_cache) {
            /* the rest of the state a bit-identical continuation needs */
            PATHF(path, "/%s/twist_rate", name);
            DR_TRY(dr_h5_write_f64(hf, path, 1, (uint64_t[]){ne}, rs.theta_dot + e0, "rad/s", false, err));
            PATHF(path, "/%s/reference_director", name);
            DR_TRY(dr_h5_write_f64(hf, path, 2, (uint64_t[]){ne, 3}, rs.a1 + 3 * e0, "1", false, err));
        }
    }
    if (!frame_cache) {
        /* solver-wide arrays: reference twists and multipliers, in the set's own order */
        long ni = rs.nverts - 2L * rs.nstrands;
        DR_TRY(dr_h5_write_f64(hf, "/hair_solver/reference_twist", 1, (uint64_t[]){(uint64_t)(ni > 0 ? ni : 0)},
                               rs.ref_twist, "rad", false, err));
        DR_TRY(dr_h5_write_f64(hf, "/hair_solver/lambda", 1, (uint64_t[]){(uint64_t)rs.nlambda}, rs.lambda, "1", false,
                               err));
        return DR_OK;
    }
    const char *g = "/diagnostics";
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_substeps", h->substeps, "1", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_cg_iterations", h->last.iterations, "1", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_residual", h->last.residual, "1", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_not_converged", h->not_converged, "1", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_collider_contacts", h->last.collider_contacts, "1", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_contacts", h->last.hair_contacts, "1", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_kinetic_energy", h->last.kinetic, "J", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_elastic_energy", h->last.elastic, "J", err));
    DR_TRY(dr_world_write_scalar_(hf, g, "hair_gravity_energy", h->last.gravity_potential, "J", err));
    DR_TRY(dr_world_write_vec_(hf, g, "hair_linear_momentum", h->last.momentum, "kg*m/s", err));
    return DR_OK;
}

/* Reads `count` numbers of dataset `path` into dst, refusing a checkpoint made from another groom. */
static DrStatus read_exact(DrH5 *hf, const char *file, const char *path, uint64_t count, double *dst, DrError *err)
{
    int rank;
    uint64_t dims[4];
    double *data = NULL;
    DR_TRY(dr_h5_read_f64(hf, path, &rank, dims, &data, err));
    uint64_t total = 1;
    for (int r = 0; r < rank; r++) total *= dims[r];
    if (total != count) {
        free(data);
        return dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                            "checkpoint dataset %s holds %llu numbers where the scene's hair has %llu; delete the "
                            "checkpoint and bake without --resume",
                            path, (unsigned long long)total, (unsigned long long)count);
    }
    if (count) memcpy(dst, data, count * sizeof(double));
    free(data);
    return DR_OK;
}

DrStatus dr_world_hair_read_(DrWorld *w, DrH5 *hf, const char *file, DrError *err)
{
    WorldHair *h = w->hair;
    if (!h) return DR_OK;
    DrRodState rs = dr_rod_set_state(h->rods);
    for (int b = 0; b < h->nelements; b++) {
        const char *name = h->elements[b]->name;
        BatchSpan sp = batch_span(&rs, b);
        int v0 = sp.v0, e0 = sp.e0;
        uint64_t nv = sp.nv, ne = sp.ne;
        char path[512];
        PATHF(path, "/%s/position", name);
        DR_TRY(read_exact(hf, file, path, 3 * nv, rs.x + 3 * v0, err));
        PATHF(path, "/%s/velocity", name);
        DR_TRY(read_exact(hf, file, path, 3 * nv, rs.v + 3 * v0, err));
        PATHF(path, "/%s/twist", name);
        DR_TRY(read_exact(hf, file, path, ne, rs.theta + e0, err));
        PATHF(path, "/%s/twist_rate", name);
        DR_TRY(read_exact(hf, file, path, ne, rs.theta_dot + e0, err));
        PATHF(path, "/%s/reference_director", name);
        DR_TRY(read_exact(hf, file, path, 3 * ne, rs.a1 + 3 * e0, err));
    }
    long ni = rs.nverts - 2L * rs.nstrands;
    DR_TRY(read_exact(hf, file, "/hair_solver/reference_twist", (uint64_t)(ni > 0 ? ni : 0), rs.ref_twist, err));
    DR_TRY(read_exact(hf, file, "/hair_solver/lambda", (uint64_t)rs.nlambda, rs.lambda, err));
    dr_rod_set_refresh(h->rods);
    return DR_OK;
}

void dr_world_hair_hash_(const DrWorld *w, DrHasher *hs)
{
    if (!w->hair) return;
    DrRodState rs = dr_rod_set_state(w->hair->rods);
    long ni = rs.nverts - 2L * rs.nstrands;
    dr_hasher_update(hs, rs.x, 3 * sizeof(double) * (size_t)rs.nverts);
    dr_hasher_update(hs, rs.v, 3 * sizeof(double) * (size_t)rs.nverts);
    dr_hasher_update(hs, rs.theta, sizeof(double) * (size_t)rs.nedges);
    dr_hasher_update(hs, rs.theta_dot, sizeof(double) * (size_t)rs.nedges);
    dr_hasher_update(hs, rs.a1, 3 * sizeof(double) * (size_t)rs.nedges);
    if (ni > 0) dr_hasher_update(hs, rs.ref_twist, sizeof(double) * (size_t)ni);
    dr_hasher_update(hs, rs.lambda, sizeof(double) * (size_t)rs.nlambda);
}
