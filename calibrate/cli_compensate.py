"""``gcpcal compensate``: seed 002's virtual-control-point compensation schemes, simulated.

Registered by :mod:`calibrate.cli` (module attribute ``command``).

``gcpcal compensate --out DIR [--step 100] [--start 0] [--stop 10000] [--noise-px 0] [--seed 0]
[--scheme NAME ...] [--no-figures] [--json]``
    runs :func:`calibrate.schemes.compensate.run_seed002` (GF-4-like 10240 x 10240 camera, seed 002
    table 1 distortion, table 2 installation errors) and writes ``DIR/table.json``,
    ``DIR/table.csv``, ``DIR/summary.md`` and ``DIR/figures/*.png`` atomically
    (:func:`calibrate.schemes.compensate.write_study`). Prints the table (or, with ``--json``, the rows
    as one JSON line). Exit code 3 when a scheme fails.
"""

from __future__ import annotations

import json

import click

__all__ = ["command"]


@click.command("compensate")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--step", "step_px", type=click.FloatRange(min=1.0), default=100.0, show_default=True,
              help="Virtual control point grid step, pixels (seed 002: 100).")
@click.option("--start", "start_px", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="First grid pixel index.")
@click.option("--stop", "stop_px", type=click.FloatRange(min=0.0), default=10000.0, show_default=True,
              help="Last grid pixel index (seed 002: 10000).")
@click.option("--noise-px", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="Gaussian noise added to the virtual control points, pixels.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the noise.")
@click.option("--scheme", "schemes", multiple=True,
              type=click.Choice(["ICO", "ECO", "ECBIC", "ICBEC", "joint", "ICO-g"]),
              help="Schemes to run (repeatable; default all).")
@click.option("--no-figures", is_flag=True, help="Skip the PNG figures.")
@click.option("--json", "as_json", is_flag=True, help="Print the table rows as JSON.")
@click.pass_context
def command(ctx, out_dir, step_px, start_px, stop_px, noise_px, seed, schemes, no_figures, as_json):
    """Seed 002 simulation: ICO, ECO, ECBIC, ICBEC and joint compensation from virtual control points."""
    from calibrate.schemes.compensate import run_seed002, write_study

    study = run_seed002(step_px=step_px, start_px=start_px, stop_px=stop_px, noise_px=noise_px, seed=seed,
                        schemes=list(schemes) or None)
    doc = write_study(study, out_dir, figures=not no_figures)
    if as_json:
        keep = ("scheme", "success", "mean_x_px", "mean_y_px", "rms_x_px", "rms_y_px", "total_px", "max_px",
                "seed_total_px", "installation_arcsec")
        click.echo(json.dumps({"best_scheme": doc["best_scheme"],
                               "rows": [{k: r.get(k) for k in keep} for r in doc["rows"]]}))
    else:
        click.echo(f"{out_dir}: {study.settings['n_vcp']} virtual control points, "
                   f"{study.settings['n_check']} check points; best {study.best}")
        click.echo(f"{'scheme':8s} {'X mean':>10s} {'Y mean':>10s} {'total':>11s} {'seed total':>10s}")
        for r in study.rows:
            seed_total = "" if r["seed_total_px"] is None else f"{r['seed_total_px']:.3f}"
            click.echo(f"{r['scheme']:8s} {r['mean_x_px']:10.4f} {r['mean_y_px']:10.4f} {r['total_px']:11.3e} "
                       f"{seed_total:>10s}")
    if not all(r["success"] for r in study.rows):
        ctx.exit(3)
