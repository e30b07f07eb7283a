/* PNG writer for the host tools: 8-bit RGB, non-interlaced, deflated with zlib. Each row gets
 * the filter (of the five PNG defines) with the smallest sum of absolute residuals, the usual
 * cheap predictor of what deflate compresses best. */
#ifndef WF_PNG_H
#define WF_PNG_H

#include "hal/status.h"

/* rgb: height rows of width R,G,B bytes, top row first. Written to path.tmp and renamed, so a
 * failure never leaves a partial file at path. Errors name the path. */
wf_status wf_png_write_rgb(const char *path, const unsigned char *rgb, int width, int height);

#endif
