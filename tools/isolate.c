#define _GNU_SOURCE /* pipe2 */
#include "tools/isolate.h"

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#ifdef __linux__
#include <sys/prctl.h>
#endif
#include <unistd.h>

#include "sim/numeric/fftw_lock.h"

/* What the child sends back: this header, the message, then (when it succeeded) the result
 * and the tail. */
typedef struct reply {
    int32_t status;
    uint32_t msglen;
    uint64_t taillen;
} reply;

static int write_all(int fd, const void *buf, size_t n)
{
    const char *p = buf;
    while (n) {
        ssize_t k = write(fd, p, n);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) return -1;
        p += k;
        n -= (size_t)k;
    }
    return 0;
}

/* Reads up to n bytes (fewer only at the end of the stream); the count read. */
static size_t read_all(int fd, void *buf, size_t n)
{
    char *p = buf;
    size_t got = 0;
    while (got < n) {
        ssize_t k = read(fd, p + got, n - got);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) break;
        got += (size_t)k;
    }
    return got;
}

/* The out-of-memory killer should take the work, not the process waiting for it (which shares
 * most of the child's pages and so scores alike): the child's score is raised by 500. */
static void prefer_for_oom(void)
{
    int fd = open("/proc/self/oom_score_adj", O_RDWR | O_CLOEXEC);
    if (fd < 0) return; /* not Linux: nothing to say */
    char buf[16] = "";
    ssize_t k = read(fd, buf, sizeof buf - 1);
    int adj = k > 0 ? atoi(buf) + 500 : 500;
    int n = snprintf(buf, sizeof buf, "%d", adj > 1000 ? 1000 : adj);
    if (lseek(fd, 0, SEEK_SET) != 0 || write(fd, buf, (size_t)n) != n) {} /* best effort */
    close(fd);
}

static void child(int fd, pid_t parent, wf_isolate_fn fn, wf_isolate_tail_fn tail_fn, void *arg, void *out,
                  size_t out_size)
{
#ifdef __linux__
    /* a parent killed (mpirun ending the job) takes its child along, rather than leave it
     * writing a product beside the rerun */
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (getppid() != parent) _exit(126);
#else
    (void)parent;
#endif
    prefer_for_oom();
    wf_status st = fn(arg, out);
    void *tail = NULL;
    size_t tail_size = 0;
    /* a tail that cannot be made (out of memory) is left out: the work itself is done */
    if (!st && tail_fn && tail_fn(arg, &tail, &tail_size)) {
        free(tail);
        tail = NULL;
        tail_size = 0;
    }
    const char *msg = st ? wf_error_message() : "";
    reply r = {(int32_t)st, (uint32_t)strlen(msg), (uint64_t)tail_size};
    int bad = write_all(fd, &r, sizeof r) || write_all(fd, msg, r.msglen) ||
              (!st && (write_all(fd, out, out_size) || write_all(fd, tail, tail_size)));
    _exit(bad ? 125 : 0);
}

static const char *signal_note(int sig)
{
    switch (sig) {
    case SIGKILL: return "SIGKILL: the kernel's out-of-memory killer sends it, as does kill -9";
    case SIGSEGV: return "SIGSEGV: an invalid memory access";
    case SIGBUS: return "SIGBUS: an invalid memory access, or a file mapped and cut short";
    case SIGABRT: return "SIGABRT: abort(), a failed assertion";
    case SIGFPE: return "SIGFPE: an arithmetic fault";
    case SIGILL: return "SIGILL: an illegal instruction (a build for another CPU?)";
    case SIGTERM: return "SIGTERM";
    case SIGINT: return "SIGINT";
    default: return "";
    }
}

wf_status wf_isolate_run(const char *what, wf_isolate_fn fn, void *arg, void *out, size_t out_size, int *crashed)
{
    return wf_isolate_run_tail(what, fn, NULL, arg, out, out_size, NULL, NULL, crashed);
}

wf_status wf_isolate_run_tail(const char *what, wf_isolate_fn fn, wf_isolate_tail_fn tail_fn, void *arg, void *out,
                              size_t out_size, void **tail, size_t *tail_size, int *crashed)
{
    *crashed = 0;
    if (tail) *tail = NULL;
    if (tail_size) *tail_size = 0;
    int fds[2];
    if (pipe2(fds, O_CLOEXEC) != 0) return wf_error(WF_ERR_IO, "%s: no pipe for its process: %s", what, strerror(errno));
    /* the locks another thread of ours may hold, held by this one across the fork: the
     * child then owns them, and releases them, instead of waiting on them forever. The
     * planner's first: a thread holding it may print. */
    fflush(stdout);
    fflush(stderr);
    wf_fftw_lock();
    flockfile(stdout);
    flockfile(stderr);
    pid_t parent = getpid(), pid = fork();
    int fork_errno = errno;
    funlockfile(stderr);
    funlockfile(stdout);
    wf_fftw_unlock();
    if (pid == 0) {
        close(fds[0]);
        child(fds[1], parent, fn, tail_fn, arg, out, out_size);
    }
    close(fds[1]);
    if (pid < 0) {
        close(fds[0]);
        return wf_error(WF_ERR_NOMEM, "%s: cannot start its process (fork: %s)", what, strerror(fork_errno));
    }
    reply r = {0, 0, 0};
    char msg[1024] = "";
    void *got = NULL; /* the tail, the caller's once the child is known to have ended well */
    size_t got_size = 0;
    int whole = read_all(fds[0], &r, sizeof r) == sizeof r;
    if (whole) {
        size_t keep = r.msglen < sizeof msg - 1 ? r.msglen : sizeof msg - 1;
        whole = read_all(fds[0], msg, keep) == keep;
        msg[keep] = '\0';
        for (size_t skip = r.msglen - keep; whole && skip;) { /* a message longer than we keep */
            char sink[256];
            size_t k = read_all(fds[0], sink, skip < sizeof sink ? skip : sizeof sink);
            whole = k > 0;
            skip -= k;
        }
        if (whole && !r.status) whole = read_all(fds[0], out, out_size) == out_size;
        /* the tail: as long as the child says, up to the end of its stream */
        void *t = whole && !r.status && r.taillen && tail ? malloc((size_t)r.taillen) : NULL;
        if (t && read_all(fds[0], t, (size_t)r.taillen) == r.taillen) {
            got = t;
            got_size = (size_t)r.taillen;
        } else {
            free(t);
            if (whole && !r.status && r.taillen) { /* unread: the child must not block on a full pipe */
                char sink[4096];
                while (read_all(fds[0], sink, sizeof sink) == sizeof sink) {}
            }
        }
    }
    close(fds[0]);
    int ws = 0;
    pid_t w;
    while ((w = waitpid(pid, &ws, 0)) < 0 && errno == EINTR) {}
    int wait_errno = errno;
    if (w < 0 || WIFSIGNALED(ws) || !WIFEXITED(ws) || WEXITSTATUS(ws) != 0 || !whole || r.status) free(got);
    if (w < 0) return wf_error(WF_ERR_INTERNAL, "%s: its process %ld was lost (waitpid: %s)", what, (long)pid,
                               strerror(wait_errno));
    if (WIFSIGNALED(ws)) {
        *crashed = 1;
        const char *note = signal_note(WTERMSIG(ws));
        return wf_error(WF_ERR_INTERNAL, "%s: its process was killed by signal %d%s%s%s", what, WTERMSIG(ws),
                        *note ? " (" : "", note, *note ? ")" : "");
    }
    if (!WIFEXITED(ws) || WEXITSTATUS(ws) != 0 || !whole) {
        *crashed = 1;
        return wf_error(WF_ERR_INTERNAL, "%s: its process exited with status %d before reporting its result", what,
                        WIFEXITED(ws) ? WEXITSTATUS(ws) : -1);
    }
    if (r.status) return wf_error((wf_status)r.status, "%s", msg);
    if (tail) {
        *tail = got;
        *tail_size = got_size;
    }
    return WF_OK;
}

typedef struct item_job {
    wf_survey_ctx *ctx;
    size_t i;
    unsigned long mark; /* the parent's cache at the fork */
} item_job;

/* WFISIM_TEST_CRASH_ITEM (tests only): the child of the item named dies by the signal asked. */
static void test_crash(const item_job *j)
{
    const char *hook = getenv("WFISIM_TEST_CRASH_ITEM");
    if (!hook || !*hook) return;
    int e, s;
    char how[16] = "kill", want[64], name[64];
    if (sscanf(hook, "%d:%d:%15s", &e, &s, how) < 2) return;
    snprintf(want, sizeof want, "exposure %d SCA %d", e, s);
    wf_survey_item_name(j->ctx, j->i, name, sizeof name);
    if (strcmp(want, name)) return;
    int sig = !strcmp(how, "segv") ? SIGSEGV : !strcmp(how, "abort") ? SIGABRT : SIGKILL;
    signal(sig, SIG_DFL); /* not a sanitizer's or MPI's handler: the signal itself ends it */
    raise(sig);
}

static wf_status make_item(void *arg, void *out)
{
    item_job *j = arg;
    test_crash(j);
    return wf_survey_make_item(j->ctx, j->i, out);
}

/* What the child drew for the item's persistence history, for the parent's cache. */
static wf_status item_tail(void *arg, void **tail, size_t *size)
{
    const item_job *j = arg;
    return wf_survey_history_export(j->ctx, j->mark, tail, size);
}

wf_status wf_survey_make_item_isolated(wf_survey_ctx *ctx, size_t i, wf_survey_item_result *res, int *crashed)
{
    *crashed = 0;
    memset(res, 0, sizeof *res);
    int built;
    wf_status st = wf_survey_item_before_fork(ctx, i, &built);
    if (st) return st;
    char name[64];
    wf_survey_item_name(ctx, i, name, sizeof name);
    item_job j = {ctx, i, wf_survey_history_mark(ctx)};
    void *tail = NULL;
    size_t size = 0;
    st = wf_isolate_run_tail(name, make_item, item_tail, &j, res, sizeof *res, &tail, &size, crashed);
    /* the next items of the SCA then draw only what is new; a tail not taken in costs only
     * that drawing again (the products are the same) */
    if (!st && tail) (void)wf_survey_history_import(ctx, tail, size);
    free(tail);
    if (!st && res->made) res->psf_built += built;
    return st;
}
