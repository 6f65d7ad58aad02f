/* Bodies in the liquid's projection (dr_liquid_set_bodies): run time against error. A sphere of radius 0.08 m held
 * 0.09 m under the surface of a 0.32 m deep tank of still water; after two settling substeps the mean force the
 * pressure gives it over ten more, against Archimedes' ρgV, at 2.5 to 16 cells per radius, ghost-fluid and
 * mass-weighted pressure. Each row: formulation, Δx, cells per radius, force/(ρgV), |error|, wall seconds of the
 * twelve substeps (2 threads as set by the environment), pressure cells. Writes the CSV given as argv[1] (default
 * out/bench/bodies.csv) and a markdown table. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "liquid/liquid.h"

static void die(const char *what, const DrError *err)
{
    if (err) dr_error_print("bench_bodies", err);
    else fprintf(stderr, "bench_bodies: %s\n", what);
    exit(1);
}

static DrCollider *make_sphere(DrVec3 center, double r, double h)
{
    int n = (int)ceil(2 * r / h) + 9;
    DrVec3 o = dr_v3(-0.5 * (n - 1) * h, -0.5 * (n - 1) * h, -0.5 * (n - 1) * h);
    float *phi = malloc(sizeof(float) * (size_t)n * n * n);
    if (!phi) die("out of memory", NULL);
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++)
                phi[i + n * (j + n * k)] = (float)(dr_v3_norm(dr_v3_add(o, dr_v3(i * h, j * h, k * h))) - r);
    double keys[14] = {0.0, center.x, center.y, center.z, 0, 0, 0, 1e3, center.x, center.y, center.z, 0, 0, 0};
    DrColliderDesc cd = {phi, n, n, n, o, h, 0.0, false, 0.0, 2, keys};
    DrCollider *c = NULL;
    DrError err;
    if (dr_collider_create(&cd, &c, &err) < 0) die(NULL, &err);
    free(phi);
    return c;
}

int main(int argc, char **argv)
{
    const char *csv = argc > 1 ? argv[1] : "out/bench/bodies.csv";
    mkdir("out", 0755);
    mkdir("out/bench", 0755);
    FILE *f = fopen(csv, "w");
    if (!f) die("cannot write the CSV", NULL);
    fprintf(f, "formulation,dx,cells_per_radius,ratio,error,seconds,cells\n");
    printf("| pressure | dx (m) | cells per radius | force / (rho g V) | error | seconds (12 substeps) | pressure cells |\n");
    printf("|---|---|---|---|---|---|---|\n");
    const double r = 0.08, H = 0.32;
    const DrVec3 c = dr_v3(0.2, 0.15, 0.2);
    const double dxs[4] = {0.032, 0.02, 0.01, 0.005};
    for (int form = 0; form < 2; form++)
        for (int q = 0; q < 4; q++) {
            double dx = dxs[q];
            DrLiquidDesc d;
            dr_liquid_desc_default(&d);
            d.dx = dx;
            d.pressure = form ? DR_PRESSURE_MASS_WEIGHTED : DR_PRESSURE_GHOST_FLUID;
            d.pressure_tol = 1e-10;
            d.domain_lo = dr_v3(0, 0, 0);
            d.domain_hi = dr_v3(0.4, H + 0.1, 0.4);
            DrBoxVel water = {dr_v3(0, 0, 0), dr_v3(0.4, H, 0.4), dr_v3(0, 0, 0), 0, 0};
            d.nsource_boxes = 1;
            d.source_boxes = &water;
            DrCollider *ball = make_sphere(c, r, 0.5 * dx);
            const DrCollider *cols[1] = {ball};
            DrLiquid *liq = NULL;
            DrError err;
            if (dr_liquid_create(&d, cols, 1, &liq, &err) < 0) die(NULL, &err);
            DrLiquidStats st;
            memset(&st, 0, sizeof st);
            double t = 0.0, sum = 0.0, span = 0.0, t0 = dr_time_now();
            for (int s = 0; s < 12; s++) {
                double h;
                if (dr_liquid_stable_dt(liq, cols, 1, t, 1.0, &h, &err) < 0) die(NULL, &err);
                h = fmin(h, 0.01);
                if (dr_liquid_begin(liq, cols, 1, t, h, &err) < 0) die(NULL, &err);
                DrLiquidBody b = {.collider = ball, .center = {c.x, c.y, c.z}};
                if (dr_liquid_set_bodies(liq, &b, 1, &err) < 0 || dr_liquid_project(liq, NULL, &st, &err) < 0)
                    die(NULL, &err);
                if (s >= 2) {
                    sum += b.impulse[1];
                    span += h;
                }
                if (dr_liquid_end(liq, &st, &err) < 0) die(NULL, &err);
                t += h;
            }
            double seconds = dr_time_now() - t0;
            double ratio = sum / span / (d.density * 9.81 * 4.0 / 3.0 * DR_PI * r * r * r);
            const char *name = form ? "mass_weighted" : "ghost_fluid";
            fprintf(f, "%s,%g,%g,%.6f,%.6f,%.3f,%ld\n", name, dx, r / dx, ratio, fabs(ratio - 1.0), seconds,
                    st.liquid_cells);
            printf("| %s | %g | %.1f | %.5f | %.2e | %.2f | %ld |\n", name, dx, r / dx, ratio, fabs(ratio - 1.0), seconds,
                   st.liquid_cells);
            fflush(stdout);
            dr_liquid_destroy(&liq);
            dr_collider_destroy(&ball);
        }
    fclose(f);
    return 0;
}
