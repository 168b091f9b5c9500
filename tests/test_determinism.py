"""The same inputs give the same GCPs whatever the thread count and the load.

``gcpcal match`` splits its work into blocks of lines (reference chips) and batches of windows
(phase correlation) that do not depend on the thread count, writes each block's results to its
own rows, and runs no sum across threads; SIFT keypoints are sorted by OpenCV before they are
filtered and the RANSAC draws are seeded. So within one environment the GCP table is identical
to the bit, and this test holds it to that: the real Pleiades pair of the tutorial
(``docs/tutorial_real_scene.md``) matched with ``--threads 1`` and ``--threads 2`` at the same
time, beside a process that keeps a core busy, then once more alone with every core.

(Across machines the last bits of floating point may differ: tests that compare with committed
outputs use the tolerances of ``tests/compare_outputs.py`` instead.)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_GCPCAL = [sys.executable, "-c", "import sys; from calibrate.cli import main; sys.exit(main(sys.argv[1:]))"]
_BUSY = [sys.executable, "-c", "import time\nend = time.time() + 120\nwhile time.time() < end: pass"]


def _env():
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


@pytest.fixture(scope="module")
def pair(shared_data, tmp_path_factory):
    """The tutorial's right crop with its biased RPC, the left crop orthorectified as the DOM, the DEM options."""
    root = tmp_path_factory.mktemp("determinism")
    (root / "right.tif").write_bytes((shared_data / "pleiades_ventoux" / "right_image.tif").read_bytes())
    (root / "right.geom").write_bytes((shared_data / "pleiades_ventoux" / "right_image_bias.geom").read_bytes())
    dem = ["--dem", str(shared_data / "dem" / "N44E005.hgt"), "--dem-datum", "egm96",
           "--geoid", str(shared_data / "dem" / "egm96_15.gtx")]
    subprocess.run([*_GCPCAL, "ortho", str(shared_data / "pleiades_ventoux" / "left_image.tif"), *dem,
                    "--resolution", "0.5", "--out", str(root / "left_ortho.tif")],
                   check=True, capture_output=True, env=_env(), cwd=root)
    return root, dem


def _match_command(root: Path, dem: list[str], out: str, threads: int) -> list[str]:
    return [*_GCPCAL, "match", str(root / "right.tif"), "--dom", str(root / "left_ortho.tif"), *dem,
            "--window", "32", "--spacing", "8", "--max-offset", "150", "--threads", str(threads),
            "--out", str(root / out)]


@pytest.mark.shared_data
def test_match_gives_the_same_gcps_under_load_and_any_thread_count(pair):
    root, dem = pair
    busy = subprocess.Popen(_BUSY)
    try:
        runs = [subprocess.Popen(_match_command(root, dem, f"t{n}.csv", n), env=_env(), cwd=root,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE) for n in (1, 2)]
        for run in runs:
            _, err = run.communicate(timeout=600)
            assert run.returncode == 0, err.decode()[-500:]
    finally:
        busy.kill()
        busy.wait()
    subprocess.run(_match_command(root, dem, "t0.csv", 0), check=True, capture_output=True, env=_env(), cwd=root)
    tables = {n: (root / f"t{n}.csv").read_bytes() for n in (0, 1, 2)}
    assert tables[1] == tables[2] == tables[0]
    counts = {n: json.loads((root / f"t{n}.summary.json").read_text()) for n in (0, 1, 2)}
    assert len({(c["gcps"], c["check_points"]) for c in counts.values()}) == 1
    assert counts[0]["gcps"] > 300  # a real match, not two empty tables
