/* The world's boundary-element bodies (seed sugimoto_surface_only_bem, "BEM"). Each bem_solid element is one
 * DrBemSolid on the matrices precompute left in the cache (bodies with one key share one set), posed by its
 * Transform, launched by its InitialVelocity, pulled by the shot's gravity, and advanced by whole steps of its own
 * Δt, BemSolver.time_step, every frame.
 *
 * Contact (BEM §3.4): the bodies with one Δt form a group that dr_bem_solids_step advances together, each step with
 * the constraints the scene gives them: every collider element (its SDF posed at the end time of the step, its
 * keyframed surface velocity for friction), the group's FixedVertices, its bem_joint elements, and contact between
 * its bodies. Bodies of different Δt are never at the same time between steps, so they do not meet each other (the
 * scene refuses a joint between them); each still meets every collider. The solver takes one contact offset, one
 * body-body switch and one friction per collider for a whole group, so a group uses the largest Collider.thickness
 * and Collider.friction of its bodies (against a collider: the larger of that and the collider element's friction),
 * and body contact only when every body of it keeps Collider.body_contact. A group with nothing to solve steps each
 * body alone, as before contact existed. */
#include "world_adapter.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "stage/stage.h"

/* One bem_solid element: a DrBemSolid on a shared matrix set. */
typedef struct WorldBemBody {
    const DrElement *element;
    DrBemSolid *solid;
    int steps_per_frame;     /* (1/fps) / BemSolver.time_step, whole (the scene checks it) */
    double *state;           /* dr_bem_solid_state_size() doubles: scratch of checkpoints and hashes */
    size_t state_size;
    long last_steps;         /* steps of the last frame */
    DrBemStepStats frame;    /* the frame being advanced: seconds summed, errors the largest of its steps */
    DrBemStepStats last;     /* the last frame's */
} WorldBemBody;

/* The bem_solid bodies with one BemSolver.time_step, stepped together by dr_bem_solids_step with the constraints the
   scene gives them (bodies of different steps never meet each other; each group meets every collider). */
typedef struct WorldBemGroup {
    int *members;            /* indices into WorldBem.bodies, in element order: the constraints' body indices */
    DrBemSolid **solids;     /* the members' solids, in that order */
    int count;
    double dt;               /* s */
    int steps_per_frame;
    int done;                /* steps of the frame being advanced */
    DrBemConstraints constraints; /* points into colliders, fixed and joints */
    DrBemCollider *colliders;     /* one per scene collider, on WorldBem.posed */
    DrBemFixed *fixed;
    DrBemJoint *joints;
    bool constrained;        /* anything to solve; else each member is stepped alone, as without contact */
    bool coupled;            /* two-way with the liquid: each step is taken at its end, loaded with the liquid's
                                pressure gathered over it (world_kinematics.c); else at its start, one-way */
    const double **force;    /* coupled and constrained: the members' forces (WorldBem.forces) in member order */
} WorldBemGroup;

typedef struct WorldBem {
    WorldBemBody *bodies;
    int nbodies;
    const DrBemSolid **solids; /* the bodies' solids and elements, for the kinematics */
    const DrElement **elements;
    DrBemMatrices **sets;    /* one per distinct cache key, read once */
    char (*keys)[33];
    int nsets;
    WorldBemGroup *groups;
    int ngroups;
    WorldPosedCollider *posed; /* every scene collider, posed at the end time of the BEM step being taken */
    DrCollider **own;        /* SDFs built here when the kinematics built none (no liquid, MPM or hair); else NULL */
    int ncolliders;
    DrBemConstraintStats contact; /* the frame being advanced, all groups: counts of its last step, iterations and
                                     passes summed, residual the largest, seconds summed */
    int not_converged;       /* steps of the frame that returned DR_WARN_NOT_CONVERGED */
    DrBemConstraintStats last_contact; /* the last frame's */
    int last_not_converged;
    /* the stability watch on the bodies' rigid motion (kinetic + potential of their frames), where nothing moving
       works on them (no keyed collider): only against the start, since elastic energy the watch does not measure
       turns back into rigid motion after a bounce, but never more than the bodies started with */
    WorldWatch watch;
    bool watched;
    DrVec3 gravity;
    double *traction;        /* 3N scratch of the largest body: a two-way body's load */
    double **forces;         /* per body: 3N world-frame forces of a constrained two-way step (NULL: none) */
    DrVec3 liquid_impulse;   /* N s: what the liquid gave the two-way bodies in the frame being advanced */
    DrVec3 last_liquid_impulse;
    double low;              /* J/kg: the least potential −g·x of any collider's box, +INFINITY without colliders */
} WorldBem;

/* ---- the bodies --------------------------------------------------------------------------------------------- */

static void bem_destroy(void *self)
{
    WorldBem *b = self;
    if (!b) return;
    for (int g = 0; g < b->ngroups; g++) {
        WorldBemGroup *gr = &b->groups[g];
        free(gr->members);
        free(gr->solids);
        free(gr->colliders);
        free(gr->fixed);
        free(gr->joints);
        free(gr->force);
    }
    free(b->groups);
    free(b->traction);
    if (b->forces)
        for (int i = 0; i < b->nbodies; i++) free(b->forces[i]);
    free(b->forces);
    if (b->own)
        for (int c = 0; c < b->ncolliders; c++) dr_collider_destroy(&b->own[c]);
    free(b->own);
    free(b->posed);
    for (int i = 0; i < b->nbodies; i++) {
        dr_bem_solid_destroy(&b->bodies[i].solid);
        free(b->bodies[i].state);
    }
    for (int k = 0; k < b->nsets; k++) dr_bem_matrices_destroy(&b->sets[k]);
    free(b->bodies);
    free(b->sets);
    free(b->keys);
    free(b->solids);
    free(b->elements);
    free(b);
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
static DrStatus matrices_of(WorldBem *b, const DrScene *scene, const DrElement *e, const DrBemAsset *a,
                            const char *cache_root, const DrBemMatrices **out, DrError *err)
{
    for (int k = 0; k < b->nsets; k++)
        if (strcmp(b->keys[k], a->key) == 0) {
            *out = b->sets[k];
            return DR_OK;
        }
    DrBemMatrices *m = NULL;
    bool found = false;
    DrError rejected;
    DR_TRY(body_context(dr_bem_cache_read(cache_root, a->key, &m, &found, &rejected, err), e->name,
                        "cannot read its matrices", err));
    char path[DR_IO_PATH_MAX];
    dr_io_precache_path(cache_root, "bem", a->key, path, sizeof path);
    if (!found && rejected.status < 0) dr_h5_drop_fix(&rejected);
    if (!found && rejected.status < 0)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "%s: its precomputed BEM matrices cannot be used: %s; run precompute on this scene, which "
                            "computes them again (pipeline.sh --from precompute does it)",
                            e->name, rejected.message);
    if (!found)
        return dr_error_set(err, DR_ERR_INPUT, dr_scene_path(scene), 0, 0,
                            "%s: no precomputed BEM matrices for its cache key %s (%s is missing or unfinished); run "
                            "precompute on this scene first (pipeline.sh runs it)",
                            e->name, a->key, path);
    /* the key covers the mesh file's bytes and the weld: a disagreement means a file not made by this code */
    if (m->nv != a->mesh.nv || m->nt != a->mesh.nt) {
        DrStatus s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                                  "%s: the cached matrices are for %d vertices and %d triangles but %s welds to %d and "
                                  "%d; delete %s and run precompute again",
                                  e->name, m->nv, m->nt, a->path, a->mesh.nv, a->mesh.nt, path);
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
static void solid_desc_of(const WorldCtx *w, const DrElement *e, const DrBemMatrices *m, DrBemSolidDesc *d)
{
    dr_bem_solid_desc_default(d);
    double scale;
    DrXform X = dr_stage_element_transform(e, &scale);
    assert(scale == 1.0);
    DrVec3 c = dr_v3(m->body.centroid[0], m->body.centroid[1], m->body.centroid[2]);
    DrVec3 T = dr_v3_add(dr_m3_apply(X.R, c), X.t);
    const DrComponent *iv = dr_element_component(e, "InitialVelocity");
    DrVec3 v = dr_component_vec3(iv, "velocity");
    DrVec3 omega = dr_v3_scale(dr_component_vec3(iv, "angular_velocity"), DR_PI / 180.0);
    const DrComponent *sol = dr_element_component(e, "BemSolver");
    dr_m3_store(X.R, d->rotation);
    double Ta[3] = {T.x, T.y, T.z}, va[3] = {v.x, v.y, v.z}, wa[3] = {omega.x, omega.y, omega.z};
    double ga[3] = {w->gravity.x, w->gravity.y, w->gravity.z};
    memcpy(d->position, Ta, sizeof Ta);
    memcpy(d->velocity, va, sizeof va);
    memcpy(d->angular_velocity, wa, sizeof wa);
    memcpy(d->gravity, ga, sizeof ga);
    d->frame_update = dr_component_bool(sol, "frame_update");
    d->error_correction = dr_component_bool(sol, "error_correction");
}

static DrStatus add_body(const WorldCtx *w, WorldBem *b, const DrElement *e, const char *cache_root, WorldBemBody *wb,
                         DrError *err)
{
    wb->element = e;
    DrBemAsset a;
    DR_TRY(dr_stage_load_bem_asset(e, &a, err));
    const DrBemMatrices *m = NULL;
    DrStatus s = matrices_of(b, w->scene, e, &a, cache_root, &m, err);
    char key[33];
    memcpy(key, a.key, sizeof key);
    dr_bem_asset_free(&a); /* the matrices hold the welded mesh */
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

/* ---- contact: colliders, groups, fixed vertices, joints ------------------------------------------------------ */

/* The adapters between the BEM's callbacks (arrays) and the posed colliders (DrVec3). */
static double posed_sdf(const double x[3], double grad[3], void *ctx)
{
    DrVec3 n;
    double d = world_posed_sdf(dr_v3(x[0], x[1], x[2]), grad ? &n : NULL, ctx);
    if (grad) grad[0] = n.x, grad[1] = n.y, grad[2] = n.z;
    return d;
}

static void posed_velocity(const double x[3], double v[3], void *ctx)
{
    DrVec3 u = world_posed_velocity(dr_v3(x[0], x[1], x[2]), ctx);
    v[0] = u.x, v[1] = u.y, v[2] = u.z;
}

/* The SDF cell of colliders built for the bodies alone: half the smallest mean edge length of any body, so that a
   vertex resting on a face sees its plane exactly (trilinear interpolation of a plane is exact) and an edge or corner
   is resolved at the scale the body's vertices sample it. Coarsened if the collider's box would need more than
   2^25 nodes (128 MiB of floats). */
#define OWN_SDF_NODES_MAX 33554432.0

static double mean_edge(const DrBemMatrices *m)
{
    double sum = 0.0;
    for (int t = 0; t < m->nt; t++)
        for (int k = 0; k < 3; k++) {
            const double *a = &m->x[3 * m->tri[3 * t + k]], *c = &m->x[3 * m->tri[3 * t + (k + 1) % 3]];
            sum += sqrt((a[0] - c[0]) * (a[0] - c[0]) + (a[1] - c[1]) * (a[1] - c[1]) + (a[2] - c[2]) * (a[2] - c[2]));
        }
    return sum / (3.0 * m->nt);
}

static DrStatus own_collider(const WorldCtx *w, const WorldBem *b, const DrElement *e, DrCollider **out, DrError *err)
{
    double dx = INFINITY;
    for (int i = 0; i < b->nbodies; i++) dx = fmin(dx, 0.5 * mean_edge(dr_bem_solid_matrices(b->bodies[i].solid)));
    DrTriMesh mesh = {0};
    DR_TRY(dr_stage_load_collider_mesh(e, &mesh, err));
    DrVec3 lo, hi;
    if (dr_trimesh_bounds(&mesh, &lo, &hi)) {
        DrVec3 ext = dr_v3_sub(hi, lo);
        double pad = 8.0 * dx; /* the SDF's band on both sides */
        double nodes = (ext.x / dx + pad / dx + 1) * (ext.y / dx + pad / dx + 1) * (ext.z / dx + pad / dx + 1);
        if (nodes > OWN_SDF_NODES_MAX) dx *= cbrt(nodes / OWN_SDF_NODES_MAX);
    }
    const DrComponent *c = dr_element_component(e, "Collider");
    double *keys = NULL;
    int nrows = 0;
    DrStatus s = dr_stage_motion_keys(e, w->first_frame, w->fps, &keys, &nrows, err);
    if (s == DR_OK)
        s = world_make_collider(&mesh, dx, dr_component_num(c, "friction"),
                                strcmp(dr_component_str(c, "boundary"), "no_slip") == 0,
                                dr_component_num(c, "thickness"), nrows, keys, out, err);
    free(keys);
    dr_trimesh_free(&mesh);
    return dr_error_prefix(s, err, "%s.Mesh.file", e->name);
}

/* Every scene collider as the bodies see it: the kinematics' SDF when it built one, else one built here. */
static DrStatus build_colliders(const WorldCtx *w, WorldBem *b, DrError *err)
{
    b->ncolliders = world_kinematics_collider_count(w->kin);
    if (b->ncolliders == 0) return DR_OK;
    DR_TRY(dr_calloc((size_t)b->ncolliders, sizeof *b->posed, &b->posed, err));
    for (int i = 0; i < b->ncolliders; i++) {
        const DrElement *e = NULL;
        const DrCollider *c = world_kinematics_collider(w->kin, i, &e);
        if (!c) {
            if (!b->own) DR_TRY(dr_calloc((size_t)b->ncolliders, sizeof *b->own, &b->own, err));
            DR_TRY(own_collider(w, b, e, &b->own[i], err));
            c = b->own[i];
        }
        const double *rows;
        b->posed[i].collider = c;
        b->posed[i].frame = dr_collider_frame(c, 0.0);
        b->posed[i].moving = dr_component_table(dr_element_component(e, "Motion"), "keys", &rows) > 0;
    }
    return DR_OK;
}

static const char *member_name(const WorldBem *b, const WorldBemGroup *g, int k)
{
    return b->bodies[g->members[k]].element->name;
}

/* The members' vertices held by their FixedVertices: every vertex inside the box at t = 0 (the placed rest pose). An
   empty selection is bad input. */
static DrStatus add_fixed(const WorldCtx *w, const WorldBem *b, WorldBemGroup *g, DrError *err)
{
    int n = 0, cap = 0;
    for (int k = 0; k < g->count; k++)
        if (dr_component_present(dr_element_component(b->bodies[g->members[k]].element, "FixedVertices")))
            cap += dr_bem_solid_matrices(g->solids[k])->nv;
    if (cap == 0) return DR_OK;
    DR_TRY(dr_calloc((size_t)cap, sizeof *g->fixed, &g->fixed, err));
    for (int k = 0; k < g->count; k++) {
        const DrComponent *fv = dr_element_component(b->bodies[g->members[k]].element, "FixedVertices");
        if (!dr_component_present(fv)) continue;
        DrVec3 lo, hi;
        dr_component_box(fv, "box", &lo, &hi);
        const DrBemMatrices *m = dr_bem_solid_matrices(g->solids[k]);
        double *V = NULL;
        DR_TRY(dr_calloc((size_t)m->n, sizeof *V, &V, err));
        dr_bem_solid_positions(g->solids[k], V);
        int held = 0;
        DrVec3 vlo = dr_v3(INFINITY, INFINITY, INFINITY), vhi = dr_v3(-INFINITY, -INFINITY, -INFINITY);
        for (int v = 0; v < m->nv; v++) {
            DrVec3 p = dr_v3(V[3 * v], V[3 * v + 1], V[3 * v + 2]);
            vlo = dr_v3_min(vlo, p);
            vhi = dr_v3_max(vhi, p);
            if (p.x < lo.x || p.x > hi.x || p.y < lo.y || p.y > hi.y || p.z < lo.z || p.z > hi.z) continue;
            g->fixed[n++] = (DrBemFixed){.body = k, .vertex = v, .target = {p.x, p.y, p.z}};
            held++;
        }
        free(V);
        if (held == 0) {
            const char *name = member_name(b, g, k);
            return dr_error_set(err, DR_ERR_INPUT, dr_scene_path(w->scene), 0, 0,
                                "%s.FixedVertices.box = [[%.6g, %.6g, %.6g], [%.6g, %.6g, %.6g]] holds none of the "
                                "body's %d vertices, which span [[%.6g, %.6g, %.6g], [%.6g, %.6g, %.6g]] in the placed "
                                "rest pose (after Transform); move the box onto the vertices to hold, or remove "
                                "FixedVertices",
                                name, lo.x, lo.y, lo.z, hi.x, hi.y, hi.z, m->nv, vlo.x, vlo.y, vlo.z, vhi.x, vhi.y,
                                vhi.z);
        }
        dr_log_info("bem: %s: %d of %d vertices fixed", member_name(b, g, k), held, m->nv);
    }
    g->constraints.fixed = g->fixed;
    g->constraints.fixed_count = n;
    return DR_OK;
}

static int member_index(const WorldBem *b, const WorldBemGroup *g, const DrElement *e)
{
    for (int k = 0; k < g->count; k++)
        if (b->bodies[g->members[k]].element == e) return k;
    return -1;
}

/* The vertex of V (nv vertices) nearest to p; the lowest index among equals. */
static int nearest_vertex(const double *V, int nv, DrVec3 p, double *dist)
{
    int best = 0;
    double bd = INFINITY;
    for (int v = 0; v < nv; v++) {
        double d = dr_v3_norm(dr_v3_sub(dr_v3(V[3 * v], V[3 * v + 1], V[3 * v + 2]), p));
        if (d < bd) bd = d, best = v;
    }
    *dist = bd;
    return best;
}

/* One bem_joint element whose bodies are members a and b of the group: its vertex pairs appended to *joints. */
static DrStatus add_joint(const WorldCtx *w, const DrElement *e, WorldBemGroup *g, int a, int bb, DrBemJoint **joints,
                          int *n, int *cap, DrError *err)
{
    const DrComponent *j = dr_element_component(e, "Joint");
    const DrBemMatrices *ma = dr_bem_solid_matrices(g->solids[a]), *mb = dr_bem_solid_matrices(g->solids[bb]);
    double *Va = NULL, *Vb = NULL;
    DrStatus s = dr_calloc((size_t)ma->n, sizeof *Va, &Va, err);
    if (s == DR_OK) s = dr_calloc((size_t)mb->n, sizeof *Vb, &Vb, err);
    if (s != DR_OK) {
        free(Va);
        return s;
    }
    dr_bem_solid_positions(g->solids[a], Va);
    dr_bem_solid_positions(g->solids[bb], Vb);
    int added = 0;
    double closest = INFINITY;
    bool point = strcmp(dr_component_str(j, "mode"), "point") == 0;
    if (point) {
        DrVec3 p = dr_component_vec3(j, "point");
        double da, db;
        int va = nearest_vertex(Va, ma->nv, p, &da), vb = nearest_vertex(Vb, mb->nv, p, &db);
        if (*n == *cap) {
            *cap = 2 * *cap + 8;
            s = dr_realloc((size_t)*cap, sizeof **joints, joints, err);
        }
        if (s == DR_OK) (*joints)[(*n)++] = (DrBemJoint){.body = {a, bb}, .vertex = {va, vb}};
        added = 1;
        double gap = dr_v3_norm(dr_v3_sub(dr_v3(Va[3 * va], Va[3 * va + 1], Va[3 * va + 2]),
                                          dr_v3(Vb[3 * vb], Vb[3 * vb + 1], Vb[3 * vb + 2])));
        if (s == DR_OK)
            dr_log_info("bem: %s: joins vertex %d of %s and vertex %d of %s (%.3g m and %.3g m from the point, %.3g m "
                        "apart at rest)", e->name, va, dr_component_str(j, "body_a"), vb, dr_component_str(j, "body_b"),
                        da, db, gap);
    } else {
        double tol = dr_component_num(j, "tolerance");
        for (int va = 0; s == DR_OK && va < ma->nv; va++)
            for (int vb = 0; s == DR_OK && vb < mb->nv; vb++) {
                double d = dr_v3_norm(dr_v3_sub(dr_v3(Va[3 * va], Va[3 * va + 1], Va[3 * va + 2]),
                                                dr_v3(Vb[3 * vb], Vb[3 * vb + 1], Vb[3 * vb + 2])));
                closest = fmin(closest, d);
                if (d > tol) continue;
                if (*n == *cap) {
                    *cap = 2 * *cap + 8;
                    s = dr_realloc((size_t)*cap, sizeof **joints, joints, err);
                    if (s != DR_OK) break;
                }
                (*joints)[(*n)++] = (DrBemJoint){.body = {a, bb}, .vertex = {va, vb}};
                added++;
            }
        if (s == DR_OK && added == 0)
            s = dr_error_set(err, DR_ERR_INPUT, dr_scene_path(w->scene), 0, 0,
                             "%s.Joint.tolerance = %.6g m: no vertex of %s lies that close to a vertex of %s in the "
                             "placed rest pose (the closest pair is %.6g m apart); raise the tolerance, move the bodies "
                             "with their Transform so that their surfaces share vertices, or use mode \"point\"",
                             e->name, tol, dr_component_str(j, "body_a"), dr_component_str(j, "body_b"), closest);
        if (s == DR_OK) dr_log_info("bem: %s: joins %d vertex pair(s)", e->name, added);
    }
    free(Va);
    free(Vb);
    return s;
}

static DrStatus add_joints(const WorldCtx *w, const WorldBem *b, WorldBemGroup *g, DrError *err)
{
    int n = 0, cap = 0;
    for (int i = 0; i < dr_scene_element_count(w->scene); i++) {
        const DrElement *e = dr_scene_element(w->scene, i);
        if (e->kind != DR_ELEMENT_BEM_JOINT) continue;
        const DrComponent *j = dr_element_component(e, "Joint");
        int a = member_index(b, g, dr_scene_find(w->scene, dr_component_str(j, "body_a")));
        int c = member_index(b, g, dr_scene_find(w->scene, dr_component_str(j, "body_b")));
        if (a < 0 && c < 0) continue;
        assert(a >= 0 && c >= 0); /* the scene refuses a joint between bodies of different time steps */
        DR_TRY(add_joint(w, e, g, a, c, &g->joints, &n, &cap, err));
    }
    g->constraints.joints = g->joints;
    g->constraints.joint_count = n;
    return DR_OK;
}

/* The groups of bodies with one Δt, in the order of their first body, and their constraints. */
static DrStatus build_groups(const WorldCtx *w, WorldBem *b, DrError *err)
{
    DR_TRY(dr_calloc((size_t)b->nbodies, sizeof *b->groups, &b->groups, err));
    for (int i = 0; i < b->nbodies; i++) {
        double dt = dr_bem_solid_matrices(b->bodies[i].solid)->desc.dt;
        int g = 0;
        while (g < b->ngroups && b->groups[g].dt != dt) g++;
        WorldBemGroup *gr = &b->groups[g];
        if (g == b->ngroups) {
            b->ngroups++;
            gr->dt = dt;
            gr->steps_per_frame = b->bodies[i].steps_per_frame;
            DR_TRY(dr_calloc((size_t)b->nbodies, sizeof *gr->members, &gr->members, err));
            DR_TRY(dr_calloc((size_t)b->nbodies, sizeof *gr->solids, &gr->solids, err));
        }
        gr->members[gr->count] = i;
        gr->solids[gr->count++] = b->bodies[i].solid;
    }
    bool liquid = dr_scene_count_kind(w->scene, DR_ELEMENT_LIQUID) > 0;
    for (int g = 0; g < b->ngroups; g++) {
        WorldBemGroup *gr = &b->groups[g];
        for (int k = 0; k < gr->count; k++) {
            const DrElement *e = b->bodies[gr->members[k]].element, *e0 = b->bodies[gr->members[0]].element;
            const char *mode = dr_component_str(dr_element_component(e, "BemSolver"), "liquid_coupling");
            const char *mode0 = dr_component_str(dr_element_component(e0, "BemSolver"), "liquid_coupling");
            if (strcmp(mode, mode0) != 0)
                return dr_error_set(err, DR_ERR_INPUT, dr_scene_path(w->scene), 0, 0,
                                    "%s.BemSolver.liquid_coupling = \"%s\" but %s.BemSolver.liquid_coupling = \"%s\", "
                                    "and both bodies step together (the same BemSolver.time_step); give them the same "
                                    "liquid_coupling", e->name, mode, e0->name, mode0);
            gr->coupled = liquid && strcmp(mode, "two_way") == 0;
        }
    }
    for (int g = 0; g < b->ngroups; g++) {
        WorldBemGroup *gr = &b->groups[g];
        DrBemConstraints *c = &gr->constraints;
        dr_bem_constraints_default(c);
        /* a two-way body's load changes from step to step with the liquid's pressure, so its contact takes more
           re-linearisations to settle (the default shot's jelly on the floor under the wave needed 9–10 of 8) */
        if (gr->coupled) c->max_passes = 16;
        double friction = 0.0, thickness = 0.0;
        bool body_contact = true;
        for (int k = 0; k < gr->count; k++) {
            const DrComponent *col = dr_element_component(b->bodies[gr->members[k]].element, "Collider");
            friction = fmax(friction, dr_component_num(col, "friction"));
            thickness = fmax(thickness, dr_component_num(col, "thickness"));
            body_contact = body_contact && dr_component_bool(col, "body_contact");
        }
        c->thickness = thickness;
        c->body_contact = body_contact;
        c->body_friction = friction;
        if (b->ncolliders > 0) {
            DR_TRY(dr_calloc((size_t)b->ncolliders, sizeof *gr->colliders, &gr->colliders, err));
            for (int k = 0; k < b->ncolliders; k++) {
                const DrElement *ce = NULL;
                (void)world_kinematics_collider(w->kin, k, &ce);
                const DrComponent *cc = dr_element_component(ce, "Collider");
                gr->colliders[k] = (DrBemCollider){.sdf = posed_sdf,
                                                   .velocity = b->posed[k].moving ? posed_velocity : NULL,
                                                   .ctx = &b->posed[k],
                                                   .friction = fmax(friction, dr_component_num(cc, "friction"))};
            }
        }
        c->colliders = gr->colliders;
        c->collider_count = b->ncolliders;
        DR_TRY(add_fixed(w, b, gr, err));
        DR_TRY(add_joints(w, b, gr, err));
        gr->constrained = c->collider_count > 0 || c->fixed_count > 0 || c->joint_count > 0 ||
                          (c->body_contact && gr->count > 1);
        if (gr->constrained)
            dr_log_info("bem: %d bod%s with steps of %.6g s stepped together: %d collider(s), %d fixed vertices, %d "
                        "joint pair(s), body contact %s, thickness %.6g m, friction %.6g", gr->count,
                        gr->count == 1 ? "y" : "ies", gr->dt, c->collider_count, c->fixed_count, c->joint_count,
                        c->body_contact && gr->count > 1 ? "on" : "off", c->thickness, friction);
    }
    return DR_OK;
}

/* The bodies' rigid energy, and what of it could turn into motion: the kinetic energy and the potential above the
   lowest collider (without colliders, above the bodies' own size below them: a free fall keeps its energy exactly). */
static WorldEnergy bem_energy(const WorldBem *b)
{
    WorldEnergy e = {0};
    double mass = 0.0, size = 0.0, pe = 0.0;
    for (int i = 0; i < b->nbodies; i++) {
        DrBemSolidDiag dg;
        dr_bem_solid_diagnostics(b->bodies[i].solid, &dg);
        const DrBemBody *body = &dr_bem_solid_matrices(b->bodies[i].solid)->body;
        e.energy += dg.kinetic + dg.potential;
        e.available += dg.kinetic;
        pe += dg.potential;
        mass += body->mass;
        size = fmax(size, body->r_max);
    }
    double g = dr_v3_norm(b->gravity);
    e.available += isfinite(b->low) ? fmax(0.0, pe - mass * b->low) : mass * g * size;
    e.floor = 1e-12 + 1e-3 * mass * g * size;
    return e;
}

static DrStatus build_bem(const WorldCtx *w, WorldBem *b, int n, const char *cache_root, DrError *err)
{
    DR_TRY(dr_calloc((size_t)n, sizeof *b->forces, &b->forces, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *b->bodies, &b->bodies, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *b->sets, &b->sets, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *b->keys, &b->keys, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *b->solids, &b->solids, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *b->elements, &b->elements, err));
    for (int i = 0; i < dr_scene_element_count(w->scene); i++) {
        const DrElement *e = dr_scene_element(w->scene, i);
        if (e->kind != DR_ELEMENT_BEM_SOLID) continue;
        WorldBemBody *wb = &b->bodies[b->nbodies];
        DR_TRY(add_body(w, b, e, cache_root, wb, err));
        b->solids[b->nbodies] = wb->solid;
        b->elements[b->nbodies] = e;
        b->nbodies++;
    }
    DR_TRY(build_colliders(w, b, err));
    DR_TRY(build_groups(w, b, err));
    int nmax = 0;
    for (int i = 0; i < b->nbodies; i++) {
        int nv = dr_bem_solid_matrices(b->bodies[i].solid)->n;
        if (nv > nmax) nmax = nv;
    }
    DR_TRY(dr_calloc((size_t)nmax, sizeof(double), &b->traction, err));
    for (int g = 0; g < b->ngroups; g++)
        if (b->groups[g].coupled && b->groups[g].constrained) {
            WorldBemGroup *gr = &b->groups[g];
            DR_TRY(dr_calloc((size_t)gr->count, sizeof *gr->force, &gr->force, err));
            for (int k = 0; k < gr->count; k++) {
                int i = gr->members[k];
                DR_TRY(dr_calloc((size_t)dr_bem_solid_matrices(b->bodies[i].solid)->n, sizeof(double), &b->forces[i],
                                 err));
                gr->force[k] = b->forces[i];
            }
        }
    world_watch_init(&b->watch, w->scene);
    b->watch.cumulative_only = true;
    b->watched = true;
    b->gravity = w->gravity;
    b->low = INFINITY;
    for (int i = 0; i < b->ncolliders; i++) {
        b->watched = b->watched && !b->posed[i].moving;
        DrVec3 lo, hi;
        dr_collider_frame_bounds(&b->posed[i].frame, &lo, &hi);
        for (int k = 0; k < 8; k++)
            b->low = fmin(b->low, -dr_v3_dot(w->gravity, dr_v3(k & 1 ? hi.x : lo.x, k & 2 ? hi.y : lo.y,
                                                              k & 4 ? hi.z : lo.z)));
    }
    WorldEnergy e = bem_energy(b);
    world_watch_start(&b->watch, w->frame, &e);
    return DR_OK;
}

static bool finite_array(const double *a, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(a[i])) return false;
    return true;
}

/* A group's members as "'a'" or "'a', 'b', ..." for messages. */
static void group_names(const WorldBem *b, const WorldBemGroup *g, char *buf, size_t size)
{
    size_t used = 0;
    buf[0] = '\0';
    for (int k = 0; k < g->count && used < size; k++) {
        int n = snprintf(buf + used, size - used, "%s'%s'", k ? ", " : "", member_name(b, g, k));
        if (n < 0) break;
        used += (size_t)n;
    }
}

/* A member's step figures added to its frame's. */
static void body_step_done(WorldBemBody *wb, const DrBemStepStats *st)
{
    DrBemStepStats *sum = &wb->frame;
    sum->seconds_history += st->seconds_history;
    sum->seconds_solve += st->seconds_solve;
    sum->seconds_correction += st->seconds_correction;
    sum->translation_error = fmax(sum->translation_error, st->translation_error);
    sum->rotation_error = fmax(sum->rotation_error, st->rotation_error);
    wb->last_steps++;
}

/* Step n (from 0) of a group taken with its constraints: a warning when it stopped above the tolerance (status s > 0,
   the step kept), and its figures added to the frame's (counts: of the frame's last step). */
static void group_step_done(WorldBem *b, WorldBemGroup *g, int n, int frame, DrStatus s,
                            const DrBemConstraintStats *st, const DrError *err)
{
    if (s > 0) {
        char names[256];
        group_names(b, g, names, sizeof names);
        dr_log_warn("bem: %s: frame %d, step %d: constraints not converged (residual %.3g m after %d passes, %d "
                    "sweeps); the step is kept: %s", names, frame, n + 1, st->residual, st->passes, st->iterations,
                    err->message);
        b->not_converged++;
    }
    DrBemConstraintStats *sum = &b->contact;
    if (n + 1 == g->steps_per_frame) {
        sum->fixed += st->fixed;
        sum->contacts += st->contacts;
        sum->joints += st->joints;
        sum->body_contacts += st->body_contacts;
        sum->sticking += st->sticking;
    }
    sum->iterations += st->iterations;
    sum->passes += st->passes;
    sum->residual = fmax(sum->residual, st->residual);
    sum->seconds_trial += st->seconds_trial;
    sum->seconds_detect += st->seconds_detect;
    sum->seconds_assembly += st->seconds_assembly;
    sum->seconds_pgs += st->seconds_pgs;
    sum->seconds_final += st->seconds_final;
    for (int k = 0; k < g->count; k++) b->bodies[g->members[k]].last_steps++;
}

/* One step of a group without anything to solve: each member alone, with its step figures. */
static DrStatus step_alone(WorldBem *b, WorldBemGroup *g, int frame, DrError *err)
{
    for (int k = 0; k < g->count; k++) {
        WorldBemBody *wb = &b->bodies[g->members[k]];
        const char *name = wb->element->name;
        DrBemStepStats st;
        DrStatus s = dr_bem_solid_step(wb->solid, NULL, &st, err);
        if (s < 0) {
            char what[64];
            snprintf(what, sizeof what, "failed in frame %d", frame);
            return body_context(s, name, what, err);
        }
        if (s > 0) dr_log_warn("bem: %s: frame %d: %s", name, frame, err->message);
        body_step_done(wb, &st);
    }
    return DR_OK;
}

/* Step n (from 0) of the frame of a group with constraints: the colliders posed at the step's end time (the
   constraints hold positions at the end of the step), all members advanced together. A step that stops above the
   tolerance is a warning: the bodies are stepped with the forces found. */
static DrStatus step_together(WorldBem *b, WorldBemGroup *g, double t0, int n, int frame, DrError *err)
{
    double t = t0 + (n + 1) * g->dt;
    for (int c = 0; c < b->ncolliders; c++)
        if (b->posed[c].moving) b->posed[c].frame = dr_collider_frame(b->posed[c].collider, t);
    DrBemConstraintStats st;
    DrStatus s = dr_bem_solids_step(g->solids, g->count, &g->constraints, &st, err);
    if (s < 0) {
        char names[256];
        group_names(b, g, names, sizeof names);
        return dr_error_prefix(s, err, "bem_solid %s failed with contact in frame %d (step %d of %d)", names, frame,
                               n + 1, g->steps_per_frame);
    }
    group_step_done(b, g, n, frame, s, &st, err);
    return DR_OK;
}

/* ---- the clock ------------------------------------------------------------------------------------------------
 * A group takes its steps_per_frame whole steps of its Δt each frame; the clock lands on every step end. A group
 * takes step n when the clock reaches its start, t0 + nΔt (step_first): the other solvers then see the bodies move
 * through the step (their colliders of the liquid carry them from the step's start to its end). Nothing acts on the
 * bodies but their own constraints (one-way). */

static double group_step_end(const WorldBemGroup *g, const WorldCtx *c, int n)
{
    return n == g->steps_per_frame ? c->t1 : c->t0 + n * g->dt;
}

static void bem_begin_frame(void *self, const WorldCtx *c)
{
    (void)c;
    WorldBem *b = self;
    memset(&b->contact, 0, sizeof b->contact);
    b->not_converged = 0;
    b->liquid_impulse = dr_v3(0, 0, 0);
    for (int i = 0; i < b->nbodies; i++) {
        b->bodies[i].last_steps = 0;
        memset(&b->bodies[i].frame, 0, sizeof b->bodies[i].frame);
    }
    for (int g = 0; g < b->ngroups; g++) b->groups[g].done = 0;
}

static double bem_landing(const void *self, const WorldCtx *c, double t)
{
    const WorldBem *b = self;
    double next = INFINITY;
    for (int g = 0; g < b->ngroups; g++) {
        const WorldBemGroup *gr = &b->groups[g];
        if (gr->coupled) {
            if (gr->done < gr->steps_per_frame) next = fmin(next, group_step_end(gr, c, gr->done + 1));
            continue;
        }
        if (gr->done > 0 && gr->done <= gr->steps_per_frame) next = fmin(next, group_step_end(gr, c, gr->done));
    }
    (void)t;
    return next;
}

static DrStatus bem_step_first(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    (void)t_next;
    WorldBem *b = self;
    for (int g = 0; g < b->ngroups; g++) {
        WorldBemGroup *gr = &b->groups[g];
        if (gr->done >= gr->steps_per_frame || gr->coupled) continue;
        /* the group's step n starts at the end of its step n − 1 (the frame's start for n = 0) */
        double start = gr->done == 0 ? c->t0 : group_step_end(gr, c, gr->done);
        if (t != start) continue;
        int n = gr->done;
        for (int k = 0; k < gr->count; k++) world_kinematics_body_begin(c->kin, gr->members[k]);
        DR_TRY(gr->constrained ? step_together(b, gr, c->t0, n, c->frame, err) : step_alone(b, gr, c->frame, err));
        gr->done++;
        for (int k = 0; k < gr->count; k++)
            DR_TRY(world_kinematics_body_end(c->kin, gr->members[k], c->t0, start, group_step_end(gr, c, gr->done),
                                                     err));
    }
    return DR_OK;
}

/* A two-way group's step that ends at t_next: each member loaded with the liquid's pressure gathered over the step
   (world_kinematics_body_load), stepped alone or with its constraints, and its proxy synced to it. */
static DrStatus bem_step_last(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    (void)t;
    WorldBem *b = self;
    for (int g = 0; g < b->ngroups; g++) {
        WorldBemGroup *gr = &b->groups[g];
        if (!gr->coupled || gr->done >= gr->steps_per_frame || t_next != group_step_end(gr, c, gr->done + 1)) continue;
        int n = gr->done;
        if (!gr->constrained) {
            for (int k = 0; k < gr->count; k++) {
                WorldBemBody *wb = &b->bodies[gr->members[k]];
                DrVec3 J;
                world_kinematics_body_load(c->kin, gr->members[k], gr->dt, b->traction, &J);
                b->liquid_impulse = dr_v3_add(b->liquid_impulse, J);
                DrBemStepStats st;
                DrStatus s = dr_bem_solid_predict(wb->solid, err);
                if (s >= 0) s = dr_bem_solid_solve(wb->solid, b->traction, NULL, &st, err);
                if (s < 0) {
                    char what[64];
                    snprintf(what, sizeof what, "failed in frame %d", c->frame);
                    return body_context(s, wb->element->name, what, err);
                }
                dr_bem_solid_commit(wb->solid, &st);
                body_step_done(wb, &st);
            }
        } else {
            /* the constraints in world forces: f = R (p area) with R at the step's start */
            for (int k = 0; k < gr->count; k++) {
                int i = gr->members[k];
                WorldBemBody *wb = &b->bodies[i];
                const DrBemMatrices *m = dr_bem_solid_matrices(wb->solid);
                DrVec3 J;
                world_kinematics_body_load(c->kin, i, gr->dt, b->traction, &J);
                b->liquid_impulse = dr_v3_add(b->liquid_impulse, J);
                double R[9], T[3];
                dr_bem_solid_pose(wb->solid, R, T);
                for (int v = 0; v < m->nv; v++) {
                    double pa[3] = {b->traction[3 * v] * m->area[v], b->traction[3 * v + 1] * m->area[v],
                                    b->traction[3 * v + 2] * m->area[v]};
                    dr_m3a_apply(R, pa, b->forces[i] + 3 * v);
                }
            }
            for (int q = 0; q < b->ncolliders; q++)
                if (b->posed[q].moving) b->posed[q].frame = dr_collider_frame(b->posed[q].collider, t_next);
            DrBemConstraintStats st;
            DrStatus s = dr_bem_solids_predict(gr->solids, gr->count, &gr->constraints, &st, err);
            if (s >= 0) s = dr_bem_solids_solve(gr->solids, gr->count, gr->force, &st, err);
            if (s < 0) {
                char names[256];
                group_names(b, gr, names, sizeof names);
                return dr_error_prefix(s, err, "bem_solid %s failed with contact in frame %d (step %d of %d)", names,
                                       c->frame, n + 1, gr->steps_per_frame);
            }
            dr_bem_solids_commit(gr->solids, gr->count, &st);
            group_step_done(b, gr, n, c->frame, s, &st, err);
        }
        gr->done++;
        for (int k = 0; k < gr->count; k++)
            DR_TRY(world_kinematics_body_synced(c->kin, gr->members[k], t_next, gr->done == gr->steps_per_frame, err));
    }
    return DR_OK;
}

static DrStatus bem_end_frame(void *self, const WorldCtx *c, DrFrameStats *stats, DrError *err)
{
    WorldBem *b = self;
    int frame = c->frame;
    for (int g = 0; g < b->ngroups; g++)
        if (b->groups[g].constrained)
            for (int k = 0; k < b->groups[g].count; k++)
                memset(&b->bodies[b->groups[g].members[k]].frame, 0, sizeof(DrBemStepStats));
    b->last_contact = b->contact;
    b->last_not_converged = b->not_converged;
    b->last_liquid_impulse = b->liquid_impulse;
    DrBemFrameStats *o = &stats->bem;
    o->present = true;
    o->bodies = b->nbodies;
    o->liquid_impulse = b->liquid_impulse;
    const DrBemConstraintStats *cs = &b->contact;
    o->contacts = cs->contacts;
    o->body_contacts = cs->body_contacts;
    o->fixed = cs->fixed;
    o->joints = cs->joints;
    o->pgs_iterations = cs->iterations;
    o->residual = cs->residual;
    o->not_converged = b->not_converged;
    o->seconds_trial = cs->seconds_trial;
    o->seconds_detect = cs->seconds_detect;
    o->seconds_assembly = cs->seconds_assembly;
    o->seconds_pgs = cs->seconds_pgs;
    o->seconds_final = cs->seconds_final;
    if (cs->passes > 0)
        dr_log_debug("bem: frame %d: %d collider contact(s), %d body contact(s), %d fixed, %d joint(s), %d PGS sweep(s) "
                     "in %d pass(es), residual %.3g m; seconds trial %.3f detect %.3f assembly %.3f pgs %.3f final %.3f",
                     frame, cs->contacts, cs->body_contacts, cs->fixed, cs->joints, cs->iterations, cs->passes,
                     cs->residual, cs->seconds_trial, cs->seconds_detect, cs->seconds_assembly, cs->seconds_pgs,
                     cs->seconds_final);
    for (int i = 0; i < b->nbodies; i++) {
        WorldBemBody *wb = &b->bodies[i];
        const char *name = wb->element->name;
        wb->last = wb->frame;
        const DrBemStepStats sum = wb->last;
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
        o->steps += wb->last_steps;
        o->kinetic_energy += dg.kinetic;
        o->potential_energy += dg.potential;
        o->momentum = dr_v3_add(o->momentum, dr_v3(dg.momentum[0], dg.momentum[1], dg.momentum[2]));
        o->max_displacement = fmax(o->max_displacement, dg.max_displacement);
        o->translation_error = fmax(o->translation_error, sum.translation_error);
        o->rotation_error = fmax(o->rotation_error, sum.rotation_error);
        o->seconds_history += sum.seconds_history;
        o->seconds_solve += sum.seconds_solve;
        o->seconds_correction += sum.seconds_correction;
        if (wb->steps_per_frame > o->substeps) o->substeps = wb->steps_per_frame;
    }
    if (!b->watched) return DR_OK;
    WorldEnergy e = bem_energy(b);
    char who[300];
    if (b->nbodies == 1) snprintf(who, sizeof who, "bem_solid '%s' (its rigid motion)", b->bodies[0].element->name);
    else snprintf(who, sizeof who, "the %d bem_solid bodies (their rigid motion)", b->nbodies);
    return world_watch_energy(&b->watch, c, &e, who,
                              "lower BemSolver.time_step (and run precompute again) or raise "
                              "BemSolver.history_margin", err);
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
    DR_TRY(dr_h5_write_vec3(h, g, "linear_momentum", dr_v3(dg->momentum[0], dg->momentum[1], dg->momentum[2]),
                               "kg*m/s", err));
    DR_TRY(dr_h5_write_vec3(h, g, "angular_momentum",
                               dr_v3(dg->angular_momentum[0], dg->angular_momentum[1], dg->angular_momentum[2]),
                               "kg*m^2/s", err));
    DR_TRY(dr_h5_write_scalar(h, g, "kinetic_energy", dg->kinetic, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "potential_energy", dg->potential, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "volume", dg->volume, "m^3", err));
    DR_TRY(dr_h5_write_scalar(h, g, "max_displacement", dg->max_displacement, "m", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mass", m->body.mass, "kg", err));
    DR_TRY(dr_h5_write_scalar(h, g, "steps", (double)wb->last_steps, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "time_step", m->desc.dt, "s", err));
    DR_TRY(dr_h5_write_scalar(h, g, "translation_error", wb->last.translation_error, "m", err));
    DR_TRY(dr_h5_write_scalar(h, g, "rotation_error", wb->last.rotation_error, "rad", err));
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
    DR_TRY(dr_h5_write_scalar(h, g, "bem_bodies", b->nbodies, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_steps", (double)steps, "1", err));
    DR_TRY(dr_h5_write_vec3(h, g, "bem_linear_momentum", dr_v3(tot.momentum[0], tot.momentum[1], tot.momentum[2]),
                               "kg*m/s", err));
    DR_TRY(dr_h5_write_vec3(h, g, "bem_angular_momentum", L, "kg*m^2/s", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_kinetic_energy", tot.kinetic, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_potential_energy", tot.potential, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_total_energy", tot.kinetic + tot.potential, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_volume", tot.volume, "m^3", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_max_displacement", tot.max_displacement, "m", err));
    /* the momentum ledger of the two-way bodies: what the liquid gave them over the frame (its pressure, and what
       setting their velocity on its faces and pushing its particles out of them took from it) */
    DR_TRY(dr_h5_write_vec3(h, g, "bem_liquid_impulse", b->last_liquid_impulse, "N*s", err));
    /* constraints (BEM §3.4): counts of the frame's last step, sweeps and passes of all its steps, the largest
       residual; the seconds per phase are wall clock and stay out */
    const DrBemConstraintStats *c = &b->last_contact;
    DR_TRY(dr_h5_write_scalar(h, g, "bem_contacts", c->contacts, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_body_contacts", c->body_contacts, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_sticking", c->sticking, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_fixed", c->fixed, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_joints", c->joints, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_pgs_iterations", c->iterations, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_passes", c->passes, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_residual", c->residual, "m", err));
    DR_TRY(dr_h5_write_scalar(h, g, "bem_not_converged", b->last_not_converged, "1", err));
    return DR_OK;
}

static DrStatus bem_write(const void *self, const WorldCtx *c, DrH5 *h, bool frame_cache, DrError *err)
{
    (void)c;
    const WorldBem *b = self;
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

static DrStatus bem_read(void *self, const WorldCtx *w, DrH5 *h, const char *file, int frame, DrError *err)
{
    WorldBem *b = self;
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
    for (int g = 0; g < b->ngroups; g++)
        if (b->groups[g].coupled)
            for (int k = 0; k < b->groups[g].count; k++)
                DR_TRY(world_kinematics_body_synced(w->kin, b->groups[g].members[k], w->t1, true, err));
    WorldEnergy e = bem_energy(b);
    world_watch_start(&b->watch, frame + 1, &e);
    return DR_OK;
}

static void bem_hash(const void *self, DrHasher *h)
{
    const WorldBem *b = self;
    for (int i = 0; i < b->nbodies; i++) {
        const WorldBemBody *wb = &b->bodies[i];
        dr_bem_solid_state_get(wb->solid, wb->state);
        dr_hasher_update(h, wb->state, wb->state_size * sizeof(double));
    }
}

DrStatus world_bem_adapter(const WorldCtx *c, const char *cache_root, WorldSolver *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    int n = dr_scene_count_kind(c->scene, DR_ELEMENT_BEM_SOLID);
    if (n == 0) return DR_OK;
    WorldBem *b = NULL;
    DR_TRY(dr_calloc(1, sizeof *b, &b, err));
    DrStatus s = build_bem(c, b, n, cache_root, err);
    if (s < 0) {
        bem_destroy(b);
        return s;
    }
    *out = (WorldSolver){.name = "bem",
                         .self = b,
                         .begin_frame = bem_begin_frame,
                         .landing = bem_landing,
                         .step_first = bem_step_first,
                         .step_last = bem_step_last,
                         .end_frame = bem_end_frame,
                         .write = bem_write,
                         .read = bem_read,
                         .hash = bem_hash,
                         .destroy = bem_destroy};
    return DR_OK;
}

bool world_bem_coupled(const WorldSolver *bem, int i)
{
    const WorldBem *b = bem->self;
    for (int g = 0; g < b->ngroups; g++)
        for (int k = 0; k < b->groups[g].count; k++)
            if (b->groups[g].members[k] == i) return b->groups[g].coupled;
    return false;
}

int world_bem_solids(const WorldSolver *bem, const DrBemSolid *const **solids, const DrElement *const **elements)
{
    const WorldBem *b = bem->self;
    *solids = (const DrBemSolid *const *)b->solids;
    *elements = (const DrElement *const *)b->elements;
    return b->nbodies;
}

void world_bem_counts(const WorldSolver *s, int *bodies, long *vertices, int *sets)
{
    const WorldBem *b = s->self;
    *bodies = b->nbodies;
    *vertices = 0;
    for (int i = 0; i < b->nbodies; i++) *vertices += dr_bem_solid_matrices(b->bodies[i].solid)->nv;
    *sets = b->nsets;
}
