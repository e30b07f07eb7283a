#include "tools/digest.h"

#include <dirent.h>
#include <errno.h>
#include <stdarg.h>
#include <fitsio.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "sim/fits/fitsout.h"

#ifndef WF_SOURCE_DIGEST
#error "WF_SOURCE_DIGEST is defined by the Makefile (a digest of the program's sources)"
#endif

const char *const wf_digest_keyword[WF_DIGEST_NPARTS] = {"WFDCONF", "WFDSEED", "WFDDATA",
                                                         "WFDCAT", "WFDSNE", "WFDVERS"};
const char *const wf_digest_part_name[WF_DIGEST_NPARTS] = {"config", "seed", "data",
                                                           "catalogs", "sne", "version"};

const char *wf_digest_source(void) { return WF_SOURCE_DIGEST; }

/* ---- SHA-256 (FIPS 180-4) ------------------------------------------------------------ */

static const uint32_t K[64] = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};

static uint32_t rotr(uint32_t x, int n) { return x >> n | x << (32 - n); }

static void compress(uint32_t h[8], const unsigned char *p)
{
    uint32_t w[64];
    for (int i = 0; i < 16; i++)
        w[i] = (uint32_t)p[4 * i] << 24 | (uint32_t)p[4 * i + 1] << 16 | (uint32_t)p[4 * i + 2] << 8 | p[4 * i + 3];
    for (int i = 16; i < 64; i++) {
        uint32_t s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ w[i - 15] >> 3;
        uint32_t s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ w[i - 2] >> 10;
        w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    uint32_t a = h[0], b = h[1], c = h[2], d = h[3], e = h[4], f = h[5], g = h[6], k = h[7];
    for (int i = 0; i < 64; i++) {
        uint32_t t1 = k + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + K[i] + w[i];
        uint32_t t2 = (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
        k = g, g = f, f = e, e = d + t1, d = c, c = b, b = a, a = t1 + t2;
    }
    h[0] += a, h[1] += b, h[2] += c, h[3] += d, h[4] += e, h[5] += f, h[6] += g, h[7] += k;
}

void wf_sha256_init(wf_sha256 *s)
{
    static const uint32_t h0[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                                   0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
    memcpy(s->h, h0, sizeof h0);
    s->bytes = 0;
    s->used = 0;
}

void wf_sha256_update(wf_sha256 *s, const void *data, size_t n)
{
    const unsigned char *p = data;
    s->bytes += n;
    if (s->used) {
        size_t take = 64 - s->used < n ? 64 - s->used : n;
        memcpy(s->block + s->used, p, take);
        s->used += take, p += take, n -= take;
        if (s->used < 64) return;
        compress(s->h, s->block);
        s->used = 0;
    }
    for (; n >= 64; p += 64, n -= 64) compress(s->h, p);
    memcpy(s->block, p, n);
    s->used = n;
}

void wf_sha256_hex(wf_sha256 *s, char hex[65])
{
    uint64_t bits = s->bytes * 8;
    unsigned char pad[72] = {0x80};
    size_t npad = (s->used < 56 ? 56 : 120) - s->used;
    for (int i = 0; i < 8; i++) pad[npad + i] = (unsigned char)(bits >> (56 - 8 * i));
    wf_sha256_update(s, pad, npad + 8);
    for (int i = 0; i < 8; i++) snprintf(hex + 8 * i, 9, "%08x", s->h[i]);
}

static void text_hex(const char *text, char hex[65])
{
    wf_sha256 s;
    wf_sha256_init(&s);
    wf_sha256_update(&s, text, strlen(text));
    wf_sha256_hex(&s, hex);
}

/* ---- file and folder contents, once per run ---------------------------------------------- */

typedef struct entry {
    struct entry *next;
    char hex[65];
    char path[]; /* "f:" or "d:" and the path as given */
} entry;

struct wf_digest_cache {
    entry *head;
};

wf_status wf_digest_cache_create(wf_digest_cache **out)
{
    *out = calloc(1, sizeof **out);
    return *out ? WF_OK : wf_error(WF_ERR_NOMEM, "out of memory for the digest cache");
}

void wf_digest_cache_free(wf_digest_cache *c)
{
    if (!c) return;
    for (entry *e = c->head, *n; e; e = n) {
        n = e->next;
        free(e);
    }
    free(c);
}

static const char *cached(wf_digest_cache *c, char kind, const char *path)
{
    for (entry *e = c ? c->head : NULL; e; e = e->next)
        if (e->path[0] == kind && !strcmp(e->path + 2, path)) return e->hex;
    return NULL;
}

static void keep(wf_digest_cache *c, char kind, const char *path, const char *hex)
{
    size_t n = strlen(path);
    entry *e = c ? malloc(sizeof *e + n + 3) : NULL;
    if (!e) return; /* not kept: computed again when asked again */
    memcpy(e->hex, hex, 65);
    e->path[0] = kind;
    e->path[1] = ':';
    memcpy(e->path + 2, path, n + 1);
    e->next = c->head;
    c->head = e;
}

static wf_status file_hex(wf_digest_cache *c, const char *what, const char *path, char hex[65])
{
    const char *known = cached(c, 'f', path);
    if (known) {
        memcpy(hex, known, 65);
        return WF_OK;
    }
    FILE *f = fopen(path, "rb");
    if (!f) return wf_error(WF_ERR_IO, "%s %s: cannot read it for the product's input digest: %s", what, path, strerror(errno));
    wf_sha256 s;
    wf_sha256_init(&s);
    static _Thread_local unsigned char buf[1 << 16];
    size_t got;
    while ((got = fread(buf, 1, sizeof buf, f)) > 0) wf_sha256_update(&s, buf, got);
    int bad = ferror(f);
    fclose(f);
    if (bad) return wf_error(WF_ERR_IO, "%s %s: read error", what, path);
    wf_sha256_hex(&s, hex);
    keep(c, 'f', path, hex);
    return WF_OK;
}

static int by_name(const void *a, const void *b) { return strcmp(*(char *const *)a, *(char *const *)b); }

/* Every regular file below dir, by its path relative to dir (sorted, so the order of the
 * directory listing does not matter) and the digest of its bytes. */
static wf_status tree_hex(wf_digest_cache *c, const char *what, const char *dir, const char *rel, wf_sha256 *s,
                          int depth)
{
    char path[2 * WF_PATH_MAX];
    snprintf(path, sizeof path, "%s%s%s", dir, *rel ? "/" : "", rel);
    DIR *d = opendir(path);
    if (!d) return wf_error(WF_ERR_IO, "%s %s: cannot list it for the product's input digest: %s", what, path, strerror(errno));
    char **names = NULL;
    size_t n = 0, cap = 0;
    wf_status st = WF_OK;
    for (struct dirent *e; (e = readdir(d));) {
        if (e->d_name[0] == '.') continue;
        if (n == cap) {
            char **more = realloc(names, (cap = cap ? 2 * cap : 64) * sizeof *names);
            if (!more) { st = wf_error(WF_ERR_NOMEM, "out of memory listing %s", path); break; }
            names = more;
        }
        if (!(names[n] = strdup(e->d_name))) { st = wf_error(WF_ERR_NOMEM, "out of memory listing %s", path); break; }
        n++;
    }
    closedir(d);
    if (!st) qsort(names, n, sizeof *names, by_name);
    for (size_t i = 0; i < n && !st; i++) {
        char sub[2 * WF_PATH_MAX], full[3 * WF_PATH_MAX];
        snprintf(sub, sizeof sub, "%s%s%s", rel, *rel ? "/" : "", names[i]);
        snprintf(full, sizeof full, "%s/%s", dir, sub);
        struct stat sb;
        if (stat(full, &sb) != 0) {
            st = wf_error(WF_ERR_IO, "%s %s: %s", what, full, strerror(errno));
        } else if (S_ISDIR(sb.st_mode)) {
            if (depth < 8) st = tree_hex(c, what, dir, sub, s, depth + 1);
        } else if (S_ISREG(sb.st_mode)) {
            char hex[65];
            if (!(st = file_hex(c, what, full, hex))) {
                wf_sha256_update(s, sub, strlen(sub) + 1);
                wf_sha256_update(s, hex, 64);
            }
        }
    }
    for (size_t i = 0; i < n; i++) free(names[i]);
    free(names);
    return st;
}

static wf_status folder_hex(wf_digest_cache *c, const char *what, const char *dir, char hex[65])
{
    const char *known = cached(c, 'd', dir);
    if (known) {
        memcpy(hex, known, 65);
        return WF_OK;
    }
    wf_sha256 s;
    wf_sha256_init(&s);
    wf_status st = tree_hex(c, what, dir, "", &s, 0);
    if (st) return st;
    wf_sha256_hex(&s, hex);
    keep(c, 'd', dir, hex);
    return WF_OK;
}

/* ---- the parts ----------------------------------------------------------------------- */

#define DATA_BUILTIN "data: built-in values (no paths.data)\n"
#define DATA_UNUSED "data: not read (grid or replayed scene)\n"

static int draws_objects(const wf_digest_inputs *in) { return !in->replay && in->cfg->scene_kind != 2; }

static wf_status config_part(const wf_digest_inputs *in, char hex[65])
{
    char *text;
    wf_status st = wf_config_product_text(in->cfg, &text);
    if (st) return st;
    wf_sha256 s;
    wf_sha256_init(&s);
    wf_sha256_update(&s, text, strlen(text));
    free(text);
    if (in->cfg->ro.mode == WF_MODE_RAMP) { /* the table as read, whatever named it */
        const wf_ma_table *ma = &in->clock->ma;
        char line[64];
        snprintf(line, sizeof line, "ma: %d resultants\n", ma->nresultants);
        wf_sha256_update(&s, line, strlen(line));
        for (int r = 0; r < ma->nresultants; r++)
            for (int j = ma->first[r]; j < ma->first[r + 1]; j++) {
                snprintf(line, sizeof line, "%d:%d\n", r, ma->read[j]);
                wf_sha256_update(&s, line, strlen(line));
            }
    }
    const char *extra = in->extra ? in->extra : "";
    wf_sha256_update(&s, "extra:\n", 7);
    wf_sha256_update(&s, extra, strlen(extra));
    wf_sha256_hex(&s, hex);
    return WF_OK;
}

static wf_status data_part(wf_digest_cache *c, const wf_digest_inputs *in, char hex[65])
{
    const char *dir = in->cfg->data_dir;
    if (!draws_objects(in)) { text_hex(DATA_UNUSED, hex); return WF_OK; }
    if (!dir[0]) { text_hex(DATA_BUILTIN, hex); return WF_OK; }
    /* roman/ is what the image chain reads (optics, WCS, bandpasses, sky): all of it, so a
     * file a module starts reading later is covered without a list kept here */
    char roman[WF_PATH_MAX + 16], tree[65];
    snprintf(roman, sizeof roman, "%s/roman", dir);
    wf_status st = folder_hex(c, "paths.data", roman, tree);
    if (st) return st;
    char text[128];
    snprintf(text, sizeof text, "data: roman/ %s\n", tree);
    text_hex(text, hex);
    return WF_OK;
}

static wf_status catalogs_part(wf_digest_cache *c, const wf_digest_inputs *in, char hex[65])
{
    const wf_config *cfg = in->cfg;
    wf_sha256 s;
    wf_sha256_init(&s);
    char h[65];
    wf_status st = WF_OK;
    if (in->replay) {
        wf_sha256_update(&s, "replay\n", 7);
        if (!(st = file_hex(c, "--replay", in->replay, h))) wf_sha256_update(&s, h, 64);
    } else if (cfg->scene_kind == 0) {
        wf_sha256_update(&s, "synthetic field of the seed\n", 28);
    } else if (cfg->scene_kind == 2) {
        wf_sha256_update(&s, "grid (scene.grid keys)\n", 23);
    } else {
        wf_sha256_update(&s, cfg->scene_kind == 3 ? "galsim\n" : "catalog\n", cfg->scene_kind == 3 ? 7 : 8);
        const char *files[2] = {cfg->catalog, cfg->scene_kind == 3 ? "" : cfg->stars};
        const char *names[2] = {"scene.catalog", "scene.stars"};
        for (int i = 0; i < 2 && !st; i++) {
            if (!files[i][0]) { wf_sha256_update(&s, "none\n", 5); continue; }
            if (!(st = file_hex(c, names[i], files[i], h))) wf_sha256_update(&s, h, 64);
        }
    }
    if (st) return st;
    wf_sha256_hex(&s, hex);
    return WF_OK;
}

static wf_status sne_part(wf_digest_cache *c, const wf_digest_inputs *in, char hex[65])
{
    if ((!in->sne && !in->ngiven) || !draws_objects(in)) { text_hex("sne: none\n", hex); return WF_OK; }
    wf_sha256 s;
    wf_sha256_init(&s);
    char text[400];
    if (in->sne) {
        char sample[65], model[65];
        wf_status st = file_hex(c, "--sne", wf_sn_injector_sample_path(in->sne), sample);
        if (!st) st = folder_hex(c, "SALT model", wf_sn_injector_model_dir(in->sne), model);
        if (st) return st;
        snprintf(text, sizeof text, "sne: %s\nmodel: %s\n", sample, model);
        wf_sha256_update(&s, text, strlen(text));
    }
    for (size_t i = 0; i < in->ngiven; i++) { /* field by field: no padding bytes */
        const wf_scene_sn *sn = &in->given[i];
        snprintf(text, sizeof text, "sn %lld %lld %a %a %a %a %a %a %u\n", sn->id, sn->host_id, sn->ra, sn->dec,
                 sn->z, sn->phase, sn->mag, sn->dlnf_dt, sn->flags);
        wf_sha256_update(&s, text, strlen(text));
    }
    wf_sha256_hex(&s, hex);
    return WF_OK;
}

wf_status wf_digest_product(wf_digest_cache *cache, const wf_digest_inputs *in, wf_digest *out)
{
    memset(out, 0, sizeof *out);
    char text[512];
    wf_status st = config_part(in, out->part[WF_DIGEST_CONFIG]);
    snprintf(text, sizeof text, "seed = %llu\n", (unsigned long long)in->cfg->seed);
    text_hex(text, out->part[WF_DIGEST_SEED]);
    if (!st) st = data_part(cache, in, out->part[WF_DIGEST_DATA]);
    if (!st) st = catalogs_part(cache, in, out->part[WF_DIGEST_CATALOGS]);
    if (!st) st = sne_part(cache, in, out->part[WF_DIGEST_SNE]);
    snprintf(text, sizeof text, "wfisim %s\n", in->version ? in->version : "?");
    text_hex(text, out->part[WF_DIGEST_VERSION]);
    if (st) return st;
    /* the whole is made of the parts as the header keeps them, so it can be checked from them */
    wf_sha256 s;
    wf_sha256_init(&s);
    for (int p = 0; p < WF_DIGEST_NPARTS; p++) {
        out->part[p][WF_DIGEST_PART_HEX] = '\0';
        snprintf(text, sizeof text, "%s %s\n", wf_digest_part_name[p], out->part[p]);
        wf_sha256_update(&s, text, strlen(text));
    }
    wf_sha256_hex(&s, out->whole);
    return WF_OK;
}

/* ---- header cards ------------------------------------------------------------------- */

#define CONFIG_TAG "wfisim config: "
#define HISTORY_TEXT 72 /* characters of a HISTORY card's text */

/* The "KEY = VALUE" lines of cfg that differ from the defaults, each short enough for one
 * card (a longer one becomes "KEY ~ <first 16 hex digits of its digest>"); '\n'-separated. */
wf_status wf_digest_config_lines(const wf_config *cfg, char **out)
{
    wf_config *def = malloc(sizeof *def);
    char *now = NULL, *was = NULL;
    *out = NULL;
    if (!def) return wf_error(WF_ERR_NOMEM, "out of memory");
    wf_config_defaults(def);
    wf_status st = wf_config_product_text(cfg, &now);
    if (!st) st = wf_config_product_text(def, &was);
    free(def);
    char *lines = st ? NULL : malloc(2 * strlen(now) + 64); /* a "KEY ~ <hex>" line may outgrow its KEY = VALUE */
    if (!st && !lines) st = wf_error(WF_ERR_NOMEM, "out of memory");
    if (!st) {
        size_t len = 0;
        lines[0] = '\0';
        /* both list the same keys in the same order: a line differs or it does not */
        for (char *p = now, *q = was, *next; *p; p = next) {
            char *nl = strchr(p, '\n'), *ql = strchr(q, '\n');
            next = nl ? nl + 1 : p + strlen(p);
            size_t n = (size_t)(next - p), m = ql ? (size_t)(ql + 1 - q) : strlen(q);
            int same = m == n && !memcmp(p, q, n);
            q += m;
            if (same) continue;
            size_t body = nl ? n - 1 : n;
            if (body + strlen(CONFIG_TAG) <= HISTORY_TEXT) {
                memcpy(lines + len, p, body);
                len += body;
            } else {
                char *eq = strstr(p, " = ");
                size_t key = eq && eq < p + body ? (size_t)(eq - p) : body;
                char hex[65];
                wf_sha256 s;
                wf_sha256_init(&s);
                wf_sha256_update(&s, p, body);
                wf_sha256_hex(&s, hex);
                len += (size_t)sprintf(lines + len, "%.*s ~ %.16s", (int)(key < 38 ? key : 38), p, hex);
            }
            lines[len++] = '\n';
            lines[len] = '\0';
        }
        *out = lines;
    }
    free(now);
    free(was);
    return st;
}

wf_status wf_digest_meta(const wf_digest *d, const wf_config *cfg, char *buf, size_t cap)
{
    size_t len = strlen(buf);
    int k = snprintf(buf + len, cap - len, "hdr.WFDIGEST = '%s' / inputs that shape this product\n", d->whole);
    for (int p = 0; p < WF_DIGEST_NPARTS && k >= 0 && (size_t)k < cap - len; p++) {
        len += (size_t)k;
        k = snprintf(buf + len, cap - len, "hdr.%s = '%.*s' / digest of the %s\n", wf_digest_keyword[p],
                     WF_DIGEST_PART_HEX, d->part[p], wf_digest_part_name[p]);
    }
    if (k < 0 || (size_t)k >= cap - len) return wf_error(WF_ERR_INPUT, "header lines too long");
    len += (size_t)k;
    char *lines;
    wf_status st = wf_digest_config_lines(cfg, &lines);
    if (st) return st;
    for (char *p = lines, *nl; *p && !st; p = nl + 1) {
        nl = strchr(p, '\n');
        k = snprintf(buf + len, cap - len, "hdr.HISTORY = " CONFIG_TAG "%.*s\n", (int)(nl - p), p);
        if (k < 0 || (size_t)k >= cap - len) st = wf_error(WF_ERR_INPUT, "header lines too long");
        else len += (size_t)k;
    }
    free(lines);
    return st;
}

/* ---- reading a product back ------------------------------------------------------------ */

wf_status wf_digest_read(const char *path, wf_digest_found *out)
{
    memset(out, 0, sizeof *out);
    fitsfile *f;
    int status = 0;
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening");
    char value[FLEN_VALUE];
    if (!fits_read_key_str(f, "WFDIGEST", value, NULL, &status)) {
        out->have = 1;
        snprintf(out->d.whole, sizeof out->d.whole, "%.64s", value);
        for (int p = 0; p < WF_DIGEST_NPARTS; p++) {
            int s = 0;
            if (!fits_read_key_str(f, wf_digest_keyword[p], value, NULL, &s))
                snprintf(out->d.part[p], sizeof out->d.part[p], "%.64s", value);
        }
    }
    status = 0;
    if (!fits_read_key_ulnglng(f, "SEED", &out->seed, NULL, &status)) out->have_seed = 1;
    status = 0;
    if (!fits_read_key_str(f, "ORIGIN", value, NULL, &status)) snprintf(out->origin, sizeof out->origin, "%s", value);
    status = 0;
    int ncards = 0;
    fits_get_hdrspace(f, &ncards, NULL, &status);
    size_t len = 0, cap = 256;
    out->config = malloc(cap);
    wf_status st = out->config ? WF_OK : wf_error(WF_ERR_NOMEM, "out of memory");
    if (out->config) out->config[0] = '\0';
    for (int i = 1; i <= ncards && !st && !status; i++) {
        char card[FLEN_CARD];
        if (fits_read_record(f, i, card, &status)) break;
        const char *tag = "HISTORY " CONFIG_TAG;
        if (strncmp(card, tag, strlen(tag))) continue;
        const char *text = card + strlen(tag);
        size_t n = strlen(text);
        while (n && text[n - 1] == ' ') n--;
        if (len + n + 2 > cap) {
            char *more = realloc(out->config, cap = 2 * cap + n);
            if (!more) { st = wf_error(WF_ERR_NOMEM, "out of memory"); break; }
            out->config = more;
        }
        memcpy(out->config + len, text, n);
        len += n;
        out->config[len++] = '\n';
        out->config[len] = '\0';
    }
    if (!st && status) st = wf_fits_error(status, path, "reading the primary header");
    int cs = 0;
    fits_close_file(f, &cs);
    fits_clear_errmsg();
    if (st) wf_digest_found_free(out);
    return st;
}

void wf_digest_found_free(wf_digest_found *f)
{
    free(f->config);
    f->config = NULL;
}

int wf_digest_same(const wf_digest_found *was, const wf_digest *now)
{
    return was->have && !strcmp(was->d.whole, now->whole);
}

/* ---- naming what changed -------------------------------------------------------------- */

typedef struct msgbuf {
    char *p;
    size_t cap, len;
} msgbuf;

static void say(msgbuf *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void say(msgbuf *m, const char *fmt, ...)
{
    if (m->len >= m->cap) return;
    va_list ap;
    va_start(ap, fmt);
    int k = vsnprintf(m->p + m->len, m->cap - m->len, fmt, ap);
    va_end(ap);
    if (k > 0) m->len += (size_t)k < m->cap - m->len ? (size_t)k : m->cap - m->len - 1;
}

/* The value of key in '\n'-separated "KEY = VALUE" lines, or NULL (then: its default). */
static const char *value_of(const char *lines, const char *key, size_t keylen, size_t *n)
{
    for (const char *p = lines; p && *p;) {
        const char *nl = strchr(p, '\n');
        size_t len = nl ? (size_t)(nl - p) : strlen(p);
        if (len > keylen + 2 && !strncmp(p, key, keylen) && p[keylen] == ' ' && (p[keylen + 1] == '=' || p[keylen + 1] == '~')) {
            *n = len - keylen - 3;
            return p + keylen + 3;
        }
        p = nl ? nl + 1 : NULL;
    }
    return NULL;
}

static void name_keys(msgbuf *m, const char *was, const char *now)
{
    int named = 0;
    for (int pass = 0; pass < 2; pass++) {
        const char *mine = pass ? was : now, *other = pass ? now : was;
        for (const char *p = mine; p && *p;) {
            const char *nl = strchr(p, '\n');
            const char *sp = strchr(p, ' ');
            size_t keylen = sp && (!nl || sp < nl) ? (size_t)(sp - p) : 0;
            size_t a = 0, b = 0;
            const char *va = keylen ? value_of(mine, p, keylen, &a) : NULL;
            const char *vb = keylen ? value_of(other, p, keylen, &b) : NULL;
            /* each changed key once: from now's lines, and from was's those now lacks */
            if (keylen && (pass == 0 ? !vb || a != b || memcmp(va, vb, a) : !vb)) {
                const char *wv = pass ? va : vb, *nv = pass ? vb : va;
                size_t wn = pass ? a : b, nn = pass ? b : a;
                say(m, "%s%.*s = %.*s%s, this run has %.*s%s", named++ ? "; " : ": ", (int)keylen, p,
                    wv ? (int)wn : 0, wv ? wv : "", wv ? "" : "the default", nv ? (int)nn : 0, nv ? nv : "",
                    nv ? "" : "the default");
            }
            p = nl ? nl + 1 : NULL;
        }
    }
    if (!named) say(m, " (the same keys; the MA table or the plan row's header lines differ)");
}

void wf_digest_explain(const wf_digest_found *was, const wf_digest *now, const wf_digest_inputs *in, char *msg,
                       size_t cap)
{
    msgbuf m = {msg, cap, 0};
    msg[0] = '\0';
    if (!was->have) {
        say(&m, "a wfisim that recorded no input digest (before WFDIGEST), so its inputs are unknown");
        return;
    }
    int n = 0;
    for (int p = 0; p < WF_DIGEST_NPARTS; p++) {
        if (!strncmp(was->d.part[p], now->part[p], WF_DIGEST_PART_HEX)) continue;
        if (n++) say(&m, "; ");
        char h[65];
        switch (p) {
        case WF_DIGEST_CONFIG: {
            say(&m, "a different configuration");
            char *lines = NULL;
            if (!wf_digest_config_lines(in->cfg, &lines)) name_keys(&m, was->config ? was->config : "", lines);
            free(lines);
            break;
        }
        case WF_DIGEST_SEED:
            if (was->have_seed) say(&m, "seed %llu, this run has seed %llu", was->seed, (unsigned long long)in->cfg->seed);
            else say(&m, "another seed, this run has seed %llu", (unsigned long long)in->cfg->seed);
            break;
        case WF_DIGEST_DATA: {
            const char *then = "data files other than this run's";
            text_hex(DATA_BUILTIN, h);
            if (!strncmp(was->d.part[p], h, WF_DIGEST_PART_HEX)) then = "the built-in values (no paths.data)";
            text_hex(DATA_UNUSED, h);
            if (!strncmp(was->d.part[p], h, WF_DIGEST_PART_HEX)) then = "no data read (grid or replayed scene)";
            if (!in->cfg->data_dir[0]) say(&m, "%s, this run has the built-in values (no paths.data)", then);
            else say(&m, "%s, this run reads the data files of %s (paths.data)", then, in->cfg->data_dir);
            break;
        }
        case WF_DIGEST_CATALOGS:
            say(&m, "other scene catalogs than this run's (scene.kind, or the contents of scene.catalog / scene.stars / --replay)");
            break;
        case WF_DIGEST_SNE:
            say(&m, "another SN sample than this run's (the --sne file or its SALT model files)");
            break;
        case WF_DIGEST_VERSION:
            say(&m, "%s, this is wfisim %s", was->origin[0] ? was->origin : "another wfisim",
                in->version ? in->version : "?");
            break;
        }
    }
    if (!n) say(&m, "inputs whose digest is '%s', this run's is '%s'", was->d.whole, now->whole);
}
