"""Quality bands of reference orthoimages (DOMs) decoded into masks of pixels not to match.

A Landsat or Sentinel-2 band used as a DOM comes with a quality raster: Landsat's bit-packed
``QA_PIXEL`` (Collection 2) or ``BQA`` (Collection 1 and pre-Collection), Sentinel-2's scene
classification ``SCL`` (Level-2A, 20 m). :func:`invalid_from_qa` turns its values into a
boolean mask, True where the DOM pixel must not be used: fill, cloud and cloud shadow. Cirrus is
a flag, not a mask: thin cirrus leaves the ground's texture visible to phase correlation, and on
a hazy date the cirrus bits cover most of a scene (two thirds of the Landsat-8 crop of
``../shared/data`` at "high" confidence, 31 %), so it is masked only when asked
(``cirrus=True``, ``--dom-mask-cirrus``). A user's own mask (any raster, nonzero = unusable)
has the layout ``mask``;
:func:`qa_layout_of` says which layout a file has, from its name and, for a ``BQA`` file, from
its values.

Layouts (bit 0 is the least significant bit):

``landsat-c2`` (Landsat 8-9 Collection 2 Level-1 ``QA_PIXEL``) [1]_
    bit 0 fill, bit 1 dilated cloud, bit 2 cirrus (high confidence), bit 3 cloud (high
    confidence), bit 4 cloud shadow (high confidence). Masked: bits 0, 1, 3, 4 (and 2 with
    cirrus).
``landsat-c1`` (Landsat 8 Collection 1 ``BQA``) [2]_
    bit 0 designated fill, bit 4 cloud, bits 7-8 cloud shadow confidence, bits 11-12 cirrus
    confidence (two-bit confidences: 0 not determined, 1 low, 2 medium, 3 high). Masked: fill,
    cloud, shadow confidence high (and cirrus confidence high with cirrus).
``landsat-pre-collection`` (Landsat 8 pre-Collection ``BQA``, 2013-2017) [3]_
    bit 0 designated fill, bits 12-13 cirrus confidence, bits 14-15 cloud confidence (no
    shadow bits). Masked: fill, cloud confidence high (3: 67-100 %) (and cirrus confidence
    high with cirrus).
``s2-scl`` (Sentinel-2 Level-2A scene classification) [4]_
    classes 0 no data, 1 saturated or defective, 3 cloud shadows, 8 cloud medium probability,
    9 cloud high probability are masked (and 10 thin cirrus with cirrus).
``mask`` (a user's own mask)
    any raster: nonzero values are unusable.

References
----------
.. [1] USGS, "Landsat 8-9 Collection 2 Level 1 Data Format Control Book", LSDS-1822,
   table "Pixel quality assessment (QA_PIXEL) bit index".
.. [2] USGS, "Landsat 8 Collection 1 Level 1 Data Format Control Book", LSDS-1656,
   table "BQA bit designations".
.. [3] USGS, "Landsat 8 Quality Assessment Band" (pre-Collection BQA, bits 14-15 cloud,
   12-13 cirrus, 10-11 snow/ice, 8-9 vegetation, 4-5 water, 0 designated fill).
.. [4] ESA, "Sentinel-2 Level-2A Product Format Specification" / Sen2Cor Software User Manual,
   scene classification values 0-11.
"""

from __future__ import annotations

import os
import re

import numpy as np

from sensor_models.errors import InputError

__all__ = ["MASK_LAYOUT", "QA_LAYOUTS", "invalid_from_qa", "qa_layout_from_name", "qa_layout_of"]

#: QA layouts of products gcpcal decodes (see the module docstring).
QA_LAYOUTS = ("landsat-c2", "landsat-c1", "landsat-pre-collection", "s2-scl")
#: The layout of a user's own mask: nonzero = unusable.
MASK_LAYOUT = "mask"

#: Scene-classification classes of Sentinel-2 L2A masked out of a DOM (10, thin cirrus, with cirrus).
S2_SCL_MASKED = (0, 1, 3, 8, 9)
S2_SCL_CIRRUS = 10

_HIGH = 3  # a two-bit confidence of 67-100 %


def _field(values: np.ndarray, first_bit: int, n_bits: int) -> np.ndarray:
    """Unsigned integer made of ``n_bits`` bits of ``values`` starting at ``first_bit``."""
    return (values >> first_bit) & ((1 << n_bits) - 1)


def invalid_from_qa(values, layout: str, *, cirrus: bool = False) -> np.ndarray:
    """Pixels a QA raster marks as fill, cloud or cloud shadow (and cirrus when asked).

    Parameters
    ----------
    values : array_like of int, any shape
        QA values (Landsat: unsigned 16-bit words; Sentinel-2 SCL: class numbers; a user's mask:
        anything, nonzero = unusable).
    layout : {"landsat-c2", "landsat-c1", "landsat-pre-collection", "s2-scl", "mask"}
        How the values are coded (module docstring).
    cirrus : bool
        Mask cirrus too (high confidence; Sentinel-2: thin cirrus).

    Returns
    -------
    ndarray of bool, shape of ``values``
        True where the DOM pixel must not be used.

    Raises
    ------
    InputError
        Unknown layout.
    """
    if layout == MASK_LAYOUT:
        v = np.asarray(values)
        return (v != 0) & ~np.isnan(v) if v.dtype.kind == "f" else v != 0
    q = np.asarray(values).astype(np.int64)
    if layout == "landsat-c2":
        return (q & (0b11011 | (0b100 if cirrus else 0))) != 0
    if layout == "landsat-c1":
        out = ((q & 1) != 0) | ((q & (1 << 4)) != 0) | (_field(q, 7, 2) == _HIGH)
        return out | (_field(q, 11, 2) == _HIGH) if cirrus else out
    if layout == "landsat-pre-collection":
        out = ((q & 1) != 0) | (_field(q, 14, 2) == _HIGH)
        return out | (_field(q, 12, 2) == _HIGH) if cirrus else out
    if layout == "s2-scl":
        return np.isin(q, S2_SCL_MASKED + ((S2_SCL_CIRRUS,) if cirrus else ()))
    raise InputError(f"unknown QA layout {layout!r}; one of {', '.join(QA_LAYOUTS)}", field="dom_qa_layout")


def qa_layout_from_name(path) -> str | None:
    """The QA layout a file's name tells, or None.

    ``*QA_PIXEL*`` is Collection 2; ``*SCL*`` Sentinel-2; ``*BQA*`` of a Collection 1 product
    identifier (``LC08_L1TP_..._01_T1_BQA.TIF``) Collection 1, of a pre-Collection scene
    identifier (``LC80440342015...LGN00_BQA.TIF``) pre-Collection; any other ``*BQA*`` name
    is left to the values (:func:`qa_layout_of`).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    str or None
        A layout of :data:`QA_LAYOUTS`, or None when the name does not tell.
    """
    name = os.path.basename(os.fspath(path)).upper()
    if "QA_PIXEL" in name:
        return "landsat-c2"
    if re.search(r"(^|_)SCL(_|\.)", name):
        return "s2-scl"
    if "BQA" in name:
        if re.match(r"L[COTEM]0\d_L1\w\w_\d{6}_\d{8}_\d{8}_01_", name):
            return "landsat-c1"
        if re.match(r"L[COTEM]\d\d{6}\d{7}[A-Z]{3}\d\d", name):
            return "landsat-pre-collection"
    return None


def qa_layout_of(path, *, layout: str | None = None) -> str:
    """The QA layout of a file: ``layout`` when given, else its name, else its values.

    A ``BQA`` file whose name does not tell is pre-Collection when any value sets one of bits
    14-15 (its cloud confidence, set on every non-fill pixel), Collection 1 otherwise (bits
    13-15 are unused there).

    Parameters
    ----------
    path : str or os.PathLike
        The QA raster.
    layout : str, optional
        The layout the user named (``--dom-qa-layout``); checked, then returned.

    Returns
    -------
    str
        A layout of :data:`QA_LAYOUTS`.

    Raises
    ------
    InputError
        Unknown ``layout``, or a name that tells nothing and is not a ``BQA`` file.
    """
    path = os.fspath(path)
    if layout is not None:
        if layout not in QA_LAYOUTS:
            raise InputError(f"unknown QA layout {layout!r}; one of {', '.join(QA_LAYOUTS)}", path=path,
                             field="dom_qa_layout")
        return layout
    named = qa_layout_from_name(path)
    if named is not None:
        return named
    if "BQA" in os.path.basename(path).upper():
        return "landsat-pre-collection" if _sets_high_bits(path) else "landsat-c1"
    raise InputError("cannot tell the QA layout from the file name (QA_PIXEL, BQA or SCL); give --dom-qa-layout "
                     f"({', '.join(QA_LAYOUTS)})", path=path, field="dom_qa_layout")


def _sets_high_bits(path: str) -> bool:
    """Whether a decimated look at a QA raster finds any value with bit 14 or 15 set."""
    import rasterio
    from rasterio.enums import Resampling

    with rasterio.open(path) as ds:
        step = max(1, max(ds.height, ds.width) // 512)
        shape = (max(1, ds.height // step), max(1, ds.width // step))
        values = ds.read(1, out_shape=shape, resampling=Resampling.nearest).astype(np.int64)
    return bool(np.any(values & 0xC000))
