/* The cloth adapter: every cloth element of the scene as a panel of src/cloth on the world's clock, with the scene's
 * colliders, the bem_solid bodies and the MPM solids as what holds it up, and, with ClothDrag and a fluid in the
 * scene, as a solid of the coupled loop (src/couple) with one face element per vertex.
 *
 * SlideVertices holds the vertices in its box on a curve (dr_cloth_slide).
 *
 * Steps. Every panel takes the same steps: ClothSolver.substeps a frame at least, more when a vertex would move by
 * more than ClothSolver.cfl shortest edges of its panel in one (at most max_substeps a frame; reaching it is a
 * warning). The scene checks that every cloth element gives the same substeps, cfl and max_substeps.
 *
 * Coupled, a vertex is a face element of area A_v (a third of its triangles'), thickness h and unit normal n (the
 * area-weighted normal of its triangles at the step's start), volume A_v h, drag law ClothDrag; a pinned vertex is
 * held (its reaction goes to the pin).
 *
 * Frame cache, per frame, under /<cloth>/ (type "cloth"): position and velocity (V×3, m and m/s, the mesh's vertex
 * order after Transform), triangles (T×3, the mesh's, counter-clockwise seen from the side its normals face), uv
 * (T×3×2, the mesh file's texture coordinates of each triangle corner, when it has them), and
 * kinetic_energy, membrane_energy, bending_energy (J). Checkpoint: position, velocity and the membrane multipliers
 * (3 per triangle), which the next step's geometric stiffness uses: a resumed bake is bit-identical. */
#include "world_adapter.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cloth/cloth.h"
#include "stage/stage.h"

typedef struct WorldPanel {
    const DrElement *element;
    DrCloth *cloth;
    double min_edge;     /* m, the panel's shortest edge */
    double *area;        /* V: a third of the area of each vertex's triangles (rest), m² */
    double thickness;
    int first;           /* its first element in the coupled samples */
    int npins;
    int *pins;           /* the pinned vertices (FixedVertices, pin and rigid attachments) */
    double *pin_rest;    /* 3 npins: where they are in the placed rest pose */
    int *pin_carrier;    /* npins: −1, moved by the panel's Motion; else the index in carriers of what carries it */
    const DrElement **carriers; /* the targets of the panel's rigid attachments */
    int ncarriers;
    double *keys;        /* Motion keys (rows of 7), moving the pins rigidly from the rest pose */
    int nkeys;
    double *uv;          /* 6T: the mesh's texture coordinates per triangle corner, NULL without */
    WorldClothPanelLink *link; /* hair meets it: an object of the hair's system, stepped by the hair adapter */
} WorldPanel;

typedef struct WorldCloth {
    WorldPanel *panels;
    int n;
    long nverts;
    DrClothCollider *colliders;
    int ncolliders;
    int substeps, max_steps;
    double cfl;
    /* the frame being advanced */
    int steps, not_converged, capped, contacts, self_contacts;
    long iterations;
    double seconds;
    DrClothFrameStats last;  /* the last completed frame's */
    /* the stability watch (off when something moves the cloth from outside: moving colliders, bodies, a fluid) */
    WorldWatch watch;
    bool watched, watch_started;
    double drop;             /* J: the panels' weight times their extent, what gravity can release */
    /* the coupled loop */
    bool couples;
    DrDragLaw *laws;         /* one per panel */
    int *law;                /* nverts */
    double *x, *v, *mass, *volume, *diameter, *slender, *normal;
    unsigned char *held, *face;
} WorldCloth;

static void cloth_destroy(void *self)
{
    WorldCloth *w = self;
    if (!w) return;
    for (int i = 0; i < w->n; i++) {
        dr_cloth_destroy(&w->panels[i].cloth);
        free(w->panels[i].area);
        free(w->panels[i].pins);
        free(w->panels[i].pin_rest);
        free(w->panels[i].pin_carrier);
        free(w->panels[i].carriers);
        free(w->panels[i].keys);
        free(w->panels[i].uv);
    }
    free(w->panels);
    free(w->colliders);
    free(w->laws);
    free(w->law);
    free(w->x);
    free(w->v);
    free(w->mass);
    free(w->volume);
    free(w->diameter);
    free(w->slender);
    free(w->normal);
    free(w->held);
    free(w->face);
    free(w);
}

/* Whether rest position q lies inside the box [lo, hi]. */
static bool in_box(const double *q, DrVec3 lo, DrVec3 hi)
{
    return q[0] >= lo.x && q[0] <= hi.x && q[1] >= lo.y && q[1] <= hi.y && q[2] >= lo.z && q[2] <= hi.z;
}

/* Pins every vertex inside box (placed rest pose), moved by the panel's Motion (carrier NULL) or carried by a rigid
   attachment's target; `by` is the element that asks (the cloth for its FixedVertices, else the attachment) and
   `where` its field for messages. The box must hold a vertex, and no vertex is held by two attachments that move it
   differently. */
static DrStatus pin_box(const DrElement *e, const DrElement *by, const char *where, DrVec3 lo, DrVec3 hi,
                        const DrElement *carrier, const DrTriMesh *m, WorldPanel *p, DrError *err)
{
    if (!p->pins) {
        DR_TRY(dr_calloc((size_t)m->nv, sizeof(int), &p->pins, err));
        DR_TRY(dr_calloc(3 * (size_t)m->nv, sizeof(double), &p->pin_rest, err));
        DR_TRY(dr_calloc((size_t)m->nv, sizeof(int), &p->pin_carrier, err));
    }
    int ci = -1;
    if (carrier) {
        for (int k = 0; k < p->ncarriers; k++)
            if (p->carriers[k] == carrier) ci = k;
        if (ci < 0) {
            DR_TRY(dr_realloc((size_t)p->ncarriers + 1, sizeof *p->carriers, &p->carriers, err));
            ci = p->ncarriers++;
            p->carriers[ci] = carrier;
        }
    }
    int pinned = 0;
    for (int v = 0; v < m->nv; v++) {
        const double *q = m->v + 3 * v;
        if (!in_box(q, lo, hi)) continue;
        pinned++;
        int k = 0;
        while (k < p->npins && p->pins[k] != v) k++;
        if (k < p->npins) { /* held already: by the same motion, or a conflict */
            if (p->pin_carrier[k] == ci) continue;
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "%s: vertex %d of %s (at %g, %g, %g in the placed rest pose) is held by %s.%s and by "
                                "another attachment that moves it otherwise (%s); shrink one of the boxes so that "
                                "they do not overlap",
                                by->name, v, e->name, q[0], q[1], q[2], by->name, where,
                                p->pin_carrier[k] < 0 ? "a pin" : p->carriers[p->pin_carrier[k]]->name);
        }
        DR_TRY(dr_cloth_pin(p->cloth, v, true, NULL, err));
        p->pins[p->npins] = v;
        p->pin_carrier[p->npins] = ci;
        memcpy(p->pin_rest + 3 * p->npins, q, 3 * sizeof(double));
        p->npins++;
    }
    if (pinned == 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "%s.%s holds none of the %d vertices of %s (in the placed rest pose); move or enlarge "
                            "the box", by->name, where, m->nv, e->name);
    return DR_OK;
}

/* The vertices inside box (placed rest pose) slide on the curve (rows of 3); the box must hold one and the curve have
   2 points or more. `by` and `where` as pin_box's. */
static DrStatus slide_box(const DrElement *e, const DrElement *by, const char *where, DrVec3 lo, DrVec3 hi,
                          const double *rows, int n, const DrTriMesh *m, DrCloth *cl, DrError *err)
{
    if (n < 2)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "%s.%s.curve has %d point(s); give the curve as 2 points or more "
                            "[[x, y, z], [x, y, z], ...]",
                            by->name, where, n);
    DR_TRY(dr_error_prefix(dr_cloth_set_slide_curve(cl, rows, n, err), err, "%s.%s.curve", by->name, where));
    int held = 0;
    for (int v = 0; v < m->nv; v++) {
        if (!in_box(m->v + 3 * v, lo, hi)) continue;
        DR_TRY(dr_cloth_slide(cl, v, true, err));
        held++;
    }
    if (held == 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "%s.%s.box holds none of the %d vertices of %s (in the placed rest pose); move or enlarge "
                            "the box", by->name, where, m->nv, e->name);
    return DR_OK;
}

/* What holds the panel: its FixedVertices and SlideVertices, then the scene's attachment elements that list it, in
   element order (pin: moved by the panel's Motion as FixedVertices; slide: as SlideVertices; rigid: carried by the
   target). */
static DrStatus attach(const WorldCtx *c, const DrElement *e, const DrTriMesh *m, WorldPanel *p, DrError *err)
{
    DrVec3 lo, hi;
    const DrComponent *fixed = dr_element_component(e, "FixedVertices");
    if (dr_component_present(fixed)) {
        dr_component_box(fixed, "box", &lo, &hi);
        DR_TRY(pin_box(e, e, "FixedVertices.box", lo, hi, NULL, m, p, err));
    }
    const DrComponent *sc = dr_element_component(e, "SlideVertices");
    if (dr_component_present(sc)) {
        const double *rows = NULL;
        int n = dr_component_table(sc, "curve", &rows);
        dr_component_box(sc, "box", &lo, &hi);
        DR_TRY(slide_box(e, e, "SlideVertices", lo, hi, rows, n, m, p->cloth, err));
    }
    for (int i = 0; i < dr_scene_element_count(c->scene); i++) {
        const DrElement *a = dr_scene_element(c->scene, i);
        if (a->kind != DR_ELEMENT_ATTACHMENT) continue;
        const DrComponent *ac = dr_element_component(a, "Attachment");
        const char *const *mem = NULL;
        int n = dr_component_names(ac, "members", &mem);
        bool listed = false;
        for (int k = 0; k < n; k++) listed = listed || strcmp(mem[k], e->name) == 0;
        if (!listed) continue;
        dr_component_box(ac, "box", &lo, &hi);
        const char *method = dr_component_str(ac, "method");
        if (strcmp(method, "slide") == 0) {
            const double *rows = NULL;
            int nr = dr_component_table(ac, "curve", &rows);
            DR_TRY(slide_box(e, a, "Attachment", lo, hi, rows, nr, m, p->cloth, err));
        } else if (strcmp(method, "pin") == 0) {
            DR_TRY(pin_box(e, a, "Attachment.box", lo, hi, NULL, m, p, err));
        } else {
            const DrElement *t = dr_scene_find(c->scene, dr_component_str(ac, "target"));
            DR_TRY(pin_box(e, a, "Attachment.box", lo, hi, t, m, p, err));
        }
    }
    return DR_OK;
}

static DrStatus build_panel(const WorldCtx *c, const DrElement *e, WorldPanel *p, DrError *err)
{
    p->element = e;
    DrTriMesh m = {0};
    DR_TRY(dr_stage_load_posed_mesh(e, dr_component_str(dr_element_component(e, "Mesh"), "file"), "Mesh.file", &m,
                                    err));
    const DrComponent *mc = dr_element_component(e, "ClothMaterial");
    const DrComponent *sc = dr_element_component(e, "ClothSolver");
    const DrComponent *col = dr_element_component(e, "Collider");
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    mat.density = dr_component_num(mc, "density");
    mat.thickness = dr_component_num(mc, "thickness");
    mat.youngs_modulus = dr_component_num(mc, "youngs_modulus");
    mat.poisson = dr_component_num(mc, "poisson");
    mat.bend_scale = dr_component_num(mc, "bend_scale");
    mat.damping = dr_component_num(mc, "damping");
    mat.bending = strcmp(dr_component_str(mc, "bending"), "hinge") == 0 ? DR_CLOTH_BEND_HINGE
                                                                         : DR_CLOTH_BEND_SHAPE_OPERATOR;
    mat.self_contact = dr_component_bool(mc, "self_contact");
    mat.friction = dr_component_num(col, "friction");
    double th = dr_component_num(col, "thickness");
    if (th > 0) mat.collision_thickness = th;
    p->thickness = mat.thickness;
    DrClothDesc desc;
    dr_cloth_desc_default(&desc);
    desc.gravity = c->gravity;
    desc.solver.tol = dr_component_num(sc, "tolerance");
    desc.solver.max_iter = dr_component_int(sc, "max_iterations");
    desc.collider_stiffness = dr_component_num(sc, "collider_stiffness");
    /* self contact: ClothMaterial.self_contact with the collider contacts' stiffness, friction and thickness, or, in a
       scene with collision elements, the vertex_face one that meets the panel with itself, whose CollisionResponse's
       written fields take their place */
    mat.self_stiffness = desc.collider_stiffness;
    mat.self_friction = mat.friction;
    mat.self_thickness = mat.collision_thickness;
    mat.self_damping = 0.0;
    if (dr_scene_count_kind(c->scene, DR_ELEMENT_COLLISION) > 0) {
        const DrElement *ce = dr_scene_collision(c->scene, e->name, e->name, "vertex_face");
        mat.self_contact = ce != NULL;
        if (ce) {
            const DrComponent *r = dr_element_component(ce, "CollisionResponse");
            if (dr_component_is_set(r, "stiffness")) mat.self_stiffness = dr_component_num(r, "stiffness");
            if (dr_component_is_set(r, "friction")) mat.self_friction = dr_component_num(r, "friction");
            if (dr_component_is_set(r, "thickness")) mat.self_thickness = dr_component_num(r, "thickness");
            mat.self_damping = dr_component_num(r, "damping");
        }
    }
    WorldClothLink *link = world_kinematics_cloth_link(c->kin);
    for (int k = 0; k < link->n; k++)
        if (link->panels[k].element == e) p->link = &link->panels[k];
    if (p->link) {
        assert(link->system); /* the hair adapter is built first */
        desc.system = link->system;
    }
    DrStatus s = dr_cloth_create(&desc, &m, &mat, e->name, &p->cloth, err);
    if (s == DR_OK && p->link) p->link->cloth = p->cloth;
    if (s == DR_OK) s = attach(c, e, &m, p, err);
    if (s == DR_OK) s = dr_stage_motion_keys(e, c->first_frame, c->fps, &p->keys, &p->nkeys, err);
    if (s == DR_OK) s = dr_calloc((size_t)m.nv, sizeof(double), &p->area, err);
    p->min_edge = INFINITY;
    for (int t = 0; s == DR_OK && t < m.nt; t++) {
        const int *tv = m.tri + 3 * t;
        DrVec3 q[3];
        for (int k = 0; k < 3; k++) q[k] = dr_v3(m.v[3 * tv[k]], m.v[3 * tv[k] + 1], m.v[3 * tv[k] + 2]);
        double a = 0.5 * dr_v3_norm(dr_v3_cross(dr_v3_sub(q[1], q[0]), dr_v3_sub(q[2], q[0])));
        for (int k = 0; k < 3; k++) {
            p->area[tv[k]] += a / 3.0;
            double l = dr_v3_norm(dr_v3_sub(q[(k + 1) % 3], q[k]));
            if (l > 0) p->min_edge = fmin(p->min_edge, l);
        }
    }
    if (s == DR_OK && m.uv) {
        p->uv = m.uv; /* the panel keeps the mesh's triangles in order: the corners' coordinates stay theirs */
        m.uv = NULL;
    }
    dr_trimesh_free(&m);
    return s;
}

/* The coupled loop's arrays and laws (ClothDrag on every panel that has it; a panel without it is not coupled: its
   elements carry no drag, law with every scale 0). */
static DrStatus build_couple(WorldCloth *w, DrError *err)
{
    long n = w->nverts;
    DR_TRY(dr_calloc((size_t)w->n, sizeof *w->laws, &w->laws, err));
    DR_TRY(dr_calloc((size_t)n, sizeof(int), &w->law, err));
    double **arrays[] = {&w->x, &w->v, &w->normal};
    for (size_t k = 0; k < sizeof arrays / sizeof arrays[0]; k++)
        DR_TRY(dr_calloc(3 * (size_t)n, sizeof(double), arrays[k], err));
    double **scalars[] = {&w->mass, &w->volume, &w->diameter, &w->slender};
    for (size_t k = 0; k < sizeof scalars / sizeof scalars[0]; k++)
        DR_TRY(dr_calloc((size_t)n, sizeof(double), scalars[k], err));
    DR_TRY(dr_calloc((size_t)n, 1, &w->held, err));
    DR_TRY(dr_calloc((size_t)n, 1, &w->face, err));
    for (int i = 0; i < w->n; i++) {
        WorldPanel *p = &w->panels[i];
        const DrComponent *d = dr_element_component(p->element, "ClothDrag");
        DrDragLaw *law = &w->laws[i];
        dr_drag_law_default(law);
        law->global = dr_component_present(d) ? 1.0 : 0.0;
        law->normal = dr_component_num(d, "normal");
        law->tangent = dr_component_num(d, "tangent");
        law->nonlinear = dr_component_num(d, "nonlinear_scale");
        law->degree = dr_component_num(d, "degree");
        law->lift = dr_component_present(d) ? dr_component_num(d, "lift_scale") : 0.0;
        law->buoyancy = dr_component_present(d) && dr_component_bool(d, "buoyancy");
        int nv = dr_cloth_vertex_count(p->cloth);
        for (int v = 0; v < nv; v++) {
            long k = p->first + v;
            w->law[k] = i;
            /* a panel without ClothDrag neither drags nor blocks the fluid */
            w->volume[k] = dr_component_present(d) ? p->area[v] * p->thickness : 0.0;
            w->diameter[k] = p->thickness;
            w->slender[k] = 2.0;
            w->face[k] = 1;
            w->mass[k] = dr_cloth_masses(p->cloth)[v];
        }
    }
    return DR_OK;
}

static DrStatus build_cloth(const WorldCtx *c, WorldCloth *w, DrError *err)
{
    const DrScene *scene = c->scene;
    int n = dr_scene_count_kind(scene, DR_ELEMENT_CLOTH);
    DR_TRY(dr_calloc((size_t)n, sizeof *w->panels, &w->panels, err));
    const DrElement *first = NULL;
    bool coupled = false;
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_CLOTH) continue;
        if (!first) first = e;
        WorldPanel *p = &w->panels[w->n++]; /* counted first: a panel that fails half-built is freed with the rest */
        DR_TRY(dr_error_prefix(build_panel(c, e, p, err), err, "cloth '%s'", e->name));
        p->first = (int)w->nverts;
        w->nverts += dr_cloth_vertex_count(p->cloth);
        coupled = coupled || dr_component_present(dr_element_component(e, "ClothDrag"));
    }
    const DrComponent *sc = dr_element_component(first, "ClothSolver");
    w->substeps = dr_component_int(sc, "substeps");
    w->max_steps = dr_component_int(sc, "max_substeps");
    w->cfl = dr_component_num(sc, "cfl");
    /* the live colliders, then the bem_solid bodies' deformed surfaces and the MPM solids' particles, posed by the
       kinematics at every clock step's end (as the hair takes them) */
    const DrCollider *const *live = NULL;
    int nlive = world_kinematics_colliders(c->kin, &live);
    WorldPosedCollider *posed = world_kinematics_posed(c->kin), *bodies = NULL;
    int nbodies = world_kinematics_bodies_posed(c->kin, &bodies);
    DrClothCollider mpm = {0};
    bool with_mpm = world_kinematics_mpm_surface(c->kin, &mpm.sdf, &mpm.velocity_at, &mpm.ctx);
    DR_TRY(dr_calloc((size_t)(nlive + nbodies + 1), sizeof *w->colliders, &w->colliders, err));
    for (int k = 0; k < nlive; k++)
        w->colliders[k] = (DrClothCollider){world_posed_sdf, world_posed_velocity, &posed[k],
                                            dr_collider_friction(live[k]), 0};
    for (int k = 0; k < nbodies; k++)
        w->colliders[nlive + k] = (DrClothCollider){world_posed_sdf, world_posed_velocity, &bodies[k], 0, 0};
    w->ncolliders = nlive + nbodies;
    if (with_mpm) w->colliders[w->ncolliders++] = mpm;
    WorldClothLink *link = world_kinematics_cloth_link(c->kin);
    link->colliders = w->colliders;
    link->ncolliders = w->ncolliders;
    bool fluid = dr_scene_count_kind(scene, DR_ELEMENT_LIQUID) > 0 || dr_scene_count_kind(scene, DR_ELEMENT_AIR) > 0;
    w->couples = coupled && fluid;
    if (w->couples) DR_TRY(build_couple(w, err));
    world_watch_init(&w->watch, scene);
    for (int i = 0; i < w->n; i++) {
        DrCloth *cl = w->panels[i].cloth;
        double mass = 0.0;
        DrVec3 lo = dr_v3(INFINITY, INFINITY, INFINITY), hi = dr_v3(-INFINITY, -INFINITY, -INFINITY);
        for (int v = 0; v < dr_cloth_vertex_count(cl); v++) {
            const double *x = dr_cloth_positions(cl) + 3 * v;
            mass += dr_cloth_masses(cl)[v];
            lo = dr_v3(fmin(lo.x, x[0]), fmin(lo.y, x[1]), fmin(lo.z, x[2]));
            hi = dr_v3(fmax(hi.x, x[0]), fmax(hi.y, x[1]), fmax(hi.z, x[2]));
        }
        w->drop += mass * dr_v3_norm(c->gravity) * dr_v3_norm(dr_v3_sub(hi, lo));
    }
    w->watched = nbodies == 0 && !with_mpm && !w->couples && link->n == 0;
    for (int i = 0; i < w->n; i++) w->watched = w->watched && w->panels[i].nkeys == 0;
    for (int k = 0; k < nlive; k++) w->watched = w->watched && dr_collider_static(live[k]);
    return DR_OK;
}

static double max_speed(const WorldCloth *w)
{
    double v2 = 0.0;
    for (int i = 0; i < w->n; i++) {
        const double *v = dr_cloth_velocities(w->panels[i].cloth);
        for (int k = 0; k < 3 * dr_cloth_vertex_count(w->panels[i].cloth); k += 3)
            v2 = fmax(v2, v[k] * v[k] + v[k + 1] * v[k + 1] + v[k + 2] * v[k + 2]);
    }
    return sqrt(v2);
}

static void cloth_begin_frame(void *self, const WorldCtx *c)
{
    (void)c;
    WorldCloth *w = self;
    w->steps = w->not_converged = w->capped = w->contacts = w->self_contacts = 0;
    w->iterations = 0;
    w->seconds = 0.0;
}

/* At least `substeps` equal steps a frame; fewer than the CFL asks for only at max_substeps. */
static DrStatus cloth_next_time(void *self, const WorldCtx *c, double t, double *t_next, DrError *err)
{
    (void)err;
    WorldCloth *w = self;
    double frame = c->t1 - c->t0, room = c->t1 - t;
    double dt = frame / w->substeps;
    double edge = INFINITY;
    for (int i = 0; i < w->n; i++) edge = fmin(edge, w->panels[i].min_edge);
    double v = max_speed(w);
    if (w->cfl > 0 && v > 0 && isfinite(edge) && v * dt > w->cfl * edge) dt = w->cfl * edge / v;
    double floor_dt = frame / w->max_steps;
    if (!(dt >= floor_dt)) {
        dt = floor_dt;
        w->capped++;
    }
    double n = ceil(room / dt * (1.0 - 1e-9));
    *t_next = n <= 1.0 ? c->t1 : t + room / n;
    return DR_OK;
}

/* With Motion, the pinned vertices' velocities over the step to t_next: each lands exactly where the motion's pose
   at t_next puts its rest position. */
static DrStatus move_pins(const WorldCtx *c, WorldPanel *p, double t, double t_next, DrError *err)
{
    if ((p->nkeys == 0 && p->ncarriers == 0) || p->npins == 0) return DR_OK;
    DrXform pose = dr_motion_pose(p->keys, p->nkeys, t_next);
    DrXform carry[8], *cp = carry;
    if (p->ncarriers > 8) DR_TRY(dr_calloc((size_t)p->ncarriers, sizeof *cp, &cp, err));
    for (int k = 0; k < p->ncarriers; k++)
        if (!world_kinematics_carry(c->kin, p->carriers[k], t_next, &cp[k])) cp[k] = dr_xform_identity();
    const double *x = dr_cloth_positions(p->cloth);
    DrStatus s = DR_OK;
    for (int k = 0; s == DR_OK && k < p->npins; k++) {
        int v = p->pins[k];
        if (p->pin_carrier[k] < 0 && p->nkeys == 0) continue; /* held where it is */
        DrXform X = p->pin_carrier[k] < 0 ? pose : cp[p->pin_carrier[k]];
        DrVec3 to = dr_xform_apply(X, dr_v3(p->pin_rest[3 * k], p->pin_rest[3 * k + 1], p->pin_rest[3 * k + 2]));
        double vel[3] = {(to.x - x[3 * v]) / (t_next - t), (to.y - x[3 * v + 1]) / (t_next - t),
                         (to.z - x[3 * v + 2]) / (t_next - t)};
        s = dr_cloth_pin(p->cloth, v, true, vel, err);
    }
    if (cp != carry) free(cp);
    return s;
}

static DrStatus panel_status(WorldCloth *w, DrStatus s)
{
    if (s == DR_WARN_NOT_CONVERGED) {
        w->not_converged++;
        return DR_OK;
    }
    return s;
}

static DrStatus cloth_step(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    WorldCloth *w = self;
    double t0 = dr_time_now();
    w->contacts = w->self_contacts = 0;
    for (int i = 0; i < w->n; i++) {
        DrClothStats st;
        WorldPanel *p = &w->panels[i];
        if (p->link) { /* the hair adapter stepped it with the hair in this clock step */
            st = p->link->last;
            st.iterations = p->link->iterations;
            w->not_converged += p->link->not_converged;
            p->link->iterations = 0;
            p->link->not_converged = 0;
            p->link->steps = 0;
        } else {
            DR_TRY(move_pins(c, p, t, t_next, err));
            DR_TRY(panel_status(w, dr_cloth_step(p->cloth, t_next - t, w->colliders, w->ncolliders, &st, err)));
        }
        w->iterations += st.iterations;
        w->contacts += st.collider_contacts;
        w->self_contacts += st.self_contacts;
    }
    w->steps++;
    w->seconds += dr_time_now() - t0;
    return DR_OK;
}

/* ---- the coupled step (src/couple) ---- */

static DrCoupleSamples couple_samples(void *ctx)
{
    WorldCloth *w = ctx;
    return (DrCoupleSamples){(int)w->nverts, w->x, w->v, w->mass, w->volume, w->diameter, w->slender, w->normal,
                             w->held, w->law, NULL, NULL, w->face};
}

/* The panels' last solve's velocities into the samples. */
static void gather_v(WorldCloth *w)
{
    for (int i = 0; i < w->n; i++) {
        const WorldPanel *p = &w->panels[i];
        memcpy(w->v + 3 * (size_t)p->first, dr_cloth_solved_velocities(p->cloth),
               3 * (size_t)dr_cloth_vertex_count(p->cloth) * sizeof(double));
    }
}

static DrStatus couple_solve(void *ctx, const double *force, const double *dforce_dv, DrError *err)
{
    WorldCloth *w = ctx;
    for (int i = 0; i < w->n; i++) {
        const WorldPanel *p = &w->panels[i];
        DrStatus s = dr_cloth_solve(p->cloth, force + 3 * (size_t)p->first, dforce_dv + 9 * (size_t)p->first, err);
        if (s < 0) return dr_error_prefix(s, err, "cloth '%s'", p->element->name);
    }
    gather_v(w);
    return DR_OK;
}

static bool cloth_couples(const void *self) { return ((const WorldCloth *)self)->couples; }

static DrStatus cloth_solid_predict(void *self, const WorldCtx *c, double t, double t_next, DrCoupleSolid *solid,
                                    DrError *err)
{
    WorldCloth *w = self;
    double t0 = dr_time_now();
    for (int i = 0; i < w->n; i++) {
        WorldPanel *p = &w->panels[i];
        DR_TRY(move_pins(c, p, t, t_next, err));
        DR_TRY(panel_status(w, dr_cloth_predict(p->cloth, t_next - t, w->colliders, w->ncolliders, err)));
        int nv = dr_cloth_vertex_count(p->cloth);
        memcpy(w->x + 3 * (size_t)p->first, dr_cloth_positions(p->cloth), 3 * (size_t)nv * sizeof(double));
        dr_cloth_normals(p->cloth, w->normal + 3 * (size_t)p->first);
        DrClothSamples sm;
        dr_cloth_samples(p->cloth, &sm);
        for (int v = 0; v < nv; v++) {
            double *nrm = w->normal + 3 * ((size_t)p->first + v);
            if (!(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2] > 0)) nrm[1] = 1.0; /* a folded-flat vertex */
            w->held[p->first + v] = sm.pinned[v];
        }
    }
    gather_v(w);
    *solid = (DrCoupleSolid){w, w->n, w->laws, couple_samples, couple_solve, NULL, NULL};
    w->seconds += dr_time_now() - t0;
    return DR_OK;
}

static DrStatus cloth_solid_commit(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    (void)c, (void)t, (void)t_next;
    WorldCloth *w = self;
    double t0 = dr_time_now();
    w->contacts = w->self_contacts = 0;
    for (int i = 0; i < w->n; i++) {
        DrClothStats st;
        DrStatus s = dr_cloth_commit(w->panels[i].cloth, &st, err);
        if (s < 0) return s;
        w->iterations += st.iterations;
        w->contacts += st.collider_contacts;
        w->self_contacts += st.self_contacts;
    }
    w->steps++;
    w->seconds += dr_time_now() - t0;
    return DR_OK;
}

static double cloth_solid_stable_dt(const void *self, double density, double viscosity)
{
    const WorldCloth *w = self;
    double dt = INFINITY;
    for (int i = 0; i < w->n; i++) {
        const DrDragLaw *law = &w->laws[i];
        if (!(law->lift > 0)) continue;
        const WorldPanel *p = &w->panels[i];
        for (int v = 0; v < dr_cloth_vertex_count(p->cloth); v++) {
            long k = p->first + v;
            DrDragSite site = {dr_v3(0, 1, 0), w->diameter[k], w->volume[k], 2.0, 0.0, true};
            double cl = viscosity * site.volume / (site.diameter * site.diameter) *
                        dr_drag_coefficient(law, 1, density, viscosity, &site, 0.0);
            double l = 0.5 * law->lift * cl;
            if (l > 0 && w->mass[k] / l < dt) dt = w->mass[k] / l;
        }
    }
    return dt;
}

/* ---- frames, caches, checkpoints ---- */

static void measure(const WorldCloth *w, DrClothFrameStats *b)
{
    for (int i = 0; i < w->n; i++) {
        DrClothEnergy e;
        dr_cloth_energy(w->panels[i].cloth, &e);
        b->kinetic_energy += e.kinetic;
        b->membrane_energy += e.membrane;
        b->bending_energy += e.bending;
        b->gravity_energy += e.gravity;
    }
}

static DrStatus cloth_end_frame(void *self, const WorldCtx *c, DrFrameStats *stats, DrError *err)
{
    WorldCloth *w = self;
    DrClothFrameStats *b = &stats->cloth;
    memset(b, 0, sizeof *b);
    b->present = true;
    b->panels = w->n;
    b->vertices = w->nverts;
    b->substeps = w->steps;
    b->cg_iterations = w->iterations;
    b->not_converged = w->not_converged;
    b->collider_contacts = w->contacts;
    b->self_contacts = w->self_contacts;
    b->seconds = w->seconds;
    b->max_speed = max_speed(w);
    measure(w, b);
    if (!isfinite(b->kinetic_energy + b->membrane_energy + b->bending_energy + b->gravity_energy))
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "cloth became non-finite in frame %d; raise ClothSolver.substeps or lower the stiffness",
                            c->frame);
    if (w->not_converged)
        dr_log_warn("cloth: %d solves in frame %d stopped at ClothSolver.max_iterations; raise max_iterations or "
                    "substeps", w->not_converged, c->frame);
    if (w->capped)
        dr_log_warn("cloth: frame %d took steps of a ClothSolver.max_substeps-th (%d) of the frame although the cloth "
                    "moved faster than ClothSolver.cfl = %g shortest edges per step allows; raise max_substeps",
                    c->frame, w->max_steps, w->cfl);
    w->last = *b;
    if (w->watched) {
        /* the energy after the frame's last step; the first frame after building or resuming gives the reference */
        WorldEnergy e = {0};
        e.energy = b->kinetic_energy + b->membrane_energy + b->bending_energy + b->gravity_energy;
        e.available = b->kinetic_energy + b->membrane_energy + b->bending_energy + w->drop;
        e.floor = 1e-12 + 1e-6 * w->drop;
        if (!w->watch_started) {
            w->watch_started = true;
            world_watch_start(&w->watch, c->frame + 1, &e);
        } else {
            DR_TRY(world_watch_energy(&w->watch, c, &e, "cloth",
                                      "raise ClothSolver.substeps (smaller steps) or ClothMaterial.damping", err));
        }
    }
    dr_log_debug("frame %d: cloth: %d panel(s), %d steps, %ld CG iterations, %d contacts, kinetic %.6g J, max speed "
                 "%.4g m/s", c->frame, w->n, w->steps, w->iterations, w->contacts, b->kinetic_energy, b->max_speed);
    return DR_OK;
}

static DrStatus cloth_write(const void *self, const WorldCtx *c, DrH5 *h, bool frame_cache, DrError *err)
{
    (void)c;
    const WorldCloth *w = self;
    for (int i = 0; i < w->n; i++) {
        const WorldPanel *p = &w->panels[i];
        const char *name = p->element->name;
        uint64_t nv = (uint64_t)dr_cloth_vertex_count(p->cloth), nt = (uint64_t)dr_cloth_triangle_count(p->cloth);
        char path[512];
        PATHF(path, "/%s/position", name);
        DR_TRY(dr_h5_write_f64(h, path, 2, (uint64_t[]){nv, 3}, dr_cloth_positions(p->cloth), "m", frame_cache, err));
        PATHF(path, "/%s/velocity", name);
        DR_TRY(dr_h5_write_f64(h, path, 2, (uint64_t[]){nv, 3}, dr_cloth_velocities(p->cloth), "m/s", frame_cache,
                               err));
        if (frame_cache) {
            int32_t *tri = NULL;
            DR_TRY(dr_calloc(3 * nt, sizeof *tri, &tri, err));
            for (uint64_t k = 0; k < 3 * nt; k++) tri[k] = dr_cloth_triangles(p->cloth)[k];
            PATHF(path, "/%s/triangles", name);
            DrStatus s = dr_h5_write_i32(h, path, 2, (uint64_t[]){nt, 3}, tri, "1", true, err);
            free(tri);
            DR_TRY(s);
            if (p->uv) {
                PATHF(path, "/%s/uv", name);
                DR_TRY(dr_h5_write_f64(h, path, 3, (uint64_t[]){nt, 3, 2}, p->uv, "1", true, err));
            }
            DrClothEnergy e;
            dr_cloth_energy(p->cloth, &e);
            PATHF(path, "/%s", name);
            DR_TRY(dr_h5_write_scalar(h, path, "kinetic_energy", e.kinetic, "J", err));
            DR_TRY(dr_h5_write_scalar(h, path, "membrane_energy", e.membrane, "J", err));
            DR_TRY(dr_h5_write_scalar(h, path, "bending_energy", e.bending, "J", err));
        } else {
            int count;
            double *lambda = dr_cloth_multipliers(p->cloth, &count);
            PATHF(path, "/%s/multipliers", name);
            DR_TRY(dr_h5_write_f64(h, path, 1, (uint64_t[]){(uint64_t)count}, lambda, "1", false, err));
        }
        PATHF(path, "/%s", name);
        DR_TRY(dr_h5_attr_str(h, path, "type", "cloth", err));
    }
    return DR_OK;
}

static DrStatus read_exact(DrH5 *h, const char *file, const char *path, uint64_t count, double *dst, DrError *err)
{
    int rank;
    uint64_t dims[4];
    double *data = NULL;
    DR_TRY(dr_h5_read_f64(h, path, &rank, dims, &data, err));
    uint64_t total = 1;
    for (int r = 0; r < rank; r++) total *= dims[r];
    if (total != count) {
        free(data);
        return dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                            "checkpoint dataset %s holds %llu numbers where the scene's cloth has %llu; delete the "
                            "checkpoint and bake without --resume",
                            path, (unsigned long long)total, (unsigned long long)count);
    }
    if (count) memcpy(dst, data, count * sizeof(double));
    free(data);
    return DR_OK;
}

static DrStatus cloth_read(void *self, const WorldCtx *c, DrH5 *h, const char *file, int frame, DrError *err)
{
    (void)c, (void)frame;
    WorldCloth *w = self;
    w->watch_started = false;
    for (int i = 0; i < w->n; i++) {
        WorldPanel *p = &w->panels[i];
        const char *name = p->element->name;
        uint64_t nv = (uint64_t)dr_cloth_vertex_count(p->cloth);
        char path[512];
        PATHF(path, "/%s/position", name);
        DR_TRY(read_exact(h, file, path, 3 * nv, dr_cloth_positions_mut(p->cloth), err));
        PATHF(path, "/%s/velocity", name);
        DR_TRY(read_exact(h, file, path, 3 * nv, dr_cloth_velocities_mut(p->cloth), err));
        int count;
        double *lambda = dr_cloth_multipliers(p->cloth, &count);
        PATHF(path, "/%s/multipliers", name);
        DR_TRY(read_exact(h, file, path, (uint64_t)count, lambda, err));
    }
    return DR_OK;
}

static void cloth_hash(const void *self, DrHasher *h)
{
    const WorldCloth *w = self;
    for (int i = 0; i < w->n; i++) {
        size_t nv = (size_t)dr_cloth_vertex_count(w->panels[i].cloth);
        dr_hasher_update(h, dr_cloth_positions(w->panels[i].cloth), 3 * nv * sizeof(double));
        dr_hasher_update(h, dr_cloth_velocities(w->panels[i].cloth), 3 * nv * sizeof(double));
    }
}

DrStatus world_cloth_adapter(const WorldCtx *c, WorldSolver *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    if (dr_scene_count_kind(c->scene, DR_ELEMENT_CLOTH) == 0) return DR_OK;
    WorldCloth *w = NULL;
    DR_TRY(dr_calloc(1, sizeof *w, &w, err));
    DrStatus s = build_cloth(c, w, err);
    if (s < 0) {
        cloth_destroy(w);
        return s;
    }
    *out = (WorldSolver){.name = "cloth",
                         .self = w,
                         .begin_frame = cloth_begin_frame,
                         .next_time = cloth_next_time,
                         .step = cloth_step,
                         .end_frame = cloth_end_frame,
                         .write = cloth_write,
                         .read = cloth_read,
                         .hash = cloth_hash,
                         .destroy = cloth_destroy,
                         .couples = cloth_couples,
                         .solid_predict = cloth_solid_predict,
                         .solid_commit = cloth_solid_commit,
                         .solid_stable_dt = cloth_solid_stable_dt};
    return DR_OK;
}

long world_cloth_vertex_count(const WorldSolver *s) { return s && s->self ? ((const WorldCloth *)s->self)->nverts : 0; }
