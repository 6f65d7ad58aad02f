/* render plots: progress.jsonl → one whitespace-separated .dat + one gnuplot script → PNGs (contract
 * in plots.h). The JSON lines are flattened into named columns ("seconds.p2g", "momentum.linear.x")
 * and each plot picks its columns by name, so keys added by later solvers show up without edits
 * here. gnuplot runs once for all plots: one process, and one log to quote when it fails. */
#include "plots.h"

#include "io/io.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <jansson.h>
#include <spawn.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

extern char **environ; /* for posix_spawnp: gnuplot inherits our environment */

enum { P_SECONDS, P_ITERATIONS, P_DRIFT, P_ENERGY, P_MOMENTUM, P_LEDGER, NPLOTS };
static const char *const plot_names[NPLOTS] = {"seconds_per_frame", "solver_iterations", "volume_drift",
                                               "energy", "momentum", "volume_ledger"};
/* The volume ledger of wet hair beside a liquid (capture and dripping; README "the volume ledger"): its parts, m³,
   drawn when the bake kept one (volume_total present); its relative error on the right axis. */
static const char *const ledger_keys[] = {"volume_bulk", "film_volume", "film_pool_volume", "volume_emitted",
                                          "volume_removed", "volume_total", "volume_initial", "volume_error"};

/* One colour per series, told apart at a glance (Paul Tol's "muted" and "light" schemes, then a few darker
 * tones): gnuplot's own cycle repeats after 8, and a frame's phases (liquid, MPM, hair, BEM, output) are 17. */
static const char *const palette[] = {"#332288", "#88ccee", "#44aa99", "#117733", "#999933", "#ddcc77", "#cc6677",
                                      "#882255", "#aa4499", "#ee8866", "#bbcc33", "#77aadd", "#ee3377", "#0077bb",
                                      "#555555", "#e69f00", "#009e73", "#cc3311", "#33bbee", "#bbbbbb", "#000000",
                                      "#f0e442", "#8c564b", "#9467bd"};
#define NPALETTE ((int)(sizeof palette / sizeof palette[0]))

typedef struct Row { json_int_t frame; int line; json_t *obj; } Row;

/* A column of the .dat: a flattened key and its value per frame, NaN where that frame's line lacks
 * the key (JSON has no NaN, so NaN never stands for a real value). Column 0 is "frame". */
typedef struct Column { char *name; double *v; } Column;
typedef struct Table { int nrows, ncols, cap; Column *cols; } Table;

static bool starts(const char *s, const char *prefix) { return !strncmp(s, prefix, strlen(prefix)); }
static bool toplevel(const char *s) { return !strchr(s, '.'); }

/* ---- reading ---------------------------------------------------------------------------------- */

static int row_cmp(const void *a, const void *b)
{
    const Row *x = a, *y = b;
    if (x->frame != y->frame) return x->frame < y->frame ? -1 : 1;
    return x->line - y->line; /* equal frames stay in file order, so the last line sorts last */
}

/* Parses every non-blank line, sorts by frame and keeps the last line of each frame. */
static DrStatus read_rows(const char *path, Row **out, int *nout, DrError *err)
{
    if (!dr_io_exists(path))
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "there is no bake progress to plot (%s is missing); run bake first", path);
    char *text = NULL;
    DR_TRY(dr_io_read_text(path, &text, err));
    Row *rows = NULL;
    int n = 0, cap = 0, lineno = 0;
    DrStatus s = DR_OK;
    for (char *line = text, *next; s == DR_OK && line; line = next) {
        lineno++;
        next = strchr(line, '\n');
        if (next) *next++ = '\0';
        if (line[strspn(line, " \t\r")] == '\0') continue; /* blank, e.g. after the last newline */
        json_error_t jerr;
        json_t *obj = json_loads(line, 0, &jerr);
        json_t *frame = json_object_get(obj, "frame");
        if (!obj || !json_is_object(obj) || !json_is_integer(frame)) {
            s = dr_error_set(err, DR_ERR_INPUT, path, lineno, obj ? 0 : jerr.column,
                             "malformed bake progress line (%s); each line must be one JSON object with an integer "
                             "\"frame\"; remove the line (a bake killed while writing it) or run bake again",
                             obj ? "not an object with an integer \"frame\"" : jerr.text);
            json_decref(obj);
            break;
        }
        if (n == cap) {
            int ncap = cap ? 2 * cap : 256;
            s = dr_realloc((size_t)ncap, sizeof *rows, &rows, err);
            if (s != DR_OK) { json_decref(obj); break; }
            cap = ncap;
        }
        rows[n++] = (Row){json_integer_value(frame), lineno, obj};
    }
    free(text);
    if (s == DR_OK && n == 0)
        s = dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                         "there is no bake progress to plot (%s has no frames); run bake first", path);
    if (s != DR_OK) {
        for (int i = 0; i < n; i++) json_decref(rows[i].obj);
        free(rows);
        return s;
    }
    qsort(rows, (size_t)n, sizeof *rows, row_cmp);
    int kept = 0;
    for (int i = 0; i < n; i++) {
        if (i + 1 < n && rows[i + 1].frame == rows[i].frame) json_decref(rows[i].obj); /* a later line wins */
        else rows[kept++] = rows[i];
    }
    *out = rows;
    *nout = kept;
    return DR_OK;
}

static DrStatus table_set(Table *t, const char *name, int row, double value, DrError *err)
{
    int c = 0;
    while (c < t->ncols && strcmp(t->cols[c].name, name)) c++;
    if (c == t->ncols) {
        if (t->ncols == t->cap) {
            int ncap = t->cap ? 2 * t->cap : 32;
            DR_TRY(dr_realloc((size_t)ncap, sizeof *t->cols, &t->cols, err));
            t->cap = ncap;
        }
        Column col = {dr_strdup(name), NULL};
        if (!col.name) return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "out of memory reading bake progress");
        if (dr_calloc((size_t)t->nrows, sizeof *col.v, &col.v, err) != DR_OK) { free(col.name); return DR_ERR_NOMEM; }
        for (int r = 0; r < t->nrows; r++) col.v[r] = NAN;
        t->cols[t->ncols++] = col;
    }
    t->cols[c].v[row] = value;
    return DR_OK;
}

/* Numbers become columns named by their JSON path; 3-arrays get x, y, z; strings, booleans and null
 * are not plottable and are skipped. */
static DrStatus flatten(Table *t, int row, const char *prefix, json_t *v, DrError *err)
{
    char name[512];
    if (json_is_number(v)) return table_set(t, prefix, row, json_number_value(v), err);
    if (json_is_object(v)) {
        const char *key;
        json_t *child;
        json_object_foreach(v, key, child) {
            if (prefix[0]) snprintf(name, sizeof name, "%s.%s", prefix, key);
            else snprintf(name, sizeof name, "%s", key);
            DR_TRY(flatten(t, row, name, child, err));
        }
    } else if (json_is_array(v)) {
        size_t i;
        json_t *child;
        json_array_foreach(v, i, child) {
            if (json_array_size(v) == 3) snprintf(name, sizeof name, "%s.%c", prefix, "xyz"[i]);
            else snprintf(name, sizeof name, "%s[%zu]", prefix, i);
            DR_TRY(flatten(t, row, name, child, err));
        }
    }
    return DR_OK;
}

static void table_free(Table *t)
{
    for (int c = 0; c < t->ncols; c++) { free(t->cols[c].name); free(t->cols[c].v); }
    free(t->cols);
    *t = (Table){0};
}

/* Wet hair's phases (seconds.film, cross_flow, bridges) are parts of seconds.hair: the stack shows the hair's solve as
   what is left of it, so that no second is counted twice. */
static void split_hair_seconds(Table *t)
{
    int hair = -1;
    for (int c = 0; c < t->ncols; c++)
        if (!strcmp(t->cols[c].name, "seconds.hair")) hair = c;
    if (hair < 0) return;
    static const char *const parts[] = {"seconds.film", "seconds.cross_flow", "seconds.bridges"};
    for (int c = 0; c < t->ncols; c++)
        for (size_t k = 0; k < sizeof parts / sizeof parts[0]; k++) {
            if (strcmp(t->cols[c].name, parts[k])) continue;
            for (int r = 0; r < t->nrows; r++)
                if (!isnan(t->cols[c].v[r]) && !isnan(t->cols[hair].v[r]))
                    t->cols[hair].v[r] = fmax(0.0, t->cols[hair].v[r] - t->cols[c].v[r]);
        }
}

/* ---- the .dat and the script ------------------------------------------------------------------ */

static DrStatus write_dat(const char *path, const Table *t, DrError *err)
{
    FILE *f = fopen(path, "w");
    if (!f)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot create %s: %s; check $TMPDIR", path, strerror(errno));
    fputc('#', f); /* header: the column names, so the file explains itself */
    for (int c = 0; c < t->ncols; c++) {
        fputc(' ', f);
        for (const char *p = t->cols[c].name; *p; p++) fputc((unsigned char)*p <= ' ' ? '_' : *p, f);
    }
    fputc('\n', f);
    for (int r = 0; r < t->nrows; r++) {
        for (int c = 0; c < t->ncols; c++) {
            double v = t->cols[c].v[r];
            /* a phase a frame lacks did not run (0 s) and must not punch a hole in the stack;
               anything else missing is NaN, which gnuplot leaves as a gap in the line (its "missing"
               marker would instead join the neighbours, hiding that nothing was measured) */
            if (isnan(v) && starts(t->cols[c].name, "seconds.")) v = 0.0;
            if (isnan(v)) fputs(c ? " NaN" : "NaN", f);
            else fprintf(f, c ? " %.9g" : "%.9g", v);
        }
        fputc('\n', f);
    }
    bool bad = ferror(f) != 0;
    if (fclose(f) != 0 || bad)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write %s; check free space in $TMPDIR", path);
    return DR_OK;
}

/* A gnuplot single-quoted string: the only escape is '' for '; control characters become spaces. */
static void gp_str(FILE *f, const char *s)
{
    fputc('\'', f);
    for (; *s; s++) {
        if (*s == '\'') fputs("''", f);
        else fputc((unsigned char)*s < ' ' ? ' ' : *s, f);
    }
    fputc('\'', f);
}

static bool any_nonzero(const Column *c, int nrows)
{
    for (int r = 0; r < nrows; r++)
        if (!isnan(c->v[r]) && c->v[r] != 0.0) return true;
    return false;
}

/* Which plot a column belongs to (-1: none); the rules are by name so new solvers' keys fit in. */
static int plot_of(const Column *c, int nrows)
{
    const char *n = c->name;
    /* a phase that took no time in any frame is a solver the shot does not have: no layer for it */
    if (starts(n, "seconds.") && strcmp(n, "seconds.frame")) return any_nonzero(c, nrows) ? P_SECONDS : -1;
    if (!strcmp(n, "substeps")) return P_ITERATIONS;
    /* iteration counts that stay 0 are a solver the shot does not have (a liquid's pressure solve in a scene
       without liquid); a count of unconverged solves is worth a line only when there was one */
    if (starts(n, "iterations.") || (toplevel(n) && strstr(n, "iterations")) || strstr(n, "not_converged"))
        return any_nonzero(c, nrows) ? P_ITERATIONS : -1;
    /* the liquid's volume as its particles carry it; the occupied-cell estimate ("volume_drift") counts a splash's
       partly filled cells as full and reads high, so it is not drawn */
    if (!strcmp(n, "liquid_particle_volume")) return P_DRIFT;
    if (!strcmp(n, "energy") || starts(n, "energy.") || (toplevel(n) && strstr(n, "_energy"))) return P_ENERGY;
    if (!strcmp(n, "momentum") || starts(n, "momentum.")) return P_MOMENTUM;
    for (size_t k = 0; k < sizeof ledger_keys / sizeof *ledger_keys; k++)
        if (!strcmp(n, ledger_keys[k])) return P_LEDGER;
    return -1;
}

/* Settings every plot shares; `reset` keeps one plot's settings out of the next. Keys with long
 * names go under the graph in rows (beside it they would take half the width); the stack's key and
 * short ones stand at the right, the stack's in the order of its layers. */
#define KEY_RIGHT "set key outside right top Left reverse"
#define KEY_BELOW "set key outside below center horizontal Left reverse"
static void gp_begin(FILE *f, const char *png_tmp, const char *title, const char *ylabel, const char *key)
{
    fputs("reset\nset output ", f);
    gp_str(f, png_tmp);
    fprintf(f, "\n%s\n", key);
    fputs("set grid\nset autoscale xfix\nset xlabel 'frame'\nset title ", f);
    gp_str(f, title);
    fputs("\nset ylabel ", f);
    gp_str(f, ylabel);
    fputc('\n', f);
}

/* One line series; `using` is a gnuplot column expression such as "3" or "(100*$9)". */
static void gp_line(FILE *f, const char *dat, const char *using, const char *style, const char *title, bool first)
{
    fputs(first ? "plot " : ", \\\n     ", f);
    gp_str(f, dat);
    fprintf(f, " using 1:%s with %s title ", using, style);
    gp_str(f, title);
}

/* Splits "momentum.<panel>.<series>" into its panel ("linear", "angular"; "" for a bare "momentum")
 * and returns the series title ("x"; the panel itself when the value is a scalar). */
static const char *momentum_split(const char *name, char panel[64])
{
    const char *rest = name + strlen("momentum");
    rest += *rest == '.';
    size_t len = strcspn(rest, ".[");
    snprintf(panel, 64, "%.*s", (int)len, rest);
    return rest[len] ? rest + len + (rest[len] == '.') : rest[0] ? rest : "momentum";
}

/* One panel per vector under "momentum", each in its own units (at most 8: more would not be
 * readable in 540 pixels). */
static void write_momentum(FILE *f, const char *dat, const Table *t, const int *cols, int n, const char *style)
{
    /* panel names are under 64 bytes; label has room beyond that only for -Wformat-truncation */
    char panels[8][64], panel[64], label[640], using[32];
    int np = 0;
    for (int i = 0; i < n; i++) {
        momentum_split(t->cols[cols[i]].name, panel);
        int k = 0;
        while (k < np && strcmp(panels[k], panel)) k++;
        if (k == np && np < 8) memcpy(panels[np++], panel, sizeof panel);
    }
    fprintf(f, "set multiplot layout %d,1 title 'Momentum per frame'\nunset title\n", np);
    for (int k = 0; k < np; k++) {
        const char *units = !strcmp(panels[k], "linear")    ? " (kg·m/s)"
                            : !strcmp(panels[k], "angular") ? " (kg·m²/s)"
                                                            : "";
        snprintf(label, sizeof label, "%s%smomentum%s", panels[k], panels[k][0] ? " " : "", units);
        fputs("set ylabel ", f);
        gp_str(f, label);
        fputc('\n', f);
        bool first = true;
        for (int i = 0; i < n; i++) {
            const char *title = momentum_split(t->cols[cols[i]].name, panel);
            if (strcmp(panel, panels[k])) continue;
            snprintf(using, sizeof using, "%d", cols[i] + 1);
            gp_line(f, dat, using, style, title, first);
            first = false;
        }
        fputc('\n', f);
    }
    fputs("unset multiplot\n", f);
}

/* Writes the script for every plot that has columns; made[p] tells which. */
static DrStatus write_script(const char *path, const char *dat, const Table *t, char png_tmp[NPLOTS][DR_IO_PATH_MAX],
                             bool made[NPLOTS], DrError *err)
{
    int *cols = NULL, n[NPLOTS] = {0}, total = -1;
    DR_TRY(dr_calloc((size_t)NPLOTS * (size_t)t->ncols, sizeof *cols, &cols, err)); /* cols[p*ncols + i] */
    for (int c = 1; c < t->ncols; c++) {
        int p = plot_of(&t->cols[c], t->nrows);
        if (p >= 0) cols[p * t->ncols + n[p]++] = c;
        if (!strcmp(t->cols[c].name, "seconds.frame")) total = c;
    }
    FILE *f = fopen(path, "w");
    if (!f) {
        free(cols);
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot create %s: %s; check $TMPDIR", path, strerror(errno));
    }
    /* points mark the frames while they are few enough to tell apart */
    const char *style = t->nrows <= 60 ? "linespoints pt 7 ps 0.5 lw 1.5" : "lines lw 1.5";
    char using[4096];
    fputs("set encoding utf8\nset terminal pngcairo size 960,540 font 'sans,10' noenhanced\n", f);
    for (int k = 0; k < NPALETTE; k++) fprintf(f, "set linetype %d lc rgb '%s'\n", k + 1, palette[k]);
    fprintf(f, "set linetype cycle %d\n", NPALETTE);
    for (int p = 0; p < NPLOTS; p++) {
        const int *pc = cols + p * t->ncols;
        made[p] = n[p] > 0 || (p == P_SECONDS && total >= 0);
        if (p == P_LEDGER) { /* only a bake that kept the ledger */
            bool kept = false;
            for (int i = 0; i < n[p]; i++) kept |= !strcmp(t->cols[pc[i]].name, "volume_total");
            made[p] = kept;
        }
        if (!made[p]) continue;
        switch (p) {
        case P_SECONDS:
            gp_begin(f, png_tmp[p], "Bake wall-clock time per frame, stacked by phase", "time per frame (s)",
                     KEY_RIGHT);
            fputs("set yrange [0:*]\nset style fill solid 0.8 border lc rgb 'white'\n", f);
            /* stacked areas: draw the highest partial sum first so each lower one covers the rest;
               fixed line types keep a phase's colour whatever the drawing order */
            for (int i = n[p] - 1; i >= 0; i--) {
                int len = snprintf(using, sizeof using, "(0");
                for (int k = 0; k <= i && len < (int)sizeof using - 16; k++)
                    len += snprintf(using + len, sizeof using - (size_t)len, "+$%d", pc[k] + 1);
                snprintf(using + len, sizeof using - (size_t)len, ")");
                char style_i[64];
                snprintf(style_i, sizeof style_i, "filledcurves x1 lt %d", i + 1);
                gp_line(f, dat, using, style_i, t->cols[pc[i]].name + strlen("seconds."), i == n[p] - 1);
            }
            if (total >= 0) {
                snprintf(using, sizeof using, "%d", total + 1);
                gp_line(f, dat, using, "lines lw 2 lc rgb 'black'", "frame (total)", n[p] == 0);
            }
            fputc('\n', f);
            break;
        case P_ITERATIONS: {
            gp_begin(f, png_tmp[p], "Solver iterations and substeps per frame", "iterations or substeps per frame",
                     KEY_BELOW);
            /* sums over a frame's substeps dwarf per-solve counts: they get the right axis */
            bool y2 = false;
            for (int i = 0; i < n[p]; i++) y2 |= strstr(t->cols[pc[i]].name, "_total") != NULL;
            fputs("set yrange [0:*]\n", f);
            if (y2)
                fputs("set ytics nomirror\nset y2tics\nset y2range [0:*]\n"
                      "set y2label 'iterations per frame, summed over substeps (right axis)'\n", f);
            for (int i = 0; i < n[p]; i++) {
                bool right = strstr(t->cols[pc[i]].name, "_total") != NULL;
                char style_i[96], title[600];
                snprintf(using, sizeof using, "%d", pc[i] + 1);
                snprintf(style_i, sizeof style_i, "%s axes x1%s", style, right ? "y2" : "y1");
                snprintf(title, sizeof title, "%s%s", t->cols[pc[i]].name, right ? " (right axis)" : "");
                gp_line(f, dat, using, style_i, title, i == 0);
            }
            fputc('\n', f);
            break;
        }
        case P_DRIFT: {
            /* against the first frame that has a volume: emitters and kill boxes change it, nothing else does */
            double v0 = NAN;
            for (int r = 0; r < t->nrows && isnan(v0); r++) v0 = t->cols[pc[0]].v[r];
            if (!(v0 > 0.0)) v0 = 1.0; /* no liquid at first: the line shows the volume in % of a cubic metre */
            gp_begin(f, png_tmp[p], "Liquid volume against the first frame: particles x the volume each was seeded with",
                     "volume change (%)", KEY_BELOW);
            fputs("set xzeroaxis lt -1\n", f);
            snprintf(using, sizeof using, "(100*($%d/%.17g-1))", pc[0] + 1, v0);
            gp_line(f, dat, using, style, "liquid_particle_volume", true);
            fputc('\n', f);
            break;
        }
        case P_ENERGY:
            gp_begin(f, png_tmp[p], "Energy per frame", "energy (J)", KEY_BELOW);
            for (int i = 0; i < n[p]; i++) {
                snprintf(using, sizeof using, "%d", pc[i] + 1);
                gp_line(f, dat, using, style, t->cols[pc[i]].name, i == 0);
            }
            fputc('\n', f);
            break;
        case P_MOMENTUM:
            gp_begin(f, png_tmp[p], "", "", KEY_RIGHT);
            write_momentum(f, dat, t, pc, n[p], style);
            break;
        case P_LEDGER: {
            gp_begin(f, png_tmp[p], "Volume ledger: bulk + film + pools + removed - emitted = initial", "volume (m³)",
                     KEY_BELOW);
            /* the film holds a thousandth of the bulk: a log axis shows both; a part that stays 0 draws nothing */
            fputs("set logscale y\nset format y '%.0e'\nset ytics nomirror\nset y2tics\nset format y2 '%.0e'\n"
                  "set y2label '(total - initial) / initial (right axis)'\n", f);
            bool first = true;
            for (int i = 0; i < n[p]; i++) {
                const char *name = t->cols[pc[i]].name;
                bool err_col = !strcmp(name, "volume_error");
                char style_i[96], title[600];
                if (err_col) snprintf(using, sizeof using, "%d", pc[i] + 1);
                else snprintf(using, sizeof using, "($%d > 0 ? $%d : NaN)", pc[i] + 1, pc[i] + 1);
                snprintf(style_i, sizeof style_i, "%s axes x1%s", err_col ? "lines lw 1 dt 2" : style,
                         err_col ? "y2" : "y1");
                snprintf(title, sizeof title, "%s%s", name, err_col ? " (right axis)" : "");
                gp_line(f, dat, using, style_i, title, first);
                first = false;
            }
            fputc('\n', f);
            break;
        }
        }
    }
    fputs("unset output\n", f); /* closes the last PNG before gnuplot exits */
    free(cols);
    bool bad = ferror(f) != 0;
    if (fclose(f) != 0 || bad)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write %s; check free space in $TMPDIR", path);
    return DR_OK;
}

/* ---- running gnuplot -------------------------------------------------------------------------- */

static bool gnuplot_on_path(void)
{
    const char *path = getenv("PATH");
    if (!path) path = "/usr/bin:/bin";
    char exe[DR_IO_PATH_MAX];
    for (const char *p = path;; p += strcspn(p, ":") + 1) {
        int len = (int)strcspn(p, ":");
        /* an empty PATH entry means the current directory */
        if (len) snprintf(exe, sizeof exe, "%.*s/gnuplot", len, p);
        else snprintf(exe, sizeof exe, "./gnuplot");
        if (access(exe, X_OK) == 0) return true;
        if (!p[len]) return false;
    }
}

/* The last few hundred characters of gnuplot's log on one line (its caret diagrams span lines). */
static void log_tail(const char *log, char *buf, size_t size)
{
    char *text = NULL;
    DrError ignored;
    if (dr_io_read_text(log, &text, &ignored) != DR_OK || !text[0]) {
        snprintf(buf, size, "(gnuplot printed nothing)");
        free(text);
        return;
    }
    size_t len = strlen(text), o = 0;
    const char *p = len > 600 ? text + len - 600 : text;
    for (; *p && o + 1 < size; p++) {
        bool space = (unsigned char)*p <= ' ';
        if (space && (o == 0 || buf[o - 1] == ' ')) continue;
        buf[o++] = space ? ' ' : *p;
    }
    while (o > 0 && buf[o - 1] == ' ') o--;
    buf[o] = '\0';
    free(text);
}

static DrStatus run_gnuplot(const char *script, const char *log, DrError *err)
{
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&fa, 1, log, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    char prog[] = "gnuplot";
    char *argv[] = {prog, (char *)script, NULL};
    pid_t pid;
    int rc = posix_spawnp(&pid, prog, &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc == ENOENT)
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "gnuplot is not on PATH, so the bake's plots cannot be "
                            "drawn; install Debian package gnuplot-nox (make deps)");
    if (rc != 0)
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "cannot start gnuplot: %s", strerror(rc));
    int status;
    while (waitpid(pid, &status, 0) < 0)
        if (errno != EINTR)
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "cannot wait for gnuplot: %s", strerror(errno));
    if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return DR_OK;
    char tail[1024], how[64];
    log_tail(log, tail, sizeof tail);
    if (WIFEXITED(status)) snprintf(how, sizeof how, "exited with status %d", WEXITSTATUS(status));
    else snprintf(how, sizeof how, "was killed by signal %d", WIFSIGNALED(status) ? WTERMSIG(status) : 0);
    return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "gnuplot %s while drawing the bake's plots: %s; check that "
                        "gnuplot has the pngcairo terminal (Debian package gnuplot-nox)", how, tail);
}

/* Removes the private temporary directory and whatever is in it (it holds only flat files). */
static void remove_tmpdir(const char *dir)
{
    DIR *d = opendir(dir);
    if (d) {
        char path[DR_IO_PATH_MAX + 256];
        for (struct dirent *e; (e = readdir(d));) {
            if (!strcmp(e->d_name, ".") || !strcmp(e->d_name, "..")) continue;
            snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
            unlink(path);
        }
        closedir(d);
    }
    rmdir(dir);
}

/* ---- the whole stage step --------------------------------------------------------------------- */

DrStatus plots_write(const char *progress_path, const char *out_dir, int *written, DrError *err)
{
    assert(progress_path && out_dir && written);
    *written = 0;
    /* before any work: without gnuplot nothing else here is of use */
    if (!gnuplot_on_path())
        return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "gnuplot is not on PATH, so the bake's plots cannot be "
                            "drawn; install Debian package gnuplot-nox (make deps)");
    if (strlen(out_dir) + 64 > DR_IO_PATH_MAX)
        return dr_error_set(err, DR_ERR_INPUT, out_dir, 0, 0, "the plots directory path is too long; use a shorter "
                            "output directory");
    Row *rows = NULL;
    int nrows = 0;
    Table t = {0};
    char tmpdir[DR_IO_PATH_MAX] = "", dat[DR_IO_PATH_MAX + 32], script[DR_IO_PATH_MAX + 32], log[DR_IO_PATH_MAX + 32];
    char png[NPLOTS][DR_IO_PATH_MAX], png_tmp[NPLOTS][DR_IO_PATH_MAX];
    bool made[NPLOTS] = {false}, pending[NPLOTS] = {false};

    DrStatus s = read_rows(progress_path, &rows, &nrows, err);
    if (s == DR_OK) {
        t.nrows = nrows;
        for (int r = 0; s == DR_OK && r < nrows; r++) s = table_set(&t, "frame", r, (double)rows[r].frame, err);
        for (int r = 0; s == DR_OK && r < nrows; r++) s = flatten(&t, r, "", rows[r].obj, err);
        if (s == DR_OK) split_hair_seconds(&t);
    }
    if (s == DR_OK) s = dr_io_mkdirs(out_dir, err);
    if (s == DR_OK) {
        dr_io_remove_stale_tmp(out_dir); /* PNGs of a render killed mid-gnuplot */
        for (int p = 0; p < NPLOTS; p++) {
            snprintf(png[p], sizeof png[p], "%s/%s.png", out_dir, plot_names[p]);
            dr_io_tmp_path(png[p], png_tmp[p], sizeof png_tmp[p]);
        }
        snprintf(tmpdir, sizeof tmpdir, "%s/drench-plots-XXXXXX", dr_temp_dir());
        if (!mkdtemp(tmpdir)) {
            s = dr_error_set(err, DR_ERR_IO, tmpdir, 0, 0,
                             "cannot create a temporary directory for the plots: %s; check $TMPDIR", strerror(errno));
            tmpdir[0] = '\0';
        }
    }
    if (s == DR_OK) {
        snprintf(dat, sizeof dat, "%s/progress.dat", tmpdir);
        snprintf(script, sizeof script, "%s/plots.gp", tmpdir);
        snprintf(log, sizeof log, "%s/gnuplot.log", tmpdir);
        s = write_dat(dat, &t, err);
    }
    if (s == DR_OK) s = write_script(script, dat, &t, png_tmp, made, err);
    bool any = false;
    for (int p = 0; p < NPLOTS; p++) any |= made[p];
    if (s == DR_OK && any) {
        for (int p = 0; p < NPLOTS; p++) pending[p] = made[p];
        s = run_gnuplot(script, log, err);
    }
    for (int p = 0; s == DR_OK && p < NPLOTS; p++) {
        if (!made[p]) {
            unlink(png[p]); /* a plot this bake does not have must not survive from an earlier one */
            continue;
        }
        s = dr_io_commit(png_tmp[p], png[p], err);
        pending[p] = false; /* dr_io_commit removes the temporary file itself when it fails */
        if (s == DR_OK) (*written)++;
    }
    for (int p = 0; p < NPLOTS; p++)
        if (pending[p]) unlink(png_tmp[p]);
    if (tmpdir[0]) remove_tmpdir(tmpdir);
    table_free(&t);
    for (int r = 0; r < nrows; r++) json_decref(rows[r].obj);
    free(rows);
    return s;
}
