/* Memory arena: the firmware's only source of memory.
 * The host hands over one block at start; every firmware buffer is carved from it. A request
 * past the budget fails with WF_ERR_NOMEM and a message naming what asked; there is no
 * fallback to malloc. Marks let a caller release scratch space in LIFO order. */
#ifndef WF_ARENA_H
#define WF_ARENA_H

#include <stddef.h>
#include "hal/status.h"

typedef struct wf_arena {
    unsigned char *base;
    size_t capacity;
    size_t used;
    size_t high_water; /* most ever used: what the budget really needed */
    const char *name;
} wf_arena;

/* Wraps memory the host reserved; the arena never frees it. The modules' *_need sizes assume
 * a block aligned to 64 bytes (wf_arena_host_alloc's): an unaligned one loses up to 63 bytes
 * to its first alignment. */
wf_status wf_arena_init(wf_arena *arena, void *memory, size_t capacity, const char *name);

/* Reserves `size` bytes aligned to 64 (cache line, SIMD), zero-filled, for `what`. */
wf_status wf_arena_alloc(wf_arena *arena, size_t size, const char *what, void **out);

/* The same, not zero-filled: for buffers whose every read follows a write, so that pages the
 * run never reaches stay out of resident memory. */
wf_status wf_arena_reserve(wf_arena *arena, size_t size, const char *what, void **out);

/* Typed convenience: count * elem bytes, with overflow check. */
wf_status wf_arena_calloc(wf_arena *arena, size_t count, size_t elem, const char *what, void **out);

/* Host memory for an arena or a pool that the run fills whole: aligned to 2 MiB and offered
 * to the kernel for transparent huge pages, so that filling it costs one page fault per
 * 2 MiB instead of 512 (a fault costs microseconds on a virtual machine). The last huge page
 * is offered only when the arena fills half of it (as wf_arena_host_realloc): a huge page is
 * resident whole, and a 28.1 MiB readout arena would otherwise keep 30. Not for memory the
 * run touches sparsely. Free with free(); NULL when out of memory. */
void *wf_arena_host_alloc(size_t size);

/* Grows a host buffer (p NULL: a new one) to `size` bytes, keeping its first `used`. From
 * `size` WF_ARENA_HOST_HUGE up, aligned to 2 MiB and offered to the kernel for huge pages:
 * its whole ones, and the last one too when the buffer fills at least half of it (else that
 * tail stays ordinary pages), so that at most 1 MiB is resident unused. Below it, realloc.
 * For the host's large buffers that the run fills whole (tile rows, the object list, an
 * inflated file, packets): on a virtual machine the first touch of a 4 KiB page costs
 * ~14 us, of a 2 MiB one ~100 us (`bench_pages`, docs/BENCHMARKS.md). Free with free();
 * NULL when out of memory, p then untouched. */
#define WF_ARENA_HOST_HUGE ((size_t)1 << 20)
#define WF_ARENA_HUGE_PAGE ((size_t)2 << 20) /* x86-64's transparent huge page */
void *wf_arena_host_realloc(void *p, size_t used, size_t size);

/* Host memory for an arena that its first user fills only in part: 2 MiB aligned, with the
 * huge pages of its first `dense` bytes offered to the kernel as wf_arena_host_realloc
 * chooses them, the rest ordinary pages that stay out of resident memory until touched.
 * Free with free(); NULL when out of memory. */
void *wf_arena_host_alloc_dense(size_t size, size_t dense);

size_t wf_arena_mark(const wf_arena *arena);
void wf_arena_release(wf_arena *arena, size_t mark);

/* Takes `size` bytes (or up to 63 more, for alignment) off the top of the arena as an arena
 * of its own, `top`: scratch that must not lie below what the caller keeps, which it keeps
 * from the bottom meanwhile. The arena's capacity shrinks by as much until wf_arena_join
 * gives them back (top's contents are then free space). */
wf_status wf_arena_split(wf_arena *arena, size_t size, const char *name, wf_arena *top);
void wf_arena_join(wf_arena *arena, const wf_arena *top);

/* Bytes an allocation of `size` consumes, alignment included: lets a module report its need
 * before anything is reserved. WF_SIZE_OVERFLOW (hal/size.h) when that does not fit a size_t. */
size_t wf_arena_cost(size_t size);

#endif
