"""``gcpcal simulate ...``: scenes with known truth (push-broom, validation series, geostationary)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from calibrate.actions.simulate import (PROFILE_NAMES, pushbroom_config, simulate_geo_earth_scene,
                                        simulate_geo_star_frames, simulate_pushbroom_scene,
                                        simulate_validation_series)
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import echo_json, echo_warnings, float_list, json_option, out_dir_option, threads_option

__all__ = ["command"]


@click.group("simulate")
def command():
    """Simulate scenes with known truth."""


@command.command("pushbroom")
@out_dir_option()
@click.option("--seed", type=click.IntRange(min=0), help="Random seed (overrides the configuration's).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="JSON configuration (any subset of the defaults).")
@click.option("--dom", "dom_path", type=click.Path(dir_okay=False), help="Reference orthoimage to render from (with --dem).")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM declaring its vertical datum (with --dom).")
@click.option("--geoid", type=click.Path(dir_okay=False), help="EGM96 grid for an orthometric DEM.")
@threads_option("rendering (each with one OpenCV thread)", "--workers")
@click.option("--print-config", is_flag=True, help="Print the effective configuration as JSON and exit.")
@click.option("--profile", type=click.Choice(PROFILE_NAMES), default="ideal", show_default=True,
              help="Error profile (docs/error_budget.md); realistic: --dom is the source radiance, no --dem.")
@click.option("--model", "model_path", type=click.Path(dir_okay=False),
              help="Render through this push-broom model (manifest, SPOT 1-5 .DIM, DIMAP v2 .XML) with the "
                   "configuration's known errors; manifest.json is the model as delivered (needs --dom, --dem).")
@click.option("--window", help="With --model: ROW0,COL0,ROWS,COLS of the model's pixels to render (default: all).")
@json_option
@click.pass_context
def pushbroom_command(ctx, out_dir, seed, config_path, dom_path, dem_path, geoid, threads, print_config, profile,
                      model_path, window, as_json):
    """Render a level-1A push-broom scene through a TRUE model; write the LAB manifest and truth.

    With --model the TRUE model is that model (or a --window of it) plus the configuration's
    errors.installation_deg, errors.focal_length_ratio and errors.attitude_drift_arcsec_s, and
    manifest.json is the model as delivered (docs/simulator.md).
    """
    cfg = pushbroom_config(config_path, seed)
    if print_config:
        click.echo(json.dumps(cfg.to_dict(), indent=1))
        return
    window = _window(window)
    with stage_progress(ctx, "gcpcal simulate pushbroom: rendering", as_json) as progress:
        summary = simulate_pushbroom_scene(out_dir, cfg, dom_path=dom_path, dem_path=dem_path, geoid=geoid,
                                           workers=threads or None, profile=profile, progress=progress.count,
                                           config_path=config_path, model_path=model_path, window=window)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
        return
    img = summary["image"]
    error = _lab_error_text(summary)
    if "source" in summary:  # --model: manifest.json is the given model as delivered
        error = error.replace("LAB model", "delivered model (manifest.json)")
    click.echo(
        f"{out_dir}: {img['n_rows']} x {img['n_cols']} px, {_count(len(img['bands']), 'band')}, "
        f"{_count(img['ccds'], 'CCD')}; "
        f"{error}; rendered in {summary['render_seconds']:.1f} s"
    )


@command.command("series")
@out_dir_option()
@click.option("--scenes", type=click.IntRange(min=1), default=10, show_default=True, help="Validation scenes.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Seed of the series' draws.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="Sensor configuration (JSON, as simulate pushbroom).")
@click.option("--clouds", default="0,0,0,0.3", show_default=True, help="Cloud covers cycled over the scenes.")
@click.option("--calibration-scene", is_flag=True, help="Also render a scene to calibrate the sensor on.")
@threads_option("rendering each scene", "--workers")
@json_option
@click.pass_context
def series_command(ctx, out_dir, scenes, seed, config_path, clouds, calibration_scene, threads, as_json):
    """Validation scenes of one sensor (dates, sites, attitude biases, clouds) and their sites file."""
    with stage_progress(ctx, f"gcpcal simulate series: {scenes} scene(s)", as_json):
        paths = simulate_validation_series(out_dir, scenes, seed=seed, config_path=config_path,
                                           cloud_fractions=tuple(float_list(clouds, "clouds")),
                                           calibration_scene=calibration_scene, workers=threads or None)
    if as_json:
        echo_json({"command": "simulate series", "scenes": [str(p) for p in paths],
                   "sites": str(Path(out_dir) / "sites.yaml")})
        return
    click.echo(f"{out_dir}: {len(paths)} scenes; sites file {Path(out_dir) / 'sites.yaml'}")


@command.command("geo-earth")
@out_dir_option()
@click.option("--seed", type=click.IntRange(min=0), help="Random seed (overrides the configuration's).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="JSON configuration (any subset of the defaults).")
@click.option("--dom", "dom_path", type=click.Path(dir_okay=False), help="Reference orthoimage (with --dem).")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM declaring its vertical datum (with --dom).")
@click.option("--geoid", type=click.Path(dir_okay=False), help="EGM96 grid for an orthometric DEM.")
@json_option
@click.pass_context
def geo_earth_command(ctx, out_dir, seed, config_path, dom_path, dem_path, geoid, as_json):
    """Render an Earth view of a geostationary staring camera through a TRUE model."""
    with stage_progress(ctx, "gcpcal simulate geo-earth: rendering", as_json):
        summary = simulate_geo_earth_scene(out_dir, seed=seed, config_path=config_path, dom_path=dom_path,
                                           dem_path=dem_path, geoid=geoid)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
        return
    img = summary["image"]
    click.echo(f"{out_dir}: {img['n_rows']} x {img['n_cols']} px staring frame; {_lab_error_text(summary)}")


@command.command("geo-stars")
@out_dir_option()
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed of the simulation.")
@click.option("--frames", "n_frames", type=int, default=120, show_default=True, help="Number of frames.")
@click.option("--interval", "frame_interval_s", type=float, default=10.0, show_default=True, help="Seconds between frames.")
@click.option("--mag-limit", type=float, default=10.0, show_default=True, help="Faintest star magnitude rendered.")
@json_option
@click.pass_context
def geo_stars_command(ctx, out_dir, seed, n_frames, frame_interval_s, mag_limit, as_json):
    """Render a star-field sequence of a geostationary staring camera (seed 000) with its truth."""
    with stage_progress(ctx, f"gcpcal simulate geo-stars: {n_frames} frames", as_json):
        s = simulate_geo_star_frames(out_dir, seed=seed, n_frames=n_frames, frame_interval_s=frame_interval_s,
                                     mag_limit=mag_limit)
    if as_json:
        echo_json(s)
        return
    click.echo(f"{out_dir}: {s['frames']} frames, {s['distinct_stars']} stars "
               f"({s['stars_per_frame']['mean']:.1f} per frame), initial error RA/DE "
               f"{s['initial_error_centre_px']['ra']:.2f}/{s['initial_error_centre_px']['de']:.2f} px "
               f"at the centre")


def _window(text):
    """``ROW0,COL0,ROWS,COLS`` as four integers (None when not given)."""
    if text is None:
        return None
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or min(values) < 0 or min(values[2:]) < 1:
        raise click.BadParameter(f"{text!r}: give ROW0,COL0,ROWS,COLS (integers, sizes >= 1)", param_hint="'--window'")
    return values


def _lab_error_text(summary) -> str:
    """``LAB model off by X px RMS (max Y)``, or why that is not measurable (every point outside the image)."""
    err = summary["lab_truth_error_px"]
    if err.get("rms") is None:
        return "LAB model error not measurable (it puts every compared point outside the image)"
    return f"LAB model off by {err['rms']:.1f} px RMS (max {err['max']:.1f})"


def _count(n: int, noun: str) -> str:
    """``"1 band"``, ``"4 bands"``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"
