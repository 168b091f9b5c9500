"""Every ``gcpcal`` command through the bad-input and fault matrix of issue 12 (item 8).

The matrix is the table ``CASES`` below: one row per (command, case) with the argument
builder, the expected exit code and the files expected in the run's working folder afterwards.
Each row asserts:

* the exit code (0 ok, 1 input or I/O, 2 usage, 3 failed, 4 partial, 130 interrupted);
* for a non-zero code, exactly ONE stderr line, and never a "Traceback";
* the files left in the working folder: nothing new (no partial output) after a failure,
  and after a rerun into a used folder exactly the files of a fresh run plus the file a user
  added there (gcpcal's own files are replaced, the user's kept);
* every input (the fixture and the damaged inputs) byte-identical before and after (SHA-256).

Inputs are built once per module (``bad`` fixture): empty, truncated, CRS-less and
off-scene rasters, damaged manifests and GCP tables, an all-cloud image, star frames
without stars or of another camera. Commands run in-process through ``calibrate.cli.main``,
except the Ctrl-C cases, which send SIGINT to a ``gcpcal`` subprocess.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import numpy as np
import pytest
import rasterio
from affine import Affine

from calibrate.cli import main

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SCENE = FIXTURE / "manifest.json"
TRUTH = FIXTURE / "truth_manifest.json"
DOM = FIXTURE / "reference" / "dom.tif"
DEM = FIXTURE / "reference" / "dem.tif"
EXAMPLE = ROOT / "fixtures" / "example_pushbroom" / "manifest.json"
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def _files(folder: Path) -> list[str]:
    """Every file and folder under ``folder`` (hidden ones too, gcpcal's ledgers excepted), relative, sorted."""
    if not folder.exists():
        return []
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.name != ".gcpcal-outputs.json")


def _checksums(*folders: Path) -> dict[str, str]:
    """SHA-256 of every file under ``folders`` (the inputs of the matrix): path -> hex."""
    import hashlib

    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for folder in folders for p in sorted(folder.rglob("*"))
            if p.is_file()}


# --------------------------------------------------------------------------- the damaged inputs
def _raster_copy(src: Path, dst: Path, *, crs=True, shift_m=0.0, edit=None) -> Path:
    with rasterio.open(src) as ds:
        profile, data, tags = ds.profile, ds.read(), ds.tags()
    profile = profile | {"compress": None, "tiled": False}
    if not crs:
        profile.pop("crs", None)
        profile["crs"] = None
    if shift_m:
        t = profile["transform"]
        profile["transform"] = Affine(t.a, t.b, t.c + shift_m, t.d, t.e, t.f)
    if edit is not None:
        data, profile = edit(data, profile)
    with rasterio.open(dst, "w", **profile) as ds:
        ds.write(data)
        ds.update_tags(**tags)
    return dst


def _truncate(path: Path) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


def _dem_voids(data, profile):
    data = data.astype("float32")
    data[:, :, : data.shape[2] * 3 // 4] = -32768.0
    return data, profile | {"dtype": "float32", "nodata": -32768.0}


def _scaled(factor):
    def edit(data, profile):
        return (data.astype("float32") * factor), profile | {"dtype": "float32"}
    return edit


def _coarse_dom(src: Path, dst: Path, factor: int) -> Path:
    """The DOM averaged over ``factor`` x ``factor`` pixels: a reference ``factor`` times coarser."""
    from rasterio.enums import Resampling

    with rasterio.open(src) as ds:
        h, w = ds.height // factor, ds.width // factor
        data = ds.read(out_shape=(ds.count, h, w), resampling=Resampling.average)
        profile = ds.profile | {"height": h, "width": w, "compress": None, "tiled": False,
                                "transform": ds.transform * Affine.scale(ds.width / w, ds.height / h)}
        tags = ds.tags()
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
        out.update_tags(**tags)
    return dst


def _gcps_moved(src: Path, dst: Path, *, east_m=0.0, h_factor=1.0) -> Path:
    """A GCP table with every ground point moved ``east_m`` east and its height scaled."""
    lines = src.read_text().splitlines()
    cols = lines[0].split(",")
    lon_i, lat_i, h_i = cols.index("lon"), cols.index("lat"), cols.index("h")
    out = [lines[0]]
    for line in lines[1:]:
        c = line.split(",")
        c[lon_i] = f"{float(c[lon_i]) + east_m / (111_320.0 * np.cos(np.radians(float(c[lat_i])))):.9f}"
        c[h_i] = f"{float(c[h_i]) * h_factor:.3f}"
        out.append(",".join(c))
    dst.write_text("\n".join(out) + "\n")
    return dst


def _all_cloud(data, profile):
    top = np.iinfo(data.dtype).max if np.issubdtype(data.dtype, np.integer) else 1.0
    return np.full_like(data, top), profile


def _manifest_variant(dst: Path, edit) -> Path:
    doc = json.loads(SCENE.read_text())
    for band, raster in doc["image"]["rasters"].items():
        raster["path"] = str(FIXTURE / raster["path"])
    edit(doc)
    dst.write_text(json.dumps(doc))
    return dst


def _unknown_key(doc):
    doc["line_timing"]["line_perod_s"] = 0.1


def _missing_field(doc):
    del doc["orbit"]["position_m"]


def _nan(doc):
    doc["orbit"]["position_m"][3][0] = float("nan")


def _not_monotonic(doc):
    s = doc["orbit"]["seconds"]
    s[4], s[5] = s[5], s[4]


def _gcp_variants(table_csv: Path, folder: Path) -> dict[str, Path]:
    """GCP tables with one defect each, written from a real table."""
    lines = table_csv.read_text().splitlines()
    header, rows = lines[0], lines[1:]
    cols = header.split(",")

    def write(name, head, body):
        p = folder / f"{name}.csv"
        p.write_text("\n".join([head, *body]) + "\n")
        return p

    def set_col(row, col, value):
        cells = row.split(",")
        cells[cols.index(col)] = value
        return ",".join(cells)

    gcp_rows = [r for r in rows if ",gcp" in r or "check" not in r]
    drop = cols.index("lat")
    out = {
        "missing column": write("missing_col", ",".join(c for i, c in enumerate(cols) if i != drop),
                                [",".join(c for i, c in enumerate(r.split(",")) if i != drop) for r in rows]),
        "NaN": write("nan", header, [set_col(rows[0], "lat", "nan"), *rows[1:]]),
        "duplicate id": write("dup", header, [*rows, rows[0]]),
        "text in a number": write("text", header, [set_col(rows[0], "lon", "abc"), *rows[1:]]),
        "0 rows": write("zero", header, []),
        "3 rows": write("three", header, gcp_rows[:3]),
    }
    out["far outside the image"] = write("far", header, [set_col(r, "row", "5000.5") if i < 2 else r
                                                         for i, r in enumerate(gcp_rows)] + [r for r in rows
                                                                                              if r not in gcp_rows])
    row_i = cols.index("row")
    same_line = [r for r in rows if r.split(",")[row_i] == rows[0].split(",")[row_i]]
    if len(same_line) < 3:  # put them on one line: collinear in the image
        same_line = [set_col(r, "row", rows[0].split(",")[row_i]) for r in rows[:12]]
    out["collinear rows"] = write("collinear", header, same_line)
    return out


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> SimpleNamespace:
    """Every damaged input of the matrix, built once."""
    from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

    d = tmp_path_factory.mktemp("bad_inputs")
    ns = SimpleNamespace(root=d, missing=d / "missing.tif", missing_json=d / "missing.json")
    ns.empty_tif = d / "empty.tif"
    ns.empty_tif.write_bytes(b"")
    ns.empty_json = d / "empty.json"
    ns.empty_json.write_text("")
    ns.empty_csv = d / "empty.csv"
    ns.empty_csv.write_text("")
    ns.truncated_dom = _truncate(_raster_copy(DOM, d / "dom_cut.tif"))
    ns.truncated_image = _truncate(_raster_copy(FIXTURE / "B2.tif", d / "B2_cut.tif"))
    ns.dom_nocrs = _raster_copy(DOM, d / "dom_nocrs.tif", crs=False)
    ns.dem_nocrs = _raster_copy(DEM, d / "dem_nocrs.tif", crs=False)
    ns.dem_far = _raster_copy(DEM, d / "dem_far.tif", shift_m=300_000.0)
    ns.dem_voids = _raster_copy(DEM, d / "dem_voids.tif", edit=_dem_voids)
    ns.cloud_image = _raster_copy(FIXTURE / "B2.tif", d / "B2_cloud.tif", edit=_all_cloud)
    ns.dem_cm = _raster_copy(DEM, d / "dem_cm.tif", edit=_scaled(100.0))  # heights up to 150 km
    ns.dem_x10 = _raster_copy(DEM, d / "dem_x10.tif", edit=_scaled(10.0))
    ns.dom_coarse = _coarse_dom(DOM, d / "dom_150m.tif", 10)  # 150 m: 4.9 x the scene's 30 m
    ns.b4_image = FIXTURE / "B4.tif"
    ns.other_size_image = DOM
    ns.manifest = {name: _manifest_variant(d / f"m_{name.replace(' ', '_')}.json", edit)
                   for name, edit in [("unknown key", _unknown_key), ("missing field", _missing_field),
                                      ("NaN", _nan), ("non-monotonic times", _not_monotonic)]}
    ns.gcps = d / "gcps.csv"
    assert main(["-q", "match", str(SCENE), "--dom", str(DOM), "--dem", str(DEM), "--out", str(ns.gcps),
                 "--spacing", "48"]) == 0
    ns.gcp = _gcp_variants(ns.gcps, d)
    ns.gcp["of a scene 55 km away"] = _gcps_moved(ns.gcps, d / "gcps_55km.csv", east_m=55_000.0)
    ns.gcp["heights in centimetres"] = _gcps_moved(ns.gcps, d / "gcps_cm.csv", h_factor=100.0)
    ns.config_unknown = d / "config_unknown.json"
    ns.config_unknown.write_text(json.dumps({"scene": {"gsd_mm": 3}}))
    ns.sites_empty = d / "sites_empty.csv"
    ns.sites_empty.write_text("name,scene,dom,dem\n")
    ns.sites_missing_col = d / "sites_bad.csv"
    ns.sites_missing_col.write_text("name,scene\na,x\n")
    ns.marks_bad = d / "marks.csv"
    ns.marks_bad.write_text("time,ccd1_x_px\n0,abc\n")
    cfg = GeoStarsConfig(n_frames=3, mag_limit=6.0)
    simulate_geo_stars(d / "stars64", config=replace(cfg, image_shape=(64, 64)))
    simulate_geo_stars(d / "stars96", config=replace(cfg, image_shape=(96, 96)))
    dark = d / "stars_dark"
    shutil.copytree(d / "stars64", dark)
    for frame in (dark / "frames").glob("*.tif"):
        _raster_copy(frame, frame.with_suffix(".tmp.tif"), edit=lambda a, p: (np.zeros_like(a), p))
        frame.with_suffix(".tmp.tif").replace(frame)
    ns.stars64, ns.stars96, ns.stars_dark = d / "stars64", d / "stars96", dark
    ns.stars_ok = d / "stars_ok"
    simulate_geo_stars(ns.stars_ok, config=replace(GeoStarsConfig(), n_frames=12))
    ns.calibration = d / "cal"
    assert main(["-q", "calibrate", str(SCENE), "--gcps", str(ns.gcps), "--out", str(ns.calibration),
                 "--no-report"]) in (0, 4)
    return ns


# --------------------------------------------------------------------------- the matrix
SAME = "same as a fresh run"
#: what a successful match writes beside --out gcps.csv
MATCH_FILES = ("gcps.csv", "gcps.csvt", "gcps.prj", "gcps.summary.json", "gcps_qc.png", "gcps_residuals.gpkg")


@dataclass(frozen=True)
class Case:
    """One row of the matrix: ``argv(bad, work)`` run in the empty folder ``work``."""

    command: str
    case: str
    argv: Callable[[SimpleNamespace, Path], list]
    code: int
    left: tuple | str = ()  # files under work afterwards, or SAME (rerun: as a fresh run)
    prepare: Callable[[SimpleNamespace, Path], None] | None = None
    marks: tuple = field(default=())


def _under_file(work: Path) -> Path:
    (work / "afile").write_text("x")
    return work / "afile"


def _file_prep(bad, work):
    _under_file(work)


M = lambda name: (lambda b, w: b.manifest[name])  # noqa: E731
G = lambda name: (lambda b, w: b.gcp[name])  # noqa: E731

_MANIFEST_CASES = ("unknown key", "missing field", "NaN", "non-monotonic times")
_IMPLAUSIBLE_GCP_CASES = ("of a scene 55 km away", "heights in centimetres")
_GCP_CASES = ("missing column", "NaN", "duplicate id", "text in a number", "0 rows", "3 rows", "collinear rows",
              "far outside the image")


def _localize(model, *extra):
    return lambda b, w: ["localize", model(b, w), "--rows", "10", "--cols", "20", "--height", "0", *extra]


def _match(scene=lambda b, w: SCENE, dom=lambda b, w: DOM, dem=lambda b, w: DEM, out="gcps.csv", extra=()):
    return lambda b, w: ["match", scene(b, w), "--dom", dom(b, w), "--dem", dem(b, w), "--out", w / out,
                         "--spacing", "64", *extra]


def _calibrate(gcps, out="cal"):
    return lambda b, w: ["calibrate", SCENE, "--gcps", gcps(b, w), "--out", w / out, "--no-report"]


def _ortho(model=lambda b, w: SCENE, dem=lambda b, w: DEM, extra=()):
    return lambda b, w: ["ortho", model(b, w), "--dem", dem(b, w), "--out", w / "o.tif", "--resolution", "120",
                         *extra]


def _truth(model=lambda b, w: SCENE, truth=lambda b, w: TRUTH, extra=()):
    ground = [] if "--dem" in extra else ["--height", "0"]  # one height source: a plane, or the DEM given
    return lambda b, w: ["truth", "error", model(b, w), "--truth", truth(b, w), *ground, "--step", "64",
                         "--out", w / "t.json", *extra]


def _stars(frames, manifest=None):
    def argv(b, w):
        extra = ["--manifest", manifest(b, w)] if manifest else []
        return ["stars", frames(b, w), *extra, "--out", w / "out"]
    return argv


CASES = [
    # localize
    Case("localize", "nonexistent model", _localize(lambda b, w: b.missing_json), 1),
    Case("localize", "empty manifest", _localize(lambda b, w: b.empty_json), 1),
    *[Case("localize", f"manifest {name}", _localize(M(name)), 1) for name in _MANIFEST_CASES],
    Case("localize", "latitude 100", lambda b, w: ["localize", SCENE, "--lon", "5", "--lat", "100", "--h", "0"], 1),
    Case("localize", "csv text in a number", lambda b, w: ["localize", SCENE, "--csv", b.gcp["text in a number"],
                                                           "--inverse"], 1),
    Case("localize", "nonexistent DEM", _localize(lambda b, w: SCENE, "--dem", "{missing}"), 2),
    Case("localize", "DEM without CRS", lambda b, w: ["localize", SCENE, "--rows", "10", "--cols", "20",
                                                     "--dem", b.dem_nocrs], 1),
    Case("localize", "DEM not covering", lambda b, w: ["localize", SCENE, "--rows", "10", "--cols", "20",
                                                       "--dem", b.dem_far], 1),
    Case("localize", "DEM with voids", lambda b, w: ["localize", SCENE, "--rows", "10", "--cols", "20",
                                                    "--dem", b.dem_voids], 1),
    Case("localize", "DEM in centimetres", lambda b, w: ["localize", SCENE, "--rows", "10", "--cols", "20",
                                                        "--dem", b.dem_cm], 1),
    Case("localize", "output under a file", _localize(lambda b, w: SCENE, "--out", "{work}/afile/p.csv"), 1,
         ("afile",), _file_prep),
    Case("localize", "output is a folder", _localize(lambda b, w: SCENE, "--out", "{work}"), 2),
    # rpc
    Case("rpc", "nonexistent model", lambda b, w: ["rpc", b.missing_json, "--out", w / "x_RPC.TXT"], 1),
    Case("rpc", "empty manifest", lambda b, w: ["rpc", b.empty_json, "--out", w / "x_RPC.TXT"], 1),
    *[Case("rpc", f"manifest {name}", (lambda n: lambda b, w: ["rpc", b.manifest[n], "--out", w / "x_RPC.TXT"])(name),
           1) for name in _MANIFEST_CASES],
    Case("rpc", "DEM not covering", lambda b, w: ["rpc", SCENE, "--dem", b.dem_far, "--out", w / "x_RPC.TXT"], 1),
    Case("rpc", "DEM without CRS", lambda b, w: ["rpc", SCENE, "--dem", b.dem_nocrs, "--out", w / "x_RPC.TXT"], 1),
    Case("rpc", "empty DEM", lambda b, w: ["rpc", SCENE, "--dem", b.empty_tif, "--out", w / "x_RPC.TXT"], 1),
    Case("rpc", "DEM with voids", lambda b, w: ["rpc", SCENE, "--dem", b.dem_voids, "--out", w / "x_RPC.TXT"], 1),
    Case("rpc", "DEM in centimetres", lambda b, w: ["rpc", SCENE, "--dem", b.dem_cm, "--out", w / "x_RPC.TXT"], 1),
    Case("rpc", "output under a file", lambda b, w: ["rpc", SCENE, "--out", w / "afile" / "x_RPC.TXT"], 1,
         ("afile",), _file_prep),
    # demo
    Case("demo", "output under a file", lambda b, w: ["demo", "--out", w / "afile" / "demo"], 1, ("afile",),
         _file_prep),
    Case("demo", "output is a file", lambda b, w: ["demo", "--out", w / "afile"], 2, ("afile",), _file_prep),
    Case("demo", "existing output", lambda b, w: ["demo", "--out", w / "demo"], 0, SAME, marks=(pytest.mark.slow,)),
    # match
    Case("match", "nonexistent scene", _match(scene=lambda b, w: b.missing_json), 1),
    Case("match", "empty manifest", _match(scene=lambda b, w: b.empty_json), 1),
    *[Case("match", f"manifest {name}", _match(scene=M(name)), 1) for name in _MANIFEST_CASES],
    Case("match", "nonexistent DOM", _match(dom=lambda b, w: b.missing), 1),
    Case("match", "empty DOM", _match(dom=lambda b, w: b.empty_tif), 1),
    Case("match", "truncated DOM", _match(dom=lambda b, w: b.truncated_dom), 1),
    Case("match", "DOM without CRS", _match(dom=lambda b, w: b.dom_nocrs), 1),
    Case("match", "DEM without CRS", _match(dem=lambda b, w: b.dem_nocrs), 1),
    Case("match", "DEM not covering", _match(dem=lambda b, w: b.dem_far), 1),
    Case("match", "DEM with voids", _match(dem=lambda b, w: b.dem_voids), 0,
         MATCH_FILES),
    Case("match", "truncated image", _match(extra=("--image", "{truncated_image}")), 1),
    Case("match", "all-cloud scene", _match(extra=("--image", "{cloud_image}")), 1),
    Case("match", "DEM in centimetres", _match(dem=lambda b, w: b.dem_cm), 1),
    Case("match", "DEM scaled by 10", _match(dem=lambda b, w: b.dem_x10), 1),
    Case("match", "DOM 10x coarser", _match(dom=lambda b, w: b.dom_coarse), 1),
    Case("match", "DOM 10x coarser, --allow-implausible", _match(dom=lambda b, w: b.dom_coarse,
                                                                 extra=("--allow-implausible",)), 0,
         MATCH_FILES),
    Case("match", "image of band B4 for B2", _match(extra=("--image", "{b4_image}")), 1),
    Case("match", "image of band B4 given --band B2", _match(extra=("--image", "{b4_image}", "--band", "B2")), 1),
    Case("match", "image of another size", _match(extra=("--image", "{other_size_image}")), 1),
    Case("match", "output under a file", _match(out="afile/gcps.csv"), 1, ("afile",), _file_prep),
    Case("match", "GeoTIFF over 10922 points", _match(extra=("--geotiff", "{work}/g.tif", "--spacing", "2")), 1),
    Case("match", "gpkg under a file", _match(extra=("--gpkg", "{work}/afile/x.gpkg")), 1, ("afile",), _file_prep),
    Case("match", "output is a folder", lambda b, w: ["match", SCENE, "--dom", DOM, "--out", w], 2),
    Case("match", "existing output", _match(), 0, SAME),
    # calibrate
    Case("calibrate", "nonexistent GCPs", _calibrate(lambda b, w: b.missing), 1),
    Case("calibrate", "empty GCPs", _calibrate(lambda b, w: b.empty_csv), 1),
    *[Case("calibrate", f"GCPs {name}", _calibrate(G(name)), 1 if name not in ("3 rows", "collinear rows") else 3,
           () if name not in ("3 rows", "collinear rows") else ("cal", "cal/calibrate.summary.json", "cal/calibration.json", "cal/manifest.json",
                                                                  "cal/residuals.gpkg"))
      for name in _GCP_CASES],
    *[Case("calibrate", f"GCPs {name}", _calibrate(G(name)), 1) for name in _IMPLAUSIBLE_GCP_CASES],
    *[Case("calibrate", f"manifest {name}", (lambda n: lambda b, w: ["calibrate", b.manifest[n], "--gcps", b.gcps,
                                                                    "--out", w / "cal", "--no-report"])(name), 1)
      for name in _MANIFEST_CASES],
    Case("calibrate", "output under a file", _calibrate(lambda b, w: b.gcps, "afile/cal"), 1, ("afile",), _file_prep),
    # exit 4 (partial): the GCPs hold one band of four; the others wait for `gcpcal relative`
    Case("calibrate", "existing output", _calibrate(lambda b, w: b.gcps), 4, SAME),
    # run
    Case("run", "nonexistent DOM", lambda b, w: ["run", SCENE, "--dom", b.missing, "--dem", DEM, "--out", w / "r"],
         1),
    Case("run", "truncated DOM", lambda b, w: ["run", SCENE, "--dom", b.truncated_dom, "--dem", DEM,
                                               "--out", w / "r"], 1),
    Case("run", "foreign star frames", lambda b, w: ["run", SCENE, "--dom", DOM, "--dem", DEM, "--star-frames",
                                                     b.stars96, "--out", w / "r"], 1),
    Case("run", "manifest NaN", lambda b, w: ["run", b.manifest["NaN"], "--dom", DOM, "--dem", DEM, "--out", w / "r"],
         1),
    Case("run", "too few GCPs, no star frames", lambda b, w: ["run", SCENE, "--dom", DOM, "--dem", DEM, "--out",
                                                               w / "r", "--min-gcps", "100000"], 3, SAME),
    Case("run", "DEM in centimetres", lambda b, w: ["run", SCENE, "--dom", DOM, "--dem", b.dem_cm, "--out", w / "r"],
         1),
    Case("run", "DOM 10x coarser", lambda b, w: ["run", SCENE, "--dom", b.dom_coarse, "--dem", DEM, "--out", w / "r"],
         1),
    Case("run", "output under a file", lambda b, w: ["run", SCENE, "--dom", DOM, "--dem", DEM, "--out",
                                                     w / "afile" / "r"], 1, ("afile",), _file_prep),
    # relative
    Case("relative", "nonexistent calibration", lambda b, w: ["relative", SCENE, "--calibration", b.missing_json,
                                                              "--dem", DEM, "--out", w / "rel"], 1),
    Case("relative", "DEM not covering", lambda b, w: ["relative", SCENE, "--calibration", b.calibration,
                                                       "--dem", b.dem_far, "--out", w / "rel"], 1),
    Case("relative", "manifest NaN", lambda b, w: ["relative", b.manifest["NaN"], "--calibration", b.calibration,
                                                   "--dem", DEM, "--out", w / "rel"], 1),
    Case("relative", "manifest non-monotonic times", lambda b, w: ["relative", b.manifest["non-monotonic times"],
                                                                   "--calibration", b.calibration, "--dem", DEM,
                                                                   "--out", w / "rel"], 1),
    Case("relative", "DEM in centimetres", lambda b, w: ["relative", SCENE, "--calibration", b.calibration,
                                                        "--dem", b.dem_cm, "--out", w / "rel"], 1),
    Case("relative", "GCPs of a scene 55 km away", lambda b, w: ["relative", SCENE, "--calibration", b.calibration,
                                                                "--dem", DEM, "--gcps", b.gcp["of a scene 55 km away"],
                                                                "--out", w / "rel"], 1),
    Case("relative", "output under a file", lambda b, w: ["relative", SCENE, "--calibration", b.calibration,
                                                          "--dem", DEM, "--out", w / "afile" / "rel"], 1,
         ("afile",), _file_prep),
    # validate
    Case("validate", "nonexistent sites", lambda b, w: ["validate", b.missing_json, "--calibration", b.calibration,
                                                        "--out", w / "v"], 1),
    Case("validate", "empty sites", lambda b, w: ["validate", b.empty_csv, "--calibration", b.calibration,
                                                  "--out", w / "v"], 1),
    Case("validate", "sites without a column", lambda b, w: ["validate", b.sites_missing_col, "--calibration",
                                                             b.calibration, "--out", w / "v"], 1),
    Case("validate", "sites with no row", lambda b, w: ["validate", b.sites_empty, "--calibration", b.calibration,
                                                        "--out", w / "v"], 1),
    Case("validate", "scheduler not an address", lambda b, w: ["validate", b.sites_empty, "--calibration",
                                                               b.calibration, "--out", w / "v", "--scheduler",
                                                               "notanaddress"], 1),
    Case("validate", "output under a file", lambda b, w: ["validate", b.sites_empty, "--calibration", b.calibration,
                                                          "--out", w / "afile" / "v"], 1, ("afile",), _file_prep),
    # ortho
    Case("ortho", "nonexistent model", _ortho(model=lambda b, w: b.missing_json), 1),
    *[Case("ortho", f"manifest {name}", _ortho(model=M(name)), 1) for name in _MANIFEST_CASES],
    Case("ortho", "truncated image", _ortho(extra=("--image", "{truncated_image}", "--band", "B2")), 1),
    Case("ortho", "DEM without CRS", _ortho(dem=lambda b, w: b.dem_nocrs), 1),
    Case("ortho", "DEM not covering", _ortho(dem=lambda b, w: b.dem_far), 1),
    Case("ortho", "DEM with voids", _ortho(dem=lambda b, w: b.dem_voids), 1),
    Case("ortho", "empty DEM", _ortho(dem=lambda b, w: b.empty_tif), 1),
    Case("ortho", "DEM in centimetres", _ortho(dem=lambda b, w: b.dem_cm), 1),
    Case("ortho", "image of band B4 for B2", _ortho(extra=("--image", "{b4_image}", "--band", "B2")), 1),
    Case("ortho", "output under a file", lambda b, w: ["ortho", SCENE, "--dem", DEM, "--out", w / "afile" / "o.tif"],
         1, ("afile",), _file_prep),
    Case("ortho", "output is a folder", lambda b, w: ["ortho", SCENE, "--dem", DEM, "--out", w], 2),
    # stars
    Case("stars", "nonexistent frames", _stars(lambda b, w: b.missing_json), 1),
    Case("stars", "empty frames.json", _stars(lambda b, w: b.empty_json), 1),
    Case("stars", "frames without stars", _stars(lambda b, w: b.stars_dark), 1),
    Case("stars", "foreign star frames", _stars(lambda b, w: b.stars96, lambda b, w: b.stars64 / "manifest.json"), 1),
    Case("stars", "output under a file", lambda b, w: ["stars", b.stars64, "--out", w / "afile" / "out"], 1,
         ("afile",), _file_prep),
    Case("stars", "existing output", _stars(lambda b, w: b.stars_ok), 0, SAME),
    # compensate
    Case("compensate", "bad option value", lambda b, w: ["compensate", "--step", "-1", "--out", w / "c"], 2),
    Case("compensate", "output under a file", lambda b, w: ["compensate", "--step", "1000", "--no-figures",
                                                            "--out", w / "afile" / "c"], 1, ("afile",), _file_prep),
    Case("compensate", "existing output", lambda b, w: ["compensate", "--step", "1000", "--no-figures",
                                                        "--out", w / "c"], 0, SAME),
    # thermal
    Case("thermal", "bad option value", lambda b, w: ["thermal", "--days", "abc", "--out", w / "t"], 2),
    Case("thermal", "output under a file", lambda b, w: ["thermal", "--days", "2", "--out", w / "afile" / "t"], 1,
         ("afile",), _file_prep),
    Case("thermal", "existing output", lambda b, w: ["thermal", "--days", "2", "--out", w / "t"], 0, SAME),
    # oalr
    Case("oalr", "nonexistent marks", lambda b, w: ["oalr", b.missing_json, "--out", w / "o"], 1),
    Case("oalr", "empty marks", lambda b, w: ["oalr", b.empty_csv, "--out", w / "o"], 1),
    Case("oalr", "marks missing columns", lambda b, w: ["oalr", b.marks_bad, "--out", w / "o"], 1),
    # truth error
    Case("truth error", "nonexistent truth", _truth(truth=lambda b, w: b.missing_json), 1),
    Case("truth error", "empty truth", _truth(truth=lambda b, w: b.empty_json), 1),
    *[Case("truth error", f"manifest {name}", _truth(model=M(name)), 1) for name in _MANIFEST_CASES],
    Case("truth error", "DEM not covering", _truth(extra=("--dem", "{dem_far}")), 1),
    Case("truth error", "DEM with voids", _truth(extra=("--dem", "{dem_voids}")), 1),
    Case("truth error", "DEM without CRS", _truth(extra=("--dem", "{dem_nocrs}")), 1),
    Case("truth error", "DEM in centimetres", _truth(extra=("--dem", "{dem_cm}")), 1),
    Case("truth error", "output under a file", lambda b, w: ["truth", "error", SCENE, "--truth", TRUTH,
                                                             "--height", "0", "--out", w / "afile" / "t.json"], 1,
         ("afile",), _file_prep),
    # simulate
    Case("simulate pushbroom", "empty config", lambda b, w: ["simulate", "pushbroom", "--config", b.empty_json,
                                                             "--out", w / "s"], 1),
    Case("simulate pushbroom", "config unknown key", lambda b, w: ["simulate", "pushbroom", "--config",
                                                                   b.config_unknown, "--out", w / "s"], 1),
    Case("simulate pushbroom", "DEM not covering", lambda b, w: ["simulate", "pushbroom", "--dom", DOM, "--dem",
                                                                 b.dem_far, "--out", w / "s"], 1),
    Case("simulate pushbroom", "DEM with voids", lambda b, w: ["simulate", "pushbroom", "--dom", DOM, "--dem",
                                                               b.dem_voids, "--out", w / "s"], 1),
    Case("simulate pushbroom", "truncated DOM", lambda b, w: ["simulate", "pushbroom", "--dom", b.truncated_dom,
                                                              "--dem", DEM, "--out", w / "s"], 1),
    Case("simulate pushbroom", "output under a file", lambda b, w: ["simulate", "pushbroom", "--out",
                                                                    w / "afile" / "s"], 1, ("afile",), _file_prep),
    Case("simulate series", "config unknown key", lambda b, w: ["simulate", "series", "--config", b.config_unknown,
                                                                "--scenes", "1", "--out", w / "s"], 1),
    Case("simulate series", "output under a file", lambda b, w: ["simulate", "series", "--scenes", "1",
                                                                 "--out", w / "afile" / "s"], 1, ("afile",),
         _file_prep),
    Case("simulate geo-earth", "config unknown key", lambda b, w: ["simulate", "geo-earth", "--config",
                                                                   b.config_unknown, "--out", w / "s"], 1),
    Case("simulate geo-earth", "output under a file", lambda b, w: ["simulate", "geo-earth", "--out",
                                                                    w / "afile" / "s"], 1, ("afile",), _file_prep),
    Case("simulate geo-stars", "bad option value", lambda b, w: ["simulate", "geo-stars", "--frames", "x",
                                                                 "--out", w / "s"], 2),
    Case("simulate geo-stars", "output under a file", lambda b, w: ["simulate", "geo-stars", "--frames", "3",
                                                                    "--out", w / "afile" / "s"], 1, ("afile",),
         _file_prep),
    Case("simulate geo-stars", "existing output", lambda b, w: ["simulate", "geo-stars", "--frames", "3",
                                                                "--out", w / "s"], 0, SAME),
]


def _argv(case: Case, bad: SimpleNamespace, work: Path) -> list[str]:
    names = {"work": str(work), **{k: str(v) for k, v in vars(bad).items() if isinstance(v, Path)}}
    return ["-q", *(str(a).format(**names) if "{" in str(a) else str(a) for a in case.argv(bad, work))]


def _run(capsys, argv):
    code = main(argv)
    _, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, [line for line in err.splitlines() if line.strip()]


@pytest.mark.parametrize("case", [pytest.param(c, marks=c.marks, id=f"{c.command}: {c.case}") for c in CASES])
def test_bad_input_matrix(case: Case, bad, tmp_path, capsys):
    work = tmp_path / "work"
    work.mkdir()
    if case.prepare is not None:
        case.prepare(bad, work)
    argv = _argv(case, bad, work)
    if case.left == SAME:  # a used folder: a first run, a stale file planted, then the rerun
        assert _run(capsys, argv)[0] == case.code
        fresh = _files(work)
        target = next(p for p in sorted(work.iterdir()) if p.name != "afile")
        added = target / "notes.txt" if target.is_dir() else work / "unrelated.txt"
        added.write_text("the user's own file")
        expected = sorted([*fresh, str(added.relative_to(work))])
    else:
        expected = sorted(case.left)
    inputs_before = _checksums(FIXTURE, bad.root)
    code, lines = _run(capsys, argv)
    assert code == case.code, lines
    if code in (1, 2, 130):  # an error: one line
        assert len(lines) == 1, lines
        assert lines[0].startswith("gcpcal: "), lines
    elif code in (3, 4):  # a result (failed or partial): its table is on stdout, at most one line here
        assert len(lines) <= 1, lines
    assert _files(work) == expected
    assert not [p for p in tmp_path.iterdir() if p.name != "work"]  # no staging folder beside it
    assert _checksums(FIXTURE, bad.root) == inputs_before  # no input written


# --------------------------------------------------------------------------- the coverage gate's two rules
def _coverage_rows(rows_px, cols_px):
    from calibrate.coverage import calibration_coverage
    from sensor_models.readers import open_model

    model = open_model(SCENE)
    n = len(rows_px)
    gcps = {"row": np.asarray(rows_px, float), "col": np.asarray(cols_px, float), "band": np.full(n, "B2"),
            "ccd": None}
    checks = {"row": np.asarray([100.5]), "col": np.asarray([100.5]), "band": np.asarray(["B2"]), "ccd": None}
    return calibration_coverage(model, gcps, checks, success=True)


def test_gcps_far_outside_the_image_are_not_calibrated():
    from calibrate.coverage import calibration_status

    inside = _coverage_rows([20.5, 480.5, 250.5], [10.5, 150.5, 90.5])
    assert inside[0].calibrated  # cam1_ccd1
    far = _coverage_rows([20.5, 480.5, 250.5, 3000.5], [10.5, 150.5, 90.5, 100.5])
    assert not any(c.calibrated for c in far)
    assert "outside" in far[0].reason
    status = calibration_status(True, "converged", far)
    assert status.status == "partial"
    assert "outside" in status.uncalibrated[0]["reason"]


def test_check_accuracy_worse_after_than_before_is_not_calibrated():
    from calibrate.coverage import apply_check_accuracy, calibration_status

    rows = _coverage_rows([20.5, 480.5, 250.5], [10.5, 150.5, 90.5])
    assert rows[0].calibrated
    rmse = [(50.0, 1626.0)] + [(None, None)] * (len(rows) - 1)
    gated = apply_check_accuracy(rows, rmse)
    assert not gated[0].calibrated and "50.000 -> 1626.000 px" in gated[0].reason
    assert calibration_status(True, "converged", gated).status == "partial"
    better = apply_check_accuracy(rows, [(50.0, 0.1)] + [(None, None)] * (len(rows) - 1))
    assert better[0].calibrated


# --------------------------------------------------------------------------- chmod (not as root)
@pytest.mark.skipif(IS_ROOT, reason="root writes into read-only folders")
@pytest.mark.parametrize("command", [
    lambda w: ["compensate", "--step", "1000", "--no-figures", "--out", w / "ro" / "c"],
    lambda w: ["rpc", SCENE, "--out", w / "ro" / "x_RPC.TXT"],
    lambda w: ["simulate", "geo-stars", "--frames", "3", "--out", w / "ro" / "s"],
])
def test_read_only_folder_is_one_line(command, tmp_path, capsys):
    (tmp_path / "ro").mkdir()
    os.chmod(tmp_path / "ro", 0o555)
    try:
        code, lines = _run(capsys, ["-q", *map(str, command(tmp_path))])
        assert code == 1 and len(lines) == 1, lines
        assert _files(tmp_path) == ["ro"]
    finally:
        os.chmod(tmp_path / "ro", 0o755)


# --------------------------------------------------------------------------- Ctrl-C
def _interrupt(argv: list[str], ready: Callable[[Path, list[str]], bool], folder: Path, *,
               timeout_s: float = 120.0) -> tuple[int, list[str]]:
    """Run ``gcpcal argv``, send SIGINT once ``ready(folder, stderr lines so far)``; the lines after it."""
    import threading

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(["gcpcal", *argv], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                            start_new_session=True, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None and not ready(folder, list(lines)):
        time.sleep(0.05)
    assert proc.poll() is None, f"the command ended before it could be interrupted: {lines}"
    n_before = len(lines)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    proc.wait(timeout=timeout_s)
    reader.join(timeout_s)
    after = [line.rstrip("\n") for line in lines[n_before:] if line.strip()]
    assert not any("Traceback" in line for line in lines), lines
    if "-q" in argv:  # quiet: nothing but the one line
        return proc.returncode, after
    return proc.returncode, [line for line in after if not line.startswith("  CCD ")]  # progress still flushing


needs_gcpcal = pytest.mark.skipif(shutil.which("gcpcal") is None, reason="the gcpcal console script is not installed")


@needs_gcpcal
def test_ctrl_c_during_match_is_one_line_and_leaves_nothing(tmp_path):
    out = tmp_path / "gcps.csv"
    code, lines = _interrupt(["match", str(SCENE), "--dom", str(DOM), "--dem", str(DEM), "--out", str(out),
                              "--spacing", "16"], lambda f, err: any("coarse stage" in e for e in err), tmp_path)
    assert code == 130, lines
    assert lines == ["gcpcal: interrupted"]
    assert _files(tmp_path) == []


@needs_gcpcal
def test_ctrl_c_during_simulate_is_one_line_and_leaves_nothing(tmp_path):
    code, lines = _interrupt(["-q", "simulate", "pushbroom", "--out", str(tmp_path / "s")],
                             lambda f, err: bool(list(f.glob(".s*"))), tmp_path)
    assert code == 130, lines
    assert lines == ["gcpcal: interrupted"]
    assert _files(tmp_path) == []


@needs_gcpcal
def test_ctrl_c_during_validate_is_one_line_and_leaves_nothing(tmp_path, tmp_path_factory):
    sys.path.insert(0, str(Path(__file__).parent))
    from test_batch import small_sensor

    from calibrate.actions.calibrate import calibrate_scene
    from calibrate.actions.match import match_scene
    from gcpmatch.options import MatchOptions
    from sensor_models.simulate.series import simulate_series

    root = tmp_path_factory.mktemp("series")
    simulate_series(root, 3, base_config=small_sensor(), seed=5, calibration_scene=True)
    cal = root / "calibration"
    match_scene(cal / "manifest.json", dom_path=cal / "reference" / "dom.tif", dem_path=cal / "reference" / "dem.tif",
                out_path=root / "cal_gcps.csv", options=MatchOptions(spacing_px=16))
    calibrate_scene(cal / "manifest.json", root / "cal_gcps.csv", root / "calibrated", report=False)
    work = tmp_path / "w"
    work.mkdir()
    code, lines = _interrupt(["-q", "validate", str(root / "sites.csv"), "--calibration", str(root / "calibrated"),
                              "--out", str(work / "o"), "--workers", "2"],
                             lambda f, err: bool(list(f.glob(".o.gcpcal-stage.*/**/*.csv"))), work)
    assert code == 130, lines
    assert lines == ["gcpcal: interrupted"]
    assert _files(work) == []


# --------------------------------------------------------------------------- usage errors
def test_usage_error_is_one_line_naming_the_help(capsys):
    code, lines = _run(capsys, ["rpc", str(EXAMPLE), "--no-such-option"])
    assert code == 2
    assert lines == ["gcpcal: error: No such option '--no-such-option'. (gcpcal rpc --help)"]


def test_usage_error_with_verbose_shows_click_usage(capsys):
    assert main(["-v", "rpc", str(EXAMPLE), "--no-such-option"]) == 2
    err = capsys.readouterr().err
    assert "Usage: gcpcal rpc" in err and "No such option" in err


# --------------------------------------------------------------------------- what the one line says
def test_all_cloud_match_names_the_cloud_figure(bad, tmp_path, capsys):
    code, lines = _run(capsys, ["-q", *map(str, _match(extra=("--image", str(bad.cloud_image)))(bad, tmp_path))])
    assert code == 1 and len(lines) == 1
    assert "cloud fraction unknown" in lines[0]
    mask = tmp_path / "mask.tif"
    _raster_copy(FIXTURE / "B2.tif", mask, edit=lambda a, p: (np.ones_like(a), p))
    code, lines = _run(capsys, ["-q", *map(str, _match()(bad, tmp_path)), "--image", str(bad.cloud_image),
                                "--mask", str(mask)])
    assert code == 1 and len(lines) == 1
    assert "the mask marks 100 % of the scene as cloud" in lines[0]
    assert _files(tmp_path) == ["mask.tif"]


def test_geotiff_over_its_limit_is_refused_before_matching(bad, tmp_path, capsys, monkeypatch):
    calls = []
    monkeypatch.setattr("calibrate.actions.match.extract_gcps", lambda *a, **k: calls.append(1))
    code, lines = _run(capsys, ["-q", *map(str, _match(extra=("--geotiff", str(tmp_path / "g.tif"), "--spacing",
                                                              "2"))(bad, tmp_path))])
    assert code == 1 and len(lines) == 1
    assert "a GeoTIFF holds at most 10922" in lines[0] and "--spacing" in lines[0]
    assert calls == [] and _files(tmp_path) == []
