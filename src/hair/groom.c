/* Grooms (PHYSICS §4 "Groom"): strands grown from a scalp mesh, or read from the polylines of an OBJ file;
 * and the default rod material.
 *
 * Growing. Roots are sampled uniformly by area: a triangle with probability proportional to its area (binary
 * search in the prefix sums of the areas, in triangle order), then a point uniform in it by the square-root
 * map of Turk (Graphics Gems I, 1990: b = (1 − √u₁, √u₁(1 − u₂), √u₁ u₂)). Each strand draws the same five
 * numbers in the same order (triangle, two barycentric, curl phase, length jitter) whatever the desc, so
 * the roots depend on the mesh, the count and the seed only. The direction is the area-weighted vertex
 * normal field (each vertex: the sum of its triangles' (b − a) × (c − a), i.e. twice area × unit normal)
 * interpolated barycentrically at the root; the triangle's own normal where that field vanishes. On a mesh
 * inscribed in a sphere whose vertex normals are radial, the interpolated normal is exactly the root's
 * radial direction (the root is the same barycentric mix of the vertices).
 *
 * Reading. Only "v" and "l" records matter (assimp drops lines, so the file is parsed here); every other
 * record is skipped, as OBJ readers do. Indices are 1-based, negative ones count back from the last "v"
 * before the record, "i/t" takes the vertex index. The whole file is checked before anything is returned,
 * and every problem is reported at its line and column. */
#include "hair/hair.h"

#include <errno.h>
#include <limits.h>
#include <stdlib.h>
#include <string.h>

void dr_groom_free(DrGroom *g)
{
    if (!g) return;
    free(g->offsets);
    free(g->x);
    free(g->root_normal);
    memset(g, 0, sizeof *g);
}

void dr_groom_desc_default(DrGroomDesc *d)
{
    *d = (DrGroomDesc){.count = 100,
                       .length = 0.05,
                       .segments = 12,
                       .curl_radius = 0.0,
                       .curl_pitch = 0.01,
                       .length_jitter = 0.0,
                       .seed = 1};
}

/* Human scalp hair: radius 50 µm (diameters 50–120 µm); keratin fibre density 1300 kg/m³; Young's modulus
 * 3.9 GPa (tensile tests of wet to dry hair span about 2–6 GPa); G = E / (2(1 + ν)) with ν = 0.5. */
void dr_rod_material_default(DrRodMaterial *m)
{
    *m = (DrRodMaterial){.radius = 5e-5, .density = 1300.0, .youngs = 3.9e9, .shear = 1.3e9, .damping = 0.0};
}

static DrVec3 vec_at(const double *a, int i) { return dr_v3(a[3 * i], a[3 * i + 1], a[3 * i + 2]); }

static void vec_put(double *a, int i, DrVec3 v)
{
    a[3 * i] = v.x;
    a[3 * i + 1] = v.y;
    a[3 * i + 2] = v.z;
}

/* An orthonormal vector perpendicular to unit n, continuous except across n.z = 0 (Duff et al. 2017,
 * "Building an orthonormal basis, revisited", JCGT 6(1)). */
static DrVec3 perpendicular(DrVec3 n)
{
    double sign = n.z >= 0.0 ? 1.0 : -1.0;
    double a = -1.0 / (sign + n.z), b = n.x * n.y * a;
    return dr_v3(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
}

/* ---- growing --------------------------------------------------------------------------------------------- */

static DrStatus check_desc(const DrGroomDesc *d, DrError *err)
{
    if (d->count < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom: count = %d; grow at least one strand", d->count);
    if (d->segments < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom: segments = %d; a strand needs at least one edge",
                            d->segments);
    if (!(d->length > 0.0) || !isfinite(d->length))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: length = %g m; give a positive strand length such as 0.05", d->length);
    if (!(d->curl_radius >= 0.0) || !isfinite(d->curl_radius))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: curl_radius = %g m; give 0 (straight) or a positive helix radius", d->curl_radius);
    if (d->curl_radius > 0.0 && (!(d->curl_pitch > 0.0) || !isfinite(d->curl_pitch)))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: curl_pitch = %g m with curl_radius > 0; give a positive rise per turn such as 0.01",
                            d->curl_pitch);
    if (!(d->length_jitter >= 0.0 && d->length_jitter < 1.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "groom: length_jitter = %g; give a fraction in [0, 1)",
                            d->length_jitter);
    if ((long long)d->count * ((long long)d->segments + 1) > INT_MAX)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: %d strands of %d segments make more than %d vertices; reduce count or segments",
                            d->count, d->segments, INT_MAX);
    return DR_OK;
}

/* Twice-area normals summed into each vertex, then normalised; (0,0,0) where they cancel to rounding (a
 * double-sided sheet), so that a vanishing sum is never blown up into an arbitrary direction. */
static void vertex_normals(const DrTriMesh *m, double *vn, double *weight)
{
    for (int t = 0; t < m->nt; t++) {
        const int *tri = &m->tri[3 * t];
        DrVec3 a = vec_at(m->v, tri[0]), b = vec_at(m->v, tri[1]), c = vec_at(m->v, tri[2]);
        DrVec3 n2 = dr_v3_cross(dr_v3_sub(b, a), dr_v3_sub(c, a));
        double w = dr_v3_norm(n2);
        for (int k = 0; k < 3; k++) {
            vec_put(vn, tri[k], dr_v3_add(vec_at(vn, tri[k]), n2));
            weight[tri[k]] += w;
        }
    }
    for (int i = 0; i < m->nv; i++) {
        DrVec3 n = vec_at(vn, i);
        double len = dr_v3_norm(n);
        vec_put(vn, i, len > 1e-12 * weight[i] ? dr_v3_scale(n, 1.0 / len) : dr_v3(0, 0, 0));
    }
}

/* First triangle whose prefix area exceeds `target`, skipping zero-area ones (equal prefix sums). */
static int pick_triangle(const double *cdf, int nt, double target)
{
    int lo = 0, hi = nt - 1;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (cdf[mid] > target) hi = mid;
        else lo = mid + 1;
    }
    /* target rounds to the total only when u₀ → 1; then take the last triangle with area */
    while (lo > 0 && cdf[lo] == cdf[lo - 1]) lo--;
    return lo;
}

DrStatus dr_groom_grow(const DrTriMesh *scalp, const DrGroomDesc *desc, DrGroom *out, DrError *err)
{
    assert(scalp && desc && out);
    memset(out, 0, sizeof *out);
    DR_TRY(check_desc(desc, err));
    if (scalp->nt < 1 || scalp->nv < 3)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "groom: the scalp mesh has no triangles (%d vertices, %d triangles); give a triangle mesh "
                            "to grow strands from",
                            scalp->nv, scalp->nt);
    for (int i = 0; i < 3 * scalp->nt; i++) assert(scalp->tri[i] >= 0 && scalp->tri[i] < scalp->nv);
    for (int i = 0; i < 3 * scalp->nv; i++)
        if (!isfinite(scalp->v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "groom: scalp vertex %d has a non-finite coordinate; fix the mesh", i / 3);

    const int S = desc->count, nvs = desc->segments + 1, V = S * nvs;
    double *cdf = NULL, *vn = NULL, *weight = NULL;
    DrStatus st = dr_calloc((size_t)scalp->nt, sizeof(double), &cdf, err);
    if (st == DR_OK) st = dr_calloc((size_t)scalp->nv * 3, sizeof(double), &vn, err);
    if (st == DR_OK) st = dr_calloc((size_t)scalp->nv, sizeof(double), &weight, err);
    if (st == DR_OK) st = dr_calloc((size_t)S + 1, sizeof(int), &out->offsets, err);
    if (st == DR_OK) st = dr_calloc((size_t)V * 3, sizeof(double), &out->x, err);
    if (st == DR_OK) st = dr_calloc((size_t)S * 3, sizeof(double), &out->root_normal, err);
    if (st != DR_OK) goto done;

    /* 1. areas and their prefix sums (triangle order: the same sums on every run) */
    double total = 0.0;
    for (int t = 0; t < scalp->nt; t++) {
        const int *tri = &scalp->tri[3 * t];
        DrVec3 a = vec_at(scalp->v, tri[0]), b = vec_at(scalp->v, tri[1]), c = vec_at(scalp->v, tri[2]);
        total += 0.5 * dr_v3_norm(dr_v3_cross(dr_v3_sub(b, a), dr_v3_sub(c, a)));
        cdf[t] = total;
    }
    if (!(total > 0.0) || !isfinite(total)) {
        st = dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                          "groom: the scalp mesh has no area (%d triangles, all degenerate); give a mesh with surface "
                          "to grow strands from",
                          scalp->nt);
        goto done;
    }
    vertex_normals(scalp, vn, weight);

    /* 2. one strand at a time: root, direction, then its vertices along a line or a helix */
    DrRng rng;
    dr_rng_seed(&rng, desc->seed);
    const double r = desc->curl_radius, pitch = desc->curl_pitch;
    const double turn = sqrt((2.0 * DR_PI * r) * (2.0 * DR_PI * r) + pitch * pitch); /* arc length per turn */
    for (int s = 0; s < S; s++) {
        double u[5];
        for (int k = 0; k < 5; k++) u[k] = dr_rng_uniform(&rng);
        int t = pick_triangle(cdf, scalp->nt, u[0] * total);
        const int *tri = &scalp->tri[3 * t];
        double r1 = sqrt(u[1]);
        double b[3] = {1.0 - r1, r1 * (1.0 - u[2]), r1 * u[2]};
        DrVec3 root = dr_v3(0, 0, 0), n = dr_v3(0, 0, 0);
        for (int k = 0; k < 3; k++) {
            root = dr_v3_add(root, dr_v3_scale(vec_at(scalp->v, tri[k]), b[k]));
            n = dr_v3_add(n, dr_v3_scale(vec_at(vn, tri[k]), b[k]));
        }
        /* the interpolated field vanishes only between opposed vertex normals: use the face's own */
        if (!(dr_v3_norm(n) > 1e-6)) {
            DrVec3 a = vec_at(scalp->v, tri[0]), bb = vec_at(scalp->v, tri[1]), c = vec_at(scalp->v, tri[2]);
            n = dr_v3_cross(dr_v3_sub(bb, a), dr_v3_sub(c, a));
        }
        n = dr_v3_normalize(n);
        vec_put(out->root_normal, s, n);

        double len = desc->length * (1.0 + desc->length_jitter * (2.0 * u[4] - 1.0));
        double psi = 2.0 * DR_PI * u[3];
        DrVec3 p = perpendicular(n), q = dr_v3_cross(n, p);
        DrVec3 e1 = dr_v3_add(dr_v3_scale(p, cos(psi)), dr_v3_scale(q, sin(psi))), e2 = dr_v3_cross(n, e1);
        out->offsets[s] = s * nvs;
        for (int k = 0; k < nvs; k++) {
            double arc = len * (double)k / (double)desc->segments;
            DrVec3 d;
            if (r > 0.0) {
                /* right-handed helix about an axis parallel to n through root − r e1: angle φ and rise h after
                   arc length s are φ = 2π s / turn, h = pitch s / turn */
                double phi = 2.0 * DR_PI * arc / turn, h = pitch * arc / turn;
                d = dr_v3_add(dr_v3_add(dr_v3_scale(e1, r * (cos(phi) - 1.0)), dr_v3_scale(e2, r * sin(phi))),
                              dr_v3_scale(n, h));
            } else {
                d = dr_v3_scale(n, arc);
            }
            vec_put(out->x, s * nvs + k, dr_v3_add(root, d));
        }
    }
    out->offsets[S] = V;
    out->nstrands = S;

done:
    free(cdf);
    free(vn);
    free(weight);
    if (st != DR_OK) dr_groom_free(out);
    return st;
}

/* ---- reading OBJ polylines ------------------------------------------------------------------------------ */

/* Growable arrays of the reader; `n` counts elements of `size` bytes. */
typedef struct Buf {
    void *p;
    size_t n, cap, size;
} Buf;

static DrStatus buf_push(Buf *b, const void *item, DrError *err)
{
    if (b->n == b->cap) {
        size_t cap = b->cap ? 2 * b->cap : 256;
        DR_TRY(dr_realloc(cap, b->size, &b->p, err));
        b->cap = cap;
    }
    memcpy((char *)b->p + b->n * b->size, item, b->size);
    b->n++;
    return DR_OK;
}

typedef struct Ref {
    long index; /* 0-based after resolving a relative index; ≥ 0 */
    int line, col;
} Ref;

typedef struct Strand {
    size_t first; /* into the refs */
    int count, line;
} Strand;

static DrStatus read_all(const char *path, char **text, size_t *len, DrError *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot open the curves file (%s); check the path",
                            strerror(errno));
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap);
    DrStatus st = DR_OK;
    while (buf) {
        n += fread(buf + n, 1, cap - n - 1, f);
        if (ferror(f)) {
            st = dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot read the curves file (%s)", strerror(errno));
            break;
        }
        if (feof(f)) break;
        char *bigger = cap <= SIZE_MAX / 2 ? realloc(buf, cap * 2) : NULL;
        if (!bigger) {
            free(buf);
            buf = NULL;
            break;
        }
        buf = bigger;
        cap *= 2;
    }
    fclose(f);
    if (!buf) return dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "out of memory reading the curves file");
    if (st != DR_OK) {
        free(buf);
        return st;
    }
    buf[n] = '\0';
    *text = buf;
    *len = n;
    return DR_OK;
}

/* Next whitespace-separated token of a line; NULL at its end. */
static char *next_token(char **cursor)
{
    char *c = *cursor;
    while (*c == ' ' || *c == '\t' || *c == '\f' || *c == '\v') c++;
    if (!*c) return NULL;
    char *start = c;
    while (*c && *c != ' ' && *c != '\t' && *c != '\f' && *c != '\v') c++;
    if (*c) *c++ = '\0';
    *cursor = c;
    return start;
}

/* The reader's state: where it is (for messages) and what it has collected. */
typedef struct Reader {
    const char *path;
    DrError *err;
    int line;
    const char *ln; /* the current line (columns count from it) */
    Buf verts, refs, strands;
} Reader;

/* A DR_ERR_INPUT at the current line, column of `at` (NULL: column 1). */
DR_PRINTF(3, 4) static DrStatus fail_at(Reader *r, const char *at, const char *fmt, ...)
{
    char msg[sizeof r->err->message];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    int col = at ? (int)(at - r->ln) + 1 : 1;
    return dr_error_set(r->err, DR_ERR_INPUT, r->path, r->line, col, "%s", msg);
}

/* "v x y z [more numbers]": a weight w or a vertex colour may follow x y z; they are checked and ignored. */
static DrStatus read_vertex(Reader *r, char *cursor)
{
    double xyz[3];
    int got = 0;
    for (char *tok; (tok = next_token(&cursor)); got++) {
        char *end;
        double x = strtod(tok, &end); /* overflow gives ±inf, caught below */
        if (end == tok || *end) return fail_at(r, tok, "'%s' is not a number; a 'v' record is \"v x y z\" in metres", tok);
        if (!isfinite(x)) return fail_at(r, tok, "vertex coordinate '%s' is not finite; fix the exporter's output", tok);
        if (got < 3) xyz[got] = x;
    }
    if (got < 3)
        return fail_at(r, NULL, "'v' record with %d number%s; a vertex is \"v x y z\" in metres", got, got == 1 ? "" : "s");
    if (r->verts.n >= (size_t)INT_MAX / 3) return fail_at(r, NULL, "more than %d vertices; split the file", INT_MAX / 3);
    return buf_push(&r->verts, xyz, r->err);
}

/* "l i j k ...": one strand. Relative indices resolve now (against the vertices so far); positive ones are
   checked once the whole file is read, since they may point forward. */
static DrStatus read_polyline(Reader *r, char *cursor)
{
    Strand sd = {.first = r->refs.n, .count = 0, .line = r->line};
    for (char *tok; (tok = next_token(&cursor)); sd.count++) {
        char *end;
        errno = 0;
        long idx = strtol(tok, &end, 10);
        if (end == tok || (*end && *end != '/') || errno == ERANGE)
            return fail_at(r, tok, "'%s' is not a vertex index; an 'l' record lists 'v' indices (1-based, or negative "
                                   "from the last vertex), root first", tok);
        if (idx == 0)
            return fail_at(r, tok, "vertex index 0: OBJ indices start at 1 (negative ones count back from the last "
                                   "vertex)");
        if (idx < 0 && -idx > (long)r->verts.n)
            return fail_at(r, tok, "vertex index %ld is out of range: only %zu 'v' records come before this line", idx,
                           r->verts.n);
        if (r->refs.n >= (size_t)INT_MAX) return fail_at(r, tok, "more than %d strand vertices; split the file", INT_MAX);
        Ref ref = {.index = idx < 0 ? (long)r->verts.n + idx : idx - 1, .line = r->line, .col = (int)(tok - r->ln) + 1};
        DR_TRY(buf_push(&r->refs, &ref, r->err));
    }
    if (sd.count < 2)
        return fail_at(r, NULL, "'l' record with %d vert%s; a strand needs at least 2 (root first)", sd.count,
                       sd.count == 1 ? "ex" : "ices");
    return buf_push(&r->strands, &sd, r->err);
}

/* One line, NUL-terminated without its '\n': text checks, comment, then the record if it is "v" or "l". */
static DrStatus read_line(Reader *r, char *ln, size_t n)
{
    r->ln = ln;
    if (strlen(ln) != n) return fail_at(r, ln + strlen(ln), "a NUL byte: this is not a text OBJ file; export the "
                                                            "curves as text OBJ");
    if (n && ln[n - 1] == '\r') ln[--n] = '\0';
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)ln[i];
        if (c < 0x20 && c != '\t' && c != '\f' && c != '\v')
            return fail_at(r, ln + i, "control byte 0x%02x: this is not a text OBJ file; export the curves as text OBJ",
                           c);
    }
    char *hash = strchr(ln, '#');
    if (hash) *hash = '\0';
    size_t used = strlen(ln); /* a trailing '\' continues the record on the next line */
    while (used && (ln[used - 1] == ' ' || ln[used - 1] == '\t')) used--;
    bool continued = used && ln[used - 1] == '\\';
    char *cursor = ln;
    char *key = next_token(&cursor);
    bool is_v = key && strcmp(key, "v") == 0, is_l = key && strcmp(key, "l") == 0;
    if (!is_v && !is_l) return DR_OK;
    if (continued)
        return fail_at(r, ln + used - 1, "'%s' record continued on the next line ('\\'), which is not supported; write "
                                         "the record on one line", key);
    return is_v ? read_vertex(r, cursor) : read_polyline(r, cursor);
}

DrStatus dr_groom_read_obj(const char *path, DrGroom *out, DrError *err)
{
    assert(path && out);
    memset(out, 0, sizeof *out);
    char *text = NULL;
    size_t len = 0;
    DR_TRY(read_all(path, &text, &len, err));

    /* 1. the records, line by line */
    Reader r = {.path = path,
                .err = err,
                .verts = {.size = 3 * sizeof(double)},
                .refs = {.size = sizeof(Ref)},
                .strands = {.size = sizeof(Strand)}};
    DrStatus st = DR_OK;
    for (char *ln = text; st == DR_OK && ln < text + len;) {
        r.line++;
        char *eol = memchr(ln, '\n', (size_t)(text + len - ln));
        char *stop = eol ? eol : text + len;
        *stop = '\0'; /* text[len] is the terminator read_all added */
        st = read_line(&r, ln, (size_t)(stop - ln));
        ln = stop + 1;
    }
    const int line = r.line;
    Buf verts = r.verts, refs = r.refs, strands = r.strands;

    /* 2. checks that need the whole file: forward indices and edge lengths */
    const double *vx = verts.p;
    const Ref *rf = refs.p;
    const Strand *sd = strands.p;
    if (st == DR_OK && strands.n == 0)
        st = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                          "no 'l' records (polylines) among %d lines: each strand is an 'l' record listing its 'v' "
                          "indices, root first",
                          line);
    for (size_t i = 0; st == DR_OK && i < refs.n; i++)
        if (rf[i].index >= (long)verts.n)
            st = dr_error_set(err, DR_ERR_INPUT, path, rf[i].line, rf[i].col,
                              "vertex index %ld is out of range: the file has %zu 'v' records", rf[i].index + 1,
                              verts.n);
    for (size_t s = 0; st == DR_OK && s < strands.n; s++) {
        for (int k = 0; k + 1 < sd[s].count; k++) {
            const Ref *a = &rf[sd[s].first + (size_t)k], *b = a + 1;
            DrVec3 pa = vec_at(vx, (int)a->index), pb = vec_at(vx, (int)b->index);
            if (dr_v3_norm(dr_v3_sub(pb, pa)) > 0.0) continue;
            st = dr_error_set(err, DR_ERR_INPUT, path, b->line, b->col,
                              "zero-length edge: vertices %d and %d of this strand (OBJ indices %ld and %ld) are at "
                              "the same position; remove the repeated vertex",
                              k + 1, k + 2, a->index + 1, b->index + 1);
            break;
        }
    }

    /* 3. the groom: positions copied per strand, root normal along the first edge */
    if (st == DR_OK) {
        int S = (int)strands.n, V = (int)refs.n;
        st = dr_calloc((size_t)S + 1, sizeof(int), &out->offsets, err);
        if (st == DR_OK) st = dr_calloc((size_t)V * 3, sizeof(double), &out->x, err);
        if (st == DR_OK) st = dr_calloc((size_t)S * 3, sizeof(double), &out->root_normal, err);
        for (int s = 0; st == DR_OK && s < S; s++) {
            int o = (int)sd[s].first;
            out->offsets[s] = o;
            for (int k = 0; k < sd[s].count; k++) vec_put(out->x, o + k, vec_at(vx, (int)rf[o + k].index));
            vec_put(out->root_normal, s, dr_v3_normalize(dr_v3_sub(vec_at(out->x, o + 1), vec_at(out->x, o))));
        }
        if (st == DR_OK) {
            out->offsets[S] = V;
            out->nstrands = S;
        } else {
            dr_groom_free(out);
        }
    }
    free(verts.p);
    free(refs.p);
    free(strands.p);
    free(text);
    return st;
}
