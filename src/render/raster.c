/* The triangle rasteriser shared by the camera view and the shadow map.
 *
 * Corners are snapped to fixed point (1/256 of a sample) and coverage is decided with exact 64-bit integer
 * edge functions and the top-left fill rule, so two triangles sharing an edge cover each sample on it
 * exactly once (no cracks, no double blending) and the result does not depend on how the image is split
 * into bands. Depth and attributes are interpolated from the barycentric weights E_i / area in float: 1/z
 * is affine in screen space, so interpolating iz and attribute×iz is perspective-correct. */
#include <float.h>
#include <stdlib.h>

#include "render/render_internal.h"

static int64_t floor_div(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

DrStatus dr_render_emit_(DrTriList *list, const double x[3], const double y[3], const float iz[3],
                         const float a[3][3], uint8_t shade, int w, int h, DrError *err)
{
    DrRTri t;
    for (int k = 0; k < 3; k++) {
        t.x[k] = (int32_t)floor(x[k] * DR_SUBPIX + 0.5);
        t.y[k] = (int32_t)floor(y[k] * DR_SUBPIX + 0.5);
        t.iz[k] = iz[k];
        for (int c = 0; c < 3; c++) t.a[k][c] = a ? a[k][c] : 0.0f;
    }
    int64_t area = (int64_t)(t.x[1] - t.x[0]) * (t.y[2] - t.y[0]) - (int64_t)(t.y[1] - t.y[0]) * (t.x[2] - t.x[0]);
    if (area == 0) return DR_OK; /* degenerate after snapping: covers no sample */
    if (area < 0) {
        /* one orientation for the edge tests; the corner order carries no meaning beyond that */
        DrRTri s = t;
        t.x[1] = s.x[2], t.x[2] = s.x[1];
        t.y[1] = s.y[2], t.y[2] = s.y[1];
        t.iz[1] = s.iz[2], t.iz[2] = s.iz[1];
        for (int c = 0; c < 3; c++) t.a[1][c] = s.a[2][c], t.a[2][c] = s.a[1][c];
    }
    int64_t xmin = t.x[0], xmax = t.x[0], ymin = t.y[0], ymax = t.y[0];
    for (int k = 1; k < 3; k++) {
        xmin = t.x[k] < xmin ? t.x[k] : xmin;
        xmax = t.x[k] > xmax ? t.x[k] : xmax;
        ymin = t.y[k] < ymin ? t.y[k] : ymin;
        ymax = t.y[k] > ymax ? t.y[k] : ymax;
    }
    /* sample centres inside the box: ceil(min / S) .. floor(max / S), clipped to the raster */
    int64_t x0 = -floor_div(-xmin, DR_SUBPIX), x1 = floor_div(xmax, DR_SUBPIX);
    int64_t y0 = -floor_div(-ymin, DR_SUBPIX), y1 = floor_div(ymax, DR_SUBPIX);
    if (x0 < 0) x0 = 0;
    if (y0 < 0) y0 = 0;
    if (x1 > w - 1) x1 = w - 1;
    if (y1 > h - 1) y1 = h - 1;
    if (x0 > x1 || y0 > y1) return DR_OK;
    t.x0 = (int32_t)x0, t.x1 = (int32_t)x1, t.y0 = (int32_t)y0, t.y1 = (int32_t)y1;
    t.shade = shade;
    if (list->n == list->cap) {
        size_t cap = list->cap ? list->cap + list->cap / 2 : 1024;
        DR_TRY(dr_realloc(cap, sizeof *list->t, &list->t, err));
        list->cap = cap;
    }
    list->t[list->n++] = t;
    return DR_OK;
}

DrStatus dr_render_bin_(const DrTriList *list, int height, int band_rows, DrBins *bins, DrError *err)
{
    *bins = (DrBins){0};
    bins->band_rows = band_rows;
    bins->nbands = (height + band_rows - 1) / band_rows;
    DR_TRY(dr_calloc((size_t)bins->nbands + 1, sizeof *bins->start, &bins->start, err));
    size_t total = 0;
    for (size_t i = 0; i < list->n; i++) {
        const DrRTri *t = &list->t[i];
        for (int b = t->y0 / band_rows; b <= t->y1 / band_rows; b++) bins->start[b + 1]++;
        total += (size_t)(t->y1 / band_rows - t->y0 / band_rows + 1);
    }
    for (int b = 0; b < bins->nbands; b++) bins->start[b + 1] += bins->start[b];
    size_t *fill = NULL;
    DrStatus s = dr_calloc(total + 1, sizeof *bins->idx, &bins->idx, err);
    if (s == DR_OK) s = dr_calloc((size_t)bins->nbands, sizeof *fill, &fill, err);
    if (s != DR_OK) {
        dr_render_bins_free_(bins);
        return s;
    }
    if (list->n > UINT32_MAX) {
        free(fill);
        dr_render_bins_free_(bins);
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "too many triangles to render (%zu)", list->n);
    }
    for (size_t i = 0; i < list->n; i++) {
        const DrRTri *t = &list->t[i];
        for (int b = t->y0 / band_rows; b <= t->y1 / band_rows; b++)
            bins->idx[bins->start[b] + fill[b]++] = (uint32_t)i;
    }
    free(fill);
    return DR_OK;
}

void dr_render_bins_free_(DrBins *bins)
{
    free(bins->start);
    free(bins->idx);
    *bins = (DrBins){0};
}

/* ---- edge walking ------------------------------------------------------------------------------------ */

/* Edge function of edge a→b at point p, and its steps per sample in x and y. A sample lies inside when all
 * three are >= 0 after the bias: an edge owns the samples exactly on it only if it is a "top-left" edge
 * (dy < 0, or dy == 0 and dx > 0), which for the shared edge of two triangles is true for exactly one of
 * them (the shared edge runs in opposite directions). */
typedef struct Edge {
    int64_t w_row; /* value at the first sample of the current row */
    int64_t step_x, step_y, bias;
} Edge;

static Edge edge_setup(int32_t ax, int32_t ay, int32_t bx, int32_t by, int64_t px, int64_t py)
{
    int64_t dx = (int64_t)bx - ax, dy = (int64_t)by - ay;
    Edge e;
    e.w_row = dx * (py - ay) - dy * (px - ax);
    e.step_x = -dy * DR_SUBPIX;
    e.step_y = dx * DR_SUBPIX;
    e.bias = (dy < 0 || (dy == 0 && dx > 0)) ? 0 : -1;
    return e;
}

/* Walks the samples of rows [ry0, ry1] covered by t, running BODY with k (sample index in the band
 * buffers), l0, l1, l2 (barycentric weights, float). The body is the variadic argument, so commas in it
 * need no protection. */
#define WALK_TRIANGLE(t, ry0, ry1, row0, w, ...)                                                               \
    do {                                                                                                     \
        int64_t px0_ = (int64_t)(t)->x0 * DR_SUBPIX, py0_ = (int64_t)(ry0) * DR_SUBPIX;                     \
        Edge e0_ = edge_setup((t)->x[1], (t)->y[1], (t)->x[2], (t)->y[2], px0_, py0_);                      \
        Edge e1_ = edge_setup((t)->x[2], (t)->y[2], (t)->x[0], (t)->y[0], px0_, py0_);                      \
        Edge e2_ = edge_setup((t)->x[0], (t)->y[0], (t)->x[1], (t)->y[1], px0_, py0_);                      \
        int64_t area_ = e0_.w_row + e1_.w_row + e2_.w_row;                                                  \
        float inv_ = 1.0f / (float)area_;                                                                    \
        for (int sy_ = (ry0); sy_ <= (ry1); sy_++) {                                                         \
            int64_t w0_ = e0_.w_row, w1_ = e1_.w_row, w2_ = e2_.w_row;                                       \
            size_t k = (size_t)(sy_ - (row0)) * (size_t)(w) + (size_t)(t)->x0;                               \
            for (int sx_ = (t)->x0; sx_ <= (t)->x1; sx_++, k++) {                                            \
                if (((w0_ + e0_.bias) | (w1_ + e1_.bias) | (w2_ + e2_.bias)) >= 0) {                         \
                    float l0 = (float)w0_ * inv_, l1 = (float)w1_ * inv_, l2 = (float)w2_ * inv_;            \
                    __VA_ARGS__                                                                              \
                }                                                                                            \
                w0_ += e0_.step_x;                                                                           \
                w1_ += e1_.step_x;                                                                           \
                w2_ += e2_.step_x;                                                                           \
            }                                                                                                \
            e0_.w_row += e0_.step_y;                                                                         \
            e1_.w_row += e1_.step_y;                                                                         \
            e2_.w_row += e2_.step_y;                                                                         \
        }                                                                                                    \
    } while (0)

/* Rows of t inside the band [row0, row0 + rows); false when none. */
static bool band_rows(const DrRTri *t, int row0, int rows, int *ry0, int *ry1)
{
    *ry0 = t->y0 > row0 ? t->y0 : row0;
    *ry1 = t->y1 < row0 + rows - 1 ? t->y1 : row0 + rows - 1;
    return *ry0 <= *ry1;
}

void dr_render_raster_opaque_(const DrRTri *t, DrDepthBand *band)
{
    int ry0, ry1;
    if (!band_rows(t, band->row0, band->rows, &ry0, &ry1)) return;
    float *depth = band->iz, *nrm = band->n;
    uint8_t *shade = band->shade;
    WALK_TRIANGLE(t, ry0, ry1, band->row0, band->w, {
        float iz = l0 * t->iz[0] + l1 * t->iz[1] + l2 * t->iz[2];
        if (iz > depth[k]) {
            depth[k] = iz;
            for (int c = 0; c < 3; c++) nrm[3 * k + c] = l0 * t->a[0][c] + l1 * t->a[1][c] + l2 * t->a[2][c];
            shade[k] = t->shade;
        }
    });
}

void dr_render_raster_depth_(const DrRTri *t, DrDepthBand *band)
{
    int ry0, ry1;
    if (!band_rows(t, band->row0, band->rows, &ry0, &ry1)) return;
    float *depth = band->iz;
    WALK_TRIANGLE(t, ry0, ry1, band->row0, band->w, {
        float d = l0 * t->iz[0] + l1 * t->iz[1] + l2 * t->iz[2];
        if (d < depth[k]) depth[k] = d;
    });
}

void dr_render_raster_liquid_(const DrRTri *t, const float *opaque_iz, int row0, int rows, int w, float *near_iz,
                              float *near_n, float *far_iz)
{
    int ry0, ry1;
    if (!band_rows(t, row0, rows, &ry0, &ry1)) return;
    WALK_TRIANGLE(t, ry0, ry1, row0, w, {
        float iz = l0 * t->iz[0] + l1 * t->iz[1] + l2 * t->iz[2];
        /* a liquid surface coincident with the opaque one (water resting on a floor) counts as in front:
           1e-5 of the depth is far below any modelled gap and far above float rounding (6e-8) */
        if (iz * 1.00001f > opaque_iz[k]) {
            if (iz > near_iz[k]) {
                near_iz[k] = iz;
                for (int c = 0; c < 3; c++) near_n[3 * k + c] = l0 * t->a[0][c] + l1 * t->a[1][c] + l2 * t->a[2][c];
            }
            if (iz < far_iz[k]) far_iz[k] = iz;
        }
    });
}

void dr_render_raster_wall_(const DrRTri *t, const float *opaque_iz, const float *liquid_iz, int row0, int rows, int w,
                            float *t_front, float *t_back)
{
    int ry0, ry1;
    if (!band_rows(t, row0, rows, &ry0, &ry1)) return;
    WALK_TRIANGLE(t, ry0, ry1, row0, w, {
        float iz = l0 * t->iz[0] + l1 * t->iz[1] + l2 * t->iz[2];
        /* in front of the opaque surface, with the liquid's tolerance: a panel on the ground (a tank's
           floor) tints it */
        if (iz * 1.00001f > opaque_iz[k] && iz > 0.0f) {
            float alpha = (l0 * t->a[0][0] + l1 * t->a[1][0] + l2 * t->a[2][0]) / iz;
            alpha = alpha < 0.0f ? 0.0f : alpha > 1.0f ? 1.0f : alpha;
            if (iz > liquid_iz[k]) t_front[k] *= 1.0f - alpha;
            else t_back[k] *= 1.0f - alpha;
        }
    });
}
