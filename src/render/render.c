/* dr_render_image: the frame's driver.
 *
 * 1. validate, set up the camera, the key light's shadow map and the contact grid;
 * 2. transform every vertex to camera space once, clip each triangle against the near plane and a guard
 *    band around the raster (Sutherland–Hodgman in camera space, so attributes stay exact), and emit it
 *    into the opaque or the liquid list; strands become camera-facing quads;
 * 3. bin the triangles into bands of BAND_PX pixel rows;
 * 4. per band (in parallel; each band owns its pixels): ground depth, opaque z-buffer, liquid near/far
 *    layers, wall panels' transmittance in front of and behind the liquid, shading (once per pixel where all its supersamples see one smooth surface, else per
 *    supersample and box-filtered) and sRGB encoding of its pixel rows.
 * A band's result depends only on the band, so any thread count gives the same bytes. */
#include <float.h>
#include <stdlib.h>
#include <string.h>

#include "render/render_internal.h"

#define BAND_PX 8     /* pixel rows per band: small enough to stay in cache, large enough to bin cheaply */
#define MAX_CLIP 10   /* a triangle clipped by 5 planes has at most 8 corners */

DrRenderDesc dr_render_desc_default(void)
{
    DrRenderDesc d = {.samples = 3, .ground = true, .ground_height = 0.0, .light_dir = {-0.4, -1.0, -0.3},
                      .shadows = true, .threads = 0, .scene_size = 0.0, .liquid_size = 0.0};
    return d;
}

static DrStatus check_desc(const DrRenderDesc *d, DrError *err)
{
    if (d->samples < 1 || d->samples > 8)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "render samples %d is outside 1..8", d->samples);
    if (!isfinite(d->ground_height))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "render ground_height is not finite");
    if (!dr_v3_isfinite(d->light_dir) || !(dr_v3_norm(d->light_dir) > 0.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "render light_dir (%g, %g, %g) must be a finite, non-zero direction", d->light_dir.x,
                            d->light_dir.y, d->light_dir.z);
    if (d->threads < 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "render threads %d must be 0 (all) or more", d->threads);
    if (!(isfinite(d->scene_size) && d->scene_size >= 0.0) || !(isfinite(d->liquid_size) && d->liquid_size >= 0.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "render scene_size %g m and liquid_size %g m must be finite and >= 0 (0 = measured)",
                            d->scene_size, d->liquid_size);
    return DR_OK;
}

void dr_render_run_(long count, int threads, DrRangeFn fn, void *ctx)
{
    if (count <= 0) return;
    if (threads == 1)
        fn(0, count, ctx);
    else
        dr_parallel_for(count, 1, fn, ctx);
}

/* ---- camera-space setup ------------------------------------------------------------------------------ */

/* The raster of supersamples and the five clip planes: near, and a guard band of `guard` samples around
 * the raster (so fixed-point corners stay small) as planes through the eye. */
typedef struct View {
    DrCamFrame cf;
    int ws, hs;              /* raster size in samples */
    double fs, cxs, cys;     /* X = cxs + fs*x/z, Y = cys - fs*y/z */
    double guard;
} View;

typedef struct ClipVert {
    double p[3]; /* camera space */
    double a[3]; /* attribute (world normal or tangent) */
} ClipVert;

static double plane_dist(const View *v, int k, const double *p)
{
    switch (k) {
    case 0: return p[2] - DR_CAMERA_NEAR;
    case 1: return v->fs * p[0] + (v->cxs + v->guard) * p[2];
    case 2: return (v->ws - 1 + v->guard - v->cxs) * p[2] - v->fs * p[0];
    case 3: return (v->cys + v->guard) * p[2] - v->fs * p[1];
    default: return v->fs * p[1] + (v->hs - 1 + v->guard - v->cys) * p[2];
    }
}

static uint8_t outcode(const View *v, const double *p)
{
    uint8_t c = 0;
    for (int k = 0; k < 5; k++) c |= (uint8_t)((plane_dist(v, k, p) < 0.0) << k);
    return c;
}

static void to_camera(const DrCamFrame *cf, const double *w, double *c)
{
    DrVec3 d = dr_v3_sub(dr_v3(w[0], w[1], w[2]), cf->eye);
    c[0] = dr_v3_dot(d, cf->r);
    c[1] = dr_v3_dot(d, cf->u);
    c[2] = dr_v3_dot(d, cf->f);
}

/* Projects the convex polygon poly[0..n) (all corners in front of the near plane) and emits it as a fan. */
static DrStatus emit_polygon(const View *v, const ClipVert *poly, int n, uint8_t shade, DrTriList *list,
                             DrError *err)
{
    double x[MAX_CLIP], y[MAX_CLIP];
    float iz[MAX_CLIP], a[MAX_CLIP][3];
    for (int i = 0; i < n; i++) {
        double inv = 1.0 / poly[i].p[2];
        x[i] = v->cxs + v->fs * poly[i].p[0] * inv;
        y[i] = v->cys - v->fs * poly[i].p[1] * inv;
        iz[i] = (float)inv;
        for (int c = 0; c < 3; c++) a[i][c] = (float)(poly[i].a[c] * inv);
    }
    for (int i = 1; i + 1 < n; i++) {
        double tx[3] = {x[0], x[i], x[i + 1]}, ty[3] = {y[0], y[i], y[i + 1]};
        float tiz[3] = {iz[0], iz[i], iz[i + 1]};
        float ta[3][3];
        for (int c = 0; c < 3; c++) ta[0][c] = a[0][c], ta[1][c] = a[i][c], ta[2][c] = a[i + 1][c];
        DR_TRY(dr_render_emit_(list, tx, ty, tiz, (const float(*)[3])ta, shade, v->ws, v->hs, err));
    }
    return DR_OK;
}

/* Sutherland–Hodgman against the planes in `planes` (bit k: plane k), then emit. */
static DrStatus clip_and_emit(const View *v, ClipVert in[3], uint8_t planes, uint8_t shade, DrTriList *list,
                              DrError *err)
{
    ClipVert buf[2][MAX_CLIP];
    int n = 3, cur = 0;
    memcpy(buf[0], in, 3 * sizeof *in);
    for (int k = 0; k < 5 && n > 0; k++) {
        if (!(planes & (1u << k))) continue;
        const ClipVert *src = buf[cur];
        ClipVert *dst = buf[1 - cur];
        int m = 0;
        for (int i = 0; i < n; i++) {
            const ClipVert *p = &src[i], *q = &src[(i + 1) % n];
            double dp = plane_dist(v, k, p->p), dq = plane_dist(v, k, q->p);
            if (dp >= 0.0) dst[m++] = *p;
            if ((dp >= 0.0) != (dq >= 0.0)) {
                double t = dp / (dp - dq);
                ClipVert r;
                for (int c = 0; c < 3; c++) {
                    r.p[c] = p->p[c] + t * (q->p[c] - p->p[c]);
                    r.a[c] = p->a[c] + t * (q->a[c] - p->a[c]);
                }
                dst[m++] = r;
            }
        }
        n = m;
        cur = 1 - cur;
    }
    if (n < 3) return DR_OK;
    return emit_polygon(v, buf[cur], n, shade, list, err);
}

static DrStatus emit_mesh(const View *v, const DrRenderMesh *m, double *cam, uint8_t *oc, DrTriList *list,
                          DrError *err)
{
    for (int i = 0; i < m->nv; i++) {
        to_camera(&v->cf, m->v + 3 * i, cam + 3 * i);
        oc[i] = outcode(v, cam + 3 * i);
    }
    uint8_t shade = (uint8_t)(DR_SHADE_MESH + m->mat);
    bool wall = m->mat == DR_MATERIAL_WALL;
    for (int t = 0; t < m->nt; t++) {
        const int *c = m->tri + 3 * t;
        if (oc[c[0]] & oc[c[1]] & oc[c[2]]) continue; /* wholly outside one plane */
        const double *w0 = m->v + 3 * c[0], *w1 = m->v + 3 * c[1], *w2 = m->v + 3 * c[2];
        DrVec3 e1 = dr_v3(w1[0] - w0[0], w1[1] - w0[1], w1[2] - w0[2]);
        DrVec3 e2 = dr_v3(w2[0] - w0[0], w2[1] - w0[1], w2[2] - w0[2]);
        DrVec3 fn = dr_v3_cross(e1, e2);
        /* two-sided: a triangle seen from its back is lit as seen from the front (open sheets, a camera inside
           a closed mesh), so its normals are turned towards the eye */
        double side = dr_v3_dot(fn, dr_v3_sub(v->cf.eye, dr_v3(w0[0], w0[1], w0[2]))) < 0.0 ? -1.0 : 1.0;
        DrVec3 fu = dr_v3_normalize(fn);
        ClipVert cv[3];
        for (int k = 0; k < 3; k++) {
            const double *n = m->n + 3 * c[k];
            /* a vertex normal more than ~25 degrees off the face is a crease (a box's corner, whose joined
               normal points diagonally): such faces are drawn flat */
            DrVec3 nn = dr_v3(n[0], n[1], n[2]);
            if (dr_v3_dot(nn, fu) < 0.9) nn = fu;
            memcpy(cv[k].p, cam + 3 * c[k], sizeof cv[k].p);
            cv[k].a[0] = side * nn.x, cv[k].a[1] = side * nn.y, cv[k].a[2] = side * nn.z;
            if (wall) {
                /* a wall panel carries its opacity instead of a normal: 5 % seen square on, rising to 30 % seen
                   edge-on ((1 - cos)^4, as a glass pane's reflectance rises), so a tank's edges read */
                const double *w = m->v + 3 * c[k];
                DrVec3 view = dr_v3_normalize(dr_v3_sub(v->cf.eye, dr_v3(w[0], w[1], w[2])));
                double g = 1.0 - fabs(dr_v3_dot(fu, view));
                cv[k].a[0] = 0.05 + 0.25 * g * g * g * g, cv[k].a[1] = cv[k].a[2] = 0.0;
            }
        }
        uint8_t planes = oc[c[0]] | oc[c[1]] | oc[c[2]];
        if (planes)
            DR_TRY(clip_and_emit(v, cv, planes, shade, list, err));
        else
            DR_TRY(emit_polygon(v, cv, 3, shade, list, err));
    }
    return DR_OK;
}

/* A strand segment as a quad across the screen, at least one pixel (samples samples) wide, capped by half
 * its width at each end so consecutive segments join without gaps. The radius and the wetness go linearly from
 * (r0, wet0) at w0 to (r1, wet1) at w1; the wetness rides in the length of the tangent attribute, 1 + wet (the
 * shading normalises the tangent and reads the wetness from its length, shade.c). */
static DrStatus emit_segment(const View *v, const double *w0, const double *w1, double r0, double r1, double wet0,
                             double wet1, int samples, uint8_t shade, DrTriList *list, DrError *err)
{
    double c[2][3];
    to_camera(&v->cf, w0, c[0]);
    to_camera(&v->cf, w1, c[1]);
    double t0 = 0.0, t1 = 1.0;
    for (int k = 0; k < 5; k++) {
        double d0 = plane_dist(v, k, c[0]), d1 = plane_dist(v, k, c[1]);
        if (d0 < 0.0 && d1 < 0.0) return DR_OK;
        if (d0 < 0.0) t0 = fmax(t0, d0 / (d0 - d1));
        if (d1 < 0.0) t1 = fmin(t1, d0 / (d0 - d1));
    }
    if (t0 > t1) return DR_OK;
    DrVec3 tan = dr_v3_normalize(dr_v3(w1[0] - w0[0], w1[1] - w0[1], w1[2] - w0[2]));
    double x[2], y[2], hw[2], mag[2];
    float iz[2];
    for (int e = 0; e < 2; e++) {
        double t = e ? t1 : t0, p[3];
        for (int k = 0; k < 3; k++) p[k] = c[0][k] + t * (c[1][k] - c[0][k]);
        x[e] = v->cxs + v->fs * p[0] / p[2];
        y[e] = v->cys - v->fs * p[1] / p[2];
        iz[e] = (float)(1.0 / p[2]);
        double radius = r0 + t * (r1 - r0); /* r0 itself on a strand of one radius */
        hw[e] = fmin(fmax(0.5 * samples, v->fs * radius / p[2]), 0.25 * v->guard);
        mag[e] = 1.0 + (wet0 + t * (wet1 - wet0));
    }
    double dx = x[1] - x[0], dy = y[1] - y[0], len = sqrt(dx * dx + dy * dy);
    if (len < 1e-9) dx = 1.0, dy = 0.0, len = 1.0; /* end-on: a square dot */
    dx /= len, dy /= len;
    /* corners: start minus and plus the normal (-dy, dx), then end minus and plus it, each moved out by the cap */
    double qx[4] = {x[0] - (dx + dy) * hw[0], x[0] - (dx - dy) * hw[0], x[1] + (dx + dy) * hw[1],
                    x[1] + (dx - dy) * hw[1]};
    double qy[4] = {y[0] - (dy - dx) * hw[0], y[0] - (dy + dx) * hw[0], y[1] + (dy - dx) * hw[1],
                    y[1] + (dy + dx) * hw[1]};
    float qiz[4] = {iz[0], iz[0], iz[1], iz[1]};
    double qmag[4] = {mag[0], mag[0], mag[1], mag[1]};
    static const int tri[2][3] = {{0, 1, 2}, {0, 2, 3}};
    for (int t = 0; t < 2; t++) {
        double tx[3], ty[3];
        float tiz[3], ta[3][3];
        for (int k = 0; k < 3; k++) {
            int q = tri[t][k];
            tx[k] = qx[q], ty[k] = qy[q], tiz[k] = qiz[q];
            DrVec3 a = dr_v3_scale(tan, qmag[q]); /* the tangent itself where dry (1.0 exactly) */
            ta[k][0] = (float)(a.x * qiz[q]), ta[k][1] = (float)(a.y * qiz[q]), ta[k][2] = (float)(a.z * qiz[q]);
        }
        DR_TRY(dr_render_emit_(list, tx, ty, tiz, (const float(*)[3])ta, shade, v->ws, v->hs, err));
    }
    return DR_OK;
}

static DrStatus emit_scene(const View *v, const DrRenderScene *scene, int samples, DrTriList *opaque,
                           DrTriList *liquid, DrTriList *walls, DrError *err)
{
    int maxv = 0;
    for (int i = 0; i < scene->nmeshes; i++) maxv = scene->meshes[i].nv > maxv ? scene->meshes[i].nv : maxv;
    double *cam = NULL;
    uint8_t *oc = NULL;
    DrStatus s = dr_calloc(3 * (size_t)maxv + 3, sizeof *cam, &cam, err);
    if (s == DR_OK) s = dr_calloc((size_t)maxv + 1, sizeof *oc, &oc, err);
    for (int i = 0; s == DR_OK && i < scene->nmeshes; i++) {
        const DrRenderMesh *m = &scene->meshes[i];
        DrTriList *list = m->mat == DR_MATERIAL_LIQUID ? liquid : m->mat == DR_MATERIAL_WALL ? walls : opaque;
        s = emit_mesh(v, m, cam, oc, list, err);
    }
    for (int i = 0; s == DR_OK && i < scene->nstrands; i++) {
        const DrRenderStrands *st = &scene->strands[i];
        uint8_t shade = (uint8_t)(DR_SHADE_STRAND | st->mat);
        for (int k = 0; s == DR_OK && k < st->count; k++)
            for (int p = st->offsets[k]; s == DR_OK && p + 1 < st->offsets[k + 1]; p++)
                s = emit_segment(v, st->points + 3 * p, st->points + 3 * p + 3, st->radius[p], st->radius[p + 1],
                                 st->wet ? st->wet[p] : 0.0, st->wet ? st->wet[p + 1] : 0.0, samples, shade, opaque,
                                 err);
    }
    free(cam);
    free(oc);
    return s;
}

/* ---- bands ---------------------------------------------------------------------------------------------- */

typedef struct Scratch {
    float *op_iz, *op_n, *lq_near, *lq_n, *lq_far;
    float *wall_front, *wall_back; /* transmittance of the wall panels in front of / behind the liquid */
    uint8_t *shade;
} Scratch;

typedef struct Job {
    const View *view;
    const DrShadeCtx *sc;
    const DrTriList *opaque, *liquid, *walls;
    const DrBins *bins_opaque, *bins_liquid, *bins_walls;
    const float *bg; /* 3 per pixel row */
    const DrSrgbTable *srgb;
    Scratch *scratch;
    int workers, nbands, width, height, samples;
    DrImage *out;
} Job;

/* `c` seen through wall panels of transmittance t: every panel has the same colour, so the panels' order
 * does not matter. */
static DrVec3 through_walls(DrVec3 c, float t)
{
    if (t >= 1.0f) return c;
    static const DrVec3 glass = {0.55, 0.62, 0.70};
    return dr_v3_add(dr_v3_scale(c, t), dr_v3_scale(glass, 1.0 - t));
}

/* Colour of sample k at raster point (sx, sy): background, or the opaque surface, seen through the walls
 * behind the liquid, the liquid when there is some in front, and the walls in front of it. */
static DrVec3 sample_colour(const DrShadeCtx *sc, const Scratch *s, size_t k, int sx, int sy, const float *bg,
                            double filter)
{
    DrVec3 dir = dr_render_ray_(sc, sx, sy), c;
    if (s->shade[k] == DR_SHADE_NONE)
        c = dr_v3(bg[0], bg[1], bg[2]);
    else
        c = dr_render_shade_opaque_(sc, dir, s->shade[k], s->op_iz[k], s->op_n + 3 * k, filter);
    c = through_walls(c, s->wall_back[k]);
    if (s->lq_near[k] > 0.0f)
        c = dr_render_shade_liquid_(sc, dir, c, s->lq_near[k], s->lq_n + 3 * k, s->lq_far[k], s->op_iz[k]);
    return through_walls(c, s->wall_front[k]);
}

/* Attributes a and b point within about 8 degrees of each other (cos² >= 0.98; unnormalised vectors). */
static bool similar(const float *a, const float *b)
{
    float d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    float aa = a[0] * a[0] + a[1] * a[1] + a[2] * a[2], bb = b[0] * b[0] + b[1] * b[1] + b[2] * b[2];
    return d > 0.0f && d * d >= 0.98f * aa * bb;
}

/* True when the S×S samples from index k0 (top-left) all see what the centre sample kc sees: the same shade
 * code (not a strand), liquid on all or none, and normals (opaque and liquid) close to the centre's. */
static bool pixel_uniform(const Scratch *s, int ws, int S, size_t k0, size_t kc)
{
    uint8_t code = s->shade[kc];
    bool liquid = s->lq_near[kc] > 0.0f, two = s->lq_far[kc] < s->lq_near[kc];
    if (code & DR_SHADE_STRAND) return false;
    for (int a = 0; a < S; a++)
        for (int b = 0; b < S; b++) {
            size_t k = k0 + (size_t)a * ws + (size_t)b;
            if (s->shade[k] != code || (s->lq_near[k] > 0.0f) != liquid) return false;
            /* a wall panel's edge, or where its opacity changes fast (grazing), is shaded per sample */
            if (fabsf(s->wall_front[k] - s->wall_front[kc]) > 0.01f || fabsf(s->wall_back[k] - s->wall_back[kc]) > 0.01f)
                return false;
            if (code >= DR_SHADE_MESH && !similar(s->op_n + 3 * k, s->op_n + 3 * kc)) return false;
            if (liquid && ((s->lq_far[k] < s->lq_near[k]) != two || !similar(s->lq_n + 3 * k, s->lq_n + 3 * kc)))
                return false;
        }
    return true;
}

static void band_pass(const Job *job, Scratch *s, int b)
{
    const View *v = job->view;
    const DrShadeCtx *sc = job->sc;
    int S = job->samples, ws = v->ws;
    int prow0 = b * BAND_PX, prows = job->height - prow0 < BAND_PX ? job->height - prow0 : BAND_PX;
    int row0 = prow0 * S, rows = prows * S;
    size_t ns = (size_t)rows * (size_t)ws;
    /* 1. ground depth (pushed back by 1e-5 of the depth, so geometry resting on the ground wins the tie) */
    for (int sy = 0; sy < rows; sy++)
        for (int sx = 0; sx < ws; sx++) {
            size_t k = (size_t)sy * ws + sx;
            double t = sc->ground ? dr_render_ground_t_(sc, dr_render_ray_(sc, sx, row0 + sy)) : 0.0;
            s->op_iz[k] = t > 0.0 ? (float)(1.0 / t) * 0.99999f : 0.0f;
            s->shade[k] = t > 0.0 ? DR_SHADE_GROUND : DR_SHADE_NONE;
        }
    for (size_t k = 0; k < ns; k++) s->lq_near[k] = 0.0f, s->lq_far[k] = FLT_MAX;
    for (size_t k = 0; k < ns; k++) s->wall_front[k] = s->wall_back[k] = 1.0f;
    /* 2. opaque, 3. liquid layers, 4. wall panels in front of the opaque surface, split by the liquid's */
    DrDepthBand band = {row0, rows, ws, s->op_iz, s->op_n, s->shade};
    for (size_t k = job->bins_opaque->start[b]; k < job->bins_opaque->start[b + 1]; k++)
        dr_render_raster_opaque_(&job->opaque->t[job->bins_opaque->idx[k]], &band);
    for (size_t k = job->bins_liquid->start[b]; k < job->bins_liquid->start[b + 1]; k++)
        dr_render_raster_liquid_(&job->liquid->t[job->bins_liquid->idx[k]], s->op_iz, row0, rows, ws, s->lq_near,
                                 s->lq_n, s->lq_far);
    for (size_t k = job->bins_walls->start[b]; k < job->bins_walls->start[b + 1]; k++)
        dr_render_raster_wall_(&job->walls->t[job->bins_walls->idx[k]], s->op_iz, s->lq_near, row0, rows, ws,
                               s->wall_front, s->wall_back);
    /* 5. shade: a pixel whose samples all see one smooth surface is shaded once at its centre sample, as
          multisampling does (most of a frame: ground, sky, the inside of surfaces); edges, creases and
          strands are shaded sample by sample and box-filtered */
    int cs = S / 2;
    for (int j = 0; j < prows; j++) {
        const float *bg = job->bg + 3 * (size_t)(prow0 + j);
        for (int i = 0; i < job->width; i++) {
            size_t kc = (size_t)(j * S + cs) * ws + (size_t)(i * S + cs);
            double c[3];
            if (pixel_uniform(s, ws, S, (size_t)j * S * ws + (size_t)i * S, kc)) {
                DrVec3 v = sample_colour(sc, s, kc, i * S + cs, row0 + j * S + cs, bg, S);
                c[0] = v.x, c[1] = v.y, c[2] = v.z;
            } else {
                /* sums of up to 64 floats; a pixel of background samples only is uniform and never summed */
                double sum[3] = {0, 0, 0};
                for (int a = 0; a < S; a++)
                    for (int b2 = 0; b2 < S; b2++) {
                        size_t k = (size_t)(j * S + a) * ws + (size_t)(i * S + b2);
                        DrVec3 v = sample_colour(sc, s, k, i * S + b2, row0 + j * S + a, bg, 1.0);
                        sum[0] += v.x, sum[1] += v.y, sum[2] += v.z;
                    }
                for (int q = 0; q < 3; q++) c[q] = sum[q] / (double)(S * S);
            }
            uint8_t *o = job->out->rgb + 3 * ((size_t)(prow0 + j) * job->width + i);
            for (int q = 0; q < 3; q++) o[q] = dr_render_encode_(job->srgb, (float)c[q]);
        }
    }
}

static void worker(long begin, long end, void *ctx)
{
    const Job *job = ctx;
    for (long w = begin; w < end; w++)
        for (int b = (int)w; b < job->nbands; b += job->workers) band_pass(job, &job->scratch[w], b);
}

static void scratch_free(Scratch *s)
{
    free(s->op_iz), free(s->op_n), free(s->lq_near), free(s->lq_n), free(s->lq_far), free(s->shade);
    free(s->wall_front), free(s->wall_back);
    *s = (Scratch){0};
}

static DrStatus scratch_alloc(Scratch *s, size_t ns, DrError *err)
{
    DrStatus st = dr_calloc(ns, sizeof *s->op_iz, &s->op_iz, err);
    if (st == DR_OK) st = dr_calloc(3 * ns, sizeof *s->op_n, &s->op_n, err);
    if (st == DR_OK) st = dr_calloc(ns, sizeof *s->lq_near, &s->lq_near, err);
    if (st == DR_OK) st = dr_calloc(3 * ns, sizeof *s->lq_n, &s->lq_n, err);
    if (st == DR_OK) st = dr_calloc(ns, sizeof *s->lq_far, &s->lq_far, err);
    if (st == DR_OK) st = dr_calloc(ns, sizeof *s->shade, &s->shade, err);
    if (st == DR_OK) st = dr_calloc(ns, sizeof *s->wall_front, &s->wall_front, err);
    if (st == DR_OK) st = dr_calloc(ns, sizeof *s->wall_back, &s->wall_back, err);
    if (st != DR_OK) scratch_free(s);
    return st;
}

/* ---- the frame ------------------------------------------------------------------------------------------ */

/* 1, 2 or 5 times a power of ten, the nearest at or below x: a checker cell size that reads as a unit. */
static double nice_step(double x)
{
    double p = pow(10.0, floor(log10(x)));
    return x >= 5 * p ? 5 * p : (x >= 2 * p ? 2 * p : p);
}

static double max_side(DrVec3 lo, DrVec3 hi) { return fmax(hi.x - lo.x, fmax(hi.y - lo.y, hi.z - lo.z)); }

static void shade_setup(const DrRenderScene *scene, const DrCamera *cam, const DrRenderDesc *desc, const View *v,
                        DrShadeCtx *sc)
{
    sc->cf = v->cf;
    sc->fs = v->fs, sc->cxs = v->cxs, sc->cys = v->cys;
    sc->to_light = dr_v3_scale(dr_v3_normalize(desc->light_dir), -1.0);
    sc->sun = dr_v3(2.0, 1.9, 1.75);
    sc->horizon = dr_render_sky_(dr_v3(1, 0, 0));
    sc->sky_fill = dr_v3(0.36, 0.42, 0.52);
    sc->ground_fill = dr_v3(0.16, 0.15, 0.14);
    sc->ground = desc->ground;
    sc->ground_h = desc->ground_height;
    DrVec3 lo, hi;
    /* scales of the ground's checker and of contact darkening: the scene's size, but no more than twice the
       eye-target distance (a floor kilometres wide must not make the checker kilometres wide) */
    double view_dist = dr_v3_norm(dr_v3_sub(cam->target, cam->eye));
    /* a size the caller fixes for a whole sequence, else what this frame draws */
    double extent = desc->scene_size > 0.0 ? desc->scene_size
                    : dr_render_scene_bounds(scene, &lo, &hi) ? max_side(lo, hi)
                                                               : 0.0;
    if (!(extent > 0.0)) extent = view_dist;
    sc->ground_cell = nice_step(fmin(extent, 2.0 * view_dist) / 6.0);
    sc->fog_dist = 20.0 * fmax(extent, view_dist);
    double opaque = desc->scene_size > 0.0 ? desc->scene_size
                    : dr_render_bounds_of_(scene, false, &lo, &hi) ? max_side(lo, hi)
                                                                    : extent;
    sc->contact_reach = 0.12 * fmin(opaque > 0.0 ? opaque : extent, 2.0 * view_dist);
    /* absorption scaled to the liquid's size, so a tank and a droplet read alike: red goes first, blue last */
    double ls = desc->liquid_size > 0.0 ? desc->liquid_size
                : dr_render_bounds_of_(scene, true, &lo, &hi) ? max_side(lo, hi)
                                                               : 1.0;
    if (!(ls > 0.0)) ls = 1.0;
    sc->sigma = dr_v3_scale(dr_v3(7.0, 2.4, 1.7), 1.0 / ls);
    sc->water_scatter = dr_v3(0.02, 0.11, 0.14);
    sc->thickness_clamp = 0.5 * ls;
}

DrStatus dr_render_image(const DrRenderScene *scene, const DrCamera *cam, const DrRenderDesc *desc, DrImage *out,
                         DrError *err)
{
    assert(scene && cam && desc && out);
    *out = (DrImage){0};
    DR_TRY(dr_camera_check(cam, err));
    DR_TRY(check_desc(desc, err));
    int S = desc->samples;
    View v;
    dr_render_cam_frame_(cam, &v.cf);
    v.ws = cam->width * S, v.hs = cam->height * S;
    v.fs = v.cf.focal * S, v.cxs = v.cf.cx * S - 0.5, v.cys = v.cf.cy * S - 0.5;
    v.guard = (double)(v.ws > v.hs ? v.ws : v.hs);

    DrShadeCtx sc = {0};
    shade_setup(scene, cam, desc, &v, &sc);
    DrSrgbTable srgb;
    dr_render_srgb_table_(&srgb);
    static const uint8_t black[3] = {0, 0, 0};
    int workers = desc->threads == 1 ? 1 : dr_threads();
    if (desc->threads > 1 && desc->threads < workers) workers = desc->threads;

    DrTriList opaque = {0}, liquid = {0}, walls = {0};
    DrBins bo = {0}, bl = {0}, bw = {0};
    float *bg = NULL;
    Scratch *scratch = NULL;
    size_t band_samples = (size_t)BAND_PX * S * (size_t)v.ws;
    int res = 2 * (cam->width > cam->height ? cam->width : cam->height);
    res = res < 512 ? 512 : (res > 2048 ? 2048 : res);

    DrStatus s = dr_image_create(cam->width, cam->height, black, out, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)cam->height, sizeof *bg, &bg, err);
    if (s == DR_OK) s = dr_calloc((size_t)workers, sizeof *scratch, &scratch, err);
    for (int w = 0; s == DR_OK && w < workers; w++) s = scratch_alloc(&scratch[w], band_samples, err);
    if (s == DR_OK) s = dr_render_shadow_build_(scene, cam, desc, res, &sc.sm, err);
    if (s == DR_OK && desc->ground)
        s = dr_render_contact_build_(scene, desc->ground_height, sc.contact_reach, &sc.cg, err);
    if (s == DR_OK) s = emit_scene(&v, scene, S, &opaque, &liquid, &walls, err);
    if (s == DR_OK) s = dr_render_bin_(&opaque, v.hs, BAND_PX * S, &bo, err);
    if (s == DR_OK) s = dr_render_bin_(&liquid, v.hs, BAND_PX * S, &bl, err);
    if (s == DR_OK) s = dr_render_bin_(&walls, v.hs, BAND_PX * S, &bw, err);
    if (s == DR_OK) {
        for (int j = 0; j < cam->height; j++) dr_render_background_linear_(&v.cf, j, bg + 3 * (size_t)j);
        Job job = {&v, &sc, &opaque, &liquid, &walls, &bo, &bl, &bw, bg, &srgb, scratch, workers, bo.nbands,
                   cam->width, cam->height, S, out};
        dr_render_run_(workers, desc->threads, worker, &job);
    }
    for (int w = 0; scratch && w < workers; w++) scratch_free(&scratch[w]);
    free(scratch);
    free(bg);
    free(opaque.t);
    free(liquid.t);
    free(walls.t);
    dr_render_bins_free_(&bo);
    dr_render_bins_free_(&bl);
    dr_render_bins_free_(&bw);
    dr_render_shadow_free_(&sc.sm);
    dr_render_contact_free_(&sc.cg);
    if (s != DR_OK) dr_image_free(out);
    return s;
}
