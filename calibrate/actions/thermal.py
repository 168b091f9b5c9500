"""Stage action of ``gcpcal thermal``: daily thermal drift of a staring camera's installation.

Seed 002 section 3.3: simulates a series of epochs with an injected drift
(:class:`calibrate.schemes.thermal_simulation.ThermalDrift`), solves the exterior at each epoch from virtual control
points, fits the angles against the time of day on all days but the last ``holdout_days``,
predicts the held-out epochs and compares the positioning error of a constant installation with
the predicted one. Writes ``OUT/thermal.json``, ``OUT/thermal_angles.png`` (seed 002 figure 11)
and ``OUT/thermal_positioning.png`` through a temporary folder.
"""

from __future__ import annotations

import json
import time

import numpy as np

from calibrate.actions._io import check_output_folder, staged_folder
from calibrate.actions._provenance import with_provenance
from sensor_models.errors import InputError

__all__ = ["thermal_experiment"]


def thermal_experiment(out_dir, *, days: float = 5.0, interval_min: float = 30.0, holdout_days: float = 1.0,
                       max_order: int = 4, n_points: int = 400, sigma_px: float = 0.1, temperature: bool = False,
                       seed: int = 0) -> dict:
    """Simulate, fit, predict, evaluate; write ``thermal.json`` and the two PNG figures.

    Parameters
    ----------
    out_dir : str or Path
        Output folder (created when missing).
    days : float
        Length of the simulated series, days.
    interval_min : float
        Minutes between epochs.
    holdout_days : float
        Last days kept out of the fit (``0 < holdout_days < days``).
    max_order : int
        Largest harmonic order tried by cross-validation.
    n_points : int
        Virtual control points per epoch.
    sigma_px : float
        Image noise of the control points, pixels.
    temperature : bool
        Offer the temperature telemetry as a regressor.
    seed : int
        Seed of the simulation's noise.

    Returns
    -------
    dict
        The document written to ``thermal.json``.
    """
    from calibrate._json import json_safe
    from calibrate.schemes.thermal import ARCSEC, DAY_S, evaluate_positioning
    from calibrate.schemes.thermal_figures import plot_positioning, plot_thermal_angles
    from calibrate.schemes.thermal_model import ThermalModel
    from calibrate.schemes.thermal_simulation import ThermalDrift, simulate_thermal_series
    from sensor_models.models.synthetic import example_geo_staring_model

    if not (days > holdout_days > 0 and interval_min > 0):
        raise InputError("needs days > holdout_days > 0 and interval_min > 0", field="days")
    check_output_folder(out_dir)  # before any work
    t_start = time.perf_counter()
    lab = example_geo_staring_model()
    drift = ThermalDrift()
    times = np.arange(0.0, days * DAY_S, interval_min * 60.0)
    series = simulate_thermal_series(lab, times, drift, n_points=n_points, sigma_px=sigma_px, seed=seed)
    train = times < (days - holdout_days) * DAY_S
    temps = series.temperatures
    model = ThermalModel.fit(times[train], series.angles[train], series.sigma[train],
                             temps[train] if temperature else None, max_order=max_order)
    predicted = model.predict(times, temps if temperature else None)
    constant = series.angles[train].mean(axis=0)
    test = ~train
    errors = evaluate_positioning(lab, series.true_angles[test], {
        "constant": constant, "predicted": predicted[test], "epoch_fit": series.angles[test]})
    curve_rms = np.sqrt(np.mean((predicted - series.smooth_angles) ** 2, axis=0)) / ARCSEC
    reduction = 1.0 - errors["predicted_rms_px"] / errors["constant_rms_px"]
    doc = {
        "format_version": 1,
        "inputs": {"days": days, "interval_min": interval_min, "holdout_days": holdout_days, "max_order": max_order,
                   "n_points": n_points, "sigma_px": sigma_px, "temperature": temperature, "seed": seed},
        "n_epochs": int(times.size),
        "n_train": int(train.sum()),
        "model": model.to_dict(),
        "per_epoch_recovery_arcsec": dict(zip(("roll", "pitch", "yaw"), series.recovery_arcsec())),
        "curve_vs_injected_rms_arcsec": dict(zip(("roll", "pitch", "yaw"), curve_rms)),
        "positioning_heldout_rms_px": {k: errors[f"{k}_rms_px"] for k in ("constant", "predicted", "epoch_fit")},
        "positioning_reduction": reduction,
        "figures": ["thermal_angles.png", "thermal_positioning.png"],
    }
    with staged_folder(out_dir, ".thermal-") as tmp:
        plot_thermal_angles(tmp / "thermal_angles.png", series, model, train=train, drift=drift)
        plot_positioning(tmp / "thermal_positioning.png", times[test], errors)
        doc["timings"] = {"command_s": time.perf_counter() - t_start}
        text = json.dumps(json_safe(with_provenance(doc)), indent=1, allow_nan=False) + "\n"
        (tmp / "thermal.json").write_text(text, encoding="utf-8")
    return doc
