/* Frame caches as the stages after bake trust them (stage.h). In a file of its own so that only the stages that
 * read frames link HDF5's checks. */
#include "stage/stage.h"

#include <stdlib.h>
#include <string.h>

/* ---- frame caches ------------------------------------------------------------------------------------------- */

/* dr_stage_check_frame, with the datasets' checksums only when `data`. */
static DrStatus check_frame(const char *bake_dir, int frame, const char *bake_key, bool data, DrError *err)
{
    char path[DR_IO_PATH_MAX];
    dr_stage_frame_path(bake_dir, "frame", frame, "h5", path, sizeof path);
    if (!dr_io_exists(path))
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "frame %d has not been baked (the file is missing)", frame);
    DrH5 *h = NULL;
    DR_TRY(dr_h5_open(path, &h, err));
    int64_t stored = 0;
    char *key = NULL;
    DrStatus s = dr_h5_read_attr_i64(h, "/", "frame", &stored, err);
    if (s == DR_OK && stored != frame)
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "the file holds frame %lld (its attribute frame), not frame %d: it was copied or renamed over "
                         "this frame's file",
                         (long long)stored, frame);
    if (s == DR_OK) s = dr_h5_read_attr_str(h, "/", "scene_key", &key, err);
    if (s == DR_OK && strcmp(key, bake_key) != 0)
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "frame %d was baked from another version of the scene (bake key %s, now %s)", frame, key,
                         bake_key);
    if (s == DR_OK && data) s = dr_h5_verify(h, false, NULL, 0, err);
    free(key);
    dr_h5_close(&h);
    return s;
}

DrStatus dr_stage_check_frame(const char *bake_dir, int frame, const char *bake_key, DrError *err)
{
    return check_frame(bake_dir, frame, bake_key, true, err);
}

typedef struct CheckFrames {
    const char *dir, *key;
    int first;
    bool data;
    DrStatus *status;
    DrError *errors;
} CheckFrames;

static void check_range(long begin, long end, void *ctx)
{
    const CheckFrames *c = ctx;
    for (long i = begin; i < end; i++) c->status[i] = check_frame(c->dir, c->first + (int)i, c->key, c->data, &c->errors[i]);
}

DrStatus dr_stage_check_frames(const char *bake_dir, int first, int last, const char *bake_key, bool data,
                               int *good_through, DrError *err)
{
    *good_through = first - 1;
    if (last < first) return DR_OK;
    long n = (long)last - first + 1;
    CheckFrames c = {bake_dir, bake_key, first, data, NULL, NULL};
    DrStatus s = dr_calloc((size_t)n, sizeof *c.status, &c.status, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof *c.errors, &c.errors, err);
    if (s != DR_OK) {
        free(c.status);
        return s;
    }
    /* Frames are checked in parallel where HDF5 allows threads: their reading and hashing, outside HDF5's lock,
       is most of the time (the default shot's 48 frames, 1 GB: 0.6 s of CPU). The first bad one in frame order is
       reported, whatever order they were checked in. */
    if (dr_h5_threadsafe()) dr_parallel_for(n, 1, check_range, &c);
    else check_range(0, n, &c);
    for (long i = 0; i < n && s == DR_OK; i++) {
        if (c.status[i] == DR_OK) {
            *good_through = first + (int)i;
            continue;
        }
        *err = c.errors[i];
        s = c.status[i];
        if (s != DR_ERR_NOMEM) /* a missing, damaged or foreign frame alike: bad input to whoever reads it */
            err->status = s = DR_ERR_INPUT;
    }
    free(c.status);
    free(c.errors);
    return s;
}

DrStatus dr_stage_check_checkpoint(const char *path, const char *bake_key, int first, int last, int *frame,
                                   DrError *err)
{
    *frame = first - 1;
    if (!dr_io_exists(path))
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "there is no checkpoint: the bake starts from frame %d",
                            first);
    DrH5 *h = NULL;
    DR_TRY(dr_h5_open(path, &h, err));
    char *key = NULL;
    int64_t f = 0;
    DrStatus s = dr_h5_read_attr_str(h, "/", "scene_key", &key, err);
    if (s == DR_OK && strcmp(key, bake_key) != 0)
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "the checkpoint was written for another version of the scene (bake key %s, now %s)", key,
                         bake_key);
    if (s == DR_OK) s = dr_h5_read_attr_i64(h, "/", "frame", &f, err);
    if (s == DR_OK && (f < first - 1 || f > last))
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "the checkpoint is after frame %lld, outside the shot's frames %d-%d",
                         (long long)f, first, last);
    char bad[512] = "";
    if (s == DR_OK) s = dr_h5_verify(h, true, bad, sizeof bad, err);
    if (s == DR_OK) *frame = (int)f;
    free(key);
    dr_h5_close(&h);
    if (s < 0 && s != DR_ERR_NOMEM) err->status = s = DR_ERR_INPUT;
    return s;
}
