"""The experiment report: summary numbers, report.md laid out like the paper's tables, figures.

Input is the results dictionary of :func:`eskin.experiments.run_experiment` (the content of
``results.json``); :func:`write_report` can be re-run on a saved ``results.json``
(``write_report(json.load(open(path)), folder)``).

Figures (matplotlib, Agg backend, PNG):

- ``figure6.png``: per problem, validation error against run for tensor-SVM and tensor-RLS at
  every D (the paper's Figure 6);
- ``figure7.png``: MD against CV selection, per problem and machine, every D (Figures 7, 8);
- ``confusion_binary.png``: confusion matrices of the binary problems (MD, largest D, summed
  over runs);
- ``confusion_multiclass.png``: the three-class confusion matrices (summed over runs).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from eskin.experiments import paper_tables as paper

MACHINE_NAME = {"svm": "tensor-SVM", "rls": "tensor-RLS"}


def _mean_sd(values: Sequence[float]) -> dict[str, float]:
    a = np.asarray(values, float) * 100.0
    if a.size == 0:
        return {
            "mean": float("nan"),
            "sd": float("nan"),
            "min": float("nan"),
            "max": float("nan"),
            "n": 0,
        }
    return {
        "mean": float(a.mean()),
        "sd": float(a.std(ddof=1)) if a.size > 1 else 0.0,
        "min": float(a.min()),
        "max": float(a.max()),
        "n": int(a.size),
    }


Cell = tuple[str, str, str, int]  # machine, selection, problem, D


def summarise(results: dict[str, Any]) -> dict[str, Any]:
    """Means over runs (in %) of every cell, MD vs CV, baseline, 3-class and subsampling."""
    groups, sigmas, lambdas, keys = _binary_cells(results)
    binary = [
        {"machine": m, "selection": s, "problem": p, "D": D, **_mean_sd(groups[(m, s, p, D)])}
        for (m, s, p, D) in keys
    ]
    md_vs_cv = _md_vs_cv(keys, groups, sigmas, lambdas)
    overall = {}
    for m in ("svm", "rls"):
        rows = [r for r in md_vs_cv if r["machine"] == m]
        if rows:
            overall[m] = {
                "md_mean": float(np.mean([r["md_mean"] for r in rows])),
                "cv_mean": float(np.mean([r["cv_mean"] for r in rows])),
            }
    worse = [r for r in md_vs_cv if r["md_minus_cv"] > 1e-9]
    bgroups: dict[tuple[str, int], list[float]] = defaultdict(list)
    for d in results.get("baseline") or []:
        bgroups[(d["problem"], int(d["D"]))].append(d["error"])
    baseline = [{"problem": p, "D": D, **_mean_sd(v)} for (p, D), v in sorted(bgroups.items())]
    md_means = [r["mean"] for r in binary if r["selection"] == "md"]
    return {
        "binary": binary,
        "md_vs_cv": md_vs_cv,
        "md_vs_cv_overall": overall,
        "md_worse_than_cv": worse,
        "baseline": baseline,
        "multiclass": _multiclass_summary(results),
        "subsampling": _subsampling_summary(results),
        "binary_md_range_pct": [float(min(md_means)), float(max(md_means))] if md_means else None,
    }


def _binary_cells(
    results: dict[str, Any],
) -> tuple[dict[Cell, list[float]], dict[Cell, list[float]], dict[Cell, list[float]], list[Cell]]:
    """The binary runs grouped by cell: errors, selected sigmas and lambdas, and the cells in
    table order (SVM before RLS, MD before CV, the problems' order, D)."""
    groups: dict[Cell, list[float]] = defaultdict(list)
    sigmas: dict[Cell, list[float]] = defaultdict(list)
    lambdas: dict[Cell, list[float]] = defaultdict(list)
    for d in results["binary"]:
        key = (d["machine"], d["selection"], d["problem"], int(d["D"]))
        groups[key].append(d["error"])
        sigmas[key].append(d["selected"]["sigma"])
        lambdas[key].append(d["selected"]["lambda"])
    problems = list(results.get("problems") or sorted({k[2] for k in groups}))

    def order(k: Cell) -> tuple[int, int, int, int]:
        m, s, p, D = k
        return (
            ("svm", "rls").index(m) if m in ("svm", "rls") else 9,
            ("md", "cv").index(s) if s in ("md", "cv") else 9,
            problems.index(p) if p in problems else 99,
            D,
        )

    return groups, sigmas, lambdas, sorted(groups, key=order)


def _md_vs_cv(
    keys: list[Cell],
    groups: dict[Cell, list[float]],
    sigmas: dict[Cell, list[float]],
    lambdas: dict[Cell, list[float]],
) -> list[dict[str, Any]]:
    """One row per cell that ran both selections: mean errors and median selected values."""
    md_vs_cv = []
    for m, s, p, D in keys:
        v = groups[(m, s, p, D)]
        if s != "md" or (m, "cv", p, D) not in groups:
            continue
        md = _mean_sd(v)["mean"]
        cv = _mean_sd(groups[(m, "cv", p, D)])["mean"]
        md_vs_cv.append(
            {
                "machine": m,
                "problem": p,
                "D": D,
                "md_mean": md,
                "cv_mean": cv,
                "md_minus_cv": md - cv,
                "md_median_sigma": float(np.median(sigmas[(m, "md", p, D)])),
                "cv_median_sigma": float(np.median(sigmas[(m, "cv", p, D)])),
                "md_median_lambda": float(np.median(lambdas[(m, "md", p, D)])),
                "cv_median_lambda": float(np.median(lambdas[(m, "cv", p, D)])),
            }
        )
    return md_vs_cv


def _multiclass_summary(results: dict[str, Any]) -> dict[str, Any]:
    """Best, mean and average 3-class error per machine."""
    mc = results.get("multiclass") or {}
    multiclass = {}
    for m in ("svm", "rls"):
        errs = [d["error"] for d in mc.get("runs", []) if d["machine"] == m]
        if errs:
            multiclass[m] = {
                "best": 100 * min(errs),
                **_mean_sd(errs),
                "average": 100 * float(np.mean(errs)),
            }
    return multiclass


def _subsampling_summary(results: dict[str, Any]) -> dict[str, Any] | None:
    """Mean errors of the two subsampling methods, per problem and overall."""
    sub = results.get("subsampling") or None
    if not (sub and sub.get("rows")):
        return None
    a, b = sub["main"], sub["other"]
    return {
        "D": sub["D"],
        "machine": sub["machine"],
        "main": a,
        "other": b,
        "per_problem": {
            p: {
                a: _mean_sd([r[f"error_{a}"] for r in sub["rows"] if r["problem"] == p])["mean"],
                b: _mean_sd([r[f"error_{b}"] for r in sub["rows"] if r["problem"] == p])["mean"],
            }
            for p in sorted({r["problem"] for r in sub["rows"]})
        },
        a: _mean_sd([r[f"error_{a}"] for r in sub["rows"]])["mean"],
        b: _mean_sd([r[f"error_{b}"] for r in sub["rows"]])["mean"],
    }


# --------------------------------------------------------------------------------------------
# markdown


def _pw(x: float | None, base: int) -> str:
    if x is None:
        return "-"
    if x > 0:
        k = math.log(x, base)
        if abs(k - round(k)) < 1e-9:
            k = int(round(k))
            if base == 10:
                return f"{x:g}"
            return "1" if k == 0 else f"2^{k}"
    return f"{x:.3g}"


def _setting(sel: dict[str, Any]) -> str:
    alpha = sel.get("alpha") or "x".join(str(a) for a in sel.get("alphas") or []) or "?"
    return f"({_pw(sel.get('lambda'), 10)}, {_pw(sel.get('sigma'), 2)}, {alpha})"


def _paper_setting(cell: tuple[float, float, float, str]) -> str:
    return f"{cell[0]:.1f} ({_pw(cell[1], 10)}, {_pw(cell[2], 2)}, {cell[3]})"


def _f(x: float | None, nd: int = 1) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{nd}f}"


def _binary_row(
    summary: dict[str, Any], machine: str, selection: str, problem: str, D: int
) -> dict[str, Any] | None:
    """The summary row of one binary cell (machine, selection, problem, D), or None."""
    return next(
        (
            x
            for x in summary["binary"]
            if x["machine"] == machine
            and x["selection"] == selection
            and x["problem"] == problem
            and x["D"] == D
        ),
        None,
    )


def _binary_table(results: dict[str, Any], machine: str, problem: str) -> list[str]:
    cells = {
        (d["run"], int(d["D"])): d
        for d in results["binary"]
        if d["machine"] == machine and d["problem"] == problem and d["selection"] == "md"
    }
    Ds = sorted({D for _, D in cells})
    runs = sorted({r for r, _ in cells})
    is_paper = (
        problem in paper.PAPER_PROBLEMS
        and tuple(results["problems"][problem]["classes"]) == paper.PAPER_PROBLEMS[problem]
    )
    head = ["run"]
    for D in Ds:
        head.append(f"D={D} ours")
        if is_paper and D in paper.PAPER_DS:
            head.append(f"D={D} paper")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in runs:
        row = [f"run #{r}"]
        for D in Ds:
            d = cells.get((r, D))
            row.append(f"{d['error_pct']:.1f} {_setting(d['selected'])}" if d else "-")
            if is_paper and D in paper.PAPER_DS:
                c = paper.paper_cell(machine, problem, D, r)
                row.append(_paper_setting(c) if c else "-")
        lines.append("| " + " | ".join(row) + " |")
    row = ["**mean**"]
    for D in Ds:
        errs = [cells[(r, D)]["error_pct"] for r in runs if (r, D) in cells]
        row.append(f"**{np.mean(errs):.1f}**" if errs else "-")
        if is_paper and D in paper.PAPER_DS:
            pm = paper.paper_mean(machine, problem, D)
            row.append(f"**{pm:.1f}**" if pm is not None else "-")
    lines.append("| " + " | ".join(row) + " |")
    return lines


def too_small_note(n_participants: int) -> str:
    """Why an analysis set smaller than the paper's cannot be compared with its tables ("" when
    it is as large)."""
    if n_participants >= paper.PAPER_PARTICIPANTS:
        return ""
    return (
        f"{n_participants} participants in the analysis set (the paper: "
        f"{paper.PAPER_PARTICIPANTS}, 20 of them validating each run), so each run's validation "
        "error rests on a few people and moves in large steps; the paper's numbers beside these "
        "are for orientation only"
    )


def _summary_lines(results: dict[str, Any]) -> list[str]:
    s = results["summary"]
    camp = results["campaign"]
    lines = []
    if camp.get("simulated"):
        lines.append(
            "**The data are simulated** (campaign source: `simulated`, eskin's simulator): these "
            "numbers measure the method on synthetic touches, not on the paper's recordings."
        )
        lines.append("")
    a = results["analysis_set"]
    p = results["protocol"]
    lines.append(
        f"Campaign `{Path(camp['path']).name}` ({camp['source']}): {camp['n_recordings']} "
        f"recordings, grid {'x'.join(map(str, camp['grid_shape']))}, "
        f"{camp['sample_rate_hz']:g} Hz, classes {', '.join(camp['modalities'])}. "
        f"Analysis set: {a['n_patterns']} patterns of {a['n_participants']} participants"
        + (f" (run {a['run']})" if a.get("run") is not None else "")
        + f"; {len(a['excluded_participants'])} participant(s) excluded. "
        f"{p['runs']} runs, D in {{{', '.join(map(str, p['Ds']))}}}, "
        f"{p['n_configurations']} configurations per search"
        + (" (**quick mode: reduced grid, not the paper's protocol**)" if p.get("quick") else "")
        + "."
    )
    lines.append("")
    note = too_small_note(a["n_participants"])
    if note:
        lines += [f"**Too small to compare with the paper**: {note}.", ""]
    lines.append(
        "| machine | problem | "
        + " | ".join(f"D={D} MD" for D in p["Ds"])
        + " | paper (mean over D) |"
    )
    lines.append("|" + "---|" * (3 + len(p["Ds"])))
    for m in ("svm", "rls"):
        for prob in results["problems"]:
            row = [MACHINE_NAME[m], prob]
            for D in p["Ds"]:
                r = _binary_row(s, m, "md", prob, D)
                row.append(f"{r['mean']:.1f} ± {r['sd']:.1f}" if r else "-")
            pms = [paper.paper_mean(m, prob, D) for D in paper.PAPER_DS]
            pms = [x for x in pms if x is not None]
            row.append(f"{np.mean(pms):.1f}" if pms and prob in paper.PAPER_PROBLEMS else "-")
            lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    lines.append("Validation error %, mean ± sd over runs, MD selection.")
    if s.get("binary_md_range_pct"):
        lo, hi = s["binary_md_range_pct"]
        lines.append(
            f"Binary problems, mean error per cell: {lo:.1f} % to {hi:.1f} % "
            "(paper: 2.5-20 % per run)."
        )
    if s.get("multiclass"):
        parts = [
            f"{MACHINE_NAME[m]} best {v['best']:.1f} %, average {v['average']:.1f} %"
            for m, v in s["multiclass"].items()
        ]
        lines.append(
            "Three classes (1-vs-all): "
            + "; ".join(parts)
            + " (paper: SVM 23.4 / 29.0, RLS 22.7 / 26.3)."
        )
    lines.append("")
    lines.extend(_md_cv_statement(results))
    return lines


def _md_cv_statement(results: dict[str, Any]) -> list[str]:
    s = results["summary"]
    lines = []
    for m, v in s.get("md_vs_cv_overall", {}).items():
        verdict = "no worse than" if v["md_mean"] <= v["cv_mean"] + 1e-9 else "**worse than**"
        lines.append(
            f"MD vs CV, {MACHINE_NAME[m]}: MD {v['md_mean']:.2f} % vs CV {v['cv_mean']:.2f} % "
            f"averaged over all problems, D and runs: MD is {verdict} CV on average."
        )
    worse = s.get("md_worse_than_cv") or []
    if worse:
        cells = ", ".join(
            f"{MACHINE_NAME[r['machine']]} {r['problem']} D={r['D']} (+{r['md_minus_cv']:.1f})"
            for r in worse
        )
        lines.append(
            f"MD is worse than CV on average over runs in {len(worse)} of "
            f"{len(s['md_vs_cv'])} (machine, problem, D) cells: {cells}."
        )
    elif s.get("md_vs_cv"):
        lines.append("MD is no worse than CV on average in every (machine, problem, D) cell.")
    return lines


def render_markdown(results: dict[str, Any], figures: Sequence[str] = ()) -> str:
    """report.md as a string."""
    L: list[str] = ["# eskin experiment report", ""]
    L += _header_section(results)
    L += _binary_section(results, figures)
    L += _md_vs_cv_section(results, figures)
    L += _multiclass_section(results, figures)
    L += _baseline_section(results)
    L += _subsampling_section(results)
    if "confusion_binary.png" in figures:
        L += ["## Confusion matrices", "", "![Binary confusion matrices](confusion_binary.png)", ""]
    L += _notes_section(results)
    return "\n".join(L)


def _header_section(results: dict[str, Any]) -> list[str]:
    """The generation line and the summary."""
    p = results["protocol"]
    L: list[str] = []
    L.append(
        f"Generated {results['created_utc']} by eskin {results['versions']['eskin']} "
        f"(numpy {results['versions']['numpy']}, scikit-learn "
        f"{results['versions']['scikit-learn']}); seed {p['seed']}; "
        f"{results.get('seconds_total', float('nan')):.0f} s."
    )
    L.append("")
    L.append("## Summary")
    L.append("")
    L.extend(_summary_lines(results))
    L.append("")
    return L


def _binary_section(results: dict[str, Any], figures: Sequence[str]) -> list[str]:
    """Tables 1-6: one table per machine and binary problem."""
    L: list[str] = []
    L.append("## Binary problems (Tables 1-6)")
    L.append("")
    L.append(
        "Each cell: validation error % (lambda, sigma, alpha) of the setting chosen by "
        "Maximal Discrepancy. **Both machines show lambda**, as the paper's Tables 1-6 do; "
        "the SVM is trained with C = 1/lambda (docs/paper-readings.md, R9). alpha is the grid label "
        "(1, Q/2, Q per mode; Q = rank bound of the mode unfolding). The paper's cells are "
        "transcribed as printed (its alpha = 0 is a misprint)."
    )
    L.append("")
    for m in ("svm", "rls"):
        for prob, info in results["problems"].items():
            tn = paper.TABLE_NUMBER.get((m, prob)) if prob in paper.PAPER_PROBLEMS else None
            title = f"Table {tn}: " if tn else ""
            L.append(
                f"### {title}problem {prob} ({' vs '.join(info['classes'])}), {MACHINE_NAME[m]}"
            )
            L.append("")
            L.extend(_binary_table(results, m, prob))
            L.append("")
    if "figure6.png" in figures:
        L += ["![Figure 6: validation error per run](figure6.png)", ""]
    return L


def _md_vs_cv_section(results: dict[str, Any], figures: Sequence[str]) -> list[str]:
    """Figures 7 and 8: Maximal Discrepancy against cross-validation."""
    s = results["summary"]
    p = results["protocol"]
    L: list[str] = []
    L.append("## Model selection: Maximal Discrepancy vs cross-validation (Figures 7, 8)")
    L.append("")
    cvo = {"n_splits": 10, "test_size": 0.3, **(p.get("cv") or {})}
    L.append(
        f"CV: {cvo['n_splits']} random splits of the training set by participant, "
        f"{100 * cvo['test_size']:.0f} % of the participants held out each time (the "
        "paper's 'repeatedly split'); both selections are scored on the same validation "
        "patterns."
    )
    L.append("")
    L.append(
        "| machine | problem | D | MD mean % | CV mean % | MD - CV | median sigma MD / CV "
        "| median lambda MD / CV |"
    )
    L.append("|---|---|---|---|---|---|---|---|")
    for r in s["md_vs_cv"]:
        L.append(
            f"| {MACHINE_NAME[r['machine']]} | {r['problem']} | {r['D']} | "
            f"{r['md_mean']:.1f} | {r['cv_mean']:.1f} | {r['md_minus_cv']:+.1f} | "
            f"{_pw(r.get('md_median_sigma'), 2)} / {_pw(r.get('cv_median_sigma'), 2)} | "
            f"{_pw(r.get('md_median_lambda'), 10)} / {_pw(r.get('cv_median_lambda'), 10)} |"
        )
    L.append("")
    L.extend(_md_cv_statement(results))
    L.append("")
    if "figure7.png" in figures:
        L += ["![Figure 7: MD vs CV](figure7.png)", ""]
    return L


def _multiclass_section(results: dict[str, Any], figures: Sequence[str]) -> list[str]:
    """Table 7: the three-class 1-vs-all experiment."""
    s = results["summary"]
    L: list[str] = []
    mc = results.get("multiclass") or {}
    L.append("## Three classes, 1-vs-all (Table 7)")
    L.append("")
    if mc.get("ran"):
        L.append(
            f"D = {mc['D']}; per run, one MD-selected machine per class trained on the "
            "training participants' patterns of that class and as many random patterns of "
            "the other classes; test on every pattern of the validation participants. "
            "Decision: the one machine that claims the pattern, else the largest f(x)."
        )
        L.append("")
        L.append("| | tensor-SVM ours | tensor-SVM paper | tensor-RLS ours | tensor-RLS paper |")
        L.append("|---|---|---|---|---|")
        ms = s.get("multiclass", {})
        for q in ("best", "average"):
            L.append(
                f"| {q} | {_f(ms.get('svm', {}).get(q))} | {paper.MULTICLASS['svm'][q]} | "
                f"{_f(ms.get('rls', {}).get(q))} | {paper.MULTICLASS['rls'][q]} |"
            )
        L.append(
            "| settings | per run below | sigma = 2^-1; C = 10; alpha = Q/2; D = 100 | "
            'per run below | sigma = 2^-1; "C" = 100; alpha = Q/2; D = 100 |'
        )
        L.append("")
        L.append(
            "Selected settings per run and class machine: SVM (C, sigma, alpha), "
            "RLS (lambda, sigma, alpha)."
        )
        L.append("")
        classes = mc.get("classes", [])
        L.append("| run | machine | error % | don't know % | " + " | ".join(classes) + " |")
        L.append("|" + "---|" * (4 + len(classes)))
        for d in mc.get("runs", []):
            sets = []
            for sel in d["selected"]:
                first = (
                    _pw(sel.get("C"), 10) if d["machine"] == "svm" else _pw(sel.get("lambda"), 10)
                )
                sets.append(f"({first}, {_pw(sel['sigma'], 2)}, {sel.get('alpha')})")
            L.append(
                f"| {d['run']} | {MACHINE_NAME[d['machine']]} | {d['error_pct']:.1f} | "
                f"{100 * d['dont_know_rate']:.1f} | " + " | ".join(sets) + " |"
            )
        L.append("")
        if "confusion_multiclass.png" in figures:
            L += ["![Three-class confusion matrices](confusion_multiclass.png)", ""]
    else:
        L.append(f"Not run: {mc.get('reason', 'disabled')}.")
        L.append("")
    return L


def _baseline_section(results: dict[str, Any]) -> list[str]:
    """The vector RBF-SVM baseline beside the tensor-SVM."""
    s = results["summary"]
    p = results["protocol"]
    L: list[str] = []
    if s.get("baseline"):
        L.append("## Vector baseline: RBF SVM on the flattened window")
        L.append("")
        L.append(
            "Same participant splits, same CV scheme; the same number of configurations "
            f"({p['n_configurations']}): C = 1/lambda, gamma = 2^-2k / median squared "
            "distance (k over the sigma exponents), input normalisation none / per pattern "
            "/ per feature; selected by cross-validation."
        )
        L.append("")
        L.append("| problem | D | vector SVM (CV) % | tensor-SVM (CV) % | tensor-SVM (MD) % |")
        L.append("|---|---|---|---|---|")
        for r in s["baseline"]:
            cv = _binary_row(s, "svm", "cv", r["problem"], r["D"])
            md = _binary_row(s, "svm", "md", r["problem"], r["D"])
            t_cv = cv["mean"] if cv else None
            t_md = md["mean"] if md else None
            L.append(
                f"| {r['problem']} | {r['D']} | {r['mean']:.1f} ± {r['sd']:.1f} | "
                f"{_f(t_cv)} | {_f(t_md)} |"
            )
        L.append("")
    return L


def _subsampling_section(results: dict[str, Any]) -> list[str]:
    """Algorithm 2 against even subsampling."""
    s = results["summary"]
    L: list[str] = []
    sub = s.get("subsampling")
    if sub:
        a, b = sub["main"], sub["other"]
        L.append(f"## Subsampling: {a} vs {b} (docs/paper-readings.md, R18)")
        L.append("")
        L.append(
            f"{MACHINE_NAME[sub['machine']]}, MD selection, D = {sub['D']}, same splits and "
            "seeds; only the subsampling differs. Algorithm 2 takes every "
            "floor(S/D)-th sample from the window start (dropping the tail remainder); "
            "'even' spreads D indices over the whole window."
        )
        L.append("")
        L.append(f"| problem | {a} % | {b} % |")
        L.append("|---|---|---|")
        for prob, v in sub["per_problem"].items():
            L.append(f"| {prob} | {v[a]:.1f} | {v[b]:.1f} |")
        L.append(f"| **all** | **{sub[a]:.1f}** | **{sub[b]:.1f}** |")
        L.append("")
    return L


def _notes_section(results: dict[str, Any]) -> list[str]:
    """The protocol's notes: analysis set, exclusion, options."""
    p = results["protocol"]
    L: list[str] = []
    a = results["analysis_set"]
    L.append("## Protocol notes")
    L.append("")
    L.append(
        f"- Analysis set: {a['n_patterns']} patterns, {a['n_participants']} participants; "
        f"per run {p['train_participants_per_run']} training / "
        f"{p['validation_participants_per_run']} validation participants, never shared."
    )
    L.append(
        f"- Exclusion: {a['exclusion_rule']}"
        + (
            f" Excluded: {', '.join(map(str, a['excluded_participants']))}."
            if a["excluded_participants"]
            else ""
        )
    )
    for n in a.get("notes", []):
        L.append(f"- {n}")
    L.append(f"- Window: {p['window']}; subsampling: {p['subsample']}.")
    md = p.get("md") or {}
    L.append(
        "- Maximal Discrepancy options: "
        + (", ".join(f"{k}={v}" for k, v in md.items()) if md else "eskin defaults")
        + "."
    )
    if "md_reading" in p:  # which reading of Algorithm 1 ran (docs/learning.md)
        L.append(f"- Algorithm 1 as run: {p['md_reading']}.")
    L.append(
        "- One participant split per run is shared by every problem, D, machine and "
        "selection method, so comparisons are paired."
    )
    for n in paper.MISPRINTS:
        L.append(f"- Paper: {n}")
    L.append("")
    return L


# --------------------------------------------------------------------------------------------
# figures


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _axes_style(ax: Any, results: dict[str, Any]) -> None:
    runs = list(range(1, int(results["protocol"]["runs"]) + 1))
    ax.set_xticks(runs)
    ax.set_xlim(0.7, runs[-1] + 0.3)
    top = max([d["error_pct"] for d in results["binary"]] + [10.0])
    ax.set_ylim(0, min(100.0, top * 1.1 + 1))
    ax.set_xlabel("run")
    ax.set_ylabel("validation error %")
    ax.grid(alpha=0.3)


def figure6(results: dict[str, Any], path: Path) -> None:
    plt = _plt()
    problems = list(results["problems"])
    Ds = results["protocol"]["Ds"]
    fig, axes = plt.subplots(1, len(problems), figsize=(4.2 * len(problems), 3.4), squeeze=False)
    for ax, prob in zip(axes[0], problems):
        for m, style in (("svm", "-o"), ("rls", "--s")):
            for j, D in enumerate(Ds):
                pts = sorted(
                    (d["run"], d["error_pct"])
                    for d in results["binary"]
                    if d["problem"] == prob
                    and d["machine"] == m
                    and d["D"] == D
                    and d["selection"] == "md"
                )
                if pts:
                    x, y = zip(*pts)
                    ax.plot(
                        x, y, style, color=f"C{j}", label=f"{MACHINE_NAME[m]} D={D}", markersize=4
                    )
        ax.set_title(f"problem {prob}")
        _axes_style(ax, results)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def figure7(results: dict[str, Any], path: Path) -> None:
    plt = _plt()
    problems = list(results["problems"])
    Ds = results["protocol"]["Ds"]
    fig, axes = plt.subplots(2, len(problems), figsize=(4.2 * len(problems), 6.4), squeeze=False)
    for i, m in enumerate(("svm", "rls")):
        for ax, prob in zip(axes[i], problems):
            for j, D in enumerate(Ds):
                for sel, style in (("md", "-o"), ("cv", ":x")):
                    pts = sorted(
                        (d["run"], d["error_pct"])
                        for d in results["binary"]
                        if d["problem"] == prob
                        and d["machine"] == m
                        and d["D"] == D
                        and d["selection"] == sel
                    )
                    if pts:
                        x, y = zip(*pts)
                        ax.plot(
                            x, y, style, color=f"C{j}", markersize=4, label=f"{sel.upper()} D={D}"
                        )
            ax.set_title(f"{MACHINE_NAME[m]}, problem {prob}")
            _axes_style(ax, results)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _draw_confusion(ax: Any, m: np.ndarray, labels: Sequence[str], title: str) -> None:
    ax.imshow(m, cmap="Blues")
    ax.set_xticks(range(len(labels)), labels, fontsize=7)
    ax.set_yticks(range(len(labels)), labels, fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title, fontsize=9)
    for (i, j), v in np.ndenumerate(m):
        ax.text(
            j,
            i,
            str(int(v)),
            ha="center",
            va="center",
            color="white" if v > m.max() / 2 else "black",
            fontsize=8,
        )


def confusion_binary(results: dict[str, Any], path: Path) -> None:
    plt = _plt()
    problems = list(results["problems"])
    D = max(results["protocol"]["Ds"])
    fig, axes = plt.subplots(2, len(problems), figsize=(3.2 * len(problems), 6.0), squeeze=False)
    for i, m in enumerate(("svm", "rls")):
        for ax, prob in zip(axes[i], problems):
            mats = [
                np.asarray(d["confusion"])
                for d in results["binary"]
                if d["problem"] == prob
                and d["machine"] == m
                and d["D"] == D
                and d["selection"] == "md"
            ]
            total = np.sum(mats, axis=0) if mats else np.zeros((2, 2), int)
            _draw_confusion(
                ax, total, results["problems"][prob]["classes"], f"{MACHINE_NAME[m]} {prob}, D={D}"
            )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def confusion_multiclass(results: dict[str, Any], path: Path) -> None:
    plt = _plt()
    mc = results["multiclass"]
    fig, axes = plt.subplots(1, 2, figsize=(8.0, 3.8), squeeze=False)
    for ax, m in zip(axes[0], ("svm", "rls")):
        mats = [np.asarray(d["confusion"]) for d in mc["runs"] if d["machine"] == m]
        k = len(mc["classes"])
        total = np.sum(mats, axis=0) if mats else np.zeros((k, k), int)
        _draw_confusion(ax, total, mc["classes"], f"{MACHINE_NAME[m]}, D={mc['D']}, all runs")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_report(results: dict[str, Any], out_dir: str | Path, *, figures: bool = True) -> Path:
    """Write report.md (and the PNG figures) into ``out_dir``; return the report's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    made: list[str] = []
    if figures and results["binary"]:
        figure6(results, out / "figure6.png")
        figure7(results, out / "figure7.png")
        confusion_binary(results, out / "confusion_binary.png")
        made += ["figure6.png", "figure7.png", "confusion_binary.png"]
        if (results.get("multiclass") or {}).get("runs"):
            confusion_multiclass(results, out / "confusion_multiclass.png")
            made.append("confusion_multiclass.png")
    path = out / "report.md"
    path.write_text(render_markdown(results, made))
    return path
