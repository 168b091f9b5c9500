"""What each vendor reader compares its model with: the product's own statements, per format.

The machinery (comparisons, tolerances, the refuse/warn policy) is in
:mod:`sensor_models.readers.self_check`; this module says, for each format, which statements are
compared and what tolerance each gets (``docs/dimap.md``, ``docs/dimap_v2.md``,
``docs/worldview.md`` give the figures on the real products):

==================  ================================================  =================================
reader              statements                                        tolerance (m, in quadrature)
==================  ================================================  =================================
SPOT 1-5 DIMAP      4 frame vertices + scene centre at the tie        half a ground pixel; coordinate
                    points' ``TIE_POINT_CRS_Z`` (max)                 rounding
DIMAP v2            4 ``Dataset_Extent`` vertices + centre at the     half a ground pixel; coordinate
                    one height that fits them (no height stated)      rounding
                    (max); the RPC where one is given (rms)           RPC: its ``ERR_RAND`` if stated
DigitalGlobe XML    ``IMD`` corners at their ``HAE`` (max); ``RPB``   ``sqrt(2) x ERRRAND`` of the RPB
                    over 11 x 11 pixels x 5 heights (rms)             (else half a ground pixel);
                                                                      rounding; refraction's height
                                                                      dependence (straight rays)
==================  ================================================  =================================
"""

from __future__ import annotations

import numpy as np

from sensor_models.errors import ProductDisagreementError
from sensor_models.readers.self_check import (
    HALF_PIXEL,
    RPC_GRID_HEIGHTS,
    ProductCheck,
    Tolerance,
    compare,
    coordinate_rounding_m,
    fit_common_height,
    ground_pixel_m,
    localization_misses_m,
    rpc_grid_misses_m,
    view_tangent,
)

__all__ = [
    "DIGITALGLOBE_SATELLITES",
    "DIGITALGLOBE_VERIFIED",
    "check_dimap",
    "check_dimap_v2",
    "check_rpc",
    "check_worldview",
    "check_worldview_pointing",
    "worldview_collected_extent",
]

#: ``SATID`` of the satellites whose level-1B products share the ``<isd>`` XML format
DIGITALGLOBE_SATELLITES = {"QB02": "QuickBird", "WV01": "WorldView-1", "WV02": "WorldView-2",
                           "WV03": "WorldView-3", "WV04": "WorldView-4", "GE01": "GeoEye-1"}
#: satellites whose conventions were established on real products (docs/worldview.md); the
#: others are accepted when, and only when, their own product confirms them (the self-check)
DIGITALGLOBE_VERIFIED = ("WV02", "WV03")
#: the attitude SPOT's ground segment computed the DIMAP frame with (docs/dimap.md: SPOT 1-4
#: frames fit the nominal attitude to 0.9-1.6 m and miss the measured one by 3-24 m)
SPOT_FRAME_ATTITUDE = {1: "nominal", 2: "nominal", 3: "nominal", 4: "nominal", 5: "measured"}


def _half_pixel(model, row, col, h, band) -> tuple[float, str]:
    gp = ground_pixel_m(model, row, col, h, band=band)
    return HALF_PIXEL * gp, f"half a ground pixel ({gp:.3g} m at the scene centre)"


# ---------------------------------------------------------------------------------------------
# RPC (any reader)


def check_rpc(model, rpc, n_rows: float, n_cols: float, *, band=None, base: tuple[float, str] | None = None,
              extra: tuple = ()):
    """The model against a vendor RPC over ``11 x 11`` pixels x ``5`` heights (rms).

    Parameters
    ----------
    model : SensorModel
    rpc : RpcModel
        The vendor RPC, in gcpcal's pixel convention.
    n_rows, n_cols : float
        The extent the RPC describes.
    band : str, optional
    base : (float, str), optional
        The tolerance's main term; default: ``sqrt(2) x err_rand`` of the RPC when it states one
        (RPC00B ``ERR_RAND``: RMS random error per horizontal axis), else half a ground pixel.
    extra : tuple of (float, str)
        Further terms (added in quadrature).

    Returns
    -------
    Comparison
    """
    heights = rpc.height_off + rpc.height_scale * np.linspace(-1.0, 1.0, RPC_GRID_HEIGHTS)
    d = rpc_grid_misses_m(model, rpc, n_rows, n_cols, heights, band=band)
    if base is None:
        if rpc.err_rand is not None and rpc.err_rand > 0.0:
            base = (np.sqrt(2.0) * rpc.err_rand, f"sqrt(2) x the RPC's ERR_RAND {rpc.err_rand:g} m per axis")
        else:
            base = _half_pixel(model, n_rows / 2, n_cols / 2, float(rpc.height_off), band)
    desc = (f"vendor RPC over {int(round(np.sqrt(d.size / heights.size)))}^2 pixels x {heights.size} heights "
            f"({heights[0]:.0f} to {heights[-1]:.0f} m)")
    return compare("rpc_grid", desc, d, "rms", Tolerance.combine(base, *extra))


# ---------------------------------------------------------------------------------------------
# DigitalGlobe


def worldview_collected_extent(meta) -> tuple[int, int]:
    """Rows and columns actually collected: the TLC list's last line; the RPB's sample span.

    The ``IMD`` corners are the centres of the first and last collected pixels, and the raster
    (``NUMROWS`` x ``NUMCOLUMNS``) extends beyond them (docs/worldview.md). Without an RPB the
    columns are ``NUMCOLUMNS``.
    """
    n_rows = int(round(meta.tlc_lines[-1]))
    n_cols = int(round(2.0 * meta.rpb["samp_off"] + 2.0)) if meta.rpb is not None else meta.n_cols
    return n_rows, n_cols


def _satellite_caveat(satellite: str) -> str:
    if satellite in DIGITALGLOBE_VERIFIED:
        return ""
    return (f"gcpcal's DigitalGlobe conventions are established on {' and '.join(DIGITALGLOBE_VERIFIED)} "
            f"products only, and this product does not confirm them for {satellite} "
            f"({DIGITALGLOBE_SATELLITES.get(satellite, 'unknown')})")


def check_worldview_pointing(meta) -> None:
    """Refuse a product whose attitude does not point the camera at the Earth.

    The scene-centre detector's line of sight at mid-scene, from the raw ``ATT`` quaternion
    and the ``GEO`` camera, must reach the ellipsoid; a wrong quaternion order or direction
    sends it into space, and no model can then be built to compare with anything.

    Raises
    ------
    ProductDisagreementError
        Naming the satellite and the ``IMD`` corners' centre.
    """
    from scipy.spatial.transform import Rotation

    from sensor_models.geometry.ephemeris import Attitude, Orbit
    from sensor_models.readers.worldview_los import camera_tangents
    from sensor_models.terrain.ellipsoid import intersect_ellipsoid

    band = meta.bands[0]
    t = float(np.mean(meta.seconds(np.array([0.5, meta.tlc_lines[-1] + 0.5]))))
    orbit = Orbit(meta.epoch, meta.ephemeris_seconds, meta.position_m, meta.velocity_m_s, frame="itrf")
    attitude = Attitude(meta.attitude_seconds, meta.quaternions_xyzw, frame="itrf")
    tx, ty = camera_tangents(band, meta.principal_distance_mm, np.array([0.5 * (meta.n_cols - 1)]))
    u = np.array([tx[0], ty[0], 1.0])
    d = (attitude.rotation(np.array([t])) * Rotation.from_quat(meta.camera_to_body_xyzw)).apply(u / np.linalg.norm(u))
    pos, _ = orbit.state(np.array([t]))
    hit = intersect_ellipsoid(pos, d.reshape(1, 3), np.array([float(np.mean(band.corner_hae_m))]))
    if not np.all(np.isfinite(hit)):
        caveat = _satellite_caveat(meta.satellite)
        raise ProductDisagreementError(
            f"DigitalGlobe XML product of {meta.satellite} disagrees with its own statements: the line of sight "
            f"built from its ATT quaternions (q4 scalar, body -> ECEF) and GEO camera misses the Earth, while its "
            f"IMD corners lie around lon {np.mean(band.corner_lon):.4f}, lat {np.mean(band.corner_lat):.4f}"
            + (f"; {caveat}" if caveat else ""), path=meta.path)


def _refraction_limit_m(fold, meta, tan_z: float, heights) -> float:
    """How far straight rays folded at one height err at other heights (refraction, m)."""
    from sensor_models.readers.worldview_los import refraction_displacement_m

    fold = fold or {}
    h_ref = fold.get("refraction_height_m")
    if h_ref is None or not fold.get("refraction_shift_m") or max(np.abs(fold["refraction_shift_m"])) == 0.0:
        return 0.0
    z = np.arctan(tan_z)
    lat = float(np.mean(meta.bands[0].corner_lat))
    d = refraction_displacement_m(z, np.asarray(heights, dtype=float), lat) - refraction_displacement_m(z, h_ref, lat)
    return float(np.max(np.abs(d)))


def check_worldview(model, meta, fold, policy: str) -> ProductCheck:
    """A DigitalGlobe product's model against its ``IMD`` corners and its ``RPB``.

    Parameters
    ----------
    model : PushbroomModel
        From :func:`~sensor_models.readers.worldview.read_worldview` (bands named by ``BANDID``).
    meta : WorldViewMetadata
    fold : dict or None
        The fold's statistics from :func:`~sensor_models.readers.worldview_los.build_model`
        (``refraction_height_m`` and ``refraction_shift_m`` set the tolerance's refraction
        term; None or empty: no such term).
    policy : {"refuse", "warn"}

    Returns
    -------
    ProductCheck
        Comparisons ``corners`` (every modelled band's four corners at their ``HAE``, max) and,
        with an RPB, ``rpc_grid`` (reference band, rms).
    """
    n_rows, n_cols = worldview_collected_extent(meta)
    row = np.array([0.5, 0.5, n_rows - 0.5, n_rows - 0.5])
    col = np.array([0.5, n_cols - 0.5, n_cols - 0.5, 0.5])
    ref = model.reference_band
    h_mid = float(np.mean(meta.band(ref).corner_hae_m))
    tan_z = view_tangent(model, n_rows / 2, n_cols / 2, h_mid, band=ref)
    rpc = meta.rpc_model()
    if rpc is not None and rpc.err_rand is not None and rpc.err_rand > 0.0:
        base = (np.sqrt(2.0) * rpc.err_rand, f"sqrt(2) x RPB ERRRAND {rpc.err_rand:g} m per axis")
    else:
        base = _half_pixel(model, n_rows / 2, n_cols / 2, h_mid, ref)
    misses, lons, lats, haes = [], [], [], []
    for name in model.bands:
        band = meta.band(name)
        misses.append(localization_misses_m(model, row, col, band.corner_lon, band.corner_lat,
                                            band.corner_hae_m, band=name))
        lons.append(band.corner_lon), lats.append(band.corner_lat), haes.append(band.corner_hae_m)
    rounding = coordinate_rounding_m(np.concatenate(lons), np.concatenate(lats), np.concatenate(haes),
                                     view_tangent_value=tan_z)
    refr = _refraction_limit_m(fold, meta, tan_z, np.concatenate(haes))
    tol = Tolerance.combine(base, (rounding, "corner rounding"), (refr, "refraction's height dependence"))
    comparisons = [compare("corners", f"IMD corners at their HAE ({', '.join(model.bands)})", np.concatenate(misses),
                           "max", tol)]
    if rpc is not None:
        heights = rpc.height_off + rpc.height_scale * np.linspace(-1.0, 1.0, RPC_GRID_HEIGHTS)
        refr_rpc = _refraction_limit_m(fold, meta, tan_z, heights)
        comparisons.append(check_rpc(model, rpc, n_rows, n_cols, band=ref, base=base,
                                     extra=((refr_rpc, "refraction's height dependence"),)))
    notes = [f"collected extent {n_rows} x {n_cols} pixels (corners at its first and last pixel centres)"]
    if meta.satellite not in DIGITALGLOBE_VERIFIED:
        notes.append(f"{meta.satellite}: conventions verified by this product's own statements only")
    return ProductCheck(product=meta.path, reader="DigitalGlobe XML", satellite=meta.satellite, policy=policy,
                        comparisons=tuple(comparisons), notes=tuple(notes),
                        caveat=_satellite_caveat(meta.satellite))


# ---------------------------------------------------------------------------------------------
# SPOT 1-5 DIMAP


def _frame_points(meta):
    rows = np.append(meta.vertex_row, meta.center_row)
    cols = np.append(meta.vertex_col, meta.center_col)
    lons = np.append(meta.vertex_lon, meta.center_lon)
    lats = np.append(meta.vertex_lat, meta.center_lat)
    return rows, cols, lons, lats


def check_dimap(model, meta, attitude: str, policy: str, build) -> ProductCheck:
    """A SPOT 1-5 model against the DIMAP frame vertices and scene centre.

    The frame was computed by SPOT's ground segment with the attitude of
    :data:`SPOT_FRAME_ATTITUDE` (nominal for SPOT 1-4); when the model was opened with another
    one, the check compares the frame with the model built with the frame's attitude (same
    orbit, timing, frames and look angles: the conventions under test) and notes how far the
    model as opened lies from the frame.

    Parameters
    ----------
    model : PushbroomModel
    meta : DimapMetadata
    attitude : {"measured", "nominal"}
        The attitude ``model`` was built with.
    policy : {"refuse", "warn"}
    build : callable
        ``build(attitude) -> PushbroomModel``: the same product with another attitude.

    Returns
    -------
    ProductCheck
        One comparison ``frame`` (5 points, max). The vertices are localized at the tie points'
        ``TIE_POINT_CRS_Z`` and the centre at their mean; when a vertex has no tie point, one
        common height is fitted to all five points instead.
    """
    frame_attitude = SPOT_FRAME_ATTITUDE.get(meta.mission, "measured")
    ref = model if attitude == frame_attitude else build(frame_attitude)
    band = ref.reference_band
    rows, cols, lons, lats = _frame_points(meta)
    notes = []
    if np.all(np.isfinite(meta.vertex_h_m)):
        heights = np.append(meta.vertex_h_m, np.mean(meta.vertex_h_m))
        misses = localization_misses_m(ref, rows, cols, lons, lats, heights, band=band)
        where = "at the tie points' heights"
    else:
        h, misses = fit_common_height(ref, rows, cols, lons, lats, band=band)
        heights = np.full(rows.shape, h)
        where = f"at the one height that fits them, {h:.2f} m (no tie-point height for every vertex)"
        notes.append(f"fitted common height {h:.2f} m")
    tan_z = view_tangent(ref, meta.center_row, meta.center_col, float(heights[-1]), band=band)
    rounding = coordinate_rounding_m(lons, lats, heights, view_tangent_value=tan_z)
    tol = Tolerance.combine(_half_pixel(ref, meta.center_row, meta.center_col, float(heights[-1]), band),
                            (rounding, "coordinate rounding"))
    if ref is not model:
        opened = localization_misses_m(model, rows, cols, lons, lats, heights, band=band)
        notes.append(f"the frame was computed with the {frame_attitude} attitude, which the check uses; the model "
                     f"as opened ({attitude} attitude) lies {np.nanmax(opened):.3g} m at most from it")
    comparison = compare("frame", f"frame vertices and scene centre {where} ({frame_attitude} attitude)", misses,
                         "max", tol)
    return ProductCheck(product=meta.path, reader="SPOT 1-5 DIMAP", satellite=f"SPOT{meta.mission}",
                        policy=policy, comparisons=(comparison,), notes=tuple(notes))


# ---------------------------------------------------------------------------------------------
# DIMAP v2


def check_dimap_v2(model, meta, policy: str, rpc=None) -> ProductCheck:
    """A SPOT 6/7 or Pleiades model against its ``Dataset_Extent`` (and its RPC, when given).

    Parameters
    ----------
    model : PushbroomModel
    meta : DimapV2Metadata
    policy : {"refuse", "warn"}
    rpc : RpcModel, optional
        The product's RPC, in gcpcal's pixel convention.

    Returns
    -------
    ProductCheck
        ``frame``: the four vertices and the centre localized at the one height that fits them
        best (the product states none; searched within -500 to 9000 m), max; ``rpc_grid`` when
        an RPC is given (rms).
    """
    band = model.reference_band
    rows, cols, lons, lats = _frame_points(meta)
    h, misses = fit_common_height(model, rows, cols, lons, lats, band=band)
    tan_z = view_tangent(model, meta.center_row, meta.center_col, h, band=band)
    tol = Tolerance.combine(_half_pixel(model, meta.center_row, meta.center_col, h, band),
                            (coordinate_rounding_m(lons, lats), "coordinate rounding"))
    comparisons = [compare("frame", f"Dataset_Extent vertices and centre at the one height that fits them, {h:.2f} m",
                           misses, "max", tol)]
    notes = [f"fitted common height of the Dataset_Extent {h:.2f} m (the product states none)",
             f"tan of the view zenith angle {tan_z:.3f}"]
    if rpc is not None:
        comparisons.append(check_rpc(model, rpc, meta.n_rows, meta.n_cols, band=band))
    elif meta.rpc_href:
        notes.append(f"the product's RPC {meta.rpc_href} was not compared (not beside the metadata, or not in a form "
                     "gcpcal reads)")
    return ProductCheck(product=meta.path, reader="DIMAP v2", satellite=f"{meta.mission}{meta.mission_index}",
                        policy=policy, comparisons=tuple(comparisons), notes=tuple(notes))
