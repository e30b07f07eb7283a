/* YAML configuration (tools/config.c): the input as a config file, loaded over the defaults
 * and finished as `wfisim expose --config FILE` does (MA table, cross-key checks); then each
 * of its first lines as a `--set KEY=VALUE` override, the command line's way in. */
#include <stdlib.h>
#include <string.h>

#include "fuzz/common.h"
#include "tools/config.h"

#define MAX_SET_LINES 16

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static wf_config cfg; /* 30 KiB: off the stack */
    char path[4096];
    fz_write("config.yaml", data, size, path);
    wf_config_defaults(&cfg);
    if (wf_config_load(&cfg, path) == WF_OK) {
        wf_clock clock;
        (void)wf_config_finish(&cfg, &clock);
    }

    char *text = malloc(size + 1);
    if (!text) return 0;
    memcpy(text, data, size);
    text[size] = '\0';
    wf_config_defaults(&cfg);
    char *save = NULL;
    int n = 0;
    for (char *line = strtok_r(text, "\n", &save); line && n < MAX_SET_LINES;
         line = strtok_r(NULL, "\n", &save), n++)
        (void)wf_config_set(&cfg, line, NULL);
    free(text);
    return 0;
}
