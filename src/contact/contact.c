/* The shape vocabulary and the sorted-cell broad phase (contact.h). */
#include "contact/contact.h"

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

DrStatus dr_broad_phase_pairs(DrBroadPhase *bp, double cell, const DrBroadPair **pairs, long *npairs, DrError *err)
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
        for (size_t i = a; i < b; i++)
            for (size_t j = i + 1; j < b; j++) {
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
    *pairs = bp->pairs;
    *npairs = bp->npairs;
    return DR_OK;
}
