"""calibrate.report.write_report: the HTML report and its figures for a calibrated synthetic scene.

The case: a two-CCD, two-band LAB push-broom model; a TRUE model with installation errors of
tenths of a degree and directional-angle errors of a few pixels on band B2; GCPs and check
points localized with TRUE and observed with 0.3 px noise; an exterior-then-interior
calibration scored on the check points before and after.
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys

import numpy as np
import pytest
from matplotlib import image as mpimg

from calibrate.absolute import calibrate_model
from calibrate.accuracy import check_point_accuracy, error_versus_gcp_count
from calibrate.report import calibration as report_module
from calibrate.report import write_report
from calibrate.report.calibration_figures import image_difference_px, look_difference_px
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model

IFOV = 50.0 / 782_121.0
ARCSEC = 180.0 * 3600.0 / np.pi
FIGURES = {"residual_vectors.png", "distortion_B2.png", "residual_histograms.png", "error_vs_gcp_count.png"}


@pytest.fixture(scope="module")
def lab():
    design = CameraDesign(n_ccds=2, detectors_per_ccd=400, band_names=("B1", "B2"), band_offsets_px=(-2.0, 2.0))
    return example_pushbroom_model(n_rows=1500, design=design)


@pytest.fixture(scope="module")
def truth(lab):
    p = lab.parameters()
    v = p.values.copy()
    pos = {n: i for i, n in enumerate(p.names)}
    for name, deg in (("roll", 0.3), ("pitch", -0.2), ("yaw", 0.5)):
        v[pos[f"installation.{name}"]] += np.radians(deg)
    rng = np.random.default_rng(0)
    for c in lab.band_ccds("B2"):
        for axis in ("tan_psi_x", "tan_psi_y"):
            for k, px in enumerate((3.0, 2.0, 2.0, 1.0)):
                v[pos[f"B2.{c.name}.{axis}.c{k}"]] += rng.uniform(-px, px) * IFOV / c.n_detectors**k
    return lab.with_parameters(v)


@pytest.fixture(scope="module")
def case(lab, truth):
    """Inputs of write_report: GCPs carry CCD names, check points CCD indices."""
    rng = np.random.default_rng(1)
    n_gcps, n_checks = 500, 200
    n = n_gcps + n_checks
    row = rng.uniform(2.0, lab.n_rows - 2.0, n)
    col = rng.uniform(0.5, lab.n_cols - 0.5, n)
    ccd = truth.ccd_index(col, band="B2")
    h = 400.0 + 300.0 * np.sin(row / 700.0) * np.cos(col / 500.0)
    lon, lat, h = truth.image_to_ground(row, col, height=h, band="B2", array=ccd)
    row = row + rng.normal(0.0, 0.3, n)
    col = col + rng.normal(0.0, 0.3, n)
    names = np.array([c.name for c in lab.band_ccds("B2")])[ccd]
    g = {"row": row[:n_gcps], "col": col[:n_gcps], "lon": lon[:n_gcps], "lat": lat[:n_gcps], "h": h[:n_gcps],
         "band": np.full(n_gcps, "B2"), "ccd": names[:n_gcps]}
    c = {"row": row[n_gcps:], "col": col[n_gcps:], "lon": lon[n_gcps:], "lat": lat[n_gcps:], "h": h[n_gcps:],
         "band": "B2", "ccd": ccd[n_gcps:]}
    result = calibrate_model(lab, GcpTable.from_arrays(g["row"], g["col"], g["lon"], g["lat"], g["h"], band=g["band"],
                                                       ccd=g["ccd"]))
    assert result.success, result.message
    kw = {"band": "B2", "ccd": c["ccd"]}
    before = check_point_accuracy(lab, c["row"], c["col"], c["lon"], c["lat"], c["h"], **kw)
    after = check_point_accuracy(result.model, c["row"], c["col"], c["lon"], c["lat"], c["h"], **kw)
    evc = error_versus_gcp_count(lab, g, c, [60, 150, n_gcps], repeats=1, seed=0)
    return {"result": result, "accuracy_before": before, "accuracy_after": after, "initial_model": lab,
            "gcps": g, "checks": c, "error_vs_count": evc, "truth_model": truth}


@pytest.fixture(scope="module")
def written(case, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    path = write_report(out, **case, title="HY-1C-like test <scene> & co",
                        extra={"note": "<script>alert(1)</script>", "gcps": 500, "nested": {"a": [1, 2]}})
    return out, path, path.read_text(encoding="utf-8")


def _leftovers(out_dir):
    return [p for p in os.listdir(out_dir) if p.startswith(".report-")]


def test_the_case_is_realistic(case):
    """Hundreds of pixels before, the 0.3 px noise (planar sqrt(2) x 0.3) after."""
    assert case["accuracy_before"].absolute.rmse_px > 50.0
    assert 0.35 < case["accuracy_after"].absolute.rmse_px < 0.55


def test_html_references_every_figure_and_the_figures_are_images(written):
    out, path, text = written
    assert path == out / "report.html" and path.is_file()
    assert text.startswith("<!DOCTYPE html>")
    on_disk = set(os.listdir(out / "figures"))
    assert on_disk == FIGURES
    referenced = set(re.findall(r'<img src="([^"]+)"', text))
    assert referenced == {f"figures/{name}" for name in on_disk}  # relative paths, none missing
    for name in on_disk:
        png = out / "figures" / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert png.stat().st_size > 10_000
        img = mpimg.imread(png)
        assert img.shape[0] >= 300 and img.shape[1] >= 500
        assert float(np.std(img[..., :3])) > 0.02  # not a blank canvas
    assert _leftovers(out) == []


def test_tables_hold_the_parameters_and_the_numbers(written, case):
    _, _, text = written
    result, before, after = case["result"], case["accuracy_before"], case["accuracy_after"]
    for name in result.names:
        assert f">{name}<" in text
    # the exterior is visible, the interior inside the collapsible block
    details = text.index("<details>")
    assert text.index(">installation.yaw<") < details < text.index(">B2.ccd1.tan_psi_x.c0<")
    assert f"{after.absolute.rmse_px:.4g}" in text
    assert f"{before.absolute.rmse_px:.4g}" in text
    assert f"{after.absolute.rmse_m:.4g}" in text
    roll = result.values[list(result.names).index("installation.roll")]
    assert f"{roll * ARCSEC:.6g}" in text  # angles also in arcseconds
    assert f"{result.sigma[0] * ARCSEC:.4g}" in text
    for key in ("B2.ccd1", "B2.ccd2"):  # per-CCD table (seed 003 table 4)
        assert f">{key}<" in text
        assert f"{before.groups[key].rmse_col_px:.4g}" in text
        assert f"{after.groups[key].rmse_row_px:.4g}" in text
    fit = after.histograms["col"]  # normal-fit table (seed 000 table 4)
    assert f"{fit.std:.4g}" in text and f"{fit.std_ci[1]:.4g}" in text
    assert f"{100 * fit.fraction_within_two_sigma:.2f} %" in text
    for step in result.steps:  # convergence log
        assert f"{step['cost']:.4g}" in text
    for row in case["error_vs_count"]:
        assert f"{row['rmse_px_mean']:.4g}" in text
    for heading in ("Summary", "Parameters", "Accuracy per CCD", "Residual distribution",
                    "Error versus number of GCPs", "Convergence log", "Additional information"):
        assert f">{heading}</h2>" in text


def test_text_is_escaped(written):
    _, _, text = written
    assert "<script>" not in text
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert "<title>HY-1C-like test &lt;scene&gt; &amp; co</title>" in text
    # a nested value is a nested table of its keys and values (no raw JSON dump)
    assert '<td class="l">a</td><td class="l">1, 2</td>' in text and '{"a"' not in text and "&quot;a&quot;" not in text


def test_look_difference_curves_measure_a_known_shift(lab):
    """Panel 1: tan psi difference over the IFOV; panel 2: image-space difference."""
    p = lab.parameters()
    v = p.values.copy()
    look = lab.band_ccds("B2")[1]
    ifov = abs(look.tan_psi_y[1])
    v[list(p.names).index(f"B2.{look.name}.tan_psi_y.c0")] += 1.5 * ifov
    shifted = lab.with_parameters(v)
    curves = look_difference_px(lab, shifted, "B2")
    x, along, across = curves[1]
    assert x[0] == look.first_col and x[-1] == look.first_col + look.n_detectors - 1
    np.testing.assert_allclose(across, 1.5, atol=1e-9)
    np.testing.assert_allclose(along, 0.0, atol=1e-9)
    np.testing.assert_allclose(curves[0][1:], 0.0, atol=1e-12)
    # detector s of the shifted model looks where detector s + 1.5 of the other one does: a
    # point the other model images at column c, the shifted one images 1.5 px to the left
    image = image_difference_px(shifted, lab, "B2", 300.0)
    det, d_row, d_col = image[1]
    # exactly: 1.5 IFOV over the local slope of tan psi_y (the cubic distortion bends it)
    slope = look.look(det - look.first_col - 0.75)[3]
    np.testing.assert_allclose(d_col, -1.5 * ifov / slope, atol=2e-3)
    assert np.all(np.abs(d_col + 1.5) < 0.05)
    assert np.all(np.abs(d_row) < 0.02)
    assert np.all(np.abs(image[0][1]) < 1e-4) and np.all(np.abs(image[0][2]) < 1e-4)


def test_calibrated_minus_truth_is_small_and_initial_minus_truth_is_not(case, lab, truth):
    calibrated = image_difference_px(case["result"].model, truth, "B2", 400.0)
    initial = image_difference_px(lab, truth, "B2", 400.0)
    err = np.concatenate([np.hypot(d_row, d_col) for _, d_row, d_col in calibrated.values()])
    err0 = np.concatenate([np.hypot(d_row, d_col) for _, d_row, d_col in initial.values()])
    assert 0.005 < np.sqrt(np.mean(err**2)) < 0.3
    assert np.min(err0) > 20.0


def test_inconsistent_inputs_leave_nothing(case, tmp_path):
    bad = dataclasses.replace(case["result"], residuals_after=case["result"].residuals_after[:-3])
    with pytest.raises(InputError, match="residuals_after"):
        write_report(tmp_path, **{**case, "result": bad})
    short = {**case["checks"], "col": case["checks"]["col"][:-1]}
    with pytest.raises(InputError, match="checks.col"):
        write_report(tmp_path, **{**case, "checks": short})
    fewer = {k: (v[:-1] if isinstance(v, np.ndarray) else v) for k, v in case["checks"].items()}
    with pytest.raises(InputError, match="accuracy_before"):
        write_report(tmp_path, **{**case, "checks": fewer})
    with pytest.raises(InputError, match="error_vs_count"):
        write_report(tmp_path, **{**case, "error_vs_count": [{"rmse_px_mean": 1.0}]})
    assert os.listdir(tmp_path) == []


def test_failure_while_writing_keeps_the_previous_report(case, tmp_path, monkeypatch):
    write_report(tmp_path, **case)
    html_before = (tmp_path / "report.html").read_bytes()
    figures_before = {p: (tmp_path / "figures" / p).read_bytes() for p in os.listdir(tmp_path / "figures")}

    def fail(*args, **kwargs):  # fault injection after every figure has been drawn
        raise RuntimeError("disk full")

    monkeypatch.setattr(report_module, "_html", fail)
    with pytest.raises(RuntimeError, match="disk full"):
        write_report(tmp_path, **{**case, "error_vs_count": None})
    assert (tmp_path / "report.html").read_bytes() == html_before
    assert {p: (tmp_path / "figures" / p).read_bytes() for p in os.listdir(tmp_path / "figures")} == figures_before
    assert _leftovers(tmp_path) == []


def test_rewrite_replaces_old_figures_and_leaves_pyplot_alone(case, tmp_path):
    import matplotlib

    backend = matplotlib.get_backend()
    had_pyplot = "matplotlib.pyplot" in sys.modules
    write_report(tmp_path, **case)
    tall = mpimg.imread(tmp_path / "figures" / "distortion_B2.png").shape[0]
    write_report(tmp_path, **{**case, "error_vs_count": None, "truth_model": None})
    assert set(os.listdir(tmp_path / "figures")) == FIGURES - {"error_vs_gcp_count.png"}
    text = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "error_vs_gcp_count.png" not in text and "Error versus number of GCPs" not in text
    # without a truth the distortion figure has one row of panels instead of two
    assert mpimg.imread(tmp_path / "figures" / "distortion_B2.png").shape[0] < 0.7 * tall
    assert matplotlib.get_backend() == backend
    assert had_pyplot or "matplotlib.pyplot" not in sys.modules
    assert sorted(os.listdir(tmp_path)) == ["figures", "report.html"]


def test_rpc_bias_result_is_unwrapped(tmp_path):
    """A non-push-broom model: no distortion figure, every parameter in the main table."""
    from calibrate.rpc_bias import compensate_rpc_bias
    from sensor_models.models.rpc_fit import fit_rpc

    design = CameraDesign(n_ccds=1, detectors_per_ccd=600, band_names=("B1",), band_offsets_px=(0.0,))
    model = example_pushbroom_model(n_rows=600, design=design)
    rpc, _ = fit_rpc(model.detector_view(array=0), height_range_m=(0.0, 1000.0), grid_shape=(11, 11, 5))
    rng = np.random.default_rng(2)
    row, col = rng.uniform(1.0, 599.0, 300), rng.uniform(1.0, 599.0, 300)
    lon, lat, h = model.image_to_ground(row, col, height=200.0)
    row, col = row + 3.0 + rng.normal(0.0, 0.2, 300), col - 2.0 + rng.normal(0.0, 0.2, 300)
    fit = compensate_rpc_bias(rpc, row[:200], col[:200], lon[:200], lat[:200], h[:200])
    assert fit.success, fit.message
    checks = {"row": row[200:], "col": col[200:]}
    before = check_point_accuracy(rpc, row[200:], col[200:], lon[200:], lat[200:], h[200:])
    after = check_point_accuracy(fit.model, row[200:], col[200:], lon[200:], lat[200:], h[200:])
    assert 3.0 < before.absolute.rmse_px < 4.5 and after.absolute.rmse_px < 0.5
    write_report(tmp_path, result=fit, accuracy_before=before, accuracy_after=after, initial_model=rpc,
                 gcps={"row": row[:200], "col": col[:200], "band": None, "ccd": None}, checks=checks)
    assert set(os.listdir(tmp_path / "figures")) == {"residual_vectors.png", "residual_histograms.png"}
    text = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert ">bias.row.a0<" in text and ">bias.col.b0<" in text and "<details><summary>Interior" not in text
    assert f"{after.absolute.rmse_px:.4g}" in text


# --------------------------------------------------------------------------- the demo report
def _section(html, sid):
    m = re.search(rf'<section id="{sid}">(.*?)</section>', html, flags=re.S)
    return None if m is None else m.group(1)


def _fmt4(value):
    return f"{value:.4g}"


@pytest.fixture(scope="module")
def demo(demo_folder):
    """``gcpcal demo``'s folder and summary (about 10-15 s)."""
    import json

    out = demo_folder
    return out, json.loads((out / "summary.json").read_text()), (out / "report.html").read_text(encoding="utf-8")


def test_demo_report_band_to_band_section_holds_the_summary_numbers(demo):
    out, s, html = demo
    section = _section(html, "band-to-band")
    assert section is not None and 'href="#band-to-band"' in html
    others = [b for b, r in s["calibration"].items() if "tie_rms_before_px" in r]
    assert sorted(others) == ["B1", "B3", "B4"]
    for band in others:
        r = s["calibration"][band]
        row = re.search(rf'<tr><td class="l">{band}</td>(.*?)</tr>', section).group(1)
        cells = re.findall(r"<td>(.*?)</td>", row)
        # tie points, inliers (from the message "... over N inliers of M GCPs"), RMS before and after
        inliers, ties = re.search(r"over (\d+) inliers of (\d+)", r["message"]).groups()
        assert cells[0] == "<span class=\"ok\">yes</span>" and cells[1] == ties and cells[2] == inliers
        assert cells[-2:] == [_fmt4(r["tie_rms_before_px"]), _fmt4(r["tie_rms_after_px"])]
        assert 1.0 < r["tie_rms_before_px"] < 20.0 and r["tie_rms_after_px"] < 0.05
        assert f'<img src="figures/band_to_band_{band}.png"' in section
        img = mpimg.imread(out / "figures" / f"band_to_band_{band}.png")
        assert img.shape[0] >= 300 and float(np.std(img[..., :3])) > 0.02
    assert "band_to_band_B2.png" not in section  # B2 is the reference band


def test_demo_report_truth_section_holds_the_summary_numbers(demo):
    out, s, html = demo
    section = _section(html, "truth")
    assert section is not None
    for which in ("truth_error_px", "truth_error_before_px"):
        assert f"<td>{_fmt4(s[which]['rms'])}</td><td>{_fmt4(s[which]['max'])}</td>" in section
    assert len(s["truth_error_per_ccd"]) == 16  # 4 bands x 4 CCDs
    for r in s["truth_error_per_ccd"]:
        assert (f'<td class="l">{r["band"]}</td><td class="l">{r["ccd"]}</td><td>1625</td>'
                f'<td>{_fmt4(r["rms_px"])}</td><td>{_fmt4(r["max_px"])}</td>') in section
    assert '<img src="figures/truth_error_vs_detector.png"' in section
    img = mpimg.imread(out / "figures" / "truth_error_vs_detector.png")
    assert img.shape[0] >= 300 and float(np.std(img[..., :3])) > 0.02
    # and in the summary table, linked to the section
    summary = _section(html, "summary")
    assert f"RMS {_fmt4(s['truth_error_px']['rms'])} px, max {_fmt4(s['truth_error_px']['max'])} px" in summary


def test_band_totals_combine_the_ccds_exactly(demo):
    from calibrate.report.truth import band_totals

    _, s, html = demo
    per_ccd = [dict(r, n_points=1625) for r in s["truth_error_per_ccd"]]
    totals = band_totals(per_ccd)
    assert sorted(totals) == ["B1", "B2", "B3", "B4"]
    everything = band_totals([dict(r, band="all") for r in per_ccd])["all"]
    assert everything["rms_px"] == pytest.approx(s["truth_error_px"]["rms"], rel=1e-9)
    assert everything["max_px"] == pytest.approx(s["truth_error_px"]["max"], rel=1e-12)
    for band, t in totals.items():
        rms = [r["rms_px"] for r in per_ccd if r["band"] == band]
        assert min(rms) < t["rms_px"] < max(rms)
        assert f'<td class="l">{band}</td><td>6500</td><td>{_fmt4(t["rms_px"])}</td>' in _section(html, "truth")


def test_demo_report_has_no_empty_header_row_and_loads_every_figure(demo):
    out, _, html = demo
    heads = re.findall(r"<thead><tr>(.*?)</tr></thead>", html)
    assert heads and all(re.sub(r"<[^>]+>", "", h).strip() for h in heads)
    assert '<table><tbody><tr><td class="l">Status</td>' in html  # the summary, without a header row
    srcs = set(re.findall(r'<img src="([^"]+)"', html))
    assert srcs == {f"figures/{p.name}" for p in (out / "figures").iterdir()}
    assert len(srcs) == 10  # with the time-varying attitude figure and the band-parallax one


def test_ordinary_report_has_neither_demo_section(written):
    _, _, text = written
    assert _section(text, "band-to-band") is None and _section(text, "truth") is None
    assert "Error against the TRUE model" not in text


@pytest.mark.parametrize("kwargs, field", [
    ({"relative": "B1"}, "relative"),
    ({"truth_error": {"before": {"rms_px": 1.0, "max_px": 2.0}}}, "truth_error"),
    ({"truth_error": {"after": {"rms_px": 1.0}}}, "truth_error.after"),
])
def test_bad_band_to_band_or_truth_inputs_write_nothing(case, tmp_path, kwargs, field):
    with pytest.raises(InputError) as err:
        write_report(tmp_path / "r", **case, **kwargs)
    assert err.value.field == field
    assert not (tmp_path / "r" / "report.html").exists()


def test_demo_report_coverage_rows_hold_each_ccds_check_rmse(demo):
    _, s, html = demo
    section = _section(html, "coverage")
    keys = [k for k in s["per_ccd_after"] if "." in k]
    assert len(keys) == 4
    for key in keys:
        band, ccd = key.split(".")
        row = re.search(rf'<tr><td class="l">{band}</td><td>{ccd}</td>(.*?)</tr>', section).group(1)
        cells = re.findall(r"<td>(.*?)</td>", row)
        assert cells[-2] == _fmt4(s["per_ccd_after"][key]) and float(cells[-3]) > 100.0  # after; before


# --------------------------------------------------------------------------- counts that differ say why
def _notes(section):
    return re.findall(r'<p class="count-note">(.*?)</p>', section)


def _check_count_notes(html):
    """Each pair of counts of the same points that differs has its phrase, and no other phrase is written."""
    summary = _section(html, "summary")
    cell = {label: int(n) for label, n in re.findall(r'<tr><td class="l">([^<]+)</td><td(?: class="l")?>(\d+)', summary)}
    n_checks = cell["Check points"]
    n_gcps = int(re.search(r'<td class="l">GCPs</td><td class="l">(\d+)', summary).group(1))
    pairs = [(cell["check points, before"], n_checks, "check points before calibration"),
             (cell["check points, after"], n_checks, "check points after calibration"),
             (cell["GCPs (inliers), after"], n_gcps, "GCPs after calibration"),
             (cell["GCPs (inliers), before"], cell["GCPs (inliers), after"], "inliers before calibration")]
    expected = [f"{n} of {total} {what}: " for n, total, what in pairs if n != total]
    notes = _notes(summary)
    assert len(notes) == len(expected) and all(n.startswith(e) for n, e in zip(notes, expected)), (notes, expected)
    per_ccd = _notes(_section(html, "per-ccd"))
    differ = cell["check points, before"] != cell["check points, after"]
    assert len(per_ccd) == differ and all("initial model projects" in n for n in per_ccd)
    shown = 0
    if (section := _section(html, "band-to-band")) is not None:
        for band, ties, inliers in re.findall(r'<tr><td class="l">([^<]+)</td><td><span[^>]*>\w+</span></td>'
                                              r'<td>(\d+)</td><td>(\d+)</td>', section):
            phrase = f"{inliers} of {ties} tie points of {band}: the inliers of the robust solve"
            assert (phrase in section) == (ties != inliers)
            shown += ties != inliers
        assert len(_notes(section)) == shown
    if (section := _section(html, "parallax")) is not None:
        used = int(re.search(r"<p>(\d+) GCPs of the reference band", section).group(1))
        assert (f"{used} of {n_gcps} GCPs: the joint solve weights only" in section) == (used != n_gcps)
    return len(expected) + len(per_ccd) + shown


def test_count_note_is_written_only_for_counts_that_differ():
    from calibrate.report._html import count_note

    assert count_note(5, 5, "GCPs", "x") == "" and count_note(None, 5, "GCPs", "x") == ""
    assert count_note(3, 5, "GCPs", "a <b>") == '<p class="count-note">3 of 5 GCPs: a &lt;b&gt;.</p>'


def test_report_counts_that_differ_say_why(written, demo):
    _check_count_notes(written[2])
    _, s, html = demo
    assert _check_count_notes(html) > 0  # the demo's LAB model projects fewer points than the calibrated one
    truth = _section(html, "truth")
    lab, cal = (re.search(rf'<td class="l">{label}[^<]*</td><td>(\d+)</td>', truth).group(1)
                for label in ("LAB model", "calibrated model, every band"))
    phrase = f"{lab} grid points for the LAB model against {cal} for the calibrated model: "
    assert (phrase in truth) == (lab != cal)


def test_calibrate_line_says_over_how_many_check_points_an_rmse_is():
    from calibrate.cli.calibrate import _over

    assert _over(158, 158, "input") == "" and _over(None, 158, "input") == ""
    assert _over(143, 158, "input") == " (over the 143 the input model projects into the image)"
