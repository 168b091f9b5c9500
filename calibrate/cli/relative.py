"""``gcpcal relative``: band-to-band relative calibration (seed 003 section 2.2.2)."""

from __future__ import annotations

import click

from calibrate.actions.relative import relative_calibration_stage
from calibrate.cli._errors import EXIT_FAILED
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import (add_options, dem_options, echo_json, echo_warnings, exit_with_status, json_option,
                                   out_dir_option)
from calibrate.config import ROBUST_LOSSES, CalibrationOptions
from sensor_models.errors import InputError

__all__ = ["command", "parse_rows", "parse_window"]


def parse_window(text: str):
    """The ``--window`` value: ``"64"`` -> 64, ``"64x32"`` -> ``(64, 32)``.

    Parameters
    ----------
    text : str
        ``N`` or ``ROWSxCOLS``; even sizes >= 16 pixels.

    Returns
    -------
    int or (int, int)
        Window size, pixels.
    """
    try:
        sizes = [int(v) for v in text.lower().split("x")]
        if len(sizes) not in (1, 2) or any(v < 16 or v % 2 for v in sizes):
            raise ValueError
    except ValueError:
        raise InputError(f"--window must be N or ROWSxCOLS, even numbers of pixels >= 16, got {text!r}") from None
    return sizes[0] if len(sizes) == 1 else tuple(sizes)


def parse_rows(text: str | None):
    """The ``--rows`` value: ``"R0:R1"`` -> ``(R0, R1)``; None stays None.

    Parameters
    ----------
    text : str or None
        Two line numbers separated by a colon.

    Returns
    -------
    (int, int) or None
    """
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
@add_options(dem_options)
@out_dir_option()
@click.option("--reference-band", help="Reference band (default: the calibrated model's reference band).")
@click.option("--window", "window_text", default="64", show_default=True, metavar="N|RxC",
              help="Phase-correlation window, pixels: N (square) or ROWSxCOLS (e.g. 64x32); even, >= 16.")
@click.option("--spacing", type=click.IntRange(min=1), default=24, show_default=True, help="Window grid spacing, pixels.")
@click.option("--rows", "rows_text", metavar="R0:R1", help="Reference-band lines holding the tie points (default: all).")
@click.option("--robust", type=click.Choice(ROBUST_LOSSES), default=CalibrationOptions.robust, show_default=True,
              help="Robust loss of the interior solve.")
@json_option
@click.pass_context
def command(ctx, scene_path, calibration, dem_path, dem_datum, geoid, out_dir, reference_band, window_text, spacing,
            rows_text, robust, as_json):
    """Calibrate every band of SCENE against its calibrated reference band (band-to-band).

    Tie points between the reference band and each other band (dense phase correlation in raw
    scene geometry) become control points through the calibrated reference band and the DEM;
    each band's interior (directional angles per CCD) is then solved with the exterior held.
    Writes OUT/manifest.json (every band calibrated), OUT/relative.json (tie statistics before
    and after, per band and CCD) and OUT/relative.summary.json.

    SCENE is the push-broom scene (a gcpcal manifest with its rasters); an RPC has no
    bands to calibrate against each other.
    """
    if dem_path is None:
        raise InputError("--dem is required: the reference band's tie points are localized on the terrain")
    with stage_progress(ctx, "gcpcal relative", as_json) as progress:
        summary = relative_calibration_stage(
            scene_path, calibration, dem_path, out_dir, reference_band=reference_band, dem_datum=dem_datum,
            geoid=geoid, window_px=parse_window(window_text), spacing_px=spacing, rows=parse_rows(rows_text),
            options=CalibrationOptions(robust=robust), progress=progress.message)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
    else:
        for band, s in summary["bands"].items():
            before, after = s["tie_rms_px"]["before"], s["tie_rms_px"]["after"]
            rms = f"tie RMS {before:.3f} -> {after:.4f} px" if before is not None and after is not None else "no fit"
            click.echo(f"{band}: {'ok' if s['success'] else 'FAILED'}, {s['ties']} tie points of {s['windows']} "
                       f"windows, {rms}")
        click.echo(f"wrote {out_dir}/manifest.json, relative.json in {summary['seconds']:.1f} s")
    if not summary["success"]:
        failed = [band for band, s in summary["bands"].items() if not s["success"]]
        exit_with_status(ctx, EXIT_FAILED, (f"band(s) {', '.join(failed)} not calibrated: " if failed else "")
                         + str(summary.get("message") or ""))
