"""``python -m rbjax fit --plot``: measured gyro rates against the fitted model's, and the residuals, per throw."""

from __future__ import annotations

from ._cli_common import CLIError

__all__ = ["fitted_rates", "plot_throw_fits", "verdict"]


def verdict(res, k: int | None = None) -> str:
    """One line: whether fit ``k`` of ``res`` (``None``: unbatched) can be trusted, why not, and its diagnosis.

    The reasons are ``FitResult.converged``'s parts: the solver's tolerances not met, a moment's σ
    beyond 0.1 tr I (``well_determined``), the fit on the edge of physical inertias
    (``on_boundary``); then
    ``FitResult.diagnosis`` (the misfit against the noise, its correlation length, its likely cause).
    """
    import numpy as np

    def get(name):
        v = np.asarray(getattr(res, name))
        return v if k is None else v[k]

    if bool(get("failed")):
        return "not fitted"
    diagnosis = res.diagnosis if k is None else res.diagnosis[k]
    p = f"white-noise χ² p-value {float(get('consistency_pvalue')):.2g}"
    if bool(get("converged")):
        return f"converged, trusted ({p}); {diagnosis}"
    why = []
    if not bool(get("solver_converged")):
        why.append(f"solver stopped short of its tolerances ({int(get('iterations'))} steps)")
    if not bool(get("well_determined")):
        why.append("moments not determined (σ > 0.1 tr I)")
    if bool(get("on_boundary")):
        why.append("on the edge of physical inertias (I1 + I2 = I3)")
    return "NOT trusted: " + ("; ".join(why) or "see the diagnostics") + f" ({p}); {diagnosis}"


def plot_throw_fits(path: str, throws, res, joint=None):
    """A PNG with two panels per throw: measured gyro (dots) against the fitted model's rates (lines), and
    their difference, measured - fitted (rad/s, body frame), against time. Each throw's title says whether
    its fit converged and, if not, why (:func:`verdict`); the figure's title says it for ``joint``, the
    joint fit, when given. Returns the (closed) figure."""
    import textwrap

    import numpy as np

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as e:
        raise CLIError("--plot needs matplotlib: pip install 'rbjax[demo]'") from e
    n = len(throws)
    fig, axes = plt.subplots(
        2 * n, 1, figsize=(8, 3.8 * n), squeeze=False, gridspec_kw=dict(height_ratios=[2.6, 1.2] * n)
    )
    for k, rec in enumerate(throws):
        ax, ax_r = axes[2 * k, 0], axes[2 * k + 1, 0]
        t = rec.times
        for j, c in enumerate("xyz"):
            ax.plot(t, rec.gyro[:, j], ".", ms=3, color=f"C{j}", label=f"ω{c} measured")
        if not bool(np.asarray(res.failed)[k]):
            I = np.asarray(res.inertia)[k]
            w0 = np.asarray(res.initial_angular_velocity)[k]
            # a result saved before per-axis drag and the gyro scale existed has neither
            per_axis = np.asarray(getattr(res, "drag_per_axis", np.full((len(throws), 2, 3), np.nan)))[k]
            drag = per_axis if np.any(np.isfinite(per_axis)) else np.asarray(res.drag)[k]
            scale = 1 + np.asarray(getattr(res, "gyro_scale", np.zeros(len(throws))))[k]  # reading (1 + s) ω + b
            w = scale * fitted_rates(I, w0, t, drag) + np.asarray(res.gyro_bias)[k]
            for j, c in enumerate("xyz"):
                ax.plot(t, w[:, j], "-", lw=1, color=f"C{j}", label=f"ω{c} fitted")
                ax_r.plot(t, rec.gyro[:, j] - w[:, j], ".-", ms=2, lw=0.5, color=f"C{j}")
        ax_r.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel("ω (rad/s, body)")
        ax_r.set_ylabel("residual (rad/s)")
        ax.set_title(textwrap.fill(f"throw {k + 1}: {verdict(res, k)}", 110), fontsize=9)
    axes[-1, 0].set_xlabel("t (s)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    line = 0.3 / (3.8 * n)  # one line of text, as a fraction of the figure's height
    title = 0.0
    if joint is not None:
        text = textwrap.fill(f"joint fit of {n} throws: {verdict(joint)}", 95)
        fig.suptitle(text, fontsize=10, y=1.0, va="top")
        title = line * (1 + text.count("\n"))
    # above the panels, hiding no data
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 1 - title), ncol=6, fontsize=7)
    fig.tight_layout(rect=(0, 0, 1, 1 - title - 1.2 * line))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return fig


def fitted_rates(I, w0, t, drag, per_sample: int = 20):
    """Body rates ``(T, 3)`` at the sample times ``t`` of the fitted model, from ``ω(t[0]) = w0`` (body).

    Torque-free, the exact solution (:func:`rbjax.torque_free`). With a fitted
    drag torque ``-(c1 + c2|ω|) ω``, which has the same form in the body and the
    world frame, :func:`rbjax.simulate` with ``"rk4"`` at ``per_sample`` steps per
    mean sample interval, interpolated linearly onto ``t``. ``I`` and ``drag``
    are given relative to ``tr I`` (a gyro-only fit fixes no scale), so the body is ``I / tr I``.
    ``drag``: ``(2,)`` ``(c1, c2)`` (``FitResult.drag``) or ``(2, 3)`` per body axis
    (``FitResult.drag_per_axis``), which the isotropic force models take only when its three
    columns are equal (``ValueError`` otherwise).
    """
    import numpy as np

    import rbjax as rb

    drag = np.nan_to_num(np.asarray(drag, float))  # NaN: no drag was fitted
    if drag.shape == (2, 3):  # FitResult.drag_per_axis: the same about every axis, or no force model has it
        if np.any(drag != drag[:, :1]):
            raise ValueError(
                "the fitted drag differs between the body axes (fit_inertia(..., drag_axes=True)); "
                "rb.LinearDrag and rb.QuadraticDrag are isotropic and cannot model it: plot a fit "
                "without drag_axes, or simulate -(c1_a + c2_a|w|) w_a with your own force"
            )
        drag = drag[:, 0]
    state = rb.State.create(rb.Body(1.0, I / np.trace(I)), angular_velocity=w0)  # identity: body = world at t[0]
    c1, c2 = drag
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
