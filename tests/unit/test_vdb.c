/* Unit tests of the OpenVDB shim: collider SDFs, the liquid surface from particles, its mesh, and
 * .vdb files. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "core/core.h"
#include "vdb/vdb.h"

/* ---- helpers ------------------------------------------------------------------------------- */

/* Unit cube [0,1]^3: 8 vertices, 12 triangles wound counter-clockwise seen from outside. */
static DrTriMesh unit_cube(void)
{
    static const double v[24] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1};
    static const int t[36] = {
        0, 2, 1, 0, 3, 2, /* z = 0, normal -z */
        4, 5, 6, 4, 6, 7, /* z = 1, normal +z */
        0, 1, 5, 0, 5, 4, /* y = 0, normal -y */
        3, 7, 6, 3, 6, 2, /* y = 1, normal +y */
        0, 4, 7, 0, 7, 3, /* x = 0, normal -x */
        1, 2, 6, 1, 6, 5, /* x = 1, normal +x */
    };
    DrTriMesh m = {0};
    m.nv = 8;
    m.nt = 12;
    m.v = malloc(sizeof v);
    m.tri = malloc(sizeof t);
    assert_non_null(m.v);
    assert_non_null(m.tri);
    memcpy(m.v, v, sizeof v);
    memcpy(m.tri, t, sizeof t);
    return m;
}

/* Exact signed distance to the box [0,1]^3. */
static double box_sdf(double x, double y, double z)
{
    double q[3] = {fabs(x - 0.5) - 0.5, fabs(y - 0.5) - 0.5, fabs(z - 0.5) - 0.5};
    double out2 = 0.0, in = -1e300;
    for (int a = 0; a < 3; a++) {
        if (q[a] > 0) out2 += q[a] * q[a];
        if (q[a] > in) in = q[a];
    }
    return sqrt(out2) + (in < 0 ? in : 0.0);
}

static float sdf_at(const DrDenseSdf *s, double x, double y, double z)
{
    int i = (int)lround((x - s->origin.x) / s->dx), j = (int)lround((y - s->origin.y) / s->dx),
        k = (int)lround((z - s->origin.z) / s->dx);
    assert_true(i >= 0 && i < s->nx && j >= 0 && j < s->ny && k >= 0 && k < s->nz);
    return s->phi[i + (size_t)s->nx * (j + (size_t)s->ny * k)];
}

/* Runs fn(ctx) with stderr captured into buf (NUL-terminated). */
static void capture_stderr(void (*fn)(void *), void *ctx, char *buf, size_t size)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/drench_vdb_stderr_XXXXXX", dr_temp_dir());
    int fd = mkstemp(path);
    assert_true(fd >= 0);
    fflush(stderr);
    int saved = dup(2);
    assert_true(saved >= 0);
    assert_true(dup2(fd, 2) >= 0);
    fn(ctx);
    fflush(stderr);
    assert_true(dup2(saved, 2) >= 0);
    close(saved);
    lseek(fd, 0, SEEK_SET);
    ssize_t got = read(fd, buf, size - 1);
    buf[got > 0 ? got : 0] = '\0';
    close(fd);
    unlink(path);
}

#define DIR_LEN 512 /* a scratch directory's name under $TMPDIR */

/* Temporary directory for written files (DIR_LEN chars), removed with its contents by rm_dir. */
static void make_dir(char *dir)
{
    snprintf(dir, DIR_LEN, "%s/drench_vdb_XXXXXX", dr_temp_dir());
    assert_non_null(mkdtemp(dir));
}

static void rm_dir(const char *dir)
{
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    assert_int_equal(system(cmd), 0);
}

static int count_files(const char *dir)
{
    char cmd[512];
    snprintf(cmd, sizeof cmd, "ls -A '%s' | wc -l", dir);
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    int n = -1;
    assert_int_equal(fscanf(p, "%d", &n), 1);
    pclose(p);
    return n;
}

/* ---- init ------------------------------------------------------------------------------------ */

static void test_init_idempotent(void **state)
{
    (void)state;
    DrError err;
    assert_int_equal(dr_vdb_init(&err), DR_OK);
    assert_int_equal(dr_vdb_init(&err), DR_OK);
}

/* ---- collider SDF ------------------------------------------------------------------------------ */

static void test_cube_sdf(void **state)
{
    (void)state;
    DrTriMesh cube = unit_cube();
    DrDenseSdf sdf = {0};
    DrError err;
    const double dx = 0.05;
    const int pad = 6;
    assert_int_equal(dr_vdb_mesh_to_sdf(&cube, dx, pad, &sdf, &err), DR_OK);

    /* [0,1] is 20 voxels, plus 6 on each side: 33 nodes per axis from -0.3. */
    assert_int_equal(sdf.nx, 33);
    assert_int_equal(sdf.ny, 33);
    assert_int_equal(sdf.nz, 33);
    assert_true(fabs(sdf.origin.x + 0.3) < 1e-12 && fabs(sdf.origin.y + 0.3) < 1e-12 &&
                fabs(sdf.origin.z + 0.3) < 1e-12);
    assert_true(sdf.dx == dx);

    /* The contract allows one voxel of error; OpenVDB computes exact point-triangle distances in
     * float, so the measured error is far smaller and dx is a loose bound. */
    float centre = sdf_at(&sdf, 0.5, 0.5, 0.5);
    assert_true(fabs(centre + 0.5) < dx);
    float outside = sdf_at(&sdf, 1.2, 0.5, 0.5);
    assert_true(fabs(outside - 0.2) < dx);
    print_message("cube sdf: centre %.6f (exact -0.5), 0.2 outside %.6f\n", centre, outside);

    /* Every node: the sign agrees with the analytic box except within one voxel of the surface;
     * inside and within the exterior band (max(3, pad+1) = 7 voxels) the value is the distance;
     * beyond the band it is clamped to +band. */
    const double band = 7 * dx;
    long sign_bad = 0, near = 0;
    double max_err = 0.0;
    for (int k = 0; k < sdf.nz; k++)
        for (int j = 0; j < sdf.ny; j++)
            for (int i = 0; i < sdf.nx; i++) {
                double x = sdf.origin.x + dx * i, y = sdf.origin.y + dx * j, z = sdf.origin.z + dx * k;
                double exact = box_sdf(x, y, z);
                float phi = sdf.phi[i + (size_t)sdf.nx * (j + (size_t)sdf.ny * k)];
                assert_true(isfinite(phi));
                if ((phi < 0) != (exact < 0)) {
                    if (fabs(exact) <= dx) near++;
                    else sign_bad++;
                }
                if (exact < band - dx) {
                    double e = fabs(phi - exact);
                    if (e > max_err) max_err = e;
                } else if (exact > band + dx) {
                    assert_true(fabs(phi - band) < 1e-6);
                }
            }
    print_message("cube sdf: %ld sign mismatches away from the surface, %ld within a voxel, "
                  "max |phi - exact| %.2e m (dx %.2f)\n",
                  sign_bad, near, max_err, dx);
    assert_int_equal(sign_bad, 0);
    /* Distances inside the band: within 1% of a voxel (float rounding of exact distances). */
    assert_true(max_err < 0.01 * dx);

    dr_dense_sdf_free(&sdf);
    assert_null(sdf.phi);
    dr_dense_sdf_free(&sdf);
    dr_trimesh_free(&cube);
}

static void test_sdf_bad_input(void **state)
{
    (void)state;
    DrTriMesh empty = {0};
    DrDenseSdf sdf = {0};
    DrError err;
    assert_int_equal(dr_vdb_mesh_to_sdf(&empty, 0.05, 2, &sdf, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "empty"));
    assert_null(sdf.phi);

    DrTriMesh cube = unit_cube();
    assert_int_equal(dr_vdb_mesh_to_sdf(&cube, 0.0, 2, &sdf, &err), DR_ERR_INPUT);
    assert_int_equal(dr_vdb_mesh_to_sdf(&cube, NAN, 2, &sdf, &err), DR_ERR_INPUT);
    assert_int_equal(dr_vdb_mesh_to_sdf(&cube, 0.05, -1, &sdf, &err), DR_ERR_INPUT);
    /* 1 m at 1.5 mm is 668 nodes per axis, beyond 512^3 in total. */
    assert_int_equal(dr_vdb_mesh_to_sdf(&cube, 0.0015, 2, &sdf, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "use a larger voxel size"));
    assert_null(sdf.phi);

    cube.tri[5] = 8; /* index out of range */
    assert_int_equal(dr_vdb_mesh_to_sdf(&cube, 0.05, 2, &sdf, &err), DR_ERR_INPUT);
    cube.tri[5] = 2;
    cube.v[4] = INFINITY;
    assert_int_equal(dr_vdb_mesh_to_sdf(&cube, 0.05, 2, &sdf, &err), DR_ERR_INPUT);
    assert_null(sdf.phi);
    dr_trimesh_free(&cube);
}

typedef struct OpenCubeCtx { DrTriMesh mesh; DrDenseSdf sdf; DrStatus st; } OpenCubeCtx;

static void run_open_cube(void *ctx)
{
    OpenCubeCtx *c = ctx;
    DrError err;
    c->st = dr_vdb_mesh_to_sdf(&c->mesh, 0.05, 3, &c->sdf, &err);
}

/* Sign mismatches against the box farther than one voxel from its surface. */
static long far_sign_mismatches(const DrDenseSdf *sdf)
{
    long bad = 0;
    for (int k = 0; k < sdf->nz; k++)
        for (int j = 0; j < sdf->ny; j++)
            for (int i = 0; i < sdf->nx; i++) {
                double e = box_sdf(sdf->origin.x + sdf->dx * i, sdf->origin.y + sdf->dx * j,
                                   sdf->origin.z + sdf->dx * k);
                float phi = sdf->phi[i + (size_t)sdf->nx * (j + (size_t)sdf->ny * k)];
                if (!isfinite(phi)) bad++;
                else if ((phi < 0) != (e < 0) && fabs(e) > sdf->dx) bad++;
            }
    return bad;
}

static void test_open_mesh_warns(void **state)
{
    (void)state;
    char log[4096];
    DrLogLevel saved = dr_log_level();
    dr_log_set_level(DR_LOG_WARN);

    /* An unwelded seam: the +x face uses a copy of vertex 6, so edges 2-6, 5-6 (other faces) and
     * 2-8, 8-5 (+x face) are open (4 edges) although the surface is geometrically closed: warning,
     * and the sign is still right everywhere. */
    OpenCubeCtx c = {0};
    c.mesh = unit_cube();
    c.mesh.v = realloc(c.mesh.v, 27 * sizeof(double));
    assert_non_null(c.mesh.v);
    memcpy(c.mesh.v + 24, c.mesh.v + 18, 3 * sizeof(double));
    c.mesh.nv = 9;
    for (int q = 30; q < 36; q++)
        if (c.mesh.tri[q] == 6) c.mesh.tri[q] = 8;
    capture_stderr(run_open_cube, &c, log, sizeof log);
    assert_int_equal(c.st, DR_OK);
    assert_non_null(strstr(log, "warning"));
    assert_non_null(strstr(log, "4 open edges"));
    assert_int_equal(far_sign_mismatches(&c.sdf), 0);
    dr_dense_sdf_free(&c.sdf);
    dr_trimesh_free(&c.mesh);

    /* A real hole (one triangle of the +x face missing, 3 open edges): still a finite field and a
     * warning; the sign behind the hole is not promised. */
    c.mesh = unit_cube();
    c.mesh.nt = 11;
    capture_stderr(run_open_cube, &c, log, sizeof log);
    assert_int_equal(c.st, DR_OK);
    assert_non_null(strstr(log, "3 open edges"));
    for (long q = 0; q < (long)c.sdf.nx * c.sdf.ny * c.sdf.nz; q++) assert_true(isfinite(c.sdf.phi[q]));
    dr_dense_sdf_free(&c.sdf);
    dr_trimesh_free(&c.mesh);

    /* A closed mesh logs nothing. */
    c.mesh = unit_cube();
    capture_stderr(run_open_cube, &c, log, sizeof log);
    assert_int_equal(c.st, DR_OK);
    assert_null(strstr(log, "open edges"));
    dr_dense_sdf_free(&c.sdf);
    dr_trimesh_free(&c.mesh);
    dr_log_set_level(saved);
}

/* ---- liquid surface ------------------------------------------------------------------------- */

#define SPH_R 0.25
#define SPH_H (SPH_R / 12.0)

/* Particles on a lattice of spacing h, jittered by up to ±h/4 per axis, kept where the distance to
 * the centre is below R - (r - h/2) (see test_sphere_surface for why). vel = A p (m/s) with a
 * fixed non-symmetric A, so every particle's velocity is distinct. */
static long sphere_particles(double r, double **pos_out, double **vel_out)
{
    const int m = 14; /* lattice half-extent: 14 h > R */
    const long cap = (long)(2 * m + 1) * (2 * m + 1) * (2 * m + 1);
    double *pos = malloc(3 * (size_t)cap * sizeof *pos), *vel = malloc(3 * (size_t)cap * sizeof *vel);
    assert_non_null(pos);
    assert_non_null(vel);
    DrRng rng;
    dr_rng_seed(&rng, 2024);
    const double keep = SPH_R - (r - 0.5 * SPH_H);
    long n = 0;
    for (int k = -m; k <= m; k++)
        for (int j = -m; j <= m; j++)
            for (int i = -m; i <= m; i++) {
                double p[3] = {(i + 0.5) * SPH_H, (j + 0.5) * SPH_H, (k + 0.5) * SPH_H};
                for (int a = 0; a < 3; a++) p[a] += 0.25 * SPH_H * (2.0 * dr_rng_uniform(&rng) - 1.0);
                if (sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) >= keep) continue;
                memcpy(pos + 3 * n, p, sizeof p);
                vel[3 * n] = 1.0 * p[0] + 2.0 * p[1];
                vel[3 * n + 1] = -3.0 * p[0] + 0.5 * p[2];
                vel[3 * n + 2] = 4.0 * p[1] - 1.5 * p[2] + 0.1;
                n++;
            }
    *pos_out = pos;
    *vel_out = vel;
    return n;
}

static void test_sphere_surface(void **state)
{
    (void)state;
    /* Volume-consistent seeding. A particle stands for the cube of side h around it, so the liquid
     * the particles represent ends h/2 beyond the outermost centres, while a union of spheres of
     * radius r ends r beyond them (less a small dip between neighbours). ParticlesToLevelSet needs
     * r >= 1.5 voxels = 1.5 h here, so r = 1.5 h and the lattice is filled to R - (r - h/2) = R - h:
     * then both boundaries sit at R, and the surface encloses 4/3 pi R^3. */
    const double r = 1.5 * SPH_H;
    double *pos, *vel;
    long n = sphere_particles(r, &pos, &vel);
    DrVdbSurfaceDesc d = dr_vdb_surface_desc_default();
    d.voxel_size = SPH_H;
    d.radius = r;
    d.smoothing = 1;
    d.adaptivity = 0.0;
    DrVdbSurface *s = NULL;
    DrError err;
    double t0 = dr_time_now();
    assert_int_equal(dr_vdb_surface_from_particles(pos, vel, n, &d, &s, &err), DR_OK);
    double t1 = dr_time_now();
    assert_non_null(s);
    assert_true(fabs(dr_vdb_surface_voxel_size(s) - SPH_H) < 1e-15);
    assert_true(dr_vdb_surface_active_voxels(s) > 0);

    /* 3 % in volume is 1 % in radius = 0.12 voxel: the sampling error of the jittered lattice
     * boundary and of one smoothing pass (mean-curvature flow shrinks a sphere by ~dx/R^2 per
     * pass) are both below that; the mesh, inscribed in the curved surface, loses ~1 % more. */
    const double exact = 4.0 / 3.0 * DR_PI * SPH_R * SPH_R * SPH_R;
    double vls = dr_vdb_surface_volume(s);
    DrTriMesh mesh = {0};
    assert_int_equal(dr_vdb_surface_to_mesh(s, &mesh, &err), DR_OK);
    double t2 = dr_time_now();
    double vmesh = dr_trimesh_volume(&mesh);
    print_message("sphere: %ld particles, level-set volume %.4f x exact, mesh volume %.4f x exact, "
                  "%d vertices, %d triangles, surface %.2fs, mesh %.2fs\n",
                  n, vls / exact, vmesh / exact, mesh.nv, mesh.nt, t1 - t0, t2 - t1);
    assert_true(fabs(vls / exact - 1.0) < 0.03);
    assert_true(fabs(vmesh / exact - 1.0) < 0.03);
    assert_true(vmesh > 0.0); /* counter-clockwise seen from outside */
    assert_true(dr_trimesh_is_closed(&mesh));

    /* Normals: unit length, outward, and every vertex within a voxel of the sphere. */
    assert_non_null(mesh.n);
    int outward = 0;
    for (int i = 0; i < mesh.nv; i++) {
        DrVec3 p = dr_v3(mesh.v[3 * i], mesh.v[3 * i + 1], mesh.v[3 * i + 2]);
        DrVec3 nn = dr_v3(mesh.n[3 * i], mesh.n[3 * i + 1], mesh.n[3 * i + 2]);
        assert_true(fabs(dr_v3_norm(nn) - 1.0) < 1e-9);
        assert_true(fabs(dr_v3_norm(p) - SPH_R) < SPH_H);
        if (dr_v3_dot(nn, p) > 0.0) outward++;
    }
    print_message("sphere: %d of %d normals outward\n", outward, mesh.nv);
    assert_true(outward > 0.99 * mesh.nv);

    /* Velocity: at the voxel nearest each mesh vertex (in the band), "vel" is the velocity of the
     * particle closest to that voxel's centre, found by brute force; float storage -> 1e-6. */
    int checked = 0, match = 0;
    for (int i = 0; i < mesh.nv; i += 7) {
        double c[3];
        for (int a = 0; a < 3; a++) c[a] = SPH_H * round(mesh.v[3 * i + a] / SPH_H);
        long best = -1;
        double bd = 1e300;
        for (long q = 0; q < n; q++) {
            double dxp = pos[3 * q] - c[0], dyp = pos[3 * q + 1] - c[1], dzp = pos[3 * q + 2] - c[2];
            double d2 = dxp * dxp + dyp * dyp + dzp * dzp;
            if (d2 < bd) { bd = d2; best = q; }
        }
        DrVec3 v = dr_vdb_surface_velocity_at(s, dr_v3(c[0], c[1], c[2]));
        checked++;
        if (fabs(v.x - vel[3 * best]) < 1e-6 && fabs(v.y - vel[3 * best + 1]) < 1e-6 &&
            fabs(v.z - vel[3 * best + 2]) < 1e-6)
            match++;
    }
    print_message("sphere: velocity of the closest particle at %d of %d band voxels\n", match, checked);
    assert_int_equal(match, checked);

    const int mesh_nt = mesh.nt;
    dr_trimesh_free(&mesh);
    dr_vdb_surface_destroy(&s);
    assert_null(s);
    dr_vdb_surface_destroy(&s);

    /* Without velocities the grid holds zeros. A radius below 1.5 voxels is rasterised at 1.5 voxels
     * and eroded back, so r = h puts the surface h/2 inside the r = 1.5 h one: a sphere of radius
     * R − h/2. Same 3 % bound as above (voxel-scale discretisation). */
    d.radius = SPH_H;
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, n, &d, &s, &err), DR_OK);
    const double eroded = 4.0 / 3.0 * DR_PI * pow(SPH_R - 0.5 * SPH_H, 3);
    print_message("sphere: r = h gives volume %.6g, sphere of R - h/2 has %.6g\n", dr_vdb_surface_volume(s), eroded);
    assert_true(fabs(dr_vdb_surface_volume(s) / eroded - 1.0) < 0.03);
    assert_true(dr_vdb_surface_volume(s) < vls);
    DrVec3 v0 = dr_vdb_surface_velocity_at(s, dr_v3(SPH_R, 0, 0));
    assert_true(v0.x == 0.0 && v0.y == 0.0 && v0.z == 0.0);
    dr_vdb_surface_destroy(&s);

    /* Adaptive meshing (adaptivity 0.05): far fewer triangles, still closed and outward. Merged
     * polygons are flat chords of the sphere, so the volume drops a little more than the uniform
     * mesh's (~2 % measured at this resolution); 3 % still bounds it. Larger adaptivities merge
     * much more on a sphere only 12 voxels in radius (0.5 loses ~17 %), so they are not bounded. */
    d.radius = r;
    d.adaptivity = 0.05;
    assert_int_equal(dr_vdb_surface_from_particles(pos, vel, n, &d, &s, &err), DR_OK);
    DrTriMesh amesh = {0};
    assert_int_equal(dr_vdb_surface_to_mesh(s, &amesh, &err), DR_OK);
    print_message("sphere: adaptivity 0.05: %d triangles, volume %.4f x exact, closed %d\n", amesh.nt,
                  dr_trimesh_volume(&amesh) / exact, dr_trimesh_is_closed(&amesh));
    assert_true(amesh.nt > 0 && amesh.nt < mesh_nt / 2);
    assert_true(dr_trimesh_is_closed(&amesh));
    assert_true(fabs(dr_trimesh_volume(&amesh) / exact - 1.0) < 0.03);
    dr_trimesh_free(&amesh);
    dr_vdb_surface_destroy(&s);

    free(pos);
    free(vel);
}

/* ---- files ---------------------------------------------------------------------------------- */

static void test_write_and_read_back(void **state)
{
    (void)state;
    double *pos, *vel;
    long n = sphere_particles(1.5 * SPH_H, &pos, &vel);
    DrVdbSurfaceDesc d = dr_vdb_surface_desc_default();
    d.voxel_size = SPH_H;
    d.radius = 1.5 * SPH_H;
    DrVdbSurface *s = NULL;
    DrError err;
    assert_int_equal(dr_vdb_surface_from_particles(pos, vel, n, &d, &s, &err), DR_OK);

    char dir[DIR_LEN], path[DIR_LEN + 88];
    make_dir(dir);
    snprintf(path, sizeof path, "%s/liquid.0012.vdb", dir);
    DrVdbMeta meta = {12, 24.0, "0123456789abcdef0123456789abcdef"};
    assert_int_equal(dr_vdb_surface_write(s, path, &meta, &err), DR_OK);
    assert_int_equal(count_files(dir), 1); /* no temporary left behind */

    char names[64], value[128];
    assert_int_equal(dr_vdb_file_info(path, names, sizeof names, &err), DR_OK);
    assert_string_equal(names, "surface,vel");
    assert_int_equal(dr_vdb_file_meta(path, "creator", value, sizeof value, &err), DR_OK);
    assert_string_equal(value, "drench " DR_VERSION);
    assert_int_equal(dr_vdb_file_meta(path, "frame", value, sizeof value, &err), DR_OK);
    assert_string_equal(value, "12");
    assert_int_equal(dr_vdb_file_meta(path, "fps", value, sizeof value, &err), DR_OK);
    assert_true(fabs(atof(value) - 24.0) < 1e-12);
    assert_int_equal(dr_vdb_file_meta(path, "units", value, sizeof value, &err), DR_OK);
    assert_string_equal(value, "m");
    assert_int_equal(dr_vdb_file_meta(path, "up_axis", value, sizeof value, &err), DR_OK);
    assert_string_equal(value, "y");
    assert_int_equal(dr_vdb_file_meta(path, "bake_key", value, sizeof value, &err), DR_OK);
    assert_string_equal(value, meta.bake_key);
    assert_int_equal(dr_vdb_file_meta(path, "no_such_key", value, sizeof value, &err), DR_ERR_INPUT);
    assert_int_equal(dr_vdb_file_info(path, names, 5, &err), DR_ERR_INPUT); /* buffer too small */

    /* Rewriting replaces the file in place. */
    meta.frame = 13;
    assert_int_equal(dr_vdb_surface_write(s, path, &meta, &err), DR_OK);
    assert_int_equal(dr_vdb_file_meta(path, "frame", value, sizeof value, &err), DR_OK);
    assert_string_equal(value, "13");
    assert_int_equal(count_files(dir), 1);

    /* Debian's vdb_print (libopenvdb-tools), an independent reader, when installed. */
    if (system("command -v vdb_print >/dev/null 2>&1") == 0) {
        char cmd[700], out[8192];
        snprintf(cmd, sizeof cmd, "vdb_print -l -m '%s' 2>&1", path);
        FILE *p = popen(cmd, "r");
        assert_non_null(p);
        size_t got = fread(out, 1, sizeof out - 1, p);
        out[got] = '\0';
        assert_int_equal(pclose(p), 0);
        assert_non_null(strstr(out, "surface"));
        assert_non_null(strstr(out, "vel"));
        assert_non_null(strstr(out, "class: level set"));
        assert_non_null(strstr(out, "bake_key"));
    } else {
        print_message("vdb_print not installed: independent read-back skipped\n");
    }

    dr_vdb_surface_destroy(&s);
    rm_dir(dir);
    free(pos);
    free(vel);
}

static void test_zero_particles(void **state)
{
    (void)state;
    DrVdbSurfaceDesc d = dr_vdb_surface_desc_default();
    DrVdbSurface *s = NULL;
    DrError err;
    assert_int_equal(dr_vdb_surface_from_particles(NULL, NULL, 0, &d, &s, &err), DR_OK);
    assert_non_null(s);
    assert_true(dr_vdb_surface_volume(s) == 0.0);
    assert_int_equal(dr_vdb_surface_active_voxels(s), 0);
    DrTriMesh mesh = {0};
    assert_int_equal(dr_vdb_surface_to_mesh(s, &mesh, &err), DR_OK);
    assert_int_equal(mesh.nv, 0);
    assert_int_equal(mesh.nt, 0);
    assert_null(mesh.v);
    assert_null(mesh.tri);

    char dir[DIR_LEN], path[DIR_LEN + 88], names[64];
    make_dir(dir);
    snprintf(path, sizeof path, "%s/liquid.0001.vdb", dir);
    DrVdbMeta meta = {1, 24.0, NULL};
    assert_int_equal(dr_vdb_surface_write(s, path, &meta, &err), DR_OK);
    assert_int_equal(dr_vdb_file_info(path, names, sizeof names, &err), DR_OK);
    assert_string_equal(names, "surface,vel");
    char value[16];
    assert_int_equal(dr_vdb_file_meta(path, "bake_key", value, sizeof value, &err), DR_OK);
    assert_string_equal(value, "");
    dr_vdb_surface_destroy(&s);
    rm_dir(dir);
}

/* Bad arguments and OpenVDB's own exceptions come back as statuses, never as a crash. */
static void test_errors_not_crashes(void **state)
{
    (void)state;
    double pos[6] = {0, 0, 0, 0.01, 0, 0};
    DrVdbSurfaceDesc d = dr_vdb_surface_desc_default();
    DrVdbSurface *s = (DrVdbSurface *)&d; /* must be reset to NULL on failure */
    DrError err;

    d.voxel_size = 0.0;
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    assert_null(s);
    assert_non_null(strstr(err.message, "voxel_size"));
    d = dr_vdb_surface_desc_default();
    d.radius = -1.0;
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    d = dr_vdb_surface_desc_default();
    d.adaptivity = 1.5;
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    d = dr_vdb_surface_desc_default();
    d.smoothing = -1;
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    d = dr_vdb_surface_desc_default();
    d.radius = 1.0; /* 250 voxels */
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    d = dr_vdb_surface_desc_default();
    assert_int_equal(dr_vdb_surface_from_particles(NULL, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, -1, &d, &s, &err), DR_ERR_INPUT);
    pos[4] = NAN;
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    pos[4] = 1e30; /* beyond 2^30 voxels */
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_ERR_INPUT);
    assert_null(s);

    /* OpenVDB throws IoError for these; it must arrive as DR_ERR_IO naming the path. */
    char names[64];
    assert_int_equal(dr_vdb_file_info("/nonexistent/drench/x.vdb", names, sizeof names, &err), DR_ERR_IO);
    assert_non_null(strstr(err.message, "/nonexistent/drench/x.vdb"));

    char dir[DIR_LEN], path[DIR_LEN + 88];
    make_dir(dir);
    snprintf(path, sizeof path, "%s/not_a.vdb", dir);
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs("this is not a vdb file\n", f);
    fclose(f);
    assert_int_equal(dr_vdb_file_info(path, names, sizeof names, &err), DR_ERR_IO);
    assert_int_equal(dr_vdb_file_meta(path, "creator", names, sizeof names, &err), DR_ERR_IO);

    pos[4] = 0.0;
    assert_int_equal(dr_vdb_surface_from_particles(pos, NULL, 2, &d, &s, &err), DR_OK);
    DrVdbMeta meta = {1, 24.0, "k"};
    snprintf(path, sizeof path, "%s/missing_dir/liquid.0001.vdb", dir);
    assert_int_equal(dr_vdb_surface_write(s, path, &meta, &err), DR_ERR_IO);
    assert_non_null(strstr(err.message, path));
    assert_string_equal(err.file, path);
    assert_int_equal(count_files(dir), 1); /* only not_a.vdb: nothing half-written */
    dr_vdb_surface_destroy(&s);
    rm_dir(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_init_idempotent),
        cmocka_unit_test(test_cube_sdf),
        cmocka_unit_test(test_sdf_bad_input),
        cmocka_unit_test(test_open_mesh_warns),
        cmocka_unit_test(test_sphere_surface),
        cmocka_unit_test(test_write_and_read_back),
        cmocka_unit_test(test_zero_particles),
        cmocka_unit_test(test_errors_not_crashes),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
