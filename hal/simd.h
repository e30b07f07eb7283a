/* SIMD clones of a hot loop's function: the compiler builds it for AVX-512, AVX2 and the
 * baseline, and the loader picks one for the CPU (GCC target_clones, x86-64 only; not under
 * the sanitizers, whose run-time does not take ifunc resolvers). A clone changes no bit as
 * long as the function does not reassociate: -std=c11 keeps floating-point contraction off,
 * so every lane does the scalar operations in the same order. */
#ifndef WF_HAL_SIMD_H
#define WF_HAL_SIMD_H

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#define WF_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define WF_CLONES
#endif

#endif
