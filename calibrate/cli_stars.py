"""``gcpcal stars`` and ``gcpcal simulate geo-stars``: star-track calibration (seed 000).

Registered by :mod:`calibrate.cli` (module attributes ``command`` and ``simulate_command``).

``gcpcal simulate geo-stars --out DIR [--seed N] [--frames N] [--interval S] [--mag-limit M]``
    renders a star-field sequence (:func:`sensor_models.simulate.geo_stars.simulate_geo_stars`).

``gcpcal stars FRAMES --out DIR [--manifest M] [--catalog hipparcos] [--scheme ...]``
    ``FRAMES`` is a frame list (``frames.json``, format in :func:`calibrate.stars.read_frame_list`)
    or the folder holding it; the frame times come from it and the model from the manifest it
    names (``--manifest`` overrides). Writes ``DIR/stars.json`` (tracks, calibration, accuracy,
    track points), ``DIR/manifest.json`` (the calibrated model of frame 0) and ``DIR/report.html``
    with ``DIR/figures/*.png`` (:func:`calibrate.report.stars.write_star_report`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from sensor_models.errors import InputError

__all__ = ["command", "simulate_command", "stars_sequence"]


def stars_sequence(frames_path, out_dir, *, manifest=None, catalog="hipparcos", mag_limit=10.5,
                   scheme="exterior-interior", centroid="iwc", versus_points=(10, 15, 20, 25), seed=0) -> dict:
    """Stage action of ``gcpcal stars``: read, calibrate, write ``stars.json`` and the manifest."""
    from calibrate.config import StarOptions
    from calibrate.stars import process_frames, read_frame_list
    from sensor_models.atomic import atomic_write_text
    from sensor_models.readers.geo_manifest import read_geo_manifest, write_geo_manifest

    t0 = time.perf_counter()
    frames, seconds, listed = read_frame_list(frames_path)
    manifest = Path(manifest) if manifest else listed
    if manifest is None:
        raise InputError("the frame list names no manifest; give --manifest", path=str(frames_path))
    lab = read_geo_manifest(manifest)
    options = StarOptions(catalog=catalog, mag_limit=mag_limit, scheme=scheme, centroid=centroid, seed=seed)
    result = process_frames(frames, seconds, lab, options=options, versus_points=versus_points)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = result.to_dict(points=True)
    doc["inputs"] = {"frames": str(frames_path), "manifest": str(manifest), "catalog": str(catalog),
                     "mag_limit": mag_limit}
    if result.success:
        write_geo_manifest(result.model, out_dir / "manifest.json")
        doc["calibrated_manifest"] = "manifest.json"
    doc["timings"]["command_s"] = time.perf_counter() - t0
    atomic_write_text(out_dir / "stars.json", json.dumps(doc, indent=1, allow_nan=False) + "\n")
    from calibrate.report.stars import write_star_report

    write_star_report(out_dir, doc, result=result)
    return doc


@click.command("stars")
@click.argument("frames_path", metavar="FRAMES", type=click.Path())
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--manifest", type=click.Path(dir_okay=False), help="LAB manifest (default: the one the frame list names).")
@click.option("--catalog", default="hipparcos", show_default=True, help="Star catalogue.")
@click.option("--mag-limit", type=float, default=10.5, show_default=True, help="Faintest catalogue magnitude.")
@click.option("--scheme", type=click.Choice(["exterior-interior", "exterior", "joint"]), default="exterior-interior",
              show_default=True, help="Seed 000's stepwise scheme, the exterior alone, or joint.")
@click.option("--centroid", type=click.Choice(["iwc", "gaussian", "windowed"]), default="iwc", show_default=True)
@click.option("--seed", type=int, default=0, show_default=True, help="Choice of the held-out points.")
@click.option("--json", "as_json", is_flag=True, help="Print the accuracy summary as JSON.")
@click.pass_context
def command(ctx, frames_path, out_dir, manifest, catalog, mag_limit, scheme, centroid, seed, as_json):
    """Calibrate a staring camera from star tracks in FRAMES (a frames.json or its folder)."""
    doc = stars_sequence(frames_path, out_dir, manifest=manifest, catalog=catalog, mag_limit=mag_limit,
                         scheme=scheme, centroid=centroid, seed=seed)
    acc = doc["accuracy"]
    if as_json:
        click.echo(json.dumps({"success": doc["success"], "message": doc["message"], "accuracy": acc}))
    elif acc:
        b, a = acc["before"], acc["after"]
        click.echo(f"{out_dir}: {doc['message']}; {doc['frames']['n_tracks']} tracks; held-out RA/DE mean "
                   f"{b['ra']['mean_px']:.3f}/{b['de']['mean_px']:.3f} px -> mean |error| "
                   f"{a['ra']['mean_abs_px']:.3f}/{a['de']['mean_abs_px']:.3f} px, 2-sigma "
                   f"{a['ra'].get('two_sigma_px', float('nan')):.3f}/{a['de'].get('two_sigma_px', float('nan')):.3f} px")
    else:
        click.echo(f"{out_dir}: {doc['message']}")
    if not doc["success"]:
        ctx.exit(3)


@click.command("geo-stars")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--frames", "n_frames", type=int, default=120, show_default=True, help="Number of frames.")
@click.option("--interval", "frame_interval_s", type=float, default=10.0, show_default=True, help="Seconds between frames.")
@click.option("--mag-limit", type=float, default=10.0, show_default=True)
def simulate_command(out_dir, seed, n_frames, frame_interval_s, mag_limit):
    """Render a star-field sequence of a geostationary staring camera (seed 000) with its truth."""
    from sensor_models.simulate.geo_stars import simulate_geo_stars

    s = simulate_geo_stars(out_dir, seed=seed, n_frames=n_frames, frame_interval_s=frame_interval_s,
                           mag_limit=mag_limit)
    click.echo(f"{out_dir}: {s['frames']} frames, {s['distinct_stars']} stars "
               f"({s['stars_per_frame']['mean']:.1f} per frame), initial error RA/DE "
               f"{s['initial_error_centre_px']['ra']:.2f}/{s['initial_error_centre_px']['de']:.2f} px "
               f"at the centre")
