/* Work in a child process of its own (tools/isolate.h): a child that ends normally gives back
 * its status, message and result (and changes nothing of the parent's memory); one killed
 * by a signal or ending by exit() is reported as crashed, naming the work and the signal or
 * status; a child forked while another thread holds stderr's or FFTW's planner lock can
 * still take them. */
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <inttypes.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <unistd.h>

#include "sim/numeric/fftw_lock.h"
#include "tools/isolate.h"
#include "tests/testutil.h"

static int in_parent = 7; /* changed by the children: the parent must still read 7 */

typedef struct answer {
    int64_t pid;
    int64_t sum;
} answer;

static wf_status sum_fn(void *arg, void *out)
{
    int n = *(int *)arg;
    answer *a = out;
    in_parent = -1;
    a->pid = getpid();
    a->sum = 0;
    for (int k = 1; k <= n; k++) a->sum += (int64_t)k * k;
    return WF_OK;
}

static wf_status fail_fn(void *arg, void *out)
{
    (void)out;
    return wf_error(WF_ERR_INPUT, "row %d: no such filter", *(int *)arg);
}

static wf_status signal_fn(void *arg, void *out)
{
    (void)out;
    int sig = *(int *)arg;
    signal(sig, SIG_DFL); /* the signal itself, not a sanitizer's handler */
    raise(sig);
    return WF_OK;
}

static wf_status exit_fn(void *arg, void *out)
{
    (void)out;
    _exit(*(int *)arg); /* a library giving up on its own: no report (_exit: no sanitizer's exit check) */
}

/* A real invalid access (a page without access rights: no undefined behaviour for the
 * sanitizers to report first). */
static wf_status fault_fn(void *arg, void *out)
{
    (void)arg;
    (void)out;
    volatile int *p = mmap(NULL, 4096, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return WF_ERR_NOMEM;
    signal(SIGSEGV, SIG_DFL); /* the signal itself, not a sanitizer's report */
    return *p ? WF_OK : WF_ERR_INTERNAL;
}

START_TEST(normal_exit)
{
    int n = 1000;
    answer a = {0, 0};
    int crashed = -1;
    ck_assert_int_eq(wf_isolate_run("sum", sum_fn, &n, &a, sizeof a, &crashed), WF_OK);
    ck_assert_int_eq(crashed, 0);
    ck_assert_int_eq(a.sum, (int64_t)n * (n + 1) * (2 * n + 1) / 6);
    ck_assert_int_ne(a.pid, getpid()); /* made in another process ... */
    ck_assert_int_eq(in_parent, 7);    /* ... which changed nothing here */
}
END_TEST

/* The child's oom_score_adj, read by itself. */
static wf_status oom_fn(void *arg, void *out)
{
    (void)arg;
    FILE *f = fopen("/proc/self/oom_score_adj", "r");
    answer *a = out;
    a->sum = -2000;
    if (f) {
        if (fscanf(f, "%" SCNd64, &a->sum) != 1) a->sum = -3000;
        fclose(f);
    }
    return WF_OK;
}

/* The out-of-memory killer is pointed at the child: its score is the parent's + 500. */
START_TEST(oom_prefers_child)
{
    FILE *f = fopen("/proc/self/oom_score_adj", "r");
    if (!f) WF_SKIP("no /proc/self/oom_score_adj (not Linux)");
    int64_t mine = 0;
    ck_assert_int_eq(fscanf(f, "%" SCNd64, &mine), 1);
    fclose(f);
    answer a = {0, 0};
    int crashed = -1;
    ck_assert_int_eq(wf_isolate_run("oom", oom_fn, NULL, &a, sizeof a, &crashed), WF_OK);
    ck_assert_int_eq(a.sum, mine + 500 > 1000 ? 1000 : mine + 500);
}
END_TEST

START_TEST(own_failure)
{
    int row = 42;
    answer a = {-5, -5};
    int crashed = -1;
    ck_assert_int_eq(wf_isolate_run("plan", fail_fn, &row, &a, sizeof a, &crashed), WF_ERR_INPUT);
    ck_assert_int_eq(crashed, 0);
    ck_assert_str_eq(wf_error_message(), "row 42: no such filter");
    ck_assert(a.pid == -5 && a.sum == -5);
}
END_TEST

START_TEST(killed_by_signal)
{
    static const int sigs[] = {SIGKILL, SIGSEGV, SIGABRT, SIGBUS};
    static const char *const said[] = {"signal 9 (SIGKILL: the kernel's out-of-memory killer",
                                       "signal 11 (SIGSEGV", "signal 6 (SIGABRT", "signal 7 (SIGBUS"};
    for (int k = 0; k < 4; k++) {
        answer a = {-5, -5};
        int crashed = -1, sig = sigs[k];
        ck_assert_int_eq(wf_isolate_run("exposure 17 SCA 7", signal_fn, &sig, &a, sizeof a, &crashed), WF_ERR_INTERNAL);
        ck_assert_int_eq(crashed, 1);
        const char *m = wf_error_message();
        ck_assert_msg(!strncmp(m, "exposure 17 SCA 7: its process was killed by ", 45) && strstr(m, said[k]), "%s", m);
        ck_assert(a.pid == -5 && a.sum == -5);
    }
    int crashed = -1;
    answer a;
    ck_assert_int_eq(wf_isolate_run("fault", fault_fn, NULL, &a, sizeof a, &crashed), WF_ERR_INTERNAL);
    ck_assert_int_eq(crashed, 1);
    ck_assert_str_eq(wf_error_message(), "fault: its process was killed by signal 11 (SIGSEGV: an invalid memory access)");
}
END_TEST

START_TEST(exit_without_report)
{
    for (int code = 0; code <= 3; code += 3) {
        answer a = {-5, -5};
        int crashed = -1;
        char want[128];
        ck_assert_int_eq(wf_isolate_run("item", exit_fn, &code, &a, sizeof a, &crashed), WF_ERR_INTERNAL);
        ck_assert_int_eq(crashed, 1);
        snprintf(want, sizeof want, "item: its process exited with status %d before reporting its result", code);
        ck_assert_str_eq(wf_error_message(), want);
        ck_assert(a.pid == -5 && a.sum == -5);
    }
}
END_TEST

/* A result larger than a pipe holds (64 KiB) comes back whole. */
static wf_status big_fn(void *arg, void *out)
{
    size_t n = *(size_t *)arg;
    uint32_t *v = out;
    for (size_t k = 0; k < n; k++) v[k] = (uint32_t)(k * 2654435761u);
    return WF_OK;
}

START_TEST(large_result)
{
    size_t n = 1 << 20;
    uint32_t *v = calloc(n, sizeof *v);
    ck_assert_ptr_nonnull(v);
    int crashed = -1;
    ck_assert_int_eq(wf_isolate_run("big", big_fn, &n, v, n * sizeof *v, &crashed), WF_OK);
    ck_assert_int_eq(crashed, 0);
    size_t bad = 0;
    for (size_t k = 0; k < n; k++) bad += v[k] != (uint32_t)(k * 2654435761u);
    ck_assert_uint_eq(bad, 0);
    free(v);
}
END_TEST

/* Another thread takes and releases stderr's and FFTW's planner lock without pause: a child
 * forked while it holds one would wait for it forever (the test's timeout) without the
 * guard around fork(). */
static atomic_int stop_holding;

static void *holder(void *arg)
{
    (void)arg;
    struct timespec ts = {0, 20000};
    while (!atomic_load(&stop_holding)) {
        wf_fftw_lock();
        flockfile(stderr);
        nanosleep(&ts, NULL);
        funlockfile(stderr);
        wf_fftw_unlock();
    }
    return NULL;
}

static wf_status locks_fn(void *arg, void *out)
{
    (void)arg;
    wf_fftw_lock();
    flockfile(stderr);
    funlockfile(stderr);
    wf_fftw_unlock();
    ((answer *)out)->sum = 1;
    return WF_OK;
}

START_TEST(locks_held_elsewhere)
{
    pthread_t t;
    atomic_store(&stop_holding, 0);
    ck_assert_int_eq(pthread_create(&t, NULL, holder, NULL), 0);
    int ok = 0;
    for (int k = 0; k < 200; k++) {
        answer a = {0, 0};
        int crashed = -1;
        ok += wf_isolate_run("locks", locks_fn, NULL, &a, sizeof a, &crashed) == WF_OK && a.sum == 1;
    }
    atomic_store(&stop_holding, 1);
    pthread_join(t, NULL);
    ck_assert_int_eq(ok, 200);
}
END_TEST

/* The work's process tells its pid and waits forever. */
static wf_status sleeper_fn(void *arg, void *out)
{
    (void)out;
    pid_t me = getpid();
    if (write(*(int *)arg, &me, sizeof me) != sizeof me) return WF_ERR_IO;
    for (;;) pause();
}

/* 1 when the process is gone or a zombie. */
static int dead(pid_t pid)
{
    char path[64], line[256];
    snprintf(path, sizeof path, "/proc/%ld/stat", (long)pid);
    FILE *f = fopen(path, "r");
    if (!f) return 1;
    int z = fgets(line, sizeof line, f) && strstr(line, ") Z ");
    fclose(f);
    return z;
}

/* A parent killed (as mpirun kills its ranks) takes the work's process along. */
START_TEST(dies_with_parent)
{
    if (access("/proc/self/stat", R_OK)) WF_SKIP("no /proc (not Linux)");
    int fds[2];
    ck_assert_int_eq(pipe(fds), 0);
    pid_t mid = fork();
    ck_assert_int_ge(mid, 0);
    if (mid == 0) {
        answer a;
        int crashed;
        wf_isolate_run("sleeper", sleeper_fn, &fds[1], &a, sizeof a, &crashed);
        _exit(0);
    }
    pid_t worker = 0;
    ck_assert_int_eq(read(fds[0], &worker, sizeof worker), sizeof worker);
    ck_assert(!dead(worker));
    kill(mid, SIGKILL);
    ck_assert_int_eq(waitpid(mid, NULL, 0), mid);
    int gone = 0;
    for (int k = 0; k < 500 && !(gone = dead(worker)); k++) usleep(10000);
    kill(worker, SIGKILL); /* whatever happened, leave nothing running */
    ck_assert_msg(gone, "the work's process %ld outlived its parent", (long)worker);
}
END_TEST

/* A tail of 3 MiB (many pipe buffers) whose bytes follow a pattern, asked for by size. */
static wf_status big_tail(void *arg, void **tail, size_t *size)
{
    size_t n = *(size_t *)arg;
    unsigned char *t = malloc(n ? n : 1);
    if (!t) return WF_ERR_NOMEM;
    for (size_t k = 0; k < n; k++) t[k] = (unsigned char)(k * 2654435761u >> 13);
    *tail = n ? t : NULL;
    *size = n;
    if (!n) free(t);
    return WF_OK;
}

static wf_status tail_sum_fn(void *arg, void *out)
{
    int n = 10;
    (void)arg;
    return sum_fn(&n, out);
}

static wf_status tail_fail_fn(void *arg, void *out)
{
    int row = 3;
    (void)arg;
    return fail_fn(&row, out);
}

/* The child's tail arrives whole after its result, byte for byte, however large; none when
 * the child gives none or the work failed. */
START_TEST(tail_whole)
{
    size_t n = 3u << 20;
    answer a = {0, 0};
    void *tail = NULL;
    size_t size = 0;
    int crashed = -1;
    ck_assert_int_eq(wf_isolate_run_tail("tail", tail_sum_fn, big_tail, &n, &a, sizeof a, &tail, &size, &crashed),
                     WF_OK);
    ck_assert_int_eq(crashed, 0);
    ck_assert_int_eq(a.sum, 385); /* 1 + 4 + ... + 100 */
    ck_assert_ptr_nonnull(tail);
    ck_assert_uint_eq(size, n);
    const unsigned char *t = tail;
    size_t bad = 0;
    for (size_t k = 0; k < n; k++) bad += t[k] != (unsigned char)(k * 2654435761u >> 13);
    ck_assert_uint_eq(bad, 0);
    free(tail);
    n = 0;
    ck_assert_int_eq(wf_isolate_run_tail("tail", tail_sum_fn, big_tail, &n, &a, sizeof a, &tail, &size, &crashed),
                     WF_OK);
    ck_assert_ptr_null(tail);
    ck_assert_uint_eq(size, 0);
    n = 3u << 20;
    ck_assert_int_eq(wf_isolate_run_tail("tail", tail_fail_fn, big_tail, &n, &a, sizeof a, &tail, &size, &crashed),
                     WF_ERR_INPUT);
    ck_assert_int_eq(crashed, 0);
    ck_assert_ptr_null(tail);
    ck_assert_str_eq(wf_error_message(), "row 3: no such filter");
    /* a tail the caller does not take is read and dropped: the child is not left blocked */
    ck_assert_int_eq(wf_isolate_run_tail("tail", tail_sum_fn, big_tail, &n, &a, sizeof a, NULL, NULL, &crashed), WF_OK);
    ck_assert_int_eq(crashed, 0);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("isolate");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, normal_exit);
    tcase_add_test(tc, own_failure);
    tcase_add_test(tc, oom_prefers_child);
    tcase_add_test(tc, killed_by_signal);
    tcase_add_test(tc, exit_without_report);
    tcase_add_test(tc, large_result);
    tcase_add_test(tc, locks_held_elsewhere);
    tcase_add_test(tc, dies_with_parent);
    tcase_add_test(tc, tail_whole);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
