"""SPOT 1-5 DIMAP level-1A metadata: strict parsing and a push-broom directional-angle model.

:func:`~sensor_models.readers.dimap_parse.parse_dimap` reads the geometric content of a SPOT
scene ``METADATA.DIM`` (DIMAP 1.1, profile ``SPOTSCENE_1A``) into a
:class:`~sensor_models.readers.dimap_parse.DimapMetadata` of plain arrays; :func:`read_dimap`
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

Modules: this one assembles the model; :mod:`~sensor_models.readers.dimap_common` holds what
the DIMAP readers share (pixel convention, strict XML access), :mod:`~sensor_models.readers.dimap_parse`
the parsing, :mod:`~sensor_models.readers.dimap_exterior` the SPOT frames, orbit and attitude,
and :mod:`~sensor_models.readers.dimap_interior` the look-angle polynomials.
"""

from __future__ import annotations

from scipy.spatial.transform import Rotation

from sensor_models.errors import InputError, ManifestError
from sensor_models.readers.dimap_common import DIMAP_ROOT
from sensor_models.readers.dimap_exterior import (
    ATTITUDE_MODES,
    attitude_sample_seconds,
    body_to_itrf,
    dimap_orbit,
)
from sensor_models.readers.dimap_interior import fit_look_polynomials
from sensor_models.readers.dimap_parse import DimapMetadata, parse_dimap
from sensor_models.readers.scene_value import ProductMetadata, ProductReading

__all__ = ["read_dimap", "read_dimap_checked"]


def read_dimap(path, *, band: int | None = None, attitude: str = "measured", self_check: str = "refuse"):
    """Build a :class:`~sensor_models.models.pushbroom.PushbroomModel` from a SPOT 1-5 DIMAP file.

    The model of :func:`read_dimap_checked`, without its self-check.

    Parameters
    ----------
    path, band, attitude, self_check
        As :func:`read_dimap_checked`.

    Returns
    -------
    PushbroomModel
        As :func:`read_dimap_checked`.
    """
    return read_dimap_checked(path, band=band, attitude=attitude, self_check=self_check)[0]


def read_dimap_checked(path, *, band: int | None = None, attitude: str = "measured", self_check: str = "refuse"):
    """A SPOT 1-5 DIMAP file's push-broom model and its check against the file's frame.

    Parameters
    ----------
    path : str or Path
        The ``METADATA.DIM`` file.
    band : int, optional
        ``BAND_INDEX`` whose look angles are used (default: every band in the file, each as
        a model band named ``"B<index>"``; the first is the reference band).
    attitude : {"measured", "nominal"}
        The file's attitude or the nominal one (see
        :func:`~sensor_models.readers.dimap_exterior.body_to_itrf`).
    self_check : {"refuse", "warn"}
        What to do when the model misses the file's frame vertices and scene centre beyond the
        tolerance (:func:`~sensor_models.readers.product_checks.check_dimap`): raise, or return
        the model with the disagreement recorded in the check.

    Returns
    -------
    ProductReading
        ``(model, check, metadata)``:

        model : PushbroomModel
            ITRF orbit, body -> ITRF attitude samples every ``ATTITUDE_STEP_S`` over the scene
            plus a margin, identity installation, one CCD per band spanning all columns, with
            ``tan psi`` polynomials fitted to the detector directions (see
            :func:`~sensor_models.readers.dimap_interior.fit_look_polynomials`).
        check : ProductCheck
            The :class:`~sensor_models.readers.self_check.ProductCheck` (``Scene.product_check``
            of :func:`~sensor_models.readers.scene_input.open_scene`).
        metadata : ProductMetadata
            ``parsed`` (the :class:`~sensor_models.readers.dimap_parse.DimapMetadata`) and
            ``look_fits`` (band -> ``LookFit``) (``Scene.metadata``).

    Raises
    ------
    ManifestError
        Malformed metadata (:func:`~sensor_models.readers.dimap_parse.parse_dimap`) or no look
        angles for ``band``.
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
                                field=f"{DIMAP_ROOT}/Data_Strip/Sensor_Configuration/Instrument_Look_Angles_List")
    fits = {f"B{lk.band_index}": fit_look_polynomials(lk, meta.n_cols) for lk in looks}
    model = _build_model(meta, fits, attitude)
    check = enforce(check_dimap(model, meta, attitude, self_check, lambda other: _build_model(meta, fits, other)))
    return ProductReading(model, check, ProductMetadata(meta, look_fits=fits))


def _build_model(meta: DimapMetadata, fits: dict, attitude: str):
    """The push-broom model of parsed DIMAP metadata with fitted look polynomials and an attitude mode."""
    from sensor_models.geometry.ephemeris import Attitude
    from sensor_models.models.pushbroom import PushbroomModel
    from sensor_models.models.pushbroom_types import CcdLook, LineTiming

    try:
        orbit = dimap_orbit(meta)
        seconds = attitude_sample_seconds(meta)
        rot = body_to_itrf(meta, seconds, orbit, attitude=attitude)
        att = Attitude(seconds, Rotation.from_matrix(rot).as_quat(), frame="itrf")
        timing = LineTiming(meta.reference_row, 0.0, meta.line_period_s)
    except InputError as exc:
        if isinstance(exc, ManifestError):
            raise
        raise ManifestError(exc.reason, path=meta.path, field=exc.field) from None
    bands = {name: [CcdLook("ccd1", 0, meta.n_cols, fit.tan_psi_x, fit.tan_psi_y)] for name, fit in fits.items()}
    return PushbroomModel(
        orbit=orbit,
        attitude=att,
        line_timing=timing,
        bands=bands,
        n_rows=meta.n_rows,
        name=f"SPOT{meta.mission} {meta.instrument} {meta.sensor_code} {meta.epoch}",
    )
