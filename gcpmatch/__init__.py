"""GCP extraction: reference chips in scene geometry, SIFT coarse matching, phase correlation.

Depends on :mod:`sensor_models` only. The public API (``docs/api.md``) is what :data:`__all__` lists.
"""


#: Public name -> the module that defines it; imported on first use (PEP 562), so that importing
#: the package stays cheap (``gcpcal --help`` imports it).
_EXPORTS = {
    "extract_gcps": "gcpmatch.extract",
    "phase_correlate": "gcpmatch.phase",
    "GcpTable": "gcpmatch.gcps",
    "read_gcps": "gcpmatch.gcp_files",
    "MatchOptions": "gcpmatch.options",
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
