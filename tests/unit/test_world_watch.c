/* The world's stability watch (src/world/world_watch.c, world_adapter.h): which energy histories raise an alarm, what
 * an alarm says and does with solver.on_instability warn and fail, the BEM bodies' cumulative-only check, and the
 * frame-length check at load. Run from the repository root. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "world/world_adapter.h"

static DrScene *load_text(const char *text)
{
    char path[512];
    snprintf(path, sizeof path, "%s/drench_test_watch.XXXXXX", dr_temp_dir());
    int fd = mkstemp(path);
    assert_true(fd >= 0);
    assert_true(write(fd, text, strlen(text)) == (ssize_t)strlen(text));
    close(fd);
    DrScene *s = NULL;
    DrError err;
    assert_int_equal(dr_scene_load(path, &s, &err), DR_OK);
    unlink(path);
    return s;
}

static WorldEnergy energy(double e, double available, double work)
{
    WorldEnergy w = {e, available, work, 1e-12};
    return w;
}

/* A solver that loses energy, or gains what was worked on it, raises nothing; one that gains more than 10 % of its
   available energy in a frame raises an alarm naming the element and the frame: a warning (DR_OK) with warn, a
   runtime error with fail. */
static void test_frame_alarm(void **state)
{
    (void)state;
    for (int fail = 0; fail < 2; fail++) {
        DrScene *scene = load_text(fail ? "{\"solver\": {\"on_instability\": \"fail\"}}" : "{}");
        WorldWatch w;
        world_watch_init(&w, scene);
        assert_int_equal(w.fail, fail);
        WorldCtx c = {.scene = scene, .fps = 24, .frame = 1};
        WorldEnergy e0 = energy(10.0, 5.0, 0.0);
        world_watch_start(&w, 1, &e0);
        DrError err;
        WorldEnergy e = energy(9.0, 4.0, 0.0); /* lost 1 J */
        assert_int_equal(world_watch_energy(&w, &c, &e, "liquid 'water'", "lower solver.cfl", &err), DR_OK);
        c.frame = 2;
        e = energy(11.0, 6.0, 2.5); /* gained 2 J with 2.5 J of work */
        assert_int_equal(world_watch_energy(&w, &c, &e, "liquid 'water'", "lower solver.cfl", &err), DR_OK);
        c.frame = 3;
        e = energy(11.5, 6.5, 0.0); /* +0.5 J of 6 J available: within 10 % */
        assert_int_equal(world_watch_energy(&w, &c, &e, "liquid 'water'", "lower solver.cfl", &err), DR_OK);
        c.frame = 4;
        e = energy(13.0, 8.0, 0.0); /* +1.5 J of 6.5 J: 23 % */
        dr_error_clear(&err);
        DrStatus s = world_watch_energy(&w, &c, &e, "liquid 'water'", "lower solver.cfl", &err);
        if (fail) {
            assert_int_equal(s, DR_ERR_RUNTIME);
            printf("fail: %s\n", err.message);
            assert_non_null(strstr(err.message, "frame 4: liquid 'water': the energy grew by 1.5 J in the frame"));
            assert_non_null(strstr(err.message, "lower solver.cfl"));
            assert_non_null(strstr(err.message, "solver.on_instability is \"fail\""));
        } else {
            assert_int_equal(s, DR_OK);
        }
        dr_scene_destroy(&scene);
    }
}

/* Slow growth, under the per-frame margin every frame, is caught against the first frame (10 % of what was available
   then); after that alarm the reference moves to the alarm's frame, so it is not repeated every frame. The BEM
   bodies' check (cumulative_only) ignores a frame's rebound that stays below the start. */
static void test_cumulative_alarm(void **state)
{
    (void)state;
    DrScene *scene = load_text("{\"solver\": {\"on_instability\": \"fail\"}}");
    WorldWatch w;
    world_watch_init(&w, scene);
    WorldCtx c = {.scene = scene, .fps = 24, .frame = 1};
    WorldEnergy e = energy(100.0, 100.0, 0.0);
    world_watch_start(&w, 1, &e);
    DrError err;
    int alarm = 0;
    for (int f = 1; f <= 6; f++) {
        c.frame = f;
        e = energy(100.0 + 3.0 * f, 100.0 + 3.0 * f, 0.0); /* +3 % a frame */
        if (world_watch_energy(&w, &c, &e, "mpm_solid 'ball'", "lower solver.cfl", &err) < 0 && !alarm) {
            alarm = f;
            printf("cumulative: %s\n", err.message);
            assert_non_null(strstr(err.message, "since the start of frame 1"));
        }
    }
    assert_int_equal(alarm, 4); /* 12 J > 10 J at frame 4 */
    /* cumulative only: a rebound (+40 % in a frame) below the start is no alarm; above it by 10 %, one */
    world_watch_init(&w, scene);
    w.cumulative_only = true;
    e = energy(50.0, 50.0, 0.0);
    world_watch_start(&w, 1, &e);
    c.frame = 1;
    e = energy(30.0, 30.0, 0.0);
    assert_int_equal(world_watch_energy(&w, &c, &e, "bem_solid 'jelly'", "lower BemSolver.time_step", &err), DR_OK);
    c.frame = 2;
    e = energy(45.0, 45.0, 0.0);
    assert_int_equal(world_watch_energy(&w, &c, &e, "bem_solid 'jelly'", "lower BemSolver.time_step", &err), DR_OK);
    c.frame = 3;
    e = energy(56.0, 56.0, 0.0);
    assert_int_equal(world_watch_energy(&w, &c, &e, "bem_solid 'jelly'", "lower BemSolver.time_step", &err),
                     DR_ERR_RUNTIME);
    dr_scene_destroy(&scene);
}

/* A frame longer than max_substeps of the solver's step is bad input naming shot.fps and solver.max_substeps with
   the values that would do; a frame that holds them passes. */
static void test_frame_length(void **state)
{
    (void)state;
    DrScene *scene = load_text("{\"shot\": {\"fps\": 0.001}, \"solver\": {\"max_substeps\": 32}}");
    WorldCtx c = {.scene = scene, .fps = 0.001, .frame = 1};
    DrError err;
    assert_int_equal(world_watch_frame_length(&c, "liquid 'water'", 0.0226, "its CFL step", &err), DR_ERR_INPUT);
    printf("frame length: %s\n", err.message);
    assert_non_null(strstr(err.message, "shot.fps = 0.001"));
    assert_non_null(strstr(err.message, "solver.max_substeps is 32"));
    assert_non_null(strstr(err.message, "at least 44248 substeps"));
    c.fps = 24;
    assert_int_equal(world_watch_frame_length(&c, "liquid 'water'", 0.0226, "its CFL step", &err), DR_OK);
    assert_int_equal(world_watch_frame_length(&c, "liquid 'water'", INFINITY, "no gravity", &err), DR_OK);
    dr_scene_destroy(&scene);
}

int main(void)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_frame_alarm),
        cmocka_unit_test(test_cumulative_alarm),
        cmocka_unit_test(test_frame_length),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
