/* Grooms (PHYSICS §4 "Groom"): strands grown from a scalp mesh, or read from the polylines of an OBJ file;
 * and the default rod material.
 *
 * Growing. Roots are sampled uniformly by area: a triangle with probability proportional to its area (binary
 * search in the prefix sums of the areas, in triangle order), then a point uniform in it by the square-root
 * map of Turk (Graphics Gems I, 1990: b = (1 − √u₁, √u₁(1 − u₂), √u₁ u₂)). Each strand draws the same five
 * numbers in the same order (triangle, two barycentric, curl phase, length jitter) whatever the desc, so
 * the roots depend on the mesh, the count and the seed only. The direction is the area-weighted vertex
 * normal field (each vertex: the sum of its triangles' (b − a) × (c − a), i.e. twice area × unit normal)
 * interpolated barycentrically at the root; the triangle's own normal where that field vanishes. On a mesh
 * inscribed in a sphere whose vertex normals are radial, the interpolated normal is exactly the root's
 * radial direction (the root is the same barycentric mix of the vertices).
 *
 * Reading. The file is parsed and checked by dr_io_read_polylines_obj (io owns file formats); a groom adds
 * the root normals. */
#include "hair/hair.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

#include "io/io.h"

void dr_groom_free(DrGroom *g)
{
    if (!g) return;
    free(g->offsets);
    free(g->x);
    free(g->root_normal);
    memset(g, 0, sizeof *g);
}

void dr_groom_desc_default(DrGroomDesc *d)
{
    *d = (DrGroomDesc){.count = 100,
                       .length = 0.05,
                       .segments = 12,
                       .curl_radius = 0.0,
                       .curl_pitch = 0.01,
                       .length_jitter = 0.0,
                       .seed = 1};
}

/* Human scalp hair: radius 50 µm (diameters 50–120 µm); keratin fibre density 1300 kg/m³; Young's modulus
 * 3.9 GPa (tensile tests of wet to dry hair span about 2–6 GPa); G = E / (2(1 + ν)) with ν = 0.5. */
void dr_rod_material_default(DrRodMaterial *m)
{
    *m = (DrRodMaterial){.radius = 5e-5, .density = 1300.0, .youngs = 3.9e9, .shear = 1.3e9, .damping = 0.0};
}

static DrVec3 vec_at(const double *a, int i) { return dr_v3(a[3 * i], a[3 * i + 1], a[3 * i + 2]); }

static void vec_put(double *a, int i, DrVec3 v)
{
    a[3 * i] = v.x;
    a[3 * i + 1] = v.y;
    a[3 * i + 2] = v.z;
}

/* An orthonormal vector perpendicular to unit n, continuous except across n.z = 0 (Duff et al. 2017,
 * "Building an orthonormal basis, revisited", JCGT 6(1)). */
static DrVec3 perpendicular(DrVec3 n)
{
    double sign = n.z >= 0.0 ? 1.0 : -1.0;
    double a = -1.0 / (sign + n.z), b = n.x * n.y * a;
    return dr_v3(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
}

/* ---- growing --------------------------------------------------------------------------------------------- */

static DrStatus check_desc(const DrGroomDesc *d, DrError *err)
{
    if (d->count < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom: count = %d; grow at least one strand", d->count);
    if (d->segments < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom: segments = %d; a strand needs at least one edge",
                            d->segments);
    if (!(d->length > 0.0) || !isfinite(d->length))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: length = %g m; give a positive strand length such as 0.05", d->length);
    if (!(d->curl_radius >= 0.0) || !isfinite(d->curl_radius))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: curl_radius = %g m; give 0 (straight) or a positive helix radius", d->curl_radius);
    if (d->curl_radius > 0.0 && (!(d->curl_pitch > 0.0) || !isfinite(d->curl_pitch)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: curl_pitch = %g m with curl_radius > 0; give a positive rise per turn such as 0.01",
                            d->curl_pitch);
    if (!(d->length_jitter >= 0.0 && d->length_jitter < 1.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom: length_jitter = %g; give a fraction in [0, 1)",
                            d->length_jitter);
    if ((long long)d->count * ((long long)d->segments + 1) > INT_MAX)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: %d strands of %d segments make more than %d vertices; reduce count or segments",
                            d->count, d->segments, INT_MAX);
    return DR_OK;
}

/* Twice-area normals summed into each vertex, then normalised; (0,0,0) where they cancel to rounding (a
 * double-sided sheet), so that a vanishing sum is never blown up into an arbitrary direction. */
static void vertex_normals(const DrTriMesh *m, double *vn, double *weight)
{
    for (int t = 0; t < m->nt; t++) {
        const int *tri = &m->tri[3 * t];
        DrVec3 a = vec_at(m->v, tri[0]), b = vec_at(m->v, tri[1]), c = vec_at(m->v, tri[2]);
        DrVec3 n2 = dr_v3_cross(dr_v3_sub(b, a), dr_v3_sub(c, a));
        double w = dr_v3_norm(n2);
        for (int k = 0; k < 3; k++) {
            vec_put(vn, tri[k], dr_v3_add(vec_at(vn, tri[k]), n2));
            weight[tri[k]] += w;
        }
    }
    for (int i = 0; i < m->nv; i++) {
        DrVec3 n = vec_at(vn, i);
        double len = dr_v3_norm(n);
        vec_put(vn, i, len > 1e-12 * weight[i] ? dr_v3_scale(n, 1.0 / len) : dr_v3(0, 0, 0));
    }
}

/* First triangle whose prefix area exceeds `target`, skipping zero-area ones (equal prefix sums). */
static int pick_triangle(const double *cdf, int nt, double target)
{
    int lo = 0, hi = nt - 1;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (cdf[mid] > target) hi = mid;
        else lo = mid + 1;
    }
    /* target rounds to the total only when u₀ → 1; then take the last triangle with area */
    while (lo > 0 && cdf[lo] == cdf[lo - 1]) lo--;
    return lo;
}

DrStatus dr_groom_grow(const DrTriMesh *scalp, const DrGroomDesc *desc, DrGroom *out, DrError *err)
{
    assert(scalp && desc && out);
    memset(out, 0, sizeof *out);
    DR_TRY(check_desc(desc, err));
    if (scalp->nt < 1 || scalp->nv < 3)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: the scalp mesh has no triangles (%d vertices, %d triangles); give a triangle mesh "
                            "to grow strands from",
                            scalp->nv, scalp->nt);
    for (int i = 0; i < 3 * scalp->nt; i++) assert(scalp->tri[i] >= 0 && scalp->tri[i] < scalp->nv);
    for (int i = 0; i < 3 * scalp->nv; i++)
        if (!isfinite(scalp->v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "groom: scalp vertex %d has a non-finite coordinate; fix the mesh", i / 3);

    const int S = desc->count, nvs = desc->segments + 1, V = S * nvs;
    double *cdf = NULL, *vn = NULL, *weight = NULL;
    DrStatus st = dr_calloc((size_t)scalp->nt, sizeof(double), &cdf, err);
    if (st == DR_OK) st = dr_calloc((size_t)scalp->nv * 3, sizeof(double), &vn, err);
    if (st == DR_OK) st = dr_calloc((size_t)scalp->nv, sizeof(double), &weight, err);
    if (st == DR_OK) st = dr_calloc((size_t)S + 1, sizeof(int), &out->offsets, err);
    if (st == DR_OK) st = dr_calloc((size_t)V * 3, sizeof(double), &out->x, err);
    if (st == DR_OK) st = dr_calloc((size_t)S * 3, sizeof(double), &out->root_normal, err);
    if (st != DR_OK) goto done;

    /* 1. areas and their prefix sums (triangle order: the same sums on every run) */
    double total = 0.0;
    for (int t = 0; t < scalp->nt; t++) {
        const int *tri = &scalp->tri[3 * t];
        DrVec3 a = vec_at(scalp->v, tri[0]), b = vec_at(scalp->v, tri[1]), c = vec_at(scalp->v, tri[2]);
        total += 0.5 * dr_v3_norm(dr_v3_cross(dr_v3_sub(b, a), dr_v3_sub(c, a)));
        cdf[t] = total;
    }
    if (!(total > 0.0) || !isfinite(total)) {
        st = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                          "groom: the scalp mesh has no area (%d triangles, all degenerate); give a mesh with surface "
                          "to grow strands from",
                          scalp->nt);
        goto done;
    }
    vertex_normals(scalp, vn, weight);

    /* 2. one strand at a time: root, direction, then its vertices along a line or a helix */
    DrRng rng;
    dr_rng_seed(&rng, desc->seed);
    const double r = desc->curl_radius, pitch = desc->curl_pitch;
    const double turn = sqrt((2.0 * DR_PI * r) * (2.0 * DR_PI * r) + pitch * pitch); /* arc length per turn */
    for (int s = 0; s < S; s++) {
        double u[5];
        for (int k = 0; k < 5; k++) u[k] = dr_rng_uniform(&rng);
        int t = pick_triangle(cdf, scalp->nt, u[0] * total);
        const int *tri = &scalp->tri[3 * t];
        double r1 = sqrt(u[1]);
        double b[3] = {1.0 - r1, r1 * (1.0 - u[2]), r1 * u[2]};
        DrVec3 root = dr_v3(0, 0, 0), n = dr_v3(0, 0, 0);
        for (int k = 0; k < 3; k++) {
            root = dr_v3_add(root, dr_v3_scale(vec_at(scalp->v, tri[k]), b[k]));
            n = dr_v3_add(n, dr_v3_scale(vec_at(vn, tri[k]), b[k]));
        }
        /* the interpolated field vanishes only between opposed vertex normals: use the face's own */
        if (!(dr_v3_norm(n) > 1e-6)) {
            DrVec3 a = vec_at(scalp->v, tri[0]), bb = vec_at(scalp->v, tri[1]), c = vec_at(scalp->v, tri[2]);
            n = dr_v3_cross(dr_v3_sub(bb, a), dr_v3_sub(c, a));
        }
        n = dr_v3_normalize(n);
        vec_put(out->root_normal, s, n);

        double len = desc->length * (1.0 + desc->length_jitter * (2.0 * u[4] - 1.0));
        double psi = 2.0 * DR_PI * u[3];
        DrVec3 p = perpendicular(n), q = dr_v3_cross(n, p);
        DrVec3 e1 = dr_v3_add(dr_v3_scale(p, cos(psi)), dr_v3_scale(q, sin(psi))), e2 = dr_v3_cross(n, e1);
        out->offsets[s] = s * nvs;
        for (int k = 0; k < nvs; k++) {
            double arc = len * (double)k / (double)desc->segments;
            DrVec3 d;
            if (r > 0.0) {
                /* right-handed helix about an axis parallel to n through root − r e1: angle φ and rise h after
                   arc length s are φ = 2π s / turn, h = pitch s / turn */
                double phi = 2.0 * DR_PI * arc / turn, h = pitch * arc / turn;
                d = dr_v3_add(dr_v3_add(dr_v3_scale(e1, r * (cos(phi) - 1.0)), dr_v3_scale(e2, r * sin(phi))),
                              dr_v3_scale(n, h));
            } else {
                d = dr_v3_scale(n, arc);
            }
            vec_put(out->x, s * nvs + k, dr_v3_add(root, d));
        }
    }
    out->offsets[S] = V;
    out->nstrands = S;

done:
    free(cdf);
    free(vn);
    free(weight);
    if (st != DR_OK) dr_groom_free(out);
    return st;
}

/* ---- reading OBJ polylines ------------------------------------------------------------------------------ */

DrStatus dr_groom_read_obj(const char *path, DrGroom *out, DrError *err)
{
    assert(path && out);
    memset(out, 0, sizeof *out);
    DrPolylinesReadDesc desc;
    dr_io_polylines_read_desc_default(&desc);
    desc.require_radius = false; /* a groom has no radius: the rod material gives it */
    desc.require_strands = true;
    desc.reject_zero_edges = true; /* the first edge gives the root normal; rods need lengths > 0 */
    DrPolylines p;
    DR_TRY(dr_io_read_polylines_obj(path, &desc, &p, err));
    DrStatus st = dr_calloc((size_t)p.count * 3, sizeof(double), &out->root_normal, err);
    if (st == DR_OK) {
        for (int s = 0; s < p.count; s++) {
            int o = p.offsets[s];
            vec_put(out->root_normal, s, dr_v3_normalize(dr_v3_sub(vec_at(p.x, o + 1), vec_at(p.x, o))));
        }
        /* the strands are the polylines: take over their arrays */
        out->nstrands = p.count;
        out->offsets = p.offsets;
        out->x = p.x;
        p.offsets = NULL;
        p.x = NULL;
    }
    dr_io_polylines_free(&p);
    return st;
}
