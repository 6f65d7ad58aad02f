/* Unit tests of src/render: silhouettes against the exact projection, background, PNG files, camera checks,
 * liquid and shadows, strands (wet ones too), determinism across thread counts, contact sheets, resizing and text. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "core/core.h"
#include "render/render.h"

#include <dirent.h>
#include <png.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static char g_dir[256]; /* scratch directory of this run */

static int group_setup(void **state)
{
    (void)state;
    snprintf(g_dir, sizeof g_dir, "%s/drench_test_render.XXXXXX", dr_temp_dir());
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

/* ---- geometry -------------------------------------------------------------------------------------- */

/* Axis-aligned box, 8 shared corners, 12 triangles counter-clockwise seen from outside. */
static DrTriMesh make_box(DrVec3 lo, DrVec3 hi)
{
    DrTriMesh m = {.nv = 8, .nt = 12};
    m.v = calloc(24, sizeof *m.v);
    m.tri = calloc(36, sizeof *m.tri);
    assert_non_null(m.v);
    assert_non_null(m.tri);
    for (int k = 0; k < 8; k++) {
        m.v[3 * k] = k & 1 ? hi.x : lo.x;
        m.v[3 * k + 1] = k & 2 ? hi.y : lo.y;
        m.v[3 * k + 2] = k & 4 ? hi.z : lo.z;
    }
    static const int f[12][3] = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    memcpy(m.tri, f, sizeof f);
    return m;
}

/* UV sphere of nu × nv quads (poles repeated per column; degenerate pole triangles are harmless). */
static DrTriMesh make_sphere(DrVec3 c, double r, int nu, int nv)
{
    DrTriMesh m = {.nv = nu * (nv + 1), .nt = 2 * nu * nv};
    m.v = calloc(3 * (size_t)m.nv, sizeof *m.v);
    m.tri = calloc(3 * (size_t)m.nt, sizeof *m.tri);
    assert_non_null(m.v);
    assert_non_null(m.tri);
    for (int j = 0; j <= nv; j++)
        for (int i = 0; i < nu; i++) {
            double th = DR_PI * j / nv, ph = 2 * DR_PI * i / nu;
            double *p = m.v + 3 * (j * nu + i);
            p[0] = c.x + r * sin(th) * cos(ph);
            p[1] = c.y + r * cos(th);
            p[2] = c.z - r * sin(th) * sin(ph);
        }
    int t = 0;
    for (int j = 0; j < nv; j++)
        for (int i = 0; i < nu; i++) {
            int a = j * nu + i, b = j * nu + (i + 1) % nu, d = (j + 1) * nu + i, e = (j + 1) * nu + (i + 1) % nu;
            int *q = m.tri + 3 * t;
            q[0] = a, q[1] = d, q[2] = b, q[3] = b, q[4] = d, q[5] = e;
            t += 2;
        }
    return m;
}

static void add_mesh(DrRenderScene *s, DrTriMesh m, DrRenderMaterial mat)
{
    DrError err;
    assert_int_equal(dr_render_scene_add_mesh(s, &m, mat, &err), DR_OK);
    dr_trimesh_free(&m); /* the scene keeps its own copy */
}

static DrRenderScene *new_scene(void)
{
    DrRenderScene *s = NULL;
    DrError err;
    assert_int_equal(dr_render_scene_create(&s, &err), DR_OK);
    assert_non_null(s);
    return s;
}

static DrCamera camera(DrVec3 eye, DrVec3 target, DrVec3 up, double fov, int w, int h)
{
    DrCamera c = {.eye = eye, .target = target, .up = up, .fov_deg = fov, .width = w, .height = h};
    return c;
}

static DrImage render(const DrRenderScene *s, const DrCamera *cam, const DrRenderDesc *desc)
{
    DrImage img;
    DrError err;
    DrStatus st = dr_render_image(s, cam, desc, &img, &err);
    if (st != DR_OK) dr_error_print("test_render", &err);
    assert_int_equal(st, DR_OK);
    assert_int_equal(img.width, cam->width);
    assert_int_equal(img.height, cam->height);
    return img;
}

static const uint8_t *px(const DrImage *img, int i, int j) { return img->rgb + 3 * ((size_t)j * img->width + i); }

static bool is_background(const DrImage *img, const DrCamera *cam, int i, int j)
{
    uint8_t bg[3];
    dr_render_background(cam, j, bg);
    return memcmp(px(img, i, j), bg, 3) == 0;
}

/* ---- 1. silhouettes ------------------------------------------------------------------------------------ */

typedef struct P2 {
    double x, y;
} P2;

static double cross2(P2 o, P2 a, P2 b) { return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x); }

static int cmp_p2(const void *a, const void *b)
{
    const P2 *p = a, *q = b;
    return p->x < q->x ? -1 : p->x > q->x ? 1 : (p->y < q->y ? -1 : p->y > q->y);
}

/* Andrew's monotone chain; hull in counter-clockwise order (in a y-up sense), returns its size. */
static int convex_hull(P2 *p, int n, P2 *h)
{
    qsort(p, (size_t)n, sizeof *p, cmp_p2);
    int k = 0;
    for (int i = 0; i < n; i++) {
        while (k >= 2 && cross2(h[k - 2], h[k - 1], p[i]) <= 0) k--;
        h[k++] = p[i];
    }
    for (int i = n - 2, t = k + 1; i >= 0; i--) {
        while (k >= t && cross2(h[k - 2], h[k - 1], p[i]) <= 0) k--;
        h[k++] = p[i];
    }
    return k - 1;
}

static double seg_dist(P2 p, P2 a, P2 b)
{
    double dx = b.x - a.x, dy = b.y - a.y, l2 = dx * dx + dy * dy;
    double t = l2 > 0 ? ((p.x - a.x) * dx + (p.y - a.y) * dy) / l2 : 0.0;
    t = t < 0 ? 0 : (t > 1 ? 1 : t);
    return hypot(p.x - a.x - t * dx, p.y - a.y - t * dy);
}

/* Signed distance of p to the convex polygon h[0..n): positive inside. */
static double hull_signed_dist(const P2 *h, int n, P2 p)
{
    bool inside = true;
    double d = 1e300;
    for (int i = 0; i < n; i++) {
        P2 a = h[i], b = h[(i + 1) % n];
        if (cross2(a, b, p) < 0) inside = false;
        double s = seg_dist(p, a, b);
        d = s < d ? s : d;
    }
    return inside ? d : -d;
}

static void check_cube_silhouette(DrCamera cam)
{
    DrRenderScene *s = new_scene();
    add_mesh(s, make_box(dr_v3(-0.5, -0.5, -0.5), dr_v3(0.5, 0.5, 0.5)), DR_MATERIAL_COLLIDER);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    desc.shadows = true;
    DrImage img = render(s, &cam, &desc);

    P2 pts[8], hull[9];
    for (int k = 0; k < 8; k++) {
        DrVec3 c = dr_v3(k & 1 ? 0.5 : -0.5, k & 2 ? 0.5 : -0.5, k & 4 ? 0.5 : -0.5);
        double depth;
        assert_true(dr_camera_project(&cam, c, &pts[k].x, &pts[k].y, &depth));
        assert_true(depth > 0);
    }
    int n = convex_hull(pts, 8, hull);
    assert_true(n >= 4);
    double hx0 = 1e300, hx1 = -1e300, hy0 = 1e300, hy1 = -1e300;
    for (int i = 0; i < n; i++) {
        hx0 = fmin(hx0, hull[i].x), hx1 = fmax(hx1, hull[i].x);
        hy0 = fmin(hy0, hull[i].y), hy1 = fmax(hy1, hull[i].y);
    }
    int bx0 = img.width, bx1 = -1, by0 = img.height, by1 = -1, inside = 0;
    for (int j = 0; j < img.height; j++)
        for (int i = 0; i < img.width; i++) {
            double d = hull_signed_dist(hull, n, (P2){i + 0.5, j + 0.5});
            bool bg = is_background(&img, &cam, i, j);
            /* one pixel of slack either side: supersamples of a pixel straddling the outline may go either way */
            if (d > 1.0) {
                inside++;
                if (bg) fail_msg("pixel (%d, %d), %.2f px inside the cube's outline, is background", i, j, d);
            }
            if (d < -1.0 && !bg)
                fail_msg("pixel (%d, %d), %.2f px outside the cube's outline, is not background", i, j, -d);
            if (!bg) {
                bx0 = i < bx0 ? i : bx0, bx1 = i > bx1 ? i : bx1;
                by0 = j < by0 ? j : by0, by1 = j > by1 ? j : by1;
            }
        }
    assert_true(inside > 100); /* the cube is in view, not a sliver */
    /* extent: the rendered box spans the pixels holding the hull's extremes, within one pixel */
    assert_true(abs(bx0 - (int)floor(hx0)) <= 1 && abs(bx1 - (int)floor(hx1)) <= 1);
    assert_true(abs(by0 - (int)floor(hy0)) <= 1 && abs(by1 - (int)floor(hy1)) <= 1);
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
}

static void test_silhouette(void **state)
{
    (void)state;
    check_cube_silhouette(camera(dr_v3(0.3, 0.8, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 320, 240));
    /* rolled camera: up tilted towards x, seen from another side */
    check_cube_silhouette(camera(dr_v3(2.2, 1.4, -1.6), dr_v3(0.1, 0, 0), dr_v3(1, 1, 0.2), 35, 320, 240));
    /* wide angle from close by, strong perspective, odd size */
    check_cube_silhouette(camera(dr_v3(0.4, -0.7, 1.3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 100, 257, 199));
}

/* ---- 2. empty scene ------------------------------------------------------------------------------------- */

static void test_empty_scene(void **state)
{
    (void)state;
    DrRenderScene *s = new_scene();
    DrVec3 lo, hi;
    assert_false(dr_render_scene_bounds(s, &lo, &hi));
    DrCamera cam = camera(dr_v3(0, 1, 3), dr_v3(0, 0.8, 0), dr_v3(0, 1, 0), 50, 200, 150);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    DrImage img = render(s, &cam, &desc);
    for (int j = 0; j < img.height; j++)
        for (int i = 0; i < img.width; i++) assert_true(is_background(&img, &cam, i, j));
    /* the gradient is a gradient: top and bottom rows differ */
    uint8_t top[3], bottom[3];
    dr_render_background(&cam, 0, top);
    dr_render_background(&cam, img.height - 1, bottom);
    assert_memory_not_equal(top, bottom, 3);
    dr_image_free(&img);

    /* with the ground: sky above the horizon (exactly the background), ground below it */
    desc.ground = true;
    img = render(s, &cam, &desc);
    double hx, hy, depth;
    DrVec3 f = dr_v3_sub(cam.target, cam.eye);
    DrVec3 far = dr_v3_add(cam.eye, dr_v3_scale(dr_v3_normalize(dr_v3(f.x, 0, f.z)), 1e6)); /* on the horizon */
    assert_true(dr_camera_project(&cam, far, &hx, &hy, &depth));
    assert_true(hy > 10 && hy < img.height - 20);
    int sky_rows = 0, ground_rows = 0;
    for (int j = 0; j < img.height; j++)
        for (int i = 0; i < img.width; i++) {
            if (j + 1.0 < hy - 1.0) {
                sky_rows += i == 0;
                assert_true(is_background(&img, &cam, i, j));
            }
            /* far below the horizon: the fog that blends the ground into the horizon has not taken over */
            if (j > hy + 10.0) {
                ground_rows += i == 0;
                assert_false(is_background(&img, &cam, i, j));
            }
        }
    assert_true(sky_rows > 5 && ground_rows > 5);
    dr_image_free(&img);
    /* the ground is seen only from above: from under it, the background */
    cam.eye.y = -1;
    img = render(s, &cam, &desc);
    for (int j = 0; j < img.height; j++)
        for (int i = 0; i < img.width; i++) assert_true(is_background(&img, &cam, i, j));
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
}

/* ---- 3. PNG files ------------------------------------------------------------------------------------------ */

static void test_png_round_trip(void **state)
{
    (void)state;
    DrError err;
    static const uint8_t fill[3] = {1, 2, 3};
    DrImage img, back;
    assert_int_equal(dr_image_create(37, 23, fill, &img, &err), DR_OK);
    assert_int_equal(px(&img, 36, 22)[2], 3);
    for (int j = 0; j < 23; j++)
        for (int i = 0; i < 37; i++)
            for (int c = 0; c < 3; c++) img.rgb[3 * (j * 37 + i) + c] = (uint8_t)(i * 7 + j * 13 + c * 50);
    char path[512];
    snprintf(path, sizeof path, "%s/round.png", g_dir);
    assert_int_equal(dr_image_write_png(path, &img, &err), DR_OK);
    assert_int_equal(dr_image_read_png(path, &back, &err), DR_OK);
    assert_int_equal(back.width, 37);
    assert_int_equal(back.height, 23);
    assert_memory_equal(back.rgb, img.rgb, 3 * 37 * 23);
    assert_int_equal(count_tmp_files(g_dir), 0);
    dr_image_free(&back);

    /* a missing directory: DR_ERR_IO naming the file, nothing left behind */
    char missing[600];
    snprintf(missing, sizeof missing, "%s/no/such/dir/x.png", g_dir);
    assert_int_equal(dr_image_write_png(missing, &img, &err), DR_ERR_IO);
    assert_string_equal(err.file, missing);
    assert_int_equal(access(missing, F_OK), -1);
    assert_int_equal(count_tmp_files(g_dir), 0);

    /* truncated, garbage, missing: DR_ERR_INPUT naming the file, nothing returned */
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    uint8_t bytes[8192];
    size_t n = fread(bytes, 1, sizeof bytes, f);
    fclose(f);
    assert_true(n > 100 && n < sizeof bytes);
    const char *names[3] = {"trunc.png", "garbage.png", "absent.png"};
    for (int k = 0; k < 3; k++) {
        char bad[600];
        snprintf(bad, sizeof bad, "%s/%s", g_dir, names[k]);
        if (k < 2) {
            f = fopen(bad, "wb");
            assert_non_null(f);
            if (k == 0) fwrite(bytes, 1, n / 2, f);
            else fputs("this is not a PNG file at all, only words", f);
            fclose(f);
        }
        back = (DrImage){.width = 5};
        assert_int_equal(dr_image_read_png(bad, &back, &err), DR_ERR_INPUT);
        assert_string_equal(err.file, bad);
        assert_true(strlen(err.message) > 10);
        assert_null(back.rgb);
        assert_int_equal(back.width, 0);
    }
    dr_image_free(&img);
    dr_image_free(&img); /* a zeroed image is a no-op */

    assert_int_equal(dr_image_create(0, 5, fill, &img, &err), DR_ERR_INPUT);
    assert_int_equal(dr_image_create(5, 65536, fill, &img, &err), DR_ERR_INPUT);
}

/* Writes a 2×1 PNG of another colour type with libpng directly: `row` holds the packed row. */
static void write_raw_png(const char *path, int color_type, int bit_depth, const uint8_t *row, const png_color *pal,
                          int npal, const uint8_t *trns, int ntrns)
{
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png_create_info_struct(png);
    assert_non_null(png);
    assert_non_null(info);
    png_init_io(png, f);
    png_set_IHDR(png, info, 2, 1, bit_depth, color_type, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
                 PNG_FILTER_TYPE_DEFAULT);
    if (pal) png_set_PLTE(png, info, pal, npal);
    if (trns) png_set_tRNS(png, info, trns, ntrns, NULL);
    png_write_info(png, info);
    png_write_row(png, row);
    png_write_end(png, info);
    png_destroy_write_struct(&png, &info);
    fclose(f);
}

/* Grey, grey+alpha 16-bit, palette with transparency and RGBA all come back as 8-bit RGB. */
static void test_png_other_formats(void **state)
{
    (void)state;
    char path[512];
    snprintf(path, sizeof path, "%s/other.png", g_dir);
    DrImage img;
    DrError err;
    static const uint8_t grey[2] = {0, 200};
    write_raw_png(path, PNG_COLOR_TYPE_GRAY, 8, grey, NULL, 0, NULL, 0);
    assert_int_equal(dr_image_read_png(path, &img, &err), DR_OK);
    static const uint8_t want_grey[6] = {0, 0, 0, 200, 200, 200};
    assert_memory_equal(img.rgb, want_grey, 6);
    dr_image_free(&img);
    static const uint8_t ga16[8] = {0x12, 0x34, 0xff, 0xff, 0xab, 0xcd, 0x00, 0x00}; /* big-endian samples */
    write_raw_png(path, PNG_COLOR_TYPE_GRAY_ALPHA, 16, ga16, NULL, 0, NULL, 0);
    assert_int_equal(dr_image_read_png(path, &img, &err), DR_OK);
    assert_int_equal(img.width, 2);
    for (int c = 0; c < 3; c++) {
        /* 16 to 8 bits: the high byte, or the rounded value, depending on libpng's choice: within 1 */
        assert_true(abs(img.rgb[c] - 0x12) <= 1);
        assert_true(abs(img.rgb[3 + c] - 0xab) <= 1);
    }
    dr_image_free(&img);
    static const png_color pal[2] = {{10, 20, 30}, {250, 128, 1}};
    static const uint8_t trns[1] = {0}, idx[1] = {0x01}; /* two 4-bit indices, high nibble first: 0, 1 */
    write_raw_png(path, PNG_COLOR_TYPE_PALETTE, 4, idx, pal, 2, trns, 1);
    assert_int_equal(dr_image_read_png(path, &img, &err), DR_OK);
    static const uint8_t want_pal[6] = {10, 20, 30, 250, 128, 1}; /* transparency dropped, colours kept */
    assert_memory_equal(img.rgb, want_pal, 6);
    dr_image_free(&img);
    static const uint8_t rgba[8] = {1, 2, 3, 0, 4, 5, 6, 255};
    write_raw_png(path, PNG_COLOR_TYPE_RGBA, 8, rgba, NULL, 0, NULL, 0);
    assert_int_equal(dr_image_read_png(path, &img, &err), DR_OK);
    static const uint8_t want_rgba[6] = {1, 2, 3, 4, 5, 6};
    assert_memory_equal(img.rgb, want_rgba, 6);
    dr_image_free(&img);
}

/* ---- 4. camera and desc checks ---------------------------------------------------------------------------- */

static void expect_camera_error(DrCamera cam, const char *field)
{
    DrError err;
    assert_int_equal(dr_camera_check(&cam, &err), DR_ERR_INPUT);
    if (!strstr(err.message, field)) fail_msg("message \"%s\" does not name %s", err.message, field);
    /* dr_render_image refuses it the same way and returns no image */
    DrRenderScene *s = new_scene();
    DrRenderDesc desc = dr_render_desc_default();
    DrImage img = {.width = 3};
    assert_int_equal(dr_render_image(s, &cam, &desc, &img, &err), DR_ERR_INPUT);
    assert_null(img.rgb);
    dr_render_scene_destroy(&s);
}

static void test_camera_checks(void **state)
{
    (void)state;
    DrCamera good = camera(dr_v3(0, 1, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 64, 48);
    DrError err;
    assert_int_equal(dr_camera_check(&good, &err), DR_OK);
    DrCamera c = good;
    c.target = c.eye;
    expect_camera_error(c, "eye");
    c = good;
    c.up = dr_v3(0, -2, -6); /* parallel to target - eye = (0, -1, -3) */
    expect_camera_error(c, "up");
    c.up = dr_v3(0, 0, 0);
    expect_camera_error(c, "up");
    c = good;
    c.fov_deg = 0;
    expect_camera_error(c, "fov_deg");
    c.fov_deg = 180;
    expect_camera_error(c, "fov_deg");
    c.fov_deg = NAN;
    expect_camera_error(c, "fov_deg");
    c = good;
    c.width = 0;
    expect_camera_error(c, "width");
    c = good;
    c.height = -3;
    expect_camera_error(c, "height");
    c = good;
    c.eye.x = INFINITY;
    expect_camera_error(c, "eye");

    /* projection: the target lands on the image centre at its distance; a point behind the eye does not project */
    double x, y, d;
    assert_true(dr_camera_project(&good, good.target, &x, &y, &d));
    assert_true(fabs(x - 32) < 1e-9 && fabs(y - 24) < 1e-9 && fabs(d - sqrt(10.0)) < 1e-12);
    assert_true(dr_camera_project(&good, dr_v3(0, 1.5, 0), &x, &y, &d));
    assert_true(y < 24); /* above the target: up the image */
    assert_false(dr_camera_project(&good, dr_v3(0, 1, 4), &x, &y, &d));

    /* bad desc fields */
    DrRenderScene *s = new_scene();
    DrImage img;
    DrRenderDesc desc = dr_render_desc_default();
    assert_int_equal(desc.samples, 3);
    assert_true(desc.ground && desc.shadows && desc.ground_height == 0.0 && desc.threads == 0);
    desc.samples = 0;
    assert_int_equal(dr_render_image(s, &good, &desc, &img, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "samples"));
    desc.samples = 9;
    assert_int_equal(dr_render_image(s, &good, &desc, &img, &err), DR_ERR_INPUT);
    desc = dr_render_desc_default();
    desc.light_dir = dr_v3(0, 0, 0);
    assert_int_equal(dr_render_image(s, &good, &desc, &img, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "light_dir"));
    desc = dr_render_desc_default();
    desc.threads = -1;
    assert_int_equal(dr_render_image(s, &good, &desc, &img, &err), DR_ERR_INPUT);
    dr_render_scene_destroy(&s);
}

static void test_camera_inside_geometry(void **state)
{
    (void)state;
    DrRenderScene *s = new_scene();
    add_mesh(s, make_box(dr_v3(-0.5, -0.5, -0.5), dr_v3(0.5, 0.5, 0.5)), DR_MATERIAL_COLLIDER);
    add_mesh(s, make_sphere(dr_v3(0.1, 0, 0), 0.3, 24, 12), DR_MATERIAL_LIQUID);
    DrRenderDesc desc = dr_render_desc_default();
    /* eye at the centre of the cube and of the liquid; then on a face, where triangles cross the near plane */
    DrCamera cams[2] = {camera(dr_v3(0, 0, 0), dr_v3(0.3, 0.2, -1), dr_v3(0, 1, 0), 90, 96, 64),
                        camera(dr_v3(0.1, 0.05, 0.5), dr_v3(-0.3, -0.1, -1), dr_v3(0, 1, 0), 120, 96, 64)};
    for (int c = 0; c < 2; c++) {
        desc.threads = 1;
        DrImage a = render(s, &cams[c], &desc);
        desc.threads = 0;
        DrImage b = render(s, &cams[c], &desc);
        assert_memory_equal(a.rgb, b.rgb, 3 * (size_t)a.width * a.height);
        if (c == 0) /* a closed box all around: every pixel sees its inside (two-sided), none the sky */
            for (int j = 0; j < a.height; j++)
                for (int i = 0; i < a.width; i++) assert_false(is_background(&a, &cams[c], i, j));
        dr_image_free(&a);
        dr_image_free(&b);
    }
    dr_render_scene_destroy(&s);
}

/* A floor quad reaching far behind the camera: its triangles cross the near plane and must be clipped there
 * (projecting corners behind the eye would fold them across the sky). The floor ends at z = -50, so the image
 * is floor below that edge's row and sky above it. */
static void test_near_plane_clipping(void **state)
{
    (void)state;
    DrRenderScene *s = new_scene();
    DrTriMesh q = {.nv = 4, .nt = 2};
    double v[12] = {-50, 0, -50, 50, 0, -50, 50, 0, 50, -50, 0, 50};
    int t[6] = {0, 2, 1, 0, 3, 2};
    q.v = v, q.tri = t;
    DrError err;
    assert_int_equal(dr_render_scene_add_mesh(s, &q, DR_MATERIAL_COLLIDER, &err), DR_OK);
    DrCamera cam = camera(dr_v3(0, 1, 0), dr_v3(0, 0.6, -3), dr_v3(0, 1, 0), 60, 160, 120);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    DrImage img = render(s, &cam, &desc);
    double ex, ey, d;
    assert_true(dr_camera_project(&cam, dr_v3(0, 0, -50), &ex, &ey, &d));
    assert_true(ey > 10 && ey < 110);
    for (int j = 0; j < img.height; j++)
        for (int i = 0; i < img.width; i++) {
            /* the far edge is straight across the image (the camera has no roll): one pixel of slack */
            if (j + 1.0 < ey - 1.0 && !is_background(&img, &cam, i, j)) fail_msg("sky pixel (%d, %d) is covered", i, j);
            if (j > ey + 1.0 && is_background(&img, &cam, i, j)) fail_msg("floor pixel (%d, %d) is not covered", i, j);
        }
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
}

/* Watertight edges: a fan of 16 triangles around a centre that projects exactly onto a sample (1 sample per
 * pixel, odd size), so its spokes run through sample centres; every pixel inside the disc must be covered. */
static void test_watertight_fan(void **state)
{
    (void)state;
    enum { N = 16 };
    DrTriMesh m = {.nv = N + 1, .nt = N};
    double v[3 * (N + 1)] = {0};
    int t[3 * N];
    for (int k = 0; k < N; k++) {
        v[3 * (k + 1)] = cos(2 * DR_PI * k / N), v[3 * (k + 1) + 1] = sin(2 * DR_PI * k / N);
        t[3 * k] = 0, t[3 * k + 1] = k + 1, t[3 * k + 2] = (k + 1) % N + 1;
    }
    m.v = v, m.tri = t;
    DrRenderScene *s = new_scene();
    DrError err;
    assert_int_equal(dr_render_scene_add_mesh(s, &m, DR_MATERIAL_SOLID, &err), DR_OK);
    DrCamera cam = camera(dr_v3(0, 0, 5), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 30, 101, 101);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    desc.samples = 1;
    DrImage img = render(s, &cam, &desc);
    double cx, cy, rx, ry, d;
    assert_true(dr_camera_project(&cam, dr_v3(0, 0, 0), &cx, &cy, &d));
    assert_true(dr_camera_project(&cam, dr_v3(cos(DR_PI / N), 0, 0), &rx, &ry, &d)); /* inner radius of the 16-gon */
    int checked = 0;
    for (int j = 0; j < img.height; j++)
        for (int i = 0; i < img.width; i++)
            if (hypot(i + 0.5 - cx, j + 0.5 - cy) < rx - cx - 1.0) {
                checked++;
                if (is_background(&img, &cam, i, j)) fail_msg("crack at pixel (%d, %d)", i, j);
            }
    assert_true(checked > 1000);
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
}

/* Joined box corners carry diagonal normals; faces must still shade flat (crease detection), not as a
 * gradient across the face. */
static void test_box_faces_flat(void **state)
{
    (void)state;
    DrRenderScene *s = new_scene();
    add_mesh(s, make_box(dr_v3(-0.5, -0.5, -0.5), dr_v3(0.5, 0.5, 0.5)), DR_MATERIAL_COLLIDER);
    DrCamera cam = camera(dr_v3(0, 0, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 30, 120, 120);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    desc.light_dir = dr_v3(-0.3, -0.4, -1); /* lights the front face at an angle a smooth normal would vary */
    DrImage img = render(s, &cam, &desc);
    double x0, y0, x1, y1, d;
    assert_true(dr_camera_project(&cam, dr_v3(-0.5, 0.5, 0.5), &x0, &y0, &d));
    assert_true(dr_camera_project(&cam, dr_v3(0.5, -0.5, 0.5), &x1, &y1, &d));
    const uint8_t *ref = px(&img, 60, 60);
    for (int j = (int)y0 + 2; j < (int)y1 - 2; j++)
        for (int i = (int)x0 + 2; i < (int)x1 - 2; i++)
            for (int c = 0; c < 3; c++)
                if (abs(px(&img, i, j)[c] - ref[c]) > 1) fail_msg("front face not flat at (%d, %d)", i, j);
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
}

/* ---- 5. liquid -------------------------------------------------------------------------------------------- */

static void centre_colour(DrRenderMaterial mat, bool ground, int rgb[3])
{
    DrRenderScene *s = new_scene();
    add_mesh(s, make_sphere(dr_v3(0, 0, 0), 0.5, 48, 24), mat);
    DrCamera cam = camera(dr_v3(0, 0.4, 2.5), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 160, 120);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = ground;
    desc.ground_height = -0.5;
    DrImage img = render(s, &cam, &desc);
    for (int c = 0; c < 3; c++) rgb[c] = px(&img, 80, 60)[c];
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
}

static void test_liquid_reads_as_water(void **state)
{
    (void)state;
    for (int g = 0; g < 2; g++) {
        int liq[3], col[3];
        centre_colour(DR_MATERIAL_LIQUID, g, liq);
        centre_colour(DR_MATERIAL_COLLIDER, g, col);
        int diff = abs(liq[0] - col[0]) + abs(liq[1] - col[1]) + abs(liq[2] - col[2]);
        if (diff < 60) fail_msg("liquid (%d %d %d) and collider (%d %d %d) look alike", liq[0], liq[1], liq[2], col[0],
                                col[1], col[2]);
        /* water absorbs red first: its green and blue stand far above red, more than on the grey-blue collider */
        double ql = (liq[1] + liq[2]) / (2.0 * liq[0] + 1.0), qc = (col[1] + col[2]) / (2.0 * col[0] + 1.0);
        if (!(ql > 1.3 * qc)) fail_msg("liquid (%d %d %d) is not bluer-greener than the collider (%d %d %d)", liq[0],
                                       liq[1], liq[2], col[0], col[1], col[2]);
    }

    /* a collider behind a liquid slab shows through it */
    DrCamera cam = camera(dr_v3(0, 0.3, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 120, 90);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    DrImage img[2];
    for (int k = 0; k < 2; k++) {
        DrRenderScene *s = new_scene();
        add_mesh(s, make_box(dr_v3(-1, -1, -0.1), dr_v3(1, 1, 0.1)), DR_MATERIAL_LIQUID);
        if (k == 0) add_mesh(s, make_box(dr_v3(-0.3, -0.3, -0.9), dr_v3(0.3, 0.3, -0.4)), DR_MATERIAL_COLLIDER);
        img[k] = render(s, &cam, &desc);
        dr_render_scene_destroy(&s);
    }
    const uint8_t *a = px(&img[0], 60, 45), *b = px(&img[1], 60, 45);
    int diff = abs(a[0] - b[0]) + abs(a[1] - b[1]) + abs(a[2] - b[2]);
    if (diff < 15) fail_msg("the collider behind the liquid is not visible (%d %d %d vs %d %d %d)", a[0], a[1], a[2],
                            b[0], b[1], b[2]);
    /* and the slab itself is not the background */
    assert_false(is_background(&img[1], &cam, 60, 45));
    dr_image_free(&img[0]);
    dr_image_free(&img[1]);
}

/* ---- 5b. sizes fixed for a sequence, wall panels ------------------------------------------------------------- */

static int colour_diff(const uint8_t *a, const uint8_t *b) { return abs(a[0] - b[0]) + abs(a[1] - b[1]) + abs(a[2] - b[2]); }

/* A shot's frames draw what moves: with desc.scene_size and liquid_size given, the ground far from a cube and the
 * colour through a liquid slab do not change when something else (a splash far away) widens what is drawn; measured
 * from what is drawn (0), both change, which flickered the checker and tinted spreading water paler frame by frame. */
static void test_fixed_sizes(void **state)
{
    (void)state;
    DrCamera cam = camera(dr_v3(0, 0.8, 2.5), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 50, 160, 90);
    for (int fixed = 0; fixed < 2; fixed++) {
        DrRenderDesc desc = dr_render_desc_default();
        desc.ground_height = -0.3;
        if (fixed) desc.scene_size = 2.0, desc.liquid_size = 1.0;
        DrImage img[2];
        for (int k = 0; k < 2; k++) {
            DrRenderScene *s = new_scene();
            add_mesh(s, make_box(dr_v3(-0.2, -0.3, -0.2), dr_v3(0.2, 0.1, 0.2)), DR_MATERIAL_LIQUID);
            add_mesh(s, make_box(dr_v3(-1.0, -0.3, -0.5), dr_v3(-0.8, -0.1, -0.3)), DR_MATERIAL_COLLIDER);
            /* a splash far off to the right and back, out of view: only the bounds see it */
            if (k) add_mesh(s, make_box(dr_v3(6.0, -0.3, -6.0), dr_v3(6.1, -0.2, -5.9)), DR_MATERIAL_LIQUID);
            img[k] = render(s, &cam, &desc);
            dr_render_scene_destroy(&s);
        }
        int ground = 0, liquid = colour_diff(px(&img[0], 80, 48), px(&img[1], 80, 48));
        for (int j = 60; j < 90; j++)
            for (int i = 0; i < 40; i++) ground += colour_diff(px(&img[0], i, j), px(&img[1], i, j));
        print_message("%s sizes: ground region differs by %d, liquid centre by %d\n", fixed ? "fixed" : "measured",
                      ground, liquid);
        if (fixed) {
            assert_int_equal(ground, 0);
            assert_int_equal(liquid, 0);
        } else {
            assert_true(ground > 0 && liquid > 0); /* what the stage's fixed sizes are for */
        }
        dr_image_free(&img[0]);
        dr_image_free(&img[1]);
    }
    DrRenderDesc bad = dr_render_desc_default();
    bad.scene_size = -1.0;
    DrRenderScene *s = new_scene();
    DrImage img;
    DrError err;
    assert_int_equal(dr_render_image(s, &cam, &bad, &img, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "scene_size"));
    dr_render_scene_destroy(&s);
}

/* Wall panels are faint: the ground seen through one changes a little (more than nothing, less than a tenth of its
 * value), a collider behind one is still seen, and walls cast no shadow. */
static void test_wall_panels(void **state)
{
    (void)state;
    DrCamera cam = camera(dr_v3(0, 0.6, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 120, 90);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground_height = -0.5;
    DrImage img[3];
    for (int k = 0; k < 3; k++) {
        DrRenderScene *s = new_scene();
        add_mesh(s, make_box(dr_v3(-0.2, -0.5, -0.2), dr_v3(0.2, -0.1, 0.2)), DR_MATERIAL_COLLIDER);
        if (k >= 1) add_mesh(s, make_box(dr_v3(-1, -0.5, -1), dr_v3(1, 0.5, 1)), DR_MATERIAL_WALL);
        if (k == 2) { /* the same with the collider moved out: what the wall alone shows */
            dr_render_scene_destroy(&s);
            s = new_scene();
            add_mesh(s, make_box(dr_v3(-1, -0.5, -1), dr_v3(1, 0.5, 1)), DR_MATERIAL_WALL);
        }
        img[k] = render(s, &cam, &desc);
        dr_render_scene_destroy(&s);
    }
    /* the collider's centre, behind the front panel: still the collider, not the wall */
    const uint8_t *c0 = px(&img[0], 60, 52), *c1 = px(&img[1], 60, 52), *w = px(&img[2], 60, 52);
    int through = colour_diff(c0, c1), covered = colour_diff(c1, w);
    print_message("wall: collider seen through it changes by %d, and differs from the wall alone by %d\n", through,
                  covered);
    assert_true(through > 0 && through < 0.1 * (c0[0] + c0[1] + c0[2]));
    assert_true(covered > 3 * through);
    /* ground inside the tank beside the collider: faintly tinted; no shadow of the walls on it */
    const uint8_t *g0 = px(&img[0], 15, 80), *g1 = px(&img[1], 15, 80);
    assert_true(colour_diff(g0, g1) < 0.15 * (g0[0] + g0[1] + g0[2]));
    for (int k = 0; k < 3; k++) dr_image_free(&img[k]);
    /* strands cannot be walls */
    DrRenderScene *s = new_scene();
    double pts[6] = {0, 0, 0, 0, 1, 0}, r = 0.01;
    int off[2] = {0, 2};
    DrError err;
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &r, DR_MATERIAL_WALL, &err), DR_ERR_INPUT);
    dr_render_scene_destroy(&s);
}

/* ---- 6. shadows ------------------------------------------------------------------------------------------ */

static double luma(const uint8_t *p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; }

static void test_shadow_under_cube(void **state)
{
    (void)state;
    DrRenderScene *s = new_scene();
    DrVec3 c = dr_v3(0, 0.65, 0);
    add_mesh(s, make_box(dr_v3(-0.15, 0.5, -0.15), dr_v3(0.15, 0.8, 0.15)), DR_MATERIAL_SOLID);
    DrCamera cam = camera(dr_v3(0.2, 1.6, 2.6), dr_v3(0, 0.3, 0), dr_v3(0, 1, 0), 45, 320, 240);
    DrRenderDesc desc = dr_render_desc_default();
    /* the ground point the light reaches through the cube's centre, and one well away from it */
    DrVec3 l = dr_v3_normalize(desc.light_dir);
    DrVec3 under = dr_v3_add(c, dr_v3_scale(l, -c.y / l.y)), away = dr_v3(0.9, 0, 0.6);
    double ux, uy, ax, ay, d;
    assert_true(dr_camera_project(&cam, under, &ux, &uy, &d));
    assert_true(dr_camera_project(&cam, away, &ax, &ay, &d));
    assert_true(ux > 0 && ux < 320 && uy > 0 && uy < 240 && ax > 0 && ax < 320 && ay > 0 && ay < 240);
    DrImage img = render(s, &cam, &desc);
    double shadowed = luma(px(&img, (int)ux, (int)uy)), lit = luma(px(&img, (int)ax, (int)ay));
    /* the key light carries most of the ground's light: a shadow keeps well under 70% of it */
    if (!(shadowed < 0.7 * lit)) fail_msg("ground under the cube (%.1f) is not darker than away (%.1f)", shadowed, lit);
    dr_image_free(&img);
    /* the darkening is the shadow map's: without shadows that ground point is lit */
    desc.shadows = false;
    img = render(s, &cam, &desc);
    double unshadowed = luma(px(&img, (int)ux, (int)uy));
    assert_true(unshadowed > shadowed + 20);
    dr_image_free(&img);
    dr_render_scene_destroy(&s);

    /* strands cast shadows too: a thick horizontal strand through the same centre */
    s = new_scene();
    double pts[6] = {-0.3, c.y, 0, 0.3, c.y, 0};
    int off[2] = {0, 2};
    DrError err;
    double r_thick = 0.05;
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &r_thick, DR_MATERIAL_HAIR, &err), DR_OK);
    desc.shadows = true;
    img = render(s, &cam, &desc);
    shadowed = luma(px(&img, (int)ux, (int)uy)), lit = luma(px(&img, (int)ax, (int)ay));
    if (!(shadowed < 0.7 * lit)) fail_msg("ground under the strand (%.1f) is not darker than away (%.1f)", shadowed, lit);
    dr_image_free(&img);
    dr_render_scene_destroy(&s);

    /* on a collider floor 200 km wide (far beyond the shadow map's fitted region and the raster's guard
       band), with the ground plane off: still a shadow, and the same bytes on any thread count */
    s = new_scene();
    DrTriMesh q = {.nv = 4, .nt = 2};
    double v[12] = {-1e5, 0, -1e5, 1e5, 0, -1e5, 1e5, 0, 1e5, -1e5, 0, 1e5};
    int t[6] = {0, 2, 1, 0, 3, 2};
    q.v = v, q.tri = t;
    assert_int_equal(dr_render_scene_add_mesh(s, &q, DR_MATERIAL_COLLIDER, &err), DR_OK);
    add_mesh(s, make_box(dr_v3(-0.15, 0.5, -0.15), dr_v3(0.15, 0.8, 0.15)), DR_MATERIAL_SOLID);
    desc.ground = false;
    desc.threads = 1;
    img = render(s, &cam, &desc);
    shadowed = luma(px(&img, (int)ux, (int)uy)), lit = luma(px(&img, (int)ax, (int)ay));
    if (!(shadowed < 0.7 * lit)) fail_msg("floor under the cube (%.1f) is not darker than away (%.1f)", shadowed, lit);
    desc.threads = 0;
    DrImage img2 = render(s, &cam, &desc);
    assert_memory_equal(img.rgb, img2.rgb, 3 * (size_t)img.width * img.height);
    dr_image_free(&img);
    dr_image_free(&img2);
    dr_render_scene_destroy(&s);
}

/* ---- 7. strands ------------------------------------------------------------------------------------------- */

static void test_strands(void **state)
{
    (void)state;
    double pts[3 * 5];
    for (int i = 0; i < 5; i++) {
        pts[3 * i] = -1.0 + 0.5 * i;
        pts[3 * i + 1] = 0.1 * i * i - 0.3;
        pts[3 * i + 2] = 0.1 * i;
    }
    int off[2] = {0, 5};
    DrCamera cam = camera(dr_v3(0, 0, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 50, 200, 150);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    DrError err;
    for (int thick = 0; thick < 2; thick++) {
        DrRenderScene *s = new_scene();
        /* (focal 161 px, depth about 3 m) 1e-5 m projects to 1e-3 px: drawn one pixel wide; 0.06 m to 6 px */
        double radius = thick ? 0.06 : 1e-5;
        assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &radius, DR_MATERIAL_HAIR, &err), DR_OK);
        DrImage img = render(s, &cam, &desc);
        int on_path = 0;
        for (int seg = 0; seg < 4; seg++)
            for (int k = 0; k < 20; k++) {
                double t = k / 20.0, x, y, d;
                DrVec3 p = dr_v3(pts[3 * seg] + t * (pts[3 * seg + 3] - pts[3 * seg]),
                                 pts[3 * seg + 1] + t * (pts[3 * seg + 4] - pts[3 * seg + 1]),
                                 pts[3 * seg + 2] + t * (pts[3 * seg + 5] - pts[3 * seg + 2]));
                assert_true(dr_camera_project(&cam, p, &x, &y, &d));
                if (x < 1 || y < 1 || x > 199 || y > 149) continue;
                on_path++;
                if (is_background(&img, &cam, (int)x, (int)y))
                    fail_msg("strand (radius %g) missing at pixel (%d, %d)", radius, (int)x, (int)y);
                if (thick) { /* about 6 px across: the pixels 2 px above and below the path are covered too */
                    assert_false(is_background(&img, &cam, (int)x, (int)(y - 2)));
                    assert_false(is_background(&img, &cam, (int)x, (int)(y + 2)));
                }
            }
        assert_true(on_path > 40);
        /* far from the path: background */
        int bg = 0;
        for (int j = 0; j < 150; j++)
            for (int i = 0; i < 200; i++) bg += is_background(&img, &cam, i, j);
        assert_true(bg > 150 * 200 / 2);
        dr_image_free(&img);
        dr_render_scene_destroy(&s);
    }
    /* bad strands */
    DrRenderScene *s = new_scene();
    int bad_off[2] = {0, -1}, late_off[2] = {1, 5};
    double r = 0.01, r_neg = -1.0, r_nan = NAN;
    assert_int_equal(dr_render_scene_add_polylines(s, pts, bad_off, 1, &r, DR_MATERIAL_HAIR, &err), DR_ERR_INPUT);
    assert_int_equal(dr_render_scene_add_polylines(s, pts, late_off, 1, &r, DR_MATERIAL_HAIR, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "offsets[0]"));
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &r_neg, DR_MATERIAL_HAIR, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "polyline 0 has radius -1"));
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &r_nan, DR_MATERIAL_HAIR, &err), DR_ERR_INPUT);
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &r, DR_MATERIAL_LIQUID, &err), DR_ERR_INPUT);
    pts[4] = INFINITY;
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &r, DR_MATERIAL_HAIR, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "vertex 1 is not finite"));
    DrVec3 lo, hi;
    assert_false(dr_render_scene_bounds(s, &lo, &hi));
    dr_render_scene_destroy(&s);
}

/* Columns of row j that are not background: the first and last (-1, -1 when none), and whether every
 * column between them is covered too. */
static void covered_columns(const DrImage *img, const DrCamera *cam, int j, int i0, int i1, int *first, int *last,
                            bool *solid)
{
    *first = *last = -1;
    for (int i = i0; i <= i1; i++)
        if (!is_background(img, cam, i, j)) {
            if (*first < 0) *first = i;
            *last = i;
        }
    *solid = true;
    for (int i = *first; *first >= 0 && i <= *last; i++) *solid = *solid && !is_background(img, cam, i, j);
}

/* Vertical strands seen square on: each covers the pixel columns its projected width 2·radius spans (at least
 * one pixel), each with its own radius, along its whole length. */
static void test_strand_columns(void **state)
{
    (void)state;
    /* three strands on the plane z = 0, 3 m from the eye: 10 cm wide, 6 mm wide, 2 µm wide */
    const double xs[3] = {-0.5, 0.5, 0.0}, radius[3] = {0.05, 0.003, 1e-6};
    double pts[3 * 9];
    for (int k = 0; k < 3; k++)
        for (int i = 0; i < 3; i++) {
            double *p = pts + 3 * (3 * k + i);
            p[0] = xs[k], p[1] = -0.25 + 0.25 * i, p[2] = 0.0;
        }
    int off[4] = {0, 3, 6, 9};
    DrCamera cam = camera(dr_v3(0, 0, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 200, 150);
    DrRenderScene *s = new_scene();
    DrError err;
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 3, radius, DR_MATERIAL_HAIR, &err), DR_OK);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    DrImage img = render(s, &cam, &desc);
    /* focal = 75 / tan(20°) = 206 px: at 3 m a metre is 68.7 px, so the strands are 6.9 px, 0.41 px and
       1.4e-4 px across; the last two are drawn one pixel wide */
    double xc[3], y_top, y_bottom, depth;
    for (int k = 0; k < 3; k++) assert_true(dr_camera_project(&cam, dr_v3(xs[k], 0, 0), &xc[k], &y_top, &depth));
    assert_true(dr_camera_project(&cam, dr_v3(0, 0.25, 0), &xc[2], &y_top, &depth));
    assert_true(dr_camera_project(&cam, dr_v3(0, -0.25, 0), &xc[2], &y_bottom, &depth));
    double focal = 0.5 * cam.height / tan(20.0 * DR_PI / 180.0);
    int rows = 0;
    /* rows a pixel inside the strands' ends (past them each ribbon has a cap of half its width) */
    for (int j = (int)y_top + 2; j <= (int)y_bottom - 2; j++, rows++)
        for (int k = 0; k < 3; k++) {
            double hw = fmax(0.5, focal * radius[k] / depth); /* half width in pixels: at least half a pixel */
            int want0 = (int)floor(xc[k] - hw), want1 = (int)floor(xc[k] + hw);
            int first, last;
            bool solid;
            covered_columns(&img, &cam, j, (int)xc[k] - 20, (int)xc[k] + 20, &first, &last, &solid);
            /* ±1 px: a pixel the edge crosses is covered when one of its 3×3 supersamples is inside */
            if (first < 0 || abs(first - want0) > 1 || abs(last - want1) > 1 || !solid)
                fail_msg("row %d: strand %d (radius %g) covers columns %d..%d%s, expected %d..%d", j, k, radius[k],
                         first, last, solid ? "" : " with gaps", want0, want1);
        }
    assert_true(rows > 25);
    /* the widest strand is wider on screen than the thinnest, which still shows */
    int f0, l0, f2, l2;
    bool solid;
    covered_columns(&img, &cam, 75, (int)xc[0] - 20, (int)xc[0] + 20, &f0, &l0, &solid);
    covered_columns(&img, &cam, 75, (int)xc[2] - 20, (int)xc[2] + 20, &f2, &l2, &solid);
    assert_true(l0 - f0 >= l2 - f2 && l2 >= f2);
    /* above and below the strands: background */
    for (int i = 0; i < cam.width; i++) {
        assert_true(is_background(&img, &cam, i, (int)y_top - 4));
        assert_true(is_background(&img, &cam, i, (int)y_bottom + 4));
    }
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
}

/* Luminance (luma above) of pixel (i, j). */
static double luma_at(const DrImage *img, int i, int j) { return luma(px(img, i, j)); }

/* Pixels of rows j0..j1 that are not background, and the mean luminance over them. */
static int covered(const DrImage *img, const DrCamera *cam, int j0, int j1, double *mean)
{
    int n = 0;
    double sum = 0.0;
    for (int j = j0; j <= j1; j++)
        for (int i = 0; i < img->width; i++)
            if (!is_background(img, cam, i, j)) n++, sum += luma_at(img, i, j);
    *mean = n ? sum / n : 0.0;
    return n;
}

/* Wet strands (dr_render_scene_add_wet_polylines): the same strand with a film (three times its radius, wetness 1)
 * covers more pixels and is darker, over all its pixels and at each pixel the dry strand covers whole; the wetness
 * alone darkens every pixel and changes no coverage; wetness 0 at one radius is byte for byte the dry call's
 * drawing; radius and wetness vary along a strand; bad values are refused naming the strand and the vertex. */
static void test_wet_strands(void **state)
{
    (void)state;
    /* one vertical strand through the centre, 3 m from the eye: 68.7 px per metre (test_strand_columns), so the
       dry strand (r = 2 cm) is 2.7 px wide and the wet one (H = 6 cm) 8.2 px */
    double pts[3 * 3] = {0, -0.25, 0, 0, 0, 0, 0, 0.25, 0};
    int off[2] = {0, 3};
    double r = 0.02, r3[3] = {0.02, 0.02, 0.02}, H[3] = {0.06, 0.06, 0.06}, w1[3] = {1, 1, 1}, w0[3] = {0, 0, 0};
    DrCamera cam = camera(dr_v3(0, 0, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 200, 150);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    DrError err;
    DrImage img[5];
    for (int k = 0; k < 5; k++) {
        DrRenderScene *s = new_scene();
        DrStatus st = k == 0 ? dr_render_scene_add_polylines(s, pts, off, 1, &r, DR_MATERIAL_HAIR, &err)
                      : k == 1 ? dr_render_scene_add_wet_polylines(s, pts, off, 1, H, w1, DR_MATERIAL_HAIR, &err)
                      : k == 2 ? dr_render_scene_add_wet_polylines(s, pts, off, 1, H, w0, DR_MATERIAL_HAIR, &err)
                      : k == 3 ? dr_render_scene_add_wet_polylines(s, pts, off, 1, r3, NULL, DR_MATERIAL_HAIR, &err)
                               : dr_render_scene_add_wet_polylines(s, pts, off, 1, r3, w0, DR_MATERIAL_HAIR, &err);
        assert_int_equal(st, DR_OK);
        img[k] = render(s, &cam, &desc);
        dr_render_scene_destroy(&s);
    }
    double x, y_top, y_bottom, depth;
    assert_true(dr_camera_project(&cam, dr_v3(0, 0.25, 0), &x, &y_top, &depth));
    assert_true(dr_camera_project(&cam, dr_v3(0, -0.25, 0), &x, &y_bottom, &depth));
    int j0 = (int)y_top + 2, j1 = (int)y_bottom - 2; /* inside the ends' caps */
    double dry_mean, wet_mean, film_mean;
    int dry_n = covered(&img[0], &cam, j0, j1, &dry_mean), wet_n = covered(&img[1], &cam, j0, j1, &wet_mean);
    int film_n = covered(&img[2], &cam, j0, j1, &film_mean);
    /* wider: 8.2 px against 2.7; an interval w px wide covers between w − 1 and w + 1 columns (a column counts
       when one of its 3 supersample columns is inside), so at least 3 more columns in every row */
    assert_true(wet_n >= dry_n + 3 * (j1 - j0 + 1));
    /* darker over its pixels, though the dry strand's include more antialiased edge (lighter) */
    assert_true(wet_mean < dry_mean);
    /* and at every pixel the dry strand covers whole (its centre column), where only the albedo differs */
    int ic = (int)x;
    for (int j = j0; j <= j1; j++) {
        assert_false(is_background(&img[0], &cam, ic, j));
        if (!(luma_at(&img[1], ic, j) < luma_at(&img[0], ic, j)))
            fail_msg("row %d: wet %.1f not darker than dry %.1f", j, luma_at(&img[1], ic, j), luma_at(&img[0], ic, j));
    }
    /* the wetness alone: the same pixels covered, each darker or as dark, and darker on the whole */
    assert_int_equal(film_n, wet_n);
    for (int j = j0; j <= j1; j++)
        for (int i = 0; i < cam.width; i++) {
            assert_true(is_background(&img[1], &cam, i, j) == is_background(&img[2], &cam, i, j));
            assert_true(luma_at(&img[1], i, j) <= luma_at(&img[2], i, j));
        }
    assert_true(wet_mean < film_mean);
    /* dry through the wet call (no wetness, or wetness 0; one radius): the dry call's bytes */
    for (int k = 3; k < 5; k++) assert_memory_equal(img[k].rgb, img[0].rgb, 3 * (size_t)cam.width * cam.height);
    for (int k = 0; k < 5; k++) dr_image_free(&img[k]);

    /* along the strand: dry and thin at the bottom, wet and wide at the top */
    double Hs[3] = {0.02, 0.04, 0.06}, ws[3] = {0, 0.5, 1};
    DrRenderScene *s = new_scene();
    assert_int_equal(dr_render_scene_add_wet_polylines(s, pts, off, 1, Hs, ws, DR_MATERIAL_HAIR, &err), DR_OK);
    DrImage g = render(s, &cam, &desc);
    dr_render_scene_destroy(&s);
    int jt = j0 + 3, jb = j1 - 3;
    int nt = 0, nb = 0;
    for (int i = 0; i < cam.width; i++) nt += !is_background(&g, &cam, i, jt), nb += !is_background(&g, &cam, i, jb);
    assert_true(nt > nb);
    assert_true(luma_at(&g, ic, jt) < luma_at(&g, ic, jb));
    dr_image_free(&g);

    /* bad values: DR_ERR_INPUT naming the strand and its vertex, nothing added */
    s = new_scene();
    double bad_w[3] = {0, 1.5, 0}, nan_w[3] = {0, 0, NAN}, bad_r[3] = {0.02, -1, 0.02};
    assert_int_equal(dr_render_scene_add_wet_polylines(s, pts, off, 1, r3, bad_w, DR_MATERIAL_HAIR, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "polyline 0 has wetness 1.5 at its vertex 1"));
    assert_int_equal(dr_render_scene_add_wet_polylines(s, pts, off, 1, r3, nan_w, DR_MATERIAL_HAIR, &err), DR_ERR_INPUT);
    assert_int_equal(dr_render_scene_add_wet_polylines(s, pts, off, 1, bad_r, NULL, DR_MATERIAL_HAIR, &err),
                     DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "polyline 0 has radius -1 at its vertex 1"));
    assert_int_equal(dr_render_scene_add_wet_polylines(s, pts, off, 1, r3, w1, DR_MATERIAL_LIQUID, &err), DR_ERR_INPUT);
    DrVec3 lo, hi;
    assert_false(dr_render_scene_bounds(s, &lo, &hi));
    dr_render_scene_destroy(&s);
}

/* No strands, or only strands of one vertex: nothing drawn, the image is the background's, and with the ground
 * on it is byte for byte an empty scene's. */
static void test_strands_empty(void **state)
{
    (void)state;
    DrCamera cam = camera(dr_v3(0, 1, 3), dr_v3(0, 0.8, 0), dr_v3(0, 1, 0), 50, 160, 120);
    DrRenderDesc desc = dr_render_desc_default();
    DrError err;
    DrRenderScene *empty = new_scene(), *s = new_scene();
    int off0[1] = {0};
    assert_int_equal(dr_render_scene_add_polylines(s, NULL, off0, 0, NULL, DR_MATERIAL_HAIR, &err), DR_OK);
    double single[6] = {0, 0.8, 0, 0.1, 0.9, 0}, r[2] = {0.05, 0.05};
    int off1[3] = {0, 1, 2}; /* two strands of one vertex each */
    assert_int_equal(dr_render_scene_add_polylines(s, single, off1, 2, r, DR_MATERIAL_HAIR, &err), DR_OK);
    DrVec3 lo, hi;
    assert_false(dr_render_scene_bounds(s, &lo, &hi));
    desc.ground = false;
    DrImage img = render(s, &cam, &desc);
    for (int j = 0; j < img.height; j++)
        for (int i = 0; i < img.width; i++) assert_true(is_background(&img, &cam, i, j));
    dr_image_free(&img);
    desc.ground = true;
    img = render(s, &cam, &desc);
    DrImage ref = render(empty, &cam, &desc);
    assert_memory_equal(img.rgb, ref.rgb, 3 * (size_t)img.width * img.height);
    dr_image_free(&img);
    dr_image_free(&ref);
    dr_render_scene_destroy(&s);
    dr_render_scene_destroy(&empty);
}

/* Strands are depth tested against meshes: behind a box they are hidden where it covers them and seen where it
 * does not; in front of it they are drawn over it. */
static void test_strand_depth(void **state)
{
    (void)state;
    DrCamera cam = camera(dr_v3(0, 0, 3), dr_v3(0, 0, 0), dr_v3(0, 1, 0), 40, 200, 150);
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = false;
    desc.shadows = false; /* the comparisons below are of coverage, not of the strand's shadow on the box */
    DrError err;
    double radius = 0.01;
    int off[2] = {0, 2};
    DrImage img[3];
    for (int k = 0; k < 3; k++) {
        DrRenderScene *s = new_scene();
        add_mesh(s, make_box(dr_v3(-0.3, -0.1, 0.2), dr_v3(0.3, 0.1, 0.4)), DR_MATERIAL_COLLIDER);
        double z = k == 1 ? 0.0 : 0.6; /* behind the box (its front face is at z = 0.4), or in front of it */
        double pts[6] = {0, -0.3, z, 0, 0.3, z};
        if (k > 0)
            assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 1, &radius, DR_MATERIAL_HAIR, &err), DR_OK);
        img[k] = render(s, &cam, &desc);
        dr_render_scene_destroy(&s);
    }
    double x, y, d;
    assert_true(dr_camera_project(&cam, dr_v3(0, 0, 0.4), &x, &y, &d));
    int i = (int)x, j = (int)y;
    assert_false(is_background(&img[0], &cam, i, j));
    /* behind: the box's pixels are untouched */
    assert_memory_equal(px(&img[1], i, j), px(&img[0], i, j), 3);
    /* ... and above the box, where nothing hides it, the strand shows */
    assert_true(dr_camera_project(&cam, dr_v3(0, 0.25, 0), &x, &y, &d));
    assert_true(is_background(&img[0], &cam, (int)x, (int)y));
    assert_false(is_background(&img[1], &cam, (int)x, (int)y));
    /* in front: drawn over the box, dark brown hair against the grey-blue collider */
    const uint8_t *h = px(&img[2], i, j), *b = px(&img[0], i, j);
    if (!(h[0] + h[1] + h[2] + 30 < b[0] + b[1] + b[2] && h[0] >= h[2]))
        fail_msg("strand in front of the box (%d %d %d) is not drawn over it (%d %d %d)", h[0], h[1], h[2], b[0],
                 b[1], b[2]);
    for (int k = 0; k < 3; k++) dr_image_free(&img[k]);
}

/* ---- 8. determinism, scene input ---------------------------------------------------------------------------- */

static void test_threads_identical(void **state)
{
    (void)state;
    DrRenderScene *s = new_scene();
    add_mesh(s, make_box(dr_v3(-1, 0, -1), dr_v3(1, 0.1, 1)), DR_MATERIAL_COLLIDER);
    add_mesh(s, make_sphere(dr_v3(0.2, 0.5, 0), 0.4, 64, 32), DR_MATERIAL_LIQUID);
    add_mesh(s, make_sphere(dr_v3(-0.6, 0.35, 0.3), 0.2, 32, 16), DR_MATERIAL_SOLID);
    double pts[3 * 8];
    for (int i = 0; i < 8; i++) pts[3 * i] = 0.6, pts[3 * i + 1] = 0.1 + 0.1 * i, pts[3 * i + 2] = 0.4 + 0.02 * i * i;
    int off[3] = {0, 4, 8};
    double radius[2] = {0.004, 0.002};
    DrError err;
    assert_int_equal(dr_render_scene_add_polylines(s, pts, off, 2, radius, DR_MATERIAL_HAIR, &err), DR_OK);
    DrVec3 lo, hi;
    assert_true(dr_render_scene_bounds(s, &lo, &hi));
    assert_true(lo.x == -1 && hi.x == 1 && lo.y == 0 && fabs(hi.y - 0.9) < 1e-12);
    /* 237 rows: the last band is partial */
    DrCamera cam = camera(dr_v3(1.5, 1.2, 2.4), dr_v3(0, 0.3, 0), dr_v3(0, 1, 0), 40, 301, 237);
    DrRenderDesc desc = dr_render_desc_default();
    desc.threads = 1;
    DrImage a = render(s, &cam, &desc);
    int saved = dr_threads();
    dr_set_threads(3); /* more workers than cores is fine, and exercises the parallel split on any machine */
    desc.threads = 0;
    DrImage b = render(s, &cam, &desc);
    desc.threads = 2;
    DrImage c = render(s, &cam, &desc);
    dr_set_threads(saved);
    size_t n = 3 * (size_t)a.width * a.height;
    assert_memory_equal(a.rgb, b.rgb, n);
    assert_memory_equal(a.rgb, c.rgb, n);
    /* and the same call twice gives the same bytes */
    desc.threads = 1;
    DrImage d = render(s, &cam, &desc);
    assert_memory_equal(a.rgb, d.rgb, n);
    /* samples = 1 and 8 are valid too, and antialiasing changes the picture */
    desc.samples = 1;
    DrImage e = render(s, &cam, &desc);
    assert_memory_not_equal(a.rgb, e.rgb, n);
    dr_image_free(&e);
    desc.samples = 8;
    e = render(s, &cam, &desc);
    dr_image_free(&e);
    dr_image_free(&a);
    dr_image_free(&b);
    dr_image_free(&c);
    dr_image_free(&d);
    dr_render_scene_destroy(&s);
}

static void test_scene_input(void **state)
{
    (void)state;
    DrRenderScene *s = new_scene();
    DrError err;
    DrTriMesh m = make_box(dr_v3(0, 0, 0), dr_v3(1, 1, 1));
    m.v[4] = NAN;
    assert_int_equal(dr_render_scene_add_mesh(s, &m, DR_MATERIAL_SOLID, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "finite"));
    m.v[4] = 0;
    m.tri[5] = 8;
    assert_int_equal(dr_render_scene_add_mesh(s, &m, DR_MATERIAL_SOLID, &err), DR_ERR_INPUT);
    dr_trimesh_free(&m);
    DrTriMesh empty = {0};
    assert_int_equal(dr_render_scene_add_mesh(s, &empty, DR_MATERIAL_LIQUID, &err), DR_OK);
    DrVec3 lo, hi;
    assert_false(dr_render_scene_bounds(s, &lo, &hi)); /* an empty mesh draws nothing */
    /* a mesh with normals given, one of them zero (double-sided sheet): drawn without NaNs, deterministically */
    DrTriMesh q = {.nv = 4, .nt = 2};
    double v[12] = {-1, 0, -1, 1, 0, -1, 1, 0, 1, -1, 0, 1}, n[12] = {0, 1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0};
    int t[6] = {0, 2, 1, 0, 3, 2};
    q.v = v, q.n = n, q.tri = t;
    assert_int_equal(dr_render_scene_add_mesh(s, &q, DR_MATERIAL_SOLID, &err), DR_OK);
    v[0] = 100; /* copied: the caller's arrays may change afterwards */
    assert_true(dr_render_scene_bounds(s, &lo, &hi));
    assert_true(lo.x == -1 && hi.x == 1 && lo.y == 0 && hi.y == 0);
    DrCamera cam = camera(dr_v3(0, -2, 0.5), dr_v3(0, 0, 0), dr_v3(0, 0, 1), 60, 80, 60); /* from below */
    DrRenderDesc desc = dr_render_desc_default();
    desc.ground_height = -1;
    DrImage img = render(s, &cam, &desc);
    assert_false(is_background(&img, &cam, 40, 30));
    dr_image_free(&img);
    dr_render_scene_destroy(&s);
    dr_render_scene_destroy(&s); /* NULL: no-op */
}

/* ---- contact sheets, resizing, text -------------------------------------------------------------------------- */

static void test_contact_sheet(void **state)
{
    (void)state;
    DrError err;
    DrImage imgs[5];
    for (int k = 0; k < 5; k++) {
        uint8_t fill[3] = {(uint8_t)(40 * k + 30), (uint8_t)(200 - 30 * k), 90};
        assert_int_equal(dr_image_create(64, 48, fill, &imgs[k], &err), DR_OK);
    }
    const char *labels[5] = {"f1", "f2", "frame 3", "a label far too long for a thumbnail", "f5"};
    DrImage sheet;
    assert_int_equal(dr_image_contact_sheet(imgs, labels, 5, 3, 32, &sheet, &err), DR_OK);
    /* 3 columns, 2 rows of 32×24 thumbnails with a 7+2*3 px label band at scale 1, 8 px margins */
    assert_int_equal(sheet.width, 8 + 3 * (32 + 8));
    assert_int_equal(sheet.height, 8 + 2 * (24 + 13 + 8));
    DrSheetLayout L;
    dr_image_sheet_layout(64, 48, 5, 3, 32, &L);
    assert_int_equal(L.width, sheet.width);
    assert_int_equal(L.height, sheet.height);
    assert_int_equal(L.thumb_height, 24);
    static const uint8_t dark[3] = {24, 24, 27};
    for (int k = 0; k < 6; k++) {
        int x0 = 8 + (k % 3) * 40, y0 = 8 + (k / 3) * 45;
        /* a constant image makes a constant thumbnail */
        if (k < 5)
            for (int j = 0; j < 24; j++)
                for (int i = 0; i < 32; i++) assert_memory_equal(px(&sheet, x0 + i, y0 + j), imgs[k].rgb, 3);
        int ink = 0;
        for (int j = y0 + 24; j < y0 + 24 + 13; j++)
            for (int i = x0; i < x0 + 32; i++) ink += memcmp(px(&sheet, i, j), dark, 3) != 0;
        if (k < 5) assert_true(ink > 5); /* a label under every thumbnail */
        else assert_int_equal(ink, 0);   /* the sixth cell is empty */
        /* the long label stays in its cell: the margin right of it is background */
        if (k == 3)
            for (int j = y0 + 24; j < y0 + 37; j++) assert_memory_equal(px(&sheet, x0 + 32, j), dark, 3);
    }
    dr_image_free(&sheet);
    /* no labels: nothing under the thumbnails */
    assert_int_equal(dr_image_contact_sheet(imgs, NULL, 2, 4, 200, &sheet, &err), DR_OK);
    assert_int_equal(sheet.width, 8 + 2 * (200 + 8));
    assert_int_equal(sheet.height, 8 + (150 + 14 + 6 + 8));
    for (int j = 8 + 150; j < 8 + 150 + 20; j++) assert_memory_equal(px(&sheet, 20, j), dark, 3);
    dr_image_free(&sheet);
    assert_int_equal(dr_image_contact_sheet(imgs, labels, 0, 3, 32, &sheet, &err), DR_ERR_INPUT);
    assert_int_equal(dr_image_contact_sheet(imgs, labels, 5, 3, 15, &sheet, &err), DR_ERR_INPUT);
    assert_non_null(strstr(err.message, "thumb_width"));
    assert_int_equal(dr_image_contact_sheet(imgs, labels, 5, 0, 32, &sheet, &err), DR_ERR_INPUT);
    DrImage other;
    static const uint8_t grey[3] = {9, 9, 9};
    assert_int_equal(dr_image_create(65, 48, grey, &other, &err), DR_OK);
    DrImage mixed[2] = {imgs[0], other};
    assert_int_equal(dr_image_contact_sheet(mixed, labels, 2, 2, 32, &sheet, &err), DR_ERR_INPUT);
    assert_null(sheet.rgb);
    dr_image_free(&other);
    for (int k = 0; k < 5; k++) dr_image_free(&imgs[k]);
}

static void test_resize(void **state)
{
    (void)state;
    DrError err;
    static const uint8_t c[3] = {200, 101, 7};
    DrImage src, dst;
    assert_int_equal(dr_image_create(37, 23, c, &src, &err), DR_OK);
    int sizes[4][2] = {{10, 7}, {37, 23}, {50, 40}, {1, 1}};
    for (int k = 0; k < 4; k++) {
        assert_int_equal(dr_image_resize(&src, sizes[k][0], sizes[k][1], &dst, &err), DR_OK);
        for (int i = 0; i < dst.width * dst.height; i++) assert_memory_equal(dst.rgb + 3 * i, c, 3);
        dr_image_free(&dst);
    }
    dr_image_free(&src);
    /* area average: a 4×2 image of black and white halves to 2×1 stays split, to 1×1 is mid grey */
    static const uint8_t black[3] = {0, 0, 0};
    assert_int_equal(dr_image_create(4, 2, black, &src, &err), DR_OK);
    for (int j = 0; j < 2; j++) memset(src.rgb + 3 * (4 * j + 2), 255, 6);
    assert_int_equal(dr_image_resize(&src, 2, 1, &dst, &err), DR_OK);
    assert_int_equal(dst.rgb[0], 0);
    assert_int_equal(dst.rgb[3], 255);
    dr_image_free(&dst);
    assert_int_equal(dr_image_resize(&src, 1, 1, &dst, &err), DR_OK);
    assert_int_equal(dst.rgb[0], 128); /* 127.5 rounds up */
    dr_image_free(&dst);
    /* 3 → 2 columns: the middle source pixel is shared half and half */
    dr_image_free(&src);
    assert_int_equal(dr_image_create(3, 1, black, &src, &err), DR_OK);
    memset(src.rgb + 3, 90, 3);
    assert_int_equal(dr_image_resize(&src, 2, 1, &dst, &err), DR_OK);
    assert_int_equal(dst.rgb[0], 30); /* (1 * 0 + 0.5 * 90) / 1.5 */
    assert_int_equal(dst.rgb[3], 30);
    dr_image_free(&dst);
    assert_int_equal(dr_image_resize(&src, 0, 1, &dst, &err), DR_ERR_INPUT);
    dr_image_free(&src);
}

static void test_text(void **state)
{
    (void)state;
    DrError err;
    int w, h;
    dr_image_text_size("Hi 7", 2, &w, &h);
    assert_int_equal(w, 2 * (4 * 6 - 1));
    assert_int_equal(h, 14);
    dr_image_text_size("", 3, &w, &h);
    assert_int_equal(w, 0);
    assert_int_equal(h, 0);
    static const uint8_t black[3] = {0, 0, 0}, white[3] = {255, 255, 255};
    DrImage img;
    assert_int_equal(dr_image_create(100, 40, black, &img, &err), DR_OK);
    dr_image_draw_text(&img, 5, 3, 2, white, "Hi 7");
    dr_image_text_size("Hi 7", 2, &w, &h);
    /* the drawn pixels fill exactly the reported box ('H' touches its left, top and bottom, '7' its right) */
    int x0 = 100, x1 = -1, y0 = 40, y1 = -1;
    for (int j = 0; j < 40; j++)
        for (int i = 0; i < 100; i++)
            if (px(&img, i, j)[0]) {
                x0 = i < x0 ? i : x0, x1 = i > x1 ? i : x1;
                y0 = j < y0 ? j : y0, y1 = j > y1 ? j : y1;
            }
    assert_int_equal(x0, 5);
    assert_int_equal(y0, 3);
    assert_int_equal(x1, 5 + w - 1);
    assert_int_equal(y1, 3 + h - 1);
    /* non-printable bytes draw as '?'; drawing off the edges is clipped, not a crash */
    DrImage q1, q2;
    assert_int_equal(dr_image_create(20, 10, black, &q1, &err), DR_OK);
    assert_int_equal(dr_image_create(20, 10, black, &q2, &err), DR_OK);
    dr_image_draw_text(&q1, 1, 1, 1, white, "\x01");
    dr_image_draw_text(&q2, 1, 1, 1, white, "?");
    assert_memory_equal(q1.rgb, q2.rgb, 3 * 200);
    dr_image_draw_text(&q1, -4, -3, 3, white, "clipped text");
    dr_image_draw_text(&q1, 18, 8, 3, white, "WW");
    dr_image_free(&q1);
    dr_image_free(&q2);
    dr_image_free(&img);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_silhouette),
        cmocka_unit_test(test_empty_scene),
        cmocka_unit_test(test_png_round_trip),
        cmocka_unit_test(test_png_other_formats),
        cmocka_unit_test(test_camera_checks),
        cmocka_unit_test(test_camera_inside_geometry),
        cmocka_unit_test(test_near_plane_clipping),
        cmocka_unit_test(test_watertight_fan),
        cmocka_unit_test(test_box_faces_flat),
        cmocka_unit_test(test_liquid_reads_as_water),
        cmocka_unit_test(test_fixed_sizes),
        cmocka_unit_test(test_wall_panels),
        cmocka_unit_test(test_shadow_under_cube),
        cmocka_unit_test(test_strands),
        cmocka_unit_test(test_strand_columns),
        cmocka_unit_test(test_wet_strands),
        cmocka_unit_test(test_strands_empty),
        cmocka_unit_test(test_strand_depth),
        cmocka_unit_test(test_threads_identical),
        cmocka_unit_test(test_scene_input),
        cmocka_unit_test(test_contact_sheet),
        cmocka_unit_test(test_resize),
        cmocka_unit_test(test_text),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
