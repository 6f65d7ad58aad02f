/* The liquid's particle ids and volumes (liquid.h, DrLiquidState.id and .vol).
 * Ids: given in seeding order, carried with each particle through the per-substep sort, never given twice (emitters
 * take the next unused one, killed ids do not come back), and continued by a checkpoint's resume state.
 * Volumes: seeded and emitted particles carry V0 = dx³/per_cell exactly; a particle's mass is the nominal mass times
 * vol/V0 in the totals, the particle volume and the substeps; particles added between substeps take the next ids,
 * zero-volume ones are removed keeping the others' order; a restore carries the volumes bit for bit and refuses bad
 * ones; the stats book the volume emitters add and kill boxes remove; varied volumes run bit-identically on 1 and 2
 * threads. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
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

static void advance(DrLiquid *liq, double t0, double t1, DrLiquidStats *st)
{
    DrLiquidStats tmp;
    DrError err;
    assert_int_equal(dr_liquid_advance(liq, NULL, 0, t0, t1, st ? st : &tmp, &err), DR_OK);
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
    for (int f = 0; f < 6; f++) advance(liq, f / 24.0, (f + 1) / 24.0, NULL);
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
        advance(liq, t, t + h, NULL);
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
    for (int f = 0; f < 4; f++) advance(a, f / 24.0, (f + 1) / 24.0, NULL);
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
        advance(a, f / 24.0, (f + 1) / 24.0, NULL);
        advance(b, f / 24.0, (f + 1) / 24.0, NULL);
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

/* ---- volumes ---- */

static bool all_finite(const DrLiquidState *s)
{
    for (long i = 0; i < 3 * s->n; i++)
        if (!isfinite(s->x[i]) || !isfinite(s->v[i])) return false;
    return true;
}

static double volume_sum(const DrLiquidState *s)
{
    double sum = 0.0;
    for (long p = 0; p < s->n; p++) sum += s->vol[p];
    return sum;
}

/* 1. Seeding gives every particle V0 exactly, and V0 is dx³/per_cell; the nominal mass is density·V0. */
static void test_seeded_nominal(void **state)
{
    (void)state;
    DrLiquid *liq = make_dam(false);
    const DrLiquidState *s = dr_liquid_state(liq);
    double v0 = dr_liquid_nominal_volume(liq), dx = 1.0 / 32.0;
    assert_true(v0 == dx * dx * dx / 8);
    assert_true(fabs(dr_liquid_particle_mass(liq) - 1000.0 * v0) <= 1e-15 * dr_liquid_particle_mass(liq));
    assert_true(s->n > 1000);
    for (long p = 0; p < s->n; p++) assert_true(s->vol[p] == v0);
    dr_liquid_destroy(&liq);
}

/* 2. Every particle at half its volume (through dr_liquid_state_mut): the total mass, momentum and kinetic energy are
   half a nominal twin's, the particle volume counts half; a dam break of a few substeps stays finite and keeps the
   halved mass (no particle leaves: no kill box). */
static void test_half_volume(void **state)
{
    (void)state;
    DrLiquid *a = make_dam(false), *b = make_dam(false);
    DrLiquidState *sa = dr_liquid_state_mut(a), *sb = dr_liquid_state_mut(b);
    double v0 = dr_liquid_nominal_volume(b);
    assert_int_equal(sa->n, sb->n);
    for (long p = 0; p < sb->n; p++) {
        sb->vol[p] = 0.5 * v0;
        for (int d = 0; d < 3; d++) sb->v[3 * p + d] = sa->v[3 * p + d] = 0.1 * (d + 1);
    }
    double ma, mb, ka, kb;
    DrVec3 pa, pb, la, lb;
    dr_liquid_totals(a, &ma, &pa, &la, &ka);
    dr_liquid_totals(b, &mb, &pb, &lb, &kb);
    /* sums of ~10⁴ equal terms against n·m: round-off ~1e-12 at most */
    assert_true(fabs(mb - 0.5 * ma) <= 1e-12 * ma);
    assert_true(fabs(kb - 0.5 * ka) <= 1e-12 * ka);
    assert_true(dr_v3_norm(dr_v3_sub(dr_v3_scale(pa, 0.5), pb)) <= 1e-12 * dr_v3_norm(pa));
    assert_true(dr_v3_norm(dr_v3_sub(dr_v3_scale(la, 0.5), lb)) <= 1e-12 * dr_v3_norm(la));
    double va, na, vb, nb;
    DrError err;
    assert_int_equal(dr_liquid_particle_volume(a, &va, &na, &err), DR_OK);
    assert_int_equal(dr_liquid_particle_volume(b, &vb, &nb, &err), DR_OK);
    printf("nominal: volume %.6g of %.6g m^3; half: %.6g of %.6g m^3\n", va, na, vb, nb);
    assert_true(va > 0.9 * na); /* freshly seeded: no block holds more than it did when full */
    assert_true(fabs(vb - 0.5 * va) <= 1e-12 * va);
    assert_true(fabs(nb - 0.5 * na) <= 1e-12 * na);

    for (int f = 0; f < 3; f++) advance(b, f / 24.0, (f + 1) / 24.0, NULL);
    const DrLiquidState *s = dr_liquid_state(b);
    assert_true(all_finite(s));
    for (long p = 0; p < s->n; p++) assert_true(s->vol[p] == 0.5 * v0); /* carried through the sorts */
    dr_liquid_totals(b, &mb, NULL, NULL, NULL);
    assert_true(fabs(mb - 0.5 * ma) <= 1e-12 * ma);
    double vmax = 0.0;
    for (long i = 0; i < 3 * s->n; i++) vmax = fmax(vmax, fabs(s->v[i]));
    printf("half-volume dam break after 3 frames: max |v| %.3f m/s\n", vmax);
    assert_true(vmax < 5.0); /* a 0.3 m column falls at √(2 g h) ≈ 2.4 m/s at most */
    dr_liquid_destroy(&a);
    dr_liquid_destroy(&b);
}

/* 3. dr_liquid_add_particles appends with the next ids, c = 0, the volumes given; bad input adds nothing. */
static void test_add_particles(void **state)
{
    (void)state;
    DrLiquid *liq = make_dam(false);
    advance(liq, 0.0, 1.0 / 24.0, NULL);
    const DrLiquidState *s = dr_liquid_state(liq);
    long n0 = s->n;
    DrLiquidResume r0;
    dr_liquid_resume_state(liq, &r0);
    double v0 = dr_liquid_nominal_volume(liq);
    double x[9] = {0.4, 0.3, 0.1, 0.45, 0.35, 0.12, 0.5, 0.5, 0.25}; /* the last on the box's corner (closed box) */
    double v[9] = {0, -1, 0, 0.5, 0, 0, 0, 0, 0};
    double vol[3] = {v0, 0.25 * v0, 3.0 * v0};
    DrError err;

    double bad[9];
    memcpy(bad, x, sizeof bad);
    bad[4] = NAN;
    assert_int_equal(dr_liquid_add_particles(liq, 3, bad, v, vol, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "particle 1"));
    assert_non_null(strstr(err.message, "position y"));
    memcpy(bad, v, sizeof bad);
    bad[6] = INFINITY;
    assert_int_equal(dr_liquid_add_particles(liq, 3, x, bad, vol, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "particle 2"));
    assert_non_null(strstr(err.message, "velocity x"));
    memcpy(bad, x, sizeof bad);
    bad[2] = -1e-9;
    assert_int_equal(dr_liquid_add_particles(liq, 3, bad, v, vol, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "particle 0"));
    assert_non_null(strstr(err.message, "outside the domain"));
    double badvol[3][3] = {{v0, 0.0, v0}, {v0, -v0, v0}, {v0, v0, NAN}};
    const char *who[3] = {"particle 1", "particle 1", "particle 2"};
    for (int k = 0; k < 3; k++) {
        assert_int_equal(dr_liquid_add_particles(liq, 3, x, v, badvol[k], &err), DR_ERR_INPUT);
        assert_non_null(strstr(err.message, who[k]));
        assert_non_null(strstr(err.message, "volume"));
    }
    s = dr_liquid_state(liq);
    DrLiquidResume r1;
    dr_liquid_resume_state(liq, &r1);
    assert_int_equal(s->n, n0); /* nothing added */
    assert_int_equal(r1.next_id, r0.next_id);

    assert_int_equal(dr_liquid_add_particles(liq, 3, x, v, vol, &err), DR_OK);
    s = dr_liquid_state(liq);
    assert_int_equal(s->n, n0 + 3);
    for (int k = 0; k < 3; k++) {
        long p = n0 + k;
        assert_int_equal(s->id[p], r0.next_id + k);
        assert_memory_equal(s->x + 3 * p, x + 3 * k, 3 * sizeof(double));
        assert_memory_equal(s->v + 3 * p, v + 3 * k, 3 * sizeof(double));
        assert_true(s->vol[p] == vol[k]);
        for (int q = 0; q < 9; q++) assert_true(s->c[9 * p + q] == 0.0);
    }
    dr_liquid_resume_state(liq, &r1);
    assert_int_equal(r1.next_id, r0.next_id + 3);
    assert_int_equal(dr_liquid_add_particles(liq, 0, NULL, NULL, NULL, &err), DR_OK);

    /* between stable_dt and begin: begin transfers again; the added particles go on with their ids and volumes, and
       they are not counted as emitted */
    double h, t = 1.0 / 24.0;
    DrLiquidStats st;
    memset(&st, 0, sizeof st);
    assert_int_equal(dr_liquid_stable_dt(liq, NULL, 0, t, 2.0 / 24.0, &h, &err), DR_OK);
    double x2[3] = {0.25, 0.2, 0.2}, v2[3] = {0, 0, 0}, vol2 = 0.5 * v0;
    assert_int_equal(dr_liquid_add_particles(liq, 1, x2, v2, &vol2, &err), DR_OK);
    assert_int_equal(dr_liquid_begin(liq, NULL, 0, t, h, &err), DR_OK);
    assert_int_equal(dr_liquid_project(liq, NULL, &st, &err), DR_OK);
    assert_int_equal(dr_liquid_end(liq, &st, &err), DR_OK);
    assert_int_equal(st.emitted, 0);
    assert_true(st.emitted_volume == 0.0);
    s = dr_liquid_state(liq);
    assert_int_equal(s->n, n0 + 4);
    assert_true(all_finite(s));
    double want[4] = {vol[0], vol[1], vol[2], vol2};
    int found = 0;
    for (long p = 0; p < s->n; p++)
        if (s->id[p] >= r0.next_id) {
            assert_true(s->vol[p] == want[s->id[p] - r0.next_id]);
            found++;
        }
    assert_int_equal(found, 4);
    dr_liquid_destroy(&liq);
}

/* 4. dr_liquid_remove_empty removes exactly the zero-volume particles, keeps the others' order, ids and volumes; the
   removed ids never come back (the emitter goes on from the counter). */
static void test_remove_empty(void **state)
{
    (void)state;
    DrLiquid *liq = make_dam(true);
    advance(liq, 0.0, 1.0 / 24.0, NULL);
    DrLiquidState *s = dr_liquid_state_mut(liq);
    long n0 = s->n, kept = 0;
    double v0 = dr_liquid_nominal_volume(liq);
    DrLiquidResume r0;
    dr_liquid_resume_state(liq, &r0);
    unsigned char *removed = calloc((size_t)r0.next_id, 1);
    int64_t *ids = malloc(sizeof(int64_t) * (size_t)n0);
    double *vols = malloc(sizeof(double) * (size_t)n0), *xs = malloc(sizeof(double) * 3 * (size_t)n0);
    for (long p = 0; p < n0; p++) {
        if (p % 3 == 1) {
            s->vol[p] = 0.0;
            removed[s->id[p]] = 1;
            continue;
        }
        if (p % 3 == 2) s->vol[p] = 0.75 * v0;
        ids[kept] = s->id[p];
        vols[kept] = s->vol[p];
        memcpy(xs + 3 * kept, s->x + 3 * p, 3 * sizeof(double));
        kept++;
    }
    assert_int_equal(dr_liquid_remove_empty(liq), n0 - kept);
    const DrLiquidState *c = dr_liquid_state(liq);
    assert_int_equal(c->n, kept);
    assert_memory_equal(c->id, ids, sizeof(int64_t) * (size_t)kept);
    assert_memory_equal(c->vol, vols, sizeof(double) * (size_t)kept);
    assert_memory_equal(c->x, xs, 3 * sizeof(double) * (size_t)kept);
    assert_int_equal(dr_liquid_remove_empty(liq), 0);
    DrLiquidStats st;
    advance(liq, 1.0 / 24.0, 3.0 / 24.0, &st);
    assert_true(st.emitted > 0);
    c = dr_liquid_state(liq);
    for (long p = 0; p < c->n; p++)
        if (c->id[p] < r0.next_id) assert_int_equal(removed[c->id[p]], 0);
        else assert_true(c->vol[p] == v0); /* emitted: nominal, new ids */
    free(removed);
    free(ids);
    free(vols);
    free(xs);
    dr_liquid_destroy(&liq);
}

/* 5. A restore carries the volumes: two liquids, one restored from the other's particles (volumes varied), go on
   bit-identically; NULL volumes are nominal; a volume that is 0, negative or not finite is refused, naming the
   particle. */
static void test_restore_volume(void **state)
{
    (void)state;
    DrLiquid *a = make_dam(true), *b = make_dam(true);
    DrLiquidState *sa = dr_liquid_state_mut(a);
    double v0 = dr_liquid_nominal_volume(a);
    for (long p = 0; p < sa->n; p++) sa->vol[p] = v0 * (0.5 + 0.25 * (double)(p % 4));
    for (int f = 0; f < 2; f++) advance(a, f / 24.0, (f + 1) / 24.0, NULL);
    long n = sa->n;
    double *x = malloc(sizeof(double) * 3 * (size_t)n), *v = malloc(sizeof(double) * 3 * (size_t)n);
    double *c = malloc(sizeof(double) * 9 * (size_t)n), *vol = malloc(sizeof(double) * (size_t)n);
    int64_t *id = malloc(sizeof(int64_t) * (size_t)n);
    memcpy(x, sa->x, sizeof(double) * 3 * (size_t)n);
    memcpy(v, sa->v, sizeof(double) * 3 * (size_t)n);
    memcpy(c, sa->c, sizeof(double) * 9 * (size_t)n);
    memcpy(vol, sa->vol, sizeof(double) * (size_t)n);
    memcpy(id, sa->id, sizeof(int64_t) * (size_t)n);
    DrLiquidResume rs;
    dr_liquid_resume_state(a, &rs);
    DrError err;

    double bad[3] = {0.0, -v0, NAN};
    for (int k = 0; k < 3; k++) {
        double keep = vol[5];
        vol[5] = bad[k];
        assert_int_equal(dr_liquid_restore(b, n, x, v, c, vol, id, &rs, &err), DR_ERR_INPUT);
        assert_non_null(strstr(err.message, "particle 5"));
        assert_non_null(strstr(err.message, "volume"));
        vol[5] = keep;
    }
    assert_int_equal(dr_liquid_restore(b, n, x, v, c, NULL, id, &rs, &err), DR_OK);
    const DrLiquidState *sb = dr_liquid_state(b);
    for (long p = 0; p < n; p++) assert_true(sb->vol[p] == v0);

    assert_int_equal(dr_liquid_restore(b, n, x, v, c, vol, id, &rs, &err), DR_OK);
    assert_memory_equal(dr_liquid_state(b)->vol, vol, sizeof(double) * (size_t)n);
    DrLiquidStats st_a, st_b;
    for (int f = 2; f < 4; f++) {
        advance(a, f / 24.0, (f + 1) / 24.0, &st_a);
        advance(b, f / 24.0, (f + 1) / 24.0, &st_b);
    }
    sa = dr_liquid_state_mut(a);
    sb = dr_liquid_state(b);
    assert_int_equal(sa->n, sb->n);
    assert_memory_equal(sa->x, sb->x, sizeof(double) * 3 * (size_t)sa->n);
    assert_memory_equal(sa->v, sb->v, sizeof(double) * 3 * (size_t)sa->n);
    assert_memory_equal(sa->vol, sb->vol, sizeof(double) * (size_t)sa->n);
    assert_memory_equal(sa->id, sb->id, sizeof(int64_t) * (size_t)sa->n);
    assert_true(st_a.killed_energy == st_b.killed_energy);
    free(x);
    free(v);
    free(c);
    free(vol);
    free(id);
    dr_liquid_destroy(&a);
    dr_liquid_destroy(&b);
}

/* 6. The volume ledger: Σ vol after a run equals Σ vol before plus emitted_volume minus killed_volume (mixed
   volumes: the killed ones count their own), emitted_volume is emitted·V0, and the totals' mass is Σ density·vol. */
static void test_volume_ledger(void **state)
{
    (void)state;
    DrLiquid *liq = make_dam(true);
    DrLiquidState *s = dr_liquid_state_mut(liq);
    double v0 = dr_liquid_nominal_volume(liq);
    for (long p = 0; p < s->n; p++) s->vol[p] = v0 * (p % 2 ? 0.5 : 1.5);
    double before = volume_sum(s), emitted = 0.0, killed = 0.0;
    long nemit = 0, nkill = 0;
    for (int f = 0; f < 8; f++) {
        DrLiquidStats st;
        advance(liq, f / 24.0, (f + 1) / 24.0, &st);
        emitted += st.emitted_volume;
        killed += st.killed_volume;
        nemit += st.emitted;
        nkill += st.killed;
    }
    s = dr_liquid_state_mut(liq);
    double after = volume_sum(s);
    printf("volume: before %.6g, emitted %.6g (%ld), killed %.6g (%ld), after %.6g m^3\n", before, emitted, nemit,
           killed, nkill, after);
    assert_true(nemit > 0 && nkill > 0);
    /* sums of ~10⁴ terms: round-off ~1e-13 of the total */
    assert_true(fabs(emitted - (double)nemit * v0) <= 1e-12 * emitted);
    assert_true(fabs(after - (before + emitted - killed)) <= 1e-12 * before);
    double mass;
    dr_liquid_totals(liq, &mass, NULL, NULL, NULL);
    assert_true(fabs(mass - 1000.0 * after) <= 1e-12 * mass);
    dr_liquid_destroy(&liq);
}

/* 7. Varied volumes on 1 and on 2 threads: bit-identical (the level set sums a cell's factors in particle order). */
static void test_threads(void **state)
{
    (void)state;
    DrLiquid *liq[2];
    for (int t = 0; t < 2; t++) {
        dr_set_threads(t + 1);
        liq[t] = make_dam(true);
        DrLiquidState *s = dr_liquid_state_mut(liq[t]);
        double v0 = dr_liquid_nominal_volume(liq[t]);
        for (long p = 0; p < s->n; p++) s->vol[p] = v0 * (0.3 + 0.1 * (double)(p % 13));
        for (int f = 0; f < 3; f++) advance(liq[t], f / 24.0, (f + 1) / 24.0, NULL);
    }
    dr_set_threads(0);
    const DrLiquidState *a = dr_liquid_state(liq[0]), *b = dr_liquid_state(liq[1]);
    assert_int_equal(a->n, b->n);
    assert_memory_equal(a->x, b->x, sizeof(double) * 3 * (size_t)a->n);
    assert_memory_equal(a->v, b->v, sizeof(double) * 3 * (size_t)a->n);
    assert_memory_equal(a->vol, b->vol, sizeof(double) * (size_t)a->n);
    dr_liquid_destroy(&liq[0]);
    dr_liquid_destroy(&liq[1]);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_seeded_in_order),
        cmocka_unit_test(test_ids_follow_the_sort),
        cmocka_unit_test(test_emitted_and_killed),
        cmocka_unit_test(test_restore),
        cmocka_unit_test(test_seeded_nominal), cmocka_unit_test(test_half_volume),
        cmocka_unit_test(test_add_particles),  cmocka_unit_test(test_remove_empty),
        cmocka_unit_test(test_restore_volume), cmocka_unit_test(test_volume_ledger),
        cmocka_unit_test(test_threads),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
