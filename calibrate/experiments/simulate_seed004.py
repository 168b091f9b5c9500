"""Seed 004 experiment: precision of the autocollimation (OALR) measurement, Monte Carlo.

Each trial draws true camera changes (focal length, rotations about X, Y, Z), turns them into
mark displacements on the two SMCCDs (:func:`calibrate.schemes.autocollimation.displacements_from_changes`,
the exact inverse of seed 004 eq. 2-5), renders each channel's cross mark before and after
(:func:`render_cross`: pixel-integrated bars, Gaussian PSF, shot and read noise) with the
profile's signal, background, PSF and PRNU, moves the SMCCD itself by the profile's unmodelled
mount drift, locates the marks (:func:`locate_cross`) and recovers the changes by eq. 2-5. The
standard deviation of recovered minus true is set beside seed 004 table 3. ``paper-004`` skips
the rendering and adds the paper's flight centroid noise ``sigma_k`` = 0.144 px to every
displacement (table 3's own assumption), which checks our propagation against the table.

Table 4 (in-orbit measurement sensitivity, 3 sigma): the single-reading noise of our detector is
measured on marks rendered with the profile's signal, background, PSF and PRNU
(:func:`calibrate.schemes.oalr_sensitivity.reading_noise`), averaged over the paper's readings and
propagated by table 2 (:func:`~calibrate.schemes.oalr_sensitivity.sensitivity_table4`); a
Monte Carlo of rendered, averaged readings through eq. 2-5 stands beside it
(:func:`~calibrate.schemes.oalr_sensitivity.monte_carlo_table4`).

Sensitivity: precision against the mark signal (centroid noise: the GCP-noise analogue) and
against the mount drift. Jitter, DEM and DOM errors do not apply (a lab-frame measurement).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from calibrate.experiments.results import ExperimentResult, PaperTable, SensitivityCurve
from sensor_models.simulate.profiles import Sourced, get_profile, profile_table

__all__ = ["monte_carlo", "run"]

#: SMCCD frame (pixels) and the true-change spread of the trials (seed 004 section 4 orders)
FRAME = (41, 41)
CHANGE_SPREAD = {"delta_f_mm": 0.2, "rot_x_arcsec": 2.0, "rot_y_arcsec": 2.0, "rot_z_arcsec": 20.0}
#: true-change spread of the table 4 Monte Carlo: changes of the order of table 4 itself (the smallest
#: changes the measurement resolves; the marks move by ~0.01 px)
SENSITIVITY_SPREAD = {"delta_f_mm": 0.003, "rot_x_arcsec": 0.005, "rot_y_arcsec": 0.005, "rot_z_arcsec": 0.2}


def _locate_pair(profile, centre, shift, rng, gain):
    """Measured displacement (drow, dcol) of one channel's mark between two rendered frames."""
    from calibrate.schemes.autocollimation import locate_cross, render_cross

    kw = dict(psf_sigma_px=float(profile.value("psf_sigma_px")), amplitude_e=float(profile.value("amplitude_e")),
              background_e=float(profile.value("background_e")), read_noise_e=float(profile.value("read_noise_e")))
    drift = rng.normal(0.0, float(profile.value("mount_drift_px")), 2) if profile.value("mount_drift_px") else 0.0
    pos = []
    for at in (centre, centre + shift + drift):
        img = render_cross(FRAME, at, rng=rng, **kw)
        if gain is not None:
            img = kw["background_e"] + (img - kw["background_e"]) * gain
        pos.append(np.array(locate_cross(img)))
    return pos[1] - pos[0]


def monte_carlo(profile, n_trials: int, *, seed: int = 0) -> dict:
    """Recovered-minus-true standard deviations of the four changes (module docstring).

    Parameters
    ----------
    profile : OalrProfile
    n_trials : int
    seed : int

    Returns
    -------
    dict
        ``sigma_f_mm``, ``sigma_rot_x_arcsec``, ``sigma_rot_y_arcsec``, ``sigma_rot_z_arcsec`` and the
        measured ``sigma_k_px`` (rms displacement error per coordinate).
    """
    from calibrate.schemes.autocollimation import (ARCSEC, OalrChanges, OalrGeometry, changes_from_displacements,
                                                   displacements_from_changes)

    rng = np.random.default_rng(seed)
    g = OalrGeometry()
    s = CHANGE_SPREAD
    true = OalrChanges(rng.normal(0, s["delta_f_mm"], n_trials), rng.normal(0, s["rot_x_arcsec"], n_trials) * ARCSEC,
                       rng.normal(0, s["rot_y_arcsec"], n_trials) * ARCSEC,
                       rng.normal(0, s["rot_z_arcsec"], n_trials) * ARCSEC)
    d_true = np.stack(displacements_from_changes(true, g), 1)  # (N, 4): dx1, dy1, dx2, dy2
    sigma_k = float(profile.value("centroid_sigma_px"))
    if sigma_k > 0:
        d_meas = d_true + rng.normal(0.0, sigma_k, d_true.shape)
    else:
        prnu = float(profile.value("prnu_rms"))
        gains = [1.0 + rng.normal(0.0, prnu, FRAME) if prnu else None for _ in range(2)]
        d_meas = np.empty_like(d_true)
        for i in range(n_trials):
            for ch in range(2):
                centre = np.array([20.5, 20.5]) + rng.uniform(-0.5, 0.5, 2)
                shift = np.array([d_true[i, 2 * ch + 1], d_true[i, 2 * ch]])  # (row = y, col = x)
                drow, dcol = _locate_pair(profile, centre, shift, rng, gains[ch])
                d_meas[i, 2 * ch], d_meas[i, 2 * ch + 1] = dcol, drow
    est = changes_from_displacements(*d_meas.T, g)
    err = {"sigma_f_mm": est.delta_f_mm - true.delta_f_mm,
           "sigma_rot_x_arcsec": (est.rot_x_rad - true.rot_x_rad) / ARCSEC,
           "sigma_rot_y_arcsec": (est.rot_y_rad - true.rot_y_rad) / ARCSEC,
           "sigma_rot_z_arcsec": (est.rot_z_rad - true.rot_z_rad) / ARCSEC}
    out = {k: float(np.std(v)) for k, v in err.items()}
    out["sigma_k_px"] = float(np.sqrt(np.mean((d_meas - d_true) ** 2)))
    return out


def _table(mc: dict) -> PaperTable:
    from calibrate.schemes.autocollimation import PAPER_TABLE3, reproduce_table3

    analytic = reproduce_table3()
    rows = []
    keys = ("sigma_k_px", "sigma_f_mm", "sigma_rot_x_arcsec", "sigma_rot_y_arcsec", "sigma_rot_z_arcsec")
    flight = analytic["conditions"]["flight"]
    for k in keys:
        ours = flight["sigma_k_px"] if k == "sigma_k_px" else flight["rows"][k]["ours"]
        rows.append([k, PAPER_TABLE3["lab"][k], PAPER_TABLE3["flight"][k], ours, mc[k]])
    return PaperTable("Measurement precision of the OALR (1 sigma)",
                      "seed 004 table 3 (lab and flight conditions)",
                      ("quantity", "paper lab", "paper flight", "ours eq. 2-5 propagation at flight sigma_k",
                       "ours Monte Carlo"), rows)


def _render_kw(profile) -> dict:
    """The profile's mark rendering (:func:`calibrate.schemes.autocollimation.render_cross` keywords)."""
    return dict(psf_sigma_px=float(profile.value("psf_sigma_px")), amplitude_e=float(profile.value("amplitude_e")),
                background_e=float(profile.value("background_e")), read_noise_e=float(profile.value("read_noise_e")))


def table4(profile, *, quick: bool = False) -> dict:
    """Seed 004 table 4 from our measured mark noise, and its rendered Monte Carlo.

    Parameters
    ----------
    profile : OalrProfile
        Rendering magnitudes (signal, background, read noise, PSF, PRNU); its given
        ``centroid_sigma_px`` and mount drift do not enter (the readings are of one static mark).
    quick : bool
        Fewer noise readings and Monte Carlo trials.

    Returns
    -------
    dict
        ``noise`` (:func:`~calibrate.schemes.oalr_sensitivity.reading_noise`), ``table``
        (:func:`~calibrate.schemes.oalr_sensitivity.sensitivity_table4`) and ``monte_carlo``
        (:func:`~calibrate.schemes.oalr_sensitivity.monte_carlo_table4`).
    """
    from calibrate.schemes.oalr_sensitivity import monte_carlo_table4, reading_noise, sensitivity_table4

    kw = _render_kw(profile)
    prnu = float(profile.value("prnu_rms"))
    rng = np.random.default_rng(7)
    gains = tuple(1.0 + rng.normal(0.0, prnu, FRAME) if prnu else None for _ in range(2))
    noise = reading_noise(kw, frame=FRAME, centres=6 if quick else 12, readings=6 if quick else 12, gain=gains[0])
    mc = monte_carlo_table4(kw, trials=12 if quick else 60, spread=SENSITIVITY_SPREAD, frame=FRAME, gains=gains)
    return {"noise": noise, "table": sensitivity_table4(noise["sigma_px"]), "monte_carlo": mc}


def _table4(t4: dict) -> PaperTable:
    from calibrate.schemes.oalr_sensitivity import TABLE4_ROWS

    tab, mc = t4["table"], t4["monte_carlo"]
    rows = [[k, tab["rows"][k]["paper"], tab["rows"][k]["ours"], mc[k]["value"], mc[k]["low"], mc[k]["high"],
             tab["paper_sigma_k_px"][k]] for k in TABLE4_ROWS]
    rows.append(["sigma_k_px (mark, 3 sigma, mean of readings)", None, tab["sigma_k_px"], None, None, None, None])
    rows.append(["readings averaged", 9, tab["readings"], tab["readings"], None, None, None])
    return PaperTable("In-orbit measurement sensitivity of the OALR (3 sigma)",
                      "seed 004 table 4 (in-orbit measurement sensitivity, 3 sigma)",
                      ("quantity", "paper", "ours", "ours Monte Carlo (rendered readings)", "Monte Carlo 95 % low",
                       "Monte Carlo 95 % high", "mark sigma_k the paper's row implies (px)"), rows)


def _table4_note(t4: dict, profile) -> str:
    """Table 4, ours against the paper's, row by row (the figures of this run)."""
    tab = t4["table"]
    ratios = {k: v["ratio"] for k, v in tab["rows"].items()}
    implied = tab["paper_sigma_k_px"]
    return (
        "Table 4: the paper derives it 'by correcting the random components using the data from multiple readings "
        f"(9)'. Ours: the single-reading mark noise our detector achieves under {profile.name} (measured on rendered "
        f"marks: {t4['noise']['sigma_px']:.4f} px, 1 sigma per coordinate), averaged over {tab['readings']} readings, "
        f"at 3 sigma ({tab['sigma_k_px']:.4f} px at the mark), through table 2. Every row is linear in that figure; "
        f"the paper's rows imply {implied['sigma_f_mm']:.4f} px (focal), {implied['sigma_rot_x_arcsec']:.4f} px (X, Y) "
        f"and {implied['sigma_rot_z_arcsec']:.4f} px (Z). Ours / paper: focal {ratios['sigma_f_mm']:.2f}, "
        f"X {ratios['sigma_rot_x_arcsec']:.2f}, Y {ratios['sigma_rot_y_arcsec']:.2f}, Z {ratios['sigma_rot_z_arcsec']:.2f}: "
        f"a common factor, the mark noise (the paper's rows need ~{tab['readings_for_paper']:.0f} of our readings "
        f"instead of {tab['readings']}), and for X and Y a further ~7.5 % that is the paper's own (as in table 3, "
        "its X/Y rows are smaller than its focal and Z rows imply through table 2). Every row scales with the "
        "assumed SMCCD pitch; the Monte Carlo of rendered, averaged readings through eq. 2-5 brackets ours.")


def run(profile_name: str, *, quick: bool = False, work_dir=None) -> ExperimentResult:
    """Run the seed 004 experiment (module docstring).

    Parameters
    ----------
    profile_name : str
        ``ideal``, ``realistic`` or ``paper-004``.
    quick : bool
        60 trials (full: 400), two points per sensitivity curve.
    work_dir : Path, optional
        Unused.

    Returns
    -------
    ExperimentResult
    """
    t0 = time.perf_counter()
    profile = get_profile(profile_name, "oalr")
    n = 60 if quick else 400
    mc = monte_carlo(profile, n)
    t4 = table4(profile, quick=quick)
    rendered = replace(profile, centroid_sigma_px=Sourced(0.0, "sensitivity: rendered"))
    curves = []
    for field, xs, label in (("amplitude_e", [100.0, 1000.0] if quick else [100.0, 300.0, 1000.0, 3000.0],
                              "mark signal (electrons, peak)"),
                             ("mount_drift_px", [0.0, 0.1] if quick else [0.0, 0.02, 0.05, 0.1, 0.2],
                              "unmodelled SMCCD mount drift (px, 1 sigma)")):
        series = {"sigma_f_mm x 10": [], "sigma_rot_x_arcsec": [], "sigma_rot_z_arcsec / 10": [], "sigma_k_px": []}
        for x in xs:
            r = monte_carlo(replace(rendered, **{field: Sourced(x, "sensitivity")}), n // 2)
            series["sigma_f_mm x 10"].append(10 * r["sigma_f_mm"])
            series["sigma_rot_x_arcsec"].append(r["sigma_rot_x_arcsec"])
            series["sigma_rot_z_arcsec / 10"].append(r["sigma_rot_z_arcsec"] / 10)
            series["sigma_k_px"].append(r["sigma_k_px"])
        curves.append(SensitivityCurve(field, label, "recovered - true (1 sigma)", xs, series,
                                       f"{n // 2} rendered trials per point; other magnitudes: {profile.name}"))
    result = ExperimentResult(
        "004", profile_name, quick, "Seed 004: autocollimation (OALR) measurement of focal length and axis rotations",
        scale={"trials": n, "frame_px": list(FRAME), "change_spread": CHANGE_SPREAD},
        tables=[_table(mc), _table4(t4)], curves=curves,
        headline={**mc, **{f"table4_{k}": v["ours"] for k, v in t4["table"]["rows"].items()},
                  "table4_sigma_reading_px": t4["noise"]["sigma_px"]},
        profile_rows=[(profile.name, *row) for row in profile_table(profile)],
        notes=NOTES + [_table4_note(t4, profile)])
    result.seconds = time.perf_counter() - t0
    return result


NOTES = [
    "Seed 004 does not state the SMCCD pixel pitch; we take the pitch that subtends 1 arcsec at f = 6550 mm, the "
    "value table 3's X and Y rows imply (calibrate/schemes/autocollimation.py); every row scales with it.",
    "Table 3's Z-rotation row does not follow from its own table 2 with any one pitch (see reproduce_table3); "
    "ours follows eq. 2-5.",
    "paper-004 injects the paper's flight sigma_k on every displacement: our Monte Carlo then matches the "
    "propagation of table 2, i.e. it checks the algebra, not the instrument.",
    "Ideal/realistic render the marks: the centroid precision comes from the signal, PSF and noise; the "
    "realistic mount drift is outside eq. 2-5 and adds directly to the displacement error.",
]
