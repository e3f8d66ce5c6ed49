"""CLI commands: simulate, info, plot, import-csv, import-tdms.

They parse arguments, call the package and print; errors for users exit with code 2 and a
one-line message naming the file, field or value.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Optional

import typer


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    """Turn the errors a user can cause into a clear message and exit code 2."""
    from eskin._files import error_line

    try:
        yield
    except (ValueError, OSError, KeyError, IndexError) as exc:
        typer.echo(f"error: {error_line(exc)}", err=True)
        raise typer.Exit(2) from None


def simulate_cmd(
    output: Path = typer.Option(..., "-o", "--output", help="campaign file to write (.h5); "
                                "with --skin, the folder of the skin's files"),
    participants: int = typer.Option(70, help="number of simulated participants"),
    seed: int = typer.Option(0, help="random seed (same seed -> identical file)"),
    difficulty: Optional[float] = typer.Option(
        None, help="0 = clean, 1 = calibrated to the paper's error ranges (default), 2 = harder"),
    grid: Optional[str] = typer.Option(
        None, help="taxel grid ROWSxCOLS over the same sensed area (default 4x4)"),
    rate: Optional[float] = typer.Option(None, help="samples per second (default 3000)"),
    duration: Optional[float] = typer.Option(
        None, help="seconds per recording (default 7)"),
    modalities: Optional[str] = typer.Option(
        None, help="gestures, comma-separated: brush, finger, washer (the default three) and "
        "press (a press-and-hold: fingertip pressed, held 0.5 s, released)"),
    jobs: int = typer.Option(0, "--jobs", "-j", help="worker processes (0 = one per core)"),
    force: bool = typer.Option(False, "--force", help="replace OUTPUT if it exists"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output"),
    skin: Optional[Path] = typer.Option(
        None, "--skin", help="simulate a whole skin (.toml, docs/skin.md): one replay per "
        "patch (PATCH.eskr) and the campaign skin.h5 in the --output folder, gestures "
        "crossing patch borders"),
    gestures: int = typer.Option(8, help="with --skin: gestures (one per episode)"),
    episode: float = typer.Option(2.0, help="with --skin: seconds per gesture (1 to 60)"),
) -> None:
    """Simulate a touch campaign (SIMULATED data: a physics model of the paper's skin)."""
    import os
    import time

    if skin is not None:
        from eskin.cli import skin as skin_cli

        skin_cli.simulate(skin, output, None, gestures, episode, seed, force)
        return

    from eskin._files import refuse_overwrite
    from eskin._progress import progress_bar
    from eskin.data.simulator import simulate

    with _user_errors():
        cfg = _acquisition(grid, rate, duration, modalities)
        refuse_overwrite(output, force)
        t0 = time.perf_counter()
        n_jobs = jobs if jobs > 0 else (os.cpu_count() or 1)
        with progress_bar(not quiet) as bar:
            task = bar.add_task("simulating recordings", total=None)
            simulate(output, participants=participants, seed=seed, difficulty=difficulty,
                     config=cfg, n_jobs=n_jobs, overwrite=force,
                     progress=lambda done, total: bar.update(task, completed=done, total=total))
        n = participants * 4 * (3 if cfg is None else len(cfg.modalities))
        typer.echo(f"wrote {output}: {n} SIMULATED recordings "
                   f"in {time.perf_counter() - t0:.1f} s")


def _acquisition(grid: Optional[str], rate: Optional[float], duration: Optional[float],
                 modalities: Optional[str]) -> Any:
    """The simulator settings of --grid, --rate, --duration, --modalities (None: none given);
    a bad value is a ValueError naming the option."""
    if grid is None and rate is None and duration is None and modalities is None:
        return None
    from eskin.data.simulator import acquisition_config

    shape = None
    if grid is not None:
        try:
            shape = tuple(int(v) for v in grid.lower().split("x"))
            if len(shape) != 2:
                raise ValueError
        except ValueError:
            raise ValueError(f"--grid {grid}: expected ROWSxCOLS, e.g. 8x8") from None
    names = None if modalities is None else tuple(
        m.strip() for m in modalities.split(",") if m.strip())
    for option, value, kw in (("--grid", grid, {"grid": shape}),
                              ("--rate", rate, {"rate_hz": rate}),
                              ("--duration", duration, {"duration_s": duration}),
                              ("--modalities", modalities, {"modalities": names})):
        if value is not None:
            try:
                acquisition_config(**kw)
            except ValueError as exc:
                raise ValueError(f"{option} {value}: {exc}") from None
    return acquisition_config(grid=shape, rate_hz=rate, duration_s=duration, modalities=names)


def _named(file: str) -> Path:
    """A file argument; an empty one is refused (Path("") would be the current folder)."""
    if not file.strip():
        raise ValueError("no file name given (the argument is empty)")
    return Path(file)


def info_cmd(
    file: str = typer.Argument(..., help="campaign file"),
    check: bool = typer.Option(False, "--check", help="also read every recording's data"),
) -> None:
    """Summarise a campaign file: grid, rate, counts, lengths, source."""
    from eskin.data.campaign import load_campaign

    with _user_errors(), load_campaign(_named(file), check_data=check) as c:
        _print_info(c)
        if check:
            from eskin.data.integrity import check_report

            for line in check_report(c.path):
                typer.echo(line)


def plot_cmd(
    file: str = typer.Argument(..., help="campaign file"),
    index: int = typer.Option(0, "--index", "-i", help="recording index, 0 to n - 1"),
    output: Path = typer.Option(..., "-o", "--output", help="image to write (.png, .svg)"),
    force: bool = typer.Option(False, "--force", help="replace OUTPUT if it exists"),
) -> None:
    """Plot one recording: the taxel traces, the detected touch window, an energy heat map."""
    from eskin._files import refuse_overwrite
    from eskin.data.campaign import load_campaign
    from eskin.signal.plotting import plot_recording

    with _user_errors():
        path = _named(file)
        refuse_overwrite(output, force, inputs=(path,))
        with load_campaign(path) as c:
            if not 0 <= index < len(c):
                raise ValueError(f"--index {index} is out of range: {path} holds recordings 0 to {len(c) - 1}")
            plot_recording(c, index, output)
        typer.echo(f"wrote {output}")


def _grid(rows: Optional[int], cols: Optional[int]) -> Optional[tuple[int, int]]:
    """--rows and --cols: both (a grid of at least 1 x 1) or neither."""
    for name, value in (("--rows", rows), ("--cols", cols)):
        if value is not None and value < 1:
            raise ValueError(f"{name} {value}: a grid has at least 1 taxel row and column")
    if (rows is None) != (cols is None):
        given, other = ("--rows", "--cols") if cols is None else ("--cols", "--rows")
        raise ValueError(f"{given} {rows if cols is None else cols} needs {other} too (the grid "
                         f"is rows x cols)")
    return None if rows is None or cols is None else (rows, cols)


def import_csv_cmd(
    folder: Path = typer.Argument(..., help="folder with one CSV per recording"),
    output: Path = typer.Option(..., "-o", "--output", help="campaign file to write"),
    manifest: Optional[Path] = typer.Option(
        None, help="manifest CSV (default: FOLDER/manifest.csv)"),
    rows: Optional[int] = typer.Option(
        None, help="taxel rows (default: a manifest column, else 4 for 16 taxel columns)"),
    cols: Optional[int] = typer.Option(
        None, help="taxel columns (default: a manifest column, else 4 for 16 taxel columns)"),
    rate: Optional[float] = typer.Option(
        None, "--rate", help="sample rate in Hz (default: a manifest column, else the "
        "recordings' time column)"),
    time_column: Optional[str] = typer.Option(
        None, "--time-column", help="the recordings' time column, by its header name (dropped; "
        "gives the rate). Default: a column named time, t, time_s, timestamp (s), time_ms, "
        "t_ms (ms), time_us (us), or sample/index (a sample index)"),
    time_unit: Optional[str] = typer.Option(
        None, "--time-unit", help="unit of the time column: s, ms or us (default: the one its "
        "name says)"),
    volts_per_count: Optional[float] = typer.Option(
        None, help="volts per ADC count. Needed when the CSV holds volts (numbers that are not "
        "integers): they are divided by it into counts. Integer counts are imported as they "
        "are; given, it is stored so plots can show volts"),
    modalities: Optional[str] = typer.Option(
        None, help="comma-separated class names in class-id order (default: sorted labels)"),
    force: bool = typer.Option(False, "--force", help="replace OUTPUT if it exists"),
) -> None:
    """Import a folder of CSV recordings (one column per taxel) into a campaign file."""
    from eskin._files import refuse_overwrite
    from eskin.data.campaign import load_campaign
    from eskin.data.importers import import_csv_folder

    with _user_errors():
        grid = _grid(rows, cols)
        inputs = [manifest or folder / "manifest.csv"]
        inputs += [p for p in folder.iterdir() if p.is_file()] if folder.is_dir() else []
        refuse_overwrite(output, force, inputs=inputs)
        import_csv_folder(
            folder, output, manifest=manifest, grid_shape=grid,
            sample_rate_hz=rate, volts_per_count=volts_per_count,
            modalities=modalities.split(",") if modalities else None, overwrite=force,
            time_column=time_column, time_unit=time_unit)
        with load_campaign(output) as c:
            vpc = ("values as ADC counts (no --volts-per-count)"
                   if "volts_per_count_given" in c.attrs else
                   f"{c.volts_per_count:.6g} V per count")
            typer.echo(f"wrote {output}: {len(c)} recordings, {c.grid_shape[0]}x"
                       f"{c.grid_shape[1]} taxels, {c.sample_rate_hz:g} Hz, {vpc}")


def import_tdms_cmd(
    files: list[Path] = typer.Argument(..., help="LabVIEW .tdms files"),
    output: Path = typer.Option(..., "-o", "--output", help="campaign file to write"),
    rows: Optional[int] = typer.Option(
        None, help="taxel rows (default: from properties, else 4 for 16 channels)"),
    cols: Optional[int] = typer.Option(
        None, help="taxel columns (default: from properties, else 4 for 16 channels)"),
    rate: Optional[float] = typer.Option(
        None, "--rate", help="sample rate in Hz (default: wf_increment property)"),
    volts_per_count: Optional[float] = typer.Option(
        None, help="volts per count for float (volt) channels (default 10/32768)"),
    modalities: Optional[str] = typer.Option(
        None, help="comma-separated class names in class-id order (default: sorted labels)"),
    force: bool = typer.Option(False, "--force", help="replace OUTPUT if it exists"),
) -> None:
    """Import LabVIEW TDMS recordings (one group per recording) into a campaign file."""
    from eskin._files import refuse_overwrite
    from eskin.data.campaign import load_campaign
    from eskin.data.importers import import_tdms

    with _user_errors():
        grid = _grid(rows, cols)
        refuse_overwrite(output, force, inputs=files)
        import_tdms(
            files, output, grid_shape=grid,
            sample_rate_hz=rate, volts_per_count=volts_per_count,
            modalities=modalities.split(",") if modalities else None, overwrite=force)
        with load_campaign(output) as c:
            typer.echo(f"wrote {output}: {len(c)} recordings")


def recover_cmd(
    file: Path = typer.Argument(
        ..., help="the campaign file an interrupted writer was writing (or its journal)"),
    output: Optional[Path] = typer.Option(
        None, "-o", "--output", help="campaign file to write (default: FILE)"),
    force: bool = typer.Option(False, "--force", help="replace OUTPUT if it exists"),
) -> None:
    """Salvage the recordings of a writer that died (kill -9, power loss, a crash).

    Exit code 0 when every complete record of the journal is in the campaign written; 2, with
    the same one-line summary on stderr, when some records were invalid (skipped, named by
    index and field; the journal is then kept as .FILE.rejected) or nothing could be written.
    A torn last record (the append a crash interrupted) is dropped and is no error."""
    from eskin._files import refuse_overwrite
    from eskin.data.campaign import recover_campaign
    from eskin.data.journal import journal_and_target

    with _user_errors():
        journal, target = journal_and_target(file)
        if journal.exists():  # else: "nothing to recover"
            refuse_overwrite(output if output is not None else target, force, inputs=(journal,))
        result = recover_campaign(file, output, overwrite=force)
    if result.skipped:  # the valid records are in place, but the journal held invalid ones
        typer.echo(f"error: {result.message()}", err=True)
        raise typer.Exit(2)
    typer.echo(result.message())


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
    app.command("simulate")(simulate_cmd)
    app.command("info")(info_cmd)
    app.command("plot")(plot_cmd)
    app.command("import-csv")(import_csv_cmd)
    app.command("import-tdms")(import_tdms_cmd)
    app.command("recover")(recover_cmd)


def _print_info(c) -> None:
    from rich.console import Console
    from rich.table import Table

    s = c.summary()
    console = Console(soft_wrap=True)
    rows, cols = s["grid"]
    src = s["source"]
    src_text = "SIMULATED (eskin simulator)" if src == "simulated" else src
    console.print(f"[bold]{s['path']}[/bold]")
    console.print(f"  source            {src_text}")
    console.print(f"  recordings        {s['recordings']}")
    console.print(f"  grid              {rows} x {cols} taxels")
    console.print(f"  sample rate       {s['sample_rate_hz']:g} Hz")
    console.print(f"  padded length T   {s['samples_per_recording']} samples "
                  f"({s['duration_s']:.3g} s)")
    if "volts_per_count_given" in c.attrs:
        console.print("  volts per count   not given (values imported as ADC counts)")
    else:
        console.print(f"  volts per count   {s['volts_per_count']:.6g} V")
    console.print(f"  valid lengths     min {s['length_min']}, median {s['length_median']:g}, "
                  f"max {s['length_max']} samples")
    console.print(f"  participants      {s['participants']}")
    console.print(f"  contact interval  {'yes (ground truth)' if s['has_contact_interval'] else 'no'}")
    if "difficulty" in c.attrs:
        console.print(f"  difficulty        {c.attrs['difficulty']:g} "
                      f"(seed {c.attrs.get('simulator_seed', '?')})")

    table = Table(title="recordings per modality, run and direction")
    table.add_column("modality (id)")
    runs = sorted(s["per_run"])
    dirs = sorted({int(d) for d in c.direction})
    import numpy as np

    from eskin.data.campaign import DIRECTION_NAMES

    for r in runs:
        for d in dirs:
            table.add_column(f"run {r} {DIRECTION_NAMES.get(d, str(d))[:1]}", justify="right")
    table.add_column("total", justify="right")
    for k, name in enumerate(c.modalities):
        cells = []
        for r in runs:
            for d in dirs:
                cells.append(str(int(np.sum((c.modality == k) & (c.run == r) & (c.direction == d)))))
        table.add_row(f"{name} ({k})", *cells, str(s["per_modality"][name]))
    console.print(table)
    pp = s["per_participant"]
    counts = sorted(set(pp.values()))
    console.print("  recordings per participant: "
                  + ", ".join(f"{sum(1 for v in pp.values() if v == n)} participants x {n}"
                              for n in counts))
