/* Private to src/render: the scene's storage, the camera frame, the sky and sRGB encoding (camera.c), the
 * triangle rasteriser (raster.c) and shading (shade.c), shared with the driver (render.c). */
#ifndef DR_RENDER_INTERNAL_H
#define DR_RENDER_INTERNAL_H

#include "render/render.h"

/* ---- scene (scene.c) ---------------------------------------------------------------------------- */

typedef struct DrRenderMesh {
    int nv, nt;
    double *v, *n; /* 3*nv positions and unit normals (zero where undefined, as on a double-sided sheet) */
    int *tri;      /* 3*nt */
    DrRenderMaterial mat;
    DrVec3 lo, hi; /* bounds of the vertices the triangles use */
} DrRenderMesh;

typedef struct DrRenderStrands {
    int count;
    int *offsets;   /* count + 1 */
    double *points; /* 3*offsets[count] */
    double *radius; /* offsets[count]: per vertex, metres */
    double *wet;    /* offsets[count] wetness in [0, 1] per vertex, or NULL (dry) */
    DrRenderMaterial mat;
} DrRenderStrands;

struct DrRenderScene {
    DrRenderMesh *meshes;
    int nmeshes, cap_meshes;
    DrRenderStrands *strands;
    int nstrands, cap_strands;
};

/* Bounds of the meshes and strands whose material satisfies `liquid` (true: liquid only, false: everything
 * else); false when there is none. */
bool dr_render_bounds_of_(const DrRenderScene *scene, bool liquid, DrVec3 *lo, DrVec3 *hi);

/* ---- camera, sky, colour (camera.c) ------------------------------------------------------------ */

/* A checked camera ready to project: orthonormal basis (f forward, r right, u up) and the focal length in
 * pixels; pixel coordinates px = cx + focal*x/z, py = cy - focal*y/z for camera-space (x, y, z). */
typedef struct DrCamFrame {
    DrVec3 eye, f, r, u;
    double focal, cx, cy;
} DrCamFrame;
void dr_render_cam_frame_(const DrCamera *cam, DrCamFrame *cf);

/* Sky radiance (linear RGB) seen along unit direction d: the background and what water reflects. */
DrVec3 dr_render_sky_(DrVec3 d);
/* Linear background colour of pixel row j, as stored before encoding (so that a pixel of background samples
 * only averages back to exactly this value and encodes to exactly dr_render_background's bytes). */
void dr_render_background_linear_(const DrCamFrame *cf, int row, float out[3]);

/* sRGB encoding by thresholds: byte k is the largest k with linear >= t[k] (t[0] = -inf), where t[k] is the
 * linear value of the sRGB code k - 1/2; exact rounding of the sRGB curve without a pow per pixel. */
typedef struct DrSrgbTable {
    float t[256];
} DrSrgbTable;
void dr_render_srgb_table_(DrSrgbTable *tab);
static inline uint8_t dr_render_encode_(const DrSrgbTable *tab, float v)
{
    int k = 0;
    for (int step = 128; step > 0; step >>= 1)
        if (v >= tab->t[k + step]) k += step; /* k + step <= 255: the steps sum to 255 */
    return (uint8_t)k;
}

/* ---- rasteriser (raster.c) -------------------------------------------------------------------- */

#define DR_SUBPIX 256 /* fixed-point steps per sample: 8 bits of sub-sample precision */

/* What a covered sample keeps of a triangle. Samples sit at integer raster coordinates; corners are in
 * fixed point (raster coordinate × DR_SUBPIX). */
typedef struct DrRTri {
    int32_t x[3], y[3];
    float iz[3];   /* perspective: 1/view depth (interpolates linearly on screen); orthographic: depth */
    float a[3][3]; /* attribute × iz per corner: the unit normal (or a strand's tangent), so that the
                      interpolated sum is perspective-correct up to a scale a later normalisation removes */
    int32_t x0, x1, y0, y1; /* sample columns and rows its bounding box covers, inside the raster */
    uint8_t shade;          /* DrShadeCode */
} DrRTri;

typedef struct DrTriList {
    DrRTri *t;
    size_t n, cap;
} DrTriList;

/* Appends the triangle with raster corners (x[i], y[i]) when it covers at least one sample centre of the
 * raster [0, w) × [0, h); corners are swapped to a positive orientation. Coordinates must lie within
 * ±2^22 samples (the callers' guard bands keep them there), so fixed-point corners fit int32 and edge
 * functions, products of two corner differences, fit int64. */
DR_NODISCARD DrStatus dr_render_emit_(DrTriList *list, const double x[3], const double y[3], const float iz[3],
                                      const float a[3][3], uint8_t shade, int w, int h, DrError *err);

/* Triangle indices per band of `band_rows` raster rows, in list order: band b holds idx[start[b] ..
 * start[b+1]). */
typedef struct DrBins {
    int nbands, band_rows;
    size_t *start;
    uint32_t *idx;
} DrBins;
DR_NODISCARD DrStatus dr_render_bin_(const DrTriList *list, int height, int band_rows, DrBins *bins, DrError *err);
void dr_render_bins_free_(DrBins *bins);

/* A band of the raster: rows [row0, row0 + rows), full width w, one depth per sample. */
typedef struct DrDepthBand {
    int row0, rows, w;
    float *iz;   /* opaque: nearest 1/depth so far (0 = nothing); shadow: nearest depth (FLT_MAX = nothing) */
    float *n;    /* 3 per sample: interpolated attribute of the nearest (NULL for a shadow map) */
    uint8_t *shade;
} DrDepthBand;

/* Opaque z-buffer: keeps the largest iz (the nearest surface) with its attribute and shade code. */
void dr_render_raster_opaque_(const DrRTri *t, DrDepthBand *band);
/* Shadow map: keeps the smallest interpolated depth (orthographic: depth is linear on the map). */
void dr_render_raster_depth_(const DrRTri *t, DrDepthBand *band);
/* Liquid: per sample keeps, among surfaces in front of the opaque depth `opaque_iz`, the nearest (iz and
 * attribute into near_iz, near_n) and the farthest (far_iz). */
void dr_render_raster_liquid_(const DrRTri *t, const float *opaque_iz, int row0, int rows, int w, float *near_iz,
                              float *near_n, float *far_iz);

/* Wall panels: per sample in front of the opaque depth, multiplies the panel's transmittance (1 − its opacity,
 * carried in the attribute's first component) into t_front where it is nearer than the liquid's near surface
 * `liquid_iz` (0: none), else into t_back. */
void dr_render_raster_wall_(const DrRTri *t, const float *opaque_iz, const float *liquid_iz, int row0, int rows, int w,
                            float *t_front, float *t_back);

/* Runs fn over [0, count) on the calling thread (threads == 1) or through dr_parallel_for (render.c). */
void dr_render_run_(long count, int threads, DrRangeFn fn, void *ctx);

/* ---- light (light.c) ----------------------------------------------------------------------------- */

/* Orthographic shadow map of the key light over the opaque geometry (casters) and what may receive
 * their shadow in view (liquid, and the ground under the casters' shadow), res × res texels at most. */
typedef struct DrShadowMap {
    bool on;
    DrVec3 lx, ly, lz; /* light frame: lz is the direction the light travels */
    double u0, v0, d0; /* light-frame origin of texel (0, 0) and of depth 0 */
    double texel;      /* metres per texel */
    int w, h;
    float *depth; /* w*h nearest caster depth - d0 per texel, +FLT_MAX where none */
} DrShadowMap;
DR_NODISCARD DrStatus dr_render_shadow_build_(const DrRenderScene *scene, const DrCamera *cam,
                                              const DrRenderDesc *desc, int res, DrShadowMap *sm, DrError *err);
/* Fraction of the key light reaching point p with unit normal n (ndl = n·to_light), in [0, 1]. */
double dr_render_shadow_(const DrShadowMap *sm, DrVec3 p, DrVec3 n, double ndl);
void dr_render_shadow_free_(DrShadowMap *sm);

/* Contact darkening on the ground: a top-down grid of how close the opaque geometry above each cell comes
 * to the ground, exp(-height / reach), blurred so the darkening spreads softly around what rests there. */
typedef struct DrContactGrid {
    bool on;
    double x0, z0, cell; /* world x, z of cell (0, 0)'s centre; cell size, metres */
    int nx, nz;
    float *occ; /* nx*nz, in [0, 1] */
} DrContactGrid;
DR_NODISCARD DrStatus dr_render_contact_build_(const DrRenderScene *scene, double ground_h, double reach,
                                               DrContactGrid *cg, DrError *err);
/* Bilinear occupancy at world (x, z); 0 off the grid. */
double dr_render_contact_(const DrContactGrid *cg, double x, double z);
void dr_render_contact_free_(DrContactGrid *cg);

/* ---- shading codes ----------------------------------------------------------------------------- */

enum DrShadeCode {
    DR_SHADE_NONE = 0,
    DR_SHADE_GROUND = 1,
    DR_SHADE_MESH = 2,     /* + DrRenderMaterial: a surface with a normal */
    DR_SHADE_STRAND = 0x40 /* | DrRenderMaterial: a strand with a tangent, scaled by 1 + its wetness (shade.c) */
};

/* ---- shading (shade.c) ---------------------------------------------------------------------------- */

/* Everything a sample's colour depends on, fixed for one render call. Colours are linear RGB. */
typedef struct DrShadeCtx {
    DrCamFrame cf;
    double fs;       /* focal length in samples */
    double cxs, cys; /* raster coordinates of the optical axis */
    DrVec3 to_light; /* unit, towards the key light */
    DrVec3 sun;      /* key light irradiance on a surface facing it */
    DrVec3 sky_fill, ground_fill; /* hemispheric fill from above and from below */
    bool ground;
    double ground_h, ground_cell, fog_dist, contact_reach;
    DrVec3 sigma;         /* liquid absorption per metre, per channel (Beer–Lambert) */
    DrVec3 water_scatter; /* radiance the liquid adds where it absorbs (its body colour) */
    double thickness_clamp;
    DrVec3 horizon;       /* sky colour at elevation 0, where the ground's fog goes */
    DrShadowMap sm;
    DrContactGrid cg;
} DrShadeCtx;

static inline double dr_maxd_(double a, double b) { return a > b ? a : b; } /* fmax without the call */
static inline double dr_mind_(double a, double b) { return a < b ? a : b; }

/* Direction (not unit: its forward component is 1) of the ray through raster point (sx, sy). */
static inline DrVec3 dr_render_ray_(const DrShadeCtx *sc, double sx, double sy)
{
    double a = (sx - sc->cxs) / sc->fs, b = -(sy - sc->cys) / sc->fs;
    return dr_v3_add(sc->cf.f, dr_v3_add(dr_v3_scale(sc->cf.r, a), dr_v3_scale(sc->cf.u, b)));
}

/* Depth t along ray `dir` (view depth, since dir's forward component is 1) where it meets the ground, or 0
 * when it does not (looking up, or the eye is under the ground). */
double dr_render_ground_t_(const DrShadeCtx *sc, DrVec3 dir);

/* Colour of an opaque sample: `code` its shade code, iz its 1/depth, nrm the interpolated attribute;
 * `filter` is the width in samples the colour stands for (1 for one sample, `samples` for a whole pixel),
 * over which the ground's checker is box-filtered. */
DrVec3 dr_render_shade_opaque_(const DrShadeCtx *sc, DrVec3 dir, uint8_t code, float iz, const float nrm[3],
                               double filter);
/* Colour through the liquid: `behind` is what lies behind it; near_iz/far_iz the nearest and farthest
 * liquid surfaces in front of the opaque depth opaque_iz (far_iz >= near_iz: only one surface found). */
DrVec3 dr_render_shade_liquid_(const DrShadeCtx *sc, DrVec3 dir, DrVec3 behind, float near_iz, const float nrm[3],
                               float far_iz, float opaque_iz);

#endif
