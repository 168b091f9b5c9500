"""``gcpcal localize``: points through a model, image -> ground or ground -> image."""

from __future__ import annotations

import click

from calibrate.actions.localize import csv_lines, json_lines, localize_points, point_fields
from calibrate.cli.options import (accept_product_disagreement_option, add_options, allow_implausible_option, constant_height_option, dem_options, echo_json, echo_warnings,
                                   float_list, json_option, one_height_source)
from sensor_models.errors import InputError

__all__ = ["command"]


def _points(rows, cols, lon, lat, h_text, csv_path, jsonl_path, inverse):
    """``(direction, points)`` from the options, after the usage checks."""
    direct_given = rows is not None or cols is not None
    inverse_given = lon is not None or lat is not None or h_text is not None
    if csv_path and jsonl_path:
        raise click.UsageError("give points with --csv or with --jsonl, not both")
    file_path = csv_path or jsonl_path
    if file_path and (direct_given or inverse_given):
        raise click.UsageError("give points either on the command line or with --csv/--jsonl, not both")
    if direct_given and inverse_given:
        raise click.UsageError("give --rows/--cols (direct) or --lon/--lat/--h (inverse), not both")
    if not (file_path or direct_given or inverse_given):
        raise click.UsageError("give points: --rows/--cols, --lon/--lat/--h, --csv or --jsonl")
    direction = "inverse" if (inverse_given or (file_path and inverse)) else "direct"
    if file_path:
        return direction, {"csv": csv_path} if csv_path else {"jsonl": jsonl_path}
    if direction == "direct":
        if rows is None or cols is None:
            raise click.UsageError("direct localization needs both --rows and --cols")
        r, c = float_list(rows, "rows"), float_list(cols, "cols")
        if r.size != c.size:
            raise InputError(f"--rows has {r.size} values, --cols {c.size}")
        return direction, {"row": r, "col": c}
    if lon is None or lat is None or h_text is None:
        raise click.UsageError("inverse localization needs --lon, --lat and --h")
    lo, la, hh = float_list(lon, "lon"), float_list(lat, "lat"), float_list(h_text, "h")
    if not lo.size == la.size == hh.size:
        raise InputError("--lon, --lat and --h need the same number of values")
    return direction, {"lon": lo, "lat": la, "h": hh}


@click.command("localize")
@allow_implausible_option
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--rows", help="Comma-separated rows (direct localization).")
@click.option("--cols", help="Comma-separated columns (direct localization).")
@click.option("--lon", help="Comma-separated longitudes, degrees (inverse localization).")
@click.option("--lat", help="Comma-separated latitudes, degrees (inverse localization).")
@click.option("--h", "h_text", help="Comma-separated ellipsoidal heights, m (inverse localization).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="CSV with a header and row,col (direct) or lon,lat,h (--inverse); - reads standard input.")
@click.option("--jsonl", "jsonl_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="JSON lines, one object per point with row,col (direct) or lon,lat,h (--inverse), other keys "
                   "passed through; - reads standard input.")
@click.option("--inverse", is_flag=True, help="Ground -> image (with --csv or --jsonl).")
@constant_height_option
@add_options(dem_options)
@click.option("--band", help="Band (multi-band models; default: the reference band).")
@click.option("--out", "out_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Write the results as CSV, or JSON lines for a .jsonl/.ndjson name (plus a .summary.json); - writes "
                   "them on standard output (JSON lines when the points came as JSON lines).")
@accept_product_disagreement_option
@json_option
def command(model_path, rows, cols, lon, lat, h_text, csv_path, jsonl_path, inverse, height, dem_path, dem_datum, geoid, band,
            out_path, as_json, self_check):
    """Localize points through MODEL, image -> ground or ground -> image.

    Direct: --rows/--cols (or --csv/--jsonl with row,col) and --height or --dem. Inverse:
    --lon/--lat/--h (or --csv/--jsonl with lon,lat,h and --inverse). Points stream: --csv - or
    --jsonl - reads standard input, --out - writes standard output. Image coordinates put the first pixel's centre at
    (0.5, 0.5); heights are metres above the WGS84 ellipsoid. Points outside the image, longitudes
    outside [-180, 360), latitudes outside [-90, 90] and heights outside [-500, 9000] m are refused.

    MODEL is a gcpcal manifest, a model file (.geom, .RPB, _RPC.TXT, .DIM, .XML) with its raster
    beside it or named in it, or a raster carrying an RPC (GeoTIFF tags, or a .RPB, _RPC.TXT or
    .geom beside it); a crop with a pixel geotransform crops the model (docs/inputs.md). Pixels are
    the raster's: a crop's own rows and columns.
    """
    if out_path == "-" and as_json:
        raise click.UsageError("--out - and --json both write on standard output: give one")
    direction, points = _points(rows, cols, lon, lat, h_text, csv_path, jsonl_path, inverse)
    if one_height_source(height=height, dem=dem_path) is None and direction == "direct":
        raise click.UsageError("direct localization needs exactly one of --height and --dem")
    summary = localize_points(model_path, points, direction=direction, height=height, dem_path=dem_path,
                              dem_datum=dem_datum, geoid=geoid, band=band, out_path=out_path, self_check=self_check)
    echo_warnings(summary)
    table = summary["results"]
    if out_path == "-":
        records = summary.get("records")
        click.echo("\n".join(json_lines(table, records) if records is not None else csv_lines(table)))
    elif as_json:
        echo_json({k: v for k, v in summary.items() if k != "records"}
                  | {"results": {k: v.tolist() for k, v in table.items()}})
    elif not out_path:
        click.echo(f"{'row':>14} {'col':>14} {'lon_deg':>16} {'lat_deg':>16} {'h_m':>11}")
        for a, b, x, y, z in zip(*table.values()):
            fields = point_fields(a, b, x, y, z)
            click.echo(" ".join(f"{t:>{w}}" for t, w in zip(fields, (14, 14, 16, 16, 11))))
