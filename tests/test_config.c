/* Run configuration: defaults against SPEC, YAML files and --set overrides, every kind of bad
 * input (status and a message naming file, line and key), and docs/CONFIG.md against the
 * generated reference.
 *
 * `test_config --write-doc docs/CONFIG.md` regenerates the reference after a key changes. */
#include <check.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "tests/testutil.h"
#include "tools/config.h"

/* Writes text to name in a fresh directory; returns the path (static, one at a time). */
static const char *write_file(const char *name, const char *text)
{
    static char path[4096];
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    ck_assert_ptr_nonnull(f);
    fputs(text, f);
    ck_assert_int_eq(fclose(f), 0);
    return path;
}

static void assert_message_has(const char *what)
{
    const char *msg = wf_error_message();
    ck_assert_msg(strstr(msg, what) != NULL, "message '%s' lacks '%s'", msg, what);
}

START_TEST(test_defaults_are_spec_values)
{
    unsetenv("WFISIM_DATA");
    unsetenv("WFISIM_REFERENCE");
    wf_config cfg;
    wf_config_defaults(&cfg);
    const wf_detector *d = &cfg.ro.det;
    ck_assert_double_eq(d->read_noise_e, 8.5);
    ck_assert_double_eq(d->dark_current, 0.015);
    ck_assert_double_eq(d->gain, 1.0);
    ck_assert_double_eq(d->nl_beta, -6.0e-7);
    ck_assert_double_eq(d->recip_alpha, 0.0065);
    ck_assert_double_eq(d->recip_f0, 1.0);
    ck_assert_double_eq(d->full_well, 1e5);
    ck_assert_double_eq(d->adc_max, 65535.0);
    ck_assert_double_eq(d->cr_rate, 8.0);
    ck_assert_double_eq(d->cr_slope, -4.33);
    ck_assert_double_eq(d->cr_dedx_loc, 120.0);
    ck_assert_double_eq(d->cr_dedx_scale, 50.0);
    ck_assert(d->on.photon_noise && d->on.reciprocity && d->on.dark && d->on.nonlinearity &&
              d->on.ipc && d->on.read_noise && d->on.quantize && d->on.saturation &&
              d->on.cosmic_rays);
    /* SPEC §2 kernel over its sum */
    const double raw_sum = 0.001269938 + 0.015399776 + 0.001199862 + 0.013800177 + 1.0 +
                           0.015600367 + 0.001270391 + 0.016129619 + 0.001200137;
    ck_assert_double_eq_tol(d->ipc[1][1], 1.0 / raw_sum, 1e-15);
    ck_assert_double_eq_tol(d->ipc[0][1], 0.015399776 / raw_sum, 1e-15);

    ck_assert_uint_eq(cfg.seed, 1);
    ck_assert_uint_eq(cfg.ro.sca, 1);
    ck_assert_str_eq(cfg.filter, "Y106");
    ck_assert_int_eq(cfg.ro.mode, WF_MODE_RAMP);
    ck_assert_int_eq(cfg.ro.sampling, WF_SAMPLE_PER_READ);
    ck_assert_double_eq(cfg.ro.exptime, 300.0);
    ck_assert_int_eq(cfg.ro.ncols, 4088);
    ck_assert_int_eq(cfg.ro.nrows, 4088);
    ck_assert_int_eq(cfg.ro.tile_rows, 32); /* the demo within 128 MiB (docs/BENCHMARKS.notes.md) */
    ck_assert_double_eq(cfg.frame_time, 3.16247);
    ck_assert_str_eq(cfg.ma_table, "6");
    ck_assert_int_eq(cfg.ro.compress, 1);
    ck_assert_int_eq(cfg.threads, 1);
    ck_assert_int_eq(cfg.quiet, 0);
    ck_assert_str_eq(cfg.out_dir, "out");
    /* Y106 zodiacal 29.7 e-/s/arcsec^2 over a 0.11" pixel, plus 10% stray light */
    ck_assert_double_eq_tol(cfg.sky_rate, 0.395307, 1e-12);
    ck_assert_double_eq(cfg.grid_flux, 1000.0);
    ck_assert_double_eq(cfg.grid_sigma, 1.0);
    ck_assert_int_eq(cfg.grid_spacing, 256);
    ck_assert_str_eq(cfg.data_dir, "");
    ck_assert_str_eq(cfg.reference_dir, "");

    wf_clock clock;
    ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_OK);
    ck_assert_double_eq(clock.frame_time, 3.16247);
    ck_assert_int_eq(clock.ma.nresultants, 15);
    ck_assert_int_eq(clock.ma.nreads, 93);
    ck_assert_int_eq(wf_ma_total_reads(&clock.ma), 93);
    ck_assert_uint_eq(cfg.ro.seed, cfg.seed);
}
END_TEST

START_TEST(test_paths_default_from_environment)
{
    setenv("WFISIM_DATA", "/data/here", 1);
    setenv("WFISIM_REFERENCE", "/ref/there", 1);
    wf_config cfg;
    wf_config_defaults(&cfg);
    ck_assert_str_eq(cfg.data_dir, "/data/here");
    ck_assert_str_eq(cfg.reference_dir, "/ref/there");
    unsetenv("WFISIM_DATA");
    unsetenv("WFISIM_REFERENCE");
}
END_TEST

START_TEST(test_yaml_overrides_nested_keys)
{
    const char *path = write_file("run.yaml",
                                  "# a comment\n"
                                  "seed: 18446744073709551615\n"
                                  "exposure:\n"
                                  "  id: 42\n"
                                  "  sca: 18\n"
                                  "  filter: F184\n"
                                  "  mode: single\n"
                                  "  sampling: direct\n"
                                  "  exptime: 900\n"
                                  "readout: {ncols: 128, nrows: 96, tile_rows: 500, ma_table: 4,"
                                  " compress: no}\n"
                                  "detector:\n"
                                  "  gain: 1.5\n"
                                  "  read_noise: 5e0\n"
                                  "  effects:\n"
                                  "    ipc: false\n"
                                  "    cosmic_rays: off\n"
                                  "  effects.dark: false\n"
                                  "  ipc:\n"
                                  "    - [0, 0, 0]\n"
                                  "    - [0.25, 0.5, 0.25]\n"
                                  "    - [0, 0, 0]\n"
                                  "detector.full_well: 80000\n"
                                  "run:\n"
                                  "  out: \"products dir\"\n"
                                  "  quiet: true\n"
                                  "  threads: 2\n"
                                  "scene:\n"
                                  "  sky_rate: 0\n"
                                  "  grid: {flux: 50.5, sigma: 2, spacing: 32}\n"
                                  "paths:\n"
                                  "  data: /\n"); /* a folder that is there */
    wf_config cfg;
    wf_config_defaults(&cfg);
    ck_assert_msg(wf_config_load(&cfg, path) == WF_OK, "%s", wf_error_message());
    ck_assert_uint_eq(cfg.seed, UINT64_MAX);
    ck_assert_uint_eq(cfg.ro.exposure, 42);
    ck_assert_uint_eq(cfg.ro.sca, 18);
    ck_assert_str_eq(cfg.filter, "F184");
    ck_assert_int_eq(cfg.ro.mode, WF_MODE_SINGLE);
    ck_assert_int_eq(cfg.ro.sampling, WF_SAMPLE_DIRECT);
    ck_assert_double_eq(cfg.ro.exptime, 900.0);
    ck_assert_int_eq(cfg.ro.ncols, 128);
    ck_assert_int_eq(cfg.ro.nrows, 96);
    ck_assert_str_eq(cfg.ma_table, "4");
    ck_assert_int_eq(cfg.ro.compress, 0);
    ck_assert_double_eq(cfg.ro.det.gain, 1.5);
    ck_assert_double_eq(cfg.ro.det.read_noise_e, 5.0);
    ck_assert_int_eq(cfg.ro.det.on.ipc, 0);
    ck_assert_int_eq(cfg.ro.det.on.cosmic_rays, 0);
    ck_assert_int_eq(cfg.ro.det.on.dark, 0);
    ck_assert_int_eq(cfg.ro.det.on.photon_noise, 1);
    ck_assert_double_eq(cfg.ro.det.ipc[1][0], 0.25);
    ck_assert_double_eq(cfg.ro.det.ipc[1][1], 0.5);
    ck_assert_double_eq(cfg.ro.det.ipc[0][0], 0.0);
    ck_assert_double_eq(cfg.ro.det.full_well, 80000.0);
    ck_assert_str_eq(cfg.out_dir, "products dir");
    ck_assert_int_eq(cfg.quiet, 1);
    ck_assert_int_eq(cfg.threads, 2);
    ck_assert_double_eq(cfg.sky_rate, 0.0);
    ck_assert_double_eq(cfg.grid_flux, 50.5);
    ck_assert_double_eq(cfg.grid_sigma, 2.0);
    ck_assert_int_eq(cfg.grid_spacing, 32);
    ck_assert_str_eq(cfg.data_dir, "/");
    /* untouched keys keep their defaults */
    ck_assert_double_eq(cfg.ro.det.dark_current, 0.015);
    ck_assert_double_eq(cfg.frame_time, 3.16247);

    wf_clock clock;
    ck_assert_msg(wf_config_finish(&cfg, &clock) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(cfg.ro.tile_rows, 96); /* clamped to nrows */
    ck_assert_int_eq(clock.ma.nresultants, 9);
    ck_assert_int_eq(clock.ma.nreads, 44);
    ck_assert_uint_eq(cfg.ro.seed, UINT64_MAX);
}
END_TEST

START_TEST(test_empty_file_changes_nothing)
{
    wf_config a, b;
    wf_config_defaults(&a);
    wf_config_defaults(&b);
    ck_assert_int_eq(wf_config_load(&a, write_file("empty.yaml", "")), WF_OK);
    ck_assert_int_eq(wf_config_load(&a, write_file("comment.yaml", "# nothing\n---\n")), WF_OK);
    ck_assert_mem_eq(&a, &b, sizeof a);
}
END_TEST

START_TEST(test_set_overrides)
{
    wf_config cfg;
    wf_config_defaults(&cfg);
    const char *sets[] = {"detector.gain=2.5",
                          " exposure.mode = single ",
                          "run.quiet=yes",
                          "seed=12345678901234",
                          "exposure.filter=H158",
                          "readout.ma_table=11",
                          "readout.frame_time=3.04",
                          "detector.effects.nonlinearity=false",
                          "detector.ipc=[[0,0,0],[0,1,0],[0,0,0]]",
                          "paths.reference=",
                          "run.out=a=b"};
    for (size_t i = 0; i < sizeof sets / sizeof *sets; i++)
        ck_assert_msg(wf_config_set(&cfg, sets[i], "--set") == WF_OK, "%s: %s", sets[i],
                      wf_error_message());
    ck_assert_double_eq(cfg.ro.det.gain, 2.5);
    ck_assert_int_eq(cfg.ro.mode, WF_MODE_SINGLE);
    ck_assert_int_eq(cfg.quiet, 1);
    ck_assert_uint_eq(cfg.seed, 12345678901234ull);
    ck_assert_str_eq(cfg.filter, "H158");
    ck_assert_int_eq(cfg.ro.det.on.nonlinearity, 0);
    ck_assert_double_eq(cfg.ro.det.ipc[1][1], 1.0);
    ck_assert_double_eq(cfg.ro.det.ipc[0][1], 0.0);
    ck_assert_str_eq(cfg.reference_dir, "");
    ck_assert_str_eq(cfg.out_dir, "a=b");
    wf_clock clock;
    ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_OK);
    ck_assert_double_eq(clock.frame_time, 3.04);
    ck_assert_int_eq(clock.ma.nreads, 309);
    ck_assert_uint_eq(cfg.ro.seed, 12345678901234ull);
}
END_TEST

START_TEST(test_set_after_file_wins)
{
    wf_config cfg;
    wf_config_defaults(&cfg);
    ck_assert_int_eq(wf_config_load(&cfg, write_file("a.yaml", "detector: {gain: 3}\n")), WF_OK);
    ck_assert_int_eq(wf_config_set(&cfg, "detector.gain=4", NULL), WF_OK);
    ck_assert_double_eq(cfg.ro.det.gain, 4.0);
}
END_TEST

/* One bad file: the status, and the message naming the file, the line and the key. */
typedef struct bad_case {
    const char *yaml;
    wf_status status;
    const char *line;  /* ":N" as it must follow the file name */
    const char *key;   /* must appear in the message */
    const char *extra; /* and this too, or NULL */
} bad_case;

static const bad_case bad_files[] = {
    /* unknown key, with a suggestion */
    {"detector:\n  gian: 1.0\n", WF_ERR_INPUT, ":2", "detector.gian", "detector.gain"},
    {"readout:\n  seed: 3\n", WF_ERR_INPUT, ":2", "readout.seed", "'seed'"},
    {"detectr:\n  gain: 1.0\n", WF_ERR_INPUT, ":1", "detectr",
     "unknown section (did you mean 'detector'?)"},
    {"seed: 1\nfoo: 2\n", WF_ERR_INPUT, ":2", "foo", "unknown key"},
    /* wrong type */
    {"detector:\n  dark_current: 0.1\n  gain: fast\n", WF_ERR_INPUT, ":3", "detector.gain",
     "expected a number"},
    {"detector:\n  gain: \"1.0\"\n", WF_ERR_INPUT, ":2", "detector.gain", "quoted"},
    {"detector:\n  gain: [1, 2]\n", WF_ERR_INPUT, ":2", "detector.gain", "a list"},
    {"readout:\n  tile_rows: 6.5\n", WF_ERR_INPUT, ":2", "readout.tile_rows", "integer"},
    {"run:\n  quiet: maybe\n", WF_ERR_INPUT, ":2", "run.quiet", "true or false"},
    {"exposure:\n  mode: rampp\n", WF_ERR_INPUT, ":2", "exposure.mode", "ramp, single"},
    {"exposure:\n  filter: W150\n", WF_ERR_INPUT, ":2", "exposure.filter", "W146"},
    {"detector: 5\n", WF_ERR_INPUT, ":1", "detector", "section"},
    {"detector:\n  gain:\n", WF_ERR_INPUT, ":2", "detector.gain", "no value"},
    {"detector:\n  ipc: 1.0\n", WF_ERR_INPUT, ":2", "detector.ipc", "3x3"},
    {"detector:\n  ipc:\n    - [0, 0, 0]\n    - [0, 1]\n    - [0, 0, 0]\n", WF_ERR_INPUT, ":4",
     "detector.ipc", "row 2"},
    {"detector:\n  ipc: [[0,0,0],[0,x,0],[0,0,0]]\n", WF_ERR_INPUT, ":2", "detector.ipc",
     "row 2, column 2"},
    {"- seed\n- 1\n", WF_ERR_INPUT, ":1", "top level", "mapping"},
    {"seed: 1\nseed: 2\n", WF_ERR_INPUT, ":2", "seed", "line 1"},
    {"detector.gain: 2\ndetector:\n  gain: 3\n", WF_ERR_INPUT, ":3", "detector.gain", "line 1"},
    /* out of range, not finite */
    {"exposure:\n  sca: 19\n", WF_ERR_RANGE, ":2", "exposure.sca", "1 to 18"},
    {"exposure:\n  sca: 0\n", WF_ERR_RANGE, ":2", "exposure.sca", "1 to 18"},
    {"readout:\n  ncols: 4089\n", WF_ERR_RANGE, ":2", "readout.ncols", "4088"},
    {"detector:\n  gain: 0\n", WF_ERR_RANGE, ":2", "detector.gain", "> 0"},
    {"detector:\n  dark_current: -0.1\n", WF_ERR_RANGE, ":2", "detector.dark_current", "≥ 0"},
    {"seed: -1\n", WF_ERR_RANGE, ":1", "seed", "-1"},
    {"seed: 18446744073709551616\n", WF_ERR_RANGE, ":1", "seed", "2^64-1"},
    {"exposure: {id: 4294967296}\n", WF_ERR_RANGE, ":1", "exposure.id", "0 to 4294967295"},
    {"readout:\n  nrows: 99999999999999999999\n", WF_ERR_RANGE, ":2", "readout.nrows", "1 to 4088"},
    {"detector:\n  read_noise: .nan\n", WF_ERR_RANGE, ":2", "detector.read_noise", "finite"},
    {"detector:\n  nl_beta: -.inf\n", WF_ERR_RANGE, ":2", "detector.nl_beta", "finite"},
    {"detector:\n  nl_beta: nan\n", WF_ERR_RANGE, ":2", "detector.nl_beta", "finite"},
    {"detector:\n  full_well: 1e999\n", WF_ERR_RANGE, ":2", "detector.full_well", "finite"},
    {"detector:\n  ipc: [[0,0,0],[0,1.01,0],[0,0,0]]\n", WF_ERR_RANGE, ":2", "detector.ipc",
     "sum"},
    {"run:\n  out: \"\"\n", WF_ERR_INPUT, ":2", "run.out", "empty"},
    /* malformed YAML: libyaml's problem at its (1-based) line, and the key it was under */
    {"detector:\n  gain: [1, 2\nrun:\n  quiet: true\n", WF_ERR_INPUT, ":3", "detector.gain",
     "YAML"},
    {"seed: 1\nexposure:\n  sca: 3\n   filter: Y106\n", WF_ERR_INPUT, ":4", "exposure.sca",
     "YAML"},
    {"seed: 1\n---\nseed: 2\n", WF_ERR_INPUT, ":2", "", "second YAML document"},
    {"seed: 1\n\xff\xfe: 2\n", WF_ERR_INPUT, ":2", "", "UTF-8"},
};

START_TEST(test_bad_file)
{
    const bad_case *c = &bad_files[_i];
    const char *path = write_file("bad.yaml", c->yaml);
    wf_config cfg, before;
    wf_config_defaults(&cfg);
    memcpy(&before, &cfg, sizeof cfg);
    wf_status st = wf_config_load(&cfg, path);
    ck_assert_msg(st == c->status, "case %d: status %d, expected %d (%s)", _i, st, c->status,
                  wf_error_message());
    char at[4200];
    snprintf(at, sizeof at, "%s%s", path, c->line);
    assert_message_has(at);
    assert_message_has(c->key);
    if (c->extra) assert_message_has(c->extra);
    /* a file with an error leaves the configuration as it was */
    ck_assert_mem_eq(&cfg, &before, sizeof cfg);
}
END_TEST

START_TEST(test_unreadable_file)
{
    wf_config cfg;
    wf_config_defaults(&cfg);
    const char *dir = wf_test_tmpdir();
    char path[4200];
    snprintf(path, sizeof path, "%s/missing.yaml", dir);
    ck_assert_int_eq(wf_config_load(&cfg, path), WF_ERR_IO);
    assert_message_has(path);
    ck_assert_int_eq(wf_config_load(&cfg, dir), WF_ERR_IO);
    assert_message_has(dir);
}
END_TEST

typedef struct bad_set {
    const char *assignment;
    wf_status status;
    const char *key;
    const char *extra;
} bad_set;

static const bad_set bad_sets[] = {
    {"detector.gain=abc", WF_ERR_INPUT, "detector.gain", "expected a number"},
    {"detector.gain=inf", WF_ERR_RANGE, "detector.gain", "finite"},
    {"detector.gian=1", WF_ERR_INPUT, "detector.gian", "detector.gain"},
    {"exposure.sca=42", WF_ERR_RANGE, "exposure.sca", "1 to 18"},
    {"detector=1", WF_ERR_INPUT, "detector", "section"},
    {"detector.gain", WF_ERR_INPUT, "detector.gain", "key=value"},
    {"=3", WF_ERR_INPUT, "=3", "no key"},
    {"detector.gain=", WF_ERR_INPUT, "detector.gain", "no value"},
    {"detector.ipc=[[0,0,0],[0,1,0]]", WF_ERR_INPUT, "detector.ipc", "3x3"},
    {"detector.ipc=[[0,0,0],[0,2,0],[0,0,0]]", WF_ERR_RANGE, "detector.ipc", "sum"},
    {"detector.ipc=[[0,0,0],[0,1,0],[0,0,0]", WF_ERR_INPUT, "detector.ipc", "YAML"},
    {"run.threads=0", WF_ERR_RANGE, "run.threads", "1 to 1024"},
    {"readout.compress=2", WF_ERR_INPUT, "readout.compress", "true or false"},
    {"products.compress=zip", WF_ERR_INPUT, "products.compress", "auto, none, rice"},
    {"products.resultants=maybe", WF_ERR_INPUT, "products.resultants", "keep, drop"},
    {"products.quantize_level=-1", WF_ERR_RANGE, "products.quantize_level", "0"},
    {"readout.frame_time=100.001", WF_ERR_RANGE, "readout.frame_time", "to 100 s"},
    {"readout.frame_time=1e300", WF_ERR_RANGE, "readout.frame_time", "to 100 s"},
    {"exposure.exptime=86400.5", WF_ERR_RANGE, "exposure.exptime", "to 86400 s"},
    {"exposure.filter=W150", WF_ERR_INPUT, "exposure.filter", "W146 (W149: W146)"},
    {"paths.data=/dev/null", WF_ERR_INPUT, "paths.data", "not a directory"},
    {"paths.reference=/dev/null", WF_ERR_INPUT, "paths.reference", "not a directory"},
    {"paths.data=/nonexistent/wfisim-data", WF_ERR_IO, "paths.data", "/nonexistent/wfisim-data"},
};

START_TEST(test_bad_set)
{
    const bad_set *c = &bad_sets[_i];
    wf_config cfg, before;
    wf_config_defaults(&cfg);
    memcpy(&before, &cfg, sizeof cfg);
    wf_status st = wf_config_set(&cfg, c->assignment, "--set #3");
    ck_assert_msg(st == c->status, "'%s': status %d, expected %d (%s)", c->assignment, st,
                  c->status, wf_error_message());
    assert_message_has("--set #3");
    assert_message_has(c->key);
    assert_message_has(c->extra);
    ck_assert_mem_eq(&cfg, &before, sizeof cfg);
}
END_TEST

/* exposure.sampling takes the three names wf_sampling_name gives, in the enum's order, and
 * refuses another by the key's name with the choices */
START_TEST(test_sampling_names)
{
    const char *names[] = {"per-read", "direct", "moments"};
    const wf_sampling want[] = {WF_SAMPLE_PER_READ, WF_SAMPLE_DIRECT, WF_SAMPLE_MOMENTS};
    for (int i = 0; i < 3; i++) {
        wf_config cfg;
        wf_config_defaults(&cfg);
        char set[64];
        snprintf(set, sizeof set, "exposure.sampling=%s", names[i]);
        ck_assert_msg(wf_config_set(&cfg, set, "--set") == WF_OK, "%s: %s", set, wf_error_message());
        ck_assert_int_eq(cfg.ro.sampling, want[i]);
        ck_assert_str_eq(wf_sampling_name(want[i]), names[i]);
    }
    wf_config cfg, before;
    wf_config_defaults(&cfg);
    memcpy(&before, &cfg, sizeof cfg);
    ck_assert_int_eq(wf_config_set(&cfg, "exposure.sampling=moment", "--set #2"), WF_ERR_INPUT);
    assert_message_has("--set #2");
    assert_message_has("exposure.sampling");
    assert_message_has("per-read, direct, moments");
    ck_assert_mem_eq(&cfg, &before, sizeof cfg);
}
END_TEST

START_TEST(test_finish_constraints)
{
    wf_config cfg;
    wf_clock clock;
    wf_config_defaults(&cfg);
    ck_assert_int_eq(wf_config_set(&cfg, "detector.cr_lmin_um=3000", NULL), WF_OK);
    ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_ERR_RANGE);
    assert_message_has("detector.cr_lmin_um");
    assert_message_has("detector.cr_lmax_um");

    wf_config_defaults(&cfg);
    const char *dir = wf_test_tmpdir();
    char path[4200], set[4300];
    snprintf(path, sizeof path, "%s/nosuch.ma", dir);
    snprintf(set, sizeof set, "readout.ma_table=%s", path);
    ck_assert_int_eq(wf_config_set(&cfg, set, NULL), WF_OK);
    ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_ERR_IO);
    assert_message_has("readout.ma_table");
    assert_message_has(path);

    /* a step coarser than the noise is refused; 0 (lossless) and >= 1 are taken */
    wf_config_defaults(&cfg);
    ck_assert_int_eq(cfg.products.compress, WF_COMPRESS_AUTO);
    ck_assert(cfg.products.quantize_level == 16 && cfg.products.drop_resultants == 0);
    ck_assert_int_eq(wf_config_set(&cfg, "products.quantize_level=0.5", NULL), WF_OK);
    ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_ERR_RANGE);
    assert_message_has("products.quantize_level");
    for (int k = 0; k < 2; k++) {
        wf_config_defaults(&cfg);
        ck_assert_int_eq(wf_config_set(&cfg, k ? "products.quantize_level=1" : "products.quantize_level=0", NULL), WF_OK);
        ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_OK);
    }
}
END_TEST

START_TEST(test_ma_table_from_file)
{
    const char *table = write_file("my.ma", "# three resultants\n1\n2-3\n5, 6\n");
    char text[4300];
    snprintf(text, sizeof text, "readout:\n  ma_table: %s\n  frame_time: 2.5\n", table);
    const char *yaml = write_file("ma.yaml", text);
    wf_config cfg;
    wf_clock clock;
    wf_config_defaults(&cfg);
    ck_assert_int_eq(wf_config_load(&cfg, yaml), WF_OK);
    ck_assert_msg(wf_config_finish(&cfg, &clock) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(clock.ma.nresultants, 3);
    ck_assert_int_eq(clock.ma.nreads, 5);
    ck_assert_int_eq(wf_ma_total_reads(&clock.ma), 6);
    ck_assert_double_eq(wf_clock_exposure_time(&clock), 15.0);
}
END_TEST

/* Read numbers past an int (found by fuzz/fuzz_matable.c: strtol's LONG_MAX, then one read
 * more, overflowed) and past the reads an exposure may take are a range error naming the
 * line, not a wrapped read index. */
START_TEST(test_ma_table_huge_read)
{
    const char *const bad[] = {"1\n2-3\n99999999999999999999999\n", "1\n3000000000\n",
                               "1\n2-9223372036854775807\n"};
    for (int i = 0; i < 3; i++) {
        const char *table = write_file("huge.ma", bad[i]);
        wf_ma_table ma;
        ck_assert_int_eq(wf_ma_load(table, &ma), WF_ERR_RANGE);
        ck_assert_msg(strstr(wf_error_message(), "huge.ma:") &&
                          strstr(wf_error_message(), "past the 2048 reads"),
                      "%s", wf_error_message());
    }
    const char *ok = write_file("edge.ma", "1\n2048\n");
    wf_ma_table ma;
    ck_assert_int_eq(wf_ma_load(ok, &ma), WF_OK);
    ck_assert_int_eq(ma.read[1], 2047);
}
END_TEST

static char *slurp(FILE *f, size_t *len)
{
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap);
    ck_assert_ptr_nonnull(buf);
    for (;;) {
        n += fread(buf + n, 1, cap - n, f);
        if (n < cap) break;
        cap *= 2;
        buf = realloc(buf, cap);
        ck_assert_ptr_nonnull(buf);
    }
    *len = n;
    return buf;
}

/* survey.* keys go to the plan's own table from YAML (scalars and lists) and --set; the
 * values land in cfg.survey and errors name the file and line. */
START_TEST(test_survey_keys)
{
    wf_config cfg;
    wf_config_defaults(&cfg);
    ck_assert_int_eq(cfg.survey.visits, 146);
    const char *path = write_file("survey.yaml", "survey:\n  visits: 12\n  exptimes: [100, 200, 300, 400]\n"
                                                 "seed: 9\n");
    ck_assert_int_eq(wf_config_load(&cfg, path), WF_OK);
    ck_assert_int_eq(cfg.survey.visits, 12);
    ck_assert_double_eq(cfg.survey.exptime[3], 400.0);
    ck_assert_uint_eq(cfg.seed, 9);
    ck_assert_int_eq(wf_config_set(&cfg, "survey.visits=7", NULL), WF_OK);
    ck_assert_int_eq(cfg.survey.visits, 7);
    const char *bad = write_file("bad_survey.yaml", "seed: 1\nsurvey:\n  visits: 0\n");
    ck_assert_int_eq(wf_config_load(&cfg, bad), WF_ERR_RANGE);
    ck_assert_msg(strstr(wf_error_message(), "bad_survey.yaml:3") && strstr(wf_error_message(), "survey.visits"), "%s",
                  wf_error_message());
    ck_assert_int_eq(cfg.survey.visits, 7); /* unchanged on error */
    ck_assert_int_ne(wf_config_set(&cfg, "survey.vists=3", NULL), WF_OK);
    ck_assert_msg(strstr(wf_error_message(), "survey.vists"), "%s", wf_error_message());
}
END_TEST

/* The physical bounds at their edges: readout.frame_time 100 s and exposure.exptime a day are
 * taken; a ramp's exposure time (reads x frame time) is held to the same day when the
 * configuration is finished (a single frame does not use it); an MA table may not name a
 * read past the 2048 the readout tabulates. */
START_TEST(test_time_limits)
{
    wf_config cfg;
    wf_clock clock;
    wf_config_defaults(&cfg);
    ck_assert_int_eq(wf_config_set(&cfg, "readout.frame_time=100", NULL), WF_OK);
    ck_assert_int_eq(wf_config_set(&cfg, "exposure.exptime=86400", NULL), WF_OK);
    ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_OK); /* table 6: 94 reads x 100 s */
    const char *longest = write_file("longest.ma", "2048\n");
    char set[4300];
    snprintf(set, sizeof set, "readout.ma_table=%s", longest);
    const struct { const char *frame, *mode; wf_status st; } cases[] = {
        {"42.1875", "ramp", WF_OK},         /* 2048 x 42.1875 s = 86400 s */
        {"42.1876", "ramp", WF_ERR_RANGE},  /* 86400.2 s */
        {"42.1876", "single", WF_OK},       /* the ramp's time is not used */
    };
    for (int i = 0; i < 3; i++) {
        wf_config_defaults(&cfg);
        char ft[64], mode[64];
        snprintf(ft, sizeof ft, "readout.frame_time=%s", cases[i].frame);
        snprintf(mode, sizeof mode, "exposure.mode=%s", cases[i].mode);
        ck_assert_int_eq(wf_config_set(&cfg, set, NULL), WF_OK);
        ck_assert_int_eq(wf_config_set(&cfg, ft, NULL), WF_OK);
        ck_assert_int_eq(wf_config_set(&cfg, mode, NULL), WF_OK);
        wf_status st = wf_config_finish(&cfg, &clock);
        ck_assert_msg(st == cases[i].st, "%s %s: status %d (%s)", cases[i].frame, cases[i].mode, st, wf_error_message());
        if (st) {
            assert_message_has("readout.ma_table");
            assert_message_has("readout.frame_time");
        } else if (!strcmp(cases[i].mode, "ramp")) {
            ck_assert_double_eq(wf_clock_exposure_time(&clock), 86400.0);
        }
    }
    const char *past = write_file("past.ma", "1\n2049\n");
    snprintf(set, sizeof set, "readout.ma_table=%s", past);
    wf_config_defaults(&cfg);
    ck_assert_int_eq(wf_config_set(&cfg, set, NULL), WF_OK);
    ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_ERR_RANGE);
    assert_message_has("past.ma:2");
    assert_message_has("2049");
}
END_TEST

/* exposure.filter reads names as sim/optics/bandpass.c does (any case; W149 is W146) and keeps the
 * one name, from --set and from YAML; paths.data and paths.reference take a folder or
 * nothing. */
START_TEST(test_filter_alias_and_dirs)
{
    wf_config cfg;
    wf_config_defaults(&cfg);
    const char *names[][2] = {{"W149", "W146"}, {"w149", "W146"}, {"W146", "W146"}, {"y106", "Y106"}};
    for (int i = 0; i < 4; i++) {
        char set[64];
        snprintf(set, sizeof set, "exposure.filter=%s", names[i][0]);
        ck_assert_int_eq(wf_config_set(&cfg, set, NULL), WF_OK);
        ck_assert_str_eq(cfg.filter, names[i][1]);
    }
    const char *yaml = write_file("w149.yaml", "exposure:\n  filter: W149\n");
    wf_config_defaults(&cfg);
    ck_assert_int_eq(wf_config_load(&cfg, yaml), WF_OK);
    ck_assert_str_eq(cfg.filter, "W146");
    char set[4300];
    snprintf(set, sizeof set, "paths.data=%s", wf_test_tmpdir());
    ck_assert_int_eq(wf_config_set(&cfg, set, NULL), WF_OK);
    ck_assert_int_eq(wf_config_set(&cfg, "paths.data=", NULL), WF_OK);
    ck_assert_str_eq(cfg.data_dir, "");
    snprintf(set, sizeof set, "paths:\n  data: %s\n", yaml); /* a file */
    const char *bad = write_file("data.yaml", set);
    ck_assert_int_eq(wf_config_load(&cfg, bad), WF_ERR_INPUT);
    assert_message_has("data.yaml:2");
    assert_message_has("not a directory");
}
END_TEST

START_TEST(test_doc_matches_generated)
{
    FILE *gen = tmpfile();
    ck_assert_ptr_nonnull(gen);
    wf_config_write_doc(gen);
    rewind(gen);
    size_t glen, dlen;
    char *want = slurp(gen, &glen);
    fclose(gen);
    FILE *doc = fopen("docs/CONFIG.md", "rb");
    ck_assert_msg(doc != NULL, "docs/CONFIG.md missing (tests run from the repository root)");
    char *have = slurp(doc, &dlen);
    fclose(doc);
    ck_assert_msg(glen == dlen && !memcmp(want, have, glen),
                  "docs/CONFIG.md is out of date: run "
                  "build/rel/tests/test_config --write-doc docs/CONFIG.md");
    /* the environment must not leak into the reference */
    setenv("WFISIM_DATA", "/elsewhere", 1);
    gen = tmpfile();
    wf_config_write_doc(gen);
    rewind(gen);
    char *again = slurp(gen, &glen);
    fclose(gen);
    ck_assert(glen == dlen && !memcmp(again, have, glen));
    unsetenv("WFISIM_DATA");
    free(want);
    free(have);
    free(again);
}
END_TEST

/* scene.synthetic.*: at their defaults wf_config_synth gives wf_synth_defaults' field (the
 * seed from the config); set, the field extends: more galaxies per arcmin^2 past H 26, 16x
 * the stars over 12 <= V <= 27 and more beyond it (star_density counts only that range). */
START_TEST(test_synthetic_keys)
{
    wf_config cfg;
    wf_config_defaults(&cfg);
    cfg.seed = 7;
    wf_synth_config a, b;
    ck_assert_int_eq(wf_synth_defaults(&a), WF_OK);
    ck_assert_int_eq(wf_config_synth(&cfg, &b), WF_OK);
    ck_assert(b.seed == 7);
    ck_assert_double_eq(b.h_faint, a.h_faint);
    ck_assert_double_eq(b.star_density, a.star_density);
    ck_assert_double_eq(b.star_v_faint, a.star_v_faint);
    ck_assert_int_eq(wf_config_set(&cfg, "scene.synthetic.h_faint=29.5", "test"), WF_OK);
    ck_assert_int_eq(wf_config_set(&cfg, "scene.synthetic.star_density=40", "test"), WF_OK);
    ck_assert_int_eq(wf_config_set(&cfg, "scene.synthetic.star_v_faint=32", "test"), WF_OK);
    ck_assert_int_eq(wf_config_synth(&cfg, &b), WF_OK);
    ck_assert_double_eq(b.h_faint, 29.5);
    wf_synth *sa, *sb;
    ck_assert_int_eq(wf_synth_create(&a, &sa), WF_OK);
    ck_assert_int_eq(wf_synth_create(&b, &sb), WF_OK);
    double ga, sta, gb, stb;
    wf_synth_expected_density(sa, &ga, &sta);
    wf_synth_expected_density(sb, &gb, &stb);
    wf_synth_free(sa);
    wf_synth_free(sb);
    ck_assert_double_eq_tol(sta, 2.5, 1e-9);
    /* the star counts' shape (sim/survey/synth.c: V 12, 16, 20, 24, 27 at 0.003, 0.03, 0.15,
     * 0.35, 0.5 per mag, log-linear between, the last slope carried on), integrated here:
     * 40 per arcmin^2 over 12-27, times (12-32) / (12-27) */
    const double v[6] = {12, 16, 20, 24, 27, 32};
    double n[6] = {0.003, 0.03, 0.15, 0.35, 0.5, 0};
    n[5] = n[4] * pow(n[4] / n[3], 5.0 / 3.0);
    double in27 = 0, in32 = 0;
    for (int k = 0; k < 5; k++) {
        double seg = (n[k + 1] - n[k]) * (v[k + 1] - v[k]) / log(n[k + 1] / n[k]);
        in32 += seg;
        if (k < 4) in27 += seg;
    }
    ck_assert_msg(fabs(stb / (40.0 * in32 / in27) - 1) < 1e-3, "stars %g per arcmin^2, expected %g", stb,
                  40.0 * in32 / in27);
    ck_assert_msg(gb > 1.5 * ga, "galaxies %g per arcmin^2 against %g", gb, ga);
    ck_assert_int_eq(wf_config_set(&cfg, "scene.synthetic.h_faint=40", "test"), WF_ERR_RANGE);
}
END_TEST

static Suite *config_suite(void)
{
    Suite *s = suite_create("config");
    TCase *tc = tcase_create("core");
    tcase_add_test(tc, test_defaults_are_spec_values);
    tcase_add_test(tc, test_paths_default_from_environment);
    tcase_add_test(tc, test_yaml_overrides_nested_keys);
    tcase_add_test(tc, test_empty_file_changes_nothing);
    tcase_add_test(tc, test_set_overrides);
    tcase_add_test(tc, test_set_after_file_wins);
    tcase_add_loop_test(tc, test_bad_file, 0, (int)(sizeof bad_files / sizeof *bad_files));
    tcase_add_test(tc, test_unreadable_file);
    tcase_add_loop_test(tc, test_bad_set, 0, (int)(sizeof bad_sets / sizeof *bad_sets));
    tcase_add_test(tc, test_sampling_names);
    tcase_add_test(tc, test_finish_constraints);
    tcase_add_test(tc, test_ma_table_from_file);
    tcase_add_test(tc, test_time_limits);
    tcase_add_test(tc, test_filter_alias_and_dirs);
    tcase_add_test(tc, test_ma_table_huge_read);
    tcase_add_test(tc, test_survey_keys);
    tcase_add_test(tc, test_synthetic_keys);
    tcase_add_test(tc, test_doc_matches_generated);
    suite_add_tcase(s, tc);
    return s;
}

int main(int argc, char **argv)
{
    if (argc == 3 && !strcmp(argv[1], "--write-doc")) {
        FILE *f = fopen(argv[2], "w");
        if (!f) {
            perror(argv[2]);
            return EXIT_FAILURE;
        }
        wf_config_write_doc(f);
        return fclose(f) == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
    }
    return wf_test_main(config_suite());
}
