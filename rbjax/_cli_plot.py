"""``python -m rbjax fit --plot``: measured gyro rates against the fitted model's, one panel per throw."""

from __future__ import annotations

from ._cli_common import CLIError

__all__ = ["fitted_rates", "plot_throw_fits"]


def plot_throw_fits(path: str, throws, res) -> None:
    """A PNG with one panel per throw: measured gyro (dots) against the fitted model's rates (lines)."""
    import numpy as np

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as e:
        raise CLIError("--plot needs matplotlib: pip install 'rbjax[demo]'") from e
    n = len(throws)
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.6 * n), squeeze=False)
    for k, (rec, ax) in enumerate(zip(throws, axes[:, 0])):
        t = rec.times
        for j, c in enumerate("xyz"):
            ax.plot(t, rec.gyro[:, j], ".", ms=3, color=f"C{j}", label=f"ω{c} measured")
        if not bool(np.asarray(res.failed)[k]):
            I = np.asarray(res.inertia)[k]
            w0 = np.asarray(res.initial_angular_velocity)[k]
            w = fitted_rates(I, w0, t, np.asarray(res.drag)[k]) + np.asarray(res.gyro_bias)[k]
            for j, c in enumerate("xyz"):
                ax.plot(t, w[:, j], "-", lw=1, color=f"C{j}", label=f"ω{c} fitted")
        ax.set_ylabel("ω (rad/s, body)")
        ax.set_title(f"throw {k + 1}", fontsize=9)
    axes[-1, 0].set_xlabel("t (s)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=6, fontsize=7)  # above the panels, hiding no data
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / (2.6 * n)))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def fitted_rates(I, w0, t, drag, per_sample: int = 20):
    """Body rates ``(T, 3)`` at the sample times ``t`` of the fitted model, from ``ω(t[0]) = w0`` (body).

    Torque-free, the exact solution (:func:`rbjax.torque_free`). With a fitted
    drag torque ``-(c1 + c2|ω|) ω``, which has the same form in the body and the
    world frame, :func:`rbjax.simulate` with ``"rk4"`` at ``per_sample`` steps per
    mean sample interval, interpolated linearly onto ``t``. ``I`` and ``drag``
    are given relative to ``tr I`` (a gyro-only fit fixes no scale), so the body is ``I / tr I``.
    """
    import numpy as np

    import rbjax as rb

    state = rb.State.create(rb.Body(1.0, I / np.trace(I)), angular_velocity=w0)  # identity: body = world at t[0]
    c1, c2 = np.nan_to_num(np.asarray(drag, float))  # NaN: no drag was fitted
    if c1 == 0 and c2 == 0:
        traj = rb.torque_free(state, t - t[0])
        return np.asarray(rb.body_angular_velocity(traj))
    steps = per_sample * (len(t) - 1)
    dt = (t[-1] - t[0]) / steps
    forces = rb.LinearDrag(0.0, angular=c1) + rb.QuadraticDrag(0.0, angular=c2)
    traj = rb.simulate(state, forces, dt, steps, "rk4")
    grid = t[0] + dt * np.arange(steps + 1)
    w = np.asarray(rb.body_angular_velocity(traj))
    return np.stack([np.interp(t, grid, w[:, j]) for j in range(3)], axis=-1)
