"""Transactional outputs and the one error boundary (issue 12, items 3 and 4).

Every command checks its output paths before it computes, stages what it writes beside the
target and swaps it in at the end; on a failure or an interrupt nothing new and nothing stale is
left. Each case asserts the exit code, one stderr line without a traceback, and the files left.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from calibrate.cli import main

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SCENE = FIXTURE / "manifest.json"
DOM = FIXTURE / "reference" / "dom.tif"
DEM = FIXTURE / "reference" / "dem.tif"


def _files(folder: Path) -> list[str]:
    """Every file and folder under ``folder`` (hidden ones too, gcpcal's ledgers excepted), relative, sorted."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.name != ".gcpcal-outputs.json")


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def gcp_table(tmp_path_factory):
    """A real GCP table of the fixture's reference band (coarse grid: a few seconds)."""
    from gcpmatch.gcp_files import read_gcps

    out = tmp_path_factory.mktemp("match") / "gcps.csv"
    assert main(["-q", "match", str(SCENE), "--dom", str(DOM), "--dem", str(DEM), "--out", str(out),
                 "--spacing", "48"]) == 0
    return read_gcps(out)


@pytest.fixture
def fast_match(monkeypatch, gcp_table):
    """``extract_gcps`` replaced by the table above; records whether it ran."""
    calls = []

    def fake(model, scene, dem, dom, **kwargs):
        calls.append(1)
        return gcp_table, {"gcps": len(gcp_table.gcps()), "check_points": len(gcp_table.checks()), "windows": 10,
                           "usable_fraction": 1.0, "cloud_fraction": 0.0, "message": "ok", "timings": {"total_s": 0.0}}

    monkeypatch.setattr("calibrate.actions.match.extract_gcps", fake)
    return calls


def _match_args(out, *extra):
    return ["-q", "match", str(SCENE), "--dom", str(DOM), "--dem", str(DEM), "--out", str(out), *extra]


# --- output paths are checked before any computation -------------------------------------------

def test_match_gpkg_under_a_file_fails_before_matching_and_leaves_nothing(tmp_path, capsys, fast_match):
    (tmp_path / "afile").write_text("x")
    code = main(_match_args(tmp_path / "gcps.csv", "--gpkg", str(tmp_path / "afile" / "x.gpkg")))
    assert code == 1
    assert "afile" in _one_error_line(capsys)
    assert fast_match == []  # refused before any work
    assert _files(tmp_path) == ["afile"]


def test_match_missing_gpkg_folder_is_created_and_all_files_arrive_together(tmp_path, capsys, fast_match):
    code = main(_match_args(tmp_path / "gcps.csv", "--gpkg", str(tmp_path / "nodir" / "x.gpkg")))
    assert code == 0, capsys.readouterr().err
    assert _files(tmp_path) == ["gcps.csv", "gcps.csvt", "gcps.prj", "gcps.summary.json", "gcps_qc.png",
                                "gcps_residuals.gpkg", "nodir", "nodir/x.gpkg"]


def test_match_geotiff_failure_leaves_no_csv_nor_gpkg(tmp_path, capsys, fast_match, monkeypatch):
    from sensor_models.errors import InputError

    def too_many(table, path, **kwargs):
        raise InputError("12000 GCPs: a GeoTIFF holds at most 10922; use CSV or GeoPackage", path=str(path))

    monkeypatch.setattr("gcpmatch.gcp_geotiff.write_gcps_geotiff", too_many)
    code = main(_match_args(tmp_path / "gcps.csv", "--gpkg", str(tmp_path / "g.gpkg"),
                            "--geotiff", str(tmp_path / "g.tif")))
    assert code == 1
    assert "10922" in _one_error_line(capsys)
    assert _files(tmp_path) == []


def test_match_backend_gpu_without_cuda_is_one_line_before_any_work(tmp_path, capsys, fast_match):
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    code = main(_match_args(tmp_path / "gcps.csv", "--backend", "gpu"))
    assert code == 1
    assert _one_error_line(capsys) == ("gcpcal: error: --backend gpu needs a CUDA device; this torch has none "
                                       "(use --backend cpu)")
    assert fast_match == [] and _files(tmp_path) == []


@pytest.mark.parametrize("command", [
    ["calibrate", str(SCENE), "--gcps", "{tmp}/gcps.csv"],
    ["relative", str(SCENE), "--calibration", str(FIXTURE), "--dem", str(DEM)],
    ["thermal", "--days", "2"],
    ["compensate", "--step", "1000", "--no-figures"],
    ["simulate", "geo-stars", "--frames", "3"],
])
def test_folder_output_under_a_file_is_refused_first(command, tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "gcps.csv").write_text("id,row,col,lon,lat,h\n")
    before = _files(tmp_path)
    args = [a.replace("{tmp}", str(tmp_path)) for a in command]
    code = main(["-q", *args, "--out", str(tmp_path / "afile" / "out")])
    assert code == 1
    line = _one_error_line(capsys)
    assert "afile" in line and "not a folder" in line
    assert _files(tmp_path) == before


def test_rpc_and_localize_outputs_under_a_file_are_refused(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    example = ROOT / "fixtures" / "example_pushbroom" / "manifest.json"
    assert main(["rpc", str(example), "--out", str(tmp_path / "afile" / "x_RPC.TXT")]) == 1
    assert "afile" in _one_error_line(capsys)
    assert main(["localize", str(example), "--rows", "1", "--cols", "1", "--height", "0",
                 "--out", str(tmp_path / "afile" / "p.csv")]) == 1
    assert "afile" in _one_error_line(capsys)
    assert _files(tmp_path) == ["afile"]


def test_an_early_error_creates_no_folder(tmp_path, capsys):
    out = tmp_path / "a" / "b" / "cal"
    code = main(["calibrate", str(SCENE), "--gcps", str(tmp_path / "missing.csv"), "--out", str(out)])
    assert code == 1
    _one_error_line(capsys)
    assert _files(tmp_path) == []


# --- folders: gcpcal's own files replaced, a user's kept ------------------------------------------

def test_rerun_replaces_gcpcal_files_and_keeps_the_users(tmp_path, capsys):
    out = tmp_path / "study"
    assert main(["-q", "compensate", "--step", "1000", "--no-figures", "--out", str(out)]) == 0
    first = _files(out)
    assert (out / ".gcpcal-outputs.json").is_file()
    (out / "notes.txt").write_text("the user's")
    assert main(["-q", "compensate", "--step", "1000", "--no-figures", "--out", str(out)]) == 0
    assert _files(out) == sorted(first + ["notes.txt"])  # merged: the user's file stays
    assert (out / "notes.txt").read_text() == "the user's"
    assert _files(tmp_path) == ["study"] + [f"study/{f}" for f in _files(out)]  # no staging folder left


def test_a_users_file_of_an_output_name_is_refused_without_overwrite(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    (out / "table.csv").write_text("the user's table")
    code = main(["-q", "compensate", "--step", "1000", "--no-figures", "--out", str(out)])
    assert code == 1
    line = _one_error_line(capsys)
    assert "table.csv" in line and "--overwrite" in line
    assert _files(tmp_path) == ["mine", "mine/table.csv", "mine/thesis.tex"]
    assert main(["-q", "compensate", "--step", "1000", "--no-figures", "--out", str(out), "--overwrite"]) == 0
    assert (out / "thesis.tex").read_text() == "precious"
    assert (out / "table.csv").read_text() != "the user's table"


def test_an_output_folder_holding_the_inputs_is_refused(tmp_path, capsys):
    assert main(["-q", "simulate", "geo-stars", "--frames", "3", "--out", str(tmp_path / "sim")]) == 0
    before = _files(tmp_path)
    assert main(["-q", "stars", str(tmp_path / "sim"), "--out", str(tmp_path / "sim")]) == 1
    assert "input" in _one_error_line(capsys)
    assert _files(tmp_path) == before


def test_calibrated_manifest_names_rasters_relative_to_the_final_folder(tmp_path, capsys, gcp_table):
    from gcpmatch.gcp_csv import write_gcps_csv
    from sensor_models.readers import open_scene

    write_gcps_csv(gcp_table, tmp_path / "gcps.csv")
    out = tmp_path / "deep" / "cal"
    # exit 4: the reference band is calibrated, the other bands wait for `gcpcal relative`
    assert main(["-q", "calibrate", str(SCENE), "--gcps", str(tmp_path / "gcps.csv"), "--out", str(out),
                 "--no-report"]) == 4
    rasters = open_scene(out / "manifest.json").rasters
    assert rasters and all(Path(r["path"]).is_file() for r in rasters.values())
    assert ".stage-" not in (out / "manifest.json").read_text() + (out / "calibration.json").read_text()
    assert not [p for p in (tmp_path / "deep").iterdir() if p.name != "cal"]


# --- failures and interrupts leave nothing new and nothing stale --------------------------------

def test_full_disk_names_the_file_and_keeps_the_previous_run(tmp_path, capsys, fast_match, monkeypatch):
    out = tmp_path / "gcps.csv"
    assert main(_match_args(out)) == 0
    before = {p: p.read_bytes() for p in tmp_path.iterdir()}

    def full(table, path, **kwargs):
        with open(path, "w") as fh:
            fh.write("id,row")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("gcpmatch.gcp_csv.write_gcps_csv", full)
    assert main(_match_args(out)) == 1
    line = _one_error_line(capsys)
    assert str(out) in line and "No space left on device" in line
    assert {p: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_read_only_filesystem_during_a_folder_write_names_the_folder(tmp_path, capsys, monkeypatch):
    import calibrate.schemes.compensation_outputs as outputs

    def read_only(*args, **kwargs):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(outputs, "write_study", read_only)
    out = tmp_path / "o"
    assert main(["compensate", "--step", "1000", "--no-figures", "--out", str(out)]) == 1
    line = _one_error_line(capsys)
    assert str(out) in line and "Read-only file system" in line
    assert _files(tmp_path) == []


def test_rasterio_write_failure_is_one_line_naming_the_file(tmp_path, capsys, fast_match, monkeypatch):
    from rasterio.errors import RasterioIOError

    def write_failed(table, path, **kwargs):
        try:
            raise RuntimeError("TIFFWriteEncodedStrip: write error, disk full")
        except RuntimeError as cause:
            raise RasterioIOError("Write failed. See previous exception for details.") from cause

    monkeypatch.setattr("gcpmatch.gcp_geotiff.write_gcps_geotiff", write_failed)
    code = main(_match_args(tmp_path / "gcps.csv", "--geotiff", str(tmp_path / "g.tif")))
    assert code == 1
    line = _one_error_line(capsys)
    assert "Write failed" in line and str(tmp_path) in line
    assert _files(tmp_path) == []


def test_interrupt_during_a_write_leaves_nothing(tmp_path, capsys, fast_match, monkeypatch):
    def interrupted(table, path, **kwargs):
        Path(path).write_text("half")
        raise KeyboardInterrupt

    monkeypatch.setattr("gcpmatch.geopackage.write_gcps_gpkg", interrupted)
    code = main(_match_args(tmp_path / "sub" / "gcps.csv", "--gpkg", str(tmp_path / "sub" / "g.gpkg")))
    assert code == 130
    assert _one_error_line(capsys) == "gcpcal: interrupted"
    assert _files(tmp_path) == []


def test_no_gcp_writes_the_summary_and_removes_the_stale_table(tmp_path, capsys, fast_match, monkeypatch):
    out = tmp_path / "gcps.csv"
    assert main(_match_args(out)) == 0
    monkeypatch.setattr("calibrate.actions.match.extract_gcps", lambda *a, **k: (None, {"message": "all cloud"}))
    assert main(_match_args(out)) == 1
    assert "all cloud" in _one_error_line(capsys)
    assert _files(tmp_path) == ["gcps.summary.json"]
    assert json.loads((tmp_path / "gcps.summary.json").read_text())["message"] == "all cloud"


def _truncated_copy(src: Path, dst: Path) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) // 2])
    return dst


def test_truncated_raster_is_one_line_naming_the_file(tmp_path, capsys):
    import rasterio

    image = tmp_path / "B2_cut.tif"
    with rasterio.open(FIXTURE / "B2.tif") as src:
        profile = src.profile | {"compress": None, "tiled": False}
        data = src.read()
    with rasterio.open(image, "w", **profile) as dst:
        dst.write(data)
    _truncated_copy(image, image)
    out = tmp_path / "o.tif"
    code = main(["ortho", str(SCENE), "--dem", str(DEM), "--image", str(image), "--band", "B2", "--out", str(out)])
    assert code == 1
    line = _one_error_line(capsys)
    assert "B2_cut.tif" in line and "Read failed" in line
    assert _files(tmp_path) == ["B2_cut.tif"]


def test_validate_bad_scheduler_is_one_line_and_no_folder(tmp_path, capsys):
    sites = tmp_path / "sites.csv"
    sites.write_text("name,scene,dom,dem\n")
    code = main(["validate", str(sites), "--calibration", str(tmp_path), "--out", str(tmp_path / "o"),
                 "--scheduler", "notanaddress"])
    assert code == 1
    assert "scheduler" in _one_error_line(capsys)
    assert _files(tmp_path) == ["sites.csv"]


# --- Ctrl-C during validate: one line, no worker tracebacks, no point files --------------------

@pytest.fixture(scope="module")
def small_series(tmp_path_factory):
    """A 3-scene validation series of a small sensor and its calibration."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_batch import small_sensor

    from calibrate.actions.calibrate import calibrate_scene
    from calibrate.actions.match import match_scene
    from gcpmatch.options import MatchOptions
    from sensor_models.simulate.series import simulate_series

    root = tmp_path_factory.mktemp("series")
    simulate_series(root, 3, base_config=small_sensor(), seed=5, calibration_scene=True)
    cal = root / "calibration"
    match_scene(cal / "manifest.json", dom_path=cal / "reference" / "dom.tif", dem_path=cal / "reference" / "dem.tif",
                out_path=root / "cal_gcps.csv", options=MatchOptions(spacing_px=16))
    calibrate_scene(cal / "manifest.json", root / "cal_gcps.csv", root / "calibrated", report=False)
    return root


@pytest.mark.skipif(shutil.which("gcpcal") is None, reason="the gcpcal console script is not installed")
def test_ctrl_c_during_validate_is_one_line_and_leaves_nothing(small_series, tmp_path):
    out = tmp_path / "o"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(["gcpcal", "-q", "validate", str(small_series / "sites.csv"), "--calibration",
                             str(small_series / "calibrated"), "--out", str(out), "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if list(tmp_path.glob(".o.gcpcal-stage.*/**/*.csv")):  # the first scene is done: work is under way
            break
        time.sleep(0.05)
    assert proc.poll() is None, "validate ended before it could be interrupted"
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    _, err = proc.communicate(timeout=120)
    err = err.decode()
    assert proc.returncode == 130, err
    assert [line for line in err.splitlines() if line.strip()] == ["gcpcal: interrupted"], err
    assert _files(tmp_path) == []
