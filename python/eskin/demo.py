"""`make demo`: the whole eskin story on the built-in simulated campaign, in a few minutes.

1. simulate a campaign (SIMULATED data, :func:`eskin.simulate`);
2. train a 3-class model with ``eskin train``'s default recipe (tensor-SVM, or tensor-RLS,
   selected by participant-grouped cross-validation) on some participants
   (:func:`eskin.learn.training.train_model`), save it and export it to a ``.eskin`` file
   (:func:`eskin.deploy.export.export_model`);
3. write the held-out participants' recordings as a replay file
   (:func:`eskin.data.replay.write_replay_file`) and start the firmware simulator ``eskin-fw-sim`` on
   it with the model on board: it publishes a pseudo-terminal and streams the recordings at
   ``speed`` x real time, sending its own DECISION frames;
4. listen on the pseudo-terminal (:class:`eskin.link.LinkListener`) with the same model on the
   host, recording the received stream to a campaign file (one recording per replay segment);
5. compare the controller's live decisions, the host's live decisions and the offline Python
   predictions on the same recordings: the TouchModel (its own float64 machines, not the exported
   file) run over the replay stream touch by touch (``eskin.preprocess.TouchDetector`` with the
   model's detector settings), exactly what a controller sees. Every touch must get the same
   window and label from all three, and so the per-recording confusion matrices are equal (one
   decision per recording: the touch on its true contact interval). The per-recording batch
   predictions (``TouchModel.predict_recordings``: one window per isolated recording, chosen by the
   detector's ``select`` rule, which can merge several touches) are shown beside them for
   reference; they need not match touch by touch, since a live controller cannot know where a
   recording ends.

:func:`run_demo` does the work and returns a :class:`DemoResult`; ``eskin demo`` prints it.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from eskin.errors import DemoError
from eskin.link.scoring import assign_decisions, confusion_matrix, score_decisions

__all__ = ["DemoError", "DemoResult", "assign_decisions", "confusion_matrix",
           "offline_stream_decisions", "run_demo", "start_fw_sim"]

#: `eskin evaluate` of the demo's recipe (eskin train's defaults, tensor-SVM) on the demo's own
#: campaign (its defaults: 20 simulated participants, seed 0), in 5 participant-disjoint folds
#: (each trained on 16 participants and tested on the other 4), measured with eskin 0.1.0 by
#:   eskin simulate -o sim20.h5 --participants 20 --seed 0
#:   eskin evaluate sim20.h5 --out ev --folds 5
#: accuracy 81.7 %, 95 % interval [76.7, 86.2] % (bootstrap over participants), 240 recordings
#: (the training windows read at the stream's stride, the hold time chosen per fold, the
#: calibrated rule; its live figure: 81.2 %, 1.06 touches per recording).
#: The demo prints it beside its live error, which comes from one split (fewer people trained).
EVALUATE_REFERENCE = {
    "command": "eskin simulate -o sim20.h5 --participants 20 --seed 0; "
               "eskin evaluate sim20.h5 --out ev --folds 5",
    "participants": 20, "seed": 0, "machine": "svm", "folds": 5, "recordings": 240,
    "error": 1 - 0.817, "error_ci95": (1 - 0.862, 1 - 0.767),
}

# decisions of one source per replay segment: label index (-1: no decision), values, dont_know
SOURCES = ("controller (live)", "host (live)", "offline (Python)")
BATCH = "offline batch (per recording)"


@dataclass
class DemoResult:
    class_names: list[str]
    true_labels: np.ndarray  # (n,) per held-out recording
    labels: dict[str, np.ndarray]  # source -> (n,) label index, -1 = no decision
    values: dict[str, np.ndarray]  # source -> (n, n_machines), nan where no decision
    confusion: dict[str, np.ndarray]  # source -> (k, k + 1) counts; last column: no decision
    error_rates: dict[str, float]
    agreement: dict[str, dict[str, Any]]  # "a vs b" -> n, equal, max_value_diff
    stats: Any  # eskin.link.LinkStats of the live run
    fw_stats: dict[str, Any]  # the simulator's final STATS line
    files: dict[str, Path]
    timings: dict[str, float]
    agree: bool = True
    disagreement: str = ""
    summary: list[str] = field(default_factory=list)
    #: the live (controller) error on the held-out people with its 95 % interval, and the
    #: `eskin evaluate` figure of the same recipe (None when the demo's settings differ from
    #: those it was measured with)
    held_out: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------- pieces


def offline_stream_decisions(model: Any, samples: np.ndarray) -> list:
    """The TouchModel's Python decisions over a stream (n, rows, cols), touch by touch, as
    :class:`eskin.link.Decision` objects with ``source="offline"``: the detector the controller
    runs (``eskin.preprocess.TouchDetector``, the model's settings) and the model's own machines."""
    from eskin.link.listener import Decision, load_host_classifier

    clf = load_host_classifier(model, backend="python")
    x = np.asarray(samples).reshape(len(samples), -1)
    out = []
    for t in clf.push(x) + clf.flush():
        out.append(Decision("offline", t.start, t.stop, clf.class_names[t.label_index]
                            if t.label_index >= 0 else None, t.label_index, t.values,
                            t.dont_know, t.stop))
    return out


def start_fw_sim(args: list[str], timeout: float = 20.0) -> tuple[subprocess.Popen, str]:
    """Start ``eskin-fw-sim`` with ``args``; return the process and the pty path it published."""
    from eskin._paths import find_executable
    from eskin.link.simulated_controllers import published_pty

    exe = find_executable("eskin-fw-sim")
    proc = subprocess.Popen([str(exe), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        return proc, published_pty(proc, timeout, str(exe))
    except OSError as exc:
        raise DemoError(str(exc)) from None


def finish_fw_sim(proc: subprocess.Popen, timeout: float = 10.0) -> dict[str, Any]:
    """Wait for the simulator to exit; return its final ``STATS {json}`` (empty if none)."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.terminate()
        out, err = proc.communicate(timeout=5)
    stats: dict[str, Any] = {}
    for line in (out or "").splitlines():
        if line.startswith("STATS "):
            try:
                stats = json.loads(line[6:])
            except json.JSONDecodeError:
                pass
    if proc.returncode not in (0, None, -15):
        raise DemoError(f"eskin-fw-sim exited with code {proc.returncode}: {(err or '').strip()}")
    return stats


# --------------------------------------------------------------------------- the demo


def run_demo(
    out: str | os.PathLike[str],
    *,
    participants: int = 20,
    test_participants: int = 8,
    speed: float = 0.0,
    seed: int = 0,
    n_jobs: int = 2,
    quick: bool = False,
    machine: str = "svm",
    max_recordings: Optional[int] = None,
    gap_s: float = 0.5,
    log: Optional[Callable[[str], None]] = None,
    controller: str = "sim",
    live_page: Any = None,
) -> DemoResult:
    """Run the demo in folder ``out`` (created; its files are replaced). See the module doc.

    ``participants`` are simulated, the last ``test_participants`` of them held out and streamed
    (all their recordings, or ``max_recordings`` of them spread over the classes) at ``speed`` x
    real time (0: as fast as the host reads, which loses nothing); ``machine`` is "svm"
    (tensor-SVM) or "rls" (tensor-RLS); ``quick`` trains on a 2x2x2 grid instead of the
    paper's 135 configurations. ``controller`` is "sim" (``eskin-fw-sim``) or "qemu": the
    controller's firmware on QEMU's Cortex-M4F board (docs/mcu.md), in real time, the model
    trained to fit the part (window <= 0.5 s); ``live_page``: a LiveState (eskin.link.web) fed too.
    """
    from eskin.data.campaign import load_campaign
    from eskin.data.replay import write_replay_file

    say = log or (lambda m: None)
    speed = _check_demo_args(participants, test_participants, speed, controller)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = demo_files(out)
    timings: dict[str, float] = {}

    # 1. simulate
    t0 = time.perf_counter()
    _simulate_campaign(files["campaign"], participants, seed, n_jobs, say)
    timings["simulate"] = time.perf_counter() - t0
    camp = load_campaign(files["campaign"])
    train_idx, test_idx = _held_out_split(camp, test_participants, max_recordings)

    # 2. train, save, export
    t0 = time.perf_counter()
    n_train_parts = len(np.unique(camp.participant)) - test_participants
    say(f"[bold]2/5[/] training a 3-class tensor-{machine.upper()} (eskin train's recipe) on "
        f"{n_train_parts} participants ({len(train_idx)} recordings"
        f"{', quick grid' if quick else ''})")
    model, compiled = _train_and_export(camp.subset(train_idx), files, machine, quick, seed, say,
                                        fit_device=controller == "qemu")
    timings["train"] = time.perf_counter() - t0
    names = list(model.classes)

    rf = write_replay_file(camp, test_idx, files["replay"], gap_s=gap_s, seed=seed)
    if list(rf.class_names) != list(camp.modalities):
        raise DemoError("replay class names differ from the campaign's")
    offline, decisions, stats, fw_stats = _offline_and_live(
        model, compiled, camp, rf, test_idx, files, controller, speed, timings, say, live_page)

    # 5. compare
    per_source = {SOURCES[0]: [d for d in decisions if d.source == "controller"],
                  SOURCES[1]: [d for d in decisions if d.source == "host"],
                  SOURCES[2]: offline.touches}
    cmp = compare_sources(per_source, offline, rf.segments, len(names), len(test_idx))
    timings["total"] = sum(timings.values())
    held_out = _held_out_figures(camp, rf, offline.true, cmp.labels[SOURCES[0]], len(names),
                                 participants, seed, machine, quick)
    summary = _summary(camp, train_idx, test_idx, speed, stats, fw_stats, len(offline.touches),
                       cmp.extras[SOURCES[0]], timings, files)
    summary[0:0] = [_held_out_line(held_out), *_live_lines(per_source[SOURCES[0]], rf, held_out)]
    result = DemoResult(
        class_names=names, true_labels=offline.true, labels=cmp.labels, values=cmp.values,
        confusion=cmp.confusion, error_rates=cmp.error_rates, agreement=cmp.agreement,
        stats=stats, fw_stats=fw_stats, files=files, timings=timings, agree=not cmp.problems,
        disagreement="; ".join(cmp.problems), summary=summary, held_out=held_out,
    )
    _write_report(files["report"], result)
    say("[bold]5/5[/] comparing live and offline decisions")
    return result


def _simulate_campaign(path: Path, participants: int, seed: int, n_jobs: int,
                       say: Callable[[str], None]) -> None:
    """Step 1: the SIMULATED campaign, with a progress bar on a terminal."""
    from eskin._progress import progress_bar
    from eskin.data.simulator import simulate

    say(f"[bold]1/5[/] simulating {participants} participants x 12 recordings "
        f"(SIMULATED data) -> {path}")
    with progress_bar() as bar:
        task = bar.add_task("simulating", total=None)
        simulate(path, participants=participants, seed=seed, n_jobs=n_jobs, overwrite=True,
                 progress=lambda done, total: bar.update(task, completed=done, total=total))


def _offline_and_live(model: Any, compiled: Any, camp: Any, rf: Any, test_idx: np.ndarray,
                      files: dict[str, Path], controller: str, speed: float,
                      timings: dict[str, float], say: Callable[[str], None],
                      live_page: Any = None) -> tuple:
    """Steps 3-4: the offline reference over the replay stream, then the live run through the
    controller (eskin-fw-sim or the QEMU board); their timings go into ``timings``."""
    t0 = time.perf_counter()
    say(f"      offline reference: the Python model touch by touch over the same "
        f"{len(rf.segments)} recordings")
    offline = _offline_reference(model, camp, rf, test_idx)
    timings["offline"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if controller == "qemu":
        decisions, stats, fw_stats = _stream_and_listen_qemu(camp, rf, files, compiled, say,
                                                             live_page)
    else:
        decisions, stats, fw_stats = _stream_and_listen(camp, rf, files, compiled, speed, say,
                                                        live_page)
    timings["live"] = time.perf_counter() - t0
    return offline, decisions, stats, fw_stats


def _held_out_figures(camp: Any, rf: Any, true: np.ndarray, live: np.ndarray, n_classes: int,
                      participants: int, seed: int, machine: str,
                      quick: bool) -> dict[str, Any]:
    """The controller's live error on the held-out recordings with a 95 % interval (bootstrap
    over the held-out participants, as eskin evaluate's), and EVALUATE_REFERENCE when the demo
    ran the campaign and recipe it was measured on."""
    from eskin.learn.evaluation import group_bootstrap_ci

    people = np.asarray(camp.participant)[rf.segments["recording"].astype(np.int64)]
    pred = np.where(live >= 0, live, (true + 1) % n_classes)  # no decision counts as wrong
    ci = group_bootstrap_ci(true, pred, people, n_classes, seed=seed)["accuracy"]
    ref = EVALUATE_REFERENCE
    same = (participants, seed, machine, quick) == (ref["participants"], ref["seed"],
                                                   ref["machine"], False)
    return {"live_error": float(np.mean(live != true)), "live_error_ci95": [1 - ci[1], 1 - ci[0]],
            "recordings": int(len(true)), "participants": int(len(np.unique(people))),
            "evaluate": dict(ref) if same else None}


def _live_lines(decisions: list, rf: Any, held_out: dict[str, Any]) -> list[str]:
    """The controller's live path in the words ``eskin listen --replay`` and ``eskin evaluate``
    use (touches, splits, misses, spurious touches, "don't know" and the error on the decided
    and the flagged recordings); also kept in ``held_out["live"]``."""
    live = score_decisions(decisions, rf)
    held_out["live"] = live[0].as_dict() if live else None
    return ["live " + sc.live_line() for sc in live]


def _held_out_line(h: dict[str, Any]) -> str:
    """The live error beside eskin evaluate's figure for the same recipe and campaign."""
    lo, hi = h["live_error_ci95"]
    line = (f"held-out error: live (controller) {h['live_error']:.1%} [{lo:.1%}, {hi:.1%}] on "
            f"{h['recordings']} recordings of {h['participants']} unseen participants; ")
    ref = h["evaluate"]
    if ref is None:
        return line + ("`eskin evaluate CAMPAIGN --out DIR` measures this recipe in "
                       "participant-disjoint folds")
    elo, ehi = ref["error_ci95"]
    return line + (f"eskin evaluate, same recipe and campaign, {ref['folds']} "
                   f"participant-disjoint folds: {ref['error']:.1%} [{elo:.1%}, {ehi:.1%}] on "
                   f"all {ref['recordings']} recordings (95 % intervals, bootstrap over "
                   f"participants)")


def _check_demo_args(participants: int, test_participants: int, speed: float,
                     controller: str = "sim") -> float:
    """Refuse impossible settings; the replay speed the run uses (the QEMU board samples in
    real time)."""
    if controller not in ("sim", "qemu"):
        raise ValueError(f"controller must be 'sim' or 'qemu', got {controller!r}")
    if controller == "qemu":
        speed = 1.0
    if participants < 2 or not 1 <= test_participants < participants:
        raise ValueError(f"need participants >= 2 and 1 <= test_participants < participants, got "
                         f"{participants} and {test_participants}")
    if not speed >= 0:
        raise ValueError(f"speed must be >= 0 (0: as fast as the host reads), got {speed}")
    return speed


def demo_files(out: Path) -> dict[str, Path]:
    """Every file the demo writes into ``out``, by role."""
    return {"campaign": out / "campaign.h5", "model": out / "model.joblib",
            "eskin": out / "model.eskin", "replay": out / "test.eskr",
            "live": out / "live.h5", "decisions": out / "decisions.jsonl",
            "report": out / "report.json"}


def _held_out_split(camp: Any, test_participants: int,
                    max_recordings: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out recordings: the last ``test_participants`` are held out (every
    k-th of their recordings when ``max_recordings`` asks for a shorter live run)."""
    parts = np.unique(camp.participant)
    is_test = np.isin(camp.participant, parts[-test_participants:])
    train_idx, test_idx = np.flatnonzero(~is_test), np.flatnonzero(is_test)
    if max_recordings is not None:  # a shorter live run: every k-th held-out recording
        if max_recordings < 1:
            raise ValueError(f"max_recordings must be >= 1, got {max_recordings}")
        step = max(1, len(test_idx) // max_recordings)
        test_idx = test_idx[::step][:max_recordings]
    return train_idx, test_idx


def _train_and_export(train: Any, files: dict[str, Path], machine: str, quick: bool,
                      seed: int, say: Callable[[str], None],
                      fit_device: bool = False) -> tuple[Any, Any]:
    """Train the model with eskin train's default recipe, save it, export the .eskin file and
    load that back as the compiled model the host runs. ``fit_device``: a touch window of at
    most 0.5 s and D = 20 (the MCU preset of docs/mcu.md), checked against the Cortex-M4F's
    budget."""
    try:
        from eskin._progress import progress_bar
        from eskin.deploy import save_model
        from eskin.deploy.export import CompiledModel, export_model
        from eskin.learn.training import train_model
    except ImportError as exc:
        raise DemoError(
            f"a part of the pipeline is missing from this installation ({exc})") from None
    device = {}
    if fit_device:
        from eskin.signal.preprocess import WindowConfig

        device = {"D": 20, "window_config": WindowConfig(max_window_s=0.5)}
    with progress_bar() as bar:  # shown on a terminal
        bar.add_task("training (cv search)", total=None)
        model = train_model(train, machine=machine, quick=quick, seed=seed, n_jobs=1, **device)
    save_model(model, files["model"])
    export_model(model, files["eskin"])
    compiled = CompiledModel(files["eskin"])
    if fit_device:
        from eskin.deploy.target import device_budget

        budget = device_budget(compiled, "cortex-m4")
        if not budget.fits:
            raise DemoError("the model does not fit the Cortex-M4F: "
                            + "; ".join(budget.report()))
    say(f"      classes {list(model.classes)}; exported {files['eskin']} "
        f"({files['eskin'].stat().st_size} bytes, {compiled.n_support} support patterns)")
    return model, compiled


@dataclass
class OfflineReference:
    """The Python model's decisions on the streamed recordings, and their true classes."""

    touches: list  # touch by touch over the replay stream (Decision, source "offline")
    batch_labels: np.ndarray  # per isolated recording (batch windows)
    batch_values: np.ndarray
    true: np.ndarray  # true class per replay segment, as an index into the model's classes
    n_values: int


def _offline_reference(model: Any, camp: Any, rf: Any, test_idx: np.ndarray) -> OfflineReference:
    """Offline predictions on the same recordings (Python): touch by touch over the replay
    stream, and per isolated recording (batch windows), for reference."""
    names = list(model.classes)
    n_values = 1 if len(names) == 2 else len(names)
    touches = offline_stream_decisions(model, np.asarray(rf.samples))
    batch = model.predict_recordings(camp, test_idx)
    batch_labels = np.array([names.index(p["label"]) for p in batch], np.int64)
    batch_values = np.array([p["decision_values"] for p in batch], float).reshape(-1, n_values)
    # model classes are names; map the campaign's modality ids onto them
    true = np.array([names.index(camp.modalities[t]) for t in rf.segments["label"]], np.int64)
    return OfflineReference(touches, batch_labels, batch_values, true, n_values)


def _stream_and_listen(camp: Any, rf: Any, files: dict[str, Path], compiled: Any,
                       speed: float, say: Callable[[str], None],
                       live_page: Any = None) -> tuple[list, Any, dict]:
    """Stream the replay file through ``eskin-fw-sim`` (the model on board) and listen on its
    pseudo-terminal with the compiled model, recording the stream and the decisions. Returns
    the live decisions, the link statistics and the simulator's final statistics."""
    stream_s = rf.n_samples / rf.sample_rate_hz
    pace = (f"at {speed:g}x: ~{stream_s / speed:.0f} s" if speed > 0
            else "as fast as the host reads")
    say(f"[bold]3/5[/] eskin-fw-sim streams {len(rf.segments)} held-out recordings "
        f"({stream_s:.0f} s of signal {pace}) with the model on board")
    link_path = files["campaign"].parent / "skin.tty"
    proc, pty = start_fw_sim([str(files["replay"]), "--model", str(files["eskin"]),
                              "--speed", f"{speed:g}", "--tick", "10", "--wait-start",
                              "--hold", "1", "--tx-buffer", str(1 << 20),
                              "--link", str(link_path), "--quiet"])
    try:
        decisions, stats = _listen(
            pty, camp, rf, files, compiled, say,
            "SIMULATED campaign streamed over the eskin-fw-sim pseudo-terminal by `eskin demo`",
            duration=max(60.0, 4 * stream_s / (speed or 10.0)), live_page=live_page)
    finally:
        fw_stats = finish_fw_sim(proc)
    return decisions, stats, fw_stats


def _listen(pty: str, camp: Any, rf: Any, files: dict[str, Path], compiled: Any,
            say: Callable[[str], None], description: str, duration: float,
            live_page: Any = None) -> tuple[list, Any]:
    """Listen on the controller's pty with the compiled model until the stream ends, recording
    the stream and writing every decision (and the final statistics) to decisions.jsonl; the
    events also go to ``live_page`` (a LiveState) when given. Returns the live decisions and
    the link statistics."""
    from eskin.link.listener import Decision, LinkListener

    decisions: list[Decision] = []
    say(f"[bold]4/5[/] listening on {pty} (host model: compiled), recording to "
        f"{files['live']}")
    with LinkListener(pty, model=compiled, replay=rf, record=files["live"], overwrite=True,
                      record_source="simulated", stats_interval=None,
                      record_attrs={"description": description}) as link:
        events = link.events(until_eof=True, duration=duration)
        if live_page is not None:
            live_page.port, live_page.replay = pty, rf
            events = live_page.observed(events, lambda: link.stats)
        with open(files["decisions"], "w", encoding="utf-8") as jf:
            for ev in events:
                if isinstance(ev, Decision):
                    decisions.append(ev)
                    jf.write(json.dumps(ev.as_dict()) + "\n")
                    if ev.source == "controller":
                        say(_decision_line(ev, camp, rf))
            stats = link.stats
            jf.write(json.dumps({"type": "stats", **stats.as_dict()}) + "\n")
    return decisions, stats


def _stream_and_listen_qemu(camp: Any, rf: Any, files: dict[str, Path], compiled: Any,
                            say: Callable[[str], None],
                            live_page: Any = None) -> tuple[list, Any, dict]:
    """The live part against the controller's firmware on QEMU (eskin.link.qemu_controller):
    the model in its flash slot, the replay as its ADC, the host listening on its pty as it
    would on eskin-fw-sim's. Returns the live decisions, the link statistics and the board's
    console lines."""
    from eskin.link.qemu_controller import QemuController, QemuControllerError

    stream_s = rf.n_samples / rf.sample_rate_hz
    say(f"[bold]3/5[/] the controller firmware on QEMU (mps2-an386, Cortex-M4F) streams "
        f"{len(rf.segments)} held-out recordings ({stream_s:.0f} s of signal in real time) with "
        f"the model in its flash")
    qc = QemuController(files["eskin"], files["replay"], files["campaign"].parent / "qemu")
    try:
        pty = qc.start()
    except QemuControllerError as exc:
        raise DemoError(str(exc)) from None
    try:
        # a busy host slows the emulated board down (docs/mcu.md): generous time
        decisions, stats = _listen(
            pty, camp, rf, files, compiled, say,
            "SIMULATED campaign streamed by the controller firmware on QEMU by `eskin demo`",
            duration=600.0 + 10 * stream_s, live_page=live_page)
    finally:
        console = qc.stop()
    return decisions, stats, {"controller": "qemu", "console": console.splitlines()[-3:]}


def _decision_line(ev: Any, camp: Any, rf: Any) -> str:
    """One controller decision as the demo prints it: time, replay segment, label."""
    seg_start = rf.segments["start"].astype(np.int64)
    seg_stop = seg_start + rf.segments["length"].astype(np.int64)
    ov = np.minimum(seg_stop, ev.offset_sample) - np.maximum(seg_start, ev.onset_sample)
    k = int(np.argmax(ov))
    true_k = camp.modalities[int(rf.segments[k]["label"])]
    where = f"recording {k + 1:2d} ({true_k})" if ov[k] > 0 else "between recordings"
    return (f"      {ev.onset_sample / rf.sample_rate_hz:7.2f} s  {where}: "
            f"controller says {ev.label}{' (?)' if ev.dont_know else ''}")


@dataclass
class Comparison:
    """The sources' decisions per replay segment and how far they agree."""

    labels: dict[str, np.ndarray]
    values: dict[str, np.ndarray]
    extras: dict[str, int]  # decisions not kept (other touches), per source
    confusion: dict[str, np.ndarray]
    error_rates: dict[str, float]
    agreement: dict[str, dict[str, Any]]
    problems: list[str]


def compare_sources(per_source: dict[str, list], offline: OfflineReference, segments: np.ndarray,
                    n_classes: int, n_streamed: int) -> Comparison:
    """Assign every source's decisions to the replay segments; confusion matrices, error rates
    and the pairwise agreement of the controller, the host and the offline Python model."""
    labels: dict[str, np.ndarray] = {}
    values: dict[str, np.ndarray] = {}
    extras: dict[str, int] = {}
    for key, ds in per_source.items():
        lab, val, _, extra = assign_decisions(ds, segments, offline.n_values)
        labels[key], values[key], extras[key] = lab, val, sum(extra)
    labels[BATCH], values[BATCH] = offline.batch_labels, offline.batch_values
    true = offline.true
    confusion = {s2: confusion_matrix(true, labels[s2], n_classes) for s2 in (*SOURCES, BATCH)}
    error_rates = {s2: float(np.mean(labels[s2] != true)) for s2 in (*SOURCES, BATCH)}
    agreement: dict[str, dict[str, Any]] = {}
    problems: list[str] = []
    for a, b in ((SOURCES[0], SOURCES[2]), (SOURCES[1], SOURCES[2]), (SOURCES[0], SOURCES[1])):
        agreement[f"{a} vs {b}"] = _pair_agreement(a, b, per_source, labels, problems)
    for s2 in SOURCES[:2]:
        if not np.array_equal(confusion[s2], confusion[SOURCES[2]]):
            problems.append(f"the {s2} and offline confusion matrices differ")
    eqb = labels[SOURCES[0]] == labels[BATCH]
    agreement[f"{SOURCES[0]} vs {BATCH}"] = {
        "touches": f"{len(per_source[SOURCES[0]])} / {n_streamed}", "equal_touches": "-",
        "n": len(eqb), "equal": int(eqb.sum()), "max_value_diff": float("nan")}
    return Comparison(labels, values, extras, confusion, error_rates, agreement, problems)


def _pair_agreement(a: str, b: str, per_source: dict[str, list],
                    labels: dict[str, np.ndarray], problems: list[str]) -> dict[str, Any]:
    """How far sources ``a`` and ``b`` agree, touch by touch and per segment; appends what
    differs to ``problems``."""
    ta, tb = per_source[a], per_source[b]
    same_touches = [(d.onset_sample, d.offset_sample) for d in ta] == [
        (d.onset_sample, d.offset_sample) for d in tb]
    touch_eq = sum(1 for x, y in zip(ta, tb) if (x.onset_sample, x.offset_sample,
                                                x.label_index) == (y.onset_sample,
                                                                   y.offset_sample,
                                                                   y.label_index))
    diffs = [np.max(np.abs(np.subtract(x.values, y.values))) for x, y in zip(ta, tb)
             if len(x.values) == len(y.values) and x.values]
    eq = labels[a] == labels[b]
    if not same_touches or touch_eq != len(ta):
        problems.append(f"{a} vs {b}: {len(ta)} and {len(tb)} touches, {touch_eq} with "
                        f"the same window and label")
    if not eq.all():
        bad = np.flatnonzero(~eq)
        problems.append(f"{a} vs {b}: {len(bad)} of {len(eq)} recordings differ (replay "
                        f"segments {bad.tolist()[:10]})")
    return {"touches": f"{len(ta)} / {len(tb)}", "equal_touches": touch_eq,
            "n": len(eq), "equal": int(eq.sum()),
            "max_value_diff": float(max(diffs)) if diffs else 0.0}


def _summary(camp: Any, train_idx: np.ndarray, test_idx: np.ndarray, speed: float, stats: Any,
             fw_stats: dict[str, Any], n_offline: int, extra: int, timings: dict[str, float],
             files: dict[str, Path]) -> list[str]:
    """The demo's closing lines: what ran, the decisions and losses, latency, timings.
    ``extra``: the controller's decisions on other touches than a recording's own."""
    lost = stats.lost_samples + stats.rejected
    summary = [
        f"SIMULATED campaign: {len(camp)} recordings; trained on {len(train_idx)}, streamed "
        f"{len(test_idx)} held-out recordings over a real pseudo-terminal "
        f"{f'at {speed:g}x' if speed > 0 else 'as fast as the host reads'}.",
        f"live decisions: {stats.decisions_controller} from the controller, "
        f"{stats.decisions_host} from the host, {n_offline} offline: "
        f"{stats.decisions_controller - extra} recordings decided, "
        f"{extra} other touches (a recording can hold several); link losses: {lost} "
        f"(lost samples {stats.lost_samples}, of which the controller dropped "
        f"{stats.controller_dropped_samples}; rejected frames {stats.rejected}).",
    ]
    if fw_stats:
        lat = fw_stats.get("decision_latency_us") or fw_stats.get("latency_us") or {}
        if isinstance(lat, dict) and lat:
            summary.append("controller decision latency (us): " + ", ".join(
                f"{k2} {v}" for k2, v in lat.items()))
    summary.append("timings (s): " + ", ".join(f"{k2} {v:.1f}" for k2, v in timings.items()))
    summary.append(f"files in {files['campaign'].parent}: "
                   + ", ".join(p.name for p in files.values()))
    return summary


def _write_report(path: Path, result: DemoResult) -> None:
    """report.json: confusion matrices, error rates, agreement, link and simulator statistics,
    timings."""
    path.write_text(json.dumps({
        "class_names": result.class_names,
        "source": "simulated",
        "confusion": {s2: c.tolist() for s2, c in result.confusion.items()},
        "error_rates": result.error_rates,
        "agreement": result.agreement,
        "agree": result.agree,
        "disagreement": result.disagreement,
        "link_stats": result.stats.as_dict(),
        "fw_sim_stats": result.fw_stats,
        "timings_s": result.timings,
        "held_out": result.held_out,
    }, indent=2, default=str))
