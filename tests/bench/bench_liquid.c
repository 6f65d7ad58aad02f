/* Liquid benchmark: dam break at 64³ and 128³ cells for N substeps (per-phase seconds, particles, PCG
 * iterations) and a run-time-versus-error sweep of the dam-break front at t = 0.25 s.
 * usage: bench_liquid [csv = out/bench/liquid.csv] [substeps = 5] */
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "liquid/liquid.h"

static DrLiquid *dam_break(double dx, DrVec3 hi, DrVec3 water_hi)
{
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = hi;
    d.dx = dx;
    d.max_substeps = 1000;
    DrBoxVel water = {dr_v3(0, 0, 0), water_hi, dr_v3(0, 0, 0), 0, 0};
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    DrLiquid *liq = NULL;
    DrError err;
    if (dr_liquid_create(&d, NULL, 0, &liq, &err) != DR_OK) {
        dr_error_print("bench_liquid", &err);
        exit(1);
    }
    return liq;
}

static double front(const DrLiquid *liq)
{
    const DrLiquidState *s = dr_liquid_state(liq);
    double f = 0;
    for (long p = 0; p < s->n; p++) f = fmax(f, s->x[3 * p]);
    return f;
}

int main(int argc, char **argv)
{
    const char *csv = argc > 1 ? argv[1] : "out/bench/liquid.csv";
    int nsub = argc > 2 ? atoi(argv[2]) : 5;
    if (nsub < 1) nsub = 1;
    mkdir("out", 0755);
    mkdir("out/bench", 0755);
    FILE *f = fopen(csv, "w");
    if (!f) { fprintf(stderr, "bench_liquid: cannot write %s\n", csv); return 1; }
    fprintf(f, "cells,particles,substeps,seconds_per_substep,p2g,pressure,g2p,advect,other,pcg_iter_mean,pcg_iter_max\n");
    printf("| grid | particles | substeps | s/substep | P2G | pressure | G2P | advect | other | PCG it. mean | max |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|\n");
    int res[2] = {64, 128};
    for (int r = 0; r < 2; r++) {
        DrLiquid *liq = dam_break(1.0 / res[r], dr_v3(1, 1, 1), dr_v3(0.4, 0.6, 1.0));
        DrLiquidStats tot;
        memset(&tot, 0, sizeof tot);
        double t = 0, t0 = dr_time_now();
        for (int s = 0; s < nsub; s++) {
            /* one CFL-sized substep per call: 0.5·dx/√(5 dx g) bounds dt here */
            double dt = 0.5 * (1.0 / res[r]) / sqrt(5.0 / res[r] * 9.81);
            DrLiquidStats st;
            DrError err;
            if (dr_liquid_advance(liq, NULL, 0, t, t + dt, &st, &err) < 0) { dr_error_print("bench_liquid", &err); return 1; }
            t += dt;
            tot.substeps += st.substeps;
            tot.seconds_p2g += st.seconds_p2g; tot.seconds_pressure += st.seconds_pressure;
            tot.seconds_g2p += st.seconds_g2p; tot.seconds_advect += st.seconds_advect; tot.seconds_other += st.seconds_other;
            tot.pressure_iterations_total += st.pressure_iterations_total;
            if (st.pressure_iterations_max > tot.pressure_iterations_max) tot.pressure_iterations_max = st.pressure_iterations_max;
            tot.particles = st.particles;
        }
        double wall = dr_time_now() - t0, ns = tot.substeps;
        fprintf(f, "%d,%ld,%d,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.1f,%d\n", res[r], tot.particles, tot.substeps, wall / ns,
                tot.seconds_p2g / ns, tot.seconds_pressure / ns, tot.seconds_g2p / ns, tot.seconds_advect / ns,
                tot.seconds_other / ns, tot.pressure_iterations_total / ns, tot.pressure_iterations_max);
        printf("| %d³ | %ld | %d | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.1f | %d |\n", res[r], tot.particles,
               tot.substeps, wall / ns, tot.seconds_p2g / ns, tot.seconds_pressure / ns, tot.seconds_g2p / ns,
               tot.seconds_advect / ns, tot.seconds_other / ns, tot.pressure_iterations_total / ns,
               tot.pressure_iterations_max);
        dr_liquid_destroy(&liq);
    }
    fclose(f);

    /* run time vs error: front position at t = 0.25 s, thin 1 × 0.5 × 0.125 m tank, against dx = 1/64 */
    FILE *e = fopen("out/bench/liquid_error.csv", "w");
    if (!e) { fprintf(stderr, "bench_liquid: cannot write out/bench/liquid_error.csv\n"); return 1; }
    fprintf(e, "cells_per_m,seconds,front_m,abs_error_m\n");
    int sweep[4] = {64, 16, 24, 32};
    double ref = 0;
    printf("\n| cells/m | seconds | front at 0.25 s (m) | error vs 1/64 (m) |\n|---|---|---|---|\n");
    for (int r = 0; r < 4; r++) {
        DrLiquid *liq = dam_break(1.0 / sweep[r], dr_v3(1, 0.5, 0.125), dr_v3(0.25, 0.375, 0.125));
        double t0 = dr_time_now();
        for (int k = 0; k < 10; k++) {
            DrLiquidStats st;
            DrError err;
            if (dr_liquid_advance(liq, NULL, 0, k * 0.025, (k + 1) * 0.025, &st, &err) < 0) { dr_error_print("bench_liquid", &err); return 1; }
        }
        double secs = dr_time_now() - t0, fr = front(liq);
        if (r == 0) ref = fr;
        fprintf(e, "%d,%.4f,%.5f,%.5f\n", sweep[r], secs, fr, fabs(fr - ref));
        printf("| %d | %.2f | %.4f | %.4f |\n", sweep[r], secs, fr, fabs(fr - ref));
        dr_liquid_destroy(&liq);
    }
    fclose(e);
    return 0;
}
