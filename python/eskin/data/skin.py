"""The skin description: one TOML file naming the patches of a skin (docs/skin.md).

A robot skin is many patches, each read by its own controller over its own link. The
description says, for each patch: its id, taxel grid, sample rate, the link it arrives on (a
serial port, or ``"simulated"``), the model it is classified with, and where its taxels sit on
the body (a 2-D layout in millimetres); which patches touch each other (adjacency) is derived
from the layout, and may be completed by hand::

    name = "forearm"
    [defaults]
    grid = [4, 4]
    sample_rate_hz = 3000
    pitch_mm = 12.0
    link = "simulated"
    model = "touch.eskin"

    [[patch]]
    id = "palm-0"
    origin_mm = [0.0, 0.0]
    rotation_deg = 0.0

:func:`load_skin` reads and checks every field; a problem is a :class:`SkinFormatError` (a
``ValueError``) whose one-line message names the file, the field and the value.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

from eskin.data.limits import MAX_SAMPLE_RATE_HZ, MIN_SAMPLE_RATE_HZ
from eskin.errors import SkinFormatError

__all__ = ["SIMULATED", "Patch", "Skin", "SkinFormatError", "load_skin", "parse_skin"]

#: the ``link`` of a patch that no hardware reads: `eskin fw-sim --skin` simulates its controller
SIMULATED = "simulated"
FORMAT = "eskin-skin"
FORMAT_VERSION = 1
#: a patch id: what file names, campaign fields and logs carry
_ID_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_.")
_TOP_KEYS = {"format", "format_version", "name", "description", "adjacency_mm", "defaults",
             "patch"}
_PATCH_KEYS = {"id", "grid", "sample_rate_hz", "link", "model", "pitch_mm", "origin_mm",
               "rotation_deg", "taxels_mm", "neighbours"}
_DEFAULT_KEYS = {"grid", "sample_rate_hz", "link", "model", "pitch_mm"}
MAX_PATCHES = 4096
MAX_GRID_SIDE = 255


@dataclass(frozen=True)
class Patch:
    """One patch of a skin: ``taxels_mm`` is (rows * cols, 2), the body position of each taxel
    in row-major order; ``model`` is an absolute path or None; ``link`` a port path or
    :data:`SIMULATED`."""

    id: str
    grid: tuple[int, int]
    sample_rate_hz: float
    link: str
    model: Path | None
    pitch_mm: float
    taxels_mm: np.ndarray = field(repr=False, compare=False)

    @property
    def simulated(self) -> bool:
        return self.link == SIMULATED

    @property
    def n_taxels(self) -> int:
        return self.grid[0] * self.grid[1]

    @property
    def centre_mm(self) -> np.ndarray:
        return self.taxels_mm.mean(axis=0)


@dataclass(frozen=True)
class Skin:
    """A skin: its patches in file order and, for each patch id, its neighbours' ids."""

    path: Path | None
    name: str
    patches: tuple[Patch, ...]
    adjacency: Mapping[str, tuple[str, ...]]
    description: str = ""

    def __len__(self) -> int:
        return len(self.patches)

    @property
    def ids(self) -> list[str]:
        return [p.id for p in self.patches]

    def patch(self, patch_id: str) -> Patch:
        for p in self.patches:
            if p.id == patch_id:
                return p
        raise KeyError(f"{self.path or '<memory>'}: no patch {patch_id!r} (patches: "
                       f"{', '.join(self.ids[:8])}{', ...' if len(self) > 8 else ''})")

    def neighbours(self, patch_id: str) -> tuple[str, ...]:
        self.patch(patch_id)
        return tuple(self.adjacency.get(patch_id, ()))

    def with_model(self, model: str | os.PathLike[str]) -> Skin:
        """This skin with every patch classified by ``model`` (a command's --model)."""
        path = Path(model).resolve()
        patches = tuple(_replace_model(p, path) for p in self.patches)
        return Skin(self.path, self.name, patches, self.adjacency, self.description)


def _replace_model(p: Patch, model: Path) -> Patch:
    return Patch(p.id, p.grid, p.sample_rate_hz, p.link, model, p.pitch_mm, p.taxels_mm)


# --------------------------------------------------------------------------- reading


def load_skin(path: str | os.PathLike[str]) -> Skin:
    """Read and check a skin description file (TOML; see the module docstring)."""
    path = Path(path)
    try:
        text = path.read_bytes()
    except FileNotFoundError:
        raise SkinFormatError(path, "", "no such file") from None
    except IsADirectoryError:
        raise SkinFormatError(path, "", "is a folder, not a skin description (.toml)") from None
    try:
        data = tomllib.loads(text.decode("utf-8"))
    except UnicodeDecodeError:
        raise SkinFormatError(path, "", "not UTF-8 text (a skin description is TOML)") from None
    except tomllib.TOMLDecodeError as exc:
        raise SkinFormatError(path, "", f"not valid TOML: {exc}") from None
    return parse_skin(data, path=path)


def parse_skin(data: Mapping[str, Any], *, path: str | os.PathLike[str] | None = None) -> Skin:
    """A :class:`Skin` from the parsed TOML ``data`` (relative model paths are taken from the
    folder of ``path``, else from the working folder)."""
    where = None if path is None else Path(path)
    _Check(where).keys("", data, _TOP_KEYS)
    check = _Check(where)
    if "format" in data and data["format"] != FORMAT:
        check.fail("format", f"{data['format']!r}: expected {FORMAT!r}")
    if "format_version" in data and data["format_version"] != FORMAT_VERSION:
        check.fail("format_version", f"{data['format_version']!r}: this eskin reads version "
                   f"{FORMAT_VERSION}")
    name = check.text("name", data.get("name", where.stem if where else "skin"))
    description = check.text("description", data.get("description", ""), empty_ok=True)
    defaults = data.get("defaults", {})
    if not isinstance(defaults, Mapping):
        check.fail("defaults", f"{defaults!r}: must be a table")
    check.keys("defaults", defaults, _DEFAULT_KEYS)
    rows = data.get("patch")
    if not isinstance(rows, list) or not rows:
        check.fail("patch", "no [[patch]] table: a skin has at least one patch")
    if len(rows) > MAX_PATCHES:
        check.fail("patch", f"{len(rows)} patches: at most {MAX_PATCHES}")
    base = where.parent if where is not None else Path.cwd()
    patches = tuple(_patch(check, i, row, defaults, base) for i, row in enumerate(rows))
    _unique_ids(check, patches)
    reach = check.positive("adjacency_mm", data.get("adjacency_mm", None), optional=True)
    adjacency = _adjacency(check, patches, rows, reach)
    return Skin(where, name, patches, adjacency, description)


class _Check:
    """The checks of one file's fields; each failure is a SkinFormatError naming the field."""

    def __init__(self, where: Path | None) -> None:
        self.where = where

    def fail(self, fld: str, problem: str) -> None:
        raise SkinFormatError(self.where, fld, problem)

    def keys(self, table: str, data: Any, allowed: set[str]) -> None:
        if not isinstance(data, Mapping):
            self.fail(table, f"{data!r}: must be a table")
        unknown = sorted(set(data) - allowed)
        if unknown:
            prefix = f"{table}." if table else ""
            self.fail(f"{prefix}{unknown[0]}", f"unknown key (known: {', '.join(sorted(allowed))})")

    def text(self, fld: str, value: Any, empty_ok: bool = False) -> str:
        if not isinstance(value, str) or (not value and not empty_ok):
            self.fail(fld, f"{value!r}: must be a{'' if empty_ok else ' non-empty'} string")
        return value

    def number(self, fld: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            self.fail(fld, f"{value!r}: must be a finite number")
        return float(value)

    def positive(self, fld: str, value: Any, optional: bool = False) -> Any:
        if value is None and optional:
            return None
        v = self.number(fld, value)
        if v <= 0:
            self.fail(fld, f"{value!r}: must be > 0")
        return v

    def pair(self, fld: str, value: Any) -> tuple[float, float]:
        if not isinstance(value, list) or len(value) != 2:
            self.fail(fld, f"{value!r}: must be a pair of numbers [x, y]")
        return self.number(fld, value[0]), self.number(fld, value[1])


def _field(row: Mapping[str, Any], defaults: Mapping[str, Any], key: str, fld: str,
           check: _Check) -> Any:
    if key in row:
        return row[key]
    if key in defaults:
        return defaults[key]
    check.fail(fld, "missing (give it in the patch or in [defaults])")
    return None


def _patch(check: _Check, i: int, row: Any, defaults: Mapping[str, Any], base: Path) -> Patch:
    at = f"patch[{i}]"
    check.keys(at, row, _PATCH_KEYS)
    pid = check.text(f"{at}.id", row.get("id"))
    if not set(pid) <= _ID_CHARS:
        check.fail(f"{at}.id", f"{pid!r}: letters, digits, '-', '_' and '.' only")
    grid = _grid(check, f"{at}.grid", _field(row, defaults, "grid", f"{at}.grid", check))
    rate = check.number(f"{at}.sample_rate_hz",
                        _field(row, defaults, "sample_rate_hz", f"{at}.sample_rate_hz", check))
    if not MIN_SAMPLE_RATE_HZ <= rate <= MAX_SAMPLE_RATE_HZ:
        check.fail(f"{at}.sample_rate_hz", f"{rate:g}: must be {MIN_SAMPLE_RATE_HZ:g} to "
                   f"{MAX_SAMPLE_RATE_HZ:g} Hz")
    link = check.text(f"{at}.link", _field(row, defaults, "link", f"{at}.link", check))
    model_value = row.get("model", defaults.get("model"))
    model = None
    if model_value is not None:
        model = base / check.text(f"{at}.model", model_value)
    pitch = check.positive(f"{at}.pitch_mm", row.get("pitch_mm", defaults.get("pitch_mm", 12.0)))
    taxels = _taxels(check, at, row, grid, pitch)
    return Patch(pid, grid, rate, link, model, pitch, taxels)


def _grid(check: _Check, fld: str, value: Any) -> tuple[int, int]:
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        check.fail(fld, f"{value!r}: must be [rows, cols], two integers")
    rows, cols = value
    if not (1 <= rows <= MAX_GRID_SIDE and 1 <= cols <= MAX_GRID_SIDE):
        check.fail(fld, f"{value!r}: rows and columns must be in 1..{MAX_GRID_SIDE}")
    return int(rows), int(cols)


def _taxels(check: _Check, at: str, row: Mapping[str, Any], grid: tuple[int, int],
            pitch: float) -> np.ndarray:
    """Every taxel's body position (mm): the explicit ``taxels_mm`` list, or the grid laid out
    from ``origin_mm`` (the centre of taxel (0, 0)) at ``pitch_mm``, columns along +x and rows
    along -y, turned by ``rotation_deg`` counter-clockwise about the origin."""
    if "taxels_mm" in row:
        if "origin_mm" in row or "rotation_deg" in row:
            check.fail(f"{at}.taxels_mm", "give either taxels_mm or origin_mm/rotation_deg")
        value = row["taxels_mm"]
        n = grid[0] * grid[1]
        if not isinstance(value, list) or len(value) != n:
            check.fail(f"{at}.taxels_mm", f"must list {n} positions [x, y] (one per taxel, "
                       f"row-major), got {len(value) if isinstance(value, list) else value!r}")
        return np.array([check.pair(f"{at}.taxels_mm[{k}]", v) for k, v in enumerate(value)])
    ox, oy = check.pair(f"{at}.origin_mm", row.get("origin_mm", [0.0, 0.0]))
    theta = math.radians(check.number(f"{at}.rotation_deg", row.get("rotation_deg", 0.0)))
    r, c = np.meshgrid(np.arange(grid[0]), np.arange(grid[1]), indexing="ij")
    local = np.stack([c.ravel() * pitch, -r.ravel() * pitch], axis=1)
    turn = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    return local @ turn.T + np.array([ox, oy])


def _unique_ids(check: _Check, patches: tuple[Patch, ...]) -> None:
    seen: dict[str, int] = {}
    for i, p in enumerate(patches):
        if p.id in seen:
            check.fail(f"patch[{i}].id", f"{p.id!r}: already the id of patch[{seen[p.id]}]")
        seen[p.id] = i


def _adjacency(check: _Check, patches: tuple[Patch, ...], rows: list[Any],
               reach: float | None) -> dict[str, tuple[str, ...]]:
    """Neighbours of each patch: two patches are adjacent when a taxel of one lies within
    ``reach`` (default 1.25 x the larger pitch: patches that share an edge, not a corner) of a taxel of the other, or when either names the
    other in ``neighbours``; the relation is symmetric."""
    ids = [p.id for p in patches]
    links: dict[str, set[str]] = {i: set() for i in ids}
    for a in range(len(patches)):
        for b in range(a + 1, len(patches)):
            pa, pb = patches[a], patches[b]
            limit = reach if reach is not None else 1.25 * max(pa.pitch_mm, pb.pitch_mm)
            d = np.linalg.norm(pa.taxels_mm[:, None, :] - pb.taxels_mm[None, :, :], axis=-1)
            if float(d.min()) <= limit + 1e-9:
                links[pa.id].add(pb.id)
                links[pb.id].add(pa.id)
    for i, row in enumerate(rows):
        named = row.get("neighbours", [])
        fld = f"patch[{i}].neighbours"
        if not isinstance(named, list) or not all(isinstance(n, str) for n in named):
            check.fail(fld, f"{named!r}: must be a list of patch ids")
        for n in named:
            if n not in links or n == ids[i]:
                check.fail(fld, f"{n!r}: not the id of another patch")
            links[ids[i]].add(n)
            links[n].add(ids[i])
    return {i: tuple(sorted(links[i], key=ids.index)) for i in ids}
