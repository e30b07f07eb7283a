/* SN Ia rates, counts, redshifts and peak dates: see sim/sn/snrate.h and docs/SN_POPULATION.md. */
#include "sim/sn/snrate.h"
#include "sim/numeric/quadrature.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Widest table interval in z: sets the Hermite error h⁴/384 max|n‴| (see the header). */
#define STEP_Z 0.002
#define DEG (M_PI / 180.0)
#define MAX_TOKENS 8
#define FULL_SKY_DEG2 (4.0 * M_PI / (DEG * DEG))

void wf_sn_rng(uint64_t seed, uint32_t i, wf_sn_draw which, wf_rng *rng)
{
    wf_noise noise = {WF_NOISE_PHILOX, seed, 0, 0};
    wf_rng_init(rng, &noise, i, (uint32_t)which, WF_PURPOSE_SN);
}

/* ------------------------------------------------------------------ the law */

void wf_snrate_clear(wf_snrate *r) { memset(r, 0, sizeof *r); }

void wf_snrate_default(wf_snrate *r)
{
    wf_snrate_clear(r);
    r->n = 2;
    r->p[0] = (wf_snrate_piece){2.5e-5, 1.5, 0.0, 1.0};
    r->p[1] = (wf_snrate_piece){9.7e-5, -0.5, 1.0, 3.0};
}

/* One piece on its own; where names it ("rate piece 2", "file:7"). */
static wf_status check_piece(const wf_snrate_piece *pc, const char *where)
{
    if (!isfinite(pc->a) || pc->a < 0.0)
        return wf_error(WF_ERR_RANGE, "%s: field A: rate %g must be finite and >= 0", where,
                        pc->a);
    if (!isfinite(pc->b))
        return wf_error(WF_ERR_RANGE, "%s: field B: power %g must be finite", where, pc->b);
    if (!(pc->zlo >= 0.0 && pc->zlo < WF_COSMO_ZMAX))
        return wf_error(WF_ERR_RANGE, "%s: field zmin: %g is outside [0, %g)", where, pc->zlo,
                        WF_COSMO_ZMAX);
    if (!(pc->zhi > pc->zlo && pc->zhi <= WF_COSMO_ZMAX))
        return wf_error(WF_ERR_RANGE, "%s: field zmax: %g must be above zmin %g and <= %g", where,
                        pc->zhi, pc->zlo, WF_COSMO_ZMAX);
    return WF_OK;
}

static int overlaps(const wf_snrate_piece *a, const wf_snrate_piece *b)
{
    return a->zlo < b->zhi && b->zlo < a->zhi;
}

wf_status wf_snrate_validate(const wf_snrate *r)
{
    if (!r) return wf_error(WF_ERR_INPUT, "SN rate: no rate law given");
    if (r->n < 1 || r->n > WF_SNRATE_MAX_PIECES)
        return wf_error(WF_ERR_RANGE, "SN rate: %d pieces; need 1 to %d", r->n,
                        WF_SNRATE_MAX_PIECES);
    for (int i = 0; i < r->n; i++) {
        char where[64];
        snprintf(where, sizeof where, "SN rate piece %d", i + 1);
        wf_status st = check_piece(&r->p[i], where);
        if (st) return st;
        for (int j = 0; j < i; j++)
            if (overlaps(&r->p[i], &r->p[j]))
                return wf_error(WF_ERR_RANGE,
                                "SN rate piece %d: [%g, %g) overlaps piece %d [%g, %g)", i + 1,
                                r->p[i].zlo, r->p[i].zhi, j + 1, r->p[j].zlo, r->p[j].zhi);
    }
    return WF_OK;
}

typedef struct token {
    const char *s;
    int len, col; /* col: 1-based */
} token;

static int split(const char *text, token *tok, int max)
{
    int n = 0;
    const char *p = text;
    while (*p && *p != '#') {
        while (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n') p++;
        if (!*p || *p == '#') break;
        const char *s = p;
        while (*p && *p != '#' && *p != ' ' && *p != '\t' && *p != '\r' && *p != '\n') p++;
        if (n < max) tok[n] = (token){s, (int)(p - s), (int)(s - text) + 1};
        n++;
    }
    return n;
}

static int tok_is(const token *t, const char *word)
{
    return t->len == (int)strlen(word) && strncmp(t->s, word, (size_t)t->len) == 0;
}

wf_status wf_snrate_add_line(wf_snrate *r, const char *text, const char *file, int line)
{
    static const char *const field[4] = {"A", "B", "zmin", "zmax"};
    const char *f = file ? file : "rate";
    if (!r || !text) return wf_error(WF_ERR_INPUT, "%s:%d: no rate law or text given", f, line);
    token tok[MAX_TOKENS];
    /* nt counts every token; only the first MAX_TOKENS are kept, and at most the one after
     * zmax (index <= 6) is looked at */
    int nt = split(text, tok, MAX_TOKENS), k = 0;
    if (k < nt && tok_is(&tok[k], "DNDZ:")) k++;
    if (k >= nt)
        return wf_error(WF_ERR_INPUT, "%s:%d: empty rate line (expected POWERLAW2 A B zmin zmax)",
                        f, line);
    if (!tok_is(&tok[k], "POWERLAW2") && !tok_is(&tok[k], "POWERLAW2:"))
        return wf_error(WF_ERR_INPUT,
                        "%s:%d: column %d: unknown rate model '%.*s' (expected POWERLAW2 A B "
                        "zmin zmax)",
                        f, line, tok[k].col, tok[k].len, tok[k].s);
    k++;
    if (nt - k < 4)
        return wf_error(WF_ERR_INPUT,
                        "%s:%d: POWERLAW2 needs 4 fields A B zmin zmax; field %s is missing", f,
                        line, field[nt - k]);
    if (nt - k > 4) {
        const token *x = &tok[k + 4];
        return wf_error(WF_ERR_INPUT, "%s:%d: column %d: unexpected '%.*s' after field zmax", f,
                        line, x->col, x->len, x->s);
    }
    double v[4];
    for (int j = 0; j < 4; j++) {
        const token *t = &tok[k + j];
        char buf[64], *end;
        if (t->len >= (int)sizeof buf)
            return wf_error(WF_ERR_INPUT, "%s:%d: column %d: field %s: '%.20s...' is too long", f,
                            line, t->col, field[j], t->s);
        memcpy(buf, t->s, (size_t)t->len);
        buf[t->len] = '\0';
        errno = 0;
        v[j] = strtod(buf, &end);
        if (end == buf || *end != '\0' || !isfinite(v[j]) || errno == ERANGE)
            return wf_error(WF_ERR_INPUT, "%s:%d: column %d: field %s: '%s' is not a finite number",
                            f, line, t->col, field[j], buf);
    }
    wf_snrate_piece pc = {v[0], v[1], v[2], v[3]};
    char where[600];
    snprintf(where, sizeof where, "%s:%d", f, line);
    wf_status st = check_piece(&pc, where);
    if (st) return st;
    if (r->n < 0 || r->n >= WF_SNRATE_MAX_PIECES)
        return wf_error(WF_ERR_RANGE, "%s: more than %d POWERLAW2 pieces", where,
                        WF_SNRATE_MAX_PIECES);
    for (int j = 0; j < r->n; j++)
        if (overlaps(&pc, &r->p[j]))
            return wf_error(WF_ERR_RANGE, "%s: [%g, %g) overlaps the earlier piece %d [%g, %g)",
                            where, pc.zlo, pc.zhi, j + 1, r->p[j].zlo, r->p[j].zhi);
    r->p[r->n++] = pc;
    return WF_OK;
}

/* Index of the piece holding z, -1 for none: [zlo, zhi), and the top end of the law closed. */
static int piece_at(const wf_snrate *r, double z)
{
    int top = -1;
    for (int i = 0; i < r->n; i++) {
        if (z >= r->p[i].zlo && z < r->p[i].zhi) return i;
        if (top < 0 || r->p[i].zhi > r->p[top].zhi) top = i;
    }
    return top >= 0 && z == r->p[top].zhi ? top : -1;
}

wf_status wf_snrate_eval(const wf_snrate *r, double z, double *rate)
{
    if (!r || !(z >= 0.0 && isfinite(z)))
        return wf_error(WF_ERR_RANGE, "SN rate: redshift %g must be finite and >= 0", z);
    int i = piece_at(r, z);
    *rate = i < 0 ? 0.0 : r->p[i].a * pow(1.0 + z, r->p[i].b);
    return WF_OK;
}

/* ------------------------------------------------------------------ densities and integrals */

typedef struct seg_ctx {
    const wf_cosmo *c;
    const wf_snrate_piece *pc; /* NULL: no piece, density 0 */
} seg_ctx;

/* n(z) for the piece fixed by the segment, so that both ends of a segment use its law even
 * where the half-open rule would hand the end point to the next piece. */
static double seg_density(double z, void *ctx)
{
    const seg_ctx *s = ctx;
    if (!s->pc) return 0.0;
    double v = 0.0;
    wf_cosmo_dvdz(s->c, z, &v); /* z is inside a checked segment */
    return s->pc->a * pow(1.0 + z, s->pc->b - 1.0) * v;
}

wf_status wf_snrate_density(const wf_snrate *r, const wf_cosmo *c, double z, double *n)
{
    double rate, v;
    wf_status st = wf_snrate_eval(r, z, &rate);
    if (!st) st = wf_cosmo_dvdz(c, z, &v);
    if (st) return st;
    *n = rate / (1.0 + z) * v;
    return WF_OK;
}

static wf_status check_range(const wf_snrate *r, const wf_cosmo *c, double zmin, double zmax)
{
    wf_status st = wf_snrate_validate(r);
    if (st) return st;
    if (!c) return wf_error(WF_ERR_INPUT, "SN rate: no cosmology given");
    if (!(zmin >= 0.0 && zmin < zmax && zmax <= WF_COSMO_ZMAX))
        return wf_error(WF_ERR_RANGE,
                        "SN rate: redshift range zmin %g, zmax %g: need 0 <= zmin < zmax <= %g",
                        zmin, zmax, WF_COSMO_ZMAX);
    return WF_OK;
}

/* Segments of [zmin, zmax] between the law's breaks: ends in edge[0..n], the piece of each
 * (or -1) in which[0..n-1]. Returns n. */
#define MAX_EDGES (2 * WF_SNRATE_MAX_PIECES + 2)
static int segments(const wf_snrate *r, double zmin, double zmax, double edge[MAX_EDGES],
                    int which[MAX_EDGES - 1])
{
    int ne = 0;
    edge[ne++] = zmin;
    for (int i = 0; i < r->n; i++) {
        double b[2] = {r->p[i].zlo, r->p[i].zhi};
        for (int j = 0; j < 2; j++)
            if (b[j] > zmin && b[j] < zmax) edge[ne++] = b[j];
    }
    edge[ne++] = zmax;
    /* insertion sort, then drop duplicates (a shared break between two pieces) */
    for (int i = 1; i < ne; i++)
        for (int j = i; j > 0 && edge[j] < edge[j - 1]; j--) {
            double t = edge[j];
            edge[j] = edge[j - 1];
            edge[j - 1] = t;
        }
    int m = 1;
    for (int i = 1; i < ne; i++)
        if (edge[i] > edge[m - 1]) edge[m++] = edge[i];
    for (int s = 0; s + 1 < m; s++) which[s] = piece_at(r, 0.5 * (edge[s] + edge[s + 1]));
    return m - 1;
}

static int intervals_in(double lo, double hi, int piece)
{
    if (piece < 0) return 1; /* no mass: one interval the quantile search skips */
    int m = (int)ceil((hi - lo) / STEP_Z - 1e-9);
    return m < 1 ? 1 : m;
}

wf_status wf_snrate_integral(const wf_snrate *r, const wf_cosmo *c, double zmin, double zmax,
                             double *per_sr_yr)
{
    wf_status st = check_range(r, c, zmin, zmax);
    if (st) return st;
    double edge[MAX_EDGES];
    int which[MAX_EDGES - 1];
    int ns = segments(r, zmin, zmax, edge, which);
    double sum = 0.0;
    for (int s = 0; s < ns; s++) {
        if (which[s] < 0) continue;
        seg_ctx ctx = {c, &r->p[which[s]]};
        sum += wf_quad_gl(&wf_quad_gl16, seg_density, &ctx, edge[s], edge[s + 1],
                                       intervals_in(edge[s], edge[s + 1], which[s]));
    }
    *per_sr_yr = sum;
    return WF_OK;
}

wf_status wf_snrate_expected(const wf_snrate *r, const wf_cosmo *c, double zmin, double zmax,
                             double area_deg2, double days, double *n)
{
    if (!(area_deg2 > 0.0 && area_deg2 <= FULL_SKY_DEG2))
        return wf_error(WF_ERR_RANGE, "SN count: area %g deg^2 is outside (0, %.2f]", area_deg2,
                        FULL_SKY_DEG2);
    if (!(days > 0.0 && isfinite(days)))
        return wf_error(WF_ERR_RANGE, "SN count: duration %g days must be finite and > 0", days);
    double per;
    wf_status st = wf_snrate_integral(r, c, zmin, zmax, &per);
    if (st) return st;
    *n = area_deg2 * DEG * DEG * days / WF_SNRATE_DAYS_PER_YEAR * per;
    return WF_OK;
}

/* ------------------------------------------------------------------ redshift table */

void wf_snrate_table_free(wf_snrate_table *t)
{
    if (!t) return;
    free(t->z);
    free(t->g);
    free(t->dl);
    free(t->dr);
    t->z = t->g = t->dl = t->dr = NULL;
    t->n = 0;
}

wf_status wf_snrate_table_build(const wf_snrate *r, const wf_cosmo *c, double zmin, double zmax,
                                wf_snrate_table *t)
{
    if (!t) return wf_error(WF_ERR_INPUT, "SN redshift table: no table given");
    memset(t, 0, sizeof *t);
    wf_status st = check_range(r, c, zmin, zmax);
    if (st) return st;
    double edge[MAX_EDGES];
    int which[MAX_EDGES - 1];
    int ns = segments(r, zmin, zmax, edge, which);
    int n = 0;
    for (int s = 0; s < ns; s++) n += intervals_in(edge[s], edge[s + 1], which[s]);
    t->z = malloc((size_t)(n + 1) * sizeof *t->z);
    t->g = malloc((size_t)(n + 1) * sizeof *t->g);
    t->dl = malloc((size_t)n * sizeof *t->dl);
    t->dr = malloc((size_t)n * sizeof *t->dr);
    if (!t->z || !t->g || !t->dl || !t->dr) {
        wf_snrate_table_free(t);
        return wf_error(WF_ERR_NOMEM, "SN redshift table: %d intervals do not fit in memory", n);
    }
    int k = 0;
    t->z[0] = zmin;
    t->g[0] = 0.0;
    for (int s = 0; s < ns; s++) {
        seg_ctx ctx = {c, which[s] < 0 ? NULL : &r->p[which[s]]};
        int m = intervals_in(edge[s], edge[s + 1], which[s]);
        double h = (edge[s + 1] - edge[s]) / m;
        for (int j = 0; j < m; j++, k++) {
            double z0 = t->z[k], z1 = j == m - 1 ? edge[s + 1] : edge[s] + (j + 1) * h;
            t->z[k + 1] = z1;
            t->dl[k] = seg_density(z0, &ctx);
            t->dr[k] = seg_density(z1, &ctx);
            t->g[k + 1] = t->g[k] + (ctx.pc ? wf_quad_gl(&wf_quad_gl16, seg_density, &ctx, z0, z1, 1)
                                            : 0.0);
        }
    }
    t->n = n;
    t->zmin = zmin;
    t->zmax = zmax;
    t->total = t->g[n];
    if (!(t->total > 0.0)) {
        wf_snrate_table_free(t);
        return wf_error(WF_ERR_RANGE, "SN rate: the rate law is zero over [%g, %g]", zmin, zmax);
    }
    return WF_OK;
}

/* Cubic Hermite of G on one interval, relative to its left value, at t in [0, 1]: value and
 * derivative in t. */
static void hermite(double dg, double h, double dl, double dr, double t, double *f, double *df)
{
    double t2 = t * t, t3 = t2 * t;
    *f = dg * (3 * t2 - 2 * t3) + h * (dl * (t3 - 2 * t2 + t) + dr * (t3 - t2));
    *df = dg * 6 * t * (1 - t) + h * (dl * (3 * t2 - 4 * t + 1) + dr * (3 * t2 - 2 * t));
}

wf_status wf_snrate_quantile(const wf_snrate_table *t, double u, double *z)
{
    if (!t || t->n < 1) return wf_error(WF_ERR_INPUT, "SN redshift table: not built");
    if (!(u >= 0.0 && u <= 1.0))
        return wf_error(WF_ERR_RANGE, "SN redshift table: u = %g is outside [0, 1]", u);
    double target = u * t->total;
    if (target <= 0.0) {
        *z = t->zmin;
        return WF_OK;
    }
    if (target >= t->total) {
        *z = t->zmax;
        return WF_OK;
    }
    /* g[lo] <= target < g[hi]: intervals without mass are never chosen */
    int lo = 0, hi = t->n;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (t->g[mid] <= target) lo = mid;
        else hi = mid;
    }
    double h = t->z[lo + 1] - t->z[lo], dg = t->g[lo + 1] - t->g[lo];
    double y = target - t->g[lo];
    double a = 0.0, b = 1.0, x = y / dg;
    for (int it = 0; it < 100; it++) {
        double f, df;
        hermite(dg, h, t->dl[lo], t->dr[lo], x, &f, &df);
        f -= y;
        if (f < 0.0) a = x;
        else b = x;
        double nx = df > 0.0 ? x - f / df : -1.0;
        if (!(nx > a && nx < b)) nx = 0.5 * (a + b); /* Newton left the bracket: bisect */
        double step = fabs(nx - x);
        x = nx;
        if (step <= 1e-15 || b - a <= 1e-15) break;
    }
    *z = t->z[lo] + x * h;
    return WF_OK;
}

/* ------------------------------------------------------------------ generation */

void wf_snrate_survey_default(wf_snrate_survey *s)
{
    *s = (wf_snrate_survey){.area_deg2 = 1.0,
                            .mjd_start = 61420.0,
                            .mjd_end = 61420.0 + 2 * WF_SNRATE_DAYS_PER_YEAR,
                            .zmin = 0.06,
                            .zmax = 2.99,
                            .rest_before = 50.0,
                            .rest_after = 20.0};
}

static wf_status check_survey(const wf_snrate_survey *s)
{
    if (!s) return wf_error(WF_ERR_INPUT, "SN survey: no parameters given");
    if (!(s->area_deg2 > 0.0 && s->area_deg2 <= FULL_SKY_DEG2))
        return wf_error(WF_ERR_RANGE, "SN survey: area_deg2 = %g is outside (0, %.2f]",
                        s->area_deg2, FULL_SKY_DEG2);
    if (!isfinite(s->mjd_start))
        return wf_error(WF_ERR_RANGE, "SN survey: mjd_start = %g is not finite", s->mjd_start);
    if (!(isfinite(s->mjd_end) && s->mjd_end > s->mjd_start))
        return wf_error(WF_ERR_RANGE, "SN survey: mjd_end = %.10g must be after mjd_start %.10g",
                        s->mjd_end, s->mjd_start);
    if (!(s->zmin >= 0.0 && s->zmin < WF_COSMO_ZMAX))
        return wf_error(WF_ERR_RANGE, "SN survey: zmin = %g is outside [0, %g)", s->zmin,
                        WF_COSMO_ZMAX);
    if (!(s->zmax > s->zmin && s->zmax <= WF_COSMO_ZMAX))
        return wf_error(WF_ERR_RANGE, "SN survey: zmax = %g must be above zmin %g and <= %g",
                        s->zmax, s->zmin, WF_COSMO_ZMAX);
    if (!(s->rest_before >= 0.0 && isfinite(s->rest_before)))
        return wf_error(WF_ERR_RANGE, "SN survey: rest_before = %g must be finite and >= 0",
                        s->rest_before);
    if (!(s->rest_after >= 0.0 && isfinite(s->rest_after)))
        return wf_error(WF_ERR_RANGE, "SN survey: rest_after = %g must be finite and >= 0",
                        s->rest_after);
    return WF_OK;
}

void wf_snrate_gen_free(wf_snrate_gen *g)
{
    if (g) wf_snrate_table_free(&g->table);
}

wf_status wf_snrate_gen_init(wf_snrate_gen *g, const wf_snrate *law, const wf_cosmo *c,
                             const wf_snrate_survey *s, uint64_t seed)
{
    if (!g) return wf_error(WF_ERR_INPUT, "SN generation: no struct given");
    memset(g, 0, sizeof *g);
    wf_status st = check_survey(s);
    if (st) return st;
    st = wf_snrate_table_build(law, c, s->zmin, s->zmax, &g->table);
    if (st) return st;
    g->survey = *s;
    g->seed = seed;
    double stretch = 1.0 + s->zmax;
    g->peak_min = s->mjd_start - s->rest_before * stretch;
    g->peak_max = s->mjd_end + s->rest_after * stretch;
    g->days = g->peak_max - g->peak_min;
    g->area_sr = s->area_deg2 * DEG * DEG;
    g->expected = g->area_sr * g->days / WF_SNRATE_DAYS_PER_YEAR * g->table.total;
    return WF_OK;
}

wf_status wf_snrate_gen_count(const wf_snrate_gen *g, uint32_t *count)
{
    if (!g || g->table.n < 1) return wf_error(WF_ERR_INPUT, "SN generation: not initialised");
    /* the Poisson tail above the mean is ~sqrt(mean): keep well clear of 2^32 */
    if (!(g->expected <= 4.0e9))
        return wf_error(WF_ERR_RANGE,
                        "SN generation: %.4g SNe expected; SN indices are 32-bit (reduce "
                        "area_deg2 or the survey span)",
                        g->expected);
    wf_rng rng;
    wf_sn_rng(g->seed, 0, WF_SN_DRAW_COUNT, &rng);
    *count = (uint32_t)wf_rng_poisson(&rng, g->expected);
    return WF_OK;
}

wf_status wf_snrate_gen_draw(const wf_snrate_gen *g, uint32_t i, double *z, double *peak_mjd)
{
    if (!g || g->table.n < 1) return wf_error(WF_ERR_INPUT, "SN generation: not initialised");
    wf_rng rng;
    if (z) {
        wf_sn_rng(g->seed, i, WF_SN_DRAW_Z, &rng);
        wf_status st = wf_snrate_quantile(&g->table, wf_rng_uniform53(&rng), z);
        if (st) return st;
    }
    if (peak_mjd) {
        wf_sn_rng(g->seed, i, WF_SN_DRAW_PEAK, &rng);
        *peak_mjd = g->peak_min + wf_rng_uniform53(&rng) * g->days;
    }
    return WF_OK;
}
