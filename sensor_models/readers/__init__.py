"""One entry point for every model file gcpcal reads: :func:`open_model`.

========================================  =========================================
file                                      model
========================================  =========================================
``*.json`` (gcpcal scene manifest)        :class:`~sensor_models.models.pushbroom.PushbroomModel` or
                                          :class:`~sensor_models.models.geo_staring.GeoStaringModel`
``*.DIM`` (SPOT 1-5 DIMAP level 1A)       :class:`~sensor_models.models.pushbroom.PushbroomModel`
``*.geom`` (OSSIM keyword list, RPC)      :class:`~sensor_models.models.rpc.RpcModel`
                                          (:func:`~sensor_models.readers.rpc_files.read_rpc`)
``*.RPB``, ``*_RPC.TXT``                  :class:`~sensor_models.models.rpc.RpcModel`
``*.XML`` DIMAP v2 (``Dimap_Document``)   :func:`sensor_models.readers.dimap_v2.read_dimap_v2`
``*.XML`` WorldView (``isd``)             :func:`sensor_models.readers.worldview.read_worldview`
a raster with RPC metadata (GeoTIFF...)   :class:`~sensor_models.models.rpc.RpcModel`
========================================  =========================================

The vendor readers (``.DIM``, DIMAP v2 and WorldView ``.XML``) compare the model they build with
the product's own corners and RPC and refuse a disagreement beyond their tolerance
(:mod:`sensor_models.readers.self_check`, ``self_check="warn"`` to proceed and record it in
``open_scene(...).product_check``).

:func:`open_scene` (:mod:`sensor_models.readers.scene_input`) opens a SCENE as the user has it:
any of these files, or a raster with an RPC, with the raster of its pixels found and the model
cropped to a crop.
"""

from __future__ import annotations

from sensor_models.readers.model_file import open_model
from sensor_models.readers.scene_input import open_scene

__all__ = ["open_model", "open_scene"]
