/* Shared helpers for the Check suites. Each tests/test_*.c is one program whose main() calls
 * wf_test_main(suite). Tests that need ../shared data call WF_SKIP_UNLESS(dir) and are
 * reported as skipped (never silently passed) by tests/run-all.sh when it is absent. */
#ifndef WF_TESTUTIL_H
#define WF_TESTUTIL_H

#include <check.h>
#include <stdint.h>
#include <stdio.h>

/* $WFISIM_REFERENCE/galsim or ../shared/reference/galsim, NULL when absent. */
const char *wf_test_reference_dir(void);
/* $WFISIM_DATA or ../shared/data, NULL when absent. */
const char *wf_test_data_dir(void);
/* The wfisim program built beside the tests ($WFISIM_BIN), NULL when unknown. */
const char *wf_test_program(void);
/* A fresh empty directory under $TMPDIR for this test (removed by the runner's tmp). */
const char *wf_test_tmpdir(void);

/* The whole file, NUL-terminated (len may be NULL); NULL when unreadable. Caller frees. */
char *wf_test_slurp(const char *path, size_t *len);

/* The packet stream of one exposure of cfg through the whole readout (tools/expose.h) into
 * memory: every thread draws from a copy of *scene, noise of kind nk keyed by cfg's seed,
 * exposure and SCA. A Check assertion fails when the readout does; caller frees. */
struct wf_readout_config;
struct wf_clock;
struct wf_scene_source;
unsigned char *wf_test_expose_stream(const struct wf_readout_config *cfg, const struct wf_clock *clock,
                                     const struct wf_scene_source *scene, int noise_kind, int threads,
                                     size_t *len);

/* A Check assertion that files a and b both exist and hold the same bytes. */
void wf_test_assert_same_file(const char *a, const char *b);

/* Runs a shell command built like printf; its exit status (255 when it did not exit). */
int wf_test_run(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

/* RA, DEC, PA and MJD_MID of the first row of a plan's PLAN table (a Check assertion fails
 * when it cannot be read). */
void wf_test_plan_row0(const char *plan, double *ra, double *dec, double *pa, double *mjd);

/* 1 when the file exists and contains needle. */
int wf_test_file_contains(const char *path, const char *needle);

/* The number at a path of JSON keys (each searched inside the previous one's value), as in
 * the reference facts.json; NAN when absent. Enough for the reference files, not general. */
double wf_test_json_number(const char *text, const char *const *keys, int nkeys);

/* Test data, not simulation noise (that is hal/noise): splitmix64 words from the state *s,
 * and standard normals from two of them (Box-Muller). */
uint64_t wf_test_splitmix(uint64_t *s);
double wf_test_gauss(uint64_t *s);

#define WF_SKIP(reason)                                                        \
    do {                                                                       \
        printf("SKIP: %s: %s\n", __func__, (reason));                          \
        fflush(stdout);                                                        \
        return;                                                                \
    } while (0)

#define WF_SKIP_UNLESS(ptr, what)                                              \
    do {                                                                       \
        if (!(ptr)) WF_SKIP(what " not found (set WFISIM_REFERENCE / WFISIM_DATA)"); \
    } while (0)

int wf_test_main(Suite *suite);

#endif
