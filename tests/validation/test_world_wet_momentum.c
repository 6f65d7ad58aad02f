/* The momentum ledger of wet hair and the bulk liquid in the world (README "Wet hair and bulk liquid"): a patch of loose
 * wet strands (Groom.roots "free") in a gravity-free blob of water that floats inside its box, so that neither the
 * walls nor a scalp push anything. The blob moves; the strands feel its drag (the coupled loop), capture its water and
 * drip their film back. After every clock step the world compares liquid + strands + film momentum with the step
 * before (/diagnostics/momentum_ledger, read back from each frame's cache): with nothing outside acting it must stay
 * constant to round-off. The scene is written to a temporary folder with its curves and its cohesion tables (built as
 * precompute builds them), and the world steps it frame by frame. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "world_run.h"

#include "io/io.h"
#include "liquid/liquid.h"
#include "stage/stage.h"
#include "world/world.h"

/* The patch: NS × NS strands of NV vertices, 3 cm long along y, in rows 6 mm apart along z of strands 0.8 mm apart along x
   (their films bridge and they touch), their lower part in the blob. */
#define NS 5
#define NV 8
#define FRAMES 4

/* 1e-8 of |P| per step is the acceptance bound; the ledger is a sum over 5,000 particles and the solves behind it stop
   at relative tolerances far below, so a conserving step shows round-off (1e-14–1e-12), a missing exchange shows as
   the hair's or the film's momentum change (1e-6–1e-4 of |P| here). */
#define TOL 1e-8

static const char *SCENE =
    "{\"shot\": {\"name\": \"wet_momentum\", \"fps\": 24, \"frames\": [1, %d], \"gravity\": [0, 0, 0]},"
    " \"solver\": {\"cfl\": 1.0, \"max_substeps\": 64, \"coupling_iterations\": 3},"
    " \"elements\": ["
    "  {\"name\": \"water\", \"type\": \"liquid\", \"components\": {"
    "    \"Domain\": {\"box\": [[0, 0, 0], [0.2, 0.2, 0.2]], \"voxel_size\": 0.01},"
    "    \"LiquidSource\": {\"box\": [[0.05, 0.05, 0.05], [0.13, 0.12, 0.15]], \"velocity\": [0.25, 0.05, 0]},"
    "    \"Pressure\": {\"formulation\": \"mass_weighted\"}, \"Transfer\": {\"scheme\": \"apic\"},"
    "    \"Particles\": {\"per_cell\": 8, \"seed\": 3}}},"
    "  {\"name\": \"fur\", \"type\": \"hair\", \"components\": {"
    "    \"Groom\": {\"curves\": \"curves.obj\", \"roots\": \"%s\"},"
    "    \"RodMaterial\": {\"radius\": 1e-4, \"youngs_modulus\": 1e8, \"damping\": 0.002},"
    "    \"HairSolver\": {\"substeps\": 4, \"tolerance\": 1e-12},"
    "    \"Wetting\": {%s},"
    "    \"Film\": {\"initial_ratio\": 3, \"max_ratio\": 6},"
    "    \"Cohesion\": {\"table_resolution\": 48},"
    "    \"Capture\": {\"rate\": 20},"
    "    \"Dripping\": {\"radius_scale\": 0.002, \"min_drop\": 0, \"pool_release\": 1e-4},"
    "    \"Drag\": {}}}]}";

typedef WorldRun Run;

/* The strands as OBJ polylines, root first (the caller frees the text). */
static char *curves_text(void)
{
    char *obj = calloc(1, 64 * NS * NS * NV + 4096);
    assert_non_null(obj);
    size_t n = 0;
    for (int i = 0; i < NS; i++)
        for (int k = 0; k < NS; k++)
            for (int j = 0; j < NV; j++)
                n += (size_t)sprintf(obj + n, "v %.6f %.6f %.6f\n", 0.085 + 0.0008 * i + 0.0004 * j,
                                     0.095 + 0.03 * j / (NV - 1), 0.088 + 0.006 * k);
    for (int s = 0; s < NS * NS; s++) {
        n += (size_t)sprintf(obj + n, "l");
        for (int j = 0; j < NV; j++) n += (size_t)sprintf(obj + n, " %d", s * NV + j + 1);
        n += (size_t)sprintf(obj + n, "\n");
    }
    return obj;
}

/* The scene with its strands' roots `roots` (Groom.roots) and its Wetting component's fields. */
static void run_open(Run *r, const char *roots, const char *wetting)
{
    char json[8192];
    snprintf(json, sizeof json, SCENE, FRAMES, roots, wetting);
    char *curves = curves_text();
    world_run_open(r, "wet_momentum", json, curves);
    free(curves);
}

static void run_close(Run *r) { world_run_close(r); }

/* A frame's diagnostics as the frame cache holds them. */
typedef struct Ledger {
    double relative, residual, steps, captured, dripped, drops, volume_error, bridges;
    double total[3], liquid[3], hair[3], film[3], external[3], captured_momentum[3], dripped_momentum[3];
    double film_pressure[3];
} Ledger;

static double read_scalar(DrH5 *h, const char *path)
{
    int rank;
    uint64_t dims[4];
    double *data = NULL;
    DrError err;
    if (dr_h5_read_f64(h, path, &rank, dims, &data, &err) < 0) fail_msg("%s: %s", path, err.message);
    double v = data[0];
    free(data);
    return v;
}

static void read_vec3(DrH5 *h, const char *path, double out[3])
{
    int rank;
    uint64_t dims[4];
    double *data = NULL;
    DrError err;
    if (dr_h5_read_f64(h, path, &rank, dims, &data, &err) < 0) fail_msg("%s: %s", path, err.message);
    assert_int_equal(dims[0], 3);
    memcpy(out, data, 3 * sizeof(double));
    free(data);
}

/* Steps one frame, writes its frame cache and reads the ledgers back. */
static void step(Run *r, Ledger *l)
{
    DrError err;
    DrFrameStats st;
    if (dr_world_step_frame(r->world, &st, &err) < 0) fail_msg("%s", err.message);
    char path[512];
    snprintf(path, sizeof path, "%s/frame.h5", r->dir);
    DrH5 *h = NULL;
    if (dr_h5_create(path, &h, &err) < 0 || dr_world_write_frame(r->world, &st, "k", h, &err) < 0 ||
        dr_h5_commit(&h, &err) < 0)
        fail_msg("%s", err.message);
    if (dr_h5_open(path, &h, &err) < 0) fail_msg("%s", err.message);
    const char *m = "/diagnostics/momentum_ledger", *v = "/diagnostics/volume_ledger";
    char p[256];
#define SCALAR(group, name) (snprintf(p, sizeof p, "%s/%s", group, name), read_scalar(h, p))
#define VEC3(group, name, out) (snprintf(p, sizeof p, "%s/%s", group, name), read_vec3(h, p, out))
    l->relative = SCALAR(m, "relative_change_max");
    l->residual = SCALAR(m, "residual_max");
    l->steps = SCALAR(m, "steps");
    l->bridges = read_scalar(h, "/diagnostics/hair_bridges");
    VEC3(m, "total", l->total);
    VEC3(m, "liquid", l->liquid);
    VEC3(m, "hair", l->hair);
    VEC3(m, "film", l->film);
    VEC3(m, "external", l->external);
    VEC3(m, "film_pressure_impulse", l->film_pressure);
    l->captured = SCALAR(v, "captured");
    l->dripped = SCALAR(v, "dripped");
    l->drops = SCALAR(v, "drops");
    l->volume_error = SCALAR(v, "relative_error");
    VEC3(v, "captured_momentum", l->captured_momentum);
    VEC3(v, "dripped_momentum", l->dripped_momentum);
#undef SCALAR
#undef VEC3
    dr_h5_close(&h);
    unlink(path);
}

static double norm3(const double a[3]) { return sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }
static double dist3(const double a[3], const double b[3])
{
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return norm3(d);
}

/* The liquid's momentum at the start (the strands and their film are at rest). */
static void start_momentum(const Run *r, double P[3])
{
    double m, ke;
    DrVec3 p, l;
    dr_liquid_totals(dr_world_liquid(r->world, 0), &m, &p, &l, &ke);
    P[0] = p.x, P[1] = p.y, P[2] = p.z;
}

/* Free wet strands in a moving, floating blob, gravity off: every step of every frame keeps liquid + strands + film
   momentum to TOL of |P|, through drag, capture and dripping, while the liquid's and the hair's momenta change by far
   more than that. */
static void test_floating_blob(void **state)
{
    (void)state;
    Run r;
    run_open(&r, "free", "\"liquid\": \"water\"");
    double liquid0[3], zero[3] = {0, 0, 0}; /* at the start the strands and their film are at rest */
    start_momentum(&r, liquid0);
    double captured = 0, dripped = 0, drops = 0, bridges = 0, worst = 0, hair_max = 0, film_max = 0, liquid_max = 0;
    double P = 0, pressure = 0;
    for (int f = 1; f <= FRAMES; f++) {
        Ledger l;
        step(&r, &l);
        printf("frame %d: %2.0f steps, largest step change %.3e of |P| (%.3e kg m/s); P %.9e %.3e %.3e kg m/s: liquid "
               "%.9e, hair %.3e, film %.3e (x); captured %.3e m^3, dripped %.3e m^3 in %.0f drops; %.0f bridges; "
               "volume error %.1e\n",
               f, l.steps, l.relative, l.residual, l.total[0], l.total[1], l.total[2], l.liquid[0], l.hair[0],
               l.film[0], l.captured, l.dripped, l.drops, l.bridges, l.volume_error);
        assert_true(l.steps > 0);
        assert_true(norm3(l.external) == 0.0); /* no gravity: nothing outside */
        worst = fmax(worst, l.relative);
        captured += l.captured;
        dripped += l.dripped;
        drops += l.drops;
        bridges += l.bridges;
        liquid_max = fmax(liquid_max, dist3(l.liquid, liquid0));
        hair_max = fmax(hair_max, dist3(l.hair, zero));
        film_max = fmax(film_max, dist3(l.film, zero));
        P = norm3(l.total);
        pressure = fmax(pressure, norm3(l.film_pressure));
        assert_true(fabs(l.volume_error) <= 1e-12);
    }
    printf("largest per-step change of liquid + hair + film momentum %.3e of |P| = %.4e kg m/s; since the start the "
           "liquid's momentum changed by %.3e, the hair's by %.3e, the film's by %.3e of |P|\n",
           worst, P, liquid_max / P, hair_max / P, film_max / P);
    printf("the bulk's pressure on the film: up to %.3e N s in a frame (%.3e of |P|), booked in the ledger\n", pressure,
           pressure / P);
    assert_true(captured > 0);
    assert_true(dripped > 0 && drops > 0);
    assert_true(bridges > 0);
    assert_true(worst <= TOL);
    /* not trivially kept: each part moved by far more than the bound */
    assert_true(liquid_max > 100 * TOL * P);
    assert_true(hair_max > 100 * TOL * P);
    assert_true(film_max > 100 * TOL * P);
    assert_true(pressure > 100 * TOL * P); /* the pressure on the film is there, and booked to the ledger's round-off */
    run_close(&r);
}

/* The ledger sees what acts from outside. Roots clamped to a still scalp hold the strands against the flow: every step
   the scalp's reaction shows, at 1e-4 of |P| here. */
static void test_clamped_roots(void **state)
{
    (void)state;
    Run r;
    run_open(&r, "clamped", "\"liquid\": \"water\"");
    double worst = 0;
    for (int f = 1; f <= 2; f++) {
        Ledger l;
        step(&r, &l);
        worst = fmax(worst, l.relative);
    }
    printf("clamped roots: the largest per-step change %.3e of |P| (the scalp's reaction)\n", worst);
    assert_true(worst > 1e-6);
    run_close(&r);
}

/* A film denser than the liquid (Wetting.density 1200 against the liquid's 1000, not Wetting.liquid): capture and
   dripping move volume one for one (the volume ledger), so the momentum changes by exactly what the density difference
   carries, (1 − ρ_liquid/ρ_film) × (the captured momentum − the dripped momentum) over each frame, both booked at the
   film's density. */
static void test_denser_film(void **state)
{
    (void)state;
    Run r;
    run_open(&r, "free", "\"density\": 1200");
    double prev[3], worst = 0, largest = 0;
    start_momentum(&r, prev);
    for (int f = 1; f <= 2; f++) {
        Ledger l;
        step(&r, &l);
        for (int a = 0; a < 3; a++) {
            double want = (1.0 - 1000.0 / 1200.0) * (l.captured_momentum[a] - l.dripped_momentum[a]);
            worst = fmax(worst, fabs(l.total[a] - prev[a] - want));
            largest = fmax(largest, fabs(want));
        }
        memcpy(prev, l.total, sizeof prev);
        assert_true(l.relative > 1e-7);
    }
    printf("denser film: the frame's momentum change is the density difference's to %.3e kg m/s (of %.3e)\n", worst,
           largest);
    /* round-off of sums of |P| ≈ 0.14 over 8 steps */
    assert_true(worst <= 1e-13);
    assert_true(largest > 1e-8);
    run_close(&r);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_floating_blob),
        cmocka_unit_test(test_clamped_roots),
        cmocka_unit_test(test_denser_film),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
