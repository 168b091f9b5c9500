"""Texture-poor land cover for the ``realistic`` profile's procedural source radiance.

Real scenes hold ground where phase correlation finds nothing: homogeneous fields, bare plains,
uniform forest canopy, water. On the real Sentinel-2 and Landsat-8 crops of docs/error_budget.md only 0.43-0.66
of the 32 x 32-pixel blocks at 30 m carry texture (``bench/bench_texture_stats.py``), against
0.88 for the procedural texture of :func:`sensor_models.simulate.procedural.generate_reference`.
This module gives that texture patches of such ground:

* :func:`texture_poor_mask`: smooth-edged patches from a low-frequency Gaussian random field
  (white noise on a 100 m grid smoothed by Gaussians of standard deviation ``scale_m`` and, at half
  the weight, ``scale_m / 4``, upsampled bicubically) thresholded at the quantile that makes them
  cover ``fraction`` of the land (water is already texture-poor);
* :func:`attenuate_texture`: inside the patches, the deviations of the radiance from its local
  mean are multiplied by ``attenuation``: ``L' = B + a (L - B)``, with ``B`` the Gaussian-weighted
  mean (``smooth_m``) of the radiance *inside the patch only* (normalized convolution, Knutsson &
  Westin 1993), so that a patch keeps its tone, a little texture and a sharp boundary with its
  neighbours (nothing leaks across it, nothing is feathered);
* :func:`texture_poor_cover`: both, as the simulator applies them.

The ``ideal`` profile never calls this module (its fixture stays byte-identical).

References
----------
.. [1] H. Knutsson and C.-F. Westin, "Normalized and differential convolution", Proc. IEEE CVPR
   1993, pp. 515-523.
"""

from __future__ import annotations

import cv2
import numpy as np

from sensor_models.errors import InputError

__all__ = ["attenuate_texture", "texture_poor_cover", "texture_poor_mask"]

#: cell of the coarse grid the random field is drawn on, metres (upsampled by bicubic interpolation)
_CELL_M = 100.0
#: pixels :func:`attenuate_texture` filters at a time (whole rows, at least four times the Gaussian's
#: reach, which is added above and below)
_STRIP_PIXELS = 1 << 18
#: weight of the finer octave (correlation length scale_m / 4) in the field
_FINE_WEIGHT = 0.5


def _smooth_field(shape: tuple, res_m: float, scale_m: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance Gaussian field of correlation length ``scale_m`` (plus a finer octave) on ``shape``."""
    n_r = int(np.ceil(shape[0] * res_m / _CELL_M)) + 4
    n_c = int(np.ceil(shape[1] * res_m / _CELL_M)) + 4
    field = np.zeros((n_r, n_c), dtype=np.float64)
    for weight, length_m in ((1.0, scale_m), (_FINE_WEIGHT, 0.25 * scale_m)):
        sigma = max(length_m / _CELL_M, 0.5)
        octave = cv2.GaussianBlur(rng.standard_normal((n_r, n_c)), (0, 0), sigmaX=sigma, sigmaY=sigma,
                                  borderType=cv2.BORDER_REFLECT)
        field += weight * octave / max(float(octave.std()), 1e-12)
    # the coarse grid covers the raster plus two cells on each side; crop after upsampling
    up = cv2.resize(field.astype(np.float32), None, fx=_CELL_M / res_m, fy=_CELL_M / res_m,
                    interpolation=cv2.INTER_CUBIC)
    off = int(round(2 * _CELL_M / res_m))
    return up[off:off + shape[0], off:off + shape[1]]


def texture_poor_mask(shape: tuple, res_m: float, fraction: float, *, seed, scale_m: float = 2000.0,
                      exclude: np.ndarray | None = None) -> np.ndarray:
    """Smooth-edged patches covering ``fraction`` of the pixels outside ``exclude``.

    Parameters
    ----------
    shape : (int, int)
        Raster shape (rows, cols).
    res_m : float
        Pixel size, metres (> 0).
    fraction : float
        Share of the pixels outside ``exclude`` inside a patch, in [0, 1).
    seed : int or sequence of int
        Seed of ``numpy.random.default_rng`` (same seed, same patches).
    scale_m : float
        Standard deviation of the coarser octave's Gaussian smoothing, metres (patches of about
        this size).
    exclude : ndarray of bool, shape ``shape``, optional
        Pixels never in a patch (e.g. water: already texture-poor).

    Returns
    -------
    ndarray of bool, shape ``shape``
        True inside a patch.

    Raises
    ------
    InputError
        When ``fraction`` or ``res_m`` is out of range.
    """
    if not 0.0 <= fraction < 1.0:
        raise InputError(f"the texture-poor fraction must be in [0, 1), got {fraction}", field="texture_poor_fraction")
    if not res_m > 0.0:
        raise InputError(f"the pixel size must be positive, got {res_m}", field="res_m")
    mask = np.zeros(shape, dtype=bool)
    if fraction == 0.0:
        return mask
    field = _smooth_field(shape, float(res_m), float(scale_m), np.random.default_rng(seed))
    allowed = np.ones(shape, dtype=bool) if exclude is None else ~np.asarray(exclude, dtype=bool)
    if not allowed.any():
        return mask
    threshold = np.quantile(field[allowed], 1.0 - fraction, overwrite_input=True)  # partitions its own copy
    return allowed & (field > threshold)


def attenuate_texture(radiance: np.ndarray, mask: np.ndarray, attenuation: float, *, res_m: float,
                      smooth_m: float = 300.0) -> np.ndarray:
    """Radiance whose texture inside ``mask`` is scaled by ``attenuation`` about the patch's local mean.

    ``L' = B + a (L - B)`` inside the mask, ``L`` elsewhere; ``B = G * (L m) / G * m`` with ``m``
    the mask and ``G`` a Gaussian of standard deviation ``smooth_m`` (normalized convolution [1]_:
    only pixels of the patch enter its mean).

    Parameters
    ----------
    radiance : ndarray, shape (H, W)
        Finite radiance.
    mask : ndarray of bool, shape (H, W)
        The texture-poor patches (:func:`texture_poor_mask`).
    attenuation : float
        Factor ``a`` in [0, 1] on the deviations from the local mean (1: unchanged).
    res_m : float
        Pixel size, metres.
    smooth_m : float
        Standard deviation of the local mean's Gaussian, metres.

    Returns
    -------
    ndarray of float32, shape (H, W)

    Raises
    ------
    InputError
        When ``attenuation`` is outside [0, 1] or the shapes differ.
    """
    if not 0.0 <= attenuation <= 1.0:
        raise InputError(f"the texture attenuation must be in [0, 1], got {attenuation}",
                         field="texture_poor_attenuation")
    if np.shape(mask) != np.shape(radiance):
        raise InputError(f"mask shape {np.shape(mask)} differs from the radiance's {np.shape(radiance)}", field="mask")
    src = np.asarray(radiance, dtype=np.float32)
    if attenuation == 1.0 or not mask.any():
        return src.copy()
    sigma = max(float(smooth_m) / float(res_m), 0.5)
    blur = dict(ksize=(0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    # by strips of rows, each blurred with the rows its kernel reaches (OpenCV's radius for float
    # images is round(4 sigma)): the whole raster is never held in float32 more than once
    halo = int(np.ceil(4.0 * sigma)) + 2
    n_rows = src.shape[0]
    out = np.empty(src.shape, dtype=np.float32)
    step = max(4 * halo, _STRIP_PIXELS // src.shape[1])
    for r0 in range(0, n_rows, step):
        r1 = min(n_rows, r0 + step)
        a0, a1 = max(0, r0 - halo), min(n_rows, r1 + halo)
        s, m = src[a0:a1], mask[a0:a1].astype(np.float32)
        keep = slice(r0 - a0, r1 - a0)
        num = cv2.GaussianBlur(s * m, **blur)[keep]
        den = cv2.GaussianBlur(m, **blur)[keep]
        s = s[keep]
        local = np.where(den > 1e-6, num / np.maximum(den, np.float32(1e-6)), s)
        out[r0:r1] = np.where(mask[r0:r1], local + np.float32(attenuation) * (s - local), s)
    return out


def texture_poor_cover(radiance: np.ndarray, res_m: float, fraction: float, attenuation: float, *, seed,
                       water: np.ndarray | None = None) -> tuple:
    """The procedural radiance with texture-poor patches (:func:`texture_poor_mask`, :func:`attenuate_texture`).

    Parameters
    ----------
    radiance : ndarray, shape (H, W)
        Procedural radiance (e.g. the DOM digital numbers of ``generate_reference``).
    res_m : float
        Its pixel size, metres.
    fraction : float
        Share of the land in patches, in [0, 1) (profile field ``texture_poor_fraction``).
    attenuation : float
        Factor on the texture inside them, in [0, 1] (profile field ``texture_poor_attenuation``).
    seed : int or sequence of int
        Seed of the patches.
    water : ndarray of bool, shape (H, W), optional
        Water (never a patch).

    Returns
    -------
    radiance : ndarray of float32, shape (H, W)
    mask : ndarray of bool, shape (H, W)
        The patches.
    """
    mask = texture_poor_mask(np.shape(radiance), res_m, fraction, seed=seed, exclude=water)
    return attenuate_texture(radiance, mask, attenuation, res_m=res_m), mask
