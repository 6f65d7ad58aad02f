/* Cloth panels (src/cloth): three measurements, each a CSV and a markdown table. Timings are wall seconds
 * (dr_time_now), measured, never asserted.
 *
 *  1. Cantilever run time against error (cloth_cantilever.csv, next to the first csv). The plate of
 *     tests/validation/test_cloth: aluminium L = 0.2 m, b = 0.04 m, h = 1 mm, E = 7e10 Pa, ρ = 2700 kg/m³, ν = 0,
 *     clamped by pinning the first two columns of vertices, loaded by its weight, implicit steps of 0.05 s (CG to
 *     1e-12) until the mean tip deflection moves less than 1e-9 of the theory's in a step (400 at most). Theory:
 *     Kirchhoff's q Lf⁴/(8 D), q = ρ h g, D = E h³/12, Lf = L − a/2 (the clamp of two columns a apart holds the slope
 *     of the cell between them). nx = 6, 11, 21, 41, 81 vertices along, nz = round((nx − 1) b/L) + 1 across; both
 *     bending models (shape operator, per hinge) on both quad-split meshes (every diagonal one way: parallel;
 *     chessboard: alternating). One thread.
 *
 *  2. Banded against sparse Cholesky for one panel's matrix (cloth_factor.csv). A square panel of n × n vertices
 *     (n = 16, 32, 48, 64, 96; 1 m, parallel diagonals, the default material) and the SPD matrix the solver factors in
 *     a step of h = 1/480 s, rebuilt here from the kernels of src/cloth/shell.h:
 *         A = M + h² Σ_membrane JᵀC⁻¹J + h² Σ_bending JᵀC⁻¹J
 *     M the lumped mass; the membrane rows from dr_shell_membrane_group; the bending rows those of the default model
 *     (the discrete shape operator): each triangle's rows u_rᵀθ over its hinges' angles (dr_shell_bend_rest for u and
 *     C⁻¹, dr_shell_hinge_angle for ∇θ), over its three vertices and the wings across its interior edges, so the
 *     pattern is the solver's. The geometric stiffness is left out (it adds no entry to the pattern). Positions are
 *     the rest positions moved by up to ±0.5 % of the spacing in each direction (a fixed seed), so that strains,
 *     angles and the out-of-plane membrane terms are nonzero. DOFs are numbered by reverse Cuthill–McKee as
 *     src/cloth/cloth.c numbers them (dr_cloth_vertex_order; the band measured here is checked against dr_cloth_band).
 *     Banded: DrBanded with kd = 3·band + 2, LAPACK dpbtrf. Sparse: DrChol (CHOLMOD, AMD ordering, supernodal when
 *     it pays) on the lower triangle of the same matrix in CSR. Each time is the median of 5 (a fresh DrChol each
 *     time, so the analysis is timed too); entries: (kd + 1)·dofs for the band, dr_chol_factor_entries for CHOLMOD;
 *     the two solutions of one right-hand side are compared (relative 2-norm difference). One thread (the BLAS run
 *     in one thread in both).
 *
 *  3. A hanging sheet's step cost (the first csv, default out/bench/cloth.csv). A 0.5 m square of the default
 *     material, 32 × 32 and 64 × 64 vertices (the latter 7,938 triangles), horizontal at rest, pinned at the two
 *     corners of one edge, 20 steps of 1/480 s with dr_cloth_step on 1 and 2 threads: seconds per step (mean of the
 *     20; the first, which sizes the solver's buffers, also alone), CG iterations per step, and whether the
 *     positions after 2 threads are bit-identical to those after 1.
 *
 * usage: bench_cloth [csv = out/bench/cloth.csv] */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cloth/cloth.h"
#include "cloth/shell.h"
#include "core/core.h"
#include "linalg/linalg.h"

#include "../validation/cloth_grid.h"

static void die(const char *what, const DrError *err)
{
    if (err) dr_error_print("bench_cloth", err);
    else fprintf(stderr, "bench_cloth: %s\n", what);
    exit(1);
}

static void *xcalloc(size_t count, size_t size)
{
    void *p = calloc(count ? count : 1, size);
    if (!p) die("out of memory", NULL);
    return p;
}

static int cmp_double(const void *pa, const void *pb)
{
    double a = *(const double *)pa, b = *(const double *)pb;
    return a < b ? -1 : (a > b);
}

#define REPS 5
static double median(double t[REPS])
{
    qsort(t, REPS, sizeof t[0], cmp_double);
    return t[REPS / 2];
}

/* ==== 1. cantilever ============================================================================================= */

typedef struct Cantilever {
    int vertices, band, steps, unconverged;
    double seconds, ratio;
} Cantilever;

/* The cantilever of tests/validation/test_cloth.c, step for step. */
static Cantilever cantilever(int nx, DrClothBending bending, bool alternate)
{
    const double L = 0.2, b = 0.04, h = 1e-3, E = 7e10, rho = 2700, g = 9.81;
    int nz = (int)lround((nx - 1) * b / L) + 1;
    DrTriMesh m;
    if (cloth_grid_pattern(nx, nz, L, b, 0.0, alternate, &m) != 0) die("out of memory for the plate", NULL);
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    mat.density = rho, mat.thickness = h, mat.youngs_modulus = E, mat.poisson = 0.0, mat.damping = 0.0;
    mat.bending = bending;
    DrClothDesc desc;
    dr_cloth_desc_default(&desc);
    desc.solver.tol = 1e-12;
    DrCloth *c = NULL;
    DrError err;
    if (dr_cloth_create(&desc, &m, &mat, "plate", &c, &err) != DR_OK) die(NULL, &err);
    for (int k = 0; k < nz; k++)
        if (dr_cloth_pin(c, 0 + nx * k, true, NULL, &err) != DR_OK || dr_cloth_pin(c, 1 + nx * k, true, NULL, &err) != DR_OK)
            die(NULL, &err);
    double a = L / (nx - 1), Lf = L - 0.5 * a, D = E * h * h * h / 12.0, q = rho * h * g;
    double theory = q * Lf * Lf * Lf * Lf / (8.0 * D);
    Cantilever r = {.vertices = nx * nz, .band = dr_cloth_band(c)};
    double t0 = dr_time_now(), tip = 0, last = INFINITY;
    int steps = 0;
    for (; steps < 400; steps++) {
        DrClothStats st;
        DrStatus s = dr_cloth_step(c, 0.05, NULL, 0, &st, &err);
        if (s < 0) die(NULL, &err);
        if (s == DR_WARN_NOT_CONVERGED) r.unconverged++;
        tip = 0;
        for (int k = 0; k < nz; k++) tip -= dr_cloth_positions(c)[3 * (nx - 1 + nx * k) + 1];
        tip /= nz;
        if (fabs(tip - last) < 1e-9 * theory) break;
        last = tip;
    }
    r.seconds = dr_time_now() - t0;
    r.steps = steps + 1 < 400 ? steps + 1 : 400; /* steps taken (the loop breaks after the step that stopped) */
    r.ratio = tip / theory;
    dr_cloth_destroy(&c);
    dr_trimesh_free(&m);
    return r;
}

static void cantilever_sweep(const char *path)
{
    const int nxs[5] = {6, 11, 21, 41, 81};
    FILE *f = fopen(path, "w");
    if (!f) die("cannot write the cantilever csv", NULL);
    fprintf(f, "bending,pattern,nx,vertices,band,steps,seconds,seconds_per_step,tip_over_kirchhoff,rel_error\n");
    printf("### Cantilever: run time against error\n\n"
           "Aluminium plate 0.2 × 0.04 m, 1 mm, ν = 0, clamped by two pinned columns, steps of 0.05 s (CG tol 1e-12) "
           "until the tip stops; tip / Kirchhoff = mean tip deflection over q Lf⁴/(8D), Lf = L − a/2. One thread.\n\n"
           "| bending | pattern | nx | vertices | band | steps | seconds | s / step | tip / Kirchhoff | rel. error |\n"
           "|---|---|---|---|---|---|---|---|---|---|\n");
    fflush(stdout);
    int unconverged = 0;
    for (int bend = 0; bend < 2; bend++)
        for (int alt = 0; alt < 2; alt++)
            for (int i = 0; i < 5; i++) {
                DrClothBending model = bend ? DR_CLOTH_BEND_HINGE : DR_CLOTH_BEND_SHAPE_OPERATOR;
                const char *bname = bend ? "hinge" : "shape_operator", *pname = alt ? "alternating" : "parallel";
                Cantilever r = cantilever(nxs[i], model, alt == 1);
                unconverged += r.unconverged;
                double err = fabs(r.ratio - 1.0);
                fprintf(f, "%s,%s,%d,%d,%d,%d,%.6e,%.6e,%.6f,%.6e\n", bname, pname, nxs[i], r.vertices, r.band,
                        r.steps, r.seconds, r.seconds / r.steps, r.ratio, err);
                fflush(f);
                printf("| %s | %s | %d | %d | %d | %d | %.3g | %.2e | %.5f | %.2e |\n", bend ? "hinge" : "shape operator",
                       pname, nxs[i], r.vertices, r.band, r.steps, r.seconds, r.seconds / r.steps, r.ratio, err);
                fflush(stdout);
            }
    if (unconverged) printf("\n%d steps stopped at the CG cap (DR_WARN_NOT_CONVERGED).\n", unconverged);
    fclose(f);
}

/* ==== 2. banded against sparse factorisation ======================================================================== */

/* The panel's topology as src/cloth/cloth.c builds it: hinges (wing, edge, edge, wing; the first wing's triangle
   traverses the edge from its first to its second vertex), the hinge of each triangle's edge i (opposite vertex i, −1
   on the boundary), the edge graph (CSR) and each vertex's place in the panel's order (dr_cloth_vertex_order). */
typedef struct Topology {
    int V, T, H;
    const int *tri;
    int *hinge, *tri_hinge, *off, *nb, *rank;
    int band;
} Topology;

typedef struct HalfEdge { int lo, hi, tri, third, forward; } HalfEdge;

static int half_edge_cmp(const void *pa, const void *pb)
{
    const HalfEdge *a = pa, *b = pb;
    if (a->lo != b->lo) return a->lo < b->lo ? -1 : 1;
    if (a->hi != b->hi) return a->hi < b->hi ? -1 : 1;
    return a->tri < b->tri ? -1 : (a->tri > b->tri);
}


/* Triangle t's shape-operator group: its three vertices, then the wing across each interior edge. */
static int group_vertices(const Topology *tp, int t, int vs[6])
{
    int n = 0;
    for (int q = 0; q < 3; q++) vs[n++] = tp->tri[3 * t + q];
    for (int q = 0; q < 3; q++) {
        int k = tp->tri_hinge[3 * t + q];
        if (k < 0) continue;
        const int *hg = tp->hinge + 4 * k;
        int w = hg[0] == tp->tri[3 * t + q] ? hg[3] : hg[0];
        bool seen = false;
        for (int a = 0; a < n; a++) seen = seen || vs[a] == w;
        if (!seen) vs[n++] = w;
    }
    return n;
}

static void topology(const DrTriMesh *m, const int *order, Topology *tp)
{
    int V = tp->V = m->nv, T = tp->T = m->nt;
    tp->tri = m->tri;
    HalfEdge *he = xcalloc(3 * (size_t)T, sizeof *he);
    for (int t = 0; t < T; t++)
        for (int a = 0; a < 3; a++) {
            const int *tv = m->tri + 3 * t;
            int p = tv[a], q = tv[(a + 1) % 3];
            he[3 * t + a] = (HalfEdge){p < q ? p : q, p < q ? q : p, t, tv[(a + 2) % 3], p < q};
        }
    qsort(he, 3 * (size_t)T, sizeof *he, half_edge_cmp);
    tp->off = xcalloc((size_t)V + 1, sizeof(int));
    tp->nb = xcalloc(6 * (size_t)T, sizeof(int));
    tp->hinge = xcalloc(6 * (size_t)T, sizeof(int));
    tp->tri_hinge = xcalloc(3 * (size_t)T, sizeof(int));
    tp->rank = xcalloc((size_t)V, sizeof(int));
    for (int i = 0; i < 3 * T; i++) tp->tri_hinge[i] = -1;
    for (int i = 0; i < 3 * T;) {
        int j = i + 1;
        while (j < 3 * T && he[j].lo == he[i].lo && he[j].hi == he[i].hi) j++;
        tp->off[he[i].lo + 1]++;
        tp->off[he[i].hi + 1]++;
        i = j;
    }
    for (int v = 0; v < V; v++) tp->off[v + 1] += tp->off[v];
    int *fill = xcalloc((size_t)V + 1, sizeof(int));
    memcpy(fill, tp->off, (size_t)V * sizeof(int));
    int H = 0;
    for (int i = 0; i < 3 * T;) {
        int j = i + 1;
        while (j < 3 * T && he[j].lo == he[i].lo && he[j].hi == he[i].hi) j++;
        tp->nb[fill[he[i].lo]++] = he[i].hi;
        tp->nb[fill[he[i].hi]++] = he[i].lo;
        if (j - i == 2) {
            const HalfEdge *a = he[i].forward ? &he[i] : &he[i + 1], *b = he[i].forward ? &he[i + 1] : &he[i];
            int *hg = tp->hinge + 4 * H;
            hg[0] = a->third, hg[1] = a->lo, hg[2] = a->hi, hg[3] = b->third;
            for (int side = 0; side < 2; side++) {
                const HalfEdge *s = side ? b : a;
                for (int q = 0; q < 3; q++)
                    if (m->tri[3 * s->tri + q] == s->third) tp->tri_hinge[3 * s->tri + q] = H;
            }
            H++;
        }
        i = j;
    }
    tp->H = H;
    memcpy(tp->rank, order, (size_t)V * sizeof(int)); /* the panel's own vertex order */
    /* the band as cloth.c measures it for the shape-operator model: the widest spread of ranks within a group */
    tp->band = 0;
    for (int t = 0; t < T; t++) {
        int vs[6], n = group_vertices(tp, t, vs);
        for (int a = 0; a < n; a++)
            for (int b = a + 1; b < n; b++) {
                int d = abs(tp->rank[vs[a]] - tp->rank[vs[b]]);
                if (d > tp->band) tp->band = d;
            }
    }
    free(he);
    free(fill);
}

static void topology_free(Topology *tp)
{
    free(tp->off);
    free(tp->nb);
    free(tp->hinge);
    free(tp->tri_hinge);
    free(tp->rank);
}

/* The matrix in LAPACK's lower band storage (ab[(i − j) + (kd + 1) j] = A(i, j)) with a mark on every entry some
   group touches (the pattern CHOLMOD gets). */
typedef struct Assembly {
    int n, kd;
    double *ab;
    unsigned char *mark;
} Assembly;

static void assemble(Assembly *A, int i, int j, double v)
{
    if (i < j) {
        int t = i;
        i = j;
        j = t;
    }
    if (i - j > A->kd) die("a group spans more than the band", NULL);
    size_t k = (size_t)(i - j) + (size_t)(A->kd + 1) * (size_t)j;
    A->ab[k] += v;
    A->mark[k] = 1;
}

/* h² JᵀC⁻¹J of one group. */
static void assemble_group(Assembly *A, const DrLagGroup *g, double h)
{
    int nd = g->ndof;
    for (int a = 0; a < nd; a++)
        for (int b = 0; b <= a; b++) {
            double m = 0;
            for (int r = 0; r < g->nrows; r++) m += g->J[r * nd + a] * g->cinv[r] * g->J[r * nd + b];
            assemble(A, g->dof[a], g->dof[b], h * h * m);
        }
}

typedef struct FactorRow {
    int n, vertices, dofs, band, kd;
    double band_factor, band_solve, band_entries, chol_analyse, chol_factor, chol_solve, chol_entries, rel_diff;
} FactorRow;

static FactorRow factor_panel(int n)
{
    const double side = 1.0, h = 1.0 / 480;
    FactorRow row = {.n = n};
    DrTriMesh m;
    if (cloth_grid(n, n, side, side, 0.0, &m) != 0) die("out of memory for the panel", NULL);
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    DrCloth *c = NULL;
    DrError err;
    if (dr_cloth_create(NULL, &m, &mat, "panel", &c, &err) != DR_OK) die(NULL, &err);
    Topology tp;
    topology(&m, dr_cloth_vertex_order(c), &tp);
    if (tp.band != dr_cloth_band(c)) {
        fprintf(stderr, "bench_cloth: the band recomputed here (%d) is not dr_cloth_band's (%d) for %d x %d\n", tp.band,
                dr_cloth_band(c), n, n);
        exit(1);
    }
    int V = tp.V, N = 3 * V, kd = 3 * tp.band + 2;
    if (kd >= N) kd = N - 1;
    row.vertices = V, row.dofs = N, row.band = tp.band, row.kd = kd;

    /* 1. the step's positions: rest positions moved by up to ±0.5 % of the spacing */
    double spacing = side / (n - 1);
    double *x = xcalloc(3 * (size_t)V, sizeof(double));
    DrRng rng;
    dr_rng_seed(&rng, 20240601u + (uint64_t)n);
    for (int i = 0; i < 3 * V; i++) x[i] = m.v[i] + 0.01 * spacing * (dr_rng_uniform(&rng) - 0.5);

    /* 2. A = M + h² Σ JᵀC⁻¹J, DOFs 3 rank(v) + 0, 1, 2 */
    Assembly A = {N, kd, xcalloc((size_t)(kd + 1) * (size_t)N, sizeof(double)),
                  xcalloc((size_t)(kd + 1) * (size_t)N, 1)};
    const double *mass = dr_cloth_masses(c);
    for (int v = 0; v < V; v++)
        for (int d = 0; d < 3; d++) assemble(&A, 3 * tp.rank[v] + d, 3 * tp.rank[v] + d, mass[v]);
    double E = mat.youngs_modulus, nu = mat.poisson, th = mat.thickness;
    double k_membrane = E * th / (1.0 - nu * nu), k_bend = mat.bend_scale * E * th * th * th / (24.0 * (1.0 - nu * nu));
    DrLagGroup g;
    for (int t = 0; t < tp.T; t++) {
        const int *tv = m.tri + 3 * t;
        const double *X[3] = {m.v + 3 * tv[0], m.v + 3 * tv[1], m.v + 3 * tv[2]};
        double Bm[4], area;
        if (!dr_shell_rest(X[0], X[1], X[2], Bm, &area)) die("a degenerate triangle", NULL);
        /* membrane */
        int dof[3] = {3 * tp.rank[tv[0]], 3 * tp.rank[tv[1]], 3 * tp.rank[tv[2]]};
        dr_shell_membrane_group(x + 3 * tv[0], x + 3 * tv[1], x + 3 * tv[2], Bm, area, k_membrane, nu, dof, NULL, false, NULL,
                                &g);
        assemble_group(&A, &g, h);
        /* shape-operator bending: rows u_rᵀθ, J_r = Σ_i u_ri ∇θ_i over the group's vertices */
        bool interior[3];
        for (int q = 0; q < 3; q++) interior[q] = tp.tri_hinge[3 * t + q] >= 0;
        double u[9], cinv[3];
        int rows = dr_shell_bend_rest(X[0], X[1], X[2], area, interior, k_bend, nu, u, cinv);
        if (rows == 0) continue;
        int vs[6], nv = group_vertices(&tp, t, vs);
        memset(&g, 0, sizeof g);
        g.kind = DR_LAG_POSITIONAL;
        g.nrows = rows;
        g.ndof = 3 * nv;
        for (int a = 0; a < nv; a++)
            for (int d = 0; d < 3; d++) g.dof[3 * a + d] = 3 * tp.rank[vs[a]] + d;
        for (int r = 0; r < rows; r++) g.cinv[r] = cinv[r];
        for (int i = 0; i < 3; i++) {
            int k = tp.tri_hinge[3 * t + i];
            if (k < 0) continue;
            const int *hg = tp.hinge + 4 * k;
            double grad[12];
            dr_shell_hinge_angle(x + 3 * hg[0], x + 3 * hg[1], x + 3 * hg[2], x + 3 * hg[3], grad);
            for (int hv = 0; hv < 4; hv++) {
                int col = 0;
                while (vs[col] != hg[hv]) col++;
                for (int r = 0; r < rows; r++)
                    for (int d = 0; d < 3; d++) g.J[r * g.ndof + 3 * col + d] += u[3 * r + i] * grad[3 * hv + d];
            }
        }
        assemble_group(&A, &g, h);
    }

    /* 3. the lower triangle by rows for CHOLMOD: the marked entries */
    int nnz = 0;
    for (size_t k = 0; k < (size_t)(kd + 1) * (size_t)N; k++) nnz += A.mark[k];
    DrCsr *L = NULL;
    if (dr_csr_create(N, nnz, &L, &err) != DR_OK) die(NULL, &err);
    L->rowptr[0] = 0;
    for (int i = 0, e = 0; i < N; i++) {
        for (int j = i - kd > 0 ? i - kd : 0; j <= i; j++) {
            size_t k = (size_t)(i - j) + (size_t)(kd + 1) * (size_t)j;
            if (!A.mark[k]) continue;
            L->col[e] = j;
            L->val[e++] = A.ab[k];
        }
        L->rowptr[i + 1] = e;
    }
    L->nnz = nnz;

    /* 4. one right-hand side, both factorisations, both solves */
    double *b = xcalloc((size_t)N, sizeof(double)), *xb = xcalloc((size_t)N, sizeof(double));
    double *xc = xcalloc((size_t)N, sizeof(double));
    for (int i = 0; i < N; i++) b[i] = dr_rng_uniform(&rng) - 0.5;
    DrBanded *B = NULL;
    if (dr_banded_create(N, kd, &B, &err) != DR_OK) die(NULL, &err);
    double tf[REPS], ts[REPS], ta[REPS], tcf[REPS], tcs[REPS];
    for (int r = 0; r < REPS; r++) {
        dr_banded_zero(B);
        memcpy(B->ab, A.ab, (size_t)(kd + 1) * (size_t)N * sizeof(double));
        double t0 = dr_time_now();
        if (dr_banded_factor(B, &err) != DR_OK) die(NULL, &err);
        double t1 = dr_time_now();
        memcpy(xb, b, (size_t)N * sizeof(double));
        double t2 = dr_time_now();
        dr_banded_solve(B, xb, 1);
        double t3 = dr_time_now();
        tf[r] = t1 - t0, ts[r] = t3 - t2;
    }
    for (int r = 0; r < REPS; r++) {
        DrChol *ch = NULL;
        if (dr_chol_create(&ch, &err) != DR_OK) die(NULL, &err);
        double t0 = dr_time_now();
        if (dr_chol_analyse(ch, L, &err) != DR_OK) die(NULL, &err);
        double t1 = dr_time_now();
        if (dr_chol_factor(ch, L, &err) != DR_OK) die(NULL, &err);
        double t2 = dr_time_now();
        memcpy(xc, b, (size_t)N * sizeof(double));
        double t3 = dr_time_now();
        dr_chol_solve(ch, xc);
        double t4 = dr_time_now();
        ta[r] = t1 - t0, tcf[r] = t2 - t1, tcs[r] = t4 - t3;
        row.chol_entries = dr_chol_factor_entries(ch);
        if (dr_chol_analyses(ch) != 1) die("CHOLMOD analysed the pattern more than once", NULL);
        dr_chol_destroy(&ch);
    }
    row.band_factor = median(tf), row.band_solve = median(ts), row.band_entries = (double)(kd + 1) * N;
    row.chol_analyse = median(ta), row.chol_factor = median(tcf), row.chol_solve = median(tcs);
    double dd = 0, nn = 0;
    for (int i = 0; i < N; i++) dd += (xb[i] - xc[i]) * (xb[i] - xc[i]), nn += xc[i] * xc[i];
    row.rel_diff = sqrt(dd / nn);

    dr_banded_destroy(&B);
    dr_csr_destroy(&L);
    free(b);
    free(xb);
    free(xc);
    free(A.ab);
    free(A.mark);
    free(x);
    topology_free(&tp);
    dr_cloth_destroy(&c);
    dr_trimesh_free(&m);
    return row;
}

static void factor_sweep(const char *path)
{
    enum { NSIZES = 5 };
    const int ns[NSIZES] = {16, 32, 48, 64, 96};
    FILE *f = fopen(path, "w");
    if (!f) die("cannot write the factor csv", NULL);
    fprintf(f, "n,vertices,dofs,band_vertices,kd,band_factor_s,band_solve_s,band_entries,chol_analyse_s,chol_factor_s,"
               "chol_solve_s,chol_entries,solution_rel_diff\n");
    printf("\n### Banded against sparse Cholesky, one panel's step matrix\n\n"
           "n × n vertices (1 m, parallel diagonals, default material, h = 1/480 s), A = M + h² Σ JᵀC⁻¹J of the "
           "membrane and shape-operator bending rows, DOFs in the reverse Cuthill–McKee order of src/cloth. Banded: "
           "LAPACK dpbtrf, kd = 3 band + 2. CHOLMOD: AMD order, its own supernodal/simplicial choice. Median of %d; "
           "one thread.\n\n"
           "| n | vertices | DOFs | band (vertices) | kd | band factor s | band solve s | band entries | CHOLMOD "
           "analyse s | CHOLMOD factor s | CHOLMOD solve s | CHOLMOD entries | solutions' rel. diff. |\n"
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
           REPS);
    fflush(stdout);
    FactorRow rows[NSIZES];
    for (int i = 0; i < NSIZES; i++) {
        FactorRow r = rows[i] = factor_panel(ns[i]);
        fprintf(f, "%d,%d,%d,%d,%d,%.6e,%.6e,%.0f,%.6e,%.6e,%.6e,%.0f,%.3e\n", r.n, r.vertices, r.dofs, r.band, r.kd,
                r.band_factor, r.band_solve, r.band_entries, r.chol_analyse, r.chol_factor, r.chol_solve,
                r.chol_entries, r.rel_diff);
        fflush(f);
        printf("| %d | %d | %d | %d | %d | %.4f | %.5f | %.3g | %.4f | %.4f | %.5f | %.3g | %.1e |\n", r.n, r.vertices,
               r.dofs, r.band, r.kd, r.band_factor, r.band_solve, r.band_entries, r.chol_analyse, r.chol_factor,
               r.chol_solve, r.chol_entries, r.rel_diff);
        fflush(stdout);
    }
    fclose(f);
    /* the verdict, from the numbers above: a step factors its matrix once (the pattern, hence CHOLMOD's analysis,
       stays from step to step) and applies the factor once per CG iteration plus once for the initial guess */
    printf("\nMeasured, per size (factor; solve), banded against CHOLMOD:\n\n");
    bool band_wins[NSIZES];
    int nband = 0;
    for (int i = 0; i < NSIZES; i++) {
        const FactorRow *r = &rows[i];
        band_wins[i] = r->band_factor < r->chol_factor;
        nband += band_wins[i];
        printf("- %d × %d: factor %s by %.1f× (%.4f s against %.4f s; CHOLMOD's analysis, once per pattern, %.4f s); "
               "solve %s by %.1f×; %.1f× the entries %s\n",
               r->n, r->n, band_wins[i] ? "banded faster" : "CHOLMOD faster",
               band_wins[i] ? r->chol_factor / r->band_factor : r->band_factor / r->chol_factor, r->band_factor,
               r->chol_factor, r->chol_analyse, r->band_solve < r->chol_solve ? "banded faster" : "CHOLMOD faster",
               r->band_solve < r->chol_solve ? r->chol_solve / r->band_solve : r->band_solve / r->chol_solve,
               r->band_entries > r->chol_entries ? r->band_entries / r->chol_entries : r->chol_entries / r->band_entries,
               r->band_entries > r->chol_entries ? "in the band" : "in CHOLMOD's factor");
    }
    printf("\nA panel alone is one block of the solver, factored whole: its step needs one factorisation and one solve "
           "(CG then starts from the exact solution of the step's matrix). Factor + solve:");
    for (int i = 0; i < NSIZES; i++) {
        double band = rows[i].band_factor + rows[i].band_solve, chol = rows[i].chol_factor + rows[i].chol_solve;
        printf("%s %d × %d %s by %.1f×", i ? ";" : "", ns[i], ns[i], band < chol ? "banded" : "CHOLMOD",
               band < chol ? chol / band : band / chol);
    }
    printf(".\n");
    int split = 0; /* sizes [0, split) banded faster, [split, NSIZES) CHOLMOD faster, when the results fall so */
    while (split < NSIZES && band_wins[split]) split++;
    bool monotone = nband == split;
    if (split == NSIZES)
        printf("\nFactorisation: banded faster at every size measured, up to %d × %d.\n", ns[NSIZES - 1], ns[NSIZES - 1]);
    else if (nband == 0)
        printf("\nFactorisation: CHOLMOD faster at every size measured, from %d × %d.\n", ns[0], ns[0]);
    else if (monotone)
        printf("\nFactorisation: banded faster up to %d × %d, CHOLMOD faster from %d × %d on.\n", ns[split - 1],
               ns[split - 1], ns[split], ns[split]);
    else
        printf("\nFactorisation: no single crossover (the faster one alternates with size; see the rows above).\n");
}

/* ==== 3. a hanging sheet's step cost ================================================================================ */

typedef struct Hanging {
    int vertices, triangles, band, unconverged, it_max;
    double per_step, first_step, it_mean;
    double *x; /* positions after the steps, malloc'd */
} Hanging;

static Hanging hanging(int n, int threads, int steps)
{
    dr_set_threads(threads);
    DrTriMesh m;
    if (cloth_grid(n, n, 0.5, 0.5, 1.0, &m) != 0) die("out of memory for the sheet", NULL);
    DrClothMaterial mat;
    dr_cloth_material_default(&mat);
    DrCloth *c = NULL;
    DrError err;
    if (dr_cloth_create(NULL, &m, &mat, "sheet", &c, &err) != DR_OK) die(NULL, &err);
    if (dr_cloth_pin(c, 0, true, NULL, &err) != DR_OK || dr_cloth_pin(c, n - 1, true, NULL, &err) != DR_OK)
        die(NULL, &err);
    Hanging r = {.vertices = dr_cloth_vertex_count(c), .triangles = dr_cloth_triangle_count(c), .band = dr_cloth_band(c)};
    double total = 0;
    long its = 0;
    for (int s = 0; s < steps; s++) {
        DrClothStats st;
        double t0 = dr_time_now();
        DrStatus status = dr_cloth_step(c, 1.0 / 480, NULL, 0, &st, &err);
        double dt = dr_time_now() - t0;
        if (status < 0) die(NULL, &err);
        if (status == DR_WARN_NOT_CONVERGED) r.unconverged++;
        if (s == 0) r.first_step = dt;
        total += dt;
        its += st.iterations;
        if (st.iterations > r.it_max) r.it_max = st.iterations;
    }
    r.per_step = total / steps;
    r.it_mean = (double)its / steps;
    r.x = xcalloc(3 * (size_t)r.vertices, sizeof(double));
    memcpy(r.x, dr_cloth_positions(c), 3 * (size_t)r.vertices * sizeof(double));
    dr_cloth_destroy(&c);
    dr_trimesh_free(&m);
    dr_set_threads(0);
    return r;
}

static void step_cost(const char *path)
{
    const int ns[2] = {32, 64}, steps = 20;
    FILE *f = fopen(path, "w");
    if (!f) die("cannot write the step-cost csv", NULL);
    fprintf(f, "n,vertices,triangles,band,threads,steps,seconds_per_step,first_step_s,cg_iterations_mean,"
               "cg_iterations_max,unconverged_steps,bit_identical_to_1_thread\n");
    printf("\n### A hanging sheet's step cost\n\n"
           "0.5 m square, default material, pinned at two corners of one edge, %d steps of 1/480 s from rest "
           "(dr_cloth_step); s / step: mean over the %d steps; first step: the first alone (it sizes the solver's "
           "buffers).\n\n"
           "| n × n | vertices | triangles | band | threads | s / step | first step s | CG iterations / step (mean, "
           "max) | bit-identical to 1 thread |\n|---|---|---|---|---|---|---|---|---|\n",
           steps, steps);
    fflush(stdout);
    for (int i = 0; i < 2; i++) {
        Hanging one = {0};
        for (int threads = 1; threads <= 2; threads++) {
            Hanging r = hanging(ns[i], threads, steps);
            const char *same = "-";
            if (threads == 1) one = r;
            else same = memcmp(one.x, r.x, 3 * (size_t)r.vertices * sizeof(double)) == 0 ? "yes" : "no";
            fprintf(f, "%d,%d,%d,%d,%d,%d,%.6e,%.6e,%.2f,%d,%d,%s\n", ns[i], r.vertices, r.triangles, r.band, threads,
                    steps, r.per_step, r.first_step, r.it_mean, r.it_max, r.unconverged, same);
            fflush(f);
            printf("| %d × %d | %d | %d | %d | %d | %.4f | %.4f | %.1f, %d%s | %s |\n", ns[i], ns[i], r.vertices,
                   r.triangles, r.band, threads, r.per_step, r.first_step, r.it_mean, r.it_max,
                   r.unconverged ? " (cap reached)" : "", same);
            fflush(stdout);
            if (threads == 2) {
                free(one.x);
                free(r.x);
            }
        }
    }
    fclose(f);
}

/* cloth.csv → cloth_factor.csv */
static void sibling(const char *csv, const char *suffix, char *out, size_t size)
{
    size_t len = strlen(csv);
    if (len > 4 && strcmp(csv + len - 4, ".csv") == 0) len -= 4;
    if (len + strlen(suffix) + 1 > size) die("csv path too long", NULL);
    memcpy(out, csv, len);
    strcpy(out + len, suffix);
}

int main(int argc, char **argv)
{
    const char *csv = argc > 1 ? argv[1] : "out/bench/cloth.csv";
    char cantilever_csv[4096], factor_csv[4096];
    sibling(csv, "_cantilever.csv", cantilever_csv, sizeof cantilever_csv);
    sibling(csv, "_factor.csv", factor_csv, sizeof factor_csv);
    double t0 = dr_time_now();
    dr_set_threads(1);
    cantilever_sweep(cantilever_csv);
    factor_sweep(factor_csv);
    dr_set_threads(0);
    step_cost(csv);
    printf("\ntotal %.0f s\n", dr_time_now() - t0);
    return 0;
}
