"""Clouds with a height: parallax in the scene and shadows on the ground (``realistic`` profile).

The cloud cover is drawn as in the ``ideal`` simulator (a smooth random field thresholded to the
requested cover, soft edges), but on the ground grid of the source radiance and with a height:
every cloud (a connected core of opacity > 0.5 with the soft edge nearest to it) is put in one of
``n_layers`` layers, each layer with its own top height
drawn uniformly in ``heights_km`` (:func:`cloud_layers`). A layer's opacity map ``o_k(p)`` holds
the cloud at the map position ``p`` of its nadir.

* Parallax (:func:`apparent_clouds`): a pixel whose line of sight meets the ground at ``g``
  (height ``h_g``) crosses layer ``k`` at ``g + (H_k - h_g) dg/dh``, ``dg/dh`` the horizontal
  motion of the line of sight per metre of height (from the TRUE model, :func:`ray_slope`); the
  pixel sees ``o_k`` there, composited with the higher layers in front.
* Shadow (:func:`ground_shadow`): the ground at ``g`` is in the shadow of layer ``k`` when
  ``o_k`` is set at ``g + (H_k - h_g) / tan(e) a``, ``a`` the horizontal unit vector towards the
  sun (azimuth ``A``, elevation ``e``): the shadow lies ``(H_k - h_g) / tan(e)`` away from the
  cloud's nadir, opposite the sun.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pyproj

from sensor_models.simulate.radiometry import smooth_field

__all__ = ["CloudLayers", "apparent_clouds", "cloud_layers", "ground_shadow", "ray_slope"]


@dataclass(frozen=True)
class CloudLayers:
    """Clouds on the ground grid of the source radiance, one opacity map per height.

    Attributes
    ----------
    opacity : ndarray of float32, shape (K, H, W)
        Opacity of each layer at its nadir position (0..1).
    heights_m : ndarray of float64, shape (K,)
        Top height of each layer above the ellipsoid, metres (ascending).
    texture : ndarray of float32, shape (H, W)
        Unit smooth field modulating the cloud brightness.
    """

    opacity: np.ndarray
    heights_m: np.ndarray
    texture: np.ndarray

    def to_dict(self) -> dict:
        """JSON-safe record: heights and the nadir cover of each layer."""
        return {"heights_m": [round(float(h), 1) for h in self.heights_m],
                "nadir_cover": [round(float((o > 0.5).mean()), 4) for o in self.opacity]}


def cloud_layers(shape, resolution_m: float, *, cover: float, scale_m: float, heights_km, n_layers: int,
                 mean_ground_m: float, seed: int) -> CloudLayers:
    """Draw the clouds of a scene (see the module docstring).

    Parameters
    ----------
    shape : (int, int)
        Ground grid rows and columns.
    resolution_m : float
        Grid spacing, metres.
    cover : float
        Share of the grid under cloud (opacity > 0.5), ``(0, 1]``.
    scale_m : float
        Correlation length of the cloud field, metres.
    heights_km : (float, float)
        Range of the layers' top heights above the ground, km.
    n_layers : int
        Distinct heights (each connected cloud is in one layer).
    mean_ground_m : float
        Mean ground height (ellipsoidal), added to the layers' heights.
    seed : int
        Pass seed.

    Returns
    -------
    CloudLayers
    """
    ss = np.random.SeedSequence([int(seed), 60])
    s_field, s_tex, s_draw = ss.spawn(3)
    f = smooth_field(shape, scale_m / resolution_m, s_field)
    thr = float(np.quantile(f, 1.0 - cover)) if cover < 1 else -np.inf
    op = np.clip((f - thr) / 0.3 + 0.5, 0.0, 1.0).astype(np.float32)
    # one cloud = one connected core (opacity > 0.5); its soft edge belongs to the nearest core
    n_labels, labels = cv2.connectedComponents((op > 0.5).astype(np.uint8), connectivity=8)
    if n_labels > 1:
        from scipy.ndimage import distance_transform_edt

        _, (ri, ci) = distance_transform_edt(labels == 0, return_distances=True, return_indices=True)
        labels = labels[ri, ci]
    rng = np.random.default_rng(s_draw)
    layer_of_label = rng.integers(0, max(1, n_layers), n_labels)
    heights = np.sort(rng.uniform(heights_km[0], heights_km[1], max(1, n_layers))) * 1000.0 + mean_ground_m
    layer = layer_of_label[labels]
    opacity = np.stack([np.where(layer == k, op, 0.0).astype(np.float32) for k in range(max(1, n_layers))])
    return CloudLayers(opacity, heights, smooth_field(shape, 2.0, s_tex))


def ground_shadow(layers: CloudLayers, ground_m: np.ndarray, resolution_m: float, sun) -> np.ndarray:
    """Opacity of the cloud shadow on every ground node, ``1 - prod_k (1 - o_k(g + (H_k - h_g) a / tan e))``.

    Parameters
    ----------
    layers : CloudLayers
        The clouds.
    ground_m : ndarray of float32, shape (H, W)
        Ground height on the same grid, metres (ellipsoidal).
    resolution_m : float
        Grid spacing, metres.
    sun : sensor_models.simulate.illumination.Sun
        The scene's sun.

    Returns
    -------
    ndarray of float32, shape (H, W)
        0 (lit) .. 1 (under an opaque cloud's shadow).
    """
    tan_e = np.tan(np.radians(sun.elevation_deg))
    az = np.radians(sun.azimuth_deg)
    rows, cols = np.mgrid[0 : ground_m.shape[0], 0 : ground_m.shape[1]].astype(np.float32)
    lit = np.ones(ground_m.shape, np.float32)
    for o, h in zip(layers.opacity, layers.heights_m):
        reach_px = (np.float32(h) - ground_m) / np.float32(tan_e * resolution_m)
        # clouds beyond the grid cast shadows on it too: the field is continued by reflection
        q = cv2.remap(o, _reflect(cols + reach_px * np.float32(np.sin(az)), o.shape[1]),
                      _reflect(rows - reach_px * np.float32(np.cos(az)), o.shape[0]), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE)
        lit *= 1.0 - q
    return 1.0 - lit


def _reflect(x, n: int):
    """Coordinates folded back into ``[0, n - 1]`` by mirror reflection (any distance)."""
    period = np.float32(2 * max(n - 1, 1))
    x = np.mod(x, period)
    return np.where(x > n - 1, period - x, x).astype(np.float32)


def ray_slope(model, grid, *, band: str, ccd: int, row: float, n_nodes: int = 9, h0_m: float = 0.0):
    """Horizontal motion of the lines of sight of one CCD per metre of height, on a map grid.

    Parameters
    ----------
    model : PushbroomModel
        The TRUE model.
    grid : sensor_models.maps.grid.MapGrid
        The ground grid (its ``transform`` and ``crs``).
    band : str
        Band.
    ccd : int
        CCD index in ``model.band_ccds(band)``.
    row : float
        Image line (continuous) where the slope is taken (it changes little along a block).
    n_nodes : int
        Detectors where it is computed exactly; linear in between.
    h0_m : float
        Height of the lower of the two localizations, metres.

    Returns
    -------
    du_dh, dv_dh : ndarray of float32, shape (n_detectors,)
        Grid columns and rows per metre of height for every detector of the CCD.
    """
    look = model.band_ccds(band)[ccd]
    s = np.linspace(0.0, look.n_detectors - 1.0, n_nodes)
    cols = look.first_col + s + 0.5
    to_map = pyproj.Transformer.from_crs("EPSG:4326", grid.crs, always_xy=True)
    uv = []
    for h in (h0_m, h0_m + 1000.0):
        lon, lat, _ = model.image_to_ground(np.full_like(cols, row), cols, height=h, band=band, array=ccd)
        x, y = to_map.transform(lon, lat)
        uv.append(((np.asarray(x) - grid.transform.c) / grid.transform.a, (np.asarray(y) - grid.transform.f) / grid.transform.e))
    du = (uv[1][0] - uv[0][0]) / 1000.0
    dv = (uv[1][1] - uv[0][1]) / 1000.0
    every = np.arange(look.n_detectors, dtype=np.float64)
    return np.interp(every, s, du).astype(np.float32), np.interp(every, s, dv).astype(np.float32)


def apparent_clouds(layers: CloudLayers, u, v, h_m, du_dh, dv_dh):
    """Opacity and brightness texture of the clouds each pixel sees, with parallax.

    Parameters
    ----------
    layers : CloudLayers
        The clouds (on the grid of ``u, v``).
    u, v : ndarray of float32, shape (L, N)
        Grid column and row of every pixel's ground point (0 at the first node).
    h_m : ndarray of float32, shape (L, N)
        Its ground height, metres.
    du_dh, dv_dh : ndarray of float32, shape (N,)
        Motion of the line of sight per metre of height (:func:`ray_slope`).

    Returns
    -------
    alpha : ndarray of float32, shape (L, N)
        Total opacity, the higher layers in front: ``1 - prod_k (1 - a_k)``.
    texture : ndarray of float32, shape (L, N)
        The cloud texture at the frontmost cloud seen.
    """
    alpha = np.zeros(u.shape, np.float32)
    texture = np.zeros(u.shape, np.float32)
    for o, h in zip(layers.opacity[::-1], layers.heights_m[::-1]):  # top layer first
        dh = np.float32(h) - h_m
        uu = u + dh * du_dh[None, :]
        vv = v + dh * dv_dh[None, :]
        a = cv2.remap(o, uu, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        t = cv2.remap(layers.texture, uu, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        texture += (1.0 - alpha) * a * t
        alpha += (1.0 - alpha) * a
    return alpha, np.where(alpha > 0, texture / np.maximum(alpha, 1e-6), 0.0).astype(np.float32)
