/* Scene loading: JSON text → validated, immutable DrScene, driven by the tables in scene_spec.c.
 *
 * One pass over the jansson tree. The parser keeps the JSON path it is at, so every error can name
 * element.Component.field in words and carry the line and column of the culprit (scene_locate.c
 * finds them in the text; jansson keeps no positions for values). Everything the scene owns lives in
 * one arena, freed at once by dr_scene_destroy. */
#include "scene_internal.h"

#include <errno.h>
#include <jansson.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define MAX_DEPTH 8 /* elements / i / components / Motion / keys / row / column is the deepest path */
#define WHERE_MAX 512

typedef struct Parser {
    DrScene *s;
    const char *text;
    size_t len;
    const char *dir; /* the scene file's directory, "" when the path has none */
    DrError *err;
    DrJsonSeg path[MAX_DEPTH];
    int depth;
} Parser;

static void push_key(Parser *p, const char *key)
{
    assert(p->depth < MAX_DEPTH);
    p->path[p->depth++] = (DrJsonSeg){key, 0};
}

static void push_index(Parser *p, int index)
{
    assert(p->depth < MAX_DEPTH);
    p->path[p->depth++] = (DrJsonSeg){NULL, index};
}

static void pop(Parser *p)
{
    assert(p->depth > 0);
    p->depth--;
}

static DrStatus failv(Parser *p, bool at_key, const char *fmt, va_list ap)
{
    int line, col;
    dr_scene_locate_(p->text, p->len, p->path, p->depth, at_key, &line, &col);
    char msg[sizeof p->err->message];
    vsnprintf(msg, sizeof msg, fmt, ap);
    return dr_error_set(p->err, DR_ERR_INPUT, p->s->path, line, col, "%s", msg);
}

/* An error located at the value the parser is at. */
DR_PRINTF(2, 3) static DrStatus fail(Parser *p, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    DrStatus st = failv(p, false, fmt, ap);
    va_end(ap);
    return st;
}

/* An error located at the key of the member the parser is at (unknown or incomplete names). */
DR_PRINTF(2, 3) static DrStatus fail_key(Parser *p, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    DrStatus st = failv(p, true, fmt, ap);
    va_end(ap);
    return st;
}

static DrStatus nomem(Parser *p) { return dr_error_set(p->err, DR_ERR_NOMEM, p->s->path, 0, 0, "out of memory while loading the scene"); }

static char *arena_strdup(DrArena *a, const char *s)
{
    size_t n = strlen(s) + 1;
    char *d = dr_arena_alloc(a, n, 1);
    if (d) memcpy(d, s, n);
    return d;
}

static const char *json_type_name(const json_t *v)
{
    switch (json_typeof(v)) {
    case JSON_OBJECT: return "object";
    case JSON_ARRAY: return "array";
    case JSON_STRING: return "string";
    case JSON_INTEGER:
    case JSON_REAL: return "number";
    case JSON_TRUE:
    case JSON_FALSE: return "boolean";
    case JSON_NULL: return "null";
    }
    return "value";
}

/* "; did you mean 'x'?" or "." to end the sentence before the list of valid names. */
static void suggestion(const char *word, const char *const *names, int n, char *buf, size_t size)
{
    const char *best = dr_scene_suggest_(word, names, n);
    if (best)
        snprintf(buf, size, "; did you mean '%s'?", best);
    else
        snprintf(buf, size, ".");
}

/* ---- single values ---------------------------------------------------------------------------------- */

static const char *unit_suffix(const DrFieldSpec *f)
{
    if (f->kind == DR_FIELD_TABLE || strcmp(f->unit, "") == 0 || strcmp(f->unit, "1") == 0) return "";
    return f->unit;
}

/* One number of a field: type, integrality, range. */
static DrStatus parse_number(Parser *p, const DrFieldSpec *f, const json_t *v, const char *where, double *out)
{
    bool integral = f->kind == DR_FIELD_INT || f->kind == DR_FIELD_INT2;
    if (!json_is_number(v))
        return fail(p, "%s: expected %s, got %s", where, integral ? "an integer" : "a number", json_type_name(v));
    double x = json_number_value(v);
    char xs[32];
    dr_scene_fmt_num_(x, xs, sizeof xs);
    if (integral && x != floor(x)) return fail(p, "%s: expected an integer, got %s", where, xs);
    if (f->ranged && ((f->lo_open ? !(x > f->lo) : !(x >= f->lo)) || (f->hi_open ? !(x < f->hi) : !(x <= f->hi)))) {
        char range[96];
        dr_scene_fmt_range_(f, range, sizeof range);
        const char *unit = unit_suffix(f);
        return fail(p, "%s = %s is out of range %s%s%s; %s", where, xs, range, unit[0] ? " " : "", unit,
                    f->hint ? f->hint : "choose a value in that range");
    }
    *out = x == 0.0 ? 0.0 : x; /* -0 and 0 are one value */
    return DR_OK;
}

/* An array of exactly n numbers of field f; `shape` describes it for messages. */
static DrStatus parse_numbers(Parser *p, const DrFieldSpec *f, const json_t *v, const char *where, int n,
                              const char *shape, double *out)
{
    if (!json_is_array(v)) return fail(p, "%s: expected %s, got %s", where, shape, json_type_name(v));
    if (json_array_size(v) != (size_t)n)
        return fail(p, "%s: expected %s, got an array of %zu", where, shape, json_array_size(v));
    for (int i = 0; i < n; i++) {
        char w[WHERE_MAX + 16];
        snprintf(w, sizeof w, "%s[%d]", where, i);
        push_index(p, i);
        DR_TRY(parse_number(p, f, json_array_get(v, (size_t)i), w, &out[i]));
        pop(p);
    }
    return DR_OK;
}

/* NULL for a valid NAME, else why not (written into buf). */
static const char *name_problem(const char *s, char *buf, size_t size)
{
    size_t n = strlen(s);
    if (n == 0) return "it is empty";
    if (n > DR_SCENE_NAME_MAX) return "it is longer than 128 characters";
    if (strcmp(s, ".") == 0 || strcmp(s, "..") == 0) return "'.' and '..' are reserved";
    for (const char *c = s; *c; c++) {
        if ((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') || *c == '_' ||
            *c == '.' || *c == '-')
            continue;
        if (*c > ' ' && *c < 127) snprintf(buf, size, "it has '%c'", *c);
        else snprintf(buf, size, "it has a space, a control or a non-ASCII character");
        return buf;
    }
    return NULL;
}

static bool is_file(const char *path, bool *is_dir)
{
    struct stat st;
    if (stat(path, &st) != 0) return false;
    if (S_ISDIR(st.st_mode)) *is_dir = true;
    return S_ISREG(st.st_mode);
}

/* Asset paths: relative to the scene file's directory first, then to the current directory. `raw`
 * lives in the scene's arena, and so does *out. */
static DrStatus resolve_path(Parser *p, const char *raw, const char *where, const char **out)
{
    if (raw[0] == '\0') return fail(p, "%s: empty path; give the asset file, relative to the scene file", where);
    DrArena *a = p->s->arena;
    const char *cand[2] = {raw, NULL};
    int ncand = 1;
    if (raw[0] != '/' && p->dir[0]) {
        size_t n = strlen(p->dir) + strlen(raw) + 2;
        char *joined = dr_arena_alloc(a, n, 1);
        if (!joined) return nomem(p);
        snprintf(joined, n, "%s/%s", p->dir, raw);
        cand[0] = joined;
        cand[1] = raw;
        ncand = 2;
    }
    bool dir = false;
    for (int i = 0; i < ncand; i++) {
        if (is_file(cand[i], &dir)) {
            *out = cand[i];
            return DR_OK;
        }
    }
    if (dir) return fail(p, "%s: asset '%s' is a directory, not a file; give the mesh file itself", where, raw);
    char cwd[1024];
    if (!getcwd(cwd, sizeof cwd)) snprintf(cwd, sizeof cwd, ".");
    if (raw[0] == '/') return fail(p, "%s: asset '%s' not found; fix the path", where, raw);
    if (ncand == 2)
        return fail(p, "%s: asset '%s' not found (looked in %s/ and in the current directory %s/); fix the path",
                    where, raw, p->dir, cwd);
    return fail(p, "%s: asset '%s' not found (looked in %s/, the scene file's directory); fix the path", where,
                raw, cwd);
}

static DrStatus parse_enum(Parser *p, const DrFieldSpec *f, const json_t *v, const char *where, DrValue *out)
{
    char split[256], list[256];
    const char *names[16];
    int n = dr_scene_split_choices_(f->choices, split, sizeof split, names, 16);
    dr_scene_join_names_(names, n, list, sizeof list);
    if (!json_is_string(v)) return fail(p, "%s: expected one of %s, got %s", where, list, json_type_name(v));
    const char *s = json_string_value(v);
    for (int i = 0; i < n; i++) {
        if (strcmp(names[i], s) == 0) {
            out->str = arena_strdup(p->s->arena, s);
            return out->str ? DR_OK : nomem(p);
        }
    }
    char sug[160];
    suggestion(s, names, n, sug, sizeof sug);
    return fail(p, "%s: '%s' is not a valid choice%s Choose one of %s", where, s, sug, list);
}

/* Any field: the JSON value v at the current path; fills out and marks it set. */
static DrStatus parse_field(Parser *p, const DrFieldSpec *f, const json_t *v, const char *where, DrValue *out)
{
    DrArena *a = p->s->arena;
    switch (f->kind) {
    case DR_FIELD_NUMBER:
    case DR_FIELD_INT: DR_TRY(parse_number(p, f, v, where, &out->num[0])); break;
    case DR_FIELD_BOOL:
        if (!json_is_boolean(v)) return fail(p, "%s: expected true or false, got %s", where, json_type_name(v));
        out->num[0] = json_is_true(v) ? 1.0 : 0.0;
        break;
    case DR_FIELD_ENUM: DR_TRY(parse_enum(p, f, v, where, out)); break;
    case DR_FIELD_NAME: {
        if (!json_is_string(v)) return fail(p, "%s: expected a name string, got %s", where, json_type_name(v));
        char reason[64];
        const char *why = name_problem(json_string_value(v), reason, sizeof reason);
        if (why)
            return fail(p, "%s: '%s' is not a valid name (%s); use letters, digits, '_', '.' and '-', e.g. \"water\"",
                        where, json_string_value(v), why);
        out->str = arena_strdup(a, json_string_value(v));
        if (!out->str) return nomem(p);
        break;
    }
    case DR_FIELD_PATH:
        if (!json_is_string(v)) return fail(p, "%s: expected a file path string, got %s", where, json_type_name(v));
        out->raw = arena_strdup(a, json_string_value(v));
        if (!out->raw) return nomem(p);
        DR_TRY(resolve_path(p, out->raw, where, &out->str));
        break;
    case DR_FIELD_VEC3: DR_TRY(parse_numbers(p, f, v, where, 3, "an array of 3 numbers [x, y, z]", out->num)); break;
    case DR_FIELD_INT2: DR_TRY(parse_numbers(p, f, v, where, 2, "an array of 2 integers", out->num)); break;
    case DR_FIELD_BOX: {
        const char *shape = "a box [[x0, y0, z0], [x1, y1, z1]]";
        if (!json_is_array(v)) return fail(p, "%s: expected %s, got %s", where, shape, json_type_name(v));
        if (json_array_size(v) != 2)
            return fail(p, "%s: expected %s (two corners), got an array of %zu", where, shape, json_array_size(v));
        for (int c = 0; c < 2; c++) {
            char w[WHERE_MAX + 16];
            snprintf(w, sizeof w, "%s[%d]", where, c);
            push_index(p, c);
            DR_TRY(parse_numbers(p, f, json_array_get(v, (size_t)c), w, 3, "a corner [x, y, z]", &out->num[3 * c]));
            pop(p);
        }
        for (int k = 0; k < 3; k++) {
            if (!(out->num[k] < out->num[3 + k])) {
                char lo[32], hi[32];
                dr_scene_fmt_num_(out->num[k], lo, sizeof lo);
                dr_scene_fmt_num_(out->num[3 + k], hi, sizeof hi);
                return fail(p, "%s: the lower corner must be below the upper corner on every axis, but on %c it "
                               "goes from %s to %s; write [[x0, y0, z0], [x1, y1, z1]] with x0 < x1, y0 < y1, z0 < z1",
                            where, "xyz"[k], lo, hi);
            }
        }
        break;
    }
    case DR_FIELD_TABLE: {
        char shape[64];
        snprintf(shape, sizeof shape, "an array of rows of %d numbers", f->arity);
        if (!json_is_array(v)) return fail(p, "%s: expected %s, got %s", where, shape, json_type_name(v));
        size_t nrows = json_array_size(v);
        if (nrows > (size_t)INT32_MAX / (size_t)f->arity)
            return fail(p, "%s: %zu rows are too many", where, nrows);
        double *rows = NULL;
        if (nrows) {
            rows = dr_arena_alloc(a, nrows * (size_t)f->arity, sizeof(double));
            if (!rows) return nomem(p);
        }
        char row_shape[64];
        snprintf(row_shape, sizeof row_shape, "a row of %d numbers", f->arity);
        for (size_t r = 0; r < nrows; r++) {
            char w[WHERE_MAX + 24];
            snprintf(w, sizeof w, "%s[%zu]", where, r);
            push_index(p, (int)r);
            DR_TRY(parse_numbers(p, f, json_array_get(v, r), w, f->arity, row_shape, rows + r * (size_t)f->arity));
            pop(p);
        }
        out->rows = rows;
        out->nrows = (int)nrows;
        break;
    }
    case DR_FIELD_NAMES: {
        const char *shape = "a list of element names [\"a\", \"b\", ...]";
        if (!json_is_array(v)) return fail(p, "%s: expected %s, got %s", where, shape, json_type_name(v));
        size_t n = json_array_size(v);
        if (n == 0) return fail(p, "%s: the list is empty; name at least one element, e.g. [\"fur\"]", where);
        if (n > 4096) return fail(p, "%s: %zu names are too many", where, n);
        const char **names = dr_arena_alloc(a, n, sizeof *names);
        if (!names) return nomem(p);
        for (size_t i = 0; i < n; i++) {
            const json_t *x = json_array_get(v, i);
            push_index(p, (int)i);
            if (!json_is_string(x))
                return fail(p, "%s[%zu]: expected an element name string, got %s", where, i, json_type_name(x));
            char reason[64];
            const char *why = name_problem(json_string_value(x), reason, sizeof reason);
            if (why)
                return fail(p, "%s[%zu]: '%s' is not a valid name (%s); use letters, digits, '_', '.' and '-'", where,
                            i, json_string_value(x), why);
            for (size_t j = 0; j < i; j++)
                if (strcmp(names[j], json_string_value(x)) == 0)
                    return fail(p, "%s[%zu]: '%s' is listed twice (also at [%zu]); list each element once", where, i,
                                names[j], j);
            names[i] = arena_strdup(a, json_string_value(x));
            if (!names[i]) return nomem(p);
            pop(p);
        }
        out->names = names;
        out->nrows = (int)n;
        break;
    }
    }
    out->set = out->has = true;
    return DR_OK;
}

/* ---- cross-field rules ------------------------------------------------------------------------------ */

static const DrValue *value_at(const DrComponent *c, const char *field)
{
    int i = dr_scene_field_index_(c->spec, field);
    assert(i >= 0);
    return &c->values[i];
}

static DrStatus check_shot(Parser *p, const DrComponent *c, const char *where)
{
    const DrValue *fr = value_at(c, "frames");
    if (fr->num[0] > fr->num[1]) {
        push_key(p, "frames");
        return fail(p, "%s.frames = [%.0f, %.0f]: frames out of order; the first frame must not come after the "
                       "last, e.g. [%.0f, %.0f]", where, fr->num[0], fr->num[1], fr->num[1], fr->num[0]);
    }
    return DR_OK;
}

static DrStatus check_camera(Parser *p, const DrComponent *c, const char *where)
{
    const double *eye = value_at(c, "eye")->num, *target = value_at(c, "target")->num, *up = value_at(c, "up")->num;
    DrVec3 view = dr_v3(target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]);
    DrVec3 u = dr_v3(up[0], up[1], up[2]);
    if (dr_v3_norm(view) == 0.0) {
        push_key(p, "target");
        return fail(p, "%s: eye and target are the same point; move the target to where the camera should look", where);
    }
    /* parallel when |view × up| is tiny against |view||up| (also catches up = 0) */
    if (!(dr_v3_norm(dr_v3_cross(view, u)) > 1e-9 * dr_v3_norm(view) * dr_v3_norm(u))) {
        push_key(p, "up");
        return fail(p, "%s.up is zero or parallel to the view direction (target - eye); use an up vector such "
                       "as [0, 1, 0] that is not", where);
    }
    return DR_OK;
}

static DrStatus check_emitter(Parser *p, const DrComponent *c, const char *where)
{
    double start = value_at(c, "start")->num[0], end = value_at(c, "end")->num[0];
    if (start > end) {
        char a[32], b[32];
        dr_scene_fmt_num_(start, a, sizeof a);
        dr_scene_fmt_num_(end, b, sizeof b);
        push_key(p, value_at(c, "end")->set ? "end" : "start");
        return fail(p, "%s: start = %s s is after end = %s s; the emitter must start before it ends", where, a, b);
    }
    return DR_OK;
}

/* The wind enters through its face: the velocity's component along the face's axis points into the box, or the
   whole velocity is 0 (a closed box). */
static DrStatus check_wind(Parser *p, const DrComponent *c, const char *where)
{
    const char *face = value_at(c, "face")->str;
    const double *v = value_at(c, "velocity")->num;
    int axis = face[1] - 'x';
    bool low = face[0] == '-';
    double un = v[axis];
    char a[32];
    dr_scene_fmt_num_(un, a, sizeof a);
    if (un == 0.0 && (v[0] != 0.0 || v[1] != 0.0 || v[2] != 0.0)) {
        push_key(p, "velocity");
        return fail(p, "%s.velocity has no %c component, so no wind enters through face %s: give it a component "
                       "into the box (%s along %c), or set velocity to [0, 0, 0] for a closed box", where, 'x' + axis,
                    face, low ? "positive" : "negative", 'x' + axis);
    }
    if (un != 0.0 && (un > 0.0) != low) {
        push_key(p, "velocity");
        return fail(p, "%s.velocity: its %c component (%s m/s) points out of the box through face %s, where the wind "
                       "enters; make it %s, or set face to \"%c%c\"", where, 'x' + axis, a, face,
                    low ? "positive" : "negative", low ? '+' : '-', 'x' + axis);
    }
    return DR_OK;
}

static DrStatus check_source(Parser *p, const DrComponent *c, const char *where)
{
    if (!value_at(c, "box")->set && !value_at(c, "mesh")->set)
        return fail_key(p, "%s: needs \"box\" or \"mesh\" for the liquid present at t=0; add \"box\": [[x0, y0, z0], "
                           "[x1, y1, z1]] or remove the component", where);
    return DR_OK;
}

static DrStatus check_motion(Parser *p, const DrComponent *c, const char *where)
{
    const DrValue *k = value_at(c, "keys");
    for (int r = 1; r < k->nrows; r++) {
        double prev = k->rows[7 * (r - 1)], cur = k->rows[7 * r];
        if (!(cur > prev)) {
            char a[32], b[32];
            dr_scene_fmt_num_(prev, a, sizeof a);
            dr_scene_fmt_num_(cur, b, sizeof b);
            push_key(p, "keys");
            push_index(p, r);
            return fail(p, "%s.keys[%d]: frames out of order (frame %s after frame %s); key frames must be "
                           "strictly increasing", where, r, b, a);
        }
    }
    return DR_OK;
}

static DrStatus check_mpm_shape(Parser *p, const DrComponent *c, const char *where)
{
    bool box = value_at(c, "box")->set, centre = value_at(c, "centre")->set, radius = value_at(c, "radius")->set;
    bool mesh = value_at(c, "mesh")->set;
    if (centre != radius) {
        push_key(p, centre ? "centre" : "radius");
        return fail_key(p, "%s: a sphere needs both \"centre\" and \"radius\"; add %s", where,
                        centre ? "\"radius\": r (metres)" : "\"centre\": [x, y, z]");
    }
    int shapes = (int)box + (int)centre + (int)mesh;
    if (shapes == 0)
        return fail_key(p, "%s: no shape; add one of \"box\": [[x0, y0, z0], [x1, y1, z1]], \"centre\": [x, y, z] "
                           "with \"radius\": r, or \"mesh\": \"path/to/closed.obj\"", where);
    if (shapes > 1) {
        const char *given = !box ? "a sphere and a mesh" : !centre ? "a box and a mesh" : !mesh ? "a box and a sphere"
                                                                                              : "a box, a sphere and a mesh";
        push_key(p, mesh ? "mesh" : "centre");
        return fail_key(p, "%s: %s are given, but a body has exactly one shape: keep one of box, centre and radius, "
                           "or mesh", where, given);
    }
    return DR_OK;
}

/* A groom is grown from a scalp or read from curves, never both; the growth parameters mean nothing for
   curves, so writing one there is a mistake worth naming rather than a value silently ignored. */
static DrStatus check_groom(Parser *p, const DrComponent *c, const char *where)
{
    bool scalp = value_at(c, "scalp")->set, curves = value_at(c, "curves")->set;
    if (!scalp && !curves)
        return fail_key(p, "%s: no strands; add \"scalp\": \"path/to/scalp.obj\" to grow them from a mesh, or "
                           "\"curves\": \"path/to/curves.obj\" to read OBJ polylines", where);
    if (scalp && curves) {
        push_key(p, "curves");
        return fail_key(p, "%s: both scalp and curves are given, but a groom comes from exactly one: keep scalp (grow "
                           "strands from the mesh) or curves (read its polylines)", where);
    }
    if (curves) {
        for (int i = 0; i < c->spec->field_count; i++) {
            const char *name = c->spec->fields[i].name;
            if (!c->values[i].set || strcmp(name, "curves") == 0 || strcmp(name, "roots") == 0) continue;
            push_key(p, name);
            return fail_key(p, "%s.%s applies to strands grown from a scalp; with curves the strands are the file's "
                               "polylines: remove %s", where, name, name);
        }
    }
    return DR_OK;
}

typedef DrStatus (*CheckFn)(Parser *p, const DrComponent *c, const char *where);
static const struct {
    const char *spec;
    CheckFn fn;
} checks[] = {
    {"shot", check_shot},       {"render.camera", check_camera}, {"Emitter", check_emitter},
    {"LiquidSource", check_source}, {"Motion", check_motion}, {"MpmShape", check_mpm_shape},
    {"Groom", check_groom}, {"Wind", check_wind},
};

/* ---- components and sections ------------------------------------------------------------------------- */

static DrStatus init_component(DrScene *s, const DrComponentSpec *spec, DrComponent *c)
{
    c->spec = spec;
    c->present = false;
    c->values = dr_arena_alloc(s->arena, (size_t)spec->field_count, sizeof(DrValue));
    if (!c->values) return DR_ERR_NOMEM;
    for (int i = 0; i < spec->field_count; i++) {
        const DrFieldSpec *f = &spec->fields[i];
        DrValue *v = &c->values[i];
        v->has = f->kind == DR_FIELD_TABLE || !(f->required || f->no_default || f->kind == DR_FIELD_PATH);
        if (!v->has) continue;
        memcpy(v->num, f->def, sizeof v->num);
        v->str = f->def_str;
    }
    return DR_OK;
}

/* Index of the section nested in `parent` under `key` ("render" + "camera"), -1 if none. */
static int child_section(const char *parent, const char *key)
{
    size_t n = strlen(parent);
    for (int i = 0; i < dr_scene_section_count_; i++) {
        const char *name = dr_scene_sections_[i].name;
        if (strncmp(name, parent, n) == 0 && name[n] == '.' && strcmp(name + n + 1, key) == 0) return i;
    }
    return -1;
}

static const char *example_of(const DrFieldSpec *f)
{
    switch (f->kind) {
    case DR_FIELD_BOX: return "[[x0, y0, z0], [x1, y1, z1]]";
    case DR_FIELD_PATH: return "\"path/to/mesh.obj\"";
    case DR_FIELD_VEC3: return "[x, y, z]";
    case DR_FIELD_NAMES: return "[\"name\", ...]";
    default: return "...";
    }
}

/* What to write for a missing field: example_of's text, or for a choice its first choice and the others. */
static void example_text(const DrFieldSpec *f, char *buf, size_t size)
{
    if (f->kind != DR_FIELD_ENUM) {
        snprintf(buf, size, "%s", example_of(f));
        return;
    }
    char split[256], list[256];
    const char *names[16];
    int n = dr_scene_split_choices_(f->choices, split, sizeof split, names, 16);
    dr_scene_join_names_(names, n, list, sizeof list);
    snprintf(buf, size, "\"%s\" (one of %s)", names[0], list);
}

/* The JSON object v at the current path into c (a component, or a section when `sections` is given:
 * then nested sections are accepted too). */
static DrStatus parse_component(Parser *p, const json_t *v, DrComponent *c, const char *where, DrComponent *sections)
{
    const DrComponentSpec *spec = c->spec;
    if (!json_is_object(v))
        return fail(p, "%s: expected an object of fields {\"field\": value, ...}, got %s", where, json_type_name(v));
    c->present = true;
    const char *key;
    json_t *fv;
    json_object_foreach((json_t *)v, key, fv) {
        push_key(p, key);
        char w[WHERE_MAX];
        snprintf(w, sizeof w, "%s.%s", where, key);
        int fi = dr_scene_field_index_(spec, key);
        int child = sections ? child_section(spec->name, key) : -1;
        if (fi >= 0) {
            DR_TRY(parse_field(p, &spec->fields[fi], fv, w, &c->values[fi]));
        } else if (child >= 0) {
            DR_TRY(parse_component(p, fv, &sections[child], w, sections));
        } else {
            const char *names[32];
            int n = 0;
            for (int i = 0; i < spec->field_count && n < 32; i++) names[n++] = spec->fields[i].name;
            for (int i = 0; sections && i < dr_scene_section_count_ && n < 32; i++) {
                const char *dot = strrchr(dr_scene_sections_[i].name, '.');
                if (dot && child_section(spec->name, dot + 1) == i) names[n++] = dot + 1;
            }
            char sug[256], list[1024];
            suggestion(key, names, n, sug, sizeof sug);
            dr_scene_join_names_(names, n, list, sizeof list);
            return fail_key(p, "%s: unknown field '%s'%s Fields of %s: %s", where, key, sug, spec->name, list);
        }
        pop(p);
    }
    for (int i = 0; i < spec->field_count; i++) {
        const DrFieldSpec *f = &spec->fields[i];
        if (f->required && !c->values[i].set) {
            char ex[300];
            example_text(f, ex, sizeof ex);
            return fail_key(p, "%s: missing required field '%s' (%s); add \"%s\": %s", where, f->name, f->doc,
                            f->name, ex);
        }
    }
    for (size_t i = 0; i < sizeof checks / sizeof checks[0]; i++) {
        if (strcmp(checks[i].spec, spec->name) != 0) continue;
        int depth = p->depth;
        DR_TRY(checks[i].fn(p, c, where));
        p->depth = depth;
    }
    return DR_OK;
}

/* ---- elements ------------------------------------------------------------------------------------------ */

static const DrFieldSpec element_name_spec = {.name = "name", .kind = DR_FIELD_NAME, .unit = "", .doc = "element name"};

/* Transfer is shared with mpm_solid, whose collocated grid takes every scheme and kernel; the liquid's MAC
   transfers are APIC, FLIP or PIC with the quadratic B-spline. */
static DrStatus check_liquid_transfer(Parser *p, const DrElement *e)
{
    const DrComponent *tr = dr_element_component(e, "Transfer");
    const char *scheme = value_at(tr, "scheme")->str, *kernel = value_at(tr, "kernel")->str;
    bool bad_scheme = strcmp(scheme, "rpic") == 0, bad_kernel = strcmp(kernel, "quadratic") != 0;
    if (!bad_scheme && !bad_kernel) return DR_OK;
    push_key(p, "components");
    push_key(p, "Transfer");
    push_key(p, bad_scheme ? "scheme" : "kernel");
    if (bad_scheme)
        return fail(p, "%s.Transfer.scheme = 'rpic' is for mpm_solid elements; a liquid takes apic, flip or pic", e->name);
    return fail(p, "%s.Transfer.kernel = '%s' is for mpm_solid elements; the liquid's MAC grid uses the quadratic "
                   "B-spline: remove the field or write \"quadratic\"", e->name, kernel);
}

/* Every hair element's Collider is its strands' contact with colliders; the liquid's velocity condition at
   a collider surface is not one of its parameters. */
static DrStatus check_hair_collider(Parser *p, const DrElement *e)
{
    const DrComponent *col = dr_element_component(e, "Collider");
    if (!value_at(col, "boundary")->set) return DR_OK;
    push_key(p, "components");
    push_key(p, "Collider");
    push_key(p, "boundary");
    return fail_key(p, "%s.Collider.boundary is the velocity condition of liquid at a collider surface and does not "
                       "apply to hair; remove it (a hair element's Collider takes friction and thickness)", e->name);
}

/* On a bem_solid, Collider is how the body's vertices meet colliders and other bodies; the liquid's velocity condition
   is not one of its parameters. body_contact is between bem_solid bodies and means nothing on other elements. */
static DrStatus check_collider_fields(Parser *p, const DrElement *e)
{
    bool has = false;
    for (int i = 0; i < e->spec->component_count; i++) has |= strcmp(e->spec->components[i], "Collider") == 0;
    if (!has) return DR_OK;
    const DrComponent *col = dr_element_component(e, "Collider");
    bool bem = e->kind == DR_ELEMENT_BEM_SOLID;
    if (bem && value_at(col, "boundary")->set) {
        push_key(p, "components");
        push_key(p, "Collider");
        push_key(p, "boundary");
        return fail_key(p, "%s.Collider.boundary is the velocity condition of liquid at a collider surface and does "
                           "not apply to a bem_solid; remove it (a bem_solid's Collider takes friction, thickness and "
                           "body_contact)", e->name);
    }
    if (!bem && value_at(col, "body_contact")->set) {
        push_key(p, "components");
        push_key(p, "Collider");
        push_key(p, "body_contact");
        return fail_key(p, "%s.Collider.body_contact is contact between bem_solid bodies and does not apply to a %s "
                           "element; remove it", e->name, e->type);
    }
    return DR_OK;
}

/* A bem_solid's matrices belong to its mesh as the file holds it (precompute keys them by the file's bytes), so its
   Transform may rotate and translate the body but not scale it. */
static DrStatus check_bem_transform(Parser *p, const DrElement *e)
{
    double scale = value_at(dr_element_component(e, "Transform"), "scale")->num[0];
    if (scale == 1.0) return DR_OK;
    char v[32];
    dr_scene_fmt_num_(scale, v, sizeof v);
    push_key(p, "components");
    push_key(p, "Transform");
    push_key(p, "scale");
    return fail(p, "%s.Transform.scale = %s: a bem_solid's boundary-element matrices are built for the mesh as it is in "
                   "its file, so the body cannot be scaled here; scale the OBJ instead (precompute then builds matrices "
                   "for it) and remove scale", e->name, v);
}

/* The shortest %.Ng (N = 15..17) that reads back as v exactly: 1/240 prints as 0.004166666666666667. */
static void fmt_exact(double v, char *buf, size_t size)
{
    for (int digits = 15; digits <= 17; digits++) {
        snprintf(buf, size, "%.*g", digits, v);
        if (strtod(buf, NULL) == v) return;
    }
}

/* A bem_solid advances by whole steps of BemSolver.time_step, so a frame must hold a whole number of them
   (relative 1e-6: 1/240 s in a 24 fps frame is 10 steps up to rounding). Needs shot.fps: checked once the whole
   file is read, since the sections may follow the elements. */
static DrStatus check_bem_time_steps(Parser *p)
{
    const DrScene *s = p->s;
    double fps = value_at(&s->sections[dr_scene_section_index_("shot")], "fps")->num[0];
    double frame = 1.0 / fps;
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind != DR_ELEMENT_BEM_SOLID) continue;
        double dt = value_at(dr_element_component(e, "BemSolver"), "time_step")->num[0];
        double ratio = frame / dt, n = floor(ratio + 0.5);
        if (n >= 1.0 && fabs(ratio - n) <= 1e-6 * ratio) continue;
        if (n < 1.0) n = 1.0;
        char a[32], b[32], c[32], d[32], steps[32];
        dr_scene_fmt_num_(dt, a, sizeof a);
        dr_scene_fmt_num_(fps, b, sizeof b);
        dr_scene_fmt_num_(fps * n, c, sizeof c);
        fmt_exact(1.0 / (fps * n), d, sizeof d);
        snprintf(steps, sizeof steps, "%.6g", ratio);
        p->depth = 0;
        push_key(p, "elements");
        push_index(p, i);
        push_key(p, "components");
        push_key(p, "BemSolver");
        push_key(p, "time_step");
        return fail(p, "%s.BemSolver.time_step = %s s does not divide the frame: 1/fps = 1/%s s is %s steps, and a "
                       "bem_solid advances a whole number of steps per frame; use 1/%s s = %s (%.0f step%s per frame at "
                       "%s fps)", e->name, a, b, steps, c, d, n, n == 1.0 ? "" : "s", b);
    }
    return DR_OK;
}

/* Fields that every element of one type must agree on, because those elements are advanced together. */
typedef struct Shared {
    const char *component, *field; /* field NULL: every field of the component */
    const char *except;            /* with field NULL: a field left out (NULL: none) */
} Shared;

/* Two values of one field are the same setting (set or defaulted alike, equal numbers, equal strings). */
static bool same_value(const DrValue *a, const DrValue *b)
{
    return a->has == b->has && memcmp(a->num, b->num, sizeof a->num) == 0 &&
           ((!a->str && !b->str) || (a->str && b->str && strcmp(a->str, b->str) == 0));
}

static void shared_value_text(const DrFieldSpec *fs, const DrValue *v, char *buf, size_t size)
{
    if (fs->kind == DR_FIELD_ENUM) snprintf(buf, size, "'%s'", v->str);
    else if (fs->kind == DR_FIELD_BOOL) snprintf(buf, size, "%s", v->num[0] != 0.0 ? "true" : "false");
    else dr_scene_fmt_num_(v->num[0], buf, size);
}

/* Element e's shared fields against first's: the first that differs is an error naming both and ending with `why`. */
static DrStatus check_pair(Parser *p, const DrElement *first, const DrElement *e, const Shared *shared, int nshared,
                           const char *why)
{
    for (int k = 0; k < nshared; k++) {
        const DrComponent *a = dr_element_component(first, shared[k].component);
        const DrComponent *b = dr_element_component(e, shared[k].component);
        for (int f = 0; f < a->spec->field_count; f++) {
            const DrFieldSpec *fs = &a->spec->fields[f];
            if (shared[k].field && strcmp(fs->name, shared[k].field) != 0) continue;
            if (shared[k].except && strcmp(fs->name, shared[k].except) == 0) continue;
            const DrValue *va = &a->values[f], *vb = &b->values[f];
            if (same_value(va, vb)) continue;
            char xa[64], xb[64];
            shared_value_text(fs, va, xa, sizeof xa);
            shared_value_text(fs, vb, xb, sizeof xb);
            push_index(p, e->index);
            push_key(p, "components");
            push_key(p, a->spec->name);
            push_key(p, fs->name);
            return fail(p, "%s.%s.%s = %s differs from %s.%s.%s = %s; %s, so give both elements the same %s.%s",
                        e->name, a->spec->name, fs->name, xb, first->name, a->spec->name, fs->name, xa, why,
                        a->spec->name, fs->name);
        }
    }
    return DR_OK;
}

/* The first element of `type` whose shared fields differ from the first one's is an error naming both and
   ending with `why`. */
static DrStatus check_shared(Parser *p, const char *type, const Shared *shared, int nshared, const char *why)
{
    const DrScene *s = p->s;
    const DrElement *first = NULL;
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (strcmp(e->type, type) != 0) continue;
        if (!first) first = e;
        else DR_TRY(check_pair(p, first, e, shared, nshared, why));
    }
    return DR_OK;
}

/* Locates an error at elements[e].components.Joint.<field>. */
static void at_joint_field(Parser *p, const DrElement *e, const char *field)
{
    push_index(p, e->index);
    push_key(p, "components");
    push_key(p, "Joint");
    push_key(p, field);
}

/* Locates an error at elements[e].components.<comp>.<field> (field NULL: the component; index >= 0: its entry). */
static void at_field(Parser *p, const DrElement *e, const char *comp, const char *field, int index)
{
    push_index(p, e->index);
    push_key(p, "components");
    push_key(p, comp);
    if (field) push_key(p, field);
    if (index >= 0) push_index(p, index);
}

/* The error for member k of element e's component comp that is not a hair or cloth element: b the element of that
   name (NULL: none), why what the members must be, cand (nc names) the hair and cloth elements to suggest from. */
static DrStatus bad_member(Parser *p, const DrElement *e, const char *comp, int k, const char *name, const DrElement *b,
                           const char *why, const char *const *cand, int nc)
{
    char sug[256], list[512];
    suggestion(name, cand, nc, sug, sizeof sug);
    dr_scene_join_names_(cand, nc, list, sizeof list);
    at_field(p, e, comp, "members", k);
    if (b)
        return fail(p, "%s.%s.members[%d] = '%s' is a %s element; %s%s Hair and cloth elements: %s", e->name, comp, k,
                    name, b->type, why, sug, nc ? list : "none");
    return fail(p, "%s.%s.members[%d] = '%s': no hair or cloth element has this name%s Hair and cloth elements: %s",
                e->name, comp, k, name, sug, nc ? list : "none");
}

/* Collision elements: each member is a hair element (method edge_edge) or a
   cloth element (vertex_face); a pair of members (or a member with itself) takes one response, so no two collision
   elements of one method cover the same pair; vertex_face meets a panel with itself only (panels are solved one by
   one); and once a scene has a collision element, the shorthand they replace (a hair's CollisionGroup and
   CollisionResponse, a cloth's ClothMaterial.self_contact) is not written beside them. Runs once every element is
   read. */
static DrStatus check_collisions(Parser *p)
{
    const DrScene *s = p->s;
    int ncol = 0, nhair = 0;
    for (int i = 0; i < s->element_count; i++) {
        ncol += s->elements[i].kind == DR_ELEMENT_COLLISION;
        nhair += s->elements[i].kind == DR_ELEMENT_HAIR;
    }
    if (ncol == 0) return DR_OK;
    const char **cand = dr_arena_alloc(s->arena, (size_t)s->element_count + 1, sizeof *cand);
    if (!cand) return nomem(p);
    int nc = 0;
    for (int i = 0; i < s->element_count; i++)
        if (s->elements[i].kind == DR_ELEMENT_HAIR || s->elements[i].kind == DR_ELEMENT_CLOTH)
            cand[nc++] = s->elements[i].name;
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind == DR_ELEMENT_HAIR) {
            const char *comp[2] = {"CollisionGroup", "CollisionResponse"};
            for (int k = 0; k < 2; k++) {
                if (!dr_component_present(dr_element_component(e, comp[k]))) continue;
                at_field(p, e, comp[k], NULL, -1);
                return fail(p, "%s.%s is the shorthand of collision elements, and this scene has collision elements: "
                               "they alone say which strands touch. Remove %s.%s and list %s in a collision element's "
                               "Collision.members (its CollisionResponse gives the response)",
                            e->name, comp[k], e->name, comp[k], e->name);
            }
        }
        const DrComponent *cm = e->kind == DR_ELEMENT_CLOTH ? dr_element_component(e, "ClothMaterial") : NULL;
        if (cm && dr_component_is_set(cm, "self_contact")) { /* written: it must say what the collision elements say */
            const DrElement *ce = dr_scene_collision(s, e->name, e->name, "vertex_face");
            bool on = value_at(cm, "self_contact")->num[0] != 0.0;
            if (on != (ce != NULL)) {
                at_field(p, e, "ClothMaterial", "self_contact", -1);
                if (on)
                    return fail(p, "%s.ClothMaterial.self_contact = true, and no collision element meets %s with itself: "
                                   "in a scene with collision elements they alone say which panels touch themselves. "
                                   "List %s in a collision element with method \"vertex_face\", or remove self_contact",
                                e->name, e->name, e->name);
                return fail(p, "%s.ClothMaterial.self_contact = false, and collision element %s meets %s with itself; "
                               "remove one of them", e->name, ce->name, e->name);
            }
        }
    }
    if (nhair > 31) {
        for (int i = 0; i < s->element_count; i++)
            if (s->elements[i].kind == DR_ELEMENT_COLLISION) {
                at_field(p, &s->elements[i], "Collision", "members", -1);
                break;
            }
        return fail(p, "this scene has %d hair elements; collision elements handle at most 31 (merge grooms into fewer "
                       "hair elements)", nhair);
    }
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind != DR_ELEMENT_COLLISION) continue;
        const DrComponent *c = dr_element_component(e, "Collision");
        const char *const *m = NULL;
        int n = dr_component_names(c, "members", &m);
        const char *method = value_at(c, "method")->str, *pairs = value_at(c, "pairs")->str;
        bool edge = strcmp(method, "edge_edge") == 0;
        for (int k = 0; k < n; k++) {
            const DrElement *b = dr_scene_find(s, m[k]);
            if (b && (b->kind == DR_ELEMENT_HAIR || b->kind == DR_ELEMENT_CLOTH)) {
                if (!edge || b->kind == DR_ELEMENT_HAIR) continue;
                at_field(p, e, "Collision", "members", k);
                return fail(p, "%s.Collision.members[%d] = '%s' is a cloth element, and method \"edge_edge\" meets "
                               "strand segments: a cloth panel meets itself, and hair, with method \"vertex_face\"",
                            e->name, k, m[k]);
            }
            return bad_member(p, e, "Collision", k, m[k], b, "members are hair or cloth elements (colliders meet every "
                              "one of them)", cand, nc);
        }
        if (strcmp(pairs, "between") == 0 && n < 2) {
            at_field(p, e, "Collision", "pairs", -1);
            return fail(p, "%s.Collision.pairs = \"between\" meets different members only, and it has one member: list "
                           "at least two, or use pairs \"self\"", e->name);
        }
        int ncloth = 0, nhair_m = 0;
        for (int k = 0; k < n; k++) {
            const DrElement *b = dr_scene_find(s, m[k]);
            ncloth += b->kind == DR_ELEMENT_CLOTH;
            nhair_m += b->kind == DR_ELEMENT_HAIR;
        }
        if (!edge && ncloth > 1 && strcmp(pairs, "self") != 0) {
            at_field(p, e, "Collision", "pairs", -1);
            return fail(p, "%s.Collision: contact between two cloth panels is not built yet (each panel is solved on "
                           "its own); with method \"vertex_face\" and several cloth members give pairs \"self\" (each "
                           "panel with itself), and pair each panel with the hair in a collision element of its own",
                        e->name);
        }
        if (!edge && nhair_m > 0 && (ncloth == 0 || strcmp(pairs, "self") == 0)) {
            at_field(p, e, "Collision", ncloth == 0 ? "members" : "pairs", -1);
            return fail(p, "%s.Collision: with method \"vertex_face\" a hair member meets the cloth members' triangles "
                           "(strands meet strands with \"edge_edge\"), and %s; list a cloth element beside the hair "
                           "with pairs \"all\" or \"between\"", e->name,
                        ncloth == 0 ? "it lists no cloth element" : "pairs \"self\" pairs no hair with a panel");
        }
        if (!edge && nhair_m > 0) { /* hair against cloth is stepped outside the coupled loop only */
            bool fluid = false, coupled = false;
            for (int q = 0; q < s->element_count; q++)
                fluid = fluid || s->elements[q].kind == DR_ELEMENT_LIQUID || s->elements[q].kind == DR_ELEMENT_AIR;
            for (int k = 0; k < n; k++) {
                const DrElement *b = dr_scene_find(s, m[k]);
                coupled = coupled || dr_component_present(dr_element_component(b, b->kind == DR_ELEMENT_HAIR ? "Drag"
                                                                                                          : "ClothDrag"));
            }
            for (int k = 0; k < n; k++) { /* the hair's step holds the panel's pins where they started */
                const DrElement *b = dr_scene_find(s, m[k]);
                if (b->kind != DR_ELEMENT_CLOTH) continue;
                bool moving = dr_component_present(dr_element_component(b, "Motion")) &&
                              dr_component_present(dr_element_component(b, "FixedVertices"));
                for (int q = 0; !moving && q < s->element_count; q++) {
                    const DrElement *a = &s->elements[q];
                    if (a->kind != DR_ELEMENT_ATTACHMENT) continue;
                    const DrComponent *ac = dr_element_component(a, "Attachment");
                    if (strcmp(value_at(ac, "method")->str, "rigid") != 0) continue;
                    const char *const *am = NULL;
                    int an = dr_component_names(ac, "members", &am);
                    for (int r = 0; r < an; r++) moving = moving || strcmp(am[r], b->name) == 0;
                }
                if (moving) {
                    at_field(p, e, "Collision", "members", k);
                    return fail(p, "%s.Collision pairs hair with cloth '%s', whose pins move (its Motion, or a rigid "
                                   "attachment): a panel that meets hair is stepped with the hair, and its pins stay "
                                   "where they start there (not built yet); hold %s still, or leave it out of %s",
                                e->name, b->name, b->name, e->name);
                }
            }
            if (fluid && coupled) {
                at_field(p, e, "Collision", "members", -1);
                return fail(p, "%s.Collision pairs hair with cloth, and one of them is coupled with the fluid (Drag or "
                               "ClothDrag): contact between hair and cloth is not built in the coupled loop yet; remove "
                               "the hair or the cloth from %s, or their Drag and ClothDrag", e->name, e->name);
            }
        }
        /* a pair covered by an earlier collision element of the same method */
        for (int j = 0; j < i; j++) {
            const DrElement *o = &s->elements[j];
            if (o->kind != DR_ELEMENT_COLLISION) continue;
            const DrComponent *oc = dr_element_component(o, "Collision");
            if (strcmp(value_at(oc, "method")->str, method) != 0) continue;
            const char *const *om = NULL;
            int on = dr_component_names(oc, "members", &om);
            const char *opairs = value_at(oc, "pairs")->str;
            for (int a = 0; a < n; a++)
                for (int b = a; b < n; b++) {
                    bool self = a == b;
                    if (self ? strcmp(pairs, "between") == 0 : strcmp(pairs, "self") == 0) continue;
                    if (!edge && dr_scene_find(s, m[a])->kind == DR_ELEMENT_HAIR &&
                        dr_scene_find(s, m[b])->kind == DR_ELEMENT_HAIR)
                        continue; /* not a contact of vertex_face */
                    int oa = -1, ob = -1;
                    for (int k = 0; k < on; k++) {
                        if (strcmp(om[k], m[a]) == 0) oa = k;
                        if (strcmp(om[k], m[b]) == 0) ob = k;
                    }
                    if (oa < 0 || ob < 0) continue;
                    if (self ? strcmp(opairs, "between") == 0 : strcmp(opairs, "self") == 0) continue;
                    at_field(p, e, "Collision", "members", b);
                    if (self)
                        return fail(p, "%s and %s both meet %s with itself (method \"%s\"); a pair takes one response: "
                                       "leave it in one of them (pairs \"between\" leaves each member's own contacts out)",
                                    o->name, e->name, m[a], method);
                    return fail(p, "%s and %s both meet %s with %s (method \"%s\"); a pair takes one response: leave it "
                                   "in one of them", o->name, e->name, m[a], m[b], method);
                }
        }
    }
    return DR_OK;
}

/* Attachment elements: members are cloth or hair elements; a cloth member's vertices are those in the box; a hair
   member is held by its roots, which only a rigid attachment can carry (in place of the hair's own Motion, and by one
   attachment); slide needs a curve of 2 points or more, rigid a target that is a collider or a bem_solid; and a panel
   slides on one curve (its SlideVertices or one slide attachment). Runs once every element is read. */
static DrStatus check_attachments(Parser *p)
{
    const DrScene *s = p->s;
    const char **cand = NULL, **targets = NULL;
    int nc = 0, nt = 0;
    cand = dr_arena_alloc(s->arena, (size_t)s->element_count + 1, sizeof *cand);
    targets = dr_arena_alloc(s->arena, (size_t)s->element_count + 1, sizeof *targets);
    if (!cand || !targets) return nomem(p);
    for (int i = 0; i < s->element_count; i++) {
        DrElementKind k = s->elements[i].kind;
        if (k == DR_ELEMENT_HAIR || k == DR_ELEMENT_CLOTH) cand[nc++] = s->elements[i].name;
        if (k == DR_ELEMENT_COLLIDER || k == DR_ELEMENT_BEM_SOLID) targets[nt++] = s->elements[i].name;
    }
    char tlist[512];
    dr_scene_join_names_(targets, nt, tlist, sizeof tlist);
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind != DR_ELEMENT_ATTACHMENT) continue;
        const DrComponent *c = dr_element_component(e, "Attachment");
        const char *const *m = NULL;
        int n = dr_component_names(c, "members", &m);
        const char *method = value_at(c, "method")->str;
        bool rigid = strcmp(method, "rigid") == 0, slide = strcmp(method, "slide") == 0;
        bool any_cloth = false;
        for (int k = 0; k < n; k++) {
            const DrElement *b = dr_scene_find(s, m[k]);
            if (!b || (b->kind != DR_ELEMENT_HAIR && b->kind != DR_ELEMENT_CLOTH))
                return bad_member(p, e, "Attachment", k, m[k], b, "an attachment holds hair or cloth elements", cand, nc);
            if (b->kind == DR_ELEMENT_CLOTH) {
                any_cloth = true;
                continue;
            }
            if (!rigid) {
                at_field(p, e, "Attachment", "method", -1);
                return fail(p, "%s.Attachment.members[%d] = '%s' is a hair element, held by its roots (Groom.roots): "
                               "method \"%s\" holds a cloth's vertices; use method \"rigid\" with a target to carry "
                               "the roots with a collider or a body", e->name, k, m[k], method);
            }
            if (strcmp(value_at(dr_element_component(b, "Groom"), "roots")->str, "free") == 0) {
                at_field(p, e, "Attachment", "members", k);
                return fail(p, "%s.Attachment carries the roots of '%s', and %s.Groom.roots is \"free\" (nothing holds "
                               "them); give %s.Groom.roots \"clamped\" or \"pinned\", or leave %s out of %s",
                            e->name, m[k], m[k], m[k], m[k], e->name);
            }
            if (dr_component_present(dr_element_component(b, "Motion"))) {
                at_field(p, e, "Attachment", "members", k);
                return fail(p, "%s.Attachment carries the roots of '%s' with its target, and %s.Motion moves them too; "
                               "remove %s.Motion (the target's motion moves the roots) or leave %s out of %s",
                            e->name, m[k], m[k], m[k], m[k], e->name);
            }
            for (int j = 0; j < i; j++) { /* one rigid attachment per hair element */
                const DrElement *o = &s->elements[j];
                if (o->kind != DR_ELEMENT_ATTACHMENT) continue;
                const char *const *om = NULL;
                int on = dr_component_names(dr_element_component(o, "Attachment"), "members", &om);
                for (int q = 0; q < on; q++)
                    if (strcmp(om[q], m[k]) == 0) {
                        at_field(p, e, "Attachment", "members", k);
                        return fail(p, "%s and %s both carry the roots of '%s'; a hair element's roots follow one "
                                       "target: leave it in one of them", o->name, e->name, m[k]);
                    }
            }
        }
        bool has_box = value_at(c, "box")->set, has_curve = value_at(c, "curve")->nrows > 0 || value_at(c, "curve")->set;
        bool has_target = value_at(c, "target")->set;
        if (any_cloth && !has_box) {
            at_field(p, e, "Attachment", NULL, -1);
            return fail(p, "%s.Attachment.box is required with a cloth member: the member's vertices inside it (in the "
                           "placed rest pose) are held; add \"box\": [[x0, y0, z0], [x1, y1, z1]]", e->name);
        }
        if (!any_cloth && has_box) {
            at_field(p, e, "Attachment", "box", -1);
            return fail(p, "%s.Attachment.box selects a cloth member's vertices, and every member is a hair element "
                           "(held by its roots); remove box", e->name);
        }
        if (slide && value_at(c, "curve")->nrows < 2) {
            at_field(p, e, "Attachment", has_curve ? "curve" : NULL, -1);
            return fail(p, "%s.Attachment.curve has %d point(s); method \"slide\" needs the curve as 2 points or more "
                           "[[x, y, z], [x, y, z], ...]", e->name, value_at(c, "curve")->nrows);
        }
        if (!slide && has_curve) {
            at_field(p, e, "Attachment", "curve", -1);
            return fail(p, "%s.Attachment.curve applies to method \"slide\", not \"%s\"; remove curve", e->name,
                        method);
        }
        if (rigid && !has_target) {
            at_field(p, e, "Attachment", NULL, -1);
            return fail(p, "%s.Attachment.target is required with method \"rigid\": the collider or bem_solid element "
                           "that carries the vertices; add \"target\": \"name\" (colliders and bem_solid elements: %s)",
                        e->name, nt ? tlist : "none");
        }
        if (!rigid && has_target) {
            at_field(p, e, "Attachment", "target", -1);
            return fail(p, "%s.Attachment.target applies to method \"rigid\", not \"%s\"; remove target", e->name,
                        method);
        }
        if (rigid) {
            const char *tn = value_at(c, "target")->str;
            const DrElement *t = dr_scene_find(s, tn);
            if (!t || (t->kind != DR_ELEMENT_COLLIDER && t->kind != DR_ELEMENT_BEM_SOLID)) {
                char sug[256];
                suggestion(tn, targets, nt, sug, sizeof sug);
                at_field(p, e, "Attachment", "target", -1);
                if (t)
                    return fail(p, "%s.Attachment.target = '%s' is a %s element; a rigid attachment is carried by a "
                                   "collider or a bem_solid%s Colliders and bem_solid elements: %s",
                                e->name, tn, t->type, sug, nt ? tlist : "none");
                return fail(p, "%s.Attachment.target = '%s': no collider or bem_solid element has this name%s "
                               "Colliders and bem_solid elements: %s", e->name, tn, sug, nt ? tlist : "none");
            }
        }
    }
    /* a panel slides on one curve */
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *b = &s->elements[i];
        if (b->kind != DR_ELEMENT_CLOTH) continue;
        const DrElement *first = NULL;
        bool own = dr_component_present(dr_element_component(b, "SlideVertices"));
        for (int j = 0; j < s->element_count; j++) {
            const DrElement *e = &s->elements[j];
            if (e->kind != DR_ELEMENT_ATTACHMENT) continue;
            const DrComponent *c = dr_element_component(e, "Attachment");
            if (strcmp(value_at(c, "method")->str, "slide") != 0) continue;
            const char *const *m = NULL;
            int n = dr_component_names(c, "members", &m);
            bool listed = false;
            for (int k = 0; k < n; k++) listed = listed || strcmp(m[k], b->name) == 0;
            if (!listed) continue;
            if (own || first) {
                at_field(p, e, "Attachment", "method", -1);
                return fail(p, "%s slides %s on a curve, and %s already does (a panel slides on one curve); give both "
                               "boxes one slide attachment, or one curve", e->name, b->name,
                            own ? "its SlideVertices" : first->name);
            }
            first = e;
        }
    }
    return DR_OK;
}

/* A bem_joint names two different bem_solid elements that are stepped together (the same BemSolver.time_step: bodies
   of different steps never meet), and a point when its mode is point. Runs once every element is read, since a joint
   may come before its bodies. */
static DrStatus check_bem_joints(Parser *p)
{
    const DrScene *s = p->s;
    const char **bodies = NULL;
    int nb = 0;
    for (int i = 0; i < s->element_count; i++) nb += strcmp(s->elements[i].type, "bem_solid") == 0;
    bodies = dr_arena_alloc(s->arena, (size_t)nb + 1, sizeof *bodies);
    if (!bodies) return nomem(p);
    nb = 0;
    for (int i = 0; i < s->element_count; i++)
        if (strcmp(s->elements[i].type, "bem_solid") == 0) bodies[nb++] = s->elements[i].name;
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind != DR_ELEMENT_BEM_JOINT) continue;
        const DrComponent *j = dr_element_component(e, "Joint");
        const char *field[2] = {"body_a", "body_b"};
        const DrElement *b[2];
        for (int k = 0; k < 2; k++) {
            const char *name = value_at(j, field[k])->str;
            b[k] = dr_scene_find(s, name);
            if (b[k] && strcmp(b[k]->type, "bem_solid") == 0) continue;
            char sug[256], list[512];
            suggestion(name, bodies, nb, sug, sizeof sug);
            dr_scene_join_names_(bodies, nb, list, sizeof list);
            at_joint_field(p, e, field[k]);
            if (b[k])
                return fail(p, "%s.Joint.%s = '%s' is a %s element, not a bem_solid%s bem_solid elements: %s", e->name,
                            field[k], name, b[k]->type, sug, nb ? list : "none");
            return fail(p, "%s.Joint.%s = '%s': no bem_solid element has this name%s bem_solid elements: %s", e->name,
                        field[k], name, sug, nb ? list : "none");
        }
        if (b[0] == b[1]) {
            at_joint_field(p, e, "body_b");
            return fail(p, "%s.Joint.body_b = '%s' is body_a as well; a joint holds two different bodies together",
                        e->name, b[1]->name);
        }
        double dta = value_at(dr_element_component(b[0], "BemSolver"), "time_step")->num[0];
        double dtb = value_at(dr_element_component(b[1], "BemSolver"), "time_step")->num[0];
        if (dta != dtb) {
            char xa[32], xb[32];
            dr_scene_fmt_num_(dta, xa, sizeof xa);
            dr_scene_fmt_num_(dtb, xb, sizeof xb);
            at_joint_field(p, e, "body_b");
            return fail(p, "%s.Joint joins %s and %s, but %s.BemSolver.time_step = %s s differs from "
                           "%s.BemSolver.time_step = %s s; bodies are stepped together only with the same time step, so "
                           "give both the same BemSolver.time_step", e->name, b[0]->name, b[1]->name, b[1]->name, xb,
                        b[0]->name, xa);
        }
        if (strcmp(value_at(j, "mode")->str, "point") == 0 && !value_at(j, "point")->set) {
            push_index(p, e->index);
            push_key(p, "components");
            push_key(p, "Joint");
            return fail(p, "%s.Joint.point is required with mode \"point\": add \"point\": [x, y, z] (m, in the placed "
                           "rest pose), or use mode \"coincident\"", e->name);
        }
    }
    return DR_OK;
}

/* Wet hair: a hair element is wet when it has a Wetting component; Film, Cohesion, CrossFlow, Capture and Dripping
   need it. Every wet hair element's strands share one film model, one pair of cohesion tables, one bridge model
   (bridges join strands of different elements) and one exchange with the liquid, so their Wetting, Cohesion,
   CrossFlow, Capture, Dripping and Film (but initial_ratio) must agree; and a Wetting.liquid names a liquid element. */
static DrStatus check_wet_hair(Parser *p)
{
    const DrScene *s = p->s;
    static const char *const needs[] = {"Film", "Cohesion", "CrossFlow", "Capture", "Dripping"};
    const DrElement *first = NULL;
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind != DR_ELEMENT_HAIR) continue;
        const DrComponent *w = dr_element_component(e, "Wetting");
        for (int k = 0; k < 5; k++) {
            if (w->present || !dr_element_component(e, needs[k])->present) continue;
            push_index(p, e->index);
            push_key(p, "components");
            push_key(p, needs[k]);
            return fail(p, "%s.%s needs a Wetting component (the liquid on the strands): add \"Wetting\": {} for "
                           "water, or remove %s", e->name, needs[k], needs[k]);
        }
        if (!w->present) continue;
        const DrValue *lq = value_at(w, "liquid");
        if (lq->set) {
            const DrElement *l = dr_scene_find(s, lq->str);
            if (!l || l->kind != DR_ELEMENT_LIQUID) {
                push_index(p, e->index);
                push_key(p, "components");
                push_key(p, "Wetting");
                push_key(p, "liquid");
                return fail(p, "%s.Wetting.liquid = '%s': %s; name a liquid element, or remove the field and set "
                               "density and viscosity", e->name, lq->str,
                            l ? "that element is not a liquid" : "no element has this name");
            }
        }
        if (!first) {
            first = e;
            continue;
        }
        static const Shared shared[] = {
            {"Wetting", NULL, NULL}, {"Cohesion", NULL, NULL}, {"CrossFlow", NULL, NULL},
            {"Capture", NULL, NULL}, {"Dripping", NULL, NULL}, {"Film", NULL, "initial_ratio"}};
        DR_TRY(check_pair(p, first, e, shared, 6,
                          "the strands of every wet hair element share one film, cohesion, cross-flow, capture and "
                          "dripping model"));
    }
    return DR_OK;
}

/* At most one air element, and none beside a liquid: the two fluids do not share a grid yet. */
static DrStatus check_air(Parser *p)
{
    const DrScene *s = p->s;
    const DrElement *air = NULL, *liquid = NULL;
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind == DR_ELEMENT_LIQUID && !liquid) liquid = e;
        if (e->kind != DR_ELEMENT_AIR) continue;
        if (air) {
            push_index(p, e->index);
            push_key(p, "type");
            return fail(p, "air elements '%s' and '%s': a scene holds at most one air element; merge them into one "
                           "(one AirDomain box, one Wind) or remove one", air->name, e->name);
        }
        air = e;
    }
    if (air && liquid) {
        const DrElement *later = air->index > liquid->index ? air : liquid;
        push_index(p, later->index);
        push_key(p, "type");
        return fail(p, "air element '%s' and liquid element '%s' in one scene: air together with a liquid is not "
                       "supported yet; bake them as separate scenes, or remove one", air->name, liquid->name);
    }
    return DR_OK;
}

/* A hair element's Drag or a cloth element's ClothDrag couples it with the scene's fluid (its liquid or its air
   element); without one there is nothing to drag against, and the component would be silently ignored. */
static DrStatus check_drag_fluid(Parser *p)
{
    const DrScene *s = p->s;
    for (int i = 0; i < s->element_count; i++)
        if (s->elements[i].kind == DR_ELEMENT_LIQUID || s->elements[i].kind == DR_ELEMENT_AIR) return DR_OK;
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        bool hair = e->kind == DR_ELEMENT_HAIR && dr_element_component(e, "Drag")->present;
        bool cloth = e->kind == DR_ELEMENT_CLOTH && dr_element_component(e, "ClothDrag")->present;
        if (!hair && !cloth) continue;
        const char *comp = hair ? "Drag" : "ClothDrag";
        push_index(p, e->index);
        push_key(p, "components");
        push_key(p, comp);
        return fail(p, "%s.%s couples %s element '%s' with the scene's fluid, but the scene has neither a liquid nor an "
                       "air element; add a liquid or an air element, or remove %s",
                    e->name, comp, hair ? "hair" : "cloth", e->name, comp);
    }
    return DR_OK;
}

/* Every mpm_solid of a scene lives on one grid advanced by one step, so what defines the grid and the step
   must agree between them: the cell size and wall condition (Domain) and every Transfer and Integrator
   field. The grid box itself is the union of the Domain boxes (world.c). Every hair element is one object
   of one Lagrangian system (contact couples them), solved by one solve: HairSolver must agree. */
static DrStatus check_cross_element(Parser *p)
{
    static const Shared mpm[] = {
        {"Domain", "voxel_size", NULL}, {"Domain", "wall_boundary", NULL}, {"Transfer", NULL, NULL},
        {"Integrator", NULL, NULL}};
    static const Shared hair[] = {{"HairSolver", NULL, NULL}};
    static const Shared cloth[] = {
        {"ClothSolver", "substeps", NULL}, {"ClothSolver", "cfl", NULL}, {"ClothSolver", "max_substeps", NULL}};
    DR_TRY(check_shared(p, "mpm_solid", mpm, (int)(sizeof mpm / sizeof mpm[0]),
                        "every mpm_solid of a scene shares one grid and one time step"));
    DR_TRY(check_bem_joints(p));
    DR_TRY(check_collisions(p));
    DR_TRY(check_attachments(p));
    DR_TRY(check_wet_hair(p));
    DR_TRY(check_air(p));
    DR_TRY(check_drag_fluid(p));
    DR_TRY(check_shared(p, "cloth", cloth, (int)(sizeof cloth / sizeof cloth[0]),
                        "every cloth element of a scene takes the same steps"));
    return check_shared(p, "hair", hair, 1, "every hair element of a scene is solved in one system");
}

/* Required components that need one of several optional fields: what to write when one is missing. */
static const struct {
    const char *component, *example;
} one_of_examples[] = {
    {"MpmShape", "\"box\": [[x0, y0, z0], [x1, y1, z1]]"},
    {"Groom", "\"scalp\": \"path/to/scalp.obj\""},
};

static DrStatus parse_element(Parser *p, const json_t *v, int index)
{
    DrScene *s = p->s;
    DrElement *e = &s->elements[index];
    e->index = index;
    char label[WHERE_MAX];
    snprintf(label, sizeof label, "elements[%d]", index);
    if (!json_is_object(v))
        return fail(p, "%s: expected an element object {\"name\": ..., \"type\": ..., \"components\": {...}}, got %s",
                    label, json_type_name(v));
    static const char *const element_keys[] = {"name", "type", "components"};
    const char *key;
    json_t *kv;
    json_object_foreach((json_t *)v, key, kv) {
        bool known = false;
        for (int i = 0; i < 3; i++) known |= strcmp(key, element_keys[i]) == 0;
        if (known) continue;
        char sug[256];
        suggestion(key, element_keys, 3, sug, sizeof sug);
        push_key(p, key);
        return fail_key(p, "%s: unknown key '%s'%s An element has \"name\", \"type\" and \"components\"", label, key, sug);
    }

    const json_t *name = json_object_get(v, "name");
    if (!name) return fail(p, "%s: missing \"name\"; give every element a unique name such as \"water\"", label);
    push_key(p, "name");
    char w[WHERE_MAX + 8];
    snprintf(w, sizeof w, "%s.name", label);
    DrValue nv = {0};
    DR_TRY(parse_field(p, &element_name_spec, name, w, &nv));
    e->name = nv.str;
    for (int j = 0; j < index; j++)
        if (strcmp(s->elements[j].name, e->name) == 0)
            return fail(p, "elements[%d] and elements[%d] are both named '%s'; element names must be unique", j,
                        index, e->name);
    pop(p);

    const char *types[16];
    for (int i = 0; i < dr_scene_type_count_ && i < 16; i++) types[i] = dr_scene_types_[i].type;
    char type_list[512];
    dr_scene_join_names_(types, dr_scene_type_count_, type_list, sizeof type_list);
    const json_t *type = json_object_get(v, "type");
    if (!type) return fail(p, "element '%s': missing \"type\"; add \"type\": one of %s", e->name, type_list);
    push_key(p, "type");
    if (!json_is_string(type))
        return fail(p, "element '%s'.type: expected a string (one of %s), got %s", e->name, type_list, json_type_name(type));
    e->spec = dr_scene_element_spec(json_string_value(type));
    if (!e->spec) {
        char sug[256];
        suggestion(json_string_value(type), types, dr_scene_type_count_, sug, sizeof sug);
        return fail(p, "element '%s': unknown type '%s'%s Types: %s", e->name, json_string_value(type), sug, type_list);
    }
    e->type = e->spec->type;
    e->kind = e->spec->kind;
    pop(p);

    const DrElementSpec *t = e->spec;
    e->components_ = dr_arena_alloc(s->arena, (size_t)t->component_count, sizeof(DrComponent));
    if (!e->components_) return nomem(p);
    for (int i = 0; i < t->component_count; i++)
        if (init_component(s, dr_scene_component_spec(t->components[i]), &e->components_[i])) return nomem(p);

    char where[WHERE_MAX];
    snprintf(where, sizeof where, "element '%s' (%s)", e->name, e->type);
    char comp_list[1024];
    dr_scene_join_names_(t->components, t->component_count, comp_list, sizeof comp_list);
    const json_t *comps = json_object_get(v, "components");
    if (comps) {
        push_key(p, "components");
        if (!json_is_object(comps))
            return fail(p, "%s: \"components\" must be an object {\"Component\": {...}}, got %s", where,
                        json_type_name(comps));
        json_object_foreach((json_t *)comps, key, kv) {
            push_key(p, key);
            int ci = -1;
            for (int i = 0; i < t->component_count; i++)
                if (strcmp(t->components[i], key) == 0) ci = i;
            if (ci < 0) {
                char sug[256], other[256] = "";
                suggestion(key, t->components, t->component_count, sug, sizeof sug);
                for (int i = 0; i < dr_scene_type_count_ && !other[0]; i++)
                    for (int j = 0; j < dr_scene_types_[i].component_count; j++)
                        if (strcmp(dr_scene_types_[i].components[j], key) == 0)
                            snprintf(other, sizeof other, " ('%s' is a component of %s elements)", key,
                                     dr_scene_types_[i].type);
                return fail_key(p, "%s: unknown component '%s'%s%s Components of %s: %s", where, key, other, sug,
                                t->type, comp_list);
            }
            char cw[WHERE_MAX + 64];
            snprintf(cw, sizeof cw, "%s.%s", e->name, key);
            DR_TRY(parse_component(p, kv, &e->components_[ci], cw, NULL));
            pop(p);
        }
        pop(p);
    }
    for (int i = 0; i < t->required_count; i++) {
        const DrComponent *c = dr_element_component(e, t->required_components[i]);
        if (c->present) continue;
        char need[512] = "";
        size_t used = 0;
        bool example = false;
        for (size_t k = 0; k < sizeof one_of_examples / sizeof one_of_examples[0]; k++)
            if (strcmp(one_of_examples[k].component, c->spec->name) == 0) {
                snprintf(need, sizeof need, "%s", one_of_examples[k].example);
                example = true;
            }
        for (int f = 0; !example && f < c->spec->field_count && used < sizeof need; f++)
            if (c->spec->fields[f].required) {
                char ex[300];
                example_text(&c->spec->fields[f], ex, sizeof ex);
                used += (size_t)snprintf(need + used, sizeof need - used, "%s\"%s\": %s", used ? ", " : "",
                                         c->spec->fields[f].name, ex);
            }
        return fail(p, "%s: missing component '%s' (%s); add \"%s\": {%s} to its components", where, c->spec->name,
                    c->spec->doc, c->spec->name, need);
    }
    if (t->kind == DR_ELEMENT_LIQUID) DR_TRY(check_liquid_transfer(p, e));
    if (t->kind == DR_ELEMENT_HAIR) DR_TRY(check_hair_collider(p, e));
    DR_TRY(check_collider_fields(p, e));
    if (t->kind == DR_ELEMENT_BEM_SOLID) DR_TRY(check_bem_transform(p, e));
    return DR_OK;
}

static DrStatus parse_elements(Parser *p, const json_t *v)
{
    DrScene *s = p->s;
    if (!json_is_array(v))
        return fail(p, "elements: expected an array of element objects, got %s", json_type_name(v));
    size_t n = json_array_size(v);
    if (n > (size_t)INT32_MAX) return fail(p, "elements: too many elements (%zu)", n);
    s->elements = dr_arena_alloc(s->arena, n ? n : 1, sizeof(DrElement));
    if (!s->elements) return nomem(p);
    for (size_t i = 0; i < n; i++) {
        push_index(p, (int)i);
        DR_TRY(parse_element(p, json_array_get(v, i), (int)i));
        pop(p);
        s->element_count = (int)i + 1;
    }
    return check_cross_element(p);
}

/* Every distinct resolved PATH value, sections first, then elements in order. */
static DrStatus collect_assets(Parser *p)
{
    DrScene *s = p->s;
    int cap = 0;
    for (int pass = 0; pass < 2; pass++) {
        if (pass == 1) {
            s->assets = dr_arena_alloc(s->arena, (size_t)cap + 1, sizeof(DrAsset));
            if (!s->assets) return nomem(p);
        }
        for (int e = -1; e < s->element_count; e++) {
            int nc = e < 0 ? dr_scene_section_count_ : s->elements[e].spec->component_count;
            const DrComponent *cs = e < 0 ? s->sections : s->elements[e].components_;
            for (int c = 0; c < nc; c++) {
                for (int f = 0; f < cs[c].spec->field_count; f++) {
                    const DrValue *v = &cs[c].values[f];
                    if (cs[c].spec->fields[f].kind != DR_FIELD_PATH || !v->set) continue;
                    if (pass == 0) { cap++; continue; }
                    bool dup = false;
                    for (int k = 0; k < s->asset_count; k++) dup |= strcmp(s->assets[k].path, v->str) == 0;
                    if (dup) continue;
                    char where[WHERE_MAX];
                    snprintf(where, sizeof where, "%s%s%s.%s", e < 0 ? "" : s->elements[e].name, e < 0 ? "" : ".",
                             cs[c].spec->name, cs[c].spec->fields[f].name);
                    DrAsset *a = &s->assets[s->asset_count++];
                    a->path = v->str;
                    a->element = e;
                    a->where = arena_strdup(s->arena, where);
                    if (!a->where) return nomem(p);
                }
            }
        }
    }
    return DR_OK;
}

static DrStatus parse_root(Parser *p, const json_t *root)
{
    DrScene *s = p->s;
    if (!json_is_object(root))
        return fail(p, "the scene must be a JSON object {\"shot\": {...}, \"elements\": [...], ...}, got %s",
                    json_type_name(root));
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)root, key, v) {
        push_key(p, key);
        int si = strchr(key, '.') ? -1 : dr_scene_section_index_(key);
        if (strcmp(key, "elements") == 0) {
            DR_TRY(parse_elements(p, v));
        } else if (si >= 0) {
            DR_TRY(parse_component(p, v, &s->sections[si], key, s->sections));
        } else {
            const char *names[32];
            int n = 0;
            for (int i = 0; i < dr_scene_section_count_ && n < 31; i++)
                if (!strchr(dr_scene_sections_[i].name, '.')) names[n++] = dr_scene_sections_[i].name;
            names[n++] = "elements";
            char sug[256], list[512];
            suggestion(key, names, n, sug, sizeof sug);
            dr_scene_join_names_(names, n, list, sizeof list);
            return fail_key(p, "unknown top-level key '%s'%s Top-level keys: %s", key, sug, list);
        }
        pop(p);
    }
    DR_TRY(check_bem_time_steps(p));
    return collect_assets(p);
}

/* ---- load / destroy ------------------------------------------------------------------------------------ */

static DrStatus read_text(const char *path, char **out, size_t *len, DrError *err)
{
    *out = NULL;
    FILE *f = fopen(path, "rb");
    if (!f)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot open the scene file (%s); check the path",
                            strerror(errno));
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap);
    DrStatus st = DR_OK;
    while (buf) {
        n += fread(buf + n, 1, cap - n - 1, f);
        if (ferror(f)) {
            st = dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot read the scene file (%s); check the path",
                              strerror(errno));
            break;
        }
        if (feof(f)) break;
        if (cap > SIZE_MAX / 2) { free(buf); buf = NULL; break; }
        char *bigger = realloc(buf, cap * 2);
        if (!bigger) { free(buf); buf = NULL; break; }
        buf = bigger;
        cap *= 2;
    }
    fclose(f);
    if (!buf) return dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "out of memory reading the scene file");
    if (st != DR_OK) { free(buf); return st; }
    buf[n] = '\0';
    *out = buf;
    *len = n;
    return DR_OK;
}

DrStatus dr_scene_load(const char *path, DrScene **out, DrError *err)
{
    assert(path && out);
    *out = NULL;
    dr_scene_check_tables_();
    char *text = NULL;
    size_t len = 0;
    DR_TRY(read_text(path, &text, &len, err));
    json_error_t jerr;
    json_t *root = json_loadb(text, len, JSON_REJECT_DUPLICATES, &jerr);
    if (!root) {
        DrStatus st = dr_error_set(err, DR_ERR_INPUT, path, jerr.line > 0 ? jerr.line : 1,
                                   jerr.column > 0 ? jerr.column : 1, "invalid JSON: %s", jerr.text);
        free(text);
        return st;
    }

    DrScene *s = NULL;
    DrStatus st = dr_calloc(1, sizeof *s, &s, err);
    if (st == DR_OK) st = dr_arena_create(1 << 16, &s->arena, err);
    char *dir = NULL;
    if (st == DR_OK) {
        s->path = arena_strdup(s->arena, path);
        dir = arena_strdup(s->arena, path);
        s->sections = dr_arena_alloc(s->arena, (size_t)dr_scene_section_count_, sizeof(DrComponent));
        if (!s->path || !dir || !s->sections) st = dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "out of memory while loading the scene");
    }
    for (int i = 0; st == DR_OK && i < dr_scene_section_count_; i++)
        if (init_component(s, &dr_scene_sections_[i], &s->sections[i]))
            st = dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "out of memory while loading the scene");
    if (st == DR_OK) {
        char *slash = strrchr(dir, '/');
        if (!slash) dir[0] = '\0';
        else if (slash == dir) dir[1] = '\0'; /* "/scene.json": the root */
        else *slash = '\0';
        Parser p = {.s = s, .text = text, .len = len, .dir = dir, .err = err};
        st = parse_root(&p, root);
    }
    json_decref(root);
    free(text);
    if (st != DR_OK) {
        dr_scene_destroy(&s);
        return st;
    }
    *out = s;
    return DR_OK;
}

void dr_scene_destroy(DrScene **scene)
{
    if (!scene || !*scene) return;
    dr_arena_destroy(&(*scene)->arena);
    free(*scene);
    *scene = NULL;
}

/* ---- accessors ------------------------------------------------------------------------------------------ */

const char *dr_scene_path(const DrScene *s) { return s->path; }
int dr_scene_element_count(const DrScene *s) { return s->element_count; }

const DrElement *dr_scene_element(const DrScene *s, int i)
{
    assert(i >= 0 && i < s->element_count);
    return &s->elements[i];
}

const DrElement *dr_scene_find(const DrScene *s, const char *name)
{
    for (int i = 0; i < s->element_count; i++)
        if (strcmp(s->elements[i].name, name) == 0) return &s->elements[i];
    return NULL;
}

int dr_scene_count_type(const DrScene *s, const char *type)
{
    int n = 0;
    for (int i = 0; i < s->element_count; i++) n += strcmp(s->elements[i].type, type) == 0;
    return n;
}

int dr_scene_count_kind(const DrScene *s, DrElementKind kind)
{
    int n = 0;
    for (int i = 0; i < s->element_count; i++) n += s->elements[i].kind == kind;
    return n;
}

const DrComponent *dr_scene_section(const DrScene *s, const char *name)
{
    int i = dr_scene_section_index_(name);
    assert(i >= 0 && "unknown scene section");
    return &s->sections[i];
}

const DrComponent *dr_element_component(const DrElement *e, const char *name)
{
    for (int i = 0; i < e->spec->component_count; i++)
        if (strcmp(e->spec->components[i], name) == 0) return &e->components_[i];
    assert(!"component not in the element type's table");
    return NULL;
}

bool dr_component_present(const DrComponent *c) { return c->present; }

static const DrValue *getter(const DrComponent *c, const char *field, DrFieldKind kind)
{
    int i = dr_scene_field_index_(c->spec, field);
    assert(i >= 0 && "unknown field");
    assert(c->spec->fields[i].kind == kind && "getter of the wrong kind for this field");
    return &c->values[i];
}

bool dr_component_is_set(const DrComponent *c, const char *field)
{
    int i = dr_scene_field_index_(c->spec, field);
    assert(i >= 0 && "unknown field");
    return c->values[i].set;
}

double dr_component_num(const DrComponent *c, const char *field) { return getter(c, field, DR_FIELD_NUMBER)->num[0]; }
int dr_component_int(const DrComponent *c, const char *field) { return (int)getter(c, field, DR_FIELD_INT)->num[0]; }
bool dr_component_bool(const DrComponent *c, const char *field) { return getter(c, field, DR_FIELD_BOOL)->num[0] != 0.0; }

const char *dr_component_str(const DrComponent *c, const char *field)
{
    int i = dr_scene_field_index_(c->spec, field);
    assert(i >= 0 && "unknown field");
    DrFieldKind k = c->spec->fields[i].kind;
    assert((k == DR_FIELD_ENUM || k == DR_FIELD_NAME || k == DR_FIELD_PATH) && "getter of the wrong kind for this field");
    (void)k;
    return c->values[i].has ? c->values[i].str : NULL;
}

DrVec3 dr_component_vec3(const DrComponent *c, const char *field)
{
    const double *n = getter(c, field, DR_FIELD_VEC3)->num;
    return dr_v3(n[0], n[1], n[2]);
}

void dr_component_int2(const DrComponent *c, const char *field, int out[2])
{
    const double *n = getter(c, field, DR_FIELD_INT2)->num;
    out[0] = (int)n[0];
    out[1] = (int)n[1];
}

void dr_component_box(const DrComponent *c, const char *field, DrVec3 *lo, DrVec3 *hi)
{
    const double *n = getter(c, field, DR_FIELD_BOX)->num;
    *lo = dr_v3(n[0], n[1], n[2]);
    *hi = dr_v3(n[3], n[4], n[5]);
}

int dr_component_table(const DrComponent *c, const char *field, const double **rows)
{
    const DrValue *v = getter(c, field, DR_FIELD_TABLE);
    *rows = v->nrows ? v->rows : NULL;
    return v->nrows;
}

int dr_component_names(const DrComponent *c, const char *field, const char *const **names)
{
    const DrValue *v = getter(c, field, DR_FIELD_NAMES);
    *names = v->set ? v->names : NULL;
    return v->set ? v->nrows : 0;
}

const DrElement *dr_scene_collision(const DrScene *s, const char *a, const char *b, const char *method)
{
    for (int i = 0; i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->kind != DR_ELEMENT_COLLISION) continue;
        const DrComponent *c = dr_element_component(e, "Collision");
        if (strcmp(value_at(c, "method")->str, method) != 0) continue;
        const char *pairs = value_at(c, "pairs")->str;
        bool self = strcmp(a, b) == 0;
        if (self ? strcmp(pairs, "between") == 0 : strcmp(pairs, "self") == 0) continue;
        const char *const *m = NULL;
        int n = dr_component_names(c, "members", &m);
        bool ha = false, hb = false;
        for (int k = 0; k < n; k++) {
            ha = ha || strcmp(m[k], a) == 0;
            hb = hb || strcmp(m[k], b) == 0;
        }
        if (ha && hb) return e;
    }
    return NULL;
}

/* ---- defaults applied ------------------------------------------------------------------------------------ */

/* Components whose absence means "none" rather than "all defaults" (the world and the stages test their
   presence): an absent one applies nothing. */
static const char *const by_presence[] = {"LiquidSource", "Emitter", "KillBox", "Motion", "FixedVertices"};

static bool str_is(const char *a, const char *b) { return a && b && strcmp(a, b) == 0; }

/* Whether field f of component c means anything for element e (NULL for a section). */
static bool field_applies(const DrElement *e, const DrComponent *c, const DrFieldSpec *f)
{
    if (!e) return true;
    const char *comp = c->spec->name, *name = f->name;
    if (str_is(comp, "Collider") && str_is(name, "boundary")) return e->kind == DR_ELEMENT_COLLIDER;
    if (str_is(comp, "Collider") && str_is(name, "body_contact")) return e->kind == DR_ELEMENT_BEM_SOLID;
    if (str_is(comp, "Transfer") && str_is(name, "flip_blend")) return str_is(value_at(c, "scheme")->str, "flip");
    if (str_is(comp, "Groom") && !str_is(name, "scalp") && !str_is(name, "curves") && !str_is(name, "roots")) {
        if (!value_at(c, "scalp")->set) return false;
        if (str_is(name, "curl_pitch")) return value_at(c, "curl_radius")->num[0] > 0.0;
    }
    if (str_is(comp, "Joint") && str_is(name, "tolerance")) return str_is(value_at(c, "mode")->str, "coincident");
    return true;
}

static int component_defaults(const DrElement *e, const DrComponent *c, DrAppliedDefault *out, int max, int n)
{
    if (!c->present)
        for (size_t i = 0; i < sizeof by_presence / sizeof by_presence[0]; i++)
            if (str_is(c->spec->name, by_presence[i])) return n;
    for (int i = 0; i < c->spec->field_count; i++) {
        const DrFieldSpec *f = &c->spec->fields[i];
        if (c->values[i].set || !c->values[i].has || !field_applies(e, c, f)) continue;
        if (n < max) out[n] = (DrAppliedDefault){c->spec->name, f};
        n++;
    }
    return n;
}

int dr_element_applied_defaults(const DrElement *e, DrAppliedDefault *out, int max)
{
    int n = 0;
    for (int i = 0; i < e->spec->component_count; i++) n = component_defaults(e, &e->components_[i], out, max, n);
    return n;
}

int dr_section_applied_defaults(const DrScene *s, const char *section, DrAppliedDefault *out, int max)
{
    return component_defaults(NULL, dr_scene_section(s, section), out, max, 0);
}

void dr_scene_default_json(const DrFieldSpec *f, char *buf, size_t size)
{
    if (f->required || f->no_default || f->kind == DR_FIELD_PATH) {
        snprintf(buf, size, "%s", "");
        return;
    }
    dr_scene_default_text_(f, buf, size);
}

int dr_scene_asset_count(const DrScene *s) { return s->asset_count; }

const char *dr_scene_asset(const DrScene *s, int i)
{
    assert(i >= 0 && i < s->asset_count);
    return s->assets[i].path;
}
