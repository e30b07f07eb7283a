/* The set-up's parallel loop (sim/numeric/parallel.h) and the arena's top split (hal/arena.h):
 * every task runs exactly once on a slot below the thread count; the error reported is
 * the lowest failing task's, with its message, whatever the timing; a split's memory lies
 * above everything kept from the bottom and comes back on join; an error message may wrap
 * the one in hand (hal/status.h). */
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hal/arena.h"
#include "sim/numeric/parallel.h"
#include "tests/testutil.h"

typedef struct counts {
    atomic_int runs[1000];
    atomic_int bad_slot;
    int threads, fail_from;
} counts;

static wf_status task_fn(void *ctx, int task, int slot)
{
    counts *c = ctx;
    if (slot < 0 || slot >= c->threads) atomic_store(&c->bad_slot, 1);
    atomic_fetch_add(&c->runs[task], 1);
    volatile double x = 0.0; /* a little work, so that threads overlap */
    for (int i = 0; i < 2000 * (task % 7 + 1); i++) x += i;
    if (c->fail_from >= 0 && task >= c->fail_from && task % 3 == 0)
        return wf_error(WF_ERR_RANGE, "task %d failed", task);
    return WF_OK;
}

START_TEST(every_task_once)
{
    for (int threads = 1; threads <= 5; threads++) {
        static counts c;
        memset(&c, 0, sizeof c);
        c.threads = threads;
        c.fail_from = -1;
        ck_assert_int_eq(wf_parallel_for(1000, threads, task_fn, &c), WF_OK);
        for (int t = 0; t < 1000; t++) ck_assert_msg(c.runs[t] == 1, "%d threads: task %d ran %d times", threads, t, c.runs[t]);
        ck_assert(!c.bad_slot);
    }
    ck_assert_int_eq(wf_parallel_for(0, 4, task_fn, NULL), WF_OK);
}
END_TEST

START_TEST(lowest_failure_reported)
{
    /* tasks 300, 303, 306, ... fail: 300's message, for any thread count, every time */
    for (int rep = 0; rep < 20; rep++)
        for (int threads = 1; threads <= 4; threads++) {
            static counts c;
            memset(&c, 0, sizeof c);
            c.threads = threads;
            c.fail_from = 300;
            ck_assert_int_eq(wf_parallel_for(1000, threads, task_fn, &c), WF_ERR_RANGE);
            ck_assert_msg(!strcmp(wf_error_message(), "task 300 failed"), "%d threads: '%s'", threads,
                          wf_error_message());
            for (int t = 0; t < 300; t++) ck_assert_int_eq(c.runs[t], 1); /* all before it ran */
        }
}
END_TEST

START_TEST(arena_split_top)
{
    static unsigned char mem[100000];
    wf_arena a, top;
    wf_arena_init(&a, mem + 3, sizeof mem - 3, "test"); /* unaligned on purpose */
    void *keep1, *scratch, *keep2;
    ck_assert_int_eq(wf_arena_alloc(&a, 1000, "kept", &keep1), WF_OK);
    ck_assert_int_eq(wf_arena_split(&a, 30000, "scratch", &top), WF_OK);
    ck_assert(top.capacity >= 30000 && top.capacity < 30000 + 64);
    ck_assert((uintptr_t)top.base % 64 == 0);
    ck_assert(top.base + top.capacity == mem + sizeof mem);
    ck_assert_int_eq(wf_arena_alloc(&top, 29000, "scratch", &scratch), WF_OK);
    /* the bottom may grow up to the split, not into it */
    ck_assert_int_eq(wf_arena_alloc(&a, 60000, "kept", &keep2), WF_OK);
    ck_assert((unsigned char *)keep2 + 60000 <= top.base);
    void *more;
    ck_assert_int_eq(wf_arena_alloc(&a, 10000, "too much", &more), WF_ERR_NOMEM);
    ck_assert(strstr(wf_error_message(), "too much"));
    wf_arena_join(&a, &top);
    ck_assert_int_eq((int)a.capacity, (int)(sizeof mem - 3));
    ck_assert(a.high_water >= (size_t)(top.base - a.base) + 29000);
    ck_assert_int_eq(wf_arena_alloc(&a, 10000, "after the join", &more), WF_OK);
    /* a split larger than the free space is refused, and the arena is unchanged */
    size_t cap = a.capacity;
    ck_assert_int_eq(wf_arena_split(&a, a.capacity - a.used + 1, "scratch", &top), WF_ERR_NOMEM);
    ck_assert(a.capacity == cap);
}
END_TEST

START_TEST(error_wraps_its_own_message)
{
    /* context added around the message in hand, as the planners do */
    wf_error(WF_ERR_RANGE, "inner reason %d", 7);
    ck_assert_int_eq(wf_error(WF_ERR_INPUT, "object %d of the scene: %s", 12, wf_error_message()), WF_ERR_INPUT);
    ck_assert_str_eq(wf_error_message(), "object 12 of the scene: inner reason 7");
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("parallel");
    TCase *tc = tcase_create("parallel");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, every_task_once);
    tcase_add_test(tc, lowest_failure_reported);
    tcase_add_test(tc, arena_split_top);
    tcase_add_test(tc, error_wraps_its_own_message);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
