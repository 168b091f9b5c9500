"""How much of a scene (or of one detector array) the reference DEM and DOM cover.

A matcher that finds no GCP on a CCD must say why; the first suspects are references that do
not reach it. Pixel centres on a regular grid over the image (or over one array's columns) are
localized through the current model at one height (the scene's median DEM height, so no DEM
is needed where it has no data) and each ground point is looked up in the DEM (a finite
height) and in the DOM (inside the raster and not no-data). The fractions are of those grid
points: ``1`` means the reference covers the whole footprint, ``0`` none of it. The model's
error (up to the coarse stage's search margin) shifts the footprint, so a fraction is good to
about that margin, plenty to tell "the DEM stops at mid-scene" from "the DEM covers it".
"""

from __future__ import annotations

import numpy as np

__all__ = ["reference_coverage"]


def _grid(n_rows: int, first_col: int, n_cols: int, n_along: int, n_across: int):
    r = np.linspace(0.5, n_rows - 0.5, n_along)
    c = first_col + np.linspace(0.5, n_cols - 0.5, n_across)
    return np.meshgrid(r, c, indexing="ij")


def _ground(model, rows, cols, *, band, height_m, array=None):
    kw = {} if array is None else {"array": array}
    lon, lat, _h = model.image_to_ground(rows.ravel(), cols.ravel(), height=height_m, band=band, **kw)
    return np.asarray(lon), np.asarray(lat)


def _dom_valid(dom, lon, lat, max_cells: int = 512) -> np.ndarray:
    """Whether the DOM has data at each ground point (inside the raster and not no-data)."""
    from sensor_models.maps.grid import MapProjector

    ok = np.isfinite(lon) & np.isfinite(lat)
    out = np.zeros(lon.shape, bool)
    if not ok.any():
        return out
    u, v = MapProjector(dom.grid)(lon[ok], lat[ok])
    n_rows, n_cols = dom.grid.shape
    inside = (u >= -0.5) & (u < n_cols - 0.5) & (v >= -0.5) & (v < n_rows - 0.5)
    if not inside.any():
        return out
    col = np.clip(np.floor(u + 0.5).astype(np.int64), 0, n_cols - 1)
    row = np.clip(np.floor(v + 0.5).astype(np.int64), 0, n_rows - 1)
    r0, r1 = int(row[inside].min()), int(row[inside].max()) + 1
    c0, c1 = int(col[inside].min()), int(col[inside].max()) + 1
    shape = (min(r1 - r0, max_cells), min(c1 - c0, max_cells))
    block = dom.read_decimated(r0, r1, c0, c1, shape)  # a coarse look is enough for a fraction
    bi = np.clip(((row - r0) * shape[0]) // max(r1 - r0, 1), 0, shape[0] - 1)
    bj = np.clip(((col - c0) * shape[1]) // max(c1 - c0, 1), 0, shape[1] - 1)
    valid = inside & np.isfinite(block[bi, bj])
    out[np.flatnonzero(ok)] = valid
    return out


def reference_coverage(model, dem, dom=None, *, band=None, array=None, height_m: float, n_along: int = 24,
                       n_across: int = 12) -> dict:
    """Fractions of a detector array's footprint (or the whole image's) that the DEM and DOM cover.

    Parameters
    ----------
    model : SensorModel
        Current model of the scene.
    dem : Dem
        Terrain heights (a finite height counts as covered).
    dom : MapImage, optional
        Reference orthoimage (inside the raster and not no-data counts as covered).
    band : str, optional
        Band of ``model`` (default: its reference band).
    array : int, optional
        Index of the detector array in ``model.detector_arrays(band)``; None: the whole image.
    height_m : float
        Height (m above the ellipsoid) at which the grid is localized.
    n_along, n_across : int
        Grid points along track (rows) and across track (the array's columns).

    Returns
    -------
    dict
        ``dem`` and ``dom`` (fractions in [0, 1]; ``dom`` None without a DOM).
    """
    n_rows, n_cols = model.image_shape
    first, width, name = 0, n_cols, None
    if array is not None:
        look = model.detector_arrays(band)[array]
        first, width, name = look.first_col, look.n_detectors, look.name
    rows, cols = _grid(n_rows, first, width, n_along, n_across)
    lon, lat = _ground(model, rows, cols, band=band, height_m=height_m,
                       array=name if (array is not None and name) else None)
    with np.errstate(invalid="ignore"):
        dem_ok = np.isfinite(dem.height_m(lon, lat))
    out = {"dem": float(dem_ok.mean()), "dom": None}
    if dom is not None:
        out["dom"] = float(_dom_valid(dom, lon, lat).mean())
    return out
