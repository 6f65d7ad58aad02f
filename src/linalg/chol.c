/* Sparse Cholesky factorisation through CHOLMOD (see linalg.h, "sparse symmetric positive definite systems").
 *
 * Memory. CHOLMOD allocates through SuiteSparse's global hooks (SuiteSparse_config), which this file points at
 * allocators of its own the first time a DrChol is made. Each DrChol owns a pool: while one of its functions
 * runs, the calling thread's requests come from that pool, and what CHOLMOD frees goes back to it, so the next
 * factorisation of the same pattern finds every block it needs (CHOLMOD allocates a few per factorisation: the
 * update matrix of the supernodal kernel, the permuted copy of A) and nothing reaches the heap. New blocks come
 * from dr_calloc and are counted in dr_alloc_count; sizes are rounded up by at most a quarter so a slowly growing
 * pattern reuses them; a block left unused over two factorisations is released. Outside a DrChol call (no pool)
 * the hooks are counted heap blocks. Each block carries a 32-byte header (its pool, its capacity), so the free
 * hook can tell where it goes.
 *
 * Determinism. The numeric factorisation and the solves run the BLAS in one thread (OpenBLAS's own threads are
 * turned off, as for the banded factors: the callers run many factorisations in parallel), and CHOLMOD's OpenMP
 * loops are element-wise (clearing, scattering), so a factor and a solve give the same bits on any thread. The
 * ordering is AMD's alone: the default strategy may try METIS, whose allocations do not pass through the hooks. */
#include "linalg/linalg.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/cholmod.h>

/* ---- SuiteSparse's allocator ------------------------------------------------------------------------------------ */

typedef struct CholPool CholPool;
typedef struct PoolBlock {
    CholPool *pool;         /* owner; NULL: a block made outside any DrChol call, freed to the heap */
    struct PoolBlock *next; /* free list */
    size_t cap;             /* usable bytes after the header */
    unsigned long epoch;    /* the pool's epoch when the block was last handed out */
} PoolBlock;                /* 32 bytes: the payload keeps malloc's 16-byte alignment */

struct CholPool {
    PoolBlock *free;     /* blocks CHOLMOD gave back */
    unsigned long epoch; /* factorisations so far */
    size_t blocks;       /* blocks owned (handed out or free) */
    bool fresh;          /* hand out new blocks only (see dr_chol_factor) */
};

static _Thread_local CholPool *tls_pool; /* the pool of the DrChol call running on this thread, if any */

/* 64 bytes, then steps of a quarter: 64, 80, 100, 125, ... */
static size_t rounded(size_t size)
{
    size_t c = 64;
    while (c < size) c += c / 4;
    return c;
}

static void *block_new(CholPool *pool, size_t size)
{
    if (size > ((size_t)-1) / 2) return NULL;
    size_t cap = pool ? rounded(size) : size;
    PoolBlock *b = NULL;
    DrError e;
    if (dr_calloc(1, sizeof(PoolBlock) + cap, &b, &e) != DR_OK) return NULL;
    b->pool = pool;
    b->cap = cap;
    if (pool) {
        b->epoch = pool->epoch;
        pool->blocks++;
    }
    return b + 1;
}

static void *hook_malloc(size_t size)
{
    CholPool *p = tls_pool;
    if (size == 0) size = 1;
    if (!p) return block_new(NULL, size);
    if (p->fresh) return block_new(p, size);
    /* best fit among the free blocks */
    PoolBlock **best = NULL;
    for (PoolBlock **q = &p->free; *q; q = &(*q)->next)
        if ((*q)->cap >= size && (!best || (*q)->cap < (*best)->cap)) best = q;
    if (!best) return block_new(p, size);
    PoolBlock *b = *best;
    *best = b->next;
    b->next = NULL;
    b->epoch = p->epoch;
    return b + 1;
}

static void *hook_calloc(size_t count, size_t size)
{
    if (size && count > ((size_t)-1) / size) return NULL;
    void *q = hook_malloc(count * size);
    if (q) memset(q, 0, count * size);
    return q;
}

static void hook_free(void *q)
{
    if (!q) return;
    PoolBlock *b = (PoolBlock *)q - 1;
    if (!b->pool) {
        free(b);
        return;
    }
    b->next = b->pool->free;
    b->pool->free = b;
}

static void *hook_realloc(void *q, size_t size)
{
    if (!q) return hook_malloc(size);
    PoolBlock *b = (PoolBlock *)q - 1;
    if (size <= b->cap) return q;
    void *r = hook_malloc(size);
    if (!r) return NULL;
    memcpy(r, q, b->cap);
    hook_free(q);
    return r;
}

/* Releases the free blocks not handed out in this factorisation or the one before. */
static void pool_trim(CholPool *p)
{
    for (PoolBlock **q = &p->free; *q;) {
        PoolBlock *b = *q;
        if (b->epoch + 1 < p->epoch) {
            *q = b->next;
            free(b);
            p->blocks--;
        } else {
            q = &b->next;
        }
    }
}

extern void openblas_set_num_threads(int);
static pthread_once_t hooks_once = PTHREAD_ONCE_INIT;
static void install_hooks(void)
{
    SuiteSparse_config.malloc_func = hook_malloc;
    SuiteSparse_config.calloc_func = hook_calloc;
    SuiteSparse_config.realloc_func = hook_realloc;
    SuiteSparse_config.free_func = hook_free;
    openblas_set_num_threads(1); /* see banded.c: the callers factor many matrices in parallel themselves */
}

/* ---- DrChol --------------------------------------------------------------------------------------------------- */

struct DrChol {
    cholmod_common cc;
    CholPool pool;
    /* the analysed pattern: A's lower triangle by rows, which is CHOLMOD's upper triangle by columns */
    cholmod_sparse A;
    int n, n_cap;
    int *ap, *ai;
    double *ax;
    size_t nnz_cap;
    cholmod_factor *L;
    cholmod_dense *X, *Y, *E; /* cholmod_solve2's result and workspace, kept */
    double *zero;             /* n_cap zeros: the right-hand side of the solve that sizes X, Y, E */
    bool factored;
    int analyses;
    double entries; /* of the factor, from the analysis */
    bool sized;     /* X, Y, E sized for the factor analysed last */
};

DrStatus dr_chol_create(DrChol **out, DrError *err)
{
    pthread_once(&hooks_once, install_hooks);
    *out = NULL;
    DrChol *c = NULL;
    DR_TRY(dr_calloc(1, sizeof *c, &c, err));
    CholPool *saved = tls_pool;
    tls_pool = &c->pool;
    cholmod_start(&c->cc);
    tls_pool = saved;
    c->cc.print = 0; /* a matrix that is not positive definite is the caller's to report */
    c->cc.nmethods = 1;
    c->cc.method[0].ordering = CHOLMOD_AMD;
    c->cc.postorder = 1;
    /* supernodal (BLAS-3) when the factor is dense enough to pay for it (flops / entries >= 40), simplicial
       otherwise: a cluster of strands in sparse contact has a factor hardly larger than its matrix, whose supernodes
       of a few columns each make the supernodal solve 20-30 % slower per call */
    c->cc.supernodal = CHOLMOD_AUTO;
    c->cc.quick_return_if_not_posdef = 1;
    *out = c;
    return DR_OK;
}

void dr_chol_destroy(DrChol **cp)
{
    if (!cp || !*cp) return;
    DrChol *c = *cp;
    CholPool *saved = tls_pool;
    tls_pool = &c->pool;
    cholmod_free_factor(&c->L, &c->cc);
    cholmod_free_dense(&c->X, &c->cc);
    cholmod_free_dense(&c->Y, &c->cc);
    cholmod_free_dense(&c->E, &c->cc);
    cholmod_finish(&c->cc);
    tls_pool = saved;
    while (c->pool.free) {
        PoolBlock *b = c->pool.free;
        c->pool.free = b->next;
        free(b);
    }
    free(c->ap);
    free(c->ai);
    free(c->ax);
    free(c->zero);
    free(c);
    *cp = NULL;
}

/* Whether A has the analysed pattern. Equal patterns only, not a subset of the analysed one (which the factorisation
   could take with zeros): the factor's bits then depend on A alone, never on what was factored before. */
static bool on_pattern(const DrChol *c, const DrCsr *A)
{
    if (!c->L || A->n != c->n || A->rowptr[A->n] != c->ap[c->n]) return false;
    return memcmp(A->rowptr, c->ap, ((size_t)A->n + 1) * sizeof(int)) == 0 &&
           memcmp(A->col, c->ai, (size_t)A->rowptr[A->n] * sizeof(int)) == 0;
}

static DrStatus analyse(DrChol *c, const DrCsr *A, DrError *err)
{
    int n = A->n, nnz = A->rowptr[n];
    if (n + 1 > c->n_cap) {
        DR_TRY(dr_realloc((size_t)n + 1, sizeof(int), &c->ap, err));
        free(c->zero);
        c->zero = NULL;
        DR_TRY(dr_calloc((size_t)n + 1, sizeof(double), &c->zero, err));
        c->n_cap = n + 1;
    }
    if ((size_t)nnz > c->nnz_cap || !c->ai) {
        size_t cap = (size_t)nnz + (size_t)nnz / 4 + 1;
        DR_TRY(dr_realloc(cap, sizeof(int), &c->ai, err));
        DR_TRY(dr_realloc(cap, sizeof(double), &c->ax, err));
        c->nnz_cap = cap;
    }
    memcpy(c->ap, A->rowptr, ((size_t)n + 1) * sizeof(int));
    memcpy(c->ai, A->col, (size_t)nnz * sizeof(int));
    c->n = n;
    c->A = (cholmod_sparse){.nrow = (size_t)n, .ncol = (size_t)n, .nzmax = c->nnz_cap, .p = c->ap, .i = c->ai,
                            .x = c->ax, .stype = 1, .itype = CHOLMOD_INT, .xtype = CHOLMOD_REAL,
                            .dtype = CHOLMOD_DOUBLE, .sorted = 1, .packed = 1};
    cholmod_free_factor(&c->L, &c->cc);
    c->factored = c->sized = false;
    c->L = cholmod_analyze(&c->A, &c->cc);
    c->analyses++;
    if (!c->L) {
        c->entries = 0;
        return dr_error_set(err, c->cc.status == CHOLMOD_OUT_OF_MEMORY ? DR_ERR_NOMEM : DR_ERR_RUNTIME, NULL, 0, 0,
                            "sparse Cholesky analysis of a %d x %d matrix with %d entries failed (CHOLMOD status %d)",
                            n, n, nnz, c->cc.status);
    }
    /* what the numeric factor will hold: a supernodal one its supernodes whole, a simplicial one its nonzeros */
    c->entries = c->L->is_super ? (double)c->L->xsize : c->cc.lnz;
    return DR_OK;
}

bool dr_chol_analysed(const DrChol *c, const DrCsr *A) { return on_pattern(c, A); }

DrStatus dr_chol_analyse(DrChol *c, const DrCsr *A, DrError *err)
{
    assert(A->n >= 1);
    if (on_pattern(c, A)) return DR_OK;
    CholPool *saved = tls_pool;
    tls_pool = &c->pool;
    DrStatus st = analyse(c, A, err);
    tls_pool = saved;
    return st;
}

DrStatus dr_chol_factor(DrChol *c, const DrCsr *A, DrError *err)
{
    assert(A->n >= 1);
    CholPool *saved = tls_pool;
    tls_pool = &c->pool;
    c->pool.epoch++;
    DrStatus st = DR_OK;
    if (!on_pattern(c, A)) st = analyse(c, A, err);
    if (st == DR_OK) {
        memcpy(c->ax, A->val, (size_t)A->rowptr[A->n] * sizeof(double));
        c->factored = false;
        int ok = cholmod_factorize(&c->A, c->L, &c->cc);
        if (!ok || c->cc.status < CHOLMOD_OK)
            st = dr_error_set(err, c->cc.status == CHOLMOD_OUT_OF_MEMORY ? DR_ERR_NOMEM : DR_ERR_RUNTIME, NULL, 0, 0,
                              "sparse Cholesky factorisation of a %d x %d matrix failed (CHOLMOD status %d)", A->n,
                              A->n, c->cc.status);
        else if (c->cc.status == CHOLMOD_NOT_POSDEF)
            st = dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                              "the %d x %d matrix is not positive definite (pivot %d of the fill-reducing order)",
                              A->n, A->n, (int)c->L->minor);
        else
            c->factored = true;
        if (c->factored && !c->L->is_ll) {
            /* a simplicial LDLᵀ factor stops at a zero pivot only: a negative one is an indefinite matrix too */
            const int *Lp = c->L->p;
            const double *Lx = c->L->x;
            for (int j = 0; j < c->n && c->factored; j++)
                if (!(Lx[Lp[j]] > 0)) {
                    c->factored = false;
                    st = dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                      "the %d x %d matrix is not positive definite (pivot %d of the fill-reducing order)",
                                      A->n, A->n, j);
                }
        }
    }
    if (c->factored && !c->sized) {
        /* a first solve sizes cholmod_solve2's result and workspace, so that dr_chol_solve cannot fail; they are kept,
           so they take new blocks: taking the blocks the factorisation just gave back would leave the next one to
           allocate again */
        cholmod_dense B = {.nrow = (size_t)c->n, .ncol = 1, .nzmax = (size_t)c->n, .d = (size_t)c->n, .x = c->zero,
                           .xtype = CHOLMOD_REAL, .dtype = CHOLMOD_DOUBLE};
        c->pool.fresh = true;
        int ok = cholmod_solve2(CHOLMOD_A, c->L, &B, NULL, &c->X, NULL, &c->Y, &c->E, &c->cc);
        c->pool.fresh = false;
        if (!ok) {
            c->factored = false;
            st = dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                              "out of memory for the workspace of a sparse Cholesky solve (%d unknowns)", c->n);
        }
        c->sized = c->factored;
    }
    pool_trim(&c->pool);
    tls_pool = saved;
    return st;
}

void dr_chol_solve(DrChol *c, double *x)
{
    assert(c->factored);
    CholPool *saved = tls_pool;
    tls_pool = &c->pool;
    cholmod_dense B = {.nrow = (size_t)c->n, .ncol = 1, .nzmax = (size_t)c->n, .d = (size_t)c->n, .x = x,
                       .xtype = CHOLMOD_REAL, .dtype = CHOLMOD_DOUBLE};
    int ok = cholmod_solve2(CHOLMOD_A, c->L, &B, NULL, &c->X, NULL, &c->Y, &c->E, &c->cc);
    assert(ok); /* the sizes were checked by the factorisation; its workspace is kept */
    (void)ok;
    memcpy(x, c->X->x, (size_t)c->n * sizeof(double));
    tls_pool = saved;
}

int dr_chol_analyses(const DrChol *c) { return c->analyses; }

double dr_chol_factor_entries(const DrChol *c) { return c->L ? c->entries : 0; }
