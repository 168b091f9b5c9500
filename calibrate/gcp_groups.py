"""The GCPs of a calibration as point arrays, grouped by band and CCD, and which interiors are estimable.

:func:`as_points` validates the point arrays of :func:`calibrate.absolute.calibrate_model` and
gives their prior weights ``score / sigma_px^2``. :func:`group_points` sorts the points into
groups by model kind: one per band and CCD of a push-broom model (the CCD named in the table or
the one whose columns hold the point), one frame of an area-array staring camera, or a single
group for a model without CCDs (RPC...); each group carries the interior parameter names of its
CCD. :func:`mark_estimable` flags the groups whose interior can be estimated (enough points,
spread over enough of the detectors) and returns a skip record for each of the others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError

__all__ = ["as_points", "group_points", "mark_estimable"]


@dataclass
class _Group:
    """Points of one band and CCD (or of the whole frame), and the CCD's interior parameters."""

    band: object  # band name or None
    ccd: int  # CCD index in the band, -1 for models without CCDs
    ccd_name: str
    idx: np.ndarray  # point indices (input order)
    interior: tuple = ()  # interior parameter names of this CCD (estimable or not)
    estimable: bool = False


def as_points(row, col, lon, lat, h, sigma_px, score, score_weight=True):
    """Point arrays and prior weights: ``score / sigma_px^2``, or ``1 / sigma_px^2`` with
    ``score_weight=False`` (a score of 0 still drops the point).

    Parameters
    ----------
    row, col : array_like, shape (N,)
        Observed image coordinates, px.
    lon, lat, h : array_like, shape (N,)
        Ground points (WGS84 degrees, metres above the ellipsoid).
    sigma_px : array_like or float or None
        Standard deviations, px (default 1).
    score : array_like or float or None
        Matching scores, >= 0 (default 1).
    score_weight : bool
        Weigh by the score (else a score only drops the points where it is 0).

    Returns
    -------
    points : dict of str to ndarray
        ``row, col, lon, lat, h``, shape (N,) each.
    weight : ndarray, shape (N,)
        Prior weights, 1/px^2.

    Raises
    ------
    InputError
        No points, arrays of different lengths, non-finite values, bad ``sigma_px``/``score``.
    """
    arrays = {}
    for name, a in (("row", row), ("col", col), ("lon", lon), ("lat", lat), ("h", h)):
        a = np.asarray(a, dtype=np.float64).reshape(-1)
        arrays[name] = a
    n = arrays["row"].size
    if n == 0:
        raise InputError("no GCPs given")
    for name, a in arrays.items():
        if a.size != n:
            raise InputError(f"{name} has {a.size} values for {n} GCPs", field=name)
        if not np.all(np.isfinite(a)):
            raise InputError("holds NaN or infinite values", field=name)
    weight = np.ones(n)
    if sigma_px is not None:
        s = _per_point_float(sigma_px, n)
        if s.size != n or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
            raise InputError(f"needs {n} positive finite values", field="sigma_px")
        weight = weight / s**2
    if score is not None:
        q = _per_point_float(score, n)
        if q.size != n or not np.all(np.isfinite(q)) or np.any(q < 0.0):
            raise InputError(f"needs {n} finite values >= 0", field="score")
        weight = weight * (q if score_weight else (q > 0.0))
    return arrays, np.ascontiguousarray(weight)


def _per_point_float(value, n):
    a = np.asarray(value, dtype=np.float64)
    return np.full(n, float(a)) if a.ndim == 0 else a.reshape(-1)


def _per_point(value, n, field_name):
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or np.ndim(value) == 0:
        return np.full(n, value, dtype=object)
    arr = np.asarray(value).reshape(-1)
    if arr.size != n:
        raise InputError(f"has {arr.size} values for {n} GCPs", field=field_name)
    return arr


def _pushbroom_groups(model, points, band, ccd, interior_terms):
    n = points["row"].size
    bands = _per_point(band, n, "band")
    if bands is None:
        bands = np.full(n, model.reference_band, dtype=object)
    bands = np.asarray(bands).astype(str)
    unknown = sorted(set(np.unique(bands)) - set(model.bands))
    if unknown:
        known = ", ".join(model.bands)
        raise InputError(f"unknown band(s) {', '.join(unknown)}; the model has {known}", field="band")
    present = [b for b in model.bands if np.any(bands == b)]
    ccds = _per_point(ccd, n, "ccd")
    ccd_idx = np.empty(n, dtype=np.intp)
    for b in present:
        sel = np.nonzero(bands == b)[0]
        look = model.detector_arrays(b)
        if ccds is None:
            ccd_idx[sel] = model.detector_index(points["col"][sel], band=b).reshape(-1)
            continue
        names = [c.name for c in look]
        values = ccds[sel]
        # resolve each distinct value once: a CCD name, an index, or missing (None, "", NaN:
        # the CCD whose columns hold the point)
        unique, inverse = np.unique(values.astype(str), return_inverse=True)
        from_col = model.detector_index(points["col"][sel], band=b).reshape(-1)
        resolved = np.array([_resolve_ccd(v, names, b) for v in unique], dtype=np.intp)
        chosen = resolved[inverse.reshape(-1)]
        ccd_idx[sel] = np.where(chosen < 0, from_col, chosen)
    all_names = set(model.parameter_names())
    groups = []
    for b in present:
        in_band = bands == b
        for ci, look in enumerate(model.detector_arrays(b)):
            idx = np.nonzero(in_band & (ccd_idx == ci))[0]
            if idx.size == 0:
                continue
            interior = _interior_names(b, look, interior_terms, all_names)
            groups.append(_Group(b, ci, look.name, idx, interior))
    return groups, bands, ccd_idx


def _staring_groups(model, points, band, ccd, interior_terms):
    """One group (the whole frame) for an area-array staring camera (20-coefficient interior)."""
    n = points["row"].size
    if ccd is not None and not all(str(v) in ("", "None", "nan", "-1") for v in np.atleast_1d(ccd)):
        raise InputError("ccd does not apply to an area-array camera", field="ccd")
    bands = _per_point(band, n, "band")
    if bands is not None:
        other = sorted(set(np.asarray(bands).astype(str)) - {model.band, "", "None"})
        if other:
            raise InputError(f"unknown band(s) {', '.join(other)}; the camera has {model.band}", field="band")
    if isinstance(interior_terms, (int, np.integer)):
        if interior_terms < 0:
            raise InputError("must be >= 0", field="interior_terms")
        interior = tuple(model.interior_parameter_names(min(int(interior_terms), 3)))
    else:
        interior = tuple(t if t.startswith("interior.") else f"interior.{t}" for t in interior_terms)
        bad = [t for t in interior if t not in set(model.parameter_names())]
        if bad:
            raise InputError(f"unknown interior terms {', '.join(bad)}", field="interior_terms")
    groups = [_Group(model.band, -1, "frame", np.arange(n), interior)]
    return groups, np.full(n, model.band, dtype=object), np.full(n, -1, dtype=np.intp)


def _check_estimable_staring(model, group, weight, points, min_points_factor, min_span_fraction):
    """Whether the frame's interior can be estimated: enough points spread over the frame."""
    used = group.idx[weight[group.idx] > 0.0]
    n_unknown = len(group.interior)
    needed = int(math.ceil(min_points_factor * n_unknown))
    if used.size:
        u, v = model.normalized(points["row"][used], points["col"][used])
        span = float(min(np.ptp(u), np.ptp(v)) / 2.0)
    else:
        span = 0.0
    record = {"band": group.band, "ccd": group.ccd_name, "n_points": int(used.size), "needed": needed, "span": span}
    if n_unknown == 0:
        return None
    if used.size < needed:
        record["reason"] = (f"{group.band}: {used.size} GCPs < {needed} needed ({min_points_factor:g} x "
                            f"{n_unknown} unknowns); the interior is not estimated")
        return record
    needs_span = any(not (n.endswith("a00") or n.endswith("b00")) for n in group.interior)
    if needs_span and span < min_span_fraction:
        record["reason"] = (f"{group.band}: GCPs span {100 * span:.0f} % of the frame < "
                            f"{100 * min_span_fraction:.0f} %; the interior is not estimated")
        return record
    group.estimable = True
    return None


def _resolve_ccd(value: str, names, band) -> int:
    """CCD index of a name or an index given as text; -1 for a missing value."""
    if value in ("None", "", "nan"):
        return -1
    if value in names:
        return names.index(value)
    try:
        number = float(value)
    except ValueError:
        raise InputError(f"unknown CCD {value!r} of band {band}; it has {', '.join(names)}", field="ccd") from None
    if not number.is_integer() or not 0 <= number < len(names):
        raise InputError(f"CCD index {value} out of range 0..{len(names) - 1} for band {band}", field="ccd")
    return int(number)


def _interior_names(band, look, terms, all_names):
    if isinstance(terms, (int, np.integer)):
        if terms < 0:
            raise InputError("must be >= 0", field="interior_terms")
        names = [
            f"{band}.{look.name}.{axis}.c{k}"
            for axis in ("tan_psi_x", "tan_psi_y")
            for k in range(min(int(terms) + 1, getattr(look, axis).size))
        ]
    else:
        names = [f"{band}.{look.name}.{t}" for t in terms]
        bad = [n for n in names if n not in all_names]
        if bad:
            raise InputError(f"unknown interior terms {', '.join(bad)}", field="interior_terms")
    return tuple(names)


def _check_estimable(model, group, weight, points, min_points_factor, min_span_fraction):
    """Decide whether a CCD's interior can be estimated; a skip record if not."""
    col = points["col"]
    look = model.detector_arrays(group.band)[group.ccd]
    used = group.idx[weight[group.idx] > 0.0]
    n_unknown = len(group.interior)
    needed = int(math.ceil(min_points_factor * n_unknown))
    s = look.detector_index(col[used])
    span = float((s.max() - s.min()) / max(look.n_detectors - 1, 1)) if used.size else 0.0
    needs_span = any(not n.endswith(".c0") for n in group.interior)
    record = {
        "band": group.band,
        "ccd": group.ccd_name,
        "n_points": int(used.size),
        "needed": needed,
        "span": span,
    }
    if n_unknown == 0:
        return None
    if used.size < needed:
        record["reason"] = (
            f"{group.band}.{group.ccd_name}: {used.size} GCPs < {needed} needed "
            f"({min_points_factor:g} x {n_unknown} unknowns); its interior is not estimated"
        )
        return record
    if needs_span and span < min_span_fraction:
        record["reason"] = (
            f"{group.band}.{group.ccd_name}: GCPs span {100 * span:.0f} % of its detectors "
            f"< {100 * min_span_fraction:.0f} %; its interior is not estimated"
        )
        return record
    group.estimable = True
    return None


def _blank_to_none(column: np.ndarray):
    """A text column of the table, or None when every entry is empty."""
    return None if np.all(column == "") else column


def group_points(model, points, table, options):
    """Groups of points (band, CCD) by model kind; per-point band names and CCD indices.

    Parameters
    ----------
    model : SensorModel
        The model calibrated (its ``interior_layout`` decides the grouping).
    points : dict of str to ndarray
        Of :func:`as_points`.
    table : GcpTable
        The fitted GCPs (their ``band`` and ``ccd`` columns; empty text means unset).
    options : CalibrationOptions
        ``scheme``, ``interior_terms`` and ``parameters``.

    Returns
    -------
    groups : list
        One group per band and CCD with points (``band, ccd, ccd_name, idx, interior,
        estimable``).
    bands : ndarray, shape (N,)
        Band name of each point.
    ccd_idx : ndarray of int, shape (N,)
        CCD index of each point (-1 for models without CCDs).

    Raises
    ------
    InputError
        Unknown bands, CCDs or interior terms; a scheme or option the model does not support.
    """
    band, ccd = _blank_to_none(table.band), _blank_to_none(table.ccd)
    scheme = options.scheme
    layout = model.interior_layout
    if layout == "frame":
        groups, bands, ccd_idx = _staring_groups(model, points, band, ccd, options.interior_terms)
    elif layout == "per_array":
        if band is not None:
            band = np.where(band == "", model.reference_band, band)
        groups, bands, ccd_idx = _pushbroom_groups(model, points, band, ccd, options.interior_terms)
    else:
        groups, bands, ccd_idx = _single_group(model, points, band, ccd, scheme)
    if options.parameters is not None and scheme != "joint":
        raise InputError("parameters= applies to scheme='joint' only", field="parameters")
    return groups, bands, ccd_idx


def _single_group(model, points, band, ccd, scheme):
    """One group for a model without CCDs (RPC...): joint scheme only, one band at most."""
    n = points["row"].size
    if scheme != "joint":
        raise InputError(
            f"scheme {scheme!r} needs a push-broom model (installation and directional angles); "
            f"use scheme='joint' for a {getattr(model, 'kind', type(model).__name__)} model",
            field="scheme",
        )
    if ccd is not None:
        raise InputError("ccd applies to push-broom models only", field="ccd")
    if band is not None:
        names = set(np.unique(band)) - {""}
        if len(names) > 1:
            raise InputError("a single band for this model", field="band")
        band = names.pop() if names else None
    groups = [_Group(band, -1, "", np.arange(n))]
    return groups, np.full(n, band, dtype=object), np.full(n, -1, dtype=np.intp)


def mark_estimable(model, groups, weight, points, options):
    """Flag the groups whose interior can be estimated; skip records of the others.

    Parameters
    ----------
    model : SensorModel
        The model calibrated.
    groups : list
        Of :func:`group_points`; their ``estimable`` flags are set in place.
    weight : ndarray, shape (N,)
        Prior weights of the points (a zero weight does not count).
    points : dict of str to ndarray
        Of :func:`as_points`.
    options : CalibrationOptions
        ``min_points_factor`` and ``min_span_fraction``.

    Returns
    -------
    list of dict
        ``band, ccd, n_points, needed, span, reason`` of each CCD whose interior is not
        estimated (empty for models without an interior).
    """
    layout = model.interior_layout
    if layout == "per_array":
        check = _check_estimable
    elif layout == "frame":
        check = _check_estimable_staring
    else:
        return []
    skipped = []
    for g in groups:
        rec = check(model, g, weight, points, options.min_points_factor, options.min_span_fraction)
        if rec is not None:
            skipped.append(rec)
    return skipped
