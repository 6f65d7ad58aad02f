/* A scene stepped in the world from a test: written to a temporary folder with its curves and, for wet hair, its
 * cohesion tables (built as precompute builds them), then a world on it. For the validation tests that step a world
 * frame by frame (include once, after cmocka.h). */
#ifndef DR_TEST_WORLD_RUN_H
#define DR_TEST_WORLD_RUN_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "io/io.h"
#include "stage/stage.h"
#include "world/world.h"

typedef struct WorldRun {
    char dir[256];
    DrScene *scene;
    DrWorld *world;
} WorldRun;

static inline void world_run_write(const char *dir, const char *name, const char *text)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs(text, f);
    fclose(f);
}

/* The two cohesion tables of the scene's wet hair in cache, as precompute writes them (none for a dry scene). */
static inline void world_run_tables(const DrScene *scene, const char *cache)
{
    DrStageWet set;
    DrError err;
    if (dr_stage_wet_settings(scene, &set, &err) < 0) fail_msg("%s", err.message);
    if (!set.wet) return;
    for (int k = 0; k < 2; k++) {
        DrCohesionTable *t = NULL;
        if (dr_cohesion_build(&set.tables[k], &t, &err) < 0) fail_msg("%s", err.message);
        char key[33], json[DR_COHESION_JSON_MAX];
        dr_cohesion_key(&set.tables[k], key);
        dr_cohesion_inputs_json(&set.tables[k], json);
        DrH5 *h = NULL;
        if (dr_io_precache_create(cache, "cohesion", key, json, NULL, &h, &err) < 0 || dr_cohesion_write(t, h, &err) < 0 ||
            dr_h5_commit(&h, &err) < 0)
            fail_msg("%s", err.message);
        dr_cohesion_destroy(&t);
    }
}

/* scene.json (json) and, unless NULL, curves.obj (curves) in a new temporary folder named after tag; the world on
   them with its cache there. */
static inline void world_run_open(WorldRun *r, const char *tag, const char *json, const char *curves)
{
    snprintf(r->dir, sizeof r->dir, "%s/drench_%s_XXXXXX", dr_temp_dir(), tag);
    assert_non_null(mkdtemp(r->dir));
    char path[512], cache[512];
    world_run_write(r->dir, "scene.json", json);
    if (curves) world_run_write(r->dir, "curves.obj", curves);
    DrError err;
    snprintf(path, sizeof path, "%s/scene.json", r->dir);
    if (dr_scene_load(path, &r->scene, &err) < 0) fail_msg("%s: %s", path, err.message);
    snprintf(cache, sizeof cache, "%s/cache", r->dir);
    world_run_tables(r->scene, cache);
    DrWorldDesc d;
    dr_world_desc_default(&d);
    d.cache_root = cache;
    if (dr_world_create_desc(r->scene, &d, &r->world, &err) < 0) fail_msg("%s", err.message);
}

static inline void world_run_close(WorldRun *r)
{
    dr_world_destroy(&r->world);
    dr_scene_destroy(&r->scene);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", r->dir);
    assert_int_equal(system(cmd), 0);
}

#endif
