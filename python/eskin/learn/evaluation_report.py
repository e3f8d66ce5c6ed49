"""Writing an evaluation (:func:`eskin.learn.evaluation.evaluate_recipe`): evaluation.json,
evaluation.md, evaluation.png, and the lines the command line prints."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np


def _pct(v: float | None) -> str:
    return "n/a" if v is None or np.isnan(v) else f"{100 * v:.1f} %"


def _ci(ci: Any) -> str:
    return f"[{100 * ci[0]:.1f}, {100 * ci[1]:.1f}] %"


def _setting(selected: Any) -> str:
    """One machine's selected setting, short: 'C=10 sigma=2 alpha=Q' (and 'amplitude=1'
    when it has the amplitude factor)."""
    if not isinstance(selected, Mapping):
        return str(selected)
    if "lambda" not in selected:
        return " ".join(
            f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in selected.items()
        )
    head = f"C={selected['C']:g}" if "C" in selected else f"lambda={selected['lambda']:g}"
    alpha = selected.get("alpha") or selected.get("alphas")
    text = f"{head} sigma={selected['sigma']:g} alpha={alpha}"
    if selected.get("amplitude") is not None:
        text += f" amplitude={selected['amplitude']:g}"
    return f"{selected['class']}: {text}" if "class" in selected else text


def fold_settings(record: Mapping[str, Any]) -> str:
    """The settings a fold selected (every machine), on one line."""
    return "; ".join(_setting(s) for s in record.get("selected", []))


def describe_trained_with(settings: Mapping[str, Any]) -> str:
    """The recipe the folds ran, in words: 'tensor-SVM, cv selection, D = 100, ...'."""
    if not settings:
        return "-"
    return (
        f"tensor-{str(settings.get('machine')).upper()}, "
        f"{settings.get('selection')} selection, D = {settings.get('D')}, "
        f"window {settings.get('window')}, {settings.get('subsample')} subsampling, "
        f"amplitude factor {_amplitude_text(settings.get('amplitudes', [None]))}, "
        + (f"{_hold_text(settings['hold_s'])}, " if settings.get("hold_s") is not None else "")
        + f"negatives {settings.get('negatives')} (eskin {settings.get('eskin_version')})"
    )


def given_options(recipe: Mapping[str, Any]) -> str:
    """The recipe options an evaluation was given, as the command line spells them
    ('--quick, --D 50'), or 'none (eskin train's defaults)'."""
    words = []
    for key, value in sorted(recipe.items()):
        if value is None or value is False:
            continue
        flag = "--" + ("amplitude" if key == "amplitudes" else key.replace("_", "-"))
        if value is True:
            words.append(flag)
        else:
            text = ",".join("off" if v is None else f"{v:g}" if isinstance(v, float) else str(v)
                            for v in value) if isinstance(value, (list, tuple)) else str(value)
            words.append(f"{flag} {text}")
    return ", ".join(f"`{w}`" for w in words) or "none (eskin train's defaults)"


def _amplitude_text(amplitudes: Any) -> str:
    """'off, 1, 4' for the amplitude widths of a recipe (as given when they are not a list of
    widths, e.g. different per fold)."""
    if isinstance(amplitudes, list) and all(
        a is None or isinstance(a, (int, float)) for a in amplitudes
    ):
        return ", ".join("off" if a is None else f"{a:g}" for a in amplitudes)
    return str(amplitudes)


def summary_lines(result: Mapping[str, Any]) -> list[str]:
    """What ``eskin evaluate`` prints: overall scores with their interval, per-class recall,
    the confusion matrix, the per-fold accuracy and settings, and the baselines."""
    classes = list(result["classes"])
    lines = [
        (
            f"{result['scheme']} by {result['groups']} ({result['n_groups']} groups, "
            f"{len(result['folds'])} folds, {result['n_recordings']} recordings)"
        ),
        f"trained with: {describe_trained_with(result.get('trained_with', {}))}",
        f"accuracy          {_pct(result['accuracy'])}  95 % CI {_ci(result['ci95'])}",
        (
            f"balanced accuracy {_pct(result['balanced_accuracy'])}  95 % CI "
            f"{_ci(result['ci95_balanced_accuracy'])}"
        ),
        "  (interval: bootstrap over groups"
        + (f"; rough with only {result['n_groups']} groups)" if result["n_groups"] < 10 else ")"),
        "per-class recall: "
        + ", ".join(f"{c} {_pct(r)}" for c, r in result["per_class_recall"].items()),
        *_dont_know_lines(result.get("dont_know")),
        *risk_coverage_lines(result.get("risk_coverage")),
        "confusion (rows true, columns predicted):",
    ]
    width = max(len(c) for c in classes) + 1
    lines.append(" " * width + " ".join(f"{c[:8]:>8}" for c in classes))
    for c, row in zip(classes, result["confusion"]):
        lines.append(f"{c:<{width}}" + " ".join(f"{v:>8d}" for v in row))
    lines.append("folds:")
    for r in result["folds"]:
        base = "".join(f", {b} {_pct(v['accuracy'])}" for b, v in r.get("baselines", {}).items())
        lines.append(
            f"  {r['fold'] + 1:3d} test {result['groups']} {_groups(r['test_groups'])}: "
            f"{_pct(r['accuracy'])} of {r['n_test']}{base} | {fold_settings(r)}"
        )
    lines += live_lines(result)
    for name, b in result.get("baselines", {}).items():
        lines.append(
            f"baseline {name}: accuracy {_pct(b['accuracy'])} {_ci(b['ci95'])}, balanced "
            f"{_pct(b['balanced_accuracy'])} {_ci(b['ci95_balanced_accuracy'])}"
        )
    return lines


def risk_coverage_lines(rc: Mapping[str, Any] | None) -> list[str]:
    """The risk-coverage curve at 100, 90, 80 and 50 % coverage, one line (none without it)."""
    if not rc:
        return []
    cov, err = np.asarray(rc["coverage"]), np.asarray(rc["error"])
    picked = sorted({int(np.argmin(np.abs(cov - c))) for c in (1.0, 0.9, 0.8, 0.5)},
                    reverse=True)
    return ["risk-coverage     error " + ", ".join(
        f"{_pct(err[i])} at {100 * cov[i]:.0f} %" for i in picked)
        + " coverage (the most confident decided, the rest flagged)"]


def _dont_know_lines(dk: Mapping[str, Any] | None) -> list[str]:
    """The share of "don't know" decisions and the accuracy on each side, when recorded."""
    if not dk:
        return []
    return [f"don't know        {_pct(dk['flagged'])} flagged ({dk['n_flagged']}); accuracy "
            f"{_pct(dk['accuracy_decided'])} on the decided, {_pct(dk['accuracy_flagged'])} on "
            "the flagged"]


def fold_line(record: Mapping[str, Any], n_folds: int) -> str:
    """A fold that has just finished, on one line (printed while the evaluation runs)."""
    live = record.get("live")
    live_text = "" if not live else (
        f", live {_pct(live['correct'] / live['recordings'] if live['recordings'] else None)}"
        f" ({live['touches']} touches)")
    return (
        f"fold {record['fold'] + 1}/{n_folds} (test {_groups(record['test_groups'])}): "
        f"{_pct(record['accuracy'])} of {record['n_test']}{live_text} "
        f"({record['seconds']:.0f} s)"
    )


def _hold_text(hold: Any) -> str:
    if isinstance(hold, list):
        return "hold_s " + ", ".join(f"{h:g}" for h in hold) + " s (by fold)"
    return f"hold_s {hold:g} s"


def live_lines(result: Mapping[str, Any]) -> list[str]:
    """What ``eskin evaluate`` prints of the live figure (none without one)."""
    live = result.get("live")
    if not live:
        return []
    n = live["recordings"]
    return [
        (f"live: each fold's held-out recordings as one stream ({live['gap_s']:g} s of quiet "
         f"between them) through its compiled stream classifier, {_hold_text(live['hold_s'])}"),
        (f"  accuracy live {_pct(live['accuracy'])}, per recording {_pct(result['accuracy'])}"
         f" (one decision kept per recording; none counts as wrong)"),
        (f"  touches per recording {live['touches_per_recording']:.2f} ({live['touches']} on "
         f"{n} recordings): {live['split']} split (2+ touches), {live['missed']} missed "
         f"(none), {live['spurious']} spurious in the gaps; {live['dont_know']} \"don't "
         f"know\""),
        (f"  error live {_pct(_minus(live['accuracy']))} overall, "
         f"{_pct(live.get('error_decided'))} on the decided recordings, "
         f"{_pct(live.get('error_flagged'))} on those flagged \"don't know\""),
    ]


def _minus(accuracy: Any) -> Any:
    return None if accuracy is None else 1 - accuracy


def _span(values: list[int]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo}" if lo == hi else f"{lo} to {hi}"


def hold_choice_lines(result: Mapping[str, Any]) -> list[str]:
    """The hold times the folds' training chose (``eskin.learn.live_windows``), one line per
    hold instead of one note per fold: in how many folds, and how many training recordings
    per fold split into 2+ live touches at the first hold tried and at the one chosen."""
    records = [f["live_touches"] for f in result.get("folds", []) if f.get("live_touches")]
    lines = []
    for hold in sorted({r["hold_s"] for r in records}):
        mine = [r for r in records if r["hold_s"] == hold]
        first = [next(iter(r["tried"].values())) for r in mine]
        start = next(iter(mine[0]["tried"]))
        if all(r["split"] == 0 and r["none"] == 0 for r in first):
            continue  # one touch per recording at the hold the folds started from
        n = _span([r["recordings"] for r in mine])
        split = _span([r["split"] for r in first])
        if not mine[0]["chosen"]:
            lines.append(f"hold_s = {hold:g} s (given) in {len(mine)} of {len(records)} folds: "
                         f"{split} of {n} training recordings per fold gave 2+ live touches "
                         f"(a longer --hold merges them)")
            continue
        short = [r for r in mine if r["one"] < r["share"] * r["recordings"]]
        why = "" if not short else (
            f" (in {len(short)} of them no hold up to {max(float(h) for h in short[0]['tried']):g}"
            f" s gave one touch on {100 * short[0]['share']:.0f} % of the recordings)")
        lines.append(
            f"hold_s = {hold:g} s (chosen) in {len(mine)} of {len(records)} folds: at {start} s, "
            f"{split} of {n} training recordings per fold gave 2+ live touches; at {hold:g} s, "
            f"{_span([r['one'] for r in mine])} give one{why}")
    return lines


def _live_markdown(result: Mapping[str, Any]) -> list[str]:
    live = result.get("live")
    if not live:
        return []
    rows = ["", "## Live: the stream a controller sees", "",
            (f"Each fold's held-out recordings were played as one continuous stream "
             f"({live['gap_s']:g} s of quiet between recordings, as `eskin replay --gap "
             f"{live['gap_s']:g}` writes it) through the fold's compiled stream classifier "
             f"({_hold_text(live['hold_s'])}). Every touch the detector ended is a decision; "
             f"the one kept for a recording is the one on its contact (`eskin listen --replay` "
             f"scores the same way)."), "",
            "| | per recording | live |", "| --- | ---: | ---: |",
            f"| accuracy | {_pct(result['accuracy'])} | {_pct(live['accuracy'])} |",
            f"| touches per recording | 1 | {live['touches_per_recording']:.2f} |",
            f"| recordings split (2+ touches) | - | {live['split']} of {live['recordings']} |",
            f"| recordings missed (no touch) | - | {live['missed']} |",
            f"| spurious touches in the gaps | - | {live['spurious']} |",
            f"| \"don't know\" decisions kept | - | {live['dont_know']} |"]
    return rows


def _groups(values: list[int]) -> str:
    return ",".join(map(str, values)) if len(values) <= 6 else f"{len(values)} groups"


def _markdown(result: Mapping[str, Any], figure: str) -> str:
    classes = list(result["classes"])
    rows = [
        "# Evaluation",
        "",
        (
            f"Campaign `{result.get('campaign')}`; {result['scheme']} by {result['groups']} "
            f"({result['n_groups']} groups, {result['n_recordings']} recordings); options "
            f"given: {given_options(result['recipe'])}; seed {result['seed']}. Each "
            "fold's model selection saw only its training groups (nested evaluation)."
        ),
        "",
        f"Trained with: {describe_trained_with(result.get('trained_with', {}))}.",
        "",
        "| | accuracy | 95 % CI | balanced accuracy | 95 % CI |",
        "| --- | ---: | ---: | ---: | ---: |",
        (
            f"| tensor recipe | {_pct(result['accuracy'])} | {_ci(result['ci95'])} | "
            f"{_pct(result['balanced_accuracy'])} | {_ci(result['ci95_balanced_accuracy'])} |"
        ),
    ]
    for name, b in result.get("baselines", {}).items():
        rows.append(
            f"| baseline {name} | {_pct(b['accuracy'])} | {_ci(b['ci95'])} | "
            f"{_pct(b['balanced_accuracy'])} | {_ci(b['ci95_balanced_accuracy'])} |"
        )
    rows += _live_markdown(result)
    rows += _risk_coverage_markdown(result)
    rows += ["", f"Intervals: {result['ci_method']}.", "", "## Per-class recall and confusion", ""]
    rows.append("| true \\ predicted | " + " | ".join(classes) + " | recall |")
    rows.append("| --- |" + " ---: |" * (len(classes) + 1))
    for c, row in zip(classes, result["confusion"]):
        rows.append(
            f"| {c} | " + " | ".join(map(str, row)) + f" | {_pct(result['per_class_recall'][c])} |"
        )
    rows += ["", "## Folds", "", "| fold | test groups | n test | accuracy | selected |"]
    rows.append("| ---: | --- | ---: | ---: | --- |")
    for r in result["folds"]:
        rows.append(
            f"| {r['fold'] + 1} | {_groups(r['test_groups'])} | {r['n_test']} | "
            f"{_pct(r['accuracy'])} | {fold_settings(r)} |"
        )
    rows += ["", f"![accuracy per fold and confusion matrix]({figure})", ""]
    return "\n".join(rows)


def _risk_coverage_markdown(result: Mapping[str, Any]) -> list[str]:
    """"Don't know" and the risk-coverage curve (none without a calibrated confidence)."""
    rc, dk = result.get("risk_coverage"), result.get("dont_know")
    if not rc:
        return []
    rows = ["", "## \"Don't know\" and the risk-coverage curve", ""]
    if dk:
        rows += [f"The model's threshold flags {_pct(dk['flagged'])} of the held-out recordings "
                 f"({dk['n_flagged']}): accuracy {_pct(dk['accuracy_decided'])} on the decided, "
                 f"{_pct(dk['accuracy_flagged'])} on the flagged.", ""]
    rows += ["Deciding only the most confident share (coverage) of the recordings:", "",
             "| coverage | " + " | ".join(f"{100 * c:.0f} %" for c in rc["coverage"][4::5])
             + " |", "| --- |" + " ---: |" * len(rc["coverage"][4::5]),
             "| error on the decided | " + " | ".join(_pct(e) for e in rc["error"][4::5]) + " |"]
    return rows


def plot_evaluation(result: Mapping[str, Any], path: Path) -> Path:
    """Accuracy per fold (recipe and baselines) and the pooled confusion matrix (row-normalised)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    folds = result["folds"]
    classes = list(result["classes"])
    rc = result.get("risk_coverage")
    ratios = [1.6, 1] + ([1] if rc else [])
    fig, axes = plt.subplots(1, len(ratios), figsize=(11 + 4 * bool(rc), 4.2),
                             gridspec_kw={"width_ratios": ratios})
    ax, axc = axes[0], axes[1]
    if rc:
        _plot_risk_coverage(axes[2], rc, result)
    x = np.arange(len(folds))
    series = [("tensor recipe", [r["accuracy"] for r in folds])]
    series += [
        (f"baseline {b}", [r["baselines"][b]["accuracy"] for r in folds])
        for b in result.get("baselines", {})
    ]
    width = 0.8 / len(series)
    for j, (label, acc) in enumerate(series):
        ax.bar(x + (j - (len(series) - 1) / 2) * width, acc, width, label=label)
    ax.axhline(result["accuracy"], color="k", lw=0.8, ls="--", label="pooled accuracy")
    ax.axhspan(*result["ci95"], color="grey", alpha=0.2, label="95 % CI")
    ax.set_xticks(x, [str(r["fold"] + 1) for r in folds], fontsize=7)
    ax.set_xlabel(f"fold (held-out {result['groups']})")
    ax.set_ylabel("accuracy")
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=7, loc="lower right")
    cm = np.asarray(result["confusion"], float)
    norm = cm / np.maximum(cm.sum(axis=1, keepdims=True), 1)
    axc.imshow(norm, vmin=0, vmax=1, cmap="Blues")
    for (i, j), v in np.ndenumerate(cm):
        axc.text(
            j,
            i,
            f"{int(v)}",
            ha="center",
            va="center",
            fontsize=7,
            color="white" if norm[i, j] > 0.5 else "black",
        )
    axc.set_xticks(range(len(classes)), classes, rotation=45, ha="right", fontsize=7)
    axc.set_yticks(range(len(classes)), classes, fontsize=7)
    axc.set_xlabel("predicted")
    axc.set_ylabel("true")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _plot_risk_coverage(ax: Any, rc: Mapping[str, Any], result: Mapping[str, Any]) -> None:
    """Error on the decided recordings against the share decided (most confident first)."""
    ax.plot(np.asarray(rc["coverage"]), np.asarray(rc["error"]), marker="o", ms=3,
            label="calibrated confidence")
    ax.axhline(1 - result["accuracy"], color="k", lw=0.8, ls="--", label="all decided")
    dk = result.get("dont_know")
    if dk and dk.get("accuracy_decided") is not None:
        ax.plot([1 - dk["flagged"]], [1 - dk["accuracy_decided"]], "s", color="C3",
                label="the model's threshold")
    ax.set_xlabel("coverage (share decided)")
    ax.set_ylabel("error on the decided")
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, max(0.05, 1.1 * max(rc["error"])))
    ax.set_title("risk-coverage", fontsize=8)
    ax.legend(fontsize=7)


def write_evaluation(result: Mapping[str, Any], out_dir: str | Path) -> dict[str, Path]:
    """Write evaluation.json, evaluation.md and evaluation.png into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "json": out / "evaluation.json",
        "md": out / "evaluation.md",
        "figure": out / "evaluation.png",
    }
    from eskin._files import whole_file, write_whole

    # each file whole or not at all: a full disk leaves no truncated evaluation.json
    write_whole(paths["json"], json.dumps(result, indent=1).encode())
    with whole_file(paths["figure"]) as tmp:
        plot_evaluation(result, tmp)
    write_whole(paths["md"], _markdown(result, paths["figure"].name).encode())
    return paths


def selection_estimate_lines(model: Any) -> list[str]:
    """What ``eskin train`` says about the held-out error its own selection expects: the inner
    cross-validation error of the selected setting (per machine), or, for Maximal Discrepancy,
    the bound it minimised."""
    lines = []
    for sel in model.selected:
        terms = sel.get("selection_terms", {})
        name = f"{sel['class']} vs rest" if "class" in sel else "the model"
        if "mean_test_error" in terms:
            lines.append(
                f"  {name}: {_pct(terms['mean_test_error'])} "
                f"(+- {_pct(terms.get('std_test_error'))} over the splits)"
            )
        elif "bound" in terms:
            lines.append(
                f"  {name}: bound {terms['bound']:.3f} = training error {terms['train_error']:.3f}"
                f" + chi {terms['chi']:.3f} + tau {terms['tau']:.3f}"
            )
    if not lines:
        return []
    if model.selection == "cv":
        head = "inner-CV estimate of the held-out error (grouped splits of the training data):"
        tail = "  (optimistic: the best setting of the grid on these very splits)"
    else:
        head = "Maximal Discrepancy bound of the selected setting (no inner-CV estimate):"
        tail = "  (an upper bound on the error rate, often above 1 on small training sets)"
    return [head, *lines, tail, "  eskin evaluate gives a nested estimate on unseen groups"]
