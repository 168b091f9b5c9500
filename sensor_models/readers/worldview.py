"""DigitalGlobe/Maxar WorldView-1/2/3 and QuickBird level-1B metadata (the ``<isd>`` XML).

:func:`parse_worldview` reads the geometric content of a Basic1B product's combined XML (root
``<isd>`` with the ``IMD``, ``EPH``, ``ATT``, ``GEO``, ``RPB`` and ``TIL`` sections) into a
:class:`WorldViewMetadata` of plain arrays; :func:`read_worldview` builds a rigorous
:class:`~sensor_models.models.pushbroom.PushbroomModel` from it (the line-of-sight physics lives in
:mod:`sensor_models.readers.worldview_los`). Frames and conventions are described, with their
sources and the measured agreement, in ``docs/worldview.md``; in short:

* Times are UTC ISO strings. The model epoch is ``IMAGE/FIRSTLINETIME``. Line ``L`` (0-based,
  DigitalGlobe's count) is imaged at ``TLCTIME + t(L)``, ``t`` interpolated linearly in the
  ``TLCLIST`` pairs ``(line, seconds)``; the seconds decrease for a ``Reverse`` scan.
* DigitalGlobe lines and samples count pixel *centres* from 0 (as the RPC00B does): our
  ``row = line + 0.5``, ``col = sample + 0.5``.
* ``EPH``: ITRF (WGS84 ECEF) positions (m) and Earth-relative velocities (m/s) every
  ``TIMEINTERVAL`` seconds from ``STARTTIME``; ``ATT``: unit quaternions ``q1 q2 q3 q4``
  (``q4`` scalar) rotating body vectors into ITRF.
* ``GEO``: detector ``c`` of the (virtual) array sits in the focal plane at
  ``(DETORIGINX, DETORIGINY - c * DETPITCH)`` mm; its line of sight in the camera frame is
  ``(x, y, PD)`` with ``PD`` the principal distance (mm); the camera frame is turned into the
  body frame by the ``CAMERA_ATTITUDE`` quaternion.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sensor_models.errors import InputError, ManifestError
from sensor_models.readers._xml import StrictXml

__all__ = [
    "WorldViewBand",
    "WorldViewMetadata",
    "dg_to_pixel",
    "is_worldview",
    "parse_worldview",
    "pixel_to_dg",
    "raster_paths",
    "read_worldview",
    "read_worldview_checked",
]

_ROOT = "isd"
_SECTIONS = ("IMD", "EPH", "ATT", "GEO")
#: largest tolerated departure of the TLC list from a straight line (lines)
TLC_LINEARITY_TOL_LINES = 0.01
#: largest tolerated |norm - 1| of an attitude quaternion
QUATERNION_NORM_TOL = 1e-6
#: largest disagreement (m/s) tolerated between the EPH velocities and dP/dt
VELOCITY_TOLERANCE_M_S = 1.0
#: IMD corner names in their order (image corners, clockwise from the first pixel)
CORNERS = ("UL", "UR", "LR", "LL")


def dg_to_pixel(line_or_sample):
    """DigitalGlobe 0-based pixel-centre coordinates -> gcpcal's (first pixel centre at 0.5).

    Parameters
    ----------
    line_or_sample : array_like
        Lines or samples as the ``TLCLIST``, ``TIL`` offsets and ``RPB`` count them.

    Returns
    -------
    ndarray of float64
        ``value + 0.5``, same shape.
    """
    return np.asarray(line_or_sample, dtype=np.float64) + 0.5


def pixel_to_dg(row_or_col):
    """gcpcal pixel coordinates -> DigitalGlobe 0-based pixel-centre coordinates.

    Parameters
    ----------
    row_or_col : array_like
        Rows or columns in gcpcal's convention (first pixel centre at 0.5).

    Returns
    -------
    ndarray of float64
        ``value - 0.5``, same shape.
    """
    return np.asarray(row_or_col, dtype=np.float64) - 0.5


# ---------------------------------------------------------------------------------------------
# parsed content


@dataclass(frozen=True)
class WorldViewBand:
    """One band: its detector array (``GEO``) and its corners (``IMD/BAND_<id>``).

    Attributes
    ----------
    band_id : str
        ``P``, ``B``, ``G``, ``R``, ``N``, ``C``, ``Y``, ``RE``, ``N2`` ...
    det_origin_x_mm, det_origin_y_mm : float
        ``DETORIGINX``, ``DETORIGINY``: focal-plane position of detector 0 (mm).
    det_pitch_mm : float
        ``DETPITCH``: spacing of the virtual detectors along the array (mm).
    det_rot_angle : float
        ``DETROTANGLE`` (only 0 is accepted: no product with another value was available to
        establish its sign).
    corner_lon, corner_lat, corner_hae_m : ndarray, shape (4,)
        ``UL, UR, LR, LL`` corners (degrees WGS84 and metres above the ellipsoid).
    tdi_level : int or None
        ``TDILEVEL``.
    """

    band_id: str
    det_origin_x_mm: float
    det_origin_y_mm: float
    det_pitch_mm: float
    det_rot_angle: float
    corner_lon: np.ndarray
    corner_lat: np.ndarray
    corner_hae_m: np.ndarray
    tdi_level: int | None


@dataclass(frozen=True)
class WorldViewMetadata:
    """The geometric content of a DigitalGlobe level-1B ``<isd>`` XML.

    Times are SI seconds since ``epoch`` (``FIRSTLINETIME``, UTC); image coordinates follow
    gcpcal (first pixel centre 0.5).

    Attributes
    ----------
    path : str
    satellite : str
        ``SATID`` (``WV01``, ``WV02``, ``WV03``, ``QB02``).
    image_descriptor : str
        ``IMAGEDESCRIPTOR`` (``Basic1B`` ...).
    n_rows, n_cols : int
        ``NUMROWS``, ``NUMCOLUMNS``.
    epoch : numpy.datetime64
        ``FIRSTLINETIME`` (UTC, ns).
    scan_direction : str
        ``Forward`` or ``Reverse``.
    tlc_lines, tlc_seconds : ndarray, shape (K,)
        ``TLCLIST`` (0-based DigitalGlobe lines; seconds since ``epoch``).
    line_period_s : float
        Slope of the TLC list (negative for a reverse scan).
    first_line_seconds : float
        Time of DigitalGlobe line 0 (our row 0.5), seconds since ``epoch``.
    avg_line_rate_hz : float
        ``AVGLINERATE``.
    ephemeris_seconds : ndarray, shape (N,)
    position_m, velocity_m_s : ndarray, shape (N, 3)
        ITRF (WGS84 ECEF) state vectors.
    attitude_seconds : ndarray, shape (M,)
    quaternions_xyzw : ndarray, shape (M, 4)
        Body -> ITRF (``q1 q2 q3 q4``, scalar last).
    principal_distance_mm : float
    camera_to_body_xyzw : ndarray, shape (4,)
        ``CAMERA_ATTITUDE`` ``QCS1..QCS4`` (scalar last).
    perspective_center_m : ndarray, shape (3,)
        ``CX, CY, CZ`` (only zero is accepted).
    bands : tuple of WorldViewBand
    rpb : dict or None
        The ``RPB/IMAGE`` values under :class:`~sensor_models.models.rpc.RpcModel` keyword names.
    tile_files : tuple of str
        ``TIL/TILE/FILENAME`` entries, as written.
    """

    path: str
    satellite: str
    image_descriptor: str
    n_rows: int
    n_cols: int
    epoch: np.datetime64
    scan_direction: str
    tlc_lines: np.ndarray
    tlc_seconds: np.ndarray
    line_period_s: float
    first_line_seconds: float
    avg_line_rate_hz: float
    ephemeris_seconds: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    attitude_seconds: np.ndarray
    quaternions_xyzw: np.ndarray
    principal_distance_mm: float
    camera_to_body_xyzw: np.ndarray
    perspective_center_m: np.ndarray
    bands: tuple
    rpb: dict | None
    tile_files: tuple

    def seconds(self, row):
        """Imaging time of continuous rows.

        Parameters
        ----------
        row : array_like
            Continuous rows (gcpcal convention, first line centre 0.5).

        Returns
        -------
        ndarray of float64
            SI seconds since ``epoch``, same shape.
        """
        return self.first_line_seconds + pixel_to_dg(row) * self.line_period_s

    def band(self, band_id: str) -> WorldViewBand:
        """The band named ``band_id``.

        Parameters
        ----------
        band_id : str
            A ``BANDID`` of ``GEO/DETECTOR_MOUNTING`` (``"P"`` ...).

        Returns
        -------
        WorldViewBand

        Raises
        ------
        InputError
            No such band; the message lists the bands there are.
        """
        for b in self.bands:
            if b.band_id == band_id:
                return b
        names = ", ".join(b.band_id for b in self.bands)
        raise InputError(f"no band {band_id!r} in the product (bands: {names})", path=self.path, field="band")

    def rpc_model(self):
        """The vendor RPC of the ``RPB`` section.

        Returns
        -------
        RpcModel or None
            With ``image_shape = (n_rows, n_cols)``; None when the XML has no ``RPB``.
        """
        if self.rpb is None:
            return None
        from sensor_models.models.rpc import RpcModel

        return RpcModel(**self.rpb, image_shape=(self.n_rows, self.n_cols), source=self.path)


# ---------------------------------------------------------------------------------------------
# strict XML access


class _Xml(StrictXml):
    """Strict typed access to the ``<isd>`` tree; errors name the file and the XML path."""

    ROOT = _ROOT
    DOCUMENT = "DigitalGlobe level-1B XML"

    def field_path(self, where: str, rel: str) -> str:
        return f"{where}/{rel}"

    def time(self, parent, rel: str, where: str) -> np.datetime64:
        from sensor_models.geometry.timescales import parse_utc

        value = self.text(parent, rel, where)
        try:
            return parse_utc(value)
        except InputError as exc:
            raise self.error(f"{where}/{rel}", exc.reason) from None

    def rows(self, parent, rel: str, where: str, n_values: int, n_rows: int | None = None):
        """Whitespace-separated number rows (``EPHEMLIST``, ``ATTLIST``, ``TLCLIST``)."""
        lst = self.node(parent, rel, where)
        items = list(lst)
        field = f"{where}/{rel}"
        if n_rows is not None and len(items) != n_rows:
            raise self.error(field, f"holds {len(items)} entries, the count field says {n_rows}")
        if not items:
            raise self.error(field, "is empty")
        out = np.empty((len(items), n_values))
        for i, item in enumerate(items):
            tokens = (item.text or "").split()
            if len(tokens) != n_values:
                raise self.error(f"{field}/{item.tag}[{i + 1}]", f"needs {n_values} numbers, got {len(tokens)}")
            try:
                out[i] = [float(t) for t in tokens]
            except ValueError:
                raise self.error(f"{field}/{item.tag}[{i + 1}]", f"holds a non-number: {item.text.strip()[:60]!r}") from None
        if not np.all(np.isfinite(out)):
            raise self.error(field, "holds NaN or infinite values")
        return out


def _seconds_since(t, epoch) -> float:
    """SI seconds from ``epoch`` to ``t`` (UTC; no leap second falls inside a product)."""
    return float((np.datetime64(t, "ns") - epoch).astype(np.int64)) * 1e-9


# ---------------------------------------------------------------------------------------------
# sections


def _sampled_times(x: _Xml, sec, where: str, index_col: np.ndarray, epoch) -> np.ndarray:
    """Times of EPH/ATT rows: ``STARTTIME + (index - 1) * TIMEINTERVAL`` (index 1-based)."""
    start = _seconds_since(x.time(sec, "STARTTIME", where), epoch)
    step = x.number(sec, "TIMEINTERVAL", where, positive=True)
    expected = np.arange(1, index_col.size + 1, dtype=np.float64)
    if not np.array_equal(index_col, expected):
        bad = int(np.nonzero(index_col != expected)[0][0])
        raise x.error(f"{where}/{'EPHEMLISTList' if where.endswith('EPH') else 'ATTLISTList'}",
                      f"entry {bad + 1} has index {index_col[bad]:g}, expected {bad + 1}: the "
                      "entries must be numbered 1, 2, 3 ...")
    return start + (index_col - 1.0) * step


def _ephemeris(x: _Xml, epoch):
    where = "isd/EPH"
    sec = x.node(x.root, "EPH", "isd")
    n = x.integer(sec, "NUMPOINTS", where, minimum=4)
    rows = x.rows(sec, "EPHEMLISTList", where, 13, n)
    seconds = _sampled_times(x, sec, where, rows[:, 0], epoch)
    pos, vel = rows[:, 1:4], rows[:, 4:7]
    radius = np.linalg.norm(pos, axis=1)
    if np.any(radius < 6.4e6) or np.any(radius > 5.0e7):
        raise x.error(f"{where}/EPHEMLISTList", "positions must be ECEF metres (radius 6 400 to 50 000 km)")
    dp = np.gradient(pos, seconds, axis=0, edge_order=2)
    worst = float(np.max(np.linalg.norm(dp - vel, axis=1)))
    if worst > VELOCITY_TOLERANCE_M_S:
        raise x.error(f"{where}/EPHEMLISTList", f"velocities differ from dP/dt by up to {worst:.2f} m/s "
                      f"(tolerance {VELOCITY_TOLERANCE_M_S} m/s): not Earth-relative ECEF velocities")
    return seconds, pos, vel


def _attitude(x: _Xml, epoch):
    where = "isd/ATT"
    sec = x.node(x.root, "ATT", "isd")
    n = x.integer(sec, "NUMPOINTS", where, minimum=4)
    rows = x.rows(sec, "ATTLISTList", where, 15, n)
    seconds = _sampled_times(x, sec, where, rows[:, 0], epoch)
    q = rows[:, 1:5]
    err = np.abs(np.linalg.norm(q, axis=1) - 1.0)
    if np.any(err > QUATERNION_NORM_TOL):
        i = int(np.argmax(err))
        raise x.error(f"{where}/ATTLISTList/ATTLIST[{i + 1}]", f"quaternion norm is off 1 by {err[i]:.2e}")
    return seconds, q / np.linalg.norm(q, axis=1, keepdims=True)


def _line_timing(x: _Xml, img, epoch):
    """TLC list -> (lines, seconds since epoch, period, time of line 0).

    The period is the slope between the first and the last entries; every entry must lie on
    that line within ``TLC_LINEARITY_TOL_LINES``.
    """
    where = "isd/IMD/IMAGE"
    t_tlc = _seconds_since(x.time(img, "TLCTIME", where), epoch)
    n = x.integer(img, "NUMTLC", where, minimum=2)
    tlc = x.rows(img, "TLCLISTList", where, 2, n)
    lines, seconds = tlc[:, 0], t_tlc + tlc[:, 1]
    if np.any(np.diff(lines) <= 0):
        raise x.error(f"{where}/TLCLISTList", "lines must increase strictly")
    slope = (seconds[-1] - seconds[0]) / (lines[-1] - lines[0])
    intercept = seconds[0] - slope * lines[0]
    if slope == 0.0:
        raise x.error(f"{where}/TLCLISTList", "line times do not change with the line")
    dev_lines = np.abs(seconds - (intercept + slope * lines)) / abs(slope)
    if np.max(dev_lines) > TLC_LINEARITY_TOL_LINES:
        raise x.error(f"{where}/TLCLISTList", f"line times depart from a constant line rate by "
                      f"{np.max(dev_lines):.3f} lines; only a constant rate is supported")
    return lines, seconds, float(slope), float(intercept)


def _corners(x: _Xml, band_el, where: str):
    lon, lat, hae = [], [], []
    for c in CORNERS:
        lon.append(x.number(band_el, f"{c}LON", where))
        lat.append(x.number(band_el, f"{c}LAT", where))
        hae.append(x.number(band_el, f"{c}HAE", where))
    return np.array(lon), np.array(lat), np.array(hae)


def _bands(x: _Xml, imd, geo) -> tuple:
    where = "isd/GEO/DETECTOR_MOUNTING"
    mounting = x.node(geo, "DETECTOR_MOUNTING", "isd/GEO")
    out = []
    for el in mounting:
        if not el.tag.startswith("BAND_"):
            continue
        bw = f"{where}/{el.tag}"
        band_id = x.text(el, "BANDID", bw)
        arrays = el.findall("DETECTOR_ARRAY")
        if len(arrays) != 1:
            raise x.error(f"{bw}/DETECTOR_ARRAY", f"needs exactly one (virtual) detector array, got {len(arrays)}")
        aw = f"{bw}/DETECTOR_ARRAY"
        arr = arrays[0]
        rot = x.number(arr, "DETROTANGLE", aw)
        if rot != 0.0:
            raise x.error(f"{aw}/DETROTANGLE", f"is {rot}; only 0 is supported (no product with a "
                          "rotated array was available to establish the sign convention)")
        iw = f"isd/IMD/{el.tag}"
        imd_band = x.node(imd, el.tag, "isd/IMD")
        lon, lat, hae = _corners(x, imd_band, iw)
        out.append(WorldViewBand(
            band_id=band_id,
            det_origin_x_mm=x.number(arr, "DETORIGINX", aw),
            det_origin_y_mm=x.number(arr, "DETORIGINY", aw),
            det_pitch_mm=x.number(arr, "DETPITCH", aw, positive=True),
            det_rot_angle=rot,
            corner_lon=lon, corner_lat=lat, corner_hae_m=hae,
            tdi_level=x.integer(imd_band, "TDILEVEL", iw, optional=True, minimum=1),
        ))  # fmt: skip
    if not out:
        raise x.error(f"{where}/BAND_*", "is missing: no band has a detector array")
    return tuple(out)


def _camera(x: _Xml, geo):
    where = "isd/GEO"
    pd = x.number(x.node(geo, "PRINCIPAL_DISTANCE", where), "PD", f"{where}/PRINCIPAL_DISTANCE", positive=True)
    dist = x.node(geo, "OPTICAL_DISTORTION", where, optional=True)
    if dist is not None:
        order = x.integer(dist, "POLYORDER", f"{where}/OPTICAL_DISTORTION")
        if order != -1:
            raise x.error(f"{where}/OPTICAL_DISTORTION/POLYORDER", f"is {order}; only -1 (no "
                          "distortion polynomial, as in Basic1B products) is supported")
    cw = f"{where}/CAMERA_ATTITUDE"
    cam = x.node(geo, "CAMERA_ATTITUDE", where)
    q = np.array([x.number(cam, f"QCS{i}", cw) for i in (1, 2, 3, 4)])
    if abs(np.linalg.norm(q) - 1.0) > QUATERNION_NORM_TOL:
        raise x.error(cw, f"QCS1..QCS4 norm is {np.linalg.norm(q):.9f}, expected 1")
    pw = f"{where}/PERSPECTIVE_CENTER"
    pc_el = x.node(geo, "PERSPECTIVE_CENTER", where)
    pc = np.array([x.number(pc_el, k, pw) for k in ("CX", "CY", "CZ")])
    if np.any(pc != 0.0):
        raise x.error(pw, f"is {pc.tolist()}; only a zero offset is supported (no product with "
                      "an offset was available to establish its units and frame)")
    return pd, q / np.linalg.norm(q), pc


_RPB_KEYS = {
    "line_off": "LINEOFFSET", "samp_off": "SAMPOFFSET", "lat_off": "LATOFFSET",
    "lon_off": "LONGOFFSET", "height_off": "HEIGHTOFFSET", "line_scale": "LINESCALE",
    "samp_scale": "SAMPSCALE", "lat_scale": "LATSCALE", "lon_scale": "LONGSCALE",
    "height_scale": "HEIGHTSCALE",
}  # fmt: skip
_RPB_COEFS = {"line_num": "LINENUMCOEF", "line_den": "LINEDENCOEF", "samp_num": "SAMPNUMCOEF", "samp_den": "SAMPDENCOEF"}


def _rpb(x: _Xml):
    sec = x.root.find("RPB")
    if sec is None:
        return None
    where = "isd/RPB/IMAGE"
    img = x.node(sec, "IMAGE", "isd/RPB")
    kw = {name: x.number(img, key, where) for name, key in _RPB_KEYS.items()}
    for name, key in _RPB_COEFS.items():
        text = x.text(img, f"{key}List/{key}", where)
        try:
            coef = [float(t) for t in text.split()]
        except ValueError:
            raise x.error(f"{where}/{key}List/{key}", "holds a non-number") from None
        if len(coef) != 20:
            raise x.error(f"{where}/{key}List/{key}", f"needs 20 coefficients, got {len(coef)}")
        kw[name] = coef
    for name, key in (("err_bias", "ERRBIAS"), ("err_rand", "ERRRAND")):
        value = x.number(img, key, where, optional=True)
        if value is not None:
            kw[name] = value
    return kw


# ---------------------------------------------------------------------------------------------
# public API


def parse_worldview(path) -> WorldViewMetadata:
    """Read the geometry of a DigitalGlobe level-1B product XML, strictly.

    Parameters
    ----------
    path : str or Path
        The combined ``<isd>`` XML (e.g. ``17NOV30191028-P1BS-..._P008.XML``).

    Returns
    -------
    WorldViewMetadata
        Plain arrays in gcpcal's conventions (see the module docstring).

    Raises
    ------
    ManifestError
        Naming the file and the XML path of anything missing, empty, not a number, not
        finite, inconsistent (counts, indices, quaternion norms, velocities that are not
        ``dP/dt``) or not supported (non-linear line timing, a rotated or several detector
        arrays, a distortion polynomial, a perspective-centre offset).
    """
    x = _Xml(path)
    imd = x.node(x.root, "IMD", "isd")
    img = x.node(imd, "IMAGE", "isd/IMD")
    epoch = x.time(img, "FIRSTLINETIME", "isd/IMD/IMAGE")
    scan = x.text(img, "SCANDIRECTION", "isd/IMD/IMAGE")
    if scan not in ("Forward", "Reverse"):
        raise x.error("isd/IMD/IMAGE/SCANDIRECTION", f"must be Forward or Reverse, got {scan!r}")
    lines, seconds, period, t_line0 = _line_timing(x, img, epoch)
    if (period > 0) != (scan == "Forward"):
        raise x.error("isd/IMD/IMAGE/TLCLISTList", f"line times {'increase' if period > 0 else 'decrease'} "
                      f"with the line but SCANDIRECTION is {scan}")
    eph_s, pos, vel = _ephemeris(x, epoch)
    att_s, quat = _attitude(x, epoch)
    geo = x.node(x.root, "GEO", "isd")
    pd, qcs, pc = _camera(x, geo)
    til = x.root.find("TIL")
    tiles = () if til is None else tuple(x.text(t, "FILENAME", "isd/TIL/TILE") for t in til.findall("TILE"))
    return WorldViewMetadata(
        path=x.path,
        satellite=x.text(img, "SATID", "isd/IMD/IMAGE"),
        image_descriptor=x.text(imd, "IMAGEDESCRIPTOR", "isd/IMD"),
        n_rows=x.integer(imd, "NUMROWS", "isd/IMD", minimum=1),
        n_cols=x.integer(imd, "NUMCOLUMNS", "isd/IMD", minimum=1),
        epoch=epoch,
        scan_direction=scan,
        tlc_lines=lines,
        tlc_seconds=seconds,
        line_period_s=period,
        first_line_seconds=t_line0,
        avg_line_rate_hz=x.number(img, "AVGLINERATE", "isd/IMD/IMAGE", positive=True),
        ephemeris_seconds=eph_s,
        position_m=pos,
        velocity_m_s=vel,
        attitude_seconds=att_s,
        quaternions_xyzw=quat,
        principal_distance_mm=pd,
        camera_to_body_xyzw=qcs,
        perspective_center_m=pc,
        bands=_bands(x, imd, geo),
        rpb=_rpb(x),
        tile_files=tiles,
    )


def is_worldview(path) -> bool:
    """Cheap sniff: is ``path`` an XML whose root ``<isd>`` holds ``IMD``, ``EPH``, ``ATT``, ``GEO``?

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
        True when the four sections are direct children of an ``<isd>`` root (the document is
        streamed; nothing is validated beyond that). Never raises.
    """
    try:
        depth, seen = 0, set()
        for event, el in ET.iterparse(str(path), events=("start", "end")):
            if event == "start":
                if depth == 0 and el.tag != _ROOT:
                    return False
                if depth == 1:
                    seen.add(el.tag)
                    if seen.issuperset(_SECTIONS):
                        return True
                depth += 1
            else:
                depth -= 1
                if depth == 1:
                    el.clear()
        return False
    except (OSError, ET.ParseError, UnicodeDecodeError):
        return False


def raster_paths(path) -> list[Path]:
    """The product's image file(s).

    Parameters
    ----------
    path : str or Path
        The ``<isd>`` XML.

    Returns
    -------
    list of Path
        The ``TIL/TILE/FILENAME`` entries resolved against the XML's folder, in the file's
        order (whether or not they exist); without a ``TIL`` section, the ``.TIF``/``.NTF``
        (either case) of the same stem beside the XML that exist.

    Raises
    ------
    ManifestError
        The XML cannot be read or is not an ``<isd>`` document; a tile has no file name.
    """
    path = Path(path)
    x = _Xml(path)
    til = x.root.find("TIL")
    if til is not None:
        return [path.parent / x.text(t, "FILENAME", "isd/TIL/TILE") for t in til.findall("TILE")]
    out = []
    for ext in (".TIF", ".tif", ".NTF", ".ntf"):
        cand = path.with_suffix(ext)
        if cand.is_file() and cand not in out:
            out.append(cand)
    return out


def read_worldview(path, *, band: str | None = None, aberration: bool = True, refraction: bool = True,
                   refraction_height_m: float | None = None, self_check: str = "refuse"):
    """Build a rigorous :class:`~sensor_models.models.pushbroom.PushbroomModel` from a level-1B XML.

    The model of :func:`read_worldview_checked`, without its self-check.

    Parameters
    ----------
    path, band, aberration, refraction, refraction_height_m, self_check
        As :func:`read_worldview_checked`.

    Returns
    -------
    PushbroomModel
        As :func:`read_worldview_checked`.
    """
    return read_worldview_checked(path, band=band, aberration=aberration, refraction=refraction,
                                  refraction_height_m=refraction_height_m, self_check=self_check)[0]


def read_worldview_checked(path, *, band: str | None = None, aberration: bool = True, refraction: bool = True,
                           refraction_height_m: float | None = None, self_check: str = "refuse"):
    """A level-1B XML's rigorous push-broom model and its check against the product's corners and RPB.

    Parameters
    ----------
    path : str or Path
        The combined ``<isd>`` XML.
    band : str, optional
        ``BANDID`` to model (default: every band with a detector array; the first is the
        reference band).
    aberration : bool
        Correct the lines of sight for the velocity aberration of light (about 20 m on the
        ground; see ``docs/worldview.md``).
    refraction : bool
        Correct them for atmospheric refraction (about 2 m at 30 degrees off nadir).
    refraction_height_m : float, optional
        Ellipsoidal height at which the refraction (and the small ``omega x (P - X)`` part of
        the aberration) is evaluated and folded into straight rays (default: the mean of the
        band's corner ``HAE`` values).
    self_check : {"refuse", "warn"}
        What to do when the model misses the product's corners or RPB beyond the tolerance
        (:func:`~sensor_models.readers.product_checks.check_worldview`): raise, or return the
        model with the disagreement recorded in the check.

    Returns
    -------
    ProductReading
        ``(model, check, metadata)``:

        model : PushbroomModel
            ITRF orbit (cubic Hermite through positions and velocities), body -> ITRF
            attitude samples (rotation spline) with the corrections folded in, identity
            installation, one CCD per band spanning ``NUMCOLUMNS``, cubic ``tan psi``
            polynomials.
        check : ProductCheck
            The :class:`~sensor_models.readers.self_check.ProductCheck` (``Scene.product_check``
            of :func:`~sensor_models.readers.scene_input.open_scene`).
        metadata : ProductMetadata
            ``parsed`` (the :class:`WorldViewMetadata`) and ``fold`` (the fold's statistics,
            see :func:`~sensor_models.readers.worldview_los.build_model`) (``Scene.metadata``).

    Raises
    ------
    ManifestError
        Malformed metadata (:func:`parse_worldview`); a ``SATID`` that is not one of
        :data:`~sensor_models.readers.product_checks.DIGITALGLOBE_SATELLITES`.
    ProductDisagreementError
        The model disagrees with the product's corners or RPB (``self_check="refuse"``), or
        the product's attitude does not point the camera at the Earth (whatever the policy).
    """
    from sensor_models.readers.product_checks import (DIGITALGLOBE_SATELLITES, check_worldview,
                                                      check_worldview_pointing)
    from sensor_models.readers.scene_value import ProductMetadata, ProductReading
    from sensor_models.readers.self_check import check_policy, enforce
    from sensor_models.readers.worldview_los import build_model

    check_policy(self_check)
    meta = parse_worldview(path)
    if meta.satellite not in DIGITALGLOBE_SATELLITES:
        known = ", ".join(f"{k} ({v})" for k, v in DIGITALGLOBE_SATELLITES.items())
        raise ManifestError(f"satellite {meta.satellite!r} is not one whose level-1B XML gcpcal reads ({known})",
                            path=meta.path, field="isd/IMD/IMAGE/SATID")
    bands = meta.bands if band is None else (meta.band(band),)
    check_worldview_pointing(meta)
    try:
        model, fold = build_model(meta, bands, aberration=aberration, refraction=refraction,
                                  refraction_height_m=refraction_height_m)
    except InputError as exc:
        if isinstance(exc, ManifestError) or exc.path is not None:
            raise
        raise ManifestError(exc.reason, path=meta.path, field=exc.field) from None
    check = enforce(check_worldview(model, meta, fold, self_check))
    return ProductReading(model, check, ProductMetadata(meta, fold=fold))
