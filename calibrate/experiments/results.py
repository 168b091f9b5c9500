"""The values an experiment returns: tables beside the paper's, sensitivity curves, the profile."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

__all__ = ["ExperimentResult", "PaperTable", "SensitivityCurve"]


@dataclass
class PaperTable:
    """A table of the paper with our figures beside it.

    Attributes
    ----------
    title : str
        What the table shows.
    source : str
        The seed's table or figure the paper column is typed in from.
    columns : tuple of str
        Column titles; the first is the row label, ``paper`` the published value.
    rows : list of list
        Cells (str or float or None; None: not given / not applicable).
    """

    title: str
    source: str
    columns: tuple
    rows: list


@dataclass
class SensitivityCurve:
    """Accuracy against one error magnitude, the other magnitudes at the profile's values.

    Attributes
    ----------
    name : str
        File stem (``sensitivity/<name>.json`` and ``.png``).
    x_label, y_label : str
        Axis titles with units.
    x : list of float
        The magnitudes tried.
    series : dict of str to list of float
        One accuracy series per quantity (same length as ``x``).
    note : str
        How the points were computed (scale, what is re-run).
    """

    name: str
    x_label: str
    y_label: str
    x: list
    series: dict
    note: str = ""


@dataclass
class ExperimentResult:
    """Everything ``gcpcal experiment`` writes for one seed and profile.

    Attributes
    ----------
    seed, profile : str
        Seed (``000`` ...) and profile name.
    quick : bool
        The reduced run (tests); the scale says what was reduced.
    title : str
        One line on what is reproduced.
    scale : dict
        Sizes used (frames, grid, days, detectors ...), and the paper's where they differ.
    tables : list of PaperTable
    curves : list of SensitivityCurve
    headline : dict
        A few numbers (pixels unless named) that tests and docs cite.
    profile_rows : list of tuple
        :func:`sensor_models.simulate.profiles.profile_table` of each profile used.
    notes : list of str
        Where ours differs from the paper, point by point.
    seconds : float
        Wall time.
    """

    seed: str
    profile: str
    quick: bool
    title: str
    scale: dict = field(default_factory=dict)
    tables: list = field(default_factory=list)
    curves: list = field(default_factory=list)
    headline: dict = field(default_factory=dict)
    profile_rows: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    seconds: float = 0.0

    def to_dict(self) -> dict:
        """JSON-ready mapping (``format: gcpcal.experiment``, version 1).

        Returns
        -------
        dict
        """
        from calibrate._json import json_safe

        return json_safe({"format": "gcpcal.experiment", "format_version": 1, **asdict(self)})
