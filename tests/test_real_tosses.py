"""Real data: thirteen phyphox gyro exports of a tossed phone (iPhone 13 Pro, ~100 Hz, rad/s).

The exports are GPL-3.0 and live outside the repository: read from
``<repository>/../shared/data/phone_tosses`` or ``$RBJAX_PHONE_TOSSES`` (never copied
here); the tests skip where they are absent. Their README: a uniform box of the
phone's size (71.5 x 146.7 x 7.65 mm) has ``Ix : Iy : Iz = 0.810 : 0.194 : 1``, so
ascending ``I1/I3, I2/I3 = 0.194, 0.810``; the real phone (camera, battery) is a few
percent off, the same for every toss.

What must hold on real data, whatever the windows: a fit the verdict trusts is
near the box values within its σ (no trusted wrong answer), and a fit on the edge
of physical inertias (a flat-body ratio 0 : 1, where the windows that include
the hand land) is neither trusted nor reported as well determined. That most
throws are trusted needs free flight found from the gyro alone without the hand
(issue 57, item 6): not yet, an expected failure below.
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

pytestmark = [
    pytest.mark.skipif(
        not DATA.is_dir(),
        reason=f"the real phone tosses are not at {DATA} (set RBJAX_PHONE_TOSSES to their folder)",
    ),
    pytest.mark.slow,  # ~30 gyro-only fits of real throws: ~1 min on 2 cores
]


@pytest.fixture(scope="module")
def tosses():
    """``(names, FitResult of every find_throws window, one fit each)``."""
    jax.config.update("jax_enable_x64", True)
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
    return names, rb.fit_inertia(throws)


def _ratios(res):
    m, s = np.asarray(res.principal_moments), np.asarray(res.moment_std)
    r = m[:, :2] / m[:, 2:]
    return r, r * np.sqrt((s[:, :2] / m[:, :2]) ** 2 + (s[:, 2:] / m[:, 2:]) ** 2)


def test_a_trusted_real_throw_is_near_the_box_within_its_sigma(tosses):
    names, res = tosses
    r, rs = _ratios(res)
    trusted = np.asarray(res.converged) & ~np.asarray(res.failed)
    wrong = [
        f"{names[i]}: {r[i].round(3)} ± {rs[i].round(3)} ({res.diagnosis[i]})"
        for i in np.flatnonzero(trusted)
        if np.any(np.abs(r[i] - BOX) > 3 * rs[i] + BAND)
    ]
    assert not wrong, wrong


def test_a_real_fit_on_the_edge_is_neither_trusted_nor_well_determined(tosses):
    # the gyro-only windows that include the hand fit a flat body (ratios 0.00 : 1.00); before this
    # verdict some reported σ of 1e-10 to 1e-5 with well_determined=True
    names, res = tosses
    edge = np.asarray(res.on_boundary) & ~np.asarray(res.failed)
    assert edge.sum() >= 10, edge.sum()  # measured 22 of 29 windows on 2026-12-07
    for flag in ("converged", "well_determined"):
        bad = [names[i] for i in np.flatnonzero(edge & np.asarray(getattr(res, flag)))]
        assert not bad, (flag, bad)
    # the diagnosis names the misfit: tens to thousands of times the gyro noise
    assert all("x the gyro noise" in d for d, e in zip(res.diagnosis, edge, strict=True) if e)


@pytest.mark.xfail(
    strict=True,
    reason="find_throws' gyro-only windows include the hand (issue 57, item 6): 0 of 29 trusted on 2026-12-07",
)
def test_most_real_throws_are_trusted_and_agree_with_the_box(tosses):
    names, res = tosses
    trusted = np.asarray(res.converged) & ~np.asarray(res.failed)
    assert trusted.mean() >= 0.5, [f"{n}: {d}" for n, d in zip(names, res.diagnosis, strict=True)]
    r, _ = _ratios(res)
    np.testing.assert_allclose(np.median(r[trusted], 0), BOX, atol=BAND)
