/* drench core: calling convention, status and errors, small math by value, logging and progress,
 * arena, content hashing, timers, parallel-for and a reproducible rng.
 *
 * Calling convention (every module follows it):
 *   - inputs first, then in/out, then outputs, then `DrError *err` last; `const` on input pointers;
 *   - functions that can fail on data return DrStatus (DR_OK = 0, positive = warning such as
 *     "not converged", negative = fatal) and fill `err` with what happened and what would fix it;
 *   - misuse by our own code is an assert (kept in release builds);
 *   - `dr_x_create(desc, &x, err)` / `dr_x_destroy(&x)`: destroy frees and NULLs, NULL is a no-op.
 * Thread safety: everything here is safe to call from several threads except the logger's
 * configuration (dr_log_set_level) and DrArena/DrRng objects, which belong to one thread. */
#ifndef DR_CORE_H
#define DR_CORE_H

#include <assert.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#define DR_VERSION "0.1.0"

#if defined(__GNUC__)
#define DR_NODISCARD __attribute__((warn_unused_result))
#define DR_PRINTF(a, b) __attribute__((format(printf, a, b)))
#else
#define DR_NODISCARD
#define DR_PRINTF(a, b)
#endif

/* ---- status and errors ------------------------------------------------------------------ */

typedef enum DrStatus {
    DR_OK = 0,
    DR_WARN_NOT_CONVERGED = 1, /* an iterative solve stopped at its limit; result usable */
    DR_ERR_RUNTIME = -1,       /* solver diverged beyond recovery, unexpected library failure */
    DR_ERR_INPUT = -2,         /* bad scene, asset or argument: the user can fix it */
    DR_ERR_IO = -3,            /* file could not be read or written (disk full, permissions) */
    DR_ERR_NOMEM = -4,         /* allocation failed or a size overflowed */
} DrStatus;

typedef struct DrError {
    DrStatus status;
    char message[2048]; /* complete sentence(s): what happened and what would fix it */
    char file[1024];    /* file the problem is in, "" if none */
    int line, col;      /* 1-based position in `file`, 0 if unknown */
} DrError;

/* Fills err (if non-NULL) and returns `status`. `file` may be NULL. */
DrStatus dr_error_set(DrError *err, DrStatus status, const char *file, int line, int col,
                      const char *fmt, ...) DR_PRINTF(6, 7);
/* Puts a formatted prefix and ": " in front of a failure's message ("jelly.MpmShape.mesh: <message>"), keeping its
   status, file and position; a message that no longer fits keeps its start and ends in ".". Returns s, and does
   nothing when s is not a failure or err is NULL. */
DrStatus dr_error_prefix(DrStatus s, DrError *err, const char *fmt, ...) DR_PRINTF(3, 4);
void dr_error_clear(DrError *err);
/* "file:line:col: error: message" (or "error: message"), one line, no trailing newline. */
void dr_error_format(const DrError *err, char *buf, size_t size);
/* Prints the formatted error on stderr prefixed by the program name. */
void dr_error_print(const char *prog, const DrError *err);
/* Exit code of DESIGN §1 for a status: 0 ok or warning, 2 bad input, 1 everything else. */
int dr_exit_code(DrStatus status);
const char *dr_status_name(DrStatus status);

#define DR_FAILED(s) ((s) < 0)
/* Evaluates expr; returns its status from the enclosing function if fatal. */
#define DR_TRY(expr)                                                                         \
    do {                                                                                     \
        DrStatus dr_try_status_ = (expr);                                                    \
        if (dr_try_status_ < 0) return dr_try_status_;                                       \
    } while (0)

/* ---- allocation with overflow checks -------------------------------------------------- */

/* calloc(count, size) that fails with DR_ERR_NOMEM on overflow or exhaustion. */
DR_NODISCARD DrStatus dr_calloc(size_t count, size_t size, void *out_ptr, DrError *err);
/* realloc to count*size bytes; on failure *ptr is kept and DR_ERR_NOMEM returned. */
DR_NODISCARD DrStatus dr_realloc(size_t count, size_t size, void *inout_ptr, DrError *err);
bool dr_mul_overflows(size_t a, size_t b, size_t *out);
char *dr_strdup(const char *s); /* NULL on NULL or exhaustion */
/* Heap allocations made so far by this process through dr_calloc, dr_realloc, dr_strdup and new arena blocks
   (every thread; relaxed atomic). Solver code allocates only through these, so a test can assert that a step
   after the first allocates nothing: read the count before and after. */
uint64_t dr_alloc_count(void);
void dr_alloc_count_add_(void); /* for core's own allocators */

/* ---- small math by value --------------------------------------------------------------- */

typedef struct DrVec3 { double x, y, z; } DrVec3;
typedef struct DrMat3 { double m[3][3]; } DrMat3; /* row-major: m[row][col] */

static inline DrVec3 dr_v3(double x, double y, double z) { DrVec3 r = {x, y, z}; return r; }
static inline DrVec3 dr_v3_add(DrVec3 a, DrVec3 b) { return dr_v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline DrVec3 dr_v3_sub(DrVec3 a, DrVec3 b) { return dr_v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline DrVec3 dr_v3_scale(DrVec3 a, double s) { return dr_v3(a.x * s, a.y * s, a.z * s); }
static inline DrVec3 dr_v3_mul(DrVec3 a, DrVec3 b) { return dr_v3(a.x * b.x, a.y * b.y, a.z * b.z); }
static inline double dr_v3_dot(DrVec3 a, DrVec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline DrVec3 dr_v3_cross(DrVec3 a, DrVec3 b)
{
    return dr_v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline double dr_v3_norm(DrVec3 a) { return sqrt(dr_v3_dot(a, a)); }
static inline DrVec3 dr_v3_min(DrVec3 a, DrVec3 b) { return dr_v3(fmin(a.x, b.x), fmin(a.y, b.y), fmin(a.z, b.z)); }
static inline DrVec3 dr_v3_max(DrVec3 a, DrVec3 b) { return dr_v3(fmax(a.x, b.x), fmax(a.y, b.y), fmax(a.z, b.z)); }
static inline double dr_v3_get(DrVec3 a, int i) { return i == 0 ? a.x : (i == 1 ? a.y : a.z); }
static inline bool dr_v3_isfinite(DrVec3 a) { return isfinite(a.x) && isfinite(a.y) && isfinite(a.z); }
static inline DrVec3 dr_v3_normalize(DrVec3 a)
{
    double n = dr_v3_norm(a);
    return n > 0.0 ? dr_v3_scale(a, 1.0 / n) : dr_v3(0, 0, 0);
}

/* A tangent basis of the plane across unit normal n (flat arrays): t1 ⊥ n from the x axis (the y axis when n lies
   near x), t2 = n × t1. The one basis every friction group takes. */
static inline void dr_tangent_basis(const double n[3], double t1[3], double t2[3])
{
    double ax[3] = {fabs(n[0]) < 0.6 ? 1.0 : 0.0, fabs(n[0]) < 0.6 ? 0.0 : 1.0, 0.0};
    double d = ax[0] * n[0] + ax[1] * n[1];
    for (int a = 0; a < 3; a++) t1[a] = ax[a] - d * n[a];
    double l = sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]);
    for (int a = 0; a < 3; a++) t1[a] /= l;
    t2[0] = n[1] * t1[2] - n[2] * t1[1];
    t2[1] = n[2] * t1[0] - n[0] * t1[2];
    t2[2] = n[0] * t1[1] - n[1] * t1[0];
}

DrMat3 dr_m3_identity(void);
DrMat3 dr_m3_mul(DrMat3 a, DrMat3 b);
DrMat3 dr_m3_transpose(DrMat3 a);
DrVec3 dr_m3_apply(DrMat3 a, DrVec3 v);
/* Rotation from XYZ Euler angles in radians: R = Rz * Ry * Rx (x applied first). */
DrMat3 dr_m3_from_euler_xyz(DrVec3 radians);
/* The rotation by θ = |w| radians about w (Rodrigues): e^{[w]×} = I + (sin θ/θ)[w]× + ((1 − cos θ)/θ²)[w]×², the
   two coefficients by their Taylor series below θ = 1e-8. Orthogonal to a few ε for any w. */
DrMat3 dr_m3_rotation_exp(DrVec3 w);
/* The rotation vector w, |w| ≤ π, with dr_m3_rotation_exp(w) = R, for R orthogonal with det +1 to round-off (the
   result means nothing for other matrices). At a half turn w and −w are the same rotation; either is returned.
   dr_m3_rotation_exp(dr_m3_rotation_log(R)) gives R back to ~1e-15 at every angle, near 0 and near π included. */
DrVec3 dr_m3_rotation_log(DrMat3 R);
/* The eigen-decomposition of a symmetric 3×3 A (row-major; only its symmetric part is meaningful) by cyclic Jacobi
   rotations: A = V diag(e) Vᵀ, the eigenvectors in V's columns, unsorted. */
void dr_m3a_sym_eigen(const double A[9], double e[3], double V[9]);

/* 3×3 matrices in flat arrays. The solvers keep matrices in per-particle and per-body arrays of 9 doubles, row-major
   (a[3·row + col], the layout of DrMat3), and work on them in place. dr_m3a_mul, dr_m3a_transpose and dr_m3a_apply
   compute every entry with the operations, in the order, of dr_m3_mul, dr_m3_transpose and dr_m3_apply, so a result
   has the same bits in either form. Outputs may alias inputs. Inline, because the MPM's per-particle loops call
   them. */
static inline DrMat3 dr_m3_load(const double a[9])
{
    DrMat3 r;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) r.m[i][j] = a[3 * i + j];
    return r;
}
static inline void dr_m3_store(DrMat3 m, double out[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) out[3 * i + j] = m.m[i][j];
}
static inline void dr_m3a_mul(const double a[9], const double b[9], double out[9]) /* out = a b */
{
    double r[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) r[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
    for (int k = 0; k < 9; k++) out[k] = r[k];
}
static inline void dr_m3a_mul_tn(const double a[9], const double b[9], double out[9]) /* out = aᵀ b */
{
    double r[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) r[3 * i + j] = a[i] * b[j] + a[3 + i] * b[3 + j] + a[6 + i] * b[6 + j];
    for (int k = 0; k < 9; k++) out[k] = r[k];
}
static inline void dr_m3a_mul_nt(const double a[9], const double b[9], double out[9]) /* out = a bᵀ */
{
    double r[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r[3 * i + j] = a[3 * i] * b[3 * j] + a[3 * i + 1] * b[3 * j + 1] + a[3 * i + 2] * b[3 * j + 2];
    for (int k = 0; k < 9; k++) out[k] = r[k];
}
static inline void dr_m3a_transpose(const double a[9], double out[9])
{
    double r[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) r[3 * i + j] = a[3 * j + i];
    for (int k = 0; k < 9; k++) out[k] = r[k];
}
static inline void dr_m3a_apply(const double a[9], const double x[3], double y[3]) /* y = a x */
{
    double r[3];
    for (int i = 0; i < 3; i++) r[i] = a[3 * i] * x[0] + a[3 * i + 1] * x[1] + a[3 * i + 2] * x[2];
    for (int i = 0; i < 3; i++) y[i] = r[i];
}
static inline void dr_m3a_apply_t(const double a[9], const double x[3], double y[3]) /* y = aᵀ x */
{
    double r[3];
    for (int i = 0; i < 3; i++) r[i] = a[i] * x[0] + a[3 + i] * x[1] + a[6 + i] * x[2];
    for (int i = 0; i < 3; i++) y[i] = r[i];
}
static inline double dr_m3a_det(const double a[9]) /* by the first row */
{
    return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) + a[2] * (a[3] * a[7] - a[4] * a[6]);
}
/* cof(a) = det(a) a⁻ᵀ, defined for singular a: its columns are b×c, c×a, a×b for the columns a, b, c. */
static inline void dr_m3a_cofactor(const double a[9], double out[9])
{
    double r[9] = {a[4] * a[8] - a[5] * a[7], a[5] * a[6] - a[3] * a[8], a[3] * a[7] - a[4] * a[6],
                   a[2] * a[7] - a[1] * a[8], a[0] * a[8] - a[2] * a[6], a[1] * a[6] - a[0] * a[7],
                   a[1] * a[5] - a[2] * a[4], a[2] * a[3] - a[0] * a[5], a[0] * a[4] - a[1] * a[3]};
    for (int k = 0; k < 9; k++) out[k] = r[k];
}
/* a⁻¹ = cof(a)ᵀ / det(a), each entry divided by the determinant. False, out untouched, when det(a) is 0 or not
   finite. */
static inline bool dr_m3a_inverse(const double a[9], double out[9])
{
    double det = dr_m3a_det(a), c[9];
    if (!(fabs(det) > 0) || !isfinite(det)) return false;
    dr_m3a_cofactor(a, c);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) out[3 * i + j] = c[3 * j + i] / det;
    return true;
}
static inline double dr_m3a_ddot(const double a[9], const double b[9]) /* a : b = Σ a_k b_k, k = 0, 1, …, 8 */
{
    double s = 0.0;
    for (int k = 0; k < 9; k++) s += a[k] * b[k];
    return s;
}

/* A rigid transform x ↦ R x + t. */
typedef struct DrXform { DrMat3 R; DrVec3 t; } DrXform;
DrXform dr_xform_identity(void);
DrVec3 dr_xform_apply(DrXform x, DrVec3 p);
DrVec3 dr_xform_apply_inverse(DrXform x, DrVec3 p); /* Rᵀ (p − t) */

#define DR_PI 3.14159265358979323846

/* ---- triangle meshes (shared by io, vdb, grid) ------------------------------------------ */

typedef struct DrTriMesh {
    int nv, nt;
    double *v; /* 3*nv vertex coordinates, metres */
    int *tri;  /* 3*nt vertex indices, counter-clockwise seen from outside */
    double *n; /* 3*nv per-vertex normals or NULL */
    double *uv; /* 6*nt texture coordinates per triangle corner (u, v), or NULL: from the file's first set when every
                   triangle has them (per corner, so a seam does not split the welded surface) */
} DrTriMesh;
void dr_trimesh_free(DrTriMesh *m); /* frees the arrays and zeroes the struct */
/* Signed volume by the divergence theorem (positive for outward CCW winding). */
double dr_trimesh_volume(const DrTriMesh *m);
/* Axis-aligned bounds; returns false for an empty mesh. */
bool dr_trimesh_bounds(const DrTriMesh *m, DrVec3 *lo, DrVec3 *hi);
/* True when every edge is shared by exactly two triangles with opposite orientation. */
bool dr_trimesh_is_closed(const DrTriMesh *m);

/* ---- logging and progress ---------------------------------------------------------------- */

typedef enum DrLogLevel { DR_LOG_ERROR = 0, DR_LOG_WARN, DR_LOG_INFO, DR_LOG_DEBUG } DrLogLevel;
void dr_log_set_level(DrLogLevel level); /* default INFO; DRENCH_LOG=debug|info|warn|error */
DrLogLevel dr_log_level(void);
void dr_log(DrLogLevel level, const char *fmt, ...) DR_PRINTF(2, 3);
#define dr_log_error(...) dr_log(DR_LOG_ERROR, __VA_ARGS__)
#define dr_log_warn(...) dr_log(DR_LOG_WARN, __VA_ARGS__)
#define dr_log_info(...) dr_log(DR_LOG_INFO, __VA_ARGS__)
#define dr_log_debug(...) dr_log(DR_LOG_DEBUG, __VA_ARGS__)

/* Progress of `total` units of work (frames), on stderr and stdout:
 *   - on a terminal (stderr is a tty, and $CI is not set) one bar redrawn in place: label, bar, done/total,
 *     rate, ETA, peak RSS and as much of `detail` as fits the terminal's width, so the line never wraps
 *     (a wrapped line cannot be redrawn); a log line printed meanwhile clears the bar first;
 *   - otherwise one line per completed unit: label, done/total, detail, ETA and peak RSS;
 *   - neither when the log level is below INFO (-q, DRENCH_LOG=warn);
 *   - `ALF_PROGRESS NN%` on stdout when the percentage changes, for farm managers, when stdout is not a tty
 *     or DRENCH_ALF_PROGRESS=1 (DRENCH_ALF_PROGRESS=0 never), whatever the log level.
 * ETA: the mean seconds of the last DR_PROGRESS_WINDOW units (time between consecutive steps, so units
 * completed in parallel count at their rate) times the units left: it follows a cost per frame that grows as
 * a shot develops, where the mean since the start lags. Steps may come from several threads if the caller
 * serialises them (one lock around dr_progress_step). */
#define DR_PROGRESS_WINDOW 5
typedef struct DrProgress {
    const char *label;
    long total, done;
    double t_start, t_last;             /* dr_time_now() at begin and at the previous step */
    double recent[DR_PROGRESS_WINDOW];  /* seconds of the last steps, a ring indexed by done */
    int last_percent;
    bool bar, lines, alf;               /* what this progress prints (fixed at begin) */
} DrProgress;
void dr_progress_begin(DrProgress *p, const char *label, long total);
/* Marks one more unit done; `detail` (may be NULL) is printed on the per-unit line. */
void dr_progress_step(DrProgress *p, const char *detail);
/* As dr_progress_step with the time of completion given (seconds on dr_time_now's clock). */
void dr_progress_step_at(DrProgress *p, double now, const char *detail);
void dr_progress_end(DrProgress *p);
/* Seconds left: the mean of the last (up to DR_PROGRESS_WINDOW) steps' seconds times the units left; 0 when
 * nothing is done yet. */
double dr_progress_eta(const DrProgress *p);
/* Peak resident set size of this process so far, bytes (getrusage); 0 if unknown. */
long long dr_peak_rss_bytes(void);
/* "812 MiB", "1.4 GiB": a byte count for people. */
void dr_format_bytes(long long bytes, char *buf, size_t size);

/* ---- arena --------------------------------------------------------------------------------- */

/* A bump allocator for per-step scratch: allocations are 64-byte aligned, freed all at once by
 * dr_arena_reset. Grows by chaining blocks; never moves what it handed out. */
typedef struct DrArena DrArena;
DR_NODISCARD DrStatus dr_arena_create(size_t block_bytes, DrArena **out, DrError *err);
void dr_arena_destroy(DrArena **arena);
/* Zeroed memory or NULL on exhaustion/overflow. */
void *dr_arena_alloc(DrArena *arena, size_t count, size_t size);
void dr_arena_reset(DrArena *arena);
size_t dr_arena_used(const DrArena *arena);

/* ---- content hashing (XXH3-128 from libxxhash) ---------------------------------------------- */

typedef struct DrHash { uint64_t hi, lo; } DrHash;
typedef struct DrHasher { void *state; } DrHasher;
DrHash dr_hash_bytes(const void *data, size_t size);
void dr_hasher_init(DrHasher *h);
void dr_hasher_update(DrHasher *h, const void *data, size_t size);
void dr_hasher_update_str(DrHasher *h, const char *s); /* includes the terminating NUL */
DrHash dr_hasher_final(DrHasher *h);                      /* also frees the state */
/* Hashes a file's bytes; DR_ERR_INPUT naming the file if it cannot be read. */
DR_NODISCARD DrStatus dr_hash_file(const char *path, DrHash *out, DrError *err);
/* 32 lowercase hex digits + NUL. */
void dr_hash_hex(DrHash h, char out[33]);

/* ---- timers ------------------------------------------------------------------------------ */

double dr_time_now(void); /* monotonic seconds */

/* ---- scratch space ------------------------------------------------------------------------ */

const char *dr_temp_dir(void); /* $TMPDIR when set and not empty, else /tmp (a farm's own scratch space) */

/* ---- parallel for ------------------------------------------------------------------------ */

/* Calls fn(begin, end, ctx) on disjoint ranges covering [0, count), in parallel over OpenMP
 * threads with a static schedule (so the split is a function of count, grain and the thread
 * count only). `grain` is the smallest range worth a thread. Reductions belong to the caller:
 * write per-range partials and sum them in range order for bit-identical results. */
typedef void (*DrRangeFn)(long begin, long end, void *ctx);
void dr_parallel_for(long count, long grain, DrRangeFn fn, void *ctx);
void dr_set_threads(int n); /* n <= 0: OpenMP's default */
/* How the parallel-for's threads wait at a barrier, by default: a short spin (GOMP_SPINCOUNT =
   DR_SPINCOUNT_DEFAULT iterations, a few microseconds), then sleep, so a process on a shared machine
   neither holds cores it does not use nor waits for woken threads at every barrier (sys.c has the
   measurements). OpenMP reads its settings once, before main, so when neither OMP_WAIT_POLICY nor
   GOMP_SPINCOUNT is set this sets GOMP_SPINCOUNT and starts the process again (execv of
   /proc/self/exe with argv): call it first thing in main, before any thread or file exists. Returns
   when the user set either variable, in the restarted process, and when the restart fails (the
   process then runs with OpenMP's defaults). */
#define DR_SPINCOUNT_DEFAULT "3000"
void dr_thread_defaults(char **argv);
/* How the threads wait, for logs: "GOMP_SPINCOUNT=3000", "OMP_WAIT_POLICY=active", ... (NUL-terminated). */
void dr_thread_wait_describe(char *buf, size_t size);
int dr_threads(void);

/* ---- rng ------------------------------------------------------------------------------------ */

/* xoshiro256** seeded by splitmix64; the whole state is 4 words so checkpoints can store it. */
typedef struct DrRng { uint64_t s[4]; } DrRng;
void dr_rng_seed(DrRng *rng, uint64_t seed);
uint64_t dr_rng_next(DrRng *rng);
double dr_rng_uniform(DrRng *rng); /* [0, 1) with 53 random bits */

#endif
