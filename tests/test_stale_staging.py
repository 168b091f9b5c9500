"""clean_stale removes what a killed gcpcal run left, including the unfinished temporary of a
staged write whose target was the run's own staging folder (``..<name>.gcpcal-stage.<host>.<pid>.<r>.stage-<r>``,
left when the kill came between that write's ``mkdtemp`` and its rename)."""

from __future__ import annotations

import os
import subprocess
import sys

from calibrate.actions._staging import _host, clean_stale


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_clean_stale_removes_a_dead_runs_nested_write_and_leaves_a_live_one(tmp_path, capsys):
    host, dead, alive = _host(), _dead_pid(), os.getpid()
    stage = f".sim.gcpcal-stage.{host}.{dead}.abc123"
    nested = tmp_path / f".{stage}.stage-x7y8z9"
    (nested / "sub").mkdir(parents=True)
    (nested / "sub" / "part.tif").write_bytes(b"half written")
    (tmp_path / stage).mkdir()
    live = tmp_path / f"..sim.gcpcal-stage.{host}.{alive}.def456.stage-k1"
    live.mkdir()
    user = tmp_path / ".my.notes.stage-1"  # not gcpcal's: never touched
    user.mkdir()
    removed = clean_stale(tmp_path)
    assert not nested.exists() and not (tmp_path / stage).exists()
    assert live.exists() and user.exists()
    assert {p.name for p in removed} >= {nested.name, stage}
    err = capsys.readouterr().err
    assert "unfinished write of an interrupted gcpcal run" in err and f"pid {dead}" in err
