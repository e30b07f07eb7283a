/* wfisim's own cfitsio disk driver, for the files the project creates. cfitsio's file://
 * driver goes through stdio with a 4 KiB buffer, and an SCA product is written out of order
 * (every image HDU's header first, then the rows of SCI, ERR and DQ tile by tile): cfitsio
 * then fills the gap before each later header with zero records, 200 MB of zeros for a
 * single-frame SCA, overwritten by the pixels moments later. This driver writes through a
 * 1 MiB write-back buffer and turns zero records appended at the end of the file into a
 * hole (extended by ftruncate at flush and close), which reads back as the same zeros.
 * Where the file system states a direct-I/O alignment, whole pages go out past the page
 * cache (O_DIRECT) and the partial pages at the edges of each write wait in memory for
 * their neighbours. The bytes of every file are those the file:// driver writes. */
#ifndef WF_FITSDISK_H
#define WF_FITSDISK_H

#include <fitsio.h>

/* As fits_create_diskfile: path is taken literally (no extended filename syntax), an
 * existing file is an error, and the cfitsio status is returned and left in *status. */
int wf_fitsdisk_create(fitsfile **f, const char *path, int *status);

/* Large writes bypass the page cache where the file system allows it (the default);
 * 0 sends everything through it. Affects files created afterwards. */
void wf_fitsdisk_uncached(int enabled);

/* Bytes this process has written to such files, past the page cache and through it. */
void wf_fitsdisk_written(long long *uncached, long long *cached);

/* Bytes this process has read back from such files (what cfitsio reloads; the kernel's). */
long long wf_fitsdisk_read_back(void);

#endif
