/* A rectangular cloth panel for the cloth tests and benchmark: nx × ny vertices on [0, lx] × [0, ly] in the plane
 * y = y0 (x along x, the other side along z), wound so that the normals point up (+y). Vertex (i, j) is i + nx j. The
 * mesh's arrays are malloc'd (dr_trimesh_free).
 * cloth_grid splits every cell along the diagonal from (i, j) to (i + 1, j + 1); cloth_grid_alternating alternates the
 * diagonal from cell to cell like a chessboard, so that the mesh is symmetric about both axes (a hinge mesh with
 * every diagonal one way couples bending to twisting, see src/cloth/shell.h). */
#ifndef DR_TESTS_CLOTH_GRID_H
#define DR_TESTS_CLOTH_GRID_H

#include <stdlib.h>

#include "core/core.h"

static inline int cloth_grid_pattern(int nx, int ny, double lx, double ly, double y0, bool alternate, DrTriMesh *m)
{
    m->nv = nx * ny;
    m->nt = 2 * (nx - 1) * (ny - 1);
    m->v = malloc(3 * (size_t)m->nv * sizeof(double));
    m->tri = malloc(3 * (size_t)m->nt * sizeof(int));
    m->n = NULL;
    m->uv = NULL;
    if (!m->v || !m->tri) return -1;
    for (int j = 0; j < ny; j++)
        for (int i = 0; i < nx; i++) {
            double *p = m->v + 3 * (i + nx * j);
            p[0] = lx * i / (nx - 1);
            p[1] = y0;
            p[2] = ly * j / (ny - 1);
        }
    int t = 0;
    for (int j = 0; j + 1 < ny; j++)
        for (int i = 0; i + 1 < nx; i++) {
            int a = i + nx * j, b = a + 1, c = a + nx, d = c + 1;
            /* (x, z) plane seen from +y: a → c → d turns counter-clockwise */
            int *q = m->tri + 3 * t;
            if (alternate && (i + j) % 2) {
                q[0] = a, q[1] = c, q[2] = b;
                q[3] = b, q[4] = c, q[5] = d;
            } else {
                q[0] = a, q[1] = c, q[2] = d;
                q[3] = a, q[4] = d, q[5] = b;
            }
            t += 2;
        }
    return 0;
}

static inline int cloth_grid(int nx, int ny, double lx, double ly, double y0, DrTriMesh *m)
{
    return cloth_grid_pattern(nx, ny, lx, ly, y0, false, m);
}
static inline int cloth_grid_alternating(int nx, int ny, double lx, double ly, double y0, DrTriMesh *m)
{
    return cloth_grid_pattern(nx, ny, lx, ly, y0, true, m);
}

#endif
