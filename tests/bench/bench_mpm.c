/* Benchmark: run time against error for the MPM solver on the rotating disk of [APIC] §6.1 (R 0.3,
 * ω 0.4, ρ 2, Neo-Hookean E 1e3 ν 0.3, 2×2 particles per cell) at 16², 32² and 64² cells, for each
 * transfer scheme (APIC, PIC, FLIP) and integrator (symplectic Euler, midpoint, backward Euler) and three
 * step sizes, over 0.5 s (12 frames).
 *
 * Step sizes. The implicit integrators take the §4.3 CFL step with ν = 1, 0.5, 0.25, capped at ν frames
 * (the disk is slow: §4.3 allows ~0.2 s, more than a frame, so without the cap ν would not change Δt).
 * §4.3's bound ignores elastic waves, which symplectic Euler must resolve: it takes ν·Δx/c with the
 * dilatational speed c = √((λ+2μ)/ρ) = 25.9 m/s, ν = 0.5, 0.25, 0.125 (ν = 1 is past its stability limit
 * and diverges, which the stress test covers).
 *
 * Errors: angular momentum |L(0.5 s)/L(0) − 1| (the exact solution keeps it) and energy |E/E(0) − 1|
 * (kinetic + elastic; the exact solution keeps it too).
 *
 * Usage: bench_mpm [out.csv]   (default out/bench/mpm.csv)
 * CSV header: cells,scheme,integrator,nu,dt,steps,particles,seconds,newton,cg,L_error,E_error
 * A markdown table of the same rows goes to stdout. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "mpm/mpm.h"

static bool in_disk(DrVec3 x, void *ctx)
{
    (void)ctx;
    return (x.x - 0.5) * (x.x - 0.5) + (x.y - 0.5) * (x.y - 0.5) < 0.09;
}

static int make_parent_dirs(const char *path)
{
    char buf[4096];
    if (strlen(path) >= sizeof buf) return -1;
    strcpy(buf, path);
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/') continue;
        *p = '\0';
        if (mkdir(buf, 0777) != 0 && errno != EEXIST) return -1;
        *p = '/';
    }
    return 0;
}

int main(int argc, char **argv)
{
    const char *path = argc > 1 ? argv[1] : "out/bench/mpm.csv";
    if (make_parent_dirs(path) != 0) {
        fprintf(stderr, "bench_mpm: cannot create the folder of %s\n", path);
        return 1;
    }
    FILE *csv = fopen(path, "w");
    if (!csv) {
        fprintf(stderr, "bench_mpm: cannot write %s\n", path);
        return 1;
    }
    fprintf(csv, "cells,scheme,integrator,nu,dt,steps,particles,seconds,newton,cg,L_error,E_error\n");
    printf("| cells | scheme | integrator | ν | Δt (s) | steps | particles | seconds | Newton | CG | \\|ΔL\\|/L | \\|ΔE\\|/E |\n");
    printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    const int cells[3] = {16, 32, 64};
    const DrTransferScheme schemes[3] = {DR_TRANSFER_APIC, DR_TRANSFER_PIC, DR_TRANSFER_FLIP};
    const char *sname[3] = {"APIC", "PIC", "FLIP"};
    const DrMpmIntegrator ints[3] = {DR_MPM_SYMPLECTIC_EULER, DR_MPM_MIDPOINT, DR_MPM_BACKWARD_EULER};
    const char *iname[3] = {"symplectic_euler", "midpoint", "backward_euler"};
    const double nus[3] = {1.0, 0.5, 0.25};
    const double c = sqrt((1000.0 / 2.6 * 2.0 + 1000.0 * 0.3 / (1.3 * 0.4)) / 2.0);
    int status = 0;
    for (int ci = 0; ci < 3; ci++)
        for (int si = 0; si < 3; si++)
            for (int ii = 0; ii < 3; ii++)
                for (int ni = 0; ni < 3; ni++) {
                    DrMpmDesc d;
                    dr_mpm_desc_default(&d);
                    d.dim = 2;
                    d.hi = dr_v3(1, 1, 0);
                    d.dx = 1.0 / cells[ci];
                    d.scheme = schemes[si];
                    d.integrator = ints[ii];
                    d.cfl = nus[ni];
                    DrMpm *m = NULL;
                    DrError err;
                    long np = 0;
                    DrMpmMaterial mat = {DR_MPM_NEOHOOKEAN, 2.0, 1000.0, 0.3};
                    if (dr_mpm_create(&d, &m, &err) != DR_OK ||
                        dr_mpm_sample_body(m, in_disk, NULL, dr_v3(0.2, 0.2, 0), dr_v3(0.8, 0.8, 0), 2, dr_v3(0, 0, 0),
                                           dr_v3(0, 0, 0.4), dr_v3(0.5, 0.5, 0), &mat, NULL, &np, &err) != DR_OK) {
                        dr_error_print("bench_mpm", &err);
                        return 1;
                    }
                    DrMpmTotals t0 = dr_mpm_totals(m, -1);
                    double E0 = t0.kinetic + t0.elastic, L0 = t0.angular.z;
                    long steps = 0, newton = 0, cg = 0;
                    double dt_used = 0, t_start = dr_time_now();
                    DrStatus rc = DR_OK;
                    for (int f = 0; f < 12 && rc >= 0; f++) {
                        DrMpmStats st;
                        if (ints[ii] == DR_MPM_SYMPLECTIC_EULER) {
                            double dtx = 0.5 * nus[ni] * d.dx / c;
                            int k = (int)ceil(1.0 / 24.0 / dtx);
                            dt_used = 1.0 / 24.0 / k;
                            for (int s = 0; s < k && rc >= 0; s++) rc = dr_mpm_step(m, dt_used, &st, &err);
                            steps += k;
                        } else {
                            double dtt = fmin(dr_mpm_cfl_dt(m), nus[ni] / 24.0);
                            int k = (int)ceil(1.0 / 24.0 / dtt - 1e-9);
                            dt_used = 1.0 / 24.0 / k;
                            for (int s = 0; s < k && rc >= 0; s++) {
                                rc = dr_mpm_step(m, dt_used, &st, &err);
                                newton += st.newton_iterations, cg += st.cg_iterations;
                            }
                            steps += k;
                        }
                    }
                    double secs = dr_time_now() - t_start;
                    DrMpmTotals t1 = dr_mpm_totals(m, -1);
                    double eL = fabs(t1.angular.z / L0 - 1), eE = fabs((t1.kinetic + t1.elastic) / E0 - 1);
                    double nu_print = ints[ii] == DR_MPM_SYMPLECTIC_EULER ? 0.5 * nus[ni] : nus[ni];
                    if (rc < 0) {
                        dr_error_print("bench_mpm", &err);
                        eL = eE = NAN;
                        status = 1;
                    }
                    fprintf(csv, "%d,%s,%s,%g,%.4e,%ld,%ld,%.4f,%ld,%ld,%.4e,%.4e\n", cells[ci], sname[si], iname[ii],
                            nu_print, dt_used, steps, np, secs, newton, cg, eL, eE);
                    printf("| %d | %s | %s | %g | %.2e | %ld | %ld | %.3f | %ld | %ld | %.2e | %.2e |\n", cells[ci],
                           sname[si], iname[ii], nu_print, dt_used, steps, np, secs, newton, cg, eL, eE);
                    fflush(stdout);
                    dr_mpm_destroy(&m);
                }
    fclose(csv);
    return status;
}
