"""``gcpcal thermal``: daily thermal drift of a staring camera's installation (seed 002 section 3.3)."""

from __future__ import annotations

import click

from calibrate.actions.thermal import thermal_experiment
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import echo_json, json_option, out_dir_option

__all__ = ["command"]


@click.command("thermal")
@out_dir_option()
@click.option("--days", type=float, default=5.0, show_default=True, help="Length of the simulated series.")
@click.option("--interval-min", type=float, default=30.0, show_default=True, help="Minutes between epochs.")
@click.option("--holdout-days", type=float, default=1.0, show_default=True, help="Last days kept out of the fit.")
@click.option("--max-order", type=int, default=4, show_default=True, help="Largest harmonic order tried by CV.")
@click.option("--points", "n_points", type=int, default=400, show_default=True, help="Control points per epoch.")
@click.option("--sigma-px", type=float, default=0.1, show_default=True, help="Image noise of the control points.")
@click.option("--temperature", is_flag=True, help="Offer the temperature telemetry as a regressor.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed of the simulation.")
@json_option
@click.pass_context
def command(ctx, out_dir, days, interval_min, holdout_days, max_order, n_points, sigma_px, temperature, seed, as_json):
    """Simulate and model the daily thermal drift of a staring camera's installation angles.

    Writes OUT/thermal.json, OUT/thermal_angles.png (seed 002 figure 11) and
    OUT/thermal_positioning.png.
    """
    with stage_progress(ctx, "gcpcal thermal", as_json):
        doc = thermal_experiment(out_dir, days=days, interval_min=interval_min, holdout_days=holdout_days,
                                 max_order=max_order, n_points=n_points, sigma_px=sigma_px, temperature=temperature,
                                 seed=seed)
    pos = doc["positioning_heldout_rms_px"]
    if as_json:
        echo_json({"orders": doc["model"]["orders"], "positioning_heldout_rms_px": pos,
                   "positioning_reduction": doc["positioning_reduction"]})
    else:
        click.echo(f"orders {doc['model']['orders']} ({doc['model']['cv_scheme']}); held-out positioning: "
                   f"constant {pos['constant']:.3f} px, predicted {pos['predicted']:.3f} px "
                   f"({100 * doc['positioning_reduction']:.1f} % less)")
