/* Asset meshes: loading through assimp's C API and writing OBJ files. */
#include "io/io.h"

#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <errno.h>
#include <limits.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

/* ---- loading ---- */

/* Assimp's OBJ reader skips lines it does not understand, so garbage bytes come back as "no
 * triangles". A text OBJ never holds control bytes other than whitespace; finding one is the
 * better diagnosis (a corrupt or mislabelled file). Returns the offset of the first such byte or -1. */
static long first_binary_byte(FILE *f, unsigned char *byte)
{
    unsigned char buf[65536];
    size_t got = fread(buf, 1, sizeof buf, f);
    for (size_t i = 0; i < got; i++) {
        unsigned char c = buf[i];
        if (c < 0x20 && c != '\t' && c != '\n' && c != '\r' && c != '\f' && c != '\v') {
            *byte = c;
            return (long)i;
        }
    }
    return -1;
}

static bool has_extension(const char *path, const char *ext)
{
    const char *dot = strrchr(path, '.');
    const char *slash = strrchr(path, '/');
    return dot && (!slash || dot > slash) && strcasecmp(dot + 1, ext) == 0;
}

typedef struct WeldKey {
    double x, y, z;
    int raw; /* index into the raw (per-mesh concatenated) vertex array */
} WeldKey;

static int weld_key_cmp(const void *pa, const void *pb)
{
    const WeldKey *a = pa, *b = pb;
    if (a->x != b->x) return a->x < b->x ? -1 : 1;
    if (a->y != b->y) return a->y < b->y ? -1 : 1;
    if (a->z != b->z) return a->z < b->z ? -1 : 1;
    return (a->raw > b->raw) - (a->raw < b->raw);
}

/* Scratch of one load, freed together. */
typedef struct LoadScratch {
    double *pos, *nrm; /* raw positions and normals, 3 per raw vertex */
    double *uv;        /* raw texture coordinates, 2 per raw vertex (when every mesh has a first set) */
    int *tri;          /* raw triangle corners */
    WeldKey *keys;
    int *rep, *remap;
    unsigned char *added; /* per raw vertex: its normal is already summed */
} LoadScratch;

static void scratch_free(LoadScratch *s)
{
    free(s->pos);
    free(s->nrm);
    free(s->uv);
    free(s->tri);
    free(s->keys);
    free(s->rep);
    free(s->remap);
    free(s->added);
}

static bool mesh_has_triangles(const struct aiMesh *m)
{
    return (m->mPrimitiveTypes & aiPrimitiveType_TRIANGLE) && m->mNumVertices > 0 && m->mNumFaces > 0;
}

/* Copies the triangles of every mesh of the scene into raw arrays (vertex indices offset per mesh). */
static DrStatus gather(const char *path, const struct aiScene *sc, LoadScratch *s, int *nraw_v, int *nraw_t,
                       bool *with_normals, DrError *err)
{
    long long nv = 0, nt = 0;
    bool normals = true, uvs = true;
    for (unsigned mi = 0; mi < sc->mNumMeshes; mi++) {
        const struct aiMesh *m = sc->mMeshes[mi];
        if (!mesh_has_triangles(m)) continue;
        nv += m->mNumVertices;
        for (unsigned f = 0; f < m->mNumFaces; f++) nt += m->mFaces[f].mNumIndices == 3;
        normals = normals && m->mNormals != NULL;
        uvs = uvs && m->mTextureCoords[0] != NULL;
    }
    if (nt == 0)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "mesh is empty: no triangles; export faces, not only points or lines");
    if (nv > INT_MAX / 3 || nt > INT_MAX / 3)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "mesh has %lld vertices and %lld triangles, more than drench handles (%d); decimate it",
                            nv, nt, INT_MAX / 3);
    DR_TRY(dr_calloc((size_t)nv * 3, sizeof(double), &s->pos, err));
    if (normals) DR_TRY(dr_calloc((size_t)nv * 3, sizeof(double), &s->nrm, err));
    if (uvs) DR_TRY(dr_calloc((size_t)nv * 2, sizeof(double), &s->uv, err));
    DR_TRY(dr_calloc((size_t)nt * 3, sizeof(int), &s->tri, err));
    int v0 = 0, t = 0;
    for (unsigned mi = 0; mi < sc->mNumMeshes; mi++) {
        const struct aiMesh *m = sc->mMeshes[mi];
        if (!mesh_has_triangles(m)) continue;
        for (unsigned i = 0; i < m->mNumVertices; i++) {
            double *p = s->pos + 3 * (size_t)(v0 + (int)i);
            p[0] = m->mVertices[i].x;
            p[1] = m->mVertices[i].y;
            p[2] = m->mVertices[i].z;
            if (normals) {
                double *q = s->nrm + 3 * (size_t)(v0 + (int)i);
                q[0] = m->mNormals[i].x;
                q[1] = m->mNormals[i].y;
                q[2] = m->mNormals[i].z;
            }
            if (uvs) {
                double *q = s->uv + 2 * (size_t)(v0 + (int)i);
                q[0] = m->mTextureCoords[0][i].x;
                q[1] = m->mTextureCoords[0][i].y;
            }
        }
        for (unsigned f = 0; f < m->mNumFaces; f++) {
            const struct aiFace *face = &m->mFaces[f];
            if (face->mNumIndices != 3) continue;
            for (int c = 0; c < 3; c++) {
                assert(face->mIndices[c] < m->mNumVertices);
                s->tri[3 * t + c] = v0 + (int)face->mIndices[c];
            }
            t++;
        }
        v0 += (int)m->mNumVertices;
    }
    *nraw_v = (int)nv;
    *nraw_t = (int)nt;
    *with_normals = normals;
    return DR_OK;
}

/* Joins vertices at equal positions and builds the output mesh. Sorting (rather than hashing)
 * keeps it deterministic and exact: two corners are one vertex only when their coordinates compare
 * equal, the condition under which a closed surface is closed by index. */
static DrStatus weld(const char *path, LoadScratch *s, int nraw_v, int nraw_t, bool with_normals, DrTriMesh *out,
                     DrError *err)
{
    DR_TRY(dr_calloc((size_t)nraw_v, sizeof(WeldKey), &s->keys, err));
    DR_TRY(dr_calloc((size_t)nraw_v, sizeof(int), &s->rep, err));
    DR_TRY(dr_calloc((size_t)nraw_v, sizeof(int), &s->remap, err));
    for (int i = 0; i < nraw_v; i++) {
        WeldKey k = {s->pos[3 * i], s->pos[3 * i + 1], s->pos[3 * i + 2], i};
        s->keys[i] = k;
    }
    qsort(s->keys, (size_t)nraw_v, sizeof(WeldKey), weld_key_cmp);
    /* The representative of a group of equal positions is its lowest raw index (first after sorting). */
    for (int i = 0; i < nraw_v; i++) {
        bool same = i > 0 && s->keys[i].x == s->keys[i - 1].x && s->keys[i].y == s->keys[i - 1].y &&
                    s->keys[i].z == s->keys[i - 1].z;
        s->rep[s->keys[i].raw] = same ? s->rep[s->keys[i - 1].raw] : s->keys[i].raw;
    }
    for (int i = 0; i < nraw_v; i++) s->remap[i] = -1;

    DR_TRY(dr_calloc((size_t)nraw_t * 3, sizeof(int), &out->tri, err));
    if (s->uv) DR_TRY(dr_calloc((size_t)nraw_t * 6, sizeof(double), &out->uv, err));
    int nv = 0, nt = 0;
    for (int t = 0; t < nraw_t; t++) {
        int r[3];
        for (int c = 0; c < 3; c++) r[c] = s->rep[s->tri[3 * t + c]];
        if (r[0] == r[1] || r[1] == r[2] || r[0] == r[2]) continue; /* collapsed by the joining */
        for (int c = 0; c < 3; c++) {
            if (s->remap[r[c]] < 0) s->remap[r[c]] = nv++;
            out->tri[3 * nt + c] = s->remap[r[c]];
            if (s->uv) memcpy(out->uv + 6 * nt + 2 * c, s->uv + 2 * s->tri[3 * t + c], 2 * sizeof(double));
        }
        nt++;
    }
    if (nt == 0)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "mesh is empty: every triangle is degenerate (corners at the same position); "
                            "export faces with non-zero area");
    out->nt = nt;
    out->nv = nv;
    DR_TRY(dr_calloc((size_t)nv * 3, sizeof(double), &out->v, err));
    for (int i = 0; i < nraw_v; i++) {
        int k = s->remap[i];
        if (k >= 0) memcpy(out->v + 3 * k, s->pos + 3 * i, 3 * sizeof(double));
    }
    if (!with_normals) return DR_OK;

    DR_TRY(dr_calloc((size_t)nv * 3, sizeof(double), &out->n, err));
    /* Each raw corner used by a kept triangle adds its file normal once (a raw vertex shared by
     * several triangles of one smooth mesh counts once, like the file's own per-vertex normal). */
    DR_TRY(dr_calloc((size_t)nraw_v, 1, &s->added, err));
    for (int t = 0; t < nraw_t; t++) {
        int r[3];
        for (int c = 0; c < 3; c++) r[c] = s->rep[s->tri[3 * t + c]];
        if (r[0] == r[1] || r[1] == r[2] || r[0] == r[2]) continue;
        for (int c = 0; c < 3; c++) {
            int raw = s->tri[3 * t + c];
            if (s->added[raw]) continue;
            s->added[raw] = 1;
            double *n = out->n + 3 * s->remap[r[c]];
            for (int d = 0; d < 3; d++) n[d] += s->nrm[3 * raw + d];
        }
    }
    /* Where the file normals cancel (or are zero), fall back to the area-weighted sum of the adjacent
     * face normals, which is defined for every vertex of a triangle with non-zero area. */
    unsigned char *fallback = NULL;
    for (int i = 0; i < nv; i++) {
        DrVec3 n = dr_v3(out->n[3 * i], out->n[3 * i + 1], out->n[3 * i + 2]);
        if (dr_v3_norm(n) > 0.0 && dr_v3_isfinite(n)) continue;
        if (!fallback) DR_TRY(dr_calloc((size_t)nv, 1, &fallback, err));
        fallback[i] = 1;
        out->n[3 * i] = out->n[3 * i + 1] = out->n[3 * i + 2] = 0.0;
    }
    if (fallback) {
        for (int t = 0; t < nt; t++) {
            const int *c = out->tri + 3 * t;
            DrVec3 a = dr_v3(out->v[3 * c[0]], out->v[3 * c[0] + 1], out->v[3 * c[0] + 2]);
            DrVec3 b = dr_v3(out->v[3 * c[1]], out->v[3 * c[1] + 1], out->v[3 * c[1] + 2]);
            DrVec3 d = dr_v3(out->v[3 * c[2]], out->v[3 * c[2] + 1], out->v[3 * c[2] + 2]);
            DrVec3 fn = dr_v3_cross(dr_v3_sub(b, a), dr_v3_sub(d, a)); /* twice the area times the unit normal */
            for (int k = 0; k < 3; k++) {
                if (!fallback[c[k]]) continue;
                double *n = out->n + 3 * c[k];
                n[0] += fn.x;
                n[1] += fn.y;
                n[2] += fn.z;
            }
        }
        free(fallback);
    }
    for (int i = 0; i < nv; i++) {
        double *n = out->n + 3 * i;
        DrVec3 u = dr_v3_normalize(dr_v3(n[0], n[1], n[2]));
        n[0] = u.x;
        n[1] = u.y;
        n[2] = u.z;
    }
    return DR_OK;
}

DrStatus dr_io_load_mesh(const char *path, DrTriMesh *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    struct stat st;
    if (stat(path, &st) != 0)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot open mesh file: %s; check the path in the scene",
                            strerror(errno));
    if (S_ISDIR(st.st_mode))
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "is a directory, not a mesh file; name the mesh file");
    FILE *f = fopen(path, "rb");
    if (!f)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot open mesh file: %s; check its permissions",
                            strerror(errno));
    if (has_extension(path, "obj")) {
        unsigned char byte = 0;
        long at = first_binary_byte(f, &byte);
        if (at >= 0) {
            fclose(f);
            return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                                "not a text OBJ file: the byte at offset %ld is binary data (0x%02x); the file is corrupt or of "
                                "another format, re-export it as OBJ",
                                at, (unsigned)byte);
        }
    }
    fclose(f);

    /* No logger is attached, so assimp's DefaultLogger stays the null logger and prints nothing. */
    const struct aiScene *sc = aiImportFile(path, aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                                      aiProcess_PreTransformVertices | aiProcess_SortByPType);
    if (!sc) {
        char why[1024];
        snprintf(why, sizeof why, "%s", aiGetErrorString());
        size_t n = strlen(why);
        while (n > 0 && (why[n - 1] == '.' || why[n - 1] == ' ' || why[n - 1] == '\n')) why[--n] = '\0';
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "cannot read mesh: assimp: %s; export it as OBJ, PLY or STL", why);
    }

    LoadScratch s = {0};
    int nraw_v = 0, nraw_t = 0;
    bool with_normals = false;
    DrStatus st_ = gather(path, sc, &s, &nraw_v, &nraw_t, &with_normals, err);
    aiReleaseImport(sc);
    if (st_ == DR_OK) {
        for (int t = 0; t < nraw_t && st_ == DR_OK; t++) {
            for (int c = 0; c < 3; c++) {
                const double *p = s.pos + 3 * s.tri[3 * t + c];
                if (!(isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]))) {
                    st_ = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                                       "vertex %d of triangle %d has a non-finite coordinate (%g, %g, %g); "
                                       "fix the asset so every vertex position is a finite number",
                                       c + 1, t + 1, p[0], p[1], p[2]);
                    break;
                }
            }
        }
    }
    if (st_ == DR_OK) st_ = weld(path, &s, nraw_v, nraw_t, with_normals, out, err);
    scratch_free(&s);
    if (st_ != DR_OK) dr_trimesh_free(out);
    return st_;
}

/* ---- writing ---- */

DrStatus dr_io_write_obj(const char *path, const DrTriMesh *mesh, const char *comment, DrError *err)
{
    for (int i = 0; mesh->uv && i < 6 * mesh->nt; i++)
        if (!isfinite(mesh->uv[i]))
            return dr_error_set(err, DR_ERR_RUNTIME, path, 0, 0,
                                "triangle %d has a non-finite texture coordinate; nothing was written", i / 6);
    for (int i = 0; i < 3 * mesh->nv; i++) {
        if (!isfinite(mesh->v[i]) || (mesh->n && !isfinite(mesh->n[i])))
            return dr_error_set(err, DR_ERR_RUNTIME, path, 0, 0,
                                "vertex %d has a non-finite %s; nothing was written (the simulation produced "
                                "invalid data; lower the time step or check the scene)",
                                i / 3, isfinite(mesh->v[i]) ? "normal" : "coordinate");
    }
    char tmp[DR_IO_PATH_MAX];
    if (strlen(path) + 32 > sizeof tmp)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "path is too long; use a shorter output path");
    dr_io_tmp_path(path, tmp, sizeof tmp);
    FILE *f = fopen(tmp, "w");
    if (!f)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot create %s: %s; check that the directory exists "
                            "and is writable", tmp, strerror(errno));
    if (comment) {
        const char *line = comment;
        for (;;) {
            size_t len = strcspn(line, "\n");
            fprintf(f, "# %.*s\n", (int)len, line);
            if (!line[len]) break;
            line += len + 1;
        }
    }
    for (int i = 0; i < mesh->nv; i++)
        fprintf(f, "v %.9g %.9g %.9g\n", mesh->v[3 * i], mesh->v[3 * i + 1], mesh->v[3 * i + 2]);
    if (mesh->n)
        for (int i = 0; i < mesh->nv; i++)
            fprintf(f, "vn %.9g %.9g %.9g\n", mesh->n[3 * i], mesh->n[3 * i + 1], mesh->n[3 * i + 2]);
    if (mesh->uv) /* one texture coordinate per corner, in triangle order */
        for (int k = 0; k < 3 * mesh->nt; k++) fprintf(f, "vt %.9g %.9g\n", mesh->uv[2 * k], mesh->uv[2 * k + 1]);
    for (int t = 0; t < mesh->nt; t++) {
        int a = mesh->tri[3 * t] + 1, b = mesh->tri[3 * t + 1] + 1, c = mesh->tri[3 * t + 2] + 1;
        int ta = 3 * t + 1, tb = 3 * t + 2, tc = 3 * t + 3;
        if (mesh->uv && mesh->n)
            fprintf(f, "f %d/%d/%d %d/%d/%d %d/%d/%d\n", a, ta, a, b, tb, b, c, tc, c);
        else if (mesh->uv)
            fprintf(f, "f %d/%d %d/%d %d/%d\n", a, ta, b, tb, c, tc);
        else if (mesh->n)
            fprintf(f, "f %d//%d %d//%d %d//%d\n", a, a, b, b, c, c);
        else
            fprintf(f, "f %d %d %d\n", a, b, c);
    }
    bool failed = ferror(f) != 0;
    if (fclose(f) != 0) failed = true;
    if (failed) {
        unlink(tmp);
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write the file; check free disk space");
    }
    return dr_io_commit(tmp, path, err);
}
