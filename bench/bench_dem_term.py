"""The user DEM's error at the seed's full width, with a perfect matcher.

A rendered ``realistic`` scene (``bench/bench_fullsize.py --scale 1 --lines N``) holds the TRUE
model, the TRUE DEM (``reference/truth/dem_true.tif``) and the degraded user DEM
(``reference/dem.tif``). On a grid of the reference band, every image point is located on the
TRUE DEM with the TRUE model: ``(row, col) -> (lon, lat, h_true)``. A perfect matcher returns
that ``(row, col)`` with the DOM's ``(lon, lat)`` and the user DEM's height ``h_user(lon, lat)``;
so a GCP table with ``h_user`` carries the DEM term and nothing else, and one with ``h_true`` none.

1. the DEM term per GCP: the TRUE model's projection of ``(lon, lat, h_user)`` minus ``(row, col)``,
   pooled and per off-nadir class (``bench/gcp_truth.py``), with the height error under them;
2. each table through ``gcpcal calibrate`` (``--attitude auto`` and ``static``) and
   ``gcpcal truth error`` over the TRUE DEM: the calibrated models' truth error with and without
   the DEM term, per CCD (the inner CCDs see 0-16 deg, the outer 16-32 deg).

Matching error, DOM error and the render are left out on purpose: the match of a 512-line strip at
the full width fails at the coarse stage (docs/experiments.md), and this isolates the one term.

Usage::

    python bench/bench_dem_term.py --scene /tmp/fw/scale1_lines512_realistic_B2B4_dom45m/scene \\
        --work /tmp/fw/dem_term --out bench/results/fullwidth_dem_term_lines512_realistic.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import bench_fullsize  # noqa: E402  (the measured child runs and truth summaries)
from gcp_truth import ANGLE_CLASSES_DEG, _stats, gcp_truth_by_angle  # noqa: E402


def perfect_gcps(scene: Path, spacing_px: int) -> dict:
    """Grid points of the reference band located on the TRUE DEM, with both DEMs' heights.

    Parameters
    ----------
    scene : Path
        The simulator's output folder (``truth_manifest.json``, ``reference/``).
    spacing_px : int
        Grid spacing, pixels (rows and columns).

    Returns
    -------
    dict
        ``row, col, lon, lat, h_true, h_user, off_nadir_deg``, ``ccd`` (names) (ndarrays, shape (N,),
        points where both DEMs have a height) and ``band``.
    """
    from calibrate.actions._io import open_dem
    from sensor_models.readers import open_model

    truth = open_model(scene / "truth_manifest.json")
    band = truth.reference_band
    n_rows, n_cols = truth.image_shape
    rr, cc = np.meshgrid(np.arange(spacing_px / 2, n_rows, spacing_px), np.arange(spacing_px / 2, n_cols, spacing_px),
                         indexing="ij")
    row, col = rr.ravel() + 0.5, cc.ravel() + 0.5
    true_dem = open_dem(scene / "reference" / "truth" / "dem_true.tif", model=truth, band=band)
    user_dem = open_dem(scene / "reference" / "dem.tif", model=truth, band=band)
    lon, lat, h_true = truth.image_to_ground(row, col, dem=true_dem, band=band)
    with np.errstate(invalid="ignore"):
        h_user = user_dem.height_m(lon, lat)
    origin, direction = truth.rays_itrf(row, col, band=band)
    nadir = -origin / np.linalg.norm(origin, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(np.sum(nadir * direction, axis=1), -1.0, 1.0)))
    ok = np.isfinite(lon) & np.isfinite(h_true) & np.isfinite(h_user)
    # the CCD that imaged each point, by name, as the matcher writes it: where two CCDs overlap a
    # ground point projects into both, and the table must say which one its (row, col) is on
    names = np.array([look.name for look in truth.band_ccds(band)], dtype=object)
    ccd = names[truth.detector_index(col, band=band)]
    out = {k: v[ok] for k, v in dict(row=row, col=col, lon=lon, lat=lat, h_true=h_true, h_user=h_user,
                                     off_nadir_deg=angle, ccd=ccd).items()}
    out["band"] = band
    return out


def dem_term(scene: Path, pts: dict) -> dict:
    """The DEM term per GCP (px) and the height error (m), pooled and per off-nadir class."""
    from sensor_models.readers import open_model

    truth = open_model(scene / "truth_manifest.json")
    r, c = truth.ground_to_image(pts["lon"], pts["lat"], pts["h_user"], band=pts["band"], array=pts["ccd"])
    err = np.hypot(r - pts["row"], c - pts["col"])
    dh = pts["h_user"] - pts["h_true"]
    out = {"all": _stats(err), "dh_rms_m": round(float(np.sqrt(np.mean(dh**2))), 3), "by_off_nadir_deg": {}}
    for lo, hi in ANGLE_CLASSES_DEG:
        sel = (pts["off_nadir_deg"] >= lo) & (pts["off_nadir_deg"] < hi)
        out["by_off_nadir_deg"][f"{lo:g}-{hi:g}"] = {
            **_stats(err[sel]), "dh_rms_m": round(float(np.sqrt(np.mean(dh[sel] ** 2))), 3) if sel.any() else None,
            "mean_tan_off_nadir": round(float(np.mean(np.tan(np.radians(pts["off_nadir_deg"][sel])))), 4)
            if sel.any() else None}
    out["off_nadir_max_deg"] = round(float(pts["off_nadir_deg"].max()), 2)
    return out


def write_table(pts: dict, heights: str, path: Path, check_every: int = 5) -> Path:
    """The GCP CSV with ``h_true`` or ``h_user`` heights; every ``check_every``-th point a check point."""
    from gcpmatch.gcp_csv import write_gcps_csv
    from gcpmatch.gcps import GcpTable

    n = pts["row"].size
    kind = np.where(np.arange(n) % check_every == check_every - 1, "check", "gcp")
    table = GcpTable.from_arrays(pts["row"], pts["col"], pts["lon"], pts["lat"], pts[f"h_{heights}"],
                                 band=pts["band"], ccd=pts["ccd"], kind=kind)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_gcps_csv(table, path)


def calibrate_and_grade(fs, scene: Path, work: Path, step_px: float) -> dict:
    """``gcpcal calibrate`` (auto, static) of ``work/gcps.csv`` and their truth errors over the TRUE DEM."""
    g, logs = fs.gcpcal_command(), work / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    out = {}
    for att in ("auto", "static"):
        cal = work / f"cal_{att}"
        rec = fs.run_measured(f"calibrate_{att}", [g, "calibrate", str(scene / "manifest.json"), "--gcps",
                                                   str(work / "gcps.csv"), "--out", str(cal), "--attitude", att,
                                                   "--no-report", "-q"], logs, 1800)
        res = work / f"truth_cal_{att}.json"
        fs.run_measured(f"truth_cal_{att}", [g, "truth", "error", str(cal / "manifest.json"), "--truth",
                                             str(scene / "truth_manifest.json"), "--dem",
                                             str(scene / "reference" / "truth" / "dem_true.tif"), "--step",
                                             str(step_px), "--out", str(res), "-q"], logs, 1800)
        c = json.loads((cal / "calibration.json").read_text())
        acc = ((c.get("check_accuracy") or {}).get("after") or {}).get("absolute") or {}
        out[f"cal_{att}"] = {"rc": rec["rc"], "wall_s": rec["wall_s"], "check_rmse_after_px": acc.get("rmse_px"),
                             "truth_error": fs.summarize_truth(json.loads(res.read_text()), "B2")}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, required=True, help="a realistic scene folder of bench_fullsize.py")
    ap.add_argument("--work", type=Path, required=True, help="scratch folder (GCP tables, calibrations)")
    ap.add_argument("--out", type=Path, required=True, help="results JSON")
    ap.add_argument("--spacing", type=int, default=64, help="GCP grid spacing, px")
    ap.add_argument("--truth-step", type=float, default=16.0, help="truth-error grid spacing, px")
    args = ap.parse_args(argv)
    fs = bench_fullsize
    pts = perfect_gcps(args.scene, args.spacing)
    summ = json.loads((args.scene / "summary.json").read_text())
    result = {"scene": str(args.scene), "image": summ.get("image"), "n_points": int(pts["row"].size),
              "spacing_px": args.spacing, "injected_dem": {k: (summ.get("injected") or {}).get(k)
                                                           for k in ("dem", "dem_error_under_footprint_m")},
              "dem_term_per_gcp": dem_term(args.scene, pts), "loadavg_start": fs.loadavg(), "runs": {}}
    for heights in ("user", "true"):
        work = args.work / f"h_{heights}"
        write_table(pts, heights, work / "gcps.csv")
        result["runs"][f"h_{heights}"] = {"gcp_truth_error": gcp_truth_by_angle(args.scene / "truth_manifest.json",
                                                                                work / "gcps.csv"),
                                          **calibrate_and_grade(fs, args.scene, work, args.truth_step)}
    result["loadavg_end"] = fs.loadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
