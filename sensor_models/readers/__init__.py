"""One entry point for every model file gcpcal reads: :func:`open_model`.

========================================  =========================================
file                                      model
========================================  =========================================
``*.json`` (gcpcal scene manifest)        :class:`~sensor_models.pushbroom.PushbroomModel` or
                                          :class:`~sensor_models.geo_staring.GeoStaringModel`
``*.DIM`` (SPOT 1-5 DIMAP level 1A)       :class:`~sensor_models.pushbroom.PushbroomModel`
``*.geom`` (OSSIM keyword list, RPC)      :class:`~sensor_models.rpc.RpcModel`
``*.RPB``, ``*_RPC.TXT``                  :class:`~sensor_models.rpc.RpcModel`
a raster with RPC metadata (GeoTIFF...)   :class:`~sensor_models.rpc.RpcModel`
========================================  =========================================
"""

from __future__ import annotations

from pathlib import Path

from sensor_models.errors import InputError

__all__ = ["open_model"]


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
    from sensor_models.rpc import RpcModel

    return RpcModel.read(path, **kwargs)
