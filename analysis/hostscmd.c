/* `wfisim hosts --out DIR [options] LIST`: option parsing for analysis/hosts.c. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "analysis/hosts.h"

static const char *hosts_usage =
    "usage: wfisim hosts --out DIR [--radius 0.3] [--dlr-max 4] [--sep-max 5] [--zbin 0.25] LIST\n"
    "  (docs/ANALYSIS.md, \"wfisim hosts\")\n"
    "  LIST: one image a line, 'IMAGE DETCAT TRUTH[,TRUTH...]' ('#' comments, blank lines skipped):\n"
    "  the detected image (a coadd, SCI with a WCS), its `wfisim detect` catalog, and the truth\n"
    "  files of its inputs. Every SN in an image gets a host by nearest separation and by\n"
    "  d_DLR, checked against the detection of its true host.\n"
    "  --radius R     truth matching radius, arcsec [0.3]\n"
    "  --dlr-max D    largest d_DLR of a chosen host [4]\n"
    "  --sep-max S    largest separation of the nearest rule's host, arcsec [5]\n"
    "  --zbin W       redshift bin width of hosts_by_z.csv and hosts.png [0.25]\n"
    "  --quiet        no summary line\n"
    "  writes DIR/hosts.csv, DIR/hosts_by_z.csv, DIR/hosts_summary.json, DIR/hosts.png\n";

static int number(const char *opt, const char *val, double *out)
{
    char *end;
    if (!val) {
        fprintf(stderr, "wfisim hosts: %s needs a value\n", opt);
        return 2;
    }
    *out = strtod(val, &end);
    if (end == val || *end || !isfinite(*out) || !(*out > 0)) {
        fprintf(stderr, "wfisim hosts: %s '%s': not a number > 0\n", opt, val);
        return 2;
    }
    return 0;
}

int wf_cmd_hosts(int argc, char **argv)
{
    wf_hosts_options o;
    wf_hosts_defaults(&o);
    const char *list = NULL, *out = NULL;
    int rc = 0;
    for (int i = 0; i < argc && !rc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) { fputs(hosts_usage, stdout); return 0; }
        else if (!strcmp(a, "--quiet")) o.quiet = 1;
        else if (!strcmp(a, "--out")) {
            if (!v) { fprintf(stderr, "wfisim hosts: --out needs a folder\n"); return 2; }
            out = v, i++;
        } else if (!strcmp(a, "--radius")) rc = number(a, v, &o.radius), i++;
        else if (!strcmp(a, "--dlr-max")) rc = number(a, v, &o.dlr_max), i++;
        else if (!strcmp(a, "--sep-max")) rc = number(a, v, &o.sep_max), i++;
        else if (!strcmp(a, "--zbin")) rc = number(a, v, &o.zbin), i++;
        else if (a[0] == '-' && a[1] == '-') {
            fprintf(stderr, "wfisim hosts: unknown option '%s'\n%s", a, hosts_usage);
            return 2;
        } else if (!list) list = a;
        else { fprintf(stderr, "wfisim hosts: unexpected argument '%s'\n", a); return 2; }
    }
    if (rc) return rc;
    if (!list || !out) { fputs(hosts_usage, stderr); return 2; }
    wf_hosts_summary s;
    wf_status st = wf_hosts_run(list, out, &o, &s);
    if (st) {
        fprintf(stderr, "wfisim hosts: %s\n", wf_error_message()[0] ? wf_error_message() : wf_status_name(st));
        return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
    }
    if (!o.quiet)
        fprintf(stderr, "wfisim hosts: %ld SNe in %ld image(s), %ld with a host in the image: DLR %ld correct, %ld wrong; "
                "nearest %ld correct, %ld wrong; host undetected %ld -> %s\n", s.sne, s.images, s.total, s.dlr_correct,
                s.dlr_wrong, s.nearest_correct, s.nearest_wrong, s.undetected, out);
    return 0;
}
