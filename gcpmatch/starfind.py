"""Star detection, sub-pixel centroids and star identification in camera frames.

Star calibration of a geostationary camera (seed 000, section 2.1) starts from the centroids
of star images and the catalogue stars they are. This module does both:

* :func:`estimate_background` -- a SExtractor-like background: robust statistics on a coarse
  mesh (sigma-clipped mode), a median filter over the mesh, interpolation to every pixel [1]_.
* :func:`detect_stars` -- background subtraction, a Gaussian matched filter, a threshold in
  units of the filtered noise, 8-connected components (``scipy.ndimage.label``), then
  centroids by one of :data:`CENTROID_METHODS`:

  - ``"iwc"``: intensity-weighted centroid over a square window (seed 000, eq. 1);
  - ``"gaussian"``: least-squares fit of a pixel-integrated circular Gaussian plus a
    constant, Levenberg-Marquardt vectorized over all stars at once;
  - ``"windowed"``: the iterative Gaussian-windowed centroid of SExtractor's ``XWIN_IMAGE``
    [1]_ (``x <- x + 2 sum w I (x_i - x) / sum w I``, ``w`` a Gaussian of the PSF's sigma).

* :func:`identify_stars` -- which catalogue star each centroid is:

  (a) with an approximate pointing: project the catalogue, vote for the offset, match mutual
      nearest neighbours within a tolerance, solve the rotation (Wahba's problem by SVD [3]_)
      and the focal length, and re-match until the set is stable;
  (b) lost in space: triangles of the brightest detections, keyed by their two side ratios,
      are looked up in a hash of catalogue triangles (:class:`StarPatternIndex`); each
      candidate gives an attitude hypothesis that is verified against the other detections,
      then refined by (a) [4]_.

Coordinates follow the project convention: ``(row, col)`` with the centre of the first pixel
at ``(0.5, 0.5)``. FITS and SExtractor number pixels from 1 with the first pixel's centre at
``1.0`` along ``x`` (columns) and ``y`` (rows): ``col = x - 0.5``, ``row = y - 0.5``
(:func:`fits_to_rowcol`).

Camera frame for identification: ``x`` along increasing columns, ``y`` along increasing rows,
``z`` along the boresight (right-handed); a pixel sees the direction
``((col - c0) / f, (row - r0) / f, 1)``. With roll 0 the top of the image (decreasing rows)
points to the north celestial pole and east is on the left, as the sky is seen; the roll is the
position angle of the image's top, from north through east.

References
----------
.. [1] E. Bertin and S. Arnouts, "SExtractor: software for source extraction", A&AS 117,
   393-404 (1996), section 3 (background mesh, mode ``2.5 median - 1.5 mean``); SExtractor
   user manual, "Windowed positional parameters" (XWIN_IMAGE).
.. [2] Seed 000: geostationary camera calibration from the relative motion of stars, eq. (1)
   (intensity-weighted centroid).
.. [3] G. Wahba, "A least squares estimate of satellite attitude", SIAM Review 7, 409 (1965);
   W. Kabsch, Acta Cryst. A32, 922-923 (1976) (the SVD solution).
.. [4] C. C. Liebe, "Pattern recognition of star constellations for spacecraft applications",
   IEEE AES Magazine 8(1), 31-39 (1993) (angular-distance star patterns);
   G. Brown and ESA, tetra3 (lost-in-space solving by hashed star patterns, 2019).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import scipy.ndimage as ndi
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.special import erf
from scipy.stats import binom

from sensor_models.errors import InputError
from sensor_models.simulate.stars_render import pixel_integrals, render_stars

__all__ = [
    "CENTROID_METHODS",
    "FLAG_EDGE",
    "FLAG_FIT_FAILED",
    "FLAG_SATURATED",
    "Background",
    "CameraPointing",
    "StarIdentification",
    "StarPatternIndex",
    "StarTable",
    "centroid_stars",
    "detect_stars",
    "estimate_background",
    "fits_to_rowcol",
    "identify_stars",
    "read_fits_image",
    "read_sextractor_catalog",
    "render_stars",
    "rowcol_to_fits",
]

CENTROID_METHODS = ("iwc", "gaussian", "windowed")
FLAG_EDGE = 1
"""The centroid window reaches outside the image (pixels outside are ignored)."""
FLAG_SATURATED = 2
"""The peak pixel reaches the ``saturation`` level."""
FLAG_FIT_FAILED = 4
"""The Gaussian fit or the windowed iteration failed; the intensity-weighted centroid is kept."""

FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))
ARCSEC_PER_RAD = 180.0 * 3600.0 / np.pi
_SQRT2 = np.sqrt(2.0)


# ============================================================================================
# Boundary conventions and readers
# ============================================================================================
def fits_to_rowcol(x_fits, y_fits) -> np.ndarray:
    """FITS/SExtractor 1-based pixel coordinates -> project ``(row, col)``.

    FITS puts the centre of the first pixel at ``x = y = 1.0``; gcpcal at ``0.5``. So
    ``col = x - 0.5`` and ``row = y - 0.5`` (FITS ``y`` is the array's first axis as stored).

    Returns
    -------
    ndarray, shape ``(..., 2)``
        ``(row, col)``.
    """
    x = np.asarray(x_fits, dtype=np.float64)
    y = np.asarray(y_fits, dtype=np.float64)
    return np.stack([y - 0.5, x - 0.5], axis=-1)


def rowcol_to_fits(rowcol) -> tuple[np.ndarray, np.ndarray]:
    """Project ``(row, col)`` of shape ``(..., 2)`` -> FITS ``(x, y)`` (``x = col + 0.5``)."""
    rc = np.asarray(rowcol, dtype=np.float64)
    return rc[..., 1] + 0.5, rc[..., 0] + 0.5


_FITS_DTYPES = {8: ">u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4", -64: ">f8"}


def _fits_value(text: str):
    text = text.strip()
    if text.startswith("'"):
        end = text.find("'", 1)
        while end != -1 and text[end + 1:end + 2] == "'":  # '' is an escaped quote
            end = text.find("'", end + 2)
        return text[1:end].replace("''", "'").rstrip() if end != -1 else text[1:]
    value = text.split("/", 1)[0].strip()
    if value in ("T", "F"):
        return value == "T"
    try:
        return int(value)
    except ValueError:
        try:
            return float(value.replace("D", "E"))
        except ValueError:
            return value


def read_fits_image(path) -> tuple[np.ndarray, dict]:
    """Read the primary 2-D image of a FITS file (a minimal reader, numpy only).

    Parameters
    ----------
    path : path-like
        A FITS file whose primary HDU holds a 2-D image (``NAXIS = 2``) of ``BITPIX`` 8, 16,
        32, 64, -32 or -64.

    Returns
    -------
    image : ndarray of float64, shape (NAXIS2, NAXIS1)
        ``BZERO + BSCALE * stored``; integer ``BLANK`` values become NaN. Row ``i`` is FITS
        ``y = i + 1``: the pixel centre at FITS ``(x, y)`` is at ``(row, col) = (y - 0.5,
        x - 0.5)`` (:func:`fits_to_rowcol`).
    header : dict
        Keyword -> value of the primary header (``COMMENT``/``HISTORY`` dropped; later
        duplicates win).

    Raises
    ------
    InputError
        Not FITS, not a 2-D primary image, an unsupported ``BITPIX`` or a truncated file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("FITS file not found", path=str(path))
    raw = path.read_bytes()
    header: dict = {}
    offset, ended = 0, False
    while not ended:
        block = raw[offset:offset + 2880]
        if len(block) < 2880:
            raise InputError("truncated FITS header (no END card)", path=str(path))
        offset += 2880
        for i in range(0, 2880, 80):
            card = block[i:i + 80].decode("ascii", errors="replace")
            key = card[:8].strip()
            if key == "END":
                ended = True
                break
            if card[8:10] == "= ":
                header[key] = _fits_value(card[10:])
    if header.get("SIMPLE") is not True:
        raise InputError("not a FITS file (SIMPLE = T missing)", path=str(path))
    bitpix = header.get("BITPIX")
    if bitpix not in _FITS_DTYPES:
        raise InputError(f"unsupported BITPIX {bitpix!r}", path=str(path), field="BITPIX")
    if header.get("NAXIS") != 2:
        raise InputError(f"expected a 2-D primary image, NAXIS = {header.get('NAXIS')!r}",
                         path=str(path), field="NAXIS")
    n1, n2 = int(header["NAXIS1"]), int(header["NAXIS2"])
    dtype = np.dtype(_FITS_DTYPES[bitpix])
    nbytes = n1 * n2 * dtype.itemsize
    if len(raw) < offset + nbytes:
        raise InputError("truncated FITS data", path=str(path))
    stored = np.frombuffer(raw, dtype=dtype, count=n1 * n2, offset=offset).reshape(n2, n1)
    image = stored.astype(np.float64)
    if bitpix > 0 and "BLANK" in header:
        image[stored == header["BLANK"]] = np.nan
    image = image * float(header.get("BSCALE", 1.0)) + float(header.get("BZERO", 0.0))
    return image, header


def read_sextractor_catalog(path) -> dict[str, np.ndarray]:
    """Read a SExtractor ASCII_HEAD catalogue.

    The header lines ``#   N NAME  description [unit]`` give the 1-based column ``N`` where
    each parameter starts; a vector parameter (``FLUX_RADIUS`` with several fractions) spans the
    columns up to the next name.

    Returns
    -------
    dict
        Name -> ndarray of shape ``(rows,)``, or ``(rows, k)`` for a vector parameter.
        Positions (``X_IMAGE``, ``XWIN_IMAGE``...) stay in SExtractor's 1-based convention;
        convert with :func:`fits_to_rowcol`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("SExtractor catalogue not found", path=str(path))
    starts: list[tuple[int, str]] = []
    for line in path.read_text(encoding="ascii", errors="replace").splitlines():
        if not line.startswith("#"):
            break
        parts = line[1:].split()
        if len(parts) >= 2 and parts[0].isdigit():
            starts.append((int(parts[0]), parts[1]))
    if not starts:
        raise InputError("no '#   N NAME' header lines: not an ASCII_HEAD catalogue",
                         path=str(path))
    data = np.loadtxt(path, comments="#", ndmin=2)
    bounds = [s for s, _ in starts] + [data.shape[1] + 1]
    if bounds[-2] > data.shape[1] or any(b2 <= b1 for b1, b2 in zip(bounds, bounds[1:])):
        raise InputError("header columns do not match the data", path=str(path))
    table = {}
    for (start, name), stop in zip(starts, bounds[1:]):
        cols = data[:, start - 1:stop - 1]
        table[name] = cols[:, 0] if cols.shape[1] == 1 else cols
    return table


# ============================================================================================
# Background
# ============================================================================================
@dataclass(frozen=True, eq=False)
class Background:
    """A smooth background level and noise map.

    Attributes
    ----------
    level : ndarray of float32, shape (H, W)
        Background level at every pixel.
    rms : ndarray of float32, shape (H, W)
        Background noise (standard deviation per pixel).
    mesh_level, mesh_rms : ndarray, shape (ny, nx)
        Values at the mesh cells, whose centres lie at ``((i + 0.5) H / ny, (j + 0.5) W / nx)``.
    """

    level: np.ndarray
    rms: np.ndarray
    mesh_level: np.ndarray
    mesh_rms: np.ndarray


def _block_edges(n: int, n_blocks: int) -> np.ndarray:
    return np.floor(np.arange(n_blocks + 1) * (n / n_blocks)).astype(np.intp)


def _block_samples(edges: np.ndarray, n_samples: int) -> np.ndarray:
    """``n_samples`` evenly spread pixel indices inside each block, shape (n_blocks, n_samples)."""
    lo, hi = edges[:-1, None], edges[1:, None]
    frac = (np.arange(n_samples) + 0.5) / n_samples
    return (lo + np.floor(frac * (hi - lo))).astype(np.intp)


def _clipped_mode(samples: np.ndarray, clip_sigma: float, iterations: int):
    """Sigma-clipped background statistics of each row of ``samples`` (shape (B, S)).

    Each row is sorted once; a clipping pass then only moves the bounds ``[lo, hi)`` of the
    kept slice: its median is read at the middle, its mean and variance from cumulative sums,
    and the new bounds by one ``searchsorted`` over all rows (the rows are offset so that
    their concatenation stays sorted). The mode is ``2.5 median - 1.5 mean`` unless the
    distribution is very skewed (``|mean - median| > 0.3 std``), where the median is kept
    (Bertin & Arnouts 1996, sec. 3.1).
    """
    s = np.sort(samples.astype(np.float64), axis=1)
    n_blocks, n = s.shape
    rows = np.arange(n_blocks)
    zero = np.zeros((n_blocks, 1))
    c1 = np.concatenate([zero, np.cumsum(s, axis=1)], axis=1)
    c2 = np.concatenate([zero, np.cumsum(s * s, axis=1)], axis=1)
    base = s[:, 0].min()
    span = s[:, -1].max() - base + 1.0
    offset = rows * span
    flat = (s - base + offset[:, None]).ravel()
    first = rows * n

    def stats(lo, hi):
        count = np.maximum(hi - lo, 1)
        median = s[rows, np.minimum(lo + count // 2, n - 1)]
        mean = (c1[rows, hi] - c1[rows, lo]) / count
        var = np.maximum((c2[rows, hi] - c2[rows, lo]) / count - mean * mean, 0.0)
        return median, mean, np.sqrt(var)

    lo = np.zeros(n_blocks, np.intp)
    hi = np.full(n_blocks, n, np.intp)
    for _ in range(iterations):
        median, mean, std = stats(lo, hi)
        low = np.clip(median - clip_sigma * std - base, -0.5, span - 0.5) + offset
        high = np.clip(median + clip_sigma * std - base, -0.5, span - 0.5) + offset
        new_lo = np.searchsorted(flat, low, "left") - first
        new_hi = np.maximum(np.searchsorted(flat, high, "right") - first, new_lo + 1)
        if np.array_equal(new_lo, lo) and np.array_equal(new_hi, hi):
            break
        lo, hi = new_lo, np.minimum(new_hi, n)
    median, mean, std = stats(lo, hi)
    skewed = np.abs(mean - median) > 0.3 * np.maximum(std, 1e-30)
    mode = np.where(skewed, median, 2.5 * median - 1.5 * mean)
    return mode, std


def estimate_background(
    image,
    *,
    mesh_px: int = 64,
    filter_size: int = 3,
    clip_sigma: float = 3.0,
    iterations: int = 8,
    samples_per_mesh: int = 256,
) -> Background:
    """SExtractor-like background and noise maps.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The frame (NaN pixels are replaced by the image median before sampling).
    mesh_px : int, optional
        Approximate mesh cell size in pixels; the image is split into ``round(H / mesh_px)``
        by ``round(W / mesh_px)`` equal cells (at least one).
    filter_size : int, optional
        Size of the median filter applied to the mesh (1 = none).
    clip_sigma : float, optional
        Clipping half-width around the median in standard deviations.
    iterations : int, optional
        Maximum clipping passes.
    samples_per_mesh : int, optional
        Pixels sampled on a regular sub-grid of each cell for the statistics. The mode's
        noise is about ``2.1 rms / sqrt(samples)`` per cell (0.13 rms for the default 256,
        chosen for speed; use ``mesh_px**2`` for SExtractor's all-pixel statistics).

    Returns
    -------
    Background

    Notes
    -----
    The mesh values are interpolated with OpenCV's bicubic resize, whose sample positions
    coincide with the cell centres because all cells have the same (fractional) size; beyond
    the outer centres the values are extended as constants.
    """
    img = _as_image(image)
    h, w = img.shape
    if mesh_px < 4:
        raise InputError("must be at least 4", field="mesh_px")
    ny, nx = max(1, int(round(h / mesh_px))), max(1, int(round(w / mesh_px)))
    side = max(2, int(np.sqrt(samples_per_mesh)))
    rows = _block_samples(_block_edges(h, ny), min(side, h // ny))
    cols = _block_samples(_block_edges(w, nx), min(side, w // nx))
    samples = img[rows[:, None, :, None], cols[None, :, None, :]].reshape(ny * nx, -1)
    if np.isnan(samples).any():
        samples = np.where(np.isnan(samples), np.nanmedian(img), samples)
    mode, std = _clipped_mode(samples, clip_sigma, iterations)
    mesh_level = mode.reshape(ny, nx)
    mesh_rms = std.reshape(ny, nx)
    if filter_size > 1 and (ny > 1 or nx > 1):
        mesh_level = ndi.median_filter(mesh_level, size=filter_size, mode="nearest")
        mesh_rms = ndi.median_filter(mesh_rms, size=filter_size, mode="nearest")
    level = cv2.resize(mesh_level.astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    rms = cv2.resize(mesh_rms.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    return Background(level=level, rms=np.maximum(rms, np.float32(1e-12)),
                      mesh_level=mesh_level, mesh_rms=mesh_rms)


def _as_image(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 2 or min(img.shape) < 3:
        raise InputError(f"expected a 2-D image of at least 3x3 pixels, got shape {img.shape}",
                         field="image")
    if img.dtype != np.float32:
        img = img.astype(np.float32)
    return img


# ============================================================================================
# Star table
# ============================================================================================
@dataclass(frozen=True, eq=False)
class StarTable:
    """Detected stars, one row per star, brightest first. All arrays have shape ``(N,)``.

    Attributes
    ----------
    row_px, col_px : ndarray
        Centroid, project convention (first pixel's centre at 0.5).
    flux : ndarray
        Background-subtracted flux (window sum; Gaussian integral for ``"gaussian"``), ADU.
    peak : ndarray
        Peak above the background, ADU (fitted amplitude for ``"gaussian"``).
    peak_snr : ndarray
        ``peak`` over the noise at the peak: the background's, plus the star's shot noise
        when the gain is known.
    fwhm_px : ndarray
        Full width at half maximum (fit, or second moments corrected for pixel size).
    area_px : ndarray of int
        Pixels of the detection footprint above the threshold.
    background : ndarray
        Background level at the star, ADU.
    flags : ndarray of uint8
        OR of :data:`FLAG_EDGE`, :data:`FLAG_SATURATED`, :data:`FLAG_FIT_FAILED`.
    method : str
        Centroid method used.
    """

    row_px: np.ndarray
    col_px: np.ndarray
    flux: np.ndarray
    peak: np.ndarray
    peak_snr: np.ndarray
    fwhm_px: np.ndarray
    area_px: np.ndarray
    background: np.ndarray
    flags: np.ndarray
    method: str

    def __len__(self) -> int:
        return int(self.row_px.size)

    @property
    def rowcol(self) -> np.ndarray:
        """Centroids as an ``(N, 2)`` array of ``(row, col)``."""
        return np.stack([self.row_px, self.col_px], axis=-1)

    def select(self, index) -> StarTable:
        """Rows picked by a boolean mask or an index array."""
        index = np.asarray(index)
        return StarTable(**{k: getattr(self, k)[index] for k in _TABLE_COLUMNS},
                         method=self.method)

    def to_dict(self) -> dict:
        """Columns as lists (JSON-ready)."""
        out = {k: getattr(self, k).tolist() for k in _TABLE_COLUMNS}
        out["method"] = self.method
        return out


_TABLE_COLUMNS = ("row_px", "col_px", "flux", "peak", "peak_snr", "fwhm_px", "area_px",
                  "background", "flags")


# ============================================================================================
# Detection
# ============================================================================================
def _resolve_background(img: np.ndarray, background, mesh_px: int) -> Background:
    if isinstance(background, Background):
        if background.level.shape != img.shape:
            raise InputError(f"background shape {background.level.shape} differs from the "
                             f"image's {img.shape}", field="background")
        return background
    if isinstance(background, str):
        if background != "auto":
            raise InputError(f"unknown background {background!r}; use 'auto', a number, an "
                             "array or a Background", field="background")
        return estimate_background(img, mesh_px=mesh_px)
    level = np.broadcast_to(np.asarray(background, dtype=np.float32), img.shape)
    resid = (img - level)[::2, ::2]
    resid = resid[np.isfinite(resid)]
    med = np.median(resid)
    rms = 1.4826 * np.median(np.abs(resid - med))
    return Background(level=np.ascontiguousarray(level), rms=np.full(img.shape, max(rms, 1e-12),
                      np.float32), mesh_level=np.atleast_2d(np.mean(level)),
                      mesh_rms=np.atleast_2d(rms))


def detect_stars(
    image,
    *,
    background="auto",
    threshold_sigma: float = 5.0,
    min_area: int = 3,
    max_stars: int | None = None,
    centroid: str = "iwc",
    window_px: int = 7,
    detect_sigma_px: float = 1.0,
    mesh_px: int = 64,
    saturation: float | None = None,
    gain_e_per_adu: float | None = None,
) -> StarTable:
    """Detect stars and measure their centroids.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The frame, in ADU.
    background : "auto", float, array_like (H, W) or Background, optional
        ``"auto"``: :func:`estimate_background` with ``mesh_px``. A number or an array: the
        level, with the noise estimated from the median absolute deviation of the residual.
    threshold_sigma : float, optional
        Detection threshold on the matched-filtered image, in units of *its* noise
        (``rms * sqrt(sum k^2)`` for the normalized Gaussian kernel ``k``): a matched-filter
        significance (5: false detections are rare, none in a 1-megapixel frame of noise in
        the tests).
    min_area : int, optional
        Minimum number of 8-connected pixels above the threshold.
    max_stars : int, optional
        Keep at most this many, the brightest (by the filtered peak).
    centroid : {"iwc", "gaussian", "windowed"}, optional
        Centroid method (see the module notes).
    window_px : int, optional
        Odd side of the square centroid window around the peak pixel (``"iwc"`` and
        ``"gaussian"``; ``"windowed"`` extends it to 4 PSF sigmas).
    detect_sigma_px : float, optional
        Sigma of the Gaussian matched filter (about the PSF's).
    mesh_px : int, optional
        Background mesh size for ``background="auto"``.
    saturation : float, optional
        Raw pixel value at or above which a star is flagged :data:`FLAG_SATURATED`.
    gain_e_per_adu : float, optional
        Detector gain; when given, ``peak_snr`` includes the star's own shot noise
        (``peak / sqrt(rms^2 + peak / gain)``), otherwise it is ``peak / rms``.

    Returns
    -------
    StarTable
        Brightest first.
    """
    img = _as_image(image)
    if centroid not in CENTROID_METHODS:
        raise InputError(f"unknown centroid method {centroid!r}; choose one of "
                         f"{CENTROID_METHODS}", field="centroid")
    if not (threshold_sigma > 0):
        raise InputError("must be positive", field="threshold_sigma")
    if min_area < 1:
        raise InputError("must be at least 1", field="min_area")
    if window_px < 3 or window_px % 2 == 0:
        raise InputError(f"must be an odd number >= 3, got {window_px}", field="window_px")
    if not (detect_sigma_px > 0):
        raise InputError("must be positive", field="detect_sigma_px")
    bkg = _resolve_background(img, background, mesh_px)
    sub = img - bkg.level
    valid = np.isfinite(sub)
    if not valid.all():
        sub = np.where(valid, sub, np.float32(0.0))
    ksize = 2 * int(np.ceil(3.0 * detect_sigma_px)) + 1
    filtered = cv2.GaussianBlur(sub, (ksize, ksize), detect_sigma_px,
                                borderType=cv2.BORDER_REFLECT)
    # noise of the filtered image: rms * sqrt(sum k^2); for the separable kernel k = k1 k1^T
    # sqrt(sum k^2) = sum k1^2 (~ 1 / (2 sqrt(pi) sigma) for sigma >~ 1 px)
    k1 = cv2.getGaussianKernel(ksize, detect_sigma_px, ktype=cv2.CV_64F)
    noise_factor = np.float32(np.sum(k1 * k1))
    mask = filtered > (np.float32(threshold_sigma) * noise_factor) * bkg.rms
    # 8-connected components; OpenCV's labelling equals scipy.ndimage.label with a 3x3
    # structure up to the label numbers, 5-7 times faster
    n_labels, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=8,
                                               ltype=cv2.CV_32S)
    n_labels -= 1
    empty = _empty_table(centroid)
    if n_labels == 0:
        return empty
    flat = np.flatnonzero(mask)
    lab = labels.ravel()[flat]
    area = np.bincount(lab, minlength=n_labels + 1)
    values = filtered.ravel()[flat]
    order = np.lexsort((-values, lab))
    first = np.r_[0, np.flatnonzero(np.diff(lab[order])) + 1]
    peak_flat = flat[order[first]]
    peak_value = values[order[first]]
    obj_area = area[lab[order[first]]]
    keep = obj_area >= min_area
    peak_flat, peak_value, obj_area = peak_flat[keep], peak_value[keep], obj_area[keep]
    if peak_flat.size == 0:
        return empty
    rank = np.argsort(-peak_value, kind="stable")
    if max_stars is not None:
        rank = rank[:max(0, int(max_stars))]
    peak_flat, obj_area = peak_flat[rank], obj_area[rank]
    peak_r, peak_c = np.divmod(peak_flat, img.shape[1])
    table = centroid_stars(sub, np.stack([peak_r, peak_c], axis=1), method=centroid,
                           window_px=window_px, rms=bkg.rms, valid=valid,
                           gain_e_per_adu=gain_e_per_adu)
    flags = table.flags.copy()
    if saturation is not None:
        r0 = np.clip(peak_r[:, None] + np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1]), 0,
                     img.shape[0] - 1)
        c0 = np.clip(peak_c[:, None] + np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1]), 0,
                     img.shape[1] - 1)
        flags[np.nanmax(img[r0, c0], axis=1) >= saturation] |= FLAG_SATURATED
    order = np.argsort(-table.flux, kind="stable")
    out = StarTable(
        row_px=table.row_px, col_px=table.col_px, flux=table.flux, peak=table.peak,
        peak_snr=table.peak_snr, fwhm_px=table.fwhm_px, area_px=obj_area.astype(np.int64),
        background=bkg.level[peak_r, peak_c].astype(np.float64), flags=flags, method=centroid,
    )
    return out.select(order)


def _empty_table(method: str) -> StarTable:
    z = np.zeros(0)
    return StarTable(row_px=z, col_px=z, flux=z, peak=z, peak_snr=z, fwhm_px=z,
                     area_px=np.zeros(0, np.int64), background=z, flags=np.zeros(0, np.uint8),
                     method=method)


# ============================================================================================
# Centroids
# ============================================================================================
def _windows(sub: np.ndarray, valid: np.ndarray, centre_rc: np.ndarray, half: int):
    """Square windows of side ``2 half + 1`` centred on integer pixels, shape (N, w, w).

    Returns the values (0 outside the image or where invalid), a validity mask and the
    continuous coordinates of the window's pixel centres (rows (N, w), cols (N, w)).
    """
    offs = np.arange(-half, half + 1)
    rr = centre_rc[:, 0:1] + offs  # (N, w) integer pixel rows
    cc = centre_rc[:, 1:2] + offs
    h, w = sub.shape
    inside_r = (rr >= 0) & (rr < h)
    inside_c = (cc >= 0) & (cc < w)
    rr_c = np.clip(rr, 0, h - 1)
    cc_c = np.clip(cc, 0, w - 1)
    vals = sub[rr_c[:, :, None], cc_c[:, None, :]].astype(np.float64)
    ok = inside_r[:, :, None] & inside_c[:, None, :] & valid[rr_c[:, :, None], cc_c[:, None, :]]
    vals = np.where(ok, vals, 0.0)
    return vals, ok, rr + 0.5, cc + 0.5


def centroid_stars(
    sub,
    peaks_rc,
    *,
    method: str = "iwc",
    window_px: int = 7,
    rms=None,
    valid=None,
    gain_e_per_adu: float | None = None,
) -> StarTable:
    """Centroids of stars around given peak pixels of a background-subtracted image.

    Parameters
    ----------
    sub : ndarray, shape (H, W)
        Background-subtracted image.
    peaks_rc : array_like of int, shape (N, 2)
        Integer array indices ``(i, j)`` of each star's peak pixel (its centre is at
        ``(i + 0.5, j + 0.5)``).
    method : {"iwc", "gaussian", "windowed"}
        See the module notes.
    window_px : int, optional
        Odd window side.
    rms : ndarray (H, W) or float, optional
        Background noise, for ``peak_snr`` (NaN without it).
    valid : ndarray of bool (H, W), optional
        Usable pixels.
    gain_e_per_adu : float, optional
        See :func:`detect_stars`.

    Returns
    -------
    StarTable
        In the order of ``peaks_rc`` (``area_px`` and ``background`` are zeros here).
    """
    sub = np.asarray(sub)
    peaks = np.asarray(peaks_rc, dtype=np.intp).reshape(-1, 2)
    if method not in CENTROID_METHODS:
        raise InputError(f"unknown centroid method {method!r}; choose one of "
                         f"{CENTROID_METHODS}", field="method")
    n = peaks.shape[0]
    if n == 0:
        return _empty_table(method)
    valid = np.isfinite(sub) if valid is None else valid
    half = window_px // 2
    vals, ok, rows, cols = _windows(sub, valid, peaks, half)
    flags = np.zeros(n, np.uint8)
    flags[~ok.all(axis=(1, 2))] |= FLAG_EDGE
    # eq. (1): intensity-weighted centroid over the window
    total = vals.sum(axis=(1, 2))
    safe = np.where(total > 0, total, 1.0)
    r_iwc = np.einsum("nij,ni->n", vals, rows) / safe
    c_iwc = np.einsum("nij,nj->n", vals, cols) / safe
    bad = total <= 0
    r_iwc[bad] = peaks[bad, 0] + 0.5
    c_iwc[bad] = peaks[bad, 1] + 0.5
    sigma = _moment_sigma(vals, rows, cols, r_iwc, c_iwc)
    peak = vals[:, half - 1:half + 2, half - 1:half + 2].max(axis=(1, 2))
    flux = total
    row, col = r_iwc, c_iwc
    if method == "gaussian":
        fit = _fit_gaussians(vals, ok, rows, cols, r_iwc, c_iwc, sigma, total)
        good = fit["ok"]
        row = np.where(good, fit["row"], r_iwc)
        col = np.where(good, fit["col"], c_iwc)
        sigma = np.where(good, fit["sigma"], sigma)
        flux = np.where(good, fit["flux"], total)
        peak = np.where(good, fit["amplitude"], peak)
        flags[~good] |= FLAG_FIT_FAILED
    elif method == "windowed":
        r_half = _half_light_radius(sub, valid, r_iwc, c_iwc, np.maximum(3.0 * sigma, 3.0))
        sigma = np.clip(r_half / np.sqrt(2.0 * np.log(2.0)), 0.3, 5.0)
        win = _windowed_centroids(sub, valid, r_iwc, c_iwc, sigma)
        good = win["ok"]
        row = np.where(good, win["row"], r_iwc)
        col = np.where(good, win["col"], c_iwc)
        flags[~good] |= FLAG_FIT_FAILED
        flags[win["edge"]] |= FLAG_EDGE
    if rms is None:
        noise = np.full(n, np.nan)
    else:
        rms_arr = np.broadcast_to(np.asarray(rms, dtype=np.float64), sub.shape)
        noise = rms_arr[peaks[:, 0], peaks[:, 1]]
        if gain_e_per_adu is not None:
            if not gain_e_per_adu > 0:
                raise InputError("must be positive", field="gain_e_per_adu")
            noise = np.sqrt(noise ** 2 + np.maximum(peak, 0.0) / gain_e_per_adu)
    return StarTable(
        row_px=np.asarray(row, np.float64), col_px=np.asarray(col, np.float64),
        flux=np.asarray(flux, np.float64), peak=np.asarray(peak, np.float64),
        peak_snr=peak / noise, fwhm_px=FWHM_PER_SIGMA * sigma,
        area_px=np.zeros(n, np.int64), background=np.zeros(n), flags=flags, method=method,
    )


def _moment_sigma(vals, rows, cols, r0, c0) -> np.ndarray:
    """PSF sigma from second moments of the positive pixels, minus the pixel's 1/12 px^2."""
    pos = np.maximum(vals, 0.0)
    total = np.maximum(pos.sum(axis=(1, 2)), 1e-30)
    dr2 = (rows - r0[:, None]) ** 2
    dc2 = (cols - c0[:, None]) ** 2
    var = (np.einsum("nij,ni->n", pos, dr2) + np.einsum("nij,nj->n", pos, dc2)) / (2 * total)
    return np.sqrt(np.clip(var - 1.0 / 12.0, 0.04, None))


def _size_groups(half_sizes: np.ndarray):
    """Yield ``(half, indices)`` for the stars sharing each window half-size (few groups)."""
    for half in np.unique(half_sizes):
        yield int(half), np.flatnonzero(half_sizes == half)


def _half_light_radius(sub, valid, r0, c0, aperture_px, oversample: int = 3) -> np.ndarray:
    """Radius enclosing half of the flux within ``aperture_px`` (like SExtractor FLUX_RADIUS).

    Each pixel is split into ``oversample^2`` sub-pixels carrying equal shares of its value;
    the radius is read on the cumulative flux of the sub-pixels sorted by distance to
    ``(r0, c0)`` and interpolated linearly. For a Gaussian, ``r_half = sigma sqrt(2 ln 2)``.
    Stars are processed in groups of equal window size.
    """
    out = np.empty(r0.size)
    sp = (np.arange(oversample) + 0.5) / oversample - 0.5
    for half, idx in _size_groups(np.ceil(aperture_px).astype(np.intp) + 1):
        n = idx.size
        centre = np.stack([np.floor(r0[idx]), np.floor(c0[idx])], axis=1).astype(np.intp)
        vals, _, rows, cols = _windows(sub, valid, centre, half)
        w = rows.shape[1]
        dr = (rows - r0[idx, None])[:, :, None] + sp  # (n, w, s)
        dc = (cols - c0[idx, None])[:, :, None] + sp
        rad = np.sqrt(dr[:, :, None, :, None] ** 2 + dc[:, None, :, None, :] ** 2).reshape(n, -1)
        share = np.broadcast_to((vals / oversample ** 2)[:, :, :, None, None],
                                (n, w, w, oversample, oversample)).reshape(n, -1)
        share = np.where(rad < aperture_px[idx, None], share, 0.0)
        order = np.argsort(rad, axis=1)
        rad_sorted = np.take_along_axis(rad, order, axis=1)
        cum = np.cumsum(np.take_along_axis(share, order, axis=1), axis=1)
        target = 0.5 * cum[:, -1:]
        k = np.clip(np.argmax(cum >= target, axis=1), 1, cum.shape[1] - 1)
        rows_n = np.arange(n)
        c_lo, c_hi = cum[rows_n, k - 1], cum[rows_n, k]
        t = np.clip((target[:, 0] - c_lo) / np.where(c_hi > c_lo, c_hi - c_lo, 1.0), 0.0, 1.0)
        out[idx] = rad_sorted[rows_n, k - 1] + t * (rad_sorted[rows_n, k]
                                                     - rad_sorted[rows_n, k - 1])
    return out


def _gaussian_model(params, rows, cols):
    """Pixel-integrated circular Gaussian + constant and its Jacobian, shapes (N, P), (N, P, 5).

    ``params[:, k]``: flux F, row r0, col c0, sigma s, background b;
    ``M_ij = b + F Er_i(r0, s) Ec_j(c0, s)``.
    """
    flux, r0, c0, s = params[:, 0], params[:, 1], params[:, 2], params[:, 3]
    er, der, dser = pixel_integrals(rows, r0, s)
    ec, dec, dsec = pixel_integrals(cols, c0, s)
    n, w = er.shape
    shape = er[:, :, None] * ec[:, None, :]
    model = params[:, 4, None, None] + flux[:, None, None] * shape
    jac = np.empty((n, w, w, 5))
    jac[..., 0] = shape
    jac[..., 1] = flux[:, None, None] * der[:, :, None] * ec[:, None, :]
    jac[..., 2] = flux[:, None, None] * er[:, :, None] * dec[:, None, :]
    jac[..., 3] = flux[:, None, None] * (dser[:, :, None] * ec[:, None, :]
                                         + er[:, :, None] * dsec[:, None, :])
    jac[..., 4] = 1.0
    return model.reshape(n, -1), jac.reshape(n, -1, 5)


def _fit_gaussians(vals, ok, rows, cols, r_init, c_init, s_init, flux_init,
                   iterations: int = 30):
    """Levenberg-Marquardt fits of :func:`_gaussian_model`, all stars at once.

    Each star has its own damping ``lambda`` (Marquardt's scaling by ``diag(J^T J)``); a step
    is kept only where it lowers that star's sum of squares.
    """
    n = vals.shape[0]
    data = vals.reshape(n, -1)
    weight = ok.reshape(n, -1).astype(np.float64)
    params = np.stack([np.maximum(flux_init, 1e-6), r_init, c_init,
                       np.clip(s_init, 0.3, rows.shape[1] / 2.0), np.zeros(n)], axis=1)
    model, jac = _gaussian_model(params, rows, cols)
    resid = (data - model) * weight
    cost = np.einsum("np,np->n", resid, resid)
    lam = np.full(n, 1e-3)
    active = np.ones(n, bool)
    eye = np.eye(5)
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        j = jac[idx] * weight[idx, :, None]
        jt = j.transpose(0, 2, 1)
        jtj = jt @ j
        jtr = (jt @ resid[idx, :, None])[..., 0]
        diag = np.einsum("nkk->nk", jtj)[:, :, None] * eye
        try:
            step = np.linalg.solve(jtj + lam[idx, None, None] * (diag + 1e-12 * eye),
                                   jtr[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        trial = params[idx] + step
        trial[:, 3] = np.clip(trial[:, 3], 0.2, rows.shape[1])
        t_model, t_jac = _gaussian_model(trial, rows[idx], cols[idx])
        t_resid = (data[idx] - t_model) * weight[idx]
        t_cost = np.einsum("np,np->n", t_resid, t_resid)
        better = t_cost < cost[idx]
        take = idx[better]
        params[take] = trial[better]
        jac[take] = t_jac[better]
        resid[take] = t_resid[better]
        rel = (cost[take] - t_cost[better]) / np.maximum(cost[take], 1e-300)
        cost[take] = t_cost[better]
        lam[take] /= 3.0
        lam[idx[~better]] *= 4.0
        small_step = np.max(np.abs(step[:, 1:3]), axis=1) < 1e-5
        done = np.zeros(n, bool)
        done[take[(rel < 1e-10)]] = True
        done[idx[small_step & better]] = True
        done[idx[lam[idx] > 1e8]] = True
        active &= ~done
    half = rows.shape[1] / 2.0
    centre_r = rows[:, rows.shape[1] // 2]
    centre_c = cols[:, cols.shape[1] // 2]
    good = (
        np.all(np.isfinite(params), axis=1)
        & (params[:, 0] > 0)
        & (params[:, 3] > 0.25) & (params[:, 3] < half)
        & (np.abs(params[:, 1] - centre_r) < half) & (np.abs(params[:, 2] - centre_c) < half)
    )
    amplitude = params[:, 0] * (erf(0.5 / (_SQRT2 * params[:, 3]))) ** 2
    return {"row": params[:, 1], "col": params[:, 2], "sigma": params[:, 3],
            "flux": params[:, 0], "amplitude": amplitude, "ok": good}


def _windowed_centroids(sub, valid, r_init, c_init, sigma, iterations: int = 16,
                        tolerance_px: float = 2e-4):
    """SExtractor's ``XWIN``: ``x <- x + 2 sum w_i I_i (x_i - x) / sum w_i I_i``.

    ``w_i = exp(-r_i^2 / (2 s^2))`` with ``s`` the PSF sigma, summed within ``4 s`` of the
    current position; iterated until the move is below ``tolerance_px``. Stars are processed
    in groups of equal window size.
    """
    n = r_init.size
    s = np.clip(sigma, 0.3, 5.0)
    halves = np.ceil(4.0 * s).astype(np.intp) + 1
    row, col = r_init.copy(), c_init.copy()
    active = np.ones(n, bool)
    edge = np.zeros(n, bool)
    for _ in range(iterations):
        if not active.any():
            break
        for half, idx in _size_groups(np.where(active, halves, -1)):
            if half < 0:
                continue
            centre = np.stack([np.floor(row[idx]), np.floor(col[idx])], axis=1).astype(np.intp)
            vals, ok, rows, cols = _windows(sub, valid, centre, half)
            dr = rows - row[idx, None]
            dc = cols - col[idx, None]
            si = s[idx, None, None]
            r2 = dr[:, :, None] ** 2 + dc[:, None, :] ** 2
            inside = r2 < (4.0 * si) ** 2
            wi = np.exp(-r2 / (2.0 * si * si)) * (inside & ok) * vals
            norm = wi.sum(axis=(1, 2))
            safe = np.where(norm > 0, norm, 1.0)
            step_r = np.clip(2.0 * np.einsum("nij,ni->n", wi, dr) / safe, -1.0, 1.0)
            step_c = np.clip(2.0 * np.einsum("nij,nj->n", wi, dc) / safe, -1.0, 1.0)
            step_r[norm <= 0] = 0.0
            step_c[norm <= 0] = 0.0
            row[idx] += step_r
            col[idx] += step_c
            edge[idx] = np.any(inside & ~ok, axis=(1, 2))
            active[idx[np.hypot(step_r, step_c) < tolerance_px]] = False
    moved = np.hypot(row - r_init, col - c_init)
    good = np.isfinite(row) & np.isfinite(col) & (moved < 2.0 * s + 1.0)
    return {"row": row, "col": col, "ok": good, "edge": edge}


# ============================================================================================
# Simulation (forward model of the Gaussian fit)
# ============================================================================================
# ============================================================================================
# Camera pointing (pinhole) for identification
# ============================================================================================
@dataclass(frozen=True, eq=False)
class CameraPointing:
    """A pinhole camera's attitude and focal length, enough to project stars.

    Attributes
    ----------
    camera_to_gcrf : scipy.spatial.transform.Rotation
        Rotation taking camera-frame vectors (x = +col, y = +row, z = boresight) to GCRF.
    focal_px : float
        Focal length in pixels.
    principal_point_px : tuple of float
        ``(row, col)`` where the boresight meets the image.
    """

    camera_to_gcrf: Rotation
    focal_px: float
    principal_point_px: tuple[float, float]

    @classmethod
    def from_boresight(cls, ra_rad: float, dec_rad: float, roll_rad: float, *,
                       focal_px: float, principal_point_px) -> CameraPointing:
        """Pointing from the boresight's right ascension, declination and the roll.

        The roll is the position angle of the image's top (decreasing rows) measured from
        north through east; with roll 0, north is up and east left. Camera axes in GCRF:
        ``z = b`` (boresight), ``y = -up`` with ``up = cos(roll) n + sin(roll) e``,
        ``x = b x up`` (``n``, ``e``: north and east unit vectors at ``b``).
        """
        ca, sa, cd, sd = np.cos(ra_rad), np.sin(ra_rad), np.cos(dec_rad), np.sin(dec_rad)
        bore = np.array([cd * ca, cd * sa, sd])
        north = np.array([-sd * ca, -sd * sa, cd])
        east = np.array([-sa, ca, 0.0])
        up = np.cos(roll_rad) * north + np.sin(roll_rad) * east
        mat = np.column_stack([np.cross(bore, up), -up, bore])
        return cls(Rotation.from_matrix(mat), float(focal_px),
                   (float(principal_point_px[0]), float(principal_point_px[1])))

    @property
    def boresight_gcrf(self) -> np.ndarray:
        """Unit boresight vector in GCRF, shape (3,)."""
        return self.camera_to_gcrf.as_matrix()[:, 2]

    @property
    def ra_dec_roll_rad(self) -> tuple[float, float, float]:
        """Boresight right ascension, declination and roll (see :meth:`from_boresight`)."""
        mat = self.camera_to_gcrf.as_matrix()
        bore, up = mat[:, 2], -mat[:, 1]
        ra = float(np.mod(np.arctan2(bore[1], bore[0]), 2 * np.pi))
        dec = float(np.arctan2(bore[2], np.hypot(bore[0], bore[1])))
        ca, sa, cd, sd = np.cos(ra), np.sin(ra), np.cos(dec), np.sin(dec)
        north = np.array([-sd * ca, -sd * sa, cd])
        east = np.array([-sa, ca, 0.0])
        roll = float(np.mod(np.arctan2(up @ east, up @ north), 2 * np.pi))
        return ra, dec, roll

    def project(self, vectors_gcrf) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions of directions.

        Parameters
        ----------
        vectors_gcrf : array_like, shape (N, 3)

        Returns
        -------
        rowcol : ndarray, shape (N, 2)
            ``r0 + f y/z``, ``c0 + f x/z`` in the camera frame (NaN behind the camera).
        in_front : ndarray of bool, shape (N,)
        """
        v = np.asarray(vectors_gcrf, dtype=np.float64).reshape(-1, 3)
        cam = self.camera_to_gcrf.inv().apply(v) if v.shape[0] else v
        in_front = cam[:, 2] > 1e-9
        z = np.where(in_front, cam[:, 2], np.nan)
        r0, c0 = self.principal_point_px
        return np.stack([r0 + self.focal_px * cam[:, 1] / z,
                         c0 + self.focal_px * cam[:, 0] / z], axis=1), in_front

    def rays(self, rowcol) -> np.ndarray:
        """Unit GCRF directions seen by pixels ``(N, 2)`` -> ``(N, 3)``."""
        cam = _camera_rays(np.asarray(rowcol, np.float64).reshape(-1, 2), self.focal_px,
                           self.principal_point_px)
        return self.camera_to_gcrf.apply(cam) if cam.shape[0] else cam


def _camera_rays(rowcol: np.ndarray, focal_px, principal_point_px) -> np.ndarray:
    r0, c0 = principal_point_px
    x = (rowcol[..., 1] - c0) / focal_px
    y = (rowcol[..., 0] - r0) / focal_px
    x, y = np.broadcast_arrays(x, y)
    v = np.stack([x, y, np.ones(x.shape)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _kabsch(cam: np.ndarray, sky: np.ndarray, weights=None) -> np.ndarray:
    """Rotation(s) ``R`` minimising ``sum w |sky - R cam|^2`` (Wahba's problem, SVD).

    ``cam``, ``sky``: shape (..., K, 3); returns (..., 3, 3) with ``det R = +1``.
    """
    w = np.ones(cam.shape[:-1]) if weights is None else weights
    b = np.einsum("...k,...ki,...kj->...ij", w, sky, cam)
    u, _, vt = np.linalg.svd(b)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


# ============================================================================================
# Pattern index (lost in space)
# ============================================================================================
@dataclass(frozen=True, eq=False)
class StarPatternIndex:
    """Catalogue star triangles hashed by their side ratios.

    Each triangle of pattern stars whose sides are all below ``max_side_rad`` is stored with
    its vertices ordered ``(A, B, C)`` = opposite the (shortest, middle, longest) side, its
    ratios ``r1 = short / long`` and ``r2 = middle / long`` (scale free), its longest side and
    its handedness ``sign(det[A, B, C])``. Triangles are sorted by the hash
    ``floor(r1 / bin) * nbins + floor(r2 / bin)``; a query reads the 3 x 3 neighbouring bins.

    Attributes
    ----------
    catalog_index : ndarray of int, shape (P,)
        Row of each pattern star in the catalogue arrays given to :meth:`build`.
    vectors : ndarray, shape (P, 3)
        Their unit vectors.
    triangles : ndarray of int32, shape (T, 3)
        Pattern-star indices ``(A, B, C)``.
    ratios : ndarray of float32, shape (T, 2)
    long_side_rad : ndarray of float32, shape (T,)
    handedness : ndarray of int8, shape (T,)
    keys : ndarray of int64, shape (T,)
        Sorted hash keys.
    bin_width : float
    max_side_rad : float
    """

    catalog_index: np.ndarray
    vectors: np.ndarray
    triangles: np.ndarray
    ratios: np.ndarray
    long_side_rad: np.ndarray
    handedness: np.ndarray
    keys: np.ndarray
    bin_width: float
    max_side_rad: float

    @property
    def n_bins(self) -> int:
        return int(np.ceil(1.0 / self.bin_width)) + 2

    @classmethod
    def build(cls, catalog_vectors, magnitudes, *, n_stars: int, max_side_deg: float,
              bin_width: float = 0.01) -> StarPatternIndex:
        """Index the triangles of the ``n_stars`` brightest catalogue stars.

        Parameters
        ----------
        catalog_vectors : array_like, shape (M, 3)
            Unit vectors (apparent directions at the date, or catalogue positions: a few
            arcseconds do not matter here).
        magnitudes : array_like, shape (M,)
            Brightness for the selection (smaller is brighter).
        n_stars : int
            Pattern stars: the brightest ``n_stars``.
        max_side_deg : float
            Longest triangle side kept (the frame's shorter angular side is a good choice).
        bin_width : float, optional
            Hash bin in ratio units; also the ratio tolerance of queries.
        """
        vec = np.asarray(catalog_vectors, dtype=np.float64).reshape(-1, 3)
        mag = np.asarray(magnitudes, dtype=np.float64).reshape(-1)
        if mag.shape[0] != vec.shape[0]:
            raise InputError(f"{mag.shape[0]} magnitudes for {vec.shape[0]} vectors",
                             field="magnitudes")
        if not (0 < max_side_deg < 90):
            raise InputError("must lie in (0, 90) degrees", field="max_side_deg")
        if not (0 < bin_width < 0.2):
            raise InputError("must lie in (0, 0.2)", field="bin_width")
        order = np.argsort(mag, kind="stable")[:max(3, int(n_stars))]
        pv = vec[order]
        max_side = np.deg2rad(max_side_deg)
        chord = 2.0 * np.sin(max_side / 2.0)
        pairs = cKDTree(pv).query_pairs(chord, output_type="ndarray")  # i < j
        tri = _triangles_from_pairs(pairs, pv.shape[0])
        if tri.shape[0] == 0:
            raise InputError("no catalogue triangle fits: raise n_stars or max_side_deg")
        tri, ratios, long_side, hand = _triangle_shapes(pv, tri)
        keys = _hash_keys(ratios, bin_width)
        srt = np.argsort(keys, kind="stable")
        return cls(catalog_index=order, vectors=pv, triangles=tri[srt].astype(np.int32),
                   ratios=ratios[srt].astype(np.float32),
                   long_side_rad=long_side[srt].astype(np.float32),
                   handedness=hand[srt].astype(np.int8), keys=keys[srt],
                   bin_width=float(bin_width), max_side_rad=float(max_side))

    @classmethod
    def for_camera(cls, catalog_vectors, magnitudes, *, image_shape, focal_px: float,
                   stars_per_fov: float = 12.0, bin_width: float = 0.01) -> StarPatternIndex:
        """An index sized for a frame: ``stars_per_fov`` pattern stars per frame on average
        and triangles no longer than the frame's shorter angular side."""
        h, w = image_shape
        fov_h = 2 * np.arctan(h / (2 * focal_px))
        fov_w = 2 * np.arctan(w / (2 * focal_px))
        n_stars = int(round(stars_per_fov * 4 * np.pi / (fov_h * fov_w)))
        return cls.build(catalog_vectors, magnitudes, n_stars=n_stars,
                         max_side_deg=float(np.rad2deg(min(fov_h, fov_w))), bin_width=bin_width)

    def query(self, r1: float, r2: float, tolerance: float | None = None) -> np.ndarray:
        """Indices of triangles with both ratios within ``tolerance`` (default one bin)."""
        tol = self.bin_width if tolerance is None else tolerance
        nb = self.n_bins
        i1, i2 = int(np.floor(r1 / self.bin_width)), int(np.floor(r2 / self.bin_width))
        k = ((i1 + np.array([-1, 0, 1]))[:, None] * nb + (i2 + np.array([-1, 0, 1]))).ravel()
        lo = np.searchsorted(self.keys, k, "left")
        hi = np.searchsorted(self.keys, k, "right")
        idx = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi) if b > a] or
                             [np.zeros(0, np.intp)])
        if idx.size:
            d = np.abs(self.ratios[idx] - np.array([r1, r2], np.float32))
            idx = idx[(d[:, 0] <= tol) & (d[:, 1] <= tol)]
        return idx


def _triangles_from_pairs(pairs: np.ndarray, n: int) -> np.ndarray:
    """All ``(i, j, k)``, ``i < j < k``, whose three pairs are in ``pairs`` (i < j rows)."""
    if pairs.shape[0] == 0:
        return np.zeros((0, 3), np.int64)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    edge_key = pairs[:, 0].astype(np.int64) * n + pairs[:, 1]
    start = np.searchsorted(pairs[:, 0], np.arange(n + 1))
    deg = np.diff(start)
    # wedges (i; j, k) with j < k both upper neighbours of i
    n_wedge = deg * (deg - 1) // 2
    owner = np.repeat(np.arange(n), n_wedge)
    if owner.size == 0:
        return np.zeros((0, 3), np.int64)
    first = np.repeat(np.cumsum(n_wedge) - n_wedge, n_wedge)
    local = np.arange(owner.size) - first
    d = deg[owner]
    # unrank local -> (a, b), a < b < d: row a holds d - 1 - a pairs
    a = (d - 0.5 - np.sqrt((d - 0.5) ** 2 - 2.0 * local)).astype(np.int64)
    a = np.clip(a, 0, None)
    before = a * (2 * d - a - 1) // 2
    fix = before > local
    while np.any(fix):
        a[fix] -= 1
        before = a * (2 * d - a - 1) // 2
        fix = before > local
    over = (before + (d - 1 - a)) <= local
    while np.any(over):
        a[over] += 1
        before = a * (2 * d - a - 1) // 2
        over = (before + (d - 1 - a)) <= local
    b = a + 1 + (local - before)
    j = pairs[start[owner] + a, 1]
    k = pairs[start[owner] + b, 1]
    closing = j.astype(np.int64) * n + k
    pos = np.searchsorted(edge_key, closing)
    pos = np.minimum(pos, edge_key.size - 1)
    hit = edge_key[pos] == closing
    return np.stack([owner[hit], j[hit], k[hit]], axis=1).astype(np.int64)


def _triangle_shapes(vectors: np.ndarray, tri: np.ndarray):
    """Reorder triangles (A, B, C) by opposite side and compute ratios, long side, handedness.

    ``vectors``: (P, 3) unit vectors; ``tri``: (T, 3) indices. Sides are angles.
    """
    v = vectors[tri]  # (T, 3, 3)
    # side opposite vertex m joins the two others
    opp = np.stack([
        _angle(v[:, 1], v[:, 2]), _angle(v[:, 0], v[:, 2]), _angle(v[:, 0], v[:, 1])], axis=1)
    order = np.argsort(opp, axis=1, kind="stable")
    tri = np.take_along_axis(tri, order, axis=1)
    sides = np.take_along_axis(opp, order, axis=1)
    v = vectors[tri]
    ratios = sides[:, :2] / sides[:, 2:3]
    hand = np.sign(np.einsum("ti,ti->t", v[:, 0], np.cross(v[:, 1], v[:, 2])))
    return tri, ratios, sides[:, 2], hand


def _angle(a, b):
    """Angle between unit vectors along the last axis (stable for small angles)."""
    return 2.0 * np.arcsin(np.clip(np.linalg.norm(a - b, axis=-1) / 2.0, 0.0, 1.0))


def _hash_keys(ratios, bin_width):
    nb = int(np.ceil(1.0 / bin_width)) + 2
    i = np.floor(ratios / bin_width).astype(np.int64)
    return i[..., 0] * nb + i[..., 1]


# ============================================================================================
# Identification
# ============================================================================================
@dataclass(frozen=True, eq=False)
class StarIdentification:
    """Outcome of :func:`identify_stars` (``success=False`` with a message when it fails).

    Attributes
    ----------
    success : bool
    message : str
    catalog_index : ndarray of int, shape (N,)
        Catalogue row of each centroid, -1 where unidentified.
    pointing : CameraPointing or None
        Refined attitude and focal length.
    residuals_px : ndarray, shape (N, 2)
        Measured minus projected ``(row, col)`` for identified stars, NaN elsewhere.
    n_matched : int
    rms_px, rms_arcsec : float
        Root-mean-square residual length (NaN when nothing matched).
    false_alarm_probability : float
        Probability that at least this many matches arise by chance from random detections
        (binomial tail with the catalogue's density in the frame).
    method : str
        ``"pointing"`` (a) or ``"lost_in_space"`` (b).
    n_hypotheses : int
        Attitude hypotheses tested (lost in space).
    """

    success: bool
    message: str
    catalog_index: np.ndarray
    pointing: CameraPointing | None
    residuals_px: np.ndarray
    n_matched: int
    rms_px: float
    rms_arcsec: float
    false_alarm_probability: float
    method: str
    n_hypotheses: int = 0
    details: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-ready figures."""
        out = {"success": self.success, "message": self.message, "method": self.method,
               "n_matched": self.n_matched, "rms_px": self.rms_px,
               "rms_arcsec": self.rms_arcsec,
               "false_alarm_probability": self.false_alarm_probability,
               "n_hypotheses": self.n_hypotheses}
        if self.pointing is not None:
            ra, dec, roll = self.pointing.ra_dec_roll_rad
            out.update(ra_deg=np.rad2deg(ra), dec_deg=np.rad2deg(dec),
                       roll_deg=np.rad2deg(roll), focal_px=self.pointing.focal_px)
        return out


def _failed(message, n, method, n_hyp=0) -> StarIdentification:
    return StarIdentification(False, message, np.full(n, -1), None, np.full((n, 2), np.nan), 0,
                              np.nan, np.nan, 1.0, method, n_hyp)


def identify_stars(
    centroids_px,
    catalog_vectors,
    *,
    image_shape,
    approximate_pointing: CameraPointing | None = None,
    fov_deg: float | None = None,
    focal_px: float | None = None,
    pixel_scale_arcsec: float | None = None,
    principal_point_px=None,
    catalog_magnitudes=None,
    pattern_index: StarPatternIndex | None = None,
    match_tolerance_px: float = 3.0,
    pointing_uncertainty_deg: float = 0.5,
    fov_tolerance: float = 0.1,
    refine_focal: bool = True,
    n_pattern_stars: int = 10,
    n_verify_stars: int = 30,
    min_matches: int = 6,
    false_alarm: float = 1e-9,
    max_iterations: int = 10,
) -> StarIdentification:
    """Identify detected stars against catalogue directions.

    Parameters
    ----------
    centroids_px : array_like, shape (N, 2)
        ``(row, col)`` of the detections, brightest first (as :func:`detect_stars` returns).
    catalog_vectors : array_like, shape (M, 3)
        Catalogue unit vectors in GCRF (e.g. :func:`sensor_models.stars.apparent_directions`).
    image_shape : (int, int)
        ``(H, W)`` of the frame.
    approximate_pointing : CameraPointing, optional
        Known attitude and focal length: method (a). Without it, lost in space (b).
    fov_deg, focal_px, pixel_scale_arcsec : float, optional
        Approximate scale for lost in space, one of them: the horizontal field of view
        across ``W`` pixels, the focal length in pixels, or the pixel scale at the centre.
    principal_point_px : (float, float), optional
        ``(row, col)`` of the boresight; default the image centre ``(H / 2, W / 2)``.
    catalog_magnitudes : array_like, shape (M,), optional
        Needed by lost in space to pick the pattern stars (unless ``pattern_index`` is given).
    pattern_index : StarPatternIndex, optional
        A prebuilt index (reuse it across frames and dates: it may be built from catalogue
        positions while ``catalog_vectors`` are apparent places, since only the hypotheses
        come from it); built with :meth:`StarPatternIndex.for_camera` otherwise (~1 s).
    match_tolerance_px : float, optional
        Final matching radius.
    pointing_uncertainty_deg : float, optional
        (a) Radius searched for the initial offset between the projected catalogue and the
        detections.
    fov_tolerance : float, optional
        (b) Relative uncertainty of the given scale.
    refine_focal : bool, optional
        Estimate the focal length with the rotation.
    n_pattern_stars : int, optional
        (b) Brightest detections combined into triangles.
    n_verify_stars : int, optional
        (b) Brightest detections used to verify a hypothesis.
    min_matches : int, optional
        Fewest identified stars for success.
    false_alarm : float, optional
        Largest accepted probability that the matches are chance coincidences.
    max_iterations : int, optional
        Match / solve iterations in (a).

    Returns
    -------
    StarIdentification
    """
    rc = np.asarray(centroids_px, dtype=np.float64).reshape(-1, 2)
    cat = np.asarray(catalog_vectors, dtype=np.float64).reshape(-1, 3)
    n = rc.shape[0]
    if not np.all(np.isfinite(rc)):
        raise InputError("centroids hold NaN or infinite values", field="centroids_px")
    if cat.shape[0] == 0 or not np.all(np.isfinite(cat)):
        raise InputError("empty or non-finite catalogue vectors", field="catalog_vectors")
    h, w = (int(image_shape[0]), int(image_shape[1]))
    pp = (h / 2.0, w / 2.0) if principal_point_px is None else (
        float(principal_point_px[0]), float(principal_point_px[1]))
    if approximate_pointing is not None:
        if n < 3:
            return _failed(f"{n} detections; at least 3 are needed", n, "pointing")
        # only the catalogue around the frame: a small tree instead of the whole sky's
        ap = approximate_pointing
        corner = np.hypot(max(ap.principal_point_px[0], h - ap.principal_point_px[0]),
                          max(ap.principal_point_px[1], w - ap.principal_point_px[1]))
        reach = np.arctan(corner / ap.focal_px) + np.deg2rad(pointing_uncertainty_deg) \
            + 20.0 * match_tolerance_px / ap.focal_px
        near = np.flatnonzero(cat @ ap.boresight_gcrf > np.cos(min(reach, np.pi)))
        if near.size == 0:
            return _failed("no catalogue star near the approximate pointing", n, "pointing")
        result = _refine(rc, cat[near], cKDTree(cat[near]), ap, (h, w), match_tolerance_px,
                         pointing_uncertainty_deg, refine_focal, min_matches, false_alarm,
                         max_iterations, "pointing", 0)
        known = result.catalog_index >= 0
        result.catalog_index[known] = near[result.catalog_index[known]]
        return result
    tree = cKDTree(cat)
    scales = [x is not None for x in (fov_deg, focal_px, pixel_scale_arcsec)]
    if sum(scales) != 1:
        raise InputError("lost-in-space identification needs exactly one of fov_deg, "
                         "focal_px, pixel_scale_arcsec (or give approximate_pointing)")
    if fov_deg is not None:
        if not (0 < fov_deg < 120):
            raise InputError("must lie in (0, 120) degrees", field="fov_deg")
        f0 = (w / 2.0) / np.tan(np.deg2rad(fov_deg) / 2.0)
    elif focal_px is not None:
        f0 = float(focal_px)
    else:
        f0 = ARCSEC_PER_RAD / float(pixel_scale_arcsec)
    if not (f0 > 0 and np.isfinite(f0)):
        raise InputError("the scale must be positive and finite")
    if pattern_index is None:
        if catalog_magnitudes is None:
            raise InputError("lost in space needs catalog_magnitudes (or a pattern_index)",
                             field="catalog_magnitudes")
        pattern_index = StarPatternIndex.for_camera(cat, catalog_magnitudes,
                                                    image_shape=(h, w), focal_px=f0)
    if n < 4:
        return _failed(f"{n} detections; lost in space needs at least 4", n, "lost_in_space")
    return _lost_in_space(rc, cat, tree, pattern_index, (h, w), pp, f0, match_tolerance_px,
                          fov_tolerance, refine_focal, n_pattern_stars, n_verify_stars,
                          min_matches, false_alarm, max_iterations)


def _false_alarm(n_matched: int, n_det: int, n_cat_in_frame: int, tol_px: float,
                 frame_area_px: float, n_given: int = 0) -> float:
    """Probability of ``>= n_matched`` chance matches among ``n_det`` random detections.

    A random detection falls within ``tol_px`` of one of ``n_cat_in_frame`` projected stars
    with probability ``p = n_cat pi tol^2 / area``; ``n_given`` matches are not counted
    (those that defined the hypothesis).
    """
    p = min(1.0, n_cat_in_frame * np.pi * tol_px ** 2 / frame_area_px)
    k = n_matched - n_given
    if k <= 0:
        return 1.0
    return float(binom.sf(k - 1, max(n_det - n_given, 0), p))


def _in_frame(pointing: CameraPointing, cat: np.ndarray, tree: cKDTree, shape, margin_px):
    """Catalogue rows projecting inside the frame (+ margin) and their pixel positions."""
    h, w = shape
    f = pointing.focal_px
    half_diag = np.hypot(h, w) / 2.0 + margin_px + np.hypot(
        pointing.principal_point_px[0] - h / 2, pointing.principal_point_px[1] - w / 2)
    radius = np.arctan(half_diag / f)
    idx = np.asarray(tree.query_ball_point(pointing.boresight_gcrf,
                                           2 * np.sin(min(radius, np.pi / 2.01) / 2)),
                     dtype=np.intp)
    if idx.size == 0:
        return idx, np.zeros((0, 2))
    proj, front = pointing.project(cat[idx])
    inside = front & (proj[:, 0] > -margin_px) & (proj[:, 0] < h + margin_px) \
        & (proj[:, 1] > -margin_px) & (proj[:, 1] < w + margin_px)
    return idx[inside], proj[inside]


def _mutual_matches(rc: np.ndarray, proj: np.ndarray, tol: float):
    """Mutual nearest neighbours within ``tol``: (detection index, projection index)."""
    if proj.shape[0] == 0 or rc.shape[0] == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    d1, j = cKDTree(proj).query(rc, distance_upper_bound=tol)
    _, i_back = cKDTree(rc).query(proj)
    det = np.flatnonzero(np.isfinite(d1))
    mutual = i_back[j[det]] == det
    return det[mutual], j[det[mutual]]


def _solve_pointing(rc, sky, pointing: CameraPointing, refine_focal: bool,
                    iterations: int = 5) -> CameraPointing:
    """Rotation by SVD (Wahba) alternating with the linear focal-length update.

    With the rotation fixed, the tangent-plane coordinates ``t = (x/z, y/z)`` of the catalogue
    directions in the camera frame and the measured ``m = (col - c0, row - r0)`` give
    ``f = sum m.t / sum t.t``.
    """
    f = pointing.focal_px
    pp = pointing.principal_point_px
    rot = pointing.camera_to_gcrf.as_matrix()
    m = np.stack([rc[:, 1] - pp[1], rc[:, 0] - pp[0]], axis=1)
    for _ in range(iterations if refine_focal else 1):
        rot = _kabsch(_camera_rays(rc, f, pp), sky)
        if not refine_focal or rc.shape[0] < 3:
            break
        cam = sky @ rot  # rows: R^T s
        t = cam[:, :2] / cam[:, 2:3]
        f_new = float(np.sum(m * t) / np.sum(t * t))
        if not (np.isfinite(f_new) and f_new > 0):
            break
        converged = abs(f_new - f) < 1e-9 * f
        f = f_new
        if converged:
            break
    return CameraPointing(Rotation.from_matrix(rot), f, pp)


def _offset_vote(rc: np.ndarray, proj: np.ndarray, radius: float, bin_px: float):
    """Most common offset ``detection - projection`` within ``radius``.

    The offsets of all pairs closer than ``radius`` are histogrammed in bins of ``bin_px``;
    the fullest bin's centre is then refined by two mean-shift steps (mean of the offsets
    within one bin of the estimate).
    """
    if proj.shape[0] == 0 or rc.shape[0] == 0:
        return np.zeros(2)
    pairs = cKDTree(proj).query_ball_point(rc, radius)
    det = np.repeat(np.arange(rc.shape[0]), [len(p) for p in pairs])
    if det.size == 0:
        return np.zeros(2)
    prj = np.fromiter((j for p in pairs for j in p), dtype=np.intp, count=det.size)
    diff = rc[det] - proj[prj]
    nbin = max(1, int(np.ceil(2 * radius / bin_px)))
    hist, er, ec = np.histogram2d(diff[:, 0], diff[:, 1], bins=nbin,
                                  range=[[-radius, radius], [-radius, radius]])
    i, j = np.unravel_index(np.argmax(hist), hist.shape)
    guess = np.array([(er[i] + er[i + 1]) / 2, (ec[j] + ec[j + 1]) / 2])
    for _ in range(2):
        near = np.linalg.norm(diff - guess, axis=1) < bin_px
        if not near.any():
            break
        guess = diff[near].mean(axis=0)
    return guess


def _robust_solve(rc, sky, pointing: CameraPointing, refine_focal: bool, tol: float):
    """:func:`_solve_pointing`, then again without the pairs whose residual exceeds
    ``max(3 x 1.4826 MAD, tol / 2)`` (mismatches caught in a wide search radius)."""
    solved = _solve_pointing(rc, sky, pointing, refine_focal)
    proj, _ = solved.project(sky)
    res = np.linalg.norm(rc - proj, axis=1)
    limit = max(3.0 * 1.4826 * np.median(res), tol / 2.0)
    keep = res <= limit
    if 3 <= keep.sum() < keep.size:
        solved = _solve_pointing(rc[keep], sky[keep], solved, refine_focal and keep.sum() >= 4)
    return solved


def _refine(rc, cat, tree, pointing: CameraPointing, shape, tol, uncertainty_deg,
            refine_focal, min_matches, false_alarm, max_iterations, method, n_hyp,
            n_given: int = 0) -> StarIdentification:
    """Method (a): offset vote, then match / solve with a shrinking radius until stable.

    The matching radius goes ``4 tol, 2 tol, tol`` (roll and scale errors of the starting
    pointing grow with the distance from the centre); each solve drops outlying pairs.
    """
    n = rc.shape[0]
    h, w = shape
    radius = pointing.focal_px * np.tan(np.deg2rad(uncertainty_deg))
    if radius > tol:
        idx, proj = _in_frame(pointing, cat, tree, shape, radius)
        shift = _offset_vote(rc, proj, radius, bin_px=2.0 * tol)
        det, prj = _mutual_matches(rc, proj + shift, 4.0 * tol)
        if det.size >= 3:
            pointing = _robust_solve(rc[det], cat[idx[prj]], pointing, False, 4.0 * tol)
    radii = (4.0 * tol, 2.0 * tol, tol)
    previous = None
    for it in range(max(max_iterations, len(radii))):
        radius_it = radii[min(it, len(radii) - 1)]
        idx, proj = _in_frame(pointing, cat, tree, shape, radius_it)
        det, prj = _mutual_matches(rc, proj, radius_it)
        if det.size < 3:
            return _failed(f"only {det.size} stars matched within {radius_it:.1f} px", n,
                           method, n_hyp)
        key = (radius_it, tuple(det), tuple(idx[prj]))
        if key == previous:
            break
        previous = key
        pointing = _robust_solve(rc[det], cat[idx[prj]], pointing,
                                 refine_focal and det.size >= 4, radius_it)
    idx, proj = _in_frame(pointing, cat, tree, shape, tol)
    det, prj = _mutual_matches(rc, proj, tol)
    catalog_index = np.full(n, -1)
    catalog_index[det] = idx[prj]
    residuals = np.full((n, 2), np.nan)
    residuals[det] = rc[det] - proj[prj]
    rms = float(np.sqrt(np.mean(np.sum(residuals[det] ** 2, axis=1)))) if det.size else np.nan
    fa = _false_alarm(det.size, n, idx.size, tol, float(h * w), n_given)
    ok = det.size >= min_matches and fa <= false_alarm
    msg = (f"{det.size} of {n} stars identified, residual RMS {rms:.3f} px"
           if ok else f"not identified: {det.size} matches (min {min_matches}), chance "
           f"probability {fa:.2g} (max {false_alarm:.2g})")
    return StarIdentification(
        ok, msg, catalog_index, pointing, residuals, int(det.size), rms,
        rms * ARCSEC_PER_RAD / pointing.focal_px, fa, method, n_hyp,
        details={"n_catalog_in_frame": int(idx.size)},
    )


def _image_triangles(n: int) -> np.ndarray:
    """Index triples ``i < j < k < n``, ordered so that triangles of brighter stars come first."""
    out = [(i, j, k) for k in range(2, n) for j in range(1, k) for i in range(j)]
    return np.array(out, dtype=np.intp).reshape(-1, 3)


def _lost_in_space(rc, cat, tree, index: StarPatternIndex, shape, pp, f0, tol, fov_tol,
                   refine_focal, n_pattern, n_verify, min_matches, false_alarm,
                   max_iterations) -> StarIdentification:
    """Method (b): triangle hypotheses from the index, verified, then refined by (a)."""
    n = rc.shape[0]
    h, w = shape
    rays0 = _camera_rays(rc, f0, pp)
    top = min(n, n_pattern)
    ver = min(n, n_verify)
    tris = _image_triangles(top)
    v = rays0[tris]
    opp = np.stack([_angle(v[:, 1], v[:, 2]), _angle(v[:, 0], v[:, 2]),
                    _angle(v[:, 0], v[:, 1])], axis=1)
    order = np.argsort(opp, axis=1, kind="stable")
    tris = np.take_along_axis(tris, order, axis=1)
    sides = np.take_along_axis(opp, order, axis=1)
    # unambiguous vertex order and a size the index covers
    gap = np.minimum(sides[:, 1] - sides[:, 0], sides[:, 2] - sides[:, 1]) / sides[:, 2]
    usable = (gap > 2.0 * index.bin_width) & (sides[:, 2] <= index.max_side_rad * (1 + fov_tol)) \
        & (sides[:, 0] > 10.0 / f0)
    tris, sides = tris[usable], sides[usable]
    v = rays0[tris]
    hand = np.sign(np.einsum("ti,ti->t", v[:, 0], np.cross(v[:, 1], v[:, 2])))
    n_hyp = 0
    verify_tol = 2.0 * tol
    frame_area = float(h * w)
    for t in range(tris.shape[0]):
        r1, r2 = sides[t, 0] / sides[t, 2], sides[t, 1] / sides[t, 2]
        cand = index.query(r1, r2)
        if cand.size == 0:
            continue
        cand = cand[index.handedness[cand] == hand[t]]
        scale = sides[t, 2] / index.long_side_rad[cand]  # ~ f_true / f0
        cand = cand[np.abs(scale - 1.0) <= fov_tol]
        if cand.size == 0:
            continue
        scale = sides[t, 2] / index.long_side_rad[cand].astype(np.float64)
        n_hyp += cand.size
        f_h = f0 * scale
        # hypotheses: rotation from the three correspondences, rays with each focal length
        cam = _camera_rays(rc[tris[t]][None, :, :], f_h[:, None], pp)  # (H, 3, 3)
        sky = index.vectors[index.triangles[cand]]  # (H, 3, 3)
        rot = _kabsch(cam, sky)
        # verify: the brightest detections must land on catalogue stars
        cam_v = _camera_rays(rc[None, :ver, :], f_h[:, None], pp)  # (H, V, 3)
        sky_v = np.einsum("hij,hvj->hvi", rot, cam_v)
        tol_rad = verify_tol / f_h
        dist, _ = tree.query(sky_v.reshape(-1, 3), distance_upper_bound=float(tol_rad.max()))
        hits = (dist.reshape(cand.size, ver) <= tol_rad[:, None]).sum(axis=1)
        best = int(np.argmax(hits))
        if hits[best] < min(min_matches, ver):
            continue
        pointing = CameraPointing(Rotation.from_matrix(rot[best]), float(f_h[best]), pp)
        idx_in, _ = _in_frame(pointing, cat, tree, shape, 0.0)
        if _false_alarm(int(hits[best]), ver, idx_in.size, verify_tol, frame_area, 3) \
                > false_alarm:
            continue
        result = _refine(rc, cat, tree, pointing, shape, tol, 0.0, refine_focal, min_matches,
                         false_alarm, max_iterations, "lost_in_space", n_hyp, n_given=3)
        if result.success:
            return result
    return _failed(f"no verified attitude after {n_hyp} hypotheses from {tris.shape[0]} "
                   "triangles", n, "lost_in_space", n_hyp)
