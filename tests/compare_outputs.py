"""Compare two folders of gcpcal outputs to the accuracy the methods document, not to the bit.

Floating-point results are not bit-reproducible across CPUs and library builds: a vectorized loop
(AVX2 against AVX-512, another SIMD width in an FFT, another BLAS kernel) sums in another order
and changes the last bits, and a pixel whose value lies on a rounding edge then gains or loses one
digital number. Tests that guard "the output has not changed" therefore compare with these
tolerances, each far below what a user of the output could notice and far above that rounding:

* integer rasters (digital numbers): at most ``DN_CHANGED_FRACTION`` (2 %) of the pixels differ
  at all, and at most ``DN_JUMP_FRACTION`` (0.05 %) by more than ``DN_TOLERANCE`` (1 DN). The
  second allowance is for fields the simulator thresholds (land-cover classes, cloud edges,
  saturation): a rounding flip on a threshold moves an isolated pixel by tens of DN (measured
  between an AVX-512 and an AVX2 CPU on the realistic fixture: 0.55-0.64 % of the pixels changed,
  0.009 % by more than 1 DN). A real change of the simulator moves most pixels;
* float rasters (heights, radiance): every pixel within ``FLOAT_RASTER_RTOL`` (1e-3) of the
  expected raster's range, e.g. 0.3 m on 300 m of relief, against the metres of a DEM's own error;
  the no-data masks identical;
* the georeferencing (size, bands, data type, CRS, no-data value) identical, the transform to
  ``TRANSFORM_RTOL`` (1e-12 relative: a few units in the last place of a UTM coordinate);
* JSON files: the same keys, strings and flags; numbers within ``JSON_ATOL`` + ``JSON_RTOL`` x
  |value| (1e-6: pixels to a micro-pixel, angles to a microradian or better; measured
  differences across CPUs are 1e-14 px and 1e-18 rad), unless a caller widens a key it knows to
  be a statistic of a float raster (e.g. the rms of a DEM's error, which follows the heights'
  own tolerance).

:func:`compare_folders` returns the list of differences (empty when the folders agree).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import rasterio

DN_TOLERANCE = 1
DN_CHANGED_FRACTION = 0.02
DN_JUMP_FRACTION = 5e-4
FLOAT_RASTER_RTOL = 1e-3
TRANSFORM_RTOL = 1e-12
JSON_ATOL = 1e-6
JSON_RTOL = 1e-6
#: gcpcal's record of what it wrote (checksums, inodes, times): not an output to compare
LEDGER = ".gcpcal-outputs.json"


def _leaves(obj, path=""):
    if isinstance(obj, dict):
        yield path, ("dict", tuple(sorted(obj)))
        for key, value in obj.items():
            yield from _leaves(value, f"{path}/{key}")
    elif isinstance(obj, list):
        yield path, ("list", len(obj))
        for i, value in enumerate(obj):
            yield from _leaves(value, f"{path}[{i}]")
    else:
        yield path, obj


def compare_json(expected: Path, actual: Path, *, widened: dict[str, float] | None = None) -> list[str]:
    """Differences between two JSON files beyond the tolerances (module docstring).

    ``widened`` maps a leaf path (``/a/b[0]/c``) prefix to a relative tolerance that replaces
    ``JSON_RTOL`` under it.
    """
    a = dict(_leaves(json.loads(expected.read_text(encoding="utf-8"))))
    b = dict(_leaves(json.loads(actual.read_text(encoding="utf-8"))))
    if a.keys() != b.keys():
        return [f"{actual.name}: keys differ: {sorted(a.keys() ^ b.keys())[:5]}"]
    out = []
    for key, x in a.items():
        y = b[key]
        numeric = (isinstance(x, (int, float)) and isinstance(y, (int, float))
                   and not isinstance(x, bool) and not isinstance(y, bool))
        if not numeric:
            if x != y:
                out.append(f"{actual.name}{key}: {x!r} != {y!r}")
            continue
        if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
            continue
        rtol = next((r for prefix, r in (widened or {}).items() if key.startswith(prefix)), JSON_RTOL)
        if not abs(x - y) <= JSON_ATOL + rtol * abs(x):
            out.append(f"{actual.name}{key}: {x!r} != {y!r}")
    return out


def compare_rasters(expected: Path, actual: Path) -> list[str]:
    """Differences between two rasters beyond the tolerances (module docstring)."""
    with rasterio.open(expected) as a, rasterio.open(actual) as b:
        head_a = (a.width, a.height, a.count, a.dtypes, a.crs, a.nodata)
        head_b = (b.width, b.height, b.count, b.dtypes, b.crs, b.nodata)
        if head_a != head_b:
            return [f"{actual.name}: {head_b} != {head_a}"]
        ta, tb = np.asarray(a.transform)[:6], np.asarray(b.transform)[:6]
        if not np.allclose(ta, tb, rtol=TRANSFORM_RTOL, atol=TRANSFORM_RTOL * np.abs(ta[[0, 4]]).max()):
            return [f"{actual.name}: transform {tuple(tb)} != {tuple(ta)}"]
        va, vb = a.read(masked=True), b.read(masked=True)
    if not np.array_equal(np.ma.getmaskarray(va), np.ma.getmaskarray(vb)):
        return [f"{actual.name}: no-data masks differ on {np.count_nonzero(va.mask != vb.mask)} pixels"]
    xa, xb = va.compressed(), vb.compressed()
    if xa.size == 0:
        return []
    if np.issubdtype(xa.dtype, np.integer):
        diff = np.abs(xa.astype(np.int64) - xb.astype(np.int64))
        changed = np.count_nonzero(diff) / diff.size
        jumps = np.count_nonzero(diff > DN_TOLERANCE) / diff.size
        if changed > DN_CHANGED_FRACTION or jumps > DN_JUMP_FRACTION:
            return [f"{actual.name}: {changed:.2%} of the pixels changed, {jumps:.3%} by more than "
                    f"{DN_TOLERANCE} DN (max {diff.max()} DN)"]
        return []
    xa, xb = xa.astype(np.float64), xb.astype(np.float64)
    both_nan = np.isnan(xa) & np.isnan(xb)
    span = float(np.nanmax(xa) - np.nanmin(xa)) or 1.0
    diff = np.where(both_nan, 0.0, np.abs(xa - xb))
    if not np.all(diff <= FLOAT_RASTER_RTOL * span):
        return [f"{actual.name}: max {np.nanmax(diff):.3g} (tolerance {FLOAT_RASTER_RTOL * span:.3g})"]
    return []


def compare_folders(expected: Path, actual: Path, *, skip: tuple[str, ...] = (),
                    widened: dict[str, float] | None = None) -> list[str]:
    """Every difference between two output folders beyond the tolerances (module docstring).

    Parameters
    ----------
    expected, actual : Path
        The folders; the same relative file names are required.
    skip : tuple of str
        Relative paths not compared (e.g. a summary holding timings).
    widened : dict, optional
        Per-JSON-key relative tolerances (:func:`compare_json`).
    """
    names_a = sorted(str(p.relative_to(expected)) for p in expected.rglob("*") if p.is_file() and p.name != LEDGER)
    names_b = sorted(str(p.relative_to(actual)) for p in actual.rglob("*") if p.is_file() and p.name != LEDGER)
    if names_a != names_b:
        return [f"files differ: {sorted(set(names_a) ^ set(names_b))}"]
    out = []
    for name in names_a:
        if name in skip:
            continue
        a, b = expected / name, actual / name
        if name.endswith((".tif", ".tiff")):
            out += compare_rasters(a, b)
        elif name.endswith(".json"):
            out += compare_json(a, b, widened=widened)
        elif a.read_bytes() != b.read_bytes():
            out.append(f"{name}: bytes differ")
    return out
