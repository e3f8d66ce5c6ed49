"""CLI for a whole skin (docs/skin.md): `eskin fw-sim --skin`, and the work behind
`eskin simulate --skin` and `eskin listen --skin`.

``eskin fw-sim --skin SKIN FOLDER`` starts one simulated controller (``eskin-fw-sim``) per
simulated patch on that patch's replay in FOLDER, prints each patch's pseudo-terminal, and
stops them all when it ends (their replays over, Ctrl-C or SIGTERM). Errors a user can cause
exit with code 2 and a one-line message.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Optional

import typer


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    from eskin._files import error_line

    try:
        yield
    except (ValueError, OSError, KeyError) as exc:
        typer.echo(f"error: {error_line(exc)}", err=True)
        raise typer.Exit(2) from None


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM ends the command as Ctrl-C does (so that it stops what it started)."""

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def load(skin: Path, model: Optional[Path]) -> Any:
    """The skin description, every patch on ``model`` when given (--model)."""
    from eskin.data.skin import load_skin

    loaded = load_skin(skin)
    return loaded if model is None else loaded.with_model(model)


# --------------------------------------------------------------------------- simulate --skin


def simulate(skin: Path, output: Path, model: Optional[Path], gestures: int, episode: float,
             seed: int, force: bool) -> None:
    """`eskin simulate --skin SKIN -o FOLDER`: the per-patch replays and the campaign."""
    from eskin.data.skin_simulator import simulate_skin

    with _user_errors():
        s = load(skin, model)
        result = simulate_skin(s, output, gestures=gestures, seed=seed, episode_s=episode,
                               overwrite=force)
    slides = sum(g.kind == "slide" for g in result.gestures)
    typer.echo(f"wrote {len(result.replays)} patch replays and {result.campaign} to "
               f"{result.folder}: {len(result.gestures)} SIMULATED gestures ({slides} slides "
               f"across a patch border), {episode:g} s each")
    for g in result.gestures:
        typer.echo(f"  gesture {g.episode}: {g.kind} on {' -> '.join(g.contacts)}")


# --------------------------------------------------------------------------- fw-sim --skin


def fw_sim_cmd(
    folder: Path = typer.Argument(..., help="the folder of `eskin simulate --skin` (one "
                                            "PATCH.eskr per patch); the ports are published "
                                            "there as PATCH.tty"),
    skin: Path = typer.Option(..., "--skin", help="skin description (.toml, docs/skin.md)"),
    model: Optional[Path] = typer.Option(
        None, "--model", help="classify on every controller with this .eskin model (default: "
        "each patch's model in the skin description)"),
    speed: float = typer.Option(1.0, help="replay speed (1 = real time, 0 = as fast as the host "
                                          "reads, which loses nothing)"),
    wait_start: bool = typer.Option(True, "--wait-start/--no-wait-start",
                                    help="stream only after the host sends START"),
    hold: float = typer.Option(1.0, help="seconds each port stays open after its replay"),
    loop: bool = typer.Option(False, "--loop", help="repeat the replays forever"),
) -> None:
    """Start one simulated controller (eskin-fw-sim) per simulated patch of a skin.

    Each streams its patch's replay over its own pseudo-terminal; all stop when the command
    ends."""
    from eskin.link.simulated_controllers import SimulatedControllers

    with _user_errors():
        fleet = SimulatedControllers(load(skin, model), folder, speed=speed,
                                     wait_start=wait_start, hold_s=hold, loop=loop)
    try:
        with _sigterm_interrupts():
            with _user_errors():
                fleet.start()
            for c in fleet.controllers:
                typer.echo(f"patch {c.patch_id} PTY {c.pty} (link {c.link})")
            typer.echo(f"ready: {len(fleet.controllers)} simulated controllers")
            fleet.wait()
    except KeyboardInterrupt:
        typer.echo("interrupted: stopping every controller")
    finally:
        fleet.stop()
    for c in fleet.controllers:
        s = c.stats or {}
        typer.echo(f"patch {c.patch_id} exit={c.process.returncode} "
                   f"samples_sent={s.get('samples_sent', '-')} "
                   f"decisions_sent={s.get('decisions_sent', '-')}")


# --------------------------------------------------------------------------- listen --skin


def ports_and_replays(s: Any, sim: Optional[Path]) -> tuple[dict[str, str], dict[str, Path]]:
    """Each patch's port (its link, or FOLDER/ID.tty for a simulated one) and the replay its
    simulated controller streams (FOLDER/ID.eskr)."""
    from eskin.link.simulated_controllers import link_path, replay_path

    ports, replays = {}, {}
    for p in s.patches:
        if not p.simulated:
            ports[p.id] = p.link
            continue
        if sim is None:
            raise ValueError(f"{s.path}: patch {p.id!r} has link = \"simulated\": give --sim "
                             f"FOLDER (the folder `eskin fw-sim --skin` streams from)")
        ports[p.id] = str(link_path(sim, p.id))
        if replay_path(sim, p.id).is_file():
            replays[p.id] = replay_path(sim, p.id)
    return ports, replays


def listen(skin: Path, sim: Optional[Path], model: Optional[Path], record: Optional[Path],
           duration: Optional[float], until_eof: bool, backend: str, force: bool,
           reconnect: bool, wait_ports: float) -> None:
    """`eskin listen --skin SKIN`: every patch's link at once; one line per decision, then
    each patch's statistics and the whole skin's."""
    from eskin._files import refuse_overwrite
    from eskin.link.skin_listener import SkinListener

    with _user_errors():
        s = load(skin, model)
        ports, replays = ports_and_replays(s, sim)
        if record is not None:
            refuse_overwrite(record, force)
        listener = SkinListener(s, ports, backend=backend, record=record, overwrite=force,
                                replays=replays, reconnect=reconnect,
                                record_source="simulated" if replays else "recorded")
    interrupted = False
    try:
        with _user_errors():
            listener.open(timeout_s=wait_ports)
        typer.echo(f"listening on {len(ports)} patches of skin {s.name!r}")
        with _sigterm_interrupts():
            report = listener.run(duration=duration, until_eof=until_eof, on_event=_print_event)
    except KeyboardInterrupt:
        typer.echo("interrupted")
        interrupted = True
        report = listener.report()
    finally:
        with _user_errors():
            listener.close()
    _print_report(report, record)
    if interrupted:
        raise typer.Exit(130)
    if report.errors:
        raise typer.Exit(1)


def _print_event(patch: str, ev: Any) -> None:
    from eskin.link.events import Decision, Recorded

    if isinstance(ev, Decision):
        label = ev.label if ev.label is not None else f"#{ev.label_index}"
        dk = " (don't know)" if ev.dont_know else ""
        typer.echo(f"patch {patch} decision {ev.source:<10} window=[{ev.onset_sample}, "
                   f"{ev.offset_sample}) label={label}{dk}")
    elif isinstance(ev, Recorded):
        typer.echo(f"patch {patch} recorded #{ev.index} [{ev.start}, {ev.stop}) {ev.label}")


def _print_report(report: Any, record: Optional[Path]) -> None:
    for p in report.patches:
        st = p.stats
        a, n = p.agree
        typer.echo(f"patch {p.patch_id} frames={st.frames} samples={st.samples} "
                   f"lost={p.lost} crc_errors={st.crc_errors} "
                   f"decisions controller={st.decisions_controller} host={st.decisions_host} "
                   f"agree={a}/{n} recordings={st.recordings}"
                   + (f" error: {p.error}" if p.error else ""))
    if record is not None and report.recordings:
        typer.echo(f"wrote {record}: {report.recordings} recordings of "
                   f"{len(report.patches)} patches")
    typer.echo(f"skin: {report.summary()}")


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
    app.command("fw-sim")(fw_sim_cmd)
