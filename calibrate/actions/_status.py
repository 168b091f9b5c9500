"""What a stage may use: a failed calibration is refused, a partial one is used with a warning.

Every action that reads a model (``ortho``, ``relative``, ``rpc``, ``validate``, ``localize``,
``truth error``, ``run``) passes it through :func:`require_usable` before computing anything.
The model's ``calibration`` (:class:`sensor_models.base.CalibrationStatus`, read from the
manifest's ``calibration`` object) decides:

* ``failed``: :class:`FailedCalibrationError` (an input error, exit 1, one line naming the file);
* ``partial``: a one-line warning naming what is not calibrated or not verified; the command
  prints it on stderr and its JSON summary carries ``calibration_status`` and ``warnings``;
* ``calibrated`` or no status (a LAB model, a vendor product): nothing to say.
"""

from __future__ import annotations

from pathlib import Path

from sensor_models.errors import InputError

__all__ = ["FailedCalibrationError", "calibration_input", "open_usable_calibration", "product_check_fields",
           "record_product_check", "require_usable", "resolve_calibration", "status_fields"]


class FailedCalibrationError(InputError):
    """A model written by a failed calibration was given to a command that would use it."""


def _arrays(entries) -> str:
    """``B2/cam2_ccd1 (0 GCPs), ...`` of ``{"band", "ccd", "reason"}`` entries."""
    names = []
    for e in entries:
        where = "/".join(x for x in (e.get("band"), e.get("ccd")) if x) or "scene"
        names.append(f"{where} ({e['reason']})" if e.get("reason") else where)
    return ", ".join(names)


def require_usable(model, source, *, command: str) -> str | None:
    """Refuse a failed calibration; describe a partial one.

    Parameters
    ----------
    model : SensorModel
        The model the command is about to use (``model.calibration`` may be None).
    source : str or Path
        The file the model was read from (named in the message).
    command : str
        The command, as typed after ``gcpcal`` (e.g. ``"ortho"``, ``"truth error"``).

    Returns
    -------
    str or None
        One warning line for a ``partial`` calibration (what is uncalibrated or unverified);
        None for a ``calibrated`` model or a model without status.

    Raises
    ------
    FailedCalibrationError
        When ``model.calibration.status == "failed"``.
    """
    status = getattr(model, "calibration", None)
    if status is None or status.status == "calibrated":
        return None
    if status.status == "failed":
        raise FailedCalibrationError(f"the calibration failed ({status.message or 'no reason recorded'}); "
                                     f"gcpcal {command} does not use a failed calibration", path=str(source))
    parts = []
    if status.uncalibrated:
        parts.append(f"uncalibrated: {_arrays(status.uncalibrated)}")
    if status.unverified:
        parts.append(f"unverified: {_arrays(status.unverified)}")
    detail = "; ".join(parts) or status.message or "no detail recorded"
    return f"{source}: the calibration is partial ({detail}); gcpcal {command} uses it as it is"


def status_fields(model, *warnings: str | None, product_check=None) -> dict:
    """The summary fields that record the status of the model a command used.

    Parameters
    ----------
    model : SensorModel
        The model used (its status is recorded).
    *warnings : str or None
        What :func:`require_usable` returned for each model the command read (None skipped).
    product_check : ProductCheck, optional
        The self-check of the vendor product opened from the user's scene
        (:attr:`Scene.product_check <sensor_models.readers.scene_value.Scene.product_check>`),
        recorded through :func:`product_check_fields`; None: not a vendor product.

    Returns
    -------
    dict
        ``calibration_status`` (``"calibrated"``, ``"partial"``, or None for a model without
        status), ``warnings`` (list of str, empty when there is nothing to say; a product's
        accepted disagreement is one) and ``product_check``.
    """
    status = getattr(model, "calibration", None)
    checked = product_check_fields(product_check)
    return {"calibration_status": None if status is None else status.status,
            "warnings": [w for w in (*warnings, checked.pop("warning")) if w], **checked}


def product_check_fields(check) -> dict:
    """What a summary records of the self-check of the vendor product a command opened.

    Parameters
    ----------
    check : ProductCheck or None
        The ``product_check`` of a :func:`sensor_models.readers.open_scene` Scene (None: not a
        vendor product).

    Returns
    -------
    dict
        ``product_check``: :meth:`ProductCheck.to_dict
        <sensor_models.readers.self_check.ProductCheck.to_dict>` (max/mean/rms metres of each
        comparison, its tolerance and source, pass/fail), or None for a model that is not a
        vendor product; ``warning``: the one-line disagreement the user accepted with
        ``--accept-product-disagreement``, or None.
    """
    if check is None:
        return {"product_check": None, "warning": None}
    warning = None
    if not check.passed:
        warning = f"{check.product}: {check.disagreement()} (accepted: --accept-product-disagreement)"
    return {"product_check": check.to_dict(), "warning": warning}


def _summary_model(folder: Path) -> Path | None:
    """The model file ``calibrate.summary.json`` in ``folder`` names, when it names one that exists."""
    import json

    try:
        name = json.loads((folder / "calibrate.summary.json").read_text(encoding="utf-8")).get("model")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(name, str) or Path(name).name != name or not (folder / name).is_file():
        return None
    return folder / name


def resolve_calibration(path) -> Path:
    """The calibrated model file of a path the user gave.

    Parameters
    ----------
    path : str or Path
        A model file, or a folder holding ``manifest.json``, or the ``*_RPC.TXT`` that its
        ``calibrate.summary.json`` names as the model, or one ``*_full_scene_RPC.TXT`` (a crop's
        calibration: beside it the crop's own sidecar), or a single ``*_RPC.TXT``.

    Returns
    -------
    Path
        The model file.

    Raises
    ------
    InputError
        When the file does not exist or the folder holds no model.
    """
    path = Path(path)
    if path.is_dir():
        manifest = path / "manifest.json"
        if manifest.is_file():
            return manifest
        named = _summary_model(path)
        if named is not None:
            return named
        rpcs = sorted(p for p in path.iterdir() if p.name.upper().endswith("_RPC.TXT"))
        full = [p for p in rpcs if p.name.upper().endswith("_FULL_SCENE_RPC.TXT")]
        if len(rpcs) == 1 or len(full) == 1:
            return (full or rpcs)[0]
        raise InputError("the calibration folder holds no manifest.json (nor a single *_RPC.TXT)", path=str(path))
    if not path.is_file():
        raise InputError("calibration not found", path=str(path))
    return path


def calibration_input(path):
    """What a command reads of a calibration the user gave: the model file, for the output guard.

    A calibration folder is read for one file (:func:`resolve_calibration`), so outputs may go
    into that folder; the model file itself is the input. A path that holds no model gives None
    (the command's read then says why).

    Parameters
    ----------
    path : str or Path or None

    Returns
    -------
    Path or None
    """
    if path is None:
        return None
    try:
        return resolve_calibration(path)
    except InputError:
        return None


def open_usable_calibration(path, *, command: str):
    """Open the calibrated model a user gave and check that it may be used.

    Parameters
    ----------
    path : str or Path
        Model file or the folder of ``gcpcal calibrate`` (:func:`resolve_calibration`).
    command : str
        The command, as typed after ``gcpcal``.

    Returns
    -------
    model : SensorModel
        The model.
    model_file : Path
        The file it was read from.
    warning : str or None
        As :func:`require_usable` returns.

    Raises
    ------
    FailedCalibrationError
        When the calibration failed.
    """
    from sensor_models import open_model

    model_file = resolve_calibration(path)
    model = open_model(model_file)
    return model, model_file, require_usable(model, model_file, command=command)


def record_product_check(summary: dict, check) -> dict:
    """Add :func:`product_check_fields` to a summary: ``product_check``, and the warning to ``warnings``.

    Parameters
    ----------
    summary : dict
        A stage's summary (changed in place).
    check : ProductCheck or None
        The self-check of the product opened from the user's scene (``Scene.product_check``).

    Returns
    -------
    dict
        ``summary``.
    """
    checked = product_check_fields(check)
    summary["product_check"] = checked["product_check"]
    if checked["warning"]:
        summary["warnings"] = [*(summary.get("warnings") or []), checked["warning"]]
    return summary
