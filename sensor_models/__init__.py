"""Rigorous sensor models: frames, orbit and attitude, push-broom and RPC models, terrain.

The lowest layer of gcpcal: it knows nothing of matching or calibration and exposes model
parameters with their analytic Jacobians. Conventions (see ``docs/conventions.md``):
image coordinates are ``(row, col)`` with the first pixel's centre at ``(0.5, 0.5)``; ground
points are WGS84 ``lon, lat`` in degrees and ``h`` in metres above the ellipsoid; angles are
radians; times are seconds (SI) since a UTC scene epoch.
"""

from sensor_models.errors import GcpcalError

__version__ = "0.1.0"

__all__ = ["GcpcalError", "__version__", "open_model"]


def open_model(path, **kwargs):
    """Open any supported model file (:func:`sensor_models.readers.open_model`).

    Parameters
    ----------
    path : str or os.PathLike
        A gcpcal scene manifest (``*.json``), a SPOT 1-5 DIMAP (``*.DIM``), an OSSIM keyword
        list (``*.geom``), an ``*.RPB`` / ``*_RPC.TXT`` file, or a raster carrying RPC tags.
    **kwargs
        Passed on to the reader (e.g. ``attitude=`` of the DIMAP reader).

    Returns
    -------
    SensorModel
    """
    from sensor_models.readers import open_model as _open_model

    return _open_model(path, **kwargs)
