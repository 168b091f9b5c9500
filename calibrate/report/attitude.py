"""Attitude section of the calibration report: the time-varying correction and its spectrum.

:func:`figure_attitude` draws, per axis (roll, pitch, yaw), the correction ``delta(t)`` the
calibration estimated (:mod:`calibrate.attitude`) against the time of the image lines with a
one-sigma band from the coefficients' covariance, and its amplitude spectrum (linear trend
removed) with the fitted dominant sinusoid. :func:`section_attitude` writes the basis chosen,
the BIC of each candidate and the recovered jitter (amplitude, frequency) per axis.
"""

from __future__ import annotations

import numpy as np

from calibrate.attitude import correction_band, jitter_spectrum
from calibrate.parallax import GCP_REJECT_SIGMAS
from calibrate.report._html import count_note, escape as _e, figure_html as _figure_html, fmt as _fmt
from calibrate.report._html import new_figure as _new_figure, save_figure as _save, table as _table
from sensor_models.models.attitude_correction import AXES

__all__ = ["OBSERVED_SNR", "attitude_observability", "figure_attitude", "figure_parallax", "section_attitude",
           "section_parallax"]

#: A correction axis counts as observed when its rms over the image is at least this many times
#: its mean a-posteriori standard deviation (a 3-sigma detection); below 1 it is within its own noise.
OBSERVED_SNR = 3.0

_COLORS = {"roll": "#c0392b", "pitch": "#1f5fa8", "yaw": "#2e7d32"}


def _image_seconds(model):
    """Time span of the image lines, seconds since the epoch (ascending)."""
    t = model.line_timing.seconds(np.array([0.0, float(model.n_rows)]))
    return float(t.min()), float(t.max())


def figure_attitude(result, fig_dir) -> dict | None:
    """Correction against time with its uncertainty band, and its spectrum, per axis.

    Parameters
    ----------
    result : calibrate.calibration_result.CalibrationResult
        A result whose model carries an attitude correction.
    fig_dir : Path
        Folder of the PNG.

    Returns
    -------
    dict or None
        ``{"src", "caption"}``; None when the model has no correction.
    """
    corr = getattr(result.model, "attitude_correction", None)
    if corr is None:
        return None
    t_lo, t_hi = _image_seconds(result.model)
    t = np.linspace(t_lo, t_hi, 600)
    cov = (result.attitude or {}).get("coefficients_covariance_rad2")
    angles, sigma = correction_band(corr, None if cov is None else np.asarray(cov, dtype=float), t)
    spectrum = jitter_spectrum(corr, t_lo, t_hi)
    fig = _new_figure(12.0, 4.2, wspace=0.3, top=0.5)
    ax_t, ax_f = fig.subplots(1, 2)
    for a, name in enumerate(AXES):
        color = _COLORS[name]
        ax_t.plot(t - t_lo, angles[:, a], color=color, lw=1.2, label=name)
        if np.all(np.isfinite(sigma[:, a])):
            ax_t.fill_between(t - t_lo, angles[:, a] - sigma[:, a], angles[:, a] + sigma[:, a], color=color, alpha=0.2)
        ax_f.plot(spectrum["frequency_hz"], spectrum["axes"][name]["spectrum_urad"], color=color, lw=1.0, label=name)
        peak = spectrum["axes"][name]["peak"]
        if peak is not None:
            ax_f.plot([peak["frequency_hz"]], [peak["amplitude_urad"]], "o", color=color, ms=4)
    ax_t.set_xlabel("time since the first line (s)")
    ax_t.set_ylabel("correction (µrad)")
    ax_t.set_title(f"attitude correction: {corr.kind}, {corr.n_terms} {'segments' if corr.kind == 'spline' else 'degree'}",
                   loc="left", fontsize=10)
    ax_f.set_xlabel("frequency (Hz)")
    ax_f.set_ylabel("amplitude (µrad)")
    ax_f.set_xlim(0.0, min(float(spectrum["frequency_hz"][-1]), 4.0 / max(corr.knot_spacing_s, 1e-9)))
    ax_f.set_title("amplitude spectrum (trend removed); dots: fitted sinusoid", loc="left", fontsize=10)
    for ax in (ax_t, ax_f):
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(fontsize=8, loc="upper right")
    caption = ("Left: the body-frame attitude correction (roll, pitch, yaw; µrad) estimated with the exterior "
               "against time over the image lines, its mean taken by the installation; shaded: one standard "
               "deviation from the coefficients' covariance (a posteriori). Right: its amplitude spectrum after "
               "removing a linear trend (Hann window); dots: amplitude and frequency of the sinusoid fitted to "
               "each axis. Yaw is weakly observed by a narrow field of view.")
    return {"src": _save(fig, fig_dir, "attitude.png"), "caption": caption}


def attitude_observability(result, n_times: int = 600) -> list[dict] | None:
    """Per axis: how large the correction is against what the data can observe of it.

    ``rms_urad`` is the correction's rms about its mean over the image lines (the mean is the
    installation's), ``sigma_urad`` the mean a-posteriori standard deviation of the correction
    (from the coefficients' covariance), ``snr = rms / sigma``. An axis is ``observed`` when
    ``snr >= OBSERVED_SNR``, ``weakly observed`` when ``1 <= snr < OBSERVED_SNR`` and ``not
    observable`` below 1: a correction that large is within its own noise, and the report says so.

    Parameters
    ----------
    result : calibrate.absolute.CalibrationResult
    n_times : int
        Times sampled over the image lines.

    Returns
    -------
    list of dict or None
        ``axis, rms_urad, sigma_urad, snr, verdict``; None without a correction or its covariance.
    """
    corr = getattr(result.model, "attitude_correction", None)
    cov = (result.attitude or {}).get("coefficients_covariance_rad2")
    if corr is None or cov is None:
        return None
    t_lo, t_hi = _image_seconds(result.model)
    angles, sigma = correction_band(corr, np.asarray(cov, dtype=float), np.linspace(t_lo, t_hi, n_times))
    rows = []
    for a, name in enumerate(AXES):
        rms = float(np.sqrt(np.mean((angles[:, a] - angles[:, a].mean()) ** 2)))
        sig = float(np.mean(sigma[:, a]))
        snr = rms / sig if sig > 0 else float("inf")
        verdict = "observed" if snr >= OBSERVED_SNR else "weakly observed" if snr >= 1.0 else "not observable"
        rows.append({"axis": name, "rms_urad": rms, "sigma_urad": sig, "snr": snr, "verdict": verdict})
    return rows


def section_attitude(result, figure) -> str:
    """HTML of the attitude section: selection table, recovered jitter, figure.

    Parameters
    ----------
    result : calibrate.calibration_result.CalibrationResult
        With ``result.attitude`` (None: the section says the attitude was held static).
    figure : dict or None
        Of :func:`figure_attitude`.

    Returns
    -------
    str
        HTML.
    """
    info = result.attitude
    if not info:
        return "<p>Static attitude (<code>--attitude static</code> or a model without a time axis).</p>"
    sel = info["selected"]
    chosen = "static (no correction)" if sel["kind"] == "static" else f"{sel['kind']} ({sel['n_terms']})"
    intro = (f"<p>Mode <code>{_e(info['mode'])}</code>: candidate bases were fitted to the static solution's "
             "residuals; the time-varying one of least GCV is kept when an F-test rejects the static model "
             f"(level 0.001): <b>{_e(chosen)}</b> (docs/attitude.md).</p>")
    sm = info.get("smoothing")
    if sm:
        intro += (f"<p>P-spline of {sm['n_segments']} segments, smoothing λ = {sm['lambda']:.3g} chosen by "
                  f"{_e(sm['criterion'])} ({sm.get('n_folds', 0)} folds): {sm['edf']:.1f} effective parameters.</p>")
    rows = [[_e(c["kind"]), str(c["n_terms"]), _fmt(c["n_parameters"]), _fmt(c["rss"]), _fmt(c.get("gcv"), 6),
             _fmt(c.get("p_value"), 3), "yes" if c["chosen"] else ""] for c in info["candidates"]]
    table = _table(["basis", "terms", "parameters (effective)", "weighted RSS (px²)", "GCV", "F-test p",
                    "chosen"], rows)
    jitter = info.get("jitter") or {}
    if jitter:
        jrows = [[_e(a), _fmt((p or {}).get("amplitude_urad")), _fmt((p or {}).get("frequency_hz"))]
                 for a, p in jitter.items()]
        table += "<p>Dominant sinusoid of the correction per axis:</p>" + _table(
            ["axis", "amplitude (µrad)", "frequency (Hz)"], jrows)
    observability = attitude_observability(result)
    if observability:
        orows = [[_e(o["axis"]), _fmt(o["rms_urad"]), _fmt(o["sigma_urad"]), _fmt(o["snr"], 3),
                  _e(o["verdict"]) if o["verdict"] == "observed" else f'<span class="fail">{_e(o["verdict"])}</span>']
                 for o in observability]
        table += ("<p>What the data observe of the correction (rms about its mean over the image against its mean "
                  f"a-posteriori sigma; observed from {OBSERVED_SNR:g} sigma):</p>"
                  + _table(["axis", "rms (µrad)", "sigma (µrad)", "rms / sigma", "verdict"], orows))
        weak = [o["axis"] for o in observability if o["verdict"] != "observed"]
        if weak:
            table += (f"<p class=\"fail\">The {', '.join(weak)} correction is not clearly above its own uncertainty: "
                      "its shape is what the smoothing and the GCPs' noise allow, not a measured attitude motion; "
                      "read it as an upper bound.</p>")
    if info.get("failed"):
        table += f"<p>The time-varying solve failed, the static solution is kept: {_e(info['failed'])}</p>"
    return intro + table + (_figure_html(figure) if figure else "")


def _parallax_record(relative):
    """The used parallax record of a RelativeResult, or None."""
    record = getattr(relative, "parallax", None) or {}
    return record if record.get("used") and record.get("result") is not None else None


def figure_parallax(relative, fig_dir) -> dict | None:
    """Joint (GCPs + band parallax) against GCP-only correction: time series and spectrum per axis.

    Parameters
    ----------
    relative : calibrate.relative.RelativeResult
        Of ``relative_calibration(..., parallax=True)``.
    fig_dir : Path
        Folder of the PNG.

    Returns
    -------
    dict or None
        ``{"src", "caption"}``; None when the parallax path was not used.
    """
    record = _parallax_record(relative)
    if record is None:
        return None
    joint = record["result"]
    model = relative.model
    t_lo, t_hi = _image_seconds(model)
    t = np.linspace(t_lo, t_hi, 1200)
    series = {"joint": joint.correction, "GCP only": joint.gcp_only}
    styles = {"joint": dict(lw=1.2), "GCP only": dict(lw=1.0, ls="--", alpha=0.8)}
    fig = _new_figure(13.0, 6.4, wspace=0.45, hspace=0.7, top=0.45)
    axes = fig.subplots(2, 3)
    f_max = 0.0
    for label, corr in series.items():
        if corr is None:
            continue
        angles = corr.angles(t) * 1e6
        spectrum = jitter_spectrum(corr, t_lo, t_hi)
        f_max = max(f_max, 1.0 / max(corr.knot_spacing_s, 1e-9))  # a spline of knots h resolves f <= 1/(4 h)
        for a, name in enumerate(AXES):
            axes[0, a].plot(t - t_lo, angles[:, a], color=_COLORS[name], label=label, **styles[label])
            axes[1, a].plot(spectrum["frequency_hz"], spectrum["axes"][name]["spectrum_urad"], color=_COLORS[name],
                            label=label, **styles[label])
    for a, name in enumerate(AXES):
        axes[0, a].set_title(f"{name}: correction (µrad)", loc="left", fontsize=10)
        axes[0, a].set_xlabel("time since the first line (s)")
        axes[1, a].set_title(f"{name}: amplitude spectrum (µrad)", loc="left", fontsize=10)
        axes[1, a].set_xlabel("frequency (Hz)")
        axes[1, a].set_xlim(0.0, min(f_max, 0.5 * (len(t) - 1) / (t_hi - t_lo)) or 1.0)
        for ax in axes[:, a]:
            ax.grid(True, lw=0.3, alpha=0.5)
            ax.legend(fontsize=8, loc="upper right")
    caption = ("Attitude correction estimated from the reference band's GCPs and the band-to-band tie points "
               f"together ({joint.n_gcps} GCPs, {joint.n_ties} ties; solid) against the GCP-only estimate the "
               "calibrated model carried (dashed): top, against time over the image lines; bottom, amplitude "
               "spectrum after removing a linear trend (Hann window). The ties measure the attitude's change over "
               "the bands' along-track time offsets, so they resolve faster jitter than the GCP rows.")
    return {"src": _save(fig, fig_dir, "attitude_parallax.png"), "caption": caption}


def section_parallax(relative, figure, n_gcps=None) -> str:
    """HTML of the band-parallax attitude section: observations, bases, recovered jitter, figure.

    Parameters
    ----------
    relative : calibrate.relative.RelativeResult
    figure : dict or None
        Of :func:`figure_parallax`.
    n_gcps : int, optional
        GCPs of the report; when the joint solve weighted fewer, a phrase says why (as for the
        tie points, against those of the band-to-band section).

    Returns
    -------
    str
        HTML.
    """
    record = getattr(relative, "parallax", None) or {}
    if not record.get("used"):
        return f"<p>Band parallax not used: {_e(str(record.get('reason') or record.get('message') or 'off'))}.</p>"
    joint = record["result"]
    t_lo, t_hi = _image_seconds(relative.model)

    def describe(c):
        return "static" if c is None else f"{c.kind} ({c.n_terms})"

    intro = (f"<p>{joint.n_gcps} GCPs of the reference band and {joint.n_ties} band-to-band tie points entered one "
             f"weighted least squares for the attitude correction ({joint.rounds} round(s) alternated with the "
             f"interiors): <b>{_e(describe(joint.correction))}</b>, against <b>{_e(describe(joint.gcp_only))}</b> "
             "from the GCPs alone (docs/attitude.md).</p>")
    n_ties = sum(len(b.ties) for b in relative.bands.values())
    intro += (count_note(joint.n_gcps, n_gcps, "GCPs",
                         "the joint solve weights only the reference band's GCPs that the model projects, "
                         f"within {GCP_REJECT_SIGMAS:g} robust standard deviations of their median residual")
              + count_note(joint.n_ties, n_ties, "tie points of the band-to-band section",
                           "the joint solve weights only those whose centre still reaches the DEM and "
                           "transfers to their band through the model"))
    rows = []
    for label, corr in (("joint", joint.correction), ("GCP only", joint.gcp_only)):
        peaks = jitter_spectrum(corr, t_lo, t_hi)["axes"] if corr is not None else {}
        for name in AXES:
            p = (peaks.get(name) or {}).get("peak") or {}
            rows.append([_e(label), _e(name), _fmt(p.get("amplitude_urad")), _fmt(p.get("frequency_hz"))])
    table = _table(["estimate", "axis", "amplitude (µrad)", "frequency (Hz)"], rows)
    cands = [[_e(c["kind"]), str(c["n_terms"]), _fmt(c["n_parameters"]), _fmt(c.get("gcv"), 6),
              _fmt(c.get("p_value"), 3), "yes" if c["chosen"] else ""] for c in joint.candidates]
    return (intro + "<p>Dominant sinusoid per axis:</p>" + table + "<p>Joint candidates:</p>"
            + _table(["basis", "terms", "parameters (effective)", "GCV", "F-test p", "chosen"], cands)
            + (_figure_html(figure) if figure else ""))
