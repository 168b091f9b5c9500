"""Stage actions of ``gcpcal simulate ...`` and ``gcpcal truth error``: scenes with known truth.

The only action module that imports :mod:`sensor_models.simulate` (production stages never do).
"""

from __future__ import annotations

from dataclasses import replace

from calibrate.actions._guard import InputSet, is_stdout
from calibrate.actions._io import check_output_files, final_paths, open_dem, staged_files, staged_folder, write_summary
from calibrate.actions._status import require_usable, status_fields
from sensor_models.errors import InputError
from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

__all__ = ["PROFILE_NAMES", "pushbroom_config", "simulate_geo_earth_scene", "simulate_geo_star_frames",
           "simulate_pushbroom_scene", "simulate_validation_series", "truth_error_of"]


#: error profiles of ``gcpcal simulate pushbroom --profile`` (sensor_models.simulate.profiles.PROFILES)
PROFILE_NAMES = ("ideal", "realistic")


def pushbroom_config(config_path=None, seed=None):
    """The effective push-broom simulation configuration.

    Parameters
    ----------
    config_path : str or Path, optional
        JSON configuration (any subset of the defaults).
    seed : int, optional
        Overrides the configuration's seed.

    Returns
    -------
    sensor_models.simulate.config.SimConfig
        The configuration (``to_dict()`` gives its JSON form).
    """
    from sensor_models.simulate.config import load_config

    cfg = load_config(config_path)
    return cfg if seed is None else cfg.with_seed(seed)


def simulate_pushbroom_scene(out_dir, config, *, dom_path=None, dem_path=None, geoid=None, workers: int | None = None,
                             progress=None, profile: str = "ideal", config_path=None, model_path=None,
                             window=None) -> dict:
    """Render a level-1A push-broom scene through a TRUE model; write the LAB manifest and truth.

    Parameters
    ----------
    out_dir : str or Path
        Output folder.
    config : SimConfig
        From :func:`pushbroom_config`.
    dom_path, dem_path : str or Path, optional
        Reference orthoimage and DEM to render from (both or neither; default: procedural).
    geoid : str or Path, optional
        EGM96 grid for an orthometric DEM.
    workers : int or None
        Rendering threads (None or 0: ``GCPCAL_THREADS`` or every core).
    progress : callable(done, total), optional
        Called as rendering proceeds.
    profile : str
        Error profile name (:data:`PROFILE_NAMES`; ``ideal``: the simulator without added errors).
    config_path : str or Path, optional
        The file ``config`` was read from (an input: never written over).
    model_path : str or Path, optional
        A push-broom model file (a gcpcal manifest, SPOT 1-5 ``.DIM``, DIMAP v2 ``.XML``) to render
        through instead of the simulator's own camera: the TRUE model is it with the
        configuration's errors, ``manifest.json`` the model as delivered
        (:func:`sensor_models.simulate.pushbroom_sim.simulate_through_model`); needs ``dom_path``
        and ``dem_path``, ``profile`` ideal.
    window : (int, int, int, int), optional
        With ``model_path``: ``(row0, col0, rows, cols)`` of the model's pixels to render (default:
        the whole image).

    Returns
    -------
    dict
        The simulation summary (``image``, ``lab_truth_error_px``, ``render_seconds``, ...).
    """
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    if model_path is not None:
        return _simulate_through_model_file(out_dir, config, model_path, window, dom_path=dom_path,
                                            dem_path=dem_path, geoid=geoid, workers=workers, progress=progress,
                                            profile=profile, config_path=config_path)
    if window is not None:
        raise InputError("--window selects pixels of --model: give --model", field="window")
    with staged_folder(out_dir, ".simulate-", inputs=[dom_path, dem_path, geoid, config_path]) as stage:
        summary = simulate_pushbroom(stage, config=config, dom=dom_path, dem=dem_path, geoid=geoid, workers=workers,
                                     progress=progress, profile=profile)
    return final_paths(summary, stage, out_dir)


def _simulate_through_model_file(out_dir, config, model_path, window, *, dom_path, dem_path, geoid, workers,
                                 progress, profile, config_path) -> dict:
    """:func:`simulate_pushbroom_scene` through the model of ``model_path`` (a window of it)."""
    import os

    from sensor_models.models.pushbroom_window import window_model
    from sensor_models.readers.model_file import open_model
    from sensor_models.simulate.pushbroom_sim import simulate_through_model

    if profile != "ideal":
        raise InputError("--model renders with the ideal profile only", field="profile")
    if dom_path is None or dem_path is None:
        raise InputError("--model needs both --dom and --dem (the reference to render from)")
    model = open_model(model_path)
    if not hasattr(model, "line_timing"):
        raise InputError(f"not a push-broom model ({type(model).__name__}); --model needs a push-broom model "
                         "(a gcpcal manifest, SPOT 1-5 .DIM or DIMAP v2 .XML)", path=str(model_path))
    n_rows, n_cols = model.image_shape
    row0, col0, rows, cols = window if window is not None else (0, 0, n_rows, n_cols)
    windowed = window_model(model, row0, col0, rows, cols)
    source = {"model": os.path.abspath(model_path), "window": [int(row0), int(col0), int(rows), int(cols)],
              "model_shape": [int(n_rows), int(n_cols)]}
    with staged_folder(out_dir, ".simulate-", inputs=[model_path, dom_path, dem_path, geoid, config_path]) as stage:
        summary = simulate_through_model(stage, windowed, dom=dom_path, dem=dem_path, config=config, geoid=geoid,
                                         workers=workers, progress=progress, source=source)
    return final_paths(summary, stage, out_dir)


def simulate_validation_series(out_dir, n_scenes: int, *, seed: int = 0, config_path=None, cloud_fractions=(),
                               calibration_scene: bool = False, workers: int | None = None) -> list:
    """Validation scenes of one sensor (dates, sites, attitude biases, clouds) and their sites file.

    Parameters
    ----------
    out_dir : str or Path
        Output folder (``sites.yaml`` goes there).
    n_scenes : int
        Validation scenes.
    seed : int
        Seed of the series' draws.
    config_path : str or Path, optional
        Sensor configuration (JSON, as for the push-broom simulation).
    cloud_fractions : tuple of float
        Cloud covers cycled over the scenes, in ``[0, 1]``.
    calibration_scene : bool
        Also render a scene to calibrate the sensor on.
    workers : int or None
        Rendering threads per scene (None or 0: ``GCPCAL_THREADS`` or every core).

    Returns
    -------
    list
        The scene folders.
    """
    from sensor_models.simulate.config import load_config
    from sensor_models.simulate.series import simulate_series

    base_config = load_config(config_path)
    with staged_folder(out_dir, ".simulate-", inputs=[config_path]) as stage:
        folders = simulate_series(stage, n_scenes, base_config=base_config, seed=seed,
                                  cloud_fractions=tuple(cloud_fractions), calibration_scene=calibration_scene,
                                  workers=workers)
    return final_paths(folders, stage, out_dir)


def simulate_geo_earth_scene(out_dir, *, seed=None, config_path=None, dom_path=None, dem_path=None,
                             geoid=None) -> dict:
    """Render an Earth view of a geostationary staring camera through a TRUE model.

    Parameters
    ----------
    out_dir : str or Path
        Output folder.
    seed : int, optional
        Overrides the configuration's seed.
    config_path : str or Path, optional
        JSON configuration (any subset of the defaults).
    dom_path, dem_path : str or Path, optional
        Reference orthoimage and DEM (both or neither).
    geoid : str or Path, optional
        EGM96 grid for an orthometric DEM.

    Returns
    -------
    dict
        The simulation summary (``image``, ``lab_truth_error_px``, ...).
    """
    from sensor_models.simulate.geo_sim import load_geo_config, simulate_geo_earth

    cfg = load_geo_config(config_path)
    if seed is not None:
        cfg = replace(cfg, seed=seed)
    with staged_folder(out_dir, ".simulate-", inputs=[dom_path, dem_path, geoid, config_path]) as stage:
        summary = simulate_geo_earth(stage, config=cfg, dom=dom_path, dem=dem_path, geoid=geoid)
    return final_paths(summary, stage, out_dir)


def simulate_geo_star_frames(out_dir, *, seed: int = 0, n_frames: int = 120, frame_interval_s: float = 10.0,
                             mag_limit: float = 10.0) -> dict:
    """Render a star-field sequence of a geostationary staring camera (seed 000) with its truth.

    Parameters
    ----------
    out_dir : str or Path
        Output folder.
    seed : int
        Random seed.
    n_frames : int
        Number of frames.
    frame_interval_s : float
        Seconds between frames.
    mag_limit : float
        Faintest catalogue magnitude rendered.

    Returns
    -------
    dict
        The simulation summary (``frames``, ``distinct_stars``, ...).
    """
    from sensor_models.simulate.star_sky import simulate_geo_stars

    with staged_folder(out_dir, ".simulate-") as stage:
        summary = simulate_geo_stars(stage, seed=seed, n_frames=n_frames, frame_interval_s=frame_interval_s,
                                     mag_limit=mag_limit)
    return final_paths(summary, stage, out_dir)


def truth_error_of(model_path, truth_path, *, dem_path=None, dem_datum=None, geoid=None, heights_m=None,
                   step_px: float = 16.0, out_path=None) -> dict:
    """Pixel error of a model against the TRUE model over a grid of every CCD and band.

    Parameters
    ----------
    model_path : str or Path
        The model to grade.
    truth_path : str or Path
        The TRUE model (``truth_manifest.json`` of a simulation).
    dem_path, dem_datum, geoid : optional
        DEM to compare on, its vertical datum and geoid grid.
    heights_m : array_like, optional
        Ellipsoidal heights (m) to compare at, when no DEM is given.
    step_px : float
        Grid spacing, pixels.
    out_path : str or Path, optional
        Write the result as JSON (``-``: nothing is written; the caller prints it).

    Returns
    -------
    dict
        ``rms_px``, ``max_px``, ``n_points`` and ``per_ccd`` rows.
    """
    from sensor_models.readers import open_model
    from sensor_models.readers.model_file import open_model_with_provenance
    from sensor_models.simulate.truth import truth_error

    inputs = InputSet([model_path, truth_path, dem_path, geoid])
    to_stdout = is_stdout(out_path)
    if out_path and not to_stdout:  # before any work
        check_output_files(out_path, inputs=inputs)
    true_model = open_model(truth_path)
    opened = open_model_with_provenance(model_path)
    model, product_check = opened.model, opened.product_check
    warning = require_usable(model, model_path, command="truth error")
    dem, coverage = None, {"warnings": []}
    if dem_path:
        dem = open_dem(dem_path, dem_datum, geoid, model=true_model)
        lon, lat = footprint_sample_lonlat(true_model, 0.5 * sum(dem.height_range_m))
        coverage = check_dem_footprint(dem, lon, lat)
    result = truth_error(true_model, model, dem=dem, step_px=step_px, heights_m=heights_m)
    status = status_fields(model, warning, *coverage.pop("warnings"), product_check=product_check)
    result = {**result, **status, **coverage}
    if out_path and not to_stdout:
        with staged_files(out_path, inputs=inputs) as (json_tmp,):
            write_summary(json_tmp, result)
    return result
