"""The one interface every sensor model implements.

A :class:`SensorModel` maps image coordinates ``(row, col)`` to WGS84 ground coordinates
``(lon, lat, h)`` and back, and exposes its calibration parameters with analytic Jacobians.
Image coordinates follow GDAL/rasterio: the first pixel's centre is ``(0.5, 0.5)``; rows are
image lines (along track for a push-broom), columns are samples.

Besides localization, the protocol describes the model's structure, so that callers never test
a model's type:

* bands: :attr:`SensorModel.bands` and :attr:`SensorModel.reference_band`. A model without
  named bands (an RPC) has ``bands == (None,)`` and ``reference_band is None``: ``band=None``
  is every method's "default band", so ``for b in model.bands: model.image_to_ground(...,
  band=b)`` works with any model.
* detector arrays: :meth:`SensorModel.detector_arrays` splits a band's image columns into the
  arrays that imaged them (the CCDs of a push-broom, one array covering the image otherwise,
  named ``""``, the GCP table's "no CCD" value); :meth:`SensorModel.detector_index` tells
  which array images a column; :meth:`SensorModel.detector_view` is one array as a model of
  its own image. ``array=`` (an array's name or its index in ``detector_arrays(band)``) forces
  the array in the localization methods.
* parameters: :meth:`SensorModel.parameter_groups` partitions :meth:`SensorModel.parameters`
  into named groups. The group names are ``"exterior"`` (installation angles) and
  ``"interior.<band>.<array>"`` (directional-angle coefficients of one CCD in one band) for the
  push-broom model, ``"exterior"`` and ``"interior"`` for the staring camera, ``"bias"`` for
  the RPC's image-space bias correction, and ``"parameters"`` (everything) by default.
  :attr:`SensorModel.is_rigorous` says whether the model is a physical one (exterior and
  interior parameters) rather than a fitted approximation such as an RPC.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError

__all__ = ["CALIBRATION_STATUSES", "WHOLE_IMAGE", "CalibrationStatus", "DetectorArray", "ParameterVector", "SensorModel",
           "array_positions", "as_float_arrays"]

#: name of the one detector array of a model whose image is not split into arrays
WHOLE_IMAGE = ""


@dataclass(frozen=True)
class ParameterVector:
    """Named calibration parameters of a model.

    Attributes
    ----------
    names : tuple of str
        One name per parameter, e.g. ``"installation.yaw"`` or ``"B2.ccd1.tan_psi_y.c1"``.
        Names carry units when they are not radians, metres or dimensionless.
    values : ndarray, shape (P,)
    """

    names: tuple[str, ...]
    values: np.ndarray

    def __post_init__(self):
        values = np.asarray(self.values, dtype=np.float64).reshape(-1)
        if values.shape[0] != len(self.names):
            raise ValueError(f"{len(self.names)} names for {values.shape[0]} values")
        object.__setattr__(self, "values", values)

    def __len__(self) -> int:
        return len(self.names)

    def as_dict(self) -> dict[str, float]:
        """The parameters as a mapping.

        Returns
        -------
        dict of str to float
            ``{name: value}`` in the order of :attr:`names`.
        """
        return {n: float(v) for n, v in zip(self.names, self.values)}

    def index(self, names) -> np.ndarray:
        """Positions of ``names`` in this vector.

        Parameters
        ----------
        names : iterable of str
            Parameter names, each one of :attr:`names`.

        Returns
        -------
        ndarray of intp, shape (len(names),)

        Raises
        ------
        KeyError
            Listing the names that are not parameters of this vector.
        """
        lookup = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise KeyError(f"unknown parameters: {', '.join(missing)}")
        return np.array([lookup[n] for n in names], dtype=np.intp)


@dataclass(frozen=True)
class DetectorArray:
    """A run of image columns imaged by one detector array (a CCD, or a whole area array).

    Attributes
    ----------
    name : str
        Unique within a band (e.g. ``"ccd1"``); ``""`` (:data:`WHOLE_IMAGE`) for the one array
        of a model whose image is not split into arrays.
    first_col : int
        Image column of the array's first detector (its left edge, so the first detector's
        centre is at ``first_col + 0.5``).
    n_detectors : int
        Number of detectors, i.e. of image columns the array covers.
    """

    name: str
    first_col: int
    n_detectors: int

    def __post_init__(self):
        if int(self.n_detectors) < 1:
            raise InputError("must be >= 1", field=f"detector array {self.name!r}.n_detectors")
        if int(self.first_col) < 0:
            raise InputError("must be >= 0", field=f"detector array {self.name!r}.first_col")
        object.__setattr__(self, "name", str(self.name))
        object.__setattr__(self, "n_detectors", int(self.n_detectors))
        object.__setattr__(self, "first_col", int(self.first_col))

    @property
    def last_col(self) -> int:
        """One past the array's last image column (``first_col + n_detectors``)."""
        return self.first_col + self.n_detectors


def as_float_arrays(*arrays, names=None):
    """Broadcast inputs to float64 arrays of one shape; reject non-finite values.

    Parameters
    ----------
    *arrays : array_like
        Inputs broadcastable to one shape.
    names : sequence of str, optional
        The inputs' names, for the error message.

    Returns
    -------
    list of ndarray
        C-contiguous float64 arrays, all of the broadcast shape.

    Raises
    ------
    InputError
        If an input holds NaN or infinity (naming it).
    """
    out = np.broadcast_arrays(*[np.asarray(a, dtype=np.float64) for a in arrays])
    for i, a in enumerate(out):
        if not np.all(np.isfinite(a)):
            label = names[i] if names else f"argument {i}"
            raise InputError(f"{label} holds NaN or infinite values")
    return [np.ascontiguousarray(a) for a in out]


def array_positions(arrays, array, shape, *, noun: str = "detector array", field: str = "array") -> np.ndarray:
    """Indices in ``arrays`` of ``array`` (a name, an index, or one of those per point).

    Parameters
    ----------
    arrays : sequence of DetectorArray
        The detector arrays of a band.
    array : str, int or array_like of those
        Which array: a name, an index, or one per point.
    shape : tuple of int
        Shape of the result (the points').
    noun, field : str
        How errors name the array (e.g. ``"CCD"``) and the keyword (e.g. ``"ccd"``).

    Returns
    -------
    ndarray of intp, shape ``shape``

    Raises
    ------
    InputError
        An unknown name or an index out of range.
    """
    names = [a.name for a in arrays]
    listed = ", ".join(repr(n) for n in names)
    if isinstance(array, str):
        if array not in names:
            raise InputError(f"unknown {noun} {array!r}; the band has {listed}", field=field)
        return np.full(shape, names.index(array), dtype=np.intp)
    arr = np.asarray(array)
    if arr.dtype.kind in "USO":  # names, one per point
        lookup = {n: i for i, n in enumerate(names)}
        flat = arr.reshape(-1).astype(str)
        unknown = sorted(set(flat) - set(lookup))
        if unknown:
            raise InputError(f"unknown {noun} {unknown[0]!r}; the band has {listed}", field=field)
        arr = np.array([lookup[n] for n in flat], dtype=np.intp).reshape(arr.shape)
    idx = np.broadcast_to(np.asarray(arr, dtype=np.intp), shape).copy()
    if np.any((idx < 0) | (idx >= len(arrays))):
        raise InputError(f"{noun} index out of range 0..{len(arrays) - 1}", field=field)
    return idx


#: outcomes of a calibration, as recorded in the model it wrote
CALIBRATION_STATUSES = ("calibrated", "partial", "failed")


@dataclass(frozen=True)
class CalibrationStatus:
    """What a calibration run achieved, carried by the model it wrote (manifest ``calibration``).

    Every command that uses a model checks it: a ``failed`` calibration is refused, a
    ``partial`` one is used with a warning naming what is not calibrated. A model that no
    calibration wrote (a LAB model, a vendor product) has no status (``model.calibration`` is
    None).

    Attributes
    ----------
    status : {"calibrated", "partial", "failed"}
        ``calibrated``: every band and detector array calibrated and verified on check points;
        ``partial``: some arrays are not calibrated (not estimable) or not verified (no check
        points); ``failed``: the estimation failed and the parameters must not be used.
    message : str
        One line: why, for ``partial`` and ``failed``.
    uncalibrated : tuple of dict
        ``{"band", "ccd", "reason"}`` of every detector array whose parameters were not
        estimated.
    unverified : tuple of dict
        ``{"band", "ccd", "reason"}`` of every detector array without check points.
    """

    status: str
    message: str = ""
    uncalibrated: tuple = ()
    unverified: tuple = ()

    def __post_init__(self):
        if self.status not in CALIBRATION_STATUSES:
            raise InputError(f"must be one of {', '.join(CALIBRATION_STATUSES)}, got {self.status!r}",
                             field="calibration.status")
        for name in ("uncalibrated", "unverified"):
            entries = tuple({"band": str(e.get("band", "")), "ccd": str(e.get("ccd", "")),
                             "reason": str(e.get("reason", ""))} for e in getattr(self, name))
            object.__setattr__(self, name, entries)

    @property
    def usable(self) -> bool:
        """Whether the model may be used (``calibrated`` or ``partial``)."""
        return self.status != "failed"

    def to_dict(self) -> dict:
        """The manifest's ``calibration`` object.

        Returns
        -------
        dict
            ``status``, ``message``, ``uncalibrated``, ``unverified`` (lists of dicts).
        """
        return {"status": self.status, "message": self.message,
                "uncalibrated": [dict(e) for e in self.uncalibrated],
                "unverified": [dict(e) for e in self.unverified]}


class SensorModel(abc.ABC):
    """Abstract sensor model: ground <-> image mapping plus parameters and Jacobians.

    Subclasses implement the abstract localization and parameter methods; the structural part of
    the protocol (bands, detector arrays, parameter groups; module docstring) has defaults for a
    single-band model whose image is one detector array.
    """

    #: short model kind, e.g. ``"pushbroom"``, ``"rpc"``, ``"geo_staring"``
    kind: str = "abstract"
    #: outcome of the calibration that wrote this model, None when no calibration did
    calibration: CalibrationStatus | None = None
    #: True for a physical model (exterior and interior parameters), False for a fitted
    #: approximation such as an RPC
    is_rigorous: bool = False

    @property
    @abc.abstractmethod
    def image_shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)`` of the image this model describes."""

    @abc.abstractmethod
    def image_to_ground(self, row, col, *, height=None, dem=None, band=None, array=None):
        """Direct localization: image coordinates to ground coordinates.

        Parameters
        ----------
        row, col : array_like, shape (N,)
            Continuous image coordinates (first pixel centre at 0.5).
        height : float or array_like, optional
            Ellipsoidal height in metres of the ground surface (exclusive with ``dem``).
        dem : sensor_models.terrain.dem.Dem, optional
            Terrain to intersect.
        band : str, optional
            Spectral band for multi-band models (default: :attr:`reference_band`).
        array : str or int or array_like, optional
            Detector array (name or index in :meth:`detector_arrays`, or one per point) whose
            geometry maps the points; default: the one that images each column.

        Returns
        -------
        lon_deg, lat_deg, h_m : ndarray, shape (N,)
        """

    @abc.abstractmethod
    def ground_to_image(self, lon, lat, h, *, band=None, array=None):
        """Inverse localization: ground coordinates to continuous image coordinates.

        Parameters
        ----------
        lon, lat : array_like, shape (N,)
            WGS84 longitude and latitude, degrees.
        h : array_like, shape (N,)
            Height above the WGS84 ellipsoid, metres.
        band : str, optional
            Spectral band (default: :attr:`reference_band`).
        array : str or int or array_like, optional
            Detector array to project into (as in :meth:`image_to_ground`).

        Returns
        -------
        row, col : ndarray, shape (N,)
        """

    @abc.abstractmethod
    def parameters(self) -> ParameterVector:
        """The calibration parameters and their current values.

        Returns
        -------
        ParameterVector
            Names in the order of :meth:`parameter_names`.
        """

    @abc.abstractmethod
    def with_parameters(self, values) -> "SensorModel":
        """A copy of this model with new parameter values.

        Parameters
        ----------
        values : array_like, shape (P,)
            In the order of :meth:`parameters`.

        Returns
        -------
        SensorModel
        """

    @abc.abstractmethod
    def image_jacobian(self, lon, lat, h, *, band=None, names=None, array=None):
        """Analytic partial derivatives of ``ground_to_image`` with respect to the parameters.

        Parameters
        ----------
        lon, lat, h : array_like, shape (N,)
            Ground points (degrees, degrees, metres above the ellipsoid).
        band : str, optional
            Spectral band (default: :attr:`reference_band`).
        names : sequence of str, optional
            Parameters to differentiate with respect to (default: all).
        array : str or int or array_like, optional
            Detector array to project into (as in :meth:`image_to_ground`).

        Returns
        -------
        row, col : ndarray, shape (N,)
            The projections of the ground points.
        jac : ndarray, shape (N, 2, P)
            ``d(row, col) / d(parameter)`` for the parameters ``names`` (default: all).
        """

    # ------------------------------------------------------------------ bands
    @property
    def reference_band(self) -> str | None:
        """The band used when a method gets ``band=None``; None for a model without bands."""
        return None

    @property
    def bands(self):
        """The model's band names, in order.

        Returns
        -------
        tuple of (str or None)
            ``(reference_band,)`` by default, i.e. ``(None,)`` for a model without named bands.
            Multi-band models may return a read-only mapping keyed by band name (iteration,
            ``in``, ``len`` and ``tuple()`` then behave as for the tuple).
        """
        return (self.reference_band,)

    def _protocol_band(self, band):
        """``band`` checked against :attr:`bands` (None: the reference band)."""
        if band is None:
            return self.reference_band
        if band not in self.bands:
            have = ", ".join(repr(b) for b in self.bands) if self.bands != (None,) else "no named band"
            raise InputError(f"unknown band {band!r}; the model has {have}", field="band")
        return band

    # ------------------------------------------------------------------ detector arrays
    def detector_arrays(self, band=None) -> tuple[DetectorArray, ...]:
        """The detector arrays that imaged a band, ordered by first column.

        Parameters
        ----------
        band : str, optional
            Default: :attr:`reference_band`.

        Returns
        -------
        tuple of DetectorArray
            Their column ranges do not overlap. By default one array named ``""``
            (:data:`WHOLE_IMAGE`) covering every image column.
        """
        self._protocol_band(band)
        return (DetectorArray(WHOLE_IMAGE, 0, int(self.image_shape[1])),)

    def detector_index(self, col, *, band=None, array=None) -> np.ndarray:
        """Index in ``detector_arrays(band)`` of the array that images each column.

        A column inside an array's range belongs to it; a column outside every array belongs to
        the nearest one. (Not to be confused with a CCD's detector coordinate
        :meth:`sensor_models.models.pushbroom_types.CcdLook.detector_index`.)

        Parameters
        ----------
        col : array_like, shape (N,)
            Continuous image columns (first pixel centre at 0.5).
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Forces the choice: an array's name or index, or one of those per point.

        Returns
        -------
        ndarray of intp, shape of ``col``
        """
        arrays = self.detector_arrays(band)
        col = np.asarray(col, dtype=np.float64)
        if array is not None:
            return array_positions(arrays, array, col.shape)
        if len(arrays) == 1:
            return np.zeros(col.shape, dtype=np.intp)
        firsts = np.array([a.first_col for a in arrays], dtype=np.float64)
        lasts = np.array([a.last_col for a in arrays], dtype=np.float64)
        flat = col.reshape(-1, 1)
        dist = np.maximum(np.maximum(firsts[None, :] - flat, flat - lasts[None, :]), 0.0)
        return np.argmin(dist + 1e-9 * np.arange(len(arrays)), axis=1).reshape(col.shape)

    def _one_array(self, band, array) -> int:
        """Index of the one array ``array`` names (None: the band's only array)."""
        arrays = self.detector_arrays(band)
        if array is None:
            if len(arrays) != 1:
                names = ", ".join(repr(a.name) for a in arrays)
                raise InputError(f"the band has {len(arrays)} detector arrays ({names}); name one",
                                 field="array")
            return 0
        if not (isinstance(array, str) or np.ndim(array) == 0):
            raise InputError("needs one detector array (a name or an index)", field="array")
        return int(array_positions(arrays, array, ())[()])

    def _check_array(self, band, array) -> None:
        """Validate ``array=`` of a single-array model's localization methods."""
        if array is None:
            return
        arrays = self.detector_arrays(band)
        array_positions(arrays, array, np.shape(array))

    def detector_view(self, band=None, array=None) -> "SensorModel":
        """One detector array of one band as a model of its own image.

        The view's column 0 is the array's ``first_col``; rows are unchanged; its parameters are
        the model's.

        Parameters
        ----------
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int, optional
            Name or index in ``detector_arrays(band)``; may be omitted when the band has one
            array.

        Returns
        -------
        SensorModel
            By default the model itself (its image is one array).
        """
        self._one_array(band, array)
        return self

    # ------------------------------------------------------------------ parameters
    def parameter_names(self) -> tuple[str, ...]:
        """The parameter names, in the order of :meth:`parameters`.

        Returns
        -------
        tuple of str
        """
        return tuple(self.parameters().names)

    def parameter(self, name: str) -> float:
        """The current value of one parameter.

        Parameters
        ----------
        name : str
            One of :meth:`parameter_names`.

        Returns
        -------
        float
            In the parameter's unit (radians unless the name says otherwise).

        Raises
        ------
        InputError
            Naming the unknown parameter.
        """
        params = self.parameters()
        try:
            position = params.names.index(name)
        except ValueError:
            raise self._unknown_parameter(name) from None
        return float(params.values[position])

    def _unknown_parameter(self, name) -> InputError:
        groups = ", ".join(self.parameter_groups())
        return InputError(
            f"unknown parameter {name!r} for a {self.kind} model; its parameter groups are {groups} "
            "(parameter_names() lists every name)",
            field="parameter",
        )

    def parameter_groups(self) -> Mapping[str, tuple[str, ...]]:
        """The parameters, partitioned into named groups (module docstring).

        Returns
        -------
        dict of str to tuple of str
            Ordered; concatenating the groups gives :meth:`parameter_names`. By default one
            group ``"parameters"`` with every parameter.
        """
        return {"parameters": self.parameter_names()}

    @property
    def interior_layout(self) -> str:
        """How the calibration parameters are organized, read from :meth:`parameter_groups`.

        Callers choose a calibration path by this capability, never by the model's type.

        Returns
        -------
        {"per_array", "frame", "none"}
            ``"per_array"``: an exterior group plus one ``"interior.<band>.<array>"`` group
            per detector array and band (the directional angles of push-broom CCDs);
            ``"frame"``: an exterior group plus one interior of the whole area array
            (staring camera); ``"none"``: not a rigorous model (e.g. an RPC), whose
            parameters are calibrated jointly as one group.
        """
        if not self.is_rigorous:
            return "none"
        return "per_array" if any(g.startswith("interior.") for g in self.parameter_groups()) else "frame"

    def interior_group(self, band=None, array=None) -> str | None:
        """Name of the group holding one detector array's interior (look) parameters.

        Parameters
        ----------
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int, optional
            Name or index in ``detector_arrays(band)``; may be omitted when the band has one
            array.

        Returns
        -------
        str or None
            A key of :meth:`parameter_groups`, or None when the model has no interior
            parameters (the default).
        """
        self._one_array(band, array)
        return None
