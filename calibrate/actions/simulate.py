"""Stage actions of ``gcpcal simulate ...`` and ``gcpcal truth error``: scenes with known truth.

The only action module that imports :mod:`sensor_models.simulate` (production stages never do).
"""

from __future__ import annotations

from dataclasses import replace

from calibrate.actions._guard import InputSet, is_stdout
from calibrate.actions._io import check_output_files, final_paths, open_dem, staged_files, staged_folder, write_summary
from calibrate.actions._status import require_usable, status_fields
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


def simulate_pushbroom_scene(out_dir, config, *, dom_path=None, dem_path=None, geoid=None, workers: int = 2,
                             progress=None, profile: str = "ideal", config_path=None) -> dict:
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
    workers : int
        Rendering threads.
    progress : callable(done, total), optional
        Called as rendering proceeds.
    profile : str
        Error profile name (:data:`PROFILE_NAMES`; ``ideal``: the simulator without added errors).
    config_path : str or Path, optional
        The file ``config`` was read from (an input: never written over).

    Returns
    -------
    dict
        The simulation summary (``image``, ``lab_truth_error_px``, ``render_seconds``, ...).
    """
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    with staged_folder(out_dir, ".simulate-", inputs=[dom_path, dem_path, geoid, config_path]) as stage:
        summary = simulate_pushbroom(stage, config=config, dom=dom_path, dem=dem_path, geoid=geoid, workers=workers,
                                     progress=progress, profile=profile)
    return final_paths(summary, stage, out_dir)


def simulate_validation_series(out_dir, n_scenes: int, *, seed: int = 0, config_path=None, cloud_fractions=(),
                               calibration_scene: bool = False, workers: int = 2) -> list:
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
    workers : int
        Parallel renderings.

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
    from sensor_models.simulate.truth import truth_error

    inputs = InputSet([model_path, truth_path, dem_path, geoid])
    to_stdout = is_stdout(out_path)
    if out_path and not to_stdout:  # before any work
        check_output_files(out_path, inputs=inputs)
    true_model = open_model(truth_path)
    model = open_model(model_path)
    warning = require_usable(model, model_path, command="truth error")
    dem, coverage = None, {"warnings": []}
    if dem_path:
        dem = open_dem(dem_path, dem_datum, geoid, model=true_model)
        lon, lat = footprint_sample_lonlat(true_model, 0.5 * sum(dem.height_range_m))
        coverage = check_dem_footprint(dem, lon, lat)
    result = truth_error(true_model, model, dem=dem, step_px=step_px, heights_m=heights_m)
    result = {**result, **status_fields(model, warning, *coverage.pop("warnings")), **coverage}
    if out_path and not to_stdout:
        with staged_files(out_path, inputs=inputs) as (json_tmp,):
            write_summary(json_tmp, result)
    return result
