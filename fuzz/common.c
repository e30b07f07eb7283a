/* Scratch files for the harnesses (fuzz/common.h). */
#include "fuzz/common.h"

#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static char dir[4096];

/* Removes everything inside path (files, and directories with their contents). */
static void empty_dir(const char *path)
{
    DIR *d = opendir(path);
    if (!d) return;
    struct dirent *e;
    char p[8192];
    while ((e = readdir(d))) {
        if (!strcmp(e->d_name, ".") || !strcmp(e->d_name, "..")) continue;
        snprintf(p, sizeof p, "%s/%s", path, e->d_name);
        if (unlink(p) != 0) {
            empty_dir(p);
            rmdir(p);
        }
    }
    closedir(d);
}

static void cleanup(void)
{
    if (!dir[0]) return;
    empty_dir(dir);
    rmdir(dir);
}

const char *fz_dir(void)
{
    if (!dir[0]) {
        const char *tmp = getenv("TMPDIR");
        snprintf(dir, sizeof dir, "%s/wfisim-fuzz-XXXXXX", tmp && *tmp ? tmp : "/tmp");
        if (!mkdtemp(dir)) {
            perror("fuzz: mkdtemp");
            abort();
        }
        atexit(cleanup);
    }
    return dir;
}

const char *fz_write(const char *name, const uint8_t *data, size_t size, char *out)
{
    snprintf(out, 4096, "%s/%s", fz_dir(), name);
    FILE *f = fopen(out, "wb");
    if (!f || (size && fwrite(data, 1, size, f) != size) || fclose(f) != 0) {
        perror("fuzz: scratch file");
        abort();
    }
    return out;
}

void fz_clean(const char *sub)
{
    char p[4096];
    snprintf(p, sizeof p, "%s/%s", fz_dir(), sub);
    empty_dir(p);
}

int fz_gzip_claims_too_much(const uint8_t *data, size_t size)
{
    if (size < 18 || data[0] != 0x1f || data[1] != 0x8b) return 0;
    const uint8_t *t = data + size - 4; /* ISIZE, little-endian */
    uint32_t isize = (uint32_t)t[0] | (uint32_t)t[1] << 8 | (uint32_t)t[2] << 16 | (uint32_t)t[3] << 24;
    return isize > (64u << 20);
}
