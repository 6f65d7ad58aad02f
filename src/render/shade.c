/* Shading of one supersample: matte surfaces, strands, the ground and the liquid, in linear RGB.
 *
 * Lighting: one directional key light (Lambert, shadowed by the shadow map) plus a hemispheric fill that
 * blends a sky colour and a ground bounce by the normal's elevation; geometry near the ground is darkened
 * by its height above it and the ground by the contact grid (a cheap stand-in for ambient occlusion). */
#include "render/render_internal.h"

/* Albedos (linear): grey-blue colliders, warm solids, dark brown hair. */
static DrVec3 albedo_of(int mat)
{
    switch (mat) {
    case DR_MATERIAL_COLLIDER: return dr_v3(0.20, 0.25, 0.32);
    case DR_MATERIAL_SOLID: return dr_v3(0.60, 0.40, 0.25);
    case DR_MATERIAL_HAIR: return dr_v3(0.10, 0.055, 0.03);
    default: return dr_v3(0.5, 0.5, 0.5);
    }
}

/* Hair under a film of water is darker (Lekner & Dorf 1988, "Why some things are darker when wet", Appl. Opt. 27,
 * 1278): light that enters the film (a fraction 1 − R_e) and is scattered back by the fibre (albedo a) meets the
 * water-air interface from below, which sends p = 1 − (1 − R_e)/n² of it back down (total internal reflection
 * beyond the critical angle), where the fibre absorbs another share; summing the bounces,
 *     a_wet = a (1 − R_e)² / (n² (1 − p a)),
 * per channel, with n = 1.333 and R_e = 0.066 (water's mean reflectance for diffuse light). Dark hair keeps about
 * half its albedo (a = 0.1 → 0.052), so a wet strand reads darker whatever its colour. The film's own glint off
 * its surface is left to the strands' highlight. `wet` in [0, 1] blends the dry albedo (0) into a_wet (1). */
static DrVec3 wet_albedo(DrVec3 a, double wet)
{
    const double n2 = 1.333 * 1.333, Re = 0.066, p = 1.0 - (1.0 - Re) / n2;
    double c[3] = {a.x, a.y, a.z};
    for (int k = 0; k < 3; k++) c[k] *= 1.0 - wet + wet * (1.0 - Re) * (1.0 - Re) / (n2 * (1.0 - p * c[k]));
    return dr_v3(c[0], c[1], c[2]);
}

static DrVec3 hemi(const DrShadeCtx *sc, double ny)
{
    double t = 0.5 + 0.5 * ny;
    return dr_v3_add(dr_v3_scale(sc->sky_fill, t), dr_v3_scale(sc->ground_fill, 1.0 - t));
}

/* Darkening of geometry near the ground: full strength at contact, gone a few reaches above. */
static double height_ao(const DrShadeCtx *sc, double y)
{
    if (!sc->ground) return 1.0;
    return 1.0 - 0.35 * exp(-dr_maxd_(y - sc->ground_h, 0.0) / sc->contact_reach);
}

double dr_render_ground_t_(const DrShadeCtx *sc, DrVec3 dir)
{
    double h = sc->cf.eye.y - sc->ground_h;
    if (!(h > 0.0) || !(dir.y < 0.0)) return 0.0;
    double t = -h / dir.y;
    return t > DR_CAMERA_NEAR && isfinite(t) ? t : 0.0;
}

/* Box-filtered checker (the analytic integral of the square wave over a filter of width w, per axis, in
 * cell units): 0 or 1 on the cells, tending to 1/2 where a cell is small against the filter, so the ground
 * neither aliases nor shimmers at a distance. */
static double square_wave_integral(double x) /* ∫ of the ±1 square wave of period 2, up to a constant */
{
    double h = 0.5 * x;
    return 2.0 * fabs(h - floor(h) - 0.5);
}

static double filtered_checker(double x, double z, double w)
{
    double hw = 0.5 * w;
    double ix = (square_wave_integral(x - hw) - square_wave_integral(x + hw)) / w;
    double iz = (square_wave_integral(z - hw) - square_wave_integral(z + hw)) / w;
    return 0.5 - 0.5 * ix * iz;
}

static DrVec3 shade_ground(const DrShadeCtx *sc, DrVec3 dir, double filter)
{
    double t = dr_render_ground_t_(sc, dir);
    DrVec3 p = dr_v3_add(sc->cf.eye, dr_v3_scale(dir, t));
    double len = dr_v3_norm(dir), dist = t * len;
    /* the filter's footprint on the ground: dist / focal per sample, stretched by the grazing angle */
    double footprint = filter * dist / sc->fs / dr_maxd_(-dir.y / len, 0.02);
    double w = dr_maxd_(footprint / sc->ground_cell, 1e-4);
    double chk = filtered_checker(p.x / sc->ground_cell, p.z / sc->ground_cell, w);
    DrVec3 albedo = dr_v3_scale(dr_v3(0.25, 0.24, 0.22), 1.0 + 0.07 * (2.0 * chk - 1.0));
    double ndl = sc->to_light.y;
    double sh = ndl > 0.0 ? dr_render_shadow_(&sc->sm, p, dr_v3(0, 1, 0), ndl) : 0.0;
    double ao = 1.0 - 0.6 * dr_render_contact_(&sc->cg, p.x, p.z);
    DrVec3 light = dr_v3_add(dr_v3_scale(sc->sun, dr_maxd_(ndl, 0.0) * sh), dr_v3_scale(sc->sky_fill, ao));
    DrVec3 c = dr_v3_mul(albedo, light);
    /* aerial perspective: the ground fades into the horizon colour, which the sky has at elevation 0 */
    double fog = 1.0 - exp(-dist / sc->fog_dist);
    return dr_v3_add(dr_v3_scale(c, 1.0 - fog), dr_v3_scale(sc->horizon, fog));
}

DrVec3 dr_render_shade_opaque_(const DrShadeCtx *sc, DrVec3 dir, uint8_t code, float iz, const float nrm[3],
                               double filter)
{
    if (code == DR_SHADE_GROUND) return shade_ground(sc, dir, filter);
    DrVec3 p = dr_v3_add(sc->cf.eye, dr_v3_scale(dir, 1.0 / iz));
    DrVec3 v = dr_v3_scale(dir, -1.0 / dr_v3_norm(dir)); /* towards the eye */
    DrVec3 a = dr_v3_normalize(dr_v3(nrm[0], nrm[1], nrm[2]));
    double ao = height_ao(sc, p.y);
    if (code & DR_SHADE_STRAND) {
        /* Kajiya–Kay: a strand of tangent T scatters diffusely by sin(T, L) and has its highlight on the
           cone around T, strongest where sin(T, H) is 1 */
        DrVec3 albedo = albedo_of(code & ~DR_SHADE_STRAND);
        /* the wetness: the tangent's length over 1/depth is 1 + wet (render.c); below 1e-4 it is the floats'
           rounding (a few 1e-7) of a dry strand, which stays exactly as it was drawn before */
        double wet = dr_v3_norm(dr_v3(nrm[0], nrm[1], nrm[2])) / iz - 1.0;
        if (wet > 1e-4) albedo = wet_albedo(albedo, dr_mind_(wet, 1.0));
        double tl = dr_v3_dot(a, sc->to_light);
        double diff = sqrt(dr_maxd_(0.0, 1.0 - tl * tl));
        DrVec3 h = dr_v3_normalize(dr_v3_add(sc->to_light, v));
        double th = dr_v3_dot(a, h);
        double spec = pow(sqrt(dr_maxd_(0.0, 1.0 - th * th)), 80.0);
        double sh = dr_render_shadow_(&sc->sm, p, sc->to_light, 1.0);
        DrVec3 c = dr_v3_mul(albedo, dr_v3_add(dr_v3_scale(sc->sun, 0.8 * diff * sh), dr_v3_scale(hemi(sc, 0.3), ao)));
        return dr_v3_add(c, dr_v3_scale(dr_v3_mul(sc->sun, dr_v3(0.9, 0.8, 0.7)), 0.10 * spec * sh));
    }
    if (dr_v3_dot(a, a) == 0.0) a = v; /* no normal (degenerate interpolation): face the eye */
    DrVec3 albedo = albedo_of(code - DR_SHADE_MESH);
    double ndl = dr_v3_dot(a, sc->to_light);
    double sh = ndl > 0.0 ? dr_render_shadow_(&sc->sm, p, a, ndl) : 0.0;
    return dr_v3_mul(albedo, dr_v3_add(dr_v3_scale(sc->sun, dr_maxd_(ndl, 0.0) * sh), dr_v3_scale(hemi(sc, a.y), ao)));
}

static double schlick(double f0, double cos_theta)
{
    double m = 1.0 - dr_mind_(1.0, dr_maxd_(0.0, cos_theta));
    return f0 + (1.0 - f0) * m * m * m * m * m;
}

DrVec3 dr_render_shade_liquid_(const DrShadeCtx *sc, DrVec3 dir, DrVec3 behind, float near_iz, const float nrm[3],
                               float far_iz, float opaque_iz)
{
    double len = dr_v3_norm(dir), zn = 1.0 / near_iz;
    DrVec3 p = dr_v3_add(sc->cf.eye, dr_v3_scale(dir, zn));
    /* 1. Beer–Lambert through the thickness between the nearest and farthest liquid surfaces (view depths
          scaled by the ray length per unit depth); with one surface only (an open sheet, or the far side
          hidden), up to what lies behind, clamped */
    double thick;
    if (far_iz < near_iz)
        thick = (1.0 / far_iz - zn) * len;
    else
        thick = dr_mind_(opaque_iz > 0.0f ? (1.0 / opaque_iz - zn) * len : sc->thickness_clamp, sc->thickness_clamp);
    thick = dr_maxd_(thick, 0.0);
    DrVec3 v = dr_v3_scale(dir, -1.0 / len);
    DrVec3 n = dr_v3_normalize(dr_v3(nrm[0], nrm[1], nrm[2]));
    if (dr_v3_dot(n, n) == 0.0) n = v;
    double cv = dr_v3_dot(n, v);
    if (cv < 0.0) n = dr_v3_scale(n, -1.0), cv = -cv; /* seen from inside the water */
    double ndl = dr_v3_dot(n, sc->to_light);
    double sh = ndl > 0.0 ? dr_render_shadow_(&sc->sm, p, n, ndl) : 0.0;
    double lit = 0.55 + 0.45 * dr_maxd_(ndl, 0.0) * sh;
    double tr[3] = {exp(-sc->sigma.x * thick), exp(-sc->sigma.y * thick), exp(-sc->sigma.z * thick)};
    DrVec3 c = dr_v3(behind.x * tr[0] + sc->water_scatter.x * lit * (1.0 - tr[0]),
                     behind.y * tr[1] + sc->water_scatter.y * lit * (1.0 - tr[1]),
                     behind.z * tr[2] + sc->water_scatter.z * lit * (1.0 - tr[2]));
    /* 2. Fresnel (Schlick, F0 = 0.02 for water) reflection of the sky along the mirror direction */
    double f = schlick(0.02, cv);
    DrVec3 r = dr_v3_sub(dr_v3_scale(n, 2.0 * cv), v);
    c = dr_v3_add(dr_v3_scale(c, 1.0 - f), dr_v3_scale(dr_render_sky_(r), f));
    /* 3. the key light's highlight: normalised Blinn–Phong lobe, (p + 8) / (8π) cos^p, times Fresnel at H */
    if (ndl > 0.0 && sh > 0.0) {
        DrVec3 h = dr_v3_normalize(dr_v3_add(sc->to_light, v));
        double ndh = dr_maxd_(dr_v3_dot(n, h), 0.0), power = 200.0;
        double lobe = (power + 8.0) / (8.0 * DR_PI) * pow(ndh, power);
        c = dr_v3_add(c, dr_v3_scale(sc->sun, lobe * schlick(0.02, dr_v3_dot(h, v)) * sh * ndl));
    }
    return c;
}
