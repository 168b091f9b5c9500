"""The thread count of the parallel stages (sensor_models.files.threads): options, environment, the ordered map."""

from __future__ import annotations

import os
import threading
import time

import pytest
import rasterio

from sensor_models.errors import InputError
from sensor_models.files.threads import (THREADS_ENV, available_cores, blas_threads, map_ordered, opencv_threads,
                                         parse_threads, thread_count)


def test_parse_threads_accepts_counts_and_names_the_field_of_a_bad_one():
    assert parse_threads("4") == 4 and parse_threads(" 0 ") == 0 and parse_threads(3) == 3
    for bad in ("x", "-1", "2.5", -3, 1.5, True, ""):
        with pytest.raises(InputError) as err:
            parse_threads(bad, field="--threads")
        message = str(err.value)
        assert "\n" not in message and "--threads" in message and repr(bad) in message


def test_thread_count_explicit_then_environment_then_affinity(monkeypatch):
    monkeypatch.delenv(THREADS_ENV, raising=False)
    cores = len(os.sched_getaffinity(0))
    assert available_cores() == cores
    assert thread_count() == cores and thread_count(0) == cores and thread_count(None) == cores
    assert thread_count(5) == 5
    monkeypatch.setenv(THREADS_ENV, "3")
    assert thread_count() == 3 and thread_count(0) == 3 and thread_count(1) == 1
    monkeypatch.setenv(THREADS_ENV, "0")
    assert thread_count() == cores
    monkeypatch.setenv(THREADS_ENV, "many")
    with pytest.raises(InputError, match=THREADS_ENV):
        thread_count()
    with pytest.raises(InputError, match="threads"):
        thread_count(-1)


def test_map_ordered_keeps_the_order_bounds_what_is_in_flight_and_raises_at_the_turn():
    started, lock = [], threading.Lock()
    yielded = []

    def work(k):
        with lock:
            started.append(k)
        time.sleep(0.002 * (k % 3))  # blocks finish out of order
        return k * k

    for k, value in enumerate(map_ordered(work, range(40), 3, in_flight=4)):
        assert value == k * k
        # at most in_flight blocks were submitted beyond the ones already yielded
        assert len(started) <= len(yielded) + 4 + 1
        yielded.append(value)
    assert yielded == [k * k for k in range(40)]
    assert list(map_ordered(work, range(5), 1)) == [0, 1, 4, 9, 16]

    def fails(k):
        if k == 6:
            raise ValueError("block 6")
        return k

    out = []
    with pytest.raises(ValueError, match="block 6"):
        for value in map_ordered(fails, range(50), 2):
            out.append(value)
    assert out == list(range(6))


def test_library_thread_settings_are_restored():
    import cv2
    from threadpoolctl import threadpool_info

    before = cv2.getNumThreads()
    with opencv_threads(1):
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before
    blas_before = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    with blas_threads(1):
        assert all(i["num_threads"] == 1 for i in threadpool_info() if i["user_api"] == "blas")
    assert [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"] == blas_before


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_cli_threads_option_parses_and_a_bad_count_is_one_line(tmp_path, capsys, monkeypatch):
    """``--threads`` on match, ortho and simulate (``--workers`` there too): a bad count is one usage
    line (exit 2), a bad ``GCPCAL_THREADS`` one line naming it (exit 1); a good count reaches the stage."""
    import json
    from pathlib import Path

    from calibrate.cli import main

    fix = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
    monkeypatch.delenv(THREADS_ENV, raising=False)
    ortho = ["ortho", str(fix / "truth_manifest.json"), "--dem", str(fix / "reference" / "dem.tif"),
             "--resolution", "400"]
    for argv in (ortho + ["--out", str(tmp_path / "o.tif"), "--threads", "x"],
                 ["simulate", "pushbroom", "--out", str(tmp_path / "s"), "--workers", "-1"],
                 ["simulate", "series", "--out", str(tmp_path / "v"), "--threads", "1.5"],
                 ["match", str(fix / "manifest.json"), "--dom", str(fix / "reference" / "dom.tif"), "--dem",
                  str(fix / "reference" / "dem.tif"), "--out", str(tmp_path / "g.csv"), "--threads", "-2"]):
        assert main(argv) == 2, argv
        assert "--threads" in _one_line(capsys.readouterr().err)
    monkeypatch.setenv(THREADS_ENV, "lots")
    assert main(ortho + ["--out", str(tmp_path / "o.tif")]) == 1
    assert THREADS_ENV in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "o.tif").exists()
    monkeypatch.setenv(THREADS_ENV, "1")
    for extra, expected in (([], 1), (["--threads", "2"], 2)):
        out = tmp_path / f"o{expected}.tif"
        assert main(ortho + ["--out", str(out), "--json", *extra]) == 0
        assert json.loads(capsys.readouterr().out)["threads"] == expected
    with rasterio.open(tmp_path / "o1.tif") as a, rasterio.open(tmp_path / "o2.tif") as b:
        assert (a.read(1) == b.read(1)).all() and a.read(1).any()


def test_library_settings_held_by_concurrent_blocks_are_restored_once_all_leave():
    """This thread and another inside ``blas_threads(1)``/``opencv_threads(1)`` at once: the other
    leaving first does not restore the settings under this one; this one leaving last restores
    what was there before. (OpenBLAS ignores a thread count raised from another thread than the
    one that lowered it, so the test keeps the setting and the restoring on this thread.)"""
    import cv2
    from threadpoolctl import threadpool_info

    def blas():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    before_cv, before_blas = cv2.getNumThreads(), blas()

    def other():
        with opencv_threads(1), blas_threads(1):
            pass

    with opencv_threads(1), blas_threads(1):
        thread = threading.Thread(target=other)
        thread.start()
        thread.join(20)
        assert cv2.getNumThreads() == 1 and all(n == 1 for n in blas())  # still held
    assert cv2.getNumThreads() == before_cv and blas() == before_blas


def test_blas_setting_reaches_a_library_loaded_after_the_first_block():
    """Each outermost block scans the libraries loaded at that time (SciPy's own BLAS may load late)."""
    import scipy.linalg  # noqa: F401  loads SciPy's BLAS where it has its own
    from threadpoolctl import threadpool_info

    with blas_threads(1):
        assert all(i["num_threads"] == 1 for i in threadpool_info() if i["user_api"] == "blas")


def test_a_command_runs_blas_on_one_thread_unless_the_user_chose(monkeypatch):
    """``gcpcal`` commands hold BLAS to one thread (loaded libraries and, through the environment,
    later ones and child processes); a user's own ``*_NUM_THREADS`` is left alone."""
    from threadpoolctl import threadpool_info

    from calibrate import cli
    from sensor_models.files.threads import BLAS_THREAD_ENVS, command_blas_single_threaded

    for name in BLAS_THREAD_ENVS:
        monkeypatch.delenv(name, raising=False)
    before = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    with command_blas_single_threaded():
        assert all(i["num_threads"] == 1 for i in threadpool_info() if i["user_api"] == "blas")
        assert all(os.environ[name] == "1" for name in BLAS_THREAD_ENVS)
    assert [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"] == before
    assert not any(name in os.environ for name in BLAS_THREAD_ENVS)

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    with command_blas_single_threaded():
        assert [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"] == before
        assert "MKL_NUM_THREADS" not in os.environ
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")

    seen = []
    monkeypatch.setattr(cli.cli, "main", lambda **kw: seen.append(os.environ.get("OPENBLAS_NUM_THREADS")) or 0)
    assert cli.main(["--version"]) == 0 and seen == ["1"]
    assert "OPENBLAS_NUM_THREADS" not in os.environ
