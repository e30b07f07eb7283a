/* Host-side assembly: a packet stream in, one FITS file per exposure and SCA out.
 * HDUs: primary (exposure keywords, MA table, detector values), SCI (rate, e-/s, float32),
 * ERR (e-/s, float32), DQ (uint32, WF_DQ_*), and in up-the-ramp mode RESULTANTS (uint16 ADU
 * cube [resultant][y][x]); COSMICRAYS (cosmic-ray truth table) when cosmic rays are on;
 * CHECKSUM/DATASUM on every HDU (docs/PACKETS.md). Tiles are fitted and written as
 * they arrive (memory bounded by a tile, not the SCA). With `compress` the image HDUs are
 * tile-compressed (sim/fits/fitscomp.h); with `drop_resultants` RESULTANTS is left out (a tile's
 * resultants are then held until its SATURATION packet arrives: one tile in the readout's
 * order, more only if a stream sends them far apart). Written to "<name>.tmp" and renamed
 * only when every row arrived exactly once, so a damaged stream leaves no FITS behind. */
#ifndef WF_ASSEMBLE_H
#define WF_ASSEMBLE_H

#include <stdio.h>
#include "hal/packet.h"
#include "hal/status.h"

typedef struct wf_assemble_options {
    const char *out_dir;   /* where FITS files go */
    int quiet;
    int compress;          /* tile-compress the image HDUs */
    double quantize_level; /* with compress: SCI and ERR step noise / q; 0 lossless */
    int drop_resultants;   /* no RESULTANTS HDU */
    int border;            /* with the reference border received: HDUs REFROWS and REFCOLS */
} wf_assemble_options;

/* Reads the whole stream; writes out_dir/wfisim_e<exposure>_sca<NN>.fits per exposure.
 * `name` is used in messages ("-" for stdin). Paths written are reported on stderr unless
 * quiet, and the last one is copied to last_path (may be NULL). */
wf_status wf_assemble_stream(FILE *in, const char *name, const wf_assemble_options *opt,
                             char *last_path, size_t last_path_len);
/* The same from any byte source (hal/packet.h), e.g. an in-process pipe (hal/link.h). */
wf_status wf_assemble_source(wf_packet_read_fn read, void *ctx, const char *name,
                             const wf_assemble_options *opt, char *last_path, size_t last_path_len);

#endif
