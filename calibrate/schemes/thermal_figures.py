"""Figures of the thermal study: installation angles against time (seed 002 figure 11), positioning.

:func:`plot_thermal_angles` draws each installation angle's per-epoch solutions, the fitted
curve of a :class:`calibrate.schemes.thermal_model.ThermalModel` and its residuals;
:func:`plot_positioning` the positioning error over the frame per epoch of a constant and a
predicted installation (:func:`calibrate.schemes.thermal.evaluate_positioning`). PNG files,
drawn with matplotlib's Agg canvas.
"""

from __future__ import annotations

import numpy as np

from calibrate.schemes.thermal import ARCSEC, AXES
from calibrate.schemes.thermal_model import ThermalModel
from calibrate.schemes.thermal_simulation import ThermalDrift, ThermalSeries

__all__ = ["plot_positioning", "plot_thermal_angles"]


def _figure(width_in, height_in):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def plot_thermal_angles(path, series: ThermalSeries, model: ThermalModel, *, train=None, drift: ThermalDrift | None = None):
    """Seed 002 figure 11: each installation angle against time, fitted curve and residuals.

    Left column: per-epoch solutions (error bars) of the training and held-out epochs, the
    fitted/predicted curve and (with ``drift``) the injected smooth truth, arcsec against
    hours. Right column: per-epoch solution minus curve. Writes a PNG at ``path``.

    Parameters
    ----------
    path : path
        PNG file to write.
    series : ThermalSeries
        Per-epoch solutions.
    model : ThermalModel
        Fitted time model.
    train : array_like of bool, shape (N,), optional
        Epochs used in the fit (the others are drawn as held out); default all.
    drift : ThermalDrift, optional
        Injected drift (its smooth part is drawn).

    Returns
    -------
    path
        ``path``.
    """
    t = series.times_s
    train = np.ones(t.size, dtype=bool) if train is None else np.asarray(train, dtype=bool)
    hours = t / 3600.0
    dense = np.linspace(t[0], t[-1], max(400, 8 * t.size))
    temps_dense = None
    if np.any(model.use_temperature):
        temps_dense = np.interp(dense, t, series.temperatures)
    curve = model.predict(dense, temps_dense)
    at_epochs = model.predict(t, series.temperatures if np.any(model.use_temperature) else None)
    fig = _figure(12.0, 8.0)
    axes = fig.subplots(3, 2, sharex=True, gridspec_kw={"width_ratios": [2.2, 1.0]})
    for j, name in enumerate(AXES):
        ax, axr = axes[j]
        ax.errorbar(hours[train], series.angles[train, j] / ARCSEC, yerr=series.sigma[train, j] / ARCSEC,
                    fmt=".", ms=3, lw=0.6, color="tab:blue", label="per-epoch exterior (fit)")
        if (~train).any():
            ax.errorbar(hours[~train], series.angles[~train, j] / ARCSEC, yerr=series.sigma[~train, j] / ARCSEC,
                        fmt=".", ms=3, lw=0.6, color="tab:orange", label="per-epoch exterior (held out)")
        if drift is not None:
            ax.plot(dense / 3600.0, drift.smooth_angles(dense)[:, j] / ARCSEC, color="k", lw=0.8, ls="--",
                    label="injected")
        ax.plot(dense / 3600.0, curve[:, j] / ARCSEC, color="tab:red", lw=1.2,
                label=f"model (order {model.orders[j]}{', +T' if model.use_temperature[j] else ''})")
        ax.set_ylabel(f"{name} (arcsec)")
        ax.grid(alpha=0.3)
        res = (series.angles[:, j] - at_epochs[:, j]) / ARCSEC
        axr.plot(hours[train], res[train], ".", ms=3, color="tab:blue")
        if (~train).any():
            axr.plot(hours[~train], res[~train], ".", ms=3, color="tab:orange")
        axr.axhline(0.0, color="k", lw=0.6)
        axr.set_ylabel("residual (arcsec)")
        axr.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel("time (h)")
    axes[-1, 1].set_xlabel("time (h)")
    fig.suptitle("Installation angles against time (seed 002 fig. 11)")
    fig.tight_layout()
    fig.savefig(path)
    return path


def plot_positioning(path, times_s, errors: dict, *, names=("constant", "predicted")):
    """Positioning error over the frame per epoch (log scale), one line per candidate. PNG.

    Parameters
    ----------
    path : path
        PNG file to write.
    times_s : array_like, shape (N,)
        Epochs, seconds.
    errors : dict of str to array_like, shape (N,)
        Positioning error per candidate model, pixels.
    names : sequence of str
        Candidates drawn, keys of ``errors``.

    Returns
    -------
    path
        ``path``.
    """
    fig = _figure(9.0, 3.8)
    ax = fig.add_subplot(1, 1, 1)
    for name in names:
        ax.semilogy(np.asarray(times_s) / 3600.0, errors[name], ".-", ms=3, lw=0.7,
                    label=f"{name}: RMS {errors[f'{name}_rms_px']:.3f} px")
    ax.set_xlabel("time (h)")
    ax.set_ylabel("positioning error over the frame (px)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    return path
