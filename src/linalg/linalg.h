/* drench linalg: square sparse matrices in CSR form, preconditioned conjugate gradients with an
 * inner-product hook, and two preconditioners (MIC(0) and Jacobi), plus the BLAS-1 helpers the
 * other modules share; a geometric multigrid V-cycle preconditioner for grid Poisson matrices; banded Cholesky (LAPACK) and sparse Cholesky (CHOLMOD).
 *
 * Determinism. Every reduction here (dr_dot, the norms and dot products inside dr_pcg_solve) splits
 * [0, n) into blocks whose size depends on n only, sums each block sequentially, and adds the block
 * partials in block order. The blocks are spread over threads with dr_parallel_for, so the result is
 * bit-identical for any thread count, not only for a given one. OpenBLAS's ddot/daxpy were not used:
 * their threaded reductions split work by thread count (results change with -j), and single-threaded
 * they give up the parallelism; a memory-bound dot product gains nothing from their kernels here.
 *
 * Thread safety: the functions may be called from several threads on distinct objects; one DrMic0 or
 * DrJacobi may be applied from several threads at once (application only reads it) as long as each
 * caller passes its own output vector. Nothing here allocates except create/reserve/update,
 * dr_pcg_solve with work == NULL, and a DrChol's analysis (see there). */
#ifndef DR_LINALG_H
#define DR_LINALG_H

#include "core/core.h"

/* ---- CSR matrices -------------------------------------------------------------------------- */

/* An n×n sparse matrix: row i holds the entries col[rowptr[i] .. rowptr[i+1]-1] with values val[...],
 * columns strictly increasing within a row, 0 <= col < n. rowptr has n+1 entries, rowptr[0] = 0 and
 * rowptr[n] = nnz. The owner fills rowptr/col/val and sets nnz (<= nnz_capacity) directly. */
typedef struct DrCsr {
    int n;
    int nnz;
    int *rowptr;
    int *col;
    double *val;
    int n_capacity;   /* rowptr holds n_capacity + 1 entries */
    int nnz_capacity; /* col and val hold nnz_capacity entries */
} DrCsr;

/* Creates the n×n zero matrix (nnz = 0, rowptr all zero) with room for nnz_capacity entries.
 * DR_ERR_INPUT for negative sizes, DR_ERR_NOMEM on exhaustion. */
DR_NODISCARD DrStatus dr_csr_create(int n, int nnz_capacity, DrCsr **out, DrError *err);
void dr_csr_destroy(DrCsr **A);
/* Reuses storage between substeps: makes A the n×n zero matrix (nnz = 0, rowptr zeroed) with room for at
 * least nnz_capacity entries; col/val contents are undefined. Reallocates only when the request exceeds
 * the current capacity (then grows by 1/4 extra to avoid reallocating every substep). On failure A
 * keeps its previous storage and contents. */
DR_NODISCARD DrStatus dr_csr_reserve(DrCsr *A, int n, int nnz_capacity, DrError *err);
/* Checks the structure (rowptr monotone from 0 to nnz, columns in range and strictly increasing per
 * row) and that every value is finite. DR_ERR_INPUT naming the first offending row/entry. O(nnz). */
DR_NODISCARD DrStatus dr_csr_check(const DrCsr *A, DrError *err);
/* y = A x (x and y of length n, not aliased), parallel over rows with dr_parallel_for; each row is
 * summed in column order, so y is bit-identical for any thread count. */
void dr_csr_matvec(const DrCsr *A, const double *x, double *y);

/* ---- linear operators ------------------------------------------------------------------------ */

/* Linear operator and preconditioner as callbacks so matrix-free operators fit too. */
typedef void (*DrApplyFn)(const double *x, double *y, void *ctx); /* y = Op(x), length n, x != y */
typedef struct DrLinearOp { int n; DrApplyFn apply; void *ctx; } DrLinearOp;
/* The operator x ↦ A x; A is borrowed and must outlive the returned value. */
DrLinearOp dr_csr_op(const DrCsr *A);

/* ---- preconditioned conjugate gradients ----------------------------------------------------- */

/* Inner-product hook: NULL means the Euclidean dot product (dr_dot). MPM passes the mass inner
 * product. CG needs A and M self-adjoint and positive (semi)definite in this inner product. */
typedef double (*DrDotFn)(const double *a, const double *b, int n, void *ctx);
typedef struct DrPcgDesc {
    double rel_tol; /* stop when ||r|| <= rel_tol * ||b|| (norm from the inner product); default 1e-6 */
    double abs_tol; /* also stop when ||r|| <= abs_tol; default 0 */
    int max_iter;   /* default 2000 */
    DrDotFn dot;    /* default NULL (Euclidean) */
    void *dot_ctx;  /* passed to dot; default NULL */
} DrPcgDesc;
void dr_pcg_desc_default(DrPcgDesc *d);

typedef struct DrPcgStats {
    int iterations;      /* operator applications after the initial residual */
    double residual;     /* ||r|| of the recursively updated residual when the solve stopped */
    double rel_residual; /* residual / ||b|| (0 when b = 0) */
    bool converged;
} DrPcgStats;

/* Solves A x = b by conjugate gradients preconditioned by M (M applies an approximation of A⁻¹).
 * x holds the initial guess on entry and the solution on exit. M may be NULL (unpreconditioned CG).
 * A->n (and M->n) must equal the length of b and x. desc NULL means dr_pcg_desc_default's values.
 *
 * Stopping: ||r|| <= max(rel_tol ||b||, abs_tol), tested on the initial residual too (a solution
 * passed as guess returns after 0 iterations). b = 0 sets x = 0 and returns DR_OK after 0 iterations:
 * zero is a solution for any A, also a singular one.
 * Singular A (pure Neumann Poisson): converges on the range of A when b is compatible (orthogonal to the
 * null space); x keeps the guess's null-space component plus rounding drift.
 *
 * Returns DR_OK when converged; DR_WARN_NOT_CONVERGED (positive) with stats and x filled with the last
 * iterate when max_iter is reached (the caller logs it; never aborts); DR_ERR_RUNTIME, with a message,
 * if b, the guess or an iterate holds a non-finite value, or on breakdown: pᵀAp <= 0 with a nonzero
 * residual (A not positive definite) or rᵀM r <= 0 (M not positive definite). On DR_ERR_RUNTIME x holds
 * the last iterate reached. stats (may be NULL) is filled in every case.
 *
 * `work` is optional scratch of 4n doubles (NULL: allocated and freed internally, DR_ERR_NOMEM on
 * exhaustion) so callers avoid allocations per step. b, x and work must not overlap. */
DR_NODISCARD DrStatus dr_pcg_solve(const DrLinearOp *A, const DrLinearOp *M, const double *b, double *x,
                                   const DrPcgDesc *desc, double *work, DrPcgStats *stats, DrError *err);

/* ---- MIC(0) preconditioner ------------------------------------------------------------------- */

/* Modified incomplete Cholesky, level 0 (Bridson, "Fluid Simulation for Computer Graphics", the MIC(0)
 * preconditioner of the pressure chapter):
 * M = Uᵀ D U with U unit upper triangular on the pattern of A's strict upper triangle. Built from the
 * lower triangle of A (entries with col <= row; the upper triangle is not read and must mirror it).
 * Works for any sparsity pattern: fill that lands on the pattern updates the factor as in IC(0); fill
 * off the pattern is dropped and tau times it is subtracted from the diagonal of both rows (tau = 1
 * keeps M's row sums equal to A's when no row falls back, tau = 0 is plain IC(0)).
 * Fallback: a row whose pivot d_j would fall below sigma * A_jj (in particular a non-positive pivot, as
 * the last row of a pure Neumann matrix gives) uses d_j = A_jj instead; dr_mic0_fallbacks counts them.
 * A row with a zero diagonal (a decoupled unknown) is preconditioned by the identity.
 * Application is a forward then a backward substitution: sequential, O(nnz), no allocation. */
typedef struct DrMic0 DrMic0;
#define DR_MIC0_TAU_DEFAULT 0.97
#define DR_MIC0_SIGMA_DEFAULT 0.25
/* tau in [0, 1], sigma in [0, 1]. DR_ERR_INPUT for parameters out of range, a matrix failing
 * dr_csr_check, or a negative diagonal entry (then A is not positive semidefinite); DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_mic0_create(const DrCsr *A, double tau, double sigma, DrMic0 **out, DrError *err);
/* Refactors in place for a new matrix (any n and pattern) with the same tau and sigma. No allocation
 * when n and the lower-triangle entry count fit the capacity reached so far; otherwise storage grows.
 * Failures as for create; on failure M must be updated successfully before it is applied again. */
DR_NODISCARD DrStatus dr_mic0_update(DrMic0 *M, const DrCsr *A, DrError *err);
void dr_mic0_destroy(DrMic0 **M);
/* The operator r ↦ M⁻¹ r; M is borrowed and must outlive the returned value. */
DrLinearOp dr_mic0_op(const DrMic0 *M);
/* Rows that used the diagonal fallback in the last factorisation. */
int dr_mic0_fallbacks(const DrMic0 *M);

/* ---- Jacobi preconditioner ------------------------------------------------------------------ */

/* M = diag(A); application r ↦ r_i / A_ii (parallel). A zero diagonal entry is preconditioned by the
 * identity. DR_ERR_INPUT for a matrix failing dr_csr_check or a negative diagonal entry; DR_ERR_NOMEM. */
typedef struct DrJacobi DrJacobi;
DR_NODISCARD DrStatus dr_jacobi_create(const DrCsr *A, DrJacobi **out, DrError *err);
/* Recomputes the diagonal for a new matrix; allocates only when A->n exceeds the capacity so far. */
DR_NODISCARD DrStatus dr_jacobi_update(DrJacobi *M, const DrCsr *A, DrError *err);
void dr_jacobi_destroy(DrJacobi **M);
DrLinearOp dr_jacobi_op(const DrJacobi *M);

/* ---- geometric multigrid preconditioner ------------------------------------------------------ */

/* A V-cycle of geometric multigrid for a symmetric 7-point cell-centred Poisson-type matrix whose rows are
 * cells of a regular dims[0] × dims[1] × dims[2] grid (any subset: the liquid of a pressure solve), as a
 * preconditioner for dr_pcg_solve. Row r sits in cell (i, j, k) = cell_ijk[3r .. 3r+2]; its off-diagonal
 * entries may only couple it to the rows of its 6 face neighbours (a missing entry is a closed, Neumann
 * face); the diagonal may exceed the sum of the couplings by Dirichlet terms (air, ghost-fluid θ weights).
 * Coefficients may vary per face (open fractions, porous scaling, 1/ρ_f).
 *
 * Hierarchy: cells coarsen 2×2×2 (a coarse cell exists where any of its children is a row; coarse rows in
 * increasing cell order) until a level has at most coarsest_rows rows. The coarse operator is the
 * piecewise-constant Galerkin product Pᵀ A P (P: every child takes its parent's value) times coarse_scale:
 * it sums the children's couplings across each coarse face and their Dirichlet terms, so every coefficient
 * variation and every boundary type carries to coarse levels without knowing where it came from, and stays
 * a 7-point stencil. Pᵀ A P overestimates a smooth error's energy by 2 in 3-D (the coarse faces are twice
 * as stiff as a rediscretisation on cells twice as large); coarse_scale 1/2 matches the rediscretised
 * operator and keeps the iteration count nearly flat in resolution (bench_pcg). Restriction Pᵀ sums the
 * children's residuals; prolongation P adds the parent's correction to each child.
 * Smoothing: `sweeps` red-black Gauss–Seidel sweeps (red then black) before the coarse correction and as
 * many in reverse order (black then red) after, from a zero guess; red = (i + j + k) even. The coarsest
 * level is solved by banded Cholesky (rows in cell order). The cycle is symmetric and positive definite
 * for any symmetric positive semidefinite A with a positive diagonal, as PCG needs.
 * Singular blocks (a pure-Neumann island: no Dirichlet term) are smoothed as they are; on the coarsest level
 * a Cholesky pivot that falls to 1e-10 of its diagonal entry or below is replaced by the diagonal entry
 * (dr_mg_fallbacks counts them), so PCG converges on a compatible right-hand side as with MIC(0).
 * A zero row (decoupled unknown) is preconditioned by the identity.
 *
 * Threads: smoothing, restriction, prolongation and the coarse operators run over rows with
 * dr_parallel_for; every value is computed by one row in a fixed order, so a V-cycle gives the same bits
 * for any thread count. One DrMg must not be applied from two threads at once (the cycle writes its coarse
 * vectors). Storage: O(rows + grid cells) over all levels (each level keeps a map of its grid). */
#define DR_MG_MAX_LEVELS 24
typedef struct DrMgDesc {
    int sweeps;          /* Gauss–Seidel sweeps before and after each coarse correction, [1, 64]; default 2 */
    int coarsest_rows;   /* coarsen until a level has at most this many rows, [1, 100000]; default 512 */
    double coarse_scale; /* factor on Pᵀ A P, (0, 1]; default 0.5 (see above) */
} DrMgDesc;
void dr_mg_desc_default(DrMgDesc *d);
typedef struct DrMg DrMg;
/* Builds the hierarchy for A (n rows, cell_ijk 3n ints, dims the grid). desc NULL means the defaults.
 * DR_ERR_INPUT for desc fields out of range, dims < 1, more rows than cells, a row outside the grid, two
 * rows in one cell, a broken CSR structure, an entry between cells that are not face neighbours, an
 * unsymmetric matrix (relative difference above 1e-12) or a negative diagonal, each naming the row;
 * DR_ERR_RUNTIME for a non-finite coefficient (naming the entry) or a non-finite coarse value;
 * DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_mg_create(const DrCsr *A, const int *cell_ijk, const int dims[3], const DrMgDesc *desc,
                                   DrMg **out, DrError *err);
/* Rebuilds the hierarchy for a new matrix (any rows, pattern and grid) with the same desc. Allocates
 * nothing when every level's rows and grid cells, and the coarsest band, fit the largest reached so far.
 * Failures as for create; on failure M must be updated successfully before it is applied again. */
DR_NODISCARD DrStatus dr_mg_update(DrMg *M, const DrCsr *A, const int *cell_ijk, const int dims[3], DrError *err);
void dr_mg_destroy(DrMg **M);
/* The operator r ↦ (one V-cycle from zero applied to r); M is borrowed and must outlive the value. */
DrLinearOp dr_mg_op(const DrMg *M);
/* Levels of the last update (1 = the matrix is solved directly), rows of one level (0 = finest; 0 out of
 * range), and the coarsest pivots replaced by their diagonal entry. */
int dr_mg_levels(const DrMg *M);
int dr_mg_rows(const DrMg *M, int level);
int dr_mg_fallbacks(const DrMg *M);

/* ---- banded symmetric positive definite systems ------------------------------------------------ */

/* A symmetric positive definite n×n matrix with bandwidth kd (A(i,j) = 0 for |i − j| > kd), such as the
 * block of one hair in the Lagrangian solve: factored by banded Cholesky (LAPACK dpbtrf through OpenBLAS,
 * O(n kd²)) and solved by forward and back substitution (O(n kd)). Storage is LAPACK's lower band, column-major:
 * ab[(i − j) + (kd + 1) j] = A(i, j) for j <= i <= min(n − 1, j + kd). One object per block; objects may
 * be used from different threads at once. */
typedef struct DrBanded {
    int n, kd;
    double *ab;    /* (kd + 1) × n */
    double *inv_diag; /* n: 1 / L_jj once factored (the substitutions multiply instead of dividing) */
    bool factored; /* ab holds the Cholesky factor L (A = L Lᵀ) */
} DrBanded;
/* n >= 1, 0 <= kd < n; DR_ERR_INPUT otherwise, DR_ERR_NOMEM. The matrix starts at zero. */
DR_NODISCARD DrStatus dr_banded_create(int n, int kd, DrBanded **out, DrError *err);
void dr_banded_destroy(DrBanded **b);
/* Sets the matrix back to zero (unfactored). */
void dr_banded_zero(DrBanded *b);
/* A(i, j) += v and, by symmetry, A(j, i); |i − j| <= kd (asserted). Only before dr_banded_factor. */
void dr_banded_add(DrBanded *b, int i, int j, double v);
/* Cholesky factorisation in place. A matrix that is not positive definite is DR_ERR_RUNTIME naming the
 * leading minor that fails; the contents are then unspecified until dr_banded_zero. */
DR_NODISCARD DrStatus dr_banded_factor(DrBanded *b, DrError *err);
/* Solves A X = B in place for nrhs right-hand sides stored one after another (x[n·r + i]); needs the
 * factor. */
void dr_banded_solve(const DrBanded *b, double *x, int nrhs);

/* ---- sparse symmetric positive definite systems (CHOLMOD) ---------------------------------------- */

/* A sparse symmetric positive definite n×n matrix factored by CHOLMOD (fill-reducing order by AMD; supernodal LLᵀ
 * with BLAS-3 kernels through OpenBLAS when the factor is dense enough, simplicial LDLᵀ otherwise), kept with its
 * symbolic analysis: a factorisation of the pattern analysed last reuses it, any other pattern is analysed anew. The
 * factor's bits depend on the matrix only (not on what was factored before). Such as a cluster of hairs joined by
 * contacts or bridges (src/lagrangian).
 * Memory: CHOLMOD's allocations go through SuiteSparse's allocator hooks, which the first dr_chol_create points at
 * linalg's own for the rest of the process (nothing else in drench calls SuiteSparse): every block is counted in
 * dr_alloc_count, and each DrChol recycles its own, so a factorisation on the pattern of the one before, and every
 * solve, allocate nothing. Threads: one DrChol is used by one thread at a time (its functions write its
 * workspace, solves included); distinct ones may be used from different threads at once. A factor and a solve
 * give the same bits on any thread and for any thread count (the BLAS run in one thread). */
typedef struct DrChol DrChol;
DR_NODISCARD DrStatus dr_chol_create(DrChol **out, DrError *err);
void dr_chol_destroy(DrChol **c);
/* The symbolic analysis alone (fill-reducing order, the factor's structure) of A's pattern, unless it is the pattern
 * analysed last; A as for dr_chol_factor (its values are not read). Then dr_chol_factor_entries tells what the
 * factor will hold before it is computed. DR_ERR_NOMEM on exhaustion, DR_ERR_RUNTIME if CHOLMOD fails otherwise. */
DR_NODISCARD DrStatus dr_chol_analyse(DrChol *c, const DrCsr *lower, DrError *err);
/* Whether A has the pattern analysed last (then factoring A needs no new analysis). */
bool dr_chol_analysed(const DrChol *c, const DrCsr *lower);
/* Factors A, given as its lower triangle by rows (columns <= row, increasing; n >= 1), analysing its pattern first
 * unless it is the pattern analysed last. DR_ERR_RUNTIME when A is not numerically positive definite (a pivot
 * not positive), DR_ERR_NOMEM on exhaustion; the factor is then unusable until a factorisation succeeds. */
DR_NODISCARD DrStatus dr_chol_factor(DrChol *c, const DrCsr *lower, DrError *err);
/* x ← A⁻¹ x (length n) with the last successful factorisation. */
void dr_chol_solve(DrChol *c, double *x);
/* Symbolic analyses so far (one per change of pattern), and the entries the factor of the pattern analysed last
 * holds (doubles; 0 before any analysis). */
int dr_chol_analyses(const DrChol *c);
double dr_chol_factor_entries(const DrChol *c);

/* ---- BLAS-1 (parallel, bit-identical for any thread count) ------------------------------------ */

double dr_dot(const double *a, const double *b, int n);  /* Σ a_i b_i in fixed block order */
void dr_axpy(double a, const double *x, double *y, int n); /* y += a x */

#endif
