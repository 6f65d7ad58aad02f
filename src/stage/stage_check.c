/* What a stage checks before it writes anything (stage.h): the scene's assets, loaded as the world loads them.
 * They fail before anything is written, naming the element, the field and the file. */
#include "stage/stage.h"

#include <stdlib.h>
#include <string.h>

#include "bem/bem.h"
#include "cloth/cloth.h"
#include "hair/hair.h"

/* ---- assets ------------------------------------------------------------------------------------------------- */

/* A mesh that encloses a volume (a collider, an MPM solid's shape) must be closed: the inside of an open one is
 * not defined, and the SDF built from it can call air solid (or the reverse) along a line through a hole. */
static DrStatus check_closed(const DrElement *e, const char *field, const char *path, const DrTriMesh *m,
                             const char *use, DrError *err)
{
    if (dr_trimesh_is_closed(m)) return DR_OK;
    return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                        "%s.%s: the mesh is not closed (some edge is not shared by exactly two oppositely oriented "
                        "triangles, e.g. a hole or a fin of extra faces), so %s has no well-defined inside; close "
                        "the mesh (fill the holes, weld the seams) and export it again",
                        e->name, field, use);
}

/* Loads mesh `path` of element e's `field` in its scene pose and, with `use`, checks it is closed. */
static DrStatus check_mesh(const DrElement *e, const char *path, const char *field, const char *use, DrError *err)
{
    DrTriMesh m = {0};
    DR_TRY(dr_stage_load_posed_mesh(e, path, field, &m, err));
    DrStatus s = use ? check_closed(e, field, path, &m, use, err) : DR_OK;
    dr_trimesh_free(&m);
    return s;
}

DrStatus dr_stage_check_assets(const DrScene *scene, DrError *err)
{
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        switch (e->kind) {
        case DR_ELEMENT_COLLIDER:
            DR_TRY(check_mesh(e, dr_component_str(dr_element_component(e, "Mesh"), "file"), "Mesh.file",
                              "the collider", err));
            break;
        case DR_ELEMENT_BEM_SOLID: {
            DrBemAsset a;
            DR_TRY(dr_stage_load_bem_asset(e, &a, err));
            dr_bem_asset_free(&a);
            break;
        }
        case DR_ELEMENT_MPM_SOLID: {
            const DrComponent *shape = dr_element_component(e, "MpmShape");
            if (dr_component_is_set(shape, "mesh"))
                DR_TRY(check_mesh(e, dr_component_str(shape, "mesh"), "MpmShape.mesh", "the body", err));
            break;
        }
        case DR_ELEMENT_LIQUID: {
            const DrComponent *src = dr_element_component(e, "LiquidSource");
            if (dr_component_present(src) && dr_component_is_set(src, "mesh")) {
                DrTriMesh m = {0};
                DR_TRY(dr_error_prefix(dr_io_load_mesh(dr_component_str(src, "mesh"), &m, err), err,
                                       "%s.LiquidSource.mesh", e->name));
                dr_trimesh_free(&m);
            }
            break;
        }
        case DR_ELEMENT_CLOTH: {
            /* the mesh loads and makes a panel (a manifold, consistently wound, no degenerate triangle) */
            DrTriMesh m = {0};
            DR_TRY(dr_stage_load_posed_mesh(e, dr_component_str(dr_element_component(e, "Mesh"), "file"), "Mesh.file", &m,
                                            err));
            DrClothMaterial mat;
            dr_cloth_material_default(&mat);
            DrCloth *cl = NULL;
            DrStatus s = dr_cloth_create(NULL, &m, &mat, e->name, &cl, err);
            if (s != DR_OK) {
                char msg[sizeof err->message];
                snprintf(msg, sizeof msg, "%s", err->message);
                s = dr_error_set(err, s, dr_component_str(dr_element_component(e, "Mesh"), "file"), 0, 0,
                                 "%s.Mesh.file: %s", e->name, msg);
            }
            dr_cloth_destroy(&cl);
            dr_trimesh_free(&m);
            DR_TRY(s);
            break;
        }
        case DR_ELEMENT_HAIR: {
            const DrComponent *g = dr_element_component(e, "Groom");
            if (dr_component_is_set(g, "scalp")) {
                DR_TRY(check_mesh(e, dr_component_str(g, "scalp"), "Groom.scalp", NULL, err));
            } else if (dr_component_is_set(g, "curves")) {
                DrGroom groom = {0};
                DR_TRY(dr_error_prefix(dr_groom_read_obj(dr_component_str(g, "curves"), &groom, err), err,
                                       "%s.Groom.curves", e->name));
                dr_groom_free(&groom);
            }
            break;
        }
        default: break;
        }
    }
    return DR_OK;
}
