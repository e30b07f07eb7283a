/* wf_median_float (sim/numeric/median.c) against medians worked by hand: odd and even counts,
 * unsorted and negative input, the two middle values averaged in double (16777216 and
 * 16777218 give 16777217, which a float cannot hold), one value, none. */
#include <math.h>

#include "sim/numeric/median.h"
#include "tests/testutil.h"

START_TEST(median_by_hand)
{
    float odd[5] = {3, -1, 7, 2, 5};
    ck_assert_double_eq(wf_median_float(odd, 5), 3.0);
    ck_assert(odd[0] == -1 && odd[4] == 7); /* sorted in place */
    float even[4] = {4, 1, 2, 3};
    ck_assert_double_eq(wf_median_float(even, 4), 2.5);
    float big[2] = {16777218.0f, 16777216.0f};
    ck_assert_double_eq(wf_median_float(big, 2), 16777217.0);
    float one[1] = {-0.25f};
    ck_assert_double_eq(wf_median_float(one, 1), -0.25);
    ck_assert(isnan(wf_median_float(one, 0)));
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("median");
    TCase *tc = tcase_create("median");
    tcase_add_test(tc, median_by_hand);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
