"""``camcal demo``: the whole pipeline on a stereo rig rendered with Blender, recovered vs true values."""

from __future__ import annotations

import argparse
import sys

from camcal.cli.options import handler
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal demo``."""
    from camcal.demo import STAGES

    parser.add_argument("--out", default="demo_out", metavar="DIR", help="output folder (default: demo_out)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--stages", metavar="A,B,...",
                        help="run only these stages (of: " + ", ".join(s.name for s in STAGES) + ")")
    handler(parser, _demo, [
        "camcal demo",
        "camcal demo --seed 1 --out demo_seed1",
    ])


def _demo(args: argparse.Namespace) -> int:
    """Render a known stereo rig with Blender (Cycles, CPU), run camcal's verbs on the images, print recovered vs
    true values with their tolerances and write DIR/report.html. Exits 1 when a value is outside its
    tolerance.
    """
    import dataclasses

    from camcal.demo import FULL, run_demo

    config = dataclasses.replace(FULL, seed=args.seed)
    if args.stages:
        config = dataclasses.replace(config, stages=tuple(s.strip() for s in args.stages.split(",")))
    report = run_demo(args.out, config)
    print(report.table())
    out = summary_of(args)
    for label, path in report.outputs:
        print(f"wrote {path} ({label})")
        out.wrote(path, label, say=False)
    print(f"report: {report.report}")
    out.wrote(report.report, "report", say=False)
    out.figures(rows=[{"stage": row.stage, "quantity": row.quantity, "true": row.true, "recovered": row.recovered,
                       "error": row.error, "tolerance": row.tolerance, "unit": row.unit, "ok": row.ok,
                       "source": row.source} for row in report.rows],
                seconds=dict(report.seconds), n_failed=len(report.failed))
    print("time per stage: " + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in report.seconds))
    if report.failed:
        print(f"outside tolerance: {', '.join(row.quantity for row in report.failed)}", file=sys.stderr)
        return 1
    print(f"all {len(report.rows)} recovered values within tolerance")
    return 0
