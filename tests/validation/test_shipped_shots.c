/* The shipped shots (assets/scenes) are set up as their own documentation asks: every bem_solid keeps at least
 * DR_BEM_MIN_COEFFICIENTS_PER_ROW Haar coefficients per row, the rule precompute warns by (the default shot's jelly,
 * 642 vertices at the default Compression.ratio 32, kept 60 and was off by ~10 %). Run from the repository root. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <stdio.h>
#include <string.h>

#include "bem/bem.h"
#include "scene/scene.h"
#include "stage/stage.h"

static const char *const SHOTS[] = {"assets/scenes/default.json",    "assets/scenes/dam_break.json",
                                    "assets/scenes/small_dam.json",
                                    "assets/scenes/jelly_drop.json", "assets/scenes/hair_shake.json",
                                    "assets/scenes/box_test.json",   "assets/scenes/dragging_test.json",
                                    "assets/scenes/bodies_tank.json"};

static void test_bem_compression_per_row(void **state)
{
    (void)state;
    int bodies = 0;
    for (size_t k = 0; k < sizeof SHOTS / sizeof *SHOTS; k++) {
        DrScene *scene = NULL;
        DrError err;
        if (dr_scene_load(SHOTS[k], &scene, &err) < 0) fail_msg("%s: %s", SHOTS[k], err.message);
        for (int i = 0; i < dr_scene_element_count(scene); i++) {
            const DrElement *e = dr_scene_element(scene, i);
            if (e->kind != DR_ELEMENT_BEM_SOLID) continue;
            DrBemAsset a;
            if (dr_stage_load_bem_asset(e, &a, &err) < 0) fail_msg("%s: %s: %s", SHOTS[k], e->name, err.message);
            double per_row = dr_bem_coefficients_per_row(a.mesh.nv, a.desc.compression_ratio);
            printf("%s: bem_solid '%s': %d vertices, Compression.ratio %g keeps %.0f coefficients per row\n", SHOTS[k],
                   e->name, a.mesh.nv, a.desc.compression_ratio, per_row);
            assert_true(a.desc.compression_ratio == 1.0 || per_row >= DR_BEM_MIN_COEFFICIENTS_PER_ROW);
            dr_bem_asset_free(&a);
            bodies++;
        }
        dr_scene_destroy(&scene);
    }
    assert_true(bodies >= 1); /* the default shot's jelly at least */
}

int main(void)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bem_compression_per_row),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
