/* drench wet: capture and dripping between the film and the bulk liquid (wet.h, "capture and dripping"; PHYSICS §5).
 *
 * Capture finds, for every particle, the nearest edge within reach through a dense lattice over the strands' box
 * (cells at least as wide as the largest reach, each edge listed in every cell its inflated box meets), in parallel
 * over particles with one result slot each; the offers are then summed per vertex in particle order, so the result
 * does not depend on the thread count. Dripping bins the vertices by the bulk's cells (sorted by cell, then vertex)
 * and walks the cells in order. Both move film through dr_film_transfer, which books the momentum.
 * Memory: buffers grow with the largest call and are kept. */
#include <stdlib.h>
#include <string.h>

#include "core/sort.h"
#include "wet/wet.h"

#define REMNANT 1e-3        /* a particle left with less than this times V₀ goes whole to the film when it has room */
#define LATTICE_MAX 4194304 /* cells of the capture lattice at most */

typedef struct VKey { long key; int v; } VKey;
#define VKEY_LESS(a, b) ((a)->key < (b)->key)
DR_DEFINE_STABLE_SORT(sort_vkeys, VKey, VKEY_LESS)

struct DrExchange {
    DrCaptureDesc cap;
    DrDripDesc drip;
    long pcap;            /* particle slots */
    int *near;            /* per particle: the capturing edge (global edge index), −1 for none */
    double *s;            /* per particle: the closest point's position along it, in [0, 1] */
    long vcap;            /* vertex slots */
    double *dV, *Pin, *Pout, *room, *offer, *an;
    int *edge_v0;         /* per edge: its first vertex */
    long ecap;
    long *cell_start, ncell_cap;
    int *cell_edges;
    long cell_edges_cap;
    VKey *vkey, *vtmp;    /* dripping: the vertices by cell */
    double *tan;          /* 3V: dripping: the vertices' unit tangents */
    DrDrops drops;
    long drop_cap;
    double *frac;         /* submersion: the bulk's volume fraction per cell */
    long frac_cap;
};

void dr_capture_desc_default(DrCaptureDesc *d) { *d = (DrCaptureDesc){.rate = 10.0, .capacity = 1.0, .reach = 1.0}; }

void dr_drip_desc_default(DrDripDesc *d)
{
    *d = (DrDripDesc){.radius_scale = 0.5, .middle = true, .root = false, .tip = true, .min_drop = 0.5,
                      .pool_release = 1.0, .budget = 20000};
}

DrStatus dr_exchange_create(const DrCaptureDesc *capture, const DrDripDesc *drip, DrExchange **out, DrError *err)
{
    *out = NULL;
#define BAD(what, v, cond, range)                                                                                   \
    if (!(cond))                                                                                                     \
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "wet exchange: " what " = %g is out of range; it must be " \
                            range, (double)(v))
    BAD("DrCaptureDesc.rate", capture->rate, capture->rate >= 0 && isfinite(capture->rate), ">= 0 (1/s)");
    BAD("DrCaptureDesc.capacity", capture->capacity, capture->capacity >= 0 && capture->capacity <= 1, "in [0, 1]");
    BAD("DrCaptureDesc.reach", capture->reach, capture->reach >= 0 && isfinite(capture->reach),
        ">= 0 (particle radii)");
    BAD("DrDripDesc.radius_scale", drip->radius_scale, drip->radius_scale > 0 && isfinite(drip->radius_scale), "> 0");
    BAD("DrDripDesc.min_drop", drip->min_drop, drip->min_drop >= 0 && isfinite(drip->min_drop), ">= 0");
    BAD("DrDripDesc.pool_release", drip->pool_release, drip->pool_release > 0 && isfinite(drip->pool_release), "> 0");
    BAD("DrDripDesc.budget", drip->budget, drip->budget >= 1, ">= 1 (drops per step)");
#undef BAD
    DrExchange *e = NULL;
    DR_TRY(dr_calloc(1, sizeof *e, &e, err));
    e->cap = *capture;
    e->drip = *drip;
    *out = e;
    return DR_OK;
}

void dr_exchange_destroy(DrExchange **ep)
{
    DrExchange *e = *ep;
    if (!e) return;
    void *a[] = {e->near, e->s, e->dV, e->Pin, e->Pout, e->room, e->offer, e->an, e->edge_v0, e->cell_start,
                 e->cell_edges, e->vkey, e->vtmp, e->tan, e->frac, e->drops.x, e->drops.v, e->drops.vol};
    for (size_t i = 0; i < sizeof a / sizeof *a; i++) free(a[i]);
    free(e);
    *ep = NULL;
}

static inline DrVec3 ld3(const double *a) { return dr_v3(a[0], a[1], a[2]); }

/* Per-vertex buffers for nverts vertices and nedges edges. */
static DrStatus grow_vertices(DrExchange *e, long V, long E, DrError *err)
{
    if (V > e->vcap) {
        long c = V + V / 4 + 16;
        DR_TRY(dr_realloc((size_t)c, sizeof(double), &e->dV, err));
        DR_TRY(dr_realloc((size_t)(3 * c), sizeof(double), &e->Pin, err));
        DR_TRY(dr_realloc((size_t)(3 * c), sizeof(double), &e->Pout, err));
        DR_TRY(dr_realloc((size_t)c, sizeof(double), &e->room, err));
        DR_TRY(dr_realloc((size_t)c, sizeof(double), &e->offer, err));
        DR_TRY(dr_realloc((size_t)c, sizeof(double), &e->an, err));
        DR_TRY(dr_realloc((size_t)c, sizeof(VKey), &e->vkey, err));
        DR_TRY(dr_realloc((size_t)c, sizeof(VKey), &e->vtmp, err));
        DR_TRY(dr_realloc((size_t)(3 * c), sizeof(double), &e->tan, err));
        e->vcap = c;
    }
    if (E > e->ecap) {
        long c = E + E / 4 + 16;
        DR_TRY(dr_realloc((size_t)c, sizeof(int), &e->edge_v0, err));
        e->ecap = c;
    }
    return DR_OK;
}

static DrStatus grow_drops(DrExchange *e, long n, DrError *err)
{
    if (n <= e->drop_cap) return DR_OK;
    long c = n + n / 2 + 64;
    DR_TRY(dr_realloc((size_t)(3 * c), sizeof(double), &e->drops.x, err));
    DR_TRY(dr_realloc((size_t)(3 * c), sizeof(double), &e->drops.v, err));
    DR_TRY(dr_realloc((size_t)c, sizeof(double), &e->drops.vol, err));
    e->drop_cap = c;
    return DR_OK;
}

static inline double sphere_radius(double vol) { return cbrt(3.0 * vol / (4.0 * DR_PI)); }

/* J/kg: ½|v|² − g·x of particle p */
static double specific_energy(const DrFilmDesc *fd, const DrBulk *b, long p)
{
    DrVec3 v = ld3(b->v + 3 * p), x = ld3(b->x + 3 * p);
    return 0.5 * dr_v3_dot(v, v) - dr_v3_dot(fd->gravity, x);
}

/* ---- capture ---------------------------------------------------------------------------------------------------- */

typedef struct Lattice {
    DrVec3 lo;
    double h;
    int n[3];
} Lattice;

static inline long lattice_cell(const Lattice *L, DrVec3 p)
{
    double q[3] = {(p.x - L->lo.x) / L->h, (p.y - L->lo.y) / L->h, (p.z - L->lo.z) / L->h};
    int c[3];
    for (int a = 0; a < 3; a++) {
        if (!(q[a] >= 0) || q[a] >= L->n[a]) return -1;
        c[a] = (int)q[a];
    }
    return c[0] + (long)L->n[0] * (c[1] + (long)L->n[1] * c[2]);
}

typedef struct CaptureCtx {
    DrExchange *e;
    const DrBulk *b;
    const DrWetStrands *s;
    const Lattice *L;
    const double *H;    /* per vertex: the film's outer radius */
    double reach;
} CaptureCtx;

/* The distance from p to segment a–b and the closest point's parameter. */
static inline double segment_distance(DrVec3 p, DrVec3 a, DrVec3 b, double *t)
{
    DrVec3 d = dr_v3_sub(b, a), w = dr_v3_sub(p, a);
    double dd = dr_v3_dot(d, d), s = dd > 0 ? dr_v3_dot(w, d) / dd : 0.0;
    s = s < 0 ? 0 : s > 1 ? 1 : s;
    *t = s;
    return dr_v3_norm(dr_v3_sub(w, dr_v3_scale(d, s)));
}

static void capture_search(long begin, long end, void *vctx)
{
    const CaptureCtx *c = vctx;
    DrExchange *e = c->e;
    for (long p = begin; p < end; p++) {
        e->near[p] = -1;
        double vol = c->b->vol[p];
        if (!(vol > 0)) continue;
        DrVec3 xp = ld3(c->b->x + 3 * p);
        long cell = lattice_cell(c->L, xp);
        if (cell < 0) continue;
        double rp = c->reach * sphere_radius(vol), best = INFINITY, bs = 0;
        int be = -1;
        for (long q = e->cell_start[cell]; q < e->cell_start[cell + 1]; q++) {
            int ed = e->cell_edges[q], i = e->edge_v0[ed];
            if (!(e->room[i] > 0 || e->room[i + 1] > 0)) continue;
            double t, d = segment_distance(xp, ld3(c->s->x + 3 * i), ld3(c->s->x + 3 * i + 3), &t);
            double R = fmax(c->H[i], c->H[i + 1]) + rp;
            if (d <= R && (d < best || (d == best && ed < be))) best = d, be = ed, bs = t;
        }
        e->near[p] = be;
        e->s[p] = bs;
    }
}

DrStatus dr_exchange_capture(DrExchange *e, DrFilm *f, const DrWetStrands *s, DrBulk *b, double h,
                             DrExchangeStats *stats, DrError *err)
{
    const DrFilmDesc *fd = dr_film_desc(f);
    const int *off = dr_film_offsets(f);
    DrFilmState fs = dr_film_state(f);
    long V = fs.nverts, E = fs.nedges;
    if (V == 0 || b->n == 0 || !(e->cap.rate > 0) || !(h > 0)) return DR_OK;
    DR_TRY(grow_vertices(e, V, E, err));
    if (b->n > e->pcap) {
        long c = b->n + b->n / 4 + 64;
        DR_TRY(dr_realloc((size_t)c, sizeof(int), &e->near, err));
        DR_TRY(dr_realloc((size_t)c, sizeof(double), &e->s, err));
        e->pcap = c;
    }
    /* room per vertex, the film's outer radii, the edges' first vertices */
    const double *r = dr_film_radius(f), *lv = dr_film_lengths(f);
    double *H = e->an; /* reused: outer radius per vertex */
    dr_film_heights(f, H);
    double cap_ratio = e->cap.capacity * (fd->max_ratio * fd->max_ratio - 1.0), Hmax = 0;
    bool any_room = false;
    for (long i = 0; i < V; i++) {
        e->room[i] = fmax(0.0, cap_ratio * DR_PI * r[i] * r[i] * lv[i] - fs.volume[i]);
        any_room = any_room || e->room[i] > 0;
        Hmax = fmax(Hmax, H[i]);
    }
    if (!any_room) return DR_OK;
    for (int k = 0, ed = 0; k < fs.nstrands; k++)
        for (int i = off[k]; i < off[k + 1] - 1; i++) e->edge_v0[ed++] = i;
    /* the lattice over the strands' box, cells at least the largest reach */
    double vmax = 0;
    for (long p = 0; p < b->n; p++) vmax = fmax(vmax, b->vol[p]);
    double R = Hmax + e->cap.reach * sphere_radius(vmax);
    DrVec3 lo = ld3(s->x), hi = lo;
    for (long i = 0; i < V; i++) {
        DrVec3 xi = ld3(s->x + 3 * i);
        lo = dr_v3_min(lo, xi);
        hi = dr_v3_max(hi, xi);
    }
    lo = dr_v3_sub(lo, dr_v3(R, R, R));
    hi = dr_v3_add(hi, dr_v3(R, R, R));
    Lattice L = {lo, fmax(R, 1e-12), {1, 1, 1}};
    for (;;) {
        double ext[3] = {hi.x - lo.x, hi.y - lo.y, hi.z - lo.z};
        long total = 1;
        for (int a = 0; a < 3; a++) {
            L.n[a] = (int)fmin(ceil(ext[a] / L.h), 1e6);
            if (L.n[a] < 1) L.n[a] = 1;
            total *= L.n[a];
        }
        if (total <= LATTICE_MAX) break;
        L.h *= 1.5;
    }
    long ncells = (long)L.n[0] * L.n[1] * L.n[2];
    if (ncells + 1 > e->ncell_cap) {
        DR_TRY(dr_realloc((size_t)(ncells + 1), sizeof(long), &e->cell_start, err));
        e->ncell_cap = ncells + 1;
    }
    memset(e->cell_start, 0, (size_t)(ncells + 1) * sizeof(long));
    /* counting sort of (cell, edge), two passes over every edge's inflated box: the counts go to cell_start[c + 1],
       become the cells' starts (shifted by one), and the fill advances each to its cell's end */
    for (int pass = 0; pass < 2; pass++) {
        if (pass == 1) {
            long acc = 0;
            for (long c = 0; c < ncells; c++) {
                long n = e->cell_start[c + 1];
                e->cell_start[c + 1] = acc;
                acc += n;
            }
            if (acc + 1 > e->cell_edges_cap) {
                DR_TRY(dr_realloc((size_t)acc + 1, sizeof(int), &e->cell_edges, err));
                e->cell_edges_cap = acc + 1;
            }
        }
        for (long ed = 0; ed < E; ed++) {
            int i = e->edge_v0[ed];
            DrVec3 a = ld3(s->x + 3 * i), c = ld3(s->x + 3 * i + 3);
            DrVec3 elo = dr_v3_sub(dr_v3_min(a, c), dr_v3(R, R, R)), ehi = dr_v3_add(dr_v3_max(a, c), dr_v3(R, R, R));
            int c0[3], c1[3];
            double l3[3] = {elo.x, elo.y, elo.z}, h3[3] = {ehi.x, ehi.y, ehi.z}, o3[3] = {lo.x, lo.y, lo.z};
            for (int d = 0; d < 3; d++) {
                c0[d] = (int)floor((l3[d] - o3[d]) / L.h);
                c1[d] = (int)floor((h3[d] - o3[d]) / L.h);
                if (c0[d] < 0) c0[d] = 0;
                if (c1[d] > L.n[d] - 1) c1[d] = L.n[d] - 1;
            }
            for (int z = c0[2]; z <= c1[2]; z++)
                for (int y = c0[1]; y <= c1[1]; y++)
                    for (int x = c0[0]; x <= c1[0]; x++) {
                        long c = x + (long)L.n[0] * (y + (long)L.n[1] * z);
                        if (pass == 0)
                            e->cell_start[c + 1]++;
                        else
                            e->cell_edges[e->cell_start[c + 1]++] = (int)ed;
                    }
        }
    }
    CaptureCtx ctx = {e, b, s, &L, H, e->cap.reach};
    dr_parallel_for(b->n, 2048, capture_search, &ctx);
    /* the offers, summed per vertex in particle order */
    double share = -expm1(-e->cap.rate * h);
    memset(e->offer, 0, (size_t)V * sizeof(double));
    for (long p = 0; p < b->n; p++) {
        int ed = e->near[p];
        if (ed < 0) continue;
        int i = e->edge_v0[ed];
        double o = b->vol[p] * share;
        e->offer[i] += o * (1.0 - e->s[p]);
        e->offer[i + 1] += o * e->s[p];
    }
    for (long i = 0; i < V; i++) e->offer[i] = e->offer[i] > e->room[i] ? e->room[i] / e->offer[i] : 1.0;
    memset(e->dV, 0, (size_t)V * sizeof(double));
    memset(e->Pin, 0, 3 * (size_t)V * sizeof(double));
    double rho = fd->density, got = 0, rem = REMNANT * b->particle_volume, energy = 0;
    DrVec3 P = dr_v3(0, 0, 0);
    long whole = 0;
    for (long p = 0; p < b->n; p++) {
        int ed = e->near[p];
        if (ed < 0) continue;
        int i = e->edge_v0[ed];
        double o = b->vol[p] * share, a0 = o * (1.0 - e->s[p]) * e->offer[i], a1 = o * e->s[p] * e->offer[i + 1];
        double left = b->vol[p] - a0 - a1;
        e->room[i] -= a0;
        e->room[i + 1] -= a1;
        e->dV[i] += a0;
        e->dV[i + 1] += a1;
        for (int d = 0; d < 3; d++) {
            e->Pin[3 * i + d] += rho * a0 * b->v[3 * p + d];
            e->Pin[3 * i + 3 + d] += rho * a1 * b->v[3 * p + d];
        }
        got += b->vol[p] - left;
        P = dr_v3_add(P, dr_v3_scale(ld3(b->v + 3 * p), rho * (b->vol[p] - left)));
        energy += rho * (b->vol[p] - left) * specific_energy(fd, b, p);
        b->vol[p] = left;
    }
    /* the remnants, whole, to the vertex with more room left, where they fit */
    for (long p = 0; p < b->n; p++) {
        int ed = e->near[p];
        double left = b->vol[p];
        if (ed < 0 || !(left < rem) || !(left > 0)) continue;
        int i = e->edge_v0[ed], j = e->room[i] >= e->room[i + 1] ? i : i + 1;
        if (!(e->room[j] >= left)) continue;
        e->room[j] -= left;
        e->dV[j] += left;
        for (int d = 0; d < 3; d++) e->Pin[3 * j + d] += rho * left * b->v[3 * p + d];
        got += left;
        P = dr_v3_add(P, dr_v3_scale(ld3(b->v + 3 * p), rho * left));
        energy += rho * left * specific_energy(fd, b, p);
        b->vol[p] = 0;
        whole++;
    }
    if (got > 0) dr_film_transfer(f, s->x, e->dV, e->Pin, e->Pout, s->v, s->mass);
    if (stats) {
        stats->captured += got;
        stats->captured_momentum = dr_v3_add(stats->captured_momentum, P);
        stats->captured_particles += whole;
        stats->captured_energy += energy;
    }
    return DR_OK;
}

/* ---- dripping --------------------------------------------------------------------------------------------------- */

/* The unit tangent at vertex i of the strand o .. o + n − 1 (central difference; one-sided at the ends). */
static DrVec3 vertex_tangent(const double *x, int o, int n, int i)
{
    int a = i > o ? i - 1 : i, c = i < o + n - 1 ? i + 1 : i;
    DrVec3 d = dr_v3_sub(ld3(x + 3 * c), ld3(x + 3 * a));
    double l = dr_v3_norm(d);
    return l > 0 ? dr_v3_scale(d, 1 / l) : dr_v3(1, 0, 0);
}

/* g − a at vertex i, a the strand's acceleration over its last step (0 without one). */
static DrVec3 effective_gravity(const DrFilmDesc *fd, const DrWetStrands *s, int i)
{
    return s->accel ? dr_v3_sub(fd->gravity, ld3(s->accel + 3 * i)) : fd->gravity;
}

static DrVec3 clamp_box(DrVec3 p, const DrBulk *b)
{
    double eps = 1e-6 * b->dx;
    double q[3] = {p.x, p.y, p.z}, lo[3] = {b->lo.x, b->lo.y, b->lo.z}, hi[3] = {b->hi.x, b->hi.y, b->hi.z};
    for (int a = 0; a < 3; a++) q[a] = fmin(fmax(q[a], lo[a] + eps), hi[a] - eps);
    return dr_v3(q[0], q[1], q[2]);
}

/* n equal drops of total volume vol and momentum P (kg m/s) around centre c, spread along unit t. */
static DrStatus add_drops(DrExchange *e, const DrBulk *b, double rho, long n, double vol, DrVec3 P, DrVec3 c,
                          DrVec3 t, DrError *err)
{
    DR_TRY(grow_drops(e, e->drops.n + n, err));
    double each = vol / (double)n, rd = sphere_radius(each);
    DrVec3 v = dr_v3_scale(P, 1.0 / (rho * vol));
    for (long j = 0; j < n; j++) {
        DrVec3 x = clamp_box(dr_v3_add(c, dr_v3_scale(t, 2.0 * rd * ((double)j - 0.5 * (double)(n - 1)))), b);
        long q = e->drops.n++;
        e->drops.x[3 * q] = x.x, e->drops.x[3 * q + 1] = x.y, e->drops.x[3 * q + 2] = x.z;
        e->drops.v[3 * q] = v.x, e->drops.v[3 * q + 1] = v.y, e->drops.v[3 * q + 2] = v.z;
        e->drops.vol[q] = each;
    }
    return DR_OK;
}

DrStatus dr_exchange_drip(DrExchange *e, DrFilm *f, const DrWetStrands *s, const DrBulk *b, DrDrops *drops,
                          DrExchangeStats *stats, DrError *err)
{
    e->drops.n = 0;
    *drops = e->drops;
    const DrFilmDesc *fd = dr_film_desc(f);
    const int *off = dr_film_offsets(f);
    DrFilmState fs = dr_film_state(f);
    long V = fs.nverts;
    if (V == 0) return DR_OK;
    DR_TRY(grow_vertices(e, V, fs.nedges, err));
    const double *r = dr_film_radius(f), *lv = dr_film_lengths(f);
    double rho = fd->density, V0 = b->particle_volume, reach = e->cap.reach, dripped = 0, held = 0;
    DrVec3 Pd = dr_v3(0, 0, 0);
    long budget = e->drip.budget;
    double *H = e->room; /* reused: outer radius per vertex */
    dr_film_heights(f, H);
    memset(e->dV, 0, (size_t)V * sizeof(double));
    bool any = false;
    if (e->drip.middle) {
        /* per vertex: the normal acceleration a_n = |(g − a)⊥|, and its cell */
        double lo3[3] = {b->lo.x, b->lo.y, b->lo.z}, hi3[3] = {b->hi.x, b->hi.y, b->hi.z};
        long nc[3];
        for (int a = 0; a < 3; a++) nc[a] = (long)ceil((hi3[a] - lo3[a]) / b->dx) + 1;
        for (int k = 0; k < fs.nstrands; k++) {
            int o = off[k], n = off[k + 1] - o;
            for (int i = o; i < o + n; i++) {
                DrVec3 t = vertex_tangent(s->x, o, n, i), g = effective_gravity(fd, s, i);
                e->tan[3 * i] = t.x, e->tan[3 * i + 1] = t.y, e->tan[3 * i + 2] = t.z;
                e->an[i] = dr_v3_norm(dr_v3_sub(g, dr_v3_scale(t, dr_v3_dot(g, t))));
                long key = 0;
                for (int a = 2; a >= 0; a--) {
                    long c = (long)floor((s->x[3 * i + a] - lo3[a]) / b->dx);
                    c = c < 0 ? 0 : c >= nc[a] ? nc[a] - 1 : c;
                    key = key * nc[a] + c;
                }
                e->vkey[i] = (VKey){key, i};
            }
        }
        sort_vkeys(e->vkey, e->vtmp, (size_t)V);
        double sigma = fd->surface_tension, c2 = e->drip.radius_scale * e->drip.radius_scale;
        for (long q0 = 0, q1; q0 < V; q0 = q1) {
            double vol = 0, len = 0, rl = 0, al = 0;
            for (q1 = q0; q1 < V && e->vkey[q1].key == e->vkey[q0].key; q1++) {
                int i = e->vkey[q1].v;
                vol += fs.volume[i];
                len += lv[i];
                rl += r[i] * lv[i];
                al += e->an[i] * lv[i];
            }
            if (!(vol > 0) || !(len > 0)) continue;
            double an = al / len, vmax = an > 0 ? 4.0 * DR_PI * (rl / len) * sigma / (rho * an) * c2 : INFINITY;
            double ex = vol - vmax;
            if (!(ex > 0) || ex < e->drip.min_drop * V0) continue;
            long nd = (long)ceil(ex / V0);
            if (nd > budget) {
                held += ex;
                continue;
            }
            budget -= nd;
            double frac = ex / vol;
            for (long q = q0; q < q1; q++) {
                int i = e->vkey[q].v;
                e->dV[i] = -fs.volume[i] * frac;
            }
            any = true;
        }
    }
    if (any) {
        memset(e->Pin, 0, 3 * (size_t)V * sizeof(double));
        dr_film_transfer(f, s->x, e->dV, e->Pin, e->Pout, s->v, s->mass);
        dr_film_heights(f, H);
        /* the drops of each cell that dripped, in cell order */
        for (long q0 = 0, q1; q0 < V; q0 = q1) {
            double ex = 0, hmax = 0;
            DrVec3 P = dr_v3(0, 0, 0), c = dr_v3(0, 0, 0), T = dr_v3(0, 0, 0), G = dr_v3(0, 0, 0);
            for (q1 = q0; q1 < V && e->vkey[q1].key == e->vkey[q0].key; q1++) {
                int i = e->vkey[q1].v;
                if (!(e->dV[i] < 0)) continue;
                double w = -e->dV[i];
                ex += w;
                P = dr_v3_add(P, ld3(e->Pout + 3 * i));
                c = dr_v3_add(c, dr_v3_scale(ld3(s->x + 3 * i), w));
                DrVec3 t = ld3(e->tan + 3 * i), g = effective_gravity(fd, s, i);
                if (dr_v3_dot(t, T) < 0) t = dr_v3_scale(t, -1);
                T = dr_v3_add(T, dr_v3_scale(t, w));
                G = dr_v3_add(G, dr_v3_scale(dr_v3_sub(g, dr_v3_scale(t, dr_v3_dot(g, t))), w));
                hmax = fmax(hmax, H[i]);
            }
            if (!(ex > 0)) continue;
            c = dr_v3_scale(c, 1.0 / ex);
            double tn = dr_v3_norm(T), gn = dr_v3_norm(G);
            T = tn > 0 ? dr_v3_scale(T, 1.0 / tn) : dr_v3(1, 0, 0);
            G = gn > 0 ? dr_v3_scale(G, 1.0 / gn) : dr_v3(0, -1, 0);
            long nd = (long)ceil(ex / V0);
            double rd = sphere_radius(ex / (double)nd);
            DrVec3 at = dr_v3_add(c, dr_v3_scale(G, hmax + (reach + 1.0) * rd));
            DR_TRY(add_drops(e, b, rho, nd, ex, P, at, T, err));
            dripped += ex;
            Pd = dr_v3_add(Pd, P);
        }
    }
    /* the pools */
    for (int k = 0; k < fs.nstrands; k++)
        for (int end = 0; end < 2; end++) {
            if (!(end == 0 ? e->drip.root : e->drip.tip)) continue;
            double pv = fs.pool[2 * k + end];
            if (!(pv >= e->drip.pool_release * V0) || !(pv > 0)) continue;
            long nd = (long)ceil(pv / V0);
            if (nd > budget) {
                held += pv;
                continue;
            }
            budget -= nd;
            int o = off[k], n = off[k + 1] - o, i = end == 0 ? o : o + n - 1;
            DrVec3 t = vertex_tangent(s->x, o, n, i);
            if (end == 0) t = dr_v3_scale(t, -1);
            DrVec3 P = dr_v3_scale(ld3(s->v + 3 * i), rho * pv);
            double rd = sphere_radius(pv / (double)nd);
            DrVec3 at = dr_v3_add(ld3(s->x + 3 * i), dr_v3_scale(t, H[i] + (reach + 1.0) * rd * (double)nd));
            DR_TRY(add_drops(e, b, rho, nd, pv, P, at, t, err));
            fs.pool[2 * k + end] = 0;
            dripped += pv;
            Pd = dr_v3_add(Pd, P);
        }
    *drops = e->drops;
    if (stats) {
        DrBulk db = {e->drops.n, e->drops.x, e->drops.v, e->drops.vol, 0, 0, dr_v3(0, 0, 0), dr_v3(0, 0, 0)};
        for (long q = 0; q < e->drops.n; q++) stats->dripped_energy += rho * e->drops.vol[q] * specific_energy(fd, &db, q);
        stats->dripped += dripped;
        stats->dripped_momentum = dr_v3_add(stats->dripped_momentum, Pd);
        stats->drops += e->drops.n;
        stats->held += held;
    }
    return DR_OK;
}

DrStatus dr_exchange_submersion(DrExchange *e, const double *x, long nverts, const DrBulk *b, double *out, DrError *err)
{
    double lo[3] = {b->lo.x, b->lo.y, b->lo.z}, hi[3] = {b->hi.x, b->hi.y, b->hi.z};
    long n[3];
    for (int a = 0; a < 3; a++) {
        n[a] = (long)ceil((hi[a] - lo[a]) / b->dx - 1e-9);
        if (n[a] < 1) n[a] = 1;
    }
    long cells = n[0] * n[1] * n[2];
    if (cells > e->frac_cap) {
        DR_TRY(dr_realloc((size_t)cells, sizeof(double), &e->frac, err));
        e->frac_cap = cells;
    }
    memset(e->frac, 0, (size_t)cells * sizeof(double));
    double inv = 1.0 / (b->dx * b->dx * b->dx);
    for (long p = 0; p < b->n; p++) {
        long c[3];
        for (int a = 0; a < 3; a++) {
            c[a] = (long)floor((b->x[3 * p + a] - lo[a]) / b->dx);
            c[a] = c[a] < 0 ? 0 : c[a] >= n[a] ? n[a] - 1 : c[a];
        }
        e->frac[c[0] + n[0] * (c[1] + n[1] * c[2])] += b->vol[p] * inv;
    }
    for (long i = 0; i < nverts; i++) {
        /* trilinear between cell centres; outside the lattice the nearest cells */
        long c0[3];
        double f[3];
        for (int a = 0; a < 3; a++) {
            double q = (x[3 * i + a] - lo[a]) / b->dx - 0.5;
            double fl = floor(q);
            c0[a] = (long)fl;
            f[a] = q - fl;
            if (c0[a] < 0) c0[a] = 0, f[a] = 0;
            if (c0[a] >= n[a] - 1) c0[a] = n[a] - 1 > 0 ? n[a] - 2 : 0, f[a] = n[a] > 1 ? 1 : 0;
        }
        double phi = 0;
        for (int dz = 0; dz < 2; dz++)
            for (int dy = 0; dy < 2; dy++)
                for (int dx = 0; dx < 2; dx++) {
                    long cx = c0[0] + dx, cy = c0[1] + dy, cz = c0[2] + dz;
                    if (cx >= n[0] || cy >= n[1] || cz >= n[2]) continue;
                    double w = (dx ? f[0] : 1 - f[0]) * (dy ? f[1] : 1 - f[1]) * (dz ? f[2] : 1 - f[2]);
                    phi += w * e->frac[cx + n[0] * (cy + n[1] * cz)];
                }
        double sub = 2.0 * phi - 1.0;
        out[i] = sub < 0 ? 0 : sub > 1 ? 1 : sub;
    }
    return DR_OK;
}
