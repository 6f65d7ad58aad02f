/* What the four stage executables share: their command line (arguments, --help, --version, the cache keys they
 * print), their output folders and frame file names, loading a collider element's mesh in its scene pose (the
 * mesh stage draws colliders; the world builds their SDFs), and a bem_solid element as the BEM takes it (precompute
 * builds its matrices; the world reads them). Nothing here simulates. */
#ifndef DR_STAGE_H
#define DR_STAGE_H

#include "core/core.h"
#include "io/io.h"
#include "scene/scene.h"

typedef enum DrStageId { DR_STAGE_PRECOMPUTE, DR_STAGE_BAKE, DR_STAGE_MESH, DR_STAGE_RENDER } DrStageId;

typedef struct DrStageArgs {
    DrStageId stage;
    const char *scene_path;  /* NULL when only --help/--version/--list-components */
    int frame_first, frame_last; /* --frames A-B; 0,0 when not given */
    bool frames_given;
    bool resume;             /* bake --resume */
    bool verify;             /* bake --verify: check the frames and the checkpoint, write nothing */
    bool quick;              /* bake --verify --quick: the frames' files, numbers and keys, not their data */
    bool sync_writes;        /* bake --sync-writes: frames and checkpoints written on the main thread */
    bool finish;             /* mesh/render --finish: seal frame ranges that ran separately */
    bool plots_only, no_plots; /* render --plots / --no-plots */
    int threads;             /* -j N; 0 = all cores */
    const char *out_root;    /* --out DIR, else $DRENCH_OUT, else "out" */
    const char *cache_root;  /* --cache DIR, else $DRENCH_CACHE, else "cache" */
    bool preview;            /* render --preview: the scene's initial state to out/<shot>/preview.png */
    bool print_key, print_out_dir, print_frames, list_components, markdown, quiet, verbose;
} DrStageArgs;

/* Parses the common options. Returns DR_OK, or DR_ERR_INPUT with a usage message. --help and --version are
 * handled here: they print and set *done (the caller exits 0). */
DR_NODISCARD DrStatus dr_stage_parse_args(DrStageId stage, int argc, char **argv, DrStageArgs *args, bool *done,
                                          DrError *err);
/* Everything a stage does before its own work: parses the arguments, loads the scene and its keys, fills
 * the stage's output folder, and answers --help, --version, --list-components, --print-key and
 * --print-out-dir (then *done is set: the caller exits 0). On failure *scene is NULL and err says why. */
DR_NODISCARD DrStatus dr_stage_begin(DrStageId stage, int argc, char **argv, DrStageArgs *args, DrScene **scene,
                                     DrSceneKeys *keys, char *dir, size_t dir_size, bool *done, DrError *err);
const char *dr_stage_name(DrStageId stage);
/* <out_root>/<shot name>/<stage> */
void dr_stage_out_dir(const DrStageArgs *args, const DrScene *scene, DrStageId stage, char *buf, size_t size);
/* Resolves --frames against the shot (DR_ERR_INPUT when out of the shot's range or out of order). */
DR_NODISCARD DrStatus dr_stage_frame_range(const DrStageArgs *args, const DrScene *scene, int *first, int *last,
                                           DrError *err);
/* Frame file name inside a stage folder: "<prefix>.NNNN.<ext>" (4 digits, more if needed). */
void dr_stage_frame_path(const char *dir, const char *prefix, int frame, const char *ext, char *buf, size_t size);


/* Loads a collider element's Mesh.file and applies its Transform component (scale, then rotation, then
 * translation): the collider in its scene pose. Errors name the element, the field and the file. */
DR_NODISCARD DrStatus dr_stage_load_collider_mesh(const DrElement *e, DrTriMesh *mesh, DrError *err);
/* Element e's Transform component without its scale (R from the XYZ Euler angles, t the translation), and the
 * scale: a point p of its mesh is placed at R·(scale·p) + t. */
DrXform dr_stage_element_transform(const DrElement *e, double *scale);
/* Loads the mesh file `path` (referenced by element e's `field`, which errors name) and applies e's Transform. */
DR_NODISCARD DrStatus dr_stage_load_posed_mesh(const DrElement *e, const char *path, const char *field,
                                               DrTriMesh *mesh, DrError *err);
/* Element e's Motion keys as the solvers take them: rows of 7 (t in s, translation in m, XYZ Euler angles in rad),
 * the scene's frame numbers turned into times on the shot's clock (frame first_frame − 1 is t = 0; fractional
 * frames keep their exact time). *keys is allocated (at least one row, so never NULL on success; free it) and
 * *nkeys is 0 when e has no Motion. */
DR_NODISCARD DrStatus dr_stage_motion_keys(const DrElement *e, int first_frame, double fps, double **keys, int *nkeys,
                                           DrError *err);

/* The strands of hair element e in its scene pose: grown (dr_groom_grow) from its Groom.scalp posed by its Transform
 * with the Groom's growth fields, or read from Groom.curves (dr_groom_read_obj) and moved by its Transform. Errors
 * start with "<element>.Groom.scalp: " or "<element>.Groom.curves: "; *g is empty then. Free with dr_groom_free. */
typedef struct DrGroom DrGroom;
DR_NODISCARD DrStatus dr_stage_load_groom(const DrElement *e, DrGroom *g, DrError *err);
/* The radius at every vertex of `count` strands x (3 per vertex, strand s = vertices offsets[s] .. offsets[s+1]-1,
 * root first) into out (offsets[count] values, metres), as the rod set tapers them (hair.h, RodMaterial.tip_radius):
 * strand_radius[s] at the root, falling linearly in arc length to tip_radius at the tip; tip_radius 0 (untapered)
 * gives strand_radius[s] at every vertex exactly. The rods measure the arc length on their rest shape, these on x:
 * on a baked frame's strands the two differ by the strands' stretch (inextensible rods: a small fraction of it). */
void dr_stage_vertex_radii(const double *x, const int *offsets, int count, const double *strand_radius,
                           double tip_radius, double *out);

/* A bem_solid element as the boundary element method takes it (DrBemAsset, bem/bem.h): its Mesh.file through
 * dr_bem_asset_load, in the file's own coordinates (Transform does not apply: it poses the body in a shot), and its
 * build parameters from LinearElastic, Compression and BemSolver (what the scene does not set keeps
 * dr_bem_desc_default). BemSolver.frame_update and error_correction are runtime choices and enter neither desc nor
 * key. Fails as dr_bem_asset_load, the message starting with "<element>.Mesh.file: "; *out holds nothing to free
 * then. */
typedef struct DrBemAsset DrBemAsset;

/* ---- the MANIFEST of a frame stage (stage_manifest.c) ------------------------------------------------------
 * mesh and render record in their MANIFEST the frames whose outputs are complete ("frames A-B", io.h), so that
 * a run over part of the shot is kept: `--frames 1-10` twice does the work once, and `--frames 11-20` after it
 * leaves the folder complete for 1-20. A farm's ranges, run apart, may under-claim (each keeps what it saw when
 * it started); `--finish` then claims the whole shot after checking every file. */
typedef struct DrStageFrames {
    char dir[2048];
    DrStageId stage;
    char key[33];
    const DrScene *scene;
    int first, last;              /* this run's frames */
    int shot_first, shot_last;
    bool had;                     /* an earlier MANIFEST under the same key */
    int had_first, had_last;      /* and its frames */
} DrStageFrames;
/* Before a run over first..last writes anything: reads the folder's MANIFEST. When the run `rewrites` those
 * frames' outputs, under the same key the MANIFEST's frames before `first` stay claimed (it is rewritten to them,
 * with `inputs`), otherwise it is removed, so a run that fails leaves no claim on the frames it was rewriting; a
 * run that only checks them (--finish) leaves it alone. DR_ERR_IO naming the MANIFEST on failure. */
DR_NODISCARD DrStatus dr_stage_frames_begin(const char *dir, DrStageId stage, const char *key, const DrScene *scene,
                                            int first, int last, bool rewrites, const char *const *inputs,
                                            int ninputs, DrStageFrames *run, DrError *err);
/* The frames the MANIFEST claims once this run has written its own: them, joined with the earlier range when the
 * two touch or overlap (the MANIFEST holds one range: an earlier one apart from this run's is dropped). */
void dr_stage_frames_done(const DrStageFrames *run, int *done_first, int *done_last);
/* After the run wrote every output of its frames (and, when they complete the shot, what the whole shot gets): the
 * MANIFEST claims dr_stage_frames_done's range. DR_ERR_IO naming it on failure. */
DR_NODISCARD DrStatus dr_stage_frames_end(const DrStageFrames *run, const char *const *inputs, int ninputs,
                                          DrError *err);
/* True when done_first..done_last covers the shot. */
bool dr_stage_frames_whole(const DrStageFrames *run, int done_first, int done_last);

/* ---- checks before anything is written (stage_check.c) ---------------------------------------------------- */

/* Loads every asset the scene's elements reference as the world loads them and checks what the world would
 * refuse, so that a scene fails at once (and --print-key fails) rather than after a stage has written something:
 * collider meshes and MPM shape meshes must load and be closed, bem_solid meshes pass dr_stage_load_bem_asset,
 * liquid source meshes, hair scalps and hair curves must load. Errors (DR_ERR_INPUT) name the element, the field
 * and the file. dr_stage_begin calls it for every stage. */
DR_NODISCARD DrStatus dr_stage_check_assets(const DrScene *scene, DrError *err);

/* Frame caches as later stages trust them: <bake_dir>/frame.NNNN.h5 exists, opens, holds `frame` (root attribute
 * frame: a file copied over another frame's is refused), was baked under bake_key (root attribute scene_key) and
 * every dataset matches its checksum (dr_h5_verify). DR_ERR_INPUT naming the file and what is wrong (the caller
 * says which stage to rerun); DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_stage_check_frame(const char *bake_dir, int frame, const char *bake_key, DrError *err);
/* Checks frames first..last (in parallel where HDF5 allows threads): *good_through is the last frame of the
 * unbroken run of good frames from `first` (first − 1 when frame `first` is bad). DR_OK when all are good, else
 * the first bad frame's failure as DR_ERR_INPUT (DR_ERR_NOMEM kept). Without `data`, the datasets' checksums
 * are left out (the file, its frame and its key only: a few milliseconds a frame instead of one read of it). */
DR_NODISCARD DrStatus dr_stage_check_frames(const char *bake_dir, int first, int last, const char *bake_key,
                                            bool data, int *good_through, DrError *err);
/* The bake's checkpoint at `path` as bake --resume would take it: written under bake_key, after a frame in
 * first−1..last (the shot's frames), every dataset matching its checksum and every number finite. DR_OK with
 * *frame the frame it follows; else DR_ERR_INPUT saying why (a missing file included) and *frame = first − 1;
 * DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_stage_check_checkpoint(const char *path, const char *bake_key, int first, int last,
                                                int *frame, DrError *err);
DR_NODISCARD DrStatus dr_stage_load_bem_asset(const DrElement *e, DrBemAsset *out, DrError *err);

/* The wet hair of a scene (src/wet): the settings every wet hair element shares (scene.c makes them agree), read from
 * the first one, with density and viscosity from Wetting.liquid's LiquidMaterial when it names one; and the two cohesion
 * tables (two cylinders, cylinder–plane) precompute builds for them, covering bridges of up to two films at
 * Film.max_ratio. wet is false (and nothing else set) when no hair element has a Wetting component. */
#include "wet/wet.h"
typedef struct DrStageWet {
    bool wet;
    int elements;                 /* wet hair elements */
    const DrElement *element;     /* the first (its settings are everyone's) */
    DrFilmDesc film;              /* gravity left at its default: the world sets the shot's */
    DrBridgeDesc bridges;
    DrCohesionDesc tables[2];     /* [0] two cylinders, [1] cylinder–plane */
    bool capture, dripping;       /* Capture.enabled, Dripping.enabled (they act only beside a liquid) */
    DrCaptureDesc capture_desc;
    DrDripDesc drip_desc;
} DrStageWet;
DR_NODISCARD DrStatus dr_stage_wet_settings(const DrScene *scene, DrStageWet *out, DrError *err);

#endif
