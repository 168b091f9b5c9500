"""Terrain shape and lakes of the procedural reference DEM.

:func:`draw_terrain` builds the land shape on the extended DEM grid (fBm relief by spectral
synthesis [1]_, ridged multifractal [2]_, mountain mask, coast and its taper, the exponent
``gamma``); :func:`fill_lakes` fills local basins to random areas without spilling. The
equations are in the notes of :mod:`sensor_models.simulate.procedural`.

References
----------
.. [1] R. F. Voss, "Fractals in nature: from characterization to simulation", in H.-O. Peitgen
   and D. Saupe (eds.), The Science of Fractal Images, Springer, 1988, pp. 21-70.
.. [2] F. K. Musgrave, "Methods for realistic landscape imaging", PhD thesis, Yale University,
   1993; and D. S. Ebert et al., Texturing and Modeling: A Procedural Approach, 3rd ed., 2003,
   ch. 16 (ridged multifractal terrain).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage

from sensor_models.simulate.procedural_noise import smoothstep, value_noise

#: Nodes added around the DEM grid while generating (Keys interpolation needs 2).
MARGIN_NODES = 4
#: Exponent of u in the height of the land when there is no sea.
_GAMMA_NO_SEA = 1.6
#: Hurst exponent of the fBm relief and wavelength below which it is rolled off, metres.
_HURST = 0.8
_ROLL_OFF_M = 400.0


@dataclass
class TerrainFields:
    """Fields on the extended DEM grid (float32, shape of ``ext``)."""

    u: np.ndarray          # normalised land shape in [0, 1] (0 over the sea)
    shape: np.ndarray      # u ** gamma before lakes and rivers
    coast: np.ndarray      # coast field c, metres (sea where c < c0)
    c0: float
    tau: np.ndarray        # coastal taper in [0, 1]
    land: np.ndarray       # bool
    gamma: float
    in_area: np.ndarray    # bool: the nodes of the output DEM


def draw_terrain(args, ext, centre, rng, keys) -> TerrainFields:
    """The land shape, coast and land mask on the extended DEM grid ``ext`` (module notes of
    :mod:`sensor_models.simulate.procedural`, "Terrain"), drawn from ``rng`` and ``keys``."""
    res = ext.res_m
    x = ext.x_m() - centre[0]
    y = ext.y_m() - centre[1]
    fbm, ridged = _spectral_relief(rng, ext.shape, res)
    mountains = smoothstep(-0.3, 1.0, value_noise(next(keys), x, y, 30_000.0))
    s = 0.45 * (0.35 + 0.65 * mountains) * fbm + mountains * ridged
    del fbm, ridged

    in_area = np.zeros(ext.shape, dtype=bool)
    in_area[ext.inner(MARGIN_NODES)] = True
    diag_m = math.hypot(args["width_m"], args["height_m"])
    if args["sea_fraction"] > 0.0:
        phi = rng.uniform(0.0, 2.0 * math.pi)
        coast = (np.cos(phi) * x)[None, :] + (np.sin(phi) * y)[:, None]
        spacing, amp = 0.5 * diag_m, 0.09 * diag_m
        while spacing >= 2.0 * res:
            coast += amp * value_noise(next(keys), x, y, spacing)
            spacing, amp = 0.5 * spacing, amp * 0.5**0.8
        coast = coast.astype(np.float32)
        c0 = float(np.quantile(coast[in_area], args["sea_fraction"]))
        land = coast >= c0
        tau = smoothstep(0.0, min(5000.0, 0.2 * diag_m), coast - c0).astype(np.float32)
    else:
        coast = np.full(ext.shape, np.float32(1e9), dtype=np.float32)
        c0 = -math.inf
        land = np.ones(ext.shape, dtype=bool)
        tau = np.ones(ext.shape, dtype=np.float32)

    land_area = land & in_area
    if not land_area.any():
        land_area = in_area
    s_lo = float(s[land_area].min())
    s_span = float(s[land_area].max()) - s_lo
    u = (s - s_lo + 0.03 * s_span) * tau
    u_hi = float(u[land_area].max())
    u = np.clip(u / u_hi if u_hi > 0.0 else u * 0.0, 0.0, 1.0).astype(np.float32)
    u[~land] = 0.0

    if args["sea_fraction"] > 0.0 and args["relief_m"] > 0.0:
        sample = u[land_area][::7].astype(np.float64)
        target = (args["mean_height_m"] - args["sea_level_m"]) / args["relief_m"]
        lo, hi = 0.2, 8.0
        for _ in range(40):
            mid = math.sqrt(lo * hi)
            if float(np.mean(sample**mid)) > target:
                lo = mid
            else:
                hi = mid
        gamma = math.sqrt(lo * hi)
    else:
        gamma = _GAMMA_NO_SEA
    shape = np.power(u, np.float32(gamma)).astype(np.float32)
    return TerrainFields(u=u, shape=shape, coast=coast, c0=c0, tau=tau, land=land, gamma=gamma,
                    in_area=in_area)


def _spectral_relief(rng, shape, res_m):
    """Fractional Brownian surface and ridged multifractal, unit scale, float32 (Voss; Musgrave).

    Returns
    -------
    fbm : ndarray, shape ``shape``
        Zero mean, unit standard deviation; power spectrum ``(k^2 + k0^2)^(-beta/2)``.
    ridged : ndarray, shape ``shape``
        In [0, ~1.6]: crests where the band-pass fields cross zero.
    """
    n_r, n_c = shape
    ky = sp_fft.fftfreq(n_r, d=res_m).astype(np.float32)[:, None]
    kx = sp_fft.rfftfreq(n_c, d=res_m).astype(np.float32)[None, :]
    k = np.sqrt(ky * ky + kx * kx)
    k[0, 0] = np.float32(1e-12)
    beta, k0, k1 = 2.0 * _HURST + 2.0, 1.0 / 40_000.0, 1.0 / _ROLL_OFF_M
    spectrum = sp_fft.rfft2(rng.standard_normal(shape, dtype=np.float32), workers=1)
    filt = (k * k + np.float32(k0 * k0)) ** np.float32(-beta / 4.0)
    filt *= np.exp(-((k / np.float32(k1)) ** 2))
    filt[0, 0] = 0.0
    fbm = sp_fft.irfft2(spectrum * filt, s=shape, workers=1)
    fbm = _standardised(fbm)

    spectrum = sp_fft.rfft2(rng.standard_normal(shape, dtype=np.float32), workers=1)
    log2k = np.log2(k)
    ridged = np.zeros(shape, dtype=np.float32)
    weight = np.ones(shape, dtype=np.float32)
    for j, wavelength in enumerate((12_000.0, 6000.0, 3000.0, 1500.0, 750.0)):
        if wavelength < 4.0 * res_m:
            break
        band = np.exp(-0.5 * ((log2k + np.float32(math.log2(wavelength))) / 0.6) ** 2)
        band[0, 0] = 0.0
        n = _standardised(sp_fft.irfft2(spectrum * band.astype(np.float32), s=shape, workers=1))
        signal = np.maximum(1.0 - 0.5 * np.abs(n), 0.0) ** 2
        signal *= weight
        weight = np.clip(2.0 * signal, 0.0, 1.0)
        ridged += np.float32(2.0 ** (-1.5 * j)) * signal
    return fbm.astype(np.float32), ridged


def _standardised(a):
    a = a.astype(np.float32, copy=False)
    a -= np.float32(a.mean(dtype=np.float64))
    std = float(a.std(dtype=np.float64))
    if std > 0.0:
        a *= np.float32(1.0 / std)
    return a


@dataclass
class LakeFields:
    """Lakes on the extended DEM grid: their levels, their mask and the terrain shape with them."""

    level: np.ndarray      # lake level (shape units) near each lake, NaN elsewhere (ext grid)
    mask: np.ndarray       # bool: lake nodes (ext grid)
    shape: np.ndarray      # terrain shape with flat lakes


def fill_lakes(args, ext, terrain, rng, area_km2) -> LakeFields:
    """Fill local basins of the terrain to random areas without spilling.

    See the notes of :mod:`sensor_models.simulate.procedural`.
    """
    shape = terrain.shape.copy()
    level = np.full(ext.shape, np.nan, dtype=np.float32)
    mask = np.zeros(ext.shape, dtype=bool)
    n_lakes = args["n_lakes"]
    if n_lakes is None:
        n_lakes = int(round(area_km2 / 200.0))
    res = ext.res_m
    size = max(3, int(round(1500.0 / res)) | 1)
    if n_lakes == 0 or min(ext.shape) < 2 * size:
        return LakeFields(level, mask, shape)
    minima = ndimage.minimum_filter(shape, size=size, mode="nearest") == shape
    candidates = (minima & terrain.land & terrain.in_area & (terrain.tau > 0.6)
                  & (terrain.u < 0.6) & (terrain.coast - terrain.c0 > 500.0))
    rows, cols = np.nonzero(candidates)
    if rows.size == 0:
        return LakeFields(level, mask, shape)
    order = rng.permutation(rows.size)[: 4 * n_lakes]
    made = 0
    for i in order:
        if made == n_lakes:
            break
        target_nodes = rng.uniform(0.1, min(2.5, 0.02 * area_km2)) * 1e6 / res**2
        half = int(3.0 * math.sqrt(target_nodes / math.pi)) + 3
        r, c = int(rows[i]), int(cols[i])
        r0, r1 = max(r - half, 0), min(r + half + 1, ext.n_rows)
        c0, c1 = max(c - half, 0), min(c + half + 1, ext.n_cols)
        window = shape[r0:r1, c0:c1]
        blocked = ~terrain.land[r0:r1, c0:c1] | mask[r0:r1, c0:c1]
        component, value = _fill_basin(window, blocked, (r - r0, c - c0), target_nodes)
        if component is None:
            continue
        made += 1
        shape[r0:r1, c0:c1][component] = value
        mask[r0:r1, c0:c1] |= component
        # The level is kept on the lake and on the shore nodes above it, so the DOM's
        # shoreline (interpolated terrain = level) is drawn there and nowhere else.
        near = ndimage.binary_dilation(component, iterations=2) & (component | (window > value))
        lv = level[r0:r1, c0:c1]
        lv[near & np.isnan(lv)] = value
    return LakeFields(level, mask, shape)


def _fill_basin(window, blocked, seed_rc, target_nodes):
    """Highest level whose basin around ``seed_rc`` stays under ``target_nodes`` and inside.

    Binary search over the sorted heights of the window; a basin touching the window's edge
    or a blocked node (sea, another lake) has spilled. Returns (component, level) or
    (None, None) when the basin is smaller than 4 nodes.
    """
    heights = np.unique(window[~blocked])
    structure = np.ones((3, 3), dtype=bool)

    def basin(level):
        labels, _ = ndimage.label(window <= level, structure=structure)
        lab = labels[seed_rc]
        if lab == 0:
            return None
        comp = labels == lab
        edge = comp[0].any() or comp[-1].any() or comp[:, 0].any() or comp[:, -1].any()
        if edge or (comp & blocked).any() or comp.sum() > target_nodes:
            return None
        return comp

    lo, hi = 0, heights.size - 1
    best = None
    while lo <= hi:
        mid = (lo + hi) // 2
        comp = basin(heights[mid])
        if comp is None:
            hi = mid - 1
        else:
            best = (comp, float(heights[mid]))
            lo = mid + 1
    if best is None or best[0].sum() < 4:
        return None, None
    return best
