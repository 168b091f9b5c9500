"""Provenance in every product: summaries, the report's header and GeoTIFF tags name the gcpcal
version, the command line, every input with its size and SHA-256, the DEM's datum and geoid and
the reference's accuracy (calibrate/actions/_provenance.py)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import rasterio

from calibrate.cli import main
from sensor_models import __version__

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SCENE = FIXTURE / "manifest.json"
DOM = FIXTURE / "reference" / "dom.tif"
DEM = FIXTURE / "reference" / "dem.tif"


def _sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def matched(tmp_path_factory):
    out = tmp_path_factory.mktemp("prov") / "gcps.csv"
    assert main(["-q", "match", str(SCENE), "--dom", str(DOM), "--dem", str(DEM), "--out", str(out)]) == 0
    return out


def test_match_summary_names_version_command_inputs_terrain_and_reference(matched):
    prov = json.loads(matched.with_suffix(".summary.json").read_text())["provenance"]
    assert prov["gcpcal_version"] == __version__
    assert prov["command_line"].startswith("gcpcal -q match ") and f"--dom {DOM}" in prov["command_line"]
    inputs = {Path(i["path"]).resolve(): i for i in prov["inputs"]}
    for path in (SCENE, DOM, DEM, FIXTURE / "B2.tif"):  # the manifest names the band rasters
        entry = inputs[path.resolve()]
        assert entry["bytes"] == path.stat().st_size and entry["sha256"] == _sha256(path), path
    assert prov["terrain"]["vertical_datum"] == "ellipsoid" and prov["terrain"]["geoid"] is None
    assert Path(prov["terrain"]["dem"]).resolve() == DEM.resolve()
    assert prov["reference_accuracy"]["source"].startswith("tag ") and not prov["reference_accuracy"]["assumed"]


def test_calibration_summary_and_report_carry_their_own_and_the_gcps_provenance(matched, tmp_path, capsys):
    out = tmp_path / "cal"
    assert main(["-q", "calibrate", str(SCENE), "--gcps", str(matched), "--out", str(out)]) == 4  # partial
    capsys.readouterr()
    prov = json.loads((out / "calibrate.summary.json").read_text())["provenance"]
    assert prov["command_line"].startswith("gcpcal -q calibrate ")
    assert any(Path(i["path"]).resolve() == matched.resolve() and i["sha256"] == _sha256(matched)
               for i in prov["inputs"])
    assert prov["gcps_from"]["command_line"].startswith("gcpcal -q match ")  # where the GCPs came from
    html = (out / "report.html").read_text()
    header = html[html.index('id="provenance"'):html.index('id="summary"')]
    for text in ("Inputs and provenance", str(DOM), str(DEM), str(matched), _sha256(DEM), "heights ellipsoid"):
        assert text in header, text


def test_ortho_geotiff_tags_hold_the_provenance(tmp_path, capsys):
    out = tmp_path / "ortho.tif"
    assert main(["-q", "ortho", str(SCENE), "--dem", str(DEM), "--out", str(out)]) == 0
    capsys.readouterr()
    with rasterio.open(out) as ds:
        tags = ds.tags()
    assert tags["TIFFTAG_SOFTWARE"] == f"gcpcal {__version__}"
    prov = json.loads(tags["GCPCAL_PROVENANCE"])
    assert prov["command_line"].startswith("gcpcal -q ortho ")
    assert any(Path(i["path"]).resolve() == DEM.resolve() and i["sha256"] == _sha256(DEM) for i in prov["inputs"])


def test_large_inputs_are_listed_but_not_hashed(tmp_path, monkeypatch):
    import calibrate.actions._provenance as provenance

    path = tmp_path / "big.bin"
    path.write_bytes(b"x" * 100)
    monkeypatch.setattr(provenance, "HASH_LIMIT_BYTES", 10)
    entry = provenance.file_digest(path)
    assert entry["bytes"] == 100 and entry["sha256"] is None and "larger than 10 bytes" in entry["sha256_note"]
    monkeypatch.setattr(provenance, "HASH_LIMIT_BYTES", 1000)
    assert provenance.file_digest(path)["sha256"] == hashlib.sha256(b"x" * 100).hexdigest()
