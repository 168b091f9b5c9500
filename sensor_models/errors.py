"""The exceptions of gcpcal: one root, builtin mix-ins, messages that say what to do.

Every error a user can cause derives from :class:`GcpcalError`, so the CLI can print its
one-line message and exit non-zero without a traceback. Foreign errors (GDAL, ERFA, PROJ)
are translated into these at the module that talks to the foreign library.
"""

from __future__ import annotations


class GcpcalError(Exception):
    """Root of every gcpcal error. ``str(err)`` is a complete one-line message."""


class InputError(GcpcalError, ValueError):
    """A user-supplied file or value is malformed.

    Parameters
    ----------
    message : str
        What is wrong and, where possible, what to do.
    path : str, optional
        The file concerned; prefixed to the message.
    field : str, optional
        The field (JSON pointer, XML path, CSV column) concerned.
    """

    def __init__(self, message: str, *, path: str | None = None, field: str | None = None):
        self.path = None if path is None else str(path)
        self.field = field
        self.reason = message
        prefix = ""
        if self.path is not None:
            prefix += f"{self.path}: "
        if field is not None:
            prefix += f"field '{field}': "
        super().__init__(prefix + message)


class ManifestError(InputError):
    """A scene manifest or vendor metadata file is malformed (missing, unknown, wrong field)."""


class ImplausibleInputError(InputError):
    """A well-formed input whose figures a real one cannot have (a DEM in centimetres, a DOM far
    coarser than the scene, another band's raster, another scene's GCPs); commands accept it
    with ``--allow-implausible``."""


class OutOfRangeError(GcpcalError, ValueError):
    """A time or coordinate lies outside the data that define the model (never extrapolated)."""


class DemError(GcpcalError, ValueError):
    """A DEM cannot be read, is not covered, or declares no usable vertical datum."""


class GeoidGridMissingError(DemError, FileNotFoundError):
    """Orthometric heights were declared but the geoid grid needed to convert them is missing."""


class RpcError(InputError):
    """An RPC model cannot be read, fitted or written."""


class ConvergenceError(GcpcalError, ArithmeticError):
    """An iterative geometric solution did not converge."""


class ProductDisagreementError(ManifestError):
    """A vendor product's rigorous model disagrees with what the product states about itself.

    Raised by the vendor readers' self-check (:mod:`sensor_models.readers.self_check`) when the
    model built from the metadata misses the product's own corners or RPC by more than the
    documented tolerance, or when no model that reaches the Earth can be built from them. The
    message names the product, the satellite and the disagreement in metres.
    """
