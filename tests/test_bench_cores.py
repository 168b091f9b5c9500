"""bench/bench_cores.py end to end at 1 and 2 cores: every stage's children run pinned, report
positive rates, and the threaded stages give the same result for every count."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_bench_cores_phase_processes_and_window_stage(tmp_path):
    cores = min(2, len(os.sched_getaffinity(0)))
    out = tmp_path / "cores.json"
    counts = ",".join(str(n) for n in range(1, cores + 1))
    subprocess.run([sys.executable, str(ROOT / "bench" / "bench_cores.py"), "--cores", counts,
                    "--stages", "phase,phase_procs,windows", "--pairs", "1500", "--phase-batch", "128",
                    "--repeat", "1", "--json", str(out)], check=True, cwd=ROOT, timeout=600)
    doc = json.loads(out.read_text())
    summary = doc["summary"]
    assert set(summary) == {"phase", "phase_procs", "windows"}
    for stage, block in summary.items():
        rows = block["by_threads"]
        assert set(rows) == {str(n) for n in range(1, cores + 1)}
        assert all(row["rate_per_s"] > 0 and row["items"] > 0 for row in rows.values())
    assert summary["phase"]["same_result_for_every_count"] and summary["windows"]["same_result_for_every_count"]
    assert summary["windows"]["by_threads"]["1"]["items"] == 127 * 63  # 4096 x 2048 px, 64 px every 32
    assert doc["options"]["phase_batch"] == 128
