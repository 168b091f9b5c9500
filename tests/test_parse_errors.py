"""Every parse error is an input error: each text reader x each malformation ends as one line.

The matrix is every reader of a user's JSON, YAML, XML, CSV or keyword-list file (through the
command that reads it) against every way such a file arrives broken: nested 100 000 levels deep,
a Latin-1 byte in UTF-8 text, random bytes, empty, truncated, NUL bytes, a 2 MiB line. Each
cell asserts exit 1, exactly one stderr line naming the file, and no traceback or "internal
error". A last test runs ``gcpcal match`` under an address-space limit (``RLIMIT_AS``) in a
subprocess: memory exhaustion is exit 1 and one line naming the command and the step.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from calibrate.cli import main
from tests.conftest import SHARED_DATA

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SCENE = FIXTURE / "manifest.json"
DEM = FIXTURE / "reference" / "dem.tif"
DOM = FIXTURE / "reference" / "dom.tif"
DATA = SHARED_DATA  # ../shared/data beside the project, or GCPCAL_SHARED_DATA

_POINT = ["--rows", "1", "--cols", "1", "--height", "0"]


def _good(kind: str) -> bytes:
    """A well-formed file of each kind, the malformations' starting point."""
    texts = {
        "manifest": lambda: SCENE.read_bytes(),
        "gcps": lambda: b"id,row,col,lon,lat,h\n1,10.5,10.5,5,5,0\n2,20.5,20.5,5,5,0\n",
        "sites_csv": lambda: b"name,scene,dom,dem\na,x.json,y.tif,z.tif\n",
        "sites_yaml": lambda: b"- name: a\n  scene: x.json\n  dom: y.tif\n  dem: z.tif\n",
        "marks": lambda: (ROOT / "fixtures" / "oalr_marks" / "marks.csv").read_bytes(),
        "config": lambda: b'{"seed": 1}\n',
        "frames": lambda: b'{"format_version": 1, "kind": "geo_star_frames", "frames": []}\n',
        "dimap": lambda: (DATA / "spot_dimap" / "SPOT1.DIM").read_bytes(),
        "dimap_v2": lambda: (DATA / "products" / "SPOT6.XML").read_bytes(),
        "worldview": lambda: (DATA / "products" / "WV2.XML").read_bytes(),
        "rpc": lambda: (DATA / "pleiades_ventoux" / "left_image.geom").read_bytes(),
    }
    return texts[kind]()


#: reader -> (kind of file, suffix, argv builder(path, work))
READERS = {
    "scene manifest": ("manifest", ".json", lambda p, w: ["localize", p, *_POINT]),
    "truth manifest": ("manifest", ".json", lambda p, w: ["truth", "error", SCENE, "--truth", p, "--height", "0"]),
    "calibrated manifest": ("manifest", ".json", lambda p, w: ["relative", SCENE, "--calibration", p, "--dem", DEM,
                                                               "--out", w / "rel"]),
    "GCP table": ("gcps", ".csv", lambda p, w: ["calibrate", SCENE, "--gcps", p, "--out", w / "cal", "--no-report"]),
    "points CSV": ("gcps", ".csv", lambda p, w: ["localize", SCENE, "--csv", p, "--height", "0"]),
    "sites CSV": ("sites_csv", ".csv", lambda p, w: ["validate", p, "--calibration", SCENE, "--out", w / "v"]),
    "sites YAML": ("sites_yaml", ".yaml", lambda p, w: ["validate", p, "--calibration", SCENE, "--out", w / "v"]),
    "OALR marks": ("marks", ".csv", lambda p, w: ["oalr", p, "--out", w / "o"]),
    "simulation config": ("config", ".json", lambda p, w: ["simulate", "pushbroom", "--config", p, "--print-config",
                                                           "--out", w / "s"]),
    "star frame list": ("frames", ".json", lambda p, w: ["stars", p, "--out", w / "st"]),
    "DIMAP": ("dimap", ".DIM", lambda p, w: ["localize", p, *_POINT]),
    "DIMAP v2 XML": ("dimap_v2", ".XML", lambda p, w: ["localize", p, *_POINT]),
    "WorldView XML": ("worldview", ".XML", lambda p, w: ["localize", p, *_POINT]),
    "OSSIM RPC": ("rpc", ".geom", lambda p, w: ["localize", p, *_POINT]),
}
_NEEDS_DATA = {"dimap", "dimap_v2", "worldview", "rpc"}


def _nested(suffix: str) -> bytes:
    depth = 100_000
    if suffix in (".json", ".yaml"):
        return b"[" * depth + b"]" * depth
    if suffix.lower() in (".xml", ".dim"):
        return b"<a>" * depth + b"</a>" * depth
    return b'"' + b"x\n" * depth  # CSV, keyword list: one quoted field over 100 000 lines, never closed


def _latin1(good: bytes) -> bytes:
    i = len(good) // 2
    return good[:i] + "é".encode("latin-1") + good[i:]


MALFORMATIONS = {
    "nested 100k deep": lambda good, suffix: _nested(suffix),
    "Latin-1 byte": lambda good, suffix: _latin1(good),
    "random bytes": lambda good, suffix: random.Random(29).randbytes(4096),
    "empty": lambda good, suffix: b"",
    "truncated": lambda good, suffix: good[: len(good) // 2],
    "NUL bytes": lambda good, suffix: good[:40] + b"\x00" * 8 + good[40:],
    "2 MiB line": lambda good, suffix: good.split(b"\n")[0][:40] + b"7" * (2 << 20) + b"\n",
}


@pytest.mark.parametrize("malformation", list(MALFORMATIONS))
@pytest.mark.parametrize("reader", list(READERS))
def test_malformed_file_is_one_input_error(reader, malformation, tmp_path, capsys):
    kind, suffix, argv = READERS[reader]
    if kind in _NEEDS_DATA and not DATA.is_dir():
        pytest.skip(f"no real test data at {DATA}")
    work = tmp_path / "work"
    work.mkdir()
    path = tmp_path / f"input{suffix}"
    path.write_bytes(MALFORMATIONS[malformation](_good(kind), suffix))
    code = main(["-q", *map(str, argv(path, work))])
    _, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err, err
    assert code == 1, lines
    assert len(lines) == 1, lines
    assert lines[0].startswith("gcpcal: error: "), lines
    assert "internal error" not in lines[0]
    assert str(path) in lines[0], lines
    assert len(lines[0]) < 1200, lines[0][:200]
    assert list(work.iterdir()) == []


def test_the_good_files_of_the_matrix_are_read(tmp_path, capsys):
    """The malformations' starting points are well formed: each failure above is the malformation's."""
    for reader in ("scene manifest", "points CSV", "OSSIM RPC"):
        kind, suffix, argv = READERS[reader]
        if kind in _NEEDS_DATA and not DATA.is_dir():
            continue
        path = tmp_path / f"{kind}{suffix}"
        path.write_bytes(_good(kind))
        if kind == "rpc":  # its raster is found beside it
            path = DATA / "pleiades_ventoux" / "left_image.geom"
        assert main(["-q", *map(str, argv(path, tmp_path))]) == 0, capsys.readouterr().err


def test_one_line_even_when_a_message_quotes_line_breaks(tmp_path, capsys):
    """A header holding a quoted line break is quoted back escaped, on the one line."""
    path = tmp_path / "points.csv"
    path.write_text('"a\nb",c\n1,2\n')
    code = main(["-q", "localize", str(SCENE), "--csv", str(path), "--height", "0"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 1 and len(lines) == 1, lines
    assert "a\\nb" in lines[0]


_RLIMIT_SCRIPT = textwrap.dedent("""
    import re, resource, sys
    import cv2, numpy, rasterio, scipy.ndimage, scipy.fft  # loaded before the limit, as a running gcpcal has them
    from calibrate.cli import main
    import calibrate.actions.match, gcpmatch.extract, gcpmatch.phase, gcpmatch.coarse  # noqa: F401
    vm_kb = int(re.search(r"VmSize:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
    limit = (vm_kb << 10) + (48 << 20)  # 48 MiB above what is mapped: matching needs hundreds
    try:
        resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))
    except (ValueError, OSError) as exc:
        print("REFUSED", exc)
        sys.exit(77)
    sys.exit(main(sys.argv[1:]))
""")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc/self/status are Linux's")
def test_address_space_limit_is_one_line_naming_the_step(tmp_path):
    out = tmp_path / "gcps.csv"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", _RLIMIT_SCRIPT, "-q", "match", str(SCENE), "--dom", str(DOM),
                           "--dem", str(DEM), "--out", str(out), "--spacing", "16"],
                          capture_output=True, text=True, env=env, timeout=300)
    if proc.returncode == 77:
        pytest.skip(f"the platform refuses RLIMIT_AS: {proc.stdout.strip()}")
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.returncode == 1, lines
    assert len(lines) == 1, lines
    assert lines[0].startswith("gcpcal: error: out of memory in gcpcal match, at "), lines
    assert list(tmp_path.iterdir()) == []


def test_memory_error_inside_a_stage_is_one_line_naming_the_step(tmp_path, capsys, monkeypatch):
    """A MemoryError raised by a step (as numpy raises it) names the command and the step."""
    def exhausted(*args, **kwargs):
        raise MemoryError("Unable to allocate 12.0 GiB for an array with shape (40000, 40000)")

    monkeypatch.setattr("calibrate.actions.match.extract_gcps", exhausted)
    code = main(["-q", "match", str(SCENE), "--dom", str(DOM), "--dem", str(DEM), "--out", str(tmp_path / "g.csv")])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 1 and len(lines) == 1, lines
    assert lines[0].startswith("gcpcal: error: out of memory in gcpcal match, at "), lines
    assert "12.0 GiB" in lines[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("reader", ["scene manifest", "sites YAML", "DIMAP", "OSSIM RPC", "simulation config"])
def test_document_over_the_size_limit_is_refused_unread(reader, tmp_path, capsys):
    """A 'manifest' of 300 MiB (sparse: nothing is written or read) is refused by its size."""
    from sensor_models.files.documents import MAX_DOCUMENT_BYTES

    _, suffix, argv = READERS[reader]
    path = tmp_path / f"huge{suffix}"
    with open(path, "wb") as fh:
        fh.truncate(MAX_DOCUMENT_BYTES + (44 << 20))
    code = main(["-q", *map(str, argv(path, tmp_path / "w"))])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 1 and len(lines) == 1, lines
    assert lines[0].startswith(f"gcpcal: error: {path}: is 300 MiB; a ") and "at most 256 MiB" in lines[0], lines
