/* src/scene: loading, defaults, every class of bad input (message, line, column), canonical JSON,
 * cache keys and the printed reference. Scenes are written to a private temporary directory; the
 * malformed scenes under tests/data/bad/ are shared with the pipeline tests. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "scene/scene.h"

static char g_dir[256]; /* this run's scratch directory */

/* ---- helpers ------------------------------------------------------------------------------------------ */

static void remove_tree(const char *path)
{
    DIR *d = opendir(path);
    if (d) {
        struct dirent *e;
        while ((e = readdir(d))) {
            if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
            char sub[1024];
            snprintf(sub, sizeof sub, "%s/%s", path, e->d_name);
            remove_tree(sub);
        }
        closedir(d);
        rmdir(path);
    } else {
        unlink(path);
    }
}

static int group_setup(void **state)
{
    (void)state;
    snprintf(g_dir, sizeof g_dir, "%s/drench_test_scene_XXXXXX", dr_temp_dir());
    if (!mkdtemp(g_dir)) return -1;
    char sub[512];
    snprintf(sub, sizeof sub, "%s/meshes", g_dir);
    return mkdir(sub, 0755);
}

static int group_teardown(void **state)
{
    (void)state;
    remove_tree(g_dir);
    return 0;
}

static void tmp_path(const char *name, char *buf, size_t size) { snprintf(buf, size, "%s/%s", g_dir, name); }

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(text, 1, strlen(text), f), strlen(text));
    assert_int_equal(fclose(f), 0);
}

static const char *const TRI_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

/* Writes text to <g_dir>/<name> and loads it; fails the test with the error text if it does not load. */
static DrScene *load_named(const char *name, const char *text)
{
    char path[512];
    tmp_path(name, path, sizeof path);
    write_file(path, text);
    DrScene *s = NULL;
    DrError err = {0};
    DrStatus st = dr_scene_load(path, &s, &err);
    if (st != DR_OK) {
        char buf[4096];
        dr_error_format(&err, buf, sizeof buf);
        fail_msg("scene did not load: %s", buf);
    }
    assert_non_null(s);
    return s;
}

static DrScene *load_text(const char *text) { return load_named("scene.json", text); }

/* Loads text that must fail; returns the status, err filled, and checks that no scene came back and
 * that the error names the file. */
static DrStatus load_bad(const char *text, DrError *err)
{
    char path[512];
    tmp_path("bad.json", path, sizeof path);
    write_file(path, text);
    DrScene *s = (DrScene *)(uintptr_t)1;
    dr_error_clear(err);
    DrStatus st = dr_scene_load(path, &s, err);
    assert_null(s);
    assert_string_equal(err->file, path);
    return st;
}

static void assert_contains(const char *hay, const char *needle)
{
    if (!strstr(hay, needle)) fail_msg("expected \"%s\" in \"%s\"", needle, hay);
}

/* tests/data/bad/<name>; tests/run_tests.sh starts every binary in the repository root. */
static void bad_file(const char *name, char *buf, size_t size)
{
    snprintf(buf, size, "tests/data/bad/%s", name);
    if (access(buf, R_OK) != 0) fail_msg("%s not found: run the test from the repository root", buf);
}

static void keys_of(const char *text, DrSceneKeys *k)
{
    DrScene *s = load_text(text);
    DrError err = {0};
    DrStatus st = dr_scene_keys(s, k, &err);
    if (st != DR_OK) fail_msg("dr_scene_keys: %s", err.message);
    dr_scene_destroy(&s);
    assert_null(s);
}

static void assert_hex32(const char *k)
{
    assert_int_equal(strlen(k), 32);
    for (const char *c = k; *c; c++) assert_true((*c >= '0' && *c <= '9') || (*c >= 'a' && *c <= 'f'));
}

/* A valid liquid scene with extra components (inside "components") and extra top-level members. */
static void liquid_scene(const char *extra_components, const char *extra_top, char *buf, size_t size)
{
    snprintf(buf, size,
             "{\"elements\":[{\"name\":\"water\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]},"
             "\"LiquidSource\":{\"box\":[[0,0,0],[0.5,0.5,0.5]]}%s}}]%s}",
             extra_components, extra_top);
}

/* ---- a valid scene -------------------------------------------------------------------------------------- */

static const char *const FULL_SCENE =
    "{\n"
    "  \"shot\": { \"name\": \"pour\", \"fps\": 30, \"frames\": [1, 10], \"gravity\": [0, -9.8, 0], \"seed\": 7 },\n"
    "  \"solver\": { \"cfl\": 2, \"max_substeps\": 16 },\n"
    "  \"mesh\": { \"voxel_size\": 0.01, \"write_obj\": false },\n"
    "  \"render\": { \"resolution\": [640, 360], \"camera\": { \"fov_deg\": 35.5, \"eye\": [1, 1, 1] } },\n"
    "  \"elements\": [\n"
    "    { \"name\": \"water\", \"type\": \"liquid\",\n"
    "      \"components\": {\n"
    "        \"Domain\": { \"box\": [[0, 0, 0], [1, 1, 1]], \"voxel_size\": 0.05, \"wall_boundary\": \"no_slip\" },\n"
    "        \"LiquidSource\": { \"box\": [[0.1, 0.1, 0.1], [0.5, 0.5, 0.5]], \"velocity\": [0, -1, 0] },\n"
    "        \"Emitter\": { \"box\": [[0.4, 0.8, 0.4], [0.6, 0.9, 0.6]], \"start\": 0.5, \"end\": 1.5 },\n"
    "        \"LiquidMaterial\": { \"density\": 1200, \"viscosity\": 0.5 },\n"
    "        \"Transfer\": { \"scheme\": \"flip\", \"flip_blend\": 0.95 } } },\n"
    "    { \"name\": \"cup\", \"type\": \"collider\",\n"
    "      \"components\": {\n"
    "        \"Mesh\": { \"file\": \"meshes/tri.obj\" },\n"
    "        \"Motion\": { \"keys\": [[1, 0, 0, 0, 0, 0, 0], [10, 0.1, 0, 0, 0, 90, 0]] } } }\n"
    "  ]\n"
    "}\n";

static void write_tri(void)
{
    char path[512];
    tmp_path("meshes/tri.obj", path, sizeof path);
    write_file(path, TRI_OBJ);
}

static void test_full_scene_getters(void **state)
{
    (void)state;
    write_tri();
    DrScene *s = load_text(FULL_SCENE);
    char path[512];
    tmp_path("scene.json", path, sizeof path);
    assert_string_equal(dr_scene_path(s), path);

    assert_int_equal(dr_scene_element_count(s), 2);
    assert_int_equal(dr_scene_count_type(s, "liquid"), 1);
    assert_int_equal(dr_scene_count_type(s, "collider"), 1);
    assert_int_equal(dr_scene_count_type(s, "hair"), 0);
    assert_null(dr_scene_find(s, "nope"));
    const DrElement *water = dr_scene_find(s, "water"), *cup = dr_scene_find(s, "cup");
    assert_ptr_equal(water, dr_scene_element(s, 0));
    assert_ptr_equal(cup, dr_scene_element(s, 1));
    assert_string_equal(water->type, "liquid");
    assert_string_equal(cup->type, "collider");
    assert_int_equal(cup->index, 1);
    assert_ptr_equal(water->spec, dr_scene_element_spec("liquid"));

    /* sections: written values, and defaults beside them */
    const DrComponent *shot = dr_scene_section(s, "shot");
    assert_true(dr_component_present(shot));
    assert_string_equal(dr_component_str(shot, "name"), "pour");
    assert_true(dr_component_num(shot, "fps") == 30.0);
    int fr[2];
    dr_component_int2(shot, "frames", fr);
    assert_int_equal(fr[0], 1);
    assert_int_equal(fr[1], 10);
    DrVec3 g = dr_component_vec3(shot, "gravity");
    assert_true(g.x == 0.0 && g.y == -9.8 && g.z == 0.0);
    assert_int_equal(dr_component_int(shot, "seed"), 7);
    const DrComponent *solver = dr_scene_section(s, "solver");
    assert_true(dr_component_num(solver, "cfl") == 2.0);
    assert_int_equal(dr_component_int(solver, "max_substeps"), 16);
    assert_false(dr_component_is_set(solver, "pressure_tolerance"));
    assert_true(dr_component_num(solver, "pressure_tolerance") == 1e-6);
    assert_int_equal(dr_component_int(solver, "checkpoint_every"), 1);
    const DrComponent *mesh = dr_scene_section(s, "mesh");
    assert_true(dr_component_num(mesh, "voxel_size") == 0.01);
    assert_false(dr_component_bool(mesh, "write_obj"));
    assert_true(dr_component_bool(mesh, "write_vdb"));
    const DrComponent *render = dr_scene_section(s, "render"), *cam = dr_scene_section(s, "render.camera");
    dr_component_int2(render, "resolution", fr);
    assert_int_equal(fr[0], 640);
    assert_int_equal(fr[1], 360);
    assert_int_equal(dr_component_int(render, "contact_every"), 4);
    assert_true(dr_component_present(cam));
    assert_true(dr_component_num(cam, "fov_deg") == 35.5);
    DrVec3 eye = dr_component_vec3(cam, "eye"), target = dr_component_vec3(cam, "target");
    assert_true(eye.x == 1.0 && eye.y == 1.0 && eye.z == 1.0);
    assert_true(target.x == 0.0 && target.y == 0.1 && target.z == 0.0);

    /* liquid components */
    const DrComponent *dom = dr_element_component(water, "Domain");
    DrVec3 lo, hi;
    dr_component_box(dom, "box", &lo, &hi);
    assert_true(lo.x == 0 && lo.y == 0 && lo.z == 0 && hi.x == 1 && hi.y == 1 && hi.z == 1);
    assert_true(dr_component_num(dom, "voxel_size") == 0.05);
    assert_string_equal(dr_component_str(dom, "wall_boundary"), "no_slip");
    const DrComponent *src = dr_element_component(water, "LiquidSource");
    assert_true(dr_component_is_set(src, "box"));
    assert_false(dr_component_is_set(src, "mesh"));
    assert_null(dr_component_str(src, "mesh"));
    assert_true(dr_component_vec3(src, "velocity").y == -1.0);
    const DrComponent *em = dr_element_component(water, "Emitter");
    assert_true(dr_component_num(em, "start") == 0.5 && dr_component_num(em, "end") == 1.5);
    assert_true(dr_component_vec3(em, "velocity").x == 0.0);
    const DrComponent *mat = dr_element_component(water, "LiquidMaterial");
    assert_true(dr_component_num(mat, "density") == 1200.0 && dr_component_num(mat, "viscosity") == 0.5);
    const DrComponent *tr = dr_element_component(water, "Transfer");
    assert_string_equal(dr_component_str(tr, "scheme"), "flip");
    assert_true(dr_component_num(tr, "flip_blend") == 0.95);
    /* absent components read as defaults */
    const DrComponent *par = dr_element_component(water, "Particles");
    assert_false(dr_component_present(par));
    assert_int_equal(dr_component_int(par, "per_cell"), 8);
    assert_true(dr_component_num(par, "jitter") == 1.0);
    assert_int_equal(dr_component_int(par, "seed"), 1);
    const DrComponent *kill = dr_element_component(water, "KillBox");
    assert_false(dr_component_present(kill));
    assert_false(dr_component_is_set(kill, "box"));
    dr_component_box(kill, "box", &lo, &hi);
    assert_true(lo.x == 0 && hi.x == 0 && hi.z == 0);

    /* collider */
    char tri[512];
    tmp_path("meshes/tri.obj", tri, sizeof tri);
    assert_string_equal(dr_component_str(dr_element_component(cup, "Mesh"), "file"), tri);
    const double *rows = NULL;
    assert_int_equal(dr_component_table(dr_element_component(cup, "Motion"), "keys", &rows), 2);
    assert_true(rows[7] == 10.0 && rows[8] == 0.1 && rows[12] == 90.0);
    const DrComponent *col = dr_element_component(cup, "Collider");
    assert_false(dr_component_present(col));
    assert_true(dr_component_num(col, "friction") == 0.0);
    assert_string_equal(dr_component_str(col, "boundary"), "slip");
    assert_true(dr_component_num(dr_element_component(cup, "Transform"), "scale") == 1.0);

    assert_int_equal(dr_scene_asset_count(s), 1);
    assert_string_equal(dr_scene_asset(s, 0), tri);
    dr_scene_destroy(&s);
    assert_null(s);
    dr_scene_destroy(&s); /* NULL is a no-op */
}

static void test_element_kinds(void **state)
{
    (void)state;
    const char *types[] = {"liquid", "collider", "mpm_solid", "hair", "bem_solid", "bem_joint", "air"};
    const DrElementKind kinds[] = {DR_ELEMENT_LIQUID,    DR_ELEMENT_COLLIDER,  DR_ELEMENT_MPM_SOLID,
                                   DR_ELEMENT_HAIR,      DR_ELEMENT_BEM_SOLID, DR_ELEMENT_BEM_JOINT,
                                   DR_ELEMENT_AIR};
    for (int i = 0; i < 7; i++) {
        const DrElementSpec *t = dr_scene_element_spec(types[i]);
        assert_non_null(t);
        assert_int_equal(t->kind, kinds[i]);
    }
    DrScene *sc = NULL;
    DrError err;
    assert_int_equal(dr_scene_load("tests/data/golden_mix.json", &sc, &err), DR_OK);
    for (int i = 0; i < dr_scene_element_count(sc); i++) {
        const DrElement *e = dr_scene_element(sc, i);
        assert_int_equal(e->kind, e->spec->kind);
        assert_int_equal(dr_scene_count_kind(sc, e->kind), dr_scene_count_type(sc, e->type));
    }
    assert_int_equal(dr_scene_count_kind(sc, DR_ELEMENT_BEM_JOINT), 0);
    dr_scene_destroy(&sc);
}

static void test_empty_scene_is_all_defaults(void **state)
{
    (void)state;
    const char *texts[] = {"{}", "{\"elements\": []}", "{\"shot\": {}, \"render\": {\"camera\": {}}}"};
    for (int t = 0; t < 3; t++) {
        DrScene *s = load_text(texts[t]);
        assert_int_equal(dr_scene_element_count(s), 0);
        assert_int_equal(dr_scene_asset_count(s), 0);
        const DrComponent *shot = dr_scene_section(s, "shot");
        assert_int_equal(dr_component_present(shot), t == 2);
        assert_string_equal(dr_component_str(shot, "name"), "shot");
        assert_true(dr_component_num(shot, "fps") == 24.0);
        int fr[2];
        dr_component_int2(shot, "frames", fr);
        assert_true(fr[0] == 1 && fr[1] == 48);
        assert_true(dr_component_vec3(shot, "gravity").y == -9.81);
        assert_true(dr_component_num(dr_scene_section(s, "mesh"), "voxel_size") == 0.0);
        assert_true(dr_component_num(dr_scene_section(s, "render.camera"), "fov_deg") == 40.0);
        assert_true(dr_component_vec3(dr_scene_section(s, "render.camera"), "up").y == 1.0);
        DrSceneKeys k;
        DrError err;
        assert_int_equal(dr_scene_keys(s, &k, &err), DR_OK);
        assert_hex32(k.precompute);
        assert_hex32(k.bake);
        assert_hex32(k.mesh);
        assert_hex32(k.render);
        dr_scene_destroy(&s);
    }
}

static void test_asset_resolution(void **state)
{
    (void)state;
    char old_cwd[1024];
    assert_non_null(getcwd(old_cwd, sizeof old_cwd));
    assert_int_equal(chdir(g_dir), 0);
    mkdir("sub", 0755);
    write_file("sub/near.obj", TRI_OBJ); /* next to the scene */
    write_file("cwd_only.obj", TRI_OBJ); /* only relative to the current directory */
    write_file("near.obj", "v 9 9 9\n");  /* same name in cwd: the scene directory wins */
    char abs[600];
    snprintf(abs, sizeof abs, "%s/cwd_only.obj", g_dir);
    char text[2048];
    snprintf(text, sizeof text,
             "{\"elements\":["
             "{\"name\":\"a\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":\"near.obj\"}}},"
             "{\"name\":\"b\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":\"cwd_only.obj\"}}},"
             "{\"name\":\"c\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":\"near.obj\"}}},"
             "{\"name\":\"d\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":\"%s\"}}}]}",
             abs);
    write_file("sub/scene.json", text);
    DrScene *s = NULL;
    DrError err;
    DrStatus st = dr_scene_load("sub/scene.json", &s, &err);
    assert_int_equal(chdir(old_cwd), 0);
    if (st != DR_OK) fail_msg("%s", err.message);
    assert_string_equal(dr_component_str(dr_element_component(dr_scene_find(s, "a"), "Mesh"), "file"), "sub/near.obj");
    assert_string_equal(dr_component_str(dr_element_component(dr_scene_find(s, "b"), "Mesh"), "file"), "cwd_only.obj");
    assert_string_equal(dr_component_str(dr_element_component(dr_scene_find(s, "d"), "Mesh"), "file"), abs);
    /* distinct paths, first use order */
    assert_int_equal(dr_scene_asset_count(s), 3);
    assert_string_equal(dr_scene_asset(s, 0), "sub/near.obj");
    assert_string_equal(dr_scene_asset(s, 1), "cwd_only.obj");
    assert_string_equal(dr_scene_asset(s, 2), abs);
    dr_scene_destroy(&s);
}

/* ---- bad input: the shared files ------------------------------------------------------------------------ */

static DrStatus load_bad_file(const char *name, DrError *err)
{
    char path[1024];
    bad_file(name, path, sizeof path);
    DrScene *s = (DrScene *)(uintptr_t)1;
    DrStatus st = dr_scene_load(path, &s, err);
    assert_null(s);
    assert_string_equal(err->file, path);
    return st;
}

static void test_bad_files(void **state)
{
    (void)state;
    DrError err;
    /* syntax.json: the comma missing after the Domain line; jansson stops at the next key */
    assert_int_equal(load_bad_file("syntax.json", &err), DR_ERR_INPUT);
    assert_contains(err.message, "invalid JSON: ");
    assert_int_equal(err.line, 7);
    assert_int_equal(err.col, 22);

    assert_int_equal(load_bad_file("unknown_component.json", &err), DR_ERR_INPUT);
    assert_contains(err.message, "element 'water' (liquid): unknown component 'LiquidMaterail'; did you mean "
                                 "'LiquidMaterial'? Components of liquid: Domain, LiquidSource, ");
    assert_int_equal(err.line, 8); /* at the misspelt key */
    assert_int_equal(err.col, 9);

    assert_int_equal(load_bad_file("negative_density.json", &err), DR_ERR_INPUT);
    assert_contains(err.message, "water.LiquidMaterial.density = -5 is out of range [1, 100000] kg/m^3; use a "
                                 "positive density such as 1000 for water");
    assert_int_equal(err.line, 8); /* at the value */
    assert_int_equal(err.col, 40);

    assert_int_equal(load_bad_file("missing_asset.json", &err), DR_ERR_INPUT);
    assert_contains(err.message, "water.LiquidSource.mesh: asset 'meshes/does_not_exist.obj' not found (looked in ");
    assert_contains(err.message, "data/bad/ and in the current directory ");
    assert_int_equal(err.line, 7);

    assert_int_equal(load_bad_file("frames_order.json", &err), DR_ERR_INPUT);
    assert_contains(err.message, "shot.frames = [48, 1]: frames out of order");
    assert_int_equal(err.line, 2);
    assert_int_equal(err.col, 56);

    char buf[4096];
    dr_error_format(&err, buf, sizeof buf);
    assert_contains(buf, "frames_order.json:2:56: error: shot.frames");
}

/* ---- bad input: every other class ---------------------------------------------------------------------- */

typedef struct BadCase {
    const char *components; /* added to the liquid element's components (leading comma) */
    const char *top;        /* added at top level (leading comma) */
    const char *whole;      /* or the whole file */
    const char *expect[3];  /* substrings of the message */
} BadCase;

static void test_bad_input_messages(void **state)
{
    (void)state;
    write_tri();
    char tri[512], cup[1024];
    tmp_path("meshes/tri.obj", tri, sizeof tri);
    snprintf(cup, sizeof cup,
             ",\"elements\":[{\"name\":\"cup\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":\"%s\"},"
             "\"Motion\":{\"keys\":[[1,0,0,0,0,0,0],[5,0,0,0,0,0,0],[3,0,0,0,0,0,0]]}}}]",
             tri);
    char motion[1200];
    snprintf(motion, sizeof motion, "{\"shot\":{}%s}", cup);
    const BadCase cases[] = {
        {",\"LiquidMaterial\":{\"densty\":1}", "", NULL,
         {"water.LiquidMaterial: unknown field 'densty'; did you mean 'density'? Fields of LiquidMaterial: density, viscosity"}},
        {",\"LiquidMaterial\":{\"density\":\"heavy\"}", "", NULL,
         {"water.LiquidMaterial.density: expected a number, got string"}},
        {",\"Emitter\":{\"box\":[[0,0,0],[1,1,1]],\"velocity\":[0,1]}", "", NULL,
         {"water.Emitter.velocity: expected an array of 3 numbers [x, y, z], got an array of 2"}},
        {",\"Emitter\":{\"box\":[[0,0,0],[1,1,1]],\"velocity\":[0,\"up\",0]}", "", NULL,
         {"water.Emitter.velocity[1]: expected a number, got string"}},
        {",\"KillBox\":{\"box\":[[0,0,0],[1,-1,1]]}", "", NULL,
         {"water.KillBox.box: the lower corner must be below the upper corner on every axis, but on y it goes from 0 to -1"}},
        {",\"KillBox\":{\"box\":[[0,0,0]]}", "", NULL, {"water.KillBox.box: expected a box [[x0, y0, z0], [x1, y1, z1]]"}},
        {",\"Emitter\":{}", "", NULL, {"water.Emitter: missing required field 'box'", "add \"box\": [[x0, y0, z0], [x1, y1, z1]]"}},
        {",\"Emitter\":{\"box\":[[0,0,0],[1,1,1]],\"start\":2,\"end\":1}", "", NULL,
         {"water.Emitter: start = 2 s is after end = 1 s"}},
        {",\"Transfer\":{\"scheme\":\"apci\"}", "", NULL,
         {"water.Transfer.scheme: 'apci' is not a valid choice; did you mean 'apic'? Choose one of apic, flip, pic, rpic"}},
        {",\"Particles\":{\"per_cell\":2.5}", "", NULL, {"water.Particles.per_cell: expected an integer, got 2.5"}},
        {",\"Particles\":{\"per_cell\":65}", "", NULL, {"water.Particles.per_cell = 65 is out of range [1, 64]; "}},
        {",\"Mesh\":{\"file\":\"x.obj\"}", "", NULL,
         {"unknown component 'Mesh' ('Mesh' is a component of collider elements)", "Components of liquid: Domain"}},
        {"", ",\"shoot\":{}", NULL,
         {"unknown top-level key 'shoot'; did you mean 'shot'? Top-level keys: shot, solver, mesh, render, elements"}},
        {"", ",\"foo\":1", NULL, {"unknown top-level key 'foo'. Top-level keys: shot, solver, mesh, render, elements"}},
        {"", ",\"render.camera\":{}", NULL, {"unknown top-level key 'render.camera'"}},
        {"", ",\"shot\":{\"frames\":[1,2],\"gravity\":[0,-2000,0]}", NULL,
         {"shot.gravity[1] = -2000 is out of range [-1000, 1000] m/s^2"}},
        {"", ",\"shot\":{\"fps\":0}", NULL, {"shot.fps = 0 is out of range (0, 1000] 1/s; use a frame rate such as 24"}},
        {"", ",\"shot\":{\"name\":\"my shot\"}", NULL,
         {"shot.name: 'my shot' is not a valid name (it has a space, a control or a non-ASCII character)"}},
        {"", ",\"shot\":{\"name\":\"{water\"}", NULL, {"shot.name: '{water' is not a valid name (it has '{'); use letters"}},
        {",\"LiquidMaterial\":{\"viscoy\":1}", "", NULL, {"unknown field 'viscoy'; did you mean 'viscosity'?"}},
        {",\"LiquidMaterial\":{\"zzz\":1}", "", NULL, {"unknown field 'zzz'. Fields of LiquidMaterial: density, viscosity"}},
        {"", ",\"shot\":{\"name\":\"..\"}", NULL, {"shot.name: '..' is not a valid name ('.' and '..' are reserved)"}},
        {"", ",\"mesh\":{\"write_obj\":1}", NULL, {"mesh.write_obj: expected true or false, got number"}},
        {"", ",\"render\":{\"camra\":{}}", NULL,
         {"render: unknown field 'camra'; did you mean 'camera'? Fields of render: resolution, contact_every, samples, ground, camera"}},
        {"", ",\"render\":{\"camera\":{\"fov_deg\":170}}", NULL,
         {"render.camera.fov_deg = 170 is out of range (1, 170) deg"}},
        {"", ",\"render\":{\"camera\":{\"eye\":[0,0.1,0]}}", NULL, {"render.camera: eye and target are the same point"}},
        {"", ",\"render\":{\"camera\":{\"eye\":[0,1,0]}}", NULL, {"render.camera.up is zero or parallel to the view direction"}},
        {"", ",\"render\":{\"camera\":3}", NULL, {"render.camera: expected an object of fields"}},
        {NULL, NULL, motion, {"cup.Motion.keys[2]: frames out of order (frame 3 after frame 5)"}},
        {NULL, NULL,
         "{\"elements\":[{\"name\":\"water\",\"type\":\"liquidd\"}]}",
         {"element 'water': unknown type 'liquidd'; did you mean 'liquid'? Types: liquid, collider, mpm_solid, hair"}},
        {NULL, NULL,
         "{\"elements\":[{\"name\":\"w\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]}}},"
         "{\"name\":\"x\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]}}},"
         "{\"name\":\"w\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]}}}]}",
         {"elements[0] and elements[2] are both named 'w'; element names must be unique"}},
        {NULL, NULL, "{\"elements\":[{\"name\":\"water\",\"type\":\"liquid\"}]}",
         {"element 'water' (liquid): missing component 'Domain'", "add \"Domain\": {\"box\": [[x0, y0, z0], [x1, y1, z1]]}"}},
        {NULL, NULL, "{\"elements\":[{\"name\":\"rock\",\"type\":\"collider\",\"components\":{}}]}",
         {"element 'rock' (collider): missing component 'Mesh'", "add \"Mesh\": {\"file\": \"path/to/mesh.obj\"}"}},
        {NULL, NULL,
         "{\"elements\":[{\"name\":\"j\",\"type\":\"mpm_solid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]}}}]}",
         {"element 'j' (mpm_solid): missing component 'MpmShape'",
          "add \"MpmShape\": {\"box\": [[x0, y0, z0], [x1, y1, z1]]} to its components"}},
        {NULL, NULL,
         "{\"elements\":[{\"name\":\"w\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]},"
         "\"LiquidSource\":{\"velocity\":[0,0,0]}}}]}",
         {"w.LiquidSource: needs \"box\" or \"mesh\""}},
        {NULL, NULL, "{\"elements\":[{\"type\":\"liquid\"}]}", {"elements[0]: missing \"name\""}},
        {NULL, NULL, "{\"elements\":[{\"name\":\"w\"}]}", {"element 'w': missing \"type\"; add \"type\": one of liquid, collider, mpm_solid, hair"}},
        {NULL, NULL, "{\"elements\":[{\"name\":\"w\",\"type\":\"liquid\",\"component\":{}}]}",
         {"elements[0]: unknown key 'component'; did you mean 'components'?"}},
        {NULL, NULL, "{\"elements\":[{\"name\":\"w\",\"type\":\"liquid\",\"components\":[]}]}",
         {"element 'w' (liquid): \"components\" must be an object"}},
        {NULL, NULL, "{\"elements\":[3]}", {"elements[0]: expected an element object"}},
        {NULL, NULL, "{\"elements\":{}}", {"elements: expected an array of element objects, got object"}},
        {NULL, NULL, "[1, 2]", {"the scene must be a JSON object"}},
        {NULL, NULL, "{\"shot\":{},\n \"shot\":{}}", {"invalid JSON: duplicate object key"}},
        {NULL, NULL, "{\"shot\":{\"fps\":1e999}}", {"invalid JSON: real number overflow"}},
        {NULL, NULL, "", {"invalid JSON: "}},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        const BadCase *c = &cases[i];
        char text[4096];
        if (c->whole)
            snprintf(text, sizeof text, "%s", c->whole);
        else
            liquid_scene(c->components, c->top, text, sizeof text);
        DrError err;
        DrStatus st = load_bad(text, &err);
        if (st != DR_ERR_INPUT) fail_msg("case %zu: status %d for %s", i, (int)st, text);
        for (int k = 0; k < 3 && c->expect[k]; k++) {
            if (!strstr(err.message, c->expect[k]))
                fail_msg("case %zu: expected \"%s\" in \"%s\"", i, c->expect[k], err.message);
        }
        if (err.line < 1 || err.col < 1) fail_msg("case %zu: no position (%d:%d) for %s", i, err.line, err.col, err.message);
    }
}

static void test_missing_scene_file(void **state)
{
    (void)state;
    DrScene *s = NULL;
    DrError err;
    assert_int_equal(dr_scene_load("/nonexistent/drench/scene.json", &s, &err), DR_ERR_INPUT);
    assert_null(s);
    assert_string_equal(err.file, "/nonexistent/drench/scene.json");
    assert_contains(err.message, "cannot open the scene file");
    assert_int_equal(dr_scene_load(g_dir, &s, &err), DR_ERR_INPUT); /* a directory */
    assert_null(s);
}

/* Line and 1-based column (characters, not bytes) of the first `needle` in text: what an editor shows. */
static void position_of(const char *text, const char *needle, int *line, int *col)
{
    const char *at = strstr(text, needle);
    assert_non_null(at);
    *line = 1;
    *col = 1;
    for (const char *c = text; c < at; c++) {
        if (*c == '\n') {
            (*line)++;
            *col = 1;
        } else if ((*c & 0xC0) != 0x80) {
            (*col)++;
        }
    }
}

static void assert_error_at(const char *text, const char *needle, const char *message)
{
    DrError err;
    int line, col;
    position_of(text, needle, &line, &col);
    assert_int_equal(load_bad(text, &err), DR_ERR_INPUT);
    assert_contains(err.message, message);
    if (err.line != line || err.col != col)
        fail_msg("\"%s\" reported at %d:%d, expected %d:%d (at %s)", message, err.line, err.col, line, col, needle);
}

/* Semantic errors point at the key or value in the text, past escapes, multi-byte characters, and
 * strings and arrays that hold brackets. */
static void test_error_positions(void **state)
{
    (void)state;
    assert_error_at("{\n  \"shot\": { \"name\": \"caf\\u00e9\" },\n  \"elements\": []\n}\n", "\"caf", "shot.name: ");
    assert_error_at("{\"elements\": [ { \"name\": \"w\", \"type\": \"liquid\", \"components\": {\n"
                    "    \"Domain\": { \"box\": [[0, 0, 0], [1, 1, 1]] },\n"
                    "    \"LiquidMaterial\": { \"é\": 1, \"density\": -5 } } } ]\n}\n",
                    "\"é\"", "w.LiquidMaterial: unknown field 'é'");
    assert_error_at("{\"elements\": [ { \"name\": \"w\", \"type\": \"liquid\", \"components\": {\n"
                    "    \"Domain\": { \"voxel_size\": 0.05, \"box\": [[0, 0, 0], [1, 1, 1]] },\n"
                    "    \"Particles\": { \"seed\": 3 },\n"
                    "    \"LiquidMaterial\": { \"viscosity\": 0.1,\n"
                    "      \"dens\\u0069ty\": -5 } } } ]\n}\n",
                    "-5", "w.LiquidMaterial.density = -5 is out of range");
    assert_error_at("{\"elements\": [ { \"name\": \"w\", \"type\": \"liquid\", \"components\": {\n"
                    "    \"Domain\": { \"box\": [[0, 0, 0], [1, 1, 1]] }, \"Emitter\": { } } } ]\n}\n",
                    "\"Emitter\"", "w.Emitter: missing required field 'box'");

    /* a file whose name has a multi-byte character, a quote and brackets, before the culprit on its line */
    char odd[512], text[2048];
    tmp_path("odd é\"}].obj", odd, sizeof odd);
    write_file(odd, TRI_OBJ);
    char esc[600];
    size_t n = 0;
    for (const char *c = odd; *c && n + 2 < sizeof esc; c++) {
        if (*c == '"') esc[n++] = '\\';
        esc[n++] = *c;
    }
    esc[n] = '\0';
    snprintf(text, sizeof text,
             "{\"elements\": [\n"
             "  { \"name\": \"cup\", \"type\": \"collider\", \"components\": { \"Mesh\": { \"file\": \"%s\" }, "
             "\"Motion\": { \"keys\": [[1, 0, 0, 0, 0, 0, 0], [2, 0, 0, 0, 0, 0, 0]] }, "
             "\"Collider\": { \"fricti\\u006fn\": -1 } } } ]\n}\n",
             esc);
    assert_error_at(text, "-1", "cup.Collider.friction = -1 is out of range [0, 10]");
}

/* ---- hair ------------------------------------------------------------------------------------------------ */

/* A scene of one hair element "fur" with the given components (the text inside "components": {...}). */
static void hair_scene(const char *components, char *buf, size_t size)
{
    snprintf(buf, size, "{\"elements\":[{\"name\":\"fur\",\"type\":\"hair\",\"components\":{%s}}]}", components);
}

static void write_curves(void)
{
    char path[512];
    tmp_path("meshes/curves.obj", path, sizeof path);
    write_file(path, "v 0 0 0\nv 0 1 0\nl 1 2\n");
}

static void test_hair_defaults(void **state)
{
    (void)state;
    write_tri();
    char text[4096];
    hair_scene("\"Groom\":{\"scalp\":\"meshes/tri.obj\"}", text, sizeof text);
    DrScene *s = load_text(text);
    assert_int_equal(dr_scene_count_type(s, "hair"), 1);
    const DrElement *fur = dr_scene_find(s, "fur");
    assert_string_equal(fur->type, "hair");
    char tri[512];
    tmp_path("meshes/tri.obj", tri, sizeof tri);
    const DrComponent *groom = dr_element_component(fur, "Groom");
    assert_true(dr_component_present(groom));
    assert_string_equal(dr_component_str(groom, "scalp"), tri);
    assert_false(dr_component_is_set(groom, "curves"));
    assert_null(dr_component_str(groom, "curves"));
    assert_int_equal(dr_component_int(groom, "count"), 100);
    assert_true(dr_component_num(groom, "length") == 0.05);
    assert_int_equal(dr_component_int(groom, "segments"), 12);
    assert_true(dr_component_num(groom, "curl_radius") == 0.0);
    assert_true(dr_component_num(groom, "curl_pitch") == 0.01);
    assert_true(dr_component_num(groom, "length_jitter") == 0.0);
    assert_int_equal(dr_component_int(groom, "seed"), 1);
    assert_string_equal(dr_component_str(groom, "roots"), "clamped");
    const DrComponent *mat = dr_element_component(fur, "RodMaterial");
    assert_false(dr_component_present(mat));
    assert_true(dr_component_num(mat, "radius") == 5e-5);
    assert_true(dr_component_num(mat, "density") == 1300.0);
    assert_true(dr_component_num(mat, "youngs_modulus") == 3.9e9);
    assert_true(dr_component_num(mat, "shear_modulus") == 1.3e9);
    assert_true(dr_component_num(mat, "damping") == 0.0);
    const DrComponent *col = dr_element_component(fur, "Collider");
    assert_true(dr_component_num(col, "friction") == 0.0 && dr_component_num(col, "thickness") == 0.0);
    assert_true(dr_component_num(dr_element_component(fur, "Transform"), "scale") == 1.0);
    const double *rows;
    assert_int_equal(dr_component_table(dr_element_component(fur, "Motion"), "keys", &rows), 0);
    const DrComponent *grp = dr_element_component(fur, "CollisionGroup");
    assert_int_equal(dr_component_int(grp, "group"), 0);
    assert_int_equal(dr_component_int(grp, "collides_with"), 2147483647);
    assert_true(dr_component_bool(grp, "self_collision"));
    const DrComponent *resp = dr_element_component(fur, "CollisionResponse");
    assert_true(dr_component_num(resp, "stiffness") == 10);
    assert_true(dr_component_num(resp, "friction") == 0.2);
    assert_true(dr_component_num(resp, "thickness") == 0.0);
    const DrComponent *sol = dr_element_component(fur, "HairSolver");
    assert_string_equal(dr_component_str(sol, "preconditioner"), "block");
    assert_true(dr_component_num(sol, "tolerance") == 1e-6);
    assert_int_equal(dr_component_int(sol, "max_iterations"), 500);
    assert_int_equal(dr_component_int(sol, "substeps"), 1);
    assert_true(dr_component_bool(sol, "geometric_stiffness"));
    assert_int_equal(dr_scene_asset_count(s), 1);
    assert_string_equal(dr_scene_asset(s, 0), tri);
    dr_scene_destroy(&s);

    /* every component written, curves instead of a scalp; two hair elements with one HairSolver */
    write_curves();
    const char *full = "\"Groom\":{\"curves\":\"meshes/curves.obj\",\"roots\":\"free\"},"
                       "\"RodMaterial\":{\"radius\":4e-5,\"density\":1100,\"youngs_modulus\":2e9,"
                       "\"shear_modulus\":7e8,\"damping\":0.01},"
                       "\"Collider\":{\"friction\":0.3,\"thickness\":1e-4},"
                       "\"Transform\":{\"translate\":[0,1,0]},\"Motion\":{\"keys\":[[1,0,0,0,0,0,0],[5,0,0.1,0,0,0,0]]},"
                       "\"CollisionGroup\":{\"group\":3,\"collides_with\":9,\"self_collision\":false},"
                       "\"CollisionResponse\":{\"stiffness\":500,\"friction\":0.4,\"thickness\":2e-5},"
                       "\"HairSolver\":{\"preconditioner\":\"jacobi\",\"tolerance\":1e-8,\"max_iterations\":50,"
                       "\"substeps\":4,\"geometric_stiffness\":false}";
    snprintf(text, sizeof text,
             "{\"elements\":[{\"name\":\"fur\",\"type\":\"hair\",\"components\":{%s}},"
             "{\"name\":\"mane\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\","
             "\"count\":7,\"curl_radius\":0.002},\"HairSolver\":{\"preconditioner\":\"jacobi\",\"tolerance\":1e-8,"
             "\"max_iterations\":50,\"substeps\":4,\"geometric_stiffness\":false}}}]}",
             full);
    s = load_text(text);
    fur = dr_scene_find(s, "fur");
    groom = dr_element_component(fur, "Groom");
    char curves[512];
    tmp_path("meshes/curves.obj", curves, sizeof curves);
    assert_string_equal(dr_component_str(groom, "curves"), curves);
    assert_null(dr_component_str(groom, "scalp"));
    assert_string_equal(dr_component_str(groom, "roots"), "free"); /* for curves too */
    assert_string_equal(dr_component_str(dr_element_component(dr_scene_find(s, "mane"), "Groom"), "roots"), "clamped");
    mat = dr_element_component(fur, "RodMaterial");
    assert_true(dr_component_num(mat, "radius") == 4e-5 && dr_component_num(mat, "damping") == 0.01);
    assert_true(dr_component_num(dr_element_component(fur, "Collider"), "friction") == 0.3);
    grp = dr_element_component(fur, "CollisionGroup");
    assert_int_equal(dr_component_int(grp, "group"), 3);
    assert_int_equal(dr_component_int(grp, "collides_with"), 9);
    assert_false(dr_component_bool(grp, "self_collision"));
    assert_true(dr_component_num(dr_element_component(fur, "CollisionResponse"), "stiffness") == 500.0);
    sol = dr_element_component(fur, "HairSolver");
    assert_string_equal(dr_component_str(sol, "preconditioner"), "jacobi");
    assert_int_equal(dr_component_int(sol, "substeps"), 4);
    assert_false(dr_component_bool(sol, "geometric_stiffness"));
    const DrElement *mane = dr_scene_find(s, "mane");
    assert_int_equal(dr_component_int(dr_element_component(mane, "Groom"), "count"), 7);
    assert_true(dr_component_num(dr_element_component(mane, "Groom"), "curl_radius") == 0.002);
    assert_int_equal(dr_scene_asset_count(s), 2);
    char *c = dr_scene_canonical(s, "elements");
    assert_non_null(strstr(c, "\"CollisionGroup\":{\"collides_with\":9,\"group\":3,\"self_collision\":false}"));
    assert_non_null(strstr(c, "\"Groom\":{\"count\":100,\"curl_pitch\":0.01,\"curl_radius\":0,"
                              "\"curves\":\"meshes/curves.obj\",\"length\":0.050000000000000003,"));
    free(c);
    dr_scene_destroy(&s);
}

static void test_hair_bad_input(void **state)
{
    (void)state;
    write_tri();
    write_curves();
    struct {
        const char *components; /* of the element "fur"; or the whole file */
        const char *whole;
        const char *expect[2];
    } cases[] = {
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"RodMaterial\":{\"radius\":-1}", NULL,
         {"fur.RodMaterial.radius = -1 is out of range (0, 0.1] m; use a positive radius such as 5e-5 (human hair)"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"count\":0}", NULL,
         {"fur.Groom.count = 0 is out of range [1, 1000000]"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"segments\":1001}", NULL,
         {"fur.Groom.segments = 1001 is out of range [1, 1000]"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"length\":0}", NULL,
         {"fur.Groom.length = 0 is out of range (0, 100] m; use a positive length such as 0.05"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"length_jitter\":1}", NULL,
         {"fur.Groom.length_jitter = 1 is out of range [0, 1)"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"curl_pitch\":0}", NULL,
         {"fur.Groom.curl_pitch = 0 is out of range (0, 10] m"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"curl_radus\":0.01}", NULL,
         {"fur.Groom: unknown field 'curl_radus'; did you mean 'curl_radius'? Fields of Groom: scalp, curves, count"}},
        {"\"Groom\":{}", NULL,
         {"fur.Groom: no strands; add \"scalp\": \"path/to/scalp.obj\" to grow them from a mesh, or \"curves\": "
          "\"path/to/curves.obj\" to read OBJ polylines"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"curves\":\"meshes/curves.obj\"}", NULL,
         {"fur.Groom: both scalp and curves are given, but a groom comes from exactly one: keep scalp"}},
        {"\"Groom\":{\"curves\":\"meshes/curves.obj\",\"count\":10}", NULL,
         {"fur.Groom.count applies to strands grown from a scalp; with curves the strands are the file's polylines: "
          "remove count"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\",\"roots\":\"loose\"}", NULL,
         {"fur.Groom.roots: 'loose' is not a valid choice", "Choose one of clamped, pinned, free"}},
        {"\"Groom\":{\"curves\":\"meshes/curves.obj\",\"roots\":true}", NULL, {"fur.Groom.roots"}},
        {"\"Groom\":{\"scalp\":\"meshes/no_scalp.obj\"}", NULL,
         {"fur.Groom.scalp: asset 'meshes/no_scalp.obj' not found"}},
        {"\"RodMaterial\":{}", NULL,
         {"element 'fur' (hair): missing component 'Groom'", "add \"Groom\": {\"scalp\": \"path/to/scalp.obj\"}"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"RodMaterail\":{}", NULL,
         {"element 'fur' (hair): unknown component 'RodMaterail'; did you mean 'RodMaterial'?",
          "Components of hair: Groom, RodMaterial, Collider"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"Collider\":{\"boundary\":\"no_slip\"}", NULL,
         {"fur.Collider.boundary is the velocity condition of liquid at a collider surface and does not apply to "
          "hair; remove it"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"CollisionGroup\":{\"group\":31}", NULL,
         {"fur.CollisionGroup.group = 31 is out of range [0, 30]"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"CollisionGroup\":{\"collides_with\":-1}", NULL,
         {"fur.CollisionGroup.collides_with = -1 is out of range [0, 2147483647]"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"CollisionResponse\":{\"stiffness\":0}", NULL,
         {"fur.CollisionResponse.stiffness = 0 is out of range (0, 1000000000] N/m"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"HairSolver\":{\"preconditioner\":\"jacoby\"}", NULL,
         {"fur.HairSolver.preconditioner: 'jacoby' is not a valid choice; did you mean 'jacobi'? Choose one of "
          "block, cluster, jacobi, none"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"HairSolver\":{\"substeps\":0}", NULL,
         {"fur.HairSolver.substeps = 0 is out of range [1, 100000]"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"Drag\":{}", NULL,
         {"fur.Drag couples hair element 'fur' with the scene's fluid, but the scene has neither a liquid nor an air "
          "element; add a liquid or an air element, or remove Drag"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"Drag\":{\"tangent_scale\":-1}", NULL,
         {"fur.Drag.tangent_scale = -1 is out of range [0, 1000000]"}},
        {"\"Groom\":{\"scalp\":\"meshes/tri.obj\"},\"Domain\":{}", NULL,
         {"unknown component 'Domain' ('Domain' is a component of liquid elements)"}},
        {NULL,
         "{\"elements\":[{\"name\":\"a\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"}}},"
         "{\"name\":\"b\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"},"
         "\"HairSolver\":{\"tolerance\":0.001}}}]}",
         {"b.HairSolver.tolerance = 0.001 differs from a.HairSolver.tolerance = 1e-06; every hair element of a scene "
          "is solved in one system, so give both elements the same HairSolver.tolerance"}},
        {NULL,
         "{\"elements\":[{\"name\":\"a\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"}}},"
         "{\"name\":\"b\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"},"
         "\"HairSolver\":{\"geometric_stiffness\":false}}}]}",
         {"b.HairSolver.geometric_stiffness = false differs from a.HairSolver.geometric_stiffness = true"}},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char text[4096];
        if (cases[i].whole) snprintf(text, sizeof text, "%s", cases[i].whole);
        else hair_scene(cases[i].components, text, sizeof text);
        /* the scene sits in g_dir, where meshes/ is */
        char path[512];
        tmp_path("hair.json", path, sizeof path);
        write_file(path, text);
        DrScene *s = (DrScene *)(uintptr_t)1;
        DrError err;
        DrStatus st = dr_scene_load(path, &s, &err);
        assert_null(s);
        if (st != DR_ERR_INPUT) fail_msg("case %zu: status %d for %s", i, (int)st, text);
        for (int k = 0; k < 2 && cases[i].expect[k]; k++)
            if (!strstr(err.message, cases[i].expect[k]))
                fail_msg("case %zu: expected \"%s\" in \"%s\"", i, cases[i].expect[k], err.message);
        if (err.line < 1 || err.col < 1) fail_msg("case %zu: no position for %s", i, err.message);
    }

    /* positions: the Groom key, the second source, the stray field, Collider.boundary, the differing field */
    const char *text = "{\"elements\": [\n"
                       "  { \"name\": \"fur\", \"type\": \"hair\", \"components\": {\n"
                       "      \"Groom\": { \"count\": 3 } } } ]\n}\n";
    assert_error_at(text, "\"Groom\"", "fur.Groom: no strands");
    text = "{\"elements\": [\n"
           "  { \"name\": \"fur\", \"type\": \"hair\", \"components\": {\n"
           "      \"Groom\": { \"scalp\": \"meshes/tri.obj\",\n"
           "                 \"curves\": \"meshes/curves.obj\" } } } ]\n}\n";
    assert_error_at(text, "\"curves\"", "fur.Groom: both scalp and curves");
    text = "{\"elements\": [\n"
           "  { \"name\": \"fur\", \"type\": \"hair\", \"components\": {\n"
           "      \"Groom\": { \"curves\": \"meshes/curves.obj\", \"seed\": 4 } } } ]\n}\n";
    assert_error_at(text, "\"seed\"", "fur.Groom.seed applies to strands grown from a scalp");
    text = "{\"elements\": [\n"
           "  { \"name\": \"fur\", \"type\": \"hair\", \"components\": { \"Groom\": { \"scalp\": \"meshes/tri.obj\" },\n"
           "      \"Collider\": { \"friction\": 0.1, \"boundary\": \"slip\" } } } ]\n}\n";
    assert_error_at(text, "\"boundary\"", "fur.Collider.boundary is the velocity condition");
    text = "{\"elements\": [\n"
           "  { \"name\": \"a\", \"type\": \"hair\", \"components\": { \"Groom\": { \"scalp\": \"meshes/tri.obj\" } } },\n"
           "  { \"name\": \"b\", \"type\": \"hair\", \"components\": { \"Groom\": { \"scalp\": \"meshes/tri.obj\" },\n"
           "      \"HairSolver\": { \"preconditioner\": \"none\" } } } ]\n}\n";
    assert_error_at(text, "\"none\"", "b.HairSolver.preconditioner = 'none' differs from a.HairSolver.preconditioner = 'block'");
    /* wet hair elements share one film model: Film.max_ratio must agree, Film.initial_ratio may differ */
    text = "{\"elements\": [\n"
           "  { \"name\": \"a\", \"type\": \"hair\", \"components\": { \"Groom\": { \"scalp\": \"meshes/tri.obj\" },\n"
           "      \"Wetting\": {}, \"Film\": { \"initial_ratio\": 2 } } },\n"
           "  { \"name\": \"b\", \"type\": \"hair\", \"components\": { \"Groom\": { \"scalp\": \"meshes/tri.obj\" },\n"
           "      \"Wetting\": {}, \"Film\": { \"initial_ratio\": 3, \"max_ratio\": 4 } } } ]\n}\n";
    assert_error_at(text, "4 } } }", "b.Film.max_ratio = 4 differs from a.Film.max_ratio = 6; the strands of every "
                                           "wet hair element share one film, cohesion, cross-flow, capture and dripping model");
    text = "{\"elements\": [\n"
           "  { \"name\": \"a\", \"type\": \"hair\", \"components\": { \"Groom\": { \"scalp\": \"meshes/tri.obj\" },\n"
           "      \"Wetting\": {}, \"Film\": { \"initial_ratio\": 2 } } },\n"
           "  { \"name\": \"b\", \"type\": \"hair\", \"components\": { \"Groom\": { \"scalp\": \"meshes/tri.obj\" },\n"
           "      \"Wetting\": {}, \"Film\": { \"initial_ratio\": 3 } } } ]\n}\n";
    DrScene *wet = load_text(text);
    dr_scene_destroy(&wet);
}

/* ---- bem_solid ------------------------------------------------------------------------------------------- */

/* A scene of one bem_solid element "jelly" with the given components (the text inside "components": {...}). */
static void bem_scene(const char *components, char *buf, size_t size)
{
    snprintf(buf, size, "{\"elements\":[{\"name\":\"jelly\",\"type\":\"bem_solid\",\"components\":{%s}}]}",
             components);
}

/* The same after a "shot" section (the text inside "shot": {...}). */
static void bem_shot_scene(const char *shot, const char *components, char *buf, size_t size)
{
    snprintf(buf, size,
             "{\"shot\":{%s},\"elements\":[{\"name\":\"jelly\",\"type\":\"bem_solid\",\"components\":{%s}}]}", shot,
             components);
}

/* The air element: defaults (air at sea level, a closed box), and bad values named element.component.field with
   the value, the range and the fix; at most one air element, and none beside a liquid. */
static void test_air(void **state)
{
    (void)state;
    DrScene *s = load_text("{\"elements\":[{\"name\":\"gust\",\"type\":\"air\",\"components\":{"
                           "\"AirDomain\":{\"box\":[[0,0,0],[1,1,1]]}}}]}");
    const DrElement *e = dr_scene_find(s, "gust");
    assert_int_equal(e->kind, DR_ELEMENT_AIR);
    assert_true(dr_component_num(dr_element_component(e, "AirMaterial"), "density") == 1.2);
    assert_true(dr_component_num(dr_element_component(e, "AirMaterial"), "viscosity") == 1.8e-5);
    assert_true(dr_component_num(dr_element_component(e, "AirDomain"), "voxel_size") == 0.02);
    const DrComponent *w = dr_element_component(e, "Wind");
    assert_string_equal(dr_component_str(w, "face"), "-x");
    assert_true(dr_v3_norm(dr_component_vec3(w, "velocity")) == 0.0);
    assert_string_equal(dr_component_str(w, "initial"), "rest");
    dr_scene_destroy(&s);
    const char *head = "{\"elements\":[{\"name\":\"gust\",\"type\":\"air\",\"components\":{"
                       "\"AirDomain\":{\"box\":[[0,0,0],[1,1,1]]}";
    struct {
        const char *tail, *says[3];
    } cases[] = {
        {",\"AirMaterial\":{\"density\":0}}}]}", {"gust.AirMaterial.density = 0 is out of range (0, 1000] kg/m^3",
                                                    "such as 1.2 for air"}},
        {",\"AirMaterial\":{\"viscosity\":-1}}}]}", {"gust.AirMaterial.viscosity = -1 is out of range [0, 10] Pa*s"}},
        {",\"Wind\":{\"face\":\"x\"}}}]}", {"gust.Wind.face: 'x' is not a valid choice", "-x, +x, -y, +y, -z, +z"}},
        {",\"Wind\":{\"face\":\"+y\",\"velocity\":[0,3,0]}}}]}",
         {"gust.Wind.velocity: its y component (3 m/s) points out of the box through face +y", "make it negative",
          "set face to \"-y\""}},
        {",\"Wind\":{\"velocity\":[0,0,2]}}}]}", {"gust.Wind.velocity has no x component", "[0, 0, 0] for a closed box"}},
        {",\"Wind\":{\"velocity\":[2,0,0],\"ramp\":-1}}}]}", {"gust.Wind.ramp = -1 is out of range [0, 1000000] s"}},
        {",\"Wind\":{\"initial\":\"moving\"}}}]}", {"gust.Wind.initial: 'moving' is not a valid choice", "rest, stream"}},
        {"}},{\"name\":\"breeze\",\"type\":\"air\",\"components\":{\"AirDomain\":{\"box\":"
         "[[0,0,0],[1,1,1]]}}}]}", {"air elements 'gust' and 'breeze'", "at most one air element"}},
        {"}},{\"name\":\"water\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]}}}]}",
         {"air element 'gust' and liquid element 'water'", "not supported yet"}},
        {"}}]}", {NULL}},
    };
    for (size_t k = 0; cases[k].says[0]; k++) {
        char text[1024];
        snprintf(text, sizeof text, "%s%s", head, cases[k].tail);
        DrError err;
        assert_int_equal(load_bad(text, &err), DR_ERR_INPUT);
        for (int m = 0; m < 3 && cases[k].says[m]; m++) assert_contains(err.message, cases[k].says[m]);
    }
}

/* Collision elements: members by name, a method, pairs; the pair lookup the world uses; and every rule's error. */
#define COLL_HAIR(n) "{\"name\":\"" n "\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"}}}"
#define COLL_CLOTH(n) "{\"name\":\"" n "\",\"type\":\"cloth\",\"components\":{\"Mesh\":{\"file\":\"meshes/tri.obj\"}}}"
#define COLL(n, body) "{\"name\":\"" n "\",\"type\":\"collision\",\"components\":{" body "}}"

static void test_collision_elements(void **state)
{
    (void)state;
    DrScene *s = load_text("{\"elements\":[" COLL_HAIR("a") "," COLL_HAIR("b") "," COLL_CLOTH("c") ","
                           COLL("ab", "\"Collision\":{\"members\":[\"a\",\"b\"],\"method\":\"edge_edge\","
                                      "\"pairs\":\"between\"},\"CollisionResponse\":{\"stiffness\":20,\"damping\":0.01}")
                           "," COLL("aa", "\"Collision\":{\"members\":[\"a\"],\"method\":\"edge_edge\"}") ","
                           COLL("cc", "\"Collision\":{\"members\":[\"c\"],\"method\":\"vertex_face\"}") "]}");
    const DrElement *ab = dr_scene_find(s, "ab");
    assert_int_equal(ab->kind, DR_ELEMENT_COLLISION);
    const char *const *m = NULL;
    assert_int_equal(dr_component_names(dr_element_component(ab, "Collision"), "members", &m), 2);
    assert_string_equal(m[0], "a");
    assert_string_equal(m[1], "b");
    assert_float_equal(dr_component_num(dr_element_component(ab, "CollisionResponse"), "damping"), 0.01, 0);
    assert_ptr_equal(dr_scene_collision(s, "a", "b", "edge_edge"), ab);
    assert_ptr_equal(dr_scene_collision(s, "b", "a", "edge_edge"), ab);
    assert_ptr_equal(dr_scene_collision(s, "a", "a", "edge_edge"), dr_scene_find(s, "aa"));
    assert_null(dr_scene_collision(s, "b", "b", "edge_edge")); /* pairs "between" leaves b's own contacts out */
    assert_null(dr_scene_collision(s, "a", "b", "vertex_face"));
    assert_ptr_equal(dr_scene_collision(s, "c", "c", "vertex_face"), dr_scene_find(s, "cc"));
    char *canon = dr_scene_canonical(s, "elements");
    assert_non_null(strstr(canon, "\"Collision\":{\"members\":[\"a\",\"b\"],\"method\":\"edge_edge\",\"pairs\":\"between\"}"));
    free(canon);
    dr_scene_destroy(&s);

    struct {
        const char *text, *expect;
    } cases[] = {
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":[\"fur\"],\"method\":\"edge_edge\"}")
         "]}", "k.Collision.members[0] = 'fur': no hair or cloth element has this name. Hair and cloth elements: a"},
        {"{\"elements\":[" COLL_HAIR("fur") "," COLL("k", "\"Collision\":{\"members\":[\"fru\"],\"method\":\"edge_edge\"}")
         "]}", "k.Collision.members[0] = 'fru': no hair or cloth element has this name; did you mean 'fur'?"},
        {"{\"elements\":[" COLL_HAIR("a") ",{\"name\":\"head\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":"
         "\"meshes/tri.obj\"}}}," COLL("k", "\"Collision\":{\"members\":[\"a\",\"head\"],\"method\":\"edge_edge\"}") "]}",
         "k.Collision.members[1] = 'head' is a collider element; members are hair or cloth elements"},
        {"{\"elements\":[" COLL_CLOTH("c") "," COLL("k", "\"Collision\":{\"members\":[\"c\"],\"method\":\"edge_edge\"}")
         "]}", "k.Collision.members[0] = 'c' is a cloth element, and method \"edge_edge\" meets strand segments: a cloth "
         "panel meets itself, and hair, with method \"vertex_face\""},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":[\"a\"],\"method\":\"vertex_face\"}")
         "]}", "k.Collision: with method \"vertex_face\" a hair member meets the cloth members' triangles (strands meet "
         "strands with \"edge_edge\"), and it lists no cloth element"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":[\"a\"],\"method\":\"edge_edge\","
         "\"pairs\":\"between\"}") "]}", "k.Collision.pairs = \"between\" meets different members only"},
        {"{\"elements\":[" COLL_CLOTH("c") "," COLL_CLOTH("d") "," COLL("k", "\"Collision\":{\"members\":[\"c\",\"d\"],"
         "\"method\":\"vertex_face\"}") "]}", "k.Collision: contact between two cloth panels is not built yet"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL_HAIR("b") "," COLL("k", "\"Collision\":{\"members\":[\"a\",\"b\"],"
         "\"method\":\"edge_edge\"}") "," COLL("q", "\"Collision\":{\"members\":[\"b\"],\"method\":\"edge_edge\"}") "]}",
         "k and q both meet b with itself (method \"edge_edge\"); a pair takes one response"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL_HAIR("b") "," COLL("k", "\"Collision\":{\"members\":[\"a\",\"b\"],"
         "\"method\":\"edge_edge\",\"pairs\":\"between\"}") "," COLL("q", "\"Collision\":{\"members\":[\"b\",\"a\"],"
         "\"method\":\"edge_edge\"}") "]}", "k and q both meet b with a (method \"edge_edge\")"},
        {"{\"elements\":[{\"name\":\"a\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"},"
         "\"CollisionGroup\":{\"group\":1}}}," COLL("k", "\"Collision\":{\"members\":[\"a\"],\"method\":\"edge_edge\"}")
         "]}", "a.CollisionGroup is the shorthand of collision elements, and this scene has collision elements"},
        {"{\"elements\":[{\"name\":\"c\",\"type\":\"cloth\",\"components\":{\"Mesh\":{\"file\":\"meshes/tri.obj\"},"
         "\"ClothMaterial\":{\"self_contact\":true}}}," COLL("k", "\"Collision\":{\"members\":[\"c\"],\"method\":"
         "\"vertex_face\",\"pairs\":\"between\"},\"CollisionResponse\":{}") "," COLL_CLOTH("d") "]}",
         "c.ClothMaterial.self_contact = true, and no collision element meets c with itself"},
        {"{\"elements\":[{\"name\":\"c\",\"type\":\"cloth\",\"components\":{\"Mesh\":{\"file\":\"meshes/tri.obj\"},"
         "\"ClothMaterial\":{\"self_contact\":false}}}," COLL("k", "\"Collision\":{\"members\":[\"c\"],\"method\":"
         "\"vertex_face\"}") "]}", "c.ClothMaterial.self_contact = false, and collision element k meets c with itself"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":[],\"method\":\"edge_edge\"}") "]}",
         "k.Collision.members: the list is empty; name at least one element"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":\"a\",\"method\":\"edge_edge\"}") "]}",
         "k.Collision.members: expected a list of element names [\"a\", \"b\", ...], got string"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":[\"a\",\"a\"],\"method\":"
         "\"edge_edge\"}") "]}", "k.Collision.members[1]: 'a' is listed twice (also at [0]); list each element once"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":[\"a\"]}") "]}",
         "k.Collision: missing required field 'method' (how contacts are found: edge_edge between strand segments "
         "(hair members), vertex_face between a panel's vertices and its triangles (cloth members)); add \"method\": "
         "\"edge_edge\" (one of edge_edge, vertex_face)"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"Collision\":{\"members\":[\"a\"],\"method\":\"edge_edge\"},"
         "\"CollisionResponse\":{\"damping\":-1}") "]}", "k.CollisionResponse.damping = -1 is out of range [0, 10] s"},
        {"{\"elements\":[" COLL_HAIR("a") "," COLL("k", "\"CollisionResponse\":{}") "]}",
         "element 'k' (collision): missing component 'Collision' (the members of a collision element and the method "
         "that finds their contacts); add \"Collision\": {\"members\": [\"name\", ...], \"method\": \"edge_edge\" (one "
         "of edge_edge, vertex_face)} to its components"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        DrError err;
        if (load_bad(cases[i].text, &err) != DR_ERR_INPUT) fail_msg("case %zu: not an input error", i);
        if (!strstr(err.message, cases[i].expect))
            fail_msg("case %zu: expected \"%s\" in \"%s\"", i, cases[i].expect, err.message);
        if (err.line < 1 || err.col < 1) fail_msg("case %zu: no position for %s", i, err.message);
    }
    /* the error points at the member it names */
    const char *text = "{\"elements\": [\n" COLL_HAIR("a") ",\n"
                       "  {\"name\": \"k\", \"type\": \"collision\", \"components\": {\n"
                       "     \"Collision\": {\"members\": [\"a\", \"b\"], \"method\": \"edge_edge\"}}}]}\n";
    assert_error_at(text, "\"b\"", "k.Collision.members[1] = 'b'");
}

/* Attachment elements: members, method, box, curve, target; every rule's error. */
#define ATT(n, body) "{\"name\":\"" n "\",\"type\":\"attachment\",\"components\":{\"Attachment\":{" body "}}}"
#define ATT_BOX "\"box\":[[0,0,0],[1,1,1]]"
#define ATT_BODY "{\"name\":\"rock\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":\"meshes/tri.obj\"}}}"

static void test_attachment_elements(void **state)
{
    (void)state;
    DrScene *s = load_text("{\"elements\":[" COLL_HAIR("a") "," COLL_CLOTH("c") "," ATT_BODY ","
                           ATT("hook", "\"members\":[\"c\",\"a\"],\"method\":\"rigid\"," ATT_BOX ",\"target\":\"rock\"")
                           "," ATT("rail", "\"members\":[\"c\"],\"method\":\"slide\"," ATT_BOX
                                   ",\"curve\":[[0,1,0],[1,1,0]]") "]}");
    const DrElement *hook = dr_scene_find(s, "hook");
    assert_int_equal(hook->kind, DR_ELEMENT_ATTACHMENT);
    const DrComponent *a = dr_element_component(hook, "Attachment");
    const char *const *m = NULL;
    assert_int_equal(dr_component_names(a, "members", &m), 2);
    assert_string_equal(dr_component_str(a, "target"), "rock");
    const double *rows = NULL;
    assert_int_equal(dr_component_table(dr_element_component(dr_scene_find(s, "rail"), "Attachment"), "curve", &rows), 2);
    dr_scene_destroy(&s);

    struct {
        const char *text, *expect;
    } cases[] = {
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT("k", "\"members\":[\"cc\"],\"method\":\"pin\"," ATT_BOX) "]}",
         "k.Attachment.members[0] = 'cc': no hair or cloth element has this name; did you mean 'c'?"},
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT_BODY "," ATT("k", "\"members\":[\"rock\"],\"method\":\"pin\","
         ATT_BOX) "]}", "k.Attachment.members[0] = 'rock' is a collider element; an attachment holds hair or cloth"},
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT("k", "\"members\":[\"c\"],\"method\":\"pin\"") "]}",
         "k.Attachment.box is required with a cloth member"},
        {"{\"elements\":[" COLL_HAIR("a") "," ATT("k", "\"members\":[\"a\"],\"method\":\"pin\"") "]}",
         "k.Attachment.members[0] = 'a' is a hair element, held by its roots (Groom.roots): method \"pin\" holds a "
         "cloth's vertices"},
        {"{\"elements\":[" COLL_HAIR("a") "," ATT_BODY "," ATT("k", "\"members\":[\"a\"],\"method\":\"rigid\","
         "\"target\":\"rock\"," ATT_BOX) "]}", "k.Attachment.box selects a cloth member's vertices"},
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT("k", "\"members\":[\"c\"],\"method\":\"slide\"," ATT_BOX
         ",\"curve\":[[0,0,0]]") "]}", "k.Attachment.curve has 1 point(s); method \"slide\" needs the curve as 2 points"},
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT("k", "\"members\":[\"c\"],\"method\":\"pin\"," ATT_BOX
         ",\"curve\":[[0,0,0],[1,0,0]]") "]}", "k.Attachment.curve applies to method \"slide\", not \"pin\""},
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT_BODY "," ATT("k", "\"members\":[\"c\"],\"method\":\"rigid\","
         ATT_BOX) "]}", "k.Attachment.target is required with method \"rigid\"", },
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT_BODY "," ATT("k", "\"members\":[\"c\"],\"method\":\"pin\","
         ATT_BOX ",\"target\":\"rock\"") "]}", "k.Attachment.target applies to method \"rigid\", not \"pin\""},
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT_BODY "," ATT("k", "\"members\":[\"c\"],\"method\":\"rigid\","
         ATT_BOX ",\"target\":\"rok\"") "]}", "k.Attachment.target = 'rok': no collider or bem_solid element has this "
         "name; did you mean 'rock'?"},
        {"{\"elements\":[" COLL_CLOTH("c") "," COLL_CLOTH("d") "," ATT("k", "\"members\":[\"c\"],\"method\":\"rigid\","
         ATT_BOX ",\"target\":\"d\"") "]}", "k.Attachment.target = 'd' is a cloth element; a rigid attachment is carried "
         "by a collider or a bem_solid"},
        {"{\"elements\":[{\"name\":\"a\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"},"
         "\"Motion\":{\"keys\":[[0,0,0,0,0,0,0]]}}}," ATT_BODY "," ATT("k", "\"members\":[\"a\"],\"method\":\"rigid\","
         "\"target\":\"rock\"") "]}", "k.Attachment carries the roots of 'a' with its target, and a.Motion moves them too"},
        {"{\"elements\":[{\"name\":\"a\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\","
         "\"roots\":\"free\"}}}," ATT_BODY "," ATT("k", "\"members\":[\"a\"],\"method\":\"rigid\",\"target\":\"rock\"")
         "]}", "k.Attachment carries the roots of 'a', and a.Groom.roots is \"free\""},
        {"{\"elements\":[" COLL_HAIR("a") "," ATT_BODY "," ATT("k", "\"members\":[\"a\"],\"method\":\"rigid\","
         "\"target\":\"rock\"") "," ATT("q", "\"members\":[\"a\"],\"method\":\"rigid\",\"target\":\"rock\"") "]}",
         "k and q both carry the roots of 'a'"},
        {"{\"elements\":[{\"name\":\"c\",\"type\":\"cloth\",\"components\":{\"Mesh\":{\"file\":\"meshes/tri.obj\"},"
         "\"SlideVertices\":{" ATT_BOX ",\"curve\":[[0,0,0],[1,0,0]]}}}," ATT("k", "\"members\":[\"c\"],\"method\":"
         "\"slide\"," ATT_BOX ",\"curve\":[[0,0,0],[1,0,0]]") "]}",
         "k slides c on a curve, and its SlideVertices already does (a panel slides on one curve)"},
        {"{\"elements\":[" COLL_CLOTH("c") "," ATT("k", "\"members\":[\"c\"],\"method\":\"glue\"," ATT_BOX) "]}",
         "k.Attachment.method: 'glue' is not a valid choice"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        DrError err;
        if (load_bad(cases[i].text, &err) != DR_ERR_INPUT) fail_msg("case %zu: not an input error", i);
        if (!strstr(err.message, cases[i].expect))
            fail_msg("case %zu: expected \"%s\" in \"%s\"", i, cases[i].expect, err.message);
        if (err.line < 1 || err.col < 1) fail_msg("case %zu: no position for %s", i, err.message);
    }
}

static void test_bem_solid_defaults(void **state)
{
    (void)state;
    write_tri();
    char text[4096];
    bem_scene("\"Mesh\":{\"file\":\"meshes/tri.obj\"}", text, sizeof text);
    DrScene *s = load_text(text);
    const DrElement *e = dr_scene_find(s, "jelly");
    assert_non_null(e);
    assert_string_equal(e->type, "bem_solid");
    assert_true(e->spec->needs_precompute);
    assert_int_equal(dr_scene_count_type(s, "bem_solid"), 1);
    char tri[512];
    tmp_path("meshes/tri.obj", tri, sizeof tri);
    assert_string_equal(dr_component_str(dr_element_component(e, "Mesh"), "file"), tri);
    const DrComponent *mat = dr_element_component(e, "LinearElastic");
    assert_false(dr_component_present(mat));
    assert_true(dr_component_num(mat, "density") == 1000.0);
    assert_true(dr_component_num(mat, "shear_modulus") == 1e5);
    assert_true(dr_component_num(mat, "poisson") == 0.4);
    const DrComponent *cmp = dr_element_component(e, "Compression");
    assert_true(dr_component_num(cmp, "ratio") == 32.0);
    assert_string_equal(dr_component_str(cmp, "ordering"), "vertex_xyz");
    const DrComponent *sol = dr_element_component(e, "BemSolver");
    assert_true(dr_component_num(sol, "time_step") == 1.0 / 240.0);
    assert_true(dr_component_num(sol, "time_step") == 0.004166666666666667);
    assert_true(dr_component_num(sol, "history_margin") == 2.0);
    assert_int_equal(dr_component_int(sol, "quadrature_levels"), 1);
    assert_true(dr_component_bool(sol, "frame_update"));
    assert_true(dr_component_bool(sol, "error_correction"));
    /* at rest at the mesh's own pose unless Transform and InitialVelocity say otherwise */
    const DrComponent *tr = dr_element_component(e, "Transform");
    assert_false(dr_component_present(tr));
    assert_true(dr_component_num(tr, "scale") == 1.0);
    DrVec3 v = dr_component_vec3(tr, "translate");
    assert_true(v.x == 0.0 && v.y == 0.0 && v.z == 0.0);
    const DrComponent *iv = dr_element_component(e, "InitialVelocity");
    assert_false(dr_component_present(iv));
    v = dr_component_vec3(iv, "angular_velocity");
    assert_true(v.x == 0.0 && v.y == 0.0 && v.z == 0.0);
    assert_int_equal(dr_scene_asset_count(s), 1);
    dr_scene_destroy(&s);

    /* every field written, at the ends of the ranges (a 1 s step needs a frame of whole seconds: 1 fps) */
    bem_shot_scene("\"fps\":1",
                   "\"Mesh\":{\"file\":\"meshes/tri.obj\"},"
                   "\"LinearElastic\":{\"density\":1e5,\"shear_modulus\":1e12,\"poisson\":-0.99},"
                   "\"Compression\":{\"ratio\":1,\"ordering\":\"none\"},"
                   "\"BemSolver\":{\"time_step\":1,\"history_margin\":0,\"quadrature_levels\":4,"
                   "\"frame_update\":false,\"error_correction\":false},"
                   "\"Transform\":{\"translate\":[0,1,0],\"rotate_deg\":[0,90,0],\"scale\":1},"
                   "\"InitialVelocity\":{\"velocity\":[1,2,3],\"angular_velocity\":[0,0,360]}",
                   text, sizeof text);
    s = load_text(text);
    e = dr_scene_find(s, "jelly");
    mat = dr_element_component(e, "LinearElastic");
    assert_true(dr_component_present(mat));
    assert_true(dr_component_num(mat, "density") == 1e5 && dr_component_num(mat, "shear_modulus") == 1e12);
    assert_true(dr_component_num(mat, "poisson") == -0.99);
    cmp = dr_element_component(e, "Compression");
    assert_true(dr_component_num(cmp, "ratio") == 1.0);
    assert_string_equal(dr_component_str(cmp, "ordering"), "none");
    sol = dr_element_component(e, "BemSolver");
    assert_true(dr_component_num(sol, "time_step") == 1.0 && dr_component_num(sol, "history_margin") == 0.0);
    assert_int_equal(dr_component_int(sol, "quadrature_levels"), 4);
    assert_false(dr_component_bool(sol, "frame_update"));
    assert_false(dr_component_bool(sol, "error_correction"));
    v = dr_component_vec3(dr_element_component(e, "Transform"), "rotate_deg");
    assert_true(v.x == 0.0 && v.y == 90.0 && v.z == 0.0);
    v = dr_component_vec3(dr_element_component(e, "InitialVelocity"), "angular_velocity");
    assert_true(v.z == 360.0);
    char *c = dr_scene_canonical(s, "elements");
    assert_non_null(strstr(c, "\"Compression\":{\"ordering\":\"none\",\"ratio\":1}"));
    assert_non_null(strstr(c, "\"type\":\"bem_solid\""));
    free(c);
    dr_scene_destroy(&s);
}

static void test_bem_solid_bad_input(void **state)
{
    (void)state;
    write_tri();
    struct {
        const char *components;
        const char *expect[2];
    } cases[] = {
        {"\"LinearElastic\":{}",
         {"element 'jelly' (bem_solid): missing component 'Mesh'", "add \"Mesh\": {\"file\": "}},
        {"\"Mesh\":{}", {"jelly.Mesh: missing required field 'file'"}},
        {"\"Mesh\":{\"file\":\"meshes/no_such.obj\"}", {"jelly.Mesh.file: asset 'meshes/no_such.obj' not found"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"LinearElastic\":{\"density\":0}",
         {"jelly.LinearElastic.density = 0 is out of range (0, 100000] kg/m^3; use a positive density"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"LinearElastic\":{\"shear_modulus\":-5}",
         {"jelly.LinearElastic.shear_modulus = -5 is out of range (0, 1000000000000] Pa"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"LinearElastic\":{\"poisson\":0.5}",
         {"jelly.LinearElastic.poisson = 0.5 is out of range [-0.99, 0.49]", "at most 0.49"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"LinearElastic\":{\"poisson\":-1}",
         {"jelly.LinearElastic.poisson = -1 is out of range [-0.99, 0.49]"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"LinearElastic\":{\"shear_modulos\":1e5}",
         {"jelly.LinearElastic: unknown field 'shear_modulos'", "did you mean 'shear_modulus'?"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"Compression\":{\"ratio\":0.5}",
         {"jelly.Compression.ratio = 0.5 is out of range [1, 4096]"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"Compression\":{\"ratio\":8192}",
         {"jelly.Compression.ratio = 8192 is out of range [1, 4096]"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"Compression\":{\"ordering\":\"vertex_xzy\"}",
         {"jelly.Compression.ordering: 'vertex_xzy' is not a valid choice; did you mean 'vertex_xyz'?",
          "vertex_xyz, xyz, none"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"time_step\":0}",
         {"jelly.BemSolver.time_step = 0 is out of range (0, 1] s"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"history_margin\":-1}",
         {"jelly.BemSolver.history_margin = -1 is out of range [0, 1000]"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"quadrature_levels\":5}",
         {"jelly.BemSolver.quadrature_levels = 5 is out of range [1, 4]"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"quadrature_levels\":1.5}",
         {"jelly.BemSolver.quadrature_levels"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"LinearElastik\":{}",
         {"element 'jelly' (bem_solid): unknown component 'LinearElastik'; did you mean 'LinearElastic'?",
          "Components of bem_solid: Mesh, LinearElastic, Compression, BemSolver"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"Motion\":{}",
         {"unknown component 'Motion' ('Motion' is a component of collider elements)"}},
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"frame_update\":1}", {"jelly.BemSolver.frame_update"}},
        /* the matrices belong to the mesh as in its file */
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"Transform\":{\"scale\":2}",
         {"jelly.Transform.scale = 2: a bem_solid's boundary-element matrices are built for the mesh as it is in its "
          "file", "scale the OBJ instead"}},
        /* a frame of the default 24 fps holds 4.17 steps of 0.01 s: the nearest whole number is 4 */
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"time_step\":0.01}",
         {"jelly.BemSolver.time_step = 0.01 s does not divide the frame: 1/fps = 1/24 s is 4.16667 steps",
          "use 1/96 s = 0.010416666666666666 (4 steps per frame at 24 fps)"}},
        /* a step longer than the frame: one step per frame is the nearest */
        {"\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"time_step\":0.05}",
         {"jelly.BemSolver.time_step = 0.05 s does not divide the frame", "use 1/24 s = 0.041666666666666664 (1 step "
          "per frame at 24 fps)"}},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char text[4096], path[512];
        bem_scene(cases[i].components, text, sizeof text);
        tmp_path("bem.json", path, sizeof path);
        write_file(path, text);
        DrScene *s = (DrScene *)(uintptr_t)1;
        DrError err;
        DrStatus st = dr_scene_load(path, &s, &err);
        assert_null(s);
        if (st != DR_ERR_INPUT) fail_msg("case %zu: status %d for %s", i, (int)st, text);
        for (int k = 0; k < 2 && cases[i].expect[k]; k++)
            if (!strstr(err.message, cases[i].expect[k]))
                fail_msg("case %zu: expected \"%s\" in \"%s\"", i, cases[i].expect[k], err.message);
        if (err.line < 1 || err.col < 1) fail_msg("case %zu: no position for %s", i, err.message);
    }
    /* a ratio checked once the file is read: shot.fps after the elements; the error points at the field, or at
       the deepest part of its path that the file holds */
    char path[512];
    tmp_path("bem.json", path, sizeof path);
    const char *late_shot = "{\"elements\":[{\"name\":\"jelly\",\"type\":\"bem_solid\",\"components\":{\"Mesh\":{"
                            "\"file\":\"meshes/tri.obj\"}}}],\n\"shot\":{\"fps\":25}}";
    write_file(path, late_shot);
    DrScene *s = NULL;
    DrError err;
    assert_int_equal(dr_scene_load(path, &s, &err), DR_ERR_INPUT);
    assert_contains(err.message, "jelly.BemSolver.time_step = 0.00416666666666667 s does not divide the frame: "
                                 "1/fps = 1/25 s is 9.6 steps");
    assert_contains(err.message, "use 1/250 s = 0.004 (10 steps per frame at 25 fps)");
    assert_int_equal(err.line, 1);
    assert_int_equal(err.col, 62); /* the element's "components" object: BemSolver is not written */
    /* whole numbers of steps up to rounding load: 1/25 s is 4 steps of 0.01 s, 1/24 s 10 of 1/240 s */
    char text[4096];
    bem_shot_scene("\"fps\":25", "\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"time_step\":0.01}", text,
                   sizeof text);
    s = load_text(text);
    dr_scene_destroy(&s);
    bem_shot_scene("\"fps\":24", "\"Mesh\":{\"file\":\"meshes/tri.obj\"},\"BemSolver\":{\"time_step\":0.0041666666666667}",
                   text, sizeof text);
    s = load_text(text);
    dr_scene_destroy(&s);

    /* an unknown type close to bem_solid is suggested */
    assert_int_equal(load_bad("{\"elements\":[{\"name\":\"j\",\"type\":\"bem_solids\"}]}", &err), DR_ERR_INPUT);
    assert_contains(err.message, "did you mean 'bem_solid'?");
}

/* Contact of bem_solid bodies: Collider (friction, thickness, body_contact) and FixedVertices on a body, bem_joint
   elements naming two bodies. */
static void test_bem_contact_components(void **state)
{
    (void)state;
    write_tri();
    const char *body = "{\"name\":\"%s\",\"type\":\"bem_solid\",\"components\":{\"Mesh\":{\"file\":\"meshes/tri.obj\"}%s}}";
    char a[512], b[512], text[4096];
    snprintf(a, sizeof a, body, "left",
             ",\"Collider\":{\"friction\":0.3,\"thickness\":0.002,\"body_contact\":false},"
             "\"FixedVertices\":{\"box\":[[0,0,0],[1,1,1]]}");
    snprintf(b, sizeof b, body, "right", "");
    snprintf(text, sizeof text,
             "{\"elements\":[{\"name\":\"hinge\",\"type\":\"bem_joint\",\"components\":{\"Joint\":{\"body_a\":"
             "\"left\",\"body_b\":\"right\"}}},%s,%s]}", a, b);
    DrScene *s = load_text(text);
    const DrElement *l = dr_scene_find(s, "left"), *r = dr_scene_find(s, "right"), *j = dr_scene_find(s, "hinge");
    assert_non_null(l);
    const DrComponent *col = dr_element_component(l, "Collider");
    assert_true(dr_component_num(col, "friction") == 0.3);
    assert_true(dr_component_num(col, "thickness") == 0.002);
    assert_false(dr_component_bool(col, "body_contact"));
    assert_true(dr_component_present(dr_element_component(l, "FixedVertices")));
    /* a body without them: no friction, no offset, contact with other bodies on, nothing fixed */
    col = dr_element_component(r, "Collider");
    assert_true(dr_component_num(col, "friction") == 0.0);
    assert_true(dr_component_num(col, "thickness") == 0.0);
    assert_true(dr_component_bool(col, "body_contact"));
    assert_false(dr_component_present(dr_element_component(r, "FixedVertices")));
    /* a joint joins coincident vertices within 1e-6 m unless told otherwise */
    const DrComponent *jc = dr_element_component(j, "Joint");
    assert_string_equal(dr_component_str(jc, "mode"), "coincident");
    assert_true(dr_component_num(jc, "tolerance") == 1e-6);
    assert_false(dr_component_is_set(jc, "point"));
    assert_int_equal(dr_scene_count_type(s, "bem_joint"), 1);
    assert_false(dr_scene_element_spec("bem_joint")->needs_precompute);
    dr_scene_destroy(&s);

    /* bad input: exit 2 material, each naming element.Component.field, located in the file */
    struct {
        const char *left, *right, *joint;
        const char *expect[2];
    } cases[] = {
        {",\"Collider\":{\"boundary\":\"no_slip\"}", "", NULL,
         {"left.Collider.boundary is the velocity condition of liquid", "does not apply to a bem_solid"}},
        {",\"FixedVertices\":{}", "", NULL, {"left.FixedVertices: missing required field 'box'"}},
        {",\"FixedVertices\":{\"box\":[[0,0,0],[0,1,1]]}", "", NULL, {"left.FixedVertices.box"}},
        {"", "", "\"body_a\":\"left\",\"body_b\":\"rigth\"",
         {"hinge.Joint.body_b = 'rigth': no bem_solid element has this name; did you mean 'right'?",
          "bem_solid elements: left, right"}},
        {"", "", "\"body_a\":\"floor\",\"body_b\":\"right\"",
         {"hinge.Joint.body_a = 'floor' is a collider element, not a bem_solid"}},
        {"", "", "\"body_a\":\"left\",\"body_b\":\"left\"",
         {"hinge.Joint.body_b = 'left' is body_a as well"}},
        {"", "", "\"body_a\":\"left\"", {"hinge.Joint: missing required field 'body_b'"}},
        {"", "", "\"body_a\":\"left\",\"body_b\":\"right\",\"mode\":\"point\"",
         {"hinge.Joint.point is required with mode \"point\""}},
        {"", "", "\"body_a\":\"left\",\"body_b\":\"right\",\"mode\":\"pont\"", {"did you mean 'point'?"}},
        {"", "", "\"body_a\":\"left\",\"body_b\":\"right\",\"tolerance\":0",
         {"hinge.Joint.tolerance = 0 is out of range (0, 1] m"}},
        /* bodies of different steps are never stepped together */
        {",\"BemSolver\":{\"time_step\":0.008333333333333333}", "", "\"body_a\":\"left\",\"body_b\":\"right\"",
         {"hinge.Joint joins left and right, but right.BemSolver.time_step = 0.00416666666666667 s differs from "
          "left.BemSolver.time_step = 0.00833333333333333 s", "give both the same BemSolver.time_step"}},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char joint[512] = "";
        if (cases[i].joint)
            snprintf(joint, sizeof joint,
                     "{\"name\":\"hinge\",\"type\":\"bem_joint\",\"components\":{\"Joint\":{%s}}},", cases[i].joint);
        snprintf(a, sizeof a, body, "left", cases[i].left);
        snprintf(b, sizeof b, body, "right", cases[i].right);
        snprintf(text, sizeof text,
                 "{\"elements\":[%s%s,%s,{\"name\":\"floor\",\"type\":\"collider\",\"components\":{\"Mesh\":"
                 "{\"file\":\"meshes/tri.obj\"}}}]}", joint, a, b);
        DrError err;
        DrStatus st = load_bad(text, &err);
        if (st != DR_ERR_INPUT) fail_msg("case %zu: status %d for %s", i, (int)st, text);
        for (int k = 0; k < 2 && cases[i].expect[k]; k++)
            if (!strstr(err.message, cases[i].expect[k]))
                fail_msg("case %zu: expected \"%s\" in \"%s\"", i, cases[i].expect[k], err.message);
        if (err.line < 1 || err.col < 1) fail_msg("case %zu: no position for %s", i, err.message);
    }
    /* body_contact is between bem_solid bodies only */
    DrError err;
    assert_int_equal(load_bad("{\"elements\":[{\"name\":\"floor\",\"type\":\"collider\",\"components\":{\"Mesh\":"
                              "{\"file\":\"meshes/tri.obj\"},\"Collider\":{\"body_contact\":true}}}]}", &err),
                     DR_ERR_INPUT);
    assert_contains(err.message, "floor.Collider.body_contact is contact between bem_solid bodies and does not apply to "
                                 "a collider element");
}

/* The precompute key follows the bem_solid elements (their canonical JSON and mesh bytes) and nothing else; every
 * later key follows it. */
static void test_bem_solid_keys(void **state)
{
    (void)state;
    char obj[512], text[2048];
    tmp_path("meshes/jelly.obj", obj, sizeof obj);
    write_file(obj, TRI_OBJ);
    const char *fmt = "{\"elements\":[{\"name\":\"%s\",\"type\":\"bem_solid\",\"components\":{\"Mesh\":{\"file\":"
                      "\"meshes/jelly.obj\"},\"LinearElastic\":{\"shear_modulus\":%s}}}%s]}";
    const char *collider = ",{\"name\":\"cup\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":"
                           "\"meshes/tri.obj\"},\"Collider\":{\"friction\":%s}}}";
    write_tri();
    char col_a[512], col_b[512];
    snprintf(col_a, sizeof col_a, collider, "0.1");
    snprintf(col_b, sizeof col_b, collider, "0.2");
    DrSceneKeys base, k;
    snprintf(text, sizeof text, fmt, "jelly", "1e5", col_a);
    keys_of(text, &base);
    snprintf(text, sizeof text, fmt, "jelly", "2e5", col_a); /* a material field: precompute and all after */
    keys_of(text, &k);
    assert_string_not_equal(k.precompute, base.precompute);
    assert_string_not_equal(k.bake, base.bake);
    snprintf(text, sizeof text, fmt, "jelly", "1e5", col_b); /* another element: not precompute */
    keys_of(text, &k);
    assert_string_equal(k.precompute, base.precompute);
    assert_string_not_equal(k.bake, base.bake);
    write_file(obj, "v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n"); /* the body's mesh bytes */
    snprintf(text, sizeof text, fmt, "jelly", "1e5", col_a);
    keys_of(text, &k);
    assert_string_not_equal(k.precompute, base.precompute);
}

/* ---- canonical JSON and keys ---------------------------------------------------------------------------- */

static void test_canonical_json(void **state)
{
    (void)state;
    DrScene *s = load_text("{\"elements\":[{\"name\":\"w\",\"type\":\"liquid\",\"components\":{"
                           "\"LiquidMaterial\":{},\"Domain\":{\"box\":[[0,0,-0.0],[1,1,1.0]]}}}],"
                           "\"render\":{\"camera\":{\"fov_deg\":30}}}");
    char *c = dr_scene_canonical(s, "solver");
    assert_string_equal(c, "{\"cfl\":1,\"checkpoint_every\":1,\"coupling_iterations\":3,\"coupling_tolerance\":0.01,"
                           "\"max_substeps\":64,\"on_instability\":\"warn\","
                           "\"pressure_max_iterations\":2000,\"pressure_preconditioner\":\"multigrid\","
                           "\"pressure_tolerance\":9.9999999999999995e-07}");
    free(c);
    c = dr_scene_canonical(s, "elements");
    assert_string_equal(c, "[{\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]],\"voxel_size\":0.02,"
                           "\"wall_boundary\":\"slip\"},\"LiquidMaterial\":{\"density\":1000,\"viscosity\":0.001}},"
                           "\"name\":\"w\",\"type\":\"liquid\"}]");
    free(c);
    c = dr_scene_canonical(s, "render");
    assert_string_equal(c, "{\"camera\":{\"eye\":[0.59999999999999998,0.40000000000000002,0.80000000000000004],"
                           "\"fov_deg\":30,\"target\":[0,0.10000000000000001,0],\"up\":[0,1,0]},\"contact_every\":4,"
                           "\"ground\":true,\"resolution\":[960,540],\"samples\":3}");
    free(c);
    c = dr_scene_canonical(s, "render.camera");
    assert_non_null(strstr(c, "\"fov_deg\":30"));
    free(c);
    c = dr_scene_canonical(s, "mesh");
    assert_string_equal(c, "{\"adaptivity\":0,\"hair_ribbons\":false,\"radius_scale\":0.80000000000000004,\"smoothing\":1,"
                           "\"velocity_interior\":false,\"voxel_size\":0,\"wet_tube_sides\":8,\"wet_tubes\":false,"
                           "\"write_obj\":true,\"write_points\":true,\"write_vdb\":true}");
    free(c);
    dr_scene_destroy(&s);

    /* a path keeps what was written, escaped */
    char q[512];
    tmp_path("q\"uote\\.obj", q, sizeof q);
    write_file(q, TRI_OBJ);
    s = load_text("{\"elements\":[{\"name\":\"c\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":"
                  "\"q\\\"uote\\\\.obj\"},\"Motion\":{}}}]}");
    c = dr_scene_canonical(s, "elements");
    assert_string_equal(c, "[{\"components\":{\"Mesh\":{\"file\":\"q\\\"uote\\\\.obj\"},\"Motion\":{\"keys\":[]}},"
                           "\"name\":\"c\",\"type\":\"collider\"}]");
    free(c);
    assert_string_equal(dr_scene_asset(s, 0), q);
    dr_scene_destroy(&s);
}

static const char *const KEY_BASE =
    "{\"shot\":{\"name\":\"k\",\"frames\":[1,4]},\"mesh\":{\"voxel_size\":0.01},"
    "\"render\":{\"camera\":{\"fov_deg\":40}},"
    "\"elements\":[{\"name\":\"water\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]},"
    "\"LiquidSource\":{\"box\":[[0,0,0],[0.5,0.5,0.5]]},\"LiquidMaterial\":{\"viscosity\":0.001}}}]}";

static void test_keys_survive_reformatting(void **state)
{
    (void)state;
    DrSceneKeys a, b;
    keys_of(KEY_BASE, &a);
    assert_hex32(a.precompute);
    assert_hex32(a.bake);
    assert_hex32(a.mesh);
    assert_hex32(a.render);
    assert_string_not_equal(a.bake, a.mesh);
    /* whitespace, key order, 1 vs 1.0, -0 vs 0, 1e-3 vs 0.001, defaults written out */
    keys_of("{\n  \"elements\": [\n    { \"type\": \"liquid\", \"components\": {\n"
            "        \"LiquidMaterial\": { \"viscosity\": 1e-3, \"density\": 1000.0 },\n"
            "        \"LiquidSource\": { \"box\": [[0.0, -0.0, 0], [0.50, 0.5, 5e-1]] },\n"
            "        \"Domain\": { \"voxel_size\": 0.02, \"box\": [[0, 0, 0], [1.0, 1, 1]] } },\n"
            "      \"name\": \"water\" } ],\n"
            "  \"render\": { \"camera\": { \"fov_deg\": 40.0 }, \"resolution\": [960, 540] },\n"
            "  \"mesh\": { \"voxel_size\": 1e-2 },\n"
            "  \"shot\": { \"frames\": [1.0, 4], \"name\": \"k\", \"fps\": 24, \"gravity\": [-0.0, -9.81, 0] }\n}\n",
            &b);
    assert_string_equal(a.precompute, b.precompute);
    assert_string_equal(a.bake, b.bake);
    assert_string_equal(a.mesh, b.mesh);
    assert_string_equal(a.render, b.render);
}

/* KEY_BASE with one substring replaced. */
static void keys_with(const char *from, const char *to, DrSceneKeys *k)
{
    const char *at = strstr(KEY_BASE, from);
    assert_non_null(at);
    char text[4096];
    snprintf(text, sizeof text, "%.*s%s%s", (int)(at - KEY_BASE), KEY_BASE, to, at + strlen(from));
    keys_of(text, k);
}

static void test_keys_invalidate_what_changed(void **state)
{
    (void)state;
    DrSceneKeys base, k;
    keys_of(KEY_BASE, &base);

    keys_with("\"mesh\":{\"voxel_size\":0.01}", "\"mesh\":{\"voxel_size\":0.005}", &k);
    assert_string_equal(k.precompute, base.precompute);
    assert_string_equal(k.bake, base.bake);
    assert_string_not_equal(k.mesh, base.mesh);
    assert_string_not_equal(k.render, base.render);

    keys_with("\"viscosity\":0.001", "\"viscosity\":0.002", &k);
    assert_string_equal(k.precompute, base.precompute);
    assert_string_not_equal(k.bake, base.bake);
    assert_string_not_equal(k.mesh, base.mesh);
    assert_string_not_equal(k.render, base.render);

    keys_with("\"fov_deg\":40", "\"fov_deg\":41", &k);
    assert_string_equal(k.precompute, base.precompute);
    assert_string_equal(k.bake, base.bake);
    assert_string_equal(k.mesh, base.mesh);
    assert_string_not_equal(k.render, base.render);

    keys_with("\"frames\":[1,4]", "\"frames\":[1,5]", &k);
    assert_string_not_equal(k.bake, base.bake);

    /* presence of a component is meaningful even with all-default fields */
    keys_with("\"LiquidMaterial\":{\"viscosity\":0.001}", "\"LiquidMaterial\":{},\"Particles\":{}", &k);
    assert_string_not_equal(k.bake, base.bake);
}

static void test_keys_follow_asset_bytes(void **state)
{
    (void)state;
    char obj[512], text[2048];
    tmp_path("meshes/key.obj", obj, sizeof obj);
    write_file(obj, TRI_OBJ);
    snprintf(text, sizeof text,
             "{\"elements\":[{\"name\":\"cup\",\"type\":\"collider\",\"components\":{\"Mesh\":{\"file\":\"%s\"}}}]}", obj);
    DrSceneKeys a, b;
    keys_of(text, &a);
    write_file(obj, "v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n"); /* one byte changed */
    keys_of(text, &b);
    assert_string_equal(a.precompute, b.precompute);
    assert_string_not_equal(a.bake, b.bake);
    assert_string_not_equal(a.mesh, b.mesh);
    assert_string_not_equal(a.render, b.render);

    /* an asset that vanishes after load: the key names it */
    DrScene *s = load_text(text);
    assert_int_equal(unlink(obj), 0);
    DrError err;
    DrSceneKeys k;
    assert_int_equal(dr_scene_keys(s, &k, &err), DR_ERR_INPUT);
    assert_contains(err.message, obj);
    assert_contains(err.message, "cup.Mesh.file");
    dr_scene_destroy(&s);
}

/* The defaults a scene applied: fields left out take their defaults, listed per element and section; a component
 * whose absence means "none" lists nothing, and fields that mean nothing for the element are not listed. */
static bool applied(const DrAppliedDefault *d, int n, const char *component, const char *field)
{
    for (int i = 0; i < n; i++)
        if (!strcmp(d[i].component, component) && !strcmp(d[i].field->name, field)) return true;
    return false;
}

static void test_applied_defaults(void **state)
{
    (void)state;
    write_tri();
    write_curves();
    DrScene *s = load_text(
        "{\"solver\":{\"cfl\":2},\"elements\":["
        "{\"name\":\"w\",\"type\":\"liquid\",\"components\":{\"Domain\":{\"box\":[[0,0,0],[1,1,1]]},"
        "\"Transfer\":{\"scheme\":\"flip\"},\"LiquidMaterial\":{\"density\":900}}},"
        "{\"name\":\"c\",\"type\":\"hair\",\"components\":{\"Groom\":{\"curves\":\"meshes/curves.obj\"}}},"
        "{\"name\":\"g\",\"type\":\"hair\",\"components\":{\"Groom\":{\"scalp\":\"meshes/tri.obj\"}}}]}");
    DrAppliedDefault d[128];
    int n = dr_element_applied_defaults(dr_scene_find(s, "w"), d, 128);
    assert_true(n > 0 && n <= 128);
    assert_true(applied(d, n, "Domain", "voxel_size") && applied(d, n, "LiquidMaterial", "viscosity"));
    assert_false(applied(d, n, "Domain", "box") || applied(d, n, "LiquidMaterial", "density")); /* written */
    assert_true(applied(d, n, "Transfer", "flip_blend")); /* scheme flip: the blend applies */
    assert_false(applied(d, n, "Emitter", "start") || applied(d, n, "LiquidSource", "velocity")); /* absent: none */
    char json[64];
    for (int i = 0; i < n; i++)
        if (!strcmp(d[i].field->name, "viscosity")) dr_scene_default_json(d[i].field, json, sizeof json);
    assert_string_equal(json, "0.001");
    /* at most max entries are written; the count is the whole */
    assert_int_equal(dr_element_applied_defaults(dr_scene_find(s, "w"), d, 2), n);
    assert_int_equal(dr_element_applied_defaults(dr_scene_find(s, "w"), NULL, 0), n);

    n = dr_element_applied_defaults(dr_scene_find(s, "c"), d, 128);
    assert_false(applied(d, n, "Groom", "count") || applied(d, n, "Groom", "length")); /* curves: no growth */
    assert_false(applied(d, n, "Collider", "boundary") || applied(d, n, "Collider", "body_contact"));
    assert_true(applied(d, n, "Collider", "friction") && applied(d, n, "RodMaterial", "radius"));
    n = dr_element_applied_defaults(dr_scene_find(s, "g"), d, 128);
    assert_true(applied(d, n, "Groom", "count") && applied(d, n, "Groom", "segments"));
    assert_false(applied(d, n, "Groom", "curl_pitch")); /* straight strands */

    n = dr_section_applied_defaults(s, "solver", d, 128);
    assert_true(applied(d, n, "solver", "max_substeps") && !applied(d, n, "solver", "cfl"));
    dr_scene_default_json(dr_scene_section_spec("shot")->fields + 3, json, sizeof json); /* gravity */
    assert_string_equal(json, "[0, -9.81, 0]");
    dr_scene_destroy(&s);
}

/* ---- reference and tables --------------------------------------------------------------------------------- */

static char *reference(bool md)
{
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    assert_non_null(f);
    dr_scene_print_reference(f, md);
    fclose(f);
    return buf;
}

static void test_reference_lists_everything(void **state)
{
    (void)state;
    char *text = reference(false), *md = reference(true);
    const char *sections[] = {"shot", "solver", "mesh", "render", "render.camera"};
    for (int i = 0; i < 5; i++) {
        const DrComponentSpec *c = dr_scene_section_spec(sections[i]);
        assert_non_null(c);
        char head[128];
        snprintf(head, sizeof head, "\n  %s: ", c->name);
        assert_contains(text, head);
        for (int f = 0; f < c->field_count; f++) {
            char row[128];
            snprintf(row, sizeof row, "\n    %s ", c->fields[f].name);
            assert_contains(text, row);
            snprintf(row, sizeof row, "| `%s` |", c->fields[f].name);
            assert_contains(md, row);
        }
    }
    const char *types[] = {"liquid", "collider", "mpm_solid", "hair", "bem_solid", "bem_joint"};
    for (int i = 0; i < 6; i++) {
        const DrElementSpec *t = dr_scene_element_spec(types[i]);
        assert_non_null(t);
        char head[128];
        snprintf(head, sizeof head, "### Element type `%s`", t->type);
        assert_contains(md, head);
        for (int j = 0; j < t->component_count; j++) {
            const DrComponentSpec *c = dr_scene_component_spec(t->components[j]);
            assert_non_null(c);
            snprintf(head, sizeof head, "#### `%s`", c->name);
            assert_contains(md, head);
            for (int f = 0; f < c->field_count; f++) {
                char row[128];
                snprintf(row, sizeof row, "| `%s` |", c->fields[f].name);
                assert_contains(md, row);
            }
        }
    }
    /* plain text: rows aligned across the listing, the description under each row, lines wrapped at 100 */
    assert_contains(text, "components: Domain (required), LiquidSource, Emitter, KillBox, LiquidMaterial, Transfer,\n"
                          "    Particles, Pressure\n");
    assert_contains(text, "\n  Domain (required): the simulation grid\n");
    assert_contains(text, "\n  LiquidMaterial: material of the liquid\n");
    assert_contains(text, "\n    density                  number        kg/m^3         1000                 [1, 100000]\n"
                          "        mass density\n");
    assert_contains(text, "\n    fov_deg                  number        deg            40                   (1, 170)\n"
                          "        vertical field of view\n");
    assert_contains(text, "\n    scheme                   choice        -              \"apic\"               -\n"
                          "        one of apic, flip, pic, rpic: particle-grid transfer;");
    for (const char *line = text; *line;) {
        size_t len = strcspn(line, "\n");
        if (len > DR_REFERENCE_COLUMNS) fail_msg("reference line of %zu columns: %.*s", len, (int)len, line);
        line += len + (line[len] == '\n');
    }
    assert_contains(md, "| `density` | number | kg/m^3 | `1000` | [1, 100000] | mass density |");
    assert_contains(md, "| `box` | box [lo, hi] | m | **required** |");
    assert_contains(md, "| `scheme` | one of apic, flip, pic, rpic | - | `\"apic\"` | - |");
    assert_contains(md, "out/&lt;name&gt;/"); /* no raw HTML in the Markdown */
    assert_contains(text, "components: Groom (required), RodMaterial, Collider, Transform, Motion, CollisionGroup,\n"
                          "    CollisionResponse, HairSolver, Wetting, Film, Cohesion, CrossFlow, Capture, Dripping, Drag\n");
    assert_contains(md, "| `preconditioner` | one of block, cluster, jacobi, none | - | `\"block\"` | - |");
    assert_contains(md, "| `collides_with` | integer | - | `2147483647` | [0, 2147483647] |");
    assert_contains(text, "components: Mesh (required), LinearElastic, Compression, BemSolver");
    assert_contains(md, "### Element type `bem_solid`");
    assert_contains(md, "| `poisson` | number | 1 | `0.4` | [-0.99, 0.49] |");
    assert_contains(md, "| `ratio` | number | 1 | `32` | [1, 4096] | fraction of Haar coefficients kept is 1/ratio; 1 "
                        "stores dense matrices |");
    assert_contains(md, "| `ordering` | one of vertex_xyz, xyz, none | - | `\"vertex_xyz\"` | - |");
    assert_contains(md, "| `time_step` | number | s | `0.00416666666666667` | (0, 1] |");
    assert_contains(md, "| `quadrature_levels` | integer | - | `1` | [1, 4] |");
    assert_contains(md, "| `frame_update` | bool | - | `true` | - | move a rigid frame with the body (BEM eqs. 10-11)");
    assert_contains(md, "| `error_correction` | bool | - | `true` | - |");
    assert_contains(text, "components: Mesh (required), LinearElastic, Compression, BemSolver, Transform, InitialVelocity,\n"
                          "    Collider, FixedVertices\n");
    assert_contains(text, "components: Joint (required)\n");
    assert_contains(md, "### Element type `bem_joint`");
    assert_contains(md, "| `mode` | one of coincident, point | - | `\"coincident\"` | - |");
    assert_contains(md, "| `body_contact` | bool | - | `true` | - |");
    free(text);
    free(md);
}

static void test_spec_lookups(void **state)
{
    (void)state;
    const DrElementSpec *liquid = dr_scene_element_spec("liquid");
    assert_non_null(liquid);
    assert_int_equal(liquid->component_count, 8); /* Domain … Particles, Pressure */
    assert_int_equal(liquid->required_count, 1);
    assert_string_equal(liquid->required_components[0], "Domain");
    assert_false(liquid->needs_precompute);
    assert_null(dr_scene_element_spec("fur"));
    const DrElementSpec *hair = dr_scene_element_spec("hair");
    assert_non_null(hair);
    assert_int_equal(hair->component_count, 15); /* Groom … HairSolver, the wet hair's Wetting … Dripping, Drag */
    assert_int_equal(hair->required_count, 1);
    assert_string_equal(hair->required_components[0], "Groom");
    assert_false(hair->needs_precompute);
    const DrElementSpec *bem = dr_scene_element_spec("bem_solid");
    assert_non_null(bem);
    assert_int_equal(bem->component_count, 8);
    assert_int_equal(bem->required_count, 1);
    assert_string_equal(bem->required_components[0], "Mesh");
    assert_true(bem->needs_precompute);
    for (int i = 0; i < 3; i++) { /* every other type needs none */
        const char *others[] = {"liquid", "collider", "mpm_solid"};
        assert_false(dr_scene_element_spec(others[i])->needs_precompute);
    }
    assert_null(dr_scene_component_spec("Nope"));
    assert_null(dr_scene_section_spec("elements"));
    const DrComponentSpec *mat = dr_scene_component_spec("LiquidMaterial");
    assert_non_null(mat);
    assert_string_equal(mat->fields[0].name, "density");
    assert_string_equal(mat->fields[0].unit, "kg/m^3");
    assert_true(mat->fields[0].def[0] == 1000.0 && mat->fields[0].lo == 1.0 && mat->fields[0].hi == 1e5);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_full_scene_getters),
        cmocka_unit_test(test_element_kinds), cmocka_unit_test(test_empty_scene_is_all_defaults),
        cmocka_unit_test(test_asset_resolution), cmocka_unit_test(test_applied_defaults),
        cmocka_unit_test(test_bad_files),
        cmocka_unit_test(test_bad_input_messages),
        cmocka_unit_test(test_missing_scene_file),
        cmocka_unit_test(test_error_positions),
        cmocka_unit_test(test_hair_defaults),
        cmocka_unit_test(test_hair_bad_input),
        cmocka_unit_test(test_air),
        cmocka_unit_test(test_collision_elements),
        cmocka_unit_test(test_attachment_elements),
        cmocka_unit_test(test_bem_solid_defaults),
        cmocka_unit_test(test_bem_solid_bad_input),
        cmocka_unit_test(test_bem_solid_keys),
        cmocka_unit_test(test_bem_contact_components),
        cmocka_unit_test(test_canonical_json),
        cmocka_unit_test(test_keys_survive_reformatting),
        cmocka_unit_test(test_keys_invalidate_what_changed),
        cmocka_unit_test(test_keys_follow_asset_bytes),
        cmocka_unit_test(test_reference_lists_everything),
        cmocka_unit_test(test_spec_lookups),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
