/* render: preview PNGs of the meshed frames (out/<shot>/render/frame.NNNN.png), a contact sheet of every
 * n-th frame, and plots of the bake's diagnostics (render/plots.c). It reads only the mesh stage's outputs
 * and the scene; frames render in parallel, one frame per thread. */
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "from_scene.h"
#include "io/io.h"
#include "plots.h"
#include "render/render.h"
#include "scene/scene.h"
#include "stage/stage.h"

static int fail(const DrError *err)
{
    dr_error_print("render", err);
    return dr_exit_code(err->status);
}

/* What the stage draws of one element: a file per frame (liquid surfaces, MPM and BEM solids, moving colliders,
 * hair strands) or one file for the whole shot (static colliders, loaded once). */
typedef struct Drawable {
    const DrElement *element;
    DrRenderMaterial material;
    bool per_frame;
    bool strands;    /* the frame's file holds OBJ polylines with their radii (hair), not triangles */
    DrTriMesh still; /* static geometry, loaded once */
} Drawable;

typedef struct Job {
    const DrScene *scene;
    const Drawable *draw;
    int ndraw;
    const char *mesh_dir, *dir;
    DrCamera cam;
    DrRenderDesc desc;
    int first;
    DrStatus *status; /* per frame */
    DrError *errors;  /* per frame */
    DrProgress *prog;
    pthread_mutex_t *lock;
} Job;

static DrStatus render_frame(const Job *job, int frame, int threads, DrError *err)
{
    DrRenderScene *rs = NULL;
    DR_TRY(dr_render_scene_create(&rs, err));
    DrStatus s = scene_add_domain_walls(job->scene, rs, err);
    char path[4096];
    for (int i = 0; s == DR_OK && i < job->ndraw; i++) {
        const Drawable *d = &job->draw[i];
        if (!d->per_frame) {
            s = dr_render_scene_add_mesh(rs, &d->still, d->material, err);
            continue;
        }
        DrTriMesh m = {0};
        dr_stage_frame_path(job->mesh_dir, d->element->name, frame, "obj", path, sizeof path);
        if (!dr_io_exists(path))
            s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                             "frame %d of element '%s' has not been meshed; run mesh (or pipeline.sh) first", frame,
                             d->element->name);
        if (s == DR_OK && d->strands) {
            /* hair: the mesh stage's polylines, each strand as wide as its radius says, wet hair as wide as its film
               and darker (scene_add_strands) */
            DrPolylines p;
            s = dr_io_read_polylines_obj(path, NULL, &p, err); /* the mesh stage's format: radius required */
            if (s == DR_OK) s = scene_add_strands(job->scene, d->element, &p, rs, err);
            dr_io_polylines_free(&p);
            continue;
        }
        if (s == DR_OK) s = dr_io_load_mesh(path, &m, err);
        /* a liquid that has drained away meshes to an empty OBJ, which assimp refuses: nothing to draw */
        if (s == DR_ERR_INPUT && d->material == DR_MATERIAL_LIQUID && strstr(err->message, "no triangles")) {
            dr_error_clear(err);
            s = DR_OK;
        }
        if (s == DR_OK) s = dr_render_scene_add_mesh(rs, &m, d->material, err);
        dr_trimesh_free(&m);
    }
    DrImage img = {0};
    DrRenderDesc desc = job->desc;
    desc.threads = threads;
    if (s == DR_OK) s = dr_render_image(rs, &job->cam, &desc, &img, err);
    dr_stage_frame_path(job->dir, "frame", frame, "png", path, sizeof path);
    if (s == DR_OK) s = dr_image_write_png(path, &img, err);
    dr_image_free(&img);
    dr_render_scene_destroy(&rs);
    return s;
}

static void render_range(long begin, long end, void *ctx)
{
    const Job *job = ctx;
    for (long k = begin; k < end; k++) {
        int frame = job->first + (int)k;
        double t = dr_time_now();
        dr_error_clear(&job->errors[k]);
        /* frames run in parallel with each other, so each frame renders on its own thread */
        job->status[k] = render_frame(job, frame, 1, &job->errors[k]);
        if (job->status[k] < 0) return;
        char detail[96];
        snprintf(detail, sizeof detail, "frame %d %.2fs", frame, dr_time_now() - t);
        pthread_mutex_lock(job->lock);
        dr_progress_step(job->prog, detail);
        pthread_mutex_unlock(job->lock);
    }
}

/* Every `every`-th frame of the shot (and the last), read back from the PNGs, labelled with its number. */
static DrStatus write_contact_sheet(const char *dir, int first, int last, int every, DrError *err)
{
    int n = 0;
    for (int f = first; f <= last; f += every) n++;
    bool add_last = (last - first) % every != 0;
    n += add_last;
    DrImage *imgs = NULL;
    char(*labels)[32] = NULL;
    const char **lp = NULL;
    DR_TRY(dr_calloc((size_t)n, sizeof *imgs, &imgs, err));
    DrStatus s = dr_calloc((size_t)n, sizeof *labels, &labels, err);
    if (s == DR_OK) s = dr_calloc((size_t)n, sizeof *lp, &lp, err);
    char path[4096];
    for (int i = 0; s == DR_OK && i < n; i++) {
        int f = (add_last && i == n - 1) ? last : first + i * every;
        dr_stage_frame_path(dir, "frame", f, "png", path, sizeof path);
        s = dr_image_read_png(path, &imgs[i], err);
        snprintf(labels[i], sizeof labels[i], "frame %d", f);
        lp[i] = labels[i];
    }
    DrImage sheet = {0};
    int columns = n < 6 ? n : 6;
    if (s == DR_OK) s = dr_image_contact_sheet(imgs, lp, n, columns, 320, &sheet, err);
    snprintf(path, sizeof path, "%s/contact_sheet.png", dir);
    if (s == DR_OK) s = dr_image_write_png(path, &sheet, err);
    dr_image_free(&sheet);
    for (int i = 0; imgs && i < n; i++) dr_image_free(&imgs[i]);
    free(imgs);
    free(labels);
    free(lp);
    return s;
}

/* The ground sits under everything the shot can hold: the lowest liquid or MPM domain floor or still collider. The
 * still colliders' meshes also set the size every frame renders with (scene_render_sizes). */
static void shot_ground_and_sizes(const DrScene *scene, const Drawable *draw, int ndraw, DrRenderDesc *desc,
                                  DrError *err, DrStatus *s)
{
    DrTriMesh *still = NULL;
    *s = dr_calloc((size_t)ndraw + 1, sizeof *still, &still, err);
    if (*s != DR_OK) return;
    for (int i = 0; i < ndraw; i++) still[i] = draw[i].still; /* shallow: borrowed for the call */
    desc->ground_height = scene_ground_height(scene, still, ndraw);
    scene_render_sizes(scene, still, ndraw, desc);
    free(still);
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
    char dir[2048], mesh_dir[2048], bake_dir[2048], path[4096];
    if (dr_stage_begin(DR_STAGE_RENDER, argc, argv, &args, &scene, &keys, dir, sizeof dir, &done, &err) < 0)
        return fail(&err);
    if (done) return 0;
    if (args.preview) {
        /* the scene's initial state, from the scene alone: nothing here reads or writes a stage folder */
        DrStatus s = scene_preview(scene, &args, path, sizeof path, &err);
        dr_scene_destroy(&scene);
        if (s < 0) return fail(&err);
        fprintf(stderr, "render: preview of the scene's initial state in %.1fs written to %s\n", dr_time_now() - t0,
                path);
        return 0;
    }
    dr_stage_out_dir(&args, scene, DR_STAGE_MESH, mesh_dir, sizeof mesh_dir);
    dr_stage_out_dir(&args, scene, DR_STAGE_BAKE, bake_dir, sizeof bake_dir);
    snprintf(path, sizeof path, "%s/progress.jsonl", bake_dir);

    char plots_dir[4096];
    snprintf(plots_dir, sizeof plots_dir, "%s/plots", dir);
    if (args.plots_only) {
        int written = 0;
        DrStatus s = plots_write(path, plots_dir, &written, &err);
        dr_scene_destroy(&scene);
        if (s < 0) return fail(&err);
        fprintf(stderr, "render: %d plots written to %s\n", written, plots_dir);
        return 0;
    }

    int first, last, shot[2];
    DrStatus s = dr_stage_frame_range(&args, scene, &first, &last, &err);
    dr_component_int2(dr_scene_section(scene, "shot"), "frames", shot);
    DrCamera cam;
    if (s == DR_OK) s = scene_camera(scene, &cam, &err);
    if (s == DR_OK && !dr_io_exists(mesh_dir))
        s = dr_error_set(&err, DR_ERR_INPUT, mesh_dir, 0, 0,
                         "the mesh folder is missing: run mesh (or pipeline.sh) for %s first", dr_scene_path(scene));

    /* 1. what to draw; static colliders are loaded once (and so checked before anything is written) */
    int nel = dr_scene_element_count(scene), ndraw = 0;
    Drawable *draw = NULL;
    if (s == DR_OK) s = dr_calloc((size_t)nel + 1, sizeof *draw, &draw, &err);
    for (int i = 0; s == DR_OK && i < nel; i++) {
        const DrElement *e = dr_scene_element(scene, i);
        Drawable d = {.element = e};
        bool liquid = e->kind == DR_ELEMENT_LIQUID, mpm = e->kind == DR_ELEMENT_MPM_SOLID;
        if (liquid || mpm) {
            if (!dr_component_bool(dr_scene_section(scene, "mesh"), "write_obj")) {
                s = dr_error_set(&err, DR_ERR_INPUT, dr_scene_path(scene), 0, 0,
                                 "render draws the %s '%s' from its OBJ surfaces, but mesh.write_obj is false; "
                                 "set mesh.write_obj to true",
                                 liquid ? "liquid" : "MPM solid", e->name);
                break;
            }
            /* MPM solids are opaque deformable bodies: the warm matte solid material, not the liquid's */
            d.material = liquid ? DR_MATERIAL_LIQUID : DR_MATERIAL_SOLID;
            d.per_frame = true;
        } else if (e->kind == DR_ELEMENT_BEM_SOLID || e->kind == DR_ELEMENT_CLOTH) {
            /* the body's deformed surface or the cloth's panel, which the mesh stage writes for every frame whatever
               mesh.write_obj says (two-sided: a sheet seen from its back is lit as from its front) */
            d.material = DR_MATERIAL_SOLID;
            d.per_frame = true;
        } else if (e->kind == DR_ELEMENT_HAIR) {
            /* strands, from the polylines the mesh stage writes for every frame whatever mesh.write_obj says */
            d.material = DR_MATERIAL_HAIR;
            d.per_frame = true;
            d.strands = true;
        } else if (e->kind == DR_ELEMENT_COLLIDER) {
            d.material = DR_MATERIAL_COLLIDER;
            d.per_frame = dr_component_present(dr_element_component(e, "Motion"));
            if (!d.per_frame) {
                snprintf(path, sizeof path, "%s/%s.obj", mesh_dir, e->name);
                if (!dr_io_exists(path))
                    s = dr_error_set(&err, DR_ERR_INPUT, path, 0, 0,
                                     "collider '%s' has not been meshed; run mesh (or pipeline.sh) first", e->name);
                if (s == DR_OK) s = dr_io_load_mesh(path, &d.still, &err);
            }
        } else {
            continue; /* element kinds without a surface of their own */
        }
        draw[ndraw++] = d;
    }

    DrRenderDesc desc = dr_render_desc_default();
    desc.ground = dr_component_bool(dr_scene_section(scene, "render"), "ground");
    desc.samples = dr_component_int(dr_scene_section(scene, "render"), "samples");
    if (s == DR_OK) shot_ground_and_sizes(scene, draw, ndraw, &desc, &err, &s);

    if (s == DR_OK) s = dr_io_mkdirs(dir, &err);
    const char *inputs[1] = {keys.mesh};
    DrStageFrames run;
    if (s == DR_OK)
        s = dr_stage_frames_begin(dir, DR_STAGE_RENDER, keys.render, scene, first, last, !args.finish, inputs, 1, &run,
                                  &err);
    /* A frame range may run beside others on other machines (a farm's job array), whose temporary files
       look stale from here: only a run that owns the whole folder clears them. */
    if (s == DR_OK && !args.frames_given) dr_io_remove_stale_tmp(dir);

    /* 2. frames, in parallel (a render of one frame, or --finish, uses every thread on it) */
    int nframes = last - first + 1;
    DrStatus *status = NULL;
    DrError *errors = NULL;
    if (s == DR_OK) s = dr_calloc((size_t)nframes, sizeof *status, &status, &err);
    if (s == DR_OK) s = dr_calloc((size_t)nframes, sizeof *errors, &errors, &err);
    DrProgress prog;
    pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
    Job job = {scene, draw, ndraw, mesh_dir, dir, cam, desc, first, status, errors, &prog, &lock};
    if (s == DR_OK && !args.finish) {
        dr_progress_begin(&prog, "render", nframes);
        if (nframes == 1 || dr_threads() == 1) {
            for (int k = 0; k < nframes && s == DR_OK; k++) {
                s = render_frame(&job, first + k, 0, &err);
                if (s == DR_OK) dr_progress_step(&prog, "frame");
            }
        } else {
            dr_parallel_for(nframes, 1, render_range, &job);
            for (int k = 0; k < nframes && s == DR_OK; k++)
                if (status[k] < 0) {
                    s = status[k];
                    err = errors[k];
                }
        }
        dr_progress_end(&prog);
    }
    double t_frames = dr_time_now() - t0;

    /* 3. a whole shot (a full run, --finish after separate ranges, or a range that completes earlier ones): contact
       sheet, plots, MANIFEST */
    int done_first = first, done_last = last;
    if (s == DR_OK) dr_stage_frames_done(&run, &done_first, &done_last);
    bool whole = done_first == shot[0] && done_last == shot[1];
    for (int f = first; s == DR_OK && args.finish && f <= last; f++) {
        dr_stage_frame_path(dir, "frame", f, "png", path, sizeof path);
        if (!dr_io_exists(path))
            s = dr_error_set(&err, DR_ERR_INPUT, path, 0, 0,
                             "render --finish: frame %d has not been rendered; run render --frames %d-%d (or "
                             "pipeline.sh) first",
                             f, f, f);
    }
    int plots = 0;
    if (s == DR_OK && whole) s = write_contact_sheet(dir, shot[0], shot[1],
                                                      dr_component_int(dr_scene_section(scene, "render"), "contact_every"), &err);
    if (s == DR_OK && whole && !args.no_plots) {
        snprintf(path, sizeof path, "%s/progress.jsonl", bake_dir);
        DrError perr;
        dr_error_clear(&perr);
        /* the images are the product; plots that cannot be drawn are reported, not fatal */
        if (plots_write(path, plots_dir, &plots, &perr) < 0) dr_error_print("render: warning: plots", &perr);
    }
    if (s == DR_OK) s = dr_stage_frames_end(&run, inputs, 1, &err);

    for (int i = 0; draw && i < ndraw; i++) dr_trimesh_free(&draw[i].still);
    free(draw);
    free(status);
    free(errors);
    dr_scene_destroy(&scene);
    if (s < 0) return fail(&err);
    if (args.finish)
        fprintf(stderr, "render: frames %d-%d complete: contact sheet, %d plots and MANIFEST written in %s\n", first,
                last, plots, dir);
    else
        fprintf(stderr, "render: %d frames at %dx%d in %.1fs (%.2fs/frame, %d threads)%s, %d plots, written to %s\n",
                nframes, cam.width, cam.height, t_frames, t_frames / nframes, dr_threads(),
                whole ? ", contact sheet" : "", plots, dir);
    return 0;
}
