#include "tools/config.h"

#include <ctype.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <yaml.h>

#include "sim/optics/bandpass.h"
#include "sim/sn/snpop.h"

/* Enum keys store the index of the chosen name as an int, so the choice lists below must
 * stay in the order of the C enums and the enums must be int-sized. */
_Static_assert(WF_MODE_RAMP == 0 && WF_MODE_SINGLE == 1, "exposure.mode choices follow wf_mode");
_Static_assert(WF_SAMPLE_PER_READ == 0 && WF_SAMPLE_DIRECT == 1 && WF_SAMPLE_MOMENTS == 2,
               "exposure.sampling choices follow wf_sampling");
_Static_assert(sizeof(wf_mode) == sizeof(int) && sizeof(wf_sampling) == sizeof(int),
               "enum keys are stored through int");

/* Default sky, SPEC §2: zodiacal light at the deep field in Y106 (GalSim table), the pixel
 * scale, stray light as a fraction of the zodiacal light, and the Y106 thermal background. */
#define ZODI_Y106_DEEP 29.7      /* e-/s/arcsec^2 */
#define PIXEL_SCALE 0.11         /* arcsec/pixel */
#define STRAY_LIGHT_FRACTION 0.1
#define THERMAL_Y106 0.0         /* e-/pixel/s */

static double default_sky_rate(void)
{
    return ZODI_Y106_DEEP * PIXEL_SCALE * PIXEL_SCALE * (1.0 + STRAY_LIGHT_FRACTION) +
           THERMAL_Y106;
}

/* ---- the key table ------------------------------------------------------------------ */

typedef enum {
    KT_BOOL,   /* int, 0 or 1 */
    KT_INT,    /* int */
    KT_UINT,   /* uint32_t or uint64_t, by size */
    KT_DOUBLE, /* double, finite */
    KT_STRING, /* char[size]; optionally restricted to choices */
    KT_ENUM,   /* int: index into choices */
    KT_KERNEL  /* double[3][3], sum 1 within IPC_SUM_TOL */
} key_type;

#define IPC_SUM_TOL 1e-6

typedef struct key_desc {
    const char *name;            /* dotted path */
    key_type type;
    const char *unit;            /* "" when dimensionless */
    const char *def;             /* default as text; NULL: set in code (see doc_default) */
    const char *doc_default;     /* what the doc shows instead of the value, or NULL */
    double lo, hi;               /* numeric bounds, used when has_lo / has_hi */
    unsigned char has_lo, has_hi, lo_open, nonempty;
    unsigned char filter;        /* KT_STRING: a filter name as sim/optics/bandpass.c reads it (W149
                                  * is W146), stored under its one name */
    unsigned char dir;           /* KT_STRING: empty, or an existing directory */
    const char *const *choices;  /* NULL-terminated, KT_ENUM and restricted KT_STRING */
    size_t off, size;            /* storage in wf_config */
    const char *doc;             /* one line */
    unsigned char digest;        /* how the key enters a product's input digest (below) */
} key_desc;

/* A key shapes the product's bits (KD_SHAPES, the default, so a new key is in the digest
 * unless marked), or is left out of the configuration part of tools/digest.h's digest:
 * KD_RUN never changes a byte of an image product (how the program runs); KD_FILE names a
 * file whose content is digested instead (a path may move, the bytes count); KD_PART has a
 * part of its own (the seed). */
enum { KD_SHAPES, KD_RUN, KD_FILE, KD_PART, KD_CORR };
/* KD_CORR: shapes the product only with a correlated-read-noise effect on (firmware/corrnoise.h),
 * and is in the digest only then: products made without them keep the digest they had before
 * those keys existed. */
#define DIGEST(d) .digest = (d)

#define FIELD(m) .off = offsetof(wf_config, m), .size = sizeof(((wf_config *)0)->m)
#define MIN(v) .has_lo = 1, .lo = (v)
#define ABOVE(v) .has_lo = 1, .lo_open = 1, .lo = (v)
#define MAX(v) .has_hi = 1, .hi = (v)

static const char *const modes[] = {"ramp", "single", NULL};
static const char *const samplings[] = {"per-read", "direct", "moments", NULL};

static const char *const scene_kinds[] = {"synthetic", "catalog", "grid", "galsim", NULL};
static const char *const pupil_bins[] = {"1", "2", "4", "8", NULL};
static const char *const compressions[] = {"auto", "none", "rice", NULL};
static const char *const keep_drop[] = {"keep", "drop", NULL};
_Static_assert(WF_COMPRESS_AUTO == 0 && WF_COMPRESS_NONE == 1 && WF_COMPRESS_RICE == 2,
               "products.compress choices follow WF_COMPRESS_*");

static const key_desc keys[] = {
    {.name = "seed", .type = KT_UINT, .unit = "", .def = "1", FIELD(seed),
     DIGEST(KD_PART), .doc = "Seed of every random number; products are bit-identical for a given seed."},

    {.name = "exposure.id", .type = KT_UINT, .unit = "", .def = "1", MIN(0), MAX(4294967295.0),
     FIELD(ro.exposure),
     .doc = "Exposure number: a noise key and the packet header's exposure id."},
    {.name = "exposure.sca", .type = KT_UINT, .unit = "", .def = "1", MIN(1), MAX(18),
     FIELD(ro.sca), .doc = "Sensor chip assembly simulated."},
    {.name = "exposure.filter", .type = KT_STRING, .unit = "", .def = "Y106", .filter = 1,
     FIELD(filter), .doc = "Filter element (W146 is also called W149)."},
    {.name = "exposure.mode", .type = KT_ENUM, .unit = "", .def = "ramp", .choices = modes,
     FIELD(ro.mode),
     .doc = "`ramp`: read up the ramp and grouped by the MA table; `single`: GalSim's "
            "single-frame chain."},
    {.name = "exposure.sampling", .type = KT_ENUM, .unit = "", .def = "per-read",
     .choices = samplings, FIELD(ro.sampling),
     .doc = "Ramp mode: draw every read (`per-read`), each resultant at once (`direct`: every "
            "interval's electrons, exact for a linear pixel), or each resultant's group mean from its "
            "exact mean and covariance (`moments`: three draws per resultant, equivalent to per-read "
            "to second order; docs/ACCURACY.md)."},
    {.name = "exposure.exptime", .type = KT_DOUBLE, .unit = "s", .def = "300", ABOVE(0),
     MAX(WF_EXPOSURE_TIME_MAX), FIELD(ro.exptime),
     .doc = "Exposure time in single mode; ramp mode takes it from the MA table (its last read, "
            "within the same bound). At most a day, ~90x the longest built-in MA table (11: 977 s): "
            "the cosmic-ray buffers grow with it (a full-width 64-row tile counts ~2x10^5 hits in a day "
            "at the default rate)."},

    {.name = "readout.ncols", .type = KT_INT, .unit = "pixels", .def = "4088", MIN(1), MAX(4088),
     FIELD(ro.ncols), .doc = "Active columns read (a smaller SCA for quick runs)."},
    {.name = "readout.nrows", .type = KT_INT, .unit = "pixels", .def = "4088", MIN(1), MAX(4088),
     FIELD(ro.nrows), .doc = "Active rows read."},
    {.name = "readout.tile_rows", .type = KT_INT, .unit = "rows", .def = "32", MIN(1), MAX(4088),
     FIELD(ro.tile_rows),
     DIGEST(KD_RUN), .doc = "Rows per firmware tile; sets memory, never the result. Clamped to readout.nrows."},
    {.name = "readout.frame_time", .type = KT_DOUBLE, .unit = "s", .def = NULL, ABOVE(0),
     MAX(WF_FRAME_TIME_MAX), FIELD(frame_time),
     .doc = "Time per full-frame read (romanisim's value; older tools 3.04). At most 100 s, 30x "
            "the flight value, room for what-if studies with every size derived from it finite; "
            "the ramp's exposure time (reads x frame time) is held to a day too (exposure.exptime)."},
    {.name = "readout.ma_table", .type = KT_STRING, .unit = "", .def = "6", .nonempty = 1,
     FIELD(ma_table),
     DIGEST(KD_FILE), .doc = "MultiAccum table: built-in Rev F `4`, `6`, `11`, or a table file (path from the "
            "working directory)."},
    {.name = "readout.compress", .type = KT_BOOL, .unit = "", .def = "true",
     FIELD(ro.compress), DIGEST(KD_RUN), .doc = "Deflate packet payloads of a written stream (--stream); the in-process link of expose, demo and survey run is never deflated (the FITS is the same either way)."},

    {.name = "run.threads", .type = KT_INT, .unit = "", .def = "1", MIN(1), MAX(1024),
     FIELD(threads), DIGEST(KD_RUN), .doc = "Readout instances run in parallel; products do not depend on it."},
    {.name = "run.quiet", .type = KT_BOOL, .unit = "", .def = "false", FIELD(quiet),
     DIGEST(KD_RUN), .doc = "Do not report progress and files written on stderr."},
    {.name = "run.uncached_writes", .type = KT_BOOL, .unit = "", .def = "true", FIELD(uncached_writes),
     DIGEST(KD_RUN), .doc = "Write products past the page cache (O_DIRECT) on file systems that state its alignment (ext4, xfs; not tmpfs): a single-frame SCA's 200 MB then cost the device's transfer, not a copy into fresh cache pages. false: through the page cache. The bytes written are the same."},
    {.name = "products.compress", .type = KT_ENUM, .unit = "", .def = "auto", .choices = compressions,
     FIELD(products.compress),
     .doc = "Image HDUs of a product: `rice`: tile-compressed FITS (one row a tile; integer HDUs, DQ and RESULTANTS, Rice-coded losslessly; SCI and ERR quantized, see products.quantize_level, with subtractive dithering seeded from seed, exposure and SCA, then Rice-coded); `none`: plain images; `auto`: rice for `survey run`, none for expose, demo and assemble (exact pixels for comparisons with GalSim and the accuracy tools). Astropy and cfitsio read both alike."},
    {.name = "products.quantize_level", .type = KT_DOUBLE, .unit = "", .def = "16", MIN(0),
     FIELD(products.quantize_level),
     .doc = "With products.compress rice: SCI and ERR are rounded to steps of (noise / q), the noise being cfitsio's estimate for each row from its pixel differences; dithered rounding adds noise of rms (step / sqrt 12) = noise / (3.46 q) and no bias (docs/SURVEY.md measures it on photometry). 0: floats kept exact (GZIP, lossless); otherwise at least 1."},
    {.name = "products.resultants", .type = KT_ENUM, .unit = "", .def = "keep", .choices = keep_drop,
     FIELD(products.drop_resultants),
     .doc = "Up-the-ramp products: `keep` writes the RESULTANTS cube (ADU, ~70% of an uncompressed product); `drop` leaves it out: SCI, ERR, DQ, COSMICRAYS and the truth file are written all the same."},
    {.name = "products.border", .type = KT_BOOL, .unit = "", .def = "false", FIELD(products.border),
     DIGEST(KD_CORR),
     .doc = "With detector.effects.refpix: write the 4-pixel reference border as it was downlinked, HDUs REFROWS (uint16 ADU [resultant][8][ncols + 8]: full-frame rows 0-3, then the last four) and REFCOLS ([resultant][nrows][8]: full-frame columns 0-3, then the last four, of each active row); SCI, ERR, DQ, RESULTANTS and their WCS stay the active area's."},
    {.name = "run.scene_cache", .type = KT_STRING, .unit = "", .def = "auto", .nonempty = 1, FIELD(scene_cache),
     DIGEST(KD_RUN),
     .doc = "Folder that keeps each static scene's plane (the galaxies' and stars' rates summed, 4 bytes a pixel: 67 MB a full SCA) for the later exposures of the same pointing, PA, filter and SCA, which then draw only the supernovae (sim/draw/plane_cache.h); the products are the same bytes either way. `auto`: <run.out>/scene_cache for survey run, none for expose and demo (which use a folder named here); `none`: off."},
    {.name = "run.scene_cache_gib", .type = KT_DOUBLE, .unit = "GiB", .def = "8", MIN(0), FIELD(scene_cache_gib),
     DIGEST(KD_RUN),
     .doc = "Room the scene cache's planes may take on disk; beyond it the least recently used go. A survey run in plan order reuses a plane after one visit's exposures of the SCA (64 in the deep tier's plan): give each SCA a run works on at once that many planes."},
    {.name = "run.out", .type = KT_STRING, .unit = "", .def = "out", .nonempty = 1,
     FIELD(out_dir), DIGEST(KD_RUN), .doc = "Directory that receives the products."},

    {.name = "detector.dark_current", .type = KT_DOUBLE, .unit = "e-/pixel/s", MIN(0),
     FIELD(ro.det.dark_current), .doc = "Dark current."},
    {.name = "detector.read_noise", .type = KT_DOUBLE, .unit = "e-", MIN(0),
     FIELD(ro.det.read_noise_e),
     .doc = "Read noise rms: per read in ramp mode, per exposure in single mode."},
    {.name = "detector.gain", .type = KT_DOUBLE, .unit = "e-/ADU", ABOVE(0), FIELD(ro.det.gain),
     .doc = "Conversion gain."},
    {.name = "detector.nl_beta", .type = KT_DOUBLE, .unit = "1/e-", FIELD(ro.det.nl_beta),
     .doc = "Classical nonlinearity: q_meas = q + beta q^2."},
    {.name = "detector.recip_alpha", .type = KT_DOUBLE, .unit = "", FIELD(ro.det.recip_alpha),
     .doc = "Reciprocity failure: q' = q (q / (t f0))^(alpha / ln 10)."},
    {.name = "detector.recip_f0", .type = KT_DOUBLE, .unit = "e-/s", ABOVE(0),
     FIELD(ro.det.recip_f0), .doc = "Reference flux of the reciprocity-failure law."},
    {.name = "detector.ipc", .type = KT_KERNEL, .unit = "",
     .doc_default = "GalSim kernel / its sum (below)", FIELD(ro.det.ipc),
     .doc = "IPC kernel, rows top to bottom; used as given: it must sum to 1 within 1e-6."},
    {.name = "detector.full_well", .type = KT_DOUBLE, .unit = "e-", ABOVE(0),
     FIELD(ro.det.full_well), .doc = "Charge at which a pixel saturates."},
    {.name = "detector.adc_max", .type = KT_DOUBLE, .unit = "ADU", MIN(1), MAX(65535),
     FIELD(ro.det.adc_max), .doc = "Ceiling of the 16-bit ADC."},
    {.name = "detector.bias", .type = KT_DOUBLE, .unit = "ADU", MIN(0), MAX(65535),
     FIELD(ro.det.bias_adu),
     .doc = "ADC offset added to every read so read noise never clips at 0 ADU; subtracted on the ground. Set 0 (with effects.saturation off) to compare single-frame ADU with GalSim."},
    {.name = "detector.cr_rate", .type = KT_DOUBLE, .unit = "hits/cm^2/s", MIN(0),
     FIELD(ro.det.cr_rate), .doc = "Cosmic-ray hit rate at L2."},
    {.name = "detector.pixel_um", .type = KT_DOUBLE, .unit = "um", ABOVE(0),
     FIELD(ro.det.pixel_um), .doc = "Pixel pitch, for cosmic-ray tracks."},
    {.name = "detector.depth_um", .type = KT_DOUBLE, .unit = "um", ABOVE(0),
     FIELD(ro.det.depth_um), .doc = "Sensitive depth, for cosmic-ray tracks."},
    {.name = "detector.cr_lmin_um", .type = KT_DOUBLE, .unit = "um", ABOVE(0),
     FIELD(ro.det.cr_lmin_um),
     .doc = "Shortest cosmic-ray path length (below detector.cr_lmax_um)."},
    {.name = "detector.cr_lmax_um", .type = KT_DOUBLE, .unit = "um", ABOVE(0),
     FIELD(ro.det.cr_lmax_um), .doc = "Longest cosmic-ray path length."},
    {.name = "detector.cr_slope", .type = KT_DOUBLE, .unit = "", FIELD(ro.det.cr_slope),
     .doc = "Power-law index of the path-length distribution."},
    {.name = "detector.cr_dedx_loc", .type = KT_DOUBLE, .unit = "eV/um", MIN(0),
     FIELD(ro.det.cr_dedx_loc), .doc = "Location of the Moyal energy-loss distribution."},
    {.name = "detector.cr_dedx_scale", .type = KT_DOUBLE, .unit = "eV/um", ABOVE(0),
     FIELD(ro.det.cr_dedx_scale), .doc = "Scale of the Moyal energy-loss distribution."},
    {.name = "detector.cr_ev_per_e", .type = KT_DOUBLE, .unit = "eV", ABOVE(0),
     FIELD(ro.det.cr_ev_per_e), .doc = "Energy deposited per electron collected."},
    {.name = "detector.rn1f_corr", .type = KT_DOUBLE, .unit = "e-", MIN(0), MAX(1000),
     FIELD(ro.det.rn1f_corr_e), DIGEST(KD_CORR),
     .doc = "With effects.read_1f: rms per read of the 1/f noise shared by all 32 channels (NGHXRG's JWST value; SPEC gives none)."},
    {.name = "detector.rn1f_uncorr", .type = KT_DOUBLE, .unit = "e-", MIN(0), MAX(1000),
     FIELD(ro.det.rn1f_uncorr_e), DIGEST(KD_CORR),
     .doc = "With effects.read_1f: rms per read of each channel's own 1/f noise."},
    {.name = "detector.channel_offset", .type = KT_DOUBLE, .unit = "ADU", MIN(0), MAX(10000),
     FIELD(ro.det.channel_offset_adu), DIGEST(KD_CORR),
     .doc = "With effects.channel_offsets: rms of the channels' offsets (one draw per channel and exposure)."},

    {.name = "detector.effects.photon_noise", .type = KT_BOOL, .unit = "",
     FIELD(ro.det.on.photon_noise), .doc = "Poisson noise on the signal."},
    {.name = "detector.effects.reciprocity", .type = KT_BOOL, .unit = "",
     FIELD(ro.det.on.reciprocity), .doc = "Reciprocity failure."},
    {.name = "detector.effects.dark", .type = KT_BOOL, .unit = "", FIELD(ro.det.on.dark),
     .doc = "Dark current (Poisson)."},
    {.name = "detector.effects.nonlinearity", .type = KT_BOOL, .unit = "",
     FIELD(ro.det.on.nonlinearity), .doc = "Classical nonlinearity."},
    {.name = "detector.effects.ipc", .type = KT_BOOL, .unit = "", FIELD(ro.det.on.ipc),
     .doc = "Interpixel capacitance."},
    {.name = "detector.effects.read_noise", .type = KT_BOOL, .unit = "",
     FIELD(ro.det.on.read_noise), .doc = "Gaussian read noise."},
    {.name = "detector.effects.quantize", .type = KT_BOOL, .unit = "", FIELD(ro.det.on.quantize),
     .doc = "ADU quantization (round half to even)."},
    {.name = "detector.effects.saturation", .type = KT_BOOL, .unit = "",
     FIELD(ro.det.on.saturation), .doc = "Full-well and ADC saturation."},
    {.name = "detector.effects.cosmic_rays", .type = KT_BOOL, .unit = "",
     FIELD(ro.det.on.cosmic_rays), .doc = "Cosmic-ray hits."},
    {.name = "detector.effects.read_1f", .type = KT_BOOL, .unit = "", FIELD(ro.det.on.read_1f), DIGEST(KD_CORR),
     .doc = "Correlated 1/f read noise along each output channel's readout order (ramp mode; docs/ARCHITECTURE.md)."},
    {.name = "detector.effects.channel_offsets", .type = KT_BOOL, .unit = "", FIELD(ro.det.on.channel_offsets), DIGEST(KD_CORR),
     .doc = "A constant offset per output channel (ramp mode)."},
    {.name = "detector.effects.refpix", .type = KT_BOOL, .unit = "", FIELD(ro.det.on.refpix), DIGEST(KD_CORR),
     .doc = "The 4-pixel reference border is read out and sent; the assembler corrects the resultants with it "
            "before the ramp fit (ramp mode)."},
    {.name = "detector.effects.persistence", .type = KT_BOOL, .unit = "", FIELD(ro.persist.on),
     .doc = "Persistence: charge of earlier exposures of the SCA released (Fermi model); only "
            "`survey run` has earlier exposures, rebuilt for each product from the plan (docs/ARCHITECTURE.md, "
            "Persistence); `expose` and `demo` make a lone exposure, which releases nothing."},

    {.name = "detector.persistence.window", .type = KT_DOUBLE, .unit = "s", .def = "3600", MIN(0),
     MAX(WF_EXPOSURE_TIME_MAX), FIELD(persist.window),
     .doc = "Earlier exposures of the same SCA that ended at most this long before an exposure's start leave it charge."},
    {.name = "detector.persistence.depth", .type = KT_INT, .unit = "exposures", .def = "8", MIN(0),
     MAX(WF_PERSIST_DEPTH_MAX), FIELD(persist.depth),
     .doc = "At most this many of them, the most recent (0: none)."},
    {.name = "detector.persistence.min_stimulus", .type = KT_DOUBLE, .unit = "e-", .def = "5000", MIN(2),
     MAX(1e9), FIELD(persist.min_stimulus),
     .doc = "Pixels that collected less than this in an earlier exposure release nothing (its objects' charge, sky left out)."},
    {.name = "detector.persistence.A", .type = KT_DOUBLE, .unit = "e-/s", MIN(0), FIELD(ro.persist.model.A),
     .doc = "Fermi model amplitude (GalSim persistence_fermi_parameters)."},
    {.name = "detector.persistence.x0", .type = KT_DOUBLE, .unit = "e-", ABOVE(0), FIELD(ro.persist.model.x0),
     .doc = "Fermi model stimulus scale and edge."},
    {.name = "detector.persistence.dx", .type = KT_DOUBLE, .unit = "e-", ABOVE(0), FIELD(ro.persist.model.dx),
     .doc = "Fermi model edge width."},
    {.name = "detector.persistence.alpha", .type = KT_DOUBLE, .unit = "", MIN(-10), MAX(10),
     FIELD(ro.persist.model.alpha), .doc = "Fermi model power of the stimulus."},
    {.name = "detector.persistence.gamma", .type = KT_DOUBLE, .unit = "", MIN(0), MAX(10),
     FIELD(ro.persist.model.gamma), .doc = "Power of the time since the stimulus ended (r)."},
    {.name = "detector.persistence.half_well", .type = KT_DOUBLE, .unit = "e-", ABOVE(0),
     FIELD(ro.persist.model.half_well), .doc = "Below this stimulus the release is linear in it."},

    {.name = "pointing.ra", .type = KT_DOUBLE, .unit = "deg", .def = "71", MIN(0), MAX(360),
     FIELD(ra), .doc = "Boresight right ascension (deep field centre by default)."},
    {.name = "pointing.dec", .type = KT_DOUBLE, .unit = "deg", .def = "-53", MIN(-89.999), MAX(89.999),
     FIELD(dec), .doc = "Boresight declination."},
    {.name = "pointing.pa", .type = KT_DOUBLE, .unit = "deg", .def = "30", MIN(-360), MAX(360),
     FIELD(pa), .doc = "Observatory position angle, as galsim.roman.getWCS(world_pos, PA=...)."},
    {.name = "exposure.mjd", .type = KT_DOUBLE, .unit = "d", .def = "61420", MIN(15021), MAX(88069),
     FIELD(mjd), .doc = "Exposure mid-time (MJD, 1900-2100): sky level and supernova epochs."},
    {.name = "scene.kind", .type = KT_ENUM, .unit = "", .def = "synthetic", .choices = scene_kinds,
     FIELD(scene_kind),
     .doc = "`synthetic`: galaxies and stars generated from the seed around the pointing; "
            "`catalog`: scene.catalog and scene.stars (a GalSim benchmark scene in scene.catalog is "
            "recognised by its columns and read as `galsim` reads it); `galsim`: a GalSim benchmark "
            "scene CSV in scene.catalog; `grid`: sky plus a grid of Gaussian sources (scene.grid.*)."},
    {.name = "scene.catalog", .type = KT_STRING, .unit = "", .def = "", FIELD(catalog),
     DIGEST(KD_FILE), .doc = "Galaxy catalog (FITS table or CSV, docs/CATALOGS.md), or the GalSim scene CSV."},
    {.name = "scene.stars", .type = KT_STRING, .unit = "", .def = "", FIELD(stars),
     DIGEST(KD_FILE), .doc = "Star catalog (FITS table or CSV); empty: no stars for scene.kind catalog."},
    {.name = "scene.sky", .type = KT_BOOL, .unit = "", .def = "true", FIELD(sky_on),
     .doc = "Add the sky (zodiacal light, stray light, thermal) to object scenes; false for checks on an empty sky."},
    {.name = "scene.stray_light", .type = KT_DOUBLE, .unit = "", .def = "0.1", MIN(0), MAX(10), FIELD(stray_light),
     .doc = "Stray light as a fraction of the zodiacal light (GalSim's stray_light_fraction)."},
    {.name = "scene.stamp_pool", .type = KT_DOUBLE, .unit = "MiB", .def = "24", MIN(1), MAX(4096), FIELD(stamp_pool_mib),
     .doc = "Stamp pool of each readout thread (float stamps); a stamp that does not fit is drawn in pieces, "
            "row band by row band: never dropped, but redrawn."},
    {.name = "scene.flux_fraction", .type = KT_DOUBLE, .unit = "", .def = "0.995", ABOVE(0.5), MAX(0.99999),
     FIELD(flux_fraction), .doc = "Each stamp holds at least this fraction of its object's flux."},
    {.name = "scene.noise_tolerance", .type = KT_DOUBLE, .unit = "sky sigma", .def = "1", MIN(0), MAX(100),
     FIELD(noise_tolerance),
     .doc = "Faint objects are drawn with looser knobs where the error bound of each stays below this many times "
            "the sky noise of one pixel over the exposure: light wrapping into the Fourier box (at most 5% of "
            "the object, never stricter than the default 0.5%), Fourier modes dropped (below at most 1e-3 of "
            "the object, and beyond where the sum of those left out stays within it), the knot lattice's aliasing (up to 1e-2 of the knots' flux), knots drawn as the smooth disk "
            "(when the knots' flux times the PSF's brightest pixel is within it), and the PSF wing placed "
            "without the object's own blur (psf.core_radius). 0: the same knobs for every object. Errors and "
            "costs: docs/ACCURACY.md."},
    {.name = "scene.synthetic.h_faint", .type = KT_DOUBLE, .unit = "mag(AB)", .def = "26", ABOVE(15), MAX(32),
     FIELD(synth.h_faint),
     .doc = "Faintest H158 magnitude of the synthetic field's galaxies (26: ~152 per arcmin^2; beyond 25.5 the "
            "counts rise 0.17 dex/mag). Deep coadds (make paper) need the field to go fainter than they reach."},
    {.name = "scene.synthetic.star_density", .type = KT_DOUBLE, .unit = "1/arcmin^2", .def = "2.5", MIN(0),
     MAX(1000), FIELD(synth.star_density),
     .doc = "Stars per arcmin^2 with 12 <= V <= 27 in the synthetic field (the counts' shape is fixed; "
            "scene.synthetic.star_v_faint extends it)."},
    {.name = "scene.synthetic.star_v_faint", .type = KT_DOUBLE, .unit = "mag", .def = "27", ABOVE(12), MAX(32),
     FIELD(synth.star_v_faint),
     .doc = "Faintest V magnitude of the synthetic field's stars (the halo's ~0.1 dex/mag counts carried on)."},
    {.name = "psf.pupil_bin", .type = KT_ENUM, .unit = "", .def = "8", .choices = pupil_bins,
     FIELD(pupil_bin), .doc = "Pupil-plane binning, as GalSim's pupil_bin (8 fast, 4 or 2 for bright stars)."},
    {.name = "psf.nlambda", .type = KT_INT, .unit = "", .def = "1", MIN(1), MAX(64), FIELD(psf_nlambda),
     .doc = "1: achromatic PSF at the band's effective wavelength (GalSim's default); n > 1: chromatic, "
            "the photon-weighted PSF of a flat-f_nu source over n slices of the band."},
    {.name = "psf.jitter", .type = KT_DOUBLE, .unit = "arcsec", .def = "0", MIN(0), MAX(1), FIELD(psf_jitter),
     .doc = "Pointing jitter, Gaussian sigma per axis (0: off; SPEC 2 gives 0.014)."},
    {.name = "psf.diffusion", .type = KT_DOUBLE, .unit = "pixels", .def = "0", MIN(0), MAX(2), FIELD(psf_diffusion),
     .doc = "Charge diffusion, Gaussian sigma per axis (0: off; SPEC 2 gives 0.1)."},
    {.name = "psf.bright_mag", .type = KT_DOUBLE, .unit = "mag(AB)", .def = "15", MIN(-100), MAX(40),
     FIELD(psf_bright_mag),
     .doc = "Stars and SNe brighter than this are drawn with a wide PSF (28\", pupil_bin 4 or finer: halo and "
            "spikes), built only when one is present; below -50: never."},
    {.name = "psf.core_radius", .type = KT_DOUBLE, .unit = "arcsec", .def = "2", MIN(0), MAX(60),
     FIELD(psf_core_radius),
     .doc = "Objects are drawn as object x PSF core (the PSF within this radius, tapered from 2/3 of it) in a "
            "Fourier box sized by the core, plus flux x the PSF's wing beyond; 0: the whole PSF in every box "
            "(exact, slower). Errors and costs: docs/ACCURACY.md."},
    {.name = "psf.core_levels", .type = KT_INT, .unit = "", .def = "3", MIN(1), MAX(4), FIELD(psf_core_levels),
     .doc = "Cores of radius psf.core_radius halved at each level (3: 2\", 1\", 0.5\"); each object takes the "
            "smallest whose wing error its sky noise allows (scene.noise_tolerance), so faint galaxies get small "
            "Fourier boxes. Each level costs ~3 MB and ~20 ms once."},
    {.name = "psf.oversample", .type = KT_INT, .unit = "", .def = "4", MIN(2), MAX(8),
     FIELD(psf_oversample), .doc = "PSF image sampling: 0.11 / oversample arcsec."},
    {.name = "scene.sky_rate", .type = KT_DOUBLE, .unit = "e-/pixel/s", MIN(0),
     FIELD(sky_rate),
     .doc = "Uniform sky of the grid scene (the others use the sky model). Default: Y106 zodiacal light at the deep field, 29.7 e-/s/arcsec^2, "
            "x 0.11^2 arcsec^2 x (1 + 0.1 stray light), + 0 thermal; it does not follow "
            "exposure.filter."},
    {.name = "scene.grid.flux", .type = KT_DOUBLE, .unit = "e-/s", .def = "1000", MIN(0),
     FIELD(grid_flux), .doc = "Total flux of each point source of the built-in grid scene."},
    {.name = "scene.grid.sigma", .type = KT_DOUBLE, .unit = "pixels", .def = "1", ABOVE(0),
     FIELD(grid_sigma), .doc = "Gaussian sigma of the grid's sources."},
    {.name = "scene.grid.spacing", .type = KT_INT, .unit = "pixels", .def = "256", MIN(1),
     MAX(1000000), FIELD(grid_spacing),
     .doc = "Distance between grid sources; the first is at spacing/2."},

    {.name = "sn.model", .type = KT_STRING, .unit = "", .def = "", FIELD(sn.model),
     DIGEST(KD_FILE), .doc = "SALT model directory; empty: `paths.data`/salt3/salt3-k21."},
    {.name = "sn.h0", .type = KT_DOUBLE, .unit = "km/s/Mpc", .def = "70", MIN(1), MAX(1000), FIELD(sn.h0),
     DIGEST(KD_FILE), .doc = "Hubble constant of the flat LCDM cosmology (SPEC 5)."},
    {.name = "sn.om", .type = KT_DOUBLE, .unit = "", .def = "0.315", MIN(0), MAX(1), FIELD(sn.om),
     DIGEST(KD_FILE), .doc = "Matter density of the flat LCDM cosmology."},
    {.name = "sn.rate", .type = KT_STRING, .unit = "1/yr/Mpc^3", .def = "POWERLAW2 2.5e-5 1.5 0 1; POWERLAW2 9.7e-5 -0.5 1 3",
     .nonempty = 1, FIELD(sn.rate),
     DIGEST(KD_FILE), .doc = "Volumetric SN Ia rate as SNANA POWERLAW2 pieces `A B zmin zmax` (R = A (1+z)^B), separated by ';'."},
    {.name = "sn.zmin", .type = KT_DOUBLE, .unit = "", .def = "0.06", MIN(0), MAX(10), FIELD(sn.zmin),
     DIGEST(KD_FILE), .doc = "Lowest redshift generated."},
    {.name = "sn.zmax", .type = KT_DOUBLE, .unit = "", .def = "2.99", MIN(0), MAX(10), FIELD(sn.zmax),
     DIGEST(KD_FILE), .doc = "Highest redshift generated."},
    {.name = "sn.alpha", .type = KT_DOUBLE, .unit = "", .def = "0.14", MIN(-WF_SNPOP_ALPHA_LIMIT), MAX(WF_SNPOP_ALPHA_LIMIT), FIELD(sn.alpha),
     DIGEST(KD_FILE), .doc = "Stretch standardisation: x0 = 10^(-0.4 (mu - alpha x1 + beta c + delta)) / 1e-12."},
    {.name = "sn.beta", .type = KT_DOUBLE, .unit = "", .def = "3.1", MIN(-WF_SNPOP_BETA_LIMIT), MAX(WF_SNPOP_BETA_LIMIT), FIELD(sn.beta),
     DIGEST(KD_FILE), .doc = "Colour standardisation."},
    {.name = "sn.sigma_int", .type = KT_DOUBLE, .unit = "mag", .def = "0.1", MIN(0), MAX(2), FIELD(sn.sigma_int),
     DIGEST(KD_FILE), .doc = "Coherent intrinsic scatter (Gaussian sigma)."},
    {.name = "sn.x1.peak", .type = KT_DOUBLE, .unit = "", .def = "0.973", MIN(-WF_SNPOP_X1_LIMIT), MAX(WF_SNPOP_X1_LIMIT), FIELD(sn.x1[0]),
     DIGEST(KD_FILE), .doc = "Stretch: peak of the asymmetric Gaussian (G10 high-z, Scolnic & Kessler 2016)."},
    {.name = "sn.x1.sigma_minus", .type = KT_DOUBLE, .unit = "", .def = "1.472", MIN(0), MAX(10), FIELD(sn.x1[1]),
     DIGEST(KD_FILE), .doc = "Stretch: sigma below the peak."},
    {.name = "sn.x1.sigma_plus", .type = KT_DOUBLE, .unit = "", .def = "0.222", MIN(0), MAX(10), FIELD(sn.x1[2]),
     DIGEST(KD_FILE), .doc = "Stretch: sigma above the peak."},
    {.name = "sn.x1.min", .type = KT_DOUBLE, .unit = "", .def = "-3", MIN(-WF_SNPOP_X1_LIMIT), MAX(WF_SNPOP_X1_LIMIT), FIELD(sn.x1[3]),
     DIGEST(KD_FILE), .doc = "Stretch: lower truncation."},
    {.name = "sn.x1.max", .type = KT_DOUBLE, .unit = "", .def = "2", MIN(-WF_SNPOP_X1_LIMIT), MAX(WF_SNPOP_X1_LIMIT), FIELD(sn.x1[4]),
     DIGEST(KD_FILE), .doc = "Stretch: upper truncation."},
    {.name = "sn.c.peak", .type = KT_DOUBLE, .unit = "", .def = "-0.054", MIN(-WF_SNPOP_C_LIMIT), MAX(WF_SNPOP_C_LIMIT), FIELD(sn.c[0]),
     DIGEST(KD_FILE), .doc = "Colour: peak of the asymmetric Gaussian."},
    {.name = "sn.c.sigma_minus", .type = KT_DOUBLE, .unit = "", .def = "0.043", MIN(0), MAX(2), FIELD(sn.c[1]),
     DIGEST(KD_FILE), .doc = "Colour: sigma below the peak."},
    {.name = "sn.c.sigma_plus", .type = KT_DOUBLE, .unit = "", .def = "0.101", MIN(0), MAX(2), FIELD(sn.c[2]),
     DIGEST(KD_FILE), .doc = "Colour: sigma above the peak."},
    {.name = "sn.c.min", .type = KT_DOUBLE, .unit = "", .def = "-0.3", MIN(-WF_SNPOP_C_LIMIT), MAX(WF_SNPOP_C_LIMIT), FIELD(sn.c[3]),
     DIGEST(KD_FILE), .doc = "Colour: lower truncation."},
    {.name = "sn.c.max", .type = KT_DOUBLE, .unit = "", .def = "0.5", MIN(-WF_SNPOP_C_LIMIT), MAX(WF_SNPOP_C_LIMIT), FIELD(sn.c[4]),
     DIGEST(KD_FILE), .doc = "Colour: upper truncation."},
    {.name = "sn.host.dztol", .type = KT_STRING, .unit = "", .def = "0.01,0,0", .nonempty = 1, FIELD(sn.dztol),
     DIGEST(KD_FILE), .doc = "Host redshift tolerance a0,a1,a2: |dz| <= a0 + a1 z + a2 z^2 (SNANA HOSTLIB_DZTOL)."},
    {.name = "sn.host.fmax", .type = KT_DOUBLE, .unit = "", .def = "0.99", MIN(0), MAX(0.999999), FIELD(sn.fmax),
     DIGEST(KD_FILE), .doc = "Largest enclosed-flux fraction of the host's light a SN is placed at."},
    {.name = "sn.host.hostless", .type = KT_BOOL, .unit = "", .def = "false", FIELD(sn.hostless),
     DIGEST(KD_FILE), .doc = "Generate without a host catalog (every SN hostless, placed uniformly)."},

    {.name = "paths.data", .type = KT_STRING, .unit = "", .dir = 1,
     .doc_default = "`$WFISIM_DATA`, else empty", FIELD(data_dir),
     DIGEST(KD_FILE), .doc = "Directory of the shared data (`roman/`, `salt3/`, ...); empty: built-in values."},
    {.name = "paths.reference", .type = KT_STRING, .unit = "", .dir = 1,
     .doc_default = "`$WFISIM_REFERENCE`, else empty", FIELD(reference_dir),
     DIGEST(KD_RUN), .doc = "Directory of the reference outputs used by comparisons; empty: none."},
};

#define NKEYS ((int)(sizeof keys / sizeof keys[0]))

static void *key_ptr(wf_config *cfg, const key_desc *k) { return (char *)cfg + k->off; }

static const void *key_cptr(const wf_config *cfg, const key_desc *k)
{
    return (const char *)cfg + k->off;
}

static int find_key(const char *name)
{
    for (int i = 0; i < NKEYS; i++)
        if (!strcmp(keys[i].name, name)) return i;
    return -1;
}

/* A section is a proper prefix of some key ending at a dot: "detector", "detector.effects". */
static const char *first_key_in(const char *section)
{
    size_t n = strlen(section);
    for (int i = 0; i < NKEYS; i++)
        if (!strncmp(keys[i].name, section, n) && keys[i].name[n] == '.') return keys[i].name;
    return "";
}

static int is_section(const char *name) { return *first_key_in(name) != '\0'; }

/* ---- messages ----------------------------------------------------------------------- */

/* Where a value came from: a YAML file and 1-based line, or a --set origin. */
typedef struct where {
    const char *file;
    int line;
    const char *origin;
} where;

static const char *where_text(const where *w, char *buf, size_t n)
{
    if (w->file && w->line > 0)
        snprintf(buf, n, "%s:%d", w->file, w->line);
    else
        snprintf(buf, n, "%s", w->file ? w->file : w->origin);
    return buf;
}

static wf_status key_error(wf_status code, const where *w, const char *key, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

static wf_status key_error(wf_status code, const where *w, const char *key, const char *fmt, ...)
{
    char at[WF_PATH_MAX + 32], what[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    return wf_error(code, "%s: %s: %s", where_text(w, at, sizeof at), key, what);
}

static int edit_distance(const char *a, const char *b)
{
    int la = (int)strlen(a), lb = (int)strlen(b);
    int row[128];
    if (la > 127 || lb > 127) return INT_MAX;
    for (int j = 0; j <= lb; j++) row[j] = j;
    for (int i = 1; i <= la; i++) {
        int diag = row[0];
        row[0] = i;
        for (int j = 1; j <= lb; j++) {
            int up = row[j];
            int best = diag + (a[i - 1] != b[j - 1]);
            if (up + 1 < best) best = up + 1;
            if (row[j - 1] + 1 < best) best = row[j - 1] + 1;
            row[j] = best;
            diag = up;
        }
    }
    return row[lb];
}

static const char *last_part(const char *name)
{
    const char *dot = strrchr(name, '.');
    return dot ? dot + 1 : name;
}

/* The closest key or section to a misspelt name, or NULL when none is plausibly meant.
 * A key with the same last part wins first: that catches a right name in a wrong section. */
static const char *suggest(const char *name, char *buf, size_t n)
{
    for (int i = 0; i < NKEYS; i++)
        if (!strcmp(last_part(keys[i].name), last_part(name))) {
            snprintf(buf, n, "%s", keys[i].name);
            return buf;
        }
    int best = INT_MAX;
    for (int i = 0; i < NKEYS; i++) {
        /* every key and every section above it */
        char cand[128];
        snprintf(cand, sizeof cand, "%s", keys[i].name);
        for (;;) {
            int d = edit_distance(name, cand);
            if (d < best) {
                best = d;
                snprintf(buf, n, "%s", cand);
            }
            char *dot = strrchr(cand, '.');
            if (!dot) break;
            *dot = '\0';
        }
    }
    int len = (int)strlen(name);
    return best <= 2 || best <= len / 4 ? buf : NULL;
}

static wf_status unknown_key(const where *w, const char *name, int section)
{
    char hint[128];
    const char *s = suggest(name, hint, sizeof hint);
    const char *what = section ? "unknown section" : "unknown key";
    if (s) return key_error(WF_ERR_INPUT, w, name, "%s (did you mean '%s'?)", what, s);
    return key_error(WF_ERR_INPUT, w, name, "%s (docs/CONFIG.md lists every key)", what);
}

/* ---- values ------------------------------------------------------------------------- */

static void format_double(double v, char *buf, size_t n)
{
    /* whole numbers in full (100000, not 1e+05); otherwise the shortest text that reads
     * back as v, capped where float noise would show */
    if (v == floor(v) && fabs(v) < 1e15) {
        snprintf(buf, n, "%.0f", v);
        return;
    }
    for (int p = 1; p <= 15; p++) {
        snprintf(buf, n, "%.*g", p, v);
        if (strtod(buf, NULL) == v) return;
    }
    snprintf(buf, n, "%.15g", v);
}

static void range_text(const key_desc *k, char *buf, size_t n)
{
    char lo[32], hi[32];
    format_double(k->lo, lo, sizeof lo);
    format_double(k->hi, hi, sizeof hi);
    if (k->has_lo && k->has_hi)
        snprintf(buf, n, "%s%s to %s", k->lo_open ? "above " : "", lo, hi);
    else if (k->has_lo)
        snprintf(buf, n, "%s %s", k->lo_open ? ">" : "≥", lo);
    else if (k->has_hi)
        snprintf(buf, n, "≤ %s", hi);
    else
        snprintf(buf, n, "any");
}

static wf_status check_range(const key_desc *k, double v, const char *text, const where *w)
{
    int low = k->has_lo && (k->lo_open ? !(v > k->lo) : !(v >= k->lo));
    int high = k->has_hi && !(v <= k->hi);
    if (!low && !high) return WF_OK;
    char r[80];
    range_text(k, r, sizeof r);
    return key_error(WF_ERR_RANGE, w, k->name, "%.60s is out of range (allowed: %s%s%s)", text, r,
                     *k->unit ? " " : "", k->unit);
}

static void choices_text(const char *const *choices, char *buf, size_t n)
{
    size_t used = 0;
    buf[0] = '\0';
    for (int i = 0; choices[i]; i++)
        used += (size_t)snprintf(buf + used, used < n ? n - used : 0, "%s%s", i ? ", " : "",
                                 choices[i]);
}

/* The filter names sim/optics/bandpass.c reads, for messages and the reference. */
static void filters_text(char *buf, size_t n)
{
    size_t used = 0;
    buf[0] = '\0';
    for (int i = 0; i < WF_NFILTER; i++)
        used += (size_t)snprintf(buf + used, used < n ? n - used : 0, "%s%s", i ? ", " : "",
                                 wf_filter_name((wf_filter)i));
    if (used < n) snprintf(buf + used, n - used, " (W149: W146)");
}

wf_status wf_config_check_dir(const char *what, const char *path)
{
    if (!path || !*path) return WF_OK;
    struct stat sb;
    if (stat(path, &sb) != 0)
        return wf_error(WF_ERR_IO, "%s: '%s': %s", what, path, strerror(errno));
    if (!S_ISDIR(sb.st_mode))
        return wf_error(WF_ERR_INPUT, "%s: '%s' is not a directory", what, path);
    return WF_OK;
}

static int choice_index(const char *const *choices, const char *text)
{
    for (int i = 0; choices[i]; i++)
        if (!strcmp(choices[i], text)) return i;
    return -1;
}

static int yaml_nonfinite_word(const char *text)
{
    static const char *const words[] = {".nan", ".inf", "+.inf", "-.inf", NULL};
    for (int i = 0; words[i]; i++)
        if (!strcasecmp(text, words[i])) return 1;
    return 0;
}

static wf_status parse_double(const key_desc *k, const char *name, const char *text, double *out,
                              const where *w)
{
    if (yaml_nonfinite_word(text))
        return key_error(WF_ERR_RANGE, w, name, "%.60s is not a finite number", text);
    char *end;
    errno = 0;
    double v = strtod(text, &end);
    if (end == text || *end)
        return key_error(WF_ERR_INPUT, w, name, "expected a number%s%s, got '%.60s'",
                         k && *k->unit ? " in " : "", k ? k->unit : "", text);
    if (!isfinite(v))
        return key_error(WF_ERR_RANGE, w, name, "%.60s is not a finite number", text);
    *out = v;
    return WF_OK;
}

/* Text of one value (a YAML scalar or the right side of --set) into cfg. */
static wf_status set_from_text(wf_config *cfg, const key_desc *k, const char *text,
                               const where *w)
{
    void *dst = key_ptr(cfg, k);
    switch (k->type) {
    case KT_BOOL: {
        static const char *const yes[] = {"true", "yes", "on", "1", NULL};
        static const char *const no[] = {"false", "no", "off", "0", NULL};
        for (int i = 0; yes[i]; i++) {
            if (!strcasecmp(text, yes[i])) {
                *(int *)dst = 1;
                return WF_OK;
            }
            if (!strcasecmp(text, no[i])) {
                *(int *)dst = 0;
                return WF_OK;
            }
        }
        return key_error(WF_ERR_INPUT, w, k->name, "expected true or false, got '%.60s'", text);
    }
    case KT_INT: {
        char *end;
        errno = 0;
        long long v = strtoll(text, &end, 10);
        if (end == text || *end || isspace((unsigned char)text[0]))
            return key_error(WF_ERR_INPUT, w, k->name, "expected an integer, got '%.60s'", text);
        /* strtoll clamps on overflow, which the bounds then reject with their range */
        wf_status st = check_range(k, (double)v, text, w);
        if (st) return st;
        if (errno == ERANGE || v < INT_MIN || v > INT_MAX)
            return key_error(WF_ERR_RANGE, w, k->name, "%.60s is out of range", text);
        *(int *)dst = (int)v;
        return WF_OK;
    }
    case KT_UINT: {
        char *end;
        /* strtoull would quietly wrap a minus sign around */
        if (!isdigit((unsigned char)text[text[0] == '+']))
            return key_error(text[0] == '-' && isdigit((unsigned char)text[1]) ? WF_ERR_RANGE
                                                                                : WF_ERR_INPUT,
                             w, k->name, "expected an unsigned integer, got '%.60s'", text);
        errno = 0;
        unsigned long long v = strtoull(text, &end, 10);
        if (*end)
            return key_error(WF_ERR_INPUT, w, k->name, "expected an unsigned integer, got '%.60s'",
                             text);
        wf_status st = check_range(k, (double)v, text, w);
        if (st) return st;
        if (errno == ERANGE || (k->size == sizeof(uint32_t) && v > UINT32_MAX))
            return key_error(WF_ERR_RANGE, w, k->name, "%.60s is out of range (allowed: 0 to %s)",
                             text, k->size == sizeof(uint32_t) ? "2^32-1" : "2^64-1");
        if (k->size == sizeof(uint32_t)) {
            uint32_t v32 = (uint32_t)v;
            memcpy(dst, &v32, sizeof v32);
        } else {
            uint64_t v64 = v;
            memcpy(dst, &v64, sizeof v64);
        }
        return WF_OK;
    }
    case KT_DOUBLE: {
        double v;
        wf_status st = parse_double(k, k->name, text, &v, w);
        if (!st) st = check_range(k, v, text, w);
        if (!st) *(double *)dst = v;
        return st;
    }
    case KT_STRING:
        if (k->choices && choice_index(k->choices, text) < 0) {
            char c[256];
            choices_text(k->choices, c, sizeof c);
            return key_error(WF_ERR_INPUT, w, k->name, "'%.60s' is not one of %s", text, c);
        }
        if (k->filter) {
            wf_filter f;
            if (!wf_filter_lookup(text, &f)) {
                char c[256];
                filters_text(c, sizeof c);
                return key_error(WF_ERR_INPUT, w, k->name, "'%.60s' is not one of %s", text, c);
            }
            text = wf_filter_name(f);
        }
        if (k->dir && *text) {
            wf_status st = wf_config_check_dir(k->name, text);
            if (st) {
                char msg[2 * WF_PATH_MAX], at[WF_PATH_MAX + 32];
                snprintf(msg, sizeof msg, "%s", wf_error_message());
                return wf_error(st, "%s: %s", where_text(w, at, sizeof at), msg);
            }
        }
        if (k->nonempty && !*text)
            return key_error(WF_ERR_INPUT, w, k->name, "must not be empty");
        if (strlen(text) >= k->size)
            return key_error(WF_ERR_RANGE, w, k->name, "longer than %zu characters",
                             k->size - 1);
        memcpy(dst, text, strlen(text) + 1);
        return WF_OK;
    case KT_ENUM: {
        int i = choice_index(k->choices, text);
        if (i < 0) {
            char c[256];
            choices_text(k->choices, c, sizeof c);
            return key_error(WF_ERR_INPUT, w, k->name, "'%.60s' is not one of %s", text, c);
        }
        *(int *)dst = i;
        return WF_OK;
    }
    case KT_KERNEL:
        break;
    }
    return key_error(WF_ERR_INTERNAL, w, k->name, "no text form for this key");
}

static int yaml_line(const yaml_node_t *node) { return (int)node->start_mark.line + 1; }

static const char *node_kind(const yaml_node_t *node)
{
    switch (node->type) {
    case YAML_MAPPING_NODE: return "a mapping";
    case YAML_SEQUENCE_NODE: return "a list";
    default: return "a scalar";
    }
}

static int is_null_scalar(const yaml_node_t *node)
{
    if (node->data.scalar.style != YAML_PLAIN_SCALAR_STYLE) return 0;
    const char *v = (const char *)node->data.scalar.value;
    return !*v || !strcmp(v, "~") || !strcmp(v, "null") || !strcmp(v, "Null") ||
           !strcmp(v, "NULL");
}

/* A 3x3 list of lists of numbers. Lines in messages are those of the offending element. */
static wf_status set_kernel(wf_config *cfg, const key_desc *k, yaml_document_t *doc,
                            yaml_node_t *node, const where *w0)
{
    where w = *w0;
    if (w.file) w.line = yaml_line(node);
    double kern[3][3], sum = 0.0;
    if (node->type != YAML_SEQUENCE_NODE ||
        node->data.sequence.items.top - node->data.sequence.items.start != 3)
        return key_error(WF_ERR_INPUT, &w, k->name,
                         "expected a 3x3 list of lists of numbers, e.g. [[0,0,0],[0,1,0],[0,0,0]]");
    for (int a = 0; a < 3; a++) {
        yaml_node_t *row = yaml_document_get_node(doc, node->data.sequence.items.start[a]);
        if (w.file) w.line = yaml_line(row);
        if (row->type != YAML_SEQUENCE_NODE ||
            row->data.sequence.items.top - row->data.sequence.items.start != 3)
            return key_error(WF_ERR_INPUT, &w, k->name, "row %d: expected a list of 3 numbers",
                             a + 1);
        for (int b = 0; b < 3; b++) {
            yaml_node_t *e = yaml_document_get_node(doc, row->data.sequence.items.start[b]);
            if (w.file) w.line = yaml_line(e);
            if (e->type != YAML_SCALAR_NODE || e->data.scalar.style != YAML_PLAIN_SCALAR_STYLE)
                return key_error(WF_ERR_INPUT, &w, k->name,
                                 "row %d, column %d: expected a number, got %s", a + 1, b + 1,
                                 e->type == YAML_SCALAR_NODE ? "a quoted string" : node_kind(e));
            char elem[96];
            snprintf(elem, sizeof elem, "%s (row %d, column %d)", k->name, a + 1, b + 1);
            wf_status st = parse_double(NULL, elem, (const char *)e->data.scalar.value,
                                        &kern[a][b], &w);
            if (st) return st;
            sum += kern[a][b];
        }
    }
    if (w.file) w.line = yaml_line(node);
    if (!(fabs(sum - 1.0) <= IPC_SUM_TOL))
        return key_error(WF_ERR_RANGE, &w, k->name,
                         "kernel sums to %.9g; it is used as given and must sum to 1 within %g",
                         sum, IPC_SUM_TOL);
    memcpy(key_ptr(cfg, k), kern, sizeof kern);
    return WF_OK;
}

/* One YAML value node for key k. */
static wf_status set_from_node(wf_config *cfg, const key_desc *k, yaml_document_t *doc,
                               yaml_node_t *node, const where *w0)
{
    if (k->type == KT_KERNEL) return set_kernel(cfg, k, doc, node, w0);
    where w = *w0;
    w.line = yaml_line(node);
    if (node->type != YAML_SCALAR_NODE)
        return key_error(WF_ERR_INPUT, &w, k->name, "expected a single value, got %s",
                         node_kind(node));
    const char *text = (const char *)node->data.scalar.value;
    if (is_null_scalar(node))
        return key_error(WF_ERR_INPUT, &w, k->name, "no value given%s",
                         k->type == KT_STRING ? " (write \"\" for an empty string)" : "");
    /* YAML types a quoted scalar as a string; a number or switch must be written plain */
    int numeric = k->type == KT_BOOL || k->type == KT_INT || k->type == KT_UINT ||
                  k->type == KT_DOUBLE;
    if (numeric && node->data.scalar.style != YAML_PLAIN_SCALAR_STYLE)
        return key_error(WF_ERR_INPUT, &w, k->name,
                         "expected %s, got the quoted string \"%.60s\" (drop the quotes)",
                         k->type == KT_BOOL ? "true or false" : "a number", text);
    if (strlen(text) != node->data.scalar.length)
        return key_error(WF_ERR_INPUT, &w, k->name, "value holds a NUL character");
    return set_from_text(cfg, k, text, &w);
}

/* ---- defaults ----------------------------------------------------------------------- */

static void default_from_env(char *dst, size_t n, const char *var)
{
    const char *v = getenv(var);
    /* one too long is left empty here and reported by wf_config_finish */
    if (v && strlen(v) < n) memcpy(dst, v, strlen(v) + 1);
}

wf_status wf_config_synth(const wf_config *cfg, wf_synth_config *sc)
{
    wf_status st = wf_synth_defaults(sc);
    sc->seed = cfg->seed;
    sc->h_faint = cfg->synth.h_faint;
    sc->star_density = cfg->synth.star_density;
    sc->star_v_faint = cfg->synth.star_v_faint;
    return st;
}

void wf_config_defaults(wf_config *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    /* the detector's numbers live with its physics, the clock's with the clock */
    wf_detector_defaults(&cfg->ro.det);
    wf_persist_defaults(&cfg->ro.persist);
    cfg->ro.persist.on = 1;
    cfg->frame_time = WF_FRAME_TIME_DEFAULT;
    cfg->sky_rate = default_sky_rate();
    default_from_env(cfg->data_dir, sizeof cfg->data_dir, "WFISIM_DATA");
    default_from_env(cfg->reference_dir, sizeof cfg->reference_dir, "WFISIM_REFERENCE");
    const where w = {.origin = "built-in default"};
    for (int i = 0; i < NKEYS; i++)
        if (keys[i].def) (void)set_from_text(cfg, &keys[i], keys[i].def, &w);
    cfg->ro.seed = cfg->seed;
    wf_survey_defaults(&cfg->survey);
}



/* ---- YAML files ---------------------------------------------------------------------- */

typedef struct load_ctx {
    const char *path;
    yaml_document_t *doc;
    wf_config *cfg;
    int seen_line[NKEYS]; /* line where each key was set in this file, 0 if not */
} load_ctx;

/* survey.* keys live in sim/survey/survey.c's own table; a YAML value (a scalar, or a sequence of
 * scalars for lists such as survey.columns) goes there as "key=value" text. */
static wf_status set_survey_node(load_ctx *lc, const char *name, yaml_node_t *vn, const where *w)
{
    char text[1024], origin[WF_PATH_MAX + 32];
    size_t len = (size_t)snprintf(text, sizeof text, "%s=", name);
    if (vn->type == YAML_SCALAR_NODE) {
        len += (size_t)snprintf(text + len, len < sizeof text ? sizeof text - len : 0, "%s",
                                (const char *)vn->data.scalar.value);
    } else if (vn->type == YAML_SEQUENCE_NODE) {
        for (yaml_node_item_t *it = vn->data.sequence.items.start; it < vn->data.sequence.items.top; it++) {
            yaml_node_t *e = yaml_document_get_node(lc->doc, *it);
            if (e->type != YAML_SCALAR_NODE)
                return key_error(WF_ERR_INPUT, w, name, "expected a list of values, got %s in it", node_kind(e));
            len += (size_t)snprintf(text + len, len < sizeof text ? sizeof text - len : 0, "%s%s",
                                    it == vn->data.sequence.items.start ? "" : ",", (const char *)e->data.scalar.value);
        }
    } else {
        return key_error(WF_ERR_INPUT, w, name, "expected a value or a list, got %s", node_kind(vn));
    }
    if (len >= sizeof text) return key_error(WF_ERR_INPUT, w, name, "value too long");
    snprintf(origin, sizeof origin, "%s:%d", w->file, w->line);
    return wf_survey_set(&lc->cfg->survey, text, origin);
}

static wf_status walk_mapping(load_ctx *lc, yaml_node_t *map, const char *prefix)
{
    for (yaml_node_pair_t *p = map->data.mapping.pairs.start; p < map->data.mapping.pairs.top;
         p++) {
        yaml_node_t *kn = yaml_document_get_node(lc->doc, p->key);
        yaml_node_t *vn = yaml_document_get_node(lc->doc, p->value);
        where w = {.file = lc->path, .line = yaml_line(kn)};
        char name[256];
        if (kn->type != YAML_SCALAR_NODE)
            return key_error(WF_ERR_INPUT, &w, *prefix ? prefix : "(top level)",
                             "a key must be a name, not %s", node_kind(kn));
        const char *kt = (const char *)kn->data.scalar.value;
        if ((size_t)snprintf(name, sizeof name, "%s%s%s", prefix, *prefix ? "." : "", kt) >=
            sizeof name)
            return key_error(WF_ERR_INPUT, &w, *prefix ? prefix : "(top level)",
                             "key name too long");
        for (yaml_node_pair_t *q = map->data.mapping.pairs.start; q < p; q++) {
            yaml_node_t *qn = yaml_document_get_node(lc->doc, q->key);
            if (qn->type == YAML_SCALAR_NODE && !strcmp((const char *)qn->data.scalar.value, kt))
                return key_error(WF_ERR_INPUT, &w, name, "given twice (first at line %d)",
                                 yaml_line(qn));
        }
        int i = find_key(name);
        if (wf_survey_is_key(name) && vn->type != YAML_MAPPING_NODE) {
            wf_status st = set_survey_node(lc, name, vn, &w);
            if (st) return st;
        } else if (!strcmp(name, "survey") && vn->type == YAML_MAPPING_NODE) {
            wf_status st = walk_mapping(lc, vn, name);
            if (st) return st;
        } else if (i >= 0) {
            if (lc->seen_line[i])
                return key_error(WF_ERR_INPUT, &w, name, "given twice (first at line %d)",
                                 lc->seen_line[i]);
            lc->seen_line[i] = w.line;
            wf_status st = set_from_node(lc->cfg, &keys[i], lc->doc, vn, &w);
            if (st) return st;
        } else if (is_section(name)) {
            if (vn->type != YAML_MAPPING_NODE) {
                w.line = yaml_line(vn);
                return key_error(WF_ERR_INPUT, &w, name,
                                 "is a section: expected a mapping of its keys, got %s",
                                 node_kind(vn));
            }
            wf_status st = walk_mapping(lc, vn, name);
            if (st) return st;
        } else {
            return unknown_key(&w, name, vn->type == YAML_MAPPING_NODE);
        }
    }
    return WF_OK;
}

/* libyaml knows where the syntax broke but not under which key; a second pass over the
 * events up to the error recovers the dotted key, so the message can name it. */
static void key_near_error(FILE *f, char *out, size_t n)
{
    struct frame {
        int mapping, want_key;
        char key[128];
    } st[32];
    int depth = 0;
    out[0] = '\0';
    rewind(f);
    yaml_parser_t parser;
    if (!yaml_parser_initialize(&parser)) return;
    yaml_parser_set_input_file(&parser, f);
    for (;;) {
        yaml_event_t ev;
        if (!yaml_parser_parse(&parser, &ev)) break;
        yaml_event_type_t t = ev.type;
        struct frame *top = depth > 0 && depth <= 32 ? &st[depth - 1] : NULL;
        int is_value_start = t == YAML_SCALAR_EVENT || t == YAML_MAPPING_START_EVENT ||
                             t == YAML_SEQUENCE_START_EVENT || t == YAML_ALIAS_EVENT;
        if (top && top->mapping && top->want_key && t == YAML_SCALAR_EVENT) {
            snprintf(top->key, sizeof top->key, "%s", (const char *)ev.data.scalar.value);
            top->want_key = 0;
        } else if (is_value_start && top && top->mapping) {
            top->want_key = 1; /* this node is the value; the next one is a key */
        }
        if (t == YAML_MAPPING_START_EVENT || t == YAML_SEQUENCE_START_EVENT) {
            if (depth < 32) {
                st[depth].mapping = t == YAML_MAPPING_START_EVENT;
                st[depth].want_key = 1;
                st[depth].key[0] = '\0';
            }
            depth++;
            if (top && top->mapping) top->want_key = 0; /* still inside top's value */
        } else if (t == YAML_MAPPING_END_EVENT || t == YAML_SEQUENCE_END_EVENT) {
            if (depth > 0) depth--;
            if (depth > 0 && depth <= 32 && st[depth - 1].mapping) st[depth - 1].want_key = 1;
        }
        yaml_event_delete(&ev);
        if (t == YAML_STREAM_END_EVENT) break;
    }
    yaml_parser_delete(&parser);
    size_t used = 0;
    for (int d = 0; d < depth && d < 32; d++) {
        if (!st[d].mapping || !st[d].key[0]) continue;
        used += (size_t)snprintf(out + used, used < n ? n - used : 0, "%s%s", used ? "." : "",
                                 st[d].key);
    }
}

static int line_of_offset(FILE *f, size_t offset)
{
    int line = 1;
    rewind(f);
    for (size_t i = 0; i < offset; i++) {
        int c = getc(f);
        if (c == EOF) break;
        if (c == '\n') line++;
    }
    return line;
}

static wf_status yaml_syntax_error(const char *path, FILE *f, const yaml_parser_t *parser)
{
    const char *problem = parser->problem ? parser->problem : "malformed YAML";
    if (parser->error == YAML_MEMORY_ERROR)
        return wf_error(WF_ERR_NOMEM, "%s: out of memory while parsing YAML", path);
    if (parser->error == YAML_READER_ERROR)
        return wf_error(WF_ERR_INPUT, "%s:%d: %s (byte %zu)", path,
                        line_of_offset(f, parser->problem_offset), problem,
                        parser->problem_offset);
    int line = (int)parser->problem_mark.line + 1, col = (int)parser->problem_mark.column + 1;
    char ctx[160] = "";
    if (parser->context)
        snprintf(ctx, sizeof ctx, " (%s at line %d)", parser->context,
                 (int)parser->context_mark.line + 1);
    char key[256];
    key_near_error(f, key, sizeof key);
    return wf_error(WF_ERR_INPUT, "%s:%d:%d: %s%s%s: YAML syntax: %s%s", path, line, col,
                    key[0] ? "near key " : "", key, key[0] ? "" : "at top level", problem, ctx);
}

wf_status wf_config_load(wf_config *cfg, const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot open config file: %s", path, strerror(errno));
    struct stat sb;
    if (fstat(fileno(f), &sb) == 0 && S_ISDIR(sb.st_mode)) {
        fclose(f);
        return wf_error(WF_ERR_IO, "%s: is a directory, not a config file", path);
    }
    yaml_parser_t parser;
    yaml_document_t doc, extra;
    int have_doc = 0;
    wf_status st = WF_OK;
    /* applied to a copy so that a file with an error leaves cfg as it was */
    wf_config *tmp = malloc(sizeof *tmp);
    if (!tmp) {
        fclose(f);
        return wf_error(WF_ERR_NOMEM, "%s: no memory for the configuration", path);
    }
    memcpy(tmp, cfg, sizeof *tmp);
    if (!yaml_parser_initialize(&parser)) {
        st = wf_error(WF_ERR_NOMEM, "%s: cannot initialise the YAML parser", path);
        goto exit_noparser;
    }
    yaml_parser_set_input_file(&parser, f);
    if (!yaml_parser_load(&parser, &doc)) {
        st = yaml_syntax_error(path, f, &parser);
        goto exit;
    }
    have_doc = 1;
    yaml_node_t *root = yaml_document_get_root_node(&doc);
    if (!root) goto exit; /* an empty file changes nothing */
    if (root->type != YAML_MAPPING_NODE) {
        if (root->type == YAML_SCALAR_NODE && is_null_scalar(root)) goto exit;
        st = wf_error(WF_ERR_INPUT, "%s:%d: (top level): expected a mapping of keys, got %s",
                      path, yaml_line(root), node_kind(root));
        goto exit;
    }
    load_ctx lc = {.path = path, .doc = &doc, .cfg = tmp};
    st = walk_mapping(&lc, root, "");
    if (st) goto exit;
    if (!yaml_parser_load(&parser, &extra)) {
        st = yaml_syntax_error(path, f, &parser);
        goto exit;
    }
    yaml_node_t *second = yaml_document_get_root_node(&extra);
    if (second)
        st = wf_error(WF_ERR_INPUT, "%s:%d: a second YAML document; a config file holds one",
                      path, (int)extra.start_mark.line + 1);
    yaml_document_delete(&extra);
exit:
    if (have_doc) yaml_document_delete(&doc);
    yaml_parser_delete(&parser);
exit_noparser:
    fclose(f);
    if (!st) memcpy(cfg, tmp, sizeof *cfg);
    free(tmp);
    return st;
}

/* ---- --set -------------------------------------------------------------------------- */

static char *trim(char *s)
{
    while (isspace((unsigned char)*s)) s++;
    size_t n = strlen(s);
    while (n > 0 && isspace((unsigned char)s[n - 1])) s[--n] = '\0';
    return s;
}

static wf_status set_kernel_text(wf_config *cfg, const key_desc *k, const char *text,
                                 const where *w)
{
    yaml_parser_t parser;
    yaml_document_t doc;
    if (!yaml_parser_initialize(&parser))
        return key_error(WF_ERR_NOMEM, w, k->name, "cannot initialise the YAML parser");
    yaml_parser_set_input_string(&parser, (const unsigned char *)text, strlen(text));
    wf_status st;
    if (!yaml_parser_load(&parser, &doc)) {
        st = key_error(WF_ERR_INPUT, w, k->name, "not a YAML list: %s",
                       parser.problem ? parser.problem : "malformed");
    } else {
        yaml_node_t *root = yaml_document_get_root_node(&doc);
        if (!root)
            st = key_error(WF_ERR_INPUT, w, k->name, "no value given");
        else
            st = set_kernel(cfg, k, &doc, root, w);
        yaml_document_delete(&doc);
    }
    yaml_parser_delete(&parser);
    return st;
}

wf_status wf_config_set(wf_config *cfg, const char *assignment, const char *origin)
{
    const where w = {.origin = origin && *origin ? origin : "--set"};
    char buf[WF_PATH_MAX + 256];
    if (strlen(assignment) >= sizeof buf)
        return wf_error(WF_ERR_INPUT, "%s: override longer than %zu characters", w.origin,
                        sizeof buf - 1);
    memcpy(buf, assignment, strlen(assignment) + 1);
    char *eq = strchr(buf, '=');
    if (!eq)
        return wf_error(WF_ERR_INPUT, "%s: '%.80s': expected key=value", w.origin, assignment);
    *eq = '\0';
    char *name = trim(buf), *value = trim(eq + 1);
    if (!*name)
        return wf_error(WF_ERR_INPUT, "%s: '%.80s': no key before '='", w.origin, assignment);
    if (wf_survey_is_key(name)) {
        char text[1200];
        snprintf(text, sizeof text, "%s=%s", name, value);
        return wf_survey_set(&cfg->survey, text, w.origin);
    }
    int i = find_key(name);
    if (i < 0) {
        if (is_section(name))
            return key_error(WF_ERR_INPUT, &w, name, "is a section; set one of its keys, e.g. %s",
                             first_key_in(name));
        return unknown_key(&w, name, 0);
    }
    const key_desc *k = &keys[i];
    if (!*value && k->type != KT_STRING)
        return key_error(WF_ERR_INPUT, &w, k->name, "no value given");
    wf_config *tmp = malloc(sizeof *tmp);
    if (!tmp) return key_error(WF_ERR_NOMEM, &w, k->name, "no memory for the configuration");
    memcpy(tmp, cfg, sizeof *tmp);
    wf_status st = k->type == KT_KERNEL ? set_kernel_text(tmp, k, value, &w)
                                        : set_from_text(tmp, k, value, &w);
    if (!st) memcpy(cfg, tmp, sizeof *cfg);
    free(tmp);
    return st;
}

/* ---- cross-key constraints ---------------------------------------------------------- */

static wf_status env_fits(const char *var, const char *dir, const char *key)
{
    const char *v = getenv(var);
    if (v && strlen(v) >= WF_PATH_MAX && !*dir)
        return wf_error(WF_ERR_RANGE, "%s: $%s is longer than %d characters", key, var,
                        WF_PATH_MAX - 1);
    return WF_OK;
}

wf_status wf_config_finish(wf_config *cfg, wf_clock *clock)
{
    if (cfg->ro.tile_rows > cfg->ro.nrows) cfg->ro.tile_rows = cfg->ro.nrows;
    if (!(cfg->ro.det.cr_lmin_um < cfg->ro.det.cr_lmax_um))
        return wf_error(WF_ERR_RANGE,
                        "detector.cr_lmin_um (%g) must be below detector.cr_lmax_um (%g)",
                        cfg->ro.det.cr_lmin_um, cfg->ro.det.cr_lmax_um);
    wf_status st = env_fits("WFISIM_DATA", cfg->data_dir, "paths.data");
    if (!st) st = env_fits("WFISIM_REFERENCE", cfg->reference_dir, "paths.reference");
    if (st) return st;
    clock->frame_time = cfg->frame_time;
    st = wf_ma_resolve(cfg->ma_table, &clock->ma);
    if (st) {
        char msg[1024];
        snprintf(msg, sizeof msg, "%s", wf_error_message());
        return wf_error(st, "readout.ma_table: %s", msg);
    }
    if (cfg->products.quantize_level > 0 && cfg->products.quantize_level < 1)
        return wf_error(WF_ERR_RANGE,
                        "products.quantize_level %g: 0 (lossless) or at least 1 (a step no coarser than the noise)",
                        cfg->products.quantize_level);
    double t = wf_clock_exposure_time(clock);
    if (cfg->ro.mode == WF_MODE_RAMP && !(t <= WF_EXPOSURE_TIME_MAX))
        return wf_error(WF_ERR_RANGE,
                        "readout.ma_table %s: %d reads x readout.frame_time %g s = %g s, longer than "
                        "the %g s an exposure may last", clock->ma.name, wf_ma_total_reads(&clock->ma),
                        clock->frame_time, t, WF_EXPOSURE_TIME_MAX);
    cfg->ro.seed = cfg->seed;
    return WF_OK;
}

/* ---- the reference ------------------------------------------------------------------ */

static const struct {
    const char *name, *doc;
} sections[] = {
    {"", "Keys outside any section."},
    {"exposure", "What is observed and how the SCA is read."},
    {"readout", "Firmware readout: image size, tiling, the read pattern and the link."},
    {"run", "How the program runs; none of these changes a product."},
    {"detector", "Detector physics (SPEC §2, §3.2; GalSim and romanisim values)."},
    {"detector.persistence", "Persistence (SPEC §2, GalSim's Fermi model; docs/ARCHITECTURE.md, Persistence)."},
    {"detector.effects", "Switches of the detector chain, in its order (SPEC §3.1); a "
                         "switched-off effect is skipped, not computed as identity."},
    {"scene", "The built-in grid scene: a uniform sky plus a square grid of Gaussian point "
              "sources."},
    {"scene.synthetic", "The synthetic field (scene.kind synthetic, and the hosts `wfisim sn generate` "
                        "draws from it): its faint ends."},
    {"sn", "Supernova generation (`wfisim sn generate`; SPEC 5, docs/SUPERNOVAE.md). Command-line "
           "options of the same meaning override these."},
    {"sn.x1", "Stretch distribution."},
    {"sn.c", "Colour distribution."},
    {"sn.host", "Host galaxies."},
    {"products", "What a product keeps and how it is stored (docs/SURVEY.md): the truth tables "
                 "are always written."},
    {"paths", "Where optional inputs live; the program runs without them on built-in values."},
};

/* The listed section a key belongs to: the longest one that is a prefix of its name, so
 * scene.grid.* stays under `scene`. */
static int section_of(const char *name)
{
    int best = 0;
    size_t best_len = 0;
    for (int s = 1; s < (int)(sizeof sections / sizeof sections[0]); s++) {
        size_t n = strlen(sections[s].name);
        if (n > best_len && !strncmp(name, sections[s].name, n) && name[n] == '.') {
            best = s;
            best_len = n;
        }
    }
    return best;
}

static const char *type_text(const key_desc *k)
{
    switch (k->type) {
    case KT_BOOL: return "bool";
    case KT_INT: return "integer";
    case KT_UINT: return "unsigned";
    case KT_DOUBLE: return "number";
    case KT_STRING: return k->choices || k->filter ? "choice" : "string";
    case KT_ENUM: return "choice";
    case KT_KERNEL: return "3x3 numbers";
    }
    return "?";
}

static void value_text(const wf_config *cfg, const key_desc *k, char *buf, size_t n)
{
    const void *src = key_cptr(cfg, k);
    char num[40];
    switch (k->type) {
    case KT_BOOL: snprintf(buf, n, "`%s`", *(const int *)src ? "true" : "false"); return;
    case KT_INT: snprintf(buf, n, "`%d`", *(const int *)src); return;
    case KT_UINT:
        if (k->size == sizeof(uint32_t)) {
            uint32_t v;
            memcpy(&v, src, sizeof v);
            snprintf(buf, n, "`%lu`", (unsigned long)v);
        } else {
            uint64_t v;
            memcpy(&v, src, sizeof v);
            snprintf(buf, n, "`%llu`", (unsigned long long)v);
        }
        return;
    case KT_DOUBLE:
        format_double(*(const double *)src, num, sizeof num);
        snprintf(buf, n, "`%s`", num);
        return;
    case KT_STRING:
        snprintf(buf, n, *(const char *)src ? "`%s`" : "(empty)", (const char *)src);
        return;
    case KT_ENUM: snprintf(buf, n, "`%s`", k->choices[*(const int *)src]); return;
    case KT_KERNEL: snprintf(buf, n, "(see below)"); return;
    }
}

/* The shortest decimal that reads back as exactly v: the digest must see every bit. */
static void exact_double(double v, char *buf, size_t n)
{
    for (int d = 1; d <= 17; d++) {
        snprintf(buf, n, "%.*g", d, v);
        if (strtod(buf, NULL) == v) return;
    }
}

static int append_text(char **text, size_t *len, size_t *cap, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

static int append_text(char **text, size_t *len, size_t *cap, const char *fmt, ...)
{
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int k = vsnprintf(*text + *len, *cap - *len, fmt, ap);
        va_end(ap);
        if (k < 0) return -1;
        if ((size_t)k < *cap - *len) {
            *len += (size_t)k;
            return 0;
        }
        char *bigger = realloc(*text, *cap * 2 + (size_t)k);
        if (!bigger) return -1;
        *text = bigger;
        *cap = *cap * 2 + (size_t)k;
    }
}

wf_status wf_config_product_text(const wf_config *cfg, char **text)
{
    size_t len = 0, cap = 8192;
    *text = malloc(cap);
    if (!*text) return wf_error(WF_ERR_NOMEM, "out of memory for the configuration text");
    (*text)[0] = '\0';
    int bad = 0;
    const wf_detector *d = &cfg->ro.det;
    const int corr = d->on.read_1f || d->on.channel_offsets || d->on.refpix;
    for (int i = 0; i < NKEYS && !bad; i++) {
        const key_desc *k = &keys[i];
        if (k->digest != KD_SHAPES && !(k->digest == KD_CORR && corr)) continue;
        const void *src = key_cptr(cfg, k);
        char v[64];
        bad |= append_text(text, &len, &cap, "%s = ", k->name);
        switch (k->type) {
        case KT_BOOL: bad |= append_text(text, &len, &cap, "%s", *(const int *)src ? "true" : "false"); break;
        case KT_INT: bad |= append_text(text, &len, &cap, "%d", *(const int *)src); break;
        case KT_UINT: {
            uint64_t u = 0;
            if (k->size == sizeof(uint32_t)) {
                uint32_t w;
                memcpy(&w, src, sizeof w);
                u = w;
            } else {
                memcpy(&u, src, sizeof u);
            }
            bad |= append_text(text, &len, &cap, "%llu", (unsigned long long)u);
            break;
        }
        case KT_DOUBLE:
            exact_double(*(const double *)src, v, sizeof v);
            bad |= append_text(text, &len, &cap, "%s", v);
            break;
        case KT_STRING: bad |= append_text(text, &len, &cap, "%s", (const char *)src); break;
        case KT_ENUM: bad |= append_text(text, &len, &cap, "%s", k->choices[*(const int *)src]); break;
        case KT_KERNEL: {
            const double *m = src;
            for (int j = 0; j < 9; j++) {
                exact_double(m[j], v, sizeof v);
                bad |= append_text(text, &len, &cap, "%s%s", j ? (j % 3 ? ", " : "; ") : "", v);
            }
            break;
        }
        }
        bad |= append_text(text, &len, &cap, "\n");
    }
    if (bad) {
        free(*text);
        *text = NULL;
        return wf_error(WF_ERR_NOMEM, "out of memory for the configuration text");
    }
    return WF_OK;
}

static void allowed_text(const key_desc *k, char *buf, size_t n)
{
    switch (k->type) {
    case KT_BOOL: snprintf(buf, n, "true, false"); return;
    case KT_STRING:
        if (k->choices)
            choices_text(k->choices, buf, n);
        else if (k->filter)
            filters_text(buf, n);
        else if (k->dir)
            snprintf(buf, n, "empty, or a directory");
        else if (k->nonempty)
            snprintf(buf, n, "non-empty, < %zu characters", k->size);
        else
            snprintf(buf, n, "< %zu characters", k->size);
        return;
    case KT_ENUM: choices_text(k->choices, buf, n); return;
    case KT_KERNEL: snprintf(buf, n, "sum 1 ± 1e-6"); return;
    case KT_UINT:
        if (!k->has_lo && !k->has_hi) {
            snprintf(buf, n, "0 to 2^64-1");
            return;
        }
        range_text(k, buf, n);
        return;
    default: range_text(k, buf, n); return;
    }
}

/* Markdown table cell: a '|' in the text would end the cell. */
static void cell(FILE *out, const char *text)
{
    fputs(" ", out);
    for (const char *p = text; *p; p++) {
        if (*p == '|') fputc('\\', out);
        fputc(*p, out);
    }
    fputs(" |", out);
}

void wf_config_write_doc(FILE *out)
{
    wf_config def;
    wf_config_defaults(&def);
    fputs("# Configuration reference\n"
          "\n"
          "<!-- Generated by wf_config_write_doc() in tools/config.c; do not edit by hand.\n"
          "     tests/test_config.c checks that this file matches the code. -->\n"
          "\n"
          "A run is configured by YAML files and `--set key=value` overrides, applied in the\n"
          "order given on top of the defaults below (a later value wins). One table in\n"
          "`tools/config.c` defines every key; it drives parsing, range checks, `--set` and this\n"
          "page.\n"
          "\n"
          "Keys are dotted paths into nested mappings: `detector.gain` is written\n"
          "\n"
          "```yaml\n"
          "detector:\n"
          "  gain: 1.0\n"
          "  effects:\n"
          "    ipc: false\n"
          "```\n"
          "\n"
          "or, equally, `detector.gain: 1.0` at any level (`detector: {effects.ipc: false}`). On\n"
          "the command line: `--set detector.gain=1.0`, `--set detector.effects.ipc=false`,\n"
          "`--set 'detector.ipc=[[0,0,0],[0,1,0],[0,0,0]]'`.\n"
          "\n"
          "Value types:\n"
          "\n"
          "- **bool**: `true`/`false` (also `yes`/`no`, `on`/`off`, `1`/`0`).\n"
          "- **integer**, **unsigned**: decimal, no fraction.\n"
          "- **number**: decimal or exponent notation; NaN and infinities are rejected.\n"
          "- **choice**: one of the listed words, exactly as spelt.\n"
          "- **string**: any text; quote it in YAML if it looks like something else.\n"
          "- In YAML, numbers and bools must be plain (`gain: 1.0`, not `gain: \"1.0\"`: YAML\n"
          "  reads a quoted value as a string). An empty value (`gain:`) is an error;\n"
          "  write `\"\"` for an empty string.\n"
          "\n"
          "Errors (the program exits non-zero and writes nothing) name the file and line, or\n"
          "the `--set` origin, and the key:\n"
          "\n"
          "| problem | status |\n"
          "|---|---|\n"
          "| file cannot be opened or read | `WF_ERR_IO` |\n"
          "| malformed YAML (libyaml's message, line and column, the key it was under) | "
          "`WF_ERR_INPUT` |\n"
          "| unknown key (the closest known key is suggested), key given twice | "
          "`WF_ERR_INPUT` |\n"
          "| wrong type (text for a number, a list for a single value, a section given a value) "
          "| `WF_ERR_INPUT` |\n"
          "| word not among a choice's values | `WF_ERR_INPUT` |\n"
          "| value out of its range, NaN or infinite, IPC kernel not summing to 1 | "
          "`WF_ERR_RANGE` |\n"
          "\n"
          "A file with an error changes nothing. An empty file is valid and changes nothing.\n",
          out);

    int cur = -1;
    for (int i = 0; i < NKEYS; i++) {
        const key_desc *k = &keys[i];
        int sec = section_of(k->name);
        if (sec != cur) {
            cur = sec;
            const char *sn = sections[sec].name;
            fprintf(out, "\n## %s%s%s\n\n%s\n\n", *sn ? "`" : "", *sn ? sn : "General",
                    *sn ? "`" : "", sections[sec].doc);
            fputs("| key | type | default | allowed | unit | meaning |\n"
                  "|---|---|---|---|---|---|\n",
                  out);
        }
        char name[140], dtext[128], allowed[256];
        snprintf(name, sizeof name, "`%s`", k->name);
        if (k->doc_default)
            snprintf(dtext, sizeof dtext, "%s", k->doc_default);
        else
            value_text(&def, k, dtext, sizeof dtext);
        allowed_text(k, allowed, sizeof allowed);
        fputs("|", out);
        cell(out, name);
        cell(out, type_text(k));
        cell(out, dtext);
        cell(out, allowed);
        cell(out, *k->unit ? k->unit : "");
        cell(out, k->doc);
        fputs("\n", out);
    }

    double ipc[3][3];
    wf_detector_ipc_default(ipc);
    fputs("\n## Notes\n"
          "\n"
          "Default `detector.ipc`, GalSim's `ipc_kernel` (SPEC §2) divided by its sum; the\n"
          "centre row and column are the pixel itself, `ipc[a][b]` weighs `in[y+a-1][x+b-1]`:\n"
          "\n"
          "```yaml\n"
          "detector:\n"
          "  ipc:\n",
          out);
    for (int a = 0; a < 3; a++) {
        fputs("    - [", out);
        for (int b = 0; b < 3; b++) {
            char num[40];
            format_double(ipc[a][b], num, sizeof num);
            fprintf(out, "%s%s", b ? ", " : "", num);
        }
        fputs("]\n", out);
    }
    fputs("```\n"
          "\n"
          "Resolved after every file and override is applied (`wf_config_finish`):\n"
          "\n"
          "- `readout.ma_table` is read (a built-in name or a file, see `hal/clock.h`), and\n"
          "  `readout.frame_time` goes with it into the clock.\n"
          "- `readout.tile_rows` above `readout.nrows` is clamped to `readout.nrows`: one tile\n"
          "  holds the whole image.\n"
          "- `detector.cr_lmin_um` must be below `detector.cr_lmax_um` (`WF_ERR_RANGE`).\n"
          "- `exposure.exptime` is used in single mode only; in ramp mode the exposure time is\n"
          "  that of the last read of the MA table.\n",
          out);
    fputs("\n## Keys that never remake a product\n"
          "\n"
          "Every product carries a digest of the inputs that shape its bits (docs/SURVEY.md, "
          "`wfisim survey run` resume); the configuration's part is every key above except these.\n"
          "Never a byte of an image product:",
          out);
    for (int pass = 0; pass < 2; pass++) {
        if (pass) fputs(".\nNamed files whose content is digested instead (moving a file changes nothing; "
                        "`readout.ma_table` counts as the table it resolves to, and the `sn` keys reach an image "
                        "only through the SN sample file):", out);
        const char *sep = " ";
        for (int i = 0; i < NKEYS; i++)
            if (keys[i].digest == (pass ? KD_FILE : KD_RUN)) {
                fprintf(out, "%s`%s`", sep, keys[i].name);
                sep = ", ";
            }
    }
    fputs(".\n`seed` is a part of its own, and the plan's `survey` keys shape the plan, not a "
          "product (`survey run` takes each exposure's pointing, filter and time from the plan's row).\n",
          out);
    fputs("\n## `survey`\n"
          "\n"
          "The deep-tier plan (`wfisim survey plan`, sim/survey/survey.h, docs/SURVEY.md). Lists are YAML\n"
          "sequences or comma-separated text (`--set survey.exptimes=300,300,300,900`).\n"
          "\n",
          out);
    wf_survey_write_doc(out);
}
