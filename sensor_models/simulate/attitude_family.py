"""A randomized family of push-broom scenes for time-varying attitude: seeded draws, fast GCPs.

Each draw (:func:`draw_scene`) picks, from documented ranges (:class:`FamilyRanges`), a scene
duration, a GCP count and noise, one band or four, an installation error, a drift and a jitter
made of one to three sinusoids per axis with random frequencies, amplitudes and phases. The TRUE
model (:func:`true_model`) is the laboratory model of :func:`sensor_models.models.synthetic.
example_pushbroom_model` with that installation and with the jitter and drift rotated into its
measured attitude, sampled at 100 Hz and interpolated by the model like any measured attitude:
sums of sinusoids are outside the spline and drift families the calibration estimates. GCPs
(:func:`synthetic_gcps`) are random pixels of the reference band at random heights, localized
through the TRUE model, with Gaussian noise added: no image matching, so that a draw of 100 000
GCPs takes seconds. For four bands, band-to-band tie points (:func:`synthetic_ties`) come from
the TRUE transfer map of a reference-band grid.

Simulation only: never imported by production code.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from sensor_models.geometry.ephemeris import Attitude
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.models.pushbroom_types import Installation
from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model

__all__ = ["AXES", "FamilyRanges", "SceneDraw", "draw_scene", "jitter_angles", "lab_model", "line_period_s",
           "gcp_rows", "max_gap_s", "synthetic_gcps", "synthetic_ties", "true_model", "truth_error", "without_time_variation"]

AXES = ("roll", "pitch", "yaw")
#: sample rate of the TRUE attitude, Hz (33 samples per period of the fastest 3 Hz jitter)
TRUE_ATTITUDE_HZ = 100.0
#: one-band camera: the example design's reference band alone
ONE_BAND = CameraDesign(band_names=("B2",), band_offsets_px=(-2.0,))


@dataclass(frozen=True)
class FamilyRanges:
    """Documented ranges of the family (docs/attitude.md "Randomized family").

    Attributes
    ----------
    duration_s : (float, float)
        Scene duration, uniform, seconds.
    n_gcps : (int, int)
        GCP count, log-uniform.
    noise_px : (float, float)
        GCP noise standard deviation per axis, log-uniform, px.
    jitter_hz : (float, float)
        Frequency of each sinusoid, log-uniform, Hz.
    jitter_urad : (float, float)
        Amplitude of the sum's strongest sinusoid per axis, uniform, micro-radians (a second and
        third sinusoid get a random fraction of it).
    max_lines : int
        Most sinusoids per axis (1 .. max_lines, uniform).
    p_no_jitter : float
        Probability that a draw has no jitter at all.
    drift_urad_s : float
        Drift rate per axis, uniform in +- this, micro-radians per second (half the draws).
    installation_urad : float
        Installation error per axis, uniform in +- this, micro-radians.
    p_four_bands : float
        Probability of four bands (GCPs in the reference band, ties from the three others).
    """

    duration_s: tuple = (2.0, 20.0)
    n_gcps: tuple = (100, 100_000)
    noise_px: tuple = (0.05, 0.5)
    jitter_hz: tuple = (0.1, 3.0)
    jitter_urad: tuple = (0.0, 40.0)
    max_lines: int = 3
    p_no_jitter: float = 0.25
    drift_urad_s: float = 2.0
    installation_urad: float = 300.0
    p_four_bands: float = 0.25


@dataclass(frozen=True)
class SceneDraw:
    """One draw of the family.

    Attributes
    ----------
    seed : int
    duration_s : float
    n_rows : int
    n_gcps : int
    noise_px : float
    n_bands : int
        1 or 4.
    jitter : tuple of (amplitudes_urad (3,), frequency_hz, phases_rad (3,))
        Sinusoids summed into the TRUE attitude (empty: none).
    drift_urad_s : ndarray, shape (3,)
    installation_rad : ndarray, shape (3,)
    """

    seed: int
    duration_s: float
    n_rows: int
    n_gcps: int
    noise_px: float
    n_bands: int
    jitter: tuple = field(default=())
    drift_urad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    installation_rad: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def has_jitter(self) -> bool:
        """True when some sinusoid has a non-zero amplitude."""
        return any(np.any(np.asarray(a) > 0.0) for a, _, _ in self.jitter)

    def max_frequency_hz(self) -> float:
        """Highest frequency with a non-zero amplitude (0 without jitter)."""
        return max([f for a, f, _ in self.jitter if np.any(np.asarray(a) > 0)] + [0.0])

    def jitter_dof(self) -> float:
        """Degrees of freedom of the truth's time variation: ``2 f_max T + 1`` per jittered axis,
        plus one per drifting axis (a band-limited signal of ``T`` seconds up to ``f_max`` has about
        ``2 f_max T`` of them, Landau and Pollak 1962)."""
        dof = 0.0
        for a in range(3):
            f = [fr for amp, fr, _ in self.jitter if amp[a] > 0.0]
            if f:
                dof += 2.0 * max(f) * self.duration_s + 1.0
            elif self.drift_urad_s[a] != 0.0:
                dof += 1.0
        return dof

    def to_dict(self) -> dict:
        """JSON form."""
        return {"seed": self.seed, "duration_s": self.duration_s, "n_rows": self.n_rows, "n_gcps": self.n_gcps,
                "noise_px": self.noise_px, "n_bands": self.n_bands,
                "jitter": [{"amplitude_urad": [float(v) for v in a], "frequency_hz": float(f)} for a, f, _ in self.jitter],
                "drift_urad_s": [float(v) for v in self.drift_urad_s],
                "installation_urad": [float(v) * 1e6 for v in self.installation_rad]}


@lru_cache(maxsize=4)
def line_period_s(design: CameraDesign = CameraDesign()) -> float:
    """Line period of the example camera, seconds (:func:`example_pushbroom_model`)."""
    return float(example_pushbroom_model(n_rows=10, design=design).line_timing.line_period_s)


def draw_scene(seed: int, ranges: FamilyRanges = FamilyRanges(), *, n_gcps=None, n_bands=None,
               jitter=None) -> SceneDraw:
    """One seeded draw of the family.

    Parameters
    ----------
    seed : int
        Seed of ``numpy.random.default_rng``; the same seed gives the same draw.
    ranges : FamilyRanges
    n_gcps : (int, int), optional
        Overrides ``ranges.n_gcps`` (e.g. a sub-family of 100-300 GCPs).
    n_bands : int, optional
        1 or 4 instead of the random choice.
    jitter : bool, optional
        Force jitter (True) or none (False) instead of ``ranges.p_no_jitter``.

    Returns
    -------
    SceneDraw
    """
    rng = np.random.default_rng(seed)
    duration = float(rng.uniform(*ranges.duration_s))
    lo, hi = n_gcps or ranges.n_gcps
    count = int(round(np.exp(rng.uniform(np.log(lo), np.log(hi)))))
    noise = float(np.exp(rng.uniform(*np.log(ranges.noise_px))))
    bands = int(n_bands or (4 if rng.uniform() < ranges.p_four_bands else 1))
    has_jitter = bool(rng.uniform() >= ranges.p_no_jitter) if jitter is None else bool(jitter)
    lines = []
    if has_jitter:
        strongest = rng.uniform(*ranges.jitter_urad, 3)
        for k in range(int(rng.integers(1, ranges.max_lines + 1))):
            frac = np.ones(3) if k == 0 else rng.uniform(0.1, 0.6, 3)
            f = float(np.exp(rng.uniform(*np.log(ranges.jitter_hz))))
            lines.append((strongest * frac, f, rng.uniform(0.0, 2.0 * np.pi, 3)))
    drift = rng.uniform(-1.0, 1.0, 3) * ranges.drift_urad_s if rng.uniform() < 0.5 else np.zeros(3)
    inst = rng.uniform(-1.0, 1.0, 3) * ranges.installation_urad * 1e-6
    n_rows = int(round(duration / line_period_s(ONE_BAND if bands == 1 else CameraDesign())))
    return SceneDraw(seed, duration, n_rows, count, noise, bands, tuple(lines), drift, inst)


def jitter_angles(draw: SceneDraw, seconds) -> np.ndarray:
    """Jitter plus drift of the TRUE attitude at ``seconds`` (N, 3), radians."""
    t = np.asarray(seconds, dtype=np.float64)
    out = np.asarray(draw.drift_urad_s)[None, :] * 1e-6 * t[:, None]
    for amp, f, phase in draw.jitter:
        out = out + np.asarray(amp)[None, :] * 1e-6 * np.sin(2.0 * np.pi * f * t[:, None] + np.asarray(phase)[None, :])
    return out


def lab_model(draw: SceneDraw) -> PushbroomModel:
    """The laboratory model a user of the draw's camera has (no installation error, no jitter)."""
    return example_pushbroom_model(n_rows=draw.n_rows, design=ONE_BAND if draw.n_bands == 1 else CameraDesign())


def true_model(draw: SceneDraw, lab: PushbroomModel) -> PushbroomModel:
    """TRUE model: ``lab`` with the draw's installation and its jitter and drift in the attitude.

    The measured attitude is multiplied (body side) by ``Rz(yaw) Ry(pitch) Rx(roll)`` of
    :func:`jitter_angles`, sampled at :data:`TRUE_ATTITUDE_HZ` over the attitude's span.

    Parameters
    ----------
    draw : SceneDraw
    lab : PushbroomModel
        :func:`lab_model` of the draw.

    Returns
    -------
    PushbroomModel
    """
    lo, hi = lab.attitude.span
    t = np.linspace(lo, hi, int((hi - lo) * TRUE_ATTITUDE_HZ) + 1)
    angles = jitter_angles(draw, t)
    quat = (lab.attitude.rotation(t) * Rotation.from_euler("ZYX", angles[:, ::-1])).as_quat()
    return PushbroomModel(orbit=lab.orbit, attitude=Attitude(t, quat, frame=lab.attitude.frame),
                          line_timing=lab.line_timing, bands=dict(lab.bands),
                          installation=Installation(*draw.installation_rad), n_rows=lab.n_rows,
                          reference_band=lab.reference_band)


def gcp_rows(draw: SceneDraw) -> np.ndarray:
    """Image rows (N,) of the draw's GCPs, before noise (uniform over the lines)."""
    return np.random.default_rng([draw.seed, 1]).uniform(0.5, draw.n_rows - 0.5, draw.n_gcps)


def max_gap_s(draw: SceneDraw) -> float:
    """Longest time between consecutive GCP lines (and from the scene's ends), seconds."""
    rows = np.sort(gcp_rows(draw))
    gaps = np.diff(np.concatenate([[0.0], rows, [draw.n_rows]]))
    return float(gaps.max() * draw.duration_s / draw.n_rows)


def synthetic_gcps(draw: SceneDraw, truth: PushbroomModel, *, noise=True):
    """The draw's GCPs: random reference-band pixels at random heights, through the TRUE model.

    Parameters
    ----------
    draw : SceneDraw
    truth : PushbroomModel
    noise : bool
        Add the draw's Gaussian noise (``noise_px`` per axis) to the image coordinates.

    Returns
    -------
    dict
        ``row``, ``col`` (observed, px), ``lon``, ``lat`` (degrees), ``h`` (m), ``band`` (str),
        each (N,) but ``band``; ``sigma_px`` (float).
    """
    rng = np.random.default_rng([draw.seed, 1])
    n = draw.n_gcps
    band = truth.reference_band
    rows = gcp_rows(draw)
    rng.uniform(size=n)  # the rows' draws
    cols = rng.uniform(0.5, truth.n_cols - 0.5, n)
    lon, lat, h = truth.image_to_ground(rows, cols, height=rng.uniform(0.0, 1500.0, n), band=band)
    err = rng.normal(0.0, draw.noise_px, (2, n)) if noise else np.zeros((2, n))
    return {"row": rows + err[0], "col": cols + err[1], "lon": np.asarray(lon), "lat": np.asarray(lat),
            "h": np.asarray(h), "band": band, "sigma_px": draw.noise_px}


def synthetic_ties(draw: SceneDraw, truth: PushbroomModel, band: str, *, row_step: float = 8.0,
                   col_step: float = 128.0, noise_px: float = 0.02, height_m: float = 300.0):
    """Band-to-band tie points of ``band``: the TRUE transfer map of a reference-band grid.

    Parameters
    ----------
    draw : SceneDraw
    truth : PushbroomModel
    band : str
    row_step, col_step : float
        Grid of window centres in the reference band, px.
    noise_px : float
        Gaussian noise of the measured band position, px per axis.
    height_m : float
        Height of the ground (flat), m.

    Returns
    -------
    dict
        ``row_ref``, ``col_ref``, ``ccd_ref``, ``row``, ``col``, ``ccd`` (N,) each.
    """
    rng = np.random.default_rng([draw.seed, 2, list(truth.bands).index(band)])
    ref = truth.reference_band
    rows, cols = (a.ravel() for a in np.meshgrid(np.arange(16.0, truth.n_rows - 16, row_step),
                                                 np.arange(8.0, truth.n_cols - 8, col_step), indexing="ij"))
    ccd_ref = np.asarray(truth.ccd_index(cols, band=ref)).reshape(-1)
    lon, lat, h = truth.image_to_ground(rows, cols, height=height_m, band=ref, array=ccd_ref)
    qr, qc = truth.ground_to_image(lon, lat, h, band=band)
    qr = np.asarray(qr) + rng.normal(0.0, noise_px, rows.size)
    qc = np.asarray(qc) + rng.normal(0.0, noise_px, rows.size)
    ccd = np.asarray(truth.ccd_index(qc, band=band)).reshape(-1)
    return {"row_ref": rows, "col_ref": cols, "ccd_ref": ccd_ref, "row": qr, "col": qc, "ccd": ccd}


def truth_error(truth: PushbroomModel, model: PushbroomModel, *, bands=None, row_step: float = 4.0,
                n_cols: int = 16, height_m: float = 500.0) -> float:
    """RMS image distance (px) between ``model`` and ``truth`` over every ``row_step`` lines.

    Parameters
    ----------
    truth, model : PushbroomModel
    bands : sequence of str, optional
        Default: every band of ``truth``.
    row_step : float
        Line step of the evaluation grid.
    n_cols : int
        Columns per line, evenly spread.
    height_m : float
        Ground height, m.

    Returns
    -------
    float
    """
    err = []
    for band in bands or truth.bands:
        rows, cols = (a.ravel() for a in np.meshgrid(np.arange(0.5, truth.n_rows, row_step),
                                                     np.linspace(1.0, truth.n_cols - 1.0, n_cols)))
        lon, lat, h = truth.image_to_ground(rows, cols, height=height_m, band=band)
        r, c = model.ground_to_image(lon, lat, h, band=band)
        err.append((np.asarray(r) - rows) ** 2 + (np.asarray(c) - cols) ** 2)
    return float(np.sqrt(np.nanmean(np.concatenate(err))))


def without_time_variation(draw: SceneDraw) -> SceneDraw:
    """The same draw without jitter and drift (the twin whose static fit gives the noise floor)."""
    return replace(draw, jitter=(), drift_urad_s=np.zeros(3))
