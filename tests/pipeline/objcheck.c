/* objcheck FILE.obj...: reloads every OBJ through assimp (dr_io_load_mesh) and checks that liquid surfaces
 * (files named <element>.NNNN.obj) are closed with positive (outward) signed volume. Prints one line per
 * file; exit 0 when all pass. Used by tests/pipeline/test_pipeline.sh. */
#include <string.h>

#include "io/io.h"

int main(int argc, char **argv)
{
    int bad = 0;
    for (int i = 1; i < argc; i++) {
        DrTriMesh m = {0};
        DrError err;
        if (dr_io_load_mesh(argv[i], &m, &err) < 0) {
            dr_error_print("objcheck", &err);
            bad++;
            continue;
        }
        const char *base = strrchr(argv[i], '/');
        base = base ? base + 1 : argv[i];
        bool framed = strchr(base, '.') != strrchr(base, '.'); /* name.NNNN.obj */
        bool closed = dr_trimesh_is_closed(&m);
        double vol = dr_trimesh_volume(&m);
        DrVec3 lo = {0, 0, 0}, hi = {0, 0, 0};
        dr_trimesh_bounds(&m, &lo, &hi);
        printf("%s: %d vertices, %d triangles, volume %.6g m^3, %s, centre %.6g %.6g %.6g\n", base, m.nv, m.nt,
               vol, closed ? "closed" : "open", 0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), 0.5 * (lo.z + hi.z));
        if (framed && (!closed || vol <= 0.0)) bad++;
        dr_trimesh_free(&m);
    }
    return bad ? 1 : 0;
}
