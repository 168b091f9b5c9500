"""SPOT 1-5 DIMAP level-1A metadata: strict parsing and a push-broom directional-angle model.

:func:`parse_dimap` reads the geometric content of a SPOT scene ``METADATA.DIM`` (DIMAP 1.1,
profile ``SPOTSCENE_1A``) into a :class:`DimapMetadata` of plain arrays; :func:`read_dimap`
turns it into a :class:`~sensor_models.models.pushbroom.PushbroomModel`. The frames and conventions
are described, with their sources, in ``docs/dimap.md``; in short:

* Times are UTC ISO strings; the model epoch is ``SCENE_CENTER_TIME`` and every time is SI
  seconds from it. ``SCENE_CENTER_LINE`` (1-based) is imaged at ``SCENE_CENTER_TIME`` and
  lines follow at ``LINE_PERIOD``.
* DIMAP pixel coordinates are 1-based centres (``FRAME_ROW = FRAME_COL = 1`` is the first
  pixel's centre). Ours put that centre at 0.5, so ``row = FRAME_ROW - 0.5`` and
  ``col = FRAME_COL - 0.5``; detector ``DETECTOR_ID = k`` images column ``k - 0.5``, i.e. the
  detector index of the model is ``s = k - 1``.
* Ephemeris: ITRF (Earth-fixed) positions; the velocities are Earth-relative in SPOT 5 files
  and inertial (expressed on the ITRF axes) in SPOT 1-4 files, which the reader detects.
* SPOT local orbital frame (SPOT Geometry Handbook): ``Z = P/|P|`` (away from the Earth),
  ``X = V x Z / |V x Z|``, ``Y = Z x X`` (along track), built from the ITRF position and the
  velocity of the kind the file gives.
* Look angles: a detector's line of sight in the satellite (navigation) frame is
  ``(-tan PSI_Y, tan PSI_X, -1)``; the mirror tilt is already included in ``PSI_Y``.
* Attitude: ``u_orbital = Rx(-pitch) Ry(-roll) Rz(yaw) u_satellite`` (the roll and pitch
  signs are reversed because the angles are given in the historical (-X, -Y, Z) frame).
  SPOT 5 gives absolute, star-tracker corrected angles (``Corrected_Attitude``); SPOT 1-4
  give two absolute AOCS samples (``Angles_List``) and angular speeds
  (``Angular_Speeds_List``) that are integrated from the first absolute sample.

The model is expressed in gcpcal's conventions with an identity installation: the camera
frame has X along track (the SPOT ``Y`` axis), Y across track (the SPOT ``X`` axis) and Z
towards the Earth (``-Z``), so ``tan psi_x = tan PSI_X`` and ``tan psi_y = -tan PSI_Y``; the
attitude is given as body -> ITRF rotations sampled densely over the scene.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sensor_models.errors import InputError, ManifestError
from sensor_models.readers._xml import StrictXml

__all__ = [
    "DimapAngles",
    "DimapLookAngles",
    "DimapMetadata",
    "LookFit",
    "attitude_angles",
    "body_to_itrf",
    "dimap_orbit",
    "dimap_to_pixel",
    "fit_look_polynomials",
    "parse_dimap",
    "pixel_to_dimap",
    "read_dimap",
    "spot_look_to_camera",
    "spot_orbital_to_itrf_mat",
    "spot_satellite_to_orbital_mat",
]

#: rotation taking gcpcal camera-frame vectors to the SPOT satellite (navigation) frame:
#: SPOT X (across track) = camera Y, SPOT Y (along track) = camera X, SPOT Z (up) = -camera Z
CAMERA_TO_SPOT = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: attitude samples of the model: spacing (s) and margin beyond the image lines (s)
ATTITUDE_STEP_S = 0.1
#: attitude choices of :func:`read_dimap`
ATTITUDE_MODES = ("measured", "nominal")
ATTITUDE_MARGIN_S = 1.0

#: the directional-angle polynomial degree is raised until the fit is this good (pixels)
MAX_FIT_RESIDUAL_PX = 0.01
MAX_DEGREE = 7

#: WGS84 nominal mean angular velocity of the Earth (rad/s)
EARTH_ROTATION_RAD_S = 7.292115e-5
#: largest disagreement (m/s) tolerated between the file's velocities and dP/dt (or dP/dt + w x P)
VELOCITY_TOLERANCE_M_S = 1.0

_ROOT = "Dimap_Document"
_TIME_RE = re.compile(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(\.\d{1,9})?Z?$")


# ---------------------------------------------------------------------------------------------
# pixel convention


def dimap_to_pixel(dimap_row_or_col):
    """DIMAP 1-based pixel-centre coordinates -> gcpcal's (first pixel centre at 0.5).

    Parameters
    ----------
    dimap_row_or_col : array_like
        Rows or columns as DIMAP counts them (the first pixel's centre is 1).

    Returns
    -------
    ndarray of float64
        The same positions in gcpcal's convention (``value - 0.5``), same shape.
    """
    return np.asarray(dimap_row_or_col, dtype=np.float64) - 0.5


def pixel_to_dimap(row_or_col):
    """gcpcal pixel coordinates -> DIMAP 1-based pixel-centre coordinates.

    Parameters
    ----------
    row_or_col : array_like
        Rows or columns in gcpcal's convention (the first pixel's centre is 0.5).

    Returns
    -------
    ndarray of float64
        The same positions as DIMAP counts them (``value + 0.5``), same shape.
    """
    return np.asarray(row_or_col, dtype=np.float64) + 0.5


# ---------------------------------------------------------------------------------------------
# parsed content


@dataclass(frozen=True)
class DimapAngles:
    """Yaw, pitch and roll samples (radians, or radians per second for angular speeds).

    Attributes
    ----------
    seconds : ndarray, shape (N,)
        SI seconds since the scene epoch, strictly increasing.
    yaw, pitch, roll : ndarray, shape (N,)
        As in the file: in the SPOT convention (see the module docstring), not yet
        converted.
    out_of_range : ndarray of bool, shape (N,)
        The file's ``OUT_OF_RANGE`` flags.
    field : str
        XML path of the list in the file.
    """

    seconds: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    out_of_range: np.ndarray
    field: str


@dataclass(frozen=True)
class DimapLookAngles:
    """Detector look angles of one band (``Instrument_Look_Angles``).

    Attributes
    ----------
    band_index : int
        ``BAND_INDEX`` (1-based).
    detector_id : ndarray of int, shape (K,)
        ``DETECTOR_ID`` (1-based; detector ``k`` images DIMAP column ``k``). SPOT 1-4 list only
        the first and the last detector, SPOT 5 every detector.
    psi_x, psi_y : ndarray, shape (K,)
        ``PSI_X`` (along track) and ``PSI_Y`` (across track, mirror tilt included), radians.
    """

    band_index: int
    detector_id: np.ndarray
    psi_x: np.ndarray
    psi_y: np.ndarray


@dataclass(frozen=True)
class DimapMetadata:
    """The geometric content of a SPOT 1-5 DIMAP level-1A metadata file.

    Image coordinates are already in gcpcal's convention (first pixel centre 0.5); times are
    SI seconds since ``epoch`` (= ``SCENE_CENTER_TIME``, UTC).

    Attributes
    ----------
    path : str
    mission : int
        ``MISSION_INDEX`` (1 to 5).
    instrument : str
        ``INSTRUMENT`` + ``INSTRUMENT_INDEX`` (``"HRV1"``, ``"HRG1"``, ...).
    sensor_code : str
        ``SENSOR_CODE`` (``P``, ``M``, ``X``, ``A``, ``B``, ``J``, ``T`` ...).
    n_rows, n_cols, n_bands : int
    epoch : numpy.datetime64
        ``SCENE_CENTER_TIME`` (UTC, ns).
    line_period_s : float
    reference_row : float
        ``SCENE_CENTER_LINE - 0.5``: the row imaged at ``epoch``.
    ephemeris_seconds : ndarray, shape (N,)
    position_m, velocity_m_s : ndarray, shape (N, 3)
        ITRF position and velocity of the satellite, as in the file.
    velocity_kind : {"earth_relative", "inertial"}
        What the file's velocities are, found by comparing them with the derivative of the
        positions: SPOT 5 gives the Earth-relative velocity (``dP/dt`` in ITRF), SPOT 1-4 the
        inertial velocity expressed on the ITRF axes (``dP/dt + omega x P``).
    doris_used : bool
    raw_angles : DimapAngles
        ``Raw_Attitudes/Aocs_Attitude/Angles_List`` (absolute AOCS angles; two samples on
        SPOT 1-4).
    angular_speeds : DimapAngles or None
        ``Raw_Attitudes/Aocs_Attitude/Angular_Speeds_List`` (rad/s).
    corrected_angles : DimapAngles or None
        ``Corrected_Attitudes/Corrected_Attitude/Angles`` (SPOT 5: absolute angles after the
        ground segment's star-tracker correction).
    star_tracker_used : bool or None
    look_angles : tuple of DimapLookAngles
        One per band.
    mirror_step : int or None
        ``Mirror_Position/STEP_COUNT``.
    incidence_angle_deg, viewing_angle_deg : float or None
    vertex_row, vertex_col : ndarray, shape (4,)
        ``Dataset_Frame/Vertex`` image coordinates (converted to gcpcal's convention).
    vertex_lon, vertex_lat : ndarray, shape (4,)
        Their ``FRAME_LON``, ``FRAME_LAT`` (degrees, WGS84).
    vertex_h_m : ndarray, shape (4,)
        The height the ground segment used for each vertex, taken from the matching
        ``Geoposition_Points/Tie_Point/TIE_POINT_CRS_Z`` (NaN where no tie point matches).
    center_row, center_col, center_lon, center_lat : float
        ``Dataset_Frame/Scene_Center``.
    """

    path: str
    mission: int
    instrument: str
    sensor_code: str
    n_rows: int
    n_cols: int
    n_bands: int
    epoch: np.datetime64
    line_period_s: float
    reference_row: float
    ephemeris_seconds: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    velocity_kind: str
    doris_used: bool
    raw_angles: DimapAngles
    angular_speeds: DimapAngles | None
    corrected_angles: DimapAngles | None
    star_tracker_used: bool | None
    look_angles: tuple
    mirror_step: int | None
    incidence_angle_deg: float | None
    viewing_angle_deg: float | None
    vertex_row: np.ndarray
    vertex_col: np.ndarray
    vertex_lon: np.ndarray
    vertex_lat: np.ndarray
    vertex_h_m: np.ndarray
    center_row: float
    center_col: float
    center_lon: float
    center_lat: float

    @property
    def earth_relative_velocity_m_s(self) -> np.ndarray:
        """Velocities relative to the rotating Earth (``dP/dt`` in ITRF), shape (N, 3)."""
        if self.velocity_kind == "earth_relative":
            return self.velocity_m_s
        return self.velocity_m_s - np.cross([0.0, 0.0, EARTH_ROTATION_RAD_S], self.position_m)

    def seconds(self, row):
        """Imaging time of continuous rows.

        Parameters
        ----------
        row : array_like
            Continuous row coordinates (gcpcal convention, first line centre 0.5).

        Returns
        -------
        ndarray of float64
            SI seconds since ``epoch``, same shape: ``(row - reference_row) * line_period_s``.
        """
        return (np.asarray(row, dtype=np.float64) - self.reference_row) * self.line_period_s


# ---------------------------------------------------------------------------------------------
# strict XML access


class _Xml(StrictXml):
    """Strict typed access to the DIMAP tree; errors name the file and the XML path."""

    ROOT = _ROOT
    DOCUMENT = "DIMAP document"

    def nodes(self, parent, rel: str, where: str, *, minimum: int = 1):
        found = parent.findall(rel)
        if len(found) < minimum:
            what = "is missing" if not found else f"needs at least {minimum} entries, got {len(found)}"
            raise self.error(where, what)
        return found

    def flag(self, parent, rel: str, where: str, *, optional: bool = False):
        value = self.text(parent, rel, where, optional=optional)
        if value is None:
            return None
        if value not in ("Y", "N"):
            raise self.error(where, f"must be 'Y' or 'N', got {value!r}")
        return value == "Y"

    def time(self, parent, rel: str, where: str) -> np.datetime64:
        value = self.text(parent, rel, where)
        return self.parse_time(value, where)

    def parse_time(self, value: str, where: str) -> np.datetime64:
        from sensor_models.geometry.timescales import parse_utc

        if not _TIME_RE.match(value):
            raise self.error(where, f"must be a UTC time YYYY-MM-DDThh:mm:ss[.ffffff], got {value!r}")
        try:
            return parse_utc(value)
        except InputError as exc:
            raise self.error(where, exc.reason) from None


def _seconds_since(times, epoch) -> np.ndarray:
    """SI seconds from ``epoch`` (UTC; no leap second falls inside a SPOT scene's data)."""
    return (np.asarray(times, dtype="datetime64[ns]") - epoch).astype(np.int64) * 1e-9


def _check_increasing(x: _Xml, seconds: np.ndarray, where: str) -> None:
    bad = np.nonzero(np.diff(seconds) <= 0.0)[0]
    if bad.size:
        i = int(bad[0])
        raise x.error(
            where,
            f"times must increase strictly; entry {i + 2} ({seconds[i + 1]:+.6f} s from the scene "
            f"centre) does not follow entry {i + 1} ({seconds[i]:+.6f} s)",
        )


def _velocity_kind(x: _Xml, seconds, position, velocity, where: str) -> str:
    """Tell Earth-relative from inertial velocities by comparing them with ``dP/dt``.

    ``dP/dt`` comes from a polynomial fitted to the positions (degree up to 8, well below the
    0.1 m/s level for a LEO orbit sampled every 30-60 s over a few minutes).
    """
    t = (seconds - seconds.mean()) / max(np.ptp(seconds), 1.0)
    deg = min(seconds.size - 1, 8)
    dpdt = np.empty_like(position)
    for k in range(3):
        c = np.polynomial.polynomial.polyfit(t, position[:, k], deg)
        dpdt[:, k] = np.polynomial.polynomial.polyval(t, np.polynomial.polynomial.polyder(c))
    dpdt /= max(np.ptp(seconds), 1.0)
    spin = np.cross([0.0, 0.0, EARTH_ROTATION_RAD_S], position)
    err_rel = float(np.abs(velocity - dpdt).max())
    err_in = float(np.abs(velocity - spin - dpdt).max())
    if min(err_rel, err_in) > VELOCITY_TOLERANCE_M_S:
        raise x.error(
            where,
            f"velocities agree neither with dP/dt (off by {err_rel:.1f} m/s) nor with dP/dt + "
            f"omega x P (off by {err_in:.1f} m/s): the ephemeris is inconsistent",
        )
    return "earth_relative" if err_rel <= err_in else "inertial"


def _angles(x: _Xml, parent, rel: str, where: str, epoch, *, minimum: int) -> DimapAngles:
    items = x.nodes(parent, rel, where, minimum=minimum)
    times, yaw, pitch, roll, oor = [], [], [], [], []
    for el in items:
        times.append(x.time(el, "TIME", f"{where}/TIME"))
        yaw.append(x.number(el, "YAW", f"{where}/YAW"))
        pitch.append(x.number(el, "PITCH", f"{where}/PITCH"))
        roll.append(x.number(el, "ROLL", f"{where}/ROLL"))
        oor.append(x.flag(el, "OUT_OF_RANGE", f"{where}/OUT_OF_RANGE", optional=True) or False)
    seconds = _seconds_since(times, epoch)
    _check_increasing(x, seconds, f"{where}/TIME")
    return DimapAngles(seconds, np.array(yaw), np.array(pitch), np.array(roll), np.array(oor, dtype=bool), where)


def _source(x: _Xml) -> dict:
    """Format check, mission, instrument, raster dimensions and pixel origin."""
    r, R = x.root, _ROOT
    fmt = x.node(r, "Metadata_Id/METADATA_FORMAT", f"{R}/Metadata_Id/METADATA_FORMAT")
    if (fmt.text or "").strip() != "DIMAP":
        raise x.error(f"{R}/Metadata_Id/METADATA_FORMAT", f"must be 'DIMAP', got {fmt.text!r}")

    src = f"{R}/Dataset_Sources/Source_Information/Scene_Source"
    scene = x.node(r, "Dataset_Sources/Source_Information/Scene_Source", src)
    mission = x.integer(scene, "MISSION_INDEX", f"{src}/MISSION_INDEX")
    if mission not in (1, 2, 3, 4, 5):
        raise x.error(f"{src}/MISSION_INDEX", f"must be 1 to 5 (SPOT 1-5), got {mission}")
    instrument = x.text(scene, "INSTRUMENT", f"{src}/INSTRUMENT") + str(
        x.integer(scene, "INSTRUMENT_INDEX", f"{src}/INSTRUMENT_INDEX")
    )
    sensor_code = x.text(scene, "SENSOR_CODE", f"{src}/SENSOR_CODE")
    incidence = x.number(scene, "INCIDENCE_ANGLE", f"{src}/INCIDENCE_ANGLE", optional=True)
    viewing = x.number(scene, "VIEWING_ANGLE", f"{src}/VIEWING_ANGLE", optional=True)

    dims = f"{R}/Raster_Dimensions"
    n_cols = x.integer(r, "Raster_Dimensions/NCOLS", f"{dims}/NCOLS", minimum=1)
    n_rows = x.integer(r, "Raster_Dimensions/NROWS", f"{dims}/NROWS", minimum=1)
    n_bands = x.integer(r, "Raster_Dimensions/NBANDS", f"{dims}/NBANDS", minimum=1)

    origin = x.integer(r, "Raster_CS/PIXEL_ORIGIN", f"{R}/Raster_CS/PIXEL_ORIGIN", optional=True)
    if origin not in (None, 1):
        raise x.error(f"{R}/Raster_CS/PIXEL_ORIGIN", f"only PIXEL_ORIGIN 1 is supported, got {origin}")
    return dict(
        mission=mission,
        instrument=instrument,
        sensor_code=sensor_code,
        incidence_angle_deg=incidence,
        viewing_angle_deg=viewing,
        n_rows=n_rows,
        n_cols=n_cols,
        n_bands=n_bands,
    )


def _line_timing(x: _Xml) -> dict:
    """Line period, scene epoch (``SCENE_CENTER_TIME``) and its line, converted to 0.5-based rows."""
    ts = f"{_ROOT}/Data_Strip/Sensor_Configuration/Time_Stamp"
    tnode = x.node(x.root, "Data_Strip/Sensor_Configuration/Time_Stamp", ts)
    line_period = x.number(tnode, "LINE_PERIOD", f"{ts}/LINE_PERIOD")
    if not line_period > 0.0:
        raise x.error(f"{ts}/LINE_PERIOD", f"must be positive, got {line_period}")
    epoch = x.time(tnode, "SCENE_CENTER_TIME", f"{ts}/SCENE_CENTER_TIME")
    center_line = x.number(tnode, "SCENE_CENTER_LINE", f"{ts}/SCENE_CENTER_LINE")
    return dict(epoch=epoch, line_period_s=line_period, reference_row=float(dimap_to_pixel(center_line)))


def _ephemeris(x: _Xml, epoch) -> dict:
    """ITRF state vectors, their seconds since ``epoch`` and the kind of velocity."""
    eph = f"{_ROOT}/Data_Strip/Ephemeris"
    enode = x.node(x.root, "Data_Strip/Ephemeris", eph)
    points = x.nodes(enode, "Points/Point", f"{eph}/Points/Point", minimum=4)
    times, pos, vel = [], [], []
    for p in points:
        w = f"{eph}/Points/Point"
        times.append(x.time(p, "TIME", f"{w}/TIME"))
        pos.append([x.number(p, f"Location/{a}", f"{w}/Location/{a}") for a in "XYZ"])
        vel.append([x.number(p, f"Velocity/{a}", f"{w}/Velocity/{a}") for a in "XYZ"])
    eph_seconds = _seconds_since(times, epoch)
    _check_increasing(x, eph_seconds, f"{eph}/Points/Point/TIME")
    position = np.array(pos)
    radius = np.linalg.norm(position, axis=1)
    if np.any((radius < 6.3e6) | (radius > 8.0e6)):
        raise x.error(f"{eph}/Points/Point/Location", "positions must be metres from the Earth's centre (LEO)")
    doris = x.flag(enode, "DORIS_USED", f"{eph}/DORIS_USED", optional=True) or False
    velocity = np.array(vel)
    velocity_kind = _velocity_kind(x, eph_seconds, position, velocity, f"{eph}/Points/Point/Velocity")
    return dict(
        ephemeris_seconds=eph_seconds,
        position_m=position,
        velocity_m_s=velocity,
        velocity_kind=velocity_kind,
        doris_used=doris,
    )


def _attitudes(x: _Xml, epoch, mission: int) -> dict:
    """Raw AOCS angles, angular speeds (SPOT 1-4) and corrected angles (SPOT 5)."""
    att = f"{_ROOT}/Data_Strip/Satellite_Attitudes"
    anode = x.node(x.root, "Data_Strip/Satellite_Attitudes", att)
    aocs = f"{att}/Raw_Attitudes/Aocs_Attitude"
    aocs_node = x.node(anode, "Raw_Attitudes/Aocs_Attitude", aocs)
    raw = _angles(x, aocs_node, "Angles_List/Angles", f"{aocs}/Angles_List/Angles", epoch, minimum=1)
    speeds = None
    if mission <= 4 or aocs_node.find("Angular_Speeds_List") is not None:
        speeds = _angles(
            x, aocs_node, "Angular_Speeds_List/Angular_Speeds", f"{aocs}/Angular_Speeds_List/Angular_Speeds",
            epoch, minimum=2,
        )
    corrected = None
    star_tracker = None
    cnode = anode.find("Corrected_Attitudes")
    if mission == 5 or cnode is not None:
        cw = f"{att}/Corrected_Attitudes"
        cnode = x.node(anode, "Corrected_Attitudes", cw)
        star_tracker = x.flag(cnode, "STAR_TRACKER_USED", f"{cw}/STAR_TRACKER_USED", optional=True)
        corrected = _angles(
            x, cnode, "Corrected_Attitude/Angles", f"{cw}/Corrected_Attitude/Angles", epoch, minimum=4
        )
    return dict(raw_angles=raw, angular_speeds=speeds, corrected_angles=corrected, star_tracker_used=star_tracker)


def _look_angles(x: _Xml, n_cols: int) -> dict:
    """Detector look angles of every band and the mirror step count."""
    sc = f"{_ROOT}/Data_Strip/Sensor_Configuration"
    snode = x.node(x.root, "Data_Strip/Sensor_Configuration", sc)
    lw = f"{sc}/Instrument_Look_Angles_List/Instrument_Look_Angles"
    looks = []
    for il in x.nodes(snode, "Instrument_Look_Angles_List/Instrument_Look_Angles", lw):
        band = x.integer(il, "BAND_INDEX", f"{lw}/BAND_INDEX", minimum=1)
        la = f"{lw}/Look_Angles_List/Look_Angles"
        ids, px, py = [], [], []
        for el in x.nodes(il, "Look_Angles_List/Look_Angles", la, minimum=2):
            ids.append(x.integer(el, "DETECTOR_ID", f"{la}/DETECTOR_ID", minimum=1))
            px.append(x.number(el, "PSI_X", f"{la}/PSI_X"))
            py.append(x.number(el, "PSI_Y", f"{la}/PSI_Y"))
        ids = np.array(ids)
        if np.any(np.diff(ids) <= 0):
            raise x.error(f"{la}/DETECTOR_ID", "detector ids must increase strictly")
        if ids[-1] > n_cols:
            raise x.error(f"{la}/DETECTOR_ID", f"detector {ids[-1]} lies beyond NCOLS = {n_cols}")
        looks.append(DimapLookAngles(band, ids, np.array(px), np.array(py)))
    mirror_step = x.integer(snode, "Mirror_Position/STEP_COUNT", f"{sc}/Mirror_Position/STEP_COUNT", optional=True)
    return dict(look_angles=tuple(looks), mirror_step=mirror_step)


def _frame(x: _Xml) -> dict:
    """Frame vertices and scene centre (DIMAP 1-based -> ours) with the tie-point heights."""
    r = x.root
    fw = f"{_ROOT}/Dataset_Frame"
    fnode = x.node(r, "Dataset_Frame", fw)
    vrow, vcol, vlon, vlat = [], [], [], []
    for v in x.nodes(fnode, "Vertex", f"{fw}/Vertex", minimum=4):
        vw = f"{fw}/Vertex"
        vlon.append(x.number(v, "FRAME_LON", f"{vw}/FRAME_LON"))
        vlat.append(x.number(v, "FRAME_LAT", f"{vw}/FRAME_LAT"))
        vrow.append(x.number(v, "FRAME_ROW", f"{vw}/FRAME_ROW"))
        vcol.append(x.number(v, "FRAME_COL", f"{vw}/FRAME_COL"))
    cw = f"{fw}/Scene_Center"
    cn = x.node(fnode, "Scene_Center", cw)
    c_lon = x.number(cn, "FRAME_LON", f"{cw}/FRAME_LON")
    c_lat = x.number(cn, "FRAME_LAT", f"{cw}/FRAME_LAT")
    c_row = x.number(cn, "FRAME_ROW", f"{cw}/FRAME_ROW")
    c_col = x.number(cn, "FRAME_COL", f"{cw}/FRAME_COL")

    # heights the ground segment used: the tie point at the same pixel (CRS_Z)
    vh = np.full(len(vrow), np.nan)
    tw = f"{_ROOT}/Geoposition/Geoposition_Points/Tie_Point"
    for tp in r.findall("Geoposition/Geoposition_Points/Tie_Point"):
        tx = x.number(tp, "TIE_POINT_DATA_X", f"{tw}/TIE_POINT_DATA_X")
        ty = x.number(tp, "TIE_POINT_DATA_Y", f"{tw}/TIE_POINT_DATA_Y")
        tz = x.number(tp, "TIE_POINT_CRS_Z", f"{tw}/TIE_POINT_CRS_Z", optional=True)
        for i, (rr, cc) in enumerate(zip(vrow, vcol)):
            if tz is not None and rr == ty and cc == tx:
                vh[i] = tz
    return dict(
        vertex_row=dimap_to_pixel(vrow),
        vertex_col=dimap_to_pixel(vcol),
        vertex_lon=np.array(vlon),
        vertex_lat=np.array(vlat),
        vertex_h_m=vh,
        center_row=float(dimap_to_pixel(c_row)),
        center_col=float(dimap_to_pixel(c_col)),
        center_lon=c_lon,
        center_lat=c_lat,
    )


def parse_dimap(path) -> DimapMetadata:
    """Parse the geometry of a SPOT 1-5 level-1A DIMAP metadata file, strictly.

    Parameters
    ----------
    path : str or Path
        The ``METADATA.DIM`` file.

    Returns
    -------
    DimapMetadata
        Image coordinates converted from DIMAP's 1-based pixel centres to gcpcal's
        (first pixel centre at 0.5); times in SI seconds since ``SCENE_CENTER_TIME`` (UTC).

    Raises
    ------
    ManifestError
        A needed field is missing, empty, not a number, not finite, or a time list does not
        increase strictly; the error names the file and the XML path of the field.
    """
    path = Path(path)
    x = _Xml(path)
    source = _source(x)
    timing = _line_timing(x)
    ephemeris = _ephemeris(x, timing["epoch"])
    attitudes = _attitudes(x, timing["epoch"], source["mission"])
    looks = _look_angles(x, source["n_cols"])
    frame = _frame(x)
    return DimapMetadata(path=str(path), **source, **timing, **ephemeris, **attitudes, **looks, **frame)


# ---------------------------------------------------------------------------------------------
# SPOT frames


def spot_orbital_to_itrf_mat(position_m, velocity_m_s) -> np.ndarray:
    """SPOT local orbital frame -> ITRF, shape (N, 3, 3) (columns: X, Y, Z axes in ITRF).

    ``Z = P/|P|``, ``X = V x Z / |V x Z|``, ``Y = Z x X`` with the ITRF position and the
    Earth-relative velocity (SPOT Geometry Handbook; as OSSIM's ``ossimSpot5Model``).

    Parameters
    ----------
    position_m : array_like, shape (N, 3) or (3,)
        ITRF positions, metres.
    velocity_m_s : array_like, shape (N, 3) or (3,)
        Earth-relative ITRF velocities, m/s.

    Returns
    -------
    ndarray, shape (N, 3, 3)
        Rotation matrices orbital -> ITRF.
    """
    p = np.atleast_2d(np.asarray(position_m, dtype=np.float64))
    v = np.atleast_2d(np.asarray(velocity_m_s, dtype=np.float64))
    z = p / np.linalg.norm(p, axis=-1, keepdims=True)
    x = np.cross(v, z)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def spot_satellite_to_orbital_mat(yaw, pitch, roll) -> np.ndarray:
    """SPOT satellite (navigation) frame -> local orbital frame, shape (N, 3, 3).

    ``Rx(-pitch) @ Ry(-roll) @ Rz(yaw)`` (active rotations): the file's roll and pitch are
    given about the reversed (-X, -Y) axes (SPOT Geometry Handbook).

    Parameters
    ----------
    yaw, pitch, roll : array_like, shape (N,) or scalar
        Attitude angles as the DIMAP file gives them (SPOT convention), radians.

    Returns
    -------
    ndarray, shape (N, 3, 3)
        Rotation matrices satellite -> local orbital frame.
    """
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (yaw, pitch, roll))
    angles = np.stack([-pitch, -roll, yaw], axis=-1)
    return Rotation.from_euler("XYZ", angles).as_matrix()  # intrinsic X-Y-Z = Rx @ Ry @ Rz


def spot_look_to_camera(psi_x, psi_y):
    """SPOT look angles -> gcpcal camera-frame ``(tan psi_x, tan psi_y)``.

    The SPOT direction ``(-tan PSI_Y, tan PSI_X, -1)`` is, in the camera frame
    (``CAMERA_TO_SPOT``), ``(tan PSI_X, -tan PSI_Y, 1)``.

    Parameters
    ----------
    psi_x, psi_y : array_like
        ``PSI_X`` (along track) and ``PSI_Y`` (across track) look angles, radians.

    Returns
    -------
    tan_psi_x, tan_psi_y : ndarray of float64
        Camera-frame direction tangents, same shape as the inputs.
    """
    return np.tan(np.asarray(psi_x, dtype=np.float64)), -np.tan(np.asarray(psi_y, dtype=np.float64))


# ---------------------------------------------------------------------------------------------
# attitude


def _integrate_speeds(t, speeds: DimapAngles, t0: float, a0: np.ndarray) -> np.ndarray:
    """``a(t) = a0 + integral_{t0}^{t} w(tau) dtau`` for yaw, pitch, roll, shape (N, 3).

    ``w`` is the piecewise-linear interpolant of the valid angular-speed samples, held
    constant beyond the first and the last sample (exact trapezoid integration).
    """
    ok = ~speeds.out_of_range
    ts = speeds.seconds[ok]
    w = np.stack([speeds.yaw[ok], speeds.pitch[ok], speeds.roll[ok]], axis=-1)
    # knots: sample times plus the query and the start, integrate piecewise-linear exactly
    grid = np.unique(np.concatenate([ts, np.atleast_1d(t), [t0]]))
    wg = np.stack([np.interp(grid, ts, w[:, k]) for k in range(3)], axis=-1)  # held beyond the ends
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (wg[1:] + wg[:-1]) * np.diff(grid)[:, None], axis=0)])
    at = np.stack([np.interp(t, grid, cum[:, k]) for k in range(3)], axis=-1)
    a_t0 = np.array([np.interp(t0, grid, cum[:, k]) for k in range(3)])
    return a0 + at - a_t0


def attitude_angles(meta: DimapMetadata, seconds) -> np.ndarray:
    """Yaw, pitch, roll (SPOT convention, radians) at ``seconds``, shape (N, 3).

    SPOT 5: the corrected (absolute) angles, interpolated linearly. SPOT 1-4: the first
    valid absolute AOCS sample plus the integral of the angular speeds from its time.

    Parameters
    ----------
    meta : DimapMetadata
        The parsed file.
    seconds : array_like, shape (N,) or scalar
        SI seconds since ``meta.epoch``.

    Returns
    -------
    ndarray, shape (N, 3)
        Yaw, pitch, roll in radians (not yet converted to gcpcal's frames).

    Raises
    ------
    ManifestError
        Fewer than two valid corrected-attitude or angular-speed samples.
    """
    t = np.atleast_1d(np.asarray(seconds, dtype=np.float64))
    if meta.corrected_angles is not None:
        c = meta.corrected_angles
        ok = ~c.out_of_range
        if ok.sum() < 2:
            raise ManifestError("fewer than two valid corrected attitude samples", path=meta.path, field=c.field)
        return np.stack([np.interp(t, c.seconds[ok], a[ok]) for a in (c.yaw, c.pitch, c.roll)], axis=-1)
    if meta.angular_speeds is None:
        raise ManifestError("neither corrected attitudes nor angular speeds", path=meta.path, field=meta.raw_angles.field)
    raw = meta.raw_angles
    valid = np.nonzero(~raw.out_of_range)[0]
    if valid.size:
        i = int(valid[0])
        t0, a0 = raw.seconds[i], np.array([raw.yaw[i], raw.pitch[i], raw.roll[i]])
    else:  # no valid absolute sample: the nominal attitude (zero) at the first speed sample
        t0, a0 = meta.angular_speeds.seconds[0], np.zeros(3)
    if (~meta.angular_speeds.out_of_range).sum() < 2:
        raise ManifestError("fewer than two valid angular speed samples", path=meta.path, field=meta.angular_speeds.field)
    return _integrate_speeds(t, meta.angular_speeds, t0, a0)


def _attitude_seconds(meta: DimapMetadata) -> np.ndarray:
    t_first = meta.seconds(0.0)
    t_last = meta.seconds(float(meta.n_rows))
    lo = min(t_first, t_last) - ATTITUDE_MARGIN_S - 0.1 * abs(t_last - t_first)
    hi = max(t_first, t_last) + ATTITUDE_MARGIN_S + 0.1 * abs(t_last - t_first)
    lo = max(lo, meta.ephemeris_seconds[0])
    hi = min(hi, meta.ephemeris_seconds[-1])
    n = int(np.ceil((hi - lo) / ATTITUDE_STEP_S)) + 1
    return np.linspace(lo, hi, n)


def dimap_orbit(meta: DimapMetadata):
    """The ITRF orbit of a DIMAP file.

    Parameters
    ----------
    meta : DimapMetadata
        The parsed file.

    Returns
    -------
    Orbit
        Frame ``"itrf"``, seconds since ``meta.epoch``, positions in metres and Earth-relative
        velocities in m/s (inertial file velocities are converted).
    """
    from sensor_models.geometry.ephemeris import Orbit

    return Orbit(meta.epoch, meta.ephemeris_seconds, meta.position_m, meta.earth_relative_velocity_m_s, frame="itrf")


def body_to_itrf(meta: DimapMetadata, seconds, orbit=None, *, attitude: str = "measured") -> np.ndarray:
    """gcpcal body (= camera) frame -> ITRF rotations at ``seconds``, shape (N, 3, 3).

    The SPOT local orbital frame is built with the velocity of the kind the file gives
    (inertial for SPOT 1-4, Earth-relative for SPOT 5): that is the frame the ground segment
    used (the other choice misplaces the frame vertices by 0.2 to 20 km).

    Parameters
    ----------
    meta : DimapMetadata
        The parsed file.
    seconds : array_like, shape (N,) or scalar
        SI seconds since ``meta.epoch``.
    orbit : Orbit, optional
        The ITRF orbit (default :func:`dimap_orbit`).
    attitude : {"measured", "nominal"}
        ``"measured"``: the file's attitude (see :func:`attitude_angles`); ``"nominal"``: zero
        yaw, pitch and roll (the satellite frame on the local orbital frame).

    Returns
    -------
    ndarray, shape (N, 3, 3)
        Rotation matrices body -> ITRF (body = camera, ``CAMERA_TO_SPOT`` included).
    """
    if attitude not in ATTITUDE_MODES:
        raise InputError(f"must be one of {ATTITUDE_MODES}, got {attitude!r}", field="attitude")
    seconds = np.atleast_1d(np.asarray(seconds, dtype=np.float64))
    if orbit is None:
        orbit = dimap_orbit(meta)
    pos, vel = orbit.state(seconds)
    if meta.velocity_kind == "inertial":
        vel = vel + np.cross([0.0, 0.0, EARTH_ROTATION_RAD_S], pos)
    if attitude == "measured":
        ypr = attitude_angles(meta, seconds)
    else:
        ypr = np.zeros((seconds.size, 3))
    sat_to_orb = spot_satellite_to_orbital_mat(ypr[:, 0], ypr[:, 1], ypr[:, 2])
    return spot_orbital_to_itrf_mat(pos, vel) @ sat_to_orb @ CAMERA_TO_SPOT


# ---------------------------------------------------------------------------------------------
# directional angles


@dataclass(frozen=True)
class LookFit:
    """A per-detector directional-angle polynomial fit of one band.

    Attributes
    ----------
    tan_psi_x, tan_psi_y : ndarray
        Coefficients in the detector index ``s`` (gcpcal camera frame).
    degree : int
    max_residual_px, rms_residual_px : float
        Fit residuals over the detectors, in pixels (detector IFOVs), the larger of the two
        axes.
    n_samples : int
        Detector directions the fit used (listed or, for SPOT 1-4, reconstructed).
    """

    tan_psi_x: np.ndarray
    tan_psi_y: np.ndarray
    degree: int
    max_residual_px: float
    rms_residual_px: float
    n_samples: int


def _detector_tans(look: DimapLookAngles, n_cols: int):
    """``(s, tan_x, tan_y)`` in the camera frame for every detector of the band.

    SPOT 5 lists every detector. SPOT 1-4 list the first and the last: the array is linear in
    the focal plane and tilted by the mirror, so the directions are interpolated linearly in
    tangent space in the frame turned about the along-track axis by the mean of the two
    ``PSI_Y`` (where the two end directions are symmetric), then turned back.
    """
    if look.detector_id.size == n_cols or look.detector_id.size > 2:
        s = look.detector_id - 1.0
        tx, ty = spot_look_to_camera(look.psi_x, look.psi_y)
        return s, tx, ty
    s_end = look.detector_id - 1.0
    theta = 0.5 * (look.psi_y[0] + look.psi_y[-1])
    # camera vectors of the two ends, rotated about camera X (along track) by the tilt
    tx, ty = spot_look_to_camera(look.psi_x, look.psi_y)
    v = np.stack([tx, ty, np.ones_like(tx)], axis=-1)
    c, sn = np.cos(theta), np.sin(theta)
    # camera tan_y = -tan(PSI_Y): a tilt PSI_Y is the rotation Rx(PSI_Y) of (0, 0, 1)
    rot = np.array([[1.0, 0.0, 0.0], [0.0, c, -sn], [0.0, sn, c]])  # Rx(theta): the tilt
    m = v @ rot  # Rx(theta)^T v: the directions with the tilt removed
    mx, my = m[:, 0] / m[:, 2], m[:, 1] / m[:, 2]
    s = np.arange(n_cols, dtype=np.float64)
    fx = np.interp(s, s_end, mx)
    fy = np.interp(s, s_end, my)
    w = np.stack([fx, fy, np.ones_like(fx)], axis=-1) @ rot.T  # tilt back: Rx(theta) m
    return s, w[:, 0] / w[:, 2], w[:, 1] / w[:, 2]


def fit_look_polynomials(look: DimapLookAngles, n_cols: int, *, max_residual_px: float = MAX_FIT_RESIDUAL_PX) -> LookFit:
    """Fit ``tan psi_x(s)``, ``tan psi_y(s)`` polynomials to a band's detector directions.

    The degree starts at 3 (seed 003) and rises, up to 7, until the largest residual is below
    ``max_residual_px`` detector IFOVs (the IFOV being the median across-track step between
    neighbouring detectors). The fit is done in a scaled variable for conditioning, then
    converted to powers of ``s``.

    Parameters
    ----------
    look : DimapLookAngles
        The band's detector look angles.
    n_cols : int
        Detectors (image columns) of the band.
    max_residual_px : float
        Target largest residual, in detector IFOVs (about pixels).

    Returns
    -------
    LookFit
        Coefficients of ``tan psi_x`` and ``tan psi_y`` in powers of the 0-based detector index
        ``s`` (detector ``s`` images column ``s + 0.5``), the degree and the residuals in IFOVs.
    """
    s, tx, ty = _detector_tans(look, n_cols)
    if s.size >= 2:
        ifov = float(np.median(np.abs(np.diff(ty) / np.diff(s))))
    else:
        ifov = np.nan
    half = max(0.5 * (s[-1] - s[0]), 1.0)
    mid = 0.5 * (s[-1] + s[0])
    u = (s - mid) / half
    best = None
    for degree in range(3, MAX_DEGREE + 1):
        deg = min(degree, s.size - 1)
        cx = np.polynomial.polynomial.polyfit(u, tx, deg)
        cy = np.polynomial.polynomial.polyfit(u, ty, deg)
        rx = tx - np.polynomial.polynomial.polyval(u, cx)
        ry = ty - np.polynomial.polynomial.polyval(u, cy)
        res = np.maximum(np.abs(rx), np.abs(ry)) / ifov
        best = (deg, cx, cy, float(res.max()), float(np.sqrt(np.mean(np.maximum(rx**2, ry**2)))) / ifov)
        if best[3] <= max_residual_px or deg == s.size - 1:
            break
    deg, cx, cy, rmax, rrms = best
    # powers of u = (s - mid)/half -> powers of s
    shift = np.polynomial.Polynomial([-mid / half, 1.0 / half])
    px = np.polynomial.Polynomial(cx)(shift).coef
    py = np.polynomial.Polynomial(cy)(shift).coef
    return LookFit(px, py, deg, rmax, rrms, int(s.size))


# ---------------------------------------------------------------------------------------------
# the model


def read_dimap(path, *, band: int | None = None, attitude: str = "measured", self_check: str = "refuse"):
    """Build a :class:`~sensor_models.models.pushbroom.PushbroomModel` from a SPOT 1-5 DIMAP file.

    Parameters
    ----------
    path : str or Path
        The ``METADATA.DIM`` file.
    band : int, optional
        ``BAND_INDEX`` whose look angles are used (default: every band in the file, each as
        a model band named ``"B<index>"``; the first is the reference band).
    attitude : {"measured", "nominal"}
        The file's attitude or the nominal one (see :func:`body_to_itrf`).
    self_check : {"refuse", "warn"}
        What to do when the model misses the file's frame vertices and scene centre beyond the
        tolerance (:func:`~sensor_models.readers.product_checks.check_dimap`): raise, or return
        the model with the disagreement recorded in ``model.product_check``.

    Returns
    -------
    PushbroomModel
        ITRF orbit, body -> ITRF attitude samples every ``ATTITUDE_STEP_S`` over the scene
        plus a margin, identity installation, one CCD per band spanning all columns, with
        ``tan psi`` polynomials fitted to the detector directions (see
        :func:`fit_look_polynomials`). ``model.dimap_fits`` holds the fits per band,
        ``model.product_check`` the :class:`~sensor_models.readers.self_check.ProductCheck`.

    Raises
    ------
    ManifestError
        Malformed metadata (:func:`parse_dimap`) or no look angles for ``band``.
    ProductDisagreementError
        The model disagrees with the frame (``self_check="refuse"``).
    """
    from sensor_models.readers.product_checks import check_dimap
    from sensor_models.readers.self_check import check_policy, enforce

    if attitude not in ATTITUDE_MODES:
        raise InputError(f"must be one of {ATTITUDE_MODES}, got {attitude!r}", field="attitude")
    check_policy(self_check)
    meta = parse_dimap(path)
    looks = meta.look_angles
    if band is not None:
        looks = tuple(lk for lk in looks if lk.band_index == band)
        if not looks:
            raise ManifestError(f"no look angles for BAND_INDEX {band}", path=meta.path,
                                field=f"{_ROOT}/Data_Strip/Sensor_Configuration/Instrument_Look_Angles_List")
    fits = {f"B{lk.band_index}": fit_look_polynomials(lk, meta.n_cols) for lk in looks}
    model = _build_model(meta, fits, attitude)
    model.product_check = enforce(check_dimap(model, meta, attitude, self_check,
                                              lambda other: _build_model(meta, fits, other)))
    return model


def _build_model(meta: DimapMetadata, fits: dict, attitude: str):
    """The push-broom model of parsed DIMAP metadata with fitted look polynomials and an attitude mode."""
    from sensor_models.geometry.ephemeris import Attitude
    from sensor_models.models.pushbroom import PushbroomModel
    from sensor_models.models.pushbroom_types import CcdLook, LineTiming

    try:
        orbit = dimap_orbit(meta)
        seconds = _attitude_seconds(meta)
        rot = body_to_itrf(meta, seconds, orbit, attitude=attitude)
        att = Attitude(seconds, Rotation.from_matrix(rot).as_quat(), frame="itrf")
        timing = LineTiming(meta.reference_row, 0.0, meta.line_period_s)
    except InputError as exc:
        if isinstance(exc, ManifestError):
            raise
        raise ManifestError(exc.reason, path=meta.path, field=exc.field) from None
    bands = {name: [CcdLook("ccd1", 0, meta.n_cols, fit.tan_psi_x, fit.tan_psi_y)] for name, fit in fits.items()}
    model = PushbroomModel(
        orbit=orbit,
        attitude=att,
        line_timing=timing,
        bands=bands,
        n_rows=meta.n_rows,
        name=f"SPOT{meta.mission} {meta.instrument} {meta.sensor_code} {meta.epoch}",
    )
    model.dimap_fits = fits
    model.dimap_metadata = meta
    return model
