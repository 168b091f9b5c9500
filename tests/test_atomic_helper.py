"""The one transactional-output helper (sensor_models/files/atomic.py): whole or absent."""

from __future__ import annotations

import pytest

from sensor_models.files.atomic import atomic_file, atomic_folder


def _listing(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_atomic_file_replaces_on_success_and_leaves_the_target_on_failure(tmp_path):
    target = tmp_path / "out" / "a.txt"
    with atomic_file(target, ".txt") as tmp:
        tmp.write_text("one")
        assert not target.exists() and tmp.parent == target.parent and tmp.name.startswith(".a.txt.")
    assert target.read_text() == "one"
    with pytest.raises(RuntimeError):
        with atomic_file(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert target.read_text() == "one" and _listing(tmp_path / "out") == ["a.txt"]


def test_atomic_folder_replace_merge_and_failure(tmp_path):
    out = tmp_path / "study"
    out.mkdir()
    (out / "stale.txt").write_text("earlier run")
    with atomic_folder(out, mode="replace") as tmp:
        (tmp / "figures").mkdir()
        (tmp / "figures" / "f.png").write_bytes(b"png")
        (tmp / "table.json").write_text("{}")
        assert tmp.parent == out.parent and tmp.name.startswith(".study.stage-")
    assert _listing(out) == ["figures", "figures/f.png", "table.json"]  # nothing of the earlier run
    assert _listing(tmp_path) == ["study", "study/figures", "study/figures/f.png", "study/table.json"]
    (out / "users.txt").write_text("mine")
    with atomic_folder(out, mode="merge", inside=True) as tmp:
        (tmp / "table.json").write_text('{"new": 1}')
    assert (out / "users.txt").read_text() == "mine" and (out / "table.json").read_text() == '{"new": 1}'
    with pytest.raises(KeyboardInterrupt):
        with atomic_folder(out, mode="merge", inside=True) as tmp:
            (tmp / "table.json").write_text("partial")
            raise KeyboardInterrupt
    assert (out / "table.json").read_text() == '{"new": 1}'
    assert _listing(out) == ["figures", "figures/f.png", "table.json", "users.txt"]  # no staging folder left
    with pytest.raises(ValueError):
        with atomic_folder(out, mode="replace", inside=True):
            pass
