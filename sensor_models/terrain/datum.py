"""What a DEM's coordinate reference system says: its vertical datum and its horizontal part.

A DEM's heights refer to the WGS84 ellipsoid or to EGM96 (:data:`VERTICAL_DATUMS`). The
datum is declared by the raster's CRS (:func:`declared_datum`: a compound CRS with an EGM96
vertical part, a 3-D geographic CRS), by a ``VERTICAL_DATUM`` metadata item
(:func:`tagged_datum`), or by the caller (:func:`check_datum_name`).
"""

from __future__ import annotations

import pyproj

from sensor_models.errors import DemError, InputError

__all__ = ["VERTICAL_DATUMS", "VERTICAL_DATUM_TAG", "check_datum_name", "declared_datum", "horizontal_crs",
           "tagged_datum"]


#: Vertical datums a DEM may declare: heights above the WGS84 ellipsoid, or EGM96 orthometric.
VERTICAL_DATUMS = ("ellipsoid", "egm96")
#: EPSG codes of vertical reference systems recognised in raster metadata.
_EPSG_EGM96_HEIGHT = 5773


def check_datum_name(vertical_datum):
    """A caller's ``vertical_datum``, lower-cased and checked against :data:`VERTICAL_DATUMS`.

    Returns
    -------
    str or None
        ``"ellipsoid"`` or ``"egm96"``; None when the caller said nothing (None).

    Raises
    ------
    InputError
        When it names another datum.
    """
    if vertical_datum is None:
        return None
    name = str(vertical_datum).lower()
    if name not in VERTICAL_DATUMS:
        raise InputError(
            f"vertical_datum must be one of {', '.join(VERTICAL_DATUMS)}, got {vertical_datum!r}"
        )
    return name


def declared_datum(crs: pyproj.CRS | None, *, source):
    """The vertical datum a CRS declares: 'ellipsoid', 'egm96' or None (declares nothing)."""
    if crs is None:
        return None
    if crs.is_compound:
        vertical = [c for c in crs.sub_crs_list if c.is_vertical]
        if not vertical:
            return None
        vcrs = vertical[0]
        if vcrs.to_epsg() == _EPSG_EGM96_HEIGHT or "egm96" in vcrs.name.lower():
            return "egm96"
        raise DemError(
            f"{source}: heights refer to {vcrs.name!r}, which gcpcal cannot convert; "
            "convert the DEM to WGS84 ellipsoidal or EGM96 heights first"
        )
    if crs.is_geographic and len(crs.axis_info) == 3:
        return "ellipsoid"
    return None
#: GDAL metadata item by which a raster in a projected CRS declares its vertical datum
VERTICAL_DATUM_TAG = "VERTICAL_DATUM"


def tagged_datum(path):
    """The datum declared by the raster's ``VERTICAL_DATUM`` metadata item, or None.

    A projected CRS cannot carry "heights above the WGS84 ellipsoid" in a standard compound
    CRS, so gcpcal's own DEMs (and any user's) may say ``VERTICAL_DATUM=ellipsoid`` (or
    ``egm96``) in the dataset's default metadata domain.
    """
    import rasterio

    with rasterio.open(path) as ds:
        value = ds.tags().get(VERTICAL_DATUM_TAG)
    if value is None:
        return None
    name = value.strip().lower()
    if name not in VERTICAL_DATUMS:
        raise DemError(
            f"{path}: metadata {VERTICAL_DATUM_TAG}={value!r} is not one of {', '.join(VERTICAL_DATUMS)}"
        )
    return name


def horizontal_crs(crs: pyproj.CRS) -> pyproj.CRS:
    """The horizontal part of ``crs``: the first part of a compound CRS, the 2-D form of a 3-D one."""
    if crs.is_compound:
        return crs.sub_crs_list[0]
    if len(crs.axis_info) == 3:
        return crs.to_2d()
    return crs
