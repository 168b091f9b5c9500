"""``gcpcal experiment``: a seed's experiment under a named error profile, paper beside ours."""

from __future__ import annotations

import click

from calibrate.pipelines.experiment import experiment_stage
from calibrate.cli.options import echo_json, json_option, out_dir_option
from calibrate.experiments.registry import EXPERIMENTS, PROFILE_CHOICES

__all__ = ["command"]


@click.command("experiment")
@click.argument("seed", type=click.Choice(sorted(EXPERIMENTS)))
@click.option("--profile", type=click.Choice(PROFILE_CHOICES), default="ideal", show_default=True,
              help="Error profile: ideal (the unit-test simulator), realistic, or the seed's paper-* setting.")
@out_dir_option()
@click.option("--quick", is_flag=True, help="Reduced run (under about a minute): fewer frames, points and trials.")
@click.option("--source", type=click.Path(dir_okay=False),
              help="Experiment 003, realistic profile: the scene's source radiance raster (e.g. a Sentinel-2 "
                   "band); default: the procedural texture.")
@click.option("--frames", type=click.IntRange(min=30),
              help="Experiment 000: frames per session, 10 s apart (default 120, 30 with --quick; paper-000 "
                   "with 160 gives over 400 tracks from its 20 sessions, the paper's scale).")
@json_option
def command(seed, profile, out_dir, quick, source, frames, as_json):
    """Run seed SEED's experiment (000 stars, 002 staring schemes + thermal, 003 push-broom, 004 OALR).

    Writes OUT/experiment.json (the paper's tables beside ours, headline figures, the profile with
    its sources), OUT/sensitivity/*.json and *.png (accuracy against each error magnitude) and
    OUT/report.html. Each seed takes ideal, realistic and its own paper-* profile.
    """
    doc = experiment_stage(seed, out_dir, profile=profile, quick=quick, source=source, frames=frames)
    if as_json:
        echo_json({"seed": seed, "profile": profile, "quick": quick, "headline": doc["headline"]})
        return
    click.echo(f"experiment {seed} ({profile}{', quick' if quick else ''}): {doc['seconds']:.1f} s -> {out_dir}")
    for key, value in doc["headline"].items():
        click.echo(f"  {key}: {value:.4g}" if isinstance(value, float) else f"  {key}: {value}")
