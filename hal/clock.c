#include "hal/clock.h"

#include <ctype.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const int rev_f_4[] = {1, 1, 2, 5, 8, 8, 8, 10, 1};
static const int rev_f_6[] = {1, 1, 2, 6, 6, 6, 8, 8, 8, 8, 8, 10, 10, 10, 1};
static const int rev_f_11[] = {1, 1, 2, 16, 16, 16, 32, 32, 32, 32, 32, 32, 32, 32, 1};

wf_status wf_ma_from_counts(const char *name, const int *counts, int n, wf_ma_table *out)
{
    memset(out, 0, sizeof *out);
    snprintf(out->name, sizeof out->name, "%s", name);
    if (n < 1 || n > WF_MA_MAX_RESULTANTS)
        return wf_error(WF_ERR_RANGE, "MA table %s: %d resultants (allowed 1..%d)", name, n,
                        WF_MA_MAX_RESULTANTS);
    int read = 0;
    for (int r = 0; r < n; r++) {
        if (counts[r] < 1)
            return wf_error(WF_ERR_RANGE, "MA table %s: resultant %d has %d reads", name, r + 1,
                            counts[r]);
        out->first[r] = out->nreads;
        for (int j = 0; j < counts[r]; j++) {
            if (out->nreads >= WF_MA_MAX_READS)
                return wf_error(WF_ERR_RANGE, "MA table %s: more than %d reads", name,
                                WF_MA_MAX_READS);
            out->read[out->nreads++] = read++;
        }
    }
    out->first[n] = out->nreads;
    out->nresultants = n;
    return WF_OK;
}

wf_status wf_ma_builtin(const char *name, wf_ma_table *out)
{
    if (!strcmp(name, "4"))
        return wf_ma_from_counts("4", rev_f_4, (int)(sizeof rev_f_4 / sizeof *rev_f_4), out);
    if (!strcmp(name, "6"))
        return wf_ma_from_counts("6", rev_f_6, (int)(sizeof rev_f_6 / sizeof *rev_f_6), out);
    if (!strcmp(name, "11"))
        return wf_ma_from_counts("11", rev_f_11, (int)(sizeof rev_f_11 / sizeof *rev_f_11), out);
    return wf_error(WF_ERR_INPUT, "unknown built-in MA table '%s' (built in: 4, 6, 11; or give a file)",
                    name);
}

wf_status wf_ma_load(const char *path, wf_ma_table *out)
{
    memset(out, 0, sizeof *out);
    FILE *f = fopen(path, "r");
    if (!f)
        return wf_error(WF_ERR_IO, "%s: cannot open MA table file", path);
    const char *base = strrchr(path, '/');
    snprintf(out->name, sizeof out->name, "%s", base ? base + 1 : path);
    char line[4096];
    int lineno = 0, last = -1;
    wf_status st = WF_OK;
    while (fgets(line, sizeof line, f)) {
        lineno++;
        char *hash = strchr(line, '#');
        if (hash) *hash = '\0';
        char *p = line;
        int count = 0;
        while (*p) {
            while (*p && (isspace((unsigned char)*p) || *p == ',')) p++;
            if (!*p) break;
            char *end;
            long a = strtol(p, &end, 10), b;
            if (end == p) {
                st = wf_error(WF_ERR_INPUT, "%s:%d: expected a read number, found '%.20s'", path, lineno, p);
                goto done;
            }
            p = end;
            b = a;
            if (*p == '-') {
                b = strtol(p + 1, &end, 10);
                if (end == p + 1) {
                    st = wf_error(WF_ERR_INPUT, "%s:%d: range without an end", path, lineno);
                    goto done;
                }
                p = end;
            }
            if (*p && !isspace((unsigned char)*p) && *p != ',') {
                st = wf_error(WF_ERR_INPUT, "%s:%d: unexpected character '%c'", path, lineno, *p);
                goto done;
            }
            if (a < 1 || b < a) {
                st = wf_error(WF_ERR_RANGE, "%s:%d: bad read range %ld-%ld (reads count from 1)", path, lineno, a, b);
                goto done;
            }
            /* the readout maps every read to its resultant in a table of this length */
            if (b > WF_MA_MAX_READS) {
                st = wf_error(WF_ERR_RANGE, "%s:%d: read %ld past the %d reads an exposure may take", path, lineno,
                              b, WF_MA_MAX_READS);
                goto done;
            }
            if (count == 0) {
                if (out->nresultants >= WF_MA_MAX_RESULTANTS) {
                    st = wf_error(WF_ERR_RANGE, "%s:%d: more than %d resultants", path, lineno, WF_MA_MAX_RESULTANTS);
                    goto done;
                }
                out->first[out->nresultants++] = out->nreads;
            }
            for (long r = a; r <= b; r++) {
                if (r - 1 <= last) {
                    st = wf_error(WF_ERR_INPUT, "%s:%d: read %ld not after read %d: reads must increase", path, lineno, r, last + 1);
                    goto done;
                }
                if (out->nreads >= WF_MA_MAX_READS) {
                    st = wf_error(WF_ERR_RANGE, "%s:%d: more than %d reads", path, lineno, WF_MA_MAX_READS);
                    goto done;
                }
                out->read[out->nreads++] = (int)(r - 1);
                last = (int)(r - 1);
                count++;
            }
        }
    }
    if (ferror(f))
        st = wf_error(WF_ERR_IO, "%s: read error", path);
    else if (out->nresultants == 0)
        st = wf_error(WF_ERR_INPUT, "%s: no resultants in MA table file", path);
    out->first[out->nresultants] = out->nreads;
done:
    fclose(f);
    return st;
}

wf_status wf_ma_resolve(const char *spec, wf_ma_table *out)
{
    if (!strcmp(spec, "4") || !strcmp(spec, "6") || !strcmp(spec, "11"))
        return wf_ma_builtin(spec, out);
    return wf_ma_load(spec, out);
}

int wf_ma_total_reads(const wf_ma_table *ma)
{
    return ma->nreads ? ma->read[ma->nreads - 1] + 1 : 0;
}

double wf_clock_read_time(const wf_clock *clock, int read)
{
    return (read + 1) * clock->frame_time;
}

double wf_clock_resultant_time(const wf_clock *clock, int r)
{
    const wf_ma_table *ma = &clock->ma;
    double sum = 0.0;
    for (int j = ma->first[r]; j < ma->first[r + 1]; j++)
        sum += wf_clock_read_time(clock, ma->read[j]);
    return sum / (ma->first[r + 1] - ma->first[r]);
}

double wf_clock_exposure_time(const wf_clock *clock)
{
    return wf_ma_total_reads(&clock->ma) * clock->frame_time;
}
