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
    from sensor_models.readers import open_scene

    assert open_scene(path).source == path


def test_read_manifest_reads_pushbroom():
    model = read_manifest(EXAMPLE)
    assert isinstance(model, PushbroomModel)
    assert isinstance(open_model(EXAMPLE), PushbroomModel)


def test_pushbroom_builder_rejects_geo_document(tmp_path):
    with pytest.raises(ManifestError, match="sensor"):
        pushbroom_model_from_document({"format_version": 1, "sensor": "geo_staring"}, tmp_path / "x.json")


# ----------------------------------------------------------------- the Scene value of open_scene


def test_open_scene_of_a_manifest_is_a_scene_with_its_rasters():
    from sensor_models.readers import open_scene
    from sensor_models.readers.scene_value import Scene

    scene = open_scene(EXAMPLE)
    assert isinstance(scene, Scene) and isinstance(scene.model, PushbroomModel)
    assert scene.source == EXAMPLE and scene.crop is None and scene.product_check is None and scene.metadata is None
    assert scene.raster_candidates == () and scene.raster_tiles == 0
    for band, ref in scene.rasters.items():
        assert scene.raster_of(band) == (ref["path"], int(ref.get("index", 1)))
    assert scene.raster_of("no such band") is None
    with pytest.raises(AttributeError):
        scene.model = None  # frozen


def test_open_scene_of_an_rpc_crop_says_where_the_crop_lies(shared_data):
    import rasterio

    from sensor_models.readers import open_scene

    raster = shared_data / "pleiades_ventoux" / "right_image.tif"
    scene = open_scene(raster)
    full = open_model(shared_data / "pleiades_ventoux" / "right_image.geom")
    with rasterio.open(raster) as ds:
        shape, transform = (ds.height, ds.width), ds.transform
    assert scene.source == raster and scene.product_check is None
    assert tuple(scene.model.image_shape) == shape != tuple(full.image_shape)
    assert scene.crop == (float(transform.f), float(transform.c), tuple(full.image_shape))
    assert scene.raster_of() == (str(raster.resolve()), 1)


def test_open_scene_of_a_dimap_product_carries_its_self_check(shared_data, tmp_path):
    from sensor_models.readers import open_scene

    dim = tmp_path / "METADATA.DIM"
    dim.symlink_to(shared_data / "spot_dimap" / "SPOT1.DIM")
    scene = open_scene(dim)
    assert scene.source == dim and scene.crop is None and scene.rasters == {}
    assert scene.raster_candidates == (str(tmp_path / "IMAGERY.TIF"),)
    assert scene.product_check is not None and scene.product_check.passed
    assert scene.raster_of() is None
    # what the reader parsed and fitted comes with the Scene, not on the model
    from sensor_models.readers.dimap import read_dimap_checked
    from sensor_models.readers.dimap_parse import parse_dimap

    parsed = parse_dimap(dim)
    assert scene.metadata.parsed.n_rows == parsed.n_rows == scene.model.n_rows
    assert list(scene.metadata.look_fits) == list(scene.model.bands) == ["B1"]
    assert scene.metadata.extension_s is None and scene.metadata.fold is None
    assert read_dimap_checked(dim).metadata.look_fits["B1"].max_residual_px == \
        scene.metadata.look_fits["B1"].max_residual_px
    assert not {"dimap_metadata", "dimap_fits"} & set(vars(scene.model))


#: Provenance attributes once hung on models after construction; a Scene carries them now (the
#: vendor readers' parsed files and fits: ``Scene.metadata``, a ``ProductMetadata``).
PROVENANCE = {"rasters", "raster_candidates", "raster_tiles", "crop_of_full_scene", "manifest_path", "product_check",
              "dimap_metadata", "dimap_fits", "dimap_v2_metadata", "dimap_v2_extension_s", "worldview_metadata",
              "worldview_fold"}
#: Where a model still gets one: nowhere (the readers return their rasters and self-checks).
STILL_HUNG: set = set()


def test_no_code_hangs_provenance_on_a_model():
    """No ``X.rasters = ...`` and the like in the packages (:data:`STILL_HUNG` is empty), and no
    ``getattr``/``hasattr``/``setattr`` of those names anywhere outside the tests."""
    root = READERS.parents[1]
    found, probed = set(), set()
    for package in ("sensor_models", "gcpmatch", "calibrate", "bench", "fixtures"):
        for path in sorted((root / package).rglob("*.py")):
            where = path.relative_to(root).as_posix()
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                targets = node.targets if isinstance(node, ast.Assign) else \
                    [node.target] if isinstance(node, (ast.AnnAssign, ast.AugAssign)) else []
                for target in targets:
                    for t in (target.elts if isinstance(target, ast.Tuple) else [target]):
                        if isinstance(t, ast.Attribute) and t.attr in PROVENANCE:
                            found.add((where, t.attr))
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                        and node.func.id in ("getattr", "hasattr", "setattr") and len(node.args) >= 2
                        and isinstance(node.args[1], ast.Constant) and node.args[1].value in PROVENANCE):
                    probed.add((where, node.func.id, node.args[1].value))
    assert found <= STILL_HUNG, sorted(found - STILL_HUNG)
    assert not probed, sorted(probed)
