"""``gcpcal relative``: band-to-band relative calibration (seed 003 section 2.2.2).

Registered on the ``gcpcal`` group by :mod:`calibrate.cli` (module attribute ``command``). This
module imports nothing from :mod:`calibrate.cli` at import time (that module imports this one
while it loads), so the DEM options are spelled out here, as in ``calibrate.cli.dem_options``.
"""

from __future__ import annotations

import json

import click

from sensor_models.errors import InputError

__all__ = ["command", "parse_rows", "parse_window"]


def parse_window(text: str):
    """``"64"`` -> 64, ``"64x32"`` -> ``(64, 32)``; even sizes >= 16, else an InputError naming ``--window``."""
    try:
        sizes = [int(v) for v in text.lower().split("x")]
        if len(sizes) not in (1, 2) or any(v < 16 or v % 2 for v in sizes):
            raise ValueError
    except ValueError:
        raise InputError(f"--window must be N or ROWSxCOLS, even numbers of pixels >= 16, got {text!r}") from None
    return sizes[0] if len(sizes) == 1 else tuple(sizes)


def parse_rows(text: str | None):
    """``"R0:R1"`` -> ``(R0, R1)`` (None stays None); an InputError names ``--rows`` otherwise."""
    if text is None:
        return None
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        r0, r1 = int(parts[0]), int(parts[1])
    except ValueError:
        raise InputError(f"--rows must be R0:R1 (two line numbers), got {text!r}") from None
    return r0, r1


@click.command("relative")
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--calibration", "calibration", required=True, type=click.Path(),
              help="Calibrated manifest.json of the reference band (as written by 'gcpcal calibrate'), or its folder.")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM raster (any CRS rasterio reads).")
@click.option("--dem-datum", type=click.Choice(["ellipsoid", "egm96"]), default=None,
              help="Vertical datum of the DEM heights when the file does not declare it.")
@click.option("--geoid", type=click.Path(dir_okay=False), help="Geoid grid (e.g. egm96_15.gtx) for egm96 heights.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--reference-band", help="Reference band (default: the calibrated model's reference band).")
@click.option("--window", "window_text", default="64", show_default=True, metavar="N|RxC",
              help="Phase-correlation window, pixels: N (square) or ROWSxCOLS (e.g. 64x32); even, >= 16.")
@click.option("--spacing", type=click.IntRange(min=1), default=24, show_default=True, help="Window grid spacing, pixels.")
@click.option("--rows", "rows_text", metavar="R0:R1", help="Reference-band lines holding the tie points (default: all).")
@click.option("--robust", type=click.Choice(["huber", "cauchy", "none"]), default="cauchy", show_default=True,
              help="Robust loss of the interior solve.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.pass_context
def command(ctx, scene_path, calibration, dem_path, dem_datum, geoid, out_dir, reference_band, window_text, spacing,
            rows_text, robust, as_json):
    """Calibrate every band of SCENE against its calibrated reference band (band-to-band).

    Tie points between the reference band and each other band (dense phase correlation in raw
    scene geometry) become control points through the calibrated reference band and the DEM;
    each band's interior (directional angles per CCD) is then solved with the exterior held.
    Writes OUT/manifest.json (every band calibrated), OUT/relative.json (tie statistics before
    and after, per band and CCD) and OUT/relative.summary.json.
    """
    from calibrate.cli import _json_default
    from calibrate.relative import relative_scene

    if dem_path is None:
        raise InputError("--dem is required: the reference band's tie points are localized on the terrain")
    window = parse_window(window_text)
    rows = parse_rows(rows_text)
    quiet = (ctx.obj or {}).get("quiet", False) or as_json
    summary = relative_scene(scene_path, calibration, dem_path, out_dir, reference_band=reference_band,
                             dem_datum=dem_datum, geoid=geoid, window_px=window, spacing_px=spacing, rows=rows,
                             robust=robust, progress=None if quiet else (lambda m: click.echo(m, err=True)))
    if as_json:
        click.echo(json.dumps(summary, default=_json_default))
    else:
        for band, s in summary["bands"].items():
            before, after = s["tie_rms_px"]["before"], s["tie_rms_px"]["after"]
            rms = f"tie RMS {before:.3f} -> {after:.4f} px" if before is not None and after is not None else "no fit"
            click.echo(f"{band}: {'ok' if s['success'] else 'FAILED'}, {s['ties']} tie points of {s['windows']} "
                       f"windows, {rms}")
        click.echo(f"wrote {out_dir}/manifest.json, relative.json in {summary['seconds']:.1f} s")
    if not summary["success"]:
        ctx.exit(3)
