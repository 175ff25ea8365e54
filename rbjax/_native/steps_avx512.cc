// The per-block steps (steps.h) for AVX-512 (x86-64 only): see block.h.
#include "block.h"
#ifdef RBJAX_X86
#pragma GCC target("avx512f,avx512dq,avx512vl,avx512bw,avx2,fma")
namespace rbjax_native {
namespace avx512 {
#include "steps.h"
}  // namespace avx512
}  // namespace rbjax_native
#endif
