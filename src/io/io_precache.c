/* The content-addressed precompute cache (DESIGN §4, §5): <root>/<kind>/<key>.h5, each file carrying
 * the inputs that made it, and never trusted unless its recorded key is the one asked for. */
#include "io/io.h"

#include <ctype.h>
#include <stdlib.h>
#include <string.h>

void dr_io_precache_path(const char *root, const char *kind, const char *key_hex, char *buf, size_t size)
{
    int n = snprintf(buf, size, "%s/%s/%s.h5", root, kind, key_hex);
    assert(n >= 0 && (size_t)n < size);
}

static DrStatus check_kind_key(const char *root, const char *kind, const char *key_hex, DrError *err)
{
    if (strcmp(kind, "cohesion") != 0 && strcmp(kind, "bem") != 0)
        return dr_error_set(err, DR_ERR_INPUT, root, 0, 0,
                            "unknown precompute cache kind \"%s\"; expected \"cohesion\" or \"bem\"", kind);
    size_t n = strlen(key_hex);
    bool hex = n >= 1 && n <= 64;
    for (size_t i = 0; hex && i < n; i++) hex = isxdigit((unsigned char)key_hex[i]) != 0;
    /* The key becomes a file name, so anything but hex digits (a '/', "..") is refused outright. */
    if (!hex)
        return dr_error_set(err, DR_ERR_INPUT, root, 0, 0, "precompute cache key \"%s\" is not 1 to 64 hex digits",
                            key_hex);
    if (strlen(root) + 96 > DR_IO_PATH_MAX)
        return dr_error_set(err, DR_ERR_INPUT, root, 0, 0, "cache directory path is too long; use a shorter path");
    return DR_OK;
}

DrStatus dr_io_precache_create(const char *root, const char *kind, const char *key_hex, const char *inputs_json,
                               const char *asset_hash_hex, DrH5 **out, DrError *err)
{
    *out = NULL;
    DR_TRY(check_kind_key(root, kind, key_hex, err));
    char dir[DR_IO_PATH_MAX], path[DR_IO_PATH_MAX];
    snprintf(dir, sizeof dir, "%s/%s", root, kind);
    DR_TRY(dr_io_mkdirs(dir, err));
    dr_io_precache_path(root, kind, key_hex, path, sizeof path);

    DrH5 *h;
    DR_TRY(dr_h5_create(path, &h, err));
    char when[32];
    dr_io_time_iso8601(when);
    DrStatus s = dr_h5_attr_str(h, "/", "kind", kind, err);
    if (s == DR_OK) s = dr_h5_attr_str(h, "/", "key", key_hex, err);
    if (s == DR_OK) s = dr_h5_attr_str(h, "/", "inputs", inputs_json, err);
    if (s == DR_OK) s = dr_h5_attr_str(h, "/", "asset_hash", asset_hash_hex ? asset_hash_hex : "", err);
    if (s == DR_OK) s = dr_h5_attr_str(h, "/", "drench_version", DR_VERSION, err);
    if (s == DR_OK) s = dr_h5_attr_str(h, "/", "created", when, err);
    if (s != DR_OK) {
        dr_h5_close(&h);
        return s;
    }
    *out = h;
    return DR_OK;
}

/* True when the string attribute `name` of the root of h equals `expected`. */
static bool root_attr_is(DrH5 *h, const char *name, const char *expected)
{
    char *value = NULL;
    DrError ignored;
    if (dr_h5_read_attr_str(h, "/", name, &value, &ignored) != DR_OK) return false;
    bool same = strcmp(value, expected) == 0;
    free(value);
    return same;
}

DrStatus dr_io_precache_open(const char *root, const char *kind, const char *key_hex, DrH5 **out, bool *found,
                             DrError *rejected, DrError *err)
{
    *out = NULL;
    *found = false;
    if (rejected) dr_error_clear(rejected);
    DR_TRY(check_kind_key(root, kind, key_hex, err));
    char path[DR_IO_PATH_MAX];
    dr_io_precache_path(root, kind, key_hex, path, sizeof path);
    if (!dr_io_exists(path)) return DR_OK;

    DrH5 *h;
    DrError open_err;
    if (dr_h5_open(path, &h, &open_err) != DR_OK) {
        if (rejected) dr_error_set(rejected, DR_ERR_INPUT, path, 0, 0, "unreadable precompute cache file: %s",
                                   open_err.message);
        return DR_OK;
    }
    /* The file name alone is not proof: a file copied or renamed by hand, or written by a run that
     * died between naming and filling it, must not stand in for another computation. */
    if (!root_attr_is(h, "key", key_hex) || !root_attr_is(h, "kind", kind)) {
        if (rejected)
            dr_error_set(rejected, DR_ERR_INPUT, path, 0, 0,
                         "the precompute cache file records another key or kind than its name says");
        dr_h5_close(&h);
        return DR_OK;
    }
    *out = h;
    *found = true;
    return DR_OK;
}
