"""Reference images on map grids and the radiometry of a simulated scene.

* :class:`MapImage`: a DOM (or any single-band map raster) in memory or on disk, read by
  windows; nodata becomes NaN.
* :func:`psf_sigma_dom_px`: the Gaussian that turns the DOM into what one scene pixel
  integrates (detector box across track, box plus line-time smear along track, optics).
* :func:`smooth_field`: seeded band-limited random fields (seasonal change, clouds) on a coarse
  grid.
* :func:`to_dn`: band response, seasonal change, PRNU, signal-dependent noise, quantization.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.simulate.render import MapGrid

__all__ = ["MapImage", "psf_sigma_dom_px", "sample_map_image", "smooth_field", "to_dn"]


@dataclass
class MapImage:
    """A single-band raster on a map grid, read by windows (float32, NaN for nodata).

    Build with :meth:`from_array` or :meth:`open`; ``grid`` describes it.
    """

    grid: MapGrid
    _array: np.ndarray | None = None
    path: str | None = None
    nodata: float | None = None

    @classmethod
    def from_array(cls, values, transform, crs) -> "MapImage":
        values = np.asarray(values)
        return cls(MapGrid(Affine(*tuple(transform)[:6]), pyproj.CRS.from_user_input(crs), values.shape), values)

    @classmethod
    def open(cls, path, *, what: str = "DOM") -> "MapImage":
        import rasterio
        from rasterio.errors import RasterioError

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise InputError(f"{what} file not found", path=path)
        try:
            with rasterio.open(path) as ds:
                if ds.crs is None:
                    raise InputError(f"the {what} declares no coordinate reference system", path=path)
                grid = MapGrid(ds.transform, pyproj.CRS.from_wkt(ds.crs.to_wkt()), (ds.height, ds.width))
                nodata = ds.nodata
        except RasterioError as exc:
            raise InputError(f"cannot be read as a {what} raster ({exc})", path=path) from None
        return cls(grid, None, path, nodata)

    def read_decimated(self, row0: int, row1: int, col0: int, col1: int, out_shape) -> np.ndarray:
        """Pixels ``[row0:row1, col0:col1]`` (inside the raster) averaged down to ``out_shape``."""
        import cv2

        n_rows, n_cols = self.grid.shape
        if not (0 <= row0 < row1 <= n_rows and 0 <= col0 < col1 <= n_cols):
            raise InputError(f"window rows {row0}..{row1}, cols {col0}..{col1} outside the raster",
                             path=self.path or "image")
        if self._array is None:
            import rasterio
            from rasterio.enums import Resampling
            from rasterio.windows import Window

            with rasterio.open(self.path) as ds:
                block = ds.read(1, window=Window(col0, row0, col1 - col0, row1 - row0), out_shape=tuple(out_shape),
                                resampling=Resampling.average, masked=True)
                block = np.ma.filled(block.astype(np.float32), np.nan)
        else:
            full = self._array[row0:row1, col0:col1].astype(np.float32)
            block = cv2.resize(full, (int(out_shape[1]), int(out_shape[0])), interpolation=cv2.INTER_AREA)
        if self.nodata is not None and not np.isnan(self.nodata):
            block[block == self.nodata] = np.nan
        return block

    def read(self, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """Pixels ``[row0:row1, col0:col1]`` (clipped to the raster) as float32; NaN = no data."""
        n_rows, n_cols = self.grid.shape
        r0, r1 = max(0, row0), min(n_rows, row1)
        c0, c1 = max(0, col0), min(n_cols, col1)
        out = np.full((row1 - row0, col1 - col0), np.nan, dtype=np.float32)
        if r1 <= r0 or c1 <= c0:
            return out
        if self._array is not None:
            block = self._array[r0:r1, c0:c1].astype(np.float32)
        else:
            import rasterio
            from rasterio.windows import Window

            with rasterio.open(self.path) as ds:
                block = ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
                block = np.ma.filled(block.astype(np.float32), np.nan)
        if self.nodata is not None and not np.isnan(self.nodata):
            block[block == self.nodata] = np.nan
        out[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0] = block
        return out


def sample_map_image(image: MapImage, u, v, *, sigma_px: float = 0.0) -> np.ndarray:
    """Sample a map image at node indices ``(u, v)`` after a Gaussian blur of ``sigma_px``.

    Only the window covering the requested positions (plus the blur's reach) is read. No-data
    pixels are excluded by normalized convolution; where more than 1 % of the blur's weight
    falls on no-data, and outside the raster, the result is NaN.

    Parameters
    ----------
    image : MapImage
    u, v : ndarray, float32, same shape
        Node-index coordinates (pixel ``[j, i]`` centre at ``(i, j)``); NaN allowed.
    sigma_px : float
        Standard deviation of the blur in image pixels (0: none).

    Returns
    -------
    ndarray, float32, shape of ``u``
        Bilinear samples (OpenCV ``remap``: positions quantized to 1/32 pixel).
    """
    import cv2

    out = np.full(u.shape, np.nan, dtype=np.float32)
    ok = np.isfinite(u) & np.isfinite(v)
    if not ok.any():
        return out
    pad = int(np.ceil(4.0 * sigma_px)) + 3
    c0 = int(np.floor(u[ok].min())) - pad
    c1 = int(np.ceil(u[ok].max())) + pad + 1
    r0 = int(np.floor(v[ok].min())) - pad
    r1 = int(np.ceil(v[ok].max())) + pad + 1
    crop = image.read(r0, r1, c0, c1)
    valid = np.isfinite(crop).astype(np.float32)
    crop = np.where(valid > 0, crop, 0.0).astype(np.float32)
    if sigma_px > 0:
        crop = cv2.GaussianBlur(crop, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
        valid = cv2.GaussianBlur(valid, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        crop = np.where(valid > 0.99, crop / valid, np.nan).astype(np.float32)
    uu = np.where(ok, u - c0, -1.0).astype(np.float32)
    vv = np.where(ok, v - r0, -1.0).astype(np.float32)
    return cv2.remap(crop, uu, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)


def psf_sigma_dom_px(gsd_m: float, dom_resolution_m: float, psf_sigma_px: float) -> float:
    """Sigma (DOM pixels) of the Gaussian equivalent of one scene pixel's response.

    Variance in scene pixels: detector box ``1/12`` across track, box plus one line of motion
    ``2/12`` along track (averaged: ``1.5/12``), plus the optics ``psf_sigma_px^2``; the DOM's own
    pixel box (``1/12`` DOM px^2) is already in the data and is taken out.
    """
    ratio = gsd_m / dom_resolution_m
    var = ratio**2 * (1.5 / 12.0 + psf_sigma_px**2) - 1.0 / 12.0
    return float(np.sqrt(max(var, 0.0)))


def smooth_field(shape, scale_px: float, seed_seq) -> np.ndarray:
    """A zero-mean, unit-variance Gaussian random field with correlation length ``scale_px``.

    White noise filtered in the Fourier domain by ``exp(-(k scale)^2 / 2)`` plus a weaker
    ``1/k``-like tail for detail; float32, deterministic for the given seed sequence.
    """
    rng = np.random.default_rng(seed_seq)
    noise = rng.standard_normal(shape)
    ky = np.fft.fftfreq(shape[0])[:, None]
    kx = np.fft.rfftfreq(shape[1])[None, :]
    k = np.hypot(ky, kx) * 2.0 * np.pi
    filt = np.exp(-0.5 * (k * scale_px) ** 2) + 0.15 / (1.0 + (k * scale_px) ** 2)
    field = np.fft.irfft2(np.fft.rfft2(noise) * filt, s=shape)
    field -= field.mean()
    field /= max(field.std(), 1e-12)
    return field.astype(np.float32)


def to_dn(reflectance, *, gain: float, offset_dn: float, gamma: float, seasonal, prnu_gain, snr: float,
          bits: int, rng: np.random.Generator) -> np.ndarray:
    """Digital numbers of a band from the DOM-normalized reflectance (0..1).

    ``L = offset + gain * max_dn * 0.8 * reflectance^gamma * (1 + seasonal)`` times the
    per-detector gain (PRNU), plus Gaussian noise of standard deviation
    ``sigma = (S_ref / snr) sqrt(0.5 + 0.5 L / S_ref)`` (read noise plus shot noise, SNR = ``snr``
    at the reference signal ``S_ref = 0.35 max_dn``), rounded and clipped to ``bits`` bits.
    NaN reflectance (no reference data) gives 0.
    """
    max_dn = float(2**bits - 1)
    refl = np.clip(reflectance, 0.0, None)
    signal = offset_dn + gain * 0.8 * max_dn * np.power(refl, gamma) * (1.0 + seasonal)
    signal = signal * prnu_gain
    s_ref = 0.35 * max_dn
    sigma = (s_ref / snr) * np.sqrt(0.5 + 0.5 * np.clip(signal, 0.0, None) / s_ref)
    dn = signal + sigma * rng.standard_normal(signal.shape, dtype=np.float32)
    dn = np.where(np.isfinite(dn), dn, 0.0)
    return np.clip(np.rint(dn), 0, max_dn).astype(np.uint16)
