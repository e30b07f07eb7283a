/* The Philox4x32-10 bijection (Salmon et al. 2011), shared by the scalar streams
 * (hal/noise.c) and the row batches (hal/noise_batch.c) so the two cannot drift apart.
 * Internal to hal/: firmware and tools use hal/noise.h. */
#ifndef WF_PHILOX_H
#define WF_PHILOX_H

#include <stdint.h>

static inline void wf_philox_rounds(uint32_t *c0, uint32_t *c1, uint32_t *c2, uint32_t *c3,
                                    uint32_t k0, uint32_t k1)
{
    uint32_t a = *c0, b = *c1, c = *c2, d = *c3;
#pragma GCC unroll 10
    for (int round = 0; round < 10; round++) {
        uint64_t p0 = (uint64_t)0xD2511F53u * a;
        uint64_t p1 = (uint64_t)0xCD9E8D57u * c;
        uint32_t n0 = (uint32_t)(p1 >> 32) ^ b ^ k0;
        uint32_t n2 = (uint32_t)(p0 >> 32) ^ d ^ k1;
        b = (uint32_t)p1;
        d = (uint32_t)p0;
        a = n0;
        c = n2;
        k0 += 0x9E3779B9u; /* Weyl key schedule */
        k1 += 0xBB67AE85u;
    }
    *c0 = a; *c1 = b; *c2 = c; *c3 = d;
}

#endif
