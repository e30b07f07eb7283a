#include "tests/testutil.h"

#include "hal/link.h"
#include "tools/expose.h"

#include <fitsio.h>

#include <stdarg.h>
#include <sys/wait.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static const char *existing_dir(const char *env, const char *fallback, const char *sub)
{
    static _Thread_local char buf[3][4096];
    static _Thread_local int slot;
    char *out = buf[slot++ % 3];
    const char *base = getenv(env);
    if (!base || !*base) base = fallback;
    snprintf(out, sizeof buf[0], "%s%s%s", base, sub ? "/" : "", sub ? sub : "");
    struct stat st;
    return stat(out, &st) == 0 && S_ISDIR(st.st_mode) ? out : NULL;
}

const char *wf_test_reference_dir(void)
{
    return existing_dir("WFISIM_REFERENCE", "../shared/reference", "galsim");
}

const char *wf_test_data_dir(void) { return existing_dir("WFISIM_DATA", "../shared/data", NULL); }

const char *wf_test_program(void)
{
    const char *p = getenv("WFISIM_BIN");
    return p && *p && access(p, X_OK) == 0 ? p : NULL;
}

const char *wf_test_tmpdir(void)
{
    static _Thread_local char dir[4096];
    const char *t = getenv("TMPDIR");
    snprintf(dir, sizeof dir, "%s/wfisim-test-XXXXXX", t && *t ? t : "/tmp");
    return mkdtemp(dir);
}

int wf_test_main(Suite *suite)
{
    SRunner *sr = srunner_create(suite);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? EXIT_FAILURE : EXIT_SUCCESS;
}

char *wf_test_slurp(const char *path, size_t *len)
{
    FILE *fp = fopen(path, "rb");
    if (!fp) return NULL;
    fseek(fp, 0, SEEK_END);
    long n = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    char *s = malloc((size_t)n + 1);
    if (s && fread(s, 1, (size_t)n, fp) != (size_t)n) {
        free(s);
        s = NULL;
    }
    if (s) s[n] = '\0';
    if (s && len) *len = (size_t)n;
    fclose(fp);
    return s;
}

/* End (one past) of the JSON value starting at p (strings skipped, brackets matched). */
static const char *json_value_end(const char *p)
{
    int depth = 0;
    for (; *p; p++) {
        if (*p == '"') {
            for (p++; *p && *p != '"'; p++)
                if (*p == '\\' && p[1]) p++;
            if (!*p) return p;
            if (depth == 0) return p + 1;
        } else if (*p == '{' || *p == '[') depth++;
        else if (*p == '}' || *p == ']') {
            if (--depth <= 0) return p + 1;
        } else if (depth == 0 && (*p == ',' || *p == '\n')) return p;
    }
    return p;
}

/* The number at a path of keys, each searched inside the previous one's value; NAN when
 * absent. */
double wf_test_json_number(const char *text, const char *const *keys, int nkeys)
{
    const char *lo = text, *hi = text + strlen(text);
    for (int k = 0; k < nkeys; k++) {
        char pat[256];
        snprintf(pat, sizeof pat, "\"%s\"", keys[k]);
        const char *p = lo;
        for (;;) {
            p = strstr(p, pat);
            if (!p || p >= hi) return NAN;
            const char *q = p + strlen(pat);
            while (*q == ' ' || *q == '\t' || *q == '\n' || *q == '\r') q++;
            if (*q == ':') {
                q++;
                while (*q == ' ' || *q == '\t' || *q == '\n' || *q == '\r') q++;
                lo = q;
                hi = json_value_end(q);
                break;
            }
            p += strlen(pat);
        }
    }
    char *end;
    double v = strtod(lo, &end);
    return end == lo ? NAN : v;
}

int wf_test_run(const char *fmt, ...)
{
    char cmd[8192];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(cmd, sizeof cmd, fmt, ap);
    va_end(ap);
    ck_assert_msg(n > 0 && (size_t)n < sizeof cmd, "command longer than %zu characters", sizeof cmd);
    int rc = system(cmd);
    return WIFEXITED(rc) ? WEXITSTATUS(rc) : 255;
}

int wf_test_file_contains(const char *path, const char *needle)
{
    char *t = wf_test_slurp(path, NULL);
    int found = t && strstr(t, needle);
    free(t);
    return found;
}

void wf_test_plan_row0(const char *plan, double *ra, double *dec, double *pa, double *mjd)
{
    fitsfile *f;
    int status = 0, c;
    fits_open_file(&f, plan, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status);
    const char *names[4] = {"RA", "DEC", "PA", "MJD_MID"};
    double *out[4] = {ra, dec, pa, mjd};
    for (int k = 0; k < 4; k++) {
        fits_get_colnum(f, CASEINSEN, (char *)names[k], &c, &status);
        fits_read_col(f, TDOUBLE, c, 1, 1, 1, NULL, out[k], NULL, &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

void wf_test_assert_same_file(const char *a, const char *b)
{
    size_t la, lb;
    char *x = wf_test_slurp(a, &la), *y = wf_test_slurp(b, &lb);
    ck_assert_msg(x != NULL, "%s missing", a);
    ck_assert_msg(y != NULL, "%s missing", b);
    ck_assert_msg(la == lb && !memcmp(x, y, la), "%s and %s differ", a, b);
    free(x);
    free(y);
}

unsigned char *wf_test_expose_stream(const wf_readout_config *cfg, const wf_clock *clock,
                                     const wf_scene_source *scene, int noise_kind, int threads, size_t *len)
{
    ck_assert_int_le(threads, 8);
    wf_scene_source scenes[8];
    for (int i = 0; i < 8; i++) scenes[i] = *scene;
    wf_link_memory mem;
    wf_link link;
    wf_link_memory_open(&mem, &link);
    wf_expose_job job = {0};
    job.ro = *cfg;
    job.clock = *clock;
    job.noise = (wf_noise){(wf_noise_kind)noise_kind, cfg->seed, cfg->exposure, cfg->sca};
    job.scenes = scenes;
    job.threads = threads;
    job.link = &link;
    wf_status st = wf_expose_run(&job);
    ck_assert_msg(st == WF_OK, "expose: %s", wf_error_message());
    unsigned char *out = malloc(mem.len ? mem.len : 1);
    ck_assert(out != NULL);
    memcpy(out, mem.data, mem.len);
    *len = mem.len;
    wf_link_memory_close(&mem);
    return out;
}

uint64_t wf_test_splitmix(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

double wf_test_gauss(uint64_t *s)
{
    double u = ((double)(wf_test_splitmix(s) >> 11) + 0.5) / 9007199254740992.0;
    double v = (double)(wf_test_splitmix(s) >> 11) / 9007199254740992.0;
    return sqrt(-2.0 * log(u)) * cos(2.0 * M_PI * v);
}
