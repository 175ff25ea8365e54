"""Several recordings fitted one by one: regular batches, ragged lists, bad members set aside.

:func:`fit_members` checks each recording alone (a bad one gets NaN results and
its reason), fits those of equal length as one batch and ragged ones padded to
shared shapes (:func:`_fit_padded`), and stacks the results with a leading axis.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .._pytree import new_unchecked
from . import _robust
from ._checks import check_options
from ._result import FitResult
from ._solve import NOT_JOINT, OPTION_NAMES, fit_regular, pack, sample_weights, solve

__all__ = ["PER_MEMBER_NDIM", "batch_members", "check_members", "fit_members", "is_ragged", "ragged_members"]


def is_ragged(times) -> bool:
    """``times`` given as a list (or tuple) of 1-D arrays: one per recording, lengths free."""
    return isinstance(times, (list, tuple)) and len(times) > 0 and all(np.ndim(t) == 1 for t in times)


PER_MEMBER_NDIM = {
    "orientations": 3,
    "body_rates": 3,
    "torques": 3,
    "body_torques": 3,
    "accelerations": 3,
    "rotor_momentum": 3,
}


def ragged_members(times, arrays):
    """Per-recording ``(times, arrays)`` of a ragged list; ``ValueError`` if the lists do not match."""
    n = len(times)
    for name, a in arrays.items():
        if a is not None and not (isinstance(a, (list, tuple)) and len(a) == n):
            raise ValueError(
                f"fit_inertia: times is a list of {n} recordings, so {name} must be a list of {n} arrays "
                f"(one per recording, each of its own length), got {type(a).__name__}"
                + (f" of length {len(a)}" if isinstance(a, (list, tuple)) else "")
            )
    return [(times[i], {k: None if a is None else a[i] for k, a in arrays.items()}) for i in range(n)]


def batch_members(times, arrays):
    """Per-recording ``(times, arrays)`` of a regular batch ``(N, T, ...)``; ``None`` for a single recording."""
    main = arrays["orientations"] if arrays["orientations"] is not None else arrays["body_rates"]
    if main is None or np.ndim(main) != 3:
        return None
    main = np.asarray(main)
    if np.ndim(times) != 1 or main.shape[1] != np.shape(times)[0]:
        return None
    for k, a in arrays.items():  # a shape that does not match the batch: the batch-wide message stands
        if a is not None and np.ndim(a) == PER_MEMBER_NDIM[k] and np.shape(a)[0] != main.shape[0]:
            return None
    out = []
    for i in range(main.shape[0]):
        member = {}
        for k, a in arrays.items():
            a = None if a is None else np.asarray(a)
            member[k] = a[i] if a is not None and a.ndim == PER_MEMBER_NDIM[k] else a
        out.append((times, member))
    return out


def fit_members(members, options) -> FitResult:
    """Fit recordings one by one (ragged) or as one batch (equal lengths), setting bad ones aside.

    Each member is checked first (:func:`._problem.prepare`, NumPy); one that raises
    ``ValueError`` (too little excitation, non-finite data, too few samples, ...) gets
    NaN results, ``failed = True`` and its reason in ``FitResult.member_errors``; the
    others are fitted. Members of equal length share one batched solve; ragged ones
    with the same number of segments are padded to the longest and fitted as one
    batch too (:func:`_fit_padded`). Arrays whose length varies (``residuals``, ``robust_weights``,
    ``outliers``) are padded with NaN (``False``) to the longest.
    """
    probs, errors, good = check_members(members, options)
    lengths = {np.shape(members[i][0])[0] for i in good}
    results: dict[int, FitResult] = {}
    if len(lengths) == 1 and all(members[i][0] is members[good[0]][0] for i in good):
        t = members[good[0]][0]
        stacked = {k: _stack_or_share([members[i][1].get(k) for i in good]) for k in PER_MEMBER_NDIM}
        batch = jax.tree.map(np.asarray, fit_regular(t, stacked, options))  # see _fit_padded
        for j, i in enumerate(good):
            results[i] = jax.tree.map(lambda a, j=j: a[j], batch)
    else:
        results = _fit_padded(members, probs, options)
    return _stack_results(results, len(members), errors)


def check_members(members, options):
    """``(problems, errors, good)``: each member packed alone, or its ``ValueError``'s message.

    Raises only when no member can be fitted (one message when all share it).
    """
    check_options(**{k: options[k] for k in OPTION_NAMES})  # an option's error is raised once
    errors: dict[int, str] = {}
    probs = {}
    for i, (t, arrays) in enumerate(members):
        try:
            probs[i] = pack(t, arrays, options)
        except ValueError as e:
            errors[i] = str(e)
    good = [i for i in range(len(members)) if i not in errors]
    if not good:
        reasons = list(dict.fromkeys(errors.values()))
        if len(reasons) == 1:  # the same for all (an option, a shared array): say it once
            raise ValueError(reasons[0])
        listed = list(errors.items())
        raise ValueError(
            f"fit_inertia: none of the {len(members)} recordings can be fitted: "
            + "; ".join(f"recording {i}: {msg}" for i, msg in listed[:5])
            + (f"; and {len(listed) - 5} more" if len(listed) > 5 else "")
        )
    return probs, errors, good


def _stack_or_share(values):
    """The members' arrays as one batch array; one shared array (the same object) passed as is."""
    if values[0] is None:
        return None
    if len(values) > 1 and all(v is values[0] for v in values):
        return values[0]
    return np.stack([np.asarray(v) for v in values])


def _fit_padded(members, probs, options) -> dict:
    """Fit ragged recordings in groups that share one compiled program: ``{index: FitResult}``.

    Recordings with the same number of segments (their default, or the option) are
    packed with the intervals per segment of the group's longest (the padding is
    masked: ``dt = 0``, no residuals) and the group's largest ``substeps``, stacked
    and fitted as one batch.
    """
    groups: dict = {}
    for i, prob in probs.items():
        groups.setdefault(prob.segments, []).append(i)
    out = {}
    for S, idx in groups.items():
        K = max(probs[i].data["seg"].dt.shape[-1] for i in idx)
        substeps = max(probs[i].static["substeps"] for i in idx)  # more steps only add accuracy
        packed = {
            i: pack(members[i][0], members[i][1], options, segments=S, substeps=substeps, pad_intervals=K) for i in idx
        }
        if len(idx) == 1:
            i = idx[0]
            out[i] = solve(packed[i], options)
            continue
        first = packed[idx[0]]
        batch = first._replace(
            y0=np.concatenate([packed[i].y0 for i in idx]),
            data=jax.tree.map(lambda *a: np.concatenate(a), *[packed[i].data for i in idx]),
            batched=True,
        )
        # members are taken apart on the host (_stack_results joins them there): indexing jax arrays
        # compiled a small program per field and shape, 14 per new ragged list
        res = jax.tree.map(np.asarray, solve(batch, options, per_sample=False))
        rw = res.robust_weights
        for j, i in enumerate(idx):
            one = jax.tree.map(lambda a, j=j: a[j], res)
            w, o = sample_weights(packed[i], rw[j], _robust.outlier_weight(options["loss"]))
            fields = {f.name: getattr(one, f.name) for f in dataclasses.fields(FitResult)}
            out[i] = new_unchecked(FitResult, **{**fields, "robust_weights": w, "outliers": o})
    return out


def _stack_results(results: dict, n: int, errors: dict) -> FitResult:
    """One batched :class:`FitResult` of ``n`` members; the failed ones NaN (False, 0), padded to the longest."""
    template = next(iter(results.values()))
    fields = {}
    for f in dataclasses.fields(FitResult):
        if f.metadata.get("static"):
            continue
        arrs = [None if i not in results else np.asarray(getattr(results[i], f.name)) for i in range(n)]
        ref = np.asarray(getattr(template, f.name))
        shape = tuple(max(a.shape[d] for a in arrs if a is not None) for d in range(ref.ndim))
        fill = np.nan if np.issubdtype(ref.dtype, np.floating) else (0 if ref.dtype != bool else False)
        out = np.full((n,) + shape, fill, ref.dtype)
        for i, a in enumerate(arrs):
            if a is not None:
                out[(i,) + tuple(slice(0, s) for s in a.shape)] = a
        fields[f.name] = jax.device_put(out)
    fields["failed"] = jax.device_put(np.array([i in errors for i in range(n)]))
    return new_unchecked(
        FitResult,
        **fields,
        scale_fixed=template.scale_fixed,
        segments=max(r.segments for r in results.values()),
        member_errors=tuple(f"recording {i}: {msg}" for i, msg in sorted(errors.items())),
        **NOT_JOINT,
    )
