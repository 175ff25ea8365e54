"""Real data: thirteen phyphox gyro exports of a tossed phone (iPhone 13 Pro, ~100 Hz, rad/s).

The exports are GPL-3.0 and live outside the repository: read from
``<repository>/../shared/data/phone_tosses`` or ``$RBJAX_PHONE_TOSSES`` (never copied
here); the tests skip where they are absent. Their README: a uniform box of the
phone's size (71.5 x 146.7 x 7.65 mm) has ``Ix : Iy : Iz = 0.810 : 0.194 : 1``, so
ascending ``I1/I3, I2/I3 = 0.194, 0.810``; the real phone (camera, battery) is a few
percent off, the same for every toss.

What must hold on real data, whatever the windows: a fit the verdict trusts is
near what the other trusted flights of the same object say, within its σ (no
trusted wrong answer), and a fit on the edge of physical inertias (a flat-body
ratio 0 : 1, where the windows that include the hand land) is neither trusted nor
reported as well determined. The gyro-only windows leave the hand and the
impacts out (issue 57, item 6): the long flights of the phone land near the box
and near each other. Their gyro misfit is correlated over a quarter to a half of
each 0.8 s flight; σ allows for that (HAC with the fixed-b widening), and the
verdict trusts every window whose moments the data determine (issue 57's goal:
≥ 90% of them; 12 of 12 on 2026-12-08, 6 of 12 before, when a slow misfit was
refused outright).

Six of the exports (12-22-44 and after) show a different motion: ``ω`` turns in
the body's x-y plane with ``ω_z`` near 0, which a torque-free phone cannot do
(``I_z ω̇_z = (I_x - I_y) ω_x ω_y``) but a flat body with ``I_x ≈ I_y ≈ I_z / 2``
does. Their fits say just that, consistently across exports (0.48-0.52 :
0.52-0.54, the in-plane axes undetermined), and the data reject the box: started
from the box's inertia, the fit ends on the edge or at its step limit with 5-30x
the misfit (measured 2026-12-08 on five of them). Whatever was tossed there is not
the box, so the tests hold the first seven exports to the box and the six others
to each other.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np
import pytest

import rbjax as rb

_ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RBJAX_PHONE_TOSSES", _ROOT.parent / "shared" / "data" / "phone_tosses"))
BOX = np.array([0.194, 0.810])  # ascending I1/I3, I2/I3 of the uniform box (README)
# the real phone is "a few percent" off the box: 0.05 in a ratio is the band beyond the fit's own 3σ
BAND = 0.05
# the exports of the phone alone; the six later ones show another body (module docstring)
BOX_EXPORTS = ("12-13-01", "12-13-51", "12-15-15", "12-16-50", "12-17-27", "12-18-19", "12-19-58")

pytestmark = [
    pytest.mark.skipif(
        not DATA.is_dir(),
        reason=f"the real phone tosses are not at {DATA} (set RBJAX_PHONE_TOSSES to their folder)",
    ),
    pytest.mark.slow,  # ~30 gyro-only fits of real throws: ~1 min on 2 cores
]


@pytest.fixture(scope="module")
def windows():
    """``(names, Recording of every find_throws window)``."""
    exports = sorted(p for p in DATA.iterdir() if p.is_dir())
    assert len(exports) == 13, exports
    throws, names = [], []
    for export in exports:
        rec = rb.Recording.from_phyphox(export)
        for t0, t1 in rb.find_throws(rec):
            keep = (rec.times >= t0) & (rec.times <= t1)
            throws.append(rb.Recording(rec.times[keep], gyro=rec.gyro[keep]))
            names.append(f"{export.name} {t0:.2f}-{t1:.2f} s")
    # every export holds at least one flight (the README: one or more per file)
    assert len(throws) >= 13, names
    return names, throws


@pytest.fixture(scope="module")
def tosses(windows):
    """``(names, FitResult of every find_throws window, one fit each)``."""
    jax.config.update("jax_enable_x64", True)
    names, throws = windows
    return names, rb.fit_inertia(throws)


def _ratios(res):
    m, s = np.asarray(res.principal_moments), np.asarray(res.moment_std)
    r = m[:, :2] / m[:, 2:]
    return r, r * np.sqrt((s[:, :2] / m[:, :2]) ** 2 + (s[:, 2:] / m[:, 2:]) ** 2)


def test_a_trusted_real_throw_is_near_its_objects_value_within_its_sigma(tosses):
    names, res = tosses
    r, rs = _ratios(res)
    trusted = np.asarray(res.converged) & ~np.asarray(res.failed)
    box = np.array([n.startswith(BOX_EXPORTS) for n in names])
    # the phone: the box's ratios, within the fit's 3σ plus the band of a real phone against a uniform box
    wrong = [
        f"{names[i]}: {r[i].round(3)} ± {rs[i].round(3)} ({res.diagnosis[i]})"
        for i in np.flatnonzero(trusted & box)
        if np.any(np.abs(r[i] - BOX) > 3 * rs[i] + BAND)
    ]
    assert not wrong, wrong
    # the other body: its trusted flights agree with their median within 3σ plus 0.01 (as the phone's do
    # below). Measured 2026-12-08: two trusted, 0.483 ± 0.047 : 0.536 ± 0.046 and 0.511 ± 0.11 : 0.529 ± 0.13
    other = trusted & ~box
    assert other.sum() >= 2, [f"{n}: {d}" for n, d in zip(names, res.diagnosis, strict=True)]
    median = np.median(r[other], axis=0)
    off = [
        f"{names[i]}: {r[i].round(3)} ± {rs[i].round(3)}"
        for i in np.flatnonzero(other)
        if np.any(np.abs(r[i] - median) > 3 * rs[i] + 0.01)
    ]
    assert not off, (median, off)


def test_a_real_fit_on_the_edge_is_neither_trusted_nor_well_determined(tosses):
    # the gyro-only windows that include the hand fit a flat body (ratios 0.00 : 1.00); before this
    # verdict some reported σ of 1e-10 to 1e-5 with well_determined=True
    names, res = tosses
    edge = np.asarray(res.on_boundary) & ~np.asarray(res.failed)
    # measured 20 of 41 windows on 2026-12-07; since 2026-12-08 find_throws drops the stretches of hand
    # motion whose Euler equations miss by more than a fifth (16 of those 20), and 4 short ones remain
    assert edge.sum() >= 2, edge.sum()
    for flag in ("converged", "well_determined"):
        bad = [names[i] for i in np.flatnonzero(edge & np.asarray(getattr(res, flag)))]
        assert not bad, (flag, bad)
    # never a near-zero σ there (issue 57, item 6; one window that held the hand read 1e-4): none at all,
    # and the diagnosis says so, then names the misfit: tens to thousands of times the gyro noise
    assert np.all(np.isinf(np.asarray(res.moment_std)[edge]))
    assert all(d.startswith("on the edge") and "x the gyro noise" in d for d, e in zip(res.diagnosis, edge) if e)


def test_no_window_is_the_hand_turning_the_phone(tosses, windows):
    # before 2026-12-08, 18 of 41 windows were stretches of hand motion that passed the torque-free cut
    # (16 fitted on the edge of physical inertias, 2 undetermined; the fit's rate misfit 14-83% of |ω|):
    # find_throws now drops a piece whose Euler equations miss by more than a fifth of their terms
    # (0.004-0.045 in the flights, 0.25-0.83 in those). What is left fits to 0.2-8% of |ω|, but for one
    # window on the edge at 28% (12-27-24 3.46-4.53 s, whose Euler miss is 0.10)
    names, res = tosses
    assert len(names) <= 25, names  # measured 23
    misfit = np.asarray(res.rate_rms) / np.array([np.sqrt(np.mean(np.sum(r.gyro**2, -1))) for r in windows[1]])
    assert np.nanmax(misfit) < 0.3, dict(zip(names, misfit.round(3)))


def test_the_gyro_alone_finds_the_phones_flights_without_the_hand(tosses):
    # before the impact test and the refitted cut, 22 of 29 windows held the hand or a knock and fitted
    # a flat body (0.00 : 1.00), and none of the long ones came within the band of the box. Measured
    # 2026-12-07: 10 of 41 windows are determined and within the band, at 0.205-0.234 : 0.785-0.807
    names, res = tosses
    r, rs = _ratios(res)
    near = np.asarray(res.well_determined) & ~np.asarray(res.failed) & np.all(np.abs(r - BOX) < BAND, axis=1)
    assert near.sum() >= 8, [f"{n}: {ri.round(3)}" for n, ri in zip(names, r, strict=True)]
    # one phone: its flights agree with their median within 3σ plus 0.01 (a few % of the ratio: the
    # hand-made throws differ in air drag, which the fit does not model here)
    median = np.median(r[near], axis=0)
    off = [
        f"{names[i]}: {r[i].round(3)} ± {rs[i].round(3)}"
        for i in np.flatnonzero(near)
        if np.any(np.abs(r[i] - median) > 3 * rs[i] + 0.01)
    ]
    assert not off, (median, off)


def test_every_real_throw_whose_moments_the_data_determine_is_trusted_and_the_phones_agree_with_the_box(tosses):
    # issue 57's goal: ≥ 90% of the flights whose moments the data determine trusted (measured 12 of 12 on
    # 2026-12-08; 6 of 12 before, when a misfit correlated over a quarter of the flight was refused)
    names, res = tosses
    determined = np.asarray(res.well_determined) & ~np.asarray(res.failed)
    trusted = np.asarray(res.converged) & ~np.asarray(res.failed)
    assert determined.sum() >= 10, determined.sum()
    assert trusted[determined].mean() >= 0.9, [f"{n}: {d}" for n, d, k in zip(names, res.diagnosis, determined) if k]
    r, _ = _ratios(res)
    box = np.array([n.startswith(BOX_EXPORTS) for n in names])
    assert (trusted & box).sum() >= 6  # measured 10
    np.testing.assert_allclose(np.median(r[trusted & box], 0), BOX, atol=BAND)


def test_a_joint_fit_of_the_phones_flights_is_trusted_and_near_the_reference(windows):
    # issue 57's goal: a joint fit of all throws of one object within ±0.02 of its reference. The
    # source repository's own simulator uses 1.2667e-4, 4.9128e-4, 6.1194e-4 kg m² (README):
    # 0.207 : 0.803. Measured 2026-12-08 over the 13 windows of the seven phone exports: 0.2178 ± 0.0024,
    # 0.7946 ± 0.0025, trusted (the misfit 189x the gyro noise, correlated over 25 samples)
    names, throws = windows
    phone = [r for n, r in zip(names, throws, strict=True) if n.startswith(BOX_EXPORTS)]
    assert len(phone) >= 10, names
    joint = rb.fit_inertia(phone, joint=True)
    assert bool(joint.converged), joint.diagnosis
    m = np.asarray(joint.principal_moments)
    np.testing.assert_allclose(m[:2] / m[2], [0.207, 0.803], atol=0.02)
