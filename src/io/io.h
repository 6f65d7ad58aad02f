/* drench io: asset meshes through assimp, OBJ writing, atomic file writes, stage manifests,
 * HDF5 caches (frames, checkpoints, precompute) and the content-addressed precompute cache.
 *
 * Atomic writes (DESIGN §4): every file is written to "NAME.tmp.<pid>", flushed to disk and renamed
 * into place, so a crash or a kill never leaves a truncated file under NAME. A killed stage may leave
 * "*.tmp.<pid>" files behind; dr_io_remove_stale_tmp clears those whose process is gone.
 *
 * Errors: a file the user can fix (missing asset, corrupt mesh, missing dataset) is DR_ERR_INPUT;
 * a file that cannot be written or read back (disk full, permissions) is DR_ERR_IO. Either way
 * err->file names the file and err->message what happened and what would fix it.
 *
 * Thread safety: the file functions are safe to call from several threads on different paths.
 * HDF5 (1.10, built thread-safe behind one global lock) is called from one thread at a time: a
 * DrH5 handle belongs to one thread. A deferred handle makes no HDF5 call until it is committed, so
 * the main thread can record a file while a DrH5Writer's thread writes earlier ones. */
#ifndef DR_IO_H
#define DR_IO_H

#include "core/core.h"

/* Buffer size that holds any path this module builds from a path of up to 4096 bytes. */
#define DR_IO_PATH_MAX 4224

/* ---- assets --------------------------------------------------------------------------------- */

/* Loads OBJ, PLY, STL (anything assimp reads) into one triangle mesh `out` (caller frees with
 * dr_trimesh_free). All meshes of the file are merged with the world transforms of the node
 * hierarchy applied, polygons are triangulated, and vertices at bit-identical positions are joined
 * into one (across meshes and across per-face normals or texture coordinates as well), so a closed
 * surface comes out closed by index. Triangles that become degenerate by the joining (two equal
 * corners) and primitives that are not triangles (points, lines) are dropped; unreferenced vertices
 * are removed. Vertex order is the order of first use by the triangles. out->n holds per-vertex unit
 * normals when the file has normals (the normalised sum of the file normals joined into the vertex;
 * where those cancel or are zero, the normalised area-weighted sum of the adjacent face normals, and
 * (0,0,0) only where even those cancel, as on a double-sided sheet), NULL otherwise; mesh->uv holds
 * the file's first set of texture coordinates per triangle corner when every mesh of the file has one (a
 * UV seam keeps the surface welded), NULL otherwise.
 * Units: the file's coordinates are taken as metres. Assimp (as packaged) keeps coordinates in single
 * precision, so they come back rounded to float (relative 6e-8).
 * Errors (DR_ERR_INPUT, err->file = path, *out left zeroed): file missing or unreadable; assimp failed
 * (its message is included); a text OBJ holding binary bytes; no triangles; a non-finite vertex.
 * Assimp's own logging is never enabled, so nothing is printed on stdout or stderr. */
DR_NODISCARD DrStatus dr_io_load_mesh(const char *path, DrTriMesh *out, DrError *err);

/* Writes `mesh` as an OBJ file atomically: optional header comment lines (each line of `comment`,
 * split at '\n', prefixed by "# "; NULL for none), then "v x y z" lines, "vn x y z" lines when
 * mesh->n is non-NULL, "vt u v" lines (one per triangle corner, in triangle order) when mesh->uv is, and
 * "f a b c" (or "f a//a …" with normals, "f a/t …" with texture coordinates, "f a/t/a …" with both) lines with
 * 1-based indices, counter-clockwise as stored. Numbers are printed with %.9g (about 1e-9 relative). An empty mesh
 * gives a file with only the comment. A non-finite vertex or normal is DR_ERR_RUNTIME and nothing is
 * written; a write failure is DR_ERR_IO naming the file, and neither path is left behind. */
DR_NODISCARD DrStatus dr_io_write_obj(const char *path, const DrTriMesh *mesh, const char *comment,
                                      DrError *err);

/* ---- files ------------------------------------------------------------------------------------ */

/* Writes "<final_path>.tmp.<pid>" into buf; asserts that it fits (size >= strlen(final_path) + 32
 * always does). */
void dr_io_tmp_path(const char *final_path, char *buf, size_t size);
/* Makes a finished temporary file durable and visible: fsync(tmp), rename(tmp, final), fsync of the
 * directory holding final. On failure returns DR_ERR_IO naming the file and removes tmp. */
DR_NODISCARD DrStatus dr_io_commit(const char *tmp_path, const char *final_path, DrError *err);
/* Writes `text` (without its NUL) to path through a temporary file and dr_io_commit. The directory
 * must exist. DR_ERR_IO naming the file on failure; nothing is left behind. */
DR_NODISCARD DrStatus dr_io_write_text_atomic(const char *path, const char *text, DrError *err);
/* mkdir -p: creates dir and its missing parents (mode 0777 & ~umask). An existing directory is fine;
 * an existing non-directory on the way or a failed mkdir is DR_ERR_IO naming it. */
DR_NODISCARD DrStatus dr_io_mkdirs(const char *dir, DrError *err);
/* Reads a whole file into *out (malloc'd, NUL-terminated; caller frees). A missing or unreadable
 * file is DR_ERR_INPUT, a read error DR_ERR_IO, both naming the file; *out is NULL on failure. */
DR_NODISCARD DrStatus dr_io_read_text(const char *path, char **out, DrError *err);
/* Removes the regular files in dir named "*.tmp.<pid>" whose pid is not a running process (left by
 * a killed stage). Files of running processes (including this one) are kept. Best effort: a missing
 * dir or a file that cannot be removed is skipped silently (logged at debug level). */
void dr_io_remove_stale_tmp(const char *dir);
/* True when path exists (any file type). */
bool dr_io_exists(const char *path);

/* ---- manifests ----------------------------------------------------------------------------------
 * <dir>/MANIFEST is text, one field a line: "key <hex>", "stage <name>", "time <ISO 8601 UTC>",
 * "drench_version <v>", "scene <path>", for a stage that works frame by frame "frames <A>-<B>" (the frames
 * whose outputs the folder holds complete: the whole shot, or the part a run with --frames made), then one
 * "input <...>" line per caller-given input. */

/* Creates dir if needed and writes <dir>/MANIFEST atomically. key_hex is 1..32 hex digits; an input
 * or name holding a newline is DR_ERR_INPUT; write failures DR_ERR_IO. */
DR_NODISCARD DrStatus dr_io_manifest_write(const char *dir, const char *stage, const char *key_hex,
                                           const char *scene_path, const char *const *inputs, int ninputs,
                                           DrError *err);
/* As dr_io_manifest_write, with the line "frames <first>-<last>" (none when first > last). */
DR_NODISCARD DrStatus dr_io_manifest_write_frames(const char *dir, const char *stage, const char *key_hex,
                                                  const char *scene_path, int first, int last,
                                                  const char *const *inputs, int ninputs, DrError *err);
/* <dir>/MANIFEST as read back: found with its key, and has_frames with the range of its "frames" line. A missing,
 * unreadable or malformed manifest (a key that is not 1..32 hex digits, a frames line that is not A-B with A <= B)
 * is not an error: found = false, as for dr_io_manifest_read_key. */
typedef struct DrManifest {
    bool found;
    char key[33];
    bool has_frames;
    int first, last;
} DrManifest;
DR_NODISCARD DrStatus dr_io_manifest_read(const char *dir, DrManifest *out, DrError *err);
/* Reads the key of <dir>/MANIFEST into key_out (NUL-terminated, at most 32 hex digits) and sets
 * *found = true. A missing, unreadable or malformed manifest is not an error: *found = false,
 * key_out = "" and DR_OK (the stage is then simply stale). */
DR_NODISCARD DrStatus dr_io_manifest_read_key(const char *dir, char key_out[33], bool *found, DrError *err);
/* Removes <dir>/MANIFEST (before a stage starts rewriting its outputs); no error when absent,
 * DR_ERR_IO naming it when it exists and cannot be removed. */
DR_NODISCARD DrStatus dr_io_manifest_remove(const char *dir, DrError *err);

/* ---- HDF5 ---------------------------------------------------------------------------------------
 * A DrH5 is one open HDF5 file, either being written (dr_h5_create) or read (dr_h5_open). Paths are
 * absolute HDF5 paths like "/water/position"; "/" is the root group. HDF5's own error printing is
 * turned off; its failures become DrError messages naming the file and the object. Strings are stored
 * as fixed-length, NUL-terminated UTF-8 string attributes (h5dump shows them as text); the readers
 * also accept variable-length strings written by other tools.
 *
 * Checksums. Every dataset carries a string attribute DR_H5_CHECKSUM_ATTR ("xxh3"): the XXH3-128 hash (32 hex
 * digits, dr_hash_bytes) of its elements' bytes in file order (little-endian; compressed datasets: the bytes
 * before compression), written by the same call that writes the data, so every cache (frames, checkpoints,
 * precompute) has them. Every dataset reader verifies it: a missing checksum (a file of an older drench or of
 * another program), one that does not match (a damaged file: a flipped bit, an edited value) and a dataset HDF5
 * cannot read are DR_ERR_INPUT naming file and dataset, and say to delete the file and rerun the stage that
 * writes it (callers name the stage). Equal data gives equal checksums, so files stay bit-identical between runs. */
#define DR_H5_CHECKSUM_ATTR "xxh3"
/* The advice those messages end with; a caller that says itself which stage to rerun drops it first. */
#define DR_H5_DAMAGED_FIX "delete it and rerun the stage that writes it"
void dr_h5_drop_fix(DrError *err);
typedef struct DrH5 DrH5;

/* Creates "<final_path>.tmp.<pid>" for writing; nothing appears at final_path until dr_h5_commit.
 * The HDF5 file itself is built in memory (HDF5's core driver, no backing store) and written to the
 * temporary file by dr_h5_commit, so HDF5 never writes to disk: a disk that fills up is this module's
 * DR_ERR_IO wherever it strikes, never a half-closed HDF5 file (whose cleanup at exit crashed). Memory:
 * the file's size while it is open, twice that while it is committed. DR_ERR_IO naming the file when
 * the temporary file cannot be created. */
DR_NODISCARD DrStatus dr_h5_create(const char *final_path, DrH5 **out, DrError *err);
/* A deferred write handle for final_path: it takes the same dataset and attribute writers as one of
 * dr_h5_create but makes no HDF5 call and touches no file. Each call is checked as far as it can be
 * without the file (writable handle, sizes, a dataset path recorded twice is DR_ERR_INPUT) and
 * recorded with a copy of its data, so the caller may change or free its arrays on return (memory:
 * about the size of the data, until committed). dr_h5_commit replays the calls in their order on a
 * handle of dr_h5_create and commits it, on whatever thread calls it (dr_h5_writer_submit: the
 * writer's): the file is byte-identical to one written directly with the same calls. Failures of the
 * file itself (cannot create, disk full) come from dr_h5_commit as from a direct handle, naming the
 * file, with the temporary file removed. dr_h5_close drops the recording. The readers, dr_h5_has and
 * dr_h5_list must not be called on it (asserted). DR_ERR_IO when the path is too long. */
DR_NODISCARD DrStatus dr_h5_create_deferred(const char *final_path, DrH5 **out, DrError *err);
/* True for a handle of dr_h5_create_deferred. */
bool dr_h5_deferred(const DrH5 *h);
/* Opens an existing file read-only. DR_ERR_INPUT naming it when missing or not HDF5. */
DR_NODISCARD DrStatus dr_h5_open(const char *path, DrH5 **out, DrError *err);

/* Dataset writers (write handles only). Intermediate groups are created; an existing object at
 * `path` is DR_ERR_INPUT. rank 1..4, dims[rank], row-major data of prod(dims) elements (data may be
 * NULL when that product is 0: zero-sized dimensions are fine, e.g. an element with 0 particles).
 * compress = true: as the handle's DrH5Compress says (dr_h5_set_compress; by default chunked, chunks
 * of about 256 KiB along the first dimension, with shuffle + deflate level 1); false: contiguous
 * (checkpoints, where speed matters more than size). A dataset without elements is contiguous either
 * way. Readers see no difference. No object timestamps are stored, so equal data gives equal datasets. `units` (NULL = none)
 * is stored as string attribute "units" on the dataset. DR_ERR_IO naming file and dataset on failure. */
DR_NODISCARD DrStatus dr_h5_write_f64(DrH5 *h, const char *path, int rank, const uint64_t *dims,
                                      const double *data, const char *units, bool compress, DrError *err);
DR_NODISCARD DrStatus dr_h5_write_i64(DrH5 *h, const char *path, int rank, const uint64_t *dims,
                                      const int64_t *data, const char *units, bool compress, DrError *err);
DR_NODISCARD DrStatus dr_h5_write_u64(DrH5 *h, const char *path, int rank, const uint64_t *dims,
                                      const uint64_t *data, bool compress, DrError *err);
/* Signed 4-byte integers: indices stored at half the size of i64 (sparse matrix columns, triangles). */
DR_NODISCARD DrStatus dr_h5_write_i32(DrH5 *h, const char *path, int rank, const uint64_t *dims,
                                      const int32_t *data, const char *units, bool compress, DrError *err);

/* One value (dims {1}) or one vector (dims {3}) at <group>/<name>, with its units: the diagnostics of caches. */
DR_NODISCARD DrStatus dr_h5_write_scalar(DrH5 *h, const char *group, const char *name, double v, const char *units,
                                         DrError *err);
DR_NODISCARD DrStatus dr_h5_write_vec3(DrH5 *h, const char *group, const char *name, DrVec3 v, const char *units,
                                       DrError *err);
/* A particle set (DESIGN §4): /<name>/position (n×3, m), velocity (n×3, m/s) and affine (n×3×3, 1/s). */
DR_NODISCARD DrStatus dr_h5_write_particles(DrH5 *h, const char *name, long n, const double *x, const double *v,
                                            const double *affine, bool compress, DrError *err);

/* What compress = true means for the datasets written to a write handle after the call. */
typedef enum DrH5Compress {
    DR_H5_COMPRESS_ALL,      /* [default] chunked, shuffle + deflate level 1 (caches written once, read often) */
    DR_H5_COMPRESS_ONE_VALUE /* contiguous, except a dataset of 4 KiB or more whose elements all hold the
                                same bytes (the zero affine matrices of a PIC or FLIP liquid), chunked with
                                shuffle + deflate 1 and shrunk to almost nothing: frame caches, written every
                                frame, whose doubles deflate by 12% at about 50 times the write time (measured
                                in io_h5.c) */
} DrH5Compress;
void dr_h5_set_compress(DrH5 *h, DrH5Compress mode);

/* Attributes on "/", a group (created with its parents if missing) or an existing dataset. An
 * existing attribute of that name is replaced. Write handles only. */
DR_NODISCARD DrStatus dr_h5_attr_str(DrH5 *h, const char *obj, const char *name, const char *value,
                                     DrError *err);
DR_NODISCARD DrStatus dr_h5_attr_f64(DrH5 *h, const char *obj, const char *name, double value, DrError *err);
DR_NODISCARD DrStatus dr_h5_attr_i64(DrH5 *h, const char *obj, const char *name, int64_t value, DrError *err);

/* Dataset readers: *rank and dims[0..rank) are filled and *data is a malloc'd array of prod(dims)
 * elements (non-NULL even for 0 elements; caller frees). A missing dataset, one of another element
 * type (f64 = 8-byte float, i64 = signed 8-byte integer, u64 = unsigned 8-byte integer, i32 = signed
 * 4-byte integer) or of rank above 4 is DR_ERR_INPUT naming file and dataset; *data is NULL on failure. */
DR_NODISCARD DrStatus dr_h5_read_f64(DrH5 *h, const char *path, int *rank, uint64_t dims[4], double **data,
                                     DrError *err);
DR_NODISCARD DrStatus dr_h5_read_i64(DrH5 *h, const char *path, int *rank, uint64_t dims[4], int64_t **data,
                                     DrError *err);
DR_NODISCARD DrStatus dr_h5_read_u64(DrH5 *h, const char *path, int *rank, uint64_t dims[4], uint64_t **data,
                                     DrError *err);
DR_NODISCARD DrStatus dr_h5_read_i32(DrH5 *h, const char *path, int *rank, uint64_t dims[4], int32_t **data,
                                     DrError *err);
/* Attribute readers; a missing attribute or one of another type is DR_ERR_INPUT naming file, object
 * and attribute. The string is malloc'd (caller frees). Integer attributes of any integer type that
 * fits int64 are accepted, float attributes of any float size. */
DR_NODISCARD DrStatus dr_h5_read_attr_str(DrH5 *h, const char *obj, const char *name, char **value,
                                          DrError *err);
DR_NODISCARD DrStatus dr_h5_read_attr_f64(DrH5 *h, const char *obj, const char *name, double *value,
                                          DrError *err);
DR_NODISCARD DrStatus dr_h5_read_attr_i64(DrH5 *h, const char *obj, const char *name, int64_t *value,
                                          DrError *err);
/* True when an object (group or dataset) exists at path. */
bool dr_h5_has(DrH5 *h, const char *path);

/* Checks a whole file opened with dr_h5_open, including the datasets no caller reads: every dataset is read
 * and compared with its checksum (see "Checksums" above), and with `finite`, its 64-bit floats must hold no
 * NaN or infinity. The first failure, in name order, is DR_ERR_INPUT naming file and dataset (the dataset's
 * path also goes to bad_dataset when non-NULL: "" for a failure of the file as a whole); DR_ERR_NOMEM.
 * Costs one read of the file (about 1 GB/s from the page cache, measured in the README). */
DR_NODISCARD DrStatus dr_h5_verify(DrH5 *h, bool finite, char *bad_dataset, size_t bad_size, DrError *err);
/* Names of the direct children of a group in ascending name order: *names is a malloc'd array of
 * *count malloc'd strings (free each, then the array; NULL when *count is 0). A missing group is
 * DR_ERR_INPUT naming it. */
DR_NODISCARD DrStatus dr_h5_list(DrH5 *h, const char *group, char ***names, int *count, DrError *err);
/* Write handle: closes the file in memory, writes its image to the temporary file, fsyncs it and renames
 * it into place, then frees *h and sets it NULL (also on failure, in which case the temporary file is
 * removed and DR_ERR_IO names the file, e.g. "No space left on device"). A deferred handle is first
 * written (see dr_h5_create_deferred). The bytes are those HDF5 writes to a file of its own. */
DR_NODISCARD DrStatus dr_h5_commit(DrH5 **h, DrError *err);
/* Read handle: closes. Write handle not committed: closes and deletes the temporary file, so neither
 * it nor the final file exists afterwards. Frees *h and sets it NULL; NULL is a no-op. */
void dr_h5_close(DrH5 **h);
/* The path the handle will have once committed (write) or was opened from (read). */
const char *dr_h5_path(const DrH5 *h);
/* True when the HDF5 library is built thread-safe (Debian's is): the dr_h5 functions may then be called from
 * several threads on different handles, and HDF5 runs them one at a time behind its own lock. */
bool dr_h5_threadsafe(void);

/* ---- background writer ----------------------------------------------------------------------------
 * A DrH5Writer commits deferred handles on a thread of its own, one at a time, in the order they were
 * submitted (FIFO), so a file submitted after another is never renamed into place before it (a
 * checkpoint never gets ahead of the frame it follows). At most max_pending files are held (waiting
 * or being written); dr_h5_writer_submit waits for room, which bounds the memory to about
 * max_pending recordings. The first failure (DR_ERR_IO naming the file, its temporary file removed)
 * is kept: every file still waiting is dropped unwritten, later submissions are dropped, and
 * dr_h5_writer_submit and dr_h5_writer_flush return that failure from then on. The writer thread
 * blocks every signal, so handlers run on the caller's threads. When HDF5 is not built thread-safe,
 * dr_h5_writer_submit commits on the calling thread instead (same files, same failures). A writer is
 * used from one thread. */
typedef struct DrH5Writer DrH5Writer;

/* What the writer has done since it was created. */
typedef struct DrH5WriterStats {
    long files;     /* files committed or dropped */
    double seconds; /* seconds the writer thread spent writing them (wall clock) */
} DrH5WriterStats;

/* max_pending >= 1. DR_ERR_RUNTIME when the thread cannot be started, DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_h5_writer_create(int max_pending, DrH5Writer **out, DrError *err);
/* Hands the deferred handle *h (dr_h5_deferred) to the writer, which owns it from then on: *h is set
 * NULL whatever happens. Waits while max_pending files are pending. Returns DR_OK once queued, or an
 * earlier file's failure (then *h is dropped unwritten). */
DR_NODISCARD DrStatus dr_h5_writer_submit(DrH5Writer *w, DrH5 **h, DrError *err);
/* Waits until every submitted file is on disk (or dropped), then returns DR_OK or the first failure. */
DR_NODISCARD DrStatus dr_h5_writer_flush(DrH5Writer *w, DrError *err);
void dr_h5_writer_stats(DrH5Writer *w, DrH5WriterStats *out);
/* Finishes every pending file (as dr_h5_writer_flush, whose failure it cannot report: flush first),
 * stops the thread and frees *w, setting it NULL; NULL is a no-op. */
void dr_h5_writer_destroy(DrH5Writer **w);

/* ---- precompute cache: <root>/<kind>/<key>.h5, self-describing (DESIGN §4) ------------------- */

/* Writes "<root>/<kind>/<key_hex>.h5" into buf; asserts it fits. Does not validate kind or key. */
void dr_io_precache_path(const char *root, const char *kind, const char *key_hex, char *buf, size_t size);
/* kind is "cohesion" or "bem", key_hex 1..64 hex digits (anything else is DR_ERR_INPUT). Creates
 * <root>/<kind>/ if needed and the file through dr_h5_create, with root string attributes "kind",
 * "key", "inputs" (inputs_json: the canonical JSON of the parameters that made it), "asset_hash"
 * (asset_hash_hex, "" when NULL: the data depends on no asset file), "drench_version" and "created"
 * (ISO 8601 UTC). The caller adds datasets, then dr_h5_commit (or dr_h5_close to abandon). */
DR_NODISCARD DrStatus dr_io_precache_create(const char *root, const char *kind, const char *key_hex,
                                            const char *inputs_json, const char *asset_hash_hex, DrH5 **out,
                                            DrError *err);
/* Opens <root>/<kind>/<key_hex>.h5 read-only when it exists, opens as HDF5 and its "kind" and "key"
 * attributes match: *found = true, *out set. Otherwise (missing, unreadable, corrupt, other key)
 * *found = false, *out = NULL and DR_OK: such a file is never trusted. When a file is there but not trusted,
 * `rejected` (NULL: not wanted) says why, naming the file (status DR_ERR_INPUT; cleared otherwise): the caller
 * tells the user what follows (precompute recomputes it; a reader asks for precompute). Nothing is logged.
 * A bad kind or key_hex is DR_ERR_INPUT. */
DR_NODISCARD DrStatus dr_io_precache_open(const char *root, const char *kind, const char *key_hex, DrH5 **out,
                                          bool *found, DrError *rejected, DrError *err);

/* ISO 8601 UTC time of now, "YYYY-MM-DDTHH:MM:SSZ" (21 bytes with NUL). */
void dr_io_time_iso8601(char buf[32]);

/* ---- OBJ polylines (hair strands) -------------------------------------------------------------
 * A strand set as OBJ: "v x y z" records, then one "l a b c ..." record per strand (1-based indices,
 * root first). OBJ has no record for a radius, so it travels in comment lines "# radius R" (metres):
 * each sets the radius of the "l" records after it, as "usemtl" sets a material, so a set of one radius
 * holds one such line. Wet hair adds, right before each "l" record, a line "# outer_radius H1 H2 ..."
 * with one number per vertex of that record: the outer radius of the liquid film around the strand at
 * the vertex (metres; the strand's own radius where it is dry), which the render stage draws. Every
 * strand of a file has such a line, or none does. Tools that skip comments read plain polylines. */
typedef struct DrPolylines {
    int count;      /* strands */
    int *offsets;   /* count + 1: strand s is vertices offsets[s] .. offsets[s+1]-1, root first */
    double *x;      /* 3*offsets[count] coordinates, metres */
    double *radius; /* count radii, metres */
    double *outer;  /* NULL, or offsets[count] outer radii of the film per vertex ("# outer_radius"), metres */
} DrPolylines;
void dr_io_polylines_free(DrPolylines *p); /* frees the arrays and zeroes the struct */

/* Writes `p` atomically as above: optional header comment lines (as dr_io_write_obj), the "v" lines,
 * then per strand a "# radius R" line where the radius differs from the previous strand's (always
 * before the first), its "# outer_radius" line when p->outer is set, and its "l" line. Numbers are
 * printed with %.9g. An empty set (count 0) gives a file with only the comment. Every strand has at
 * least 2 vertices, offsets[0] is 0 and offsets do not decrease (asserted: the caller validates what it
 * read). A non-finite coordinate or a non-finite or negative radius or outer radius is DR_ERR_RUNTIME
 * and nothing is written; a write failure is DR_ERR_IO naming the
 * file, and neither path is left behind. */
DR_NODISCARD DrStatus dr_io_write_polylines_obj(const char *path, const DrPolylines *p, const char *comment,
                                                DrError *err);

/* What dr_io_read_polylines_obj asks of a file beyond being well formed. The defaults (in brackets,
 * dr_io_polylines_read_desc_default) are the mesh stage's format. */
typedef struct DrPolylinesReadDesc {
    bool require_radius;    /* [true] an "l" record before any "# radius" line is an error. When false,
                               such strands get radius NAN (unknown; dr_io_write_polylines_obj refuses it) */
    bool require_strands;   /* [false] a file without "l" records is an error (else an empty set, count 0) */
    bool reject_zero_edges; /* [false] two consecutive vertices of a strand at one position are an error */
} DrPolylinesReadDesc;
void dr_io_polylines_read_desc_default(DrPolylinesReadDesc *d);

/* Reads an OBJ polyline file into *out (caller frees with dr_io_polylines_free), with the checks `desc`
 * asks for (NULL: the defaults). Every "l" record is a strand whose vertices are copied in record order (a
 * vertex shared by two records is copied into both); its radius is that of the last "# radius" line
 * before it. Indices are 1-based, negative ones count back from the last "v" record before the line,
 * positive ones may point forward; "a/b" takes the vertex a. Numbers after x y z of a "v" record (a
 * weight, a colour) are checked and ignored. Faces, normals, groups, other comments and text after a '#'
 * are skipped; CRLF line ends are accepted. "# outer_radius" lines fill out->outer (per vertex of each
 * "l" record, as its vertices are copied); out->outer stays NULL in a file without them. The whole file
 * is checked before anything is returned.
 * Errors, *out left zeroed:
 *   DR_ERR_INPUT at file:line:col for: a NUL or other control byte (not a text file); a "v" record
 *   without three numbers, a token in it that is not a number, a non-finite coordinate; a "# radius"
 *   line without one finite number >= 0 (whatever require_radius says); an "# outer_radius" line whose
 *   numbers are not finite and >= 0, or whose count differs from the vertices of the "l" record after
 *   it, or that no "l" record follows, or an "l" record without one where the records before it had one
 *   (or the reverse); an "l" token that is not an
 *   index, index 0, an index of no vertex, an "l" record of fewer than 2 vertices; a "v" or "l" record
 *   continued with '\'; with require_radius an "l" record before any "# radius" line; with
 *   reject_zero_edges a zero-length edge (at its second vertex).
 *   DR_ERR_INPUT naming the file: a missing or unopenable file; with require_strands, no "l" record.
 *   DR_ERR_IO naming the file: a read failure. */
DR_NODISCARD DrStatus dr_io_read_polylines_obj(const char *path, const DrPolylinesReadDesc *desc, DrPolylines *out,
                                               DrError *err);

#endif
