"""SPOT 6/7 and Pleiades DIMAP v2 sensor products: a rigorous push-broom model.

:func:`parse_dimap_v2` (in :mod:`._dimap_v2_parse`) reads the ``Geometric_Data/Refined_Model``
of a ``DIM_*.XML`` into a :class:`DimapV2Metadata`; :func:`read_dimap_v2` turns it into a
:class:`~sensor_models.models.pushbroom.PushbroomModel`; :func:`is_dimap_v2` tells such a file from
others cheaply and :func:`raster_paths` lists the raster tiles it names. Conventions, each
checked on a real SPOT 6 file (``docs/dimap_v2.md``):

* Times are UTC; the model epoch is ``Time_Range/START``, the time of the first line's centre.
  DIMAP line ``L`` (1-based) is imaged at ``START + (L - 1) * LINE_PERIOD``, i.e. our row
  ``r`` (first line's centre at 0.5) at ``(r - 0.5) * LINE_PERIOD``; ``Time_Range/END`` is
  the last line's time.
* Ephemeris: ITRF (WGS84 geocentric) positions and Earth-relative velocities, interpolated
  by cubic Hermite through both.
* Quaternions ``(Q0, Q1, Q2, Q3)``, ``Q0`` the scalar, rotate satellite-frame vectors into
  ITRF (``v_itrf = R(q) v_sat``); interpolated by a rotation spline.
* Look angles: the detector of DIMAP column ``COL`` looks along
  ``(YLOS(c), -XLOS(c), 1)`` in the satellite frame, with ``c = COL - 1`` and ``XLOS``,
  ``YLOS`` the ``Polynomial_Look_Angles`` polynomials. The satellite frame is gcpcal's camera
  frame (X along track, Y across, Z towards the Earth), so ``tan psi_x = YLOS`` and
  ``tan psi_y = -XLOS``; the detector index ``s = col - 0.5`` is ``COL - 1``.

The ephemeris and attitudes of a sensor product end at the first and the last lines, and
:class:`~sensor_models.models.pushbroom.PushbroomModel` needs a line beyond each end: the reader adds
one sample ``EXTENSION_LINES`` lines beyond each end (orbit: a local polynomial; attitude: the
end rotation rate held), recorded in the ``extension_s`` of the reader's
:class:`~sensor_models.readers.scene_value.ProductMetadata` (``Scene.metadata``).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sensor_models.errors import InputError, ManifestError
from sensor_models.readers._dimap_v2_parse import DimapV2Band, DimapV2Metadata, product_references, parse_dimap_v2
from sensor_models.readers.dimap_common import DimapXml
from sensor_models.readers.scene_value import ProductMetadata, ProductReading

__all__ = [
    "DimapV2Band",
    "DimapV2Metadata",
    "band_look",
    "build_dimap_v2",
    "build_dimap_v2_checked",
    "extend_attitude",
    "extend_orbit",
    "is_dimap_v2",
    "parse_dimap_v2",
    "raster_paths",
    "read_dimap_v2",
    "read_dimap_v2_checked",
]

#: lines of ephemeris and attitude added beyond each end of the image (the model's margin)
EXTENSION_LINES = 64
#: samples (nearest the end) and degree of the polynomial that extends the orbit (positions and
#: velocities fitted together)
ORBIT_FIT_SAMPLES = 8
ORBIT_FIT_DEGREE = 3
#: look polynomials are padded with zeros to at least this many coefficients (the cubic of seed
#: 003 eq. 2), so that interior calibration can estimate every term of it
MIN_LOOK_COEFFICIENTS = 4
#: elements read at most by :func:`is_dimap_v2` before giving up
_SNIFF_ELEMENTS = 64


def is_dimap_v2(path) -> bool:
    """Tell whether a file is DIMAP v2 metadata, reading only its first elements.

    The root element must be ``Dimap_Document`` and
    ``Metadata_Identification/METADATA_FORMAT`` must read ``DIMAP`` with a ``version``
    attribute ``2.x`` (SPOT 1-5 DIMAP is version 1.1 under ``Metadata_Id``).

    Parameters
    ----------
    path : str or Path
        Any file.

    Returns
    -------
    bool
        True for DIMAP v2 metadata; False for anything else, including unreadable or
        malformed files (never raises).
    """
    try:
        events = ET.iterparse(str(path), events=("start", "end"))
        for i, (event, el) in enumerate(events):
            if i == 0 and el.tag != "Dimap_Document":
                return False
            if event == "end" and el.tag == "METADATA_FORMAT":
                return (el.text or "").strip() == "DIMAP" and el.get("version", "").startswith("2.")
            if i > _SNIFF_ELEMENTS:
                return False
    except (OSError, ET.ParseError, UnicodeDecodeError):
        return False
    return False


def raster_paths(path) -> list[Path]:
    """The raster tiles a DIMAP v2 file names (``Data_File/DATA_FILE_PATH@href``).

    Parameters
    ----------
    path : str or Path
        The ``DIM_*.XML`` file.

    Returns
    -------
    list of Path
        One path per tile, ordered by ``tile_R`` then ``tile_C``, resolved against the XML's
        folder (the files need not exist).

    Raises
    ------
    ManifestError
        The file is not readable DIMAP, or a ``Data_File`` has no ``href``.
    """
    path = Path(path)
    x = DimapXml(path)
    return [path.parent / href for href in product_references(x)["raster_hrefs"]]


def _fit_state_polynomial(seconds, position_m, velocity_m_s, degree: int):
    """Least-squares polynomial through positions and velocities; returns ``(mid, scale, coef)``.

    Velocity rows are weighted by the median sample spacing, so that a velocity error over one
    interval counts as the position error it would cause.
    """
    mid, scale = seconds.mean(), max(float(np.ptp(seconds)), 1e-9)
    u = (seconds - mid) / scale
    powers = np.arange(degree + 1)
    a_pos = u[:, None] ** powers
    a_vel = np.zeros_like(a_pos)
    a_vel[:, 1:] = powers[1:] * u[:, None] ** (powers[1:] - 1) / scale
    weight = float(np.median(np.diff(seconds))) if seconds.size > 1 else 1.0
    design = np.vstack([a_pos, weight * a_vel])
    rhs = np.vstack([position_m, weight * velocity_m_s])
    coef, *_ = np.linalg.lstsq(design, rhs, rcond=None)
    return mid, scale, coef


def extend_orbit(seconds, position_m, velocity_m_s, *, before_s: float, after_s: float):
    """Add one state vector ``before_s`` before the first and ``after_s`` after the last sample.

    Each end is a polynomial of degree ``ORBIT_FIT_DEGREE`` fitted by least squares to the
    positions and velocities of the ``ORBIT_FIT_SAMPLES`` samples nearest it; the new velocity
    is its derivative. Dropping the last three SPOT 6 samples and extending over a whole
    sample interval (0.13 s) reproduces the next one to 4 mm; the reader extends by 15 ms.

    Parameters
    ----------
    seconds : ndarray, shape (N,)
        Sample times, SI seconds, strictly increasing (N >= 2).
    position_m, velocity_m_s : ndarray, shape (N, 3)
        ITRF positions and Earth-relative velocities.
    before_s, after_s : float
        Extension at each end, seconds (0: none at that end).

    Returns
    -------
    seconds, position_m, velocity_m_s : ndarray
        The samples with up to two more, shapes (N', ), (N', 3), (N', 3).
    """
    t, p, v = [np.asarray(a, dtype=np.float64) for a in (seconds, position_m, velocity_m_s)]
    m = min(ORBIT_FIT_SAMPLES, t.size)
    deg = min(ORBIT_FIT_DEGREE, 2 * m - 1)
    out_t, out_p, out_v = [t], [p], [v]
    for extra, sl, first in ((before_s, slice(0, m), True), (after_s, slice(t.size - m, t.size), False)):
        if not extra > 0.0:
            continue
        new_t = t[0] - extra if first else t[-1] + extra
        mid, scale, coef = _fit_state_polynomial(t[sl], p[sl], v[sl], deg)
        u = (new_t - mid) / scale
        pos = np.polynomial.polynomial.polyval(u, coef)
        vel = np.polynomial.polynomial.polyval(u, np.polynomial.polynomial.polyder(coef)) / scale
        where = 0 if first else len(out_t)
        out_t.insert(where, np.array([new_t]))
        out_p.insert(where, pos[None, :])
        out_v.insert(where, vel[None, :])
    return np.concatenate(out_t), np.concatenate(out_p), np.concatenate(out_v)


def extend_attitude(seconds, rotations: Rotation, *, before_s: float, after_s: float):
    """Add one rotation ``before_s`` before the first and ``after_s`` after the last sample.

    The rotation rate of the end interval is held: ``R(t) = exp((t - t_a) / (t_b - t_a)
    log(R_b R_a^-1)) R_a`` over the two samples ``a``, ``b`` at that end.

    Parameters
    ----------
    seconds : ndarray, shape (M,)
        Sample times, SI seconds, strictly increasing (M >= 2).
    rotations : scipy.spatial.transform.Rotation
        ``M`` rotations (body -> reference).
    before_s, after_s : float
        Extension at each end, seconds (0: none at that end).

    Returns
    -------
    seconds : ndarray, shape (M',)
    rotations : scipy.spatial.transform.Rotation
        ``M'`` rotations, ``M' = M`` plus one per extended end.
    """
    t = np.asarray(seconds, dtype=np.float64)
    quats = [rotations.as_quat()]
    times = [t]
    if before_s > 0.0:
        step = rotations[1] * rotations[0].inv()
        r0 = Rotation.from_rotvec(step.as_rotvec() * (-before_s / (t[1] - t[0]))) * rotations[0]
        quats.insert(0, r0.as_quat()[None, :])
        times.insert(0, np.array([t[0] - before_s]))
    if after_s > 0.0:
        step = rotations[-1] * rotations[-2].inv()
        r1 = Rotation.from_rotvec(step.as_rotvec() * (after_s / (t[-1] - t[-2]))) * rotations[-1]
        quats.append(r1.as_quat()[None, :])
        times.append(np.array([t[-1] + after_s]))
    return np.concatenate(times), Rotation.from_quat(np.concatenate(quats))


def _exterior(meta: DimapV2Metadata):
    """ITRF :class:`Orbit` and satellite -> ITRF :class:`Attitude`, extended by the margin."""
    from sensor_models.geometry.ephemeris import Attitude, Orbit

    margin = EXTENSION_LINES * meta.line_period_s
    t0, t1 = -margin, meta.end_seconds + margin
    te, pe, ve = extend_orbit(meta.ephemeris_seconds, meta.position_m, meta.velocity_m_s,
                              before_s=max(0.0, meta.ephemeris_seconds[0] - t0),
                              after_s=max(0.0, t1 - meta.ephemeris_seconds[-1]))
    rot = Rotation.from_quat(meta.quaternions_wxyz[:, [1, 2, 3, 0]])  # scalar-first -> scalar-last
    ta, ra = extend_attitude(meta.attitude_seconds, rot,
                             before_s=max(0.0, meta.attitude_seconds[0] - t0),
                             after_s=max(0.0, t1 - meta.attitude_seconds[-1]))
    orbit = Orbit(meta.epoch, te, pe, ve, frame="itrf")
    attitude = Attitude(ta, ra.as_quat(), frame="itrf")
    return orbit, attitude, (float(meta.ephemeris_seconds[0] - te[0]), float(te[-1] - meta.ephemeris_seconds[-1]))


def band_look(band: DimapV2Band):
    """The :class:`~sensor_models.models.pushbroom_types.CcdLook` of a DIMAP v2 band.

    Parameters
    ----------
    band : DimapV2Band
        The band's swath and look-angle polynomials.

    Returns
    -------
    CcdLook
        One array ``"ccd1"`` from column ``FIRST_COL - 1`` (left edge) with
        ``LAST_COL - FIRST_COL + 1`` detectors, ``tan psi_x = YLOS(s)``,
        ``tan psi_y = -XLOS(s)`` in the detector index ``s = COL - 1``, each padded with zero
        coefficients to at least ``MIN_LOOK_COEFFICIENTS`` (the geometry is unchanged).
    """
    from sensor_models.models.pushbroom_types import CcdLook

    def padded(coefficients):
        c = np.asarray(coefficients, dtype=np.float64)
        return np.concatenate([c, np.zeros(max(0, MIN_LOOK_COEFFICIENTS - c.size))])

    return CcdLook("ccd1", band.first_col - 1, band.last_col - band.first_col + 1,
                   tan_psi_x=padded(band.ylos), tan_psi_y=-padded(band.xlos))


def read_dimap_v2(path, *, band: str | None = None, rpc=None, self_check: str = "refuse"):
    """Build a :class:`~sensor_models.models.pushbroom.PushbroomModel` from a DIMAP v2 sensor product.

    The model of :func:`read_dimap_v2_checked`, without its self-check.

    Parameters
    ----------
    path, band, rpc, self_check
        As :func:`read_dimap_v2_checked`.

    Returns
    -------
    PushbroomModel
        As :func:`read_dimap_v2_checked`.
    """
    return read_dimap_v2_checked(path, band=band, rpc=rpc, self_check=self_check)[0]


def read_dimap_v2_checked(path, *, band: str | None = None, rpc=None, self_check: str = "refuse"):
    """A DIMAP v2 sensor product's push-broom model and its check against the product.

    Parameters
    ----------
    path : str or Path
        The ``DIM_*.XML`` file.
    band : str, optional
        ``BAND_ID`` to keep (default: every ``Band_Calibration``, each a model band named by
        its ``BAND_ID``; the first is the reference band).
    rpc : str or Path or RpcModel, optional
        The product's RPC, to compare the model with (any file
        :func:`~sensor_models.readers.rpc_files.read_rpc` reads, in its pixel convention).
        Default: the file the product names (``Rational_Function_Model/.../COMPONENT_PATH``)
        when it lies beside the metadata in such a form; else only the ``Dataset_Extent``.
    self_check : {"refuse", "warn"}
        What to do when the model misses the product's ``Dataset_Extent`` (or its RPC) beyond
        the tolerance (:func:`~sensor_models.readers.product_checks.check_dimap_v2`): raise, or
        return the model with the disagreement recorded in the check.

    Returns
    -------
    ProductReading
        ``(model, check, metadata)``:

        model : PushbroomModel
            ITRF orbit and satellite -> ITRF attitude (each extended by ``EXTENSION_LINES``
            lines beyond the image), identity installation, line ``r`` at
            ``(r - 0.5) * LINE_PERIOD`` from ``Time_Range/START``, one array per band
            (:func:`band_look`).
        check : ProductCheck
            The :class:`~sensor_models.readers.self_check.ProductCheck` (``Scene.product_check``
            of :func:`~sensor_models.readers.scene_input.open_scene`).
        metadata : ProductMetadata
            ``parsed`` (the :class:`DimapV2Metadata`) and ``extension_s`` (the orbit and
            attitude extension (before, after) in seconds) (``Scene.metadata``).

    Raises
    ------
    ManifestError
        The file is malformed (see :func:`parse_dimap_v2`) or names no band ``band``.
    ProductDisagreementError
        The model disagrees with the product (``self_check="refuse"``).
    """
    from sensor_models.readers.self_check import check_policy

    check_policy(self_check)
    return build_dimap_v2_checked(parse_dimap_v2(path), band=band, rpc=rpc, self_check=self_check)


def build_dimap_v2(meta: DimapV2Metadata, *, band: str | None = None, rpc=None, self_check: str = "refuse"):
    """The model of parsed DIMAP v2 metadata, checked against the product (see :func:`read_dimap_v2`).

    Parameters
    ----------
    meta : DimapV2Metadata
        From :func:`parse_dimap_v2`.
    band, rpc, self_check
        As :func:`read_dimap_v2`.

    Returns
    -------
    PushbroomModel
        As :func:`read_dimap_v2`.
    """
    return build_dimap_v2_checked(meta, band=band, rpc=rpc, self_check=self_check)[0]


def build_dimap_v2_checked(meta: DimapV2Metadata, *, band: str | None = None, rpc=None, self_check: str = "refuse"):
    """The model of parsed DIMAP v2 metadata and its check against the product.

    Parameters
    ----------
    meta : DimapV2Metadata
        From :func:`parse_dimap_v2`.
    band, rpc, self_check
        As :func:`read_dimap_v2_checked`.

    Returns
    -------
    ProductReading
        ``(model, check, metadata)``, as :func:`read_dimap_v2_checked`.
    """
    from sensor_models.models.pushbroom import PushbroomModel
    from sensor_models.models.pushbroom_types import LineTiming
    from sensor_models.readers.product_checks import check_dimap_v2
    from sensor_models.readers.self_check import check_policy, enforce

    check_policy(self_check)
    chosen = meta.bands
    if band is not None:
        chosen = tuple(b for b in meta.bands if b.band_id == band)
        if not chosen:
            raise ManifestError(
                f"no Band_Calibration for BAND_ID {band!r} (the file has {[b.band_id for b in meta.bands]})",
                path=meta.path,
                field="Dimap_Document/Geometric_Data/Refined_Model/Geometric_Calibration/Instrument_Calibration/"
                "Band_Calibration_List/Band_Calibration/BAND_ID",
            )
    try:
        orbit, attitude, extension = _exterior(meta)
        model = PushbroomModel(
            orbit=orbit,
            attitude=attitude,
            line_timing=LineTiming(0.5, 0.0, meta.line_period_s),
            bands={b.band_id: [band_look(b)] for b in chosen},
            n_rows=meta.n_rows,
            name=f"{meta.mission} {meta.mission_index} {meta.profile} {meta.epoch}",
        )
    except InputError as exc:
        if isinstance(exc, ManifestError):
            raise
        raise ManifestError(exc.reason, path=meta.path, field=exc.field) from None
    check = enforce(check_dimap_v2(model, meta, self_check, rpc=_product_rpc(meta, rpc)))
    return ProductReading(model, check, ProductMetadata(meta, extension_s=extension))


def _product_rpc(meta: DimapV2Metadata, rpc):
    """The RPC to compare with: the one given, or the product's own when gcpcal reads its form."""
    from sensor_models.models.rpc import RpcModel
    from sensor_models.readers.rpc_files import read_rpc

    if rpc is not None:
        return rpc if isinstance(rpc, RpcModel) else read_rpc(rpc)
    if not meta.rpc_href:
        return None
    path = Path(meta.path).parent / meta.rpc_href
    if path.is_file() and path.name.lower().endswith((".geom", ".rpb", "_rpc.txt")):
        return read_rpc(path)
    return None
