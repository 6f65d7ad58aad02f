/* bake: simulates a shot frame by frame into out/<shot>/bake/ (frame caches, checkpoint, progress, report). */
#include <dirent.h>
#include <jansson.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "io/io.h"
#include "scene/scene.h"
#include "stage/stage.h"
#include "world/world.h"

typedef struct Totals {
    double p2g, pressure, g2p, advect, other, io, frames_seconds;
    double io_wait;   /* part of io (main thread) spent waiting for the writer thread */
    double io_writer; /* seconds the writer thread spent writing (0 with --sync-writes) */
    long io_files;    /* frame caches and checkpoints written, or handed to the writer thread */
    bool io_background;
    long pressure_total;
    int pressure_max, not_converged, substeps_max, frames;
    long particles_first, particles_last;
    double volume_drift_max;
    bool mpm;
    long mpm_particles, mpm_newton, mpm_cg;
    int mpm_not_converged;
    double mpm_transfer, mpm_solve;
    bool hair;
    long hair_vertices, hair_cg;
    int hair_not_converged;
    double hair_seconds;
    bool bem;
    int bem_bodies;
    long bem_steps;
    double bem_seconds, bem_max_displacement;
    long bem_pgs_iterations;
    int bem_not_converged;
    double bem_residual_max, bem_seconds_trial, bem_seconds_detect, bem_seconds_assembly, bem_seconds_pgs,
        bem_seconds_final;
} Totals;

/* Exit code of a bake stopped by SIGUSR1, SIGTERM or SIGINT after writing its checkpoint: the caller (a
 * person, pipeline.sh, or a farm job asked to leave before its time limit) continues with --resume. */
enum { EXIT_INTERRUPTED = 3 };

static volatile sig_atomic_t stop_signal;

/* The first signal asks for a clean stop at the next frame boundary; a second one kills as usual. */
static void on_stop_signal(int sig)
{
    stop_signal = sig;
    signal(sig, SIG_DFL);
}

static void install_stop_handlers(void)
{
    const int sigs[] = {SIGUSR1, SIGTERM, SIGINT};
    for (size_t i = 0; i < sizeof sigs / sizeof sigs[0]; i++) {
        struct sigaction sa;
        memset(&sa, 0, sizeof sa);
        sa.sa_handler = on_stop_signal;
        sa.sa_flags = SA_RESTART; /* file writes in flight (HDF5) must not fail with EINTR */
        sigemptyset(&sa.sa_mask);
        sigaction(sigs[i], &sa, NULL);
    }
}

static void remove_previous_outputs(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d) return;
    struct dirent *e;
    char path[4096];
    while ((e = readdir(d))) {
        const char *n = e->d_name;
        bool frame = !strncmp(n, "frame.", 6) && strstr(n, ".h5");
        if (frame || !strcmp(n, "checkpoint.h5") || !strcmp(n, "progress.jsonl") || !strcmp(n, "report.json")) {
            snprintf(path, sizeof path, "%s/%s", dir, n);
            unlink(path);
        }
    }
    closedir(d);
}

/* On resume, keeps only the progress lines of frames the checkpoint covers (later ones are baked again). */
static DrStatus trim_progress(const char *path, int last_frame, DrError *err)
{
    char *text = NULL;
    if (!dr_io_exists(path)) return DR_OK;
    DR_TRY(dr_io_read_text(path, &text, err));
    size_t cap = strlen(text) + 1, len = 0;
    char *out = calloc(cap, 1);
    if (!out) {
        free(text);
        return dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "out of memory");
    }
    for (char *line = strtok(text, "\n"); line; line = strtok(NULL, "\n")) {
        const char *f = strstr(line, "\"frame\":");
        if (f && atoi(f + 8) <= last_frame) len += (size_t)snprintf(out + len, cap - len, "%s\n", line);
    }
    DrStatus s = dr_io_write_text_atomic(path, out, err);
    free(text);
    free(out);
    return s;
}

/* Output seconds of one frame: io is the main thread's (recording the frame and checkpoint and handing them
 * to the writer, or writing them itself with --sync-writes), wait the part of io spent waiting for the
 * writer, writer the writer thread's own seconds on the files it finished since the previous frame's line. */
typedef struct FrameIo {
    double io, wait, writer;
    bool background;
} FrameIo;

static void append_progress(const char *path, const DrFrameStats *fs, const FrameIo *io)
{
    FILE *f = fopen(path, "a");
    if (!f) {
        dr_log_warn("cannot append to %s; progress of this frame is not logged", path);
        return;
    }
    fprintf(f,
            "{\"frame\":%d,\"time\":%.9g,\"substeps\":%d,\"particles\":%ld,\"pressure_iterations_max\":%d,"
            "\"pressure_iterations_total\":%ld,\"pressure_not_converged\":%d,\"liquid_volume\":%.9g,"
            "\"volume_drift\":%.6g,\"kinetic_energy\":%.9g,",
            fs->frame, fs->time, fs->substeps, fs->liquid.particles, fs->liquid.pressure_iterations_max,
            fs->liquid.pressure_iterations_total, fs->liquid.pressure_not_converged, fs->liquid.volume, fs->liquid.drift,
            fs->kinetic_energy);
    if (fs->liquid.present)
        fprintf(f, "\"liquid_substeps\":%d,\"liquid_particle_volume\":%.9g,", fs->liquid.substeps,
                fs->liquid.particle_volume);
    /* MPM solids, only in scenes that have them; the names follow render/plots.c's rules (…_iterations,
       …_energy, momentum.*, seconds.*) so the plots pick them up */
    if (fs->mpm.present)
        fprintf(f,
                "\"mpm_particles\":%ld,\"mpm_substeps\":%d,\"mpm_newton_iterations\":%ld,\"mpm_cg_iterations\":%ld,"
                "\"mpm_newton_residual\":%.6g,\"mpm_newton_not_converged\":%d,\"mpm_kinetic_energy\":%.9g,"
                "\"mpm_elastic_energy\":%.9g,\"mpm_gravity_energy\":%.9g,\"mpm_total_energy\":%.9g,",
                fs->mpm.particles, fs->mpm.substeps, fs->mpm.newton_iterations, fs->mpm.cg_iterations,
                fs->mpm.newton_residual, fs->mpm.not_converged, fs->mpm.kinetic_energy, fs->mpm.elastic_energy,
                fs->mpm.gravity_energy, fs->mpm.kinetic_energy + fs->mpm.elastic_energy + fs->mpm.gravity_energy);
    /* cloth panels */
    if (fs->cloth.present)
        fprintf(f,
                "\"cloth_vertices\":%ld,\"cloth_substeps\":%d,\"cloth_cg_iterations\":%ld,\"cloth_not_converged\":%d,"
                "\"cloth_kinetic_energy\":%.9g,\"cloth_membrane_energy\":%.9g,\"cloth_bending_energy\":%.9g,"
                "\"cloth_gravity_energy\":%.9g,\"cloth_total_energy\":%.9g,\"cloth_collider_contacts\":%d,"
                "\"cloth_self_contacts\":%d,",
                fs->cloth.vertices, fs->cloth.substeps, fs->cloth.cg_iterations, fs->cloth.not_converged,
                fs->cloth.kinetic_energy, fs->cloth.membrane_energy, fs->cloth.bending_energy, fs->cloth.gravity_energy,
                fs->cloth.kinetic_energy + fs->cloth.membrane_energy + fs->cloth.bending_energy +
                    fs->cloth.gravity_energy, fs->cloth.collider_contacts, fs->cloth.self_contacts);
    /* boundary-element bodies: the energies of their rigid frames (kinetic and gravity's) */
    if (fs->bem.present)
        fprintf(f,
                "\"bem_bodies\":%d,\"bem_steps\":%ld,\"bem_kinetic_energy\":%.9g,\"bem_potential_energy\":%.9g,"
                "\"bem_total_energy\":%.9g,\"bem_max_displacement\":%.9g,\"bem_translation_error\":%.6g,"
                "\"bem_rotation_error\":%.6g,\"bem_contacts\":%d,\"bem_body_contacts\":%d,\"bem_fixed\":%d,"
                "\"bem_joints\":%d,\"bem_pgs_iterations\":%ld,\"bem_residual\":%.6g,\"bem_not_converged\":%d,",
                fs->bem.bodies, fs->bem.steps, fs->bem.kinetic_energy, fs->bem.potential_energy,
                fs->bem.kinetic_energy + fs->bem.potential_energy, fs->bem.max_displacement, fs->bem.translation_error,
                fs->bem.rotation_error, fs->bem.contacts, fs->bem.body_contacts, fs->bem.fixed, fs->bem.joints,
                fs->bem.pgs_iterations, fs->bem.residual, fs->bem.not_converged);
    /* one "momentum" object: a panel per vector */
    if (fs->mpm.present || fs->bem.present) {
        fprintf(f, "\"momentum\":{");
        if (fs->mpm.present) {
            DrVec3 p = fs->mpm.momentum, l = fs->mpm.angular_momentum;
            fprintf(f,
                    "\"mpm_linear\":{\"x\":%.9g,\"y\":%.9g,\"z\":%.9g},\"mpm_angular\":{\"x\":%.9g,\"y\":%.9g,"
                    "\"z\":%.9g}%s",
                    p.x, p.y, p.z, l.x, l.y, l.z, fs->bem.present ? "," : "");
        }
        if (fs->bem.present)
            fprintf(f, "\"bem_linear\":{\"x\":%.9g,\"y\":%.9g,\"z\":%.9g}", fs->bem.momentum.x, fs->bem.momentum.y,
                    fs->bem.momentum.z);
        fprintf(f, "},");
    }
    if (fs->hair.present)
        fprintf(f,
                "\"hair_vertices\":%ld,\"hair_substeps\":%d,\"hair_cg_iterations\":%ld,\"hair_residual\":%.6g,"
                "\"hair_not_converged\":%d,\"hair_collider_contacts\":%d,\"hair_contacts\":%d,"
                "\"hair_kinetic_energy\":%.9g,\"hair_elastic_energy\":%.9g,\"hair_gravity_energy\":%.9g,"
                "\"hair_total_energy\":%.9g,",
                fs->hair.vertices, fs->hair.substeps, fs->hair.cg_iterations, fs->hair.residual, fs->hair.not_converged,
                fs->hair.collider_contacts, fs->hair.contacts, fs->hair.kinetic_energy, fs->hair.elastic_energy,
                fs->hair.gravity_energy, fs->hair.kinetic_energy + fs->hair.elastic_energy + fs->hair.gravity_energy);
    if (fs->hair.present && fs->hair.meets_cloth)
        fprintf(f, "\"hair_cloth_contacts\":%d,", fs->hair.cloth_contacts);
    if (fs->hair.present)
        fprintf(f, "\"hair_scalp_work\":%.9g,\"hair_max_speed\":%.9g,\"hair_max_speed_growth\":%.6g,", fs->hair.scalp_work,
                fs->hair.max_speed, fs->hair.max_speed_growth);
    if (fs->hair.wet) /* the film and the bridges; the volumes in m^3 */
        fprintf(f,
                "\"film_volume\":%.9g,\"film_pool_volume\":%.9g,\"film_max_ratio\":%.6g,\"film_kinetic_energy\":%.9g,"
                "\"film_gravity_energy\":%.9g,\"film_substeps\":%d,\"hair_bridges\":%d,\"hair_solid_bridges\":%d,"
                "\"film_cross_flow\":%.9g,",
                fs->hair.film_volume, fs->hair.pool_volume, fs->hair.film_max_ratio, fs->hair.film_kinetic_energy,
                fs->hair.film_gravity_energy, fs->hair.film_substeps, fs->hair.bridges, fs->hair.solid_bridges,
                fs->hair.cross_flow);
    if (fs->hair.exchange) /* capture, dripping and the volume ledger, m^3 */
        fprintf(f,
                "\"captured\":%.9g,\"dripped\":%.9g,\"drops\":%ld,\"captured_particles\":%ld,\"drip_held_back\":%.9g,"
                "\"volume_bulk\":%.12g,\"volume_emitted\":%.12g,\"volume_removed\":%.12g,\"volume_total\":%.12g,"
                "\"volume_initial\":%.12g,\"volume_error\":%.3g,",
                fs->hair.captured, fs->hair.dripped, fs->hair.drops, fs->hair.captured_particles, fs->hair.held_back,
                fs->hair.ledger_bulk, fs->hair.ledger_emitted, fs->hair.ledger_removed, fs->hair.ledger_total,
                fs->hair.ledger_initial, fs->hair.ledger_error);
    if (fs->coupling.steps > 0) /* the coupled loop (src/couple): iterations and the momentum ledger, N s */
        fprintf(f,
                "\"coupling_steps\":%d,\"coupling_iterations\":%ld,\"coupling_iterations_max\":%d,"
                "\"coupling_not_converged\":%d,\"coupling_change_max\":%.6g,\"coupling_impulse_hair\":{\"x\":%.9g,"
                "\"y\":%.9g,\"z\":%.9g},\"coupling_impulse_fluid\":{\"x\":%.9g,\"y\":%.9g,\"z\":%.9g},",
                fs->coupling.steps, fs->coupling.iterations, fs->coupling.iterations_max, fs->coupling.not_converged,
                fs->coupling.change_max, fs->coupling.solid_impulse.x, fs->coupling.solid_impulse.y,
                fs->coupling.solid_impulse.z, fs->coupling.fluid_impulse.x, fs->coupling.fluid_impulse.y,
                fs->coupling.fluid_impulse.z);
    fprintf(f,
            "\"seconds\":{\"p2g\":%.6f,\"pressure\":%.6f,\"g2p\":%.6f,\"advect\":%.6f,\"other\":%.6f,",
            fs->liquid.seconds_p2g, fs->liquid.seconds_pressure, fs->liquid.seconds_g2p, fs->liquid.seconds_advect, fs->liquid.seconds_other);
    if (fs->mpm.present)
        fprintf(f, "\"mpm_transfer\":%.6f,\"mpm_solve\":%.6f,", fs->mpm.seconds_transfer, fs->mpm.seconds_solve);
    if (fs->hair.present) fprintf(f, "\"hair\":%.6f,", fs->hair.seconds);
    if (fs->hair.wet) /* parts of "hair" */
        fprintf(f, "\"film\":%.6f,\"cross_flow\":%.6f,\"bridges\":%.6f,", fs->hair.seconds_film,
                fs->hair.seconds_cross_flow, fs->hair.seconds_bridges);
    if (fs->hair.exchange) fprintf(f, "\"capture_drip\":%.6f,", fs->hair.seconds_exchange);
    if (fs->cloth.present) fprintf(f, "\"cloth\":%.6f,", fs->cloth.seconds);
    if (fs->bem.present)
        fprintf(f,
                "\"bem_history\":%.6f,\"bem_solve\":%.6f,\"bem_correction\":%.6f,\"bem_trial\":%.6f,"
                "\"bem_detect\":%.6f,\"bem_assembly\":%.6f,\"bem_pgs\":%.6f,\"bem_final\":%.6f,",
                fs->bem.seconds_history, fs->bem.seconds_solve, fs->bem.seconds_correction, fs->bem.seconds_trial,
                fs->bem.seconds_detect, fs->bem.seconds_assembly, fs->bem.seconds_pgs, fs->bem.seconds_final);
    fprintf(f, "\"io\":%.6f,\"frame\":%.6f},", io->io, fs->seconds + io->io);
    /* the coupled loop's wall time: it holds parts of the fluid's and the solids' seconds, so it is not a share */
    if (fs->coupling.steps > 0) fprintf(f, "\"coupling_seconds\":%.6f,", fs->coupling.seconds);
    /* outside "seconds", whose keys the plots stack as shares of the frame: the writer's seconds overlap
       the next frame's simulation and the wait is part of seconds.io */
    fprintf(f, "\"io\":{\"background\":%s,\"wait\":%.6f,\"writer\":%.6f}}\n", io->background ? "true" : "false",
            io->wait, io->writer);
    fclose(f);
}

/* The defaults the scene applied (dr_element_applied_defaults): {"sections": {"shot": {field: value}, "solver":
 * {...}}, "elements": {name: {Component: {field: value}}}}, values as JSON; with log, also one -v line per element
 * and section. */
static json_t *applied_defaults(const DrScene *scene, bool log)
{
    json_t *root = json_object(), *sections = json_object(), *elements = json_object();
    json_object_set_new(root, "sections", sections);
    json_object_set_new(root, "elements", elements);
    DrAppliedDefault list[256];
    int nel = dr_scene_element_count(scene);
    for (int i = -2; i < nel; i++) {
        static const char *const names[2] = {"shot", "solver"};
        const DrElement *e = i >= 0 ? dr_scene_element(scene, i) : NULL;
        int n = e ? dr_element_applied_defaults(e, list, 256) : dr_section_applied_defaults(scene, names[i + 2], list, 256);
        if (n > 256) n = 256;
        json_t *obj = json_object();
        char line[4096] = "", value[256];
        size_t used = 0;
        for (int k = 0; k < n; k++) {
            dr_scene_default_json(list[k].field, value, sizeof value);
            json_t *v = json_loads(value, JSON_DECODE_ANY, NULL);
            if (!v) continue;
            json_t *into = obj;
            if (e) {
                into = json_object_get(obj, list[k].component);
                if (!into) json_object_set_new(obj, list[k].component, into = json_object());
            }
            json_object_set_new(into, list[k].field->name, v);
            const char *unit = list[k].field->unit;
            if (used < sizeof line)
                used += (size_t)snprintf(line + used, sizeof line - used, "%s%s.%s = %s%s%s", k ? ", " : "",
                                         list[k].component, list[k].field->name, value,
                                         unit[0] && strcmp(unit, "1") ? " " : "", strcmp(unit, "1") ? unit : "");
        }
        json_object_set_new(e ? elements : sections, e ? e->name : names[i + 2], obj);
        if (log && e)
            dr_log_debug("%s (%s): defaults applied: %s", e->name, e->type, n ? line : "none (every field written)");
        else if (log)
            dr_log_debug("%s: defaults applied: %s", names[i + 2], n ? line : "none (every field written)");
    }
    return root;
}

static DrStatus write_report(const char *dir, const char *status, const char *message, const DrScene *scene, const char *key, int first, int last, const Totals *t,
                             double wall, DrError *err)
{
    json_t *r = json_pack("{s:s, s:s, s:s, s:s, s:s, s:[i,i], s:i, s:i, s:f}", "status", status, "message",
                          message ? message : "", "scene", dr_scene_path(scene), "key", key, "drench_version",
                          DR_VERSION, "frames", first, last, "frames_baked", t->frames, "threads", dr_threads(),
                          "seconds_total", wall);
    json_object_set_new(r, "seconds_by_phase",
                        json_pack("{s:f, s:f, s:f, s:f, s:f, s:f}", "p2g", t->p2g, "pressure", t->pressure, "g2p",
                                  t->g2p, "advect", t->advect, "other", t->other, "io", t->io));
    /* main_thread_seconds (= seconds_by_phase.io) is what the bake waited for its output; writer_seconds ran
       beside the simulation */
    json_object_set_new(r, "io",
                        json_pack("{s:b, s:I, s:f, s:f, s:f, s:f}", "background", t->io_background,
                                  "files", (json_int_t)t->io_files, "main_thread_seconds", t->io,
                                  "wait_seconds", t->io_wait, "writer_seconds", t->io_writer,
                                  "main_thread_share", wall > 0 ? t->io / wall : 0.0));
    json_object_set_new(r, "pressure_iterations",
                        json_pack("{s:i, s:I, s:i}", "max", t->pressure_max, "total", (json_int_t)t->pressure_total,
                                  "not_converged_substeps", t->not_converged));
    json_object_set_new(r, "particles",
                        json_pack("{s:I, s:I}", "first_frame", (json_int_t)t->particles_first, "last_frame",
                                  (json_int_t)t->particles_last));
    /* occupied liquid cells × Δx³ against the first frame: a cheap, noisy estimate (splashes fill cells
       partly); the mesh stage's level set measures the volume itself */
    json_object_set_new(r, "occupied_cell_volume", json_pack("{s:f}", "max_relative_drift", t->volume_drift_max));
    json_object_set_new(r, "substeps_max", json_integer(t->substeps_max));
    /* the process's peak resident memory: what a farm job of this shot must request */
    json_object_set_new(r, "peak_rss_bytes", json_integer((json_int_t)dr_peak_rss_bytes()));
    json_object_set_new(r, "defaults_applied", applied_defaults(scene, false));
    if (t->mpm)
        json_object_set_new(r, "mpm",
                            json_pack("{s:I, s:I, s:I, s:i, s:f, s:f}", "particles", (json_int_t)t->mpm_particles,
                                      "newton_iterations", (json_int_t)t->mpm_newton, "cg_iterations",
                                      (json_int_t)t->mpm_cg, "newton_not_converged_frames", t->mpm_not_converged,
                                      "seconds_transfer", t->mpm_transfer, "seconds_solve", t->mpm_solve));
    if (t->hair)
        json_object_set_new(r, "hair",
                            json_pack("{s:I, s:I, s:i, s:f}", "vertices", (json_int_t)t->hair_vertices, "cg_iterations",
                                      (json_int_t)t->hair_cg, "not_converged_substeps", t->hair_not_converged,
                                      "seconds", t->hair_seconds));
    if (t->bem)
        json_object_set_new(r, "bem",
                            json_pack("{s:i, s:I, s:f, s:f, s:I, s:f, s:i, s:{s:f, s:f, s:f, s:f, s:f}}", "bodies",
                                      t->bem_bodies, "steps", (json_int_t)t->bem_steps, "seconds", t->bem_seconds,
                                      "max_displacement", t->bem_max_displacement, "pgs_iterations",
                                      (json_int_t)t->bem_pgs_iterations, "residual_max", t->bem_residual_max,
                                      "not_converged", t->bem_not_converged, "seconds_by_phase", "trial",
                                      t->bem_seconds_trial, "detection", t->bem_seconds_detect, "assembly",
                                      t->bem_seconds_assembly, "pgs", t->bem_seconds_pgs, "final",
                                      t->bem_seconds_final));
    char *text = json_dumps(r, JSON_INDENT(2) | JSON_REAL_PRECISION(9));
    json_decref(r);
    char path[4096];
    snprintf(path, sizeof path, "%s/report.json", dir);
    size_t n = strlen(text);
    char *withnl = malloc(n + 2);
    memcpy(withnl, text, n);
    withnl[n] = '\n';
    withnl[n + 1] = 0;
    DrStatus s = dr_io_write_text_atomic(path, withnl, err);
    free(text);
    free(withnl);
    return s;
}

/* Writes the frame cache (fs non-NULL) or the checkpoint to path: recorded and handed to the writer thread,
 * or, without one (--sync-writes), written and renamed into place here. *wait grows by the seconds spent
 * waiting for the writer to have room. A failure of an earlier file in the background comes back here. */
static DrStatus write_output(DrH5Writer *writer, const DrWorld *world, const DrFrameStats *fs, const char *key,
                             const char *path, double *wait, DrError *err)
{
    DrH5 *h = NULL;
    DR_TRY(writer ? dr_h5_create_deferred(path, &h, err) : dr_h5_create(path, &h, err));
    DrStatus s = fs ? dr_world_write_frame(world, fs, key, h, err) : dr_world_write_checkpoint(world, key, h, err);
    if (s < 0) {
        dr_h5_close(&h); /* uncommitted: nothing appears at path */
        return s;
    }
    if (!writer) return dr_h5_commit(&h, err);
    double t0 = dr_time_now();
    s = dr_h5_writer_submit(writer, &h, err);
    *wait += dr_time_now() - t0;
    return s;
}

static int fail(const DrError *err)
{
    dr_error_print("bake", err);
    return dr_exit_code(err->status);
}

/* bake --verify: the frames shot_first..last and the checkpoint, checked as --resume and the later stages take
 * them; prints what pipeline.sh reads on stdout ("shot F L", "good_through G", "checkpoint C|none") and what is
 * wrong on stderr. Exit 0 when every frame is good, 2 otherwise (a missing, damaged or foreign frame alike). */
static int verify(const char *dir, const char *key, int shot_first, int shot_last, int last, bool data)
{
    DrError err, cerr;
    dr_error_clear(&err);
    int good, ckpt;
    DrStatus s = dr_stage_check_frames(dir, shot_first, last, key, data, &good, &err);
    char path[4096];
    snprintf(path, sizeof path, "%s/checkpoint.h5", dir);
    DrStatus cs = dr_stage_check_checkpoint(path, key, shot_first, shot_last, &ckpt, &cerr);
    printf("shot %d %d\n", shot_first, shot_last);
    printf("good_through %d\n", good);
    if (cs == DR_OK) printf("checkpoint %d\n", ckpt);
    else printf("checkpoint none\n");
    fflush(stdout);
    if (cs < 0 && dr_io_exists(path)) {
        dr_error_prefix(cs, &cerr, "bake --resume cannot continue from it");
        dr_error_print("bake", &cerr);
    }
    if (s == DR_ERR_INPUT) {
        dr_h5_drop_fix(&err);
        char msg[sizeof err.message], file[sizeof err.file], before[64] = "no frame before it is good";
        snprintf(msg, sizeof msg, "%s", err.message);
        snprintf(file, sizeof file, "%s", err.file);
        if (good >= shot_first) snprintf(before, sizeof before, "frames %d-%d before it are good", shot_first, good);
        dr_error_set(&err, s, file, 0, 0, "%s; %s: bake from frame %d again (pipeline.sh does it)", msg, before,
                     good + 1);
    }
    if (s < 0) return fail(&err);
    fprintf(stderr, "bake: frames %d-%d are good%s\n", shot_first, last, data ? "" : " (files, numbers and keys)");
    return 0;
}

int main(int argc, char **argv)
{
    DrError err;
    dr_error_clear(&err);
    DrStageArgs args;
    bool done;
    DrScene *scene = NULL;
    DrSceneKeys keys;
    char dir[2048];
    double t_start = dr_time_now();
    if (dr_stage_begin(DR_STAGE_BAKE, argc, argv, &args, &scene, &keys, dir, sizeof dir, &done, &err) < 0)
        return fail(&err);
    if (done) return 0;
    int first, last;
    if (dr_stage_frame_range(&args, scene, &first, &last, &err) < 0) {
        dr_scene_destroy(&scene);
        return fail(&err);
    }
    int shot_first = first, shot_last = last;
    {
        int fr[2];
        dr_component_int2(dr_scene_section(scene, "shot"), "frames", fr);
        shot_first = fr[0];
        shot_last = fr[1];
    }
    if (args.verify) {
        dr_scene_destroy(&scene);
        return verify(dir, keys.bake, shot_first, shot_last, last, !args.quick);
    }
    if (args.frames_given && !args.resume && first != shot_first) {
        dr_error_set(&err, DR_ERR_INPUT, NULL, 0, 0,
                     "bake --frames %d-%d: a bake starts at the shot's first frame %d (or continues with --resume); "
                     "use --frames %d-%d", first, last, shot_first, shot_first, last);
        dr_scene_destroy(&scene);
        return fail(&err);
    }

    /* Everything that can be bad input is checked here, before anything is written. */
    DrWorld *world = NULL;
    DrWorldDesc wd;
    dr_world_desc_default(&wd);
    wd.cache_root = args.cache_root;
    DrStatus s = dr_world_create_desc(scene, &wd, &world, &err);
    char ckpt[4096], progress[4096], path[4096];
    snprintf(ckpt, sizeof ckpt, "%s/checkpoint.h5", dir);
    snprintf(progress, sizeof progress, "%s/progress.jsonl", dir);
    if (s == DR_OK && args.resume) {
        if (dr_io_exists(ckpt)) {
            s = dr_world_read_checkpoint(world, ckpt, keys.bake, &err);
            /* the frames before the checkpoint are not baked again: they must all be there and intact (and a
               MANIFEST that says they are is wrong) */
            int good = 0;
            DrStatus fs = s == DR_OK ? dr_stage_check_frames(dir, shot_first, dr_world_frame(world), keys.bake, true,
                                                             &good, &err)
                                     : DR_OK;
            if (fs == DR_ERR_INPUT) {
                dr_h5_drop_fix(&err);
                fs = dr_error_prefix(fs, &err,
                                     "bake --resume: the checkpoint continues after frame %d, but frame %d is not "
                                     "usable; bake without --resume to bake every frame again (pipeline.sh does it)",
                                     dr_world_frame(world), good + 1);
                DrError merr;
                if (dr_io_manifest_remove(dir, &merr) < 0) dr_error_print("bake", &merr);
            }
            if (s == DR_OK) s = fs;
            if (s == DR_OK) dr_log_info("resuming after frame %d from %s", dr_world_frame(world), ckpt);
        } else {
            dr_log_info("no checkpoint in %s: baking from the first frame", dir);
        }
    }
    if (s == DR_OK && dr_world_frame(world) >= last) {
        dr_log_info("nothing to bake: the checkpoint is already at frame %d", dr_world_frame(world));
    }
    if (s == DR_OK) s = dr_io_mkdirs(dir, &err);
    if (s == DR_OK) s = dr_io_manifest_remove(dir, &err); /* the folder is stale until this bake completes */
    if (s == DR_OK) {
        dr_io_remove_stale_tmp(dir);
        if (!args.resume || dr_world_frame(world) < shot_first) remove_previous_outputs(dir);
        else s = trim_progress(progress, dr_world_frame(world), &err);
    }
    if (s < 0) {
        dr_world_destroy(&world);
        dr_scene_destroy(&scene);
        return fail(&err);
    }

    int checkpoint_every = dr_component_int(dr_scene_section(scene, "solver"), "checkpoint_every");
    /* Frames and checkpoints are written by a thread of their own while the next frame is simulated. Two
       files pending (a frame and its checkpoint) bound the memory to one frame's state held twice; a
       frame that finishes before its predecessor's files are written waits for them. Nothing calls HDF5
       on this thread from here on (the checkpoint and the precompute caches were read above). */
    DrH5Writer *writer = NULL;
    if (!args.sync_writes && dr_h5_writer_create(2, &writer, &err) < 0) {
        dr_world_destroy(&world);
        dr_scene_destroy(&scene);
        return fail(&err);
    }
    install_stop_handlers();
    char wait[96];
    dr_thread_wait_describe(wait, sizeof wait);
    dr_log_info("baking '%s' frames %d-%d into %s (%d threads, %s, key %s)", dr_scene_path(scene),
                dr_world_frame(world) + 1, last, dir, dr_threads(), wait, keys.bake);
    if (dr_log_level() >= DR_LOG_DEBUG) json_decref(applied_defaults(scene, true));
    Totals tot = {0};
    tot.io_background = writer != NULL;
    double writer_seconds = 0.0; /* the writer's seconds at the previous progress line */
    DrProgress prog;
    dr_progress_begin(&prog, "bake", last - dr_world_frame(world));
    while (s >= 0 && dr_world_frame(world) < last) {
        DrFrameStats fs;
        s = dr_world_step_frame(world, &fs, &err);
        if (s < 0) break;
        double t_io = dr_time_now();
        FrameIo fio = {.background = writer != NULL};
        dr_stage_frame_path(dir, "frame", fs.frame, "h5", path, sizeof path);
        s = write_output(writer, world, &fs, keys.bake, path, &fio.wait, &err);
        if (s == DR_OK) tot.io_files++;
        /* submitted after the frame: the writer renames it into place after the frame's file */
        if (s == DR_OK && ((fs.frame - shot_first + 1) % checkpoint_every == 0 || fs.frame == last || stop_signal)) {
            s = write_output(writer, world, NULL, keys.bake, ckpt, &fio.wait, &err);
            if (s == DR_OK) tot.io_files++;
        }
        if (s < 0) break;
        fio.io = dr_time_now() - t_io;
        double io = fio.io;
        if (writer) {
            DrH5WriterStats ws;
            dr_h5_writer_stats(writer, &ws);
            fio.writer = ws.seconds - writer_seconds;
            writer_seconds = ws.seconds;
        }
        append_progress(progress, &fs, &fio);
        if (tot.frames == 0) tot.particles_first = fs.liquid.particles;
        tot.frames++;
        tot.particles_last = fs.liquid.particles;
        tot.p2g += fs.liquid.seconds_p2g;
        tot.pressure += fs.liquid.seconds_pressure;
        tot.g2p += fs.liquid.seconds_g2p;
        tot.advect += fs.liquid.seconds_advect;
        tot.other += fs.liquid.seconds_other;
        tot.io += io;
        tot.io_wait += fio.wait;
        tot.pressure_total += fs.liquid.pressure_iterations_total;
        if (fs.liquid.pressure_iterations_max > tot.pressure_max) tot.pressure_max = fs.liquid.pressure_iterations_max;
        if (fs.substeps > tot.substeps_max) tot.substeps_max = fs.substeps;
        tot.not_converged += fs.liquid.pressure_not_converged;
        if (fabs(fs.liquid.drift) > fabs(tot.volume_drift_max)) tot.volume_drift_max = fs.liquid.drift;
        tot.mpm |= fs.mpm.present;
        tot.mpm_particles = fs.mpm.particles;
        tot.mpm_newton += fs.mpm.newton_iterations;
        tot.mpm_cg += fs.mpm.cg_iterations;
        tot.mpm_not_converged += fs.mpm.not_converged;
        tot.mpm_transfer += fs.mpm.seconds_transfer;
        tot.mpm_solve += fs.mpm.seconds_solve;
        tot.hair |= fs.hair.present;
        tot.hair_vertices = fs.hair.vertices;
        tot.hair_cg += fs.hair.cg_iterations;
        tot.hair_not_converged += fs.hair.not_converged;
        tot.hair_seconds += fs.hair.seconds;
        tot.bem |= fs.bem.present;
        tot.bem_bodies = fs.bem.bodies;
        tot.bem_steps += fs.bem.steps;
        tot.bem_seconds += fs.bem.seconds_history + fs.bem.seconds_solve + fs.bem.seconds_correction +
                           fs.bem.seconds_trial + fs.bem.seconds_detect + fs.bem.seconds_assembly + fs.bem.seconds_pgs +
                           fs.bem.seconds_final;
        tot.bem_pgs_iterations += fs.bem.pgs_iterations;
        tot.bem_not_converged += fs.bem.not_converged;
        tot.bem_residual_max = fmax(tot.bem_residual_max, fs.bem.residual);
        tot.bem_seconds_trial += fs.bem.seconds_trial;
        tot.bem_seconds_detect += fs.bem.seconds_detect;
        tot.bem_seconds_assembly += fs.bem.seconds_assembly;
        tot.bem_seconds_pgs += fs.bem.seconds_pgs;
        tot.bem_seconds_final += fs.bem.seconds_final;
        tot.bem_max_displacement = fmax(tot.bem_max_displacement, fs.bem.max_displacement);
        char detail[560], mpm[96] = "", hair[96] = "", bem[96] = "", cloth[96] = "";
        if (fs.mpm.present)
            snprintf(mpm, sizeof mpm, " mpm %ld newton %ld cg %ld", fs.mpm.particles, fs.mpm.newton_iterations,
                     fs.mpm.cg_iterations);
        if (fs.hair.present)
            snprintf(hair, sizeof hair, " hair %ld cg %ld contacts %d+%d", fs.hair.vertices, fs.hair.cg_iterations,
                     fs.hair.collider_contacts, fs.hair.contacts);
        if (fs.bem.present)
            snprintf(bem, sizeof bem, " bem %d steps %ld max|u| %.3g m", fs.bem.bodies, fs.bem.steps,
                     fs.bem.max_displacement);
        if (fs.cloth.present)
            snprintf(cloth, sizeof cloth, " cloth %ld steps %d cg %ld contacts %d+%d", fs.cloth.vertices,
                     fs.cloth.substeps, fs.cloth.cg_iterations, fs.cloth.collider_contacts, fs.cloth.self_contacts);
        char cpl[64] = "";
        if (fs.coupling.steps > 0)
            snprintf(cpl, sizeof cpl, " couple %.1f it/step", (double)fs.coupling.iterations / fs.coupling.steps);
        snprintf(detail, sizeof detail, "frame %d substeps %d iters %d particles %ld cells %+.1f%%%s%s%s%s%s %.2fs",
                 fs.frame, fs.substeps, fs.liquid.pressure_iterations_max, fs.liquid.particles, 100.0 * fs.liquid.drift, mpm, hair,
                 cloth, cpl, bem, fs.seconds + io);
        dr_progress_step(&prog, detail);
        if (stop_signal && dr_world_frame(world) < last) break;
    }
    dr_progress_end(&prog);
    /* Every file handed to the writer is on disk (or its failure known) before report.json and the MANIFEST;
       after a failure of the simulation the frames before it and their checkpoint are still written. */
    if (writer) {
        double t0 = dr_time_now();
        DrError werr;
        dr_error_clear(&werr);
        DrStatus ws = dr_h5_writer_flush(writer, &werr);
        double waited = dr_time_now() - t0;
        tot.io += waited;
        tot.io_wait += waited;
        if (ws < 0 && s >= 0) {
            s = ws;
            err = werr;
        } else if (ws < 0 && strcmp(werr.message, err.message) != 0) {
            dr_error_print("bake", &werr); /* a second failure, after the one reported below */
        }
        DrH5WriterStats st;
        dr_h5_writer_stats(writer, &st);
        tot.io_writer = st.seconds;
        dr_h5_writer_destroy(&writer);
    }
    bool interrupted = s >= 0 && stop_signal && dr_world_frame(world) < last;
    double wall = dr_time_now() - t_start;
    DrError rerr;
    dr_error_clear(&rerr);
    char msg[sizeof err.message + 64] = "";
    if (s < 0) dr_error_format(&err, msg, sizeof msg);
    if (interrupted)
        snprintf(msg, sizeof msg, "stopped by signal %d after frame %d; the checkpoint holds it: continue with --resume",
                 (int)stop_signal, dr_world_frame(world));
    DrStatus rs = write_report(dir, s < 0 ? "failed" : interrupted ? "interrupted" : "ok", msg, scene, keys.bake, shot_first, last, &tot,
                               wall, &rerr);
    if (s >= 0 && rs < 0) {
        s = rs;
        err = rerr;
    }
    int fr[2];
    dr_component_int2(dr_scene_section(scene, "shot"), "frames", fr);
    if (s >= 0 && interrupted) {
        dr_world_destroy(&world);
        dr_scene_destroy(&scene);
        fprintf(stderr, "bake: %s\n", msg);
        return EXIT_INTERRUPTED;
    }
    if (s >= 0) {
        /* every frame from the first to the one the world is at is on disk, written now or checked on resume */
        int done = dr_world_frame(world);
        const char *inputs[1] = {path};
        snprintf(path, sizeof path, "frames %d-%d", fr[0], done);
        s = dr_io_manifest_write_frames(dir, "bake", keys.bake, dr_scene_path(scene), fr[0], done, inputs, 1, &err);
        if (s >= 0 && done < fr[1])
            dr_log_info("partial bake: frames %d-%d of %d-%d done; bake --resume continues it", fr[0], done, fr[0],
                        fr[1]);
    }
    dr_world_destroy(&world);
    dr_scene_destroy(&scene);
    if (s < 0) return fail(&err);
    char mpm[160] = "";
    if (tot.mpm)
        snprintf(mpm, sizeof mpm, ", %ld MPM particles (Newton iterations %ld, CG %ld%s)", tot.mpm_particles,
                 tot.mpm_newton, tot.mpm_cg, tot.mpm_not_converged ? ", some Newton solves hit their cap" : "");
    char hair[160] = "";
    if (tot.hair)
        snprintf(hair, sizeof hair, ", %ld hair vertices (CG iterations %ld%s)", tot.hair_vertices, tot.hair_cg,
                 tot.hair_not_converged ? ", some hair solves hit their cap" : "");
    char bem[160] = "";
    if (tot.bem)
        snprintf(bem, sizeof bem, ", %d BEM bod%s (%ld steps, %.1f s)", tot.bem_bodies, tot.bem_bodies == 1 ? "y" : "ies",
                 tot.bem_steps, tot.bem_seconds);
    char io[160];
    if (tot.io_background)
        snprintf(io, sizeof io, ", output %.1fs on the main thread + %.1fs in the background", tot.io, tot.io_writer);
    else
        snprintf(io, sizeof io, ", output %.1fs", tot.io);
    char rss[32];
    dr_format_bytes(dr_peak_rss_bytes(), rss, sizeof rss);
    fprintf(stderr, "bake: %d frames in %.1fs (%.2fs/frame, %d threads), %ld particles, pressure iterations max %d%s%s%s%s%s, "
            "peak RSS %s\n",
            tot.frames, wall, tot.frames ? wall / tot.frames : 0.0, dr_threads(), tot.particles_last, tot.pressure_max,
            tot.not_converged ? ", some pressure solves did not converge (see warnings)" : "", mpm, hair, bem, io, rss);
    return 0;
}
