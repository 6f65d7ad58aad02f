/* Unit tests of src/cloth: the shell kernels (membrane rows and their Jacobians and geometric stiffness against
 * central differences, the rows' energy against the StVK energy, the hinge angle and its gradient), the membrane
 * patch tests (uniaxial stretch and shear of one triangle and of an irregular patch give the StVK energy and the
 * nodal forces of the homogeneous stress exactly; a rigid motion gives zero strain and force), the panel's vertex
 * order (its band) and malformed meshes; self contact: two sheets pushed together stop at the contact distance with
 * their momentum kept to round-off and the same bits on 1 and 2 threads, friction between the layers, pairs close in
 * the rest shape left alone, and contacts within the band solved by the panel's block alone. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "cloth/cloth.h"
#include "cloth/shell.h"
#include "core/core.h"
#include "../validation/cloth_grid.h"

static void near_or_fail(double a, double b, double tol, const char *file, int line)
{
    if (fabs(a - b) <= tol) return;
    print_error("%.17g != %.17g (|diff| %.3g > tol %.3g)\n", a, b, fabs(a - b), tol);
    _fail(file, line);
}
#define assert_near(a, b, tol) near_or_fail((a), (b), (tol), __FILE__, __LINE__)

static double uni(DrRng *rng, double a, double b) { return a + (b - a) * dr_rng_uniform(rng); }

static const double K = 2.5e3, NU = 0.3; /* membrane stiffness E h/(1 − ν²) (N/m) and Poisson's ratio of the tests */

/* ---- membrane rows -------------------------------------------------------------------------------------------- */

static void random_triangle(DrRng *rng, double *X)
{
    for (;;) {
        for (int i = 0; i < 9; i++) X[i] = uni(rng, -0.01, 0.01);
        double Bm[4], A;
        if (dr_shell_rest(X, X + 3, X + 6, Bm, &A) && A > 1e-6) return;
    }
}

static void test_membrane_rows(void **state)
{
    (void)state;
    DrRng rng;
    dr_rng_seed(&rng, 11);
    for (int trial = 0; trial < 20; trial++) {
        double X[9], x[9], Bm[4], A;
        random_triangle(&rng, X);
        assert_true(dr_shell_rest(X, X + 3, X + 6, Bm, &A));
        for (int i = 0; i < 9; i++) x[i] = X[i] * uni(&rng, 0.8, 1.2) + uni(&rng, -1e-3, 1e-3);
        const int dof[3] = {0, 3, 6};
        double lambda[3] = {uni(&rng, -1, 1), uni(&rng, -1, 1), uni(&rng, -1, 1)}, G[81];
        DrLagGroup g;
        dr_shell_membrane_group(x, x + 3, x + 6, Bm, A, K, NU, dof, lambda, false, G, &g);
        assert_int_equal(g.nrows, 3);
        assert_int_equal(g.ndof, 9);
        /* the rows' energy is the StVK energy */
        double W = 0;
        for (int r = 0; r < 3; r++) W += 0.5 * g.cinv[r] * g.phi[r] * g.phi[r];
        assert_near(W, dr_shell_membrane_energy(x, x + 3, x + 6, Bm, A, K, NU), 1e-13 * (W + 1e-30));
        /* J and G against central differences of φ and of Σ λ J */
        const double eps = 1e-7;
        for (int a = 0; a < 9; a++) {
            double s = x[a], Jp[27], Jm[27], pp[3], pm[3];
            DrLagGroup gp, gm;
            x[a] = s + eps;
            dr_shell_membrane_group(x, x + 3, x + 6, Bm, A, K, NU, dof, NULL, false, NULL, &gp);
            x[a] = s - eps;
            dr_shell_membrane_group(x, x + 3, x + 6, Bm, A, K, NU, dof, NULL, false, NULL, &gm);
            x[a] = s;
            memcpy(pp, gp.phi, sizeof pp), memcpy(pm, gm.phi, sizeof pm);
            memcpy(Jp, gp.J, sizeof Jp), memcpy(Jm, gm.J, sizeof Jm);
            for (int r = 0; r < 3; r++) assert_near(g.J[9 * r + a], (pp[r] - pm[r]) / (2 * eps), 1e-6);
            for (int b = 0; b < 9; b++) {
                double fd = 0;
                for (int r = 0; r < 3; r++) fd += lambda[r] * (Jp[9 * r + b] - Jm[9 * r + b]) / (2 * eps);
                assert_near(G[9 * b + a], fd, 1e-6 * (1 + fabs(fd)));
            }
        }
    }
}

/* ---- patch tests (acceptance 1) ------------------------------------------------------------------------------- */

/* Forces f = −Σ Jᵀ C⁻¹ φ of a mesh's membrane rows (DOFs 3 v), and its energy. */
static double membrane_forces(const DrTriMesh *rest, const double *x, double *f)
{
    memset(f, 0, 3 * (size_t)rest->nv * sizeof(double));
    double W = 0;
    for (int t = 0; t < rest->nt; t++) {
        const int *tv = rest->tri + 3 * t;
        double Bm[4], A;
        assert_true(dr_shell_rest(rest->v + 3 * tv[0], rest->v + 3 * tv[1], rest->v + 3 * tv[2], Bm, &A));
        int dof[3] = {3 * tv[0], 3 * tv[1], 3 * tv[2]};
        DrLagGroup g;
        dr_shell_membrane_group(x + 3 * tv[0], x + 3 * tv[1], x + 3 * tv[2], Bm, A, K, NU, dof, NULL, false, NULL, &g);
        for (int r = 0; r < 3; r++) {
            W += 0.5 * g.cinv[r] * g.phi[r] * g.phi[r];
            for (int a = 0; a < 9; a++) f[g.dof[a]] -= g.J[9 * r + a] * g.cinv[r] * g.phi[r];
        }
    }
    return W;
}

/* An irregular patch: a 5 × 4 grid on [0, 0.04] × [0, 0.03] (x, z) whose interior vertices are moved at random. */
static void irregular_patch(DrTriMesh *m)
{
    assert_int_equal(cloth_grid(5, 4, 0.04, 0.03, 0.0, m), 0);
    DrRng rng;
    dr_rng_seed(&rng, 5);
    for (int j = 1; j < 3; j++)
        for (int i = 1; i < 4; i++) {
            m->v[3 * (i + 5 * j)] += uni(&rng, -0.003, 0.003);
            m->v[3 * (i + 5 * j) + 2] += uni(&rng, -0.003, 0.003);
        }
}

/* x = F X (F: 3 × 3 row-major) + b */
static void deform(const DrTriMesh *m, const double F[9], const double b[3], double *x)
{
    for (int v = 0; v < m->nv; v++)
        for (int a = 0; a < 3; a++)
            x[3 * v + a] = F[3 * a] * m->v[3 * v] + F[3 * a + 1] * m->v[3 * v + 1] + F[3 * a + 2] * m->v[3 * v + 2] + b[a];
}

/* A homogeneous in-plane deformation of the patch (the sheet spans x and z): the energy is A ½ εᵀDε with the Green
   strain of F, interior vertices feel no force, and each boundary vertex the traction of the first Piola stress
   P = F S over its share of the boundary. */
static void check_patch(const double F[9])
{
    DrTriMesh m;
    irregular_patch(&m);
    double *x = malloc(3 * (size_t)m.nv * sizeof(double)), *f = malloc(3 * (size_t)m.nv * sizeof(double));
    const double b[3] = {0.1, -0.2, 0.3};
    deform(&m, F, b, x);
    double W = membrane_forces(&m, x, f);
    /* the in-plane 2×2 strain in the (x, z) axes */
    double C11 = F[0] * F[0] + F[3] * F[3] + F[6] * F[6], C22 = F[2] * F[2] + F[5] * F[5] + F[8] * F[8];
    double C12 = F[0] * F[2] + F[3] * F[5] + F[6] * F[8];
    double E11 = 0.5 * (C11 - 1), E22 = 0.5 * (C22 - 1), E12 = 0.5 * C12;
    double area = 0.04 * 0.03;
    double Wexact = 0.5 * area * K * (E11 * E11 + E22 * E22 + 2 * NU * E11 * E22 + 2 * (1 - NU) * E12 * E12);
    assert_near(W, Wexact, 1e-12 * Wexact);
    /* second Piola stress (plane stress, per unit length) and P = F S on the in-plane columns */
    double S11 = K * (E11 + NU * E22), S22 = K * (E22 + NU * E11), S12 = K * (1 - NU) * E12;
    double fscale = K * 0.04;
    for (int j = 0; j < 4; j++)
        for (int i = 0; i < 5; i++) {
            int v = i + 5 * j;
            /* the boundary's outward normal N (x, z components) times the vertex's share of its length */
            double Nx = 0, Nz = 0;
            if (i == 0) Nx -= (j == 0 || j == 3) ? 0.005 : 0.01;
            if (i == 4) Nx += (j == 0 || j == 3) ? 0.005 : 0.01;
            if (j == 0) Nz -= (i == 0 || i == 4) ? 0.005 : 0.01;
            if (j == 3) Nz += (i == 0 || i == 4) ? 0.005 : 0.01;
            double T1 = S11 * Nx + S12 * Nz, T2 = S12 * Nx + S22 * Nz; /* S N */
            for (int a = 0; a < 3; a++) {
                double expect = -(F[3 * a] * T1 + F[3 * a + 2] * T2); /* the body pulls back: −P N = −F S N */
                assert_near(f[3 * v + a], expect, 1e-10 * fscale);
            }
        }
    free(x);
    free(f);
    dr_trimesh_free(&m);
}

static void test_patch_uniaxial(void **state)
{
    (void)state;
    const double F[9] = {1.1, 0, 0, 0, 1, 0, 0, 0, 1};
    check_patch(F);
    const double Fz[9] = {1, 0, 0, 0, 1, 0, 0, 0, 0.93};
    check_patch(Fz);
}

static void test_patch_shear(void **state)
{
    (void)state;
    const double F[9] = {1, 0, 0.2, 0, 1, 0, 0, 0, 1};
    check_patch(F);
    /* shear with out-of-plane tilt and stretch together */
    const double G[9] = {1.05, 0, 0.1, 0.2, 1, -0.1, 0.05, 0, 0.97};
    check_patch(G);
}

static void test_single_triangle(void **state)
{
    (void)state;
    /* one right triangle of legs a in the (x, z) plane stretched along x by s: W = ½ A k E11², E11 = ((1+s)² − 1)/2 */
    const double a = 0.02, s = 0.05;
    const double X[9] = {0, 0, 0, a, 0, 0, 0, 0, a}; /* the rest frame's first axis is x0 → x1: x */
    double Bm[4], A;
    assert_true(dr_shell_rest(X, X + 3, X + 6, Bm, &A));
    assert_near(A, 0.5 * a * a, 1e-18);
    double x[9];
    memcpy(x, X, sizeof x);
    x[3] *= 1 + s;
    double E11 = 0.5 * ((1 + s) * (1 + s) - 1);
    assert_near(dr_shell_membrane_energy(x, x + 3, x + 6, Bm, A, K, NU), 0.5 * A * K * E11 * E11, 1e-15);
    double E[3];
    dr_shell_green(x, x + 3, x + 6, Bm, E);
    assert_near(E[0], E11, 1e-15);
    assert_near(E[1], 0, 1e-15);
    assert_near(E[2], 0, 1e-15);
}

static void test_rigid_motion(void **state)
{
    (void)state;
    DrTriMesh m;
    irregular_patch(&m);
    DrRng rng;
    dr_rng_seed(&rng, 9);
    for (int trial = 0; trial < 10; trial++) {
        /* a random rotation (Rodrigues) and translation */
        DrVec3 k = dr_v3_normalize(dr_v3(uni(&rng, -1, 1), uni(&rng, -1, 1), uni(&rng, -1, 1)));
        double th = uni(&rng, -3, 3), c = cos(th), s = sin(th), kk[3] = {k.x, k.y, k.z};
        double R[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double cross = 0;
                if (i == 0 && j == 1) cross = -kk[2];
                if (i == 0 && j == 2) cross = kk[1];
                if (i == 1 && j == 0) cross = kk[2];
                if (i == 1 && j == 2) cross = -kk[0];
                if (i == 2 && j == 0) cross = -kk[1];
                if (i == 2 && j == 1) cross = kk[0];
                R[3 * i + j] = (i == j ? c : 0) + s * cross + (1 - c) * kk[i] * kk[j];
            }
        double b[3] = {uni(&rng, -1, 1), uni(&rng, -1, 1), uni(&rng, -1, 1)};
        double *x = malloc(3 * (size_t)m.nv * sizeof(double)), *f = malloc(3 * (size_t)m.nv * sizeof(double));
        deform(&m, R, b, x);
        double W = membrane_forces(&m, x, f);
        assert_true(W < 1e-25);
        for (int i = 0; i < 3 * m.nv; i++) assert_near(f[i], 0, 1e-11);
        free(x);
        free(f);
    }
    dr_trimesh_free(&m);
}

/* ---- hinges ------------------------------------------------------------------------------------------------------ */

static void test_hinge_angle(void **state)
{
    (void)state;
    /* edge x1 = (0,0,0) → x2 = (0,0,1) (along z); wings at unit distance, x0 at −x, x3 at +x, folded by α about
       the edge; the triangles (x0 x1 x2), (x3 x2 x1) both face +y when flat */
    for (double alpha = -2.5; alpha <= 2.5; alpha += 0.5) {
        double x0[3] = {-cos(alpha / 2), sin(alpha / 2), 0.3}, x1[3] = {0, 0, 0}, x2[3] = {0, 0, 1};
        double x3[3] = {cos(alpha / 2), sin(alpha / 2), 0.6};
        double Bm[4], A;
        assert_true(dr_shell_rest(x0, x1, x2, Bm, &A));
        double th = dr_shell_hinge_angle(x0, x1, x2, x3, NULL);
        /* wings lifted (+y, the normals' side) fold the hinge by θ = α */
        assert_near(fabs(th), fabs(alpha), 1e-12);
        if (alpha != 0) assert_true(th * alpha > 0);
    }
    DrRng rng;
    dr_rng_seed(&rng, 3);
    for (int trial = 0; trial < 50; trial++) {
        double x[12], g[12];
        for (int i = 0; i < 12; i++) x[i] = uni(&rng, -1, 1);
        dr_shell_hinge_angle(x, x + 3, x + 6, x + 9, g);
        double sum[3] = {0, 0, 0};
        for (int i = 0; i < 12; i++) {
            double s = x[i], e = 1e-6;
            x[i] = s + e;
            double a = dr_shell_hinge_angle(x, x + 3, x + 6, x + 9, NULL);
            x[i] = s - e;
            double b = dr_shell_hinge_angle(x, x + 3, x + 6, x + 9, NULL);
            x[i] = s;
            if (fabs(a - b) < 1.0) assert_near(g[i], (a - b) / (2 * e), 1e-5 * (1 + fabs(g[i])));
            sum[i % 3] += g[i];
        }
        for (int a = 0; a < 3; a++) assert_near(sum[a], 0, 1e-10);
    }
}

/* The bending energy of a flat panel (both quad-split patterns, 41 × 41) bent to a uniform curvature tensor K (the
   height field ½ xᵀ K x, small): the shape-operator rows store Kirchhoff's k_b A [ν (tr K)² + (1 − ν)|K|²] for
   bending about either axis, twist and saddles, at ν = 0 and 0.3, within what the boundary triangles (1/40 of the
   panel, whose boundary edges do not enter their shape operator) change: 2.5 % measured. The shape operator is
   exact for a uniform K on lattice meshes (every triangle a translate of one of two, as with parallel diagonals, or
   equilateral); on alternating diagonals it is exact for bending and saddles but stores 2/(1 − ν) times the twisting energy
   (printed, not asserted; shell.h). */
static double bent_energy(DrCloth *c, const DrTriMesh *m, double kxx, double kzz, double kxz)
{
    double *x = dr_cloth_positions_mut(c);
    for (int v = 0; v < m->nv; v++) {
        double X = m->v[3 * v] - 0.05, Z = m->v[3 * v + 2] - 0.05;
        x[3 * v] = X, x[3 * v + 2] = Z;
        x[3 * v + 1] = 0.5 * (kxx * X * X + kzz * Z * Z) + kxz * X * Z;
    }
    DrClothEnergy e;
    dr_cloth_energy(c, &e);
    return e.bending;
}

static void test_bending_energy(void **state)
{
    (void)state;
    const double k = 0.01, nus[2] = {0.0, 0.3};
    const double fields[4][3] = {{k, 0, 0}, {0, k, 0}, {0, 0, k}, {k, -k, 0}};
    for (int pattern = 0; pattern < 2; pattern++)
        for (int in = 0; in < 2; in++) {
            DrTriMesh m;
            assert_int_equal(cloth_grid_pattern(41, 41, 0.1, 0.1, 0, pattern == 1, &m), 0);
            DrClothMaterial mat;
            dr_cloth_material_default(&mat);
            mat.poisson = nus[in];
            mat.youngs_modulus = 1e6, mat.thickness = 1e-3;
            double kb = 1e6 * 1e-9 / (24 * (1 - nus[in] * nus[in])), nu = nus[in];
            DrCloth *c = NULL;
            DrError err;
            assert_int_equal(dr_cloth_create(NULL, &m, &mat, "panel", &c, &err), DR_OK);
            for (int f = 0; f < 4; f++) {
                double kxx = fields[f][0], kzz = fields[f][1], kxz = fields[f][2], tr = kxx + kzz;
                double expect = kb * 0.01 * (nu * tr * tr + (1 - nu) * (kxx * kxx + kzz * kzz + 2 * kxz * kxz));
                double ratio = bent_energy(c, &m, kxx, kzz, kxz) / expect;
                print_message("%s diagonals, nu %.1f, K (%g %g %g): energy / Kirchhoff %.4f\n",
                              pattern ? "alternating" : "parallel", nu, kxx, kzz, kxz, ratio);
                if (pattern == 1 && kxz != 0) continue; /* see above: measured, not exact */
                assert_true(ratio > 0.95 && ratio < 1.05);
            }
            dr_cloth_destroy(&c);
            dr_trimesh_free(&m);
        }
}

/* ---- panels ---------------------------------------------------------------------------------------------------------- */

static void test_band(void **state)
{
    (void)state;
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    for (int n = 4; n <= 32; n *= 2) {
        DrTriMesh m;
        assert_int_equal(cloth_grid(n, n, 0.1, 0.1, 0, &m), 0);
        /* shuffle the vertex numbering: the order must come from the mesh's graph, not its input order */
        DrRng rng;
        dr_rng_seed(&rng, (uint64_t)n);
        int *perm = malloc((size_t)m.nv * sizeof(int));
        for (int i = 0; i < m.nv; i++) perm[i] = i;
        for (int i = m.nv - 1; i > 0; i--) {
            int j = (int)(dr_rng_uniform(&rng) * (i + 1));
            int t = perm[i];
            perm[i] = perm[j], perm[j] = t;
        }
        double *v = malloc(3 * (size_t)m.nv * sizeof(double));
        for (int i = 0; i < m.nv; i++) memcpy(v + 3 * perm[i], m.v + 3 * i, 3 * sizeof(double));
        for (int i = 0; i < 3 * m.nt; i++) m.tri[i] = perm[m.tri[i]];
        free(m.v);
        m.v = v;
        DrCloth *c = NULL;
        DrError err;
        assert_int_equal(dr_cloth_create(NULL, &m, &mat, "panel", &c, &err), DR_OK);
        /* a grid of n × n vertices: a hinge spans two rows, so the band is at most 2n + 1 whatever the input order */
        print_message("grid %d x %d: band %d vertices\n", n, n, dr_cloth_band(c));
        assert_true(dr_cloth_band(c) <= 2 * n + 1);
        assert_int_equal(dr_cloth_hinge_count(c), 3 * (n - 1) * (n - 1) - 2 * (n - 1));
        dr_cloth_destroy(&c);
        free(perm);
        dr_trimesh_free(&m);
    }
}

static void expect_input_error(DrTriMesh *m, const char *needle)
{
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    DrCloth *c = NULL;
    DrError err;
    assert_int_equal(dr_cloth_create(NULL, m, &mat, "flag", &c, &err), DR_ERR_INPUT);
    assert_null(c);
    if (!strstr(err.message, needle)) fail_msg("message \"%s\" lacks \"%s\"", err.message, needle);
    assert_non_null(strstr(err.message, "flag"));
}

static void test_bad_meshes(void **state)
{
    (void)state;
    DrTriMesh m;
    /* a flipped triangle */
    assert_int_equal(cloth_grid(3, 3, 1, 1, 0, &m), 0);
    int t = m.tri[1];
    m.tri[1] = m.tri[2], m.tri[2] = t;
    expect_input_error(&m, "wound opposite ways");
    dr_trimesh_free(&m);
    /* three triangles on one edge */
    assert_int_equal(cloth_grid(3, 3, 1, 1, 0, &m), 0);
    m.tri = realloc(m.tri, 3 * (size_t)(m.nt + 1) * sizeof(int));
    m.tri[3 * m.nt] = m.tri[0], m.tri[3 * m.nt + 1] = m.tri[2], m.tri[3 * m.nt + 2] = 2;
    m.nt++;
    expect_input_error(&m, "borders 3 triangles");
    dr_trimesh_free(&m);
    /* a degenerate triangle */
    assert_int_equal(cloth_grid(3, 3, 1, 1, 0, &m), 0);
    memcpy(m.v + 3 * 4, m.v + 3 * 0, 3 * sizeof(double));
    expect_input_error(&m, "degenerate");
    dr_trimesh_free(&m);
    /* an index out of range, a vertex in no triangle */
    assert_int_equal(cloth_grid(3, 3, 1, 1, 0, &m), 0);
    m.tri[5] = 9;
    expect_input_error(&m, "refers to vertex 9");
    m.tri[5] = 1;
    m.v = realloc(m.v, 3 * 10 * sizeof(double));
    m.v[27] = m.v[28] = m.v[29] = 2;
    m.nv = 10;
    expect_input_error(&m, "vertex 9 belongs to no triangle");
    dr_trimesh_free(&m);
    /* a material out of range */
    assert_int_equal(cloth_grid(3, 3, 1, 1, 0, &m), 0);
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    mat.poisson = 0.5;
    DrCloth *c = NULL;
    DrError err;
    assert_int_equal(dr_cloth_create(NULL, &m, &mat, "flag", &c, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "Poisson"));
    dr_trimesh_free(&m);
}

/* ---- self contact ------------------------------------------------------------------------------------------------ */

/* Two square sheets (6 × 6 vertices, 0.1 m, one panel of two pieces) parallel in the (x, z) plane, 6.5 mm apart, the
   upper one shifted by a fraction of a cell in x and z so that its vertices fall inside the lower one's triangles,
   pushed together at 0.5 m/s each (both drifting along x and z alike) with no gravity and no friction, 40 steps of
   1 ms: they meet in the sixth step. */
typedef struct TwoSheets {
    double meet_min, meet_max; /* at the first step with self contacts: the upper sheet's vertices over the lower
                                  sheet, their height above it, m */
    double closest;            /* the least such height over every step, m */
    double end_min;            /* the least such height at the end, m */
    double slide;              /* at the end: the upper sheet's mean velocity along x less the lower one's, m/s */
    double dp, p_scale;        /* the largest change of a momentum component over a step (N s), and Σ m |v| */
    int contacts_max;          /* the most self contacts of a step */
    DrHash hash;               /* positions and velocities at the end */
} TwoSheets;

/* The height of point p above the lower sheet (vertices 0..35, triangles 0..49) where p's (x, z) falls on it; false
   elsewhere. */
static bool height_above(const DrCloth *c, const double *p, double *height)
{
    const double *x = dr_cloth_positions(c);
    const int *tri = dr_cloth_triangles(c);
    for (int t = 0; t < 50; t++) {
        const double *a = x + 3 * tri[3 * t], *b = x + 3 * tri[3 * t + 1], *d = x + 3 * tri[3 * t + 2];
        double det = (b[0] - a[0]) * (d[2] - a[2]) - (d[0] - a[0]) * (b[2] - a[2]);
        double u = ((p[0] - a[0]) * (d[2] - a[2]) - (d[0] - a[0]) * (p[2] - a[2])) / det;
        double w = ((b[0] - a[0]) * (p[2] - a[2]) - (p[0] - a[0]) * (b[2] - a[2])) / det;
        if (u < 0 || w < 0 || u + w > 1) continue;
        *height = p[1] - (a[1] + u * (b[1] - a[1]) + w * (d[1] - a[1]));
        return true;
    }
    return false;
}

/* The least and the largest height of the upper sheet's vertices over the lower sheet. */
static void sheet_heights(const DrCloth *c, double *lo, double *hi)
{
    *lo = INFINITY, *hi = -INFINITY;
    for (int v = 36; v < 72; v++) {
        double h;
        if (!height_above(c, dr_cloth_positions(c) + 3 * v, &h)) continue;
        *lo = fmin(*lo, h), *hi = fmax(*hi, h);
    }
}

/* The lower sheet at y = 0 (vertices 0..35), the upper one `gap` above it, shifted by (0.37, 0.29) of a cell. */
static void two_sheet_mesh(double gap, DrTriMesh *m)
{
    DrTriMesh lo, hi;
    assert_int_equal(cloth_grid(6, 6, 0.1, 0.1, 0.0, &lo), 0);
    assert_int_equal(cloth_grid(6, 6, 0.1, 0.1, gap, &hi), 0);
    m->nv = 72, m->nt = 100, m->n = NULL, m->uv = NULL;
    m->v = malloc(3 * 72 * sizeof(double));
    m->tri = malloc(3 * 100 * sizeof(int));
    memcpy(m->v, lo.v, 3 * 36 * sizeof(double));
    for (int v = 0; v < 36; v++) {
        m->v[3 * (36 + v)] = hi.v[3 * v] + 0.37 * 0.02;
        m->v[3 * (36 + v) + 1] = hi.v[3 * v + 1];
        m->v[3 * (36 + v) + 2] = hi.v[3 * v + 2] + 0.29 * 0.02;
    }
    memcpy(m->tri, lo.tri, 3 * 50 * sizeof(int));
    for (int i = 0; i < 150; i++) m->tri[150 + i] = hi.tri[i] + 36;
    dr_trimesh_free(&lo);
    dr_trimesh_free(&hi);
}

/* slide: the upper sheet's velocity along x relative to the lower one's, m/s */
static TwoSheets two_sheets(bool self_contact, double friction, double slide, int steps, int threads)
{
    dr_set_threads(threads);
    DrTriMesh m;
    two_sheet_mesh(0.0065, &m);
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    mat.self_contact = self_contact;
    mat.self_friction = friction; /* between the two sheets */
    DrClothDesc desc;
    dr_cloth_desc_default(&desc);
    desc.gravity = dr_v3(0, 0, 0);
    desc.solver.tol = 1e-14; /* the momentum a solve leaves unbalanced is of order tol |M v| */
    DrCloth *c = NULL;
    DrError err;
    assert_int_equal(dr_cloth_create(&desc, &m, &mat, "pair", &c, &err), DR_OK);
    int V = dr_cloth_vertex_count(c);
    double *vel = dr_cloth_velocities_mut(c);
    for (int v = 0; v < V; v++) {
        const double w[2][3] = {{0.1, 0.5, 0.05}, {0.1 + slide, -0.5, 0.05}};
        memcpy(vel + 3 * v, w[v >= 36], sizeof w[0]);
    }
    TwoSheets r = {.meet_min = NAN, .meet_max = NAN, .closest = INFINITY};
    const double *mass = dr_cloth_masses(c);
    for (int v = 0; v < V; v++)
        r.p_scale += mass[v] * sqrt(vel[3 * v] * vel[3 * v] + vel[3 * v + 1] * vel[3 * v + 1] + vel[3 * v + 2] * vel[3 * v + 2]);
    for (int s = 0; s < steps; s++) {
        double p0[3] = {0, 0, 0}, p1[3] = {0, 0, 0};
        for (int v = 0; v < V; v++)
            for (int a = 0; a < 3; a++) p0[a] += mass[v] * dr_cloth_velocities(c)[3 * v + a];
        DrClothStats st;
        assert_int_equal(dr_cloth_step(c, 1e-3, NULL, 0, &st, &err), DR_OK);
        for (int v = 0; v < V; v++)
            for (int a = 0; a < 3; a++) p1[a] += mass[v] * dr_cloth_velocities(c)[3 * v + a];
        for (int a = 0; a < 3; a++) r.dp = fmax(r.dp, fabs(p1[a] - p0[a]));
        double gmin, gmax;
        sheet_heights(c, &gmin, &gmax);
        r.closest = fmin(r.closest, gmin);
        if (st.self_contacts > 0 && isnan(r.meet_min)) r.meet_min = gmin, r.meet_max = gmax;
        r.contacts_max = st.self_contacts > r.contacts_max ? st.self_contacts : r.contacts_max;
    }
    double unused, vlo = 0, vhi = 0;
    sheet_heights(c, &r.end_min, &unused);
    for (int v = 0; v < 36; v++) {
        vlo += dr_cloth_velocities(c)[3 * v] / 36;
        vhi += dr_cloth_velocities(c)[3 * (36 + v)] / 36;
    }
    r.slide = vhi - vlo;
    DrHasher hs;
    dr_hasher_init(&hs);
    dr_hasher_update(&hs, dr_cloth_positions(c), 3 * (size_t)V * sizeof(double));
    dr_hasher_update(&hs, dr_cloth_velocities(c), 3 * (size_t)V * sizeof(double));
    r.hash = dr_hasher_final(&hs);
    dr_cloth_destroy(&c);
    dr_trimesh_free(&m);
    dr_set_threads(0);
    return r;
}

/* The sheets stop at the contact distance: φ is linear in the positions, so the solve stops each contact at φ = −F/k,
   F its force, k = 1e4 N/m. Stopping a vertex's relative momentum (8e-5 kg × 1 m/s) within a step of 1 ms takes at
   most F = 0.08 N, F/k = 8e-6 m: 0.8 % of the contact distance, the tolerance (0.2 % measured where they meet, 0.2 %
   at the closest). Momentum: the contacts' rows have weights (1, −b0, −b1, −b2) that sum to zero, the membrane's and
   the bending's are translation invariant, and there is no friction, gravity or pin, so Σ m v changes only by what
   the solve's residual leaves, of order tol |M v| (tol 1e-14): asserted below 1e-12 of Σ m |v|. 1 and 2 threads give
   the same bits. Without self contact the sheets pass through each other. */
static void test_self_contact_sheets(void **state)
{
    (void)state;
    const double thickness = 1e-3;
    TwoSheets r = two_sheets(true, 0.0, 0.0, 40, 2);
    print_message("two sheets pushed together at 1 m/s: where they meet %.6e .. %.6e m (contact distance 1e-3), "
                  "closest over 40 steps %.6e m, up to %d self contacts a step; largest momentum change of a step "
                  "%.2e N s (of %.2e)\n",
                  r.meet_min, r.meet_max, r.closest, r.contacts_max, r.dp, r.p_scale);
    assert_true(r.contacts_max > 0);
    assert_true(r.meet_min > thickness * (1 - 0.008) && r.meet_max < thickness * (1 + 1e-9));
    assert_true(r.closest > thickness * (1 - 0.008));
    assert_true(r.dp < 1e-12 * r.p_scale);
    TwoSheets off = two_sheets(false, 0.0, 0.0, 40, 2);
    print_message("without self contact: %d self contacts, the upper sheet %.4e m above the lower at the end\n",
                  off.contacts_max, off.end_min);
    assert_int_equal(off.contacts_max, 0);
    assert_true(off.end_min < 0);
    TwoSheets one = two_sheets(true, 0.0, 0.0, 40, 1);
    assert_true(one.hash.hi == r.hash.hi && one.hash.lo == r.hash.lo);
}

/* A strip of 13 × 5 vertices (0.24 × 0.08 m, cells with alternating diagonals) folded along its length: the rows
   j ≤ 1 at y = 0, the rows j ≥ 3 mirrored over them 6.5 mm higher, the middle row between at the edges' rest length.
   On alternating diagonals the panel's vertex order is a sweep along the strip (narrower than reverse Cuthill–McKee,
   cloth.h), so a vertex and the triangle under it lie within the band: their contacts join the panel's banded block,
   which the solver factors whole, so the step needs no CG iteration (the block solve is the solution) and momentum
   is kept to round-off at the default tolerance. The layers, pushed together at 1 m/s with no gravity, stop at the
   contact distance as the two sheets do. */
static void test_self_contact_in_band(void **state)
{
    (void)state;
    const double gap = 0.0065, dz = 0.02, thickness = 1e-3;
    DrTriMesh m;
    assert_int_equal(cloth_grid_alternating(13, 5, 0.24, 0.08, 0.0, &m), 0);
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    DrClothDesc desc;
    dr_cloth_desc_default(&desc);
    desc.gravity = dr_v3(0, 0, 0);
    DrCloth *c = NULL;
    DrError err;
    assert_int_equal(dr_cloth_create(&desc, &m, &mat, "strip", &c, &err), DR_OK);
    double *x = dr_cloth_positions_mut(c), *vel = dr_cloth_velocities_mut(c);
    for (int j = 0; j < 5; j++)
        for (int i = 0; i < 13; i++) {
            double *p = x + 3 * (i + 13 * j), *w = vel + 3 * (i + 13 * j);
            if (j < 2) p[2] = dz * j, p[1] = 0, w[1] = 0.5;
            else if (j > 2) p[2] = dz * (4 - j), p[1] = gap, w[1] = -0.5;
            else p[2] = dz + sqrt(dz * dz - 0.25 * gap * gap), p[1] = 0.5 * gap;
        }
    const double *mass = dr_cloth_masses(c);
    double dp = 0, scale = 0, closest = INFINITY;
    int contacts = 0, iterations = 0;
    for (int v = 0; v < 65; v++) scale += mass[v] * fabs(vel[3 * v + 1]);
    for (int s = 0; s < 12; s++) {
        double p0[3] = {0, 0, 0}, p1[3] = {0, 0, 0};
        for (int v = 0; v < 65; v++)
            for (int a = 0; a < 3; a++) p0[a] += mass[v] * dr_cloth_velocities(c)[3 * v + a];
        DrClothStats st;
        assert_int_equal(dr_cloth_step(c, 1e-3, NULL, 0, &st, &err), DR_OK);
        for (int v = 0; v < 65; v++)
            for (int a = 0; a < 3; a++) p1[a] += mass[v] * dr_cloth_velocities(c)[3 * v + a];
        for (int a = 0; a < 3; a++) dp = fmax(dp, fabs(p1[a] - p0[a]));
        contacts += st.self_contacts;
        iterations += st.iterations;
        for (int i = 0; i < 13; i++) /* the rows j = 1 and 3, one over the other */
            closest = fmin(closest, dr_cloth_positions(c)[3 * (i + 39) + 1] - dr_cloth_positions(c)[3 * (i + 13) + 1]);
    }
    print_message("strip folded lengthwise (band %d vertices): %d self contacts over 12 steps, %d CG iterations, layers "
                  "%.6e m apart at the closest, momentum change of a step %.2e N s (of %.2e)\n",
                  dr_cloth_band(c), contacts, iterations, closest, dp, scale);
    assert_true(contacts > 0);
    assert_int_equal(iterations, 0);
    assert_true(closest > thickness * (1 - 0.008));
    assert_true(dp < 1e-12 * scale);
    dr_cloth_destroy(&c);
    dr_trimesh_free(&m);
}

/* Friction between the layers: the upper sheet slides along x at 0.1 m/s relative to the lower one as they meet. The
   impact's normal impulse per vertex, λ h ≈ m × 0.5 m/s, lets μ = 0.5 take up to m × 0.25 m/s of sliding, more than
   the slide: the contacts stop their vertices' sliding in the step the sheets meet, and what remains of the sheets'
   mean slide two steps later is the membrane's share from the parts no contact holds (the overhanging rows), −3 %
   measured: asserted below 10 %, while without friction the slide is kept within 2 %. Friction's impulses act on both
   sides with weights that sum to zero, so momentum is conserved as without it (1e-12 of Σ m |v|). Two steps past the
   meeting, before the overhanging rows slide over the other sheet. */
static void test_self_contact_friction(void **state)
{
    (void)state;
    TwoSheets dry = two_sheets(true, 0.0, 0.1, 8, 2), rough = two_sheets(true, 0.5, 0.1, 8, 2);
    print_message("sheets sliding at 0.1 m/s as they meet: slide after two steps in contact %.4e m/s without friction, "
                  "%.4e m/s with mu 0.5; momentum change of a step %.2e N s (of %.2e)\n",
                  dry.slide, rough.slide, rough.dp, rough.p_scale);
    assert_true(rough.contacts_max > 0);
    assert_true(fabs(dry.slide - 0.1) < 2e-3);
    assert_true(fabs(rough.slide) < 1e-2);
    assert_true(rough.dp < 1e-12 * rough.p_scale);
}

/* Pairs closer than the contact distance in the rest shape never touch: the two sheets 0.5 mm apart at rest stay so
   (no self contact, nothing moves) with no gravity. The same sheets made 6.5 mm apart at rest and placed 0.5 mm apart
   are pushed apart by their self contacts (beyond the contact distance: a contact undoes its overlap within one step,
   through the velocity, as the collider contacts do). */
static void test_self_contact_rest(void **state)
{
    (void)state;
    for (int placed = 0; placed < 2; placed++) {
        DrTriMesh m;
        two_sheet_mesh(placed ? 0.0065 : 0.0005, &m);
        DrClothMaterial mat;
        dr_cloth_material_default(&mat);
        DrClothDesc desc;
        dr_cloth_desc_default(&desc);
        desc.gravity = dr_v3(0, 0, 0);
        DrCloth *c = NULL;
        DrError err;
        assert_int_equal(dr_cloth_create(&desc, &m, &mat, "rest", &c, &err), DR_OK);
        double *x = dr_cloth_positions_mut(c);
        for (int v = 36; v < 72; v++) x[3 * v + 1] = 0.0005;
        int contacts = 0;
        for (int s = 0; s < 5; s++) {
            DrClothStats st;
            assert_int_equal(dr_cloth_step(c, 1e-3, NULL, 0, &st, &err), DR_OK);
            contacts += st.self_contacts;
        }
        double lo, hi;
        sheet_heights(c, &lo, &hi);
        print_message("sheets 0.5 mm apart, %s: %d self contacts over 5 steps, now %.4e .. %.4e m apart\n",
                      placed ? "placed so (6.5 mm at rest)" : "at rest", contacts, lo, hi);
        if (placed) {
            assert_true(contacts > 0);
            assert_true(lo > 0.0005);
        } else {
            assert_int_equal(contacts, 0);
            assert_true(lo == 0.0005 && hi == 0.0005);
        }
        dr_cloth_destroy(&c);
        dr_trimesh_free(&m);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_membrane_rows),  cmocka_unit_test(test_single_triangle),
        cmocka_unit_test(test_patch_uniaxial), cmocka_unit_test(test_patch_shear),
        cmocka_unit_test(test_rigid_motion),   cmocka_unit_test(test_hinge_angle),
        cmocka_unit_test(test_bending_energy), cmocka_unit_test(test_band),           cmocka_unit_test(test_bad_meshes),
        cmocka_unit_test(test_self_contact_sheets), cmocka_unit_test(test_self_contact_friction),
        cmocka_unit_test(test_self_contact_rest),      cmocka_unit_test(test_self_contact_in_band),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
