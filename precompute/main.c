/* precompute: per-asset data that shots share, content-keyed under cache/. Computes only what the scene's
 * elements need and the cache does not already hold: today the boundary-element matrices of every bem_solid
 * element (cache/bem/<key>.h5). Every body's input is checked before anything is computed or written, so bad
 * input leaves the cache and the output folder as they were. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bem/bem.h"
#include "io/io.h"
#include "scene/scene.h"
#include "stage/stage.h"
#include "wet/wet.h"

static int fail(const DrError *err)
{
    dr_error_print("precompute", err);
    return dr_exit_code(err->status);
}

/* One bem_solid element, checked and keyed (dr_stage_load_bem_asset: the world reads the matrices under the same
 * key). */
typedef struct Body {
    const DrElement *e;
    DrBemAsset a;
    int first; /* index of the first body with the same key (itself when it is the first) */
} Body;

/* Prefixes "<element>.Mesh.file: " to a failure's message, so it names the element as well as the file. */
static DrStatus in_element(DrStatus s, const Body *b, DrError *err)
{
    if (dr_error_prefix(s, err, "%s.Mesh.file", b->e->name) < 0 && !err->file[0])
        snprintf(err->file, sizeof err->file, "%s", b->a.path);
    return s;
}

/* Loads, welds and checks the element's mesh, hashes its file and computes the cache key. */
static DrStatus prepare(const DrElement *e, Body *b, DrError *err)
{
    b->e = e;
    DR_TRY(dr_stage_load_bem_asset(e, &b->a, err));
    const DrBemAsset *a = &b->a;
    dr_log_info("bem: %s: %s: %d vertices, %d triangles (%d of %d vertices merged by welding within %.3g m)",
                e->name, a->path, a->mesh.nv, a->mesh.nt, a->welded, a->vertices_in_file, a->weld_tolerance);
    return DR_OK;
}

/* -0 prints as 0, as in the scene's canonical JSON. */
static double canon(double v) { return v == 0.0 ? 0.0 : v; }

/* The canonical JSON of what the key covers (keys sorted, numbers %.17g), recorded in the file as "inputs". */
static void inputs_json(const Body *b, char *buf, size_t size)
{
    const DrBemDesc *d = &b->a.desc;
    snprintf(buf, size,
             "{\"bem_version\":\"%s\",\"compression_ratio\":%.17g,\"cq_epsilon\":%.17g,\"density\":%.17g,"
             "\"dt\":%.17g,\"history_margin\":%.17g,\"mesh_hash\":\"%s\",\"near_factor\":%.17g,\"ordering\":\"%s\","
             "\"poisson\":%.17g,\"quad_levels\":%d,\"shear_modulus\":%.17g,\"singular_order\":%d,\"wavelet\":%s}",
             DR_BEM_VERSION, canon(d->compression_ratio), canon(d->cq_epsilon), canon(d->material.density),
             canon(d->dt), canon(d->history_margin), b->a.mesh_hash, canon(d->near_factor), dr_bem_ordering_name(d->ordering),
             canon(d->material.poisson), d->quad_levels, canon(d->material.shear_modulus), d->singular_order,
             d->wavelet ? "true" : "false");
}

/* Makes sure cache/bem/<key>.h5 holds the body's matrices: a trusted file is a hit, anything else is built and
 * written (atomically: a kill leaves at most a temporary file that no reader trusts). */
static DrStatus ensure_cached(const Body *body, const char *cache_root, bool *hit, DrError *err)
{
    const DrBemAsset *b = &body->a;
    const DrElement *e = body->e;
    DrBemMatrices *m = NULL;
    DrError rejected;
    DR_TRY(dr_bem_cache_read(cache_root, b->key, &m, hit, &rejected, err));
    if (!*hit && rejected.status < 0) {
        dr_h5_drop_fix(&rejected);
        char why[sizeof rejected.message + 64];
        dr_error_format(&rejected, why, sizeof why);
        dr_log_warn("bem: %s: %s; it will be recomputed", e->name, why);
    }
    if (*hit) {
        dr_log_info("bem: %s: cache hit %s (n_max %d)", e->name, b->key, m->n_max);
        dr_bem_matrices_destroy(&m);
        return DR_OK;
    }
    dr_log_info("bem: %s: computing %s (%d vertices, dt %.6g s, compression 1/%g)", e->name, b->key, b->mesh.nv,
                b->desc.dt, b->desc.compression_ratio);
    /* The Haar coefficients kept per row of a 3N × 3N matrix (bem.h: dr_bem_coefficients_per_row): the sphere under
       sudden pressure settles within 3 % of Lamé's solution with ~120 per row, 10 % with 60, 41 % with 15; the
       2,906-vertex bench keeps 270 at 32x. */
    double per_row = dr_bem_coefficients_per_row(b->mesh.nv, b->desc.compression_ratio);
    if (b->desc.compression_ratio > 1 && per_row < DR_BEM_MIN_COEFFICIENTS_PER_ROW)
        dr_log_warn("bem: %s: Compression.ratio %g keeps %.0f coefficients per row of this %d-vertex body; below ~100 "
                    "the response of the body is off by 10 %% or more: set %s.Compression.ratio to at most %.0f "
                    "(3N/100), or 1",
                    e->name, b->desc.compression_ratio, per_row, b->mesh.nv, e->name,
                    fmax(1.0, floor(3.0 * b->mesh.nv / DR_BEM_MIN_COEFFICIENTS_PER_ROW)));
    double t0 = dr_time_now();
    DR_TRY(dr_bem_matrices_build(&b->mesh, &b->desc, e->name, &m, err));
    double t_build = dr_time_now() - t0;
    /* Σ_k H_k annihilates rigid translations only for a complete history (BEM §4's margin of 2 steps leaves a
       few per cent, the runtime's error correction absorbs it); a large remainder means a visible drift. */
    if (m->stats.rigid_residual > 0.05)
        dr_log_warn("bem: %s: the %d-step history leaves %.1f %% of a rigid translation (|sum_k H_k m| / |H_0 m|); "
                    "raise BemSolver.history_margin (now %g) to reduce it: 6 more steps typically divide it by 10",
                    e->name, m->n_max, 100 * m->stats.rigid_residual, b->desc.history_margin);
    char inputs[2048];
    inputs_json(body, inputs, sizeof inputs);
    DrStatus s = dr_bem_cache_write(cache_root, b->key, inputs, b->mesh_hash, m, err);
    if (s == DR_OK) {
        char path[DR_IO_PATH_MAX];
        dr_io_precache_path(cache_root, "bem", b->key, path, sizeof path);
        dr_log_info("bem: %s: wrote %s (n_max %d, %.1f MB kept of %.1f MB dense; built in %.1f s, written in %.1f s)",
                    e->name, path, m->n_max, (double)m->stats.bytes_compressed / 1e6,
                    (double)m->stats.bytes_dense / 1e6, t_build, dr_time_now() - t0 - t_build);
    }
    dr_bem_matrices_destroy(&m);
    return s;
}

/* Makes sure cache/cohesion/<key>.h5 holds table k of the wet hair (stage.h dr_stage_wet_settings). */
static DrStatus ensure_table(const DrCohesionDesc *d, const char *cache_root, char key[33], bool *hit, DrError *err)
{
    dr_cohesion_key(d, key);
    const char *what = d->shape == DR_COHESION_CYLINDERS ? "strand-strand" : "strand-solid";
    DrCohesionTable *t = NULL;
    DrError lerr;
    *hit = dr_cohesion_load(cache_root, d, &t, &lerr) == DR_OK;
    if (*hit) {
        dr_log_info("cohesion: %s table cache hit %s", what, key);
        dr_cohesion_destroy(&t);
        return DR_OK;
    }
    char existing[DR_IO_PATH_MAX];
    dr_io_precache_path(cache_root, "cohesion", key, existing, sizeof existing);
    if (dr_io_exists(existing)) dr_log_warn("%s; building it again", lerr.message);
    double t0 = dr_time_now();
    DR_TRY(dr_cohesion_build(d, &t, err));
    double t_build = dr_time_now() - t0;
    char inputs[DR_COHESION_JSON_MAX];
    dr_cohesion_inputs_json(d, inputs);
    DrH5 *h = NULL;
    DrStatus s = dr_io_precache_create(cache_root, "cohesion", key, inputs, NULL, &h, err);
    if (s == DR_OK) s = dr_cohesion_write(t, h, err);
    if (s == DR_OK) s = dr_h5_commit(&h, err);
    else dr_h5_close(&h);
    dr_cohesion_destroy(&t);
    if (s == DR_OK) {
        char path[DR_IO_PATH_MAX];
        dr_io_precache_path(cache_root, "cohesion", key, path, sizeof path);
        dr_log_info("cohesion: %s table %d x %d built in %.2f s, wrote %s", what, d->resolution, d->resolution,
                    t_build, path);
    }
    return s;
}

static void free_bodies(Body *bodies, int n)
{
    for (int i = 0; i < n; i++) dr_bem_asset_free(&bodies[i].a);
    free(bodies);
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
    if (dr_stage_begin(DR_STAGE_PRECOMPUTE, argc, argv, &args, &scene, &keys, dir, sizeof dir, &done, &err) < 0)
        return fail(&err);
    if (done) return 0;
    double t0 = dr_time_now();

    /* 1. every bem_solid element checked and keyed before anything is computed or written */
    int nbodies = dr_scene_count_kind(scene, DR_ELEMENT_BEM_SOLID);
    Body *bodies = NULL;
    DrStatus s = dr_calloc((size_t)nbodies + 1, sizeof *bodies, &bodies, &err);
    int nb = 0;
    for (int i = 0; s == DR_OK && i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_BEM_SOLID) continue;
        Body *b = &bodies[nb++];
        s = prepare(e, b, &err);
        b->first = nb - 1;
        for (int j = 0; s == DR_OK && j < nb - 1; j++)
            if (strcmp(bodies[j].a.key, b->a.key) == 0) {
                b->first = j;
                break;
            }
    }
    DrStageWet wet;
    if (s == DR_OK) s = dr_stage_wet_settings(scene, &wet, &err);
    if (s == DR_OK && nbodies == 0 && !wet.wet)
        fprintf(stderr, "precompute: nothing to do: no element in '%s' needs precomputed data (%d elements: "
                        "liquid, mpm_solid, dry hair and collider elements use none)\n",
                dr_scene_path(scene), dr_scene_element_count(scene));

    /* 2. the stage is stale until it finishes; temporary files of killed runs go */
    if (s == DR_OK) s = dr_io_mkdirs(dir, &err);
    if (s == DR_OK) s = dr_io_manifest_remove(dir, &err);
    if (s == DR_OK && nbodies > 0) {
        char bem_dir[DR_IO_PATH_MAX];
        snprintf(bem_dir, sizeof bem_dir, "%s/bem", args.cache_root);
        dr_io_remove_stale_tmp(bem_dir);
    }

    /* 3. each distinct key once: from the cache, or built and written */
    int hits = 0, computed = 0, distinct = 0;
    for (int i = 0; s == DR_OK && i < nb; i++) {
        const Body *b = &bodies[i];
        if (b->first != i) {
            dr_log_info("bem: %s: same matrices as %s (%s)", b->e->name, bodies[b->first].e->name, b->a.key);
            continue;
        }
        distinct++;
        bool hit = false;
        s = ensure_cached(b, args.cache_root, &hit, &err);
        if (s == DR_OK && hit) hits++;
        else if (s == DR_OK) computed++;
        else if (s == DR_ERR_INPUT)
            s = in_element(s, b, &err); /* a mesh the build refuses (degenerate quadrature, singular H₀) */
    }
    char rss[32];
    dr_format_bytes(dr_peak_rss_bytes(), rss, sizeof rss);
    if (s == DR_OK && nbodies > 0)
        fprintf(stderr, "precompute: %d bem bod%s, %d hit%s, %d computed, %.1f s, peak RSS %s\n", nbodies,
                nbodies == 1 ? "y" : "ies", hits, hits == 1 ? "" : "s", computed, dr_time_now() - t0, rss);
    /* the wet hair's two cohesion tables */
    char table_key[2][33] = {"", ""};
    if (s == DR_OK && wet.wet) {
        char coh_dir[DR_IO_PATH_MAX];
        snprintf(coh_dir, sizeof coh_dir, "%s/cohesion", args.cache_root);
        dr_io_remove_stale_tmp(coh_dir);
        int thits = 0;
        double tt = dr_time_now();
        for (int k = 0; s == DR_OK && k < 2; k++) {
            bool hit = false;
            s = ensure_table(&wet.tables[k], args.cache_root, table_key[k], &hit, &err);
            if (s == DR_OK && hit) thits++;
            else if (s != DR_OK) s = dr_error_prefix(s, &err, "%s.Cohesion", wet.element->name);
        }
        if (s == DR_OK)
            fprintf(stderr, "precompute: %d wet hair element%s, 2 cohesion tables, %d hit%s, %d computed, %.1f s\n",
                    wet.elements, wet.elements == 1 ? "" : "s", thits, thits == 1 ? "" : "s", 2 - thits,
                    dr_time_now() - tt);
    }

    /* 4. the MANIFEST last: one input line per body with its key */
    if (s == DR_OK) {
        const char **inputs = NULL;
        char *lines = NULL;
        const size_t line_max = DR_SCENE_NAME_MAX + 64;
        int nt = wet.wet ? 2 : 0;
        s = dr_calloc((size_t)nb + nt + 1, sizeof *inputs, &inputs, &err);
        if (s == DR_OK) s = dr_calloc((size_t)nb + nt + 1, line_max, &lines, &err);
        if (s == DR_OK) {
            snprintf(lines, line_max, "cache entries %d", distinct);
            inputs[0] = lines;
            for (int i = 0; i < nb; i++) {
                char *line = lines + (size_t)(i + 1) * line_max;
                snprintf(line, line_max, "bem %s %s", bodies[i].e->name, bodies[i].a.key);
                inputs[i + 1] = line;
            }
            for (int k = 0; k < nt; k++) { /* "cohesion <table> <key>": pipeline.sh checks the file is there */
                char *line = lines + (size_t)(nb + 1 + k) * line_max;
                snprintf(line, line_max, "cohesion %s %s", k == 0 ? "cylinders" : "plane", table_key[k]);
                inputs[nb + 1 + k] = line;
            }
            s = dr_io_manifest_write(dir, "precompute", keys.precompute, dr_scene_path(scene), inputs, nb + nt + 1,
                                     &err);
        }
        free(lines);
        free(inputs);
    }
    free_bodies(bodies, nb);
    dr_scene_destroy(&scene);
    if (s < 0) return fail(&err);
    return 0;
}
