"""The ``colour fit --report`` files: per-patch tables, the ``auto`` candidates, plots."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from camcal.base.atomic import atomic_path
from camcal.colour.difference import DELTA_E_METHODS, delta_E
from camcal.colour.fit.characterise import Characterisation
from camcal.colour.fit.evaluate import patch_table
from camcal.io.patches import write_patch_table
from camcal.report.colour_plots import plot_report

__all__ = ["write_report"]


def write_report(outcome: Characterisation, out_dir: str | os.PathLike, title: str = "") -> list[Path]:
    """Write tables and plots for a characterisation into ``out_dir``.

    Files: ``train_patches.csv`` (reference and fitted CIELAB, four Delta E),
    ``loo_patches.csv`` (the same with leave-one-out predictions),
    ``test_patches.csv`` (independent set), ``candidates.csv`` (``auto``),
    ``summary.txt``, and the plots of
    :func:`camcal.report.colour_plots.plot_report` under ``train/`` and
    ``test/``.
    """
    directory = Path(out_dir)
    directory.mkdir(parents=True, exist_ok=True)
    white = outcome.fit.target_white_XYZ
    model = outcome.result.model
    written: list[Path] = []
    train = outcome.train
    pred = model.apply(train.RGB)
    path = directory / "train_patches.csv"
    write_patch_table(path, patch_table(train.names, train.XYZ, pred, white))
    written.append(path)
    if outcome.result.XYZ_loo is not None:
        path = directory / "loo_patches.csv"
        write_patch_table(path, patch_table(train.names, train.XYZ, outcome.result.XYZ_loo, white))
        written.append(path)
    written += plot_report(directory / "train", train.names, train.XYZ, pred, white,
                           title=f"{title} training: {model.label}".strip())
    if outcome.test is not None:
        test = outcome.test
        test_pred = model.apply(test.RGB)
        path = directory / "test_patches.csv"
        write_patch_table(path, patch_table(test.names, test.XYZ, test_pred, white))
        written.append(path)
        written += plot_report(directory / "test", test.names, test.XYZ, test_pred, white,
                               title=f"{title} independent: {model.label}".strip(), columns=10)
    if outcome.selection is not None:
        path = directory / "candidates.csv"
        with atomic_path(path) as tmp, open(tmp, "w") as handle:
            handle.write("model,objective,regularisation,shrinkage,score,score_se,loo_mean,loo_p95,picked\n")
            for c in sorted(outcome.selection.candidates, key=lambda c: c.score):
                handle.write(f"{c.spec.label},{c.objective},{c.regularisation:g},{c.shrinkage:g},{c.score:.4f},"
                             f"{c.score_se:.4f},"
                             f"{c.loo_mean:.4f},"
                             f"{c.loo_p95:.4f},{'yes' if c is outcome.selection.picked else ''}\n")
        written.append(path)
    lines = [outcome.summary(), "", "mean Delta E by formula (colour-science):"]
    sets = [("training", train.RGB, train.XYZ)]
    if outcome.test is not None:
        sets.append(("independent", outcome.test.RGB, outcome.test.XYZ))
    for name, RGB, XYZ in sets:
        means = [f"{m} {np.mean(delta_E(model.apply(RGB), XYZ, white, m)):.3f}" for m in DELTA_E_METHODS]
        lines.append(f"  {name}: " + ", ".join(means))
    path = directory / "summary.txt"
    path.write_text("\n".join(lines) + "\n")
    written.append(path)
    return written
