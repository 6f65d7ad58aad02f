/* OBJ polylines: strand sets (hair) written by the mesh stage and read back by the render stage. The radius
 * rides in "# radius R" comments (io.h), so the file stays a plain OBJ for every other tool. */
#include <errno.h>
#include <limits.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "io/io.h"

void dr_io_polylines_free(DrPolylines *p)
{
    if (!p) return;
    free(p->offsets);
    free(p->x);
    free(p->radius);
    *p = (DrPolylines){0};
}

/* ---- writing ---- */

DrStatus dr_io_write_polylines_obj(const char *path, const DrPolylines *p, const char *comment, DrError *err)
{
    assert(path && p && p->count >= 0);
    assert(p->count == 0 || (p->offsets && p->offsets[0] == 0));
    int nv = p->count > 0 ? p->offsets[p->count] : 0;
    for (int s = 0; s < p->count; s++) {
        assert(p->offsets[s + 1] - p->offsets[s] >= 2);
        if (!isfinite(p->radius[s]) || p->radius[s] < 0.0)
            return dr_error_set(err, DR_ERR_RUNTIME, path, 0, 0,
                                "strand %d has radius %g, not a finite number >= 0; nothing was written", s,
                                p->radius[s]);
    }
    for (int i = 0; i < 3 * nv; i++)
        if (!isfinite(p->x[i]))
            return dr_error_set(err, DR_ERR_RUNTIME, path, 0, 0,
                                "vertex %d has a non-finite coordinate; nothing was written (the simulation produced "
                                "invalid data; lower the time step or check the scene)",
                                i / 3);
    char tmp[DR_IO_PATH_MAX];
    if (strlen(path) + 32 > sizeof tmp)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "path is too long; use a shorter output path");
    dr_io_tmp_path(path, tmp, sizeof tmp);
    FILE *f = fopen(tmp, "w");
    if (!f)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0,
                            "cannot create %s: %s; check that the directory exists and is writable", tmp,
                            strerror(errno));
    if (comment) {
        const char *line = comment;
        for (;;) {
            size_t len = strcspn(line, "\n");
            fprintf(f, "# %.*s\n", (int)len, line);
            if (!line[len]) break;
            line += len + 1;
        }
    }
    for (int i = 0; i < nv; i++) fprintf(f, "v %.9g %.9g %.9g\n", p->x[3 * i], p->x[3 * i + 1], p->x[3 * i + 2]);
    for (int s = 0; s < p->count; s++) {
        /* a new radius line only where the stored value changes (exact comparison on purpose: it asks
           whether the state the reader keeps must change, not whether two radii are close) */
        if (s == 0 || p->radius[s] != p->radius[s - 1]) fprintf(f, "# radius %.9g\n", p->radius[s]);
        fputc('l', f);
        for (int v = p->offsets[s]; v < p->offsets[s + 1]; v++) fprintf(f, " %d", v + 1);
        fputc('\n', f);
    }
    bool failed = ferror(f) != 0;
    if (fclose(f) != 0) failed = true;
    if (failed) {
        unlink(tmp);
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write the file; check free disk space");
    }
    return dr_io_commit(tmp, path, err);
}

/* ---- reading ---- */

/* What the parser accumulates: vertices in file order, and per strand its vertex indices (0-based, into
 * the file's vertices) in one flat array. */
typedef struct Parse {
    double *v;
    int nv, cap_v;
    int *idx;
    size_t nidx, cap_idx;
    int *start; /* nstrands + 1 into idx */
    double *radius;
    int nstrands, cap_strands;
    int max_index, max_index_line; /* largest positive index seen (1-based) and its line */
} Parse;

static void parse_free(Parse *p)
{
    free(p->v);
    free(p->idx);
    free(p->start);
    free(p->radius);
    *p = (Parse){0};
}

static bool blank(const char *s)
{
    while (*s == ' ' || *s == '\t') s++;
    return *s == '\0';
}

/* Token `word` at the start of s, followed by a blank or the end. */
static bool keyword(const char *s, const char *word)
{
    size_t n = strlen(word);
    return strncmp(s, word, n) == 0 && (s[n] == ' ' || s[n] == '\t' || s[n] == '\0');
}

static DrStatus parse_vertex(const char *path, int line, const char *s, Parse *p, DrError *err)
{
    double c[3];
    for (int k = 0; k < 3; k++) {
        char *end;
        c[k] = strtod(s, &end);
        if (end == s || (*end != ' ' && *end != '\t' && *end != '\0'))
            return dr_error_set(err, DR_ERR_INPUT, path, line, 0,
                                "malformed vertex: expected \"v x y z\" with three numbers");
        if (!isfinite(c[k]))
            return dr_error_set(err, DR_ERR_INPUT, path, line, 0,
                                "vertex %d has a non-finite coordinate; the file is corrupt, rerun the stage that "
                                "wrote it",
                                p->nv + 1);
        s = end;
    }
    if (p->nv >= INT_MAX / 3)
        return dr_error_set(err, DR_ERR_INPUT, path, line, 0, "too many vertices (more than %d)", INT_MAX / 3);
    if (p->nv == p->cap_v) {
        int cap = p->cap_v ? (p->cap_v < INT_MAX / 6 ? 2 * p->cap_v : INT_MAX / 3) : 1024;
        DR_TRY(dr_realloc(3 * (size_t)cap, sizeof *p->v, &p->v, err));
        p->cap_v = cap;
    }
    memcpy(p->v + 3 * (size_t)p->nv, c, sizeof c);
    p->nv++;
    return DR_OK;
}

static DrStatus push_index(Parse *p, int i, DrError *err)
{
    if (p->nidx == p->cap_idx) {
        size_t cap = p->cap_idx ? 2 * p->cap_idx : 4096;
        DR_TRY(dr_realloc(cap, sizeof *p->idx, &p->idx, err));
        p->cap_idx = cap;
    }
    p->idx[p->nidx++] = i;
    return DR_OK;
}

static DrStatus parse_line_record(const char *path, int line, const char *s, double radius, bool have_radius,
                                  Parse *p, DrError *err)
{
    if (!have_radius)
        return dr_error_set(err, DR_ERR_INPUT, path, line, 0,
                            "polyline before any \"# radius R\" line: the strand radius is unknown; the file was not "
                            "written by the mesh stage, rerun mesh (or pipeline.sh)");
    if (p->nstrands >= INT_MAX - 1)
        return dr_error_set(err, DR_ERR_INPUT, path, line, 0, "too many polylines");
    if (p->nstrands == p->cap_strands) {
        int cap = p->cap_strands ? (p->cap_strands < INT_MAX / 4 ? 2 * p->cap_strands : INT_MAX - 1) : 256;
        DR_TRY(dr_realloc((size_t)cap + 1, sizeof *p->start, &p->start, err));
        DR_TRY(dr_realloc((size_t)cap, sizeof *p->radius, &p->radius, err));
        p->cap_strands = cap;
    }
    size_t first = p->nidx;
    for (;;) {
        while (*s == ' ' || *s == '\t') s++;
        if (!*s) break;
        char *end;
        errno = 0;
        long k = strtol(s, &end, 10);
        if (end == s || (*end != '/' && *end != ' ' && *end != '\t' && *end != '\0'))
            return dr_error_set(err, DR_ERR_INPUT, path, line, 0,
                                "malformed polyline: expected \"l a b ...\" with vertex indices");
        int i;
        if (errno == 0 && k > 0 && k <= INT_MAX) {
            i = (int)(k - 1);
            if (k > p->max_index) p->max_index = (int)k, p->max_index_line = line;
        } else if (errno == 0 && k < 0 && k >= -(long)p->nv) {
            i = p->nv + (int)k; /* -1 is the last vertex so far */
        } else {
            return dr_error_set(err, DR_ERR_INPUT, path, line, 0,
                                "polyline index %ld refers to no vertex (%d vertices so far)", k, p->nv);
        }
        DR_TRY(push_index(p, i, err));
        s = end;
        while (*s && *s != ' ' && *s != '\t') s++; /* the rest of "a/b" */
    }
    if (p->nidx - first < 2)
        return dr_error_set(err, DR_ERR_INPUT, path, line, 0,
                            "polyline of %zu vertex index(es): a strand needs at least 2 vertices", p->nidx - first);
    if (p->nidx > INT_MAX / 3)
        return dr_error_set(err, DR_ERR_INPUT, path, line, 0, "too many polyline vertices (more than %d)",
                            INT_MAX / 3);
    if (p->nstrands == 0) p->start[0] = 0;
    p->radius[p->nstrands] = radius;
    p->start[++p->nstrands] = (int)p->nidx;
    return DR_OK;
}

static DrStatus parse_radius(const char *path, int line, const char *s, double *radius, DrError *err)
{
    char *end;
    double r = strtod(s, &end);
    if (end == s || !blank(end))
        return dr_error_set(err, DR_ERR_INPUT, path, line, 0,
                            "malformed radius line: expected \"# radius R\" (metres)");
    if (!isfinite(r) || r < 0.0)
        return dr_error_set(err, DR_ERR_INPUT, path, line, 0, "strand radius %g is not a finite number >= 0", r);
    *radius = r;
    return DR_OK;
}

static DrStatus parse_file(const char *path, FILE *f, Parse *p, DrError *err)
{
    char *buf = NULL;
    size_t cap = 0;
    ssize_t len;
    int line = 0;
    double radius = 0.0;
    bool have_radius = false;
    DrStatus s = DR_OK;
    while (s == DR_OK && (len = getline(&buf, &cap, f)) >= 0) {
        line++;
        if ((size_t)len != strlen(buf)) {
            s = dr_error_set(err, DR_ERR_INPUT, path, line, 0, "binary data (a NUL byte): not a text OBJ file");
            break;
        }
        while (len > 0 && (buf[len - 1] == '\n' || buf[len - 1] == '\r')) buf[--len] = '\0';
        const char *t = buf;
        while (*t == ' ' || *t == '\t') t++;
        if (*t == '#') {
            t++;
            while (*t == ' ' || *t == '\t') t++;
            if (keyword(t, "radius")) {
                s = parse_radius(path, line, t + 6, &radius, err);
                have_radius = true;
            }
        } else if (keyword(t, "v")) {
            s = parse_vertex(path, line, t + 1, p, err);
        } else if (keyword(t, "l")) {
            s = parse_line_record(path, line, t + 1, radius, have_radius, p, err);
        }
    }
    if (s == DR_OK && ferror(f))
        s = dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot read the file: %s", strerror(errno));
    free(buf);
    if (s == DR_OK && p->max_index > p->nv)
        s = dr_error_set(err, DR_ERR_INPUT, path, p->max_index_line, 0,
                         "polyline index %d refers to no vertex (the file has %d)", p->max_index, p->nv);
    return s;
}

DrStatus dr_io_read_polylines_obj(const char *path, DrPolylines *out, DrError *err)
{
    assert(path && out);
    *out = (DrPolylines){0};
    FILE *f = fopen(path, "r");
    if (!f)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot open the polyline file: %s", strerror(errno));
    Parse p = {0};
    DrStatus s = parse_file(path, f, &p, err);
    fclose(f);
    DrPolylines r = {.count = p.nstrands};
    if (s == DR_OK) s = dr_calloc((size_t)r.count + 1, sizeof *r.offsets, &r.offsets, err);
    if (s == DR_OK) s = dr_calloc(3 * p.nidx + 1, sizeof *r.x, &r.x, err);
    if (s == DR_OK) s = dr_calloc((size_t)r.count + 1, sizeof *r.radius, &r.radius, err);
    if (s == DR_OK) {
        for (int k = 0; k < r.count; k++) {
            r.offsets[k + 1] = p.start[k + 1];
            r.radius[k] = p.radius[k];
        }
        for (size_t k = 0; k < p.nidx; k++) memcpy(r.x + 3 * k, p.v + 3 * (size_t)p.idx[k], 3 * sizeof *r.x);
        *out = r;
    } else {
        dr_io_polylines_free(&r);
    }
    parse_free(&p);
    return s;
}
