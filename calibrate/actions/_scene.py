"""Reading a scene for a stage: the model cropped to the raster the user gave."""

from __future__ import annotations

from sensor_models.errors import InputError

__all__ = ["crop_to_raster"]


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
    SensorModel
        The model of the crop.

    Raises
    ------
    InputError
        When the raster carries no pixel geotransform.
    """
    import rasterio

    with rasterio.open(image) as ds:
        t, crs = ds.transform, ds.crs
    if crs is None and abs(t.a - 1) < 1e-12 and abs(t.e - 1) < 1e-12 and t.b == 0 and t.d == 0:
        return model.cropped(t.f, t.c, shape)
    raise InputError(f"the raster is {shape[0]} x {shape[1]} px but the model describes {model.image_shape}; "
                     "a crop must carry a pixel geotransform (1, 0, col0, 0, 1, row0)", path=str(image))
