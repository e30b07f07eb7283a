/* What the fuzz harnesses share. The parsers read paths (as users give them), so each input
 * is written to a scratch file in a directory of this process's own and the parser is handed
 * its path: the code under test is the one `wfisim` runs, not a memory-only variant. */
#ifndef WF_FUZZ_COMMON_H
#define WF_FUZZ_COMMON_H

#include <stddef.h>
#include <stdint.h>

/* This process's scratch directory (made on first use, removed at exit). */
const char *fz_dir(void);

/* Writes size bytes to fz_dir()/name; the path goes to out (at least 4096 bytes) and is
 * returned. Aborts on a write error, which is the harness's fault, not the parser's. */
const char *fz_write(const char *name, const uint8_t *data, size_t size, char *out);

/* Empties fz_dir()/sub (products a parser wrote), keeping the directory. */
void fz_clean(const char *sub);

/* 1 when data is gzip'd and its trailer says it inflates to more than 64 MiB. cfitsio takes
 * that length on trust and allocates it before inflating (up to 4 GiB for a few damaged
 * bytes); glibc leaves such memory untouched, but ASan poisons its shadow, seconds and
 * hundreds of MiB per input. The FITS harnesses skip these inputs: cfitsio's, not wfisim's. */
int fz_gzip_claims_too_much(const uint8_t *data, size_t size);

/* The entry point libFuzzer (or AFL++ through afl-clang-fast -fsanitize=fuzzer) calls. */
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#endif
