"""Rigorous sensor models: frames, orbit and attitude, push-broom, staring and RPC models, terrain.

The lowest layer of gcpcal: it knows nothing of matching or calibration and exposes model
parameters with their analytic Jacobians. Conventions (see ``docs/conventions.md``):
image coordinates are ``(row, col)`` with the first pixel's centre at ``(0.5, 0.5)``; ground
points are WGS84 ``lon, lat`` in degrees and ``h`` in metres above the ellipsoid; angles are
radians; times are seconds (SI) since a UTC scene epoch.

The public API (``docs/api.md``) is what :data:`__all__` lists; everything else lives in the rooms
``geometry/``, ``models/``, ``terrain/``, ``maps/``, ``imaging/``, ``readers/``, ``simulate/``.
"""

from sensor_models.errors import GcpcalError, InputError  # noqa: F401  (exported: __all__)

__version__ = "0.1.0"

#: Public name -> the module that defines it; imported on first use (PEP 562), so that importing
#: the package stays cheap (``gcpcal --help`` imports it).
_EXPORTS = {
    "open_model": "sensor_models.readers.model_file",
    "open_scene": "sensor_models.readers.scene_input",
    "Scene": "sensor_models.readers.scene_value",
    "SensorModel": "sensor_models.base",
    "PushbroomModel": "sensor_models.models.pushbroom",
    "GeoStaringModel": "sensor_models.models.geo_staring",
    "RpcModel": "sensor_models.models.rpc",
    "fit_rpc": "sensor_models.models.rpc_fit",
    "Dem": "sensor_models.terrain.dem",
    "Geoid": "sensor_models.terrain.geoid",
    "MapImage": "sensor_models.maps.raster",
}

__all__ = sorted([*_EXPORTS, "GcpcalError", "InputError", "__version__"])


def __getattr__(name: str):
    """The public name ``name``, imported from its module on first use."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
