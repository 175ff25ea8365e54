// The types the per-block steps (steps.h) and the FFI handler (kernels.cc) share, and the
// per-instruction-set entry points. Included first by every source of the kernels library,
// before any `#pragma GCC target`: it defines only types and declarations, so no function
// here is compiled for one instruction set and used by another.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

namespace rbjax_native {

// Method codes (the `method` attribute), as in rbjax/_native/__init__.py.
enum Method : int64_t { kEuler = 0, kRk4 = 1, kSplitting = 2, kSemiImplicitEuler = 3, kRk4Body = 4 };

constexpr int kBlock = 64;  // bodies per block: its state and constants stay in L1 across the steps

// The state of one block of bodies, structure of arrays.
template <typename T>
struct Block {
  T x[3][kBlock], v[3][kBlock], q[4][kBlock], L[3][kBlock];
};

// Per-body constants of a block: mass, I_L⁻¹ (row-major 3x3) and the force parameters
// (constant F and τ, gravity g, drag b, b_r, c, c_r, thrusters' body-frame sums; zero where a
// term is absent).
template <typename T>
struct Consts {
  T m[kBlock], inv_m[kBlock], inv[9][kBlock];  // inv_m: 1/m, so F/m is a product (within an ulp)
  T F[3][kBlock], tau[3][kBlock], g[3][kBlock];
  T b[kBlock], br[kBlock], c[kBlock], cr[kBlock];
  T fb[3][kBlock], tb[3][kBlock];  // thrusters' body-frame force and torque sums (steps.h: forces)
};

// the per-body helpers of steps.h must inline into the loops over bodies, or nothing vectorises
#define RBJAX_INLINE __attribute__((always_inline)) inline

// The steps of one block (steps.h: block_steps), compiled once per instruction set, each in a
// source of its own (steps_baseline.cc, steps_avx2.cc, steps_avx512.cc) so that a build
// compiles the three in parallel; kernels.cc picks one at run time.
#define RBJAX_DECLARE_BLOCK_STEPS(isa)                                                                 \
  namespace isa {                                                                                      \
  template <typename T>                                                                                \
  void block_steps(Block<T>& B, const Consts<T>& k, const T (*frame)[kBlock], int n, T dt, int64_t steps, \
                   int64_t method, bool forces, bool quad, bool turn);                                 \
  extern template void block_steps<float>(Block<float>&, const Consts<float>&, const float (*)[kBlock], int, \
                                          float, int64_t, int64_t, bool, bool, bool);                  \
  extern template void block_steps<double>(Block<double>&, const Consts<double>&, const double (*)[kBlock], \
                                           int, double, int64_t, int64_t, bool, bool, bool);           \
  template <typename T>                                                                                \
  void block_frames(const T (*inertia)[kBlock], int n, T (*frame)[kBlock]);                            \
  extern template void block_frames<float>(const float (*)[kBlock], int, float (*)[kBlock]);           \
  extern template void block_frames<double>(const double (*)[kBlock], int, double (*)[kBlock]);        \
  }
RBJAX_DECLARE_BLOCK_STEPS(baseline)
#if defined(__x86_64__) && defined(__GNUC__)
#define RBJAX_X86 1
RBJAX_DECLARE_BLOCK_STEPS(avx2)
RBJAX_DECLARE_BLOCK_STEPS(avx512)
#endif

}  // namespace rbjax_native
