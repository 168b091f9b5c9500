"""Read a gcpcal scene manifest of either kind: the dispatch on ``sensor``.

A manifest says which camera it describes (``"sensor": "pushbroom"`` or ``"geo_staring"``);
:func:`read_manifest` decodes the JSON once and hands the document to the reader of that kind
(:mod:`sensor_models.readers.manifest` or :mod:`sensor_models.readers.geo_manifest`). Neither
of those readers imports the other; both import their shared pieces from ``readers._common``.
"""

from __future__ import annotations

from pathlib import Path

from sensor_models.readers._common import load_json
from sensor_models.readers.geo_manifest import SENSOR as GEO_SENSOR
from sensor_models.readers.geo_manifest import geo_model_and_rasters
from sensor_models.readers.manifest import pushbroom_model_and_rasters

__all__ = ["read_manifest", "read_manifest_and_rasters"]


def read_manifest(path):
    """Read a scene manifest into the sensor model it describes.

    Parameters
    ----------
    path : str or Path
        The manifest JSON file (``docs/manifest.md``, ``docs/geo_manifest.md``).

    Returns
    -------
    PushbroomModel or GeoStaringModel
        A :class:`~sensor_models.models.pushbroom.PushbroomModel` for ``sensor: "pushbroom"`` (and for
        a document whose ``sensor`` is missing or wrong, which then fails with the field named),
        a :class:`~sensor_models.models.geo_staring.GeoStaringModel` for ``sensor: "geo_staring"``.
        Its rasters: :func:`read_manifest_and_rasters`, or ``open_scene(path).rasters``.

    Raises
    ------
    ManifestError
        One line: ``<file>: field '<dotted.path>': <what is wrong>``.
    """
    return read_manifest_and_rasters(path)[0]


def read_manifest_and_rasters(path) -> tuple:
    """Read a scene manifest into its model and the rasters it lists.

    Parameters
    ----------
    path : str or Path
        The manifest JSON file.

    Returns
    -------
    model : PushbroomModel or GeoStaringModel
        As :func:`read_manifest`.
    rasters : dict
        Band -> ``RasterRef`` with an absolute path (empty when the manifest names none).

    Raises
    ------
    ManifestError
        As :func:`read_manifest`.
    """
    path = Path(path)
    doc = load_json(path)
    if isinstance(doc, dict) and doc.get("sensor") == GEO_SENSOR:
        return geo_model_and_rasters(doc, path)
    return pushbroom_model_and_rasters(doc, path)
