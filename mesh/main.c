/* mesh: turns each baked frame's liquid particles and MPM solid particles into an OpenVDB level set (.vdb) and
 * a surface (.obj) per element, and exports colliders as OBJ, into out/<shot>/mesh/. */
#include <stdlib.h>
#include <string.h>

#include "io/io.h"
#include "scene/scene.h"
#include "vdb/vdb.h"
#include "world/world.h"

static int fail(const DrError *err)
{
    dr_error_print("mesh", err);
    return dr_exit_code(err->status);
}

/* out = R·rest + t for nv vertices (R row-major 3×3 as stored in the frame cache). */
static void apply_pose(const double *rest, int nv, const double R[9], const double t[3], double *out)
{
    for (int i = 0; i < nv; i++) {
        const double *p = rest + 3 * i;
        for (int a = 0; a < 3; a++) out[3 * i + a] = R[3 * a] * p[0] + R[3 * a + 1] * p[1] + R[3 * a + 2] * p[2] + t[a];
    }
}

/* rest[i]: element i's collider mesh in its scene pose (loaded once; empty for other elements). */
static DrStatus mesh_frame(const DrScene *scene, const DrTriMesh *rest, const char *bake_dir, const char *dir,
                           int frame, int first_frame, const char *bake_key, double fps, long *triangles, DrError *err)
{
    char path[4096], out[4096];
    dr_stage_frame_path(bake_dir, "frame", frame, "h5", path, sizeof path);
    if (!dr_io_exists(path))
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "frame %d has not been baked; run bake (or pipeline.sh) first",
                            frame);
    DrH5 *h = NULL;
    DR_TRY(dr_h5_open(path, &h, err));
    char *key = NULL;
    DrStatus s = dr_h5_read_attr_str(h, "/", "scene_key", &key, err);
    if (s == DR_OK && strcmp(key, bake_key) != 0)
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "frame %d was baked from another version of the scene; rerun bake (pipeline.sh does it)",
                         frame);
    free(key);
    const DrComponent *ms = dr_scene_section(scene, "mesh");
    for (int i = 0; s == DR_OK && i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (strcmp(e->type, "collider") == 0 && dr_component_present(dr_element_component(e, "Motion"))) {
            double *R = NULL, *t = NULL;
            int rank;
            uint64_t d1[4], d2[4];
            snprintf(path, sizeof path, "/%s/rotation", e->name);
            s = dr_h5_read_f64(h, path, &rank, d1, &R, err);
            snprintf(path, sizeof path, "/%s/translation", e->name);
            if (s == DR_OK) s = dr_h5_read_f64(h, path, &rank, d2, &t, err);
            /* the posed copy shares the rest mesh's triangles and owns only its vertices */
            DrTriMesh posed = rest[i];
            posed.n = NULL;
            posed.v = NULL;
            if (s == DR_OK) s = dr_calloc(3 * (size_t)posed.nv, sizeof(double), &posed.v, err);
            if (s == DR_OK) {
                apply_pose(rest[i].v, posed.nv, R, t, posed.v);
                dr_stage_frame_path(dir, e->name, frame, "obj", out, sizeof out);
                s = dr_io_write_obj(out, &posed, "drench collider (posed for this frame)", err);
            }
            free(posed.v);
            free(R);
            free(t);
            continue;
        }
        bool liquid = strcmp(e->type, "liquid") == 0;
        if (!liquid && strcmp(e->type, "mpm_solid") != 0) continue;
        double *x = NULL, *v = NULL;
        int rank;
        uint64_t dx_[4], dv[4];
        snprintf(path, sizeof path, "/%s/position", e->name);
        s = dr_h5_read_f64(h, path, &rank, dx_, &x, err);
        snprintf(path, sizeof path, "/%s/velocity", e->name);
        if (s == DR_OK) s = dr_h5_read_f64(h, path, &rank, dv, &v, err);
        const DrComponent *dom = dr_element_component(e, "Domain");
        double cell = dr_component_num(dom, "voxel_size");
        /* Liquid particles sit 1/cbrt(per_cell) of a cell apart. Jittered within their sub-cells, their union
           of spheres has dips where an outer particle sits deep; a radius of 0.8 spacings (the default) gives
           back the seeded volume of a box within 2 % (tests/validation/test_world.c). MPM particles start on a
           lattice of cell/particles_per_axis and move with the material, so the same rule in their spacing
           gives the body's surface (slightly outside the sampled one, as for the liquid). */
        double spacing = liquid ? cell / cbrt((double)dr_component_int(dr_element_component(e, "Particles"), "per_cell"))
                                : cell / dr_component_int(dr_element_component(e, "MpmShape"), "particles_per_axis");
        double radius = dr_component_num(ms, "radius_scale") * spacing;
        double voxel = dr_component_num(ms, "voxel_size");
        /* The level set is the union of the particles' spheres; spheres under 1.5 voxels are rasterised at
           1.5 and the union eroded back, which needs voxel centres within a radius of the particles.
           Jittered liquid particles have them at half a cell; MPM particles start on a lattice that puts
           them half a voxel from every voxel centre, where the eroded union vanishes. So an MPM solid's
           automatic voxel resolves its spheres (radius / 1.5, at most half a cell). */
        if (voxel <= 0.0) voxel = liquid ? 0.5 * cell : fmin(0.5 * cell, radius / 1.5);
        else if (!liquid && frame == first_frame && radius < 1.5 * voxel)
            dr_log_warn("mesh.voxel_size = %g m is coarse for the particles of MPM solid '%s' (radius %g m, under 1.5 "
                        "voxels): its surface may break up; use mesh.voxel_size 0 (automatic) or at most %g m",
                        voxel, e->name, radius, radius / 1.5);
        DrVdbSurfaceDesc sd = {voxel, radius, dr_component_int(ms, "smoothing"), dr_component_num(ms, "adaptivity")};
        DrVdbSurface *surf = NULL;
        if (s == DR_OK) s = dr_vdb_surface_from_particles(x, v, (long)dx_[0], &sd, &surf, err);
        if (s == DR_OK && dr_component_bool(ms, "write_vdb")) {
            DrVdbMeta meta = {frame, fps, bake_key};
            dr_stage_frame_path(dir, e->name, frame, "vdb", out, sizeof out);
            s = dr_vdb_surface_write(surf, out, &meta, err);
        }
        if (s == DR_OK && dr_component_bool(ms, "write_obj")) {
            DrTriMesh m = {0};
            s = dr_vdb_surface_to_mesh(surf, &m, err);
            if (s == DR_OK) {
                char comment[256];
                snprintf(comment, sizeof comment, "drench %s %s '%s' frame %d (m, y up)", DR_VERSION,
                         liquid ? "liquid" : "MPM solid", e->name, frame);
                dr_stage_frame_path(dir, e->name, frame, "obj", out, sizeof out);
                s = dr_io_write_obj(out, &m, comment, err);
                *triangles += m.nt;
            }
            dr_trimesh_free(&m);
        }
        dr_vdb_surface_destroy(&surf);
        free(x);
        free(v);
    }
    dr_h5_close(&h);
    return s;
}

/* mesh --finish: every output a full run would have written must be there (the frame ranges ran as separate
 * processes, e.g. a farm's job array); then the folder is complete and the MANIFEST may say so. */
static DrStatus check_outputs(const DrScene *scene, const char *dir, int first, int last, DrError *err)
{
    const DrComponent *ms = dr_scene_section(scene, "mesh");
    char path[4096];
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        /* liquid and MPM solids are surfaced alike, one file per frame */
        bool liquid = strcmp(e->type, "liquid") == 0 || strcmp(e->type, "mpm_solid") == 0;
        bool collider = strcmp(e->type, "collider") == 0;
        bool moving = collider && dr_component_present(dr_element_component(e, "Motion"));
        if (collider) {
            snprintf(path, sizeof path, "%s/%s.obj", dir, e->name);
            if (!dr_io_exists(path)) goto missing;
        }
        for (int f = first; f <= last; f++) {
            const char *ext[2] = {NULL, NULL};
            if (liquid && dr_component_bool(ms, "write_obj")) ext[0] = "obj";
            if (liquid && dr_component_bool(ms, "write_vdb")) ext[1] = "vdb";
            if (moving) ext[0] = "obj";
            for (int k = 0; k < 2; k++) {
                if (!ext[k]) continue;
                dr_stage_frame_path(dir, e->name, f, ext[k], path, sizeof path);
                if (!dr_io_exists(path))
                    return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                                        "mesh --finish: frame %d of element '%s' is missing; run mesh --frames %d-%d "
                                        "(or pipeline.sh) first",
                                        f, e->name, f, f);
            }
        }
    }
    return DR_OK;
missing:
    return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                        "mesh --finish: the collider mesh is missing; run mesh --frames on any range first");
}

int main(int argc, char **argv)
{
    DrError err;
    dr_error_clear(&err);
    DrStageArgs args;
    bool done;
    double t0 = dr_time_now();
    DrScene *scene = NULL;
    DrSceneKeys keys;
    char dir[2048], bake_dir[2048];
    if (dr_stage_begin(DR_STAGE_MESH, argc, argv, &args, &scene, &keys, dir, sizeof dir, &done, &err) < 0)
        return fail(&err);
    if (done) return 0;
    int first, last;
    DrStatus s = dr_stage_frame_range(&args, scene, &first, &last, &err);
    dr_stage_out_dir(&args, scene, DR_STAGE_BAKE, bake_dir, sizeof bake_dir);
    if (s == DR_OK && args.finish) {
        char line[128];
        snprintf(line, sizeof line, "frames %d-%d (ran in separate ranges)", first, last);
        const char *inputs[2] = {line, keys.bake};
        s = check_outputs(scene, dir, first, last, &err);
        if (s == DR_OK) s = dr_io_manifest_write(dir, "mesh", keys.mesh, dr_scene_path(scene), inputs, 2, &err);
        dr_scene_destroy(&scene);
        if (s < 0) return fail(&err);
        fprintf(stderr, "mesh: frames %d-%d complete in %s; MANIFEST written\n", first, last, dir);
        return 0;
    }
    /* Every collider asset is loaded (and so validated) once, before anything is written. */
    int nel = dr_scene_element_count(scene);
    DrTriMesh *rest = NULL;
    if (s == DR_OK) s = dr_calloc((size_t)nel + 1, sizeof(DrTriMesh), &rest, &err);
    for (int i = 0; s == DR_OK && i < nel; i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (strcmp(e->type, "collider") == 0) s = dr_world_load_collider_mesh(e, &rest[i], &err);
    }
    if (s == DR_OK) s = dr_vdb_init(&err);
    if (s == DR_OK) s = dr_io_mkdirs(dir, &err);
    if (s == DR_OK) s = dr_io_manifest_remove(dir, &err);
    /* A frame range may run beside others on other machines (a farm's job array), whose temporary files
       look stale from here: only a run that owns the whole folder clears them. */
    if (s == DR_OK && !args.frames_given) dr_io_remove_stale_tmp(dir);
    /* colliders once, in their scene pose */
    for (int i = 0; s == DR_OK && i < nel; i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (strcmp(e->type, "collider") != 0) continue;
        char out[4096];
        snprintf(out, sizeof out, "%s/%s.obj", dir, e->name);
        s = dr_io_write_obj(out, &rest[i], "drench collider (scene pose)", &err);
    }
    double fps = dr_component_num(dr_scene_section(scene, "shot"), "fps");
    long triangles = 0;
    DrProgress prog;
    if (s == DR_OK) dr_progress_begin(&prog, "mesh", last - first + 1);
    for (int f = first; s == DR_OK && f <= last; f++) {
        double tf = dr_time_now();
        s = mesh_frame(scene, rest, bake_dir, dir, f, first, keys.bake, fps, &triangles, &err);
        char detail[128];
        snprintf(detail, sizeof detail, "frame %d %.2fs", f, dr_time_now() - tf);
        if (s == DR_OK) dr_progress_step(&prog, detail);
    }
    int fr[2];
    dr_component_int2(dr_scene_section(scene, "shot"), "frames", fr);
    if (s == DR_OK && first == fr[0] && last == fr[1]) {
        char line[128];
        snprintf(line, sizeof line, "frames %d-%d", first, last);
        const char *inputs[2] = {line, keys.bake};
        s = dr_io_manifest_write(dir, "mesh", keys.mesh, dr_scene_path(scene), inputs, 2, &err);
    }
    for (int i = 0; rest && i < nel; i++) dr_trimesh_free(&rest[i]);
    free(rest);
    dr_scene_destroy(&scene);
    if (s < 0) return fail(&err);
    fprintf(stderr, "mesh: %d frames in %.1fs, %ld triangles written to %s\n", last - first + 1, dr_time_now() - t0,
            triangles, dir);
    return 0;
}
