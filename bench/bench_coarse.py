"""Coarse stage: the brute-force reference search against the adaptive and the fast searches.

The three searches of :func:`gcpmatch.coarse.coarse_match` (``search="exhaustive"``: 12 000 SIFT
features in both images, brute-force matching; ``"adaptive"``, the default; ``"fast"``: the
half-resolution pass of :mod:`gcpmatch.coarse_fast` where trusted) run on the same inputs in one
process, interleaved, with one OpenCV thread (``cv2.setNumThreads(1)``); the time is the CPU time
of the whole coarse stage (best of ``--repeat``). The cases:

* ``demo_realistic``: the realistic demo fixture (``fixtures/hy1c_czi_realistic``, B2);
* ``pleiades``: the Pleiades tutorial pair (``docs/tutorial_real_scene.md``): the right crop with
  the 60-line RPC bias against the left crop orthorectified (``gcpcal ortho``, made on first use);
* ``sentinel2``, ``landsat8``: the realistic profile rendered from the Sentinel-2 red band and
  the Landsat 8 panchromatic band of ``../shared/data/real_textures`` as source radiance (15 and
  20 m pixels: the scene inside the crop);
* ``large_sentinel2``: the same at 10 m over 1536 lines and 1500 columns (the S2 crop's size);
* ``clouds60``: 60 % cloud cover; ``texture_poor``: 60 % sea and SNR 30; ``far``: 300 px
  across-track error and a 5 degree yaw (simulated, procedural reference).

Simulated scenes are made once in ``--cache``. Per case it prints the three times and the
speed-ups against the reference search, whether the fast pass was trusted, RANSAC and kept
inliers, the largest distance of each pre-correction from the reference search's at four points
2 % inside the image's corners (pixels) and, for simulated scenes, each pre-correction's largest
error against the TRUE model; for the Pleiades pair, the recovered RPC line offset (the geometry
file carries a 60-line bias); then the CPU seconds of the SIFT detections (scene and DOM window,
``gcpmatch.coarse_sift.sift_features``) and the pixels they saw, and the rest of the stage
(matching, RANSAC, the DOM read, the warp, the pre-correction). JSON only where ``--json PATH`` says.

Usage: ``python bench/bench_coarse.py [--cache /tmp/bench_coarse] [--cases demo_realistic,far]
[--repeat 2] [--json out.json] [--data ../shared/data]`` (``GCPCAL_SHARED_DATA`` also names the
data folder)
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: ``../shared/data`` beside the checkout (``--data`` for another place)
DATA = {"root": Path(os.environ.get("GCPCAL_SHARED_DATA", ROOT.parent / "shared" / "data"))}
SOURCES = {"sentinel2": ("real_textures", "sentinel2", "s2_B04.jp2"),
           "landsat8": ("real_textures", "landsat8", "l8_B8.tif")}
CASES = ("demo_realistic", "pleiades", "sentinel2", "landsat8", "large_sentinel2", "clouds60", "texture_poor",
         "far")
SEARCHES = ("exhaustive", "adaptive", "fast")


def _small_config(**changes):
    """A 4-CCD x 160-detector, 384-line single-band scene (as ``tests/test_match.py``)."""
    from sensor_models.simulate.config import SimConfig

    cfg = SimConfig()
    cam = replace(cfg.camera, detectors_per_ccd=160, bands=("B2",), reference_band="B2", band_offsets_px=(0.0,))
    rad = replace(cfg.radiometry, band_gain=(1.0,), band_offset_dn=(40.0,), band_gamma=(0.9,))
    cfg = replace(cfg, scene=replace(cfg.scene, n_rows=384), camera=cam, radiometry=rad)
    for section, values in changes.items():
        cfg = replace(cfg, **{section: replace(getattr(cfg, section), **values)})
    return cfg.validate()


def _source(name: str) -> Path:
    return DATA["root"].joinpath(*SOURCES[name])


def _simulate(cache: Path, name: str) -> Path:
    """The simulated scene folder of case ``name`` (made on first use)."""
    from sensor_models.simulate.profiles import PROFILES
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    out = cache / name
    if (out / "truth_manifest.json").exists():
        return out
    if name in SOURCES:
        gsd_m = {"sentinel2": 15.0, "landsat8": 20.0}[name]  # the scene inside the source crop
        cfg = _small_config(scene={"gsd_m": gsd_m}, reference={"margin_m": 1000.0})
        simulate_pushbroom(out, config=cfg, profile=PROFILES["realistic"], dom=_source(name))
    elif name == "large_sentinel2":  # 1536 lines x 4 CCDs of 384 detectors at 10 m: 15 x 15 km
        cfg = _small_config(scene={"n_rows": 1536, "gsd_m": 10.0}, camera={"detectors_per_ccd": 384},
                            reference={"margin_m": 1000.0})
        simulate_pushbroom(out, config=cfg, profile=PROFILES["realistic"], dom=_source("sentinel2"))
    elif name == "clouds60":
        simulate_pushbroom(out, config=_small_config(clouds={"cover": 0.6}))
    elif name == "texture_poor":
        simulate_pushbroom(out, config=_small_config(reference={"sea_fraction": 0.6}, radiometry={"snr": 30.0}))
    elif name == "far":  # roll 0.66 degrees ~ 300 px across at 30 m and 780 km, yaw 5 degrees
        simulate_pushbroom(out, config=_small_config(errors={"installation_deg": (0.66, 0.1, 5.0)},
                                                     reference={"margin_m": 12000.0}))
    return out


def _pleiades(cache: Path) -> dict:
    """The tutorial's right crop with the biased RPC, the left crop's orthoimage as DOM."""
    from calibrate.cli import main
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_scene
    from sensor_models.terrain.dem import Dem
    from gcpmatch.extract import read_band

    data = DATA["root"]
    src = data / "pleiades_ventoux"
    dem_args = ["--dem", str(data / "dem" / "N44E005.hgt"), "--dem-datum", "egm96",
                "--geoid", str(data / "dem" / "egm96_15.gtx")]
    work = cache / "pleiades"
    work.mkdir(parents=True, exist_ok=True)
    for name, target in (("right.tif", src / "right_image.tif"), ("right.geom", src / "right_image_bias.geom")):
        if not (work / name).exists():
            os.symlink(target, work / name)
    ortho = work / "left_ortho.tif"
    if not ortho.exists():
        rc = main(["-q", "ortho", str(src / "left_image.tif"), *dem_args, "--resolution", "0.5", "--out", str(ortho)])
        if rc != 0:
            raise SystemExit(f"gcpcal ortho -> {rc}")
    scene = open_scene(work / "right.tif")
    band = scene.model.reference_band
    return {"img": read_band(scene, band), "model": scene.model, "band": band, "truth": None,
            "dem": Dem.open(data / "dem" / "N44E005.hgt", vertical_datum="egm96", geoid=data / "dem" / "egm96_15.gtx"),
            "dom": MapImage.open(ortho), "max_offset_px": 150.0, "capture_px": 8.0}


def load_case(cache: Path, name: str) -> dict | None:
    """Inputs of case ``name``: image, model, DEM, DOM, band, TRUE model or None, options."""
    from gcpmatch.extract import read_band
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model, open_scene
    from sensor_models.terrain.dem import Dem

    if name == "pleiades":
        return _pleiades(cache) if (DATA["root"] / "pleiades_ventoux").is_dir() else None
    source = "sentinel2" if name == "large_sentinel2" else name
    if source in SOURCES and not _source(source).exists():
        return None
    folder = ROOT / "fixtures" / "hy1c_czi_realistic" if name == "demo_realistic" else _simulate(cache, name)
    scene = open_scene(folder / "manifest.json")
    return {"img": read_band(scene, "B2"), "model": scene.model, "band": "B2",
            "truth": open_model(folder / "truth_manifest.json"), "dem": Dem.open(folder / "reference" / "dem.tif"),
            "dom": MapImage.open(folder / "reference" / "dom.tif"),
            "max_offset_px": 1000.0, "capture_px": 16.0}


def corners_apart_px(a, b, case: dict) -> float:
    """Largest pixel distance, at four points 2 % inside the image's corners, between where
    models ``a`` and ``b`` see the ground point that ``a`` localizes there (at the DEM height)."""
    from gcpmatch.coarse import scene_height_m

    n_rows, n_cols = a.image_shape
    inset_r, inset_c = 0.02 * n_rows, 0.02 * n_cols
    rows = np.array([inset_r, inset_r, n_rows - inset_r, n_rows - inset_r])
    cols = np.array([inset_c, n_cols - inset_c, inset_c, n_cols - inset_c])
    h = scene_height_m(a, case["dem"], band=case["band"])
    lon, lat, _ = a.image_to_ground(rows, cols, height=h, band=case["band"])
    arrays = a.detector_index(cols, band=case["band"]) if hasattr(a, "detector_index") else [None] * 4
    out = []
    for k in range(4):
        arr = None if arrays[k] is None else int(arrays[k])
        r, c = b.ground_to_image(lon[k:k + 1], lat[k:k + 1], np.array([h]), band=case["band"], array=arr)
        out.append(float(np.hypot(r[0] - rows[k], c[0] - cols[k])))
    return float(np.nanmax(out))


def _truth_max(case: dict, model) -> float | None:
    if case["truth"] is None:
        return None
    from sensor_models.simulate.truth import truth_error

    return truth_error(case["truth"], model, dem=case["dem"], step_px=32)["max_px"]


class _SiftClock:
    """CPU seconds and pixels of the SIFT detections (``sift_features``) inside a ``with`` block."""

    def __enter__(self):
        import gcpmatch.coarse_fast as fast
        import gcpmatch.coarse_sift as sift

        self.seconds, self.pixels, self._modules = 0.0, 0, (sift, fast)
        self._original = sift.sift_features

        def timed(img, mask, n_features):
            t0 = time.process_time()
            try:
                return self._original(img, mask, n_features)
            finally:
                self.seconds += time.process_time() - t0
                self.pixels += img.size

        for module in self._modules:
            module.sift_features = timed
        return self

    def __exit__(self, *exc):
        for module in self._modules:
            module.sift_features = self._original


def _run(case: dict, search: str):
    """CPU seconds of one coarse stage, its result (or the error's text) and its SIFT clock."""
    from gcpmatch.coarse import CoarseMatchError, coarse_match

    with _SiftClock() as clock:
        t0 = time.process_time()
        try:
            result = coarse_match(case["img"], case["model"], case["dem"], case["dom"], band=case["band"],
                                  max_offset_px=case["max_offset_px"], capture_px=case["capture_px"], search=search)
        except CoarseMatchError as exc:
            result = str(exc)
        seconds = time.process_time() - t0
    return seconds, result, clock


def _line_offset(model):
    pv = model.parameters()
    return float(pv.values[pv.index(["bias.row.a0"])][0]) if "bias.row.a0" in pv.names else None


def run_case(case: dict, repeat: int) -> dict:
    """The three searches ``repeat`` times, interleaved; best CPU times, counts and pre-corrections."""
    times = {k: [] for k in SEARCHES}
    results, sift = {}, {}
    for _ in range(repeat):
        for key in SEARCHES:
            dt, results[key], clock = _run(case, key)
            times[key].append(dt)
            if dt == min(times[key]):  # the SIFT share of the best run
                sift[key] = clock
    row = {f"{k}_s": min(v) for k, v in times.items()}
    for key in SEARCHES:
        row[f"{key}_sift_s"], row[f"{key}_sift_mpx"] = sift[key].seconds, sift[key].pixels / 1e6
    ref = results["exhaustive"]
    for key in SEARCHES:
        row[f"{key}_x"] = row["exhaustive_s"] / row[f"{key}_s"]
        r = results[key]
        if isinstance(r, str):
            row[f"{key}_error"] = r
            continue
        row.update({f"{key}_ransac": r.n_ransac_inliers, f"{key}_inliers": r.n_inliers,
                    f"{key}_truth_max_px": _truth_max(case, r.model), f"{key}_line_offset": _line_offset(r.model)})
        if key != "exhaustive" and not isinstance(ref, str):
            row[f"{key}_apart_px"] = corners_apart_px(ref.model, r.model, case)
    if not isinstance(results["fast"], str):
        row["fast_trusted"] = bool(results["fast"].fast_pass)
    return row


def _fmt(v, spec="{:.2f}"):
    return "-" if v is None else spec.format(v)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--cache", type=Path, default=Path("/tmp/bench_coarse"))
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--data", type=Path, default=DATA["root"], help="the shared data folder")
    args = parser.parse_args(argv)
    DATA["root"] = args.data
    cv2.setNumThreads(1)
    args.cache.mkdir(parents=True, exist_ok=True)
    print(f"load {open('/proc/loadavg').read().split()[0:3]}, 1 OpenCV thread, CPU s best of {args.repeat}")
    print(f"{'case':15s} {'exh s':>6s} {'adapt':>6s} {'fast':>6s} {'x ad':>5s} {'x fa':>5s} {'fast?':>5s} "
          f"{'ransac e/a/f':>14s} {'kept e/a/f':>14s} {'apart a/f px':>12s} {'truth e/a/f px':>17s} {'line off e/a/f':>20s}")
    rows = {}
    for name in args.cases.split(","):
        case = load_case(args.cache, name)
        if case is None:
            print(f"{name:15s} skipped: its data are not in {DATA['root']}")
            continue
        row = rows[name] = run_case(case, args.repeat)
        errors = [f"{k}: {row[k + '_error']}" for k in SEARCHES if k + "_error" in row]
        if errors:
            print(f"{name:15s} {row['exhaustive_s']:6.2f} {row['adaptive_s']:6.2f} {row['fast_s']:6.2f} " + "; ".join(errors))
            continue
        trio = lambda key, spec="{:d}": "/".join(_fmt(row[f"{k}_{key}"], spec) for k in SEARCHES)  # noqa: E731
        print(f"{name:15s} {row['exhaustive_s']:6.2f} {row['adaptive_s']:6.2f} {row['fast_s']:6.2f} "
              f"{row['adaptive_x']:5.1f} {row['fast_x']:5.1f} {('yes' if row['fast_trusted'] else 'no'):>5s} "
              f"{trio('ransac'):>14s} {trio('inliers'):>14s} "
              f"{_fmt(row['adaptive_apart_px'])}/{_fmt(row['fast_apart_px']):<6s} "
              f"{trio('truth_max_px', '{:.2f}'):>17s} {trio('line_offset', '{:.2f}'):>20s}")
        rest = "/".join(f"{row[k + '_s'] - row[k + '_sift_s']:.2f}" for k in SEARCHES)
        print(f"{'':15s} SIFT detection e/a/f {trio('sift_s', '{:.2f}')} s on {trio('sift_mpx', '{:.2f}')} Mpx; "
              f"the rest {rest} s")
    print(f"load {open('/proc/loadavg').read().split()[0:3]}")
    if args.json:
        args.json.write_text(json.dumps({"load": open("/proc/loadavg").read().split()[:3], "cases": rows}, indent=1))


if __name__ == "__main__":
    main()
