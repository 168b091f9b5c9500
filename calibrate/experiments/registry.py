"""Seed name -> experiment module, and the profiles each accepts."""

from __future__ import annotations

import importlib

from sensor_models.errors import InputError

__all__ = ["EXPERIMENTS", "NEEDS_PIPELINE", "PROFILE_CHOICES", "profiles_of", "run_experiment"]

#: seed -> (module under calibrate.experiments, its ``paper-*`` profile)
EXPERIMENTS = {"000": ("simulate_seed000", "paper-000"), "002": ("simulate_seed002", "paper-002"),
               "003": ("simulate_seed003", "paper-003"),
               "004": ("simulate_seed004", "paper-004")}
#: the seeds whose experiment runs the user's chain through the scene pipeline (``run_experiment(pipeline=)``)
NEEDS_PIPELINE = ("003",)
#: every profile name the command accepts (each seed takes ideal, realistic and its own paper-*)
PROFILE_CHOICES = ("ideal", "realistic", "paper-000", "paper-002", "paper-003", "paper-004")


def profiles_of(seed: str) -> tuple:
    """The profiles seed ``seed`` runs under.

    Parameters
    ----------
    seed : str
        A key of :data:`EXPERIMENTS`.

    Returns
    -------
    tuple of str
    """
    return ("ideal", "realistic", EXPERIMENTS[seed][1])


def run_experiment(seed: str, profile: str, *, quick: bool = False, work_dir=None, source=None, pipeline=None,
                   frames: int | None = None):
    """Run one experiment.

    Parameters
    ----------
    seed : str
        ``000``, ``002``, ``003`` or ``004``.
    profile : str
        ``ideal``, ``realistic`` or the seed's ``paper-*``.
    quick : bool
        The reduced run.
    work_dir : Path
        Scratch folder for simulated data.
    source : str or Path, optional
        Source radiance raster of experiment 003's ``realistic`` scene.
    pipeline : callable, optional
        The scene pipeline experiment 003 runs the user's chain through
        (:func:`calibrate.pipelines.scene.scene_pipeline`, handed in by ``gcpcal experiment``:
        experiments never import the stage actions); required by seed 003, unused by the others.
    frames : int, optional
        Experiment 000: frames per session (default its own: 120, 30 with ``quick``).

    Returns
    -------
    ExperimentResult

    Raises
    ------
    InputError
        Unknown seed, or a profile the seed does not take.
    """
    if seed not in EXPERIMENTS:
        raise InputError(f"unknown experiment {seed!r} (known: {', '.join(EXPERIMENTS)})", field="seed")
    if profile not in profiles_of(seed):
        raise InputError(f"experiment {seed} takes the profiles {', '.join(profiles_of(seed))}, not {profile!r}",
                         field="profile")
    if source is not None and seed != "003":
        raise InputError("--source applies to experiment 003 (the push-broom scene's radiance)", field="source")
    if frames is not None and seed != "000":
        raise InputError("--frames applies to experiment 000 (frames per star session)", field="frames")
    module = importlib.import_module(f"calibrate.experiments.{EXPERIMENTS[seed][0]}")
    kwargs = {} if source is None else {"source": source}
    if frames is not None:
        kwargs["frames"] = int(frames)
    if seed in NEEDS_PIPELINE:
        kwargs["pipeline"] = pipeline
    return module.run(profile, quick=quick, work_dir=work_dir, **kwargs)
