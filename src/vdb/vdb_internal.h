/* Private to src/vdb and its tests. */
#ifndef DR_VDB_INTERNAL_H
#define DR_VDB_INTERNAL_H

#include "vdb/vdb.h"

#ifdef __cplusplus
extern "C" {
#endif

/* dr_vdb_mesh_to_sdf with OpenVDB's own sign, the flood fill from outside (enclosed cavities come
 * out solid, with distances to the outer surface only): the field dr_vdb_mesh_to_sdf gave before it
 * counted crossings, which tests compare it with on meshes without cavities. Same arguments,
 * errors and ownership as dr_vdb_mesh_to_sdf. */
DR_NODISCARD DrStatus dr_vdb_mesh_to_sdf_flood_fill_(const DrTriMesh *mesh, double dx, int pad_voxels,
                                                     DrDenseSdf *out, DrError *err);

/* The votes of the grid lines through each node of `grid`'s node box (its nx, ny, nz, origin and dx;
 * phi is not read) as dr_vdb_mesh_to_sdf counts them: per line +1 inside, -1 outside, 0 where the
 * counts from the line's two ends disagree, summed over the three lines into votes[nx*ny*nz]
 * (x fastest). On a closed mesh every node off the surface gets +3 or -3. Errors: DR_ERR_INPUT for a
 * bad mesh, DR_ERR_NOMEM, DR_ERR_RUNTIME. */
DR_NODISCARD DrStatus dr_vdb_crossing_votes_(const DrTriMesh *mesh, const DrDenseSdf *grid, int8_t *votes,
                                            DrError *err);

#ifdef __cplusplus
}
#endif

#endif
