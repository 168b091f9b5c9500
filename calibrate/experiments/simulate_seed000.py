"""Seed 000 experiment: calibration of a geostationary staring camera from star tracks.

Each session is one 20-minute sequence (seed 000: a specific time on consecutive days; 1024 x
1024 frames of the 1250 mm / 25 um camera every 10 s) rendered by
:func:`sensor_models.simulate.star_sky.simulate_geo_stars` under the stars profile (``ideal``:
the default sequence; ``realistic``/``paper-000``: 1 arcsec attitude noise, an unmeasured 2 arcsec wobble
over 20 min, Hipparcos-level catalogue errors, pixel-phase and PRNU centroid systematics, orbit
error: :mod:`sensor_models.simulate.star_truth`), then processed by
:func:`calibrate.star_calibration.process_frames` (detection, identification, tracks, stepwise calibration,
five held-out points per track). Accuracy is seed 000's: mean absolute RA/DE error of the
held-out points (table 3) and the 2-sigma bound of their normal fit (table 4), pixels.

Scale: the paper pools 20 days (437 tracks). A session here is one day with its own noise,
wobble and date; ``paper-000`` runs :data:`FULL_SESSIONS` of them (``quick``: one short one), and
the result states the number. A session has 120 frames by default (``frames``: more frames,
more tracks of over 25 points; 160 give over 400 tracks from 20 sessions, the paper's scale).

Sensitivity: accuracy against the attitude noise (the observation-noise analogue for stars) and
against the unmeasured wobble amplitude (jitter). DEM and DOM errors do not apply to stars.

Speed: the sessions are independent (each its own seed), so they run in worker processes
(:class:`SessionPool`, one per core this process may use, one OpenCV and one BLAS thread each);
day 0 goes first, as the other days take its installation. Each session's figures are those of
a run in one process. A session's frames stay in memory (``simulate_geo_stars(frames_out=)``):
the same uint16 values as the GeoTIFF frames a user's run reads.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate.config import StarOptions
from calibrate.experiments.results import ExperimentResult, PaperTable, SensitivityCurve
from sensor_models.errors import InputError
from sensor_models.simulate.profiles import Sourced, get_profile, profile_table

__all__ = ["FULL_SESSIONS", "MIN_FRAMES", "PAPER", "SessionPool", "default_workers", "run", "run_session"]

#: sessions of a full ``paper-000`` run: the paper's 20 days (a session of 120 frames: ~6 CPU-s)
FULL_SESSIONS = 20
#: fewest frames per session: a track needs more than 25 points (seed 000 section 3.2)
MIN_FRAMES = 30
#: sessions of a quick run of a profile with several sessions (enough to exercise the pooling)
QUICK_SESSIONS = 2
#: the star processing of every session (seed 000: tracks of > 25 points, five held out per track)
OPTIONS = StarOptions(mag_limit=10.5, compare_joint=False)
#: sessions pooled per point of the day-to-day sensitivity curve
CURVE_SESSIONS = 5
#: seed of the day-to-day installation offsets (one draw per day index)
DAY_TO_DAY_SEED = 17
#: seed 000 table 3 (mean of 20 days) and table 4 (normal fit), pixels
PAPER = {"ra_before_px": -6.795, "de_before_px": -21.004, "ra_mean_abs_px": 0.84175, "de_mean_abs_px": 0.8534,
         "ra_two_sigma_px": 2.24, "de_two_sigma_px": 2.35, "tracks": 437}


def run_session(work: Path, profile, *, day: int, n_frames: int, installation_error_arcsec=(),
                noise_replay=None) -> dict:
    """Simulate and calibrate one session; its held-out accuracy.

    Parameters
    ----------
    work : Path
        Scratch folder of the session's manifest and truth (its frames stay in memory).
    profile : StarsProfile
    day : int
        Day index (the date and the noise seed).
    n_frames : int
        Frames, 10 s apart.
    installation_error_arcsec : (float, float, float) or ()
        The session's TRUE installation error (roll, pitch, yaw); empty: the simulator's
        choice for seed 000's initial error at the centre.
    noise_replay : sensor_models.simulate.noise_replay.NormalReplay, optional
        Noise draws shared with the other sessions of the same day (the same frames, faster).

    Returns
    -------
    dict
        ``success``, ``tracks``, ``ra/de_before_px`` (mean), ``ra/de_mean_abs_px``,
        ``ra/de_two_sigma_px``, ``installation_error_arcsec`` (the TRUE one) and ``session``
        (a :class:`calibrate.star_pooling.StarSession`, for pooling; not JSON).
    """
    from calibrate.star_calibration import process_frames
    from calibrate.star_pooling import StarSession
    from sensor_models.readers.geo_manifest import read_geo_manifest
    from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

    epoch = str(np.datetime64("2023-08-02T14:40:00") + np.timedelta64(int(day), "D"))
    inst = tuple(float(x) for x in installation_error_arcsec)
    folder = work / f"{profile.name}_day{day:02d}_{n_frames}" if not inst else work / f"{profile.name}_day{day:02d}_{n_frames}_i"
    config = GeoStarsConfig(n_frames=int(n_frames), epoch_utc=epoch, seed=int(day), installation_error_arcsec=inst)
    frames = []  # the uint16 frames, kept in memory (2 MB a frame) instead of written and read back
    simulated = simulate_geo_stars(folder, config=config, profile=profile, frames_out=frames,
                                   noise_replay=noise_replay)
    seconds = np.arange(len(frames)) * float(config.frame_interval_s)
    lab = read_geo_manifest(folder / "manifest.json")
    r = process_frames(frames, seconds, lab, options=OPTIONS)
    del frames
    a = r.accuracy
    out = {"success": bool(r.success), "tracks": int(r.frames["n_tracks"]),
           "installation_error_arcsec": simulated["installation_error_arcsec"],
           "session": StarSession.from_result(r, lab, seconds)}
    for k in ("ra", "de"):
        out[f"{k}_before_px"] = a["before"][k].get("mean_px")
        out[f"{k}_mean_abs_px"] = a["after"][k].get("mean_abs_px")
        out[f"{k}_two_sigma_px"] = a["after"][k].get("two_sigma_px")
    return out


def _session_mean(sessions: list) -> dict:
    """Mean of the per-session figures (each session calibrated alone)."""
    keys = [k for k in sessions[0] if k.endswith("_px")]
    out = {k: float(np.mean([s[k] for s in sessions if s[k] is not None])) for k in keys}
    out["tracks"] = int(sum(s["tracks"] for s in sessions))
    out["sessions"] = len(sessions)
    out["success"] = all(s["success"] for s in sessions)
    return out


def _table(alone: dict, pooled: dict | None) -> PaperTable:
    """Seed 000 tables 3-4 beside ours: each session calibrated alone, and one calibration of all."""
    def cell(doc, key):
        return None if doc is None else doc.get(key)

    rows = []
    for label, key in (("RA mean error before (px)", "ra_before_px"), ("DE mean error before (px)", "de_before_px"),
                       ("mean |RA| after (px)", "ra_mean_abs_px"), ("mean |DE| after (px)", "de_mean_abs_px"),
                       ("RA 2-sigma after (px)", "ra_two_sigma_px"), ("DE 2-sigma after (px)", "de_two_sigma_px")):
        rows.append([label, PAPER[key], alone[key], cell(pooled, key)])
    rows.append(["tracks", PAPER["tracks"], alone["tracks"], cell(pooled, "tracks")])
    return PaperTable("Held-out positioning error before and after calibration",
                      "seed 000 table 3 (means over 20 days), table 4 (2-sigma of the normal fit), section 4 "
                      "(437 tracks of the 20 days verify one model)",
                      ("quantity", "paper", "ours, each session alone (mean)", "ours, one calibration of all sessions"),
                      rows)


def _day_offsets_arcsec(profile, n_sessions: int) -> np.ndarray:
    """Day-to-day installation offsets (roll, pitch, yaw, arcsec) of each session; day 0 none."""
    sigma = float(profile.value("installation_day_to_day_arcsec"))
    out = np.zeros((n_sessions, 3))
    for day in range(1, n_sessions):
        out[day] = np.random.default_rng([DAY_TO_DAY_SEED, day]).normal(0.0, sigma, 3)
    return out


def default_workers() -> int:
    """Worker processes for the sessions: the cores this process may run on.

    Returns
    -------
    int
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # platforms without CPU affinity
        return max(1, os.cpu_count() or 1)


def _timed_session(work: Path, profile, **kw) -> tuple:
    """:func:`run_session` and the CPU seconds its process spent on it."""
    c0 = time.process_time()
    out = run_session(work, profile, **kw)
    return out, time.process_time() - c0


def _timed_group(work: Path, sessions: list, replay_bytes: int) -> list:
    """:func:`_timed_session` of each ``(profile, kw)`` in turn, the noise draws of the first
    replayed for the others (sessions of one day: the same draws, :mod:`~sensor_models.simulate.noise_replay`)."""
    from sensor_models.simulate.noise_replay import NormalReplay

    replay = NormalReplay(replay_bytes)
    return [_timed_session(work, profile, noise_replay=replay, **kw) for profile, kw in sessions]


def replay_budget_bytes(workers: int) -> int:
    """Memory each worker may keep of a day's noise draws: a quarter of the available memory
    shared by the workers (0 where the system does not say: nothing kept, the same results).

    Parameters
    ----------
    workers : int

    Returns
    -------
    int
        Bytes (a 160-frame session of 1024 x 1024 frames draws 1.34 GB).
    """
    from sensor_models.files.memory import available_memory_bytes

    free = available_memory_bytes()
    return 0 if free is None else int(free // (4 * max(1, int(workers))))


def _init_worker() -> None:
    """One OpenCV thread and one BLAS thread per worker process (the workers already fill the
    cores; a BLAS thread pool per process only contends on them)."""
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(1, user_api="blas")


class SessionPool:
    """Sessions run once each, in worker processes (``workers`` > 1) or in this one.

    ``submit`` returns a future of :func:`run_session`'s dict; a session already asked for
    (same magnitudes, day, frames and installation) returns the first one's future.
    ``submit_group`` runs sessions of one day one after the other in one worker, which draws
    their per-pixel noise once (:func:`replay_budget_bytes` of it kept). ``cpu_s`` sums the CPU
    seconds of the sessions finished so far (wherever they ran).

    Parameters
    ----------
    work : Path
        Scratch folder of the simulated sessions.
    workers : int
        Worker processes; 1 runs every session in this process.
    max_group : int, optional
        Most sessions a group runs in one worker (larger groups are split: many workers gain
        more from running sessions side by side than from sharing their noise).
    """

    def __init__(self, work: Path, workers: int, max_group: int | None = None):
        self.work = Path(work)
        self.workers = int(workers)
        self.max_group = None if max_group is None else max(1, int(max_group))
        self.futures: dict = {}
        self.cpu_s = 0.0
        self.pool = None
        self.replay_bytes = replay_budget_bytes(self.workers)
        if self.workers > 1:
            import multiprocessing

            if "forkserver" in multiprocessing.get_all_start_methods():  # no threads inherited, imports once
                ctx = multiprocessing.get_context("forkserver")
                ctx.set_forkserver_preload(["calibrate.experiments.simulate_seed000", "calibrate.star_calibration",
                                            "calibrate.star_pooling", "sensor_models.simulate.star_sky"])
            else:
                ctx = multiprocessing.get_context("spawn")
            self.pool = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_init_worker)

    def submit(self, profile, *, day: int, n_frames: int, installation_error_arcsec=()) -> Future:
        """Run one session (:func:`run_session`), or return the future of the same one asked before.

        Parameters
        ----------
        profile : StarsProfile
        day, n_frames, installation_error_arcsec
            Of :func:`run_session`.

        Returns
        -------
        Future
            Of :func:`run_session`'s dict.
        """
        return self.submit_group([(profile, dict(day=day, n_frames=n_frames,
                                                 installation_error_arcsec=installation_error_arcsec))])[0]

    def submit_group(self, sessions: list) -> list:
        """Run sessions of one day one after the other in one worker, their noise drawn once.

        Parameters
        ----------
        sessions : list of (StarsProfile, dict)
            Each profile and :meth:`submit`'s keywords (``day``, ``n_frames``,
            ``installation_error_arcsec``); sessions already asked for are not run again.

        Returns
        -------
        list of Future
            Of :func:`run_session`'s dict, one per session given.
        """
        keys, new = [], {}
        for profile, kw in sessions:
            kw = dict(day=int(kw["day"]), n_frames=int(kw["n_frames"]),
                      installation_error_arcsec=tuple(float(x) for x in kw.get("installation_error_arcsec", ())))
            key = (_magnitudes(profile), kw["day"], kw["n_frames"], kw["installation_error_arcsec"])
            keys.append(key)
            if key not in self.futures and key not in new:
                new[key] = (profile, kw)
        items = list(new.items())
        size = len(items) if self.max_group is None else self.max_group
        for start in range(0, len(items), max(1, size)):
            chunk = items[start:start + size]
            args = (_timed_group, self.work, [session for _, session in chunk], self.replay_bytes)
            if self.pool is not None:
                timed = self.pool.submit(*args)
            else:
                timed = Future()
                timed.set_result(args[0](*args[1:]))
            for i, (key, _) in enumerate(chunk):
                self.futures[key] = self._untimed(timed, i)
        return [self.futures[key] for key in keys]

    def _untimed(self, timed: Future, index: int) -> Future:
        """A future of one session's dict (``index`` in its group); its CPU time added to ``cpu_s``."""
        out = Future()

        def done(f):
            if f.cancelled():
                out.cancel()
                return
            if f.exception() is not None:
                out.set_exception(f.exception())
                return
            result, cpu = f.result()[index]
            self.cpu_s += cpu
            out.set_result(result)

        timed.add_done_callback(done)
        return out

    def close(self) -> None:
        """Stop the worker processes (waiting for the sessions running, cancelling the others)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)


def _following_days(profile, first: dict, n_sessions: int, n_frames: int) -> dict:
    """Days 1..n-1 of ``profile``, ``{day: (profile, keywords of SessionPool.submit)}``: day 0's
    installation plus the profile's daily offset."""
    base = np.asarray(first["installation_error_arcsec"], dtype=np.float64)
    offsets = _day_offsets_arcsec(profile, n_sessions)
    return {day: (profile, dict(day=day, n_frames=n_frames, installation_error_arcsec=tuple(base + offsets[day])))
            for day in range(1, n_sessions)}


def _day_to_day_plan(profile, quick: bool, n_sessions: int) -> tuple:
    """Points of the day-to-day curve: the offsets (arcsec), the sessions pooled per point and the
    varied profile of each offset (None: the profile's own value, its sessions are reused)."""
    own = float(profile.value("installation_day_to_day_arcsec"))
    xs = sorted({own, 4.0 if quick else 0.0} | (set() if quick else {2.0, 4.0}))
    k = min(n_sessions, 2 if quick else CURVE_SESSIONS)
    varied = {x: None if x == own else replace(profile, name=f"{profile.name}-day{x:g}",
                                                installation_day_to_day_arcsec=Sourced(x, "sensitivity"))
              for x in xs}
    return xs, k, varied


def _day_to_day_curve(profile, n_frames: int, xs, k: int, runs: dict) -> SensitivityCurve:
    """Pooled held-out error against the day-to-day installation change (``runs``: offset -> the
    ``k`` sessions of that point; day 0 is shared, its installation has no offset)."""
    mean_abs, two_sigma = [], []
    for x in xs:
        doc = _pooled_figures(runs[x])
        mean_abs.append(0.5 * (doc["ra_mean_abs_px"] + doc["de_mean_abs_px"]))
        two_sigma.append(0.5 * (doc["ra_two_sigma_px"] + doc["de_two_sigma_px"]))
    return SensitivityCurve("installation_day_to_day", "day-to-day installation change (arcsec, 1 sigma per axis)",
                            "held-out error, one calibration of all sessions (px)", xs,
                            {"mean |RA|,|DE| px": mean_abs, "2-sigma px": two_sigma},
                            f"{k} sessions of {n_frames} frames pooled per point; other magnitudes: {profile.name}")


def _pooled_figures(sessions: list) -> dict:
    """One calibration of every session's tracks, scored on every held-out point."""
    from calibrate.star_pooling import calibrate_pooled

    doc = calibrate_pooled([s["session"] for s in sessions], options=OPTIONS)
    out = {"success": bool(doc["success"]), "tracks": int(sum(s["tracks"] for s in sessions)),
           "sessions": int(doc["sessions"])}
    if not doc["success"] and "after" not in doc:
        return out
    for k in ("ra", "de"):
        out[f"{k}_before_px"] = doc["before"][k].get("mean_px")
        out[f"{k}_mean_abs_px"] = doc["after"][k].get("mean_abs_px")
        out[f"{k}_two_sigma_px"] = doc["after"][k].get("two_sigma_px")
    per_session = [0.5 * (p["ra_mean_abs_px"] + p["de_mean_abs_px"]) for p in doc["per_session"]]
    out["worst_session_mean_abs_px"] = float(max(per_session))
    return out


def _magnitudes(profile) -> tuple:
    """The profile's magnitudes (not its name): equal tuples render the same session."""
    return tuple(str(row[1]) for row in profile_table(profile))


def _curve_plan(profile, quick: bool) -> list:
    """Attitude-noise and wobble curves: ``(field, xs, label, profiles)``, one day-0 profile per point."""
    base = profile if not profile.is_ideal else replace(profile, name="ideal-varied")
    own = {"attitude_noise_arcsec": profile.value("attitude_noise_arcsec"), "wobble_arcsec": profile.value("wobble_arcsec")}
    plan = []
    for field, xs, label in (("attitude_noise_arcsec", [0.1, 1.0] if quick else [0.1, 0.5, 1.0, 2.0],
                              "measured-attitude noise (arcsec, 1 sigma)"),
                             ("wobble_arcsec", [0.0, 2.0] if quick else [0.0, 1.0, 2.0, 4.0],
                              "unmeasured wobble amplitude (arcsec, 20 min period)")):
        if quick:  # the profile's own value and one other
            xs = sorted({float(own[field]), xs[1] if float(own[field]) == xs[0] else xs[0]})
        plan.append((field, xs, label, [replace(base, name=f"{profile.name}-{field}-{x:g}",
                                                **{field: Sourced(x, "sensitivity")}) for x in xs]))
    return plan


def _curves(profile, n_frames, plan: list, runs: list) -> list:
    """Sensitivity curves of :func:`_curve_plan`; ``runs[i][j]``: the session of point ``j`` of curve ``i``."""
    curves = []
    for (field, xs, label, _), points in zip(plan, runs):
        mean_abs = [0.5 * (s["ra_mean_abs_px"] + s["de_mean_abs_px"]) for s in points]
        two_sigma = [0.5 * (s["ra_two_sigma_px"] + s["de_two_sigma_px"]) for s in points]
        curves.append(SensitivityCurve(field.replace("_arcsec", ""), label, "held-out error (px)", xs,
                                       {"mean |RA|,|DE| px": mean_abs, "2-sigma px": two_sigma},
                                       f"one session of {n_frames} frames per point; other magnitudes: {profile.name}"))
    return curves


def _all_sessions(work, profile, n_sessions: int, n_frames: int, quick: bool, workers: int) -> tuple:
    """Every session of the experiment: the profile's days, the curves' day-0 variants and the
    day-to-day curve's days (day 0 first; the other days once its installation is known), the
    sessions of one day grouped (:meth:`SessionPool.submit_group`); and ``{"simulated": sessions
    run, "cpu_s": their CPU seconds}``."""
    plan = _curve_plan(profile, quick)
    xs, k, varied = _day_to_day_plan(profile, quick, n_sessions) if n_sessions > 1 else (None, 0, {})
    expected = n_sessions + sum(len(row[-1]) for row in plan) + (k - 1) * sum(v is not None for v in varied.values())
    runner = SessionPool(work, workers, max_group=max(1, -(-expected // (2 * max(1, int(workers))))))
    try:
        first = runner.submit(profile, day=0, n_frames=n_frames)
        flat = iter(runner.submit_group([(p, dict(day=0, n_frames=n_frames)) for *_, profiles in plan for p in profiles]))
        curve_runs = [[next(flat) for _ in profiles] for *_, profiles in plan]
        day0 = first.result()
        wanted = {None: _following_days(profile, day0, n_sessions, n_frames)}  # None: the profile's own days
        wanted.update({x: _following_days(v, day0, k, n_frames) for x, v in varied.items() if v is not None})
        futures = {x: {} for x in wanted}
        groups = [[(x, wanted[x][day]) for x in wanted if day in wanted[x]] for day in range(1, n_sessions)]
        for group in sorted(groups, key=len, reverse=True):  # the longest first: the workers end together
            for (x, session), f in zip(group, runner.submit_group([session for _, session in group])):
                futures[x][session[1]["day"]] = f
        days = [first] + [futures[None][day] for day in range(1, n_sessions)]
        day_runs = {x: days[:k] if v is None else [first] + [futures[x][day] for day in range(1, k)]
                    for x, v in varied.items()}
        days = [f.result() for f in days]
        curve_runs = [[f.result() for f in row] for row in curve_runs]
        day_runs = {x: [f.result() for f in row] for x, row in day_runs.items()}
    finally:
        runner.close()
    day_plan = (xs, k) if n_sessions > 1 else None
    return days, (plan, curve_runs), (day_plan, day_runs), {"simulated": len(runner.futures), "cpu_s": runner.cpu_s}


def run(profile_name: str, *, quick: bool = False, work_dir=None, workers: int | None = None,
        frames: int | None = None) -> ExperimentResult:
    """Run the seed 000 experiment (module docstring).

    Parameters
    ----------
    profile_name : str
        ``ideal``, ``realistic`` or ``paper-000``.
    quick : bool
        Sessions of 30 frames (one, or two for a profile of several sessions, so that the pooling
        runs); two points per sensitivity curve (one of them the profile's own).
    work_dir : Path
        Scratch folder (frames).
    workers : int, optional
        Processes running the sessions (default :func:`default_workers`; 1: all in this one).
        The figures do not depend on it. With more than one, a script that calls ``run`` must
        do so under ``if __name__ == "__main__":`` (the workers import the main module).
    frames : int, optional
        Frames per session, 10 s apart (default 120, 30 with ``quick``; at least
        :data:`MIN_FRAMES`). A star crosses the frame in about 28 frames, so the tracks of more
        than 25 points grow with the session: ~16 a session at 120 frames, ~19 at 150.

    Raises
    ------
    InputError
        ``frames`` below :data:`MIN_FRAMES`.

    Returns
    -------
    ExperimentResult
    """
    t0 = time.perf_counter()
    profile = get_profile(profile_name, "stars")
    work = Path(work_dir)
    n_frames = (30 if quick else 120) if frames is None else int(frames)
    if n_frames < MIN_FRAMES:
        raise InputError(f"at least {MIN_FRAMES} frames per session, got {n_frames}", field="frames")
    wanted = int(profile.value("sessions"))
    n_sessions = min(wanted, QUICK_SESSIONS if quick else FULL_SESSIONS)
    sessions, (plan, curve_runs), (day_plan, day_runs), cost = _all_sessions(
        work, profile, n_sessions, n_frames, quick, default_workers() if workers is None else int(workers))
    alone = _session_mean(sessions)
    pooled = _pooled_figures(sessions) if n_sessions > 1 else None
    headline = {**{k: v for k, v in alone.items() if k.endswith("_px")}, "tracks": alone["tracks"],
                "success": alone["success"]}
    if pooled is not None:
        headline.update({f"pooled_{k}": v for k, v in pooled.items() if k.endswith("_px")})
        headline["pooled_success"] = pooled["success"]
    result = ExperimentResult(
        "000", profile_name, quick, "Seed 000: geostationary staring camera calibrated from the relative motion of stars",
        scale={"frames_per_session": n_frames, "frame_interval_s": 10.0, "image_shape": [1024, 1024],
               "sessions_run": n_sessions, "sessions_of_profile": wanted, "paper_days": 20, "paper_tracks": 437,
               "day_to_day_installation_arcsec": float(profile.value("installation_day_to_day_arcsec")),
               "sessions_simulated": cost["simulated"], "session_cpu_s": round(cost["cpu_s"], 1)},
        tables=[_table(alone, pooled)],
        curves=_curves(profile, n_frames, plan, curve_runs)
        + ([_day_to_day_curve(profile, n_frames, *day_plan, day_runs)] if pooled is not None else []),
        headline=headline, profile_rows=[(profile.name, *row) for row in profile_table(profile)], notes=NOTES)
    result.seconds = time.perf_counter() - t0
    return result

NOTES = [
    "Before: ours is set to the paper's table 3 means by construction (installation error chosen to give "
    "-7/-21 px at the centre): not a result.",
    "After, ideal: ~0.02 px, 40x better than the paper: the ideal truth has 0.1 arcsec attitude noise, no "
    "unmeasured motion, a perfect catalogue and an unbiased centroid.",
    "After, realistic (full 120-frame sessions, measured): the unmeasured 2 arcsec wobble and the 1 arcsec "
    "attitude noise share the error (0.32 px; 0.20 px without the wobble, 0.26 px with 0.1 arcsec noise); "
    "catalogue errors (~32 mas with the proper-motion epoch error, ~0.01 px), the 0.05 px pixel-phase S-curve "
    "and PRNU are small by their magnitudes (not ablated one by one), and a GEO orbit error moves no star.",
    "The paper verifies one model on 20 days (437 tracks) in which the installation changes thermally from day "
    "to day. paper-000 runs 20 sessions that share one TRUE installation plus a daily offset "
    "(installation_day_to_day_arcsec, 1 arcsec: an assumption) and reports each session calibrated alone and "
    "one calibration of all (pooled). The day-to-day sensitivity curve shows the paper's figures at about 4 "
    "arcsec a day, inside the 3-6 arcsec thermal budget: the main remaining gap, not tuned away.",
]
