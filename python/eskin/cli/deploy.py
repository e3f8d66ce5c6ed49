"""CLI commands: export."""

from __future__ import annotations

from pathlib import Path
from typing import NoReturn, Optional

import typer


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""

    @app.command("export")
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
    ) -> None:
        """Export a trained model for the controller: a .eskin file (docs/model-format.md)
        that eskin-classify and the C++ library load, and optionally a C header."""
        from eskin.deploy import load_model
        from eskin.deploy.export import CompiledModel, export_model, write_c_header

        try:
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
            _fail(str(exc))
        typer.echo(
            f"wrote {path}: {cm.file_bytes} bytes, {', '.join(cm.class_names)} ({cm.rule}), "
            f"D={cm.D}, {cm.n_support} support vectors, "
            f"{'float64' if cm.is_float64 else 'float32'}"
        )
        if c_header is not None:
            typer.echo(f"wrote {c_header}")


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
