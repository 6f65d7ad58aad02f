/* drench cloth: a panel of discrete shells on the Lagrangian solver (cloth.h).
 *
 * A step: (1) the DOF arrays (mass, velocity, gravity, pinned vertices) in the panel's vertex order; (2) the groups:
 * membrane rows per triangle with their viscous twins, hinge rows per interior edge with theirs, vertex–collider
 * contacts, vertex–triangle self contacts (self_contact.c); (3) the solve; (4) multipliers, Coulomb friction at the
 * contacts, positions. */
#include "cloth/cloth.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "cloth/self_contact.h"
#include "cloth/shell.h"
#include "core/sort.h"

struct DrCloth {
    DrClothDesc desc;
    DrClothMaterial mat;
    char name[160];
    int V, T, H;
    int *tri;           /* 3T */
    double *x, *v;      /* 3V, mesh order */
    double *mass;       /* V */
    double *Bm, *area;  /* 4T, T */
    int *hinge;         /* 4H: x0 x1 x2 x3 (wing, edge, edge, wing) */
    double *theta_bar, *hinge_cinv; /* H */
    int *tri_hinge;     /* 3T: the hinge of each triangle's edge i (opposite its vertex i), −1 on the boundary */
    double *bend_u, *bend_cinv; /* 9T, 3T: shape-operator rows of each triangle (shell.h) */
    int *bend_rows;     /* T */
    double *hinge_now;  /* 13H: θ and ∂θ/∂x of each hinge at the step's start */
    double k_membrane, nu, k_bend;
    int *rank;          /* V: the vertex's place in the object's order */
    int band;
    /* the Lagrangian system */
    DrLag *lag;
    int object, dof0;
    double *lambda;     /* 3T membrane multipliers */
    unsigned char *pinned; /* V */
    double *pin_vel;    /* 3V */
    unsigned char *slide; /* V: vertices held on the slide curve */
    double *curve;      /* 3 ncurve: the slide curve's points (a polyline), m */
    int ncurve;
    /* contacts of the step */
    unsigned char *cflag;
    double *cnormal, *cvel, *cfric, *clambda;
    double *cphi;       /* V: the contact row's constant (see detect_contacts) */
    int ncontacts;
    double *rest;       /* 3V: the mesh's positions at creation (self contact's rest distances) */
    DrClothSelf *self;  /* NULL when the material's self_contact is off */
    unsigned char *touch; /* V: the vertices in self contact (dr_cloth_self_update) */
    unsigned char *cban;  /* V: collider contacts let go for the rest of the step (update_contacts) */
    double *save;       /* 6V */
    double h_step;
    /* the step's phases */
    enum { CLOTH_IDLE, CLOTH_PREDICTED, CLOTH_SOLVED } phase;
    double *vsolve;     /* 3V, mesh order: the last solve's velocities */
    int *block_dof;     /* V: each vertex's first DOF (a load's 3×3 blocks) */
    int iterations;
    bool converged;
    double seconds;
};

void dr_cloth_material_default(DrClothMaterial *m)
{
    m->density = 400.0;
    m->thickness = 5e-4;
    m->youngs_modulus = 1e6;
    m->poisson = 0.3;
    m->bend_scale = 1.0;
    m->damping = 0.0;
    m->friction = 0.0;
    m->collision_thickness = 1e-3;
    m->self_contact = true;
    m->self_stiffness = 1e4;
    m->self_friction = 0.0;
    m->self_thickness = 1e-3;
    m->self_damping = 0.0;
    m->bending = DR_CLOTH_BEND_SHAPE_OPERATOR;
}

void dr_cloth_desc_default(DrClothDesc *d)
{
    memset(d, 0, sizeof *d);
    d->gravity = dr_v3(0, -9.81, 0);
    dr_lag_desc_default(&d->solver);
    d->geometric_stiffness = true;
    d->collider_stiffness = 1e4;
}

int dr_cloth_vertex_count(const DrCloth *c) { return c->V; }
int dr_cloth_triangle_count(const DrCloth *c) { return c->T; }
int dr_cloth_hinge_count(const DrCloth *c) { return c->H; }
int dr_cloth_band(const DrCloth *c) { return c->band; }
const int *dr_cloth_vertex_order(const DrCloth *c) { return c->rank; }
const int *dr_cloth_triangles(const DrCloth *c) { return c->tri; }
const double *dr_cloth_positions(const DrCloth *c) { return c->x; }
double *dr_cloth_positions_mut(DrCloth *c) { return c->x; }
const double *dr_cloth_velocities(const DrCloth *c) { return c->v; }
double *dr_cloth_velocities_mut(DrCloth *c) { return c->v; }
const double *dr_cloth_masses(const DrCloth *c) { return c->mass; }

void dr_cloth_destroy(DrCloth **cp)
{
    if (!cp || !*cp) return;
    DrCloth *c = *cp;
    free(c->tri);
    free(c->x);
    free(c->v);
    free(c->mass);
    free(c->Bm);
    free(c->area);
    free(c->hinge);
    free(c->theta_bar);
    free(c->hinge_cinv);
    free(c->tri_hinge);
    free(c->bend_u);
    free(c->bend_cinv);
    free(c->bend_rows);
    free(c->hinge_now);
    free(c->rank);
    free(c->lambda);
    free(c->pinned);
    free(c->pin_vel);
    free(c->slide);
    free(c->curve);
    free(c->cflag);
    free(c->cnormal);
    free(c->cvel);
    free(c->cfric);
    free(c->clambda);
    free(c->cphi);
    free(c->rest);
    free(c->touch);
    free(c->cban);
    dr_cloth_self_destroy(&c->self);
    free(c->save);
    free(c->vsolve);
    free(c->block_dof);
    if (!c->desc.system) dr_lag_destroy(&c->lag);
    free(c);
    *cp = NULL;
}

/* ---- topology -------------------------------------------------------------------------------------------------- */

/* A directed half-edge of a triangle: the edge (lo, hi) with the triangle, its third vertex and its direction. */
typedef struct HalfEdge { int lo, hi, tri, third, forward; } HalfEdge;

static int half_edge_cmp(const void *pa, const void *pb)
{
    const HalfEdge *a = pa, *b = pb;
    if (a->lo != b->lo) return a->lo < b->lo ? -1 : 1;
    if (a->hi != b->hi) return a->hi < b->hi ? -1 : 1;
    return a->tri < b->tri ? -1 : (a->tri > b->tri);
}

/* Reverse Cuthill–McKee over the graph adj (CSR: off, nb), each component from a pseudo-peripheral vertex (the far
   end of two breadth-first sweeps from its lowest-degree vertex); neighbours visited by increasing degree, ties by
   index, so the order depends on the mesh alone. rank[v] = place of v. */
static DrStatus rcm_order(int V, const int *off, const int *nb, int *rank, DrError *err)
{
    int *order = NULL, *level = NULL, *queue = NULL, *tmp = NULL;
    DrStatus st = dr_calloc((size_t)V + 1, sizeof(int), &order, err);
    if (st == DR_OK) st = dr_calloc((size_t)V + 1, sizeof(int), &level, err);
    if (st == DR_OK) st = dr_calloc((size_t)V + 1, sizeof(int), &queue, err);
    if (st == DR_OK) st = dr_calloc((size_t)V + 1, sizeof(int), &tmp, err);
    if (st != DR_OK) goto done;
    for (int v = 0; v < V; v++) rank[v] = -1;
    int placed = 0;
    for (int seed = 0; seed < V; seed++) {
        if (rank[seed] >= 0) continue;
        /* the component of seed, by breadth-first search (level = -1 marks unvisited within this search) */
        int start = seed;
        for (int sweep = 0; sweep < 3; sweep++) {
            /* sweep 0: find the component's lowest-degree vertex; sweeps 1, 2: move to the far end */
            for (int k = 0; k < V; k++) level[k] = -1;
            int head = 0, tail = 0;
            queue[tail++] = start;
            level[start] = 0;
            int best = start;
            while (head < tail) {
                int u = queue[head++];
                int du = off[u + 1] - off[u], db = off[best + 1] - off[best];
                if (sweep == 0 ? (du < db || (du == db && u < best))
                               : (level[u] > level[best] || (level[u] == level[best] && (du < db || (du == db && u < best)))))
                    best = u;
                for (int k = off[u]; k < off[u + 1]; k++)
                    if (level[nb[k]] < 0) {
                        level[nb[k]] = level[u] + 1;
                        queue[tail++] = nb[k];
                    }
            }
            start = best;
        }
        /* Cuthill–McKee from start */
        int head = placed, tail = placed;
        order[tail++] = start;
        rank[start] = 0; /* marks visited; the final rank is set below */
        while (head < tail) {
            int u = order[head++];
            int n = 0;
            for (int k = off[u]; k < off[u + 1]; k++)
                if (rank[nb[k]] < 0) tmp[n++] = nb[k];
            /* insertion sort by (degree, index): neighbour lists are short */
            for (int i = 1; i < n; i++) {
                int w = tmp[i], dw = off[w + 1] - off[w], j = i - 1;
                while (j >= 0) {
                    int dj = off[tmp[j] + 1] - off[tmp[j]];
                    if (dj < dw || (dj == dw && tmp[j] < w)) break;
                    tmp[j + 1] = tmp[j];
                    j--;
                }
                tmp[j + 1] = w;
            }
            for (int i = 0; i < n; i++) {
                rank[tmp[i]] = 0;
                order[tail++] = tmp[i];
            }
        }
        placed = tail;
    }
    for (int i = 0; i < V; i++) rank[order[i]] = V - 1 - i; /* reversed */
done:
    free(order);
    free(level);
    free(queue);
    free(tmp);
    return st;
}

/* The vertices of triangle t's bending group: its own three, then the wing across each interior edge. Returns how
   many. */
static int tri_group_vertices(const DrCloth *c, int t, int vs[6])
{
    int n = 0;
    for (int q = 0; q < 3; q++) vs[n++] = c->tri[3 * t + q];
    for (int q = 0; q < 3; q++) {
        int k = c->tri_hinge[3 * t + q];
        if (k < 0) continue;
        const int *hg = c->hinge + 4 * k;
        int w = hg[0] == c->tri[3 * t + q] ? hg[3] : hg[0]; /* the wing that is not this triangle's vertex */
        bool seen = false;
        for (int a = 0; a < n; a++) seen = seen || vs[a] == w; /* a folded-over mesh may repeat one */
        if (!seen) vs[n++] = w;
    }
    return n;
}

/* The widest spread of `rank` within any group of the panel (a triangle, or its bending group: a hinge's four
   vertices, or a triangle with the wings across its edges), in vertices. */
static int group_band(const DrCloth *c, const int *rank)
{
    int band = 0;
    for (int t = 0; t < c->T; t++) {
        int vs[6], n = 3;
        if (c->mat.bending == DR_CLOTH_BEND_SHAPE_OPERATOR) n = tri_group_vertices(c, t, vs);
        else
            for (int a = 0; a < 3; a++) vs[a] = c->tri[3 * t + a];
        for (int a = 0; a < n; a++)
            for (int b = a + 1; b < n; b++) band = abs(rank[vs[a]] - rank[vs[b]]) > band ? abs(rank[vs[a]] - rank[vs[b]]) : band;
    }
    if (c->mat.bending == DR_CLOTH_BEND_HINGE)
        for (int q = 0; q < c->H; q++)
            for (int a = 0; a < 4; a++)
                for (int b = a + 1; b < 4; b++) {
                    int d = abs(rank[c->hinge[4 * q + a]] - rank[c->hinge[4 * q + b]]);
                    if (d > band) band = d;
                }
    return band;
}

/* qsort by one coordinate of the rest positions, then by index (the order depends on the mesh alone); qsort takes no
   context, so the axis and the positions are set in per-thread statics just before it. */
static _Thread_local int sort_axis;
static _Thread_local const double *sort_x;
static int axis_cmp(const void *pa, const void *pb)
{
    int a = *(const int *)pa, b = *(const int *)pb;
    double xa = sort_x[3 * a + sort_axis], xb = sort_x[3 * b + sort_axis];
    if (xa != xb) return xa < xb ? -1 : 1;
    return a < b ? -1 : (a > b);
}

static bool material_ok(const DrClothMaterial *m)
{
    return m->density > 0 && isfinite(m->density) && m->thickness > 0 && isfinite(m->thickness) &&
           m->youngs_modulus > 0 && isfinite(m->youngs_modulus) && m->poisson >= 0 && m->poisson < 0.5 &&
           m->bend_scale >= 0 && isfinite(m->bend_scale) && m->damping >= 0 && isfinite(m->damping) &&
           m->friction >= 0 && isfinite(m->friction) && m->collision_thickness >= 0 &&
           isfinite(m->collision_thickness) && m->self_stiffness > 0 && isfinite(m->self_stiffness) &&
           m->self_friction >= 0 && isfinite(m->self_friction) && m->self_thickness >= 0 &&
           isfinite(m->self_thickness) && m->self_damping >= 0 && isfinite(m->self_damping) && (m->bending == DR_CLOTH_BEND_SHAPE_OPERATOR || m->bending == DR_CLOTH_BEND_HINGE);
}

DrStatus dr_cloth_create(const DrClothDesc *desc, const DrTriMesh *mesh, const DrClothMaterial *material,
                         const char *name, DrCloth **out, DrError *err)
{
    *out = NULL;
    const char *nm = name ? name : "cloth";
    if (!mesh || mesh->nt < 1 || mesh->nv < 3)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s: the cloth mesh has no triangle; give a triangle mesh",
                            nm);
    if (!material_ok(material))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "%s: cloth material out of range (density, thickness, Young's modulus > 0; Poisson's ratio "
                            "in [0, 0.5); bend scale, damping, friction, collision thickness >= 0; self contact stiffness > 0, "
                            "its friction, thickness and damping >= 0)",
                            nm);
    for (int i = 0; i < 3 * mesh->nt; i++)
        if (mesh->tri[i] < 0 || mesh->tri[i] >= mesh->nv)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "%s: triangle %d refers to vertex %d, but the mesh has %d vertices", nm, i / 3,
                                mesh->tri[i], mesh->nv);
    for (int i = 0; i < 3 * mesh->nv; i++)
        if (!isfinite(mesh->v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s: vertex %d has a non-finite coordinate", nm, i / 3);
    DrCloth *c = NULL;
    DR_TRY(dr_calloc(1, sizeof *c, &c, err));
    if (desc) c->desc = *desc;
    else dr_cloth_desc_default(&c->desc);
    c->mat = *material;
    snprintf(c->name, sizeof c->name, "%s", nm);
    int V = c->V = mesh->nv, T = c->T = mesh->nt;
    HalfEdge *he = NULL;
    int *off = NULL, *nb = NULL, *fill = NULL, *order = NULL, *trial = NULL;
    DrStatus st = DR_OK;
#define ALLOC(p, n) \
    if (st == DR_OK) st = dr_calloc((size_t)(n) > 0 ? (size_t)(n) : 1, sizeof *(p), &(p), err)
    ALLOC(c->tri, 3 * T);
    ALLOC(c->x, 3 * V);
    ALLOC(c->v, 3 * V);
    ALLOC(c->mass, V);
    ALLOC(c->Bm, 4 * T);
    ALLOC(c->area, T);
    ALLOC(c->rank, V);
    ALLOC(c->lambda, 3 * T);
    ALLOC(c->pinned, V);
    ALLOC(c->pin_vel, 3 * V);
    ALLOC(c->slide, V);
    ALLOC(c->cflag, V);
    ALLOC(c->cnormal, 3 * V);
    ALLOC(c->cvel, 3 * V);
    ALLOC(c->cfric, V);
    ALLOC(c->clambda, V);
    ALLOC(c->cphi, V);
    ALLOC(c->rest, 3 * V);
    ALLOC(c->touch, V);
    ALLOC(c->cban, V);
    ALLOC(c->save, 6 * V);
    ALLOC(c->vsolve, 3 * V);
    ALLOC(c->block_dof, V);
    ALLOC(he, 3 * T);
    ALLOC(off, V + 1);
    ALLOC(fill, V + 1);
    if (st != DR_OK) goto fail;
    memcpy(c->tri, mesh->tri, 3 * (size_t)T * sizeof(int));
    memcpy(c->x, mesh->v, 3 * (size_t)V * sizeof(double));
    memcpy(c->rest, mesh->v, 3 * (size_t)V * sizeof(double));
    const DrClothMaterial *m = material;
    double E = m->youngs_modulus, nu = m->poisson, h = m->thickness;
    c->k_membrane = E * h / (1.0 - nu * nu);
    c->nu = nu;
    c->k_bend = m->bend_scale * E * h * h * h / (24.0 * (1.0 - nu * nu));
    for (int t = 0; t < T; t++) {
        const int *tv = c->tri + 3 * t;
        if (!dr_shell_rest(c->x + 3 * tv[0], c->x + 3 * tv[1], c->x + 3 * tv[2], c->Bm + 4 * t, &c->area[t])) {
            st = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                              "%s: triangle %d (vertices %d, %d, %d) is degenerate (zero area); clean the mesh", nm, t,
                              tv[0], tv[1], tv[2]);
            goto fail;
        }
        for (int a = 0; a < 3; a++) c->mass[tv[a]] += m->density * h * c->area[t] / 3.0;
        for (int a = 0; a < 3; a++) {
            int p = tv[a], q = tv[(a + 1) % 3];
            he[3 * t + a] = (HalfEdge){p < q ? p : q, p < q ? q : p, t, tv[(a + 2) % 3], p < q};
        }
    }
    for (int v = 0; v < V; v++)
        if (!(c->mass[v] > 0)) {
            st = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                              "%s: vertex %d belongs to no triangle; remove unused vertices from the mesh", nm, v);
            goto fail;
        }
    qsort(he, 3 * (size_t)T, sizeof *he, half_edge_cmp);
    /* edges: runs of equal (lo, hi); count hinges and the graph's degrees */
    int nedges = 0, H = 0;
    for (int i = 0; i < 3 * T;) {
        int j = i + 1;
        while (j < 3 * T && he[j].lo == he[i].lo && he[j].hi == he[i].hi) j++;
        if (j - i > 2) {
            st = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                              "%s: edge (%d, %d) borders %d triangles; a cloth mesh is a manifold (each edge borders "
                              "one or two triangles)",
                              nm, he[i].lo, he[i].hi, j - i);
            goto fail;
        }
        if (j - i == 2) {
            if (he[i].forward == he[i + 1].forward) {
                st = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                  "%s: triangles %d and %d are wound opposite ways across edge (%d, %d); orient the "
                                  "mesh consistently",
                                  nm, he[i].tri, he[i + 1].tri, he[i].lo, he[i].hi);
                goto fail;
            }
            H++;
        }
        off[he[i].lo + 1]++;
        off[he[i].hi + 1]++;
        nedges++;
        i = j;
    }
    c->H = H;
    ALLOC(c->hinge, 4 * H);
    ALLOC(c->theta_bar, H);
    ALLOC(c->hinge_cinv, H);
    ALLOC(c->hinge_now, 13 * H);
    ALLOC(c->tri_hinge, 3 * T);
    ALLOC(c->bend_u, 9 * T);
    ALLOC(c->bend_cinv, 3 * T);
    ALLOC(c->bend_rows, T);
    ALLOC(nb, 2 * nedges);
    if (st != DR_OK) goto fail;
    for (int v = 0; v < V; v++) off[v + 1] += off[v];
    memcpy(fill, off, (size_t)V * sizeof(int));
    for (int i = 0; i < 3 * T; i++) c->tri_hinge[i] = -1;
    int k = 0;
    for (int i = 0; i < 3 * T;) {
        int j = i + 1;
        while (j < 3 * T && he[j].lo == he[i].lo && he[j].hi == he[i].hi) j++;
        nb[fill[he[i].lo]++] = he[i].hi;
        nb[fill[he[i].hi]++] = he[i].lo;
        if (j - i == 2) {
            /* x1 → x2 as the forward triangle (A) traverses the edge: A = (x0, x1, x2), B = (x3, x2, x1) */
            const HalfEdge *a = he[i].forward ? &he[i] : &he[i + 1], *b = he[i].forward ? &he[i + 1] : &he[i];
            int *hg = c->hinge + 4 * k;
            hg[0] = a->third, hg[1] = a->lo, hg[2] = a->hi, hg[3] = b->third;
            c->theta_bar[k] = dr_shell_hinge_angle(c->x + 3 * hg[0], c->x + 3 * hg[1], c->x + 3 * hg[2],
                                                   c->x + 3 * hg[3], NULL);
            double l2 = 0;
            for (int d = 0; d < 3; d++) l2 += (c->x[3 * hg[2] + d] - c->x[3 * hg[1] + d]) *
                                              (c->x[3 * hg[2] + d] - c->x[3 * hg[1] + d]);
            c->hinge_cinv[k] = 2.0 * c->k_bend * l2 / (c->area[a->tri] + c->area[b->tri]);
            /* the edge is opposite the third vertex in each triangle */
            for (int side = 0; side < 2; side++) {
                const HalfEdge *s = side ? b : a;
                for (int q = 0; q < 3; q++)
                    if (c->tri[3 * s->tri + q] == s->third) c->tri_hinge[3 * s->tri + q] = k;
            }
            k++;
        }
        i = j;
    }
    for (int t = 0; t < T; t++) {
        const int *tv = c->tri + 3 * t;
        bool interior[3];
        for (int q = 0; q < 3; q++) interior[q] = c->tri_hinge[3 * t + q] >= 0;
        c->bend_rows[t] = dr_shell_bend_rest(c->x + 3 * tv[0], c->x + 3 * tv[1], c->x + 3 * tv[2], c->area[t], interior,
                                             c->k_bend, nu, c->bend_u + 9 * t, c->bend_cinv + 3 * t);
    }
    /* the vertex order: reverse Cuthill–McKee, or a sweep of the rest positions along a coordinate axis when that
       gives a narrower band (on quad-split cells with alternating diagonals, RCM's breadth-first levels run along
       the diagonals and its band is twice a sweep's: 251 against 129 vertices on a 64 × 64 panel) */
    ALLOC(order, V);
    ALLOC(trial, V);
    if (st != DR_OK) goto fail;
    st = rcm_order(V, off, nb, c->rank, err);
    if (st != DR_OK) goto fail;
    int band = group_band(c, c->rank);
    for (int axis = 0; axis < 3; axis++) {
        for (int v = 0; v < V; v++) order[v] = v;
        sort_axis = axis;
        sort_x = c->x;
        qsort(order, (size_t)V, sizeof(int), axis_cmp);
        for (int k = 0; k < V; k++) trial[order[k]] = k;
        int b = group_band(c, trial);
        if (b < band) {
            band = b;
            memcpy(c->rank, trial, (size_t)V * sizeof(int));
        }
    }
    c->band = band;
    if (c->desc.system) c->lag = c->desc.system;
    else st = dr_lag_create(&c->desc.solver, &c->lag, err);
    if (st != DR_OK) goto fail;
    for (int v = 0; v < V; v++) c->vsolve[3 * v] = c->vsolve[3 * v + 1] = c->vsolve[3 * v + 2] = 0.0;
    int kd = 3 * band + 2;
    if (kd >= 3 * V) kd = 3 * V - 1;
    st = dr_lag_add_object(c->lag, 3 * V, kd, &c->object, &c->dof0, err);
    if (st != DR_OK) goto fail;
    for (int v = 0; v < V; v++) c->block_dof[v] = c->dof0 + 3 * c->rank[v];
    if (m->self_contact) {
        DrClothSelfPanel sp = {V, T, c->tri, c->rest, c->mass, c->pinned, c->rank, c->band, c->dof0,
                               m->self_thickness, m->self_stiffness, m->self_friction, m->self_damping};
        st = dr_cloth_self_create(&sp, &c->self, err);
        if (st != DR_OK) goto fail;
    }
    free(he);
    free(off);
    free(nb);
    free(fill);
    free(order);
    free(trial);
    *out = c;
    return DR_OK;
fail:
#undef ALLOC
    free(he);
    free(off);
    free(nb);
    free(fill);
    free(order);
    free(trial);
    dr_cloth_destroy(&c);
    return st;
}

DrStatus dr_cloth_pin(DrCloth *c, int v, bool pinned, const double *vel, DrError *err)
{
    if (v < 0 || v >= c->V)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s: vertex %d to pin is out of range (the panel has %d)",
                            c->name, v, c->V);
    c->pinned[v] = pinned;
    for (int a = 0; a < 3; a++) c->pin_vel[3 * v + a] = pinned && vel ? vel[a] : 0.0;
    return DR_OK;
}

DrStatus dr_cloth_set_slide_curve(DrCloth *c, const double *points, int npoints, DrError *err)
{
    if (npoints < 2)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s: a slide curve needs 2 points or more, got %d", c->name,
                            npoints);
    for (int i = 0; i < 3 * npoints; i++)
        if (!isfinite(points[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s: point %d of the slide curve is not finite", c->name,
                                i / 3);
    for (int i = 0; i + 1 < npoints; i++) {
        const double *a = points + 3 * i, *b = a + 3;
        if (!((b[0] - a[0]) * (b[0] - a[0]) + (b[1] - a[1]) * (b[1] - a[1]) + (b[2] - a[2]) * (b[2] - a[2]) > 0))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "%s: points %d and %d of the slide curve coincide; remove one", c->name, i, i + 1);
    }
    double *copy = NULL;
    DR_TRY(dr_calloc(3 * (size_t)npoints, sizeof(double), &copy, err));
    memcpy(copy, points, 3 * (size_t)npoints * sizeof(double));
    free(c->curve);
    c->curve = copy;
    c->ncurve = npoints;
    return DR_OK;
}

DrStatus dr_cloth_slide(DrCloth *c, int v, bool on, DrError *err)
{
    if (v < 0 || v >= c->V)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s: vertex %d to slide is out of range (the panel has %d)",
                            c->name, v, c->V);
    if (on && c->ncurve < 2)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s: vertex %d slides, but the panel has no slide curve",
                            c->name, v);
    c->slide[v] = on;
    return DR_OK;
}

/* The point of the slide curve nearest to x (the first of equally near ones) and the unit tangent of its segment. */
static void nearest_on_curve(const DrCloth *c, DrVec3 x, DrVec3 *p, DrVec3 *t)
{
    double best = INFINITY;
    *p = dr_v3(c->curve[0], c->curve[1], c->curve[2]);
    *t = dr_v3(1, 0, 0);
    for (int i = 0; i + 1 < c->ncurve; i++) {
        DrVec3 a = dr_v3(c->curve[3 * i], c->curve[3 * i + 1], c->curve[3 * i + 2]);
        DrVec3 b = dr_v3(c->curve[3 * i + 3], c->curve[3 * i + 4], c->curve[3 * i + 5]);
        DrVec3 e = dr_v3_sub(b, a);
        double s = dr_v3_dot(dr_v3_sub(x, a), e) / dr_v3_dot(e, e);
        s = s < 0 ? 0 : (s > 1 ? 1 : s);
        DrVec3 q = dr_v3_add(a, dr_v3_scale(e, s));
        double d = dr_v3_norm(dr_v3_sub(x, q));
        if (d < best) {
            best = d;
            *p = q;
            *t = dr_v3_normalize(e);
        }
    }
}

/* Solves of one step at most: the contacts' active set (update_contacts) settles within them or is used as it stands. */
#define SLIDE_STIFFNESS 1e8 /* N/m of a slide attachment's rows */
#define CONTACT_PASSES 8

static inline int vdof(const DrCloth *c, int v) { return c->dof0 + 3 * c->rank[v]; }


/* The panel's DOF arrays for a step of h: mass, velocity, gravity, pins. */
static void fill_dofs(DrCloth *c, const DrLagDofs *d)
{
    DrVec3 gv = c->desc.gravity;
    const double g[3] = {gv.x, gv.y, gv.z};
    for (int v = 0; v < c->V; v++) {
        int d0 = vdof(c, v);
        for (int a = 0; a < 3; a++) {
            d->mass[d0 + a] = c->mass[v];
            d->qdot[d0 + a] = c->v[3 * v + a];
            d->fext[d0 + a] = c->mass[v] * g[a];
            d->prescribed[d0 + a] = c->pinned[v];
            d->qdot_prescribed[d0 + a] = c->pin_vel[3 * v + a];
            d->force[d0 + a] = 0;
        }
    }
}

/* θ and ∂θ/∂x of every hinge now (hinge_now). */
static void hinge_angles(DrCloth *c)
{
    for (int q = 0; q < c->H; q++) {
        const int *hg = c->hinge + 4 * q;
        double *o = c->hinge_now + 13 * q;
        o[0] = dr_shell_hinge_angle(c->x + 3 * hg[0], c->x + 3 * hg[1], c->x + 3 * hg[2], c->x + 3 * hg[3], o + 1);
    }
}

static double wrap(double d)
{
    if (d > DR_PI) d -= 2.0 * DR_PI;
    if (d < -DR_PI) d += 2.0 * DR_PI;
    return d;
}

/* Triangle t's shape-operator rows (shell.h) from hinge_now: φ_r = Σ_i u_ri (θ_i − θ̄_i), J_r = Σ_i u_ri ∇θ_i. */
static void shape_group(const DrCloth *c, int t, DrLagGroup *g)
{
    int vs[6], n = tri_group_vertices(c, t, vs);
    memset(g, 0, sizeof *g);
    g->kind = DR_LAG_POSITIONAL;
    g->nrows = c->bend_rows[t];
    g->ndof = 3 * n;
    for (int a = 0; a < n; a++)
        for (int d = 0; d < 3; d++) g->dof[3 * a + d] = vdof(c, vs[a]) + d;
    const double *u = c->bend_u + 9 * t;
    for (int r = 0; r < g->nrows; r++) g->cinv[r] = c->bend_cinv[3 * t + r];
    for (int i = 0; i < 3; i++) {
        int k = c->tri_hinge[3 * t + i];
        if (k < 0) continue;
        const double *o = c->hinge_now + 13 * k;
        const int *hg = c->hinge + 4 * k;
        double d = wrap(o[0] - c->theta_bar[k]);
        int col[4];
        for (int hv = 0; hv < 4; hv++) {
            col[hv] = 0;
            while (vs[col[hv]] != hg[hv]) col[hv]++; /* every hinge vertex is in the group */
        }
        for (int r = 0; r < g->nrows; r++) {
            double w = u[3 * r + i];
            if (w == 0.0) continue;
            g->phi[r] += w * d;
            for (int hv = 0; hv < 4; hv++)
                for (int dd = 0; dd < 3; dd++) g->J[r * g->ndof + 3 * col[hv] + dd] += w * o[1 + 3 * hv + dd];
        }
    }
}

/* The step's groups (after dr_lag_begin). */
static DrStatus add_groups(DrCloth *c, DrError *err)
{
    DrLagGroup g;
    double G[81];
    bool geo = c->desc.geometric_stiffness;
    double damping = c->mat.damping;
    for (int t = 0; t < c->T; t++) {
        const int *tv = c->tri + 3 * t;
        int dof[3] = {vdof(c, tv[0]), vdof(c, tv[1]), vdof(c, tv[2])};
        double *lam = c->lambda + 3 * t;
        dr_shell_membrane_group(c->x + 3 * tv[0], c->x + 3 * tv[1], c->x + 3 * tv[2], c->Bm + 4 * t, c->area[t],
                                c->k_membrane, c->nu, dof, geo ? lam : NULL, true, geo ? G : NULL, &g);
        g.lambda = lam;
        DR_TRY(dr_lag_add_with_twin(c->lag, &g, damping, err));
    }
    if (c->k_bend > 0 && c->mat.bending == DR_CLOTH_BEND_SHAPE_OPERATOR) {
        hinge_angles(c);
        for (int t = 0; t < c->T; t++) {
            if (c->bend_rows[t] == 0) continue;
            shape_group(c, t, &g);
            DR_TRY(dr_lag_add_with_twin(c->lag, &g, damping, err));
        }
    }
    if (c->k_bend > 0 && c->mat.bending == DR_CLOTH_BEND_HINGE)
        for (int q = 0; q < c->H; q++) {
            const int *hg = c->hinge + 4 * q;
            int dof[4] = {vdof(c, hg[0]), vdof(c, hg[1]), vdof(c, hg[2]), vdof(c, hg[3])};
            dr_shell_hinge_group(c->x + 3 * hg[0], c->x + 3 * hg[1], c->x + 3 * hg[2], c->x + 3 * hg[3],
                                 c->theta_bar[q], c->hinge_cinv[q], dof, &g);
            DR_TRY(dr_lag_add_with_twin(c->lag, &g, damping, err));
        }
    /* vertex–collider contacts, as detect_contacts and update_contacts left them */
    int nc = 0;
    for (int v = 0; v < c->V; v++) {
        if (!c->cflag[v]) continue;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 3;
        int d0 = vdof(c, v);
        for (int a = 0; a < 3; a++) {
            g.dof[a] = d0 + a;
            g.J[a] = c->cnormal[3 * v + a];
        }
        g.phi[0] = c->cphi[v];
        g.cinv[0] = c->desc.collider_stiffness;
        c->clambda[v] = 0;
        g.lambda = &c->clambda[v];
        DR_TRY(dr_lag_add(c->lag, &g, err));
        nc++;
    }
    c->ncontacts = nc;
    /* slide attachments: two rows per vertex, its distance from the curve along the two directions across the curve's
       tangent at the nearest point, φ_k = n_k·(x − p), held at SLIDE_STIFFNESS (a stiff spring: the vertex stays within
       its load over the stiffness of the curve, 1e-8 m per N; on a curved rail the step's chord adds (h v)²/(2R)) */
    for (int v = 0; v < c->V; v++) {
        if (!c->slide[v] || c->pinned[v]) continue;
        DrVec3 x = dr_v3(c->x[3 * v], c->x[3 * v + 1], c->x[3 * v + 2]), p = x, t = dr_v3(1, 0, 0);
        nearest_on_curve(c, x, &p, &t);
        DrVec3 a = fabs(t.x) < 0.9 ? dr_v3(1, 0, 0) : dr_v3(0, 1, 0);
        DrVec3 n1 = dr_v3_normalize(dr_v3_cross(t, a)), n2 = dr_v3_cross(t, n1);
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 2;
        g.ndof = 3;
        int d0 = vdof(c, v);
        const DrVec3 n[2] = {n1, n2};
        DrVec3 r = dr_v3_sub(x, p);
        for (int k = 0; k < 2; k++) {
            g.phi[k] = dr_v3_dot(n[k], r);
            g.cinv[k] = SLIDE_STIFFNESS;
            const double nk[3] = {n[k].x, n[k].y, n[k].z};
            for (int a3 = 0; a3 < 3; a3++) g.J[3 * k + a3] = nk[a3];
        }
        for (int a3 = 0; a3 < 3; a3++) g.dof[a3] = d0 + a3;
        DR_TRY(dr_lag_add(c->lag, &g, err));
    }
    if (c->self) DR_TRY(dr_cloth_self_add(c->self, c->lag, err));
    return DR_OK;
}

/* The nearest collider at p within reach: d (minus the thicknesses), its unit normal, velocity and friction. False
   when no collider is nearer than `reach`. */
static bool nearest_collider(const DrCloth *c, DrVec3 p, const DrClothCollider *col, int ncol, double reach, double *d,
                             DrVec3 *n, DrVec3 *vc, double *mu)
{
    bool found = false;
    for (int k = 0; k < ncol; k++) {
        DrVec3 nk;
        double dk = col[k].sdf(p, &nk, col[k].ctx) - (col[k].thickness + c->mat.collision_thickness);
        if (dk >= reach || (found && dk >= *d)) continue;
        found = true;
        *d = dk;
        double nn = dr_v3_norm(nk);
        *n = nn > 0 ? dr_v3_scale(nk, 1.0 / nn) : dr_v3(0, 1, 0);
        *vc = col[k].velocity_at ? col[k].velocity_at(p, col[k].ctx) : dr_v3(0, 0, 0);
        *mu = fmax(col[k].friction, c->mat.friction);
    }
    return found;
}

static void set_contact(DrCloth *c, int v, double phi, DrVec3 n, DrVec3 vc, double mu)
{
    c->cflag[v] = 1;
    c->cphi[v] = phi;
    c->cnormal[3 * v] = n.x, c->cnormal[3 * v + 1] = n.y, c->cnormal[3 * v + 2] = n.z;
    c->cvel[3 * v] = vc.x, c->cvel[3 * v + 1] = vc.y, c->cvel[3 * v + 2] = vc.z;
    c->cfric[v] = mu;
}

/* Contacts at the step's start: a vertex inside, or that would enter within the step at its current velocity, gets
   φ = d − thickness ≥ 0 linearised along the normal relative to the collider's motion, φ₊ = d + h n·(v₊ − v_c), so
   the row's constant is d − h n·v_c (the hair's rule). */
static void detect_contacts(DrCloth *c, double h, const DrClothCollider *col, int ncol)
{
    for (int v = 0; v < c->V; v++) {
        c->cflag[v] = 0;
        c->cban[v] = 0;
        if (c->pinned[v] || ncol == 0) continue;
        DrVec3 p = dr_v3(c->x[3 * v], c->x[3 * v + 1], c->x[3 * v + 2]);
        DrVec3 vel = dr_v3(c->v[3 * v], c->v[3 * v + 1], c->v[3 * v + 2]);
        double d = 0, mu = 0;
        DrVec3 n, vc;
        if (!nearest_collider(c, p, col, ncol, h * dr_v3_norm(vel) + 1e-12, &d, &n, &vc, &mu)) continue;
        double approach = h * dr_v3_dot(dr_v3_sub(vel, vc), n);
        if (d + fmin(approach, 0) >= 0) continue;
        set_contact(c, v, d - h * dr_v3_dot(n, vc), n, vc, mu);
    }
}

/* After a solve (velocities q̇₊): a free vertex that would end the step inside a collider (at p* = x + h v₊) becomes a
   contact linearised there, φ₊ = d(p*) + h n·(v − v₊); after the first solve only (`release`), a contact whose force
   pulls (λ = −k(φ + h n·v₊) < 0) is let go. Later passes only add, so the set settles (a vertex let go and caught
   again would otherwise alternate between pulling and entering); a contact kept while it pulls holds its vertex at
   the surface with a force of order k times a distance the solve already made small.
   With self contact (`touch`, NULL without: 1 on the vertices of the panel's self contacts, 2 on those of the ones the
   last pass added) a vertex can be held by both: a layer landing on another that lies on the collider pushes the lower
   layer into it in the first solve, so both layers' vertices get collider contacts, and the upper layer's then pulls
   it down onto the lower (4 N on a sheet of 0.03 kg in tests/validation/test_cloth, 0.4 mm into the thickness). So a
   collider contact on a vertex in self contact that pulls is let go after any solve, and not taken again in the step
   (cban: the set still only changes finitely often), and a vertex whose self contact is new waits a pass: the solve
   with that contact tells whether it still enters. Returns whether the set changed (the step is then solved
   again). */
static bool update_contacts(DrCloth *c, double h, const DrClothCollider *col, int ncol, const double *qdot,
                            bool release, const unsigned char *touch)
{
    bool changed = false;
    for (int v = 0; v < c->V; v++) {
        if (c->pinned[v] || ncol == 0) continue;
        int d0 = vdof(c, v);
        DrVec3 w = dr_v3(qdot[d0], qdot[d0 + 1], qdot[d0 + 2]);
        if (c->cflag[v]) {
            bool layered = touch && touch[v];
            if (!release && !layered) continue;
            DrVec3 n = dr_v3(c->cnormal[3 * v], c->cnormal[3 * v + 1], c->cnormal[3 * v + 2]);
            double lambda = -c->desc.collider_stiffness * (c->cphi[v] + h * dr_v3_dot(n, w));
            if (lambda < 0) {
                c->cflag[v] = 0;
                c->cban[v] = !release;
                changed = true;
            }
            continue;
        }
        if (c->cban[v] || (touch && touch[v] == 2)) continue;
        DrVec3 p = dr_v3(c->x[3 * v] + h * w.x, c->x[3 * v + 1] + h * w.y, c->x[3 * v + 2] + h * w.z);
        double d = 0, mu = 0;
        DrVec3 n, vc;
        if (!nearest_collider(c, p, col, ncol, 0.0, &d, &n, &vc, &mu)) continue;
        set_contact(c, v, d - h * dr_v3_dot(n, w), n, vc, mu);
        changed = true;
    }
    return changed;
}

/* The solve's velocities (DOF order) into vsolve (mesh order). */
static void gather_velocities(DrCloth *c, const double *qdot)
{
    for (int v = 0; v < c->V; v++) {
        int d0 = vdof(c, v);
        for (int a = 0; a < 3; a++) c->vsolve[3 * v + a] = qdot[d0 + a];
    }
}

/* Positions from the solve's velocities, with friction at the contacts; false (state restored) when non-finite. */
static bool advance(DrCloth *c, double h, const double *qdot)
{
    memcpy(c->save, c->x, 3 * (size_t)c->V * sizeof(double));
    memcpy(c->save + 3 * c->V, c->v, 3 * (size_t)c->V * sizeof(double));
    for (int v = 0; v < c->V; v++) {
        int d0 = vdof(c, v);
        double w[3] = {qdot[d0], qdot[d0 + 1], qdot[d0 + 2]};
        if (c->cflag[v]) {
            const double *n = c->cnormal + 3 * v, *vc = c->cvel + 3 * v;
            double rel[3] = {w[0] - vc[0], w[1] - vc[1], w[2] - vc[2]};
            double vn = rel[0] * n[0] + rel[1] * n[1] + rel[2] * n[2];
            double vt[3] = {rel[0] - vn * n[0], rel[1] - vn * n[1], rel[2] - vn * n[2]};
            double vtn = sqrt(vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2]);
            double dvn = fmax(c->clambda[v], 0) * h / c->mass[v];
            double keep = vtn > 0 ? fmax(0, 1 - c->cfric[v] * dvn / vtn) : 0;
            for (int a = 0; a < 3; a++) w[a] = vc[a] + vn * n[a] + keep * vt[a];
        }
        for (int a = 0; a < 3; a++) c->v[3 * v + a] = w[a];
    }
    if (c->self) dr_cloth_self_friction(c->self, h, c->v);
    bool finite = true;
    for (int i = 0; i < 3 * c->V; i++) {
        c->x[i] += h * c->v[i];
        finite = finite && isfinite(c->x[i]) && isfinite(c->v[i]);
    }
    if (!finite) {
        memcpy(c->x, c->save, 3 * (size_t)c->V * sizeof(double));
        memcpy(c->v, c->save + 3 * c->V, 3 * (size_t)c->V * sizeof(double));
    }
    return finite;
}

DrStatus dr_cloth_predict_dofs(DrCloth *c, double h, const DrClothCollider *colliders, int ncolliders, DrError *err)
{
    assert(h > 0 && c->phase == CLOTH_IDLE && c->desc.system);
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(c->lag, &d, err));
    fill_dofs(c, &d);
    detect_contacts(c, h, colliders, ncolliders);
    if (c->self) DR_TRY(dr_cloth_self_detect(c->self, h, c->x, c->v, err));
    c->iterations = 0;
    c->converged = true;
    c->h_step = h;
    return DR_OK;
}

DrStatus dr_cloth_predict_groups(DrCloth *c, DrError *err) { return add_groups(c, err); }

DrStatus dr_cloth_update_contacts(DrCloth *c, const DrClothCollider *colliders, int ncolliders, int pass, bool *changed,
                                  DrError *err)
{
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(c->lag, &d, err));
    bool self_changed = false;
    if (c->self) DR_TRY(dr_cloth_self_update(c->self, c->h_step, c->x, d.qdot_out, pass == 0, &self_changed, c->touch, err));
    *changed = update_contacts(c, c->h_step, colliders, ncolliders, d.qdot_out, pass == 0, c->self ? c->touch : NULL) ||
               self_changed;
    return DR_OK;
}

void dr_cloth_take(DrCloth *c)
{
    DrLagDofs d;
    DrError e;
    if (dr_lag_dofs(c->lag, &d, &e) != DR_OK) return; /* sized since predict_dofs: cannot fail */
    gather_velocities(c, d.qdot_out);
    c->phase = CLOTH_PREDICTED;
}

int dr_cloth_vertex_dof(const DrCloth *c, int v) { return vdof(c, v); }

DrStatus dr_cloth_predict(DrCloth *c, double h, const DrClothCollider *colliders, int ncolliders, DrError *err)
{
    assert(h > 0 && c->phase == CLOTH_IDLE && !c->desc.system);
    double t0 = dr_time_now();
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(c->lag, &d, err));
    fill_dofs(c, &d);
    detect_contacts(c, h, colliders, ncolliders);
    if (c->self) DR_TRY(dr_cloth_self_detect(c->self, h, c->x, c->v, err));
    DrLagStats ls;
    c->iterations = 0;
    for (int pass = 0;; pass++) {
        DR_TRY(dr_lag_begin(c->lag, h, d.mass, d.qdot, d.fext, d.prescribed, d.qdot_prescribed, err));
        DR_TRY(add_groups(c, err));
        DrStatus st = dr_lag_solve_load(c->lag, NULL, d.qdot_out, &ls, err);
        if (st != DR_OK && st != DR_WARN_NOT_CONVERGED) return st;
        c->iterations += ls.iterations;
        if (pass + 1 == CONTACT_PASSES) break;
        bool self_changed = false;
        if (c->self)
            DR_TRY(dr_cloth_self_update(c->self, h, c->x, d.qdot_out, pass == 0, &self_changed, c->touch, err));
        bool changed = update_contacts(c, h, colliders, ncolliders, d.qdot_out, pass == 0, c->self ? c->touch : NULL);
        if (!changed && !self_changed) break;
    }
    c->converged = ls.converged;
    gather_velocities(c, d.qdot_out);
    c->h_step = h;
    c->phase = CLOTH_PREDICTED;
    c->seconds = dr_time_now() - t0;
    return ls.converged ? DR_OK : DR_WARN_NOT_CONVERGED;
}

DrStatus dr_cloth_solve(DrCloth *c, const double *force, const double *dforce_dv, DrError *err)
{
    assert(c->phase != CLOTH_IDLE);
    double t0 = dr_time_now();
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(c->lag, &d, err));
    for (int v = 0; v < c->V; v++) {
        int d0 = vdof(c, v);
        for (int a = 0; a < 3; a++) d.force[d0 + a] = force ? force[3 * v + a] : 0.0;
    }
    DrLagLoad load = {force ? d.force : NULL, dforce_dv ? c->V : 0, c->block_dof, dforce_dv};
    DrLagStats ls;
    DrStatus st = dr_lag_solve_load(c->lag, &load, d.qdot_out, &ls, err);
    if (st != DR_OK && st != DR_WARN_NOT_CONVERGED) return st;
    c->iterations += ls.iterations;
    c->converged = ls.converged;
    gather_velocities(c, d.qdot_out);
    c->phase = CLOTH_SOLVED;
    c->seconds += dr_time_now() - t0;
    return st;
}

const double *dr_cloth_solved_velocities(const DrCloth *c) { return c->vsolve; }

DrStatus dr_cloth_commit(DrCloth *c, DrClothStats *stats, DrError *err)
{
    assert(c->phase != CLOTH_IDLE);
    double t0 = dr_time_now();
    DrLagDofs d;
    DR_TRY(dr_lag_dofs(c->lag, &d, err));
    c->phase = CLOTH_IDLE;
    if (!c->desc.system) dr_lag_update_multipliers(c->lag, d.qdot_out); /* else the system's owner did */
    if (!advance(c, c->h_step, d.qdot_out))
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                            "%s: the cloth's state became non-finite (time step %g s too large for its stiffness, or a "
                            "collider too stiff); raise ClothSolver.substeps or lower the stiffness",
                            c->name, c->h_step);
    c->seconds += dr_time_now() - t0;
    if (stats) {
        stats->iterations = c->iterations;
        stats->converged = c->converged;
        stats->collider_contacts = c->ncontacts;
        stats->self_contacts = c->self ? dr_cloth_self_count(c->self) : 0;
        stats->seconds = c->seconds;
    }
    return c->converged ? DR_OK : DR_WARN_NOT_CONVERGED;
}

DrStatus dr_cloth_step(DrCloth *c, double h, const DrClothCollider *colliders, int ncolliders, DrClothStats *stats,
                       DrError *err)
{
    assert(h > 0);
    DrStatus st = dr_cloth_predict(c, h, colliders, ncolliders, err);
    if (st < 0) return st;
    return dr_cloth_commit(c, stats, err);
}

void dr_cloth_samples(const DrCloth *c, DrClothSamples *out)
{
    *out = (DrClothSamples){c->V, c->x, c->vsolve, c->mass, c->pinned};
}

double *dr_cloth_multipliers(DrCloth *c, int *count)
{
    *count = 3 * c->T;
    return c->lambda;
}

void dr_cloth_energy(const DrCloth *c, DrClothEnergy *e)
{
    memset(e, 0, sizeof *e);
    DrVec3 g = c->desc.gravity;
    for (int v = 0; v < c->V; v++) {
        const double *x = c->x + 3 * v, *w = c->v + 3 * v;
        e->kinetic += 0.5 * c->mass[v] * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
        e->gravity -= c->mass[v] * (g.x * x[0] + g.y * x[1] + g.z * x[2]);
    }
    for (int t = 0; t < c->T; t++) {
        const int *tv = c->tri + 3 * t;
        e->membrane += dr_shell_membrane_energy(c->x + 3 * tv[0], c->x + 3 * tv[1], c->x + 3 * tv[2], c->Bm + 4 * t,
                                                c->area[t], c->k_membrane, c->nu);
    }
    if (c->k_bend > 0 && c->mat.bending == DR_CLOTH_BEND_HINGE)
        for (int q = 0; q < c->H; q++) {
            const int *hg = c->hinge + 4 * q;
            double th = dr_shell_hinge_angle(c->x + 3 * hg[0], c->x + 3 * hg[1], c->x + 3 * hg[2], c->x + 3 * hg[3], NULL);
            double d = wrap(th - c->theta_bar[q]);
            e->bending += 0.5 * c->hinge_cinv[q] * d * d;
        }
    if (c->k_bend > 0 && c->mat.bending == DR_CLOTH_BEND_SHAPE_OPERATOR) {
        double *dth = NULL;
        if (dr_calloc((size_t)c->H + 1, sizeof(double), &dth, NULL) != DR_OK) {
            e->bending = NAN;
            return;
        }
        for (int q = 0; q < c->H; q++) {
            const int *hg = c->hinge + 4 * q;
            dth[q] = wrap(dr_shell_hinge_angle(c->x + 3 * hg[0], c->x + 3 * hg[1], c->x + 3 * hg[2], c->x + 3 * hg[3],
                                               NULL) - c->theta_bar[q]);
        }
        for (int t = 0; t < c->T; t++)
            for (int r = 0; r < c->bend_rows[t]; r++) {
                double phi = 0;
                for (int i = 0; i < 3; i++) {
                    int k = c->tri_hinge[3 * t + i];
                    if (k >= 0) phi += c->bend_u[9 * t + 3 * r + i] * dth[k];
                }
                e->bending += 0.5 * c->bend_cinv[3 * t + r] * phi * phi;
            }
        free(dth);
    }
}

void dr_cloth_normals(const DrCloth *c, double *n)
{
    memset(n, 0, 3 * (size_t)c->V * sizeof(double));
    for (int t = 0; t < c->T; t++) {
        const int *tv = c->tri + 3 * t;
        const double *a = c->x + 3 * tv[0], *b = c->x + 3 * tv[1], *d = c->x + 3 * tv[2];
        DrVec3 N = dr_v3_cross(dr_v3(b[0] - a[0], b[1] - a[1], b[2] - a[2]), dr_v3(d[0] - a[0], d[1] - a[1], d[2] - a[2]));
        for (int k = 0; k < 3; k++) {
            n[3 * tv[k]] += N.x, n[3 * tv[k] + 1] += N.y, n[3 * tv[k] + 2] += N.z;
        }
    }
    for (int v = 0; v < c->V; v++) {
        double l = sqrt(n[3 * v] * n[3 * v] + n[3 * v + 1] * n[3 * v + 1] + n[3 * v + 2] * n[3 * v + 2]);
        if (l > 0)
            for (int a = 0; a < 3; a++) n[3 * v + a] /= l;
    }
}
