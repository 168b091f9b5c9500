"""Stage actions: one module per ``gcpcal`` stage.

An action reads its inputs, calls the library, writes its outputs and its JSON summary (through a
temporary folder where it writes several files) and returns the summary as a ``dict``. Actions
never import :mod:`click` nor :mod:`calibrate.cli`; the commands in :mod:`calibrate.cli` parse
options, build the options values and hand off to them, directly or through a composition of
several actions (:mod:`calibrate.pipelines`). Actions never import a pipeline; library modules
(the rest of ``calibrate``, :mod:`calibrate.experiments` included) never import actions.
"""
