/* drench vdb: a C interface over OpenVDB 10 for the three things the pipeline needs from it:
 * collider signed distance fields sampled on a dense grid, the liquid surface as a narrow-band
 * level set built from particles (with a velocity grid), and that level set as a triangle mesh
 * and as a .vdb file (DESIGN §4 "Mesh outputs").
 *
 * Every function catches every C++ exception inside and reports it as a DrStatus:
 * bad arguments -> DR_ERR_INPUT, allocation failure -> DR_ERR_NOMEM, file errors -> DR_ERR_IO,
 * anything else OpenVDB throws -> DR_ERR_RUNTIME. Nothing here terminates the process.
 *
 * Thread safety: all functions may be called from several threads on different objects;
 * functions taking a `const DrVdbSurface *` do not modify it. OpenVDB runs its own TBB worker
 * threads inside these calls.
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
                          closing of one radius (the mesh stage's choice for MPM solids). Gaps narrower than about 2 * closing between separate
                          bodies are bridged; 0 = the union of spheres as it is (as before the
                          closing existed, bit for bit). */
} DrVdbSurfaceDesc;

/* voxel_size 0.004 m, radius 0.006 m (1.5 voxels), smoothing 1, adaptivity 0, closing 0. */
DrVdbSurfaceDesc dr_vdb_surface_desc_default(void);

/* Owns a FloatGrid "surface" (class level set, narrow band 3 voxels on each side, uniform transform
 * of voxel_size, zero translation: voxel (i,j,k) is centred at voxel_size*(i,j,k)) and a Vec3SGrid
 * "vel" (m/s, contravariant-relative vectors) with the surface grid's active topology. */
typedef struct DrVdbSurface DrVdbSurface;

/* Builds the liquid surface as the union of spheres of `desc->radius` around the particles, closed
 * by `desc->closing`: tools::ParticlesToLevelSet at the radius plus the closing (and at least 1.5
 * voxels), then tools::levelSetRebuild at the level that takes the spheres back to the radius
 * (with a closing: first to a signed distance, then at the level that erodes the union back), then
 * `desc->smoothing` passes of tools::LevelSetFilter::meanCurvature.
 * pos: 3n doubles (m); vel: 3n doubles (m/s) or NULL (then "vel" is zero). n may be 0: an empty
 * surface (no active voxels). At each active voxel of the surface "vel" holds the velocity of the
 * particle closest to the voxel centre (ParticlesToLevelSet attribute transfer; a voxel exactly
 * equidistant from two particles takes either's). Inputs are copied; nothing is kept.
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

#ifdef __cplusplus
}
#endif

#endif
