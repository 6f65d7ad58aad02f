/* A body's mesh as the matrices take it: loaded, welded, checked, hashed and keyed (bem.h). */
#include "bem/bem.h"

#include <string.h>

/* Welding merges vertices closer than this fraction of the bounding-box diagonal: far below any real feature,
 * far above the float rounding of the loader (6e-8 relative) only where a file holds the same point twice with
 * different digits. A change here changes the matrices: it goes with a new DR_BEM_VERSION. */
#define WELD_RELATIVE 1e-9

/* Names the mesh file in a failure that names no file yet. */
static DrStatus in_file(DrStatus s, const char *path, DrError *err)
{
    if (s < 0 && err && !err->file[0]) snprintf(err->file, sizeof err->file, "%s", path);
    return s;
}

DrStatus dr_bem_asset_load(const char *path, const DrBemDesc *desc, DrBemAsset *a, DrError *err)
{
    memset(a, 0, sizeof *a);
    a->path = path;
    DR_TRY(in_file(dr_io_load_mesh(path, &a->mesh, err), path, err));
    DrVec3 lo, hi;
    double diag = dr_trimesh_bounds(&a->mesh, &lo, &hi) ? dr_v3_norm(dr_v3_sub(hi, lo)) : 0.0;
    a->vertices_in_file = a->mesh.nv;
    a->weld_tolerance = WELD_RELATIVE * diag;
    DrStatus s = dr_bem_mesh_weld(&a->mesh, a->weld_tolerance, &a->welded, err);
    if (s == DR_OK) s = dr_bem_mesh_check(&a->mesh, path, err);
    DrHash h;
    if (s == DR_OK) s = dr_hash_file(path, &h, err);
    if (s != DR_OK) {
        dr_bem_asset_free(a);
        return in_file(s, path, err);
    }
    dr_hash_hex(h, a->mesh_hash);
    a->desc = *desc;
    dr_bem_cache_key(a->mesh_hash, &a->desc, a->key);
    return DR_OK;
}

void dr_bem_asset_free(DrBemAsset *a) { dr_trimesh_free(&a->mesh); }
