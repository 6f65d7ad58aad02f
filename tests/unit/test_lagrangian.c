/* Unit tests for src/lagrangian: the linearised implicit Euler step against hand and dense solutions (assembly
 * checked independently of the solver), the λ updates of eqs. (S24)–(S25), prescribed DOFs, the three
 * preconditioners agreeing, indefinite blocks, bad groups, the iteration cap, and thread-count determinism;
 * solves with an external load (forces and 3×3 velocity derivatives) against hand and dense solutions,
 * re-solving from one assembly, and dr_lag_solve as solve_load + update_multipliers. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <omp.h>
#include <stdlib.h>
#include <string.h>

#include "core/core.h"
#include "lagrangian/lagrangian.h"

static void near_or_fail(double a, double b, double tol, const char *file, int line)
{
    if (fabs(a - b) <= tol) return;
    print_error("%.17g != %.17g (|diff| %.3g > tol %.3g)\n", a, b, fabs(a - b), tol);
    _fail(file, line);
}
#define assert_near(a, b, tol) near_or_fail((a), (b), (tol), __FILE__, __LINE__)

extern void dposv_(const char *uplo, const int *n, const int *nrhs, double *a, const int *lda, double *b,
                   const int *ldb, int *info, size_t);

/* ---- a random test system, with its dense matrix and right-hand side assembled here ---------------------- */

typedef struct TestSystem {
    int nobj, per, kd, n;
    double h;
    double *mass, *v, *f;
    unsigned char *pres;
    double *vp;
    DrLagGroup *groups;
    bool *global;
    int ngroups;
    double *lambda; /* DR_LAG_MAX_ROWS per group */
} TestSystem;

static void sys_free(TestSystem *t)
{
    free(t->mass);
    free(t->v);
    free(t->f);
    free(t->pres);
    free(t->vp);
    free(t->groups);
    free(t->global);
    free(t->lambda);
}

/* nobj objects of `per` DOFs, half-bandwidth kd; per object `per` random banded groups (1–3 rows, SPD
   material terms), plus `nglobal` groups joining random DOFs of different objects, and room for `extra` more groups
   (sys_spring). */
static void sys_make_room(TestSystem *t, int nobj, int per, int kd, int nglobal, int extra, uint64_t seed)
{
    memset(t, 0, sizeof *t);
    DrRng rng;
    dr_rng_seed(&rng, seed);
    t->nobj = nobj;
    t->per = per;
    t->kd = kd;
    t->n = nobj * per;
    t->h = 0.01;
    t->mass = calloc((size_t)t->n, sizeof(double));
    t->v = calloc((size_t)t->n, sizeof(double));
    t->f = calloc((size_t)t->n, sizeof(double));
    t->pres = calloc((size_t)t->n, 1);
    t->vp = calloc((size_t)t->n, sizeof(double));
    for (int i = 0; i < t->n; i++) {
        t->mass[i] = 0.5 + dr_rng_uniform(&rng);
        t->v[i] = dr_rng_uniform(&rng) - 0.5;
        t->f[i] = 2 * dr_rng_uniform(&rng) - 1;
    }
    int cap = nobj * per + nglobal + extra;
    t->groups = calloc((size_t)cap, sizeof(DrLagGroup));
    t->global = calloc((size_t)cap, sizeof(bool));
    t->lambda = calloc((size_t)cap * DR_LAG_MAX_ROWS, sizeof(double));
    for (int o = 0; o < nobj; o++)
        for (int k = 0; k < per; k++) {
            DrLagGroup *g = &t->groups[t->ngroups];
            g->kind = (k % 5 == 4) ? DR_LAG_VISCOUS : DR_LAG_POSITIONAL;
            g->nrows = 1 + (int)(dr_rng_next(&rng) % 3);
            int first = o * per + (int)(dr_rng_next(&rng) % (uint64_t)(per - kd));
            g->ndof = 2 + (int)(dr_rng_next(&rng) % (uint64_t)kd);
            for (int a = 0; a < g->ndof; a++) g->dof[a] = first + a;
            for (int r = 0; r < g->nrows; r++) {
                g->phi[r] = dr_rng_uniform(&rng) - 0.5;
                g->cinv[r] = 10 + 1000 * dr_rng_uniform(&rng);
                for (int a = 0; a < g->ndof; a++) g->J[r * g->ndof + a] = dr_rng_uniform(&rng) - 0.5;
            }
            g->lambda = t->lambda + DR_LAG_MAX_ROWS * t->ngroups;
            t->ngroups++;
        }
    for (int k = 0; k < nglobal; k++) {
        DrLagGroup *g = &t->groups[t->ngroups];
        g->kind = DR_LAG_POSITIONAL;
        g->nrows = 1;
        g->ndof = 2;
        int a = (int)(dr_rng_next(&rng) % (uint64_t)t->n), b;
        do b = (int)(dr_rng_next(&rng) % (uint64_t)t->n);
        while (b / per == a / per);
        g->dof[0] = a;
        g->dof[1] = b;
        g->phi[0] = dr_rng_uniform(&rng) - 0.5;
        g->cinv[0] = 100;
        g->J[0] = 1;
        g->J[1] = -1;
        g->lambda = t->lambda + DR_LAG_MAX_ROWS * t->ngroups;
        t->global[t->ngroups] = true;
        t->ngroups++;
    }
}

static void sys_make(TestSystem *t, int nobj, int per, int kd, int nglobal, uint64_t seed)
{
    sys_make_room(t, nobj, per, kd, nglobal, 0, seed);
}

/* Appends a K_G spring φ = q_a − q_b − l (C⁻¹ = k) between DOFs a and b of different objects. */
static void sys_spring(TestSystem *t, int a, int b, double k, double phi)
{
    DrLagGroup *g = &t->groups[t->ngroups];
    memset(g, 0, sizeof *g);
    g->kind = DR_LAG_POSITIONAL;
    g->nrows = 1;
    g->ndof = 2;
    g->dof[0] = a;
    g->dof[1] = b;
    g->phi[0] = phi;
    g->cinv[0] = k;
    g->J[0] = 1;
    g->J[1] = -1;
    g->lambda = t->lambda + DR_LAG_MAX_ROWS * t->ngroups;
    t->global[t->ngroups++] = true;
}

/* A bundle: side × side objects (strands) of `per` DOFs on a grid, each joined to its grid neighbours by a spring of
   stiffness k at every DOF, as capillary bridges join wet strands along their whole length. */
static void sys_bundle(TestSystem *t, int side, int per, int kd, double k, uint64_t seed)
{
    sys_make_room(t, side * side, per, kd, 0, 2 * side * side * per, seed);
    for (int i = 0; i < side; i++)
        for (int j = 0; j < side; j++)
            for (int d = 0; d < per; d++) {
                int o = i * side + j;
                if (i + 1 < side) sys_spring(t, o * per + d, (o + side) * per + d, k, 0.01 * ((d % 3) - 1));
                if (j + 1 < side) sys_spring(t, o * per + d, (o + 1) * per + d, k, -0.01 * ((d % 5) - 2));
            }
}

/* Dense A (n×n, column-major = row-major: symmetric) and b of eq. (S26) with prescribed DOFs eliminated. */
static void sys_dense(const TestSystem *t, double *A, double *b)
{
    int n = t->n;
    double h = t->h;
    memset(A, 0, (size_t)n * n * sizeof(double));
    for (int i = 0; i < n; i++) {
        A[i * n + i] = t->mass[i];
        b[i] = t->mass[i] * (t->pres[i] ? t->vp[i] : t->v[i]) + (t->pres[i] ? 0 : h * t->f[i]);
    }
    for (int k = 0; k < t->ngroups; k++) {
        const DrLagGroup *g = &t->groups[k];
        double sc = g->kind == DR_LAG_POSITIONAL ? h : 1.0;
        for (int a = 0; a < g->ndof; a++) {
            int da = g->dof[a];
            if (t->pres[da]) continue;
            double rhs = 0;
            for (int r = 0; r < g->nrows; r++) rhs -= h * g->J[r * g->ndof + a] * g->cinv[r] * g->phi[r];
            b[da] += rhs;
            for (int c = 0; c < g->ndof; c++) {
                int dc = g->dof[c];
                double m = 0;
                for (int r = 0; r < g->nrows; r++) m += h * sc * g->J[r * g->ndof + a] * g->cinv[r] * g->J[r * g->ndof + c];
                if (g->G && g->kind == DR_LAG_POSITIONAL) m -= h * h * g->G[a * g->ndof + c];
                if (t->pres[dc]) b[da] -= m * t->vp[dc];
                else A[da * n + dc] += m;
            }
        }
    }
}

static DrLag *sys_solver(const TestSystem *t, DrLagPrecond pc, double tol)
{
    DrLagDesc d;
    dr_lag_desc_default(&d);
    d.precond = pc;
    d.tol = tol;
    d.max_iter = 5000;
    DrLag *s = NULL;
    DrError err;
    assert_int_equal(dr_lag_create(&d, &s, &err), DR_OK);
    for (int o = 0; o < t->nobj; o++) {
        int id, d0;
        assert_int_equal(dr_lag_add_object(s, t->per, t->kd, &id, &d0, &err), DR_OK);
        assert_int_equal(id, o);
        assert_int_equal(d0, o * t->per);
    }
    return s;
}

static DrStatus sys_step(const TestSystem *t, DrLag *s, double *x, DrLagStats *st)
{
    DrError err;
    bool any = false;
    for (int i = 0; i < t->n; i++) any = any || t->pres[i];
    assert_int_equal(dr_lag_begin(s, t->h, t->mass, t->v, t->f, any ? t->pres : NULL, t->vp, &err), DR_OK);
    for (int k = 0; k < t->ngroups; k++) {
        DrStatus r = t->global[k] ? dr_lag_add_global(s, &t->groups[k], &err) : dr_lag_add(s, &t->groups[k], &err);
        assert_int_equal(r, DR_OK);
    }
    return dr_lag_solve(s, x, st, &err);
}

/* max_i |(A x − b)_i| / max_i |b_i| with the dense A, b assembled above */
static double dense_residual(const TestSystem *t, const double *x)
{
    int n = t->n;
    double *A = malloc((size_t)n * n * sizeof(double)), *b = malloc((size_t)n * sizeof(double));
    sys_dense(t, A, b);
    double worst = 0, scale = 0;
    for (int i = 0; i < n; i++) {
        double r = -b[i];
        for (int j = 0; j < n; j++) r += A[i * n + j] * x[j];
        worst = fmax(worst, fabs(r));
        scale = fmax(scale, fabs(b[i]));
    }
    free(A);
    free(b);
    return worst / scale;
}

/* ---- tests ------------------------------------------------------------------------------------------------- */

/* One DOF on a linear spring φ = q − 1 (C⁻¹ = k): (m + h²k) v₊ = m v + h (f − k φ), λ₊ = −k (φ + h v₊). */
static void test_spring_by_hand(void **state)
{
    (void)state;
    DrLag *s = NULL;
    DrError err;
    assert_int_equal(dr_lag_create(NULL, &s, &err), DR_OK);
    int id, d0;
    assert_int_equal(dr_lag_add_object(s, 1, 0, &id, &d0, &err), DR_OK);
    double m = 2, v = 0.3, f = -1.5, h = 0.1, k = 50, q = 1.2, lambda = 0;
    assert_int_equal(dr_lag_begin(s, h, &m, &v, &f, NULL, NULL, &err), DR_OK);
    DrLagGroup g = {.kind = DR_LAG_POSITIONAL, .nrows = 1, .ndof = 1, .dof = {0}, .phi = {q - 1}, .cinv = {k},
                    .J = {1}, .lambda = &lambda};
    assert_int_equal(dr_lag_add(s, &g, &err), DR_OK);
    double x = 0;
    DrLagStats st;
    assert_int_equal(dr_lag_solve(s, &x, &st, &err), DR_OK);
    double expect = (m * v + h * (f - k * (q - 1))) / (m + h * h * k);
    assert_near(x, expect, 1e-14);
    assert_near(lambda, -k * ((q - 1) + h * expect), 1e-12);
    assert_int_equal(st.groups_block, 1);
    dr_lag_destroy(&s);
    assert_null(s);
}

/* A drag φ_v = q̇ − u (J_v = 1, c = −u, C_v⁻¹ = c_d): (m + h c_d) v₊ = m v + h (f + c_d u), λ_v₊ = −c_d (v₊ − u). */
static void test_viscous_by_hand(void **state)
{
    (void)state;
    DrLag *s = NULL;
    DrError err;
    assert_int_equal(dr_lag_create(NULL, &s, &err), DR_OK);
    int id, d0;
    assert_int_equal(dr_lag_add_object(s, 1, 0, &id, &d0, &err), DR_OK);
    double m = 0.5, v = 2, f = 0.25, h = 0.05, cd = 3, u = -1, lambda = 0;
    assert_int_equal(dr_lag_begin(s, h, &m, &v, &f, NULL, NULL, &err), DR_OK);
    DrLagGroup g = {.kind = DR_LAG_VISCOUS, .nrows = 1, .ndof = 1, .dof = {0}, .phi = {-u}, .cinv = {cd},
                    .J = {1}, .lambda = &lambda};
    assert_int_equal(dr_lag_add(s, &g, &err), DR_OK);
    double x = 0;
    assert_int_equal(dr_lag_solve(s, &x, NULL, &err), DR_OK);
    double expect = (m * v + h * (f + cd * u)) / (m + h * cd);
    assert_near(x, expect, 1e-14);
    assert_near(lambda, -cd * (expect - u), 1e-12);
    dr_lag_destroy(&s);
}

/* All four preconditioners solve the same system (checked against the dense assembly) and agree. */
static void test_preconditioners_agree(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 12, 20, 5, 30, 7);
    double *x[4];
    int iters[4];
    DrLagPrecond pcs[4] = {DR_LAG_PRECOND_BLOCK, DR_LAG_PRECOND_JACOBI, DR_LAG_PRECOND_NONE, DR_LAG_PRECOND_CLUSTER};
    for (int p = 0; p < 4; p++) {
        x[p] = calloc((size_t)t.n, sizeof(double));
        DrLag *s = sys_solver(&t, pcs[p], 1e-12);
        DrLagStats st;
        assert_int_equal(sys_step(&t, s, x[p], &st), DR_OK);
        assert_true(st.converged);
        assert_int_equal(st.groups_global, 30);
        iters[p] = st.iterations;
        /* ‖r‖_{M⁻¹} ≤ 1e-12 ‖b‖_{M⁻¹} bounds the dense residual to ~1e-11 of b's largest entry here
           (masses within [0.5, 1.5]) */
        assert_true(dense_residual(&t, x[p]) < 1e-10);
        dr_lag_destroy(&s);
    }
    for (int i = 0; i < t.n; i++)
        for (int p = 1; p < 4; p++) assert_near(x[p][i], x[0][i], 1e-9 * (1 + fabs(x[0][i])));
    /* the block preconditioner captures everything but the 30 inter-object springs; the cluster one those too (the
       springs join every object: one cluster, whose factor is A's) */
    assert_true(iters[0] < iters[1]);
    assert_true(iters[3] <= 1);
    print_message("iterations: block %d, jacobi %d, none %d, cluster %d\n", iters[0], iters[1], iters[2], iters[3]);
    for (int p = 0; p < 4; p++) free(x[p]);
    sys_free(&t);
}

/* Without inter-object terms the local block solves are the solution: 0 CG iterations. */
static void test_local_solve_exact(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 6, 16, 4, 0, 11);
    double *x = calloc((size_t)t.n, sizeof(double));
    DrLag *s = sys_solver(&t, DR_LAG_PRECOND_BLOCK, 1e-10);
    DrLagStats st;
    assert_int_equal(sys_step(&t, s, x, &st), DR_OK);
    assert_int_equal(st.iterations, 0);
    assert_true(dense_residual(&t, x) < 1e-12);
    /* λ₊ = −C⁻¹(c + s J q̇₊) for every group */
    for (int k = 0; k < t.ngroups; k++) {
        const DrLagGroup *g = &t.groups[k];
        double sc = g->kind == DR_LAG_POSITIONAL ? t.h : 1.0;
        for (int r = 0; r < g->nrows; r++) {
            double jv = 0;
            for (int a = 0; a < g->ndof; a++) jv += g->J[r * g->ndof + a] * x[g->dof[a]];
            double expect = -g->cinv[r] * (g->phi[r] + sc * jv);
            assert_near(g->lambda[r], expect, 1e-12 * (1 + fabs(expect)));
        }
    }
    dr_lag_destroy(&s);
    free(x);
    sys_free(&t);
}

/* Prescribed DOFs get their velocity exactly and the rest solve the reduced system. */
static void test_prescribed(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 5, 12, 4, 8, 3);
    for (int o = 0; o < t.nobj; o++) {
        t.pres[o * t.per] = t.pres[o * t.per + 1] = 1;
        t.vp[o * t.per] = 0.7;
        t.vp[o * t.per + 1] = -0.2;
    }
    DrLagPrecond pcs[4] = {DR_LAG_PRECOND_BLOCK, DR_LAG_PRECOND_JACOBI, DR_LAG_PRECOND_NONE, DR_LAG_PRECOND_CLUSTER};
    for (int p = 0; p < 4; p++) {
        double *x = calloc((size_t)t.n, sizeof(double));
        DrLag *s = sys_solver(&t, pcs[p], 1e-12);
        assert_int_equal(sys_step(&t, s, x, NULL), DR_OK);
        for (int o = 0; o < t.nobj; o++) {
            assert_true(x[o * t.per] == 0.7);
            assert_true(x[o * t.per + 1] == -0.2);
        }
        assert_true(dense_residual(&t, x) < 1e-10);
        dr_lag_destroy(&s);
        free(x);
    }
    sys_free(&t);
}

/* A block made indefinite by its geometric stiffness drops it, for every preconditioner alike. */
static void test_indefinite_block(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 3, 10, 3, 2, 5);
    double G[4] = {1e9, 0, 0, 1e9}; /* −h² G = −1e5 on two diagonal entries: the block turns indefinite */
    DrLagGroup *g = &t.groups[0];
    g->kind = DR_LAG_POSITIONAL;
    g->ndof = 2;
    g->G = G;
    double *x[3];
    DrLagPrecond pcs[3] = {DR_LAG_PRECOND_BLOCK, DR_LAG_PRECOND_JACOBI, DR_LAG_PRECOND_CLUSTER};
    for (int p = 0; p < 3; p++) {
        x[p] = calloc((size_t)t.n, sizeof(double));
        DrLag *s = sys_solver(&t, pcs[p], 1e-12);
        DrLagStats st;
        assert_int_equal(sys_step(&t, s, x[p], &st), DR_OK);
        assert_int_equal(st.indefinite_blocks, 1);
        dr_lag_destroy(&s);
    }
    g->G = NULL; /* the dense reference without it */
    assert_true(dense_residual(&t, x[0]) < 1e-10);
    for (int i = 0; i < t.n; i++)
        for (int p = 1; p < 3; p++) assert_near(x[p][i], x[0][i], 1e-9 * (1 + fabs(x[0][i])));
    for (int p = 0; p < 3; p++) free(x[p]);
    sys_free(&t);
}


/* Two one-DOF objects whose geometric stiffness makes each operator negative (−0.5), joined by a stiff spring in
   K_G: each block with the spring's own diagonal (k − 0.5) is positive, yet A = [[k−.5, −k], [−k, k−.5]] has
   the eigenvalue −0.5. Definiteness must be decided on the blocks without their contact terms. */
static void test_contact_hides_indefinite_block(void **state)
{
    (void)state;
    DrLag *s = NULL;
    DrError err;
    assert_int_equal(dr_lag_create(NULL, &s, &err), DR_OK);
    int id, d0;
    assert_int_equal(dr_lag_add_object(s, 1, 0, &id, &d0, &err), DR_OK);
    assert_int_equal(dr_lag_add_object(s, 1, 0, &id, &d0, &err), DR_OK);
    double m[2] = {1, 1}, v[2] = {0.3, -0.1}, h = 0.1, k = 100;
    assert_int_equal(dr_lag_begin(s, h, m, v, NULL, NULL, NULL, &err), DR_OK);
    double G = 150; /* −h² G = −1.5: op = 1 − 1.5 = −0.5 */
    for (int i = 0; i < 2; i++) {
        DrLagGroup g = {.kind = DR_LAG_POSITIONAL, .nrows = 1, .ndof = 1, .dof = {i}, .phi = {0}, .cinv = {1e-12},
                        .J = {1}, .G = &G};
        assert_int_equal(dr_lag_add(s, &g, &err), DR_OK);
    }
    DrLagGroup spring = {.kind = DR_LAG_POSITIONAL, .nrows = 1, .ndof = 2, .dof = {0, 1}, .phi = {0.01},
                         .cinv = {k / (h * h)}, .J = {1, -1}};
    assert_int_equal(dr_lag_add_global(s, &spring, &err), DR_OK);
    double x[2];
    DrLagStats st;
    assert_int_equal(dr_lag_solve(s, x, &st, &err), DR_OK);
    assert_int_equal(st.indefinite_blocks, 2);
    /* the solution of the system without geometric stiffness: [[1 + k, −k], [−k, 1 + k]] x = v − h k φ [1, −1]
       (material terms 1e-14 dropped) */
    double b0 = v[0] - h * (k / (h * h)) * 0.01, b1 = v[1] + h * (k / (h * h)) * 0.01;
    double det = (1 + k) * (1 + k) - k * k;
    assert_near(x[0], ((1 + k) * b0 + k * b1) / det, 1e-9);
    assert_near(x[1], (k * b0 + (1 + k) * b1) / det, 1e-9);
    dr_lag_destroy(&s);
}

static void test_bad_groups(void **state)
{
    (void)state;
    DrLag *s = NULL;
    DrError err;
    assert_int_equal(dr_lag_create(NULL, &s, &err), DR_OK);
    int id, d0;
    assert_int_equal(dr_lag_add_object(s, 0, 0, &id, &d0, &err), DR_ERR_INPUT);
    assert_int_equal(dr_lag_add_object(s, 4, 4, &id, &d0, &err), DR_ERR_INPUT);
    assert_int_equal(dr_lag_add_object(s, 6, 2, &id, &d0, &err), DR_OK);
    assert_int_equal(dr_lag_add_object(s, 6, 2, &id, &d0, &err), DR_OK);
    double m[12], v[12] = {0};
    for (int i = 0; i < 12; i++) m[i] = 1;
    assert_int_equal(dr_lag_begin(s, 0.01, m, v, NULL, NULL, NULL, &err), DR_OK);
    DrLagGroup g = {.kind = DR_LAG_POSITIONAL, .nrows = 1, .ndof = 2, .dof = {0, 3}, .phi = {0}, .cinv = {1},
                    .J = {1, -1}};
    assert_int_equal(dr_lag_add(s, &g, &err), DR_ERR_INPUT); /* wider than the band */
    assert_non_null(strstr(err.message, "band"));
    g.dof[1] = 7;
    assert_int_equal(dr_lag_add(s, &g, &err), DR_ERR_INPUT); /* two objects */
    assert_non_null(strstr(err.message, "dr_lag_add_global"));
    assert_int_equal(dr_lag_add_global(s, &g, &err), DR_OK);
    g.dof[1] = 1;
    g.phi[0] = NAN;
    assert_int_equal(dr_lag_add(s, &g, &err), DR_ERR_RUNTIME);
    assert_non_null(strstr(err.message, "non-finite"));
    m[3] = 0;
    assert_int_equal(dr_lag_begin(s, 0.01, m, v, NULL, NULL, NULL, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "DOF 3"));
    dr_lag_destroy(&s);
}

/* A K_G group on DOFs of one object spread wider than its band: its in-band part, [1 1 0; 1 1 1; 0 1 1] h²k for
   J = (1, 1, 1), has the eigenvalue (1 − √2) h²k, which outweighs masses of 1e-6; the block is preconditioned
   without it and the whole system (positive definite) is solved. */
static void test_contact_terms_beyond_band(void **state)
{
    (void)state;
    DrLagPrecond pcs[3] = {DR_LAG_PRECOND_BLOCK, DR_LAG_PRECOND_JACOBI, DR_LAG_PRECOND_CLUSTER};
    for (int p = 0; p < 3; p++) {
        DrLagDesc d;
        dr_lag_desc_default(&d);
        d.precond = pcs[p];
        d.tol = 1e-13;
        DrLag *s = NULL;
        DrError err;
        assert_int_equal(dr_lag_create(&d, &s, &err), DR_OK);
        int id, d0;
        assert_int_equal(dr_lag_add_object(s, 3, 1, &id, &d0, &err), DR_OK);
        double m[3] = {1e-6, 1e-6, 1e-6}, v[3] = {0.1, -0.2, 0.3}, h = 0.01, k = 10, lambda = 0;
        assert_int_equal(dr_lag_begin(s, h, m, v, NULL, NULL, NULL, &err), DR_OK);
        DrLagGroup g = {.kind = DR_LAG_POSITIONAL, .nrows = 1, .ndof = 3, .dof = {0, 1, 2}, .phi = {0.01},
                        .cinv = {k}, .J = {1, 1, 1}, .lambda = &lambda};
        assert_int_equal(dr_lag_add(s, &g, &err), DR_ERR_INPUT); /* wider than the band */
        assert_int_equal(dr_lag_add_global(s, &g, &err), DR_OK);
        double x[3];
        DrLagStats st;
        assert_int_equal(dr_lag_solve(s, x, &st, &err), DR_OK);
        assert_int_equal(st.contact_blocks_dropped, 1); /* every preconditioner factors the blocks */
        /* (m + h² k 1 1ᵀ) x = m v − h k φ 1, by hand: x = v − 1 (h k (φ + h 1ᵀv)) / (m + 3 h² k) */
        double sv = v[0] + v[1] + v[2], c = h * k * (0.01 + h * sv) / (m[0] + 3 * h * h * k);
        for (int a = 0; a < 3; a++) assert_near(x[a], v[a] - c, 1e-9 * fabs(c));
        dr_lag_destroy(&s);
    }
}

/* ---- solves with an external load ------------------------------------------------------------------------ */

/* One object of 3 DOFs (a vertex), D = −c I and a force F: (m + h c) v₊ = m v + h (f + F) per DOF. */
static void test_load_by_hand(void **state)
{
    (void)state;
    DrLag *s = NULL;
    DrError err;
    assert_int_equal(dr_lag_create(NULL, &s, &err), DR_OK);
    int id, d0;
    assert_int_equal(dr_lag_add_object(s, 3, 2, &id, &d0, &err), DR_OK);
    double m[3] = {2, 2, 2}, v[3] = {0.3, -1, 0.5}, f[3] = {0, -19.6, 0}, h = 0.01, c = 40;
    double F[3] = {1, 2, -3}, D[9] = {-c, 0, 0, 0, -c, 0, 0, 0, -c};
    int block = 0;
    DrLagLoad load = {F, 1, &block, D};
    assert_int_equal(dr_lag_begin(s, h, m, v, f, NULL, NULL, &err), DR_OK);
    double x[3];
    assert_int_equal(dr_lag_solve_load(s, &load, x, NULL, &err), DR_OK);
    for (int a = 0; a < 3; a++) assert_near(x[a], (m[a] * v[a] + h * (f[a] + F[a])) / (m[a] + h * c), 1e-14);
    /* the antisymmetric part of D does not enter: D + S with S antisymmetric gives the same velocity */
    double DS[9] = {-c, 5, -2, -5, -c, 7, 2, -7, -c};
    DrLagLoad load2 = {F, 1, &block, DS};
    double y[3];
    assert_int_equal(dr_lag_solve_load(s, &load2, y, NULL, &err), DR_OK);
    for (int a = 0; a < 3; a++) assert_near(y[a], x[a], 1e-14);
    dr_lag_destroy(&s);
}

/* A random load on a random system: forces everywhere, blocks on DOF triples of every object, some of them over
   prescribed DOFs, D = −(c I + K) + S (K SPD, S antisymmetric, random). The solution against the dense system
   with −h ½(D + Dᵀ) added on each block, h f on the free DOFs, and prescribed columns moved to the right. */
typedef struct TestLoad {
    int nblocks;
    int *block_dof;
    double *force, *D;
} TestLoad;

static void load_make(const TestSystem *t, TestLoad *L, uint64_t seed)
{
    DrRng rng;
    dr_rng_seed(&rng, seed);
    L->nblocks = 0;
    L->block_dof = calloc((size_t)t->n, sizeof(int));
    L->force = calloc((size_t)t->n, sizeof(double));
    L->D = calloc((size_t)t->n * 9, sizeof(double));
    for (int i = 0; i < t->n; i++) L->force[i] = 4 * dr_rng_uniform(&rng) - 2;
    for (int o = 0; o < t->nobj; o++)
        for (int k = 0; k + 2 < t->per; k += 4) {
            double *D = L->D + 9 * L->nblocks, K[9], S[9];
            L->block_dof[L->nblocks++] = o * t->per + k;
            for (int a = 0; a < 9; a++) K[a] = dr_rng_uniform(&rng) - 0.5;
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) S[3 * a + b] = a < b ? 3 * (dr_rng_uniform(&rng) - 0.5) : 0;
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) {
                    double kk = 0;
                    for (int c = 0; c < 3; c++) kk += K[3 * a + c] * K[3 * b + c];
                    D[3 * a + b] = -(a == b ? 20.0 : 0.0) - 10 * kk + S[3 * a + b] - S[3 * b + a];
                }
        }
}

static void load_free(TestLoad *L)
{
    free(L->block_dof);
    free(L->force);
    free(L->D);
}

static void load_dense(const TestSystem *t, const TestLoad *L, double *A, double *b)
{
    int n = t->n;
    sys_dense(t, A, b);
    for (int i = 0; i < n; i++)
        if (!t->pres[i]) b[i] += t->h * L->force[i];
    for (int k = 0; k < L->nblocks; k++)
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 3; c++) {
                int da = L->block_dof[k] + a, dc = L->block_dof[k] + c;
                double v = -t->h * 0.5 * (L->D[9 * k + 3 * a + c] + L->D[9 * k + 3 * c + a]);
                if (t->pres[da]) continue;
                if (t->pres[dc]) b[da] -= v * t->vp[dc];
                else A[da * n + dc] += v;
            }
}

static double residual_dense(const double *A, const double *b, const double *x, int n)
{
    double worst = 0, scale = 0;
    for (int i = 0; i < n; i++) {
        double r = -b[i];
        for (int j = 0; j < n; j++) r += A[i * n + j] * x[j];
        worst = fmax(worst, fabs(r));
        scale = fmax(scale, fabs(b[i]));
    }
    return worst / scale;
}

static void test_load_dense(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 6, 14, 4, 12, 17);
    for (int o = 0; o < t.nobj; o += 2) { /* the first DOF of every other object is held, inside a block */
        t.pres[o * t.per] = 1;
        t.vp[o * t.per] = 0.4;
    }
    TestLoad L;
    load_make(&t, &L, 5);
    DrLagLoad load = {L.force, L.nblocks, L.block_dof, L.D};
    int n = t.n;
    double *A = malloc((size_t)n * n * sizeof(double)), *b = malloc((size_t)n * sizeof(double));
    load_dense(&t, &L, A, b);
    DrLagPrecond pcs[4] = {DR_LAG_PRECOND_BLOCK, DR_LAG_PRECOND_JACOBI, DR_LAG_PRECOND_NONE, DR_LAG_PRECOND_CLUSTER};
    for (int p = 0; p < 4; p++) {
        DrLag *s = sys_solver(&t, pcs[p], 1e-12);
        DrError err;
        assert_int_equal(dr_lag_begin(s, t.h, t.mass, t.v, t.f, t.pres, t.vp, &err), DR_OK);
        for (int k = 0; k < t.ngroups; k++)
            assert_int_equal(t.global[k] ? dr_lag_add_global(s, &t.groups[k], &err) : dr_lag_add(s, &t.groups[k], &err),
                             DR_OK);
        double *x = calloc((size_t)n, sizeof(double));
        DrLagStats st;
        assert_int_equal(dr_lag_solve_load(s, &load, x, &st, &err), DR_OK);
        /* as in test_preconditioners_agree: ‖r‖_{M⁻¹} ≤ 1e-12 ‖b‖_{M⁻¹} bounds the dense residual near 1e-11 */
        double res = residual_dense(A, b, x, n);
        print_message("load, preconditioner %d: %d iterations, dense residual %.2e\n", p, st.iterations, res);
        assert_true(res < 1e-10);
        for (int o = 0; o < t.nobj; o += 2) assert_true(x[o * t.per] == 0.4);
        free(x);
        dr_lag_destroy(&s);
    }
    free(A);
    free(b);
    load_free(&L);
    sys_free(&t);
}

/* One assembly, several solves: a solve does not touch λ, the same load gives the same bits whatever was solved
   before it, and dr_lag_solve equals solve_load(NULL) + update_multipliers bit for bit. */
static void test_load_resolve(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 8, 16, 5, 20, 23);
    TestLoad L;
    load_make(&t, &L, 9);
    DrLagLoad load = {L.force, L.nblocks, L.block_dof, L.D};
    int n = t.n;
    size_t nl = (size_t)t.ngroups * DR_LAG_MAX_ROWS;
    double *x0 = calloc((size_t)n, sizeof(double)), *x1 = calloc((size_t)n, sizeof(double));
    double *x2 = calloc((size_t)n, sizeof(double)), *x3 = calloc((size_t)n, sizeof(double));
    double *lam = malloc(nl * sizeof(double));
    /* reference: the one-call solve */
    DrLag *s = sys_solver(&t, DR_LAG_PRECOND_BLOCK, 1e-12);
    assert_int_equal(sys_step(&t, s, x0, NULL), DR_OK);
    memcpy(lam, t.lambda, nl * sizeof(double));
    /* the same system solved with the load, without, with it again, then the multipliers */
    for (size_t k = 0; k < nl; k++) t.lambda[k] = -7.0;
    DrError err;
    assert_int_equal(dr_lag_begin(s, t.h, t.mass, t.v, t.f, NULL, NULL, &err), DR_OK);
    for (int k = 0; k < t.ngroups; k++)
        assert_int_equal(t.global[k] ? dr_lag_add_global(s, &t.groups[k], &err) : dr_lag_add(s, &t.groups[k], &err),
                         DR_OK);
    assert_int_equal(dr_lag_solve_load(s, &load, x1, NULL, &err), DR_OK);
    assert_int_equal(dr_lag_solve_load(s, NULL, x2, NULL, &err), DR_OK);
    assert_int_equal(dr_lag_solve_load(s, &load, x3, NULL, &err), DR_OK);
    for (size_t k = 0; k < nl; k++) assert_true(t.lambda[k] == -7.0);
    assert_memory_equal(x2, x0, (size_t)n * sizeof(double));
    assert_memory_equal(x3, x1, (size_t)n * sizeof(double));
    /* the load changed the answer */
    double diff = 0;
    for (int i = 0; i < n; i++) diff = fmax(diff, fabs(x1[i] - x0[i]));
    assert_true(diff > 1e-6);
    dr_lag_update_multipliers(s, x2);
    for (int k = 0; k < t.ngroups; k++) /* each group's rows */
        assert_memory_equal(t.lambda + DR_LAG_MAX_ROWS * k, lam + DR_LAG_MAX_ROWS * k,
                            (size_t)t.groups[k].nrows * sizeof(double));
    dr_lag_destroy(&s);
    free(x0);
    free(x1);
    free(x2);
    free(x3);
    free(lam);
    load_free(&L);
    sys_free(&t);
}

static void test_iteration_cap(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 8, 12, 4, 20, 9);
    DrLag *s = sys_solver(&t, DR_LAG_PRECOND_NONE, 1e-14);
    DrLagDesc d;
    dr_lag_desc_default(&d);
    d.precond = DR_LAG_PRECOND_NONE;
    d.tol = 1e-14;
    d.max_iter = 2;
    dr_lag_set_desc(s, &d);
    double *x = calloc((size_t)t.n, sizeof(double));
    DrLagStats st;
    assert_int_equal(sys_step(&t, s, x, &st), DR_WARN_NOT_CONVERGED);
    assert_false(st.converged);
    assert_int_equal(st.iterations, 2);
    for (int i = 0; i < t.n; i++) assert_true(isfinite(x[i]));
    dr_lag_destroy(&s);
    free(x);
    sys_free(&t);
}

/* 1 and 2 threads give the same bits, with the block and with the cluster preconditioner (several clusters: the
   60 random springs leave 40 objects in more than one piece, and a small factor budget cuts the large ones). */
static void test_threads_bit_identical(void **state)
{
    (void)state;
    TestSystem t;
    sys_make(&t, 40, 30, 6, 60, 21);
    DrLagPrecond pcs[2] = {DR_LAG_PRECOND_BLOCK, DR_LAG_PRECOND_CLUSTER};
    for (int pc = 0; pc < 2; pc++) {
        double *x[2], *lam[2];
        DrLagStats st[2];
        for (int p = 0; p < 2; p++) {
            omp_set_num_threads(p + 1);
            x[p] = calloc((size_t)t.n, sizeof(double));
            DrLag *s = sys_solver(&t, pcs[pc], 1e-12);
            DrLagDesc d;
            dr_lag_desc_default(&d);
            d.precond = pcs[pc];
            d.tol = 1e-12;
            d.max_iter = 5000;
            d.cluster_entries = 3000;
            dr_lag_set_desc(s, &d);
            assert_int_equal(sys_step(&t, s, x[p], &st[p]), DR_OK);
            lam[p] = malloc((size_t)t.ngroups * DR_LAG_MAX_ROWS * sizeof(double));
            memcpy(lam[p], t.lambda, (size_t)t.ngroups * DR_LAG_MAX_ROWS * sizeof(double));
            dr_lag_destroy(&s);
        }
        omp_set_num_threads(2);
        if (pcs[pc] == DR_LAG_PRECOND_CLUSTER) {
            print_message("cluster: %d clusters, the largest %d DOFs, %d iterations\n", st[0].clusters,
                          st[0].cluster_dofs_max, st[0].iterations);
            assert_true(st[0].clusters >= 2);
        }
        assert_memory_equal(x[0], x[1], (size_t)t.n * sizeof(double));
        assert_memory_equal(lam[0], lam[1], (size_t)t.ngroups * DR_LAG_MAX_ROWS * sizeof(double));
        for (int p = 0; p < 2; p++) {
            free(x[p]);
            free(lam[p]);
        }
    }
    sys_free(&t);
}


/* ---- the cluster preconditioner ---------------------------------------------------------------------------- */

static DrLag *cluster_solver(const TestSystem *t, double tol, double entries)
{
    DrLag *s = sys_solver(t, DR_LAG_PRECOND_CLUSTER, tol);
    DrLagDesc d;
    dr_lag_desc_default(&d);
    d.precond = DR_LAG_PRECOND_CLUSTER;
    d.tol = tol;
    d.max_iter = 5000;
    if (entries > 0) d.cluster_entries = entries;
    dr_lag_set_desc(s, &d);
    return s;
}

/* A bundle of 8 × 8 objects joined by stiff springs at every DOF (h²k = 100 against masses near 1: bridges far
   stiffer than the strands): the block preconditioner is blind to the neighbours and needs many iterations; the
   cluster preconditioner makes the whole bundle one cluster, whose factor is A's, and needs at most 1 — at least 3
   times fewer — for the same solution at the same tolerance (against the dense assembly as in
   test_preconditioners_agree). */
static void test_cluster_bundle(void **state)
{
    (void)state;
    TestSystem t;
    sys_bundle(&t, 8, 24, 4, 1e6, 31);
    double *x[2];
    DrLagStats st[2];
    for (int p = 0; p < 2; p++) {
        x[p] = calloc((size_t)t.n, sizeof(double));
        DrLag *s = p ? cluster_solver(&t, 1e-12, 0) : sys_solver(&t, DR_LAG_PRECOND_BLOCK, 1e-12);
        assert_int_equal(sys_step(&t, s, x[p], &st[p]), DR_OK);
        assert_true(dense_residual(&t, x[p]) < 1e-10);
        dr_lag_destroy(&s);
    }
    print_message("bundle of 64 objects, %d springs: block %d iterations, cluster %d (%d cluster of %d DOFs, %.0f "
                  "entries in its factor)\n",
                  st[1].groups_global, st[0].iterations, st[1].iterations, st[1].clusters, st[1].cluster_dofs_max,
                  st[1].cluster_entries);
    assert_int_equal(st[1].clusters, 1);
    assert_int_equal(st[1].cluster_dofs_max, t.n);
    assert_int_equal(st[1].clusters_failed, 0);
    assert_true(st[1].iterations <= 1);
    assert_true(3 * st[1].iterations <= st[0].iterations && st[0].iterations >= 3);
    for (int i = 0; i < t.n; i++) assert_near(x[1][i], x[0][i], 1e-9 * (1 + fabs(x[0][i])));
    free(x[0]);
    free(x[1]);
    sys_free(&t);
}

/* A cluster whose factorisation fails falls back to its objects' blocks, and the rest is solved as usual. Objects 0
   and 1 (one DOF each, mass 1) are joined by a group whose geometric stiffness (−h²G = −3 on DOF 0) makes their part
   of A indefinite, [[−1, −1], [−1, 2]]; they carry no load, so CG never moves them. Objects 2 and 3 are joined by a
   spring (k = 100, φ = 0.01): [[101, −100], [−100, 101]] v = (0.3 − 1, −0.2 + 1), by hand v = (9.3, 10.8) / 201. */
static void test_cluster_fallback(void **state)
{
    (void)state;
    DrLagPrecond pcs[2] = {DR_LAG_PRECOND_CLUSTER, DR_LAG_PRECOND_BLOCK};
    for (int p = 0; p < 2; p++) {
        DrLagDesc d;
        dr_lag_desc_default(&d);
        d.precond = pcs[p];
        d.tol = 1e-13;
        DrLag *s = NULL;
        DrError err;
        assert_int_equal(dr_lag_create(&d, &s, &err), DR_OK);
        for (int o = 0; o < 4; o++) {
            int id, d0;
            assert_int_equal(dr_lag_add_object(s, 1, 0, &id, &d0, &err), DR_OK);
        }
        double m[4] = {1, 1, 1, 1}, v[4] = {0, 0, 0.3, -0.2}, G[4] = {3, 0, 0, 0};
        assert_int_equal(dr_lag_begin(s, 1.0, m, v, NULL, NULL, NULL, &err), DR_OK);
        DrLagGroup bad = {.kind = DR_LAG_POSITIONAL, .nrows = 1, .ndof = 2, .dof = {0, 1}, .phi = {0}, .cinv = {1},
                          .J = {1, -1}, .G = G};
        DrLagGroup spring = {.kind = DR_LAG_POSITIONAL, .nrows = 1, .ndof = 2, .dof = {2, 3}, .phi = {0.01},
                             .cinv = {100}, .J = {1, -1}};
        assert_int_equal(dr_lag_add_global(s, &bad, &err), DR_OK);
        assert_int_equal(dr_lag_add_global(s, &spring, &err), DR_OK);
        double x[4];
        DrLagStats st;
        assert_int_equal(dr_lag_solve(s, x, &st, &err), DR_OK);
        assert_true(x[0] == 0 && x[1] == 0);
        assert_near(x[2], 9.3 / 201, 1e-12);
        assert_near(x[3], 10.8 / 201, 1e-12);
        assert_int_equal(st.contact_blocks_dropped, 1); /* object 0's block with its K_G terms is −1 */
        if (pcs[p] == DR_LAG_PRECOND_CLUSTER) {
            assert_int_equal(st.clusters, 2);
            assert_int_equal(st.clusters_failed, 1);
            assert_true(st.iterations <= 1); /* the good cluster is solved exactly */
        }
        dr_lag_destroy(&s);
    }
}

/* Steps after the first allocate nothing: the clusters, their matrices, analyses and factors are kept, and CHOLMOD's
   own blocks come back from its pool. Six steps of a bundle, each with two solves (with a load, without) and the
   multipliers; the first step allocates (the count works), and no step after it analyses again. */
static void test_cluster_no_allocation(void **state)
{
    (void)state;
    TestSystem t;
    sys_bundle(&t, 4, 16, 4, 1e4, 41);
    TestLoad L;
    load_make(&t, &L, 3);
    DrLagLoad load = {L.force, L.nblocks, L.block_dof, L.D};
    for (int threads = 1; threads <= 2; threads++) {
        omp_set_num_threads(threads);
        DrLag *s = cluster_solver(&t, 1e-10, 0);
        double *x = calloc((size_t)t.n, sizeof(double));
        DrError err;
        for (int step = 0; step < 6; step++) {
            uint64_t before = dr_alloc_count();
            assert_int_equal(dr_lag_begin(s, t.h, t.mass, t.v, t.f, NULL, NULL, &err), DR_OK);
            for (int k = 0; k < t.ngroups; k++)
                assert_int_equal(t.global[k] ? dr_lag_add_global(s, &t.groups[k], &err)
                                             : dr_lag_add(s, &t.groups[k], &err),
                                 DR_OK);
            DrLagStats st[2];
            assert_int_equal(dr_lag_solve_load(s, &load, x, &st[0], &err), DR_OK);
            assert_int_equal(dr_lag_solve_load(s, NULL, x, &st[1], &err), DR_OK);
            dr_lag_update_multipliers(s, x);
            uint64_t made = dr_alloc_count() - before;
            assert_int_equal(st[0].clusters, 1);
            if (step == 0) {
                assert_true(made > 0);
                assert_int_equal(st[0].cluster_analyses + st[1].cluster_analyses, 0); /* made with the clusters */
            } else if (made != 0 || st[0].cluster_analyses + st[1].cluster_analyses != 0) {
                fail_msg("step %d on %d thread(s): %llu allocations, %d analyses", step + 1, threads,
                         (unsigned long long)made, st[0].cluster_analyses + st[1].cluster_analyses);
            }
        }
        free(x);
        dr_lag_destroy(&s);
    }
    omp_set_num_threads(2);
    load_free(&L);
    sys_free(&t);
}

/* A factor budget too small for the whole bundle cuts it into clusters that fit; the answer is the same (to the
   tolerance) and costs more iterations than one cluster. The clusters depend on the step alone: a system that has
   solved other steps before (another pattern, which leaves other analyses and probes behind; the same step
   twice) gives the bits of a fresh one. */
static void test_cluster_budget(void **state)
{
    (void)state;
    TestSystem t;
    sys_bundle(&t, 6, 16, 4, 1e6, 43);
    double *whole = calloc((size_t)t.n, sizeof(double)), *x[3];
    DrLagStats sw, st;
    DrLag *s = cluster_solver(&t, 1e-12, 0);
    assert_int_equal(sys_step(&t, s, whole, &sw), DR_OK);
    dr_lag_destroy(&s);
    double budget = sw.cluster_entries / 3;
    /* fresh */
    x[0] = calloc((size_t)t.n, sizeof(double));
    s = cluster_solver(&t, 1e-12, budget);
    assert_int_equal(sys_step(&t, s, x[0], &st), DR_OK);
    dr_lag_destroy(&s);
    print_message("budget %.0f entries (whole bundle: %.0f): %d clusters, the largest %d of %d DOFs, %.0f entries; %d "
                  "iterations against %d\n",
                  budget, sw.cluster_entries, st.clusters, st.cluster_dofs_max, t.n, st.cluster_entries, st.iterations,
                  sw.iterations);
    assert_true(st.clusters >= 3 && st.cluster_dofs_max < t.n && st.clusters_failed == 0);
    assert_true(st.cluster_entries <= st.clusters * budget);
    assert_true(st.iterations > sw.iterations);
    assert_true(dense_residual(&t, x[0]) < 1e-10);
    for (int i = 0; i < t.n; i++) assert_near(x[0][i], whole[i], 1e-9 * (1 + fabs(whole[i])));
    /* after a step with half the springs, and after the same step */
    int all = t.ngroups;
    for (int k = 1; k < 3; k++) {
        x[k] = calloc((size_t)t.n, sizeof(double));
        s = cluster_solver(&t, 1e-12, budget);
        t.ngroups = k == 1 ? all - (all - t.nobj * t.per) / 2 : all;
        assert_int_equal(sys_step(&t, s, x[k], NULL), DR_OK);
        t.ngroups = all;
        assert_int_equal(sys_step(&t, s, x[k], NULL), DR_OK);
        dr_lag_destroy(&s);
        assert_memory_equal(x[k], x[0], (size_t)t.n * sizeof(double));
    }
    for (int k = 0; k < 3; k++) free(x[k]);
    free(whole);
    sys_free(&t);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_spring_by_hand),       cmocka_unit_test(test_viscous_by_hand),
        cmocka_unit_test(test_preconditioners_agree), cmocka_unit_test(test_local_solve_exact),
        cmocka_unit_test(test_prescribed),           cmocka_unit_test(test_indefinite_block),
        cmocka_unit_test(test_bad_groups),           cmocka_unit_test(test_iteration_cap),
        cmocka_unit_test(test_threads_bit_identical), cmocka_unit_test(test_contact_hides_indefinite_block),
        cmocka_unit_test(test_load_by_hand),         cmocka_unit_test(test_load_dense),
        cmocka_unit_test(test_load_resolve),         cmocka_unit_test(test_contact_terms_beyond_band),
        cmocka_unit_test(test_cluster_bundle),       cmocka_unit_test(test_cluster_fallback),
        cmocka_unit_test(test_cluster_no_allocation), cmocka_unit_test(test_cluster_budget),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
