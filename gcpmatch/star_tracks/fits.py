"""FITS and SExtractor files, and the FITS pixel convention.

FITS and SExtractor number pixels from 1 with the first pixel's centre at ``1.0`` along ``x``
(columns) and ``y`` (rows); gcpcal puts that centre at ``(row, col) = (0.5, 0.5)``:
``col = x - 0.5``, ``row = y - 0.5`` (:func:`fits_to_rowcol`, :func:`rowcol_to_fits`). FITS
files are decoded by :mod:`astropy.io.fits`; its exceptions become :class:`InputError` here,
with one line naming the file and what is wrong with it.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from astropy.io import fits as _fits
from astropy.utils.exceptions import AstropyWarning

from sensor_models.errors import InputError

__all__ = ["fits_to_rowcol", "read_fits_image", "read_sextractor_catalog", "rowcol_to_fits"]


def fits_to_rowcol(x_fits, y_fits) -> np.ndarray:
    """FITS/SExtractor 1-based pixel coordinates -> project ``(row, col)``.

    FITS puts the centre of the first pixel at ``x = y = 1.0``; gcpcal at ``0.5``. So
    ``col = x - 0.5`` and ``row = y - 0.5`` (FITS ``y`` is the array's first axis as stored).

    Parameters
    ----------
    x_fits, y_fits : array_like, broadcastable shapes (...)
        FITS / SExtractor ``X_IMAGE``-like (column) and ``Y_IMAGE``-like (row) positions,
        pixels, 1-based centres.

    Returns
    -------
    ndarray, shape ``(..., 2)``
        ``(row, col)``.
    """
    x = np.asarray(x_fits, dtype=np.float64)
    y = np.asarray(y_fits, dtype=np.float64)
    return np.stack([y - 0.5, x - 0.5], axis=-1)


def rowcol_to_fits(rowcol) -> tuple[np.ndarray, np.ndarray]:
    """Project ``(row, col)`` -> FITS ``(x, y)``: ``x = col + 0.5``, ``y = row + 0.5``.

    Parameters
    ----------
    rowcol : array_like, shape (..., 2)
        ``(row, col)`` in pixels, first pixel's centre at ``(0.5, 0.5)``.

    Returns
    -------
    x, y : ndarray, shape (...)
        FITS pixel coordinates, first pixel's centre at ``(1.0, 1.0)``.
    """
    rc = np.asarray(rowcol, dtype=np.float64)
    return rc[..., 1] + 0.5, rc[..., 0] + 0.5


def read_fits_image(path) -> tuple[np.ndarray, dict]:
    """Read the first 2-D image of a FITS file.

    Parameters
    ----------
    path : path-like
        A FITS file with a 2-D image (``NAXIS = 2``) in its primary HDU or, when the primary
        HDU holds no data, in an IMAGE (or tile-compressed image) extension.

    Returns
    -------
    image : ndarray of float64, shape (NAXIS2, NAXIS1)
        ``BZERO + BSCALE * stored``, in the file's units (ADU); integer ``BLANK`` values become
        NaN. Row ``i`` is FITS ``y = i + 1``: the pixel centre at FITS ``(x, y)`` is at
        ``(row, col) = (y - 0.5, x - 0.5)`` (:func:`fits_to_rowcol`).
    header : dict
        Keyword -> value of that HDU's header (``COMMENT``/``HISTORY`` dropped; later
        duplicates win). ``BITPIX`` is the stored type's, before scaling.

    Raises
    ------
    InputError
        Missing file, not FITS, no 2-D image HDU or a truncated file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("FITS file not found", path=str(path))
    try:
        with warnings.catch_warnings():
            # non-standard cards (ESO HIERARCH-like keys, odd values) do not concern the pixels
            warnings.simplefilter("ignore", AstropyWarning)
            with _fits.open(path, memmap=False, do_not_scale_image_data=True, uint=False,
                            lazy_load_hdus=False) as hdus:
                index = _image_hdu_index(hdus, path)
                header = _header_dict(hdus[index].header)
                stored = _checked_data(hdus, index, path)
    except InputError:
        raise
    except (OSError, ValueError, TypeError, IndexError) as exc:
        raise InputError(f"not a readable FITS file ({_first_line(exc)})", path=str(path)) \
            from exc
    image = stored.astype(np.float64)
    if header["BITPIX"] > 0 and "BLANK" in header:
        image[stored == header["BLANK"]] = np.nan
    image = image * float(header.get("BSCALE", 1.0)) + float(header.get("BZERO", 0.0))
    return image, header


def _first_line(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _image_hdu_index(hdus, path: Path) -> int:
    """Index of the first HDU holding a 2-D image; :class:`InputError` listing them otherwise."""
    found = []
    for k, hdu in enumerate(hdus):
        is_image = isinstance(hdu, (_fits.PrimaryHDU, _fits.ImageHDU, _fits.CompImageHDU))
        naxis = hdu.header.get("NAXIS", 0)
        if is_image and naxis == 2:
            return k
        found.append(f"{hdu.name or k} {type(hdu).__name__} NAXIS = {naxis}")
    raise InputError(f"no 2-D image HDU (found: {'; '.join(found)})", path=str(path),
                     field="NAXIS")


def _header_dict(header) -> dict:
    return {key: value for key, value in header.items()
            if key not in ("COMMENT", "HISTORY", "")}


def _checked_data(hdus, index: int, path: Path) -> np.ndarray:
    """The stored (unscaled) pixels of HDU ``index``, after checking the file holds them all."""
    hdu = hdus[index]
    if not isinstance(hdu, _fits.CompImageHDU):
        need = abs(int(hdu.header["BITPIX"])) // 8 * int(hdu.header["NAXIS1"]) \
            * int(hdu.header["NAXIS2"])
        have = path.stat().st_size - hdus.fileinfo(index)["datLoc"]
        if have < need:
            raise InputError(f"truncated FITS data ({have} of {need} bytes)", path=str(path))
    data = hdu.data
    if data is None or data.ndim != 2:
        raise InputError("no 2-D image data", path=str(path), field="NAXIS")
    return np.asarray(data)


def read_sextractor_catalog(path) -> dict[str, np.ndarray]:
    """Read a SExtractor ASCII_HEAD catalogue.

    The header lines ``#   N NAME  description [unit]`` give the 1-based column ``N`` where
    each parameter starts; a vector parameter (``FLUX_RADIUS`` with several fractions) spans the
    columns up to the next name.

    Parameters
    ----------
    path : path-like
        A catalogue written with ``CATALOG_TYPE ASCII_HEAD``.

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
