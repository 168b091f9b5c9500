"""Reading a GCP table from any of its files: the extension picks CSV, GeoPackage or GeoTIFF.

:func:`read_gcps` hands the file to :func:`gcpmatch.gcp_csv.read_gcps_csv`,
:func:`gcpmatch.geopackage.read_gcps_gpkg` or :func:`gcpmatch.gcp_geotiff.read_gcps_geotiff`;
each of those modules documents its format and holds the matching writer.
"""

from __future__ import annotations

from pathlib import Path

from gcpmatch.gcp_csv import read_gcps_csv
from gcpmatch.gcp_geotiff import read_gcps_geotiff
from gcpmatch.gcps import GcpTable, check_image_shape
from gcpmatch.geopackage import read_gcps_gpkg
from sensor_models.errors import InputError

__all__ = ["read_gcps"]


def read_gcps(path, *, image_shape=None, layer=None) -> GcpTable:
    """Read a GCP table from CSV (``*.csv``), GeoPackage (``*.gpkg``) or GeoTIFF (``*.tif``).

    Parameters
    ----------
    path : str or Path
        The file; its extension selects the format.
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``: points outside ``[0, n_rows] x [0, n_cols]`` are errors. For a
        GeoTIFF the raster's own shape is used when not given (and must agree when given).
    layer : str, optional
        GeoPackage only: the features layer. Default: the only one, else ``"gcps"``.

    Returns
    -------
    GcpTable

    Raises
    ------
    InputError
        One line naming the file, the place (CSV line number, header = line 1; GeoPackage
        feature id; GeoTIFF GCP number), the column and the problem.
    """
    path = Path(path)
    image_shape = check_image_shape(image_shape)
    suffix = path.suffix.lower()
    if layer is not None and suffix != ".gpkg":
        raise InputError("layer= applies to GeoPackage (*.gpkg) files only", path=str(path))
    if suffix == ".csv":
        return read_gcps_csv(path, image_shape)
    if suffix == ".gpkg":
        return read_gcps_gpkg(path, image_shape, layer)
    if suffix in (".tif", ".tiff"):
        return read_gcps_geotiff(path, image_shape)
    raise InputError("unknown GCP table format; expected *.csv, *.gpkg, *.tif or *.tiff",
                     path=str(path))  # fmt: skip
