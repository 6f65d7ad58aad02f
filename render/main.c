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
    DrScene *scene = NULL;
    DrSceneKeys keys;
    char dir[2048];
    if (dr_stage_begin(DR_STAGE_RENDER, argc, argv, &args, &scene, &keys, dir, sizeof dir, &done, &err) < 0) {
        dr_error_print("render", &err);
        return dr_exit_code(err.status);
    }
    if (done) return 0;
    fprintf(stderr, "render: not available yet: this build has no preview renderer; the meshes in %s/../mesh "
                    "open in any DCC tool\n", dir);
    dr_scene_destroy(&scene);
    return 1;
}
