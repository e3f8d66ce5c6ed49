"""The `eskin` command line. It parses and prints; the work is done by the package.

Each group of commands lives in its own module with a ``register(app)`` function.
"""

from __future__ import annotations

import typer

from eskin.cli import campaign, deploy, evaluate, learn, link

app = typer.Typer(
    name="eskin",
    help="Touch-modality recognition for piezoelectric electronic skin.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root() -> None:
    """Touch-modality recognition for piezoelectric electronic skin."""


for _module in (campaign, learn, evaluate, deploy, link):
    _module.register(app)


@app.command("version")
def version() -> None:
    """Print the eskin version."""
    import eskin

    typer.echo(eskin.__version__)


def main() -> None:
    app()
