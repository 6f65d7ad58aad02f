/* The cohesion tables of capillary bridges (fei2017 §S1, §S3; PHYSICS §5; contract in wet.h).
 *
 * Geometry, nondimensional (r = 1, σ = 1). Two cylinders: centres (∓d/2, 0), the contact lines at angle α from the
 * line of centres, β = θ + α the angle of the meniscus at the contact line, w = (d − 2 cos α)/2 half the horizontal
 * distance between the two contact lines (≥ 0 for d ≥ 2). Each meniscus is a circular arc of signed radius
 * R = w / cos β (< 0: convex) and central angle π − 2β. Cylinder over a plane: the axis d above y = 0, the contact
 * line on the cylinder at P = (sin α, d − cos α), α from the downward normal; the meniscus meets the plane at
 * x_p = sin α + P_y tan(α/2) (the chord of an arc with equal contact angles at both ends depends on α alone) with
 * central angle φ = π − α − 2θ and radius R = P_y / (2 sin(φ/2) cos(α/2)).
 *
 * Every closed form is written with two analytic helpers, sinc z = sin z / z and s3(z) = (z − sin z)/z³, whose
 * Taylor series are used near 0, so no formula divides 0 by 0 (β = π/2, a flat meniscus; φ = 0; α = 0) nor loses
 * digits to cancellation there. Being analytic in both variables, each closed form is differentiated by complex
 * step (the derivative is Im f(x + ih)/h for h = 1e-30): exact to round-off, with no step size to tune. */
#include "wet/wet.h"

#include <complex.h>
#include <stdlib.h>
#include <string.h>

typedef double complex Cx;

/* ---- analytic helpers ------------------------------------------------------------------------------------ */

/* sin z / z. Below |z| = 0.5 by its series through z¹⁶ (the next term is below 1e-19 there), which keeps the
 * function analytic at 0. */
static Cx c_sinc(Cx z)
{
    if (fabs(creal(z)) >= 0.5) return csin(z) / z;
    Cx z2 = z * z, s = 1.0;
    for (int k = 8; k >= 1; k--) s = 1.0 - z2 * s / ((2.0 * k) * (2.0 * k + 1.0));
    return s;
}

/* (z − sin z) / z³ = 1/3! − z²/5! + z⁴/7! − …: below |z| = 0.5 by the series through z¹⁶, above directly, where the
 * subtraction loses fewer than 5 bits. */
static Cx c_s3(Cx z)
{
    if (fabs(creal(z)) >= 0.5) return (z - csin(z)) / (z * z * z);
    Cx z2 = z * z, s = 1.0;
    for (int k = 9; k >= 2; k--) s = 1.0 - z2 * s / ((2.0 * k) * (2.0 * k + 1.0));
    return s / 6.0;
}

/* ---- closed forms ------------------------------------------------------------------------------------------ */

/* Two cylinders: the bridge's whole cross-section (both menisci)
 *     A = 4 w sin α + w² f(β) − 2 (α − sin α cos α),   f(β) = (sin 2β + 2β − π)/cos²β = (2γ − sin 2γ)/sin²γ,
 * γ = β − π/2 (the rectangle between the contact lines, the two circular segments of the menisci, and the four
 * pieces of the cylinders inside that rectangle), and its energy E = l_A + l_S cos θ with the menisci's length
 * l_A = 2 w (π − 2β)/cos β = 4 w γ / sin γ and the dry perimeter l_S = 4π − 4α (the constant 4π cos θ dropped). */
static void cyl_forms(double theta, Cx a, Cx d, Cx *area, Cx *energy)
{
    Cx w = 0.5 * (d - 2.0 * ccos(a));
    Cx g = theta + a - 0.5 * DR_PI;
    Cx sg = c_sinc(g);
    Cx f = 8.0 * g * c_s3(2.0 * g) / (sg * sg);
    *area = 4.0 * w * csin(a) + w * w * f - 8.0 * a * a * a * c_s3(2.0 * a);
    *energy = 4.0 * w / sg - 4.0 * a * cos(theta);
}

/* Cylinder over a plane, both sides: A = x_p P_y + P_x (d − 1) − R²(φ − sin φ) − (α − sin α) (the quadrilateral
 * below the cylinder's bottom, P and the plane contact, less the meniscus's circular segment and the cylinder's),
 * with R²(φ − sin φ) = P_y² φ s3(φ) / (sinc²(φ/2) cos²(α/2)); E = 2 R φ − 2 (α + x_p) cos θ, 2 R φ =
 * 2 P_y / (sinc(φ/2) cos(α/2)) (dry lengths of the cylinder and of the plane, constants dropped). */
static void plane_forms(double theta, Cx a, Cx d, Cx *area, Cx *energy)
{
    Cx py = d - ccos(a), px = csin(a);
    Cx phi = DR_PI - a - 2.0 * theta;
    Cx c2 = ccos(0.5 * a);
    Cx xp = px + py * ctan(0.5 * a);
    Cx sh = c_sinc(0.5 * phi);
    Cx seg = py * py * phi * c_s3(phi) / (sh * sh * c2 * c2);
    *area = xp * py + px * (d - 1.0) - seg - a * a * a * c_s3(a);
    *energy = 2.0 * py / (sh * c2) - 2.0 * (a + xp) * cos(theta);
}

static void forms(DrCohesionShape shape, double theta, Cx a, Cx d, Cx *area, Cx *energy)
{
    if (shape == DR_COHESION_CYLINDERS)
        cyl_forms(theta, a, d, area, energy);
    else
        plane_forms(theta, a, d, area, energy);
}

/* How far the bridge is from pinching off: > 0 while its menisci are apart. Two cylinders: the height of the upper
 * meniscus above the line of centres at its lowest point, sin α − R (1 − sin β) = sin α − w cos β / (1 + sin β)
 * (a convex meniscus, β > π/2, is lowest at its ends, sin α > 0). Plane: the distance of the meniscus from the
 * axis of symmetry at its innermost point, x_p − R (1 − sin θ) while that point lies inside the arc (α + θ ≤ π/2),
 * else at the contact line P_x = sin α. */
static double neck(DrCohesionShape shape, double theta, double a, double d)
{
    if (shape == DR_COHESION_CYLINDERS) {
        double w = 0.5 * (d - 2.0 * cos(a)), b = theta + a;
        return sin(a) - w * cos(b) / (1.0 + sin(b));
    }
    if (a + theta > 0.5 * DR_PI) return sin(a);
    double py = d - cos(a), phi = DR_PI - a - 2.0 * theta;
    double R = py / (2.0 * sin(0.5 * phi) * cos(0.5 * a));
    return sin(a) + py * tan(0.5 * a) - R * (1.0 - sin(theta));
}

/* The smallest gap of the shape: solids touching. */
static double gap_min(DrCohesionShape shape) { return shape == DR_COHESION_CYLINDERS ? 2.0 : 1.0; }

/* Area and energy at (α, d) with their derivatives by complex step: ∂/∂α from a step in α, ∂/∂d from one in d. */
typedef struct Forms {
    double area, energy, area_a, area_d, energy_a, energy_d;
} Forms;

#define CSTEP 1e-30

static Forms forms_diff(DrCohesionShape shape, double theta, double a, double d)
{
    Cx A, E;
    Forms f;
    forms(shape, theta, CMPLX(a, CSTEP), CMPLX(d, 0.0), &A, &E);
    f.area = creal(A);
    f.energy = creal(E);
    f.area_a = cimag(A) / CSTEP;
    f.energy_a = cimag(E) / CSTEP;
    forms(shape, theta, CMPLX(a, 0.0), CMPLX(d, CSTEP), &A, &E);
    f.area_d = cimag(A) / CSTEP;
    f.energy_d = cimag(E) / CSTEP;
    return f;
}

static double area_of(DrCohesionShape shape, double theta, double a, double d)
{
    Cx A, E;
    forms(shape, theta, CMPLX(a, 0.0), CMPLX(d, 0.0), &A, &E);
    return creal(A);
}

bool dr_cohesion_geometry(DrCohesionShape shape, double theta, double alpha, double d_nd, double *area_nd,
                          double *energy_nd)
{
    assert(shape == DR_COHESION_CYLINDERS || shape == DR_COHESION_PLANE);
    if (!(alpha >= 0.0 && alpha <= DR_PI - theta) || !(d_nd >= gap_min(shape))) return false;
    if (neck(shape, theta, alpha, d_nd) < 0.0) return false;
    Cx A, E;
    forms(shape, theta, CMPLX(alpha, 0.0), CMPLX(d_nd, 0.0), &A, &E);
    if (area_nd) *area_nd = creal(A);
    if (energy_nd) *energy_nd = creal(E);
    return true;
}

/* ---- desc --------------------------------------------------------------------------------------------------- */

void dr_cohesion_desc_default(DrCohesionDesc *d)
{
    d->shape = DR_COHESION_CYLINDERS;
    d->contact_angle = 40.0 * DR_PI / 180.0;
    d->resolution = 256;
    d->max_area = 2.0 * DR_PI * (6.0 * 6.0 - 1.0);
    d->max_gap = 0.0;
}

/* The rupture gap of a bridge of area Ã: the 2-D analogue of Lian's rupture distance, (1 + θ/2)√Ã (PHYSICS §5). */
static double rupture_gap(double theta, double area_nd) { return (1.0 + 0.5 * theta) * sqrt(area_nd); }

/* Checks desc and fills in what it leaves to the code (max_gap = 0). Field names as in wet.h. */
static DrStatus resolve_desc(const DrCohesionDesc *in, DrCohesionDesc *out, DrError *err)
{
    *out = *in;
    if (in->shape != DR_COHESION_CYLINDERS && in->shape != DR_COHESION_PLANE)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "cohesion table: shape = %d is neither DR_COHESION_CYLINDERS nor DR_COHESION_PLANE",
                            (int)in->shape);
    if (!(in->contact_angle >= 0.0 && in->contact_angle < 0.5 * DR_PI))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "cohesion table: contact_angle = %g rad (%g deg) is outside [0, pi/2); a liquid that does "
                            "not wet the hair forms no bridge: give an angle below 90 degrees",
                            in->contact_angle, in->contact_angle * 180.0 / DR_PI);
    if (in->resolution < 16 || in->resolution > 4096)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "cohesion table: resolution = %d is outside [16, 4096]; 256 is the default",
                            in->resolution);
    if (!(in->max_area > 0.0 && isfinite(in->max_area)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "cohesion table: max_area = %g is not a finite area > 0 (in units of r^2)", in->max_area);
    if (!(in->max_gap >= 0.0 && isfinite(in->max_gap)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "cohesion table: max_gap = %g is not a finite gap > 0 (in units of r), nor 0 for the "
                            "rupture gap at max_area",
                            in->max_gap);
    if (in->max_gap == 0.0) out->max_gap = rupture_gap(in->contact_angle, in->max_area);
    return DR_OK;
}

/* ---- the table ---------------------------------------------------------------------------------------------- */

struct DrCohesionTable {
    DrCohesionDesc desc; /* resolved: max_gap > 0 */
    double d0;           /* d̃ of the first column: the solids touching (2 or 1) */
    double *force;       /* res², F̃ at (column i, row j) in force[i res + j] (d̃ slowest) */
    int32_t *valid;      /* res², 1 where a bridge exists, else 0 (and F̃ = 0) */
    double check_error;  /* the build's self-check: largest |F̃_table − F̃| / max(|F̃|, 1) at the cell centres it
                            looked at (the closed form solved there, not interpolated) */
    int check_points;    /* how many cell centres that was */
};

/* The axes (wet.h): column i is d̃ = d̃_min + (d̃_max − d̃_min) s², row j is Ã = Ã_max s², s = index/(res − 1). A
 * quadratic axis puts its finest spacing where F̃ changes fastest, at small bridges and small gaps: against uniform
 * axes of the same size it cuts the largest error of the 256² table in the acceptance test's region from 3 % to
 * 0.5 % (cylinders, θ = 20°, 100,000 random points), and it leaves F̃ smooth in the fractional indices (F̃ is
 * smooth in d̃ and Ã, which are smooth in s), so bilinear interpolation stays second order. */
static double column_gap(const DrCohesionTable *t, int i)
{
    double s = (double)i / (t->desc.resolution - 1);
    return t->d0 + t->desc.max_gap * (s * s);
}

static double row_area(const DrCohesionTable *t, int j)
{
    double s = (double)j / (t->desc.resolution - 1);
    return t->desc.max_area * (s * s);
}

/* Their inverses: fractional column and row indices (NaN below the first). */
static double column_coord(const DrCohesionTable *t, double d_nd)
{
    return sqrt((d_nd - t->d0) / t->desc.max_gap) * (t->desc.resolution - 1);
}

static double row_coord(const DrCohesionTable *t, double area_nd)
{
    return sqrt(area_nd / t->desc.max_area) * (t->desc.resolution - 1);
}

/* A table of desc (resolved), with zeroed arrays when `arrays`, else none yet. */
static DrStatus table_alloc(const DrCohesionDesc *desc, bool arrays, DrCohesionTable **out, DrError *err)
{
    *out = NULL;
    DrCohesionTable *t = NULL;
    DR_TRY(dr_calloc(1, sizeof *t, &t, err));
    t->desc = *desc;
    t->d0 = gap_min(desc->shape);
    size_t n = (size_t)desc->resolution * (size_t)desc->resolution;
    DrStatus s = arrays ? dr_calloc(n, sizeof *t->force, &t->force, err) : DR_OK;
    if (s == DR_OK && arrays) s = dr_calloc(n, sizeof *t->valid, &t->valid, err);
    if (s != DR_OK) {
        dr_cohesion_destroy(&t);
        return s;
    }
    *out = t;
    return DR_OK;
}

void dr_cohesion_destroy(DrCohesionTable **t)
{
    if (!t || !*t) return;
    free((*t)->force);
    free((*t)->valid);
    free(*t);
    *t = NULL;
}

const DrCohesionDesc *dr_cohesion_desc(const DrCohesionTable *t) { return &t->desc; }

/* ---- build ---------------------------------------------------------------------------------------------------- */

/* α at which the bridge pinches off at gap d: the root of neck(α) on [0, π/2 − θ], where the neck is negative at 0
 * (for d above contact) and sin α > 0 at the top (the meniscus is flat there). Bisection to the last bit; the neck
 * changes sign once on that interval (checked for θ from 0° to 89.9° and gaps up to 40 r). */
static double pinch_angle(DrCohesionShape shape, double theta, double d)
{
    double lo = 0.0, hi = 0.5 * DR_PI - theta;
    if (neck(shape, theta, lo, d) >= 0.0) return 0.0;
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (lo + hi);
        if (mid <= lo || mid >= hi) break;
        if (neck(shape, theta, mid, d) > 0.0)
            hi = mid;
        else
            lo = mid;
    }
    return hi;
}

/* α in [lo, hi] with A(α, d) = target, for A increasing with A(lo) ≤ target ≤ A(hi): Newton on the complex-step slope
 * from `guess`, a bisection step whenever Newton would leave the bracket, until the step or the bracket is a few
 * ulps. */
static double solve_alpha(DrCohesionShape shape, double theta, double d, double target, double lo, double hi,
                          double guess)
{
    double a = guess > lo && guess < hi ? guess : 0.5 * (lo + hi);
    for (int it = 0; it < 200; it++) {
        Cx A, E;
        forms(shape, theta, CMPLX(a, CSTEP), CMPLX(d, 0.0), &A, &E);
        double r = creal(A) - target, slope = cimag(A) / CSTEP;
        if (r == 0.0) return a;
        if (r < 0.0)
            lo = a;
        else
            hi = a;
        double next = slope > 0.0 ? a - r / slope : 0.5 * (lo + hi);
        if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
        if (fabs(next - a) <= 4e-16 * fabs(a) || hi - lo <= 4e-16 * hi) return next;
        a = next;
    }
    return a;
}

/* F̃ = ∂Ẽ/∂d̃ at constant Ã (eq. S18): ∂E/∂d + ∂E/∂α dα/dd|_A, dα/dd|_A = −(∂A/∂d)/(∂A/∂α). */
static double force_at(DrCohesionShape shape, double theta, double a, double d)
{
    Forms f = forms_diff(shape, theta, a, d);
    return f.energy_d - f.energy_a * f.area_d / f.area_a;
}

/* Where a column's bridges live: α from the pinch angle α_0 to α_1, the end of the part of [α_0, π − θ] on which A
 * increases (sampled at MONOTONE_SAMPLES points: never shorter than π − θ for θ in [0°, 89.9°] and gaps up to 40 r,
 * but a column is inverted only where it is monotone, so a truncation would be found and logged, not mis-inverted).
 * false when the column holds no bridge. */
#define MONOTONE_SAMPLES 64

typedef struct Column {
    double a0, a1, A0, A1;
    bool truncated;
} Column;

static Column column_range(DrCohesionShape shape, double theta, double d)
{
    Column c = {pinch_angle(shape, theta, d), DR_PI - theta, 0.0, 0.0, false};
    for (int k = 1; k <= MONOTONE_SAMPLES; k++) {
        double a = c.a0 + (DR_PI - theta - c.a0) * k / MONOTONE_SAMPLES;
        if (!(forms_diff(shape, theta, a, d).area_a > 0.0)) {
            c.a1 = c.a0 + (DR_PI - theta - c.a0) * (k - 1) / MONOTONE_SAMPLES;
            c.truncated = true;
            break;
        }
    }
    c.A0 = area_of(shape, theta, c.a0, d);
    c.A1 = area_of(shape, theta, c.a1, d);
    return c;
}

/* A bridge of area Ã exists in the column when A(α_0) < Ã ≤ A(α_1). */
static bool column_holds(const Column *c, double area) { return c->a1 > c->a0 && area > c->A0 && area <= c->A1; }

typedef struct BuildCtx {
    DrCohesionTable *t;
    unsigned char *truncated; /* per column */
} BuildCtx;

/* Columns [begin, end): each row's α by Newton from the row below's, and F̃ there. A column depends on nothing but its
 * d̃, so the table is the same for any split over threads. */
static void build_columns(long begin, long end, void *ctx_)
{
    BuildCtx *ctx = ctx_;
    DrCohesionTable *t = ctx->t;
    const DrCohesionShape shape = t->desc.shape;
    const double theta = t->desc.contact_angle;
    const int res = t->desc.resolution;
    for (long i = begin; i < end; i++) {
        const double d = column_gap(t, (int)i);
        const Column c = column_range(shape, theta, d);
        ctx->truncated[i] = c.truncated;
        double guess = c.a0;
        /* more liquid than the largest bridge holds: the force of that bridge (saturated) */
        const double saturated = c.a1 > c.a0 ? force_at(shape, theta, c.a1, d) : 0.0;
        for (int j = 0; j < res; j++) {
            const double area = row_area(t, j);
            const size_t k = (size_t)i * (size_t)res + (size_t)j;
            if (c.a1 > c.a0 && area > c.A1) {
                t->force[k] = saturated;
                t->valid[k] = 2;
                continue;
            }
            if (!column_holds(&c, area)) {
                t->force[k] = 0.0;
                t->valid[k] = 0;
                continue;
            }
            guess = solve_alpha(shape, theta, d, area, c.a0, c.a1, guess);
            t->force[k] = force_at(shape, theta, guess, d);
            t->valid[k] = 1;
        }
    }
}

/* The self-check: at the centre of every stride-th cell whose four corners hold bridges (the point of a cell farthest
 * from its nodes), the table against F̃ solved there from the closed forms. */
#define CHECK_CELLS_PER_AXIS 16

static void self_check(DrCohesionTable *t)
{
    const int res = t->desc.resolution, stride = res - 1 > CHECK_CELLS_PER_AXIS ? (res - 1) / CHECK_CELLS_PER_AXIS : 1;
    const DrCohesionShape shape = t->desc.shape;
    const double theta = t->desc.contact_angle;
    t->check_error = 0.0;
    t->check_points = 0;
    for (int i = stride / 2; i < res - 1; i += stride)
        for (int j = stride / 2; j < res - 1; j += stride) {
            const size_t k = (size_t)i * (size_t)res + (size_t)j;
            if (!(t->valid[k] == 1 && t->valid[k + 1] == 1 && t->valid[k + res] == 1 && t->valid[k + res + 1] == 1))
                continue;
            double s = (i + 0.5) / (res - 1), q = (j + 0.5) / (res - 1);
            double d = t->d0 + t->desc.max_gap * (s * s), area = t->desc.max_area * (q * q);
            Column c = column_range(shape, theta, d);
            if (!column_holds(&c, area)) continue;
            double F = force_at(shape, theta, solve_alpha(shape, theta, d, area, c.a0, c.a1, -1.0), d);
            double e = fabs(dr_cohesion_eval(t, d, area) - F) / fmax(fabs(F), 1.0);
            if (e > t->check_error) t->check_error = e;
            t->check_points++;
        }
}

DrStatus dr_cohesion_build(const DrCohesionDesc *desc, DrCohesionTable **out, DrError *err)
{
    *out = NULL;
    DrCohesionDesc d;
    DR_TRY(resolve_desc(desc, &d, err));
    DrCohesionTable *t;
    DR_TRY(table_alloc(&d, true, &t, err));
    unsigned char *truncated = NULL;
    DrStatus s = dr_calloc((size_t)d.resolution, sizeof *truncated, &truncated, err);
    if (s != DR_OK) {
        dr_cohesion_destroy(&t);
        return s;
    }
    BuildCtx ctx = {t, truncated};
    dr_parallel_for(d.resolution, 8, build_columns, &ctx);
    int ntrunc = 0;
    for (int i = 0; i < d.resolution; i++) ntrunc += truncated[i];
    free(truncated);
    if (ntrunc > 0)
        dr_log_warn("cohesion table: the bridge area stops increasing with the wetting angle before pi - theta in %d "
                    "of %d columns (theta %g deg); those columns hold the increasing part only",
                    ntrunc, d.resolution, d.contact_angle * 180.0 / DR_PI);
    self_check(t);
    *out = t;
    return DR_OK;
}

/* ---- evaluation --------------------------------------------------------------------------------------------- */

double dr_cohesion_eval(const DrCohesionTable *t, double d_nd, double area_nd)
{
    const int res = t->desc.resolution;
    const double x = column_coord(t, d_nd), y = row_coord(t, area_nd);
    if (!(x >= 0.0 && x <= res - 1) || !(y >= 0.0 && y <= res - 1)) return 0.0;
    int i = (int)x, j = (int)y;
    if (i > res - 2) i = res - 2;
    if (j > res - 2) j = res - 2;
    const double fx = x - i, fy = y - j;
    const size_t k = (size_t)i * (size_t)res + (size_t)j;
    const double *F = t->force;
    return (1.0 - fx) * ((1.0 - fy) * F[k] + fy * F[k + 1]) + fx * ((1.0 - fy) * F[k + res] + fy * F[k + res + 1]);
}

double dr_cohesion_force(const DrCohesionTable *t, double r, double sigma, double d, double area)
{
    return sigma * dr_cohesion_eval(t, d / r, area / (r * r));
}

/* ---- key ------------------------------------------------------------------------------------------------------ */

static const char *shape_name(DrCohesionShape s) { return s == DR_COHESION_CYLINDERS ? "cylinders" : "plane"; }

static bool shape_parse(const char *name, DrCohesionShape *out)
{
    if (strcmp(name, "cylinders") == 0) *out = DR_COHESION_CYLINDERS;
    else if (strcmp(name, "plane") == 0) *out = DR_COHESION_PLANE;
    else return false;
    return true;
}

/* Numbers as %.17g (exact for a double; −0 as 0), the form of the scene's canonical JSON. */
static void put_num(char *buf, size_t size, double v) { snprintf(buf, size, "%.17g", v == 0.0 ? 0.0 : v); }

void dr_cohesion_inputs_json(const DrCohesionDesc *desc, char json[DR_COHESION_JSON_MAX])
{
    DrCohesionDesc d = *desc;
    if (d.max_gap == 0.0) d.max_gap = rupture_gap(d.contact_angle, d.max_area);
    char theta[32], area[32], gap[32];
    put_num(theta, sizeof theta, d.contact_angle);
    put_num(area, sizeof area, d.max_area);
    put_num(gap, sizeof gap, d.max_gap);
    int n = snprintf(json, DR_COHESION_JSON_MAX,
                     "{\"contact_angle\":%s,\"max_area\":%s,\"max_gap\":%s,\"resolution\":%d,\"shape\":\"%s\","
                     "\"version\":\"%s\"}",
                     theta, area, gap, d.resolution,
                     d.shape == DR_COHESION_CYLINDERS || d.shape == DR_COHESION_PLANE ? shape_name(d.shape) : "?",
                     DR_COHESION_VERSION);
    assert(n > 0 && n < DR_COHESION_JSON_MAX);
}

void dr_cohesion_key(const DrCohesionDesc *desc, char key_hex[33])
{
    char json[DR_COHESION_JSON_MAX];
    dr_cohesion_inputs_json(desc, json);
    dr_hash_hex(dr_hash_bytes(json, strlen(json)), key_hex);
}

/* ---- file ----------------------------------------------------------------------------------------------------
 * In the precompute cache file (root attributes kind, key, inputs, ... from dr_io_precache_create), group /cohesion:
 *   force (res × res, "1")  F̃ at (column i, row j), row-major, d̃ slowest
 *   valid (res × res, int)  1 where a bridge exists
 *   gap (res), area (res)   d̃ of each column, Ã of each row
 * and attributes on /cohesion that say what they are and how to use them. */

#define GROUP "/cohesion"
#define COHESION_KIND "cohesion"

static DrStatus put_attrs(const DrCohesionTable *t, DrH5 *h, DrError *err)
{
    const DrCohesionDesc *d = &t->desc;
    DR_TRY(dr_h5_attr_str(h, GROUP, "cohesion_version", DR_COHESION_VERSION, err));
    DR_TRY(dr_h5_attr_str(h, GROUP, "shape", shape_name(d->shape), err));
    DR_TRY(dr_h5_attr_str(h, GROUP, "description",
                          d->shape == DR_COHESION_CYLINDERS
                              ? "capillary bridge between two parallel cylinders of radius r, axes d apart"
                              : "capillary bridge between a cylinder of radius r, axis d above a plane, and the plane",
                          err));
    DR_TRY(dr_h5_attr_f64(h, GROUP, "contact_angle_deg", d->contact_angle * 180.0 / DR_PI, err));
    DR_TRY(dr_h5_attr_f64(h, GROUP, "contact_angle_rad", d->contact_angle, err));
    DR_TRY(dr_h5_attr_i64(h, GROUP, "resolution", d->resolution, err));
    DR_TRY(dr_h5_attr_f64(h, GROUP, "gap_min", t->d0, err));
    DR_TRY(dr_h5_attr_f64(h, GROUP, "gap_max", t->d0 + d->max_gap, err));
    DR_TRY(dr_h5_attr_f64(h, GROUP, "max_gap", d->max_gap, err));
    DR_TRY(dr_h5_attr_f64(h, GROUP, "max_area", d->max_area, err));
    DR_TRY(dr_h5_attr_str(h, GROUP, "units", "1", err));
    DR_TRY(dr_h5_attr_str(h, GROUP, "scaling",
                          "nondimensional: gap = d/r, area = A/r^2, force F = surface_tension * force(gap, area) in N "
                          "per metre of bridge length, > 0 pulling the solids together; r the radius (m), A the "
                          "bridge's cross-section area (m^2), surface_tension in N/m",
                          err));
    DR_TRY(dr_h5_attr_str(h, GROUP, "grid",
                          "column i: gap = gap_min + max_gap (i/(resolution-1))^2; row j: area = max_area "
                          "(j/(resolution-1))^2; force[i][j] bilinear in the fractional indices; valid = 0 where no "
                          "bridge exists (force 0 there)",
                          err));
    DR_TRY(dr_h5_attr_f64(h, GROUP, "check_max_error", t->check_error, err));
    DR_TRY(dr_h5_attr_i64(h, GROUP, "check_points", t->check_points, err));
    return dr_h5_attr_str(h, GROUP, "check",
                          "largest |interpolated - exact| / max(|exact|, 1) at check_points cell centres, the exact "
                          "force solved from the closed forms there",
                          err);
}

DrStatus dr_cohesion_write(const DrCohesionTable *t, DrH5 *h, DrError *err)
{
    const int res = t->desc.resolution;
    const uint64_t n = (uint64_t)res, dims[2] = {n, n};
    double *axis = NULL;
    DR_TRY(dr_calloc(2 * (size_t)res, sizeof *axis, &axis, err));
    for (int i = 0; i < res; i++) axis[i] = column_gap(t, i);
    for (int j = 0; j < res; j++) axis[res + j] = row_area(t, j);
    DrStatus s = dr_h5_write_f64(h, GROUP "/force", 2, dims, t->force, "1", true, err);
    if (s == DR_OK) s = dr_h5_write_i32(h, GROUP "/valid", 2, dims, t->valid, "1", true, err);
    if (s == DR_OK) s = dr_h5_write_f64(h, GROUP "/gap", 1, &n, axis, "1", true, err);
    if (s == DR_OK) s = dr_h5_write_f64(h, GROUP "/area", 1, &n, axis + res, "1", true, err);
    free(axis);
    if (s == DR_OK) s = put_attrs(t, h, err);
    return s;
}

/* A file that does not hold what its attributes say. */
static DrStatus bad_file(const char *path, DrError *err, const char *what)
{
    return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                        "cohesion table file %s; delete it and run precompute to rebuild it", what);
}

static DrStatus read_desc(DrH5 *h, const char *path, DrCohesionDesc *out, DrError *err)
{
    char *text = NULL;
    DR_TRY(dr_h5_read_attr_str(h, GROUP, "cohesion_version", &text, err));
    bool same = strcmp(text, DR_COHESION_VERSION) == 0;
    char msg[160];
    snprintf(msg, sizeof msg, "was written by cohesion code version \"%.32s\", this is \"%s\"", text,
             DR_COHESION_VERSION);
    free(text);
    if (!same) return bad_file(path, err, msg);
    DR_TRY(dr_h5_read_attr_str(h, GROUP, "shape", &text, err));
    DrCohesionDesc d;
    dr_cohesion_desc_default(&d);
    same = shape_parse(text, &d.shape);
    free(text);
    if (!same) return bad_file(path, err, "records a shape other than \"cylinders\" or \"plane\"");
    int64_t res;
    DR_TRY(dr_h5_read_attr_f64(h, GROUP, "contact_angle_rad", &d.contact_angle, err));
    DR_TRY(dr_h5_read_attr_i64(h, GROUP, "resolution", &res, err));
    DR_TRY(dr_h5_read_attr_f64(h, GROUP, "max_area", &d.max_area, err));
    DR_TRY(dr_h5_read_attr_f64(h, GROUP, "max_gap", &d.max_gap, err));
    if (res < 16 || res > 4096) return bad_file(path, err, "records a resolution outside [16, 4096]");
    d.resolution = (int)res;
    DrError why;
    if (resolve_desc(&d, out, &why) != DR_OK || d.max_gap == 0.0) {
        snprintf(msg, sizeof msg, "records parameters out of range (%.100s)", why.message);
        return bad_file(path, err, msg);
    }
    return DR_OK;
}

static DrStatus read_square(DrH5 *h, const char *path, const char *name, int res, bool f64, void **data, DrError *err)
{
    int rank;
    uint64_t dims[4];
    DR_TRY(f64 ? dr_h5_read_f64(h, name, &rank, dims, (double **)data, err)
               : dr_h5_read_i32(h, name, &rank, dims, (int32_t **)data, err));
    if (rank != 2 || dims[0] != (uint64_t)res || dims[1] != (uint64_t)res) {
        char msg[160];
        snprintf(msg, sizeof msg, "dataset %s is not %d x %d as its resolution says", name, res, res);
        return bad_file(path, err, msg);
    }
    return DR_OK;
}

DrStatus dr_cohesion_read(DrH5 *h, const char *path, DrCohesionTable **out, DrError *err)
{
    *out = NULL;
    DrCohesionDesc d;
    DR_TRY(read_desc(h, path, &d, err));
    DrCohesionTable *t;
    DR_TRY(table_alloc(&d, false, &t, err));
    const int res = d.resolution;
    int64_t points = 0;
    DrStatus s = read_square(h, path, GROUP "/force", res, true, (void **)&t->force, err);
    if (s == DR_OK) s = read_square(h, path, GROUP "/valid", res, false, (void **)&t->valid, err);
    if (s == DR_OK) s = dr_h5_read_attr_f64(h, GROUP, "check_max_error", &t->check_error, err);
    if (s == DR_OK) s = dr_h5_read_attr_i64(h, GROUP, "check_points", &points, err);
    for (size_t k = 0; s == DR_OK && k < (size_t)res * (size_t)res; k++)
        if (!(t->valid[k] == 0 || t->valid[k] == 1 || t->valid[k] == 2) || !isfinite(t->force[k]) ||
            (t->valid[k] == 0 && t->force[k] != 0.0))
            s = bad_file(path, err, "holds a non-finite force, a valid flag other than 0, 1 or 2, or a force where it "
                                    "marks no bridge");
    if (s != DR_OK) {
        dr_cohesion_destroy(&t);
        return s;
    }
    t->check_points = (int)points;
    *out = t;
    return DR_OK;
}

DrStatus dr_cohesion_load(const char *cache_root, const DrCohesionDesc *desc, DrCohesionTable **out, DrError *err)
{
    *out = NULL;
    DrCohesionDesc want;
    DR_TRY(resolve_desc(desc, &want, err));
    char key[33], path[DR_IO_PATH_MAX];
    dr_cohesion_key(&want, key);
    DrH5 *h;
    bool found;
    DrError rejected;
    dr_error_clear(&rejected);
    DR_TRY(dr_io_precache_open(cache_root, COHESION_KIND, key, &h, &found, &rejected, err));
    dr_io_precache_path(cache_root, COHESION_KIND, key, path, sizeof path);
    if (!found)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "the cohesion table of %s at contact angle %g deg (resolution %d) is %s%s; run "
                            "precompute on the scene first",
                            want.shape == DR_COHESION_CYLINDERS ? "hair against hair" : "hair against a solid",
                            want.contact_angle * 180.0 / DR_PI, want.resolution,
                            dr_io_exists(path) ? "not to be trusted: " : "missing",
                            dr_io_exists(path) ? rejected.message : "");
    DrCohesionTable *t;
    DrStatus s = dr_cohesion_read(h, path, &t, err);
    dr_h5_close(&h);
    DR_TRY(s);
    const DrCohesionDesc *got = &t->desc;
    if (got->shape != want.shape || got->contact_angle != want.contact_angle || got->resolution != want.resolution ||
        got->max_area != want.max_area || got->max_gap != want.max_gap) {
        dr_cohesion_destroy(&t);
        return bad_file(path, err, "records other parameters than its key stands for");
    }
    *out = t;
    return DR_OK;
}
