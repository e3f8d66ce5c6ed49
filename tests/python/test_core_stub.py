"""The shipped type stub of the compiled module must describe what the module really exports."""

import ast
from pathlib import Path

import eskin
from eskin import _core

STUB = Path(eskin.__file__).with_name("_core.pyi")


def _stub_names() -> set[str]:
    tree = ast.parse(STUB.read_text())
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return names


def test_stub_lists_every_public_name_of_the_compiled_module():
    public = {n for n in dir(_core) if not n.startswith("_")}
    missing = public - _stub_names()
    assert not missing, f"_core.pyi is stale (run `make stubs`); missing: {sorted(missing)}"


def test_stub_names_exist_in_the_compiled_module():
    extra = {n for n in _stub_names() if not n.startswith("_")} - set(dir(_core))
    assert not extra, f"_core.pyi names what _core does not export: {sorted(extra)}"
