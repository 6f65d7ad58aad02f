/* Benchmark: the cohesion tables (src/wet/cohesion.c) at resolutions 64² to 1024², hair–hair and hair–solid, contact
 * angle 40°, default ranges: build time (with every thread and with one), and the error of the table's F̃ against a
 * central difference of the closed-form energy at constant area (α by bisection), at the same random points for
 * every resolution: points where a bridge exists and whose four nodes hold bridges in every table (the tables'
 * interior, wet.h): 2,000 over the whole range outside the corner of nearly touching solids and vanishing bridges
 * (Ã < 0.2, d̃ < d̃_min + 0.5, where F̃ diverges), 300 in that corner.
 *
 * Usage: bench_cohesion [out.csv]   (default out/bench/cohesion.csv; parent directories are created)
 * CSV header: shape,resolution,threads,seconds,seconds_one_thread,mean_error,max_error,max_error_corner,points,
 *             points_corner
 * Errors are |F̃_table − F̃| / max(|F̃|, 1). A markdown table of the same rows goes to stdout. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "wet/wet.h"

#define NRES 5
#define POINTS 2000
#define CORNER_POINTS 300
static const int resolutions[NRES] = {64, 128, 256, 512, 1024};

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

/* ---- the direct reference (as tests/unit/test_cohesion.c) ---------------------------------------------------- */

static double touching(DrCohesionShape s) { return s == DR_COHESION_CYLINDERS ? 2.0 : 1.0; }

static double alpha0(DrCohesionShape s, double theta, double d)
{
    if (dr_cohesion_geometry(s, theta, 0.0, d, NULL, NULL)) return 0.0;
    double lo = 0.0, hi = DR_PI - theta;
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (lo + hi);
        if (mid <= lo || mid >= hi) break;
        if (dr_cohesion_geometry(s, theta, mid, d, NULL, NULL))
            hi = mid;
        else
            lo = mid;
    }
    return hi;
}

static double area_at(DrCohesionShape s, double theta, double a, double d)
{
    double A = NAN;
    dr_cohesion_geometry(s, theta, a, d, &A, NULL);
    return A;
}

static bool exists(DrCohesionShape s, double theta, double d, double A)
{
    return A > area_at(s, theta, alpha0(s, theta, d), d) && A <= area_at(s, theta, DR_PI - theta, d);
}

static double energy(DrCohesionShape s, double theta, double d, double A)
{
    double lo = alpha0(s, theta, d), hi = DR_PI - theta;
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (lo + hi);
        if (mid <= lo || mid >= hi) break;
        if (area_at(s, theta, mid, d) < A)
            lo = mid;
        else
            hi = mid;
    }
    double area, E = NAN;
    dr_cohesion_geometry(s, theta, 0.5 * (lo + hi), d, &area, &E);
    return E;
}

static double force(DrCohesionShape s, double theta, double d, double A)
{
    const double h = 1e-6;
    return (energy(s, theta, d + h, A) - energy(s, theta, d - h, A)) / (2.0 * h);
}

/* The four nodes around (d, A) of a table of this desc hold bridges (the grid of wet.h). */
static bool interior(const DrCohesionDesc *desc, double d, double A)
{
    const int n = desc->resolution;
    int i = (int)(sqrt((d - touching(desc->shape)) / desc->max_gap) * (n - 1));
    int j = (int)(sqrt(A / desc->max_area) * (n - 1));
    if (i < 0 || j < 0 || i > n - 2 || j > n - 2) return false;
    for (int k = 0; k < 4; k++) {
        double s = (double)(i + k / 2) / (n - 1), q = (double)(j + k % 2) / (n - 1);
        if (!exists(desc->shape, desc->contact_angle, touching(desc->shape) + desc->max_gap * s * s,
                    desc->max_area * q * q))
            return false;
    }
    return true;
}

/* ---- one shape ----------------------------------------------------------------------------------------------- */

static int bench_shape(DrCohesionShape shape, FILE *csv)
{
    const char *name = shape == DR_COHESION_CYLINDERS ? "cylinders" : "plane";
    const double theta = 40.0 * DR_PI / 180.0;
    DrCohesionTable *t[NRES] = {0};
    double seconds[NRES], seconds1[NRES];
    DrError err;
    const int threads = dr_threads();
    for (int r = 0; r < NRES; r++) {
        DrCohesionDesc d;
        dr_cohesion_desc_default(&d);
        d.shape = shape;
        d.contact_angle = theta;
        d.resolution = resolutions[r];
        DrCohesionTable *one = NULL;
        dr_set_threads(1);
        double t0 = dr_time_now();
        DrStatus s = dr_cohesion_build(&d, &one, &err);
        seconds1[r] = dr_time_now() - t0;
        dr_cohesion_destroy(&one);
        dr_set_threads(threads);
        t0 = dr_time_now();
        if (s == DR_OK) s = dr_cohesion_build(&d, &t[r], &err);
        seconds[r] = dr_time_now() - t0;
        if (s != DR_OK) {
            fprintf(stderr, "bench_cohesion: %s\n", err.message);
            for (int k = 0; k < NRES; k++) dr_cohesion_destroy(&t[k]);
            return 1;
        }
    }

    /* POINTS over the whole (d̃, Ã) box outside the corner, CORNER_POINTS in the corner box */
    double sum[NRES] = {0}, max[NRES] = {0}, max_corner[NRES] = {0};
    int points = 0, corner = 0;
    DrRng rng;
    dr_rng_seed(&rng, 2024);
    const DrCohesionDesc *d0 = dr_cohesion_desc(t[0]);
    while (points < POINTS || corner < CORNER_POINTS) {
        bool want_corner = points >= POINTS;
        double d = touching(shape) + dr_rng_uniform(&rng) * (want_corner ? 0.5 : d0->max_gap);
        double A = dr_rng_uniform(&rng) * (want_corner ? 0.2 : d0->max_area);
        bool in_corner = A < 0.2 && d < touching(shape) + 0.5;
        if (in_corner != want_corner) continue;
        bool inside = exists(shape, theta, d, A);
        for (int r = 0; r < NRES && inside; r++) inside = interior(dr_cohesion_desc(t[r]), d, A);
        if (!inside) continue;
        double F = force(shape, theta, d, A);
        for (int r = 0; r < NRES; r++) {
            double e = fabs(dr_cohesion_eval(t[r], d, A) - F) / fmax(fabs(F), 1.0);
            if (in_corner) {
                max_corner[r] = fmax(max_corner[r], e);
            } else {
                max[r] = fmax(max[r], e);
                sum[r] += e;
            }
        }
        if (in_corner)
            corner++;
        else
            points++;
    }
    for (int r = 0; r < NRES; r++) {
        double mean = sum[r] / points;
        fprintf(csv, "%s,%d,%d,%.6f,%.6f,%.3e,%.3e,%.3e,%d,%d\n", name, resolutions[r], threads, seconds[r],
                seconds1[r], mean, max[r], max_corner[r], points, corner);
        printf("| %s | %d² | %.3f | %.3f | %.2e | %.2e | %.2e |\n", name, resolutions[r], seconds[r], seconds1[r],
               mean, max[r], max_corner[r]);
        dr_cohesion_destroy(&t[r]);
    }
    return 0;
}

int main(int argc, char **argv)
{
    const char *path = argc > 1 ? argv[1] : "out/bench/cohesion.csv";
    if (make_parent_dirs(path) != 0) {
        fprintf(stderr, "bench_cohesion: cannot create the directories of %s: %s\n", path, strerror(errno));
        return 1;
    }
    FILE *csv = fopen(path, "w");
    if (!csv) {
        fprintf(stderr, "bench_cohesion: cannot write %s: %s\n", path, strerror(errno));
        return 1;
    }
    dr_log_set_level(DR_LOG_WARN);
    fprintf(csv, "shape,resolution,threads,seconds,seconds_one_thread,mean_error,max_error,max_error_corner,points,"
                 "points_corner\n");
    printf("| shape | table | seconds | seconds (1 thread) | mean error | max error | max error, corner |\n");
    printf("| --- | ---: | ---: | ---: | ---: | ---: | ---: |\n");
    int rc = bench_shape(DR_COHESION_CYLINDERS, csv);
    if (rc == 0) rc = bench_shape(DR_COHESION_PLANE, csv);
    if (fclose(csv) != 0) {
        fprintf(stderr, "bench_cohesion: error closing %s: %s\n", path, strerror(errno));
        return 1;
    }
    if (rc == 0)
        printf("\ncontact angle 40°, default ranges; per shape %d points over the whole range and %d in the corner "
               "(area < 0.2 r², gap < 0.5 r above touching), each with a bridge at the four nodes around it in every "
               "table; errors |table - exact| / max(|exact|, 1), the exact force a central difference of "
               "the closed-form energy at constant area. threads: %d; CSV written to %s\n",
               POINTS, CORNER_POINTS, dr_threads(), path);
    return rc;
}
