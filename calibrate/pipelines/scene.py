"""The scene pipeline: ``gcpcal match`` -> ``gcpcal calibrate`` -> ``gcpcal relative`` on one scene.

:func:`scene_pipeline` runs the stage actions a user runs, with the options given, into one
folder laid out as a user's own run of the three commands would be:

* ``gcps.csv`` (+ ``gcps.summary.json``, ``gcps_residuals.gpkg``): the reference band's GCPs and
  check points (:func:`calibrate.actions.match.match_scene`, ``gcpcal match --out gcps.csv``);
* ``calibration/``: the reference band calibrated from them
  (:func:`calibrate.actions.calibrate.calibrate_scene`, ``gcpcal calibrate --gcps gcps.csv
  --out calibration``);
* ``relative/`` (``manifest.json``: every band calibrated against the calibrated reference band,
  ``relative.json``, ``relative.summary.json``;
  :func:`calibrate.actions.relative.relative_calibration_stage`, ``gcpcal relative
  --calibration calibration --gcps gcps.csv --out relative``);
* on a simulated scene, the final model's error against the TRUE model
  (:func:`calibrate.actions.simulate.truth_error_of`, ``gcpcal truth error``), returned only.

The steps (:func:`match_step`, :func:`calibrate_step`, :func:`relative_step`) are also what
``gcpcal run`` (:mod:`calibrate.pipelines.run`) composes. Each stage stages its own outputs;
a caller that wants the whole folder whole-or-absent stages ``out_dir`` itself (``gcpcal demo``
and ``gcpcal run`` do).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from calibrate.config import CalibrationOptions
from gcpmatch.options import MatchOptions

__all__ = ["CALIBRATION_DIR", "FINAL_MODEL", "GCP_FILE", "RELATIVE_DIR", "SceneRun", "calibrate_step", "match_step", "relative_step",
           "scene_pipeline"]

#: the GCP table the match step writes, in the pipeline's folder
GCP_FILE = "gcps.csv"
#: the calibrate step's output folder, in the pipeline's folder
CALIBRATION_DIR = "calibration"
#: the relative step's output folder, in the pipeline's folder
RELATIVE_DIR = "relative"
#: the relative step's model (every band calibrated), in the pipeline's folder
FINAL_MODEL = f"{RELATIVE_DIR}/manifest.json"


@dataclass
class SceneRun:
    """What :func:`scene_pipeline` ran: each stage's summary, and the fits a report needs.

    Attributes
    ----------
    out_dir : Path
        The pipeline's folder.
    match, calibrate, relative, truth : dict or None
        The summaries of the stages (``relative`` None when not run; ``truth`` None without a
        TRUE model).
    model : str or None
        The final model, relative to ``out_dir`` (:data:`FINAL_MODEL` after the relative step,
        ``calibration/manifest.json`` without it or when the calibration failed; None when the
        calibration wrote none).
    calibration : CalibrationResult or None
        The calibrate step's fit (``calibration.model``: the calibrated reference band).
    relative_result : RelativeResult or None
        The relative step's result (``relative_result.model``: the final model).
    """

    out_dir: Path
    match: dict
    calibrate: dict | None = None
    relative: dict | None = None
    truth: dict | None = None
    model: str | None = None
    calibration: object = None
    relative_result: object = None

    def summaries(self) -> dict:
        """The stages' summaries by stage name (``match``, ``calibrate``, ``relative``, ``truth``)."""
        return {"match": self.match, "calibrate": self.calibrate, "relative": self.relative, "truth": self.truth}


def match_step(scene_path, out_dir, *, dom_path, dem_path, dem_datum=None, geoid=None,
               options: MatchOptions = MatchOptions(), self_check: str = "refuse", progress=None) -> dict:
    """``gcpcal match SCENE --dom DOM --dem DEM --out OUT/gcps.csv``: the reference band's GCPs.

    Parameters
    ----------
    scene_path : str or Path
        The scene (any form :func:`calibrate.actions.match.match_scene` reads).
    out_dir : str or Path
        The pipeline's folder; the table goes to ``out_dir / GCP_FILE``.
    dom_path, dem_path, dem_datum, geoid
        As :func:`calibrate.actions.match.match_scene`.
    options : MatchOptions
        Matching settings.
    self_check : {"refuse", "warn"}
    progress : callable(str), optional

    Returns
    -------
    dict
        The match summary.

    Raises
    ------
    InputError
        Bad inputs, or no GCP extracted (the summary is written all the same).
    """
    from calibrate.actions.match import match_scene

    return match_scene(scene_path, dom_path=dom_path, dem_path=dem_path, out_path=Path(out_dir) / GCP_FILE,
                       geoid=geoid, dem_datum=dem_datum, options=options, progress=progress, self_check=self_check)


def calibrate_step(scene_path, out_dir, *, options: CalibrationOptions = CalibrationOptions(), report: bool = True,
                   self_check: str = "refuse", progress=None, on_result=None) -> dict:
    """``gcpcal calibrate SCENE --gcps OUT/gcps.csv --out OUT/calibration``.

    Parameters
    ----------
    scene_path : str or Path
    out_dir : str or Path
        The pipeline's folder (holding :data:`GCP_FILE` and its match summary).
    options : CalibrationOptions
        Without ``reference_sigma_m``, the match summary's reference accuracy is taken, as the
        command does.
    report : bool
        Write the stage's ``report.html``.
    self_check : {"refuse", "warn"}
    progress : callable(str), optional
    on_result : callable, optional
        Receives the fit (:func:`calibrate.actions.calibrate.calibrate_scene`).

    Returns
    -------
    dict
        The calibrate summary.
    """
    from calibrate.actions.calibrate import calibrate_scene

    out_dir = Path(out_dir)
    return calibrate_scene(scene_path, out_dir / GCP_FILE, out_dir / CALIBRATION_DIR, options=options, report=report,
                           progress=progress, self_check=self_check, on_result=on_result)


def relative_step(scene_path, out_dir, *, dem_path, dem_datum=None, geoid=None,
                  options: CalibrationOptions = CalibrationOptions(), self_check: str = "refuse", progress=None,
                  on_result=None) -> dict:
    """``gcpcal relative SCENE --calibration OUT/calibration --gcps OUT/gcps.csv --dem DEM --out OUT/relative``.

    Window and spacing are the command's defaults; with the GCPs, the band parallax path runs.

    Parameters
    ----------
    scene_path : str or Path
        The LAB scene manifest.
    out_dir : str or Path
        The pipeline's folder: ``manifest.json`` (every band), ``relative.json``,
        ``relative.summary.json`` go into its :data:`RELATIVE_DIR`.
    dem_path, dem_datum, geoid
        As :func:`calibrate.actions.relative.relative_calibration_stage`.
    options : CalibrationOptions
        ``robust`` and ``attitude`` are used.
    self_check : {"refuse", "warn"}
    progress : callable(str), optional
    on_result : callable, optional
        Receives the :class:`calibrate.relative.RelativeResult`.

    Returns
    -------
    dict
        The relative summary.
    """
    from calibrate.actions.relative import relative_calibration_stage

    out_dir = Path(out_dir)
    return relative_calibration_stage(scene_path, out_dir / CALIBRATION_DIR, dem_path, out_dir / RELATIVE_DIR,
                                      dem_datum=dem_datum, geoid=geoid, options=options, gcps_path=out_dir / GCP_FILE,
                                      progress=progress, self_check=self_check, on_result=on_result)


def scene_pipeline(scene_path, *, dom_path, dem_path, out_dir, match_options: MatchOptions = MatchOptions(),
                   calibration_options: CalibrationOptions = CalibrationOptions(), relative: bool = True,
                   report: bool = True, truth_path=None, dem_datum=None, geoid=None, self_check: str = "refuse",
                   progress=None) -> SceneRun:
    """Match, calibrate the reference band, calibrate the other bands against it (module docstring).

    Parameters
    ----------
    scene_path : str or Path
        The scene manifest (the LAB model a user has).
    dom_path, dem_path : str or Path
        Reference orthoimage and DEM (:func:`match_step`).
    out_dir : str or Path
        The pipeline's folder (created when missing; the caller stages it for whole-or-absent).
    match_options : MatchOptions
        The match step's settings (``gcpcal match``'s options).
    calibration_options : CalibrationOptions
        The calibrate step's settings; the relative step takes its ``robust`` and ``attitude``.
    relative : bool
        Run the relative step (band-to-band); without it the final model is the calibrate step's.
    report : bool
        The calibrate step writes its ``report.html``.
    truth_path : str or Path, optional
        The TRUE model of a simulated scene (``truth_manifest.json``): the final model is graded
        against it on ``dem_path`` (:func:`calibrate.actions.simulate.truth_error_of`).
    dem_datum, geoid : optional
        The DEM's vertical datum when the file does not say, and the geoid grid.
    self_check : {"refuse", "warn"}
    progress : callable(str), optional
        Receives progress messages (the stages' own included).

    Returns
    -------
    SceneRun
        The stages' summaries and fits. A failed calibration is not carried on to the relative
        step (``relative`` None).

    Raises
    ------
    InputError
        Bad inputs, or no GCP extracted.
    FailedCalibrationError
        A TRUE model given and the calibration failed (``gcpcal truth error`` refuses a failed
        model).
    """
    say = progress or (lambda message: None)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    say("matching the reference band against the DOM")
    run = SceneRun(out_dir, match_step(scene_path, out_dir, dom_path=dom_path, dem_path=dem_path, dem_datum=dem_datum,
                                       geoid=geoid, options=match_options, self_check=self_check, progress=progress))
    band = run.match.get("band") or "the reference band"
    say(f"calibrating {band}: exterior then interior")

    def keep(field):
        return lambda result: setattr(run, field, result)

    run.calibrate = calibrate_step(scene_path, out_dir, options=calibration_options, report=report,
                                   self_check=self_check, progress=progress, on_result=keep("calibration"))
    run.model = f"{CALIBRATION_DIR}/{run.calibrate['model']}" if run.calibrate.get("model") else None
    if relative and run.calibrate["status"] != "failed":
        say(f"band-to-band calibration against {band}")
        run.relative = relative_step(scene_path, out_dir, dem_path=dem_path, dem_datum=dem_datum, geoid=geoid,
                                     options=calibration_options, self_check=self_check, progress=progress,
                                     on_result=keep("relative_result"))
        run.model = FINAL_MODEL
    if truth_path is not None and run.model is not None:
        from calibrate.actions.simulate import truth_error_of

        say("grading the model against the TRUE model")
        run.truth = truth_error_of(out_dir / run.model, truth_path, dem_path=dem_path, dem_datum=dem_datum,
                                   geoid=geoid)
    return run
