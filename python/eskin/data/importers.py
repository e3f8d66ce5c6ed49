"""Importers: recordings from other tools -> an eskin campaign file (source="recorded").

Two layouts are read (both documented in ``docs/dataset-format.md``):

* :func:`import_csv_folder` - a folder of CSV files, one recording per file, one column per
  taxel (row-major: column k is taxel (k // cols, k % cols)), plus a manifest CSV listing each
  file with its modality label, participant, direction and run;
* :func:`import_tdms` - LabVIEW TDMS files (read with npTDMS), one group per recording, one
  channel per taxel, the labels in the group's (or the file's) properties.

Both stream: one recording is in memory at a time. Both raise ``ValueError`` (or
``FileNotFoundError``) with a message naming the file, the line or channel, and the problem.
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eskin.data.campaign import (
    DIRECTION_HORIZONTAL,
    DIRECTION_UNKNOWN,
    DIRECTION_VERTICAL,
    CampaignWriter,
)

_DIRECTIONS = {
    "0": DIRECTION_HORIZONTAL, "h": DIRECTION_HORIZONTAL, "horizontal": DIRECTION_HORIZONTAL,
    "1": DIRECTION_VERTICAL, "v": DIRECTION_VERTICAL, "vertical": DIRECTION_VERTICAL,
    "255": DIRECTION_UNKNOWN, "": DIRECTION_UNKNOWN, "unknown": DIRECTION_UNKNOWN,
    "?": DIRECTION_UNKNOWN, "nan": DIRECTION_UNKNOWN,
}
#: seconds per unit of a time column (import_csv_folder's ``time_unit``)
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
#: header names recognised as a time column (any position, any case), with their unit; None:
#: a sample index (dropped, gives no rate)
TIME_COLUMNS: dict[str, str | None] = {
    **dict.fromkeys(("t", "time", "time_s", "t_s", "times", "seconds", "sec", "secs", "s",
                     "timestamp", "timestamp_s", "time_sec", "elapsed_s"), "s"),
    **dict.fromkeys(("time_ms", "t_ms", "ms", "millis", "milliseconds", "timestamp_ms",
                     "elapsed_ms"), "ms"),
    **dict.fromkeys(("time_us", "t_us", "us", "micros", "microseconds", "timestamp_us",
                     "elapsed_us"), "us"),
    **dict.fromkeys(("sample", "samples", "index", "sample_index", "n"), None),
}
#: the attribute an import writes when no volts per count was given (the values are counts)
VPC_NOT_GIVEN = "not given: the values were imported as ADC counts"


@dataclass(frozen=True)
class TimeColumn:
    """Which column of a recording CSV holds the time (or a sample index) and its unit."""

    index: int
    name: str
    unit: str | None  # "s", "ms", "us"; None: a sample index


def find_time_column(names: Sequence[str], path: Path, time_column: str | None = None,
                     time_unit: str | None = None) -> TimeColumn | None:
    """The time column of a CSV header: the one named ``time_column`` (any case; its unit is
    ``time_unit``, else the unit its name says), else the first header name of
    :data:`TIME_COLUMNS`; None when there is none."""
    if time_unit is not None and time_unit not in TIME_UNITS:
        raise ValueError(f"time unit {time_unit!r}: use one of {', '.join(TIME_UNITS)}")
    lower = [n.strip().lower() for n in names]
    if time_column is not None:
        want = time_column.strip().lower()
        if want not in lower:
            raise ValueError(f"{path}: no column {time_column!r} (--time-column); the header "
                             f"has {', '.join(map(repr, names[:8]))}"
                             f"{', ...' if len(names) > 8 else ''}")
        k = lower.index(want)
        _check_unit(path, names[k], time_unit)
        unit = time_unit or TIME_COLUMNS.get(want)
        if unit is None and want not in TIME_COLUMNS:
            raise ValueError(f"{path}: time column {names[k]!r}: its name does not say its "
                             f"unit; give --time-unit s, ms or us")
        return TimeColumn(k, names[k], unit)
    for k, n in enumerate(lower):
        if n in TIME_COLUMNS:
            _check_unit(path, names[k], time_unit)
            return TimeColumn(k, names[k], time_unit or TIME_COLUMNS[n])
    return None


#: the unit a time column's name states by its suffix (time_ms, t_us, elapsed_s) or whole
#: (ms, millis, seconds); a bare "t", "time" or "timestamp" states none
_UNIT_WORDS = {"s": ("s", "sec", "secs", "seconds"), "ms": ("ms", "millis", "milliseconds"),
               "us": ("us", "micros", "microseconds")}


def unit_in_name(name: str) -> str | None:
    """The unit ("s", "ms", "us") a column name states, or None."""
    low = name.strip().lower()
    last = low.replace("-", "_").replace(" ", "_").rsplit("_", 1)[-1]
    for unit, words in _UNIT_WORDS.items():
        if low in words or (last != low and last in words):
            return unit
    return None


def _check_unit(path: Path, name: str, time_unit: str | None) -> None:
    """Refuse a --time-unit that contradicts the unit the column's name states (time_ms read
    as seconds gives a rate 1000 times too low, without a word)."""
    stated = unit_in_name(name)
    if time_unit is not None and stated is not None and stated != time_unit:
        raise ValueError(f"{path}: time column {name!r}: its name says {stated}, --time-unit "
                         f"says {time_unit}; give --time-unit {stated} (or leave it out), or "
                         f"name the column by its unit")
#: the grid taken when none is given and a recording has 16 taxels: the paper's sensor
DEFAULT_GRID = (4, 4)


def parse_direction(value: Any, where: str) -> int:
    """'h'/'horizontal'/0 -> 0, 'v'/'vertical'/1 -> 1, ''/'unknown'/255 -> 255."""
    key = str(value).strip().lower()
    key = key.removesuffix(".0")
    if key not in _DIRECTIONS:
        raise ValueError(
            f"{where}: direction {value!r} not understood (use h/horizontal/0, v/vertical/1, "
            f"or unknown/255/empty)")
    return _DIRECTIONS[key]


def _parse_int(value: Any, where: str, what: str, lo: int, hi: int) -> int:
    try:
        f = float(str(value).strip())
    except ValueError:
        raise ValueError(f"{where}: {what} {value!r} is not a number") from None
    if not math.isfinite(f) or f != int(f) or not lo <= f <= hi:
        raise ValueError(f"{where}: {what} {value!r} must be an integer in [{lo}, {hi}]")
    return int(f)


def _class_ids(labels: Sequence[str], modalities: Sequence[str] | None,
               where: str) -> tuple[list[str], list[int]]:
    if modalities is None:
        names = sorted(set(labels))
    else:
        names = [str(m).strip() for m in modalities]
        unknown = sorted(set(labels) - set(names))
        if unknown:
            raise ValueError(
                f"{where}: modality labels {unknown} are not among the given modalities {names}")
    if not names:
        raise ValueError(f"{where}: no recordings listed")
    return names, [names.index(lab) for lab in labels]


def _to_counts(x: np.ndarray, volts_per_count: float | None, units: str,
               where: str) -> np.ndarray:
    """Samples (counts or volts) -> int16 counts, with clear errors."""
    if not np.all(np.isfinite(x)):
        bad = np.argwhere(~np.isfinite(x))[0]
        raise ValueError(f"{where}: non-finite value at sample {bad[-1]}")
    if units == "auto":
        units = "counts" if np.all(x == np.round(x)) else "volts"
    if units == "volts":
        if volts_per_count is None:
            bad = np.argwhere(x != np.round(x))
            at = f" (the first at sample {bad[0][-1]})" if len(bad) else ""
            raise ValueError(f"{where}: values are not integers{at}, so they are taken for volts "
                             f"and need the volts per ADC count (--volts-per-count, or a "
                             f"manifest column 'volts_per_count')")
        x = np.round(x / volts_per_count)
    elif units != "counts":
        raise ValueError(f"units must be 'auto', 'counts' or 'volts', got {units!r}")
    if x.size and (x.min() < -32768 or x.max() > 32767):
        raise ValueError(
            f"{where}: values span [{x.min():g}, {x.max():g}] counts, outside int16 "
            f"(check units and volts_per_count)")
    return x.astype(np.int16)


# --------------------------------------------------------------------------- CSV


@dataclass
class _CsvEntry:
    file: Path
    label: str
    participant: int
    direction: int
    run: int
    line: int


def _read_manifest(manifest: Path) -> tuple[list[dict[str, str]], list[str]]:
    try:
        with open(manifest, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            if reader.fieldnames is None:
                raise ValueError(f"{manifest}: empty manifest (expected a header line)")
            fields = [f.strip().lower() for f in reader.fieldnames]
            rows = [{(k or "").strip().lower(): (v or "").strip() for k, v in row.items()}
                    for row in reader]
    except UnicodeDecodeError as exc:
        raise ValueError(f"{manifest}: not a text CSV file ({exc.reason})") from None
    return rows, fields


def _one_value(rows: list[dict[str, str]], column: str, manifest: Path) -> str | None:
    vals = {r.get(column, "") for r in rows} - {""}
    if not vals:
        return None
    if len(vals) > 1:
        raise ValueError(
            f"{manifest}: column {column!r} must hold one value for the whole campaign, "
            f"found {sorted(vals)}")
    return vals.pop()


def _csv_header(path: Path) -> tuple[bool, list[str], int]:
    """(has_header, header names, number of columns of the first line)."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        first = fh.readline()
    if not first.strip():
        return False, [], 0
    cells = next(csv.reader([first]))
    try:
        [float(c) for c in cells]
        return False, [], len(cells)
    except ValueError:
        return True, [c.strip() for c in cells], len(cells)


def _time_hint(names: Sequence[str]) -> str:
    """For a column-count error: a header name that looks like a time column but is not one
    that is recognised, and the options that declare it."""
    for n in names:
        low = n.strip().lower()
        looks_like_time = re.search(r"time|stamp|clock|elapsed|^ts?_|_ts?$|^ts$", low)
        if low not in TIME_COLUMNS and looks_like_time:
            return (f"; if column {n!r} is the time, give --time-column {n} --time-unit s|ms|us "
                    f"(recognised without options: time, t, time_s, time_ms, time_us, "
                    f"timestamp, ...)")
    return ""


def _read_csv_recording(path: Path, n_taxels: int, time_column: str | None = None,
                        time_unit: str | None = None) -> np.ndarray:
    """One recording CSV -> float64 (n_taxels, length), its time column dropped."""
    has_header, names, n_cols = _csv_header(path)
    if n_cols == 0:
        raise ValueError(f"{path}: empty file")
    if time_column is not None and not has_header:
        raise ValueError(f"{path}: --time-column {time_column!r} names a header column, but "
                         f"the file's first line holds numbers (no header)")
    tc = find_time_column(names, path, time_column, time_unit) if has_header else None
    use = n_cols - (1 if tc is not None else 0)
    if use != n_taxels:
        raise ValueError(
            f"{path}: {use} taxel columns"
            f"{f' (after the time column {tc.name!r})' if tc is not None else ''}, expected "
            f"{n_taxels} (rows x cols){_time_hint(names) if tc is None else ''}")
    data = _load_numbers(path, has_header, names, n_cols)
    if tc is not None:
        data = np.delete(data, tc.index, axis=1)
    return np.ascontiguousarray(data.T)


def _load_numbers(path: Path, has_header: bool, names: Sequence[str], n_cols: int,
                  usecols: int | None = None) -> np.ndarray:
    """The numbers of a recording CSV (float64 (lines, n_cols), or (lines,) of column
    ``usecols``). A bad cell or line is reported at the file's own 1-based line number."""
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1 if has_header else 0, ndmin=2,
                          dtype=np.float64, encoding="utf-8-sig",
                          usecols=None if usecols is None else (usecols,))
    except ValueError as exc:
        raise ValueError(_first_bad_cell(path, has_header, names, n_cols) or f"{path}: {exc}"
                         ) from None
    if data.shape[0] == 0:
        raise ValueError(f"{path}: no samples")
    if usecols is None and data.shape[1] != n_cols:
        raise ValueError(f"{path}: rows have {data.shape[1]} columns, header has {n_cols}")
    return data if usecols is None else data[:, 0]


def _first_bad_cell(path: Path, has_header: bool, names: Sequence[str], n_cols: int) -> str:
    """'FILE, line 100, column 2 ('r0c1'): '' is not a number' for the first cell that is not a
    number (or line with a wrong number of cells), counting lines as an editor does; '' if
    none is found."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        for line_no, cells in enumerate(csv.reader(fh), start=1):
            if line_no == 1 and has_header:
                continue
            if not cells or (len(cells) == 1 and not cells[0].strip()):
                continue  # a blank line: skipped
            if len(cells) != n_cols:
                return (f"{path}, line {line_no}: {len(cells)} cells, expected {n_cols} (as the "
                        f"{'header' if has_header else 'first line'})")
            for col, cell in enumerate(cells, start=1):
                try:
                    float(cell)
                except ValueError:
                    name = f" ({names[col - 1]!r})" if has_header and col <= len(names) else ""
                    return f"{path}, line {line_no}, column {col}{name}: {cell!r} is not a number"
    return ""


def _count_lines(path: Path) -> int:
    has_header, _, _ = _csv_header(path)
    with open(path, "rb") as fh:
        n = sum(1 for line in fh if line.strip())
    return n - (1 if has_header else 0)


def _manifest_setting(rows: list[dict[str, str]], man: Path, column: str, cast: Any) -> Any:
    v = _one_value(rows, column, man)
    if v is None:
        return None
    try:
        return cast(v)
    except ValueError:
        raise ValueError(f"{man}: column {column!r} value {v!r} is not a number") from None


def _rate_from_time_column(path: Path, time_column: str | None = None,
                           time_unit: str | None = None) -> float | None:
    """The sample rate read from a recording's time column (evenly spaced; seconds, ms or us,
    see :func:`find_time_column`); None when it has none, or only a sample index."""
    has_header, names, n_cols = _csv_header(path)
    tc = find_time_column(names, path, time_column, time_unit) if has_header else None
    if tc is None or tc.unit is None:
        return None
    t = _load_numbers(path, True, names, n_cols, usecols=tc.index) * TIME_UNITS[tc.unit]
    dt = np.diff(t)
    if t.size < 2 or not np.all(np.isfinite(t)) or not np.all(dt > 0):
        raise ValueError(f"{path}: time column {tc.name!r} does not increase, so it gives no "
                         f"sample rate (give --rate)")
    step = (t[-1] - t[0]) / (t.size - 1)
    if np.max(np.abs(dt - step)) > 0.01 * step:
        raise ValueError(f"{path}: time column {tc.name!r} is not evenly spaced (steps "
                         f"{dt.min():g} to {dt.max():g} s), so it gives no sample rate "
                         f"(give --rate)")
    return float(f"{1.0 / step:.6g}")


def _taxel_columns(path: Path, time_column: str | None = None,
                   time_unit: str | None = None) -> int:
    has_header, names, n = _csv_header(path)
    tc = find_time_column(names, path, time_column, time_unit) if has_header else None
    return n - (1 if tc is not None else 0)


def _csv_settings(
    rows: list[dict[str, str]], man: Path, first: Path | None, grid_shape: Any,
    rate: float | None, vpc: float | None, time_column: str | None = None,
    time_unit: str | None = None,
) -> tuple[tuple[int, int], float, float | None]:
    """Grid, rate and volts per count: from the arguments, else the manifest, else (grid) 4x4
    when the first recording has 16 taxel columns and (rate) its time column; every setting
    still missing is named in one error."""
    readable = first is not None and first.is_file()
    grid_note = ""
    if grid_shape is None:
        r = _manifest_setting(rows, man, "rows", int)
        c = _manifest_setting(rows, man, "cols", int)
        if r is not None and c is not None:
            grid_shape = (r, c)
        elif readable:
            n_taxels = _taxel_columns(first, time_column, time_unit)
            if n_taxels == DEFAULT_GRID[0] * DEFAULT_GRID[1]:
                grid_shape = DEFAULT_GRID
            else:
                grid_note = (f", the first recording has {n_taxels}"
                             f"{_time_hint(_csv_header(first)[1])}")
    if rate is None:
        rate = _manifest_setting(rows, man, "sample_rate_hz", float)
    if rate is None and readable:
        rate = _rate_from_time_column(first, time_column, time_unit)
    if vpc is None:
        vpc = _manifest_setting(rows, man, "volts_per_count", float)
    missing = [what for what, value in (
        ("the grid (--rows and --cols, or manifest columns 'rows' and 'cols'; 4x4 is taken "
         f"only for 16 taxel columns{grid_note})", grid_shape),
        ("the sample rate (--rate, a manifest column 'sample_rate_hz', or a time column in "
         "the recordings: a column named time, t, time_ms, time_us, timestamp, ... or given "
         "by --time-column NAME --time-unit s|ms|us)", rate),
    ) if value is None]
    if missing:
        raise ValueError(f"{man}: {len(missing)} setting(s) not given: " + "; ".join(missing))
    return grid_shape, float(rate), None if vpc is None else float(vpc)


def _manifest_entries(rows_: list[dict[str, str]], man: Path, folder: Path) -> list[_CsvEntry]:
    """The manifest's lines, checked: each recording file exists, its labels parse."""
    entries: list[_CsvEntry] = []
    for k, row in enumerate(rows_):
        line = k + 2
        where = f"{man}, line {line}"
        if not row["file"]:
            raise ValueError(f"{where}: empty 'file'")
        f = (folder / row["file"]).resolve()
        if not f.is_file():
            raise FileNotFoundError(f"{where}: recording file {row['file']!r} not found in "
                                    f"{folder}")
        if not row["modality"]:
            raise ValueError(f"{where}: empty 'modality'")
        entries.append(_CsvEntry(
            f, row["modality"], _parse_int(row["participant"], where, "participant",
                                           -2**31, 2**31 - 1),
            parse_direction(row["direction"], where),
            _parse_int(row["run"], where, "run", 0, 255), line))
    return entries


def import_csv_folder(
    folder: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    manifest: str | os.PathLike[str] | None = None,
    grid_shape: tuple[int, int] | None = None,
    sample_rate_hz: float | None = None,
    volts_per_count: float | None = None,
    modalities: Sequence[str] | None = None,
    units: str = "auto",
    overwrite: bool = False,
    attrs: Mapping[str, Any] | None = None,
    time_column: str | None = None,
    time_unit: str | None = None,
) -> Path:
    """Import a folder of CSV recordings into a campaign file at ``output``.

    The manifest (default ``folder/manifest.csv``) has a header and one line per recording with
    columns ``file`` (relative to the folder), ``modality`` (a label), ``participant`` (integer),
    ``direction`` (h/horizontal/0, v/vertical/1, or unknown/255/empty) and ``run`` (integer).
    Optional columns, one value for the whole campaign: ``rows``, ``cols``, ``sample_rate_hz``,
    ``volts_per_count`` (arguments override them). Without them, the grid is 4x4 when the
    recordings have 16 taxel columns, and the rate is read from the recordings' time column
    (evenly spaced). Every setting still missing is named in one error. Each recording CSV: one
    column per taxel in row-major order, an optional header line, one line per sample. A time
    column is dropped: the header column named ``time_column`` (unit ``time_unit``: "s", "ms" or
    "us", else the one its name says), else the first one named as in :data:`TIME_COLUMNS`
    (time, t, time_s, timestamp in seconds; time_ms, t_ms in ms; time_us in us; sample, index:
    a sample index). Integers are ADC counts, other numbers volts (``units`` forces one);
    ``volts_per_count`` converts volts to counts and is stored in the campaign (plots show
    volts with it). It is needed only for volts: integer counts are imported as they are, and
    without it the campaign stores 1.0 and the attribute ``volts_per_count_given`` =
    :data:`VPC_NOT_GIVEN`. A cell that is not a number is reported at the file's own 1-based
    line and column. Recordings may differ in length: the campaign pads them (``length`` keeps
    each). Class ids follow ``modalities`` if given, else the sorted labels.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    man = Path(manifest) if manifest is not None else folder / "manifest.csv"
    if not man.is_file():
        raise FileNotFoundError(f"{man}: manifest not found (a CSV with columns file, modality, "
                                f"participant, direction, run)")
    rows_, fields = _read_manifest(man)
    missing = [c for c in ("file", "modality", "participant", "direction", "run")
               if c not in fields]
    if missing:
        raise ValueError(f"{man}: missing column(s) {missing} (found {fields})")
    if not rows_:
        raise ValueError(f"{man}: lists no recordings")

    first = (folder / rows_[0]["file"]).resolve() if rows_[0].get("file") else None
    grid_shape, rate, vpc = _csv_settings(rows_, man, first, grid_shape, sample_rate_hz,
                                          volts_per_count, time_column, time_unit)
    n_rows, n_cols = int(grid_shape[0]), int(grid_shape[1])
    if n_rows < 1 or n_cols < 1:
        raise ValueError(f"grid shape must be positive, got {grid_shape}")

    entries = _manifest_entries(rows_, man, folder)
    names, ids = _class_ids([e.label for e in entries], modalities, str(man))
    lengths = [_count_lines(e.file) for e in entries]
    t = max(max(lengths), 1)
    extra = {} if vpc is not None else {"volts_per_count_given": VPC_NOT_GIVEN}
    with CampaignWriter(output, grid_shape=(n_rows, n_cols), n_samples=t,
                        sample_rate_hz=rate, volts_per_count=1.0 if vpc is None else vpc,
                        modalities=names, source="recorded", overwrite=overwrite,
                        on_error="discard",
                        attrs={"imported_from": f"csv folder {folder.name}", **extra,
                               **dict(attrs or {})}
                        ) as w:
        for e, cid in zip(entries, ids):
            x = _read_csv_recording(e.file, n_rows * n_cols, time_column, time_unit)
            counts = _to_counts(x, vpc, units, str(e.file))
            w.append(counts.reshape(n_rows, n_cols, -1), modality=cid,
                     participant=e.participant, direction=e.direction, run=e.run)
    return Path(output)


# --------------------------------------------------------------------------- TDMS


def _natural_key(name: str) -> list[Any]:
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", name)]


def _prop(obj: Any, *names: str) -> Any:
    props = getattr(obj, "properties", {}) or {}
    lower = {str(k).lower(): v for k, v in props.items()}
    for n in names:
        if n.lower() in lower:
            return lower[n.lower()]
    return None


def _taxel_order(channels: list[Any], n_rows: int, n_cols: int, where: str) -> list[Any]:
    """Channels in row-major taxel order: by taxel_row/taxel_col properties when all have
    them, else by 'r<i>c<j>' names, else by natural name order."""
    rc = [(_prop(ch, "taxel_row", "row"), _prop(ch, "taxel_col", "col", "column"))
          for ch in channels]
    if all(r is not None and c is not None for r, c in rc):
        pos = {}
        for ch, (r, c) in zip(channels, rc):
            r, c = int(r), int(c)
            if not (0 <= r < n_rows and 0 <= c < n_cols) or (r, c) in pos:
                raise ValueError(f"{where}: channel {ch.name!r} has taxel ({r}, {c}), out of the "
                                 f"{n_rows}x{n_cols} grid or repeated")
            pos[(r, c)] = ch
        return [pos[(r, c)] for r in range(n_rows) for c in range(n_cols)]
    pat = re.compile(r"^\D*r(?:ow)?[ _]?(\d+)[ _,-]*c(?:ol)?[ _]?(\d+)\D*$", re.IGNORECASE)
    m = [pat.match(ch.name) for ch in channels]
    if all(m):
        pos = {(int(x.group(1)), int(x.group(2))): ch for x, ch in zip(m, channels)}
        want = [(r, c) for r in range(n_rows) for c in range(n_cols)]
        base = min(k[0] for k in pos), min(k[1] for k in pos)
        if base == (1, 1):  # 1-based names
            pos = {(r - 1, c - 1): ch for (r, c), ch in pos.items()}
        if set(pos) == set(want):
            return [pos[k] for k in want]
    return sorted(channels, key=lambda ch: _natural_key(ch.name))


def _channel_count_problem(where: str, n: int, grid: tuple[int, int], defaulted: bool) -> str:
    return (f"{where}: {n} channels, expected one per taxel ({grid[0]}x{grid[1]} = "
            f"{grid[0] * grid[1]})" + ("; 4x4 is taken only for 16 channels: give the grid "
                                       "(--rows and --cols, or rows/cols properties)"
                                       if defaulted else ""))


def import_tdms(
    files: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    output: str | os.PathLike[str],
    *,
    grid_shape: tuple[int, int] | None = None,
    sample_rate_hz: float | None = None,
    volts_per_count: float | None = None,
    modalities: Sequence[str] | None = None,
    units: str = "auto",
    overwrite: bool = False,
    attrs: Mapping[str, Any] | None = None,
) -> Path:
    """Import LabVIEW TDMS files into a campaign file at ``output``.

    Mapping: every group of every file is one recording; its channels are the taxels
    (rows x cols of them, in row-major order: by channel properties ``taxel_row``/``taxel_col``
    if present, else names like ``r0c3``, else natural name order). Labels come from the
    group's properties, falling back to the file's: ``modality`` (a name), ``participant``,
    ``direction`` (h/v/0/1/unknown) and ``run``. The rate comes from ``sample_rate_hz`` (argument,
    group or file property) or the LabVIEW waveform property ``wf_increment`` (seconds per
    sample). Integer channels are ADC counts; floating channels are volts, converted with
    ``volts_per_count`` (argument or property; default 10/32768, a +-10 V 16-bit range).
    The grid is ``grid_shape``, else the file properties ``rows``/``cols``, else 4x4.
    """
    paths = [Path(files)] if isinstance(files, (str, os.PathLike)) else [Path(f) for f in files]
    if not paths:
        raise ValueError("no TDMS files given")
    for p in paths:
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such TDMS file")

    # pass 1: metadata only (no channel data is read)
    settings = (grid_shape, sample_rate_hz, volts_per_count)
    recs = [rec for p in paths for rec in _tdms_file_recordings(p, *settings)]
    grid, rate, vpc = _tdms_common_settings(recs)
    names, ids = _class_ids([r["label"] for r in recs], modalities, "TDMS files")
    t = max(max(r["length"] for r in recs), 1)

    # pass 2: one recording at a time
    with CampaignWriter(output, grid_shape=grid, n_samples=t, sample_rate_hz=rate,
                        volts_per_count=vpc, modalities=names, source="recorded",
                        overwrite=overwrite, on_error="discard",
                        attrs={"imported_from": "tdms " + ", ".join(p.name for p in paths[:10]),
                               **dict(attrs or {})}) as w:
        for rec, cid, counts in _tdms_counts(recs, ids, grid, vpc, units):
            w.append(counts.reshape(grid[0], grid[1], -1), modality=cid,
                     participant=rec["participant"], direction=rec["direction"],
                     run=rec["run"])
    return Path(output)


def _tdms_file_recordings(
    p: Path,
    grid_shape: tuple[int, int] | None,
    sample_rate_hz: float | None,
    volts_per_count: float | None,
) -> list[dict[str, Any]]:
    """The metadata of every group (recording) of one TDMS file; no channel data is read."""
    from nptdms import TdmsFile

    recs: list[dict[str, Any]] = []
    try:
        with open(p, "rb") as fh, TdmsFile.open(fh) as tf:
            groups = tf.groups()
            if not groups:
                raise ValueError(f"{p}: no groups (expected one group per recording)")
            for g in groups:
                recs.append(
                    _tdms_group_recording(p, tf, g, grid_shape, sample_rate_hz, volts_per_count)
                )
    except (OSError, KeyError, EOFError) as exc:
        raise ValueError(f"{p}: not a readable TDMS file ({exc})") from None
    except ValueError as exc:
        if str(exc).startswith(str(p)):
            raise
        raise ValueError(f"{p}: not a readable TDMS file ({exc})") from None
    return recs


def _tdms_group_recording(
    p: Path,
    tf: Any,
    g: Any,
    grid_shape: tuple[int, int] | None,
    sample_rate_hz: float | None,
    volts_per_count: float | None,
) -> dict[str, Any]:
    """One group's recording: labels, grid, rate and volts per count (group properties, else
    the file's), length, checked."""
    where = f"{p}, group {g.name!r}"
    chans = g.channels()
    if not chans:
        raise ValueError(f"{where}: no channels")

    def label(*names: str, _g: Any = g) -> Any:
        v = _prop(_g, *names)
        return v if v is not None else _prop(tf, *names)

    r = label("rows")
    c = label("cols", "columns")
    if grid_shape is not None:
        grid = (int(grid_shape[0]), int(grid_shape[1]))
    elif r is not None and c is not None:
        grid = (int(r), int(c))
    else:
        grid = DEFAULT_GRID
    if len(chans) != grid[0] * grid[1]:
        defaulted = grid_shape is None and (r is None or c is None)
        raise ValueError(_channel_count_problem(where, len(chans), grid, defaulted))
    rate = sample_rate_hz if sample_rate_hz is not None else label(
        "sample_rate_hz", "sample_rate")
    if rate is None:
        incs = {float(ch.properties.get("wf_increment", 0) or 0) for ch in chans}
        if len(incs) != 1 or next(iter(incs)) <= 0:
            raise ValueError(
                f"{where}: sample rate unknown (no sample_rate_hz property and "
                f"no single positive wf_increment on the channels)")
        rate = 1.0 / incs.pop()
    vpc = volts_per_count if volts_per_count is not None else label("volts_per_count")
    modality = label("modality", "label", "touch")
    if modality is None or str(modality).strip() == "":
        raise ValueError(f"{where}: no 'modality' property (group or file)")
    part = label("participant", "subject")
    if part is None:
        raise ValueError(f"{where}: no 'participant' property (group or file)")
    run = label("run")
    lengths = {len(ch) for ch in chans}
    if len(lengths) != 1:
        raise ValueError(f"{where}: channels have different lengths "
                         f"{sorted(lengths)}")
    return dict(
        path=p, group=g.name, where=where, label=str(modality).strip(),
        participant=_parse_int(part, where, "participant", -2**31, 2**31 - 1),
        direction=parse_direction(
            label("direction") if label("direction") is not None else "",
            where),
        run=_parse_int(run if run is not None else 0, where, "run", 0, 255),
        length=lengths.pop(), grid=grid, rate=round(float(rate), 6),
        vpc=None if vpc is None else float(vpc))


def _tdms_common_settings(recs: list[dict[str, Any]]) -> tuple[tuple[int, int], float, float]:
    """The one grid, sample rate and volts per count of every recording."""
    grid_seen = {r["grid"] for r in recs}
    rate_seen = {r["rate"] for r in recs}
    vpc_seen = {r["vpc"] for r in recs if r["vpc"] is not None}
    if len(grid_seen) != 1:
        raise ValueError(f"recordings have different grid shapes {sorted(grid_seen)}")
    if len(rate_seen) != 1:
        raise ValueError(f"recordings have different sample rates {sorted(rate_seen)} Hz")
    if len(vpc_seen) > 1:
        raise ValueError(f"recordings have different volts_per_count {sorted(vpc_seen)}")
    return grid_seen.pop(), rate_seen.pop(), vpc_seen.pop() if vpc_seen else 10.0 / 32768


def _tdms_counts(
    recs: list[dict[str, Any]], ids: Any, grid: tuple[int, int], vpc: float, units: str
) -> Iterator[tuple[dict[str, Any], int, np.ndarray]]:
    """(recording, class id, ADC counts (taxels, length)) one at a time, each file opened once
    for its consecutive groups."""
    from nptdms import TdmsFile

    open_file: Any = None
    try:
        for rec, cid in zip(recs, ids):
            if open_file is None or open_file[0] != rec["path"]:
                if open_file is not None:
                    open_file[1].close()
                    open_file[2].close()
                fh = open(rec["path"], "rb")  # noqa: SIM115 - closed below
                open_file = (rec["path"], TdmsFile.open(fh), fh)
            g = open_file[1][rec["group"]]
            chans = _taxel_order(g.channels(), grid[0], grid[1], rec["where"])
            x = np.stack([np.asarray(ch[:]) for ch in chans])
            if x.dtype.kind == "f":
                counts = _to_counts(x.astype(np.float64), vpc,
                                    "volts" if units == "auto" else units, rec["where"])
            elif x.dtype.kind in "iu":
                counts = _to_counts(x.astype(np.float64), vpc,
                                    "counts" if units == "auto" else units, rec["where"])
            else:
                raise ValueError(f"{rec['where']}: channel data of type {x.dtype} "
                                 f"(expected numbers)")
            yield rec, cid, counts
    finally:
        if open_file is not None:
            open_file[1].close()
            open_file[2].close()
