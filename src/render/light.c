/* The key light's shadow map and the ground's contact darkening. */
#include <float.h>
#include <stdlib.h>
#include <string.h>

#include "render/render_internal.h"

#define SHADOW_MARGIN 4  /* texels around the fitted region, so PCF taps at its edge stay on the map */
#define SHADOW_BAND 32   /* map rows per parallel band */
#define SHADOW_REACH 5.0 /* shadows end this many eye-target distances from the eye */

/* ---- shadow map ---------------------------------------------------------------------------------------- */

static void light_coords(const DrShadowMap *sm, DrVec3 p, double *tu, double *tv, double *d)
{
    *tu = (dr_v3_dot(p, sm->lx) - sm->u0) / sm->texel;
    *tv = (dr_v3_dot(p, sm->ly) - sm->v0) / sm->texel;
    *d = dr_v3_dot(p, sm->lz) - sm->d0;
}

static void box_corners(DrVec3 lo, DrVec3 hi, DrVec3 c[8])
{
    for (int k = 0; k < 8; k++) c[k] = dr_v3(k & 1 ? hi.x : lo.x, k & 2 ? hi.y : lo.y, k & 4 ? hi.z : lo.z);
}

/* Light-frame bounds (u, v) of the part of the view frustum between view depths z0 and z1. */
static void frustum_uv(const DrCamera *cam, const DrShadowMap *sm, double z0, double z1, double uv[4])
{
    DrCamFrame cf;
    dr_render_cam_frame_(cam, &cf);
    double ax = cf.cx / cf.focal, ay = cf.cy / cf.focal; /* half extents of the image at unit depth */
    uv[0] = uv[2] = DBL_MAX;
    uv[1] = uv[3] = -DBL_MAX;
    for (int k = 0; k < 8; k++) {
        double z = k & 4 ? z1 : z0, x = (k & 1 ? ax : -ax) * z, y = (k & 2 ? ay : -ay) * z;
        DrVec3 side = dr_v3_add(dr_v3_scale(cf.r, x), dr_v3_scale(cf.u, y));
        DrVec3 p = dr_v3_add(cf.eye, dr_v3_add(dr_v3_scale(cf.f, z), side));
        double u = dr_v3_dot(p, sm->lx), v = dr_v3_dot(p, sm->ly);
        uv[0] = fmin(uv[0], u), uv[1] = fmax(uv[1], u), uv[2] = fmin(uv[2], v), uv[3] = fmax(uv[3], v);
    }
}

/* Fits the light frame around what may receive a shadow in view: the casters, the liquid, and the casters'
 * shadow on the ground (the corners of the caster box pushed along the light onto the ground plane bound
 * it), cut to the view frustum over the depths those span, so a close-up gets the map's full resolution.
 * Returns false when none of it is in view. */
static bool fit(const DrRenderScene *scene, const DrCamera *cam, const DrRenderDesc *desc, DrVec3 clo, DrVec3 chi,
                int res, DrShadowMap *sm)
{
    DrVec3 lz = dr_v3_normalize(desc->light_dir);
    DrVec3 helper = fabs(lz.y) < 0.9 ? dr_v3(0, 1, 0) : dr_v3(1, 0, 0);
    sm->lz = lz;
    sm->lx = dr_v3_normalize(dr_v3_cross(helper, lz));
    sm->ly = dr_v3_cross(lz, sm->lx);
    DrVec3 pts[24], llo, lhi;
    int np = 0;
    box_corners(clo, chi, pts);
    np = 8;
    if (dr_render_bounds_of_(scene, true, &llo, &lhi)) {
        box_corners(llo, lhi, pts + np);
        np += 8;
    }
    double diag = dr_v3_norm(dr_v3_sub(chi, clo));
    if (desc->ground && lz.y < -1e-6)
        for (int k = 0; k < 8; k++) {
            /* a grazing light throws long shadows; beyond 4 caster diagonals they no longer matter */
            double t = fmin((desc->ground_height - pts[k].y) / lz.y, 4.0 * diag);
            if (t > 0.0) pts[np++] = dr_v3_add(pts[k], dr_v3_scale(lz, t));
        }
    double ulo = DBL_MAX, uhi = -DBL_MAX, vlo = DBL_MAX, vhi = -DBL_MAX, dlo = DBL_MAX;
    double zlo = DBL_MAX, zhi = -DBL_MAX;
    DrCamFrame cf;
    dr_render_cam_frame_(cam, &cf);
    for (int k = 0; k < np; k++) {
        double u = dr_v3_dot(pts[k], sm->lx), v = dr_v3_dot(pts[k], sm->ly), d = dr_v3_dot(pts[k], lz);
        ulo = fmin(ulo, u), uhi = fmax(uhi, u), vlo = fmin(vlo, v), vhi = fmax(vhi, v), dlo = fmin(dlo, d);
        double z = dr_v3_dot(dr_v3_sub(pts[k], cf.eye), cf.f);
        zlo = fmin(zlo, z), zhi = fmax(zhi, z);
    }
    if (zhi <= DR_CAMERA_NEAR) return false; /* all behind the camera */
    /* shadows reach SHADOW_REACH eye-target distances: a floor kilometres long would otherwise spread the
       map's texels over ground too far away to matter */
    zhi = fmin(zhi, SHADOW_REACH * dr_v3_norm(dr_v3_sub(cam->target, cam->eye)));
    if (zlo > zhi) return false;
    double fr[4];
    frustum_uv(cam, sm, fmax(zlo, DR_CAMERA_NEAR), zhi, fr);
    ulo = fmax(ulo, fr[0]), uhi = fmin(uhi, fr[1]), vlo = fmax(vlo, fr[2]), vhi = fmin(vhi, fr[3]);
    if (!(ulo <= uhi && vlo <= vhi)) return false;
    double extent = fmax(fmax(uhi - ulo, vhi - vlo), 1e-9);
    sm->texel = extent / (res - 2 * SHADOW_MARGIN - 1);
    sm->w = (int)ceil((uhi - ulo) / sm->texel) + 2 * SHADOW_MARGIN + 1;
    sm->h = (int)ceil((vhi - vlo) / sm->texel) + 2 * SHADOW_MARGIN + 1;
    sm->w = sm->w > res ? res : sm->w;
    sm->h = sm->h > res ? res : sm->h;
    sm->u0 = ulo - SHADOW_MARGIN * sm->texel;
    sm->v0 = vlo - SHADOW_MARGIN * sm->texel;
    sm->d0 = dlo;
    return true;
}

/* Emits the convex polygon (x, y, d)[0..n) (map coordinates in texels, depth), n <= 4, cut to a guard
 * rectangle of one map size around the map so that fixed-point corners stay small however far a caster
 * reaches past the fitted region. Depth is affine in (x, y) on an orthographic map, so interpolating it
 * along the cut edges is exact. */
static DrStatus emit_polygon(DrTriList *list, const DrShadowMap *sm, const double *x, const double *y,
                             const double *d, int n, DrError *err)
{
    double g = sm->w > sm->h ? sm->w : sm->h;
    double lim[4] = {-g, sm->w - 1 + g, -g, sm->h - 1 + g}; /* x >= lim[0], x <= lim[1], y >= ..., y <= ... */
    double buf[2][8][3];
    int m = n, cur = 0;
    for (int i = 0; i < n; i++) buf[0][i][0] = x[i], buf[0][i][1] = y[i], buf[0][i][2] = d[i];
    for (int k = 0; k < 4 && m > 0; k++) {
        int axis = k / 2, out = 0;
        double sign = k % 2 ? -1.0 : 1.0;
        double(*src)[3] = buf[cur], (*dst)[3] = buf[1 - cur];
        for (int i = 0; i < m; i++) {
            const double *p = src[i], *q = src[(i + 1) % m];
            double dp = sign * (p[axis] - lim[k]), dq = sign * (q[axis] - lim[k]);
            if (dp >= 0.0) memcpy(dst[out++], p, sizeof *dst);
            if ((dp >= 0.0) != (dq >= 0.0)) {
                double t = dp / (dp - dq);
                for (int c = 0; c < 3; c++) dst[out][c] = p[c] + t * (q[c] - p[c]);
                out++;
            }
        }
        m = out;
        cur = 1 - cur;
    }
    for (int i = 1; i + 1 < m; i++) {
        const double(*p)[3] = buf[cur];
        double tx[3] = {p[0][0], p[i][0], p[i + 1][0]}, ty[3] = {p[0][1], p[i][1], p[i + 1][1]};
        float td[3] = {(float)p[0][2], (float)p[i][2], (float)p[i + 1][2]};
        DR_TRY(dr_render_emit_(list, tx, ty, td, NULL, 0, sm->w, sm->h, err));
    }
    return DR_OK;
}

/* Emits a strand segment as a quad facing the light, at least one texel wide, of radius r0 at p0 and r1 at p1. */
static DrStatus emit_segment(DrTriList *list, const DrShadowMap *sm, DrVec3 p0, DrVec3 p1, double r0, double r1,
                             DrError *err)
{
    double u[2], v[2], d[2];
    light_coords(sm, p0, &u[0], &v[0], &d[0]);
    light_coords(sm, p1, &u[1], &v[1], &d[1]);
    double du = u[1] - u[0], dv = v[1] - v[0], len = sqrt(du * du + dv * dv);
    if (len < 1e-9) du = 1.0, dv = 0.0, len = 1.0;
    double tx[2], ty[2];
    for (int e = 0; e < 2; e++) {
        double hw = fmin(fmax(0.5, (e ? r1 : r0) / sm->texel), (double)(sm->w > sm->h ? sm->w : sm->h));
        tx[e] = du / len * hw, ty[e] = dv / len * hw;
    }
    /* each end's corners: along the segment by its half width (the cap) and across it (normal (-ty, tx)) */
    double qx[4] = {u[0] - tx[0] - ty[0], u[0] - tx[0] + ty[0], u[1] + tx[1] + ty[1], u[1] + tx[1] - ty[1]};
    double qy[4] = {v[0] - ty[0] + tx[0], v[0] - ty[0] - tx[0], v[1] + ty[1] - tx[1], v[1] + ty[1] + tx[1]};
    double qd[4] = {d[0], d[0], d[1], d[1]};
    return emit_polygon(list, sm, qx, qy, qd, 4, err);
}

static DrStatus emit_casters(const DrRenderScene *scene, const DrShadowMap *sm, DrTriList *list, DrError *err)
{
    for (int i = 0; i < scene->nmeshes; i++) {
        const DrRenderMesh *m = &scene->meshes[i];
        /* water lets light through (its own shadow would darken the floor seen through it twice); so, near
           enough, does a faint wall panel */
        if (m->mat == DR_MATERIAL_LIQUID || m->mat == DR_MATERIAL_WALL) continue;
        for (int t = 0; t < m->nt; t++) {
            double x[3], y[3], d[3];
            for (int k = 0; k < 3; k++) {
                const double *p = m->v + 3 * m->tri[3 * t + k];
                light_coords(sm, dr_v3(p[0], p[1], p[2]), &x[k], &y[k], &d[k]);
            }
            /* wholly off the map: nothing to cast here (the common case once the fit is cut to the view) */
            if ((x[0] < -1 && x[1] < -1 && x[2] < -1) || (y[0] < -1 && y[1] < -1 && y[2] < -1) ||
                (x[0] > sm->w && x[1] > sm->w && x[2] > sm->w) || (y[0] > sm->h && y[1] > sm->h && y[2] > sm->h))
                continue;
            DR_TRY(emit_polygon(list, sm, x, y, d, 3, err));
        }
    }
    for (int i = 0; i < scene->nstrands; i++) {
        const DrRenderStrands *st = &scene->strands[i];
        for (int s = 0; s < st->count; s++)
            for (int v = st->offsets[s]; v + 1 < st->offsets[s + 1]; v++) {
                const double *a = st->points + 3 * v, *b = a + 3;
                DR_TRY(emit_segment(list, sm, dr_v3(a[0], a[1], a[2]), dr_v3(b[0], b[1], b[2]), st->radius[v],
                                    st->radius[v + 1], err));
            }
    }
    return DR_OK;
}

typedef struct ShadowJob {
    DrShadowMap *sm;
    const DrTriList *list;
    const DrBins *bins;
} ShadowJob;

static void shadow_bands(long begin, long end, void *ctx)
{
    const ShadowJob *job = ctx;
    for (long b = begin; b < end; b++) {
        int row0 = (int)b * job->bins->band_rows;
        DrDepthBand band = {row0, job->bins->band_rows, job->sm->w, job->sm->depth + (size_t)row0 * job->sm->w,
                            NULL, NULL};
        if (row0 + band.rows > job->sm->h) band.rows = job->sm->h - row0;
        for (size_t k = job->bins->start[b]; k < job->bins->start[b + 1]; k++)
            dr_render_raster_depth_(&job->list->t[job->bins->idx[k]], &band);
    }
}

DrStatus dr_render_shadow_build_(const DrRenderScene *scene, const DrCamera *cam, const DrRenderDesc *desc, int res,
                                 DrShadowMap *sm, DrError *err)
{
    *sm = (DrShadowMap){0};
    DrVec3 clo, chi;
    if (!desc->shadows || !dr_render_bounds_of_(scene, false, &clo, &chi)) return DR_OK;
    if (!fit(scene, cam, desc, clo, chi, res, sm)) {
        *sm = (DrShadowMap){0};
        return DR_OK;
    }
    DrTriList list = {0};
    DrBins bins = {0};
    DrStatus s = dr_calloc((size_t)sm->w * (size_t)sm->h, sizeof *sm->depth, &sm->depth, err);
    if (s == DR_OK) {
        for (size_t k = 0; k < (size_t)sm->w * (size_t)sm->h; k++) sm->depth[k] = FLT_MAX;
        s = emit_casters(scene, sm, &list, err);
    }
    if (s == DR_OK) s = dr_render_bin_(&list, sm->h, SHADOW_BAND, &bins, err);
    if (s == DR_OK) {
        ShadowJob job = {sm, &list, &bins};
        dr_render_run_(bins.nbands, desc->threads, shadow_bands, &job);
        sm->on = true;
    }
    free(list.t);
    dr_render_bins_free_(&bins);
    if (s != DR_OK) dr_render_shadow_free_(sm);
    return s;
}

void dr_render_shadow_free_(DrShadowMap *sm)
{
    free(sm->depth);
    *sm = (DrShadowMap){0};
}

/* Percentage-closer filtering with a 2-texel box: each of the 3×3 texels around the lookup counts with its
 * overlap with the box, so the lit fraction varies smoothly across a shadow edge (about two texels wide).
 * Acne is kept away by a normal offset of one texel plus a slope-scaled depth bias: a surface at angle θ
 * to the light spans tan θ texel depths within one texel. */
double dr_render_shadow_(const DrShadowMap *sm, DrVec3 p, DrVec3 n, double ndl)
{
    if (!sm->on) return 1.0;
    double c = dr_maxd_(fabs(ndl), 0.05);
    double tan_theta = dr_mind_(sqrt(dr_maxd_(0.0, 1.0 - c * c)) / c, 8.0);
    p = dr_v3_add(p, dr_v3_scale(n, sm->texel * (ndl >= 0.0 ? 1.0 : -1.0)));
    double tu, tv, d;
    light_coords(sm, p, &tu, &tv, &d);
    if (!(tu > -1.0 && tv > -1.0 && tu < sm->w && tv < sm->h)) return 1.0; /* off the map: nothing casts */
    float dref = (float)(d - sm->texel * (1.0 + 1.5 * tan_theta));
    int iu = (int)floor(tu + 0.5), iv = (int)floor(tv + 0.5);
    double wu[3], wv[3];
    for (int k = -1; k <= 1; k++) {
        /* overlap of texel iu+k (extent ±0.5 around it) with the box [tu-1, tu+1], over the box width 2 */
        double lo = dr_maxd_(tu - 1.0, iu + k - 0.5), hi = dr_mind_(tu + 1.0, iu + k + 0.5);
        wu[k + 1] = dr_maxd_(0.0, hi - lo) * 0.5;
        lo = dr_maxd_(tv - 1.0, iv + k - 0.5), hi = dr_mind_(tv + 1.0, iv + k + 0.5);
        wv[k + 1] = dr_maxd_(0.0, hi - lo) * 0.5;
    }
    double lit = 0.0;
    for (int a = 0; a < 3; a++) {
        int y = iv + a - 1;
        for (int b = 0; b < 3; b++) {
            int x = iu + b - 1;
            bool open = x < 0 || y < 0 || x >= sm->w || y >= sm->h || dref <= sm->depth[(size_t)y * sm->w + x];
            if (open) lit += wu[b] * wv[a];
        }
    }
    return lit;
}

/* ---- contact darkening ---------------------------------------------------------------------------------- */

#define CONTACT_CELLS 128 /* along the longer side: fine enough for a soft darkening, cheap to blur */

static void contact_mark(DrContactGrid *cg, float *hmin, double x, double z, double h)
{
    int i = (int)floor((x - cg->x0) / cg->cell + 0.5), k = (int)floor((z - cg->z0) / cg->cell + 0.5);
    if (i < 0 || k < 0 || i >= cg->nx || k >= cg->nz) return;
    float *c = &hmin[(size_t)k * cg->nx + i];
    if (h < *c) *c = (float)h;
}

/* Lowest height over each cell: triangles are rasterised top-down at cell centres, and every corner marks
 * its own cell so triangles smaller than a cell are not lost. */
static void contact_heights(const DrRenderScene *scene, double ground_h, DrContactGrid *cg, float *hmin)
{
    for (int i = 0; i < scene->nmeshes; i++) {
        const DrRenderMesh *m = &scene->meshes[i];
        if (m->mat == DR_MATERIAL_LIQUID || m->mat == DR_MATERIAL_WALL) continue;
        for (int t = 0; t < m->nt; t++) {
            const double *p[3];
            for (int k = 0; k < 3; k++) p[k] = m->v + 3 * m->tri[3 * t + k];
            for (int k = 0; k < 3; k++) contact_mark(cg, hmin, p[k][0], p[k][2], p[k][1] - ground_h);
            double ax = p[1][0] - p[0][0], az = p[1][2] - p[0][2], bx = p[2][0] - p[0][0], bz = p[2][2] - p[0][2];
            double det = ax * bz - az * bx;
            if (fabs(det) < 1e-300) continue;
            double xlo = fmin(p[0][0], fmin(p[1][0], p[2][0])), xhi = fmax(p[0][0], fmax(p[1][0], p[2][0]));
            double zlo = fmin(p[0][2], fmin(p[1][2], p[2][2])), zhi = fmax(p[0][2], fmax(p[1][2], p[2][2]));
            int i0 = (int)ceil((xlo - cg->x0) / cg->cell), i1 = (int)floor((xhi - cg->x0) / cg->cell);
            int k0 = (int)ceil((zlo - cg->z0) / cg->cell), k1 = (int)floor((zhi - cg->z0) / cg->cell);
            for (int k = k0 > 0 ? k0 : 0; k <= k1 && k < cg->nz; k++)
                for (int j = i0 > 0 ? i0 : 0; j <= i1 && j < cg->nx; j++) {
                    double x = cg->x0 + j * cg->cell - p[0][0], z = cg->z0 + k * cg->cell - p[0][2];
                    double b1 = (x * bz - z * bx) / det, b2 = (ax * z - az * x) / det;
                    if (b1 < 0.0 || b2 < 0.0 || b1 + b2 > 1.0) continue;
                    double y = p[0][1] + b1 * (p[1][1] - p[0][1]) + b2 * (p[2][1] - p[0][1]);
                    contact_mark(cg, hmin, x + p[0][0], z + p[0][2], y - ground_h);
                }
        }
    }
}

/* One pass of a box blur of radius r along rows (stride 1) or columns (stride nx), from src into dst. */
static void box_blur(const float *src, float *dst, int nx, int nz, int r, bool along_x)
{
    int n = along_x ? nx : nz, lines = along_x ? nz : nx;
    size_t stride = along_x ? 1 : (size_t)nx, step = along_x ? (size_t)nx : 1;
    for (int l = 0; l < lines; l++) {
        const float *s = src + (size_t)l * step;
        float *d = dst + (size_t)l * step;
        for (int i = 0; i < n; i++) {
            double sum = 0.0;
            for (int k = i - r; k <= i + r; k++)
                if (k >= 0 && k < n) sum += s[(size_t)k * stride];
            d[(size_t)i * stride] = (float)(sum / (2 * r + 1));
        }
    }
}

DrStatus dr_render_contact_build_(const DrRenderScene *scene, double ground_h, double reach, DrContactGrid *cg,
                                  DrError *err)
{
    *cg = (DrContactGrid){0};
    DrVec3 lo, hi;
    if (!dr_render_bounds_of_(scene, false, &lo, &hi) || !(reach > 0.0)) return DR_OK;
    /* the darkening spreads about one reach beyond what touches the ground */
    double margin = 2.0 * reach;
    double sx = hi.x - lo.x + 2 * margin, sz = hi.z - lo.z + 2 * margin;
    cg->cell = fmax(sx, sz) / CONTACT_CELLS;
    cg->nx = (int)ceil(sx / cg->cell) + 1;
    cg->nz = (int)ceil(sz / cg->cell) + 1;
    cg->x0 = lo.x - margin;
    cg->z0 = lo.z - margin;
    size_t n = (size_t)cg->nx * (size_t)cg->nz;
    float *tmp = NULL;
    DR_TRY(dr_calloc(n, sizeof *cg->occ, &cg->occ, err));
    DrStatus s = dr_calloc(n, sizeof *tmp, &tmp, err);
    if (s != DR_OK) {
        dr_render_contact_free_(cg);
        return s;
    }
    for (size_t k = 0; k < n; k++) tmp[k] = FLT_MAX;
    contact_heights(scene, ground_h, cg, tmp);
    for (size_t k = 0; k < n; k++) cg->occ[k] = tmp[k] == FLT_MAX ? 0.0f : (float)exp(-fmax(tmp[k], 0.0) / reach);
    /* two box passes per axis approximate a Gaussian of about half a reach */
    int r = (int)fmax(1.0, floor(0.35 * reach / cg->cell + 0.5));
    for (int pass = 0; pass < 2; pass++) {
        box_blur(cg->occ, tmp, cg->nx, cg->nz, r, true);
        box_blur(tmp, cg->occ, cg->nx, cg->nz, r, false);
    }
    free(tmp);
    cg->on = true;
    return DR_OK;
}

double dr_render_contact_(const DrContactGrid *cg, double x, double z)
{
    if (!cg->on) return 0.0;
    double fx = (x - cg->x0) / cg->cell, fz = (z - cg->z0) / cg->cell;
    if (!(fx >= 0.0 && fz >= 0.0 && fx < cg->nx - 1 && fz < cg->nz - 1)) return 0.0;
    int i = (int)fx, k = (int)fz;
    double a = fx - i, b = fz - k;
    const float *o = cg->occ + (size_t)k * cg->nx + i;
    return (1 - b) * ((1 - a) * o[0] + a * o[1]) + b * ((1 - a) * o[cg->nx] + a * o[cg->nx + 1]);
}

void dr_render_contact_free_(DrContactGrid *cg)
{
    free(cg->occ);
    *cg = (DrContactGrid){0};
}
