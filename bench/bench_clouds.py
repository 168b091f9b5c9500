"""Cloud detector benchmark: the base revision's detector against the current one, one run.

Called by :mod:`bench.bench_stages` (``--stages clouds``); runs on the cloud-free scene that
:mod:`bench.bench_match` simulates and on the same geometry simulated with 30 % cloud cover
(``match_scene_<rows>x<detectors>_clouds30``, made on first use). Per CCD, both detectors see
the same scene band and the same reference chips; the figures are the ratio of their best
times and the cloud fractions (per CCD and over the scene) of both, with the true fraction.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from baseline import load_baseline


def cloudy_twin(scene: Path, cover: float = 0.3) -> Path:
    """The bench scene simulated again with clouds (cached beside it)."""
    from sensor_models.simulate.config import SimConfig
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    out = scene.parent / f"{scene.name}_clouds{int(round(cover * 100))}"
    if not (out / "summary.json").exists():
        rows, det = (int(v) for v in scene.name.rsplit("_", 1)[1].split("x"))
        cfg = SimConfig()
        cfg = replace(cfg, scene=replace(cfg.scene, n_rows=rows, gsd_m=16.0),
                      camera=replace(cfg.camera, detectors_per_ccd=det, overlap_detectors=16),
                      reference=replace(cfg.reference, margin_m=1500.0),
                      clouds=replace(cfg.clouds, cover=cover)).validate()
        simulate_pushbroom(out, config=cfg)
    return out


def _ccd_pairs(folder: Path):
    """Scene band B2 and the reference chips of each CCD.

    The chips are rendered through the TRUE model, standing in for the coarse stage's
    pre-corrected model (the detector runs after it; the lab model is hundreds of pixels off).
    """
    from gcpmatch.extract import read_band
    from gcpmatch.reference import reference_for_ccd
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model, open_scene
    from sensor_models.terrain.dem import Dem

    model = open_model(folder / "truth_manifest.json")
    dem, dom = Dem.open(folder / "reference" / "dem.tif"), MapImage.open(folder / "reference" / "dom.tif")
    img = read_band(open_scene(folder / "manifest.json"), "B2")
    pairs = []
    for c, look in enumerate(model.detector_arrays("B2")):
        ref = reference_for_ccd(model, dem, dom, band="B2", ccd=c)
        pairs.append((np.ascontiguousarray(img[:, look.first_col : look.first_col + look.n_detectors]), ref))
    truth = json.loads((folder / "summary.json").read_text()).get("cloud_fraction")
    return pairs, truth


def _time(pairs, base, current, repeat: int):
    best = {"before": np.inf, "after": np.inf}
    out = {}
    for _ in range(repeat):
        for key, fn in (("before", base.detect_clouds), ("after", current.detect_clouds)):
            t = time.perf_counter()
            out[key] = [fn(s, r) for s, r in pairs]
            best[key] = min(best[key], time.perf_counter() - t)
    return best, out


def _fractions(results, pairs):
    per = [None if f is None else round(f, 4) for _, f in results]
    n_ok = [np.count_nonzero(np.isfinite(s) & np.isfinite(r) & (s > 0)) for s, r in pairs]
    total = sum(np.count_nonzero(m) for m, _ in results) / max(1, sum(n_ok))
    return per, round(float(total), 4)


def bench_clouds(model, dem, dom, scene: Path, repeat: int) -> dict:
    """Times and cloud fractions of both detectors on the clear scene and its cloudy twin."""
    import gcpmatch.clouds as current

    base = load_baseline("gcpmatch/clouds.py")
    result = {}
    for label, folder in (("clear", scene), ("cloudy", cloudy_twin(scene))):
        pairs, truth = _ccd_pairs(folder)
        best, out = _time(pairs, base, current, repeat)
        (per_b, tot_b), (per_a, tot_a) = _fractions(out["before"], pairs), _fractions(out["after"], pairs)
        inter = sum(np.count_nonzero(a[0] & b[0]) for a, b in zip(out["before"], out["after"]))
        union = sum(np.count_nonzero(a[0] | b[0]) for a, b in zip(out["before"], out["after"]))
        result[label] = {"scene": folder.name, "seconds": best, "speedup": best["before"] / best["after"],
                         "fraction_before": tot_b, "fraction_after": tot_a, "true_fraction": truth,
                         "per_ccd_before": per_b, "per_ccd_after": per_a,
                         "mask_iou": (inter / union) if union else 1.0}
    result["clear_speedup"] = result["clear"]["speedup"]
    result["cloudy_speedup"] = result["cloudy"]["speedup"]
    result["fractions"] = {k: (result[k]["fraction_before"], result[k]["fraction_after"], result[k]["true_fraction"])
                           for k in ("clear", "cloudy")}
    return result
