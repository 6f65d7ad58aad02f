/* The shape vocabulary and the sorted-cell broad phase (contact.h). */
#include "contact/contact.h"

#include "lagrangian/lagrangian.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "core/sort.h"

bool dr_shape_pair_allowed(const DrShape *a, const DrShape *b)
{
    return (a->group & b->mask) != 0 && (b->group & a->mask) != 0;
}

void dr_shape_element_box(const DrShape *s, int k, double pad, DrVec3 *lo, DrVec3 *hi)
{
    int per = s->kind == DR_SHAPE_TRIANGLES ? 3 : (s->kind == DR_SHAPE_SEGMENTS ? 2 : 1);
    double l[3] = {INFINITY, INFINITY, INFINITY}, h[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int c = 0; c < per; c++) {
        int v = s->elements && per > 1 ? s->elements[per * k + c] : k;
        const double *p = s->x + 3 * v;
        for (int a = 0; a < 3; a++) {
            l[a] = fmin(l[a], p[a]);
            h[a] = fmax(h[a], p[a]);
        }
    }
    *lo = dr_v3(l[0] - pad, l[1] - pad, l[2] - pad);
    *hi = dr_v3(h[0] + pad, h[1] + pad, h[2] + pad);
}

/* ---- broad phase ------------------------------------------------------------------------------------------- */

typedef struct CellEntry { int cx, cy, cz, box; } CellEntry;

struct DrBroadPhase {
    double *box;           /* 6 per box: lo xyz, hi xyz */
    int nbox, cap_box;
    CellEntry *cells, *cells_tmp; /* the entries and their sort's scratch */
    size_t ncells, cap_cells;
    DrBroadPair *pairs;
    long npairs, cap_pairs;
    bool slack;            /* the first query left room for twice its pairs */
};

DrStatus dr_broad_phase_create(DrBroadPhase **out, DrError *err) { return dr_calloc(1, sizeof **out, out, err); }

void dr_broad_phase_destroy(DrBroadPhase **bp)
{
    if (!bp || !*bp) return;
    free((*bp)->box);
    free((*bp)->cells);
    free((*bp)->cells_tmp);
    free((*bp)->pairs);
    free(*bp);
    *bp = NULL;
}

void dr_broad_phase_clear(DrBroadPhase *bp)
{
    bp->nbox = 0;
    bp->npairs = 0;
}

int dr_broad_phase_count(const DrBroadPhase *bp) { return bp->nbox; }

DrStatus dr_broad_phase_reserve(DrBroadPhase *bp, int boxes, size_t cell_entries, DrError *err)
{
    if (boxes > bp->cap_box) {
        DR_TRY(dr_realloc((size_t)boxes * 6, sizeof(double), &bp->box, err));
        bp->cap_box = boxes;
    }
    if (cell_entries > bp->cap_cells) {
        DR_TRY(dr_realloc(cell_entries, sizeof(CellEntry), &bp->cells, err));
        DR_TRY(dr_realloc(cell_entries, sizeof(CellEntry), &bp->cells_tmp, err));
        bp->cap_cells = cell_entries;
    }
    return DR_OK;
}

DrStatus dr_broad_phase_add(DrBroadPhase *bp, DrVec3 lo, DrVec3 hi, DrError *err)
{
    if (bp->nbox == bp->cap_box) {
        int cap = bp->cap_box ? 2 * bp->cap_box : 256;
        DR_TRY(dr_realloc((size_t)cap * 6, sizeof(double), &bp->box, err));
        bp->cap_box = cap;
    }
    double *b = bp->box + 6 * (size_t)bp->nbox++;
    b[0] = lo.x, b[1] = lo.y, b[2] = lo.z, b[3] = hi.x, b[4] = hi.y, b[5] = hi.z;
    return DR_OK;
}

static inline bool cell_less(const CellEntry *a, const CellEntry *b)
{
    if (a->cx != b->cx) return a->cx < b->cx;
    if (a->cy != b->cy) return a->cy < b->cy;
    if (a->cz != b->cz) return a->cz < b->cz;
    return a->box < b->box;
}

DR_DEFINE_STABLE_SORT(cells_sort, CellEntry, cell_less) /* keys are distinct: a box enters a cell once */

#define CELL_LIMIT 1073741824.0 /* 2^30 cells from the origin */

static DrStatus cell_range(const double *b, double cell, int i, int lo[3], int hi[3], DrError *err)
{
    for (int a = 0; a < 3; a++) {
        double l = floor(b[a] / cell), h = floor(b[3 + a] / cell);
        if (!(fabs(l) < CELL_LIMIT) || !(fabs(h) < CELL_LIMIT) || !(b[a] <= b[3 + a]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "contact: box %d [%g, %g] on axis %d is not finite, inverted, or more than 2^30 cells "
                                "of %g m from the origin; check the scene's scale and the contact thickness",
                                i, b[a], b[3 + a], a, cell);
        lo[a] = (int)l;
        hi[a] = (int)h;
    }
    return DR_OK;
}

/* The pairs of both queries: every pair when split < 0, else only the pairs (i, j) with i < split ≤ j. */
static DrStatus find_pairs(DrBroadPhase *bp, double cell, int split, const DrBroadPair **pairs, long *npairs,
                           DrError *err)
{
    *pairs = bp->pairs;
    *npairs = 0;
    bp->npairs = 0;
    if (!(cell > 0.0) || !isfinite(cell))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "contact: cell size %g m must be positive and finite", cell);
    /* count the entries first, so the array grows once */
    size_t need = 0;
    for (int i = 0; i < bp->nbox; i++) {
        int lo[3], hi[3];
        DR_TRY(cell_range(bp->box + 6 * (size_t)i, cell, i, lo, hi, err));
        need += (size_t)(hi[0] - lo[0] + 1) * (size_t)(hi[1] - lo[1] + 1) * (size_t)(hi[2] - lo[2] + 1);
    }
    if (need > bp->cap_cells) {
        size_t cap = bp->cap_cells ? bp->cap_cells : 1024;
        while (cap < need) cap *= 2;
        DR_TRY(dr_realloc(cap, sizeof(CellEntry), &bp->cells, err));
        DR_TRY(dr_realloc(cap, sizeof(CellEntry), &bp->cells_tmp, err));
        bp->cap_cells = cap;
    }
    size_t n = 0;
    for (int i = 0; i < bp->nbox; i++) {
        int lo[3], hi[3];
        DR_TRY(cell_range(bp->box + 6 * (size_t)i, cell, i, lo, hi, err));
        for (int cx = lo[0]; cx <= hi[0]; cx++)
            for (int cy = lo[1]; cy <= hi[1]; cy++)
                for (int cz = lo[2]; cz <= hi[2]; cz++) bp->cells[n++] = (CellEntry){cx, cy, cz, i};
    }
    bp->ncells = n;
    cells_sort(bp->cells, bp->cells_tmp, n);
    const CellEntry *ce = bp->cells;
    for (size_t a = 0; a < n;) {
        size_t b = a;
        while (b < n && ce[b].cx == ce[a].cx && ce[b].cy == ce[a].cy && ce[b].cz == ce[a].cz) b++;
        /* a cell's entries are in box order, so with a split those below it come first, [a, m), and the pairs
           across it are [a, m) × [m, b) in the order the full enumeration meets them */
        size_t m = a;
        while (split >= 0 && m < b && ce[m].box < split) m++;
        size_t i_end = split >= 0 ? m : b;
        for (size_t i = a; i < i_end; i++)
            for (size_t j = split >= 0 ? m : i + 1; j < b; j++) {
                const double *p = bp->box + 6 * (size_t)ce[i].box, *q = bp->box + 6 * (size_t)ce[j].box;
                bool overlap = true;
                int own[3];
                for (int c = 0; c < 3; c++) {
                    if (p[c] > q[3 + c] || q[c] > p[3 + c]) overlap = false;
                    own[c] = (int)floor(fmax(p[c], q[c]) / cell);
                }
                /* the cell holding the low corner of the overlap owns the pair */
                if (!overlap || own[0] != ce[a].cx || own[1] != ce[a].cy || own[2] != ce[a].cz) continue;
                if (bp->npairs == bp->cap_pairs) {
                    long cap = bp->cap_pairs ? 2 * bp->cap_pairs : 1024;
                    DR_TRY(dr_realloc((size_t)cap, sizeof(DrBroadPair), &bp->pairs, err));
                    bp->cap_pairs = cap;
                }
                bp->pairs[bp->npairs++] = (DrBroadPair){ce[i].box, ce[j].box};
            }
        a = b;
    }
    if (!bp->slack && 2 * bp->npairs > bp->cap_pairs) {
        DR_TRY(dr_realloc((size_t)(2 * bp->npairs), sizeof(DrBroadPair), &bp->pairs, err));
        bp->cap_pairs = 2 * bp->npairs;
    }
    bp->slack = true;
    *pairs = bp->pairs;
    *npairs = bp->npairs;
    return DR_OK;
}

DrStatus dr_broad_phase_pairs(DrBroadPhase *bp, double cell, const DrBroadPair **pairs, long *npairs, DrError *err)
{
    return find_pairs(bp, cell, -1, pairs, npairs, err);
}

DrStatus dr_broad_phase_pairs_across(DrBroadPhase *bp, double cell, int split, const DrBroadPair **pairs,
                                     long *npairs, DrError *err)
{
    assert(split >= 0 && split <= bp->nbox);
    return find_pairs(bp, cell, split, pairs, npairs, err);
}

/* ---- a point set as a surface ------------------------------------------------------------------------------ */

typedef struct PointEntry { int cx, cy, cz; long p; } PointEntry;

static inline bool point_less(const PointEntry *a, const PointEntry *b)
{
    if (a->cx != b->cx) return a->cx < b->cx;
    if (a->cy != b->cy) return a->cy < b->cy;
    if (a->cz != b->cz) return a->cz < b->cz;
    return a->p < b->p;
}

DR_DEFINE_STABLE_SORT(points_sort, PointEntry, point_less)

struct DrPointField {
    long n;
    const double *x, *v;     /* borrowed */
    double *radius;          /* n */
    double support, inv_support2;
    PointEntry *entries, *tmp;
    size_t cap;
};

DrStatus dr_point_field_create(DrPointField **out, DrError *err) { return dr_calloc(1, sizeof **out, out, err); }

void dr_point_field_destroy(DrPointField **pf)
{
    if (!pf || !*pf) return;
    free((*pf)->radius);
    free((*pf)->entries);
    free((*pf)->tmp);
    free(*pf);
    *pf = NULL;
}

long dr_point_field_count(const DrPointField *pf) { return pf->n; }

DrStatus dr_point_field_build(DrPointField *pf, long n, const double *x, const double *v, const double *volume,
                              DrError *err)
{
    pf->n = 0;
    if (n <= 0) return DR_OK;
    if ((size_t)n > pf->cap) {
        size_t cap = pf->cap ? pf->cap : 256;
        while (cap < (size_t)n) cap *= 2;
        DR_TRY(dr_realloc(cap, sizeof(double), &pf->radius, err));
        DR_TRY(dr_realloc(cap, sizeof(PointEntry), &pf->entries, err));
        DR_TRY(dr_realloc(cap, sizeof(PointEntry), &pf->tmp, err));
        pf->cap = cap;
    }
    double rmax = 0.0;
    for (long p = 0; p < n; p++) {
        if (!(volume[p] > 0.0) || !isfinite(volume[p]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "contact: particle %ld has volume %g; it must be positive",
                                p, volume[p]);
        pf->radius[p] = 0.5 * cbrt(volume[p]);
        rmax = fmax(rmax, pf->radius[p]);
    }
    double R = 4.0 * rmax;
    for (long p = 0; p < n; p++) {
        double c[3];
        for (int a = 0; a < 3; a++) {
            c[a] = floor(x[3 * p + a] / R);
            if (!(fabs(c[a]) < CELL_LIMIT))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "contact: particle %ld is at %g m on axis %d: not "
                                    "finite, or more than 2^30 cells of %g m from the origin", p, x[3 * p + a], a, R);
        }
        pf->entries[p] = (PointEntry){(int)c[0], (int)c[1], (int)c[2], p};
    }
    points_sort(pf->entries, pf->tmp, (size_t)n);
    pf->n = n;
    pf->x = x;
    pf->v = v;
    pf->support = R;
    pf->inv_support2 = 1.0 / (R * R);
    return DR_OK;
}

/* The first entry of cell (cx, cy, cz), or n when it holds none (*end: one past its last). */
static long cell_first(const DrPointField *pf, int cx, int cy, int cz, long *end)
{
    PointEntry key = {cx, cy, cz, -1};
    long lo = 0, hi = pf->n;
    while (lo < hi) {
        long mid = lo + (hi - lo) / 2;
        if (point_less(&pf->entries[mid], &key)) lo = mid + 1;
        else hi = mid;
    }
    long e = lo;
    while (e < pf->n && pf->entries[e].cx == cx && pf->entries[e].cy == cy && pf->entries[e].cz == cz) e++;
    *end = e;
    return lo;
}

/* Σk, Σk x, Σk r and Σk v over the particles within the support of x, cells in order, particles by index. */
static double field_sums(const DrPointField *pf, DrVec3 x, double sx[3], double *sr, double sv[3])
{
    double w = 0.0;
    sx[0] = sx[1] = sx[2] = 0.0;
    sv[0] = sv[1] = sv[2] = 0.0;
    *sr = 0.0;
    if (pf->n == 0) return 0.0;
    double R = pf->support, q[3] = {x.x, x.y, x.z};
    double c[3];
    for (int a = 0; a < 3; a++) {
        c[a] = floor(q[a] / R);
        if (!(fabs(c[a]) < CELL_LIMIT)) return 0.0;
    }
    for (int i = -1; i <= 1; i++)
        for (int j = -1; j <= 1; j++)
            for (int k = -1; k <= 1; k++) {
                long end, b = cell_first(pf, (int)c[0] + i, (int)c[1] + j, (int)c[2] + k, &end);
                for (long e = b; e < end; e++) {
                    long p = pf->entries[e].p;
                    const double *xp = pf->x + 3 * p;
                    double d2 = 0.0;
                    for (int a = 0; a < 3; a++) d2 += (q[a] - xp[a]) * (q[a] - xp[a]);
                    double s = 1.0 - d2 * pf->inv_support2;
                    if (s <= 0.0) continue;
                    double kw = s * s * s;
                    w += kw;
                    for (int a = 0; a < 3; a++) {
                        sx[a] += kw * xp[a];
                        if (pf->v) sv[a] += kw * pf->v[3 * p + a];
                    }
                    *sr += kw * pf->radius[p];
                }
            }
    return w;
}

double dr_point_field_phi(const DrPointField *pf, DrVec3 x, DrVec3 *normal)
{
    double sx[3], sr, sv[3];
    double w = field_sums(pf, x, sx, &sr, sv);
    if (!(w > 0.0)) {
        if (normal) *normal = dr_v3(0, 1, 0);
        return INFINITY;
    }
    DrVec3 d = dr_v3(x.x - sx[0] / w, x.y - sx[1] / w, x.z - sx[2] / w);
    double len = dr_v3_norm(d);
    if (normal) *normal = len > 1e-12 * pf->support ? dr_v3_scale(d, 1.0 / len) : dr_v3(0, 1, 0);
    return len - sr / w;
}

DrVec3 dr_point_field_velocity(const DrPointField *pf, DrVec3 x)
{
    double sx[3], sr, sv[3];
    double w = field_sums(pf, x, sx, &sr, sv);
    if (!(w > 0.0)) return dr_v3(0, 0, 0);
    return dr_v3(sv[0] / w, sv[1] / w, sv[2] / w);
}

/* ---- a triangle mesh as a surface ------------------------------------------------------------------------------ */

typedef struct TriEntry { int cx, cy, cz, t; } TriEntry;

static inline bool tri_less(const TriEntry *a, const TriEntry *b)
{
    if (a->cx != b->cx) return a->cx < b->cx;
    if (a->cy != b->cy) return a->cy < b->cy;
    if (a->cz != b->cz) return a->cz < b->cz;
    return a->t < b->t;
}

DR_DEFINE_STABLE_SORT(tris_sort, TriEntry, tri_less)

struct DrTriField {
    int nt;
    const int *tri;          /* borrowed */
    const double *x, *v;     /* borrowed */
    double reach;
    TriEntry *entries, *tmp;
    size_t n, cap;
};

DrStatus dr_tri_field_create(DrTriField **out, DrError *err) { return dr_calloc(1, sizeof **out, out, err); }

void dr_tri_field_destroy(DrTriField **tf)
{
    if (!tf || !*tf) return;
    free((*tf)->entries);
    free((*tf)->tmp);
    free(*tf);
    *tf = NULL;
}

DrStatus dr_tri_field_build(DrTriField *tf, int nt, const int *tri, const double *x, const double *v, double reach,
                            DrError *err)
{
    tf->nt = 0;
    tf->n = 0;
    if (!(reach > 0.0) || !isfinite(reach))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "contact: a triangle field's reach is %g m; it must be "
                            "positive", reach);
    /* the cells each triangle's inflated box covers: counted, then filled */
    size_t n = 0;
    for (int pass = 0; pass < 2; pass++) {
        n = 0;
        for (int t = 0; t < nt; t++) {
            int lo[3], hi[3];
            for (int a = 0; a < 3; a++) {
                double mn = INFINITY, mx = -INFINITY;
                for (int k = 0; k < 3; k++) {
                    double q = x[3 * tri[3 * t + k] + a];
                    mn = fmin(mn, q);
                    mx = fmax(mx, q);
                }
                double l = floor((mn - reach) / reach), h = floor((mx + reach) / reach);
                if (!(fabs(l) < CELL_LIMIT) || !(fabs(h) < CELL_LIMIT))
                    return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "contact: triangle %d of a triangle field is "
                                        "not finite, or more than 2^30 cells of %g m from the origin", t, reach);
                lo[a] = (int)l;
                hi[a] = (int)h;
            }
            for (int i = lo[0]; i <= hi[0]; i++)
                for (int j = lo[1]; j <= hi[1]; j++)
                    for (int k = lo[2]; k <= hi[2]; k++) {
                        if (pass == 1) tf->entries[n] = (TriEntry){i, j, k, t};
                        n++;
                    }
        }
        if (pass == 0 && n > tf->cap) {
            size_t cap = tf->cap ? tf->cap : 1024;
            while (cap < n) cap *= 2;
            DR_TRY(dr_realloc(cap, sizeof(TriEntry), &tf->entries, err));
            DR_TRY(dr_realloc(cap, sizeof(TriEntry), &tf->tmp, err));
            tf->cap = cap;
        }
    }
    tris_sort(tf->entries, tf->tmp, n);
    tf->n = n;
    tf->nt = nt;
    tf->tri = tri;
    tf->x = x;
    tf->v = v;
    tf->reach = reach;
    return DR_OK;
}

/* The point of triangle (a, b, c) nearest to p, as barycentric coordinates w (Ericson, Real-Time Collision Detection
   §5.1.5: by the Voronoi region of p). */
static void nearest_on_triangle(const double *p, const double *a, const double *b, const double *c, double w[3])
{
    double ab[3], ac[3], ap[3];
    for (int k = 0; k < 3; k++) ab[k] = b[k] - a[k], ac[k] = c[k] - a[k], ap[k] = p[k] - a[k];
#define DOT(u, v) ((u)[0] * (v)[0] + (u)[1] * (v)[1] + (u)[2] * (v)[2])
    double d1 = DOT(ab, ap), d2 = DOT(ac, ap);
    if (d1 <= 0 && d2 <= 0) { w[0] = 1, w[1] = 0, w[2] = 0; return; }
    double bp[3], cp[3];
    for (int k = 0; k < 3; k++) bp[k] = p[k] - b[k], cp[k] = p[k] - c[k];
    double d3 = DOT(ab, bp), d4 = DOT(ac, bp);
    if (d3 >= 0 && d4 <= d3) { w[0] = 0, w[1] = 1, w[2] = 0; return; }
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double s = d1 / (d1 - d3);
        w[0] = 1 - s, w[1] = s, w[2] = 0;
        return;
    }
    double d5 = DOT(ab, cp), d6 = DOT(ac, cp);
    if (d6 >= 0 && d5 <= d6) { w[0] = 0, w[1] = 0, w[2] = 1; return; }
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double s = d2 / (d2 - d6);
        w[0] = 1 - s, w[1] = 0, w[2] = s;
        return;
    }
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double s = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        w[0] = 0, w[1] = 1 - s, w[2] = s;
        return;
    }
    double den = 1.0 / (va + vb + vc);
    w[1] = vb * den, w[2] = vc * den, w[0] = 1 - w[1] - w[2];
#undef DOT
}

/* The nearest triangle to q within reach (−1 when none), its barycentric w and the distance *d. */
static int tri_nearest(const DrTriField *tf, const double q[3], double w[3], double *d)
{
    *d = INFINITY;
    if (tf->n == 0) return -1;
    int c[3];
    for (int a = 0; a < 3; a++) {
        double f = floor(q[a] / tf->reach);
        if (!(fabs(f) < CELL_LIMIT)) return -1;
        c[a] = (int)f;
    }
    TriEntry key = {c[0], c[1], c[2], -1};
    size_t lo = 0, hi = tf->n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (tri_less(&tf->entries[mid], &key)) lo = mid + 1;
        else hi = mid;
    }
    int best = -1;
    double best2 = tf->reach * tf->reach;
    for (size_t e = lo; e < tf->n && tf->entries[e].cx == c[0] && tf->entries[e].cy == c[1] && tf->entries[e].cz == c[2];
         e++) {
        int t = tf->entries[e].t;
        const int *tv = tf->tri + 3 * t;
        const double *a = tf->x + 3 * tv[0], *b = tf->x + 3 * tv[1], *cc = tf->x + 3 * tv[2];
        double ww[3];
        nearest_on_triangle(q, a, b, cc, ww);
        double d2 = 0;
        for (int k = 0; k < 3; k++) {
            double pk = ww[0] * a[k] + ww[1] * b[k] + ww[2] * cc[k] - q[k];
            d2 += pk * pk;
        }
        if (d2 < best2) {
            best2 = d2;
            best = t;
            w[0] = ww[0], w[1] = ww[1], w[2] = ww[2];
        }
    }
    if (best >= 0) *d = sqrt(best2);
    return best;
}

double dr_tri_field_phi(const DrTriField *tf, DrVec3 x, DrVec3 *normal)
{
    double q[3] = {x.x, x.y, x.z}, w[3], d;
    int t = tri_nearest(tf, q, w, &d);
    if (t < 0) {
        if (normal) *normal = dr_v3(0, 1, 0);
        return INFINITY;
    }
    if (normal) {
        const int *tv = tf->tri + 3 * t;
        double p[3];
        for (int k = 0; k < 3; k++)
            p[k] = q[k] - (w[0] * tf->x[3 * tv[0] + k] + w[1] * tf->x[3 * tv[1] + k] + w[2] * tf->x[3 * tv[2] + k]);
        if (d > 1e-12 * tf->reach) {
            *normal = dr_v3(p[0] / d, p[1] / d, p[2] / d);
        } else { /* on the sheet: its face normal */
            const double *a = tf->x + 3 * tv[0], *b = tf->x + 3 * tv[1], *c = tf->x + 3 * tv[2];
            DrVec3 n = dr_v3_cross(dr_v3(b[0] - a[0], b[1] - a[1], b[2] - a[2]), dr_v3(c[0] - a[0], c[1] - a[1], c[2] - a[2]));
            double l = dr_v3_norm(n);
            *normal = l > 0 ? dr_v3_scale(n, 1.0 / l) : dr_v3(0, 1, 0);
        }
    }
    return d;
}

DrVec3 dr_tri_field_velocity(const DrTriField *tf, DrVec3 x)
{
    double q[3] = {x.x, x.y, x.z}, w[3], d;
    int t = tri_nearest(tf, q, w, &d);
    if (t < 0 || !tf->v) return dr_v3(0, 0, 0);
    const int *tv = tf->tri + 3 * t;
    double u[3];
    for (int k = 0; k < 3; k++)
        u[k] = w[0] * tf->v[3 * tv[0] + k] + w[1] * tf->v[3 * tv[1] + k] + w[2] * tf->v[3 * tv[2] + k];
    return dr_v3(u[0], u[1], u[2]);
}

int dr_tri_field_nearest(const DrTriField *tf, DrVec3 x, double bary[3])
{
    double q[3] = {x.x, x.y, x.z}, d;
    return tri_nearest(tf, q, bary, &d);
}

/* ---- points against a sheet, in one Lagrangian system ---------------------------------------------------------- */

DrStatus dr_contact_points_sheet(DrLag *lag, double h, const DrContactPoints *p, const DrContactSheet *s,
                                 const DrContactResponse *r, int *count, DrError *err)
{
    const double thickness = r->thickness, stiffness = r->stiffness;
    *count = 0;
    for (int i = 0; i < p->n; i++) {
        if (p->held && p->held[i]) continue;
        DrVec3 q = dr_v3(p->x[3 * i], p->x[3 * i + 1], p->x[3 * i + 2]);
        double b[3];
        int t = dr_tri_field_nearest(s->field, q, b);
        if (t < 0) continue;
        const int *tv = s->tri + 3 * t;
        double c[3], vc[3] = {0, 0, 0}, n[3];
        for (int a = 0; a < 3; a++) {
            c[a] = b[0] * s->x[3 * tv[0] + a] + b[1] * s->x[3 * tv[1] + a] + b[2] * s->x[3 * tv[2] + a];
            if (s->v) vc[a] = b[0] * s->v[3 * tv[0] + a] + b[1] * s->v[3 * tv[1] + a] + b[2] * s->v[3 * tv[2] + a];
            n[a] = p->x[3 * i + a] - c[a];
        }
        double d = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(d > 0)) continue; /* on the sheet: no side to push it to */
        for (int a = 0; a < 3; a++) n[a] /= d;
        double phi = d - (p->radius[i] + thickness);
        double approach = 0;
        for (int a = 0; a < 3; a++) approach += h * n[a] * ((p->v ? p->v[3 * i + a] : 0) - vc[a]);
        if (phi + fmin(approach, 0) >= 0) continue;
        DrLagGroup g;
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = 1;
        g.ndof = 12;
        const double w[4] = {1.0, -b[0], -b[1], -b[2]};
        const int base[4] = {p->dof[i], s->dof[tv[0]], s->dof[tv[1]], s->dof[tv[2]]};
        for (int k = 0; k < 4; k++)
            for (int a = 0; a < 3; a++) {
                g.dof[3 * k + a] = base[k] + a;
                g.J[3 * k + a] = w[k] * n[a];
            }
        g.phi[0] = phi;
        g.cinv[0] = stiffness;
        DR_TRY(dr_lag_add_global(lag, &g, err));
        (*count)++;
        if (r->damping > 0) { /* a dashpot along n beside the spring */
            DrLagGroup dmp = g;
            dmp.kind = DR_LAG_VISCOUS;
            dmp.phi[0] = 0;
            dmp.cinv[0] = r->damping * stiffness;
            DR_TRY(dr_lag_add_global(lag, &dmp, err));
        }
        if (!(r->friction > 0) || !(phi < 0)) continue;
        /* friction: the tangential relative velocity and a basis of the tangent plane */
        double vr[3];
        for (int a = 0; a < 3; a++) vr[a] = (p->v ? p->v[3 * i + a] : 0) - vc[a];
        double vn = vr[0] * n[0] + vr[1] * n[1] + vr[2] * n[2];
        double vt[3] = {vr[0] - vn * n[0], vr[1] - vn * n[1], vr[2] - vn * n[2]};
        double vtn = sqrt(vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2]);
        double t1[3], t2[3];
        dr_tangent_basis(n, t1, t2);
        DrLagGroup f = g;
        f.kind = DR_LAG_VISCOUS;
        f.nrows = 2;
        for (int k = 0; k < 4; k++)
            for (int a = 0; a < 3; a++) {
                f.J[3 * k + a] = w[k] * t1[a];
                f.J[12 + 3 * k + a] = w[k] * t2[a];
            }
        double grip = r->friction * fabs(phi) / h;
        f.phi[0] = f.phi[1] = 0;
        f.cinv[0] = f.cinv[1] = r->friction * stiffness * fabs(phi) / fmax(vtn, fmax(grip, 1e-12));
        f.lambda = NULL;
        DR_TRY(dr_lag_add_global(lag, &f, err));
    }
    return DR_OK;
}
