"""One entry point for every model file gcpcal reads: :func:`open_model`.

========================================  =========================================
file                                      model
========================================  =========================================
``*.json`` (gcpcal scene manifest)        :class:`~sensor_models.pushbroom.PushbroomModel` or
                                          :class:`~sensor_models.geo_staring.GeoStaringModel`
``*.DIM`` (SPOT 1-5 DIMAP level 1A)       :class:`~sensor_models.pushbroom.PushbroomModel`
``*.geom`` (OSSIM keyword list, RPC)      :class:`~sensor_models.rpc.RpcModel`
``*.RPB``, ``*_RPC.TXT``                  :class:`~sensor_models.rpc.RpcModel`
``*.XML`` DIMAP v2 (``Dimap_Document``)   :func:`sensor_models.readers.dimap_v2.read_dimap_v2`
``*.XML`` WorldView (``isd``)             :func:`sensor_models.readers.worldview.read_worldview`
a raster with RPC metadata (GeoTIFF...)   :class:`~sensor_models.rpc.RpcModel`
========================================  =========================================

:func:`open_scene` (:mod:`sensor_models.readers.scene_input`) opens a SCENE as the user has it:
any of these files, or a raster with an RPC, with the raster of its pixels found and the model
cropped to a crop.
"""

from __future__ import annotations

from pathlib import Path

from sensor_models.errors import InputError

__all__ = ["open_model", "open_scene"]

#: Root element of a vendor XML file -> (module, reader function) of its geometric reader.
_XML_READERS = {
    "Dimap_Document": ("sensor_models.readers.dimap_v2", "read_dimap_v2"),
    "isd": ("sensor_models.readers.worldview", "read_worldview"),
}


def open_scene(path, *, image=None, band=None, **kwargs):
    """Open a SCENE as the user has it (:func:`sensor_models.readers.scene_input.open_scene`)."""
    from sensor_models.readers.scene_input import open_scene as _open_scene

    return _open_scene(path, image=image, band=band, **kwargs)


def open_model(path, **kwargs):
    """Open a sensor model from any supported file (see the module table).

    Parameters
    ----------
    path : str or Path
        The model file; its kind is told by its name (``.json``, ``.dim``, anything else RPC).
    **kwargs
        Passed to the reader of that kind (:func:`~sensor_models.readers.scene.read_manifest`,
        :func:`~sensor_models.readers.dimap.read_dimap`, :meth:`RpcModel.read
        <sensor_models.rpc.RpcModel.read>`).

    Returns
    -------
    SensorModel
        The model the file describes.

    Raises
    ------
    InputError
        If the file does not exist or its kind is not recognized (naming the file).
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path=str(path))
    name = path.name.lower()
    if name.endswith(".json"):
        from sensor_models.readers.scene import read_manifest

        return read_manifest(path, **kwargs)
    if name.endswith(".dim"):
        from sensor_models.readers.dimap import read_dimap

        return read_dimap(path, **kwargs)
    if name.endswith(".xml"):
        return _read_vendor_xml(path, **kwargs)
    from sensor_models.rpc import RpcModel

    return RpcModel.read(path, **kwargs)


def _read_vendor_xml(path: Path, **kwargs):
    """A DIMAP v2 or WorldView XML file, told by its root element, through its reader."""
    import importlib

    from sensor_models.readers.scene_input import xml_root

    root = xml_root(path)
    if root not in _XML_READERS:
        raise InputError(f"unknown XML product (root element {root!r}); gcpcal reads DIMAP v2 "
                         "(Dimap_Document) and WorldView (isd) XML", path=str(path))
    module_name, function_name = _XML_READERS[root]
    try:
        reader = getattr(importlib.import_module(module_name), function_name)
    except (ImportError, AttributeError):
        raise InputError(f"reader not available for {root} XML ({module_name}.{function_name})",
                         path=str(path)) from None
    return reader(path, **kwargs)
