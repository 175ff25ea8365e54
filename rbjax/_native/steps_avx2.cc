// The per-block steps (steps.h) for AVX2 and FMA (x86-64 only): see block.h.
#include "block.h"
#ifdef RBJAX_X86
#pragma GCC target("avx2,fma")
namespace rbjax_native {
namespace avx2 {
#include "steps.h"
}  // namespace avx2
}  // namespace rbjax_native
#endif
