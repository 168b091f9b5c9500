"""``gcpcal thermal``: daily thermal drift of a staring camera's installation (seed 002 section 3.3).

Registered by :mod:`calibrate.cli` (module attribute ``command``).

``gcpcal thermal --out DIR [--days 5] [--interval-min 30] [--holdout-days 1] [--max-order 4]
[--points 400] [--sigma-px 0.1] [--temperature] [--seed 0]``
    simulates a series of epochs with an injected drift (:class:`calibrate.schemes.thermal.ThermalDrift`),
    solves the exterior at each epoch from virtual control points, fits the angles against the
    time of day on all days but the last ``--holdout-days``, predicts the held-out epochs and
    compares the positioning error of a constant installation with the predicted one. Writes
    ``DIR/thermal.json``, ``DIR/thermal_angles.png`` (seed 002 figure 11) and
    ``DIR/thermal_positioning.png``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import click
import numpy as np

from sensor_models.errors import InputError

__all__ = ["command", "thermal_experiment"]


def thermal_experiment(out_dir, *, days: float = 5.0, interval_min: float = 30.0, holdout_days: float = 1.0,
                       max_order: int = 4, n_points: int = 400, sigma_px: float = 0.1, temperature: bool = False,
                       seed: int = 0) -> dict:
    """Stage action of ``gcpcal thermal``: simulate, fit, predict, evaluate, write JSON and PNGs."""
    from calibrate._json import json_safe
    from calibrate.schemes.thermal import (ARCSEC, DAY_S, ThermalDrift, ThermalModel, evaluate_positioning,
                                   plot_positioning, plot_thermal_angles, simulate_thermal_series)
    from sensor_models.atomic import atomic_write_text
    from sensor_models.geo_staring import example_geo_staring_model

    if not (days > holdout_days > 0 and interval_min > 0):
        raise InputError("needs days > holdout_days > 0 and interval_min > 0", field="days")
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
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plot_thermal_angles(out_dir / "thermal_angles.png", series, model, train=train, drift=drift)
    plot_positioning(out_dir / "thermal_positioning.png", times[test], errors)
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
        "timings": {"command_s": time.perf_counter() - t_start},
    }
    atomic_write_text(out_dir / "thermal.json", json.dumps(json_safe(doc), indent=1, allow_nan=False) + "\n")
    return doc


@click.command("thermal")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--days", type=float, default=5.0, show_default=True, help="Length of the simulated series.")
@click.option("--interval-min", type=float, default=30.0, show_default=True, help="Minutes between epochs.")
@click.option("--holdout-days", type=float, default=1.0, show_default=True, help="Last days kept out of the fit.")
@click.option("--max-order", type=int, default=4, show_default=True, help="Largest harmonic order tried by CV.")
@click.option("--points", "n_points", type=int, default=400, show_default=True, help="Control points per epoch.")
@click.option("--sigma-px", type=float, default=0.1, show_default=True, help="Image noise of the control points.")
@click.option("--temperature", is_flag=True, help="Offer the temperature telemetry as a regressor.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def command(out_dir, days, interval_min, holdout_days, max_order, n_points, sigma_px, temperature, seed, as_json):
    """Simulate and model the daily thermal drift of a staring camera's installation angles."""
    doc = thermal_experiment(out_dir, days=days, interval_min=interval_min, holdout_days=holdout_days,
                             max_order=max_order, n_points=n_points, sigma_px=sigma_px, temperature=temperature,
                             seed=seed)
    pos = doc["positioning_heldout_rms_px"]
    if as_json:
        click.echo(json.dumps({"orders": doc["model"]["orders"], "positioning_heldout_rms_px": pos,
                               "positioning_reduction": doc["positioning_reduction"]}))
    else:
        click.echo(f"orders {doc['model']['orders']} ({doc['model']['cv_scheme']}); held-out positioning: "
                   f"constant {pos['constant']:.3f} px, predicted {pos['predicted']:.3f} px "
                   f"({100 * doc['positioning_reduction']:.1f} % less)")
