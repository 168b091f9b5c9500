"""The manifest dispatch: one ``read_manifest`` for both camera kinds, readers that do not import each other."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from sensor_models.errors import ManifestError
from sensor_models.models.geo_staring import GeoStaringModel
from sensor_models.models.synthetic import example_geo_staring_model
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.readers import open_model
from sensor_models.readers.geo_manifest import read_geo_manifest, write_geo_manifest
from sensor_models.readers.manifest import pushbroom_model_from_document
from sensor_models.readers.scene import read_manifest

READERS = Path(__file__).resolve().parents[1] / "sensor_models" / "readers"
EXAMPLE = Path(__file__).resolve().parents[1] / "fixtures" / "example_pushbroom" / "manifest.json"


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def test_manifest_readers_do_not_import_each_other():
    assert "sensor_models.readers.geo_manifest" not in _imported_modules(READERS / "manifest.py")
    assert "sensor_models.readers.manifest" not in _imported_modules(READERS / "geo_manifest.py")
    shared = ("sensor_models.readers._strict", "sensor_models.files.documents")  # parsing pieces, no reader
    assert not any(m.startswith("sensor_models.readers.") and m not in shared
                   for m in _imported_modules(READERS / "_common.py"))


def test_read_manifest_dispatches_geo_staring(tmp_path):
    model = example_geo_staring_model(image_shape=(256, 256)).at_frame(10.0)
    path = write_geo_manifest(model, tmp_path / "frame.json")
    for read in (read_manifest, open_model):
        got = read(path)
        assert isinstance(got, GeoStaringModel)
        np.testing.assert_array_equal(got.parameters().values, read_geo_manifest(path).parameters().values)
        assert got.manifest_path == str(path)


def test_read_manifest_reads_pushbroom():
    model = read_manifest(EXAMPLE)
    assert isinstance(model, PushbroomModel)
    assert isinstance(open_model(EXAMPLE), PushbroomModel)


def test_pushbroom_builder_rejects_geo_document(tmp_path):
    with pytest.raises(ManifestError, match="sensor"):
        pushbroom_model_from_document({"format_version": 1, "sensor": "geo_staring"}, tmp_path / "x.json")
