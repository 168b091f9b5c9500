"""Texture statistics of real imagery against the simulator's procedural texture (issue 13 item 1).

What a matcher sees of a texture, measured the same way on every source after block-averaging it
to one ground sample distance (``--gsd``, 30 m: the Landsat-like reference DOM):

* **spectral slope** ``beta``: the radially averaged power spectrum ``P(k) ~ k^-beta`` fitted in
  log-log between wavelengths of 4 and 64 pixels (120 m - 1.9 km at 30 m), the scales a 64-pixel
  correlation window uses; natural scenes have ``beta`` near 2 (van der Schaaf & van Hateren
  1996, Vision Res. 36(17):2759-2770: 1.88-2.13 for natural images);
* **local contrast**: median over 32 x 32-pixel windows of ``std / mean`` of the radiance (the
  "RMS contrast" of Pelli & Bex, Vision Res. 90 (2013) 10-14);
* **texture fraction**: the share of those windows whose gradient energy
  (mean ``|grad|^2`` / mean^2) exceeds that of a flat window with 1 % noise by 10x, i.e. where a
  phase correlation has something to lock on.

Sources: the real Sentinel-2 L1C red band (10 m) and Landsat-8 red (30 m) and panchromatic
(15 m) crops of ``../shared/data/real_textures`` (used in place; skipped when absent), and the
procedural DOM (15 m) of the embedded fixtures (``fixtures/hy1c_czi/reference/dom.tif``: the
radiance the ideal and realistic fixtures are rendered from, and the realistic fixture's
degraded 30 m reference). Landsat pixels flagged cloudy in its QA band are left out; so are the
windows with no data.

Usage: ``python bench/bench_texture_stats.py [--gsd 30] [--out bench/results/texture_stats.json]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import rasterio

from sensor_models.simulate.texture_stats import block_average, block_rms_contrast, spectral_slope

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "real_textures"
WINDOW = 32


def _read(path: Path, qa: Path | None = None):
    with rasterio.open(path) as ds:
        data = ds.read(1).astype(np.float64)
        gsd = abs(ds.transform.a)
        nodata = ds.nodata
    valid = np.isfinite(data) & (data > 0)
    if nodata is not None:
        valid &= data != nodata
    if qa is not None and qa.exists():
        with rasterio.open(qa) as ds:
            bits = ds.read(1).astype(np.uint16)
        if bits.shape == data.shape:
            cloud = ((bits >> 14) & 3) >= 2  # pre-Collection-2 BQA: cloud confidence medium/high
            cirrus = ((bits >> 12) & 3) >= 2
            valid &= ~(cloud | cirrus) & (bits != 1)
    return data, valid, gsd


def _largest_valid_square(valid, size: int):
    """Top-left corner of a size x size block with every pixel valid (None when there is none)."""
    from scipy.ndimage import uniform_filter

    frac = uniform_filter(valid.astype(np.float64), size=size, mode="constant")
    c = size // 2
    ok = np.argwhere(frac[c:valid.shape[0] - size + c + 1, c:valid.shape[1] - size + c + 1] > 0.9999)
    if ok.size == 0:
        return None
    return tuple(ok[len(ok) // 2])


def local_stats(img: np.ndarray, valid: np.ndarray, *, window: int = WINDOW) -> dict:
    """Median RMS contrast and texture fraction over window x window blocks.

    Parameters
    ----------
    img, valid : ndarray, shape (H, W)
        Radiance and validity.
    window : int
        Block size, pixels.

    Returns
    -------
    dict
        ``rms_contrast_median``, ``rms_contrast_p10``, ``rms_contrast_p90``, ``texture_fraction``,
        ``windows``.
    """
    c = block_rms_contrast(img, valid, window=window)
    gy, gx = np.gradient(img)
    h, w = (s // window * window for s in img.shape)
    shape = (h // window, window, w // window, window)
    v = valid[:h, :w].reshape(shape).all(axis=(1, 3))
    mean = img[:h, :w].reshape(shape).mean(axis=(1, 3))
    energy = (gx * gx + gy * gy)[:h, :w].reshape(shape).mean(axis=(1, 3)) / np.where(mean > 0, mean, np.nan) ** 2
    flat = 10.0 * 2.0 * (0.01**2)  # flat window with 1 % noise: |grad|^2/mean^2 ~ 2 * 0.01^2 (central differences halve it; kept conservative)
    e = energy[v & np.isfinite(energy)]
    return {"rms_contrast_median": float(np.median(c)), "rms_contrast_p10": float(np.percentile(c, 10)),
            "rms_contrast_p90": float(np.percentile(c, 90)), "texture_fraction": float(np.mean(e > flat)),
            "windows": int(c.size)}


def measure(path: Path, gsd_m: float, qa: Path | None = None) -> dict:
    """Statistics of one raster at ``gsd_m`` (module docstring).

    Parameters
    ----------
    path : Path
        Single-band raster.
    gsd_m : float
        Common ground sample distance, metres (an integer multiple of the raster's).
    qa : Path, optional
        Landsat pre-Collection-2 BQA band (cloudy pixels left out).

    Returns
    -------
    dict
        ``file``, ``native_gsd_m``, ``spectral_slope``, ``square_px`` and :func:`local_stats`.
    """
    data, valid, gsd = _read(path, qa)
    factor = max(1, int(round(gsd_m / gsd)))
    img, ok = block_average(data, valid, factor)
    base = ROOT if path.is_relative_to(ROOT) else ROOT.parent  # the repository's files, or shared/...
    out = {"file": str(path.relative_to(base) if path.is_relative_to(base) else path),
           "native_gsd_m": gsd, "gsd_m": gsd * factor, **local_stats(img, ok)}
    for size in (256, 192, 128):
        corner = _largest_valid_square(ok, size)
        if corner is not None:
            r, c = corner
            out["spectral_slope"] = spectral_slope(img[r:r + size, c:c + size])
            out["square_px"] = size
            break
    return out


def main(argv=None) -> dict:
    """Measure every available source and write the JSON (module docstring).

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments.

    Returns
    -------
    dict
        The written document.
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gsd", type=float, default=30.0)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "texture_stats.json")
    args = ap.parse_args(argv)
    sources = {
        "sentinel2_B04": (SHARED / "sentinel2" / "s2_B04.jp2", None),
        "landsat8_B4": (SHARED / "landsat8" / "l8_B4.tif", SHARED / "landsat8" / "l8_BQA.tif"),
        "landsat8_B8": (SHARED / "landsat8" / "l8_B8.tif", None),
        "procedural_dom": (ROOT / "fixtures" / "hy1c_czi" / "reference" / "dom.tif", None),
        "realistic_fixture_reference": (ROOT / "fixtures" / "hy1c_czi_realistic" / "reference" / "dom.tif", None),
    }
    doc = {"gsd_m": args.gsd, "window_px": WINDOW, "sources": {}}
    for name, (path, qa) in sources.items():
        if not path.exists():
            doc["sources"][name] = {"skipped": f"{path} not found"}
            continue
        doc["sources"][name] = measure(path, args.gsd, qa)
    for name, r in doc["sources"].items():
        if "skipped" in r:
            print(f"{name:30s} skipped: {r['skipped']}")
            continue
        print(f"{name:30s} gsd {r['gsd_m']:5.1f} m  beta {r.get('spectral_slope', float('nan')):5.2f}  "
              f"RMS contrast median {r['rms_contrast_median']:.3f} (p10 {r['rms_contrast_p10']:.3f}, "
              f"p90 {r['rms_contrast_p90']:.3f})  textured {r['texture_fraction']:.2f}  windows {r['windows']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return doc


if __name__ == "__main__":
    main()
