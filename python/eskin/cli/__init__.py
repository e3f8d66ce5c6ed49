"""The `eskin` command line. It parses and prints; the work is done by the package.

Each group of commands lives in its own module with a ``register(app)`` function.
"""

from __future__ import annotations

from typing import Any

import typer

from eskin.cli import campaign, deploy, evaluate, learn, link, skin

app = typer.Typer(
    name="eskin",
    help="Touch-modality recognition for piezoelectric electronic skin.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        import eskin

        typer.echo(f"eskin {eskin.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True,
        help="print the version and exit"),
) -> None:
    """Touch-modality recognition for piezoelectric electronic skin."""


for _module in (campaign, learn, evaluate, deploy, link, skin):
    _module.register(app)


@app.command("version")
def version() -> None:
    """Print the eskin version."""
    import eskin

    typer.echo(eskin.__version__)


def _flags_without_value(command: Any) -> None:
    """On/off options take no value: the help shows ``--force``, not ``--force <bool>`` (the
    type column typer gives every option), for every command and its --help."""
    for param in command.params:
        if getattr(param, "is_flag", False):
            param.metavar = ""
    get_help_option = command.get_help_option

    def help_option(ctx: Any) -> Any:
        option = get_help_option(ctx)
        if option is not None:
            option.metavar = ""
        return option

    command.get_help_option = help_option
    for sub in getattr(command, "commands", {}).values():
        _flags_without_value(sub)


def _one_line_summaries(group: Any) -> None:
    """`eskin --help` lists each command with the first sentence of its help, on one line (the
    list keeps the help's own line breaks, which would cut a sentence in the middle)."""
    import re

    for sub in getattr(group, "commands", {}).values():
        if sub.short_help is None and sub.help:
            first_paragraph = sub.help.strip().split("\n\n")[0]
            text = " ".join(first_paragraph.split())
            sub.short_help = re.split(r"(?<=[.?!])\s+(?=[A-Z])", text)[0]


def main() -> None:
    """The `eskin` command: Ctrl-C (or SIGTERM where a command turns it into one) ends any
    command with one line, "interrupted", and exit code 130 (128 + SIGINT), as a shell does."""
    command = typer.main.get_command(app)
    _flags_without_value(command)
    _one_line_summaries(command)
    try:
        command(prog_name="eskin")
    except SystemExit as exc:
        if exc.code != 143 and _from_interrupt(exc):
            typer.echo("interrupted", err=True)
            raise SystemExit(130) from None
        raise


def _from_interrupt(exc: BaseException) -> bool:
    """True if ``exc`` ends a chain that a KeyboardInterrupt started (click turns Ctrl-C into
    an exit or an abort, raised from it)."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, KeyboardInterrupt):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False
