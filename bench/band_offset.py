"""Displacement between two co-located bands of one product, by estimators outside gcpmatch.

Two bands of one product (Sentinel-2 L1C red B04 and near-infrared B08; Landsat-8 red B4 and
panchromatic B8) are registered to each other by the producer only to a specification. This
module measures what is left with three estimators that share nothing with gcpmatch's phase
correlation, each maximising a similarity over a sub-pixel shift ``d = (d_row, d_col)``:

* ``mi``: mutual information of the grey levels (joint histogram, 64 x 64 bins, smoothed by a
  Gaussian of 1 bin), ``MI = sum p_ab log(p_ab / (p_a p_b))`` (Viola and Wells 1997; Maes et
  al. 1997). It needs no grey-level map between the bands: contrast inversion is allowed;
* ``orientation``: correlation of the doubled-angle gradient orientations,
  ``C = mean cos(2 (theta_a - theta_b))`` over pixels whose gradient exceeds the noise in both
  bands (orientation correlation, Fitch et al. 2002; the doubled angle makes it blind to the
  sign of the contrast);
* ``ecc``: OpenCV's enhanced correlation coefficient (``cv2.findTransformECC``, translation
  only; Evangelidis and Psarakis 2008) on the gradient magnitudes (sign-free), with its own
  optimiser and bilinear warping.

``mi`` and ``orientation`` shift both bands by half the trial shift each, in opposite
directions, with the Fourier shift theorem (exact for band-limited images, no interpolation
smoothing that would favour integer shifts), and score an interior that excludes a margin of
``MARGIN_PX`` (the periodic wrap). The maximum is found on a grid of step 0.25 px over
``+-SEARCH_PX`` then refined by Nelder-Mead to 0.001 px.

Convention: ``d`` is where a feature at pixel ``p`` of band ``a`` appears in band ``b``:
``b(p + d) ~ f(a(p))``, in pixels of the grid both are read on (row down, col right). On a
north-up grid, ``d_row > 0`` is south and ``d_col > 0`` east.

Run as a script (``python bench/band_offset.py``) to print the whole-crop and per-tile (4 x 4)
estimates for the Sentinel-2 and Landsat-8 crops of ``../shared/data/real_textures``, and each
estimator's recovery of a known Fourier shift added to one band.

References: P. Viola, W. M. Wells, "Alignment by maximization of mutual information", IJCV
24(2):137-154, 1997. F. Maes et al., "Multimodality image registration by maximization of mutual
information", IEEE TMI 16(2):187-198, 1997. A. J. Fitch, A. Kadyrov, W. J. Christmas, J. Kittler,
"Orientation correlation", BMVC 2002, 133-142. G. D. Evangelidis, E. Z. Psarakis, "Parametric
image alignment using enhanced correlation coefficient maximization", IEEE TPAMI
30(10):1858-1865, 2008.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy import fft as sfft
from scipy.ndimage import gaussian_filter
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import change_pairs  # noqa: E402

#: interior margin (px) left out of every score: the periodic wrap of the Fourier shift
MARGIN_PX = 24
#: half-width (px) of the coarse grid the maximum is searched on
SEARCH_PX = 1.5
#: bins of the joint histogram of ``mi``
MI_BINS = 64
#: Sentinel-2 B08 digital number under which a pixel counts as water (open sea: median 313, 95th
#: percentile 423; land vegetation 1500-3000)
WATER_NIR_DN = 500
#: Sentinel-2 crop regions (rows, cols of the 10 m grid): the footprint of the scenes of
#: bench/change_pairs.py (the bounding box of their GCPs' ground points, seeds 11 and 12) and its
#: land, coast (barrier island and its shore) and open-sea parts, split by eye on the image
S2_REGIONS = {"footprint": ((700, 1270), (220, 1660)), "footprint_land": ((700, 1270), (220, 1150)),
              "footprint_coast": ((700, 1270), (1150, 1450)), "footprint_sea": ((700, 1270), (1450, 1660))}
#: Landsat-8 crop rows (30 m) of the cloud-free strip south of the cumulus field (the BQA flags
#: 15 % of the crop as cloud; the small cumulus over most of it are not flagged)
L8_CLEAR_ROWS = (470, 603)


def read_band(path: Path, out_shape=None) -> tuple[np.ndarray, object]:
    """Band 1 of ``path`` as float64 and its affine transform; averaged onto ``out_shape`` if given."""
    import rasterio
    from rasterio.enums import Resampling

    with rasterio.open(path) as src:
        if out_shape is None:
            return src.read(1).astype(np.float64), src.transform
        img = src.read(1, out_shape=out_shape, resampling=Resampling.average).astype(np.float64)
        return img, src.transform * src.transform.scale(src.width / out_shape[1], src.height / out_shape[0])


class _Shifter:
    """Both bands shifted by ``-d/2`` and ``+d/2`` (Fourier shift theorem), cropped to the interior."""

    def __init__(self, a: np.ndarray, b: np.ndarray):
        self.shape = a.shape
        self.fa = sfft.rfft2(a - a.mean())
        self.fb = sfft.rfft2(b - b.mean())
        self.kr = sfft.fftfreq(a.shape[0])[:, None]
        self.kc = sfft.rfftfreq(a.shape[1])[None, :]

    def pair(self, d) -> tuple[np.ndarray, np.ndarray]:
        """``a`` moved by ``+d/2`` and ``b`` by ``-d/2``: a feature at ``p`` in ``a`` and ``p + d``
        in ``b`` lands at ``p + d/2`` in both. Interior only, shape ``(rows - 2 M, cols - 2 M)``."""
        ramp = np.exp(-1j * np.pi * (self.kr * d[0] + self.kc * d[1]))  # half shift
        a = sfft.irfft2(self.fa * ramp, s=self.shape)
        b = sfft.irfft2(self.fb / ramp, s=self.shape)
        m = MARGIN_PX
        return a[m:-m, m:-m], b[m:-m, m:-m]


def _mutual_information(a: np.ndarray, b: np.ndarray, lim_a, lim_b) -> float:
    """MI (nats) of two images' grey levels: joint histogram of :data:`MI_BINS` bins, Gaussian-smoothed."""
    ia = np.clip(((a - lim_a[0]) / (lim_a[1] - lim_a[0]) * MI_BINS).astype(np.int64), 0, MI_BINS - 1)
    ib = np.clip(((b - lim_b[0]) / (lim_b[1] - lim_b[0]) * MI_BINS).astype(np.int64), 0, MI_BINS - 1)
    h = np.bincount((ia * MI_BINS + ib).ravel(), minlength=MI_BINS * MI_BINS).reshape(MI_BINS, MI_BINS)
    p = gaussian_filter(h.astype(np.float64), 1.0, mode="constant")
    p /= p.sum()
    pa = p.sum(axis=1, keepdims=True)
    pb = p.sum(axis=0, keepdims=True)
    nz = p > 0
    return float(np.sum(p[nz] * np.log(p[nz] / (pa @ pb)[nz])))


def _orientation(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Doubled-angle unit orientation ``exp(2 i theta)`` of the central-difference gradient, and its magnitude."""
    gr = np.zeros_like(img)
    gc = np.zeros_like(img)
    gr[1:-1, :] = 0.5 * (img[2:, :] - img[:-2, :])
    gc[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    g = gc + 1j * gr
    mag = np.abs(g)
    return np.where(mag > 0, g * g / np.maximum(mag, 1e-12) ** 2, 0.0), mag


def _noise_gradient(img: np.ndarray) -> float:
    """Gradient magnitude of noise alone: the median absolute Laplacian (Immerkaer 1996) scaled."""
    lap = img[1:-1, 1:-1] * 4 - img[2:, 1:-1] - img[:-2, 1:-1] - img[1:-1, 2:] - img[1:-1, :-2]
    sigma = np.sqrt(np.pi / 2) * np.mean(np.abs(lap)) / np.sqrt(20.0)
    return float(sigma / np.sqrt(2.0))  # std of one central difference over 2 px


def _objective(kind: str, a: np.ndarray, b: np.ndarray):
    """Negative similarity of ``kind`` as a function of the shift ``d`` (px); lower is better."""
    sh = _Shifter(a, b)
    if kind == "mi":
        ca, cb = a - a.mean(), b - b.mean()
        lim_a = np.percentile(ca, [0.5, 99.5])
        lim_b = np.percentile(cb, [0.5, 99.5])
        return lambda d: -_mutual_information(*sh.pair(d), lim_a, lim_b)
    if kind == "orientation":
        thr = 3.0 * max(_noise_gradient(a), _noise_gradient(b))

        def neg(d):
            sa, sb = sh.pair(d)
            oa, ma = _orientation(sa)
            ob, mb = _orientation(sb)
            keep = (ma > thr) & (mb > thr)
            return -float(np.mean(np.real(oa[keep] * np.conj(ob[keep]))))
        return neg
    raise ValueError(kind)


def estimate(kind: str, a: np.ndarray, b: np.ndarray, *, x0=None) -> np.ndarray:
    """Shift ``d`` (px, shape (2,): row, col) of band ``b`` against band ``a`` by estimator ``kind``.

    Parameters
    ----------
    kind : {"mi", "orientation", "ecc"}
        Estimator (module docstring).
    a, b : ndarray, shape (rows, cols)
        The two bands on one grid.
    x0 : (float, float), optional
        Start of the refinement (px); None: the best node of the coarse grid. ``ecc`` starts at 0.

    Returns
    -------
    ndarray, shape (2,)
        ``d`` such that ``b(p + d) ~ f(a(p))``; NaN where the estimator did not converge.
    """
    if kind == "ecc":
        return _ecc(a, b)
    f = _objective(kind, a, b)
    if x0 is None:
        grid = np.arange(-SEARCH_PX, SEARCH_PX + 1e-9, 0.25)
        vals = np.array([[f((r, c)) for c in grid] for r in grid])
        i, j = np.unravel_index(np.argmin(vals), vals.shape)
        x0 = (grid[i], grid[j])
    simplex = [[x0[0], x0[1]], [x0[0] + 0.2, x0[1]], [x0[0], x0[1] + 0.2]]
    res = minimize(f, x0=list(x0), method="Nelder-Mead",
                   options={"xatol": 1e-3, "fatol": 1e-12, "initial_simplex": simplex})
    return np.asarray(res.x, dtype=float)


def _ecc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``cv2.findTransformECC`` (translation) on the gradient magnitudes of ``a`` (template) and ``b``."""
    import cv2

    def gmag(img):
        return np.hypot(cv2.Sobel(img, cv2.CV_64F, 1, 0, ksize=3), cv2.Sobel(img, cv2.CV_64F, 0, 1, ksize=3)).astype(np.float32)

    warp = np.eye(2, 3, dtype=np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-6)
    mask = np.zeros(a.shape, np.uint8)
    mask[MARGIN_PX:-MARGIN_PX, MARGIN_PX:-MARGIN_PX] = 1
    try:
        # ECC warps the input (b) onto the template (a): a(p) ~ b(p + t), t = warp[:, 2] (x, y)
        _, warp = cv2.findTransformECC(gmag(a), gmag(b), warp, cv2.MOTION_TRANSLATION, crit, mask, 1)
    except cv2.error:
        return np.full(2, np.nan)
    return np.array([warp[1, 2], warp[0, 2]], dtype=float)


def tiles(shape, n: int = 4):
    """``n x n`` tiles of an image of ``shape``: list of (row slice, col slice)."""
    er = np.linspace(0, shape[0], n + 1).astype(int)
    ec = np.linspace(0, shape[1], n + 1).astype(int)
    return [(slice(er[i], er[i + 1]), slice(ec[j], ec[j + 1])) for i in range(n) for j in range(n)]


def measure(a: np.ndarray, b: np.ndarray, kinds=("mi", "orientation", "ecc"), n_tiles: int = 4) -> dict:
    """Whole-image and per-tile ``d`` (px) of ``b`` against ``a`` for each estimator.

    Returns
    -------
    dict
        ``{kind: {"whole": [d_row, d_col], "tiles": [[d_row, d_col], ...], "tile_median": ...,
        "tile_std": ...}}``.
    """
    out = {}
    for kind in kinds:
        whole = estimate(kind, a, b)
        per = np.array([estimate(kind, a[t], b[t]) for t in tiles(a.shape, n_tiles)]) if n_tiles else np.zeros((0, 2))
        out[kind] = {"whole": whole.tolist(), "tiles": per.tolist(),
                     "tile_median": np.nanmedian(per, axis=0).tolist() if len(per) else None,
                     "tile_std": np.nanstd(per, axis=0).tolist() if len(per) else None}
    return out


def local_offsets_m(table, source: Path, reference: Path, half_px: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Displacement of ``reference`` against ``source`` around each GCP by ECC, as (east, north) m.

    A diagnostic of what a constant band displacement leaves: ``2 half_px`` px windows of the two
    bands (one grid, north-up) centred on each GCP's ground point, estimated by ``ecc`` (at the
    estimators' cross-band floor, about 0.1 px on such windows).

    Returns
    -------
    (east_m, north_m) : ndarray, shape (n,) each
        NaN where the window leaves the raster or ECC does not converge.
    """
    import pyproj
    import rasterio

    a, transform = read_band(source)
    b, _ = read_band(reference)
    with rasterio.open(source) as src:
        to_map = pyproj.Transformer.from_crs("EPSG:4326", src.crs.to_wkt(), always_xy=True)
    e, n = to_map.transform(np.asarray(table.lon, dtype=float), np.asarray(table.lat, dtype=float))
    col, row = ~transform * (np.asarray(e), np.asarray(n))
    d = np.full((len(row), 2), np.nan)
    for i, (r, c) in enumerate(zip(row.astype(int), col.astype(int))):
        if half_px <= r < a.shape[0] - half_px and half_px <= c < a.shape[1] - half_px:
            w = (slice(r - half_px, r + half_px), slice(c - half_px, c + half_px))
            d[i] = estimate("ecc", a[w], b[w])
    return d[:, 1] * transform.a, d[:, 0] * transform.e


def fourier_shift(img: np.ndarray, d) -> np.ndarray:
    """``img`` with its content moved by ``d`` (px, row, col): Fourier shift theorem (periodic)."""
    kr = sfft.fftfreq(img.shape[0])[:, None]
    kc = sfft.rfftfreq(img.shape[1])[None, :]
    return sfft.irfft2(sfft.rfft2(img) * np.exp(-2j * np.pi * (kr * d[0] + kc * d[1])), s=img.shape)


def sentinel2_bands():
    """Sentinel-2 B04 (red) and B08 (near-infrared), 10 m, as read."""
    a, ta = read_band(change_pairs.DATA / "sentinel2" / "s2_B04.jp2")
    b, tb = read_band(change_pairs.DATA / "sentinel2" / "s2_B08.jp2")
    assert ta == tb and a.shape == b.shape
    return a, b, ta


def landsat8_bands():
    """Landsat-8 red B4 (30 m) and panchromatic B8 averaged 2 x 2 onto 30 m, each on its own transform."""
    a, ta = read_band(change_pairs.DATA / "landsat8" / "l8_B4.tif")
    import rasterio

    with rasterio.open(change_pairs.DATA / "landsat8" / "l8_B8.tif") as src:
        pan = src.read(1).astype(np.float64)
        tp = src.transform
    rows, cols = pan.shape[0] // 2, pan.shape[1] // 2
    b = pan[:2 * rows, :2 * cols].reshape(rows, 2, cols, 2).mean(axis=(1, 3))
    tb = tp * tp.scale(2, 2)
    return a, b, ta, tb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--which", default="sentinel2,landsat8,recovery")
    ap.add_argument("--json", type=Path, help="write the figures there")
    a = ap.parse_args(argv)
    if not change_pairs.DATA.is_dir():
        print(f"real test data not found at {change_pairs.DATA}", file=sys.stderr)
        return 1
    which = a.which.split(",")
    res = {}
    if "sentinel2" in which:
        red, nir, _ = sentinel2_bands()
        res["sentinel2_B04_to_B08"] = measure(red, nir)
        # water: near-infrared under WATER_NIR_DN (the open sea's 95th percentile is about 420 DN)
        res["sentinel2_tile_water_fraction"] = [float(np.mean(nir[t] < WATER_NIR_DN)) for t in tiles(red.shape)]
        _print("Sentinel-2 B04 -> B08 (10 m px)", res["sentinel2_B04_to_B08"], res["sentinel2_tile_water_fraction"], "water")
        for name, ((r0, r1), (c0, c1)) in S2_REGIONS.items():
            part = (slice(r0, r1), slice(c0, c1))
            res["sentinel2_" + name] = measure(red[part], nir[part], n_tiles=0)
            print(f"  {name} (rows {r0}-{r1}, cols {c0}-{c1}):",
                  {k: np.round(v["whole"], 3).tolist() for k, v in res["sentinel2_" + name].items()})
    if "landsat8" in which:
        red, pan, tr, tp = landsat8_bands()
        # the pan average is on its own grid: common window, shift by the transforms' origins
        n_r = min(red.shape[0], pan.shape[0])
        n_c = min(red.shape[1], pan.shape[1])
        red, pan = red[:n_r, :n_c], pan[:n_r, :n_c]
        res["landsat8_B4_to_B8_as_read"] = measure(red, pan, n_tiles=3)
        # a feature at red index p sits at pan-average index p - (origin difference) if both
        # geotransforms are right
        res["landsat8_expected_px"] = [-(tp.f - tr.f) / tr.e, -(tp.c - tr.c) / tr.a]
        import rasterio

        with rasterio.open(change_pairs.DATA / "landsat8" / "l8_BQA.tif") as src:
            cloud = ((src.read(1)[:n_r, :n_c] >> 14) & 3) >= 2  # cloud confidence medium or high
        res["landsat8_tile_cloud_fraction"] = [float(cloud[t].mean()) for t in tiles(red.shape, 3)]
        _print("Landsat-8 B4 -> B8 averaged 2 x 2 to 30 m, array index against array index (30 m px)",
               res["landsat8_B4_to_B8_as_read"], res["landsat8_tile_cloud_fraction"], "BQA cloud")
        clear = (slice(L8_CLEAR_ROWS[0], L8_CLEAR_ROWS[1]), slice(0, n_c))
        res["landsat8_clear_strip"] = measure(red[clear], pan[clear], n_tiles=0)
        print(f"  cloud-free strip (rows {L8_CLEAR_ROWS[0]}-{L8_CLEAR_ROWS[1]}):",
              {k: np.round(v["whole"], 3).tolist() for k, v in res["landsat8_clear_strip"].items()})
        print("  expected from the two geotransforms (30 m px, row, col):", res["landsat8_expected_px"])
    if "recovery" in which:
        red, nir, _ = sentinel2_bands()
        t = tiles(red.shape, 4)[5]
        known = np.array([0.3, -0.2])
        base = measure(red[t], nir[t], n_tiles=0)
        moved = measure(red[t], fourier_shift(nir[t], known), n_tiles=0)
        same = measure(red[t], fourier_shift(red[t], known), n_tiles=0)
        res["recovery"] = {k: {"added": known.tolist(), "recovered": (np.array(moved[k]["whole"]) - base[k]["whole"]).tolist(),
                               "same_band": same[k]["whole"]} for k in base}
        for k, v in res["recovery"].items():
            print(f"recovery {k:12s} added {v['added']}  cross-band difference {np.round(v['recovered'], 4)}  "
                  f"same band {np.round(v['same_band'], 4)}")
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))
    return 0


def _print(title: str, res: dict, fraction, what: str) -> None:
    print(title)
    for kind, r in res.items():
        per = np.array(r["tiles"])
        print(f"  {kind:12s} whole {np.round(r['whole'], 3)}  tiles median {np.round(r['tile_median'], 3)} "
              f"std {np.round(r['tile_std'], 3)}  min {np.round(per.min(axis=0), 3)} max {np.round(per.max(axis=0), 3)}")
    for i, f in enumerate(fraction):
        print(f"  tile {i:2d} {what} {f:4.2f}  " + "  ".join(f"{k} {np.round(r['tiles'][i], 3)}" for k, r in res.items()))


if __name__ == "__main__":
    sys.exit(main())
