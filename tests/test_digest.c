/* tools/digest.c: SHA-256 against the FIPS 180-4 examples, whatever the update boundaries; the
 * configuration text leaves out exactly the keys that cannot change a product; the digest
 * does not move with them and does with any other; the explanation names what changed. */
#include <stdlib.h>
#include <string.h>

#include "tests/testutil.h"
#include "tools/digest.h"

static void hex_of(const void *data, size_t n, size_t step, char hex[65])
{
    wf_sha256 s;
    wf_sha256_init(&s);
    const unsigned char *p = data;
    for (size_t at = 0; at < n; at += step) wf_sha256_update(&s, p + at, n - at < step ? n - at : step);
    wf_sha256_hex(&s, hex);
}

START_TEST(sha256_examples)
{
    static const struct { const char *text, *hex; } v[] = {
        {"", "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"},
        {"abc", "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"},
        {"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq",
         "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1"},
        {"abcdefghbcdefghicdefghijdefghijkefghijklfghijklmghijklmnhijklmnoijklmnopjklmnopqklmnopqrlmnopqrs"
         "mnopqrstnopqrstu", "cf5b16a778af8380036ce59e7b0492370b249b11e8f07a51afac45037afee9d1"},
    };
    for (size_t i = 0; i < sizeof v / sizeof *v; i++)
        for (size_t step = 1; step <= 130; step += 43) {
            char hex[65];
            hex_of(v[i].text, strlen(v[i].text), step, hex);
            ck_assert_str_eq(hex, v[i].hex);
        }
    /* one million 'a', fed in pieces that straddle the 64-byte blocks */
    char *a = malloc(1000000);
    ck_assert_ptr_nonnull(a);
    memset(a, 'a', 1000000);
    char hex[65];
    hex_of(a, 1000000, 4097, hex);
    ck_assert_str_eq(hex, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
    free(a);
}
END_TEST

static void digest_of(const wf_config *cfg, wf_digest *d)
{
    wf_config c = *cfg;
    wf_clock clock;
    ck_assert_int_eq(wf_config_finish(&c, &clock), WF_OK);
    wf_digest_inputs in = {&c, &clock, "hdr.VISIT = 1\n", NULL, NULL, NULL, 0, "test"};
    ck_assert_msg(wf_digest_product(NULL, &in, d) == WF_OK, "%s", wf_error_message());
}

START_TEST(config_part)
{
    wf_config *cfg = malloc(sizeof *cfg), *other = malloc(sizeof *other);
    ck_assert(cfg && other);
    wf_config_defaults(cfg);
    cfg->data_dir[0] = '\0';
    char *text;
    ck_assert_int_eq(wf_config_product_text(cfg, &text), WF_OK);
    ck_assert(strstr(text, "\ndetector.gain = "));
    ck_assert(strstr(text, "\nexposure.mode = ramp\n") && strstr(text, "\ndetector.ipc = "));
    static const char *const out_keys[] = {"run.", "readout.tile_rows", "readout.compress", "paths.", "seed =",
                                           "scene.catalog", "scene.stars", "readout.ma_table", "sn."};
    for (size_t i = 0; i < sizeof out_keys / sizeof *out_keys; i++)
        ck_assert_msg(!strstr(text, out_keys[i]), "%s is in the product text", out_keys[i]);
    free(text);
    wf_digest base, d;
    digest_of(cfg, &base);
    /* the keys left out do not move the digest */
    static const char *const same[] = {"run.threads=7", "readout.tile_rows=8", "run.quiet=true", "run.out=elsewhere",
                                       "readout.compress=false", "sn.h0=60", "run.uncached_writes=false"};
    for (size_t i = 0; i < sizeof same / sizeof *same; i++) {
        *other = *cfg;
        ck_assert_int_eq(wf_config_set(other, same[i], NULL), WF_OK);
        digest_of(other, &d);
        ck_assert_msg(!strcmp(d.whole, base.whole), "%s moved the digest", same[i]);
    }
    /* any other does, in its own part */
    static const struct { const char *set; int part; } moves[] = {
        {"detector.gain=1.5", WF_DIGEST_CONFIG}, {"psf.oversample=5", WF_DIGEST_CONFIG},
        {"exposure.mode=single", WF_DIGEST_CONFIG}, {"readout.ma_table=11", WF_DIGEST_CONFIG},
        {"detector.ipc=[[0,0,0],[0,1,0],[0,0,0]]", WF_DIGEST_CONFIG}, {"seed=2", WF_DIGEST_SEED},
        {"scene.kind=grid", WF_DIGEST_DATA}};
    for (size_t i = 0; i < sizeof moves / sizeof *moves; i++) {
        *other = *cfg;
        ck_assert_int_eq(wf_config_set(other, moves[i].set, NULL), WF_OK);
        digest_of(other, &d);
        ck_assert_msg(strcmp(d.whole, base.whole), "%s did not move the digest", moves[i].set);
        ck_assert_msg(strcmp(d.part[moves[i].part], base.part[moves[i].part]), "%s: not in its part", moves[i].set);
    }
    /* the header's lines: only keys off their defaults, each within one HISTORY card */
    *other = *cfg;
    ck_assert_int_eq(wf_config_set(other, "detector.ipc=[[0.01,0.02,0.01],[0.02,0.88,0.02],[0.01,0.02,0.01]]", NULL), WF_OK);
    ck_assert_int_eq(wf_config_set(other, "psf.jitter=0.014", NULL), WF_OK);
    char *lines;
    ck_assert_int_eq(wf_digest_config_lines(other, &lines), WF_OK);
    ck_assert_msg(!strncmp(lines, "detector.ipc ~ ", 15) && strstr(lines, "\npsf.jitter = 0.014\n"), "%s", lines);
    ck_assert_int_eq((int)(strchr(lines, '\n') - lines), 15 + 16);
    ck_assert_ptr_null(strstr(lines, "gain"));
    free(lines);
    free(cfg);
    free(other);
}
END_TEST

START_TEST(explain_names_keys)
{
    wf_config *cfg = malloc(sizeof *cfg);
    ck_assert_ptr_nonnull(cfg);
    wf_config_defaults(cfg);
    cfg->data_dir[0] = '\0';
    ck_assert_int_eq(wf_config_set(cfg, "detector.gain=1.5", NULL), WF_OK);
    wf_clock clock;
    ck_assert_int_eq(wf_config_finish(cfg, &clock), WF_OK);
    wf_digest_inputs in = {cfg, &clock, NULL, NULL, NULL, NULL, 0, "new"};
    wf_digest now;
    ck_assert_int_eq(wf_digest_product(NULL, &in, &now), WF_OK);
    wf_digest_found was = {.have = 1, .d = now, .have_seed = 1, .seed = 1};
    snprintf(was.origin, sizeof was.origin, "wfisim old");
    strcpy(was.d.whole, "0");
    strcpy(was.d.part[WF_DIGEST_CONFIG], "0");
    strcpy(was.d.part[WF_DIGEST_VERSION], "0");
    was.config = strdup("psf.jitter = 0.014\n");
    char msg[1024];
    wf_digest_explain(&was, &now, &in, msg, sizeof msg);
    ck_assert_msg(strstr(msg, "detector.gain = the default, this run has 1.5") &&
                  strstr(msg, "psf.jitter = 0.014, this run has the default") &&
                  strstr(msg, "wfisim old, this is wfisim new"), "%s", msg);
    ck_assert_msg(!strstr(msg, "seed"), "%s", msg);
    free(was.config);
    wf_digest_found none = {0};
    wf_digest_explain(&none, &now, &in, msg, sizeof msg);
    ck_assert(strstr(msg, "recorded no input digest"));
    free(cfg);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("digest");
    TCase *tc = tcase_create("all");
    tcase_add_test(tc, sha256_examples);
    tcase_add_test(tc, config_part);
    tcase_add_test(tc, explain_names_keys);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
