"""Lists of scenes a user writes by hand: one entry per scene, read strictly.

``gcpcal validate`` (a sites file, :func:`calibrate.batch.read_sites`) and ``gcpcal campaign``
(a campaign file, :func:`calibrate.pipelines.campaign.read_campaign`) read the same kind of
file, in three forms told by the extension:

* YAML (``.yaml``, ``.yml``): a list of mappings;
* JSON (``.json``): a list of objects (where the command accepts it);
* CSV (``.csv``): a header naming the fields, one scene per line; an empty cell means "not
  given" and blank lines are skipped.

:func:`read_entries` checks what every such list needs (known fields only, required fields
present and non-empty, text values, unique names) and resolves paths relative to the file's
folder; the command checks its own fields' values. Referenced files are not opened here: a
missing DOM fails its scene, not the whole list.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from sensor_models.errors import InputError
from sensor_models.files.documents import csv_error, load_json, load_yaml, read_text

__all__ = ["read_entries"]


def read_entries(path, *, required: tuple[str, ...], optional: tuple[str, ...], paths: tuple[str, ...],
                 what: str = "a sites file", suffixes: tuple[str, ...] = (".yaml", ".yml", ".csv")) -> list[dict]:
    """Read a list of scenes (module docstring), strictly.

    Parameters
    ----------
    path : str or Path
        The list's file.
    required, optional : tuple of str
        Field names; ``required[0]`` is the entry's unique name (``"name"``).
    paths : tuple of str
        Fields holding file paths, resolved against the file's folder.
    what : str
        What the file is, for the messages (``"a campaign file"``).
    suffixes : tuple of str
        Extensions accepted (lower case, among ``.yaml``, ``.yml``, ``.json``, ``.csv``).

    Returns
    -------
    list of dict
        One per scene, in the file's order: field -> value (``str``, or ``Path`` for ``paths``
        fields), with only the fields given; ``"_label"`` names the entry for messages
        (``"entry 2 ('coast')"``).

    Raises
    ------
    InputError
        One line naming the file, the entry and the field: unreadable file, not a list, missing
        or empty required field, unknown field, a value that is not text, duplicate name.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in suffixes:
        raise InputError(f"{what} must be {', '.join(suffixes[:-1])} or {suffixes[-1]}", path=str(path))
    if suffix == ".csv":
        entries = _csv_entries(read_text(path), path, required, optional)
    else:
        entries = _document_entries(path, required, json=suffix == ".json")
    if not entries:
        raise InputError("lists no scene", path=str(path))
    base = path.resolve().parent
    known = required + optional
    out, seen = [], {}
    for label, entry in entries:
        unknown = [k for k in entry if k not in known]
        if unknown:
            raise InputError(f"{label}: unknown field (known: {', '.join(known)})", path=str(path),
                             field=str(unknown[0]))
        values = {"_label": label}
        for key in known:
            value = entry.get(key)
            if isinstance(value, bool) or (value is not None and not isinstance(value, (str, int, float))):
                raise InputError(f"{label}: must be a string, got {type(value).__name__}", path=str(path), field=key)
            value = None if value is None else str(value).strip()
            if key in required and not value:
                raise InputError(f"{label}: required field missing or empty", path=str(path), field=key)
            if value:
                values[key] = (base / value) if key in paths else value
        name = values[required[0]]
        if name in seen:
            raise InputError(f"{label}: name {name!r} already used by {seen[name]}", path=str(path),
                             field=required[0])
        seen[name] = label
        out.append(values)
    return out


def _document_entries(path: Path, required, *, json: bool) -> list[tuple[str, dict]]:
    doc = load_json(path) if json else load_yaml(path)
    kind = "JSON" if json else "YAML"
    if doc is None:
        return []
    if not isinstance(doc, list):
        raise InputError(f"must be a {kind} list of scenes (mappings), got a {type(doc).__name__}", path=str(path))
    out = []
    for k, entry in enumerate(doc, start=1):
        if not isinstance(entry, dict):
            raise InputError(f"entry {k}: must be a mapping with {', '.join(required)}", path=str(path))
        name = entry.get(required[0])
        out.append((f"entry {k}" + (f" ({name!r})" if isinstance(name, str) and name else ""),
                    {str(key): v for key, v in entry.items()}))
    return out


def _csv_entries(text: str, path: Path, required, optional) -> list[tuple[str, dict]]:
    reader = csv.DictReader(io.StringIO(text))
    try:
        return _csv_records(reader, path, required, optional)
    except csv.Error as exc:  # bad quoting, a field over the csv module's limit
        raise csv_error(exc, path, reader.line_num) from None


def _csv_records(reader: csv.DictReader, path: Path, required, optional) -> list[tuple[str, dict]]:
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"the header lacks column(s) {', '.join(missing)} (header: {','.join(header)})",
                         path=str(path), field=missing[0])
    unknown = [c for c in header if c not in required + optional]
    if unknown:
        raise InputError(f"unknown column (known: {', '.join(required + optional)})", path=str(path),
                         field=unknown[0])
    reader.fieldnames = header
    out = []
    for k, rec in enumerate(reader, start=1):
        if None in rec:
            raise InputError(f"entry {k} (line {reader.line_num}): more cells than header columns", path=str(path))
        if all((v or "").strip() == "" for v in rec.values()):
            continue
        name = (rec.get(required[0]) or "").strip()
        label = f"entry {k} (line {reader.line_num}" + (f", {name!r})" if name else ")")
        out.append((label, {key: (v if (v or "").strip() else None) for key, v in rec.items()}))
    return out
