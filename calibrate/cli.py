"""The ``gcpcal`` command line: one click group, one subcommand per job.

Every subcommand turns user mistakes (:class:`~sensor_models.errors.GcpcalError`) into a
one-line message on stderr and exit code 1; click's usage errors exit with 2. Library code
never calls ``sys.exit``; only :func:`main` does.
"""

from __future__ import annotations

import csv
import json
import logging
import sys
import time
from pathlib import Path

import click
import numpy as np

from calibrate._json import json_default
from sensor_models import __version__
from sensor_models.atomic import atomic_write_text
from sensor_models.errors import GcpcalError, InputError

log = logging.getLogger("gcpcal")


# ---------------------------------------------------------------- shared helpers
def write_summary(path: Path, summary: dict) -> Path:
    """Write a stage's JSON summary atomically and return its path."""
    atomic_write_text(Path(path), json.dumps(summary, indent=2, default=_json_default) + "\n")
    return Path(path)


_json_default = json_default


def _float_list(text: str, what: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in text.split(",") if v.strip() != ""], dtype=np.float64)
    except ValueError:
        raise InputError(f"--{what} must be comma-separated numbers, got {text!r}") from None


def read_points_csv(path: Path, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Read numeric ``columns`` from a CSV with a header; errors name the file, row and column."""
    path = Path(path)
    try:
        fh = path.open(newline="", encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None
    with fh:
        reader = csv.DictReader(fh)
        header = reader.fieldnames or []
        missing = [c for c in columns if c not in header]
        if missing:
            raise InputError(f"missing column(s) {', '.join(missing)} (header: {','.join(header)})", path=str(path))
        values = {c: [] for c in columns}
        for line, rec in enumerate(reader, start=2):
            for c in columns:
                try:
                    v = float(rec[c])
                except (TypeError, ValueError):
                    raise InputError(f"row {line}: column '{c}' is not a number: {rec[c]!r}", path=str(path)) from None
                if not np.isfinite(v):
                    raise InputError(f"row {line}: column '{c}' is not finite", path=str(path))
                values[c].append(v)
    if not values[columns[0]]:
        raise InputError("holds no data rows", path=str(path))
    return {c: np.asarray(v) for c, v in values.items()}


def open_dem(dem_path, datum, geoid):
    """Open a DEM for the CLI (the datum must be declared when the file does not say)."""
    from sensor_models.terrain import Dem

    return Dem.open(dem_path, vertical_datum=datum, geoid=geoid)


dem_options = [
    click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM raster (any CRS rasterio reads)."),
    click.option(
        "--dem-datum",
        type=click.Choice(["ellipsoid", "egm96"]),
        default=None,
        help="Vertical datum of the DEM heights when the file does not declare it.",
    ),
    click.option("--geoid", type=click.Path(dir_okay=False), help="Geoid grid (e.g. egm96_15.gtx) for egm96 heights."),
]


def add_options(options):
    def wrap(func):
        for opt in reversed(options):
            func = opt(func)
        return func

    return wrap


# ---------------------------------------------------------------- the group
@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="gcpcal")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors.")
@click.pass_context
def cli(ctx, verbose, quiet):
    """gcpcal: on-orbit geometric calibration of satellite cameras."""
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    ctx.ensure_object(dict)
    ctx.obj["quiet"] = quiet


@cli.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--rows", help="Comma-separated rows (direct localization).")
@click.option("--cols", help="Comma-separated columns (direct localization).")
@click.option("--lon", help="Comma-separated longitudes, degrees (inverse localization).")
@click.option("--lat", help="Comma-separated latitudes, degrees (inverse localization).")
@click.option("--h", "h_text", help="Comma-separated ellipsoidal heights, m (inverse localization).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), help="CSV with row,col (direct) or lon,lat,h (--inverse).")
@click.option("--inverse", is_flag=True, help="Ground -> image (with --csv).")
@click.option("--height", type=float, help="Ellipsoidal height of the ground for direct localization, m.")
@add_options(dem_options)
@click.option("--band", help="Band (multi-band models; default: the reference band).")
@click.option("--out", "out_path", type=click.Path(dir_okay=False), help="Write the results as CSV (plus a .summary.json).")
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON.")
@click.pass_context
def localize(ctx, model_path, rows, cols, lon, lat, h_text, csv_path, inverse, height, dem_path, dem_datum, geoid, band, out_path, as_json):
    """Localize points through MODEL, image -> ground or ground -> image.

    Direct: --rows/--cols (or --csv with row,col) and --height or --dem. Inverse: --lon/--lat/--h
    (or --csv with lon,lat,h and --inverse). Image coordinates put the first pixel's centre at
    (0.5, 0.5); heights are metres above the WGS84 ellipsoid.
    """
    from sensor_models import open_model

    t0 = time.perf_counter()
    direct_given = rows is not None or cols is not None
    inverse_given = lon is not None or lat is not None or h_text is not None
    if csv_path and (direct_given or inverse_given):
        raise click.UsageError("give points either on the command line or with --csv, not both")
    if direct_given and inverse_given:
        raise click.UsageError("give --rows/--cols (direct) or --lon/--lat/--h (inverse), not both")
    if not (csv_path or direct_given or inverse_given):
        raise click.UsageError("give points: --rows/--cols, --lon/--lat/--h, or --csv")
    direction = "inverse" if (inverse_given or (csv_path and inverse)) else "direct"
    if direction == "direct":
        if csv_path:
            pts = read_points_csv(Path(csv_path), ("row", "col"))
            r, c = pts["row"], pts["col"]
        else:
            if rows is None or cols is None:
                raise click.UsageError("direct localization needs both --rows and --cols")
            r, c = _float_list(rows, "rows"), _float_list(cols, "cols")
            if r.size != c.size:
                raise InputError(f"--rows has {r.size} values, --cols {c.size}")
        if (height is None) == (dem_path is None):
            raise click.UsageError("direct localization needs exactly one of --height and --dem")
    else:
        if csv_path:
            pts = read_points_csv(Path(csv_path), ("lon", "lat", "h"))
            lo, la, hh = pts["lon"], pts["lat"], pts["h"]
        else:
            if lon is None or lat is None or h_text is None:
                raise click.UsageError("inverse localization needs --lon, --lat and --h")
            lo, la, hh = _float_list(lon, "lon"), _float_list(lat, "lat"), _float_list(h_text, "h")
            if not lo.size == la.size == hh.size:
                raise InputError("--lon, --lat and --h need the same number of values")
    model = open_model(model_path)
    kwargs = {} if band is None else {"band": band}
    if direction == "direct":
        if dem_path is not None:
            dem = open_dem(dem_path, dem_datum, geoid)
            lo, la, hh = model.image_to_ground(r, c, dem=dem, **kwargs)
        else:
            lo, la, hh = model.image_to_ground(r, c, height=height, **kwargs)
    else:
        r, c = model.ground_to_image(lo, la, hh, **kwargs)
    table = {"row": np.atleast_1d(r), "col": np.atleast_1d(c), "lon": np.atleast_1d(lo), "lat": np.atleast_1d(la), "h": np.atleast_1d(hh)}
    n = table["row"].size
    summary = {
        "command": "localize",
        "model": str(model_path),
        "model_kind": model.kind,
        "direction": direction,
        "points": int(n),
        "not_localized": int(np.count_nonzero(~np.isfinite(table["row"] + table["lon"]))),
        "seconds": round(time.perf_counter() - t0, 4),
    }
    if out_path:
        lines = ["row,col,lon,lat,h"]
        lines += [f"{a:.6f},{b:.6f},{x:.10f},{y:.10f},{z:.4f}" for a, b, x, y, z in zip(*table.values())]
        atomic_write_text(Path(out_path), "\n".join(lines) + "\n")
        write_summary(Path(out_path).with_suffix(".summary.json"), summary | {"output": str(out_path)})
    if as_json:
        click.echo(json.dumps(summary | {"results": {k: v.tolist() for k, v in table.items()}}, default=_json_default))
    elif not out_path:
        click.echo(f"{'row':>14} {'col':>14} {'lon_deg':>16} {'lat_deg':>16} {'h_m':>11}")
        for a, b, x, y, z in zip(*table.values()):
            click.echo(f"{a:14.6f} {b:14.6f} {x:16.10f} {y:16.10f} {z:11.4f}")


@cli.command()
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False), help="Output: *_RPC.TXT, *.RPB, or *.tif (RPC tags).")
@add_options(dem_options)
@click.option("--height-range", nargs=2, type=float, help="Min and max ellipsoidal heights (m) when no --dem is given.")
@click.option("--band", help="Band (multi-band models; default: the reference band).")
@click.option("--ccd", help="CCD name; default: one RPC per CCD (suffix _<ccd> in the file name).")
@click.option("--json", "as_json", is_flag=True, help="Print the fit summary as JSON.")
def rpc(model_path, out_path, dem_path, dem_datum, geoid, height_range, band, ccd, as_json):
    """Fit an RPC to MODEL over its image and height range and write it.

    A push-broom band with several CCDs gets one RPC per CCD image (columns counted from the
    CCD's first detector), since the stitched raster is discontinuous where CCDs overlap.

    The height range comes from --dem (its minimum and maximum over the scene, with a margin) or
    --height-range. The fit is terrain-independent; its errors on an independent check grid are
    reported in OUT.summary.json.
    """
    from sensor_models import open_model
    from sensor_models.rpc import fit_rpc

    t0 = time.perf_counter()
    model = open_model(model_path)
    if dem_path is not None:
        dem = open_dem(dem_path, dem_datum, geoid)
        h_lo, h_hi = dem.height_range_m
        pad = max(50.0, 0.05 * (h_hi - h_lo))
        height_range = (h_lo - pad, h_hi + pad)
    elif height_range is None:
        height_range = (-100.0, 3000.0)
    out = Path(out_path)
    targets = [(model, out, None)]
    if hasattr(model, "band_ccds"):
        # an RPC describes one smooth image: one per CCD (the stitched raster jumps at overlaps)
        ccds = model.band_ccds(band)
        if ccd is not None:
            targets = [(model.ccd_view(ccd, band=band), out, ccd)]
        elif len(ccds) == 1:
            targets = [(model.ccd_view(0, band=band), out, ccds[0].name)]
        else:
            targets = [(model.ccd_view(i, band=band), _with_ccd_suffix(out, c.name), c.name) for i, c in enumerate(ccds)]
    elif ccd is not None:
        raise InputError(f"--ccd applies to push-broom models, not to a {model.kind} model")
    fits = []
    out.parent.mkdir(parents=True, exist_ok=True)
    for target, path, ccd_name in targets:
        kwargs = {} if (band is None or ccd_name is not None) else {"band": band}
        fitted, report = fit_rpc(target, height_range_m=tuple(height_range), **kwargs)
        fitted.write(path)
        fits.append({"ccd": ccd_name, "output": str(path), "fit": report})
    summary = {
        "command": "rpc",
        "model": str(model_path),
        "height_range_m": list(height_range),
        "rpcs": fits,
        "check_max_px": max(f["fit"]["check_max_px"] for f in fits),
        "seconds": round(time.perf_counter() - t0, 3),
    }
    write_summary(out.with_name(out.name + ".summary.json"), summary)
    if as_json:
        click.echo(json.dumps(summary, default=_json_default))
    else:
        for f in fits:
            rep = f["fit"]
            label = f" (CCD {f['ccd']})" if f["ccd"] else ""
            click.echo(f"wrote {f['output']}{label}: check-grid max {rep['check_max_px']:.2e} px, rms {rep['check_rms_px']:.2e} px")


def _with_ccd_suffix(path: Path, ccd: str) -> Path:
    """``scene_RPC.TXT`` -> ``scene_ccd1_RPC.TXT``; ``scene.RPB`` -> ``scene_ccd1.RPB``."""
    name = path.name
    if name.upper().endswith("_RPC.TXT"):
        return path.with_name(f"{name[:-8]}_{ccd}{name[-8:]}")
    return path.with_name(f"{path.stem}_{ccd}{path.suffix}")


@cli.command()
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="gcpcal-demo", show_default=True, help="Output folder.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.pass_context
def demo(ctx, out_dir, as_json):
    """Run the main job on the embedded fixtures and write OUT/summary.json."""
    from rich.console import Console
    from rich.table import Table

    from calibrate.demo import run_demo

    console = Console(stderr=True, quiet=ctx.obj.get("quiet", False) or as_json)
    with console.status("gcpcal demo") as status:
        summary = run_demo(Path(out_dir), progress=lambda m: status.update(f"gcpcal demo: {m}"))
    if as_json:
        click.echo(json.dumps(summary, default=_json_default))
        return
    table = Table(title="HY-1C-like scene: LAB model -> calibrated (check points never used in the fit)")
    for col in ("", "before", "after"):
        table.add_column(col, justify="right")
    for key, label in (("check_rmse_row_px", "check RMSE along track, px"), ("check_rmse_col_px", "check RMSE across track, px"),
                       ("check_rmse_px", "check RMSE planar, px"), ("check_rmse_m", "check RMSE planar, m")):
        b, a = summary[key]["before"], summary[key]["after"]
        table.add_row(label, f"{b:.2f}" if b is not None else "-", f"{a:.3f}" if a is not None else "-")
    table.add_row("error against the TRUE model (rms), px", f"{summary['truth_error_before_px']['rms']:.2f}",
                  f"{summary['truth_error_px']['rms']:.3f}")
    table.add_row("error against the TRUE model (max), px", f"{summary['truth_error_before_px']['max']:.2f}",
                  f"{summary['truth_error_px']['max']:.3f}")
    out = Console()
    out.print(table)
    out.print(f"{summary['gcps']} GCPs, {summary['check_points']} check points; "
              f"wrote {out_dir}/summary.json, {out_dir}/report.html in {summary['seconds']:.1f} s")


# ---------------------------------------------------------------- simulation and truth
@cli.group()
def simulate():
    """Simulate scenes with known truth."""


@simulate.command("pushbroom")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--seed", type=click.IntRange(min=0), help="Random seed (overrides the configuration's).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="JSON configuration (any subset of the defaults).")
@click.option("--dom", "dom_path", type=click.Path(dir_okay=False), help="Reference orthoimage to render from (with --dem).")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM declaring its vertical datum (with --dom).")
@click.option("--geoid", type=click.Path(dir_okay=False), help="EGM96 grid for an orthometric DEM.")
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True, help="Rendering threads.")
@click.option("--print-config", is_flag=True, help="Print the effective configuration as JSON and exit.")
@click.pass_context
def simulate_pushbroom_cmd(ctx, out_dir, seed, config_path, dom_path, dem_path, geoid, workers, print_config):
    """Render a level-1A push-broom scene through a TRUE model; write the LAB manifest and truth."""
    from rich.progress import Progress

    from sensor_models.simulate.config import load_config
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    cfg = load_config(config_path)
    if seed is not None:
        cfg = cfg.with_seed(seed)
    if print_config:
        click.echo(json.dumps(cfg.to_dict(), indent=1))
        return
    with Progress(transient=True, disable=ctx.obj.get("quiet", False)) as bar:
        task = bar.add_task("rendering", total=None)
        summary = simulate_pushbroom(
            Path(out_dir), config=cfg, dom=dom_path, dem=dem_path, geoid=geoid, workers=workers,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    img = summary["image"]
    click.echo(
        f"{out_dir}: {img['n_rows']} x {img['n_cols']} px, {len(img['bands'])} bands, {img['ccds']} CCDs; "
        f"LAB model off by {summary['lab_truth_error_px']['rms']:.1f} px RMS "
        f"(max {summary['lab_truth_error_px']['max']:.1f}); rendered in {summary['render_seconds']:.1f} s"
    )


@simulate.command("series")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--scenes", type=click.IntRange(min=1), default=10, show_default=True, help="Validation scenes.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Seed of the series' draws.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="Sensor configuration (JSON, as simulate pushbroom).")
@click.option("--clouds", default="0,0,0,0.3", show_default=True, help="Cloud covers cycled over the scenes.")
@click.option("--calibration-scene", is_flag=True, help="Also render a scene to calibrate the sensor on.")
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True)
def simulate_series_cmd(out_dir, scenes, seed, config_path, clouds, calibration_scene, workers):
    """Validation scenes of one sensor (dates, sites, attitude biases, clouds) and their sites file."""
    from sensor_models.simulate.config import load_config
    from sensor_models.simulate.series import simulate_series

    paths = simulate_series(Path(out_dir), scenes, base_config=load_config(config_path), seed=seed,
                            cloud_fractions=tuple(_float_list(clouds, "clouds")), calibration_scene=calibration_scene,
                            workers=workers)
    click.echo(f"{out_dir}: {len(paths)} scenes; sites file {Path(out_dir) / 'sites.yaml'}")


@simulate.command("geo-earth")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--seed", type=click.IntRange(min=0), help="Random seed (overrides the configuration's).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="JSON configuration (any subset of the defaults).")
@click.option("--dom", "dom_path", type=click.Path(dir_okay=False), help="Reference orthoimage (with --dem).")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM declaring its vertical datum (with --dom).")
@click.option("--geoid", type=click.Path(dir_okay=False), help="EGM96 grid for an orthometric DEM.")
def simulate_geo_earth_cmd(out_dir, seed, config_path, dom_path, dem_path, geoid):
    """Render an Earth view of a geostationary staring camera through a TRUE model."""
    from dataclasses import replace

    from sensor_models.simulate.geo_sim import load_geo_config, simulate_geo_earth

    cfg = load_geo_config(config_path)
    if seed is not None:
        cfg = replace(cfg, seed=seed)
    summary = simulate_geo_earth(Path(out_dir), config=cfg, dom=dom_path, dem=dem_path, geoid=geoid)
    img = summary["image"]
    click.echo(f"{out_dir}: {img['n_rows']} x {img['n_cols']} px staring frame; LAB model off by "
               f"{summary['lab_truth_error_px']['rms']:.1f} px RMS (max {summary['lab_truth_error_px']['max']:.1f})")


@cli.group()
def truth():
    """Compare models with the truth of a simulated scene."""


@truth.command("error")
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--truth", "truth_path", required=True, type=click.Path(dir_okay=False), help="The TRUE model (truth_manifest.json of a simulation).")
@add_options(dem_options)
@click.option("--heights", help="Comma-separated ellipsoidal heights (m) to compare at, when no --dem is given.")
@click.option("--step", type=click.FloatRange(min=1.0), default=16.0, show_default=True, help="Grid spacing in pixels.")
@click.option("--out", "out_path", type=click.Path(dir_okay=False), help="Write the result as JSON.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def truth_error_cmd(model_path, truth_path, dem_path, dem_datum, geoid, heights, step, out_path, as_json):
    """Pixel error of MODEL against the TRUE model over a grid of every CCD and band."""
    from sensor_models.readers import open_model
    from sensor_models.compare import model_difference

    true_model = open_model(truth_path)
    model = open_model(model_path)
    dem = open_dem(dem_path, dem_datum, geoid) if dem_path else None
    result = model_difference(true_model, model, dem=dem, step_px=step,
                         heights_m=None if heights is None else _float_list(heights, "heights"))
    if out_path:
        write_summary(Path(out_path), result)
    if as_json:
        click.echo(json.dumps(result, default=_json_default))
        return
    for r in result["per_ccd"]:
        click.echo(f"{r['band']:>6} {r['ccd']:>10}  rms {r['rms_px']:.4f} px  max {r['max_px']:.4f} px  "
                   f"mean (row, col) ({r['mean_row_px']:+.4f}, {r['mean_col_px']:+.4f})")
    click.echo(f"all: rms {result['rms_px']:.4f} px, max {result['max_px']:.4f} px over {result['n_points']} points")

# ---------------------------------------------------------------- matching
@cli.command()
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--dom", "dom_path", required=True, type=click.Path(dir_okay=False), help="Reference orthoimage (any CRS).")
@add_options(dem_options)
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False), help="GCP table (CSV); a .summary.json goes beside it.")
@click.option("--gpkg", "gpkg_path", type=click.Path(dir_okay=False), help="Also write the GCPs as a GeoPackage layer.")
@click.option("--geotiff", "geotiff_path", type=click.Path(dir_okay=False), help="Also write the GCPs into a GeoTIFF (GDAL GCPs).")
@click.option("--band", help="Band to match (default: the reference band).")
@click.option("--image", type=click.Path(dir_okay=False), help="Scene raster (default: the manifest's raster of the band).")
@click.option("--mask", "mask_path", type=click.Path(dir_okay=False), help="Cloud/invalid mask raster in scene geometry (nonzero = invalid).")
@click.option("--check-fraction", type=click.FloatRange(0.0, 0.9), default=0.2, show_default=True, help="Share of matches kept as independent check points.")
@click.option("--window", type=click.IntRange(min=16), default=64, show_default=True, help="Phase-correlation window, pixels.")
@click.option("--spacing", type=click.IntRange(min=1), default=32, show_default=True, help="Window grid spacing, pixels.")
@click.option("--max-offset", type=click.FloatRange(min=1.0), default=1000.0, show_default=True, help="Largest expected model error, pixels.")
@click.option("--backend", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True, help="Phase correlation on CPU (numpy) or GPU (torch).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.pass_context
def match(ctx, scene_path, dom_path, dem_path, dem_datum, geoid, out_path, gpkg_path, geotiff_path, band, image, mask_path,
          check_fraction, window, spacing, max_offset, backend, as_json):
    """Extract GCPs of SCENE against a DOM and a DEM (coarse SIFT, dense phase correlation)."""
    from gcpmatch.extract import match_scene
    from gcpmatch.options import MatchOptions

    if dem_path is None:
        raise InputError("--dem is required: GCPs need terrain heights")
    options = MatchOptions(window_px=window, spacing_px=spacing, max_offset_px=max_offset,
                           check_fraction=check_fraction, backend=backend)
    quiet = ctx.obj.get("quiet", False) or as_json
    summary = match_scene(scene_path, dom_path=dom_path, dem_path=dem_path, out_path=out_path, geoid=geoid,
                          dem_datum=dem_datum, band=band, image=image, mask_path=mask_path, gpkg_path=gpkg_path,
                          geotiff_path=geotiff_path, options=options,
                          progress=None if quiet else (lambda m: click.echo(m, err=True)))
    if as_json:
        click.echo(json.dumps(summary, default=_json_default))
        return
    click.echo(f"{out_path}: {summary['gcps']} GCPs + {summary['check_points']} check points from "
               f"{summary['windows']} windows ({100 * summary['usable_fraction']:.0f} % usable, "
               f"{100 * summary['cloud_fraction']:.0f} % cloud) in {summary['timings']['total_s']:.1f} s")

# ---------------------------------------------------------------- calibration
@cli.command()
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--gcps", "gcps_path", required=True, type=click.Path(dir_okay=False), help="GCP table (CSV, GeoPackage or GeoTIFF).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--scheme", type=click.Choice(["exterior", "interior", "exterior-interior", "interior-exterior", "joint"]),
              default="exterior-interior", show_default=True, help="Which parameters, in which order (seed 002's schemes).")
@click.option("--robust", type=click.Choice(["huber", "cauchy", "none"]), default="cauchy", show_default=True, help="Robust loss.")
@click.option("--band", help="Band of GCPs that name none (default: the reference band).")
@click.option("--image", type=click.Path(dir_okay=False), help="Raster the GCPs were measured in, when it is a crop of SCENE.")
@click.option("--no-report", is_flag=True, help="Skip report.html and its figures.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.pass_context
def calibrate(ctx, scene_path, gcps_path, out_dir, scheme, robust, band, image, no_report, as_json):
    """Calibrate SCENE's model from GCPs; write calibration.json, the calibrated model and report.html."""
    from calibrate.run import calibrate_scene

    quiet = ctx.obj.get("quiet", False) or as_json
    summary = calibrate_scene(scene_path, gcps_path, out_dir, scheme=scheme, robust=robust, band=band, image=image,
                              report=not no_report, progress=None if quiet else (lambda m: click.echo(m, err=True)))
    if as_json:
        click.echo(json.dumps(summary, default=_json_default))
        return
    before, after = summary["check_rmse_px"]["before"], summary["check_rmse_px"]["after"]
    checks = (f"check RMSE {before:.3f} -> {after:.3f} px on {summary['check_points']} check points"
              if before is not None else "no check points")
    click.echo(f"{out_dir}: {'converged' if summary['success'] else 'FAILED'} ({summary['message']}); {checks}")
    if not summary["success"]:
        ctx.exit(3)

@cli.command("run")
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--dom", "dom_path", required=True, type=click.Path(dir_okay=False), help="Reference orthoimage.")
@add_options(dem_options)
@click.option("--star-frames", type=click.Path(), help="Star sequence (frames.json or its folder) for the fallback.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--min-gcps", type=click.IntRange(min=1), default=60, show_default=True, help="GCPs needed to calibrate from the ground.")
@click.option("--min-coverage", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="Share of a 4 x 4 partition of the image the GCPs must cover.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.pass_context
def run_cmd(ctx, scene_path, dom_path, dem_path, dem_datum, geoid, star_frames, out_dir, min_gcps, min_coverage, as_json):
    """Calibrate SCENE from GCPs, or from star frames when clouds leave too few (says which and why)."""
    from calibrate.fallback import run_scene

    if dem_path is None:
        raise InputError("--dem is required: GCPs need terrain heights")
    quiet = ctx.obj.get("quiet", False) or as_json
    summary = run_scene(scene_path, dom_path=dom_path, dem_path=dem_path, out_dir=out_dir, star_frames=star_frames,
                        dem_datum=dem_datum, geoid=geoid, min_gcps=min_gcps, min_coverage=min_coverage,
                        progress=None if quiet else (lambda m: click.echo(m, err=True)))
    if as_json:
        click.echo(json.dumps(summary, default=_json_default))
    else:
        click.echo(f"{out_dir}: path {summary['path']} ({summary['reason']}); "
                   f"{'converged' if summary['success'] else 'FAILED'}: {summary['message']}")
    if not summary["success"]:
        ctx.exit(3)


def _register_commands() -> None:
    """Add the commands that live in their own modules (``calibrate.cli_*``, attribute ``command``)."""
    import importlib

    for name in ("calibrate.cli_relative", "calibrate.cli_validate", "calibrate.cli_ortho", "calibrate.cli_stars",
                 "calibrate.cli_compensate", "calibrate.cli_oalr", "calibrate.cli_thermal"):
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # not written yet
                continue
            raise
        cli.add_command(module.command)
        if hasattr(module, "simulate_command"):  # a `gcpcal simulate ...` subcommand
            simulate.add_command(module.simulate_command)


_register_commands()


def main(argv=None) -> int:
    """Console entry point: run the CLI, turn user errors into one line and exit code 1."""
    try:
        rv = cli.main(args=argv, prog_name="gcpcal", standalone_mode=False)
        if isinstance(rv, int) and not isinstance(rv, bool):  # ctx.exit(code) in non-standalone mode
            return rv
    except click.exceptions.Abort:
        click.echo("gcpcal: aborted", err=True)
        return 130
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except GcpcalError as exc:
        click.echo(f"gcpcal: error: {exc}", err=True)
        return 1
    except click.exceptions.Exit as exc:
        return exc.exit_code
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
