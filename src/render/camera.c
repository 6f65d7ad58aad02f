/* The pinhole camera (checks, frame, projection), the sky gradient behind everything, and sRGB encoding. */
#include <float.h>

#include "render/render_internal.h"

#define MAX_SIDE 65535

static bool vec_finite_or_error(DrVec3 v, const char *name, DrError *err)
{
    if (dr_v3_isfinite(v)) return true;
    dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "camera %s (%g, %g, %g) is not finite; give three finite numbers",
                 name, v.x, v.y, v.z);
    return false;
}

DrStatus dr_camera_check(const DrCamera *cam, DrError *err)
{
    assert(cam);
    if (!vec_finite_or_error(cam->eye, "eye", err) || !vec_finite_or_error(cam->target, "target", err) ||
        !vec_finite_or_error(cam->up, "up", err))
        return DR_ERR_INPUT;
    DrVec3 view = dr_v3_sub(cam->target, cam->eye);
    double vn = dr_v3_norm(view), un = dr_v3_norm(cam->up);
    if (!(vn > 0.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "camera eye and target are the same point (%g, %g, %g); move the target in front of the "
                            "eye",
                            cam->eye.x, cam->eye.y, cam->eye.z);
    /* |sin| of the angle between up and the view direction; below 1e-9 the roll is undefined */
    if (!(un > 0.0) || dr_v3_norm(dr_v3_cross(view, cam->up)) <= 1e-9 * vn * un)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "camera up (%g, %g, %g) is zero or parallel to the view direction (eye to target); give an "
                            "up vector that is not",
                            cam->up.x, cam->up.y, cam->up.z);
    if (!(cam->fov_deg > 0.0 && cam->fov_deg < 180.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "camera fov_deg %g is outside (0, 180); give the vertical field of view in degrees",
                            cam->fov_deg);
    if (cam->width < 1 || cam->width > MAX_SIDE || cam->height < 1 || cam->height > MAX_SIDE)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "camera width x height %d x %d is invalid: the resolution must be 1 to %d pixels per side",
                            cam->width, cam->height, MAX_SIDE);
    return DR_OK;
}

void dr_render_cam_frame_(const DrCamera *cam, DrCamFrame *cf)
{
    cf->eye = cam->eye;
    cf->f = dr_v3_normalize(dr_v3_sub(cam->target, cam->eye));
    cf->r = dr_v3_normalize(dr_v3_cross(cf->f, cam->up));
    cf->u = dr_v3_cross(cf->r, cf->f);
    cf->focal = 0.5 * cam->height / tan(0.5 * cam->fov_deg * DR_PI / 180.0);
    cf->cx = 0.5 * cam->width;
    cf->cy = 0.5 * cam->height;
}

bool dr_camera_project(const DrCamera *cam, DrVec3 p, double *px, double *py, double *depth)
{
    DrCamFrame cf;
    dr_render_cam_frame_(cam, &cf);
    DrVec3 d = dr_v3_sub(p, cf.eye);
    double z = dr_v3_dot(d, cf.f);
    *depth = z;
    if (!(z > DR_CAMERA_NEAR)) return false;
    *px = cf.cx + cf.focal * dr_v3_dot(d, cf.r) / z;
    *py = cf.cy - cf.focal * dr_v3_dot(d, cf.u) / z;
    return true;
}

/* ---- sky --------------------------------------------------------------------------------------------- */

/* A soft overcast-to-blue gradient in elevation e = d.y: light blue-grey at the horizon, deeper blue
 * overhead, a dull grey below the horizon (seen only with the ground off, or in reflections). The
 * quadratic ease keeps the horizon band wide, as in a hazy sky. */
DrVec3 dr_render_sky_(DrVec3 d)
{
    static const DrVec3 horizon = {0.58, 0.64, 0.72}, zenith = {0.16, 0.27, 0.50}, nadir = {0.33, 0.35, 0.39};
    double e = fmax(-1.0, fmin(1.0, d.y));
    double t = e >= 0.0 ? 1.0 - (1.0 - e) * (1.0 - e) : 1.0 - (1.0 + e) * (1.0 + e);
    DrVec3 far = e >= 0.0 ? zenith : nadir;
    return dr_v3_add(dr_v3_scale(horizon, 1.0 - t), dr_v3_scale(far, t));
}

void dr_render_background_linear_(const DrCamFrame *cf, int row, float out[3])
{
    /* the ray through the centre column of the row: the gradient follows the camera's pitch and roll */
    double b = -((double)row + 0.5 - cf->cy) / cf->focal;
    DrVec3 d = dr_v3_normalize(dr_v3_add(cf->f, dr_v3_scale(cf->u, b)));
    DrVec3 c = dr_render_sky_(d);
    out[0] = (float)c.x;
    out[1] = (float)c.y;
    out[2] = (float)c.z;
}

static float srgb_threshold(int k);

void dr_render_background(const DrCamera *cam, int row, uint8_t rgb[3])
{
    DrCamFrame cf;
    dr_render_cam_frame_(cam, &cf);
    float c[3];
    dr_render_background_linear_(&cf, row, c);
    /* dr_render_encode_'s binary search, with only the 8 thresholds it visits computed */
    for (int ch = 0; ch < 3; ch++) {
        int k = 0;
        for (int step = 128; step > 0; step >>= 1)
            if (c[ch] >= srgb_threshold(k + step)) k += step;
        rgb[ch] = (uint8_t)k;
    }
}

/* ---- sRGB ---------------------------------------------------------------------------------------------- */

/* IEC 61966-2-1 decoding: code value c in [0, 1] to linear. */
static double srgb_to_linear(double c)
{
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

/* Linear value of sRGB code k - 1/2 (k = 1..255): the boundary between codes k - 1 and k. */
static float srgb_threshold(int k) { return (float)srgb_to_linear((k - 0.5) / 255.0); }

void dr_render_srgb_table_(DrSrgbTable *tab)
{
    tab->t[0] = -FLT_MAX;
    for (int k = 1; k < 256; k++) tab->t[k] = srgb_threshold(k);
}
