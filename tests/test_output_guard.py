"""The output guard: no output on an input, a device, a link or a user's file; gcpcal's own files replaced.

Each case of the hostile tester's report is run through ``calibrate.cli.main`` on a copy of the
embedded fixture: the command is refused before any work (exit 1, one line naming the output and
the input) and every input keeps its SHA-256.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from calibrate.cli import main

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


@pytest.fixture
def s(tmp_path):
    """A copy of the fixture scene (manifest, rasters, DOM, DEM, truth)."""
    return Path(shutil.copytree(FIXTURE, tmp_path / "s"))


def _sums(folder: Path) -> dict:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def _run(capsys, *argv):
    code = main(["-q", *map(str, argv)])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err
    return code, lines


def _match(s, out, *extra):
    return ["match", s / "manifest.json", "--dom", s / "reference/dom.tif", "--dem", s / "reference/dem.tif",
            "--out", out, "--spacing", "96", *extra]


# the cases of the report: (name, argv(s, tmp), input named in the refusal)
CASES = {
    "match --out the manifest": (lambda s, t: _match(s, s / "manifest.json"), "manifest.json"),
    "match --geotiff the DOM": (lambda s, t: _match(s, t / "new.csv", "--geotiff", s / "reference/dom.tif"), "dom.tif"),
    "ortho --out the DEM": (lambda s, t: ["ortho", s / "manifest.json", "--dem", s / "reference/dem.tif", "--out",
                                          s / "reference/dem.tif"], "dem.tif"),
    "ortho --out the scene raster": (lambda s, t: ["ortho", s / "manifest.json", "--dem", s / "reference/dem.tif",
                                                   "--band", "B2", "--out", s / "B2.tif"], "B2.tif"),
    "rpc --out the scene raster": (lambda s, t: ["rpc", s / "manifest.json", "--band", "B2", "--ccd", "cam1_ccd1",
                                                 "--out", s / "B2.tif"], "B2.tif"),
    "localize --out its --csv": (lambda s, t: ["localize", s / "manifest.json", "--csv", t / "pts.csv", "--height",
                                               "0", "--out", t / "pts.csv"], "pts.csv"),
    "truth error --out the truth": (lambda s, t: ["truth", "error", s / "manifest.json", "--truth",
                                                  s / "truth_manifest.json", "--out", s / "truth_manifest.json"],
                                    "truth_manifest.json"),
    "simulate --out the folder of its config": (lambda s, t: ["simulate", "pushbroom", "--config", t / "sim" / "c.json",
                                                              "--out", t / "sim"], "c.json"),
    "calibrate --out the folder of its image": (lambda s, t: ["calibrate", s / "manifest.json", "--gcps",
                                                              t / "g.csv", "--image", s / "B2.tif", "--out", s],
                                                "manifest.json"),
    "match --out a hard link to the manifest": (lambda s, t: _match(s, t / "hard.csv"), "manifest.json"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_an_output_on_an_input_is_refused_before_any_work(name, s, tmp_path, capsys):
    build, named = CASES[name]
    (tmp_path / "pts.csv").write_text("row,col\n10,10\n")
    (tmp_path / "g.csv").write_text("id,row,col,lon,lat,h\n")
    (tmp_path / "sim").mkdir()
    (tmp_path / "sim" / "c.json").write_text(json.dumps({"seed": 3}))
    os.link(s / "manifest.json", tmp_path / "hard.csv")
    before = _sums(tmp_path)
    code, lines = _run(capsys, *build(s, tmp_path))
    assert code == 1 and len(lines) == 1, lines
    assert named in lines[0] and "input" in lines[0], lines
    assert _sums(tmp_path) == before


def test_validate_into_a_folder_holding_a_scene_of_its_sites_is_refused(s, tmp_path, capsys):
    sites = tmp_path / "sites.csv"
    sites.write_text(f"name,scene,dom,dem\na,{s / 'manifest.json'},{s / 'reference/dom.tif'},"
                     f"{s / 'reference/dem.tif'}\n")
    before = _sums(tmp_path)
    code, lines = _run(capsys, "validate", sites, "--calibration", FIXTURE / "manifest.json", "--out", tmp_path)
    assert code == 1 and "holds the input" in lines[0], lines
    assert _sums(tmp_path) == before


def test_an_output_in_an_input_folder_is_refused(s, tmp_path, capsys):
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    shutil.copy(s / "reference" / "dem.tif", tiles / "dem.tif")
    code, lines = _run(capsys, "localize", s / "manifest.json", "--rows", "10", "--cols", "10", "--dem", tiles,
                       "--out", tiles / "pts.csv")
    assert code == 1 and "inside the input folder" in lines[0], lines
    assert sorted(p.name for p in tiles.iterdir()) == ["dem.tif"]


def test_a_users_folder_is_merged_into_never_wiped(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "summary.json").write_text("{}")
    (mine / "thesis.tex").write_text("precious")
    code, lines = _run(capsys, "thermal", "--days", "3", "--interval-min", "60", "--points", "50", "--out", mine)
    assert code == 0, lines
    assert (mine / "thesis.tex").read_text() == "precious" and (mine / "summary.json").read_text() == "{}"
    assert (mine / "thermal.json").is_file()


# --- devices, FIFOs, links, standard output ---------------------------------------------------------
def _localize(s, out, *extra):
    return ["localize", s / "manifest.json", "--rows", "10", "--cols", "10", "--height", "0", "--out", out, *extra]


@pytest.mark.skipif(not IS_ROOT, reason="mknod needs root")
def test_a_character_device_is_never_replaced(s, tmp_path, capsys):
    dev = tmp_path / "full"
    os.mknod(dev, 0o666 | stat.S_IFCHR, os.makedev(1, 7))  # a copy of /dev/full
    code, lines = _run(capsys, *_localize(s, dev))
    assert code == 1 and "character device" in lines[0], lines
    assert stat.S_ISCHR(os.lstat(dev).st_mode) and not (tmp_path / "full.summary.json").exists()
    code, lines = _run(capsys, *_localize(s, dev, "--overwrite"))
    assert code == 1 and stat.S_ISCHR(os.lstat(dev).st_mode)


def test_a_fifo_and_a_link_to_a_pipe_are_refused(s, tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    link = tmp_path / "stdout"
    link.symlink_to(fifo)  # as /dev/stdout -> /proc/self/fd/1 -> a pipe
    for out in (fifo, link):
        code, lines = _run(capsys, *_localize(s, out, "--overwrite"))
        assert code == 1 and "FIFO" in lines[0], lines
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and link.is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "s", "stdout"]


def test_a_symbolic_link_is_written_through_only_with_overwrite(s, tmp_path, capsys):
    target = tmp_path / "real.csv"
    target.write_text("the user's\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    code, lines = _run(capsys, *_localize(s, link))
    assert code == 1 and "symbolic link" in lines[0] and "--overwrite" in lines[0], lines
    assert target.read_text() == "the user's\n"
    code, lines = _run(capsys, *_localize(s, link, "--overwrite"))
    assert code == 0, lines
    assert link.is_symlink() and target.read_text().startswith("row,col,lon,lat,h")


def test_dash_is_standard_output_where_supported_and_refused_elsewhere(s, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["-q", *map(str, _localize(s, "-"))]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "row,col,lon,lat,h" and len(out) == 2
    code, lines = _run(capsys, "ortho", s / "manifest.json", "--dem", s / "reference/dem.tif", "--out", "-")
    assert code == 1, lines
    assert not (tmp_path / "-").exists() and not list(tmp_path.glob("-*"))


# --- gcpcal's own files and the user's ----------------------------------------------------------------
def test_own_outputs_replaced_user_files_and_edited_outputs_need_overwrite(s, tmp_path, capsys):
    out = tmp_path / "p.csv"
    assert _run(capsys, *_localize(s, out))[0] == 0
    assert _run(capsys, *_localize(s, out))[0] == 0  # gcpcal's own: replaced without a flag
    out.write_text(out.read_text() + "# my note\n")  # edited: the user's now
    code, lines = _run(capsys, *_localize(s, out))
    assert code == 1 and "did not write" in lines[0], lines
    assert out.read_text().endswith("# my note\n")
    assert _run(capsys, *_localize(s, out, "--overwrite"))[0] == 0
    user = tmp_path / "q.csv"
    user.write_text("mine")
    assert _run(capsys, *_localize(s, user))[0] == 1 and user.read_text() == "mine"
    (tmp_path / "legacy").mkdir()
    (tmp_path / "legacy" / "summary.json").write_text("{}")  # a summary's name proves nothing
    assert _run(capsys, *_localize(s, tmp_path / "legacy" / "summary.json"))[0] == 1


def test_match_writes_the_format_its_name_says(s, tmp_path, capsys):
    from gcpmatch.gcp_files import read_gcps

    code, lines = _run(capsys, *_match(s, tmp_path / "gcps.gpkg"))
    assert code == 0, lines
    assert (tmp_path / "gcps.gpkg").read_bytes()[:16] == b"SQLite format 3\x00"
    assert len(read_gcps(tmp_path / "gcps.gpkg")) > 0
    code, lines = _run(capsys, *_match(s, tmp_path / "gcps.xyz"))
    assert code == 1 and ".gpkg" in lines[0], lines


# --- staging of dead runs ---------------------------------------------------------------------------------
def test_stale_staging_of_a_dead_run_is_removed_and_reported(s, tmp_path, capsys):
    from calibrate.actions._staging import make_stage_dir

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    stale = make_stage_dir(tmp_path, "p.csv")
    stale = stale.rename(tmp_path / stale.name.replace(f".{os.getpid()}.", f".{pid}."))
    (stale / "p.csv").write_text("half")
    live = make_stage_dir(tmp_path, "p.csv")  # this process's: alive, kept
    other = tmp_path / f".p.csv.gcpcal-stage.another-host.{pid}.abc"
    other.mkdir()  # another host's: kept
    legacy = tmp_path / ".p.csv.stage-xyz"
    legacy.mkdir()  # not named by this scheme: kept
    code, lines = _run(capsys, *_localize(s, tmp_path / "p.csv"))
    assert code == 0
    assert any("interrupted gcpcal run" in line and str(pid) in line for line in lines), lines
    assert not stale.exists() and live.exists() and other.exists() and legacy.exists()
