"""Stage benchmarks of ``gcpcal match``, before and after, side by side in one run.

The machine is shared and noisy, so each stage is timed for the code of the base revision
(:mod:`bench.baseline`, ``git show``) and for the current code in alternation, ``--repeat``
times, and the best time of each is kept; the figure is their ratio. Accuracy is compared on
the same inputs. Stages:

* ``reference``: the matcher's reference chips (:func:`gcpmatch.reference.reference_for_ccd`
  on every CCD, one worker; before = the base revision's whole chip pipeline), its DOM sampling
  (read, blur, remap) and ``locate_block`` shares (with the chips' settings, and the per-pixel
  path they are checked against) and the DEM intersection alone;
* ``clouds``: the cloud detector (:func:`gcpmatch.clouds.detect_clouds`) on every CCD of the
  (cloud-free) scene against its reference, and on a copy with synthetic clouds.

The scene is the one :mod:`bench.bench_match` simulates (``--rows``, ``--detectors``).

Usage: ``python bench/bench_stages.py [--rows 2000] [--detectors 512] [--repeat 3] [--stages reference,clouds]
[--exact]`` (``--exact``: the chips' positions against the model's exact per-pixel localization).
Writes ``bench/results/match_stages.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from baseline import BASE_REV, load_baseline  # noqa: E402


def alternate(funcs: dict, repeat: int) -> dict:
    """Best wall time (s) of each callable, run in alternation ``repeat`` times; plus results."""
    best = {k: np.inf for k in funcs}
    out = {}
    for _ in range(repeat):
        for k, f in funcs.items():
            t = time.perf_counter()
            out[k] = f()
            best[k] = min(best[k], time.perf_counter() - t)
    return best, out


def open_scene(rows: int, detectors: int):
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model
    from sensor_models.terrain.dem import Dem

    scene = ROOT / "bench" / "results" / f"match_scene_{rows}x{detectors}"
    if not (scene / "summary.json").exists():
        raise SystemExit(f"no scene at {scene}: run bench/bench_match.py --rows {rows} --detectors {detectors} first")
    return (open_model(scene / "manifest.json"), Dem.open(scene / "reference" / "dem.tif"),
            MapImage.open(scene / "reference" / "dom.tif"), scene)


def bench_reference(model, dem, dom, repeat: int) -> dict:
    """Reference chips, locate_block and the DEM intersection: base revision vs current."""
    import gcpmatch.reference as reference
    import sensor_models.imaging.locate as locate
    from sensor_models.terrain.intersect import intersect_dem_adaptive

    base = load_baseline("sensor_models/imaging/locate.py")
    # "before" is the base revision's whole chip pipeline: its reference_for_ccd, locate_block,
    # sample_map_image and MapImage (a file opened per window read, masked reads)
    base_reference = load_baseline("gcpmatch/reference.py")
    base_raster = load_baseline("sensor_models/maps/raster.py")
    base_reference.locate_block = base.locate_block
    base_reference.sample_map_image = base_raster.sample_map_image
    dom_before = base_raster.MapImage.open(dom.path)
    locate.dem_planes(dem)
    base.dem_planes(dem)
    band, n_ccd = "B2", len(model.detector_arrays("B2"))

    def chips(module, image):
        return lambda: [module.reference_for_ccd(model, dem, image, band=band, ccd=c, workers=1) for c in range(n_ccd)]

    def chips_one_session():  # what extract_gcps would get holding dom.reading() over its CCD loop
        with dom.reading():
            return chips(reference, dom)()

    t_chips, chips_out = alternate({"before": chips(base_reference, dom_before), "after": chips(reference, dom),
                                    "after_one_session": chips_one_session}, repeat)
    diff = np.concatenate([np.abs(a - b).ravel() for a, b in zip(chips_out["before"], chips_out["after"])])
    scale = float(np.nanstd(np.concatenate([a.ravel() for a in chips_out["before"]])))
    t_sample = bench_sampling(model, dem, dom, dom_before, base_raster, band, n_ccd, repeat)

    rows = model.image_shape[0]
    blocks = [(c, a, min(rows, a + 512)) for c in range(n_ccd) for a in range(0, rows, 512)]

    def loc(fn, **kw):
        return lambda: [fn(model, dem, [dom.grid], band=band, ccd=c, row0=a, row1=b, **kw) for c, a, b in blocks]

    # "after" = the chips' settings; "per_pixel" = the adaptive path with a 1 mm height tolerance
    # and 16-column nodes (the per-pixel chips), the path the chips' settings are checked against
    t_loc, loc_out = alternate({"before": loc(base.locate_block), "after": loc(locate.locate_block, **chip_settings(dom)),
                                "per_pixel": loc(locate.locate_block, tolerance_m=locate.HEIGHT_TOLERANCE_M)}, repeat)
    d_uv = np.concatenate([np.hypot(p.uv[0][0] - q.uv[0][0], p.uv[0][1] - q.uv[0][1]).ravel()
                           for p, q in zip(loc_out["before"], loc_out["after"])])
    d_h = np.concatenate([(p.h_m - q.h_m).ravel() for p, q in zip(loc_out["before"], loc_out["after"])])
    d_pp = position_differences(loc_out["per_pixel"], loc_out["after"])

    # the intersection alone, on the layers each version builds
    h_lo = np.float32(dem.height_range_m[0] - 50.0)
    h_hi = dem.height_range_m[1] + 50.0
    kw = {"band": band, "array": 1}
    look = model.detector_arrays(band)[1]
    c0, c1 = look.first_col, look.first_col + look.n_detectors
    lay_b = base._pixel_layers(model, kw, [base.MapProjector(base.MapGrid.of_dem(dem))], 0, 512, c0, c1, 16.0,
                               float(h_lo), h_hi)[0]
    cols = float(reference.NODE_STEP_COLS)  # the chips' settings
    lay_a = locate._pixel_layers(model, kw, [locate.MapProjector(locate.MapGrid.of_dem(dem))], 0, 512, c0, c1, 16.0,
                                 float(h_lo), h_hi, col_step=cols)[0]
    tol = max(locate.HEIGHT_TOLERANCE_M, locate.height_tolerance_for_position(
        dem, lay_a[2], lay_a[3], chip_settings(dom)["position_tolerance_m"]))
    t_int, _ = alternate({"before": lambda: base._intersect_dem(dem, *lay_b, h_lo, 4),
                          "after": lambda: intersect_dem_adaptive(dem, *lay_a, h_lo, tolerance_m=tol)}, repeat * 3)
    t_lay, _ = alternate({"before": lambda: base._pixel_layers(model, kw, [base.MapProjector(base.MapGrid.of_dem(dem))],
                                                              0, 512, c0, c1, 16.0, float(h_lo), h_hi),
                          "after": lambda: locate._pixel_layers(model, kw,
                                                               [locate.MapProjector(locate.MapGrid.of_dem(dem))],
                                                               0, 512, c0, c1, 16.0, float(h_lo), h_hi,
                                                               col_step=cols)}, repeat * 3)
    return {
        "pixels": int(sum(a.size for a in chips_out["after"])),
        "reference_chips_s": t_chips, "reference_chips_speedup": t_chips["before"] / t_chips["after"],
        "reference_chips_one_session_speedup": t_chips["before"] / t_chips["after_one_session"],
        "dom_sampling_s": t_sample, "dom_sampling_speedup": t_sample["before"] / t_sample["after"],
        "locate_block_s": t_loc, "locate_block_speedup": t_loc["before"] / t_loc["after"],
        "intersection_512_lines_s": t_int, "intersection_speedup": t_int["before"] / t_int["after"],
        "pixel_layers_512_lines_s": t_lay, "pixel_layers_speedup": t_lay["before"] / t_lay["after"],
        "locate_block_settings": {k: float(v) for k, v in chip_settings(dom).items()},
        "locate_block_vs_per_pixel": d_pp,
        "accuracy_vs_before": {
            "uv_dom_px_max": float(np.nanmax(d_uv)), "uv_dom_px_rms": float(np.sqrt(np.nanmean(d_uv**2))),
            "h_m_max": float(np.nanmax(np.abs(d_h))), "h_m_rms": float(np.sqrt(np.nanmean(d_h**2))),
            "nan_pixels_differ": int(np.count_nonzero(np.isnan(d_h) != np.isnan(d_uv))),
            "chip_dn_max": float(np.nanmax(diff)), "chip_dn_std": scale,
            "chip_nan_pixels_differ": int(sum(np.count_nonzero(np.isnan(a) != np.isnan(b))
                                              for a, b in zip(chips_out["before"], chips_out["after"]))),
        },
    }


def chip_settings(dom) -> dict:
    """The ``locate_block`` keywords :func:`gcpmatch.reference.reference_for_ccd` uses."""
    import gcpmatch.reference as reference
    import sensor_models.imaging.locate as locate

    return {"tolerance_m": locate.HEIGHT_TOLERANCE_M, "node_step_cols": reference.NODE_STEP_COLS,
            "position_tolerance_m": reference.POSITION_TOLERANCE_DOM_PX * dom.grid.resolution_m}


def position_differences(reference_blocks, blocks) -> dict:
    """Max and RMS distance (first grid's pixels) between two lists of PixelGround, NaN count."""
    e = np.concatenate([np.hypot(p.uv[0][0] - q.uv[0][0], p.uv[0][1] - q.uv[0][1]).ravel()
                        for p, q in zip(reference_blocks, blocks)])
    nan_differ = sum(int(np.count_nonzero(np.isnan(p.uv[0][0]) != np.isnan(q.uv[0][0])))
                     for p, q in zip(reference_blocks, blocks))
    ok = np.isfinite(e)
    return {"pixels": int(ok.sum()), "dom_px_max": float(e[ok].max()), "dom_px_rms": float(np.sqrt(np.mean(e[ok] ** 2))),
            "nan_pixels_differ": nan_differ}


def bench_exact(model, dem, dom, band: str = "B2") -> dict:
    """Positions of every pixel against the model's exact per-pixel localization.

    ``image_to_ground(row, col, dem=dem)`` (first crossing, heights to 1e-4 m) projected into the
    DOM grid, against the chips' settings and the per-pixel adaptive path (1 mm, 16-column nodes).
    """
    import sensor_models.imaging.locate as locate

    project = locate.MapProjector(dom.grid)
    rows = model.image_shape[0]
    out = {"chips": [], "per_pixel": []}
    for c, look in enumerate(model.detector_arrays(band)):
        for a in range(0, rows, 512):
            b = min(rows, a + 512)
            rr, cc = np.meshgrid(np.arange(a, b) + 0.5, look.first_col + np.arange(look.n_detectors) + 0.5, indexing="ij")
            lon, lat, _ = model.image_to_ground(rr.ravel(), cc.ravel(), dem=dem, band=band, array=c)
            u, v = project(lon, lat)
            exact = locate.PixelGround(None, [(u.reshape(rr.shape), v.reshape(rr.shape))])
            for k, kw in (("chips", chip_settings(dom)), ("per_pixel", {"tolerance_m": locate.HEIGHT_TOLERANCE_M})):
                out[k].append((exact, locate.locate_block(model, dem, [dom.grid], band=band, ccd=c, row0=a, row1=b, **kw)))
    return {k: position_differences(*zip(*pairs)) for k, pairs in out.items()}


def bench_sampling(model, dem, dom, dom_before, base_raster, band: str, n_ccd: int, repeat: int) -> dict:
    """The DOM sampling of the chips alone (read, blur, remap) on the same node indices:
    the base revision's ``sample_map_image`` and ``MapImage`` vs the current ones."""
    import gcpmatch.reference as reference
    import sensor_models.imaging.locate as locate
    from sensor_models.imaging.psf import psf_sigma_dom_px
    from sensor_models.maps.raster import sample_map_image

    sigma = psf_sigma_dom_px(reference.scene_gsd_m(model, band=band), dom.grid.resolution_m, 0.45)
    rows = model.image_shape[0]
    uv = [locate.locate_block(model, dem, [dom.grid], band=band, ccd=c, row0=a, row1=min(rows, a + 512),
                              tolerance_m=locate.HEIGHT_TOLERANCE_M).uv[0] for c in range(n_ccd) for a in range(0, rows, 512)]

    def after():
        with dom.reading():
            return [sample_map_image(dom, u, v, sigma_px=sigma, exact_weights=False) for u, v in uv]

    t, _ = alternate({"before": lambda: [base_raster.sample_map_image(dom_before, u, v, sigma_px=sigma) for u, v in uv],
                      "after": after}, repeat)
    return t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=2000)
    ap.add_argument("--detectors", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--stages", default="reference,clouds")
    ap.add_argument("--exact", action="store_true",
                    help="also compare the chips' locate_block with the model's exact per-pixel localization")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "match_stages.json")
    args = ap.parse_args()
    import cv2

    model, dem, dom, scene = open_scene(args.rows, args.detectors)
    result = {"scene": str(scene.name), "image_shape": [int(v) for v in model.image_shape], "base_rev": BASE_REV,
              "repeat": args.repeat, "opencv_threads": cv2.getNumThreads(), "machine": platform.machine(),
              "command": " ".join(["python"] + sys.argv)}
    stages = args.stages.split(",")
    if "reference" in stages:
        result["reference"] = r = bench_reference(model, dem, dom, args.repeat)
        print(f"reference chips  {r['reference_chips_s']['before']:.2f} s -> {r['reference_chips_s']['after']:.2f} s"
              f"  x{r['reference_chips_speedup']:.2f}   (locate_block x{r['locate_block_speedup']:.2f}, "
              f"intersection x{r['intersection_speedup']:.2f}, layers x{r['pixel_layers_speedup']:.2f})")
        print(f"   one DOM session over all CCDs: {r['reference_chips_s']['after_one_session']:.2f} s"
              f"  x{r['reference_chips_one_session_speedup']:.2f}")
        print(f"   DOM sampling {r['dom_sampling_s']['before']:.2f} s -> {r['dom_sampling_s']['after']:.2f} s"
              f"  x{r['dom_sampling_speedup']:.2f}")
        pp = r["locate_block_vs_per_pixel"]
        print(f"   locate_block {r['locate_block_s']['before']:.2f} s -> {r['locate_block_s']['after']:.2f} s "
              f"(per-pixel path {r['locate_block_s']['per_pixel']:.2f} s); chips' settings vs per-pixel path: "
              f"max {pp['dom_px_max']:.1e}, rms {pp['dom_px_rms']:.1e} DOM px, NaN differ {pp['nan_pixels_differ']}")
        if args.exact:
            r["vs_exact_model"] = ex = bench_exact(model, dem, dom)
            for k, e in ex.items():
                print(f"   {k} vs the exact model: max {e['dom_px_max']:.1e}, rms {e['dom_px_rms']:.1e} DOM px, "
                      f"NaN differ {e['nan_pixels_differ']}")
        print(f"   vs before: uv max {r['accuracy_vs_before']['uv_dom_px_max']:.1e} DOM px, "
              f"h max {r['accuracy_vs_before']['h_m_max'] * 1e3:.2f} mm, chips max {r['accuracy_vs_before']['chip_dn_max']:.3f} DN "
              f"(DN std {r['accuracy_vs_before']['chip_dn_std']:.0f}), NaN pixels differ "
              f"{r['accuracy_vs_before']['chip_nan_pixels_differ']}")
    if "clouds" in stages:
        from bench_clouds import bench_clouds

        result["clouds"] = c = bench_clouds(model, dem, dom, scene, args.repeat)
        print(f"clouds (cloud-free) x{c['clear_speedup']:.2f}, (cloudy) x{c['cloudy_speedup']:.2f}; "
              f"fractions {c['fractions']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
