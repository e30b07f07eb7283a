/* The static planes of scenes kept in a folder, for the later exposures of the same static
 * scene (sim/draw/render.h "plane"): an SCA's static objects summed once per pointing, PA,
 * filter and SCA and read back by every later exposure of it, instead of drawn again (~1.8
 * CPU-s of a deep-field product; docs/BENCHMARKS.md). The bytes of a product do not depend on
 * whether its plane came from here.
 *
 * An entry is one file, <key>.plane: a 4096-byte text header (the key, the SCA's size,
 * whether it has the layer, and a note its writer left: the scene's counts) and the plane's
 * float rows, then the layer's, in this machine's byte order, each row at its fixed place; rows
 * of zeros are never written (holes). It is written under a temporary name by the threads that
 * fill the rows, and renamed into place only when every row came and every write succeeded,
 * so a reader sees whole entries or none, whichever processes share the folder (survey run's
 * isolated children, MPI ranks, job arrays). A file that does not match its key is never
 * used. Beyond max_bytes of entries, the least recently used go (and temporary files a
 * killed writer left, once a day old).
 *
 * Failing to keep an entry (a full disk, a folder that cannot be written) never fails the
 * exposure: the plane was drawn anyway; the stats count it and keep the first reason. */
#ifndef WF_PLANE_CACHE_H
#define WF_PLANE_CACHE_H

#include <stddef.h>

#include "hal/scene.h"
#include "hal/status.h"

#define WF_PLANE_NOTE_MAX 1024

typedef struct wf_plane_cache wf_plane_cache;

typedef struct wf_plane_cache_stats {
    long hits;       /* entries read instead of drawn */
    long stored;     /* entries written */
    long unusable;   /* files found under a key but not matching it (redrawn, replaced) */
    long not_kept;   /* entries that could not be written */
    long evicted;    /* entries removed for room */
    char reason[512]; /* why the first entry was not kept ("" when none) */
} wf_plane_cache_stats;

/* The folder is made when absent. max_bytes: the room the entries may take on disk. */
wf_status wf_plane_cache_open(const char *dir, double max_bytes, wf_plane_cache **out);
void wf_plane_cache_close(wf_plane_cache *c);
void wf_plane_cache_get_stats(wf_plane_cache *c, wf_plane_cache_stats *out);

typedef struct wf_plane_entry wf_plane_entry;

/* The entry of key (64 hex digits: everything that shapes the plane) for an SCA of ncols x
 * nrows, with the layer's rows when layer is nonzero. *found 1: it gives the rows
 * (wf_plane_entry_get) and the note; 0: it takes them (wf_plane_entry_put). */
wf_status wf_plane_entry_open(wf_plane_cache *c, const char *key, int ncols, int nrows, int layer,
                              wf_plane_entry **out, int *found);
/* The entry of key when the folder holds it whole, to read (*out NULL when not): nothing is
 * written. */
wf_status wf_plane_entry_find(wf_plane_cache *c, const char *key, int ncols, int nrows, int layer,
                              wf_plane_entry **out);
/* The renderer's plane_get (plane may be NULL: the layer alone) and plane_put
 * (sim/draw/render.h), with the entry as ctx. */
wf_status wf_plane_entry_get(void *entry, int y0, int y1, int ncols, float *plane, float *layer);
void wf_plane_entry_put(void *entry, int y, const float *plane, const float *layer, int ncols);
/* A found entry's layer rows as a scene source's rates (a persistence history's earlier
 * exposure read instead of drawn, tools/persist.h); valid while e is open. An entry without
 * the layer fails the first fill. */
void wf_plane_entry_layer_source(wf_plane_entry *e, wf_scene_source *out);
/* A found entry's note. */
const char *wf_plane_entry_note(const wf_plane_entry *e);
/* The note an entry being written will keep. */
void wf_plane_entry_set_note(wf_plane_entry *e, const char *note);
/* Closes the entry; one being written is kept if every row came (and removed if not). */
void wf_plane_entry_close(wf_plane_entry *e);

#endif
