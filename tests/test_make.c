/* The build itself: the README's commands on a machine that has none of the build packages
 * yet (issue 27). tests/fresh_make.sh dry-runs `make demo` and `make test` in a copy of the
 * tree with a pkg-config that knows the packages only once the install step has run. And the
 * house's layers: tests/layers.sh checks that every include points down (issue 28 §3). */
#include "tests/testutil.h"

START_TEST(test_install_before_flags)
{
    /* The tests run from the repository's root (make test); the script beside this file. */
    int rc = wf_test_run("sh tests/fresh_make.sh");
    ck_assert_msg(rc == 0, "tests/fresh_make.sh exited %d (its reason is printed above)", rc);
}
END_TEST

START_TEST(test_includes_point_down)
{
    int rc = wf_test_run("sh tests/layers.sh");
    ck_assert_msg(rc == 0, "tests/layers.sh exited %d (the includes that point up are printed above)", rc);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("make");
    TCase *tc = tcase_create("make");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, test_install_before_flags);
    tcase_add_test(tc, test_includes_point_down);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
