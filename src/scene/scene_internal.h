/* Private to src/scene: the tables, the parsed representation, and the helpers shared by the parser,
 * the canonical writer and the reference printer. */
#ifndef DR_SCENE_INTERNAL_H
#define DR_SCENE_INTERNAL_H

#include "scene/scene.h"

/* ---- tables (scene_spec.c) ---- */
extern const DrComponentSpec dr_scene_sections_[]; /* parents before children ("render" before "render.camera") */
extern const int dr_scene_section_count_;
extern const DrComponentSpec dr_scene_components_[];
extern const int dr_scene_component_count_;
extern const DrElementSpec dr_scene_types_[];
extern const int dr_scene_type_count_;

int dr_scene_section_index_(const char *name); /* -1 if unknown */
int dr_scene_field_index_(const DrComponentSpec *c, const char *field); /* -1 if unknown */
/* Number of numbers a field of this kind holds (TABLE: per row). */
int dr_scene_kind_width_(const DrFieldSpec *f);
/* Asserts the tables are consistent (unique names, defaults inside ranges and choices, ...). */
void dr_scene_check_tables_(void);

/* ---- parsed values ---- */
typedef struct DrValue {
    bool set;          /* written in the file */
    bool has;          /* set, or a default exists */
    double num[6];     /* NUMBER/INT/BOOL/VEC3/INT2/BOX, as in DrFieldSpec.def */
    const char *str;   /* ENUM/NAME/PATH; PATH: resolved */
    const char *raw;   /* PATH as written (the canonical JSON uses it) */
    const double *rows; /* TABLE, nrows*arity */
    const char **names; /* NAMES, nrows of them */
    int nrows;
} DrValue;

struct DrComponent {
    const DrComponentSpec *spec;
    bool present;
    DrValue *values; /* spec->field_count */
};

typedef struct DrAsset {
    const char *path;  /* resolved */
    const char *where; /* "pour.Mesh.file" */
    int element;       /* index of the first element that references it, -1 for a section */
} DrAsset;

struct DrScene {
    DrArena *arena; /* everything below lives in it */
    const char *path;
    DrComponent *sections; /* dr_scene_section_count_, table order */
    DrElement *elements;
    int element_count;
    DrAsset *assets;
    int asset_count;
};

/* ---- locating a JSON path in the source text (scene_locate.c) ---- */
typedef struct DrJsonSeg {
    const char *key; /* object member, or NULL for the array element `index` */
    int index;
} DrJsonSeg;
/* Line and 1-based column (in characters, as jansson counts them) of the value at `path` in the valid
 * JSON `text` — or of its key when `at_key` and the path ends in a member. When the path is not fully
 * present (a field that was not written) it gives the deepest value that is. line = 0 if even the
 * root cannot be found. */
void dr_scene_locate_(const char *text, size_t len, const DrJsonSeg *path, int depth, bool at_key, int *line,
                      int *col);

/* ---- small text helpers (scene_spec.c) ---- */
/* Levenshtein distance, case-insensitive. */
int dr_scene_edit_distance_(const char *a, const char *b);
/* Best candidate for a misspelt `word` among `n` names (first of the nearest), NULL when none is
 * close: distance <= max(2, length of the longer of the two / 3). */
const char *dr_scene_suggest_(const char *word, const char *const *names, int n);
/* Splits an ENUM's "a|b|c" into names pointing into buf; returns how many (at most max). */
int dr_scene_split_choices_(const char *choices, char *buf, size_t size, const char **names, int max);
/* "a, b, c" into buf. */
void dr_scene_join_names_(const char *const *names, int n, char *buf, size_t size);
/* %.15g, the short form used in messages and the reference. */
void dr_scene_fmt_num_(double v, char *buf, size_t size);
/* The default as the reference prints it: "required", "unset", "[]", or its JSON text. */
void dr_scene_default_text_(const DrFieldSpec *f, char *buf, size_t size);
/* "[1, 100000]" or "(0, 1000]"; "" when the field has no range. */
void dr_scene_fmt_range_(const DrFieldSpec *f, char *buf, size_t size);

#endif
