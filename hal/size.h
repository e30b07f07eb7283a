/* Checked size arithmetic for memory budgets and buffer lengths.
 * A product or sum that would wrap gives WF_SIZE_OVERFLOW (SIZE_MAX), and every later step
 * keeps it, so a budget of many terms is checked once, at its end, with a message naming
 * what was being sized: a wrapped size would otherwise reach an allocator as a small or an
 * absurd request. */
#ifndef WF_SIZE_H
#define WF_SIZE_H

#include <stddef.h>
#include <stdint.h>

#define WF_SIZE_OVERFLOW SIZE_MAX

static inline size_t wf_size_mul(size_t a, size_t b)
{
    size_t r;
    if (a == WF_SIZE_OVERFLOW || b == WF_SIZE_OVERFLOW || __builtin_mul_overflow(a, b, &r))
        return WF_SIZE_OVERFLOW;
    return r;
}

static inline size_t wf_size_add(size_t a, size_t b)
{
    size_t r;
    if (a == WF_SIZE_OVERFLOW || b == WF_SIZE_OVERFLOW || __builtin_add_overflow(a, b, &r))
        return WF_SIZE_OVERFLOW;
    return r;
}

static inline size_t wf_size_mul3(size_t a, size_t b, size_t c) { return wf_size_mul(wf_size_mul(a, b), c); }

/* A non-negative count held in a double (an expectation, a capacity with its margin) as a
 * size: NaN, negative or past `limit` gives WF_SIZE_OVERFLOW rather than the undefined
 * conversion that turns 1e300 into a negative int. */
static inline size_t wf_size_from_double(double v, size_t limit)
{
    if (!(v >= 0.0) || !(v <= (double)limit)) return WF_SIZE_OVERFLOW;
    return (size_t)v;
}

#endif
