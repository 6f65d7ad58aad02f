/* drench bem: surface meshes of BEM bodies: validity check, welding, rigid-body properties, the frame
 * operators of BEM eq. (10), shape-matching weights (BEM §3.2.1), a spatially coherent vertex order
 * (BEM §3.3) and generated test meshes. */
#include "bem/bem.h"
#include "bem_internal.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

/* Coordinates of vertex i of mesh m, and the three numbers for a "(%g, %g, %g)" format. */
#define VTX(m, i) ((m)->v + 3 * (size_t)(i))
#define XYZ(p) (p)[0], (p)[1], (p)[2]

static void sub3(const double *a, const double *b, double *out)
{
    out[0] = a[0] - b[0];
    out[1] = a[1] - b[1];
    out[2] = a[2] - b[2];
}

static void cross3(const double *a, const double *b, double *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static double dist2(const double *a, const double *b)
{
    double d[3];
    sub3(a, b, d);
    return dot3(d, d);
}

/* Centre of the axis-aligned bounds and the length of their diagonal; (0, 0) for an empty mesh. A reference
 * point inside the body keeps the signed-volume sums free of the cancellation that coordinates far from the
 * origin would cause. */
static void bounds_centre(const DrTriMesh *m, double centre[3], double *diagonal)
{
    DrVec3 lo, hi;
    if (!dr_trimesh_bounds(m, &lo, &hi)) {
        centre[0] = centre[1] = centre[2] = 0.0;
        *diagonal = 0.0;
        return;
    }
    centre[0] = 0.5 * (lo.x + hi.x);
    centre[1] = 0.5 * (lo.y + hi.y);
    centre[2] = 0.5 * (lo.z + hi.z);
    *diagonal = dr_v3_norm(dr_v3_sub(hi, lo));
}

/* Signed volume (positive for outward counter-clockwise winding), summed as tetrahedra from `ref`. */
static double signed_volume(const DrTriMesh *m, const double ref[3])
{
    double vol = 0.0;
    for (int t = 0; t < m->nt; t++) {
        const int *f = m->tri + 3 * (size_t)t;
        double a[3], b[3], c[3], bc[3];
        sub3(VTX(m, f[0]), ref, a);
        sub3(VTX(m, f[1]), ref, b);
        sub3(VTX(m, f[2]), ref, c);
        cross3(b, c, bc);
        vol += dot3(a, bc);
    }
    return vol / 6.0;
}

/* ---- validity check ------------------------------------------------------------------------------- */

/* A triangle counts as zero-area when twice its area is below this fraction of its longest edge squared,
 * i.e. its height over the longest edge is below 1e-10 of that edge: zero up to the double round-off of
 * coordinates up to 10⁴ times the triangle's size. Its normal is then undefined and the boundary integrals,
 * which need the normal and divide by the area in the singular rules, are meaningless. */
#define ZERO_AREA_REL 1e-10

/* One triangle side, for sorting sides into edges: key = (lower vertex << 32) | higher vertex. */
typedef struct HalfEdge {
    uint64_t key;
    int32_t t, k; /* triangle and corner: the side runs from corner k to corner k+1 */
} HalfEdge;

static int half_edge_cmp(const void *pa, const void *pb)
{
    const HalfEdge *a = pa, *b = pb;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    if (a->t != b->t) return a->t < b->t ? -1 : 1;
    return (a->k > b->k) - (a->k < b->k);
}

/* Union-find over triangle corners; the smaller index becomes the root, so the structure (and which
 * vertex is reported) depends on the mesh only. */
static int uf_find(int *parent, int x)
{
    while (parent[x] != x) {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    return x;
}

static void uf_union(int *parent, int a, int b)
{
    a = uf_find(parent, a);
    b = uf_find(parent, b);
    if (a < b)
        parent[b] = a;
    else if (b < a)
        parent[a] = b;
}

static int corner_of(const int *f, int v)
{
    for (int c = 0; c < 3; c++)
        if (f[c] == v) return c;
    return -1;
}

/* The edge problems found by one pass over the sorted sides. Examples are the first in edge-key order. */
typedef struct EdgeReport {
    long open, nonmanifold, inconsistent;
    int open_a, open_b;
    int nm_a, nm_b, nm_count;
    int inc_a, inc_b;
} EdgeReport;

/* Plural endings for counts in messages. */
static const char *s_(long n) { return n == 1 ? "" : "s"; }

DrStatus dr_bem_mesh_check(const DrTriMesh *m, const char *path, DrError *err)
{
    const int nv = m->nv, nt = m->nt;
    /* 1. size: a tetrahedron is the smallest closed triangle surface */
    if (nt < 4)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "mesh has %d triangles and %d vertices; a BEM body must be a closed, watertight surface, "
                            "which needs at least 4 triangles (a tetrahedron); export the whole closed body, not a "
                            "single face or an open sheet",
                            nt, nv);

    if (nt > INT_MAX / 3)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "mesh has %d triangles, more than drench handles (%d); decimate it", nt, INT_MAX / 3);

    /* 2. indices, finite coordinates, triangles that repeat a vertex */
    for (int t = 0; t < nt; t++)
        for (int c = 0; c < 3; c++) {
            int v = m->tri[3 * (size_t)t + c];
            if (v < 0 || v >= nv)
                return dr_error_set(
                    err, DR_ERR_INPUT, path, 0, 0,
                    "triangle %d refers to vertex %d (1-based) but the mesh has %d vertices; the mesh is "
                    "corrupt, export it again",
                    t + 1, v + 1, nv);
        }
    for (int i = 0; i < nv; i++) {
        const double *p = VTX(m, i);
        if (!(isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2])))
            return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                                "vertex %d (1-based) has a non-finite coordinate (%g, %g, %g); fix the asset so every "
                                "vertex position is a finite number",
                                i + 1, XYZ(p));
    }
    long repeated = 0;
    int rep_t = -1;
    for (int t = 0; t < nt; t++) {
        const int *f = m->tri + 3 * (size_t)t;
        if (f[0] == f[1] || f[1] == f[2] || f[0] == f[2]) {
            if (repeated++ == 0) rep_t = t;
        }
    }
    if (repeated > 0) {
        const int *f = m->tri + 3 * (size_t)rep_t;
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "%ld triangle%s %s the same vertex twice, e.g. triangle %d (1-based vertices %d, %d, %d); "
                            "a BEM body must be a closed surface of proper triangles, and such a triangle has no area "
                            "and no normal; weld the mesh and delete the collapsed faces",
                            repeated, s_(repeated), repeated == 1 ? "uses" : "use", rep_t + 1, f[0] + 1, f[1] + 1,
                            f[2] + 1);
    }

    int *first = NULL, *parent = NULL;
    HalfEdge *he = NULL;
    const size_t ns = 3 * (size_t)nt;
    DrStatus st = dr_calloc((size_t)nv, sizeof(int), &first, err);
    if (st == DR_OK) st = dr_calloc(ns, sizeof(int), &parent, err);
    if (st == DR_OK) st = dr_calloc(ns, sizeof(HalfEdge), &he, err);
    if (st != DR_OK) goto done;

    /* 3. unused vertices: each vertex is one BEM node, and a node on no triangle has empty matrix rows */
    for (size_t s = 0; s < ns; s++) first[m->tri[s]] = 1;
    long unused = 0;
    int unused_v = -1;
    for (int i = 0; i < nv; i++)
        if (!first[i] && unused++ == 0) unused_v = i;
    if (unused > 0) {
        st = dr_error_set(
            err, DR_ERR_INPUT, path, 0, 0,
            "%ld vert%s %s used by no triangle, e.g. vertex %d (1-based) at (%g, %g, %g); every vertex of "
            "a BEM body is a node of the closed surface, and a loose vertex makes the boundary matrices "
            "singular; weld / remove unreferenced vertices",
            unused, unused == 1 ? "ex" : "ices", unused == 1 ? "is" : "are", unused_v + 1, XYZ(VTX(m, unused_v)));
        goto done;
    }

    /* 4. zero-area triangles */
    long zero = 0;
    int zero_t = -1;
    for (int t = 0; t < nt; t++) {
        const int *f = m->tri + 3 * (size_t)t;
        double e0[3], e1[3], e2[3], n[3];
        sub3(VTX(m, f[1]), VTX(m, f[0]), e0);
        sub3(VTX(m, f[2]), VTX(m, f[0]), e1);
        sub3(VTX(m, f[2]), VTX(m, f[1]), e2);
        cross3(e0, e1, n);
        double lmax2 = fmax(dot3(e0, e0), fmax(dot3(e1, e1), dot3(e2, e2)));
        if (sqrt(dot3(n, n)) <= ZERO_AREA_REL * lmax2 && zero++ == 0) zero_t = t;
    }
    if (zero > 0) {
        const int *f = m->tri + 3 * (size_t)zero_t;
        st = dr_error_set(
            err, DR_ERR_INPUT, path, 0, 0,
            "%ld zero-area triangle%s (collinear corners), e.g. triangle %d with vertices %d, %d, %d (1-based) "
            "at (%g, %g, %g), (%g, %g, %g), (%g, %g, %g); a BEM body must be a closed surface of proper "
            "triangles, since the boundary integrals need each triangle's normal and area; dissolve the "
            "degenerate faces (e.g. Blender: Mesh > Clean Up > Degenerate Dissolve)",
            zero, s_(zero), zero_t + 1, f[0] + 1, f[1] + 1, f[2] + 1, XYZ(VTX(m, f[0])), XYZ(VTX(m, f[1])),
            XYZ(VTX(m, f[2])));
        goto done;
    }

    /* 5. edges: sorting the 3M sides by their vertex pair groups each edge's triangles, O(M log M) */
    for (int t = 0; t < nt; t++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = (uint32_t)m->tri[3 * (size_t)t + k], b = (uint32_t)m->tri[3 * (size_t)t + (k + 1) % 3];
            uint32_t lo = a < b ? a : b, hi = a < b ? b : a;
            HalfEdge h = {((uint64_t)lo << 32) | hi, t, k};
            he[3 * (size_t)t + k] = h;
        }
    qsort(he, ns, sizeof *he, half_edge_cmp);
    for (size_t s = 0; s < ns; s++) parent[s] = (int)s;
    EdgeReport r = {0};
    for (size_t s = 0; s < ns;) {
        size_t e = s + 1;
        while (e < ns && he[e].key == he[s].key) e++;
        int a = (int)(he[s].key >> 32), b = (int)(he[s].key & 0xffffffffu);
        size_t count = e - s;
        if (count == 1) {
            if (r.open++ == 0) r.open_a = a, r.open_b = b;
        } else if (count >= 3) {
            if (r.nonmanifold++ == 0) r.nm_a = a, r.nm_b = b, r.nm_count = (int)count;
        } else {
            /* Two sides: opposite directions when consistently oriented. Either way the two triangles are
             * neighbours in the fans of both end vertices. */
            const int *f1 = m->tri + 3 * (size_t)he[s].t, *f2 = m->tri + 3 * (size_t)he[s + 1].t;
            int d1 = f1[he[s].k], d2 = f2[he[s + 1].k]; /* start vertex of each side */
            if (d1 == d2 && r.inconsistent++ == 0) r.inc_a = a, r.inc_b = b;
            uf_union(parent, 3 * he[s].t + corner_of(f1, a), 3 * he[s + 1].t + corner_of(f2, a));
            uf_union(parent, 3 * he[s].t + corner_of(f1, b), 3 * he[s + 1].t + corner_of(f2, b));
        }
        s = e;
    }
    if (r.nonmanifold > 0) {
        char also[96] = ""; /* a fin of extra faces usually leaves open edges as well */
        if (r.open > 0)
            snprintf(also, sizeof also, " (the mesh also has %ld open boundary edge%s)", r.open, s_(r.open));
        st = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                          "%ld non-manifold edge%s (shared by 3 or more triangles), e.g. between vertices %d and %d "
                          "(1-based) at (%g, %g, %g) and (%g, %g, %g), shared by %d triangles%s; a BEM body must be a "
                          "closed, watertight surface that separates inside from outside, which fails where more than "
                          "two faces meet; remove internal faces or separate the parts that touch along the edge",
                          r.nonmanifold, s_(r.nonmanifold), r.nm_a + 1, r.nm_b + 1, XYZ(VTX(m, r.nm_a)),
                          XYZ(VTX(m, r.nm_b)), r.nm_count, also);
        goto done;
    }
    if (r.open > 0) {
        st = dr_error_set(
            err, DR_ERR_INPUT, path, 0, 0,
            "mesh is not closed: %ld open boundary edge%s (used by one triangle only), e.g. between vertices "
            "%d and %d (1-based) at (%g, %g, %g) and (%g, %g, %g); a BEM body must be a closed, watertight "
            "surface; fill the holes, or weld vertices split along seams, and export again",
            r.open, s_(r.open), r.open_a + 1, r.open_b + 1, XYZ(VTX(m, r.open_a)), XYZ(VTX(m, r.open_b)));
        goto done;
    }

    /* 6. vertices: with every edge shared by two triangles, the triangles around a vertex form one or more
     * closed fans; more than one (two bodies touching at a point) is not a surface locally like a disc. */
    for (int i = 0; i < nv; i++) first[i] = -1;
    long nm_vertices = 0;
    int nm_v = -1;
    for (size_t s = 0; s < ns; s++) {
        int v = m->tri[s], root = uf_find(parent, (int)s);
        if (first[v] == -1)
            first[v] = root;
        else if (first[v] >= 0 && first[v] != root) {
            first[v] = -2; /* counted */
            if (nm_vertices++ == 0 || v < nm_v) nm_v = v;
        }
    }
    if (nm_vertices > 0) {
        st = dr_error_set(
            err, DR_ERR_INPUT, path, 0, 0,
            "%ld non-manifold vert%s (where separate sheets of the surface touch at a point), e.g. vertex "
            "%d (1-based) at (%g, %g, %g); a BEM body must be a closed, watertight surface that is locally a "
            "disc at every vertex; separate the touching parts or split the vertex",
            nm_vertices, nm_vertices == 1 ? "ex" : "ices", nm_v + 1, XYZ(VTX(m, nm_v)));
        goto done;
    }

    /* 7. orientation */
    if (r.inconsistent > 0) {
        st = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                          "triangle winding is inconsistent: %ld edge%s %s traversed in the same direction by both of "
                          "%s triangles, e.g. between vertices %d and %d (1-based) at (%g, %g, %g) and (%g, %g, %g), "
                          "so some faces are flipped; a BEM body needs every normal pointing out of the body; make the "
                          "normals consistent (e.g. Blender: Mesh > Normals > Recalculate Outside)",
                          r.inconsistent, s_(r.inconsistent), r.inconsistent == 1 ? "is" : "are",
                          r.inconsistent == 1 ? "its" : "their", r.inc_a + 1, r.inc_b + 1, XYZ(VTX(m, r.inc_a)),
                          XYZ(VTX(m, r.inc_b)));
        goto done;
    }

    /* 8. outward: the enclosed signed volume is positive for counter-clockwise winding seen from outside */
    double ref[3], diag;
    bounds_centre(m, ref, &diag);
    double vol = signed_volume(m, ref);
    if (fabs(vol) <= 1e-12 * diag * diag * diag) {
        st = dr_error_set(
            err, DR_ERR_INPUT, path, 0, 0,
            "the surface encloses no volume (signed volume %g m^3 within bounds of diagonal %g m), e.g. two "
            "shells of opposite orientation; a BEM body must be a closed surface around material; export "
            "a solid body with outward normals",
            vol, diag);
        goto done;
    }
    if (vol < 0.0) {
        st = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                          "normals point inward (signed volume %g m^3 < 0); a BEM body needs outward normals, with "
                          "triangles counter-clockwise seen from outside; flip the winding (reverse every face, e.g. "
                          "Blender: Mesh > Normals > Flip)",
                          vol);
        goto done;
    }

done:
    free(first);
    free(parent);
    free(he);
    return st;
}

/* ---- welding ---------------------------------------------------------------------------------------- */

typedef struct CellKey {
    uint64_t key; /* cell coordinates, 21 bits each */
    int idx;
} CellKey;

static int cell_key_cmp(const void *pa, const void *pb)
{
    const CellKey *a = pa, *b = pb;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    return (a->idx > b->idx) - (a->idx < b->idx);
}

#define CELL_BITS 21
#define CELL_MAX ((int64_t)1 << CELL_BITS)

static uint64_t pack_cell(const int64_t c[3])
{
    return ((uint64_t)c[0] << (2 * CELL_BITS)) | ((uint64_t)c[1] << CELL_BITS) | (uint64_t)c[2];
}

/* Vertices are sorted by grid cell (cell size ≥ tol), so every vertex within tol of vertex i lies in the 27
 * cells around i's; sorting rather than hashing keeps the pass deterministic without a hash function to tune.
 * Vertices are visited in index order and each joins the lowest-indexed earlier vertex that was kept and lies
 * within tol; so kept vertices keep their position and every merged vertex moved by at most tol (chains of
 * vertices each within tol of the next are not collapsed into one). */
DrStatus dr_bem_mesh_weld(DrTriMesh *m, double tol, int *removed, DrError *err)
{
    *removed = 0;
    if (!(tol >= 0.0) || !isfinite(tol))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "weld tolerance is %g; it must be a finite distance >= 0 (0 joins only equal positions)",
                            tol);
    const int nv = m->nv;
    for (int i = 0; i < nv; i++) {
        const double *p = VTX(m, i);
        if (!(isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2])))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "vertex %d (1-based) has a non-finite coordinate (%g, %g, %g); fix the asset so every "
                                "vertex position is a finite number",
                                i + 1, XYZ(p));
    }
    for (size_t s = 0; s < 3 * (size_t)m->nt; s++)
        if (m->tri[s] < 0 || m->tri[s] >= nv)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "triangle %zu refers to vertex %d (1-based) but the mesh has %d vertices; the mesh is "
                                "corrupt, export it again",
                                s / 3 + 1, m->tri[s] + 1, nv);

    CellKey *keys = NULL;
    int *rep = NULL, *newidx = NULL;
    DrStatus st = dr_calloc((size_t)nv, sizeof(CellKey), &keys, err);
    if (st == DR_OK) st = dr_calloc((size_t)nv, sizeof(int), &rep, err);
    if (st == DR_OK) st = dr_calloc((size_t)nv, sizeof(int), &newidx, err);
    if (st != DR_OK) goto done;

    /* 1. representatives */
    DrVec3 lo = {0, 0, 0}, hi = {0, 0, 0};
    dr_trimesh_bounds(m, &lo, &hi);
    double ext = fmax(hi.x - lo.x, fmax(hi.y - lo.y, hi.z - lo.z));
    /* Cells no smaller than ext/2^20 keep the coordinates within 21 bits; cells larger than tol only add
     * candidates, never lose one, and a hair larger keeps the rounding of the division from putting a pair at
     * distance exactly tol two cells apart. */
    double h = fmax(tol * (1.0 + 1e-9), ext / (double)(CELL_MAX / 2));
    if (!(h > 0.0)) h = 1.0;
    const double lo3[3] = {lo.x, lo.y, lo.z};
    for (int i = 0; i < nv; i++) {
        int64_t c[3];
        for (int a = 0; a < 3; a++) {
            c[a] = (int64_t)floor((VTX(m, i)[a] - lo3[a]) / h);
            if (c[a] >= CELL_MAX) c[a] = CELL_MAX - 1;
        }
        keys[i].key = pack_cell(c);
        keys[i].idx = i;
    }
    qsort(keys, (size_t)nv, sizeof *keys, cell_key_cmp);
    const double tol2 = tol * tol;
    for (int i = 0; i < nv; i++) {
        int64_t c[3];
        for (int a = 0; a < 3; a++) {
            c[a] = (int64_t)floor((VTX(m, i)[a] - lo3[a]) / h);
            if (c[a] >= CELL_MAX) c[a] = CELL_MAX - 1;
        }
        int best = i;
        for (int d = 0; d < 27; d++) {
            int64_t q[3] = {c[0] + d % 3 - 1, c[1] + (d / 3) % 3 - 1, c[2] + d / 9 - 1};
            if (q[0] < 0 || q[1] < 0 || q[2] < 0 || q[0] >= CELL_MAX || q[1] >= CELL_MAX || q[2] >= CELL_MAX) continue;
            uint64_t key = pack_cell(q);
            size_t l = 0, u = (size_t)nv; /* first entry with key >= key */
            while (l < u) {
                size_t mid = l + (u - l) / 2;
                if (keys[mid].key < key)
                    l = mid + 1;
                else
                    u = mid;
            }
            for (size_t s = l; s < (size_t)nv && keys[s].key == key && keys[s].idx < best; s++) {
                int j = keys[s].idx;
                if (rep[j] == j && dist2(VTX(m, i), VTX(m, j)) <= tol2) {
                    best = j; /* the cell lists indices in increasing order: the first hit is its lowest */
                    break;
                }
            }
        }
        rep[i] = best;
    }

    /* 2. remap triangles and drop those that collapsed */
    int nt = 0;
    for (int t = 0; t < m->nt; t++) {
        int f[3];
        for (int c = 0; c < 3; c++) f[c] = rep[m->tri[3 * (size_t)t + c]];
        if (f[0] == f[1] || f[1] == f[2] || f[0] == f[2]) continue;
        memcpy(m->tri + 3 * (size_t)nt, f, sizeof f);
        nt++;
    }

    /* 3. drop unreferenced vertices, keeping the survivors in their original relative order */
    for (int i = 0; i < nv; i++) newidx[i] = -1;
    for (size_t s = 0; s < 3 * (size_t)nt; s++) newidx[m->tri[s]] = 0;
    int kept = 0;
    for (int i = 0; i < nv; i++) {
        if (newidx[i] < 0) continue;
        newidx[i] = kept;
        if (kept != i) memmove(VTX(m, kept), VTX(m, i), 3 * sizeof(double)); /* kept ≤ i: forward copy is safe */
        kept++;
    }
    for (size_t s = 0; s < 3 * (size_t)nt; s++) m->tri[s] = newidx[m->tri[s]];
    m->nt = nt;
    m->nv = kept;
    free(m->n);
    m->n = NULL;
    free(m->uv); /* per-corner texture coordinates would not follow the triangles dropped above */
    m->uv = NULL;
    *removed = nv - kept;

done:
    free(keys);
    free(rep);
    free(newidx);
    return st;
}

/* ---- rigid-body properties ------------------------------------------------------------------------- */

typedef struct RmaxCtx {
    const double *v;
    int nv;
    double centre[3];
    double radius; /* max |x_j − centre| */
    double best2;  /* squared result; starts at a lower bound that a real pair attains */
} RmaxCtx;

/* Row pairs k and nv−1−k give every range about the same number of distances. A row i can only beat the
 * lower bound L if |x_i − c| + max_j |x_j − c| > L (triangle inequality), which skips most rows of elongated
 * bodies. The maximum is exact, so merging the ranges' results in any order gives the same answer. */
static void rmax_rows(long begin, long end, void *ctx_)
{
    RmaxCtx *ctx = ctx_;
    double start2;
#pragma omp critical(dr_bem_rmax)
    start2 = ctx->best2;
    double best2 = start2;
    const double lower = sqrt(start2);
    for (long k = begin; k < end; k++) {
        int rows[2] = {(int)k, ctx->nv - 1 - (int)k};
        for (int r = 0; r < (rows[1] == rows[0] ? 1 : 2); r++) {
            int i = rows[r];
            const double *xi = ctx->v + 3 * (size_t)i;
            if ((sqrt(dist2(xi, ctx->centre)) + ctx->radius) * (1.0 + 1e-12) < lower) continue;
            for (int j = i + 1; j < ctx->nv; j++) {
                double d2 = dist2(xi, ctx->v + 3 * (size_t)j);
                if (d2 > best2) best2 = d2;
            }
        }
    }
#pragma omp critical(dr_bem_rmax)
    if (best2 > ctx->best2) ctx->best2 = best2;
}

static double farthest_from(const DrTriMesh *m, int from, int *at)
{
    double best = -1.0;
    for (int j = 0; j < m->nv; j++) {
        double d2 = dist2(VTX(m, from), VTX(m, j));
        if (d2 > best) best = d2, *at = j;
    }
    return best;
}

/* Largest vertex-to-vertex distance, exact, by all pairs: O(N²), measured 0.15 s for 10k and 2.6 s for 41k
 * vertices of a sphere (where no row is skipped) on two threads; small beside assembling the (3N)² dense
 * matrices the body is built for. */
static double max_vertex_distance(const DrTriMesh *m)
{
    if (m->nv < 2) return 0.0;
    RmaxCtx ctx = {m->v, m->nv, {0, 0, 0}, 0.0, 0.0};
    double diag;
    bounds_centre(m, ctx.centre, &diag);
    for (int j = 0; j < m->nv; j++) ctx.radius = fmax(ctx.radius, sqrt(dist2(VTX(m, j), ctx.centre)));
    /* Lower bound by alternating farthest-point sweeps (often the exact answer already). */
    int p = 0, q = 0;
    for (int sweep = 0; sweep < 3; sweep++) {
        double d2 = farthest_from(m, p, &q);
        if (d2 > ctx.best2) ctx.best2 = d2;
        p = q;
    }
    dr_parallel_for((m->nv + 1) / 2, 64, rmax_rows, &ctx);
    return sqrt(ctx.best2);
}

/* Volume, first and second moments as sums over the signed tetrahedra (ref, a, b, c) of the triangles: the
 * divergence-theorem integrals of Mirtich (1996) in their equivalent tetrahedral form, exact for polyhedra.
 * For a tetrahedron with one corner at the origin and the others a, b, c (det = a·(b×c)):
 *   ∫ dV = det/6,  ∫ x dV = det/24 (a+b+c),  ∫ x xᵀ dV = det/120 (a aᵀ + b bᵀ + c cᵀ + s sᵀ), s = a+b+c. */
void dr_bem_body_compute(const DrTriMesh *m, double density, DrBemBody *out)
{
    memset(out, 0, sizeof *out);
    double ref[3], diag;
    bounds_centre(m, ref, &diag);
    double vol6 = 0.0, first[3] = {0, 0, 0}, second[9] = {0};
    for (int t = 0; t < m->nt; t++) {
        const int *f = m->tri + 3 * (size_t)t;
        double a[3], b[3], c[3], bc[3], s[3];
        sub3(VTX(m, f[0]), ref, a);
        sub3(VTX(m, f[1]), ref, b);
        sub3(VTX(m, f[2]), ref, c);
        cross3(b, c, bc);
        double det = dot3(a, bc);
        for (int i = 0; i < 3; i++) s[i] = a[i] + b[i] + c[i];
        vol6 += det;
        for (int i = 0; i < 3; i++) first[i] += det * s[i];
        for (int i = 0; i < 3; i++)
            for (int j = i; j < 3; j++)
                second[3 * i + j] += det * (a[i] * a[j] + b[i] * b[j] + c[i] * c[j] + s[i] * s[j]);
    }
    double vol = vol6 / 6.0;
    out->volume = vol;
    out->mass = density * vol;
    double d[3] = {0, 0, 0}; /* x̄ − ref */
    if (vol != 0.0)
        for (int i = 0; i < 3; i++) d[i] = first[i] / 24.0 / vol;
    for (int i = 0; i < 3; i++) out->centroid[i] = ref[i] + d[i];
    /* P = ∫ (x − x̄)(x − x̄)ᵀ dV = ∫ (x − ref)(x − ref)ᵀ dV − V d dᵀ; I = ρ (tr P · Id − P). */
    double P[9];
    for (int i = 0; i < 3; i++)
        for (int j = i; j < 3; j++) P[3 * i + j] = P[3 * j + i] = second[3 * i + j] / 120.0 - vol * d[i] * d[j];
    double tr = P[0] + P[4] + P[8];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) out->inertia[3 * i + j] = density * ((i == j ? tr : 0.0) - P[3 * i + j]);
    out->r_max = max_vertex_distance(m);
}

/* ---- frame operators and vertex areas ------------------------------------------------------------- */

/* Exact integrals over a linear triangle T of area A_T with corners y_a, y_b, y_c:
 *   ∫_T Φ_a dΓ = A_T/3,   ∫_T y Φ_a dΓ = A_T/12 (2 y_a + y_b + y_c).
 * Positions are taken relative to x̄ throughout. For C this is the definition (y − x̄); for w it makes the
 * weights independent of where the mesh sits in its file's coordinates (with absolute y they would turn
 * negative on one side of a body placed away from the origin); Σ_j w_j = ∫ (y − x̄)·n dΓ = 3V either way.
 * As (y − x̄)·n is constant on a flat triangle, w_j is the sum over the vertex's triangles T of the volumes
 * of the cones (x̄, T): the vertex's share of the body's volume when each cone is counted at its three
 * corners, positive for a body star-shaped about x̄. */
void dr_bem_frame_operators(const DrTriMesh *m, const DrBemBody *b, double *A, double *C, double *w)
{
    const int nv = m->nv;
    const size_t n = 3 * (size_t)nv;
    memset(A, 0, 3 * n * sizeof *A);
    memset(C, 0, 3 * n * sizeof *C);
    memset(w, 0, (size_t)nv * sizeof *w);
    /* Accumulate ∫Φ_j in A[0][3j] and q_j = ∫ (y − x̄) Φ_j dΓ in C[0][3j..3j+2]: each vertex's 3×3 blocks
     * are written from them afterwards, so no scratch is needed. */
    for (int t = 0; t < m->nt; t++) {
        const int *f = m->tri + 3 * (size_t)t;
        double r[3][3], e0[3], e1[3], cr[3], s[3];
        for (int c = 0; c < 3; c++) sub3(VTX(m, f[c]), b->centroid, r[c]);
        sub3(r[1], r[0], e0);
        sub3(r[2], r[0], e1);
        cross3(e0, e1, cr); /* 2 A_T n */
        double area = 0.5 * sqrt(dot3(cr, cr));
        for (int i = 0; i < 3; i++) s[i] = r[0][i] + r[1][i] + r[2][i];
        for (int c = 0; c < 3; c++) {
            double y[3] = {r[c][0] + s[0], r[c][1] + s[1], r[c][2] + s[2]}; /* 2 y_a + y_b + y_c */
            size_t j = (size_t)f[c];
            A[3 * j] += area / 3.0;
            for (int i = 0; i < 3; i++) C[3 * j + i] += area / 12.0 * y[i];
            w[j] += dot3(cr, y) / 24.0; /* n·(A_T/12)(2y_a + y_b + y_c), A_T n = cr/2 */
        }
    }
    double Iinv[9];
    bool ok = dr_m3a_inverse(b->inertia, Iinv);
    assert(ok && "dr_bem_frame_operators: singular inertia; the body was not computed from a checked mesh");
    (void)ok;
    const double inv_mass = 1.0 / b->mass;
    for (size_t j = 0; j < (size_t)nv; j++) {
        double a = A[3 * j], q[3] = {C[3 * j], C[3 * j + 1], C[3 * j + 2]};
        /* A[a][3j+b] = δ_ab ∫Φ_j / m */
        A[3 * j] = 0.0;
        for (int i = 0; i < 3; i++) A[i * n + 3 * j + i] = a * inv_mass;
        /* α = I⁻¹ Σ_j q_j × p_j = I⁻¹ Σ_j [q_j]× p_j, [q]× = ((0, −q_z, q_y), (q_z, 0, −q_x), (−q_y, q_x, 0)) */
        const double X[9] = {0.0, -q[2], q[1], q[2], 0.0, -q[0], -q[1], q[0], 0.0};
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)
                C[r * n + 3 * j + c] = Iinv[3 * r] * X[c] + Iinv[3 * r + 1] * X[3 + c] + Iinv[3 * r + 2] * X[6 + c];
    }
}

void dr_bem_vertex_areas(const DrTriMesh *m, double *area)
{
    memset(area, 0, (size_t)m->nv * sizeof *area);
    for (int t = 0; t < m->nt; t++) {
        const int *f = m->tri + 3 * (size_t)t;
        double e0[3], e1[3], cr[3];
        sub3(VTX(m, f[1]), VTX(m, f[0]), e0);
        sub3(VTX(m, f[2]), VTX(m, f[0]), e1);
        cross3(e0, e1, cr);
        double third = sqrt(dot3(cr, cr)) / 6.0;
        for (int c = 0; c < 3; c++) area[f[c]] += third;
    }
}

/* ---- vertex order ------------------------------------------------------------------------------------
 * BEM §3.3 reorders vertices with the cache-oblivious layouts of [YLPM05] so that vertices close together
 * get close indices, which makes neighbouring matrix rows and columns similar and the Haar coefficients
 * small. What the compression needs is that locality only, not the cache-miss metric [YLPM05] optimises
 * over the connectivity graph with a multilevel partitioner; a 3-D Hilbert curve gives it from positions
 * alone, deterministically and in O(N log N). Hilbert rather than Morton order: consecutive Hilbert cells
 * always share a face, so the order never jumps across the body between neighbours in the sequence.
 * The proximity is Euclidean, not along the surface: the two faces of a thin plate are interleaved. */

#define HILBERT_BITS 16 /* 65536 cells per axis of the bounding cube */

/* Index along the Hilbert curve of the cell x[0..2] (each < 2^HILBERT_BITS), by Skilling's transposed form
 * (AIP Conf. Proc. 707, 2004): the coordinates are turned into the curve's "transposed index" by undoing
 * the rotations and reflections level by level and Gray-encoding the result, whose bits, interleaved most
 * significant first, are the index. */
static uint64_t hilbert_index(uint32_t x[3])
{
    const uint32_t top = 1u << (HILBERT_BITS - 1);
    for (uint32_t q = top; q > 1; q >>= 1) {
        const uint32_t low = q - 1;
        for (int i = 0; i < 3; i++) {
            if (x[i] & q) {
                x[0] ^= low; /* reflect */
            } else {
                uint32_t swap = (x[0] ^ x[i]) & low; /* exchange low bits of x[0] and x[i] */
                x[0] ^= swap;
                x[i] ^= swap;
            }
        }
    }
    x[1] ^= x[0];
    x[2] ^= x[1];
    uint32_t flip = 0;
    for (uint32_t q = top; q > 1; q >>= 1)
        if (x[2] & q) flip ^= q - 1;
    for (int i = 0; i < 3; i++) x[i] ^= flip;
    uint64_t key = 0;
    for (int bit = HILBERT_BITS - 1; bit >= 0; bit--)
        for (int i = 0; i < 3; i++) key = (key << 1) | ((x[i] >> bit) & 1u);
    return key;
}

typedef struct OrderCtx {
    const double *v;
    double lo[3];
    double scale; /* cells per metre: 2^bits / (largest extent), the same on all axes */
} OrderCtx;

static uint64_t vertex_key(const OrderCtx *c, int i)
{
    const uint32_t cmax = (1u << HILBERT_BITS) - 1;
    uint32_t q[3];
    for (int a = 0; a < 3; a++) {
        double t = (c->v[3 * (size_t)i + a] - c->lo[a]) * c->scale;
        q[a] = !(t > 0.0) ? 0u : (t >= (double)cmax ? cmax : (uint32_t)t);
    }
    return hilbert_index(q);
}

static bool key_before(uint64_t ka, int a, uint64_t kb, int b) { return ka < kb || (ka == kb && a < b); }

/* Heap sort on (key, index), a total order, so the result is unique. The keys are recomputed on the fly
 * (two per level of a sift) because this function has no way to report a failed allocation for them:
 * measured 0.07 s for 10k and 1.4 s for 164k vertices, against the hours the dense matrices of such bodies
 * take to assemble. */
static void sift_down(const OrderCtx *c, int *order, int root, int end)
{
    int v = order[root];
    uint64_t kv = vertex_key(c, v);
    for (;;) {
        int child = 2 * root + 1;
        if (child >= end) break;
        uint64_t kc = vertex_key(c, order[child]);
        if (child + 1 < end) {
            uint64_t k2 = vertex_key(c, order[child + 1]);
            if (key_before(kc, order[child], k2, order[child + 1])) child++, kc = k2;
        }
        if (!key_before(kv, v, kc, order[child])) break;
        order[root] = order[child];
        root = child;
    }
    order[root] = v;
}

void dr_bem_vertex_order(const DrTriMesh *m, int *order)
{
    const int nv = m->nv;
    for (int i = 0; i < nv; i++) order[i] = i;
    DrVec3 lo, hi;
    if (!dr_trimesh_bounds(m, &lo, &hi)) return;
    double ext = fmax(hi.x - lo.x, fmax(hi.y - lo.y, hi.z - lo.z));
    if (!(ext > 0.0)) return; /* one point: input order */
    /* A cube rather than the box keeps cells isotropic, so that nearness along the curve means the same
     * distance on every axis. */
    OrderCtx c = {m->v, {lo.x, lo.y, lo.z}, (double)(1u << HILBERT_BITS) / ext};
    for (int i = nv / 2 - 1; i >= 0; i--) sift_down(&c, order, i, nv);
    for (int end = nv - 1; end > 0; end--) {
        int t = order[0];
        order[0] = order[end];
        order[end] = t;
        sift_down(&c, order, 0, end);
    }
}

/* ---- generated meshes ------------------------------------------------------------------------------ */

/* Edge → midpoint vertex, open addressing; vertex numbers follow the order triangles are visited, so the
 * table's layout does not affect the mesh. */
typedef struct MidCache {
    uint64_t *key; /* (lo << 32 | hi) + 1; 0 = empty */
    int *val;
    size_t cap; /* power of two */
} MidCache;

static int mid_vertex(MidCache *mc, double *v, int *nv, int a, int b)
{
    uint32_t lo = (uint32_t)(a < b ? a : b), hi = (uint32_t)(a < b ? b : a);
    uint64_t key = (((uint64_t)lo << 32) | hi) + 1;
    size_t h = (size_t)((key * 0x9e3779b97f4a7c15ULL) >> 17) & (mc->cap - 1);
    while (mc->key[h] != 0) {
        if (mc->key[h] == key) return mc->val[h];
        h = (h + 1) & (mc->cap - 1);
    }
    int k = (*nv)++;
    double *p = v + 3 * (size_t)k;
    for (int i = 0; i < 3; i++) p[i] = 0.5 * (v[3 * (size_t)a + i] + v[3 * (size_t)b + i]);
    double len = sqrt(dot3(p, p));
    for (int i = 0; i < 3; i++) p[i] /= len;
    mc->key[h] = key;
    mc->val[h] = k;
    return k;
}

#define ICO_MAX_LEVEL 12 /* 20·4^12 triangles: 3·nt still fits an int */

DrStatus dr_bem_mesh_icosphere(int level, double radius, double bump, double freq, DrTriMesh *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    if (level < 0 || level > ICO_MAX_LEVEL)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "icosphere level %d is out of range; use 0 to %d (20·4^level triangles)", level,
                            ICO_MAX_LEVEL);
    if (!(radius > 0.0) || !isfinite(radius))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "icosphere radius %g must be a finite length > 0", radius);
    if (!(fabs(bump) < 1.0) || !isfinite(freq))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "icosphere bump %g and frequency %g: the bump must lie in (-1, 1) (a fraction of the "
                            "radius, so the surface stays around the centre) and the frequency be finite",
                            bump, freq);
    const int nv_final = 10 * (1 << (2 * level)) + 2, nt_final = 20 * (1 << (2 * level));
    MidCache mc = {0};
    int *tri2 = NULL;
    DrStatus st = dr_calloc(3 * (size_t)nv_final, sizeof(double), &out->v, err);
    if (st == DR_OK) st = dr_calloc(3 * (size_t)nt_final, sizeof(int), &out->tri, err);
    if (st == DR_OK) st = dr_calloc(3 * (size_t)nt_final, sizeof(int), &tri2, err);
    size_t edges_last = 3 * (size_t)nt_final / 8; /* edges of the level subdivided last */
    mc.cap = 64;
    while (mc.cap < 2 * edges_last) mc.cap *= 2;
    if (st == DR_OK && level > 0) st = dr_calloc(mc.cap, sizeof(uint64_t), &mc.key, err);
    if (st == DR_OK && level > 0) st = dr_calloc(mc.cap, sizeof(int), &mc.val, err);
    if (st != DR_OK) goto done;

    /* 1. icosahedron: the 12 cyclic permutations of (0, ±1, ±φ); faces are the triples at mutual distance 2,
     * wound counter-clockwise seen from outside (a·(b×c) > 0 for a body around the origin). */
    const double phi = 0.5 * (1.0 + sqrt(5.0));
    double base[12][3];
    int nb = 0;
    for (int perm = 0; perm < 3; perm++)
        for (int s1 = -1; s1 <= 1; s1 += 2)
            for (int s2 = -1; s2 <= 1; s2 += 2) {
                double p[3] = {0.0, s1 * 1.0, s2 * phi};
                for (int i = 0; i < 3; i++) base[nb][(i + perm) % 3] = p[i];
                nb++;
            }
    int nt = 0;
    for (int i = 0; i < 12; i++)
        for (int j = i + 1; j < 12; j++)
            for (int k = j + 1; k < 12; k++) {
                if (fabs(dist2(base[i], base[j]) - 4.0) > 1e-9 || fabs(dist2(base[j], base[k]) - 4.0) > 1e-9 ||
                    fabs(dist2(base[i], base[k]) - 4.0) > 1e-9)
                    continue;
                double bc[3];
                cross3(base[j], base[k], bc);
                int *f = out->tri + 3 * (size_t)nt++;
                f[0] = i;
                f[1] = dot3(base[i], bc) > 0.0 ? j : k;
                f[2] = dot3(base[i], bc) > 0.0 ? k : j;
            }
    assert(nt == 20);
    const double blen = sqrt(1.0 + phi * phi);
    for (int i = 0; i < 12; i++)
        for (int a = 0; a < 3; a++) out->v[3 * i + a] = base[i][a] / blen;
    int nv = 12;

    /* 2. subdivision: each triangle into four, the new vertices on the unit sphere, shared through the cache */
    for (int l = 0; l < level; l++) {
        memset(mc.key, 0, mc.cap * sizeof *mc.key);
        for (int t = 0; t < nt; t++) {
            const int *f = out->tri + 3 * (size_t)t;
            int ab = mid_vertex(&mc, out->v, &nv, f[0], f[1]);
            int bc = mid_vertex(&mc, out->v, &nv, f[1], f[2]);
            int ca = mid_vertex(&mc, out->v, &nv, f[2], f[0]);
            const int sub[12] = {f[0], ab, ca, f[1], bc, ab, f[2], ca, bc, ab, bc, ca};
            memcpy(tri2 + 12 * (size_t)t, sub, sizeof sub);
        }
        nt *= 4;
        int *swap = out->tri;
        out->tri = tri2;
        tri2 = swap;
    }
    assert(nv == nv_final && nt == nt_final);

    /* 3. radial bump on the unit sphere, then scale: x = radius (1 + bump sin(f u_x) sin(f u_y) sin(f u_z)) u */
    for (int i = 0; i < nv; i++) {
        double *u = out->v + 3 * (size_t)i;
        double g = radius * (1.0 + bump * sin(freq * u[0]) * sin(freq * u[1]) * sin(freq * u[2]));
        for (int a = 0; a < 3; a++) u[a] *= g;
    }
    out->nv = nv;
    out->nt = nt;

done:
    free(tri2);
    free(mc.key);
    free(mc.val);
    if (st != DR_OK) dr_trimesh_free(out);
    return st;
}

/* Position of lattice coordinate i of n along an axis: the ends exactly lo and hi. */
static double lattice(double lo, double hi, int i, int n)
{
    if (i == 0) return lo;
    if (i == n) return hi;
    return lo + (hi - lo) * i / n;
}

/* Index of the boundary lattice point (i, j, k) among all boundary points numbered with x fastest, then y,
 * then z: the layers k = 0 and k = n_z are full (n_x+1)(n_y+1) grids, the layers between are rings of
 * 2 n_x + 2 n_y points (row j = 0, then the two ends of each inner row, then row j = n_y). Computed rather
 * than looked up, so the box needs no scratch the size of the whole lattice. */
static int64_t box_index(const int n[3], int i, int j, int k)
{
    const int64_t full = (int64_t)(n[0] + 1) * (n[1] + 1), ring = 2 * (int64_t)n[0] + 2 * (int64_t)n[1];
    if (k == 0) return (int64_t)j * (n[0] + 1) + i;
    int64_t start = full + (int64_t)(k - 1) * ring;
    if (k == n[2]) return start + (int64_t)j * (n[0] + 1) + i;
    if (j == 0) return start + i;
    if (j == n[1]) return start + (n[0] + 1) + 2 * (int64_t)(n[1] - 1) + i;
    assert(i == 0 || i == n[0]);
    return start + (n[0] + 1) + 2 * (int64_t)(j - 1) + (i == n[0]);
}

DrStatus dr_bem_mesh_box(const double lo[3], const double hi[3], const int n[3], DrTriMesh *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    for (int a = 0; a < 3; a++) {
        if (!(isfinite(lo[a]) && isfinite(hi[a]) && lo[a] < hi[a]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "box bounds on axis %c are [%g, %g]; give finite bounds with lo < hi", "xyz"[a], lo[a],
                                hi[a]);
        if (n[a] < 1)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "box has %d segments along axis %c; use at least 1 per edge", n[a], "xyz"[a]);
    }
    const int64_t n0 = n[0], n1 = n[1], n2 = n[2];
    /* int64 holds these products for any int n; the mesh's int indices bound the result. */
    const int64_t nt64 = 4 * (n0 * n1 + n1 * n2 + n2 * n0);
    const int64_t nv64 = 2 * (n0 + 1) * (n1 + 1) + (n2 - 1) * (2 * n0 + 2 * n1);
    if (n0 > INT_MAX / 4 || n1 > INT_MAX / 4 || n2 > INT_MAX / 4 || 3 * nt64 > INT_MAX)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "box with %d x %d x %d segments has more triangles than drench handles (%d); use fewer "
                            "segments",
                            n[0], n[1], n[2], INT_MAX / 3);
    DrStatus st = dr_calloc(3 * (size_t)nv64, sizeof(double), &out->v, err);
    if (st == DR_OK) st = dr_calloc(3 * (size_t)nt64, sizeof(int), &out->tri, err);
    if (st != DR_OK) {
        dr_trimesh_free(out);
        return st;
    }

    /* 1. the lattice points on the boundary, in the order box_index numbers them */
    int nv = 0;
    for (int k = 0; k <= n[2]; k++)
        for (int j = 0; j <= n[1]; j++)
            for (int i = 0; i <= n[0]; i++) {
                if (!(i == 0 || i == n[0] || j == 0 || j == n[1] || k == 0 || k == n[2])) continue;
                assert(box_index(n, i, j, k) == nv);
                double *p = out->v + 3 * (size_t)nv++;
                p[0] = lattice(lo[0], hi[0], i, n[0]);
                p[1] = lattice(lo[1], hi[1], j, n[1]);
                p[2] = lattice(lo[2], hi[2], k, n[2]);
            }
    assert(nv == nv64);

    /* 2. faces: on the side of normal ±e_a the quads span u = a+1, v = a+2 (cyclic), and e_u × e_v = e_a, so
     * (p00, p10, p11) is counter-clockwise seen from outside on the + side and reversed on the − side. */
    int nt = 0;
    for (int a = 0; a < 3; a++) {
        int u = (a + 1) % 3, v = (a + 2) % 3;
        for (int side = 0; side < 2; side++)
            for (int jv = 0; jv < n[v]; jv++)
                for (int iu = 0; iu < n[u]; iu++) {
                    int q[4]; /* p00, p10, p11, p01 */
                    for (int c = 0; c < 4; c++) {
                        int ijk[3];
                        ijk[a] = side ? n[a] : 0;
                        ijk[u] = iu + (c == 1 || c == 2);
                        ijk[v] = jv + (c >= 2);
                        q[c] = (int)box_index(n, ijk[0], ijk[1], ijk[2]);
                    }
                    const int plus[6] = {q[0], q[1], q[2], q[0], q[2], q[3]};
                    const int minus[6] = {q[0], q[2], q[1], q[0], q[3], q[2]};
                    memcpy(out->tri + 3 * (size_t)nt, side ? plus : minus, sizeof plus);
                    nt += 2;
                }
    }
    assert(nt == nt64);
    out->nv = nv;
    out->nt = nt;
    return DR_OK;
}
