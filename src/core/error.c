/* Status, error messages and checked allocation. */
#include "core.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

DrStatus dr_error_set(DrError *err, DrStatus status, const char *file, int line, int col,
                      const char *fmt, ...)
{
    if (!err) return status;
    err->status = status;
    err->line = line;
    err->col = col;
    snprintf(err->file, sizeof err->file, "%s", file ? file : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err->message, sizeof err->message, fmt, ap);
    va_end(ap);
    return status;
}

DrStatus dr_error_prefix(DrStatus s, DrError *err, const char *fmt, ...)
{
    if (s >= 0 || !err) return s;
    char msg[sizeof err->message];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (n < 0) return s;
    if ((size_t)n < sizeof msg) n += snprintf(msg + n, sizeof msg - (size_t)n, ": %s", err->message);
    if (n >= (int)sizeof msg) msg[sizeof msg - 2] = '.'; /* long messages keep their start */
    memcpy(err->message, msg, sizeof msg);
    return s;
}

void dr_error_clear(DrError *err)
{
    if (!err) return;
    memset(err, 0, sizeof *err);
}

void dr_error_format(const DrError *err, char *buf, size_t size)
{
    if (err->file[0] && err->line > 0)
        snprintf(buf, size, "%s:%d:%d: error: %s", err->file, err->line, err->col > 0 ? err->col : 1,
                 err->message);
    else if (err->file[0])
        snprintf(buf, size, "%s: error: %s", err->file, err->message);
    else
        snprintf(buf, size, "error: %s", err->message);
}

void dr_error_print(const char *prog, const DrError *err)
{
    char buf[4096];
    dr_error_format(err, buf, sizeof buf);
    fprintf(stderr, "%s: %s\n", prog, buf);
}

int dr_exit_code(DrStatus status)
{
    if (status >= 0) return 0;
    return status == DR_ERR_INPUT ? 2 : 1;
}

const char *dr_status_name(DrStatus status)
{
    switch (status) {
    case DR_OK: return "ok";
    case DR_WARN_NOT_CONVERGED: return "not converged";
    case DR_ERR_RUNTIME: return "runtime failure";
    case DR_ERR_INPUT: return "bad input";
    case DR_ERR_IO: return "i/o failure";
    case DR_ERR_NOMEM: return "out of memory";
    }
    return "unknown status";
}

bool dr_mul_overflows(size_t a, size_t b, size_t *out)
{
    if (a != 0 && b > SIZE_MAX / a) return true;
    if (out) *out = a * b;
    return false;
}

static _Atomic uint64_t g_allocs;

uint64_t dr_alloc_count(void) { return atomic_load_explicit(&g_allocs, memory_order_relaxed); }
void dr_alloc_count_add_(void) { atomic_fetch_add_explicit(&g_allocs, 1, memory_order_relaxed); }

DrStatus dr_calloc(size_t count, size_t size, void *out_ptr, DrError *err)
{
    dr_alloc_count_add_();
    void **out = (void **)out_ptr;
    size_t bytes;
    *out = NULL;
    if (dr_mul_overflows(count, size, &bytes))
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                            "allocation of %zu x %zu bytes overflows; reduce the problem size", count, size);
    if (bytes == 0) bytes = 1;
    *out = calloc(1, bytes);
    if (!*out)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                            "out of memory allocating %zu bytes; reduce resolution or particle count", bytes);
    return DR_OK;
}

DrStatus dr_realloc(size_t count, size_t size, void *inout_ptr, DrError *err)
{
    void **ptr = (void **)inout_ptr;
    size_t bytes;
    dr_alloc_count_add_();
    if (dr_mul_overflows(count, size, &bytes))
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                            "allocation of %zu x %zu bytes overflows; reduce the problem size", count, size);
    if (bytes == 0) bytes = 1;
    void *p = realloc(*ptr, bytes);
    if (!p)
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0,
                            "out of memory allocating %zu bytes; reduce resolution or particle count", bytes);
    *ptr = p;
    return DR_OK;
}

char *dr_strdup(const char *s)
{
    if (!s) return NULL;
    size_t n = strlen(s) + 1;
    dr_alloc_count_add_();
    char *d = malloc(n);
    if (d) memcpy(d, s, n);
    return d;
}
