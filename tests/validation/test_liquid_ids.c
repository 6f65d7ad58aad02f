/* The liquid's particle ids (liquid.h, DrLiquidState.id): given in seeding order, carried with each particle
 * through the per-substep sort, never given twice (emitters take the next unused one, killed ids do not come
 * back), and continued by a checkpoint's resume state. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "liquid/liquid.h"

/* A small dam break (water 0.2 × 0.3 × 0.25 m in a 0.5 × 0.5 × 0.25 m box, 1/32 m cells, 8 per cell), with an
   emitter and a kill box when `flow` is set. */
static DrLiquid *make_dam(bool flow)
{
    static const DrBoxVel water = {{0, 0, 0}, {0.2, 0.3, 0.25}, {0, 0, 0}, 0, 0};
    static const DrBoxVel em = {{0.3, 0.35, 0.1}, {0.4, 0.45, 0.15}, {0, -1, 0}, 0.0, 0.2};
    static const DrVec3 klo = {0.4, 0.0, 0.0}, khi = {0.5, 0.1, 0.25};
    DrLiquidDesc d;
    dr_liquid_desc_default(&d);
    d.domain_hi = dr_v3(0.5, 0.5, 0.25);
    d.dx = 1.0 / 32.0;
    d.nsource_boxes = 1;
    d.source_boxes = &water;
    if (flow) {
        d.nemitters = 1;
        d.emitters = &em;
        d.nkill_boxes = 1;
        d.kill_lo = &klo;
        d.kill_hi = &khi;
    }
    DrLiquid *liq = NULL;
    DrError err;
    assert_int_equal(dr_liquid_create(&d, NULL, 0, &liq, &err), DR_OK);
    return liq;
}

static void advance(DrLiquid *liq, double t0, double t1)
{
    DrLiquidStats st;
    DrError err;
    assert_int_equal(dr_liquid_advance(liq, NULL, 0, t0, t1, &st, &err), DR_OK);
}

/* Every id in [0, next_id) and none twice; marks them in seen[next_id] (zeroed here). */
static void check_distinct(const DrLiquidState *s, int64_t next_id, unsigned char *seen)
{
    memset(seen, 0, (size_t)next_id);
    for (long p = 0; p < s->n; p++) {
        assert_true(s->id[p] >= 0 && s->id[p] < next_id);
        assert_int_equal(seen[s->id[p]], 0);
        seen[s->id[p]] = 1;
    }
}

/* 1. Seeding numbers the particles 0, 1, 2 … in the order it makes them; the counter stands at their count. */
static void test_seeded_in_order(void **state)
{
    (void)state;
    DrLiquid *liq = make_dam(false);
    const DrLiquidState *s = dr_liquid_state(liq);
    assert_true(s->n > 1000);
    for (long p = 0; p < s->n; p++) assert_int_equal(s->id[p], p);
    DrLiquidResume rs;
    dr_liquid_resume_state(liq, &rs);
    assert_int_equal(rs.next_id, s->n);
    dr_liquid_destroy(&liq);
}

/* 2. The sort by cell carries each id with its particle. Over a substep of h = 1e-4 s, advection moves a particle
   by exactly h·v (its new velocity) except where the domain clamp stops it, so x_new − h·v_new must give back
   the position the same id had before, to rounding (1e-12 m: positions under 1 m, h·v under 1e-3 m). The dam
   has collapsed for 6 frames first, so particles have changed cells and the substep's sort reorders them
   (checked: otherwise the test would not see a sort that forgets the ids). */
static void test_ids_follow_the_sort(void **state)
{
    (void)state;
    DrLiquid *liq = make_dam(false);
    for (int f = 0; f < 6; f++) advance(liq, f / 24.0, (f + 1) / 24.0);
    const DrLiquidState *s = dr_liquid_state(liq);
    long n = s->n;
    double *x_by_id = malloc(sizeof(double) * 3 * (size_t)n);
    int64_t *id_before = malloc(sizeof(int64_t) * (size_t)n);
    assert_non_null(x_by_id);
    assert_non_null(id_before);
    const double h = 1e-4, margin = 1e-3;
    long reordered = 0, checked = 0;
    double t = 6 / 24.0;
    for (int step = 0; step < 3; step++, t += h) {
        s = dr_liquid_state(liq);
        for (long p = 0; p < n; p++) {
            assert_true(s->id[p] >= 0 && s->id[p] < n); /* no emitter: the seeded ids only */
            memcpy(x_by_id + 3 * s->id[p], s->x + 3 * p, 3 * sizeof(double));
            id_before[p] = s->id[p];
        }
        advance(liq, t, t + h);
        s = dr_liquid_state(liq);
        assert_int_equal(s->n, n);
        for (long p = 0; p < n; p++) {
            reordered += s->id[p] != id_before[p];
            const double *x = s->x + 3 * p, *v = s->v + 3 * p;
            bool near_wall = x[0] < margin || x[0] > 0.5 - margin || x[1] < margin || x[1] > 0.5 - margin ||
                             x[2] < margin || x[2] > 0.25 - margin;
            if (near_wall) continue;
            for (int a = 0; a < 3; a++) assert_true(fabs(x[a] - h * v[a] - x_by_id[3 * s->id[p] + a]) < 1e-12);
            checked++;
        }
    }
    printf("ids through the sort: %ld particles, %ld checked, %ld moved in the order\n", n, checked, reordered);
    assert_true(reordered > 0);
    assert_true(checked > 2 * n); /* most particles are away from the walls */
    free(x_by_id);
    free(id_before);
    dr_liquid_destroy(&liq);
}

/* 3. An emitter's particles take ids never given before (from the counter up), a killed particle's id never comes
   back, and the counter is the number of particles ever made. */
static void test_emitted_and_killed(void **state)
{
    (void)state;
    DrLiquid *liq = make_dam(true);
    int64_t seeded = dr_liquid_state(liq)->n, emitted = 0, killed = 0;
    enum { CAP = 1 << 20 };
    unsigned char *seen = calloc(CAP, 1), *was = calloc(CAP, 1), *gone = calloc(CAP, 1);
    assert_non_null(seen);
    assert_non_null(was);
    assert_non_null(gone);
    DrLiquidResume rs;
    dr_liquid_resume_state(liq, &rs);
    int64_t next_before = rs.next_id;
    check_distinct(dr_liquid_state(liq), next_before, was);
    for (int f = 0; f < 12; f++) {
        DrLiquidStats st;
        DrError err;
        assert_int_equal(dr_liquid_advance(liq, NULL, 0, f / 24.0, (f + 1) / 24.0, &st, &err), DR_OK);
        emitted += st.emitted;
        killed += st.killed;
        dr_liquid_resume_state(liq, &rs);
        assert_int_equal(rs.next_id, seeded + emitted);
        assert_true(rs.next_id < CAP);
        const DrLiquidState *s = dr_liquid_state(liq);
        check_distinct(s, rs.next_id, seen);
        for (long p = 0; p < s->n; p++) {
            assert_int_equal(gone[s->id[p]], 0);                      /* a killed id never comes back */
            if (!was[s->id[p]]) assert_true(s->id[p] >= next_before); /* new: from the counter up */
        }
        for (int64_t i = 0; i < next_before; i++)
            if (was[i] && !seen[i]) gone[i] = 1;
        memcpy(was, seen, (size_t)rs.next_id);
        next_before = rs.next_id;
    }
    printf("ids: %lld seeded, %lld emitted, %lld killed\n", (long long)seeded, (long long)emitted, (long long)killed);
    assert_true(emitted > 0);
    assert_true(killed > 0);
    assert_int_equal(dr_liquid_state(liq)->n, seeded + emitted - killed);
    free(seen);
    free(was);
    free(gone);
    dr_liquid_destroy(&liq);
}

/* 4. A liquid restored from a copy of another's particles and resume state goes on with the same ids (and the
   same bits) as the original, emitting from the same counter; restore refuses ids out of range or given twice. */
static void test_restore(void **state)
{
    (void)state;
    DrLiquid *a = make_dam(true), *b = make_dam(true);
    for (int f = 0; f < 4; f++) advance(a, f / 24.0, (f + 1) / 24.0);
    const DrLiquidState *sa = dr_liquid_state(a);
    long n = sa->n;
    double *x = malloc(sizeof(double) * 3 * (size_t)n), *v = malloc(sizeof(double) * 3 * (size_t)n);
    double *c = malloc(sizeof(double) * 9 * (size_t)n);
    int64_t *id = malloc(sizeof(int64_t) * (size_t)n);
    memcpy(x, sa->x, sizeof(double) * 3 * (size_t)n);
    memcpy(v, sa->v, sizeof(double) * 3 * (size_t)n);
    memcpy(c, sa->c, sizeof(double) * 9 * (size_t)n);
    memcpy(id, sa->id, sizeof(int64_t) * (size_t)n);
    DrLiquidResume rs;
    dr_liquid_resume_state(a, &rs);
    DrError err;

    DrLiquidResume low = rs;
    low.next_id = 1;
    assert_int_equal(dr_liquid_restore(b, n, x, v, c, NULL, id, &low, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "outside"));
    int64_t keep = id[n - 1];
    id[n - 1] = id[0];
    assert_int_equal(dr_liquid_restore(b, n, x, v, c, NULL, id, &rs, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "two particles"));
    id[n - 1] = keep;

    assert_int_equal(dr_liquid_restore(b, n, x, v, c, NULL, id, &rs, &err), DR_OK);
    for (int f = 4; f < 8; f++) {
        advance(a, f / 24.0, (f + 1) / 24.0);
        advance(b, f / 24.0, (f + 1) / 24.0);
    }
    sa = dr_liquid_state(a);
    const DrLiquidState *sb = dr_liquid_state(b);
    assert_int_equal(sa->n, sb->n);
    assert_memory_equal(sa->id, sb->id, sizeof(int64_t) * (size_t)sa->n);
    assert_memory_equal(sa->x, sb->x, sizeof(double) * 3 * (size_t)sa->n);
    DrLiquidResume ra, rb;
    dr_liquid_resume_state(a, &ra);
    dr_liquid_resume_state(b, &rb);
    assert_int_equal(ra.next_id, rb.next_id);
    assert_true(ra.next_id > rs.next_id); /* the emitter ran on after the copy */
    free(x);
    free(v);
    free(c);
    free(id);
    dr_liquid_destroy(&a);
    dr_liquid_destroy(&b);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_seeded_in_order),
        cmocka_unit_test(test_ids_follow_the_sort),
        cmocka_unit_test(test_emitted_and_killed),
        cmocka_unit_test(test_restore),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
