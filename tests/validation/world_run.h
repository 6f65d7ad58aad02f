/* A scene stepped in the world from a test: written to a temporary folder with its curves and, for wet hair, its
 * cohesion tables (built as precompute builds them), then a world on it. For the validation tests that step a world
 * frame by frame (include once, after cmocka.h). */
#ifndef DR_TEST_WORLD_RUN_H
#define DR_TEST_WORLD_RUN_H

#include <math.h>
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

/* The drag-limited sinking tests (test_world_bodies, test_world_mpm_liquid): the speed at which the drag of a sphere
   of radius R with C_d = 0.47 balances its weight less buoyancy in water, v_t = sqrt(8 R g (ρ_s − ρ_f)/(3 ρ_f C_d)),
   and their scene: `frames` frames at 24 fps of a tank of still water [0, width] × [0, depth] × [0, width] (Δx = dx,
   the domain a few cells higher) with the body element `body` (JSON) in it. */
static inline double world_run_terminal_speed(double rho, double R)
{
    return sqrt(8.0 * R * 9.81 * (rho - 1000.0) / (3.0 * 1000.0 * 0.47));
}

static inline void world_run_sink_tank(char *json, size_t size, int frames, double width, double depth, double dx,
                                       const char *body)
{
    int n = snprintf(json, size,
                     "{\"shot\": {\"name\": \"terminal\", \"fps\": 24, \"frames\": [1, %d], \"gravity\": [0, -9.81, 0]},"
                     "\"solver\": {\"cfl\": 1.0, \"max_substeps\": 64},"
                     "\"elements\": [{\"name\": \"water\", \"type\": \"liquid\", \"components\": {"
                     "  \"Domain\": {\"box\": [[0, 0, 0], [%g, %g, %g]], \"voxel_size\": %g},"
                     "  \"LiquidSource\": {\"box\": [[0, 0, 0], [%g, %g, %g]]},"
                     "  \"Particles\": {\"per_cell\": 8, \"seed\": 3}}}, %s]}",
                     frames, width, depth + 3 * dx, width, dx, width, depth, width, body);
    assert_true(n > 0 && (size_t)n < size);
}

/* The mean of v[from..to] and its spread (largest − smallest), both over vt. */
static inline void world_run_levelled(const double *v, int from, int to, double vt, double *mean, double *spread)
{
    double sum = 0.0, lo = v[from], hi = v[from];
    for (int f = from; f <= to; f++) sum += v[f], lo = fmin(lo, v[f]), hi = fmax(hi, v[f]);
    *mean = sum / (to - from + 1) / vt;
    *spread = (hi - lo) / vt;
}

#endif
