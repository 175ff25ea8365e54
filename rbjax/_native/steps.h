// The per-block steps of rbjax's native kernels (see README.md beside this file).
//
// Included once per instruction set, by steps_baseline.cc, steps_avx2.cc and
// steps_avx512.cc, inside a namespace of its own under `#pragma GCC target`, so
// this file includes nothing (block.h, included first, has the types) and defines
// only templates. Every loop runs over the bodies j of one block, straight-line, so
// the compiler vectorises it; the steps are the outer loop, so the block's
// state stays in L1 between them.
//
// Each formula computes the same map as the JAX function it names, mostly in the
// same order; where it regroups for speed (README.md lists where), the two still
// agree to round-off, which tests/test_native.py holds them to.

// q ⊗ (0, a) ⊗ q* as rbjax._math.quat_rotate: a + w t + u × t with t = 2 u × a.
template <typename T>
RBJAX_INLINE void quat_rotate(const T q[4], const T a[3], T out[3]) {
  const T ux = q[1], uy = q[2], uz = q[3];
  const T t0 = T(2) * (uy * a[2] - uz * a[1]);
  const T t1 = T(2) * (uz * a[0] - ux * a[2]);
  const T t2 = T(2) * (ux * a[1] - uy * a[0]);
  out[0] = a[0] + q[0] * t0 + (uy * t2 - uz * t1);
  out[1] = a[1] + q[0] * t1 + (uz * t0 - ux * t2);
  out[2] = a[2] + q[0] * t2 + (ux * t1 - uy * t0);
}

// Rᵀ a: the rotation by the conjugate (w, -u), as quat_rotate(quat_conjugate(q), a).
template <typename T>
RBJAX_INLINE void quat_rotate_back(const T q[4], const T a[3], T out[3]) {
  const T conj[4] = {q[0], -q[1], -q[2], -q[3]};
  quat_rotate(conj, a, out);
}

// out_i = Σ_k A[i·kRow + k·kCol] a_k, summed left to right: A v for a row-major 3x3 A
// with (kRow, kCol) = (3, 1), Aᵀ v with (1, 3).
template <int kRow, int kCol, typename T>
RBJAX_INLINE void strided_matvec3(const T A[9], const T a[3], T out[3]) {
  #pragma GCC unroll 16
  for (int i = 0; i < 3; ++i) out[i] = A[i * kRow] * a[0] + A[i * kRow + kCol] * a[1] + A[i * kRow + 2 * kCol] * a[2];
}

// A v for a row-major 3x3 A, as rbjax._math.matvec3.
template <typename T>
RBJAX_INLINE void matvec3(const T A[9], const T a[3], T out[3]) {
  strided_matvec3<3, 1>(A, a, out);
}

// The matrix of quat_rotate(q, ·) for any q (unit or not, as the stages of RK4 see it):
// a ↦ a + 2w (u × a) + 2 u × (u × a), i.e. R = 1 + 2w [u]ₓ + 2 [u]ₓ²; quat_rotate_back is Rᵀ.
// With `two` = 2/|q|² it is the rotation of q/|q| (for q ≠ 0 of any norm).
template <typename T>
RBJAX_INLINE void rotation(const T q[4], T R[9], T two = T(2)) {
  const T x2 = two * q[1], y2 = two * q[2], z2 = two * q[3];
  const T xx = q[1] * x2, yy = q[2] * y2, zz = q[3] * z2, xy = q[1] * y2, xz = q[1] * z2, yz = q[2] * z2;
  const T wx = q[0] * x2, wy = q[0] * y2, wz = q[0] * z2;
  R[0] = T(1) - (yy + zz);
  R[1] = xy - wz;
  R[2] = xz + wy;
  R[3] = xy + wz;
  R[4] = T(1) - (xx + zz);
  R[5] = yz - wx;
  R[6] = xz - wy;
  R[7] = yz + wx;
  R[8] = T(1) - (xx + yy);
}

// Rᵀ a for a row-major 3x3 R.
template <typename T>
RBJAX_INLINE void matvec3_t(const T A[9], const T a[3], T out[3]) {
  strided_matvec3<1, 3>(A, a, out);
}

// ω = R I_L⁻¹ Rᵀ L, as rbjax._dynamics.omega_world computes it with two quat_rotates and
// matvec3; here R is built once and applied twice (fewer operations, the same map).
template <typename T>
RBJAX_INLINE void omega(const T q[4], const T L[3], const T inv[9], T w[3]) {
  T R[9], b[3], a[3];
  rotation(q, R);
  matvec3_t(R, L, b);
  matvec3(inv, b, a);
  matvec3(R, a, w);
}

// (0, ω) ⊗ q without the zero, as rbjax._math.pure_quat_multiply.
template <typename T>
RBJAX_INLINE void pure_quat_multiply(const T w[3], const T q[4], T p[4]) {
  p[0] = -(w[0] * q[1] + w[1] * q[2] + w[2] * q[3]);
  p[1] = q[0] * w[0] + (w[1] * q[3] - w[2] * q[2]);
  p[2] = q[0] * w[1] + (w[2] * q[1] - w[0] * q[3]);
  p[3] = q[0] * w[2] + (w[0] * q[2] - w[1] * q[1]);
}

// a × b.
template <typename T>
RBJAX_INLINE void cross3(const T a[3], const T b[3], T out[3]) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

// ‖a‖, as rbjax._math.safe_norm (whose where only guards its gradient at 0).
template <typename T>
RBJAX_INLINE T norm3(const T a[3]) {
  return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
}

template <typename T>
RBJAX_INLINE void normalize(T q[4]) {
  const T inv = T(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  #pragma GCC unroll 16
  for (int c = 0; c < 4; ++c) q[c] = q[c] * inv;
}

// Force and torque on body j at attitude q, velocity v and world ω: the terms of a force model
// sum in the order constant, gravity, linear drag, quadratic drag, thrusters. Absent terms have
// zero coefficients, and adding their (signed) zeros changes no finite value, so this is the
// sum of the present terms alone.
//
// Thrusters (kThrust; rbjax/_attached.py: Thruster): thruster s on body j pushes with world force
// T_s R d_s at the world offset R p_s, torque (R p_s) × (T_s R d_s), with R the matrix of
// quat_rotate(q, ·) (not a rotation at an RK4 stage, where |q| ≠ 1). Summed over the body's
// thrusters, F = R f_b and τ = Σ (R p_s) × (R f_s) = cof(R) τ_b, with the body-frame sums
// f_b = Σ T_s d_s and τ_b = Σ p_s × T_s d_s (scattered onto the bodies in JAX once per call):
// (R a) × (R b) = cof(R) (a × b) holds for any 3x3 R, whose cofactor matrix has the columns
// c₁ × c₂, c₂ × c₀, c₀ × c₁ of R's columns c_k. The same map as the JAX model's, regrouped.
template <typename T, bool kQuad, bool kThrust>
RBJAX_INLINE void forces(const Consts<T>& k, int j, const T q[4], const T v[3], const T w[3], T F[3], T tau[3]) {
  T sv = T(0), sw = T(0);
  if (kQuad) {
    sv = -k.c[j] * norm3(v);
    sw = -k.cr[j] * norm3(w);
  }
  #pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) {
    F[c] = (k.F[c][j] + k.m[j] * k.g[c][j]) + -k.b[j] * v[c];
    tau[c] = k.tau[c][j] + -k.br[j] * w[c];
    if (kQuad) {
      F[c] = F[c] + sv * v[c];
      tau[c] = tau[c] + sw * w[c];
    }
  }
  if (kThrust) {
    T R[9];
    rotation(q, R);
    const T fb[3] = {k.fb[0][j], k.fb[1][j], k.fb[2][j]}, tb[3] = {k.tb[0][j], k.tb[1][j], k.tb[2][j]};
    T Fw[3];
    matvec3(R, fb, Fw);
    // the columns of R, and cof(R) τ_b = τ_b,0 (c₁ × c₂) + τ_b,1 (c₂ × c₀) + τ_b,2 (c₀ × c₁)
    const T c0[3] = {R[0], R[3], R[6]}, c1[3] = {R[1], R[4], R[7]}, c2[3] = {R[2], R[5], R[8]};
    T x12[3], x20[3], x01[3];
    cross3(c1, c2, x12);
    cross3(c2, c0, x20);
    cross3(c0, c1, x01);
    #pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) {
      F[c] = F[c] + Fw[c];
      tau[c] = tau[c] + ((tb[0] * x12[c] + tb[1] * x20[c]) + tb[2] * x01[c]);
    }
  }
}

// Body j's row-major I_L⁻¹, out of the block's constants.
template <typename T>
RBJAX_INLINE void load_inv(const Consts<T>& k, int j, T inv[9]) {
#pragma GCC unroll 16
  for (int c = 0; c < 9; ++c) inv[c] = k.inv[c][j];
}

// Body j's quaternion, into the block's rows.
template <typename T>
RBJAX_INLINE void store_q(Block<T>& B, int j, const T q[4]) {
#pragma GCC unroll 16
  for (int c = 0; c < 4; ++c) B.q[c][j] = q[c];
}

// Body j's quaternion, momentum, velocity and inverse inertia, out of the block's rows.
template <typename T>
RBJAX_INLINE void load_body(const Block<T>& B, const Consts<T>& k, int j, T q[4], T L[3], T v[3], T inv[9]) {
#pragma GCC unroll 16
  for (int c = 0; c < 4; ++c) q[c] = B.q[c][j];
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) {
    L[c] = B.L[c][j];
    v[c] = B.v[c][j];
  }
  load_inv(k, j, inv);
}

// Body j's quaternion, momentum and velocity, back into the block's rows.
template <typename T>
RBJAX_INLINE void store_body(Block<T>& B, int j, const T q[4], const T L[3], const T v[3]) {
  store_q(B, j, q);
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) {
    B.v[c][j] = v[c];
    B.L[c][j] = L[c];
  }
}

// `steps` explicit-Euler steps of a block (rbjax/_methods/euler.py: euler_state).
// kForces: whether any force or torque acts (else v and L do not change).
template <typename T, bool kForces, bool kQuad, bool kThrust>
void euler_steps(Block<T>& B, const Consts<T>& k, int n, T dt, int64_t steps) {
  const T h = T(0.5) * dt;
  for (int64_t s = 0; s < steps; ++s) {
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      T q[4], L[3], v[3], inv[9], w[3], p[4];
      load_body(B, k, j, q, L, v, inv);
      omega(q, L, inv, w);
      if (kForces) {
        T F[3], tau[3];
        forces<T, kQuad, kThrust>(k, j, q, v, w, F, tau);
        #pragma GCC unroll 16
        for (int c = 0; c < 3; ++c) {
          B.v[c][j] = v[c] + F[c] * k.inv_m[j] * dt;
          B.L[c][j] = L[c] + tau[c] * dt;
        }
      }
      #pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) B.x[c][j] = B.x[c][j] + v[c] * dt;
      pure_quat_multiply(w, q, p);
      #pragma GCC unroll 16
      for (int c = 0; c < 4; ++c) q[c] = q[c] + h * p[c];
      normalize(q);
      store_q(B, j, q);
    }
  }
}

// The Newton–Euler right-hand side (rbjax/_dynamics.py) of a 13-component state
// y = (x, v, q, L) of body j, into d; v̇ and L̇ only with forces.
template <typename T, bool kForces, bool kQuad, bool kThrust>
RBJAX_INLINE void derivative(const Consts<T>& k, int j, const T y[13], T d[13]) {
  T inv[9], w[3], p[4];
  load_inv(k, j, inv);
  omega(y + 6, y + 10, inv, w);
  #pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) d[c] = y[3 + c];
  if (kForces) {
    T F[3], tau[3];
    forces<T, kQuad, kThrust>(k, j, y + 6, y + 3, w, F, tau);
    #pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) {
      d[3 + c] = F[c] * k.inv_m[j];
      d[10 + c] = tau[c];
    }
  }
  pure_quat_multiply(w, y + 6, p);
  #pragma GCC unroll 16
  for (int c = 0; c < 4; ++c) d[6 + c] = T(0.5) * p[c];
}

// One stage of the classical RK4 tableau over the moving components c of y:
// acc = b k (the first stage) or acc + b k, and the next stage's point st = y + dt (a k).
template <typename T, bool kFirst, bool kForces>
RBJAX_INLINE void rk4_stage(int first, int moving, T b, T a, T dt, const T y[13], const T kk[13], T acc[13], T st[13]) {
  #pragma GCC unroll 16
  for (int c = first; c < moving; ++c) {
    if (kForces || c >= 6) {
      acc[c] = kFirst ? b * kk[c] : acc[c] + b * kk[c];
      st[c] = y[c] + dt * (a * kk[c]);
    }
  }
}

// `steps` classical RK4 steps of a block (rbjax/_methods/rk4.py through
// explicit_rk.py): stage i at y + dt (a_i k_{i-1}), the result y + dt Σ_i b_i k_i
// summed left to right (accumulated as each stage's k is known, the same sum), then q
// normalised. Without forces v and L do not change, and x moves by v in every stage.
template <typename T, bool kForces, bool kQuad, bool kThrust>
void rk4_steps(Block<T>& B, const Consts<T>& k, int n, T dt, int64_t steps) {
  const T half = T(0.5), sixth = T(1.0 / 6.0), third = T(1.0 / 3.0);
  const int first = kForces ? 0 : 3;  // without forces only x (0-2, from v alone) and q move
  const int moving = kForces ? 13 : 10;
  for (int64_t s = 0; s < steps; ++s) {
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      T y[13], kk[13], st[13], acc[13];
      #pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) {
        y[c] = B.x[c][j];
        y[3 + c] = B.v[c][j];
        y[10 + c] = B.L[c][j];
      }
      #pragma GCC unroll 16
      for (int c = 0; c < 4; ++c) y[6 + c] = B.q[c][j];
      #pragma GCC unroll 16
      for (int c = 0; c < 13; ++c) st[c] = y[c];
      derivative<T, kForces, kQuad, kThrust>(k, j, y, kk);
      rk4_stage<T, true, kForces>(first, moving, sixth, half, dt, y, kk, acc, st);
      derivative<T, kForces, kQuad, kThrust>(k, j, st, kk);
      rk4_stage<T, false, kForces>(first, moving, third, half, dt, y, kk, acc, st);
      derivative<T, kForces, kQuad, kThrust>(k, j, st, kk);
      rk4_stage<T, false, kForces>(first, moving, third, T(1), dt, y, kk, acc, st);
      derivative<T, kForces, kQuad, kThrust>(k, j, st, kk);
      #pragma GCC unroll 16
      for (int c = first; c < moving; ++c) {
        if (kForces || c >= 6) y[c] = y[c] + dt * (acc[c] + sixth * kk[c]);
      }
      if (!kForces) {
        // every stage's ẋ is the constant v: the same sum with k_i = v
        #pragma GCC unroll 16
        for (int c = 0; c < 3; ++c) {
          const T v = y[3 + c];
          y[c] = y[c] + dt * (((sixth * v + third * v) + third * v) + sixth * v);
        }
      }
      normalize(y + 6);
      #pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) {
        B.x[c][j] = y[c];
        B.v[c][j] = y[3 + c];
        B.L[c][j] = y[10 + c];
      }
      #pragma GCC unroll 16
      for (int c = 0; c < 4; ++c) B.q[c][j] = y[6 + c];
    }
  }
}

// Hamilton product p ⊗ q, as rbjax._math.quat_multiply.
template <typename T>
RBJAX_INLINE void quat_multiply(const T p[4], const T q[4], T out[4]) {
  out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3];
  out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2];
  out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1];
  out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0];
}

// Half-angle pair of a rational turn (rbjax/_methods/splitting.py: _cayley).
template <typename T>
RBJAX_INLINE void cayley(T g, T n2, T& c2, T& t2) {
  const T x2 = g * g * n2;
  const T num = g * (T(945) + x2 * (x2 - T(105)));
  const T den = T(945) + x2 * (T(15) * x2 - T(420));
  const T num2 = num * num * n2, den2 = den * den;
  const T r = T(1) / (den2 + num2);
  c2 = (den2 - num2) * r;
  t2 = T(2) * num * den * r;
}

// The turn about principal axis i by θ with half-angle pair (c2, s2) and (c, s) = (cos θ, sin θ):
// qp ← qp ⊗ (c2, s2 e_i), m ← Rot_i(-θ) m (splitting.py: _rotate_about, after its _cayley).
template <typename T, int i>
RBJAX_INLINE void apply_turn(T qp[4], T m[3], T c2, T s2, T c, T s) {
  constexpr int j = (i + 1) % 3, l = (i + 2) % 3;
  const T qw = qp[0], u[3] = {qp[1], qp[2], qp[3]};
  T nu[3], nm[3];
  nu[i] = c2 * u[i] + s2 * qw;
  nu[j] = c2 * u[j] + s2 * u[l];
  nu[l] = c2 * u[l] - s2 * u[j];
  nm[i] = m[i];
  nm[j] = c * m[j] + s * m[l];
  nm[l] = c * m[l] - s * m[j];
  qp[0] = qw * c2 - s2 * u[i];
  for (int a = 0; a < 3; ++a) {
    qp[1 + a] = nu[a];
    m[a] = nm[a];
  }
}

// The pair of the turn by θ = h k m_i about axis i: c2, s2 and c, s as apply_turn takes them.
template <typename T, int i>
RBJAX_INLINE void turn_pair(const T m[3], T k, T h, T pair[4]) {
  T c2, t2;
  cayley(h * k / T(4), m[i] * m[i], c2, t2);
  const T s2 = t2 * m[i];
  pair[0] = c2;
  pair[1] = s2;
  pair[2] = T(1) - T(2) * s2 * s2;
  pair[3] = T(2) * s2 * c2;
}

// The exact flow of ½ k_i m_i² over h: a turn about principal axis i (splitting.py: _rotate_about).
template <typename T, int i>
RBJAX_INLINE void rotate_about(T qp[4], T m[3], T k, T h) {
  T pair[4];
  turn_pair<T, i>(m, k, h, pair);
  apply_turn<T, i>(qp, m, pair[0], pair[1], pair[2], pair[3]);
}

// H_L of the split free rotor over h (splitting.py: free_rotor): the turn about world L by
// |L| h e₂, [c2, tl L], with e the principal frame's inverse moments (rbjax._eigh3.principal_frame).
template <typename T>
RBJAX_INLINE void turn_about_L(const T L[3], const T e[3], T h, T turn[4]) {
  T c2, tl;
  cayley(h * e[1] / T(4), L[0] * L[0] + L[1] * L[1] + L[2] * L[2], c2, tl);
  turn[0] = c2;
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) turn[1 + c] = tl * L[c];
}

// kick(h) of body j (rbjax._methods._common.kick): v += F/m h, L += τ h, with the forces at (q, L, v).
template <typename T, bool kQuad, bool kThrust>
RBJAX_INLINE void kick(const Consts<T>& k, int j, const T q[4], const T inv[9], T h, T v[3], T L[3]) {
  T w[3], F[3], tau[3];
  omega(q, L, inv, w);
  forces<T, kQuad, kThrust>(k, j, q, v, w, F, tau);
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) {
    v[c] = v[c] + F[c] * k.inv_m[j] * h;
    L[c] = L[c] + tau[c] * h;
  }
}

// Body j's principal-frame attitude qp = q ⊗ p and momentum m = R(qp)ᵀ L, from the block's q and L
// and the frame's p (rows 0-3): where the splitting kernels start a call.
template <typename T>
RBJAX_INLINE void to_principal(const Block<T>& B, const T (*frame)[kBlock], int j, T qp[4], T m[3]) {
  const T q[4] = {B.q[0][j], B.q[1][j], B.q[2][j], B.q[3][j]}, L[3] = {B.L[0][j], B.L[1][j], B.L[2][j]};
  const T p[4] = {frame[0][j], frame[1][j], frame[2][j], frame[3][j]};
  quat_multiply(q, p, qp);
  quat_rotate_back(qp, L, m);
}

// Force (world) and torque (in the frame of the attitude q) on body j, with ω = w in that frame:
// drag's torque is the same law of w, since R(q) keeps lengths (|ω| = |w|); the world torque
// turns back by R̂ᵀ, thrusters push with R̂ fb and add their torque tb0 (both sums already in that
// frame), R̂ = R(q)/|q|² the rotation of q/|q|, built only with kTurn (thrusters or a world torque).
// Body frame for rk4_body (body_forces), principal frame for splitting (principal_kick).
template <typename T, bool kQuad, bool kTurn>
RBJAX_INLINE void frame_forces(const Consts<T>& k, int j, const T q[4], const T v[3], const T w[3], const T fb[3],
                               const T tb0[3], T F[3], T tb[3]) {
  T sv = T(0), sw = -k.br[j];
  if (kQuad) {
    sv = -k.c[j] * norm3(v);
    sw = sw + -k.cr[j] * norm3(w);
  }
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) {
    F[c] = ((k.F[c][j] + k.m[j] * k.g[c][j]) + -k.b[j] * v[c]) + sv * v[c];
    tb[c] = sw * w[c];
  }
  if (kTurn) {
    T R[9], Fw[3], tw[3];
    rotation(q, R, T(2) / (((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3]));
    const T tau[3] = {k.tau[0][j], k.tau[1][j], k.tau[2][j]};
    matvec3(R, fb, Fw);
    matvec3_t(R, tau, tw);
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) {
      F[c] = F[c] + Fw[c];
      tb[c] = (tb[c] + tw[c]) + tb0[c];
    }
  }
}

// kick(h) of body j (rbjax._methods._common.kick: v += F/m h, L += τ h) in the principal frame of
// splitting_steps: m += R(qp)ᵀ τ h, with the forces at (qp, m, v) and ω_p = e∘m (frame_forces,
// the thrusters' sums turned into the principal frame, fbp and tbp, once per call).
template <typename T, bool kQuad, bool kTurn>
RBJAX_INLINE void principal_kick(const Consts<T>& k, int j, const T qp[4], const T e[3], const T fbp[3],
                                 const T tbp[3], T h, T v[3], T m[3]) {
  const T w[3] = {e[0] * m[0], e[1] * m[1], e[2] * m[2]};
  T F[3], tau[3];
  frame_forces<T, kQuad, kTurn>(k, j, qp, v, w, fbp, tbp, F, tau);
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) {
    v[c] = v[c] + F[c] * k.inv_m[j] * h;
    m[c] = m[c] + tau[c] * h;
  }
}

// `steps` steps of "splitting" (rbjax/_methods/splitting.py) with forces: kick(h/2) drift(h)
// kick(h/2), the forces at the step's start and after the drift, regrouped over the steps of a
// call in the principal frame: the attitude qp = q ⊗ p and the momentum m = R(qp)ᵀ L are carried
// from step to step instead of q and the world L (equal in exact arithmetic, so the two agree to
// round-off). A kick adds the torque turned into that frame; H_L's world turn about L is the
// body turn about m (turn ⊗ qp = qp ⊗ (c2, tl m) for m = R(qp)ᵀ L), which leaves m. q ⊗ p, L's
// turns into the frame and back and the normalisation happen once per call, not per step.
// frame: the principal frame's quaternion p (rows 0-3) and inverse moments e (rows 4-6) per body.
// kTurn: a world torque or thrusters (turned by R(qp) at each kick).
template <typename T, bool kQuad, bool kTurn>
void splitting_steps(Block<T>& B, const Consts<T>& k, const T (*frame)[kBlock], int n, T dt, int64_t steps) {
  const T half = dt / T(2);
  T qps[4][kBlock], ms[3][kBlock], fbps[3][kBlock], tbps[3][kBlock];
#pragma GCC ivdep
  for (int j = 0; j < n; ++j) {
    T qp[4], m[3];
    to_principal(B, frame, j, qp, m);
#pragma GCC unroll 16
    for (int c = 0; c < 4; ++c) qps[c][j] = qp[c];
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) ms[c][j] = m[c];
    if (kTurn) {  // the thrusters' body-frame sums in the principal frame: R(p)ᵀ f_b, R(p)ᵀ τ_b
      const T p[4] = {frame[0][j], frame[1][j], frame[2][j], frame[3][j]};
      const T fb[3] = {k.fb[0][j], k.fb[1][j], k.fb[2][j]}, tb[3] = {k.tb[0][j], k.tb[1][j], k.tb[2][j]};
      T fbp[3], tbp[3];
      quat_rotate_back(p, fb, fbp);
      quat_rotate_back(p, tb, tbp);
#pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) {
        fbps[c][j] = fbp[c];
        tbps[c][j] = tbp[c];
      }
    }
  }
  for (int64_t st = 0; st < steps; ++st) {
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      const T e[3] = {frame[4][j], frame[5][j], frame[6][j]};
      const T k0 = e[0] - e[1], k2 = e[2] - e[1];
      T qp[4] = {qps[0][j], qps[1][j], qps[2][j], qps[3][j]}, m[3] = {ms[0][j], ms[1][j], ms[2][j]};
      T v[3] = {B.v[0][j], B.v[1][j], B.v[2][j]}, fbp[3] = {}, tbp[3] = {};
      if (kTurn) {
#pragma GCC unroll 16
        for (int c = 0; c < 3; ++c) {
          fbp[c] = fbps[c][j];
          tbp[c] = tbps[c][j];
        }
      }
      principal_kick<T, kQuad, kTurn>(k, j, qp, e, fbp, tbp, half, v, m);  // with the forces at the start
#pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) B.x[c][j] = B.x[c][j] + v[c] * dt;
      rotate_about<T, 2>(qp, m, k2, half);
      rotate_about<T, 0>(qp, m, k0, dt);
      rotate_about<T, 2>(qp, m, k2, half);
      T c2, tl;  // H_L: the turn by |m| h e₂ about m
      cayley(dt * e[1] / T(4), m[0] * m[0] + m[1] * m[1] + m[2] * m[2], c2, tl);
      const T turn[4] = {c2, tl * m[0], tl * m[1], tl * m[2]};
      T turned[4];
      quat_multiply(qp, turn, turned);
      principal_kick<T, kQuad, kTurn>(k, j, turned, e, fbp, tbp, half, v, m);  // with the forces after the drift
#pragma GCC unroll 16
      for (int c = 0; c < 4; ++c) qps[c][j] = turned[c];
#pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) {
        ms[c][j] = m[c];
        B.v[c][j] = v[c];
      }
    }
  }
#pragma GCC ivdep
  for (int j = 0; j < n; ++j) {
    T qp[4] = {qps[0][j], qps[1][j], qps[2][j], qps[3][j]};
    const T m[3] = {ms[0][j], ms[1][j], ms[2][j]};
    const T conj[4] = {frame[0][j], -frame[1][j], -frame[2][j], -frame[3][j]};
    T q[4], L[3];
    normalize(qp);
    quat_rotate(qp, m, L);
    quat_multiply(qp, conj, q);
    normalize(q);
    store_q(B, j, q);
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) B.L[c][j] = L[c];
  }
}

// `steps` torque-free steps of "splitting": the map of splitting_steps without forces, regrouped
// over the steps of a call. Without a torque L stays, and three things each step recomputes are
// carried from step to step instead (equal in exact arithmetic, so the two agree to round-off):
// - the principal-frame attitude qp = q ⊗ p: q ⊗ p and ⊗ p* once per call, not per step;
// - the body-frame momentum m = R(qp)ᵀ L: the principal turns move it as they move qp, and
//   H_L's turn about L itself leaves it;
// - the pair of the step's last half turn about axis 3, which the next step's first half turn
//   repeats (the same m₃: turns about axis 3 keep it, and so does H_L).
// |qp| enters nothing (the turns are unit and m is carried), so q is normalised once, at the
// end of the call, as the step normalises it. It does about half the arithmetic of a step
// (benchmarks/results/native_splitting_carried_2026-12-04.md).
template <typename T>
void splitting_free_steps(Block<T>& B, const T (*frame)[kBlock], int n, T dt, int64_t steps) {
  const T half = dt / T(2);
  T qps[4][kBlock], ms[3][kBlock], turns[4][kBlock], pairs[4][kBlock];
#pragma GCC ivdep
  for (int j = 0; j < n; ++j) {
    const T L[3] = {B.L[0][j], B.L[1][j], B.L[2][j]}, e[3] = {frame[4][j], frame[5][j], frame[6][j]};
    T qp[4], m[3], turn[4], pair[4];
    to_principal(B, frame, j, qp, m);
    turn_about_L(L, e, dt, turn);
    turn_pair<T, 2>(m, e[2] - e[1], half, pair);
#pragma GCC unroll 16
    for (int c = 0; c < 4; ++c) {
      qps[c][j] = qp[c];
      turns[c][j] = turn[c];
      pairs[c][j] = pair[c];
    }
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) ms[c][j] = m[c];
  }
  for (int64_t st = 0; st < steps; ++st) {
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      const T k0 = frame[4][j] - frame[5][j], k2 = frame[6][j] - frame[5][j];
      T qp[4] = {qps[0][j], qps[1][j], qps[2][j], qps[3][j]}, m[3] = {ms[0][j], ms[1][j], ms[2][j]};
      const T turn[4] = {turns[0][j], turns[1][j], turns[2][j], turns[3][j]};
      T pair[4];
      apply_turn<T, 2>(qp, m, pairs[0][j], pairs[1][j], pairs[2][j], pairs[3][j]);
      rotate_about<T, 0>(qp, m, k0, dt);
      turn_pair<T, 2>(m, k2, half, pair);
      apply_turn<T, 2>(qp, m, pair[0], pair[1], pair[2], pair[3]);
      T turned[4];
      quat_multiply(turn, qp, turned);
#pragma GCC unroll 16
      for (int c = 0; c < 4; ++c) {
        qps[c][j] = turned[c];
        pairs[c][j] = pair[c];
      }
#pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) {
        ms[c][j] = m[c];
        B.x[c][j] = B.x[c][j] + B.v[c][j] * dt;
      }
    }
  }
#pragma GCC ivdep
  for (int j = 0; j < n; ++j) {
    const T qp[4] = {qps[0][j], qps[1][j], qps[2][j], qps[3][j]};
    const T conj[4] = {frame[0][j], -frame[1][j], -frame[2][j], -frame[3][j]};
    T q[4];
    quat_multiply(qp, conj, q);
    normalize(q);
    store_q(B, j, q);
  }
}

// Force (world) and torque (body frame) on body j at an RK4 stage of rk4_body: the world state
// the JAX step gives the forces is (q̂, L = R̂ π) with q̂ = q/|q| and R̂ = R(q)/|q|² its rotation
// (rbjax/_methods/rk4_body.py: _world_for_forces), and the torque is turned back by R̂ᵀ. There
// ω = R̂ ω_b, so |ω| = |ω_b| and a drag torque turned back is -(b_r + c_r |ω_b|) ω_b; a thruster
// pushes with R̂ f_b and its torque turned back is R̂ᵀ cof(R̂) τ_b = τ_b (cof(R̂) = R̂ for a
// rotation); the world torques (constant, time series) turn back as R̂ᵀ τ. The same map as
// forces() followed by R̂ᵀ, regrouped (frame_forces in the body frame).
template <typename T, bool kQuad, bool kTurn>
RBJAX_INLINE void body_forces(const Consts<T>& k, int j, const T q[4], const T v[3], const T w[3], T F[3], T tb[3]) {
  T fb[3] = {}, tb0[3] = {};
  if (kTurn) {
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) {
      fb[c] = k.fb[c][j];
      tb0[c] = k.tb[c][j];
    }
  }
  frame_forces<T, kQuad, kTurn>(k, j, q, v, w, fb, tb0, F, tb);
}

// The body-frame right-hand side of rbjax/_methods/rk4_body.py (_body_derivative) for
// y = (x, v, q, π): ẋ = v, v̇ = F/m, q̇ = ½ q ⊗ (0, ω), π̇ = π × ω + R̂ᵀ τ with ω = I_L⁻¹ π, the
// forces as body_forces gives them.
template <typename T, bool kForces, bool kQuad, bool kTurn>
RBJAX_INLINE void body_derivative(const Consts<T>& k, int j, const T y[13], T d[13]) {
  T inv[9], w[3], p[4];
  load_inv(k, j, inv);
  const T* q = y + 6;
  const T* pi = y + 10;
  matvec3(inv, pi, w);
  d[10] = pi[1] * w[2] - pi[2] * w[1];
  d[11] = pi[2] * w[0] - pi[0] * w[2];
  d[12] = pi[0] * w[1] - pi[1] * w[0];
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) {
    d[c] = y[3 + c];
    d[3 + c] = T(0);
  }
  if (kForces) {
    T F[3], tb[3];
    body_forces<T, kQuad, kTurn>(k, j, q, y + 3, w, F, tb);
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) {
      d[3 + c] = F[c] * k.inv_m[j];
      d[10 + c] = d[10 + c] + tb[c];
    }
  }
  const T pw[4] = {T(0), w[0], w[1], w[2]};
  quat_multiply(q, pw, p);
#pragma GCC unroll 16
  for (int c = 0; c < 4; ++c) d[6 + c] = T(0.5) * p[c];
}

// `steps` RK4 steps of the body-frame equations (rbjax/_methods/rk4_body.py): π = Rᵀ L, the
// classical tableau as rk4_steps sums it, q normalised, then L = R(q) π. kTurn: see body_forces.
template <typename T, bool kForces, bool kQuad, bool kTurn>
void rk4_body_steps(Block<T>& B, const Consts<T>& k, int n, T dt, int64_t steps) {
  const T half = T(0.5), sixth = T(1.0 / 6.0), third = T(1.0 / 3.0);
  for (int64_t s = 0; s < steps; ++s) {
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      T y[13], k1[13], k2[13], k3[13], k4[13], st[13], inv[9];
      load_body(B, k, j, y + 6, st, y + 3, inv);
      quat_rotate_back(y + 6, st, y + 10);
#pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) y[c] = B.x[c][j];
      body_derivative<T, kForces, kQuad, kTurn>(k, j, y, k1);
#pragma GCC unroll 16
      for (int c = 0; c < 13; ++c) st[c] = y[c] + dt * (half * k1[c]);
      body_derivative<T, kForces, kQuad, kTurn>(k, j, st, k2);
#pragma GCC unroll 16
      for (int c = 0; c < 13; ++c) st[c] = y[c] + dt * (half * k2[c]);
      body_derivative<T, kForces, kQuad, kTurn>(k, j, st, k3);
#pragma GCC unroll 16
      for (int c = 0; c < 13; ++c) st[c] = y[c] + dt * k3[c];
      body_derivative<T, kForces, kQuad, kTurn>(k, j, st, k4);
#pragma GCC unroll 16
      for (int c = 0; c < 13; ++c) {
        y[c] = y[c] + dt * (((sixth * k1[c] + third * k2[c]) + third * k3[c]) + sixth * k4[c]);
      }
      normalize(y + 6);
      T L[3];
      quat_rotate(y + 6, y + 10, L);
#pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) B.x[c][j] = y[c];
      store_body(B, j, y + 6, L, y + 3);
    }
  }
}

// sin x and cos x for 0 <= x <= SinCos<T>::kLimit, straight-line so that the loop calling it
// vectorises (without -ffast-math the compiler has no vector sin or cos, and a libm call keeps
// its whole loop scalar). Cephes' sin.c/sinf.c: x reduced by the multiple k of π/2 nearest to it
// (π/2 split in three parts, Cody–Waite, exact to the last bit up to kLimit), then their minimax
// polynomials on [-π/4, π/4], within 1 ulp of libm there (checked over [0, kLimit]); k mod 4
// picks which polynomial and sign each of sin and cos takes. k comes from adding 1.5·2^(digits-1),
// which rounds x 2/π to an integer held in the low bits of the sum: no float-to-int conversion,
// whose undefined range would need a branch. Larger x (and NaN) are left to libm by the caller.
template <typename T>
struct SinCos;
template <>
struct SinCos<double> {
  using Bits = uint64_t;
  static constexpr double kLimit = 1.0e6;
  static constexpr double kTwoOverPi = 6.36619772367581343076e-1, kShifter = 6755399441055744.0;  // 1.5·2⁵²
  // π/2 in three parts: 2 × Cephes' DP1..DP3 for π/4 (doubling is exact)
  static constexpr double kDp1 = 2 * 7.85398125648498535156e-1, kDp2 = 2 * 3.77489470793079817668e-8,
                          kDp3 = 2 * 2.69515142907905952645e-15;
  static RBJAX_INLINE double sin_poly(double z, double zz) {
    return z + z * zz * (((((1.58962301576546568060e-10 * zz + -2.50507477628578072866e-8) * zz +
                           2.75573136213857245213e-6) * zz + -1.98412698295895385996e-4) * zz +
                         8.33333333332211858878e-3) * zz + -1.66666666666666307295e-1);
  }
  static RBJAX_INLINE double cos_poly(double zz) {
    return (1.0 - 0.5 * zz) + zz * zz * (((((-1.13585365213876817300e-11 * zz + 2.08757008419747316778e-9) * zz +
                                           -2.75573141792967388112e-7) * zz + 2.48015872888517045348e-5) * zz +
                                         -1.38888888888730564116e-3) * zz + 4.16666666666665929218e-2);
  }
};
template <>
struct SinCos<float> {
  using Bits = uint32_t;
  static constexpr float kLimit = 8192.0f;
  static constexpr float kTwoOverPi = 6.36619772367581343076e-1f, kShifter = 12582912.0f;  // 1.5·2²³
  static constexpr float kDp1 = 2 * 0.78515625f, kDp2 = 2 * 2.4187564849853515625e-4f,
                         kDp3 = 2 * 3.77489497744594108e-8f;
  static RBJAX_INLINE float sin_poly(float z, float zz) {
    return ((-1.9515295891e-4f * zz + 8.3321608736e-3f) * zz + -1.6666654611e-1f) * zz * z + z;
  }
  static RBJAX_INLINE float cos_poly(float zz) {
    return ((2.443315711809948e-5f * zz + -1.388731625493765e-3f) * zz + 4.166664568298827e-2f) * zz * zz -
           0.5f * zz + 1.0f;
  }
};

template <typename T>
RBJAX_INLINE void sincos_reduced(T x, T& s, T& c) {
  using K = SinCos<T>;
  const T shifted = x * K::kTwoOverPi + K::kShifter;
  const T k = shifted - K::kShifter;  // the nearest integer to x 2/π
  typename K::Bits bits;
  std::memcpy(&bits, &shifted, sizeof bits);
  const T z = ((x - k * K::kDp1) - k * K::kDp2) - k * K::kDp3;  // x - k π/2, in [-π/4, π/4]
  const T zz = z * z;
  const T sp = K::sin_poly(z, zz), cp = K::cos_poly(zz);
  const bool swap = (bits & 1) != 0, sin_neg = (bits & 2) != 0, cos_neg = ((bits + 1) & 2) != 0;
  const T sin_abs = swap ? cp : sp, cos_abs = swap ? sp : cp;
  s = sin_neg ? -sin_abs : sin_abs;
  c = cos_neg ? -cos_abs : cos_abs;
}

// exp(r) = [cos(θ/2), sin(θ/2)/θ r] as rbjax._math.quat_exp, in two parts: exp_scalars gives
// its first component and the factor hs of r, with the Taylor series below θ² < √eps (both
// branches computed and one selected, so the loop stays straight-line; the series divides by
// its constants' reciprocals, which moves terms below √eps/48 by an ulp, far under the result's).
template <typename T>
RBJAX_INLINE void exp_scalars(const T r[3], T& th, T& e0, T& hs) {
  const T th2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
  const bool small = th2 < std::sqrt(std::numeric_limits<T>::epsilon());
  th = std::sqrt(small ? T(1) : th2);
  T sin_half, cos_half;
  sincos_reduced(th * T(0.5), sin_half, cos_half);
  const T half_sinc_series = (T(0.5) - th2 * T(1.0 / 48)) + th2 * th2 * T(1.0 / 3840);
  const T cos_half_series = (T(1) - th2 * T(0.125)) + th2 * th2 * T(1.0 / 384);
  hs = small ? half_sinc_series : sin_half / th;
  e0 = small ? cos_half_series : cos_half;
}

// `steps` semi-implicit Euler steps of a block (rbjax/_methods/semi_implicit_euler.py:
// semi_implicit_state): kick(dt) with the forces at the step's start, then q ← exp(ω dt) ⊗ q
// with ω from the new L and the old q, normalised, and x += v dt with the new v. Three loops
// per step, vectorised: the kick and r = ω dt, exp's scalars, the turn; between the last two, a
// scalar pass hands angles beyond sincos_reduced's range (which no accurate step reaches) to libm.
template <typename T, bool kForces, bool kQuad, bool kThrust>
void semi_implicit_steps(Block<T>& B, const Consts<T>& k, int n, T dt, int64_t steps) {
  T r[3][kBlock], th[kBlock], e0[kBlock], hs[kBlock];
  for (int64_t s = 0; s < steps; ++s) {
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      T q[4], L[3], v[3], inv[9], w[3];
      load_body(B, k, j, q, L, v, inv);
      if (kForces) kick<T, kQuad, kThrust>(k, j, q, inv, dt, v, L);
      omega(q, L, inv, w);
#pragma GCC unroll 16
      for (int c = 0; c < 3; ++c) {
        r[c][j] = w[c] * dt;
        B.x[c][j] = B.x[c][j] + v[c] * dt;
      }
      store_body(B, j, q, L, v);
    }
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      const T rj[3] = {r[0][j], r[1][j], r[2][j]};
      exp_scalars(rj, th[j], e0[j], hs[j]);
    }
    for (int j = 0; j < n; ++j) {
      if (!(th[j] * T(0.5) <= SinCos<T>::kLimit)) {  // θ ≥ 1 here: not the series
        hs[j] = std::sin(th[j] * T(0.5)) / th[j];
        e0[j] = std::cos(th[j] * T(0.5));
      }
    }
#pragma GCC ivdep
    for (int j = 0; j < n; ++j) {
      T q[4], q1[4];
      const T e[4] = {e0[j], hs[j] * r[0][j], hs[j] * r[1][j], hs[j] * r[2][j]};
#pragma GCC unroll 16
      for (int c = 0; c < 4; ++c) q[c] = B.q[c][j];
      quat_multiply(e, q, q1);
      normalize(q1);
      store_q(B, j, q1);
    }
  }
}

// One Jacobi rotation in the plane (p, q) zeroing a_pq (rbjax/_eigh3.py: _rotate, the same
// arithmetic in the same order): a holds the upper triangle, v the rows of P.
template <typename T, int p, int q>
RBJAX_INLINE void jacobi_rotate(T a[3][3], T v[3][3]) {
  const T apq = a[p][q], app = a[p][p], aqq = a[q][q];
  const bool nonzero = std::abs(apq) > std::numeric_limits<T>::epsilon() * std::sqrt(std::abs(app * aqq));
  const T delta = aqq - app;
  const T root = std::sqrt(delta * delta + T(4) * apq * apq);
  T t = T(2) * (delta < T(0) ? -apq : apq) / (nonzero ? std::abs(delta) + root : T(1));
  t = nonzero ? t : T(0);
  const T c = T(1) / std::sqrt(t * t + T(1));
  const T s = t * c;
  a[p][p] = app - t * apq;
  a[q][q] = aqq + t * apq;
  a[p][q] = T(0);
  constexpr int r = 3 - p - q;
  constexpr int rp0 = r < p ? r : p, rp1 = r < p ? p : r, rq0 = r < q ? r : q, rq1 = r < q ? q : r;
  const T arp = a[rp0][rp1], arq = a[rq0][rq1];
  a[rp0][rp1] = c * arp - s * arq;
  a[rq0][rq1] = s * arp + c * arq;
#pragma GCC unroll 16
  for (int i = 0; i < 3; ++i) {
    const T vp = v[i][p], vq = v[i][q];
    v[i][p] = c * vp - s * vq;
    v[i][q] = s * vp + c * vq;
  }
}

// The principal frame of a symmetric inertia (upper triangle I00 I01 I02 I11 I12 I22), as
// rbjax._eigh3.principal_frame_values gives it: eigh3's five Jacobi sweeps, the moments sorted
// ascending with their axes, det P = +1, one Newton–Schulz step, then matrix_to_quat_unchecked;
// out: the axes' quaternion p and the inverse moments e = 1/d.
template <typename T>
RBJAX_INLINE void principal_frame(const T I6[6], T p[4], T e[3]) {
  T a[3][3] = {{I6[0], I6[1], I6[2]}, {T(0), I6[3], I6[4]}, {T(0), T(0), I6[5]}};
  T v[3][3] = {{T(1), T(0), T(0)}, {T(0), T(1), T(0)}, {T(0), T(0), T(1)}};
#pragma GCC unroll 16
  for (int sweep = 0; sweep < 5; ++sweep) {  // _SWEEPS
    jacobi_rotate<T, 0, 1>(a, v);
    jacobi_rotate<T, 0, 2>(a, v);
    jacobi_rotate<T, 1, 2>(a, v);
  }
  T d[3] = {a[0][0], a[1][1], a[2][2]}, col[3][3];
#pragma GCC unroll 16
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 16
    for (int j = 0; j < 3; ++j) col[j][i] = v[i][j];
  // ascending, by the three-comparison network; each swap carries its column along
  constexpr int net[3][2] = {{0, 1}, {1, 2}, {0, 1}};
#pragma GCC unroll 16
  for (int k = 0; k < 3; ++k) {
    const int i = net[k][0], j = net[k][1];
    const bool swap = d[j] < d[i];
    const T di = d[i], dj = d[j];
    d[i] = swap ? dj : di;
    d[j] = swap ? di : dj;
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) {
      const T x = col[i][c], y = col[j][c];
      col[i][c] = swap ? y : x;
      col[j][c] = swap ? x : y;
    }
  }
  const T* x = col[0];
  const T* y = col[1];
  const T* z = col[2];
  const T det = x[0] * (y[1] * z[2] - y[2] * z[1]) + x[1] * (y[2] * z[0] - y[0] * z[2]) + x[2] * (y[0] * z[1] - y[1] * z[0]);
  const T sign = det < T(0) ? T(-1) : T(1);
  T P[3][3], RtR[3][3], M[3][3], R[3][3];
#pragma GCC unroll 16
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 16
    for (int j = 0; j < 3; ++j) P[i][j] = sign * col[j][i];
  // orthonormalize_unchecked(P, 1): P (3·1 - PᵀP) / 2, products summed as matmul3 sums them
#pragma GCC unroll 16
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 16
    for (int j = 0; j < 3; ++j) RtR[i][j] = (P[0][i] * P[0][j] + P[1][i] * P[1][j]) + P[2][i] * P[2][j];
#pragma GCC unroll 16
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 16
    for (int j = 0; j < 3; ++j) M[i][j] = (i == j ? T(3) : T(0)) - RtR[i][j];
#pragma GCC unroll 16
  for (int i = 0; i < 3; ++i)
#pragma GCC unroll 16
    for (int j = 0; j < 3; ++j) R[i][j] = T(0.5) * ((P[i][0] * M[0][j] + P[i][1] * M[1][j]) + P[i][2] * M[2][j]);
  // matrix_to_quat_unchecked (Shepperd): the candidate of the largest 4 q_k², w ≥ 0, normalised
  const T tr = (R[0][0] + R[1][1]) + R[2][2];
  const T four[4] = {T(1) + tr, ((T(1) + R[0][0]) - R[1][1]) - R[2][2], ((T(1) - R[0][0]) + R[1][1]) - R[2][2],
                     ((T(1) - R[0][0]) - R[1][1]) + R[2][2]};
  T sq[4];
#pragma GCC unroll 16
  for (int k = 0; k < 4; ++k) sq[k] = T(2) * std::sqrt(std::max(four[k], std::numeric_limits<T>::epsilon()));
  const T d21 = R[2][1] - R[1][2], d02 = R[0][2] - R[2][0], d10 = R[1][0] - R[0][1];
  const T s01 = R[0][1] + R[1][0], s02 = R[0][2] + R[2][0], s12 = R[1][2] + R[2][1];
  const T cand[4][4] = {{sq[0] / T(4), d21 / sq[0], d02 / sq[0], d10 / sq[0]},
                        {d21 / sq[1], sq[1] / T(4), s01 / sq[1], s02 / sq[1]},
                        {d02 / sq[2], s01 / sq[2], sq[2] / T(4), s12 / sq[2]},
                        {d10 / sq[3], s02 / sq[3], s12 / sq[3], sq[3] / T(4)}};
  // argmax (the first of equal largest), as selects
  T qv[4] = {cand[0][0], cand[0][1], cand[0][2], cand[0][3]}, top = four[0];
#pragma GCC unroll 16
  for (int k = 1; k < 4; ++k) {
    const bool better = four[k] > top;
    top = better ? four[k] : top;
#pragma GCC unroll 16
    for (int c = 0; c < 4; ++c) qv[c] = better ? cand[k][c] : qv[c];
  }
  const T flip = qv[0] < T(0) ? T(-1) : T(1);
#pragma GCC unroll 16
  for (int c = 0; c < 4; ++c) qv[c] = flip * qv[c];
  const T inv = T(1) / std::sqrt(((qv[0] * qv[0] + qv[1] * qv[1]) + qv[2] * qv[2]) + qv[3] * qv[3]);
#pragma GCC unroll 16
  for (int c = 0; c < 4; ++c) p[c] = qv[c] * inv;
#pragma GCC unroll 16
  for (int c = 0; c < 3; ++c) e[c] = T(1) / d[c];
}

// "splitting"'s principal frames of a block's bodies, from their inertias' upper triangles
// (rows 0-5): the axes' quaternion p (rows 0-3) and inverse moments e (rows 4-6), once per call.
template <typename T>
void block_frames(const T (*inertia)[kBlock], int n, T (*frame)[kBlock]) {
#pragma GCC ivdep
  for (int j = 0; j < n; ++j) {
    const T I6[6] = {inertia[0][j], inertia[1][j], inertia[2][j], inertia[3][j], inertia[4][j], inertia[5][j]};
    T p[4], e[3];
    principal_frame(I6, p, e);
#pragma GCC unroll 16
    for (int c = 0; c < 4; ++c) frame[c][j] = p[c];
#pragma GCC unroll 16
    for (int c = 0; c < 3; ++c) frame[4 + c][j] = e[c];
  }
}

// All steps of one block with the method's and the forces' static choices made.
template <typename T, bool kForces, bool kQuad, bool kThrust>
void method_steps(Block<T>& B, const Consts<T>& k, const T (*frame)[kBlock], int n, T dt, int64_t steps,
                  int64_t method) {
  if (method == kSplitting) {
    if (!kForces) return splitting_free_steps<T>(B, frame, n, dt, steps);
    return splitting_steps<T, kQuad, kThrust>(B, k, frame, n, dt, steps);  // kThrust: the turn flag
  }
  if (method == kSemiImplicitEuler) return semi_implicit_steps<T, kForces, kQuad, kThrust>(B, k, n, dt, steps);
  if (method == kRk4Body) return rk4_body_steps<T, kForces, kQuad, kThrust>(B, k, n, dt, steps);
  if (method == kEuler) return euler_steps<T, kForces, kQuad, kThrust>(B, k, n, dt, steps);
  return rk4_steps<T, kForces, kQuad, kThrust>(B, k, n, dt, steps);
}

template <typename T>
void block_steps(Block<T>& B, const Consts<T>& k, const T (*frame)[kBlock], int n, T dt, int64_t steps,
                 int64_t method, bool forces, bool quad, bool turn) {
  // turn: the forces need R(q) (thrusters; for rk4_body a world torque too): the kThrust/kTurn flag
  if (!forces) return method_steps<T, false, false, false>(B, k, frame, n, dt, steps, method);
  if (turn) {
    if (!quad) return method_steps<T, true, false, true>(B, k, frame, n, dt, steps, method);
    return method_steps<T, true, true, true>(B, k, frame, n, dt, steps, method);
  }
  if (!quad) return method_steps<T, true, false, false>(B, k, frame, n, dt, steps, method);
  return method_steps<T, true, true, false>(B, k, frame, n, dt, steps, method);
}

// instantiated here, inside the includer's instruction-set region, for both float types
template void block_steps<float>(Block<float>&, const Consts<float>&, const float (*)[kBlock], int, float, int64_t,
                                 int64_t, bool, bool, bool);
template void block_steps<double>(Block<double>&, const Consts<double>&, const double (*)[kBlock], int, double,
                                  int64_t, int64_t, bool, bool, bool);
template void block_frames<float>(const float (*)[kBlock], int, float (*)[kBlock]);
template void block_frames<double>(const double (*)[kBlock], int, double (*)[kBlock]);
