"""SPOT 1-5 DIMAP level-1A metadata parsed strictly into a :class:`DimapMetadata` of plain arrays.

:func:`parse_dimap` reads the geometric content of a SPOT scene ``METADATA.DIM`` (DIMAP 1.1,
profile ``SPOTSCENE_1A``): source and raster dimensions, line timing, ephemeris, raw and
corrected attitudes, detector look angles and the frame with its tie-point heights. Image
coordinates are converted to gcpcal's convention and times to SI seconds since
``SCENE_CENTER_TIME``; the conventions are in :mod:`sensor_models.readers.dimap` and
``docs/dimap.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sensor_models.readers.dimap_common import (
    DIMAP_ROOT,
    EARTH_ROTATION_RAD_S,
    DimapXml,
    check_increasing,
    dimap_to_pixel,
    ephemeris_velocity_kind,
    seconds_since,
)

__all__ = ["DimapAngles", "DimapLookAngles", "DimapMetadata", "parse_dimap"]


@dataclass(frozen=True)
class DimapAngles:
    """Yaw, pitch and roll samples (radians, or radians per second for angular speeds).

    Attributes
    ----------
    seconds : ndarray, shape (N,)
        SI seconds since the scene epoch, strictly increasing.
    yaw, pitch, roll : ndarray, shape (N,)
        As in the file: in the SPOT convention (see :mod:`sensor_models.readers.dimap`), not yet
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


def _angles(x: DimapXml, parent, rel: str, where: str, epoch, *, minimum: int) -> DimapAngles:
    items = x.nodes(parent, rel, where, minimum=minimum)
    times, yaw, pitch, roll, oor = [], [], [], [], []
    for el in items:
        times.append(x.time(el, "TIME", f"{where}/TIME"))
        yaw.append(x.number(el, "YAW", f"{where}/YAW"))
        pitch.append(x.number(el, "PITCH", f"{where}/PITCH"))
        roll.append(x.number(el, "ROLL", f"{where}/ROLL"))
        oor.append(x.flag(el, "OUT_OF_RANGE", f"{where}/OUT_OF_RANGE", optional=True) or False)
    seconds = seconds_since(times, epoch)
    check_increasing(x, seconds, f"{where}/TIME")
    return DimapAngles(seconds, np.array(yaw), np.array(pitch), np.array(roll), np.array(oor, dtype=bool), where)


def _source(x: DimapXml) -> dict:
    """Format check, mission, instrument, raster dimensions and pixel origin."""
    r, R = x.root, DIMAP_ROOT
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


def _line_timing(x: DimapXml) -> dict:
    """Line period, scene epoch (``SCENE_CENTER_TIME``) and its line, converted to 0.5-based rows."""
    ts = f"{DIMAP_ROOT}/Data_Strip/Sensor_Configuration/Time_Stamp"
    tnode = x.node(x.root, "Data_Strip/Sensor_Configuration/Time_Stamp", ts)
    line_period = x.number(tnode, "LINE_PERIOD", f"{ts}/LINE_PERIOD")
    if not line_period > 0.0:
        raise x.error(f"{ts}/LINE_PERIOD", f"must be positive, got {line_period}")
    epoch = x.time(tnode, "SCENE_CENTER_TIME", f"{ts}/SCENE_CENTER_TIME")
    center_line = x.number(tnode, "SCENE_CENTER_LINE", f"{ts}/SCENE_CENTER_LINE")
    return dict(epoch=epoch, line_period_s=line_period, reference_row=float(dimap_to_pixel(center_line)))


def _ephemeris(x: DimapXml, epoch) -> dict:
    """ITRF state vectors, their seconds since ``epoch`` and the kind of velocity."""
    eph = f"{DIMAP_ROOT}/Data_Strip/Ephemeris"
    enode = x.node(x.root, "Data_Strip/Ephemeris", eph)
    points = x.nodes(enode, "Points/Point", f"{eph}/Points/Point", minimum=4)
    times, pos, vel = [], [], []
    for p in points:
        w = f"{eph}/Points/Point"
        times.append(x.time(p, "TIME", f"{w}/TIME"))
        pos.append([x.number(p, f"Location/{a}", f"{w}/Location/{a}") for a in "XYZ"])
        vel.append([x.number(p, f"Velocity/{a}", f"{w}/Velocity/{a}") for a in "XYZ"])
    eph_seconds = seconds_since(times, epoch)
    check_increasing(x, eph_seconds, f"{eph}/Points/Point/TIME")
    position = np.array(pos)
    radius = np.linalg.norm(position, axis=1)
    if np.any((radius < 6.3e6) | (radius > 8.0e6)):
        raise x.error(f"{eph}/Points/Point/Location", "positions must be metres from the Earth's centre (LEO)")
    doris = x.flag(enode, "DORIS_USED", f"{eph}/DORIS_USED", optional=True) or False
    velocity = np.array(vel)
    velocity_kind = ephemeris_velocity_kind(x, eph_seconds, position, velocity, f"{eph}/Points/Point/Velocity")
    return dict(
        ephemeris_seconds=eph_seconds,
        position_m=position,
        velocity_m_s=velocity,
        velocity_kind=velocity_kind,
        doris_used=doris,
    )


def _attitudes(x: DimapXml, epoch, mission: int) -> dict:
    """Raw AOCS angles, angular speeds (SPOT 1-4) and corrected angles (SPOT 5)."""
    att = f"{DIMAP_ROOT}/Data_Strip/Satellite_Attitudes"
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


def _look_angles(x: DimapXml, n_cols: int) -> dict:
    """Detector look angles of every band and the mirror step count."""
    sc = f"{DIMAP_ROOT}/Data_Strip/Sensor_Configuration"
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


def _frame(x: DimapXml) -> dict:
    """Frame vertices and scene centre (DIMAP 1-based -> ours) with the tie-point heights."""
    r = x.root
    fw = f"{DIMAP_ROOT}/Dataset_Frame"
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
    tw = f"{DIMAP_ROOT}/Geoposition/Geoposition_Points/Tie_Point"
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
    x = DimapXml(path)
    source = _source(x)
    timing = _line_timing(x)
    ephemeris = _ephemeris(x, timing["epoch"])
    attitudes = _attitudes(x, timing["epoch"], source["mission"])
    looks = _look_angles(x, source["n_cols"])
    frame = _frame(x)
    return DimapMetadata(path=str(path), **source, **timing, **ephemeris, **attitudes, **looks, **frame)
