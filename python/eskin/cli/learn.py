"""CLI commands: train, predict, experiment."""

from __future__ import annotations

import json
from enum import Enum
from pathlib import Path
from typing import Any, NoReturn, Optional

import typer


class Machine(str, Enum):
    svm = "svm"
    rls = "rls"


class Selection(str, Enum):
    md = "md"
    cv = "cv"


class Window(str, Enum):
    energy = "energy"
    none = "none"


class Decision(str, Enum):
    calibrated = "calibrated"
    paper = "paper"


class Engine(str, Enum):
    python = "python"
    cpp = "cpp"


class Subsample(str, Enum):
    algorithm2 = "algorithm2"
    even = "even"


class Negatives(str, Enum):
    all = "all"
    balanced = "balanced"


NEGATIVES_HELP = (
    "what each one-vs-all machine sees of the other classes: all their patterns, or as many "
    "random ones as its class has (the paper)"
)


SCHEDULER_HELP = "Dask scheduler address, or local:N for a pool of N worker processes here"

#: --decision-us's default, the host budget's (the support vectors' share of a decision at the
#: end of a touch): eskin.learn.host_budget.HOST_DECISION_US (not imported: light CLI), or
#: twice the input's bases where those take more (HOST_INPUT_FACTOR)
DECISION_US_DEFAULT = 80.0
DECISION_US_HELP = (
    "without --target/--budget: the searched model's support vectors take at most this many "
    "microseconds of a decision at the end of a touch on the host, estimated by a fixed count "
    f"(the search trades D, alpha and the support vectors; docs/learning.md); default: "
    f"{DECISION_US_DEFAULT:g}, or twice the input's own bases on a grid where those take more; "
    f"0: no bound")


def _decision_us(value: float | None) -> dict[str, Any]:
    """train_model's ``decision_us`` for --decision-us (0: None, no bound; not given: nothing,
    train_model's own default, "auto")."""
    if value is None:
        return {}
    return {"decision_us": float(value) if value > 0 else None}


def _training_set_notes(campaign: Path, D: Optional[int], selection: str) -> list[str]:
    """Refuse a D no recording can fill; notes on a D far above the paper's and on a campaign
    of one participant (which MD cannot warn about: it never splits by person)."""
    import numpy as np

    from eskin.data.campaign import load_campaign

    try:
        with load_campaign(campaign) as c:
            longest = int(np.max(c.lengths)) if len(c) else 0
            people = len(np.unique(c.participant))
    except (ValueError, OSError):
        return []  # train_model names the problem
    if len(c) and D is not None and D > longest:
        _fail(f"--D {D} is longer than every recording of {campaign} (at most {longest} samples): "
              f"every touch window would be stretched to D samples by interpolation, which adds "
              f"nothing but time and size (the model file grows with D); the paper uses D in "
              f"{{20, 50, 100}}")
    notes = []
    if D is not None and D > 1000:
        notes.append(f"--D {D} is far above the paper's 20-100: the search is slow and the model "
                     f"file large (both grow with D)")
    if people == 1 and selection == "md":
        notes.append("every recording comes from one participant: nothing in the selection says "
                     "how the model does on other people (record more participants)")
    return notes


def _prediction_table(model: Any, preds: list[dict[str, Any]]) -> list[str]:
    """`eskin predict`'s table, columns aligned: index, label, true label, decision value(s)."""
    heads = ["decision"] if model.is_binary else [f"f({c})" for c in model.classes]
    names = [str(p["label"]) for p in preds] + [str(p.get("true_label", "-")) for p in preds]
    w_label = max([len(n) for n in names] + [len("label")])
    w_value = max([len(h) for h in heads] + [len("+0.0000")])
    lines = ["index  " + "label".ljust(w_label) + "  " + "true".ljust(w_label) + "  "
             + "  ".join(h.rjust(w_value) for h in heads)]
    for p in preds:
        vals = "  ".join(f"{v:+.4f}".rjust(w_value) for v in p["decision_values"])
        flag = "  (don't know)" if p.get("dont_know") else ""
        lines.append(f"{p['index']:5d}  {str(p['label']).ljust(w_label)}  "
                     f"{str(p.get('true_label', '-')).ljust(w_label)}  {vals}{flag}")
    return lines


def _dont_know_lines(preds: list[dict[str, Any]], classes: list[str]) -> list[str]:
    """The flagged share and the error rates on the decided and the flagged recordings."""
    from eskin.learn.models import error_rate

    flagged = [p for p in preds if p.get("dont_know")]
    if not flagged:
        return ["don't know: none flagged"]
    decided = [p for p in preds if not p.get("dont_know")]
    e_dec, n_dec = error_rate(decided, classes)
    e_flag, n_flag = error_rate(flagged, classes)
    parts = [f"don't know: {len(flagged)} of {len(preds)} flagged "
             f"({100 * len(flagged) / len(preds):.1f} %)"]
    if n_dec:
        parts.append(f"error {100 * e_dec:.2f} % on the {n_dec} decided")
    if n_flag:
        parts.append(f"{100 * e_flag:.2f} % on the {n_flag} flagged")
    return ["; ".join(parts)]


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def _ints(text: str, what: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        _fail(f"{what} must be comma-separated integers, got {text!r}")
    if not values:
        _fail(f"{what} is empty")
    return values


AMPLITUDE_HELP = (
    "amplitude-aware kernel widths to search, e.g. off, 1 or off,1,4 (in spreads of the "
    "training touches' log energy; off: the paper's kernel)"
)


def _amplitudes(text: Optional[str]) -> dict[str, Any]:
    """``{"amplitudes": ...}`` for train_model from --amplitude, or {} (its default)."""
    from eskin.learn.grids import parse_amplitudes

    if text is None:
        return {}
    try:
        return {"amplitudes": parse_amplitudes(text)}
    except ValueError as exc:
        _fail(f"--amplitude {text}: {exc}")


def _train_and_save(
    campaign: Any, output: Path, recipe: dict[str, Any], scheduler: Optional[str], progress: bool,
    budget: Any = None,
) -> Any:
    """train_model(campaign, **recipe) on the scheduler's cluster (if any) with a progress
    display, saved to ``output``; a one-line error for bad input."""
    from eskin._progress import progress_bar
    from eskin.deploy import save_model
    from eskin.learn.training import train_model
    from eskin.learn.parallel import compute_backend

    try:
        with compute_backend(scheduler), progress_bar(progress) as bar:
            bar.add_task(f"training ({recipe['selection']} search)", total=None)
            model = train_model(campaign, **recipe)
            if budget is not None:
                model = _fitting_model(campaign, recipe, budget, model)
        model.training["recording_digests"] = sorted(_trained_digests(campaign, model.classes))
        save_model(model, output)
    except (ValueError, OSError, KeyError) as exc:
        from eskin._files import error_line

        _fail(error_line(exc, output))
    return model


def _recording_digests(camp: Any, indices: Any) -> list[str]:
    """A short content digest of each recording (its valid samples), so that `eskin predict`
    can tell the recordings a model was trained on, in any file that holds them."""
    import hashlib

    import numpy as np

    return [hashlib.sha1(np.ascontiguousarray(camp.recording(int(i)), dtype="<i2").tobytes())
            .hexdigest()[:16] for i in indices]


def _trained_digests(campaign: Any, classes: Any) -> list[str]:
    """The digests of the recordings `eskin train` learns from: every recording of the
    model's classes (``campaign``: a file, or the Campaign of some patches)."""
    import numpy as np

    from eskin.data.campaign import load_campaign

    def digests(c: Any) -> list[str]:
        ids = [k for k, name in enumerate(c.modalities) if name in set(classes)]
        return _recording_digests(c, np.flatnonzero(np.isin(c.modality, ids)))

    if not isinstance(campaign, (str, Path)):
        return digests(campaign)
    with load_campaign(campaign) as c:
        return digests(c)


def _patch_campaign(campaign: Path, patch: str) -> Any:
    """The recordings of the --patch ids (comma-separated) of a skin's campaign."""
    from eskin._files import error_line
    from eskin.data.campaign import load_campaign

    ids = [p.strip() for p in patch.split(",") if p.strip()]
    try:
        c = load_campaign(campaign)
        if c.patches is None:
            raise ValueError(f"{campaign}: --patch {patch}: the campaign has no patch field "
                             f"(one patch; docs/skin.md)")
        chosen = c.select(patch=ids)
    except (ValueError, OSError) as exc:
        _fail(error_line(exc))
    if not len(chosen):
        _fail(f"{campaign}: --patch {patch}: no recording of these patches")
    return chosen


MAX_WINDOW_HELP = "longest touch window in seconds (WindowConfig.max_window_s, default 7)"
MEMORY_LIMIT_HELP = (
    "GiB (default 0.5) the recipe search's pattern distances may take at once (bases, blocks of the pairwise "
    "kernel, distances); a D and alpha whose distances cannot fit are refused with a message")


MODEL_SIZE_HELP = (
    "MB the model's float32 .eskin file may take (default 0: no limit): a model with more "
    "support vectors keeps the most that fit, chosen by kernel matching pursuit as with "
    "--max-support")


def memory_options(gib: float) -> dict[str, int]:
    """The recipe-search options of --memory-limit GIB (none at the search's default)."""
    from eskin.learn.recipes import DEFAULT_MEMORY_LIMIT

    limit = int(float(gib) * 2**30)
    return {} if limit == DEFAULT_MEMORY_LIMIT else {"memory_limit": limit}


def model_size_option(mb: float) -> dict[str, int | None]:
    """train_model's option of --max-model-size MB (0: no limit)."""
    return {"max_model_bytes": int(float(mb) * 1e6) if mb > 0 else None}


WINDOW_SAMPLES_HELP = (
    "samples per taxel a stream keeps of a touch window (WindowConfig.window_samples, default "
    "1024; a longer window is kept at half the time resolution each time the buffer fills; 0: "
    "every sample, the detector's RAM growing with --max-window)"
)


HOLD_HELP = (
    "seconds of quiet that end a touch (WindowConfig.hold_s; default: chosen on the training "
    "recordings so that one gesture gives one live touch, from 0.15 s up)")
ON_FACTOR_HELP = "touch onset threshold, times the noise floor (WindowConfig.on_factor, default 4)"
OFF_FACTOR_HELP = (
    "touch continuation threshold, times the noise floor (WindowConfig.off_factor, default 2; "
    "at most --on-factor)")

#: detector options -> WindowConfig fields
DETECTOR_OPTIONS = {"--max-window": "max_window_s", "--window-samples": "window_samples",
                    "--hold": "hold_s", "--on-factor": "on_factor", "--off-factor": "off_factor"}


def _preprocessing(
    window: Window, subsample: Optional[Subsample], max_window: Optional[float] = None,
    window_samples: Optional[int] = None, *, hold: Optional[float] = None,
    on_factor: Optional[float] = None, off_factor: Optional[float] = None,
) -> dict:
    """train_model's preprocessing options: window, subsample (None: searched) and the
    detector's (:func:`_detector`)."""
    out: dict[str, Any] = {"window": window.value,
                           "subsample": None if subsample is None else subsample.value}
    return {**out, **_detector(max_window, window_samples, hold, on_factor, off_factor)}


def _detector(max_window: Optional[float], window_samples: Optional[int],
              hold: Optional[float], on_factor: Optional[float],
              off_factor: Optional[float]) -> dict:
    """train_model's options for the detector options given (--max-window, --window-samples,
    --hold, --on-factor, --off-factor): the window_config, and choose_hold False with --hold
    (the hold time is then the user's). A bad value fails with one line naming the option and
    the value."""
    given = dict(zip(DETECTOR_OPTIONS, (max_window, window_samples, hold, on_factor, off_factor)))
    fields = {DETECTOR_OPTIONS[o]: v for o, v in given.items() if v is not None}
    out: dict[str, Any] = {} if hold is None else {"choose_hold": False}
    if not fields:
        return out
    from eskin.signal.preprocess import WindowConfig

    try:
        cfg = WindowConfig(**fields)
        cfg.resolve()  # the detector's own checks, named by field and value
    except ValueError as exc:
        named = [o for o, f in DETECTOR_OPTIONS.items() if f in str(exc) and f in fields]
        option = named[0] if named else next(o for o in given if given[o] is not None)
        _fail(f"{option}: {exc}")
    return {**out, "window_config": cfg}


def _fitting_model(campaign: Path, recipe: dict[str, Any], budget: Any, model: Any) -> Any:
    """``model`` if its compiled form fits ``budget``; else retrained with the support-vector
    estimates of the search inflated (1.25x, then 1.6x), since the search's estimate of a
    candidate's support vectors comes from its splits, not from the final fit."""
    from eskin.deploy.export import model_to_bytes, spec_from_model
    from eskin.deploy.target import model_fits
    from eskin.learn.training import train_model
    from eskin.learn.recipes import CandidateBudget

    base = recipe["budget"]
    for margin in (1.25, 1.6):
        if model_fits(model_to_bytes(spec_from_model(model), "float32"), budget)[0]:
            return model
        inflated = CandidateBudget(
            lambda c, n, m=margin: base.fits(c, int(n * m) + 1),
            f"{base.description}, support vectors x{margin:g}")
        model = train_model(campaign, **{**recipe, "budget": inflated})
    return model


def _selected_lines(model: Any) -> list[str]:
    """The setting each machine of a trained model selected, a line each."""
    lines = []
    for sel in model.selected:
        name = f"{sel['class']} vs rest: " if "class" in sel else ""
        first = f"C={sel['C']:g}" if model.machine == "svm" else f"lambda={sel['lambda']:g}"
        amp = "" if sel.get("amplitude") is None else f", amplitude={sel['amplitude']:g}"
        lines.append(
            f"  {name}{first}, sigma={sel['sigma']:g}, alpha={sel['alpha'] or sel['alphas']}"
            f"{amp} ({sel['n_train']} patterns)"
        )
    return lines


def _problems(text: Optional[str]) -> Optional[list[str]]:
    """'A,B' -> presets; 'brush:washer;finger:washer' -> class pairs."""
    if text is None:
        return None
    items = [p.strip() for p in text.replace(";", " ").split() if p.strip()]
    out: list[str] = []
    for item in items:
        if ":" in item:
            out.append(",".join(c for c in item.split(":")))
        else:
            out.extend(x for x in item.split(",") if x)
    return out


def experiment(
    campaign: Path = typer.Argument(..., help="campaign file (HDF5)"),
    out: Path = typer.Option(..., "--out", "-o", help="output folder"),
    runs: Optional[int] = typer.Option(
        None, help="independent runs (default 5; 2 with --quick)"
    ),
    quick: bool = typer.Option(False, "--quick", help="reduced grid and runs (smoke test)"),
    window: Window = typer.Option(Window.energy, help="touch-window detector, or none"),
    subsample: Subsample = typer.Option(Subsample.algorithm2, help="subsampling method"),
    n_jobs: int = typer.Option(-1, "--n-jobs", help="worker processes (-1: all cores)"),
    Ds: Optional[str] = typer.Option(None, "--D", help="D values, e.g. 20,50,100"),
    problems: Optional[str] = typer.Option(
        None, help="binary problems: presets 'A,B,C' or class pairs 'brush:washer;a:b'"
    ),
    seed: int = typer.Option(0, help="seed of every random choice"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bar"),
    scheduler: Optional[str] = typer.Option(None, help=SCHEDULER_HELP),
    force: bool = typer.Option(False, "--force", help="replace the results in OUT"),
) -> None:
    """Run the paper's protocol (Tables 1-7, Figures 6-7) and write results.json, report.md
    and figures into OUT."""
    from eskin._files import refuse_overwrite_all
    from eskin.experiments.paper_protocol import run_experiment
    from eskin.experiments.report import too_small_note
    from eskin.learn.parallel import compute_backend

    try:
        written = [out / "results.json", out / "report.md"]
        refuse_overwrite_all(written, force, inputs=(campaign,))
        with compute_backend(scheduler):
            res = run_experiment(
                campaign,
                out,
                runs=runs,
                quick=quick,
                Ds=_ints(Ds, "--D") if Ds else None,
                seed=seed,
                n_jobs=-1 if scheduler else n_jobs,
                window=window.value,
                subsample=subsample.value,
                problems=_problems(problems),
                progress=progress,
            )
    except (ValueError, OSError, KeyError) as exc:
        _fail(str(exc))
    s = res["summary"]
    if res["campaign"].get("simulated"):
        typer.echo("note: the campaign is simulated")
    small = too_small_note(res["analysis_set"]["n_participants"])
    if small:
        typer.echo(f"note: too small to compare with the paper: {small}")
    rng = s.get("binary_md_range_pct")
    if rng:
        typer.echo(f"binary problems (MD): mean validation error {rng[0]:.1f}-{rng[1]:.1f} %")
    for m, v in (s.get("multiclass") or {}).items():
        typer.echo(f"three classes, {m}: best {v['best']:.1f} %, average {v['average']:.1f} %")
    for m, v in (s.get("md_vs_cv_overall") or {}).items():
        typer.echo(f"{m}: MD {v['md_mean']:.1f} % vs CV {v['cv_mean']:.1f} %")
    typer.echo(
        f"wrote {out / 'results.json'} and {out / 'report.md'} ({res['seconds_total']:.0f} s)"
    )


# long: one typer option per parameter; the body is a few named steps
def train(
    campaign: Path = typer.Argument(..., help="campaign file (HDF5)"),
    output: Path = typer.Option(..., "-o", "--output", help="model file to write"),
    classes: Optional[str] = typer.Option(
        None, help="classes to learn, e.g. brush,washer (default: every class)"),
    all_classes: bool = typer.Option(
        False, "--all-classes", help="learn every class (the default)"),
    machine: Optional[Machine] = typer.Option(
        None, help="tensor-SVM or tensor-RLS (default: searched)"),
    selection: Selection = typer.Option(
        Selection.cv,
        help="cv: cross-validation over participant-grouped splits; md: Maximal "
        "Discrepancy (the paper's Algorithm 1)",
    ),
    D: Optional[int] = typer.Option(
        None, "--D", help="subsampled window length (default: searched among 20, 50, 100, "
        "capped by the median touch window's samples)"
    ),
    window: Window = typer.Option(Window.energy, help="touch-window detector, or none"),
    subsample: Optional[Subsample] = typer.Option(
        None, help="subsampling method (default: searched)"),
    max_window: Optional[float] = typer.Option(None, "--max-window", help=MAX_WINDOW_HELP),
    window_samples: Optional[int] = typer.Option(None, help=WINDOW_SAMPLES_HELP),
    hold: Optional[float] = typer.Option(None, "--hold", help=HOLD_HELP),
    on_factor: Optional[float] = typer.Option(None, "--on-factor", help=ON_FACTOR_HELP),
    off_factor: Optional[float] = typer.Option(None, "--off-factor", help=OFF_FACTOR_HELP),
    amplitude: Optional[str] = typer.Option(None, help=AMPLITUDE_HELP),
    groups: str = typer.Option(
        "participant",
        help="label whose groups the cv splits keep apart: participant, run, direction or an "
        "integer extra field",
    ),
    negatives: Optional[Negatives] = typer.Option(
        None, help=NEGATIVES_HELP + " (default: searched)"),
    target: Optional[str] = typer.Option(
        None, help="controller the model must fit: cortex-m4 (1 MB flash, 128 KB RAM, "
        "1.5 M instructions per decision)"),
    budget: Optional[str] = typer.Option(
        None, help="the model's budget, e.g. flash=1M,ram=128K,instr=1.5M (overrides "
        "--target's figures)"),
    decision_us: Optional[float] = typer.Option(
        None, "--decision-us", min=0.0, help=DECISION_US_HELP, show_default=False),
    max_support: Optional[int] = typer.Option(
        None, "--max-support", min=1,
        help="at most this many support vectors in the model (all machines together), chosen "
        "by kernel matching pursuit; each machine refitted on them to its decision values on "
        "the training patterns"),
    decision: Decision = typer.Option(
        Decision.calibrated, help="calibrated: a sigmoid per machine fitted on out-of-fold "
        "decision values, the label of the largest calibrated score, \"don't know\" below a "
        "confidence threshold (docs/learning.md); paper: the paper's rule (one machine claims "
        "the touch, else \"don't know\")"),
    reject: float = typer.Option(
        0.1, "--reject", min=0.0, max=0.99,
        help="calibrated rule: the fraction of (out-of-fold) training touches flagged \"don't "
        "know\"; 0 never flags"),
    quick: bool = typer.Option(False, "--quick", help="small grid (tests, demos)"),
    memory_limit: float = typer.Option(
        0.5, "--memory-limit", min=0.01, help=MEMORY_LIMIT_HELP),
    max_model_size: float = typer.Option(
        0.0, "--max-model-size", min=0.0, help=MODEL_SIZE_HELP),
    seed: int = typer.Option(0, help="seed of every random choice"),
    n_jobs: int = typer.Option(1, "--n-jobs", help="worker processes for the search"),
    scheduler: Optional[str] = typer.Option(None, help=SCHEDULER_HELP),
    force: bool = typer.Option(False, "--force", help="replace OUTPUT if it exists"),
    progress: bool = typer.Option(
        True, "--progress/--no-progress", help="show that the search is running (terminal)"),
    patch: Optional[str] = typer.Option(
        None, "--patch", help="a skin's campaign (docs/skin.md): train on the recordings of "
        "these patches only (ids, comma-separated)"),
) -> None:
    """Choose the recipe on the campaign, fit on all its recordings and save a model.

    Default: the recipe is searched on the campaign by participant-grouped
    cross-validation (successive halving over tensor-SVM/RLS, D 20/50/100,
    Algorithm 2 or even subsampling, all or balanced negatives, times the
    paper's grid and the amplitude-aware factor off/1/4); every option given
    fixes its part. With --target or --budget only models that fit the
    controller are chosen. Prints the chosen recipe, its inner-CV estimate,
    the runners-up and the model's size and decision time; see
    docs/selection-study.md.
    """
    amplitudes = _amplitudes(amplitude)
    names = _train_classes(classes, all_classes, output, force, campaign)
    _notes(_training_set_notes(campaign, D, selection.value))
    given = {"machine": machine, "selection": selection, "D": D, "negatives": negatives}
    recipe = {
        "classes": names, **{k: getattr(v, "value", v) for k, v in given.items()},
        **_preprocessing(window, subsample, max_window, window_samples, hold=hold,
                         on_factor=on_factor, off_factor=off_factor),
        "quick": quick, "seed": seed, "n_jobs": -1 if scheduler else n_jobs, "group_by": groups,
        **amplitudes, **({} if max_support is None else {"max_support": max_support}),
        "decision": decision.value, "reject": reject, **_decision_us(decision_us),
        "recipe_options": memory_options(memory_limit), **model_size_option(max_model_size),
    }
    the_budget = None
    if target is not None or budget is not None:
        the_budget, notes = _budget_recipe(campaign, target, budget, recipe)
        _notes(notes)
    data = campaign if patch is None else _patch_campaign(campaign, patch)
    model = _train_and_save(data, output, recipe, scheduler, progress, the_budget)
    _notes(model.training.get("notes", []))
    for line in trained_lines(model) + _size_lines(model, the_budget) + [f"wrote {output}"]:
        typer.echo(line)


def _train_classes(classes, all_classes, output, force, campaign):
    """The --classes names (None: every class), once the options agree and OUTPUT may be
    written."""
    from eskin._files import refuse_overwrite

    if classes is not None and all_classes:
        _fail("give --classes a,b,... or --all-classes, not both")
    try:
        refuse_overwrite(output, force, inputs=(campaign,))
    except OSError as exc:
        _fail(str(exc))
    return None if classes is None else [c.strip() for c in classes.split(",") if c.strip()]


def _notes(notes) -> None:
    for note in notes:
        typer.echo(f"note: {note}")


def trained_lines(model: Any) -> list[str]:
    """What train prints about a trained model: classes and recipe, the settings chosen, the
    inner-CV estimate and (when the recipe was searched) the runners-up."""
    from eskin.learn.evaluation_report import selection_estimate_lines

    lines = [
        f"classes: {', '.join(model.classes)} ({model.machine}, {model.selection}, "
        f"D={model.D}, window={model.window})"
    ]
    search = model.training.get("recipe_search")
    if search:
        c = search["chosen"]
        lines.append(f"recipe chosen on this campaign ({', '.join(model.training['searched'])} "
                     f"searched): {_candidate_text(c)}")
        lines.append(f"  inner-CV error {100 * c['cv_error']:.1f} % (+- "
                     f"{100 * c['cv_std']:.1f} over {c['splits']} grouped splits), about "
                     f"{c['support_vectors']} support vectors")
        lines.append(f"  by {search['method']}; {search['evaluations']} candidate-split scores")
        pref = search.get("preference")
        if pref and pref["recipe"] != pref["lowest"] and pref["gap"] > 0:
            why = ("less than one held-out pattern" if pref.get("within_one_pattern") else
                   f"not significantly (p = {pref['p']:.2f}, corrected paired t-test on the "
                   "splits)")
            lines.append(f"  kept the preferred recipe: {pref['lowest']} scored "
                         f"{100 * pref['gap']:.1f} points lower on the inner splits, {why}")
        lines += _selected_lines(model)
        if search["runners_up"]:
            lines.append("  runners-up (best setting of each other recipe):")
            for r in search["runners_up"]:
                lines.append(f"    {_candidate_text(r)}: {100 * r['cv_error']:.1f} % "
                             f"({r['splits']} splits, ~{r['support_vectors']} support vectors)")
        lines.append("  (optimistic: the best of many candidates on these very splits; eskin "
                     "evaluate gives a nested estimate on unseen groups)")
        return lines + _support_budget_lines(model) + _decision_lines(model)
    return (lines + _selected_lines(model) + selection_estimate_lines(model)
            + _support_budget_lines(model) + _decision_lines(model))


def _decision_lines(model: Any) -> list[str]:
    """What train prints about the decision rule."""
    d = model.training.get("decision")
    if not d:
        return []
    if d.get("rule") == "paper":
        return ["decision: the paper's rule (a touch is \"don't know\" unless exactly one "
                "machine claims it)"]
    decided = d.get("oof_error_decided")
    return [f"decision: calibrated, \"don't know\" below confidence {d['threshold']:.4f} "
            f"(--reject {d['reject']:g}); out of fold ({d['folds']} folds): "
            f"{100 * d['oof_flagged']:.1f} % flagged, error {100 * d['oof_error']:.1f} % "
            f"overall" + ("" if decided is None else
                          f", {100 * decided:.1f} % on the decided touches")]


def _support_budget_lines(model: Any) -> list[str]:
    b = model.training.get("support_budget")
    if not b:
        return []
    by = {"budget": f"to {b['max_support']} to fit the budget",
          "size": f"to {b['max_support']} to fit --max-model-size "
                  f"{b.get('max_model_bytes', 0) / 1e6:g} MB"}.get(
        b.get("by"), f"by --max-support {b['max_support']}")
    return [f"support vectors bounded {by}: "
            f"{b['support_vectors_before']} -> {b['support_vectors']} (each machine refitted on "
            f"the kept patterns)"]


def _candidate_text(c: dict[str, Any]) -> str:
    amp = "off" if c.get("amplitude") is None else f"{c['amplitude']:g}"
    return (f"{c['machine']} D={c['D']} {c['subsample']} negatives={c['negatives']}, "
            f"lambda={c['lambda']:g}, sigma={c['sigma']:g}, alpha={c['alpha']}, amplitude={amp}")


def _budget_recipe(
    campaign: Path, target: Optional[str], budget_text: Optional[str], recipe: dict[str, Any]
) -> tuple[Any, list[str]]:
    """The budget of --target/--budget, with the detector settings and the candidate filter it
    implies added to ``recipe``; (budget, notes)."""
    import numpy as np

    from eskin.data.campaign import load_campaign
    from eskin.deploy.target import parse_budget, training_budget

    try:
        b = parse_budget(budget_text, target)
        with load_campaign(campaign) as c:
            rate = float(c.sample_rate_hz)
            grid = tuple(int(v) for v in np.shape(c.recording(0))[:2])
            n_classes = len(recipe["classes"] or set(np.asarray(c.modality).tolist()))
        window_config, search_budget, note = training_budget(
            b, grid, rate, recipe.get("window_config"), n_classes, recipe.get("max_support"))
    except (ValueError, OSError, KeyError) as exc:
        _fail(str(exc))
    if recipe.get("selection", "cv") != "cv" or None not in (
            recipe.get("machine"), recipe.get("D"), recipe.get("subsample"),
            recipe.get("negatives")):
        _fail("--target/--budget choose among recipes: use --selection cv and leave at least "
              "one of --machine, --D, --subsample, --negatives to the search")
    recipe["window_config"], recipe["budget"] = window_config, search_budget
    return b, [note] if note else []


def _size_lines(model: Any, budget: Any) -> list[str]:
    """The model's size and decision cost: on the budget's controller (estimated flash, RAM,
    instructions) or, without a budget, the .eskin file and the decision time on this host."""
    import time

    import numpy as np

    from eskin.deploy.export import CompiledModel, model_to_bytes, spec_from_model
    from eskin.deploy.target import INSTRUCTION_MARGIN, model_fits

    try:
        data = model_to_bytes(spec_from_model(model), "float32")
    except (ValueError, TypeError) as exc:
        return [f"model size: unknown ({exc})"]
    cm = CompiledModel(data)
    if budget is not None:
        fits, fig = model_fits(data, budget)
        return [f"on {budget.target.name}: flash {fig['flash']} of {budget.flash_bytes} B, RAM "
                f"{fig['ram']} of {budget.ram_bytes} B, at most {fig['instructions'] / 1e6:.2f} M "
                f"of {budget.instructions / 1e6:g} M instructions per decision (cost model: "
                f"{fig['estimate'] / 1e6:.2f} M + {100 * INSTRUCTION_MARGIN:.0f} % margin)"
                + ("" if fits else ": DOES NOT FIT")]
    rng = np.random.default_rng(0)
    X = rng.standard_normal((16, *model.pattern_shape))
    cm.classify_tensors(X[:2])  # warm
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        cm.classify_tensors(X)
        best = min(best, (time.perf_counter() - t0) / len(X))
    return [f"model: {len(data)} bytes as .eskin float32, {cm.n_support} support vectors; one "
            f"decision {1e3 * best:.3f} ms on this host (compiled classifier, best of 3)"]


def predict(
    model_path: Path = typer.Argument(..., metavar="MODEL", help="model file"),
    campaign: Path = typer.Argument(..., help="campaign file (HDF5)"),
    json_out: Optional[Path] = typer.Option(None, "--json", help="write predictions as JSON"),
    engine: Engine = typer.Option(
        Engine.python, help="python: the Python model; cpp: the compiled C++ classifier"
    ),
    force: bool = typer.Option(False, "--force", help="replace the --json file if it exists"),
) -> None:
    """Classify every recording of a campaign; print labels, decision values, error rate."""
    from eskin._files import refuse_overwrite
    from eskin.data.campaign import load_campaign
    from eskin.deploy import load_model
    from eskin.learn.models import error_rate

    try:
        if json_out is not None:
            refuse_overwrite(json_out, force, inputs=(model_path, campaign))
        model = load_model(model_path)
        camp = load_campaign(campaign)
        if engine is Engine.cpp:
            from eskin.deploy.export import compiled_engine

            preds = compiled_engine(model).predict_recordings(camp)
        else:
            preds = model.predict_recordings(camp)
    except (ValueError, OSError, KeyError) as exc:
        _fail(str(exc))
    if abs(float(camp.sample_rate_hz) - model.sample_rate_hz) > 1e-9:
        typer.echo(
            f"note: model trained at {model.sample_rate_hz:g} Hz, campaign recorded "
            f"at {float(camp.sample_rate_hz):g} Hz",
            err=True,
        )
    for line in _prediction_table(model, preds):
        typer.echo(line)
    err, n = error_rate(preds, model.classes)
    if n:
        typer.echo(f"error rate: {100 * err:.2f} % ({n} recordings of the model's classes)")
        for line in _dont_know_lines(preds, model.classes):
            typer.echo(line)
    else:
        typer.echo("error rate: unknown (no labelled recording of the model's classes)")
    trained = set(getattr(model, "training", {}).get("recording_digests", ()))
    if trained:
        seen = sum(d in trained for d in _recording_digests(camp, range(len(camp))))
        if seen:
            typer.echo(
                f"note: {seen} of these {len(camp)} recordings trained this model: their "
                f"error rate says how well the model fits them, not how it does on new "
                f"recordings (`eskin evaluate` measures that on held-out people)")
    if json_out is not None:
        try:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(preds, indent=1))
        except OSError as exc:
            _fail(f"cannot write {json_out}: {exc}")
        typer.echo(f"wrote {json_out}")


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
    app.command("experiment")(experiment)
    app.command("train")(train)
    app.command("predict")(predict)
