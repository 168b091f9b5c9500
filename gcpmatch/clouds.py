"""Clouds and water: which match windows cannot give a GCP.

* A mask raster in scene geometry (nonzero = cloud or invalid) is used when given.
* Otherwise a detector flags windows that are much brighter than the reference predicts:
  per CCD, the scene window means are regressed robustly on the reference window means
  (``m_s ~ a m_r + b``, IRLS), and windows whose residual exceeds ``4 * 1.4826 MAD`` on the bright
  side are clouds. Clouds are bright, opaque and absent from the reference.
* Water (and any featureless ground) is recognized in the reference: windows whose reference
  standard deviation is below ``texture_fraction`` of the median over the CCD have no texture.
"""

from __future__ import annotations

import numpy as np

from sensor_models.files.memory import line_bands

__all__ = ["bright_outliers", "cloud_pixels", "detect_clouds", "low_texture"]

#: fewest land pixels (scene and reference correlating) the detector needs to fit its relation
MIN_LAND_PX = 100
#: block size of the images on which the detector finds land (1: full resolution)
DECIMATION = 2
#: land pixels (at most, about) that fit the scene-versus-reference relation with decimation
LAND_SAMPLES = 10_000


def _local_ncc(a: np.ndarray, b: np.ndarray, size: int) -> np.ndarray:
    """Normalized cross-correlation of ``a`` and ``b`` in a sliding ``size`` x ``size`` box.

    ``cov / sqrt(va vb + 1e-12)`` with ``cov = box(a b) - box(a) box(b)`` and
    ``va = max(box(a a) - box(a)^2, 0)`` (likewise ``vb``), each step written into one of five
    arrays of the images' size (fresh arrays cost page faults: on a 44 M pixel CCD, decimated
    twice, the eighteen a step used to take were half of the detector's time).
    """
    import cv2

    def box(x, out):
        return cv2.boxFilter(x, -1, (size, size), dst=out, normalize=True, borderType=cv2.BORDER_REFLECT)

    ma, mb = box(a, None), box(b, None)
    scratch, cov, var = np.empty_like(ma), np.empty_like(ma), np.empty_like(ma)
    box(np.multiply(a, b, out=scratch), cov)
    cov -= np.multiply(ma, mb, out=scratch)
    box(np.multiply(a, a, out=scratch), var)  # va
    var -= np.multiply(ma, ma, out=scratch)
    np.maximum(var, 0.0, out=var)
    box(np.multiply(b, b, out=scratch), ma)  # vb, in the place of box(a)
    ma -= np.multiply(mb, mb, out=scratch)
    np.maximum(ma, 0.0, out=ma)
    var *= ma
    var += 1e-12
    np.sqrt(var, out=var)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.divide(cov, var, out=cov)


def cloud_pixels(scene: np.ndarray, reference: np.ndarray, *, k: float = 5.0, ncc_land: float = 0.5,
                 box_px: int = 15, min_size_px: int = 5) -> np.ndarray:
    """Pixels much brighter than the reference predicts (clouds), as a boolean mask.

    The mask of :func:`detect_clouds` (which also says whether the detector could estimate).

    1. Land is where scene and reference correlate locally (normalized cross-correlation in a
       ``box_px`` box above ``ncc_land``); clouds and water do not.
    2. On land pixels the scene is regressed on the reference (``s ~ a r + b``, IRLS with Huber
       weights, pixels more than 2.5 sigma on the bright side trimmed: haze and cloud edges
       correlate but are brighter), started from the darker half of the pixels, so the
       relation holds even when clouds cover most of a CCD.
    3. Pixels whose residual exceeds ``k`` robust standard deviations on the bright side, after
       a morphological opening of ``min_size_px`` (clouds are extended, noise is not), are
       flagged. NaN reference pixels are never flagged.

    Parameters
    ----------
    scene : ndarray, shape (n_rows, n_cols)
        Scene pixels of one CCD (0 or NaN = no data).
    reference : ndarray, shape (n_rows, n_cols)
        The reference resampled into the same scene geometry (NaN = no data).
    k : float
        Threshold on the bright-side residual, robust standard deviations.
    ncc_land : float
        Local normalized cross-correlation above which a pixel counts as land.
    box_px : int
        Side of the box of the local cross-correlation, pixels.
    min_size_px : int
        Diameter of the elliptical opening that removes specks, pixels.

    Returns
    -------
    ndarray of bool, shape (n_rows, n_cols)
        True on cloud pixels (none where the detector cannot estimate).
    """
    return detect_clouds(scene, reference, k=k, ncc_land=ncc_land, box_px=box_px, min_size_px=min_size_px)[0]


def detect_clouds(scene: np.ndarray, reference: np.ndarray, *, k: float = 5.0, ncc_land: float = 0.5,
                  box_px: int = 15, min_size_px: int = 5, decimation: int = DECIMATION):
    """Cloud mask of :func:`cloud_pixels` and the cloud fraction, or None where it cannot tell.

    The detector needs :data:`MIN_LAND_PX` pixels where scene and reference correlate (land)
    to fit its scene-versus-reference relation. Without them (a scene all cloud, no reference
    under it, a reference of another place) it cannot estimate the cloud cover: the fraction
    is then None ("unknown"), never 0.

    With ``decimation`` > 1 the land mask (the local cross-correlation, five box filters) is
    computed on images averaged over ``decimation`` x ``decimation`` blocks, with a box of the
    same ground size (``box_px // decimation``, odd, at least 7 blocks); the relation is still
    fitted on full-resolution pixels (those
    at the centres of land blocks), the bright test is made on every pixel, and the opening runs
    only on the bands of lines that hold bright pixels (:func:`_open_where_bright`: identical to
    opening the whole image). On a cloud-free 2000 x 512 CCD this is about 4x faster
    (``bench/bench_stages.py --stages clouds``); cloud fractions agree with ``decimation=1``
    (the original full-resolution detector) within 0.005 (``tests/test_speed_paths.py``).
    Blocks of 4 were tried and rejected: their coarser land mask shifted the fitted relation
    and the fraction by up to 0.05.

    Parameters
    ----------
    scene, reference : ndarray, shape (n_rows, n_cols)
        As :func:`cloud_pixels`.
    k, ncc_land, box_px, min_size_px
        As :func:`cloud_pixels`.
    decimation : int
        Block size of the land mask's images (1: full resolution, the original detector; images
        smaller than three decimated boxes on a side use full resolution).

    Returns
    -------
    mask : ndarray of bool, shape (n_rows, n_cols)
        True on cloud pixels.
    fraction : float or None
        Cloud pixels over the pixels with scene and reference data, in [0, 1]; None when the
        detector cannot estimate.
    """
    f = int(decimation)
    box_d = max(7, (box_px // max(f, 1)) | 1)  # the same ground footprint; 7 x 7 blocks at least
    if f > 1 and min(scene.shape) >= 3 * box_d * f:
        return _detect_decimated(scene, reference, f, k=k, ncc_land=ncc_land, box_d=box_d, min_size_px=min_size_px)
    return _detect_full(scene, reference, k=k, ncc_land=ncc_land, box_px=box_px, min_size_px=min_size_px)


def _detect_full(scene, reference, *, k, ncc_land, box_px, min_size_px):
    """The original detector: land from the full-resolution cross-correlation."""
    ok = np.isfinite(scene) & np.isfinite(reference) & (scene > 0)
    out = np.zeros(scene.shape, bool)
    s32 = np.where(ok, scene, 0.0).astype(np.float32)
    r32 = np.where(ok, reference, 0.0).astype(np.float32)
    land = np.flatnonzero(ok & (_local_ncc(s32, r32, box_px) > ncc_land))
    if land.size < MIN_LAND_PX:
        return out, None
    # a regular subsample of at most ~50 000 land pixels is plenty for two coefficients
    land = land[:: max(1, land.size // 50_000)]
    coef, s = _fit_land(r32.ravel()[land].astype(np.float64), s32.ravel()[land].astype(np.float64))
    bright = ok & (s32 - (np.float32(coef[0]) * r32 + np.float32(coef[1])) > np.float32(k * s))
    mask = _open(bright, min_size_px)
    return mask, float(mask[ok].mean())


def _detect_decimated(scene, reference, f: int, *, k, ncc_land, box_d, min_size_px):
    """The detector with land found on ``f`` x ``f`` block means (see :func:`detect_clouds`).

    Full-resolution work is kept to a few passes without copies of the images: the data mask,
    the bright test and the opening of the line bands that hold bright pixels.
    """
    scene = np.asarray(scene, dtype=np.float32)
    reference = np.asarray(reference, dtype=np.float32)
    ok = np.empty(scene.shape, bool)
    for rows in line_bands(*scene.shape, BAND_PX):  # small temporaries, the same values
        np.isfinite(reference[rows], out=ok[rows])
        ok[rows] &= scene[rows] > 0
        ok[rows] &= scene[rows] < np.inf
    land, count, n_land = _land_decimated(scene, reference, ok, f, ncc_land, box_d)
    if n_land < MIN_LAND_PX or count < 10:
        return np.zeros(scene.shape, bool), None
    coef, s = _fit_land(reference.ravel()[land].astype(np.float64), scene.ravel()[land].astype(np.float64))
    gain, offset = np.float32(coef[0]), np.float32(coef[1] + k * s)
    bright = np.empty(scene.shape, bool)
    for rows in line_bands(*scene.shape, BAND_PX):
        threshold = reference[rows] * gain
        threshold += offset
        np.greater(scene[rows], threshold, out=bright[rows])  # False on NaN
        bright[rows] &= ok[rows]
    mask = _open_where_bright(bright, min_size_px)
    n_ok = np.count_nonzero(ok)
    return mask, (float(np.count_nonzero(mask)) / n_ok if n_ok else 0.0)


def _fit_land(x, y):
    """Robust line ``y ~ a x + b`` of land pixels and the robust residual spread ``s``."""
    w = _darker_half_start(x, y)
    for it in range(9):
        coef = _line_fit(x, y, w)
        res = y - (coef[0] * x + coef[1])
        s = 1.4826 * np.median(np.abs(res[w > 0])) + 1e-9
        w = np.where(np.abs(res) <= 1.345 * s, 1.0, 1.345 * s / np.abs(res))
        # haze and cloud edges still correlate with the ground but are brighter: trim the
        # bright side (one-sided contamination) so that they cannot pull the fit
        w[res > 2.5 * s] = 0.0
    return coef, s


def _open(bright: np.ndarray, min_size_px: int) -> np.ndarray:
    """Morphological opening of a boolean image by an ellipse of ``min_size_px`` (bool)."""
    import cv2

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (min_size_px, min_size_px))
    return cv2.morphologyEx(bright.astype(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)


def _open_where_bright(bright: np.ndarray, min_size_px: int, band_lines: int = 128) -> np.ndarray:
    """:func:`_open` computed only on the bands of ``band_lines`` lines that hold bright pixels.

    Each band is opened with ``min_size_px`` lines of real neighbours on both sides (an opening
    reaches ``min_size_px - 1`` lines), so the result equals the opening of the whole image.
    """
    out = np.zeros(bright.shape, bool)
    n = bright.shape[0]
    rows_hit = np.flatnonzero(bright.any(axis=1))
    if not rows_hit.size:
        return out
    pad = int(min_size_px)
    for b0 in np.unique(rows_hit // band_lines) * band_lines:
        b1 = min(n, b0 + band_lines)
        lo, hi = max(0, b0 - pad), min(n, b1 + pad)
        out[b0:b1] = _open(bright[lo:hi], min_size_px)[b0 - lo : b1 - lo]
    return out


#: Pixels per band of lines of the detector's full-resolution passes (whole lines).
BAND_PX = 1 << 20


def _land_decimated(scene, reference, ok, f: int, ncc_land: float, box_px: int):
    """Land pixels from the cross-correlation (box of ``box_px`` blocks) of ``f`` x ``f`` block means.

    Only blocks whose pixels all have data count. Returns a regular subsample of at most about
    ``LAND_SAMPLES`` of the flat full-resolution indices of the centre pixels of land blocks
    (where that pixel has data: every ``max(1, count // LAND_SAMPLES)``-th in row order), their
    ``count`` and the number of full-resolution pixels the land blocks cover. Only the subsample
    becomes full-resolution indices (the whole list was eight arrays of 8 bytes a block).
    """
    import cv2

    n_rows, n_cols = (scene.shape[0] // f) * f, (scene.shape[1] // f) * f
    size = (n_cols // f, n_rows // f)
    crop = ok[:n_rows, :n_cols]
    rows = crop[0::f].copy()  # blocks whose f x f pixels all have data: lines first, then columns
    for a in range(1, f):
        rows &= crop[a::f]
    full = rows[:, 0::f].copy()
    for b in range(1, f):
        full &= rows[:, b::f]
    means = []
    partial = ~full
    for image in (scene, reference):
        m = cv2.resize(image[:n_rows, :n_cols], size, interpolation=cv2.INTER_AREA)  # a view: no copy
        np.copyto(m, np.float32(0.0), where=partial)  # no NaN into the running box sums
        means.append(m)
    land_d = full & (_local_ncc(means[0], means[1], box_px) > ncc_land)
    n_land_px = int(np.count_nonzero(land_d)) * f * f
    land_d &= crop[f // 2::f, f // 2::f]  # the block's centre pixel has data
    index = np.flatnonzero(land_d)
    count = index.size
    i, j = np.divmod(index[:: max(1, count // LAND_SAMPLES)], size[0])
    return (i * f + f // 2) * scene.shape[1] + (j * f + f // 2), count, n_land_px


def _darker_half_start(x, y, rounds: int = 3) -> np.ndarray:
    """Start weights of the land fit: the pixels below the line fitted to the darker half.

    Cloud edges and haze correlate with the ground but are brighter; when they are a large
    share of the "land" pixels (a CCD mostly under cloud) a fit to all of them is pulled up
    and the clouds are missed. The contamination is one-sided, so the darker half about the
    current line is refitted a few times, which settles on the ground's relation.
    """
    low = np.ones(x.size)
    for _ in range(rounds):
        coef = _line_fit(x, y, low)
        res = y - (coef[0] * x + coef[1])
        low = (res <= np.median(res)).astype(np.float64)
    return low


def _line_fit(x, y, w):
    """Weighted least-squares line ``y ~ a x + b`` from the 2 x 2 normal equations: ``(a, b)``.

    ``x`` is centred first, so the equations stay well conditioned (DN values of thousands);
    the sums are numpy's, not BLAS dot products (BLAS threads stall on a busy machine).
    """
    sw = w.sum()
    wx = w * x
    xm = wx.sum() / sw
    wxc = wx - w * xm
    sxx = (wxc * (x - xm)).sum()
    a = (wxc * y).sum() / sxx if sxx > 0 else 0.0
    b = (w * y).sum() / sw - a * xm
    return a, b


def bright_outliers(mean_scene: np.ndarray, mean_ref: np.ndarray, *, k: float = 4.0) -> np.ndarray:
    """Flags of windows far brighter than the linear prediction from the reference (clouds).

    The window means are regressed robustly (``m_s ~ a m_r + b``, IRLS with Huber weights).

    Parameters
    ----------
    mean_scene, mean_ref : ndarray, shape (N,)
        Mean of each scene window and of its reference window (NaN = unusable).
    k : float
        Threshold on the bright-side residual, robust (1.4826 MAD) standard deviations.

    Returns
    -------
    ndarray of bool, shape (N,)
        True for cloudy windows (always False with fewer than 10 usable windows).
    """
    ok = np.isfinite(mean_scene) & np.isfinite(mean_ref)
    out = np.zeros(mean_scene.shape, bool)
    if ok.sum() < 10:
        return out
    x, y = mean_ref[ok], mean_scene[ok]
    w = np.ones(x.size)
    for _ in range(6):
        a = np.stack([x, np.ones_like(x)], axis=-1) * np.sqrt(w)[:, None]
        coef = np.linalg.lstsq(a, y * np.sqrt(w), rcond=None)[0]
        res = y - (coef[0] * x + coef[1])
        s = 1.4826 * np.median(np.abs(res)) + 1e-9
        w = np.where(np.abs(res) <= 1.345 * s, 1.0, 1.345 * s / np.abs(res))
    out[ok] = res > k * s
    return out


def low_texture(std_ref: np.ndarray, *, texture_fraction: float = 0.2) -> np.ndarray:
    """Flags of windows whose reference has (almost) no texture (water, haze, uniform fields).

    Parameters
    ----------
    std_ref : ndarray, shape (N,)
        Standard deviation of each reference window (NaN = no reference).
    texture_fraction : float
        A window is featureless below this fraction of the median over the finite ``std_ref``.

    Returns
    -------
    ndarray of bool, shape (N,)
        True for featureless windows and for NaN ``std_ref``.
    """
    ok = np.isfinite(std_ref)
    out = ~ok
    if ok.any():
        out |= std_ref < texture_fraction * np.median(std_ref[ok])
    return out
