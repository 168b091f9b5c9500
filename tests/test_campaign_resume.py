"""``gcpcal campaign --resume``: kept scene folders, their rows, what reruns a scene, and a killed campaign resumed.

Scenes: copies of the embedded fixture ``fixtures/hy1c_czi`` (``a``, ``b``; their files are
changed by some tests) and ``fixtures/small_ideal_scene`` (``tiny``: too small for any matching
window, a failed scene). Matching at a 48 px spacing keeps each scene to seconds.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.actions._ledger import LEDGER_NAME, owned
from calibrate.actions._guard import OutputRefusedError
from calibrate.cli import main
from calibrate.pipelines.campaign import read_campaign, run_campaign
from calibrate.pipelines.campaign_resume import clear_scene, earlier_output, made_from
from calibrate.residual_layer import read_residual_layer

ROOT = Path(__file__).resolve().parents[1]
HY1C = ROOT / "fixtures" / "hy1c_czi"
TINY = ROOT / "fixtures" / "small_ideal_scene"
SPACING = 48
#: Columns that differ between any two runs of a scene (its wall seconds, the worker's pid).
RUN_COLUMNS = ("seconds", "worker")


def _entry(name, scene: Path):
    ref = scene / "reference"
    return {"name": name, "scene": str(scene / "manifest.json"), "dom": str(ref / "dom.tif"), "dem": str(ref / "dem.tif")}


def _campaign(folder: Path, names) -> Path:
    """A campaign file of copies of HY1C named ``names`` (``tiny``: the broken scene)."""
    entries = []
    for name in names:
        if name == "tiny":
            entries.append(_entry(name, TINY))
            continue
        if not (folder / name).exists():
            shutil.copytree(HY1C, folder / name)
        entries.append(_entry(name, folder / name))
    path = folder / f"campaign_{'_'.join(names)}.csv"
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(entries[0]))
        writer.writeheader()
        writer.writerows(entries)
    return path


def _options():
    return {"spacing_px": SPACING, "min_gcps": 60, "min_coverage": 0.5, "relative": False, "threads": 1}


def _rows(out: Path) -> list[dict]:
    with (out / "campaign.csv").open() as f:
        return list(csv.DictReader(f))


def _assert_same_tables(out: Path, clean: Path) -> None:
    """The campaign table equal but for the run columns; the residual layer equal to the bit."""
    def strip(rows):
        return [{k: v.replace(str(out), "<out>").replace(str(clean), "<out>") for k, v in r.items()
                 if k not in RUN_COLUMNS} for r in rows]

    assert strip(_rows(out)) == strip(_rows(clean))
    got, want = read_residual_layer(out / "campaign_residuals.gpkg"), read_residual_layer(clean / "campaign_residuals.gpkg")
    assert set(got) == set(want) and len(want["id"]) > 100
    for key in want:
        assert np.array_equal(np.asarray(got[key]), np.asarray(want[key])), key


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    """Relative name -> (inode, mtime_ns) of every file under ``folder`` (but the ledger, which a
    scene folder committed alone holds until the campaign's ledger takes its entries)."""
    return {p.relative_to(folder).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns)
            for p in folder.rglob("*") if p.is_file() and p.name != LEDGER_NAME}


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """An uninterrupted campaign of ``a`` and ``tiny``, staged whole (no ``--resume``)."""
    folder = tmp_path_factory.mktemp("resume")
    campaign = _campaign(folder, ["a", "tiny"])
    out = folder / "clean"
    summary = run_campaign(read_campaign(campaign), out, source=campaign, workers=1, processes=False, spacing_px=SPACING)
    assert [r["status"] for r in summary["rows"]] == ["ok", "failed"]
    return folder, campaign, out


# --------------------------------------------------------------------------- kept scenes and their rows
def test_resume_keeps_a_finished_scene_and_gives_the_same_tables(clean, tmp_path):
    folder, campaign, out_clean = clean
    out = tmp_path / "out"
    shutil.copytree(out_clean, out)  # other inodes: gcpcal's files are told by their checksums
    kept_before = _files(out / "a")
    summary = run_campaign(read_campaign(campaign), out, source=campaign, workers=1, processes=False,
                           spacing_px=SPACING, resume=True)
    assert summary["kept"] == ["a"] and summary["rerun"] == {"tiny": "it failed before"}
    assert _files(out / "a") == kept_before  # not recomputed: the same files, untouched
    a = summary["rows"][0]
    run = json.loads((out / "a" / "run.summary.json").read_text())
    assert (a["seconds"], a["worker"]) == (run["seconds"], run["campaign"]["worker"])
    fresh = json.loads((out_clean / "campaign.json").read_text())["rows"][0]
    assert {k: v for k, v in a.items() if k not in RUN_COLUMNS} == {k: v for k, v in fresh.items() if k not in RUN_COLUMNS}
    _assert_same_tables(out, out_clean)
    # one ledger for the campaign folder, as a campaign staged whole leaves it; every file gcpcal's
    assert not list(out.glob(f"*/{LEDGER_NAME}")) and not list(out.rglob("*gcpcal-stage*"))
    assert all(owned(p) for p in out.rglob("*") if p.is_file() and p.name != LEDGER_NAME)

    # a rerun without --resume replaces the folder whole, as before
    summary = run_campaign(read_campaign(campaign), out, source=campaign, workers=1, processes=False,
                           spacing_px=SPACING)
    assert "kept" not in summary and _files(out / "a") != kept_before
    _assert_same_tables(out, out_clean)


def test_resume_never_replaces_a_users_file(clean, tmp_path):
    folder, campaign, out_clean = clean
    out = tmp_path / "out"
    shutil.copytree(out_clean, out)
    (out / "campaign.csv").write_text("edited by hand\n")
    with pytest.raises(OutputRefusedError, match="--overwrite"):
        run_campaign(read_campaign(campaign), out, workers=1, processes=False, spacing_px=SPACING, resume=True)
    assert (out / "campaign.csv").read_text() == "edited by hand\n"
    (out / "campaign.csv").unlink()
    # a file of the user's where the rerun scene writes one: the scene fails, the file stays
    (out / "tiny" / "gcps.summary.json").write_text("mine\n")
    (out / "tiny" / "notes.txt").write_text("mine too\n")
    summary = run_campaign(read_campaign(campaign), out, workers=1, processes=False, spacing_px=SPACING, resume=True)
    tiny = summary["rows"][1]
    assert summary["rerun"]["tiny"] == "its earlier gcps.summary.json is missing or changed"
    assert tiny["status"] == "failed" and "gcpcal did not write it" in tiny["reason"]
    assert (out / "tiny" / "gcps.summary.json").read_text() == "mine\n"
    assert (out / "tiny" / "notes.txt").read_text() == "mine too\n"
    assert summary["kept"] == ["a"]


# --------------------------------------------------------------------------- what reruns a scene
def test_what_makes_a_scene_run_again(clean, tmp_path):
    folder, campaign, out_clean = clean
    out = tmp_path / "out"
    shutil.copytree(out_clean, out)
    scene = read_campaign(campaign)[0]
    options = _options()
    now = made_from(scene, options)
    assert earlier_output(out / "a", now)[0]["success"] is True
    assert earlier_output(out / "nothing", now) == (None, None)
    (out / "a_file").write_text("x")
    assert earlier_output(out / "a_file", now) == (None, "its folder in OUT is a link or a file, not a folder gcpcal wrote")

    band = folder / "a" / "B2.tif"
    stat = band.stat()
    os.utime(band, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # touched, same content: kept
    assert earlier_output(out / "a", made_from(scene, options))[0] is not None
    saved = band.read_bytes()
    try:
        band.write_bytes(saved[:-1] + bytes([saved[-1] ^ 1]))  # same size, one bit changed
        assert earlier_output(out / "a", made_from(scene, options)) == (None, f"{band} changed")
    finally:
        band.write_bytes(saved)
        os.utime(band, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert earlier_output(out / "a", made_from(scene, {**options, "min_gcps": 61})) == \
        (None, "an option changed (min_gcps: 60 -> 61)")
    assert earlier_output(out / "a", made_from(scene, {**options, "threads": 7}))[0] is not None  # no result changes
    assert earlier_output(out / "a", made_from(replace(scene, dem_datum="egm96"), options)) == \
        (None, "its campaign entry changed (dem_datum: None -> 'egm96')")
    (out / "a" / "gcps_qc.png").unlink()
    assert earlier_output(out / "a", now) == (None, "its earlier gcps_qc.png is missing or changed")
    # the scene runs again: gcpcal's files of the earlier run go, a user's stay
    (out / "a" / "mine.txt").write_text("x")
    clear_scene(out / "a")
    assert [p.name for p in (out / "a").iterdir()] == ["mine.txt"]
    shutil.copytree(out_clean / "a", out / "a", dirs_exist_ok=True)  # files gcpcal's ledger no longer lists
    assert earlier_output(out / "a", now) == (None, "its earlier output is incomplete or not gcpcal's")


def test_changed_option_reruns_with_the_reason_on_stderr(clean, tmp_path, capsys):
    folder, campaign, out_clean = clean
    out = tmp_path / "out"
    shutil.copytree(out_clean, out)
    args = ["campaign", str(campaign), "--out", str(out), "--workers", "1", "--spacing", str(SPACING), "--resume"]
    assert main([*args, "--min-coverage", "0.4"]) == 4
    err = capsys.readouterr().err
    assert "kept 0 of 2 scene(s) from the earlier run" in err
    assert "a runs again: an option changed (min_coverage: 0.5 -> 0.4)" in err
    assert "tiny runs again: it failed before" in err
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["kept"] == [] and doc["options"]["min_coverage"] == 0.4
    assert [r["status"] for r in doc["rows"]] == ["ok", "failed"]


# --------------------------------------------------------------------------- a killed campaign, resumed
@pytest.mark.slow
def test_sigterm_mid_campaign_then_resume_equals_a_clean_run(tmp_path, capsys):
    """SIGTERM once a scene has ended; ``--resume`` keeps its folder (same inodes and times), runs the
    rest, and the campaign's table and residual layer equal those of an uninterrupted run."""
    campaign = _campaign(tmp_path, ["a", "tiny", "b"])
    out = tmp_path / "out"
    args = ["-q", "campaign", str(campaign), "--out", str(out), "--workers", "1", "--spacing", str(SPACING)]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    command = [sys.executable, "-c", "import sys; from calibrate.cli import main; sys.exit(main())"]
    proc = subprocess.Popen([*command, *args, "--resume"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if any((out / name / "run.summary.json").is_file() for name in ("a", "b")):
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the campaign ended before it could be interrupted"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err.decode()
    assert not (out / "campaign.csv").exists()
    done = [name for name in ("a", "b") if (out / name / "run.summary.json").is_file()]
    assert len(done) == 1, "the campaign was not interrupted mid-way"
    before = {name: _files(out / name) for name in done}

    assert main([*args[1:], "--resume"]) == 4
    err = capsys.readouterr().err
    assert f"kept {len(done)} of 3 scene(s) from the earlier run" in err
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["kept"] == done
    for name in done:  # not recomputed
        assert _files(out / name) == before[name]
    assert not list(tmp_path.rglob("*gcpcal-stage*"))

    clean = tmp_path / "clean"
    summary = run_campaign(read_campaign(campaign), clean, workers=1, processes=False, spacing_px=SPACING)
    assert [r["status"] for r in summary["rows"]] == ["ok", "failed", "ok"]
    _assert_same_tables(out, clean)


def test_a_scene_folder_left_by_a_stopped_resume_run_is_gcpcals_to_a_run_without_it(tmp_path):
    """A scene committed alone (its own ledger, as a stopped ``--resume`` run leaves it), then a campaign
    staged whole over it: every file stays gcpcal's, so that later runs replace them."""
    from calibrate.pipelines.campaign import campaign_scene

    campaign = _campaign(tmp_path, ["tiny"])
    scenes = read_campaign(campaign)
    out = tmp_path / "out"
    out.mkdir()
    row = campaign_scene(scenes[0], out, options=_options(), made_from=made_from(scenes[0], _options()))
    assert row["status"] == "failed" and (out / "tiny" / LEDGER_NAME).is_file()
    before = _files(out / "tiny")
    run_campaign(scenes, out, workers=1, processes=False, spacing_px=SPACING)
    assert _files(out / "tiny") != before and not (out / "tiny" / LEDGER_NAME).exists()
    assert all(owned(p) for p in out.rglob("*") if p.is_file() and p.name != LEDGER_NAME)
    run_campaign(scenes, out, workers=1, processes=False, spacing_px=SPACING)  # and again: nothing refused
