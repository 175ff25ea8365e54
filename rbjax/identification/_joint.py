"""One inertia fitted to several recordings of one body (``fit_inertia(..., joint=True)``)."""

from __future__ import annotations

import jax
import numpy as np

from .._pytree import replace
from ._layout import SEGMENT_PARAMS
from ._members import check_members
from ._problem import Problem, join_problems
from ._result import CONSISTENCY_ALPHA, FitResult
from ._solve import pack, solve_with_starts
from ._tails import f_sf

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
    y0 = np.concatenate([prob.y0, np.tile(prob.y0[:, -SEGMENT_PARAMS:], (1, pad))], 1)  # copies of the last p_s
    data = dict(prob.data, seg=seg, n_unused=prob.data["n_unused"] + SEGMENT_PARAMS * pad)
    rows = lambda a, fill: np.concatenate([a, np.full((pad,) + a.shape[1:], fill, a.dtype)])
    return prob._replace(
        y0=y0,
        data=data,
        sample_index=rows(prob.sample_index, 0),
        sample_valid=rows(prob.sample_valid, False),
    )


def _solve_joined(packed, options):
    """``(problem, result, starts, (r, J, row_owner))`` of one joint fit of the packed recordings.

    ``r``, ``J``: the whitened residuals and Jacobian at the solution; ``row_owner``:
    each residual row's recording (its index in ``packed``), -1 for padding (blank
    segments, padded intervals): its segments' valid data rows, and the joins
    inside it (6 rows each, after the data rows, in the order of the static joins).
    """
    prob = _pad_segments(join_problems(packed), segment_bucket(sum(p.segments for p in packed)))
    res, starts = solve_with_starts(prob, options)
    r, J = starts.pop("r"), starts.pop("J")
    seg = prob.data["seg"]
    S, K1 = seg.rw.shape[1], seg.rw.shape[-1]
    shape = (S, len(prob.sensors), K1, 3)
    owner = np.full(S, -1)  # blank segments: -1
    owner[: sum(p.segments for p in packed)] = np.repeat(np.arange(len(packed)), [p.segments for p in packed])
    valid = np.concatenate([seg.first[0][:, None], seg.mask[0]], 1) > 0  # (S, K+1)
    data_owner = np.where(np.broadcast_to(valid[:, None, :, None], shape), owner[:, None, None, None], -1)
    joins = prob.static["joins"]
    join_owner = np.repeat(owner[np.asarray(joins, int)], 6) if joins else np.zeros(0, int)
    return prob, res, starts, (r, J, np.concatenate([data_owner.reshape(-1), join_owner]))


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
    prob, res, starts, (r_all, J_all, row_owner) = _solve_joined(packed, options)
    # per member: its segments' data rows (segment-major, as the model lays them out)
    seg = prob.data["seg"]
    S, K1 = seg.rw.shape[1], seg.rw.shape[-1]
    blocks = len(prob.sensors)
    r = r_all[: S * blocks * K1 * 3].reshape(S, blocks, K1, 3)
    valid = np.concatenate([seg.first[0][:, None], seg.mask[0]], 1)  # (S, K+1)
    n_all = 3 * blocks * valid.sum()
    n_shared = prob.static["layout"].shared
    tests = _left_out_tests(r_all, J_all, row_owner, len(packed))
    if len(packed) >= 3 and not np.isnan([x[0] for x in tests]).all():
        worst = int(np.nanargmax([x[0] for x in tests]))
        if tests[worst][1] < CONSISTENCY_ALPHA:
            # it disagrees: the others are tested around a fit without it, where the linearisation
            # holds (around the joint fit its pull on the shared parameters is no small step)
            rest = [p for k, p in enumerate(packed) if k != worst]
            clean = _left_out_tests(*_solve_joined(rest, options)[3], len(rest))
            tests = clean[:worst] + [tests[worst]] + clean[worst:]
        else:
            tests = _left_out_tests(r_all, J_all, row_owner, len(packed), drop=worst)
    stats = {}
    start = 0
    for k, (i, p) in enumerate(zip(good, packed)):
        part = slice(start, start + p.segments)
        start += p.segments
        chi2 = float(np.sum(r[part] ** 2))
        n_i = 3 * blocks * float(valid[part].sum())
        # its share of the joint fit's degrees of freedom: they add up to the fit's
        dof = n_i - (6 - float(p.data["n_unused"][0])) - n_shared * n_i / n_all
        stats[i] = (*tests[k][:1], chi2, float(dof), tests[k][1])
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


def _left_out_tests(
    r: np.ndarray, J: np.ndarray, row_owner: np.ndarray, members: int, drop: int | None = None
) -> list[tuple[float, float]]:
    """Per member ``(rms, p-value)``: how far its rows lie from a fit of the other members.

    In the joint fit's linearisation at its solution (whitened residuals ``r``,
    Jacobian ``J``; ``row_owner``: each row's member, -1 for padding), the least
    squares minimum ``χ²_R`` of a set ``R`` of members' rows has ``ν_R`` degrees of
    freedom (rows less the rank of their columns). Member ``i`` against a
    reference set ``R`` (``i`` not in it): ``T = χ²_{R+i} - χ²_R`` on
    ``ν_T = ν_{R+i} - ν_R``, its residuals as ``R``'s parameters predict them with
    its own start state refitted; for a member like ``R``'s,
    ``F = (T / ν_T) / (χ²_R / ν_R)`` follows ``F(ν_T, ν_R)`` (independent sums of
    squares of one noise level): ``p = P(F(ν_T, ν_R) ≥ F)``, ``rms = √F``.
    ``R``: every other member, less ``drop`` (for the members other than ``drop``).

    Each member's rows touch the shared columns ``A_k`` and columns of its own
    ``B_k`` (its segments' start states) only, so its own parameters are eliminated
    once per member: with ``Q_k`` an orthonormal basis of ``B_k``'s range and
    ``P_k = I - Q_k Q_kᵀ``, ``χ²_R = Σ_R ‖P_k r_k‖² - hᵀ H⁺ h`` with
    ``H = Σ_R (P_k A_k)ᵀ P_k A_k``, ``h = Σ_R (P_k A_k)ᵀ P_k r_k``, and
    ``ν_R = Σ_R (rows_k - rank B_k) - rank H``: the least squares of the stacked rows,
    at a cost linear in the number of members instead of a dense solve per test
    (1,000x less at 82 throws).
    """
    J = np.asarray(J, np.float64)
    r = np.asarray(r, np.float64)
    rows = row_owner >= 0
    norms = np.linalg.norm(J[rows], axis=0)
    used = norms > 0
    Jn = J[:, used] / norms[used]  # unit columns: the rank decision does not depend on units
    owned = [row_owner == k for k in range(members)]
    touched = np.stack([np.any(Jn[mine] != 0, axis=0) for mine in owned])  # (members, columns)
    shared = touched.sum(0) > 1  # a column one member alone touches is that member's own
    # singular values below 1e-10 of ‖Jn‖_F = √columns (≥ its largest one) count as zero
    tol = 1e-10 * np.sqrt(Jn.shape[1])
    parts = []
    for k, mine in enumerate(owned):
        A, B, b = Jn[mine][:, shared], Jn[mine][:, touched[k] & ~shared], r[mine]
        U, sv, _ = np.linalg.svd(B, full_matrices=False)
        Q = U[:, sv > tol]
        A, b = A - Q @ (Q.T @ A), b - Q @ (Q.T @ b)
        parts.append((A.T @ A, A.T @ b, float(b @ b), float(mine.sum() - Q.shape[1])))

    def least_squares(members_in: list[int]) -> tuple[float, float]:
        H = sum(parts[k][0] for k in members_in)
        h = sum(parts[k][1] for k in members_in)
        w, V = np.linalg.eigh(H)
        keep = w > tol**2
        z = V[:, keep].T @ h
        chi2 = sum(parts[k][2] for k in members_in) - float(np.sum(z**2 / w[keep]))
        return chi2, sum(parts[k][3] for k in members_in) - float(keep.sum())

    def test(k: int) -> tuple[float, float]:
        reference = [j for j in range(members) if j != k and (drop is None or k == drop or j != drop)]
        if not reference:
            return np.nan, np.nan
        chi2_r, dof_r = least_squares(reference)
        chi2, dof = least_squares([*reference, k])
        dof_t = dof - dof_r
        if not (dof_t > 0 and dof_r > 0 and chi2_r > 0):
            return np.nan, np.nan
        f = max(chi2 - chi2_r, 0.0) / dof_t / (chi2_r / dof_r)
        return float(np.sqrt(f)), float(f_sf(dof_t, dof_r, f))

    return [test(k) for k in range(members)]
