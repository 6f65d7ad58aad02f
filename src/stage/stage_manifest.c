/* The MANIFEST of a stage that works frame by frame (mesh, render) around one run over a range of frames
 * (stage.h): what earlier runs under the same key completed is kept, the frames being rewritten are not claimed
 * while they are, and the run adds its own. */
#include "stage/stage.h"

#include <string.h>

DrStatus dr_stage_frames_begin(const char *dir, DrStageId stage, const char *key, const DrScene *scene, int first,
                               int last, bool rewrites, const char *const *inputs, int ninputs, DrStageFrames *run,
                               DrError *err)
{
    memset(run, 0, sizeof *run);
    snprintf(run->dir, sizeof run->dir, "%s", dir);
    run->stage = stage;
    snprintf(run->key, sizeof run->key, "%s", key);
    run->scene = scene;
    run->first = first;
    run->last = last;
    int shot[2];
    dr_component_int2(dr_scene_section(scene, "shot"), "frames", shot);
    run->shot_first = shot[0];
    run->shot_last = shot[1];
    DrManifest m;
    DR_TRY(dr_io_manifest_read(dir, &m, err));
    if (m.found && strcmp(m.key, key) == 0) {
        run->had = true;
        /* a MANIFEST without a frames line was written for the whole shot */
        run->had_first = m.has_frames ? m.first : shot[0];
        run->had_last = m.has_frames ? m.last : shot[1];
    }
    if (!rewrites) return DR_OK;
    /* the frames before this run's stay claimed; those it rewrites are not, until it has written them */
    if (run->had && run->had_first < first) {
        int keep = run->had_last < first - 1 ? run->had_last : first - 1;
        return dr_io_manifest_write_frames(dir, dr_stage_name(stage), key, dr_scene_path(scene), run->had_first, keep,
                                           inputs, ninputs, err);
    }
    return dr_io_manifest_remove(dir, err);
}

void dr_stage_frames_done(const DrStageFrames *run, int *done_first, int *done_last)
{
    int a = run->first, b = run->last;
    /* an earlier range that touches or overlaps this one joins it; one apart from it is dropped (the MANIFEST
       holds one range) */
    if (run->had && run->had_first <= b + 1 && run->had_last >= a - 1) {
        if (run->had_first < a) a = run->had_first;
        if (run->had_last > b) b = run->had_last;
    }
    *done_first = a;
    *done_last = b;
}

DrStatus dr_stage_frames_end(const DrStageFrames *run, const char *const *inputs, int ninputs, DrError *err)
{
    int a, b;
    dr_stage_frames_done(run, &a, &b);
    return dr_io_manifest_write_frames(run->dir, dr_stage_name(run->stage), run->key, dr_scene_path(run->scene), a, b,
                                       inputs, ninputs, err);
}

bool dr_stage_frames_whole(const DrStageFrames *run, int done_first, int done_last)
{
    return done_first <= run->shot_first && done_last >= run->shot_last;
}
