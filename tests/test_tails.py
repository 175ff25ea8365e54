"""The consistency tests' χ² and F tail probabilities (NumPy) against scipy.special."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.special as sp
import scipy.stats as st

from rbjax.identification._tails import chi2_sf, f_sf


def test_chi2_tail_matches_scipy():
    rng = np.random.default_rng(0)
    # the fits' range: ν from a few (a short throw's share) to ~3e5 (long recordings), χ² around ν
    nu = np.concatenate([rng.uniform(0.5, 5, 200), rng.uniform(5, 5000, 200), 10 ** rng.uniform(3, 5.5, 50)])
    c = nu * rng.uniform(0.2, 3, nu.size)
    ref, got = sp.gammaincc(nu / 2, c / 2), chi2_sf(nu, c)
    # series / continued fraction to ~1e-14 per term; lgamma's rounding at ν ~ 1e5 dominates: 1e-9
    # relative where the probability is representable, 1e-12 absolute everywhere
    big = ref > 1e-290
    np.testing.assert_allclose(got[big], ref[big], rtol=1e-9)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


def test_f_tail_matches_scipy():
    rng = np.random.default_rng(1)
    d1 = np.concatenate([rng.uniform(1, 50, 200), rng.uniform(50, 5000, 200)])
    d2 = rng.uniform(1, 3000, d1.size)
    f = rng.uniform(0.1, 3, d1.size)
    ref, got = st.f.sf(f, d1, d2), f_sf(d1, d2, f)
    big = ref > 1e-290
    np.testing.assert_allclose(got[big], ref[big], rtol=1e-9)
    # the complement 1 - I_x(b, a) carries the rounding of lgamma at arguments ~2500 (~1e4 · 1e-16)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)


@pytest.mark.parametrize("bad", [np.nan, -1.0, 0.0])
def test_undefined_arguments_give_nan_not_a_probability(bad):
    assert np.isnan(chi2_sf(bad, 3.0)) and np.isnan(f_sf(bad, 10.0, 1.0)) and np.isnan(f_sf(3.0, bad, 1.0))
    assert np.isnan(chi2_sf(3.0, np.nan)) and np.isnan(f_sf(3.0, 10.0, np.nan))
