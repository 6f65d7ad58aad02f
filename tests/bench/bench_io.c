/* Bake output benchmark, two parts, each a markdown table on stdout and a CSV under out/bench/:
 *  1. bakes of two dam breaks (72k and 120k particles at 8 per cell, dx 0.02) with frames and checkpoints
 *     written on the main thread (bake --sync-writes) and by the writer thread (the default): wall time, the
 *     main thread's output seconds per frame and their share of the wall time, the writer thread's seconds
 *     (the first csv, default out/bench/io.csv; the per-frame figures of the kept runs in io_frames.csv);
 *  2. storage of a frame's particle arrays (position, velocity, affine of the last frame of part 1, and the
 *     same with zero affine matrices as a PIC or FLIP liquid writes them) under chunk sizes, shuffle, deflate
 *     levels and szip: seconds to write (through H5Fclose), to make durable and rename (fsync, as every frame
 *     is), to read back, and the file's size (out/bench/io_storage.csv).
 * Part 1 runs bin/bake (build it first: make bench does); part 2 writes with the HDF5 calls of src/io/io_h5.c
 * and its dataset properties, one option at a time. Files go under $TMPDIR. Wall-clock seconds depend on what
 * else runs on the machine: each bake and each write is repeated and the fastest repetition is kept.
 * usage: bench_io [csv = out/bench/io.csv] [frames = 12] */
#include <hdf5.h>
#include <jansson.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "io/io.h"

#define BAKE_REPEATS 2
#define WRITE_REPEATS 3

static char g_dir[512];

static void die(const char *what)
{
    fprintf(stderr, "bench_io: %s\n", what);
    exit(1);
}

static FILE *open_csv(const char *path)
{
    FILE *f = fopen(path, "w");
    if (!f) die("cannot write a csv under out/bench/");
    return f;
}

/* ---- 1. bakes ---------------------------------------------------------------------------------- */

typedef struct Scene {
    const char *name;
    double source_hi[3]; /* liquid box from the origin, m */
} Scene;

static const Scene scenes[2] = {{"dam72k", {0.4, 0.5, 0.36}}, {"dam120k", {0.5, 0.6, 0.4}}};

static void write_scene(const Scene *sc, int frames, char *path, size_t size)
{
    snprintf(path, size, "%s/%s.json", g_dir, sc->name);
    FILE *f = fopen(path, "w");
    if (!f) die("cannot write a scene under $TMPDIR");
    fprintf(f,
            "{ \"shot\": { \"name\": \"%s\", \"fps\": 24, \"frames\": [1, %d], \"seed\": 1 },\n"
            "  \"solver\": { \"cfl\": 2.0, \"max_substeps\": 64 },\n"
            "  \"elements\": [ { \"name\": \"water\", \"type\": \"liquid\", \"components\": {\n"
            "    \"Domain\": { \"box\": [[0, 0, 0], [1.2, 0.7, 0.4]], \"voxel_size\": 0.02 },\n"
            "    \"LiquidSource\": { \"box\": [[0, 0, 0], [%g, %g, %g]] },\n"
            "    \"Particles\": { \"per_cell\": 8, \"seed\": 7 } } } ] }\n",
            sc->name, frames, sc->source_hi[0], sc->source_hi[1], sc->source_hi[2]);
    fclose(f);
}

typedef struct BakeRun {
    double wall, io, wait, writer;
    long particles;
    int frames;
} BakeRun;

static double number(json_t *o, const char *key)
{
    json_t *v = json_object_get(o, key);
    if (!json_is_number(v)) die("report.json lacks a field the benchmark reads");
    return json_number_value(v);
}

static BakeRun bake(const char *scene, const char *name, bool sync)
{
    char cmd[2048], path[1024];
    snprintf(cmd, sizeof cmd, "bin/bake '%s' --out '%s/out' -q%s >/dev/null 2>&1", scene, g_dir,
             sync ? " --sync-writes" : "");
    if (system(cmd) != 0) die("bin/bake failed (is it built? make bench builds it)");
    snprintf(path, sizeof path, "%s/out/%s/bake/report.json", g_dir, name);
    json_error_t jerr;
    json_t *r = json_load_file(path, 0, &jerr);
    if (!r) die("cannot read the bake's report.json");
    json_t *io = json_object_get(r, "io");
    BakeRun b = {number(r, "seconds_total"), number(io, "main_thread_seconds"), number(io, "wait_seconds"),
                 number(io, "writer_seconds"), (long)number(json_object_get(r, "particles"), "last_frame"),
                 (int)number(r, "frames_baked")};
    json_decref(r);
    return b;
}

/* Keeps the progress.jsonl of the run just baked (the fastest so far) as <dir>/kept.jsonl. */
static void keep_progress(const char *name)
{
    char from[1024], to[1024];
    snprintf(from, sizeof from, "%s/out/%s/bake/progress.jsonl", g_dir, name);
    snprintf(to, sizeof to, "%s/kept.jsonl", g_dir);
    if (rename(from, to) != 0) die("cannot keep the bake's progress.jsonl");
}

/* Appends the kept run's per-frame output seconds to the frames csv. */
static void frame_rows(FILE *f, const char *name, const char *mode)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/kept.jsonl", g_dir);
    FILE *in = fopen(path, "r");
    if (!in) die("cannot read the bake's progress.jsonl");
    char line[16384];
    while (fgets(line, sizeof line, in)) {
        json_error_t jerr;
        json_t *o = json_loads(line, 0, &jerr);
        if (!o) die("progress.jsonl holds a line that is not JSON");
        json_t *sec = json_object_get(o, "seconds"), *io = json_object_get(o, "io");
        fprintf(f, "%s,%s,%d,%.4f,%.4f,%.4f,%.4f\n", name, mode, (int)number(o, "frame"), number(sec, "io"),
                number(io, "wait"), number(io, "writer"), number(sec, "frame"));
        json_decref(o);
    }
    fclose(in);
}

static void bakes(const char *csv, int frames)
{
    FILE *f = open_csv(csv), *ff = open_csv("out/bench/io_frames.csv");
    fprintf(f, "scene,particles,mode,frames,wall,io_main,io_main_per_frame,io_wait,io_writer,io_writer_per_frame,"
               "main_share\n");
    fprintf(ff, "scene,mode,frame,io_main,io_wait,io_writer,frame_seconds\n");
    printf("| scene | particles | frames written | wall (s) | main-thread output (s/frame) | waiting (s) | writer "
           "thread (s/frame) | main thread's share of the wall time |\n");
    printf("|---|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < 2; i++) {
        char scene[1024];
        write_scene(&scenes[i], frames, scene, sizeof scene);
        for (int m = 0; m < 2; m++) {
            bool sync = m == 0;
            const char *mode = sync ? "main thread" : "background";
            BakeRun best = {INFINITY, 0, 0, 0, 0, 0};
            for (int rep = 0; rep < BAKE_REPEATS; rep++) {
                BakeRun b = bake(scene, scenes[i].name, sync);
                if (b.wall < best.wall) {
                    best = b;
                    keep_progress(scenes[i].name);
                }
            }
            frame_rows(ff, scenes[i].name, mode);
            double n = best.frames;
            fprintf(f, "%s,%ld,%s,%d,%.3f,%.3f,%.4f,%.3f,%.3f,%.4f,%.4f\n", scenes[i].name, best.particles, mode,
                    best.frames, best.wall, best.io, best.io / n, best.wait, best.writer, best.writer / n,
                    best.io / best.wall);
            printf("| %s | %ld | %s | %.2f | %.3f | %.2f | %.3f | %.1f%% |\n", scenes[i].name, best.particles, mode,
                   best.wall, best.io / n, best.wait, best.writer / n, 100.0 * best.io / best.wall);
            fflush(stdout);
        }
    }
    fclose(f);
    fclose(ff);
}

/* ---- 2. storage options ------------------------------------------------------------------------ */

typedef struct Storage {
    const char *name;
    size_t chunk_bytes; /* 0: contiguous, no filters */
    bool shuffle;
    int deflate;        /* level, 0 = none */
    bool szip;          /* instead of deflate (a reader needs libaec: not every HDF5 build has it) */
    bool only_constant; /* chunked and filtered only when every element holds the same bits, else contiguous */
} Storage;

static const Storage storages[] = {
    {"contiguous", 0, false, 0, false, false},
    {"256K deflate1", 256 << 10, false, 1, false, false},
    {"64K shuffle+deflate1", 64 << 10, true, 1, false, false},
    {"256K shuffle+deflate1", 256 << 10, true, 1, false, false},
    {"1M shuffle+deflate1", 1 << 20, true, 1, false, false},
    {"4M shuffle+deflate1", 4 << 20, true, 1, false, false},
    {"256K shuffle+deflate3", 256 << 10, true, 3, false, false},
    {"256K shuffle+deflate6", 256 << 10, true, 6, false, false},
    {"1M shuffle", 1 << 20, true, 0, false, false},
    {"256K szip", 256 << 10, false, 0, true, false},
    {"contiguous; one value deflated", 256 << 10, true, 1, false, true},
};
#define NSTORAGE ((int)(sizeof storages / sizeof storages[0]))

typedef struct Arrays {
    int n;
    const char *names[3];
    int rank[3];
    uint64_t dims[3][4];
    double *data[3];
} Arrays;

static void read_arrays(const char *path, Arrays *a)
{
    DrH5 *h = NULL;
    DrError err;
    if (dr_h5_open(path, &h, &err) < 0) die(err.message);
    static const char *names[3] = {"/water/position", "/water/velocity", "/water/affine"};
    a->n = 3;
    for (int i = 0; i < 3; i++) {
        a->names[i] = names[i];
        if (dr_h5_read_f64(h, names[i], &a->rank[i], a->dims[i], &a->data[i], &err) < 0) die(err.message);
    }
    dr_h5_close(&h);
}

/* The chunk shape of io_h5.c: whole trailing dimensions, the leading one cut to about `bytes`. */
static void chunk_shape(int rank, const uint64_t *dims, size_t bytes, hsize_t *chunk)
{
    for (int i = 0; i < rank; i++) chunk[i] = dims[i];
    uint64_t rest = 1;
    for (int i = 1; i < rank; i++) rest *= dims[i];
    uint64_t rows = bytes / 8 / rest;
    if (rows < dims[0]) chunk[0] = rows > 0 ? rows : 1;
}

/* Writes the arrays under one storage option; returns the seconds through H5Fclose and of the commit. */
static void write_file(const Arrays *a, const Storage *st, const char *path, double *write_s, double *commit_s)
{
    char tmp[DR_IO_PATH_MAX];
    dr_io_tmp_path(path, tmp, sizeof tmp);
    double t0 = dr_time_now();
    hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
    H5Pset_fclose_degree(fapl, H5F_CLOSE_STRONG);
    hid_t file = H5Fcreate(tmp, H5F_ACC_TRUNC, H5P_DEFAULT, fapl);
    H5Pclose(fapl);
    if (file < 0) die("cannot create a file under $TMPDIR");
    hid_t lcpl = H5Pcreate(H5P_LINK_CREATE);
    H5Pset_create_intermediate_group(lcpl, 1);
    for (int i = 0; i < a->n; i++) {
        hsize_t hd[4], chunk[4];
        for (int k = 0; k < a->rank[i]; k++) hd[k] = a->dims[i][k];
        hid_t space = H5Screate_simple(a->rank[i], hd, NULL);
        hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
        H5Pset_obj_track_times(dcpl, 0);
        size_t count = 1;
        for (int k = 0; k < a->rank[i]; k++) count *= (size_t)a->dims[i][k];
        bool constant = count > 1 && memcmp(a->data[i], a->data[i] + 1, 8 * (count - 1)) == 0;
        if (st->chunk_bytes && (!st->only_constant || constant)) {
            chunk_shape(a->rank[i], a->dims[i], st->chunk_bytes, chunk);
            H5Pset_chunk(dcpl, a->rank[i], chunk);
            if (st->shuffle) H5Pset_shuffle(dcpl);
            if (st->deflate) H5Pset_deflate(dcpl, (unsigned)st->deflate);
            if (st->szip) H5Pset_szip(dcpl, H5_SZIP_NN_OPTION_MASK, 32);
        }
        hid_t d = H5Dcreate2(file, a->names[i], H5T_IEEE_F64LE, space, lcpl, dcpl, H5P_DEFAULT);
        if (d < 0 || H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, a->data[i]) < 0)
            die("cannot write a dataset under $TMPDIR");
        H5Dclose(d);
        H5Pclose(dcpl);
        H5Sclose(space);
    }
    H5Pclose(lcpl);
    if (H5Fclose(file) < 0) die("cannot close a file under $TMPDIR");
    double t1 = dr_time_now();
    DrError err;
    if (dr_io_commit(tmp, path, &err) < 0) die(err.message);
    *write_s = t1 - t0;
    *commit_s = dr_time_now() - t1;
}

static double read_file(const char *path)
{
    double t0 = dr_time_now();
    Arrays back;
    read_arrays(path, &back);
    double s = dr_time_now() - t0;
    for (int i = 0; i < back.n; i++) free(back.data[i]);
    return s;
}

/* zero_affine: the affine matrices set to zero, as a PIC or FLIP liquid writes them */
static void storage(const char *name, bool zero_affine, FILE *f)
{
    char src[1024], path[1100];
    snprintf(src, sizeof src, "%s/out/%s/bake", g_dir, name);
    /* the last frame the bakes wrote: particles that have moved, not the initial lattice */
    int last = 0;
    for (int fr = 1; fr < 10000; fr++) {
        snprintf(path, sizeof path, "%s/frame.%04d.h5", src, fr);
        if (!dr_io_exists(path)) break;
        last = fr;
    }
    snprintf(path, sizeof path, "%s/frame.%04d.h5", src, last);
    Arrays a;
    read_arrays(path, &a);
    if (zero_affine) memset(a.data[2], 0, 8 * (size_t)a.dims[2][0] * 9);
    double raw = 0;
    for (int i = 0; i < a.n; i++) raw += 8.0 * (double)(a.dims[i][0] * a.dims[i][1] * (a.rank[i] > 2 ? a.dims[i][2] : 1));
    printf("\n%s, frame %d%s: %ld particles, %.1f MB of position, velocity and affine\n\n", name, last,
           zero_affine ? " with zero affine matrices (pic, flip)" : "", (long)a.dims[0][0], raw / 1e6);
    unsigned szip = 0;
    H5Zget_filter_info(H5Z_FILTER_SZIP, &szip);
    printf("| storage | write (s) | fsync + rename (s) | read (s) | size (MB) | of raw |\n|---|---|---|---|---|---|\n");
    snprintf(path, sizeof path, "%s/storage.h5", g_dir);
    for (int o = 0; o < NSTORAGE; o++) {
        if (storages[o].szip && !(szip & H5Z_FILTER_CONFIG_ENCODE_ENABLED)) continue;
        double bw = INFINITY, bc = INFINITY, br = INFINITY;
        for (int rep = 0; rep < WRITE_REPEATS; rep++) {
            double w, c;
            write_file(&a, &storages[o], path, &w, &c);
            bw = fmin(bw, w);
            bc = fmin(bc, c);
            br = fmin(br, read_file(path));
        }
        struct stat sb;
        if (stat(path, &sb) != 0) die("cannot stat the file written");
        double mb = (double)sb.st_size / 1e6;
        fprintf(f, "%s%s,%ld,%s,%.4f,%.4f,%.4f,%.3f,%.4f\n", name, zero_affine ? " zero affine" : "",
                (long)a.dims[0][0], storages[o].name, bw, bc, br, mb, (double)sb.st_size / raw);
        printf("| %s | %.3f | %.3f | %.3f | %.2f | %.1f%% |\n", storages[o].name, bw, bc, br, mb,
               100.0 * (double)sb.st_size / raw);
        fflush(stdout);
    }
    unlink(path);
    for (int i = 0; i < a.n; i++) free(a.data[i]);
}

int main(int argc, char **argv)
{
    const char *csv = argc > 1 ? argv[1] : "out/bench/io.csv";
    int frames = argc > 2 ? atoi(argv[2]) : 12;
    if (frames < 1) die("frames must be at least 1");
    dr_log_set_level(DR_LOG_WARN);
    H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
    snprintf(g_dir, sizeof g_dir, "%s/drench_bench_io.XXXXXX", dr_temp_dir());
    if (!mkdtemp(g_dir)) die("cannot make a directory under $TMPDIR");
    printf("Bakes of %d frames, output on the main thread (--sync-writes) and in the background (fastest of %d "
           "runs):\n\n",
           frames, BAKE_REPEATS);
    bakes(csv, frames);
    FILE *f = open_csv("out/bench/io_storage.csv");
    fprintf(f, "scene,particles,storage,write,commit,read,megabytes,of_raw\n");
    for (int z = 0; z < 2; z++)
        for (int i = 0; i < 2; i++) storage(scenes[i].name, z == 1, f);
    fclose(f);
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    return system(cmd) == 0 ? 0 : 1;
}
