"""``gcpcal calibrate``: calibrate a scene's model from a GCP table.

Exit codes follow the run's status (:mod:`calibrate.coverage`): 0 ``calibrated``, 4 ``partial``
(some CCD not calibrated or without check points; each is named with its reason), 3 ``failed``.
"""

from __future__ import annotations


import click

from calibrate.actions.calibrate import calibrate_scene
from calibrate.cli._errors import EXIT_FAILED, EXIT_OK, EXIT_PARTIAL
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import (accept_product_disagreement_option, allow_implausible_option, east_north_metres,
                                   echo_json, echo_warnings, exit_with_status, json_option, out_dir_option,
                                   reference_sigma_option)
from calibrate.config import ATTITUDE_MODES, CALIBRATION_SCHEMES, ROBUST_LOSSES, CalibrationOptions

__all__ = ["command"]

_EXIT_OF_STATUS = {"calibrated": EXIT_OK, "partial": EXIT_PARTIAL, "failed": EXIT_FAILED}


@click.command("calibrate")
@allow_implausible_option
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--gcps", "gcps_path", required=True, type=click.Path(dir_okay=False), help="GCP table (CSV, GeoPackage or GeoTIFF).")
@out_dir_option()
@click.option("--scheme", type=click.Choice(CALIBRATION_SCHEMES), default=CalibrationOptions.scheme, show_default=True,
              help="Which parameters, in which order (seed 002's schemes).")
@click.option("--robust", type=click.Choice(ROBUST_LOSSES), default=CalibrationOptions.robust, show_default=True,
              help="Robust loss.")
@click.option("--attitude", type=click.Choice(ATTITUDE_MODES), default=CalibrationOptions.attitude, show_default=True,
              help="Time-varying attitude correction (push-broom): none, drift, P-spline (smoothing by blocked cross-validation), or chosen by the data (docs/attitude.md).")
@reference_sigma_option("the reference the GCPs come from; its common shift enters the parameters' covariance "
                        "(default: reference_accuracy of the match summary beside the GCP table, else no such term).")
@click.option("--reference-field-m", "reference_field_m", metavar="RMS,LENGTH", default=None,
              help="Part of that error that is a smooth field: its rms per axis and correlation length, m (the rest "
                   "is one common shift; docs/calibration_outputs.md).")
@click.option("--band", help="Band of GCPs that name none (default: the reference band).")
@click.option("--image", type=click.Path(dir_okay=False), help="Raster the GCPs were measured in, when it is a crop of SCENE.")
@click.option("--no-report", is_flag=True, help="Skip report.html and its figures.")
@accept_product_disagreement_option
@json_option
@click.pass_context
def command(ctx, scene_path, gcps_path, out_dir, scheme, robust, attitude, reference_sigma_m, reference_field_m, band,
            image, no_report, as_json, self_check):
    """Calibrate SCENE's model from GCPs; write calibration.json, the calibrated model and report.html.

    SCENE is a gcpcal manifest, a model file (.geom, .RPB, _RPC.TXT, .DIM, .XML) with its raster
    beside it or named in it, or a raster carrying an RPC (GeoTIFF tags, or a .RPB, _RPC.TXT or
    .geom beside it); a crop with a pixel geotransform crops the model (docs/inputs.md).

    Exit 0: calibrated; 4: partial (CCDs not calibrated or not verified, named); 3: failed.
    """
    options = CalibrationOptions(scheme=scheme, robust=robust, attitude=attitude,
                                 reference_sigma_m=reference_sigma_m,
                                 reference_field_m=_pair(reference_field_m, "--reference-field-m"))
    with stage_progress(ctx, "gcpcal calibrate", as_json) as progress:
        summary = calibrate_scene(scene_path, gcps_path, out_dir, options=options, band=band, image=image,
                                  report=not no_report, progress=progress.message, self_check=self_check)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
    else:
        _print_summary(out_dir, summary)
    code = _EXIT_OF_STATUS[summary["status"]]
    if code != EXIT_OK:
        exit_with_status(ctx, code, summary.get("status_message") or summary["message"])


def _pair(text, hint):
    """``--reference-field-m RMS,LENGTH``: None or (rms, length) metres, length > 0."""
    value = east_north_metres(text, hint, sizes=(2,))
    if value is not None and value[1] <= 0.0:
        raise click.BadParameter(f"the correlation length must be > 0 m, got {text!r}", param_hint=hint)
    return value


def _over(used, n, which: str) -> str:
    """`` (over the 143 the input model projects)`` where an RMSE is over fewer check points than there are."""
    return "" if used is None or used == n else f" (over the {used} the {which} model projects into the image)"


def _print_summary(out_dir, summary) -> None:
    """The one-line outcome, the per-CCD coverage table and the CCDs that are not calibrated/verified."""
    before, after = summary["check_rmse_px"]["before"], summary["check_rmse_px"]["after"]
    n, used = summary["check_points"], summary.get("check_points_used") or {}
    checks = (f"check RMSE {before:.3f}{_over(used.get('before'), n, 'input')} -> "
              f"{after:.3f}{_over(used.get('after'), n, 'calibrated')} px on {n} check points"
              if before is not None else "no check points")
    state = {"calibrated": "calibrated", "partial": "PARTIAL", "failed": "FAILED"}[summary["status"]]
    vf = summary.get("variance_factor")
    vf_text = "" if vf is None else f"; variance factor {vf:.3g}"
    if vf is not None and summary.get("covariance_factor") is not None:
        vf_text += f" (covariance x {summary['covariance_factor']:.3g})"
    ref = summary.get("reference_accuracy") or {}
    if ref.get("east_m") is not None:
        vf_text += f"; reference term {ref['east_m']:.3g}/{ref['north_m']:.3g} m (E/N)"
    click.echo(f"{out_dir}: {state} ({summary['message']}); {checks}{vf_text}")
    att = summary.get("attitude")
    if att:
        sel = att["selected"]
        text = f"attitude ({att['mode']}): {sel['kind']}"
        if sel["kind"] != "static":
            text += f", {sel['n_terms']} terms ({sel['knot_spacing_s']:.3g} s apart)"
        if sel.get("edf") is not None:
            text += f", {sel['edf']:.1f} effective parameters"
        if sel.get("lambda") is not None:
            text += f", smoothing {sel['lambda']:.3g} ({sel['criterion']})"
        # a drift (or a static choice) has no oscillation: its "dominant sinusoid" is numerical noise
        peaks = [f"{a} {p['amplitude_urad']:.2g} urad at {p['frequency_hz']:.2g} Hz"
                 for a, p in (att.get("jitter") or {}).items()
                 if p and sel["kind"] == "spline" and p.get("amplitude_urad", 0.0) >= 1e-3]
        click.echo(text + (f"; dominant: {', '.join(peaks)}" if peaks else ""))
    rows = summary.get("coverage") or []
    if not rows:
        return
    header = ("band", "CCD", "GCPs", "checks", "along", "across", "calibrated", "verified", "check RMSE after")
    table = [header] + [(c["band"], c["ccd"], str(c["gcps"]), str(c["check_points"]),
                         f"{100 * c['spread_along']:.0f} %", f"{100 * c['spread_across']:.0f} %",
                         "yes" if c["calibrated"] else "NO", "yes" if c["verified"] else "NO",
                         _px((c.get("check_rmse_px") or {}).get("after"))) for c in rows]
    widths = [max(len(r[k]) for r in table) for k in range(len(header))]
    for r in table:
        click.echo("  " + "  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip())
    for c in rows:
        if not (c["calibrated"] and c["verified"]):
            name = ".".join(p for p in (c["band"], c["ccd"]) if p) or "image"
            click.echo(f"  {name}: {c['reason']}")


def _px(value) -> str:
    return "-" if value is None else f"{value:.3f} px"
