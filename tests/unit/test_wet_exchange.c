/* Unit tests of capture and dripping between the film and the bulk liquid (wet.h, "capture and dripping";
 * src/wet/exchange.c), water on a hair of r = 50 µm in cells of 1 mm (V₀ = 1 mm³/8):
 *  - capture from a cloud of particles around a free strand in zero gravity: bulk + film volume kept to 1e-14
 *    relative, bulk + film + strand momentum to 1e-13 of |P|, no vertex above its capacity, particles wholly captured
 *    leave with volume 0; the capture is the same for any thread count; rate 0 captures nothing;
 *  - middle dripping: a held horizontal hair (a_n = g) loaded with 3 V_max per cell holds at most V_max (1 + 1e-9)
 *    per cell after one call; the drops carry exactly the excess and the momentum the film lost (the strand moving);
 *  - a vertical hair (a_n = 0) does not drip in the middle; its tip pool is released as drops of its volume, moving
 *    with the tip, once it reaches the release volume;
 *  - a forced blow-up (a strand's acceleration of 10⁶ g) emits at most the budget and reports what it held back;
 *  - descs out of range are DR_ERR_INPUT naming the field. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/core.h"
#include "wet/wet.h"

#define CHECK(expr)                                                                                                \
    do {                                                                                                           \
        DrError err_;                                                                                              \
        DrStatus s_ = (expr);                                                                                      \
        if (s_ < 0) fail_msg("%s: status %d: %s", #expr, s_, err_.message);                                       \
    } while (0)
#define ERR (&err_)

static const double RHO = 1000, R = 5e-5, DX = 1e-3;

/* One strand of n vertices from p0 along d, length L, with a film of H/r = ratio, in gravity g. */
static DrFilm *strand(int n, DrVec3 p0, DrVec3 d, double L, double ratio, DrVec3 g, double *x)
{
    for (int j = 0; j < n; j++) {
        DrVec3 p = dr_v3_add(p0, dr_v3_scale(d, L * j / (n - 1)));
        x[3 * j] = p.x, x[3 * j + 1] = p.y, x[3 * j + 2] = p.z;
    }
    double *r = malloc((size_t)n * sizeof(double));
    for (int i = 0; i < n; i++) r[i] = R;
    int off[2] = {0, n};
    DrFilmDesc fd;
    dr_film_desc_default(&fd);
    fd.gravity = g;
    DrFilm *f = NULL;
    CHECK(dr_film_create(&fd, 1, off, r, x, &ratio, &f, ERR));
    free(r);
    return f;
}

static double film_volume(DrFilm *f)
{
    DrFilmState s = dr_film_state(f);
    double v = 0;
    for (int i = 0; i < s.nverts; i++) v += s.volume[i];
    return v + s.pool[0] + s.pool[1];
}

/* strands + film momentum */
static DrVec3 wet_momentum(DrFilm *f, const double *x, const double *v, const double *m, int n)
{
    DrFilmStats st = {0};
    dr_film_measure(f, x, v, &st);
    DrVec3 P = st.momentum;
    for (int i = 0; i < n; i++) P = dr_v3_add(P, dr_v3_scale(dr_v3(v[3 * i], v[3 * i + 1], v[3 * i + 2]), m[i]));
    return P;
}

static DrBulk bulk(long n, const double *x, const double *v, double *vol)
{
    return (DrBulk){n, x, v, vol, DX * DX * DX / 8, DX, dr_v3(-0.05, -0.05, -0.05), dr_v3(0.05, 0.05, 0.05)};
}

/* An exchange with the default descs but capture rate, capacity and drop budget (< 0: the default). */
static DrExchange *exchange(double rate, double capacity, long budget)
{
    DrCaptureDesc cd;
    DrDripDesc dd;
    dr_capture_desc_default(&cd);
    dr_drip_desc_default(&dd);
    if (rate >= 0) cd.rate = rate;
    if (capacity >= 0) cd.capacity = capacity;
    if (budget >= 0) dd.budget = budget;
    DrExchange *e = NULL;
    CHECK(dr_exchange_create(&cd, &dd, &e, ERR));
    return e;
}

enum { NV = 21, NP = 5000 };

static void capture_case(double *px, double *pv, double *pvol, double *x, double *v, double *m, uint64_t seed)
{
    (void)x;
    DrRng rng;
    dr_rng_seed(&rng, seed);
    for (long p = 0; p < NP; p++) {
        /* around the strand (x from 0 to 10 mm), within 1.5 mm */
        px[3 * p] = 0.01 * dr_rng_uniform(&rng);
        px[3 * p + 1] = 1.5e-3 * (2 * dr_rng_uniform(&rng) - 1);
        px[3 * p + 2] = 1.5e-3 * (2 * dr_rng_uniform(&rng) - 1);
        for (int a = 0; a < 3; a++) pv[3 * p + a] = 0.3 * (2 * dr_rng_uniform(&rng) - 1);
        pvol[p] = DX * DX * DX / 8 * (p % 7 == 0 ? 1e-4 : 0.5 + dr_rng_uniform(&rng));
    }
    for (int i = 0; i < NV; i++) {
        v[3 * i] = 0.05, v[3 * i + 1] = -0.02 * i / NV, v[3 * i + 2] = 0.01;
        m[i] = 1e-7;
    }
}

static void test_capture_conserves(void **state)
{
    (void)state;
    double x[3 * NV], v[3 * NV], m[NV], px[3 * NP], pv[3 * NP], pvol[NP];
    DrFilm *f = strand(NV, dr_v3(0, 0, 0), dr_v3(1, 0, 0), 0.01, 1.5, dr_v3(0, 0, 0), x);
    capture_case(px, pv, pvol, x, v, m, 7);
    DrExchange *e = exchange(-1, 0.5, -1);
    DrWetStrands s = {x, v, NULL, m};
    DrBulk b = bulk(NP, px, pv, pvol);
    double V0 = film_volume(f);
    for (long p = 0; p < NP; p++) V0 += pvol[p];
    DrVec3 P0 = wet_momentum(f, x, v, m, NV);
    for (long p = 0; p < NP; p++) P0 = dr_v3_add(P0, dr_v3_scale(dr_v3(pv[3 * p], pv[3 * p + 1], pv[3 * p + 2]), RHO * pvol[p]));
    DrExchangeStats st = {0};
    for (int step = 0; step < 20; step++) CHECK(dr_exchange_capture(e, f, &s, &b, 0.01, &st, ERR));
    double V1 = film_volume(f);
    DrVec3 P1 = wet_momentum(f, x, v, m, NV);
    long empty = 0;
    for (long p = 0; p < NP; p++) {
        V1 += pvol[p];
        assert_true(pvol[p] >= 0);
        empty += pvol[p] == 0;
        P1 = dr_v3_add(P1, dr_v3_scale(dr_v3(pv[3 * p], pv[3 * p + 1], pv[3 * p + 2]), RHO * pvol[p]));
    }
    printf("capture: %.3g m³ in %ld steps, %ld particles whole; volume error %.2e, momentum error %.2e of |P|\n",
           st.captured, 20L, st.captured_particles, fabs(V1 - V0) / V0, dr_v3_norm(dr_v3_sub(P1, P0)) / dr_v3_norm(P0));
    assert_true(st.captured > 0);
    assert_true(empty == st.captured_particles);
    assert_true(fabs(V1 - V0) <= 1e-14 * V0);
    assert_true(dr_v3_norm(dr_v3_sub(P1, P0)) <= 1e-13 * dr_v3_norm(P0));
    /* no vertex above capacity */
    DrFilmState fs = dr_film_state(f);
    const double *lv = dr_film_lengths(f);
    for (int i = 0; i < NV; i++)
        assert_true(fs.volume[i] <= 0.5 * (36.0 - 1.0) * DR_PI * R * R * lv[i] * (1 + 1e-12));
    dr_exchange_destroy(&e);
    dr_film_destroy(&f);
}

/* a small particle next to a dry strand goes whole into its film, volume and momentum exactly */
static void test_capture_remnant(void **state)
{
    (void)state;
    double x[3 * NV], v[3 * NV], m[NV];
    DrFilm *f = strand(NV, dr_v3(0, 0, 0), dr_v3(1, 0, 0), 0.01, 1.0, dr_v3(0, 0, 0), x);
    for (int i = 0; i < 3 * NV; i++) v[i] = 0;
    for (int i = 0; i < NV; i++) m[i] = 1e-7;
    double px[3] = {0.0051, 5.5e-5, 0}, pv[3] = {0.1, -0.2, 0.3}, pvol[1] = {1e-4 * DX * DX * DX / 8};
    DrExchange *e = exchange(-1, -1, -1);
    DrWetStrands s = {x, v, NULL, m};
    DrBulk b = bulk(1, px, pv, pvol);
    double want = pvol[0];
    DrExchangeStats st = {0};
    CHECK(dr_exchange_capture(e, f, &s, &b, 1e-3, &st, ERR));
    assert_true(pvol[0] == 0 && st.captured_particles == 1 && fabs(st.captured - want) <= 1e-15 * want);
    assert_true(fabs(film_volume(f) - want) <= 1e-15 * want);
    DrVec3 P = wet_momentum(f, x, v, m, NV);
    assert_true(dr_v3_norm(dr_v3_sub(P, dr_v3_scale(dr_v3(0.1, -0.2, 0.3), RHO * want))) <= 1e-13 * RHO * want);
    dr_exchange_destroy(&e);
    dr_film_destroy(&f);
}

/* the same capture on 1 and 2 threads: the same bits */
static void test_capture_threads(void **state)
{
    (void)state;
    double out[2][NP];
    
    for (int run = 0; run < 2; run++) {
        dr_set_threads(run + 1);
        double x[3 * NV], v[3 * NV], m[NV], px[3 * NP], pv[3 * NP], pvol[NP];
        DrFilm *f = strand(NV, dr_v3(0, 0, 0), dr_v3(1, 0, 0), 0.01, 1.5, dr_v3(0, 0, 0), x);
        capture_case(px, pv, pvol, x, v, m, 11);
        DrExchange *e = exchange(-1, -1, -1);
        DrWetStrands s = {x, v, NULL, m};
        DrBulk b = bulk(NP, px, pv, pvol);
        for (int step = 0; step < 5; step++) CHECK(dr_exchange_capture(e, f, &s, &b, 0.01, NULL, ERR));
        memcpy(out[run], pvol, sizeof pvol);
        dr_exchange_destroy(&e);
        dr_film_destroy(&f);
    }
    dr_set_threads(0);
    assert_memory_equal(out[0], out[1], sizeof out[0]);
}

static void test_capture_rate_zero(void **state)
{
    (void)state;
    double x[3 * NV], v[3 * NV], m[NV], px[3 * NP], pv[3 * NP], pvol[NP], keep[NP];
    DrFilm *f = strand(NV, dr_v3(0, 0, 0), dr_v3(1, 0, 0), 0.01, 1.5, dr_v3(0, 0, 0), x);
    capture_case(px, pv, pvol, x, v, m, 3);
    memcpy(keep, pvol, sizeof keep);
    DrExchange *e = exchange(0, -1, -1);
    DrWetStrands s = {x, v, NULL, m};
    DrBulk b = bulk(NP, px, pv, pvol);
    CHECK(dr_exchange_capture(e, f, &s, &b, 0.01, NULL, ERR));
    assert_memory_equal(keep, pvol, sizeof keep);
    dr_exchange_destroy(&e);
    dr_film_destroy(&f);
}

/* V_max of a cell of hair with normal acceleration an */
static double vmax(double an, double c) { return 4 * DR_PI * R * 0.072 / (RHO * an) * c * c; }

static void test_drip_middle(void **state)
{
    (void)state;
    /* 41 vertices over 20 mm along x: about 2 vertices per 1 mm cell, the hair at the cells' mid-height */
    enum { N = 41 };
    double x[3 * N], v[3 * N], m[N];
    DrFilm *f = strand(N, dr_v3(0.0001, 0.0005, 0.0005), dr_v3(1, 0, 0), 0.02, 1.0, dr_v3(0, -9.81, 0), x);
    DrFilmState fs = dr_film_state(f);
    double target = 3 * vmax(9.81, 0.5);
    /* per cell: 3 V_max, split over the cell's vertices */
    int cell[N], count[64] = {0};
    for (int i = 0; i < N; i++) {
        cell[i] = (int)floor((x[3 * i] + 0.05) / DX);
        count[cell[i] - 50]++;
    }
    for (int i = 0; i < N; i++) fs.volume[i] = target / count[cell[i] - 50];
    for (int i = 0; i < N; i++) {
        v[3 * i] = 0.02, v[3 * i + 1] = 0.01, v[3 * i + 2] = 0;
        m[i] = 2e-8;
    }
    double acc[3 * N] = {0}; /* not accelerating: a_n = g */
    DrExchange *e = exchange(-1, -1, -1);
    double pvol[1] = {0};
    DrBulk b = bulk(0, NULL, NULL, pvol);
    DrWetStrands s = {x, v, acc, m};
    double V0 = film_volume(f);
    DrVec3 P0 = wet_momentum(f, x, v, m, N);
    DrDrops d;
    DrExchangeStats st = {0};
    CHECK(dr_exchange_drip(e, f, &s, &b, &d, &st, ERR));
    double dv = 0;
    DrVec3 Pd = dr_v3(0, 0, 0);
    for (long q = 0; q < d.n; q++) {
        dv += d.vol[q];
        Pd = dr_v3_add(Pd, dr_v3_scale(dr_v3(d.v[3 * q], d.v[3 * q + 1], d.v[3 * q + 2]), RHO * d.vol[q]));
        assert_true(d.vol[q] <= b.particle_volume * (1 + 1e-12));
    }
    double worst = 0;
    double per[64] = {0};
    for (int i = 0; i < N; i++) per[cell[i] - 50] += fs.volume[i];
    for (int c = 0; c < 64; c++) worst = fmax(worst, per[c] / vmax(9.81, 0.5));
    double V1 = film_volume(f);
    DrVec3 P1 = wet_momentum(f, x, v, m, N);
    printf("middle dripping: %ld drops of %.3g m³ (excess %.3g); fullest cell %.12f V_max; volume error %.2e; "
           "momentum error %.2e of |P|\n",
           d.n, dv, V0 - V1, worst, fabs(V1 + dv - V0) / V0, dr_v3_norm(dr_v3_sub(dr_v3_add(P1, Pd), P0)) / dr_v3_norm(P0));
    assert_true(worst <= 1 + 1e-9);
    assert_true(worst >= 1 - 1e-9);
    assert_true(fabs(V1 + dv - V0) <= 1e-13 * V0);
    assert_true(fabs(dv - 2.0 / 3.0 * V0) <= 1e-9 * V0);
    assert_true(dr_v3_norm(dr_v3_sub(dr_v3_add(P1, Pd), P0)) <= 1e-13 * dr_v3_norm(P0));
    assert_true(fabs(st.dripped - dv) <= 1e-13 * dv && st.drops == d.n && st.held == 0);
    /* drops lie below the strand, beyond capture's reach */
    for (long q = 0; q < d.n; q++) assert_true(d.x[3 * q + 1] < 0.0005 - 2 * R);
    dr_exchange_destroy(&e);
    dr_film_destroy(&f);
}

static void test_drip_vertical(void **state)
{
    (void)state;
    enum { N = 21 };
    double x[3 * N], v[3 * N], m[N];
    DrFilm *f = strand(N, dr_v3(0, 0.01, 0), dr_v3(0, -1, 0), 0.01, 5.0, dr_v3(0, -9.81, 0), x);
    for (int i = 0; i < N; i++) {
        v[3 * i] = 0.0, v[3 * i + 1] = -0.05, v[3 * i + 2] = 0.01;
        m[i] = 2e-8;
    }
    double acc[3 * N] = {0};
    DrFilmState fs = dr_film_state(f);
    DrExchange *e = exchange(-1, -1, -1);
    double pvol[1] = {0};
    DrBulk b = bulk(0, NULL, NULL, pvol);
    DrWetStrands s = {x, v, acc, m};
    DrDrops d;
    fs.pool[1] = 0.9 * b.particle_volume; /* below the release volume */
    double V0 = film_volume(f);
    CHECK(dr_exchange_drip(e, f, &s, &b, &d, NULL, ERR));
    assert_int_equal(d.n, 0);
    assert_true(film_volume(f) == V0);
    fs.pool[1] = 2.5 * b.particle_volume;
    fs.pool[0] = 3 * b.particle_volume; /* the root pool is not released by default */
    V0 = film_volume(f);
    CHECK(dr_exchange_drip(e, f, &s, &b, &d, NULL, ERR));
    assert_int_equal(d.n, 3);
    double dv = 0;
    for (long q = 0; q < d.n; q++) {
        dv += d.vol[q];
        assert_true(d.v[3 * q + 1] == -0.05 && d.v[3 * q] == 0.0 && d.v[3 * q + 2] == 0.01);
        assert_true(d.x[3 * q + 1] < x[3 * (N - 1) + 1]); /* beyond the tip */
    }
    assert_true(fabs(dv - 2.5 * b.particle_volume) <= 1e-15 * dv);
    assert_true(fs.pool[1] == 0 && fs.pool[0] == 3 * b.particle_volume);
    assert_true(fabs(film_volume(f) + dv - V0) <= 1e-15 * V0);
    dr_exchange_destroy(&e);
    dr_film_destroy(&f);
}

static void test_drip_budget(void **state)
{
    (void)state;
    enum { N = 41 };
    double x[3 * N], v[3 * N], m[N], acc[3 * N];
    DrFilm *f = strand(N, dr_v3(0.0001, 0.0005, 0.0005), dr_v3(1, 0, 0), 0.02, 6.0, dr_v3(0, -9.81, 0), x);
    for (int i = 0; i < N; i++) {
        v[3 * i] = 0, v[3 * i + 1] = 0, v[3 * i + 2] = 0;
        acc[3 * i] = 0, acc[3 * i + 1] = -1e7, acc[3 * i + 2] = 0; /* a blow-up: 10⁷ m/s² across the hair */
        m[i] = 2e-8;
    }
    DrExchange *e = exchange(-1, -1, 10);
    double pvol[1] = {0};
    DrBulk b = bulk(0, NULL, NULL, pvol);
    DrWetStrands s = {x, v, acc, m};
    DrDrops d;
    DrExchangeStats st = {0};
    double V0 = film_volume(f);
    CHECK(dr_exchange_drip(e, f, &s, &b, &d, &st, ERR));
    double dv = 0;
    for (long q = 0; q < d.n; q++) dv += d.vol[q];
    printf("blow-up: %ld drops (budget 10), %.3g m³ dripped, %.3g m³ held back\n", d.n, dv, st.held);
    assert_true(d.n <= 10 && st.held > 0);
    assert_true(fabs(film_volume(f) + dv - V0) <= 1e-13 * V0);
    dr_exchange_destroy(&e);
    dr_film_destroy(&f);
}

/* Submersion: a pool 10 mm deep of nominal particles (8 per 1 mm cell): 1 from half a cell under its surface, 0 at
   it and above, in between over that half cell; the same on 1 and 2 threads (it is serial) and a vertex outside the
   lattice takes the nearest cells. */
static void test_submersion(void **state)
{
    (void)state;
    enum { NC = 10 };
    long n = 8L * 20 * 20 * NC, q = 0;
    double *px = malloc(3 * (size_t)n * sizeof(double)), *pv = calloc(3 * (size_t)n, sizeof(double));
    double *vol = malloc((size_t)n * sizeof(double));
    for (int k = 0; k < 20; k++)
        for (int j = 0; j < NC; j++)
            for (int i = 0; i < 20; i++)
                for (int s = 0; s < 8; s++, q++) {
                    px[3 * q] = -0.01 + (i + 0.25 + 0.5 * (s & 1)) * DX;
                    px[3 * q + 1] = -0.05 + (j + 0.25 + 0.5 * ((s >> 1) & 1)) * DX;
                    px[3 * q + 2] = -0.01 + (k + 0.25 + 0.5 * (s >> 2)) * DX;
                    vol[q] = DX * DX * DX / 8;
                }
    DrBulk b = {n, px, pv, vol, DX * DX * DX / 8, DX, dr_v3(-0.01, -0.05, -0.01), dr_v3(0.01, 0.05, 0.01)};
    /* the surface at y = −0.04; vertices at depths 3, 0.5, 0.25 cells, at the surface, above it, and outside the box */
    double x[3 * 6] = {0.0005, -0.0435, 0.0005, 0.0005, -0.0405, 0.0005, 0.0005, -0.04025, 0.0005,
                       0.0005, -0.04, 0.0005,  0.0005, -0.035, 0.0005,  0.02, -0.045, 0.0005};
    double out[6];
    DrExchange *e = exchange(-1, -1, -1);
    CHECK(dr_exchange_submersion(e, x, 6, &b, out, ERR));
    printf("submersion at 3, 0.5, 0.25 cells deep, at the surface, above it, outside: %g %g %g %g %g %g\n", out[0],
           out[1], out[2], out[3], out[4], out[5]);
    assert_true(fabs(out[0] - 1) < 1e-12 && fabs(out[1] - 1) < 1e-12);
    assert_true(fabs(out[2] - 0.5) < 1e-12);
    assert_true(out[3] == 0.0 && out[4] == 0.0);
    assert_true(fabs(out[5] - 1) < 1e-12);
    dr_exchange_destroy(&e);
    free(px), free(pv), free(vol);
}

static void test_bad_desc(void **state)
{
    (void)state;
    DrCaptureDesc cd;
    DrDripDesc dd;
    DrExchange *e = NULL;
    DrError err;
    dr_capture_desc_default(&cd);
    dr_drip_desc_default(&dd);
    cd.capacity = 1.5;
    assert_int_equal(dr_exchange_create(&cd, &dd, &e, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "capacity"));
    dr_capture_desc_default(&cd);
    cd.rate = -1;
    assert_int_equal(dr_exchange_create(&cd, &dd, &e, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "rate"));
    dr_capture_desc_default(&cd);
    dd.budget = 0;
    assert_int_equal(dr_exchange_create(&cd, &dd, &e, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "budget"));
    dr_drip_desc_default(&dd);
    dd.radius_scale = 0;
    assert_int_equal(dr_exchange_create(&cd, &dd, &e, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "radius_scale"));
    assert_null(e);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_capture_conserves), cmocka_unit_test(test_capture_remnant), cmocka_unit_test(test_capture_threads),
        cmocka_unit_test(test_capture_rate_zero), cmocka_unit_test(test_drip_middle),
        cmocka_unit_test(test_drip_vertical),     cmocka_unit_test(test_drip_budget),
        cmocka_unit_test(test_submersion), cmocka_unit_test(test_bad_desc),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
