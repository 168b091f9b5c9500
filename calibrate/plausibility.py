"""Plausibility of a stage's inputs, checked before any work: figures a real input cannot have.

A file can be well formed and still not be what the command needs: a DEM in centimetres, a
reference orthoimage far coarser than the scene, the raster of another band, a GCP table of
another scene. Each gives results that look like results (GCPs, a calibration), so each is
refused here, before the work, in one line naming the file and the figure. Where a user can
know better (a DEM of the sea floor, a coarse reference accepted knowingly) the commands'
``--allow-implausible`` option turns the refusal into a warning (``gcpcal: warning: ...`` on
stderr, and ``implausible_accepted`` in the summaries of ``match`` and ``calibrate``): the CLI runs
the stage inside :func:`accepting_implausible`, which every check consults when its ``allow`` is
None; a library caller passes ``allow=True`` or uses the same context manager.

=====================================  =========================================================
check                                  refused when
=====================================  =========================================================
:func:`check_dem_heights`              a DEM height over the scene's footprint lies outside
                                       :data:`PLAUSIBLE_HEIGHTS_M`
:func:`check_dom_resolution`           the DOM's pixel is more than :data:`MAX_DOM_GSD_RATIO`
                                       times the scene's ground sampling distance
:func:`check_scene_raster`             the raster given for a band is the manifest's raster of
                                       another band, or says (band description, tags, file
                                       name) that it holds another band
:func:`check_gcps_on_scene`            GCP heights outside :data:`PLAUSIBLE_HEIGHTS_M`, or most
                                       GCPs outside the scene's footprint (with the margin an
                                       uncalibrated model needs)
=====================================  =========================================================
"""

from __future__ import annotations

import contextlib
import contextvars
import re
from pathlib import Path

import numpy as np

from sensor_models.errors import ImplausibleInputError

__all__ = ["ALLOW_OPTION", "FOOTPRINT_MARGIN", "accepting_implausible", "MAX_DOM_GSD_RATIO", "PLAUSIBLE_HEIGHTS_M", "check_dem_heights",
           "check_dom_resolution", "check_gcps_on_scene", "check_scene_raster"]

#: The option that accepts an implausible input (a warning instead of the refusal).
ALLOW_OPTION = "--allow-implausible"

#: Heights a terrain surface can have, metres above the WGS84 ellipsoid. The lowest dry land,
#: the Dead Sea shore, is about -430 m above the geoid and the highest, Everest, 8849 m; the
#: geoid lies between -106 and +85 m from the ellipsoid (EGM96), so every land height on Earth
#: (SRTM's range, -415..8752 m orthometric) is inside -500..9000 m whichever datum the DEM
#: uses. A DEM scaled into centimetres or decimetres (a unit error) leaves this range as soon as
#: its relief exceeds 90 m or 900 m.
PLAUSIBLE_HEIGHTS_M = (-500.0, 9000.0)

#: Largest ratio of the DOM's pixel to the scene's ground sampling distance. Matching compares
#: the scene with the DOM resampled into scene geometry: a DOM r times coarser holds no texture
#: above 1/(2 r) cycles per scene pixel, so a 64-pixel window sees 64/(2 r) cycles at most and
#: the sub-pixel phase estimate degrades in proportion to r (the fundamental of phase
#: correlation is the shared high-frequency content; Foroosh et al. 2002, IEEE TIP 11(3); Leprince
#: et al. 2007, IEEE TGRS 45(6) on aliasing bias). Landsat's 15/30 m DOM for 16 to 50 m scenes
#: (seed 003) is a ratio of 0.3 to 2. Measured on the two 30 m demo scenes
#: (``bench/bench_dom_ratio.py``, GCP truth RMS against the TRUE model): ratio 1: 0.02 / 0.10 px
#: (ideal / realistic profile), 2: 0.07 / 0.12 px, 3: 0.20 / 0.24 px, 4: 0.42 / 0.45 px, 4.9:
#: 0.69 px; the GCPs' stated ``sigma_px`` barely grows (0.03 to 0.06 px, 0.07 to 0.08 px), so past
#: 4 the truth error is more than 0.4 px and 6 to 11 times the sigma the table states.
MAX_DOM_GSD_RATIO = 4.0

#: Margin around a scene's footprint within which its GCPs must lie, as a share of the
#: footprint's larger side (the room :func:`calibrate.actions._io.open_dem` leaves for an
#: uncalibrated model off by hundreds of pixels).
FOOTPRINT_MARGIN = 0.5

#: Least share of a GCP table that must lie on the scene (the rest is the outlier rejection's).
_MIN_GCPS_ON_SCENE = 0.5


#: None: implausible inputs are refused; a list: they are accepted, and their warnings collected there.
_ACCEPTED = contextvars.ContextVar("gcpcal_accepted_implausible", default=None)


@contextlib.contextmanager
def accepting_implausible(allow: bool = True):
    """Within the block, checks called with ``allow=None`` warn instead of refusing (``--allow-implausible``).

    Parameters
    ----------
    allow : bool
        Whether implausible inputs are accepted in the block.

    Yields
    ------
    list of str
        The warnings of the inputs accepted in the block (the CLI prints them at its end).
    """
    accepted: list[str] = []
    token = _ACCEPTED.set(accepted if allow else None)
    try:
        yield accepted
    finally:
        _ACCEPTED.reset(token)


def _refuse_or_warn(message: str, *, path, allow: bool | None) -> list[str]:
    """Raise the refusal, or (``allow``) return it as a warning (also collected for the CLI)."""
    accepted = _ACCEPTED.get()
    if allow is None:
        allow = accepted is not None
    if not allow:
        raise ImplausibleInputError(f"{message} ({ALLOW_OPTION} to proceed)", path=None if path is None else str(path))
    line = f"{path}: {message} (accepted: {ALLOW_OPTION})" if path is not None else message
    if accepted is not None:
        accepted.append(line)
    return [line]


def check_dem_heights(dem, model, *, band=None, allow: bool | None = None) -> list[str]:
    """Refuse a DEM whose heights over the scene's footprint leave :data:`PLAUSIBLE_HEIGHTS_M`.

    The footprint is localized at the middle of the plausible range clipped to the DEM's own
    range (a centimetre DEM must not move it) on a 16 x 16 grid of the image; the DEM is
    sampled at those points (voids and points off the DEM are left to the coverage check).

    Parameters
    ----------
    dem : sensor_models.terrain.dem.Dem
        The DEM (heights in metres above the ellipsoid after its datum conversion).
    model : SensorModel
        The scene's model.
    band : str, optional
        Band whose footprint counts (default: the reference band).
    allow : bool, optional
        Warn instead of refusing (default: as :func:`accepting_implausible` says, else refuse).

    Returns
    -------
    list of str
        The warning (with ``allow``), else empty.

    Raises
    ------
    ImplausibleInputError
        Naming the DEM, the heights found and the range accepted.
    """
    from sensor_models.terrain.footprint import footprint_sample_lonlat

    low, high = PLAUSIBLE_HEIGHTS_M
    h_lo, h_hi = dem.height_range_m
    h_mid = float(np.clip(0.5 * (max(h_lo, low) + min(h_hi, high)), low, high)) if np.isfinite(h_lo + h_hi) else 0.0
    lon, lat = footprint_sample_lonlat(model, h_mid, n_side=16, band=band)
    if lon.size == 0:
        return []
    h = np.asarray(dem.height_m(lon, lat), dtype=np.float64)
    h = h[np.isfinite(h)]
    if h.size == 0 or (h.min() >= low and h.max() <= high):
        return []
    return _refuse_or_warn(f"DEM heights {h.min():.0f}..{h.max():.0f} m over the scene's footprint, outside "
                           f"{low:.0f}..{high:.0f} m (Earth's land): heights in centimetres or decimetres, or scaled? "
                           "give them in metres", path=dem.source or "DEM", allow=allow)


def check_dom_resolution(dom, model, *, band=None, source=None, allow: bool | None = None) -> list[str]:
    """Refuse a DOM more than :data:`MAX_DOM_GSD_RATIO` times coarser than the scene.

    Parameters
    ----------
    dom : sensor_models.maps.raster.MapImage
        The reference orthoimage (``grid.resolution_m``: its pixel, metres).
    model : SensorModel
        The scene's model (:func:`sensor_models.imaging.ortho_grid.scene_gsd_m` at 0 m).
    band : str, optional
        Band matched (default: the reference band).
    source : str or Path, optional
        The DOM's file, named in the message.
    allow : bool, optional
        Warn instead of refusing (default: as :func:`accepting_implausible` says, else refuse).

    Returns
    -------
    list of str
        The warning (with ``allow``), else empty.
    """
    from sensor_models.imaging.ortho_grid import scene_gsd_m

    dom_m = float(dom.grid.resolution_m)
    gsd_m = float(scene_gsd_m(model, band=band))
    if not (np.isfinite(dom_m) and np.isfinite(gsd_m) and gsd_m > 0.0):
        return []
    ratio = dom_m / gsd_m
    if ratio <= MAX_DOM_GSD_RATIO:
        return []
    return _refuse_or_warn(f"the DOM's pixel is {dom_m:.1f} m, {ratio:.1f} times the scene's ground sampling "
                           f"distance ({gsd_m:.1f} m; at most {MAX_DOM_GSD_RATIO:g} times): GCPs matched on it "
                           "would be far less accurate than they state; give a finer reference",
                           path=source if source is not None else getattr(dom, "source", None) or "DOM", allow=allow)


def _band_tokens(text: str) -> set[str]:
    return {t.lower() for t in re.split(r"[^0-9A-Za-z]+", str(text)) if t}


def _raster_header(path, index: int) -> tuple[tuple[int, int] | None, list[str]]:
    """``(n_rows, n_cols)`` and the band description and band-naming tags of band ``index`` of a
    raster (header only); ``(None, [])`` when it cannot be opened (its reader says why)."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                shape = (ds.height, ds.width)
                if not 1 <= index <= ds.count:
                    return shape, []
                labels = [ds.descriptions[index - 1] or ""]
                for tags in (ds.tags(index), ds.tags()):
                    labels += [v for k, v in tags.items() if k.lower() in ("band", "band_name", "bandname", "band_id")]
    except RasterioError:
        return None, []  # unreadable: the reader says so with its own message
    return shape, [label for label in labels if label]


def check_scene_raster(scene, band, image, *, allow: bool | None = None) -> list[str]:
    """Refuse a raster given for ``band`` that is, or says it is, the raster of another band.

    Cheap checks on names and headers only: the file is the manifest's raster of another band;
    its band description or a ``BAND``-like tag names another of the model's bands and not
    ``band``; its file name holds another band's name as a word and not ``band``'s. A raster
    given of another size than the model's image (a crop has already cropped the model) is
    refused whatever ``allow`` says.

    Parameters
    ----------
    scene : Scene
        The scene opened (:func:`sensor_models.readers.open_scene`): its model's ``bands`` and
        its ``rasters`` (band -> ``{"path", "index"}``).
    band : str
        The band the raster is for.
    image : str or Path or None
        The raster given (``--image``); None: the manifest's own raster of ``band``.
    allow : bool, optional
        Warn instead of refusing (default: as :func:`accepting_implausible` says, else refuse).

    Returns
    -------
    list of str
        The warning (with ``allow``), else empty.
    """
    from sensor_models.errors import InputError

    model = scene.model
    if image is not None:
        shape = _raster_header(image, 1)[0]
        if shape is not None and tuple(shape) != tuple(model.image_shape):
            raise InputError(f"the raster is {shape[0]} x {shape[1]} px, the model describes {model.image_shape[0]} x "
                             f"{model.image_shape[1]} px: not this scene's raster", path=str(image))
    bands = [str(b) for b in (getattr(model, "bands", None) or ())]
    if band is None or len(bands) < 2:
        return []
    rasters = scene.rasters
    if image is None:
        ref = rasters.get(band)
        if ref is None:
            return []
        path, index = Path(ref["path"]), int(ref.get("index", 1))
    else:
        path, index = Path(image), 1
    others = [b for b in bands if b != band]
    resolved = path.resolve()
    for other in others:
        ref = rasters.get(other)
        if image is not None and ref is not None and Path(ref["path"]).resolve() == resolved \
                and int(ref.get("index", 1)) == index:
            return _refuse_or_warn(f"given for band {band}, but the manifest lists this file as band {other}'s raster",
                                   path=path, allow=allow)
    own = {band.lower()}
    for label in _raster_header(path, index)[1]:
        said = _band_tokens(label)
        named = [b for b in others if b.lower() in said]
        if named and not own & said:
            return _refuse_or_warn(f"given for band {band}, but its band {index} says {label!r} (band {named[0]})",
                                   path=path, allow=allow)
    if image is not None:
        said = _band_tokens(path.stem)
        named = [b for b in others if b.lower() in said]
        if named and not own & said:
            return _refuse_or_warn(f"given for band {band}, but its name says band {named[0]}", path=path, allow=allow)
    return []


def check_gcps_on_scene(model, lon, lat, h, *, source, band=None, allow: bool | None = None) -> list[str]:
    """Refuse GCPs with implausible heights or, for most of them, ground off the scene.

    The footprint is the image's border localized at the GCPs' lowest and highest heights,
    as a lon/lat box grown by :data:`FOOTPRINT_MARGIN` of its larger side on each side (an
    uncalibrated model may be off by hundreds of pixels); more than half of the GCPs outside
    it is a table of another scene (or of other coordinates: projected metres, swapped axes).

    Parameters
    ----------
    model : SensorModel
        The scene's model.
    lon, lat : array_like, shape (N,)
        GCP ground coordinates, WGS84 degrees.
    h : array_like, shape (N,)
        GCP heights, metres above the ellipsoid.
    source : str or Path
        The GCP table, named in the message.
    band : str, optional
        Band whose footprint counts (default: the reference band).
    allow : bool, optional
        Warn instead of refusing (default: as :func:`accepting_implausible` says, else refuse).

    Returns
    -------
    list of str
        The warnings (with ``allow``), else empty.
    """
    from sensor_models.terrain.footprint import footprint_sample_lonlat

    lon, lat, h = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (lon, lat, h))
    finite = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)  # the readers refuse the others
    lon, lat, h = lon[finite], lat[finite], h[finite]
    if lon.size == 0:
        return []
    low, high = PLAUSIBLE_HEIGHTS_M
    out = []
    bad_h = (h < low) | (h > high)
    if bad_h.any():
        out += _refuse_or_warn(f"{int(bad_h.sum())} of {h.size} GCP heights outside {low:.0f}..{high:.0f} m "
                               f"({h.min():.0f}..{h.max():.0f} m): heights of a DEM in centimetres or decimetres? "
                               "(column h, metres above the ellipsoid)", path=source, allow=allow)
    h_ok = np.clip(h, low, high)
    parts = [footprint_sample_lonlat(model, z, n_side=9, band=band) for z in (float(h_ok.min()), float(h_ok.max()))]
    f_lon = np.concatenate([p[0] for p in parts])
    f_lat = np.concatenate([p[1] for p in parts])
    if f_lon.size == 0 or np.ptp(f_lon) > 180.0:  # off the Earth, or across the antimeridian
        return out
    g_lon = f_lon[0] + (lon - f_lon[0] + 180.0) % 360.0 - 180.0  # GCP longitudes on the footprint's side
    margin = FOOTPRINT_MARGIN * max(np.ptp(f_lon), np.ptp(f_lat))
    box = (f_lon.min() - margin, f_lat.min() - margin, f_lon.max() + margin, f_lat.max() + margin)
    outside = (g_lon < box[0]) | (g_lon > box[2]) | (lat < box[1]) | (lat > box[3])
    if outside.mean() <= 1.0 - _MIN_GCPS_ON_SCENE:
        return out
    c_lat = np.radians(0.5 * (f_lat.min() + f_lat.max()))
    dx = np.maximum(np.maximum(box[0] - g_lon, g_lon - box[2]), 0.0) * np.cos(c_lat)
    dy = np.maximum(np.maximum(box[1] - lat, lat - box[3]), 0.0)
    km = float(np.median(np.hypot(dx, dy)[outside])) * 111.32  # degrees of arc to km
    center = (float(np.median(lon)), float(np.median(lat)))
    out += _refuse_or_warn(f"{int(outside.sum())} of {lon.size} GCPs lie outside the scene's footprint (lon "
                           f"{f_lon.min():.3f}..{f_lon.max():.3f}, lat {f_lat.min():.3f}..{f_lat.max():.3f}, plus "
                           f"{100 * FOOTPRINT_MARGIN:.0f} % for the model's error), a median {km:.1f} km beyond it "
                           f"(GCPs around lon {center[0]:.3f}, lat {center[1]:.3f}): a GCP table of another scene?",
                           path=source, allow=allow)
    return out
