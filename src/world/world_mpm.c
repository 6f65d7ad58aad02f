/* MPM solids in the world: the one DrMpm that every mpm_solid element of a scene shares (one grid, so the
 * bodies collide through it), the scene colliders as grid boundary conditions, substepping a frame, and the
 * bodies' datasets in frame caches and checkpoints. */
#include "world_internal.h"

#include <stdlib.h>
#include <string.h>

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
    DR_TRY(dr_world_load_posed_mesh_(e, path, "MpmShape.mesh", &mesh, err));
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
        s = dr_world_asset_context_(dr_world_make_collider_(&mesh, 0.5 * spacing, 0, false, 0, 0, NULL, &sh->sdf, err),
                                    e->name, "MpmShape.mesh", err);
    }
    dr_trimesh_free(&mesh);
    return s;
}

static void fmt_v3(DrVec3 v, char *buf, size_t size) { snprintf(buf, size, "[%.6g, %.6g, %.6g]", v.x, v.y, v.z); }

/* Samples element e's MpmShape into the solver as one body. */
static DrStatus add_body(DrWorld *w, WorldMpm *m, const DrElement *e, double dx, WorldMpmBody *wb, DrError *err)
{
    const DrComponent *shape = dr_element_component(e, "MpmShape");
    const DrComponent *mat = dr_element_component(e, "MpmMaterial");
    const DrComponent *iv = dr_element_component(e, "InitialVelocity");
    wb->element = e;
    int per_axis = dr_component_int(shape, "particles_per_axis");
    double spacing = dx / per_axis;
    Shape sh = {0};
    sh.X = dr_world_transform_(e, &sh.scale);
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
        char a[96], b[96], c[96], d[96];
        fmt_v3(lo, a, sizeof a);
        fmt_v3(hi, b, sizeof b);
        fmt_v3(dlo, c, sizeof c);
        fmt_v3(dhi, d, sizeof d);
        s = dr_error_set(err, DR_ERR_INPUT, dr_scene_path(w->scene), 0, 0,
                         "%s.MpmShape: the body spans %s to %s, outside %s.Domain.box [%s, %s]; move the shape (or its "
                         "Transform) into the domain or enlarge the Domain box",
                         e->name, a, b, e->name, c, d);
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
        dr_error_set(err, s, dr_scene_path(w->scene), 0, 0, "%s.MpmShape: %s", e->name, msg);
    }
    if (s == DR_OK && wb->count == 0)
        s = dr_error_set(err, DR_ERR_INPUT, dr_scene_path(w->scene), 0, 0,
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

DrStatus dr_world_mpm_create_(DrWorld *w, DrError *err)
{
    const DrScene *scene = w->scene;
    int n = dr_scene_count_type(scene, "mpm_solid");
    if (n == 0) return DR_OK; /* nothing MPM is allocated */
    WorldMpm *m = NULL;
    DR_TRY(dr_calloc(1, sizeof *m, &m, err));
    w->mpm = m;
    DR_TRY(dr_calloc((size_t)n, sizeof *m->bodies, &m->bodies, err));
    DR_TRY(dr_calloc((size_t)w->ncolliders + 1, sizeof *m->colliders, &m->colliders, err));

    /* The scene parser made every mpm_solid agree on Domain.voxel_size and wall_boundary, Transfer and
       Integrator, so the first element speaks for all; the grid box is the union of the Domain boxes. */
    const DrElement *first = NULL;
    DrVec3 lo = dr_v3(INFINITY, INFINITY, INFINITY), hi = dr_v3(-INFINITY, -INFINITY, -INFINITY);
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (strcmp(e->type, "mpm_solid") != 0) continue;
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
    d.gravity = w->gravity;
    DrMpmWall wall = strcmp(dr_component_str(dom, "wall_boundary"), "no_slip") == 0 ? DR_MPM_WALL_NO_SLIP : DR_MPM_WALL_SLIP;
    for (int f = 0; f < 6; f++) d.wall[f] = wall;
    d.cfl = dr_component_num(solver, "cfl");
    m->max_substeps = dr_component_int(solver, "max_substeps");
    DR_TRY(dr_mpm_create(&d, &m->mpm, err));

    for (int i = 0; i < w->ncolliders; i++) {
        const WorldCollider *c = &w->colliders[i];
        if (!c->collider) continue;
        WorldPosedCollider *mc = &m->colliders[m->ncolliders++];
        const double *rows;
        mc->collider = c->collider;
        mc->frame = dr_collider_frame(c->collider, 0.0);
        mc->moving = dr_component_table(dr_element_component(c->element, "Motion"), "keys", &rows) > 0;
        m->any_moving |= mc->moving;
        /* posed at every substep; its surface velocity (keyframed motion) goes into the contacts */
        DrMpmCollider desc = {dr_world_posed_sdf_, mc, dr_v3(0, 0, 0), dr_collider_friction(c->collider),
                              dr_collider_no_slip(c->collider), dr_world_posed_velocity_};
        DR_TRY(dr_mpm_add_collider(m->mpm, &desc, err));
    }

    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (strcmp(e->type, "mpm_solid") != 0) continue;
        DR_TRY(add_body(w, m, e, d.dx, &m->bodies[m->nbodies++], err));
    }
    return DR_OK;
}

void dr_world_mpm_destroy_(WorldMpm **mp)
{
    if (!mp || !*mp) return;
    WorldMpm *m = *mp;
    dr_mpm_destroy(&m->mpm);
    free(m->bodies);
    free(m->colliders);
    free(m);
    *mp = NULL;
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

/* dr_mpm_advance's substepping (each substep the solver's stable step dr_mpm_stable_dt, evened out over what
   is left of the frame, at most max_substeps), taken here one dr_mpm_step at a time so that moving colliders
   are posed at each substep's midpoint. The same limit as dr_mpm_advance, so a moving collider the bodies
   never touch leaves the substeps as they are without it. */
static DrStatus advance_posing_colliders(WorldMpm *m, double duration, DrMpmStats *sum, DrError *err)
{
    memset(sum, 0, sizeof *sum);
    DrStatus worst = DR_OK;
    double left = duration, t = m->time;
    while (left > 0.0 && sum->substeps < m->max_substeps) {
        double lim = dr_mpm_stable_dt(m->mpm);
        double need = isfinite(lim) ? ceil(left / lim - 1e-9) : 1.0;
        int budget = m->max_substeps - sum->substeps;
        double k = need < 1.0 ? 1.0 : (need > budget ? budget : need);
        double dt = k <= 1.0 ? left : left / k;
        for (int c = 0; c < m->ncolliders; c++)
            if (m->colliders[c].moving) m->colliders[c].frame = dr_collider_frame(m->colliders[c].collider, t + 0.5 * dt);
        DrMpmStats st;
        DrStatus s = dr_mpm_step(m->mpm, dt, &st, err);
        sum->newton_iterations += st.newton_iterations;
        sum->cg_iterations += st.cg_iterations;
        sum->newton_residual = st.newton_residual;
        sum->seconds_transfer += st.seconds_transfer;
        sum->seconds_solve += st.seconds_solve;
        sum->substeps++;
        if (s < 0) return s;
        if (s > worst) worst = s;
        left = k <= 1.0 ? 0.0 : left - dt;
        t += dt;
    }
    return worst;
}

DrStatus dr_world_mpm_step_(DrWorld *w, double t0, double t1, DrFrameStats *stats, DrError *err)
{
    WorldMpm *m = w->mpm;
    if (!m) return DR_OK;
    int frame = w->frame + 1;
    m->time = t0;
    DrMpmStats sum = {0};
    DrStatus s = m->any_moving ? advance_posing_colliders(m, t1 - t0, &sum, err)
                               : dr_mpm_advance(m->mpm, t1 - t0, m->max_substeps, &sum, err);
    if (s < 0) return step_failed(s, frame, err);
    int not_converged = s == DR_WARN_NOT_CONVERGED;
    int k = sum.substeps;
    if (k >= m->max_substeps)
        dr_log_warn("frame %d: the MPM solids took all solver.max_substeps = %d substeps; if the time step limit "
                    "asked for more, the substeps are longer than it allows (raise solver.max_substeps)",
                    frame, m->max_substeps);
    if (not_converged)
        dr_log_warn("frame %d: a Newton iteration of the MPM solids stopped at Integrator.newton_max_iterations (last "
                    "relative residual %.3g); the steps are kept", frame, sum.newton_residual);
    m->last = sum;
    m->not_converged = not_converged;

    DrMpmState st = dr_mpm_state(m->mpm);
    for (long i = 0; i < 3 * st.n; i++)
        if (!isfinite(st.x[i]) || !isfinite(st.v[i]))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "MPM solids became non-finite in frame %d; lower solver.cfl or raise solver.max_substeps",
                                frame);
    DrMpmTotals tot = dr_mpm_totals(m->mpm, -1);
    stats->mpm = true;
    stats->mpm_particles = st.n;
    stats->mpm_substeps = k;
    if (k > stats->substeps) stats->substeps = k;
    stats->mpm_newton_iterations = sum.newton_iterations;
    stats->mpm_cg_iterations = sum.cg_iterations;
    stats->mpm_newton_residual = sum.newton_residual;
    stats->mpm_not_converged = not_converged;
    stats->mpm_kinetic_energy = tot.kinetic;
    stats->mpm_elastic_energy = tot.elastic;
    stats->mpm_gravity_energy = tot.gravity_potential;
    stats->mpm_momentum = tot.momentum;
    stats->mpm_angular_momentum = tot.angular;
    stats->kinetic_energy += tot.kinetic;
    stats->seconds_mpm_transfer = sum.seconds_transfer;
    stats->seconds_mpm_solve = sum.seconds_solve;
    return DR_OK;
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

/* The particles of one body, in solver order (the order dr_world_mpm_read_ puts them back in). */
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
    DR_TRY(dr_world_write_particles_(h, name, wb->count, a->x, a->v, a->C, frame_cache, err));
    PATHF(path, "/%s/deformation_gradient", name);
    DR_TRY(dr_h5_write_f64(h, path, 3, d3, a->F, "1", frame_cache, err));
    if (!frame_cache) return DR_OK; /* rest volumes come from the scene again on resume */
    PATHF(path, "/%s/volume", name);
    DR_TRY(dr_h5_write_f64(h, path, 1, d1, a->vol, "m^3", frame_cache, err));
    return DR_OK;
}

static DrStatus write_body_diagnostics(const DrWorld *w, DrH5 *h, const DrMpmState *st, const WorldMpmBody *wb,
                                       DrError *err)
{
    char g[512];
    PATHF(g, "/diagnostics/%s", wb->element->name);
    DrMpmTotals t = dr_mpm_totals(w->mpm->mpm, wb->body);
    double mass = 0.0;
    DrVec3 mx = dr_v3(0, 0, 0);
    for (long p = 0; p < st->n; p++) {
        if (st->body[p] != wb->body) continue;
        mass += st->mass[p];
        mx = dr_v3_add(mx, dr_v3_scale(dr_v3(st->x[3 * p], st->x[3 * p + 1], st->x[3 * p + 2]), st->mass[p]));
    }
    DR_TRY(dr_world_write_scalar_(h, g, "particles", (double)wb->count, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mass", mass, "kg", err));
    DR_TRY(dr_world_write_vec_(h, g, "centre_of_mass", dr_v3_scale(mx, mass > 0 ? 1.0 / mass : 0.0), "m", err));
    DR_TRY(dr_world_write_scalar_(h, g, "kinetic_energy", t.kinetic, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "elastic_energy", t.elastic, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "gravity_energy", t.gravity_potential, "J", err));
    DR_TRY(dr_world_write_vec_(h, g, "linear_momentum", t.momentum, "kg*m/s", err));
    DR_TRY(dr_world_write_vec_(h, g, "angular_momentum", t.angular, "kg*m^2/s", err));
    return DR_OK;
}

static DrStatus write_solver_diagnostics(const WorldMpm *m, DrH5 *h, DrError *err)
{
    const char *g = "/diagnostics";
    DrMpmTotals t = dr_mpm_totals(m->mpm, -1);
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_substeps", m->last.substeps, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_newton_iterations", m->last.newton_iterations, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_cg_iterations", m->last.cg_iterations, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_newton_residual", m->last.newton_residual, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_newton_not_converged", m->not_converged, "1", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_kinetic_energy", t.kinetic, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_elastic_energy", t.elastic, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_gravity_energy", t.gravity_potential, "J", err));
    DR_TRY(dr_world_write_scalar_(h, g, "mpm_total_energy", t.kinetic + t.elastic + t.gravity_potential, "J", err));
    DR_TRY(dr_world_write_vec_(h, g, "mpm_linear_momentum", t.momentum, "kg*m/s", err));
    DR_TRY(dr_world_write_vec_(h, g, "mpm_angular_momentum", t.angular, "kg*m^2/s", err));
    return DR_OK;
}

DrStatus dr_world_mpm_write_(const DrWorld *w, DrH5 *h, bool frame_cache, DrError *err)
{
    const WorldMpm *m = w->mpm;
    if (!m) return DR_OK;
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
        if (s == DR_OK) s = write_body_diagnostics(w, h, &st, wb, err);
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

DrStatus dr_world_mpm_read_(DrWorld *w, DrH5 *h, const char *path, DrError *err)
{
    WorldMpm *m = w->mpm;
    if (!m) return DR_OK;
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
    return s;
}

void dr_world_mpm_hash_(const DrWorld *w, DrHasher *h)
{
    if (!w->mpm) return;
    DrMpmState st = dr_mpm_state(w->mpm->mpm);
    size_t n = (size_t)st.n;
    dr_hasher_update(h, &st.n, sizeof st.n);
    dr_hasher_update(h, st.x, 3 * sizeof(double) * n);
    dr_hasher_update(h, st.v, 3 * sizeof(double) * n);
    dr_hasher_update(h, st.C, 9 * sizeof(double) * n);
    dr_hasher_update(h, st.F, 9 * sizeof(double) * n);
}
