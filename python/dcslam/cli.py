"""The ``dcslam`` command. It only drives the library's pipelines; no algorithm lives here."""

from __future__ import annotations

from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from ._version import __version__

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Divide and Conquer EKF SLAM with data association in linear time.",
)
console = Console()


def _version_callback(value: bool) -> None:
    if value:
        console.print(f"dcslam {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Optional[bool] = typer.Option(
        None, "--version", callback=_version_callback, is_eager=True, help="Print the version."
    ),
) -> None:
    """Divide and Conquer EKF SLAM (Paz, Guivant, Tardós, Neira, RSS 2007)."""


@app.command()
def selfcheck(samples: int = typer.Option(200, help="Random inputs per function.")) -> None:
    """Check the compiled core: analytic Jacobians against central differences."""
    from .selfcheck import geometry_errors

    table = Table(title="Jacobians: max |analytic - central difference|")
    table.add_column("function")
    table.add_column("max error", justify="right")
    table.add_column("status")
    failed = False
    for name, error in geometry_errors(samples):
        ok = error < 1e-5
        failed |= not ok
        table.add_row(name, f"{error:.2e}", "[green]ok" if ok else "[red]FAIL")
    console.print(table)
    if failed:
        raise typer.Exit(code=1)


def main() -> None:
    app(prog_name="dcslam")
