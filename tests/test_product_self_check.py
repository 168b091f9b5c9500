"""Vendor readers check their model against the product's own statements, and refuse a mismatch.

Every product in ``../shared/data`` passes its reader's self-check with the figures below
(bracketed from both sides: a check that measured nothing would fail the lower bound). Edited
copies in ``tmp_path`` carry the wrong conventions a reader can make, and each must be refused:

* the line dating one line period late (the time tag moved by one ``LINE_PERIOD``);
* the attitude read in the wrong order or direction (quaternions scalar-first read as
  scalar-last; SPOT 5's roll and pitch taken about +X, +Y instead of the file's reversed axes);
* a stated corner moved by about 100 m.

``self_check="warn"`` proceeds and records the disagreement; an unknown DigitalGlobe satellite id
is refused naming it; a known one whose conventions gcpcal has not seen on a real product is
accepted when its own product confirms them and refused, naming it, when not.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from sensor_models.errors import InputError, ManifestError, ProductDisagreementError
from sensor_models.readers import open_model, open_scene
from sensor_models.readers.dimap import read_dimap, read_dimap_checked
from sensor_models.readers.dimap_v2 import (build_dimap_v2, build_dimap_v2_checked, parse_dimap_v2, read_dimap_v2,
                                            read_dimap_v2_checked)
from sensor_models.readers.worldview import read_worldview, read_worldview_checked
from sensor_models.readers.rpc_files import write_rpc

#: the measured figures on every shared product: (comparison, statistic) -> (low, high) metres;
#: measured WV2 corners 0.050 max, RPB 0.111 rms; WV3 0.105, 0.168; SPOT6 frame 0.0041; SPOT 1-5
#: frames 0.87, 0.94, 1.21, 1.59, 0.055 (docs/worldview.md, dimap_v2.md, dimap.md)
FIGURES = {
    "WV2": {"corners": (0.02, 0.10), "rpc_grid": (0.06, 0.20)},
    "WV3": {"corners": (0.05, 0.20), "rpc_grid": (0.10, 0.25)},
    "SPOT6": {"frame": (0.001, 0.02)},
    "SPOT1": {"frame": (0.5, 1.5)},
    "SPOT2": {"frame": (0.5, 1.5)},
    "SPOT3": {"frame": (0.7, 2.0)},
    "SPOT4": {"frame": (1.0, 2.5)},
    "SPOT5": {"frame": (0.02, 0.15)},
}
#: tolerances: (low, high) metres; DigitalGlobe from the RPB's ERRRAND (0.26 m, 0.20 m), the
#: others half a ground pixel
TOLERANCES = {
    "WV2": (0.36, 0.40), "WV3": (0.28, 0.32), "SPOT6": (0.78, 0.84), "SPOT1": (6.0, 7.0),
    "SPOT2": (4.8, 5.3), "SPOT3": (4.8, 5.5), "SPOT4": (4.8, 5.5), "SPOT5": (2.4, 2.7),
}


def product_path(shared_data, name):
    if name.startswith("WV") or name == "SPOT6":
        return shared_data / "products" / f"{name}.XML"
    return shared_data / "spot_dimap" / f"{name}.DIM"


def edited(src, dst, *replacements):
    """A copy of ``src`` at ``dst`` with each ``(old, new)`` replaced once (each must be there)."""
    text = src.read_text()
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new, 1)
    dst.write_text(text)
    return dst


def later(iso: str, seconds: float) -> str:
    """An ISO time string moved by ``seconds`` (microseconds kept, the trailing Z kept)."""
    z = "Z" if iso.endswith("Z") else ""
    t = np.datetime64(iso.rstrip("Z"), "ns") + np.timedelta64(int(round(seconds * 1e9)), "ns")
    return str(t.astype("datetime64[us]")) + z


def tag_text(text: str, tag: str) -> str:
    return re.search(f"<{tag}>([^<]*)</{tag}>", text).group(1)


# --------------------------------------------------------------------------------------------- every product


@pytest.mark.parametrize("name", list(FIGURES))
def test_every_shared_product_passes_its_self_check(shared_data, name):
    path = product_path(shared_data, name)
    if not path.is_file():
        pytest.skip(f"{path} not found")
    check = open_scene(path).product_check
    assert check.passed and check.policy == "refuse"
    assert check.satellite == {"WV2": "WV02", "WV3": "WV03"}.get(name, name)
    got = {c.name: c for c in check.comparisons}
    assert set(got) == set(FIGURES[name])
    for key, (low, high) in FIGURES[name].items():
        assert low < got[key].value_m < high, (key, got[key].text())
    lo, hi = TOLERANCES[name]
    assert all(lo < c.tolerance.metres < hi for c in check.comparisons), [c.tolerance for c in check.comparisons]
    doc = check.to_dict()
    assert doc["passed"] and doc["disagreement"] is None and doc["comparisons"][0]["tolerance_source"]


def test_spot1_4_frames_are_checked_with_the_nominal_attitude(shared_data):
    path = product_path(shared_data, "SPOT3")
    measured = read_dimap_checked(path)[1]
    nominal = read_dimap_checked(path, attitude="nominal")[1]
    assert measured.comparisons[0].max_m == pytest.approx(nominal.comparisons[0].max_m, abs=1e-9)
    # the model as opened (measured AOCS attitude) lies 24 m from the frame: noted, not hidden
    note = [n for n in measured.notes if "as opened" in n]
    assert note and 20.0 < float(re.search(r"lies ([\d.]+) m", note[0]).group(1)) < 30.0


# --------------------------------------------------------------------------------------------- DigitalGlobe


@pytest.mark.parametrize("name", ["WV2", "WV3"])
def test_worldview_one_line_late_is_refused(shared_data, tmp_path, name):
    src = product_path(shared_data, name)
    text = src.read_text()
    period = 1.0 / float(tag_text(text, "AVGLINERATE"))
    first, tlc = tag_text(text, "FIRSTLINETIME"), tag_text(text, "TLCTIME")
    bad = edited(src, tmp_path / f"{name}.XML",
                 (f"<FIRSTLINETIME>{first}</FIRSTLINETIME>", f"<FIRSTLINETIME>{later(first, period)}</FIRSTLINETIME>"),
                 (f"<TLCTIME>{tlc}</TLCTIME>", f"<TLCTIME>{later(tlc, period)}</TLCTIME>"))
    with pytest.raises(ProductDisagreementError) as info:
        read_worldview(bad)
    msg = str(info.value)
    assert str(bad) in msg and f"of {name[:2]}0{name[2]}" in msg and "\n" not in msg
    assert "IMD corners" in msg and "vendor RPC" in msg and "self_check='warn'" in msg


def _quaternions_scalar_first(text: str) -> str:
    def swap(m):
        v = m.group(1).split()
        return "<ATTLIST>" + " ".join([v[0], v[4], v[1], v[2], v[3]] + v[5:]) + "</ATTLIST>"

    return re.sub(r"<ATTLIST>([^<]*)</ATTLIST>", swap, text)


@pytest.mark.parametrize("name", ["WV2", "WV3"])
def test_worldview_quaternion_order_swapped_is_refused(shared_data, tmp_path, name):
    bad = tmp_path / f"{name}.XML"
    bad.write_text(_quaternions_scalar_first(product_path(shared_data, name).read_text()))
    with pytest.raises(ProductDisagreementError, match="misses the Earth|lines of sight miss") as info:
        read_worldview(bad)
    assert info.value.path == str(bad)
    # the inverse rotation (the conjugate quaternion): off the Earth (WV2) or 1 300 km away (WV3)
    text = product_path(shared_data, name).read_text()

    def conj(m):
        v = m.group(1).split()
        return "<ATTLIST>" + " ".join([v[0]] + [repr(-float(x)) for x in v[1:4]] + v[4:]) + "</ATTLIST>"

    inverse = tmp_path / f"{name}_inverse.XML"
    inverse.write_text(re.sub(r"<ATTLIST>([^<]*)</ATTLIST>", conj, text))
    with pytest.raises(ProductDisagreementError, match=r"misses the Earth|IMD corners at their HAE \(P\): \d{6,} m max"):
        read_worldview(inverse)


def _corner_moved(src, dst, metres=100.0):
    text = src.read_text()
    lon, lat = tag_text(text, "ULLON"), tag_text(text, "ULLAT")
    moved = float(float(lon) + metres / (111_319.49 * np.cos(np.radians(float(lat)))))
    return edited(src, dst, (f"<ULLON>{lon}</ULLON>", f"<ULLON>{moved!r}</ULLON>"))


def test_worldview_corner_moved_100_m_is_refused_and_warn_records_it(shared_data, tmp_path):
    bad = _corner_moved(product_path(shared_data, "WV2"), tmp_path / "WV2.XML")
    with pytest.raises(ProductDisagreementError, match=r"IMD corners at their HAE \(P\): (9\d|10\d)(\.\d+)? m max") as info:
        open_model(bad)
    assert "vendor RPC" not in str(info.value)  # the RPB still agrees: only the corners are named
    check = open_scene(bad, self_check="warn").product_check
    assert not check.passed and check.policy == "warn"
    doc = check.to_dict()
    corners = doc["comparisons"][0]
    assert not corners["passed"] and 95.0 < corners["max_m"] < 105.0 and doc["comparisons"][1]["passed"]
    assert "IMD corners" in doc["disagreement"] and doc["satellite"] == "WV02"


def test_worldview_satellites_named_when_refused(shared_data, tmp_path):
    src = product_path(shared_data, "WV2")
    # an id gcpcal does not know: refused before anything is built, naming it and the field
    unknown = edited(src, tmp_path / "XX.XML", ("<SATID>WV02</SATID>", "<SATID>XX07</SATID>"))
    with pytest.raises(ManifestError, match="'XX07'") as info:
        read_worldview(unknown)
    assert info.value.field == "isd/IMD/IMAGE/SATID"
    with pytest.raises(ManifestError, match="'XX07'"):
        read_worldview(unknown, self_check="warn")
    # a DigitalGlobe satellite never seen on a real product: its own statements decide
    qb = edited(src, tmp_path / "QB.XML", ("<SATID>WV02</SATID>", "<SATID>QB02</SATID>"))
    confirmed = read_worldview_checked(qb).check
    assert confirmed.passed and any("QB02" in n for n in confirmed.notes)
    ge = _corner_moved(edited(src, tmp_path / "GE.XML", ("<SATID>WV02</SATID>", "<SATID>GE01</SATID>")),
                       tmp_path / "GE_moved.XML")
    with pytest.raises(ProductDisagreementError, match="GE01.*does not confirm them for GE01 \\(GeoEye-1\\)"):
        read_worldview(ge)


def test_bad_self_check_option(shared_data):
    with pytest.raises(InputError, match="self_check"):
        read_worldview(product_path(shared_data, "WV3"), self_check="ignore")


# --------------------------------------------------------------------------------------------- SPOT 1-5 DIMAP


@pytest.mark.parametrize("name", ["SPOT1", "SPOT5"])
def test_dimap_one_line_late_is_refused(shared_data, tmp_path, name):
    src = product_path(shared_data, name)
    text = src.read_text()
    t, period = tag_text(text, "SCENE_CENTER_TIME"), float(tag_text(text, "LINE_PERIOD"))
    bad = edited(src, tmp_path / f"{name}.DIM",
                 (f"<SCENE_CENTER_TIME>{t}</SCENE_CENTER_TIME>", f"<SCENE_CENTER_TIME>{later(t, period)}</SCENE_CENTER_TIME>"))
    with pytest.raises(ProductDisagreementError, match=f"SPOT 1-5 DIMAP product of {name}.*frame vertices") as info:
        read_dimap(bad)
    value = float(re.search(r"\): ([\d.]+) m max", str(info.value)).group(1))
    ground_line = {"SPOT1": 10.0, "SPOT5": 5.0}[name]  # one line on the ground, about the along-track GSD
    assert 0.6 * ground_line < value < 1.5 * ground_line


def test_dimap_reversed_attitude_axes_are_refused(shared_data, tmp_path):
    """SPOT 5's roll and pitch are about the reversed -X, -Y axes; reading them about +X, +Y misses by ~1 km."""
    src = product_path(shared_data, "SPOT5")
    text = src.read_text()
    start, end = text.index("<Corrected_Attitudes>"), text.index("</Corrected_Attitudes>")

    def negate(m):
        return f"<{m.group(1)}>{-float(m.group(2))!r}</{m.group(1)}>"

    block = re.sub(r"<(PITCH|ROLL)>([^<]*)</\1>", negate, text[start:end])
    bad = tmp_path / "SPOT5.DIM"
    bad.write_text(text[:start] + block + text[end:])
    with pytest.raises(ProductDisagreementError, match=r"frame vertices.*: \d{3,4}(\.\d+)? m max"):
        read_dimap(bad)


def test_dimap_vertex_moved_100_m_is_refused_and_warn_records_it(shared_data, tmp_path):
    src = product_path(shared_data, "SPOT5")
    text = src.read_text()
    lon, lat = tag_text(text, "FRAME_LON"), tag_text(text, "FRAME_LAT")
    moved = float(lon) + 100.0 / (111_319.49 * np.cos(np.radians(float(lat))))
    bad = edited(src, tmp_path / "SPOT5.DIM", (f"<FRAME_LON>{lon}</FRAME_LON>", f"<FRAME_LON>{moved:.10e}</FRAME_LON>"))
    with pytest.raises(ProductDisagreementError, match=r"frame vertices.*: (9\d|10\d)(\.\d+)? m max"):
        open_model(bad)
    check = open_scene(bad, self_check="warn").product_check
    assert not check.passed and 95.0 < check.comparisons[0].max_m < 105.0
    assert "frame vertices" in check.to_dict()["disagreement"]


# --------------------------------------------------------------------------------------------- DIMAP v2


def test_dimap_v2_one_line_late_is_refused(shared_data):
    """Lines dated one line later against the ephemeris and attitude (their tags moved one period earlier)."""
    meta = parse_dimap_v2(product_path(shared_data, "SPOT6"))
    lp = meta.line_period_s
    late = dataclasses.replace(meta, ephemeris_seconds=meta.ephemeris_seconds - lp,
                               attitude_seconds=meta.attitude_seconds - lp)
    with pytest.raises(ProductDisagreementError, match=r"DIMAP v2 product of SPOT6.*Dataset_Extent.*: 1\.\d+ m max"):
        build_dimap_v2(late)
    assert build_dimap_v2_checked(meta)[1].passed


def test_dimap_v2_quaternion_order_swapped_is_refused(shared_data, tmp_path):
    text = product_path(shared_data, "SPOT6").read_text()
    swapped = re.sub(r"<Q0>([^<]*)</Q0>(.*?)<Q3>([^<]*)</Q3>", r"<Q0>\3</Q0>\2<Q3>\1</Q3>", text, flags=re.S)
    assert swapped != text
    bad = tmp_path / "SPOT6.XML"
    bad.write_text(swapped)
    # the rotation lands the rays hundreds of km away at any height (here the search's 9 000 m bound)
    with pytest.raises(ProductDisagreementError, match=r"Dataset_Extent.*: \d{6,} m max"):
        read_dimap_v2(bad)


def test_dimap_v2_vertex_moved_100_m_is_refused_and_warn_records_it(shared_data, tmp_path):
    src = product_path(shared_data, "SPOT6")
    text = src.read_text()
    lon, lat = tag_text(text, "LON"), tag_text(text, "LAT")
    moved = float(lon) + 100.0 / (111_319.49 * np.cos(np.radians(float(lat))))
    bad = edited(src, tmp_path / "SPOT6.XML", (f"<LON>{lon}</LON>", f"<LON>{moved:.9f}</LON>"))
    # one vertex 100 m off: the best common height cannot absorb it (the misses stay tens of metres)
    with pytest.raises(ProductDisagreementError, match=r"Dataset_Extent.*: \d{2,3}(\.\d+)? m max"):
        read_dimap_v2(bad)
    check = read_dimap_v2_checked(bad, self_check="warn")[1]
    assert not check.passed and 30.0 < check.comparisons[0].max_m < 100.0


# --------------------------------------------------------------------------------------------- the CLI

#: the commands that open a user's scene, which may be a vendor product
PRODUCT_COMMANDS = ("calibrate", "match", "relative", "localize", "ortho", "rpc", "run")


def test_every_command_opening_a_product_offers_the_option():
    from calibrate.cli import load_all_commands

    commands = load_all_commands()
    for name in PRODUCT_COMMANDS:
        options = {o for p in commands[name].params for o in getattr(p, "opts", ())}
        assert "--accept-product-disagreement" in options, name


def test_cli_refuses_in_one_line_and_the_option_records_the_disagreement(shared_data, tmp_path, capsys):
    import json

    from calibrate.cli import main

    bad = _corner_moved(product_path(shared_data, "WV3"), tmp_path / "WV3.XML")
    argv = ["localize", str(bad), "--rows", "100", "--cols", "200", "--height", "1000"]
    assert main(argv) == 1
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"gcpcal: error: {bad}: DigitalGlobe XML product of WV03")
    assert "IMD corners" in lines[0] and "--accept-product-disagreement" in lines[0]
    out = tmp_path / "points.csv"
    assert main([*argv, "--accept-product-disagreement", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "gcpcal: warning:" in err and "WV03" in err
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    check = summary["product_check"]
    assert check["policy"] == "warn" and not check["passed"] and check["satellite"] == "WV03"
    corners = check["comparisons"][0]
    assert corners["name"] == "corners" and 95.0 < corners["max_m"] < 105.0 and corners["tolerance_m"] < 0.5
    assert any("IMD corners" in w for w in summary["warnings"])
    # an agreeing product: its check is recorded too, with no warning
    good = tmp_path / "good.csv"
    assert main(["localize", str(product_path(shared_data, "WV3")), "--rows", "100", "--cols", "200", "--height",
                 "1000", "--out", str(good)]) == 0
    summary = json.loads(good.with_suffix(".summary.json").read_text())
    assert summary["product_check"]["passed"] and summary["warnings"] == []


def test_dimap_v2_compares_an_rpc_given_with_the_product(shared_data, tmp_path):
    """The product's own RPC_*.XML is not in the shared data: an RPC fitted to the rigorous model
    (written as _RPC.TXT) agrees; one fitted to the model one line late, or another product's
    RPC (the Pleiades Ventoux .geom), is refused."""
    from sensor_models.models.rpc_fit import fit_rpc

    meta = parse_dimap_v2(product_path(shared_data, "SPOT6"))
    model = build_dimap_v2(meta)
    rpc, _ = fit_rpc(model, height_range_m=(500.0, 1200.0), grid_shape=(11, 11, 4))
    path = write_rpc(rpc, tmp_path / "SPOT6_RPC.TXT")
    check = read_dimap_v2_checked(meta.path, rpc=path)[1]
    rpc_cmp = {c.name: c for c in check.comparisons}["rpc_grid"]
    assert check.passed and rpc_cmp.n_points == 605 and 0.0 < rpc_cmp.rms_m < 0.05
    assert 0.78 < rpc_cmp.tolerance.metres < 0.84  # no ERR_RAND stated: half a ground pixel
    lp = meta.line_period_s
    late = build_dimap_v2(dataclasses.replace(meta, ephemeris_seconds=meta.ephemeris_seconds - lp,
                                              attitude_seconds=meta.attitude_seconds - lp), self_check="warn")
    late_rpc, _ = fit_rpc(late, height_range_m=(500.0, 1200.0), grid_shape=(11, 11, 4))
    with pytest.raises(ProductDisagreementError, match=r"vendor RPC over 11\^2 pixels x 5 heights.*: 1\.\d+ m rms"):
        read_dimap_v2(meta.path, rpc=late_rpc)
    ventoux = shared_data / "pleiades_ventoux" / "left_image.geom"
    if ventoux.is_file():
        with pytest.raises(ProductDisagreementError, match="vendor RPC"):
            read_dimap_v2(meta.path, rpc=ventoux)
