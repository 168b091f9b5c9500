"""The ``calibration`` object of a manifest: what the calibration that wrote a model achieved."""

from __future__ import annotations

import json

import pytest

from sensor_models.base import CalibrationStatus
from sensor_models.errors import InputError, ManifestError
from sensor_models.readers import open_model
from sensor_models.readers.manifest import write_manifest

FIXTURE = "fixtures/hy1c_czi/manifest.json"


def test_lab_model_has_no_status_and_its_manifest_is_unchanged(tmp_path):
    model = open_model(FIXTURE)
    assert model.calibration is None
    write_manifest(model, tmp_path / "m.json")
    assert "calibration" not in json.loads((tmp_path / "m.json").read_text())


def test_status_round_trips(tmp_path):
    model = open_model(FIXTURE)
    model.calibration = CalibrationStatus(
        "partial", "camera 2 not estimable",
        uncalibrated=({"band": "B2", "ccd": "cam2_ccd1", "reason": "0 GCPs (DEM covers 0 % of the CCD)"},),
        unverified=({"band": "B2", "ccd": "cam2_ccd2", "reason": "no check points"},))
    write_manifest(model, tmp_path / "m.json")
    back = open_model(tmp_path / "m.json").calibration
    assert back == model.calibration
    assert back.usable and not CalibrationStatus("failed", "one GCP").usable


@pytest.mark.parametrize("bad, field", [
    ({"status": "maybe"}, "calibration.status"),
    ({"status": "failed", "extra": 1}, "calibration"),
    ({"status": "failed", "uncalibrated": 3}, "calibration.uncalibrated"),
    ({"status": "failed", "uncalibrated": [3]}, "calibration.uncalibrated[0]"),
    ({"message": "no status"}, "calibration.status"),
])
def test_bad_status_names_the_field(tmp_path, bad, field):
    doc = json.loads(open(FIXTURE).read())
    doc["calibration"] = bad
    (tmp_path / "m.json").write_text(json.dumps(doc))
    with pytest.raises(ManifestError) as err:
        open_model(tmp_path / "m.json")
    assert f"field '{field}'" in str(err.value)


def test_unknown_status_value_is_refused_in_code():
    with pytest.raises(InputError):
        CalibrationStatus("done")
