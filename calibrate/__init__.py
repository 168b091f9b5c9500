"""Calibration of sensor models from GCPs and stars, accuracy reports, batch runs, and the CLI.

The public API (``docs/api.md``) is what :data:`__all__` lists; the command line is
:mod:`calibrate.cli`, the stage actions :mod:`calibrate.actions`, their compositions
:mod:`calibrate.pipelines`.
"""


#: Public name -> the module that defines it; imported on first use (PEP 562), so that importing
#: the package stays cheap (``gcpcal --help`` imports it).
_EXPORTS = {
    "calibrate_model": "calibrate.absolute",
    "CalibrationResult": "calibrate.calibration_result",
    "CalibrationOptions": "calibrate.config",
    "check_point_accuracy": "calibrate.accuracy",
}

__all__ = sorted([*_EXPORTS])


def __getattr__(name: str):
    """The public name ``name``, imported from its module on first use."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
