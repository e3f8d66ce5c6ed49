"""The package's folders are its layers (docs/architecture.md): every import of every module in
python/eskin, read from the source with ast (function-level imports included), must point to the
same layer or a lower one, and the modules must not import each other in a circle."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "python" / "eskin"

#: bottom up; a module may import its own layer and the layers before it
LAYERS: tuple[str, ...] = (
    "base",  # eskin/__init__.py, the compiled core and the private helpers next to it
    "data",
    "signal",
    "learn",
    "deploy",
    "link",
    "experiments",
    "demo",
    "cli",
    "__main__",
)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def package_modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


MODULES = package_modules()


def layer_of(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] not in LAYERS:
        return "base"
    return parts[1]


def imported_modules(module: str, path: Path) -> set[str]:
    """The eskin modules ``module`` imports (a name imported from a package resolves to the
    submodule of that name when there is one)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == "eskin")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            if source.split(".")[0] != "eskin":
                continue
            for alias in node.names:
                sub = f"{source}.{alias.name}"
                found.add(sub if sub in MODULES else source)
    found.discard(module)
    return found


@functools.cache
def import_graph() -> dict[str, set[str]]:
    return {m: imported_modules(m, p) for m, p in MODULES.items()}


def test_the_walk_sees_the_layers():
    # the test would pass vacuously if it found no module or no import
    graph = import_graph()
    assert {layer_of(m) for m in graph} == set(LAYERS)
    assert "eskin.learn.kernel" in graph["eskin.learn.estimators"]
    assert "eskin.learn.models" in graph["eskin.deploy.export"]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_only_go_down(module):
    rank = LAYERS.index(layer_of(module))
    upward = sorted(
        f"{target} ({layer_of(target)})"
        for target in import_graph()[module]
        if LAYERS.index(layer_of(target)) > rank
    )
    assert not upward, f"{module} ({layer_of(module)}) imports a higher layer: {upward}"


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (as the list of modules round it), or None."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)) is not None:
                return cycle
        state[node] = 2
        path.pop()
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start)) is not None:
            return cycle
    return None


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_import_circle():
    # a package's __init__ re-exporting its modules is not a circle: its modules import each
    # other by their own names, and the __init__ imports them, never the other way round
    cycle = find_cycle(import_graph())
    assert cycle is None, "import circle: " + " -> ".join(cycle or [])


def exception_classes() -> dict[str, list[str]]:
    """Class name -> the modules that define a class of that name deriving from an exception
    (a base named ``...Error`` / ``...Exception`` / ``...Warning``, or an earlier such class)."""
    found: dict[str, list[str]] = {}
    for module, path in MODULES.items():
        if path.suffix != ".py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.ClassDef):
                continue
            bases = [
                b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases
            ]
            if any(b.endswith(("Error", "Exception", "Warning")) for b in bases):
                found.setdefault(node.name, []).append(module)
    return found


def test_every_error_type_has_one_home():
    found = exception_classes()
    assert "ModelFormatError" in found and "CampaignFormatError" in found
    elsewhere = {name: mods for name, mods in found.items() if mods != ["eskin.errors"]}
    assert not elsewhere, f"error types defined outside eskin.errors (or twice): {elsewhere}"


# ---------------------------------------------------------------------------------- sizes

MAX_FUNCTION_LINES = 80
MAX_CLASS_LINES = 300
#: a definition may run longer only with this comment on the line above it, saying why
EXEMPTION = "# long:"


def definition_sizes() -> dict[str, tuple[int, int, bool]]:
    """Qualified name -> (lines, limit, exempted) of every function and class in the package
    (decorators not counted; nested definitions count in their parent and on their own)."""
    sizes: dict[str, tuple[int, int, bool]] = {}

    def walk(node: ast.AST, prefix: str, lines: list[str]) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}.{child.name}"
                limit = MAX_CLASS_LINES if isinstance(child, ast.ClassDef) else MAX_FUNCTION_LINES
                first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                exempt = first >= 2 and lines[first - 2].strip().startswith(EXEMPTION)
                sizes[name] = (child.end_lineno - child.lineno + 1, limit, exempt)
                walk(child, name, lines)
            else:
                walk(child, prefix, lines)

    for module, path in MODULES.items():
        if path.suffix == ".py":
            text = path.read_text()
            walk(ast.parse(text, str(path)), module, text.splitlines())
    return sizes


def test_sizes_are_measured():
    sizes = definition_sizes()
    assert sizes["eskin.errors.CampaignFormatError.__init__"][0] == 5
    assert sizes["eskin.learn.kernel.tensor_kernel"][1] == MAX_FUNCTION_LINES


def test_no_function_over_80_lines_and_no_class_over_300():
    too_long = {
        name: n
        for name, (n, limit, exempt) in definition_sizes().items()
        if n > limit and not exempt
    }
    assert not too_long, f"over the size limit (split into named steps): {too_long}"


def test_cli_commands_are_top_level_functions():
    # one thin module per command group: its commands are module-level functions, registered
    # by register(app), never defined inside another function
    nested = []
    for module, path in MODULES.items():
        if not module.startswith("eskin.cli."):
            continue
        for outer in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(outer, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for inner in ast.walk(outer):
                decorators = getattr(inner, "decorator_list", [])
                if inner is not outer and any("command" in ast.unparse(d) for d in decorators):
                    nested.append(f"{module}.{outer.name}.{inner.name}")
    assert not nested, f"commands defined inside functions: {nested}"
