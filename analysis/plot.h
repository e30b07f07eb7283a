/* Raster plots for the host tools (light curves, accuracy plots, coverage maps), written as
 * PNG by analysis/png.h. No anti-aliasing; a built-in 5x7 font (x2 for titles). A plot is a black
 * frame with outward ticks, a light grid at the ticks, %g tick labels, the title above, the
 * x label below, the y label rotated along the left edge and a legend box in the frame's
 * top-right corner. Example and layout: docs/PLOTS.md. */
#ifndef WF_PLOT_H
#define WF_PLOT_H

#include "hal/status.h"

typedef struct wf_plot wf_plot;
enum { WF_PLOT_LINE = 1, WF_PLOT_MARKERS = 2, WF_PLOT_ERRORBARS = 4 };

/* width, height: 64..8000 pixels; title and labels may be NULL. */
wf_status wf_plot_create(int width, int height, const char *title, const char *xlabel,
                         const char *ylabel, wf_plot **out);
/* Fixed ranges; without a call the ranges come from the data (5% margins, error bars
 * included). Log axes need positive ranges (non-positive data skipped). */
wf_status wf_plot_set_range(wf_plot *p, double xmin, double xmax, double ymin, double ymax);
wf_status wf_plot_set_log(wf_plot *p, int logx, int logy);
wf_status wf_plot_invert_y(wf_plot *p, int on); /* magnitudes: bright up */
/* A series; yerr may be NULL unless style has WF_PLOT_ERRORBARS. Colours cycle through a fixed
 * palette; label goes into a legend box (NULL: no legend entry). Non-finite points are skipped
 * (a line breaks there). The data are copied. */
wf_status wf_plot_series(wf_plot *p, const double *x, const double *y, const double *yerr, int n,
                         const char *label, int style);
/* Pixel position (column, row from the top; pixel centres at integers) of a data point in the
 * image written, with the ranges as they are now (call after the last series). */
wf_status wf_plot_data_to_pixel(wf_plot *p, double x, double y, double *px, double *py);
wf_status wf_plot_write_png(wf_plot *p, const char *path);
void wf_plot_free(wf_plot *p);

/* A map, e.g. survey coverage: data[iy*nx + ix], row iy = 0 at the bottom, column ix = 0 at the
 * left. [x0,x1] x [y0,y1] are the user coordinates of the map's left, right, bottom and top
 * edges (x0 > x1 allowed: RA increasing to the left). Colours vmin..vmax through
 * wf_plot_colormap; values below vmin (zero coverage) and non-finite ones are white, values
 * above vmax take the vmax colour. Cells are scaled to a map of 160..800 pixels a side (nearest
 * cell when the map is larger). A colour bar with tick labels and cbar_label on the right. */
wf_status wf_plot_map_png(const float *data, int nx, int ny, double x0, double x1, double y0,
                          double y1, double vmin, double vmax, const char *title,
                          const char *xlabel, const char *ylabel, const char *cbar_label,
                          const char *path);

/* The tick rule of linear axes: ticks at the integer multiples of a step 1, 2 or 5 x 10^k that
 * lie in [lo, hi], with the largest such step that gives at least max(4, target) ticks. Writes
 * at most max and returns their number (0 when lo >= hi or either is not finite). Log axes
 * tick the decades (every n-th beyond 8), or 1, 2, 5 x 10^k when they span under 3 decades. */
int wf_plot_nice_ticks(double lo, double hi, int target, double *ticks, int max);

/* The map colour at t (clamped to [0, 1]): dark violet through blue, teal and green to yellow,
 * lightness rising throughout, so that order survives grey printing. */
void wf_plot_colormap(double t, unsigned char rgb[3]);

#endif
