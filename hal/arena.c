#include "hal/arena.h"
#include "hal/size.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#define ARENA_ALIGN 64u

wf_status wf_arena_init(wf_arena *arena, void *memory, size_t capacity, const char *name)
{
    if (!arena || (!memory && capacity))
        return wf_error(WF_ERR_INTERNAL, "arena: no memory given");
    arena->base = memory;
    arena->capacity = capacity;
    arena->used = 0;
    arena->high_water = 0;
    arena->name = name ? name : "arena";
    /* Align the start so that every offset we hand out is aligned in absolute terms. */
    uintptr_t start = (uintptr_t)memory;
    size_t pad = (size_t)((ARENA_ALIGN - start % ARENA_ALIGN) % ARENA_ALIGN);
    arena->used = pad > capacity ? capacity : pad;
    arena->high_water = arena->used;
    return WF_OK;
}

#define HUGE_PAGE WF_ARENA_HUGE_PAGE

static size_t whole_huge_pages(size_t size) { return (size + HUGE_PAGE - 1) / HUGE_PAGE * HUGE_PAGE; }

/* `size` bytes aligned to a huge page, of which the first `advised` are offered to the kernel
 * for transparent huge pages (the rest stays ordinary pages). */
static void *huge_aligned(size_t size, size_t advised)
{
    void *p = NULL;
    /* more than the address space could hold is refused here, not handed to the allocator */
    if (!size || size > SIZE_MAX / 4) return NULL;
    if (posix_memalign(&p, HUGE_PAGE, whole_huge_pages(size)) != 0) return NULL;
#ifdef MADV_HUGEPAGE
    /* Memory the allocator recycles may still have some of its pages mapped, and a range that
     * does is faulted in 4 KiB pages whatever the advice: drop them first (the block is ours
     * whole, its contents are not yet anyone's). */
    if (advised) {
        (void)madvise(p, advised, MADV_DONTNEED);
        (void)madvise(p, advised, MADV_HUGEPAGE); /* advice: without it, ordinary pages */
    }
#endif
    return p;
}

/* The huge pages a range of `filled` bytes from a huge page's start takes: its whole ones,
 * and the last only when the range fills half of it at least (a huge page is resident
 * whole, so at most 1 MiB goes unused). */
static size_t huge_part(size_t filled)
{
    size_t whole = filled / HUGE_PAGE * HUGE_PAGE, tail = filled - whole;
    return whole + (tail >= HUGE_PAGE / 2 ? HUGE_PAGE : 0);
}

void *wf_arena_host_alloc(size_t size)
{
    return huge_aligned(size, huge_part(size));
}

void *wf_arena_host_alloc_dense(size_t size, size_t dense)
{
    return huge_aligned(size, huge_part(dense < size ? dense : size));
}

void *wf_arena_host_realloc(void *p, size_t used, size_t size)
{
    if (size < WF_ARENA_HOST_HUGE) return realloc(p, size ? size : 1);
    void *q = huge_aligned(size, huge_part(size));
    if (!q) return NULL;
    if (p) memcpy(q, p, used < size ? used : size);
    free(p);
    return q;
}

size_t wf_arena_cost(size_t size)
{
    if (size > WF_SIZE_OVERFLOW - (ARENA_ALIGN - 1)) return WF_SIZE_OVERFLOW; /* would wrap to 0 */
    return (size + ARENA_ALIGN - 1) / ARENA_ALIGN * ARENA_ALIGN;
}

wf_status wf_arena_alloc(wf_arena *arena, size_t size, const char *what, void **out)
{
    wf_status st = wf_arena_reserve(arena, size, what, out);
    if (!st) memset(*out, 0, size);
    return st;
}

wf_status wf_arena_reserve(wf_arena *arena, size_t size, const char *what, void **out)
{
    *out = NULL;
    size_t need = wf_arena_cost(size);
    if (need == WF_SIZE_OVERFLOW || need > arena->capacity - arena->used)
        return wf_error(WF_ERR_NOMEM,
                        "%s: cannot reserve %zu bytes for %s (%zu of %zu bytes in use); "
                        "raise the memory budget or lower the tile height",
                        arena->name, size, what ? what : "a buffer", arena->used, arena->capacity);
    void *p = arena->base + arena->used;
    arena->used += need;
    if (arena->used > arena->high_water)
        arena->high_water = arena->used;
    *out = p;
    return WF_OK;
}

wf_status wf_arena_calloc(wf_arena *arena, size_t count, size_t elem, const char *what, void **out)
{
    if (wf_size_mul(count, elem) == WF_SIZE_OVERFLOW) {
        *out = NULL;
        return wf_error(WF_ERR_NOMEM, "%s: size of %s overflows (%zu x %zu)", arena->name,
                        what ? what : "a buffer", count, elem);
    }
    return wf_arena_alloc(arena, count * elem, what, out);
}

size_t wf_arena_mark(const wf_arena *arena) { return arena->used; }

void wf_arena_release(wf_arena *arena, size_t mark)
{
    if (mark <= arena->used)
        arena->used = mark;
}

wf_status wf_arena_split(wf_arena *arena, size_t size, const char *name, wf_arena *top)
{
    memset(top, 0, sizeof *top);
    uintptr_t end = (uintptr_t)arena->base + arena->capacity, low = (uintptr_t)arena->base + arena->used;
    if (size > end - low || (end - size) / ARENA_ALIGN * ARENA_ALIGN < low)
        return wf_error(WF_ERR_NOMEM,
                        "%s: cannot split off %zu bytes for %s (%zu of %zu bytes in use); "
                        "raise the memory budget",
                        arena->name, size, name ? name : "scratch", arena->used, arena->capacity);
    uintptr_t start = (end - size) / ARENA_ALIGN * ARENA_ALIGN;
    arena->capacity = (size_t)(start - (uintptr_t)arena->base);
    return wf_arena_init(top, (void *)start, (size_t)(end - start), name);
}

void wf_arena_join(wf_arena *arena, const wf_arena *top)
{
    size_t at = (size_t)(top->base - arena->base);
    if (at != arena->capacity) return; /* not this arena's top: nothing to give back */
    arena->capacity += top->capacity;
    if (at + top->high_water > arena->high_water) arena->high_water = at + top->high_water;
}
