/* Logging with levels and progress reporting (bar on a terminal, lines otherwise, ALF_PROGRESS). */
#include "core.h"

#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>

static DrLogLevel g_level = DR_LOG_INFO; /* set once by the stage mains before any thread starts */
static bool g_level_from_env = false;

static void level_from_env(void)
{
    if (g_level_from_env) return;
    g_level_from_env = true;
    const char *e = getenv("DRENCH_LOG");
    if (!e) return;
    if (!strcasecmp(e, "debug")) g_level = DR_LOG_DEBUG;
    else if (!strcasecmp(e, "info")) g_level = DR_LOG_INFO;
    else if (!strcasecmp(e, "warn")) g_level = DR_LOG_WARN;
    else if (!strcasecmp(e, "error")) g_level = DR_LOG_ERROR;
}

void dr_log_set_level(DrLogLevel level)
{
    g_level_from_env = true;
    g_level = level;
}

DrLogLevel dr_log_level(void)
{
    level_from_env();
    return g_level;
}

void dr_log(DrLogLevel level, const char *fmt, ...)
{
    if (level > dr_log_level()) return;
    static const char *names[] = {"error", "warning", "info", "debug"};
    char buf[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    /* one fprintf per message so lines from threads do not interleave mid-line */
    fprintf(stderr, "drench: %s: %s\n", names[level], buf);
}

void dr_progress_begin(DrProgress *p, const char *label, long total)
{
    memset(p, 0, sizeof *p);
    p->label = label;
    p->total = total > 0 ? total : 1;
    p->t_start = dr_time_now();
    p->last_percent = -1;
    p->tty = isatty(fileno(stderr)) && !getenv("CI");
}

double dr_progress_eta(const DrProgress *p)
{
    if (p->done <= 0) return 0.0;
    double el = dr_time_now() - p->t_start;
    return el / (double)p->done * (double)(p->total - p->done);
}

static void fmt_seconds(double s, char *buf, size_t n)
{
    if (s < 60) snprintf(buf, n, "%.1fs", s);
    else if (s < 3600) snprintf(buf, n, "%dm%02ds", (int)(s / 60), (int)s % 60);
    else snprintf(buf, n, "%dh%02dm", (int)(s / 3600), ((int)s % 3600) / 60);
}

void dr_progress_step(DrProgress *p, const char *detail)
{
    p->done++;
    double el = dr_time_now() - p->t_start;
    double rate = el > 0 ? (double)p->done / el : 0.0;
    char eta[32];
    fmt_seconds(dr_progress_eta(p), eta, sizeof eta);
    int pct = (int)(100.0 * (double)p->done / (double)p->total);
    if (p->tty) {
        int width = 30, fill = (int)(width * (double)p->done / (double)p->total);
        char bar[64];
        for (int i = 0; i < width; i++) bar[i] = i < fill ? '#' : '.';
        bar[width] = 0;
        fprintf(stderr, "\r%s [%s] %ld/%ld %.2f/s ETA %s  %s\033[K", p->label, bar, p->done, p->total, rate,
                eta, detail ? detail : "");
        if (p->done >= p->total) fputc('\n', stderr);
    } else {
        fprintf(stderr, "%s %ld/%ld%s%s ETA %s\n", p->label, p->done, p->total, detail ? " " : "",
                detail ? detail : "", eta);
    }
    fflush(stderr);
    if (pct != p->last_percent) {
        p->last_percent = pct;
        printf("ALF_PROGRESS %d%%\n", pct);
        fflush(stdout);
    }
}

void dr_progress_end(DrProgress *p)
{
    if (p->tty && p->done < p->total) fputc('\n', stderr);
}
