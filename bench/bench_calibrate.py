"""Benchmark: exterior-interior calibration of a 4-CCD, 4-band push-broom model from GCPs.

For 1e4, 1e5 and 1e6 GCPs (spread over the four bands and CCDs, 0.3 px noise) the LAB model
is calibrated against a TRUE model (installation errors of a few tenths of a degree,
directional-angle offsets and distortion of a few pixels). Reports the wall time, the number of
model evaluations (one ``image_jacobian`` pass over all GCPs each), the time of one such pass,
the peak memory (tracemalloc of the calibration and the process's maximum RSS), and the
recovered accuracy (RMS over a dense check grid of every CCD and band). Runs on one core (BLAS
threads pinned to 1 before numpy is imported).

Targets: 1e5 GCPs <= 5 s, 1e6 <= 60 s, memory <= 2 GB.

Usage: ``python bench/bench_calibrate.py [--sizes 10000,100000,1000000] [--out FILE]``
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
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from calibrate.absolute import calibrate_model  # noqa: E402
from calibrate.config import CalibrationOptions  # noqa: E402
from gcpmatch.gcps import GcpTable  # noqa: E402
from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BANDS = ("B1", "B2", "B3", "B4")


def true_and_lab(n_rows: int = 6000, seed: int = 0):
    """LAB model and a TRUE model with installation and interior errors (same orbit)."""
    design = CameraDesign(n_ccds=4, detectors_per_ccd=512)
    lab = example_pushbroom_model(n_rows=n_rows, design=design)
    p = lab.parameters()
    values = p.values.copy()
    pos = {n: i for i, n in enumerate(p.names)}
    rng = np.random.default_rng(seed)
    ifov = design.ifov_rad
    for name, deg in (("roll", 0.3), ("pitch", -0.2), ("yaw", 0.5)):
        values[pos[f"installation.{name}"]] += np.radians(deg)
    n = design.detectors_per_ccd
    for b in BANDS:
        for c in lab.band_ccds(b):
            for axis in ("tan_psi_x", "tan_psi_y"):
                for k, px in enumerate((3.0, 2.0, 2.0, 1.0)):
                    values[pos[f"{b}.{c.name}.{axis}.c{k}"]] += rng.uniform(-px, px) * ifov / n**k
    return lab, lab.with_parameters(values)


def height(row, col):
    return 400.0 + 300.0 * np.sin(row / 700.0) * np.cos(col / 500.0)


def simulate_gcps(true, n_points: int, *, noise_px: float = 0.3, seed: int = 1):
    """GCPs over every band and CCD: localized with TRUE, observed with Gaussian noise."""
    rng = np.random.default_rng(seed)
    row = rng.uniform(1.0, true.n_rows - 1.0, n_points)
    col = rng.uniform(0.5, true.n_cols - 0.5, n_points)
    band = np.array(BANDS, dtype=object)[rng.integers(0, len(BANDS), n_points)]
    lon = np.empty(n_points)
    lat = np.empty(n_points)
    h = height(row, col)
    for b in BANDS:
        sel = band == b
        ccd = true.ccd_index(col[sel], band=b)
        lon[sel], lat[sel], _ = true.image_to_ground(row[sel], col[sel], height=h[sel], band=b, array=ccd)
    row_obs = row + rng.normal(0.0, noise_px, n_points)
    col_obs = col + rng.normal(0.0, noise_px, n_points)
    return row_obs, col_obs, lon, lat, h, band


def grid_rms(true, model, n: int = 25) -> float:
    """RMS (px) of the calibrated model against TRUE over a grid of every band and CCD."""
    errors = []
    for b in BANDS:
        for k, c in enumerate(true.band_ccds(b)):
            r, cc = np.meshgrid(
                np.linspace(5.0, true.n_rows - 5.0, n), np.linspace(c.first_col + 0.5, c.last_col - 0.5, n), indexing="ij"
            )
            r, cc = r.ravel(), cc.ravel()
            lon, lat, h = true.image_to_ground(r, cc, height=height(r, cc), band=b, array=k)
            rr, ccc = model.ground_to_image(lon, lat, h, band=b, array=k)
            errors.append(np.hypot(rr - r, ccc - cc))
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(e * e)))


def one_pass_seconds(lab, gcps) -> float:
    """Seconds of one image_jacobian pass (exterior + one CCD interior names) over all GCPs."""
    row, col, lon, lat, h, band = gcps
    t0 = time.perf_counter()
    for b in BANDS:
        sel = band == b
        ccd = lab.ccd_index(col[sel], band=b)
        for k, c in enumerate(lab.band_ccds(b)):
            s = np.nonzero(ccd == k)[0]
            names = ["installation.roll", "installation.pitch", "installation.yaw"] + [
                f"{b}.{c.name}.{a}.c{j}" for a in ("tan_psi_x", "tan_psi_y") for j in range(4)
            ]
            for a in range(0, s.size, 50_000):
                i = np.nonzero(sel)[0][s[a : a + 50_000]]
                lab.image_jacobian(lon[i], lat[i], h[i], band=b, names=names, array=k)
    return time.perf_counter() - t0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="10000,100000,1000000")
    parser.add_argument("--traced", action="store_true", help="also trace peak allocations (slow)")
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "calibrate.json"))
    args = parser.parse_args(argv)
    sizes = [int(float(s)) for s in args.sizes.split(",") if s.strip()]

    lab, true = true_and_lab()
    rows = []
    for n in sizes:
        gcps = simulate_gcps(true, n)
        row, col, lon, lat, h, band = gcps
        table = GcpTable.from_arrays(row, col, lon, lat, h, band=band)
        options = CalibrationOptions(scheme="exterior-interior")
        t0, c0 = time.perf_counter(), time.process_time()
        result = calibrate_model(lab, table, options=options)
        seconds, cpu_seconds = time.perf_counter() - t0, time.process_time() - c0
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        peak = float("nan")
        if args.traced:  # tracemalloc slows allocation down: a separate, untimed run
            tracemalloc.start()
            calibrate_model(lab, table, options=options)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        passes = sum(len(s["log"]) for s in result.steps)
        per_pass = one_pass_seconds(lab, gcps)
        entry = {
            "n_gcps": n,
            "seconds": seconds,
            "cpu_seconds": cpu_seconds,
            "model_passes": passes,
            "seconds_per_pass": per_pass,
            "model_share": min(1.0, passes * per_pass / seconds),
            "peak_traced_mb": peak / 2**20,
            "max_rss_mb": rss,
            "success": result.success,
            "steps": [(s["step"], s["outer"], s["iterations"]) for s in result.steps],
            "rms_after_px": result.statistics("after")["rms_px"],
            "grid_rms_px": grid_rms(true, result.model),
            "grid_rms_before_px": grid_rms(true, lab) if n == sizes[0] else None,
        }
        rows.append(entry)
        print(
            f"{n:>9,d} GCPs: {seconds:7.2f} s ({cpu_seconds:.2f} s CPU)  {passes:2d} passes x {per_pass:6.2f} s "
            f"({100 * entry['model_share']:.0f} % in the model)  peak {entry['peak_traced_mb']:7.1f} MB traced, "
            f"{entry['max_rss_mb']:7.1f} MB RSS  grid RMS {entry['grid_rms_px']:.4f} px  {result.message[:60]}"
        )
    if len(rows) > 1:
        base = rows[0]
        for r in rows[1:]:
            r["time_ratio_vs_first"] = r["seconds"] / base["seconds"]
            r["size_ratio_vs_first"] = r["n_gcps"] / base["n_gcps"]
    out = {
        "benchmark": "calibrate",
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "threads": 1,
            "load_average_at_end": os.getloadavg(),
            "cpus": os.cpu_count(),
        },
        "model": "4 bands x 4 CCDs x 512 detectors, 6000 lines, 131 parameters (3 exterior + 128 interior)",
        "targets": {"1e5_seconds": 5.0, "1e6_seconds": 60.0, "memory_mb": 2048.0},
        "results": rows,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
