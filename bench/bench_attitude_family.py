"""Measure the time-varying attitude over a randomized family of scenes (docs/attitude.md).

Each seeded draw of :mod:`sensor_models.simulate.attitude_family` (duration 2-20 s, 100 to
100 000 GCPs, noise 0.05-0.5 px, jitter 0.1-3 Hz at 0-40 urad per axis as sums of one to three
sinusoids, drift, one band or four) is calibrated from its synthetic GCPs with ``--attitude
static`` and ``auto`` (four bands: then the joint estimation with the band parallax,
:func:`calibrate.parallax.calibrate_with_parallax`, from the three other bands' tie points), and
scored against its TRUE model (rms image distance over every fourth line, 16 columns per line,
every band). The criteria:

* ``observable`` jitter: the highest jitter frequency lies below the GCPs' Nyquist rate in time,
  ``n_lines / (2 T)`` with ``n_lines`` the distinct image lines holding GCPs;
* ``noise floor``: ``sqrt(e_twin^2 + sigma^2 p / N)``, ``e_twin`` the static calibration's truth
  error on the same draw without jitter and drift (the same GCP pixels and noise), ``p`` the
  truth's time-variation degrees of freedom (:meth:`SceneDraw.jitter_dof`), ``sigma`` the GCP
  noise and ``N`` the GCPs;
* ``accuracy`` (observable jitter): truth error <= 0.15 px or <= 1.5 x the noise floor;
* ``gain`` (observable jitter, static above 0.5 px, and 1.5 x the floor below 0.35 x static: no
  estimator beats its noise floor): truth error <= 0.35 x static; ``gain_raw`` without the floor
  condition;
* ``no_jitter`` (no jitter): truth error <= 1.05 x static;
* ``accuracy_gap``, ``gain_gap``: the same two where the largest gap between GCP lines is below
  half the jitter's shortest period (irregular sampling, Gröchenig 1992).

Usage: ``python bench/bench_attitude_family.py [--draws 120] [--small 40] [--first-seed 0]
[--jobs N] [--out FILE.json]`` (prints the table: draws, pass rate per criterion, worst case);
``--summarize FILE.json`` prints the tables of a (partial) run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from calibrate.absolute import calibrate_model  # noqa: E402
from calibrate.config import CalibrationOptions  # noqa: E402
from gcpmatch.gcps import GcpTable  # noqa: E402
from sensor_models.simulate import attitude_family as fam  # noqa: E402

#: the criteria (module docstring)
ACCURACY_PX = 0.15
FLOOR_FACTOR = 1.5
GAIN_RATIO = 0.35
GAIN_STATIC_PX = 0.5
NO_JITTER_RATIO = 1.05
#: the sub-family of few GCPs
SMALL_GCPS = (100, 300)


def _table(g) -> GcpTable:
    n = g["row"].size
    return GcpTable.from_arrays(g["row"], g["col"], g["lon"], g["lat"], g["h"], band=np.full(n, g["band"]),
                                sigma_px=np.full(n, g["sigma_px"]))


def _ties(draw, truth, model, band):
    """TiePoints of ``band`` (TRUE transfer map), their ground through the calibrated ``model``."""
    from calibrate.tie_points import TiePoints

    t = fam.synthetic_ties(draw, truth, band)
    lon, lat, h = model.image_to_ground(t["row_ref"], t["col_ref"], height=300.0, band=model.reference_band,
                                        array=t["ccd_ref"])
    n = t["row"].size
    return TiePoints(band, t["row_ref"], t["col_ref"], t["ccd_ref"], np.asarray(lon), np.asarray(lat), np.asarray(h),
                     t["row"], t["col"], t["ccd"], t["row"], t["col"], np.ones(n), np.full(n, 0.02))


def _with_bands(draw, truth, ref_result):
    """Reference band calibrated (``ref_result``); every other band's interior from its ties."""
    model, ties = ref_result.model, {}
    for band in truth.bands:
        if band == truth.reference_band:
            continue
        ties[band] = _ties(draw, truth, model, band)
        model = calibrate_model(model, ties[band].as_gcp_table(), options=CalibrationOptions(scheme="interior")).model
    return model, ties


def run_draw(draw) -> dict:
    """Calibrate one draw static and auto (and jointly for four bands); its errors and criteria.

    Parameters
    ----------
    draw : SceneDraw

    Returns
    -------
    dict
        The draw, ``static_px``, ``auto_px``, ``twin_px``, ``floor_px``, ``nyquist_hz``,
        ``observable``, the selection (``kind``, ``n_terms``, ``edf``, ``lambda``), ``seconds``
        and per criterion True/False (None where it does not apply).
    """
    t0 = time.perf_counter()
    lab = fam.lab_model(draw)
    truth = fam.true_model(draw, lab)
    g = fam.synthetic_gcps(draw, truth)
    gcps = _table(g)
    static = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="static"))
    auto = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="auto"))
    ref = [truth.reference_band]
    if draw.has_jitter or np.any(draw.drift_urad_s):
        twin_truth = fam.true_model(fam.without_time_variation(draw), lab)
        twin = calibrate_model(lab, _table(fam.synthetic_gcps(draw, twin_truth)),
                               options=CalibrationOptions(attitude="static"))
        twin_px = fam.truth_error(twin_truth, twin.model, bands=ref)
    else:  # the draw is its own twin
        twin, twin_px = static, fam.truth_error(truth, static.model, bands=ref)
    out = {"draw": draw.to_dict(), "success": bool(static.success and auto.success and twin.success)}
    if draw.n_bands > 1:
        from calibrate.parallax import calibrate_with_parallax

        static_model, _ = _with_bands(draw, truth, static)
        gcp_only, ties = _with_bands(draw, truth, auto)
        joint = calibrate_with_parallax(gcp_only, ties, gcps, height=300.0)
        out["success"] &= bool(joint.success)
        final = joint.model
        out["gcp_only_px"] = fam.truth_error(truth, gcp_only)
        sel = joint.to_dict()["selected"]
        chosen = next((r for r in joint.candidates if r.get("chosen")), {})
        out["selection"] = {**sel, "edf": chosen.get("n_parameters"), "lambda": chosen.get("lambda")}
    else:
        static_model, final = static.model, auto.model
        sel = (auto.attitude or {}).get("selected", {})
        out["selection"] = {k: sel.get(k) for k in ("kind", "n_terms", "knot_spacing_s", "edf", "lambda")}
    static_px = fam.truth_error(truth, static_model)
    auto_px = fam.truth_error(truth, final)
    n = draw.n_gcps
    rows = np.unique(np.floor(g["row"]))
    nyquist = rows.size / (2.0 * draw.duration_s)
    floor = float(np.sqrt(twin_px**2 + draw.noise_px**2 * draw.jitter_dof() / n))
    observable = draw.has_jitter and draw.max_frequency_hz() < nyquist
    out.update({"static_px": static_px, "auto_px": auto_px, "twin_px": twin_px, "floor_px": floor,
                "nyquist_hz": nyquist, "observable": bool(observable), "seconds": time.perf_counter() - t0})
    out["accuracy"] = bool(auto_px <= ACCURACY_PX or auto_px <= FLOOR_FACTOR * floor) if observable else None
    gain_applies = observable and static_px > GAIN_STATIC_PX
    out["gain_raw"] = bool(auto_px <= GAIN_RATIO * static_px) if gain_applies else None
    # no estimator beats its noise floor: the gain is asked where the floor allows it
    out["gain"] = out["gain_raw"] if gain_applies and FLOOR_FACTOR * floor <= GAIN_RATIO * static_px else None
    out["no_jitter"] = bool(auto_px <= NO_JITTER_RATIO * static_px) if not draw.has_jitter else None
    return out


def draws(n: int, *, first_seed: int = 0, n_gcps=None, ranges=fam.FamilyRanges()):
    """``n`` draws of seeds ``first_seed ..``; ``n_gcps`` overrides the GCP range."""
    return [fam.draw_scene(first_seed + k, ranges, n_gcps=n_gcps) for k in range(n)]


def _with_gap_criteria(r) -> dict:
    """``accuracy`` and ``gain`` again where the sampling theorem for irregular samples holds.

    Gröchenig (1992): a signal band-limited to ``f`` is recovered stably from samples whose
    largest gap is below ``1 / (2 f)``; random GCP lines have gaps several times their mean, so
    a mean rate above Nyquist does not suffice.
    """
    d = r["draw"]
    draw = fam.SceneDraw(d["seed"], d["duration_s"], d["n_rows"], d["n_gcps"], d["noise_px"], d["n_bands"])
    f_max = max([j["frequency_hz"] for j in d["jitter"] if max(j["amplitude_urad"]) > 0] + [0.0])
    gap = fam.max_gap_s(draw)
    ok = bool(r["observable"] and f_max > 0 and gap < 0.5 / f_max)
    gain_raw = r.get("gain_raw", r["gain"])
    if "gain_raw" not in r and r["gain"] is not None:  # a run before the floor condition
        floor_ok = FLOOR_FACTOR * r["floor_px"] <= GAIN_RATIO * r["static_px"]
        r = {**r, "gain": r["gain"] if floor_ok else None}
    return {**r, "gain_raw": gain_raw, "max_gap_s": gap, "observable_gap": ok,
            "accuracy_gap": r["accuracy"] if ok else None, "gain_gap": r["gain"] if ok else None}


def summarize(results) -> dict:
    """Pass rate and worst case per criterion.

    Returns
    -------
    dict
        ``draws``; per criterion ``applies``, ``passed``, ``rate`` and ``worst`` (the seed and
        its figures: for ``accuracy`` the largest ``auto / max(0.15, 1.5 floor)``, for ``gain``
        the largest ``auto / static``, for ``no_jitter`` the largest ``auto / static``).
    """
    out = {"draws": len(results), "success": sum(r["success"] for r in results)}
    results = [_with_gap_criteria(r) for r in results]

    def worst(rs, key):
        if not rs:
            return None
        r = max(rs, key=key)
        return {"seed": r["draw"]["seed"], "ratio": float(key(r)), "static_px": r["static_px"],
                "auto_px": r["auto_px"], "floor_px": r["floor_px"], "n_gcps": r["draw"]["n_gcps"],
                "duration_s": r["draw"]["duration_s"], "noise_px": r["draw"]["noise_px"],
                "n_bands": r["draw"]["n_bands"], "max_jitter_hz": max([j["frequency_hz"] for j in r["draw"]["jitter"]] + [0.0]),
                "selection": r["selection"]}

    keys = {"accuracy": lambda r: r["auto_px"] / max(ACCURACY_PX, FLOOR_FACTOR * r["floor_px"]),
            "gain": lambda r: r["auto_px"] / r["static_px"],
            "no_jitter": lambda r: r["auto_px"] / r["static_px"]}
    keys["accuracy_gap"], keys["gain_gap"], keys["gain_raw"] = keys["accuracy"], keys["gain"], keys["gain"]
    for name, key in keys.items():
        rs = [r for r in results if r[name] is not None]
        out[name] = {"applies": len(rs), "passed": sum(r[name] for r in rs),
                     "rate": (sum(r[name] for r in rs) / len(rs)) if rs else None, "worst": worst(rs, key)}
    unobs = [r for r in results if r["draw"]["jitter"] and not r["observable"] and any(
        max(j["amplitude_urad"]) > 0 for j in r["draw"]["jitter"])]
    out["unobservable"] = {"draws": len(unobs), "auto_over_static_max": max(
        [r["auto_px"] / r["static_px"] for r in unobs], default=None)}
    return out


def print_table(name, summary) -> None:
    """The summary as a text table."""
    print(f"{name}: {summary['draws']} draws ({summary['success']} calibrated)")
    print(f"  {'criterion':<12} {'applies':>7} {'passed':>6} {'rate':>6}  worst case")
    for key in ("accuracy", "gain", "no_jitter", "gain_raw", "accuracy_gap", "gain_gap"):
        c = summary[key]
        w = c["worst"]
        text = "-" if w is None else (
            f"seed {w['seed']}: auto {w['auto_px']:.3f} px, static {w['static_px']:.3f} px, floor "
            f"{w['floor_px']:.3f} px (ratio {w['ratio']:.2f}; {w['n_gcps']} GCPs, {w['duration_s']:.1f} s, "
            f"{w['noise_px']:.2f} px, {w['n_bands']} band(s), jitter to {w['max_jitter_hz']:.2f} Hz, "
            f"{w['selection'].get('kind')} edf {w['selection'].get('edf')})")
        rate = "-" if c["rate"] is None else f"{100 * c['rate']:.0f} %"
        print(f"  {key:<12} {c['applies']:>7} {c['passed']:>6} {rate:>6}  {text}")
    u = summary["unobservable"]
    if u["draws"]:
        print(f"  jitter above the GCPs' Nyquist rate (no criterion): {u['draws']} draws, auto/static at most "
              f"{u['auto_over_static_max']:.2f}")


def _run(seed_and_gcps):
    seed, n_gcps = seed_and_gcps
    return run_draw(fam.draw_scene(seed, n_gcps=n_gcps))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=120, help="draws of the whole family")
    parser.add_argument("--small", type=int, default=40, help="draws of the 100-300 GCP sub-family")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1, help="draws calibrated at once (processes)")
    parser.add_argument("--out", type=Path, help="JSON file to write (every draw and the summaries), "
                        "rewritten after each draw")
    parser.add_argument("--summarize", type=Path, help="only print the tables of a JSON file this script wrote")
    args = parser.parse_args(argv)
    if args.summarize:
        doc = json.loads(args.summarize.read_text(encoding="utf-8"))
        for name, part in doc.items():
            print_table(name, summarize(part["draws"]))
        return 0
    doc = {}
    families = (("small", [(args.first_seed + 100_000 + k, SMALL_GCPS) for k in range(args.small)]),
                ("family", [(args.first_seed + k, None) for k in range(args.draws)]))
    for name, family in families:
        if not family:
            continue
        results = []
        if args.jobs > 1:
            from concurrent.futures import ProcessPoolExecutor

            pool = ProcessPoolExecutor(args.jobs)
            outcomes = pool.map(_run, family)
        else:
            pool, outcomes = None, map(_run, family)
        for r in outcomes:
            results.append(r)
            d = r["draw"]
            print(f"  seed {d['seed']}: {d['n_gcps']} GCPs, {d['duration_s']:.1f} s, {d['n_bands']} band(s), jitter to "
                  f"{max([j['frequency_hz'] for j in d['jitter']] + [0.0]):.2f} Hz: static {r['static_px']:.3f}, "
                  f"auto {r['auto_px']:.3f}, floor {r['floor_px']:.3f} px ({r['selection'].get('kind')}, edf "
                  f"{r['selection'].get('edf')}; {r['seconds']:.1f} s)", flush=True)
            doc[name] = {"summary": summarize(results), "draws": results}
            if args.out:
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        if pool is not None:
            pool.shutdown()
        print_table(name, doc[name]["summary"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
