"""``gcpcal campaign``: many scenes through ``gcpcal run``'s pipeline on Dask, equal to the serial runs.

Scenes: the embedded fixture ``fixtures/hy1c_czi`` (and a copy of it under another name), and
two broken ones: ``fixtures/small_ideal_scene`` (64 x 128 px, too small for any matching window:
"no GCP") and a scene whose DOM does not exist.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from calibrate.cli import main
from calibrate.pipelines.campaign import COLUMNS, read_campaign, run_campaign
from calibrate.residual_layer import read_residual_layer
from calibrate.actions._guard import OutputRefusedError
from sensor_models.errors import InputError
from sensor_models.maps.dom_inputs import DomSource

ROOT = Path(__file__).resolve().parents[1]
HY1C = ROOT / "fixtures" / "hy1c_czi"
TINY = ROOT / "fixtures" / "small_ideal_scene"


def _entry(name, scene: Path, dom=None):
    ref = scene / "reference"
    return {"name": name, "scene": str(scene / "manifest.json"), "dom": str(dom or ref / "dom.tif"),
            "dem": str(ref / "dem.tif")}


def _write_csv(path: Path, entries) -> Path:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for e in entries for k in e)))
        writer.writeheader()
        writer.writerows(entries)
    return path


def _stderr_lines(capsys):
    return [line for line in capsys.readouterr().err.splitlines() if line.strip()]


# --------------------------------------------------------------------------- the campaign file
def test_campaign_file_forms_and_errors(tmp_path):
    entries = [_entry("clear", HY1C), {**_entry("coast/2", TINY), "out": "coast2", "dem_datum": "ellipsoid"}]
    as_csv = read_campaign(_write_csv(tmp_path / "c.csv", entries))
    (tmp_path / "c.json").write_text(json.dumps(entries))
    (tmp_path / "c.yaml").write_text("".join(f"- {json.dumps(e)}\n" for e in entries))
    assert read_campaign(tmp_path / "c.json") == as_csv == read_campaign(tmp_path / "c.yaml")
    assert [(s.name, s.out, s.dem_datum) for s in as_csv] == [("clear", "clear", None), ("coast/2", "coast2", "ellipsoid")]
    assert as_csv[0].scene == HY1C / "manifest.json"

    # a folder of scenes: one per subfolder holding a manifest.json, its reference/ by default
    folder = tmp_path / "scenes"
    for name in ("b", "a"):
        (folder / name).mkdir(parents=True)
        (folder / name / "manifest.json").write_text("{}")
    (folder / "notes").mkdir()
    scenes = read_campaign(folder)
    assert [s.name for s in scenes] == ["a", "b"] and scenes[0].dom == folder / "a" / "reference" / "dom.tif"
    assert read_campaign(folder, dom="d.tif", dem="e.tif")[1].dem == "e.tif"
    qa = read_campaign(folder, dom=DomSource(band="B4"), dem_datum="egm96")[0]  # the DOM options, each scene's DOM
    assert qa.dom == DomSource(items=(str(folder / "a" / "reference" / "dom.tif"),), band="B4")
    assert qa.dem_datum == "egm96"

    bad = {
        "unknown field": ([{**entries[0], "colour": "red"}], "colour"),
        "missing dem": ([{k: v for k, v in entries[0].items() if k != "dem"}], "dem"),
        "duplicate name": ([entries[0], entries[0]], "already used"),
        "folder outside OUT": ([{**entries[0], "out": "../x"}], "one folder name inside OUT"),
        "folder of the campaign": ([{**entries[0], "out": "campaign.csv"}], "file of the campaign"),
        "two scenes, one folder": ([entries[0], {**entries[1], "out": "CLEAR"}], "already used by scene 'clear'"),
        "bad datum": ([{**entries[0], "dem_datum": "wgs84"}], "ellipsoid or egm96"),
    }
    for what, (rows, message) in bad.items():
        with pytest.raises(InputError, match=message):
            read_campaign(_write_csv(tmp_path / "bad.csv", rows))
    with pytest.raises(InputError, match="the DOM and DEM options apply to a folder"):
        read_campaign(tmp_path / "c.csv", dom="d.tif")
    with pytest.raises(InputError, match="holds no scene"):
        read_campaign(tmp_path / "scenes" / "notes")
    with pytest.raises(InputError, match="must be .yaml, .yml, .json or .csv"):
        read_campaign(tmp_path / "c.txt")


def test_bad_campaign_and_scheduler_are_one_line_and_no_folder(tmp_path, capsys):
    (tmp_path / "c.yaml").write_text("name: a\n")
    assert main(["campaign", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "o")]) == 1
    assert len(_stderr_lines(capsys)) == 1
    good = _write_csv(tmp_path / "c.csv", [_entry("clear", HY1C)])
    assert main(["campaign", str(good), "--out", str(tmp_path / "o"), "--scheduler", "notanaddress"]) == 1
    assert "scheduler" in _stderr_lines(capsys)[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.csv", "c.yaml"]


# --------------------------------------------------------------------------- failed scenes are rows
def test_failed_scenes_are_rows_with_their_reason(tmp_path):
    """Threads of this process (processes=False): no GCP, and a missing DOM; the campaign goes on."""
    scenes = read_campaign(_write_csv(tmp_path / "c.csv", [_entry("tiny", TINY),
                                                            _entry("no_dom", HY1C, dom=tmp_path / "nowhere.tif")]))
    out = tmp_path / "out"
    summary = run_campaign(scenes, out, source=tmp_path / "c.csv", workers=2, processes=False)
    assert (summary["ok"], summary["failed"], summary["workers"]) == (0, 2, 2)
    tiny, no_dom = summary["rows"]
    assert tiny["status"] == no_dom["status"] == "failed"
    assert "no GCP" in tiny["reason"] and tiny["gcps"] == 0
    assert f"see {out / 'tiny' / 'gcps.summary.json'}," in tiny["reason"]  # where it is, not where it was staged
    assert "nowhere.tif" in no_dom["reason"] and "not found" in no_dom["reason"]
    assert all("\n" not in r["reason"] for r in summary["rows"])
    # the scene that ran wrote its folder (run.summary.json says why it failed); the other none
    assert json.loads((out / "tiny" / "run.summary.json").read_text())["success"] is False
    assert not (out / "no_dom").exists()
    with (out / "campaign.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["name"] for r in rows] == ["tiny", "no_dom"] and list(rows[0]) == list(COLUMNS)
    assert rows[1]["reason"] == no_dom["reason"]
    assert len(read_residual_layer(out / "campaign_residuals.gpkg")["id"]) == 0
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["failures"] == {"tiny": tiny["reason"], "no_dom": no_dom["reason"]}
    assert doc["provenance"]["inputs"] and doc["options"]["threads"] >= 1

    # a rerun replaces gcpcal's own campaign; a campaign file edited since is refused before any work
    (out / "notes.txt").write_text("mine")
    run_campaign(scenes[:1], out, workers=1, processes=False)
    assert (out / "notes.txt").read_text() == "mine" and (out / "tiny" / "run.summary.json").is_file()
    assert [r["name"] for r in csv.DictReader((out / "campaign.csv").open())] == ["tiny"]
    (out / "campaign.csv").write_text("edited by hand\n")
    t0 = time.perf_counter()
    with pytest.raises(OutputRefusedError, match="--overwrite"):
        run_campaign(scenes[:1], out, workers=1, processes=False)
    assert time.perf_counter() - t0 < 1.0 and (out / "campaign.csv").read_text() == "edited by hand\n"


def test_campaign_at_a_scheduler_address(tmp_path, capsys):
    """--scheduler: the workers of a running scheduler (here one in this process); every scene failed: exit 3."""
    from distributed import LocalCluster

    campaign = _write_csv(tmp_path / "c.csv", [_entry("tiny", TINY), _entry("no_dom", HY1C, dom=tmp_path / "x.tif")])
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0") as cluster:
        code = main(["campaign", str(campaign), "--out", str(tmp_path / "o"), "--scheduler", cluster.scheduler_address,
                     "--json"])
    captured = capsys.readouterr()
    assert code == 3, captured.err
    summary = json.loads(captured.out)
    assert summary["scheduler"] == cluster.scheduler_address and summary["workers"] == 1
    assert summary["options"]["threads"] == 0  # at a scheduler: every core of the worker's machine
    assert [r["status"] for r in summary["rows"]] == ["failed", "failed"]
    assert "2 of 2 scene(s) failed (tiny: " in captured.err.splitlines()[-1]


# --------------------------------------------------------------------------- equal to the serial runs
def _figures(run: Path, name: str, scene: Path) -> dict:
    """A summary's numbers, without what names the run (its folder and scene, times, provenance, and
    the campaign's record of what a scene was made from)."""
    text = (run / name).read_text().replace(str(run), "<run>").replace(str(scene), "<scene>")
    doc = json.loads(text)
    for key in ("provenance", "seconds", "warnings", "campaign"):
        doc.pop(key, None)
    return doc


def _assert_same_numbers(a, b, where=""):
    """Equal; numbers to 1e-12 of their array's largest magnitude: BLAS reductions (covariances)
    differ in the last bits with the thread count of the process (Dask's workers run
    single-threaded BLAS)."""
    if isinstance(a, dict):
        assert set(a) == set(b), where
        for k in a:
            _assert_same_numbers(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, list) and _numeric(a):
        x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        assert x.shape == y.shape, where
        scale = np.nanmax(np.abs(x), initial=0.0)
        assert np.allclose(x, y, rtol=1e-12, atol=1e-12 * scale, equal_nan=True), where
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_same_numbers(x, y, f"{where}[{k}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert math.isclose(a, b, rel_tol=1e-12), (where, a, b)
    else:
        assert a == b, where


def _numeric(value) -> bool:
    if isinstance(value, list):
        return bool(value) and all(_numeric(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool) or value is None


@pytest.mark.slow
def test_campaign_equals_serial_runs_and_reports_the_broken_scene(tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(HY1C, copy)
    campaign = _write_csv(tmp_path / "campaign.csv", [_entry("clear", HY1C), _entry("tiny", TINY),
                                                      {**_entry("copy", copy), "out": "copy_scene"}])
    out = tmp_path / "out"
    t0 = time.perf_counter()
    code = main(["-q", "campaign", str(campaign), "--out", str(out), "--workers", "2", "--relative", "--json"])
    t_campaign = time.perf_counter() - t0
    summary = json.loads(capsys.readouterr().out)
    assert code == 4  # partial
    t0 = time.perf_counter()
    serial = tmp_path / "serial"
    ref = HY1C / "reference"
    assert main(["-q", "run", str(HY1C / "manifest.json"), "--dom", str(ref / "dom.tif"), "--dem", str(ref / "dem.tif"),
                 "--out", str(serial), "--relative"]) == 0
    print(f"campaign of 3 scenes on 2 workers {t_campaign:.1f} s; one serial run {time.perf_counter() - t0:.1f} s")

    by = {r["name"]: r for r in summary["rows"]}
    assert [r["name"] for r in summary["rows"]] == ["clear", "tiny", "copy"]
    assert (summary["ok"], summary["failed"]) == (2, 1) and "no GCP" in by["tiny"]["reason"]
    run = json.loads((serial / "run.summary.json").read_text())
    assert run["model"] == "relative/manifest.json" and run["relative"]["success"]
    for name, folder, scene in (("clear", out / "clear", HY1C), ("copy", out / "copy_scene", copy)):
        row = by[name]
        assert row["status"] == "ok" and row["folder"] == folder.name
        assert row["gcps"] == run["gcps"] and row["check_rmse_after_px"] == run["check_rmse_px"]["after"]
        assert row["check_rmse_before_px"] == run["check_rmse_px"]["before"] > 100.0 > 0.1 > row["check_rmse_after_px"]
        # the same GCP table, byte for byte, and the same calibration figures
        assert (folder / "gcps.csv").read_bytes() == (serial / "gcps.csv").read_bytes()
        for summary_file in ("run.summary.json", "calibration/calibration.json", "relative/relative.json"):
            _assert_same_numbers(_figures(serial, summary_file, HY1C), _figures(folder, summary_file, scene),
                                 summary_file)
        cal, cal_serial = (json.loads((f / "calibration/calibration.json").read_text()) for f in (folder, serial))
        assert cal["parameters"] == cal_serial["parameters"]  # exactly
        scene_run = json.loads((folder / "run.summary.json").read_text())
        assert scene_run["provenance"]["command_line"].startswith("gcpcal -q campaign ")
        assert str(out) in json.dumps(scene_run) and ".gcpcal-stage" not in json.dumps(scene_run)

    # one residual layer: every calibrated scene's points, the scene's name in `site`
    layer = read_residual_layer(out / "campaign_residuals.gpkg")
    serial_layer = read_residual_layer(serial / "calibration" / "residuals.gpkg")
    n = len(serial_layer["id"])
    assert list(layer["site"]) == ["clear"] * n + ["copy"] * n
    assert list(layer["resid_planar_px"][:n]) == pytest.approx(list(serial_layer["resid_planar_px"]), rel=1e-9)
    with (out / "campaign.csv").open() as f:
        assert [r["status"] for r in csv.DictReader(f)] == ["ok", "failed", "ok"]
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["residual_points"] == 2 * n and doc["workers"] == 2 and doc["options"]["relative"] is True



# --------------------------------------------------------------------------- Ctrl-C
def test_ctrl_c_during_a_campaign_is_one_line_and_leaves_nothing(tmp_path):
    """A folder of scenes; the workers ignore SIGINT (calibrate.actions._worker_signals); gcpcal stops,
    the staging goes."""
    campaign = tmp_path / "scenes"
    campaign.mkdir()
    (campaign / "tiny").symlink_to(TINY, target_is_directory=True)  # each with its reference/dom.tif, dem.tif
    (campaign / "clear").symlink_to(HY1C, target_is_directory=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    command = [sys.executable, "-c", "import sys; from calibrate.cli import main; sys.exit(main())"]
    proc = subprocess.Popen([*command, "-q", "campaign", str(campaign), "--out", str(tmp_path / "o"), "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if list(tmp_path.glob(".o.gcpcal-stage.*/tiny/run.summary.json")):  # a scene is done: work is under way
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the campaign ended before it could be interrupted"
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    _, err = proc.communicate(timeout=120)
    err = err.decode()
    assert proc.returncode == 130, err
    assert [line for line in err.splitlines() if line.strip()] == ["gcpcal: interrupted"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenes"]
