"""Seed experiments under named error profiles: ``gcpcal experiment {000,002,003,004}``.

One module per seed (:mod:`.seed000` stars, :mod:`.seed002` staring compensation and thermal
series, :mod:`.seed003` push-broom end to end, :mod:`.seed004` autocollimation), each with a
``run(profile, *, quick, work_dir)`` returning an :class:`~calibrate.experiments.results.ExperimentResult`:
the paper's tables beside ours (paper numbers typed in from the seed, table cited), sensitivity
curves (accuracy against each error magnitude that applies) and the profile's magnitudes with
their sources. :mod:`.registry` maps seed names to modules; :mod:`.report` writes JSON, PNG
and ``report.html``.

Experiments are simulations by nature: this package is the one production package besides
``*simulate*`` modules allowed to import :mod:`sensor_models.simulate` (tests/test_layers.py).
"""
