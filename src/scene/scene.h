/* drench scene: a JSON scene file → a validated, immutable DrScene (DESIGN §3) and the stage cache
 * keys derived from it (DESIGN §5).
 *
 * Model. Top-level sections ("shot", "solver", "mesh", "render" with its nested "render.camera") and
 * an "elements" array. An element has a unique name, a type ("liquid", "collider", "mpm_solid", "hair",
 * "bem_solid") and named
 * components; a component is a table of typed fields. One set of static tables (DrFieldSpec,
 * DrComponentSpec, DrElementSpec) drives parsing, validation, defaults, the canonical JSON and the
 * printed reference, so the documentation cannot drift from the parser.
 *
 * Values. Every field has a kind, a unit (SI; angles in degrees in the scene), a default (or none),
 * a range checked on each of its numbers, and a one-line doc. An absent section or component reads as
 * all defaults; a field without a default that was not written reads as unset (dr_component_str
 * returns NULL, dr_component_is_set false). Required fields must be written when their component is;
 * a liquid element must have a Domain, a collider a Mesh, an mpm_solid a Domain and an MpmShape (exactly
 * one of box, centre + radius, mesh), a hair element a Groom (exactly one of scalp and curves; the growth
 * fields only with scalp; Collider.boundary is for colliders). Cross-element rules: every mpm_solid of a
 * scene shares one grid and one time step, so their Domain.voxel_size and wall_boundary and all Transfer
 * and Integrator fields must be equal (the error names both elements and the field); every hair element
 * is solved in one system, so their HairSolver fields must be equal; a liquid's Transfer takes neither
 * scheme rpic nor a kernel other than quadratic.
 *
 * Errors. Every problem in the file is DR_ERR_INPUT with DrError.file = the scene path, line and
 * column of the offending key or value (jansson's for syntax errors, this module's own scan of the
 * text for semantic ones), and a message naming element.Component.field or section.field, the value,
 * the allowed range or choices, a "did you mean" suggestion for misspelt names, and what to write.
 * Asset paths (PATH fields) resolve against the scene file's directory, then the current directory;
 * a missing asset is an error at load time. Asset contents are not read here except by dr_scene_keys.
 *
 * Ownership and threads. dr_scene_load allocates; dr_scene_destroy frees everything it returned.
 * Every pointer handed out (elements, components, strings, table rows) lives as long as the scene.
 * A loaded scene is never modified, so any number of threads may read it at once. The spec tables are
 * static and const.
 *
 * Programmer errors assert (kept in release builds): asking for a field a component does not have,
 * with the getter of another kind, a component not in the element type's table, an unknown section. */
#ifndef DR_SCENE_H
#define DR_SCENE_H

#include "core/core.h"

/* ---- schema tables --------------------------------------------------------------------------------- */

typedef enum DrFieldKind {
    DR_FIELD_NUMBER, /* a finite double */
    DR_FIELD_INT,    /* an integral number (1 and 1.0 alike) that fits an int */
    DR_FIELD_BOOL,   /* true or false */
    DR_FIELD_ENUM,   /* one of the '|'-separated `choices` */
    DR_FIELD_NAME,   /* identifier [A-Za-z0-9_.-]+, at most DR_SCENE_NAME_MAX bytes, not "." or ".." */
    DR_FIELD_PATH,   /* asset file path; must exist when the scene loads */
    DR_FIELD_VEC3,   /* [x, y, z] */
    DR_FIELD_INT2,   /* [a, b] of integers (frame range, resolution) */
    DR_FIELD_BOX,    /* [[x0,y0,z0],[x1,y1,z1]] with x0<x1, y0<y1, z0<z1 */
    DR_FIELD_TABLE,  /* [[...], ...]: rows of exactly `arity` numbers; default empty */
    DR_FIELD_NAMES,  /* ["a", "b", ...]: one or more distinct NAMEs (element names); always required */
} DrFieldKind;

#define DR_SCENE_NAME_MAX 128

typedef struct DrFieldSpec {
    const char *name;
    DrFieldKind kind;
    const char *unit;     /* "m", "kg/m^3", "Pa*s", "s", "m/s", "m/s^2", "deg", "1" dimensionless, "" none */
    double def[6];        /* default numbers: NUMBER/INT/BOOL def[0], VEC3 def[0..2], INT2 def[0..1], BOX lo then hi */
    const char *def_str;  /* default of an ENUM/NAME/PATH field, NULL if none */
    bool no_default;      /* no default: the field is unset unless written (implied by `required`) */
    bool required;        /* must be written whenever its component is */
    bool ranged;          /* [lo, hi] (ends open when lo_open/hi_open) applies to every number of the field */
    bool lo_open, hi_open;
    double lo, hi;
    const char *choices;  /* ENUM: "apic|flip|pic" */
    int arity;            /* TABLE: numbers per row */
    const char *doc;      /* one line */
    const char *hint;     /* appended to an out-of-range message ("use ... such as ..."), NULL for a generic one */
    bool precompute;      /* enters data that precompute builds for an element whose type does not need precompute
                             otherwise (a wet hair's cohesion tables): its value is in the precompute key */
} DrFieldSpec;

typedef struct DrComponentSpec {
    const char *name; /* "LiquidMaterial"; for sections the JSON path: "shot", "render.camera" */
    const char *doc;
    const DrFieldSpec *fields;
    int field_count;
} DrComponentSpec;

/* The element types, in the order of the type table; DrElement.kind and DrElementSpec.kind say which one. */
typedef enum DrElementKind {
    DR_ELEMENT_LIQUID,
    DR_ELEMENT_COLLIDER,
    DR_ELEMENT_MPM_SOLID,
    DR_ELEMENT_HAIR,
    DR_ELEMENT_BEM_SOLID,
    DR_ELEMENT_BEM_JOINT,
    DR_ELEMENT_AIR,
    DR_ELEMENT_CLOTH,
    DR_ELEMENT_COLLISION,
    DR_ELEMENT_ATTACHMENT,
} DrElementKind;

typedef struct DrElementSpec {
    const char *type;
    const char *doc;
    const char *const *components; /* names of the component specs this type accepts, in print order */
    int component_count;
    const char *const *required_components;
    int required_count;
    bool needs_precompute; /* whether `precompute` builds data for elements of this type (bem_solid) */
    DrElementKind kind;
} DrElementSpec;

/* Spec lookups (NULL when unknown). Sections: "shot", "solver", "mesh", "render", "render.camera". */
const DrElementSpec *dr_scene_element_spec(const char *type);
const DrComponentSpec *dr_scene_component_spec(const char *name);
const DrComponentSpec *dr_scene_section_spec(const char *name);

/* Reference of every section, element type, component and field (kind, unit, default, range, doc),
 * generated from the tables; markdown=true gives Markdown tables suitable for README, false a plain-text
 * listing (what `bake --list-components` prints): one row per field in columns aligned across the whole
 * listing (name, type, unit, default, range) with its description wrapped under it, the components an
 * element type must have marked "(required)", and no line longer than DR_REFERENCE_COLUMNS. */
#define DR_REFERENCE_COLUMNS 100
void dr_scene_print_reference(FILE *f, bool markdown);

/* ---- a loaded scene -------------------------------------------------------------------------------- */

typedef struct DrComponent DrComponent; /* parsed values of one component or section; opaque */
typedef struct DrScene DrScene;         /* opaque, immutable after load */

typedef struct DrElement {
    const char *name;
    const char *type;
    DrElementKind kind;         /* the type, as an enum */
    int index;                  /* position in the scene's "elements" array */
    const DrElementSpec *spec;
    DrComponent *components_;   /* private: one per spec component, in spec order */
} DrElement;

/* Reads, parses and validates `path`; on failure *out is NULL and err says what and where. */
DR_NODISCARD DrStatus dr_scene_load(const char *path, DrScene **out, DrError *err);
void dr_scene_destroy(DrScene **scene);
const char *dr_scene_path(const DrScene *s); /* as given to dr_scene_load */

int dr_scene_element_count(const DrScene *s);
const DrElement *dr_scene_element(const DrScene *s, int i); /* asserts 0 <= i < count */
const DrElement *dr_scene_find(const DrScene *s, const char *name); /* NULL if absent */
int dr_scene_count_type(const DrScene *s, const char *type);
int dr_scene_count_kind(const DrScene *s, DrElementKind kind);

/* Sections: never NULL for a section name (absent -> defaults); asserts on any other name. */
const DrComponent *dr_scene_section(const DrScene *s, const char *name);
/* Never NULL for a component of the element's type (absent -> all defaults); asserts otherwise. */
const DrComponent *dr_element_component(const DrElement *e, const char *name);

bool dr_component_present(const DrComponent *c);                    /* written in the scene file */
bool dr_component_is_set(const DrComponent *c, const char *field); /* field written in the file */
/* Typed getters: the written value or the table default. Assert on an unknown field or wrong kind. */
double dr_component_num(const DrComponent *c, const char *field);      /* NUMBER */
int dr_component_int(const DrComponent *c, const char *field);         /* INT */
bool dr_component_bool(const DrComponent *c, const char *field);       /* BOOL */
/* ENUM, NAME, PATH (the resolved path, openable from the current directory); NULL if unset, no default. */
const char *dr_component_str(const DrComponent *c, const char *field);
DrVec3 dr_component_vec3(const DrComponent *c, const char *field);
void dr_component_int2(const DrComponent *c, const char *field, int out[2]);
/* An unset BOX without default (e.g. an absent LiquidSource.box) yields lo = hi = 0; check is_set. */
void dr_component_box(const DrComponent *c, const char *field, DrVec3 *lo, DrVec3 *hi);
/* Row count (0 when unset); *rows points at count*arity numbers, row-major (NULL when 0 rows). */
int dr_component_table(const DrComponent *c, const char *field, const double **rows);
/* NAMES: how many (0 when the component is absent); *names points at them, in the file's order. */
int dr_component_names(const DrComponent *c, const char *field, const char *const **names);

/* The collision element whose members a and b (element names; a == b for a member with itself) meet by `method`
 * ("edge_edge", "vertex_face"), NULL when none does (the scene's rules allow at most one). */
const DrElement *dr_scene_collision(const DrScene *s, const char *a, const char *b, const char *method);

/* ---- defaults a scene applied ---------------------------------------------------------------------------- */

/* A field the scene file did not write that took its documented default. */
typedef struct DrAppliedDefault {
    const char *component;    /* component name ("LiquidMaterial"), or the section ("solver") */
    const DrFieldSpec *field; /* name, kind, unit and doc of the field */
} DrAppliedDefault;

/* Fields of element e that the file left unwritten and that take their default, in component and field
 * order: every field with a default of each component the element reads, unless it does not apply:
 *   - a component whose absence means "none" (LiquidSource, Emitter, KillBox, Motion, FixedVertices) applies
 *     nothing unless written;
 *   - Collider.boundary applies to collider elements only, Collider.body_contact to bem_solid elements only;
 *   - Transfer.flip_blend only with scheme flip; Groom's growth fields only with a scalp, curl_pitch only with
 *     curl_radius > 0; Joint.tolerance only with mode coincident.
 * Fills up to `max` entries of out (out may be NULL when max is 0); returns how many there are. */
int dr_element_applied_defaults(const DrElement *e, DrAppliedDefault *out, int max);
/* The same for a section ("shot", "solver", "mesh", "render", "render.camera"). */
int dr_section_applied_defaults(const DrScene *s, const char *section, DrAppliedDefault *out, int max);
/* A field's default as JSON text (1000, 0.001, true, "apic", [0, -9.81, 0], [[0, 0, 0], [1, 1, 1]], []);
 * "" for a field without a default. */
void dr_scene_default_json(const DrFieldSpec *f, char *buf, size_t size);

/* Canonical JSON of "shot", "solver", "mesh", "render" (camera nested), "render.camera" or "elements":
 * keys sorted by byte value, every number printed as %.17g of its double value (so 1 and 1.0 are the
 * same; -0 prints as 0), strings JSON-escaped, no whitespace. Sections carry every field that has a
 * value (written or default), so writing a default explicitly changes nothing. "elements" is the array
 * in file order; each element lists the components written in the file (presence is meaningful: an
 * Emitter that is absent emits nothing), each with all its valued fields. PATH fields appear as written.
 * Malloc'd (caller frees); NULL only when memory runs out. Asserts on another section name. */
char *dr_scene_canonical(const DrScene *s, const char *section);

/* Every distinct resolved asset path the scene references (PATH fields), in element order. */
int dr_scene_asset_count(const DrScene *s);
const char *dr_scene_asset(const DrScene *s, int i);

/* ---- stage cache keys (DESIGN §5) ---------------------------------------------------------------------- */

#define DR_STAGE_VERSION_PRECOMPUTE "precompute-2" /* precompute-2: cache files carry checksums (DR_BEM_VERSION bem-2) */
#define DR_STAGE_VERSION_BAKE "bake-4" /* bake-2: liquid collider boundary and CFL rework, checkpoint layout;
                                          bake-3: frames and checkpoints carry checksums; bake-4: the liquid's
                                          particle ids in frame caches and checkpoints */
#define DR_STAGE_VERSION_MESH "mesh-3" /* mesh-2: points files, whole-liquid velocity option; mesh-3: wet hair's film */
#define DR_STAGE_VERSION_RENDER "render-2" /* render-2: wet hair wider and darker */
typedef struct DrSceneKeys { char precompute[33], bake[33], mesh[33], render[33]; } DrSceneKeys;

/* 32 lowercase hex digits each (XXH3-128); every input is fed with a label and a terminator so that
 * moving bytes from one input to the next changes the key.
 *   precompute: DR_STAGE_VERSION_PRECOMPUTE + canonical JSON and asset bytes of every element whose
 *               type needs_precompute (bem_solid; a scene without one has the key of an empty list);
 *   bake:       canonical shot, solver and elements + the bytes of every asset + precompute key +
 *               DR_STAGE_VERSION_BAKE + DR_VERSION (not mesh, not render);
 *   mesh:       bake key + canonical mesh + DR_STAGE_VERSION_MESH;
 *   render:     mesh key + canonical render (with its camera) + DR_STAGE_VERSION_RENDER.
 * Reads every asset: an asset that vanished or cannot be read since load is DR_ERR_INPUT naming it
 * and the field that references it. */
DR_NODISCARD DrStatus dr_scene_keys(const DrScene *s, DrSceneKeys *out, DrError *err);

#endif
