/* drench vdb: a C interface over OpenVDB 10 for the things the pipeline needs from it:
 * collider signed distance fields sampled on a dense grid, the liquid surface as a narrow-band
 * level set built from particles (with a velocity grid), that level set as a triangle mesh
 * and as a .vdb file (DESIGN §4 "Mesh outputs"), and particles as OpenVDB point data.
 *
 * Every function catches every C++ exception inside and reports it as a DrStatus:
 * bad arguments -> DR_ERR_INPUT, allocation failure -> DR_ERR_NOMEM, file errors -> DR_ERR_IO,
 * anything else OpenVDB throws -> DR_ERR_RUNTIME. Nothing here terminates the process.
 *
 * Thread safety: all functions may be called from several threads on different objects;
 * functions taking a `const DrVdbSurface *` do not modify it. OpenVDB runs its own TBB worker
 * threads inside these calls (as many as there are cores, or as dr_vdb_run_with_threads allows).
 * Results and files do not depend on the number of threads.
 *
 * Units: metres and metres per second, like the rest of drench. */
#ifndef DR_VDB_H
#define DR_VDB_H

#ifdef __cplusplus
/* core.h is C: its declarations get C linkage. Its system headers come first, outside the
 * extern "C" block, because in C++ they pull in C++ library headers. */
#include <assert.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
extern "C" {
#include "core/core.h"
}
extern "C" {
#else
#include "core/core.h"
#endif

/* Initialises OpenVDB (registers grid and metadata types). Idempotent and thread-safe; every other
 * function here calls it itself, so calling it is only needed to report a failure early. */
DR_NODISCARD DrStatus dr_vdb_init(DrError *err);

/* Runs fn(ctx) on the calling thread with every OpenVDB algorithm it calls (through the functions
 * below) limited to `threads` threads, the calling one included: a TBB task arena of that
 * concurrency. So callers on several threads of their own, each with threads = 1, run side by side
 * without taking each other's cores (the mesh stage's frames in flight), and threads = all cores
 * gives one caller every core. fn is C and reports its own failures through ctx. DR_ERR_INPUT for
 * threads < 1; DR_ERR_RUNTIME if TBB cannot make the arena (fn has not run). */
typedef void (*DrVdbTask)(void *ctx);
DR_NODISCARD DrStatus dr_vdb_run_with_threads(int threads, DrVdbTask fn, void *ctx, DrError *err);

/* ---- collider signed distance fields --------------------------------------------------------- */

/* A signed distance field sampled at the nodes of a dense grid; negative inside.
 * Node (i,j,k) is at origin + dx*(i,j,k); phi holds nx*ny*nz floats, x fastest:
 * phi[i + nx*(j + ny*k)], in metres. Owned by the struct: free with dr_dense_sdf_free. */
typedef struct DrDenseSdf {
    int nx, ny, nz;
    DrVec3 origin; /* m */
    double dx;     /* m */
    float *phi;
} DrDenseSdf;

/* Largest number of nodes (nx*ny*nz) dr_vdb_mesh_to_sdf produces: 512^3 (512 MiB of floats). */
#define DR_VDB_SDF_MAX_NODES (512L * 512L * 512L)

/* Samples the signed distance to `mesh` (metres, CCW-outward triangles) at the nodes of a grid of
 * spacing `dx` (m) covering the mesh bounds plus `pad_voxels` (>= 0) nodes on every side. The origin
 * is a multiple of dx, so grids of the same dx from different meshes share their nodes.
 * Values: inside the mesh phi is the distance to the surface everywhere (negative); outside it is
 * the distance up to max(3, pad_voxels + 1) voxels from the surface and clamped to
 * +max(3, pad_voxels + 1)*dx beyond. Distances come from OpenVDB's meshToVolume.
 * Sign: a node is inside where the winding number of the surface around it is not zero, counted
 * exactly along the three grid lines through it (signed crossings; rays through edges and vertices,
 * as on an axis-aligned cube with its corners on nodes, count once). So the sign is correct at every
 * node of a closed mesh, unwelded seams (the same positions under separate indices) included: an
 * enclosed cavity (an inner shell facing into a hollow, as in a closed tank) is outside, positive and
 * clamped like the exterior, with the material around it at its distance to the nearer surface; a
 * solid in that hollow is inside again; overlapping shells are solid where they overlap; an
 * inside-out mesh is solid. Nodes within 1e-3 voxel of the surface may take either sign. On a closed
 * mesh without cavities the field is OpenVDB's, whose flood fill from outside gets the sign right
 * there. A cavity costs one more meshToVolume per shell that bounds it, with a band as deep as the
 * solid's deepest node (measured: a fifth more time for a thick hollow ball on 301^3 nodes).
 * A mesh that is not closed (an edge not shared by exactly two oppositely oriented triangles) still
 * gives a field, with a dr_log_warn line that gives the count of open edges. A grid line through a
 * hole crosses the surface unevenly and does not vote where the counts from its two ends disagree;
 * each node takes the majority of its lines' votes, so it keeps the right sign while at most one of
 * its three lines passes through holes (a missing face leaves the interior inside), and takes
 * OpenVDB's flood-fill sign when the votes tie. Where the flood fill runs in through a hole, the
 * interior keeps the distance OpenVDB computed as outside: to the remaining triangles, capped at
 * the exterior band.
 * Errors (out untouched): DR_ERR_INPUT for an empty mesh, a vertex index out of range, a non-finite
 * vertex, dx not finite and positive, pad_voxels < 0, or a grid of more than DR_VDB_SDF_MAX_NODES
 * nodes (the message says to use a larger voxel size); DR_ERR_NOMEM; DR_ERR_RUNTIME. */
DR_NODISCARD DrStatus dr_vdb_mesh_to_sdf(const DrTriMesh *mesh, double dx, int pad_voxels,
                                         DrDenseSdf *out, DrError *err);
/* Frees phi and zeroes the struct; NULL and an already freed struct are no-ops. */
void dr_dense_sdf_free(DrDenseSdf *sdf);

/* ---- liquid surface from particles ---------------------------------------------------------- */

typedef struct DrVdbSurfaceDesc {
    double voxel_size; /* m, finite and > 0 */
    double radius;     /* particle radius, m, finite and > 0: the surface lies this far beyond the
                          outermost particle centres. ParticlesToLevelSet resolves spheres of at
                          least 1.5 voxels; a smaller radius is rasterised at 1.5 voxels and the
                          union is then eroded by the difference (levelSetRebuild at that level),
                          which also fills the gaps between neighbouring particles. */
    int smoothing;     /* >= 0 passes of mean-curvature flow, each followed by renormalisation */
    double adaptivity; /* volumeToMesh adaptivity in [0, 1]; 0 = uniform triangles */
    double closing;    /* m, finite and >= 0: morphological closing of the union of spheres (dilated by
                          `closing`, then eroded by as much), which fills the dips between neighbouring
                          spheres and leaves convex parts where they are. Particles on a lattice (an MPM
                          solid) otherwise give a flat face one bump per particle column: 0.28 spacings
                          high for spheres of 0.8 spacings after one smoothing pass, against 0.02 with a
                          closing of one radius (the mesh stage's choice for MPM solids). Gaps narrower than
                          about 2 * closing between separate bodies are bridged; 0 = the union of spheres as
                          it is (as before the closing existed, bit for bit). */
    bool velocity_interior; /* "vel" covers the whole liquid: the narrow band and every voxel inside
                               the surface; false: the narrow band only */
} DrVdbSurfaceDesc;

/* voxel_size 0.004 m, radius 0.006 m (1.5 voxels), smoothing 1, adaptivity 0, closing 0, velocity on the band. */
DrVdbSurfaceDesc dr_vdb_surface_desc_default(void);

/* Owns a FloatGrid "surface" (class level set, narrow band 3 voxels on each side, uniform transform
 * of voxel_size, zero translation: voxel (i,j,k) is centred at voxel_size*(i,j,k)) and a Vec3SGrid
 * "vel" (m/s, contravariant-relative vectors) with the surface grid's active topology, and with
 * desc.velocity_interior also every voxel inside the surface active (as voxels, not tiles). */
typedef struct DrVdbSurface DrVdbSurface;

/* Builds the liquid surface as the union of spheres of `desc->radius` around the particles, closed
 * by `desc->closing`: tools::ParticlesToLevelSet at the radius plus the closing (and at least 1.5
 * voxels), then tools::levelSetRebuild at the level that takes the spheres back to the radius
 * (with a closing: first to a signed distance, then at the level that erodes the union back), then
 * `desc->smoothing` passes of tools::LevelSetFilter::meanCurvature.
 * pos: 3n doubles (m); vel: 3n doubles (m/s) or NULL (then "vel" is zero). n may be 0: an empty
 * surface (no active voxels). At each active voxel of "vel" (the band's, and with
 * desc->velocity_interior the interior's) it holds the velocity of the particle closest to the
 * voxel centre (ParticlesToLevelSet attribute transfer, which reaches radius + 4 voxels from each
 * particle; a voxel exactly equidistant from two particles takes either's; a voxel out of that
 * reach takes its nearest reached voxel's within 2 voxels, else zero). Inputs are copied; nothing is
 * kept.
 * Errors (*out left NULL): DR_ERR_INPUT for n < 0, pos NULL with n > 0, a non-finite position or
 * velocity, a position farther than 2^30 voxels from the origin, or a desc field out of its range;
 * DR_ERR_NOMEM; DR_ERR_RUNTIME. */
DR_NODISCARD DrStatus dr_vdb_surface_from_particles(const double *pos, const double *vel, long n,
                                                    const DrVdbSurfaceDesc *desc,
                                                    DrVdbSurface **out, DrError *err);
void dr_vdb_surface_destroy(DrVdbSurface **s); /* frees and NULLs; NULL is a no-op */

/* Volume enclosed by the zero level set, m^3 (tools::levelSetVolume); 0 for an empty surface.
 * NaN (with a dr_log_error line) only if OpenVDB fails. */
double dr_vdb_surface_volume(const DrVdbSurface *s);
/* Voxel size of the surface grid, m. */
double dr_vdb_surface_voxel_size(const DrVdbSurface *s);
/* Number of active voxels of the surface grid (the narrow band); 0 for an empty surface
 * (-1 with a dr_log_error line only if OpenVDB fails). */
long dr_vdb_surface_active_voxels(const DrVdbSurface *s);
/* Velocity (m/s) stored in "vel" at the voxel whose centre is nearest to world point p (zero off
 * the band, and with a dr_log_error line if OpenVDB fails). */
DrVec3 dr_vdb_surface_velocity_at(const DrVdbSurface *s, DrVec3 p);

/* Polygonises the zero level set (tools::volumeToMesh with desc->adaptivity) into `out`, which must
 * be zeroed or freed on entry and is owned by the caller afterwards (dr_trimesh_free). Quads are
 * split along their shorter diagonal; triangles wind counter-clockwise seen from outside; vertices
 * are shared, so the mesh of a closed surface is closed; out->n holds per-vertex outward unit
 * normals (the normalised level-set gradient, or the area-weighted face normal where the gradient
 * vanishes). Vertices no triangle uses are dropped. An empty surface gives nv = nt = 0 and NULL
 * arrays. Errors (out left zeroed): DR_ERR_NOMEM, DR_ERR_RUNTIME (more than INT_MAX vertices or
 * triangles, or an OpenVDB failure). */
DR_NODISCARD DrStatus dr_vdb_surface_to_mesh(const DrVdbSurface *s, DrTriMesh *out, DrError *err);

/* File metadata written next to the grids. */
typedef struct DrVdbMeta {
    int frame;
    double fps;
    const char *bake_key; /* NULL is written as "" */
} DrVdbMeta;

/* Writes a .vdb with the grids "surface" and "vel" and the file metadata creator
 * ("drench " DR_VERSION), frame (int32), fps (double), units ("m"), up_axis ("y") and bake_key
 * (string). Atomic: written to "<path>.tmp.<pid>" and renamed onto `path`, so `path` is either the
 * old file or the complete new one. Errors: DR_ERR_IO naming the path (the temporary file is
 * removed); DR_ERR_NOMEM; DR_ERR_RUNTIME. */
DR_NODISCARD DrStatus dr_vdb_surface_write(const DrVdbSurface *s, const char *path,
                                           const DrVdbMeta *meta, DrError *err);

/* Comma-separated names of the grids in the .vdb at `path`, in file order ("surface,vel" for a file
 * written above) into grid_names (NUL-terminated). Errors: DR_ERR_IO naming the path if it cannot
 * be opened or is not a .vdb; DR_ERR_INPUT if `size` is too small for the names. */
DR_NODISCARD DrStatus dr_vdb_file_info(const char *path, char *grid_names, size_t size,
                                       DrError *err);
/* The file metadata item `key` of the .vdb at `path` as text (OpenVDB's Metadata::str(): "12" for
 * an int, "24" for a double, the string itself for a string) into value. Errors: DR_ERR_IO as
 * above; DR_ERR_INPUT if the file has no such item or `size` is too small. */
DR_NODISCARD DrStatus dr_vdb_file_meta(const char *path, const char *key, char *value,
                                       size_t size, DrError *err);

/* ---- particles as OpenVDB point data ---------------------------------------------------------- */

typedef enum DrVdbAttrType {
    DR_VDB_ATTR_FLOAT, /* one number per point, from `f` (n doubles), stored as a 32-bit float */
    DR_VDB_ATTR_VEC3,  /* three numbers per point, from `f` (3n doubles), stored as 3 32-bit floats */
    DR_VDB_ATTR_INT64  /* one 64-bit integer per point, from `i` (n values) */
} DrVdbAttrType;

/* A point attribute: `name` (not "P", which holds the positions; names unique within a call) and its values,
 * borrowed for the call. */
typedef struct DrVdbPointAttr {
    const char *name;
    DrVdbAttrType type;
    const double *f;
    const int64_t *i;
} DrVdbPointAttr;

/* Writes n points (pos: 3n doubles, m) as one PointDataGrid named "points" (OpenVDB's points API:
 * createPointDataGrid, then appendAttribute/populateAttribute per attribute) with the file metadata of
 * dr_vdb_surface_write. Positions "P" are stored as 32-bit float offsets within their voxel (uncompressed
 * codec), so they come back to within 1e-7 of a voxel; the points are ordered voxel by voxel (OpenVDB's
 * layout), every attribute in the same order. voxel_size (m) is the grid's: > 0, or 0 to let OpenVDB choose
 * one for about 8 points per voxel (points::computeVoxelSize); the transform is uniform with zero
 * translation. n may be 0 (a grid without points). Atomic and byte-reproducible like dr_vdb_surface_write
 * (the same inputs give the same bytes). Errors (nothing written): DR_ERR_INPUT for n < 0, pos NULL with
 * n > 0, a non-finite position or attribute value, a position beyond 2^30 voxels, voxel_size < 0 or not
 * finite, an attribute named "P", twice, empty, or without its values; DR_ERR_IO naming the path;
 * DR_ERR_NOMEM; DR_ERR_RUNTIME. */
DR_NODISCARD DrStatus dr_vdb_points_write(const char *path, long n, const double *pos, const DrVdbPointAttr *attrs,
                                          int nattrs, double voxel_size, const DrVdbMeta *meta, DrError *err);

/* Reads attribute `name` of the grid "points" of the .vdb at `path`, in the file's point order: "P" gives the
 * world positions (3 per point), a float attribute 1 number per point, a Vec3 attribute 3 (both into *f), an
 * integer attribute of any size 1 value per point (into *i). *n is the point count, *width the numbers per
 * point; the array not filled is NULL, the other is malloc'd (caller frees; non-NULL for 0 points). A grid
 * without points stores no attributes: any name gives 0 values (width 3 for "P", else 1, into *f). Errors
 * (outputs NULL): DR_ERR_IO as dr_vdb_file_info; DR_ERR_INPUT when the file has no PointDataGrid "points" or
 * its points have no such attribute (or one of another type); DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_vdb_points_read(const char *path, const char *name, long *n, int *width, double **f,
                                         int64_t **i, DrError *err);

/* Comma-separated names of the attributes of the grid "points" of the .vdb at `path` in their stored order
 * ("P,v,id,volume") into names (empty for a grid without points). Errors as dr_vdb_points_read; DR_ERR_INPUT
 * also if `size` is too small. */
DR_NODISCARD DrStatus dr_vdb_points_attributes(const char *path, char *names, size_t size, DrError *err);

#ifdef __cplusplus
}
#endif

#endif
