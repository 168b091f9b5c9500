"""Seed experiments under named error profiles: ``gcpcal experiment {000,002,003,004}``.

One module per seed (:mod:`.simulate_seed000` stars, :mod:`.simulate_seed002` staring
compensation and thermal series, :mod:`.simulate_seed003` push-broom end to end,
:mod:`.simulate_seed004` autocollimation), each with a
``run(profile, *, quick, work_dir)`` returning an :class:`~calibrate.experiments.results.ExperimentResult`:
the paper's tables beside ours (paper numbers typed in from the seed, table cited), sensitivity
curves (accuracy against each error magnitude that applies) and the profile's magnitudes with
their sources. :mod:`.registry` maps seed names to modules; :mod:`.report` writes JSON, PNG
and ``report.html``.

Experiments are simulations by nature: only the ``simulate_seed*`` modules import
:mod:`sensor_models.simulate` (the layer rule: only ``*simulate*`` modules may;
tests/test_layers.py); the registry, results and report do not.

Experiments are library code: they import neither the stage actions nor the pipelines. The one
that runs the user's chain (:mod:`.simulate_seed003`) is handed the scene pipeline
(``run_experiment(..., pipeline=)``) by :mod:`calibrate.pipelines.experiment`, the
``gcpcal experiment`` stage.
"""
