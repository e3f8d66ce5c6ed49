"""CLI command: evaluate (nested, group-disjoint evaluation of a training recipe)."""

from __future__ import annotations

from pathlib import Path

import typer

from eskin.cli.learn import (
    Decision,
    AMPLITUDE_HELP,
    HOLD_HELP,
    MAX_WINDOW_HELP,
    MEMORY_LIMIT_HELP,
    MODEL_SIZE_HELP,
    NEGATIVES_HELP,
    OFF_FACTOR_HELP,
    ON_FACTOR_HELP,
    WINDOW_SAMPLES_HELP,
    Machine,
    Negatives,
    Selection,
    Subsample,
    Window,
    DECISION_US_HELP,
    _amplitudes,
    _decision_us,
    _detector,
    _fail,
    _patch_campaign,
    memory_options,
    model_size_option,
)


def _names(text: str | None) -> list[str] | None:
    return None if text is None else [c.strip() for c in text.split(",") if c.strip()]


# long: one typer option per parameter; the body is a few named steps
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
    max_window: float | None = typer.Option(None, "--max-window", help=MAX_WINDOW_HELP),
    window_samples: int | None = typer.Option(None, help=WINDOW_SAMPLES_HELP),
    hold: float | None = typer.Option(None, "--hold", help=HOLD_HELP),
    on_factor: float | None = typer.Option(None, "--on-factor", help=ON_FACTOR_HELP),
    off_factor: float | None = typer.Option(None, "--off-factor", help=OFF_FACTOR_HELP),
    amplitude: str | None = typer.Option(None, help=AMPLITUDE_HELP),
    negatives: Negatives | None = typer.Option(None, help=NEGATIVES_HELP),
    target: str | None = typer.Option(
        None, help="also evaluate the recipe chosen under this controller's budget "
        "(cortex-m4), in the same folds"),
    budget: str | None = typer.Option(
        None, help="the budget, e.g. flash=1M,ram=128K,instr=1.5M (overrides --target's)"),
    max_support: int | None = typer.Option(
        None, "--max-support", min=1, help="at most this many support vectors in each fold's "
        "model (as eskin train --max-support)"),
    decision_us: float | None = typer.Option(
        None, "--decision-us", min=0.0, help=DECISION_US_HELP, show_default=False),
    live: bool = typer.Option(
        True, "--live/--no-live", help="also play each fold's held-out recordings as one "
        "stream through its compiled stream classifier and score the live decisions"),
    decision: Decision | None = typer.Option(
        None, help="calibrated (default) or paper: the decision rule (as eskin train "
        "--decision)"),
    reject: float | None = typer.Option(
        None, "--reject", min=0.0, max=0.99, help="the calibrated rule's share of touches "
        "flagged \"don't know\" (as eskin train --reject; default 0.1)"),
    quick: bool = typer.Option(False, "--quick", help="small grid (tests, demos)"),
    memory_limit: float = typer.Option(
        0.5, "--memory-limit", min=0.01, help=MEMORY_LIMIT_HELP),
    max_model_size: float = typer.Option(
        0.0, "--max-model-size", min=0.0, help=MODEL_SIZE_HELP),
    seed: int = typer.Option(0, help="seed of every random choice"),
    n_jobs: int = typer.Option(
        1, "--n-jobs", help="folds run at once, each in a single-threaded worker process of "
        "this machine (as --scheduler local:N; -1: one per core)"),
    scheduler: str | None = typer.Option(
        None, help="Dask scheduler address, or local:N for a pool of N worker processes here"
    ),
    force: bool = typer.Option(False, "--force", help="replace the evaluation in OUT"),
    patch: str | None = typer.Option(
        None, "--patch", help="a skin's campaign (docs/skin.md): evaluate on the recordings "
        "of these patches only (ids, comma-separated)"),
) -> None:
    """How well will a recipe work on a new person? Train it (the options of train, with
    train's defaults) on all groups but the held-out ones, fold by fold, and score the
    held-out predictions: accuracy and balanced accuracy with 95 % intervals (bootstrap over
    groups), per-class recall, confusion matrix, settings per fold. Writes
    OUT/evaluation.json, .md, .png. The live figure (--live, the default) plays each fold's
    held-out recordings as one stream (as eskin replay --gap 2 writes it) through the fold's
    compiled stream classifier, as a controller would run it, and scores every touch it
    decides: accuracy, touches per recording, splits, misses, spurious touches. With
    --target/--budget, the search under the budget runs in the same folds and its accuracy is
    reported beside the unconstrained one."""
    from eskin._files import error_line, refuse_overwrite_all
    from eskin.learn.parallel import compute_backend

    given = {
        "machine": machine,
        "selection": selection,
        "D": D,
        "window": window,
        "subsample": subsample,
        "negatives": negatives,
    }
    recipe = _recipe_of(given, quick, amplitude, max_support)
    recipe.update(_detector(max_window, window_samples, hold, on_factor, off_factor))
    recipe.update(_decision_us(decision_us))
    if memory_options(memory_limit):
        recipe["recipe_options"] = memory_options(memory_limit)
    recipe.update(model_size_option(max_model_size))
    if reject is not None:
        recipe["reject"] = reject
    if decision is not None:
        recipe["decision"] = decision.value
    budgeted, the_budget = _budgeted(campaign, target, budget, recipe, classes)
    try:
        written = [out / f"evaluation.{ext}" for ext in ("json", "md", "png")]
        refuse_overwrite_all(written, force, inputs=(campaign,))
        where = _scheduler_of(scheduler, n_jobs)
        with compute_backend(where):
            # on a cluster, evaluate_recipe reads the recordings here and scatters them
            data = campaign if patch is None else _patch_campaign(campaign, patch)
            result = _in_folds(data, recipe, budgeted, the_budget, groups=groups,
                               n_folds=folds, classes=_names(classes),
                               baselines=_names(baselines) or (), seed=seed,
                               n_jobs=1 if where is None else -1,
                               live=live)
    except (ValueError, OSError, KeyError, ImportError) as exc:
        _fail(error_line(exc, out))
    _report(result, out)


def _scheduler_of(scheduler: str | None, n_jobs: int) -> str | None:
    """Where the folds run: --scheduler when given, else a local pool of --n-jobs workers
    (``local:N``: single-threaded processes, stopped and reaped when the evaluation ends, so
    their CPU time is the command's), or here, one fold after the other (None)."""
    if scheduler is not None or n_jobs == 1:
        return scheduler
    import os

    workers = n_jobs if n_jobs > 1 else os.cpu_count() or 1
    return f"local:{workers}"


def _recipe_of(given: dict, quick: bool, amplitude: str | None,
               max_support: int | None) -> dict:
    """The recipe of the options given; those not given keep eskin.train_model's defaults
    (the recipe eskin train uses)."""
    recipe = {k: getattr(v, "value", v) for k, v in given.items() if v is not None}
    recipe["quick"] = quick
    recipe.update(_amplitudes(amplitude))
    if max_support is not None:
        recipe["max_support"] = max_support
    return recipe


def _in_folds(data, recipe, budgeted, the_budget, *, groups, n_folds, classes, baselines,
              seed, n_jobs, live=True) -> dict:
    """evaluate_recipe of the recipe (with the live figure unless ``live`` is False), and of
    the recipe under the budget (when given) in the same folds: same campaign, groups, folds
    and seed."""
    from eskin.learn.evaluation import evaluate_recipe
    from eskin.learn.evaluation_report import fold_line
    from eskin.link.live_scores import LiveScoring

    result = evaluate_recipe(
        data, recipe=recipe, groups=groups, n_folds=n_folds, classes=classes,
        baselines=baselines, seed=seed, n_jobs=n_jobs,
        on_fold=lambda record, n: typer.echo(fold_line(record, n)),
        live=LiveScoring() if live else None,
    )
    if budgeted is not None:
        under = evaluate_recipe(data, recipe=budgeted, groups=groups, n_folds=n_folds,
                                classes=classes, seed=seed, n_jobs=n_jobs)
        result["under_budget"] = _under_budget(under, the_budget)
    return result


def _report(result: dict, out: Path) -> None:
    """Print the scores, then write OUT/evaluation.* (a full disk then costs the files, not
    the scores)."""
    from eskin._files import error_line
    from eskin.learn.evaluation_report import hold_choice_lines, summary_lines, write_evaluation

    for line in summary_lines(result):
        typer.echo(line)
    for line in _under_budget_lines(result):
        typer.echo(line)
    # the hold time each fold chose, summed up (one note per fold would repeat it)
    notes = sorted({n for f in result["folds"] for n in f.get("notes", [])
                    if not n.startswith("hold_s = ")})
    for note in hold_choice_lines(result) + notes:
        typer.echo(f"note: {note}")
    try:
        paths = write_evaluation(result, out)
    except (ValueError, OSError) as exc:
        _fail(error_line(exc, out))
    typer.echo(f"wrote {paths['json']}, {paths['md'].name} and {paths['figure'].name}")


def _budgeted(campaign, target, budget_text, recipe, classes):
    """(the recipe under --target/--budget, the budget), or (None, None) without them."""
    if target is None and budget_text is None:
        return None, None
    from eskin.cli.learn import _budget_recipe

    budgeted = {**recipe, "classes": _names(classes)}
    the_budget, notes = _budget_recipe(campaign, target, budget_text, budgeted)
    for note in notes:
        typer.echo(f"note: {note}")
    return {k: v for k, v in budgeted.items() if k != "classes"}, the_budget


def _under_budget_lines(result: dict) -> list[str]:
    if "under_budget" not in result:
        return []
    u = result["under_budget"]
    return [
        f"under the budget ({u['budget']}): accuracy {100 * u['accuracy']:.1f} % (95 % CI "
        f"{100 * u['ci95'][0]:.1f}-{100 * u['ci95'][1]:.1f}), unconstrained "
        f"{100 * result['accuracy']:.1f} %, in the same folds"
    ]


def _under_budget(under: dict, budget) -> dict:
    """The budgeted evaluation's figures kept beside the unconstrained one's."""
    return {
        "budget": budget.describe(),
        "accuracy": under["accuracy"],
        "balanced_accuracy": under["balanced_accuracy"],
        "ci95": under["ci95"],
        "per_fold": [{"fold": f["fold"], "accuracy": f["accuracy"],
                      "trained_with": f["trained_with"]} for f in under["folds"]],
        "recipe": under["recipe"],
    }


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
    app.command("evaluate")(evaluate)
