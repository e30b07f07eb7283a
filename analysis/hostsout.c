/* `wfisim hosts`: one row per SN, the counts, and the four files (analysis/hosts.h). Every
 * file is written whole beside its name first; the four are renamed into place only when all
 * are written, so a failure leaves the folder as it was. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "analysis/hosts_int.h"
#include "analysis/plot.h"
#include "hal/file.h"

wf_status hosts_rows_push(hosts_rows *rows, const hosts_row *r)
{
    if (rows->n == rows->cap) {
        size_t nc = rows->cap ? 2 * rows->cap : 256;
        hosts_row *p = realloc(rows->v, nc * sizeof *p);
        if (!p) return wf_error(WF_ERR_NOMEM, "hosts: out of memory for %zu rows", nc);
        rows->v = p, rows->cap = nc;
    }
    rows->v[rows->n++] = *r;
    return WF_OK;
}

/* By SN, then the image farthest from the SN's edge first, then the earlier line. */
static int by_sn(const void *a, const void *b)
{
    const hosts_row *p = a, *q = b;
    if (p->sn != q->sn) return p->sn < q->sn ? -1 : 1;
    if (p->edge != q->edge) return p->edge > q->edge ? -1 : 1;
    return (p->line > q->line) - (p->line < q->line);
}

static const char *outcome_name(int k)
{
    static const char *names[] = {"correct", "wrong", "undetected", "host_outside", "hostless_none", "hostless_chosen"};
    return names[k];
}

static void count(const hosts_rows *rows, wf_hosts_summary *s)
{
    for (size_t i = 0; i < rows->n; i++) {
        const hosts_row *r = &rows->v[i];
        s->sne++;
        if (r->dlr_out == HOSTS_HOSTLESS_NONE || r->dlr_out == HOSTS_HOSTLESS_CHOSEN) {
            s->hostless++;
            s->hostless_dlr_chosen += r->dlr_out == HOSTS_HOSTLESS_CHOSEN;
            s->hostless_nearest_chosen += r->near_out == HOSTS_HOSTLESS_CHOSEN;
            continue;
        }
        if (r->dlr_out == HOSTS_OUTSIDE) { s->host_outside++; continue; }
        s->total++;
        if (r->dlr_out == HOSTS_UNDETECTED) { s->undetected++; continue; }
        s->dlr_correct += r->dlr_out == HOSTS_CORRECT;
        s->dlr_wrong += r->dlr_out == HOSTS_WRONG;
        s->dlr_none += r->dlr_out == HOSTS_WRONG && r->dlr_det < 0;
        s->nearest_correct += r->near_out == HOSTS_CORRECT;
        s->nearest_wrong += r->near_out == HOSTS_WRONG;
        s->nearest_none += r->near_out == HOSTS_WRONG && r->near_det < 0;
    }
}

static void num(FILE *f, const char *fmt, double v)
{
    fputc(',', f);
    if (isfinite(v)) fprintf(f, fmt, v);
}

static void id(FILE *f, long long v)
{
    fputc(',', f);
    if (v >= 0) fprintf(f, "%lld", v);
}

static void write_rows(FILE *f, const hosts_rows *rows)
{
    fputs("sn_id,z,ra,dec,line,true_host_id,host_det_id,host_sep_arcsec,host_d_dlr,"
          "dlr_det_id,dlr_galaxy_id,dlr_sep_arcsec,dlr_d_dlr,dlr_outcome,"
          "nearest_det_id,nearest_galaxy_id,nearest_sep_arcsec,nearest_d_dlr,nearest_outcome\n", f);
    for (size_t i = 0; i < rows->n; i++) {
        const hosts_row *r = &rows->v[i];
        fprintf(f, "%lld,%.6f,%.8f,%.8f,%d", r->sn, r->z, r->ra, r->dec, r->line);
        id(f, r->host), id(f, r->host_det_id);
        num(f, "%.4f", r->host_sep), num(f, "%.4f", r->host_ddlr);
        id(f, r->dlr_det_id), id(f, r->dlr_gal);
        num(f, "%.4f", r->dlr_sep), num(f, "%.4f", r->dlr_ddlr);
        fprintf(f, ",%s", outcome_name(r->dlr_out));
        id(f, r->near_det_id), id(f, r->near_gal);
        num(f, "%.4f", r->near_sep), num(f, "%.4f", r->near_ddlr);
        fprintf(f, ",%s\n", outcome_name(r->near_out));
    }
}

/* Counts per redshift bin: hosts (SNe with a true host in the image), then the outcomes. */
enum { B_HOSTS, B_DLR_OK, B_DLR_WRONG, B_NEAR_OK, B_NEAR_WRONG, B_UNDET, B_HOSTLESS, NB };

static int nbins(const hosts_rows *rows, double zbin)
{
    double zmax = 0;
    for (size_t i = 0; i < rows->n; i++) zmax = fmax(zmax, rows->v[i].z);
    int n = (int)floor(zmax / zbin) + 1;
    return n < 1 ? 1 : n > 10000 ? 10000 : n;
}

static wf_status bin_counts(const hosts_rows *rows, double zbin, int nb, long (**out)[NB])
{
    long (*b)[NB] = calloc((size_t)nb, sizeof *b);
    if (!b) return wf_error(WF_ERR_NOMEM, "hosts: out of memory");
    for (size_t i = 0; i < rows->n; i++) {
        const hosts_row *r = &rows->v[i];
        int k = (int)floor(r->z / zbin);
        if (k >= nb) k = nb - 1;
        if (r->dlr_out == HOSTS_HOSTLESS_NONE || r->dlr_out == HOSTS_HOSTLESS_CHOSEN) { b[k][B_HOSTLESS]++; continue; }
        if (r->dlr_out == HOSTS_OUTSIDE) continue;
        b[k][B_HOSTS]++;
        b[k][B_UNDET] += r->dlr_out == HOSTS_UNDETECTED;
        b[k][B_DLR_OK] += r->dlr_out == HOSTS_CORRECT;
        b[k][B_DLR_WRONG] += r->dlr_out == HOSTS_WRONG;
        b[k][B_NEAR_OK] += r->near_out == HOSTS_CORRECT;
        b[k][B_NEAR_WRONG] += r->near_out == HOSTS_WRONG;
    }
    *out = b;
    return WF_OK;
}

static void write_by_z(FILE *f, long (*b)[NB], int nb, double zbin)
{
    fputs("z_lo,z_hi,hosts,dlr_correct,dlr_wrong,nearest_correct,nearest_wrong,undetected,"
          "frac_dlr_correct,frac_dlr_wrong,frac_nearest_correct,frac_nearest_wrong,frac_undetected,hostless\n", f);
    for (int k = 0; k < nb; k++) {
        long n = b[k][B_HOSTS];
        fprintf(f, "%.4f,%.4f,%ld,%ld,%ld,%ld,%ld,%ld", k * zbin, (k + 1) * zbin, n, b[k][B_DLR_OK],
                b[k][B_DLR_WRONG], b[k][B_NEAR_OK], b[k][B_NEAR_WRONG], b[k][B_UNDET]);
        const int cols[5] = {B_DLR_OK, B_DLR_WRONG, B_NEAR_OK, B_NEAR_WRONG, B_UNDET};
        for (int c = 0; c < 5; c++) num(f, "%.6f", n ? (double)b[k][cols[c]] / n : NAN);
        fprintf(f, ",%ld\n", b[k][B_HOSTLESS]);
    }
}

static void write_json(FILE *f, const wf_hosts_summary *s, const wf_hosts_options *o)
{
    fprintf(f, "{\n  \"hosts_total\": %ld,\n  \"hosts_correct\": %ld,\n  \"hosts_nearest_wrong\": %ld,\n"
               "  \"hosts_undetected\": %ld,\n",
            s->total, s->dlr_correct, s->nearest_wrong, s->undetected);
    fprintf(f, "  \"hosts_detected\": %ld,\n  \"hosts_dlr_correct\": %ld,\n  \"hosts_dlr_wrong\": %ld,\n"
               "  \"hosts_dlr_none\": %ld,\n  \"hosts_nearest_correct\": %ld,\n  \"hosts_nearest_none\": %ld,\n",
            s->total - s->undetected, s->dlr_correct, s->dlr_wrong, s->dlr_none, s->nearest_correct, s->nearest_none);
    fprintf(f, "  \"hosts_outside\": %ld,\n  \"sne_total\": %ld,\n  \"sne_hostless\": %ld,\n"
               "  \"hostless_dlr_chosen\": %ld,\n  \"hostless_nearest_chosen\": %ld,\n  \"sne_duplicates\": %ld,\n",
            s->host_outside, s->sne, s->hostless, s->hostless_dlr_chosen, s->hostless_nearest_chosen, s->duplicates);
    fprintf(f, "  \"images\": %ld,\n  \"detections\": %ld,\n  \"galaxies_matched\": %ld,\n"
               "  \"detections_excluded\": %ld,\n",
            s->images, s->detections, s->galaxies_matched, s->excluded);
    fprintf(f, "  \"radius_arcsec\": %.10g,\n  \"dlr_max\": %.10g,\n  \"sep_max_arcsec\": %.10g,\n  \"zbin\": %.10g\n}\n",
            o->radius, o->dlr_max, o->sep_max, o->zbin);
}

/* Fractions of the SNe with a true host, per bin, with binomial errors (bins without one:
 * no point). */
static wf_status plot(const char *path, long (*b)[NB], int nb, double zbin)
{
    double *x = malloc(nb * sizeof *x), *y = malloc(nb * sizeof *y), *e = malloc(nb * sizeof *e);
    wf_plot *p = NULL;
    wf_status st = x && y && e ? WF_OK : wf_error(WF_ERR_NOMEM, "hosts: out of memory");
    if (!st) st = wf_plot_create(760, 480, "SN host association", "redshift", "fraction of SNe with a host", &p);
    /* y up to 1.45: the legend (top right) sits above the fractions */
    if (!st) st = wf_plot_set_range(p, 0, nb * zbin, 0, 1.45);
    static const struct { int col; const char *label; } s[5] = {
        {B_DLR_OK, "DLR: host chosen"},
        {B_NEAR_OK, "nearest: host chosen"},
        {B_DLR_WRONG, "DLR: other or none"},
        {B_NEAR_WRONG, "nearest: other or none"},
        {B_UNDET, "host not detected"},
    };
    for (int k = 0; !st && k < 5; k++) {
        for (int i = 0; i < nb; i++) {
            long n = b[i][B_HOSTS];
            double f = n ? (double)b[i][s[k].col] / n : NAN;
            x[i] = (i + 0.5) * zbin, y[i] = f, e[i] = n ? sqrt(f * (1 - f) / n) : NAN;
        }
        st = wf_plot_series(p, x, y, e, nb, s[k].label, WF_PLOT_LINE | WF_PLOT_MARKERS | WF_PLOT_ERRORBARS);
    }
    if (!st) st = wf_plot_write_png(p, path);
    wf_plot_free(p);
    free(x), free(y), free(e);
    return st;
}

enum { F_CSV, F_BYZ, F_JSON, F_PNG, NF };

wf_status hosts_finish(hosts_rows *rows, const wf_hosts_options *o, wf_hosts_summary *sum, const char *out_dir)
{
    /* One row per SN: the image where it lies farthest from the edge. */
    qsort(rows->v, rows->n, sizeof *rows->v, by_sn);
    size_t k = 0;
    for (size_t i = 0; i < rows->n; i++)
        if (!k || rows->v[i].sn != rows->v[k - 1].sn) rows->v[k++] = rows->v[i];
    sum->duplicates = (long)(rows->n - k);
    rows->n = k;
    count(rows, sum);
    int nb = nbins(rows, o->zbin);
    long (*b)[NB] = NULL;
    wf_status st = bin_counts(rows, o->zbin, nb, &b);
    if (st) return st;

    char made[WF_PATH_MAX] = "";
    static const char *names[NF] = {"hosts.csv", "hosts_by_z.csv", "hosts_summary.json", "hosts.png"};
    char path[NF][WF_PATH_MAX + 64], tmp[NF][WF_PATH_MAX + 96];
    int have_tmp[NF] = {0};
    st = wf_file_make_dir_noting(out_dir, made);
    for (int i = 0; !st && i < NF; i++)
        if ((size_t)snprintf(path[i], sizeof path[i], "%s/%s", out_dir, names[i]) >= sizeof path[i])
            st = wf_error(WF_ERR_INPUT, "--out %s: path too long", out_dir);
    for (int i = 0; !st && i < F_PNG; i++) {
        FILE *f = NULL;
        if ((st = wf_file_text_open(path[i], tmp[i], sizeof tmp[i], &f))) break;
        have_tmp[i] = 1;
        if (i == F_CSV) write_rows(f, rows);
        else if (i == F_BYZ) write_by_z(f, b, nb, o->zbin);
        else write_json(f, sum, o);
        int bad = ferror(f);
        if (fclose(f) != 0 || bad) st = wf_error(WF_ERR_IO, "%s: write failed", tmp[i]);
    }
    /* the plot writer renames its own temporary file: onto a second temporary name here */
    if (!st) {
        snprintf(tmp[F_PNG], sizeof tmp[F_PNG], "%s.part", path[F_PNG]);
        st = plot(tmp[F_PNG], b, nb, o->zbin);
        have_tmp[F_PNG] = !st;
    }
    for (int i = 0; !st && i < NF; i++)
        if (!(st = wf_file_rename(tmp[i], path[i]))) have_tmp[i] = 0;
    for (int i = 0; i < NF; i++)
        if (have_tmp[i]) remove(tmp[i]);
    if (st && made[0]) wf_file_unmake_dir(out_dir, made);
    free(b);
    return st;
}
