/* A hair element's strands in its scene pose (stage.h), for the world's rods and the render stage's preview. In a
 * file of its own, as stage_bem.c, so that what loads a groom is one function. */
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
