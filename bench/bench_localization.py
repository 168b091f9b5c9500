"""Benchmark: push-broom localization over a DEM, inverse localization, grid mode and RPC fit.

Prints figures and writes JSON (default ``bench/results/localization.json``). Runs on one core
(BLAS threads pinned to 1). Uses the real SRTM tile from ``../shared/data/dem`` when present,
else a synthetic DEM of the same size and relief.

Also RPC localization over the DEM, side by side: the base revision, the current code and GDAL's
RPC transformer (``bench_rpc_dem``; ``--rpc-only`` runs just that and writes
``bench/results/localization_rpc.json``).

Usage: ``python bench/bench_localization.py [--points 1000000] [--out FILE] [--rpc-only]``
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

from sensor_models.locgrid import InverseLocalizationGrid  # noqa: E402
from sensor_models.pushbroom_types import Installation  # noqa: E402
from sensor_models.rpc import fit_rpc  # noqa: E402
from sensor_models.synthetic import example_pushbroom_model  # noqa: E402
from sensor_models.terrain import Dem  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED_DEM = ROOT.parent / "shared" / "data" / "dem"


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


def bench_rpc_dem(model, dem, n: int, repeat: int = 3) -> dict:
    """RPC localization over the DEM: base revision, current code and GDAL, side by side.

    The RPC is fitted to CCD 0 of ``model``; GDAL's RPC transformer (rasterio
    ``RPCTransformer``, ``RPC_DEM`` = the same ellipsoidal heights as a GeoTIFF, bilinear,
    ``RPC_PIXEL_ERROR_THRESHOLD`` 1e-4 px) localizes the same pixels. Timings alternate, best of
    ``repeat``. Accuracy: reprojection residual (max norm, px) of each method's ground point
    through the RPC at its height, the DEM misfit ``|DEM(lon, lat) - h|`` (ours), and the ground
    distance to the base revision's solution (1e-9 px inversions), metres and pixels.
    """
    import sys
    import tempfile

    import rasterio
    from rasterio.transform import RPCTransformer

    sys.path.insert(0, str(ROOT / "bench"))
    from baseline import BASE_REV, load_baseline

    h_lo, h_hi = dem.height_range_m
    rpc, _ = fit_rpc(model.ccd_view(0), height_range_m=(h_lo, h_hi))
    base_rpc = load_baseline("sensor_models/rpc.py").RpcModel(**rpc._init_kwargs())
    rng = np.random.default_rng(7)
    rows = rng.uniform(300.0, 1700.0, n)
    cols = rng.uniform(50.0, rpc.image_shape[1] - 50.0, n)
    z = np.asarray(dem.heights_m, dtype=np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "dem_ellipsoid.tif"
        with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                           crs=dem.crs.to_wkt(), transform=dem.transform, nodata=np.nan) as ds:
            ds.write(z, 1)
        with RPCTransformer(rpc.to_rasterio(), RPC_DEM=str(path), RPC_DEMINTERPOLATION="bilinear",
                            RPC_PIXEL_ERROR_THRESHOLD=1e-4) as gdal:
            funcs = {"before": lambda: base_rpc.image_to_ground(rows, cols, dem=dem),
                     "after": lambda: rpc.image_to_ground(rows, cols, dem=dem),
                     "gdal": lambda: gdal.xy(rows, cols, offset="ul")}
            best = {k: np.inf for k in funcs}
            out = {}
            for _ in range(repeat):
                for k, f in funcs.items():
                    t0 = time.perf_counter()
                    out[k] = f()
                    best[k] = min(best[k], time.perf_counter() - t0)
    ref_lon, ref_lat, ref_h = out["before"]
    result = {"points": n, "base_rev": BASE_REV, "points_per_s": {k: n / v for k, v in best.items()},
              "speedup_vs_before": best["before"] / best["after"], "ratio_vs_gdal": best["gdal"] / best["after"]}
    lon_g, lat_g = (np.asarray(v, dtype=np.float64) for v in out["gdal"])
    for key, (lon, lat, h) in (("after", out["after"]), ("gdal", (lon_g, lat_g, None))):
        ok = np.isfinite(lon) & np.isfinite(ref_lon)
        d_m = np.hypot((lon - ref_lon)[ok] * np.cos(np.radians(ref_lat[ok])), (lat - ref_lat)[ok]) * 111_320.0
        hh = ref_h[ok] if h is None else h[ok]  # GDAL gives no height: reproject at the reference's
        r2, c2 = rpc.ground_to_image(lon[ok], lat[ok], hh)
        # the ground offset to the reference solution, in image pixels (both at its height)
        r3, c3 = rpc.ground_to_image(lon[ok], lat[ok], ref_h[ok])
        r4, c4 = rpc.ground_to_image(ref_lon[ok], ref_lat[ok], ref_h[ok])
        result[key] = {"found": float(np.isfinite(lon).mean()), "distance_to_before_m_max": float(d_m.max()),
                       "distance_to_before_px_max": float(np.max(np.hypot(r3 - r4, c3 - c4))),
                       "reprojection_px_max": float(np.max(np.maximum(abs(r2 - rows[ok]), abs(c2 - cols[ok]))))}
        if h is not None:
            result[key]["dem_misfit_m_max"] = float(np.nanmax(np.abs(dem.height_m(lon[ok], lat[ok]) - h[ok])))
    result["before"] = {"found": float(np.isfinite(ref_lon).mean())}
    return result


def rpc_only(n: int) -> None:
    """``--rpc-only``: the RPC-over-DEM comparison alone, written to ``localization_rpc.json``."""
    dem, dem_name = load_dem()
    model = example_pushbroom_model(n_rows=2000, installation=Installation(0.0, 0.0, np.radians(3.55)))
    r = bench_rpc_dem(model, dem, n)
    r.update(dem=dem_name, command=f"python bench/bench_localization.py --rpc-only --points {n}",
             machine=platform.machine())
    print(json.dumps(r, indent=1))
    out = ROOT / "bench" / "results" / "localization_rpc.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(r, indent=1) + "\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "localization.json")
    parser.add_argument("--rpc-only", action="store_true",
                        help="only the RPC-over-DEM comparison (base revision, current, GDAL); writes "
                             "bench/results/localization_rpc.json")
    args = parser.parse_args()
    n = args.points
    if args.rpc_only:
        rpc_only(n)
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
    rk, ck = grid.ground_to_image(lon[ok], lat[ok], h[ok], ccd=ccd[ok])
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
        t, (rpc, report) = timed(fit_rpc, m.ccd_view(0), height_range_m=(h_lo, h_hi))
        key = "rpc_fit" if m is model else "rpc_fit_no_jitter"
        results[key] = {"seconds": t, "check_max_px": report["check_max_px"], "check_rms_px": report["check_rms_px"]}
        print(f"RPC fit ({label}) {t:.2f} s   check max {report['check_max_px']:.1e} px, rms {report['check_rms_px']:.1e} px")

    results["rpc_dem"] = r = bench_rpc_dem(model, dem, min(n, 200_000))
    print(f"RPC over DEM       {r['points_per_s']['after']:12,.0f} points/s   x{r['speedup_vs_before']:.2f} vs before, "
          f"x{r['ratio_vs_gdal']:.2f} vs GDAL; reprojection max {r['after']['reprojection_px_max']:.1e} px "
          f"(GDAL {r['gdal']['reprojection_px_max']:.1e} px)")

    results["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak memory {results['max_rss_mb']:.0f} MB")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
