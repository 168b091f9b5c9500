"""The batch-validation tutorial (``docs/tutorial_batch_validation.md``), run command by command.

As ``tests/test_tutorial.py`` does for the real-scene tutorial: the document's fenced ``bash``
blocks are parsed into commands and run, in order, by one bash process in a temporary folder,
each with its stdout, stderr and exit status recorded, and the document is held to what
happened:

* every command exits with 0, or with the code its ``# exit N`` comment announces;
* every line of a ``text`` block is a line that the commands of the ``bash`` block before it
  printed (timings masked, the work folder written as ``/path/to/batch``; figures of matched
  points to small tolerances, everything else exactly);
* the physics is bracketed: each validated scene's mean residual is the attitude-bias
  difference the truth predicts (within 0.35 px), the LAB camera is about 260 px off, the
  failed entry is a row with its reason, and the residual layer holds every point of the table.

Needs no shared data. One series of four small scenes, a match, a calibration and a validation
on a two-process local Dask cluster: about 20 s of CPU, 1 to 2 min on two busy cores (``slow``).
Every section needs the simulated series, so the fast tests check the document itself and its
sites file.
"""

from __future__ import annotations

import csv
import json
import re
import types
from pathlib import Path

import numpy as np
import pytest

from tests.test_tutorial import checked_text_blocks, fenced_blocks, normalized, split_commands
from tests.test_tutorial import line_agrees as tutorial_line_agrees
from tests.test_tutorial_pushbroom import run_document

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "tutorial_batch_validation.md"
WORK_FOLDER = "batch"  # the folder the tutorial creates and enters
WORK_PLACEHOLDER = "/path/to/batch"

#: lines whose figures come from matched points or a fit on them (tests/test_tutorial.py,
#: GCP_LINE): the table's rows and the per-scene lines; every other line is printed exactly
FITTED_LINE = re.compile(r"GCPs|inliers|points|│")
COUNT_WORDS = re.compile(r"\s*(GCPs|check points|inliers|points|windows)\b")


def line_agrees(doc_line: str, printed_line: str) -> bool:
    """``printed_line`` is ``doc_line``, up to the tolerances of fitted figures (``FITTED_LINE``)."""
    return tutorial_line_agrees(doc_line, printed_line, fitted=FITTED_LINE, counts=COUNT_WORDS)


# ----------------------------------------------------------------------------- the document itself
def test_the_document_has_commands_outputs_and_a_sites_file(tmp_path):
    from calibrate.batch import read_sites

    markdown = DOC.read_text(encoding="utf-8")
    blocks = fenced_blocks(markdown)
    commands = [c for lang, body in blocks if lang == "bash" for c in split_commands(body)]
    gcpcal = [c for c, _ in commands if c.startswith("gcpcal ")]
    for name in ("simulate series", "match", "calibrate", "validate"):
        assert any(c.startswith(f"gcpcal {name} ") for c in gcpcal), name
    assert any("--scheduler" in c for c in gcpcal) and any("--workers" in c for c in gcpcal)
    assert {code for _, code in commands} == {0, 1, 4}
    assert all(lang == "bash" or body.strip() for lang, body in blocks), "an empty text block"
    assert sum(lang == "text" for lang, _ in blocks) >= 6
    # the sites file the tutorial writes is one gcpcal reads: four entries, paths beside it
    heredoc = next(c for c, _ in commands if c.startswith("cat > sites.csv"))
    (tmp_path / "sites.csv").write_text(heredoc.split("\n", 1)[1].rsplit("\nEOF", 1)[0] + "\n")
    sites = read_sites(tmp_path / "sites.csv")
    assert [s.site for s in sites] == ["zhengzhou", "huairou", "dalian", "zhengzhou"]
    assert all(Path(s.scene).is_relative_to(tmp_path / "series") for s in sites)


def test_line_agrees_tolerates_matched_figures_only():
    row = "│ 1 │ 01_zhengzhou_20230627 │ 2023-06-27 │ 1.878 │ 1.390 │ 2.337 │ 73.5 │ 84 │ 260.9 │"
    assert line_agrees(row, row.replace("2.337", "2.351").replace(" 84 ", " 85 "))
    assert not line_agrees(row, row.replace("2.337", "2.537"))
    assert not line_agrees(row, row.replace("01_zhengzhou", "01_huairou"))
    exact = "3/4 scenes in N s on 2 worker(s); wrote val/validation.html, validation.csv, validation.json"
    assert not line_agrees(exact, exact.replace("2 worker", "3 worker"))


# ----------------------------------------------------------------------------- the run
@pytest.fixture(scope="module")
def tutorial(tmp_path_factory):
    markdown = DOC.read_text(encoding="utf-8")
    root = tmp_path_factory.mktemp("tutorial_batch")
    steps = run_document(markdown, ROOT, root)
    return types.SimpleNamespace(markdown=markdown, blocks=fenced_blocks(markdown), steps=steps,
                                 work=root / WORK_FOLDER)


@pytest.mark.slow
def test_every_command_exits_as_announced(tutorial):
    wrong = [(s.command.splitlines()[0], s.expected, s.rc, s.err.strip()[-300:])
             for s in tutorial.steps if s.rc != s.expected]
    assert not wrong, wrong
    for s in tutorial.steps:
        if s.expected:  # the reason in one line on stderr (after the progress), no traceback
            said = [line for line in s.err.splitlines() if line.startswith("gcpcal: ")]
            assert len(said) == 1 and "Traceback" not in s.err, s.err


@pytest.mark.slow
def test_text_blocks_are_what_the_commands_printed(tutorial):
    assert checked_text_blocks(tutorial.blocks, tutorial.steps,
                               lambda text: normalized(text.replace(str(tutorial.work), WORK_PLACEHOLDER)),
                               line_agrees) >= 6


@pytest.mark.slow
def test_each_scene_shows_its_own_attitude_bias_and_nothing_of_the_camera(tutorial):
    import pyogrio
    from pyogrio.raw import read

    work = tutorial.work
    doc = json.loads((work / "val" / "validation.json").read_text())
    assert doc["ok"] == 3 and doc["failed"] == 1 and doc["workers"] == 2
    rows = {r["name"]: r for r in doc["rows"]}
    assert rows["04_zhengzhou_no_dom"]["status"] == "failed"
    assert "no such DOM file" in rows["04_zhengzhou_no_dom"]["reason"]
    truth = {s["name"]: s for s in json.loads((work / "series" / "series.json").read_text())["scenes"]}
    assert len(truth) == 3
    for name, scene in truth.items():
        r, expected = rows[name], scene["expected_offset_px"]
        assert r["status"] == "ok", r["reason"]
        assert abs(r["mean_along_px"] - expected["row"]) < 0.35 and abs(r["mean_across_px"] - expected["col"]) < 0.35
        assert 200.0 < r["lab_rmse_planar_px"] < 330.0
    with open(work / "val" / "validation.csv", newline="") as fh:
        assert [r["name"] for r in csv.DictReader(fh)] == list(rows)  # the sites file's order
    # the residual layer: every matched point of the scenes that succeeded, in EPSG:4326, with its style
    layers = dict(pyogrio.list_layers(work / "val" / "residuals.gpkg"))
    assert set(layers) == {"validation_residuals", "layer_styles"}
    info = pyogrio.read_info(work / "val" / "residuals.gpkg", layer="validation_residuals")
    assert info["crs"] == "EPSG:4326" and info["features"] == sum(rows[n]["points"] for n in truth)
    _, _, _, (site, along) = read(work / "val" / "residuals.gpkg", layer="validation_residuals",
                                  columns=["site", "resid_along_px"], read_geometry=False)
    for name in truth:
        assert np.mean(along[site == name]) == pytest.approx(rows[name]["mean_along_px"], abs=1e-9)
    # the cluster that cannot be reached: nothing written
    assert not (work / "val_cluster").exists()
