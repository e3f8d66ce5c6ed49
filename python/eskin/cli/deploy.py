"""CLI commands: export (a trained model for the controller), replay (a campaign's recordings
for the controller simulator and for eskin-classify)."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Any, NoReturn, Optional

import typer


class ReplayFormat(str, Enum):
    replay = "replay"
    npy = "npy"
    records = "records"
    raw = "raw"


#: what each output format is for, as `eskin replay` reports it
_FORMAT_USE = {
    "replay": "a stream for eskin-fw-sim",
    "npy": "recordings for eskin-classify",
    "records": "raw records for eskin-classify",
    "raw": "a raw int16 stream, one sample of every taxel after another, for a controller "
           "loop on its standard input (the README's classify_stream.cpp)",
}
_SELECT_KEYS = ("modality", "participant", "direction", "run", "index")


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def export(
    model_path: Path = typer.Argument(..., metavar="MODEL", help="trained model (eskin train)"),
    output: Path = typer.Option(..., "-o", "--output", help=".eskin file to write"),
    float64: bool = typer.Option(False, "--float64", help="store float64 (default float32)"),
    c_header: Optional[Path] = typer.Option(
        None, "--c-header", help="also write the model as a C header (static const arrays)"
    ),
    target: Optional[str] = typer.Option(
        None,
        "--target",
        help="a controller (cortex-m4): check that the model fits its flash and RAM before "
        "writing (docs/mcu.md)",
    ),
    force: bool = typer.Option(False, "--force", help="replace existing output files"),
) -> None:
    """Export a trained model for the controller: a .eskin file (docs/model-format.md)
    that eskin-classify and the C++ library load, and optionally a C header."""
    from eskin._files import refuse_overwrite_all
    from eskin.deploy import load_model
    from eskin.deploy.export import CompiledModel, export_model, write_c_header

    try:
        outputs = [output] + ([c_header] if c_header is not None else [])
        refuse_overwrite_all(outputs, force, inputs=(model_path,))
        model = load_model(model_path)
        if getattr(model, "machine", None) == "compiled":
            _fail(f"{model_path} is already an exported .eskin model")
        dtype = "float64" if float64 else "float32"
        if target is not None:
            _check_target(model, dtype, target)
        path = export_model(model, output, dtype=dtype)
        cm = CompiledModel(path)
        if c_header is not None:
            write_c_header(path, c_header, name=_header_name(c_header))
    except (ValueError, OSError, KeyError) as exc:
        from eskin._files import error_line

        _fail(error_line(exc, output))
    typer.echo(
        f"wrote {path}: {_size(cm.file_bytes)}, {', '.join(cm.class_names)} ({cm.rule}), "
        f"D={cm.D}, {cm.n_support} support vectors, "
        f"{'float64' if cm.is_float64 else 'float32'}"
    )
    if c_header is not None:
        typer.echo(f"wrote {c_header}: {_size(c_header.stat().st_size)} of C source (the "
                   f"compiled arrays take {_size(cm.file_bytes)})")
    if cm.file_bytes > EXPORT_WARN_BYTES and target is None:
        typer.echo(
            f"warning: {path} is {_size(cm.file_bytes)}, more than the "
            f"{_size(EXPORT_WARN_BYTES)} of flash of a Cortex-M4F controller (docs/mcu.md); "
            f"`eskin export --target cortex-m4` checks a model against it", err=True)


#: `eskin export` warns when a model file is larger than this: the flash of the Cortex-M4F
#: controllers eskin targets (deploy/target.py's cortex-m4, 1 MiB)
EXPORT_WARN_BYTES = 1 << 20


def _size(n: int) -> str:
    """A file size for people: '1.8 MiB (1886884 bytes)', '41228 bytes'."""
    if n < 1 << 16:
        return f"{n} bytes"
    unit, scale = ("MiB", 1 << 20) if n >= 1 << 20 else ("KiB", 1 << 10)
    return f"{n / scale:.1f} {unit} ({n} bytes)"


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
    app.command("export")(export)
    app.command("replay")(replay)


def _ints(text: str, key: str) -> list[int]:
    """'1,3,5-8' -> [1, 3, 5, 6, 7, 8]."""
    out: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        lo, dash, hi = part.partition("-")
        try:
            if dash and lo:
                out.extend(range(int(lo), int(hi) + 1))
            else:
                out.append(int(part))
        except ValueError:
            _fail(f"--select {key}={text}: {part!r} is not an integer or a range a-b")
    return out


def _select_mask(c: Any, item: str) -> Any:
    """The recordings of campaign ``c`` that one ``--select KEY=VALUES`` keeps."""
    import numpy as np

    from eskin.data.importers import parse_direction

    key, eq, values = item.partition("=")
    key = key.strip()
    if not eq or key not in _SELECT_KEYS or not values.strip():
        _fail(f"--select {item!r}: expected KEY=VALUES with KEY one of {', '.join(_SELECT_KEYS)}")
    if key == "modality":
        names = [v.strip() for v in values.split(",")]
        unknown = [v for v in names if v not in c.modalities and not v.isdigit()]
        if unknown:
            _fail(f"--select modality: unknown {unknown}; this campaign has "
                  f"{', '.join(c.modalities)}")
        ids = [int(v) if v.isdigit() else c.modalities.index(v) for v in names]
        return np.isin(c.modality, ids)
    if key == "direction":
        try:
            dirs = [parse_direction(v, "--select direction") for v in values.split(",")]
        except ValueError as exc:
            _fail(str(exc))
        return np.isin(c.direction, dirs)
    wanted = _ints(values, key)
    if key == "index":
        return np.isin(np.arange(len(c)), wanted)
    return np.isin(getattr(c, key), wanted)


def _selected(c: Any, select: list[str]) -> Any:
    import numpy as np

    mask = np.ones(len(c), dtype=bool)
    for item in select:
        mask &= _select_mask(c, item)
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        _fail(f"no recording of {len(c)} matches --select {' '.join(select)}")
    return idx


def _replay_format(output: Path, fmt: Optional[ReplayFormat]) -> str:
    if fmt is not None:
        return fmt.value
    by_suffix = {".eskr": "replay", ".npy": "npy", ".raw": "raw"}
    if output.suffix.lower() not in by_suffix:
        _fail(f"{output}: say what to write with --format (replay, npy, records or raw), or "
              f"name the file .eskr (a replay stream for eskin-fw-sim), .npy (for "
              f"eskin-classify) or .raw (a raw int16 stream)")
    return by_suffix[output.suffix.lower()]


def replay(
    campaign: Path = typer.Argument(..., metavar="CAMPAIGN", help="campaign file (.h5)"),
    output: Path = typer.Option(
        ..., "-o", "--output",
        help="file to write: .eskr (a replay stream for eskin-fw-sim), .npy (the "
        "recordings, for eskin-classify) or .raw (the replay stream's int16 samples alone)"),
    select: list[str] = typer.Option(
        [], "--select", metavar="KEY=VALUES",
        help="keep the recordings with these values: modality=brush,washer, "
        "participant=61-70, direction=h, run=2, index=0-9 (repeat to combine; default: "
        "every recording)"),
    fmt: Optional[ReplayFormat] = typer.Option(
        None, "--format", help="replay, npy, records (raw records of any lengths for "
        "eskin-classify) or raw (the replay stream without its header: int16 little-endian, "
        "one sample of every taxel, row by row, after another); default: from the file name"),
    gap: float = typer.Option(0.5, "--gap", help="replay and raw: seconds of quiet noise "
                              "between recordings"),
    seed: int = typer.Option(0, help="replay and raw: seed of the quiet noise"),
    force: bool = typer.Option(False, "--force", help="replace OUTPUT if it exists"),
) -> None:
    """Write a campaign's recordings for the controller: a replay stream that eskin-fw-sim
    plays over its serial link, the same stream as raw int16 samples (what a controller loop
    reads), or the recordings for eskin-classify (.npy or raw records)."""
    from collections import Counter

    from eskin._files import refuse_overwrite
    from eskin.data.campaign import load_campaign
    from eskin.data.replay import (
        write_raw_records,
        write_raw_stream,
        write_recordings_npy,
        write_replay_file,
    )

    kind = _replay_format(output, fmt)
    from eskin.data.replay import MAX_GAP_S

    if not 0 <= gap <= MAX_GAP_S:  # NaN and inf too
        _fail(f"--gap must be a number of seconds in [0, {MAX_GAP_S:g}], got {gap:g}")
    try:
        refuse_overwrite(output, force, inputs=(campaign,))
        with load_campaign(campaign) as c:
            idx = _selected(c, select)
            if kind == "replay":
                rf = write_replay_file(c, idx, output, gap_s=gap, seed=seed)
                detail = f", {rf.n_samples / rf.sample_rate_hz:.1f} s at {rf.sample_rate_hz:g} Hz"
            elif kind == "raw":
                n, rows, cols = write_raw_stream(c, idx, output, gap_s=gap, seed=seed)
                detail = (f", {n} samples of {rows}x{cols} taxels ({n / c.sample_rate_hz:.1f} s "
                          f"at {c.sample_rate_hz:g} Hz)")
            elif kind == "npy":
                detail = f", shape {write_recordings_npy(c, idx, output)}"
            else:
                write_raw_records(c, idx, output)
                detail = ""
            counts = Counter(c.modalities[int(m)] for m in c.modality[idx])
    except (ValueError, OSError) as exc:
        from eskin._files import error_line

        _fail(error_line(exc, output))
    per_class = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
    typer.echo(f"wrote {output}: {len(idx)} recordings ({per_class}){detail}; "
               f"{_FORMAT_USE[kind]}")


def _check_target(model: object, dtype: str, target: str) -> None:
    """Print the model's flash and RAM on ``target``; stop (nothing written) if it does not fit."""
    from eskin.deploy.export import CompiledModel
    from eskin.deploy.target import device_budget

    budget = device_budget(CompiledModel.from_model(model, dtype), target)
    for line in budget.report():
        typer.echo(line)
    if not budget.fits:
        _fail(f"the model does not fit {target}; nothing written")


def _header_name(path: Path) -> str:
    """The array prefix of a header: eskin_model unless the file name says otherwise."""
    stem = path.stem
    return "eskin_model" if stem in ("model", "") else stem
