/* Canonical JSON of the parsed scene and the stage cache keys built on it (DESIGN §5). The JSON is
 * written from the parsed values, not re-serialised from the text, so reformatting, key order, 1 vs
 * 1.0 and writing a default explicitly cannot change a key. */
#include "scene_internal.h"

#include <stdlib.h>
#include <string.h>

typedef struct Buf {
    char *p;
    size_t len, cap;
    bool oom;
} Buf;

static void put(Buf *b, const char *s, size_t n)
{
    if (b->oom) return;
    if (b->len + n + 1 > b->cap) {
        size_t cap = b->cap ? b->cap : 256;
        while (cap < b->len + n + 1) {
            if (cap > SIZE_MAX / 2) { b->oom = true; return; }
            cap *= 2;
        }
        char *q = realloc(b->p, cap);
        if (!q) { b->oom = true; return; }
        b->p = q;
        b->cap = cap;
    }
    memcpy(b->p + b->len, s, n);
    b->len += n;
    b->p[b->len] = '\0';
}

static void puts_(Buf *b, const char *s) { put(b, s, strlen(s)); }

static void put_num(Buf *b, double v)
{
    char s[40];
    snprintf(s, sizeof s, "%.17g", v); /* the parser stored -0 as 0 */
    puts_(b, s);
}

static void put_str(Buf *b, const char *s)
{
    puts_(b, "\"");
    for (const unsigned char *c = (const unsigned char *)s; *c; c++) {
        char e[8];
        if (*c == '"' || *c == '\\') {
            e[0] = '\\';
            e[1] = (char)*c;
            put(b, e, 2);
        } else if (*c < 0x20) {
            snprintf(e, sizeof e, "\\u%04x", *c);
            puts_(b, e);
        } else {
            put(b, (const char *)c, 1);
        }
    }
    puts_(b, "\"");
}

static void put_value(Buf *b, const DrFieldSpec *f, const DrValue *v)
{
    const double *n = v->num;
    switch (f->kind) {
    case DR_FIELD_NUMBER:
    case DR_FIELD_INT: put_num(b, n[0]); return;
    case DR_FIELD_BOOL: puts_(b, n[0] != 0.0 ? "true" : "false"); return;
    case DR_FIELD_ENUM:
    case DR_FIELD_NAME: put_str(b, v->str); return;
    case DR_FIELD_PATH: put_str(b, v->raw); return;
    case DR_FIELD_VEC3:
    case DR_FIELD_INT2:
        puts_(b, "[");
        for (int i = 0; i < dr_scene_kind_width_(f); i++) {
            if (i) puts_(b, ",");
            put_num(b, n[i]);
        }
        puts_(b, "]");
        return;
    case DR_FIELD_NAMES:
        puts_(b, "[");
        for (int i = 0; i < v->nrows; i++) {
            if (i) puts_(b, ",");
            put_str(b, v->names[i]);
        }
        puts_(b, "]");
        return;
    case DR_FIELD_BOX:
        puts_(b, "[[");
        for (int i = 0; i < 6; i++) {
            if (i) puts_(b, i == 3 ? "],[" : ",");
            put_num(b, n[i]);
        }
        puts_(b, "]]");
        return;
    case DR_FIELD_TABLE:
        puts_(b, "[");
        for (int r = 0; r < v->nrows; r++) {
            puts_(b, r ? ",[" : "[");
            for (int i = 0; i < f->arity; i++) {
                if (i) puts_(b, ",");
                put_num(b, v->rows[(size_t)r * (size_t)f->arity + (size_t)i]);
            }
            puts_(b, "]");
        }
        puts_(b, "]");
        return;
    }
}

static int cmp_str(const void *a, const void *b) { return strcmp(*(const char *const *)a, *(const char *const *)b); }

/* {"field": value, ...} of every valued field of c, keys sorted; for a section also its nested
 * sections under their keys. */
static void put_component(Buf *b, const DrScene *s, const DrComponent *c, bool nested)
{
    const char *keys[64];
    int n = 0;
    for (int i = 0; i < c->spec->field_count && n < 64; i++)
        if (c->values[i].has) keys[n++] = c->spec->fields[i].name;
    size_t plen = strlen(c->spec->name);
    for (int i = 0; nested && i < dr_scene_section_count_ && n < 64; i++) {
        const char *name = dr_scene_sections_[i].name;
        if (strncmp(name, c->spec->name, plen) == 0 && name[plen] == '.' && !strchr(name + plen + 1, '.'))
            keys[n++] = name + plen + 1;
    }
    assert(n < 64);
    qsort(keys, (size_t)n, sizeof keys[0], cmp_str);
    puts_(b, "{");
    for (int k = 0; k < n; k++) {
        if (k) puts_(b, ",");
        put_str(b, keys[k]);
        puts_(b, ":");
        int fi = dr_scene_field_index_(c->spec, keys[k]);
        if (fi >= 0) {
            put_value(b, &c->spec->fields[fi], &c->values[fi]);
        } else {
            char child[256];
            snprintf(child, sizeof child, "%s.%s", c->spec->name, keys[k]);
            put_component(b, s, dr_scene_section(s, child), true);
        }
    }
    puts_(b, "}");
}

static void put_element(Buf *b, const DrElement *e)
{
    const char *names[64];
    int n = 0;
    for (int i = 0; i < e->spec->component_count && n < 64; i++)
        if (e->components_[i].present) names[n++] = e->spec->components[i];
    qsort(names, (size_t)n, sizeof names[0], cmp_str);
    puts_(b, "{\"components\":{");
    for (int i = 0; i < n; i++) {
        if (i) puts_(b, ",");
        put_str(b, names[i]);
        puts_(b, ":");
        put_component(b, NULL, dr_element_component(e, names[i]), false);
    }
    puts_(b, "},\"name\":");
    put_str(b, e->name);
    puts_(b, ",\"type\":");
    put_str(b, e->type);
    puts_(b, "}");
}

char *dr_scene_canonical(const DrScene *s, const char *section)
{
    Buf b = {0};
    if (strcmp(section, "elements") == 0) {
        puts_(&b, "[");
        for (int i = 0; i < s->element_count; i++) {
            if (i) puts_(&b, ",");
            put_element(&b, &s->elements[i]);
        }
        puts_(&b, "]");
    } else {
        put_component(&b, s, dr_scene_section(s, section), true);
    }
    if (b.oom) {
        free(b.p);
        return NULL;
    }
    return b.p;
}

/* ---- keys ------------------------------------------------------------------------------------------------ */

/* label NUL text NUL: neither may contain NUL, so no two different (label, text) sequences feed the
 * hasher the same bytes. */
static void feed(DrHasher *h, const char *label, const char *text)
{
    dr_hasher_update_str(h, label);
    dr_hasher_update_str(h, text);
}

static DrStatus feed_canonical(DrHasher *h, const DrScene *s, const char *section, DrError *err)
{
    char *c = dr_scene_canonical(s, section);
    if (!c) return dr_error_set(err, DR_ERR_NOMEM, s->path, 0, 0, "out of memory writing the canonical scene");
    feed(h, section, c);
    free(c);
    return DR_OK;
}

static DrStatus feed_asset(DrHasher *h, const DrScene *s, const DrAsset *a, DrError *err)
{
    DrHash ah;
    DrError ferr;
    if (dr_hash_file(a->path, &ah, &ferr) != DR_OK)
        return dr_error_set(err, DR_ERR_INPUT, s->path, 0, 0,
                            "asset '%s' referenced by %s cannot be read (%s); restore the file or fix the path",
                            a->path, a->where, ferr.message);
    char hex[33];
    dr_hash_hex(ah, hex);
    feed(h, "asset", hex);
    return DR_OK;
}

/* The hasher owns an allocation until final: every exit goes through it. */
static DrStatus finish(DrHasher *h, DrStatus st, char out[33])
{
    DrHash r = dr_hasher_final(h);
    if (st == DR_OK) dr_hash_hex(r, out);
    return st;
}

DrStatus dr_scene_keys(const DrScene *s, DrSceneKeys *out, DrError *err)
{
    DrHasher h;
    DrStatus st = DR_OK;

    /* 1. precompute: the elements that need precomputed data, with their assets */
    dr_hasher_init(&h);
    feed(&h, "version", DR_STAGE_VERSION_PRECOMPUTE);
    for (int i = 0; st == DR_OK && i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (!e->spec->needs_precompute) continue;
        Buf b = {0};
        put_element(&b, e);
        if (b.oom) st = dr_error_set(err, DR_ERR_NOMEM, s->path, 0, 0, "out of memory writing the canonical scene");
        else feed(&h, "element", b.p);
        free(b.p);
        for (int k = 0; st == DR_OK && k < s->asset_count; k++)
            if (s->assets[k].element == i) st = feed_asset(&h, s, &s->assets[k], err);
    }
    /* the fields of other elements that enter precomputed data (a wet hair's cohesion tables), when their component is
       written: a scene without such components keeps the key it had before they existed */
    for (int i = 0; st == DR_OK && i < s->element_count; i++) {
        const DrElement *e = &s->elements[i];
        if (e->spec->needs_precompute) continue;
        for (int c = 0; c < e->spec->component_count; c++) {
            const DrComponent *comp = &e->components_[c];
            if (!comp->present) continue;
            for (int f = 0; f < comp->spec->field_count; f++) {
                if (!comp->spec->fields[f].precompute || !comp->values[f].has) continue;
                Buf b = {0};
                put_str(&b, e->name);
                puts_(&b, ".");
                put_str(&b, comp->spec->name);
                puts_(&b, ".");
                put_str(&b, comp->spec->fields[f].name);
                puts_(&b, "=");
                put_value(&b, &comp->spec->fields[f], &comp->values[f]);
                if (b.oom) st = dr_error_set(err, DR_ERR_NOMEM, s->path, 0, 0, "out of memory writing the scene key");
                else feed(&h, "precompute-field", b.p);
                free(b.p);
            }
        }
    }
    DR_TRY(finish(&h, st, out->precompute));

    /* 2. bake: shot, solver, elements, asset bytes, precompute key, versions */
    dr_hasher_init(&h);
    st = feed_canonical(&h, s, "shot", err);
    if (st == DR_OK) st = feed_canonical(&h, s, "solver", err);
    if (st == DR_OK) st = feed_canonical(&h, s, "elements", err);
    for (int k = 0; st == DR_OK && k < s->asset_count; k++) st = feed_asset(&h, s, &s->assets[k], err);
    feed(&h, "precompute", out->precompute);
    feed(&h, "version", DR_STAGE_VERSION_BAKE);
    feed(&h, "drench", DR_VERSION);
    DR_TRY(finish(&h, st, out->bake));

    /* 3. mesh */
    dr_hasher_init(&h);
    feed(&h, "bake", out->bake);
    st = feed_canonical(&h, s, "mesh", err);
    feed(&h, "version", DR_STAGE_VERSION_MESH);
    DR_TRY(finish(&h, st, out->mesh));

    /* 4. render */
    dr_hasher_init(&h);
    feed(&h, "mesh", out->mesh);
    st = feed_canonical(&h, s, "render", err);
    feed(&h, "version", DR_STAGE_VERSION_RENDER);
    return finish(&h, st, out->render);
}
