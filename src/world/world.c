/* DrWorld: scene → solvers, one frame at a time; frame caches and checkpoints. */
#include "world_internal.h"

#include <stdlib.h>
#include <string.h>

#include "io/io.h"
#include "liquid/liquid.h"
#include "vdb/vdb.h"

int dr_world_first_frame(const DrWorld *w) { return w->first_frame; }
int dr_world_last_frame(const DrWorld *w) { return w->last_frame; }
int dr_world_frame(const DrWorld *w) { return w->frame; }
int dr_world_liquid_count(const DrWorld *w) { return w->nliquids; }
const DrLiquid *dr_world_liquid(const DrWorld *w, int i) { return w->liquids[i].liquid; }
const DrElement *dr_world_liquid_element(const DrWorld *w, int i) { return w->liquids[i].element; }
int dr_world_live_collider_count(const DrWorld *w) { return w->nlive; }
long dr_world_mpm_particle_count(const DrWorld *w) { return w->mpm ? dr_mpm_state(w->mpm->mpm).n : 0; }
long dr_world_hair_vertex_count(const DrWorld *w) { return w->hair ? dr_rod_set_state(w->hair->rods).nverts : 0; }

double dr_world_frame_time(const DrWorld *w, int frame) { return (double)(frame - w->first_frame + 1) / w->fps; }

DrStatus dr_world_asset_context_(DrStatus s, const char *element, const char *field, DrError *err)
{
    return dr_error_prefix(s, err, "%s.%s", element, field);
}

DrXform dr_world_transform_(const DrElement *e, double *scale) { return dr_stage_element_transform(e, scale); }

DrStatus dr_world_load_posed_mesh_(const DrElement *e, const char *path, const char *field, DrTriMesh *mesh,
                                   DrError *err)
{
    return dr_stage_load_posed_mesh(e, path, field, mesh, err);
}

double dr_world_posed_sdf_(DrVec3 x, DrVec3 *normal, void *ctx)
{
    const WorldPosedCollider *c = ctx;
    return dr_collider_frame_phi(&c->frame, x, normal);
}

DrVec3 dr_world_posed_velocity_(DrVec3 x, void *ctx)
{
    const WorldPosedCollider *c = ctx;
    return dr_collider_frame_velocity(&c->frame, x);
}

DrStatus dr_world_make_collider_(const DrTriMesh *mesh, double dx, double friction, bool no_slip, double thickness,
                                 int nkeys, const double *keys, DrCollider **out, DrError *err)
{
    DrDenseSdf sdf = {0};
    DR_TRY(dr_vdb_mesh_to_sdf(mesh, dx, 4, &sdf, err));
    DrColliderDesc d = {0};
    d.phi = sdf.phi;
    d.nx = sdf.nx;
    d.ny = sdf.ny;
    d.nz = sdf.nz;
    d.origin = sdf.origin;
    d.dx = sdf.dx;
    d.friction = friction;
    d.no_slip = no_slip;
    d.thickness = thickness;
    d.nkeys = nkeys;
    d.keys = keys;
    DrStatus s = dr_collider_create(&d, out, err);
    dr_dense_sdf_free(&sdf);
    return s;
}

/* The smallest cell of any grid that samples colliders (liquid and MPM) or, for hair, a grown groom's segment
   length (4 mm for curves read from a file), 0 when nothing samples colliders. */
static double smallest_grid_dx(const DrScene *scene)
{
    double dx = 0.0;
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        double d;
        if (e->kind == DR_ELEMENT_HAIR) {
            const DrComponent *g = dr_element_component(e, "Groom");
            d = dr_component_is_set(g, "scalp") ? dr_component_num(g, "length") / dr_component_int(g, "segments") : 0.004;
        } else if (e->kind == DR_ELEMENT_LIQUID || e->kind == DR_ELEMENT_MPM_SOLID) {
            d = dr_component_num(dr_element_component(e, "Domain"), "voxel_size");
        } else {
            continue;
        }
        if (dx == 0.0 || d < dx) dx = d;
    }
    return dx;
}

static DrStatus build_colliders(DrWorld *w, DrError *err)
{
    const DrScene *scene = w->scene;
    int n = dr_scene_count_kind(scene, DR_ELEMENT_COLLIDER);
    DR_TRY(dr_calloc((size_t)n + 1, sizeof(WorldCollider), &w->colliders, err));
    DR_TRY(dr_calloc((size_t)n + 1, sizeof(DrCollider *), &w->collider_ptrs, err));
    /* The SDF resolves the smallest grid cell twice so face fractions see the collider's shape. */
    double dx = smallest_grid_dx(scene) * 0.5;
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_COLLIDER) continue;
        WorldCollider *wc = &w->colliders[w->ncolliders++];
        wc->element = e;
        DrTriMesh mesh = {0};
        DR_TRY(dr_stage_load_collider_mesh(e, &mesh, err));
        if (dx <= 0.0) { /* nothing in the scene samples colliders: validate the asset, build nothing */
            dr_trimesh_free(&mesh);
            continue;
        }
        const DrComponent *c = dr_element_component(e, "Collider");
        double *keys = NULL;
        int nrows = 0;
        DrStatus s = dr_stage_motion_keys(e, w->first_frame, w->fps, &keys, &nrows, err);
        if (s == DR_OK)
            s = dr_world_make_collider_(&mesh, dx, dr_component_num(c, "friction"),
                                        strcmp(dr_component_str(c, "boundary"), "no_slip") == 0,
                                        dr_component_num(c, "thickness"), nrows, keys, &wc->collider, err);
        free(keys);
        dr_trimesh_free(&mesh);
        DR_TRY(dr_world_asset_context_(s, e->name, "Mesh.file", err));
        w->collider_ptrs[w->nlive++] = wc->collider;
    }
    return DR_OK;
}

/* ---- bem_solid bodies as moving colliders of the liquid (one-way) ------------------------------------------
 * The liquid poses its colliders itself at every substep time (dr_collider_frame), from motion keys. A body's
 * frame is known at the BEM steps only, and the bodies are advanced over the whole frame before the liquid, so each
 * frame the body's DrCollider is rebuilt with keys that carry its frame from the start of the frame to its end:
 * BODY_KEY_INTERVALS + 1 rows, the position on the cubic Hermite curve through T and Ṫ at both ends (exact for a
 * free fall), the rotation along the shortest arc from R(t0) to R(t1). Between keys the pose is linear (rotation in
 * XYZ Euler angles, as every collider's), so the surface velocity the liquid sees is the rate of that pose:
 * Ṫ + ω × r to within the key spacing. The displacement u is not seen: the SDF is the rest shape's. */
#define BODY_KEY_INTERVALS 16

static DrMat3 skew_exp(DrVec3 w) /* rotation by |w| about w (Rodrigues) */
{
    double th = dr_v3_norm(w);
    DrMat3 R = dr_m3_identity();
    if (!(th > 0.0)) return R;
    DrVec3 a = dr_v3_scale(w, 1.0 / th);
    double K[3][3] = {{0, -a.z, a.y}, {a.z, 0, -a.x}, {-a.y, a.x, 0}};
    double s = sin(th), c = 1.0 - cos(th);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double k2 = 0.0;
            for (int l = 0; l < 3; l++) k2 += K[i][l] * K[l][j];
            R.m[i][j] += s * K[i][j] + c * k2;
        }
    return R;
}

static DrVec3 rotation_log(DrMat3 M) /* the rotation vector w with skew_exp(w) = M, |w| ≤ π */
{
    double c = 0.5 * (M.m[0][0] + M.m[1][1] + M.m[2][2] - 1.0);
    c = c > 1.0 ? 1.0 : (c < -1.0 ? -1.0 : c);
    double th = acos(c);
    DrVec3 v = dr_v3(M.m[2][1] - M.m[1][2], M.m[0][2] - M.m[2][0], M.m[1][0] - M.m[0][1]); /* 2 sin θ · axis */
    if (th < 1e-6) return dr_v3_scale(v, 0.5);
    if (DR_PI - th > 1e-6) return dr_v3_scale(v, th / (2.0 * sin(th)));
    /* near a half turn: the axis from the symmetric part (M + I)/2 = a aᵀ, its sign from v */
    int k = 0;
    for (int i = 1; i < 3; i++)
        if (M.m[i][i] > M.m[k][k]) k = i;
    double col[3];
    for (int i = 0; i < 3; i++) col[i] = 0.5 * (M.m[i][k] + (i == k ? 1.0 : 0.0));
    DrVec3 a = dr_v3_normalize(dr_v3(col[0], col[1], col[2]));
    if (dr_v3_dot(a, v) < 0.0) a = dr_v3_scale(a, -1.0);
    return dr_v3_scale(a, th);
}

static double unwrap_angle(double a, double near) { return a + 2.0 * DR_PI * floor((near - a) / (2.0 * DR_PI) + 0.5); }

/* XYZ Euler angles of R (R = Rz·Ry·Rx as dr_m3_from_euler_xyz), of the two triples (and their 2π shifts) the one
   nearest `near`, so that keys interpolate along the short way. */
static DrVec3 euler_near(DrMat3 R, DrVec3 near)
{
    double cy = hypot(R.m[0][0], R.m[1][0]);
    DrVec3 e[2];
    int n = 1;
    if (cy > 1e-9) {
        double ry = atan2(-R.m[2][0], cy), rx = atan2(R.m[2][1], R.m[2][2]), rz = atan2(R.m[1][0], R.m[0][0]);
        e[0] = dr_v3(rx, ry, rz);
        e[1] = dr_v3(rx + DR_PI, DR_PI - ry, rz + DR_PI);
        n = 2;
    } else { /* ry = ±90°: only rx − rz or rx + rz is fixed; keep rz, take rx from Rz(rz)ᵀ R = Ry Rx */
        double rz = near.z, cz = cos(rz), sz = sin(rz);
        double m11 = -sz * R.m[0][1] + cz * R.m[1][1], m12 = -sz * R.m[0][2] + cz * R.m[1][2];
        e[0] = dr_v3(atan2(-m12, m11), atan2(-R.m[2][0], cy), rz);
    }
    int best = 0;
    double dbest = INFINITY;
    for (int i = 0; i < n; i++) {
        e[i] = dr_v3(unwrap_angle(e[i].x, near.x), unwrap_angle(e[i].y, near.y), unwrap_angle(e[i].z, near.z));
        DrVec3 d = dr_v3_sub(e[i], near);
        if (dr_v3_dot(d, d) < dbest) {
            dbest = dr_v3_dot(d, d);
            best = i;
        }
    }
    return e[best];
}

/* The body's frame now: R, T and Ṫ. */
static void body_frame(const DrBemSolid *s, DrXform *X, DrVec3 *v)
{
    double R[9], T[3], va[3], wa[3];
    dr_bem_solid_pose(s, R, T);
    dr_bem_solid_frame_velocity(s, va, wa);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) X->R.m[i][j] = R[3 * i + j];
    X->t = dr_v3(T[0], T[1], T[2]);
    *v = dr_v3(va[0], va[1], va[2]);
}

static void put_key(double *row, double t, DrVec3 T, DrVec3 e)
{
    double r[7] = {t, T.x, T.y, T.z, e.x, e.y, e.z};
    memcpy(row, r, sizeof r);
}

/* (Re)builds the body's DrCollider from its SDF and its current keys. */
static DrStatus pose_body_collider(WorldBodyCollider *bc, DrError *err)
{
    dr_collider_destroy(&bc->collider);
    DrColliderDesc d = {0};
    d.phi = bc->phi;
    d.nx = bc->nx;
    d.ny = bc->ny;
    d.nz = bc->nz;
    d.origin = bc->origin;
    d.dx = bc->dx;
    d.friction = 0.0; /* slip, frictionless: the liquid slides along the jelly */
    d.nkeys = bc->nkeys;
    d.keys = bc->keys;
    return dr_collider_create(&d, &bc->collider, err);
}

/* Keys carrying the body from bc->start (at t0) to its frame now (at t1). */
static void body_keys(WorldBodyCollider *bc, double t0, double t1)
{
    DrXform X1;
    DrVec3 V1, V0 = bc->start_velocity;
    body_frame(bc->body->solid, &X1, &V1);
    DrMat3 R0 = bc->start.R;
    DrVec3 T0 = bc->start.t, w = rotation_log(dr_m3_mul(dr_m3_transpose(R0), X1.R));
    double h = t1 - t0;
    DrVec3 e = euler_near(R0, dr_v3(0, 0, 0));
    for (int k = 0; k <= BODY_KEY_INTERVALS; k++) {
        double s = (double)k / BODY_KEY_INTERVALS, s2 = s * s, s3 = s2 * s;
        DrVec3 T = dr_v3_add(dr_v3_add(dr_v3_scale(T0, 2 * s3 - 3 * s2 + 1), dr_v3_scale(V0, h * (s3 - 2 * s2 + s))),
                             dr_v3_add(dr_v3_scale(X1.t, 3 * s2 - 2 * s3), dr_v3_scale(V1, h * (s3 - s2))));
        DrMat3 R = k == BODY_KEY_INTERVALS ? X1.R : dr_m3_mul(R0, skew_exp(dr_v3_scale(w, s)));
        if (k == BODY_KEY_INTERVALS) T = X1.t;
        e = euler_near(R, e);
        put_key(bc->keys + 7 * k, k == BODY_KEY_INTERVALS ? t1 : t0 + s * h, T, e);
    }
    bc->nkeys = BODY_KEY_INTERVALS + 1;
}

/* One collider per bem_solid body for the liquid (none without a liquid), posed at t = 0, and the list of
   colliders the liquid takes: the live colliders, then the bodies. */
static DrStatus build_body_colliders(DrWorld *w, DrError *err)
{
    size_t n = w->bem && dr_scene_count_kind(w->scene, DR_ELEMENT_LIQUID) > 0 ? (size_t)w->bem->nbodies : 0;
    DR_TRY(dr_calloc((size_t)w->nlive + n + 1, sizeof(DrCollider *), &w->liquid_colliders, err));
    for (int i = 0; i < w->nlive; i++) w->liquid_colliders[i] = w->collider_ptrs[i];
    w->nliquid_colliders = w->nlive;
    if (n == 0) return DR_OK;
    DR_TRY(dr_calloc(n, sizeof(WorldBodyCollider), &w->body_colliders, err));
    double dx = smallest_grid_dx(w->scene) * 0.5; /* as the colliders' SDFs */
    for (size_t i = 0; i < n; i++) {
        WorldBodyCollider *bc = &w->body_colliders[w->nbody_colliders++];
        bc->body = &w->bem->bodies[i];
        const DrBemSolid *solid = bc->body->solid;
        const DrBemMatrices *m = dr_bem_solid_matrices(solid);
        DrTriMesh rest = {.nv = m->nv, .nt = m->nt, .tri = m->tri};
        DR_TRY(dr_calloc(3 * (size_t)m->nv, sizeof(double), &rest.v, err));
        memcpy(rest.v, dr_bem_solid_reference(solid), 3 * (size_t)m->nv * sizeof(double));
        DrDenseSdf sdf = {0};
        DrStatus s = dr_vdb_mesh_to_sdf(&rest, dx, 4, &sdf, err);
        free(rest.v);
        DR_TRY(dr_world_asset_context_(s, bc->body->element->name, "Mesh.file", err));
        bc->phi = sdf.phi; /* owned from here */
        bc->nx = sdf.nx;
        bc->ny = sdf.ny;
        bc->nz = sdf.nz;
        bc->origin = sdf.origin;
        bc->dx = sdf.dx;
        DR_TRY(dr_calloc(7 * (BODY_KEY_INTERVALS + 1), sizeof(double), &bc->keys, err));
        body_frame(solid, &bc->start, &bc->start_velocity);
        put_key(bc->keys, 0.0, bc->start.t, euler_near(bc->start.R, dr_v3(0, 0, 0)));
        bc->nkeys = 1; /* at rest where the Transform put it: no liquid is seeded inside it */
        DR_TRY(pose_body_collider(bc, err));
        w->liquid_colliders[w->nliquid_colliders++] = bc->collider;
    }
    dr_log_info("world: the liquid sees %d bem_solid bod%s as moving collider(s) (rest-shape SDF, rigid frame only)",
                w->nbody_colliders, w->nbody_colliders == 1 ? "y" : "ies");
    return DR_OK;
}

/* Before the bodies' frame: remember where each starts. */
static void body_colliders_begin(DrWorld *w)
{
    for (int i = 0; i < w->nbody_colliders; i++) {
        WorldBodyCollider *bc = &w->body_colliders[i];
        body_frame(bc->body->solid, &bc->start, &bc->start_velocity);
    }
}

/* After it: the keys from t0 to t1 and the colliders the liquid takes for the frame. */
static DrStatus body_colliders_end(DrWorld *w, double t0, double t1, DrError *err)
{
    for (int i = 0; i < w->nbody_colliders; i++) {
        WorldBodyCollider *bc = &w->body_colliders[i];
        body_keys(bc, t0, t1);
        DR_TRY(dr_world_asset_context_(pose_body_collider(bc, err), bc->body->element->name, "BemSolver", err));
        w->liquid_colliders[w->nlive + i] = bc->collider;
    }
    return DR_OK;
}

static void box_of(const DrComponent *c, const char *field, DrVec3 *lo, DrVec3 *hi) { dr_component_box(c, field, lo, hi); }

static DrStatus build_liquid(DrWorld *w, const DrElement *e, WorldLiquid *wl, DrError *err)
{
    const DrScene *scene = w->scene;
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
    d.gravity = w->gravity;
    d.cfl = dr_component_num(solver, "cfl");
    d.max_substeps = dr_component_int(solver, "max_substeps");
    d.pressure_tol = dr_component_num(solver, "pressure_tolerance");
    d.pressure_max_iter = dr_component_int(solver, "pressure_max_iterations");

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
            DR_TRY(dr_world_asset_context_(dr_io_load_mesh(dr_component_str(src, "mesh"), &mesh, err), e->name,
                                           "LiquidSource.mesh", err));
            DR_TRY(dr_calloc(1, sizeof(DrCollider *), &wl->shapes, err));
            DrStatus s = dr_world_make_collider_(&mesh, d.dx * 0.5, 0, false, 0, 0, NULL, &wl->shapes[0], err);
            dr_trimesh_free(&mesh);
            DR_TRY(dr_world_asset_context_(s, e->name, "LiquidSource.mesh", err));
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
    return dr_liquid_create(&d, w->liquid_colliders, w->nliquid_colliders, &wl->liquid, err);
}

void dr_world_desc_default(DrWorldDesc *d) { *d = (DrWorldDesc){.cache_root = "cache"}; }

DrStatus dr_world_create(const DrScene *scene, DrWorld **out, DrError *err)
{
    DrWorldDesc d;
    dr_world_desc_default(&d);
    return dr_world_create_desc(scene, &d, out, err);
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
    DrStatus s = dr_vdb_init(err);
    if (s == DR_OK) s = build_colliders(w, err);
    /* the bodies before the liquid: it seeds no particle inside them */
    if (s == DR_OK) s = dr_world_bem_create_(w, desc->cache_root, err);
    if (s == DR_OK) s = build_body_colliders(w, err);
    int nl = dr_scene_count_kind(scene, DR_ELEMENT_LIQUID);
    if (s == DR_OK) s = dr_calloc((size_t)nl + 1, sizeof(WorldLiquid), &w->liquids, err);
    for (int i = 0; s == DR_OK && i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind == DR_ELEMENT_LIQUID) s = build_liquid(w, e, &w->liquids[w->nliquids++], err);
    }
    if (s == DR_OK) s = dr_world_mpm_create_(w, err);
    if (s == DR_OK) s = dr_world_hair_create_(w, err);
    if (s < 0) {
        dr_world_destroy(&w);
        return s;
    }
    long mpm_particles = dr_world_mpm_particle_count(w);
    char hair[128] = "no hair";
    if (w->hair) {
        DrRodState rs = dr_rod_set_state(w->hair->rods);
        snprintf(hair, sizeof hair, "%d strand(s) of hair with %d vertices", rs.nstrands, rs.nverts);
    }
    char bem[160] = "";
    if (w->bem) {
        long nv = 0;
        for (int i = 0; i < w->bem->nbodies; i++) nv += dr_bem_solid_matrices(w->bem->bodies[i].solid)->nv;
        snprintf(bem, sizeof bem, ", %d BEM bod%s with %ld vertices (%d matrix set%s)", w->bem->nbodies,
                 w->bem->nbodies == 1 ? "y" : "ies", nv, w->bem->nsets, w->bem->nsets == 1 ? "" : "s");
    }
    if (w->mpm)
        dr_log_info("world: %d liquid grid(s), one MPM grid with %ld particles in %d bod%s, %s%s, %d collider SDF(s)",
                    w->nliquids, mpm_particles, w->mpm->nbodies, w->mpm->nbodies == 1 ? "y" : "ies", hair, bem,
                    w->nlive);
    else
        dr_log_info("world: %d liquid grid(s), no MPM solver, %s%s, %d collider SDF(s)", w->nliquids, hair, bem,
                    w->nlive);
    *out = w;
    return DR_OK;
}

void dr_world_destroy(DrWorld **world)
{
    if (!world || !*world) return;
    DrWorld *w = *world;
    for (int i = 0; i < w->nliquids; i++) {
        dr_liquid_destroy(&w->liquids[i].liquid);
        for (int k = 0; k < w->liquids[i].nshapes; k++) dr_collider_destroy(&w->liquids[i].shapes[k]);
        free(w->liquids[i].shapes);
    }
    dr_world_mpm_destroy_(&w->mpm);
    dr_world_hair_destroy_(&w->hair);
    for (int i = 0; i < w->nbody_colliders; i++) {
        dr_collider_destroy(&w->body_colliders[i].collider);
        free(w->body_colliders[i].phi);
        free(w->body_colliders[i].keys);
    }
    free(w->body_colliders);
    free(w->liquid_colliders);
    dr_world_bem_destroy_(&w->bem);
    for (int i = 0; i < w->ncolliders; i++) dr_collider_destroy(&w->colliders[i].collider);
    free(w->liquids);
    free(w->colliders);
    free(w->collider_ptrs);
    free(w);
    *world = NULL;
}

static bool all_finite(const double *a, long n)
{
    for (long i = 0; i < n; i++)
        if (!isfinite(a[i])) return false;
    return true;
}

DrStatus dr_world_step_frame(DrWorld *w, DrFrameStats *stats, DrError *err)
{
    assert(w->frame < w->last_frame);
    double t_start = dr_time_now();
    int frame = w->frame + 1;
    double t0 = dr_world_frame_time(w, frame - 1), t1 = dr_world_frame_time(w, frame);
    memset(stats, 0, sizeof *stats);
    stats->frame = frame;
    stats->time = t1;
    /* The BEM bodies first, over the whole frame: the liquid then sees each body's frame at its own substep times,
       interpolated between the frame's start and end (one-way: nothing of the liquid acts on the bodies). */
    body_colliders_begin(w);
    DR_TRY(dr_world_bem_step_(w, frame, stats, err));
    DR_TRY(body_colliders_end(w, t0, t1, err));
    double volume = 0.0, volume0 = 0.0;
    stats->liquid = w->nliquids > 0;
    for (int i = 0; i < w->nliquids; i++) {
        WorldLiquid *wl = &w->liquids[i];
        DrLiquidStats ls;
        DR_TRY(dr_liquid_advance(wl->liquid, w->liquid_colliders, w->nliquid_colliders, t0, t1, &ls, err));
        const DrLiquidState *st = dr_liquid_state(wl->liquid);
        if (!all_finite(st->x, 3 * st->n) || !all_finite(st->v, 3 * st->n))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "liquid '%s' became non-finite in frame %d; lower solver.cfl or raise "
                                "solver.max_substeps", wl->element->name, frame);
        wl->last = ls;
        double dx = dr_liquid_grid(wl->liquid)->dx;
        double vol = (double)ls.liquid_cells * dx * dx * dx;
        if (wl->volume0 == 0.0) wl->volume0 = vol;
        volume += vol;
        volume0 += wl->volume0;
        double mass, ke;
        DrVec3 p, l;
        dr_liquid_totals(wl->liquid, &mass, &p, &l, &ke);
        stats->kinetic_energy += ke;
        if (ls.substeps > stats->substeps) stats->substeps = ls.substeps;
        if (ls.substeps > stats->liquid_substeps) stats->liquid_substeps = ls.substeps;
        stats->particles += ls.particles;
        if (ls.pressure_iterations_max > stats->pressure_iterations_max)
            stats->pressure_iterations_max = ls.pressure_iterations_max;
        stats->pressure_iterations_total += ls.pressure_iterations_total;
        stats->pressure_not_converged += ls.pressure_not_converged;
        stats->seconds_p2g += ls.seconds_p2g;
        stats->seconds_pressure += ls.seconds_pressure;
        stats->seconds_g2p += ls.seconds_g2p;
        stats->seconds_advect += ls.seconds_advect;
        stats->seconds_other += ls.seconds_other;
    }
    stats->liquid_volume = volume;
    stats->volume_drift = volume0 > 0 ? volume / volume0 - 1.0 : 0.0;
    DR_TRY(dr_world_mpm_step_(w, t0, t1, stats, err));
    DR_TRY(dr_world_hair_step_(w, t0, t1, stats, err));
    w->frame = frame;
    stats->seconds = dr_time_now() - t_start;
    return DR_OK;
}

/* ---- frame caches and checkpoints --------------------------------------------------------------- */

DrStatus dr_world_write_scalar_(DrH5 *h, const char *group, const char *name, double v, const char *units, DrError *err)
{
    return dr_h5_write_scalar(h, group, name, v, units, err);
}

DrStatus dr_world_write_vec_(DrH5 *h, const char *group, const char *name, DrVec3 v, const char *units, DrError *err)
{
    return dr_h5_write_vec3(h, group, name, v, units, err);
}

static DrStatus write_liquid_arrays(DrH5 *h, const WorldLiquid *wl, bool compress, DrError *err)
{
    const DrLiquidState *st = dr_liquid_state(wl->liquid);
    return dr_world_write_particles_(h, wl->element->name, st->n, st->x, st->v, st->c, compress, err);
}

DrStatus dr_world_write_particles_(DrH5 *h, const char *name, long n, const double *x, const double *v,
                                   const double *affine, bool compress, DrError *err)
{
    return dr_h5_write_particles(h, name, n, x, v, affine, compress, err);
}

static DrStatus write_frame_body(const DrWorld *w, const DrFrameStats *stats, DrH5 *h, const char *bake_key,
                                 DrError *err)
{
    DR_TRY(dr_h5_attr_str(h, "/", "drench_version", DR_VERSION, err));
    DR_TRY(dr_h5_attr_i64(h, "/", "frame", w->frame, err));
    DR_TRY(dr_h5_attr_f64(h, "/", "time", dr_world_frame_time(w, w->frame), err));
    DR_TRY(dr_h5_attr_i64(h, "/", "substeps", stats->substeps, err));
    DR_TRY(dr_h5_attr_str(h, "/", "scene_key", bake_key, err));
    DR_TRY(dr_h5_attr_str(h, "/", "units", "SI: m, s, kg", err));
    for (int i = 0; i < w->nliquids; i++) {
        const WorldLiquid *wl = &w->liquids[i];
        char g[512];
        PATHF(g, "/%s", wl->element->name);
        DR_TRY(write_liquid_arrays(h, wl, true, err));
        DR_TRY(dr_h5_attr_str(h, g, "type", "liquid", err));
        double mass, ke;
        DrVec3 p, l;
        dr_liquid_totals(wl->liquid, &mass, &p, &l, &ke);
        const DrLiquidStats *ls = &wl->last;
        double dx = dr_liquid_grid(wl->liquid)->dx;
        PATHF(g, "/diagnostics/%s", wl->element->name);
        DR_TRY(dr_world_write_scalar_(h, g, "particles", (double)ls->particles, "1", err));
        DR_TRY(dr_world_write_scalar_(h, g, "mass", mass, "kg", err));
        DR_TRY(dr_world_write_scalar_(h, g, "kinetic_energy", ke, "J", err));
        DR_TRY(dr_world_write_vec_(h, g, "linear_momentum", p, "kg*m/s", err));
        DR_TRY(dr_world_write_vec_(h, g, "angular_momentum", l, "kg*m^2/s", err));
        DR_TRY(dr_world_write_scalar_(h, g, "volume_cells", (double)ls->liquid_cells * dx * dx * dx, "m^3", err));
        DR_TRY(dr_world_write_scalar_(h, g, "max_speed", ls->max_speed, "m/s", err));
        DR_TRY(dr_world_write_scalar_(h, g, "divergence_mean", ls->divergence_mean, "1", err));
        DR_TRY(dr_world_write_scalar_(h, g, "pressure_iterations_max", ls->pressure_iterations_max, "1", err));
        DR_TRY(dr_world_write_scalar_(h, g, "pressure_iterations_total", (double)ls->pressure_iterations_total, "1", err));
        DR_TRY(dr_world_write_scalar_(h, g, "pressure_residual_max", ls->pressure_residual_max, "1", err));
        DR_TRY(dr_world_write_scalar_(h, g, "emitted", (double)ls->emitted, "1", err));
        DR_TRY(dr_world_write_scalar_(h, g, "killed", (double)ls->killed, "1", err));
    }
    for (int i = 0; i < w->ncolliders; i++) {
        const WorldCollider *wc = &w->colliders[i];
        if (!wc->collider) continue;
        DrXform X = dr_collider_pose(wc->collider, dr_world_frame_time(w, w->frame));
        char path[512];
        PATHF(path, "/%s/rotation", wc->element->name);
        uint64_t d33[2] = {3, 3}, d3[1] = {3};
        DR_TRY(dr_h5_write_f64(h, path, 2, d33, &X.R.m[0][0], "1", false, err));
        PATHF(path, "/%s/translation", wc->element->name);
        double t[3] = {X.t.x, X.t.y, X.t.z};
        DR_TRY(dr_h5_write_f64(h, path, 1, d3, t, "m", false, err));
        PATHF(path, "/%s", wc->element->name);
        DR_TRY(dr_h5_attr_str(h, path, "type", "collider", err));
    }
    DR_TRY(dr_world_mpm_write_(w, h, true, err));
    DR_TRY(dr_world_hair_write_(w, h, true, err));
    DR_TRY(dr_world_bem_write_(w, h, true, err));
    const char *g = "/diagnostics";
    DR_TRY(dr_world_write_scalar_(h, g, "substeps", stats->substeps, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "liquid_volume_cells", stats->liquid_volume, "m^3", err));
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
    DrStatus s = dr_h5_attr_str(h, "/", "scene_key", bake_key, err);
    if (s == DR_OK) s = dr_h5_attr_i64(h, "/", "frame", w->frame, err);
    if (s == DR_OK) s = dr_h5_attr_str(h, "/", "drench_version", DR_VERSION, err);
    for (int i = 0; s == DR_OK && i < w->nliquids; i++) {
        const WorldLiquid *wl = &w->liquids[i];
        /* uncompressed: a checkpoint is written every frame and read rarely */
        s = write_liquid_arrays(h, wl, false, err);
        DrLiquidResume rs;
        dr_liquid_resume_state(wl->liquid, &rs);
        uint64_t d[1] = {4}, d1[1] = {1};
        char p[512];
        PATHF(p, "/%s/rng", wl->element->name);
        if (s == DR_OK) s = dr_h5_write_u64(h, p, 1, d, rs.rng, false, err);
        PATHF(p, "/%s/cfl_acceleration", wl->element->name);
        if (s == DR_OK) s = dr_h5_write_f64(h, p, 1, d1, &rs.cfl_accel, "m/s^2", false, err);
        PATHF(p, "/%s/volume0", wl->element->name);
        if (s == DR_OK) s = dr_h5_write_f64(h, p, 1, d1, &wl->volume0, "m^3", false, err);
    }
    if (s == DR_OK) s = dr_world_mpm_write_(w, h, false, err);
    if (s == DR_OK) s = dr_world_hair_write_(w, h, false, err);
    if (s == DR_OK) s = dr_world_bem_write_(w, h, false, err);
    return s;
}

static DrStatus read_liquid(DrH5 *h, const char *path, WorldLiquid *wl, DrError *err)
{
    const char *name = wl->element->name;
    char p[512];
    int rank;
    uint64_t dx[4], dv[4], dc[4], dr[4], d0[4], da[4];
    double *x = NULL, *v = NULL, *c = NULL, *v0 = NULL, *acc = NULL;
    uint64_t *rng = NULL;
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
    if (s == DR_OK && (dx[0] != dv[0] || dx[0] != dc[0] || dr[0] != 4 || d0[0] != 1 || da[0] != 1))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "checkpoint arrays of '%s' disagree in size; delete the "
                         "checkpoint and bake without --resume", name);
    if (s == DR_OK) {
        DrLiquidResume rs;
        memcpy(rs.rng, rng, sizeof rs.rng);
        rs.cfl_accel = acc[0];
        s = dr_liquid_restore(wl->liquid, (long)dx[0], x, v, c, &rs, err);
    }
    if (s == DR_OK) wl->volume0 = v0[0];
    free(x);
    free(v);
    free(c);
    free(rng);
    free(v0);
    free(acc);
    return s;
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
    if (s == DR_OK && (frame < w->first_frame - 1 || frame >= w->last_frame))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "checkpoint frame %lld is outside the shot's frames %d-%d",
                         (long long)frame, w->first_frame, w->last_frame);
    for (int i = 0; s == DR_OK && i < w->nliquids; i++) s = read_liquid(h, path, &w->liquids[i], err);
    if (s == DR_OK) s = dr_world_mpm_read_(w, h, path, err);
    if (s == DR_OK) s = dr_world_hair_read_(w, h, path, err);
    if (s == DR_OK) s = dr_world_bem_read_(w, h, path, (int)frame, err);
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
    for (int i = 0; i < w->nliquids; i++) {
        const DrLiquidState *st = dr_liquid_state(w->liquids[i].liquid);
        dr_hasher_update(&h, &st->n, sizeof st->n);
        dr_hasher_update(&h, st->x, 3 * sizeof(double) * (size_t)st->n);
        dr_hasher_update(&h, st->v, 3 * sizeof(double) * (size_t)st->n);
        dr_hasher_update(&h, st->c, 9 * sizeof(double) * (size_t)st->n);
        DrLiquidResume rs;
        dr_liquid_resume_state(w->liquids[i].liquid, &rs);
        dr_hasher_update(&h, rs.rng, sizeof rs.rng);
        dr_hasher_update(&h, &rs.cfl_accel, sizeof rs.cfl_accel);
    }
    dr_world_mpm_hash_(w, &h);
    dr_world_hair_hash_(w, &h);
    dr_world_bem_hash_(w, &h);
    return dr_hasher_final(&h);
}
