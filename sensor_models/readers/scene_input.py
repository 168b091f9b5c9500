"""A SCENE as the user has it: the sensor model with the raster that holds its pixels.

:func:`open_scene` accepts every form a user brings and returns a
:class:`~sensor_models.readers.scene_value.Scene`: the model, cropped to the raster when the
raster is a crop, with ``rasters`` (band -> ``{"path", "index"}``):

==========================================  ==================================================
given                                       model / raster
==========================================  ==================================================
``*.json`` (gcpcal scene manifest)          the manifest's model and ``image.rasters``
a raster with GeoTIFF RPC tags, or with     the RPC (GDAL finds tags, ``.RPB`` and
``X.RPB`` / ``X_RPC.TXT`` beside it         ``_RPC.TXT`` itself); the raster itself
a raster with ``X.geom`` beside it          the OSSIM keyword-list RPC; the raster itself
``X.geom``, ``X.RPB``, ``X_RPC.TXT``        the RPC; ``X.tif`` (``.TIF``, ``.tiff``, ``.NTF``,
                                            ``.jp2`` ...) beside it
SPOT 1-5 ``*.DIM``                          the DIMAP model; ``Data_Access/Data_File/
                                            DATA_FILE_PATH@href``
DIMAP v2 ``*.XML`` (``Dimap_Document``)     ``Raster_Data/Data_Access/Data_Files/Data_File/
                                            DATA_FILE_PATH@href`` (one tile)
WorldView ``*.XML`` (``isd``)               ``X.TIF`` / ``X.NTF`` beside it
==========================================  ==================================================

A raster whose size differs from the model's is a crop: it must carry a pixel geotransform
``(1, 0, col0, 0, 1, row0)`` and no CRS (the convention of the CNES shareloc / OTB test data:
``(col0, row0)`` is the full-scene column and row of the crop's first pixel corner), and the
model becomes ``model.cropped(row0, col0, shape)`` (only models that offer ``cropped``: RPCs)
and ``Scene.crop`` says where the crop lies.

When no raster is found the Scene comes back with empty ``rasters`` and
``raster_candidates`` (the files looked for); :func:`missing_raster_message` turns that into
the one-line error of a command that needs pixels.
"""

from __future__ import annotations

import re
from pathlib import Path

from sensor_models.errors import InputError
from sensor_models.readers.scene_value import Scene

__all__ = ["RASTER_SUFFIXES", "crop_to_raster", "missing_raster_message", "open_scene", "raster_beside"]

#: Raster suffixes looked for beside a model file with the same stem, in this order.
RASTER_SUFFIXES = (".tif", ".TIF", ".tiff", ".TIFF", ".NTF", ".ntf", ".jp2", ".JP2")

_MODEL_SUFFIXES = (".json", ".dim", ".xml", ".geom", ".rpb")


def open_scene(path, *, image=None, band=None, self_check: str = "refuse", **kwargs):
    """The sensor model of a SCENE with the raster of its pixels (see the module table).

    Parameters
    ----------
    path : str or Path
        A gcpcal manifest, a model file (``.geom``, ``.RPB``, ``_RPC.TXT``, ``.DIM``, DIMAP v2
        or WorldView ``.XML``) or a raster carrying an RPC (tags or a sidecar).
    image : str or Path, optional
        A raster that replaces the scene's raster of ``band`` (``--image``); a crop of the
        scene crops the model.
    band : str, optional
        Band ``image`` is for (default: the model's reference band).
    self_check : {"refuse", "warn"}
        For a vendor product, what to do when its model disagrees with the product's own
        statements (:func:`~sensor_models.readers.open_model`); the result is
        ``Scene.product_check`` (None for manifests and RPCs).
    **kwargs
        Passed to the model reader (:func:`~sensor_models.readers.open_model`).

    Returns
    -------
    Scene
        The :class:`~sensor_models.readers.scene_value.Scene`: ``model`` (a crop's model
        describes the crop's pixels), ``rasters`` (band -> ``{"path": str, "index": int}``,
        absolute path, 1-based raster band), ``raster_candidates`` (the files looked for when
        none was found, else empty), ``source``, ``crop``, ``product_check`` and ``metadata``
        (a vendor product's :class:`~sensor_models.readers.scene_value.ProductMetadata`).

    Raises
    ------
    InputError
        No such file; a file that is neither a model file nor a raster; a raster with no RPC
        anywhere (the message lists what was looked for); a raster of another size without a
        pixel geotransform. A tiled DIMAP product gives no raster (``raster_tiles`` > 1) and
        :func:`missing_raster_message` says so.
    """
    from sensor_models.readers.model_file import open_model_with_provenance

    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path=str(path))
    if _is_model_file(path):
        model, listed, check, metadata = open_model_with_provenance(path, self_check=self_check, **kwargs)
        if path.name.lower().endswith(".json"):  # a manifest lists its own rasters
            return _with_image(model, dict(listed), image, band, check_shape=image is not None,
                               source=path, product_check=check)
        rasters, candidates = _rasters_of_model_file(path, model)
    else:
        from sensor_models.readers.self_check import check_policy

        check_policy(self_check)
        model = _model_of_raster(path, **kwargs)
        check = metadata = None
        rasters, candidates = _single_raster(model, path), ()
    return _with_image(model, rasters, image, band, check_shape=True, source=path, product_check=check,
                       metadata=metadata, raster_candidates=() if rasters else tuple(str(c) for c in candidates),
                       raster_tiles=len(candidates) if _names_tiles(path) else 0)


def missing_raster_message(scene, band) -> str:
    """The one-line reason a command needing the pixels of ``band`` cannot find them.

    Parameters
    ----------
    scene : Scene or None
        A :class:`~sensor_models.readers.scene_value.Scene` from :func:`open_scene` (None: the
        generic message).
    band : str or None
        The band whose pixels were asked for.

    Returns
    -------
    str
        E.g. ``"no raster found for the scene (looked for a.tif, a.TIF in /data); give --image"``.
    """
    candidates = [Path(c) for c in (scene.raster_candidates if scene is not None else ())]
    tiles = scene.raster_tiles if scene is not None else 0
    if tiles > 1:
        return (f"the product's raster is split into {tiles} tiles ({candidates[0].name}, ...); give one raster "
                "(e.g. a VRT of the tiles) as --image")
    if candidates:
        folders = {c.parent for c in candidates}
        names = ", ".join(c.name for c in candidates)
        where = f" in {candidates[0].parent}" if len(folders) == 1 else ""
        if len(folders) > 1:
            names = ", ".join(str(c) for c in candidates)
        return f"no raster found for the scene (looked for {names}{where}); give --image"
    return f"the scene lists no raster for band {band!r}; give --image"


def raster_beside(model_file) -> tuple[Path | None, tuple[Path, ...]]:
    """The raster with the same stem as an RPC or WorldView file, and the names looked for.

    Parameters
    ----------
    model_file : str or Path
        ``X.geom``, ``X.RPB``, ``X_RPC.TXT`` or ``X.XML``.

    Returns
    -------
    raster : Path or None
        The first of ``X`` + :data:`RASTER_SUFFIXES` that exists.
    candidates : tuple of Path
        Every name looked for, in order.
    """
    model_file = Path(model_file)
    name = model_file.name
    stem = name[: -len("_RPC.TXT")] if name.upper().endswith("_RPC.TXT") else model_file.stem
    candidates = tuple(model_file.with_name(stem + s) for s in RASTER_SUFFIXES)
    return next((c for c in candidates if c.is_file()), None), candidates


def crop_to_raster(model, image, shape):
    """The model of a crop whose raster says where it lies in the full scene.

    A crop saved with a pixel geotransform ``(1, 0, c0, 0, 1, r0)`` and no CRS (the convention
    of the shareloc / OTB test data: ``(c0, r0)`` is the full-scene column and row of the crop's
    first pixel) gets ``model.cropped(r0, c0, shape)``; anything else is an error.

    Parameters
    ----------
    model : SensorModel
        Model of the full scene; it must offer ``cropped(row0, col0, shape)``.
    image : str or Path
        The crop's raster.
    shape : tuple of int
        ``(n_rows, n_cols)`` of the crop, pixels.

    Returns
    -------
    model : SensorModel
        The model of the crop.
    corner : tuple of float
        ``(row0, col0)``: where the crop lies in the full scene (with the full model's
        ``image_shape`` this is :attr:`Scene.crop <sensor_models.readers.scene_value.Scene.crop>`,
        so that a model calibrated in crop pixels can be written back in the full scene's pixels).

    Raises
    ------
    InputError
        When the raster carries no pixel geotransform, or the model cannot be cropped.
    """
    t, crs = _raster_info(image)[1:]
    pixel = crs is None and abs(t.a - 1) < 1e-12 and abs(t.e - 1) < 1e-12 and t.b == 0 and t.d == 0
    if pixel and hasattr(model, "cropped"):
        return model.cropped(t.f, t.c, shape), (float(t.f), float(t.c))
    described = tuple(model.image_shape)
    why = ("a crop must carry a pixel geotransform (1, 0, col0, 0, 1, row0)" if hasattr(model, "cropped")
           else f"a {model.kind} model cannot be cropped; give the full scene raster")
    raise InputError(f"the raster is {shape[0]} x {shape[1]} px but the model describes "
                     f"{described[0]} x {described[1]}; {why}", path=str(image))


# ---------------------------------------------------------------- phases
def _is_model_file(path: Path) -> bool:
    name = path.name.lower()
    return name.endswith(_MODEL_SUFFIXES) or name.endswith("_rpc.txt")


def _model_of_raster(path: Path, **kwargs):
    """The RPC of a raster: GDAL's (tags, ``.RPB``, ``_RPC.TXT``), else ``X.geom`` beside it."""
    from sensor_models.readers.rpc_files import read_rpc

    shape, has_rpc = _raster_rpc(path)
    if has_rpc:
        return read_rpc(path, **kwargs)
    for geom in (path.with_suffix(".geom"), path.with_suffix(".GEOM")):
        if geom.is_file():
            return read_rpc(geom, **kwargs)
    looked = ", ".join(str(path.with_name(path.stem + s)) for s in (".RPB", "_RPC.TXT", ".geom"))
    raise InputError(f"no sensor model found for this {shape[0]} x {shape[1]} px raster: no GeoTIFF RPC tag "
                     f"and none of {looked}; give the model file (.geom, .RPB, _RPC.TXT, .DIM, .XML, .json) "
                     "as SCENE and the raster as --image", path=str(path))


def _rasters_of_model_file(path: Path, model) -> tuple[dict, tuple]:
    """``(rasters, candidates)`` of a model file: the raster it names or the one beside it."""
    name = path.name.lower()
    if name.endswith(".dim"):
        raster, candidates = _dimap_data_file(path, "Data_Access/Data_File/DATA_FILE_PATH")
    elif name.endswith(".xml") and _xml_root(path) == "Dimap_Document":
        raster, candidates = _dimap_data_file(path, "Raster_Data/Data_Access/Data_Files/Data_File/DATA_FILE_PATH")
    else:  # .geom, .RPB, _RPC.TXT, WorldView .XML
        raster, candidates = raster_beside(path)
    if raster is None:
        return {}, candidates
    return _band_rasters(model, raster), candidates


def _names_tiles(path: Path) -> bool:
    """Whether the candidates of this model file are the tiles it names (DIMAP), not alternatives."""
    name = path.name.lower()
    return name.endswith(".dim") or (name.endswith(".xml") and _xml_root(path) == "Dimap_Document")


def _dimap_data_file(path: Path, rel: str) -> tuple[Path | None, tuple[Path, ...]]:
    """The raster a DIMAP file names (``DATA_FILE_PATH@href``, relative to the file's folder).

    A product tiled into several files gives no raster (the tiles are the candidates).
    """
    from sensor_models.files.documents import parse_xml

    root = parse_xml(path)
    hrefs = [e.get("href") for e in root.iterfind(rel) if e.get("href")]
    candidates = tuple(path.parent / h for h in hrefs)
    if len(candidates) != 1:  # none named, or a tiled product (one raster per tile)
        return None, candidates
    return (candidates[0] if candidates[0].is_file() else None), candidates


def _xml_root(path: Path) -> str:
    from sensor_models.readers.model_file import xml_root

    return xml_root(path)


def _band_rasters(model, raster: Path) -> dict:
    """band -> raster reference: model band k in the raster's band k (``B<k>`` names: band k)."""
    bands = list(getattr(model, "bands", (None,)) or (None,))
    rasters = {}
    for position, band in enumerate(bands, start=1):
        named = re.fullmatch(r"B(\d+)", str(band)) if band is not None else None
        index = int(named.group(1)) if named and len(bands) > 1 else position
        rasters[band] = {"path": str(raster.resolve()), "index": index}
    return rasters


def _single_raster(model, raster: Path) -> dict:
    """The raster given as SCENE, band 1, for the model's one band."""
    return {getattr(model, "reference_band", None): {"path": str(raster.resolve()), "index": 1}}


def _with_image(model, rasters: dict, image, band, *, check_shape: bool, source: Path, product_check,
                metadata=None, raster_candidates: tuple = (), raster_tiles: int = 0) -> Scene:
    """The Scene: ``image`` replaces the raster of ``band``; a raster of another size crops the model."""
    key = band if band is not None else getattr(model, "reference_band", None)
    if image is not None:
        rasters[key] = {"path": str(Path(image).resolve()), "index": 1}
    ref = rasters.get(key)
    crop = None
    # a manifest's model with --image of another size is left to the command (as before)
    if check_shape and ref is not None and (image is None or hasattr(model, "cropped")):
        shape = _raster_info(ref["path"])[0]
        if shape != tuple(model.image_shape):
            full_shape = tuple(model.image_shape)
            model, (row0, col0) = crop_to_raster(model, ref["path"], shape)
            crop = (row0, col0, full_shape)
    return Scene(model=model, rasters=rasters, source=Path(source), raster_candidates=raster_candidates,
                 raster_tiles=raster_tiles, crop=crop, product_check=product_check, metadata=metadata)


def _raster_rpc(path) -> tuple[tuple[int, int], bool]:
    """``((n_rows, n_cols), whether GDAL finds an RPC)`` of a raster (tags or sidecar)."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                return (ds.height, ds.width), bool(ds.tags(ns="RPC"))
    except RasterioError as exc:
        raise InputError(f"cannot open as a raster ({exc}); a SCENE is a manifest, a model file or a raster",
                         path=str(path)) from None


def _raster_info(path):
    """``((n_rows, n_cols), transform, crs)`` of a raster, read from its header."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                return (ds.height, ds.width), ds.transform, ds.crs
    except RasterioError as exc:
        raise InputError(f"cannot read the raster ({exc})", path=str(path)) from None
