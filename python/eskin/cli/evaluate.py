"""CLI command: evaluate (nested, group-disjoint evaluation of a training recipe)."""

from __future__ import annotations

from pathlib import Path

import typer

from eskin.cli.learn import (
    AMPLITUDE_HELP,
    NEGATIVES_HELP,
    Machine,
    Negatives,
    Selection,
    Subsample,
    Window,
    _amplitudes,
    _fail,
)


def _names(text: str | None) -> list[str] | None:
    return None if text is None else [c.strip() for c in text.split(",") if c.strip()]


def evaluate(
    campaign: Path = typer.Argument(..., help="campaign file (HDF5)"),
    out: Path = typer.Option(..., "--out", "-o", help="output folder"),
    groups: str = typer.Option(
        "participant",
        help="label whose groups make the folds: participant, run, direction or an "
        "integer extra field",
    ),
    folds: int | None = typer.Option(
        None, "--folds", help="K grouped folds (default: leave one group out)"
    ),
    baselines: str | None = typer.Option(
        None, help="baselines in the same folds: vector, minirocket (comma-separated)"
    ),
    classes: str | None = typer.Option(None, help="classes (default: every class)"),
    machine: Machine | None = typer.Option(None, help="tensor-SVM or tensor-RLS"),
    selection: Selection | None = typer.Option(None, help="Maximal Discrepancy or CV"),
    D: int | None = typer.Option(None, "--D", help="subsampled window length"),
    window: Window | None = typer.Option(None, help="touch-window detector, or none"),
    subsample: Subsample | None = typer.Option(None, help="subsampling method"),
    amplitude: str | None = typer.Option(None, help=AMPLITUDE_HELP),
    negatives: Negatives | None = typer.Option(None, help=NEGATIVES_HELP),
    quick: bool = typer.Option(False, "--quick", help="small grid (tests, demos)"),
    seed: int = typer.Option(0, help="seed of every random choice"),
    n_jobs: int = typer.Option(1, "--n-jobs", help="folds run at once (-1: all cores)"),
    scheduler: str | None = typer.Option(
        None, help="Dask scheduler address, or local:N for a local cluster of N workers"
    ),
    force: bool = typer.Option(False, "--force", help="replace the evaluation in OUT"),
) -> None:
    """How well will a recipe work on a new person? Train it (the options of train, with
    train's defaults) on all groups but the held-out ones, fold by fold, and score the
    held-out predictions: accuracy and balanced accuracy with 95 % intervals (bootstrap over
    groups), per-class recall, confusion matrix, settings per fold. Writes
    OUT/evaluation.json, .md, .png."""
    from eskin._files import refuse_overwrite_all
    from eskin.learn.evaluation import evaluate_recipe
    from eskin.learn.evaluation_report import fold_line, summary_lines, write_evaluation
    from eskin.learn.parallel import compute_backend

    given = {
        "machine": machine,
        "selection": selection,
        "D": D,
        "window": window,
        "subsample": subsample,
        "negatives": negatives,
    }
    # options not given keep eskin.train_model's defaults (the recipe eskin train uses)
    recipe = {k: getattr(v, "value", v) for k, v in given.items() if v is not None}
    recipe["quick"] = quick
    recipe.update(_amplitudes(amplitude))
    try:
        written = [out / f"evaluation.{ext}" for ext in ("json", "md", "png")]
        refuse_overwrite_all(written, force, inputs=(campaign,))
        with compute_backend(scheduler):
            result = evaluate_recipe(
                campaign,
                recipe=recipe,
                groups=groups,
                n_folds=folds,
                classes=_names(classes),
                baselines=_names(baselines) or (),
                seed=seed,
                n_jobs=-1 if scheduler else n_jobs,
                on_fold=lambda record, n: typer.echo(fold_line(record, n)),
            )
        paths = write_evaluation(result, out)
    except (ValueError, OSError, KeyError, ImportError) as exc:
        from eskin._files import error_line

        _fail(error_line(exc, out))
    for line in summary_lines(result):
        typer.echo(line)
    notes = sorted({n for f in result["folds"] for n in f.get("notes", [])})
    for note in notes:
        typer.echo(f"note: {note}")
    typer.echo(f"wrote {paths['json']}, {paths['md'].name} and {paths['figure'].name}")


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
    app.command("evaluate")(evaluate)
