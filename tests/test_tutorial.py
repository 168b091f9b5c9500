"""The real-scene tutorial (``docs/tutorial_real_scene.md``), run command by command.

The tutorial's fenced ``bash`` blocks are parsed into commands and run, in order, by one bash
process in a temporary folder (the line ``DATA=...`` points at ``../shared/data``), each with its
stdout, stderr and exit status recorded. The tests then hold the document to what happened:

* every command exits with 0, or with the code its ``# exit N`` comment announces;
* every line of a ``text`` block is a line that the commands of the ``bash`` block before it
  printed (timings masked, the data and work folders written as ``/path/to/...``);
* every figure of the table "Figures measured on this pair" equals the value recomputed from the
  files the commands wrote, to the precision printed;
* the physics is bracketed from both sides: the 60-line bias comes back within 60 +- 2 lines, the
  check RMSE falls from about 63 px to the few-pixel floor of SRTM against the canopy, GDAL reads
  the level-1A's RPC, and the two orthoimages are identical.

Uses ``../shared/data`` in place and skips when it is absent; 20 commands of gcpcal (three
matches of the real pair: about 1 min on 2 idle cores, 2.5 min on busy ones); they run in CI,
so the tutorial cannot drift from what the commands do.
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
import rasterio

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "tutorial_real_scene.md"
DATA_PLACEHOLDER = "/path/to/shared/data"
WORK_PLACEHOLDER = "/path/to/ventoux"
WORK_FOLDER = "ventoux"  # the folder the tutorial creates and enters

# ----------------------------------------------------------------------------- parsing the document
_FENCE = re.compile(r"^```(\w+)\n(.*?)^```$", re.S | re.M)
_EXIT = re.compile(r"#\s*exit\s+(\d+)\s*$")
_HEREDOC = re.compile(r"<<-?\s*'?(\w+)'?")
_TIMING = re.compile(r"(?<![\w.])\d+(?:\.\d+)? s\b")


def fenced_blocks(markdown: str) -> list[tuple[str, str]]:
    """``(language, body)`` of every fenced block of ``markdown``, in order."""
    return [(m.group(1), m.group(2)) for m in _FENCE.finditer(markdown)]


def split_commands(body: str) -> list[tuple[str, int]]:
    """The commands of a bash block with the exit status each must end with.

    A command is a line, with its ``\\``-continued lines and its here-document; full-line comments
    and blank lines are skipped; a trailing ``# exit N`` announces status ``N`` (default 0).
    """
    lines, commands, i = body.splitlines(), [], 0
    while i < len(lines):
        line = lines[i]
        i += 1
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        text = [line]
        while text[-1].endswith("\\") and i < len(lines):
            text.append(lines[i])
            i += 1
        last = text[-1]  # the line that ends the command, unless a here-document follows
        heredoc = _HEREDOC.search(last)
        if heredoc:
            while i < len(lines) and lines[i - 1].strip() != heredoc.group(1):
                text.append(lines[i])
                i += 1
        code = _EXIT.search(last)
        commands.append(("\n".join(text), int(code.group(1)) if code else 0))
    return commands


#: a figure below 1e-6 in exponent notation (e.g. an RPC fit error of 5.9e-09 px)
_TINY = re.compile(r"\b\d\.\d+e-(?:0[7-9]|[1-9]\d)\b")


def normalized(text: str, *, data: Path | None = None, work: Path | None = None) -> list[str]:
    """Lines with the folders written as placeholders, timings as ``N s`` and spaces collapsed."""
    if work is not None:
        text = text.replace(str(work), WORK_PLACEHOLDER)
    if data is not None:
        text = text.replace(str(data), DATA_PLACEHOLDER)
    text = _TIMING.sub("N s", text)
    text = _TINY.sub("<1e-6", text)  # fit errors at the rounding floor change with the last bits
    return [" ".join(line.split()) for line in text.splitlines() if line.strip()]


#: Lines whose figures come from the matched GCP set (match, residuals, calibration, RPC offsets).
#: Between machines a window on a rejection threshold may flip (the last bits of floating point
#: differ between CPUs), so the counts and the figures computed from them may differ slightly:
#: counts by up to ``COUNT_RTOL`` (2 %, at least 1), percentages by 1 point, other figures by
#: ``FIGURE_ATOL`` (0.05 px, lines or m) plus one unit of the last printed digit plus
#: ``FIGURE_RTOL`` (0.1 %) of figures below 1000 (not of offsets such as LINE_OFF). Measured
#: between an AVX-512 CPU and the same machine with AVX2 kernels (NPY_DISABLE_CPU_FEATURES,
#: OPENBLAS_CORETYPE): SIFT matches 479 / 484 (1.0 %), GCPs 463 / 464, check RMSE before
#: calibration 62.765 / 62.823 px, recovered bias 60.06 / 60.03 lines; the tolerances are about
#: twice that. Every other line (coordinates, sizes, CRSs, error messages) must be printed exactly.
GCP_LINE = re.compile(r"GCPs|inliers|points|LINE_OFF|line_off|SIFT matches")
COUNT_WORDS = re.compile(r"\s*(GCPs|check points|inliers|points|SIFT matches)\b")
COUNT_RTOL = 0.02
FIGURE_ATOL = 0.05
FIGURE_RTOL = 0.001
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def number_agrees(doc: str, printed: str, *, count: bool, percent: bool) -> bool:
    """Whether a printed number agrees with the document's to the tolerance of its kind."""
    a, b = float(doc), float(printed)
    if count:
        return abs(a - b) <= max(1.0, COUNT_RTOL * abs(a))
    if percent:
        return abs(a - b) <= 1.0
    mantissa = doc.lower().split("e")[0]
    unit = 10.0 ** -len(mantissa.split(".")[1]) if "." in mantissa else 1.0
    relative = FIGURE_RTOL * abs(a) if abs(a) < 1000.0 else 0.0
    return abs(a - b) <= FIGURE_ATOL + unit + relative + 1e-12


def line_agrees(doc_line: str, printed_line: str, *, fitted=GCP_LINE, counts=COUNT_WORDS) -> bool:
    """``printed_line`` is ``doc_line``, up to the tolerances of lines whose figures come from a
    matched GCP set or a fit on it (those ``fitted`` finds; ``counts`` names the count words)."""
    if doc_line == printed_line:
        return True
    if not fitted.search(doc_line) or _NUMBER.sub("#", doc_line) != _NUMBER.sub("#", printed_line):
        return False
    for m_doc, m_out in zip(_NUMBER.finditer(doc_line), _NUMBER.finditer(printed_line)):
        rest = doc_line[m_doc.end():]
        if not number_agrees(m_doc.group(), m_out.group(), count=bool(counts.match(rest)),
                      percent=rest.lstrip().startswith("%")):
            return False
    return True


def figures_table(markdown: str, heading: str = "## Figures measured on this pair") -> dict[str, str]:
    """``figure -> value`` of the table under ``heading``."""
    section = markdown.split(heading, 1)[1]
    rows = [line for line in section.splitlines() if line.startswith("|")][2:]  # header, rule
    return {cells[0]: cells[1] for cells in ([c.strip() for c in r.strip("|").split("|")] for r in rows)}


def _script(commands, data: Path, logs: Path) -> str:
    """One bash script running every command in turn, each logged to ``logs/<i>.{out,err,rc}``."""
    parts = ["cd " + shlex.quote(str(logs.parent))]
    if shutil.which("gcpcal", path=os.path.dirname(sys.executable)) is None:  # not installed as a script
        parts.append(f"gcpcal() {{ {shlex.quote(sys.executable)} -c "
                     "'import sys; from calibrate.cli import main; sys.exit(main(sys.argv[1:]))' \"$@\"; }")
    for i, (text, _) in enumerate(commands):
        text = re.sub(r"^DATA=.*$", "DATA=" + shlex.quote(str(data)), text, flags=re.M)
        parts.append(f"{{\n{text}\n}} > {logs}/{i}.out 2> {logs}/{i}.err\necho $? > {logs}/{i}.rc")
    return "\n".join(parts) + "\n"


# ----------------------------------------------------------------------------- running it once
@pytest.fixture(scope="module")
def tutorial(shared_data, tmp_path_factory):
    """Run the tutorial; per bash block its commands with their expected and actual status and output."""
    markdown = DOC.read_text(encoding="utf-8")
    blocks = fenced_blocks(markdown)
    root = tmp_path_factory.mktemp("tutorial")
    logs = root / "logs"
    logs.mkdir()
    commands, owner = [], []  # every command, and the index of its block
    for b, (lang, body) in enumerate(blocks):
        if lang == "bash":
            for command in split_commands(body):
                commands.append(command)
                owner.append(b)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "PATH": os.pathsep.join([os.path.dirname(sys.executable), os.environ.get("PATH", "")]),
           "COLUMNS": "120", "NO_COLOR": "1"}
    proc = subprocess.run(["bash", "-c", _script(commands, shared_data, logs)], env=env, capture_output=True,
                          text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr
    steps = []
    for i, ((text, expected), b) in enumerate(zip(commands, owner)):
        rc = (logs / f"{i}.rc").read_text().strip()
        steps.append(types.SimpleNamespace(command=text, expected=expected, rc=int(rc) if rc else None, block=b,
                                           out=(logs / f"{i}.out").read_text(), err=(logs / f"{i}.err").read_text()))
    return types.SimpleNamespace(markdown=markdown, blocks=blocks, steps=steps, data=shared_data,
                                 work=root / WORK_FOLDER)


# ----------------------------------------------------------------------------- the parser itself (no data)
def test_split_commands_handles_continuations_heredocs_and_exit_markers():
    body = ("# a comment\nA=1\n\ngcpcal x \\\n  --y 2  # exit 2\npython - <<'EOF'\nprint(1)\n# not a command\nEOF\n"
            "sed 's/a/b/' f > g\n")
    assert split_commands(body) == [("A=1", 0), ("gcpcal x \\\n  --y 2  # exit 2", 2),
                                    ("python - <<'EOF'\nprint(1)\n# not a command\nEOF", 0), ("sed 's/a/b/' f > g", 0)]


def test_normalized_masks_timings_and_folders_only():
    line = "wrote /d/x/ref/a.tif: 533 x 514 px at 0.5 m, check max 0.0000 px, 1.1 s; in 12 s of /w/v/out"
    assert normalized(line, data=Path("/d/x"), work=Path("/w/v")) == [
        "wrote /path/to/shared/data/ref/a.tif: 533 x 514 px at 0.5 m, check max 0.0000 px, N s; in N s of "
        "/path/to/ventoux/out"]
    assert normalized("fit max 5.87e-09 px, rms 1.2e-05 px, 3.1e-12") == ["fit max <1e-6 px, rms 1.2e-05 px, <1e-6"]


def test_line_agrees_tolerates_the_matched_set_and_nothing_else():
    doc = "work/gcps.csv: 460 GCPs + 115 check points from 3540 windows (16 % usable, 0 % cloud) in N s"
    assert line_agrees(doc, doc.replace("460 GCPs", "459 GCPs").replace("16 %", "17 %"))
    assert not line_agrees(doc, doc.replace("460 GCPs", "445 GCPs"))  # 3 %: a user notices
    assert not line_agrees(doc, doc.replace("3540 windows", "3600 windows"))
    rms = "cal: calibrated (RPC bias (offset) a0=-63, b0=-4.127; RMS 63.2 -> 4.87 px over 460 inliers of 460 GCPs)"
    assert line_agrees(rms, rms.replace("4.87 px", "4.89 px").replace("b0=-4.127", "b0=-4.131"))
    assert not line_agrees(rms, rms.replace("4.87 px", "4.97 px"))
    assert not line_agrees(rms, rms.replace("calibrated", "partial"))
    exact = "wrote ref/left_ortho.tif: 533 x 514 px at 0.5 m in EPSG:32631, 91 % valid"
    assert not line_agrees(exact, exact.replace("32631", "32632"))
    assert not line_agrees(exact, exact.replace("533 x", "534 x"))


def test_the_document_has_commands_outputs_and_figures():
    markdown = DOC.read_text(encoding="utf-8")
    blocks = fenced_blocks(markdown)
    commands = [c for lang, body in blocks if lang == "bash" for c in split_commands(body)]
    gcpcal = [c for c, _ in commands if c.startswith("gcpcal ")]
    for name in ("localize", "ortho", "match", "calibrate", "rpc"):
        assert any(c.startswith(f"gcpcal {name} ") for c in gcpcal), name
    assert {code for _, code in commands} == {0, 1, 2, 4}
    assert sum(lang == "text" for lang, _ in blocks) >= 8
    assert len(figures_table(markdown)) >= 10


# ----------------------------------------------------------------------------- the run
@pytest.mark.shared_data
def test_every_command_exits_as_announced(tutorial):
    wrong = [(s.command.splitlines()[0], s.expected, s.rc, s.err.strip()[-300:])
             for s in tutorial.steps if s.rc != s.expected]
    assert not wrong, wrong
    assert len(tutorial.steps) >= 25
    # a failing command is one line on stderr, no traceback
    for s in tutorial.steps:
        if s.expected in (1, 2):
            assert len(s.err.strip().splitlines()) == 1 and s.err.startswith("gcpcal: error: "), s.err
            assert "Traceback" not in s.err


def text_blocks_against_output(blocks, steps, printed_of, agrees):
    """Per ``text`` block of a tutorial, its lines no command of the bash block before it printed.

    Parameters
    ----------
    blocks : list of (str, str)
        The document's fenced blocks (:func:`fenced_blocks`).
    steps : list
        The commands run, each with ``block``, ``out`` and ``err``.
    printed_of : callable(str) -> list of str
        What a command printed, as the document shows it (folders as placeholders).
    agrees : callable(str, str) -> bool
        Whether a printed line is the document's line, up to its tolerance.

    Returns
    -------
    list of (list of str, list of str)
        Per text block: the document's lines not printed, and what was printed.
    """
    out = []
    for b, (lang, body) in enumerate(blocks):
        if lang != "text":
            continue
        source = max(i for i, (lang_i, _) in enumerate(blocks[:b]) if lang_i == "bash")
        printed = set()
        for s in steps:
            if s.block == source:
                printed |= set(printed_of(s.out + "\n" + s.err))
        missing = [line for line in normalized(body)
                   if line not in printed and not any(agrees(line, p) for p in printed)]
        out.append((missing, sorted(printed)))
    return out


def checked_text_blocks(blocks, steps, printed_of, agrees) -> int:
    """Assert that every ``text`` block was printed by the bash block before it; the blocks checked.

    Parameters as :func:`text_blocks_against_output`; a block with a line no command printed
    fails with the missing lines and what was printed.
    """
    checked = 0
    for missing, printed in text_blocks_against_output(blocks, steps, printed_of, agrees):
        assert not missing, (missing, printed)
        checked += 1
    return checked


@pytest.mark.shared_data
def test_text_blocks_are_what_the_commands_printed(tutorial):
    assert checked_text_blocks(tutorial.blocks, tutorial.steps,
                               lambda text: normalized(text, data=tutorial.data, work=tutorial.work), line_agrees) >= 8


def _json(tutorial, relative):
    return json.loads((tutorial.work / relative).read_text())


def _line_off(path) -> float:
    return float(re.search(r"^line_off:\s*([-\d.eE+]+)", Path(path).read_text(), re.I | re.M).group(1))


def _gdal_offsets(tutorial):
    """Matched points minus GDAL's RPC transformer on the level-1A: (d_row, d_col), px."""
    from rasterio.transform import RPCTransformer

    from gcpmatch.gcp_files import read_gcps

    points = read_gcps(tutorial.work / "work" / "gcps.csv")
    with rasterio.open(tutorial.work / "out" / "right_l1a.tif") as ds, RPCTransformer(ds.rpcs) as tr:
        rows, cols = tr.rowcol(points.lon, points.lat, points.h, op=np.positive)
    return points.row - np.asarray(rows, float), points.col - np.asarray(cols, float)


def _rows_moved_by_51_m(tutorial) -> list[float]:
    """Row change of the ground point of section 7 lowered by 51 m, left and right image (library, not CLI)."""
    from sensor_models.readers import open_scene

    moved = []
    for scene in (tutorial.data / "pleiades_ventoux" / "left_image.tif", tutorial.work / "work" / "right.tif"):
        rows, _ = open_scene(scene).model.ground_to_image(np.array([5.195, 5.195]), np.array([44.2063, 44.2063]),
                                                          np.array([520.0, 469.0]))
        moved.append(float(rows[1] - rows[0]))
    return moved


def _measured(tutorial) -> dict[str, list[float]]:
    """Each figure of the table, recomputed from the files the commands wrote."""
    from calibrate.residual_layer import read_residual_layer

    match = _json(tutorial, "work/gcps.summary.json")
    cal, control, ellipsoid = (_json(tutorial, f"{d}/calibration.json") for d in ("cal", "control/cal", "ellipsoid/cal"))
    summary = _json(tutorial, "cal/calibrate.summary.json")
    a0, a0_control, a0_ellipsoid = (d["bias"]["bias.row.a0"] for d in (cal, control, ellipsoid))
    after = cal["check_accuracy"]["after"]["absolute"]
    layer = read_residual_layer(tutorial.work / "work" / "gcps_residuals.gpkg")
    original = tutorial.data / "pleiades_ventoux" / "right_image.geom"
    geoid = _rows_moved_by_51_m(tutorial)
    return {
        "GCPs + check points matched on the biased product": [match["gcps"], match["check_points"]],
        "mean residual along track before calibration (px)": [float(np.mean(layer["resid_along_px"]))],
        "bias `a0` of the biased product (lines)": [a0],
        "bias `a0` of the original product (lines)": [a0_control],
        "recovered bias (lines)": [a0_control - a0],
        "check RMSE before calibration (px)": [summary["check_rmse_px"]["before"]],
        "check RMSE after calibration (px)": [summary["check_rmse_px"]["after"]],
        "check RMSE along / across track after (px)": [after["rmse_row_px"], after["rmse_col_px"]],
        "calibrated `LINE_OFF` minus the original product's (lines)":
            [_line_off(tutorial.work / "cal" / "right_full_scene_RPC.TXT") - _line_off(original)],
        "GDAL's RPC transformer on the level-1A, mean row offset (px)": [float(np.mean(_gdal_offsets(tutorial)[0]))],
        "bias `a0` with the DEM declared ellipsoidal (lines)": [a0_ellipsoid],
        "ellipsoid minus EGM96 `a0` (lines)": [a0_ellipsoid - a0],
        "a point 51 m lower: lines moved in the left / right image": [abs(d) for d in geoid],
        "a point 51 m lower: lines between the two images": [abs(geoid[0]) + abs(geoid[1])],
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
            if "51 m lower" in name:  # geometry of the RPCs alone, no GCP involved: exact
                assert part == printed, (name, part, value)
            else:  # counts and figures of the matched set (GCP_LINE's tolerances)
                assert number_agrees(part, printed, count="GCPs" in name, percent=False), (name, part, value)


@pytest.mark.shared_data
def test_the_sixty_lines_come_back_down_to_the_srtm_floor(tutorial):
    m = _measured(tutorial)
    assert abs(m["recovered bias (lines)"][0] - 60.0) < 2.0  # the bias put into right_image_bias.geom
    assert 55.0 < m["check RMSE before calibration (px)"][0] < 70.0  # 60 lines plus the floor
    assert 1.0 < m["check RMSE after calibration (px)"][0] < 10.0  # SRTM vs canopy parallax, not zero
    along, across = m["check RMSE along / across track after (px)"]
    assert along > 2 * across  # the floor lies along the stereo base (along track)
    assert abs(m["calibrated `LINE_OFF` minus the original product's (lines)"][0]) < 6.0
    assert 25.0 < abs(m["ellipsoid minus EGM96 `a0` (lines)"][0]) < 45.0  # 51 m of geoid x the stereo parallax
    predicted = m["a point 51 m lower: lines between the two images"][0]
    assert abs(abs(m["ellipsoid minus EGM96 `a0` (lines)"][0]) - predicted) < 3.0  # the chain's error is the geometry's


@pytest.mark.shared_data
def test_gis_products_are_georeferenced_and_agree(tutorial):
    work = tutorial.work
    # the calibrated RPC file is the full scene's, as the product's .geom (its offsets near the product's)
    assert abs(_line_off(work / "cal" / "right_full_scene_RPC.TXT") - _line_off(work / "work" / "right.geom") + 63.0) < 3.0
    # the level-1A: the product's pixels, an RPC GDAL reads, which puts the matched points where they are
    with rasterio.open(work / "out" / "right_l1a.tif") as ds, rasterio.open(work / "work" / "right.tif") as src:
        assert ds.rpcs is not None and np.array_equal(ds.read(1), src.read(1))
        assert float(ds.tags()["GCPCAL_RPC_CHECK_MAX_PX"]) < 0.01
    d_row, d_col = _gdal_offsets(tutorial)
    assert abs(np.mean(d_row)) < 0.5 and abs(np.mean(d_col)) < 0.5
    assert 1.0 < np.sqrt(np.mean(d_row**2 + d_col**2)) < 10.0
    # ortho through --calibration and through the level-1A alone: the same grid and pixels
    with rasterio.open(work / "out" / "right_ortho.tif") as a, rasterio.open(work / "out" / "right_l1a_ortho.tif") as b:
        assert a.transform == b.transform and a.crs == b.crs
        pa, pb = a.read(1), b.read(1)
    # the level-1A's RPC is a fit (5.9e-9 px): a rare pixel on a rounding edge may differ by 1 DN
    differ = pa != pb
    assert np.count_nonzero(differ) <= 1e-4 * pa.size and np.abs(pa.astype(np.int64) - pb).max() <= 1
    assert np.count_nonzero(pa) > 0.8 * pa.size
    # nothing of the shared data was written: the product copies are the originals
    assert (work / "work" / "right.geom").read_bytes() == (
        tutorial.data / "pleiades_ventoux" / "right_image_bias.geom").read_bytes()
