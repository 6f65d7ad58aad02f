/* OBJ polylines: strand sets (hair) written by the mesh stage and read back by the render stage, and grooms
 * drawn in other tools (dr_groom_read_obj). The radius rides in "# radius R" comments and a wet strand's film
 * in "# outer_radius" comments (io.h), so the file stays a plain OBJ for every other tool. Parsed here rather than through assimp, as dr_io_load_mesh keeps
 * triangles only. The whole file is checked before anything is returned, and every problem is reported at
 * its line and column. */
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
    free(p->outer);
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
    for (int i = 0; p->outer && i < nv; i++)
        if (!isfinite(p->outer[i]) || p->outer[i] < 0.0)
            return dr_error_set(err, DR_ERR_RUNTIME, path, 0, 0,
                                "vertex %d has film outer radius %g, not a finite number >= 0; nothing was written", i,
                                p->outer[i]);
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
        if (p->outer) {
            fputs("# outer_radius", f);
            for (int v = p->offsets[s]; v < p->offsets[s + 1]; v++) fprintf(f, " %.9g", p->outer[v]);
            fputc('\n', f);
        }
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

void dr_io_polylines_read_desc_default(DrPolylinesReadDesc *d)
{
    *d = (DrPolylinesReadDesc){.require_radius = true, .require_strands = false, .reject_zero_edges = false};
}

/* A positive index past the vertices read so far. OBJ allows such forward references; whether the vertex
 * exists is known only at the end of the file, and then the first one that does not is reported. */
typedef struct Forward {
    long index; /* 0-based */
    int line, col;
} Forward;

/* The parser: where it is (for messages) and what it has collected. Vertices in file order, and per strand
 * its vertex indices (0-based, into the file's vertices) in one flat array. The column of every index and
 * the line of every strand are kept only when zero-length edges are checked: that check waits for the end
 * of the file (an edge may end at a forward reference) and its message needs them. */
typedef struct Parse {
    const char *path;
    DrPolylinesReadDesc desc;
    DrError *err;
    int line;       /* current line, 1-based */
    const char *ln; /* its text: columns count from here */
    double radius;  /* the last "# radius" line's; NAN before any */
    bool have_radius;
    double *pend;   /* the numbers of an "# outer_radius" line waiting for its "l" record */
    int npend, pend_line;
    size_t cap_pend;
    bool have_pend;
    int outer_strands; /* strands that had an "# outer_radius" line */
    double *v;
    int nv;
    size_t cap_v;
    int *idx;
    double *outer; /* per index the film's outer radius (allocated with the first "# outer_radius" line) */
    int *col; /* per index its column (reject_zero_edges only) */
    size_t nidx, cap_idx;
    int *start; /* nstrands + 1 into idx */
    double *sradius;
    int *sline; /* per strand its line (reject_zero_edges only) */
    int nstrands;
    size_t cap_strands;
    Forward *fwd;
    size_t nfwd, cap_fwd;
} Parse;

static void parse_free(Parse *p)
{
    free(p->v);
    free(p->idx);
    free(p->outer);
    free(p->pend);
    free(p->col);
    free(p->start);
    free(p->sradius);
    free(p->sline);
    free(p->fwd);
    *p = (Parse){0};
}

/* A DR_ERR_INPUT at the current line, at the column of `at` (NULL: column 1). */
DR_PRINTF(3, 4) static DrStatus fail_at(const Parse *p, const char *at, const char *fmt, ...)
{
    char msg[sizeof p->err->message];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    int col = at ? (int)(at - p->ln) + 1 : 1;
    return dr_error_set(p->err, DR_ERR_INPUT, p->path, p->line, col, "%s", msg);
}

static bool is_blank(char c) { return c == ' ' || c == '\t' || c == '\f' || c == '\v'; }

static char *skip_blanks(char *s)
{
    while (is_blank(*s)) s++;
    return s;
}

/* Next blank-separated token of a line, NUL-terminated in place; NULL at the line's end. */
static char *next_token(char **cursor)
{
    char *c = skip_blanks(*cursor);
    if (!*c) return NULL;
    char *start = c;
    while (*c && !is_blank(*c)) c++;
    if (*c) *c++ = '\0';
    *cursor = c;
    return start;
}

/* Token `word` at the start of s, followed by a blank or the end. */
static bool keyword(const char *s, const char *word)
{
    size_t n = strlen(word);
    return strncmp(s, word, n) == 0 && (s[n] == '\0' || is_blank(s[n]));
}

/* "v x y z [more numbers]": a weight w or a vertex colour may follow x y z; they are checked and ignored. */
static DrStatus parse_vertex(Parse *p, char *cursor)
{
    double xyz[3];
    int got = 0;
    for (char *tok; (tok = next_token(&cursor)); got++) {
        char *end;
        double x = strtod(tok, &end); /* overflow gives ±inf, caught below */
        if (end == tok || *end)
            return fail_at(p, tok, "'%s' is not a number; a 'v' record is \"v x y z\" in metres", tok);
        if (!isfinite(x))
            return fail_at(p, tok, "vertex coordinate '%s' is not finite; the file is corrupt, fix or rerun what "
                                   "wrote it", tok);
        if (got < 3) xyz[got] = x;
    }
    if (got < 3)
        return fail_at(p, NULL, "'v' record with %d number%s; a vertex is \"v x y z\" in metres", got,
                       got == 1 ? "" : "s");
    if (p->nv >= INT_MAX / 3) return fail_at(p, NULL, "more than %d vertices; split the file", INT_MAX / 3);
    if ((size_t)p->nv == p->cap_v) {
        size_t cap = p->cap_v ? 2 * p->cap_v : 1024;
        DR_TRY(dr_realloc(3 * cap, sizeof *p->v, &p->v, p->err));
        p->cap_v = cap;
    }
    memcpy(p->v + 3 * (size_t)p->nv, xyz, sizeof xyz);
    p->nv++;
    return DR_OK;
}

static DrStatus push_index(Parse *p, int i, int col)
{
    if (p->nidx == p->cap_idx) {
        size_t cap = p->cap_idx ? 2 * p->cap_idx : 4096;
        DR_TRY(dr_realloc(cap, sizeof *p->idx, &p->idx, p->err));
        if (p->outer) DR_TRY(dr_realloc(cap, sizeof *p->outer, &p->outer, p->err));
        if (p->desc.reject_zero_edges) DR_TRY(dr_realloc(cap, sizeof *p->col, &p->col, p->err));
        p->cap_idx = cap;
    }
    p->idx[p->nidx] = i;
    if (p->desc.reject_zero_edges) p->col[p->nidx] = col;
    p->nidx++;
    return DR_OK;
}

static DrStatus push_forward(Parse *p, Forward f)
{
    if (p->nfwd == p->cap_fwd) {
        size_t cap = p->cap_fwd ? 2 * p->cap_fwd : 64;
        DR_TRY(dr_realloc(cap, sizeof *p->fwd, &p->fwd, p->err));
        p->cap_fwd = cap;
    }
    p->fwd[p->nfwd++] = f;
    return DR_OK;
}

/* "l i j k ...": one strand, root first. Relative indices resolve now (against the vertices so far);
 * positive ones past them are checked at the end of the file. */
static DrStatus parse_polyline(Parse *p, const char *key, char *cursor)
{
    if (p->desc.require_radius && !p->have_radius)
        return fail_at(p, key, "polyline before any \"# radius R\" line: the strand radius is unknown; the file was "
                               "not written by the mesh stage, rerun mesh (or pipeline.sh)");
    if (p->nstrands >= INT_MAX - 1) return fail_at(p, key, "more than %d polylines; split the file", INT_MAX - 2);
    if ((size_t)p->nstrands + 1 >= p->cap_strands) {
        size_t cap = p->cap_strands ? 2 * p->cap_strands : 256;
        DR_TRY(dr_realloc(cap, sizeof *p->start, &p->start, p->err));
        DR_TRY(dr_realloc(cap, sizeof *p->sradius, &p->sradius, p->err));
        if (p->desc.reject_zero_edges) DR_TRY(dr_realloc(cap, sizeof *p->sline, &p->sline, p->err));
        p->cap_strands = cap;
    }
    size_t first = p->nidx;
    for (char *tok; (tok = next_token(&cursor));) {
        char *end;
        errno = 0;
        long k = strtol(tok, &end, 10);
        if (end == tok || (*end && *end != '/') || errno == ERANGE)
            return fail_at(p, tok, "'%s' is not a vertex index; an 'l' record lists 'v' indices (1-based, or "
                                   "negative from the last vertex), root first", tok);
        if (k == 0)
            return fail_at(p, tok, "vertex index 0: OBJ indices start at 1 (negative ones count back from the last "
                                   "vertex)");
        if (k < -(long)p->nv)
            return fail_at(p, tok, "vertex index %ld is out of range: only %d 'v' records come before this line", k,
                           p->nv);
        if (p->nidx >= INT_MAX / 3)
            return fail_at(p, tok, "more than %d strand vertices; split the file", INT_MAX / 3);
        long i = k < 0 ? p->nv + k : k - 1;
        int col = (int)(tok - p->ln) + 1;
        if (i >= p->nv) DR_TRY(push_forward(p, (Forward){.index = i, .line = p->line, .col = col}));
        /* an index past INT_MAX is out of range whatever follows; the forward check reports it */
        DR_TRY(push_index(p, i < INT_MAX ? (int)i : INT_MAX, col));
    }
    size_t n = p->nidx - first;
    if (n < 2)
        return fail_at(p, key, "'l' record with %zu vert%s; a strand needs at least 2 (root first)", n,
                       n == 1 ? "ex" : "ices");
    /* the film's outer radii: every strand has its "# outer_radius" line, or none has */
    if (p->have_pend && p->outer_strands < p->nstrands)
        return fail_at(p, key, "this strand has an \"# outer_radius\" line (line %d) but the %d before it have none; "
                               "give every strand one or none (the mesh stage writes one per strand of wet hair)",
                       p->pend_line, p->nstrands - p->outer_strands);
    if (!p->have_pend && p->outer_strands > 0)
        return fail_at(p, key, "this strand has no \"# outer_radius\" line but the strands before it have one; give "
                               "every strand one or none (the mesh stage writes one per strand of wet hair)");
    if (p->have_pend) {
        if ((size_t)p->npend != n)
            return fail_at(p, key, "the \"# outer_radius\" line before this record (line %d) gives %d radii for its %zu "
                                   "vertices; give one per vertex",
                           p->pend_line, p->npend, n);
        if (!p->outer) DR_TRY(dr_calloc(p->cap_idx, sizeof *p->outer, &p->outer, p->err));
        memcpy(p->outer + first, p->pend, n * sizeof *p->outer);
        p->have_pend = false;
        p->outer_strands++;
    }
    if (p->nstrands == 0) p->start[0] = 0;
    p->sradius[p->nstrands] = p->radius;
    if (p->desc.reject_zero_edges) p->sline[p->nstrands] = p->line;
    p->start[++p->nstrands] = (int)p->nidx;
    return DR_OK;
}

/* "# radius R": the radius of the "l" records that follow. */
static DrStatus parse_radius(Parse *p, char *s)
{
    s = skip_blanks(s);
    char *end;
    double r = strtod(s, &end);
    if (end == s || *skip_blanks(end))
        return fail_at(p, s, "malformed radius line: expected \"# radius R\" (metres)");
    if (!isfinite(r) || r < 0.0) return fail_at(p, s, "strand radius %g is not a finite number >= 0", r);
    p->radius = r;
    p->have_radius = true;
    return DR_OK;
}

/* "# outer_radius H1 H2 ...": the film's outer radius at each vertex of the next "l" record. */
static DrStatus parse_outer(Parse *p, char *cursor)
{
    if (p->have_pend)
        return fail_at(p, NULL, "a second \"# outer_radius\" line before the 'l' record the one on line %d belongs "
                                "to; write one such line right before each 'l' record", p->pend_line);
    p->npend = 0;
    for (char *tok; (tok = next_token(&cursor));) {
        char *end;
        double h = strtod(tok, &end);
        if (end == tok || *end)
            return fail_at(p, tok, "'%s' is not a number; an outer radius line is \"# outer_radius H1 H2 ...\" in "
                                   "metres, one per vertex of the 'l' record after it", tok);
        if (!isfinite(h) || h < 0.0) return fail_at(p, tok, "film outer radius %g is not a finite number >= 0", h);
        if (p->npend >= INT_MAX / 3) return fail_at(p, tok, "more than %d outer radii on one line", INT_MAX / 3);
        if ((size_t)p->npend == p->cap_pend) {
            size_t cap = p->cap_pend ? 2 * p->cap_pend : 64;
            DR_TRY(dr_realloc(cap, sizeof *p->pend, &p->pend, p->err));
            p->cap_pend = cap;
        }
        p->pend[p->npend++] = h;
    }
    p->have_pend = true;
    p->pend_line = p->line;
    return DR_OK;
}

/* One line as getline returned it (`len` bytes with its '\n'): text checks, then a radius comment or a
 * "v" or "l" record; anything else is skipped. */
static DrStatus parse_line(Parse *p, char *ln, size_t len)
{
    p->ln = ln;
    if (strlen(ln) != len)
        return fail_at(p, ln + strlen(ln), "a NUL byte: this is not a text OBJ file; write or export it as text");
    while (len > 0 && (ln[len - 1] == '\n' || ln[len - 1] == '\r')) ln[--len] = '\0';
    for (size_t i = 0; i < len; i++) {
        unsigned char c = (unsigned char)ln[i];
        if (c < 0x20 && c != '\t' && c != '\f' && c != '\v')
            return fail_at(p, ln + i, "control byte 0x%02x: this is not a text OBJ file; write or export it as text",
                           c);
    }
    char *t = skip_blanks(ln);
    if (*t == '#') {
        t = skip_blanks(t + 1);
        if (keyword(t, "outer_radius")) return parse_outer(p, t + 12);
        return keyword(t, "radius") ? parse_radius(p, t + 6) : DR_OK;
    }
    char *hash = strchr(t, '#'); /* a comment after a record */
    if (hash) *hash = '\0';
    size_t used = strlen(ln);
    while (used && is_blank(ln[used - 1])) used--;
    bool continued = used && ln[used - 1] == '\\';
    char *cursor = t;
    char *key = next_token(&cursor);
    bool is_v = key && strcmp(key, "v") == 0, is_l = key && strcmp(key, "l") == 0;
    if (!is_v && !is_l) return DR_OK;
    if (continued)
        return fail_at(p, ln + used - 1, "'%s' record continued on the next line ('\\'), which is not supported; "
                                         "write the record on one line", key);
    return is_v ? parse_vertex(p, cursor) : parse_polyline(p, key, cursor);
}

/* Checks that need the whole file: forward indices, then (when asked) edge lengths. */
static DrStatus check_file(Parse *p)
{
    if (p->have_pend)
        return dr_error_set(p->err, DR_ERR_INPUT, p->path, p->pend_line, 1,
                            "\"# outer_radius\" line without an 'l' record after it; write it right before the "
                            "strand's 'l' record");
    if (p->desc.require_strands && p->nstrands == 0)
        return dr_error_set(p->err, DR_ERR_INPUT, p->path, 0, 0,
                            "no 'l' records (polylines) among %d lines: each strand is an 'l' record listing its 'v' "
                            "indices, root first",
                            p->line);
    for (size_t k = 0; k < p->nfwd; k++)
        if (p->fwd[k].index >= p->nv)
            return dr_error_set(p->err, DR_ERR_INPUT, p->path, p->fwd[k].line, p->fwd[k].col,
                                "vertex index %ld is out of range: the file has %d 'v' records", p->fwd[k].index + 1,
                                p->nv);
    if (!p->desc.reject_zero_edges) return DR_OK;
    for (int s = 0; s < p->nstrands; s++) {
        for (int k = p->start[s]; k + 1 < p->start[s + 1]; k++) {
            const double *a = p->v + 3 * (size_t)p->idx[k], *b = p->v + 3 * (size_t)p->idx[k + 1];
            if (dr_v3_norm(dr_v3(b[0] - a[0], b[1] - a[1], b[2] - a[2])) > 0.0) continue;
            return dr_error_set(p->err, DR_ERR_INPUT, p->path, p->sline[s], p->col[k + 1],
                                "zero-length edge: vertices %d and %d of this strand (OBJ indices %d and %d) are at "
                                "the same position; remove the repeated vertex",
                                k - p->start[s] + 1, k - p->start[s] + 2, p->idx[k] + 1, p->idx[k + 1] + 1);
        }
    }
    return DR_OK;
}

static DrStatus parse_file(FILE *f, Parse *p)
{
    char *buf = NULL;
    size_t cap = 0;
    ssize_t len;
    DrStatus s = DR_OK;
    while (s == DR_OK && (len = getline(&buf, &cap, f)) >= 0) {
        p->line++;
        s = parse_line(p, buf, (size_t)len);
    }
    if (s == DR_OK && ferror(f))
        s = dr_error_set(p->err, DR_ERR_IO, p->path, 0, 0, "cannot read the file: %s", strerror(errno));
    free(buf);
    if (s == DR_OK) s = check_file(p);
    return s;
}

DrStatus dr_io_read_polylines_obj(const char *path, const DrPolylinesReadDesc *desc, DrPolylines *out,
                                  DrError *err)
{
    assert(path && out);
    *out = (DrPolylines){0};
    Parse p = {.path = path, .err = err, .radius = NAN};
    if (desc) p.desc = *desc;
    else dr_io_polylines_read_desc_default(&p.desc);
    FILE *f = fopen(path, "r");
    if (!f)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot open the polyline file: %s; check the path",
                            strerror(errno));
    DrStatus s = parse_file(f, &p);
    fclose(f);
    DrPolylines r = {.count = p.nstrands};
    if (s == DR_OK) s = dr_calloc((size_t)r.count + 1, sizeof *r.offsets, &r.offsets, err);
    if (s == DR_OK) s = dr_calloc(3 * p.nidx + 1, sizeof *r.x, &r.x, err);
    if (s == DR_OK) s = dr_calloc((size_t)r.count + 1, sizeof *r.radius, &r.radius, err);
    if (s == DR_OK && p.outer) s = dr_calloc(p.nidx + 1, sizeof *r.outer, &r.outer, err);
    if (s == DR_OK) {
        if (p.outer) memcpy(r.outer, p.outer, p.nidx * sizeof *r.outer);
        for (int k = 0; k < r.count; k++) {
            r.offsets[k + 1] = p.start[k + 1];
            r.radius[k] = p.sradius[k];
        }
        for (size_t k = 0; k < p.nidx; k++) memcpy(r.x + 3 * k, p.v + 3 * (size_t)p.idx[k], 3 * sizeof *r.x);
        *out = r;
    } else {
        dr_io_polylines_free(&r);
    }
    parse_free(&p);
    return s;
}
