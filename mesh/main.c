/* mesh: turns each baked frame's liquid particles and MPM solid particles into an OpenVDB level set (.vdb) and
 * a surface (.obj) per element, writes them and hair vertices as OpenVDB point data (.points.vdb, with
 * mesh.write_points), hair strands as OBJ polylines (and, with mesh.hair_ribbons, as triangle-strip ribbons;
 * wet hair's film in the polylines and, with mesh.wet_tubes, as closed tubes) and boundary-element bodies as
 * their deformed surfaces, and exports colliders as OBJ, into out/<shot>/mesh/.
 *
 * Frames are independent, so -j N meshes up to N frames at once, each on a thread of its own with OpenVDB
 * limited to N / (frames in flight) threads inside it (dr_vdb_run_with_threads), and honours -j, which OpenVDB's
 * own threads (every core) did not. Frames side by side scale better than OpenVDB's threads inside one frame,
 * which stop at its serial parts and merge per-thread grids: on 2 cores one frame at a time used 1.75 cores,
 * two frames at once use both with 5 % less CPU time (README, "Mesh"). Every file is the same whatever N
 * (OpenVDB's results do not depend on its thread count, and each frame's files are its own). The frame caches
 * are read by the frames' threads through the thread-safe HDF5 library, which runs the reads one at a time
 * behind its lock (a frame's reads are a few milliseconds against seconds of meshing). */
#include <limits.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "io/io.h"
#include "scene/scene.h"
#include "vdb/vdb.h"
#include "stage/stage.h"

static int fail(const DrError *err)
{
    dr_error_print("mesh", err);
    return dr_exit_code(err->status);
}

/* out = R·rest + t for nv vertices (R row-major 3×3 as stored in the frame cache). */
static void apply_pose(const double *rest, int nv, const double R[9], const double t[3], double *out)
{
    for (int i = 0; i < nv; i++) {
        const double *p = rest + 3 * i;
        for (int a = 0; a < 3; a++) out[3 * i + a] = R[3 * a] * p[0] + R[3 * a + 1] * p[1] + R[3 * a + 2] * p[2] + t[a];
    }
}

/* ---- particles as OpenVDB points ------------------------------------------------------------------------- */

/* "3×4" for a dataset's shape. */
static void shape_str(int rank, const uint64_t *dims, char *buf, size_t size);

/* DR_ERR_INPUT naming the file and the dataset unless what was read from `path` has rank want_rank and dims want. */
static DrStatus check_shape(DrH5 *h, const char *path, int rank, const uint64_t *dims, int want_rank,
                            const uint64_t *want, DrError *err)
{
    bool ok = rank == want_rank;
    for (int i = 0; ok && i < rank; i++) ok = dims[i] == want[i];
    if (ok) return DR_OK;
    char shape[96], expected[96];
    shape_str(rank, dims, shape, sizeof shape);
    shape_str(want_rank, want, expected, sizeof expected);
    return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                        "dataset %s has shape %s; expected %s; rerun bake (or pipeline.sh)", path, shape, expected);
}

/* J = det F and the von Mises equivalent of the Green–Lagrange strain E = ½(FᵀF − I), √(2/3 dev E : dev E):
   0 for a rigid motion and for a pure change of volume, the uniaxial strain for a small uniaxial stretch at
   constant volume. */
static void deformation_measures(const double F[9], double *J, double *strain)
{
    double C[9], E[9];
    dr_m3a_mul_tn(F, F, C);
    for (int k = 0; k < 9; k++) E[k] = 0.5 * (C[k] - (k % 4 == 0 ? 1.0 : 0.0)); /* k = 0, 4, 8: the diagonal */
    double mean = (E[0] + E[4] + E[8]) / 3.0, dd = 0.0;
    for (int k = 0; k < 9; k++) {
        double d = E[k] - (k % 4 == 0 ? mean : 0.0);
        dd += d * d;
    }
    *J = dr_m3a_det(F);
    *strain = sqrt(2.0 / 3.0 * dd);
}

/* <e>.NNNN.points.vdb (mesh.write_points): the n particles x (m), v (m/s) of liquid or MPM solid e as OpenVDB
 * points with P, v, id and volume (m³), and for an MPM solid J and strain (deformation_measures). A liquid's id is
 * /<e>/id (its own through the bake's sorts, liquid.h) and its volume /<e>/volume (its own, liquid.h; a cache without
 * it: its share of the seeded volume, Δx³ per per_cell particles); an MPM solid's particles keep their order, so the id is the index, and the volume is the
 * current one, J·V₀ (/<e>/deformation_gradient, /<e>/volume). The point grid's voxel is the element's grid cell
 * (Domain.voxel_size): 8 liquid particles per voxel by default, particles_per_axis³ of an MPM solid. */
static DrStatus write_particle_points(const DrElement *e, DrH5 *h, const char *dir, const DrVdbMeta *meta, long n,
                                      const double *x, const double *v, DrError *err)
{
    bool liquid = e->kind == DR_ELEMENT_LIQUID;
    double cell = dr_component_num(dr_element_component(e, "Domain"), "voxel_size");
    char path[1024];
    int rank;
    uint64_t dims[4], want[3] = {(uint64_t)n, 3, 3};
    int64_t *id = NULL;
    double *F = NULL, *V0 = NULL, *vol = NULL, *J = NULL, *strain = NULL;
    DrStatus s = dr_calloc((size_t)n + 1, sizeof *vol, &vol, err);
    if (s == DR_OK && liquid) {
        snprintf(path, sizeof path, "/%s/id", e->name);
        if (!dr_h5_has(h, path))
            s = dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                             "the frame cache holds no particle ids %s (baked by an older drench); rerun bake "
                             "(pipeline.sh does it) or set mesh.write_points to false",
                             path);
        if (s == DR_OK) s = dr_h5_read_i64(h, path, &rank, dims, &id, err);
        if (s == DR_OK) s = check_shape(h, path, rank, dims, 1, want, err);
        /* each particle's own volume (capture and dripping change it); a cache without it holds the seeded one */
        snprintf(path, sizeof path, "/%s/volume", e->name);
        if (s == DR_OK && dr_h5_has(h, path)) {
            double *pv = NULL;
            s = dr_h5_read_f64(h, path, &rank, dims, &pv, err);
            if (s == DR_OK) s = check_shape(h, path, rank, dims, 1, want, err);
            if (s == DR_OK) memcpy(vol, pv, (size_t)n * sizeof *vol);
            free(pv);
        } else {
            int per_cell = dr_component_int(dr_element_component(e, "Particles"), "per_cell");
            for (long p = 0; s == DR_OK && p < n; p++) vol[p] = cell * cell * cell / per_cell;
        }
    } else if (s == DR_OK) {
        snprintf(path, sizeof path, "/%s/deformation_gradient", e->name);
        s = dr_h5_read_f64(h, path, &rank, dims, &F, err);
        if (s == DR_OK) s = check_shape(h, path, rank, dims, 3, want, err);
        snprintf(path, sizeof path, "/%s/volume", e->name);
        if (s == DR_OK) s = dr_h5_read_f64(h, path, &rank, dims, &V0, err);
        if (s == DR_OK) s = check_shape(h, path, rank, dims, 1, want, err);
        if (s == DR_OK) s = dr_calloc((size_t)n + 1, sizeof *id, &id, err);
        if (s == DR_OK) s = dr_calloc((size_t)n + 1, sizeof *J, &J, err);
        if (s == DR_OK) s = dr_calloc((size_t)n + 1, sizeof *strain, &strain, err);
        for (long p = 0; s == DR_OK && p < n; p++) {
            id[p] = p;
            deformation_measures(F + 9 * p, &J[p], &strain[p]);
            vol[p] = J[p] * V0[p];
        }
    }
    DrVdbPointAttr attrs[] = {{"v", DR_VDB_ATTR_VEC3, v, NULL},
                              {"id", DR_VDB_ATTR_INT64, NULL, id},
                              {"volume", DR_VDB_ATTR_FLOAT, vol, NULL},
                              {"J", DR_VDB_ATTR_FLOAT, J, NULL},
                              {"strain", DR_VDB_ATTR_FLOAT, strain, NULL}};
    dr_stage_frame_path(dir, e->name, meta->frame, "points.vdb", path, sizeof path);
    if (s == DR_OK)
        s = dr_error_prefix(dr_vdb_points_write(path, n, x, attrs, liquid ? 3 : 5, cell, meta, err), err,
                            "%s: points of frame %d", e->name, meta->frame);
    free(id);
    free(F);
    free(V0);
    free(vol);
    free(J);
    free(strain);
    return s;
}

/* ---- hair ------------------------------------------------------------------------------------------------ */

static bool is_hair(const DrElement *e) { return e->kind == DR_ELEMENT_HAIR; }

/* "3×4" for a dataset's shape. */
static void shape_str(int rank, const uint64_t *dims, char *buf, size_t size)
{
    size_t n = 0;
    buf[0] = '\0';
    for (int i = 0; i < rank && n < size; i++)
        n += (size_t)snprintf(buf + n, size - n, "%s%llu", i ? "×" : "", (unsigned long long)dims[i]);
}

/* The frame cache's strands of hair element `name` (DESIGN §4): position V×3, strand_offsets S+1 (int64,
 * strand s = vertices offsets[s] .. offsets[s+1]-1, root first) and radius S. Velocity and twist are not read:
 * the OBJ carries neither. Anything missing or inconsistent is DR_ERR_INPUT naming the file and the dataset. */
static DrStatus read_strands(DrH5 *h, const char *name, DrPolylines *out, DrError *err)
{
    *out = (DrPolylines){0};
    const char *file = dr_h5_path(h);
    char px[1024], po[1024], pr[1024];
    snprintf(px, sizeof px, "/%s/position", name);
    snprintf(po, sizeof po, "/%s/strand_offsets", name);
    snprintf(pr, sizeof pr, "/%s/radius", name);
    double *x = NULL, *radius = NULL;
    int64_t *off = NULL;
    int rx, ro, rr;
    uint64_t dx[4], dof[4], dr[4];
    DrStatus s = dr_h5_read_f64(h, px, &rx, dx, &x, err);
    if (s == DR_OK) s = dr_h5_read_i64(h, po, &ro, dof, &off, err);
    if (s == DR_OK) s = dr_h5_read_f64(h, pr, &rr, dr, &radius, err);
    /* shapes: V×3, S+1 and S, with V small enough for int indices of coordinates */
    char shape[96];
    if (s == DR_OK && (rx != 2 || dx[1] != 3 || dx[0] > (uint64_t)(INT_MAX / 3))) {
        shape_str(rx, dx, shape, sizeof shape);
        s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                         "dataset %s has shape %s; expected V×3 vertex positions (V < %d); rerun bake (or pipeline.sh)",
                         px, shape, INT_MAX / 3);
    }
    if (s == DR_OK && (ro != 1 || dof[0] < 1 || dof[0] - 1 > dx[0] / 2)) {
        shape_str(ro, dof, shape, sizeof shape);
        s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                         "dataset %s has shape %s; expected S+1 entries for S strands of at least 2 of the %llu "
                         "vertices of %s; rerun bake (or pipeline.sh)",
                         po, shape, (unsigned long long)dx[0], px);
    }
    long S = s == DR_OK ? (long)dof[0] - 1 : 0;
    if (s == DR_OK && (rr != 1 || dr[0] != (uint64_t)S)) {
        shape_str(rr, dr, shape, sizeof shape);
        s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                         "dataset %s has shape %s; expected one radius per strand (%ld, from %s); rerun bake (or "
                         "pipeline.sh)",
                         pr, shape, S, po);
    }
    /* offsets: from 0 to V, at least 2 vertices per strand (a rod has at least one edge) */
    long V = s == DR_OK ? (long)dx[0] : 0;
    if (s == DR_OK && off[0] != 0)
        s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                         "dataset %s is malformed: entry 0 is %lld, it must be 0; rerun bake (or pipeline.sh)", po,
                         (long long)off[0]);
    for (long k = 0; s == DR_OK && k < S; k++)
        if (off[k + 1] < off[k] + 2 || off[k + 1] > V) /* off[k] is in [0, V] here: no overflow */
            s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                             "dataset %s is malformed: strand %ld runs from vertex %lld to %lld (of %ld in %s); "
                             "offsets must increase by at least 2 (a strand has at least 2 vertices) up to V; rerun "
                             "bake (or pipeline.sh)",
                             po, k, (long long)off[k], (long long)off[k + 1] - 1, V, px);
    if (s == DR_OK && off[S] != V)
        s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                         "dataset %s is malformed: its last entry is %lld but %s holds %ld vertices; rerun bake (or "
                         "pipeline.sh)",
                         po, (long long)off[S], px, V);
    for (long i = 0; s == DR_OK && i < 3 * V; i++)
        if (!isfinite(x[i]))
            s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                             "dataset %s holds a non-finite coordinate at vertex %ld; the bake produced invalid data "
                             "(lower the time step or check the scene, then rerun bake)",
                             px, i / 3);
    for (long k = 0; s == DR_OK && k < S; k++)
        if (!isfinite(radius[k]) || radius[k] < 0.0)
            s = dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                             "dataset %s holds radius %g for strand %ld; a radius is a finite number >= 0; rerun "
                             "bake (or pipeline.sh)",
                             pr, radius[k], k);
    DrPolylines p = {.count = (int)S, .x = x, .radius = radius};
    if (s == DR_OK) s = dr_calloc((size_t)S + 1, sizeof *p.offsets, &p.offsets, err);
    if (s == DR_OK) {
        for (long k = 0; k <= S; k++) p.offsets[k] = (int)off[k];
        *out = p;
    } else {
        free(x);
        free(radius);
    }
    free(off);
    return s;
}

/* Unit tangent of edge e (vertices e, e+1) of a strand's x, or `fallback` when the edge has no length. */
static DrVec3 edge_tangent(const double *x, int e, DrVec3 fallback)
{
    DrVec3 d = dr_v3(x[3 * e + 3] - x[3 * e], x[3 * e + 4] - x[3 * e + 1], x[3 * e + 5] - x[3 * e + 2]);
    double n = dr_v3_norm(d);
    return n > 0.0 ? dr_v3_scale(d, 1.0 / n) : fallback;
}

/* d carried from unit tangent a to unit tangent b by the rotation about a×b that takes a to b (parallel
 * transport, Rodrigues' formula written without the angle: d' = (a·b) d + (a×b)×d + (a×b)(a×b·d)/(1 + a·b)).
 * Where b turns back onto −a the rotation is undefined and d, perpendicular to both, is kept. */
static DrVec3 transport(DrVec3 d, DrVec3 a, DrVec3 b)
{
    double c = dr_v3_dot(a, b);
    if (c <= -1.0 + 1e-12) return d;
    DrVec3 v = dr_v3_cross(a, b);
    DrVec3 r = dr_v3_add(dr_v3_add(dr_v3_scale(d, c), dr_v3_cross(v, d)), dr_v3_scale(v, dr_v3_dot(v, d) / (1.0 + c)));
    /* rounding drift: back onto the plane perpendicular to b, at unit length */
    return dr_v3_normalize(dr_v3_sub(r, dr_v3_scale(b, dr_v3_dot(r, b))));
}

/* The frame the ribbons and the wet tubes share along one strand of n vertices x (3 per vertex): at vertex i the
 * unit tangent T[i] (the first edge's direction at the root, the last edge's at the tip, the normalised sum of
 * the two adjacent edge directions between) and a unit director d[i] perpendicular to it. d starts at the root as
 * ŷ×T_0 normalised, horizontal so that hanging and horizontal strands alike show their width to a level camera
 * (x̂×T_0 where the first edge is within about 0.06 degrees of vertical), and is parallel-transported from each
 * vertex tangent to the next, so it does not twist about the strand: it depends on the strand's shape only, not
 * on any camera. Edges of no length take the previous edge's direction. */
static void strand_frames(const double *x, int n, DrVec3 *T, DrVec3 *d)
{
    /* the first edge with a length sets the direction of any before it; a strand of coincident vertices points up */
    DrVec3 first = dr_v3(0, 1, 0);
    for (int e = n - 2; e >= 0; e--) first = edge_tangent(x, e, first);
    DrVec3 prev_edge = first, T_prev = first, di = dr_v3(0, 0, 0);
    for (int i = 0; i < n; i++) {
        DrVec3 in = prev_edge, outd = i + 1 < n ? edge_tangent(x, i, prev_edge) : prev_edge;
        DrVec3 Ti = i == 0 ? outd : (i + 1 == n ? in : dr_v3_normalize(dr_v3_add(in, outd)));
        if (dr_v3_dot(Ti, Ti) == 0.0) Ti = outd; /* a hairpin: the two edges cancel */
        if (i == 0) {
            di = dr_v3_cross(dr_v3(0, 1, 0), Ti);
            if (dr_v3_norm(di) < 1e-3) di = dr_v3_cross(dr_v3(1, 0, 0), Ti);
            di = dr_v3_normalize(di);
        } else {
            di = transport(di, T_prev, Ti);
        }
        T[i] = Ti;
        d[i] = di;
        prev_edge = outd;
        T_prev = Ti;
    }
}

/* Scratch for strand_frames over the longest of p's strands. */
static DrStatus frames_alloc(const DrPolylines *p, DrVec3 **T, DrVec3 **d, DrError *err)
{
    int longest = 1;
    for (int k = 0; k < p->count; k++)
        if (p->offsets[k + 1] - p->offsets[k] > longest) longest = p->offsets[k + 1] - p->offsets[k];
    DR_TRY(dr_calloc((size_t)longest, sizeof **T, T, err));
    DrStatus s = dr_calloc((size_t)longest, sizeof **d, d, err);
    if (s != DR_OK) {
        free(*T);
        *T = NULL;
    }
    return s;
}

/* mesh.hair_ribbons: each strand as a triangle strip 2·radius wide, for tools that do not draw OBJ polylines.
 * The strip's width direction at vertex i is strand_frames' director d_i: vertex i gives the strip's corners
 * x_i ∓ radius·d_i with normal T_i × d_i; the triangles wind counter-clockwise about it. */
static DrStatus build_ribbons(const DrPolylines *p, DrTriMesh *out, DrError *err)
{
    *out = (DrTriMesh){0};
    int V = p->offsets[p->count];
    if (V > INT_MAX / 6)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "%d strand vertices are too many for one ribbon mesh", V);
    DrTriMesh m = {.nv = 2 * V, .nt = 2 * (V - p->count)};
    DrVec3 *T = NULL, *d = NULL;
    DrStatus s = dr_calloc(3 * (size_t)m.nv, sizeof *m.v, &m.v, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)m.nv, sizeof *m.n, &m.n, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)m.nt + 1, sizeof *m.tri, &m.tri, err);
    if (s == DR_OK) s = frames_alloc(p, &T, &d, err);
    if (s != DR_OK) {
        dr_trimesh_free(&m);
        return s;
    }
    int t = 0;
    for (int k = 0; k < p->count; k++) {
        int o = p->offsets[k], n = p->offsets[k + 1] - o;
        const double *x = p->x + 3 * (size_t)o;
        strand_frames(x, n, T, d);
        for (int i = 0; i < n; i++) {
            DrVec3 nrm = dr_v3_normalize(dr_v3_cross(T[i], d[i]));
            DrVec3 c = dr_v3(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
            DrVec3 w = dr_v3_scale(d[i], p->radius[k]);
            DrVec3 corner[2] = {dr_v3_sub(c, w), dr_v3_add(c, w)};
            for (int side = 0; side < 2; side++) {
                double *v = m.v + 3 * (2 * (size_t)(o + i) + side), *nn = m.n + 3 * (2 * (size_t)(o + i) + side);
                v[0] = corner[side].x, v[1] = corner[side].y, v[2] = corner[side].z;
                nn[0] = nrm.x, nn[1] = nrm.y, nn[2] = nrm.z;
            }
            if (i + 1 < n) {
                /* left L = x − r·d, right R = x + r·d: (L_i, L_i+1, R_i) and (R_i, L_i+1, R_i+1) turn
                   counter-clockwise about T × d */
                int L0 = 2 * (o + i), R0 = L0 + 1, L1 = L0 + 2, R1 = L0 + 3;
                int q[6] = {L0, L1, R0, R0, L1, R1};
                memcpy(m.tri + 3 * t, q, sizeof q);
                t += 2;
            }
        }
    }
    assert(t == m.nt);
    free(T);
    free(d);
    *out = m;
    return DR_OK;
}

/* ---- wet hair --------------------------------------------------------------------------------------------- */

/* A scene with wet hair: some hair element has a Wetting component. Its bake then writes the film of every hair
 * element (dry ones start without any, and may catch some). */
static bool wet_scene(const DrScene *scene)
{
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (is_hair(e) && dr_component_present(dr_element_component(e, "Wetting"))) return true;
    }
    return false;
}

/* The film around hair element e's strands p in this frame (DESIGN §4): /<e>/liquid_area, the film's cross-section
 * A = π(H² − r²) per vertex (m²), into p->outer = H = sqrt(r² + A/π) per vertex, with r the vertex's radius
 * (dr_stage_vertex_radii: the strand's, tapered by RodMaterial.tip_radius); H = r where A = 0 (dry). DR_ERR_INPUT
 * naming the file and the dataset when it is missing, of another shape, or holds a non-finite or negative area. */
static DrStatus read_film(const DrElement *e, DrH5 *h, DrPolylines *p, DrError *err)
{
    int V = p->offsets[p->count];
    char path[1024];
    snprintf(path, sizeof path, "/%s/liquid_area", e->name);
    if (!dr_h5_has(h, path))
        return dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                            "the frame cache holds no film %s, which a scene with wet hair has for every hair element "
                            "(baked by an older drench); rerun bake (or pipeline.sh)",
                            path);
    double *A = NULL, *H = NULL;
    int rank;
    uint64_t dims[4], want[1] = {(uint64_t)V};
    DR_TRY(dr_h5_read_f64(h, path, &rank, dims, &A, err));
    DrStatus s = check_shape(h, path, rank, dims, 1, want, err);
    if (s == DR_OK) s = dr_calloc((size_t)V + 1, sizeof *H, &H, err);
    if (s == DR_OK)
        dr_stage_vertex_radii(p->x, p->offsets, p->count, p->radius,
                              dr_component_num(dr_element_component(e, "RodMaterial"), "tip_radius"), H);
    for (int i = 0; s == DR_OK && i < V; i++) {
        double r = H[i];
        /* the bake writes A = π(H·H − r·r) from H = sqrt(r² + V/(πL)) ≥ r, where rounding may leave −1e-16 π r²
           for no film: anything above −1e-9 π r² is no film, anything below it is not a cross-section */
        if (!isfinite(A[i]) || A[i] < -1e-9 * DR_PI * r * r)
            s = dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                             "dataset %s holds %g m^2 at vertex %d; a film's cross-section is a finite area >= 0; "
                             "rerun bake (or pipeline.sh)",
                             path, A[i], i);
        else
            H[i] = sqrt(r * r + fmax(A[i], 0.0) / DR_PI);
    }
    free(A);
    if (s == DR_OK) p->outer = H;
    else free(H);
    return s;
}

/* mesh.wet_tubes: each strand as a closed tube of the film's outer radius p->outer[v] at its vertex v, in the
 * frame of the ribbons (strand_frames: d_v the parallel-transported director, b_v = T_v × d_v). Vertex v of the
 * strands gets a ring of `sides` points v·sides + j at x_v + H_v (cos φ_j d_v + sin φ_j b_v), φ_j = 2πj/sides,
 * with that unit vector as normal; after all rings come strand s's root and tip centres, V·sides + 2s and
 * V·sides + 2s + 1 (the strand's end vertices, normals −T and +T), which close its ends as flat fans. Rings of
 * consecutive vertices are joined by 2·sides triangles. Every triangle winds counter-clockwise seen from outside
 * (φ turns counter-clockwise about T), so each tube is closed (every edge is shared by two triangles that run it
 * in opposite directions) with its normals outward. Per strand of n vertices: n·sides + 2 vertices and 2·sides·n
 * triangles. */
static DrStatus build_tubes(const DrPolylines *p, int sides, DrTriMesh *out, DrError *err)
{
    *out = (DrTriMesh){0};
    int V = p->offsets[p->count], S = p->count;
    if ((long long)V * sides + 2LL * S > INT_MAX / 3 || 2LL * sides * V > INT_MAX / 3)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                            "%d strand vertices with %d sides are too many for one tube mesh; lower mesh.wet_tube_sides",
                            V, sides);
    DrTriMesh m = {.nv = V * sides + 2 * S, .nt = 2 * sides * V};
    DrVec3 *T = NULL, *d = NULL;
    double *cs = NULL;
    DrStatus s = dr_calloc(3 * (size_t)m.nv, sizeof *m.v, &m.v, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)m.nv, sizeof *m.n, &m.n, err);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)m.nt + 1, sizeof *m.tri, &m.tri, err);
    if (s == DR_OK) s = dr_calloc(2 * (size_t)sides, sizeof *cs, &cs, err);
    if (s == DR_OK) s = frames_alloc(p, &T, &d, err);
    if (s != DR_OK) {
        dr_trimesh_free(&m);
        free(cs);
        return s;
    }
    for (int j = 0; j < sides; j++) cs[2 * j] = cos(2.0 * DR_PI * j / sides), cs[2 * j + 1] = sin(2.0 * DR_PI * j / sides);
    int t = 0;
    for (int k = 0; k < S; k++) {
        int o = p->offsets[k], n = p->offsets[k + 1] - o;
        const double *x = p->x + 3 * (size_t)o;
        strand_frames(x, n, T, d);
        for (int i = 0; i < n; i++) {
            DrVec3 b = dr_v3_cross(T[i], d[i]), c = dr_v3(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
            for (int j = 0; j < sides; j++) {
                DrVec3 u = dr_v3_add(dr_v3_scale(d[i], cs[2 * j]), dr_v3_scale(b, cs[2 * j + 1]));
                DrVec3 q = dr_v3_add(c, dr_v3_scale(u, p->outer[o + i]));
                size_t a = 3 * ((size_t)(o + i) * sides + j);
                m.v[a] = q.x, m.v[a + 1] = q.y, m.v[a + 2] = q.z;
                m.n[a] = u.x, m.n[a + 1] = u.y, m.n[a + 2] = u.z;
            }
            if (i + 1 < n) {
                /* ring i to ring i+1: (i,j) → (i,j+1) → (i+1,j) and (i,j+1) → (i+1,j+1) → (i+1,j) turn
                   counter-clockwise about the outward normal (b × T = d at φ = 0) */
                for (int j = 0; j < sides; j++) {
                    int j1 = (j + 1) % sides, r0 = (o + i) * sides, r1 = r0 + sides;
                    int q[6] = {r0 + j, r0 + j1, r1 + j, r0 + j1, r1 + j1, r1 + j};
                    memcpy(m.tri + 3 * t, q, sizeof q);
                    t += 2;
                }
            }
        }
        /* the ends: a fan about the end vertex, facing −T at the root and +T at the tip */
        for (int end = 0; end < 2; end++) {
            int i = end ? n - 1 : 0, centre = V * sides + 2 * k + end, r0 = (o + i) * sides;
            DrVec3 nrm = dr_v3_scale(T[i], end ? 1.0 : -1.0);
            size_t a = 3 * (size_t)centre;
            m.v[a] = x[3 * i], m.v[a + 1] = x[3 * i + 1], m.v[a + 2] = x[3 * i + 2];
            m.n[a] = nrm.x, m.n[a + 1] = nrm.y, m.n[a + 2] = nrm.z;
            for (int j = 0; j < sides; j++) {
                int j1 = (j + 1) % sides;
                int q[3] = {centre, end ? r0 + j : r0 + j1, end ? r0 + j1 : r0 + j};
                memcpy(m.tri + 3 * t, q, sizeof q);
                t++;
            }
        }
    }
    assert(t == m.nt);
    free(T);
    free(d);
    free(cs);
    *out = m;
    return DR_OK;
}

/* <e>.NNNN.points.vdb of hair element e (mesh.write_points): its V vertices as OpenVDB points with P, v (from
 * /<e>/velocity), id (the vertex index: strands keep their vertices), strand (the strand's index), width (its
 * diameter, m) and, with the film (p->outer), wet_width (the film's outer diameter 2H, m), the voxel chosen by
 * OpenVDB for about 8 vertices per voxel. */
static DrStatus write_hair_points(const DrElement *e, DrH5 *h, const char *dir, const DrVdbMeta *meta,
                                  const DrPolylines *p, DrError *err)
{
    long V = p->offsets[p->count];
    char path[1024];
    int rank;
    uint64_t dims[4], want[2] = {(uint64_t)V, 3};
    double *v = NULL, *width = NULL, *wet_width = NULL;
    int64_t *id = NULL, *strand = NULL;
    snprintf(path, sizeof path, "/%s/velocity", e->name);
    DrStatus s = dr_h5_read_f64(h, path, &rank, dims, &v, err);
    if (s == DR_OK) s = check_shape(h, path, rank, dims, 2, want, err);
    if (s == DR_OK) s = dr_calloc((size_t)V + 1, sizeof *width, &width, err);
    if (s == DR_OK) s = dr_calloc((size_t)V + 1, sizeof *id, &id, err);
    if (s == DR_OK) s = dr_calloc((size_t)V + 1, sizeof *strand, &strand, err);
    if (s == DR_OK && p->outer) s = dr_calloc((size_t)V + 1, sizeof *wet_width, &wet_width, err);
    for (int k = 0; s == DR_OK && k < p->count; k++)
        for (int i = p->offsets[k]; i < p->offsets[k + 1]; i++) {
            id[i] = i;
            strand[i] = k;
            width[i] = 2.0 * p->radius[k];
            if (wet_width) wet_width[i] = 2.0 * p->outer[i];
        }
    DrVdbPointAttr attrs[] = {{"v", DR_VDB_ATTR_VEC3, v, NULL},
                              {"id", DR_VDB_ATTR_INT64, NULL, id},
                              {"strand", DR_VDB_ATTR_INT64, NULL, strand},
                              {"width", DR_VDB_ATTR_FLOAT, width, NULL},
                              {"wet_width", DR_VDB_ATTR_FLOAT, wet_width, NULL}};
    dr_stage_frame_path(dir, e->name, meta->frame, "points.vdb", path, sizeof path);
    if (s == DR_OK)
        s = dr_error_prefix(dr_vdb_points_write(path, V, p->x, attrs, wet_width ? 5 : 4, 0.0, meta, err), err,
                            "%s: points of frame %d", e->name, meta->frame);
    free(v);
    free(width);
    free(wet_width);
    free(id);
    free(strand);
    return s;
}

/* What the mesh stage writes of a hair element, from the scene's mesh section. */
typedef struct HairOutputs {
    bool ribbons, points; /* mesh.hair_ribbons, mesh.write_points */
    bool wet;             /* the scene has wet hair: the frame caches hold every hair element's film */
    bool tubes;           /* mesh.wet_tubes, in a scene with wet hair */
    int sides;            /* mesh.wet_tube_sides */
} HairOutputs;

static HairOutputs hair_outputs(const DrScene *scene)
{
    const DrComponent *ms = dr_scene_section(scene, "mesh");
    bool wet = wet_scene(scene);
    return (HairOutputs){dr_component_bool(ms, "hair_ribbons"), dr_component_bool(ms, "write_points"), wet,
                         wet && dr_component_bool(ms, "wet_tubes"), dr_component_int(ms, "wet_tube_sides")};
}

/* Hair element e of this frame: <e>.NNNN.obj polylines (in a scene with wet hair with the film's outer radius per
 * vertex), <e>_ribbons.NNNN.obj with mesh.hair_ribbons, <e>_wet.NNNN.obj with mesh.wet_tubes and
 * <e>.NNNN.points.vdb with mesh.write_points (meta: that file's metadata). */
static DrStatus mesh_hair(const DrElement *e, DrH5 *h, const char *dir, const DrVdbMeta *meta, const HairOutputs *o,
                          long *strands, long *triangles, DrError *err)
{
    int frame = meta->frame;
    DrPolylines p;
    DR_TRY(read_strands(h, e->name, &p, err));
    char comment[512], out[4096];
    DrStatus s = o->wet ? read_film(e, h, &p, err) : DR_OK;
    snprintf(comment, sizeof comment,
             "drench %s hair '%s' frame %d (m, y up): one polyline per strand, root first; each \"# radius\" line\n"
             "sets the strand radius in metres of the polylines after it%s",
             DR_VERSION, e->name, frame,
             p.outer ? "; each \"# outer_radius\" line gives\nthe liquid film's outer radius in metres at each vertex "
                       "of the polyline after it"
                     : "");
    dr_stage_frame_path(dir, e->name, frame, "obj", out, sizeof out);
    if (s == DR_OK) s = dr_io_write_polylines_obj(out, &p, comment, err);
    if (s == DR_OK) *strands += p.count;
    if (s == DR_OK && o->ribbons) {
        DrTriMesh m;
        s = build_ribbons(&p, &m, err);
        if (s == DR_OK) {
            char prefix[1024];
            snprintf(prefix, sizeof prefix, "%s_ribbons", e->name);
            snprintf(comment, sizeof comment,
                     "drench %s hair '%s' frame %d (m, y up): each strand as a ribbon 2 radii wide, its width\n"
                     "direction parallel-transported from the root (independent of any camera)",
                     DR_VERSION, e->name, frame);
            dr_stage_frame_path(dir, prefix, frame, "obj", out, sizeof out);
            s = dr_io_write_obj(out, &m, comment, err);
            if (s == DR_OK) *triangles += m.nt;
        }
        dr_trimesh_free(&m);
    }
    if (s == DR_OK && o->tubes) {
        DrTriMesh m;
        s = build_tubes(&p, o->sides, &m, err);
        if (s == DR_OK) {
            char prefix[1024];
            snprintf(prefix, sizeof prefix, "%s_wet", e->name);
            snprintf(comment, sizeof comment,
                     "drench %s hair '%s' frame %d (m, y up): each strand as a closed tube of the liquid film's outer\n"
                     "radius (the strand's radius where dry), %d sides: vertex v of the strands has ring points\n"
                     "v*%d+1 .. v*%d+%d (OBJ indices), then each strand's root and tip centres close its ends",
                     DR_VERSION, e->name, frame, o->sides, o->sides, o->sides, o->sides);
            dr_stage_frame_path(dir, prefix, frame, "obj", out, sizeof out);
            s = dr_io_write_obj(out, &m, comment, err);
            if (s == DR_OK) *triangles += m.nt;
        }
        dr_trimesh_free(&m);
    }
    if (s == DR_OK && o->points) s = write_hair_points(e, h, dir, meta, &p, err);
    dr_io_polylines_free(&p);
    return s;
}

/* ---- boundary-element bodies ------------------------------------------------------------------------------ */

static bool is_bem(const DrElement *e) { return e->kind == DR_ELEMENT_BEM_SOLID; }

/* Reads dataset /<name>/<what> of a frame cache: `rows` rows of `cols` finite numbers (rows 0: a vector of cols
 * numbers, rank 1; rows < 0: any count of rows, returned in *nrows). Anything else is DR_ERR_INPUT naming the file
 * and the dataset. */
static DrStatus read_bem_f64(DrH5 *h, const char *name, const char *what, long rows, int cols, double **out,
                             long *nrows, DrError *err)
{
    char path[1024], shape[96], want[64];
    snprintf(path, sizeof path, "/%s/%s", name, what);
    int rank;
    uint64_t dims[4];
    DR_TRY(dr_h5_read_f64(h, path, &rank, dims, out, err));
    bool ok = rows == 0 ? rank == 1 && dims[0] == (uint64_t)cols
                        : rank == 2 && dims[1] == (uint64_t)cols && dims[0] <= (uint64_t)(INT_MAX / 3) &&
                              (rows < 0 || dims[0] == (uint64_t)rows);
    uint64_t count = rows == 0 ? (uint64_t)cols : (ok ? dims[0] * (uint64_t)cols : 0);
    DrStatus s = DR_OK;
    if (!ok) {
        shape_str(rank, dims, shape, sizeof shape);
        if (rows == 0) snprintf(want, sizeof want, "%d", cols);
        else if (rows < 0) snprintf(want, sizeof want, "N×%d", cols);
        else snprintf(want, sizeof want, "%ld×%d", rows, cols);
        s = dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                         "dataset %s has shape %s; expected %s; rerun bake (or pipeline.sh)", path, shape, want);
    }
    for (uint64_t i = 0; s == DR_OK && i < count; i++)
        if (!isfinite((*out)[i]))
            s = dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                             "dataset %s holds a non-finite number; the bake produced invalid data (check the scene, "
                             "then rerun bake)", path);
    if (s != DR_OK) {
        free(*out);
        *out = NULL;
        return s;
    }
    if (nrows) *nrows = rows == 0 ? 1 : (long)dims[0];
    return DR_OK;
}

/* Dataset /<name>/triangles of a frame cache: M ≥ 1 rows of 3 vertex indices, each below nv, into a new array of 3M
   ints (*out, *nt). Anything else is DR_ERR_INPUT naming the file and the dataset. */
static DrStatus read_triangles(DrH5 *h, const char *name, long nv, int **out, long *nt, DrError *err)
{
    *out = NULL;
    *nt = 0;
    char path[1024];
    snprintf(path, sizeof path, "/%s/triangles", name);
    int rank;
    uint64_t dims[4];
    int32_t *tri = NULL;
    DrStatus s = dr_h5_read_i32(h, path, &rank, dims, &tri, err);
    if (s == DR_OK && (rank != 2 || dims[1] != 3 || dims[0] < 1 || dims[0] > (uint64_t)(INT_MAX / 3))) {
        char shape[96];
        shape_str(rank, dims, shape, sizeof shape);
        s = dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                         "dataset %s has shape %s; expected M×3 vertex indices; rerun bake (or pipeline.sh)", path, shape);
    }
    long n = s == DR_OK ? (long)dims[0] : 0;
    for (long k = 0; s == DR_OK && k < 3 * n; k++)
        if (tri[k] < 0 || tri[k] >= nv)
            s = dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                             "dataset %s: triangle %ld refers to vertex %d of %ld; rerun bake (or pipeline.sh)", path,
                             k / 3, (int)tri[k], nv);
    if (s == DR_OK) s = dr_calloc(3 * (size_t)n + 1, sizeof **out, out, err);
    if (s == DR_OK) {
        for (long k = 0; k < 3 * n; k++) (*out)[k] = tri[k];
        *nt = n;
    }
    free(tri);
    return s;
}

/* m->n (allocated, 3 per vertex): area-weighted vertex normals, the normalised sum of the (unnormalised) face normals
   around each vertex (0 where they cancel). */
static DrStatus area_normals(DrTriMesh *m, DrError *err)
{
    DR_TRY(dr_calloc(3 * (size_t)m->nv + 1, sizeof *m->n, &m->n, err));
    for (long t = 0; t < m->nt; t++) {
        const int *c = m->tri + 3 * t;
        DrVec3 p0 = dr_v3(m->v[3 * c[0]], m->v[3 * c[0] + 1], m->v[3 * c[0] + 2]);
        DrVec3 p1 = dr_v3(m->v[3 * c[1]], m->v[3 * c[1] + 1], m->v[3 * c[1] + 2]);
        DrVec3 p2 = dr_v3(m->v[3 * c[2]], m->v[3 * c[2] + 1], m->v[3 * c[2] + 2]);
        DrVec3 fn = dr_v3_cross(dr_v3_sub(p1, p0), dr_v3_sub(p2, p0));
        for (int j = 0; j < 3; j++) {
            m->n[3 * c[j]] += fn.x;
            m->n[3 * c[j] + 1] += fn.y;
            m->n[3 * c[j] + 2] += fn.z;
        }
    }
    for (long i = 0; i < m->nv; i++) {
        DrVec3 n = dr_v3(m->n[3 * i], m->n[3 * i + 1], m->n[3 * i + 2]);
        double len = dr_v3_norm(n);
        n = len > 0.0 ? dr_v3_scale(n, 1.0 / len) : dr_v3(0, 0, 0);
        m->n[3 * i] = n.x, m->n[3 * i + 1] = n.y, m->n[3 * i + 2] = n.z;
    }
    return DR_OK;
}

/* The body's surface in this frame (DESIGN §4): V = R·(reference + displacement) + translation, with the cached
 * triangles (counter-clockwise from outside: R is a rotation, so it keeps the winding) and area-weighted vertex
 * normals. */
static DrStatus read_bem_surface(DrH5 *h, const char *name, DrTriMesh *out, DrError *err)
{
    *out = (DrTriMesh){0};
    double *R = NULL, *T = NULL, *ref = NULL, *u = NULL;
    long nv = 0, nt = 0;
    DrTriMesh m = {0};
    DrStatus s = read_bem_f64(h, name, "rotation", 3, 3, &R, NULL, err);
    if (s == DR_OK) s = read_bem_f64(h, name, "translation", 0, 3, &T, NULL, err);
    if (s == DR_OK) s = read_bem_f64(h, name, "reference", -1, 3, &ref, &nv, err);
    if (s == DR_OK) s = read_bem_f64(h, name, "displacement", nv, 3, &u, NULL, err);
    if (s == DR_OK) s = read_triangles(h, name, nv, &m.tri, &nt, err);
    m.nv = (int)nv, m.nt = (int)nt;
    if (s == DR_OK) s = dr_calloc(3 * (size_t)nv + 1, sizeof *m.v, &m.v, err);
    if (s == DR_OK) {
        for (long i = 0; i < nv; i++) {
            double b[3] = {ref[3 * i] + u[3 * i], ref[3 * i + 1] + u[3 * i + 1], ref[3 * i + 2] + u[3 * i + 2]};
            for (int a = 0; a < 3; a++)
                m.v[3 * i + a] = R[3 * a] * b[0] + R[3 * a + 1] * b[1] + R[3 * a + 2] * b[2] + T[a];
        }
        s = area_normals(&m, err);
    }
    if (s == DR_OK) *out = m;
    else dr_trimesh_free(&m);
    free(R);
    free(T);
    free(ref);
    free(u);
    return s;
}

static DrStatus mesh_bem(const DrElement *e, DrH5 *h, const char *dir, int frame, long *triangles, DrError *err)
{
    DrTriMesh m;
    DR_TRY(read_bem_surface(h, e->name, &m, err));
    char comment[512], out[4096];
    snprintf(comment, sizeof comment,
             "drench %s BEM solid '%s' frame %d (m, y up): R (reference + displacement) + translation of the frame "
             "cache",
             DR_VERSION, e->name, frame);
    dr_stage_frame_path(dir, e->name, frame, "obj", out, sizeof out);
    DrStatus s = dr_io_write_obj(out, &m, comment, err);
    if (s == DR_OK) *triangles += m.nt;
    dr_trimesh_free(&m);
    return s;
}

/* ---- cloth ----------------------------------------------------------------------------------------------------- */

static bool is_cloth(const DrElement *e) { return e->kind == DR_ELEMENT_CLOTH; }

/* The panel in this frame: the cached positions and triangles, with area-weighted vertex normals (the side the mesh's
   winding faces). */
static DrStatus mesh_cloth(const DrElement *e, DrH5 *h, const char *dir, int frame, long *triangles, DrError *err)
{
    long nv = 0, nt = 0;
    DrTriMesh m = {0};
    DrStatus s = read_bem_f64(h, e->name, "position", -1, 3, &m.v, &nv, err);
    if (s == DR_OK) s = read_triangles(h, e->name, nv, &m.tri, &nt, err);
    m.nv = (int)nv, m.nt = (int)nt;
    char path[1024];
    snprintf(path, sizeof path, "/%s/uv", e->name);
    if (s == DR_OK && dr_h5_has(h, path)) { /* the mesh file's texture coordinates, per triangle corner */
        int rank;
        uint64_t dims[4];
        s = dr_h5_read_f64(h, path, &rank, dims, &m.uv, err);
        if (s == DR_OK && (rank != 3 || dims[0] != (uint64_t)nt || dims[1] != 3 || dims[2] != 2))
            s = dr_error_set(err, DR_ERR_INPUT, dr_h5_path(h), 0, 0,
                             "dataset %s does not hold 2 coordinates for each corner of the %ld triangles; rerun bake "
                             "(or pipeline.sh)", path, nt);
    }
    if (s == DR_OK) s = area_normals(&m, err);
    if (s == DR_OK) {
        char comment[512], out[4096];
        snprintf(comment, sizeof comment,
                 "drench %s cloth '%s' frame %d (m, y up): the panel's vertices in the mesh's order, its triangles as "
                 "the input mesh winds them, area-weighted normals, the mesh file's texture coordinates per corner",
                 DR_VERSION, e->name, frame);
        dr_stage_frame_path(dir, e->name, frame, "obj", out, sizeof out);
        s = dr_io_write_obj(out, &m, comment, err);
        if (s == DR_OK) *triangles += m.nt;
    }
    dr_trimesh_free(&m);
    return s;
}

/* With mesh.hair_ribbons, hair element H writes H_ribbons.NNNN.obj, and with mesh.wet_tubes (in a scene with wet
 * hair) H_wet.NNNN.obj: an element named H_ribbons or H_wet would share those files. Checked before anything is
 * written. */
static DrStatus check_hair_names(const DrScene *scene, DrError *err)
{
    HairOutputs o = hair_outputs(scene);
    static const char *const suffix[2] = {"_ribbons", "_wet"}, *const field[2] = {"hair_ribbons", "wet_tubes"},
                             *const what[2] = {"ribbons", "wet tubes"};
    int n = dr_scene_element_count(scene);
    for (int k = 0; k < 2; k++) {
        if (!(k == 0 ? o.ribbons : o.tubes)) continue;
        for (int i = 0; i < n; i++) {
            const DrElement *e = dr_scene_element(scene, i);
            if (!is_hair(e)) continue;
            size_t len = strlen(e->name);
            for (int j = 0; j < n; j++) {
                const char *other = dr_scene_element(scene, j)->name;
                if (strncmp(other, e->name, len) == 0 && strcmp(other + len, suffix[k]) == 0)
                    return dr_error_set(err, DR_ERR_INPUT, dr_scene_path(scene), 0, 0,
                                        "mesh.%s writes the %s of hair '%s' as %s.NNNN.obj, the files of element "
                                        "'%s'; rename one of the two elements or set mesh.%s to false",
                                        field[k], what[k], e->name, other, other, field[k]);
            }
        }
    }
    return DR_OK;
}

/* The bake must hold this run's frames, whole, before anything is written: its MANIFEST, under the current bake
 * key, records them (a bake that stopped or failed, or ran for fewer frames, does not), and each frame file holds
 * its own frame, under that key, every dataset matching its checksum. Any of these is DR_ERR_INPUT (exit 2). */
static DrStatus check_bake(const char *bake_dir, const char *bake_key, int first, int last, DrError *err)
{
    DrManifest m;
    DR_TRY(dr_io_manifest_read(bake_dir, &m, err));
    char path[4096];
    snprintf(path, sizeof path, "%s/MANIFEST", bake_dir);
    if (!m.found)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "the shot has not been baked completely: the bake folder has no MANIFEST (the bake never "
                            "ran, or it stopped or failed); continue it with bake --resume, or run pipeline.sh");
    if (strcmp(m.key, bake_key) != 0)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "the frames were baked from another version of the scene (bake key %s, now %s); rerun "
                            "bake (pipeline.sh does it)",
                            m.key, bake_key);
    if (m.has_frames && (first < m.first || last > m.last)) {
        int f = first < m.first ? first : m.last + 1;
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "frame %d has not been baked: the bake holds frames %d-%d; continue it with bake --resume "
                            "--frames %d-%d (pipeline.sh does it)",
                            f, m.first, m.last, m.first, last);
    }
    int good;
    DrStatus s = dr_stage_check_frames(bake_dir, first, last, bake_key, true, &good, err);
    if (s != DR_ERR_INPUT) return s;
    dr_h5_drop_fix(err);
    char msg[sizeof err->message], file[sizeof err->file];
    snprintf(msg, sizeof msg, "%s", err->message);
    snprintf(file, sizeof file, "%s", err->file);
    return dr_error_set(err, DR_ERR_INPUT, file, 0, 0,
                        "frame %d cannot be meshed: %s; bake it again (pipeline.sh re-bakes from the first bad frame)",
                        good + 1, msg);
}

/* rest[i]: element i's collider mesh in its scene pose (loaded once; empty for other elements). */
static DrStatus mesh_frame(const DrScene *scene, const DrTriMesh *rest, const char *bake_dir, const char *dir,
                           int frame, int first_frame, const char *bake_key, double fps, long *triangles,
                           long *strands, DrError *err)
{
    char path[4096], out[4096];
    dr_stage_frame_path(bake_dir, "frame", frame, "h5", path, sizeof path);
    if (!dr_io_exists(path))
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "frame %d has not been baked; run bake (or pipeline.sh) first",
                            frame);
    DrH5 *h = NULL;
    DR_TRY(dr_h5_open(path, &h, err));
    char *key = NULL;
    DrStatus s = dr_h5_read_attr_str(h, "/", "scene_key", &key, err);
    if (s == DR_OK && strcmp(key, bake_key) != 0)
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "frame %d was baked from another version of the scene; rerun bake (pipeline.sh does it)",
                         frame);
    free(key);
    const DrComponent *ms = dr_scene_section(scene, "mesh");
    HairOutputs hair_out = hair_outputs(scene);
    for (int i = 0; s == DR_OK && i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind == DR_ELEMENT_COLLIDER && dr_component_present(dr_element_component(e, "Motion"))) {
            double *R = NULL, *t = NULL;
            int rank;
            uint64_t d1[4], d2[4];
            snprintf(path, sizeof path, "/%s/rotation", e->name);
            s = dr_h5_read_f64(h, path, &rank, d1, &R, err);
            snprintf(path, sizeof path, "/%s/translation", e->name);
            if (s == DR_OK) s = dr_h5_read_f64(h, path, &rank, d2, &t, err);
            /* the posed copy shares the rest mesh's triangles and owns only its vertices */
            DrTriMesh posed = rest[i];
            posed.n = NULL;
            posed.v = NULL;
            if (s == DR_OK) s = dr_calloc(3 * (size_t)posed.nv, sizeof(double), &posed.v, err);
            if (s == DR_OK) {
                apply_pose(rest[i].v, posed.nv, R, t, posed.v);
                dr_stage_frame_path(dir, e->name, frame, "obj", out, sizeof out);
                s = dr_io_write_obj(out, &posed, "drench collider (posed for this frame)", err);
            }
            free(posed.v);
            free(R);
            free(t);
            continue;
        }
        if (is_hair(e)) {
            DrVdbMeta meta = {frame, fps, bake_key};
            s = mesh_hair(e, h, dir, &meta, &hair_out, strands, triangles, err);
            continue;
        }
        if (is_bem(e)) {
            s = mesh_bem(e, h, dir, frame, triangles, err);
            continue;
        }
        if (is_cloth(e)) {
            s = mesh_cloth(e, h, dir, frame, triangles, err);
            continue;
        }
        bool liquid = e->kind == DR_ELEMENT_LIQUID;
        if (!liquid && e->kind != DR_ELEMENT_MPM_SOLID) continue;
        double *x = NULL, *v = NULL;
        int rank;
        uint64_t dx_[4], dv[4];
        snprintf(path, sizeof path, "/%s/position", e->name);
        s = dr_h5_read_f64(h, path, &rank, dx_, &x, err);
        snprintf(path, sizeof path, "/%s/velocity", e->name);
        if (s == DR_OK) s = dr_h5_read_f64(h, path, &rank, dv, &v, err);
        const DrComponent *dom = dr_element_component(e, "Domain");
        double cell = dr_component_num(dom, "voxel_size");
        /* Liquid particles sit 1/cbrt(per_cell) of a cell apart. Jittered within their sub-cells, their union
           of spheres has dips where an outer particle sits deep; a radius of 0.8 spacings (the default) gives
           back the seeded volume of a box within 2 % (tests/validation/test_world.c). MPM particles start on a
           lattice of cell/particles_per_axis and move with the material, so the same rule in their spacing
           gives the body's surface (slightly outside the sampled one, as for the liquid). */
        double spacing = liquid ? cell / cbrt((double)dr_component_int(dr_element_component(e, "Particles"), "per_cell"))
                                : cell / dr_component_int(dr_element_component(e, "MpmShape"), "particles_per_axis");
        double radius = dr_component_num(ms, "radius_scale") * spacing;
        double voxel = dr_component_num(ms, "voxel_size");
        /* The level set is the union of the particles' spheres; spheres under 1.5 voxels are rasterised at
           1.5 and the union eroded back, which needs voxel centres within a radius of the particles.
           Jittered liquid particles have them at half a cell; MPM particles start on a lattice that puts
           them half a voxel from every voxel centre, where the eroded union vanishes. So an MPM solid's
           automatic voxel resolves its spheres (radius / 1.5, at most half a cell). */
        if (voxel <= 0.0) voxel = liquid ? 0.5 * cell : fmin(0.5 * cell, radius / 1.5);
        else if (!liquid && frame == first_frame && radius < 1.5 * voxel)
            dr_log_warn("mesh.voxel_size = %g m is coarse for the particles of MPM solid '%s' (radius %g m, under 1.5 "
                        "voxels): its surface may break up; use mesh.voxel_size 0 (automatic) or at most %g m",
                        voxel, e->name, radius, radius / 1.5);
        /* MPM particles sit on a lattice, whose union of spheres rises over every particle column: a closing of
           one radius flattens the faces (vdb.h); jittered liquid particles keep their union as it is */
        DrVdbSurfaceDesc sd = {voxel, radius, dr_component_int(ms, "smoothing"), dr_component_num(ms, "adaptivity"),
                               liquid ? 0.0 : radius, dr_component_bool(ms, "velocity_interior")};
        DrVdbSurface *surf = NULL;
        if (s == DR_OK) s = dr_vdb_surface_from_particles(x, v, (long)dx_[0], &sd, &surf, err);
        if (s == DR_OK && dr_component_bool(ms, "write_vdb")) {
            DrVdbMeta meta = {frame, fps, bake_key};
            dr_stage_frame_path(dir, e->name, frame, "vdb", out, sizeof out);
            s = dr_vdb_surface_write(surf, out, &meta, err);
        }
        if (s == DR_OK && dr_component_bool(ms, "write_obj")) {
            DrTriMesh m = {0};
            s = dr_vdb_surface_to_mesh(surf, &m, err);
            if (s == DR_OK) {
                char comment[256];
                snprintf(comment, sizeof comment, "drench %s %s '%s' frame %d (m, y up)", DR_VERSION,
                         liquid ? "liquid" : "MPM solid", e->name, frame);
                dr_stage_frame_path(dir, e->name, frame, "obj", out, sizeof out);
                s = dr_io_write_obj(out, &m, comment, err);
                *triangles += m.nt;
            }
            dr_trimesh_free(&m);
        }
        if (s == DR_OK && dr_component_bool(ms, "write_points")) {
            DrVdbMeta meta = {frame, fps, bake_key};
            s = write_particle_points(e, h, dir, &meta, (long)dx_[0], x, v, err);
        }
        dr_vdb_surface_destroy(&surf);
        free(x);
        free(v);
    }
    dr_h5_close(&h);
    return s;
}

/* ---- frames in parallel --------------------------------------------------------------------------------- */

/* The frames first .. first + nframes − 1, taken in order by `workers` threads, each meshing one frame at a time
 * with OpenVDB limited to vdb_threads threads. A frame that fails stops the others from taking more; the
 * frames in flight finish. */
typedef struct FrameJob {
    const DrScene *scene;
    const DrTriMesh *rest;
    const char *bake_dir, *dir, *bake_key;
    double fps;
    int first, nframes, vdb_threads;
    atomic_int next;       /* index of the next frame to take */
    atomic_bool stop;      /* a frame failed */
    DrStatus *status;      /* per frame; frames never taken stay DR_OK */
    DrError *errors;       /* per frame */
    long *triangles, *strands; /* per frame */
    DrProgress *prog;
    pthread_mutex_t *lock; /* the progress lines */
} FrameJob;

static void mesh_frames(void *ctx)
{
    FrameJob *job = ctx;
    for (;;) {
        if (atomic_load(&job->stop)) return;
        int k = atomic_fetch_add(&job->next, 1);
        if (k >= job->nframes) return;
        int frame = job->first + k;
        double t = dr_time_now();
        dr_error_clear(&job->errors[k]);
        job->status[k] = mesh_frame(job->scene, job->rest, job->bake_dir, job->dir, frame, job->first, job->bake_key,
                                    job->fps, &job->triangles[k], &job->strands[k], &job->errors[k]);
        if (job->status[k] < 0) {
            atomic_store(&job->stop, true);
            return;
        }
        char detail[128];
        snprintf(detail, sizeof detail, "frame %d %.2fs", frame, dr_time_now() - t);
        pthread_mutex_lock(job->lock);
        dr_progress_step(job->prog, detail);
        pthread_mutex_unlock(job->lock);
    }
}

/* One frame thread: mesh_frames inside its OpenVDB thread limit. */
static void frame_thread(long begin, long end, void *ctx)
{
    FrameJob *job = ctx;
    for (long w = begin; w < end; w++) {
        DrError err;
        if (dr_vdb_run_with_threads(job->vdb_threads, mesh_frames, job, &err) < 0) {
            /* no thread limit could be set up: the next frame (if any is left) carries the failure */
            int k = atomic_fetch_add(&job->next, 1);
            if (k < job->nframes) {
                job->status[k] = err.status;
                job->errors[k] = err;
            }
            atomic_store(&job->stop, true);
        }
    }
}

/* Meshes frames first..last on up to `threads` frames at once (fewer when there are fewer frames, each then
 * with threads / frames in flight OpenVDB threads); the error of the lowest failing frame goes to err (every
 * frame below it was taken before it, and every frame taken finishes). *in_flight: the frames at once. */
static DrStatus mesh_frame_range(const DrScene *scene, const DrTriMesh *rest, const char *bake_dir, const char *dir,
                                 int first, int last, const char *bake_key, double fps, int threads, long *triangles,
                                 long *strands, int *in_flight, DrError *err)
{
    int nframes = last - first + 1;
    int workers = threads < nframes ? threads : nframes;
    if (workers < 1) workers = 1;
    /* a thread-unsafe HDF5 build cannot be read from several threads: one frame at a time then */
    if (!dr_h5_threadsafe()) workers = 1;
    *in_flight = workers;
    DrStatus *status = NULL;
    DrError *errors = NULL;
    long *tri = NULL, *str = NULL;
    DrStatus s = dr_calloc((size_t)nframes, sizeof *status, &status, err);
    if (s == DR_OK) s = dr_calloc((size_t)nframes, sizeof *errors, &errors, err);
    if (s == DR_OK) s = dr_calloc((size_t)nframes, sizeof *tri, &tri, err);
    if (s == DR_OK) s = dr_calloc((size_t)nframes, sizeof *str, &str, err);
    DrProgress prog;
    pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
    if (s == DR_OK) {
        FrameJob job = {.scene = scene, .rest = rest, .bake_dir = bake_dir, .dir = dir, .bake_key = bake_key,
                        .fps = fps, .first = first, .nframes = nframes,
                        .vdb_threads = threads / workers > 1 ? threads / workers : 1, .status = status,
                        .errors = errors, .triangles = tri, .strands = str, .prog = &prog, .lock = &lock};
        atomic_init(&job.next, 0);
        atomic_init(&job.stop, false);
        dr_progress_begin(&prog, "mesh", nframes);
        /* workers threads, one frame thread each (dr_parallel_for makes as many chunks when -j allows it) */
        dr_parallel_for(workers, 1, frame_thread, &job);
        dr_progress_end(&prog);
        for (int k = 0; k < nframes && s == DR_OK; k++) {
            if (status[k] < 0) {
                s = status[k];
                *err = errors[k];
            }
            *triangles += tri[k];
            *strands += str[k];
        }
    }
    free(status);
    free(errors);
    free(tri);
    free(str);
    return s;
}

/* mesh --finish: every output a full run would have written must be there (the frame ranges ran as separate
 * processes, e.g. a farm's job array); then the folder is complete and the MANIFEST may say so. */
static DrStatus check_outputs(const DrScene *scene, const char *dir, int first, int last, DrError *err)
{
    const DrComponent *ms = dr_scene_section(scene, "mesh");
    HairOutputs hair = hair_outputs(scene);
    char path[4096];
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        /* liquid and MPM solids are surfaced alike, one file per frame */
        bool liquid = e->kind == DR_ELEMENT_LIQUID || e->kind == DR_ELEMENT_MPM_SOLID;
        bool collider = e->kind == DR_ELEMENT_COLLIDER;
        bool moving = collider && dr_component_present(dr_element_component(e, "Motion"));
        if (collider) {
            snprintf(path, sizeof path, "%s/%s.obj", dir, e->name);
            if (!dr_io_exists(path)) goto missing;
        }
        char ribbons[1024], tubes[1024];
        snprintf(ribbons, sizeof ribbons, "%s_ribbons", e->name);
        snprintf(tubes, sizeof tubes, "%s_wet", e->name);
        for (int f = first; f <= last; f++) {
            /* (prefix, extension) of each file this element writes per frame */
            const char *file[5][2] = {{NULL, NULL}, {NULL, NULL}, {NULL, NULL}, {NULL, NULL}, {NULL, NULL}};
            if (liquid && dr_component_bool(ms, "write_obj")) file[0][0] = e->name, file[0][1] = "obj";
            if (liquid && dr_component_bool(ms, "write_vdb")) file[1][0] = e->name, file[1][1] = "vdb";
            if (moving || is_hair(e) || is_bem(e) || is_cloth(e)) file[0][0] = e->name, file[0][1] = "obj";
            if (is_hair(e) && dr_component_bool(ms, "hair_ribbons")) file[2][0] = ribbons, file[2][1] = "obj";
            if ((liquid || is_hair(e)) && dr_component_bool(ms, "write_points"))
                file[3][0] = e->name, file[3][1] = "points.vdb";
            if (is_hair(e) && hair.tubes) file[4][0] = tubes, file[4][1] = "obj";
            for (int k = 0; k < 5; k++) {
                if (!file[k][0]) continue;
                dr_stage_frame_path(dir, file[k][0], f, file[k][1], path, sizeof path);
                if (!dr_io_exists(path))
                    return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                                        "mesh --finish: frame %d of element '%s' is missing; run mesh --frames %d-%d "
                                        "(or pipeline.sh) first",
                                        f, e->name, f, f);
            }
        }
    }
    return DR_OK;
missing:
    return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                        "mesh --finish: the collider mesh is missing; run mesh --frames on any range first");
}

int main(int argc, char **argv)
{
    DrError err;
    dr_error_clear(&err);
    DrStageArgs args;
    bool done;
    double t0 = dr_time_now();
    DrScene *scene = NULL;
    DrSceneKeys keys;
    char dir[2048], bake_dir[2048];
    if (dr_stage_begin(DR_STAGE_MESH, argc, argv, &args, &scene, &keys, dir, sizeof dir, &done, &err) < 0)
        return fail(&err);
    if (done) return 0;
    int first, last;
    DrStatus s = dr_stage_frame_range(&args, scene, &first, &last, &err);
    dr_stage_out_dir(&args, scene, DR_STAGE_BAKE, bake_dir, sizeof bake_dir);
    if (s == DR_OK && args.finish) {
        char line[128];
        snprintf(line, sizeof line, "frames %d-%d (ran in separate ranges)", first, last);
        const char *inputs[2] = {line, keys.bake};
        s = check_outputs(scene, dir, first, last, &err);
        if (s == DR_OK)
            s = dr_io_manifest_write_frames(dir, "mesh", keys.mesh, dr_scene_path(scene), first, last, inputs, 2, &err);
        dr_scene_destroy(&scene);
        if (s < 0) return fail(&err);
        fprintf(stderr, "mesh: frames %d-%d complete in %s; MANIFEST written\n", first, last, dir);
        return 0;
    }
    /* The output names, and every collider asset (loaded once), are checked before anything is written. */
    if (s == DR_OK) s = check_hair_names(scene, &err);
    if (s == DR_OK && dr_component_bool(dr_scene_section(scene, "mesh"), "wet_tubes") && !wet_scene(scene))
        dr_log_warn("%s: mesh.wet_tubes is set but no hair element is wet (none has a Wetting component): no wet tubes "
                    "are written",
                    dr_scene_path(scene));
    int nel = dr_scene_element_count(scene);
    DrTriMesh *rest = NULL;
    if (s == DR_OK) s = dr_calloc((size_t)nel + 1, sizeof(DrTriMesh), &rest, &err);
    for (int i = 0; s == DR_OK && i < nel; i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind == DR_ELEMENT_COLLIDER) s = dr_stage_load_collider_mesh(e, &rest[i], &err);
    }
    if (s == DR_OK) s = check_bake(bake_dir, keys.bake, first, last, &err);
    if (s == DR_OK) s = dr_vdb_init(&err);
    if (s == DR_OK) s = dr_io_mkdirs(dir, &err);
    const char *inputs[1] = {keys.bake};
    DrStageFrames run;
    if (s == DR_OK)
        s = dr_stage_frames_begin(dir, DR_STAGE_MESH, keys.mesh, scene, first, last, true, inputs, 1, &run, &err);
    /* A frame range may run beside others on other machines (a farm's job array), whose temporary files
       look stale from here: only a run that owns the whole folder clears them. */
    if (s == DR_OK && !args.frames_given) dr_io_remove_stale_tmp(dir);
    /* colliders once, in their scene pose */
    for (int i = 0; s == DR_OK && i < nel; i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_COLLIDER) continue;
        char out[4096];
        snprintf(out, sizeof out, "%s/%s.obj", dir, e->name);
        s = dr_io_write_obj(out, &rest[i], "drench collider (scene pose)", &err);
    }
    double fps = dr_component_num(dr_scene_section(scene, "shot"), "fps");
    long triangles = 0, strands = 0;
    int in_flight = 1;
    if (s == DR_OK)
        s = mesh_frame_range(scene, rest, bake_dir, dir, first, last, keys.bake, fps, dr_threads(), &triangles,
                             &strands, &in_flight, &err);
    if (s == DR_OK) s = dr_stage_frames_end(&run, inputs, 1, &err);
    char hair[64] = "";
    if (dr_scene_count_kind(scene, DR_ELEMENT_HAIR) > 0) snprintf(hair, sizeof hair, " and %ld strands", strands);
    for (int i = 0; rest && i < nel; i++) dr_trimesh_free(&rest[i]);
    free(rest);
    dr_scene_destroy(&scene);
    if (s < 0) return fail(&err);
    char rss[32];
    dr_format_bytes(dr_peak_rss_bytes(), rss, sizeof rss);
    fprintf(stderr, "mesh: %d frames in %.1fs (%d at a time), %ld triangles%s written to %s, peak RSS %s\n",
            last - first + 1, dr_time_now() - t0, in_flight, triangles, hair, dir, rss);
    return 0;
}
