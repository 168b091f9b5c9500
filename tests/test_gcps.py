"""GCP tables: the GcpTable type, strict CSV reading, and CSV / GeoPackage / GeoTIFF round trips.

GeoPackage files are checked against the OGC GeoPackage 1.3 layout with sqlite3 and read back
by GDAL through pyogrio (skipped when pyogrio is absent); GeoTIFF GCPs are read back by GDAL
through rasterio.
"""

from __future__ import annotations

import hashlib
import sqlite3
import struct

import numpy as np
import pytest

from gcpmatch import gcp_csv as gcp_csv_module
from gcpmatch import gcps as gcps_module
from gcpmatch.gcp_csv import write_gcps_csv
from gcpmatch.gcp_files import read_gcps
from gcpmatch.gcp_geotiff import GEOTIFF_MAX_GCPS, write_gcps_geotiff
from gcpmatch.gcps import COLUMNS, GcpTable
from gcpmatch.geopackage import write_gcps_gpkg
from sensor_models.errors import InputError

HEADER = "id,row,col,lon,lat,h"


def make_table(n=200, seed=0, **kw) -> GcpTable:
    """Random points inside a 1000 x 2000 image, full-precision floats, two bands and CCDs."""
    rng = np.random.default_rng(seed)
    args = dict(
        band=np.where(rng.random(n) < 0.5, "B1", "B2"),
        ccd=np.where(rng.random(n) < 0.5, "1", "2"),
        sigma_px=rng.uniform(0.1, 2.0, n),
        score=rng.random(n),
        kind=np.where(rng.random(n) < 0.2, "check", "gcp"),
    )
    args.update(kw)
    return GcpTable.from_arrays(rng.uniform(0, 1000, n), rng.uniform(0, 2000, n),
                                rng.uniform(-180, 360, n) * (1 - 1e-12), rng.uniform(-90, 90, n),
                                rng.uniform(-400, 9000, n), **args)  # fmt: skip


def assert_same(a: GcpTable, b: GcpTable):
    """Column-by-column equality, floats bit for bit."""
    assert len(a) == len(b)
    for name in COLUMNS:
        x, y = getattr(a, name), getattr(b, name)
        if x.dtype.kind == "f":
            assert y.dtype == np.float64
            np.testing.assert_array_equal(x.view(np.int64), y.view(np.int64), err_msg=name)
        else:
            assert x.tolist() == y.tolist(), name


def write_text(path, text, encoding="utf-8"):
    path.write_bytes(text.encode(encoding))
    return path


def raises_input(match_parts, func, *args, **kwargs) -> str:
    """Call ``func``; it must raise InputError whose message contains every part."""
    with pytest.raises(InputError) as info:
        func(*args, **kwargs)
    msg = str(info.value)
    assert "\n" not in msg
    for part in match_parts:
        assert part in msg, (part, msg)
    return msg


# ---------------------------------------------------------------------------------------------
# The table type
# ---------------------------------------------------------------------------------------------
def test_from_arrays_defaults_ids_and_read_only():
    t = GcpTable.from_arrays([0.5, 1.5, 2.5], [3, 4, 5], [5.0, 5.1, 5.2], [44, 44.1, 44.2], 0.0)
    assert t.id.tolist() == ["g000001", "g000002", "g000003"]
    assert t.sigma_px.tolist() == [1.0] * 3 and t.score.tolist() == [1.0] * 3
    assert t.band.tolist() == [""] * 3 and t.ccd.tolist() == [""] * 3
    assert t.kind.tolist() == ["gcp"] * 3 and t.h.tolist() == [0.0] * 3
    assert t.row.dtype == np.float64 and t.id.dtype.kind == "U" and len(t) == 3
    with pytest.raises(ValueError):
        t.row[0] = 7.0
    assert repr(t) == "GcpTable(3 points: 3 gcp, 0 check)"
    t2 = GcpTable.from_arrays([1], [1], [0], [0], [0], ccd=[3], band="pan", kind="check")
    assert t2.ccd.tolist() == ["3"] and t2.band.tolist() == ["pan"] and len(t2.checks()) == 1


@pytest.mark.parametrize(
    "kw, field, part",
    [
        (dict(lat=[95.0]), "lat", "outside [-90, 90]"),
        (dict(lon=[360.0]), "lon", "outside [-180, 360)"),
        (dict(h=[np.nan]), "h", "NaN"),
        (dict(sigma_px=[0.0]), "sigma_px", "> 0"),
        (dict(kind=["CHECK"]), "kind", "'gcp' or 'check'"),
        (dict(id=[""]), "id", "empty id"),
        (dict(band=[" B1"]), "band", "leading or trailing spaces"),
        (dict(ccd=[1.5]), "ccd", "cannot be converted to text"),
        (dict(col=[1.0, 2.0]), "col", "shape"),
    ],
)
def test_constructor_rejects_bad_values(kw, field, part):
    base = dict(row=[1.0], col=[2.0], lon=[5.0], lat=[44.0], h=[100.0])
    base.update({k: v for k, v in kw.items() if k in base})
    opt = {k: v for k, v in kw.items() if k not in base}
    msg = raises_input([f"field '{field}'", part], GcpTable.from_arrays, **base, **opt)
    assert "point 0" in msg or part in ("shape", "cannot be converted to text")


def test_duplicate_ids_name_both_points():
    raises_input(["field 'id'", "point 2", "point 0", "'a'"], GcpTable.from_arrays,
                 [1, 2, 3], [1, 2, 3], [5, 5, 5], [44, 44, 44], 0, id=["a", "b", "a"])  # fmt: skip


def test_select_subsets_and_concatenate():
    t = make_table(50)
    assert len(t.gcps()) + len(t.checks()) == 50
    assert set(t.gcps().kind.tolist()) == {"gcp"} and set(t.checks().kind.tolist()) == {"check"}
    sub = t.select(np.arange(50) % 2 == 0)
    assert sub.id.tolist() == t.id[::2].tolist()
    assert t.select([3, 1]).id.tolist() == [t.id[3], t.id[1]]
    raises_input(["field 'id'", "already used"], t.select, [1, 1])
    raises_input(["mask has shape"], t.select, np.ones(3, dtype=bool))
    both = GcpTable.concatenate([t.select(np.arange(20)), t.select(np.arange(20, 50))])
    assert_same(both, t)
    raises_input(["field 'id'", "already used"], GcpTable.concatenate, [t, t])


def test_hilbert_key_is_a_continuous_curve():
    order = 3
    side = 2**order
    rr, cc = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    key = gcps_module._hilbert_key(rr.ravel() + 0.5, cc.ravel() + 0.5, order=order)
    assert sorted(key.tolist()) == list(range(side * side))  # a bijection onto the cells
    path = np.argsort(key)
    steps = np.abs(np.diff(rr.ravel()[path])) + np.abs(np.diff(cc.ravel()[path]))
    assert np.all(steps == 1)  # consecutive keys are edge neighbours


def test_split_check_counts_per_stratum_and_reproducible():
    t = make_table(1001, seed=3)
    s = t.split_check(0.25, seed=7)
    for band in ("B1", "B2"):
        for ccd in ("1", "2"):
            m = (t.band == band) & (t.ccd == ccd)
            n_check = int(np.count_nonzero(s.kind[m] == "check"))
            assert n_check == int(np.floor(0.25 * m.sum() + 0.5))
    for name in ("id", "row", "col", "lon", "lat", "h", "band", "ccd", "sigma_px", "score"):
        assert np.array_equal(getattr(s, name), getattr(t, name))
    assert np.array_equal(t.split_check(0.25, seed=7).kind, s.kind)
    assert not np.array_equal(t.split_check(0.25, seed=8).kind, s.kind)
    assert len(t.split_check(0.0, seed=1).checks()) == 0
    tiny = GcpTable.from_arrays([1, 2], [1, 2], [5, 5], [44, 44], 0)
    assert len(tiny.split_check(0.9, seed=0).gcps()) == 1  # every stratum keeps a GCP
    raises_input(["fraction"], t.split_check, 1.0, seed=0)
    raises_input(["stratify_by"], t.split_check, 0.1, seed=0, stratify_by=("kind",))


def test_split_check_is_spatially_even():
    """Checks fill a 4 x 4 grid of cells much more evenly than a binomial draw would."""
    rng = np.random.default_rng(11)
    n = 4000
    t = GcpTable.from_arrays(rng.uniform(0, 1000, n), rng.uniform(0, 1000, n),
                             np.full(n, 5.0), np.full(n, 44.0), 0.0)  # fmt: skip
    s = t.split_check(0.1, seed=5, stratify_by=())
    chk = s.kind == "check"
    assert chk.sum() == 400
    cell = (s.row // 250).astype(int) * 4 + (s.col // 250).astype(int)
    per_cell = np.bincount(cell[chk], minlength=16) / np.bincount(cell, minlength=16)
    # stratified along the Hilbert curve: every cell within 2 points of 10 %; a plain random
    # 10 % draw has a standard deviation of ~1.9 % per cell here (binomial, 250 points).
    assert np.all(np.abs(per_cell - 0.1) < 0.02), per_cell
    random_draw = rng.random(n) < 0.1
    spread_random = np.std(np.bincount(cell[random_draw], minlength=16))
    spread_split = np.std(np.bincount(cell[chk], minlength=16))
    assert spread_split < 0.5 * spread_random


# ---------------------------------------------------------------------------------------------
# CSV
# ---------------------------------------------------------------------------------------------
def test_csv_round_trip_is_bit_exact_with_awkward_text(tmp_path):
    t = make_table(300)
    ids = t.id.astype(object)
    ids[:5] = ["a,b", 'say "hi"', "multi\nline", "ünïcødé", "tab\tinside"]
    h = t.h.copy()
    h[:4] = [5e-324, 1e-300, 1.7976931348623157e308, -0.0]
    cols = t.as_dict()
    cols.update(id=ids, h=h)
    t = GcpTable(**cols)
    p = write_gcps_csv(t, tmp_path / "g.csv")
    assert p == tmp_path / "g.csv"
    assert p.read_text(encoding="utf-8").startswith(",".join(COLUMNS) + "\n")
    back = read_gcps(p)
    assert_same(back, t)
    assert np.signbit(back.h[3])


def test_csv_round_trip_plain_path_several_chunks(tmp_path):
    n = 2 * gcp_csv_module._CHUNK_ROWS + 3
    t = make_table(n, seed=5)
    p = write_gcps_csv(t, tmp_path / "big.csv")
    assert b'"' not in p.read_bytes()  # the vectorized (quote-free) reader
    assert_same(read_gcps(p), t)


def test_csv_minimal_hand_written_file(tmp_path):
    text = ("\ufeffid, row, col ,lon,lat,h\r\n"
            "p1, 10.5, 20.25, 5.5, 44.25, 310\r\n"
            "\r\n"
            " p2 ,0,2000,-180,-90,-12.5\r\n")  # fmt: skip
    t = read_gcps(write_text(tmp_path / "m.csv", text), image_shape=(1000, 2000))
    assert t.id.tolist() == ["p1", "p2"]
    assert t.row.tolist() == [10.5, 0.0] and t.col.tolist() == [20.25, 2000.0]
    assert t.lon.tolist() == [5.5, -180.0] and t.h.tolist() == [310.0, -12.5]
    assert t.sigma_px.tolist() == [1.0, 1.0] and t.kind.tolist() == ["gcp", "gcp"]
    assert t.band.tolist() == ["", ""]


def test_csv_quoted_path_matches_plain_path(tmp_path):
    rows = ["a,1.5,2.5,5.0,44.0,10,0.5,B1,1,0.9,check", "b,3.5,4.5,6.0,45.0,20,2,B2,2,0.1,gcp"]
    plain = read_gcps(write_text(tmp_path / "p.csv", ",".join(COLUMNS) + "\n" + "\n".join(rows)))
    quoted_rows = ['"' + r.replace(",", '","') + '"' for r in rows]
    quoted_text = ",".join(COLUMNS) + "\n" + "\n".join(quoted_rows) + "\n"
    quoted = read_gcps(write_text(tmp_path / "q.csv", quoted_text))
    assert_same(plain, quoted)
    assert plain.kind.tolist() == ["check", "gcp"] and plain.sigma_px.tolist() == [0.5, 2.0]


BAD_CSV = [
    # (name, text, line, column, phrase)
    ("missing column", "id,row,col,lon,lat\na,1,1,5,44\n", 1, "h", "missing required column"),
    ("unknown column", HEADER + ",foo\na,1,1,5,44,0,1\n", 1, "foo", "unknown column"),
    ("duplicate column", HEADER + ",lat\na,1,1,5,44,0,44\n", 1, "lat", "appears twice"),
    ("non-numeric", HEADER + "\na,1,1,5,44,0\nb,abc,1,5,44,0\n", 3, "row", "'abc' is not a number"),
    ("empty number", HEADER + "\na,1,1,5,44,0\nb,1,,5,44,0\n", 3, "col", "empty value"),
    ("nan", HEADER + "\na,1,1,5,44,nan\n", 2, "h", "NaN"),
    ("inf", HEADER + "\na,1,1,5,44,0\nb,1,1,-inf,44,0\n", 3, "lon", "NaN and infinity"),
    ("duplicate id", HEADER + "\na,1,1,5,44,0\nb,1,1,5,44,0\na,2,2,5,44,0\n", 4, "id",
     "already used at line 2"),
    ("lat range", HEADER + "\na,1,1,5,44,0\nb,1,1,5,90.0000001,0\n", 3, "lat", "outside [-90, 90]"),
    ("lon range", HEADER + "\na,1,1,360,44,0\n", 2, "lon", "outside [-180, 360)"),
    ("lon range low", HEADER + "\na,1,1,-180.5,44,0\n", 2, "lon", "outside [-180, 360)"),
    ("sigma zero", HEADER + ",sigma_px\na,1,1,5,44,0,1\nb,1,1,5,44,0,0\n", 3, "sigma_px", "> 0"),
    ("sigma negative", HEADER + ",sigma_px\na,1,1,5,44,0,-2\n", 2, "sigma_px", "> 0"),
    ("kind", HEADER + ",kind\na,1,1,5,44,0,gcp\nb,1,1,5,44,0,Check\n", 3, "kind",
     "'gcp' or 'check'"),
    ("empty id", HEADER + "\na,1,1,5,44,0\n,1,1,5,44,0\n", 3, "id", "empty id"),
]  # fmt: skip


@pytest.mark.parametrize("quoted", [False, True], ids=["plain", "quoted"])
@pytest.mark.parametrize("case", BAD_CSV, ids=[c[0] for c in BAD_CSV])
def test_csv_bad_input_names_file_line_and_column(tmp_path, case, quoted):
    name, text, line, column, phrase = case
    if quoted:  # the csv-module path: same messages
        text = text.replace("\na,", '\n"a",', 1)
    path = write_text(tmp_path / "bad.csv", text)
    raises_input([str(path), f"line {line}:", f"field '{column}'", phrase], read_gcps, path)


def test_csv_points_outside_image(tmp_path):
    text = HEADER + "\na,0,0,5,44,0\nb,1000,2000,5,44,0\nc,1000.001,5,5,44,0\nd,5,-0.5,5,44,0\n"
    path = write_text(tmp_path / "img.csv", text)
    assert len(read_gcps(path)) == 4
    raises_input([str(path), "line 4:", "field 'row'", "outside the image [0, 1000]"],
                 read_gcps, path, image_shape=(1000, 2000))  # fmt: skip
    raises_input(["line 3:", "field 'row'", "2 rows have this problem"], read_gcps, path,
                 image_shape=(999, 2000))  # fmt: skip
    raises_input(["line 3:", "field 'col'", "3 rows have this problem"], read_gcps, path,
                 image_shape=(1000, 4))  # fmt: skip
    path2 = write_text(tmp_path / "img2.csv", HEADER + "\na,0,0,5,44,0\nd,5,-0.5,5,44,0\n")
    raises_input(["line 3:", "field 'col'", "outside the image [0, 2000]"], read_gcps, path2,
                 image_shape=(1000, 2000))  # fmt: skip
    raises_input(["image_shape"], read_gcps, path, image_shape=(1000, 0))


def test_csv_reports_the_first_problem_in_file_order_with_a_count(tmp_path):
    text = HEADER + "\na,1,1,5,44,0\nb,1,1,5,99,0\nc,x,1,5,44,0\nd,1,1,5,-99,0\n"
    path = write_text(tmp_path / "two.csv", text)
    raises_input(["line 3:", "field 'lat'", "2 rows have this problem"], read_gcps, path)
    text = HEADER + "\na,1,1,5,44,0\nb,1,1,500,99,0\n"  # same line: lon comes before lat
    raises_input(["line 3:", "field 'lon'"], read_gcps, write_text(tmp_path / "t2.csv", text))
    text = HEADER + "\na,1,1,5,44,0\nb,1,1,5,x,0\nc,1,1,5,99,0\n"  # parse error first
    raises_input(["line 3:", "field 'lat'", "'x' is not a number"], read_gcps,
                 write_text(tmp_path / "t3.csv", text))  # fmt: skip
    text = HEADER + "\na,1,1,5,44,0\nb,1,1,5,99,0\nc,1,1,5,x,0\n"  # range error first
    raises_input(["line 3:", "field 'lat'", "outside"], read_gcps,
                 write_text(tmp_path / "t4.csv", text))  # fmt: skip


def test_csv_structural_errors(tmp_path):
    p = write_text(tmp_path / "empty.csv", "")
    raises_input([str(p), "empty file"], read_gcps, p)
    p = write_text(tmp_path / "header_only.csv", HEADER + "\n\n")
    raises_input([str(p), "no data rows"], read_gcps, p)
    p = write_text(tmp_path / "fields.csv", HEADER + "\na,1,1,5,44,0\nb,1,1,5,44\n")
    raises_input([str(p), "line 3:", "5 fields", "6 columns"], read_gcps, p)
    p = write_text(tmp_path / "fieldsq.csv", HEADER + '\n"a",1,1,5,44,0\nb,1,1,5,44,0,7\n')
    raises_input([str(p), "line 3:", "7 fields"], read_gcps, p)
    p = tmp_path / "latin1.csv"
    p.write_bytes((HEADER + "\na,1,1,5,44,0\n\xe9,1,1,5,44,0\n").encode("latin-1"))
    raises_input([str(p), "line 3:", "UTF-8"], read_gcps, p)
    raises_input(["cannot read"], read_gcps, tmp_path / "missing.csv")
    raises_input(["unknown GCP table format"], read_gcps, tmp_path / "g.txt")
    raises_input(["layer="], read_gcps, tmp_path / "g.csv", layer="x")


def test_csv_line_numbers_count_quoted_newlines_and_blank_lines(tmp_path):
    text = HEADER + '\n"multi\nline",1,1,5,44,0\n\nb,1,1,5,44,0\nc,1,1,5,91,0\n'
    p = write_text(tmp_path / "ml.csv", text)
    raises_input(["line 6:", "field 'lat'"], read_gcps, p)
    text = HEADER + "\r\n\r\na,1,1,5,44,0\r\n\r\nc,1,1,5,91,0\r\n"
    raises_input(["line 5:", "field 'lat'"], read_gcps, write_text(tmp_path / "crlf.csv", text))


# ---------------------------------------------------------------------------------------------
# GeoPackage
# ---------------------------------------------------------------------------------------------
def test_gpkg_round_trip_and_layout(tmp_path):
    t = make_table(120)
    p = write_gcps_gpkg(t, tmp_path / "g.gpkg")
    assert_same(read_gcps(p), t)
    con = sqlite3.connect(p)
    try:
        assert con.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47
        assert con.execute("PRAGMA user_version").fetchone()[0] == 10300
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert con.execute("PRAGMA foreign_key_check").fetchall() == []
        srs = con.execute("SELECT srs_id, organization, organization_coordsys_id FROM "
                          "gpkg_spatial_ref_sys ORDER BY srs_id").fetchall()  # fmt: skip
        assert srs == [(-1, "NONE", -1), (0, "NONE", 0), (4326, "EPSG", 4326)]
        contents = con.execute("SELECT table_name, data_type, srs_id, min_x, max_y, last_change "
                               "FROM gpkg_contents").fetchall()  # fmt: skip
        assert contents[0][:3] == ("gcps", "features", 4326)
        # GDAL prints the extent with 15 significant digits: equal to 1e-12 degree
        assert contents[0][3:5] == pytest.approx((t.lon.min(), t.lat.max()), abs=1e-12, rel=0)
        assert contents[0][5].endswith("Z") and "T" in contents[0][5]
        geom_cols = con.execute("SELECT * FROM gpkg_geometry_columns").fetchall()
        assert geom_cols == [("gcps", "geom", "POINT", 4326, 1, 0)]
        blob, lon, lat, h = con.execute("SELECT geom, lon, lat, h FROM gcps WHERE fid = 7"
                                        ).fetchone()  # fmt: skip
    finally:
        con.close()
    assert blob[:4] == b"GP\x00\x01"  # magic, version 0, flags: little-endian, no envelope
    srs_id, order, wkb_type, x, y, z = struct.unpack("<iBIddd", blob[4:])
    assert (srs_id, order, wkb_type) == (4326, 1, 1001) and (x, y, z) == (lon, lat, h)
    assert (lon, lat, h) == (t.lon[6], t.lat[6], t.h[6])


def test_gpkg_read_by_gdal(tmp_path):
    pyogrio = pytest.importorskip("pyogrio")
    t = make_table(80)
    p = write_gcps_gpkg(t, tmp_path / "g.gpkg", layer="scene_gcps")
    info = pyogrio.read_info(p, layer="scene_gcps")
    assert info["crs"] == "EPSG:4326" and info["geometry_type"] == "Point Z"
    assert info["features"] == 80 and list(info["fields"]) == list(COLUMNS)
    meta, fids, geometry, fields = pyogrio.raw.read(p, layer="scene_gcps", return_fids=True)
    assert fids.tolist() == list(range(1, 81))
    for name, values in zip(meta["fields"], fields):
        expected = getattr(t, name)
        if expected.dtype.kind == "f":
            np.testing.assert_array_equal(values.astype(np.float64), expected)
        else:
            assert values.tolist() == expected.tolist()
    xyz = np.array([struct.unpack("<ddd", g[5:29]) for g in geometry])
    assert all(g[0] == 1 for g in geometry)  # little-endian WKB
    np.testing.assert_array_equal(xyz, np.stack([t.lon, t.lat, t.h], axis=1))


def test_gpkg_written_by_gdal_reads(tmp_path):
    pyogrio = pytest.importorskip("pyogrio")
    lon, lat, h = np.array([5.25, 6.5]), np.array([44.5, 45.125]), np.array([12.5, 30.0])
    geometry = np.array([struct.pack("<BIddd", 1, 1001, *v) for v in zip(lon, lat, h)],
                        dtype=object)  # fmt: skip
    fields = [np.array(["p1", "p2"], dtype=object), np.array([0.5, 1.5]), np.array([2.5, 3.5]),
              lon, lat, h, np.array(["check", "gcp"], dtype=object)]  # fmt: skip
    p = tmp_path / "ogr.gpkg"
    pyogrio.raw.write(p, geometry, fields, fields=["id", "row", "col", "lon", "lat", "h", "kind"],
                      crs="EPSG:4326", geometry_type="Point Z", layer="pts",
                      driver="GPKG")  # fmt: skip
    t = read_gcps(p)
    assert t.id.tolist() == ["p1", "p2"] and t.kind.tolist() == ["check", "gcp"]
    assert t.h.tolist() == [12.5, 30.0] and t.sigma_px.tolist() == [1.0, 1.0]


def test_gpkg_bad_inputs(tmp_path):
    t = make_table(10)
    p = write_gcps_gpkg(t, tmp_path / "g.gpkg")
    con = sqlite3.connect(p)
    with con:
        con.execute("UPDATE gcps SET lon = lon + 0.001 WHERE fid = 4")
    con.close()
    raises_input([str(p), "feature fid 4", "field 'lon'", "differs"], read_gcps, p)
    p = write_gcps_gpkg(t, tmp_path / "g2.gpkg", layer="pts")
    con = sqlite3.connect(p)
    with con:
        con.execute("ALTER TABLE pts ADD COLUMN extra TEXT")
    con.close()
    raises_input([str(p), "unknown column 'extra'", "field 'extra'"], read_gcps, p)
    raises_input(["no features layer 'nope'"], read_gcps, p, layer="nope")
    con = sqlite3.connect(tmp_path / "plain.gpkg")
    con.execute("CREATE TABLE x (a)")
    con.close()
    raises_input(["not a GeoPackage"], read_gcps, tmp_path / "plain.gpkg")
    (tmp_path / "text.gpkg").write_text("hello")
    raises_input(["text.gpkg"], read_gcps, tmp_path / "text.gpkg")
    raises_input(["layer name"], write_gcps_gpkg, t, tmp_path / "l.gpkg", layer="gpkg_bad")
    raises_input(["layer name"], write_gcps_gpkg, t, tmp_path / "l.gpkg", layer='a"b')


def test_gpkg_null_values(tmp_path):
    p = write_gcps_gpkg(make_table(10), tmp_path / "g.gpkg")
    con = sqlite3.connect(p)
    with con:  # drop NOT NULL by rebuilding is heavy: make a layer without constraints instead
        con.execute("CREATE TABLE g2 AS SELECT * FROM gcps")
        con.execute("UPDATE g2 SET score = NULL WHERE fid = 3")
        con.execute("UPDATE g2 SET band = NULL WHERE fid = 2")
        con.execute("INSERT INTO gpkg_contents (table_name, data_type, srs_id) "
                    "VALUES ('g2', 'features', 4326)")  # fmt: skip
        con.execute("INSERT INTO gpkg_geometry_columns VALUES ('g2', 'geom', 'POINT', 4326, 1, 0)")
    con.close()
    with pytest.raises(InputError, match="single integer primary key"):
        read_gcps(p, layer="g2")  # CREATE TABLE AS keeps no primary key
    con = sqlite3.connect(p)
    with con:
        con.execute("DROP TABLE g2")
        con.execute('CREATE TABLE g2 (fid INTEGER PRIMARY KEY, geom POINT, id TEXT, "row" DOUBLE, '
                    "col DOUBLE, lon DOUBLE, lat DOUBLE, h DOUBLE, score DOUBLE, band TEXT)")
        con.execute('INSERT INTO g2 SELECT fid, geom, id, "row", col, lon, lat, h, score, band '
                    "FROM gcps")
        con.execute("UPDATE g2 SET band = NULL WHERE fid = 2")
    con.close()
    assert read_gcps(p, layer="g2").band[1] == ""  # NULL band: no band
    con = sqlite3.connect(p)
    with con:
        con.execute("UPDATE g2 SET score = NULL WHERE fid = 3")
    con.close()
    raises_input(["feature fid 3", "field 'score'", "NULL"], read_gcps, p, layer="g2")
    assert len(read_gcps(p)) == 10  # two layers: "gcps" is the default
    p2 = write_gcps_gpkg(make_table(4), tmp_path / "pts.gpkg", layer="pts")
    pyogrio = pytest.importorskip("pyogrio")  # a second features layer, added by GDAL
    pyogrio.raw.write(p2, np.array([struct.pack("<BIddd", 1, 1001, 5.0, 44.0, 0.0)], dtype=object),
                      [np.array(["q1"], dtype=object)], fields=["id"], layer="other",
                      driver="GPKG", crs="EPSG:4326", geometry_type="Point Z")  # fmt: skip
    raises_input([str(p2), "2 feature layers", "layer="], read_gcps, p2)


# ---------------------------------------------------------------------------------------------
# GeoTIFF
# ---------------------------------------------------------------------------------------------
def test_geotiff_round_trip_and_gdal_gcps(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    t = make_table(150)
    p = write_gcps_geotiff(t, tmp_path / "g.tif", image_shape=(1000, 2000))
    assert_same(read_gcps(p), t)
    assert_same(read_gcps(p, image_shape=(1000, 2000)), t)
    with rasterio.open(p) as src:
        gcps, crs = src.gcps
        assert crs.to_epsg() == 4326 and (src.height, src.width, src.count) == (1000, 2000, 1)
        assert src.dtypes == ("uint8",)
    got = np.array([(g.row, g.col, g.x, g.y, g.z) for g in gcps])
    fit = t.kind == "gcp"  # GDAL GCPs are the fit's points only; check points live in the stored table
    assert 0 < fit.sum() < len(t) and len(gcps) == fit.sum()
    np.testing.assert_array_equal(got, np.stack([t.row, t.col, t.lon, t.lat, t.h], axis=1)[fit])
    assert p.stat().st_size < 100_000  # zero raster: sparse and compressed
    checks_only = GcpTable.from_arrays([0.5], [1.5], [5.0], [44.0], [100.0], kind="check")
    raises_input(["no point of kind gcp"], write_gcps_geotiff, checks_only, tmp_path / "c.tif", image_shape=(10, 20))
    raises_input(["contradicts"], read_gcps, p, image_shape=(10, 10))


def test_geotiff_gcp_pixel_convention_matches_gdal_geotransform(tmp_path):
    """GDAL reads our (row, col) GCPs as corner-based (line, pixel): the affine fitted to them
    by GDAL is the true one and puts the first pixel's centre at our (0.5, 0.5)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import from_gcps, from_origin, xy

    truth = from_origin(5.0, 45.0, 0.001, 0.002)  # lon = 5 + 0.001 col, lat = 45 - 0.002 row
    rng = np.random.default_rng(2)
    row, col = rng.uniform(0, 100, 30), rng.uniform(0, 200, 30)
    lon, lat = truth @ (col, row)
    p = write_gcps_geotiff(GcpTable.from_arrays(row, col, lon, lat, 0.0), tmp_path / "a.tif",
                           image_shape=(100, 200))  # fmt: skip
    with rasterio.open(p) as src:
        fitted = from_gcps(src.gcps[0])
    assert fitted.almost_equals(truth, precision=1e-12)
    centre = xy(fitted, 0, 0, offset="center")  # GDAL/rasterio: centre of pixel (0, 0)
    np.testing.assert_allclose(centre, truth @ (0.5, 0.5), atol=1e-12)


def test_geotiff_copies_source_pixels(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import from_origin

    data = np.arange(3 * 40 * 70, dtype=np.int16).reshape(3, 40, 70) - 500
    src_path = tmp_path / "scene.tif"
    with rasterio.open(src_path, "w", driver="GTiff", width=70, height=40, count=3,
                       dtype="int16", nodata=-9999, crs="EPSG:32631",
                       transform=from_origin(600000, 5000000, 10, 10)) as dst:  # fmt: skip
        dst.write(data)
        dst.set_band_description(2, "green")
    before = hashlib.sha256(src_path.read_bytes()).hexdigest()
    t = make_table(20)
    t = GcpTable.from_arrays(t.row / 25, t.col / 30, t.lon, t.lat, t.h, id=t.id)
    p = write_gcps_geotiff(t, tmp_path / "out.tif", image_shape=(40, 70), source_raster=src_path)
    assert hashlib.sha256(src_path.read_bytes()).hexdigest() == before
    with rasterio.open(p) as out:
        np.testing.assert_array_equal(out.read(), data)
        assert out.dtypes == ("int16",) * 3 and out.nodata == -9999
        assert out.descriptions[1] == "green" and out.gcps[1].to_epsg() == 4326
    assert_same(read_gcps(p), t)
    raises_input(["differs from image_shape"], write_gcps_geotiff, t, tmp_path / "o2.tif",
                 image_shape=(41, 70), source_raster=src_path)  # fmt: skip
    raises_input(["replace source_raster"], write_gcps_geotiff, t, src_path,
                 image_shape=(40, 70), source_raster=src_path)  # fmt: skip
    assert not (tmp_path / "o2.tif").exists()


def test_geotiff_foreign_and_edited_gcps(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.control import GroundControlPoint
    from rasterio.crs import CRS

    pts = [GroundControlPoint(row=0.5, col=1.5, x=5.0, y=44.0, z=100.0),
           GroundControlPoint(row=9.5, col=19.5, x=5.1, y=44.1, z=200.0)]  # fmt: skip
    p = tmp_path / "foreign.tif"
    with rasterio.open(p, "w", driver="GTiff", width=20, height=10, count=1, dtype="uint8",
                       gcps=pts, crs=CRS.from_epsg(4326)) as dst:  # fmt: skip
        dst.write(np.zeros((1, 10, 20), np.uint8))
    t = read_gcps(p)
    assert t.id.tolist() == ["1", "2"] and t.row.tolist() == [0.5, 9.5]
    assert t.h.tolist() == [100.0, 200.0] and t.kind.tolist() == ["gcp", "gcp"]
    p_utm = tmp_path / "utm.tif"
    with rasterio.open(p_utm, "w", driver="GTiff", width=20, height=10, count=1, dtype="uint8",
                       gcps=pts, crs=CRS.from_epsg(32631)) as dst:  # fmt: skip
        dst.write(np.zeros((1, 10, 20), np.uint8))
    raises_input([str(p_utm), "EPSG:4326"], read_gcps, p_utm)
    # ours, then its GCPs moved by another tool: the stored table no longer matches
    ours = write_gcps_geotiff(GcpTable.from_arrays([0.5, 9.5], [1.5, 19.5], [5.0, 5.1],
                                                   [44.0, 44.1], [100.0, 200.0]),
                              tmp_path / "ours.tif", image_shape=(10, 20))  # fmt: skip
    with rasterio.open(ours, "r+") as dst:
        dst.gcps = ([pts[0], GroundControlPoint(row=9.5, col=19.5, x=5.2, y=44.1, z=200.0)],
                    CRS.from_epsg(4326))  # fmt: skip
    raises_input([str(ours), "GCP 2", "field 'lon'", "edited by another tool"], read_gcps, ours)
    plain = tmp_path / "plain.tif"
    with rasterio.open(plain, "w", driver="GTiff", width=4, height=4, count=1, dtype="uint8",
                       crs="EPSG:4326", transform=(0.1, 0, 5, 0, -0.1, 45)) as dst:  # fmt: skip
        dst.write(np.zeros((1, 4, 4), np.uint8))
    raises_input([str(plain), "no GDAL ground control points"], read_gcps, plain)


def test_geotiff_points_outside_image_write_nothing(tmp_path):
    t = GcpTable.from_arrays([0.5, 120.0], [1.5, 3.0], [5.0, 5.1], [44.0, 44.1], 0.0)
    raises_input(["point 1", "field 'row'", "outside the image [0, 100]"], write_gcps_geotiff,
                 t, tmp_path / "x.tif", image_shape=(100, 200))  # fmt: skip
    raises_input(["image_shape"], write_gcps_geotiff, t, tmp_path / "x.tif", image_shape=None)
    big = make_table(GEOTIFF_MAX_GCPS + 1)
    raises_input(["at most 10922 GCPs"], write_gcps_geotiff, big, tmp_path / "x.tif",
                 image_shape=(1000, 2000))  # fmt: skip
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
# Atomic output
# ---------------------------------------------------------------------------------------------
WRITERS = {
    "csv": (write_gcps_csv, "g.csv", {}),
    "gpkg": (write_gcps_gpkg, "g.gpkg", {}),
    "geotiff": (write_gcps_geotiff, "g.tif", {"image_shape": (1000, 2000)}),
}


@pytest.mark.parametrize("fmt", list(WRITERS))
def test_missing_folder_is_an_error_and_writes_nothing(tmp_path, fmt):
    write, name, kw = WRITERS[fmt]
    dest = tmp_path / "no" / "such" / name
    raises_input(["does not exist"], write, make_table(5), dest, **kw)
    assert list(tmp_path.iterdir()) == []
    raises_input(["empty"], write, make_table(5).select(np.zeros(5, bool)), tmp_path / name, **kw)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("fmt", ["csv", "gpkg"])
def test_failure_mid_write_leaves_destination_untouched(tmp_path, fmt):
    """A text value that cannot be encoded (a lone surrogate) in the last chunk fails the write
    after earlier chunks were written: the old file stays as it was and no temporary is left."""
    write, name, kw = WRITERS[fmt]
    n = gcp_csv_module._CHUNK_ROWS + 10
    t = make_table(n, seed=4)
    dest = write(make_table(3), tmp_path / name, **kw)
    before = dest.read_bytes()
    ids = t.id.astype(object)
    ids[-1] = "bad\ud800"
    object.__setattr__(t, "id", ids)  # bypasses the constructor on purpose
    with pytest.raises(UnicodeEncodeError):
        write(t, dest, **kw)
    assert dest.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
