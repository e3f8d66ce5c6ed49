"""CLI commands: listen, demo.

``eskin listen PORT`` shows the controller's live stream (decisions, link statistics, taxel
activity) with rich.live on a terminal and as plain lines otherwise; ``eskin demo`` runs the whole
pipeline (eskin.demo) and prints its tables. Errors a user can cause exit with code 2 and a
one-line message.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import time
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple, Optional

import typer


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    """Turn the errors a user can cause into a clear message and exit code 2."""
    from eskin._files import error_line

    try:
        yield
    except (ValueError, OSError) as exc:  # SerialPortError is an OSError
        typer.echo(f"error: {error_line(exc)}", err=True)
        raise typer.Exit(2) from None


# --------------------------------------------------------------------------- rendering


def report_console() -> Any:
    """A rich console for tables and lines that end up in a terminal or in a file: on a
    terminal, its width; otherwise (a pipe, a log) 200 columns and no wrapping of long lines,
    instead of rich's 80 columns (the COLUMNS variable still wins)."""
    import os

    from rich.console import Console

    if sys.stdout.isatty() or os.environ.get("COLUMNS"):
        return Console()
    return Console(width=200, soft_wrap=True)


def jsonl_line(obj: Any) -> str:
    """One strict JSON line (RFC 8259: no NaN or Infinity): a non-finite number is null."""

    def finite(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: finite(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [finite(x) for x in v]
        return v

    return json.dumps(finite(obj), allow_nan=False) + "\n"


def _fmt_values(values: Any) -> str:
    return "[" + ", ".join(f"{v:+.3f}" for v in values) + "]"


#: what the "?" after a label means, wherever a decision is shown
DONT_KNOW_NOTE = ("? = don't know: the model's confidence in the label is below its threshold "
                  "(calibrated rule), or no machine, or more than one, claimed the touch (the "
                  "paper's rule, for models trained with --decision paper)")


def decision_line(d: Any, rate: float, truth: Any = None) -> str:
    """One plain line for a decision; ``truth(d)`` gives the true class (with --replay)."""
    label = d.label if d.label is not None else f"#{d.label_index}"
    dk = " (don't know)" if d.dont_know else ""
    lost = f" lost={d.lost_samples}" if d.lost_samples else ""
    true = f" true={truth(d)}" if truth is not None else ""
    return (f"decision {d.source:<10} onset={d.onset_sample} ({d.onset_sample / rate:.2f} s) "
            f"label={label}{dk}{true} values={_fmt_values(d.values)}{lost}")


def replay_truth(listener: Any) -> Any:
    """The function giving a decision's true class from the listener's replay file (the class
    of the recording its window overlaps most; "-" in a gap), or None without a replay."""
    from eskin.link.scoring import segment_of

    replay = listener.replay
    if replay is None:
        return None
    names = list(replay.class_names)

    def truth(d: Any) -> str:
        k = segment_of(replay, d.onset_sample, d.offset_sample, listener.replay_offset)
        label = int(replay.segments["label"][k]) if k >= 0 else -1
        return names[label] if 0 <= label < len(names) else "-"

    return truth


def loss_lines(score: Any) -> list[str]:
    """The recordings whose samples the link lost: their decisions rest on incomplete data, so
    they are named, and the score is also given without them."""
    if not score.lossy:
        return []
    names = list(score.class_names)
    shown = [f"{k} ({n} samples lost; {'decided ' + names[lab] if lab >= 0 else 'no decision'}"
             f"{', right' if right else ''})" for k, n, lab, right in score.lossy[:8]]
    more = f", and {len(score.lossy) - 8} more" if len(score.lossy) > 8 else ""
    return [f"  {len(score.lossy)} recording(s) lost samples on the link, so their decisions "
            f"are not a fair score of the model: segment {', '.join(shown)}{more}",
            f"  without them: {score.correct_without_losses}/{score.recordings_without_losses} "
            f"right ({100 * score.accuracy_without_losses:.1f} %); eskin-fw-sim --speed 0 "
            f"(as fast as the host reads) loses nothing"]


def score_lines(score: Any) -> list[str]:
    """Accuracy and confusion matrix of one source against the replay's labels, as text."""
    names = list(score.class_names)
    head = (f"{score.source}: {score.correct}/{score.recordings} recordings right "
            f"({100 * score.accuracy:.1f} %), {score.dont_know} don't know, "
            f"{score.no_decision} without a decision")
    lines = [head, "  live " + score.live_line().split(": ", 1)[1], *loss_lines(score)]
    cols = [*names, "none"]
    first = max([len(n) for n in names] + [len("true \\ decided")])
    width = max(len(c) for c in cols)
    lines.append("  " + "true \\ decided".ljust(first) + "".join(f" {c:>{width}}" for c in cols))
    for name, row in zip(names, score.confusion):
        lines.append("  " + name.ljust(first) + "".join(f" {int(v):>{width}}" for v in row))
    return lines


def stats_line(s: Any) -> str:
    return (f"stats frames={s.frames} bytes={s.bytes} samples={s.samples} "
            f"crc_errors={s.crc_errors} malformed={s.malformed} oversize={s.oversize} "
            f"sequence_gaps={s.sequence_gaps} lost_frames={s.lost_frames} "
            f"lost_samples={s.lost_samples} lost_decisions={s.lost_decisions} "
            f"absurd_frames={s.absurd_frames} "
            f"unexpected_frames={s.unexpected_frames} "
            f"overrun_frames={s.overrun_frames} "
            f"controller_dropped={s.controller_dropped_samples} "
            f"controller_overruns={s.controller_overrun_events} "
            f"controller_decisions_dropped={s.controller_decisions_dropped} "
            f"controller_frames_dropped={s.controller_frames_dropped} "
            f"decisions controller={s.decisions_controller} host={s.decisions_host}")


def stats_table(s: Any, title: str = "link statistics") -> Any:
    from rich.table import Table

    t = Table(title=title, show_header=False, box=None, pad_edge=False)
    t.add_column(style="bold")
    t.add_column(justify="right")
    rows = [
        ("elapsed", f"{s.elapsed_s:.1f} s"),
        ("bytes / frames", f"{s.bytes} / {s.frames}"),
        ("samples", f"{s.samples} ({s.rate_samples_per_s:.0f}/s)"),
        ("CRC errors", str(s.crc_errors)),
        ("malformed / oversize", f"{s.malformed} / {s.oversize}"),
        ("absurd frames (refused fields)", str(s.absurd_frames)),
        ("unexpected frames (host commands)", str(s.unexpected_frames)),
        ("sequence gaps (frames)", f"{s.sequence_gaps} ({s.lost_frames})"),
        ("lost samples", str(s.lost_samples)),
        ("DATA frames flagged overrun", str(s.overrun_frames)),
        ("controller dropped samples", str(s.controller_dropped_samples)),
        ("controller overrun events", str(s.controller_overrun_events)),
        ("controller rx errors", str(s.controller_rx_errors)),
        ("controller faults injected", str(s.controller_faults_injected)),
        ("controller pacing p50 / p99", f"{s.controller_pacing_p50_us:.0f} / "
                                        f"{s.controller_pacing_p99_us:.0f} us"),
        ("controller state", s.controller_state),
        ("decisions controller / host", f"{s.decisions_controller} / {s.decisions_host}"),
        ("controller decisions sent / dropped", f"{s.controller_decisions_sent} / "
                                                f"{s.controller_decisions_dropped}"),
        ("decisions sent but not received", str(s.lost_decisions)),
        ("controller frames dropped (STATUS, INFO, PONG)", str(s.controller_frames_dropped)),
        ("disconnects / reconnects", f"{s.disconnects} / {s.reconnects}"),
    ]
    if s.recordings:
        rows.append(("recordings written", str(s.recordings)))
    for k, v in rows:
        t.add_row(k, v)
    return t


def heat_table(activity: Any, title: str = "taxel activity (RMS counts, last 0.2 s)") -> Any:
    """A rows x cols heat map of recent energy, coloured on a log scale."""
    import math

    from rich.table import Table
    from rich.text import Text

    t = Table(title=title, show_header=False, box=None, padding=(0, 0))
    if activity is None:
        t.add_column()
        t.add_row("(no data yet)")
        return t
    rows, cols = activity.shape
    for _ in range(cols):
        t.add_column(justify="center", min_width=7)
    top = max(float(activity.max()), 1.0)
    ramp = ["grey15", "grey30", "dark_blue", "blue", "dark_green", "green3", "yellow",
            "dark_orange", "red", "bright_red"]
    for r in range(rows):
        cells = []
        for c in range(cols):
            v = float(activity[r, c])
            level = 0 if v <= 0 else int(
                min(len(ramp) - 1, max(0.0, math.log10(max(v, 1.0)) / math.log10(max(top, 10.0)))
                * (len(ramp) - 1)))
            cells.append(Text(f"{v:6.0f} ", style=f"on {ramp[level]}"))
        t.add_row(*cells)
    return t


def decisions_table(decisions: Any, rate: float, truth: Any = None) -> Any:
    from rich.table import Table

    t = Table(title="decisions (latest last)", caption=DONT_KNOW_NOTE)
    for name in ("source", "onset s", "label", *(["true"] if truth else []), "values", "lost"):
        t.add_column(name)
    for d in decisions:
        label = d.label if d.label is not None else f"#{d.label_index}"
        if d.dont_know:
            label += " ?"
        true = [truth(d)] if truth is not None else []
        t.add_row(d.source, f"{d.onset_sample / rate:.2f}", label, *true, _fmt_values(d.values),
                  str(d.lost_samples or ""))
    return t


def _live_mode(duration: Optional[float], view: str) -> bool:
    """Check `eskin listen`'s --duration and --view; True for the rich live view."""
    if duration is not None and duration <= 0:
        typer.echo(f"error: --duration must be > 0 seconds, got {duration}", err=True)
        raise typer.Exit(2)
    if view not in ("auto", "live", "plain"):
        typer.echo(f"error: --view must be auto, live or plain, got {view!r}", err=True)
        raise typer.Exit(2)
    return view == "live" or (view == "auto" and sys.stdout.isatty())


class _Terminated(KeyboardInterrupt):
    """SIGTERM, turned into an interrupt."""


def _sigterm_interrupts() -> Any:
    """Make SIGTERM end `eskin listen` like Ctrl-C (so it finishes its files); returns the
    function that puts the previous handler back."""
    import signal

    def interrupt(signum: int, frame: Any) -> None:
        raise _Terminated

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread: leave SIGTERM alone
        return lambda: None
    return lambda: signal.signal(signal.SIGTERM, previous)


def _run_plain(events: Any, out: Any, truth: Any = None) -> None:
    """Print one line per event; decisions also go to the JSON-lines file ``out``."""
    from eskin.link.listener import Connection, Decision, InfoEvent, Recorded, Rejection, Stats

    rate = 3000.0
    last_info = None
    for ev in events:
        if isinstance(ev, InfoEvent):
            rate = ev.info.sample_rate_hz
            names = ", ".join(ev.info.class_names) or "-"
            key = (ev.info.rows, ev.info.cols, rate, names, ev.info.speed)
            if key == last_info:
                continue  # sent again at every (re)start: print it once
            last_info = key
            typer.echo(f"info grid={ev.info.rows}x{ev.info.cols} "
                       f"rate={rate:g} Hz classes={names} speed={ev.info.speed:g}")
        elif isinstance(ev, Decision):
            typer.echo(decision_line(ev, rate, truth))
            if out is not None:
                out.write(jsonl_line(ev.as_dict()))
                out.flush()
        elif isinstance(ev, Connection):
            typer.echo(f"{ev.state} {ev.path} {ev.reason}".rstrip())
        elif isinstance(ev, Recorded):
            typer.echo(f"recorded #{ev.index} [{ev.start}, {ev.stop}) {ev.label}")
        elif isinstance(ev, Rejection):
            typer.echo(f"refused {ev.message()}")
        elif isinstance(ev, Stats):
            typer.echo(stats_line(ev.stats))


# --------------------------------------------------------------------------- commands


def listen_cmd(
    port: Optional[str] = typer.Argument(
        None, help="serial port or pseudo-terminal (e.g. the path eskin-fw-sim prints, or its "
                   "--link symlink); not with --skin"),
    model: Optional[Path] = typer.Option(
        None, "--model", help="classify on the host too (.eskin file or saved model)"),
    jsonl: Optional[Path] = typer.Option(
        None, "--jsonl", help="write one JSON object per decision, then the link statistics"),
    duration: Optional[float] = typer.Option(None, "--duration", help="stop after S seconds"),
    until_eof: bool = typer.Option(
        False, "--until-eof", help="stop when the controller's replay is over (or it closes)"),
    record: Optional[Path] = typer.Option(
        None, "--record", help="record the received stream to a campaign file (.h5)"),
    replay: Optional[Path] = typer.Option(
        None, "--replay", help="the replay file the controller streams: each decision shows "
        "its recording's true class, the run ends with the accuracy and confusion matrix "
        "against them, and --record writes one recording per segment, with its true label"),
    reconnect: bool = typer.Option(
        False, "--reconnect", help="reopen the port when the controller goes away"),
    backend: str = typer.Option("auto", help="host classifier: auto | compiled | python"),
    force: bool = typer.Option(False, "--force", help="replace the --record and --jsonl files"),
    view: str = typer.Option(
        "auto", help="live (rich view), plain (one line per event) or auto (live on a "
                     "terminal)"),
    web: Optional[str] = typer.Option(
        None, "--web", metavar="[HOST:]PORT", help="also serve a live page (heat map, traces, "
        "decisions, statistics) at http://HOST:PORT/ (HOST: 127.0.0.1 unless given; PORT 0: "
        "any free port); read-only"),
    web_public: bool = typer.Option(
        False, "--web-public", help="allow --web to bind a non-loopback address (the page is "
        "then readable by other machines)"),
    web_grace: float = typer.Option(
        3.0, "--web-grace", help="seconds the page stays served after the listener stops"),
    skin: Optional[Path] = typer.Option(
        None, "--skin", help="listen to every patch of a skin (.toml, docs/skin.md) at once: "
        "per-patch and whole-skin statistics, --record into one campaign with a patch field"),
    sim: Optional[Path] = typer.Option(
        None, "--sim", help="with --skin: the folder `eskin fw-sim --skin` streams from (the "
        "simulated patches' ports PATCH.tty and replays PATCH.eskr)"),
    wait_ports: float = typer.Option(
        0.0, "--wait-ports", help="with --skin: seconds to wait for ports not there yet"),
) -> None:
    """Listen to the skin controller: live decisions, link statistics, taxel activity.

    A label followed by "?" is a "don't know": the model's confidence in the label is below
    its threshold (the calibrated rule), or, for a model with the paper's rule, no machine, or
    more than one, claimed the touch."""
    if skin is not None or port is None:
        _listen_skin(port, skin, sim, model, record, duration, until_eof, backend, force,
                     reconnect, wait_ports, refused=[("--jsonl", jsonl), ("--replay", replay),
                                                     ("--web", web)])
        return
    _listen(port, model, jsonl, duration, until_eof, record, replay, reconnect, backend,
            force, view, WebOptions(web, web_public, web_grace))


def _listen_skin(port: Optional[str], skin: Optional[Path], sim: Optional[Path], model: Any,
                 record: Any, duration: Any, until_eof: bool, backend: str, force: bool,
                 reconnect: bool, wait_ports: float, refused: list[tuple[str, Any]]) -> None:
    """`eskin listen --skin SKIN` (eskin.cli.skin); a PORT, or an option only one link takes,
    is refused with it, and no PORT needs --skin."""
    from eskin.cli import skin as skin_cli

    if skin is None:
        typer.echo("error: give a PORT, or --skin SKIN for every patch of a skin", err=True)
        raise typer.Exit(2)
    given = [name for name, value in refused if value is not None]
    if port is not None or given:
        typer.echo(f"error: --skin listens to the ports of the skin description; not with "
                   f"{'PORT ' + repr(port) if port is not None else given[0]}", err=True)
        raise typer.Exit(2)
    _live_mode(duration, "plain")
    skin_cli.listen(skin, sim, model, record, duration, until_eof, backend, force, reconnect,
                    wait_ports)


def demo_cmd(
    out: Path = typer.Option(Path("demo_out"), "--out", help="folder for every file"),
    participants: int = typer.Option(20, help="simulated participants"),
    test_participants: int = typer.Option(8, help="held out, streamed over the link"),
    speed: float = typer.Option(
        0.0, help="replay speed (x real time; 0: as fast as the host reads, which loses "
        "nothing)"),
    seed: int = typer.Option(0, help="random seed"),
    jobs: int = typer.Option(2, "--jobs", "-j", help="worker processes for the simulator"),
    machine: str = typer.Option("svm", help="svm (tensor-SVM) or rls (tensor-RLS)"),
    quick: bool = typer.Option(False, "--quick", help="a 2x2x2 grid instead of the paper's"),
    recordings: Optional[int] = typer.Option(
        None, "--recordings", help="stream only this many held-out recordings"),
    force: bool = typer.Option(
        False, "--force", help="use an --out folder that holds other files than the demo's"),
    controller: str = typer.Option(
        "sim", "--controller", help="sim: the simulator eskin-fw-sim; qemu: the controller "
        "firmware on QEMU's Cortex-M4F board (make mcu-link builds it; real time, a model "
        "trained to fit the part)"),
    web: Optional[str] = typer.Option(
        None, "--web", metavar="[HOST:]PORT", help="show the live stream on a page at "
        "http://HOST:PORT/ as `eskin listen --web` does (try --speed 1 to watch it)"),
    web_public: bool = typer.Option(
        False, "--web-public", help="allow --web to bind a non-loopback address"),
    web_grace: float = typer.Option(
        10.0, "--web-grace", help="seconds the page stays served after the stream ends"),
) -> None:
    """The whole pipeline on the built-in simulated campaign, over a real pseudo-terminal.
    Its own files in --out are replaced; a folder holding other files needs --force."""
    from eskin.demo import DemoError, run_demo

    console = report_console()
    options = WebOptions(web, web_public, web_grace)
    with _user_errors():
        _check_demo_folder(out, force)
        page = _start_web(options, None)
    try:
        with _user_errors():
            try:
                result = run_demo(out, participants=participants,
                                  test_participants=test_participants, speed=speed, seed=seed,
                                  n_jobs=jobs, quick=quick, machine=machine,
                                  max_recordings=recordings, log=lambda m: console.print(m),
                                  controller=controller,
                                  live_page=page.state if page is not None else None)
            except DemoError as exc:
                console.print(f"[bold red]demo failed:[/] {exc}")
                raise typer.Exit(1) from None
    finally:
        if page is not None and sys.exc_info()[0] is not None:
            page.stop(grace_s=0.0)
    _print_demo(console, result)
    if page is not None:
        _stop_web(page, [], result.stats, options.grace_s, summary=list(result.summary))
    if not result.agree:
        console.print(f"[bold red]demo failed: live and offline decisions disagree:[/] "
                      f"{result.disagreement}")
        raise typer.Exit(1)
    console.print("[bold green]live decisions (controller and host) equal the offline "
                  "ones[/]")


def _check_demo_folder(out: Path, force: bool) -> None:
    """The demo replaces its own files in ``out``; other files there need --force."""
    from eskin.demo import demo_files
    from eskin.errors import OverwriteError

    if out.exists() and not out.is_dir():
        raise OverwriteError(f"{out}: is a file; --out names the demo's folder")
    if force or not out.is_dir():
        return
    ours = {p.name for p in demo_files(out).values()} | {"skin.tty"}
    others = sorted(p.name for p in out.iterdir() if p.name not in ours)
    if others:
        raise OverwriteError(
            f"{out}: the folder holds files the demo did not write ({', '.join(others[:3])}"
            f"{', ...' if len(others) > 3 else ''}); use another --out, or --force"
        )


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
    app.command("listen")(listen_cmd)
    app.command("demo")(demo_cmd)


class WebOptions(NamedTuple):
    """`eskin listen --web [HOST:]PORT --web-public --web-grace S` (address None: no page)."""

    address: Optional[str] = None
    public: bool = False
    grace_s: float = 3.0


def _start_web(options: WebOptions, listener: Any) -> Any:
    """The live page's server for ``listener`` (None: one that `eskin demo` starts later), or
    None without --web; raises ValueError naming the option and its value for a bad address,
    one not allowed or one in use."""
    if options.address is None:
        return None
    from eskin.link.web import LiveState, WebServer, parse_web_address

    if not (math.isfinite(options.grace_s) and options.grace_s >= 0):
        raise ValueError(f"--web-grace {options.grace_s}: must be a number of seconds >= 0")
    host, web_port = parse_web_address(options.address, options.public)
    state = (LiveState() if listener is None else
             LiveState(listener.path, replay=listener.replay,
                       replay_offset=listener.replay_offset))
    server = WebServer(state, host, web_port, public=options.public).start()
    typer.echo(f"live page: {server.url} (read-only)")
    return server


def _stop_web(server: Any, scores: list[Any], stats: Any, grace_s: float,
              summary: Optional[list[str]] = None) -> None:
    """Tell the pages the listener stopped (with the scores, or ``summary``, and the final
    statistics), serve them ``grace_s`` more seconds, close."""
    if server is None:
        return
    if summary is None:
        summary = [line for sc in scores for line in score_lines(sc)] + [stats_line(stats)]
    server.state.observe_stats(stats)
    if grace_s > 0:
        typer.echo(f"live page: showing the final state for {grace_s:g} s (Ctrl-C ends it)")
    try:
        server.stop(summary, grace_s)
    except KeyboardInterrupt:
        pass  # the server's thread ends with the process


def _listen(port: str, model: Any, jsonl: Any, duration: Any, until_eof: bool, record: Any,
            replay: Any, reconnect: bool, backend: str, force: bool, view: str,
            web: WebOptions = WebOptions()) -> None:
    """`eskin listen`: run the listener until it ends, then score and report."""
    from eskin._files import refuse_overwrite_all
    from eskin.link.listener import LinkListener

    live_mode = _live_mode(duration, view)
    if web.address is not None:
        with _user_errors():  # a bad --web value ends the command before anything opens
            from eskin.link.web import parse_web_address

            parse_web_address(web.address, web.public)
    with _user_errors():
        outputs = [p for p in (record, jsonl) if p is not None]
        refuse_overwrite_all(outputs, force, inputs=(model, replay))
        listener = LinkListener(port, model=model, backend=backend, record=record,
                                replay=replay, reconnect=reconnect, overwrite=force,
                                stats_interval=0.25 if live_mode else 5.0)
        try:
            page = _start_web(web, listener)
        except BaseException:
            listener.close()
            raise
    out = None
    decisions: list[Any] = []
    interrupted = 0
    lost: list[tuple[int, int]] = []
    restore = _sigterm_interrupts()
    try:
        with _user_errors():
            listener.open()
            out = open(jsonl, "w", encoding="utf-8") if jsonl is not None else None
        typer.echo(f"listening on {port}" + (f" (host model: {listener.classifier.kind})"
                                             if listener.classifier is not None else ""))
        events = _kept(listener.events(duration=duration, until_eof=until_eof), decisions, lost)
        if page is not None:
            events = page.state.observed(events, lambda: listener.stats)
        truth = replay_truth(listener)
        with _user_errors():  # e.g. the --record file, written once the first one is due
            if live_mode:
                _run_live(listener, events, deque(maxlen=12), out, truth)
            else:
                _run_plain(events, out, truth)
    except KeyboardInterrupt as exc:
        typer.echo("interrupted")
        interrupted = 143 if isinstance(exc, _Terminated) else 130  # 128 + the signal
    finally:
        restore()
        scores = _finish(listener, decisions, lost, out)
        if sys.exc_info()[0] is not None:  # ending with an error: the pages are told at once
            _stop_web(page, scores, listener.stats, 0.0)
    _print_scores(scores, live_mode)
    if record is not None and record.exists() and listener.stats.recordings:
        typer.echo(f"wrote {record}")
    _stop_web(page, scores, listener.stats, web.grace_s)
    if interrupted:
        raise typer.Exit(interrupted)


def _finish(listener: Any, decisions: list[Any], lost: list[tuple[int, int]],
            out: Any) -> list[Any]:
    """Close the listener (finishing the recording), then write the scores against the replay
    and the final statistics to --jsonl, also after SIGINT or SIGTERM; returns the scores."""
    try:
        with _user_errors():
            listener.close()
    finally:
        scores = _score(listener, decisions, lost)
        if out is not None:
            for sc in scores:
                out.write(jsonl_line(sc.as_dict()))
            out.write(jsonl_line({"type": "stats", **listener.stats.as_dict()}))
            out.close()
    return scores


def _kept(events: Any, decisions: list[Any], lost: list[tuple[int, int]]) -> Any:
    """Pass the events on, keeping the decisions and the stream ranges of lost samples."""
    from eskin.link.listener import DataBlock, Decision

    for ev in events:
        if isinstance(ev, Decision):
            decisions.append(ev)
        elif isinstance(ev, DataBlock) and ev.lost_before > 0:
            lost.append((ev.first_sample - ev.lost_before, ev.first_sample))
        yield ev


def _score(listener: Any, decisions: list[Any], lost: list[tuple[int, int]]) -> list[Any]:
    """The decisions scored against the replay's true classes (none without --replay), with
    the recordings whose samples were lost (``lost``: stream ranges) named."""
    from eskin.link.scoring import score_decisions

    if listener.replay is None or not decisions:
        return []
    return score_decisions(decisions, listener.replay, listener.replay_offset, lost)


def _print_scores(scores: list[Any], live_mode: bool) -> None:
    if not scores:
        return
    if live_mode:
        from rich.table import Table

        console = report_console()
        console.print("\naccuracy against the replay's true classes (one decision per recording):")
        for sc in scores:
            names = list(sc.class_names)
            console.print(score_lines(sc)[0], style="bold", highlight=False)
            for line in loss_lines(sc):
                console.print(line, highlight=False)
            t = Table()
            t.add_column("true \\ decided", style="bold")
            for n in [*names, "none"]:
                t.add_column(n, justify="right")
            for name, row in zip(names, sc.confusion):
                t.add_row(name, *[str(int(v)) for v in row])
            console.print(t)
        return
    typer.echo("accuracy against the replay's true classes (one decision per recording):")
    for sc in scores:
        for line in score_lines(sc):
            typer.echo(line)


def _run_live(listener: Any, events: Any, recent: Any, out: Any, truth: Any = None) -> Any:
    """The rich.live view; returns the last statistics."""
    from rich.console import Group
    from rich.live import Live
    from rich.panel import Panel
    from rich.table import Table

    from eskin.link.listener import Decision, InfoEvent, Stats

    rate = 3000.0
    last_stats = listener.stats
    header = f"port {listener.path}"

    def view() -> Any:
        grid = Table.grid(padding=(0, 4))
        grid.add_row(heat_table(listener.activity()), stats_table(last_stats))
        return Panel(Group(header, grid, decisions_table(list(recent), rate, truth)),
                     title="eskin listen")

    # drawn from this loop, at most 5 times a second, so that rendering never competes with
    # reading the port (no refresh thread)
    t_draw = 0.0
    with Live(view(), auto_refresh=False, transient=False) as live:
        for ev in events:
            if isinstance(ev, InfoEvent):
                rate = ev.info.sample_rate_hz
                header = (f"port {listener.path}  grid {ev.info.rows}x{ev.info.cols}  "
                          f"{rate:g} Hz  x{ev.info.speed:g}  classes: "
                          f"{', '.join(ev.info.class_names) or '-'}")
            elif isinstance(ev, Decision):
                recent.append(ev)
                if out is not None:
                    out.write(jsonl_line(ev.as_dict()))
                    out.flush()
            elif isinstance(ev, Stats):
                last_stats = ev.stats
            now = time.monotonic()
            if now - t_draw > 0.2:
                t_draw = now
                live.update(view(), refresh=True)
        live.update(view(), refresh=True)
    return last_stats


def _print_demo(console: Any, result: Any) -> None:
    from rich.columns import Columns
    from rich.table import Table

    def matrix(title: str, cm: Any, names: list[str]) -> Table:
        t = Table(title=title)
        t.add_column("true \\ decided", style="bold")
        for n in names:
            t.add_column(n, justify="right")
        t.add_column("none", justify="right")
        for i, n in enumerate(names):
            t.add_row(n, *[str(int(v)) for v in cm[i]])
        return t

    names = list(result.class_names)
    console.print(Columns([matrix(f"{k} ({result.error_rates[k]:.1%} error)", cm, names)
                           for k, cm in result.confusion.items()]))
    t = Table(title="agreement (touch by touch, then per recording)")
    t.add_column("decisions", no_wrap=True)
    for c in ("touches", "same touches", "recs", "same labels", "max |dv|"):
        t.add_column(c, justify="right")
    for k, row in result.agreement.items():
        diff = row["max_value_diff"]
        short = (k.replace(" (live)", "").replace(" (Python)", "")
                 .replace("offline batch (per recording)", "batch").replace(" vs ", " / "))
        t.add_row(short, str(row["touches"]), str(row["equal_touches"]), str(row["n"]),
                  str(row["equal"]), "-" if math.isnan(diff) else f"{diff:.1e}")
    console.print(t)
    console.print("same touches: equal window and label, touch by touch; recs: recordings "
                  "compared (one decision each: the touch on its true contact); max |dv|: largest "
                  "difference of the decision values (float32 export vs float64)")
    console.print(stats_table(result.stats, title="link statistics (live run)"))
    for line in result.summary:
        console.print(line)
