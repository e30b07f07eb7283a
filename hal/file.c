#include "hal/file.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

wf_status wf_file_make_dir_noting(const char *dir, char *made)
{
    char buf[WF_PATH_MAX];
    if (made) made[0] = '\0';
    if (strlen(dir) >= sizeof buf) return wf_error(WF_ERR_INPUT, "%.80s...: directory name too long", dir);
    snprintf(buf, sizeof buf, "%s", dir);
    /* every folder from the first one made down is new: the first is all undo needs */
    for (char *p = buf + 1;; p++)
        if (*p == '/' || !*p) {
            char c = *p;
            *p = '\0';
            if (mkdir(buf, 0777) == 0) {
                if (made && !made[0]) snprintf(made, WF_PATH_MAX, "%s", buf);
            } else if (errno != EEXIST) {
                wf_file_unmake_dir(dir, made);
                return wf_error(WF_ERR_IO, "%s: cannot create directory: %s", buf, strerror(errno));
            }
            *p = c;
            if (!c) break;
        }
    return WF_OK;
}

wf_status wf_file_make_dir(const char *dir) { return wf_file_make_dir_noting(dir, NULL); }

void wf_file_unmake_dir(const char *dir, const char *made)
{
    if (!made || !made[0]) return;
    char buf[WF_PATH_MAX];
    snprintf(buf, sizeof buf, "%s", dir);
    size_t keep = strlen(made);
    for (;;) {
        size_t n = strlen(buf);
        while (n > 1 && buf[n - 1] == '/') buf[--n] = '\0';
        /* rmdir takes only an empty folder: anything a run left in it stays */
        if (n < keep || rmdir(buf) != 0) return;
        char *slash = strrchr(buf, '/');
        if (!slash) return;
        *slash = '\0';
    }
}

wf_status wf_file_text_open(const char *path, char *tmp, size_t cap, FILE **out)
{
    *out = NULL;
    if ((size_t)snprintf(tmp, cap, "%s.tmp.XXXXXX", path) >= cap) return wf_error(WF_ERR_INPUT, "%s: path too long", path);
    int fd = mkstemp(tmp);
    if (fd < 0) return wf_error(WF_ERR_IO, "%s: cannot create a temporary file beside it", path);
    fchmod(fd, 0644); /* mkstemp's 0600 would be the file's mode after the rename */
    *out = fdopen(fd, "w");
    if (!*out) {
        close(fd);
        remove(tmp);
        return wf_error(WF_ERR_IO, "%s: cannot open", tmp);
    }
    return WF_OK;
}

wf_status wf_file_text_commit(FILE *out, const char *tmp, const char *path)
{
    int bad = ferror(out);
    if (fclose(out) != 0 || bad) {
        remove(tmp);
        return wf_error(WF_ERR_IO, "%s: write failed", tmp);
    }
    return wf_file_rename(tmp, path);
}

wf_status wf_file_rename(const char *tmp, const char *path)
{
    if (rename(tmp, path) == 0) return WF_OK;
    const int e = errno;
    remove(tmp);
    return wf_error(WF_ERR_IO, "%s: cannot rename %s into place: %s", path, tmp, strerror(e));
}
