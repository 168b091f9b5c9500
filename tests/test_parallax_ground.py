"""Tie points re-localized through an updated model (``calibrate.parallax._with_ground``).

Between the joint band-parallax rounds every tie's ground is what the updated reference band
sees at its window centre on the DEM. A centre whose ray no longer meets the DEM (a void, the
DEM's edge, a CCD left uncalibrated by a partial calibration) used to go on as a NaN ground point
and stopped ``gcpcal relative`` with "lon = nan" (measured on a full-width 512-line strip whose
outermost CCD had no GCP). It is now dropped; the others are kept unchanged.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio

from calibrate.parallax import _with_ground
from calibrate.tie_points import TiePoints
from sensor_models.readers import open_scene
from sensor_models.terrain.dem import Dem

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"


def _ties(model, n_per_ccd=30):
    rng = np.random.default_rng(3)
    band = model.reference_band
    rows, cols, ccds = [], [], []
    for k, look in enumerate(model.band_ccds(band)):
        rows.append(rng.uniform(20, model.image_shape[0] - 20, n_per_ccd))
        cols.append(rng.uniform(10, look.n_detectors - 10, n_per_ccd))
        ccds.append(np.full(n_per_ccd, k))
    row, col, ccd = (np.concatenate(a) for a in (rows, cols, ccds))
    nan = np.full(row.size, np.nan)
    return TiePoints(band=band, row_ref=row, col_ref=col, ccd_ref=ccd, lon=nan, lat=nan, h=nan, row=row + 0.1,
                     col=col - 0.1, ccd=ccd, predicted_row=row, predicted_col=col, score=np.full(row.size, 0.9),
                     sigma_px=np.full(row.size, 0.05))


def test_ties_off_the_dem_are_dropped_the_others_kept():
    model = open_scene(FIXTURE / "manifest.json").model
    with rasterio.open(FIXTURE / "reference" / "dem.tif") as src:
        heights = src.read(1).astype(float)
        transform, crs = src.transform, src.crs
    whole = Dem.open(FIXTURE / "reference" / "dem.tif")
    ties = _ties(model)
    full = _with_ground(model, ties, whole, None)
    assert len(full) == len(ties) and np.isfinite(full.lon).all()
    holed_heights = heights.copy()
    holed_heights[:, heights.shape[1] // 2:] = np.nan  # the eastern half is a void
    holed = Dem.from_array(holed_heights, transform, crs, vertical_datum="ellipsoid")
    part = _with_ground(model, ties, holed, None)
    assert 0 < len(part) < len(ties)  # some ties lost their ground, not all
    assert np.isfinite(part.lon).all() and np.isfinite(part.lat).all() and np.isfinite(part.h).all()
    # the kept ties are the same ties, every array subset alike, grounds as on the whole DEM
    kept = np.isin(ties.row_ref, part.row_ref)
    np.testing.assert_array_equal(part.row, ties.row[kept])
    np.testing.assert_array_equal(part.ccd, ties.ccd[kept])
    np.testing.assert_allclose(part.lon, full.lon[kept], atol=1e-9)
    part.as_gcp_table()  # what used to raise on a NaN longitude
