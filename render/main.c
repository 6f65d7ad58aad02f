/* render: preview PNGs of the meshed frames. The renderer is not part of this build yet: the stage answers
 * --help, --version, --print-key and --available, and refuses to run (exit 1) rather than write fake images. */
#include <string.h>

#include "scene/scene.h"
#include "world/world.h"

int main(int argc, char **argv)
{
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--available")) {
            fprintf(stderr, "render: not available yet\n");
            return 1;
        }
    DrError err;
    dr_error_clear(&err);
    DrStageArgs args;
    bool done;
    if (dr_stage_parse_args(DR_STAGE_RENDER, argc, argv, &args, &done, &err) < 0) {
        dr_error_print("render", &err);
        return dr_exit_code(err.status);
    }
    if (done) return 0;
    DrScene *scene = NULL;
    if (dr_scene_load(args.scene_path, &scene, &err) < 0) {
        dr_error_print("render", &err);
        return dr_exit_code(err.status);
    }
    DrSceneKeys keys;
    if (dr_scene_keys(scene, &keys, &err) < 0) {
        dr_scene_destroy(&scene);
        dr_error_print("render", &err);
        return dr_exit_code(err.status);
    }
    char dir[2048];
    dr_stage_out_dir(&args, scene, DR_STAGE_RENDER, dir, sizeof dir);
    int rc = 1;
    if (args.print_key || args.print_out_dir) {
        printf("%s\n", args.print_key ? keys.render : dir);
        rc = 0;
    } else {
        fprintf(stderr, "render: not available yet: this build has no preview renderer; the meshes in %s/../mesh "
                        "open in any DCC tool\n", dir);
    }
    dr_scene_destroy(&scene);
    return rc;
}
