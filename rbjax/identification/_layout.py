"""Where each block of the fit's parameter vector lies.

``y = (shared block, p_0, ..., p_{S-1})``: the shared block holds the inertia
parameters θ and the sensor and torque models that apply to the whole
recording (or to every recording of a joint fit), in the order of
:class:`Layout`'s fields; each segment ``s`` then has ``p_s = (δ_s, ω_s)`` (6).
:func:`._problem.prepare` builds the layout once; the model (:mod:`._model`)
and the result (:mod:`._result`) read their slices from it, so a new model
block is one new field here.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["Layout", "SEGMENT_PARAMS"]

SEGMENT_PARAMS = 6  # per segment: δ_s (3, rad) and ω_s (3, rad/s, body frame)


class Layout(NamedTuple):
    """Sizes of the shared blocks, in their order in ``y`` (0: not fitted). Hashable: a static option.

    ``inertia``: θ of the log-Cholesky map, 6, or 5 without torques (the gauge
    ``log L00 = 0``); ``gyro_bias``: ``b`` (3, rad/s); ``gyro_rotation``: ``ρ``
    (3, rad); ``accelerometer``: lever arm ``r`` (3, m) then bias ``b_a`` (3, m/s²);
    ``drag``: the damping torque's coefficients: 1 (``c₁``) or 2 (``c₁, c₂``) shared by the
    body axes, 3 (``c₁ₐ`` per body axis) or 6 (``c₁ₐ`` then ``c₂ₐ``); ``gyro_scale``: the gyro's
    common scale error ``s`` (1, dimensionless).
    """

    inertia: int
    gyro_bias: int = 0
    gyro_rotation: int = 0
    accelerometer: int = 0
    drag: int = 0
    gyro_scale: int = 0

    @property
    def drag_axes(self) -> bool:
        """Whether the drag coefficients are per body axis (3 or 6 of them)."""
        return self.drag >= 3

    def span(self, name: str) -> slice:
        """The slice of ``y`` (or of a segment's ``x_s = (θ-block, p_s)``) that holds block ``name``."""
        start = 0
        for field, size in zip(self._fields, self, strict=True):
            if field == name:
                return slice(start, start + size)
            start += size
        raise KeyError(name)

    @property
    def shared(self) -> int:
        """Length of the shared block (the parameters before the segments')."""
        return sum(self)

    def size(self, segments: int) -> int:
        """Length of ``y`` for ``segments`` segments."""
        return self.shared + SEGMENT_PARAMS * segments
