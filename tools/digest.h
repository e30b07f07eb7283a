/* The inputs that shape a product, as digests: a product is "done" only if it was made from
 * the same inputs (docs/SURVEY.md, resume). Six parts, each a SHA-256 of a canonical text:
 *   config    the resolved configuration (wf_config_product_text: every key that can change
 *             a byte, after defaults, files and --set), the MA table as resolved in ramp
 *             mode, and the header lines the caller adds (a survey's plan row)
 *   seed      the seed
 *   data      the bytes of every file of paths.data/roman/ (pupils, Zernikes, SIP, bandpasses,
 *             sky), or "built-in values" without paths.data; "not read" for a grid or replay
 *   catalogs  synthetic field (its seed is the seed part), or the bytes of scene.catalog and
 *             scene.stars, of a GalSim scene, of a replayed recording
 *   sne       the bytes of the --sne sample and of every file of its SALT model folder, and
 *             the SNe given as they are
 *   version   the program's version string, which carries a digest of its sources
 * and the whole: a SHA-256 over the six. File contents count, never paths or times; a file's
 * digest is computed once per wf_digest_cache (one run). */
#ifndef WF_DIGEST_H
#define WF_DIGEST_H

#include <stddef.h>
#include <stdint.h>
#include "hal/clock.h"
#include "tools/config.h"
#include "tools/sninject.h"

typedef struct wf_sha256 {
    uint32_t h[8];
    uint64_t bytes;
    unsigned char block[64];
    size_t used;
} wf_sha256;

void wf_sha256_init(wf_sha256 *s);
void wf_sha256_update(wf_sha256 *s, const void *data, size_t n);
void wf_sha256_hex(wf_sha256 *s, char hex[65]); /* finishes s: 64 lower-case hex digits */

enum { WF_DIGEST_CONFIG, WF_DIGEST_SEED, WF_DIGEST_DATA, WF_DIGEST_CATALOGS, WF_DIGEST_SNE,
       WF_DIGEST_VERSION, WF_DIGEST_NPARTS };

/* Primary-header keywords: WFDIGEST (the whole, 64 hex digits) and one per part (the first
 * 32 hex digits: 128 bits). */
extern const char *const wf_digest_keyword[WF_DIGEST_NPARTS];
extern const char *const wf_digest_part_name[WF_DIGEST_NPARTS];
#define WF_DIGEST_PART_HEX 32

typedef struct wf_digest {
    char whole[65];
    char part[WF_DIGEST_NPARTS][65];
} wf_digest;

typedef struct wf_digest_cache wf_digest_cache;
wf_status wf_digest_cache_create(wf_digest_cache **out);
void wf_digest_cache_free(wf_digest_cache *c);

typedef struct wf_digest_inputs {
    const wf_config *cfg;
    const wf_clock *clock;
    const char *extra;              /* the caller's header lines, or NULL */
    const char *replay;             /* a replayed recording, or NULL */
    const wf_sn_injector *sne;      /* or NULL */
    const wf_scene_sn *given;       /* SNe given as they are (wf_pipeline_job.sne), or NULL */
    size_t ngiven;
    const char *version;
} wf_digest_inputs;

/* cache may be NULL (nothing kept). */
wf_status wf_digest_product(wf_digest_cache *cache, const wf_digest_inputs *in, wf_digest *out);

/* Appends to buf (holding a NUL-terminated text of META lines) the digest keywords and one
 * "HISTORY wfisim config: KEY = VALUE" card per configuration key that differs from its
 * default (a value too long for a card is given as "KEY ~ <digest>"), so that a refusal can
 * name the keys that changed. */
wf_status wf_digest_meta(const wf_digest *d, const wf_config *cfg, char *buf, size_t cap);

/* The "KEY = VALUE" lines of cfg's configuration that differ from the defaults, as the header
 * cards carry them ('\n'-separated, malloc'd). */
wf_status wf_digest_config_lines(const wf_config *cfg, char **lines);

/* What a product's primary header says of its inputs. */
typedef struct wf_digest_found {
    int have;                        /* 0: no WFDIGEST (made by a wfisim before digests) */
    wf_digest d;                     /* parts: as many hex digits as the header holds */
    int have_seed;
    unsigned long long seed;
    char origin[72];                 /* ORIGIN: "wfisim <version>" */
    char *config;                    /* its "KEY = VALUE" lines, '\n'-separated, malloc'd */
} wf_digest_found;

wf_status wf_digest_read(const char *path, wf_digest_found *out);
void wf_digest_found_free(wf_digest_found *f);

/* 1 when the product's header names exactly these inputs. */
int wf_digest_same(const wf_digest_found *was, const wf_digest *now);

/* What differs, as "seed 1, this run has seed 2; a different configuration: ..." (the parts
 * that differ, in order). */
void wf_digest_explain(const wf_digest_found *was, const wf_digest *now, const wf_digest_inputs *in,
                       char *msg, size_t cap);

/* The digest of the program's sources (hal, firmware, sim, tools), baked in at build time:
 * the version string's "+src." suffix. */
const char *wf_digest_source(void);

#endif
