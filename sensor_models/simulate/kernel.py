"""The simulator's own radiometric kernel (``realistic`` profile).

Independent of the matcher's chip resampling (:func:`sensor_models.maps.raster.sample_map_image`, a
Gaussian-prefiltered bicubic): nothing here calls it. The geometry (which ground point a pixel
centre sees) still comes from :func:`sensor_models.imaging.locate.locate_block` through the TRUE model.

Signal chain of one detector sample, in order:

1. optics: the source radiance is convolved once with the optical PSF, a uniform disk of radius
   ``defocus_radius_px`` (geometric defocus) plus a Gaussian halo of width ``halo_sigma_px``
   holding ``halo_fraction`` of the energy (:func:`optics_kernel`); with astigmatism the disk is
   an ellipse of other radii along and across track (``defocus_radius_row_px``), and the
   renderer filters the radiance with the field centre's and the swath edge's PSF and blends
   them per detector (:func:`sensor_models.simulate.realistic_sim.field_weights`);
2. detector footprint: the radiance is integrated over the detector box (1 x 1 px) and the
   along-track motion during integration (``motion_smear_lines``) by ``n x n x n_smear``
   sub-pixel samples (:func:`footprint_offsets`), mapped into the source raster through the
   local Jacobian of the located pixel centres, each detector shifted by its line-of-sight
   irregularity (:mod:`sensor_models.simulate.true_lens`);
3. detector response (:func:`detector_response`): band gain and gamma, quadratic
   non-linearity, per-detector gain (PRNU) and offset (striping), per-CCD gain steps, read and
   shot noise, quantization.

The system MTF of steps 1-2 (:func:`system_mtf`) is that of the disk (``2 J1(x) / x``), the halo, the
box ``sinc`` and the smear ``sinc``, plus the bilinear interpolation of the source raster.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["detector_response", "footprint_offsets", "integrate_footprint", "optics_kernel", "system_mtf"]


def optics_kernel(defocus_radius_px: float, halo_fraction: float, halo_sigma_px: float, *,
                  source_px_per_px: float, defocus_radius_row_px: float | None = None) -> np.ndarray:
    """The optical PSF sampled on the source raster (sums to 1).

    Parameters
    ----------
    defocus_radius_px : float
        Disk radius, detector pitches (across track: along the columns).
    defocus_radius_row_px : float, optional
        Radius along track (along the rows), detector pitches: the disk becomes an ellipse
        (astigmatism: the sagittal and tangential foci differ). None: a circle.
    halo_fraction : float
        Share of the energy in the Gaussian halo, ``[0, 1)``.
    halo_sigma_px : float
        Halo standard deviation, detector pitches.
    source_px_per_px : float
        Source-raster pixels per detector pitch on the ground (scene GSD / source resolution).

    Returns
    -------
    ndarray of float32, shape (2 m + 1, 2 m + 1)
        The kernel (disk integrated over each source pixel by 8 x 8 sub-samples).
    """
    r = defocus_radius_px * source_px_per_px
    r_row = r if defocus_radius_row_px is None else defocus_radius_row_px * source_px_per_px
    sig = halo_sigma_px * source_px_per_px
    m = int(np.ceil(max(max(r, r_row) + 1.0, 4.0 * sig if halo_fraction > 0 else 0.0, 1.0)))
    sub = (np.arange(8) + 0.5) / 8.0 - 0.5
    g = np.arange(-m, m + 1, dtype=np.float64)
    yy = (g[:, None, None, None] + sub[None, None, :, None])
    xx = (g[None, :, None, None] + sub[None, None, None, :])
    if r > 0 and r_row > 0:
        disk = (np.hypot(yy / r_row, xx / r) <= 1.0).mean(axis=(2, 3))
    else:
        disk = np.zeros((g.size, g.size))
        disk[m, m] = 1.0
    disk /= disk.sum()
    kern = (1.0 - halo_fraction) * disk
    if halo_fraction > 0 and sig > 0:
        halo = np.exp(-0.5 * (g[:, None] ** 2 + g[None, :] ** 2) / sig**2)
        kern = kern + halo_fraction * halo / halo.sum()
    return (kern / kern.sum()).astype(np.float32)


def footprint_offsets(n: int, smear_lines: float):
    """Sub-pixel sample offsets of the detector box convolved with the along-track smear.

    Parameters
    ----------
    n : int
        Samples per pixel axis (stratified, centred in ``n`` equal cells of the box).
    smear_lines : float
        Along-track motion during integration, lines (0: none; else ``n`` samples over it).

    Returns
    -------
    d_row, d_col : ndarray of float64, shape (K,)
        Offsets from the pixel centre, px (``K = n * n`` or ``n * n * n``).
    """
    box = (np.arange(n) + 0.5) / n - 0.5
    smear = box * smear_lines if smear_lines > 0 else np.zeros(1)
    dr = (box[:, None, None] + smear[None, None, :] + 0.0 * box[None, :, None]).ravel()
    dc = (0.0 * box[:, None, None] + box[None, :, None] + 0.0 * smear[None, None, :]).ravel()
    return dr, dc


def system_mtf(freq_cyc_px, *, defocus_radius_px: float, halo_fraction: float, halo_sigma_px: float,
               supersampling: int, smear_lines: float, source_px_per_px: float, axis: str = "col",
               defocus_radius_row_px: float | None = None):
    """Modulation transfer of the kernel (optics, footprint sampling, source interpolation).

    Evaluated from the very kernels the renderer uses: the DFT of :func:`optics_kernel` along one
    axis, the mean phasor of :func:`footprint_offsets`, and the bilinear interpolation of the source
    raster (``sinc^2`` at the source pixel).

    Parameters
    ----------
    freq_cyc_px : array_like
        Spatial frequencies, cycles per detector pitch (Nyquist = 0.5).
    defocus_radius_px, halo_fraction, halo_sigma_px : float
        Optics (see :func:`optics_kernel`).
    supersampling : int
        Footprint samples per axis.
    smear_lines : float
        Along-track smear, lines.
    source_px_per_px : float
        Source-raster pixels per detector pitch.
    axis : {"col", "row"}
        Across track (``col``) or along track (``row``, with the smear).
    defocus_radius_row_px : float, optional
        Along-track disk radius (astigmatism, :func:`optics_kernel`); None: ``defocus_radius_px``.

    Returns
    -------
    ndarray
        MTF (modulus) at ``freq_cyc_px``.
    """
    f = np.atleast_1d(np.asarray(freq_cyc_px, dtype=np.float64))
    kern = optics_kernel(defocus_radius_px, halo_fraction, halo_sigma_px, source_px_per_px=source_px_per_px,
                         defocus_radius_row_px=defocus_radius_row_px)
    m = kern.shape[0] // 2
    # line spread function along ``axis``: the PSF summed over the other axis
    line = kern.sum(axis=0 if axis == "col" else 1).astype(np.float64)
    x = (np.arange(kern.shape[0]) - m) / source_px_per_px  # detector pitches
    optics = np.abs(np.exp(-2j * np.pi * f[:, None] * x[None, :]) @ line)
    dr, dc = footprint_offsets(int(supersampling), smear_lines)
    d = dr if axis == "row" else dc
    foot = np.abs(np.exp(-2j * np.pi * f[:, None] * d[None, :]).mean(axis=1))
    interp = np.sinc(f / source_px_per_px) ** 2
    return optics * foot * interp


#: pixels of one window of the filtered source radiance that :func:`integrate_footprint` reads at a time
#: (a block's detectors are split into column tiles until each tile's window is within it)
MAX_WINDOW_PIXELS = 1 << 24
#: OpenCV's ``remap`` takes sources and maps of less than ``SHRT_MAX`` (32 767) pixels a side
_REMAP_MAX_SIDE = 32_000
#: NaN outside the source in every channel (a scalar ``np.nan`` border fills only the first)
_NAN_BORDER = (np.nan,) * 4


def integrate_footprint(radiance, u, v, d_row, d_col, *, irregular_row=None, irregular_col=None,
                        max_window_px: int = MAX_WINDOW_PIXELS):
    """Mean of the (optics-filtered) source radiance over every pixel's footprint.

    Parameters
    ----------
    radiance : ndarray of float32, shape (H, W) or (H, W, C), or FilteredWindows
        Source radiance already convolved with :func:`optics_kernel` (``C`` channels: e.g. the
        same radiance through the PSFs of two field positions, integrated in one pass); or a
        :class:`sensor_models.simulate.source_windows.FilteredWindows`, filtered window by window:
        the detectors are then split into column tiles whose windows hold at most
        ``max_window_px`` source pixels and less than 32 000 a side (OpenCV's ``remap`` limit).
    u, v : ndarray of float32, shape (L, N)
        Source-raster column and row (0 at the first pixel's centre) of the pixel centres of
        ``L`` lines of ``N`` detectors (``L >= 2``, ``N >= 2``).
    d_row, d_col : ndarray, shape (K,)
        Sub-pixel offsets (:func:`footprint_offsets`), px.
    irregular_row, irregular_col : ndarray, shape (N,), optional
        Per-detector line-of-sight offsets, px.
    max_window_px : int
        Largest window of a column tile (windowed ``radiance`` only), source pixels.

    Returns
    -------
    ndarray of float32, shape (L, N) or (L, N, C)
        NaN where a sample leaves the source raster.

    Notes
    -----
    Sample ``k`` of detector ``(l, n)`` lies at ``u + du/dr (d_row_k + ir_n) + du/dc (d_col_k + ic_n)``
    (likewise ``v``), the Jacobian from :func:`numpy.gradient` of the whole block. A tile's window
    is the box of ``u -+ (|du/dr| R_r + |du/dc| R_c)`` over its pixels (``R_r = max |d_row| +
    max |ir|``, ``R_c`` likewise), grown by 2 pixels, so every sample and its bilinear
    neighbours lie inside it or outside the grid; the samples are shifted by the window's integer
    origin after they are computed, which is exact in float32, so a window gives the whole grid's
    interpolation.
    """
    u = np.asarray(u, dtype=np.float32)
    v = np.asarray(v, dtype=np.float32)
    # local Jacobian d(u, v) / d(row, col) of the located grid (pixel units)
    du_dr, du_dc = np.gradient(u)
    dv_dr, dv_dc = np.gradient(v)
    n_det = u.shape[1]
    ir = np.zeros(n_det, np.float32) if irregular_row is None else np.asarray(irregular_row, np.float32)
    ic = np.zeros(n_det, np.float32) if irregular_col is None else np.asarray(irregular_col, np.float32)
    jac = (du_dr, du_dc, dv_dr, dv_dc)
    if isinstance(radiance, np.ndarray):
        return _integrate(radiance, (0, 0), u, v, jac, d_row, d_col, ir, ic)
    channels = () if radiance.channels == 1 else (radiance.channels,)
    out = np.full(u.shape + channels, np.nan, dtype=np.float32)
    reach_r = float(np.max(np.abs(d_row))) + float(np.max(np.abs(ir)))
    reach_c = float(np.max(np.abs(d_col))) + float(np.max(np.abs(ic)))
    reach_u = np.abs(du_dr) * reach_r + np.abs(du_dc) * reach_c
    reach_v = np.abs(dv_dr) * reach_r + np.abs(dv_dc) * reach_c
    for cols, box in _column_tiles(u, v, reach_u, reach_v, radiance.shape, max_window_px, 0, n_det):
        if box is None:  # the tile's footprint misses the grid: NaN
            continue
        r0, r1, c0, c1 = box
        part = (slice(None), cols)
        out[part] = _integrate(radiance.window(r0, r1, c0, c1), (r0, c0), u[part], v[part],
                               tuple(j[part] for j in jac), d_row, d_col, ir[cols], ic[cols])
    return out


def _window_box(u, v, reach_u, reach_v, shape):
    """``(row0, row1, col0, col1)`` of the source pixels the samples around ``(u, v)`` need; None: none."""
    with np.errstate(invalid="ignore"):
        lo_u, hi_u = np.nanmin(u - reach_u), np.nanmax(u + reach_u)
        lo_v, hi_v = np.nanmin(v - reach_v), np.nanmax(v + reach_v)
    if not np.isfinite([lo_u, hi_u, lo_v, hi_v]).all():
        return None
    c0, c1 = max(0, int(np.floor(lo_u)) - 2), min(shape[1], int(np.floor(hi_u)) + 3)
    r0, r1 = max(0, int(np.floor(lo_v)) - 2), min(shape[0], int(np.floor(hi_v)) + 3)
    return (r0, r1, c0, c1) if r0 < r1 and c0 < c1 else None


def _column_tiles(u, v, reach_u, reach_v, shape, max_px: int, a: int, b: int):
    """``(slice of detectors, window box or None)`` tiles covering detectors ``a:b``, halved until each fits."""
    cols = slice(a, b)
    box = _window_box(u[:, cols], v[:, cols], reach_u[:, cols], reach_v[:, cols], shape)
    if box is not None and b - a > 1:
        h, w = box[1] - box[0], box[3] - box[2]
        if h * w > max_px or max(h, w) > _REMAP_MAX_SIDE:
            mid = (a + b) // 2
            yield from _column_tiles(u, v, reach_u, reach_v, shape, max_px, a, mid)
            yield from _column_tiles(u, v, reach_u, reach_v, shape, max_px, mid, b)
            return
    yield cols, box


def _integrate(radiance, origin, u, v, jac, d_row, d_col, ir, ic):
    """The footprint mean of ``radiance`` (a window whose first pixel is ``origin`` = (row, col) of the grid)."""
    du_dr, du_dc, dv_dr, dv_dc = jac
    row0, col0 = np.float32(origin[0]), np.float32(origin[1])
    acc = np.zeros(u.shape + radiance.shape[2:], np.float32)
    for a, b in zip(d_row, d_col):
        rr = np.float32(a) + ir[None, :]
        cc = np.float32(b) + ic[None, :]
        uu = u + du_dr * rr + du_dc * cc
        vv = v + dv_dr * rr + dv_dc * cc
        if origin != (0, 0):  # exact: an integer shift of a float32 inside the window
            uu -= col0
            vv -= row0
        acc += cv2.remap(radiance, uu, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=_NAN_BORDER)
    return acc / np.float32(len(d_row))


def detector_response(radiance, *, gain: float, gamma: float, offset_dn: float, nonlinearity: float,
                      pixel_gain, pixel_offset_dn, snr: float, bits: int, rng: np.random.Generator) -> np.ndarray:
    """Digital numbers from at-aperture radiance (0..1 of the source's bright land).

    ``L = gain 0.8 s^gamma`` (relative to full scale), ``r = L (1 - a (1 - L))`` (quadratic
    non-linearity ``a``), ``DN = offset + full r g_k + o_k`` with the per-detector (and per-CCD)
    gain ``g_k`` and offset ``o_k``; Gaussian noise ``sigma = (S_ref / snr) sqrt(0.5 + 0.5 DN /
    S_ref)``, ``S_ref = 0.35 full``; rounded and clipped to ``bits`` bits; NaN gives 0.

    Parameters
    ----------
    radiance : ndarray, shape (L, N)
        Integrated radiance, 0..1.
    gain, gamma, offset_dn : float
        Band response.
    nonlinearity : float
        ``a`` above (largest relative deviation ``a / 4`` at half scale).
    pixel_gain, pixel_offset_dn : ndarray, shape (N,)
        Per-detector gain (PRNU times the CCD's gain) and offset (striping), DN.
    snr : float
        Signal-to-noise ratio at ``0.35`` of full scale.
    bits : int
        Quantization.
    rng : numpy.random.Generator
        Noise.

    Returns
    -------
    ndarray of uint16, shape (L, N)
    """
    full = float(2**bits - 1)
    s = np.clip(np.asarray(radiance, dtype=np.float32), 0.0, None)
    level = np.float32(gain * 0.8) * np.power(s, np.float32(gamma))
    level = level * (1.0 - np.float32(nonlinearity) * (1.0 - level))
    dn = np.float32(offset_dn) + np.float32(full) * level * pixel_gain[None, :] + pixel_offset_dn[None, :]
    s_ref = 0.35 * full
    sigma = (s_ref / snr) * np.sqrt(0.5 + 0.5 * np.clip(dn, 0.0, None) / s_ref)
    dn = dn + sigma * rng.standard_normal(dn.shape, dtype=np.float32)
    dn = np.where(np.isfinite(dn), dn, 0.0)
    return np.clip(np.rint(dn), 0, full).astype(np.uint16)
