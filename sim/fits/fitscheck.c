#include "sim/fits/fitscheck.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#define BLOCK 2880
#define CARD 80
/* More HDUs than any input of ours has; a walk past this stops checking, it does not fail. */
#define MAX_HDUS 100000

/* The integer value of a fixed-format card "KEY     = value", or 0 when the card is not KEY. */
static int card_int(const char *card, const char *key, long long *v)
{
    size_t n = strlen(key);
    if (strncmp(card, key, n)) return 0;
    for (size_t i = n; i < 8; i++)
        if (card[i] != ' ') return 0;
    if (card[8] != '=' || card[9] != ' ') return 0;
    char text[CARD - 9];
    memcpy(text, card + 10, CARD - 10);
    text[CARD - 10] = '\0';
    char *end;
    long long x = strtoll(text, &end, 10);
    if (end == text) return 0;
    *v = x;
    return 1;
}

/* a * b, or -1 when it passes what a FITS file of ours could hold */
static long long mul_cap(long long a, long long b)
{
    const long long cap = (long long)1 << 50;
    if (a < 0 || b < 0) return -1;
    if (a != 0 && b > cap / a) return -1;
    return a * b;
}

wf_status wf_fits_check_headers(const char *path)
{
    gzFile gz = gzopen(path, "rb");
    if (!gz) return WF_OK; /* the reader's own open says why, in its words */
    wf_status st = WF_OK;
    char block[BLOCK];
    for (int hdu = 1; hdu <= MAX_HDUS; hdu++) {
        long long bitpix = 0, naxis = -1, pcount = 0, gcount = 1, axes[1000];
        int have_bitpix = 0, end = 0, groups = 0;
        for (int j = 0; j < 1000; j++) axes[j] = -1; /* a missing NAXISn ends the walk */
        long long card_no = 0;
        while (!end) {
            int got = gzread(gz, block, BLOCK);
            if (got != BLOCK) goto done; /* the end of the file (or a short one: cfitsio's to say) */
            for (int c = 0; c < BLOCK / CARD && !end; c++, card_no++) {
                const char *card = block + c * CARD;
                for (int i = 0; i < CARD; i++) {
                    unsigned char b = (unsigned char)card[i];
                    if (b < 0x20 || b > 0x7e) {
                        char key[9];
                        int k = 0;
                        for (; k < 8 && card[k] >= 0x21 && card[k] <= 0x7e; k++) key[k] = card[k];
                        key[k] = '\0';
                        st = wf_error(WF_ERR_INPUT,
                                      "%s: HDU %d, header card %lld%s%s%s: byte 0x%02x at column %d is not "
                                      "printable ASCII, which FITS headers must be",
                                      path, hdu, card_no + 1, k ? " (" : "", key, k ? ")" : "", b, i + 1);
                        goto done;
                    }
                }
                long long v;
                if (!strncmp(card, "END", 3) && !strncmp(card + 3, "     ", 5)) end = 1;
                else if (card_int(card, "BITPIX", &v)) bitpix = v, have_bitpix = 1;
                else if (card_int(card, "NAXIS", &v)) naxis = v;
                else if (card_int(card, "PCOUNT", &v)) pcount = v;
                else if (card_int(card, "GCOUNT", &v)) gcount = v;
                else if (!strncmp(card, "GROUPS  = ", 10) && memchr(card + 10, 'T', CARD - 10)) groups = 1;
                else if (!strncmp(card, "NAXIS", 5) && card[5] >= '1' && card[5] <= '9') {
                    char key[9];
                    memcpy(key, card, 8);
                    key[8] = '\0';
                    char *sp = strchr(key, ' ');
                    if (sp) *sp = '\0';
                    long long j = strtoll(key + 5, NULL, 10);
                    if (j >= 1 && j <= 999 && card_int(card, key, &v)) axes[j] = v;
                }
            }
        }
        if (!have_bitpix || naxis < 0 || naxis > 999) goto done;
        long long n = naxis ? 1 : 0;
        for (long long j = 1; j <= naxis && n >= 0; j++) {
            if (j == 1 && groups && axes[1] == 0) continue; /* random groups: NAXIS1 = 0 */
            n = mul_cap(n, axes[j]);
        }
        long long bytes = mul_cap(mul_cap(llabs(bitpix) / 8, gcount), n + (naxis ? pcount : 0));
        if (n < 0 || bytes < 0) goto done;
        long long skip = (bytes + BLOCK - 1) / BLOCK * BLOCK;
        if (skip && gzseek(gz, (z_off_t)skip, SEEK_CUR) < 0) goto done;
    }
done:
    gzclose(gz);
    return st;
}
