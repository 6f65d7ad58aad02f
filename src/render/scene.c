/* The render scene: copies of the meshes and strands to draw, with their materials. */
#include <stdlib.h>
#include <string.h>

#include "render/render_internal.h"

DrStatus dr_render_scene_create(DrRenderScene **out, DrError *err)
{
    assert(out);
    *out = NULL;
    DrRenderScene *s = NULL;
    DR_TRY(dr_calloc(1, sizeof *s, &s, err));
    *out = s;
    return DR_OK;
}

void dr_render_scene_destroy(DrRenderScene **scene)
{
    if (!scene || !*scene) return;
    DrRenderScene *s = *scene;
    for (int i = 0; i < s->nmeshes; i++) {
        free(s->meshes[i].v);
        free(s->meshes[i].n);
        free(s->meshes[i].tri);
    }
    for (int i = 0; i < s->nstrands; i++) {
        free(s->strands[i].offsets);
        free(s->strands[i].points);
        free(s->strands[i].radius);
        free(s->strands[i].wet);
    }
    free(s->meshes);
    free(s->strands);
    free(s);
    *scene = NULL;
}

static bool material_valid(DrRenderMaterial mat)
{
    return mat == DR_MATERIAL_LIQUID || mat == DR_MATERIAL_COLLIDER || mat == DR_MATERIAL_SOLID ||
           mat == DR_MATERIAL_HAIR || mat == DR_MATERIAL_WALL;
}

/* Area-weighted vertex normals: the sum of the (unnormalised) cross products of the adjacent faces, whose
 * length is twice the face area, normalised at the end. */
static void compute_normals(const DrRenderMesh *m, double *n)
{
    memset(n, 0, 3 * (size_t)m->nv * sizeof *n);
    for (int t = 0; t < m->nt; t++) {
        const int *c = m->tri + 3 * t;
        DrVec3 p[3];
        for (int k = 0; k < 3; k++) p[k] = dr_v3(m->v[3 * c[k]], m->v[3 * c[k] + 1], m->v[3 * c[k] + 2]);
        DrVec3 fn = dr_v3_cross(dr_v3_sub(p[1], p[0]), dr_v3_sub(p[2], p[0]));
        for (int k = 0; k < 3; k++) {
            n[3 * c[k]] += fn.x;
            n[3 * c[k] + 1] += fn.y;
            n[3 * c[k] + 2] += fn.z;
        }
    }
    for (int i = 0; i < m->nv; i++) {
        DrVec3 v = dr_v3_normalize(dr_v3(n[3 * i], n[3 * i + 1], n[3 * i + 2]));
        n[3 * i] = v.x;
        n[3 * i + 1] = v.y;
        n[3 * i + 2] = v.z;
    }
}

DrStatus dr_render_scene_add_mesh(DrRenderScene *scene, const DrTriMesh *mesh, DrRenderMaterial mat, DrError *err)
{
    assert(scene && mesh && material_valid(mat));
    if (mesh->nv < 0 || mesh->nt < 0 || (mesh->nv > 0 && !mesh->v) || (mesh->nt > 0 && !mesh->tri))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "render mesh with %d vertices and %d triangles is malformed",
                            mesh->nv, mesh->nt);
    for (int i = 0; i < 3 * mesh->nv; i++)
        if (!isfinite(mesh->v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "render mesh vertex %d is not finite; the mesh cannot be drawn", i / 3);
    for (int i = 0; i < 3 * mesh->nt; i++)
        if (mesh->tri[i] < 0 || mesh->tri[i] >= mesh->nv)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "render mesh triangle %d refers to vertex %d of %d", i / 3, mesh->tri[i], mesh->nv);
    if (mesh->nt == 0) return DR_OK; /* nothing to draw */
    if (scene->nmeshes == scene->cap_meshes) {
        int cap = scene->cap_meshes ? 2 * scene->cap_meshes : 8;
        DR_TRY(dr_realloc((size_t)cap, sizeof *scene->meshes, &scene->meshes, err));
        scene->cap_meshes = cap;
    }
    DrRenderMesh m = {.nv = mesh->nv, .nt = mesh->nt, .mat = mat};
    DrStatus s = dr_calloc(3 * (size_t)m.nv, sizeof *m.v, &m.v, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)m.nv, sizeof *m.n, &m.n, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)m.nt, sizeof *m.tri, &m.tri, err);
    if (s != DR_OK) {
        free(m.v);
        free(m.n);
        free(m.tri);
        return s;
    }
    memcpy(m.v, mesh->v, 3 * (size_t)m.nv * sizeof *m.v);
    memcpy(m.tri, mesh->tri, 3 * (size_t)m.nt * sizeof *m.tri);
    if (mesh->n) {
        for (int i = 0; i < m.nv; i++) {
            DrVec3 v = dr_v3(mesh->n[3 * i], mesh->n[3 * i + 1], mesh->n[3 * i + 2]);
            v = dr_v3_isfinite(v) ? dr_v3_normalize(v) : dr_v3(0, 0, 0);
            m.n[3 * i] = v.x;
            m.n[3 * i + 1] = v.y;
            m.n[3 * i + 2] = v.z;
        }
    } else {
        compute_normals(&m, m.n);
    }
    m.lo = m.hi = dr_v3(m.v[3 * m.tri[0]], m.v[3 * m.tri[0] + 1], m.v[3 * m.tri[0] + 2]);
    for (int i = 0; i < 3 * m.nt; i++) {
        const double *p = m.v + 3 * m.tri[i];
        m.lo = dr_v3_min(m.lo, dr_v3(p[0], p[1], p[2]));
        m.hi = dr_v3_max(m.hi, dr_v3(p[0], p[1], p[2]));
    }
    scene->meshes[scene->nmeshes++] = m;
    return DR_OK;
}

/* The checks both polyline calls share: the material, the count, the offsets and the points. */
static DrStatus check_polylines(const double *points, const int *offsets, int count, const void *radius,
                                DrRenderMaterial mat, DrError *err)
{
    if (mat == DR_MATERIAL_LIQUID || mat == DR_MATERIAL_WALL)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "polylines cannot be drawn as liquid or wall panels; use a hair, solid or collider material");
    if (count < 0 || (count > 0 && (!offsets || !radius)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "polyline count %d is invalid", count);
    if (count == 0) return DR_OK;
    if (offsets[0] != 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "polyline offsets[0] is %d; it must be 0", offsets[0]);
    for (int s = 0; s < count; s++)
        if (offsets[s + 1] < offsets[s])
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "polyline offsets decrease at strand %d (%d then %d); they must not", s, offsets[s],
                                offsets[s + 1]);
    int nvert = offsets[count];
    if (nvert > 0 && !points) return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "polyline points are missing");
    for (int i = 0; i < 3 * nvert; i++)
        if (!isfinite(points[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "polyline vertex %d is not finite", i / 3);
    return DR_OK;
}

/* Copies checked polylines in: a radius per strand (strand_radius) or per vertex (vertex_radius), the wetness per
 * vertex or NULL. */
static DrStatus add_strands(DrRenderScene *scene, const double *points, const int *offsets, int count,
                            const double *strand_radius, const double *vertex_radius, const double *wetness,
                            DrRenderMaterial mat, DrError *err)
{
    if (count == 0) return DR_OK;
    int nvert = offsets[count];
    if (scene->nstrands == scene->cap_strands) {
        int cap = scene->cap_strands ? 2 * scene->cap_strands : 4;
        DR_TRY(dr_realloc((size_t)cap, sizeof *scene->strands, &scene->strands, err));
        scene->cap_strands = cap;
    }
    DrRenderStrands st = {.count = count, .mat = mat};
    DrStatus s = dr_calloc((size_t)count + 1, sizeof *st.offsets, &st.offsets, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)nvert + 1, sizeof *st.points, &st.points, err);
    if (s == DR_OK) s = dr_calloc((size_t)nvert + 1, sizeof *st.radius, &st.radius, err);
    if (s == DR_OK && wetness) s = dr_calloc((size_t)nvert + 1, sizeof *st.wet, &st.wet, err);
    if (s != DR_OK) {
        free(st.offsets);
        free(st.points);
        free(st.radius);
        free(st.wet);
        return s;
    }
    memcpy(st.offsets, offsets, ((size_t)count + 1) * sizeof *offsets);
    if (vertex_radius && nvert > 0) memcpy(st.radius, vertex_radius, (size_t)nvert * sizeof *st.radius);
    for (int k = 0; !vertex_radius && k < count; k++)
        for (int v = offsets[k]; v < offsets[k + 1]; v++) st.radius[v] = strand_radius[k];
    if (wetness && nvert > 0) memcpy(st.wet, wetness, (size_t)nvert * sizeof *st.wet);
    if (nvert > 0) memcpy(st.points, points, 3 * (size_t)nvert * sizeof *points);
    scene->strands[scene->nstrands++] = st;
    return DR_OK;
}

DrStatus dr_render_scene_add_polylines(DrRenderScene *scene, const double *points, const int *offsets, int count,
                                       const double *radius, DrRenderMaterial mat, DrError *err)
{
    assert(scene && material_valid(mat));
    DR_TRY(check_polylines(points, offsets, count, radius, mat, err));
    for (int s = 0; s < count; s++)
        if (!(radius[s] >= 0.0) || !isfinite(radius[s]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "polyline %d has radius %g; it must be a finite number >= 0", s, radius[s]);
    return add_strands(scene, points, offsets, count, radius, NULL, NULL, mat, err);
}

DrStatus dr_render_scene_add_wet_polylines(DrRenderScene *scene, const double *points, const int *offsets, int count,
                                           const double *radius, const double *wetness, DrRenderMaterial mat,
                                           DrError *err)
{
    assert(scene && material_valid(mat));
    DR_TRY(check_polylines(points, offsets, count, radius, mat, err));
    for (int s = 0; s < count; s++)
        for (int v = offsets[s]; v < offsets[s + 1]; v++) {
            if (!(radius[v] >= 0.0) || !isfinite(radius[v]))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "polyline %d has radius %g at its vertex %d; it must be a finite number >= 0", s,
                                    radius[v], v - offsets[s]);
            if (wetness && !(wetness[v] >= 0.0 && wetness[v] <= 1.0))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "polyline %d has wetness %g at its vertex %d; it must be in [0, 1]", s, wetness[v],
                                    v - offsets[s]);
        }
    return add_strands(scene, points, offsets, count, NULL, radius, wetness, mat, err);
}

static void grow(DrVec3 v, bool *any, DrVec3 *lo, DrVec3 *hi)
{
    *lo = *any ? dr_v3_min(*lo, v) : v;
    *hi = *any ? dr_v3_max(*hi, v) : v;
    *any = true;
}

bool dr_render_bounds_of_(const DrRenderScene *scene, bool liquid, DrVec3 *lo, DrVec3 *hi)
{
    bool any = false;
    for (int i = 0; i < scene->nmeshes; i++) {
        const DrRenderMesh *m = &scene->meshes[i];
        if ((m->mat == DR_MATERIAL_LIQUID) != liquid) continue;
        grow(m->lo, &any, lo, hi);
        grow(m->hi, &any, lo, hi);
    }
    for (int i = 0; i < scene->nstrands && !liquid; i++) {
        const DrRenderStrands *st = &scene->strands[i];
        /* a strand of one vertex draws nothing, so it does not count */
        for (int s = 0; s < st->count; s++)
            if (st->offsets[s + 1] - st->offsets[s] >= 2)
                for (int v = st->offsets[s]; v < st->offsets[s + 1]; v++) {
                    const double *p = st->points + 3 * v;
                    grow(dr_v3(p[0], p[1], p[2]), &any, lo, hi);
                }
    }
    return any;
}

bool dr_render_scene_bounds(const DrRenderScene *scene, DrVec3 *lo, DrVec3 *hi)
{
    assert(scene && lo && hi);
    DrVec3 lo1, hi1, lo2, hi2;
    bool a = dr_render_bounds_of_(scene, false, &lo1, &hi1), b = dr_render_bounds_of_(scene, true, &lo2, &hi2);
    if (a && b) {
        *lo = dr_v3_min(lo1, lo2);
        *hi = dr_v3_max(hi1, hi2);
    } else if (a || b) {
        *lo = a ? lo1 : lo2;
        *hi = a ? hi1 : hi2;
    }
    return a || b;
}
