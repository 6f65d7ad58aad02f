/* A hair element's strands in its scene pose (stage.h), for the world's rods and the render stage's preview, and the
 * radius along a tapered strand, for the mesh and render stages. In a file of its own, as stage_bem.c, so that what
 * loads a groom is one function. */
#include "stage/stage.h"

#include "hair/hair.h"

DrStatus dr_stage_load_groom(const DrElement *e, DrGroom *g, DrError *err)
{
    const DrComponent *gc = dr_element_component(e, "Groom");
    if (dr_component_is_set(gc, "scalp")) {
        DrTriMesh scalp = {0};
        DR_TRY(dr_stage_load_posed_mesh(e, dr_component_str(gc, "scalp"), "Groom.scalp", &scalp, err));
        DrGroomDesc d;
        dr_groom_desc_default(&d);
        d.count = dr_component_int(gc, "count");
        d.length = dr_component_num(gc, "length");
        d.segments = dr_component_int(gc, "segments");
        d.curl_radius = dr_component_num(gc, "curl_radius");
        d.curl_pitch = dr_component_num(gc, "curl_pitch");
        d.length_jitter = dr_component_num(gc, "length_jitter");
        d.seed = (uint64_t)dr_component_int(gc, "seed");
        DrStatus s = dr_groom_grow(&scalp, &d, g, err);
        dr_trimesh_free(&scalp);
        return dr_error_prefix(s, err, "%s.Groom.scalp", e->name);
    }
    DR_TRY(dr_error_prefix(dr_groom_read_obj(dr_component_str(gc, "curves"), g, err), err, "%s.Groom.curves", e->name));
    double sc;
    DrXform X = dr_stage_element_transform(e, &sc);
    DrMat3 R = X.R;
    DrVec3 t = X.t;
    for (int i = 0; i < g->offsets[g->nstrands]; i++) {
        DrVec3 p = dr_v3_add(dr_m3_apply(R, dr_v3_scale(dr_v3(g->x[3 * i], g->x[3 * i + 1], g->x[3 * i + 2]), sc)), t);
        g->x[3 * i] = p.x;
        g->x[3 * i + 1] = p.y;
        g->x[3 * i + 2] = p.z;
    }
    for (int k = 0; g->root_normal && k < g->nstrands; k++) {
        DrVec3 n = dr_m3_apply(R, dr_v3(g->root_normal[3 * k], g->root_normal[3 * k + 1], g->root_normal[3 * k + 2]));
        g->root_normal[3 * k] = n.x;
        g->root_normal[3 * k + 1] = n.y;
        g->root_normal[3 * k + 2] = n.z;
    }
    return DR_OK;
}

static double dist(const double *x, int a, int b)
{
    return dr_v3_norm(dr_v3(x[3 * b] - x[3 * a], x[3 * b + 1] - x[3 * a + 1], x[3 * b + 2] - x[3 * a + 2]));
}

void dr_stage_vertex_radii(const double *x, const int *offsets, int count, const double *strand_radius,
                           double tip_radius, double *out)
{
    for (int k = 0; k < count; k++) {
        int o = offsets[k], n = offsets[k + 1] - o;
        double rad = strand_radius[k], rt = tip_radius > 0 ? tip_radius : rad, total = 0, along = 0;
        for (int j = 0; j + 1 < n; j++) total += dist(x, o + j, o + j + 1);
        /* the rod set's rule (hair.c): linear in arc length, the root's radius exactly where nothing tapers; a
           strand of no length (every vertex at one point) keeps the root's */
        for (int j = 0; j < n; j++) {
            if (j > 0) along += dist(x, o + j - 1, o + j);
            out[o + j] = rt == rad || !(total > 0) ? rad : rad + (rt - rad) * (along / total);
        }
    }
}
