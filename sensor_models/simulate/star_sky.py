"""Star-field frames of a geostationary staring camera, with known truth (seed 000, section 2).

Scenario
--------
A geostationary satellite (:func:`~sensor_models.models.synthetic.geostationary_orbit`, exactly
fixed above ``lon_deg``) holds an Earth-pointing attitude (orbital frame, seed 000 eq. 3:
X along the velocity, Z to the Earth's centre) with a small bias, drift and jitter. The camera
looks through a two-axis pointing mirror, the 45-degree fold of seed 000 figure 2: the mirror
normal ``(0, 1, -1)/sqrt(2)`` folds the camera boresight +Z onto +Y, and the laboratory
installation (roll 90 degrees) brings that folded view back to nadir. For star observation the
mirror turns by ``view_north_deg / 2`` about the camera X axis, which turns the view
``view_north_deg`` north of nadir: past the Earth's limb (8.7 degrees from GEO) into deep space
at a declination of about ``view_north_deg``. With the Earth-fixed pointing the stars then drift
across the frame at the sidereal rate (about 15 arcsec/s, 3.6 px/s for the seed 000 camera),
from the left edge to the right (columns increasing), each at a nearly constant row: the
"relative motion of stars" of seed 000 section 2.3.1.

Truth
-----
The TRUE model has installation errors (roll, pitch, yaw of tens of arcseconds, chosen so that
the laboratory model is off by ``initial_error_px`` = (RA, DE) pixels at the array centre: seed
000 table 3, about -7 and -21) and a distorted interior (a :class:`StaringLab` with a focal
length, principal point, radial and decentering distortion, tilt and rotation differing from the
design lens), fitted to the 20-coefficient cubic. The LAB model a user receives has the design
lens (seed 000 table 1: 1250 mm, 25 um pixels) and the nominal installation (roll 90 degrees),
and the *measured* attitude: the true attitude with white measurement noise.

Rendering
---------
Hipparcos stars (:class:`~sensor_models.geometry.star_catalogue.StarCatalog`) brighter than ``mag_limit`` are
moved to their apparent directions at each frame instant (space motion, parallax, light
deflection, aberration by the satellite's velocity), projected with the TRUE model, and drawn
by :func:`sensor_models.imaging.psf.render_stars` (pixel-integrated Gaussian PSF, background, shot and
read noise), then quantized to uint16 with saturation. A crude SWIR-like magnitude
``m = V - swir_color_term * (B - V)`` (red stars are brighter in the short-wave infrared)
scales the flux: ``flux = flux_ref_adu * 10^(-0.4 (m - ref_mag))``. This is a rendering
device, not a photometric model.

Outputs (``out_dir``)
---------------------
``frames/frame_NNNN.tif``
    uint16 single-band GeoTIFF frames without georeferencing.
``frames.json``
    The frame list (``format_version`` 1, ``kind: "geo_star_frames"``): ``epoch_utc``,
    ``manifest`` (relative path), and ``frames``: ``[{"path", "seconds"}, ...]`` in time
    order. The seconds are relative to the manifest's epoch.
``manifest.json``
    The LAB model of frame 0 (``docs/geo_manifest.md``). One manifest serves the sequence: its
    orbit and attitude samples cover every frame, and the model of frame ``k`` is
    ``model.at_frame(frames[k].seconds)`` (the mirror angles stay fixed).
``truth_manifest.json``, ``truth.json``
    The TRUE model of frame 0, and the true parameters, the installation errors, the expected
    initial errors and every rendered star per frame (HIP id, row, col, magnitude).
``summary.json``
    Counts and timings.

With ``frames_out`` the frames are handed back in memory instead, and ``frames/`` and
``frames.json`` are not written.

Everything is written into a temporary folder beside ``out_dir`` and moved in with
:func:`os.replace`; the output is a deterministic function of the configuration and seed.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sensor_models.files.atomic import atomic_folder
from sensor_models.errors import InputError
from sensor_models.geometry.ephemeris import Attitude
from sensor_models.models.geo_staring import GeoStaringModel
from sensor_models.models.synthetic import SEED000_CAMERA, geostationary_orbit
from sensor_models.models.star_directions import vectors_to_radec
from sensor_models.models.staring_camera import PointingMirror, StaringLab
from sensor_models.models.pushbroom_types import Installation

__all__ = ["FOLD_NORMAL_CAM", "GeoStarsConfig", "frame_models", "simulate_geo_stars"]

ARCSEC = np.pi / (180.0 * 3600.0)
#: 45-degree fold mirror: camera +Z folded onto camera +Y (seed 000 figure 2)
FOLD_NORMAL_CAM = (0.0, 1.0, -1.0)
FRAMES_KIND = "geo_star_frames"


@dataclass(frozen=True)
class GeoStarsConfig:
    """Settings of :func:`simulate_geo_stars` (all defaults follow seed 000 where it says).

    Attributes
    ----------
    n_frames, frame_interval_s : int, float
        Consecutive frames, one every ``frame_interval_s`` seconds (10 s: a star crosses the
        1024-pixel frame in about 28 frames, the seed's > 25 track points).
    epoch_utc : str
        Time of frame 0 (seed 000 observed for 20 minutes a day in August; 14:40 UTC turns the
        view from 105 E to the Milky Way in Orion-Gemini, a richer field than 11:25).
    lon_deg : float
        Sub-satellite longitude.
    view_north_deg : float
        Angle of the star view north of nadir (mirror turned by half of it).
    image_shape : (int, int)
        Array (or sub-array) size; the seed 000 optics (1250 mm, 25 um) are kept.
    mag_limit : float
        Faintest catalogue magnitude (V) rendered.
    initial_error_px : (float, float)
        RA and DE errors (pixels) of the LAB model at the array centre (seed 000 table 3).
    boresight_rotation_arcsec : float
        Installation error about the boresight (not visible at the centre).
    installation_error_arcsec : (float, float, float) or ()
        The TRUE installation error (roll, pitch, yaw, arcsec) given outright; empty (default):
        chosen from ``initial_error_px`` and ``boresight_rotation_arcsec`` for this session's
        attitude. A series of sessions of one camera gives one value (plus its day-to-day
        change) so that the sessions share one installation.
    focal_length_mm, principal_point_offset_px, radial_k1, decentering_p, tilt_arcsec,
    rotation_arcsec : interior truth (see :class:`~sensor_models.models.staring_camera.StaringLab`).
    attitude_bias_arcsec, attitude_drift_arcsec_s, attitude_jitter_arcsec,
    attitude_jitter_hz : true attitude (body -> orbital, roll/pitch/yaw).
    attitude_noise_arcsec : float
        White noise of the measured attitude (1 s samples) given to the LAB model.
    psf_sigma_px, background_adu, gain_e_per_adu, read_noise_e : rendering.
    flux_ref_adu, ref_mag, swir_color_term : flux scale (module docstring).
    only_hip : tuple of int
        Render only these Hipparcos stars (e.g. one: a single star per frame); empty: all.
    seed : int
        Every random draw derives from it.
    """

    n_frames: int = 120
    frame_interval_s: float = 10.0
    epoch_utc: str = "2023-08-02T14:40:00"
    lon_deg: float = 105.0
    view_north_deg: float = 11.0
    image_shape: tuple = (1024, 1024)
    mag_limit: float = 10.0
    initial_error_px: tuple = (-7.0, -21.0)
    boresight_rotation_arcsec: float = 40.0
    installation_error_arcsec: tuple = ()
    focal_length_mm: float = 1250.8
    principal_point_offset_px: tuple = (0.6, -0.4)
    radial_k1: float = 1.5e-8
    decentering_p: tuple = (2e-7, -1e-7)
    tilt_arcsec: tuple = (-8.0, 6.0)
    rotation_arcsec: float = -8.0
    attitude_bias_arcsec: tuple = (12.0, -8.0, 20.0)
    attitude_drift_arcsec_s: tuple = (0.002, -0.002, 0.004)
    attitude_jitter_arcsec: tuple = (0.2, 0.2, 0.2)
    attitude_jitter_hz: float = 0.02
    attitude_noise_arcsec: float = 0.1
    psf_sigma_px: float = 0.8
    background_adu: float = 300.0
    gain_e_per_adu: float = 2.0
    read_noise_e: float = 30.0
    flux_ref_adu: float = 40000.0
    ref_mag: float = 8.0
    swir_color_term: float = 1.0
    only_hip: tuple = ()
    seed: int = 0
    extra: dict = field(default_factory=dict, repr=False)

    def validate(self) -> "GeoStarsConfig":
        """Check the settings.

        Returns
        -------
        GeoStarsConfig
            ``self``, unchanged.

        Raises
        ------
        InputError
            Naming the first field out of range.
        """
        if int(self.n_frames) < 2:
            raise InputError(f"must be >= 2, got {self.n_frames}", field="n_frames")
        if not (float(self.frame_interval_s) > 0.0):
            raise InputError(f"must be positive, got {self.frame_interval_s}", field="frame_interval_s")
        if len(self.image_shape) != 2 or min(int(x) for x in self.image_shape) < 16:
            raise InputError(f"must be two sizes >= 16, got {self.image_shape}", field="image_shape")
        if not 9.5 <= float(self.view_north_deg) <= 60.0:
            raise InputError("must be 9.5..60 degrees (past the Earth's limb)", field="view_north_deg")
        if not np.isfinite(self.mag_limit):
            raise InputError("must be finite", field="mag_limit")
        inst = np.asarray(self.installation_error_arcsec, dtype=np.float64).reshape(-1)
        if inst.size not in (0, 3) or not np.all(np.isfinite(inst)):
            raise InputError(f"must be empty or three finite angles, got {self.installation_error_arcsec}",
                             field="installation_error_arcsec")
        if self.extra:
            raise InputError(f"unknown settings {sorted(self.extra)}", field="extra")
        return self


# --------------------------------------------------------------------------- models
def frame_models(model: GeoStaringModel, seconds) -> list:
    """The model at each frame instant (:meth:`GeoStaringModel.at_frame`).

    Parameters
    ----------
    model : GeoStaringModel
        The model at the scene epoch.
    seconds : array_like of float, shape (n,)
        Frame instants, seconds after the scene epoch.

    Returns
    -------
    list of GeoStaringModel
        One per instant.
    """
    return [model.at_frame(float(t)) for t in np.asarray(seconds, dtype=np.float64).reshape(-1)]


def _attitudes(cfg: GeoStarsConfig, t_att: np.ndarray, rng, wobble_rad=None):
    """True and measured body -> orbital attitude (roll, pitch, yaw, Rz Ry Rx).

    ``wobble_rad`` (N, 3), when given, is added to the TRUE angles only (unmeasured)."""
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    angles = (
        np.asarray(cfg.attitude_bias_arcsec)[None, :]
        + np.asarray(cfg.attitude_drift_arcsec_s)[None, :] * t_att[:, None]
        + np.asarray(cfg.attitude_jitter_arcsec)[None, :]
        * np.sin(2.0 * np.pi * cfg.attitude_jitter_hz * t_att[:, None] + phase[None, :])
    ) * ARCSEC
    known_rot = Rotation.from_euler("ZYX", angles[:, ::-1])
    true_rot = known_rot if wobble_rad is None else Rotation.from_euler("ZYX", (angles + wobble_rad)[:, ::-1])
    noise = rng.normal(0.0, cfg.attitude_noise_arcsec * ARCSEC, (t_att.size, 3))
    measured = known_rot * Rotation.from_rotvec(noise)
    return Attitude(t_att, true_rot.as_quat(), frame="orbital"), Attitude(t_att, measured.as_quat(), frame="orbital")


def _true_lab(cfg: GeoStarsConfig) -> StaringLab:
    n_rows, n_cols = (int(x) for x in cfg.image_shape)
    return StaringLab(
        focal_length_mm=cfg.focal_length_mm,
        pixel_size_mm=SEED000_CAMERA.pixel_size_mm,
        principal_point_px=(0.5 * n_rows + cfg.principal_point_offset_px[0], 0.5 * n_cols + cfg.principal_point_offset_px[1]),
        radial_k=(cfg.radial_k1, 0.0),
        decentering_p=tuple(cfg.decentering_p),
        tilt_rad=tuple(np.asarray(cfg.tilt_arcsec) * ARCSEC),
        rotation_rad=cfg.rotation_arcsec * ARCSEC,
    )


def _radec_error_px(lab: GeoStaringModel, truth: GeoStaringModel, row, col, dinst=None):
    """(RA, DE) errors in pixels (seed 000 eq. 18-19) of ``lab`` at pixels seen by ``truth``."""
    if dinst is not None:
        p = truth.parameters().values.copy()
        p[:3] += dinst
        truth = truth.with_parameters(p)
    ra1, de1 = vectors_to_radec(lab.object_vector_gcrf(row, col))
    ra0, de0 = vectors_to_radec(truth.object_vector_gcrf(row, col))
    pix_deg = np.degrees(lab.ifov_rad)
    return np.stack([((ra1 - ra0 + 180.0) % 360.0 - 180.0) / pix_deg, (de1 - de0) / pix_deg], -1)


def _installation_error(cfg: GeoStarsConfig, lab: GeoStaringModel, truth0: GeoStaringModel) -> np.ndarray:
    """Installation deltas giving ``initial_error_px`` at the centre, plus a boresight rotation."""
    rc = ([0.5 * lab.n_rows], [0.5 * lab.n_cols])
    base = _radec_error_px(lab, truth0, *rc)[0]
    step = 10.0 * ARCSEC
    jac = np.stack([(_radec_error_px(lab, truth0, *rc, dinst=step * e)[0] - base) / step for e in np.eye(3)], 1)
    # the installation rotation about the boresight leaves the centre in place: the null
    # direction of the 2x3 Jacobian
    _, _, vt = np.linalg.svd(jac)
    null = vt[-1] / np.linalg.norm(vt[-1])
    d = np.linalg.pinv(jac) @ (np.asarray(cfg.initial_error_px, dtype=np.float64) - base)
    d = d + cfg.boresight_rotation_arcsec * ARCSEC * null
    for _ in range(3):  # small-angle nonlinearity: a couple of Newton corrections
        resid = np.asarray(cfg.initial_error_px) - _radec_error_px(lab, truth0, *rc, dinst=d)[0]
        d = d + np.linalg.pinv(jac) @ resid
    return d


def _build_models(cfg: GeoStarsConfig, rng, errors=None):
    """LAB and TRUE models and the installation error; ``errors`` (StarTruthErrors) beyond the default ones."""
    n_rows, n_cols = (int(x) for x in cfg.image_shape)
    t_end = (int(cfg.n_frames) - 1) * float(cfg.frame_interval_s)
    t0, t1 = -60.0, t_end + 60.0
    epoch = np.datetime64(cfg.epoch_utc, "ns")
    t_orbit = np.linspace(t0, t1, max(4, int(np.ceil((t1 - t0) / 60.0)) + 1))
    orbit = geostationary_orbit(epoch, t_orbit, lon_deg=cfg.lon_deg)
    t_att = np.linspace(t0, t1, int(np.ceil(t1 - t0)) + 1)
    wobble, lab_orbit = None, orbit
    if errors is not None:
        from sensor_models.simulate.star_truth import wobble_angles

        wobble = wobble_angles(t_att, errors.wobble_arcsec, errors.wobble_period_s,
                               np.random.default_rng([int(cfg.seed), 1]))
        dlon = np.degrees(errors.orbit_bias_m / np.linalg.norm(orbit.position_m[0]))
        lab_orbit = geostationary_orbit(epoch, t_orbit, lon_deg=cfg.lon_deg + dlon)
    true_att, measured_att = _attitudes(cfg, t_att, rng, wobble)
    mirror = PointingMirror(FOLD_NORMAL_CAM, 0.5 * np.radians(cfg.view_north_deg), 0.0)
    nominal = Installation(np.pi / 2.0, 0.0, 0.0)
    common = dict(image_shape=(n_rows, n_cols), orbit=orbit, frame_seconds=0.0, mirror=mirror)
    lab = GeoStaringModel.from_lab(SEED000_CAMERA, attitude=measured_att, installation=nominal, name="geo_stars_lab",
                                   **{**common, "orbit": lab_orbit})
    truth0 = GeoStaringModel.from_lab(_true_lab(cfg), attitude=true_att, installation=nominal, name="geo_stars_truth", **common)
    if len(cfg.installation_error_arcsec):
        d = np.asarray(cfg.installation_error_arcsec, dtype=np.float64) * ARCSEC
    else:
        d = _installation_error(cfg, lab, truth0)
    p = truth0.parameters().values.copy()
    p[:3] += d
    truth = truth0.with_parameters(p)
    truth.lab, truth.lab_fit_residual = truth0.lab, truth0.lab_fit_residual
    return lab, truth, d


# --------------------------------------------------------------------------- rendering
def simulate_geo_stars(out_dir, *, config: GeoStarsConfig | None = None, n_frames: int | None = None,
                       frame_interval_s: float | None = None, seed: int | None = None,
                       mag_limit: float | None = None, image_shape=None, profile=None,
                       frames_out: list | None = None, noise_replay=None) -> dict:
    """Render a star-field sequence of a geostationary staring camera (module docstring).

    Parameters
    ----------
    out_dir : path
        Output folder (created; files already there with the same names are replaced).
    config : GeoStarsConfig, optional
        All settings; the keyword arguments below override its fields.
    n_frames, frame_interval_s, seed, mag_limit, image_shape
        Shortcuts for the :class:`GeoStarsConfig` fields of the same names.
    profile : StarsProfile, optional
        Error profile (:mod:`sensor_models.simulate.profiles`): its attitude noise, jitter and
        drift replace the configuration's, and its errors beyond the default ones
        (:mod:`sensor_models.simulate.star_truth`) are injected. None or ``ideal``: the default
        sequence, byte for byte.
    frames_out : list, optional
        Keep the frames in memory instead of writing them: each frame's uint16 array (H, W),
        the values the GeoTIFF would hold, is appended to this list in time order, and neither
        ``frames/`` nor ``frames.json`` is written (the frame of index ``k`` is at ``k *
        frame_interval_s`` seconds). For a caller that processes the frames at once (the seed
        000 experiment) rather than a user's files.
    noise_replay : sensor_models.simulate.noise_replay.NormalReplay, optional
        Keeps the frames' per-pixel noise draws and replays them where another sequence's
        generator reaches the same state (sequences of one seed): the same frames, bit for bit,
        without drawing the noise again.

    Returns
    -------
    dict
        The summary written to ``summary.json``: counts (frames, stars per frame, distinct
        stars), the installation error in arcsec, the expected initial errors and timings.
    """
    from sensor_models.readers.geo_manifest import write_geo_manifest

    t_start = time.perf_counter()
    cfg = _resolved_config(config, n_frames=n_frames, frame_interval_s=frame_interval_s, seed=seed,
                           mag_limit=mag_limit, image_shape=image_shape)
    errors = None
    if profile is not None and not profile.is_ideal:
        from sensor_models.simulate.star_truth import truth_errors

        cfg = _profile_config(cfg, profile)
        errors = truth_errors(profile)
    rng = np.random.default_rng(int(cfg.seed))
    lab, truth, d_inst = _build_models(cfg, rng, errors)
    catalog, unit_icrs, mags = _star_catalog(cfg)
    shape = truth.image_shape

    out_dir = Path(out_dir)
    with atomic_folder(out_dir, mode="merge") as tmp:
        tmp = tmp.resolve()
        frame_rng = rng if noise_replay is None else noise_replay.generator(rng)
        frames, rendered, n_per_frame = _render_frames(tmp, cfg, truth, catalog, unit_icrs, mags, frame_rng, errors,
                                                       frames_out)
        write_geo_manifest(lab, tmp / "manifest.json")
        write_geo_manifest(truth, tmp / "truth_manifest.json")
        frames_doc = {"format_version": 1, "kind": FRAMES_KIND, "epoch_utc": str(np.datetime64(lab.epoch, "ms")),
                      "manifest": "manifest.json", "frames": frames}
        names = ("truth.json", "summary.json") if frames_out is not None else ("frames.json", "truth.json",
                                                                                 "summary.json")
        truth_doc = _truth_doc(cfg, lab, truth, d_inst, rendered)
        hips = sorted({h for r in rendered for h, rr, cc in zip(r["hip"], r["row"], r["col"])
                       if 0 <= rr < shape[0] and 0 <= cc < shape[1]})
        summary = {
            "frames": int(cfg.n_frames),
            "frame_interval_s": float(cfg.frame_interval_s),
            "image_shape": list(shape),
            "stars_per_frame": {"min": int(min(n_per_frame)), "mean": float(np.mean(n_per_frame)),
                                "max": int(max(n_per_frame))},
            "distinct_stars": len(hips),
            "installation_error_arcsec": (d_inst / ARCSEC).round(3).tolist(),
            "initial_error_centre_px": truth_doc["initial_error_centre_px"],
            "seconds": round(time.perf_counter() - t_start, 3),
        }
        if profile is not None:
            summary["profile"] = profile.name
        written = {"frames.json": frames_doc, "truth.json": truth_doc, "summary.json": summary}
        for name in names:
            (tmp / name).write_text(json.dumps(written[name], indent=1) + "\n", encoding="utf-8")
    return summary


def _resolved_config(config, **overrides) -> GeoStarsConfig:
    """``config`` (default settings when None) with the non-None ``overrides``, validated."""
    cfg = config or GeoStarsConfig()
    changes = {k: v for k, v in overrides.items() if v is not None}
    if changes:
        cfg = GeoStarsConfig(**{**asdict(cfg), **changes})
    return cfg.validate()


def _profile_config(cfg: GeoStarsConfig, profile) -> GeoStarsConfig:
    """``cfg`` with the attitude magnitudes of a stars profile."""
    return GeoStarsConfig(**{**asdict(cfg), **{k: profile.value(k) for k in (
        "attitude_noise_arcsec", "attitude_jitter_arcsec", "attitude_jitter_hz", "attitude_drift_arcsec_s")}}).validate()


def _star_catalog(cfg: GeoStarsConfig):
    """The catalogue to render, its ICRS unit vectors and the magnitudes in the camera's band."""
    from sensor_models.geometry.star_catalogue import StarCatalog

    catalog = StarCatalog.load(mag_limit=cfg.mag_limit)
    if cfg.only_hip:
        catalog = catalog.select(np.isin(catalog.hip, np.asarray(cfg.only_hip, dtype=np.int64)))
        if len(catalog) == 0:
            raise InputError(f"none of {list(cfg.only_hip)} is in the catalogue", field="only_hip")
    unit_icrs = catalog.unit_vectors()
    mags = catalog.vmag - np.nan_to_num(np.clip(catalog.b_minus_v, -0.3, 2.0), nan=0.0) * cfg.swir_color_term
    return catalog, unit_icrs, mags


def _render_frames(tmp: Path, cfg: GeoStarsConfig, truth, catalog, unit_icrs, mags, rng, errors=None,
                   frames_out: list | None = None):
    """Render and write every frame under ``tmp/frames`` (or append it to ``frames_out``); the
    frame list, stars drawn, counts inside. One float64 buffer serves every frame."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from sensor_models.imaging.psf import dn_uint16, render_stars
    from sensor_models.geometry.star_catalogue import catalog_stars_in_frame

    seconds = np.arange(int(cfg.n_frames)) * float(cfg.frame_interval_s)
    margin = 5.0 * cfg.psf_sigma_px + 2.0
    shape = truth.image_shape
    if frames_out is None:
        (tmp / "frames").mkdir()
    frames, rendered = [], []
    buffer = np.empty(shape)
    profile = dict(driver="GTiff", width=shape[1], height=shape[0], count=1, dtype="uint16")
    n_per_frame = []
    unit_icrs, gain = _truth_sky(cfg, unit_icrs, shape, errors)
    for k, t in enumerate(seconds):
        model_t = truth.at_frame(float(t))
        idx, _, row, col = catalog_stars_in_frame(model_t, catalog, unit_icrs, margin)
        flux = cfg.flux_ref_adu * 10.0 ** (-0.4 * (mags[idx] - cfg.ref_mag))
        at = np.stack([row, col], -1)
        if errors is not None and errors.pixel_phase_px:
            from sensor_models.simulate.star_truth import pixel_phase_shift

            at = at + pixel_phase_shift(at, errors.pixel_phase_px)
        img = render_stars(shape, at, flux, sigma_px=cfg.psf_sigma_px,
                           background=cfg.background_adu, gain_e_per_adu=cfg.gain_e_per_adu,
                           read_noise_e=cfg.read_noise_e, rng=rng, out=buffer)
        offset = 0.0
        if gain is not None:  # background + (img - background) * gain; the background added in dn_uint16
            img -= cfg.background_adu
            img *= gain
            offset = cfg.background_adu
        dn = dn_uint16(img, offset)
        name = f"frames/frame_{k:04d}.tif"
        if frames_out is not None:
            frames_out.append(dn)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(tmp / name, "w", **profile) as dst:
                    dst.write(dn, 1)
        frames.append({"path": name, "seconds": float(t)})
        inside = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
        n_per_frame.append(int(inside.sum()))
        rendered.append({"seconds": float(t), "hip": catalog.hip[idx].tolist(), "row": row.tolist(),
                         "col": col.tolist(), "mag": mags[idx].round(3).tolist()})
    return frames, rendered, n_per_frame


def _truth_sky(cfg: GeoStarsConfig, unit_icrs, shape, errors):
    """Catalogue directions as the TRUE sky has them, and the PRNU gain map (None: none)."""
    if errors is None:
        return unit_icrs, None
    from sensor_models.simulate.star_truth import perturb_catalogue, prnu_map

    year = 1970.0 + np.datetime64(cfg.epoch_utc, "s").astype(np.int64) / (365.25 * 86400.0)
    unit_icrs = perturb_catalogue(unit_icrs, errors.catalogue_position_mas, errors.proper_motion_error_mas_yr, year,
                                  np.random.default_rng([int(cfg.seed), 2]))
    gain = prnu_map(shape, errors.prnu_rms, np.random.default_rng([int(cfg.seed), 3])) if errors.prnu_rms else None
    return unit_icrs, gain


def _truth_doc(cfg: GeoStarsConfig, lab, truth, d_inst, rendered) -> dict:
    """The content of ``truth.json``: settings, true and LAB parameters, errors, stars drawn."""
    shape = truth.image_shape
    initial = _radec_error_px(lab, truth, [0.5 * shape[0]], [0.5 * shape[1]])[0]
    return {
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()
                   if k != "extra" and not (k == "installation_error_arcsec" and not len(v))},
        "parameter_names": list(truth.parameter_names()),
        "true_parameters": truth.parameters().values.tolist(),
        "lab_parameters": lab.parameters().values.tolist(),
        "installation_error_arcsec": (d_inst / ARCSEC).tolist(),
        "initial_error_centre_px": {"ra": float(initial[0]), "de": float(initial[1])},
        "true_interior_fit_residual": truth.lab_fit_residual,
        "stars": rendered,
    }
