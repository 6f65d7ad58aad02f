/* The cohesion tables of capillary bridges (src/wet/cohesion.c, contract in wet.h "cohesion tables").
 *
 * The reference every table is held to is computed here, independently of the table code: the bridge's energy at
 * constant area comes from the public closed forms (dr_cohesion_geometry) with α solved by bisection, and its
 * derivative in the gap by a central difference; the closed forms themselves are checked against a polygon traced
 * along the solids and the circular menisci. Random points use fixed seeds. Build times are printed, never asserted.
 * Scratch files live under $TMPDIR and are removed. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "wet/wet.h"

#include <hdf5.h>

#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static char g_dir[256]; /* scratch directory of this run */

static int group_setup(void **state)
{
    (void)state;
    dr_log_set_level(DR_LOG_ERROR);
    snprintf(g_dir, sizeof g_dir, "%s/drench_test_cohesion.XXXXXX", dr_temp_dir());
    return mkdtemp(g_dir) ? 0 : -1;
}

static int group_teardown(void **state)
{
    (void)state;
    char cmd[512];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    return system(cmd) == 0 ? 0 : -1;
}

static double deg(double d) { return d * DR_PI / 180.0; }

static double touching_gap(DrCohesionShape shape) { return shape == DR_COHESION_CYLINDERS ? 2.0 : 1.0; }

static DrCohesionTable *build(DrCohesionShape shape, double theta, int resolution, double *seconds)
{
    DrCohesionDesc d;
    dr_cohesion_desc_default(&d);
    d.shape = shape;
    d.contact_angle = theta;
    d.resolution = resolution;
    DrCohesionTable *t = NULL;
    DrError err;
    double t0 = dr_time_now();
    DrStatus s = dr_cohesion_build(&d, &t, &err);
    if (seconds) *seconds = dr_time_now() - t0;
    if (s != DR_OK) fprintf(stderr, "%s\n", err.message);
    assert_int_equal(s, DR_OK);
    assert_non_null(t);
    return t;
}

/* ---- the direct reference ------------------------------------------------------------------------------------ */

/* The pinch-off angle: the smallest α at which the closed forms have a bridge (bisection on their answer). */
static double direct_alpha0(DrCohesionShape shape, double theta, double d)
{
    if (dr_cohesion_geometry(shape, theta, 0.0, d, NULL, NULL)) return 0.0;
    double lo = 0.0, hi = DR_PI - theta;
    assert_true(dr_cohesion_geometry(shape, theta, hi, d, NULL, NULL));
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (lo + hi);
        if (mid <= lo || mid >= hi) break;
        if (dr_cohesion_geometry(shape, theta, mid, d, NULL, NULL))
            hi = mid;
        else
            lo = mid;
    }
    return hi;
}

static double area_at(DrCohesionShape shape, double theta, double a, double d)
{
    double A = NAN, E;
    assert_true(dr_cohesion_geometry(shape, theta, a, d, &A, &E));
    return A;
}

/* Whether a bridge of area A exists at gap d: between the pinch-off area and the area at α = π − θ. */
static bool direct_exists(DrCohesionShape shape, double theta, double d, double A)
{
    double a0 = direct_alpha0(shape, theta, d);
    return A > area_at(shape, theta, a0, d) && A <= area_at(shape, theta, DR_PI - theta, d);
}

/* α of the bridge of area A at gap d, by bisection on [α_0, π − θ]. */
static double direct_alpha(DrCohesionShape shape, double theta, double d, double A)
{
    double lo = direct_alpha0(shape, theta, d), hi = DR_PI - theta;
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (lo + hi);
        if (mid <= lo || mid >= hi) break;
        if (area_at(shape, theta, mid, d) < A)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

static double direct_energy(DrCohesionShape shape, double theta, double d, double A)
{
    double area, E = NAN;
    assert_true(dr_cohesion_geometry(shape, theta, direct_alpha(shape, theta, d, A), d, &area, &E));
    return E;
}

/* ∂E/∂d at constant A by a central difference, δ = 1e-6 r: truncation ~δ² E''' ≈ 1e-12, round-off ~ε E/δ ≈ 1e-9. */
static double direct_force(DrCohesionShape shape, double theta, double d, double A)
{
    const double h = 1e-6;
    return (direct_energy(shape, theta, d + h, A) - direct_energy(shape, theta, d - h, A)) / (2.0 * h);
}

/* The error measure: relative to max(|F̃|, 1). F̃ changes sign on the engulfing branch, where a relative error means
 * nothing; 1 is σ, the scale of the force (a bridge pulls with 2σ as it pinches off). */
static double force_error(double table, double exact) { return fabs(table - exact) / fmax(fabs(exact), 1.0); }

/* The table's grid as wet.h documents it: node (i, j) of a resolution-n table. */
static double node_gap(const DrCohesionDesc *d, int i)
{
    double s = (double)i / (d->resolution - 1);
    return touching_gap(d->shape) + d->max_gap * (s * s);
}

static double node_area(const DrCohesionDesc *d, int j)
{
    double s = (double)j / (d->resolution - 1);
    return d->max_area * (s * s);
}

/* True when the four grid nodes around (d, A) hold bridges (by the closed forms): the table's interior, where
 * bilinear interpolation is second order. */
static bool in_interior(const DrCohesionDesc *desc, double d, double A)
{
    const int n = desc->resolution;
    int i = (int)(sqrt((d - touching_gap(desc->shape)) / desc->max_gap) * (n - 1));
    int j = (int)(sqrt(A / desc->max_area) * (n - 1));
    if (i < 0 || j < 0 || i > n - 2 || j > n - 2) return false;
    for (int di = 0; di < 2; di++)
        for (int dj = 0; dj < 2; dj++)
            if (!direct_exists(desc->shape, desc->contact_angle, node_gap(desc, i + di), node_area(desc, j + dj)))
                return false;
    return true;
}

/* ---- acceptance: table against direct geometry --------------------------------------------------------------- */

typedef struct Accuracy {
    double max256, mean256, max512, mean512;
    int points, tries;
} Accuracy;

/* n random off-grid points inside the interior of both tables, uniform over the (d̃, Ã) box. */
static Accuracy accuracy(DrCohesionShape shape, double theta, int n, uint64_t seed)
{
    double s256, s512;
    DrCohesionTable *t256 = build(shape, theta, 256, &s256), *t512 = build(shape, theta, 512, &s512);
    const DrCohesionDesc *d256 = dr_cohesion_desc(t256), *d512 = dr_cohesion_desc(t512);
    Accuracy acc = {0};
    DrRng rng;
    dr_rng_seed(&rng, seed);
    while (acc.points < n) {
        acc.tries++;
        double d = touching_gap(shape) + dr_rng_uniform(&rng) * d256->max_gap;
        double A = dr_rng_uniform(&rng) * d256->max_area;
        if (!in_interior(d256, d, A) || !in_interior(d512, d, A)) continue;
        double F = direct_force(shape, theta, d, A);
        double e256 = force_error(dr_cohesion_eval(t256, d, A), F);
        double e512 = force_error(dr_cohesion_eval(t512, d, A), F);
        acc.max256 = fmax(acc.max256, e256);
        acc.max512 = fmax(acc.max512, e512);
        acc.mean256 += e256;
        acc.mean512 += e512;
        acc.points++;
    }
    acc.mean256 /= n;
    acc.mean512 /= n;
    printf("# %s theta %2.0f deg: build 256^2 %.3f s, 512^2 %.3f s; %d points (%d drawn); error 256^2 max %.2e mean "
           "%.2e, 512^2 max %.2e mean %.2e; mean ratio %.2f\n",
           shape == DR_COHESION_CYLINDERS ? "cylinders" : "plane", theta * 180 / DR_PI, s256, s512, acc.points,
           acc.tries, acc.max256, acc.mean256, acc.max512, acc.mean512, acc.mean256 / acc.mean512);
    dr_cohesion_destroy(&t256);
    dr_cohesion_destroy(&t512);
    return acc;
}

/* Within 1 % everywhere; second order: the mean error (over the same points) falls by about 4 when the resolution
 * doubles (the largest error is not used for the ratio: where it falls inside its cell moves with the grid). */
static void check_accuracy(DrCohesionShape shape, double theta, int n, uint64_t seed)
{
    Accuracy acc = accuracy(shape, theta, n, seed);
    assert_true(acc.max256 < 0.01);
    assert_true(acc.max512 < 0.01);
    double ratio = acc.mean256 / acc.mean512;
    assert_true(ratio > 3.5 && ratio < 4.5);
}

static void test_cylinders_against_direct_geometry(void **state)
{
    (void)state;
    check_accuracy(DR_COHESION_CYLINDERS, deg(20), 1000, 20);
    check_accuracy(DR_COHESION_CYLINDERS, deg(40), 1000, 40);
    check_accuracy(DR_COHESION_CYLINDERS, deg(60), 1000, 60);
}

static void test_plane_against_direct_geometry(void **state)
{
    (void)state;
    check_accuracy(DR_COHESION_PLANE, deg(20), 300, 21);
    check_accuracy(DR_COHESION_PLANE, deg(40), 300, 41);
    check_accuracy(DR_COHESION_PLANE, deg(60), 300, 61);
}

/* The corner of touching solids and a vanishing bridge, where F̃ grows without bound (≈ 4 cos θ / α as α → 0): every
 * interior cell centre of the 256² table within the first 60 columns and 30 rows (gaps up to 1.1 r, areas up to 3 r²)
 * is within 1 % unless it lies in the corner Ã < 0.2, d̃ < d̃_min + 0.5 (wet.h), and within 15 % there. Cell centres
 * are the points farthest from the nodes. */
static void check_corner(DrCohesionShape shape, double theta)
{
    DrCohesionTable *t = build(shape, theta, 256, NULL);
    const DrCohesionDesc *desc = dr_cohesion_desc(t);
    double worst_in = 0.0, worst_out = 0.0;
    int cells = 0;
    for (int i = 0; i < 60; i++)
        for (int j = 0; j < 30; j++) {
            bool nodes = true;
            for (int k = 0; k < 4 && nodes; k++)
                nodes = direct_exists(shape, theta, node_gap(desc, i + k / 2), node_area(desc, j + k % 2));
            if (!nodes) continue;
            double s = (i + 0.5) / 255.0, q = (j + 0.5) / 255.0;
            double d = touching_gap(shape) + desc->max_gap * s * s, A = desc->max_area * q * q;
            if (!direct_exists(shape, theta, d, A)) continue;
            double e = force_error(dr_cohesion_eval(t, d, A), direct_force(shape, theta, d, A));
            bool corner = A < 0.2 && d < touching_gap(shape) + 0.5;
            if (corner)
                worst_in = fmax(worst_in, e);
            else
                worst_out = fmax(worst_out, e);
            cells++;
        }
    printf("# corner %s theta %2.0f: %d cells, largest error %.2e in the corner, %.2e outside it\n",
           shape == DR_COHESION_CYLINDERS ? "cylinders" : "plane", theta * 180 / DR_PI, cells, worst_in, worst_out);
    assert_true(cells > 1000);
    assert_true(worst_out < 0.01);
    assert_true(worst_in < 0.15);
    dr_cohesion_destroy(&t);
}

static void test_corner_of_touching_solids(void **state)
{
    (void)state;
    check_corner(DR_COHESION_CYLINDERS, deg(40));
    check_corner(DR_COHESION_PLANE, deg(40));
}

/* A(α) increases on [α_0, π − θ] in every column of the 256² tables (the inverse the table is built on exists), at
 * 2,000 angles per column. */
static void check_monotone(DrCohesionShape shape, double theta)
{
    DrCohesionDesc desc;
    dr_cohesion_desc_default(&desc);
    desc.shape = shape;
    desc.contact_angle = theta;
    desc.max_gap = (1.0 + theta / 2.0) * sqrt(desc.max_area);
    for (int i = 0; i < desc.resolution; i++) {
        double d = node_gap(&desc, i), a0 = direct_alpha0(shape, theta, d), prev = -INFINITY;
        for (int k = 0; k <= 2000; k++) {
            double A = area_at(shape, theta, k == 2000 ? DR_PI - theta : a0 + (DR_PI - theta - a0) * k / 2000.0, d);
            assert_true(A > prev);
            prev = A;
        }
    }
}

static void test_columns_are_monotone(void **state)
{
    (void)state;
    for (int k = 0; k < 3; k++) {
        check_monotone(DR_COHESION_CYLINDERS, deg(20 + 20 * k));
        check_monotone(DR_COHESION_PLANE, deg(20 + 20 * k));
    }
}

/* The work of the table's force along a path at constant A between two gaps equals the energy difference of the
 * direct geometry, to 1e-3 of it. The path stays in the table's interior; trapezoids of 1e-4 r (the interpolant is
 * piecewise smooth, so their error is far below the tolerance). */
static void check_work(DrCohesionShape shape, double theta, double A, double d1, double d2)
{
    DrCohesionTable *t = build(shape, theta, 256, NULL);
    const int steps = (int)ceil((d2 - d1) / 1e-4);
    double W = 0.0, h = (d2 - d1) / steps;
    for (int k = 0; k <= steps; k++) {
        double d = d1 + k * h;
        if (k % 100 == 0) assert_true(in_interior(dr_cohesion_desc(t), d, A));
        W += (k == 0 || k == steps ? 0.5 : 1.0) * h * dr_cohesion_eval(t, d, A);
    }
    double dE = direct_energy(shape, theta, d2, A) - direct_energy(shape, theta, d1, A);
    printf("# work %s theta %2.0f: A %g, gap %g to %g: work %.8f, energy difference %.8f, relative %.1e\n",
           shape == DR_COHESION_CYLINDERS ? "cylinders" : "plane", theta * 180 / DR_PI, A, d1, d2, W, dE,
           fabs(W - dE) / fabs(dE));
    assert_true(fabs(W - dE) <= 1e-3 * fabs(dE));
    dr_cohesion_destroy(&t);
}

static void test_work_equals_energy_difference(void **state)
{
    (void)state;
    for (int k = 0; k < 3; k++) {
        double theta = deg(20 + 20 * k);
        check_work(DR_COHESION_CYLINDERS, theta, 2.0, 2.2, 5.0);
        check_work(DR_COHESION_CYLINDERS, theta, 50.0, 7.0, 14.0);
        check_work(DR_COHESION_PLANE, theta, 3.0, 1.2, 3.5);
    }
}

/* ---- the closed forms ------------------------------------------------------------------------------------------ */

/* The bridge traced as a polygon in the plane across the solids, at radius r: its area by the shoelace formula, its
 * menisci's length by summing segments, the wetted length on the solids. Independent of the closed forms: the arcs are
 * placed by their ends and their lowest (or highest) point. Enough segments that both are exact to ~1e-9. */
#define ARC 20000

typedef struct Polygon {
    double area, meniscus, wetted;
} Polygon;

static void shoelace_add(double *acc, double x0, double y0, double x1, double y1) { *acc += x0 * y1 - x1 * y0; }

/* A circular arc through p, q and m (m between them on the arc): its centre from the three points, then the points
 * at equal angles, with their contribution to the shoelace sum (from p, excluding q) and their length. */
static void arc(double px, double py, double mx, double my, double qx, double qy, double *shoe, double *len)
{
    double ax = mx - px, ay = my - py, bx = qx - px, by = qy - py;
    double D = 2.0 * (ax * by - ay * bx);
    double cx = px + (by * (ax * ax + ay * ay) - ay * (bx * bx + by * by)) / D;
    double cy = py + (ax * (bx * bx + by * by) - bx * (ax * ax + ay * ay)) / D;
    double R = hypot(px - cx, py - cy);
    double t0 = atan2(py - cy, px - cx), tm = atan2(my - cy, mx - cx), t1 = atan2(qy - cy, qx - cx);
    /* counter-clockwise from p: if m comes before q, that way; else clockwise */
    double dm = fmod(tm - t0 + 4 * DR_PI, 2 * DR_PI), dq = fmod(t1 - t0 + 4 * DR_PI, 2 * DR_PI);
    t1 = dm < dq ? t0 + dq : t0 - (2 * DR_PI - dq);
    double x = px, y = py;
    for (int k = 1; k <= ARC; k++) {
        double t = t0 + (t1 - t0) * k / ARC;
        double nx = k == ARC ? qx : cx + R * cos(t), ny = k == ARC ? qy : cy + R * sin(t);
        shoelace_add(shoe, x, y, nx, ny);
        *len += hypot(nx - x, ny - y);
        x = nx, y = ny;
    }
}

/* Two cylinders of radius r, centres (∓d/2, 0): upper half traced from the left cylinder's inner point, up its
 * surface to the contact line, along the meniscus (through its point on the axis of symmetry, at height y_c − R),
 * down the right cylinder, and back along the line of centres; doubled. */
static Polygon polygon_cylinders(double theta, double a, double d, double r)
{
    double w = 0.5 * (d - 2 * r * cos(a)), b = theta + a, R = w / cos(b), yc = r * sin(a) + R * sin(b);
    double shoe = 0.0, len = 0.0, x = -d / 2 + r, y = 0.0;
    for (int k = 1; k <= ARC; k++) {
        double t = a * k / ARC, nx = -d / 2 + r * cos(t), ny = r * sin(t);
        shoelace_add(&shoe, x, y, nx, ny);
        x = nx, y = ny;
    }
    arc(-w, r * sin(a), 0.0, yc - R, w, r * sin(a), &shoe, &len);
    x = w, y = r * sin(a);
    for (int k = 1; k <= ARC; k++) {
        double t = DR_PI - a + a * k / ARC, nx = d / 2 + r * cos(t), ny = r * sin(t);
        shoelace_add(&shoe, x, y, nx, ny);
        x = nx, y = ny;
    }
    shoelace_add(&shoe, x, y, -d / 2 + r, 0.0);
    Polygon p = {fabs(shoe), 2.0 * len, 4.0 * r * a};
    return p;
}

/* Cylinder of radius r with axis at height d over y = 0, right half: from the origin along the plane to the plane's
 * contact x_p, up the meniscus to the cylinder's contact line P, along the cylinder to its bottom, down to the
 * origin; doubled. The meniscus's middle point is found from its ends and its tangent at the plane (contact angle
 * θ): a circle through X tangent to (−cos θ, sin θ) there. */
static Polygon polygon_plane(double theta, double a, double d, double r)
{
    double Px = r * sin(a), Py = d - r * cos(a);
    double R = Py / (cos(theta) + cos(a + theta));
    double xp = Px + R * sin(a + theta) - R * sin(theta);
    /* the arc's centre lies on the normal of its tangent (−cos θ, sin θ) at X, at signed distance R; its middle
     * point halfway in angle between X (at 3π/2 − θ seen from the centre) and P (at α + θ + π/2) */
    double cx = xp + R * sin(theta), cy = R * cos(theta), tm = DR_PI + 0.5 * a;
    double mx = cx + R * cos(tm), my = cy + R * sin(tm);
    double shoe = 0.0, len = 0.0;
    shoelace_add(&shoe, 0.0, 0.0, xp, 0.0);
    arc(xp, 0.0, mx, my, Px, Py, &shoe, &len);
    double x = Px, y = Py;
    for (int k = 1; k <= ARC; k++) {
        double t = a - a * k / ARC, nx = r * sin(t), ny = d - r * cos(t);
        shoelace_add(&shoe, x, y, nx, ny);
        x = nx, y = ny;
    }
    shoelace_add(&shoe, x, y, 0.0, 0.0);
    Polygon p = {fabs(shoe), 2.0 * len, 2.0 * (r * a + xp)};
    return p;
}

/* The closed forms' area equals the polygon's, and their energy differences equal those of σ(l_A − l_wet cos θ)
 * (eq. S4 with l_S = perimeter − l_wet) from the polygon, at random angles and gaps, concave and convex menisci. And
 * the scaling claim: the polygon at radius r and at 2r (d scaled) has 4× the area and 2× the lengths, so its energy at
 * constant scaled area scales with r and the force σ ∂E/∂d does not change; dr_cohesion_force agrees at r and 2r. */
static void check_polygons(DrCohesionShape shape, double theta, uint64_t seed)
{
    DrRng rng;
    dr_rng_seed(&rng, seed);
    double max_area = 0.0, max_energy = 0.0;
    for (int n = 0; n < 40;) {
        double d = touching_gap(shape) + 6.0 * dr_rng_uniform(&rng);
        double a = dr_rng_uniform(&rng) * (DR_PI - theta), a2 = dr_rng_uniform(&rng) * (DR_PI - theta);
        double A, E, A2, E2;
        if (!dr_cohesion_geometry(shape, theta, a, d, &A, &E) || !dr_cohesion_geometry(shape, theta, a2, d, &A2, &E2))
            continue;
        if (fabs(theta + a - DR_PI / 2) < 1e-3 || fabs(theta + a2 - DR_PI / 2) < 1e-3) continue; /* flat meniscus */
        n++;
        Polygon p = shape == DR_COHESION_CYLINDERS ? polygon_cylinders(theta, a, d, 1.0)
                                                   : polygon_plane(theta, a, d, 1.0);
        Polygon p2 = shape == DR_COHESION_CYLINDERS ? polygon_cylinders(theta, a2, d, 1.0)
                                                    : polygon_plane(theta, a2, d, 1.0);
        max_area = fmax(max_area, fabs(A - p.area) / fmax(p.area, 1.0));
        double dE = (p2.meniscus - p2.wetted * cos(theta)) - (p.meniscus - p.wetted * cos(theta));
        max_energy = fmax(max_energy, fabs((E2 - E) - dE) / fmax(fabs(dE), 1.0));

        const double r = 50e-6;
        Polygon q = shape == DR_COHESION_CYLINDERS ? polygon_cylinders(theta, a, d * r, r)
                                                   : polygon_plane(theta, a, d * r, r);
        Polygon q2 = shape == DR_COHESION_CYLINDERS ? polygon_cylinders(theta, a, 2 * d * r, 2 * r)
                                                    : polygon_plane(theta, a, 2 * d * r, 2 * r);
        assert_true(fabs(q.area / (r * r) - p.area) <= 1e-8 * fmax(p.area, 1.0));
        assert_true(fabs(q2.area / (4 * r * r) - p.area) <= 1e-8 * fmax(p.area, 1.0));
        assert_true(fabs(q2.meniscus / (2 * r) - p.meniscus) <= 1e-8 * p.meniscus);
        assert_true(fabs(q2.wetted / (2 * r) - p.wetted) <= 1e-8 * fmax(p.wetted, 1.0));
    }
    printf("# closed forms against polygons (%s, theta %2.0f): area %.1e, energy difference %.1e\n",
           shape == DR_COHESION_CYLINDERS ? "cylinders" : "plane", theta * 180 / DR_PI, max_area, max_energy);
    assert_true(max_area < 1e-7);
    assert_true(max_energy < 1e-7);
}

static void test_closed_forms_against_polygons(void **state)
{
    (void)state;
    for (int k = 0; k < 3; k++) {
        check_polygons(DR_COHESION_CYLINDERS, deg(20 + 20 * k), 100 + k);
        check_polygons(DR_COHESION_PLANE, deg(20 + 20 * k), 200 + k);
    }
}

/* The force in SI units: σ F̃(d/r, A/r²). A bridge at radius 2r with gap and area scaled (2d, 4A) pulls as hard per
 * unit length as at r (the geometry is similar: above), and the force is proportional to σ. */
static void test_force_scales(void **state)
{
    (void)state;
    DrCohesionTable *t = build(DR_COHESION_CYLINDERS, deg(40), 128, NULL);
    const double r = 50e-6, sigma = 0.072;
    DrRng rng;
    dr_rng_seed(&rng, 5);
    int nonzero = 0;
    for (int n = 0; n < 1000; n++) {
        double d = (2.0 + 10.0 * dr_rng_uniform(&rng)) * r, A = 60.0 * dr_rng_uniform(&rng) * r * r;
        double F = dr_cohesion_force(t, r, sigma, d, A);
        double F2 = dr_cohesion_force(t, 2 * r, sigma, 2 * d, 4 * A);
        assert_true(fabs(F - F2) <= 1e-12 * fmax(fabs(F), sigma));
        assert_true(fabs(F - sigma * dr_cohesion_eval(t, d / r, A / (r * r))) <= 1e-15 * fmax(fabs(F), sigma));
        assert_true(fabs(dr_cohesion_force(t, r, 2 * sigma, d, A) - 2 * F) <= 1e-15 * fmax(fabs(F), sigma));
        nonzero += F != 0.0;
    }
    assert_true(nonzero > 500);
    dr_cohesion_destroy(&t);
}

/* The closed forms are analytic through the points where their helpers switch from series to direct formulas
 * (sinc and (z − sin z)/z³ at |z| = 0.5) and where a meniscus is flat (β = π/2, φ = 0): second differences across
 * each such point are as small as a smooth function's. Points out of [α_0, π − θ] are skipped. */
static int check_smooth_at(DrCohesionShape shape, double theta, double a)
{
    const double h = 1e-5, d = touching_gap(shape) + 0.02;
    if (a - h < direct_alpha0(shape, theta, d) || a + h > DR_PI - theta) return 0;
    double Am, A0, Ap, Em, E0, Ep;
    assert_true(dr_cohesion_geometry(shape, theta, a - h, d, &Am, &Em));
    assert_true(dr_cohesion_geometry(shape, theta, a, d, &A0, &E0));
    assert_true(dr_cohesion_geometry(shape, theta, a + h, d, &Ap, &Ep));
    /* h² f'' ≈ 1e-10 of the scale; a jump of 1e-9 between branches would show */
    assert_true(fabs(Ap - 2 * A0 + Am) < 1e-9 * fmax(fabs(A0), 1.0));
    assert_true(fabs(Ep - 2 * E0 + Em) < 1e-9 * fmax(fabs(E0), 1.0));
    return 1;
}

static void test_closed_forms_are_smooth(void **state)
{
    (void)state;
    int checked = 0;
    for (int k = 0; k < 3; k++) {
        double theta = deg(20 + 20 * k), flat = DR_PI / 2 - theta; /* α at which β = π/2 */
        const double gammas[] = {0.0, 0.25, -0.25, 0.5, -0.5};    /* γ = β − π/2: sinc(γ), s3(2γ) */
        for (int g = 0; g < 5; g++) checked += check_smooth_at(DR_COHESION_CYLINDERS, theta, flat + gammas[g]);
        checked += check_smooth_at(DR_COHESION_CYLINDERS, theta, 0.25); /* s3(2α) */
        const double phis[] = {0.0, 0.5, -0.5, 1.0, -1.0};              /* φ = π − α − 2θ: s3(φ), sinc(φ/2) */
        for (int f = 0; f < 5; f++) checked += check_smooth_at(DR_COHESION_PLANE, theta, DR_PI - 2 * theta - phis[f]);
        checked += check_smooth_at(DR_COHESION_PLANE, theta, 0.5); /* s3(α) */
    }
    assert_true(checked >= 30);
}

/* What the closed forms refuse: α outside [0, π − θ], overlapping solids, crossed menisci (below pinch-off). */
static void test_geometry_refuses_no_bridge(void **state)
{
    (void)state;
    double A, E, theta = deg(40);
    assert_false(dr_cohesion_geometry(DR_COHESION_CYLINDERS, theta, -0.1, 3.0, &A, &E));
    assert_false(dr_cohesion_geometry(DR_COHESION_CYLINDERS, theta, DR_PI - theta + 1e-9, 3.0, &A, &E));
    assert_false(dr_cohesion_geometry(DR_COHESION_CYLINDERS, theta, 1.0, 1.9, &A, &E));
    assert_false(dr_cohesion_geometry(DR_COHESION_PLANE, theta, 1.0, 0.9, &A, &E));
    assert_false(dr_cohesion_geometry(DR_COHESION_CYLINDERS, theta, 0.01, 5.0, &A, &E)); /* menisci cross */
    assert_false(dr_cohesion_geometry(DR_COHESION_PLANE, theta, 0.01, 3.0, &A, &E));
    assert_true(dr_cohesion_geometry(DR_COHESION_CYLINDERS, theta, 1.0, 5.0, &A, &E));
    assert_true(A > 0.0);
    assert_true(dr_cohesion_geometry(DR_COHESION_CYLINDERS, theta, 0.0, 2.0, &A, &E)); /* touching, no liquid */
    assert_true(fabs(A) < 1e-15);
}

/* Two facts of the physics the table must show. As a bridge pinches off its menisci meet at a neck of zero width
 * (tangent along the force there), so it pulls with 2σ; and a bridge nearly engulfing two touching solids (convex
 * menisci) pushes them apart: F̃ is not clamped at 0. */
static void test_pinch_off_and_engulfing(void **state)
{
    (void)state;
    for (int k = 0; k < 3; k++) {
        double theta = deg(20 + 20 * k);
        for (int s = 0; s < 2; s++) {
            DrCohesionShape shape = s ? DR_COHESION_PLANE : DR_COHESION_CYLINDERS;
            double d = touching_gap(shape) + 3.0;
            double A0 = area_at(shape, theta, direct_alpha0(shape, theta, d), d);
            /* a bridge 1e-6 above pinch-off, and the difference taken below the gap (at d it has just pinched) */
            const double h = 1e-7, A = A0 + 1e-6;
            double F = (direct_energy(shape, theta, d, A) - direct_energy(shape, theta, d - 2 * h, A)) / (2 * h);
            assert_true(fabs(F - 2.0) < 1e-3);
        }
    }
    DrCohesionTable *t = build(DR_COHESION_CYLINDERS, deg(40), 256, NULL);
    double A1 = area_at(DR_COHESION_CYLINDERS, deg(40), DR_PI - deg(40), 2.05);
    assert_true(dr_cohesion_eval(t, 2.05, 0.9 * A1) < 0.0);
    assert_true(direct_force(DR_COHESION_CYLINDERS, deg(40), 2.05, 0.9 * A1) < 0.0);
    assert_true(dr_cohesion_eval(t, 4.0, 10.0) > 0.0);
    dr_cohesion_destroy(&t);
}

/* Outside the table's range and where no bridge is: 0. */
static void test_eval_outside(void **state)
{
    (void)state;
    DrCohesionTable *t = build(DR_COHESION_CYLINDERS, deg(40), 64, NULL);
    const DrCohesionDesc *d = dr_cohesion_desc(t);
    assert_true(d->max_gap > 0.0);
    assert_true(dr_cohesion_eval(t, 1.99, 1.0) == 0.0);
    assert_true(dr_cohesion_eval(t, 2.0 + d->max_gap * 1.001, 1.0) == 0.0);
    assert_true(dr_cohesion_eval(t, 3.0, -1.0) == 0.0);
    assert_true(dr_cohesion_eval(t, 3.0, d->max_area * 1.001) == 0.0);
    assert_true(dr_cohesion_eval(t, NAN, 1.0) == 0.0);
    assert_true(dr_cohesion_eval(t, 3.0, NAN) == 0.0);
    /* a gap of 20 r with 1 r² of liquid: far beyond pinch-off, and a cell away from any bridge */
    assert_false(direct_exists(DR_COHESION_CYLINDERS, deg(40), 20.0, 3.0));
    assert_true(dr_cohesion_eval(t, 20.0, 1.0) == 0.0);
    /* touching cylinders hold at most A(π − θ): far above it, the force of that largest bridge (saturated) */
    double amax = 0, e = 0;
    assert_true(dr_cohesion_geometry(DR_COHESION_CYLINDERS, deg(40), DR_PI - deg(40) - 1e-9, 2.0, &amax, &e));
    assert_true(amax < 100.0);
    assert_true(dr_cohesion_eval(t, 2.0, 100.0) == dr_cohesion_eval(t, 2.0, 99.0));
    dr_cohesion_destroy(&t);
}

/* The table is the same for 1 and 2 threads, bit for bit (each column depends on its gap only). */
static void test_threads_bit_identical(void **state)
{
    (void)state;
    dr_set_threads(1);
    DrCohesionTable *a = build(DR_COHESION_PLANE, deg(30), 128, NULL);
    dr_set_threads(2);
    DrCohesionTable *b = build(DR_COHESION_PLANE, deg(30), 128, NULL);
    dr_set_threads(0);
    DrRng rng;
    dr_rng_seed(&rng, 9);
    for (int n = 0; n < 20000; n++) {
        double d = 1.0 + 22.0 * dr_rng_uniform(&rng), A = 230.0 * dr_rng_uniform(&rng);
        double fa = dr_cohesion_eval(a, d, A), fb = dr_cohesion_eval(b, d, A);
        assert_memory_equal(&fa, &fb, sizeof fa);
    }
    dr_cohesion_destroy(&a);
    dr_cohesion_destroy(&b);
}

/* ---- desc, key, file ------------------------------------------------------------------------------------------- */

static void expect_bad_desc(const DrCohesionDesc *d, const char *field)
{
    DrCohesionTable *t = (DrCohesionTable *)(uintptr_t)1;
    DrError err;
    dr_error_clear(&err);
    assert_int_equal(dr_cohesion_build(d, &t, &err), DR_ERR_INPUT);
    assert_null(t);
    assert_int_equal(err.status, DR_ERR_INPUT);
    if (!strstr(err.message, field)) fprintf(stderr, "expected '%s' in: %s\n", field, err.message);
    assert_non_null(strstr(err.message, field));
}

static void test_bad_desc_names_the_field(void **state)
{
    (void)state;
    DrCohesionDesc d;
    const double bad_angles[] = {-0.1, DR_PI / 2, 2.0, NAN, INFINITY};
    for (int k = 0; k < 5; k++) {
        dr_cohesion_desc_default(&d);
        d.contact_angle = bad_angles[k];
        expect_bad_desc(&d, "contact_angle");
    }
    const int bad_res[] = {15, 4097, 0, -3};
    for (int k = 0; k < 4; k++) {
        dr_cohesion_desc_default(&d);
        d.resolution = bad_res[k];
        expect_bad_desc(&d, "resolution");
    }
    const double bad_sizes[] = {0.0, -1.0, NAN, INFINITY};
    for (int k = 0; k < 4; k++) {
        dr_cohesion_desc_default(&d);
        d.max_area = bad_sizes[k];
        expect_bad_desc(&d, "max_area");
        if (bad_sizes[k] != 0.0) { /* 0 means "the rupture gap" */
            dr_cohesion_desc_default(&d);
            d.max_gap = bad_sizes[k];
            expect_bad_desc(&d, "max_gap");
        }
    }
    dr_cohesion_desc_default(&d);
    d.shape = (DrCohesionShape)7;
    expect_bad_desc(&d, "shape");
}

/* max_gap 0 is the rupture gap at max_area for the desc's own θ, whatever θ was set after the defaults. */
static void test_default_gap_follows_theta(void **state)
{
    (void)state;
    DrCohesionDesc d;
    dr_cohesion_desc_default(&d);
    assert_int_equal(d.resolution, 256);
    assert_true(fabs(d.max_area - 2 * DR_PI * 35) < 1e-12);
    d.contact_angle = deg(60);
    d.resolution = 32;
    DrCohesionTable *t;
    DrError err;
    assert_int_equal(dr_cohesion_build(&d, &t, &err), DR_OK);
    assert_true(fabs(dr_cohesion_desc(t)->max_gap - (1 + deg(60) / 2) * sqrt(d.max_area)) < 1e-12);
    dr_cohesion_destroy(&t);
}

static void key_of(const DrCohesionDesc *d, char key[33]) { dr_cohesion_key(d, key); }

/* The key covers shape, θ, resolution, Ã_max, the gap range and the code version, and nothing else: the same inputs
 * give the same key (also when max_gap is left to its default or θ is −0); each input changes it. It is the hash of
 * the canonical inputs JSON, which carries DR_COHESION_VERSION, so a new version gives new keys. */
static void test_key(void **state)
{
    (void)state;
    DrCohesionDesc base, d;
    dr_cohesion_desc_default(&base);
    char k0[33], k[33];
    key_of(&base, k0);
    assert_int_equal(strlen(k0), 32);
    key_of(&base, k);
    assert_string_equal(k0, k);

    d = base;
    d.max_gap = (1 + base.contact_angle / 2) * sqrt(base.max_area);
    key_of(&d, k);
    assert_string_equal(k0, k);

    DrCohesionDesc z;
    dr_cohesion_desc_default(&z);
    z.contact_angle = 0.0;
    char kz[33];
    key_of(&z, kz);
    z.contact_angle = -0.0;
    key_of(&z, k);
    assert_string_equal(kz, k);

    DrCohesionDesc variants[6];
    for (int v = 0; v < 6; v++) variants[v] = base;
    variants[0].shape = DR_COHESION_PLANE;
    variants[1].contact_angle = nextafter(base.contact_angle, 1.0);
    variants[2].resolution = 512;
    variants[3].max_area *= 2;
    variants[4].max_gap = 10.0;
    variants[5].contact_angle = deg(20);
    char keys[6][33];
    for (int v = 0; v < 6; v++) {
        key_of(&variants[v], keys[v]);
        assert_string_not_equal(keys[v], k0);
        for (int w = 0; w < v; w++) assert_string_not_equal(keys[v], keys[w]);
    }

    char json[DR_COHESION_JSON_MAX], hex[33];
    dr_cohesion_inputs_json(&base, json);
    dr_hash_hex(dr_hash_bytes(json, strlen(json)), hex);
    assert_string_equal(hex, k0);
    char version[64];
    snprintf(version, sizeof version, "\"version\":\"%s\"", DR_COHESION_VERSION);
    char *at = strstr(json, version);
    assert_non_null(at);
    assert_non_null(strstr(json, "\"shape\":\"cylinders\""));
    assert_null(strchr(json, ' '));
    /* another version string in the same inputs hashes to another key */
    char other[DR_COHESION_JSON_MAX + 16];
    snprintf(other, sizeof other, "%.*s\"version\":\"%s-next\"}", (int)(at - json), json, DR_COHESION_VERSION);
    dr_hash_hex(dr_hash_bytes(other, strlen(other)), hex);
    assert_string_not_equal(hex, k0);
}

/* Writes t into root's cache under desc's key as precompute does: create, write, commit. */
static void save(const char *root, const DrCohesionDesc *desc, const DrCohesionTable *t)
{
    char key[33], json[DR_COHESION_JSON_MAX];
    dr_cohesion_key(desc, key);
    dr_cohesion_inputs_json(desc, json);
    DrH5 *h;
    DrError err;
    assert_int_equal(dr_io_precache_create(root, "cohesion", key, json, NULL, &h, &err), DR_OK);
    assert_int_equal(dr_cohesion_write(t, h, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
}

static void assert_same_table(const DrCohesionTable *a, const DrCohesionTable *b)
{
    const DrCohesionDesc *da = dr_cohesion_desc(a), *db = dr_cohesion_desc(b);
    assert_int_equal(da->shape, db->shape);
    assert_int_equal(da->resolution, db->resolution);
    assert_memory_equal(&da->contact_angle, &db->contact_angle, sizeof(double));
    assert_memory_equal(&da->max_area, &db->max_area, sizeof(double));
    assert_memory_equal(&da->max_gap, &db->max_gap, sizeof(double));
    DrRng rng;
    dr_rng_seed(&rng, 3);
    for (int n = 0; n < 20000; n++) {
        double d = 1.0 + 22.0 * dr_rng_uniform(&rng), A = 230.0 * dr_rng_uniform(&rng);
        double fa = dr_cohesion_eval(a, d, A), fb = dr_cohesion_eval(b, d, A);
        assert_memory_equal(&fa, &fb, sizeof fa);
    }
}

/* Write, read back: the same table bit for bit (its datasets compared, and every evaluation), self-describing
 * attributes present; a second load finds the file (a cache hit) and does not touch it. */
static void test_round_trip(void **state)
{
    (void)state;
    char root[512];
    snprintf(root, sizeof root, "%s/round_trip", g_dir);
    for (int s = 0; s < 2; s++) {
        DrCohesionDesc desc;
        dr_cohesion_desc_default(&desc);
        desc.shape = s ? DR_COHESION_PLANE : DR_COHESION_CYLINDERS;
        desc.contact_angle = deg(35);
        desc.resolution = 96;
        DrCohesionTable *t, *back;
        DrError err;
        assert_int_equal(dr_cohesion_build(&desc, &t, &err), DR_OK);
        save(root, &desc, t);

        char key[33], path[DR_IO_PATH_MAX];
        dr_cohesion_key(&desc, key);
        dr_io_precache_path(root, "cohesion", key, path, sizeof path);
        struct stat before, after;
        assert_int_equal(stat(path, &before), 0);

        DrH5 *h;
        bool found;
        assert_int_equal(dr_io_precache_open(root, "cohesion", key, &h, &found, NULL, &err), DR_OK);
        assert_true(found);
        assert_int_equal(dr_cohesion_read(h, path, &back, &err), DR_OK);
        assert_same_table(t, back);
        dr_cohesion_destroy(&back);

        /* what the file says about itself */
        char *text = NULL;
        assert_int_equal(dr_h5_read_attr_str(h, "/cohesion", "units", &text, &err), DR_OK);
        assert_string_equal(text, "1");
        free(text);
        assert_int_equal(dr_h5_read_attr_str(h, "/cohesion", "scaling", &text, &err), DR_OK);
        assert_non_null(strstr(text, "surface_tension"));
        free(text);
        assert_int_equal(dr_h5_read_attr_str(h, "/cohesion", "shape", &text, &err), DR_OK);
        assert_string_equal(text, s ? "plane" : "cylinders");
        free(text);
        assert_int_equal(dr_h5_read_attr_str(h, "/", "inputs", &text, &err), DR_OK);
        char json[DR_COHESION_JSON_MAX];
        dr_cohesion_inputs_json(&desc, json);
        assert_string_equal(text, json);
        free(text);
        double v;
        assert_int_equal(dr_h5_read_attr_f64(h, "/cohesion", "contact_angle_deg", &v, &err), DR_OK);
        assert_true(fabs(v - 35.0) < 1e-12);
        assert_int_equal(dr_h5_read_attr_f64(h, "/cohesion", "check_max_error", &v, &err), DR_OK);
        assert_true(v >= 0.0 && v < 0.05); /* a 96² table: coarse, but the check is recorded */
        int rank;
        uint64_t dims[4];
        double *axis = NULL;
        assert_int_equal(dr_h5_read_f64(h, "/cohesion/area", &rank, dims, &axis, &err), DR_OK);
        assert_int_equal(rank, 1);
        assert_int_equal(dims[0], 96);
        assert_true(axis[0] == 0.0 && axis[95] == desc.max_area);
        free(axis);
        dr_h5_close(&h);

        assert_int_equal(dr_cohesion_load(root, &desc, &back, &err), DR_OK);
        assert_same_table(t, back);
        dr_cohesion_destroy(&back);
        assert_int_equal(stat(path, &after), 0);
        assert_true(before.st_ino == after.st_ino && before.st_size == after.st_size &&
                    before.st_mtim.tv_sec == after.st_mtim.tv_sec && before.st_mtim.tv_nsec == after.st_mtim.tv_nsec);
        dr_cohesion_destroy(&t);
    }
}

/* No table in the cache: DR_ERR_INPUT (exit 2) naming the file it looked for and saying "run precompute"; nothing is
 * created. A file under the key that holds a table of other parameters is refused, naming the file. */
static void test_missing_table(void **state)
{
    (void)state;
    char root[512];
    snprintf(root, sizeof root, "%s/empty_cache", g_dir);
    DrCohesionDesc desc;
    dr_cohesion_desc_default(&desc);
    DrCohesionTable *t = (DrCohesionTable *)(uintptr_t)1;
    DrError err;
    dr_error_clear(&err);
    DrStatus s = dr_cohesion_load(root, &desc, &t, &err);
    assert_int_equal(s, DR_ERR_INPUT);
    assert_int_equal(dr_exit_code(s), 2);
    assert_null(t);
    char key[33], path[DR_IO_PATH_MAX];
    dr_cohesion_key(&desc, key);
    dr_io_precache_path(root, "cohesion", key, path, sizeof path);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "run precompute"));
    assert_false(dr_io_exists(root));

    /* a table of 30° filed under the key of 40° */
    char other_root[512];
    snprintf(other_root, sizeof other_root, "%s/mismatch", g_dir);
    DrCohesionDesc other = desc;
    other.contact_angle = deg(30);
    other.resolution = 32;
    desc.resolution = 32;
    DrCohesionTable *wrong;
    assert_int_equal(dr_cohesion_build(&other, &wrong, &err), DR_OK);
    char k[33], json[DR_COHESION_JSON_MAX];
    dr_cohesion_key(&desc, k);
    dr_cohesion_inputs_json(&desc, json);
    DrH5 *h;
    assert_int_equal(dr_io_precache_create(other_root, "cohesion", k, json, NULL, &h, &err), DR_OK);
    assert_int_equal(dr_cohesion_write(wrong, h, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    dr_cohesion_destroy(&wrong);
    dr_error_clear(&err);
    assert_int_equal(dr_cohesion_load(other_root, &desc, &t, &err), DR_ERR_INPUT);
    assert_null(t);
    dr_io_precache_path(other_root, "cohesion", k, path, sizeof path);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "precompute"));
}

/* A 16² table written to path with one root-group attribute of /cohesion replaced (name NULL: none). */
static void write_edited(const char *path, const char *name, const char *text, double number, int64_t integer)
{
    DrCohesionDesc desc;
    dr_cohesion_desc_default(&desc);
    desc.resolution = 16;
    DrCohesionTable *t;
    DrError err;
    assert_int_equal(dr_cohesion_build(&desc, &t, &err), DR_OK);
    DrH5 *h;
    assert_int_equal(dr_h5_create(path, &h, &err), DR_OK);
    assert_int_equal(dr_cohesion_write(t, h, &err), DR_OK);
    if (name && text) assert_int_equal(dr_h5_attr_str(h, "/cohesion", name, text, &err), DR_OK);
    if (name && !text && integer) assert_int_equal(dr_h5_attr_i64(h, "/cohesion", name, integer, &err), DR_OK);
    if (name && !text && !integer) assert_int_equal(dr_h5_attr_f64(h, "/cohesion", name, number, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    dr_cohesion_destroy(&t);
}

/* Overwrites element k of a dataset of the file (through HDF5 itself: a file edited by hand), and its checksum with
 * it (io.h: XXH3-128 of the elements' bytes), so that the table's own checks, not the checksum, meet the edit. */
static void poke(const char *path, const char *dataset, size_t k, double value)
{
    hid_t f = H5Fopen(path, H5F_ACC_RDWR, H5P_DEFAULT);
    assert_true(f >= 0);
    hid_t d = H5Dopen2(f, dataset, H5P_DEFAULT);
    assert_true(d >= 0);
    hid_t type = H5Dget_type(d);
    bool is_float = H5Tget_class(type) == H5T_FLOAT;
    H5Tclose(type);
    double buf[256];
    int32_t ibuf[256];
    if (is_float) {
        assert_true(H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf) >= 0);
        buf[k] = value;
        assert_true(H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf) >= 0);
    } else {
        assert_true(H5Dread(d, H5T_NATIVE_INT32, H5S_ALL, H5S_ALL, H5P_DEFAULT, ibuf) >= 0);
        ibuf[k] = (int32_t)value;
        assert_true(H5Dwrite(d, H5T_NATIVE_INT32, H5S_ALL, H5S_ALL, H5P_DEFAULT, ibuf) >= 0);
    }
    char hex[33];
    dr_hash_hex(is_float ? dr_hash_bytes(buf, sizeof buf) : dr_hash_bytes(ibuf, sizeof ibuf), hex);
    hid_t a = H5Aopen(d, DR_H5_CHECKSUM_ATTR, H5P_DEFAULT);
    assert_true(a >= 0);
    hid_t atype = H5Aget_type(a);
    assert_true(H5Tget_size(atype) == sizeof hex && H5Awrite(a, atype, hex) >= 0);
    H5Tclose(atype);
    H5Aclose(a);
    H5Dclose(d);
    H5Fclose(f);
}

static void expect_refused(const char *path, const char *words)
{
    DrH5 *h;
    DrError err;
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    DrCohesionTable *t = (DrCohesionTable *)(uintptr_t)1;
    dr_error_clear(&err);
    assert_int_equal(dr_cohesion_read(h, path, &t, &err), DR_ERR_INPUT);
    assert_null(t);
    assert_string_equal(err.file, path);
    if (!strstr(err.message, words)) fprintf(stderr, "expected '%s' in: %s\n", words, err.message);
    assert_non_null(strstr(err.message, words));
    dr_h5_close(&h);
}

/* A file that does not hold what it says is refused, naming the file: another code version, a shape or resolution or
 * angle out of range, datasets of other sizes than the resolution, a force that is not finite, a flag other than
 * 0 or 1, a force where no bridge is. An unedited file reads. */
static void test_read_refuses_bad_files(void **state)
{
    (void)state;
    char path[512];
    snprintf(path, sizeof path, "%s/edited.h5", g_dir);
    write_edited(path, NULL, NULL, 0, 0);
    DrH5 *h;
    DrError err;
    DrCohesionTable *t;
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    assert_int_equal(dr_cohesion_read(h, path, &t, &err), DR_OK);
    dr_cohesion_destroy(&t);
    dr_h5_close(&h);

    write_edited(path, "cohesion_version", "cohesion-0", 0, 0);
    expect_refused(path, "version");
    write_edited(path, "shape", "sphere", 0, 0);
    expect_refused(path, "shape");
    write_edited(path, "resolution", NULL, 0, 17);
    expect_refused(path, "17 x 17");
    write_edited(path, "resolution", NULL, 0, 8);
    expect_refused(path, "resolution");
    write_edited(path, "contact_angle_rad", NULL, 2.0, 0);
    expect_refused(path, "contact_angle");
    write_edited(path, "max_area", NULL, -1.0, 0);
    expect_refused(path, "max_area");

    /* node (15, 0): no bridge (no area) */
    write_edited(path, NULL, NULL, 0, 0);
    poke(path, "/cohesion/valid", 15 * 16, 3);
    expect_refused(path, "flag");
    write_edited(path, NULL, NULL, 0, 0);
    poke(path, "/cohesion/force", 15 * 16, 0.5);
    expect_refused(path, "no bridge");
    write_edited(path, NULL, NULL, 0, 0);
    poke(path, "/cohesion/force", 8 * 16 + 8, NAN);
    expect_refused(path, "non-finite");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_closed_forms_against_polygons),
        cmocka_unit_test(test_closed_forms_are_smooth),
        cmocka_unit_test(test_geometry_refuses_no_bridge),
        cmocka_unit_test(test_cylinders_against_direct_geometry),
        cmocka_unit_test(test_plane_against_direct_geometry),
        cmocka_unit_test(test_corner_of_touching_solids),
        cmocka_unit_test(test_columns_are_monotone),
        cmocka_unit_test(test_work_equals_energy_difference),
        cmocka_unit_test(test_pinch_off_and_engulfing),
        cmocka_unit_test(test_force_scales),
        cmocka_unit_test(test_eval_outside),
        cmocka_unit_test(test_threads_bit_identical),
        cmocka_unit_test(test_bad_desc_names_the_field),
        cmocka_unit_test(test_default_gap_follows_theta),
        cmocka_unit_test(test_key),
        cmocka_unit_test(test_round_trip),
        cmocka_unit_test(test_missing_table),
        cmocka_unit_test(test_read_refuses_bad_files),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
