"""Error of a model against the TRUE model of a simulated scene, in pixels (``gcpcal truth error``).

The comparison itself is production code, :func:`sensor_models.models.compare.model_difference`; this
module names its use with the simulator's TRUE model as the reference.
"""

from __future__ import annotations

from sensor_models.models.compare import model_difference

__all__ = ["truth_error"]


def truth_error(true_model, model, *, dem=None, heights_m=None, step_px: float = 16.0, bands=None) -> dict:
    """Image-space error of ``model`` against ``true_model`` over a grid of every CCD and band.

    Parameters
    ----------
    true_model, model : PushbroomModel or GeoStaringModel
        The TRUE model of a simulated scene and the model under test (same image layout).
    dem : Dem, optional
        Terrain on which the TRUE model localizes the grid pixels.
    heights_m : sequence of float, optional
        Ellipsoidal heights (metres) at which to localize instead; default ``(0, 1000, 2000)``
        when no DEM is given.
    step_px : float
        Grid spacing in pixels along rows and columns.
    bands : sequence of str, optional
        Bands to compare (default: all bands of ``true_model``).

    Returns
    -------
    dict
        :func:`sensor_models.models.compare.model_difference`'s statistics; errors are
        ``model - truth`` in pixels.
    """
    return model_difference(true_model, model, dem=dem, step_px=step_px, heights_m=heights_m, bands=bands)
