/* The drag-limited sinking scene shared by the tests (test_world_bodies, test_world_mpm_liquid) and the bench
 * (bench_terminal): a ball of density rho and radius R let go at the speed a sphere reaches with C_d = 0.47 in a tank of
 * still water. Plain C (no cmocka): the bench includes it too. */
#ifndef DR_TEST_SINK_TANK_H
#define DR_TEST_SINK_TANK_H

#include <math.h>
#include <stdbool.h>
#include <stdio.h>

/* The speed at which the drag of a sphere of radius R with C_d = 0.47 balances its weight less buoyancy in water,
   v_t = sqrt(2 (ρ_s − ρ_f) V g / (ρ_f C_d A)) = sqrt(8 R g (ρ_s − ρ_f)/(3 ρ_f C_d)). */
static inline double sink_terminal_speed(double rho, double R)
{
    return sqrt(8.0 * R * 9.81 * (rho - 1000.0) / (3.0 * 1000.0 * 0.47));
}

/* The ball's element (JSON) at (½ width, depth − 2.5 R, ½ width), moving down at sink_terminal_speed: a BEM icosphere
   read from ball.obj beside the scene, or an MPM sphere on a domain of the tank's size. False when it does not fit. */
static inline bool sink_ball_json(char *out, size_t size, bool bem, double rho, double R, double width, double depth,
                                  double dx)
{
    int n;
    if (bem)
        n = snprintf(out, size,
                     "{\"name\": \"ball\", \"type\": \"bem_solid\", \"components\": {\"Mesh\": {\"file\": \"ball.obj\"},"
                     " \"Transform\": {\"translate\": [%g, %g, %g]}, \"InitialVelocity\": {\"velocity\": [0, %.17g, 0]},"
                     " \"LinearElastic\": {\"density\": %g, \"shear_modulus\": 1e6, \"poisson\": 0.4},"
                     " \"Compression\": {\"ratio\": 1},"
                     " \"BemSolver\": {\"time_step\": 0.004166666666666667, \"history_margin\": 8}}}",
                     0.5 * width, depth - 2.5 * R, 0.5 * width, -sink_terminal_speed(rho, R), rho);
    else
        n = snprintf(out, size,
                     "{\"name\": \"ball\", \"type\": \"mpm_solid\", \"components\": {"
                     " \"Domain\": {\"box\": [[0, 0, 0], [%g, %g, %g]], \"voxel_size\": %g},"
                     " \"MpmShape\": {\"centre\": [%g, %g, %g], \"radius\": %g},"
                     " \"InitialVelocity\": {\"velocity\": [0, %.17g, 0]},"
                     " \"MpmMaterial\": {\"model\": \"fixed_corotated\", \"density\": %g, \"youngs_modulus\": 1e6,"
                     " \"poisson\": 0.3}}}",
                     width, depth + 3 * dx, width, dx, 0.5 * width, depth - 2.5 * R, 0.5 * width, R,
                     -sink_terminal_speed(rho, R), rho);
    return n > 0 && (size_t)n < size;
}

/* The scene: `frames` frames at 24 fps of a tank of still water [0, width] × [0, depth] × [0, width] (Δx = dx, the
   domain a few cells higher) with the element `body` (JSON) in it. False when it does not fit. */
static inline bool sink_tank_json(char *json, size_t size, int frames, double width, double depth, double dx,
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
    return n > 0 && (size_t)n < size;
}

/* The mean of v[from..to] and its spread (largest − smallest), both over vt. */
static inline void sink_levelled(const double *v, int from, int to, double vt, double *mean, double *spread)
{
    double sum = 0.0, lo = v[from], hi = v[from];
    for (int f = from; f <= to; f++) sum += v[f], lo = fmin(lo, v[f]), hi = fmax(hi, v[f]);
    *mean = sum / (to - from + 1) / vt;
    *spread = (hi - lo) / vt;
}

#endif
