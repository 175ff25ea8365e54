"""One inertia fitted to several recordings of one body (``fit_inertia(..., joint=True)``)."""

from __future__ import annotations

import jax
import numpy as np

from .._pytree import replace
from ._layout import SEGMENT_PARAMS
from ._members import check_members
from ._problem import Problem, join_problems
from ._result import FitResult
from ._solve import pack, solve_with_starts
from ._tails import chi2_sf

__all__ = ["fit_joint", "segment_bucket"]


def segment_bucket(n: int) -> int:
    """The padded segment count of a joint problem of ``n`` segments: 1, 2, 3, 4, 6, 8, 12, 16, 24, ...

    Powers of two and 1.5 times them (at most 50% padding): a joint fit of 5, 6
    or 7 one-segment throws runs one compiled program, not three. A padding
    segment costs what a real one does (its intervals are stepped with
    ``dt = 0``), a new program of this model ~3-5 s of compile.
    """
    if n <= 3:
        return max(n, 1)
    p = 1 << (n - 1).bit_length()  # the next power of two >= n
    return 3 * p // 4 if 3 * p // 4 >= n else p


def _pad_segments(prob: Problem, total: int) -> Problem:
    """``prob`` with blank segments appended up to ``total``: no samples, no joins, ``dt = 0``.

    A blank segment is a copy of the last one with its sample weights (``first``,
    ``mask``) and intervals zeroed: no residual depends on its 6 parameters, so
    their Jacobian columns are zero, the damped step leaves them at their start
    and the covariance (columns scaled by their norms, zero ones dropped) and
    the degrees of freedom (``n_unused``) do not count them. The static
    ``joins`` are those of the real segments, so they stay the same.
    """
    pad = total - prob.segments
    if pad <= 0:
        return prob
    seg = prob.data["seg"]
    blank = jax.tree.map(lambda v: np.repeat(v[:, -1:], pad, axis=1), seg)
    blank = replace(blank, first=np.zeros_like(blank.first), mask=np.zeros_like(blank.mask), dt=np.zeros_like(blank.dt))
    seg = jax.tree.map(lambda a, b: np.concatenate([a, b], 1), seg, blank)
    y0 = np.concatenate([prob.y0, np.repeat(prob.y0[:, -SEGMENT_PARAMS:], pad, axis=1)], 1)
    data = dict(prob.data, seg=seg, n_unused=prob.data["n_unused"] + SEGMENT_PARAMS * pad)
    rows = lambda a, fill: np.concatenate([a, np.full((pad,) + a.shape[1:], fill, a.dtype)])
    return prob._replace(
        y0=y0,
        data=data,
        sample_index=rows(prob.sample_index, 0),
        sample_valid=rows(prob.sample_valid, False),
    )


def fit_joint(members, options) -> FitResult:
    """One inertia for all members (:func:`._problem.join_problems`); bad members left out and named.

    The joined problem is padded to :func:`segment_bucket` segments, so new
    throws of lengths in the same buckets, and a few more or fewer of them,
    reuse one compiled program (when each throw's own segments stay the same:
    the joins inside a recording are static).
    """
    probs, errors, good = check_members(members, options)
    K = max(probs[i].data["seg"].dt.shape[-1] for i in good)
    substeps = max(probs[i].static["substeps"] for i in good)  # more steps only add accuracy
    packed = [
        pack(members[i][0], members[i][1], options, segments=probs[i].segments, substeps=substeps, pad_intervals=K)
        for i in good
    ]
    prob = _pad_segments(join_problems(packed), segment_bucket(sum(p.segments for p in packed)))
    res, starts = solve_with_starts(prob, options)
    # per member: its segments' data rows (segment-major, as the model lays them out)
    seg = prob.data["seg"]
    S, K1 = seg.rw.shape[1], seg.rw.shape[-1]
    blocks = len(prob.sensors)
    r = np.asarray(res.residuals)[: S * blocks * K1 * 3].reshape(S, blocks, K1, 3)
    valid = np.concatenate([seg.first[0][:, None], seg.mask[0]], 1)  # (S, K+1)
    n_all = 3 * blocks * valid.sum()
    n_shared = prob.static["layout"].shared
    s2 = float(res.residual_ratio) ** 2
    stats = {}
    start = 0
    for i, p in zip(good, packed):
        part = slice(start, start + p.segments)
        start += p.segments
        chi2 = float(np.sum(r[part] ** 2))
        n_i = 3 * blocks * float(valid[part].sum())
        dof = n_i - (6 - float(p.data["n_unused"][0])) - n_shared * n_i / n_all
        # against the joint fit's own residual level s² (the noise levels are model_consistent's
        # test): which throw stands out from the others
        ratio = chi2 / (dof * s2)
        pval = float(chi2_sf(dof, ratio * dof))
        stats[i] = (float(np.sqrt(ratio)), chi2, float(dof), pval)
    nan4 = (np.nan,) * 4
    per = [stats.get(i, nan4) for i in range(len(members))]
    # each member's start state: that of its first segment (segments stacked in member order)
    first = dict(zip(good, np.cumsum([0] + [p.segments for p in packed])[:-1], strict=False))
    rows = {k: np.full((len(members), v.shape[-1]), np.nan, v.dtype) for k, v in starts.items()}
    for i, s0 in first.items():
        for k in rows:
            rows[k][i] = starts[k][s0]
    return replace(
        res,
        member_errors=tuple(f"recording {i}: {msg}" for i, msg in sorted(errors.items())),
        joint=True,
        member_rms=tuple(x[0] for x in per),
        member_chi2=tuple(x[1] for x in per),
        member_dof=tuple(x[2] for x in per),
        member_pvalue=tuple(x[3] for x in per),
        member_initial_orientation=jax.device_put(rows["q"]),
        member_initial_orientation_std=jax.device_put(rows["q_std"]),
        member_initial_angular_velocity=jax.device_put(rows["w"]),
        member_initial_angular_velocity_std=jax.device_put(rows["w_std"]),
    )
