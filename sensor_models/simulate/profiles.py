"""Named error profiles of the push-broom simulator: what differs from an easy problem, and why.

A profile is a frozen dataclass whose every magnitude is a :class:`Sourced` value: the number
and the citation (or the word *assumption*) it comes from. Each field's unit and how the
simulator injects it are in the field's metadata (``unit``, ``model``); :func:`profile_table`
turns a profile into the rows of ``docs/error_budget.md``.

* ``ideal``: the simulator's default path (:func:`sensor_models.simulate.pushbroom_sim.
  simulate_pushbroom` renders it byte for byte as without a profile; the fields record the
  defaults' magnitudes).
* ``realistic``: the truth lies outside the estimator's family, the radiometric kernel is the
  simulator's own (:mod:`sensor_models.simulate.kernel`) and the reference DOM and DEM differ
  from what rendered the scene (:mod:`sensor_models.simulate.reference_pair`).

Profiles of the other seeds are other dataclasses, one per kind of experiment, in
:data:`KIND_PROFILES` (``kind`` -> name -> profile): :class:`StaringProfile` (seed 002 staring
camera), :class:`ThermalProfile` (seed 002 section 3.3 thermal installation), :class:`StarsProfile`
(seed 000 star tracks), :class:`OalrProfile` (seed 004 autocollimation) and the push-broom one
(seed 003). Each kind has ``ideal`` (the defaults' numbers), ``realistic`` and the ``paper-*`` profile
of its seed. :data:`PROFILES` stays the push-broom table (``gcpcal simulate pushbroom``);
:func:`get_profile` looks up any kind.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from sensor_models.errors import InputError

__all__ = ["KIND_PROFILES", "OalrProfile", "PROFILES", "PushbroomProfile", "Sourced", "StaringProfile", "StarsProfile",
           "ThermalProfile", "get_profile", "profile_table"]

DEFAULT = "the simulator's default (sensor_models/simulate/config.py)"
REALISTIC_RANGE = "project's realistic range"
ASSUMPTION = "assumption (no public figure for this sensor; order of magnitude)"
LIEBE = "Liebe 2002, Accuracy performance of star trackers - a tutorial, IEEE TAES 38(2):587-599 (arcsec class = ~5 urad)"
TONG = ("Tong et al. 2015, ZY-3 image distortions caused by attitude oscillation, ISPRS J. Photogramm. "
        "Remote Sens. 101:291-309 (oscillation of about 0.6-0.7 Hz)")
FARR = "Farr et al. 2007, The Shuttle Radar Topography Mission, Rev. Geophys. 45, RG2004 (16 m absolute, 90 %)"
RODRIGUEZ = "Rodriguez et al. 2006, An assessment of the SRTM topographic products, PE&RS 72(3):249-260 (5-9 m)"
SEED003 = "seed 003 (HY-1C CZI: Landsat 8 DOM, SRTM DEM, level-1A radiometrically corrected)"
SEIDEL = ("Smith, Modern Optical Engineering, 4th ed. 2008, ch. 3 (third-order astigmatism and field curvature "
          "grow as the square of the field angle)")
SUNSYNC = ("sun-synchronous 10:30 local time (Sentinel-2 MSI; HY-1C, seed 003); sun from Cooper's declination and the "
           "hour angle (Iqbal 1983, An Introduction to Solar Radiation, ch. 1)")
LANDSAT_TIME = "Landsat 8 descending node 10:00 +- 15 min (USGS Landsat 8 Data Users Handbook)"
IQBAL = "Iqbal 1983, An Introduction to Solar Radiation, Academic Press"
ISCCP = ("Rossow and Schiffer 1999, Advances in understanding clouds from ISCCP, BAMS 80(11):2261-2287 "
         "(cloud-top classes: low below ~3 km, middle ~3-6.5 km, high above)")
POD = ("precise orbit determination errors vary over a good part of the ~100 min orbit (once-per-revolution "
       "terms), e.g. Montenbruck & Gill 2000, Satellite Orbits, ch. 8")
S2_CONTRAST = ("measured on the real Sentinel-2 L1C red crop of the shared test data (real_textures/sentinel2/s2_B04.jp2) "
               "at 30 m by bench/bench_texture_stats.py (Landsat-8 pan 0.086, procedural texture 0.372)")
TEXTURE_POOR_FRACTION = (
    "calibrated by bench/bench_texture_stats.py: the share of textured 32 x 32 blocks at 30 m of the realistic "
    "fixture's procedural source becomes 0.56 (0.87 without), inside the real crops' 0.43-0.66 (Landsat-8 red, "
    "Landsat-8 pan, Sentinel-2 red of real_textures)")
TEXTURE_POOR_ATTENUATION = (
    "measured on the real Sentinel-2 L1C red crop (real_textures/sentinel2/s2_B04.jp2) at 30 m by "
    "bench/bench_texture_stats.py: median relative gradient RMS of its untextured blocks over that of its textured "
    "blocks, 0.17")
S2_MTF = "Sentinel-2 MSI image-quality requirement, MTF at Nyquist 0.15-0.30 (ESA Sentinel-2 User Handbook)"


@dataclass(frozen=True)
class Sourced:
    """A magnitude and where it comes from.

    Attributes
    ----------
    value : float, tuple of float or str
        The magnitude, in the unit of the profile field that holds it.
    source : str
        A citation, the project's realistic range, a default of the code, or ``assumption``.
    """

    value: object
    source: str


def _f(unit: str, model: str):
    return field(metadata={"unit": unit, "model": model})


class _ProfileFields:
    """What every profile offers: whether it is ``ideal``, and a field's magnitude."""

    @property
    def is_ideal(self) -> bool:
        """True for the profile that takes the simulator's default path."""
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


@dataclass(frozen=True)
class PushbroomProfile(_ProfileFields):
    """Error magnitudes of a push-broom scene (seed 003 kind); every field a :class:`Sourced`."""

    name: str
    # -- attitude and orbit: TRUE model only; the LAB (user's) model never knows them --------
    star_tracker_noise_urad: Sourced = _f("urad (1 sigma, per axis)", "white noise on the measured attitude, 4 Hz samples")
    jitter_amplitude_urad: Sourced = _f("urad (roll, pitch, yaw)", "sinusoid in the TRUE attitude, random phase")
    jitter_frequency_hz: Sourced = _f("Hz", "frequency of that sinusoid")
    attitude_drift_arcsec_s: Sourced = _f("arcsec/s (roll, pitch, yaw)", "linear drift of the TRUE attitude")
    orbit_bias_m: Sourced = _f("m (norm)", "constant ITRF offset of the measured orbit, seeded direction")
    orbit_noise_m: Sourced = _f("m (1 sigma, per axis)", "error of the measured orbit (1 s samples)")
    orbit_noise_period_s: Sourced = _f(
        "s (shortest period)", "0: white per sample; else a smooth error: three sinusoids per axis of periods in "
        "[P, 5 P] (scene.smooth_orbit_error), positions and velocities consistent")
    jitter_line2_amplitude_urad: Sourced = _f("urad (roll, pitch, yaw)", "second sinusoid in the TRUE attitude, random phase")
    jitter_line2_frequency_hz: Sourced = _f("Hz", "frequency of that second sinusoid")
    jitter_floor_rms_urad: Sourced = _f("urad rms (roll, pitch, yaw)", "coloured-noise floor of the TRUE attitude")
    jitter_floor_exponent: Sourced = _f("a in PSD ~ 1/f^a", "slope of that floor")
    jitter_floor_band_hz: Sourced = _f("Hz (low, high)", "band outside which the floor has no power")
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
    astigmatism_edge_px: Sourced = _f("px (along, across track) at the swath edge",
                                      "defocus radius added to the disk, growing as (field / half field)^2")
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
    procedural_rms_contrast: Sourced = _f(
        "median std/mean over 32 x 32 blocks at 30 m",
        "procedural source radiance: deviations from its mean scaled to this RMS contrast (real sources keep theirs)")
    texture_poor_fraction: Sourced = _f(
        "share of the land", "procedural source: smooth-edged patches of texture-poor ground (fields, plains, canopy) "
        "from a thresholded low-frequency field (simulate/texture_poor.py), after the contrast scaling")
    texture_poor_attenuation: Sourced = _f(
        "factor on deviations from the patch's local mean", "texture kept inside those patches (1: unchanged)")
    dom_bias_m: Sourced = _f("m (east, north)", "DOM geolocation bias")
    dom_field_rms_m: Sourced = _f("m rms (per axis)", "smooth DOM geolocation field")
    dom_field_scale_m: Sourced = _f("m", "correlation length of that field")
    dem_resolution_m: Sourced = _f("m", "user DEM grid (SRTM 3 arcsec-like), block average of the true DEM")
    dem_error_rms_m: Sourced = _f("m rms", "smooth height error field")
    dem_error_scale_m: Sourced = _f("m", "correlation length of that field")
    dem_void_fraction: Sourced = _f("share of nodes", "voids (nodata) in blobs")
    # -- illumination and clouds (sensor_models.simulate.illumination, clouds3d) ---------------
    sun_scene_date_time: Sourced = _f("(day of year, local solar hour)", "sun of the scene: hill shading and cast shadows on its radiance")
    sun_dom_date_time: Sourced = _f("(day of year, local solar hour)", "sun of the reference DOM: its own shading and shadows")
    skylight_fraction: Sourced = _f("share of irradiance on flat ground", "diffuse light, which reaches shadows")
    cloud_top_height_km: Sourced = _f("km (lowest, highest)", "uniform range of the cloud layers' top heights (parallax, shadow offset)")
    cloud_layers: Sourced = _f("layers", "distinct cloud heights per scene (each cloud in one layer)")
    cloud_shadow: Sourced = _f("share of the direct sun a cloud blocks", "cloud shadow on the ground, offset along the sun azimuth")
    kind: str = "pushbroom"



def _ideal() -> PushbroomProfile:
    s = lambda v: Sourced(v, DEFAULT)  # noqa: E731
    none = lambda v: Sourced(v, "not simulated in this profile")  # noqa: E731
    return PushbroomProfile(
        name="ideal",
        star_tracker_noise_urad=s(1.0), jitter_amplitude_urad=s((1.0, 1.0, 0.5)), jitter_frequency_hz=s(1.3),
        attitude_drift_arcsec_s=s((0.05, -0.04, 0.02)), orbit_bias_m=none(0.0), orbit_noise_m=s(1.0),
        orbit_noise_period_s=Sourced(0.0, DEFAULT + ": white per sample"),
        radial_k2_px=none(0.0), radial_k3_px=none(0.0), focal_plane_curvature_px=none(0.0),
        ccd_bending_px=none(0.0), detector_irregularity_px=none(0.0),
        supersampling=none(1), motion_smear_lines=none(0.0), defocus_radius_px=none(0.0),
        halo_fraction=none(0.0), halo_sigma_px=none(0.0), psf_sigma_px=s(0.45),
        prnu_rms=s(0.004), striping_dn=none(0.0), ccd_gain_step=none(0.0), nonlinearity=none(0.0),
        snr=s(100.0), bits=s(12),
        reference_resolution_m=s(15.0), reference_mtf_sigma_px=Sourced(0.0, "reference is the rendering DOM itself"),
        reference_gamma=Sourced(1.0, "reference is the rendering DOM itself"),
        seasonal_change=s(0.12), seasonal_scale_m=s(4000.0), haze=none(0.0), procedural_rms_contrast=none(0.0),
        texture_poor_fraction=none(0.0), texture_poor_attenuation=none(1.0),
        dom_bias_m=none((0.0, 0.0)), dom_field_rms_m=none(0.0), dom_field_scale_m=none(0.0),
        dem_resolution_m=Sourced(30.0, "user DEM is the rendering DEM itself"), dem_error_rms_m=none(0.0),
        dem_error_scale_m=none(0.0), dem_void_fraction=none(0.0),
        jitter_line2_amplitude_urad=none((0.0, 0.0, 0.0)), jitter_line2_frequency_hz=none(0.0),
        jitter_floor_rms_urad=none((0.0, 0.0, 0.0)), jitter_floor_exponent=none(0.0),
        jitter_floor_band_hz=none((0.0, 0.0)), astigmatism_edge_px=none((0.0, 0.0)),
        sun_scene_date_time=none(None), sun_dom_date_time=none(None), skylight_fraction=none(0.0),
        cloud_top_height_km=Sourced((0.0, 0.0), "the default clouds lie on the ground (no parallax, no shadow)"),
        cloud_layers=none(0), cloud_shadow=none(0.0),
    )


def _realistic() -> PushbroomProfile:
    return PushbroomProfile(
        name="realistic",
        star_tracker_noise_urad=Sourced(3.0, f"{REALISTIC_RANGE}: a few urad; {LIEBE}"),
        jitter_amplitude_urad=Sourced((5.0, 5.0, 2.0), f"{REALISTIC_RANGE}: 5 urad at 0.3 Hz"),
        jitter_frequency_hz=Sourced(0.3, f"{REALISTIC_RANGE}: 0.1-1 Hz; {TONG}"),
        attitude_drift_arcsec_s=Sourced((0.05, -0.04, 0.02), DEFAULT),
        orbit_bias_m=Sourced(3.0, f"{REALISTIC_RANGE}: 1-5 m"),
        orbit_noise_m=Sourced(1.0, f"{REALISTIC_RANGE}: 1-5 m"),
        orbit_noise_period_s=Sourced(600.0, f"{POD}; the 600 s floor: {ASSUMPTION}"),
        radial_k2_px=Sourced(0.4, ASSUMPTION),
        radial_k3_px=Sourced(-0.15, ASSUMPTION),
        focal_plane_curvature_px=Sourced(0.5, ASSUMPTION),
        ccd_bending_px=Sourced(0.3, ASSUMPTION),
        detector_irregularity_px=Sourced(0.03, f"{REALISTIC_RANGE}: 0.02-0.05 px rms"),
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
        snr=Sourced(100.0, DEFAULT),
        bits=Sourced(12, DEFAULT),
        reference_resolution_m=Sourced(30.0, f"{SEED003}; Landsat 8 OLI multispectral 30 m"),
        reference_mtf_sigma_px=Sourced(0.5, ASSUMPTION),
        reference_gamma=Sourced(0.8, ASSUMPTION),
        seasonal_change=Sourced(0.15, ASSUMPTION),
        seasonal_scale_m=Sourced(600.0, "field-parcel size; assumption"),
        haze=Sourced(0.03, ASSUMPTION),
        procedural_rms_contrast=Sourced(0.195, S2_CONTRAST),
        texture_poor_fraction=Sourced(0.5, TEXTURE_POOR_FRACTION),
        texture_poor_attenuation=Sourced(0.17, TEXTURE_POOR_ATTENUATION),
        dom_bias_m=Sourced((1.2, -0.9), f"{REALISTIC_RANGE}: DOM error 1-3 m"),
        dom_field_rms_m=Sourced(0.8, f"{REALISTIC_RANGE}: DOM error 1-3 m"),
        dom_field_scale_m=Sourced(3000.0, ASSUMPTION),
        dem_resolution_m=Sourced(90.0, FARR),
        dem_error_rms_m=Sourced(8.0, f"{RODRIGUEZ}; {FARR}"),
        dem_error_scale_m=Sourced(1000.0, ASSUMPTION),
        dem_void_fraction=Sourced(0.003, f"{FARR}: voids in steep and dry terrain; {ASSUMPTION}"),
        jitter_line2_amplitude_urad=Sourced((1.5, 1.5, 0.5), f"{TONG}: the line; amplitude: {ASSUMPTION}"),
        jitter_line2_frequency_hz=Sourced(0.65, TONG),
        jitter_floor_rms_urad=Sourced((1.0, 1.0, 0.5), f"{REALISTIC_RANGE}: ~1 urad; {ASSUMPTION}"),
        jitter_floor_exponent=Sourced(1.0, f"pink (1/f) floor; {ASSUMPTION}"),
        jitter_floor_band_hz=Sourced((0.05, 5.0), f"{REALISTIC_RANGE}: 0.05-5 Hz"),
        astigmatism_edge_px=Sourced((0.25, 0.08), f"{SEIDEL}; magnitude: {ASSUMPTION}"),
        sun_scene_date_time=Sourced((288, 10.5), f"{SUNSYNC}: 10:30 descending node, mid-October"),
        sun_dom_date_time=Sourced((213, 10.0), f"{LANDSAT_TIME}, early August (growing season)"),
        skylight_fraction=Sourced(0.15, f"{IQBAL}: diffuse share of clear-sky irradiance; {ASSUMPTION}"),
        cloud_top_height_km=Sourced((1.0, 8.0), ISCCP),
        cloud_layers=Sourced(3, ASSUMPTION),
        cloud_shadow=Sourced(0.9, f"optically thick cloud: the direct beam is almost all scattered; {ASSUMPTION}"),
    )


def _paper003() -> PushbroomProfile:
    """Seed 003's setting: the realistic magnitudes; its scale is :data:`PAPER003_SCALE`."""
    from dataclasses import replace

    return replace(_realistic(), name="paper-003")


#: every named push-broom profile (``gcpcal simulate pushbroom --profile`` offers ideal and realistic;
#: ``paper-003`` is run by ``gcpcal experiment 003``)
PROFILES = {"ideal": _ideal(), "realistic": _realistic(), "paper-003": _paper003()}

#: seed 003's acquisition (HY-1C CZI), for the ``paper-003`` experiment's scale
PAPER003_SCALE = {
    "n_cameras": Sourced(2, "seed 003 section 2 (two cameras)"),
    "ccds_per_camera": Sourced(2, "seed 003 section 2 (two CCDs per camera)"),
    "detectors_total": Sourced(21800, "seed 003 (about 21 800 detectors over the swath)"),
    "field_of_view_deg": Sourced(62.0, "seed 003 (+-31 degrees)"),
    "duration_s": Sourced(60.0, "seed 003 (about 60 s of imaging)"),
}

# --------------------------------------------------------------------------- other seeds
HIPPARCOS = "ESA 1997, The Hipparcos and Tycho Catalogues, ESA SP-1200 (about 1 mas and 1 mas/yr at Hp < 9)"
JIA = ("Jia et al. 2010, Systematic error analysis and compensation for high accuracy star centroid "
       "estimation of star tracker, Sci. China Tech. Sci. 53(11):3145-3152 (S-curve pixel-phase error)")
SEED000 = "seed 000 (geostationary staring camera, star tracks, August 2-21, 437 tracks, tables 1-4)"
SEED002 = "seed 002 (Xiao et al. 2023, Appl. Sci. 13, 9688: tables 1-3, section 3.3 figure 11)"
SEED004 = "seed 004 (OALR autocollimation, table 3: sigma_k 0.430 px lab, 0.144 px flight)"
NOT_SIMULATED = "not simulated in this profile"


@dataclass(frozen=True)
class StaringProfile(_ProfileFields):
    """Error magnitudes of seed 002's staring-camera compensation study; every field a :class:`Sourced`."""

    name: str
    physical_truth: Sourced = _f("bool", "TRUE interior evaluated from the physical lens at every pixel (else its 20-coefficient fit)")
    radial_k2_corner_px: Sourced = _f("px at the frame corner", "k2 r^5 radial term of the TRUE lens (Brown-Conrady)")
    radial_k3_corner_px: Sourced = _f("px at the frame corner", "k3 r^7 radial term of the TRUE lens")
    vcp_noise_px: Sourced = _f("px (1 sigma, per axis)", "Gaussian noise on the virtual control points' image coordinates")
    interior_source: Sourced = _f(
        "vcp | lab", "data of the interior: 'vcp' the free cubic on the VCPs (calibrate/schemes/compensate.py); 'lab' "
        "the camera-frame pointing angles of the grid measured in the lab, the exterior from the VCPs, one pass per "
        "scheme (calibrate/schemes/paper_flow.py)")
    lab_noise_px: Sourced = _f("px (1 sigma, per axis)", "Gaussian noise on the lab-measured camera-frame pointing angles "
                               "of the grid (interior_source lab)")
    attitude_noise_arcsec: Sourced = _f(
        "arcsec (1 sigma, per axis, white per VCP)", "attitude error of each VCP's observation: its ground point "
        "computed through the measured attitude (small-angle image equivalent; interior_source lab)")
    kind: str = "staring"


@dataclass(frozen=True)
class ThermalProfile(_ProfileFields):
    """Error magnitudes of seed 002's thermal installation series; every field a :class:`Sourced`."""

    name: str
    day_to_day_arcsec: Sourced = _f("arcsec per day (1 sigma step, per axis)", "random walk of the TRUE installation from day to day, smooth within a day")
    epoch_noise_arcsec: Sourced = _f("arcsec (1 sigma, per axis)", "white epoch-to-epoch noise of the TRUE installation")
    vcp_noise_px: Sourced = _f("px (1 sigma, per axis)", "noise on each epoch's control points")
    kind: str = "thermal"


@dataclass(frozen=True)
class StarsProfile(_ProfileFields):
    """Error magnitudes of seed 000's star-track calibration; every field a :class:`Sourced`."""

    name: str
    attitude_noise_arcsec: Sourced = _f("arcsec (1 sigma, per axis)", "white noise of the measured attitude (1 s samples) the LAB model uses")
    attitude_jitter_arcsec: Sourced = _f("arcsec (roll, pitch, yaw)", "sinusoid in the TRUE attitude, also in the measured one")
    attitude_jitter_hz: Sourced = _f("Hz", "its frequency")
    attitude_drift_arcsec_s: Sourced = _f("arcsec/s (roll, pitch, yaw)", "linear drift, TRUE and measured")
    wobble_arcsec: Sourced = _f("arcsec (per axis, random phase)", "sinusoid in the TRUE attitude only: unknown to the LAB model")
    wobble_period_s: Sourced = _f("s", "its period")
    catalogue_position_mas: Sourced = _f("mas (1 sigma, per axis)", "catalogue position error at its epoch: the rendered star is displaced")
    proper_motion_error_mas_yr: Sourced = _f("mas/yr (1 sigma, per axis)", "proper-motion error, times the years from J1991.25 to the frame epoch")
    pixel_phase_px: Sourced = _f("px (amplitude)", "centroid S-curve: rendered photocentre moved by a sin(2 pi frac(x))")
    prnu_rms: Sourced = _f("relative gain, rms", "per-pixel gain on the star signal")
    orbit_bias_m: Sourced = _f("m (along track)", "the LAB orbit is displaced along the GEO arc")
    installation_day_to_day_arcsec: Sourced = _f(
        "arcsec (1 sigma, per axis, independent per session)",
        "TRUE installation of day d = the first day's + an offset drawn per day: the thermal state at the same "
        "time of day differs from day to day; matters only when sessions are pooled")
    sessions: Sourced = _f("daily 20-min sessions", "independent sequences (another date, noise and wobble each)")
    kind: str = "stars"


@dataclass(frozen=True)
class OalrProfile(_ProfileFields):
    """Error magnitudes of seed 004's autocollimation (OALR) measurement; every field a :class:`Sourced`."""

    name: str
    amplitude_e: Sourced = _f("electrons (peak)", "cross-mark signal on the SMCCD")
    background_e: Sourced = _f("electrons", "background (stray light, dark)")
    read_noise_e: Sourced = _f("electrons rms", "read noise")
    psf_sigma_px: Sourced = _f("px", "Gaussian PSF of the mark")
    prnu_rms: Sourced = _f("relative gain, rms", "per-pixel gain of the SMCCD")
    mount_drift_px: Sourced = _f("px (1 sigma, per channel and axis)", "motion of the SMCCD itself between the two frames, unknown to eq. 2-5")
    centroid_sigma_px: Sourced = _f("px (1 sigma)", "given centroid noise added to every mark coordinate (paper's sigma_k); 0: from the rendering")
    kind: str = "oalr"


def _staring_profiles() -> dict:
    none = lambda v: Sourced(v, NOT_SIMULATED)  # noqa: E731
    vcp_match = "seed 003: SIFT/phase matches against Landsat 0.3-0.5 px, taken for the VCPs' source; project's realistic range"
    return {
        "ideal": StaringProfile("ideal", physical_truth=Sourced(False, "the default path: TRUE interior = 20-coefficient fit"),
                                radial_k2_corner_px=none(0.0), radial_k3_corner_px=none(0.0),
                                vcp_noise_px=Sourced(0.0, "`gcpcal compensate`'s default"),
                                interior_source=Sourced("vcp", "`gcpcal compensate`'s schemes"),
                                lab_noise_px=none(0.0), attitude_noise_arcsec=none(0.0)),
        "realistic": StaringProfile("realistic", physical_truth=Sourced(True, "project's realistic range: a TRUE lens outside the fitted family"),
                                    radial_k2_corner_px=Sourced(1.0, ASSUMPTION),
                                    radial_k3_corner_px=Sourced(-0.3, ASSUMPTION),
                                    vcp_noise_px=Sourced(0.3, vcp_match),
                                    interior_source=Sourced("vcp", "`gcpcal compensate`'s schemes"),
                                    lab_noise_px=none(0.0), attitude_noise_arcsec=none(0.0)),
        "paper-002": StaringProfile("paper-002", physical_truth=Sourced(True, f"{SEED002}: table 1 lens"),
                                    radial_k2_corner_px=Sourced(0.0, f"{SEED002}: table 1 has k1 only"),
                                    radial_k3_corner_px=Sourced(0.0, f"{SEED002}: table 1 has k1 only"),
                                    vcp_noise_px=Sourced(0.0, f"{SEED002}: no noise stated for the VCPs"),
                                    interior_source=Sourced("lab", f"{SEED002} section 2.3 bullets 4-6 and section 3.1: "
                                                            "the interior from the grid's camera-frame pointing "
                                                            "angles, the exterior from the VCPs"),
                                    lab_noise_px=Sourced(0.43, f"{SEED002} states none; {SEED004}: the lab sigma_k, "
                                                         "centroid noise of a space camera measured in the lab"),
                                    attitude_noise_arcsec=Sourced(1.0, f"{SEED002} section 2.3 bullet 2 and section "
                                                                  f"3.2 add attitude errors without a magnitude; "
                                                                  f"{LIEBE}")),
    }


def _thermal_profiles() -> dict:
    return {
        "ideal": ThermalProfile("ideal", day_to_day_arcsec=Sourced(0.0, NOT_SIMULATED),
                                epoch_noise_arcsec=Sourced(0.3, "ThermalDrift's default"),
                                vcp_noise_px=Sourced(0.1, "`gcpcal thermal`'s default")),
        "realistic": ThermalProfile("realistic", day_to_day_arcsec=Sourced(4.0, f"{REALISTIC_RANGE}: 3-6 arcsec a day"),
                                    epoch_noise_arcsec=Sourced(0.3, "ThermalDrift's default"),
                                    vcp_noise_px=Sourced(0.3, "as the staring profile's VCP noise")),
        "paper-002": ThermalProfile("paper-002", day_to_day_arcsec=Sourced(0.0, f"{SEED002}: figure 11 is one daily curve"),
                                    epoch_noise_arcsec=Sourced(0.3, "ThermalDrift's default"),
                                    vcp_noise_px=Sourced(0.0, f"{SEED002}: no noise stated for the VCPs")),
    }


def _stars_ideal() -> StarsProfile:
    s = lambda v: Sourced(v, "GeoStarsConfig's default")  # noqa: E731
    none = lambda v: Sourced(v, NOT_SIMULATED)  # noqa: E731
    return StarsProfile(
        "ideal", attitude_noise_arcsec=s(0.1), attitude_jitter_arcsec=s((0.2, 0.2, 0.2)), attitude_jitter_hz=s(0.02),
        attitude_drift_arcsec_s=s((0.002, -0.002, 0.004)), wobble_arcsec=none(0.0), wobble_period_s=none(1200.0),
        catalogue_position_mas=none(0.0), proper_motion_error_mas_yr=none(0.0), pixel_phase_px=none(0.0),
        prnu_rms=none(0.0), orbit_bias_m=none(0.0), installation_day_to_day_arcsec=none(0.0), sessions=s(1))


def _stars_profiles() -> dict:
    from dataclasses import replace

    ideal = _stars_ideal()
    realistic = replace(
        ideal, name="realistic",
        attitude_noise_arcsec=Sourced(1.0, f"{REALISTIC_RANGE}: 1 arcsec of attitude noise; {LIEBE}"),
        wobble_arcsec=Sourced(2.0, f"{REALISTIC_RANGE}: unmeasured 2 arcsec wobble over 20 min"),
        wobble_period_s=Sourced(1200.0, f"{REALISTIC_RANGE}: 20 min; {SEED000}: 20-min daily sessions"),
        catalogue_position_mas=Sourced(1.0, HIPPARCOS),
        proper_motion_error_mas_yr=Sourced(1.0, HIPPARCOS),
        pixel_phase_px=Sourced(0.05, f"{JIA}; {ASSUMPTION}"),
        prnu_rms=Sourced(0.01, f"SWIR focal plane after non-uniformity correction; {ASSUMPTION}"),
        orbit_bias_m=Sourced(200.0, f"GEO orbit determination by ranging, hundreds of m; {ASSUMPTION}"),
        installation_day_to_day_arcsec=Sourced(1.0, f"{SEED000} section 3.2: thermal deformation is periodic with "
                                                    f"about one day (its ref. [4]), so sessions are taken at one time "
                                                    f"of day; the residual day-to-day change is {ASSUMPTION}"))
    paper = replace(realistic, name="paper-000",
                    sessions=Sourced(20, f"{SEED000}: 20 days (the experiment states the number it ran)"))
    return {"ideal": ideal, "realistic": realistic, "paper-000": paper}


def _oalr_profiles() -> dict:
    from dataclasses import replace

    s = lambda v: Sourced(v, "render_cross's default (calibrate/schemes/autocollimation.py)")  # noqa: E731
    none = lambda v: Sourced(v, NOT_SIMULATED)  # noqa: E731
    ideal = OalrProfile("ideal", amplitude_e=s(1000.0), background_e=s(50.0), read_noise_e=s(10.0),
                        psf_sigma_px=s(0.8), prnu_rms=none(0.0), mount_drift_px=none(0.0),
                        centroid_sigma_px=none(0.0))
    realistic = replace(ideal, name="realistic",
                        amplitude_e=Sourced(300.0, f"flight: fainter mark through the camera's optics; {ASSUMPTION}"),
                        background_e=Sourced(200.0, f"stray light in flight; {ASSUMPTION}"),
                        read_noise_e=Sourced(15.0, ASSUMPTION), psf_sigma_px=Sourced(1.0, ASSUMPTION),
                        prnu_rms=Sourced(0.01, ASSUMPTION),
                        mount_drift_px=Sourced(0.05, f"SMCCD mount stability; {ASSUMPTION}"))
    paper = replace(ideal, name="paper-004", centroid_sigma_px=Sourced(0.144, f"{SEED004}: flight sigma_k"),
                    amplitude_e=Sourced(1000.0, "rendered noise is replaced by the paper's sigma_k"))
    return {"ideal": ideal, "realistic": realistic, "paper-004": paper}


#: every profile by experiment kind, then name
KIND_PROFILES = {"pushbroom": PROFILES, "staring": _staring_profiles(), "thermal": _thermal_profiles(),
                 "stars": _stars_profiles(), "oalr": _oalr_profiles()}


def get_profile(name: str, kind: str = "pushbroom"):
    """The profile called ``name`` of experiment kind ``kind``.

    Parameters
    ----------
    name : str
        A key of ``KIND_PROFILES[kind]`` (:data:`PROFILES` for the push-broom).
    kind : {"pushbroom", "staring", "thermal", "stars", "oalr"}
        The kind of experiment.

    Returns
    -------
    PushbroomProfile, StaringProfile, ThermalProfile, StarsProfile or OalrProfile

    Raises
    ------
    InputError
        Unknown kind or name (the message lists the known ones).
    """
    if kind not in KIND_PROFILES:
        raise InputError(f"unknown profile kind {kind!r} (known: {', '.join(KIND_PROFILES)})", field="kind")
    table = KIND_PROFILES[kind]
    try:
        return table[name]
    except KeyError:
        raise InputError(f"unknown profile {name!r} (known: {', '.join(table)})", field="profile") from None


def profile_table(profile) -> list:
    """Rows ``(field, value, unit, model, source)`` of a profile, in field order.

    Parameters
    ----------
    profile : PushbroomProfile, StaringProfile, ThermalProfile, StarsProfile or OalrProfile

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

