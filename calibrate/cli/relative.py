"""``gcpcal relative``: band-to-band relative calibration (seed 003 section 2.2.2)."""

from __future__ import annotations

import click

from calibrate.actions.relative import relative_calibration_stage
from calibrate.cli._errors import EXIT_FAILED, EXIT_PARTIAL
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import (accept_product_disagreement_option, add_options, allow_implausible_option,
                                   echo_json, echo_warnings, exit_with_status, json_option, out_dir_option,
                                   required_dem_options, window_option)
from calibrate.config import ATTITUDE_MODES, ROBUST_LOSSES, CalibrationOptions
from sensor_models.errors import InputError

__all__ = ["command", "parse_rows"]


def _parallax_line(p: dict) -> str:
    """One line on the parallax path: ties and GCPs that entered, the basis chosen, or why not."""
    if not p.get("used"):
        return f"parallax: not used ({p.get('reason')})"
    sel = p["selected"]
    basis = "static" if sel["kind"] == "static" else f"{sel['kind']} {sel['n_terms']}"
    if sel["kind"] == "spline":
        basis += f" segments ({sel['knot_spacing_s']:.3f} s knots)"
    return f"parallax: {p['ties']} tie points and {p['gcps']} GCPs entered; attitude {basis}"


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
@allow_implausible_option
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--calibration", "calibration", required=True, type=click.Path(),
              help="Calibrated manifest.json of the reference band (as written by 'gcpcal calibrate'), or its folder.")
@add_options(required_dem_options)
@out_dir_option()
@click.option("--reference-band", help="Reference band (default: the calibrated model's reference band).")
@window_option(64)
@click.option("--spacing", type=click.IntRange(min=1), default=24, show_default=True,
              help="Window grid spacing, pixels (denser than match's: each band's interior is fitted per CCD from "
                   "these tie points alone).")
@click.option("--rows", "rows_text", metavar="R0:R1", help="Reference-band lines holding the tie points (default: all).")
@click.option("--robust", type=click.Choice(ROBUST_LOSSES), default=CalibrationOptions.robust, show_default=True,
              help="Robust loss of the interior solve.")
@click.option("--parallax/--no-parallax", default=True, show_default=True,
              help="Estimate the time-varying attitude from the reference band's GCPs and the band-to-band tie points "
                   "together (band parallax) and write it into the manifest.")
@click.option("--gcps", "gcps_path", type=click.Path(dir_okay=False),
              help="GCP table of the reference band for --parallax (default: the gcp_file named by the "
                   "calibration.json beside the calibrated manifest).")
@click.option("--attitude", type=click.Choice(ATTITUDE_MODES), default=CalibrationOptions.attitude, show_default=True,
              help="Candidate bases of the parallax path, chosen by BIC (static: no parallax).")
@accept_product_disagreement_option
@json_option
@click.pass_context
def command(ctx, scene_path, calibration, dem_path, dem_datum, geoid, out_dir, reference_band, window, spacing,
            rows_text, robust, parallax, gcps_path, attitude, as_json, self_check):
    """Calibrate every band of SCENE against its calibrated reference band (band-to-band).

    Tie points between the reference band and each other band (dense phase correlation in raw
    scene geometry) become control points through the calibrated reference band and the DEM;
    each band's interior (directional angles per CCD) is then solved with the exterior held.
    With --parallax (the default) the tie points, which see the ground at other line times
    than the reference band, enter one least squares with the reference band's GCPs for the
    time-varying attitude correction (jitter above what the GCPs resolve), alternated with the
    interiors. Writes OUT/manifest.json (every band calibrated, the attitude correction),
    OUT/relative.json (tie statistics before and after, per band and CCD; the parallax fit)
    and OUT/relative.summary.json.

    SCENE is the push-broom scene (a gcpcal manifest with its rasters); an RPC has no
    bands to calibrate against each other.
    """
    with stage_progress(ctx, "gcpcal relative", as_json) as progress:
        summary = relative_calibration_stage(
            scene_path, calibration, dem_path, out_dir, reference_band=reference_band, dem_datum=dem_datum,
            geoid=geoid, window_px=window, spacing_px=spacing, rows=parse_rows(rows_text),
            options=CalibrationOptions(robust=robust, attitude=attitude), parallax=parallax, gcps_path=gcps_path,
            progress=progress.message, self_check=self_check)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
    else:
        for band, s in summary["bands"].items():
            before, after = s["tie_rms_px"]["before"], s["tie_rms_px"]["after"]
            rms = f"tie RMS {before:.3f} -> {after:.4f} px" if before is not None and after is not None else "no fit"
            click.echo(f"{band}: {'ok' if s['success'] else 'FAILED'}, {s['ties']} tie points of {s['windows']} "
                       f"windows, {rms}")
        click.echo(_parallax_line(summary["parallax"]))
        click.echo(f"wrote {out_dir}/manifest.json, relative.json in {summary['seconds']:.1f} s")
    if not summary["success"]:
        failed = [band for band, s in summary["bands"].items() if not s["success"]]
        exit_with_status(ctx, EXIT_FAILED, (f"band(s) {', '.join(failed)} not calibrated: " if failed else "")
                         + str(summary.get("message") or ""))
    if summary.get("calibration_status") == "partial":  # the bands are registered, the model is not whole
        exit_with_status(ctx, EXIT_PARTIAL, str(summary.get("calibration_message") or "the calibration is partial"))
