/* drench render: a CPU preview renderer for dailies, PNG images and contact sheets.
 *
 * Model. A DrRenderScene holds triangle meshes and polylines (hair), each with a material kind, and a
 * ground plane. dr_render_image rasterises them with a z-buffer at `samples`×`samples` supersamples
 * per pixel (box-filtered down: antialiasing), lights them with one directional key light whose
 * shadows come from a shadow map, a sky fill light, and darkens where geometry meets the ground
 * (contact shadow). Liquid is drawn last, as a tinted transparent medium: what lies behind it is
 * attenuated by its thickness along the view ray (Beer–Lambert, between the liquid's nearest and
 * farthest surfaces in front of the opaque geometry) and a Schlick-Fresnel reflection of the sky is
 * blended on top, so it reads as water rather than plastic. Liquid receives shadows but casts none;
 * shadows end at 5 eye-target distances from the eye (so a huge floor does not dilute the shadow map).
 *
 * Meshes are drawn two-sided (a face seen from behind is lit as its front), so open sheets and a camera
 * inside a closed mesh work; vertex normals more than ~25° off their face are taken as creases (a box's
 * joined corner normals) and that face is drawn flat. The ground is an infinite plane y = ground_height
 * with a faint checker whose cell is a round size (1, 2 or 5 × 10^k m) near a sixth of the scene's
 * extent (desc.scene_size, else what is drawn; at most a third of the eye-target distance), fading into
 * the horizon colour with distance; it is seen only from above. Wall panels (DR_MATERIAL_WALL) are
 * composited over what lies behind them, after the liquid when in front of it.
 *
 * Camera: a pinhole at `eye` looking at `target`, `up` giving the roll, `fov_deg` the vertical field of
 * view, `width`×`height` pixels. Pixel (i, j) has its centre at image-plane point (i + 0.5, j + 0.5),
 * j counting down from the top row. dr_camera_project is the exact projection the rasteriser uses:
 * with the ground off, a pixel whose supersamples all lie outside the projected geometry is exactly the
 * background (dr_render_background).
 *
 * Images are 8-bit sRGB RGB, rows top to bottom.
 *
 * Ownership: the scene copies what it is given (the caller may free its meshes afterwards).
 * Thread safety: a scene is read-only during dr_render_image; several threads may render different
 * scenes (or the same scene) at once. dr_render_image runs on `threads` threads of its own
 * (dr_parallel_for when threads != 1; 1 = the calling thread only, for callers that render several
 * frames in parallel). The image is bit-identical for any thread count: the frame is split into bands
 * of pixel rows that each compute their own pixels from the same inputs in the same order.
 * Memory: a render holds its triangles once more (about 100 bytes each after clipping), a shadow map
 * of up to 2048² floats and, per thread, one band of supersample buffers (37 bytes per sample). */
#ifndef DR_RENDER_H
#define DR_RENDER_H

#include <stdint.h>

#include "core/core.h"

/* ---- images --------------------------------------------------------------------------------- */

typedef struct DrImage {
    int width, height;
    uint8_t *rgb; /* 3*width*height bytes, row-major from the top row */
} DrImage;

/* Allocates a width×height image filled with `fill` (r, g, b). DR_ERR_INPUT for a size < 1 or above
 * 65535 per side, DR_ERR_NOMEM when it cannot be allocated. */
DR_NODISCARD DrStatus dr_image_create(int width, int height, const uint8_t fill[3], DrImage *out, DrError *err);
void dr_image_free(DrImage *img); /* frees and zeroes; a zeroed image is a no-op */
/* Writes a PNG (libpng, 8-bit RGB) atomically: "<path>.tmp.<pid>" then rename, so a killed writer never
 * leaves a partial PNG under `path`. DR_ERR_IO naming the file on failure, nothing left behind. */
DR_NODISCARD DrStatus dr_image_write_png(const char *path, const DrImage *img, DrError *err);
/* Reads any PNG libpng reads (palette, grey, 16-bit and alpha are converted to 8-bit RGB; alpha is
 * dropped). DR_ERR_INPUT naming the file for a missing or corrupt file. */
DR_NODISCARD DrStatus dr_image_read_png(const char *path, DrImage *out, DrError *err);
/* Draws `text` (printable ASCII; other bytes draw as '?') with the built-in 5×7 bitmap font, each font
 * pixel `scale`×`scale` image pixels, top-left corner at (x, y), clipped to the image. */
void dr_image_draw_text(DrImage *img, int x, int y, int scale, const uint8_t color[3], const char *text);
/* Width and height in pixels that dr_image_draw_text covers for `text` at `scale`. */
void dr_image_text_size(const char *text, int scale, int *w, int *h);
/* Area-averaged resize of `src` to w×h (each destination pixel averages the source pixels it covers,
 * weighted by overlap; a constant image stays exactly constant), used for contact-sheet thumbnails.
 * Upscaling works too (then a pixel blends at most two neighbours per axis). DR_ERR_INPUT for a size
 * < 1 or above 65535. */
DR_NODISCARD DrStatus dr_image_resize(const DrImage *src, int w, int h, DrImage *out, DrError *err);

/* Contact sheet: `count` images (all the same size) as thumbnails `thumb_width` wide (height keeps the
 * aspect) in a grid of `columns`, each labelled with labels[i] (e.g. "frame 12") under it, on a dark
 * background. The geometry is dr_image_sheet_layout's: image i sits in column i % columns, row
 * i / columns, at x = M + column*(thumb_width + M), y = M + row*(thumb_height + label_height + M) with
 * M = DR_SHEET_MARGIN; its label starts DR_SHEET_LABEL_PAD pixels under the thumbnail, cut to the
 * characters that fit in thumb_width. `labels` (or an entry of it) may be NULL: no label.
 * DR_ERR_INPUT when count < 1, columns < 1, the sizes differ, or thumb_width < 16. */
#define DR_SHEET_MARGIN 8    /* pixels around and between thumbnails */
#define DR_SHEET_LABEL_PAD 3 /* pixels above and below a label */
#define DR_SHEET_MIN_THUMB 16
DR_NODISCARD DrStatus dr_image_contact_sheet(const DrImage *images, const char *const *labels, int count,
                                             int columns, int thumb_width, DrImage *out, DrError *err);
typedef struct DrSheetLayout {
    int columns, rows;              /* columns = min(columns, count), rows = ceil(count / columns) */
    int thumb_width, thumb_height;  /* thumb_height = round(thumb_width * height / width), at least 1 */
    int label_scale, label_height;  /* font scale 2 for thumbnails >= 200 px wide, else 1; 7*scale + 2*pad */
    int width, height;              /* of the whole sheet: M + columns*(thumb_width + M) by
                                       M + rows*(thumb_height + label_height + M) */
} DrSheetLayout;
/* The layout dr_image_contact_sheet uses for `count` images of image_width x image_height (all >= 1). */
void dr_image_sheet_layout(int image_width, int image_height, int count, int columns, int thumb_width,
                           DrSheetLayout *layout);

/* ---- camera ---------------------------------------------------------------------------------- */

typedef struct DrCamera {
    DrVec3 eye, target, up; /* metres; up need not be unit or orthogonal to the view direction */
    double fov_deg;         /* vertical field of view, degrees, in (0, 180) */
    int width, height;      /* pixels */
} DrCamera;

/* DR_ERR_INPUT when eye == target, up is parallel to the view direction, the field of view is outside
 * (0, 180) or a size is < 1; the message names the field. */
DR_NODISCARD DrStatus dr_camera_check(const DrCamera *cam, DrError *err);
/* Near clipping distance, metres: geometry closer to the eye plane than this is clipped away. */
#define DR_CAMERA_NEAR 1e-3
/* Projects world point p to continuous pixel coordinates (px right, py down, pixel centres at +0.5) and
 * view depth (distance along the view direction). Returns false when p is not in front of the camera
 * (depth <= DR_CAMERA_NEAR); px, py are then left unset. */
bool dr_camera_project(const DrCamera *cam, DrVec3 p, double *px, double *py, double *depth);

/* ---- scene ------------------------------------------------------------------------------------ */

typedef enum DrRenderMaterial {
    DR_MATERIAL_LIQUID,   /* transparent tinted water with Fresnel reflection */
    DR_MATERIAL_COLLIDER, /* matte grey-blue solid */
    DR_MATERIAL_SOLID,    /* deformable solids (MPM, BEM, cloth): warm matte */
    DR_MATERIAL_HAIR,     /* hair/fur strands: dark brown, anisotropic highlight */
    DR_MATERIAL_WALL,     /* faint glass panels (a tank's or a simulation domain's walls): each panel in front
                             of the opaque geometry tints what lies behind it towards a pale blue-grey, by 5 %
                             facing the camera and up to 30 % at grazing angles (so its edges read); panels behind
                             the liquid's near surface are seen through the liquid. Walls occlude nothing,
                             cast no shadow and take no contact shadow; triangles only. */
} DrRenderMaterial;

typedef struct DrRenderDesc {
    int samples;          /* supersamples per pixel side (1..8); default 3 */
    bool ground;          /* draw the ground plane; default true */
    double ground_height; /* y of the ground plane, metres; default 0 */
    DrVec3 light_dir;     /* direction the key light travels (towards the scene); default (-0.4,-1,-0.3) */
    bool shadows;         /* shadow map for the key light; default true */
    int threads;          /* 0 = all threads (dr_parallel_for), 1 = calling thread only, n > 1 = at most
                             n of dr_parallel_for's threads; default 0 */
    double scene_size;    /* metres, >= 0: the size the ground's checker cell (a round number near a sixth
                             of it), its fog and the contact shadows' reach follow; 0 (default) = the
                             largest side of what is drawn. Frames of one sequence must share one size
                             (the render stage passes the extent of the shot's domains and still colliders),
                             or the checker changes scale as things move */
    double liquid_size;   /* metres, >= 0: the liquid's absorption scale (Beer–Lambert, red fading over a
                             seventh of it, blue over two thirds); 0 (default) = the largest side of the
                             liquid drawn. A sequence passes one size (the render stage: the liquid's
                             Domain), or the water's tint changes with how far it has spread */
} DrRenderDesc;
DrRenderDesc dr_render_desc_default(void);

typedef struct DrRenderScene DrRenderScene;

DR_NODISCARD DrStatus dr_render_scene_create(DrRenderScene **out, DrError *err);
void dr_render_scene_destroy(DrRenderScene **scene);
/* Adds a triangle mesh (copied). Missing normals (mesh->n NULL) are computed, area-weighted; given ones
 * are normalised (zero stays zero: that corner takes its face's normal). Non-finite vertices and triangle
 * indices outside [0, nv) are DR_ERR_INPUT. An empty mesh is accepted and draws nothing. */
DR_NODISCARD DrStatus dr_render_scene_add_mesh(DrRenderScene *scene, const DrTriMesh *mesh, DrRenderMaterial mat,
                                               DrError *err);
/* Adds `count` polylines (copied): strand s has vertices offsets[s] .. offsets[s+1]-1 of `points` (3 per
 * vertex, metres) and radius radius[s] (metres). Each segment is drawn as a ribbon facing the camera,
 * 2*radius[s] wide in projection and at least one pixel wide, extended by half its width past each end
 * (so consecutive segments join without gaps), depth tested against everything else, lit with Kajiya–Kay
 * along its tangent (a dark brown for DR_MATERIAL_HAIR); strands cast shadows. A strand of fewer than 2
 * vertices draws nothing; count 0 adds nothing. DR_ERR_INPUT for offsets[0] != 0, decreasing offsets, a
 * non-finite point, a negative or non-finite radius (naming the strand), or the liquid or wall material. */
DR_NODISCARD DrStatus dr_render_scene_add_polylines(DrRenderScene *scene, const double *points,
                                                    const int *offsets, int count, const double *radius,
                                                    DrRenderMaterial mat, DrError *err);
/* Wet strands: as dr_render_scene_add_polylines, with a radius per vertex (radius[v] for vertex v of `points`,
 * metres: the liquid film's outer radius, which the strand is drawn as wide as) and a wetness per vertex
 * (wetness[v] in [0, 1], or wetness NULL for none), both linear along each segment. Wetness darkens the strand's
 * albedo towards that of a fibre under a film of water (Lekner and Dorf's model: dark hair keeps about half its
 * albedo at wetness 1); at wetness 0 and one radius per strand a strand is drawn exactly as
 * dr_render_scene_add_polylines draws it. Shadows follow the per-vertex width. DR_ERR_INPUT as
 * dr_render_scene_add_polylines, and for a negative or non-finite radius or a wetness outside [0, 1] (naming the
 * strand and its vertex). */
DR_NODISCARD DrStatus dr_render_scene_add_wet_polylines(DrRenderScene *scene, const double *points,
                                                        const int *offsets, int count, const double *radius,
                                                        const double *wetness, DrRenderMaterial mat, DrError *err);
/* Axis-aligned bounds of everything added (false when the scene is empty). */
bool dr_render_scene_bounds(const DrRenderScene *scene, DrVec3 *lo, DrVec3 *hi);

/* Renders the scene through `cam` into *out (allocated here; caller frees with dr_image_free). Nothing in
 * view renders the background alone (sky gradient, and the ground if enabled); a camera inside geometry
 * or looking at nothing is not an error. DR_ERR_INPUT for an invalid camera (dr_camera_check) or desc
 * (samples outside 1..8, a non-finite ground_height, a zero or non-finite light_dir, threads < 0, a
 * negative or non-finite scene_size or liquid_size), with
 * *out zeroed; DR_ERR_NOMEM when buffers cannot be allocated. */
DR_NODISCARD DrStatus dr_render_image(const DrRenderScene *scene, const DrCamera *cam, const DrRenderDesc *desc,
                                      DrImage *out, DrError *err);
/* The background colour of pixel row j (0 = top) for a camera: what an empty scene renders with
 * desc.ground false. Exposed so tests and callers can tell background from geometry. */
void dr_render_background(const DrCamera *cam, int row, uint8_t rgb[3]);

#endif
