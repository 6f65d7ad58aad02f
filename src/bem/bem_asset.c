/* A body's mesh as the matrices take it: loaded, welded, checked, hashed and keyed (bem.h); the names of the
 * orderings and the cache key live here rather than beside the cache's reader and writer, so that loading and
 * keying a body (what every stage's asset check does) does not link HDF5. */
#include "bem/bem.h"

#include <string.h>

/* Welding merges vertices closer than this fraction of the bounding-box diagonal: far below any real feature,
 * far above the float rounding of the loader (6e-8 relative) only where a file holds the same point twice with
 * different digits. A change here changes the matrices: it goes with a new DR_BEM_VERSION. */
#define WELD_RELATIVE 1e-9

void dr_bem_desc_default(DrBemDesc *d)
{
    *d = (DrBemDesc){
        .material = {.density = 1000.0, .shear_modulus = 1e5, .poisson = 0.4},
        .dt = 1.0 / 240.0,
        .history_margin = 2.0,
        .cq_epsilon = 1e-10,
        .compression_ratio = 32.0,
        .ordering = DR_BEM_ORDER_VERTEX_XYZ,
        .wavelet = true,
        .quad_levels = 1,
        .near_factor = 1.5,
        .singular_order = 8,
        .keep_dense = false,
    };
}

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

/* ---- names ---------------------------------------------------------------------------------------------- */

static const char *const ordering_names[] = {"vertex_xyz", "xyz", "none"};

const char *dr_bem_ordering_name(DrBemOrdering o)
{
    assert(o >= DR_BEM_ORDER_VERTEX_XYZ && o <= DR_BEM_ORDER_NONE);
    return ordering_names[o];
}

bool dr_bem_ordering_parse(const char *name, DrBemOrdering *out)
{
    for (int o = 0; o < 3; o++)
        if (strcmp(name, ordering_names[o]) == 0) {
            *out = (DrBemOrdering)o;
            return true;
        }
    return false;
}
/* ---- key ------------------------------------------------------------------------------------------------ */

static void feed(DrHasher *h, const char *label, const char *text)
{
    dr_hasher_update_str(h, label);
    dr_hasher_update_str(h, text);
}

/* Numbers as %.17g text (exact for a double; -0 as 0), the form the scene's canonical JSON uses. */
static void feed_num(DrHasher *h, const char *label, double v)
{
    char buf[40];
    snprintf(buf, sizeof buf, "%.17g", v == 0.0 ? 0.0 : v);
    feed(h, label, buf);
}

/* Everything that changes a matrix or the layout they are stored in. keep_dense is left out: the dense copies
 * are never cached, so a file serves either setting. What precompute does to the mesh before building (the
 * weld tolerance) is part of DR_BEM_VERSION. */
void dr_bem_cache_key(const char *mesh_hash_hex, const DrBemDesc *d, char key_hex[33])
{
    DrHasher h;
    dr_hasher_init(&h);
    feed(&h, "version", DR_BEM_VERSION);
    feed(&h, "mesh", mesh_hash_hex);
    feed_num(&h, "density", d->material.density);
    feed_num(&h, "shear_modulus", d->material.shear_modulus);
    feed_num(&h, "poisson", d->material.poisson);
    feed_num(&h, "dt", d->dt);
    feed_num(&h, "history_margin", d->history_margin);
    feed_num(&h, "cq_epsilon", d->cq_epsilon);
    feed_num(&h, "compression_ratio", d->compression_ratio);
    feed(&h, "ordering", dr_bem_ordering_name(d->ordering));
    feed(&h, "wavelet", d->wavelet ? "true" : "false");
    feed_num(&h, "quad_levels", d->quad_levels);
    feed_num(&h, "near_factor", d->near_factor);
    feed_num(&h, "singular_order", d->singular_order);
    dr_hash_hex(dr_hasher_final(&h), key_hex);
}
