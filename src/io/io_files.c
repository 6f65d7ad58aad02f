/* Atomic writes, directories, whole-file reads, stale temporary files and stage manifests. */
#include "io/io.h"

#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <time.h>
#include <unistd.h>

void dr_io_tmp_path(const char *final_path, char *buf, size_t size)
{
    int n = snprintf(buf, size, "%s.tmp.%ld", final_path, (long)getpid());
    assert(n >= 0 && (size_t)n < size);
}

bool dr_io_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

void dr_io_time_iso8601(char buf[32])
{
    time_t now = time(NULL);
    struct tm tm;
    gmtime_r(&now, &tm);
    strftime(buf, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
}

/* fsync of the directory entry is what makes a rename survive a power cut (POSIX leaves the
 * directory's durability to the directory's own fsync). */
static DrStatus fsync_parent_dir(const char *path, DrError *err)
{
    char dir[DR_IO_PATH_MAX];
    const char *slash = strrchr(path, '/');
    if (!slash) {
        snprintf(dir, sizeof dir, ".");
    } else if (slash == path) {
        snprintf(dir, sizeof dir, "/");
    } else {
        size_t len = (size_t)(slash - path);
        if (len >= sizeof dir)
            return dr_error_set(err, DR_ERR_IO, path, 0, 0, "path is too long (%zu bytes); use a shorter output path", len);
        memcpy(dir, path, len);
        dir[len] = '\0';
    }
    int fd = open(dir, O_RDONLY | O_DIRECTORY);
    if (fd < 0)
        return dr_error_set(err, DR_ERR_IO, dir, 0, 0, "cannot open directory to sync it: %s", strerror(errno));
    /* Some file systems (e.g. certain network mounts) refuse fsync on directories with EINVAL;
     * the rename has still happened, so that is not a failure of the write. */
    if (fsync(fd) != 0 && errno != EINVAL) {
        int e = errno;
        close(fd);
        return dr_error_set(err, DR_ERR_IO, dir, 0, 0, "cannot sync directory: %s; check the disk", strerror(e));
    }
    close(fd);
    return DR_OK;
}

DrStatus dr_io_commit(const char *tmp_path, const char *final_path, DrError *err)
{
    int fd = open(tmp_path, O_RDONLY);
    if (fd < 0) {
        int e = errno;
        unlink(tmp_path);
        return dr_error_set(err, DR_ERR_IO, final_path, 0, 0, "cannot reopen the temporary file %s: %s",
                            tmp_path, strerror(e));
    }
    if (fsync(fd) != 0) {
        int e = errno;
        close(fd);
        unlink(tmp_path);
        return dr_error_set(err, DR_ERR_IO, final_path, 0, 0,
                            "cannot flush the file to disk: %s; check free space and the disk", strerror(e));
    }
    close(fd);
    if (rename(tmp_path, final_path) != 0) {
        int e = errno;
        unlink(tmp_path);
        return dr_error_set(err, DR_ERR_IO, final_path, 0, 0,
                            "cannot rename the temporary file into place: %s; check permissions of the directory",
                            strerror(e));
    }
    return fsync_parent_dir(final_path, err);
}

DrStatus dr_io_write_text_atomic(const char *path, const char *text, DrError *err)
{
    char tmp[DR_IO_PATH_MAX];
    if (strlen(path) + 32 > sizeof tmp)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "path is too long; use a shorter output path");
    dr_io_tmp_path(path, tmp, sizeof tmp);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC, 0666);
    if (fd < 0)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot create %s: %s; check that the directory exists and is writable",
                            tmp, strerror(errno));
    size_t len = strlen(text), done = 0;
    while (done < len) {
        ssize_t w = write(fd, text + done, len - done);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) {
            int e = w < 0 ? errno : EIO;
            close(fd);
            unlink(tmp);
            return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write: %s; check free disk space", strerror(e));
        }
        done += (size_t)w;
    }
    if (close(fd) != 0) {
        int e = errno;
        unlink(tmp);
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write: %s; check free disk space", strerror(e));
    }
    return dr_io_commit(tmp, path, err);
}

DrStatus dr_io_mkdirs(const char *dir, DrError *err)
{
    char buf[DR_IO_PATH_MAX];
    size_t len = strlen(dir);
    if (len == 0) return DR_OK;
    if (len >= sizeof buf)
        return dr_error_set(err, DR_ERR_IO, dir, 0, 0, "directory path is too long; use a shorter path");
    memcpy(buf, dir, len + 1);
    /* Walk the components left to right, creating each missing one; "a//b" and a trailing '/' are
     * harmless because an empty component is skipped. */
    for (size_t i = 1; i <= len; i++) {
        if (buf[i] != '/' && buf[i] != '\0') continue;
        if (buf[i - 1] == '/') continue;
        char saved = buf[i];
        buf[i] = '\0';
        if (mkdir(buf, 0777) != 0) {
            int e = errno;
            struct stat st;
            if (e == EEXIST && stat(buf, &st) == 0 && S_ISDIR(st.st_mode)) {
                buf[i] = saved;
                continue;
            }
            if (e == EEXIST)
                return dr_error_set(err, DR_ERR_IO, buf, 0, 0,
                                    "exists and is not a directory, so %s cannot be created; move it away", dir);
            return dr_error_set(err, DR_ERR_IO, buf, 0, 0, "cannot create directory: %s; check permissions",
                                strerror(e));
        }
        buf[i] = saved;
    }
    return DR_OK;
}

DrStatus dr_io_read_text(const char *path, char **out, DrError *err)
{
    *out = NULL;
    FILE *f = fopen(path, "rb");
    if (!f)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot open file: %s; check the path", strerror(errno));
    size_t cap = 4096, len = 0;
    char *buf = malloc(cap);
    if (!buf) {
        fclose(f);
        return dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "out of memory reading the file");
    }
    for (;;) {
        if (len + 1 >= cap) {
            if (cap > SIZE_MAX / 2) {
                free(buf);
                fclose(f);
                return dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "file too large to read into memory");
            }
            char *nb = realloc(buf, cap * 2);
            if (!nb) {
                free(buf);
                fclose(f);
                return dr_error_set(err, DR_ERR_NOMEM, path, 0, 0, "out of memory reading the file");
            }
            buf = nb;
            cap *= 2;
        }
        size_t got = fread(buf + len, 1, cap - 1 - len, f);
        len += got;
        if (got == 0) break;
    }
    if (ferror(f)) {
        free(buf);
        fclose(f);
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "error while reading the file; check the disk");
    }
    fclose(f);
    buf[len] = '\0';
    *out = buf;
    return DR_OK;
}

/* Parses the pid of "<anything>.tmp.<digits>"; false when the name does not have that form. */
static bool parse_tmp_pid(const char *name, long *pid)
{
    const char *tag = NULL;
    for (const char *p = strstr(name, ".tmp."); p; p = strstr(p + 1, ".tmp.")) tag = p;
    if (!tag || tag == name) return false;
    const char *digits = tag + 5;
    if (!*digits) return false;
    for (const char *p = digits; *p; p++)
        if (!isdigit((unsigned char)*p)) return false;
    errno = 0;
    long v = strtol(digits, NULL, 10);
    if (errno == ERANGE || v <= 0) return false;
    *pid = v;
    return true;
}

void dr_io_remove_stale_tmp(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d) return;
    long self = (long)getpid();
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        long pid;
        if (!parse_tmp_pid(e->d_name, &pid) || pid == self) continue;
        /* kill(pid, 0) probes existence without sending anything: ESRCH means no such process.
         * A pid beyond pid_t's range cannot belong to a process either. EPERM means it runs
         * under another user, so the file is kept. */
        bool dead = (long)(pid_t)pid != pid || (kill((pid_t)pid, 0) != 0 && errno == ESRCH);
        if (!dead) continue;
        char path[DR_IO_PATH_MAX];
        int n = snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
        if (n < 0 || (size_t)n >= sizeof path) continue;
        struct stat st;
        if (lstat(path, &st) != 0 || !S_ISREG(st.st_mode)) continue;
        if (unlink(path) == 0)
            dr_log_debug("removed %s left by process %ld, which is no longer running", path, pid);
        else
            dr_log_debug("cannot remove stale %s: %s", path, strerror(errno));
    }
    closedir(d);
}

/* ---- manifests ---- */

static DrStatus manifest_path(const char *dir, char *buf, size_t size, DrError *err)
{
    int n = snprintf(buf, size, "%s/MANIFEST", dir);
    if (n < 0 || (size_t)n + 32 >= size)
        return dr_error_set(err, DR_ERR_IO, dir, 0, 0, "directory path is too long; use a shorter path");
    return DR_OK;
}

static bool is_hex(const char *s, size_t max_len)
{
    size_t n = strlen(s);
    if (n == 0 || n > max_len) return false;
    for (size_t i = 0; i < n; i++)
        if (!isxdigit((unsigned char)s[i])) return false;
    return true;
}

static DrStatus check_line(const char *dir, const char *what, const char *s, DrError *err)
{
    if (strpbrk(s, "\n\r"))
        return dr_error_set(err, DR_ERR_INPUT, dir, 0, 0,
                            "manifest %s \"%s\" contains a line break; a manifest field is one line", what, s);
    return DR_OK;
}

DrStatus dr_io_manifest_write(const char *dir, const char *stage, const char *key_hex, const char *scene_path,
                              const char *const *inputs, int ninputs, DrError *err)
{
    return dr_io_manifest_write_frames(dir, stage, key_hex, scene_path, 1, 0, inputs, ninputs, err);
}

DrStatus dr_io_manifest_write_frames(const char *dir, const char *stage, const char *key_hex, const char *scene_path,
                                     int first, int last, const char *const *inputs, int ninputs, DrError *err)
{
    assert(ninputs >= 0 && (ninputs == 0 || inputs));
    if (!is_hex(key_hex, 32))
        return dr_error_set(err, DR_ERR_INPUT, dir, 0, 0, "manifest key \"%s\" is not 1 to 32 hex digits", key_hex);
    DR_TRY(check_line(dir, "stage", stage, err));
    DR_TRY(check_line(dir, "scene", scene_path, err));
    size_t total = 256 + strlen(stage) + strlen(scene_path) + strlen(DR_VERSION);
    for (int i = 0; i < ninputs; i++) {
        DR_TRY(check_line(dir, "input", inputs[i], err));
        total += strlen(inputs[i]) + 8;
    }
    char path[DR_IO_PATH_MAX];
    DR_TRY(manifest_path(dir, path, sizeof path, err));
    DR_TRY(dr_io_mkdirs(dir, err));

    char *text;
    DR_TRY(dr_calloc(total, 1, &text, err));
    char when[32];
    dr_io_time_iso8601(when);
    size_t len = (size_t)snprintf(text, total, "key %s\nstage %s\ntime %s\ndrench_version %s\nscene %s\n", key_hex,
                                  stage, when, DR_VERSION, scene_path);
    if (first <= last) len += (size_t)snprintf(text + len, total - len, "frames %d-%d\n", first, last);
    for (int i = 0; i < ninputs; i++) len += (size_t)snprintf(text + len, total - len, "input %s\n", inputs[i]);
    assert(len < total);
    DrStatus s = dr_io_write_text_atomic(path, text, err);
    free(text);
    return s;
}

DrStatus dr_io_manifest_read_key(const char *dir, char key_out[33], bool *found, DrError *err)
{
    key_out[0] = '\0';
    *found = false;
    char path[DR_IO_PATH_MAX];
    DR_TRY(manifest_path(dir, path, sizeof path, err));
    FILE *f = fopen(path, "rb");
    if (!f) return DR_OK;
    char line[128];
    bool got = fgets(line, sizeof line, f) != NULL;
    fclose(f);
    if (!got || strncmp(line, "key ", 4) != 0) return DR_OK;
    char *key = line + 4;
    key[strcspn(key, "\r\n")] = '\0';
    if (!is_hex(key, 32)) return DR_OK;
    memcpy(key_out, key, strlen(key) + 1);
    *found = true;
    return DR_OK;
}

DrStatus dr_io_manifest_read(const char *dir, DrManifest *out, DrError *err)
{
    memset(out, 0, sizeof *out);
    char path[DR_IO_PATH_MAX];
    DR_TRY(manifest_path(dir, path, sizeof path, err));
    FILE *f = fopen(path, "rb");
    if (!f) return DR_OK;
    char line[4224];
    bool first_line = true, bad = false;
    while (fgets(line, sizeof line, f)) {
        line[strcspn(line, "\r\n")] = '\0';
        if (first_line) {
            first_line = false;
            bad = strncmp(line, "key ", 4) != 0 || !is_hex(line + 4, 32);
            if (bad) break;
            memcpy(out->key, line + 4, strlen(line + 4) + 1);
        } else if (strncmp(line, "frames ", 7) == 0) {
            char tail;
            bad = sscanf(line + 7, "%d-%d%c", &out->first, &out->last, &tail) != 2 || out->first > out->last;
            if (bad) break;
            out->has_frames = true;
        }
    }
    fclose(f);
    if (bad || first_line) memset(out, 0, sizeof *out);
    else out->found = true;
    return DR_OK;
}

DrStatus dr_io_manifest_remove(const char *dir, DrError *err)
{
    char path[DR_IO_PATH_MAX];
    DR_TRY(manifest_path(dir, path, sizeof path, err));
    if (unlink(path) != 0 && errno != ENOENT && errno != ENOTDIR)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot remove the manifest: %s; check permissions",
                            strerror(errno));
    return DR_OK;
}
