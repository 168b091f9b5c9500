"""Measure matcher variants on cached ideal and realistic scenes, against the TRUE model.

The expensive steps run once per scene and are cached in ``--cache``: ``gcpcal simulate
pushbroom`` (demo size at ``--gsd`` m, as ``bench/bench_profiles.py``: the realistic profile with
the Sentinel-2 red band as source radiance when present), the coarse SIFT pre-correction, the
reference chips per CCD, the window screening (no reference, no data, clouds) and, per window,
the TRUE shift: the ground point that the pre-corrected model sees at the window centre (DEM
intersection on the user's DEM, as :func:`gcpmatch.extract.extract_gcps` does) projected
through ``truth_manifest.json``, minus the centre. A GCP's truth error is then its measured
shift minus this true shift: exactly its error as an observation of the true model.

Each variant then correlates the cached windows (:func:`gcpmatch.extract.correlate_windows` with
its :class:`~gcpmatch.options.MatchOptions`) and runs the production outlier rejection and sigma
(:func:`gcpmatch.extract.reject_outliers`); the bench reports per variant: GCP count, truth
error rms / median / p95 (px, 2-D), the share of kept GCPs off by more than 1 px, and the sigma
calibration: rms of (truth error / sigma_px) per axis and the truth-error rms per decile of
sigma_px.

A variant whose ``reference_sigma_m`` is None takes the reference accuracy as production does
(:func:`sensor_models.maps.dom_inputs.reference_accuracy`: the tags the simulator writes into the
realistic DOM), projected per CCD into rows and columns through the pre-corrected model
(:func:`gcpmatch.uncertainty.reference_sigma_px`).

``--calibrate`` variants also go through ``match`` and ``gcpcal calibrate`` on the realistic
scenes: the calibration's variance factor and check RMSE, and the installation angles against
those of the same calibration on exact observations (each GCP's ground point projected through
the TRUE model, same points and weights: the model family's best fit to the truth), as z =
difference / reported sigma. ``--coverage-seeds`` repeats that chain on more realistic scenes
(Sentinel-2 and procedural source, one per seed) for the coverage of the 95 % intervals.

Usage: ``python bench/bench_matcher_realism.py --cache /tmp/mr [--variants a,b] [--out FILE]``
(default ``--out bench/results/matcher_realism.json``; the sigma-model comparison:
``--variants default,ccd,window_ref0 --calibrate default,ccd --coverage-seeds 3,5,7,9
--out bench/results/matcher_realism_sigma.json``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_profiles import _gcpcal  # noqa: E402  (the same gcpcal subprocess runner)
S2_RED = ROOT.parent / "shared" / "data" / "real_textures" / "sentinel2" / "s2_B04.jp2"
#: ``realistic_no_dom_error``: realistic with the DOM's geolocation error switched off (as
#: ``bench_profiles.py``'s ``no_dom_error`` ablation), so that what remains of the truth error is
#: the matcher's own (radiometric change, MTF, DEM error, resampling)
#: ``realistic_procedural``: realistic on the procedural source texture (the sigma model's
#: constants were fitted on the Sentinel-2 source: this scene checks them out of sample)
#: ``*_heldout``: the same on another seed (7), nothing fitted on it
PROFILES = ("ideal", "realistic", "realistic_no_dom_error", "realistic_procedural", "realistic_heldout",
            "realistic_procedural_heldout")
HELDOUT_SEED = 7


def simulate_once(cache: Path, profile: str, gsd_m: float, source) -> Path:
    """The scene folder of ``profile`` in ``cache``, simulated only when it is not there yet."""
    scene = cache / profile
    if (scene / "truth_manifest.json").exists():
        return scene
    config = cache / "config.json"
    config.write_text(json.dumps({"scene": {"gsd_m": gsd_m}, "reference": {"margin_m": 1000.0, "relief_m": 600.0}}))
    seed = HELDOUT_SEED if profile.endswith("_heldout") else None
    if "_seed" in profile:  # coverage scenes: realistic[_procedural]_seedN
        seed = int(profile.rsplit("_seed", 1)[1])
    profile_name = profile.replace("_heldout", "").split("_seed")[0]
    if profile == "realistic_no_dom_error":
        from sensor_models.simulate.config import load_config
        from sensor_models.simulate.profiles import PROFILES as SIM_PROFILES, Sourced
        from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

        off = {"dom_bias_m": Sourced((0.0, 0.0), "bench: DOM error off"), "dom_field_rms_m": Sourced(0.0, "bench")}
        simulate_pushbroom(scene, config=load_config(config), profile=replace(SIM_PROFILES["realistic"], name=profile,
                                                                               **off), dom=source)
        return scene
    sim = ["simulate", "pushbroom", "--out", scene, "--config", config, "--profile", profile.split("_")[0]]
    if profile_name == "realistic" and source is not None:
        sim += ["--dom", source]
    if seed is not None:
        sim += ["--seed", seed]
    _gcpcal(*sim)
    return scene


#: the reference chips' resampling kernel (``--chip-interpolation``; default: production's)
CHIP_KERNEL = {"name": None}


def chip_interpolation() -> str:
    """The kernel the chips are resampled with: ``--chip-interpolation`` or production's default."""
    from gcpmatch.reference import CHIP_INTERPOLATION

    return CHIP_KERNEL["name"] or CHIP_INTERPOLATION


def prepare_windows(scene: Path, options, *, dom_path: Path | None = None, band_offset=None) -> dict:
    """Coarse stage, reference chips, screened windows and TRUE shifts of one scene (arrays).

    Every window of every CCD's grid is kept, in grid order, CCD after CCD.

    ``dom_path`` (default: the scene's ``reference/dom.tif``) is the reference DOM. With
    ``band_offset`` = ``(east_m, north_m, crs)``, where the reference shows a ground feature minus
    where the scene's source shows it (:data:`change_pairs.BAND_OFFSET_M`, in the map CRS ``crs``),
    the ground point of each window centre is moved back by it before the TRUE projection, as
    :func:`change_pairs.truth_errors` does: the truth is the source's ground.

    Returns
    -------
    dict
        ``ws``, ``wr`` (n, w, w) float32 scene and reference windows (0 where they have no data);
        ``status`` (n,) str: ``""`` or the screening reason (no_reference, no_data, cloud);
        ``std_r`` (n,) reference standard deviation; ``true_shift`` (n, 2) px (NaN where the
        truth cannot project); ``rr``, ``cc`` (n,) window corners in the CCD image; ``ccd``
        (n,); ``grid`` (n_ccd, 2) grid shape per CCD; ``first_col`` (n_ccd,); ``ref_px_per_m``
        (n_ccd, 2, 2): (row, col) pixels per metre of east and north reference error.
    """
    from numpy.lib.stride_tricks import sliding_window_view

    from gcpmatch.clouds import detect_clouds
    from gcpmatch.coarse import scene_height_m
    from gcpmatch.extract import coarse_stage, grid_starts, read_band
    from gcpmatch.reference import reference_for_ccd, scene_gsd_m
    from gcpmatch.uncertainty import reference_sigma_px
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model, open_scene
    from sensor_models.terrain.dem import Dem

    opened = open_scene(scene / "manifest.json")
    model = opened.model
    truth = open_model(scene / "truth_manifest.json")
    band = model.reference_band
    img_all = read_band(opened, band)
    dem = Dem.open(scene / "reference" / "dem.tif")
    dom = MapImage.open(dom_path or scene / "reference" / "dom.tif")
    model_pc = coarse_stage(img_all, model, dem, dom, band, options).model
    w, half = options.window_px, options.window_px // 2
    out = {k: [] for k in ("ws", "wr", "status", "std_r", "true_shift", "rr", "cc", "ccd")}
    grids, first_cols, per_m = [], [], []
    height_m = scene_height_m(model_pc, dem, band=band)
    for i, look in enumerate(model_pc.detector_arrays(band)):
        kw = dict(band=band, first_col=look.first_col, n_detectors=look.n_detectors, height_m=height_m, array=i)
        per_m.append(np.array([reference_sigma_px(model_pc, 1.0, 0.0, **kw), reference_sigma_px(model_pc, 0.0, 1.0, **kw)]).T)
        ref = reference_for_ccd(model_pc, dem, dom, band=band, ccd=i, psf_sigma_px=options.psf_sigma_px,
                                interpolation=chip_interpolation())
        img = img_all[:, look.first_col:look.first_col + look.n_detectors]
        msk, _ = detect_clouds(img, ref)
        rs = grid_starts(img.shape[0], w, options.spacing_px)
        cs = grid_starts(img.shape[1], w, options.spacing_px)
        rr, cc = (a.ravel() for a in np.meshgrid(rs, cs, indexing="ij"))
        wr = sliding_window_view(ref, (w, w))[rr, cc]
        ws = sliding_window_view(img, (w, w))[rr, cc]
        status = np.full(rr.size, "", dtype=object)
        status[~(np.isfinite(ws).all(axis=(1, 2)) & (ws > 0).all(axis=(1, 2)))] = "no_data"
        status[~np.isfinite(wr).all(axis=(1, 2))] = "no_reference"
        cloudy = sliding_window_view(msk, (w, w))[rr, cc].mean(axis=(1, 2)) > options.cloud_window_fraction
        status[(status == "") & cloudy] = "cloud"
        r_c, c_c = rr + half, cc + half + look.first_col
        lon, lat, h = model_pc.image_to_ground(r_c.astype(float), c_c.astype(float), dem=dem, band=band, array=i)
        if band_offset is not None:
            lon, lat = _moved_back(lon, lat, band_offset)
        fin = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
        r_t, c_t = np.full(lon.size, np.nan), np.full(lon.size, np.nan)
        r_t[fin], c_t[fin] = truth.ground_to_image(lon[fin], lat[fin], h[fin], band=band,
                                                   array=np.full(fin.sum(), look.name, dtype=object))
        with np.errstate(invalid="ignore"):
            out["std_r"].append(wr.std(axis=(1, 2)))
        out["ws"].append(np.nan_to_num(ws).astype(np.float32))
        out["wr"].append(np.nan_to_num(wr).astype(np.float32))
        out["status"].append(status.astype(str))
        out["true_shift"].append(np.stack([r_t - r_c, c_t - c_c], axis=1))
        out["rr"].append(rr)
        out["cc"].append(cc)
        out["ccd"].append(np.full(rr.size, i))
        grids.append((rs.size, cs.size))
        first_cols.append(look.first_col)
    arrays = {k: np.concatenate(v) for k, v in out.items()}
    arrays["grid"] = np.array(grids)
    arrays["first_col"] = np.array(first_cols)
    arrays["ref_px_per_m"] = np.array(per_m)
    arrays["gsd_m"] = np.array(scene_gsd_m(model_pc, band=band))
    return arrays


def _moved_back(lon, lat, band_offset):
    """``(lon, lat)`` moved by minus ``band_offset`` = ``(east_m, north_m, crs)`` in that map CRS."""
    import pyproj

    east_m, north_m, crs = band_offset
    to_map = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    e, n = to_map.transform(lon, lat)
    return to_map.transform(e - east_m, n - north_m, direction="INVERSE")


def load_windows(cache: Path, profile: str, gsd_m: float, source, options) -> dict:
    """:func:`prepare_windows` of the cached scene, itself cached as ``PROFILE_windows.npz``."""
    from sensor_models.maps.dom_inputs import reference_accuracy

    path = cache / (f"{profile}_w{options.window_px}_s{options.spacing_px}_psf{options.psf_sigma_px}"
                    f"_{chip_interpolation()}_windows.npz")
    scene = simulate_once(cache, profile, gsd_m, source)
    if not path.exists():
        np.savez(path, **prepare_windows(scene, options))
    with np.load(path) as data:
        win = dict(data)
    win["stated_accuracy"] = reference_accuracy([str(scene / "reference" / "dom.tif")])
    win["status"] = win["status"].astype(object)
    return win


def run_variant(win: dict, options, phase_options: dict | None = None) -> dict:
    """Correlate, reject and assign sigma with ``options``; the kept windows' errors and sigmas."""
    from gcpmatch.extract import correlate_pairs, reject_outliers

    from sensor_models.maps.dom_inputs import reference_accuracy

    acc = win["stated_accuracy"] if options.reference_sigma_m is None else reference_accuracy(
        [], given_m=options.reference_sigma_m)
    ref_px = np.sqrt(np.mean((win["ref_px_per_m"] ** 2) @ np.array([acc.east_m**2, acc.north_m**2]), axis=1))
    seconds, err, sig, score = 0.0, [], [], []
    for i, (n_r, n_c) in enumerate(win["grid"]):
        sel = np.flatnonzero(win["ccd"] == i)
        status = win["status"][sel].copy()
        shift = np.full((sel.size, 2), np.nan)
        go = np.flatnonzero(status == "")
        t0 = time.perf_counter()
        res = correlate_pairs(win["wr"][sel[go]], win["ws"][sel[go]], options, phase_options=phase_options)
        seconds += time.perf_counter() - t0
        shift[go] = res.shift_px
        status[go] = res.status
        quality = {k: np.full(sel.size, np.nan) for k in res.quality}
        for k, v in res.quality.items():
            quality[k][go] = v
        keep, _, _, sigma = reject_outliers(status, win["std_r"][sel], shift, win["rr"][sel], win["cc"][sel],
                                            (int(n_r), int(n_c)), int(win["first_col"][i]), options, quality=quality,
                                            reference_sigma_px=float(ref_px[i]) if options.sigma_model == "window" else 0.0)
        ok = np.isfinite(win["true_shift"][sel[keep]]).all(axis=1)
        err.append((shift[keep] - win["true_shift"][sel[keep]])[ok])
        sig.append(sigma[ok])
        score.append(quality["score"][keep][ok])
    return {"err": np.concatenate(err), "sigma": np.concatenate(sig), "score": np.concatenate(score),
            "seconds": seconds}


def score_fit(err: np.ndarray, score: np.ndarray) -> dict:
    """Least-squares fit ``e^2 = a^2 (1 - s) / s + f^2`` of the squared per-axis truth errors.

    The constants of :mod:`gcpmatch.uncertainty` (``SCORE_SIGMA_PX`` = a, ``MATCH_FLOOR_PX`` = f)
    come from this fit on the ``realistic_no_dom_error`` scene.
    """
    g2 = (1.0 - score) / score
    y = np.mean(err**2, axis=1)
    coef = np.linalg.lstsq(np.stack([g2, np.ones_like(g2)], axis=1), y, rcond=None)[0]
    return {"a_px": float(np.sqrt(max(coef[0], 0.0))), "f_px": float(np.sqrt(max(coef[1], 0.0))), "n": int(y.size)}


def metrics(run: dict) -> dict:
    """GCP count, truth-error statistics (px) and sigma calibration of one variant's kept GCPs."""
    err, sig = run["err"], run["sigma"]
    dist = np.hypot(err[:, 0], err[:, 1])
    good = dist <= 1.0
    z = err / sig[:, None]
    order = np.argsort(sig)
    deciles = [{"sigma_px": float(np.median(sig[b])), "truth_rms_px_per_axis": float(np.sqrt(np.mean(err[b] ** 2)))}
               for b in np.array_split(order, 10) if b.size]
    return {
        "gcps": int(dist.size),
        "truth_error_px": {"rms": float(np.sqrt(np.mean(dist**2))), "median": float(np.median(dist)),
                           "p95": float(np.percentile(dist, 95)),
                           "rms_without_outliers": float(np.sqrt(np.mean(dist[good] ** 2)))},
        "outlier_share_gt_1px": float(1.0 - good.mean()),
        "normalized_rms": {"row": float(np.sqrt(np.mean(z[:, 0] ** 2))), "col": float(np.sqrt(np.mean(z[:, 1] ** 2))),
                           "pooled": float(np.sqrt(np.mean(z**2)))},
        "normalized_rms_without_outliers": {
            "row": float(np.sqrt(np.mean(z[good, 0] ** 2))), "col": float(np.sqrt(np.mean(z[good, 1] ** 2)))},
        "sigma_px_median": float(np.median(sig)),
        "sigma_deciles": deciles,
        "correlate_s": run["seconds"],
        "score_sigma_fit": score_fit(err, run["score"]),
    }


#: the realistic profile's DOM geolocation error per axis, metres: bias (1.2, -0.9) m and a
#: smooth field of 0.8 m rms per axis (sensor_models/simulate/profiles.py), what a user reads in
#: the reference's specification: sqrt((1.2^2 + 0.9^2) / 2 + 0.8^2) = 1.3 m
REALISTIC_REFERENCE_SIGMA_M = 1.3


def variants() -> dict:
    """Named (:class:`~gcpmatch.options.MatchOptions`, phase-correlation keywords) to measure."""
    from gcpmatch.options import MatchOptions

    base = MatchOptions(sigma_model="ccd")  # the matcher candidates, with the per-CCD sigma model
    window = replace(base, sigma_model="window")
    return {
        "default": (MatchOptions(), None),  # window model, the reference accuracy the DOM states
        "ccd": (base, None),
        "window_ref0": (replace(MatchOptions(), reference_sigma_m=0.0), None),
        "baseline": (base, None),
        "rank": (replace(base, radiometry="rank"), None),
        "gradient": (replace(base, radiometry="gradient"), None),
        "phase_only_eps1e-6": (base, {"eps": 1e-6}),
        "eps_0.2": (base, {"eps": 0.2}),
        "eps_1.0": (base, {"eps": 1.0}),
        "lowpass_0.25": (base, {"lowpass": 0.25}),
        "eps_2.0": (base, {"eps": 2.0}),
        "lowpass_0.2": (base, {"lowpass": 0.2}),
        "lowpass_0.15": (base, {"lowpass": 0.15}),
        "eps_1.0_lowpass_0.25": (replace(base, phase_eps=1.0, lowpass_cycles_px=0.25), None),
        "eps_1.0_lowpass_0.2": (base, {"eps": 1.0, "lowpass": 0.2}),
        "follow_0": (base, {"follow": 0}),
        "follow_2": (base, {"follow": 2}),
        "tukey_window": (base, {"window": "tukey"}),
        "psf_0.6": (replace(base, psf_sigma_px=0.6), None),
        "psf_0.3": (replace(base, psf_sigma_px=0.3), None),
        "min_score_0.8": (base, {"min_score": 0.8}),
        "window_48": (replace(base, window_px=48, spacing_px=32), None),
        "window_96": (replace(base, window_px=96, spacing_px=32), None),
        "sigma_window_ref0": (window, None),
        "sigma_window_ref0.65": (replace(window, reference_sigma_m=0.65), None),
        "sigma_window_ref1.3": (replace(window, reference_sigma_m=REALISTIC_REFERENCE_SIGMA_M), None),
        # the phase kernel's first pass at half resolution (the default) against the
        # full-resolution one, and the half one with the full one's peak-ratio threshold
        "first_pass_full": (MatchOptions(), {"first_pass": "full"}),
        "first_pass_half_pr2": (MatchOptions(), {"min_peak_ratio": 2.0}),
    }


INSTALLATION = ("installation.roll", "installation.pitch", "installation.yaw")


def _calibrate(scene: Path, gcps: Path, out: Path) -> dict:
    """``gcpcal calibrate`` of ``scene`` on ``gcps`` into ``out``; its calibration.json."""
    _gcpcal("calibrate", scene / "manifest.json", "--gcps", gcps, "--out", out, "--no-report")
    return json.loads((out / "calibration.json").read_text())


def _exact_gcps(scene: Path, gcps: Path, out: Path) -> None:
    """The same GCPs (ground points, sigma, kind) observed exactly: projected through the TRUE model."""
    from gcpmatch.gcp_csv import write_gcps_csv
    from gcpmatch.gcp_files import read_gcps
    from gcpmatch.gcps import GcpTable
    from sensor_models.readers import open_model

    table = read_gcps(gcps)
    truth = open_model(scene / "truth_manifest.json")
    row, col = truth.ground_to_image(table.lon, table.lat, table.h, band=str(table.band[0]), array=table.ccd)
    ok = np.isfinite(row) & np.isfinite(col)
    cols = {k: np.asarray(getattr(table, k))[ok] for k in ("lon", "lat", "h", "sigma_px", "band", "ccd", "score",
                                                         "kind", "id")}
    write_gcps_csv(GcpTable.from_arrays(row[ok], col[ok], **cols), out)


def _installation(cal: dict) -> dict:
    return {p["name"]: (p["value"], p["sigma"]) for p in cal["parameters"] if p["name"] in INSTALLATION}


def calibration_chain(cache: Path, profile: str, name: str, options) -> dict:
    """``match`` (the library action, with ``options``) then ``gcpcal calibrate`` on a cached scene:
    the calibration's variance factor and check RMSE, the figures the sigma model must serve, and
    z = (installation angle - its value calibrated on exact observations) / reported sigma."""
    from calibrate.actions.match import match_scene

    scene, out = cache / profile, cache / f"chain_{profile}_{name}"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    match_scene(scene / "manifest.json", dom_path=scene / "reference" / "dom.tif",
                dem_path=scene / "reference" / "dem.tif", out_path=out / "gcps.csv", options=options)
    cal = _calibrate(scene, out / "gcps.csv", out / "cal")
    _exact_gcps(scene, out / "gcps.csv", out / "exact.csv")
    exact = _installation(_calibrate(scene, out / "exact.csv", out / "cal_exact"))
    est = _installation(cal)
    z = {k.split(".")[1]: (est[k][0] - exact[k][0]) / est[k][1] for k in INSTALLATION}
    sigma_arcsec = {k.split(".")[1]: est[k][1] * 206264.806 for k in INSTALLATION}
    after = ((cal.get("check_accuracy") or {}).get("after") or {}).get("absolute") or {}
    return {"variance_factor": cal.get("variance_factor"), "check_rmse_px": after.get("rmse_px"),
            "installation_z": z, "installation_sigma_arcsec": sigma_arcsec}


ARCSEC_PER_RAD = 206264.806


def reference_floor_arcsec(scene: Path) -> float:
    """The angle that the DOM's stated accuracy (per axis) subtends from the orbit, arcsec: the
    part of a roll or pitch error that all GCPs share (their common reference error)."""
    from sensor_models.maps.dom_inputs import reference_accuracy

    altitude_m = json.loads((scene / "truth.json").read_text())["orbit"]["altitude_m"]
    return reference_accuracy([str(scene / "reference" / "dom.tif")]).per_axis_m / altitude_m * ARCSEC_PER_RAD


def coverage(results: dict, floors: dict | None = None) -> dict:
    """Share of the installation angles' 95 % intervals (|z| <= 1.96) holding the exact-observation value:
    as reported; with the covariance not scaled by a variance factor below 1; and with that plus the
    reference's common error (``floors``, arcsec per scene, on roll and pitch) added in quadrature."""
    z, z_unscaled, z_floor = [], [], []
    for p, c in results.items():
        vf = max(c["variance_factor"], 1.0) / c["variance_factor"]  # undo a down-scaling only
        for k, zk in c["installation_z"].items():
            sig = c["installation_sigma_arcsec"][k]
            diff = zk * sig
            z.append(zk)
            z_unscaled.append(diff / (sig * np.sqrt(vf)))
            floor = (floors or {}).get(p, 0.0) if k in ("roll", "pitch") else 0.0
            z_floor.append(diff / np.hypot(sig * np.sqrt(vf), floor))

    def share(v):
        v = np.abs(np.array(v))
        return {"covered_95": float(np.mean(v <= 1.96)), "rms_z": float(np.sqrt(np.mean(v**2)))}

    return {"angles": len(z), "as_reported": share(z), "unscaled": share(z_unscaled),
            "unscaled_with_reference_floor": share(z_floor)}


def _print_chain(name: str, profile: str, c: dict) -> None:
    z = " ".join(f"{k} {v:+.2f}" for k, v in c["installation_z"].items())
    print(f"{name:>22} {profile:>9}: calibration variance factor {c['variance_factor']:.2f}, "
          f"check RMSE {c['check_rmse_px']:.3f} px, installation z {z}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "matcher_realism.json")
    ap.add_argument("--gsd", type=float, default=20.0)
    ap.add_argument("--source", default=str(S2_RED) if S2_RED.exists() else "procedural")
    ap.add_argument("--variants", default=None, help="Comma-separated names (default: all).")
    ap.add_argument("--coverage-seeds", default="", help="Comma-separated seeds of the coverage scenes ('' for none).")
    ap.add_argument("--calibrate", default="default,ccd",
                    help="Variants also run through match + calibrate on the realistic scenes ('' for none).")
    ap.add_argument("--chip-interpolation", default=None, choices=("linear", "cubic", "lanczos"),
                    help="Resampling kernel of the reference chips (default: gcpmatch.reference.CHIP_INTERPOLATION).")
    args = ap.parse_args()
    CHIP_KERNEL["name"] = args.chip_interpolation
    args.cache.mkdir(parents=True, exist_ok=True)
    source = None if args.source == "procedural" else args.source
    table = variants()
    names = args.variants.split(",") if args.variants else list(table)
    results = {"gsd_m": args.gsd, "source": args.source, "chip_interpolation": chip_interpolation(), "variants": {}}
    for name in names:
        results["variants"][name] = {}
        options, phase_options = table[name]
        for p in PROFILES:
            win = load_windows(args.cache, p, args.gsd, source, options)
            m = metrics(run_variant(win, options, phase_options))
            results["variants"][name][p] = m
            print(f"{name:>22} {p:>9}: {m['gcps']:4d} GCPs  truth rms {m['truth_error_px']['rms']:.4f} "
                  f"p95 {m['truth_error_px']['p95']:.4f} out {100 * m['outlier_share_gt_1px']:.1f} %  "
                  f"z-rms row {m['normalized_rms']['row']:.2f} col {m['normalized_rms']['col']:.2f} "
                  f"pooled {m['normalized_rms']['pooled']:.2f}  "
                  f"({m['correlate_s']:.1f} s)", flush=True)
    results["calibration"] = {}
    scenes = ("realistic", "realistic_procedural", "realistic_heldout", "realistic_procedural_heldout")
    for name in filter(None, args.calibrate.split(",")):
        for p in scenes:
            simulate_once(args.cache, p, args.gsd, source)
            c = calibration_chain(args.cache, p, name, table[name][0])
            results["calibration"].setdefault(name, {})[p] = c
            _print_chain(name, p, c)
    seeds = [int(x) for x in filter(None, args.coverage_seeds.split(","))]
    if seeds:
        runs = {}
        for seed in seeds:
            for texture in ("realistic", "realistic_procedural"):
                p = f"{texture}_seed{seed}"
                simulate_once(args.cache, p, args.gsd, source)
                runs[p] = calibration_chain(args.cache, p, "default", table["default"][0])
                _print_chain("default", p, runs[p])
        floors = {p: reference_floor_arcsec(args.cache / p) for p in runs}
        results["coverage"] = {"runs": runs, "reference_floor_arcsec": floors, **coverage(runs, floors)}
        print("coverage of the 95 % installation intervals:", coverage(runs, floors), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
