// RELMAP_MULTIVERSION: a hot function compiled twice from its one source, for the baseline
// x86-64 ISA and for x86-64-v3 (AVX2 + FMA), the copy the processor runs chosen by the loader
// when the module loads (GCC's function multiversioning, resolved by glibc's ifunc: no run-time
// compilation, no -march=native). Elsewhere (clang, MSVC, musl, other ISAs) the baseline copy
// alone. The copies differ only by rounding where the compiler contracts a·b + c into a fused
// multiply-add.
#pragma once

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__GLIBC__)
#define RELMAP_MULTIVERSION __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define RELMAP_MULTIVERSION
#endif
