/* The MPM adapter: the one DrMpm that every mpm_solid element of a scene shares (one grid, so the bodies collide
 * through it), the scene colliders as grid boundary conditions (posed by the kinematics), its steps on the world's
 * clock, and the bodies' datasets in frame caches and checkpoints. */
#include "world_adapter.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mpm/mpm.h"
#include "stage/stage.h"

/* One mpm_solid element: a body of the shared DrMpm. */
typedef struct WorldMpmBody {
    const DrElement *element;
    int body;                /* DrMpm body id */
    long count;              /* its particles */
} WorldMpmBody;

typedef struct WorldMpm {
    DrMpm *mpm;
    WorldMpmBody *bodies;
    int nbodies;
    int max_substeps;
    /* the frame being advanced: dr_mpm_advance's substepping on the world's clock */
    int done;                /* substeps taken */
    double left;             /* s, to the frame's end */
    double from, dt;         /* the substep proposed from t = from */
    bool last;               /* and whether it ends the frame */
    DrMpmStats frame;        /* summed over the frame's substeps */
    DrStatus worst;          /* DR_WARN_NOT_CONVERGED when a Newton iteration of the frame stopped at its cap */
    DrMpmStats last_frame;   /* the last frame's stats */
    int not_converged;       /* 1 when a Newton iteration of the last frame stopped at its cap */
    /* the stability watch: the energy of all bodies together (they exchange it through the grid) */
    WorldWatch watch;
    double *body_energy;     /* per body, at the start of the frame: the alarm names the body that gained most */
    DrVec3 lo, hi;           /* the grid box: the lowest point the bodies reach along gravity is one of its corners */
    double dx;
    DrVec3 gravity;
    bool liquid;             /* two-way with the first liquid (Integrator.liquid_coupling, a liquid present) */
    double liquid_work;      /* J, the frame's work of the liquid's forces on the particles (the stability watch) */
} WorldMpm;

/* The particles as the liquid takes them (world_kinematics_set_mpm_particles; a no-op when not two-way). */
static DrStatus publish(const WorldMpm *m, const WorldCtx *c, DrError *err)
{
    if (!m->liquid) return DR_OK;
    DrMpmState st = dr_mpm_state(m->mpm);
    return world_kinematics_set_mpm_particles(c->kin, st.n, st.x, st.v, st.mass, st.vol0, st.F, err);
}

/* ---- shapes ------------------------------------------------------------------------------------------ */

typedef enum ShapeKind { SHAPE_BOX, SHAPE_SPHERE, SHAPE_MESH } ShapeKind;

/* An MpmShape placed by the element's Transform: world = R·(scale·local) + t. */
typedef struct Shape {
    ShapeKind kind;
    DrXform X;
    double scale;
    DrVec3 lo, hi;        /* box, local */
    DrVec3 centre;        /* sphere, local */
    double radius;
    DrCollider *sdf;      /* mesh: SDF of the posed mesh (world frame) */
} Shape;

/* Called by dr_mpm_sample_body for lattice points, possibly from several threads: reads only. */
static bool shape_inside(DrVec3 x, void *ctx)
{
    const Shape *s = ctx;
    if (s->kind == SHAPE_MESH) return dr_collider_phi(s->sdf, 0.0, x, NULL) < 0.0;
    DrVec3 p = dr_v3_scale(dr_xform_apply_inverse(s->X, x), 1.0 / s->scale);
    if (s->kind == SHAPE_SPHERE) return dr_v3_norm(dr_v3_sub(p, s->centre)) < s->radius;
    return p.x >= s->lo.x && p.x <= s->hi.x && p.y >= s->lo.y && p.y <= s->hi.y && p.z >= s->lo.z && p.z <= s->hi.z;
}

static DrVec3 shape_to_world(const Shape *s, DrVec3 local) { return dr_xform_apply(s->X, dr_v3_scale(local, s->scale)); }

/* Volume centroid of a closed mesh (sum over the tetrahedra from the origin to each triangle), or the
   centre of its bounds when it encloses no volume. */
static DrVec3 mesh_centroid(const DrTriMesh *m, DrVec3 lo, DrVec3 hi)
{
    double vol = 0.0;
    DrVec3 acc = dr_v3(0, 0, 0);
    for (int t = 0; t < m->nt; t++) {
        const double *a = m->v + 3 * m->tri[3 * t], *b = m->v + 3 * m->tri[3 * t + 1], *c = m->v + 3 * m->tri[3 * t + 2];
        DrVec3 A = dr_v3(a[0], a[1], a[2]), B = dr_v3(b[0], b[1], b[2]), C = dr_v3(c[0], c[1], c[2]);
        double v = dr_v3_dot(A, dr_v3_cross(B, C)) / 6.0;
        vol += v;
        acc = dr_v3_add(acc, dr_v3_scale(dr_v3_add(dr_v3_add(A, B), C), v / 4.0));
    }
    if (vol == 0.0) return dr_v3_scale(dr_v3_add(lo, hi), 0.5);
    return dr_v3_scale(acc, 1.0 / vol);
}

static DrStatus load_mesh_shape(const DrElement *e, const char *path, double spacing, Shape *sh, DrVec3 *lo,
                                DrVec3 *hi, DrVec3 *centre, DrError *err)
{
    DrTriMesh mesh = {0};
    DR_TRY(dr_stage_load_posed_mesh(e, path, "MpmShape.mesh", &mesh, err));
    DrStatus s = DR_OK;
    if (!dr_trimesh_is_closed(&mesh))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "%s.MpmShape.mesh: the mesh is not closed (some edge is not shared by exactly two oppositely "
                         "oriented triangles), so the body has no well-defined inside; close the mesh, or give the "
                         "shape as \"box\" or \"centre\" and \"radius\"",
                         e->name);
    if (s == DR_OK) {
        dr_trimesh_bounds(&mesh, lo, hi);
        *centre = mesh_centroid(&mesh, *lo, *hi);
        /* half the particle spacing: the inside test resolves the surface finer than the lattice samples it */
        s = dr_error_prefix(world_make_collider(&mesh, 0.5 * spacing, 0, false, 0, 0, NULL, &sh->sdf, err), err,
                            "%s.MpmShape.mesh", e->name);
    }
    dr_trimesh_free(&mesh);
    return s;
}

static void fmt_v3(DrVec3 v, char *buf, size_t size) { snprintf(buf, size, "[%.6g, %.6g, %.6g]", v.x, v.y, v.z); }

/* Samples element e's MpmShape into the solver as one body. */
static DrStatus add_body(const WorldCtx *c, WorldMpm *m, const DrElement *e, double dx, WorldMpmBody *wb, DrError *err)
{
    const DrComponent *shape = dr_element_component(e, "MpmShape");
    const DrComponent *mat = dr_element_component(e, "MpmMaterial");
    const DrComponent *iv = dr_element_component(e, "InitialVelocity");
    wb->element = e;
    int per_axis = dr_component_int(shape, "particles_per_axis");
    double spacing = dx / per_axis;
    Shape sh = {0};
    sh.X = dr_stage_element_transform(e, &sh.scale);
    DrVec3 lo, hi, centre;
    if (dr_component_is_set(shape, "box")) {
        sh.kind = SHAPE_BOX;
        dr_component_box(shape, "box", &sh.lo, &sh.hi);
        lo = dr_v3(INFINITY, INFINITY, INFINITY);
        hi = dr_v3(-INFINITY, -INFINITY, -INFINITY);
        for (int c = 0; c < 8; c++) {
            DrVec3 p = shape_to_world(&sh, dr_v3(c & 1 ? sh.hi.x : sh.lo.x, c & 2 ? sh.hi.y : sh.lo.y,
                                                 c & 4 ? sh.hi.z : sh.lo.z));
            lo = dr_v3_min(lo, p);
            hi = dr_v3_max(hi, p);
        }
        centre = shape_to_world(&sh, dr_v3_scale(dr_v3_add(sh.lo, sh.hi), 0.5));
    } else if (dr_component_is_set(shape, "centre")) {
        sh.kind = SHAPE_SPHERE;
        sh.centre = dr_component_vec3(shape, "centre");
        sh.radius = dr_component_num(shape, "radius");
        centre = shape_to_world(&sh, sh.centre);
        double r = sh.radius * sh.scale;
        lo = dr_v3_sub(centre, dr_v3(r, r, r));
        hi = dr_v3_add(centre, dr_v3(r, r, r));
    } else {
        sh.kind = SHAPE_MESH; /* the scene parser guarantees exactly one shape */
        DR_TRY(load_mesh_shape(e, dr_component_str(shape, "mesh"), spacing, &sh, &lo, &hi, &centre, err));
    }

    DrVec3 dlo, dhi;
    dr_component_box(dr_element_component(e, "Domain"), "box", &dlo, &dhi);
    DrStatus s = DR_OK;
    if (lo.x < dlo.x || lo.y < dlo.y || lo.z < dlo.z || hi.x > dhi.x || hi.y > dhi.y || hi.z > dhi.z) {
        char a[96], b[96], cl[96], d[96];
        fmt_v3(lo, a, sizeof a);
        fmt_v3(hi, b, sizeof b);
        fmt_v3(dlo, cl, sizeof cl);
        fmt_v3(dhi, d, sizeof d);
        s = dr_error_set(err, DR_ERR_INPUT, dr_scene_path(c->scene), 0, 0,
                         "%s.MpmShape: the body spans %s to %s, outside %s.Domain.box [%s, %s]; move the shape (or its "
                         "Transform) into the domain or enlarge the Domain box",
                         e->name, a, b, e->name, cl, d);
    }
    DrMpmMaterial mm = {
        .model = strcmp(dr_component_str(mat, "model"), "neo_hookean") == 0 ? DR_MPM_NEOHOOKEAN : DR_MPM_FIXED_COROTATED,
        .density = dr_component_num(mat, "density"),
        .youngs = dr_component_num(mat, "youngs_modulus"),
        .poisson = dr_component_num(mat, "poisson"),
    };
    DrVec3 v0 = dr_component_vec3(iv, "velocity");
    DrVec3 omega = dr_v3_scale(dr_component_vec3(iv, "angular_velocity"), DR_PI / 180.0);
    if (s == DR_OK)
        s = dr_mpm_sample_body(m->mpm, shape_inside, &sh, lo, hi, per_axis, v0, omega, centre, &mm, &wb->body,
                               &wb->count, err);
    if (s < 0 && err->file[0] == '\0') {
        char msg[sizeof err->message];
        snprintf(msg, sizeof msg, "%s", err->message);
        dr_error_set(err, s, dr_scene_path(c->scene), 0, 0, "%s.MpmShape: %s", e->name, msg);
    }
    if (s == DR_OK && wb->count == 0)
        s = dr_error_set(err, DR_ERR_INPUT, dr_scene_path(c->scene), 0, 0,
                         "%s.MpmShape: no particle lies inside the shape (it is thinner than the particle spacing "
                         "%.3g m = Domain.voxel_size / particles_per_axis); enlarge the shape, raise "
                         "MpmShape.particles_per_axis or lower Domain.voxel_size",
                         e->name, spacing);
    dr_collider_destroy(&sh.sdf);
    return s;
}

/* ---- the solver ---------------------------------------------------------------------------------------- */

static DrMpmIntegrator integrator_of(const char *s)
{
    if (strcmp(s, "symplectic_euler") == 0) return DR_MPM_SYMPLECTIC_EULER;
    if (strcmp(s, "backward_euler") == 0) return DR_MPM_BACKWARD_EULER;
    return DR_MPM_MIDPOINT;
}

static DrTransferScheme scheme_of(const char *s)
{
    if (strcmp(s, "flip") == 0) return DR_TRANSFER_FLIP;
    if (strcmp(s, "pic") == 0) return DR_TRANSFER_PIC;
    if (strcmp(s, "rpic") == 0) return DR_TRANSFER_RPIC;
    return DR_TRANSFER_APIC;
}

static DrKernel kernel_of(const char *s)
{
    if (strcmp(s, "linear") == 0) return DR_KERNEL_LINEAR;
    if (strcmp(s, "cubic") == 0) return DR_KERNEL_CUBIC;
    return DR_KERNEL_QUADRATIC;
}

static void mpm_destroy(void *self)
{
    WorldMpm *m = self;
    if (!m) return;
    dr_mpm_destroy(&m->mpm);
    free(m->bodies);
    free(m->body_energy);
    free(m);
}

/* ---- the stability watch ------------------------------------------------------------------------------------- */

/* The bodies' energy now (kinetic, elastic, gravitational potential; the work of the frame is added by the caller)
   and what of it could turn into motion: the potential above the grid box's lowest corner along gravity. The floor
   is a thousandth of the weight of the bodies lifted by a cell: round-off of bodies at rest. */
static WorldEnergy mpm_energy(const WorldMpm *m)
{
    DrVec3 gravity = m->gravity;
    DrMpmTotals t = dr_mpm_totals(m->mpm, -1);
    DrMpmState st = dr_mpm_state(m->mpm);
    double mass = 0.0;
    for (long p = 0; p < st.n; p++) mass += st.mass[p];
    double low = INFINITY; /* min over the box corners of −g·x: the least potential per kilogram */
    for (int k = 0; k < 8; k++) {
        DrVec3 x = dr_v3(k & 1 ? m->hi.x : m->lo.x, k & 2 ? m->hi.y : m->lo.y, k & 4 ? m->hi.z : m->lo.z);
        low = fmin(low, -dr_v3_dot(gravity, x));
    }
    WorldEnergy e = {0};
    e.energy = t.kinetic + t.elastic + t.gravity_potential;
    e.available = fmax(0.0, e.energy - mass * low);
    e.floor = 1e-12 + 1e-3 * mass * dr_v3_norm(gravity) * m->dx;
    return e;
}

/* The state after building or restoring is the start of `frame`. */
static void watch_start(WorldMpm *m, int frame)
{
    WorldEnergy e = mpm_energy(m);
    world_watch_start(&m->watch, frame, &e);
    for (int b = 0; b < m->nbodies; b++) {
        DrMpmTotals t = dr_mpm_totals(m->mpm, m->bodies[b].body);
        m->body_energy[b] = t.kinetic + t.elastic + t.gravity_potential;
    }
}

/* End of a frame: the check, naming the body whose energy grew most. */
static DrStatus watch_frame(WorldMpm *m, const WorldCtx *c, DrError *err)
{
    WorldEnergy e = mpm_energy(m);
    e.work = m->frame.collider_work + m->liquid_work;
    m->liquid_work = 0.0;
    int worst = 0;
    double most = -INFINITY;
    for (int b = 0; b < m->nbodies; b++) {
        DrMpmTotals t = dr_mpm_totals(m->mpm, m->bodies[b].body);
        double E = t.kinetic + t.elastic + t.gravity_potential;
        if (E - m->body_energy[b] > most) most = E - m->body_energy[b], worst = b;
        m->body_energy[b] = E;
    }
    char who[300];
    snprintf(who, sizeof who, "mpm_solid '%s'%s", m->bodies[worst].element->name,
             m->nbodies > 1 ? " (the body that gained most; the MPM solids exchange energy on their grid)" : "");
    const char *fix = m->frame.substeps >= m->max_substeps
                          ? "the frame took all solver.max_substeps substeps, so they were longer than the solver's "
                            "stable step: raise solver.max_substeps"
                          : "lower solver.cfl (smaller MPM substeps), or use Integrator.type backward_euler, which damps";
    return world_watch_energy(&m->watch, c, &e, who, fix, err);
}

static DrStatus build_mpm(const WorldCtx *c, WorldMpm *m, int n, DrError *err)
{
    const DrScene *scene = c->scene;
    DR_TRY(dr_calloc((size_t)n, sizeof *m->bodies, &m->bodies, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *m->body_energy, &m->body_energy, err));

    /* The scene parser made every mpm_solid agree on Domain.voxel_size and wall_boundary, Transfer and
       Integrator, so the first element speaks for all; the grid box is the union of the Domain boxes. */
    const DrElement *first = NULL;
    DrVec3 lo = dr_v3(INFINITY, INFINITY, INFINITY), hi = dr_v3(-INFINITY, -INFINITY, -INFINITY);
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_MPM_SOLID) continue;
        if (!first) first = e;
        DrVec3 a, b;
        dr_component_box(dr_element_component(e, "Domain"), "box", &a, &b);
        lo = dr_v3_min(lo, a);
        hi = dr_v3_max(hi, b);
    }
    const DrComponent *dom = dr_element_component(first, "Domain");
    const DrComponent *tr = dr_element_component(first, "Transfer");
    const DrComponent *in = dr_element_component(first, "Integrator");
    const DrComponent *solver = dr_scene_section(scene, "solver");
    DrMpmDesc d;
    dr_mpm_desc_default(&d);
    d.dim = 3;
    d.lo = lo;
    d.hi = hi;
    d.dx = dr_component_num(dom, "voxel_size");
    d.kernel = kernel_of(dr_component_str(tr, "kernel"));
    d.scheme = scheme_of(dr_component_str(tr, "scheme"));
    /* the scene gives the FLIP fraction of the blend; the solver takes the PIC fraction */
    d.flip_blend = 1.0 - dr_component_num(tr, "flip_blend");
    d.integrator = integrator_of(dr_component_str(in, "type"));
    d.f_update_order = dr_component_int(in, "f_update_order");
    d.newton_tolerance = dr_component_num(in, "newton_tolerance");
    d.newton_max_iterations = dr_component_int(in, "newton_max_iterations");
    d.cg_tolerance = dr_component_num(in, "cg_tolerance");
    d.cg_max_iterations = dr_component_int(in, "cg_max_iterations");
    d.gravity = c->gravity;
    DrMpmWall wall = strcmp(dr_component_str(dom, "wall_boundary"), "no_slip") == 0 ? DR_MPM_WALL_NO_SLIP : DR_MPM_WALL_SLIP;
    for (int f = 0; f < 6; f++) d.wall[f] = wall;
    d.cfl = dr_component_num(solver, "cfl");
    m->max_substeps = dr_component_int(solver, "max_substeps");
    m->lo = lo, m->hi = hi, m->dx = d.dx, m->gravity = d.gravity;
    /* a frame must hold the substeps of a body starting to fall: Δt(S + |g|Δt) = νΔx with S = 0 (mpm.h) */
    if (dr_v3_norm(d.gravity) > 0.0)
        DR_TRY(world_watch_frame_length(c, "the MPM solids", sqrt(d.cfl * d.dx / dr_v3_norm(d.gravity)),
                                        "their stable step as a body starts to fall, sqrt(cfl*dx/|g|)", err));
    world_watch_init(&m->watch, scene);
    DR_TRY(dr_mpm_create(&d, &m->mpm, err));

    /* the scene colliders, posed by the kinematics at every clock step's end; their surface velocity (keyframed
       motion) goes into the contacts */
    const DrCollider *const *live = NULL;
    int nlive = world_kinematics_colliders(c->kin, &live);
    WorldPosedCollider *posed = world_kinematics_posed(c->kin);
    for (int i = 0; i < nlive; i++) {
        DrMpmCollider desc = {world_posed_sdf, &posed[i], dr_v3(0, 0, 0), dr_collider_friction(live[i]),
                              dr_collider_no_slip(live[i]), world_posed_velocity};
        DR_TRY(dr_mpm_add_collider(m->mpm, &desc, err));
    }

    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_MPM_SOLID) continue;
        DR_TRY(add_body(c, m, e, d.dx, &m->bodies[m->nbodies++], err));
    }
    m->liquid = dr_scene_count_kind(scene, DR_ELEMENT_LIQUID) > 0 &&
                strcmp(dr_component_str(in, "liquid_coupling"), "two_way") == 0;
    if (m->liquid) world_kinematics_mpm_couple(c->kin);
    DR_TRY(publish(m, c, err));
    watch_start(m, c->frame);
    return DR_OK;
}

static DrStatus step_failed(DrStatus s, int frame, DrError *err)
{
    char msg[sizeof err->message];
    snprintf(msg, sizeof msg, "%s", err->message);
    return dr_error_set(err, s, err->file[0] ? err->file : NULL, err->line, err->col,
                        "MPM solids, frame %d: %s; lower solver.cfl, raise solver.max_substeps or use Integrator.type "
                        "midpoint",
                        frame, msg);
}

/* ---- the clock ----------------------------------------------------------------------------------------------
 * dr_mpm_advance's substepping (each substep the solver's stable step dr_mpm_stable_dt, evened out over what is left
 * of the frame, at most max_substeps), one proposal at a time: when the clock takes the proposed substep, what is
 * left shrinks by it as in dr_mpm_advance (the same bits); when another solver's step ends first, the substep is
 * cut there and what is left is counted from there. */

static void mpm_begin_frame(void *self, const WorldCtx *c)
{
    WorldMpm *m = self;
    m->done = 0;
    m->left = c->t1 - c->t0;
    m->from = c->t0;
    m->worst = DR_OK;
    m->liquid_work = 0.0;
    memset(&m->frame, 0, sizeof m->frame);
}

static DrStatus mpm_next_time(void *self, const WorldCtx *c, double t, double *t_next, DrError *err)
{
    (void)err;
    WorldMpm *m = self;
    if (t != m->from) m->left = c->t1 - t; /* a step of the clock ended before this solver's proposal */
    m->from = t;
    double lim = dr_mpm_stable_dt(m->mpm);
    double need = isfinite(lim) ? ceil(m->left / lim - 1e-9) : 1.0;
    int budget = m->max_substeps - m->done;
    if (budget < 1) budget = 1;
    double k = need < 1.0 ? 1.0 : (need > budget ? budget : need);
    m->last = k <= 1.0;
    m->dt = m->last ? m->left : m->left / k;
    *t_next = m->last ? c->t1 : t + m->dt;
    return DR_OK;
}

static DrStatus mpm_step(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    WorldMpm *m = self;
    assert(t == m->from);
    double proposed_end = m->last ? c->t1 : t + m->dt;
    bool as_proposed = t_next == proposed_end;
    double dt = as_proposed ? m->dt : t_next - t;
    /* the liquid's substep over this clock step came first: its pressure's impulse m_p dv_p acts as a force over this
       step, within the step's solve (its contacts see it with gravity: an impulse added to the velocities before the
       step made a body resting on a collider creep up, the contact letting the lift through and taking the weight) */
    WorldMpmParticles *lp = m->liquid ? world_kinematics_mpm_particles(c->kin) : NULL;
    DrMpmStats st;
    DrStatus s;
    if (lp && lp->pending) {
        for (long p = 0; p < lp->n; p++)
            for (int a = 0; a < 3; a++) lp->dv[3 * p + a] *= lp->mass[p] / dt; /* now the force, N */
        lp->pending = false;
        memset(&st, 0, sizeof st);
        s = dr_mpm_predict(m->mpm, dt, err);
        if (s >= 0) s = dr_mpm_solve(m->mpm, lp->dv, NULL, &st, err);
        if (s >= 0) {
            DrStatus cs = dr_mpm_commit(m->mpm, err);
            if (cs < 0) s = cs;
        }
        st.substeps = 1;
        if (s >= 0) { /* the force's work over the step, at the mean of the velocities before (published) and after */
            DrMpmState ms = dr_mpm_state(m->mpm);
            double w = 0.0;
            for (long i = 0; i < 3 * ms.n; i++) w += lp->dv[i] * 0.5 * (lp->v[i] + ms.v[i]) * dt;
            m->liquid_work += w;
        }
    } else {
        s = dr_mpm_step(m->mpm, dt, &st, err);
    }
    m->frame.newton_iterations += st.newton_iterations;
    m->frame.cg_iterations += st.cg_iterations;
    m->frame.newton_residual = st.newton_residual;
    m->frame.seconds_transfer += st.seconds_transfer;
    m->frame.seconds_solve += st.seconds_solve;
    m->frame.collider_work += st.collider_work;
    m->frame.substeps++;
    m->done++;
    if (s < 0) return step_failed(s, c->frame, err);
    if (s > m->worst) m->worst = s;
    if (as_proposed) m->left = m->last ? 0.0 : m->left - dt;
    else m->left = c->t1 - t_next;
    m->from = t_next;
    DR_TRY(publish(m, c, err));
    if (!world_kinematics_wants_mpm_surface(c->kin)) return DR_OK;
    DrMpmState sm = dr_mpm_state(m->mpm); /* the hair meets the particles where this step left them */
    return world_kinematics_set_mpm_surface(c->kin, sm.n, sm.x, sm.v, sm.vol0, err);
}

static DrStatus mpm_end_frame(void *self, const WorldCtx *c, DrFrameStats *stats, DrError *err)
{
    WorldMpm *m = self;
    int frame = c->frame;
    int not_converged = m->worst == DR_WARN_NOT_CONVERGED;
    int k = m->frame.substeps;
    if (k >= m->max_substeps)
        dr_log_warn("frame %d: the MPM solids took all solver.max_substeps = %d substeps; if the time step limit "
                    "asked for more, the substeps are longer than it allows (raise solver.max_substeps)",
                    frame, m->max_substeps);
    if (not_converged)
        dr_log_warn("frame %d: a Newton iteration of the MPM solids stopped at Integrator.newton_max_iterations (last "
                    "relative residual %.3g); the steps are kept", frame, m->frame.newton_residual);
    m->last_frame = m->frame;
    m->not_converged = not_converged;

    DrMpmState st = dr_mpm_state(m->mpm);
    for (long i = 0; i < 3 * st.n; i++)
        if (!isfinite(st.x[i]) || !isfinite(st.v[i]))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "MPM solids became non-finite in frame %d; lower solver.cfl or raise solver.max_substeps",
                                frame);
    DrMpmTotals tot = dr_mpm_totals(m->mpm, -1);
    DrMpmFrameStats *b = &stats->mpm;
    b->present = true;
    b->particles = st.n;
    b->substeps = k;
    b->newton_iterations = m->frame.newton_iterations;
    b->cg_iterations = m->frame.cg_iterations;
    b->newton_residual = m->frame.newton_residual;
    b->not_converged = not_converged;
    b->kinetic_energy = tot.kinetic;
    b->elastic_energy = tot.elastic;
    b->gravity_energy = tot.gravity_potential;
    b->momentum = tot.momentum;
    b->angular_momentum = tot.angular;
    b->seconds_transfer = m->frame.seconds_transfer;
    b->seconds_solve = m->frame.seconds_solve;
    return watch_frame(m, c, err);
}

/* ---- frame caches and checkpoints ------------------------------------------------------------------------ */

typedef struct BodyArrays { double *x, *v, *C, *F, *vol; } BodyArrays;

static void body_arrays_free(BodyArrays *a)
{
    free(a->x);
    free(a->v);
    free(a->C);
    free(a->F);
    free(a->vol);
    memset(a, 0, sizeof *a);
}

static DrStatus body_arrays_alloc(long n, BodyArrays *a, DrError *err)
{
    size_t k = (size_t)n + 1;
    DR_TRY(dr_calloc(3 * k, sizeof(double), &a->x, err));
    DR_TRY(dr_calloc(3 * k, sizeof(double), &a->v, err));
    DR_TRY(dr_calloc(9 * k, sizeof(double), &a->C, err));
    DR_TRY(dr_calloc(9 * k, sizeof(double), &a->F, err));
    return dr_calloc(k, sizeof(double), &a->vol, err);
}

/* The particles of one body, in solver order (the order mpm_read puts them back in). */
static void gather_body(const DrMpmState *st, int body, BodyArrays *a)
{
    long j = 0;
    for (long p = 0; p < st->n; p++) {
        if (st->body[p] != body) continue;
        memcpy(a->x + 3 * j, st->x + 3 * p, 3 * sizeof(double));
        memcpy(a->v + 3 * j, st->v + 3 * p, 3 * sizeof(double));
        memcpy(a->C + 9 * j, st->C + 9 * p, 9 * sizeof(double));
        memcpy(a->F + 9 * j, st->F + 9 * p, 9 * sizeof(double));
        a->vol[j] = st->vol0[p];
        j++;
    }
}

static DrStatus write_body(DrH5 *h, const WorldMpmBody *wb, const BodyArrays *a, bool frame_cache, DrError *err)
{
    char path[512];
    const char *name = wb->element->name;
    uint64_t n = (uint64_t)wb->count, d1[1] = {n}, d3[3] = {n, 3, 3};
    DR_TRY(dr_h5_write_particles(h, name, wb->count, a->x, a->v, a->C, frame_cache, err));
    PATHF(path, "/%s/deformation_gradient", name);
    DR_TRY(dr_h5_write_f64(h, path, 3, d3, a->F, "1", frame_cache, err));
    if (!frame_cache) return DR_OK; /* rest volumes come from the scene again on resume */
    PATHF(path, "/%s/volume", name);
    DR_TRY(dr_h5_write_f64(h, path, 1, d1, a->vol, "m^3", frame_cache, err));
    return DR_OK;
}

static DrStatus write_body_diagnostics(const WorldMpm *m, DrH5 *h, const DrMpmState *st, const WorldMpmBody *wb,
                                       DrError *err)
{
    char g[512];
    PATHF(g, "/diagnostics/%s", wb->element->name);
    DrMpmTotals t = dr_mpm_totals(m->mpm, wb->body);
    double mass = 0.0;
    DrVec3 mx = dr_v3(0, 0, 0);
    for (long p = 0; p < st->n; p++) {
        if (st->body[p] != wb->body) continue;
        mass += st->mass[p];
        mx = dr_v3_add(mx, dr_v3_scale(dr_v3(st->x[3 * p], st->x[3 * p + 1], st->x[3 * p + 2]), st->mass[p]));
    }
    DR_TRY(dr_h5_write_scalar(h, g, "particles", (double)wb->count, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mass", mass, "kg", err));
    DR_TRY(dr_h5_write_vec3(h, g, "centre_of_mass", dr_v3_scale(mx, mass > 0 ? 1.0 / mass : 0.0), "m", err));
    DR_TRY(dr_h5_write_scalar(h, g, "kinetic_energy", t.kinetic, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "elastic_energy", t.elastic, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "gravity_energy", t.gravity_potential, "J", err));
    DR_TRY(dr_h5_write_vec3(h, g, "linear_momentum", t.momentum, "kg*m/s", err));
    DR_TRY(dr_h5_write_vec3(h, g, "angular_momentum", t.angular, "kg*m^2/s", err));
    return DR_OK;
}

static DrStatus write_solver_diagnostics(const WorldMpm *m, DrH5 *h, DrError *err)
{
    const char *g = "/diagnostics";
    DrMpmTotals t = dr_mpm_totals(m->mpm, -1);
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_substeps", m->last_frame.substeps, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_newton_iterations", m->last_frame.newton_iterations, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_cg_iterations", m->last_frame.cg_iterations, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_newton_residual", m->last_frame.newton_residual, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_newton_not_converged", m->not_converged, "1", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_kinetic_energy", t.kinetic, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_elastic_energy", t.elastic, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_gravity_energy", t.gravity_potential, "J", err));
    DR_TRY(dr_h5_write_scalar(h, g, "mpm_total_energy", t.kinetic + t.elastic + t.gravity_potential, "J", err));
    DR_TRY(dr_h5_write_vec3(h, g, "mpm_linear_momentum", t.momentum, "kg*m/s", err));
    DR_TRY(dr_h5_write_vec3(h, g, "mpm_angular_momentum", t.angular, "kg*m^2/s", err));
    return DR_OK;
}

static DrStatus mpm_write(const void *self, const WorldCtx *c, DrH5 *h, bool frame_cache, DrError *err)
{
    (void)c;
    const WorldMpm *m = self;
    DrMpmState st = dr_mpm_state(m->mpm);
    long most = 0;
    for (int b = 0; b < m->nbodies; b++)
        if (m->bodies[b].count > most) most = m->bodies[b].count;
    BodyArrays a = {0};
    DrStatus s = body_arrays_alloc(most, &a, err);
    for (int b = 0; s == DR_OK && b < m->nbodies; b++) {
        const WorldMpmBody *wb = &m->bodies[b];
        gather_body(&st, wb->body, &a);
        s = write_body(h, wb, &a, frame_cache, err);
        if (s != DR_OK || !frame_cache) continue;
        char g[512];
        PATHF(g, "/%s", wb->element->name);
        const DrComponent *dom = dr_element_component(wb->element, "Domain");
        const DrComponent *shape = dr_element_component(wb->element, "MpmShape");
        s = dr_h5_attr_str(h, g, "type", "mpm_solid", err);
        if (s == DR_OK)
            s = dr_h5_attr_f64(h, g, "particle_spacing",
                               dr_component_num(dom, "voxel_size") / dr_component_int(shape, "particles_per_axis"), err);
        if (s == DR_OK) s = write_body_diagnostics(m, h, &st, wb, err);
    }
    body_arrays_free(&a);
    if (s == DR_OK && frame_cache) s = write_solver_diagnostics(m, h, err);
    return s;
}

/* Reads one dataset of a body: n rows of `cols` numbers. */
static DrStatus read_rows(DrH5 *h, const char *file, const char *name, const char *what, long n, int cols, double **out,
                          DrError *err)
{
    char path[512];
    PATHF(path, "/%s/%s", name, what);
    int rank;
    uint64_t dims[4];
    DR_TRY(dr_h5_read_f64(h, path, &rank, dims, out, err));
    uint64_t total = 1;
    for (int r = 0; r < rank; r++) total *= dims[r];
    if (rank < 1 || dims[0] != (uint64_t)n || total != (uint64_t)n * (uint64_t)cols) {
        free(*out);
        *out = NULL;
        return dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                            "checkpoint dataset %s does not hold the %ld particles of '%s' the scene makes; delete the "
                            "checkpoint and bake without --resume",
                            path, n, name);
    }
    return DR_OK;
}

static DrStatus mpm_read(void *self, const WorldCtx *c, DrH5 *h, const char *path, int frame, DrError *err)
{
    WorldMpm *m = self;
    DrMpmState st = dr_mpm_state(m->mpm);
    BodyArrays all = {0};
    DrStatus s = body_arrays_alloc(st.n, &all, err);
    for (int b = 0; s == DR_OK && b < m->nbodies; b++) {
        const WorldMpmBody *wb = &m->bodies[b];
        const char *name = wb->element->name;
        BodyArrays a = {0};
        s = read_rows(h, path, name, "position", wb->count, 3, &a.x, err);
        if (s == DR_OK) s = read_rows(h, path, name, "velocity", wb->count, 3, &a.v, err);
        if (s == DR_OK) s = read_rows(h, path, name, "affine", wb->count, 9, &a.C, err);
        if (s == DR_OK) s = read_rows(h, path, name, "deformation_gradient", wb->count, 9, &a.F, err);
        /* back into solver order: the body's particles in the order gather_body wrote them */
        long j = 0;
        for (long p = 0; s == DR_OK && p < st.n; p++) {
            if (st.body[p] != wb->body) continue;
            memcpy(all.x + 3 * p, a.x + 3 * j, 3 * sizeof(double));
            memcpy(all.v + 3 * p, a.v + 3 * j, 3 * sizeof(double));
            memcpy(all.C + 9 * p, a.C + 9 * j, 9 * sizeof(double));
            memcpy(all.F + 9 * p, a.F + 9 * j, 9 * sizeof(double));
            j++;
        }
        body_arrays_free(&a);
    }
    if (s == DR_OK) s = dr_mpm_restore(m->mpm, st.n, all.x, all.v, all.C, all.F, err);
    body_arrays_free(&all);
    if (s == DR_OK) watch_start(m, frame + 1);
    if (s == DR_OK) s = publish(m, c, err);
    return s;
}

static void mpm_hash(const void *self, DrHasher *h)
{
    const WorldMpm *m = self;
    DrMpmState st = dr_mpm_state(m->mpm);
    size_t n = (size_t)st.n;
    dr_hasher_update(h, &st.n, sizeof st.n);
    dr_hasher_update(h, st.x, 3 * sizeof(double) * n);
    dr_hasher_update(h, st.v, 3 * sizeof(double) * n);
    dr_hasher_update(h, st.C, 9 * sizeof(double) * n);
    dr_hasher_update(h, st.F, 9 * sizeof(double) * n);
}

DrStatus world_mpm_adapter(const WorldCtx *c, WorldSolver *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    int n = dr_scene_count_kind(c->scene, DR_ELEMENT_MPM_SOLID);
    if (n == 0) return DR_OK; /* nothing MPM is allocated */
    WorldMpm *m = NULL;
    DR_TRY(dr_calloc(1, sizeof *m, &m, err));
    DrStatus s = build_mpm(c, m, n, err);
    if (s < 0) {
        mpm_destroy(m);
        return s;
    }
    *out = (WorldSolver){.name = "mpm",
                         .self = m,
                         .begin_frame = mpm_begin_frame,
                         .next_time = mpm_next_time,
                         .step = mpm_step,
                         .end_frame = mpm_end_frame,
                         .write = mpm_write,
                         .read = mpm_read,
                         .hash = mpm_hash,
                         .destroy = mpm_destroy,
                         .lockstep = m->liquid};
    return DR_OK;
}

const DrMpm *world_mpm_solver(const WorldSolver *s) { return s->self ? ((const WorldMpm *)s->self)->mpm : NULL; }
long world_mpm_particles(const WorldSolver *s) { return s->self ? dr_mpm_state(((const WorldMpm *)s->self)->mpm).n : 0; }
int world_mpm_bodies(const WorldSolver *s) { return s->self ? ((const WorldMpm *)s->self)->nbodies : 0; }
