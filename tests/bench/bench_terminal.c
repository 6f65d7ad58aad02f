/* Drag-limited sinking against resolution: a ball of 2000 kg/m³ (a BEM icosphere and an MPM sphere) let go at the
 * speed v_t = sqrt(8 R g (ρ_s − ρ_f)/(3 ρ_f C_d)) a sphere of its volume reaches with C_d = 0.47, 2.5 radii under the
 * surface of a tank 5 radii wide and 24 deep, Δx = 0.01 m and R = 4, 5 and 6 cells (the tests in make test bake 5).
 * The ball's speed levels off where the wake the grid resolves balances its weight less buoyancy; each row: body,
 * cells per radius, the mean speed over the last three frames before its centre comes within 8 radii of the floor
 * over v_t, |that − 1|, the spread of those three over v_t, frames, wall seconds (threads as the environment sets).
 * Writes the CSV given as argv[1] (default out/bench/terminal.csv) and a markdown table. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "mpm/mpm.h"
#include "stage/stage.h"
#include "world/world.h"

#include "../validation/sink_tank.h"

static void die(const char *what, const DrError *err)
{
    if (err) dr_error_print("bench_terminal", err);
    else fprintf(stderr, "bench_terminal: %s\n", what);
    exit(1);
}

/* One run: writes the scene (and the icosphere) into a temporary folder, builds the body's matrices as precompute
   would, steps until the ball is 8 radii above the floor. */
static void run(int bem, int cells, FILE *csv)
{
    const double dx = 0.01, R = cells * dx, W = 5.0 * R, H = 24.0 * R, rho = 2000.0;
    char dir[256] = "/tmp/drench_bench_terminal_XXXXXX", path[512], json[4096];
    if (!mkdtemp(dir)) die("mkdtemp failed", NULL);
    DrError err;
    if (bem) {
        DrTriMesh m = {0};
        if (dr_bem_mesh_icosphere(2, R, 0.0, 0.0, &m, &err) != DR_OK) die(NULL, &err);
        snprintf(path, sizeof path, "%s/ball.obj", dir);
        if (dr_io_write_obj(path, &m, NULL, &err) != DR_OK) die(NULL, &err);
        dr_trimesh_free(&m);
    }
    char body[1536];
    if (!sink_ball_json(body, sizeof body, bem, rho, R, W, H, dx) ||
        !sink_tank_json(json, sizeof json, 48, W, H, dx, body))
        die("the scene does not fit its buffer", NULL);
    snprintf(path, sizeof path, "%s/scene.json", dir);
    FILE *f = fopen(path, "w");
    if (!f) die("cannot write the scene", NULL);
    fputs(json, f);
    fclose(f);
    DrScene *scene;
    if (dr_scene_load(path, &scene, &err) < 0) die(NULL, &err);
    char cache[512];
    snprintf(cache, sizeof cache, "%s/cache", dir);
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_BEM_SOLID) continue;
        DrBemAsset a;
        if (dr_stage_load_bem_asset(e, &a, &err) < 0) die(NULL, &err);
        DrBemMatrices *mats = NULL;
        if (dr_bem_matrices_build(&a.mesh, &a.desc, NULL, &mats, &err) != DR_OK) die(NULL, &err);
        if (dr_bem_cache_write(cache, a.key, "{}", a.mesh_hash, mats, &err) != DR_OK) die(NULL, &err);
        dr_bem_matrices_destroy(&mats);
        dr_bem_asset_free(&a);
    }
    DrWorldDesc d;
    dr_world_desc_default(&d);
    d.cache_root = cache;
    DrWorld *w;
    if (dr_world_create_desc(scene, &d, &w, &err) < 0) die(NULL, &err);
    double v[48] = {0}, vt = 0.0, t0 = dr_time_now();
    int frames = 0;
    for (int fr = 0; fr < 48; fr++) {
        DrFrameStats st;
        if (dr_world_step_frame(w, &st, &err) < 0) die(NULL, &err);
        double y, vy, volume;
        if (bem) {
            const DrBemSolid *s = dr_world_bem_solid(w, 0);
            double Rm[9], T[3], V[3], om[3];
            dr_bem_solid_pose(s, Rm, T);
            dr_bem_solid_frame_velocity(s, V, om);
            y = T[1], vy = V[1], volume = dr_bem_solid_matrices(s)->body.volume;
        } else {
            DrMpmState s = dr_mpm_state(dr_world_mpm(w));
            double m = 0.0, c = 0.0, p = 0.0;
            volume = 0.0;
            for (long i = 0; i < s.n; i++)
                m += s.mass[i], volume += s.vol0[i], c += s.mass[i] * s.x[3 * i + 1], p += s.mass[i] * s.v[3 * i + 1];
            y = c / m, vy = p / m;
        }
        vt = sink_terminal_speed(rho, cbrt(3.0 * volume / (4.0 * DR_PI)));
        v[fr] = -vy;
        frames = fr + 1;
        if (y < 8.0 * R) break;
    }
    double secs = dr_time_now() - t0;
    if (frames < 3) die("the ball reached the floor within three frames", NULL);
    double mean, spread;
    sink_levelled(v, frames - 3, frames - 1, vt, &mean, &spread);
    fprintf(csv, "%s,%d,%.6f,%.6f,%.6f,%d,%.2f\n", bem ? "bem" : "mpm", cells, mean, fabs(mean - 1.0), spread, frames,
            secs);
    fflush(csv);
    printf("| %s | %d | %.3f | %.3f | %.3f | %d | %.1f |\n", bem ? "BEM" : "MPM", cells, mean, fabs(mean - 1.0), spread,
           frames, secs);
    fflush(stdout);
    dr_world_destroy(&w);
    dr_scene_destroy(&scene);
    char cmd[320];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0) die("cannot remove the scratch folder", NULL);
}

int main(int argc, char **argv)
{
    const char *out = argc > 1 ? argv[1] : "out/bench/terminal.csv";
    FILE *csv = fopen(out, "w");
    if (!csv) die("cannot write the CSV", NULL);
    fprintf(csv, "body,cells_per_radius,speed_over_vt,error,spread,frames,seconds\n");
    printf("| body | cells per radius | levelled speed / v_t (C_d 0.47) | error | spread of the last 3 frames | frames "
           "| seconds |\n|---|---|---|---|---|---|---|\n");
    for (int bem = 1; bem >= 0; bem--)
        for (int cells = 4; cells <= 6; cells++) run(bem, cells, csv);
    fclose(csv);
    return 0;
}
