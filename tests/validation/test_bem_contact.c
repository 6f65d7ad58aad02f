/* Validation of the constraint step of BEM §3.4 (src/bem/bem_constraint.c): Coulomb friction against the rigid
 * stopping distance, fixed vertices held to their targets, the volume of a beam hanging from a fixed end with and
 * without the moving frame (BEM Fig. 5), a long drop-and-rest run with dense and compressed matrices, point joints,
 * and rejected input. Matrices are built here on small meshes so the whole binary runs in seconds. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bem/bem.h"
#include "bem/bem_internal.h"

/* ---- scene helpers ---------------------------------------------------------------------------------------- */

/* The floor y = 0: exact signed distance, outward normal +y. */
static double floor_sdf(const double x[3], double grad[3], void *ctx)
{
    (void)ctx;
    if (grad) grad[0] = 0, grad[1] = 1, grad[2] = 0;
    return x[1];
}

/* Contact with one collider (and, if asked, between the bodies), solved to 1e-6 m. */
static DrBemConstraints on_collider(const DrBemCollider *col, bool body_contact)
{
    DrBemConstraints c;
    dr_bem_constraints_default(&c);
    c.colliders = col;
    c.collider_count = 1;
    c.body_contact = body_contact;
    c.tolerance = 1e-6;
    return c;
}

static DrBemMatrices *build_box(const double lo[3], const double hi[3], const int seg[3], const DrBemDesc *d)
{
    DrTriMesh m = {0};
    DrError err;
    assert_int_equal(dr_bem_mesh_box(lo, hi, seg, &m, &err), DR_OK);
    assert_int_equal(dr_bem_mesh_check(&m, "box", &err), DR_OK);
    DrBemMatrices *bm = NULL;
    DrStatus st = dr_bem_matrices_build(&m, d, NULL, &bm, &err);
    if (st != DR_OK) print_message("build: %s\n", err.message);
    assert_int_equal(st, DR_OK);
    dr_trimesh_free(&m);
    return bm;
}

static DrBemDesc material(double mu, double nu, double dt, double ratio)
{
    DrBemDesc d;
    dr_bem_desc_default(&d);
    d.material = (DrBemMaterial){.density = 1000, .shear_modulus = mu, .poisson = nu};
    d.dt = dt;
    d.compression_ratio = ratio;
    return d;
}

/* A 0.1 m cube, 2 segments per edge (26 vertices), stiff enough to act nearly rigid on the floor: c₂ = 31.6 m/s,
   so n_max = ⌊0.173/(31.6·2e-3) + 2⌋ = 4. */
static DrBemMatrices *small_cube(double ratio)
{
    const double lo[3] = {-0.05, -0.05, -0.05}, hi[3] = {0.05, 0.05, 0.05};
    const int seg[3] = {2, 2, 2};
    DrBemDesc d = material(1e6, 0.3, 2e-3, ratio);
    return build_box(lo, hi, seg, &d);
}

static double lowest_y(const DrBemSolid *s, double *V)
{
    int nv = dr_bem_solid_matrices(s)->nv;
    dr_bem_solid_positions(s, V);
    double y = INFINITY;
    for (int v = 0; v < nv; v++) y = fmin(y, V[3 * v + 1]);
    return y;
}

/* ---- 1. Coulomb friction: the stopping distance of a sliding block ----------------------------------------- */

static void test_friction_stopping_distance(void **state)
{
    (void)state;
    /* A cube launched along the floor at v0 decelerates at μg while it slides, so a rigid block stops after
       v0²/(2μg). The elastic cube is stiff (static sag ~5e-5 m), so the rigid estimate holds up to the small
       transient of the first contact steps and the rocking the friction torque causes; 10 % covers both. */
    DrBemMatrices *bm = small_cube(1);
    print_message("cube: %d vertices, n_max %d, dt %.0e s\n", bm->nv, bm->n_max, bm->desc.dt);
    const double v0 = 1.0, g = 9.81, mus[3] = {0.2, 0.4, 0.6};
    double prev = INFINITY;
    double *V = malloc(sizeof(double) * bm->n);
    for (int i = 0; i < 3; i++) {
        DrBemCollider floor = {.sdf = floor_sdf, .friction = mus[i]};
        DrBemConstraints c = on_collider(&floor, false);
        DrBemSolidDesc sd;
        dr_bem_solid_desc_default(&sd);
        sd.position[1] = 0.05 + c.thickness;
        sd.velocity[0] = v0;
        DrBemSolid *s = NULL;
        DrError err;
        assert_int_equal(dr_bem_solid_create(bm, &sd, &s, &err), DR_OK);
        double R[9], T[3], T0[3], v[3], w[3], stop = NAN, t_max = 3 * v0 / (mus[i] * g), worst_pen = 0;
        dr_bem_solid_pose(s, R, T0);
        DrBemConstraintStats cs, tot = {0};
        int steps = 0, max_passes = 0;
        for (; steps * bm->desc.dt < t_max; steps++) {
            DrStatus st = dr_bem_solids_step(&s, 1, &c, &cs, &err);
            if (st != DR_OK) print_message("step %d: %s\n", steps, err.message);
            assert_true(st >= 0);
            tot.seconds_trial += cs.seconds_trial;
            tot.seconds_assembly += cs.seconds_assembly;
            tot.seconds_pgs += cs.seconds_pgs;
            tot.seconds_final += cs.seconds_final;
            tot.iterations += cs.iterations;
            max_passes = cs.passes > max_passes ? cs.passes : max_passes;
            worst_pen = fmax(worst_pen, -lowest_y(s, V));
            dr_bem_solid_frame_velocity(s, v, w);
            if (v[0] <= 1e-3 * v0 && isnan(stop)) {
                dr_bem_solid_pose(s, R, T);
                stop = T[0] - T0[0];
                break;
            }
        }
        double rigid = v0 * v0 / (2 * mus[i] * g);
        print_message("mu %.1f: stopped after %.3f m in %d steps (rigid %.3f m, %+.1f %%), contacts %d, sticking %d, "
                      "PGS sweeps/step %.1f, max passes %d, worst penetration %.1e m; per step: trial %.2e s, "
                      "assembly %.2e s, PGS %.2e s, final %.2e s\n",
                      mus[i], stop, steps, rigid, 100 * (stop / rigid - 1), cs.contacts, cs.sticking,
                      (double)tot.iterations / (steps + 1), max_passes, worst_pen, tot.seconds_trial / (steps + 1),
                      tot.seconds_assembly / (steps + 1), tot.seconds_pgs / (steps + 1),
                      tot.seconds_final / (steps + 1));
        /* once stopped, static friction holds it: 100 more steps move it less than 1 mm */
        for (int t = 0; t < 100; t++) assert_true(dr_bem_solids_step(&s, 1, &c, &cs, &err) >= 0);
        double T1[3];
        dr_bem_solid_pose(s, R, T1);
        print_message("        100 steps after stopping: moved %.2e m\n", fabs(T1[0] - T[0]));
        assert_false(isnan(stop));
        assert_true(fabs(T1[0] - T[0]) < 1e-3);
        assert_true(fabs(stop / rigid - 1) < 0.10);
        assert_true(stop < prev);
        prev = stop;
        dr_bem_solid_destroy(&s);
    }
    free(V);
    dr_bem_matrices_destroy(&bm);
}

/* ---- 1b. a moving collider: a block picked up by a conveyor belt ---------------------------------------------- */

static void belt_velocity(const double x[3], double v[3], void *ctx)
{
    (void)x;
    const double *speed = ctx;
    v[0] = *speed, v[1] = 0, v[2] = 0;
}

static void test_friction_moving_collider(void **state)
{
    (void)state;
    /* A cube at rest on a floor moving at 0.5 m/s along x (the collider velocity callback; the surface itself stays
       at y = 0) slides until friction μ = 0.4 has brought it to the belt's speed after v/(μg) = 0.127 s, then rides
       with it. Tolerances as for the stopping distance: 10 % on the time, and the riding speed within 1 %. */
    DrBemMatrices *bm = small_cube(1);
    double speed = 0.5;
    DrBemCollider belt = {.sdf = floor_sdf, .velocity = belt_velocity, .ctx = &speed, .friction = 0.4};
    DrBemConstraints c = on_collider(&belt, false);
    DrBemSolidDesc sd;
    dr_bem_solid_desc_default(&sd);
    sd.position[1] = 0.05 + c.thickness;
    DrBemSolid *s = NULL;
    DrError err;
    assert_int_equal(dr_bem_solid_create(bm, &sd, &s, &err), DR_OK);
    double v[3], w[3], t_sync = NAN, dt = bm->desc.dt;
    for (int t = 1; t <= 150; t++) {
        assert_true(dr_bem_solids_step(&s, 1, &c, NULL, &err) >= 0);
        dr_bem_solid_frame_velocity(s, v, w);
        if (isnan(t_sync) && v[0] >= 0.99 * speed) t_sync = t * dt;
    }
    double expect = speed / (0.4 * 9.81);
    print_message("belt: reached 99 %% of the belt speed after %.4f s (rigid %.4f s, %+.1f %%), speed after 0.3 s "
                  "%.4f m/s\n",
                  t_sync, expect, 100 * (t_sync / expect - 1), v[0]);
    assert_false(isnan(t_sync));
    assert_true(fabs(t_sync / expect - 1) < 0.10);
    assert_true(fabs(v[0] / speed - 1) < 0.01);
    dr_bem_solid_destroy(&s);
    dr_bem_matrices_destroy(&bm);
}

/* ---- 2–3. a beam hanging from a fixed end ---------------------------------------------------------------- */

/* The paper's beam material (BEM Fig. 5: μ = 3e5 Pa, ρ = 1000, Δt = 5e-3) on a 0.4 × 0.1 × 0.1 m box with 8 × 2 × 2
   segments (74 vertices): c₂ = 17.3 m/s, n_max = ⌊0.424/(17.3·5e-3) + 2⌋ = 6. The end x = 0 is held. */
static DrBemMatrices *paper_beam(double nu)
{
    const double lo[3] = {0, -0.05, -0.05}, hi[3] = {0.4, 0.05, 0.05};
    const int seg[3] = {8, 2, 2};
    DrBemDesc d = material(3e5, nu, 5e-3, 1);
    return build_box(lo, hi, seg, &d);
}

typedef struct BeamRun {
    double max_fixed_error;   /* m, over all steps */
    double max_inflation;     /* max (V − V₀)/V₀ */
    double max_sag;           /* largest downward displacement of the free end, m */
    double worst_residual;
    int max_passes, max_active;
    double seconds_per_step;
    long sweeps;
    double seconds_trial, seconds_pgs, seconds_final; /* totals */
} BeamRun;

static void run_beam(const DrBemMatrices *bm, bool frame, int steps, BeamRun *out)
{
    DrBemSolidDesc sd;
    dr_bem_solid_desc_default(&sd);
    memcpy(sd.position, bm->body.centroid, sizeof sd.position); /* the rest pose: V = x */
    sd.frame_update = frame;
    sd.error_correction = frame;
    DrBemSolid *s = NULL;
    DrError err;
    assert_int_equal(dr_bem_solid_create(bm, &sd, &s, &err), DR_OK);
    DrBemFixed *fx = malloc(sizeof *fx * bm->nv);
    int nf = 0, tip = -1;
    for (int v = 0; v < bm->nv; v++) {
        if (bm->x[3 * v] < 1e-9) {
            fx[nf] = (DrBemFixed){.body = 0, .vertex = v};
            memcpy(fx[nf].target, &bm->x[3 * v], sizeof fx[nf].target);
            nf++;
        }
        if (bm->x[3 * v] > 0.4 - 1e-9 && fabs(bm->x[3 * v + 1]) < 1e-9 && fabs(bm->x[3 * v + 2]) < 1e-9) tip = v;
    }
    assert_int_equal(nf, 9);
    assert_true(tip >= 0);
    DrBemConstraints c;
    dr_bem_constraints_default(&c);
    c.fixed = fx;
    c.fixed_count = nf;
    DrBemSolidDiag dg;
    dr_bem_solid_diagnostics(s, &dg);
    double vol0 = dg.volume, *V = malloc(sizeof(double) * bm->n), t0 = dr_time_now();
    *out = (BeamRun){0};
    for (int t = 0; t < steps; t++) {
        DrBemConstraintStats cs;
        DrStatus st = dr_bem_solids_step(&s, 1, &c, &cs, &err);
        if (st != DR_OK) print_message("step %d: %s\n", t, err.message);
        assert_int_equal(st, DR_OK);
        dr_bem_solid_positions(s, V);
        for (int i = 0; i < nf; i++) {
            const double *x = &V[3 * fx[i].vertex];
            double e = sqrt(pow(x[0] - fx[i].target[0], 2) + pow(x[1] - fx[i].target[1], 2) +
                            pow(x[2] - fx[i].target[2], 2));
            out->max_fixed_error = fmax(out->max_fixed_error, e);
        }
        dr_bem_solid_diagnostics(s, &dg);
        out->max_inflation = fmax(out->max_inflation, dg.volume / vol0 - 1);
        out->max_sag = fmax(out->max_sag, bm->x[3 * tip + 1] - V[3 * tip + 1]);
        out->worst_residual = fmax(out->worst_residual, cs.residual);
        out->max_passes = cs.passes > out->max_passes ? cs.passes : out->max_passes;
        out->max_active = cs.fixed > out->max_active ? cs.fixed : out->max_active;
        out->sweeps += cs.iterations;
        out->seconds_trial += cs.seconds_trial;
        out->seconds_pgs += cs.seconds_pgs;
        out->seconds_final += cs.seconds_final;
    }
    out->seconds_per_step = (dr_time_now() - t0) / steps;
    free(V);
    free(fx);
    dr_bem_solid_destroy(&s);
}

static void test_fixed_vertices_hold(void **state)
{
    (void)state;
    /* The solve iterates (trial steps with the forces found) until the measured error of every fixed vertex is
       below the tolerance (1e-7 m by default), so the committed step, which repeats the last trial exactly, holds
       them within 1e-6 m with a margin of ten. */
    DrBemMatrices *bm = paper_beam(0.45);
    BeamRun r;
    run_beam(bm, true, 100, &r);
    print_message("fixed end, 100 steps: max fixed-vertex error %.2e m, max passes %d, PGS sweeps/step %.0f, tip sag "
                  "%.4f m; per step %.2e s (trial %.2e, PGS %.2e, final %.2e)\n",
                  r.max_fixed_error, r.max_passes, r.sweeps / 100.0, r.max_sag, r.seconds_per_step,
                  r.seconds_trial / 100, r.seconds_pgs / 100, r.seconds_final / 100);
    assert_true(r.max_fixed_error < 1e-6);
    assert_true(r.max_sag > 1e-3); /* the rest of the beam moves: the constraint is not freezing the body */

    /* a tolerance the passes cannot reach: the step is still taken, with DR_WARN_NOT_CONVERGED and the residual */
    DrBemSolidDesc sd;
    dr_bem_solid_desc_default(&sd);
    memcpy(sd.position, bm->body.centroid, sizeof sd.position);
    sd.angular_velocity[2] = -0.5; /* already turning, so the rotation's nonlinearity shows */
    DrBemSolid *s = NULL;
    DrError err;
    assert_int_equal(dr_bem_solid_create(bm, &sd, &s, &err), DR_OK);
    DrBemFixed fx = {.body = 0, .vertex = 0};
    memcpy(fx.target, &bm->x[0], sizeof fx.target);
    DrBemConstraints c;
    dr_bem_constraints_default(&c);
    c.fixed = &fx;
    c.fixed_count = 1;
    c.max_passes = 1;
    c.tolerance = 1e-15;
    DrBemConstraintStats cs;
    DrStatus st = dr_bem_solids_step(&s, 1, &c, &cs, &err);
    print_message("one pass, tolerance 1e-15 m: status %s, residual %.2e m: %s\n", dr_status_name(st), cs.residual,
                  err.message);
    assert_int_equal(st, DR_WARN_NOT_CONVERGED);
    assert_true(cs.residual > 1e-15 && cs.passes == 1);
    assert_int_equal(dr_bem_solid_steps(s), 1);
    dr_bem_solid_destroy(&s);
    dr_bem_matrices_destroy(&bm);
}

static void test_beam_volume_frame(void **state)
{
    (void)state;
    /* BEM Fig. 5: linear elasticity in a fixed frame gains volume when the beam rotates as it sags (30.4 % in the
       paper's run); the moving frame keeps the rotation out of u (1.91 %). The claim tested: with the frame the
       inflation stays ≤ 2 % and is at least 5× smaller than without. */
    DrBemMatrices *bm = paper_beam(0.45);
    BeamRun on, off;
    run_beam(bm, true, 200, &on);
    run_beam(bm, false, 200, &off);
    print_message("beam 1 s: frame on: inflation %.3f %%, tip sag %.4f m, fixed error %.1e m, passes %d; "
                  "frame off: inflation %.3f %%, tip sag %.4f m, fixed error %.1e m, passes %d; ratio %.1f\n",
                  100 * on.max_inflation, on.max_sag, on.max_fixed_error, on.max_passes, 100 * off.max_inflation,
                  off.max_sag, off.max_fixed_error, off.max_passes, off.max_inflation / fmax(on.max_inflation, 1e-300));
    assert_true(on.max_inflation <= 0.02);
    assert_true(off.max_inflation >= 5 * on.max_inflation);
    dr_bem_matrices_destroy(&bm);
}

/* ---- 4. stability: a 1,000-step drop and rest ------------------------------------------------------------- */

static void drop_and_rest(double ratio)
{
    /* The cube falls 5 cm (tilted 15° about z, so a corner lands first and it rocks), bounces and rests on a floor
       with μ = 0.5. Non-penetration at position level is inelastic and friction dissipates, so the frame's kinetic
       energy can never exceed the potential energy released, m g Δh with Δh the drop of the centre of mass to its
       lowest possible rest height; u stays finite and small against the 0.1 m body. */
    DrBemMatrices *bm = small_cube(ratio);
    const double drop = 0.05, th = 15 * M_PI / 180;
    DrBemCollider floor = {.sdf = floor_sdf, .friction = 0.5};
    DrBemConstraints c = on_collider(&floor, false);
    DrBemSolidDesc sd;
    dr_bem_solid_desc_default(&sd);
    double R0[9] = {cos(th), -sin(th), 0, sin(th), cos(th), 0, 0, 0, 1};
    memcpy(sd.rotation, R0, sizeof R0);
    double half_h = 0.05 * (cos(th) + sin(th)); /* lowest corner below the centre when tilted */
    sd.position[1] = half_h + drop;
    DrBemSolid *s = NULL;
    DrError err;
    assert_int_equal(dr_bem_solid_create(bm, &sd, &s, &err), DR_OK);
    double mass = bm->body.mass, E_drop = mass * 9.81 * (sd.position[1] - 0.05);
    double ke_max = 0, umax = 0, pen = 0, *V = malloc(sizeof(double) * bm->n), t0 = dr_time_now();
    int warns = 0, max_contacts = 0, bounces = 0;
    bool in_air = true;
    DrBemSolidDiag dg;
    for (int t = 0; t < 1000; t++) {
        DrBemConstraintStats cs;
        DrStatus st = dr_bem_solids_step(&s, 1, &c, &cs, &err);
        if (st < 0) print_message("ratio %.0f step %d: %s\n", ratio, t, err.message);
        assert_true(st >= 0);
        warns += st != DR_OK;
        max_contacts = cs.contacts > max_contacts ? cs.contacts : max_contacts;
        if (in_air && cs.contacts > 0) bounces++;
        in_air = cs.contacts == 0;
        dr_bem_solid_diagnostics(s, &dg);
        assert_true(isfinite(dg.kinetic) && isfinite(dg.max_displacement));
        ke_max = fmax(ke_max, dg.kinetic);
        umax = fmax(umax, dg.max_displacement);
        pen = fmax(pen, -lowest_y(s, V));
    }
    double R[9], T[3];
    dr_bem_solid_pose(s, R, T);
    print_message("drop, ratio %2.0f (%zu bytes of H0inv_Gp): max frame KE %.3e J (potential drop %.3e J), max |u| "
                  "%.2e m, worst penetration %.1e m, landings %d, max contacts %d, steps over tolerance %d, final KE "
                  "%.1e J, centre height %.4f m; %.2e s/step\n",
                  ratio, dr_bem_cmat_bytes(&bm->H0inv_Gp), ke_max, E_drop, umax, pen, bounces, max_contacts, warns,
                  dg.kinetic, T[1], (dr_time_now() - t0) / 1000);
    assert_true(ke_max <= E_drop);
    assert_true(umax < 5e-3);                  /* 5 % of the body: small deformation, no blow-up */
    assert_true(pen < 1e-4);                   /* the floor holds (tolerance 1e-6 m beyond the contact offset) */
    assert_true(dg.kinetic < 1e-4 * E_drop);   /* at rest after 2 s */
    assert_true(fabs(T[1] - 0.05) < 2e-3);     /* resting on a face */
    free(V);
    dr_bem_solid_destroy(&s);
    dr_bem_matrices_destroy(&bm);
}

static void test_drop_and_rest_dense(void **state)
{
    (void)state;
    drop_and_rest(1);
}

static void test_drop_and_rest_compressed(void **state)
{
    (void)state;
    drop_and_rest(32);
}

/* ---- 5. point joints ------------------------------------------------------------------------------------ */

static void test_joint_hinge(void **state)
{
    (void)state;
    /* Cube A is held by its top face; cube B hangs from A's bottom-right edge by three point joints along that edge
       (B's top-left edge) and swings down under gravity like a physical pendulum about the hinge. Every joint must
       hold to the solver tolerance (1e-7 m; 1e-6 m asserted) while B turns through tens of degrees. */
    DrBemMatrices *bm = small_cube(1);
    DrBemSolidDesc da, db;
    dr_bem_solid_desc_default(&da);
    dr_bem_solid_desc_default(&db);
    da.position[1] = 0.5;
    db.position[0] = 0.1;
    db.position[1] = 0.4;
    DrBemSolid *s[2] = {NULL, NULL};
    DrError err;
    assert_int_equal(dr_bem_solid_create(bm, &da, &s[0], &err), DR_OK);
    assert_int_equal(dr_bem_solid_create(bm, &db, &s[1], &err), DR_OK);
    DrBemFixed fx[32];
    DrBemJoint jn[8];
    int nf = 0, nj = 0;
    const double *x = bm->x, h = 0.05, e = 1e-9;
    for (int v = 0; v < bm->nv; v++) {
        if (x[3 * v + 1] > h - e) {
            fx[nf] = (DrBemFixed){.body = 0, .vertex = v, .target = {x[3 * v], x[3 * v + 1] + 0.5, x[3 * v + 2]}};
            nf++;
        }
        if (x[3 * v] > h - e && x[3 * v + 1] < -h + e) /* A's bottom-right edge: find B's matching top-left vertex */
            for (int w = 0; w < bm->nv; w++)
                if (x[3 * w] < -h + e && x[3 * w + 1] > h - e && fabs(x[3 * w + 2] - x[3 * v + 2]) < e)
                    jn[nj++] = (DrBemJoint){.body = {0, 1}, .vertex = {v, w}};
    }
    assert_int_equal(nf, 9);
    assert_int_equal(nj, 3);
    DrBemConstraints c;
    dr_bem_constraints_default(&c);
    c.fixed = fx;
    c.fixed_count = nf;
    c.joints = jn;
    c.joint_count = nj;
    double *VA = malloc(sizeof(double) * bm->n), *VB = malloc(sizeof(double) * bm->n);
    double worst = 0, worst_fixed = 0, max_angle = 0, t0 = dr_time_now();
    int max_passes = 0;
    long sweeps = 0;
    for (int t = 0; t < 200; t++) {
        DrBemConstraintStats cs;
        DrStatus st = dr_bem_solids_step(s, 2, &c, &cs, &err);
        if (st != DR_OK) print_message("step %d: %s\n", t, err.message);
        assert_int_equal(st, DR_OK);
        max_passes = cs.passes > max_passes ? cs.passes : max_passes;
        sweeps += cs.iterations;
        dr_bem_solid_positions(s[0], VA);
        dr_bem_solid_positions(s[1], VB);
        for (int j = 0; j < nj; j++) {
            const double *a = &VA[3 * jn[j].vertex[0]], *b = &VB[3 * jn[j].vertex[1]];
            worst = fmax(worst, sqrt(pow(a[0] - b[0], 2) + pow(a[1] - b[1], 2) + pow(a[2] - b[2], 2)));
        }
        for (int f = 0; f < nf; f++) {
            const double *a = &VA[3 * fx[f].vertex];
            worst_fixed = fmax(worst_fixed, sqrt(pow(a[0] - fx[f].target[0], 2) + pow(a[1] - fx[f].target[1], 2) +
                                                 pow(a[2] - fx[f].target[2], 2)));
        }
        double R[9], T[3];
        dr_bem_solid_pose(s[1], R, T);
        max_angle = fmax(max_angle, acos(fmax(-1, fmin(1, 0.5 * (R[0] + R[4] + R[8] - 1)))));
    }
    print_message("hinge, 200 steps: worst joint gap %.2e m, worst fixed error %.2e m, B turned up to %.1f deg, max "
                  "passes %d, PGS sweeps/step %.0f, %.2e s/step\n",
                  worst, worst_fixed, max_angle * 180 / M_PI, max_passes, sweeps / 200.0, (dr_time_now() - t0) / 200);
    assert_true(worst < 1e-6);
    assert_true(worst_fixed < 1e-6);
    assert_true(max_angle > 30 * M_PI / 180);
    free(VA);
    free(VB);
    dr_bem_solid_destroy(&s[0]);
    dr_bem_solid_destroy(&s[1]);
    dr_bem_matrices_destroy(&bm);
}

/* ---- 6. contact between bodies ---------------------------------------------------------------------------- */

/* The deepest point of VB below the deformed top face of VA (its triangles whose rest normal is +y), measured along
   that face's normal over the triangle the point projects into (edges included: B's vertices lie over A's
   triangle edges), down to 1 cm below it. */
static double depth_below_top(const DrBemMatrices *bm, const double *VA, const double *VB)
{
    double worst = 0;
    for (int t = 0; t < bm->nt; t++) {
        const int *tr = &bm->tri[3 * t];
        bool top = true;
        for (int a = 0; a < 3; a++) top = top && bm->x[3 * tr[a] + 1] > 0.05 - 1e-9;
        if (!top) continue;
        const double *a = &VA[3 * tr[0]], *b = &VA[3 * tr[1]], *c = &VA[3 * tr[2]];
        double e1[3], e2[3], n[3];
        for (int q = 0; q < 3; q++) e1[q] = b[q] - a[q], e2[q] = c[q] - a[q];
        n[0] = e1[1] * e2[2] - e1[2] * e2[1];
        n[1] = e1[2] * e2[0] - e1[0] * e2[2];
        n[2] = e1[0] * e2[1] - e1[1] * e2[0];
        double ln = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int q = 0; q < 3; q++) n[q] /= ln;
        double d11 = 0, d12 = 0, d22 = 0;
        for (int q = 0; q < 3; q++) d11 += e1[q] * e1[q], d12 += e1[q] * e2[q], d22 += e2[q] * e2[q];
        for (int v = 0; v < bm->nv; v++) {
            const double *x = &VB[3 * v];
            double r[3] = {x[0] - a[0], x[1] - a[1], x[2] - a[2]}, r1 = 0, r2 = 0, h = 0;
            for (int q = 0; q < 3; q++) r1 += r[q] * e1[q], r2 += r[q] * e2[q], h += r[q] * n[q];
            double det = d11 * d22 - d12 * d12, u = (d22 * r1 - d12 * r2) / det, w = (d11 * r2 - d12 * r1) / det;
            if (u > -1e-9 && w > -1e-9 && u + w < 1 + 1e-9 && h > -0.01) worst = fmax(worst, -h);
        }
    }
    return worst;
}

/* Cube A resting on the floor, cube B above it at height y, 3 cm to the side, spinning at w rad/s about z. */
static void stack_bodies(const DrBemMatrices *bm, const DrBemConstraints *c, double y, double w, DrBemSolid *s[2])
{
    DrBemSolidDesc da, db;
    dr_bem_solid_desc_default(&da);
    dr_bem_solid_desc_default(&db);
    da.position[1] = 0.05 + c->thickness;
    db.position[0] = 0.03;
    db.position[1] = y;
    db.angular_velocity[2] = w;
    DrError err;
    assert_int_equal(dr_bem_solid_create(bm, &da, &s[0], &err), DR_OK);
    assert_int_equal(dr_bem_solid_create(bm, &db, &s[1], &err), DR_OK);
}

static void test_body_stack(void **state)
{
    (void)state;
    /* Cube B falls 5 cm onto cube A resting on the floor, offset by 3 cm so its bottom overhangs A's edge while its
       centre of mass stays over A. Body contact (each body's vertices against the other's triangles, μ = 0.5) must
       stop it on A's top face: no vertex of B sinks below A's deformed top face by more than 1e-4 m (the contact
       offset is 1e-4 m and the solve tolerance 1e-6 m), and B ends at rest with its centre 0.1 m above A's. Without
       body contact the same run sinks B through A (the depth measure saturates near its 1 cm window) and ends with
       both centres level on the floor. */
    DrBemMatrices *bm = small_cube(1);
    DrBemCollider floor = {.sdf = floor_sdf, .friction = 0.5};
    DrBemConstraints c = on_collider(&floor, true);
    DrBemSolid *s[2] = {NULL, NULL};
    stack_bodies(bm, &c, 0.2, 0.0, s);
    DrError err;
    double *V = malloc(sizeof(double) * bm->n), *VA = malloc(sizeof(double) * bm->n);
    double sink = 0, t0 = dr_time_now(), det = 0;
    int max_bc = 0, warns = 0, max_passes = 0;
    for (int t = 0; t < 500; t++) {
        DrBemConstraintStats cs;
        DrStatus st = dr_bem_solids_step(s, 2, &c, &cs, &err);
        if (st < 0) print_message("step %d: %s\n", t, err.message);
        assert_true(st >= 0);
        warns += st != DR_OK;
        max_bc = cs.body_contacts > max_bc ? cs.body_contacts : max_bc;
        max_passes = cs.passes > max_passes ? cs.passes : max_passes;
        det += cs.seconds_detect;
        dr_bem_solid_positions(s[0], VA);
        dr_bem_solid_positions(s[1], V);
        sink = fmax(sink, depth_below_top(bm, VA, V));
    }
    double R[9], TA[3], TB[3];
    DrBemSolidDiag dg;
    dr_bem_solid_pose(s[0], R, TA);
    dr_bem_solid_pose(s[1], R, TB);
    dr_bem_solid_diagnostics(s[1], &dg);
    print_message("stack, 500 steps: B sank %.2e m below A's top, B centre %.4f m above A's centre, A centre %.4f m, "
                  "B final KE %.1e J, max body contacts %d, max passes %d, steps over tolerance %d, detection %.2e "
                  "s/step, %.2e s/step\n",
                  sink, TB[1] - TA[1], TA[1], dg.kinetic, max_bc, max_passes, warns, det / 500,
                  (dr_time_now() - t0) / 500);
    assert_true(max_bc > 0);
    assert_true(sink < 1e-4);
    assert_true(fabs(TB[1] - TA[1] - 0.1) < 2e-3);
    assert_true(fabs(TA[1] - 0.05) < 2e-3);
    assert_true(dg.kinetic < 1e-6);
    free(V);
    free(VA);
    dr_bem_solid_destroy(&s[0]);
    dr_bem_solid_destroy(&s[1]);
    dr_bem_matrices_destroy(&bm);
}

/* The Gauss–Seidel sweeps of a large contact set on several threads collect the changes of up to 64 constraint ends
   and apply them together; every prediction must take the same terms in the same order as when each change is
   applied at once. The stack of two cubes (compressed at 4×: the response comes from single columns of H₀⁻¹G′),
   with floor contact, body contact and friction, is run 60 steps with and without blocks on 1 and 2 threads: both
   bodies' whole state (frame, history window) and their positions agree bit for bit. */
static void test_blocked_sweeps_bit_identical(void **state)
{
    (void)state;
    DrBemMatrices *bm = small_cube(4);
    DrBemCollider floor = {.sdf = floor_sdf, .friction = 0.5};
    DrBemConstraints c = on_collider(&floor, true);
    int saved = dr_threads();
    double *ref[2] = {NULL, NULL};
    size_t size[2] = {0, 0};
    int contacts = 0;
    for (int run = 0; run < 4; run++) {
        bool blocks = run % 2 == 1;
        bem_constraints_force_blocks(blocks);
        dr_set_threads(run / 2 + 1);
        DrBemSolid *s[2] = {NULL, NULL};
        stack_bodies(bm, &c, 0.16, 2.0, s);
        DrError err;
        int bc = 0;
        for (int t = 0; t < 60; t++) {
            DrBemConstraintStats cs;
            assert_true(dr_bem_solids_step(s, 2, &c, &cs, &err) >= 0);
            bc += cs.body_contacts;
        }
        if (run == 0) contacts = bc;
        assert_int_equal(bc, contacts);
        for (int b = 0; b < 2; b++) {
            size_t n = dr_bem_solid_state_size(s[b]) + (size_t)bm->n;
            double *st = malloc(sizeof(double) * n);
            dr_bem_solid_state_get(s[b], st);
            dr_bem_solid_positions(s[b], st + dr_bem_solid_state_size(s[b]));
            if (run == 0) {
                ref[b] = st;
                size[b] = n;
            } else {
                assert_int_equal(n, size[b]);
                assert_memory_equal(st, ref[b], sizeof(double) * n);
                free(st);
            }
            dr_bem_solid_destroy(&s[b]);
        }
    }
    bem_constraints_force_blocks(false);
    dr_set_threads(saved);
    print_message("blocked sweeps: 60 steps of the stack, %d body contacts in all, bit-identical with and without "
                  "blocks on 1 and 2 threads\n", contacts);
    assert_true(contacts > 0);
    free(ref[0]);
    free(ref[1]);
    dr_bem_matrices_destroy(&bm);
}

/* ---- bad input ------------------------------------------------------------------------------------------ */

static void test_bad_input(void **state)
{
    (void)state;
    /* Each is rejected with DR_ERR_INPUT and a message naming the problem, and no body is stepped. */
    DrBemMatrices *bm = small_cube(1);
    DrBemSolidDesc sd;
    dr_bem_solid_desc_default(&sd);
    DrBemSolid *s = NULL;
    DrError err;
    assert_int_equal(dr_bem_solid_create(bm, &sd, &s, &err), DR_OK);
    DrBemConstraints c;
    DrBemFixed fx = {.body = 0, .vertex = bm->nv};
    DrBemJoint jn = {.body = {0, 1}, .vertex = {0, 0}};
    DrBemCollider col = {.sdf = NULL};
    struct {
        int which;
        const char *needle;
    } cases[] = {{0, "fixed vertex 0"}, {1, "joint 0 end 1"}, {2, "no signed distance"}, {3, "negative or NaN"},
                 {4, "tolerance"}, {5, "body friction"}};
    for (int i = 0; i < 6; i++) {
        dr_bem_constraints_default(&c);
        col = (DrBemCollider){.sdf = cases[i].which == 3 ? floor_sdf : NULL, .friction = -1};
        if (cases[i].which == 0) c.fixed = &fx, c.fixed_count = 1;
        if (cases[i].which == 1) c.joints = &jn, c.joint_count = 1;
        if (cases[i].which == 2 || cases[i].which == 3) c.colliders = &col, c.collider_count = 1;
        if (cases[i].which == 4) c.tolerance = 0;
        if (cases[i].which == 5) c.body_contact = true, c.body_friction = -0.1;
        DrStatus st = dr_bem_solids_step(&s, 1, &c, NULL, &err);
        print_message("rejected: %s\n", err.message);
        assert_int_equal(st, DR_ERR_INPUT);
        assert_non_null(strstr(err.message, cases[i].needle));
        assert_int_equal(dr_bem_solid_steps(s), 0);
    }
    /* no constraints and no bodies are fine */
    dr_bem_constraints_default(&c);
    assert_int_equal(dr_bem_solids_step(&s, 1, &c, NULL, &err), DR_OK);
    assert_int_equal(dr_bem_solid_steps(s), 1);
    assert_int_equal(dr_bem_solids_step(NULL, 0, &c, NULL, &err), DR_OK);
    dr_bem_solid_destroy(&s);
    dr_bem_matrices_destroy(&bm);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_friction_stopping_distance),
        cmocka_unit_test(test_friction_moving_collider),
        cmocka_unit_test(test_fixed_vertices_hold),
        cmocka_unit_test(test_beam_volume_frame),
        cmocka_unit_test(test_drop_and_rest_dense),
        cmocka_unit_test(test_drop_and_rest_compressed),
        cmocka_unit_test(test_joint_hinge),
        cmocka_unit_test(test_body_stack),
        cmocka_unit_test(test_blocked_sweeps_bit_identical),
        cmocka_unit_test(test_bad_input),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
