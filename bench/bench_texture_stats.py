"""Texture statistics of real imagery against the simulator's procedural texture.

What a matcher sees of a texture, measured the same way on every source after block-averaging it
to one ground sample distance (``--gsd``, 30 m: the Landsat-like reference DOM):

* **spectral slope** ``beta``: the radially averaged power spectrum ``P(k) ~ k^-beta`` fitted in
  log-log between wavelengths of 4 and 64 pixels (120 m - 1.9 km at 30 m), the scales a 64-pixel
  correlation window uses; natural scenes have ``beta`` near 2 (van der Schaaf & van Hateren
  1996, Vision Res. 36(17):2759-2770: 1.88-2.13 for natural images);
* **local contrast**: median over 32 x 32-pixel windows of ``std / mean`` of the radiance (the
  "RMS contrast" of Pelli & Bex, Vision Res. 90 (2013) 10-14);
* **texture fraction**: the share of those windows whose relative gradient energy
  (mean ``|grad|^2`` / mean^2, per 30 m pixel) exceeds ``2e-3`` (10 x ``2 s^2`` with ``s`` = 1 % of
  the mean: ten times what the noise of a flat window gives; a relative gradient RMS of 4.5 % per
  pixel), i.e. where a phase correlation has something to lock on
  (:func:`sensor_models.simulate.texture_stats.textured_fraction`). The threshold is absolute
  (relative to the window's mean), unlike the matcher's own gate (``gcpmatch.clouds.low_texture``:
  a window's standard deviation below 0.2 of the median over the CCD), which only ranks windows
  within an image and so cannot say that an image is texture-poor; that gate's share is reported
  too (``matcher_gate_fraction``). Landsat digital numbers carry an offset that lowers every
  relative figure (contrast, gradient energy) of its crops;
* **untextured / textured gradient ratio**: the median relative gradient RMS of the untextured
  windows over that of the textured ones: how much texture texture-poor ground keeps (the
  ``realistic`` profile's ``texture_poor_attenuation``).

Sources: the real Sentinel-2 L1C red band (10 m) and Landsat-8 red (30 m) and panchromatic
(15 m) crops of ``../shared/data/real_textures`` (used in place; skipped when absent); the
procedural DOM (15 m) of the ideal fixture (``fixtures/hy1c_czi/reference/dom.tif``: the radiance
the ideal fixture is rendered from); the realistic fixture's procedural source radiance, redrawn
by the simulator (:func:`sensor_models.simulate.realistic_sim.source_radiance`, the fixture's
configuration), with and without its texture-poor patches (``texture_poor_fraction`` 0); and the
realistic fixture's degraded 30 m reference DOM. Landsat pixels flagged cloudy in its QA band are
left out; so are the windows with no data.

Usage: ``python bench/bench_texture_stats.py [--gsd 30] [--out bench/results/texture_stats.json]``
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import rasterio

from sensor_models.simulate.texture_stats import (TEXTURED_GRADIENT_ENERGY, block_average, block_rms_contrast,
                                                  matcher_gate_fraction, spectral_slope, textured_fraction,
                                                  untextured_gradient_ratio)

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
    """Median RMS contrast, texture fractions and the untextured / textured gradient ratio over blocks.

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
        ``matcher_gate_fraction``, ``untextured_to_textured_gradient_ratio``, ``windows``.
    """
    c = block_rms_contrast(img, valid, window=window)
    return {"rms_contrast_median": float(np.median(c)), "rms_contrast_p10": float(np.percentile(c, 10)),
            "rms_contrast_p90": float(np.percentile(c, 90)),
            "texture_fraction": textured_fraction(img, valid, window=window),
            "matcher_gate_fraction": matcher_gate_fraction(img, valid, window=window),
            "untextured_to_textured_gradient_ratio": untextured_gradient_ratio(img, valid, window=window),
            "windows": int(c.size)}


def _describe(path: Path) -> str:
    base = ROOT if path.is_relative_to(ROOT) else ROOT.parent  # the repository's files, or shared/...
    return str(path.relative_to(base) if path.is_relative_to(base) else path)


def measure_array(data: np.ndarray, valid: np.ndarray, gsd: float, gsd_m: float) -> dict:
    """Statistics of one radiance array at ``gsd_m`` (module docstring).

    Parameters
    ----------
    data, valid : ndarray, shape (H, W)
        Radiance and validity.
    gsd : float
        Its pixel size, metres.
    gsd_m : float
        Common ground sample distance, metres (block average by ``round(gsd_m / gsd)``).

    Returns
    -------
    dict
        ``native_gsd_m``, ``gsd_m``, ``spectral_slope``, ``square_px`` and :func:`local_stats`.
    """
    factor = max(1, int(round(gsd_m / gsd)))
    img, ok = block_average(np.asarray(data, dtype=np.float64), valid, factor)
    out = {"native_gsd_m": gsd, "gsd_m": gsd * factor, **local_stats(img, ok)}
    for size in (256, 192, 128):
        corner = _largest_valid_square(ok, size)
        if corner is not None:
            r, c = corner
            out["spectral_slope"] = spectral_slope(img[r:r + size, c:c + size])
            out["square_px"] = size
            break
    return out


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
        ``file`` and :func:`measure_array`.
    """
    data, valid, gsd = _read(path, qa)
    return {"file": _describe(path), **measure_array(data, valid, gsd, gsd_m)}


def realistic_source(gsd_m: float, *, texture_poor: bool = True) -> dict:
    """Statistics of the realistic fixture's procedural source radiance, redrawn (module docstring).

    Parameters
    ----------
    gsd_m : float
        Common ground sample distance, metres.
    texture_poor : bool
        False: the same source without its texture-poor patches (``texture_poor_fraction`` 0).

    Returns
    -------
    dict
        ``file`` (how it was drawn), ``texture_poor_fraction``, ``texture_poor_attenuation`` and
        :func:`measure_array`.
    """
    sys.path.insert(0, str(ROOT / "fixtures"))
    from make_hy1c_fixture import config
    from sensor_models.simulate.profiles import Sourced, get_profile
    from sensor_models.simulate.realistic_sim import source_radiance

    profile = get_profile("realistic")
    if not texture_poor:
        profile = replace(profile, texture_poor_fraction=Sourced(0.0, "bench: without the patches"))
    radiance, transform, _ = source_radiance(config(), profile)
    return {"file": "realistic_sim.source_radiance(fixtures/make_hy1c_fixture.config(), realistic"
                    + ("" if texture_poor else ", texture_poor_fraction 0") + ")",
            "texture_poor_fraction": profile.value("texture_poor_fraction"),
            "texture_poor_attenuation": profile.value("texture_poor_attenuation"),
            **measure_array(radiance, np.isfinite(radiance) & (radiance > 0), abs(transform.a), gsd_m)}


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
        "realistic_source": None,
        "realistic_source_without_texture_poor": None,
        "realistic_fixture_reference": (ROOT / "fixtures" / "hy1c_czi_realistic" / "reference" / "dom.tif", None),
    }
    doc = {"gsd_m": args.gsd, "window_px": WINDOW, "textured_gradient_energy": TEXTURED_GRADIENT_ENERGY,
           "sources": {}}
    for name, where in sources.items():
        if where is None:
            doc["sources"][name] = realistic_source(args.gsd, texture_poor=not name.endswith("without_texture_poor"))
        elif not where[0].exists():
            doc["sources"][name] = {"skipped": f"{_describe(where[0])} not found"}
        else:
            doc["sources"][name] = measure(where[0], args.gsd, where[1])
    for name, r in doc["sources"].items():
        if "skipped" in r:
            print(f"{name:30s} skipped: {r['skipped']}")
            continue
        print(f"{name:30s} gsd {r['gsd_m']:5.1f} m  beta {r.get('spectral_slope', float('nan')):5.2f}  "
              f"RMS contrast median {r['rms_contrast_median']:.3f} (p10 {r['rms_contrast_p10']:.3f}, "
              f"p90 {r['rms_contrast_p90']:.3f})  textured {r['texture_fraction']:.3f} (matcher gate "
              f"{r['matcher_gate_fraction']:.3f}, untextured/textured gradient "
              f"{r['untextured_to_textured_gradient_ratio']:.3f})  windows {r['windows']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return doc


if __name__ == "__main__":
    main()
