"""Generate the example notebooks from the cell sources below: ``python notebooks/_make.py --execute``.

Edit the cells here, not in the ``.ipynb`` files. With ``--execute`` each notebook is run (in a
kernel of this interpreter, from notebooks/) and written with its outputs, small PNG plots and the
first notebook's GIF: that is what is committed, so the plots show on GitHub and in the
documentation site without running anything. Without ``--execute`` the notebooks are written
without outputs. tests/test_docs.py checks that the committed code cells are the ones made here.
"""

from __future__ import annotations

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent

SIZES_NOTE = (
    "*Sizes are reduced so that this notebook runs in well under a minute on a 2-core CPU "
    "(it is executed by `tests/test_notebooks.py` in CI). {how}*"
)


def md(text: str):
    return new_markdown_cell(text.strip("\n"))


def code(text: str):
    return new_code_cell(text.strip("\n"))


# --------------------------------------------------------------------------------------------------
NB1 = [
    md("""
# 1. The tumbling T-handle (Dzhanibekov effect)

A T-handle spun about its **intermediate** principal axis does not keep spinning: every few
seconds it flips over by half a turn and flips back, the effect Vladimir Dzhanibekov filmed on
the Salyut 7 station. Here the body has principal moments `I = diag(1, 2, 2.8)` kg m² and starts
at `ω₀ = (0.001, 2, 0.001)` rad/s, a hair off the unstable middle axis.

We compare three answers:

* the lecture notes' explicit **`"euler"`** step (first order),
* **`"splitting"`** (second order, a symplectic free-rotor splitting that conserves |L| exactly
  and energy to within a bounded oscillation),
* the **exact** closed-form solution, `rb.torque_free` (Jacobi elliptic functions).

Accuracy is the point here, so everything runs in float64.
"""),
    md(SIZES_NOTE.format(how="For a longer movie raise `T` (e.g. 200 s); cost grows linearly.")),
    code("""
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import rbjax as rb

jax.config.update("jax_enable_x64", True)  # float64: we are looking at small errors (set before any array)

%matplotlib inline
"""),
    code("""
body = rb.Body(1.0, jnp.diag(jnp.array([1.0, 2.0, 2.8])))                  # kg, kg m^2 (principal frame)
s0 = rb.State.create(body, angular_velocity=jnp.array([1e-3, 2.0, 1e-3]))  # identity attitude: world = body

T, dt = 40.0, 0.01                     # s
steps = int(round(T / dt))
t = np.arange(steps + 1) * dt

trajs = {m: rb.simulate(s0, None, dt, steps, m) for m in ["euler", "splitting"]}
trajs["exact"] = rb.torque_free(s0, t)  # closed form at every sample time
"""),
    md("""
## Body-frame angular velocity

The middle component `ω_y` changes sign at every flip. The splitting trajectory lies on top of
the exact one; explicit Euler gains energy every step, drifts off the separatrix and flips
faster and faster.
"""),
    code("""
colors = dict(euler="tab:red", splitting="tab:blue", exact="k")
fig, axes = plt.subplots(3, 1, figsize=(9, 6), sharex=True)
for m, tr in trajs.items():
    w_body = np.asarray(rb.body_angular_velocity(tr))  # (T+1, 3), rad/s, body frame
    for i, ax in enumerate(axes):
        ax.plot(t, w_body[:, i], color=colors[m], lw=1.0 if m != "exact" else 2.5,
                alpha=1.0 if m != "exact" else 0.35, label=m)
for i, ax in enumerate(axes):
    ax.set_ylabel(f"$\\\\omega_{'xyz'[i]}$ (rad/s)")
axes[0].legend(ncol=3, loc="upper right")
axes[-1].set_xlabel("t (s)")
fig.suptitle("T-handle: body-frame angular velocity, dt = 0.01 s")
fig.tight_layout()
"""),
    md("""
## Energy and |L|

rbjax stores the **world-frame angular momentum** `L` as the state variable. Without torque every
method leaves it untouched, so |L| is conserved to round-off by all of them — the integration
error goes into the attitude and hence the kinetic energy `E = ½ Lᵀ I_w⁻¹ L`. For contrast we also
integrate the textbook form, forward Euler on Euler's equations for the body-frame `ω`
(`I ω̇ = (I ω) × ω`), in a few lines of numpy: it gains both energy and |L|.
"""),
    code("""
I_body = np.diag([1.0, 2.0, 2.8])
w = np.array([1e-3, 2.0, 1e-3])
w_textbook = [w]
for _ in range(steps):  # forward Euler on Euler's equations, body frame
    w = w + dt * np.linalg.solve(I_body, np.cross(I_body @ w, w))
    w_textbook.append(w)
w_textbook = np.array(w_textbook)
E_tb = 0.5 * np.einsum("ti,ij,tj->t", w_textbook, I_body, w_textbook)
L_tb = np.linalg.norm(w_textbook @ I_body, axis=-1)

E = {m: np.asarray(rb.kinetic_energy(tr)) for m, tr in trajs.items()}
L = {m: np.linalg.norm(np.asarray(rb.angular_momentum(tr)), axis=-1) for m, tr in trajs.items()}
E["ω-form euler (numpy)"], L["ω-form euler (numpy)"] = E_tb, L_tb
colors["ω-form euler (numpy)"] = "tab:orange"

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.8))
for m in E:
    lw = 0.5 if m == "exact" else 1.5  # the exact solution's curve is round-off noise
    a1.semilogy(t[1:], np.abs(E[m][1:] / E[m][0] - 1) + 1e-17, color=colors[m], lw=lw, label=m)
    a2.semilogy(t[1:], np.abs(L[m][1:] / L[m][0] - 1) + 1e-17, color=colors[m], lw=lw, label=m)
a1.set(title="relative energy error |E/E₀ − 1|", xlabel="t (s)")
a2.set(title="relative |L| error (1e-17: exactly conserved; rbjax methods overlap)", xlabel="t (s)")
a1.legend(fontsize=8)
fig.tight_layout()
for m in E:
    print(f"{m:>22}: max |ΔE/E| = {np.abs(E[m] / E[m][0] - 1).max():.2e},"
          f"  max |Δ|L|/|L|| = {np.abs(L[m] / L[m][0] - 1).max():.2e}")
"""),
    md("""
## Flip times

A flip is a sign change of `ω_y`. Splitting's flip times agree with the exact ones to within a
step; explicit Euler's do not.
"""),
    code("""
def flip_times(tr):
    wy = np.asarray(rb.body_angular_velocity(tr))[:, 1]
    return t[1:][np.sign(wy[1:]) != np.sign(wy[:-1])]

flips = {m: flip_times(tr) for m, tr in trajs.items()}
for m, f in flips.items():
    print(f"{m:>10}: {np.round(f, 2)}")
"""),
    md("""
## Seeing it move

`rb.animate` writes a GIF (or an MP4, with ffmpeg) of a trajectory: each body drawn as the box with
its principal moments, the red arrow its world angular momentum `L` (fixed: no torque), the grey
trail the tip of its longest axis. Here the first 20 s of the splitting run: the body turns about
its middle axis, then flips over.
"""),
    code("""
import base64

from IPython.display import HTML

info = rb.animate(trajs["splitting"], "t_handle.gif", dt=dt, frames=slice(0, 2000), max_frames=80,
                  dpi=56, panel_size=3.2, trail=20, title="T-handle, splitting, dt = 0.01 s")
print(f"{info['frames']:.0f} frames, {info['bytes'] / 1e3:.0f} kB, rendered in {info['seconds']:.1f} s")
gif = base64.b64encode(open("t_handle.gif", "rb").read()).decode()  # inline, so the page needs no file
HTML(f'<img src="data:image/gif;base64,{gif}" alt="the T-handle flipping">')
"""),
    code("""
# Physical checks (these can fail):
# 1. splitting's energy error stays bounded (second order, dt = 0.01: ~1e-5 here; 1e-4 allows
#    for a different BLAS) and is far below explicit Euler's, which grows without bound;
dE = {m: np.abs(E[m] / E[m][0] - 1) for m in E}
assert dE["splitting"].max() < 1e-4, dE["splitting"].max()
assert dE["euler"][-1] > 100 * dE["splitting"].max()
# 2. |L| is conserved by every rbjax method (the state stores world L), to round-off;
assert all(np.abs(L[m] / L[m][0] - 1).max() < 1e-12 for m in trajs)
# 3. splitting flips when the exact solution flips: same number of flips, each within 5 steps.
assert len(flips["exact"]) >= 2
assert len(flips["splitting"]) == len(flips["exact"])
assert np.abs(flips["splitting"] - flips["exact"]).max() <= 5 * dt
# 4. the animation holds the frames asked for.
assert info["frames"] == 80 and info["bytes"] > 10_000
print("all checks passed")
"""),
]

# --------------------------------------------------------------------------------------------------
NB2 = [
    md("""
# 2. Ten thousand bodies in one call

`rb.simulate` integrates any batch of bodies in one compiled `lax.scan`: every array in the state
carries leading batch dimensions, and each integrator is written for one body and `vmap`ped.
Here: 10 000 random boxes (random sizes, masses, attitudes and spins) tumbling freely, in
**float32** (the precision most users will run batches in).
"""),
    md(
        SIZES_NOTE.format(
            how="The histogram uses 10 000 bodies for 5 s; for the throughput curve raise `Ns` to "
            "`[1e2, 1e3, 1e4, 1e5, 1e6]` and `steps` to 1000 on a bigger machine or a GPU."
        )
    ),
    code("""
import time

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import rbjax as rb

%matplotlib inline
print(jax.devices(), "default dtype:", jnp.zeros(1).dtype)
"""),
    code("""
def random_boxes(n, seed=0):
    rng = np.random.default_rng(seed)
    size = rng.uniform(0.05, 1.0, (n, 3)).astype(np.float32)    # m, full side lengths
    mass = rng.uniform(0.5, 5.0, n).astype(np.float32)          # kg
    q = rng.normal(size=(n, 4)).astype(np.float32)              # uniform random attitudes
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    w = rng.normal(0.0, 2.0, (n, 3)).astype(np.float32)         # rad/s, world frame
    body = rb.box(jnp.asarray(mass), jnp.asarray(size))
    return rb.State.create(body, orientation=jnp.asarray(q), angular_velocity=jnp.asarray(w))

N, dt, steps = 10_000, 0.01, 500
s0 = random_boxes(N)
print("batch shape:", s0.orientation.shape[:-1], s0.orientation.dtype)
"""),
    md("""
## Energy drift across the batch

For each body, the relative energy error `max_t |E(t)/E₀ − 1|` over 5 s, for the notes' explicit
`"euler"` and for `"splitting"`. Both leave |L| alone; the energy tells how far each body's
rotation has wandered.
"""),
    code("""
drift = {}
for m in ["euler", "splitting"]:
    tr = rb.simulate(s0, None, dt, steps, m, save_every=10)  # 51 frames x 10 000 bodies
    E = np.asarray(rb.kinetic_energy(tr), np.float64)       # (51, N), J
    drift[m] = np.abs(E / E[0] - 1).max(axis=0)

bins = np.logspace(-8, 2, 61)
fig, ax = plt.subplots(figsize=(8, 3.8))
for m, c in [("euler", "tab:red"), ("splitting", "tab:blue")]:
    ax.hist(np.maximum(drift[m], 1e-8), bins=bins, color=c, alpha=0.6, label=m)
    print(f"{m:>10}: median {np.median(drift[m]):.1e}, 99th percentile {np.percentile(drift[m], 99):.1e}")
ax.set_xscale("log")
ax.set(xlabel="max relative energy error over 5 s", ylabel="bodies",
       title=f"{N} random boxes, float32, dt = {dt} s")
ax.legend()
fig.tight_layout()
"""),
    md("""
Explicit Euler's error grows with `|ω|² dt · t`: fast spinners in the batch gain tens of
percent of their energy. Splitting's error is bounded (dt² oscillation) and sits near float32
round-off for most bodies.

## Throughput against batch size

Wall time of one `rb.simulate` call (after compilation, which happens once per shape), in
body-steps per second. Small batches are dominated by per-step overhead, large ones by
arithmetic; on a CPU the curve flattens early, on a GPU it keeps rising to ~1e6 bodies.
"""),
    code("""
Ns, steps_t, method = [100, 1_000, 10_000], 200, "splitting"
big = random_boxes(max(Ns), seed=1)
rates, finals = [], {}
for n in Ns:
    s = jax.tree.map(lambda a, n=n: a[:n], big)  # the first n bodies of one batch
    run = lambda s=s: jax.block_until_ready(rb.simulate(s, None, dt, steps_t, method, save_every=steps_t))
    finals[n] = run()  # compiles for this shape
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    rates.append(n * steps_t / min(times))
    print(f"N = {n:>6}: {min(times) * 1e3:7.1f} ms for {steps_t} steps -> {rates[-1]:.2e} body-steps/s")

fig, ax = plt.subplots(figsize=(6, 3.8))
ax.loglog(Ns, rates, "o-")
ax.set(xlabel="bodies N", ylabel="body-steps / s", title=f"{method}, float32, {jax.devices()[0].platform}")
ax.grid(True, which="both", alpha=0.3)
fig.tight_layout()
"""),
    code("""
# Physical checks (these can fail):
# 1. splitting conserves energy to a bounded error for every body: 2nd order, dt = 0.01 s,
#    |ω| up to ~8 rad/s gives (|ω| dt)² ~ 6e-3 at worst; typical bodies are near float32 eps.
assert np.all(np.isfinite(drift["splitting"])) and drift["splitting"].max() < 1e-2
assert np.median(drift["splitting"]) < 1e-4
# 2. and beats explicit Euler on (almost) every body: euler's error grows linearly in time.
assert np.mean(drift["splitting"] < drift["euler"]) > 0.99
# 3. bodies in a batch do not interact: the first 100 bodies end in the same state whether they
#    are simulated alone or among 10 000. XLA vectorises the two batch sizes differently, so
#    float32 rounding differs (eps 6e-8) and grows over 200 steps, most for the fast, near-
#    separatrix spinners (~3e-5 seen); 2e-4 allows for that, a coupling bug would give O(1).
small, large, n0 = finals[Ns[0]], finals[Ns[-1]], Ns[0]
np.testing.assert_allclose(np.asarray(large.orientation[:, :n0]), np.asarray(small.orientation), atol=2e-4)
np.testing.assert_allclose(np.asarray(large.angular_momentum[:, :n0]), np.asarray(small.angular_momentum),
                           rtol=1e-5, atol=1e-6)
print("all checks passed")
"""),
]

# --------------------------------------------------------------------------------------------------
NB3 = [
    md("""
# 3. Speed against error: choosing a method and a time step

Which integrator, and which `dt`, reaches a given accuracy at the lowest cost? We run a small
**work–precision** study: a generic tumbling body, every registered method, a sweep of `dt`, the
attitude error at the final time against the exact solution `rb.torque_free`, and the measured
wall time per body-step. float64 throughout.
"""),
    md(
        SIZES_NOTE.format(
            how="Here: 256 identical bodies, T = 4 s, three time steps per method. The full study "
            "(10 000 bodies, three test problems, float32 and float64, diffrax as a peer) is "
            "`python benchmarks/work_precision.py`; its plot is shown at the end if present."
        )
    ),
    code("""
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import rbjax as rb

jax.config.update("jax_enable_x64", True)  # float64: errors down to 1e-11

%matplotlib inline
"""),
    code("""
# a generic tumble: distinct moments, principal axes not aligned with the body axes
R = rb.quat_to_matrix(rb.quat_normalize(jnp.array([0.9, 0.3, -0.2, 0.25])))
body = rb.Body(1.0, rb.rotate_inertia(jnp.diag(jnp.array([1.0, 1.8, 2.6])), R))
B = 256                                  # identical bodies: the timing is per body-step of a batch
s1 = rb.State.create(body, angular_velocity=jnp.array([0.6, 1.0, -0.8]))
s0 = jax.tree.map(lambda a: jnp.broadcast_to(a, (B,) + a.shape), s1)
T = 4.0
exact = rb.torque_free(s1, T)

methods = list(rb.methods(rb.State))
# orders 6 and 8 reach float64 round-off (1e-13) by dt = 0.1 here: they get 40x larger steps;
# splitting4 (the middle-axis split, nearly exact here) meets 1e-12 by dt = 0.005: 4x larger steps
def dts_for(m):
    if rb.methods()[m].order >= 6:
        return [0.8, 0.4, 0.2]
    return [0.08, 0.04, 0.02] if m.startswith("splitting") and rb.methods()[m].order == 4 else [0.02, 0.01, 0.005]
results = {}  # method -> list of (dt, error rad, seconds per body-step)
for m in methods:
    results[m] = []
    for dt in dts_for(m):
        steps = int(round(T / dt))
        def run(dt=dt, steps=steps, m=m):
            return jax.block_until_ready(rb.simulate(s0, None, dt, steps, m, save_every=steps))
        run()  # compile
        t0 = time.perf_counter()
        tr = run()
        sec = time.perf_counter() - t0
        err = float(rb.quat_angle(tr.orientation[-1, 0], exact.orientation))
        results[m].append((dt, err, sec / (B * steps)))
    print(f"{m:>20}:", "  ".join(f"{e:.1e}" for _, e, _ in results[m]), "rad")
"""),
    code("""
fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
for m, r in results.items():
    dt_, err, cost = map(np.array, zip(*r, strict=True))
    a1.loglog(dt_, err, "o-", label=f"{m} (order {rb.methods()[m].order})")
    a2.loglog(cost * T / dt_ * 1e6, err, "o-", label=m)   # µs of wall time per body to reach T
a1.set(xlabel="dt (s)", ylabel="attitude error at T (rad)", title="convergence")
a2.set(xlabel="wall time per body to T = 4 s (µs)", ylabel="attitude error at T (rad)",
       title="work–precision (lower left is better)")
a1.legend(fontsize=8)
for a in (a1, a2):
    a.grid(True, which="both", alpha=0.3)
fig.tight_layout()
"""),
    md("""
## Picking a method and `dt` for a target accuracy

Each method's error follows `err ≈ C dtᵖ`. Fitting `C` and `p` on the two smallest steps gives
the `dt` that just meets a tolerance, and from the measured cost per step the wall time to reach
`T`. The cheapest row wins. (On this problem: high accuracy favours `rk8`, then `rk4`; the symplectic
`splitting` is the choice for long runs where energy must not drift, even at loose tolerances.
Without torque `semi_implicit_euler` reduces to `euler`; the implicit first-order
`implicit_gyroscopic` buys stability for stiff fast spins, not accuracy. Timings on a shared CPU
are noisy: treat the cost column as an order of magnitude.)
"""),
    code("""
def plan(tol):
    rows = []
    for m, r in results.items():
        (dt1, e1, c1), (dt2, e2, c2) = r[-2], r[-1]
        p = np.log(e1 / e2) / np.log(dt1 / dt2)          # observed order
        dt_needed = dt2 * (tol / e2) ** (1 / p)
        rows.append((T / dt_needed * min(c1, c2) * 1e6, m, dt_needed, p))
    return sorted(rows)

for tol in [1e-3, 1e-6]:
    print(f"target attitude error {tol:g} rad at T = {T} s:")
    for us, m, dt_needed, p in plan(tol):
        note = "  (extrapolated beyond the sweep: check stability)" if dt_needed > max(dts_for(m)) else ""
        print(f"   {m:>20}: order {p:4.2f}, dt = {dt_needed:.1e} s, ~{us:9.1f} µs per body{note}")
"""),
    code("""
png = Path("../benchmarks/results/work_precision.png")
if png.exists():  # the full study, from `python benchmarks/work_precision.py`
    from IPython.display import display
    from PIL import Image
    im = Image.open(png).convert("RGB")
    im.thumbnail((1000, 1000))
    display(im.quantize(128))  # a 128-colour copy: stored in the notebook at a fifth of the file's bytes
else:
    print("run `python benchmarks/work_precision.py` for the full study")
"""),
    code("""
# Physical/numerical checks (these can fail): each method converges at its registered order,
# observed on the two smallest steps (asymptotic regime here, errors >> 1e-13 round-off);
# 0.3 allows for the pre-asymptotic error constant.
for m, r in results.items():
    (dt1, e1, _), (dt2, e2, _) = r[-2], r[-1]
    p = np.log(e1 / e2) / np.log(dt1 / dt2)
    assert abs(p - rb.methods()[m].order) < 0.3, (m, p)
    assert e2 > 1e-12, (m, e2)  # the slope was measured above round-off
# and among the low-order sweep (the same three steps) a fourth-order method is the most accurate.
low = [m for m in results if rb.methods()[m].order <= 4]
assert rb.methods()[min(low, key=lambda m: results[m][-1][1])].order == 4
print("all checks passed")
"""),
]

# --------------------------------------------------------------------------------------------------
NB4 = [
    md("""
# 4. Fitting an inertia tensor to a recording

System identification: given a recording of a body tumbling freely — orientations (from motion
capture or an IMU's attitude filter) and body-frame angular rates (the gyro) — recover its
inertia tensor. `rb.fit_inertia` integrates the rigid-body equations between samples
(differentiably, `rk4`) and solves the least-squares problem by Levenberg–Marquardt.

Without known torques only the **shape** of the inertia is identifiable (`I` and `c·I` give the
same motion), so the fit returns `I / tr I` and `scale_fixed = False`.

**Data generator.** The recording is made with the exact closed-form solution `rb.torque_free`
(Jacobi elliptic functions), not with the integrator the fit uses, so the fit's own
discretisation error is part of what we test.
"""),
    md(
        SIZES_NOTE.format(
            how="The recording is 1 s at 200 Hz; for a real study use several seconds at 1 kHz "
            "(`T`, `rate` below) — compile time then dominates the first call, ~1 min."
        )
    ),
    code("""
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import rbjax as rb

jax.config.update("jax_enable_x64", True)  # accuracy: fit residuals go down to ~1e-12

%matplotlib inline
"""),
    code("""
# truth: principal moments (1, 1.6, 2.5) kg m^2 with principal axes rotated away from the body axes
R_true = rb.quat_to_matrix(rb.quat_normalize(jnp.array([0.9, 0.2, -0.3, 0.1])))
I_true = np.asarray(rb.rotate_inertia(jnp.diag(jnp.array([1.0, 1.6, 2.5])), R_true))
s0 = rb.State.create(rb.Body(1.0, I_true), angular_velocity=jnp.array([3.0, 8.0, 3.0]))  # rad/s

T, rate = 1.0, 200                           # s, Hz
times = np.linspace(0.0, T, int(T * rate) + 1)
rec = rb.torque_free(s0, times)
quats = np.asarray(rec.orientation)                  # (201, 4), body -> world
gyro = np.asarray(rb.body_angular_velocity(rec))     # (201, 3), rad/s, body frame
print(np.round(I_true, 4))
"""),
    code("""
# IMU-like noise: 1e-3 rad of random attitude error, 0.01 rad/s of gyro noise
rng = np.random.default_rng(0)
attitude_noise = rb.quat_exp(jnp.asarray(rng.normal(0, 1e-3, (len(times), 3))))  # body-frame rotation vectors
quats_noisy = np.array(rb.quat_multiply(quats, attitude_noise))
quats_noisy /= np.linalg.norm(quats_noisy, axis=-1, keepdims=True)
gyro_noisy = gyro + rng.normal(0, 0.01, gyro.shape)

fig, ax = plt.subplots(figsize=(8, 3))
ax.plot(times, gyro_noisy, lw=0.8)
ax.set(xlabel="t (s)", ylabel="gyro (rad/s)", title="the noisy recording (body-frame rates)")
fig.tight_layout()
"""),
    md("""
## Fit: clean, then noisy

Both fits use the same static settings (`segments`, `substeps`) so the second reuses the first's
compiled program.
"""),
    code("""
opts = dict(segments=2, substeps=2)
fit_clean = rb.fit_inertia(times, quats, body_rates=gyro, **opts)
fit_noisy = rb.fit_inertia(times, quats_noisy, body_rates=gyro_noisy, **opts)

truth = np.linalg.eigvalsh(I_true / np.trace(I_true))   # shape only: normalise tr I = 1
print("                 principal moments (tr I = 1)      1-sigma              |error|/sigma")
print(f"truth        {truth}")
for name, f in [("clean", fit_clean), ("noisy", fit_noisy)]:
    pm, sd = np.asarray(f.principal_moments), np.asarray(f.moment_std)
    print(f"{name:<12} {pm}  {sd}  {np.abs(pm - truth) / sd}"
          f"   converged={bool(f.converged)}, {int(f.iterations)} LM steps")

def axis_angles(f):  # angle (deg) between fitted and true principal axes
    ax_true = np.linalg.eigh(I_true)[1]
    return np.degrees(np.arccos(np.clip(np.abs(np.sum(ax_true * np.asarray(f.principal_axes), 0)), 0, 1)))
print("principal-axis errors (deg): clean", axis_angles(fit_clean), " noisy", axis_angles(fit_noisy))
"""),
    md("""
## Inertia ellipsoids

The inertia ellipsoid `xᵀ I x = 1` has semi-axes `1/√Iᵢ` along the principal axes. Below: its
shadows on the three body-frame coordinate planes, true vs fitted (both `tr I = 1`). At these
noise levels the fitted and true ellipsoids are indistinguishable by eye (errors ~1e-4), so the
right panel shows the moment errors against the reported ±2σ bars.
"""),
    code("""
def shadow(I, i, j, n=200):
    # projection of {x: xᵀ I x <= 1} onto coordinates (i, j): yᵀ ((I⁻¹)_ij)⁻¹ y <= 1
    C = np.linalg.inv(I)[np.ix_([i, j], [i, j])]
    a = np.linspace(0, 2 * np.pi, n)
    return np.linalg.cholesky(C) @ np.stack([np.cos(a), np.sin(a)])

fig, axes = plt.subplots(1, 4, figsize=(14, 3.6))
I_t = I_true / np.trace(I_true)
for ax, (i, j) in zip(axes[:3], [(0, 1), (0, 2), (1, 2)], strict=True):
    for I, style, lab in [(I_t, "k-", "truth"), (np.asarray(fit_clean.inertia), "b--", "fit, clean"),
                          (np.asarray(fit_noisy.inertia), "r:", "fit, noisy")]:
        ax.plot(*shadow(I, i, j), style, lw=2 if lab == "truth" else 1.2, label=lab)
    ax.set(aspect="equal", xlabel="xyz"[i], ylabel="xyz"[j], title=f"{'xyz'[i]}{'xyz'[j]} shadow")
axes[0].legend(fontsize=8)
for k, (f, c) in enumerate([(fit_clean, "b"), (fit_noisy, "r")]):
    err = np.asarray(f.principal_moments) - truth
    axes[3].errorbar(np.arange(3) + 0.1 * k, err, yerr=2 * np.asarray(f.moment_std), fmt="o", color=c,
                     capsize=3, label=["clean", "noisy"][k])
axes[3].axhline(0, color="k", lw=0.8)
axes[3].set(xticks=range(3), xticklabels=["I₁", "I₂", "I₃"], ylabel="fitted − true (tr I = 1)",
            title="moment errors ± 2σ")
axes[3].legend(fontsize=8)
fig.tight_layout()
"""),
    code("""
# Physical checks (these can fail):
# 1. clean data: the shape of I is recovered to 1e-6 (rk4 with 2 substeps at 200 Hz has a
#    discretisation error ~1e-9 here; the tolerance leaves room for other BLAS/platforms);
pm_c, pm_n, sd_n = (np.asarray(a) for a in (fit_clean.principal_moments, fit_noisy.principal_moments,
                                              fit_noisy.moment_std))
assert bool(fit_clean.converged) and bool(fit_noisy.converged)
assert np.abs(pm_c - truth).max() < 1e-6
assert axis_angles(fit_clean).max() < 1e-3                     # degrees
# 2. noisy data: within 0.5% of the truth, and the reported uncertainty is honest (errors
#    within 4 sigma; the sigmas are not absurdly large either).
assert np.abs(pm_n / truth - 1).max() < 5e-3
assert np.all(np.abs(pm_n - truth) < 4 * sd_n)
assert np.all(sd_n < 1e-2 * truth)
print("all checks passed")
"""),
]

# --------------------------------------------------------------------------------------------------
NB5 = [
    md("""
# 5. Reaction-wheel slews: a torque schedule by gradient descent through `simulate`

A thousand small satellites, each with its own inertia and three orthogonal reaction wheels, start
at rest. Each must turn by 90° about its own axis and come to rest again in `T = 15 s`, with every
wheel's torque within `|τ_k| ≤ τ_max`. We find the wheel-torque schedules by plain gradient descent
(Adam, written out below) on the final attitude error, differentiating through `rb.simulate`: the
whole batch is one `simulate` call and one `jax.value_and_grad`.

**The model** (the Gyrostats page of the guide, `docs/gyrostats.md`). The wheels' momenta relative to the body are
`h_k = J_k Ω_k`, `h = Σ_k h_k a_k` in the body frame; a wheel torque `τ_k` changes only them,
`ḣ_k = τ_k`, and never the total angular momentum `L`, which rbjax keeps in the state. The body rate is

    ω_b = I⁻¹ (Rᵀ L − h)

and the satellites start at rest, so `L = 0` for all time and `ω_b = −I⁻¹ h`: the body turns
exactly as the wheels' momentum tells it. *Rest to rest* then means `h(T) = 0`, and the wheel
inertias `J_k` do not enter the motion at all (they set only the wheel speeds `Ω_k = h_k / J_k`).
The attitude is what is hard: rotations do not commute, so the attitude reached is not a linear
function of the schedule.
"""),
    md(
        SIZES_NOTE.format(
            how="Here: 1,000 satellites, 32 rk4 steps per slew, 200 Adam iterations. A finer schedule "
            "(`SEGMENTS`) or more satellites (`n`) costs proportionally more."
        )
    ),
    code("""
import time

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import rbjax as rb

%matplotlib inline
# float32 (JAX's default): the target is 1e-3 rad, four orders above float32's round-off over
# 32 steps, and float32 runs the optimisation faster than float64 (docs/slews.md has both times)
dtype = np.float32
"""),
    code("""
n = 1_000
rng = np.random.default_rng(5)

# principal moments 0.5-2 kg m^2; a physical body has its largest moment at most the sum of the others
moments = rng.uniform(0.5, 2.0, (4 * n, 3))
moments = moments[2 * moments.max(1) <= moments.sum(1)][:n]

def random_quaternions(k):
    q = rng.normal(size=(k, 4))  # uniform on the rotation group
    return q / np.linalg.norm(q, axis=1, keepdims=True)

R_p = np.asarray(rb.quat_to_matrix(random_quaternions(n)))  # random principal axes
inertia = np.einsum("nij,nj,nkj->nik", R_p, moments, R_p)   # (n, 3, 3) kg m^2, body frame
J = rng.uniform(1e-3, 1e-2, (n, 3))                          # kg m^2, each wheel its own
wheels = rb.Rotors(axes=np.eye(3, dtype=dtype), inertia=J.astype(dtype))  # wheels along the body axes

axis = rng.normal(size=(n, 3))
axis /= np.linalg.norm(axis, axis=1, keepdims=True)          # slew axes, body frame
q0 = random_quaternions(n)                                   # start attitudes
q_goal = jnp.asarray(rb.quat_multiply(q0, rb.quat_exp(0.5 * np.pi * axis)), dtype)  # 90 deg about each axis

# at rest: zero body rate and zero wheel rates, so L = 0 (create's defaults)
s0 = rb.State.create(rb.Body(np.full(n, 20.0, dtype), inertia.astype(dtype)), orientation=q0.astype(dtype),
                     rotors=wheels)
print(s0.batch_shape, s0.rotor_momentum.shape, s0.dtype)
"""),
    md("""
## The schedule

Each wheel's torque is piecewise constant over `2 × SEGMENTS` equal segments of the slew, and two
choices build the constraints in, so that the optimiser never sees them:

* **the limit**: `τ = τ_max tanh(u)`, so `|τ_k| ≤ τ_max` whatever the parameters `u`;
* **rest to rest**: the second half is the first half reversed in time and negated,
  `τ(T − t) = −τ(t)`, so `h(T) = ∫ τ dt = 0` and the body ends at rest (`ω_b = −I⁻¹ h`). The
  time-optimal eigen-axis slew (full torque, then full reverse torque) has this form.

With `τ_max = 0.08 N m` a bang-bang eigen-axis slew would need up to about two thirds of the limit
for the hardest satellite of this batch (printed below). The torque reaches `simulate` as a per-step time series,
`Forces(rotor_torque=(steps, n, 3))`.

The loss is `Σ_i |vec(q_goal,i* ⊗ q_i(T))|² = Σ_i sin²(θ_i / 2)`, `θ_i` the attitude error of
satellite `i`: smooth, blind to the quaternion's sign, and a sum of independent terms, so each
satellite's parameters get their own satellite's gradient.
"""),
    code("""
T, SEGMENTS, PER_SEGMENT = 15.0, 8, 2       # s; 8 free segments per half; rk4 steps per segment
steps = 2 * SEGMENTS * PER_SEGMENT            # 32
dt = T / steps                                # s
tau_max = 0.08                                # N m, each wheel

need = 4 * (np.pi / 2) / T**2 * np.abs(np.einsum("nij,nj->ni", inertia, axis)).max(1)  # bang-bang eigen-axis
print(f"eigen-axis bang-bang torque / tau_max: median {np.median(need) / tau_max:.2f}, max {need.max() / tau_max:.2f}")

def schedule(u):
    # u (SEGMENTS, n, 3) -> torques (steps, n, 3), N m
    half = tau_max * jnp.tanh(u)
    full = jnp.concatenate([half, -half[::-1]])   # antisymmetric about T/2: h(T) = 0
    return jnp.repeat(full, PER_SEGMENT, axis=0)  # held over each segment's steps

def slew(u, save_every=steps, refine=1):
    tau = jnp.repeat(schedule(u), refine, axis=0)  # refine > 1: the same schedule on finer steps
    return rb.simulate(s0, rb.Forces(rotor_torque=tau), dt / refine, steps * refine, "rk4",
                       save_every=save_every * refine)

def loss(u):
    q_end = slew(u).orientation[-1]
    err = rb.quat_multiply(rb.quat_conjugate(q_goal), q_end)[..., 1:]  # sin(theta/2) along the error axis
    return jnp.sum(err**2), err
"""),
    md("""
## Gradient descent

Adam, in a few lines: per-parameter step sizes suit a batch whose satellites need torques of
different sizes, and the learning rate decays over the run (cosine) so that the last iterations
settle. Every iteration is one forward `simulate` of all 1,000 satellites and its reverse pass.
"""),
    code("""
ITERATIONS, LR, B1, B2 = 200, 0.1, 0.9, 0.999

@jax.jit
def adam_step(u, m, v, k):
    (_, err), g = jax.value_and_grad(loss, has_aux=True)(u)
    lr = LR * 0.5 * (1 + jnp.cos(jnp.pi * k / ITERATIONS)) + 1e-3
    m = B1 * m + (1 - B1) * g
    v = B2 * v + (1 - B2) * g * g
    u = u - lr * (m / (1 - B1 ** (k + 1))) / (jnp.sqrt(v / (1 - B2 ** (k + 1))) + 1e-12)
    theta = 2 * jnp.arcsin(jnp.minimum(jnp.linalg.norm(err, axis=-1), 1.0))  # rad, before this step
    return u, m, v, theta

u = jnp.zeros((SEGMENTS, n, 3), dtype)  # no torque: the first error is the whole 90 deg
m, v = jnp.zeros_like(u), jnp.zeros_like(u)
history = []  # (median, max) attitude error over the batch, rad
t0 = time.perf_counter()
for k in range(ITERATIONS):
    u, m, v, theta = adam_step(u, m, v, jnp.asarray(k, dtype))
    history.append((float(jnp.median(theta)), float(jnp.max(theta))))
    if k % 40 == 0:
        print(f"iteration {k:3d}: attitude error median {history[-1][0]:.1e} rad, max {history[-1][1]:.1e} rad")
print(f"{ITERATIONS} iterations in {time.perf_counter() - t0:.1f} s (the first compiles)")
history = np.array(history)

traj = slew(u, save_every=1)                              # the found schedules, every step saved
theta = np.asarray(rb.quat_angle(traj.orientation[-1], q_goal))
w_end = np.asarray(rb.body_angular_velocity(traj[-1]))  # rad/s, body frame
tau = np.asarray(schedule(u))                           # (steps, n, 3), N m
print(f"final attitude error: median {np.median(theta):.1e} rad, max {theta.max():.1e} rad")
print(f"final body rate: max {np.abs(w_end).max():.1e} rad/s; peak wheel torque {np.abs(tau).max():.3f} N m")
"""),
    code("""
i = int(np.argmax(np.abs(tau).max(axis=(0, 2))))  # the satellite that comes closest to the limit
t_seg = np.linspace(0.0, T, 2 * SEGMENTS + 1)

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.8))
a1.semilogy(history[:, 0], label="median")
a1.semilogy(history[:, 1], label="max")
a1.axhline(1e-3, color="k", ls=":", lw=1, label="1e-3 rad")
a1.set(xlabel="Adam iteration", ylabel="final attitude error (rad)", title=f"{n} satellites, one batch")
a1.legend()
for k_, c in enumerate(["tab:red", "tab:green", "tab:blue"]):
    a2.stairs(tau[::PER_SEGMENT, i, k_], t_seg, baseline=None, color=c, lw=1.5, label=f"wheel {'xyz'[k_]}")
for s in (1, -1):
    a2.axhline(s * tau_max, color="k", ls="--", lw=1)
a2.set(xlabel="t (s)", ylabel="wheel torque (N m)", title=f"satellite {i}: schedule and limit ±{tau_max} N m")
a2.legend(fontsize=8, loc="lower left")
fig.tight_layout()
"""),
    code("""
# Physical checks (these can fail):
# 1. every satellite ends within 1e-3 rad of its goal, in the run the optimiser saw ...
assert theta.max() < 1e-3, theta.max()
# ... and with the same schedules on 8x finer steps: the schedules do not lean on rk4's error
fine = slew(u, refine=8)
theta_fine = np.asarray(rb.quat_angle(fine.orientation[-1], q_goal))
assert theta_fine.max() < 1e-3, theta_fine.max()
# 2. rest to rest: h(T) = 0 by construction, so the final body rate is float32 round-off of the
#    wheel momenta; 1e-5 rad/s is four orders below the slews' peak rates (and the body did turn)
w = np.asarray(rb.body_angular_velocity(traj))
assert np.abs(w_end).max() < 1e-5 and np.abs(w).max() > 0.05, (np.abs(w_end).max(), np.abs(w).max())
#    and the wheels have stopped with the body: the kinetic energy is back to round-off
E = np.asarray(rb.kinetic_energy(traj))  # (steps + 1, n), J
assert E[-1].max() < 1e-9 * E.max(), (E[-1].max(), E.max())
# 3. the torque limit holds everywhere (tanh keeps it, whatever the optimiser did)
assert np.abs(tau).max() <= tau_max
# 4. the wheel torques are internal: world L stays zero over every step (rbjax steps L itself)
L = np.asarray(traj.angular_momentum)
assert np.abs(L).max() < 1e-6, np.abs(L).max()
peak_rpm = (np.abs(np.asarray(traj.rotor_momentum)) / J).max() * 60 / (2 * np.pi)
print(f"max error {theta.max():.1e} rad ({theta_fine.max():.1e} on 8x finer steps), "
      f"max final rate {np.abs(w_end).max():.1e} rad/s, max |L| {np.abs(L).max():.1e} N m s, "
      f"peak wheel speed {peak_rpm:.0f} rpm")
print("all checks passed")
"""),
]

NOTEBOOKS = {
    "01_tumbling_t_handle.ipynb": NB1,
    "02_ten_thousand_bodies.ipynb": NB2,
    "03_speed_against_error.ipynb": NB3,
    "04_fitting_inertia.ipynb": NB4,
    "05_reaction_wheel_slews.ipynb": NB5,
}


def execute(nb, name: str) -> None:
    """Run ``nb`` in a kernel of this interpreter, in notebooks/, keeping its outputs in ``nb``."""
    import nbclient

    nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(HERE)}}
    ).execute()
    for cell in nb.cells:  # execution counts and timing metadata would make every re-run a diff
        cell.pop("id", None)
        cell.metadata = {}
        if cell.cell_type == "code":
            cell.execution_count = None
            for out in cell.get("outputs", []):
                if "execution_count" in out:
                    out["execution_count"] = None
    print("executed", name)


def main(run: bool = False, only: list[str] | None = None) -> None:
    for name, cells in NOTEBOOKS.items():
        if only and not any(name.startswith(o) for o in only):
            continue
        nb = new_notebook(cells=cells)
        nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
        nb.metadata["language_info"] = {"name": "python"}
        for cell in nb.cells:  # stable ids keep regenerated files diff-free
            cell.pop("id", None)
        nb.nbformat, nb.nbformat_minor = 4, 4
        if run:
            execute(nb, name)
        nbformat.validate(nb)
        nbformat.write(nb, HERE / name)
        print("wrote", HERE / name)
        _ruff_format(HERE / name)


def _ruff_format(path: Path) -> None:
    """Format the notebook's code cells as tests/test_lint.py expects (the cells above are not)."""
    import shutil
    import subprocess
    import sys

    ruff = shutil.which("ruff") or str(Path(sys.executable).parent / "ruff")
    if Path(ruff).exists():
        subprocess.run([ruff, "format", "-q", str(path)], check=True)
    else:
        print("ruff not found: run `ruff format notebooks` before committing")


if __name__ == "__main__":
    import sys

    # python notebooks/_make.py [--execute] [01 03 ...]: all notebooks, or those whose names start so
    main(run="--execute" in sys.argv[1:], only=[a for a in sys.argv[1:] if not a.startswith("--")])
