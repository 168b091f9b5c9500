"""Named error profiles of the push-broom simulator: what differs from an easy problem, and why.

A profile is a frozen dataclass whose every magnitude is a :class:`Sourced` value: the number
and the citation (or the word *assumption*) it comes from. Each field's unit and how the
simulator injects it are in the field's metadata (``unit``, ``model``); :func:`profile_table`
turns a profile into the rows of ``docs/error_budget.md``.

* ``ideal``: today's simulator, byte for byte (:func:`sensor_models.simulate.pushbroom_sim.
  simulate_pushbroom` takes its historical path; the fields record today's magnitudes).
* ``realistic``: the truth lies outside the estimator's family, the radiometric kernel is the
  simulator's own (:mod:`sensor_models.simulate.kernel`) and the reference DOM and DEM differ
  from what rendered the scene (:mod:`sensor_models.simulate.reference_pair`).

Later profiles (stars, thermal, ``paper-*``) register another dataclass in :data:`PROFILES`;
callers look profiles up by name with :func:`get_profile` and test ``profile.kind``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from sensor_models.errors import InputError

__all__ = ["PROFILES", "PushbroomProfile", "Sourced", "get_profile", "profile_table"]

TODAY = "today's simulator default (sensor_models/simulate/config.py)"
ISSUE13 = "issue 13 (project's realistic range)"
ASSUMPTION = "assumption (no public figure for this sensor; order of magnitude)"
LIEBE = "Liebe 2002, Accuracy performance of star trackers - a tutorial, IEEE TAES 38(2):587-599 (arcsec class = ~5 urad)"
TONG = ("Tong et al. 2015, ZY-3 image distortions caused by attitude oscillation, ISPRS J. Photogramm. "
        "Remote Sens. 101:291-309 (oscillation of about 0.6-0.7 Hz)")
FARR = "Farr et al. 2007, The Shuttle Radar Topography Mission, Rev. Geophys. 45, RG2004 (16 m absolute, 90 %)"
RODRIGUEZ = "Rodriguez et al. 2006, An assessment of the SRTM topographic products, PE&RS 72(3):249-260 (5-9 m)"
SEED003 = "seed 003 (HY-1C CZI: Landsat 8 DOM, SRTM DEM, level-1A radiometrically corrected)"
S2_MTF = "Sentinel-2 MSI image-quality requirement, MTF at Nyquist 0.15-0.30 (ESA Sentinel-2 User Handbook)"


@dataclass(frozen=True)
class Sourced:
    """A magnitude and where it comes from.

    Attributes
    ----------
    value : float, tuple of float or str
        The magnitude, in the unit of the profile field that holds it.
    source : str
        A citation, ``issue 13``, today's default, or ``assumption``.
    """

    value: object
    source: str


def _f(unit: str, model: str):
    return field(metadata={"unit": unit, "model": model})


@dataclass(frozen=True)
class PushbroomProfile:
    """Error magnitudes of a push-broom scene (seed 003 kind); every field a :class:`Sourced`."""

    name: str
    # -- attitude and orbit: TRUE model only; the LAB (user's) model never knows them --------
    star_tracker_noise_urad: Sourced = _f("urad (1 sigma, per axis)", "white noise on the measured attitude, 4 Hz samples")
    jitter_amplitude_urad: Sourced = _f("urad (roll, pitch, yaw)", "sinusoid in the TRUE attitude, random phase")
    jitter_frequency_hz: Sourced = _f("Hz", "frequency of that sinusoid")
    attitude_drift_arcsec_s: Sourced = _f("arcsec/s (roll, pitch, yaw)", "linear drift of the TRUE attitude")
    orbit_bias_m: Sourced = _f("m (norm)", "constant ITRF offset of the measured orbit, seeded direction")
    orbit_noise_m: Sourced = _f("m (1 sigma, per axis)", "white noise on the measured orbit, 1 s samples")
    # -- TRUE lens beyond the cubic in detector index -----------------------------------------
    radial_k2_px: Sourced = _f("px at the array end", "k2 r^5 radial term of the TRUE camera")
    radial_k3_px: Sourced = _f("px at the array end", "k3 r^7 radial term of the TRUE camera")
    focal_plane_curvature_px: Sourced = _f("px at the array ends", "along-track sag ~ (y / half width)^2 over the focal plane")
    ccd_bending_px: Sourced = _f("px (peak)", "along-track clamped-beam bow per CCD, 16 u^2 (1-u)^2 (quartic)")
    detector_irregularity_px: Sourced = _f("px rms (per axis)", "white per-detector LOS offset, applied by the kernel")
    # -- radiometric kernel (sensor_models.simulate.kernel) ----------------------------------
    supersampling: Sourced = _f("points per pixel axis", "sub-pixel integration over the detector footprint")
    motion_smear_lines: Sourced = _f("lines", "along-track smear during integration (box)")
    defocus_radius_px: Sourced = _f("px", "uniform-disk PSF (geometric defocus)")
    halo_fraction: Sourced = _f("share of energy", "Gaussian halo (stray light / scatter)")
    halo_sigma_px: Sourced = _f("px", "halo width")
    psf_sigma_px: Sourced = _f("px", "Gaussian PSF of the shared kernel (ideal path only)")
    prnu_rms: Sourced = _f("relative gain, rms", "per-detector gain")
    striping_dn: Sourced = _f("DN rms", "per-detector offset")
    ccd_gain_step: Sourced = _f("relative gain, rms", "gain of each CCD (steps at the CCD joins)")
    nonlinearity: Sourced = _f("coefficient a (largest deviation a/4 at half scale)", "response L (1 - a (1 - L))")
    snr: Sourced = _f("at 0.35 full scale", "read + shot noise")
    bits: Sourced = _f("bits", "quantization")
    # -- reference DOM and DEM given to the user --------------------------------------------
    reference_resolution_m: Sourced = _f("m", "DOM pixel (Landsat-like), block-averaged after its own MTF")
    reference_mtf_sigma_px: Sourced = _f("reference px", "Gaussian MTF of the reference sensor")
    reference_gamma: Sourced = _f("exponent", "non-linear radiometric mapping (another sensor)")
    seasonal_change: Sourced = _f("relative, rms", "multiplicative smooth field (another date)")
    seasonal_scale_m: Sourced = _f("m", "correlation length of that field")
    haze: Sourced = _f("share of full scale (mean)", "additive smooth veil (another date)")
    dom_bias_m: Sourced = _f("m (east, north)", "DOM geolocation bias")
    dom_field_rms_m: Sourced = _f("m rms (per axis)", "smooth DOM geolocation field")
    dom_field_scale_m: Sourced = _f("m", "correlation length of that field")
    dem_resolution_m: Sourced = _f("m", "user DEM grid (SRTM 3 arcsec-like), block average of the true DEM")
    dem_error_rms_m: Sourced = _f("m rms", "smooth height error field")
    dem_error_scale_m: Sourced = _f("m", "correlation length of that field")
    dem_void_fraction: Sourced = _f("share of nodes", "voids (nodata) in blobs")
    kind: str = "pushbroom"

    @property
    def is_ideal(self) -> bool:
        """True for the profile that takes the simulator's historical path."""
        return self.name == "ideal"

    def value(self, name: str):
        """The magnitude of field ``name`` (its :attr:`Sourced.value`).

        Parameters
        ----------
        name : str
            A field of this profile.

        Returns
        -------
        float, tuple or str
        """
        return getattr(self, name).value


def _ideal() -> PushbroomProfile:
    s = lambda v: Sourced(v, TODAY)  # noqa: E731
    none = lambda v: Sourced(v, "not simulated in this profile")  # noqa: E731
    return PushbroomProfile(
        name="ideal",
        star_tracker_noise_urad=s(1.0), jitter_amplitude_urad=s((1.0, 1.0, 0.5)), jitter_frequency_hz=s(1.3),
        attitude_drift_arcsec_s=s((0.05, -0.04, 0.02)), orbit_bias_m=none(0.0), orbit_noise_m=s(1.0),
        radial_k2_px=none(0.0), radial_k3_px=none(0.0), focal_plane_curvature_px=none(0.0),
        ccd_bending_px=none(0.0), detector_irregularity_px=none(0.0),
        supersampling=none(1), motion_smear_lines=none(0.0), defocus_radius_px=none(0.0),
        halo_fraction=none(0.0), halo_sigma_px=none(0.0), psf_sigma_px=s(0.45),
        prnu_rms=s(0.004), striping_dn=none(0.0), ccd_gain_step=none(0.0), nonlinearity=none(0.0),
        snr=s(100.0), bits=s(12),
        reference_resolution_m=s(15.0), reference_mtf_sigma_px=Sourced(0.0, "reference is the rendering DOM itself"),
        reference_gamma=Sourced(1.0, "reference is the rendering DOM itself"),
        seasonal_change=s(0.12), seasonal_scale_m=s(4000.0), haze=none(0.0),
        dom_bias_m=none((0.0, 0.0)), dom_field_rms_m=none(0.0), dom_field_scale_m=none(0.0),
        dem_resolution_m=Sourced(30.0, "user DEM is the rendering DEM itself"), dem_error_rms_m=none(0.0),
        dem_error_scale_m=none(0.0), dem_void_fraction=none(0.0),
    )


def _realistic() -> PushbroomProfile:
    return PushbroomProfile(
        name="realistic",
        star_tracker_noise_urad=Sourced(3.0, f"{ISSUE13}: a few urad; {LIEBE}"),
        jitter_amplitude_urad=Sourced((5.0, 5.0, 2.0), f"{ISSUE13}: 5 urad at 0.3 Hz"),
        jitter_frequency_hz=Sourced(0.3, f"{ISSUE13}: 0.1-1 Hz; {TONG}"),
        attitude_drift_arcsec_s=Sourced((0.05, -0.04, 0.02), TODAY),
        orbit_bias_m=Sourced(3.0, f"{ISSUE13}: 1-5 m"),
        orbit_noise_m=Sourced(1.0, f"{ISSUE13}: 1-5 m"),
        radial_k2_px=Sourced(0.4, ASSUMPTION),
        radial_k3_px=Sourced(-0.15, ASSUMPTION),
        focal_plane_curvature_px=Sourced(0.5, ASSUMPTION),
        ccd_bending_px=Sourced(0.3, ASSUMPTION),
        detector_irregularity_px=Sourced(0.03, f"{ISSUE13} brief: 0.02-0.05 px rms"),
        supersampling=Sourced(4, "numerical choice: 4 x 4 samples over the box, x 4 over the smear"),
        motion_smear_lines=Sourced(1.0, "push-broom without TDI integrates over one line period"),
        defocus_radius_px=Sourced(0.6, f"{ASSUMPTION}; chosen so that the system MTF at Nyquist is in {S2_MTF}"),
        halo_fraction=Sourced(0.05, ASSUMPTION),
        halo_sigma_px=Sourced(3.0, ASSUMPTION),
        psf_sigma_px=Sourced(0.0, "not used: the realistic kernel has its own PSF"),
        prnu_rms=Sourced(0.005, f"{SEED003}: residual after relative correction; {ASSUMPTION}"),
        striping_dn=Sourced(2.0, ASSUMPTION),
        ccd_gain_step=Sourced(0.02, ASSUMPTION),
        nonlinearity=Sourced(0.02, ASSUMPTION),
        snr=Sourced(100.0, TODAY),
        bits=Sourced(12, TODAY),
        reference_resolution_m=Sourced(30.0, f"{SEED003}; Landsat 8 OLI multispectral 30 m"),
        reference_mtf_sigma_px=Sourced(0.5, ASSUMPTION),
        reference_gamma=Sourced(0.8, ASSUMPTION),
        seasonal_change=Sourced(0.15, ASSUMPTION),
        seasonal_scale_m=Sourced(600.0, "field-parcel size; assumption"),
        haze=Sourced(0.03, ASSUMPTION),
        dom_bias_m=Sourced((1.2, -0.9), f"{ISSUE13}: DOM error 1-3 m"),
        dom_field_rms_m=Sourced(0.8, f"{ISSUE13}: DOM error 1-3 m"),
        dom_field_scale_m=Sourced(3000.0, ASSUMPTION),
        dem_resolution_m=Sourced(90.0, FARR),
        dem_error_rms_m=Sourced(8.0, f"{RODRIGUEZ}; {FARR}"),
        dem_error_scale_m=Sourced(1000.0, ASSUMPTION),
        dem_void_fraction=Sourced(0.003, f"{FARR}: voids in steep and dry terrain; {ASSUMPTION}"),
    )


#: every named profile
PROFILES = {"ideal": _ideal(), "realistic": _realistic()}


def get_profile(name: str):
    """The profile called ``name``.

    Parameters
    ----------
    name : str
        A key of :data:`PROFILES`.

    Returns
    -------
    PushbroomProfile

    Raises
    ------
    InputError
        Unknown name (the message lists the known ones).
    """
    try:
        return PROFILES[name]
    except KeyError:
        raise InputError(f"unknown profile {name!r} (known: {', '.join(PROFILES)})", field="profile") from None


def profile_table(profile) -> list:
    """Rows ``(field, value, unit, model, source)`` of a profile, in field order.

    Parameters
    ----------
    profile : PushbroomProfile

    Returns
    -------
    list of tuple of str
    """
    rows = []
    for f in fields(profile):
        v = getattr(profile, f.name)
        if isinstance(v, Sourced):
            rows.append((f.name, str(v.value), f.metadata["unit"], f.metadata["model"], v.source))
    return rows
