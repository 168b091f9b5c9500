"""Benchmark: push-broom localization over a DEM, inverse localization, grid mode and RPC fit.

Prints figures and writes JSON (default ``bench/results/localization.json``). Runs on one core
(BLAS threads pinned to 1). Uses the real SRTM tile from ``../shared/data/dem`` when present
(``GCPCAL_SHARED_DATA`` names another place), else a synthetic DEM of the same size and relief.

Also RPC localization over a DEM on real data, side by side in one run: the real Pleiades RPC
(``pleiades_ventoux/left_image.geom``, pixels over its full scene) over SRTM N44E005, localized
by ours, ours' bracketed search, the base revision, GDAL's RPC transformer and, with
``--shareloc-python PATH`` (an interpreter whose environment has shareloc installed; gcpcal
itself does not depend on it), shareloc's C++ in a child process (``bench/shareloc_child.py``):
points per CPU-second, ratios, machine load and the reprojection error of each.
``bench_rpc_dem``; ``--rpc-only`` runs just that and writes JSON only with ``--json PATH``.

Usage: ``python bench/bench_localization.py [--points 1000000] [--out FILE] [--rpc-only
[--json FILE]] [--shareloc-python PATH] [--repeat 3]``
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from sensor_models.models.locgrid import InverseLocalizationGrid  # noqa: E402
from sensor_models.models.pushbroom_types import Installation  # noqa: E402
from sensor_models.models.rpc_fit import fit_rpc  # noqa: E402
from sensor_models.models.synthetic import example_pushbroom_model  # noqa: E402
from sensor_models.terrain.dem import Dem  # noqa: E402
from sensor_models.readers.rpc_files import read_rpc, rpc_to_rasterio, write_rpc  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: ``../shared/data`` beside the project (``GCPCAL_SHARED_DATA`` names another place)
SHARED_DATA = Path(os.environ.get("GCPCAL_SHARED_DATA") or ROOT.parent / "shared" / "data")
SHARED_DEM = SHARED_DATA / "dem"


def load_dem():
    hgt, gtx = SHARED_DEM / "N44E005.hgt", SHARED_DEM / "egm96_15.gtx"
    if hgt.exists() and gtx.exists():
        return Dem.open(hgt, vertical_datum="egm96", geoid=gtx), "SRTM N44E005 + EGM96"
    from rasterio.transform import from_origin

    rng = np.random.default_rng(0)
    n = 1201
    spectrum = np.fft.fft2(rng.normal(size=(n, n)))
    k = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n), indexing="ij"))
    k[0, 0] = 1.0
    relief = np.real(np.fft.ifft2(spectrum / k**1.6))
    relief = 200.0 + 1800.0 * (relief - relief.min()) / np.ptp(relief)
    return Dem.from_array(relief, from_origin(5.0, 45.0, 1 / 1200, 1 / 1200), "EPSG:4326"), "synthetic fractal DEM"


def timed(func, *args, repeat=1, **kwargs):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = func(*args, **kwargs)
        best = min(best, time.perf_counter() - t0)
    return best, out


class HeightsOnly:
    """A DEM seen through ``height_m`` and ``height_range_m`` alone: without its slopes
    (``height_and_slope_m``), ``RpcModel.image_to_ground(..., dem=)`` takes its bracketed search."""

    def __init__(self, dem):
        self._dem = dem
        self.height_range_m = dem.height_range_m

    def height_m(self, lon, lat):
        return self._dem.height_m(lon, lat)


def real_rpc_scene(data: Path, n: int):
    """The real Pleiades RPC and ``n`` pixels over its full scene.

    Parameters
    ----------
    data : Path
        ``../shared/data`` (``pleiades_ventoux/left_image.geom``: the RPC of the full
        41801 x 39182 scene; ``dem/N44E005.hgt`` + ``egm96_15.gtx``: SRTM under it).
    n : int
        Pixels, uniform over the full scene (seed 7).

    Returns
    -------
    rpc : RpcModel
    dem : Dem
        SRTM N44E005 in ellipsoidal heights (EGM96 undulations added).
    rows, cols : ndarray, shape (n,)
    """
    rpc = read_rpc(data / "pleiades_ventoux" / "left_image.geom")
    dem = Dem.open(data / "dem" / "N44E005.hgt", vertical_datum="egm96", geoid=data / "dem" / "egm96_15.gtx")
    rng = np.random.default_rng(7)
    rows = rng.uniform(0.0, rpc.image_shape[0], n)
    cols = rng.uniform(0.0, rpc.image_shape[1], n)
    return rpc, dem, rows, cols


def _write_inputs(folder: Path, rpc, dem, rows, cols) -> Path:
    """The files GDAL and shareloc read: ``dem.tif`` (ellipsoidal heights, float32, NaN voids),
    ``rpc.tif`` (gcpcal's GeoTIFF RPC writer), ``rows.npy``, ``cols.npy``. Returns the DEM path."""
    import rasterio

    z = np.asarray(dem.heights_m, dtype=np.float32)
    path = folder / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs=dem.crs.to_wkt(), transform=dem.transform, nodata=np.nan) as ds:
        ds.write(z, 1)
    write_rpc(rpc, folder / "rpc.tif")
    np.save(folder / "rows.npy", rows)
    np.save(folder / "cols.npy", cols)
    return path


def _time_round(funcs: dict, repeat: int, best: dict, out: dict) -> None:
    """``repeat`` passes over ``funcs`` in turn; keeps each one's best CPU time and last output."""
    for _ in range(repeat):
        for k, f in funcs.items():
            t0 = time.process_time()
            out[k] = f()
            best[k] = min(best.get(k, np.inf), time.process_time() - t0)


def run_shareloc(python, folder: Path, repeat: int) -> tuple[dict | None, str]:
    """shareloc's C++ localization of the same pixels, in a child process of ``python``.

    Parameters
    ----------
    python : str or None
        Interpreter of an environment with shareloc installed (``--shareloc-python``).
    folder : Path
        The files of :func:`_write_inputs`.
    repeat : int
        Best of ``repeat`` (inside the child).

    Returns
    -------
    result : dict or None
        The child's JSON (``seconds``: ``cpp``, ``wrapper``; ``shareloc_version``...) plus
        ``lonlath`` (3, n), or None when skipped.
    reason : str
        Why it was skipped ("" when it ran).
    """
    import subprocess

    if not python:
        return None, "--shareloc-python not given"
    env = dict(os.environ, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    try:
        proc = subprocess.run([str(python), str(ROOT / "bench" / "shareloc_child.py"), str(folder), "--repeat",
                               str(repeat)], capture_output=True, text=True, env=env, timeout=3600)
    except OSError as err:
        return None, f"cannot run {python}: {err}"
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        return None, f"{python} could not run shareloc ({last})"
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["lonlath"] = np.load(folder / "shareloc_lonlath.npy")
    return result, ""


def _accuracy(rpc, dem, rows, cols, lonlath, ref: dict, *, has_height: bool = True) -> dict:
    """Accuracy of one method's ground points (``lonlath``: lon, lat, h arrays).

    ``ref`` maps a name (``before``: the base revision, 1e-9 px inversions; ``bracketed``: the
    bracketed search; ``after``: ours) to its ``(lon, lat, h)``. Reports the fraction found; the
    reprojection residual through the RPC at the method's own height (max norm, px; for a method
    that gives no height, GDAL, at the DEM's height under its point, the surface it intersects);
    the DEM misfit ``|DEM(lon, lat) - h|`` (m); and, for each reference, the ground distance to
    its solution (m) and the image offset of that distance at its height (px).
    """
    lon, lat, h = lonlath
    base_lon = ref["before"][0]
    ok = np.isfinite(lon) & np.isfinite(base_lon)
    hh = h[ok] if has_height else dem.height_m(lon[ok], lat[ok])
    r2, c2 = rpc.ground_to_image(lon[ok], lat[ok], hh)
    res = {"found": float(np.isfinite(lon).mean()), "compared": int(ok.sum()),
           "reprojection_px_max": float(np.nanmax(np.maximum(abs(r2 - rows[ok]), abs(c2 - cols[ok]))))}
    if has_height:
        res["dem_misfit_m_max"] = float(np.nanmax(np.abs(dem.height_m(lon[ok], lat[ok]) - h[ok])))
    for name, (rlon, rlat, rh) in ref.items():
        if rlon is lon:  # the method itself
            continue
        both = np.isfinite(lon) & np.isfinite(rlon)
        d_m = np.hypot((lon - rlon)[both] * np.cos(np.radians(rlat[both])), (lat - rlat)[both]) * 111_320.0
        r3, c3 = rpc.ground_to_image(lon[both], lat[both], rh[both])
        r4, c4 = rpc.ground_to_image(rlon[both], rlat[both], rh[both])
        res[f"distance_to_{name}_m_max"] = float(d_m.max())
        res[f"distance_to_{name}_px_max"] = float(np.max(np.hypot(r3 - r4, c3 - c4)))
    return res


def bench_rpc_dem(data: Path, n: int, repeat: int = 3, shareloc_python=None) -> dict:
    """RPC localization over SRTM on the real Pleiades RPC: ours, its bracketed search, the base
    revision, GDAL and shareloc, side by side.

    The scene is :func:`real_rpc_scene`. Every method reads the same heights: SRTM in
    ellipsoidal heights written as a float32 GeoTIFF, which ours opens as a :class:`Dem` and GDAL's
    RPC transformer (rasterio ``RPCTransformer``, ``RPC_DEM``, bilinear,
    ``RPC_PIXEL_ERROR_THRESHOLD`` 1e-4 px) reads. ``bracketed`` is ours on a DEM that does not
    give its slopes (:class:`HeightsOnly`): the bracketed (Illinois) search alone. CPU times
    (``time.process_time``) alternate, best of ``repeat``, in two rounds with shareloc's C++
    (child process in ``shareloc_python``'s environment, one thread, see
    ``bench/shareloc_child.py``) between them. Accuracy: see :func:`_accuracy`.
    """
    import sys
    import tempfile

    from rasterio.transform import RPCTransformer

    sys.path.insert(0, str(ROOT / "bench"))
    from baseline import BASE_REV, load_baseline

    rpc, srtm, rows, cols = real_rpc_scene(data, n)
    base_rpc = load_baseline("sensor_models/models/rpc.py").RpcModel(**rpc.init_kwargs())
    best, out = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        dem_path = _write_inputs(Path(tmp), rpc, srtm, rows, cols)
        dem = Dem.open(dem_path, vertical_datum="ellipsoid")
        heights_only = HeightsOnly(dem)
        with RPCTransformer(rpc_to_rasterio(rpc), RPC_DEM=str(dem_path), RPC_DEMINTERPOLATION="bilinear",
                            RPC_PIXEL_ERROR_THRESHOLD=1e-4) as gdal:
            funcs = {"before": lambda: base_rpc.image_to_ground(rows, cols, dem=dem),
                     "bracketed": lambda: rpc.image_to_ground(rows, cols, dem=heights_only),
                     "after": lambda: rpc.image_to_ground(rows, cols, dem=dem),
                     "gdal": lambda: gdal.xy(rows, cols, offset="ul")}
            load = [os.getloadavg()[0]]
            _time_round(funcs, repeat, best, out)
            rounds = {k: [v] for k, v in best.items()}
            load.append(os.getloadavg()[0])
            shareloc, reason = run_shareloc(shareloc_python, Path(tmp), repeat)
            second = {}
            _time_round(funcs, repeat, second, out)
            load.append(os.getloadavg()[0])
            for k, v in second.items():
                rounds[k].append(v)
            best = {k: min(best[k], second[k]) for k in best}
        result = _rpc_result(rpc, dem, rows, cols, best, out, shareloc, reason, rounds, load, BASE_REV)
    return result


def _rpc_result(rpc, dem, rows, cols, best, out, shareloc, reason, rounds, load, base_rev) -> dict:
    """The JSON record of :func:`bench_rpc_dem`: speeds, ratios, accuracy of each method."""
    n = rows.size
    ref = {"before": out["before"], "bracketed": out["bracketed"], "after": out["after"]}
    result = {"rpc": "Pleiades-1B left_image.geom (full scene 41801 x 39182), pixels uniform over it",
              "dem": "SRTM N44E005 + EGM96, ellipsoidal heights as float32 GeoTIFF (the same file for all)",
              "points": n, "base_rev": base_rev, "points_per_cpu_s": {k: n / v for k, v in best.items()},
              "cpu_s_per_round": rounds, "load_average_1min": load,
              "speedup_vs_before": best["before"] / best["after"],
              "speedup_vs_bracketed": best["bracketed"] / best["after"], "ratio_vs_gdal": best["gdal"] / best["after"]}
    for name in ("before", "bracketed", "after"):
        result[name] = _accuracy(rpc, dem, rows, cols, out[name], ref)
    gdal_lonlath = tuple(np.asarray(v, dtype=np.float64) for v in out["gdal"]) + (None,)
    result["gdal"] = _accuracy(rpc, dem, rows, cols, gdal_lonlath, ref, has_height=False)
    if shareloc is None:
        print(f"shareloc column skipped: {reason}")
        result["shareloc"] = {"skipped": reason}
        return result
    sec = shareloc["seconds"]
    result["points_per_cpu_s"]["shareloc_cpp"] = n / sec["cpp"]
    result["points_per_cpu_s"]["shareloc_wrapper"] = n / sec["wrapper"]
    result["ratio_vs_shareloc_cpp"] = sec["cpp"] / best["after"]
    result["shareloc"] = _accuracy(rpc, dem, rows, cols, shareloc["lonlath"], ref)
    result["shareloc"].update({k: shareloc[k] for k in ("shareloc_version", "python", "dem_nodes_filled", "threads")})
    return result


def print_rpc_result(r: dict) -> None:
    """The RPC-over-DEM comparison as a table: points per CPU-second, ratio to ours, accuracy."""
    pps = r["points_per_cpu_s"]
    load = ", ".join(f"{v:.2f}" for v in r["load_average_1min"])
    print(f"RPC localization over a DEM: {r['points']:,} points, {r['rpc']}; {r['dem']}; "
          f"1 thread, load average (1 min) {load} on {os.cpu_count()} cores")
    rows = [("ours (Newton on lon, lat, h)", "after"), ("ours, bracketed search", "bracketed"),
            (f"base revision {r['base_rev']}", "before"), ("GDAL RPCTransformer (1e-4 px)", "gdal")]
    if "shareloc_cpp" in pps:
        rows.append(("shareloc C++ direct_loc_dtm", "shareloc_cpp"))
    print(f"  {'method':32s} {'points/CPU-s':>13s} {'ours / it':>10s} {'reproj. max px':>15s} {'found':>7s}")
    for label, key in rows:
        acc = r.get("shareloc" if key.startswith("shareloc") else key, {})
        print(f"  {label:32s} {pps[key]:13,.0f} {pps['after'] / pps[key]:10.2f} "
              f"{acc.get('reprojection_px_max', float('nan')):15.2e} {acc.get('found', float('nan')):7.4f}")
    print(f"  ours against GDAL: x{r['ratio_vs_gdal']:.2f}; ours within {r['after']['distance_to_bracketed_m_max']:.1e} m "
          f"({r['after']['distance_to_bracketed_px_max']:.1e} px) of the bracketed search, GDAL within "
          f"{r['gdal']['distance_to_after_m_max']:.1e} m ({r['gdal']['distance_to_after_px_max']:.1e} px) of ours")


def rpc_only(data: Path, n: int, shareloc_python=None, repeat: int = 3, out: Path | None = None) -> None:
    """``--rpc-only``: the RPC-over-DEM comparison alone, printed; JSON written to ``out`` when given."""
    r = bench_rpc_dem(data, n, repeat=repeat, shareloc_python=shareloc_python)
    command = f"python bench/bench_localization.py --rpc-only --points {n} --repeat {repeat}"
    if shareloc_python:
        command += f" --shareloc-python {shareloc_python}"
    r.update(command=command, machine=platform.machine(), python=platform.python_version(), cpus=os.cpu_count())
    print_rpc_result(r)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(r, indent=1) + "\n")
        print(f"wrote {out}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--out", type=Path, default=None,
                        help="JSON of the full run (default bench/results/localization.json)")
    parser.add_argument("--rpc-only", action="store_true",
                        help="only the RPC-over-DEM comparison on the real Pleiades RPC and SRTM (ours, base "
                        "revision, GDAL), printed; JSON written with --json")
    parser.add_argument("--json", type=Path, default=None, metavar="PATH",
                        help="with --rpc-only: write the comparison's JSON here")
    parser.add_argument("--shareloc-python", default=None, metavar="PATH",
                        help="Python of an environment with shareloc installed: adds shareloc's C++ to the RPC "
                        "comparison (skipped with a printed reason when not given or not importable)")
    parser.add_argument("--repeat", type=int, default=3, help="best of N for the RPC comparison")
    args = parser.parse_args()
    n = args.points
    if args.rpc_only:
        if not (SHARED_DATA / "pleiades_ventoux").is_dir():
            parser.error(f"the real Pleiades RPC is not at {SHARED_DATA} (set GCPCAL_SHARED_DATA)")
        rpc_only(SHARED_DATA, n, args.shareloc_python, args.repeat, args.json)
        return
    rng = np.random.default_rng(42)

    model = example_pushbroom_model(
        n_rows=2000,
        installation=Installation(0.0, 0.0, np.radians(3.55)),
        attitude_kwargs=dict(bias_rad=(2e-4, -3e-4, 1e-3), drift_rad_s=(1e-6, -1e-6, 2e-6), jitter_amplitude_rad=(2e-6, 2e-6, 1e-6), jitter_frequency_hz=1.3, seed=1),
    )
    dem, dem_name = load_dem()
    results = {"points": n, "dem": dem_name, "machine": platform.machine(), "python": platform.python_version()}

    # points inside the DEM tile: rows and columns whose footprint lies over it
    rows = rng.uniform(300.0, 1700.0, n)
    cols = rng.uniform(100.0, model.n_cols - 100.0, n)

    t, (lon, lat, h) = timed(model.image_to_ground, rows, cols, dem=dem)
    ok = np.isfinite(lon)
    results["direct_dem_points_per_s"] = n / t
    results["direct_dem_fraction_on_dem"] = float(ok.mean())
    print(f"direct over DEM   {n / t:12,.0f} points/s   ({t:.2f} s, {ok.mean():.1%} on the DEM: {dem_name})")

    t, (lon_h, lat_h, h_h) = timed(model.image_to_ground, rows, cols, height=500.0)
    results["direct_height_points_per_s"] = n / t
    print(f"direct at height  {n / t:12,.0f} points/s   ({t:.2f} s)")

    ccd = model.ccd_index(cols)
    t, (r2, c2) = timed(model.ground_to_image, lon[ok], lat[ok], h[ok], ccd=ccd[ok])
    err = np.hypot(r2 - rows[ok], c2 - cols[ok])
    results["inverse_points_per_s_ccd_known"] = ok.sum() / t
    results["round_trip_dem_rms_px"] = float(np.sqrt(np.mean(err**2)))
    results["round_trip_dem_max_px"] = float(err.max())
    print(f"inverse (CCD known){ok.sum() / t:11,.0f} points/s   round trip rms {results['round_trip_dem_rms_px']:.1e} px, max {results['round_trip_dem_max_px']:.1e} px")

    t, (r3, c3) = timed(model.ground_to_image, lon[ok], lat[ok], h[ok])
    results["inverse_points_per_s"] = ok.sum() / t
    print(f"inverse (any CCD) {ok.sum() / t:12,.0f} points/s   ({t:.2f} s)")

    h_lo, h_hi = dem.height_range_m
    lon_rng = (float(np.nanmin(lon)) - 0.01, float(np.nanmax(lon)) + 0.01)
    lat_rng = (float(np.nanmin(lat)) - 0.01, float(np.nanmax(lat)) + 0.01)
    t_build, grid = timed(InverseLocalizationGrid, model, lon_rng, lat_rng, (h_lo - 10.0, h_hi + 10.0), spacing_px=16.0)
    t, (rg, cg) = timed(grid.ground_to_image, lon[ok], lat[ok], h[ok], repeat=3)
    # interpolation error with the CCD known (the automatic choice differs only on CCD overlaps)
    rk, ck = grid.ground_to_image(lon[ok], lat[ok], h[ok], array=ccd[ok])
    gerr = np.hypot(rk - r2, ck - c2)
    results["grid_ccd_choice_differs"] = int(np.count_nonzero(np.hypot(rg - r3, cg - c3) > 0.01))
    results["grid_build_s"] = t_build
    results["grid_nodes"] = list(grid.shape)
    results["grid_points_per_s"] = ok.sum() / t
    results["grid_error_rms_px"] = float(np.sqrt(np.nanmean(gerr**2)))
    results["grid_error_max_px"] = float(np.nanmax(gerr))
    results["grid_nan"] = int(np.isnan(gerr).sum())
    print(
        f"grid inverse      {ok.sum() / t:12,.0f} points/s   error rms {results['grid_error_rms_px']:.1e} px, "
        f"max {results['grid_error_max_px']:.1e} px (nodes {grid.shape}, built in {t_build:.2f} s)"
    )

    for label, m in (("with 0.03 px attitude jitter", model), ("without jitter", example_pushbroom_model(n_rows=2000, installation=Installation(0.0, 0.0, np.radians(3.55))))):
        t, (rpc, report) = timed(fit_rpc, m.detector_view(array=0), height_range_m=(h_lo, h_hi))
        key = "rpc_fit" if m is model else "rpc_fit_no_jitter"
        results[key] = {"seconds": t, "check_max_px": report["check_max_px"], "check_rms_px": report["check_rms_px"]}
        print(f"RPC fit ({label}) {t:.2f} s   check max {report['check_max_px']:.1e} px, rms {report['check_rms_px']:.1e} px")

    if (SHARED_DATA / "pleiades_ventoux").is_dir():
        results["rpc_dem"] = r = bench_rpc_dem(SHARED_DATA, min(n, 200_000), repeat=args.repeat,
                                               shareloc_python=args.shareloc_python)
        print_rpc_result(r)
    else:
        print(f"RPC over DEM skipped: the real Pleiades RPC is not at {SHARED_DATA}")

    results["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak memory {results['max_rss_mb']:.0f} MB")
    args.out = args.out or ROOT / "bench" / "results" / "localization.json"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
