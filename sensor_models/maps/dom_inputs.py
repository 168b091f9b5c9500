"""Reference orthoimages (DOMs) as users have them: Landsat and Sentinel-2 products, tiles, QA.

:class:`DomSource` is what a user names (``--dom``, ``--dom-band``, ``--dom-qa``, ...);
:func:`open_dom` resolves it into a :class:`sensor_models.maps.raster.MapImage`:

1. **Band files.** Without a band, each item is a file, a comma list, a folder of tiles, a
   glob or a ``.vrt`` (:func:`sensor_models.maps.mosaic.raster_inputs`). With a band (``B04``,
   ``B4``, ``4``, ``B8A``), folders are searched (recursively: a Sentinel-2 ``.SAFE``, a
   granule's ``IMG_DATA``, a Landsat product folder) for that band's files
   (``*_B04.jp2``, ``*_B04_10m.jp2``, ``*_B4.TIF``); of Sentinel-2 L2A resolutions the finest
   is taken. A folder holding several bands of a product and no band given is refused.
2. **Radiometry.** Sentinel-2 (a ``.jp2`` band ``Bnn``): reflectance
   ``(DN + offset) / quantification`` with the ``QUANTIFICATION_VALUE`` (L1C) or
   ``BOA_QUANTIFICATION_VALUE`` (L2A) and the band's ``RADIO_ADD_OFFSET`` (L1C) or
   ``BOA_ADD_OFFSET`` (L2A) of the product's ``MTD_MSIL1C.xml`` / ``MTD_MSIL2A.xml`` (searched up
   to four folders above the band; -1000 from processing baseline 04.00 on [1]_); without the
   file, quantification 10000 and offset 0 are assumed and the summary says so. DN 0 is no
   data. Landsat (``*_B<n>.TIF``): ``REFLECTANCE_MULT_BAND_<n>`` and ``REFLECTANCE_ADD_BAND_<n>``
   of a ``*_MTL.txt`` beside the band when present (else DN), DN 0 (fill) is no data.
   ``--dom-scale`` / ``--dom-offset`` override.
3. **QA.** ``--dom-qa`` names the QA raster(s); otherwise one found beside each band file is
   used: ``<id>_QA_PIXEL.TIF`` or ``<id>_BQA.TIF`` for Landsat, ``*_SCL_20m.jp2`` (or
   ``*_SCL*``) of the same Sentinel-2 granule. Its layout comes from ``--dom-qa-layout``, the
   file name, or its values (:mod:`sensor_models.maps.reference_qa`).
4. **Stated geolocation accuracy** (:func:`reference_accuracy`, docs/matching.md "sigma_px"):
   the user's value (``--reference-sigma-m``); else the DOM's own statement: the GDAL metadata
   items :data:`ACCURACY_TAG` (one value per axis) or :data:`ACCURACY_TAG_X` /
   :data:`ACCURACY_TAG_Y` (east / north) of the band file, or ``GEOMETRIC_RMSE_MODEL_X`` /
   ``_Y`` of a Landsat ``*_MTL.txt`` beside it [2]_; else :data:`ASSUMED_REFERENCE_SIGMA_M`,
   marked as assumed.

References
----------
.. [1] ESA, "Sentinel-2 Products Specification Document", S2-PDGS-TAS-DI-PSD, edition 15,
   sections on the radiometric offset introduced with processing baseline 04.00 (25 January
   2022): ``L1C reflectance = (DN + RADIO_ADD_OFFSET) / QUANTIFICATION_VALUE``, likewise L2A
   with ``BOA_ADD_OFFSET``.
.. [2] USGS, "Landsat 8-9 Calibration and Validation (Cal/Val) Algorithm Description Document"
   and "Landsat 8-9 OLI/TIRS Collection 2 Level 1 Data Format Control Book" (LSDS-1822): the
   MTL group ``LEVEL1_PROCESSING_RECORD`` gives ``GEOMETRIC_RMSE_MODEL_X`` / ``_Y``, the RMSE
   in metres of the ground control points about the precision model, per map axis.
.. [3] J. Storey, M. Choate, K. Lee, "Landsat 8 Operational Land Imager On-Orbit Geometric
   Calibration and Performance", Remote Sens. 6(11):11127-11152, 2014, Table 1: L1T product
   (terrain corrected with ground control) accuracy requirement 12 m CE90.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from sensor_models.errors import InputError
from sensor_models.files.gdal_paths import is_gdal_virtual
from sensor_models.maps.mosaic import RASTER_SUFFIXES, raster_inputs

__all__ = ["ACCURACY_TAG", "ACCURACY_TAG_X", "ACCURACY_TAG_Y", "ASSUMED_REFERENCE_SIGMA_M", "DomSource",
           "ReferenceAccuracy", "ResolvedDom", "S2_BAND_IDS", "dom_description", "masked_fraction", "open_dom",
           "reference_accuracy", "resolve_dom", "s2_radiometry", "stated_accuracy"]

#: Sentinel-2 band names in the order of the MTD files' ``band_id`` (0 to 12).
S2_BAND_IDS = ("B01", "B02", "B03", "B04", "B05", "B06", "B07", "B08", "B8A", "B09", "B10", "B11", "B12")

_BAND_NAME = re.compile(r"(?:^|_)B(\d{1,2}A?)(?:_(\d+)M)?\.(?:JP2|TIF|TIFF)$", re.IGNORECASE)
_SEARCH_DEPTH = 6


@dataclass(frozen=True)
class DomSource:
    """What a user names as the reference orthoimage.

    Attributes
    ----------
    items : tuple of str
        Files, comma lists, folders, globs or ``.vrt`` (:func:`sensor_models.maps.mosaic.raster_inputs`).
    band : str or None
        Band of a product (``B04``, ``B4``, ``4``, ``B8A``).
    qa : tuple of str
        QA raster(s); empty: looked for beside the band files.
    qa_layout : str or None
        Layout of the QA (:data:`sensor_models.maps.reference_qa.QA_LAYOUTS`); None: from name or values.
    scale, offset : float or None
        Override of ``value = DN * scale + offset``.
    use_qa : bool
        False: no QA, not even one found beside the band.
    qa_cirrus : bool
        The QA's cirrus flags mask too (by default cirrus is a flag, not a mask).
    mask : tuple of str
        The user's own mask raster(s) in the DOM's CRS: nonzero = unusable; applied with the QA.
    """

    items: tuple = ()
    band: str | None = None
    qa: tuple = ()
    qa_layout: str | None = None
    scale: float | None = None
    offset: float | None = None
    use_qa: bool = True
    qa_cirrus: bool = False
    mask: tuple = ()

    @property
    def paths(self) -> tuple:
        """The items, QA and mask files given (for checks that outputs do not overwrite inputs)."""
        return tuple(self.items) + tuple(self.qa) + tuple(self.mask)

    def __str__(self) -> str:
        return ",".join(self.items)


@dataclass
class ResolvedDom:
    """A DOM source resolved into files and radiometry (see :func:`resolve_dom`)."""

    files: list
    qa_files: list = field(default_factory=list)
    qa_layout: str | None = None
    qa_cirrus: bool = False
    mask_files: list = field(default_factory=list)
    scale: float = 1.0
    offset: float = 0.0
    nodata: float | None = None
    product: str = "raster"
    notes: list = field(default_factory=list)


def _as_source(source) -> DomSource:
    if isinstance(source, DomSource):
        return source
    if isinstance(source, (str, os.PathLike)):
        return DomSource(items=(os.fspath(source),))
    return DomSource(items=tuple(os.fspath(s) for s in source))


def _normalize_band(band: str) -> str:
    text = str(band).strip().upper()
    text = text[1:] if text.startswith("B") else text
    if not re.fullmatch(r"\d{1,2}A?", text):
        raise InputError(f"--dom-band must name a band like B04, B4, 4 or B8A, got {band!r}", field="dom_band")
    return text.lstrip("0") or "0"


def _band_of(name: str):
    """``(band without zeros, resolution in m or None)`` of a band file name, or None."""
    m = _BAND_NAME.search(name)
    if m is None:
        return None
    return m.group(1).upper().lstrip("0") or "0", None if m.group(2) is None else int(m.group(2))


def _walk_rasters(folder: str):
    base_depth = folder.rstrip(os.sep).count(os.sep)
    for root, dirs, names in os.walk(folder):
        dirs.sort()
        if root.count(os.sep) - base_depth >= _SEARCH_DEPTH:
            dirs[:] = []
        for name in sorted(names):
            if name.lower().endswith(RASTER_SUFFIXES):
                yield os.path.join(root, name)


def _band_files(folder: str, band: str, given: str) -> list:
    """Files of ``band`` (as normalized; ``given`` as the user wrote it) under ``folder``, finest resolution."""
    found = [(p, _band_of(os.path.basename(p))) for p in _walk_rasters(folder)]
    found = [(p, res) for p, b in found if b is not None and b[0] == band for res in [b[1]]]
    if not found:
        raise InputError(f"no file of band {given} under the DOM folder (looked for *_B{band}.TIF, *_B{band:0>2}.jp2, "
                         f"*_B{band:0>2}_<res>m.jp2)", path=folder, field="dom_band")
    finest = min((res or 0) for _, res in found)
    return [p for p, res in found if (res or 0) == finest]


def _refuse_product_folder(folder: str) -> None:
    bands = {b[0] for p in _walk_rasters(folder) if (b := _band_of(os.path.basename(p))) is not None}
    if len(bands) > 1:
        raise InputError(f"the DOM folder holds several bands ({', '.join('B' + b for b in sorted(bands))}); "
                         "choose one with --dom-band", path=folder, field="dom_band")


def _band_inputs(source: DomSource) -> list:
    """The band files a source names (step 1 of the module docstring)."""
    if source.band is None:
        for item in source.items:
            if os.path.isdir(item):
                _refuse_product_folder(item)
        return raster_inputs(source.items, what="DOM")
    band = _normalize_band(source.band)
    files = []
    for item in source.items:
        if os.path.isdir(item):
            found = _band_files(item, band, source.band)
        else:  # files, comma lists and globs: those named as the band
            found = [f for f in raster_inputs(item, what="DOM") if (_band_of(os.path.basename(f)) or ("",))[0] == band]
            if not found:
                raise InputError(f"names no file of band {source.band} (*_B{band}.TIF, *_B{band:0>2}.jp2)", path=item,
                                 field="dom_band")
        files += [f for f in found if f not in files]
    return files


def _find_upwards(start: str, names) -> str | None:
    folder = os.path.dirname(os.path.abspath(start))
    for _ in range(5):
        for name in names:
            candidate = os.path.join(folder, name)
            if os.path.isfile(candidate):
                return candidate
        folder = os.path.dirname(folder)
    return None


def _is_sentinel2(path: str) -> bool:
    name = os.path.basename(path)
    return name.lower().endswith(".jp2") and re.search(r"(?:^|_)B(\d\d|8A)(?:_\d+m)?\.jp2$", name, re.I) is not None


def _landsat_id(path: str):
    """``(scene identifier, band number)`` of a Landsat band file ``<id>_B<n>.TIF``, or None."""
    m = re.match(r"(.+)_B(\d{1,2})\.TIFF?$", os.path.basename(path), re.I)
    return None if m is None else (m.group(1), m.group(2))


def s2_radiometry(mtd_path: str, band: str):
    """Quantification value and additive offset of one band from a Sentinel-2 ``MTD_MSIL1C/2A.xml``.

    Parameters
    ----------
    mtd_path : str
        The product metadata file.
    band : str
        Band name of :data:`S2_BAND_IDS` (``B04``).

    Returns
    -------
    quantification : float
        ``QUANTIFICATION_VALUE`` (L1C) or ``BOA_QUANTIFICATION_VALUE`` (L2A).
    offset_dn : float
        ``RADIO_ADD_OFFSET`` (L1C) or ``BOA_ADD_OFFSET`` (L2A) of the band; 0 when the file has
        none (processing baselines before 04.00).
    """
    from sensor_models.files.documents import parse_xml

    root = parse_xml(mtd_path)
    by_tag = {}
    for el in root.iter():
        tag = el.tag.rsplit("}", 1)[-1]
        by_tag.setdefault(tag, []).append(el)
    quant = by_tag.get("QUANTIFICATION_VALUE") or by_tag.get("BOA_QUANTIFICATION_VALUE")
    if not quant:
        raise InputError("no QUANTIFICATION_VALUE or BOA_QUANTIFICATION_VALUE", path=mtd_path)
    band_id = str(S2_BAND_IDS.index(band))
    offset = 0.0
    for tag in ("RADIO_ADD_OFFSET", "BOA_ADD_OFFSET"):
        for el in by_tag.get(tag, []):
            if el.get("band_id") == band_id:
                offset = float(el.text)
    return float(quant[0].text), offset


def _s2_band_name(path: str) -> str:
    b = _band_of(os.path.basename(path))[0]
    return "B8A" if b == "8A" else f"B{int(b):02d}"


def _resolve_s2(files: list, dom: ResolvedDom) -> None:
    dom.product, dom.nodata = "sentinel-2", 0.0
    mtd = _find_upwards(files[0], ("MTD_MSIL1C.xml", "MTD_MSIL2A.xml"))
    if mtd is None:
        dom.scale, dom.offset = 1.0 / 10000.0, 0.0
        dom.notes.append("Sentinel-2 without MTD_MSIL1C/2A.xml: reflectance = DN / 10000 assumed (offset 0)")
        return
    quant, offset_dn = s2_radiometry(mtd, _s2_band_name(files[0]))
    dom.scale, dom.offset = 1.0 / quant, offset_dn / quant
    dom.notes.append(f"Sentinel-2 radiometry from {os.path.basename(mtd)}: (DN + {offset_dn:g}) / {quant:g}")


def _mtl_value(mtl: str, key: str):
    with open(mtl, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            name, _, value = line.partition("=")
            if name.strip() == key:
                return float(value.strip().strip('"'))
    return None


def _resolve_landsat(files: list, dom: ResolvedDom) -> None:
    dom.product, dom.nodata = "landsat", 0.0
    scene_id, band = _landsat_id(files[0])
    mtl = os.path.join(os.path.dirname(files[0]), f"{scene_id}_MTL.txt")
    if os.path.isfile(mtl):
        mult = _mtl_value(mtl, f"REFLECTANCE_MULT_BAND_{band}")
        add = _mtl_value(mtl, f"REFLECTANCE_ADD_BAND_{band}")
        if mult is not None and add is not None:
            dom.scale, dom.offset = mult, add
            dom.notes.append(f"Landsat TOA reflectance from {os.path.basename(mtl)}: DN * {mult:g} + {add:g}")


def _sibling(folder: str, pattern: str):
    if not os.path.isdir(folder):
        return None
    rx = re.compile(pattern, re.I)
    for name in sorted(os.listdir(folder)):
        if rx.fullmatch(name):
            return os.path.join(folder, name)
    return None


def _qa_beside(path: str, product: str):
    """The QA raster that belongs to a band file, or None."""
    folder = os.path.dirname(os.path.abspath(path))
    if product == "landsat":
        scene_id = re.escape(_landsat_id(path)[0])
        return _sibling(folder, rf"{scene_id}_QA_PIXEL\.TIFF?") or _sibling(folder, rf"{scene_id}_BQA\.TIFF?")
    if product == "sentinel-2":
        found = _sibling(folder, r".*_SCL(_\d+m)?\.(jp2|tif)")
        if found is None and re.fullmatch(r"R\d+m", os.path.basename(folder)):
            found = _sibling(os.path.join(os.path.dirname(folder), "R20m"), r".*_SCL_20m\.jp2")
        return found
    return None


def resolve_dom(source) -> ResolvedDom:
    """Band files, QA files and radiometry of a DOM source (module docstring, steps 1-3).

    Parameters
    ----------
    source : DomSource, str, os.PathLike or sequence of them

    Returns
    -------
    ResolvedDom
        ``files``, ``qa_files``, ``qa_layout``, ``scale``, ``offset``, ``nodata``, ``product``
        (``sentinel-2``, ``landsat`` or ``raster``) and ``notes`` for the summary.
    """
    source = _as_source(source)
    if source.qa and not source.use_qa:
        raise InputError("--dom-qa and --no-dom-qa contradict each other; give one", field="dom_qa")
    files = _band_inputs(source)
    dom = ResolvedDom(files=files, qa_layout=source.qa_layout, qa_cirrus=bool(source.qa_cirrus))
    if source.mask:
        dom.mask_files = raster_inputs(source.mask, what="DOM mask")
    if all(_is_sentinel2(f) for f in files):
        _resolve_s2(files, dom)
    elif all(_landsat_id(f) is not None for f in files):
        _resolve_landsat(files, dom)
    if source.scale is not None:
        dom.scale = float(source.scale)
    if source.offset is not None:
        dom.offset = float(source.offset)
    if source.qa:
        dom.qa_files = raster_inputs(source.qa, what="DOM QA")
    elif source.use_qa and dom.product != "raster":
        beside = [_qa_beside(f, dom.product) for f in files]
        if all(q is not None for q in beside):
            dom.qa_files = beside
            dom.notes.append(f"QA found beside the band: {', '.join(os.path.basename(q) for q in beside)}")
    return dom


def open_dom(source):
    """Open a DOM source as one map image (mosaic, radiometry, QA mask applied when read).

    Parameters
    ----------
    source : DomSource, str, os.PathLike or sequence of them

    Returns
    -------
    image : sensor_models.maps.raster.MapImage
    resolved : ResolvedDom
        What was found (for the summary: :func:`dom_description`).

    Raises
    ------
    InputError
        As :func:`resolve_dom`, :meth:`sensor_models.maps.raster.MapImage.open`.
    """
    from sensor_models.maps.raster import MapImage

    dom = resolve_dom(source)
    image = MapImage.open(dom.files, nodata=dom.nodata, scale=dom.scale, offset=dom.offset,
                          qa_path=dom.qa_files or None, qa_layout=dom.qa_layout, qa_cirrus=dom.qa_cirrus,
                          mask_path=dom.mask_files or None)
    dom.qa_layout = image.qa_layout
    return image, dom


def dom_description(dom: ResolvedDom) -> dict:
    """The summary fields describing a resolved DOM.

    Parameters
    ----------
    dom : ResolvedDom

    Returns
    -------
    dict
        ``dom_files``, ``dom_product``, ``dom_scale``, ``dom_offset``, ``dom_qa_files``,
        ``dom_qa_layout``, ``dom_qa_masks_cirrus``, ``dom_mask_files``, ``dom_notes``.
    """
    return {"dom_files": list(dom.files), "dom_product": dom.product, "dom_scale": dom.scale,
            "dom_offset": dom.offset, "dom_qa_files": list(dom.qa_files), "dom_qa_layout": dom.qa_layout,
            "dom_qa_masks_cirrus": bool(dom.qa_cirrus) if dom.qa_files else None,
            "dom_mask_files": list(dom.mask_files), "dom_notes": list(dom.notes)}


def masked_fraction(image, lon_deg, lat_deg, *, max_side: int = 512):
    """Share of the DOM under a footprint that its QA and the user's mask mask.

    The DOM window bounding the footprint's points is looked at decimated to at most
    ``max_side`` pixels a side.

    Parameters
    ----------
    image : sensor_models.maps.raster.MapImage
        The DOM (with ``qa_path``).
    lon_deg, lat_deg : ndarray of float
        Footprint sample points (WGS84 degrees).
    max_side : int
        Largest side of the decimated look, pixels.

    Returns
    -------
    float or None
        In ``[0, 1]``; None without a QA raster or mask, or when the footprint misses the DOM.
    """
    import pyproj

    if not image.has_mask:
        return None
    to_map = pyproj.Transformer.from_crs("EPSG:4326", image.grid.crs, always_xy=True)
    lon = np.asarray(lon_deg, dtype=np.float64).ravel()
    x, y = to_map.transform(lon, np.asarray(lat_deg, dtype=np.float64).ravel())
    col, row = ~image.grid.transform * (np.asarray(x), np.asarray(y))
    ok = np.isfinite(col) & np.isfinite(row)
    n_rows, n_cols = image.grid.shape
    if not ok.any():
        return None
    r0, r1 = max(0, int(np.floor(row[ok].min()))), min(n_rows, int(np.ceil(row[ok].max())))
    c0, c1 = max(0, int(np.floor(col[ok].min()))), min(n_cols, int(np.ceil(col[ok].max())))
    if r1 <= r0 or c1 <= c0:
        return None
    shape = (min(max_side, r1 - r0), min(max_side, c1 - c0))
    return float(image.qa_invalid(r0, r1, c0, c1, shape).mean())


#: GDAL metadata item (default domain) of a DOM: its geolocation accuracy, metres, 1 sigma (RMSE)
#: per horizontal axis
ACCURACY_TAG = "GEOLOCATION_RMSE_M"
#: GDAL metadata items of a DOM: its geolocation RMSE along the map's x (east) and y (north) axes,
#: metres (the names of the Landsat MTL items without ``_MODEL``); both or neither
ACCURACY_TAG_X = "GEOMETRIC_RMSE_X"
ACCURACY_TAG_Y = "GEOMETRIC_RMSE_Y"
#: per-axis accuracy assumed for a DOM that states none, metres: Landsat 8 L1T's 12 m CE90
#: requirement (Storey et al. 2014, Table 1; module references) as a circular normal error,
#: CE90 = 2.146 sigma
ASSUMED_REFERENCE_SIGMA_M = 12.0 / 2.146


@dataclass(frozen=True)
class ReferenceAccuracy:
    """The geolocation accuracy of a reference DOM, metres (1 sigma per axis), and where it came from.

    Attributes
    ----------
    east_m, north_m : float
        RMSE along east (map x) and north (map y), metres, >= 0.
    source : str
        ``"option"``, ``"tag <file>"``, ``"mtl <file>"`` or ``"assumed"``.
    assumed : bool
        True when nothing stated it (:data:`ASSUMED_REFERENCE_SIGMA_M`).
    """

    east_m: float
    north_m: float
    source: str
    assumed: bool = False

    @property
    def per_axis_m(self) -> float:
        """The per-axis rms of east and north, metres: ``sqrt((east^2 + north^2) / 2)``."""
        return float(np.sqrt(0.5 * (self.east_m**2 + self.north_m**2)))

    @property
    def note(self) -> str | None:
        """The summary's line when the value is assumed, else None."""
        if not self.assumed:
            return None
        return (f"reference accuracy unknown: assumed {self.per_axis_m:.1f} m per axis (Landsat 8 L1T, 12 m CE90); "
                "give --reference-sigma-m")

    def to_dict(self) -> dict:
        """JSON-ready: ``east_m``, ``north_m``, ``source``, ``assumed``."""
        return {"east_m": self.east_m, "north_m": self.north_m, "source": self.source, "assumed": self.assumed}


def _accuracy_value(text, what: str, path: str) -> float:
    try:
        value = float(str(text).strip().strip('"'))
    except ValueError:
        value = float("nan")
    if not np.isfinite(value) or value < 0:
        raise InputError(f"{what} must be a number of metres >= 0, got {text!r}", path=path, field=what)
    return value


def _tag_accuracy(path: str):
    """``ReferenceAccuracy`` from the GDAL metadata items of one raster, or None."""
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(path) as ds:
            tags = ds.tags()
    except RasterioError:
        return None
    if ACCURACY_TAG_X in tags or ACCURACY_TAG_Y in tags:
        if not (ACCURACY_TAG_X in tags and ACCURACY_TAG_Y in tags):
            raise InputError(f"the DOM states {ACCURACY_TAG_X} or {ACCURACY_TAG_Y} alone; give both", path=path,
                             field=ACCURACY_TAG_X)
        return ReferenceAccuracy(_accuracy_value(tags[ACCURACY_TAG_X], ACCURACY_TAG_X, path),
                                 _accuracy_value(tags[ACCURACY_TAG_Y], ACCURACY_TAG_Y, path), f"tag {path}")
    if ACCURACY_TAG in tags:
        value = _accuracy_value(tags[ACCURACY_TAG], ACCURACY_TAG, path)
        return ReferenceAccuracy(value, value, f"tag {path}")
    return None


def _mtl_beside(path: str):
    """The Landsat ``<id>_MTL.txt`` of a band file, else the one ``*_MTL.txt`` beside it, or None."""
    folder = os.path.dirname(os.path.abspath(path))
    ident = _landsat_id(path)
    if ident is not None and os.path.isfile(os.path.join(folder, f"{ident[0]}_MTL.txt")):
        return os.path.join(folder, f"{ident[0]}_MTL.txt")
    found = [n for n in sorted(os.listdir(folder)) if n.upper().endswith("_MTL.TXT")] if os.path.isdir(folder) else []
    return os.path.join(folder, found[0]) if len(found) == 1 else None


def _mtl_accuracy(path: str):
    """``ReferenceAccuracy`` from ``GEOMETRIC_RMSE_MODEL_X/Y`` of the MTL beside a band file, or None."""
    mtl = _mtl_beside(path)
    if mtl is None:
        return None
    items = {}
    with open(mtl, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            name, _, value = line.partition("=")
            items.setdefault(name.strip(), value)
    x, y = items.get("GEOMETRIC_RMSE_MODEL_X"), items.get("GEOMETRIC_RMSE_MODEL_Y")
    if x is None or y is None:
        return None
    return ReferenceAccuracy(_accuracy_value(x, "GEOMETRIC_RMSE_MODEL_X", mtl),
                             _accuracy_value(y, "GEOMETRIC_RMSE_MODEL_Y", mtl), f"mtl {mtl}")


def stated_accuracy(files):
    """What the DOM's files state of their geolocation accuracy (tags, then a Landsat MTL), or None.

    Over several files (tiles) the largest statement per axis is kept.

    Parameters
    ----------
    files : sequence of str
        The DOM's band files (:attr:`ResolvedDom.files`).

    Returns
    -------
    ReferenceAccuracy or None
        None when no file states it.

    Raises
    ------
    InputError
        A stated value that is not a number >= 0, or one of the x / y items without the other.
    """
    found = []
    for path in files:
        virtual = is_gdal_virtual(path)
        if not (virtual or os.path.isfile(path)):
            continue
        acc = _tag_accuracy(path) or (None if virtual else _mtl_accuracy(path))
        if acc is not None:
            found.append(acc)
    if not found:
        return None
    worst = max(found, key=lambda a: a.per_axis_m)
    return ReferenceAccuracy(max(a.east_m for a in found), max(a.north_m for a in found), worst.source)


def reference_accuracy(files, *, given_m=None) -> ReferenceAccuracy:
    """The DOM's geolocation accuracy per axis, in the order of the module docstring (step 4).

    Parameters
    ----------
    files : sequence of str
        The DOM's band files.
    given_m : float, (float, float) or None
        The user's value, metres: both axes, or ``(east, north)`` (``--reference-sigma-m``);
        wins when given.

    Returns
    -------
    ReferenceAccuracy
        ``assumed`` is True when neither the user nor the files state it.
    """
    if given_m is not None:
        east, north = (given_m[0], given_m[-1]) if isinstance(given_m, (tuple, list)) else (given_m, given_m)
        return ReferenceAccuracy(float(east), float(north), "option")
    stated = stated_accuracy(files)
    if stated is not None:
        return stated
    return ReferenceAccuracy(ASSUMED_REFERENCE_SIGMA_M, ASSUMED_REFERENCE_SIGMA_M, "assumed", assumed=True)
