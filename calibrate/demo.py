"""``gcpcal demo``: the main job on the embedded fixtures.

Today the sensor-model core: the example HY-1C-like scene (``fixtures/example_pushbroom``) is
localized image -> ground -> image over a dense grid of every CCD and band at three heights, an
RPC is fitted to it and checked, and a ``summary.json`` is written. GCP matching and calibration
join this job when they land (issues 4 and 5).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

__all__ = ["FIXTURE_MANIFEST", "run_demo"]

FIXTURE_MANIFEST = Path(__file__).resolve().parents[1] / "fixtures" / "example_pushbroom" / "manifest.json"


def run_demo(out_dir: Path, *, progress=None) -> dict:
    """Run the demo and return its summary (also written to ``out_dir/summary.json``)."""
    from sensor_models import open_model
    from sensor_models.rpc import fit_rpc

    t_start = time.perf_counter()
    step = progress or (lambda message: None)
    step("reading the example scene manifest")
    model = open_model(FIXTURE_MANIFEST)
    rows = []
    for band, ccds in model.bands.items():
        for i, ccd in enumerate(ccds):
            r, c = np.meshgrid(
                np.linspace(0.5, model.n_rows - 0.5, 100), np.linspace(ccd.first_col + 0.5, ccd.last_col - 0.5, 100), indexing="ij"
            )
            r, c = r.ravel(), c.ravel()
            for height in (0.0, 1500.0, 4000.0):
                step(f"round trip {band} {ccd.name} at {height:.0f} m")
                lon, lat, h = model.image_to_ground(r, c, height=height, band=band)
                r2, c2 = model.ground_to_image(lon, lat, h, band=band, ccd=i)
                err = np.hypot(r2 - r, c2 - c)
                rows.append(
                    {"band": band, "ccd": ccd.name, "height_m": height, "rms_px": float(np.sqrt(np.mean(err**2))), "max_px": float(err.max())}
                )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fits, outputs = [], []
    for i, ccd in enumerate(model.band_ccds()):
        step(f"fitting an RPC to {model.reference_band} {ccd.name}")
        rpc, report = fit_rpc(model.ccd_view(i), height_range_m=(0.0, 4000.0))
        path = out_dir / f"example_{ccd.name}_RPC.TXT"
        rpc.write(path)
        outputs.append(str(path))
        fits.append({"ccd": ccd.name, **report})
    corners_r = np.array([0.5, 0.5, model.n_rows - 0.5, model.n_rows - 0.5])
    corners_c = np.array([0.5, model.n_cols - 0.5, 0.5, model.n_cols - 0.5])
    lon, lat, _ = model.image_to_ground(corners_r, corners_c, height=0.0)
    summary = {
        "command": "demo",
        "scene": str(FIXTURE_MANIFEST),
        "footprint_lonlat_deg": np.stack([lon, lat], -1).round(6).tolist(),
        "round_trip": rows,
        "round_trip_max_px": max(r["max_px"] for r in rows),
        "rpc_fit": fits,
        "rpc_check_max_px": max(f["check_max_px"] for f in fits),
        "outputs": outputs + [str(out_dir / "summary.json")],
        "seconds": round(time.perf_counter() - t_start, 3),
    }
    from calibrate.cli import write_summary

    write_summary(out_dir / "summary.json", summary)
    return summary
