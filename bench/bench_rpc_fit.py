"""Benchmark: how closely RPC00B fits follow the rigorous models of the fixtures and real products.

Per product (the first CCD of the reference band; the demo fixtures, and with ``../shared/data``
the SPOT 1-5 DIMAPs, SPOT 6 DIMAP v2, WorldView-2/-3), over -100 to 3000 m, check-grid maximum
errors (pixels) of:

* one cubic polynomial and one rational RPC over the CCD's image (``rpc_fit.fit_rpc``);
* the same two with the model's attitude replaced by the least-squares cubic in time of its
  rotation vector over the scene: what one RPC can reach once the attitude is smooth, so the
  difference from the first pair is the attitude's, not the fit's;
* the tiles ``gcpcal rpc`` writes into a folder (``rpc_fit.fit_rpc_tiles``, 0.01 px, 32 px):
  their number and largest error.

Writes ``bench/results/rpc_fit.json``. Usage: ``python bench/bench_rpc_fit.py [--out FILE] [--only NAME ...]``.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from sensor_models.geometry.ephemeris import Attitude  # noqa: E402
from sensor_models.models.pushbroom import PushbroomModel  # noqa: E402
from sensor_models.readers import open_model  # noqa: E402
from sensor_models.models.rpc_fit import fit_rpc, fit_rpc_tiles  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
HEIGHTS = (-100.0, 3000.0)
PRODUCTS = [("ideal demo", ROOT / "fixtures/hy1c_czi/manifest.json"),
            ("realistic demo", ROOT / "fixtures/hy1c_czi_realistic/manifest.json")]
PRODUCTS += [(f"SPOT {i}", SHARED / f"spot_dimap/SPOT{i}.DIM") for i in range(1, 6)]
PRODUCTS += [("SPOT 6", SHARED / "products/SPOT6.XML"), ("WorldView-2", SHARED / "products/WV2.XML"),
             ("WorldView-3", SHARED / "products/WV3.XML")]


def cubic_attitude(model: PushbroomModel) -> PushbroomModel:
    """``model`` with its attitude replaced by the least-squares cubic in time of the rotation
    vector (relative to mid-scene) over the scene and up to 64 lines beyond each end."""
    lt = model.line_timing
    t0, t1 = sorted((float(lt.seconds(-64.0)), float(lt.seconds(model.n_rows + 64.0))))
    t0, t1 = max(t0, model.attitude.span[0]), min(t1, model.attitude.span[1])
    t = np.linspace(t0, t1, 200)
    mid = model.attitude.rotation([(t0 + t1) / 2.0])[0]
    rv = (mid.inv() * model.attitude.rotation(t)).as_rotvec()
    V = np.vander((t - t.mean()) / (t1 - t0), 4)
    smooth = mid * Rotation.from_rotvec(V @ np.linalg.lstsq(V, rv, rcond=None)[0])
    return PushbroomModel(orbit=model.orbit, attitude=Attitude(t, smooth.as_quat(), frame=model.attitude.frame),
                          line_timing=lt, bands=model.bands, installation=model.installation, n_rows=model.n_rows,
                          reference_band=model.reference_band, attitude_correction=model.attitude_correction)


def one_product(path: Path) -> dict:
    model = open_model(path)
    band = model.reference_band
    view = model.detector_view(band, 0)
    smooth = cubic_attitude(model).detector_view(band, 0)
    row = {"image_shape": list(view.image_shape)}
    for label, m in (("", view), ("cubic_attitude_", smooth)):
        for form in ("polynomial", "rational"):
            row[f"{label}{form}_check_max_px"] = fit_rpc(m, height_range_m=HEIGHTS, form=form)[1]["check_max_px"]
    t = time.perf_counter()
    tiles = fit_rpc_tiles(view, height_range_m=HEIGHTS, max_error_px=0.01, min_tile_px=32)
    row.update(tiles=len(tiles), tiles_check_max_px=max(x.report["check_max_px"] for x in tiles),
               tiles_min_denominator_bound=min(x.report["denominator_lower_bound"] for x in tiles),
               tiles_seconds=round(time.perf_counter() - t, 1))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "rpc_fit.json")
    parser.add_argument("--only", nargs="*", help="product names to run (default: all)")
    args = parser.parse_args()
    results = {}
    for name, path in PRODUCTS:
        if args.only and name not in args.only:
            continue
        if not path.exists():
            print(f"{name}: {path} not found, skipped")
            continue
        r = results[name] = one_product(path)
        print(f"{name} {r['image_shape']}: one RPC poly {r['polynomial_check_max_px']:.2e} / rational "
              f"{r['rational_check_max_px']:.2e} px; cubic attitude: poly {r['cubic_attitude_polynomial_check_max_px']:.2e}"
              f" / rational {r['cubic_attitude_rational_check_max_px']:.2e} px; tiles {r['tiles']}, max "
              f"{r['tiles_check_max_px']:.4f} px ({r['tiles_seconds']} s)", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"height_range_m": HEIGHTS, "products": results}, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
