"""Shared test fixtures.

Real data lives in ``../shared/data`` beside the project's root (see its README); tests that
need it use the ``shared_data`` fixture and skip with a reason when it is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]
#: ``../shared/data`` beside the project; ``GCPCAL_SHARED_DATA`` names another place (a git worktree
#: of the project lies one folder deeper than the checkout the data sit beside)
SHARED_DATA = Path(os.environ.get("GCPCAL_SHARED_DATA") or PROJECT_ROOT.parent / "shared" / "data")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ``../shared/data``; skips the test when it is not there."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real test data not found at {SHARED_DATA} (../shared/data beside the project)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def demo_folder(tmp_path_factory):
    """``gcpcal demo --fixture ideal``'s output folder, run once per session (about 15-30 s); tests only read it.

    The ``ideal`` fixture (``fixtures/hy1c_czi``): the tests using this folder (test_demo,
    test_report, test_report_render, test_ortho) hold the ideal scene's figures and compare with
    its DOM. The default ``realistic`` demo is tested in ``tests/test_demo_realistic.py``.
    """
    from calibrate.cli import main

    out = tmp_path_factory.mktemp("demo-session") / "demo"
    assert main(["-q", "demo", "--fixture", "ideal", "--out", str(out), "--json"]) == 0
    return out


@pytest.fixture(scope="session")
def realistic_demo_inputs():
    """The realistic demo fixture's coarse-stage inputs (``fixtures/hy1c_czi_realistic``), read
    once: ``(reference band raster, LAB model, Dem, DOM MapImage, band name, TRUE model)``."""
    from gcpmatch.extract import read_band
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model, open_scene
    from sensor_models.terrain.dem import Dem

    fixture = PROJECT_ROOT / "fixtures" / "hy1c_czi_realistic"
    scene = open_scene(fixture / "manifest.json")
    band = scene.model.reference_band
    return (read_band(scene, band), scene.model, Dem.open(fixture / "reference" / "dem.tif"),
            MapImage.open(fixture / "reference" / "dom.tif"), band, open_model(fixture / "truth_manifest.json"))
