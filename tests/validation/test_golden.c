/* Golden states: one small scene per solver kind (liquid with a moving collider, MPM, hair, two BEM bodies apart and
 * three in contact on a floor, and one scene mixing them all), stepped a few frames on 1 and on 2 threads; the
 * world's state hash (dr_world_state_hash: every particle, vertex, body state, generator state and step count) must
 * equal the constant stored here. A change to any solver's arithmetic, its order of operations or its clock shows up as a new hash: a
 * deliberate one updates the constant in the same commit and says why. Run from the repository root.
 *
 * The constants hold on any x86-64 CPU because the test runs itself on the baseline instruction paths of the two
 * libraries that pick code by CPU: glibc's libm (sin, cos, exp, pow, atan2 have FMA and AVX2 variants that round
 * differently) and OpenBLAS (its kernels, and so its sums' order, are chosen per CPU family). main() re-executes the
 * test with GLIBC_TUNABLES masking those features and OPENBLAS_CORETYPE=Prescott (SSE3 kernels) before either
 * library has chosen; a bake uses the fast paths, and is bit-identical only on one machine kind.
 *
 * DRENCH_GOLDEN_PRINT=1 prints the hashes instead of checking them. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bem/bem.h"
#include "scene/scene.h"
#include "stage/stage.h"
#include "world/world.h"

#define DATA "tests/data/"

static char g_cache[512];

/* Builds every bem_solid's matrices of a scene into the test's cache folder, on one thread (the assembly is
   deterministic for a given thread count, so the matrices do not depend on the run's). */
static void precompute(const DrScene *scene)
{
    dr_set_threads(1);
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (strcmp(e->type, "bem_solid") != 0) continue;
        DrBemAsset a;
        DrError err;
        if (dr_stage_load_bem_asset(e, &a, &err) < 0) fail_msg("%s: %s", e->name, err.message);
        DrBemMatrices *m = NULL;
        DrBemMatrices *have = NULL;
        bool hit = false;
        if (dr_bem_cache_read(g_cache, a.key, &have, &hit, NULL, &err) < 0) fail_msg("%s", err.message);
        if (have) dr_bem_matrices_destroy(&have);
        if (!hit) {
            if (dr_bem_matrices_build(&a.mesh, &a.desc, NULL, &m, &err) < 0) fail_msg("%s: %s", e->name, err.message);
            if (dr_bem_cache_write(g_cache, a.key, "{}", a.mesh_hash, m, &err) < 0) fail_msg("%s", err.message);
            dr_bem_matrices_destroy(&m);
        }
        dr_bem_asset_free(&a);
    }
}

/* The state hash of scene `path` after `frames` frames on `threads` threads, as 32 hex digits. */
static void golden_hash(const char *path, int frames, int threads, char hex[33])
{
    DrScene *scene = NULL;
    DrError err;
    if (dr_scene_load(path, &scene, &err) < 0) fail_msg("%s: %s", path, err.message);
    precompute(scene);
    dr_set_threads(threads);
    DrWorldDesc d;
    dr_world_desc_default(&d);
    d.cache_root = g_cache;
    DrWorld *w = NULL;
    if (dr_world_create_desc(scene, &d, &w, &err) < 0) fail_msg("%s: %s", path, err.message);
    for (int f = 0; f < frames; f++) {
        DrFrameStats fs;
        if (dr_world_step_frame(w, &fs, &err) < 0) fail_msg("%s frame %d: %s", path, f + 1, err.message);
    }
    dr_hash_hex(dr_world_state_hash(w), hex);
    dr_world_destroy(&w);
    dr_scene_destroy(&scene);
    dr_set_threads(0);
}

typedef struct Golden {
    const char *scene;
    int frames;
    const char *hash; /* on 1 and on 2 threads alike */
} Golden;

/* hair_small and golden_mix changed with the hair's steps cut by its speed (HairSolver.cfl 1): hair_small's first
   frame takes 5 steps instead of 4, golden_mix's strands (3 m/s) 14-20 a frame instead of its substeps.
   moving_collider and golden_mix changed with the liquid's pressure preconditioner (multigrid by default instead of
   MIC(0)): both solve to the same tolerance, so the liquid differs at that level; with
   solver.pressure_preconditioner = "mic0" both give their previous hashes (975f9b2f…, 79a81558…) again.
   golden_mix changed with BEM bodies two-way with the liquid by default (BemSolver.liquid_coupling "two_way"): its
   jelly now floats in the pool; with "one_way" it gives its previous hash (afb130db…) again. It changed again with
   MPM solids two-way with the liquid by default (Integrator.liquid_coupling "two_way": the MPM steps with every liquid
   substep); with "none" it gives its previous hash (f0dba8f7…) again. */
static const Golden GOLDEN[] = {
    {DATA "moving_collider.json", 2, "cbf6d19a53d70c0fa1bd02cdc4e48273"},
    {DATA "mpm_drop.json", 4, "f82e4206818696d3b77be6c0e58924ff"},
    {DATA "hair_small.json", 3, "458492c98ec6b9957556c7708f76c97f"},
    {DATA "bem_pair.json", 2, "c1e076eea5909a3afe407387da37cfa1"},
    {DATA "golden_mix.json", 3, "6645c916f6e429ddc16025dc8289063a"},
    {DATA "bem_floor.json", 12, "5c8756117acc72e3a8ae2d5e18c054cb"},
};

static void check(int k)
{
    const Golden *g = &GOLDEN[k];
    bool print = getenv("DRENCH_GOLDEN_PRINT") != NULL;
    for (int t = 0; t < 2; t++) {
        char hex[33];
        golden_hash(g->scene, g->frames, t + 1, hex);
        if (print)
            printf("golden %s %d frames %d thread(s): %s\n", g->scene, g->frames, t + 1, hex);
        else if (strcmp(hex, g->hash) != 0)
            fail_msg("%s after %d frames on %d thread(s): state hash %s, stored %s", g->scene, g->frames, t + 1, hex,
                     g->hash);
    }
}

static void test_liquid_with_moving_collider(void **state) { (void)state; check(0); }
static void test_mpm_drop(void **state) { (void)state; check(1); }
static void test_hair_on_moving_scalp(void **state) { (void)state; check(2); }
static void test_bem_pair_apart(void **state) { (void)state; check(3); }
static void test_every_solver_in_one_scene(void **state) { (void)state; check(4); }
/* three bodies on a floor collider, two of them stacked: body–body contacts from frame 6 on */
static void test_bem_bodies_in_contact(void **state) { (void)state; check(5); }

static int setup(void **state)
{
    (void)state;
    snprintf(g_cache, sizeof g_cache, "%s/drench_test_golden.XXXXXX", dr_temp_dir());
    return mkdtemp(g_cache) ? 0 : -1;
}

static int teardown(void **state)
{
    (void)state;
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_cache);
    return system(cmd) == 0 ? 0 : -1;
}

/* The environment the constants were taken in; re-executes the test in it once (see the banner). */
static void pin_math_paths(char **argv)
{
    if (getenv("DRENCH_GOLDEN_PINNED")) return;
    setenv("DRENCH_GOLDEN_PINNED", "1", 1);
    setenv("GLIBC_TUNABLES", "glibc.cpu.hwcaps=-AVX512F,-AVX2,-FMA,-FMA4,-AVX", 1);
    setenv("OPENBLAS_CORETYPE", "Prescott", 1);
    execv("/proc/self/exe", argv);
    fprintf(stderr, "test_golden: cannot re-execute itself with the pinned math paths\n");
    exit(1);
}

int main(int argc, char **argv)
{
    (void)argc;
    pin_math_paths(argv);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_liquid_with_moving_collider),
        cmocka_unit_test(test_mpm_drop),
        cmocka_unit_test(test_hair_on_moving_scalp),
        cmocka_unit_test(test_bem_pair_apart),
        cmocka_unit_test(test_every_solver_in_one_scene),
        cmocka_unit_test(test_bem_bodies_in_contact),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
