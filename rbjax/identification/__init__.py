"""Inertia identification from recorded rotational motion (:func:`fit_inertia`).

One concept per private module, so the simulator's core stays small:

* :mod:`._checks`: data and option checks, before tracing;
* :mod:`._linear`: the linear least-squares start and the identifiability check;
* :mod:`._problem`: noise levels, segment defaults, recordings packed into segments;
* :mod:`._sensors`: sensor models (gyro frame, accelerometer lever arm);
* :mod:`._robust`: robust losses by iteratively reweighted least squares;
* :mod:`._model`: the multiple-shooting residual model and its Jacobian (traced);
* :mod:`._flow`: the model's rk4 on ``(q, L)`` with tangents, in structure of arrays;
* :mod:`._solver`: trust-region Levenberg–Marquardt with MINPACK's stop;
* :mod:`._queue`: a batch of solves as a work queue, each member stopping on its own;
* :mod:`._result`: :class:`FitResult`, the covariance and the diagnostics;
* :mod:`._tails`: χ² and F tail probabilities (NumPy) for the consistency tests;
* :mod:`._solve`: one packed problem through the compiled solver (one program per shape);
* :mod:`._members`: several recordings fitted one by one (batches, ragged lists, bad ones set aside);
* :mod:`._joint`: one inertia fitted to several recordings (`joint=True`), padded to segment buckets;
* :mod:`._fit`: the entry point :func:`fit_inertia`;
* :mod:`._recording_data`: :class:`Recording` and its readers (rbjax's table, phyphox exports);
* :mod:`._throws`: :func:`find_throws`, the free flights of a recording with throws and catches.

The public names are re-exported by :mod:`rbjax`.
"""

from ._fit import fit_inertia as fit_inertia
from ._linear import fit_inertia_linear as fit_inertia_linear
from ._recording_data import Recording as Recording
from ._result import FitResult as FitResult
from ._throws import find_throws as find_throws
from ._throws import plot_throws as plot_throws

__all__ = ["FitResult", "Recording", "find_throws", "fit_inertia", "fit_inertia_linear", "plot_throws"]
