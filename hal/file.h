/* Host files, the way every product and table leaves the program: written under a temporary
 * name and renamed into place only when whole, and output folders made so that a failed run
 * can take back the empty ones it made. Host side only: the firmware writes through the link. */
#ifndef WF_HAL_FILE_H
#define WF_HAL_FILE_H

#include <stddef.h>
#include <stdio.h>

#include "hal/status.h"

#define WF_PATH_MAX 1024

/* mkdir -p. */
wf_status wf_file_make_dir(const char *dir);
/* The same, noting in made (WF_PATH_MAX bytes) the shallowest folder it created ("" when
 * all were there), so that wf_file_unmake_dir can take back the folders a failed run made,
 * those still empty: a failure leaves no empty output folder behind. */
wf_status wf_file_make_dir_noting(const char *dir, char *made);
void wf_file_unmake_dir(const char *dir, const char *made);

/* Renames the whole file tmp onto path (atomic within a file system); on failure removes
 * tmp, so that neither a half-written product nor its temporary stays, and says why, naming
 * both. Every writer of a product ends with this. */
wf_status wf_file_rename(const char *tmp, const char *path);

/* Opens a new temporary text file beside path, of a name no other process has (mkstemp: job
 * array tasks writing into one folder at once never share it), its name in tmp. */
wf_status wf_file_text_open(const char *path, char *tmp, size_t cap, FILE **out);
/* Closes a text file written to tmp and renames it onto path (removing tmp on any error). */
wf_status wf_file_text_commit(FILE *out, const char *tmp, const char *path);

#endif
