"""``gcpcal campaign``: many scenes matched and calibrated, one Dask task per scene.

Each scene of a campaign runs the pipeline of ``gcpcal run`` (:func:`calibrate.pipelines.run.run_scene`:
match, calibrate from the GCPs, with ``relative`` the other bands against the reference band, and
the star fallback when the entry names star frames) into ``OUT/<scene>/``, exactly as
``gcpcal run SCENE --dom DOM --dem DEM --out OUT/<scene>`` would write it; the matching of a
scene gives the same GCPs whatever its thread count (:class:`gcpmatch.options.MatchOptions`),
so the campaign's results equal those of the serial runs. The scenes run on Dask distributed
(:mod:`calibrate.cluster`): a LocalCluster of this machine by default, or the workers of a
scheduler at an address (a cluster of machines, or HPC batch jobs through ``dask_jobqueue``;
docs/campaign.md), which must read the scenes' files and write ``OUT`` at the same paths
(a shared filesystem).

The campaign folder ``OUT`` holds, besides the scenes' folders:

* ``campaign.csv``: one row per scene (:data:`COLUMNS`): ``status`` ``ok`` or ``failed`` with
  the one-line ``reason``, the GCP count, the check-point RMSE before and after calibration
  (pixels), the wall seconds of its task and the worker that ran it;
* ``campaign_residuals.gpkg``: the residual points of every calibrated scene against its
  calibrated model (each scene's ``calibration/residuals.gpkg``), one layer whose ``site``
  field holds the scene's name (:mod:`calibrate.residual_layer`);
* ``campaign.json``: the rows, counts, options, cluster, timings and provenance.

A scene that fails (bad input, no GCP, a failed calibration, a lost worker) is a row with its
reason; the others go on. ``OUT`` is staged whole (:func:`calibrate.actions._io.staged_folder`):
an interrupted campaign leaves the previous ``OUT`` (or none), never part of one. With
``resume``, each scene's folder is moved into ``OUT`` whole as its scene ends instead, the scene
folders an earlier run completed from the same inputs and options are kept
(:mod:`calibrate.pipelines.campaign_resume`), and the campaign's files are rebuilt over all scenes.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from calibrate._json import json_safe
from calibrate.actions._guard import OutputRefusedError, allow_overwrite, overwrite_allowed, running_command
from calibrate.actions._io import final_paths, staged_folder
from calibrate.actions._provenance import command_line, current_command_line, with_provenance
from calibrate.cluster import available_cores, check_scheduler_address, connect, dask_log_level, worker_count
from calibrate.pipelines.campaign_resume import (RECORD_KEY, clear_scene, earlier_output, fold_ledgers, made_from,
                                                 summary_row)
from calibrate.pipelines.run import MIN_COVERAGE, MIN_GCPS, run_scene
from sensor_models.errors import GcpcalError, InputError
from sensor_models.files.atomic import atomic_folder

__all__ = ["COLUMNS", "CampaignScene", "campaign_scene", "read_campaign", "run_campaign"]

_REQUIRED = ("name", "scene", "dom", "dem")
_OPTIONAL = ("out", "dem_datum", "geoid", "dom_band", "dom_qa", "star_frames")
_PATHS = ("scene", "dom", "dem", "geoid", "dom_qa", "star_frames")
#: The campaign's own files in ``OUT`` (no scene folder may take their names).
FILES = {"csv": "campaign.csv", "json": "campaign.json", "residuals": "campaign_residuals.gpkg"}

#: Columns of ``campaign.csv``, in order (``*_px`` pixels, ``seconds`` wall seconds of the task).
COLUMNS = ("name", "status", "reason", "folder", "path", "gcps", "check_rmse_before_px", "check_rmse_after_px",
           "calibration_status", "seconds", "worker")


@dataclass(frozen=True)
class CampaignScene:
    """One scene of a campaign: the inputs of ``gcpcal run`` and its folder in the campaign.

    Attributes
    ----------
    name : str
        Unique label (the row's name; the residual points' ``site``).
    scene : Path
        Scene manifest, or any scene form ``gcpcal run`` reads.
    dom : Path or sensor_models.maps.dom_inputs.DomSource
        Reference orthoimage (file, folder, glob or ``.vrt``), or its source with the DOM options.
    dem : Path or tuple of Path
        DEM (or its tiles) covering the scene.
    out : str
        The scene's folder in ``OUT`` (default: ``name`` with characters other than letters,
        digits and ``-_.`` replaced by ``_``).
    dem_datum : str or None
        ``"ellipsoid"`` or ``"egm96"`` when the DEM file does not declare it.
    geoid : Path or None
        EGM96 grid for an orthometric DEM.
    dom_band : str or None
        Band of a DOM product folder (``B04``, ``B4``).
    dom_qa : Path or None
        QA raster masking the DOM (default: the one beside the band, when found).
    star_frames : Path or None
        Star sequence for the fallback when clouds leave too few GCPs.
    """

    name: str
    scene: Path
    dom: object
    dem: object
    out: str
    dem_datum: str | None = None
    geoid: Path | None = None
    dom_band: str | None = None
    dom_qa: Path | None = None
    star_frames: Path | None = None

    @property
    def inputs(self) -> list:
        """The files the scene reads (for the output guard)."""
        dom = getattr(self.dom, "paths", self.dom)  # a DomSource: its files
        return [p for p in (self.scene, dom, self.dem, self.geoid, self.dom_qa, self.star_frames) if p is not None]


def _safe_name(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name).strip(".") or "scene"


def read_campaign(path, *, dom=None, dem=None, dem_datum=None, geoid=None) -> list[CampaignScene]:
    """The scenes of a campaign file, or of a folder of scenes.

    A campaign file (YAML ``.yaml``/``.yml``, JSON ``.json`` or CSV ``.csv``; read strictly by
    :func:`calibrate.scene_lists.read_entries`) lists one scene per entry with the fields
    ``name, scene, dom, dem`` and optionally ``out, dem_datum, geoid, dom_band, dom_qa,
    star_frames``; relative paths are taken from the file's folder. A folder of scenes holds
    one scene per subfolder with a ``manifest.json`` (the subfolder's name is the scene's
    name), whose DOM and DEM are ``dom`` and ``dem`` when given, else the subfolder's
    ``reference/dom.tif`` and ``reference/dem.tif`` (the layout ``gcpcal simulate`` writes);
    ``dom``'s band, QA and mask settings apply to either.

    Parameters
    ----------
    path : str or Path
        Campaign file or folder.
    dom : str, Path or sensor_models.maps.dom_inputs.DomSource, optional
        DOM of every scene of a folder (not allowed with a file, whose entries name theirs); a
        DomSource without items gives its settings to each scene's own DOM.
    dem : str, Path or tuple of them, optional
        DEM (or tiles) of every scene of a folder.
    dem_datum, geoid : optional
        The DEM's vertical datum and geoid grid, for every scene of a folder.

    Returns
    -------
    list of CampaignScene
        In the file's order (a folder's: by name).

    Raises
    ------
    InputError
        One line naming the file, the entry and the field: unreadable or malformed file, unknown
        field, duplicate name or folder, a folder that is not one plain name, bad ``dem_datum``,
        a folder holding no scene.
    """
    from calibrate.scene_lists import read_entries

    from sensor_models.maps.dom_inputs import DomSource

    path = Path(path)
    if isinstance(dom, DomSource) and dom == DomSource():
        dom = None  # no DOM option given
    if path.is_dir():
        scenes = _folder_scenes(path, dom, dem, dem_datum, geoid)
    else:
        given = [k for k, v in (("dom", dom), ("dem", dem), ("dem_datum", dem_datum), ("geoid", geoid)) if v is not None]
        if given:
            raise InputError("the DOM and DEM options apply to a folder of scenes; a campaign file names each scene's",
                             path=str(path), field=given[0])
        entries = read_entries(path, required=_REQUIRED, optional=_OPTIONAL, paths=_PATHS, what="a campaign file",
                               suffixes=(".yaml", ".yml", ".json", ".csv"))
        scenes = [_scene_of(values, path) for values in entries]
    seen: dict[str, str] = {}
    for s in scenes:
        key = s.out.casefold()
        if key in seen:
            raise InputError(f"scene {s.name!r}: folder {s.out!r} already used by scene {seen[key]!r}",
                             path=str(path), field="out")
        seen[key] = s.name
    return scenes


def _scene_of(values: dict, path: Path) -> CampaignScene:
    label = values.pop("_label")
    out = values.pop("out", None)
    if out is None:
        out = _safe_name(values["name"])
    elif out in (".", "..") or "/" in out or "\\" in out or out.startswith("."):
        raise InputError(f"{label}: must be one folder name inside OUT, got {out!r}", path=str(path), field="out")
    if out.casefold() in {name.casefold() for name in FILES.values()}:
        raise InputError(f"{label}: {out!r} is a file of the campaign", path=str(path), field="out")
    if values.get("dem_datum") not in (None, "ellipsoid", "egm96"):
        raise InputError(f"{label}: must be ellipsoid or egm96, got {values['dem_datum']!r}", path=str(path),
                         field="dem_datum")
    return CampaignScene(out=out, **values)


def _folder_scenes(folder: Path, dom, dem, dem_datum, geoid) -> list[CampaignScene]:
    from dataclasses import replace

    from sensor_models.maps.dom_inputs import DomSource

    scenes = []
    for sub in sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if not (sub / "manifest.json").is_file():
            continue
        own_dom = sub / "reference" / "dom.tif"
        if isinstance(dom, DomSource):
            scene_dom = dom if dom.items else replace(dom, items=(str(own_dom),))
        else:
            scene_dom = own_dom if dom is None else Path(dom)
        scenes.append(CampaignScene(name=sub.name, scene=sub / "manifest.json", out=_safe_name(sub.name),
                                    dom=scene_dom, dem=sub / "reference" / "dem.tif" if dem is None else dem,
                                    dem_datum=dem_datum, geoid=None if geoid is None else Path(geoid)))
    if not scenes:
        raise InputError("holds no scene (no subfolder with a manifest.json)", path=str(folder))
    return scenes


# --------------------------------------------------------------------------- one scene (a Dask task)
def _dom_source(scene: CampaignScene):
    if not isinstance(scene.dom, (str, Path)) or (scene.dom_band is None and scene.dom_qa is None):
        return scene.dom
    from sensor_models.maps.dom_inputs import DomSource

    return DomSource(items=(str(scene.dom),), band=scene.dom_band, qa=() if scene.dom_qa is None else (str(scene.dom_qa),))


def _failed_row(scene: CampaignScene, reason: str) -> dict:
    row = {c: None for c in COLUMNS}
    row.update(name=scene.name, folder=scene.out, status="failed", reason=" ".join(str(reason).split()))
    return row


def campaign_scene(scene: CampaignScene, out_dir, *, options: dict, argv=None, overwrite: bool = False,
                   made_from: dict | None = None) -> dict:
    """Run one scene of a campaign (:func:`calibrate.pipelines.run.run_scene` into ``out_dir/scene.out``); never raises.

    Parameters
    ----------
    scene : CampaignScene
    out_dir : str or Path
        The campaign's folder (its staging folder while a campaign staged whole runs).
    options : dict
        Keywords of :func:`calibrate.pipelines.run.run_scene` common to every scene
        (``spacing_px``, ``min_gcps``, ``min_coverage``, ``relative``, ``threads``).
    argv : sequence of str, optional
        The campaign's command line, recorded in the scene's provenance.
    overwrite : bool
        ``--overwrite`` of the campaign (a worker does not share the command's context).
    made_from : dict, optional
        What the scene is made from (:func:`calibrate.pipelines.campaign_resume.made_from`),
        recorded with the worker in the scene's ``run.summary.json`` under ``campaign``.

    Returns
    -------
    dict
        The scene's row (keys :data:`COLUMNS`): ``status`` ``"ok"`` when the run succeeded,
        else ``"failed"`` with the one-line ``reason``.
    """
    t0 = time.perf_counter()
    row = _failed_row(scene, "")
    worker = f"{os.uname().nodename}:{os.getpid()}"
    try:
        if not Path(out_dir).is_dir():  # a task started after its campaign stopped: write nothing
            raise InputError("the campaign's folder is gone (the campaign was stopped)", path=str(out_dir))
        with contextlib.ExitStack() as stack:
            stack.enter_context(running_command("campaign"))
            stack.enter_context(allow_overwrite(overwrite))
            if argv is not None:
                stack.enter_context(command_line(argv))
            summary = run_scene(scene.scene, dom_path=_dom_source(scene), dem_path=scene.dem,
                                out_dir=Path(out_dir) / scene.out, star_frames=scene.star_frames,
                                dem_datum=scene.dem_datum, geoid=scene.geoid,
                                record={RECORD_KEY: {"made_from": made_from, "worker": worker}}, **options)
        summary_row(row, summary)
    except GcpcalError as exc:
        row["reason"] = " ".join(str(exc).split())
    except MemoryError:
        row["reason"] = "out of memory"
    except Exception as exc:  # noqa: BLE001 - a failing scene is a row, never a stopped campaign
        row["reason"] = " ".join(f"{type(exc).__name__}: {exc}".split())
    row["seconds"] = time.perf_counter() - t0
    row["worker"] = worker
    return json_safe(row)


def _kept_row(scene: CampaignScene, summary: dict) -> dict:
    """The row of a scene whose earlier folder stands: read from its ``run.summary.json``
    (``seconds``: that run's, ``worker``: the one that ran it)."""
    row = summary_row(_failed_row(scene, ""), summary)
    row["seconds"] = summary.get("seconds")
    row["worker"] = (summary.get(RECORD_KEY) or {}).get("worker")
    return json_safe(row)


# --------------------------------------------------------------------------- the campaign
def run_campaign(scenes, out_dir, *, source=None, scheduler=None, workers: int | None = None, threads: int | None = None,
                 processes: bool = True, timeout_s: float = 10.0, spacing_px: int = 16, min_gcps: int = MIN_GCPS,
                 min_coverage: float = MIN_COVERAGE, relative: bool = False, resume: bool = False, progress=None,
                 note=None) -> dict:
    """Run every scene (module docstring) and write the campaign folder ``out_dir``.

    Parameters
    ----------
    scenes : list of CampaignScene
        From :func:`read_campaign`.
    out_dir : str or Path
        The campaign folder (checked by the output guard before any work).
    source : str or Path, optional
        The campaign file or folder (recorded, and an input of the guard).
    scheduler : str, optional
        Dask scheduler address; default: a LocalCluster of ``workers``.
    workers : int, optional
        Workers of the LocalCluster; default: one per core, at most one per scene.
    threads : int, optional
        Matching threads of each scene; default: the cores shared among the LocalCluster's
        workers, or every core of the worker's machine at a scheduler (0).
    processes : bool
        LocalCluster workers are processes (True) or threads of this process (False).
    timeout_s : float
        Seconds allowed to reach ``scheduler`` and for its first worker.
    spacing_px, min_gcps, min_coverage, relative
        As :func:`calibrate.pipelines.run.run_scene` (``gcpcal run``'s options).
    resume : bool
        Keep the scene folders of ``out_dir`` that an earlier run completed from the same inputs
        and options (:mod:`calibrate.pipelines.campaign_resume`), run the other scenes, each
        folder moved into ``out_dir`` as soon as its scene ends, and rebuild the campaign's files
        over all. Without it ``out_dir`` is staged whole.
    progress : callable(done, total, row), optional
        Called with ``(0, n, None)`` when the work starts, then as each scene finishes (a kept
        scene first).
    note : callable(str), optional
        Receives the resume decisions: how many scenes are kept, and why each other scene runs again.

    Returns
    -------
    dict
        The summary written to ``campaign.json`` (``rows`` in the campaign's order, ``ok``,
        ``failed``, ``failures`` by name, ``files``; with ``resume``, ``kept``: the names of the
        scenes kept and ``rerun``: name -> why), its paths naming ``out_dir``.

    Raises
    ------
    InputError
        No scene, a bad scheduler address or an unreachable scheduler, an output refused by the guard.
    """
    t0 = time.perf_counter()
    scenes = list(scenes)
    if not scenes:
        raise InputError("no scene in the campaign", field="scenes")
    if scheduler is not None:
        check_scheduler_address(scheduler)
    cores = available_cores()
    workers = int(workers) if workers else min(len(scenes), cores)
    if threads is None:
        threads = 0 if scheduler is not None else max(1, cores // workers)
    options = {"spacing_px": int(spacing_px), "min_gcps": int(min_gcps), "min_coverage": float(min_coverage),
               "relative": bool(relative), "threads": int(threads)}
    _refuse_foreign_files(out_dir)
    inputs = [source] + [s.inputs for s in scenes]
    records = [made_from(s, options) for s in scenes]
    cluster = {"scheduler": scheduler, "workers": workers, "processes": processes, "timeout_s": timeout_s}
    if resume:
        return _resume_campaign(scenes, records, out_dir, options, inputs, cluster, source, t0, progress, note)
    with staged_folder(out_dir, ".campaign-", inputs=inputs) as stage:
        if Path(out_dir).is_dir():  # scene folders an interrupted --resume run committed: one ledger
            fold_ledgers(Path(out_dir), [Path(out_dir) / s.out for s in scenes])
        if progress is not None:
            progress(0, len(scenes), None)
        todo = dict(enumerate(scenes))
        with dask_log_level():
            rows, n_workers = _run_tasks(todo, records, stage, out_dir, options, progress=progress, **cluster)
        rows = [rows[k] for k in range(len(scenes))]
        summary = _summary(source, rows, options, scheduler, n_workers)
        with atomic_folder(stage, mode="merge", inside=True) as tmp:
            _write_outputs({key: tmp / name for key, name in FILES.items()}, stage, scenes, rows, summary, t0)
    return final_paths(summary, stage, out_dir)


def _summary(source, rows, options, scheduler, n_workers) -> dict:
    return {"kind": "gcpcal.campaign", "campaign": None if source is None else str(source),
            "scenes": len(rows), "ok": sum(r["status"] == "ok" for r in rows),
            "failed": sum(r["status"] != "ok" for r in rows),
            "failures": {r["name"]: r["reason"] for r in rows if r["status"] != "ok"},
            "options": options, "scheduler": scheduler or "LocalCluster", "workers": n_workers,
            "task_seconds": float(sum(r["seconds"] or 0.0 for r in rows))}


def _resume_campaign(scenes, records, out_dir, options, inputs, cluster, source, t0, progress, note) -> dict:
    """``run_campaign(resume=True)``: keep the scene folders that stand, run the others into ``out_dir``
    one folder at a time, then write the campaign's files (:func:`run_campaign`)."""
    from calibrate.actions._commit import folder_unit
    from calibrate.actions._guard import input_set
    from calibrate.actions._io import check_output_folder, staged_files
    from calibrate.actions._ledger import record
    from calibrate.actions._staging import clean_stale

    inputs = input_set(inputs)
    final = check_output_folder(out_dir, inputs=inputs)
    final.mkdir(parents=True, exist_ok=True)
    clean_stale(final)  # staging of scenes a killed campaign was running
    fold_ledgers(final, [final / s.out for s in scenes])
    rows: list = [None] * len(scenes)
    todo, rerun = {}, {}
    for k, scene in enumerate(scenes):
        summary, why = earlier_output(final / scene.out, records[k])
        if summary is not None:
            rows[k] = _kept_row(scene, summary)
            continue
        todo[k] = scene
        if why is not None:
            rerun[scene.name] = why
            clear_scene(final / scene.out)
    kept = [s.name for k, s in enumerate(scenes) if k not in todo]
    if note is not None:
        note(f"kept {len(kept)} of {len(scenes)} scene(s) from the earlier run (same inputs and options)")
        for name, why in rerun.items():
            note(f"{name} runs again: {why}")
    if progress is not None:
        progress(0, len(scenes), None)
        for done, row in enumerate((r for r in rows if r is not None), start=1):
            progress(done, len(scenes), row)
    n_workers = 0
    if todo:
        with dask_log_level():
            new, n_workers = _run_tasks(todo, records, final, out_dir, options, progress=progress,
                                        done0=len(kept), **cluster)
        for k in todo:
            rows[k] = new[k]
    fold_ledgers(final, [final / s.out for s in scenes])
    summary = _summary(source, rows, options, cluster["scheduler"], n_workers)
    summary.update(kept=kept, rerun=rerun)
    paths = {key: final / name for key, name in FILES.items()}
    keys = list(paths)
    with staged_files(*paths.values(), inputs=inputs) as staged:
        _write_outputs(dict(zip(keys, staged)), final, scenes, rows, summary, t0)
    # one unit with the scenes' files, as a campaign staged whole records them
    record(final, {name: final / name for name in FILES.values()}, unit=folder_unit("campaign"), command="campaign")
    return final_paths(summary, final, out_dir)


def _refuse_foreign_files(out_dir) -> None:
    """Refuse, before hours of work, to replace a campaign file gcpcal did not write (or that changed since).

    The commit checks every file again at the end (:mod:`calibrate.actions._commit`); the
    campaign's own names are known now.
    """
    from calibrate.actions._ledger import owned

    if overwrite_allowed():
        return
    for name in FILES.values():
        path = Path(out_dir) / name
        if path.is_file() and not path.is_symlink() and not owned(path):
            raise OutputRefusedError("exists and gcpcal did not write it (or it changed since): give --overwrite to "
                                     "replace it, or another --out", path=str(path))


def _run_tasks(todo: dict, records, into: Path, out_dir, options: dict, *, scheduler, workers, processes, timeout_s,
               progress, done0: int = 0):
    """Submit one :func:`campaign_scene` per scene of ``todo`` (index -> scene) into ``into``; return
    their rows by index (their messages naming ``out_dir``, not ``into``) and the worker count."""
    from distributed import as_completed

    argv, overwrite = current_command_line(), overwrite_allowed()
    rows: dict = {}
    total = len(records)
    client, cluster = connect(scheduler, workers, timeout_s, processes=processes)
    futures = {}
    try:
        n_workers = worker_count(client, cluster, scheduler, timeout_s)
        futures = {client.submit(campaign_scene, s, str(into), options=options, argv=argv, overwrite=overwrite,
                                 made_from=records[k], pure=False, key=f"gcpcal-campaign-{k}-{s.out}"): k
                   for k, s in todo.items()}
        for done, fut in enumerate(as_completed(futures), start=done0 + 1):
            k = futures[fut]
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 - a lost worker fails its scene only
                row = _failed_row(todo[k], f"task error: {type(exc).__name__}: {exc}")
            rows[k] = row = final_paths(row, into, out_dir)
            if progress is not None:
                progress(done, total, row)
    finally:
        if futures:
            client.cancel(list(futures))
        client.close()
        if cluster is not None:
            cluster.close()
    return rows, n_workers


def _write_outputs(paths: dict, scene_root: Path, scenes, rows, summary: dict, t0: float) -> None:
    """Write the campaign's files (:data:`FILES`) to ``paths`` (key -> staged path): the residual
    layer of the scene folders under ``scene_root``, the table and the summary."""
    from calibrate.residual_layer import LAYER_NAMES, concatenate_layers, read_residual_layer, write_residual_layer

    layers = []
    for scene, row in zip(scenes, rows):
        part = scene_root / scene.out / "calibration" / "residuals.gpkg"
        if row["status"] == "ok" and part.is_file():
            layer = read_residual_layer(part)
            layer["site"] = [scene.name] * len(layer["id"])
            layers.append(layer)
    summary["residual_points"] = int(sum(len(x["id"]) for x in layers))
    summary["files"] = dict(FILES)
    write_residual_layer(concatenate_layers(layers), paths["residuals"], layer=LAYER_NAMES["campaign"])
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({c: "" if r.get(c) is None else (repr(r[c]) if isinstance(r[c], float) else r[c])
                         for c in COLUMNS})
    Path(paths["csv"]).write_text(buf.getvalue(), encoding="utf-8")
    summary["seconds"] = time.perf_counter() - t0
    summary.update(columns=list(COLUMNS), rows=rows)
    doc = json_safe(with_provenance(summary))
    Path(paths["json"]).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
