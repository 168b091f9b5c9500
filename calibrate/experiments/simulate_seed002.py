"""Seed 002 experiment: the four compensation schemes (table 3) and the thermal series (figure 11).

Compensation (:func:`calibrate.schemes.compensation_study.run_seed002`): GF-4-like 10240 x 10240
staring camera, seed 002 table 1 lens and table 2 installation errors, VCPs every 100 px (the
paper's grid; ``quick``: every 500 px). Under ``ideal`` the TRUE interior is the cubic fitted to
the lens (the default path); otherwise it is the physical lens itself (:mod:`sensor_models.simulate.staring_truth`)
with the profile's ``k2``, ``k3`` and VCP noise.

Table 3 (source "seed 002 table 3"): the four schemes ICO, ECO, ECBIC, ICBEC with the paper's X /
Y / total beside ours. Under ``interior_source = lab`` (``paper-002``) they follow seed 002's own
data flow (:mod:`calibrate.schemes.paper_flow`: the interior from the lab's camera-frame grid with
the profile's lab noise, the exterior from VCPs that carry the profile's attitude noise, one pass
each); otherwise they are the schemes on the VCPs alone (:mod:`calibrate.schemes.compensate`,
whose free cubic absorbs the installation: ICO = ECBIC = ICBEC, the degenerate ranking).

Thermal (:mod:`calibrate.schemes.thermal`): the installation drifts with the time of day; under
``realistic`` the TRUE installation also walks from day to day
(:func:`sensor_models.simulate.thermal_truth.day_to_day_offsets`), which no daily harmonic model
can predict. Held-out positioning RMS of a constant installation and of the predicted one.

Sensitivity: accuracy against the VCP noise (the GCP-noise analogue) and against the day-to-day
thermal variability; under ``interior_source = lab`` also the four schemes and whether the
paper's ranking holds against the lab noise and against the attitude noise. Jitter, DEM and DOM errors do not apply: VCPs are computed from a model,
not matched on a reference, and a staring frame is one instant.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from calibrate.experiments.results import ExperimentResult, PaperTable, SensitivityCurve
from calibrate.schemes.paper_flow import PAPER_RANKING, ranking
from sensor_models.simulate.profiles import get_profile, profile_table

__all__ = ["run", "staring_models", "thermal_series_errors"]

#: numerical floor of the per-epoch control-point sigma when a profile has no VCP noise (weights)
SIGMA_FLOOR_PX = 0.01


def staring_models(profile, image_shape=(10240, 10240)):
    """``(true_lab, truth, lab)`` of seed 002 under a staring profile; None for ``ideal`` (the default path).

    Parameters
    ----------
    profile : StaringProfile
    image_shape : (int, int)

    Returns
    -------
    tuple or None
    """
    if not profile.value("physical_truth"):
        return None
    from calibrate.schemes.compensation_study import ARCSEC, SEED002_INSTALLATION_ARCSEC, seed002_true_lab
    from sensor_models.models.synthetic import GF4_LIKE_CAMERA, example_geo_staring_model
    from sensor_models.models.pushbroom_types import Installation
    from sensor_models.simulate.staring_truth import physical_truth, radial_from_corner_px

    base = seed002_true_lab(GF4_LIKE_CAMERA, image_shape)
    lens = replace(base, radial_k=(base.radial_k[0], radial_from_corner_px(profile.value("radial_k2_corner_px"), 4,
                                                                             image_shape)))
    inst = Installation(*(a * ARCSEC for a in SEED002_INSTALLATION_ARCSEC))
    fitted = example_geo_staring_model(camera=lens, image_shape=image_shape, installation=inst, name="truth")
    truth = physical_truth(fitted, lens, radial_k3=radial_from_corner_px(profile.value("radial_k3_corner_px"), 6,
                                                                          image_shape))
    lab = example_geo_staring_model(camera=GF4_LIKE_CAMERA, image_shape=image_shape, name="lab")
    return lens, truth, lab


def _study(profile, step_px, noise_px=None, schemes=None):
    from calibrate.schemes.compensation_study import run_seed002

    noise = profile.value("vcp_noise_px") if noise_px is None else noise_px
    return run_seed002(step_px=step_px, noise_px=float(noise), schemes=schemes, models=staring_models(profile))


def thermal_series_errors(profile, *, days: float, interval_min: float, day_to_day_arcsec=None, seed: int = 0) -> dict:
    """Held-out positioning RMS (px) of the thermal compensation under a thermal profile.

    Parameters
    ----------
    profile : ThermalProfile
    days, interval_min : float
        Series length (the last day held out) and epoch spacing.
    day_to_day_arcsec : float, optional
        Overrides the profile's day-to-day variation (sensitivity).
    seed : int

    Returns
    -------
    dict
        ``constant_rms_px``, ``predicted_rms_px``, ``epoch_fit_rms_px``, ``orders``.
    """
    from calibrate.schemes.thermal import DAY_S, evaluate_positioning
    from calibrate.schemes.thermal_model import ThermalModel
    from calibrate.schemes.thermal_simulation import ThermalDrift, simulate_thermal_series
    from sensor_models.models.synthetic import example_geo_staring_model
    from sensor_models.simulate.thermal_truth import day_to_day_offsets

    lab = example_geo_staring_model()
    drift = ThermalDrift(noise_arcsec=float(profile.value("epoch_noise_arcsec")))
    times = np.arange(0.0, days * DAY_S, interval_min * 60.0)
    dd = profile.value("day_to_day_arcsec") if day_to_day_arcsec is None else day_to_day_arcsec
    offsets = day_to_day_offsets(times, float(dd), seed=seed)
    sigma = max(float(profile.value("vcp_noise_px")), SIGMA_FLOOR_PX)
    series = simulate_thermal_series(lab, times, drift, n_points=400, sigma_px=sigma, seed=seed,
                                     truth_offsets_rad=offsets)
    train = times < (days - 1.0) * DAY_S
    model = ThermalModel.fit(times[train], series.angles[train], series.sigma[train], None, max_order=4)
    predicted = model.predict(times, None)
    errors = evaluate_positioning(lab, series.true_angles[~train], {
        "constant": series.angles[train].mean(axis=0), "predicted": predicted[~train],
        "epoch_fit": series.angles[~train]})
    return {**{f"{k}_rms_px": errors[f"{k}_rms_px"] for k in ("constant", "predicted", "epoch_fit")},
            "orders": model.to_dict().get("orders")}


def _flow_errors(staring, study, step_px, *, lab_noise_px=None, attitude_arcsec=None) -> dict:
    """Scheme -> positioning errors of seed 002's four schemes (``before`` first) under ``staring``."""
    from calibrate.schemes.compensation_study import ARCSEC
    from calibrate.schemes.paper_flow import attitude_noise, lab_pointing_interior, run_paper_flow

    if staring.value("interior_source") != "lab":
        by = {r["scheme"]: r for r in study.rows}
        return {k: by[k] for k in ("before", *PAPER_RANKING[::-1])}
    lab_noise = staring.value("lab_noise_px") if lab_noise_px is None else lab_noise_px
    att = staring.value("attitude_noise_arcsec") if attitude_arcsec is None else attitude_arcsec
    truth, stop = study.truth, study.settings["stop_px"]
    interior = lab_pointing_interior(truth, step_px=step_px, stop_px=stop, noise_px=float(lab_noise), seed=1)
    vcp = attitude_noise(study.vcp, float(att) * ARCSEC, truth.ifov_rad, truth.image_shape, seed=2)
    runs = run_paper_flow(study.lab, vcp, study.check, interior)
    return {k: v["errors"] for k, v in runs.items()}


def _paper_table3(errors, flow) -> PaperTable:
    from calibrate.schemes.compensation_study import SEED002_TABLE3

    rows = []
    for name, e in errors.items():
        px, py, pt = SEED002_TABLE3[name]
        rows.append([name, px, py, pt, e["rms_x_px"], e["rms_y_px"], e["total_px"], e["mean_x_px"], e["mean_y_px"]])
    return PaperTable(f"The four compensation schemes ({flow}): positioning error on the check grid (X = column, "
                      "Y = row)", "seed 002 table 3",
                      ("scheme", "paper X", "paper Y", "paper total", "ours X RMS", "ours Y RMS", "ours total RMS",
                       "ours mean X", "ours mean Y"), rows)


def _ranking_curves(staring, study, step_px, quick) -> list:
    """The four schemes and the paper's ranking against the lab noise and the attitude noise."""
    out = []
    grids = {"lab_noise_px": [0.0, 0.43, 50.0, 200.0] if quick else [0.0, 0.43, 2.0, 10.0, 50.0, 100.0, 200.0],
             "attitude_arcsec": [0.0, 1.0, 10.0] if quick else [0.0, 1.0, 3.0, 10.0, 30.0]}
    labels = {"lab_noise_px": ("lab_noise_ranking", "lab noise on the camera-frame pointing angles (px, 1 sigma)"),
              "attitude_arcsec": ("attitude_noise_ranking", "attitude error per VCP (arcsec, 1 sigma per axis)")}
    for key, xs in grids.items():
        shown = PAPER_RANKING[:3]
        series = {f"{k} total RMS px": [] for k in shown}
        series["paper ranking held (1 yes, 0 no)"] = []
        ico = []
        for x in xs:
            errors = _flow_errors(staring, study, step_px, **{key: x})
            totals = {k: errors[k]["total_px"] for k in PAPER_RANKING}
            for k in shown:
                series[f"{k} total RMS px"].append(totals[k])
            ico.append(totals["ICO"])
            series["paper ranking held (1 yes, 0 no)"].append(1.0 if ranking(totals) == PAPER_RANKING else 0.0)
        name, x_label = labels[key]
        out.append(SensitivityCurve(name, x_label, "check-grid error (px)", xs, series,
                                    f"seed 002's flow (lab interior, exterior from VCPs, one pass); the other "
                                    f"magnitudes at profile {staring.name}'s; VCP grid every {step_px:g} px; ICO "
                                    f"(not drawn) {min(ico):.0f} to {max(ico):.0f} px: the installation error"))
    return out


def _table3(study) -> PaperTable:
    rows = []
    for r in study.rows:
        rows.append([r["scheme"], r["seed_x_px"], r["seed_y_px"], r["seed_total_px"], r["mean_x_px"], r["mean_y_px"],
                     r["total_px"], r["max_px"]])
    return PaperTable("Every scheme on the VCPs alone (free cubic), positioning error on the check grid",
                      "seed 002 table 3 beside the schemes on VCPs alone (mean X, mean Y, total, pixels)",
                      ("scheme", "paper X", "paper Y", "paper total", "ours mean X", "ours mean Y", "ours RMS total",
                       "ours max"), rows)


def _curves(staring, thermal, step_px, days, interval_min, quick) -> list:
    noises = [0.0, 0.3, 1.0] if quick else [0.0, 0.1, 0.3, 0.5, 1.0]
    series = {"ICBEC RMS px": [], "ICBEC max px": [], "ECO RMS px": []}
    for n in noises:
        st = _study(staring, step_px, noise_px=n, schemes=["ICBEC", "ECO"])
        by = {r["scheme"]: r for r in st.rows}
        series["ICBEC RMS px"].append(by["ICBEC"]["total_px"])
        series["ICBEC max px"].append(by["ICBEC"]["max_px"])
        series["ECO RMS px"].append(by["ECO"]["total_px"])
    dds = [0.0, 4.0] if quick else [0.0, 2.0, 4.0, 6.0]
    th = {"predicted RMS px": [], "constant RMS px": []}
    for dd in dds:
        e = thermal_series_errors(thermal, days=days, interval_min=interval_min, day_to_day_arcsec=dd)
        th["predicted RMS px"].append(e["predicted_rms_px"])
        th["constant RMS px"].append(e["constant_rms_px"])
    return [SensitivityCurve("vcp_noise", "VCP noise (px, 1 sigma per axis)", "check-grid error (px)", noises, series,
                             f"VCP grid every {step_px:g} px; TRUE lens of profile {staring.name}"),
            SensitivityCurve("thermal_day_to_day", "day-to-day installation variation (arcsec/day)",
                             "held-out positioning RMS (px)", dds, th,
                             f"{days:g} days every {interval_min:g} min, last day held out; profile {thermal.name}")]


def run(profile_name: str, *, quick: bool = False, work_dir=None) -> ExperimentResult:
    """Run the seed 002 experiment (module docstring).

    Parameters
    ----------
    profile_name : str
        ``ideal``, ``realistic`` or ``paper-002``.
    quick : bool
        VCPs every 500 px, 3 days every 60 min, fewer sensitivity points.
    work_dir : Path, optional
        Unused (nothing is written).

    Returns
    -------
    ExperimentResult
    """
    t0 = time.perf_counter()
    staring, thermal = get_profile(profile_name, "staring"), get_profile(profile_name, "thermal")
    step_px, days, interval_min = (500.0, 3.0, 60.0) if quick else (100.0, 5.0, 30.0)
    study = _study(staring, step_px)
    flow = staring.value("interior_source")
    errors = _flow_errors(staring, study, step_px)
    totals = {k: errors[k]["total_px"] for k in PAPER_RANKING}
    order = ranking(totals)
    therm = thermal_series_errors(thermal, days=days, interval_min=interval_min)
    by = {r["scheme"]: r for r in study.rows}
    thermal_table = PaperTable("Thermal installation drift: held-out positioning RMS (px)",
                               "seed 002 figure 11 (curves only, no table: the paper column is empty)",
                               ("case", "paper", "ours"),
                               [["constant installation", None, therm["constant_rms_px"]],
                                ["predicted (daily harmonics)", None, therm["predicted_rms_px"]],
                                ["per-epoch fit", None, therm["epoch_fit_rms_px"]]])
    result = ExperimentResult(
        "002", profile_name, quick, "Seed 002: VCP compensation schemes of a staring camera and its thermal drift",
        scale={"image_shape": [10240, 10240], "vcp_step_px": step_px, "n_vcp": study.settings["n_vcp"],
               "paper_vcp_step_px": 100.0, "thermal_days": days, "thermal_interval_min": interval_min},
        tables=[_paper_table3(errors, "seed 002's flow: lab interior, exterior from VCPs" if flow == "lab"
                              else "on the VCPs alone"), _table3(study), thermal_table],
        curves=_curves(staring, thermal, step_px, days, interval_min, quick)
        + (_ranking_curves(staring, study, step_px, quick) if flow == "lab" else []),
        headline={"ranking": list(order), "paper_ranking_reproduced": order == PAPER_RANKING,
                  **{f"table3_{k.lower()}_total_px": totals[k] for k in PAPER_RANKING},"icbec_rms_px": by["ICBEC"]["total_px"], "icbec_max_px": by["ICBEC"]["max_px"],
                  "eco_rms_px": by["ECO"]["total_px"], "before_rms_px": by["before"]["total_px"],
                  "truth_beyond_cubic_px": (study.truth.lab_fit_residual or {}).get("physical_fit_residual_px", 0.0),
                  "thermal_constant_rms_px": therm["constant_rms_px"],
                  "thermal_predicted_rms_px": therm["predicted_rms_px"]},
        profile_rows=[(p.name, *row) for p in (staring, thermal) for row in profile_table(p)],
        notes=NOTES + (LAB_FLOW_NOTES if flow == "lab" else VCP_FLOW_NOTES))
    result.seconds = time.perf_counter() - t0
    return result


NOTES = [
    "Before compensation ours is ~354 px against the paper's 43.3 px: the paper does not give its camera; the "
    "72 arcsec installation errors of table 2 are ~250 px of the GF-4-like 0.288 arcsec pixels.",
    "The paper's 'total' is computed from mean signed errors; ours lists RMS X / Y / total over the check grid "
    "(what a user meets) and the mean signed X / Y (comparable with the paper's).",
    "Schemes on the VCPs alone (the all-schemes table): our free cubic absorbs the installation, ICO ~0 px; the "
    "ICO-g row (frame held) is the nearest reading of the paper's ICO without a lab grid. With the physical lens "
    "rendered exactly the cubic leaves only the beyond-cubic part (tilt projection, k2, k3) plus the VCP noise, a "
    "few hundredths of a pixel.",
    "Thermal: the paper shows curves (figure 11), no table. Day-to-day variation (realistic, 4 arcsec/day) is not "
    "predictable from the time of day and dominates the predicted error.",
]

VCP_FLOW_NOTES = [
    "Table 3 (schemes on the VCPs alone): the free 20-coefficient cubic holds the boresight offset and rotation, so "
    "ICO, ECBIC and ICBEC fit the same model space to the same data and land on the same positions whatever the "
    "noise: the paper's ranking cannot appear; ECO keeps the distortion shape.",
]

LAB_FLOW_NOTES = [
    "Table 3 (seed 002's flow): the interior comes from the lab's camera-frame grid, which cannot see the "
    "installation, and the exterior from the VCPs, one pass each. ICO leaves the installation error (a little worse "
    "than before, as the paper's 47.5 px against 43.3 px: the distortion had offset part of it); ECO leaves the "
    "distortion shape; ECBIC's exterior absorbs the distortion's mean shift and rotation, which the lab interior "
    "then removes a second time; ICBEC ends with the exterior, which takes what is left: the paper's order.",
    "The ranking is decided by that data flow, not by a noise magnitude: the lab_noise_ranking and "
    "attitude_noise_ranking curves keep it up to lab noise or attitude errors far above the profile's, and the "
    "schemes on VCPs alone (previous table) never show it.",
    "Our ICBEC stays far below the paper's 1.065 px: the profile's lab noise (0.43 px) and attitude errors (1 arcsec "
    "per VCP) average out over the grid; the paper scores a target track whose own attitude and orbit errors we do "
    "not add to the check grid.",
]
