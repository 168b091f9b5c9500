"""Compare two sensor models of the same image, in pixels, over a dense grid of every CCD and band.

:func:`model_difference` answers: where does a model put the ground that a pixel of the
reference model sees? For every node of a regular grid on every CCD and band, the reference
model localizes the pixel centre on the terrain (or at given heights) and the model under test
projects that ground point back; the difference ``model - reference`` in ``(row, col)`` is the
error. Both models must describe the same image (same bands, CCDs and line count); their
parameters, orbit and attitude may differ. With the TRUE model of a simulated scene as the
reference this is ``gcpcal truth error`` (:func:`sensor_models.simulate.truth.truth_error`, a thin wrapper).
"""

from __future__ import annotations

import numpy as np

from sensor_models.errors import InputError

__all__ = ["model_difference"]


def _grid(n: int, step: float) -> np.ndarray:
    """Pixel centres ``0.5 .. n - 0.5`` every ``step`` pixels, both ends included."""
    k = max(2, int(np.ceil((n - 1) / step)) + 1)
    return np.linspace(0.5, n - 0.5, k)


def model_difference(
    reference_model,
    model,
    *,
    dem=None,
    step_px: float = 16.0,
    heights_m=None,
    bands=None,
) -> dict:
    """Image-space difference of ``model`` from ``reference_model`` over every CCD and band.

    Parameters
    ----------
    reference_model, model : PushbroomModel or GeoStaringModel
        Same image layout (bands, CCD columns, number of lines; or the same frame size).
    dem : Dem, optional
        Terrain on which the reference model localizes the grid pixels.
    step_px : float
        Grid spacing in pixels along rows and columns.
    heights_m : sequence of float, optional
        Ellipsoidal heights (metres) at which to localize instead (every grid pixel at each
        height); default ``(0, 1000, 2000)`` when no DEM is given.
    bands : sequence of str, optional
        Bands to compare (default: all bands of ``reference_model``).

    Returns
    -------
    dict
        ``{"rms_px", "max_px", "mean_row_px", "mean_col_px", "n_points", "per_ccd": [{"band",
        "ccd", "rms_px", "max_px", "mean_row_px", "mean_col_px", "rms_row_px", "rms_col_px",
        "n_points"}, ...], "n_missing", "step_px"}``; errors are ``model - reference``, in pixels.
        Grid points that either model cannot see (off the DEM, behind the other model's CCD) are
        left out and counted in ``"n_missing"``; ``"step_px"`` is the grid spacing.
        ``"compared"`` is ``"ground"``, or ``"lines of sight"`` for staring frames that see no
        ground at all (a frame pointed at the stars): there each pixel's GCRF direction by the
        reference model is projected through ``model`` (a point at infinity).

    Raises
    ------
    InputError
        The models describe different images (size, bands or CCD layout).
    """
    if dem is None and heights_m is None:
        heights_m = (0.0, 1000.0, 2000.0)
    if bands is None:
        bands = tuple(reference_model.bands)
    bands = tuple(bands)
    if tuple(reference_model.image_shape) != tuple(model.image_shape):
        raise InputError(f"the models describe different images ({reference_model.image_shape} and {model.image_shape})")
    rows = _grid(reference_model.image_shape[0], step_px)

    def on_ground(rr, cc, kw):
        return _ground_difference(reference_model, model, rr, cc, kw, dem, heights_m)

    out = _over_arrays(reference_model, model, rows, bands, step_px, on_ground, "ground")
    if out["n_points"] == 0 and _sees_stars(reference_model) and _sees_stars(model):
        out = _over_arrays(reference_model, model, rows, bands, step_px,
                           lambda rr, cc, kw: _line_of_sight_difference(reference_model, model, rr, cc),
                           "lines of sight")
    return out


def _over_arrays(reference_model, model, rows, bands, step_px: float, difference, compared: str) -> dict:
    """:func:`model_difference`'s statistics of ``difference(rows, cols, kw) -> (dr, dc, n_missing)``
    over the grid of every detector array of ``bands`` (``compared`` names the comparison)."""
    per_ccd, all_dr, all_dc, missing = [], [], [], 0
    for band in bands:
        for _, c, kw in _arrays(reference_model, model, band):
            cols = c.first_col + _grid(c.n_detectors, step_px)
            rr, cc = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
            dr, dc, n_missing = difference(rr, cc, kw)
            missing += n_missing
            per_ccd.append(_stats(dr, dc) | {"band": band, "ccd": c.name})
            all_dr.append(dr)
            all_dc.append(dc)
    out = _stats(np.concatenate(all_dr), np.concatenate(all_dc))
    out["n_missing"] = missing
    out["step_px"] = float(step_px)
    out["per_ccd"] = per_ccd
    out["compared"] = compared
    return out


def _sees_stars(model) -> bool:
    """True for a staring model that maps lines of sight (GCRF directions) to pixels and back."""
    return callable(getattr(model, "object_vector_gcrf", None)) and callable(getattr(model, "star_to_image", None))


def _line_of_sight_difference(reference_model, model, rr, cc):
    """Row and column differences over the lines of sight, for a frame that sees no ground (a star frame).

    Each pixel's direction in GCRF by ``reference_model`` is projected through ``model``
    (:meth:`star_to_image`): the pixel error of ``model`` for a point at infinity along that
    line of sight, which is what a star frame can check. Returns the finite differences and the
    number of the others.
    """
    r_m, c_m = model.star_to_image(reference_model.object_vector_gcrf(rr, cc))
    return _finite(r_m - rr, c_m - cc)


def _finite(dr, dc):
    """The differences where both are finite, and how many are not."""
    good = np.isfinite(dr) & np.isfinite(dc)
    return dr[good], dc[good], int((~good).sum())


def _ground_difference(reference_model, model, rr, cc, kw, dem, heights_m):
    """Row and column differences ``model - reference`` at the grid pixels ``rr, cc`` of one array,
    localized by the reference model on ``dem`` or at each of ``heights_m``.

    Returns the differences of the points both models see and the number of the others.
    """
    if dem is not None:
        lon, lat, h = reference_model.image_to_ground(rr, cc, dem=dem, **kw)
        r_obs, c_obs = rr, cc
    else:
        hs = np.repeat(np.asarray(heights_m, dtype=np.float64), rr.size)
        r_obs, c_obs = np.tile(rr, len(heights_m)), np.tile(cc, len(heights_m))
        lon, lat, h = reference_model.image_to_ground(r_obs, c_obs, height=hs, **kw)
    ok = np.isfinite(lon)
    r_m, c_m = np.full(lon.shape, np.nan), np.full(lon.shape, np.nan)
    if ok.any():
        r_m[ok], c_m[ok] = model.ground_to_image(lon[ok], lat[ok], h[ok], **kw)
    return _finite(r_m - r_obs, c_m - c_obs)


def _arrays(reference_model, model, band):
    """(index, detector array, keyword arguments) of every detector array of a band."""
    if band not in model.bands:
        raise InputError(f"band {band!r} is missing from the model under test")
    ref_arrays, arrays = reference_model.detector_arrays(band), model.detector_arrays(band)
    if [(a.first_col, a.n_detectors) for a in ref_arrays] != [(a.first_col, a.n_detectors) for a in arrays]:
        raise InputError(f"band {band!r}: the models have different detector-array layouts")
    return [(i, a, {"band": band, "array": i}) for i, a in enumerate(ref_arrays)]


def _stats(dr, dc) -> dict:
    if dr.size == 0:
        return {"rms_px": None, "max_px": None, "mean_row_px": None, "mean_col_px": None,
                "rms_row_px": None, "rms_col_px": None, "n_points": 0}
    d = np.hypot(dr, dc)
    return {
        "rms_px": float(np.sqrt(np.mean(d * d))),
        "max_px": float(d.max()),
        "mean_row_px": float(dr.mean()),
        "mean_col_px": float(dc.mean()),
        "rms_row_px": float(np.sqrt(np.mean(dr * dr))),
        "rms_col_px": float(np.sqrt(np.mean(dc * dc))),
        "n_points": int(d.size),
    }
