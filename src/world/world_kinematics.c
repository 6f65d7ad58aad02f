/* Kinematics: every scene collider (its SDF, its motion keys, posed once per clock step for every solver) and each
 * bem_solid body as a moving collider of the liquid and of the hair (one-way: neither pushes the bodies). */
#include "world_adapter.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact.h"
#include "liquid/liquid.h"
#include "stage/stage.h"
#include "vdb/vdb.h"

typedef struct WorldCollider {
    const DrElement *element;
    DrCollider *collider;    /* NULL when no solver needs an SDF (a scene with neither liquid, MPM nor hair) */
} WorldCollider;

/* A bem_solid body as the liquid sees it. The signed distance of its surface in the body frame, x − x̄ + u (the
   reference and displacement of V = R(x − x̄ + u) + T), is carried by the body's rigid frame through motion keys
   over each BEM step (body_keys); it is rebuilt from the deformed surface when u moved a vertex by more than a
   quarter of the SDF's cell since it was built. */
typedef struct WorldBodyCollider {
    const DrBemSolid *solid;
    const DrElement *element;
    float *phi;              /* body-frame SDF nodes, x fastest */
    int nx, ny, nz;
    DrVec3 origin;
    double dx;
    double *built_u;         /* u when the SDF was built (3N) */
    DrXform start;           /* the body's frame (R, T) at the start of the step being taken */
    DrXform start0;          /* and at t = 0: R₀ the element's Transform rotation, T₀ = R₀x̄ + t (world_bem.c) */
    DrVec3 start_velocity;   /* and its Ṫ */
    double *keys;            /* the frame's key rows so far (7 each) */
    int nkeys, cap_keys;
    DrCollider *collider;    /* the SDF posed by keys; rebuilt every BEM step */
    /* two-way with the liquid (world_kinematics_body_couple): a rigid proxy of the body's frame that the liquid's
       substeps move between two BEM steps, and what the liquid gave it over the BEM step being gathered */
    bool coupled;
    DrMat3 R;                /* the proxy: rotation, centre of mass, velocity, angular velocity (world) */
    DrVec3 T, V, W;
    double mass;             /* kg */
    DrMat3 Ib_inv;           /* inverse inertia about x̄, body axes */
    DrVec3 impulse, angular_impulse; /* summed over the step's substeps, N s and N m s about the centre */
    double span;             /* seconds gathered */
    double *pdt, *wdt;       /* N: ∫ p dt (Pa s) and ∫ wet dt (s) at each vertex */
    double *nb;              /* 3N unit outward normals of the deformed surface, body axes */
    double *pts, *pv, *pw;   /* scratch: 3N sample points, N pressures, N wet weights */
} WorldBodyCollider;

struct WorldKinematics {
    WorldCollider *colliders;
    int ncolliders;
    const DrCollider **live; /* the live colliders, in element order, as the solvers take them */
    int nlive;
    WorldPosedCollider *posed; /* one per live collider */
    double dx;               /* SDF spacing, 0 when nothing samples colliders */
    WorldBodyCollider *bodies;
    int nbodies;
    int rebuilds;
    const DrCollider **liquid; /* what the liquid sees: the live colliders, then the bodies */
    int nliquid;
    WorldPosedCollider *body_posed; /* the bodies posed at the clock step's end, as the hair sees them */
    DrPointField *mpm_surface; /* the MPM particles as a surface for the hair, NULL without hair or MPM */
    WorldMpmParticles mpm;   /* the MPM particles two-way with the first liquid (world_kinematics_mpm_couple) */
    WorldWetLink wet;        /* capture and dripping between the first liquid and the wet hair */
    WorldClothLink cloth;    /* hair against cloth */
    DrVec3 gravity;          /* the shot's, m/s² (the bodies' proxies) */
    DrLiquidBody *lbodies;   /* the two-way bodies as the liquid's substep takes them, and their body indices */
    int *lb_body;
    int nlb;
    double lb_h;             /* the substep they were predicted for */
};

double world_posed_sdf(DrVec3 x, DrVec3 *normal, void *ctx)
{
    const WorldPosedCollider *c = ctx;
    return dr_collider_frame_phi(&c->frame, x, normal);
}

DrVec3 world_posed_velocity(DrVec3 x, void *ctx)
{
    const WorldPosedCollider *c = ctx;
    return dr_collider_frame_velocity(&c->frame, x);
}

DrStatus world_make_collider(const DrTriMesh *mesh, double dx, double friction, bool no_slip, double thickness,
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

/* The smallest cell of any grid that samples colliders (liquid, MPM and air) or, for hair, a grown groom's segment
   length (4 mm for curves read from a file), for cloth 4 mm, 0 when nothing samples colliders. */
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
        } else if (e->kind == DR_ELEMENT_AIR) {
            d = dr_component_num(dr_element_component(e, "AirDomain"), "voxel_size");
        } else if (e->kind == DR_ELEMENT_CLOTH) {
            d = 0.004; /* a cloth vertex meets colliders through their SDF: samples every 2 mm keep the trilinear SDF's
                          error at a faceted body's edges within a tenth of the default 1 mm contact layer */
        } else {
            continue;
        }
        if (dx == 0.0 || d < dx) dx = d;
    }
    return dx;
}

static DrStatus build_colliders(WorldKinematics *k, const DrScene *scene, int first_frame, double fps, DrError *err)
{
    int n = dr_scene_count_kind(scene, DR_ELEMENT_COLLIDER);
    DR_TRY(dr_calloc((size_t)n + 1, sizeof(WorldCollider), &k->colliders, err));
    DR_TRY(dr_calloc((size_t)n + 1, sizeof(DrCollider *), &k->live, err));
    DR_TRY(dr_calloc((size_t)n + 1, sizeof(WorldPosedCollider), &k->posed, err));
    /* The SDF resolves the smallest grid cell twice so face fractions see the collider's shape. */
    double dx = smallest_grid_dx(scene) * 0.5;
    k->dx = dx;
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_COLLIDER) continue;
        WorldCollider *wc = &k->colliders[k->ncolliders++];
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
        DrStatus s = dr_stage_motion_keys(e, first_frame, fps, &keys, &nrows, err);
        if (s == DR_OK)
            s = world_make_collider(&mesh, dx, dr_component_num(c, "friction"),
                                    strcmp(dr_component_str(c, "boundary"), "no_slip") == 0,
                                    dr_component_num(c, "thickness"), nrows, keys, &wc->collider, err);
        free(keys);
        dr_trimesh_free(&mesh);
        DR_TRY(dr_error_prefix(s, err, "%s.Mesh.file", e->name));
        WorldPosedCollider *p = &k->posed[k->nlive];
        p->collider = wc->collider;
        p->frame = dr_collider_frame(wc->collider, 0.0);
        p->moving = nrows > 0;
        k->live[k->nlive++] = wc->collider;
    }
    return DR_OK;
}

#define BODY_KEY_INTERVALS 16

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
    X->R = dr_m3_load(R);
    X->t = dr_v3(T[0], T[1], T[2]);
    *v = dr_v3(va[0], va[1], va[2]);
}

static DrVec3 body_angular_velocity(const DrBemSolid *s) /* ω of the body's frame, world axes */
{
    double va[3], wa[3];
    dr_bem_solid_frame_velocity(s, va, wa);
    return dr_v3(wa[0], wa[1], wa[2]);
}

static void put_key(double *row, double t, DrVec3 T, DrVec3 e)
{
    double r[7] = {t, T.x, T.y, T.z, e.x, e.y, e.z};
    memcpy(row, r, sizeof r);
}

/* (Re)builds the body's DrCollider from its SDF and its current keys (when the SDF is new). */
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

/* Keys carrying the body from bc->start (at t0) to its frame now (at t1), appended to the frame's keys so far (from
   the frame's start; a step starting at t_frame starts them afresh): BODY_KEY_INTERVALS rows per step, the position
   on the cubic Hermite curve through T and Ṫ at both ends (exact for a free fall), the rotation along the shortest
   arc from R(t0) to R(t1); then one key past t1 along the body's velocity there (a collider holds still after its
   last key, and a solver takes a collider's velocity at the end of its step, which may be t1), replaced by the next
   step's keys. Between keys the pose is linear (rotation in XYZ Euler angles, as every collider's), so the surface
   velocity a solver sees is the rate of that pose: Ṫ + ω × r to within the key spacing; the rate of the
   deformation u̇ is not seen. Keeping the frame's keys lets the liquid and the hair take steps across BEM step
   ends: the pose at a step's start and at its end both come from them. */
static DrStatus body_keys(WorldBodyCollider *bc, double t_frame, double t0, double t1, DrError *err)
{
    DrXform X1;
    DrVec3 V1, V0 = bc->start_velocity;
    body_frame(bc->solid, &X1, &V1);
    DrMat3 R0 = bc->start.R;
    DrVec3 T0 = bc->start.t, w = dr_m3_rotation_log(dr_m3_mul(dr_m3_transpose(R0), X1.R));
    double h = t1 - t0;
    int first = 1; /* the step's first key is the last step's last (t0) */
    DrVec3 e;
    if (t0 == t_frame || bc->nkeys < 2) {
        bc->nkeys = 0;
        first = 0;
        e = euler_near(R0, dr_v3(0, 0, 0));
    } else {
        bc->nkeys--; /* drops the key past the last step's end */
        const double *last = bc->keys + 7 * (bc->nkeys - 1);
        e = dr_v3(last[4], last[5], last[6]);
    }
    int need = bc->nkeys + BODY_KEY_INTERVALS + 2;
    if (need > bc->cap_keys) { /* doubled, kept: the first frame sizes it */
        int cap = 2 * need;
        DR_TRY(dr_realloc((size_t)cap * 7, sizeof(double), &bc->keys, err));
        bc->cap_keys = cap;
    }
    for (int k = first; k <= BODY_KEY_INTERVALS; k++) {
        double s = (double)k / BODY_KEY_INTERVALS, s2 = s * s, s3 = s2 * s;
        DrVec3 T = dr_v3_add(dr_v3_add(dr_v3_scale(T0, 2 * s3 - 3 * s2 + 1), dr_v3_scale(V0, h * (s3 - 2 * s2 + s))),
                             dr_v3_add(dr_v3_scale(X1.t, 3 * s2 - 2 * s3), dr_v3_scale(V1, h * (s3 - s2))));
        DrMat3 R = k == BODY_KEY_INTERVALS ? X1.R : dr_m3_mul(R0, dr_m3_rotation_exp(dr_v3_scale(w, s)));
        if (k == BODY_KEY_INTERVALS) T = X1.t;
        e = euler_near(R, e);
        put_key(bc->keys + 7 * bc->nkeys++, k == BODY_KEY_INTERVALS ? t1 : t0 + s * h, T, e);
    }
    DrVec3 W1 = body_angular_velocity(bc->solid);
    DrMat3 Rx = dr_m3_mul(dr_m3_rotation_exp(dr_v3_scale(W1, h)), X1.R);
    e = euler_near(Rx, e);
    put_key(bc->keys + 7 * bc->nkeys++, t1 + h, dr_v3_add(X1.t, dr_v3_scale(V1, h)), e);
    return DR_OK;
}

/* The SDF of the body's surface in its frame, x − x̄ + u, at spacing dx; remembers u. */
static DrStatus build_body_sdf(WorldBodyCollider *bc, double dx, DrError *err)
{
    const DrBemMatrices *m = dr_bem_solid_matrices(bc->solid);
    size_t n3 = 3 * (size_t)m->nv;
    const double *ref = dr_bem_solid_reference(bc->solid), *u = dr_bem_solid_displacement(bc->solid);
    DrTriMesh surf = {.nv = m->nv, .nt = m->nt, .tri = m->tri};
    DR_TRY(dr_calloc(n3, sizeof(double), &surf.v, err));
    for (size_t i = 0; i < n3; i++) surf.v[i] = ref[i] + u[i];
    DrDenseSdf sdf = {0};
    DrStatus s = dr_vdb_mesh_to_sdf(&surf, dx, 4, &sdf, err);
    free(surf.v);
    DR_TRY(dr_error_prefix(s, err, "%s.Mesh.file", bc->element->name));
    free(bc->phi);
    bc->phi = sdf.phi; /* owned from here */
    bc->nx = sdf.nx;
    bc->ny = sdf.ny;
    bc->nz = sdf.nz;
    bc->origin = sdf.origin;
    bc->dx = sdf.dx;
    memcpy(bc->built_u, u, n3 * sizeof(double));
    return DR_OK;
}

/* Whether u moved any vertex by more than a quarter of the SDF's cell since the SDF was built. */
static bool deformed_since_built(const WorldBodyCollider *bc)
{
    const DrBemMatrices *m = dr_bem_solid_matrices(bc->solid);
    const double *u = dr_bem_solid_displacement(bc->solid);
    double lim2 = 0.0625 * bc->dx * bc->dx;
    for (int i = 0; i < m->nv; i++) {
        double d[3] = {u[3 * i] - bc->built_u[3 * i], u[3 * i + 1] - bc->built_u[3 * i + 1],
                       u[3 * i + 2] - bc->built_u[3 * i + 2]};
        if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > lim2) return true;
    }
    return false;
}

DrStatus world_kinematics_add_bodies(WorldKinematics *k, const DrScene *scene, const DrBemSolid *const *solids,
                                     const DrElement *const *elements, int n, DrError *err)
{
    bool liquid = dr_scene_count_kind(scene, DR_ELEMENT_LIQUID) > 0, hair = dr_scene_count_kind(scene, DR_ELEMENT_HAIR) > 0;
    bool cloth = dr_scene_count_kind(scene, DR_ELEMENT_CLOTH) > 0;
    if (!liquid && !hair && !cloth) n = 0;
    DR_TRY(dr_calloc((size_t)k->nlive + (size_t)n + 1, sizeof(DrCollider *), &k->liquid, err));
    for (int i = 0; i < k->nlive; i++) k->liquid[i] = k->live[i];
    k->nliquid = k->nlive;
    if (n == 0) return DR_OK;
    DR_TRY(dr_calloc((size_t)n, sizeof(WorldBodyCollider), &k->bodies, err));
    DR_TRY(dr_calloc((size_t)n, sizeof(WorldPosedCollider), &k->body_posed, err));
    for (int i = 0; i < n; i++) {
        WorldBodyCollider *bc = &k->bodies[k->nbodies++];
        bc->solid = solids[i];
        bc->element = elements[i];
        DR_TRY(dr_calloc(3 * (size_t)dr_bem_solid_matrices(bc->solid)->nv, sizeof(double), &bc->built_u, err));
        DR_TRY(build_body_sdf(bc, k->dx, err));
        DR_TRY(dr_calloc(7 * (BODY_KEY_INTERVALS + 2), sizeof(double), &bc->keys, err));
        bc->cap_keys = BODY_KEY_INTERVALS + 2;
        body_frame(bc->solid, &bc->start, &bc->start_velocity);
        double scale;
        DrXform X = dr_stage_element_transform(bc->element, &scale);
        const double *xb = dr_bem_solid_matrices(bc->solid)->body.centroid;
        bc->start0 = (DrXform){X.R, dr_v3_add(dr_m3_apply(X.R, dr_v3(xb[0], xb[1], xb[2])), X.t)};
        put_key(bc->keys, 0.0, bc->start.t, euler_near(bc->start.R, dr_v3(0, 0, 0)));
        bc->nkeys = 1; /* at rest where the Transform put it: no liquid is seeded inside it */
        DR_TRY(pose_body_collider(bc, err));
        if (liquid) k->liquid[k->nliquid++] = bc->collider;
        k->body_posed[i] = (WorldPosedCollider){bc->collider, dr_collider_frame(bc->collider, 0.0), true};
    }
    dr_log_info("world: the %s %d bem_solid bod%s as moving collider(s) (the deformed surface, rebuilt when "
                "it moved by a quarter of an SDF cell, carried by the body's frame)",
                liquid && hair ? "liquid and the hair see" : liquid ? "liquid sees" : "hair sees", k->nbodies,
                k->nbodies == 1 ? "y" : "ies");
    return DR_OK;
}

void world_kinematics_body_begin(WorldKinematics *k, int i)
{
    if (i >= k->nbodies) return; /* neither liquid nor hair sees the bodies */
    body_frame(k->bodies[i].solid, &k->bodies[i].start, &k->bodies[i].start_velocity);
}

DrStatus world_kinematics_body_end(WorldKinematics *k, int i, double t_frame, double t0, double t1, DrError *err)
{
    if (i >= k->nbodies) return DR_OK;
    WorldBodyCollider *bc = &k->bodies[i];
    bool rebuilt = deformed_since_built(bc);
    if (rebuilt) {
        DR_TRY(build_body_sdf(bc, k->dx, err));
        k->rebuilds++;
    }
    DR_TRY(body_keys(bc, t_frame, t0, t1, err));
    /* a new collider only for a new SDF; otherwise the one there takes the frame's keys so far */
    DrStatus s = rebuilt ? pose_body_collider(bc, err) : dr_collider_set_keys(bc->collider, bc->keys, bc->nkeys, err);
    DR_TRY(dr_error_prefix(s, err, "%s.BemSolver", bc->element->name));
    if (k->nliquid > k->nlive) k->liquid[k->nlive + i] = bc->collider;
    k->body_posed[i].collider = bc->collider;
    return DR_OK;
}

int world_kinematics_body_rebuilds(const WorldKinematics *k) { return k->rebuilds; }

/* ---- two-way bodies: the liquid pushes them ---------------------------------------------------------------------
 * Between two of its BEM steps a two-way body is, for the liquid, a rigid body: a proxy of its frame (R, T, Ṫ, ω,
 * with the body's mass and inertia) that each liquid substep predicts under gravity, keys the body's collider along,
 * and hands to the projection, which solves the proxy's velocity with the pressure (dr_liquid_set_bodies). The
 * proxy takes the velocity the projection gives and keeps the position the liquid saw, and every vertex gathers the
 * pressure one liquid cell outside it. At the step's end the body takes one BEM step loaded with that pressure as
 * traction, corrected by the least rigid field so that its resultant force and moment are exactly the impulses the
 * projections gave the proxy over the step: the frame's velocity after the step is the proxy's (the BEM frame
 * integrates its position over the whole step, the proxy over the substeps: they differ by O(Δt²) in position,
 * which the next step's proxy starts from). The elastic response to the pressure is lagged by the BEM step (the
 * deformed shape the liquid sees is that of the last step; the deformation's own velocity u̇ is not seen). */

/* Area-weighted unit vertex normals of the deformed surface ref + u, body axes. */
static void body_normals(WorldBodyCollider *bc)
{
    const DrBemMatrices *m = dr_bem_solid_matrices(bc->solid);
    const double *ref = dr_bem_solid_reference(bc->solid), *u = dr_bem_solid_displacement(bc->solid);
    memset(bc->nb, 0, sizeof(double) * 3 * (size_t)m->nv);
    for (int t = 0; t < m->nt; t++) {
        const int *tv = m->tri + 3 * t;
        DrVec3 p[3];
        for (int q = 0; q < 3; q++)
            p[q] = dr_v3(ref[3 * tv[q]] + u[3 * tv[q]], ref[3 * tv[q] + 1] + u[3 * tv[q] + 1],
                         ref[3 * tv[q] + 2] + u[3 * tv[q] + 2]);
        DrVec3 n = dr_v3_cross(dr_v3_sub(p[1], p[0]), dr_v3_sub(p[2], p[0])); /* twice the area, outward */
        for (int q = 0; q < 3; q++) {
            bc->nb[3 * tv[q]] += n.x;
            bc->nb[3 * tv[q] + 1] += n.y;
            bc->nb[3 * tv[q] + 2] += n.z;
        }
    }
    for (int v = 0; v < m->nv; v++) {
        double *n = bc->nb + 3 * v, l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (l > 0.0)
            for (int c = 0; c < 3; c++) n[c] /= l;
    }
}

/* The proxy from the body's frame now, nothing gathered. */
static void proxy_sync(WorldBodyCollider *bc)
{
    double R[9], T[3], v[3], w[3];
    dr_bem_solid_pose(bc->solid, R, T);
    dr_bem_solid_frame_velocity(bc->solid, v, w);
    bc->R = dr_m3_load(R);
    bc->T = dr_v3(T[0], T[1], T[2]);
    bc->V = dr_v3(v[0], v[1], v[2]);
    bc->W = dr_v3(w[0], w[1], w[2]);
    bc->impulse = bc->angular_impulse = dr_v3(0, 0, 0);
    bc->span = 0.0;
    int nv = dr_bem_solid_matrices(bc->solid)->nv;
    memset(bc->pdt, 0, sizeof(double) * (size_t)nv);
    memset(bc->wdt, 0, sizeof(double) * (size_t)nv);
    body_normals(bc);
}

/* Keys: the pose now at t, X1 at t1, and one more along V1, W1 past it. */
static DrStatus proxy_keys(WorldBodyCollider *bc, double t, DrMat3 R0, DrVec3 T0, double t1, DrMat3 R1, DrVec3 T1,
                           DrVec3 V1, DrVec3 W1, DrError *err)
{
    double h = t1 - t;
    DrVec3 e0 = euler_near(R0, dr_v3(0, 0, 0)); /* a function of the pose alone: a resumed bake keys the same bits */
    DrVec3 e1 = euler_near(R1, e0);
    DrVec3 e2 = euler_near(dr_m3_mul(dr_m3_rotation_exp(dr_v3_scale(W1, h)), R1), e1);
    if (bc->cap_keys < 3) {
        DR_TRY(dr_realloc(3 * 7, sizeof(double), &bc->keys, err));
        bc->cap_keys = 3;
    }
    put_key(bc->keys, t, T0, e0);
    put_key(bc->keys + 7, t1, T1, e1);
    put_key(bc->keys + 14, t1 + h, dr_v3_add(T1, dr_v3_scale(V1, h)), e2);
    bc->nkeys = 3;
    return dr_collider_set_keys(bc->collider, bc->keys, bc->nkeys, err);
}

DrStatus world_kinematics_body_couple(WorldKinematics *k, int i, DrError *err)
{
    if (i >= k->nbodies) return DR_OK;
    WorldBodyCollider *bc = &k->bodies[i];
    const DrBemMatrices *m = dr_bem_solid_matrices(bc->solid);
    size_t nv = (size_t)m->nv;
    DR_TRY(dr_calloc(nv, sizeof(double), &bc->pdt, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &bc->wdt, err));
    DR_TRY(dr_calloc(3 * nv, sizeof(double), &bc->nb, err));
    DR_TRY(dr_calloc(3 * nv, sizeof(double), &bc->pts, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &bc->pv, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &bc->pw, err));
    double Ib[9];
    bc->mass = m->body.mass;
    if (!dr_m3a_inverse(m->body.inertia, Ib))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s.Mesh.file: the body's inertia is singular (a flat or "
                            "degenerate mesh); it cannot float in the liquid: give a closed mesh with volume or set "
                            "%s.BemSolver.liquid_coupling to \"one_way\"", bc->element->name, bc->element->name);
    bc->Ib_inv = dr_m3_load(Ib);
    bc->coupled = true;
    int n = 0;
    for (int b = 0; b < k->nbodies; b++) n += k->bodies[b].coupled;
    DR_TRY(dr_realloc((size_t)n, sizeof(DrLiquidBody), &k->lbodies, err));
    DR_TRY(dr_realloc((size_t)n, sizeof(int), &k->lb_body, err));
    proxy_sync(bc);
    return DR_OK;
}

bool world_kinematics_body_coupled(const WorldKinematics *k, int i) { return i < k->nbodies && k->bodies[i].coupled; }

/* The proxy's contact with the scene's colliders (posed at the clock step's end): a vertex within an SDF cell of a
   collider does not move into it, by sequential normal impulses on the rigid proxy (a few sweeps). The body's own BEM
   step solves its contact exactly; this keeps the proxy, which gravity pulls down between two BEM steps, from
   squeezing the liquid between a resting body and the floor into a pressure spike. */
static void proxy_contact(WorldKinematics *k, WorldBodyCollider *bc, DrVec3 *V, DrVec3 *W)
{
    if (k->nlive == 0) return;
    const DrBemMatrices *m = dr_bem_solid_matrices(bc->solid);
    const double *ref = dr_bem_solid_reference(bc->solid), *u = dr_bem_solid_displacement(bc->solid);
    DrMat3 Iw = dr_m3_mul(dr_m3_mul(bc->R, bc->Ib_inv), dr_m3_transpose(bc->R));
    double reach = 2.0 * k->dx;
    for (int sweep = 0; sweep < 4; sweep++)
        for (int v = 0; v < m->nv; v++) {
            DrVec3 r = dr_m3_apply(bc->R, dr_v3(ref[3 * v] + u[3 * v], ref[3 * v + 1] + u[3 * v + 1], ref[3 * v + 2] + u[3 * v + 2]));
            DrVec3 x = dr_v3_add(bc->T, r);
            for (int c = 0; c < k->nlive; c++) {
                const DrColliderFrame *fr = &k->posed[c].frame;
                if (dr_collider_frame_phi(fr, x, NULL) > reach) continue;
                DrVec3 n;
                (void)dr_collider_frame_phi(fr, x, &n);
                DrVec3 vrel = dr_v3_sub(dr_v3_add(*V, dr_v3_cross(*W, r)), dr_collider_frame_velocity(fr, x));
                double vn = dr_v3_dot(vrel, n);
                if (!(vn < 0.0)) continue;
                DrVec3 rn = dr_v3_cross(r, n);
                double inv = 1.0 / bc->mass + dr_v3_dot(rn, dr_m3_apply(Iw, rn));
                double j = -vn / inv;
                *V = dr_v3_add(*V, dr_v3_scale(n, j / bc->mass));
                *W = dr_v3_add(*W, dr_m3_apply(Iw, dr_v3_scale(rn, j)));
            }
        }
}

int world_kinematics_liquid_bodies(WorldKinematics *k, double t, double h, DrLiquidBody **out, DrError *err)
{
    k->nlb = 0;
    k->lb_h = h;
    for (int i = 0; i < k->nbodies; i++) {
        WorldBodyCollider *bc = &k->bodies[i];
        if (!bc->coupled) continue;
        DrVec3 V = dr_v3_add(bc->V, dr_v3_scale(k->gravity, h)), W = bc->W;
        proxy_contact(k, bc, &V, &W);
        DrVec3 T1 = dr_v3_add(bc->T, dr_v3_scale(V, h));
        DrMat3 R1 = dr_m3_mul(dr_m3_rotation_exp(dr_v3_scale(W, h)), bc->R);
        DrStatus s = proxy_keys(bc, t, bc->R, bc->T, t + h, R1, T1, V, W, err);
        if (s < 0) return dr_error_prefix(s, err, "%s.BemSolver", bc->element->name);
        if (k->nliquid > k->nlive) k->liquid[k->nlive + i] = bc->collider;
        k->body_posed[i].collider = bc->collider;
        DrLiquidBody *lb = &k->lbodies[k->nlb];
        memset(lb, 0, sizeof *lb);
        lb->collider = bc->collider;
        lb->center[0] = T1.x, lb->center[1] = T1.y, lb->center[2] = T1.z;
        lb->inv_mass = 1.0 / bc->mass;
        dr_m3_store(dr_m3_mul(dr_m3_mul(R1, bc->Ib_inv), dr_m3_transpose(R1)), lb->inv_inertia);
        lb->velocity[0] = V.x, lb->velocity[1] = V.y, lb->velocity[2] = V.z;
        lb->angular_velocity[0] = W.x, lb->angular_velocity[1] = W.y, lb->angular_velocity[2] = W.z;
        k->lb_body[k->nlb++] = i;
    }
    *out = k->lbodies;
    return k->nlb;
}

void world_kinematics_liquid_bodies_done(WorldKinematics *k, const DrLiquid *liquid)
{
    double h = k->lb_h, dx = dr_liquid_grid(liquid)->dx;
    for (int n = 0; n < k->nlb; n++) {
        const DrLiquidBody *lb = &k->lbodies[n];
        WorldBodyCollider *bc = &k->bodies[k->lb_body[n]];
        /* the pose the liquid saw at the substep's end, the velocity its projection gave */
        bc->T = dr_v3(lb->center[0], lb->center[1], lb->center[2]);
        bc->R = dr_m3_mul(dr_m3_rotation_exp(dr_v3_scale(dr_v3(lb->angular_velocity[0], lb->angular_velocity[1],
                                                                 lb->angular_velocity[2]), h)), bc->R);
        bc->V = dr_v3(lb->velocity_out[0], lb->velocity_out[1], lb->velocity_out[2]);
        bc->W = dr_v3(lb->angular_velocity_out[0], lb->angular_velocity_out[1], lb->angular_velocity_out[2]);
        bc->impulse = dr_v3_add(bc->impulse, dr_v3(lb->impulse[0], lb->impulse[1], lb->impulse[2]));
        bc->angular_impulse = dr_v3_add(bc->angular_impulse, dr_v3(lb->angular_impulse[0], lb->angular_impulse[1],
                                                                   lb->angular_impulse[2]));
        bc->span += h;
        /* the pressure a cell outside each vertex */
        const DrBemMatrices *m = dr_bem_solid_matrices(bc->solid);
        const double *ref = dr_bem_solid_reference(bc->solid), *u = dr_bem_solid_displacement(bc->solid);
        for (int v = 0; v < m->nv; v++) {
            DrVec3 y = dr_v3(ref[3 * v] + u[3 * v] + dx * bc->nb[3 * v], ref[3 * v + 1] + u[3 * v + 1] + dx * bc->nb[3 * v + 1],
                             ref[3 * v + 2] + u[3 * v + 2] + dx * bc->nb[3 * v + 2]);
            DrVec3 x = dr_v3_add(dr_m3_apply(bc->R, y), bc->T);
            bc->pts[3 * v] = x.x, bc->pts[3 * v + 1] = x.y, bc->pts[3 * v + 2] = x.z;
        }
        dr_liquid_sample_wet_pressure(liquid, m->nv, bc->pts, bc->pv, bc->pw);
        for (int v = 0; v < m->nv; v++) {
            bc->pdt[v] += h * bc->pv[v];
            bc->wdt[v] += h * bc->pw[v];
        }
    }
    k->nlb = 0;
}

/* Solves the 6 × 6 system a x = b by Gaussian elimination with partial pivoting; false if singular. */
static bool solve6(double a[36], double b[6])
{
    for (int c = 0; c < 6; c++) {
        int p = c;
        for (int r = c + 1; r < 6; r++)
            if (fabs(a[6 * r + c]) > fabs(a[6 * p + c])) p = r;
        if (!(fabs(a[6 * p + c]) > 1e-300)) return false;
        if (p != c) {
            for (int q = 0; q < 6; q++) {
                double tmp = a[6 * c + q];
                a[6 * c + q] = a[6 * p + q];
                a[6 * p + q] = tmp;
            }
            double tmp = b[c];
            b[c] = b[p];
            b[p] = tmp;
        }
        for (int r = c + 1; r < 6; r++) {
            double f = a[6 * r + c] / a[6 * c + c];
            for (int q = c; q < 6; q++) a[6 * r + q] -= f * a[6 * c + q];
            b[r] -= f * b[c];
        }
    }
    for (int c = 5; c >= 0; c--) {
        for (int q = c + 1; q < 6; q++) b[c] -= a[6 * c + q] * b[q];
        b[c] /= a[6 * c + c];
    }
    return true;
}

/* [A p; C p] of eq. (10) for a traction p (3N, body frame). */
static void frame_load(const DrBemMatrices *m, const double *p, double out[6])
{
    for (int i = 0; i < 6; i++) out[i] = 0.0;
    for (int i = 0; i < 3; i++)
        for (int c = 0; c < m->n; c++) {
            out[i] += m->A[(size_t)i * m->n + c] * p[c];
            out[3 + i] += m->C[(size_t)i * m->n + c] * p[c];
        }
}

void world_kinematics_body_load(WorldKinematics *k, int i, double dt, double *traction, DrVec3 *impulse)
{
    WorldBodyCollider *bc = &k->bodies[i];
    const DrBemMatrices *m = dr_bem_solid_matrices(bc->solid);
    const double *ref = dr_bem_solid_reference(bc->solid);
    int nv = m->nv;
    *impulse = bc->impulse;
    /* the mean pressure as traction −p̄ n */
    for (int v = 0; v < nv; v++)
        for (int c = 0; c < 3; c++) traction[3 * v + c] = -bc->pdt[v] / dt * bc->nb[3 * v + c];
    /* the frame's accelerations the impulses give, body axes at the step's start (eqs. 10–11 use that rotation) */
    double R[9], T[3];
    dr_bem_solid_pose(bc->solid, R, T);
    DrMat3 Rt = dr_m3_transpose(dr_m3_load(R));
    DrVec3 F = dr_m3_apply(Rt, dr_v3_scale(bc->impulse, 1.0 / dt));
    DrVec3 tau = dr_m3_apply(Rt, dr_v3_scale(bc->angular_impulse, 1.0 / dt));
    DrVec3 alpha = dr_m3_apply(bc->Ib_inv, tau);
    double want[6] = {F.x / bc->mass, F.y / bc->mass, F.z / bc->mass, alpha.x, alpha.y, alpha.z}, have[6];
    frame_load(m, traction, have);
    /* the rigid field c + d × r closing the difference, weighted towards the vertices that were wet over the step
       (weight 0.1 + the fraction of the step they were wet: never singular, even when one vertex is wet) */
    double wsum = 0.0;
    for (int v = 0; v < nv; v++) wsum += bc->wdt[v];
    double a[36], rhs[6];
    double *basis = bc->pts; /* 3N scratch */
    for (int q = 0; q < 6; q++) {
        for (int v = 0; v < nv; v++) {
            double wt = 0.1 + bc->wdt[v] / dt;
            double r[3] = {ref[3 * v], ref[3 * v + 1], ref[3 * v + 2]}, e[3] = {0, 0, 0}, f[3];
            e[q % 3] = 1.0;
            if (q < 3) memcpy(f, e, sizeof f);
            else { /* e × r */
                f[0] = e[1] * r[2] - e[2] * r[1];
                f[1] = e[2] * r[0] - e[0] * r[2];
                f[2] = e[0] * r[1] - e[1] * r[0];
            }
            for (int c = 0; c < 3; c++) basis[3 * v + c] = wt * f[c];
        }
        double col[6];
        frame_load(m, basis, col);
        for (int r = 0; r < 6; r++) a[6 * r + q] = col[r];
    }
    for (int r = 0; r < 6; r++) rhs[r] = want[r] - have[r];
    if (solve6(a, rhs))
        for (int v = 0; v < nv; v++) {
            double wt = 0.1 + bc->wdt[v] / dt;
            double r[3] = {ref[3 * v], ref[3 * v + 1], ref[3 * v + 2]};
            double d[3] = {rhs[3], rhs[4], rhs[5]};
            double f[3] = {rhs[0] + d[1] * r[2] - d[2] * r[1], rhs[1] + d[2] * r[0] - d[0] * r[2],
                           rhs[2] + d[0] * r[1] - d[1] * r[0]};
            for (int c = 0; c < 3; c++) traction[3 * v + c] += wt * f[c];
        }
}

DrStatus world_kinematics_body_synced(WorldKinematics *k, int i, double t1, bool rebuild, DrError *err)
{
    WorldBodyCollider *bc = &k->bodies[i];
    if (rebuild || deformed_since_built(bc)) {
        DR_TRY(build_body_sdf(bc, k->dx, err));
        DR_TRY(pose_body_collider(bc, err));
        k->rebuilds++;
    }
    proxy_sync(bc);
    DrStatus s = proxy_keys(bc, t1, bc->R, bc->T, t1 + 1e-3, dr_m3_mul(dr_m3_rotation_exp(dr_v3_scale(bc->W, 1e-3)), bc->R),
                            dr_v3_add(bc->T, dr_v3_scale(bc->V, 1e-3)), bc->V, bc->W, err);
    DR_TRY(dr_error_prefix(s, err, "%s.BemSolver", bc->element->name));
    if (k->nliquid > k->nlive) k->liquid[k->nlive + i] = bc->collider;
    k->body_posed[i].collider = bc->collider;
    return DR_OK;
}


/* ---- the kinematics object ------------------------------------------------------------------------------------ */

DrStatus world_kinematics_create(const DrScene *scene, int first_frame, double fps, WorldKinematics **out, DrError *err)
{
    WorldKinematics *k = NULL;
    DR_TRY(dr_calloc(1, sizeof *k, &k, err));
    k->gravity = dr_component_vec3(dr_scene_section(scene, "shot"), "gravity");
    DrStatus s = build_colliders(k, scene, first_frame, fps, err);
    if (s == DR_OK && dr_scene_count_kind(scene, DR_ELEMENT_HAIR) + dr_scene_count_kind(scene, DR_ELEMENT_CLOTH) > 0 &&
        dr_scene_count_kind(scene, DR_ELEMENT_MPM_SOLID) > 0)
        s = dr_point_field_create(&k->mpm_surface, err);
    /* the cloth elements some hair element meets (vertex_face collision elements) */
    for (int i = 0; s == DR_OK && i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_CLOTH) continue;
        bool met = false;
        for (int j = 0; !met && j < dr_scene_element_count(scene); j++) {
            const DrElement *h = dr_scene_element(scene, j);
            met = h->kind == DR_ELEMENT_HAIR && dr_scene_collision(scene, h->name, e->name, "vertex_face");
        }
        if (!met) continue;
        s = dr_realloc((size_t)k->cloth.n + 1, sizeof *k->cloth.panels, &k->cloth.panels, err);
        if (s != DR_OK) break;
        WorldClothPanelLink *pl = &k->cloth.panels[k->cloth.n++];
        *pl = (WorldClothPanelLink){.element = e};
        s = dr_tri_field_create(&pl->field, err);
    }
    if (s < 0) {
        world_kinematics_destroy(&k);
        return s;
    }
    *out = k;
    return DR_OK;
}

void world_kinematics_destroy(WorldKinematics **kp)
{
    if (!kp || !*kp) return;
    WorldKinematics *k = *kp;
    for (int i = 0; i < k->nbodies; i++) {
        dr_collider_destroy(&k->bodies[i].collider);
        free(k->bodies[i].phi);
        free(k->bodies[i].keys);
        free(k->bodies[i].built_u);
    }
    for (int i = 0; i < k->nbodies; i++) {
        WorldBodyCollider *bc = &k->bodies[i];
        free(bc->pdt), free(bc->wdt), free(bc->nb), free(bc->pts), free(bc->pv), free(bc->pw);
    }
    free(k->lbodies);
    free(k->lb_body);
    free(k->bodies);
    free(k->body_posed);
    dr_point_field_destroy(&k->mpm_surface);
    for (int i = 0; i < k->cloth.n; i++) {
        dr_tri_field_destroy(&k->cloth.panels[i].field);
        free(k->cloth.panels[i].dof);
    }
    free(k->cloth.panels);
    free(k->mpm.x), free(k->mpm.v), free(k->mpm.mass), free(k->mpm.volume), free(k->mpm.dv);
    free(k->liquid);
    for (int i = 0; i < k->ncolliders; i++) dr_collider_destroy(&k->colliders[i].collider);
    free(k->colliders);
    free(k->live);
    free(k->posed);
    free(k);
    *kp = NULL;
}

double world_kinematics_dx(const WorldKinematics *k) { return k->dx; }

int world_kinematics_collider_count(const WorldKinematics *k) { return k->ncolliders; }

const DrCollider *world_kinematics_collider(const WorldKinematics *k, int i, const DrElement **element)
{
    *element = k->colliders[i].element;
    return k->colliders[i].collider;
}

int world_kinematics_colliders(const WorldKinematics *k, const DrCollider *const **out)
{
    *out = k->live;
    return k->nlive;
}

int world_kinematics_liquid_colliders(const WorldKinematics *k, const DrCollider *const **out)
{
    *out = k->liquid;
    return k->nliquid;
}

WorldPosedCollider *world_kinematics_posed(WorldKinematics *k) { return k->posed; }

void world_kinematics_pose(WorldKinematics *k, double t)
{
    for (int i = 0; i < k->nlive; i++)
        if (k->posed[i].moving) k->posed[i].frame = dr_collider_frame(k->posed[i].collider, t);
    for (int i = 0; i < k->nbodies; i++) k->body_posed[i].frame = dr_collider_frame(k->body_posed[i].collider, t);
}

bool world_kinematics_carry(const WorldKinematics *k, const DrElement *target, double t, DrXform *out)
{
    for (int i = 0; i < k->ncolliders; i++)
        if (k->colliders[i].element == target && k->colliders[i].collider) {
            *out = dr_collider_pose(k->colliders[i].collider, t);
            return true;
        }
    for (int i = 0; i < k->nbodies; i++)
        if (k->bodies[i].element == target) {
            const WorldBodyCollider *bc = &k->bodies[i];
            DrXform P = dr_collider_pose(bc->collider, t);
            DrMat3 R = dr_m3_mul(P.R, dr_m3_transpose(bc->start0.R));
            *out = (DrXform){R, dr_v3_sub(P.t, dr_m3_apply(R, bc->start0.t))};
            return true;
        }
    return false;
}

int world_kinematics_bodies_posed(WorldKinematics *k, WorldPosedCollider **out)
{
    *out = k->body_posed;
    return k->nbodies;
}

DrStatus world_kinematics_write(const WorldKinematics *k, DrH5 *h, double t, DrError *err)
{
    for (int i = 0; i < k->ncolliders; i++) {
        const WorldCollider *wc = &k->colliders[i];
        if (!wc->collider) continue;
        DrXform X = dr_collider_pose(wc->collider, t);
        char path[512];
        PATHF(path, "/%s/rotation", wc->element->name);
        uint64_t d33[2] = {3, 3}, d3[1] = {3};
        DR_TRY(dr_h5_write_f64(h, path, 2, d33, &X.R.m[0][0], "1", false, err));
        PATHF(path, "/%s/translation", wc->element->name);
        double tr[3] = {X.t.x, X.t.y, X.t.z};
        DR_TRY(dr_h5_write_f64(h, path, 1, d3, tr, "m", false, err));
        PATHF(path, "/%s", wc->element->name);
        DR_TRY(dr_h5_attr_str(h, path, "type", "collider", err));
    }
    return DR_OK;
}

/* ---- the MPM particles as a surface ---------------------------------------------------------------------------- */

bool world_kinematics_wants_mpm_surface(const WorldKinematics *k) { return k->mpm_surface != NULL; }

DrStatus world_kinematics_set_mpm_surface(WorldKinematics *k, long n, const double *x, const double *v,
                                          const double *volume, DrError *err)
{
    if (!k->mpm_surface) return DR_OK;
    return dr_error_prefix(dr_point_field_build(k->mpm_surface, n, x, v, volume, err), err, "the MPM solids as a "
                           "surface for the hair");
}

static double mpm_surface_sdf(DrVec3 x, DrVec3 *normal, void *ctx) { return dr_point_field_phi(ctx, x, normal); }
static DrVec3 mpm_surface_velocity(DrVec3 x, void *ctx) { return dr_point_field_velocity(ctx, x); }

bool world_kinematics_mpm_surface(WorldKinematics *k, double (**sdf)(DrVec3, DrVec3 *, void *),
                                  DrVec3 (**velocity)(DrVec3, void *), void **ctx)
{
    *sdf = mpm_surface_sdf;
    *velocity = mpm_surface_velocity;
    *ctx = k->mpm_surface;
    return k->mpm_surface != NULL;
}

/* ---- the MPM solids two-way with the first liquid ---- */

void world_kinematics_mpm_couple(WorldKinematics *k) { k->mpm.on = true; }

bool world_kinematics_mpm_coupled(const WorldKinematics *k) { return k->mpm.on; }

DrStatus world_kinematics_set_mpm_particles(WorldKinematics *k, long n, const double *x, const double *v,
                                            const double *mass, const double *vol0, const double *F, DrError *err)
{
    WorldMpmParticles *m = &k->mpm;
    if (!m->on) return DR_OK;
    if (n > m->cap) {
        DR_TRY(dr_realloc((size_t)(3 * n), sizeof(double), &m->x, err));
        DR_TRY(dr_realloc((size_t)(3 * n), sizeof(double), &m->v, err));
        DR_TRY(dr_realloc((size_t)(3 * n), sizeof(double), &m->dv, err));
        DR_TRY(dr_realloc((size_t)n, sizeof(double), &m->mass, err));
        DR_TRY(dr_realloc((size_t)n, sizeof(double), &m->volume, err));
        m->cap = n;
    }
    m->n = n;
    memcpy(m->x, x, 3 * (size_t)n * sizeof(double));
    memcpy(m->v, v, 3 * (size_t)n * sizeof(double));
    memcpy(m->mass, mass, (size_t)n * sizeof(double));
    for (long p = 0; p < n; p++) m->volume[p] = vol0[p] * fabs(dr_m3a_det(F + 9 * p)); /* V₀ det F */
    m->pending = false;
    return DR_OK;
}

WorldMpmParticles *world_kinematics_mpm_particles(WorldKinematics *k) { return k->mpm.on ? &k->mpm : NULL; }

WorldWetLink *world_kinematics_wet(WorldKinematics *k) { return &k->wet; }
WorldClothLink *world_kinematics_cloth_link(WorldKinematics *k) { return &k->cloth; }
