/* Logging with levels and progress reporting (bar on a terminal, lines otherwise, ALF_PROGRESS). */
#include "core.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/ioctl.h>
#include <sys/resource.h>
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

/* True while a progress bar occupies the terminal's last line: a log line clears it first. */
static atomic_bool g_bar_shown;

void dr_log(DrLogLevel level, const char *fmt, ...)
{
    if (level > dr_log_level()) return;
    static const char *names[] = {"error", "warning", "info", "debug"};
    char buf[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    /* one fprintf per message so lines from threads do not interleave mid-line; the bar is redrawn at the
       next step */
    fprintf(stderr, "%sdrench: %s: %s\n", atomic_exchange(&g_bar_shown, false) ? "\r\033[K" : "", names[level], buf);
}

long long dr_peak_rss_bytes(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) != 0) return 0;
    return (long long)ru.ru_maxrss * 1024; /* Linux reports kilobytes */
}

void dr_format_bytes(long long bytes, char *buf, size_t size)
{
    double b = (double)bytes;
    if (b < 1024.0 * 1024.0) snprintf(buf, size, "%.0f KiB", b / 1024.0);
    else if (b < 1024.0 * 1024.0 * 1024.0) snprintf(buf, size, "%.0f MiB", b / (1024.0 * 1024.0));
    else snprintf(buf, size, "%.1f GiB", b / (1024.0 * 1024.0 * 1024.0));
}

/* The terminal's width in columns: the tty's own, else $COLUMNS, else 80. */
static int terminal_columns(void)
{
    struct winsize ws;
    if (ioctl(fileno(stderr), TIOCGWINSZ, &ws) == 0 && ws.ws_col > 0) return ws.ws_col;
    const char *c = getenv("COLUMNS");
    int n = c ? atoi(c) : 0;
    return n > 0 ? n : 80;
}

void dr_progress_begin(DrProgress *p, const char *label, long total)
{
    memset(p, 0, sizeof *p);
    p->label = label;
    p->total = total > 0 ? total : 1;
    p->t_start = p->t_last = dr_time_now();
    p->last_percent = -1;
    bool shown = dr_log_level() >= DR_LOG_INFO;
    p->bar = shown && isatty(fileno(stderr)) && !getenv("CI");
    p->lines = shown && !p->bar;
    const char *alf = getenv("DRENCH_ALF_PROGRESS");
    if (alf && !strcmp(alf, "1")) p->alf = true;
    else if (alf && !strcmp(alf, "0")) p->alf = false;
    else p->alf = !isatty(fileno(stdout));
}

double dr_progress_eta(const DrProgress *p)
{
    if (p->done <= 0) return 0.0;
    long n = p->done < DR_PROGRESS_WINDOW ? p->done : DR_PROGRESS_WINDOW;
    double sum = 0.0;
    for (long i = 0; i < n; i++) sum += p->recent[i];
    long left = p->total - p->done;
    return left > 0 ? sum / (double)n * (double)left : 0.0;
}

static void fmt_seconds(double s, char *buf, size_t n)
{
    if (s < 60) snprintf(buf, n, "%.1fs", s);
    else if (s < 3600) snprintf(buf, n, "%dm%02ds", (int)(s / 60), (int)s % 60);
    else snprintf(buf, n, "%dh%02dm", (int)(s / 3600), ((int)s % 3600) / 60);
}

void dr_progress_step(DrProgress *p, const char *detail) { dr_progress_step_at(p, dr_time_now(), detail); }

void dr_progress_step_at(DrProgress *p, double now, const char *detail)
{
    p->recent[p->done % DR_PROGRESS_WINDOW] = now - p->t_last;
    p->t_last = now;
    p->done++;
    if (p->bar || p->lines) {
        double el = now - p->t_start;
        double rate = el > 0 ? (double)p->done / el : 0.0;
        char eta[32], rss[32];
        fmt_seconds(dr_progress_eta(p), eta, sizeof eta);
        dr_format_bytes(dr_peak_rss_bytes(), rss, sizeof rss);
        if (p->bar) {
            int width = 30, fill = (int)(width * (double)p->done / (double)p->total);
            char bar[64], line[1024];
            for (int i = 0; i < width; i++) bar[i] = i < fill ? '#' : '.';
            bar[width] = 0;
            int n = snprintf(line, sizeof line, "%s [%s] %ld/%ld %.2f/s ETA %s RSS %s  %s", p->label, bar, p->done,
                             p->total, rate, eta, rss, detail ? detail : "");
            /* cut to the terminal's width less one column: a line that reaches the last column wraps on
               some terminals, and a wrapped line cannot be redrawn with a carriage return */
            int cols = terminal_columns() - 1;
            if (n > cols && cols > 0) line[cols] = 0;
            fprintf(stderr, "\r%s\033[K", line);
            if (p->done >= p->total) {
                fputc('\n', stderr);
                atomic_store(&g_bar_shown, false);
            } else {
                atomic_store(&g_bar_shown, true);
            }
        } else {
            fprintf(stderr, "%s %ld/%ld%s%s ETA %s peak RSS %s\n", p->label, p->done, p->total, detail ? " " : "",
                    detail ? detail : "", eta, rss);
        }
        fflush(stderr);
    }
    int pct = (int)(100.0 * (double)p->done / (double)p->total);
    if (p->alf && pct != p->last_percent) {
        p->last_percent = pct;
        printf("ALF_PROGRESS %d%%\n", pct);
        fflush(stdout);
    }
}

void dr_progress_end(DrProgress *p)
{
    if (p->bar && p->done < p->total && atomic_exchange(&g_bar_shown, false)) fputc('\n', stderr);
}
