/* What the render stage draws from the scene alone (contract in from_scene.h): domain walls, the shot's fixed
 * sizes, the camera, and the preview of the scene's initial state. */
#include "from_scene.h"

#include <stdlib.h>
#include <string.h>

#include "grid/grid.h"
#include "hair/hair.h"
#include "io/io.h"

DrStatus scene_box_mesh(DrVec3 lo, DrVec3 hi, bool top, DrTriMesh *out, DrError *err)
{
    /* corners: bit 0 x, bit 1 y, bit 2 z; faces wound counter-clockwise seen from outside, the top (y = hi) last */
    static const int tri[36] = {0, 4, 6, 0, 6, 2, /* x = lo */ 1, 3, 7, 1, 7, 5, /* x = hi */
                                0, 1, 5, 0, 5, 4, /* y = lo */ 0, 2, 3, 0, 3, 1, /* z = lo */
                                4, 5, 7, 4, 7, 6, /* z = hi */ 2, 6, 7, 2, 7, 3 /* y = hi */};
    *out = (DrTriMesh){0};
    int nt = top ? 12 : 10;
    DR_TRY(dr_calloc(24, sizeof *out->v, &out->v, err));
    DrStatus s = dr_calloc((size_t)nt * 3, sizeof *out->tri, &out->tri, err);
    if (s != DR_OK) {
        dr_trimesh_free(out);
        return s;
    }
    for (int c = 0; c < 8; c++) {
        out->v[3 * c] = c & 1 ? hi.x : lo.x;
        out->v[3 * c + 1] = c & 2 ? hi.y : lo.y;
        out->v[3 * c + 2] = c & 4 ? hi.z : lo.z;
    }
    memcpy(out->tri, tri, (size_t)nt * 3 * sizeof *out->tri);
    out->nv = 8;
    out->nt = nt;
    return DR_OK;
}

/* A sphere of `radius` about `centre` as a closed UV sphere (24 segments around, 12 from pole to pole). */
static DrStatus sphere_mesh(DrVec3 centre, double radius, DrTriMesh *out, DrError *err)
{
    enum { AROUND = 24, RINGS = 12 };
    *out = (DrTriMesh){0};
    int nv = 2 + AROUND * (RINGS - 1), nt = 2 * AROUND * (RINGS - 1);
    DR_TRY(dr_calloc(3 * (size_t)nv, sizeof *out->v, &out->v, err));
    DrStatus s = dr_calloc(3 * (size_t)nt, sizeof *out->tri, &out->tri, err);
    if (s != DR_OK) {
        dr_trimesh_free(out);
        return s;
    }
    double *v = out->v;
    int *t = out->tri, k = 0;
    v[0] = centre.x, v[1] = centre.y + radius, v[2] = centre.z; /* north pole, vertex 0 */
    for (int r = 1; r < RINGS; r++)
        for (int a = 0; a < AROUND; a++) {
            double th = DR_PI * r / RINGS, ph = 2.0 * DR_PI * a / AROUND;
            double *p = v + 3 * (1 + (r - 1) * AROUND + a);
            p[0] = centre.x + radius * sin(th) * cos(ph);
            p[1] = centre.y + radius * cos(th);
            p[2] = centre.z - radius * sin(th) * sin(ph);
        }
    int south = nv - 1;
    v[3 * south] = centre.x, v[3 * south + 1] = centre.y - radius, v[3 * south + 2] = centre.z;
    for (int a = 0; a < AROUND; a++) {
        int b = (a + 1) % AROUND;
        t[k++] = 0, t[k++] = 1 + a, t[k++] = 1 + b;
        for (int r = 1; r + 1 < RINGS; r++) {
            int p0 = 1 + (r - 1) * AROUND, p1 = 1 + r * AROUND;
            t[k++] = p0 + a, t[k++] = p1 + a, t[k++] = p1 + b;
            t[k++] = p0 + a, t[k++] = p1 + b, t[k++] = p0 + b;
        }
        int last = 1 + (RINGS - 2) * AROUND;
        t[k++] = south, t[k++] = last + b, t[k++] = last + a;
    }
    out->nv = nv;
    out->nt = nt;
    return DR_OK;
}

static bool has_domain(const DrElement *e) { return e->kind == DR_ELEMENT_LIQUID || e->kind == DR_ELEMENT_MPM_SOLID; }

DrStatus scene_add_domain_walls(const DrScene *scene, DrRenderScene *rs, DrError *err)
{
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (!has_domain(e)) continue;
        DrVec3 lo, hi;
        dr_component_box(dr_element_component(e, "Domain"), "box", &lo, &hi);
        DrTriMesh box;
        DR_TRY(scene_box_mesh(lo, hi, false, &box, err));
        DrStatus s = dr_render_scene_add_mesh(rs, &box, DR_MATERIAL_WALL, err);
        dr_trimesh_free(&box);
        DR_TRY(s);
    }
    return DR_OK;
}

static void grow_box(DrVec3 lo, DrVec3 hi, bool *any, DrVec3 *blo, DrVec3 *bhi)
{
    *blo = *any ? dr_v3_min(*blo, lo) : lo;
    *bhi = *any ? dr_v3_max(*bhi, hi) : hi;
    *any = true;
}

static double max_side(DrVec3 lo, DrVec3 hi) { return fmax(hi.x - lo.x, fmax(hi.y - lo.y, hi.z - lo.z)); }

void scene_render_sizes(const DrScene *scene, const DrTriMesh *still, int n, DrRenderDesc *desc)
{
    bool any = false, any_liquid = false;
    DrVec3 lo = {0, 0, 0}, hi = {0, 0, 0}, llo = {0, 0, 0}, lhi = {0, 0, 0};
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (!has_domain(e)) continue;
        DrVec3 a, b;
        dr_component_box(dr_element_component(e, "Domain"), "box", &a, &b);
        grow_box(a, b, &any, &lo, &hi);
        if (e->kind == DR_ELEMENT_LIQUID) grow_box(a, b, &any_liquid, &llo, &lhi);
    }
    for (int i = 0; i < n; i++) {
        DrVec3 a, b;
        if (still[i].nt > 0 && dr_trimesh_bounds(&still[i], &a, &b)) grow_box(a, b, &any, &lo, &hi);
    }
    const DrComponent *c = dr_scene_section(scene, "render.camera");
    double view = dr_v3_norm(dr_v3_sub(dr_component_vec3(c, "target"), dr_component_vec3(c, "eye")));
    desc->scene_size = any && max_side(lo, hi) > 0.0 ? max_side(lo, hi) : view;
    desc->liquid_size = any_liquid ? max_side(llo, lhi) : 0.0;
}

double scene_ground_height(const DrScene *scene, const DrTriMesh *meshes, int n)
{
    double y = 1e300;
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (!has_domain(e)) continue;
        DrVec3 lo, hi;
        dr_component_box(dr_element_component(e, "Domain"), "box", &lo, &hi);
        if (lo.y < y) y = lo.y;
    }
    for (int i = 0; i < n; i++)
        for (int v = 0; v < meshes[i].nv; v++)
            if (meshes[i].v[3 * v + 1] < y) y = meshes[i].v[3 * v + 1];
    return y < 1e300 ? y : 0.0;
}

DrStatus scene_camera(const DrScene *scene, DrCamera *cam, DrError *err)
{
    const DrComponent *r = dr_scene_section(scene, "render");
    const DrComponent *c = dr_scene_section(scene, "render.camera");
    int res[2];
    cam->eye = dr_component_vec3(c, "eye");
    cam->target = dr_component_vec3(c, "target");
    cam->up = dr_component_vec3(c, "up");
    cam->fov_deg = dr_component_num(c, "fov_deg");
    dr_component_int2(r, "resolution", res);
    cam->width = res[0];
    cam->height = res[1];
    DrStatus s = dr_camera_check(cam, err);
    if (s < 0) {
        char msg[sizeof err->message];
        snprintf(msg, sizeof msg, "%s", err->message);
        dr_error_set(err, DR_ERR_INPUT, dr_scene_path(scene), 0, 0, "render.camera: %s", msg);
    }
    return s;
}

/* ---- the preview ------------------------------------------------------------------------------------------ */

/* Moves the mesh by the rigid transform X (world = R·p + t). */
static void transform_mesh(DrXform X, DrTriMesh *m)
{
    for (int i = 0; i < m->nv; i++) {
        DrVec3 p = dr_xform_apply(X, dr_v3(m->v[3 * i], m->v[3 * i + 1], m->v[3 * i + 2]));
        m->v[3 * i] = p.x, m->v[3 * i + 1] = p.y, m->v[3 * i + 2] = p.z;
    }
}

/* A collider in its scene pose, moved by its Motion to the pose at time t (s on the shot's clock). */
static DrStatus posed_collider(const DrElement *e, int first_frame, double fps, double t, DrTriMesh *m, DrError *err)
{
    DR_TRY(dr_stage_load_collider_mesh(e, m, err));
    double *keys = NULL;
    int nkeys = 0;
    DrStatus s = dr_stage_motion_keys(e, first_frame, fps, &keys, &nkeys, err);
    if (s == DR_OK && nkeys > 0) transform_mesh(dr_motion_pose(keys, nkeys, t), m);
    free(keys);
    if (s != DR_OK) dr_trimesh_free(m);
    return s;
}

/* An mpm_solid's MpmShape at rest: the box or sphere in its local frame placed by the Transform (scale, rotate,
   translate), or the mesh, which dr_stage_load_posed_mesh places. */
static DrStatus mpm_shape(const DrElement *e, DrTriMesh *m, DrError *err)
{
    const DrComponent *sh = dr_element_component(e, "MpmShape");
    if (dr_component_is_set(sh, "mesh"))
        return dr_stage_load_posed_mesh(e, dr_component_str(sh, "mesh"), "MpmShape.mesh", m, err);
    if (dr_component_is_set(sh, "box")) {
        DrVec3 lo, hi;
        dr_component_box(sh, "box", &lo, &hi);
        DR_TRY(scene_box_mesh(lo, hi, true, m, err));
    } else {
        DR_TRY(sphere_mesh(dr_component_vec3(sh, "centre"), dr_component_num(sh, "radius"), m, err));
    }
    double scale;
    DrXform X = dr_stage_element_transform(e, &scale);
    for (int i = 0; i < 3 * m->nv; i++) m->v[i] *= scale;
    transform_mesh(X, m);
    return DR_OK;
}

/* A liquid's initial liquid: its LiquidSource (box or closed mesh) and its Emitter box, each drawn as water. */
static DrStatus add_liquid(const DrElement *e, DrRenderScene *rs, DrError *err)
{
    const DrComponent *src = dr_element_component(e, "LiquidSource"), *em = dr_element_component(e, "Emitter");
    DrTriMesh m = {0};
    DrStatus s = DR_OK;
    DrVec3 lo, hi;
    if (dr_component_present(src) && dr_component_is_set(src, "box")) {
        dr_component_box(src, "box", &lo, &hi);
        s = scene_box_mesh(lo, hi, true, &m, err);
        if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &m, DR_MATERIAL_LIQUID, err);
        dr_trimesh_free(&m);
    }
    if (s == DR_OK && dr_component_present(src) && dr_component_is_set(src, "mesh")) {
        s = dr_error_prefix(dr_io_load_mesh(dr_component_str(src, "mesh"), &m, err), err, "%s.LiquidSource.mesh",
                            e->name);
        if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &m, DR_MATERIAL_LIQUID, err);
        dr_trimesh_free(&m);
    }
    if (s == DR_OK && dr_component_present(em)) {
        dr_component_box(em, "box", &lo, &hi);
        s = scene_box_mesh(lo, hi, true, &m, err);
        if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &m, DR_MATERIAL_LIQUID, err);
        dr_trimesh_free(&m);
    }
    return s;
}

/* ---- hair ------------------------------------------------------------------------------------------------ */

DrStatus scene_add_strands(const DrScene *scene, const DrElement *e, const DrPolylines *p, DrRenderScene *rs,
                           DrError *err)
{
    if (!p->outer)
        return dr_error_prefix(dr_render_scene_add_polylines(rs, p->x, p->offsets, p->count, p->radius,
                                                             DR_MATERIAL_HAIR, err),
                               err, "%s", e->name);
    DrStageWet wet;
    DR_TRY(dr_stage_wet_settings(scene, &wet, err));
    /* a film without wet hair in the scene (an edited OBJ): no ratio to measure it by, so the darkest */
    double max_ratio = wet.wet ? wet.film.max_ratio : 1.0;
    int V = p->count > 0 ? p->offsets[p->count] : 0;
    double *r = NULL, *w = NULL;
    DrStatus s = dr_calloc((size_t)V + 1, sizeof *r, &r, err);
    if (s == DR_OK) s = dr_calloc((size_t)V + 1, sizeof *w, &w, err);
    if (s == DR_OK) {
        dr_stage_vertex_radii(p->x, p->offsets, p->count, p->radius,
                              dr_component_num(dr_element_component(e, "RodMaterial"), "tip_radius"), r);
        for (int v = 0; v < V; v++) {
            double film = r[v] > 0.0 ? p->outer[v] / r[v] - 1.0 : (p->outer[v] > 0.0 ? INFINITY : 0.0);
            w[v] = max_ratio > 1.0 ? film / (max_ratio - 1.0) : (film > 0.0 ? 1.0 : 0.0);
            w[v] = w[v] > 1.0 ? 1.0 : (w[v] > 0.0 ? w[v] : 0.0); /* clamp; NaN (an outer radius of NaN) to 0 */
        }
        s = dr_error_prefix(dr_render_scene_add_wet_polylines(rs, p->x, p->offsets, p->count, p->outer, w,
                                                              DR_MATERIAL_HAIR, err),
                            err, "%s", e->name);
    }
    free(r);
    free(w);
    return s;
}

/* A hair element's grown strands, each as wide as RodMaterial.radius; in a scene with wet hair with the film the
   bake starts from (Film.initial_ratio on a wet element, none on a dry one: dr_film_create's H = ratio · r). */
static DrStatus add_groom(const DrScene *scene, const DrElement *e, DrRenderScene *rs, DrError *err)
{
    DrGroom g = {0};
    DR_TRY(dr_stage_load_groom(e, &g, err));
    DrStageWet wet;
    DrStatus s = dr_stage_wet_settings(scene, &wet, err);
    DrPolylines p = {.count = g.nstrands, .offsets = g.offsets, .x = g.x};
    int V = g.nstrands > 0 ? g.offsets[g.nstrands] : 0;
    if (s == DR_OK) s = dr_calloc((size_t)g.nstrands + 1, sizeof *p.radius, &p.radius, err);
    if (s == DR_OK && wet.wet) s = dr_calloc((size_t)V + 1, sizeof *p.outer, &p.outer, err);
    const DrComponent *rm = dr_element_component(e, "RodMaterial");
    for (int k = 0; s == DR_OK && k < g.nstrands; k++) p.radius[k] = dr_component_num(rm, "radius");
    if (s == DR_OK && p.outer) {
        bool wet_element = dr_component_present(dr_element_component(e, "Wetting"));
        double ratio = wet_element ? dr_component_num(dr_element_component(e, "Film"), "initial_ratio") : 1.0;
        dr_stage_vertex_radii(p.x, p.offsets, p.count, p.radius, dr_component_num(rm, "tip_radius"), p.outer);
        for (int v = 0; v < V; v++) p.outer[v] *= ratio;
    }
    if (s == DR_OK) s = scene_add_strands(scene, e, &p, rs, err);
    free(p.radius);
    free(p.outer);
    dr_groom_free(&g);
    return s;
}

DrStatus scene_preview(const DrScene *scene, const DrStageArgs *args, char *path, size_t size, DrError *err)
{
    DrCamera cam;
    DR_TRY(scene_camera(scene, &cam, err));
    const DrComponent *shot = dr_scene_section(scene, "shot");
    int frames[2];
    dr_component_int2(shot, "frames", frames);
    double fps = dr_component_num(shot, "fps");
    double t_first = 1.0 / fps; /* the shot's first frame, one frame after t = 0 */
    int nel = dr_scene_element_count(scene);
    DrTriMesh *colliders = NULL; /* posed colliders (empty for other elements) */
    DrRenderScene *rs = NULL;
    DR_TRY(dr_calloc((size_t)nel + 1, sizeof *colliders, &colliders, err));
    DrStatus s = dr_render_scene_create(&rs, err);
    for (int i = 0; s == DR_OK && i < nel; i++) {
        const DrElement *e = dr_scene_element(scene, i);
        DrTriMesh m = {0};
        switch (e->kind) {
        case DR_ELEMENT_LIQUID: s = add_liquid(e, rs, err); break;
        case DR_ELEMENT_COLLIDER:
            s = posed_collider(e, frames[0], fps, t_first, &colliders[i], err);
            if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &colliders[i], DR_MATERIAL_COLLIDER, err);
            break;
        case DR_ELEMENT_MPM_SOLID:
            s = mpm_shape(e, &m, err);
            if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &m, DR_MATERIAL_SOLID, err);
            break;
        case DR_ELEMENT_BEM_SOLID:
            s = dr_stage_load_posed_mesh(e, dr_component_str(dr_element_component(e, "Mesh"), "file"), "Mesh.file", &m,
                                         err);
            if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &m, DR_MATERIAL_SOLID, err);
            break;
        case DR_ELEMENT_HAIR: s = add_groom(scene, e, rs, err); break;
        case DR_ELEMENT_CLOTH:
            s = dr_stage_load_posed_mesh(e, dr_component_str(dr_element_component(e, "Mesh"), "file"), "Mesh.file", &m,
                                         err);
            if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &m, DR_MATERIAL_SOLID, err);
            break;
        case DR_ELEMENT_BEM_JOINT: break; /* no surface of its own */
        case DR_ELEMENT_AIR: break;       /* no surface */
        case DR_ELEMENT_COLLISION:        /* interactions, no surface */
        case DR_ELEMENT_ATTACHMENT: break;
        }
        dr_trimesh_free(&m);
    }
    if (s == DR_OK) s = scene_add_domain_walls(scene, rs, err);
    DrRenderDesc desc = dr_render_desc_default();
    const DrComponent *r = dr_scene_section(scene, "render");
    desc.ground = dr_component_bool(r, "ground");
    desc.samples = dr_component_int(r, "samples");
    /* the ground and the sizes as the shot's frames take them: from the still colliders only */
    for (int i = 0; s == DR_OK && i < nel; i++)
        if (dr_scene_element(scene, i)->kind == DR_ELEMENT_COLLIDER &&
            dr_component_present(dr_element_component(dr_scene_element(scene, i), "Motion")))
            dr_trimesh_free(&colliders[i]);
    desc.ground_height = scene_ground_height(scene, colliders, nel);
    scene_render_sizes(scene, colliders, nel, &desc);
    DrImage img = {0};
    if (s == DR_OK) s = dr_render_image(rs, &cam, &desc, &img, err);
    char dir[4096];
    snprintf(dir, sizeof dir, "%s/%s", args->out_root, dr_component_str(shot, "name"));
    snprintf(path, size, "%s/preview.png", dir);
    if (s == DR_OK) s = dr_io_mkdirs(dir, err);
    if (s == DR_OK) s = dr_image_write_png(path, &img, err);
    dr_image_free(&img);
    dr_render_scene_destroy(&rs);
    for (int i = 0; i < nel; i++) dr_trimesh_free(&colliders[i]);
    free(colliders);
    return s;
}
