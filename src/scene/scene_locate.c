/* Line and column of a JSON path in the scene text. jansson keeps no positions for values, so
 * semantic errors re-scan the (already validated) text along the path: only on the error path, once.
 * Columns count characters (UTF-8 lead bytes), 1-based, as jansson's syntax errors do. */
#include "scene_internal.h"

#include <string.h>

typedef struct Scan {
    const char *t;
    size_t len, pos;
    int line, col; /* of t[pos] */
} Scan;

static int peek(const Scan *s) { return s->pos < s->len ? (unsigned char)s->t[s->pos] : -1; }

static void advance(Scan *s)
{
    if (s->pos >= s->len) return;
    unsigned char c = (unsigned char)s->t[s->pos++];
    if (c == '\n') {
        s->line++;
        s->col = 1;
    } else if ((c & 0xC0) != 0x80) {
        s->col++;
    }
}

static void skip_ws(Scan *s)
{
    for (int c = peek(s); c == ' ' || c == '\t' || c == '\n' || c == '\r'; c = peek(s)) advance(s);
}

static int hex4(const Scan *s, size_t at)
{
    if (at + 4 > s->len) return -1;
    int v = 0;
    for (size_t i = at; i < at + 4; i++) {
        char c = s->t[i];
        int d = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
        if (d < 0) return -1;
        v = v * 16 + d;
    }
    return v;
}

static int utf8_encode(unsigned cp, char out[4])
{
    if (cp < 0x80) { out[0] = (char)cp; return 1; }
    if (cp < 0x800) { out[0] = (char)(0xC0 | (cp >> 6)); out[1] = (char)(0x80 | (cp & 0x3F)); return 2; }
    if (cp < 0x10000) {
        out[0] = (char)(0xE0 | (cp >> 12));
        out[1] = (char)(0x80 | ((cp >> 6) & 0x3F));
        out[2] = (char)(0x80 | (cp & 0x3F));
        return 3;
    }
    out[0] = (char)(0xF0 | (cp >> 18));
    out[1] = (char)(0x80 | ((cp >> 12) & 0x3F));
    out[2] = (char)(0x80 | ((cp >> 6) & 0x3F));
    out[3] = (char)(0x80 | (cp & 0x3F));
    return 4;
}

/* At an opening quote: consumes the string; returns whether its decoded value equals `want` (which
 * may be NULL: just skip). */
static bool scan_string(Scan *s, const char *want)
{
    bool eq = want != NULL;
    size_t wi = 0;
    advance(s); /* " */
    for (;;) {
        int c = peek(s);
        if (c < 0) return false;
        if (c == '"') {
            advance(s);
            return eq && want[wi] == '\0';
        }
        char buf[4];
        int n = 1;
        if (c != '\\') {
            buf[0] = (char)c;
            advance(s);
        } else {
            advance(s);
            int e = peek(s);
            advance(s);
            switch (e) {
            case 'b': buf[0] = '\b'; break;
            case 'f': buf[0] = '\f'; break;
            case 'n': buf[0] = '\n'; break;
            case 'r': buf[0] = '\r'; break;
            case 't': buf[0] = '\t'; break;
            case 'u': {
                int cp = hex4(s, s->pos);
                if (cp < 0) return false;
                for (int i = 0; i < 4; i++) advance(s);
                if (cp >= 0xD800 && cp < 0xDC00 && peek(s) == '\\' && s->pos + 1 < s->len && s->t[s->pos + 1] == 'u') {
                    int lo = hex4(s, s->pos + 2);
                    if (lo >= 0xDC00 && lo < 0xE000) {
                        for (int i = 0; i < 6; i++) advance(s);
                        cp = 0x10000 + ((cp - 0xD800) << 10) + (lo - 0xDC00);
                    }
                }
                n = utf8_encode((unsigned)cp, buf);
                break;
            }
            default: buf[0] = (char)e; break; /* \" \\ \/ */
            }
        }
        for (int i = 0; i < n && eq; i++) {
            if (want[wi] != buf[i]) eq = false;
            else wi++;
        }
    }
}

static void skip_value(Scan *s)
{
    int depth = 0;
    do {
        int c = peek(s);
        if (c < 0) return;
        if (c == '"') {
            scan_string(s, NULL);
        } else if (c == '{' || c == '[') {
            depth++;
            advance(s);
        } else if (c == '}' || c == ']') {
            depth--;
            advance(s);
        } else if (depth == 0) { /* scalar at top: up to a delimiter */
            while ((c = peek(s)) >= 0 && !strchr(",}] \t\r\n", c)) advance(s);
        } else {
            advance(s);
        }
    } while (depth > 0);
}

typedef struct Found {
    int line, col;         /* deepest value found so far */
    int key_line, key_col; /* key of the last segment, when the full path is an object member */
    bool complete;
} Found;

/* At the start of a value; follows path[level..depth). */
static void descend(Scan *s, const DrJsonSeg *path, int depth, int level, Found *out)
{
    out->line = s->line;
    out->col = s->col;
    if (level == depth) {
        out->complete = true;
        return;
    }
    const DrJsonSeg *seg = &path[level];
    int open = peek(s);
    if ((open == '{') != (seg->key != NULL) || (open != '{' && open != '[')) return;
    advance(s);
    for (int index = 0;; index++) {
        skip_ws(s);
        int c = peek(s);
        if (c < 0 || c == '}' || c == ']') return;
        bool match;
        int kl = s->line, kc = s->col;
        if (open == '{') {
            if (c != '"') return;
            match = scan_string(s, seg->key);
            skip_ws(s);
            if (peek(s) != ':') return;
            advance(s);
            skip_ws(s);
        } else {
            match = index == seg->index;
        }
        if (match) {
            if (open == '{' && level + 1 == depth) {
                out->key_line = kl;
                out->key_col = kc;
            }
            descend(s, path, depth, level + 1, out);
            return;
        }
        skip_value(s);
        skip_ws(s);
        if (peek(s) != ',') return;
        advance(s);
    }
}

void dr_scene_locate_(const char *text, size_t len, const DrJsonSeg *path, int depth, bool at_key, int *line,
                      int *col)
{
    Scan s = {text, len, 0, 1, 1};
    Found f = {0};
    skip_ws(&s);
    if (peek(&s) >= 0) descend(&s, path, depth, 0, &f);
    *line = f.line;
    *col = f.col;
    if (at_key && f.complete && f.key_line > 0) {
        *line = f.key_line;
        *col = f.key_col;
    }
}
