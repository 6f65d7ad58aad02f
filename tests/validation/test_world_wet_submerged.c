/* The bulk liquid's pressure on the film of wet hair (README "Wet hair and bulk liquid", wet.h dr_film_pressure): a
 * film under still water is neutral. Nine wet strands hang from clamped roots in a tank; with the water below them
 * (in air) their film drains down the strands into the tip pools at the friction law's speed (about 6 cm/s at
 * H = 3r), while under the water's surface the pressure's gradient, ρ g, holds the film where it is. Without the
 * pressure on the film (before it existed) the submerged film drained exactly as in air. */
#include <math.h>
#include <stdbool.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "world_run.h"

#define NS 3     /* NS × NS strands */
#define NV 11    /* vertices per strand */
#define FRAMES 6 /* 0.25 s */

static const char *SCENE =
    "{\"shot\": {\"name\": \"wet_submerged\", \"fps\": 24, \"frames\": [1, %d], \"gravity\": [0, -9.81, 0]},"
    " \"solver\": {\"cfl\": 1.0, \"max_substeps\": 64, \"coupling_iterations\": 3},"
    " \"elements\": ["
    "  {\"name\": \"water\", \"type\": \"liquid\", \"components\": {"
    "    \"Domain\": {\"box\": [[0, 0, 0], [0.08, 0.12, 0.08]], \"voxel_size\": 0.005},"
    "    \"LiquidSource\": {\"box\": [[0, 0, 0], [0.08, %g, 0.08]]},"
    "    \"Particles\": {\"per_cell\": 8, \"seed\": 3}}},"
    "  {\"name\": \"fur\", \"type\": \"hair\", \"components\": {"
    "    \"Groom\": {\"curves\": \"curves.obj\"},"
    "    \"RodMaterial\": {\"radius\": 5e-5},"
    "    \"HairSolver\": {\"substeps\": 4},"
    "    \"Wetting\": {\"liquid\": \"water\"},"
    "    \"Film\": {\"initial_ratio\": 3, \"max_ratio\": 6},"
    "    \"Capture\": {\"rate\": 0}, \"Dripping\": {\"middle\": false, \"tip\": false, \"root\": false},"
    "    \"Drag\": {\"buoyancy\": %s}}}]}";

/* Vertical strands 4 cm long, roots at y = 9.5 cm, 1.5 cm apart (no bridges between them). */
static char *curves_text(void)
{
    char *obj = calloc(1, 64 * NS * NS * NV + 1024);
    assert_non_null(obj);
    size_t n = 0;
    for (int i = 0; i < NS; i++)
        for (int k = 0; k < NS; k++)
            for (int j = 0; j < NV; j++)
                n += (size_t)sprintf(obj + n, "v %.6f %.6f %.6f\n", 0.025 + 0.015 * i, 0.095 - 0.04 * j / (NV - 1),
                                     0.025 + 0.015 * k);
    for (int s = 0; s < NS * NS; s++) {
        n += (size_t)sprintf(obj + n, "l");
        for (int j = 0; j < NV; j++) n += (size_t)sprintf(obj + n, " %d", s * NV + j + 1);
        n += (size_t)sprintf(obj + n, "\n");
    }
    return obj;
}

/* The film's volume at the start and the pools' after FRAMES frames, with the water's surface at `level` (m) and the
   pressure on the strands and their film on or off (Drag.buoyancy). */
static void run(double level, bool pressure, double *film0, double *pools, double *film_end)
{
    char json[4096];
    snprintf(json, sizeof json, SCENE, FRAMES, level, pressure ? "true" : "false");
    char *curves = curves_text();
    WorldRun r;
    world_run_open(&r, "wet_submerged", json, curves);
    free(curves);
    DrError err;
    DrFrameStats st;
    for (int f = 1; f <= FRAMES; f++) {
        if (dr_world_step_frame(r.world, &st, &err) < 0) fail_msg("%s", err.message);
        if (f == 1) *film0 = st.hair.film_volume + st.hair.pool_volume;
        printf("  surface at %.3f m, frame %d: film %.4e m^3, pools %.4e m^3, largest hair speed %.3e m/s\n", level, f,
               st.hair.film_volume, st.hair.pool_volume, st.hair.max_speed);
        assert_true(isfinite(st.hair.film_volume) && isfinite(st.hair.pool_volume));
    }
    *pools = st.hair.pool_volume;
    *film_end = st.hair.film_volume;
    world_run_close(&r);
}

static void test_submerged_film_holds(void **state)
{
    (void)state;
    double air0, air_pools, air_film, sub0, sub_pools, sub_film, off0, off_pools, off_film;
    run(0.02, true, &air0, &air_pools, &air_film);   /* the strands (y 5.5–9.5 cm) above the water */
    run(0.11, true, &sub0, &sub_pools, &sub_film);   /* under it */
    run(0.11, false, &off0, &off_pools, &off_film);  /* under it, without the pressure on them */
    printf("after %d frames the tip pools hold %.3e m^3 in air (%.1f %% of the film) and %.3e m^3 under water "
           "(%.2f %% of the film, %.2f %% of the air's)\n",
           FRAMES, air_pools, 100 * air_pools / air0, sub_pools, 100 * sub_pools / sub0, 100 * sub_pools / air_pools);
    printf("without the pressure (Drag.buoyancy false) the submerged film drains as in air: %.3e m^3 in the pools "
           "(%.1f %% of the air's)\n", off_pools, 100 * off_pools / air_pools);
    assert_true(air_pools > 0.05 * air0);                   /* in air the film drains */
    assert_true(sub_pools < 1e-3 * air_pools);              /* under water it stays on the strands */
    assert_true(sub_film > (1 - 1e-4) * sub0);              /* all but a trace (no capture, no dripping here) */
    assert_true(off_pools > 0.5 * air_pools);               /* and the check can tell: without it, it drains */
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_submerged_film_holds),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
