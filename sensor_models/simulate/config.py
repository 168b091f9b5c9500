"""The push-broom simulator's configuration: every default in one typed tree, loaded strictly.

A configuration file is JSON with any subset of the sections and keys below; an unknown key, a
wrong type or an impossible value is an error naming the file and the dotted field. The
defaults are the embedded fixture: seed 003's HY-1C coastal zone imager (two cameras of two
CCDs, four bands, 0.12 degree boresight offset, errors of hundreds of pixels) scaled down to
4 x 192 detectors, 512 lines and 30 m pixels.

Units are in the names: ``_deg``, ``_arcsec``, ``_urad``, ``_px`` (detector pitches), ``_m``,
``_s``, ``_hz``; unsuffixed numbers are ratios.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from sensor_models.errors import InputError

__all__ = ["SimConfig", "load_config"]


@dataclass(frozen=True)
class SceneConfig:
    center_lon_deg: float = 5.5
    center_lat_deg: float = 44.5
    epoch_utc: str = "2023-06-15T03:00:00"
    n_rows: int = 512
    altitude_m: float = 782_121.0
    gsd_m: float = 30.0
    inclination_deg: float = 98.5
    #: seed of this acquisition's own draws (attitude and orbit noise, jitter phase, image noise,
    #: seasonal change, clouds); -1: the sensor's ``seed``. The camera (its true errors, PRNU)
    #: follows ``seed`` only, so scenes of one sensor share it.
    acquisition_seed: int = -1


@dataclass(frozen=True)
class CameraConfig:
    n_cameras: int = 2
    ccds_per_camera: int = 2
    detectors_per_ccd: int = 192
    overlap_detectors: int = 12
    bands: tuple = ("B1", "B2", "B3", "B4")
    reference_band: str = "B2"
    band_offsets_px: tuple = (-6.0, -2.0, 2.0, 6.0)
    boresight_offset_deg: float = 0.12
    pixel_size_mm: float = 0.0105
    lab_polynomial_degree: int = 3


@dataclass(frozen=True)
class ErrorConfig:
    """What differs between the TRUE camera and the LAB model written in the manifest."""

    installation_deg: tuple = (0.45, -0.32, 2.0)
    camera2_rotation_arcsec: tuple = (40.0, -30.0, 60.0)
    focal_length_ratio: float = 1.0015
    principal_point_px: tuple = (1.5, -2.0)
    radial_distortion_px: float = 2.5
    decentering_px: tuple = (0.4, -0.3)
    ccd_shift_px: float = 0.8
    band_offset_error_px: float = 0.3
    attitude_bias_arcsec: tuple = (8.0, -6.0, 15.0)
    attitude_drift_arcsec_s: tuple = (0.05, -0.04, 0.02)
    jitter_amplitude_urad: tuple = (1.0, 1.0, 0.5)
    jitter_frequency_hz: float = 1.3
    thermal_drift_arcsec_s: tuple = (0.0, 0.0, 0.0)
    attitude_noise_urad: float = 1.0
    orbit_noise_m: float = 1.0
    orbit_noise_period_s: float = 0.0


@dataclass(frozen=True)
class RadiometryConfig:
    snr: float = 100.0
    band_gain: tuple = (0.85, 1.0, 0.9, 1.1)
    band_offset_dn: tuple = (60.0, 40.0, 50.0, 30.0)
    band_gamma: tuple = (1.1, 1.0, 0.95, 0.85)
    seasonal_change: float = 0.12
    seasonal_scale_m: float = 4000.0
    psf_sigma_px: float = 0.45
    prnu: float = 0.004
    bits: int = 12


@dataclass(frozen=True)
class CloudConfig:
    cover: float = 0.0
    scale_m: float = 3000.0


@dataclass(frozen=True)
class ReferenceConfig:
    dom_resolution_m: float = 15.0
    dem_resolution_m: float = 30.0
    relief_m: float = 1500.0
    mean_height_m: float = 500.0
    sea_fraction: float = 0.15
    margin_m: float = 2000.0


@dataclass(frozen=True)
class SimConfig:
    seed: int = 2023
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    errors: ErrorConfig = field(default_factory=ErrorConfig)
    radiometry: RadiometryConfig = field(default_factory=RadiometryConfig)
    clouds: CloudConfig = field(default_factory=CloudConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)

    def to_dict(self) -> dict:
        """The configuration as a JSON-ready mapping (the form :func:`config_from_dict` reads).

        Returns
        -------
        dict
            ``{"seed": int, "<section>": {field: value}}``; tuples become lists.
        """
        out = {"seed": self.seed}
        for f in fields(self):
            if f.name != "seed":
                sec = getattr(self, f.name)
                out[f.name] = {g.name: _jsonable(getattr(sec, g.name)) for g in fields(sec)}
        return out

    @property
    def pass_seed(self) -> int:
        """Seed of the acquisition's own random draws (``scene.acquisition_seed`` or ``seed``)."""
        return self.seed if self.scene.acquisition_seed < 0 else self.scene.acquisition_seed

    def with_seed(self, seed: int) -> "SimConfig":
        """A copy with another master seed.

        Parameters
        ----------
        seed : int
            The new ``seed``.

        Returns
        -------
        SimConfig
        """
        return replace(self, seed=int(seed))

    def validate(self, source: str | None = None) -> "SimConfig":
        """Raise :class:`InputError` naming the field of the first impossible value.

        Parameters
        ----------
        source : str, optional
            The configuration file, named in errors.

        Returns
        -------
        SimConfig
            ``self``.
        """

        def bad(name, why):
            return InputError(why, path=source, field=name)

        s, c, e, r = self.scene, self.camera, self.errors, self.radiometry
        if not -80.0 <= s.center_lat_deg <= 80.0:
            raise bad("scene.center_lat_deg", "must lie in [-80, 80] (UTM reference grids)")
        if not -180.0 <= s.center_lon_deg <= 180.0:
            raise bad("scene.center_lon_deg", "must lie in [-180, 180]")
        for name in ("altitude_m", "gsd_m"):
            if not getattr(s, name) > 0:
                raise bad(f"scene.{name}", "must be positive")
        if not 200_000 <= s.altitude_m <= 2_000_000:
            raise bad("scene.altitude_m", "must be a low Earth orbit (200 to 2000 km)")
        if s.acquisition_seed < -1:
            raise bad("scene.acquisition_seed", "must be -1 (the sensor's seed) or >= 0")
        if s.n_rows < 32:
            raise bad("scene.n_rows", "must be at least 32 lines")
        if c.n_cameras < 1 or c.ccds_per_camera < 1:
            raise bad("camera.n_cameras", "cameras and CCDs per camera must be >= 1")
        if c.detectors_per_ccd < 16:
            raise bad("camera.detectors_per_ccd", "must be at least 16")
        if not 0 <= c.overlap_detectors < c.detectors_per_ccd // 2:
            raise bad("camera.overlap_detectors", "must be >= 0 and less than half a CCD")
        if len(set(c.bands)) != len(c.bands) or not c.bands:
            raise bad("camera.bands", "must be a non-empty list of distinct names")
        if c.reference_band not in c.bands:
            raise bad("camera.reference_band", f"{c.reference_band!r} is not one of the bands")
        nb = len(c.bands)
        for sec, name in (("camera", "band_offsets_px"), ("radiometry", "band_gain"),
                          ("radiometry", "band_offset_dn"), ("radiometry", "band_gamma")):
            if len(getattr(getattr(self, sec), name)) != nb:
                raise bad(f"{sec}.{name}", f"must have one value per band ({nb})")
        if not c.pixel_size_mm > 0:
            raise bad("camera.pixel_size_mm", "must be positive")
        if not 1 <= c.lab_polynomial_degree <= 7:
            raise bad("camera.lab_polynomial_degree", "must be 1 to 7")
        if max(abs(a) for a in e.installation_deg) > 10.0:
            raise bad("errors.installation_deg", "installation errors beyond 10 degrees are not a calibration problem")
        if not 0.9 < e.focal_length_ratio < 1.1:
            raise bad("errors.focal_length_ratio", "must lie in (0.9, 1.1)")
        if e.jitter_frequency_hz < 0:
            raise bad("errors.jitter_frequency_hz", "must be >= 0")
        for name in ("attitude_noise_urad", "orbit_noise_m", "orbit_noise_period_s", "ccd_shift_px",
                     "band_offset_error_px"):
            if getattr(e, name) < 0:
                raise bad(f"errors.{name}", "must be >= 0")
        if not r.snr > 0:
            raise bad("radiometry.snr", "must be positive")
        if not 8 <= r.bits <= 16:
            raise bad("radiometry.bits", "must be 8 to 16")
        if any(g <= 0 for g in r.band_gain) or any(g <= 0 for g in r.band_gamma):
            raise bad("radiometry.band_gain", "gains and gammas must be positive")
        if not 0 <= r.seasonal_change < 1:
            raise bad("radiometry.seasonal_change", "must lie in [0, 1)")
        if not 0 <= r.psf_sigma_px <= 5:
            raise bad("radiometry.psf_sigma_px", "must lie in [0, 5]")
        if not 0 <= self.clouds.cover <= 1:
            raise bad("clouds.cover", "must lie in [0, 1]")
        ref = self.reference
        if not (ref.dom_resolution_m > 0 and ref.dem_resolution_m > 0):
            raise bad("reference.dom_resolution_m", "resolutions must be positive")
        if not 0 <= ref.sea_fraction <= 0.9:
            raise bad("reference.sea_fraction", "must lie in [0, 0.9]")
        if ref.relief_m < 0 or ref.margin_m < 0:
            raise bad("reference.relief_m", "relief and margin must be >= 0")
        return self


def _jsonable(v):
    return list(v) if isinstance(v, tuple) else v


def coerce_value(value, default, where: str, source: str):
    """Check ``value`` against the type of ``default``; return it in that type."""

    def err(why):
        return InputError(why, path=source, field=where)

    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise err(f"must be true or false, got {type(value).__name__}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise err(f"must be an integer, got {type(value).__name__}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise err(f"must be a finite number, got {value!r}")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise err(f"must be a string, got {type(value).__name__}")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, list):
            raise err(f"must be a list, got {type(value).__name__}")
        kinds = {type(d) for d in default} or {type(v) for v in value}
        if str in kinds:
            if not all(isinstance(v, str) for v in value):
                raise err("must be a list of strings")
            return tuple(value)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
            raise err("must be a list of finite numbers")
        if len(default) in (2, 3) and len(value) != len(default) and where.split(".")[0] == "errors":
            raise err(f"must have {len(default)} values")
        return tuple(float(v) for v in value)
    raise err("unsupported value")  # pragma: no cover


def config_from_dict(doc, *, source: str = "<config>") -> SimConfig:
    """A validated :class:`SimConfig` from a JSON-like mapping (strict).

    Parameters
    ----------
    doc : dict
        ``seed`` and sections (``scene``, ``camera``, ``errors``, ``radiometry``, ``clouds``,
        ``reference``), each a subset of that section's fields; the rest keep their defaults.
    source : str
        Named in errors.

    Returns
    -------
    SimConfig

    Raises
    ------
    InputError
        Unknown key, wrong type or impossible value (naming the field).
    """
    if not isinstance(doc, dict):
        raise InputError("the configuration must be a JSON object", path=source)
    base = SimConfig()
    kwargs = {}
    sections = {f.name: f for f in fields(SimConfig)}
    for key, value in doc.items():
        if key not in sections:
            raise InputError(f"unknown key {key!r} (known: {', '.join(sections)})", path=source, field="(root)")
        if key == "seed":
            seed = coerce_value(value, 0, "seed", source)
            if seed < 0:
                raise InputError("must be >= 0", path=source, field="seed")
            kwargs["seed"] = seed
            continue
        if not isinstance(value, dict):
            raise InputError("must be an object", path=source, field=key)
        sec_default = getattr(base, key)
        known = {f.name for f in fields(sec_default)}
        changes = {}
        for k, v in value.items():
            if k not in known:
                raise InputError(f"unknown key {k!r}", path=source, field=key)
            changes[k] = coerce_value(v, getattr(sec_default, k), f"{key}.{k}", source)
        kwargs[key] = replace(sec_default, **changes)
    return replace(base, **kwargs).validate(source)


def load_config(path=None) -> SimConfig:
    """Read a JSON configuration file (``None``: the defaults).

    Parameters
    ----------
    path : str or os.PathLike, optional
        The JSON file (see :func:`config_from_dict`).

    Returns
    -------
    SimConfig
        Validated.
    """
    if path is None:
        return SimConfig().validate()
    path = Path(path)
    from sensor_models.files.documents import load_json

    doc = load_json(path)
    return config_from_dict(doc, source=str(path))
