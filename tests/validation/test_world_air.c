/* The air element through the world: a bake of tests/data/air_wind.json (wind past a moving block) writes its frame
 * diagnostics under /<air>/, conserves volume through the box, and a continuation from a checkpoint is bit-identical
 * to an uninterrupted run. Run from the repository root. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "io/io.h"
#include "scene/scene.h"
#include "world/world.h"

#define SCENE "tests/data/air_wind.json"

static DrWorld *load_world(DrScene **scene)
{
    DrError err;
    if (dr_scene_load(SCENE, scene, &err) < 0) fail_msg("%s: %s", SCENE, err.message);
    DrWorld *w = NULL;
    if (dr_world_create(*scene, &w, &err) < 0) fail_msg("%s: %s", SCENE, err.message);
    return w;
}

static void step(DrWorld *w, int frames, DrFrameStats *fs)
{
    for (int i = 0; i < frames; i++) {
        DrError err;
        if (dr_world_step_frame(w, fs, &err) < 0) fail_msg("frame %d: %s", dr_world_frame(w) + 1, err.message);
    }
}

static double read_scalar(DrH5 *h, const char *path)
{
    int rank;
    uint64_t dims[4];
    double *v = NULL, out;
    DrError err;
    if (dr_h5_read_f64(h, path, &rank, dims, &v, &err) < 0) fail_msg("%s", err.message);
    out = v[0];
    free(v);
    return out;
}

static void temp_path(const char *name, char *buf, size_t size)
{
    snprintf(buf, size, "%s/drench_world_air_%ld_%s", dr_temp_dir(), (long)getpid(), name);
}

static void test_frame_cache(void **state)
{
    (void)state;
    DrScene *scene = NULL;
    DrWorld *w = load_world(&scene);
    assert_int_equal(dr_world_live_collider_count(w), 1); /* the air samples the block */
    DrFrameStats fs;
    step(w, 4, &fs);
    char path[1024];
    temp_path("frame.h5", path, sizeof path);
    DrError err;
    DrH5 *h = NULL;
    if (dr_h5_create(path, &h, &err) < 0 || dr_world_write_frame(w, &fs, "k", h, &err) < 0 || dr_h5_commit(&h, &err) < 0)
        fail_msg("%s", err.message);
    if (dr_h5_open(path, &h, &err) < 0) fail_msg("%s", err.message);
    /* at 1/6 s the wind has ramped to 4 m/s through the 0.6 × 0.6 m² face: 1.44 m³/s in, the same out (the pressure
       solve's tolerance, 1e-6) */
    double in = read_scalar(h, "/wind/inflow_flux"), out = read_scalar(h, "/wind/outflow_flux");
    assert_true(fabs(in - 1.44) <= 1e-12);
    assert_true(fabs(out - in) <= 1e-4 * in);
    double vmax = read_scalar(h, "/wind/max_speed"), ke = read_scalar(h, "/wind/kinetic_energy");
    assert_true(vmax > 4.0 && vmax < 16.0);
    /* the box's 0.54 m³ of air (less the 0.008 m³ block) at 1.2 kg/m³, moving at about the wind's 4 m/s */
    assert_true(ke > 0.5 * 1.2 * 0.5 * 16.0 && ke < 0.5 * 1.2 * 0.54 * 64.0);
    assert_true(read_scalar(h, "/wind/mass") < 1.2 * 0.54 && read_scalar(h, "/wind/mass") > 1.2 * 0.53);
    assert_true(dr_h5_has(h, "/wind/linear_momentum"));
    assert_false(dr_h5_has(h, "/wind/velocity_u")); /* the grid goes to checkpoints only */
    dr_h5_close(&h);
    unlink(path);
    dr_world_destroy(&w);
    dr_scene_destroy(&scene);
}

static void test_resume_is_bit_identical(void **state)
{
    (void)state;
    DrScene *sa = NULL, *sb = NULL;
    DrWorld *a = load_world(&sa), *b = load_world(&sb);
    char path[1024];
    temp_path("ckpt.h5", path, sizeof path);
    DrFrameStats fs;
    step(a, 3, &fs);
    DrError err;
    DrH5 *h = NULL;
    if (dr_h5_create(path, &h, &err) < 0 || dr_world_write_checkpoint(a, "k", h, &err) < 0 || dr_h5_commit(&h, &err) < 0)
        fail_msg("%s", err.message);
    step(a, 3, &fs);
    if (dr_world_read_checkpoint(b, path, "k", &err) < 0) fail_msg("%s", err.message);
    assert_int_equal(dr_world_frame(b), 3);
    step(b, 3, &fs);
    DrHash ha = dr_world_state_hash(a), hb = dr_world_state_hash(b);
    assert_memory_equal(&ha, &hb, sizeof ha);
    /* and the state did move: a fresh world differs */
    DrScene *sc = NULL;
    DrWorld *c = load_world(&sc);
    DrHash hc = dr_world_state_hash(c);
    assert_memory_not_equal(&ha, &hc, sizeof ha);
    unlink(path);
    dr_world_destroy(&a);
    dr_world_destroy(&b);
    dr_world_destroy(&c);
    dr_scene_destroy(&sa);
    dr_scene_destroy(&sb);
    dr_scene_destroy(&sc);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_frame_cache),
        cmocka_unit_test(test_resume_is_bit_identical),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
