"""Every kind of map output of ``docs/qgis.md`` opened as QGIS opens it: GDAL/OGR, then QGIS itself.

The outputs come from the real commands, cheaply: the session's ``gcpcal demo --fixture ideal``
folder (``demo_folder``: the GCP CSV with its ``.csvt`` and ``.prj``, the match and calibration
residual layers) and, once per module on the embedded fixture ``fixtures/hy1c_czi``, a match with
``--gpkg`` and ``--geotiff``, an orthoimage at 120 m, a level-1A with RPC tags, an RPC sidecar
paired with a raster of its name, and a localized point CSV (a few seconds of CPU); the reference
DOM and DEM and a level-1A band are the fixture's own, written by ``gcpcal simulate pushbroom``.
``validate``'s layer and table come from one validation of the fixture (a Dask cluster: ``slow``).

Each file is opened with GDAL/OGR, through the first of: the ``osgeo`` bindings; the ``gdalinfo``
and ``ogrinfo`` programs; rasterio and pyogrio (the GDAL library they bundle); the test skips
with the reason when none is there. Each is then loaded through QGIS when the ``qgis`` Python
module (PyQGIS) or ``qgis_process`` is installed, and skips with the reason when neither is.
The checks are what an analyst relies on: the layer opens, its CRS, geometry type and feature
count, RPC or GCPs found on a raster in sensor geometry, the residual layer's stored style.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import shutil
import subprocess
import warnings
from pathlib import Path

import pytest

from calibrate.cli import main

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
DEM = FIXTURE / "reference" / "dem.tif"


# ----------------------------------------------------------------------------- GDAL/OGR, as available
def gdal_backend() -> str | None:
    """``"osgeo"``, ``"programs"`` (gdalinfo/ogrinfo), ``"rasterio"`` (rasterio + pyogrio) or None."""
    if importlib.util.find_spec("osgeo") is not None:
        return "osgeo"
    if shutil.which("gdalinfo") and shutil.which("ogrinfo"):
        return "programs"
    if importlib.util.find_spec("rasterio") is not None and importlib.util.find_spec("pyogrio") is not None:
        return "rasterio"
    return None


@pytest.fixture(scope="module")
def gdal():
    backend = gdal_backend()
    if backend is None:
        pytest.skip("no GDAL: neither the osgeo bindings, nor gdalinfo/ogrinfo, nor rasterio with pyogrio")
    return backend


def _epsg(wkt_or_code) -> str | None:
    import pyproj

    if not wkt_or_code:
        return None
    crs = pyproj.CRS.from_user_input(wkt_or_code)
    code = crs.to_epsg() or crs.to_epsg(min_confidence=25)  # an ESRI .prj matches EPSG's WKT loosely
    return f"EPSG:{code}" if code else "other"


def open_raster(backend: str, path: Path) -> dict:
    """GDAL's view of a raster: ``size``, ``crs`` (EPSG code or None), ``rpc``, ``gcps``, ``metadata``."""
    if backend == "osgeo":
        from osgeo import gdal

        gdal.UseExceptions()
        ds = gdal.Open(str(path))
        gcp_wkt = ds.GetGCPProjection() if ds.GetGCPCount() else None
        return {"size": (ds.RasterXSize, ds.RasterYSize), "crs": _epsg(ds.GetProjection()),
                "rpc": bool(ds.GetMetadata("RPC")), "gcps": ds.GetGCPCount(), "gcp_crs": _epsg(gcp_wkt),
                "metadata": ds.GetMetadata() or {}}
    if backend == "programs":
        info = json.loads(subprocess.run(["gdalinfo", "-json", str(path)], capture_output=True, text=True,
                                         check=True).stdout)
        gcps = info.get("gcps", {})
        return {"size": tuple(info["size"]), "crs": _epsg(info.get("coordinateSystem", {}).get("wkt")),
                "rpc": bool(info.get("metadata", {}).get("RPC")), "gcps": len(gcps.get("gcpList", [])),
                "gcp_crs": _epsg(gcps.get("coordinateSystem", {}).get("wkt")),
                "metadata": info.get("metadata", {}).get("", {})}
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path) as ds:
            gcps, gcp_crs = ds.gcps
            return {"size": (ds.width, ds.height), "crs": _epsg(ds.crs.to_wkt()) if ds.crs else None,
                    "rpc": ds.rpcs is not None, "gcps": len(gcps),
                    "gcp_crs": _epsg(gcp_crs.to_wkt()) if gcp_crs else None, "metadata": ds.tags()}


def open_vector(backend: str, path: Path, layer: str | None = None) -> dict:
    """OGR's view of a vector file: ``layers`` (name -> geometry type), and of ``layer`` (default:
    the first): ``crs``, ``geometry``, ``count``, ``fields``."""
    if backend == "osgeo":
        from osgeo import ogr

        ogr.UseExceptions()
        ds = ogr.Open(str(path))
        layers = {ds.GetLayer(i).GetName(): ogr.GeometryTypeToName(ds.GetLayer(i).GetGeomType())
                  for i in range(ds.GetLayerCount())}
        lyr = ds.GetLayerByName(layer) if layer else ds.GetLayer(0)
        srs = lyr.GetSpatialRef()
        defn = lyr.GetLayerDefn()
        return {"layers": layers, "crs": _epsg(srs.ExportToWkt()) if srs else None,
                "geometry": ogr.GeometryTypeToName(lyr.GetGeomType()), "count": lyr.GetFeatureCount(),
                "fields": [defn.GetFieldDefn(i).GetName() for i in range(defn.GetFieldCount())]}
    if backend == "programs":
        proc = subprocess.run(["ogrinfo", "-json", "-so", "-al", str(path)], capture_output=True, text=True)
        if proc.returncode != 0:
            pytest.skip(f"ogrinfo has no -json output (GDAL before 3.7): {proc.stderr.strip()[:200]}")
        info = json.loads(proc.stdout)
        layers = {lyr["name"]: (lyr.get("geometryFields") or [{"type": "None"}])[0]["type"] for lyr in info["layers"]}
        lyr = next(x for x in info["layers"] if layer in (None, x["name"]))
        geometry = (lyr.get("geometryFields") or [{}])[0]
        return {"layers": layers, "crs": _epsg(geometry.get("coordinateSystem", {}).get("wkt")),
                "geometry": geometry.get("type"), "count": lyr.get("featureCount"),
                "fields": [f["name"] for f in lyr.get("fields", [])]}
    import pyogrio

    layers = {str(name): str(kind) for name, kind in pyogrio.list_layers(path)}
    info = pyogrio.read_info(path, layer=layer or next(iter(layers)))
    return {"layers": layers, "crs": _epsg(info["crs"]), "geometry": info["geometry_type"],
            "count": info["features"], "fields": list(info["fields"])}


def _is_point(geometry: str | None, z: bool) -> bool:
    """Whether GDAL's name of a geometry type (``Point Z``, ``Point25D``, osgeo's ``3D Point``) is a point."""
    text = (geometry or "").replace(" ", "").lower()
    is_3d = text.startswith("3d") or "25d" in text or text.endswith("z")
    return text.removeprefix("3d").startswith("point") and "multi" not in text and (is_3d or not z)


# ----------------------------------------------------------------------------- QGIS, when installed
class QgisLoader:
    """Loads files as QGIS layers through PyQGIS, or runs QGIS processing on them with ``qgis_process``."""

    def __init__(self):
        self.app = None
        if importlib.util.find_spec("qgis") is not None:
            from qgis.core import QgsApplication

            self.app = QgsApplication.instance() or QgsApplication([], False)
            self.app.initQgis()
            self.kind = "pyqgis"
        elif shutil.which("qgis_process"):
            self.kind = "qgis_process"
        else:
            self.kind = None

    def raster(self, path: Path) -> dict:
        """``valid``, ``crs`` (authid) of the raster as a QGIS layer (or a processing run on it)."""
        if self.kind == "pyqgis":
            from qgis.core import QgsRasterLayer

            layer = QgsRasterLayer(str(path), path.stem, "gdal")
            return {"valid": layer.isValid(), "crs": layer.crs().authid() or None, "width": layer.width()}
        out = self._process("native:rasterlayerstatistics", INPUT=path, BAND=1)
        return {"valid": "MEAN" in out, "crs": None, "width": None}

    def vector(self, uri: str, provider: str = "ogr") -> dict:
        """``valid``, ``crs``, ``count`` and ``renderer`` (the style QGIS applied) of a vector layer."""
        if self.kind == "pyqgis":
            from qgis.core import QgsVectorLayer

            layer = QgsVectorLayer(uri, "layer", provider)
            renderer = layer.renderer()
            return {"valid": layer.isValid(), "crs": layer.crs().authid() or None, "count": layer.featureCount(),
                    "renderer": renderer.type() if renderer else None,
                    "attribute": getattr(renderer, "classAttribute", lambda: None)()}
        out = self._process("native:exportlayersinformation", LAYERS=uri, OUTPUT="TEMPORARY_OUTPUT")
        return {"valid": "OUTPUT" in out, "crs": None, "count": None, "renderer": None, "attribute": None}

    @staticmethod
    def _process(algorithm: str, **params) -> dict:
        args = ["qgis_process", "--json", "run", algorithm, "--"] + [f"{k}={v}" for k, v in params.items()]
        proc = subprocess.run(args, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-500:]
        return json.loads(proc.stdout[proc.stdout.index("{"):]).get("results", {})


@pytest.fixture(scope="module")
def qgis():
    loader = QgisLoader()
    if loader.kind is None:
        pytest.skip("QGIS is not installed: neither the qgis Python module (PyQGIS) nor qgis_process")
    yield loader


# ----------------------------------------------------------------------------- the outputs, once
def _run(*argv) -> None:
    assert main(["-q", *map(str, argv)]) == 0, argv


@pytest.fixture(scope="module")
def outputs(demo_folder, tmp_path_factory):
    """Paths of one output of each kind (docs/qgis.md, "The kinds of file")."""
    import rasterio

    out = tmp_path_factory.mktemp("qgis_outputs")
    calibrated = demo_folder / "relative" / "manifest.json"  # every band calibrated
    _run("match", FIXTURE / "manifest.json", "--dom", FIXTURE / "reference" / "dom.tif", "--dem", DEM,
         "--out", out / "gcps.csv", "--gpkg", out / "gcps.gpkg", "--geotiff", out / "gcps.tif")
    _run("ortho", FIXTURE / "manifest.json", "--calibration", demo_folder / "relative", "--dem", DEM,
         "--resolution", 120, "--out", out / "ortho.tif")
    _run("rpc", calibrated, "--ccd", "cam1_ccd1", "--dem", DEM, "--max-error-px", 0.1, "--out", out / "l1a.tif")
    # the sidecar: an RPC text named after a raster that carries none, in the same folder
    (out / "pair").mkdir()
    _run("rpc", calibrated, "--ccd", "cam1_ccd1", "--dem", DEM, "--max-error-px", 0.1,
         "--out", out / "pair" / "cam1_ccd1_RPC.TXT")
    with rasterio.open(out / "l1a.tif") as src:
        profile = {k: src.profile[k] for k in ("driver", "width", "height", "count", "dtype")}
        pixels = src.read()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NotGeoreferencedWarning: the raster has no georeferencing of its own
        with rasterio.open(out / "pair" / "cam1_ccd1.tif", "w", **profile) as dst:
            dst.write(pixels)
    _run("localize", FIXTURE / "manifest.json", "--rows", "0.5,255.5", "--cols", "0.5,100.5", "--height", 0,
         "--out", out / "points.csv")
    return {"demo": demo_folder, "out": out}


# ----------------------------------------------------------------------------- GDAL/OGR
def test_residual_layers_are_pointz_in_wgs84_with_their_style_table(gdal, outputs):
    demo = outputs["demo"]
    for path, layer in ((demo / "gcps_residuals.gpkg", "match_residuals"),
                        (demo / "calibration" / "residuals.gpkg", "calibration_residuals")):
        info = open_vector(gdal, path, layer)
        assert set(info["layers"]) == {layer, "layer_styles"}, info["layers"]
        assert info["crs"] == "EPSG:4326" and _is_point(info["geometry"], z=True), info
        assert info["count"] > 100 and {"resid_azimuth_deg", "resid_planar_px", "kind"} <= set(info["fields"])


def test_gcp_csv_is_a_typed_point_layer_through_its_sidecars(gdal, outputs):
    table = outputs["demo"] / "gcps.csv"
    assert table.with_suffix(".csvt").is_file() and table.with_suffix(".prj").is_file()
    info = open_vector(gdal, table)
    with open(table, newline="") as fh:
        rows = sum(1 for _ in csv.DictReader(fh))
    assert info["crs"] == "EPSG:4326" and _is_point(info["geometry"], z=False), info
    assert info["count"] == rows and "lon" in info["fields"] and "sigma_px" in info["fields"]


def test_gcp_geopackage_and_geotiff(gdal, outputs):
    out = outputs["out"]
    info = open_vector(gdal, out / "gcps.gpkg", "gcps")
    with open(out / "gcps.csv", newline="") as fh:
        kinds = [r["kind"] for r in csv.DictReader(fh)]
    assert info["crs"] == "EPSG:4326" and info["count"] == len(kinds) and _is_point(info["geometry"], z=True)
    raster = open_raster(gdal, out / "gcps.tif")
    # only the points of kind gcp are GDAL GCPs: a warp uses them all, the check points stay independent
    assert raster["gcps"] == kinds.count("gcp") < len(kinds)
    assert raster["gcp_crs"] == "EPSG:4326" and raster["crs"] is None


def test_orthoimage_is_georeferenced_in_the_printed_crs(gdal, outputs):
    raster = open_raster(gdal, outputs["out"] / "ortho.tif")
    summary = json.loads((outputs["out"] / "ortho.summary.json").read_text())
    assert raster["crs"] == summary["crs"] == "EPSG:32631" and not raster["rpc"]
    assert "GCPCAL_PROVENANCE" in raster["metadata"]


def test_level1a_carries_its_rpc_inside_or_beside(gdal, outputs):
    inside = open_raster(gdal, outputs["out"] / "l1a.tif")
    assert inside["rpc"] and inside["crs"] is None and inside["gcps"] == 0
    assert float(inside["metadata"]["GCPCAL_RPC_CHECK_MAX_PX"]) < 0.1
    assert "GCPCAL_RPC_HEIGHT_HINT_M" in inside["metadata"]
    beside = open_raster(gdal, outputs["out"] / "pair" / "cam1_ccd1.tif")
    assert beside["rpc"] and beside["size"] == inside["size"]  # GDAL paired the _RPC.TXT with the raster


def test_simulated_rasters_reference_with_crs_level1a_without(gdal):
    dom, dem = open_raster(gdal, FIXTURE / "reference" / "dom.tif"), open_raster(gdal, DEM)
    assert dom["crs"] == dem["crs"] == "EPSG:32631"
    assert dem["metadata"].get("VERTICAL_DATUM") == "ellipsoid"
    band = open_raster(gdal, FIXTURE / "B2.tif")
    assert band["crs"] is None and not band["rpc"] and band["gcps"] == 0  # raw sensor geometry


def test_localized_points_are_a_delimited_text_table(outputs):
    with open(outputs["out"] / "points.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 and {"lon", "lat", "h"} <= set(rows[0])
    assert all(-180 <= float(r["lon"]) <= 180 and -90 <= float(r["lat"]) <= 90 for r in rows)


@pytest.fixture(scope="module")
def validated(demo_folder, tmp_path_factory):
    """One validation of the fixture with its own calibration, on a one-process local Dask cluster."""
    out = tmp_path_factory.mktemp("qgis_validate")
    sites = out / "sites.csv"
    sites.write_text("name,scene,dom,dem\n"
                     f"hy1c,{FIXTURE / 'manifest.json'},{FIXTURE / 'reference' / 'dom.tif'},{DEM}\n")
    _run("validate", sites, "--calibration", demo_folder / "calibration", "--workers", 1, "--out", out / "val")
    return out / "val"


@pytest.mark.slow
def test_validation_layer_and_table(gdal, validated):
    info = open_vector(gdal, validated / "residuals.gpkg", "validation_residuals")
    assert info["crs"] == "EPSG:4326" and _is_point(info["geometry"], z=True) and "site" in info["fields"]
    with open(validated / "validation.csv", newline="") as fh:
        row = next(csv.DictReader(fh))
    assert info["count"] == int(row["points"]) > 0
    assert -180 <= float(row["center_lon_deg"]) <= 180 and -90 <= float(row["center_lat_deg"]) <= 90


# ----------------------------------------------------------------------------- QGIS itself
def test_qgis_loads_every_kind(qgis, outputs):
    demo, out = outputs["demo"], outputs["out"]
    residuals = qgis.vector(f"{demo / 'calibration' / 'residuals.gpkg'}|layername=calibration_residuals")
    assert residuals["valid"]
    if qgis.kind == "pyqgis":  # the stored default style, applied on loading
        assert residuals["crs"] == "EPSG:4326" and residuals["count"] > 100
        assert residuals["renderer"] == "categorizedSymbol" and residuals["attribute"] == "kind"
    table = qgis.vector(str(demo / "gcps.csv"))
    assert table["valid"]
    if qgis.kind == "pyqgis":  # the .prj's ESRI WKT of WGS84
        assert table["crs"] in ("EPSG:4326", "OGC:CRS84"), table
        text = qgis.vector(f"file://{out / 'points.csv'}?type=csv&xField=lon&yField=lat&crs=EPSG:4326",
                           provider="delimitedtext")
        assert text["valid"] and text["count"] == 2
    for raster in (out / "ortho.tif", out / "l1a.tif", out / "pair" / "cam1_ccd1.tif", out / "gcps.tif"):
        layer = qgis.raster(raster)
        assert layer["valid"], raster
        if qgis.kind == "pyqgis":  # drawn on the map: ortho in its UTM zone, RPC and GCP rasters warped
            assert layer["crs"] == ("EPSG:32631" if raster.name == "ortho.tif" else "EPSG:4326"), (raster, layer)


def test_point_geometry_names_of_each_gdal_interface():
    # pyogrio and ogrinfo -json name a 3D point "Point Z" or "Point25D", osgeo's GeometryTypeToName "3D Point"
    for name in ("Point Z", "Point25D", "3D Point"):
        assert _is_point(name, z=True) and _is_point(name, z=False)
    assert _is_point("Point", z=False) and not _is_point("Point", z=True)
    assert not _is_point("3D Multi Point", z=True) and not _is_point("Polygon", z=False) and not _is_point(None, False)
