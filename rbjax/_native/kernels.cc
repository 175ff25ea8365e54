// Native CPU kernels for rbjax's explicit steps, called from JAX through XLA's FFI.
//
// One call advances a batch of State bodies (x, v, q, L) by `steps` steps of dt,
// the steps between two saved frames of rbjax.simulate. The arithmetic mirrors the
// JAX reference in rbjax/_methods/ (euler.py, explicit_rk.py, splitting.py,
// semi_implicit_euler.py, rk4_body.py; with rbjax/_dynamics.py and the force models
// of rbjax/_forces.py) map by map, so the two agree to round-off; tests/test_native.py
// holds them to it.
// How the pieces map, and how to add a method: README.md beside this file.
//
// Layout: batch-first, as the state arrives from the user (no transposes): a
// field of c components is a (V, N, c) array, component k of body i at
// [i * c + k]; per-body parameters are (V, n, c) with n = N (one per body) or
// n = 1 (shared). V (from jax.vmap) counts independent batches. Each block
// gathers its bodies into a structure of arrays once per call.
//
// The `terms` attribute: bit 0, some force or torque acts (else v and L stay);
// bit 1, quadratic drag is among them (two square roots per evaluation); bit 2, thrusters
// (body-fixed force and torque sums, turned by R(q) at each evaluation); bit 3, a world torque
// (constant or a time series), which rk4_body turns into the body frame (steps.h: body_forces)
// and splitting into the principal frame (steps.h: principal_kick).
// The `series` attribute: 0, or `steps` when F and τ are a time series (V, steps, n, 3),
// one slice per step (rbjax.simulate's forces of shape (steps, *B, 3)), held over its stages.

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <memory>
#include <thread>

#include "block.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace rbjax_native {

// Which instruction set the steps run with: 0 baseline, 1 AVX2, 2 AVX-512.
// Every extension a variant is compiled for must be there (a processor with AVX-512F alone, as
// Xeon Phi, lacks the VL/DQ/BW forms the compiler may emit). RBJAX_NATIVE_ISA=baseline or avx2
// caps the choice (avx512 or unset: no cap), so that a processor which would take a wider variant
// can test the others.
int isa() {
#ifdef RBJAX_X86
  static const int level = [] {
    const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    const bool avx512 = avx2 && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
                        __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512bw");
    const int cpu = avx512 ? 2 : avx2 ? 1 : 0;
    const char* cap = std::getenv("RBJAX_NATIVE_ISA");
    if (cap != nullptr && std::strcmp(cap, "baseline") == 0) return 0;
    if (cap != nullptr && std::strcmp(cap, "avx2") == 0) return std::min(cpu, 1);
    return cpu;
  }();
  return level;
#else
  return 0;
#endif
}

template <typename T>
inline void block_frames(const T (*inertia)[kBlock], int n, T (*frame)[kBlock]) {
#ifdef RBJAX_X86
  if (isa() == 2) return avx512::block_frames<T>(inertia, n, frame);
  if (isa() == 1) return avx2::block_frames<T>(inertia, n, frame);
#endif
  baseline::block_frames<T>(inertia, n, frame);
}

template <typename T>
inline void block_steps(Block<T>& B, const Consts<T>& k, const T (*frame)[kBlock], int n, T dt, int64_t steps,
                        int64_t method, bool forces, bool quad, bool turn) {
#ifdef RBJAX_X86
  if (isa() == 2) return avx512::block_steps<T>(B, k, frame, n, dt, steps, method, forces, quad, turn);
  if (isa() == 1) return avx2::block_steps<T>(B, k, frame, n, dt, steps, method, forces, quad, turn);
#endif
  baseline::block_steps<T>(B, k, frame, n, dt, steps, method, forces, quad, turn);
}

// A per-body parameter of `comps` components, (V, n, comps) with n = N or 1 (shared).
template <typename T>
struct Param {
  const T* p = nullptr;
  int64_t n = 1;
  int64_t rows = 1;  // slices per batch V: the steps of a time series (V, steps, n, comps), else 1
  void load(int64_t vb, int64_t i0, int count, int comps, T (*dst)[kBlock], int64_t row = 0) const {
    const T* base = p + (vb * rows + row) * comps * n;
    for (int c = 0; c < comps; ++c)
      for (int j = 0; j < count; ++j) dst[c][j] = base[(n == 1 ? 0 : i0 + j) * comps + c];
  }
};

// Everything one call needs, with the element type erased to T.
template <typename T>
struct Problem {
  T *x, *v, *q, *L;                  // outputs, (V, N, c)
  const T *x0, *v0, *q0, *L0;        // inputs, (V, N, c)
  Param<T> m, inv, F, tau, g, drag;  // (V, n, c): mass 1, inverse 9, F/τ/g 3, drag 4 (b, b_r, c, c_r);
                                     // F and τ (V, steps, n, 3) when `series`
  Param<T> inertia;                  // (V, n, 6): the inertia's upper triangle (splitting's principal frames)
  Param<T> thrusters;                // (V, n, 6): the thrusters' body-frame force and torque sums
  const T* dt;                       // (V,)
  int64_t V, N, steps, method;
  bool forces, quad, thrust, series;  // series: F and τ hold one slice per step, held over the step's stages
  bool turn;  // the steps' forces need R(q): thrusters, and for rk4_body and splitting a world torque too
};

template <typename T>
void run_block(const Problem<T>& P, int64_t vb, int64_t i0, int n) {
  Block<T> B;
  Consts<T> k;
  const int64_t N = P.N;
  const T* in[4] = {P.x0, P.v0, P.q0, P.L0};
  T* out[4] = {P.x, P.v, P.q, P.L};
  T(*blk[4])[kBlock] = {B.x, B.v, B.q, B.L};
  const int comps[4] = {3, 3, 4, 3};
  for (int f = 0; f < 4; ++f)
    for (int c = 0; c < comps[f]; ++c)
      for (int j = 0; j < n; ++j) blk[f][c][j] = in[f][(vb * N + i0 + j) * comps[f] + c];
  T m[1][kBlock], drag[4][kBlock], frame[7][kBlock];
  P.m.load(vb, i0, n, 1, m);
  P.inv.load(vb, i0, n, 9, k.inv);
  P.F.load(vb, i0, n, 3, k.F);
  P.tau.load(vb, i0, n, 3, k.tau);
  P.g.load(vb, i0, n, 3, k.g);
  P.drag.load(vb, i0, n, 4, drag);
  if (P.method == kSplitting) {  // the principal frames, once per call (steps.h: block_frames)
    T inertia[6][kBlock];
    P.inertia.load(vb, i0, n, 6, inertia);
    block_frames(inertia, n, frame);
  }
  if (P.thrust) {
    T fbtb[6][kBlock];
    P.thrusters.load(vb, i0, n, 6, fbtb);
    for (int c = 0; c < 3; ++c)
      for (int j = 0; j < n; ++j) {
        k.fb[c][j] = fbtb[c][j];
        k.tb[c][j] = fbtb[3 + c][j];
      }
  } else if (P.turn) {  // a world torque and no thrusters: zero sums
    for (int c = 0; c < 3; ++c)
      for (int j = 0; j < n; ++j) k.fb[c][j] = k.tb[c][j] = T(0);
  }
  for (int j = 0; j < n; ++j) {
    k.m[j] = m[0][j];
    k.inv_m[j] = T(1) / m[0][j];
    k.b[j] = drag[0][j];
    k.br[j] = drag[1][j];
    k.c[j] = drag[2][j];
    k.cr[j] = drag[3][j];
  }
  if (!P.series) {
    block_steps(B, k, frame, n, P.dt[vb], P.steps, P.method, P.forces, P.quad, P.turn);
  } else {
    // a time series: each step's F and τ into the block's constants, then that one step (the
    // block stays in L1 between the steps, as in the loop over steps of block_steps)
    for (int64_t s = 0; s < P.steps; ++s) {
      if (s > 0) {
        P.F.load(vb, i0, n, 3, k.F, s);
        P.tau.load(vb, i0, n, 3, k.tau, s);
      }
      block_steps(B, k, frame, n, P.dt[vb], 1, P.method, P.forces, P.quad, P.turn);
    }
  }
  for (int f = 0; f < 4; ++f)
    for (int c = 0; c < comps[f]; ++c)
      for (int j = 0; j < n; ++j) out[f][(vb * N + i0 + j) * comps[f] + c] = blk[f][c][j];
}

// The blocks of all V batches, claimed from a shared counter by the calling thread and by
// tasks on XLA's intra-op thread pool. The caller claims blocks too, so the call finishes
// even if no task ever runs (or the caller is the pool's only thread); it returns once
// every block is done. The counters are shared with the tasks, which may start late.
template <typename T>
void run(const Problem<T>& P, ffi::ThreadPool& pool) {
  const int64_t per_v = (P.N + kBlock - 1) / kBlock;
  const int64_t blocks = P.V * per_v;
  struct Counters {
    std::atomic<int64_t> next{0}, done{0};
  };
  auto counters = std::make_shared<Counters>();
  auto work = [P, per_v, blocks](Counters& s) {
    for (int64_t b; (b = s.next.fetch_add(1)) < blocks;) {
      const int64_t vb = b / per_v, i0 = (b % per_v) * kBlock;
      run_block(P, vb, i0, static_cast<int>(std::min<int64_t>(kBlock, P.N - i0)));
      s.done.fetch_add(1);
    }
  };
  // a few blocks per task at least: below ~16 blocks a task costs more than it saves
  const int64_t helpers = std::min<int64_t>(pool.num_threads(), blocks / 16);
  for (int64_t h = 0; h < helpers; ++h) pool.Schedule([counters, work]() { work(*counters); });
  work(*counters);
  while (counters->done.load() < blocks) std::this_thread::yield();
}

template <typename T>
ffi::Error advance_typed(ffi::ThreadPool& pool, ffi::AnyBuffer x, ffi::AnyBuffer v, ffi::AnyBuffer q,
                         ffi::AnyBuffer L, ffi::AnyBuffer m, ffi::AnyBuffer inv, ffi::AnyBuffer F,
                         ffi::AnyBuffer tau, ffi::AnyBuffer g, ffi::AnyBuffer drag, ffi::AnyBuffer inertia,
                         ffi::AnyBuffer thrust, ffi::AnyBuffer dt, ffi::Result<ffi::AnyBuffer> xo,
                         ffi::Result<ffi::AnyBuffer> vo, ffi::Result<ffi::AnyBuffer> qo,
                         ffi::Result<ffi::AnyBuffer> Lo, int64_t steps, int64_t method, int64_t terms,
                         int64_t series) {
  auto dims = x.dimensions();
  if (dims.size() < 2 || dims[dims.size() - 1] != 3) return ffi::Error::InvalidArgument("x must be (..., N, 3)");
  if (method < kEuler || method > kRk4Body) {
    return ffi::Error::InvalidArgument("unknown method code");
  }
  Problem<T> P;
  P.N = dims[dims.size() - 2];
  P.V = P.N == 0 ? 0 : static_cast<int64_t>(x.element_count()) / (3 * P.N);
  P.steps = steps;
  P.method = method;
  P.forces = (terms & 1) != 0;
  P.quad = (terms & 2) != 0;
  P.thrust = (terms & 4) != 0;
  P.turn = P.thrust || ((method == kRk4Body || method == kSplitting) && (terms & 8) != 0);
  P.series = series != 0;
  if (P.series && series != steps) return ffi::Error::InvalidArgument("a time series needs one slice per step");
  P.x0 = x.typed_data<T>();
  P.v0 = v.typed_data<T>();
  P.q0 = q.typed_data<T>();
  P.L0 = L.typed_data<T>();
  P.x = xo->typed_data<T>();
  P.v = vo->typed_data<T>();
  P.q = qo->typed_data<T>();
  P.L = Lo->typed_data<T>();
  P.dt = dt.typed_data<T>();
  auto bind = [](const ffi::AnyBuffer& b, Param<T>& p) {
    auto d = b.dimensions();
    p.p = b.typed_data<T>();
    p.n = d[d.size() - 2];
  };
  bind(m, P.m);
  bind(inv, P.inv);
  bind(F, P.F);
  bind(tau, P.tau);
  bind(g, P.g);
  bind(drag, P.drag);
  bind(inertia, P.inertia);
  bind(thrust, P.thrusters);
  if (P.series) {
    P.F.rows = P.tau.rows = steps;
    for (const ffi::AnyBuffer* b : {&F, &tau}) {
      auto d = b->dimensions();
      if (d.size() < 3 || d[d.size() - 3] != steps) {
        return ffi::Error::InvalidArgument("time-series F and tau must be (..., steps, n, 3)");
      }
    }
  }
  if (P.V > 0) run(P, pool);
  return ffi::Error::Success();
}

ffi::Error advance(ffi::ThreadPool pool, ffi::AnyBuffer x, ffi::AnyBuffer v, ffi::AnyBuffer q, ffi::AnyBuffer L,
                   ffi::AnyBuffer m, ffi::AnyBuffer inv, ffi::AnyBuffer F, ffi::AnyBuffer tau, ffi::AnyBuffer g,
                   ffi::AnyBuffer drag, ffi::AnyBuffer inertia, ffi::AnyBuffer thrust, ffi::AnyBuffer dt,
                   ffi::Result<ffi::AnyBuffer> xo, ffi::Result<ffi::AnyBuffer> vo, ffi::Result<ffi::AnyBuffer> qo,
                   ffi::Result<ffi::AnyBuffer> Lo, int64_t steps, int64_t method, int64_t terms, int64_t series) {
  switch (x.element_type()) {
    case ffi::DataType::F32:
      return advance_typed<float>(pool, x, v, q, L, m, inv, F, tau, g, drag, inertia, thrust, dt, xo, vo, qo, Lo,
                                  steps, method, terms, series);
    case ffi::DataType::F64:
      return advance_typed<double>(pool, x, v, q, L, m, inv, F, tau, g, drag, inertia, thrust, dt, xo, vo, qo, Lo,
                                   steps, method, terms, series);
    default:
      return ffi::Error::InvalidArgument("rbjax native kernels take float32 or float64 states");
  }
}

}  // namespace rbjax_native

// The library's exported symbols (everything else is hidden: -fvisibility=hidden).
extern "C" __attribute__((visibility("default"))) XLA_FFI_Error* RbjaxAdvance(XLA_FFI_CallFrame* call_frame);

// The version of the call's operands and attributes, which rbjax/_native/__init__.py checks on
// load (_ABI there): a library built from an older kernels.cc is refused, not called wrongly.
// 2: the thrusters' operand and the `series` attribute. 3: `terms` bit 3 (a world torque), and
// rk4_body's forces on the unit quaternion q/|q|. 4: the inertia's upper triangle in place of
// splitting's principal frames, which the kernel computes. (A library without this symbol is older.)
extern "C" __attribute__((visibility("default"))) int rbjax_native_abi() { return 4; }

// The instruction set the steps run with here: 0 x86-64 baseline (or not x86), 1 AVX2, 2 AVX-512.
extern "C" __attribute__((visibility("default"))) int rbjax_native_isa() { return rbjax_native::isa(); }

XLA_FFI_DEFINE_HANDLER_SYMBOL(RbjaxAdvance, rbjax_native::advance,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::AnyBuffer>()  // x
                                  .Arg<ffi::AnyBuffer>()  // v
                                  .Arg<ffi::AnyBuffer>()  // q
                                  .Arg<ffi::AnyBuffer>()  // L
                                  .Arg<ffi::AnyBuffer>()  // mass
                                  .Arg<ffi::AnyBuffer>()  // inverse inertia
                                  .Arg<ffi::AnyBuffer>()  // force
                                  .Arg<ffi::AnyBuffer>()  // torque
                                  .Arg<ffi::AnyBuffer>()  // gravity
                                  .Arg<ffi::AnyBuffer>()  // drag coefficients
                                  .Arg<ffi::AnyBuffer>()  // inertia's upper triangle (splitting's frames)
                                  .Arg<ffi::AnyBuffer>()  // thrusters' body-frame sums
                                  .Arg<ffi::AnyBuffer>()  // dt
                                  .Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Attr<int64_t>("steps")
                                  .Attr<int64_t>("method")
                                  .Attr<int64_t>("terms")
                                  .Attr<int64_t>("series"));
