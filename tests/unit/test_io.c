/* Unit tests of src/io: asset loading, OBJ writing, atomic files, manifests, HDF5 caches and the
 * precompute cache. Run from the repository root (assets/meshes/ is read relative to it). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "core/core.h"
#include "io/io.h"

#include <hdf5.h>
#include <math.h>

#include <dirent.h>
#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define MESHES "assets/meshes/"

static char g_dir[256]; /* scratch directory of this run */

static void scratch_path(const char *name, char *buf, size_t size)
{
    snprintf(buf, size, "%s/%s", g_dir, name);
}

static int group_setup(void **state)
{
    (void)state;
    if (!dr_io_exists(MESHES "cube.obj")) {
        fprintf(stderr, "test_io: %scube.obj not found; run from the repository root\n", MESHES);
        return -1;
    }
    snprintf(g_dir, sizeof g_dir, "%s/drench_test_io.XXXXXX", dr_temp_dir());
    return mkdtemp(g_dir) ? 0 : -1;
}

static int group_teardown(void **state)
{
    (void)state;
    char cmd[512];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    return system(cmd) == 0 ? 0 : -1;
}

/* Number of directory entries whose name contains ".tmp.". */
static int count_tmp_files(const char *dir)
{
    DIR *d = opendir(dir);
    assert_non_null(d);
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) n += strstr(e->d_name, ".tmp.") != NULL;
    closedir(d);
    return n;
}

static char *slurp(const char *path)
{
    char *text = NULL;
    DrError err;
    assert_int_equal(dr_io_read_text(path, &text, &err), DR_OK);
    return text;
}

/* ---- assets ---- */

static void check_unit_cube(const char *path, bool expect_normals)
{
    DrTriMesh m;
    DrError err;
    assert_int_equal(dr_io_load_mesh(path, &m, &err), DR_OK);
    assert_int_equal(m.nv, 8);
    assert_int_equal(m.nt, 12);
    /* Corners ±0.5 are exact in float and double, so the divergence-theorem volume is exact up to
     * the rounding of twelve triple products of magnitude 1/8: 1e-12 leaves a wide margin. */
    assert_true(fabs(dr_trimesh_volume(&m) - 1.0) < 1e-12);
    assert_true(dr_trimesh_is_closed(&m));
    DrVec3 lo, hi;
    assert_true(dr_trimesh_bounds(&m, &lo, &hi));
    assert_true(lo.x == -0.5 && lo.y == -0.5 && lo.z == -0.5 && hi.x == 0.5 && hi.y == 0.5 && hi.z == 0.5);
    if (expect_normals) {
        assert_non_null(m.n);
        /* STL face normals joined at a corner average to the outward diagonal (±1, ±1, ±1)/√3. */
        for (int i = 0; i < m.nv; i++) {
            DrVec3 n = dr_v3(m.n[3 * i], m.n[3 * i + 1], m.n[3 * i + 2]);
            DrVec3 p = dr_v3(m.v[3 * i], m.v[3 * i + 1], m.v[3 * i + 2]);
            assert_true(fabs(dr_v3_norm(n) - 1.0) < 1e-12);
            assert_true(fabs(dr_v3_dot(n, dr_v3_normalize(p)) - 1.0) < 1e-12);
        }
    } else {
        assert_null(m.n);
    }
    dr_trimesh_free(&m);
    assert_null(m.v);
}

static void test_load_cube_formats(void **state)
{
    (void)state;
    check_unit_cube(MESHES "cube.obj", false);
    check_unit_cube(MESHES "cube.ply", false);
    check_unit_cube(MESHES "cube.stl", true);
}

static void test_load_sphere_and_ground(void **state)
{
    (void)state;
    DrTriMesh m;
    DrError err;
    assert_int_equal(dr_io_load_mesh(MESHES "sphere.obj", &m, &err), DR_OK);
    assert_int_equal(m.nv, 642);
    assert_int_equal(m.nt, 1280);
    assert_true(dr_trimesh_is_closed(&m));
    double vol = dr_trimesh_volume(&m);
    double sphere = 4.0 / 3.0 * DR_PI * 0.125;
    /* An icosphere of 3 subdivisions is inscribed in the sphere: its volume is below 4/3 π r³ by
     * 0.861% (computed exactly from the generated vertices, 0.519092602137 m³). Bounds: the deficit
     * is positive and under 1%; and against the exact polyhedron, assimp keeps positions in single
     * precision (relative rounding 6e-8 per coordinate, about 3 times that on a volume): 1e-6. */
    assert_true(vol < sphere && (sphere - vol) / sphere < 0.01);
    assert_true(fabs(vol - 0.519092602137) / 0.519092602137 < 1e-6);
    for (int i = 0; i < m.nv; i++) {
        double r = sqrt(m.v[3 * i] * m.v[3 * i] + m.v[3 * i + 1] * m.v[3 * i + 1] + m.v[3 * i + 2] * m.v[3 * i + 2]);
        assert_true(fabs(r - 0.5) < 1e-6); /* float rounding of the coordinates, as above */
    }
    dr_trimesh_free(&m);

    assert_int_equal(dr_io_load_mesh(MESHES "ground.obj", &m, &err), DR_OK);
    assert_int_equal(m.nv, 8);
    assert_int_equal(m.nt, 12);
    assert_true(dr_trimesh_is_closed(&m));
    DrVec3 lo, hi;
    assert_true(dr_trimesh_bounds(&m, &lo, &hi));
    assert_true(hi.y == 0.0 && lo.x == -2.0 && hi.x == 2.0 && lo.z == -2.0 && hi.z == 2.0);
    assert_true(fabs(lo.y + 0.1) < 1e-8); /* -0.1 rounded to float: error 1.5e-9 */
    assert_true(fabs(dr_trimesh_volume(&m) - 1.6) < 1e-6);
    dr_trimesh_free(&m);
}

/* Loads path with stdout and stderr redirected to a file; returns the status and the number of
 * bytes the loader printed. */
static DrStatus load_quietly(const char *path, DrTriMesh *m, DrError *err, long *printed)
{
    char capture[512];
    scratch_path("captured_output", capture, sizeof capture);
    fflush(stdout);
    fflush(stderr);
    int fd = open(capture, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    assert_true(fd >= 0);
    int saved_out = dup(1), saved_err = dup(2);
    dup2(fd, 1);
    dup2(fd, 2);
    DrStatus s = dr_io_load_mesh(path, m, err);
    fflush(stdout);
    fflush(stderr);
    dup2(saved_out, 1);
    dup2(saved_err, 2);
    close(saved_out);
    close(saved_err);
    close(fd);
    struct stat st;
    assert_int_equal(stat(capture, &st), 0);
    *printed = (long)st.st_size;
    return s;
}

static void expect_bad_mesh(const char *path, const char *needle)
{
    DrTriMesh m;
    DrError err;
    dr_error_clear(&err);
    long printed = -1;
    DrStatus s = load_quietly(path, &m, &err, &printed);
    assert_int_equal(s, DR_ERR_INPUT);
    assert_int_equal(err.status, DR_ERR_INPUT);
    assert_string_equal(err.file, path);
    if (!strstr(err.message, needle)) fail_msg("message for %s: \"%s\" lacks \"%s\"", path, err.message, needle);
    assert_int_equal(printed, 0);
    assert_null(m.v);
    assert_null(m.tri);
    assert_int_equal(m.nt, 0);
}

static void test_load_bad_meshes(void **state)
{
    (void)state;
    expect_bad_mesh(MESHES "empty.obj", "mesh is empty: no triangles; export faces");
    expect_bad_mesh(MESHES "nan.obj", "non-finite coordinate");
    expect_bad_mesh(MESHES "broken.obj", "not a text OBJ file");
    expect_bad_mesh(MESHES "does_not_exist.obj", "No such file");
    expect_bad_mesh("assets/meshes", "is a directory");
    char path[512];
    scratch_path("not_a_mesh.xyz", path, sizeof path);
    assert_int_equal(dr_io_write_text_atomic(path, "hello\n", NULL), DR_OK);
    expect_bad_mesh(path, "assimp");
    /* A good load prints nothing either. */
    DrTriMesh m;
    DrError err;
    long printed = -1;
    assert_int_equal(load_quietly(MESHES "cube.ply", &m, &err, &printed), DR_OK);
    assert_int_equal(printed, 0);
    dr_trimesh_free(&m);
}

/* Texture coordinates: per triangle corner, so that a seam (one position, two coordinates) keeps the surface welded;
   the cloth panel's are u = x + 0.5, v = z + 0.5 of its 33 × 33 rest grid. Written as "vt" per corner and "f a/t/n",
   read back the same. */
static void test_texture_coordinates(void **state)
{
    (void)state;
    DrTriMesh a, b;
    DrError err;
    assert_int_equal(dr_io_load_mesh(MESHES "cloth_panel.obj", &a, &err), DR_OK);
    assert_int_equal(a.nv, 33 * 33);
    assert_int_equal(a.nt, 2 * 32 * 32);
    assert_non_null(a.uv);
    for (int t = 0; t < a.nt; t++)
        for (int c = 0; c < 3; c++) {
            const double *p = a.v + 3 * a.tri[3 * t + c], *uv = a.uv + 6 * t + 2 * c;
            assert_true(fabs(uv[0] - (p[0] + 0.5)) < 1e-6 && fabs(uv[1] - (p[2] + 0.5)) < 1e-6);
        }
    /* a seam: two triangles sharing an edge whose corners carry different coordinates stay joined */
    char path[512];
    scratch_path("seam.obj", path, sizeof path);
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\nvt 0.9 0.1\nvt 0.1 0.9\n"
          "f 1/1 2/2 3/3\nf 2/5 4/4 3/6\n", f);
    fclose(f);
    assert_int_equal(dr_io_load_mesh(path, &b, &err), DR_OK);
    assert_int_equal(b.nv, 4);
    assert_int_equal(b.nt, 2);
    assert_non_null(b.uv);
    assert_true(fabs(b.uv[6] - 0.9) < 1e-6 && fabs(b.uv[7] - 0.1) < 1e-6);
    dr_trimesh_free(&b);
    scratch_path("panel_out.obj", path, sizeof path);
    assert_int_equal(dr_io_write_obj(path, &a, NULL, &err), DR_OK);
    char *text = slurp(path);
    assert_non_null(strstr(text, "\nvt "));
    free(text);
    assert_int_equal(dr_io_load_mesh(path, &b, &err), DR_OK);
    assert_int_equal(b.nt, a.nt);
    assert_memory_equal(a.tri, b.tri, 3 * sizeof(int) * (size_t)a.nt);
    assert_memory_equal(a.uv, b.uv, 6 * sizeof(double) * (size_t)a.nt);
    dr_trimesh_free(&a);
    dr_trimesh_free(&b);
}

static void test_write_obj_round_trip(void **state)
{
    (void)state;
    DrTriMesh a, b;
    DrError err;
    char path[512];
    scratch_path("sphere_out.obj", path, sizeof path);
    assert_int_equal(dr_io_load_mesh(MESHES "sphere.obj", &a, &err), DR_OK);
    assert_int_equal(dr_io_write_obj(path, &a, "written by test_io\nsecond line", &err), DR_OK);
    assert_int_equal(count_tmp_files(g_dir), 0);
    char *text = slurp(path);
    const char *head = "# written by test_io\n# second line\nv ";
    assert_true(strncmp(text, head, strlen(head)) == 0);
    assert_null(strstr(text, "vn "));
    free(text);
    assert_int_equal(dr_io_load_mesh(path, &b, &err), DR_OK);
    assert_int_equal(a.nv, b.nv);
    assert_int_equal(a.nt, b.nt);
    /* Loaded coordinates are floats and %.9g prints every float exactly, and the loader orders
     * vertices by first use, which the writer preserves: the reload is bit-identical. */
    assert_memory_equal(a.tri, b.tri, 3 * sizeof(int) * (size_t)a.nt);
    assert_memory_equal(a.v, b.v, 3 * sizeof(double) * (size_t)a.nv);
    assert_true(dr_trimesh_volume(&a) == dr_trimesh_volume(&b));
    dr_trimesh_free(&a);
    dr_trimesh_free(&b);

    /* With normals: "vn" lines and "f a//a ..." faces, read back as normals. */
    scratch_path("cube_out.obj", path, sizeof path);
    assert_int_equal(dr_io_load_mesh(MESHES "cube.stl", &a, &err), DR_OK);
    assert_int_equal(dr_io_write_obj(path, &a, NULL, &err), DR_OK);
    text = slurp(path);
    assert_true(strncmp(text, "v ", 2) == 0);
    assert_non_null(strstr(text, "\nvn "));
    assert_non_null(strstr(text, "\nf 1//1 2//2 3//3\n"));
    free(text);
    assert_int_equal(dr_io_load_mesh(path, &b, &err), DR_OK);
    assert_int_equal(b.nv, 8);
    assert_int_equal(b.nt, 12);
    assert_non_null(b.n);
    assert_true(fabs(dr_trimesh_volume(&b) - 1.0) < 1e-12);
    /* Normals printed with 9 digits: 1e-8 covers the rounding of a unit vector. */
    for (int i = 0; i < 3 * a.nv; i++) assert_true(fabs(a.n[i] - b.n[i]) < 1e-8);
    dr_trimesh_free(&b);

    /* Zero normals in the file fall back to the adjacent faces' normals: unit length, outward. */
    scratch_path("zero_normals.obj", path, sizeof path);
    {
        char body[2048];
        size_t len = (size_t)snprintf(body, sizeof body, "vn 0 0 0\n");
        for (int i = 0; i < a.nv; i++)
            len += (size_t)snprintf(body + len, sizeof body - len, "v %g %g %g\n", a.v[3 * i], a.v[3 * i + 1],
                                    a.v[3 * i + 2]);
        for (int t = 0; t < a.nt; t++)
            len += (size_t)snprintf(body + len, sizeof body - len, "f %d//1 %d//1 %d//1\n", a.tri[3 * t] + 1,
                                    a.tri[3 * t + 1] + 1, a.tri[3 * t + 2] + 1);
        assert_true(len < sizeof body);
        assert_int_equal(dr_io_write_text_atomic(path, body, &err), DR_OK);
    }
    assert_int_equal(dr_io_load_mesh(path, &b, &err), DR_OK);
    assert_int_equal(b.nv, 8);
    assert_non_null(b.n);
    for (int i = 0; i < b.nv; i++) {
        DrVec3 n = dr_v3(b.n[3 * i], b.n[3 * i + 1], b.n[3 * i + 2]);
        DrVec3 p = dr_v3(b.v[3 * i], b.v[3 * i + 1], b.v[3 * i + 2]);
        assert_true(fabs(dr_v3_norm(n) - 1.0) < 1e-12);
        /* Each corner touches three faces; their area-weighted sum points into the corner's octant. */
        assert_true(n.x * p.x > 0 && n.y * p.y > 0 && n.z * p.z > 0);
    }
    dr_trimesh_free(&b);

    /* A non-finite vertex is refused and nothing is written. */
    scratch_path("nan_out.obj", path, sizeof path);
    a.v[4] = NAN;
    dr_error_clear(&err);
    assert_int_equal(dr_io_write_obj(path, &a, NULL, &err), DR_ERR_RUNTIME);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "vertex 1 has a non-finite coordinate"));
    assert_false(dr_io_exists(path));
    assert_int_equal(count_tmp_files(g_dir), 0);
    dr_trimesh_free(&a);

    /* An empty mesh is a comment-only file. */
    DrTriMesh empty = {0};
    scratch_path("empty_out.obj", path, sizeof path);
    assert_int_equal(dr_io_write_obj(path, &empty, "nothing", &err), DR_OK);
    text = slurp(path);
    assert_string_equal(text, "# nothing\n");
    free(text);
}

/* ---- OBJ polylines ---- */

/* Writes `text` to the scratch file `name` and returns its path in buf. */
static void write_scratch(const char *name, const char *text, char *buf, size_t size)
{
    DrError err;
    scratch_path(name, buf, size);
    assert_int_equal(dr_io_write_text_atomic(buf, text, &err), DR_OK);
}

static void test_polylines_round_trip(void **state)
{
    (void)state;
    DrError err;
    char path[512];
    /* three strands: two of one radius, then one of another (one "# radius" line per change) */
    double x[3 * 7] = {0, 0, 0, 0, 0.01, 0, 0.001, 0.02, 0, 1, 0, 0, 1, 0.1, 0.003, 0.5, 0.25, 0.125, 0.5, -0.25, 1e-7};
    int off[4] = {0, 3, 5, 7};
    double r[3] = {5e-5, 5e-5, 2.5e-4};
    DrPolylines a = {3, off, x, r, NULL}, b;
    scratch_path("strands.obj", path, sizeof path);
    assert_int_equal(dr_io_write_polylines_obj(path, &a, "written by test_io\nsecond line", &err), DR_OK);
    assert_int_equal(count_tmp_files(g_dir), 0);
    char *text = slurp(path);
    const char *head = "# written by test_io\n# second line\nv ";
    assert_true(strncmp(text, head, strlen(head)) == 0);
    assert_non_null(strstr(text, "\n# radius 5e-05\nl 1 2 3\nl 4 5\n# radius 0.00025\nl 6 7\n"));
    free(text);
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &b, &err), DR_OK);
    assert_int_equal(b.count, 3);
    assert_memory_equal(b.offsets, off, sizeof off);
    /* %.9g keeps 9 significant digits: 1e-9 relative to each coordinate bounds the rounding */
    for (int i = 0; i < 21; i++) assert_true(fabs(b.x[i] - x[i]) <= 1e-9 * fabs(x[i]));
    for (int s = 0; s < 3; s++) assert_true(fabs(b.radius[s] - r[s]) <= 1e-9 * r[s]);
    dr_io_polylines_free(&b);
    assert_null(b.x);
    dr_io_polylines_free(&b); /* zeroed: a no-op */

    /* an empty set is a comment-only file and reads back empty */
    DrPolylines empty = {0};
    int off0[1] = {0};
    empty.offsets = off0;
    scratch_path("no_strands.obj", path, sizeof path);
    assert_int_equal(dr_io_write_polylines_obj(path, &empty, "nothing", &err), DR_OK);
    text = slurp(path);
    assert_string_equal(text, "# nothing\n");
    free(text);
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &b, &err), DR_OK);
    assert_int_equal(b.count, 0);
    dr_io_polylines_free(&b);

    /* non-finite data: DR_ERR_RUNTIME and nothing written */
    scratch_path("nan_strands.obj", path, sizeof path);
    x[4] = NAN;
    assert_int_equal(dr_io_write_polylines_obj(path, &a, NULL, &err), DR_ERR_RUNTIME);
    assert_non_null(strstr(err.message, "vertex 1 has a non-finite coordinate"));
    x[4] = 0.01;
    r[2] = -1;
    assert_int_equal(dr_io_write_polylines_obj(path, &a, NULL, &err), DR_ERR_RUNTIME);
    assert_non_null(strstr(err.message, "strand 2 has radius -1"));
    assert_false(dr_io_exists(path));
    assert_int_equal(count_tmp_files(g_dir), 0);

    /* a missing directory: DR_ERR_IO naming the file */
    r[2] = 2.5e-4;
    scratch_path("no/such/dir/strands.obj", path, sizeof path);
    assert_int_equal(dr_io_write_polylines_obj(path, &a, NULL, &err), DR_ERR_IO);
    assert_string_equal(err.file, path);
}

/* Files from other tools: negative and "a/b" indices, a forward reference, a radius that changes mid-file,
 * vertices shared by two strands, faces, normals, weights, colours, other comments and comments after a
 * record skipped, tabs, CRLF line ends. */
static void test_polylines_read_other_writers(void **state)
{
    (void)state;
    DrError err;
    char path[512];
    write_scratch("other.obj",
                  "# made elsewhere\r\n# radius_scale 3 (not a radius line)\r\no strands\r\n"
                  "v 0 0 0 1\r\nv 0 1 0\r\nvn 0 0 1\r\n# radius 0.5\r\nl -2/1 -1/2\r\n"
                  "v 1 1 0\r\n#radius 0.25\r\nl 2 3 1 # a comment\r\nf 1 2 3\r\nl\t4 2\r\n"
                  "v 2 0 0 0.5 0.5 0.5\r\n",
                  path, sizeof path);
    DrPolylines p;
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &p, &err), DR_OK);
    assert_int_equal(p.count, 3);
    int off[4] = {0, 2, 5, 7};
    assert_memory_equal(p.offsets, off, sizeof off);
    double x[21] = {0, 0, 0, 0, 1, 0, 0, 1, 0, 1, 1, 0, 0, 0, 0, 2, 0, 0, 0, 1, 0};
    assert_memory_equal(p.x, x, sizeof x); /* small integers: exact */
    assert_true(p.radius[0] == 0.5 && p.radius[1] == 0.25 && p.radius[2] == 0.25);
    dr_io_polylines_free(&p);
}

/* The desc: radius lines optional (strands before the first get NAN), a file without strands refused,
 * zero-length edges refused; and the defaults, which accept the last two. */
static void test_polylines_read_desc(void **state)
{
    (void)state;
    DrError err;
    char path[512];
    DrPolylinesReadDesc d;
    dr_io_polylines_read_desc_default(&d);
    assert_true(d.require_radius);
    assert_false(d.require_strands);
    assert_false(d.reject_zero_edges);

    /* without require_radius: NAN until the first radius line, that radius after it */
    write_scratch("no_radius.obj", "v 0 0 0\nv 0 1 0\nl 1 2\n# radius 0.5\nl 2 1\n", path, sizeof path);
    DrPolylines p;
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &p, &err), DR_ERR_INPUT);
    assert_int_equal(err.line, 3);
    d.require_radius = false;
    assert_int_equal(dr_io_read_polylines_obj(path, &d, &p, &err), DR_OK);
    assert_int_equal(p.count, 2);
    assert_true(isnan(p.radius[0]));
    assert_true(p.radius[1] == 0.5);
    dr_io_polylines_free(&p);
    /* a radius line is still checked when it is optional */
    write_scratch("bad_radius.obj", "v 0 0 0\nv 0 1 0\n# radius 5 cm\nl 1 2\n", path, sizeof path);
    assert_int_equal(dr_io_read_polylines_obj(path, &d, &p, &err), DR_ERR_INPUT);
    assert_int_equal(err.line, 3);
    assert_int_equal(err.col, 10);
    assert_non_null(strstr(err.message, "malformed radius line"));
    assert_null(p.x);

    /* require_strands: a file without "l" records is refused, naming the file */
    write_scratch("no_lines.obj", "# radius 1\nv 0 0 0\nf 1 1 1\n", path, sizeof path);
    assert_int_equal(dr_io_read_polylines_obj(path, &d, &p, &err), DR_OK);
    assert_int_equal(p.count, 0);
    dr_io_polylines_free(&p);
    d.require_strands = true;
    assert_int_equal(dr_io_read_polylines_obj(path, &d, &p, &err), DR_ERR_INPUT);
    assert_string_equal(err.file, path);
    assert_int_equal(err.line, 0);
    assert_non_null(strstr(err.message, "no 'l' records (polylines) among 3 lines"));
    assert_null(p.offsets);

    /* reject_zero_edges: reported at the edge's second vertex, also through a forward reference */
    write_scratch("zero_edge.obj", "# radius 1\nv 0 0 0\nv 0 1 0\nl 1 2\nl 2  3\nv 0 1 0\n", path, sizeof path);
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &p, &err), DR_OK);
    assert_int_equal(p.count, 2);
    dr_io_polylines_free(&p);
    d.reject_zero_edges = true;
    assert_int_equal(dr_io_read_polylines_obj(path, &d, &p, &err), DR_ERR_INPUT);
    assert_int_equal(err.line, 5);
    assert_int_equal(err.col, 6);
    assert_non_null(strstr(err.message, "zero-length edge: vertices 1 and 2 of this strand (OBJ indices 2 and 3)"));
    assert_null(p.x);
}

static void test_polylines_bad_files(void **state)
{
    (void)state;
    static const struct {
        const char *text;
        int line, col;
        const char *message;
    } bad[] = {
        {"v 0 0 0\nv 0 1 0\nl 1 2\n", 3, 1, "before any \"# radius R\" line"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1 3\n", 4, 5, "vertex index 3 is out of range: the file has 2 'v' records"},
        /* forward references: the first one past the end of the file is reported */
        {"# radius 0.1\nv 0 0 0\nl 1 2\nl 1 9\nl 7 1\nv 0 1 0\n", 4, 5, "vertex index 9 is out of range"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl -3 1\n", 4, 3,
         "vertex index -3 is out of range: only 2 'v' records come before this line"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 0 1\n", 4, 3, "vertex index 0: OBJ indices start at 1"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1\n", 4, 1, "'l' record with 1 vertex; a strand needs at least 2"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl\n", 4, 1, "'l' record with 0 vertices"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1 x\n", 4, 5, "'x' is not a vertex index"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1 99999999999999999999\n", 4, 5, "is not a vertex index"},
        {"# radius 0.1\nv 0 0\n", 2, 1, "'v' record with 2 numbers; a vertex is \"v x y z\""},
        {"# radius 0.1\nv 0 0 0 w\n", 2, 9, "'w' is not a number"},
        {"# radius 0.1\nv 0 nan 0\n", 2, 5, "vertex coordinate 'nan' is not finite"},
        {"# radius 0.1\nv 0 1e999 0\n", 2, 5, "vertex coordinate '1e999' is not finite"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1 2\x01\n", 4, 6, "control byte 0x01: this is not a text OBJ file"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1 \\\n 2\n", 4, 5, "'l' record continued on the next line"},
        {"# radius -0.1\n", 1, 10, "radius -0.1 is not a finite number >= 0"},
        {"# radius inf\n", 1, 10, "not a finite number"},
        {"# radius 0.1 m\n", 1, 10, "malformed radius line"},
    };
    DrError err;
    char path[512], name[64];
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        snprintf(name, sizeof name, "bad_%zu.obj", k);
        write_scratch(name, bad[k].text, path, sizeof path);
        DrPolylines p = {.count = 7};
        assert_int_equal(dr_io_read_polylines_obj(path, NULL, &p, &err), DR_ERR_INPUT);
        assert_string_equal(err.file, path);
        if (err.line != bad[k].line || err.col != bad[k].col)
            fail_msg("case %zu: reported at %d:%d, expected %d:%d", k, err.line, err.col, bad[k].line, bad[k].col);
        if (!strstr(err.message, bad[k].message))
            fail_msg("case %zu: message \"%s\" lacks \"%s\"", k, err.message, bad[k].message);
        assert_int_equal(p.count, 0);
        assert_null(p.x);
    }
    /* a NUL byte: binary, not text */
    scratch_path("nul.obj", path, sizeof path);
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    fwrite("# radius 1\nv 0 0 0\nv \0 1 0\n", 1, 28, f);
    fclose(f);
    DrPolylines p;
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &p, &err), DR_ERR_INPUT);
    assert_int_equal(err.line, 3);
    assert_int_equal(err.col, 3);
    assert_non_null(strstr(err.message, "a NUL byte: this is not a text OBJ file"));
    /* missing file */
    scratch_path("absent.obj", path, sizeof path);
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &p, &err), DR_ERR_INPUT);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "cannot open the polyline file: No such file or directory"));
}

/* The film of wet hair: "# outer_radius" lines, one number per vertex right before each "l" record, written
 * when outer is set and read back per vertex (also through shared and forward vertices); files mixing strands
 * with and without them, counts that differ, a line without its record, bad numbers refused at line:col. */
static void test_polylines_outer_radius(void **state)
{
    (void)state;
    DrError err;
    char path[512];
    double x[3 * 5] = {0, 0, 0, 0, 0.01, 0, 0.001, 0.02, 0, 1, 0, 0, 1, 0.1, 0.003};
    int off[3] = {0, 3, 5};
    double r[2] = {5e-5, 5e-5}, H[5] = {5.5e-4, 3e-4, 5e-5, 1.25e-4, 5e-5};
    DrPolylines a = {2, off, x, r, H}, b;
    scratch_path("wet_strands.obj", path, sizeof path);
    assert_int_equal(dr_io_write_polylines_obj(path, &a, "wet", &err), DR_OK);
    char *text = slurp(path);
    assert_non_null(strstr(text, "\n# radius 5e-05\n# outer_radius 0.00055 0.0003 5e-05\nl 1 2 3\n"
                                 "# outer_radius 0.000125 5e-05\nl 4 5\n"));
    free(text);
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &b, &err), DR_OK);
    assert_non_null(b.outer);
    for (int i = 0; i < 5; i++) assert_true(fabs(b.outer[i] - H[i]) <= 1e-9 * H[i]); /* %.9g */
    dr_io_polylines_free(&b);
    /* a dry set has none and reads back without */
    a.outer = NULL;
    assert_int_equal(dr_io_write_polylines_obj(path, &a, NULL, &err), DR_OK);
    text = slurp(path);
    assert_null(strstr(text, "outer_radius"));
    free(text);
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &b, &err), DR_OK);
    assert_null(b.outer);
    dr_io_polylines_free(&b);
    /* a non-finite or negative outer radius: nothing written */
    a.outer = H;
    H[3] = NAN;
    scratch_path("wet_nan.obj", path, sizeof path);
    assert_int_equal(dr_io_write_polylines_obj(path, &a, NULL, &err), DR_ERR_RUNTIME);
    assert_non_null(strstr(err.message, "vertex 3 has film outer radius nan"));
    H[3] = -1e-4;
    assert_int_equal(dr_io_write_polylines_obj(path, &a, NULL, &err), DR_ERR_RUNTIME);
    assert_false(dr_io_exists(path));

    /* per vertex of each record, as its vertices are copied: a shared vertex and a forward reference */
    write_scratch("wet_other.obj",
                  "# radius 0.1\nv 0 0 0\nv 0 1 0\n# outer_radius 0.5 0.25\nl 1 2\n# outer_radius 0.3 0.2 0.1\n"
                  "l 2 1 3\nv 0 2 0\n",
                  path, sizeof path);
    assert_int_equal(dr_io_read_polylines_obj(path, NULL, &b, &err), DR_OK);
    assert_int_equal(b.count, 2);
    double want[5] = {0.5, 0.25, 0.3, 0.2, 0.1};
    assert_memory_equal(b.outer, want, sizeof want); /* exact: strtod of the same text */
    dr_io_polylines_free(&b);

    static const struct {
        const char *text;
        int line, col;
        const char *message;
    } bad[] = {
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\n# outer_radius 0.2\nl 1 2\n", 5, 1, "gives 1 radii for its 2 vertices"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\n# outer_radius 0.2 0.2\nl 1 2\nl 2 1\n", 6, 1,
         "has no \"# outer_radius\" line but the strands before it have one"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1 2\n# outer_radius 0.2 0.2\nl 2 1\n", 6, 1,
         "but the 1 before it have none"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\n# outer_radius 0.2 0.2\n# outer_radius 0.2 0.2\nl 1 2\n", 5, 1,
         "a second \"# outer_radius\" line"},
        {"# radius 0.1\nv 0 0 0\nv 0 1 0\nl 1 2\n# outer_radius 0.2 0.2\n", 5, 1, "without an 'l' record after it"},
        {"# radius 0.1\n# outer_radius 0.2 -0.1\n", 2, 20, "film outer radius -0.1 is not a finite number >= 0"},
        {"# radius 0.1\n# outer_radius 0.2 nan\n", 2, 20, "is not a finite number"},
        {"# radius 0.1\n# outer_radius 0.2 2mm\n", 2, 20, "'2mm' is not a number"},
    };
    char name[64];
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        snprintf(name, sizeof name, "bad_outer_%zu.obj", k);
        write_scratch(name, bad[k].text, path, sizeof path);
        DrPolylines p = {.count = 7};
        assert_int_equal(dr_io_read_polylines_obj(path, NULL, &p, &err), DR_ERR_INPUT);
        assert_string_equal(err.file, path);
        if (err.line != bad[k].line || err.col != bad[k].col)
            fail_msg("case %zu: reported at %d:%d, expected %d:%d", k, err.line, err.col, bad[k].line, bad[k].col);
        if (!strstr(err.message, bad[k].message))
            fail_msg("case %zu: message \"%s\" lacks \"%s\"", k, err.message, bad[k].message);
        assert_int_equal(p.count, 0);
        assert_null(p.outer);
    }
}

/* ---- files ---- */

static void test_files(void **state)
{
    (void)state;
    char buf[64], expect[64];
    dr_io_tmp_path("out/frame.0001.h5", buf, sizeof buf);
    snprintf(expect, sizeof expect, "out/frame.0001.h5.tmp.%ld", (long)getpid());
    assert_string_equal(buf, expect);

    DrError err;
    char dir[512], path[600], deep[600];
    scratch_path("a/b//c/", dir, sizeof dir);
    assert_int_equal(dr_io_mkdirs(dir, &err), DR_OK);
    assert_int_equal(dr_io_mkdirs(dir, &err), DR_OK); /* existing: fine */
    snprintf(path, sizeof path, "%s/a/b/c/note.txt", g_dir);
    assert_int_equal(dr_io_write_text_atomic(path, "first\n", &err), DR_OK);
    assert_int_equal(dr_io_write_text_atomic(path, "second line\nthird\n", &err), DR_OK); /* replaces */
    char *text = slurp(path);
    assert_string_equal(text, "second line\nthird\n");
    free(text);
    snprintf(deep, sizeof deep, "%s/a/b/c", g_dir);
    assert_int_equal(count_tmp_files(deep), 0);

    /* A regular file in the way of mkdir -p is an error naming it. */
    snprintf(deep, sizeof deep, "%s/a/b/c/note.txt/d", g_dir);
    dr_error_clear(&err);
    assert_int_equal(dr_io_mkdirs(deep, &err), DR_ERR_IO);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "not a directory"));

    /* Writing into a missing directory fails and leaves nothing. */
    snprintf(deep, sizeof deep, "%s/missing/x.txt", g_dir);
    assert_int_equal(dr_io_write_text_atomic(deep, "x", &err), DR_ERR_IO);
    assert_string_equal(err.file, deep);
    assert_false(dr_io_exists(deep));

    /* Commit of a temporary file that does not exist. */
    scratch_path("never.txt", path, sizeof path);
    assert_int_equal(dr_io_commit("/nonexistent/x.tmp.1", path, &err), DR_ERR_IO);
    assert_string_equal(err.file, path);
    assert_false(dr_io_exists(path));

    char *none = (char *)1;
    assert_int_equal(dr_io_read_text(path, &none, &err), DR_ERR_INPUT);
    assert_null(none);
    assert_string_equal(err.file, path);
    assert_true(dr_io_exists(g_dir));
    assert_false(dr_io_exists(path));

    /* An empty file reads as "". */
    scratch_path("empty.txt", path, sizeof path);
    assert_int_equal(dr_io_write_text_atomic(path, "", &err), DR_OK);
    text = slurp(path);
    assert_string_equal(text, "");
    free(text);
}

static void touch(const char *dir, const char *name)
{
    char path[600];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs("partial", f);
    fclose(f);
}

static bool exists_in(const char *dir, const char *name)
{
    char path[600];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    return dr_io_exists(path);
}

static void test_remove_stale_tmp(void **state)
{
    (void)state;
    char dir[512], mine[64];
    DrError err;
    scratch_path("stale", dir, sizeof dir);
    assert_int_equal(dr_io_mkdirs(dir, &err), DR_OK);
    /* Linux pids are below pid_max, which can be at most 2^22 = 4194304 (PID_MAX_LIMIT), so pid
     * 999999999 cannot be running. Pid 1 (init) always is. */
    touch(dir, "frame.0001.h5.tmp.999999999");
    touch(dir, "frame.0002.h5.tmp.1");
    snprintf(mine, sizeof mine, "frame.0003.h5.tmp.%ld", (long)getpid());
    touch(dir, mine);
    touch(dir, "frame.0004.h5");
    touch(dir, "notes.tmp.abc");
    touch(dir, "x.tmp.");
    dr_io_remove_stale_tmp(dir);
    assert_false(exists_in(dir, "frame.0001.h5.tmp.999999999"));
    assert_true(exists_in(dir, "frame.0002.h5.tmp.1"));
    assert_true(exists_in(dir, mine));
    assert_true(exists_in(dir, "frame.0004.h5"));
    assert_true(exists_in(dir, "notes.tmp.abc"));
    assert_true(exists_in(dir, "x.tmp."));
    dr_io_remove_stale_tmp("/nonexistent/dir"); /* no-op */
}

/* ---- manifests ---- */

static void test_manifest(void **state)
{
    (void)state;
    char dir[512], path[600];
    DrError err;
    scratch_path("out/shot/bake", dir, sizeof dir);
    const char *inputs[] = {"asset assets/meshes/cube.obj 0123abcd", "precompute bem 77aa"};
    const char *key = "0123456789abcdef0123456789abcdef";
    assert_int_equal(dr_io_manifest_write(dir, "bake", key, "scenes/wet.json", inputs, 2, &err), DR_OK);
    snprintf(path, sizeof path, "%s/MANIFEST", dir);
    char *text = slurp(path);
    char expect_head[256];
    snprintf(expect_head, sizeof expect_head, "key %s\nstage bake\ntime ", key);
    assert_true(strncmp(text, expect_head, strlen(expect_head)) == 0);
    /* time: YYYY-MM-DDTHH:MM:SSZ */
    const char *t = text + strlen(expect_head);
    assert_true(t[4] == '-' && t[7] == '-' && t[10] == 'T' && t[13] == ':' && t[16] == ':' && t[19] == 'Z' &&
                t[20] == '\n');
    assert_non_null(strstr(text, "\ndrench_version " DR_VERSION "\nscene scenes/wet.json\n"
                                 "input asset assets/meshes/cube.obj 0123abcd\ninput precompute bem 77aa\n"));
    free(text);

    char got[33];
    bool found = false;
    assert_int_equal(dr_io_manifest_read_key(dir, got, &found, &err), DR_OK);
    assert_true(found);
    assert_string_equal(got, key);

    /* A manifest whose first line is not a key is not trusted. */
    assert_int_equal(dr_io_write_text_atomic(path, "stage bake\n", &err), DR_OK);
    assert_int_equal(dr_io_manifest_read_key(dir, got, &found, &err), DR_OK);
    assert_false(found);
    assert_string_equal(got, "");

    assert_int_equal(dr_io_manifest_write(dir, "mesh", "beef", "s.json", NULL, 0, &err), DR_OK);
    assert_int_equal(dr_io_manifest_read_key(dir, got, &found, &err), DR_OK);
    assert_true(found);
    assert_string_equal(got, "beef");
    assert_int_equal(dr_io_manifest_remove(dir, &err), DR_OK);
    assert_false(dr_io_exists(path));
    assert_int_equal(dr_io_manifest_remove(dir, &err), DR_OK); /* absent: fine */
    assert_int_equal(dr_io_manifest_read_key(dir, got, &found, &err), DR_OK);
    assert_false(found);

    /* A field with a line break or a bad key is refused and nothing is written. */
    const char *bad[] = {"two\nlines"};
    assert_int_equal(dr_io_manifest_write(dir, "bake", key, "s.json", bad, 1, &err), DR_ERR_INPUT);
    assert_int_equal(dr_io_manifest_write(dir, "bake", "not-hex", "s.json", NULL, 0, &err), DR_ERR_INPUT);
    assert_false(dr_io_exists(path));
    assert_int_equal(count_tmp_files(dir), 0);

    /* The frames a frame stage holds: written as "frames A-B" after the scene, read back; a MANIFEST without the
     * line has none, one with a malformed line is not trusted. */
    DrManifest m;
    assert_int_equal(dr_io_manifest_write_frames(dir, "bake", key, "s.json", 1, 10, inputs, 2, &err), DR_OK);
    text = slurp(path);
    assert_non_null(strstr(text, "\nscene s.json\nframes 1-10\ninput asset"));
    free(text);
    assert_int_equal(dr_io_manifest_read(dir, &m, &err), DR_OK);
    assert_true(m.found && m.has_frames);
    assert_string_equal(m.key, key);
    assert_int_equal(m.first, 1);
    assert_int_equal(m.last, 10);
    assert_int_equal(dr_io_manifest_write(dir, "precompute", key, "s.json", NULL, 0, &err), DR_OK);
    assert_int_equal(dr_io_manifest_read(dir, &m, &err), DR_OK);
    assert_true(m.found && !m.has_frames);
    assert_int_equal(dr_io_write_text_atomic(path, "key beef\nframes 9-3\n", &err), DR_OK);
    assert_int_equal(dr_io_manifest_read(dir, &m, &err), DR_OK);
    assert_false(m.found);
    assert_int_equal(dr_io_manifest_remove(dir, &err), DR_OK);
    assert_int_equal(dr_io_manifest_read(dir, &m, &err), DR_OK);
    assert_false(m.found);
}

/* ---- HDF5 ---- */

static void test_h5_round_trip(void **state)
{
    (void)state;
    DrError err;
    char path[512], tmp[600];
    scratch_path("frame.0001.h5", path, sizeof path);
    dr_io_tmp_path(path, tmp, sizeof tmp);

    enum { N = 20000 };
    double *pos = malloc(sizeof(double) * 3 * N);
    double *aff = malloc(sizeof(double) * 9 * 5);
    int64_t ids[7] = {INT64_MIN, -1, 0, 1, 42, INT64_MAX, 7};
    uint64_t offs[4] = {0, 3, UINT64_MAX, 12};
    assert_non_null(pos);
    assert_non_null(aff);
    /* Particles on a lattice: regular data that shuffle + deflate compress well. */
    for (int i = 0; i < N; i++) {
        pos[3 * i] = 0.01 * (i % 20);
        pos[3 * i + 1] = 0.01 * ((i / 20) % 50);
        pos[3 * i + 2] = 0.01 * (i / 1000);
    }
    for (int i = 0; i < 45; i++) aff[i] = (double)i / 3.0 - 1e-300 * i;

    DrH5 *h = NULL;
    assert_int_equal(dr_h5_create(path, &h, &err), DR_OK);
    assert_true(dr_io_exists(tmp));
    assert_false(dr_io_exists(path));
    assert_string_equal(dr_h5_path(h), path);
    uint64_t dpos[2] = {N, 3}, daff[3] = {5, 3, 3}, dids[1] = {7}, doffs[1] = {4}, dzero[2] = {0, 3};
    assert_int_equal(dr_h5_attr_str(h, "/", "drench_version", DR_VERSION, &err), DR_OK);
    assert_int_equal(dr_h5_attr_i64(h, "/", "frame", 1, &err), DR_OK);
    assert_int_equal(dr_h5_attr_f64(h, "/", "time", 1.0 / 24.0, &err), DR_OK);
    assert_int_equal(dr_h5_attr_str(h, "/", "scene_key", "", &err), DR_OK);
    assert_int_equal(dr_h5_attr_str(h, "/", "scene_key", "abc123", &err), DR_OK); /* replaced */
    assert_int_equal(dr_h5_write_f64(h, "/water/position", 2, dpos, pos, "m", true, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/water/affine", 3, daff, aff, "1/s", false, &err), DR_OK);
    assert_int_equal(dr_h5_write_i64(h, "/water/ids", 1, dids, ids, NULL, true, &err), DR_OK);
    assert_int_equal(dr_h5_write_u64(h, "/fur/strand_offsets", 1, doffs, offs, false, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/empty/position", 2, dzero, NULL, "m", true, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/empty/velocity", 2, dzero, NULL, "m/s", false, &err), DR_OK);
    assert_int_equal(dr_h5_attr_str(h, "/water", "material", "w\xc3\xa4sser \xc2\xb5m", &err), DR_OK);
    assert_int_equal(dr_h5_attr_f64(h, "/diagnostics/energy", "kinetic", -0.0, &err), DR_OK); /* new group */
    assert_int_equal(dr_h5_attr_i64(h, "/water/ids", "count", INT64_MIN, &err), DR_OK);     /* on a dataset */
    dr_error_clear(&err);
    assert_int_equal(dr_h5_write_f64(h, "/water/position", 2, dpos, pos, "m", true, &err), DR_ERR_INPUT);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "/water/position already exists"));
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    assert_null(h);
    assert_true(dr_io_exists(path));
    assert_false(dr_io_exists(tmp));

    struct stat st;
    assert_int_equal(stat(path, &st), 0);
    /* Compression works: the whole file is well under the raw bytes of the positions alone
     * (measured: 26%; without compression it would exceed 100%). */
    assert_true((size_t)st.st_size < sizeof(double) * 3 * N / 2);

    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    int rank;
    uint64_t dims[4];
    double *f = NULL;
    assert_int_equal(dr_h5_read_f64(h, "/water/position", &rank, dims, &f, &err), DR_OK);
    assert_int_equal(rank, 2);
    assert_true(dims[0] == N && dims[1] == 3);
    assert_memory_equal(f, pos, sizeof(double) * 3 * N); /* bit-identical */
    free(f);
    assert_int_equal(dr_h5_read_f64(h, "/water/affine", &rank, dims, &f, &err), DR_OK);
    assert_int_equal(rank, 3);
    assert_true(dims[0] == 5 && dims[1] == 3 && dims[2] == 3);
    assert_memory_equal(f, aff, sizeof(double) * 45);
    free(f);
    int64_t *i64 = NULL;
    assert_int_equal(dr_h5_read_i64(h, "/water/ids", &rank, dims, &i64, &err), DR_OK);
    assert_true(rank == 1 && dims[0] == 7);
    assert_memory_equal(i64, ids, sizeof ids);
    free(i64);
    uint64_t *u64 = NULL;
    assert_int_equal(dr_h5_read_u64(h, "/fur/strand_offsets", &rank, dims, &u64, &err), DR_OK);
    assert_true(rank == 1 && dims[0] == 4);
    assert_memory_equal(u64, offs, sizeof offs);
    free(u64);
    const char *zeros[] = {"/empty/position", "/empty/velocity"};
    for (int k = 0; k < 2; k++) {
        assert_int_equal(dr_h5_read_f64(h, zeros[k], &rank, dims, &f, &err), DR_OK);
        assert_true(rank == 2 && dims[0] == 0 && dims[1] == 3);
        assert_non_null(f);
        free(f);
    }

    /* Attributes. */
    char *s = NULL;
    double x;
    int64_t n;
    assert_int_equal(dr_h5_read_attr_str(h, "/", "drench_version", &s, &err), DR_OK);
    assert_string_equal(s, DR_VERSION);
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/", "scene_key", &s, &err), DR_OK);
    assert_string_equal(s, "abc123");
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/water/position", "units", &s, &err), DR_OK);
    assert_string_equal(s, "m");
    free(s);
    assert_int_equal(dr_h5_read_attr_str(h, "/water", "material", &s, &err), DR_OK);
    assert_string_equal(s, "w\xc3\xa4sser \xc2\xb5m");
    free(s);
    assert_int_equal(dr_h5_read_attr_i64(h, "/", "frame", &n, &err), DR_OK);
    assert_true(n == 1);
    assert_int_equal(dr_h5_read_attr_i64(h, "/water/ids", "count", &n, &err), DR_OK);
    assert_true(n == INT64_MIN);
    assert_int_equal(dr_h5_read_attr_f64(h, "/", "time", &x, &err), DR_OK);
    assert_memory_equal(&x, &(double){1.0 / 24.0}, sizeof x);
    assert_int_equal(dr_h5_read_attr_f64(h, "/diagnostics/energy", "kinetic", &x, &err), DR_OK);
    assert_true(x == 0.0 && signbit(x));
    assert_false(dr_h5_has(h, "/water/ids/count")); /* attributes are not objects */

    /* Structure. */
    assert_true(dr_h5_has(h, "/water"));
    assert_true(dr_h5_has(h, "/water/affine"));
    assert_false(dr_h5_has(h, "/water/nope"));
    assert_false(dr_h5_has(h, "/nope/deeper/still"));
    char **names = NULL;
    int count = 0;
    assert_int_equal(dr_h5_list(h, "/", &names, &count, &err), DR_OK);
    assert_int_equal(count, 4);
    const char *expect_root[] = {"diagnostics", "empty", "fur", "water"};
    for (int i = 0; i < count; i++) {
        assert_string_equal(names[i], expect_root[i]);
        free(names[i]);
    }
    free(names);
    assert_int_equal(dr_h5_list(h, "/water", &names, &count, &err), DR_OK);
    assert_int_equal(count, 3);
    const char *expect_water[] = {"affine", "ids", "position"};
    for (int i = 0; i < count; i++) {
        assert_string_equal(names[i], expect_water[i]);
        free(names[i]);
    }
    free(names);

    /* Errors name the file and the object. */
    dr_error_clear(&err);
    assert_int_equal(dr_h5_read_f64(h, "/water/velocity", &rank, dims, &f, &err), DR_ERR_INPUT);
    assert_null(f);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "/water/velocity"));
    assert_int_equal(dr_h5_read_i64(h, "/water/position", &rank, dims, &i64, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "/water/position does not hold signed 64-bit integer"));
    assert_int_equal(dr_h5_read_u64(h, "/water/ids", &rank, dims, &u64, &err), DR_ERR_INPUT);
    assert_int_equal(dr_h5_read_attr_str(h, "/water", "color", &s, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "attribute color of /water is missing"));
    assert_int_equal(dr_h5_read_attr_str(h, "/", "frame", &s, &err), DR_ERR_INPUT);
    assert_int_equal(dr_h5_read_attr_f64(h, "/nope", "x", &x, &err), DR_ERR_INPUT);
    assert_int_equal(dr_h5_list(h, "/water/position", &names, &count, &err), DR_ERR_INPUT);
    assert_int_equal(dr_h5_write_f64(h, "/new", 1, dids, aff, NULL, false, &err), DR_ERR_INPUT); /* read-only */
    dr_h5_close(&h);
    assert_null(h);
    assert_true(dr_io_exists(path)); /* closing a read handle keeps the file */

    /* h5dump (when installed) shows the units attribute as text. */
    if (system("command -v h5dump >/dev/null 2>&1") == 0) {
        char cmd[1400], dump[600];
        scratch_path("dump.txt", dump, sizeof dump);
        snprintf(cmd, sizeof cmd, "h5dump -A '%s' > '%s' 2>&1", path, dump);
        assert_int_equal(system(cmd), 0);
        char *text = slurp(dump);
        assert_non_null(strstr(text, "ATTRIBUTE \"units\""));
        assert_non_null(strstr(text, "\"m/s\""));
        assert_non_null(strstr(text, "H5T_CSET_UTF8"));
        free(text);
    }
    free(pos);
    free(aff);
}

static void test_h5_abandon_and_bad_files(void **state)
{
    (void)state;
    DrError err;
    char path[512], tmp[600];
    scratch_path("abandoned.h5", path, sizeof path);
    dr_io_tmp_path(path, tmp, sizeof tmp);
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_create(path, &h, &err), DR_OK);
    uint64_t d[1] = {3};
    double v[3] = {1, 2, 3};
    assert_int_equal(dr_h5_write_f64(h, "/a/b/c/d", 1, d, v, NULL, true, &err), DR_OK);
    assert_true(dr_io_exists(tmp));
    dr_h5_close(&h);
    assert_null(h);
    assert_false(dr_io_exists(tmp));
    assert_false(dr_io_exists(path));
    dr_h5_close(&h); /* NULL: no-op */

    /* Opening a missing file or one that is not HDF5. */
    dr_error_clear(&err);
    assert_int_equal(dr_h5_open(path, &h, &err), DR_ERR_INPUT);
    assert_null(h);
    assert_string_equal(err.file, path);
    scratch_path("garbage.h5", path, sizeof path);
    assert_int_equal(dr_io_write_text_atomic(path, "this is not an HDF5 file\n", &err), DR_OK);
    assert_int_equal(dr_h5_open(path, &h, &err), DR_ERR_INPUT);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "not HDF5"));

    /* Creating in a missing directory. */
    assert_int_equal(dr_h5_create("/nonexistent/dir/x.h5", &h, &err), DR_ERR_IO);
    assert_null(h);
    assert_string_equal(err.file, "/nonexistent/dir/x.h5");
}

/* ---- deferred handles and the background writer ---- */

/* Files' bytes equal (both must exist). */
static bool same_bytes(const char *a, const char *b)
{
    char cmd[1400];
    snprintf(cmd, sizeof cmd, "cmp -s '%s' '%s'", a, b);
    return system(cmd) == 0;
}

/* The calls of a small frame: every writer, compressed and not, empty datasets, an attribute replaced,
 * on the root, a group made by it and a dataset. The arrays are overwritten after each call, so a
 * deferred handle that kept pointers instead of copies would write other bytes. */
static void write_sample(DrH5 *h, int seed)
{
    enum { N = 30000 };
    DrError err;
    double *x = malloc(sizeof(double) * 3 * N);
    int64_t *ids = malloc(sizeof(int64_t) * N);
    int32_t *tri = malloc(sizeof(int32_t) * 3 * N);
    uint64_t rng[4] = {1, UINT64_MAX, 3, (uint64_t)seed};
    assert_non_null(x);
    assert_non_null(ids);
    assert_non_null(tri);
    DrRng r;
    dr_rng_seed(&r, (uint64_t)seed);
    for (int i = 0; i < 3 * N; i++) x[i] = 0.001 * (i % 997) + 1e-6 * dr_rng_uniform(&r);
    for (int i = 0; i < N; i++) ids[i] = (int64_t)i * seed - 5;
    for (int i = 0; i < 3 * N; i++) tri[i] = i / 2;
    uint64_t d2[2] = {N, 3}, d1[1] = {N}, d4[1] = {4}, d0[2] = {0, 3};
    assert_int_equal(dr_h5_attr_str(h, "/", "drench_version", DR_VERSION, &err), DR_OK);
    assert_int_equal(dr_h5_attr_i64(h, "/", "frame", seed, &err), DR_OK);
    assert_int_equal(dr_h5_attr_f64(h, "/", "time", seed / 24.0, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/water/position", 2, d2, x, "m", true, &err), DR_OK);
    for (int i = 0; i < 3 * N; i++) x[i] = -1.0;
    assert_int_equal(dr_h5_write_f64(h, "/water/velocity", 2, d2, x, "m/s", false, &err), DR_OK);
    for (int i = 0; i < 3 * N; i++) x[i] = 2.0;
    assert_int_equal(dr_h5_write_i64(h, "/water/ids", 1, d1, ids, NULL, true, &err), DR_OK);
    for (int i = 0; i < N; i++) ids[i] = 0;
    assert_int_equal(dr_h5_write_i32(h, "/body/triangles", 2, d2, tri, "1", true, &err), DR_OK);
    for (int i = 0; i < 3 * N; i++) tri[i] = 0;
    assert_int_equal(dr_h5_write_u64(h, "/water/rng", 1, d4, rng, false, &err), DR_OK);
    rng[0] = 0;
    assert_int_equal(dr_h5_write_f64(h, "/empty/position", 2, d0, NULL, "m", true, &err), DR_OK);
    assert_int_equal(dr_h5_attr_str(h, "/water", "type", "liquid", &err), DR_OK);
    assert_int_equal(dr_h5_attr_str(h, "/water", "type", "liquid!", &err), DR_OK); /* replaced */
    assert_int_equal(dr_h5_attr_f64(h, "/diagnostics/water", "mass", 1.25, &err), DR_OK);
    assert_int_equal(dr_h5_attr_i64(h, "/water/ids", "count", N, &err), DR_OK);
    free(x);
    free(ids);
    free(tri);
}

static void test_h5_deferred_identical(void **state)
{
    (void)state;
    DrError err;
    char direct[512], deferred[512], background[512], tmp[600];
    scratch_path("direct.h5", direct, sizeof direct);
    scratch_path("deferred.h5", deferred, sizeof deferred);
    scratch_path("background.h5", background, sizeof background);
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_create(direct, &h, &err), DR_OK);
    assert_false(dr_h5_deferred(h));
    write_sample(h, 3);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);

    /* Deferred, committed on this thread: nothing on disk until the commit. */
    assert_int_equal(dr_h5_create_deferred(deferred, &h, &err), DR_OK);
    assert_true(dr_h5_deferred(h));
    assert_string_equal(dr_h5_path(h), deferred);
    write_sample(h, 3);
    dr_io_tmp_path(deferred, tmp, sizeof tmp);
    assert_false(dr_io_exists(tmp));
    assert_false(dr_io_exists(deferred));
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    assert_null(h);
    assert_true(same_bytes(direct, deferred));

    /* Deferred, committed by the writer's thread. */
    DrH5Writer *w = NULL;
    assert_int_equal(dr_h5_writer_create(2, &w, &err), DR_OK);
    assert_int_equal(dr_h5_create_deferred(background, &h, &err), DR_OK);
    write_sample(h, 3);
    assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_OK);
    assert_null(h);
    assert_int_equal(dr_h5_writer_flush(w, &err), DR_OK);
    DrH5WriterStats st;
    dr_h5_writer_stats(w, &st);
    assert_int_equal(st.files, 1);
    assert_true(st.seconds > 0.0);
    dr_h5_writer_destroy(&w);
    assert_null(w);
    dr_h5_writer_destroy(&w); /* NULL: no-op */
    assert_true(same_bytes(direct, background));

    /* Another seed gives another file: the comparison can tell files apart. */
    assert_int_equal(dr_h5_create_deferred(deferred, &h, &err), DR_OK);
    write_sample(h, 4);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    assert_false(same_bytes(direct, deferred));
    assert_int_equal(count_tmp_files(g_dir), 0);
}

static void test_h5_deferred_checks(void **state)
{
    (void)state;
    DrError err;
    char path[512], tmp[600];
    scratch_path("dropped.h5", path, sizeof path);
    dr_io_tmp_path(path, tmp, sizeof tmp);
    DrH5 *h = NULL;
    uint64_t d[1] = {3};
    double v[3] = {1, 2, 3};
    assert_int_equal(dr_h5_create_deferred(path, &h, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/a/b", 1, d, v, NULL, true, &err), DR_OK);
    /* the same dataset twice is refused when recorded, as on a direct handle */
    assert_int_equal(dr_h5_write_f64(h, "/a/b", 1, d, v, NULL, true, &err), DR_ERR_INPUT);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "/a/b"));
    /* closing drops the recording: no file, no temporary file */
    dr_h5_close(&h);
    assert_null(h);
    assert_false(dr_io_exists(path));
    assert_false(dr_io_exists(tmp));

    /* A failure of the file itself comes from the commit, naming the file, leaving nothing. */
    const char *missing = "/nonexistent/dir/x.h5";
    assert_int_equal(dr_h5_create_deferred(missing, &h, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/a", 1, d, v, NULL, false, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_ERR_IO);
    assert_null(h);
    assert_string_equal(err.file, missing);
    /* A clash only the file can see (a dataset under a dataset) also comes from the commit. */
    assert_int_equal(dr_h5_create_deferred(path, &h, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/a", 1, d, v, NULL, false, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/a/b", 1, d, v, NULL, false, &err), DR_OK);
    assert_true(dr_h5_commit(&h, &err) < 0);
    assert_string_equal(err.file, path);
    assert_false(dr_io_exists(path));
    assert_false(dr_io_exists(tmp));
}

/* The two meanings of compress = true: DR_H5_COMPRESS_ALL (the default) deflates every such dataset;
 * DR_H5_COMPRESS_ONE_VALUE (frame caches) only those of 4 KiB or more holding one value. Every dataset
 * reads back bit-identical either way, and a deferred handle keeps the mode it was given. */
static void write_modes_sample(DrH5 *h)
{
    enum { N = 20000 };
    DrError err;
    double *x = malloc(sizeof(double) * 3 * N), *still = malloc(sizeof(double) * 3 * N);
    assert_non_null(x);
    assert_non_null(still);
    DrRng r;
    dr_rng_seed(&r, 9);
    for (int i = 0; i < 3 * N; i++) {
        x[i] = dr_rng_uniform(&r);
        still[i] = 0.25;
    }
    uint64_t d[2] = {N, 3}, dsmall[2] = {100, 3}; /* 2.4 kB: under the 4 KiB where deflating one value pays */
    assert_int_equal(dr_h5_write_f64(h, "/varied", 2, d, x, "m", true, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/still", 2, d, still, "1/s", true, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/still_small", 2, dsmall, still, "1/s", true, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/still_raw", 2, d, still, "1/s", false, &err), DR_OK);
    free(x);
    free(still);
}

static void test_h5_compress_modes(void **state)
{
    (void)state;
    DrError err;
    char all[512], frame[512], deferred[512];
    scratch_path("mode_all.h5", all, sizeof all);
    scratch_path("mode_frame.h5", frame, sizeof frame);
    scratch_path("mode_frame_deferred.h5", deferred, sizeof deferred);
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_create(all, &h, &err), DR_OK);
    write_modes_sample(h);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    assert_int_equal(dr_h5_create(frame, &h, &err), DR_OK);
    dr_h5_set_compress(h, DR_H5_COMPRESS_ONE_VALUE);
    write_modes_sample(h);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    assert_int_equal(dr_h5_create_deferred(deferred, &h, &err), DR_OK);
    dr_h5_set_compress(h, DR_H5_COMPRESS_ONE_VALUE);
    write_modes_sample(h);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    assert_true(same_bytes(frame, deferred));

    /* Sizes: 480 kB per large array. ALL deflates the varied doubles a little (shuffle groups their
     * exponent bytes: measured 88%) and the one-value array to almost nothing; ONE_VALUE stores the
     * varied array raw. Either way the compress = false array takes its 480 kB. */
    size_t raw = sizeof(double) * 3 * 20000;
    struct stat sa, sf;
    assert_int_equal(stat(all, &sa), 0);
    assert_int_equal(stat(frame, &sf), 0);
    assert_true((size_t)sf.st_size >= 2 * raw && (size_t)sf.st_size < 2 * raw + raw / 10);
    assert_true((size_t)sa.st_size < (size_t)sf.st_size);
    assert_true((size_t)sa.st_size >= raw);

    const char *names[] = {"/varied", "/still", "/still_small", "/still_raw"};
    for (int m = 0; m < 2; m++) {
        assert_int_equal(dr_h5_open(m == 0 ? all : frame, &h, &err), DR_OK);
        double *back = NULL;
        int rank;
        uint64_t dims[4];
        assert_int_equal(dr_h5_read_f64(h, "/still", &rank, dims, &back, &err), DR_OK);
        for (int i = 0; i < 60000; i++) assert_true(back[i] == 0.25);
        free(back);
        dr_h5_close(&h);
    }
    /* h5dump (when installed) shows each dataset's storage. */
    if (system("command -v h5dump >/dev/null 2>&1") == 0) {
        const bool deflated[2][4] = {{true, true, true, false}, {false, true, false, false}};
        char cmd[1400], dump[600];
        scratch_path("modes.txt", dump, sizeof dump);
        for (int m = 0; m < 2; m++)
            for (int k = 0; k < 4; k++) {
                snprintf(cmd, sizeof cmd, "h5dump -p -H -d %s '%s' > '%s' 2>&1", names[k], m == 0 ? all : frame,
                         dump);
                assert_int_equal(system(cmd), 0);
                char *text = slurp(dump);
                assert_true((strstr(text, "DEFLATE") != NULL) == deflated[m][k]);
                assert_true((strstr(text, "CONTIGUOUS") != NULL) == !deflated[m][k]);
                free(text);
            }
    }
}

/* A frame of n particles' worth of data for the writer tests. */
static DrH5 *deferred_file(const char *path, long n)
{
    DrError err;
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_create_deferred(path, &h, &err), DR_OK);
    double *x = calloc((size_t)(3 * n), sizeof(double));
    assert_non_null(x);
    for (long i = 0; i < 3 * n; i++) x[i] = sin((double)i);
    uint64_t d[2] = {(uint64_t)n, 3};
    assert_int_equal(dr_h5_write_f64(h, "/water/position", 2, d, x, "m", true, &err), DR_OK);
    free(x);
    return h;
}

static void test_h5_writer_order(void **state)
{
    (void)state;
    DrError err;
    char big[512], small[512];
    scratch_path("order_frame.h5", big, sizeof big);
    scratch_path("order_checkpoint.h5", small, sizeof small);
    for (int pending = 1; pending <= 2; pending++) {
        unlink(big);
        unlink(small);
        DrH5Writer *w = NULL;
        assert_int_equal(dr_h5_writer_create(pending, &w, &err), DR_OK);
        DrH5 *h = deferred_file(big, 400000); /* takes the writer a while */
        assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_OK);
        h = deferred_file(small, 1);
        assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_OK);
        /* the file submitted second is never in place before the first: look as soon as it is */
        for (int i = 0; i < 300000 && !dr_io_exists(small); i++) usleep(200);
        assert_true(dr_io_exists(small));
        assert_true(dr_io_exists(big));
        assert_int_equal(dr_h5_writer_flush(w, &err), DR_OK);
        DrH5WriterStats st;
        dr_h5_writer_stats(w, &st);
        assert_int_equal(st.files, 2);
        dr_h5_writer_destroy(&w);
    }
    /* destroy finishes what is still pending */
    unlink(big);
    DrH5Writer *w = NULL;
    assert_int_equal(dr_h5_writer_create(1, &w, &err), DR_OK);
    DrH5 *h = deferred_file(big, 1000);
    assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_OK);
    dr_h5_writer_destroy(&w);
    assert_true(dr_io_exists(big));
    assert_int_equal(count_tmp_files(g_dir), 0);
}

/* The thread a SIGUSR1 handler ran on, and how often it ran. */
static pthread_t g_signal_thread;
static volatile sig_atomic_t g_signals;

static void on_usr1(int sig)
{
    (void)sig;
    g_signal_thread = pthread_self();
    g_signals++;
}

/* Signals sent to the process while the writer thread runs are handled on this thread (the writer
 * blocks them all), as bake's stop request must be. This thread blocks the signal while it is sent, so
 * that the kernel would hand it to the writer thread if that one let it through; once unblocked here,
 * the pending signal must arrive here. */
static void test_h5_writer_signals(void **state)
{
    (void)state;
    DrError err;
    char path[512];
    scratch_path("signalled.h5", path, sizeof path);
    struct sigaction sa, old;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_usr1;
    sa.sa_flags = SA_RESTART;
    sigemptyset(&sa.sa_mask);
    assert_int_equal(sigaction(SIGUSR1, &sa, &old), 0);
    DrH5Writer *w = NULL;
    assert_int_equal(dr_h5_writer_create(2, &w, &err), DR_OK);
    DrH5 *h = deferred_file(path, 400000); /* busy for a while */
    assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_OK);
    pthread_t self = pthread_self();
    sigset_t usr1;
    sigemptyset(&usr1);
    sigaddset(&usr1, SIGUSR1);
    for (int i = 0; i < 5; i++) {
        g_signals = 0;
        assert_int_equal(pthread_sigmask(SIG_BLOCK, &usr1, NULL), 0);
        assert_int_equal(kill(getpid(), SIGUSR1), 0);
        usleep(2000);
        assert_int_equal(g_signals, 0); /* nobody took it: the writer blocks it */
        assert_int_equal(pthread_sigmask(SIG_UNBLOCK, &usr1, NULL), 0);
        for (int k = 0; k < 10000 && g_signals == 0; k++) usleep(100);
        assert_int_equal(g_signals, 1);
        assert_true(pthread_equal(g_signal_thread, self));
    }
    assert_int_equal(dr_h5_writer_flush(w, &err), DR_OK);
    dr_h5_writer_destroy(&w);
    assert_int_equal(sigaction(SIGUSR1, &old, NULL), 0);
    assert_true(dr_io_exists(path));
}

/* A background failure: the second of three files cannot be written. It surfaces at the next submit
 * or flush as DR_ERR_IO naming that file, its temporary file is gone, the first file is in place and
 * the third was dropped unwritten. Disk full is real: the temporary path is made a link to /dev/full
 * (writes fail with ENOSPC whoever runs the test, root included); without /dev/full, a missing
 * directory. */
static void test_h5_writer_failure(void **state)
{
    (void)state;
    DrError err;
    char first[512], second[512], third[512], tmp[600];
    scratch_path("fail.0001.h5", first, sizeof first);
    bool full = dr_io_exists("/dev/full");
    if (full) {
        scratch_path("fail.0002.h5", second, sizeof second);
        dr_io_tmp_path(second, tmp, sizeof tmp);
        assert_int_equal(symlink("/dev/full", tmp), 0);
    } else {
        snprintf(second, sizeof second, "%s/missing/fail.0002.h5", g_dir);
        dr_io_tmp_path(second, tmp, sizeof tmp);
    }
    scratch_path("fail.0003.h5", third, sizeof third);
    DrH5Writer *w = NULL;
    assert_int_equal(dr_h5_writer_create(2, &w, &err), DR_OK);
    DrH5 *h = deferred_file(first, 1000);
    assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_OK);
    h = deferred_file(second, 100000);
    assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_OK);
    h = deferred_file(third, 1000);
    DrStatus s = dr_h5_writer_submit(w, &h, &err); /* may come before or after the failure */
    assert_null(h);
    dr_error_clear(&err);
    assert_int_equal(dr_h5_writer_flush(w, &err), DR_ERR_IO);
    assert_string_equal(err.file, second);
    assert_true(s == DR_OK || s == DR_ERR_IO);
    assert_true(dr_io_exists(first));
    assert_false(dr_io_exists(second));
    struct stat sb;
    assert_true(lstat(tmp, &sb) != 0); /* the temporary file (here the link) is removed */
    assert_false(dr_io_exists(third));
    /* the failure sticks: later files are dropped and the same failure returned */
    h = deferred_file(third, 10);
    dr_error_clear(&err);
    assert_int_equal(dr_h5_writer_submit(w, &h, &err), DR_ERR_IO);
    assert_null(h);
    assert_string_equal(err.file, second);
    assert_int_equal(dr_h5_writer_flush(w, &err), DR_ERR_IO);
    dr_h5_writer_destroy(&w);
    assert_false(dr_io_exists(third));
    assert_int_equal(count_tmp_files(g_dir), 0);
}


/* ---- checksums ---- */

/* Offset of the first occurrence of `needle` in file `path`, -1 if none. */
static long find_bytes(const char *path, const void *needle, size_t n)
{
    char *text = NULL;
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, 0, SEEK_SET);
    text = malloc((size_t)size);
    assert_int_equal(fread(text, 1, (size_t)size, f), (size_t)size);
    fclose(f);
    long at = -1;
    for (long i = 0; at < 0 && i + (long)n <= size; i++)
        if (memcmp(text + i, needle, n) == 0) at = i;
    free(text);
    return at;
}

static void flip_bit_at(const char *path, long at)
{
    FILE *f = fopen(path, "r+b");
    assert_non_null(f);
    fseek(f, at, SEEK_SET);
    int c = fgetc(f);
    fseek(f, at, SEEK_SET);
    fputc(c ^ 0x01, f);
    fclose(f);
}

/* The sample file of this test: a stored dataset (/a/x, a pattern easy to find on disk), one no reader asks for
 * (/a/unread), a compressed one, an integer one and an empty one. */
static void write_checked(const char *path, double first)
{
    DrError err;
    DrH5 *h = NULL;
    double x[64], unread[64], z[4096] = {0};
    int32_t tri[6] = {0, 1, 2, 2, 1, 3};
    for (int i = 0; i < 64; i++) x[i] = first + 0.125 * i, unread[i] = -1000.0 - i;
    assert_int_equal(dr_h5_create(path, &h, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/a/x", 2, (uint64_t[]){32, 2}, x, "m", false, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/a/unread", 1, (uint64_t[]){64}, unread, "m", false, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/b/zeros", 1, (uint64_t[]){4096}, z, NULL, true, &err), DR_OK);
    assert_int_equal(dr_h5_write_i32(h, "/b/tri", 2, (uint64_t[]){2, 3}, tri, "1", true, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(h, "/b/empty", 2, (uint64_t[]){0, 3}, NULL, "m", false, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
}

/* Every dataset carries the XXH3-128 of its bytes; readers and dr_h5_verify check it. A flipped bit in a dataset
 * (read or not), a dataset rewritten by another tool without its checksum, and one that never had one are refused
 * as DR_ERR_INPUT naming file and dataset; equal data gives equal files. */
static void test_h5_checksums(void **state)
{
    (void)state;
    DrError err;
    char path[512], again[512];
    scratch_path("checked.h5", path, sizeof path);
    scratch_path("checked_again.h5", again, sizeof again);
    write_checked(path, 3.0);
    write_checked(again, 3.0);
    assert_true(same_bytes(path, again));

    DrH5 *h = NULL;
    char *sum = NULL, bad[256];
    double *v = NULL;
    int rank;
    uint64_t dims[4];
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    assert_int_equal(dr_h5_read_attr_str(h, "/a/x", DR_H5_CHECKSUM_ATTR, &sum, &err), DR_OK);
    double x[64];
    for (int i = 0; i < 64; i++) x[i] = 3.0 + 0.125 * i;
    char want[33];
    dr_hash_hex(dr_hash_bytes(x, sizeof x), want);
    assert_string_equal(sum, want);
    free(sum);
    assert_int_equal(dr_h5_read_f64(h, "/a/x", &rank, dims, &v, &err), DR_OK);
    free(v);
    assert_int_equal(dr_h5_verify(h, true, bad, sizeof bad, &err), DR_OK);
    assert_string_equal(bad, "");
    dr_h5_close(&h);

    /* one bit of /a/x flipped: the reader and the verification refuse it */
    long at = find_bytes(path, &x[10], sizeof(double));
    assert_true(at > 0);
    flip_bit_at(path, at);
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    assert_int_equal(dr_h5_read_f64(h, "/a/x", &rank, dims, &v, &err), DR_ERR_INPUT);
    assert_null(v);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "/a/x does not match its checksum"));
    assert_int_equal(dr_h5_verify(h, false, bad, sizeof bad, &err), DR_ERR_INPUT);
    assert_string_equal(bad, "/a/x");
    dr_h5_close(&h);

    /* a bit flipped in a dataset no caller reads: only the whole-file verification sees it */
    write_checked(path, 3.0);
    double u = -1000.0 - 7;
    flip_bit_at(path, find_bytes(path, &u, sizeof u));
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    assert_int_equal(dr_h5_read_f64(h, "/a/x", &rank, dims, &v, &err), DR_OK);
    free(v);
    assert_int_equal(dr_h5_verify(h, false, bad, sizeof bad, &err), DR_ERR_INPUT);
    assert_string_equal(bad, "/a/unread");
    assert_non_null(strstr(err.message, "does not match its checksum"));
    dr_h5_close(&h);

    /* a value edited by another tool (HDF5 directly: its checksum is not updated) */
    write_checked(path, 3.0);
    hid_t f = H5Fopen(path, H5F_ACC_RDWR, H5P_DEFAULT);
    hid_t d = H5Dopen2(f, "/b/tri", H5P_DEFAULT);
    int32_t edited[6] = {0, 1, 2, 2, 1, 4};
    assert_true(H5Dwrite(d, H5T_NATIVE_INT32, H5S_ALL, H5S_ALL, H5P_DEFAULT, edited) >= 0);
    H5Dclose(d);
    /* and a dataset of another program, which has no checksum */
    hid_t space = H5Screate_simple(1, (hsize_t[]){3}, NULL);
    d = H5Dcreate2(f, "/c", H5T_IEEE_F64LE, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    assert_true(H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, (double[]){1, 2, 3}) >= 0);
    H5Dclose(d);
    H5Sclose(space);
    H5Fclose(f);
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    int32_t *t = NULL;
    assert_int_equal(dr_h5_read_i32(h, "/b/tri", &rank, dims, &t, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "/b/tri does not match its checksum"));
    assert_int_equal(dr_h5_read_f64(h, "/c", &rank, dims, &v, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "/c has no checksum"));
    assert_int_equal(dr_h5_verify(h, false, bad, sizeof bad, &err), DR_ERR_INPUT);
    assert_string_equal(bad, "/b/tri"); /* the first in name order */
    dr_h5_close(&h);

    /* finite: a NaN stored under a valid checksum passes the checksum, not the finite check */
    DrH5 *w = NULL;
    double nan3[3] = {1.0, NAN, 2.0};
    assert_int_equal(dr_h5_create(path, &w, &err), DR_OK);
    assert_int_equal(dr_h5_write_f64(w, "/g/v", 1, (uint64_t[]){3}, nan3, NULL, false, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&w, &err), DR_OK);
    assert_int_equal(dr_h5_open(path, &h, &err), DR_OK);
    assert_int_equal(dr_h5_verify(h, false, bad, sizeof bad, &err), DR_OK);
    assert_int_equal(dr_h5_verify(h, true, bad, sizeof bad, &err), DR_ERR_INPUT);
    assert_string_equal(bad, "/g/v");
    assert_non_null(strstr(err.message, "nan at element 1"));
    dr_h5_close(&h);
}

/* A file whose last bytes HDF5 writes on closing cannot be written (a disk that fills up): DR_ERR_IO naming the file,
 * no file and no temporary file left, and the process goes on (HDF5 keeps no half-closed file behind). The temporary
 * path is a link to /dev/full: every write fails there, as on a full disk. */
static void test_h5_full_disk_on_close(void **state)
{
    (void)state;
    if (!dr_io_exists("/dev/full")) {
        print_message("no /dev/full: skipped\n");
        return;
    }
    DrError err;
    char path[512], tmp[600];
    scratch_path("full.h5", path, sizeof path);
    dr_io_tmp_path(path, tmp, sizeof tmp);
    assert_int_equal(symlink("/dev/full", tmp), 0);
    DrH5 *h = NULL;
    assert_int_equal(dr_h5_create(path, &h, &err), DR_OK);
    double v[1000] = {0};
    assert_int_equal(dr_h5_write_f64(h, "/v", 1, (uint64_t[]){1000}, v, NULL, false, &err), DR_OK);
    dr_error_clear(&err);
    assert_int_equal(dr_h5_commit(&h, &err), DR_ERR_IO);
    assert_null(h);
    assert_string_equal(err.file, path);
    assert_non_null(strstr(err.message, "No space left on device"));
    struct stat sb;
    assert_true(lstat(tmp, &sb) != 0);
    assert_false(dr_io_exists(path));
}

/* ---- precompute cache ---- */

static void test_precache(void **state)
{
    (void)state;
    DrError err;
    char root[512], path[DR_IO_PATH_MAX], other[DR_IO_PATH_MAX];
    scratch_path("cache", root, sizeof root);
    const char *key = "00112233445566778899aabbccddeeff";
    const char *inputs = "{\"density\":1000,\"ratio\":32}";
    DrH5 *h = NULL;
    assert_int_equal(dr_io_precache_create(root, "bem", key, inputs, "feedface", &h, &err), DR_OK);
    uint64_t d[2] = {2, 2};
    double m[4] = {1.5, -2.5, 3.25, 1e-17};
    assert_int_equal(dr_h5_write_f64(h, "/matrix", 2, d, m, "m/N", true, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    dr_io_precache_path(root, "bem", key, path, sizeof path);
    snprintf(other, sizeof other, "%s/bem/%s.h5", root, key);
    assert_string_equal(path, other);
    assert_true(dr_io_exists(path));

    bool found = false;
    assert_int_equal(dr_io_precache_open(root, "bem", key, &h, &found, NULL, &err), DR_OK);
    assert_true(found);
    assert_non_null(h);
    const char *names[] = {"kind", "key", "inputs", "asset_hash", "drench_version", "created"};
    const char *values[] = {"bem", key, inputs, "feedface", DR_VERSION, NULL};
    for (int i = 0; i < 6; i++) {
        char *s = NULL;
        assert_int_equal(dr_h5_read_attr_str(h, "/", names[i], &s, &err), DR_OK);
        if (values[i]) assert_string_equal(s, values[i]);
        else assert_int_equal((int)strlen(s), 20); /* YYYY-MM-DDTHH:MM:SSZ */
        free(s);
    }
    int rank;
    uint64_t dims[4];
    double *back = NULL;
    assert_int_equal(dr_h5_read_f64(h, "/matrix", &rank, dims, &back, &err), DR_OK);
    assert_memory_equal(back, m, sizeof m);
    free(back);
    dr_h5_close(&h);

    /* Another key: no file, not found. Another kind: not found. */
    assert_int_equal(dr_io_precache_open(root, "bem", "abcd", &h, &found, NULL, &err), DR_OK);
    assert_false(found);
    assert_null(h);
    assert_int_equal(dr_io_precache_open(root, "cohesion", key, &h, &found, NULL, &err), DR_OK);
    assert_false(found);

    /* A file whose recorded key differs from its name is not trusted. */
    dr_log_set_level(DR_LOG_ERROR); /* the warnings below are expected */
    dr_io_precache_path(root, "bem", "abcd", other, sizeof other);
    assert_int_equal(rename(path, other), 0);
    assert_int_equal(dr_io_precache_open(root, "bem", "abcd", &h, &found, NULL, &err), DR_OK);
    assert_false(found);
    assert_null(h);
    /* Nor is a corrupt one. */
    dr_io_precache_path(root, "bem", "ef01", other, sizeof other);
    assert_int_equal(dr_io_write_text_atomic(other, "truncated", &err), DR_OK);
    assert_int_equal(dr_io_precache_open(root, "bem", "ef01", &h, &found, NULL, &err), DR_OK);
    assert_false(found);
    assert_null(h);
    dr_log_set_level(DR_LOG_INFO);

    /* Cohesion table without an asset; bad kinds and keys are refused. */
    assert_int_equal(dr_io_precache_create(root, "cohesion", "42", "{}", NULL, &h, &err), DR_OK);
    assert_int_equal(dr_h5_commit(&h, &err), DR_OK);
    assert_int_equal(dr_io_precache_open(root, "cohesion", "42", &h, &found, NULL, &err), DR_OK);
    assert_true(found);
    char *s = NULL;
    assert_int_equal(dr_h5_read_attr_str(h, "/", "asset_hash", &s, &err), DR_OK);
    assert_string_equal(s, "");
    free(s);
    dr_h5_close(&h);
    assert_int_equal(dr_io_precache_create(root, "fluid", key, "{}", NULL, &h, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "\"fluid\""));
    assert_int_equal(dr_io_precache_create(root, "bem", "../evil", "{}", NULL, &h, &err), DR_ERR_INPUT);
    assert_int_equal(dr_io_precache_open(root, "bem", "", &h, &found, NULL, &err), DR_ERR_INPUT);
    assert_null(h);
    char bemdir[600];
    snprintf(bemdir, sizeof bemdir, "%s/bem", root);
    assert_int_equal(count_tmp_files(bemdir), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_load_cube_formats),
        cmocka_unit_test(test_load_sphere_and_ground),
        cmocka_unit_test(test_load_bad_meshes),
        cmocka_unit_test(test_write_obj_round_trip),
        cmocka_unit_test(test_texture_coordinates),
        cmocka_unit_test(test_polylines_round_trip),
        cmocka_unit_test(test_polylines_read_other_writers),
        cmocka_unit_test(test_polylines_read_desc),
        cmocka_unit_test(test_polylines_bad_files),
        cmocka_unit_test(test_polylines_outer_radius),
        cmocka_unit_test(test_files),
        cmocka_unit_test(test_remove_stale_tmp),
        cmocka_unit_test(test_manifest),
        cmocka_unit_test(test_h5_round_trip),
        cmocka_unit_test(test_h5_abandon_and_bad_files),
        cmocka_unit_test(test_h5_deferred_identical),
        cmocka_unit_test(test_h5_deferred_checks),
        cmocka_unit_test(test_h5_compress_modes),
        cmocka_unit_test(test_h5_writer_order),
        cmocka_unit_test(test_h5_writer_signals),
        cmocka_unit_test(test_h5_writer_failure),
        cmocka_unit_test(test_h5_checksums),
        cmocka_unit_test(test_h5_full_disk_on_close),
        cmocka_unit_test(test_precache),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
