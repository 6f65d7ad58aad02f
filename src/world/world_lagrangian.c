/* The Lagrangian adapter: the world's one constraint system (DESIGN §8 "One Lagrangian system") and the models that
 * put their objects in it. Today that is the hair: every hair element of a scene is one batch of a single DrRodSet
 * (solved together, so strands of different elements can touch), stepped on the world's clock with the scene
 * colliders, the bem_solid bodies' deformed surfaces and the MPM solids' particles (posed by the kinematics) and the
 * scalp motion. A step: every model fills its DOFs, the system begins, every model adds its groups, one solve of the
 * whole system, the multipliers, every model commits (hair.h, "in a shared system"). */
#include "world_adapter.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hair/hair.h"
#include "stage/stage.h"
#include "wet/wet.h"

/* The momentum ledger of wet hair beside the liquid it exchanges water with (capture, dripping; README "The ledger"):
   after every clock step, once the exchange has run, P = liquid particles (m_p = the nominal particle's mass ×
   vol_p/V0) + strands (vertex masses) + film (dr_film_measure: its edges and pools), against the previous step's P plus
   what the world knows acts from outside, gravity × the total mass × the step. Anything else that pushes (the
   domain's walls, colliders, held roots, emitters, kill boxes, a film denser than the liquid) shows as a residual. */
typedef struct WorldMomentum {
    DrVec3 prev;               /* kg m/s: P after the last step (or at the start, or as resumed) */
    double mass;               /* kg: liquid + strands + film then */
    /* the frame's: the largest |ΔP − gravity impulse| / max(|P| before, |P| after) of a step and its residual, the
       gravity impulse summed, the steps measured */
    double relative_max, residual_max;
    DrVec3 external;
    int steps;
    DrVec3 liquid, hair, film; /* kg m/s: the parts of P after the frame's last step */
    /* the last frame's, for the frame cache */
    double last_relative_max, last_residual_max;
    DrVec3 last_external, last_liquid, last_hair, last_film;
    int last_steps;
} WorldMomentum;

/* Wet hair (src/wet): the film on every strand of the rod set (dry elements' strands start with none), the bridges
   between strands and to the colliders, and the cohesion tables precompute built. */
typedef struct WorldWet {
    DrStageWet set;
    DrCohesionTable *tables[2];
    DrFilm *film;
    DrBridges *bridges;
    double *radius;            /* per vertex, m */
    double *thickness;         /* per strand: CollisionResponse.thickness */
    int *batch;                /* per strand: its hair element */
    unsigned *group, *mask;    /* per element: the contact filter (CollisionGroup) */
    unsigned char *self;       /* per element: self_collision */
    unsigned char *held;       /* per vertex, from the first step's samples */
    bool held_known;
    double *force, *dfdv;      /* the film's load on the strands, per vertex */
    int *block_dof;
    double *block;
    double *x_old;             /* positions at the start of the step */
    double *dV;                /* cross-hair flow */
    double *heights;           /* per vertex: the film's outer radius, for the frame cache */
    DrFilmStats film_frame;    /* summed over the frame */
    double cross_flow;         /* m³ over the frame */
    double seconds_film, seconds_bridges, seconds_cross_flow; /* the frame's, disjoint parts of the hair's seconds */
    DrVec3 film_pressure;      /* N·s over the frame: the bulk's pressure on the film and pools (dr_film_pressure) */
    /* capture and dripping with the first liquid (world_wet.c): the exchange, the link it is driven through, and the
       strands' velocities at the start of a step and their acceleration over the last one */
    DrExchange *exchange;
    WorldWetLink *link;
    double *v_start, *accel;
    double *submerged;         /* per vertex, [0, 1]: how far under the liquid's surface (cohesion is off there) */
    bool warned_budget;
    WorldMomentum momentum;    /* the momentum ledger of liquid, strands and film (with the exchange) */
} WorldWet;


/* Hair coupled two ways with a fluid (elements with a Drag component; src/couple): per vertex the element's law, the
   volume, diameter and slenderness the laws read, and the coupling's load added to the film's. */
typedef struct WorldCouple {
    DrDragLaw *laws;           /* per hair element (an element without Drag: a law of no drag, no buoyancy) */
    int *law;                  /* per vertex */
    double *slender;           /* per vertex: its strand's rest length over its diameter */
    double *volume, *diameter; /* per vertex, filled with the samples (volume 0 on an uncoupled element) */
    double *mass;              /* per vertex, kg: the vertex's inertia the loop weighs it by, m_i + tr(B_i)/3 with the
                                  film it carries across (B_i, wet.h; m_i on dry hair) */
    double *pending, *next;    /* per vertex × 3, kg m/s: the loop's corrections (couple_correct), received in one step
                                  and applied as a force over the next one's solve (pending); next: this step's */
    unsigned char *coupled;    /* per element */
    double *carried;           /* per vertex, m³: the film and pools it carries (0 on dry hair or an uncoupled element) */
    double *impulse;           /* per vertex × 3, N·s: the bulk's pressure on its film and pools over the step
                                  (dr_film_pressure; 0 until the loop hands the hair ∇p) */
    double *gradp;             /* per vertex × 3, Pa/m: ∇p as the film takes it (0 on uncoupled elements) */
    double *force, *dfdv;      /* the solve's load per vertex (the film's plus the coupling's) */
    int *block_dof;
    double *block;
    double dt;                 /* the step being coupled */
    bool not_converged;        /* a solve of the step stopped at its cap */
} WorldCouple;

typedef struct WorldHair {
    DrLag *system;           /* the one system; the rod set's strands are objects in it */
    DrRodSet *rods;
    WorldWet *wet;           /* NULL: no hair element is wet */
    WorldCouple *cpl;        /* NULL: no hair element has a Drag component */
    const DrElement **elements;
    int nelements;
    /* per element: which strands touch (the rod set's group, mask and self_contact) and the thickness bridges keep,
       from the element's CollisionGroup and CollisionResponse or from the scene's collision elements */
    unsigned *cgroup, *cmask;
    unsigned char *cself;
    double *cthick;
    double **keys;           /* per element: scalp motion keys (rows of 7: s, m, rad) */
    const DrElement **carrier; /* per element: the target of the rigid attachment that carries its roots, or NULL */
    int *nkeys;
    bool any_motion;
    DrXform *poses;          /* per element, the step's end pose */
    DrRodCollider *colliders;
    int ncolliders;
    /* hair against cloth (world_kinematics_cloth_link): the panels are objects of this system, stepped here; one rows
       set per panel and collision element, for the batches that element pairs with the panel */
    WorldClothLink *link;
    int ncross;
    struct HairCross { int panel; DrContactResponse response; unsigned char *batch_on; } *cross;
    unsigned char *skip;     /* per vertex: not in the rows being added (held, or of another batch) */
    int hair_dofs;           /* the system's DOFs that are the hair's (the panels' come after) */
    long fint_cap;
    int cross_contacts;      /* rows of the last step */
    int last_cross;          /* the last frame's */
    long solve_iterations;   /* of the last solve */
    int substeps;            /* HairSolver.substeps: the hair's steps per frame when nothing else is faster */
    double cfl;              /* HairSolver.cfl: a step moves no vertex (nor film) by more than cfl shortest segments;
                                0: the substeps alone */
    int max_steps;           /* HairSolver.max_substeps: the cfl's steps per frame at most */
    double min_segment;      /* m: the shortest segment of the rest groom */
    int cfl_steps;           /* steps of the frame the cfl cut short */
    int capped_steps;        /* of them, steps max_substeps kept longer than the cfl asked */
    int last_steps, last_cfl_steps; /* the last frame's steps taken and cfl-cut steps */
    int reached;             /* of the frame's substep ends t0 + k (t1 − t0)/substeps, the last the clock reached */
    int steps;               /* steps taken in the frame (more than substeps when another solver cut them) */
    int not_converged_steps;
    double seconds;          /* wall time of the frame's steps */
    DrRodStats frame;        /* the frame being advanced, summed over its steps */
    double *fint;            /* per DOF: the constraints' forces over a step (the scalp's work) */
    double scalp_work;       /* J, done on the strands through their held DOFs in the frame */
    double last_scalp_work;  /* the last frame's */
    double speed_prev;       /* max |v| after the last step (at the frame's start: of the state then) */
    double speed_growth;     /* the frame's largest step-to-step ratio of max |v| (DrHairFrameStats) */
    double last_speed, last_speed_growth; /* the last frame's */
    DrRodStats last;         /* the last frame's */
    DrHairFrameStats last_wet; /* the last frame's wet figures */
    int not_converged;
    /* the stability watch, where nothing outside works on the hair: no scalp motion, only static colliders */
    WorldWatch watch;
    bool watched;
    bool watch_started;      /* a frame's end gave the reference (the first frame after building or resuming) */
    double drop;             /* J: the weight of the hair lifted by its longest strand, what it can release */
} WorldHair;

static void wet_destroy(WorldWet **wp)
{
    WorldWet *w = *wp;
    if (!w) return;
    dr_bridges_destroy(&w->bridges);
    dr_film_destroy(&w->film);
    dr_exchange_destroy(&w->exchange);
    free(w->v_start);
    free(w->accel);
    free(w->submerged);
    for (int k = 0; k < 2; k++) dr_cohesion_destroy(&w->tables[k]);
    void *a[] = {w->radius, w->thickness, w->batch, w->group, w->mask, w->self, w->held, w->force, w->dfdv,
                 w->block_dof, w->block, w->x_old, w->dV, w->heights};
    for (size_t k = 0; k < sizeof a / sizeof a[0]; k++) free(a[k]);
    free(w);
    *wp = NULL;
}

static void hair_destroy(void *self)
{
    WorldHair *h = self;
    if (!h) return;
    wet_destroy(&h->wet);
    if (h->cpl) {
        WorldCouple *k = h->cpl;
        free(k->laws); free(k->law); free(k->slender); free(k->volume); free(k->diameter); free(k->coupled);
        free(k->mass); free(k->pending); free(k->next); free(k->carried); free(k->impulse); free(k->gradp);
        free(k->force); free(k->dfdv); free(k->block_dof); free(k->block);
        free(k);
    }
    dr_rod_set_destroy(&h->rods);
    dr_lag_destroy(&h->system);
    free(h->fint);
    for (int k = 0; k < h->ncross; k++) free(h->cross[k].batch_on);
    free(h->cross);
    free(h->skip);
    for (int i = 0; h->keys && i < h->nelements; i++) free(h->keys[i]);
    free(h->keys);
    free(h->carrier);
    free(h->nkeys);
    free(h->elements);
    free(h->cgroup);
    free(h->cmask);
    free(h->cself);
    free(h->cthick);
    free(h->poses);
    free(h->colliders);
    free(h);
}

/* Which hair elements' strands touch, and with what response, in a scene with collision elements: batch b is group bit
   b, its mask holds the bits of the batches an edge_edge collision element pairs it with (itself: self_contact), and
   pairs[a·B + b] that element's CollisionResponse, each strand thickened by its thickness (as two elements that each
   have a CollisionResponse). The thickness bridges keep (per element) is its own pair's, else the largest of its pairs'.
   Without collision elements pairs stays NULL and the elements' own CollisionGroup and CollisionResponse apply. */
static DrStatus collision_elements(const DrScene *scene, WorldHair *h, DrRodBatch *batches, DrRodPairResponse **pairs,
                                   DrError *err)
{
    int B = h->nelements;
    *pairs = NULL;
    if (dr_scene_count_kind(scene, DR_ELEMENT_COLLISION) == 0) return DR_OK;
    assert(B <= 31); /* the scene's rules */
    DR_TRY(dr_calloc((size_t)B * (size_t)B, sizeof **pairs, pairs, err));
    for (int a = 0; a < B; a++) {
        batches[a].group = 1u << a;
        batches[a].mask = 0;
        batches[a].self_contact = false;
        double own = -1.0, most = 0.0;
        for (int b = 0; b < B; b++) {
            const DrElement *ce = dr_scene_collision(scene, h->elements[a]->name, h->elements[b]->name, "edge_edge");
            if (!ce) continue;
            const DrComponent *r = dr_element_component(ce, "CollisionResponse");
            DrRodPairResponse *p = &(*pairs)[(size_t)a * (size_t)B + (size_t)b];
            *p = (DrRodPairResponse){dr_component_num(r, "stiffness"), dr_component_num(r, "friction"),
                                     dr_component_num(r, "thickness"), dr_component_num(r, "damping")};
            if (a == b) {
                batches[a].self_contact = true;
                own = p->thickness;
            } else {
                batches[a].mask |= 1u << b;
            }
            most = fmax(most, p->thickness);
        }
        batches[a].contact_thickness = own >= 0 ? own : most;
    }
    return DR_OK;
}

/* The target of the rigid attachment element that carries hair element e's roots (the scene allows one), or NULL. */
static const DrElement *root_carrier(const DrScene *scene, const DrElement *e)
{
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *a = dr_scene_element(scene, i);
        if (a->kind != DR_ELEMENT_ATTACHMENT) continue;
        const DrComponent *ac = dr_element_component(a, "Attachment");
        const char *const *m = NULL;
        int n = dr_component_names(ac, "members", &m);
        for (int k = 0; k < n; k++)
            if (strcmp(m[k], e->name) == 0) return dr_scene_find(scene, dr_component_str(ac, "target"));
    }
    return NULL;
}

/* Each element's scalp pose at t: its Motion's, or its rigid attachment's target's. */
static void scalp_poses(WorldHair *h, const WorldCtx *c, double t)
{
    for (int b = 0; b < h->nelements; b++)
        if (!h->carrier[b] || !world_kinematics_carry(c->kin, h->carrier[b], t, &h->poses[b]))
            h->poses[b] = dr_motion_pose(h->keys[b], h->nkeys[b], t);
}

/* Hair against cloth: the system goes to the link, for the cloth adapter to make the panels in; one set of rows per
   panel and response, with its collision element's CollisionResponse where written, else the hair's collider
   stiffness (1e4 N/m), the panel's Collider.thickness (1 mm when 0, as the panel keeps from colliders) and the larger
   of the hair's and the panel's Collider.friction; damping as written (0: none). */
static DrStatus link_cloth(const WorldCtx *c, WorldHair *h, DrError *err)
{
    WorldClothLink *link = world_kinematics_cloth_link(c->kin);
    if (link->n == 0) return DR_OK;
    h->link = link;
    link->system = h->system;
    int B = h->nelements;
    DR_TRY(dr_calloc((size_t)(link->n * B), sizeof *h->cross, &h->cross, err));
    for (int k = 0; k < link->n; k++) {
        const DrElement *pe = link->panels[k].element;
        for (int b = 0; b < B; b++) {
            const DrElement *ce = dr_scene_collision(c->scene, h->elements[b]->name, pe->name, "vertex_face");
            if (!ce) continue;
            const DrComponent *r = dr_element_component(ce, "CollisionResponse");
            const DrComponent *pc = dr_element_component(pe, "Collider");
            double th = dr_component_num(pc, "thickness");
            double mu = fmax(dr_component_num(pc, "friction"),
                             dr_component_num(dr_element_component(h->elements[b], "Collider"), "friction"));
            DrContactResponse rsp = {
                dr_component_is_set(r, "thickness") ? dr_component_num(r, "thickness") : th > 0 ? th : 1e-3,
                dr_component_is_set(r, "stiffness") ? dr_component_num(r, "stiffness") : 1e4,
                dr_component_is_set(r, "friction") ? dr_component_num(r, "friction") : mu,
                dr_component_num(r, "damping")};
            int j = 0;
            while (j < h->ncross && !(h->cross[j].panel == k && memcmp(&h->cross[j].response, &rsp, sizeof rsp) == 0)) j++;
            if (j == h->ncross) {
                h->cross[j] = (struct HairCross){k, rsp, NULL};
                DR_TRY(dr_calloc((size_t)B, 1, &h->cross[j].batch_on, err));
                h->ncross++;
            }
            h->cross[j].batch_on[b] = 1;
        }
    }
    DR_TRY(dr_calloc((size_t)dr_rod_set_state(h->rods).nverts, 1, &h->skip, err));
    return DR_OK;
}

/* The panels' DOFs (once, after the cloth adapter made them) and their steps' start: their DOF ranges. */
static DrStatus panels_predict_dofs(WorldHair *h, double dt, DrError *err)
{
    for (int k = 0; h->link && k < h->link->n; k++) {
        WorldClothPanelLink *pl = &h->link->panels[k];
        if (!pl->dof) {
            int V = dr_cloth_vertex_count(pl->cloth);
            DR_TRY(dr_calloc((size_t)V, sizeof(int), &pl->dof, err));
            for (int v = 0; v < V; v++) pl->dof[v] = dr_cloth_vertex_dof(pl->cloth, v);
        }
        DR_TRY(dr_error_prefix(dr_cloth_predict_dofs(pl->cloth, dt, h->link->colliders, h->link->ncolliders, err), err,
                               "cloth '%s'", pl->element->name));
    }
    return DR_OK;
}

/* After the system began: the panels' groups, and the rows between the hair's vertices and each panel's triangles
   (contact.h), the panel as it stands at the step's start. */
static DrStatus panels_predict_groups(WorldHair *h, double dt, DrError *err)
{
    if (!h->link) return DR_OK;
    h->cross_contacts = 0;
    for (int k = 0; k < h->link->n; k++) {
        WorldClothPanelLink *pl = &h->link->panels[k];
        DR_TRY(dr_cloth_predict_groups(pl->cloth, err));
        double reach = 0.02;
        DR_TRY(dr_tri_field_build(pl->field, dr_cloth_triangle_count(pl->cloth), dr_cloth_triangles(pl->cloth),
                                  dr_cloth_positions(pl->cloth), dr_cloth_velocities(pl->cloth), reach, err));
    }
    DrRodState rs = dr_rod_set_state(h->rods);
    const int *vdof = dr_rod_set_vertex_dofs(h->rods);
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(h->system, &d, err));
    for (int j = 0; j < h->ncross; j++) {
        const struct HairCross *x = &h->cross[j];
        WorldClothPanelLink *pl = &h->link->panels[x->panel];
        for (int b = 0; b < rs.nbatches; b++)
            for (int s = rs.batch_offsets[b]; s < rs.batch_offsets[b + 1]; s++)
                for (int i = rs.offsets[s]; i < rs.offsets[s + 1]; i++)
                    h->skip[i] = !x->batch_on[b] || d.prescribed[vdof[i]];
        DrContactPoints pts = {rs.nverts, rs.x, rs.v, rs.vertex_radius, vdof, h->skip};
        DrContactSheet sh = {pl->field, dr_cloth_triangles(pl->cloth), dr_cloth_positions(pl->cloth),
                             dr_cloth_velocities(pl->cloth), pl->dof};
        int n = 0;
        DR_TRY(dr_contact_points_sheet(h->system, dt, &pts, &sh, &x->response, &n, err));
        h->cross_contacts += n;
    }
    return DR_OK;
}

static DrStatus build_hair(const WorldCtx *c, WorldHair *h, int n, DrError *err)
{
    const DrScene *scene = c->scene;
    DR_TRY(dr_calloc((size_t)n, sizeof *h->elements, &h->elements, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *h->keys, &h->keys, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *h->nkeys, &h->nkeys, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *h->carrier, &h->carrier, err));
    DR_TRY(dr_calloc((size_t)n, sizeof *h->poses, &h->poses, err));
    DrGroom *grooms = NULL;
    DrRodBatch *batches = NULL;
    DR_TRY(dr_calloc((size_t)n, sizeof *grooms, &grooms, err));
    DrRodRoots *roots = NULL; /* per element: Groom.roots */
    DrStatus s = dr_calloc((size_t)n, sizeof *batches, &batches, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof *roots, &roots, err);
    const DrComponent *solver = NULL;
    bool contact = false;
    for (int i = 0; s == DR_OK && i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_HAIR) continue;
        int b = h->nelements++;
        h->elements[b] = e;
        solver = dr_element_component(e, "HairSolver"); /* equal on every hair element (scene rule) */
        s = dr_stage_load_groom(e, &grooms[b], err);
        if (s != DR_OK) break;
        const DrComponent *rm = dr_element_component(e, "RodMaterial");
        const DrComponent *cg = dr_element_component(e, "CollisionGroup");
        const DrComponent *cr = dr_element_component(e, "CollisionResponse");
        const DrComponent *co = dr_element_component(e, "Collider");
        DrRodBatch *bt = &batches[b];
        bt->groom = &grooms[b];
        bt->material = (DrRodMaterial){dr_component_num(rm, "radius"), dr_component_num(rm, "density"),
                                       dr_component_num(rm, "youngs_modulus"), dr_component_num(rm, "shear_modulus"),
                                       dr_component_num(rm, "damping"), dr_component_num(rm, "tip_radius")};
        bt->group = 1u << dr_component_int(cg, "group");
        bt->mask = (unsigned)dr_component_int(cg, "collides_with");
        bt->self_contact = dr_component_bool(cg, "self_collision");
        bt->contact_stiffness = dr_component_num(cr, "stiffness");
        bt->contact_friction = dr_component_num(cr, "friction");
        bt->contact_thickness = dr_component_num(cr, "thickness");
        bt->contact_damping = dr_component_num(cr, "damping");
        bt->collider_friction = dr_component_num(co, "friction");
        bt->collider_thickness = dr_component_num(co, "thickness");
        const char *rt = dr_component_str(dr_element_component(e, "Groom"), "roots");
        roots[b] = strcmp(rt, "free") == 0     ? DR_ROD_ROOTS_FREE
                   : strcmp(rt, "pinned") == 0 ? DR_ROD_ROOTS_PINNED
                                               : DR_ROD_ROOTS_CLAMPED;

        /* scalp motion keys: times in s, angles in radians, as the colliders take them */
        if (s == DR_OK) s = dr_stage_motion_keys(e, c->first_frame, c->fps, &h->keys[b], &h->nkeys[b], err);
        if (s == DR_OK && h->nkeys[b] > 0) h->any_motion = true;
        h->carrier[b] = root_carrier(scene, e);
        if (h->carrier[b]) h->any_motion = true;
    }
    DrRodPairResponse *pairs = NULL;
    if (s == DR_OK) s = collision_elements(scene, h, batches, &pairs, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof *h->cgroup, &h->cgroup, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof *h->cmask, &h->cmask, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof *h->cself, &h->cself, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof *h->cthick, &h->cthick, err);
    for (int b = 0; s == DR_OK && b < h->nelements; b++) {
        const DrRodBatch *bt = &batches[b];
        h->cgroup[b] = bt->group;
        h->cmask[b] = bt->mask;
        h->cself[b] = bt->self_contact;
        h->cthick[b] = bt->contact_thickness;
        /* with the elements' own filters, any two elements may touch (their masks decide); with collision elements,
           only the pairs they list */
        contact = contact || bt->self_contact || (pairs ? bt->mask != 0 : h->nelements > 1);
    }
    if (s == DR_OK) {
        DrRodSetDesc d;
        dr_rod_set_desc_default(&d);
        d.gravity = c->gravity;
        d.batch_roots = roots;
        d.hair_contact = contact;
        d.pairs = pairs;
        d.geometric_stiffness = dr_component_bool(solver, "geometric_stiffness");
        const char *pc = dr_component_str(solver, "preconditioner");
        d.solver.precond = strcmp(pc, "jacobi") == 0    ? DR_LAG_PRECOND_JACOBI
                           : strcmp(pc, "none") == 0    ? DR_LAG_PRECOND_NONE
                           : strcmp(pc, "cluster") == 0 ? DR_LAG_PRECOND_CLUSTER
                                                        : DR_LAG_PRECOND_BLOCK;
        d.solver.tol = dr_component_num(solver, "tolerance");
        d.solver.max_iter = dr_component_int(solver, "max_iterations");
        h->substeps = dr_component_int(solver, "substeps");
        h->cfl = dr_component_num(solver, "cfl");
        h->max_steps = dr_component_int(solver, "max_substeps");
        s = dr_lag_create(&d.solver, &h->system, err);
        d.system = h->system;
        if (s == DR_OK) s = dr_rod_set_create(&d, batches, h->nelements, &h->rods, err);
        if (s != DR_OK && h->nelements == 1) s = dr_error_prefix(s, err, "%s.Groom", h->elements[0]->name);
    }
    for (int b = 0; b < n; b++) dr_groom_free(&grooms[b]);
    free(grooms);
    free(batches);
    free(roots);
    free(pairs);
    if (s != DR_OK) return s;
    /* the live colliders, then the bem_solid bodies' deformed surfaces and the MPM solids' particles (frictionless
       themselves: the hair's own Collider.friction applies), all where the kinematics put them at every clock
       step's end */
    const DrCollider *const *live = NULL;
    int nlive = world_kinematics_colliders(c->kin, &live);
    WorldPosedCollider *posed = world_kinematics_posed(c->kin), *bodies = NULL;
    int nbodies = world_kinematics_bodies_posed(c->kin, &bodies);
    DrRodCollider mpm = {0};
    bool with_mpm = world_kinematics_mpm_surface(c->kin, &mpm.sdf, &mpm.velocity_at, &mpm.ctx);
    if (nlive + nbodies + with_mpm > 0) {
        DR_TRY(dr_calloc((size_t)(nlive + nbodies + 1), sizeof *h->colliders, &h->colliders, err));
        for (int k = 0; k < nlive; k++)
            h->colliders[k] = (DrRodCollider){world_posed_sdf, world_posed_velocity, &posed[k],
                                              dr_collider_friction(live[k]), 0};
        for (int k = 0; k < nbodies; k++)
            h->colliders[nlive + k] = (DrRodCollider){world_posed_sdf, world_posed_velocity, &bodies[k], 0, 0};
        h->ncolliders = nlive + nbodies;
        if (with_mpm) h->colliders[h->ncolliders++] = mpm; /* the MPM solids' particles as a surface */
    }
    world_watch_init(&h->watch, scene);
    h->watched = !h->any_motion && nbodies == 0 && !with_mpm && world_kinematics_cloth_link(c->kin)->n == 0;
    for (int k = 0; k < nlive; k++) h->watched = h->watched && dr_collider_static(live[k]);
    DrRodState rs = dr_rod_set_state(h->rods);
    double mass = 0.0, longest = 0.0;
    h->min_segment = INFINITY;
    for (int v = 0; v < rs.nverts; v++) mass += rs.mass[v];
    for (int k = 0; k < rs.nstrands; k++) {
        double len = 0.0;
        for (int v = rs.offsets[k]; v + 1 < rs.offsets[k + 1]; v++) {
            DrVec3 a = dr_v3(rs.x[3 * v], rs.x[3 * v + 1], rs.x[3 * v + 2]);
            DrVec3 b = dr_v3(rs.x[3 * v + 3], rs.x[3 * v + 4], rs.x[3 * v + 5]);
            double l = dr_v3_norm(dr_v3_sub(b, a));
            len += l;
            if (l > 0) h->min_segment = fmin(h->min_segment, l);
        }
        longest = fmax(longest, len);
    }
    h->drop = mass * dr_v3_norm(c->gravity) * longest;
    return DR_OK;
}

/* P of the liquid's particles, of the strands (with the coupled loop's impulses given them but not yet applied,
   impulse: 3 per vertex or NULL) and of the film now (parts and total, kg m/s) and their mass, kg (WorldMomentum). In a
   fixed order: the same state gives the same bits. */
static DrVec3 ledger_measure(WorldWet *w, const DrRodState *rs, const double *impulse, DrVec3 *liquid, DrVec3 *hair,
                             DrVec3 *film, double *mass)
{
    const DrLiquid *L = w->link->liquid;
    const DrLiquidState *st = dr_liquid_state(L);
    double pm = dr_liquid_particle_mass(L), v0 = dr_liquid_nominal_volume(L), m_all = 0.0;
    DrVec3 pl = dr_v3(0, 0, 0), ph = dr_v3(0, 0, 0);
    for (long p = 0; p < st->n; p++) {
        double m = pm * (st->vol[p] / v0);
        const double *v = st->v + 3 * p;
        m_all += m;
        pl = dr_v3_add(pl, dr_v3(m * v[0], m * v[1], m * v[2]));
    }
    for (int i = 0; i < rs->nverts; i++) {
        double m = rs->mass[i];
        const double *v = rs->v + 3 * i;
        m_all += m;
        ph = dr_v3_add(ph, dr_v3(m * v[0], m * v[1], m * v[2]));
        if (impulse) ph = dr_v3_add(ph, dr_v3(impulse[3 * i], impulse[3 * i + 1], impulse[3 * i + 2]));
    }
    DrFilmStats fs = {0};
    dr_film_measure(w->film, rs->x, rs->v, &fs);
    m_all += w->set.film.density * (fs.volume + fs.pools);
    *liquid = pl;
    *hair = ph;
    *film = fs.momentum;
    *mass = m_all;
    return dr_v3_add(dr_v3_add(pl, ph), fs.momentum);
}

/* The ledger's reference: the state now (the bake's start, or a restored checkpoint). */
static void ledger_start(WorldWet *w, const DrRodState *rs, const double *impulse)
{
    WorldMomentum *m = &w->momentum;
    m->prev = ledger_measure(w, rs, impulse, &m->liquid, &m->hair, &m->film, &m->mass);
}

/* The wet hair: the cohesion tables from the cache (bake refuses to start without them: "run precompute"), the film
   on every strand (Film.initial_ratio of its element; 1, dry, on a dry element's strands), the bridges. */
static DrStatus build_wet(const WorldCtx *c, WorldHair *h, const char *cache_root, DrError *err)
{
    DrStageWet set;
    DR_TRY(dr_stage_wet_settings(c->scene, &set, err));
    if (!set.wet) return DR_OK;
    WorldWet *w = NULL;
    DR_TRY(dr_calloc(1, sizeof *w, &w, err));
    h->wet = w;
    w->set = set;
    w->set.film.gravity = c->gravity;
    for (int k = 0; k < 2; k++)
        DR_TRY(dr_error_prefix(dr_cohesion_load(cache_root, &set.tables[k], &w->tables[k], err), err, "%s.Cohesion",
                               set.element->name));
    DrRodState rs = dr_rod_set_state(h->rods);
    int S = rs.nstrands, V = rs.nverts, B = rs.nbatches;
    DR_TRY(dr_calloc((size_t)V, sizeof(double), &w->radius, err));
    DR_TRY(dr_calloc((size_t)S, sizeof(double), &w->thickness, err));
    DR_TRY(dr_calloc((size_t)S, sizeof(int), &w->batch, err));
    DR_TRY(dr_calloc((size_t)B, sizeof(unsigned), &w->group, err));
    DR_TRY(dr_calloc((size_t)B, sizeof(unsigned), &w->mask, err));
    DR_TRY(dr_calloc((size_t)B, 1, &w->self, err));
    DR_TRY(dr_calloc((size_t)V, 1, &w->held, err));
    DR_TRY(dr_calloc(3 * (size_t)V, sizeof(double), &w->force, err));
    DR_TRY(dr_calloc(9 * (size_t)V, sizeof(double), &w->dfdv, err));
    DR_TRY(dr_calloc((size_t)V, sizeof(int), &w->block_dof, err));
    DR_TRY(dr_calloc(9 * (size_t)V, sizeof(double), &w->block, err));
    DR_TRY(dr_calloc(3 * (size_t)V, sizeof(double), &w->x_old, err));
    DR_TRY(dr_calloc((size_t)V, sizeof(double), &w->dV, err));
    DR_TRY(dr_calloc((size_t)V, sizeof(double), &w->heights, err));
    double *ratio = NULL;
    DR_TRY(dr_calloc((size_t)S, sizeof(double), &ratio, err));
    for (int b = 0; b < B; b++) {
        const DrElement *e = h->elements[b];
        w->group[b] = h->cgroup[b];
        w->mask[b] = h->cmask[b];
        w->self[b] = h->cself[b];
        bool wet = dr_component_present(dr_element_component(e, "Wetting"));
        double r0 = wet ? dr_component_num(dr_element_component(e, "Film"), "initial_ratio") : 1.0;
        double tk = h->cthick[b];
        for (int k = rs.batch_offsets[b]; k < rs.batch_offsets[b + 1]; k++) {
            w->batch[k] = b;
            w->thickness[k] = tk;
            ratio[k] = r0;
            for (int i = rs.offsets[k]; i < rs.offsets[k + 1]; i++) w->radius[i] = rs.vertex_radius[i];
        }
    }
    DrStatus st = dr_film_create(&w->set.film, S, rs.offsets, w->radius, rs.x, ratio, &w->film, err);
    free(ratio);
    DR_TRY(dr_error_prefix(st, err, "%s.Film", set.element->name));
    DR_TRY(dr_error_prefix(dr_bridges_create(&w->set.bridges, w->tables[0], w->tables[1], &w->bridges, err), err,
                           "%s.Cohesion", set.element->name));
    /* capture and dripping, beside a liquid */
    WorldWetLink *link = world_kinematics_wet(c->kin);
    if ((set.capture || set.dripping) && link->liquid) {
        DrCaptureDesc cd = set.capture_desc;
        DrDripDesc dd = set.drip_desc;
        if (!set.capture) cd.rate = 0.0;
        if (!set.dripping) dd.middle = dd.root = dd.tip = false;
        DR_TRY(dr_error_prefix(dr_exchange_create(&cd, &dd, &w->exchange, err), err, "%s.Capture/Dripping",
                               set.element->name));
        DR_TRY(dr_calloc(3 * (size_t)V, sizeof(double), &w->v_start, err));
        DR_TRY(dr_calloc(3 * (size_t)V, sizeof(double), &w->accel, err));
        DR_TRY(dr_calloc((size_t)V, sizeof(double), &w->submerged, err));
        *link = (WorldWetLink){.on = true, .liquid = link->liquid, .film = w->film, .exchange = w->exchange,
                               .x = rs.x, .v = rs.v, .accel = NULL, .mass = rs.mass, .submerged = w->submerged,
                               .nverts = V};
        w->link = link;
        DR_TRY(world_wet_start(link, c->t0, err)); /* a resumed bake reads the ledger back */
        ledger_start(w, &rs, NULL);                /* and measures its momentum from the restored state */
    }
    return DR_OK;
}

/* The strands as the bridges see them, now. */
static DrBridgeStrands wet_strands(const WorldHair *h)
{
    const WorldWet *w = h->wet;
    DrRodState rs = dr_rod_set_state(h->rods);
    DrFilmState fs = dr_film_state(w->film);
    return (DrBridgeStrands){.nstrands = rs.nstrands, .nverts = rs.nverts, .offsets = rs.offsets, .x = rs.x,
                             .radius = w->radius, .volume = fs.volume, .vertex_dof = dr_rod_set_vertex_dofs(h->rods),
                             .held = w->held_known ? w->held : NULL, .thickness = w->thickness,
                             .submerged = w->link ? w->submerged : NULL, .batch = w->batch,
                             .group = w->group, .mask = w->mask, .self = w->self};
}

/* The largest |v| of any vertex (m/s). */
static double max_speed(const DrRodState *rs)
{
    double m = 0;
    for (int i = 0; i < rs->nverts; i++) {
        const double *v = rs->v + 3 * i;
        m = fmax(m, sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]));
    }
    return m;
}

/* ---- the clock --------------------------------------------------------------------------------------------------
 * The hair takes HairSolver.substeps equal steps per frame; a step of the world's clock that ends first (a faster
 * solver, a BEM step end) cuts the hair's step there, and the hair goes on to the same next substep end. Within a
 * substep the hair takes more, equal steps when its fastest vertex plus the fastest film on a strand would move more
 * than HairSolver.cfl shortest segments in one: contacts and bridges are found at a step's start and the film's load
 * is linearised there, so a step that carries a strand past its neighbours (or its film far along it) acts on stale
 * geometry. The speeds are those of the state at the step's start, so the steps are a function of the state alone (a
 * resumed bake takes the ones an uninterrupted one does). */

static double substep_end(const WorldHair *h, const WorldCtx *c, int k)
{
    return k == h->substeps ? c->t1 : c->t0 + k * ((c->t1 - c->t0) / h->substeps);
}

static void hair_begin_frame(void *self, const WorldCtx *c)
{
    (void)c;
    WorldHair *h = self;
    h->reached = 0;
    h->steps = 0;
    h->cfl_steps = 0;
    h->capped_steps = 0;
    h->not_converged_steps = 0;
    h->seconds = 0.0;
    h->scalp_work = 0.0;
    DrRodState rs = dr_rod_set_state(h->rods);
    h->speed_prev = max_speed(&rs); /* from the state, so that a resumed bake reports what an uninterrupted one does */
    h->speed_growth = 0.0;
    memset(&h->frame, 0, sizeof h->frame);
    if (h->wet) {
        memset(&h->wet->film_frame, 0, sizeof h->wet->film_frame);
        h->wet->cross_flow = 0;
        h->wet->seconds_film = h->wet->seconds_bridges = h->wet->seconds_cross_flow = 0;
        h->wet->film_pressure = dr_v3(0, 0, 0);
        WorldWetLink *l = h->wet->link;
        if (l) {
            l->captured = l->dripped = l->held = l->seconds = 0, l->drops = l->captured_particles = 0;
            l->captured_momentum = l->dripped_momentum = dr_v3(0, 0, 0);
            WorldMomentum *m = &h->wet->momentum;
            m->relative_max = m->residual_max = 0.0;
            m->external = dr_v3(0, 0, 0);
            m->steps = 0;
        }
    }
}

/* After every solver stepped from t to t_next, the liquid's exchange included (liquids come first): the momentum
   ledger's step. */
static DrStatus hair_step_last(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    (void)err;
    WorldHair *h = self;
    if (!h->wet || !h->wet->link) return DR_OK;
    WorldMomentum *m = &h->wet->momentum;
    DrRodState rs = dr_rod_set_state(h->rods);
    double mass;
    DrVec3 P = ledger_measure(h->wet, &rs, h->cpl ? h->cpl->next : NULL, &m->liquid, &m->hair, &m->film, &mass);
    DrVec3 ext = dr_v3_scale(c->gravity, m->mass * (t_next - t));
    double res = dr_v3_norm(dr_v3_sub(dr_v3_sub(P, m->prev), ext));
    double scale = fmax(fmax(dr_v3_norm(P), dr_v3_norm(m->prev)), 1e-300);
    /* fmax drops a NaN: a non-finite state is reported by the solvers' own checks */
    m->relative_max = fmax(m->relative_max, res / scale);
    m->residual_max = fmax(m->residual_max, res);
    m->external = dr_v3_add(m->external, ext);
    m->steps++;
    m->prev = P;
    m->mass = mass;
    return DR_OK;
}

/* m/s: the fastest vertex, plus the fastest film along its strand (wet hair) */
static double cfl_speed(WorldHair *h)
{
    DrRodState rs = dr_rod_set_state(h->rods);
    double v = max_speed(&rs);
    if (h->wet) {
        DrFilmState fs = dr_film_state(h->wet->film);
        double u = 0.0;
        for (int e = 0; e < fs.nedges; e++) u = fmax(u, fabs(fs.u[e]));
        v += u;
    }
    return v;
}

static DrStatus hair_next_time(void *self, const WorldCtx *c, double t, double *t_next, DrError *err)
{
    (void)err;
    WorldHair *h = self;
    double end = substep_end(h, c, h->reached < h->substeps ? h->reached + 1 : h->substeps);
    *t_next = end;
    double room = end - t;
    if (!(h->cfl > 0) || !(room > 0) || !isfinite(h->min_segment)) return DR_OK;
    double reach = h->cfl * h->min_segment; /* m a step may carry a vertex */
    double v = cfl_speed(h);
    if (!(v * room > reach)) return DR_OK;
    /* equal steps to the substep end, none shorter than a max_substeps-th of the frame (a non-finite speed gives
       that shortest step: the solve that follows reports the failure) */
    double floor_dt = (c->t1 - c->t0) / h->max_steps;
    double n = isfinite(v) ? ceil(v * room / reach) : INFINITY;
    double dt = room / n;
    if (dt < floor_dt) {
        dt = floor_dt;
        h->capped_steps++;
    }
    /* a remainder under a thousandth of the step is taken with it */
    if (dt >= room * (1.0 - 1e-3) || room - dt < 1e-3 * dt) return DR_OK;
    *t_next = t + dt;
    h->cfl_steps++;
    return DR_OK;
}

/* One step of the system: every model predicts (its DOFs, then, once the system has begun, its groups), one solve of
   the whole system (with the film's load and, coupled to a fluid, the coupling's), the multipliers, every model
   commits. In three parts so that the coupled loop (src/couple) can solve between predict and commit several times. */
static DrStatus system_predict(WorldHair *h, double dt, DrError *err)
{
    WorldWet *w = h->wet;
    DrRodState rs = dr_rod_set_state(h->rods);
    if (w && w->link) memcpy(w->v_start, rs.v, 3 * (size_t)rs.nverts * sizeof(double));
    DR_TRY(dr_rod_set_predict_dofs(h->rods, dt, h->any_motion ? h->poses : NULL, err));
    DR_TRY(panels_predict_dofs(h, dt, err));
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(h->system, &d, err));
    DR_TRY(dr_lag_begin(h->system, dt, d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, err));
    DR_TRY(dr_rod_set_predict_groups(h->rods, h->colliders, h->ncolliders, err));
    DR_TRY(panels_predict_groups(h, dt, err));
    if (w) {
        /* wet hair: the bridges (at the start of the step) join the system, the film rides on the strands */
        double tb = dr_time_now();
        if (!w->held_known) {
            DrRodSamples sm = dr_rod_set_samples(h->rods);
            memcpy(w->held, sm.held, (size_t)rs.nverts);
            w->held_known = true;
        }
        DrBridgeStrands bs = wet_strands(h);
        DR_TRY(dr_bridges_update(w->bridges, &bs, h->colliders, h->ncolliders, err));
        DR_TRY(dr_bridges_add_groups(w->bridges, &bs, h->system, dt, err));
        memset(w->force, 0, 3 * (size_t)rs.nverts * sizeof(double));
        memset(w->dfdv, 0, 9 * (size_t)rs.nverts * sizeof(double));
        dr_film_hair_load(w->film, rs.x, rs.v, dt, w->force, w->dfdv);
        memcpy(w->x_old, rs.x, 3 * (size_t)rs.nverts * sizeof(double));
        w->seconds_bridges += dr_time_now() - tb;
    }
    return DR_OK;
}

/* A solve of the predicted step with the film's load plus (cforce, cdfdv: per vertex, NULL for none) the coupling's. */
static DrStatus system_solve(WorldHair *h, const double *cforce, const double *cdfdv, DrError *err)
{
    WorldWet *w = h->wet;
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(h->system, &d, err));
    DrLagLoad load = {NULL, 0, NULL, NULL};
    bool loaded = false;
    if (cforce && h->cpl) {
        WorldCouple *k = h->cpl;
        int nv = dr_rod_set_state(h->rods).nverts;
        double inv_h = 1.0 / k->dt;
        for (long i = 0; i < 3L * nv; i++) k->force[i] = cforce[i] + (w ? w->force[i] : 0.0) + k->pending[i] * inv_h;
        for (long i = 0; i < 9L * nv; i++) k->dfdv[i] = cdfdv[i] + (w ? w->dfdv[i] : 0.0);
        dr_rod_set_fill_load(h->rods, k->force, k->dfdv, d.force, k->block_dof, k->block);
        load = (DrLagLoad){d.force, dr_rod_set_load_blocks(h->rods), k->block_dof, k->block};
        loaded = true;
    } else if (w) {
        dr_rod_set_fill_load(h->rods, w->force, w->dfdv, d.force, w->block_dof, w->block);
        load = (DrLagLoad){d.force, dr_rod_set_load_blocks(h->rods), w->block_dof, w->block};
        loaded = true;
    }
    double ts = dr_time_now();
    DrLagStats ls;
    DrStatus solved = dr_lag_solve_load(h->system, loaded ? &load : NULL, d.qdot_out, &ls, err);
    if (solved < 0) return solved;
    dr_rod_set_take(h->rods);
    for (int k = 0; h->link && k < h->link->n; k++) {
        dr_cloth_take(h->link->panels[k].cloth);
        h->link->panels[k].iterations += ls.iterations;
        h->link->panels[k].not_converged += ls.converged ? 0 : 1;
    }
    h->frame.iterations += ls.iterations;
    h->frame.residual = ls.residual;
    h->frame.not_converged += ls.converged ? 0 : 1;
    h->frame.indefinite_blocks += ls.indefinite_blocks;
    h->frame.seconds_solve += dr_time_now() - ts;
    return solved;
}

static DrStatus system_commit(WorldHair *h, double dt, DrError *err)
{
    WorldWet *w = h->wet;
    DrRodState rs = dr_rod_set_state(h->rods);
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(h->system, &d, err));
    dr_lag_update_multipliers(h->system, d.qdot_out);
    /* the work the scalp (and any held tip) does on the strands over the step: the force that gives each held DOF its
       prescribed velocity against gravity and the constraints, times its displacement h q̇₊ (the hair's DOFs only) */
    int n = dr_lag_dof_count(h->system);
    if (n > h->fint_cap) {
        DR_TRY(dr_realloc((size_t)n, sizeof(double), &h->fint, err));
        h->fint_cap = n;
    }
    memset(h->fint, 0, (size_t)n * sizeof(double));
    dr_lag_constraint_forces(h->system, d.qdot_out, h->fint);
    n = h->hair_dofs;
    for (int k = 0; k < n; k++)
        if (d.prescribed[k])
            h->scalp_work += (d.mass[k] * (d.qdot_out[k] - d.qdot[k]) - dt * (d.fext[k] + h->fint[k])) * d.qdot_out[k];
    DR_TRY(dr_rod_set_commit(h->rods, &h->frame, err));
    for (int k = 0; h->link && k < h->link->n; k++) {
        WorldClothPanelLink *pl = &h->link->panels[k];
        DR_TRY(dr_error_prefix(dr_cloth_commit(pl->cloth, &pl->last, err), err, "cloth '%s'", pl->element->name));
        pl->steps++;
    }
    if (w) {
        /* the film follows the strands' step and flows; then across the bridges */
        double tf = dr_time_now();
        DR_TRY(dr_film_step(w->film, w->x_old, rs.x, rs.v, rs.mass, w->held, dt, &w->film_frame, err));
        double tc = dr_time_now();
        w->seconds_film += tc - tf;
        DrBridgeStrands bs = wet_strands(h);
        DR_TRY(dr_bridges_cross_flow(w->bridges, &bs, dt, w->dV, err));
        DrBridgeStats bst;
        dr_bridges_stats(w->bridges, &bst);
        if (bst.cross_flow > 0) dr_film_exchange(w->film, rs.x, w->dV, rs.v, rs.mass);
        w->cross_flow += bst.cross_flow;
        w->seconds_cross_flow += dr_time_now() - tc;
        if (w->link) {
            /* the strands' acceleration over the step, which sets how much film they hold (dripping) */
            for (long i = 0; i < 3L * rs.nverts; i++) w->accel[i] = (rs.v[i] - w->v_start[i]) / dt;
            w->link->accel = w->accel;
        }
    }
    return DR_OK;
}

static DrStatus step_system(WorldHair *h, double dt, DrError *err)
{
    DR_TRY(system_predict(h, dt, err));
    DrStatus solved = system_solve(h, NULL, NULL, err);
    if (solved < 0) return solved;
    DR_TRY(system_commit(h, dt, err));
    return solved;
}

static DrStatus after_step(WorldHair *h, const WorldCtx *c, double t_next, DrStatus s);

static DrStatus hair_step(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    WorldHair *h = self;
    double t_start = dr_time_now();
    scalp_poses(h, c, t_next);
    DrStatus s = step_system(h, t_next - t, err);
    h->seconds += dr_time_now() - t_start;
    return after_step(h, c, t_next, s);
}

/* ---- the coupled step (src/couple): the hair as a solid of the loop ------------------------------------------ */

/* B_i of vertex i (wet.h): the film's load of the step holds −B_i/h in its velocity derivative. */
static void film_inertia(const WorldHair *h, int i, double B[9])
{
    const WorldWet *w = h->wet;
    for (int q = 0; q < 9; q++) B[q] = w ? -h->cpl->dt * w->dfdv[9 * i + q] : 0.0;
}

/* The elements are the vertices, weighed with the film they carry: the loop decides by an element's inertia whether
   the fluid or the element takes the explicit part of the exchange, and a correction given to the vertex alone would
   move the film's momentum across the strand with it unaccounted (and a thin strand under a heavy film would be
   given a velocity change its film's inertia never saw). */
static DrCoupleSamples couple_samples(void *ctx)
{
    WorldHair *h = ctx;
    WorldCouple *k = h->cpl;
    DrRodSamples sm = dr_rod_set_samples(h->rods);
    DrFilmState fs = h->wet ? dr_film_state(h->wet->film) : (DrFilmState){0};
    const int *off = h->wet ? dr_film_offsets(h->wet->film) : NULL; /* the rod set's strands */
    for (int st = 0; st < fs.nstrands; st++) /* the film, and the pools at their end vertices */
        for (int i = off[st]; i < off[st + 1]; i++) {
            bool on = k->coupled[k->law[i]];
            double pool = (i == off[st] ? fs.pool[2 * st] : 0.0) + (i == off[st + 1] - 1 ? fs.pool[2 * st + 1] : 0.0);
            k->carried[i] = on ? fs.volume[i] + pool : 0.0;
        }
    for (int i = 0; i < sm.n; i++) {
        bool on = k->coupled[k->law[i]];
        k->volume[i] = on ? M_PI * sm.radius[i] * sm.radius[i] * sm.length[i] : 0.0;
        k->diameter[i] = 2.0 * sm.radius[i];
        double B[9];
        film_inertia(h, i, B);
        k->mass[i] = sm.mass[i] + (B[0] + B[4] + B[8]) / 3.0;
    }
    return (DrCoupleSamples){sm.n, sm.x, sm.v, k->mass, k->volume, k->diameter, k->slender, sm.tangent, sm.held,
                             k->law, h->wet ? k->carried : NULL, h->wet ? k->impulse : NULL, NULL};
}

static DrStatus couple_solve(void *ctx, const double *force, const double *dforce_dv, DrError *err)
{
    WorldHair *h = ctx;
    DrStatus s = system_solve(h, force, dforce_dv, err);
    if (s == DR_WARN_NOT_CONVERGED) h->cpl->not_converged = true;
    return s == DR_WARN_NOT_CONVERGED ? DR_OK : s; /* counted in the frame's stats */
}

/* The loop's correction dv_i = Δp_i / k->mass[i] (couple.h), the impulse the loop's last projection gave vertex i
   beyond its solve. Added to the velocity at once, it bypassed the solve: a vertex next to a clamped root kicked by a
   fluid change of a few m/s stretched its edge and the next solve threw it at several times that. So the impulse is
   kept (k->next, in the checkpoint) and enters the next step's solves as the force Δp_i/h on the vertex, where the
   strand's constraints, contacts, film (m_i I + B_i) and implicit drag take it up. The momentum ledgers count it
   when given: the hair's momentum includes the impulses not yet applied. */
static void couple_correct(void *ctx, const double *dv)
{
    WorldHair *h = ctx;
    WorldCouple *k = h->cpl;
    int n = dr_rod_set_samples(h->rods).n;
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) k->next[3 * i + a] += k->mass[i] * dv[3 * i + a];
}

/* The bulk's pressure on the film and pools (DrCoupleSolid.pressure_gradient, dr_film_pressure): across the strand
   into the film's load of the step's solves, along it into the film's speed at its step, all of it into k->impulse for
   the loop's books. ∇p at the step's first projection: the iterations refine drag, not this. Weighted by each
   vertex's submersion s (the exchange's, which switches cohesion off), min(1, 2s): 0 where the particles fill at
   most half of the cells around the vertex, 1 from three quarters (well-mixed particles fill about 95 %, so a film
   deep in the bulk gets all of it). The film is in the bulk's pressure where the bulk surrounds it; a drop or a
   splash beside a strand in the air has a pressure whose gradient over a cell or two (up to 1e7 Pa/m as the default
   shot's fur swings through its drops) would fling a film of a fraction of the drop's mass. Without the exchange
   (Capture and Dripping both off) there is no submersion, and the film takes no pressure. */
static void couple_pressure(void *ctx, const double *gradp)
{
    WorldHair *h = ctx;
    WorldCouple *k = h->cpl;
    WorldWet *w = h->wet;
    DrRodState rs = dr_rod_set_state(h->rods);
    for (int i = 0; i < rs.nverts; i++) {
        double s = k->coupled[k->law[i]] && w->link ? fmin(1.0, 2.0 * w->submerged[i]) : 0.0;
        for (int a = 0; a < 3; a++) k->gradp[3 * i + a] = s * gradp[3 * i + a];
    }
    dr_film_pressure(w->film, w->x_old, k->gradp, k->dt, w->force, k->impulse);
    for (int i = 0; i < rs.nverts; i++)
        w->film_pressure = dr_v3_add(w->film_pressure, dr_v3(k->impulse[3 * i], k->impulse[3 * i + 1], k->impulse[3 * i + 2]));
}

/* The lift's limit (couple.h): m/(½ ξ_L (μV/D²) C_⊥) over the free vertices of elements with lift, V and the
   vertex's length from the current state. */
static double hair_solid_stable_dt(const void *self, double density, double viscosity)
{
    const WorldHair *h = self;
    const WorldCouple *k = h->cpl;
    bool any = false;
    for (int b = 0; b < h->nelements; b++) any = any || (k->coupled[b] && k->laws[b].lift > 0.0);
    if (!any) return INFINITY;
    DrRodState rs = dr_rod_set_state(h->rods);
    double dt = INFINITY;
    for (int st = 0; st < rs.nstrands; st++)
        for (int v = rs.offsets[st]; v < rs.offsets[st + 1]; v++) {
            const DrDragLaw *law = &k->laws[k->law[v]];
            if (!k->coupled[k->law[v]] || !(law->lift > 0.0)) continue;
            double len = 0.0;
            for (int e = v - 1; e <= v; e++) {
                if (e < rs.offsets[st] || e + 1 >= rs.offsets[st + 1]) continue;
                DrVec3 a = dr_v3(rs.x[3 * e], rs.x[3 * e + 1], rs.x[3 * e + 2]);
                DrVec3 c = dr_v3(rs.x[3 * e + 3], rs.x[3 * e + 4], rs.x[3 * e + 5]);
                len += 0.5 * dr_v3_norm(dr_v3_sub(c, a));
            }
            double r = rs.vertex_radius[v];
            DrDragSite site = {dr_v3(1, 0, 0), 2.0 * r, M_PI * r * r * len, k->slender[v], 0.0, false};
            double cp = viscosity * site.volume / (site.diameter * site.diameter) *
                        dr_drag_coefficient(law, 0, density, viscosity, &site, 0.0);
            double l = 0.5 * law->lift * cp;
            if (l > 0.0 && rs.mass[v] / l < dt) dt = rs.mass[v] / l;
        }
    return dt;
}

static bool hair_couples(const void *self) { return ((const WorldHair *)self)->cpl != NULL; }

static DrStatus hair_solid_predict(void *self, const WorldCtx *c, double t, double t_next, DrCoupleSolid *solid,
                                   DrError *err)
{
    WorldHair *h = self;
    h->cpl->dt = t_next - t;
    h->cpl->not_converged = false;
    size_t nv3 = 3 * (size_t)dr_rod_set_state(h->rods).nverts;
    memcpy(h->cpl->pending, h->cpl->next, nv3 * sizeof(double)); /* the last step's corrections act in this one */
    memset(h->cpl->next, 0, nv3 * sizeof(double));
    scalp_poses(h, c, t_next);
    double t_start = dr_time_now();
    DR_TRY(system_predict(h, t_next - t, err));
    h->seconds += dr_time_now() - t_start;
    memset(h->cpl->impulse, 0, nv3 * sizeof(double));
    *solid = (DrCoupleSolid){h, h->nelements, h->cpl->laws, couple_samples, couple_solve, couple_correct,
                             h->wet ? couple_pressure : NULL};
    return DR_OK;
}

static DrStatus hair_solid_commit(void *self, const WorldCtx *c, double t, double t_next, DrError *err)
{
    WorldHair *h = self;
    double t_start = dr_time_now();
    DrStatus s = system_commit(h, t_next - t, err);
    h->seconds += dr_time_now() - t_start;
    if (s < 0) return s;
    return after_step(h, c, t_next, h->cpl->not_converged ? DR_WARN_NOT_CONVERGED : DR_OK);
}

static DrStatus after_step(WorldHair *h, const WorldCtx *c, double t_next, DrStatus s)
{
    h->steps++;
    if (s == DR_WARN_NOT_CONVERGED) h->not_converged_steps++;
    else if (s != DR_OK) return s;
    /* the step-to-step growth of the largest speed: an instability shows as a jump of 10×–100× in one step */
    DrRodState rs = dr_rod_set_state(h->rods);
    double speed = max_speed(&rs);
    if (h->speed_prev > 0) h->speed_growth = fmax(h->speed_growth, speed / h->speed_prev);
    h->speed_prev = speed;
    /* reached when the clock ends on it, or (snapped to a BEM step end a rounding error away) a few ulps past it */
    if (h->reached < h->substeps && t_next >= substep_end(h, c, h->reached + 1) - 1e-9 * (c->t1 - c->t0)) h->reached++;
    return DR_OK;
}

static DrStatus hair_end_frame(void *self, const WorldCtx *c, DrFrameStats *stats, DrError *err)
{
    WorldHair *h = self;
    const DrRodStats *st = &h->frame;
    if (h->not_converged_steps)
        dr_log_warn("hair: %d of %d solves stopped at HairSolver.max_iterations (last relative residual %.2e); raise "
                    "max_iterations or substeps",
                    h->not_converged_steps, h->steps, st->residual);
    h->last = *st;
    h->last_cross = h->cross_contacts;
    h->last_scalp_work = h->scalp_work;
    h->last_speed = h->speed_prev;
    h->last_speed_growth = h->speed_growth;
    h->not_converged = h->not_converged_steps;
    h->last_steps = h->steps;
    h->last_cfl_steps = h->cfl_steps;
    if (h->capped_steps)
        dr_log_warn("hair: frame %d: %d hair steps were kept at HairSolver.max_substeps = %d a frame although the "
                    "strands (and their film) moved faster than HairSolver.cfl = %g shortest segments (%g m) per "
                    "step allows; raise max_substeps, or look for what drives the hair that fast",
                    c->frame, h->capped_steps, h->max_steps, h->cfl, h->min_segment);
    DrRodState rs = dr_rod_set_state(h->rods);
    DrHairFrameStats *b = &stats->hair;
    b->present = true;
    b->vertices = rs.nverts;
    b->substeps = h->steps;
    b->cg_iterations = st->iterations;
    b->residual = st->residual;
    b->not_converged = h->not_converged_steps;
    b->collider_contacts = st->collider_contacts;
    b->contacts = st->hair_contacts;
    b->cloth_contacts = h->cross_contacts;
    b->meets_cloth = h->link != NULL;
    b->kinetic_energy = st->kinetic;
    b->elastic_energy = st->elastic;
    b->gravity_energy = st->gravity_potential;
    b->scalp_work = h->scalp_work;
    b->max_speed = h->last_speed;
    b->max_speed_growth = h->last_speed_growth;
    b->seconds = h->seconds;
    if (h->wet) {
        WorldWet *w = h->wet;
        DrFilmStats fs = {0};
        dr_film_measure(w->film, rs.x, rs.v, &fs);
        DrBridgeStats bst;
        dr_bridges_stats(w->bridges, &bst);
        b->wet = true;
        b->film_volume = fs.volume;
        b->film_pressure_impulse = w->film_pressure;
        b->pool_volume = fs.pools;
        b->film_max_ratio = fs.max_ratio;
        b->film_kinetic_energy = fs.kinetic;
        /* the film's and pools' weight: −Σ ρ V g·x at their vertices */
        DrFilmState st = dr_film_state(w->film);
        double pe = 0;
        for (int k = 0; k < st.nstrands; k++) {
            int o = rs.offsets[k], e = rs.offsets[k + 1] - 1;
            for (int i = o; i <= e; i++) {
                double vol = st.volume[i] + (i == o ? st.pool[2 * k] : 0.0) + (i == e ? st.pool[2 * k + 1] : 0.0);
                pe -= w->set.film.density * vol * dr_v3_dot(c->gravity, dr_v3(rs.x[3 * i], rs.x[3 * i + 1], rs.x[3 * i + 2]));
            }
        }
        b->film_gravity_energy = pe;
        b->bridges = bst.bridges;
        b->solid_bridges = bst.solid_bridges;
        b->film_substeps = w->film_frame.substeps;
        b->cross_flow = w->cross_flow;
        b->seconds_film = w->seconds_film;
        b->seconds_bridges = w->seconds_bridges;
        b->seconds_cross_flow = w->seconds_cross_flow;
        if (w->link) {
            /* the volume ledger: the liquid's end_frame (earlier in the frame's end) booked its emitters and kill
               boxes into the link */
            const WorldWetLink *l = w->link;
            double bulk, film, pools;
            world_wet_volumes(l, &bulk, &film, &pools);
            b->exchange = true;
            b->captured = l->captured;
            b->dripped = l->dripped;
            b->captured_momentum = l->captured_momentum;
            b->dripped_momentum = l->dripped_momentum;
            b->drops = l->drops;
            b->captured_particles = l->captured_particles;
            b->held_back = l->held;
            b->ledger_bulk = bulk;
            b->ledger_emitted = l->emitted;
            b->ledger_removed = l->removed;
            b->ledger_total = bulk + film + pools + l->removed - l->emitted;
            b->ledger_initial = l->initial;
            /* relative to the volume there is (the initial may be 0: liquid that only emitters bring) */
            double scale = fmax(l->initial, bulk + film + pools + l->removed);
            b->ledger_error = scale > 0 ? (b->ledger_total - b->ledger_initial) / scale : 0.0;
            b->seconds_exchange = l->seconds;
            if (l->held > 0 && !w->warned_budget) {
                w->warned_budget = true;
                dr_log_warn("%s: frame %d: %.3g m^3 of film stayed on the strands because Dripping.budget = %ld drops "
                            "a step was reached; the strands may be blowing up (look at hair_max_speed_growth), or "
                            "raise Dripping.budget (warned once per bake)",
                            w->set.element->name, c->frame, l->held, w->set.drip_desc.budget);
            }
        }
        h->last_wet = *b;
        if (w->link) {
            WorldMomentum *m = &w->momentum;
            m->last_relative_max = m->relative_max;
            m->last_residual_max = m->residual_max;
            m->last_external = m->external;
            m->last_steps = m->steps;
            m->last_liquid = m->liquid;
            m->last_hair = m->hair;
            m->last_film = m->film;
        }
        if (!isfinite(fs.volume) || !isfinite(fs.kinetic))
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "%s: the film on the strands became non-finite in frame %d (volume %g m^3); lower "
                                "Film.substeps' step (raise Film.substeps) or HairSolver.substeps",
                                w->set.element->name, c->frame, fs.volume);
    }
    /* Wet hair is not watched: its bridges release surface energy the ledger does not hold (a clump gains kinetic
       energy from cohesion), and a film that fails is caught above. */
    if (!h->watched || h->wet) return DR_OK;
    /* the energy after the frame's last step; the first frame after building or resuming gives the reference */
    WorldEnergy e = {0};
    e.energy = st->kinetic + st->elastic + st->gravity_potential;
    e.available = st->kinetic + st->elastic + h->drop;
    e.floor = 1e-12 + 1e-6 * h->drop;
    if (!h->watch_started) {
        h->watch_started = true;
        world_watch_start(&h->watch, c->frame + 1, &e);
        return DR_OK;
    }
    char who[200];
    if (h->nelements == 1) snprintf(who, sizeof who, "hair '%s'", h->elements[0]->name);
    else snprintf(who, sizeof who, "the %d hair elements (solved together)", h->nelements);
    return world_watch_energy(&h->watch, c, &e, who,
                              "raise HairSolver.substeps (smaller hair steps) or HairSolver.max_iterations", err);
}

/* ---- files ------------------------------------------------------------------------------------------------- */

/* The film and the bridge set: what a bit-identical continuation of wet hair needs. */
static DrStatus wet_write_checkpoint(const WorldWet *w, DrH5 *hf, DrError *err)
{
    DrFilmState fs = dr_film_state(w->film);
    DR_TRY(dr_h5_write_f64(hf, "/hair_solver/film_volume", 1, (uint64_t[]){(uint64_t)fs.nverts}, fs.volume, "m^3",
                           false, err));
    DR_TRY(dr_h5_write_f64(hf, "/hair_solver/film_velocity", 1, (uint64_t[]){(uint64_t)fs.nedges}, fs.u, "m/s",
                           false, err));
    DR_TRY(dr_h5_write_f64(hf, "/hair_solver/film_pools", 2, (uint64_t[]){(uint64_t)fs.nstrands, 2}, fs.pool, "m^3",
                           false, err));
    DR_TRY(dr_h5_write_f64(hf, "/hair_solver/film_strand_speed", 1, (uint64_t[]){(uint64_t)fs.nedges},
                           fs.strand_speed, "m/s", false, err));
    int n = dr_bridges_count(w->bridges);
    int *vs = NULL;
    int64_t *pairs = NULL;
    DR_TRY(dr_calloc(2 * (size_t)n + 2, sizeof(int), &vs, err));
    DrStatus s = dr_calloc(2 * (size_t)n + 2, sizeof(int64_t), &pairs, err);
    if (s == DR_OK) {
        dr_bridges_get(w->bridges, vs, vs + n);
        for (int k = 0; k < n; k++) {
            pairs[2 * k] = vs[k];
            pairs[2 * k + 1] = vs[n + k];
        }
        s = dr_h5_write_i64(hf, "/hair_solver/bridges", 2, (uint64_t[]){(uint64_t)n, 2}, pairs, "1", false, err);
    }
    free(vs);
    free(pairs);
    if (s != DR_OK || !w->link) return s;
    /* capture and dripping: the strands' last acceleration, the ledger since the bake's start and the last exchange */
    const WorldWetLink *l = w->link;
    DR_TRY(dr_h5_write_f64(hf, "/hair_solver/acceleration", 1, (uint64_t[]){3 * (uint64_t)fs.nverts}, w->accel,
                           "m/s^2", false, err));
    DR_TRY(dr_h5_write_f64(hf, "/hair_solver/submerged", 1, (uint64_t[]){(uint64_t)fs.nverts}, w->submerged, "1",
                           false, err));
    /* whether the strands have stepped (an acceleration), the ledger's start, emitted, removed, the last exchange */
    double ledger[5] = {l->accel ? 1.0 : 0.0, l->initial, l->emitted, l->removed, l->t_last};
    return dr_h5_write_f64(hf, "/hair_solver/volume_ledger", 1, (uint64_t[]){5}, ledger, "m^3", false, err);
}

static DrStatus read_exact(DrH5 *hf, const char *file, const char *path, uint64_t count, double *dst, DrError *err);

static DrStatus wet_read_checkpoint(WorldWet *w, DrH5 *hf, const char *file, DrError *err)
{
    DrFilmState fs = dr_film_state(w->film);
    DR_TRY(read_exact(hf, file, "/hair_solver/film_volume", (uint64_t)fs.nverts, fs.volume, err));
    DR_TRY(read_exact(hf, file, "/hair_solver/film_velocity", (uint64_t)fs.nedges, fs.u, err));
    DR_TRY(read_exact(hf, file, "/hair_solver/film_pools", 2 * (uint64_t)fs.nstrands, fs.pool, err));
    DR_TRY(read_exact(hf, file, "/hair_solver/film_strand_speed", (uint64_t)fs.nedges, fs.strand_speed, err));
    int rank;
    uint64_t dims[4];
    int64_t *pairs = NULL;
    DR_TRY(dr_h5_read_i64(hf, "/hair_solver/bridges", &rank, dims, &pairs, err));
    int n = rank == 2 && dims[1] == 2 ? (int)dims[0] : -1;
    int *vs = NULL;
    DrStatus s = n < 0 ? dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                                      "checkpoint dataset /hair_solver/bridges is not a list of (vertex, strand) "
                                      "pairs; delete the checkpoint and bake without --resume")
                       : dr_calloc(2 * (size_t)n + 2, sizeof(int), &vs, err);
    for (int k = 0; s == DR_OK && k < n; k++) {
        vs[k] = (int)pairs[2 * k];
        vs[n + k] = (int)pairs[2 * k + 1];
    }
    if (s == DR_OK) s = dr_bridges_set(w->bridges, n, vs, vs + n, err);
    if (s != DR_OK && !err->file[0]) snprintf(err->file, sizeof err->file, "%s", file);
    free(vs);
    free(pairs);
    if (s != DR_OK || !w->link) return s;
    double ledger[5];
    DR_TRY(read_exact(hf, file, "/hair_solver/acceleration", 3 * (uint64_t)fs.nverts, w->accel, err));
    DR_TRY(read_exact(hf, file, "/hair_solver/volume_ledger", 5, ledger, err));
    DR_TRY(read_exact(hf, file, "/hair_solver/submerged", (uint64_t)fs.nverts, w->submerged, err));
    WorldWetLink *l = w->link;
    l->accel = ledger[0] != 0.0 ? w->accel : NULL;
    l->initial = ledger[1];
    l->emitted = ledger[2];
    l->removed = ledger[3];
    l->t_last = ledger[4];
    return DR_OK;
}

/* Where hair element b's strands lie in the rod set's arrays: first strand, vertex and edge, and their counts. */
typedef struct BatchSpan { int s0, v0, e0; uint64_t ns, nv, ne; } BatchSpan;

static BatchSpan batch_span(const DrRodState *rs, int b)
{
    int s0 = rs->batch_offsets[b], s1 = rs->batch_offsets[b + 1];
    int v0 = rs->offsets[s0], v1 = rs->offsets[s1];
    BatchSpan sp = {s0, v0, v0 - s0, (uint64_t)(s1 - s0), (uint64_t)(v1 - v0), (uint64_t)((v1 - s1) - (v0 - s0))};
    return sp;
}

static DrStatus hair_write(const void *self, const WorldCtx *c, DrH5 *hf, bool frame_cache, DrError *err)
{
    (void)c;
    const WorldHair *h = self;
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
        if (h->wet && frame_cache) {
            /* the film: its cross-section area A = π (H² − r²) and its thickness H − r at every vertex */
            double *a = NULL;
            DR_TRY(dr_calloc(2 * nv + 1, sizeof(double), &a, err));
            dr_film_heights(h->wet->film, h->wet->heights);
            for (uint64_t k = 0; k < nv; k++) {
                int i = v0 + (int)k;
                double r = h->wet->radius[i], H = h->wet->heights[i];
                a[k] = DR_PI * (H * H - r * r);
                a[nv + k] = H - r;
            }
            PATHF(path, "/%s/liquid_area", name);
            DrStatus s = dr_h5_write_f64(hf, path, 1, (uint64_t[]){nv}, a, "m^2", true, err);
            PATHF(path, "/%s/film_thickness", name);
            if (s == DR_OK) s = dr_h5_write_f64(hf, path, 1, (uint64_t[]){nv}, a + nv, "m", true, err);
            free(a);
            DR_TRY(s);
        }
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
        if (h->cpl)
            DR_TRY(dr_h5_write_f64(hf, "/hair_solver/coupling_impulse", 2, (uint64_t[]){(uint64_t)rs.nverts, 3},
                                   h->cpl->next, "kg*m/s", false, err));
        DR_TRY(dr_h5_write_f64(hf, "/hair_solver/lambda", 1, (uint64_t[]){(uint64_t)rs.nlambda}, rs.lambda, "1", false,
                               err));
        if (h->wet) DR_TRY(wet_write_checkpoint(h->wet, hf, err));
        return DR_OK;
    }
    const char *g = "/diagnostics";
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_substeps", h->substeps, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_steps", h->last_steps, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_cfl_steps", h->last_cfl_steps, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_cg_iterations", h->last.iterations, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_residual", h->last.residual, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_not_converged", h->not_converged, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_collider_contacts", h->last.collider_contacts, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_contacts", h->last.hair_contacts, "1", err));
    if (h->link) DR_TRY(dr_h5_write_scalar(hf, g, "hair_cloth_contacts", h->last_cross, "1", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_kinetic_energy", h->last.kinetic, "J", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_elastic_energy", h->last.elastic, "J", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_gravity_energy", h->last.gravity_potential, "J", err));
    DR_TRY(dr_h5_write_vec3(hf, g, "hair_linear_momentum", h->last.momentum, "kg*m/s", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_scalp_work", h->last_scalp_work, "J", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_max_speed", h->last_speed, "m/s", err));
    DR_TRY(dr_h5_write_scalar(hf, g, "hair_max_speed_growth", h->last_speed_growth, "1", err));
    if (h->wet) {
        const DrHairFrameStats *b = &h->last_wet;
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_film_volume", b->film_volume, "m^3", err));
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_pool_volume", b->pool_volume, "m^3", err));
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_film_max_ratio", b->film_max_ratio, "1", err));
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_film_kinetic_energy", b->film_kinetic_energy, "J", err));
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_film_gravity_energy", b->film_gravity_energy, "J", err));
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_bridges", b->bridges, "1", err));
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_solid_bridges", b->solid_bridges, "1", err));
        DR_TRY(dr_h5_write_scalar(hf, g, "hair_cross_flow", b->cross_flow, "m^3", err));
        if (b->exchange) {
            /* capture, dripping and the volume ledger of bulk, film and pools */
            const char *lg = "/diagnostics/volume_ledger";
            DR_TRY(dr_h5_write_scalar(hf, lg, "bulk", b->ledger_bulk, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "film", b->film_volume, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "pools", b->pool_volume, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "emitted", b->ledger_emitted, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "removed", b->ledger_removed, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "total", b->ledger_total, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "initial", b->ledger_initial, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "relative_error", b->ledger_error, "1", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "captured", b->captured, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "dripped", b->dripped, "m^3", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "drops", (double)b->drops, "1", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "captured_particles", (double)b->captured_particles, "1", err));
            DR_TRY(dr_h5_write_scalar(hf, lg, "held_back", b->held_back, "m^3", err));
            DR_TRY(dr_h5_write_vec3(hf, lg, "captured_momentum", b->captured_momentum, "kg*m/s", err));
            DR_TRY(dr_h5_write_vec3(hf, lg, "dripped_momentum", b->dripped_momentum, "kg*m/s", err));
            /* the momentum ledger of liquid + strands + film over the frame's steps */
            const WorldMomentum *m = &h->wet->momentum;
            const char *mg = "/diagnostics/momentum_ledger";
            DrVec3 total = dr_v3_add(dr_v3_add(m->last_liquid, m->last_hair), m->last_film);
            DR_TRY(dr_h5_write_scalar(hf, mg, "relative_change_max", m->last_relative_max, "1", err));
            DR_TRY(dr_h5_write_scalar(hf, mg, "residual_max", m->last_residual_max, "kg*m/s", err));
            DR_TRY(dr_h5_write_scalar(hf, mg, "steps", m->last_steps, "1", err));
            DR_TRY(dr_h5_write_vec3(hf, mg, "external", m->last_external, "kg*m/s", err));
            DR_TRY(dr_h5_write_vec3(hf, mg, "total", total, "kg*m/s", err));
            DR_TRY(dr_h5_write_vec3(hf, mg, "liquid", m->last_liquid, "kg*m/s", err));
            DR_TRY(dr_h5_write_vec3(hf, mg, "hair", m->last_hair, "kg*m/s", err));
            DR_TRY(dr_h5_write_vec3(hf, mg, "film", m->last_film, "kg*m/s", err));
            DR_TRY(dr_h5_write_vec3(hf, mg, "film_pressure_impulse", b->film_pressure_impulse, "N*s", err));
        }
    }
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

static DrStatus hair_read(void *self, const WorldCtx *c, DrH5 *hf, const char *file, int frame, DrError *err)
{
    (void)c;
    (void)frame;
    WorldHair *h = self;
    h->watch_started = false; /* the next frame's end is the watch's reference */
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
    if (h->cpl)
        DR_TRY(read_exact(hf, file, "/hair_solver/coupling_impulse", 3 * (uint64_t)rs.nverts, h->cpl->next, err));
    dr_rod_set_refresh(h->rods);
    if (h->wet) DR_TRY(wet_read_checkpoint(h->wet, hf, file, err));
    if (h->wet && h->wet->link) /* the liquid (read first) and the strands restored */
        ledger_start(h->wet, &rs, h->cpl ? h->cpl->next : NULL);
    return DR_OK;
}

static void hair_hash(const void *self, DrHasher *hs)
{
    const WorldHair *h = self;
    DrRodState rs = dr_rod_set_state(h->rods);
    long ni = rs.nverts - 2L * rs.nstrands;
    dr_hasher_update(hs, rs.x, 3 * sizeof(double) * (size_t)rs.nverts);
    dr_hasher_update(hs, rs.v, 3 * sizeof(double) * (size_t)rs.nverts);
    dr_hasher_update(hs, rs.theta, sizeof(double) * (size_t)rs.nedges);
    dr_hasher_update(hs, rs.theta_dot, sizeof(double) * (size_t)rs.nedges);
    dr_hasher_update(hs, rs.a1, 3 * sizeof(double) * (size_t)rs.nedges);
    if (ni > 0) dr_hasher_update(hs, rs.ref_twist, sizeof(double) * (size_t)ni);
    dr_hasher_update(hs, rs.lambda, sizeof(double) * (size_t)rs.nlambda);
    if (h->cpl) dr_hasher_update(hs, h->cpl->next, 3 * sizeof(double) * (size_t)rs.nverts);
    if (h->wet) {
        DrFilmState fs = dr_film_state(h->wet->film);
        dr_hasher_update(hs, fs.volume, sizeof(double) * (size_t)fs.nverts);
        dr_hasher_update(hs, fs.u, sizeof(double) * (size_t)fs.nedges);
        dr_hasher_update(hs, fs.pool, 2 * sizeof(double) * (size_t)fs.nstrands);
        dr_hasher_update(hs, fs.strand_speed, sizeof(double) * (size_t)fs.nedges);
        int n = dr_bridges_count(h->wet->bridges);
        dr_hasher_update(hs, &n, sizeof n);
    }
}

/* The drag laws of the elements with a Drag component (none: no coupling), per vertex arrays. */
static DrStatus build_couple(WorldHair *h, DrError *err)
{
    bool any = false;
    for (int b = 0; b < h->nelements; b++)
        any = any || dr_component_present(dr_element_component(h->elements[b], "Drag"));
    if (!any) return DR_OK;
    DrRodState rs = dr_rod_set_state(h->rods);
    WorldCouple *k = NULL;
    DR_TRY(dr_calloc(1, sizeof *k, &k, err));
    h->cpl = k;
    size_t nv = (size_t)rs.nverts;
    DR_TRY(dr_calloc((size_t)h->nelements, sizeof *k->laws, &k->laws, err));
    DR_TRY(dr_calloc((size_t)h->nelements, 1, &k->coupled, err));
    DR_TRY(dr_calloc(nv, sizeof *k->law, &k->law, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &k->slender, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &k->volume, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &k->diameter, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &k->mass, err));
    DR_TRY(dr_calloc(3 * nv, sizeof(double), &k->pending, err));
    DR_TRY(dr_calloc(3 * nv, sizeof(double), &k->next, err));
    DR_TRY(dr_calloc(nv, sizeof(double), &k->carried, err));
    DR_TRY(dr_calloc(3 * nv, sizeof(double), &k->impulse, err));
    DR_TRY(dr_calloc(3 * nv, sizeof(double), &k->gradp, err));
    DR_TRY(dr_calloc(3 * nv, sizeof(double), &k->force, err));
    DR_TRY(dr_calloc(9 * nv, sizeof(double), &k->dfdv, err));
    int nb = dr_rod_set_load_blocks(h->rods);
    DR_TRY(dr_calloc((size_t)nb, sizeof(int), &k->block_dof, err));
    DR_TRY(dr_calloc(9 * (size_t)nb, sizeof(double), &k->block, err));
    for (int b = 0; b < h->nelements; b++) {
        DrDragLaw *law = &k->laws[b];
        dr_drag_law_default(law);
        const DrComponent *dc = dr_element_component(h->elements[b], "Drag");
        if (!dr_component_present(dc)) {
            law->global = 0.0;
            law->buoyancy = false;
            continue;
        }
        k->coupled[b] = 1;
        law->model = strcmp(dr_component_str(dc, "model"), "permeability") == 0 ? DR_DRAG_PERMEABILITY : DR_DRAG_SCALES;
        law->reference = strcmp(dr_component_str(dc, "reference"), "literal") == 0 ? DR_DRAG_LITERAL : DR_DRAG_STOKES;
        law->global = dr_component_num(dc, "global_scale");
        law->normal = dr_component_num(dc, "normal_scale");
        law->tangent = dr_component_num(dc, "tangent_scale");
        law->nonlinear = dr_component_num(dc, "nonlinear_scale");
        law->degree = dr_component_num(dc, "degree");
        law->lift = dr_component_num(dc, "lift_scale");
        law->buoyancy = dr_component_bool(dc, "buoyancy");
    }
    for (int b = 0; b < rs.nbatches; b++)
        for (int st = rs.batch_offsets[b]; st < rs.batch_offsets[b + 1]; st++) {
            double len = 0.0;
            for (int v = rs.offsets[st]; v + 1 < rs.offsets[st + 1]; v++) {
                DrVec3 a = dr_v3(rs.x[3 * v], rs.x[3 * v + 1], rs.x[3 * v + 2]);
                DrVec3 c = dr_v3(rs.x[3 * v + 3], rs.x[3 * v + 4], rs.x[3 * v + 5]);
                len += dr_v3_norm(dr_v3_sub(c, a));
            }
            double lam = len / (2.0 * rs.radius[st]);
            for (int v = rs.offsets[st]; v < rs.offsets[st + 1]; v++) {
                k->law[v] = b;
                k->slender[v] = lam > 1.0 ? lam : 1.0;
            }
        }
    return DR_OK;
}

DrStatus world_lagrangian_adapter(const WorldCtx *c, const char *cache_root, WorldSolver *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    int n = dr_scene_count_kind(c->scene, DR_ELEMENT_HAIR);
    if (n == 0) return DR_OK;
    WorldHair *h = NULL;
    DR_TRY(dr_calloc(1, sizeof *h, &h, err));
    DrStatus s = build_hair(c, h, n, err);
    if (s == DR_OK) s = dr_calloc((size_t)dr_lag_dof_count(h->system), sizeof(double), &h->fint, err);
    h->fint_cap = dr_lag_dof_count(h->system);
    h->hair_dofs = dr_lag_dof_count(h->system);
    if (s == DR_OK) s = link_cloth(c, h, err);
    if (s == DR_OK) s = build_wet(c, h, cache_root, err);
    if (s == DR_OK) s = build_couple(h, err);
    if (s < 0) {
        hair_destroy(h);
        return s;
    }
    *out = (WorldSolver){.name = "lagrangian",
                         .self = h,
                         .begin_frame = hair_begin_frame,
                         .next_time = hair_next_time,
                         .step = hair_step,
                         .step_last = hair_step_last,
                         .end_frame = hair_end_frame,
                         .write = hair_write,
                         .read = hair_read,
                         .hash = hair_hash,
                         .destroy = hair_destroy,
                         .couples = hair_couples,
                         .solid_predict = hair_solid_predict,
                         .solid_commit = hair_solid_commit,
                         .solid_stable_dt = hair_solid_stable_dt};
    return DR_OK;
}

void world_lagrangian_hair_counts(const WorldSolver *s, int *strands, int *vertices)
{
    DrRodState rs = dr_rod_set_state(((const WorldHair *)s->self)->rods);
    *strands = rs.nstrands;
    *vertices = rs.nverts;
}
