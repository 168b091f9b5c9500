"""``gcpcal match``: GCPs of a scene against a reference orthoimage and a DEM."""

from __future__ import annotations

import click

from calibrate.actions.match import match_scene
from calibrate.config import MatchOptions
from gcpmatch.options import COARSE_SEARCHES, SIGMA_MODELS
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import (accept_product_disagreement_option, add_options, allow_implausible_option,
                                   dom_options, echo_json, echo_warnings, json_option, reference_sigma_option,
                                   required_dem_options, threads_option, window_option)
from sensor_models.maps.dom_inputs import ASSUMED_REFERENCE_SIGMA_M

__all__ = ["CHANGE_MODES", "change_options", "command"]

#: ``--change``: the matcher's handling of a reference that shows the ground differently
CHANGE_MODES = ("off", "auto", "on")


def change_options(mode: str) -> dict:
    """Keywords of :class:`~gcpmatch.options.MatchOptions` for ``--change`` ``mode``.

    ``off``: none (the matcher as it is); ``on``: ``spectral_spread_sigma`` and
    ``max_spectral_spread`` 1 (each window's spread in its sigma; windows beyond their noise
    rejected); ``auto``: ``detect_change`` (the scene's windows decide between the two).
    """
    if mode == "on":
        return {"spectral_spread_sigma": True, "max_spectral_spread": 1.0}
    if mode == "auto":
        return {"detect_change": True}
    return {}


@click.command("match")
@allow_implausible_option
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@dom_options
@add_options(required_dem_options)
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False), help="GCP table (CSV); a .summary.json goes beside it.")
@click.option("--gpkg", "gpkg_path", type=click.Path(dir_okay=False), help="Also write the GCPs as a GeoPackage layer.")
@click.option("--geotiff", "geotiff_path", type=click.Path(dir_okay=False), help="Also write the GCPs into a GeoTIFF (GDAL GCPs).")
@click.option("--band", help="Band to match (default: the reference band).")
@click.option("--image", type=click.Path(dir_okay=False), help="Scene raster (default: the raster SCENE lists, names or has beside it).")
@click.option("--mask", "mask_path", type=click.Path(dir_okay=False), help="Cloud/invalid mask raster in scene geometry (nonzero = invalid).")
@click.option("--check-fraction", type=click.FloatRange(0.0, 0.9), default=MatchOptions.check_fraction, show_default=True,
              help="Share of matches kept as independent check points.")
@window_option(MatchOptions.window_px, square=True)
@click.option("--spacing", type=click.IntRange(min=1), default=MatchOptions.spacing_px, show_default=True,
              help="Window grid spacing, pixels.")
@click.option("--max-offset", type=click.FloatRange(min=1.0), default=MatchOptions.max_offset_px, show_default=True,
              help="Largest expected model error, pixels.")
@click.option("--coarse-search", type=click.Choice(COARSE_SEARCHES), default=MatchOptions.coarse_search,
              show_default=True,
              help="Coarse SIFT search: 'adaptive' (full resolution, FLANN), 'fast' (SIFT on the images averaged "
                   "down 1.5 times, matches measured at full resolution, where trusted) or 'exhaustive' (brute "
                   "force); docs/matching.md.")
@click.option("--backend", type=click.Choice(["cpu", "gpu"]), default=MatchOptions.backend, show_default=True,
              help="Phase correlation on CPU (numpy) or GPU (torch).")
@click.option("--sigma-model", type=click.Choice(SIGMA_MODELS), default=MatchOptions.sigma_model, show_default=True,
              help="Per-GCP sigma: 'window' (from each window's correlation score plus the reference's accuracy) "
                   "or 'ccd' (the spread of each CCD's matches); docs/matching.md.")
@reference_sigma_option("the DOM's, as its producer states it (default: the DOM's GEOLOCATION_RMSE_M or "
                        "GEOMETRIC_RMSE_X/Y tags, or GEOMETRIC_RMSE_MODEL_X/Y of a Landsat MTL beside it, else an "
                        f"assumed {ASSUMED_REFERENCE_SIGMA_M:.1f} m); used by --sigma-model window.")
@click.option("--change", type=click.Choice(CHANGE_MODES), default="off", show_default=True,
              help="A reference of another band, season or sensor: 'on' adds each window's spectral spread to its "
                   "sigma and rejects windows whose shift depends on the weighting beyond their noise; 'auto' "
                   "turns that on when most windows of the scene disagree with themselves (the summary's "
                   "'change' says which); docs/matching.md, 'Matching under real change'.")
@threads_option("the reference chips, the phase correlation's batches of windows and OpenCV (SIFT)")
@accept_product_disagreement_option
@json_option
@click.pass_context
def command(ctx, scene_path, dom_path, dem_path, dem_datum, geoid, out_path, gpkg_path, geotiff_path, band, image,
            mask_path, check_fraction, window, spacing, max_offset, coarse_search, backend, sigma_model, change,
            reference_sigma_m, threads, as_json, self_check):
    """Extract GCPs of SCENE against a DOM and a DEM (coarse SIFT, dense phase correlation).

    SCENE is a gcpcal manifest, a model file (.geom, .RPB, _RPC.TXT, .DIM, .XML) with its raster
    beside it or named in it, or a raster carrying an RPC (GeoTIFF tags, or a .RPB, _RPC.TXT or
    .geom beside it); a crop with a pixel geotransform crops the model (docs/inputs.md).
    """
    options = MatchOptions(window_px=window, spacing_px=spacing, max_offset_px=max_offset,
                           check_fraction=check_fraction, backend=backend, sigma_model=sigma_model,
                           coarse_search=coarse_search, reference_sigma_m=reference_sigma_m, threads=threads,
                           **change_options(change))
    with stage_progress(ctx, "gcpcal match: windows", as_json) as progress:
        summary = match_scene(scene_path, dom_path=dom_path, dem_path=dem_path, out_path=out_path, geoid=geoid,
                              dem_datum=dem_datum, band=band, image=image, mask_path=mask_path, gpkg_path=gpkg_path,
                              geotiff_path=geotiff_path, options=options, progress=progress.message,
                              self_check=self_check, progress_count=progress.count)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
        return
    _print_summary(out_path, summary)


def _percent(value, what) -> str:
    return f"{what} unknown" if value is None else f"{100 * value:.0f} % {what}"


def _print_summary(out_path, summary) -> None:
    """The totals, then per CCD: DEM and DOM coverage, clouds, texture and the cause of an empty CCD."""
    click.echo(f"{out_path}: {summary['gcps']} GCPs + {summary['check_points']} check points from "
               f"{summary['windows']} windows ({100 * summary['usable_fraction']:.0f} % usable, "
               f"{_percent(summary['cloud_fraction'], 'cloud')}) in {summary['timings']['total_s']:.1f} s")
    for key in ("note", "cloud_note", "dom_note", "reference_note"):
        if summary.get(key):
            click.echo(f"  note: {summary[key]}")
    change = summary.get("change")
    if change:
        ratio = change["median_spread_ratio"]
        ratio = "unknown" if ratio is None else f"{ratio:.2f}"
        click.echo(f"  change: median spectral spread over its noise {ratio}; "
                   + ("the reference disagrees with the scene: change options on" if change["detected"]
                      else "the reference agrees with the scene: default matcher"))
    acc = summary.get("reference_accuracy")
    if acc and not acc["assumed"]:
        click.echo(f"  reference accuracy: {acc['east_m']:g} m east, {acc['north_m']:g} m north (1 sigma, from "
                   f"{acc['source']})")
    for c in summary.get("per_ccd", []):
        dom = c.get("dom_coverage")
        line = (f"  {'CCD ' + c['ccd'] if c['ccd'] else 'image'}: {c['gcps']} GCPs; DEM {100 * c.get('dem_coverage', 0.0):.0f} %, "
                f"DOM {'-' if dom is None else f'{100 * dom:.0f} %'}, {_percent(c.get('cloud_fraction'), 'cloud')}, "
                f"{100 * c.get('no_texture_fraction', 0.0):.0f} % no texture")
        click.echo(line + (f"; cause: {c['cause']}" if c.get("cause") else ""))
