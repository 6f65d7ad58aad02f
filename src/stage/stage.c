/* What the four stage executables share: the command line, output folders, posed element meshes. */
#include "stage/stage.h"

#include <stdlib.h>
#include <string.h>

static const char *const stage_names[] = {"precompute", "bake", "mesh", "render"};

const char *dr_stage_name(DrStageId stage) { return stage_names[stage]; }

static const char *stage_summary(DrStageId stage)
{
    switch (stage) {
    case DR_STAGE_PRECOMPUTE: return "computes per-asset data (cohesion tables, BEM matrices) into cache/";
    case DR_STAGE_BAKE: return "simulates the shot and writes one HDF5 frame cache per frame";
    case DR_STAGE_MESH: return "turns the bake's frames into OpenVDB level sets and OBJ meshes";
    case DR_STAGE_RENDER: return "renders preview PNGs of the meshed frames";
    }
    return "";
}

static void print_help(DrStageId stage)
{
    const char *n = dr_stage_name(stage);
    printf("usage: %s SCENE.json [options]\n\n%s %s.\n\noptions:\n", n, n, stage_summary(stage));
    if (stage != DR_STAGE_PRECOMPUTE) printf("  --frames A-B        limit to frames A..B of the shot (the MANIFEST records the frames done)\n");
    if (stage == DR_STAGE_MESH || stage == DR_STAGE_RENDER)
        printf("  --finish            after frame ranges ran separately (a farm's job array): check every\n"
               "                      frame's output is there and write the MANIFEST%s\n",
               stage == DR_STAGE_RENDER ? ", contact sheet and plots" : "");
    if (stage == DR_STAGE_RENDER)
        printf("  --plots             only turn the bake's progress.jsonl into PNG plots (gnuplot)\n"
               "  --no-plots          render frames and contact sheet without the plots\n"
               "  --preview           render the scene's initial state (liquid sources, colliders at the\n"
               "                      first frame, grooms, bodies at rest, the scene camera) to\n"
               "                      out/<shot>/preview.png, from the scene alone: nothing baked or meshed\n"
               "                      is read and no stage folder is touched\n");
    if (stage == DR_STAGE_BAKE) {
        printf("  --resume            continue from out/<shot>/bake/checkpoint.h5 (bit-identical to an\n"
               "                      uninterrupted bake)\n"
               "  --verify            check, writing nothing, the frames from the shot's first to its last\n"
               "                      (or to B of --frames A-B) and the checkpoint; print \"shot F L\" (the\n"
               "                      shot's frames), \"good_through N\" (the last frame of the unbroken run\n"
               "                      of good frames) and \"checkpoint N\" (the frame --resume continues\n"
               "                      after) or \"checkpoint none\"; exit 0 when every frame is good, else 2\n"
               "                      naming the first bad frame's file and what is wrong; with --quick,\n"
               "                      the frames' files, numbers and keys only, not their data\n"
               "  --sync-writes       write each frame and checkpoint on the main thread before the next\n"
               "                      frame starts (by default a writer thread writes them while the next\n"
               "                      frame is simulated; the files are the same)\n"
               "  --list-components   print every element type, component and field (unit, default,\n"
               "                      range) and exit; add --markdown for a Markdown reference\n");
    }
    printf("  -j N                threads (default: all cores)\n"
           "  --out DIR           output root (default $DRENCH_OUT or ./out)\n"
           "  --cache DIR         precompute cache root (default $DRENCH_CACHE or ./cache)\n"
           "  --print-key         print this stage's cache key for the scene and exit\n"
           "  --print-out-dir     print this stage's output folder for the scene and exit (after the key\n"
           "                      with --print-key)\n"
           "  --print-frames      print the shot's first and last frame (after --frames) and exit\n"
           "  -q, --quiet         only warnings and errors: no progress bar or per-frame lines\n"
           "  -v, --verbose       also debug lines%s\n"
           "  --help, --version\n\n"
           "progress: on a terminal a bar redrawn in place (rate, ETA from the last frames' cost, peak\n"
           "memory); otherwise one line per frame. 'ALF_PROGRESS NN%%' lines go to stdout when it is not\n"
           "a terminal, or when DRENCH_ALF_PROGRESS=1 (=0: never).\n\n"
           "exit codes: 0 success, 1 runtime failure, 2 bad input (scene, asset or arguments)\n",
           stage == DR_STAGE_BAKE ? ", and the defaults each element took for what the scene leaves out" : "");
    if (stage == DR_STAGE_BAKE)
        printf("            3 stopped by SIGUSR1, SIGTERM or SIGINT: the frame in progress was finished and\n"
               "              checkpointed; continue with --resume (a second signal stops at once)\n");
}

static DrStatus usage_error(DrStageId stage, DrError *err, const char *fmt, const char *arg)
{
    char msg[512];
    snprintf(msg, sizeof msg, fmt, arg);
    return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "%s; run '%s --help' for usage", msg, dr_stage_name(stage));
}

static bool parse_int(const char *s, int *out)
{
    char *end;
    long v = strtol(s, &end, 10);
    if (end == s || *end || v < -1000000000L || v > 1000000000L) return false;
    *out = (int)v;
    return true;
}

DrStatus dr_stage_parse_args(DrStageId stage, int argc, char **argv, DrStageArgs *a, bool *done, DrError *err)
{
    memset(a, 0, sizeof *a);
    a->stage = stage;
    *done = false;
    a->out_root = getenv("DRENCH_OUT") && *getenv("DRENCH_OUT") ? getenv("DRENCH_OUT") : "out";
    a->cache_root = getenv("DRENCH_CACHE") && *getenv("DRENCH_CACHE") ? getenv("DRENCH_CACHE") : "cache";
    for (int i = 1; i < argc; i++) {
        const char *s = argv[i];
        bool has_next = i + 1 < argc;
        if (!strcmp(s, "--help") || !strcmp(s, "-h")) {
            print_help(stage);
            *done = true;
            return DR_OK;
        } else if (!strcmp(s, "--version")) {
            printf("%s (drench) %s\n", dr_stage_name(stage), DR_VERSION);
            *done = true;
            return DR_OK;
        } else if (!strcmp(s, "--frames")) {
            if (!has_next) return usage_error(stage, err, "%s needs a range A-B", s);
            const char *r = argv[++i];
            char buf[64];
            snprintf(buf, sizeof buf, "%s", r);
            char *dash = strchr(buf + 1, '-');
            if (dash) *dash = 0;
            if (!dash || !parse_int(buf, &a->frame_first) || !parse_int(dash + 1, &a->frame_last))
                return usage_error(stage, err, "--frames '%s' is not a range like 1-48", r);
            if (a->frame_first > a->frame_last)
                return usage_error(stage, err, "--frames '%s' is out of order: the first frame must not exceed the last", r);
            a->frames_given = true;
        } else if (!strcmp(s, "-j") || !strcmp(s, "--threads")) {
            if (!has_next || !parse_int(argv[i + 1], &a->threads) || a->threads < 1 || a->threads > 1024)
                return usage_error(stage, err, "%s needs a thread count between 1 and 1024", s);
            i++;
        } else if (!strncmp(s, "-j", 2) && s[2]) {
            if (!parse_int(s + 2, &a->threads) || a->threads < 1 || a->threads > 1024)
                return usage_error(stage, err, "'%s' needs a thread count between 1 and 1024", s);
        } else if (!strcmp(s, "--out") || !strcmp(s, "--cache")) {
            if (!has_next) return usage_error(stage, err, "%s needs a folder", s);
            if (!strcmp(s, "--out")) a->out_root = argv[++i];
            else a->cache_root = argv[++i];
        } else if (!strcmp(s, "--resume") && stage == DR_STAGE_BAKE) {
            a->resume = true;
        } else if (!strcmp(s, "--verify") && stage == DR_STAGE_BAKE) {
            a->verify = true;
        } else if (!strcmp(s, "--quick") && stage == DR_STAGE_BAKE) {
            a->quick = true;
        } else if (!strcmp(s, "--sync-writes") && stage == DR_STAGE_BAKE) {
            a->sync_writes = true;
        } else if (!strcmp(s, "--finish") && (stage == DR_STAGE_MESH || stage == DR_STAGE_RENDER)) {
            a->finish = true;
        } else if (!strcmp(s, "--plots") && stage == DR_STAGE_RENDER) {
            a->plots_only = true;
        } else if (!strcmp(s, "--no-plots") && stage == DR_STAGE_RENDER) {
            a->no_plots = true;
        } else if (!strcmp(s, "--preview") && stage == DR_STAGE_RENDER) {
            a->preview = true;
        } else if (!strcmp(s, "--list-components") && stage == DR_STAGE_BAKE) {
            a->list_components = true;
        } else if (!strcmp(s, "--markdown")) {
            a->markdown = true;
        } else if (!strcmp(s, "--print-key")) {
            a->print_key = true;
        } else if (!strcmp(s, "--print-out-dir")) {
            a->print_out_dir = true;
        } else if (!strcmp(s, "--print-frames")) {
            a->print_frames = true;
        } else if (!strcmp(s, "-q") || !strcmp(s, "--quiet")) {
            a->quiet = true;
        } else if (!strcmp(s, "-v") || !strcmp(s, "--verbose")) {
            a->verbose = true;
        } else if (s[0] == '-' && s[1]) {
            return usage_error(stage, err, "unknown option '%s'", s);
        } else if (a->scene_path) {
            return usage_error(stage, err, "more than one scene given ('%s')", s);
        } else {
            a->scene_path = s;
        }
    }
    if (!a->scene_path && !a->list_components)
        return usage_error(stage, err, "%s", "no scene given: pass the scene file, e.g. assets/scenes/default.json");
    if (a->quick && !a->verify) return usage_error(stage, err, "%s", "--quick goes with --verify");
    if (a->verify && (a->resume || a->print_key || a->print_out_dir || a->print_frames))
        return usage_error(stage, err, "%s", "--verify only checks: it does not combine with --resume or --print-*");
    if (a->finish && a->frames_given)
        return usage_error(stage, err, "%s", "--finish covers the whole shot; it does not take --frames");
    if (a->plots_only && (a->finish || a->no_plots))
        return usage_error(stage, err, "%s", "--plots cannot be combined with --finish or --no-plots");
    if (a->preview && (a->finish || a->plots_only || a->no_plots || a->frames_given))
        return usage_error(stage, err, "%s", "--preview renders the scene alone; it takes none of --finish, --plots, "
                                             "--no-plots, --frames");
    if (a->quiet && a->verbose) return usage_error(stage, err, "%s", "-q and -v contradict each other; give one");
    if (a->quiet) dr_log_set_level(DR_LOG_WARN);
    if (a->verbose) dr_log_set_level(DR_LOG_DEBUG);
    if (a->threads > 0) dr_set_threads(a->threads);
    return DR_OK;
}

void dr_stage_out_dir(const DrStageArgs *a, const DrScene *scene, DrStageId stage, char *buf, size_t size)
{
    snprintf(buf, size, "%s/%s/%s", a->out_root, dr_component_str(dr_scene_section(scene, "shot"), "name"),
             dr_stage_name(stage));
}

DrStatus dr_stage_frame_range(const DrStageArgs *a, const DrScene *scene, int *first, int *last, DrError *err)
{
    int fr[2];
    dr_component_int2(dr_scene_section(scene, "shot"), "frames", fr);
    *first = fr[0];
    *last = fr[1];
    if (!a->frames_given) return DR_OK;
    if (a->frame_first < fr[0] || a->frame_last > fr[1])
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "--frames %d-%d is outside the shot's frames %d-%d (shot.frames in %s)", a->frame_first,
                            a->frame_last, fr[0], fr[1], dr_scene_path(scene));
    *first = a->frame_first;
    *last = a->frame_last;
    return DR_OK;
}

void dr_stage_frame_path(const char *dir, const char *prefix, int frame, const char *ext, char *buf, size_t size)
{
    snprintf(buf, size, "%s/%s.%04d.%s", dir, prefix, frame, ext);
}

static const char *stage_key(const DrSceneKeys *k, DrStageId stage)
{
    switch (stage) {
    case DR_STAGE_PRECOMPUTE: return k->precompute;
    case DR_STAGE_BAKE: return k->bake;
    case DR_STAGE_MESH: return k->mesh;
    case DR_STAGE_RENDER: return k->render;
    }
    return "";
}

DrStatus dr_stage_begin(DrStageId stage, int argc, char **argv, DrStageArgs *args, DrScene **scene,
                        DrSceneKeys *keys, char *dir, size_t dir_size, bool *done, DrError *err)
{
    *scene = NULL;
    dr_thread_defaults(argv);
    DR_TRY(dr_stage_parse_args(stage, argc, argv, args, done, err));
    if (*done) return DR_OK;
    if (args->list_components) {
        dr_scene_print_reference(stdout, args->markdown);
        *done = true;
        return DR_OK;
    }
    DR_TRY(dr_scene_load(args->scene_path, scene, err));
    DrStatus s = dr_scene_keys(*scene, keys, err);
    if (s < 0) {
        dr_scene_destroy(scene);
        return s;
    }
    dr_stage_out_dir(args, *scene, stage, dir, dir_size);
    if (args->print_frames) {
        int first, last;
        s = dr_stage_frame_range(args, *scene, &first, &last, err);
        if (s == DR_OK) printf("%d %d\n", first, last);
        dr_scene_destroy(scene);
        *done = s == DR_OK;
        return s;
    }
    /* The assets are checked as loading them in the stage would (so a key is printed only for a scene the stage
       accepts); --print-out-dir and --print-frames only name things. */
    if (args->print_key || !args->print_out_dir) s = dr_stage_check_assets(*scene, err);
    if (s < 0) {
        dr_scene_destroy(scene);
        return s;
    }
    if (args->print_key || args->print_out_dir) {
        if (args->print_key) printf("%s\n", stage_key(keys, stage));
        if (args->print_out_dir) printf("%s\n", dir); /* both: the key, then the folder (pipeline.sh asks so) */
        dr_scene_destroy(scene);
        *done = true;
    }
    return DR_OK;
}

/* ---- element meshes in their scene pose ------------------------------------------------------------------- */

DrXform dr_stage_element_transform(const DrElement *e, double *scale)
{
    const DrComponent *tr = dr_element_component(e, "Transform");
    DrXform X = {dr_m3_from_euler_xyz(dr_v3_scale(dr_component_vec3(tr, "rotate_deg"), DR_PI / 180.0)),
                 dr_component_vec3(tr, "translate")};
    *scale = dr_component_num(tr, "scale");
    return X;
}

DrStatus dr_stage_load_posed_mesh(const DrElement *e, const char *path, const char *field, DrTriMesh *mesh,
                                  DrError *err)
{
    DR_TRY(dr_error_prefix(dr_io_load_mesh(path, mesh, err), err, "%s.%s", e->name, field));
    free(mesh->n); /* file normals would not follow the transform; consumers recompute what they need */
    mesh->n = NULL;
    if (!dr_element_component(e, "Transform")) return DR_OK;
    double s;
    DrXform X = dr_stage_element_transform(e, &s);
    for (int i = 0; i < mesh->nv; i++) {
        DrVec3 p = dr_v3(mesh->v[3 * i], mesh->v[3 * i + 1], mesh->v[3 * i + 2]);
        p = dr_v3_add(dr_m3_apply(X.R, dr_v3_scale(p, s)), X.t);
        mesh->v[3 * i] = p.x;
        mesh->v[3 * i + 1] = p.y;
        mesh->v[3 * i + 2] = p.z;
    }
    return DR_OK;
}

DrStatus dr_stage_load_collider_mesh(const DrElement *e, DrTriMesh *mesh, DrError *err)
{
    return dr_stage_load_posed_mesh(e, dr_component_str(dr_element_component(e, "Mesh"), "file"), "Mesh.file", mesh,
                                    err);
}

DrStatus dr_stage_motion_keys(const DrElement *e, int first_frame, double fps, double **keys, int *nkeys, DrError *err)
{
    const double *rows = NULL;
    int n = dr_component_table(dr_element_component(e, "Motion"), "keys", &rows);
    *nkeys = 0;
    DR_TRY(dr_calloc((size_t)n * 7 + 7, sizeof(double), keys, err));
    for (int k = 0; k < n; k++) {
        (*keys)[7 * k] = (rows[7 * k] - first_frame + 1) / fps;
        for (int j = 1; j < 4; j++) (*keys)[7 * k + j] = rows[7 * k + j];
        for (int j = 4; j < 7; j++) (*keys)[7 * k + j] = rows[7 * k + j] * DR_PI / 180.0;
    }
    *nkeys = n;
    return DR_OK;
}
