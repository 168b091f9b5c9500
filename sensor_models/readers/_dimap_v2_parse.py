"""Strict parsing of SPOT 6/7 and Pleiades DIMAP v2 sensor-product metadata (``DIM_*.XML``).

The public entry points are in :mod:`sensor_models.readers.dimap_v2`; this module only turns
the XML into a :class:`DimapV2Metadata` of plain arrays, already in gcpcal's pixel convention
(first pixel centre at 0.5) with times in SI seconds since the first line's time
(``Time_Range/START``, UTC). Conventions and sources: ``docs/dimap_v2.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sensor_models.readers.dimap_common import (
    EARTH_ROTATION_RAD_S,
    DimapXml,
    check_increasing,
    dimap_to_pixel,
    ephemeris_velocity_kind,
    seconds_since,
)

__all__ = ["DimapV2Band", "DimapV2Metadata", "parse_dimap_v2"]

_R = "Dimap_Document"
_MODEL = "Geometric_Data/Refined_Model"
#: ``Time_Range`` must agree with ``(NROWS - 1) * LINE_PERIOD`` to this fraction of a line
TIME_RANGE_TOLERANCE_LINES = 0.05
#: largest tolerated departure of a quaternion's norm from 1
QUATERNION_NORM_TOLERANCE = 1e-6
#: units of ``LINE_PERIOD`` accepted, with their factor to seconds
_PERIOD_UNITS = {"microsecond": 1e-6, "us": 1e-6, "millisecond": 1e-3, "ms": 1e-3, "second": 1.0, "s": 1.0}
_GEOCENTRIC_CODES = ("urn:ogc:def:crs:EPSG::4978", "EPSG:4978")


@dataclass(frozen=True)
class DimapV2Band:
    """Look-angle polynomials of one band (``Band_Calibration``).

    Attributes
    ----------
    band_id : str
        ``BAND_ID`` (``P``, ``B0`` ... ``B3``).
    first_col, last_col : int
        ``Swath_Range`` as in the file (1-based DIMAP columns, inclusive).
    xlos, ylos : ndarray, shape (K,)
        ``XLOS_k``, ``YLOS_k``: coefficients of the tangents of the look angles in powers of
        the 0-based detector index ``COL - 1`` (``XLOS`` across track, ``YLOS`` along track;
        see ``docs/dimap_v2.md``).
    """

    band_id: str
    first_col: int
    last_col: int
    xlos: np.ndarray
    ylos: np.ndarray


@dataclass(frozen=True)
class DimapV2Metadata:
    """The geometric content of a DIMAP v2 sensor (primary) product.

    Attributes
    ----------
    path : str
    profile : str
        ``METADATA_PROFILE`` (``S6_SENSOR``, ``S7_SENSOR``, ``PHR_SENSOR`` ...).
    mission, mission_index : str, int
        ``Strip_Source/MISSION`` and ``MISSION_INDEX`` (``SPOT``/6, ``PHR``/1 ...).
    n_rows, n_cols, n_bands : int
    epoch : numpy.datetime64
        ``Time_Range/START`` (UTC, ns): the time of the first line's centre.
    line_period_s : float
    end_seconds : float
        ``Time_Range/END`` in seconds since ``epoch`` (checked to be the last line's time).
    ephemeris_seconds : ndarray, shape (N,)
    position_m, velocity_m_s : ndarray, shape (N, 3)
        ITRF (WGS84 geocentric, EPSG:4978) state vectors; velocities Earth-relative
        (converted when the file gives inertial ones, see ``velocity_kind``).
    velocity_kind : {"earth_relative", "inertial"}
        What the file's velocities were, found by comparing them with ``dP/dt``.
    attitude_seconds : ndarray, shape (M,)
    quaternions_wxyz : ndarray, shape (M, 4)
        ``Q0`` (the scalar), ``Q1``, ``Q2``, ``Q3``: rotations satellite frame -> ITRF.
    bands : tuple of DimapV2Band
    vertex_row, vertex_col, vertex_lon, vertex_lat : ndarray, shape (4,)
        ``Dataset_Extent/Vertex`` (rows and columns in gcpcal's convention).
    center_row, center_col, center_lon, center_lat : float
        ``Dataset_Extent/Center``.
    gsd_across_m, gsd_along_m : float or None
        Mean ``Use_Area`` ground sample distances, metres (None when absent).
    raster_hrefs : tuple of str
        ``Data_File/DATA_FILE_PATH@href`` in tile order, relative to the XML's folder.
    rpc_href : str or None
        The RPC file the product refers to (``Rational_Function_Model``), relative.
    """

    path: str
    profile: str
    mission: str
    mission_index: int
    n_rows: int
    n_cols: int
    n_bands: int
    epoch: np.datetime64
    line_period_s: float
    end_seconds: float
    ephemeris_seconds: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    velocity_kind: str
    attitude_seconds: np.ndarray
    quaternions_wxyz: np.ndarray
    bands: tuple
    vertex_row: np.ndarray
    vertex_col: np.ndarray
    vertex_lon: np.ndarray
    vertex_lat: np.ndarray
    center_row: float
    center_col: float
    center_lon: float
    center_lat: float
    gsd_across_m: float | None
    gsd_along_m: float | None
    raster_hrefs: tuple
    rpc_href: str | None

    def seconds(self, row):
        """Imaging time of continuous rows (gcpcal convention).

        Parameters
        ----------
        row : array_like
            Continuous rows (first line's centre at 0.5).

        Returns
        -------
        ndarray of float64
            SI seconds since :attr:`epoch`, same shape: ``(row - 0.5) * line_period_s``.
        """
        return (np.asarray(row, dtype=np.float64) - 0.5) * self.line_period_s


# ---------------------------------------------------------------------------------------------
# sections


def _identification(x: DimapXml) -> dict:
    """Format and version, profile, mission, raster size and pixel origin."""
    r = x.root
    w = f"{_R}/Metadata_Identification/METADATA_FORMAT"
    fmt = x.node(r, "Metadata_Identification/METADATA_FORMAT", w)
    version = fmt.get("version", "")
    if (fmt.text or "").strip() != "DIMAP" or not version.startswith("2."):
        raise x.error(w, f"must be 'DIMAP' version 2.x, got {(fmt.text or '').strip()!r} version {version!r}")
    profile = x.text(r, "Metadata_Identification/METADATA_PROFILE", f"{_R}/Metadata_Identification/METADATA_PROFILE")
    src = "Dataset_Sources/Source_Identification/Strip_Source"
    mission = x.text(r, f"{src}/MISSION", f"{_R}/{src}/MISSION")
    mission_index = x.integer(r, f"{src}/MISSION_INDEX", f"{_R}/{src}/MISSION_INDEX", minimum=1)
    dims = "Raster_Data/Raster_Dimensions"
    sizes = {k: x.integer(r, f"{dims}/{k}", f"{_R}/{dims}/{k}", minimum=1) for k in ("NROWS", "NCOLS", "NBANDS")}
    geometry = x.text(r, "Geoposition/Raster_CRS/RASTER_GEOMETRY", f"{_R}/Geoposition/Raster_CRS/RASTER_GEOMETRY")
    if geometry != "SENSOR":
        raise x.error(f"{_R}/Geoposition/Raster_CRS/RASTER_GEOMETRY",
                      f"must be SENSOR (a level-1 sensor product), got {geometry!r}")
    origin = x.integer(r, "Geoposition/Raster_CRS/PIXEL_ORIGIN", f"{_R}/Geoposition/Raster_CRS/PIXEL_ORIGIN")
    if origin != 1:
        raise x.error(f"{_R}/Geoposition/Raster_CRS/PIXEL_ORIGIN", f"only PIXEL_ORIGIN 1 is supported, got {origin}")
    return dict(profile=profile, mission=mission, mission_index=mission_index,
                n_rows=sizes["NROWS"], n_cols=sizes["NCOLS"], n_bands=sizes["NBANDS"])


def _timing(x: DimapXml, n_rows: int) -> dict:
    """``Time_Range/START`` as the epoch, the line period, and the check of ``END``."""
    w = f"{_R}/{_MODEL}/Time"
    node = x.node(x.root, f"{_MODEL}/Time", w)
    epoch = x.time(node, "Time_Range/START", f"{w}/Time_Range/START")
    end = x.time(node, "Time_Range/END", f"{w}/Time_Range/END")
    pw = f"{w}/Time_Stamp/LINE_PERIOD"
    period_node = x.node(node, "Time_Stamp/LINE_PERIOD", pw)
    unit = period_node.get("unit", "microsecond")
    if unit not in _PERIOD_UNITS:
        raise x.error(pw, f"unit must be one of {sorted(_PERIOD_UNITS)}, got {unit!r}")
    period = x.number(node, "Time_Stamp/LINE_PERIOD", pw) * _PERIOD_UNITS[unit]
    if not period > 0.0:
        raise x.error(pw, f"must be positive, got {period}")
    end_s = float(seconds_since([end], epoch)[0])
    expected = (n_rows - 1) * period
    if abs(end_s - expected) > TIME_RANGE_TOLERANCE_LINES * period:
        raise x.error(
            f"{w}/Time_Range/END",
            f"lies {end_s:.6f} s after START, but NROWS and LINE_PERIOD put the last line at "
            f"{expected:.6f} s: the line dating is inconsistent",
        )
    _check_reference_line(x, node, epoch, period)
    return dict(epoch=epoch, line_period_s=period, end_seconds=end_s)


def _check_reference_line(x: DimapXml, node, epoch, period: float) -> None:
    """Optional ``Time_Stamp/REFERENCE_LINE`` + ``REFERENCE_TIME`` must agree with ``START``.

    The line dating used is ``START + (ROW - 1) * LINE_PERIOD`` (verified on a real file); a
    file that also dates a reference line must agree with it, or it is refused rather than
    guessed.
    """
    w = f"{_R}/{_MODEL}/Time/Time_Stamp"
    line = x.number(node, "Time_Stamp/REFERENCE_LINE", f"{w}/REFERENCE_LINE", optional=True)
    has_time = node.find("Time_Stamp/REFERENCE_TIME") is not None
    if line is None and not has_time:
        return
    if line is None or not has_time:
        missing = "REFERENCE_LINE" if line is None else "REFERENCE_TIME"
        raise x.error(f"{w}/{missing}", "is missing (REFERENCE_LINE and REFERENCE_TIME come together)")
    ref_s = float(seconds_since([x.time(node, "Time_Stamp/REFERENCE_TIME", f"{w}/REFERENCE_TIME")], epoch)[0])
    expected = (line - 1.0) * period
    if abs(ref_s - expected) > TIME_RANGE_TOLERANCE_LINES * period:
        raise x.error(
            f"{w}/REFERENCE_TIME",
            f"dates line {line:g} at {ref_s:.6f} s after START, but START and LINE_PERIOD date it at "
            f"{expected:.6f} s: the line dating is inconsistent",
        )


def _check_geocentric(x: DimapXml) -> None:
    """The model's CRS must be WGS84 geocentric (ITRF) and its time scale UTC."""
    w = f"{_R}/{_MODEL}/Coordinate_Reference_System"
    code = x.text(x.root, f"{_MODEL}/Coordinate_Reference_System/Geodetic_CRS/GEODETIC_CRS_CODE",
                  f"{w}/Geodetic_CRS/GEODETIC_CRS_CODE")
    if code not in _GEOCENTRIC_CODES:
        raise x.error(f"{w}/Geodetic_CRS/GEODETIC_CRS_CODE", f"must be geocentric EPSG:4978, got {code!r}")
    scale = x.text(x.root, f"{_MODEL}/Coordinate_Reference_System/Temporal_CRS/TEMPORAL_CRS_NAME",
                   f"{w}/Temporal_CRS/TEMPORAL_CRS_NAME", optional=True)
    if scale not in (None, "UTC"):
        raise x.error(f"{w}/Temporal_CRS/TEMPORAL_CRS_NAME", f"only UTC is supported, got {scale!r}")


def _vector(x: DimapXml, parent, rel: str, where: str) -> list[float]:
    """Three numbers separated by blanks (``LOCATION_XYZ``, ``VELOCITY_XYZ``)."""
    text = x.text(parent, rel, where)
    parts = text.split()
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise x.error(where, f"must be three numbers, got {text!r}") from None
    if len(values) != 3 or not np.all(np.isfinite(values)):
        raise x.error(where, f"must be three finite numbers, got {text!r}")
    return values


def _ephemeris(x: DimapXml, epoch) -> dict:
    """ITRF state vectors; inertial velocities are made Earth-relative."""
    w = f"{_R}/{_MODEL}/Ephemeris/Point_List/Point"
    points = x.nodes(x.root, f"{_MODEL}/Ephemeris/Point_List/Point", w, minimum=4)
    times = [x.time(p, "TIME", f"{w}/TIME") for p in points]
    position = np.array([_vector(x, p, "LOCATION_XYZ", f"{w}/LOCATION_XYZ") for p in points])
    velocity = np.array([_vector(x, p, "VELOCITY_XYZ", f"{w}/VELOCITY_XYZ") for p in points])
    seconds = seconds_since(times, epoch)
    check_increasing(x, seconds, f"{w}/TIME")
    radius = np.linalg.norm(position, axis=1)
    if np.any((radius < 6.3e6) | (radius > 8.0e6)):
        raise x.error(f"{w}/LOCATION_XYZ", "positions must be metres from the Earth's centre (LEO)")
    kind = ephemeris_velocity_kind(x, seconds, position, velocity, f"{w}/VELOCITY_XYZ")
    if kind == "inertial":
        velocity = velocity - np.cross([0.0, 0.0, EARTH_ROTATION_RAD_S], position)
    return dict(ephemeris_seconds=seconds, position_m=position, velocity_m_s=velocity, velocity_kind=kind)


def _attitudes(x: DimapXml, epoch) -> dict:
    """Quaternions ``(Q0, Q1, Q2, Q3)``, ``Q0`` the scalar, satellite -> ITRF."""
    w = f"{_R}/{_MODEL}/Attitudes/Quaternion_List/Quaternion"
    nodes = x.nodes(x.root, f"{_MODEL}/Attitudes/Quaternion_List/Quaternion", w, minimum=4)
    times = [x.time(q, "TIME", f"{w}/TIME") for q in nodes]
    quats = np.array([[x.number(q, k, f"{w}/{k}") for k in ("Q0", "Q1", "Q2", "Q3")] for q in nodes])
    seconds = seconds_since(times, epoch)
    check_increasing(x, seconds, f"{w}/TIME")
    norm = np.linalg.norm(quats, axis=1)
    bad = np.nonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)[0]
    if bad.size:
        raise x.error(f"{w}/Q0", f"quaternion {bad[0] + 1} has norm {norm[bad[0]]:.9f}, expected 1")
    return dict(attitude_seconds=seconds, quaternions_wxyz=quats / norm[:, None])


def _coefficients(x: DimapXml, parent, prefix: str, where: str) -> np.ndarray:
    """``PREFIX_0``, ``PREFIX_1`` ... up to the first missing power (at least ``PREFIX_0``)."""
    coefs = []
    while parent.find(f"{prefix}_{len(coefs)}") is not None:
        k = len(coefs)
        coefs.append(x.number(parent, f"{prefix}_{k}", f"{where}/{prefix}_{k}"))
    if not coefs:
        raise x.error(f"{where}/{prefix}_0", "is missing")
    if len(coefs) > 8:
        raise x.error(f"{where}/{prefix}_8", "at most 8 coefficients (degree 7) are supported")
    return np.array(coefs)


def _bands(x: DimapXml, n_cols: int) -> dict:
    """Per-band swath and look-angle polynomials; instrument biases must be zero."""
    cal = f"{_MODEL}/Geometric_Calibration/Instrument_Calibration"
    w = f"{_R}/{cal}/Band_Calibration_List/Band_Calibration"
    bands = []
    for node in x.nodes(x.root, f"{cal}/Band_Calibration_List/Band_Calibration", w):
        band_id = x.text(node, "BAND_ID", f"{w}/BAND_ID")
        first = x.integer(node, "Swath_Range/FIRST_COL", f"{w}/Swath_Range/FIRST_COL", minimum=1)
        last = x.integer(node, "Swath_Range/LAST_COL", f"{w}/Swath_Range/LAST_COL", minimum=1)
        if first != 1:
            raise x.error(f"{w}/Swath_Range/FIRST_COL",
                          f"only FIRST_COL 1 is supported (the layout verified on real data), got {first}")
        if last > n_cols:
            raise x.error(f"{w}/Swath_Range/LAST_COL", f"must be <= NCOLS ({n_cols}), got {last}")
        pw = f"{w}/Polynomial_Look_Angles"
        poly = x.node(node, "Polynomial_Look_Angles", pw)
        bands.append(DimapV2Band(band_id, first, last, _coefficients(x, poly, "XLOS", pw),
                                 _coefficients(x, poly, "YLOS", pw)))
    if len({b.band_id for b in bands}) != len(bands):
        raise x.error(f"{w}/BAND_ID", "band ids must be unique")
    bw = f"{_R}/{cal}/Instrument_Biases"
    biases = x.node(x.root, f"{cal}/Instrument_Biases", bw, optional=True)
    if biases is not None:
        for axis in ("YAW", "PITCH", "ROLL"):
            value = x.number(biases, axis, f"{bw}/{axis}", optional=True)
            if value not in (None, 0.0):
                raise x.error(f"{bw}/{axis}", f"non-zero instrument biases are not supported, got {value}")
    return dict(bands=tuple(bands))


def _extent(x: DimapXml) -> dict:
    """``Dataset_Extent`` vertices and centre, converted to gcpcal's pixel convention."""
    w = f"{_R}/Dataset_Content/Dataset_Extent"
    node = x.node(x.root, "Dataset_Content/Dataset_Extent", w)
    vals = {k: [] for k in ("ROW", "COL", "LON", "LAT")}
    for v in x.nodes(node, "Vertex", f"{w}/Vertex", minimum=4):
        for k in vals:
            vals[k].append(x.number(v, k, f"{w}/Vertex/{k}"))
    c = x.node(node, "Center", f"{w}/Center")
    center = {k: x.number(c, k, f"{w}/Center/{k}") for k in ("ROW", "COL", "LON", "LAT")}
    return dict(
        vertex_row=dimap_to_pixel(vals["ROW"]),
        vertex_col=dimap_to_pixel(vals["COL"]),
        vertex_lon=np.array(vals["LON"]),
        vertex_lat=np.array(vals["LAT"]),
        center_row=float(dimap_to_pixel(center["ROW"])),
        center_col=float(dimap_to_pixel(center["COL"])),
        center_lon=center["LON"],
        center_lat=center["LAT"],
    )


def _gsd(x: DimapXml) -> dict:
    """Mean ``Use_Area`` ground sample distances (optional)."""
    w = f"{_R}/Geometric_Data/Use_Area/Located_Geometric_Values/Ground_Sample_Distance"
    across, along = [], []
    for node in x.root.findall("Geometric_Data/Use_Area/Located_Geometric_Values/Ground_Sample_Distance"):
        across.append(x.number(node, "GSD_ACROSS_TRACK", f"{w}/GSD_ACROSS_TRACK"))
        along.append(x.number(node, "GSD_ALONG_TRACK", f"{w}/GSD_ALONG_TRACK"))
    return dict(gsd_across_m=float(np.mean(across)) if across else None,
                gsd_along_m=float(np.mean(along)) if along else None)


def product_references(x: DimapXml) -> dict:
    """Raster tiles (in ``tile_R``, ``tile_C`` order) and the RPC file the product names."""
    w = f"{_R}/Raster_Data/Data_Access/Data_Files/Data_File"
    tiles = []
    for node in x.root.findall("Raster_Data/Data_Access/Data_Files/Data_File"):
        href = x.node(node, "DATA_FILE_PATH", f"{w}/DATA_FILE_PATH").get("href", "").strip()
        if not href:
            raise x.error(f"{w}/DATA_FILE_PATH", "has no href")
        key = []
        for attr in ("tile_R", "tile_C"):
            try:
                key.append(int(node.get(attr, "1")))
            except ValueError:
                raise x.error(f"{w}@{attr}", f"must be an integer, got {node.get(attr)!r}") from None
        tiles.append((tuple(key), href))
    rpc = x.root.find("Geoposition/Geoposition_Models/Rational_Function_Model/Component/COMPONENT_PATH")
    rpc_href = None
    if rpc is not None:
        rpc_href = rpc.get("href", "").strip() or None
    return dict(raster_hrefs=tuple(h for _, h in sorted(tiles)), rpc_href=rpc_href)


def _check_coverage(x: DimapXml, meta: dict) -> None:
    """The ephemeris and the attitudes must cover the first to the last line."""
    span = (0.0, meta["end_seconds"])
    for key, rel in (("ephemeris_seconds", "Ephemeris/Point_List/Point/TIME"),
                     ("attitude_seconds", "Attitudes/Quaternion_List/Quaternion/TIME")):
        t = meta[key]
        if t[0] > span[0] + 1e-6 or t[-1] < span[1] - 1e-6:
            raise x.error(f"{_R}/{_MODEL}/{rel}",
                          f"samples span [{t[0]:.6f}, {t[-1]:.6f}] s from START but the image lines "
                          f"span [0, {span[1]:.6f}] s")


def parse_dimap_v2(path) -> DimapV2Metadata:
    """Parse the geometry of a SPOT 6/7 or Pleiades DIMAP v2 sensor product, strictly.

    Parameters
    ----------
    path : str or Path
        The ``DIM_*.XML`` file.

    Returns
    -------
    DimapV2Metadata
        Image coordinates converted from DIMAP's 1-based pixel centres to gcpcal's (first
        pixel centre at 0.5); times in SI seconds since ``Time_Range/START`` (UTC).

    Raises
    ------
    ManifestError
        The file cannot be read or is not DIMAP v2, or a needed field is missing, empty, not a
        number or not finite, a time list does not increase strictly or does not cover the
        image lines, ``Time_Range/END`` disagrees with ``NROWS`` and ``LINE_PERIOD``, or the
        product uses a layout not supported (pixel origin, swath start, instrument biases);
        the error names the file and the XML path of the field.
    """
    path = Path(path)
    x = DimapXml(path)
    ident = _identification(x)
    timing = _timing(x, ident["n_rows"])
    _check_geocentric(x)
    fields = dict(**ident, **timing, **_ephemeris(x, timing["epoch"]), **_attitudes(x, timing["epoch"]),
                  **_bands(x, ident["n_cols"]), **_extent(x), **_gsd(x), **product_references(x))
    _check_coverage(x, fields)
    return DimapV2Metadata(path=str(path), **fields)
