"""Star-track calibration report (calibrate.report.star_report): figures, numbers, atomic output."""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pytest

from calibrate.report.star_report import SEED_000, held_out_errors, write_star_report
from sensor_models.errors import InputError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A short simulated sequence calibrated with the figure 8 study (about 3 s)."""
    from calibrate.star_calibration import process_frames
    from calibrate.star_frames import read_frame_list
    from sensor_models.readers.geo_manifest import read_geo_manifest
    from sensor_models.simulate.star_sky import simulate_geo_stars

    sim = tmp_path_factory.mktemp("star_report") / "sim"
    simulate_geo_stars(sim, n_frames=40, seed=0)
    frames, seconds, manifest = read_frame_list(sim)
    result = process_frames(frames, seconds, read_geo_manifest(manifest), versus_points=(10, 20))
    assert result.success
    doc = json.loads(json.dumps(result.to_dict(points=True), allow_nan=False))  # as stars.json holds it
    return result, doc


def _images(html):
    return re.findall(r'<img src="([^"]+)"', html)


def _check_png(path):
    from matplotlib.image import imread

    assert path.read_bytes()[:8] == PNG_SIGNATURE
    img = imread(path)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 300
    assert float(np.std(img[..., :3])) > 0.01  # something was drawn


def test_held_out_errors_reproduce_the_document_statistics(run):
    result, doc = run
    e = held_out_errors(result)
    chk = np.asarray(doc["points"]["check"])
    for key in ("ra_before_px", "de_before_px", "ra_after_px", "de_after_px"):
        assert np.all(np.isfinite(e[key][chk])) and np.all(np.isnan(e[key][~chk]))
    for which in ("before", "after"):
        for axis in ("ra", "de"):
            x = e[f"{axis}_{which}_px"][chk]
            stats = doc["accuracy"][which][axis]
            assert abs(np.mean(x) - stats["mean_px"]) < 1e-9
            assert abs(np.mean(np.abs(x)) - stats["mean_abs_px"]) < 1e-9
            assert abs(2.0 * np.std(x, ddof=1) - stats["two_sigma_px"]) < 1e-9
    # the simulation's LAB error is about (-7, -21) px as in seed 000 table 3; after: hundredths
    assert -8.0 < np.mean(e["ra_before_px"][chk]) < -6.0 and -22.0 < np.mean(e["de_before_px"][chk]) < -20.0
    assert 0.005 < np.mean(np.abs(e["de_after_px"][chk])) < 0.2


def test_report_has_every_figure_and_the_numbers(run, tmp_path):
    result, doc = run
    path = write_star_report(tmp_path, doc, result=result)
    assert path == tmp_path / "report.html"
    html = path.read_text(encoding="utf-8")
    srcs = _images(html)
    assert sorted(srcs) == sorted(f"figures/{n}.png" for n in
                                  ("star_tracks", "radec_errors", "error_histograms", "error_vs_points"))
    for src in srcs:
        _check_png(tmp_path / src)
    assert sorted(p.name for p in (tmp_path / "figures").iterdir()) == sorted(s.split("/")[1] for s in srcs)
    for section in ("summary", "accuracy", "parameters", "versus-points", "convergence", "timings"):
        assert f'<section id="{section}">' in html
    acc = doc["accuracy"]
    for which in ("before", "after"):
        for axis in ("ra", "de"):
            for key in ("mean_px", "mean_abs_px", "two_sigma_px"):
                assert f"{acc[which][axis][key]:.4g}" in html
    assert SEED_000["before"]["de"]["mean_px"] == -21.004
    for text in ("<td>-6.795</td>", "<td>-21.004</td>", "<td>0.84175</td>", "<td>0.8534</td>", "±2.24", "±2.35"):
        assert text in html
    for axis, corr in doc["installation_correction_arcsec"].items():
        assert f"{corr:.4g}" in html
    assert "<details><summary>Interior: 20 directional-angle coefficients" in html
    assert f"{doc['frames']['n_tracks']}</td>" in html and "calibrated" in html
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folder left


def test_document_alone_and_html_escaping(run, tmp_path):
    _, doc = run
    doc = copy.deepcopy(doc)
    doc["message"] = "<script>alert(1)</script> & more"
    doc["versus_points"] = []
    html = write_star_report(tmp_path, doc).read_text(encoding="utf-8")
    assert "<script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt; &amp; more" in html
    srcs = _images(html)  # no per-point errors: no scatter; histograms fall back to the fitted curves
    assert sorted(srcs) == ["figures/error_histograms.png", "figures/star_tracks.png"]
    assert "per-point errors are not in the document" in html
    for src in srcs:
        _check_png(tmp_path / src)


def test_failed_calibration_still_reports(tmp_path):
    doc = {"success": False, "message": "only 3 usable track points", "scheme": "exterior-interior",
           "accuracy": {}, "frames": {"n_frames": 4, "n_tracks": 0}, "runs": [], "tracks": []}
    html = write_star_report(tmp_path, doc).read_text(encoding="utf-8")
    assert "failed" in html and "only 3 usable track points" in html and "<img" not in html


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.pop("accuracy"), "accuracy"),
    (lambda d: d.__setitem__("success", "yes"), "success"),
    (lambda d: d["points"]["row"].pop(), "points.row"),
    (lambda d: d["points"].__setitem__("col", ["a"] * len(d["points"]["row"])), "points.col"),
    (lambda d: d.__setitem__("runs", "none"), "runs"),
])
def test_bad_document_writes_nothing(run, tmp_path, mutate, field):
    result, doc = run
    write_star_report(tmp_path, doc, result=result)  # a previous good report
    before = {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    bad = copy.deepcopy(doc)
    mutate(bad)
    with pytest.raises(InputError) as err:
        write_star_report(tmp_path, bad)
    assert f"'{field}'" in str(err.value)
    assert {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    fresh = tmp_path / "fresh"
    with pytest.raises(InputError):
        write_star_report(fresh, bad)
    assert not fresh.exists() or not any(fresh.iterdir())
    with pytest.raises(InputError):
        write_star_report(tmp_path / "nothing", ["not", "a", "document"])


def test_failure_while_drawing_keeps_previous_report(run, tmp_path):
    result, doc = run
    write_star_report(tmp_path, doc, result=result)
    old = (tmp_path / "report.html").read_bytes()
    bad = copy.deepcopy(doc)
    bad["versus_points"] = [{"points_per_track": "ten"}]  # passes validation, fails in the figure
    with pytest.raises(ValueError):
        write_star_report(tmp_path, bad)
    assert (tmp_path / "report.html").read_bytes() == old
    assert len(list((tmp_path / "figures").iterdir())) == 4
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_cli_writes_the_report(tmp_path):
    from calibrate.cli import main
    from sensor_models.simulate.star_sky import simulate_geo_stars

    simulate_geo_stars(tmp_path / "sim", n_frames=30, seed=1)
    assert main(["stars", str(tmp_path / "sim"), "--out", str(tmp_path / "cal")]) == 0
    html = (tmp_path / "cal" / "report.html").read_text(encoding="utf-8")
    doc = json.loads((tmp_path / "cal" / "stars.json").read_text())
    assert {"figures/star_tracks.png", "figures/radec_errors.png", "figures/error_histograms.png",
            "figures/error_vs_points.png"} <= set(_images(html))
    assert f"{doc['accuracy']['after']['de']['mean_abs_px']:.4g}" in html


def _sky_frames(sim, out, *, fmt, hot_pixels=300, seed=0):
    """A frame list of the simulated camera whose frames hold sky noise and hot pixels only.

    Each frame: Gaussian sky background (300 DN, sigma 19 DN, the simulator's level) plus
    ``hot_pixels`` single hot pixels of 200-3000 DN at random places, written as FITS with
    astropy (``fmt="fits"``) or as a GeoTIFF with rasterio (``fmt="tif"``).
    """
    from sensor_models.readers.geo_manifest import read_geo_manifest

    listed = json.loads((sim / "frames.json").read_text())
    shape = read_geo_manifest(sim / "manifest.json").image_shape
    rng = np.random.default_rng(seed)
    (out / "frames").mkdir(parents=True)
    frames = []
    for k, frame in enumerate(listed["frames"]):
        sky = rng.normal(300.0, 19.3, shape)
        r, c = rng.integers(0, shape[0], hot_pixels), rng.integers(0, shape[1], hot_pixels)
        sky[r, c] += rng.uniform(200.0, 3000.0, hot_pixels)
        path = out / "frames" / f"sky_{k:04d}.{fmt}"
        if fmt == "fits":
            from astropy.io import fits

            fits.writeto(path, sky.astype(np.float32))
        else:
            import warnings

            import rasterio
            from rasterio.errors import NotGeoreferencedWarning

            with warnings.catch_warnings():  # a sky frame has no map geometry
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(path, "w", driver="GTiff", width=shape[1], height=shape[0], count=1,
                                   dtype="uint16") as ds:
                    ds.write(np.clip(sky, 0, 65535).astype(np.uint16), 1)
        frames.append({"path": f"frames/{path.name}", "seconds": frame["seconds"]})
    listed.update(frames=frames, manifest=str((sim / "manifest.json").resolve()))
    (out / "frames.json").write_text(json.dumps(listed))
    return out


@pytest.fixture(scope="module")
def sim20(tmp_path_factory):
    from sensor_models.simulate.star_sky import simulate_geo_stars

    sim = tmp_path_factory.mktemp("sim20") / "sim"
    simulate_geo_stars(sim, n_frames=20, seed=0)
    return sim


def _assert_says_starless(html, frames_doc, n_frames):
    n_det, n_id = frames_doc["n_detections"], frames_doc["n_identified"]
    assert n_det > 1000 and frames_doc["n_tracks"] == 0  # thousands of detections, no track
    assert frames_doc["frames_without_stars"] == []  # every frame has detections: the old count said "0 without"
    assert f"No star identified in any of the {n_frames} frames" in html
    assert f"none of the {n_det} detections lies on a star track" in html
    assert "noise or hot pixels" in html and f"{n_id} chance" in html
    assert "without stars)" not in html and f"{n_det} / {n_id}" not in html
    assert "<img" not in html  # no empty track figure
    assert "No accuracy: no star track to calibrate from." in html


def test_starless_frames_say_so_instead_of_counting_detections(sim20, tmp_path):
    """``gcpcal stars`` on frames of noise and hot pixels: the report says no star was found."""
    from calibrate.cli import main

    sky = _sky_frames(sim20, tmp_path / "sky", fmt="tif")
    assert main(["-q", "stars", str(sky), "--out", str(tmp_path / "cal")]) == 3  # stage failed, report written
    doc = json.loads((tmp_path / "cal" / "stars.json").read_text())
    _assert_says_starless((tmp_path / "cal" / "report.html").read_text(encoding="utf-8"), doc["frames"], 20)


def test_starless_fits_frames_say_so(sim20, tmp_path):
    """The same with FITS frames written by astropy, through the library (process_frames)."""
    from calibrate.star_calibration import process_frames
    from calibrate.star_frames import read_frame_list
    from sensor_models.readers.geo_manifest import read_geo_manifest

    sky = _sky_frames(sim20, tmp_path / "sky", fmt="fits", seed=1)
    frames, seconds, manifest = read_frame_list(sky)
    assert all(str(f).endswith(".fits") for f in frames)
    result = process_frames(frames, seconds, read_geo_manifest(manifest))
    assert not result.success
    doc = json.loads(json.dumps(result.to_dict(points=True), allow_nan=False))
    html = write_star_report(tmp_path / "report", doc, result=result).read_text(encoding="utf-8")
    _assert_says_starless(html, doc["frames"], 20)


def test_stars_command_reads_fits_frame_lists(sim20, tmp_path):
    """``gcpcal stars`` takes a frame list of FITS files (the frame size is read by astropy)."""
    from calibrate.cli import main

    sky = _sky_frames(sim20, tmp_path / "sky", fmt="fits", seed=2)
    assert main(["-q", "stars", str(sky), "--out", str(tmp_path / "cal")]) == 3  # starless: failed, reported
    doc = json.loads((tmp_path / "cal" / "stars.json").read_text())
    _assert_says_starless((tmp_path / "cal" / "report.html").read_text(encoding="utf-8"), doc["frames"], 20)


def test_report_with_stars_does_not_say_starless(run, tmp_path):
    result, doc = run
    html = write_star_report(tmp_path, doc, result=result).read_text(encoding="utf-8")
    f = doc["frames"]
    assert "No star identified" not in html and "noise or hot pixels" not in html
    assert f"{f['n_detections']} detections, {f['n_identified']} matched to catalogue stars, " \
           f"{f['n_points']} on star tracks" in html
    assert "(0 without a tracked star)" in html
    # a frame without any track point is counted
    thin = copy.deepcopy(doc)
    keep = [i for i, k in enumerate(thin["points"]["frame"]) if k not in (3, 4)]
    thin["points"] = {key: [v[i] for i in keep] for key, v in thin["points"].items()}
    html = write_star_report(tmp_path / "thin", thin).read_text(encoding="utf-8")
    assert "(2 without a tracked star)" in html


def test_key_value_tables_have_no_empty_header_row(run, tmp_path):
    result, doc = run
    html = write_star_report(tmp_path, doc, result=result).read_text(encoding="utf-8")
    heads = re.findall(r"<thead><tr>(.*?)</tr></thead>", html)
    assert heads and all(re.sub(r"<[^>]+>", "", h).strip() for h in heads)
    assert html.count("<table>") > len(heads)  # the summary table is there, without a header
