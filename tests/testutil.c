#include "tests/testutil.h"

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
