"""``dualcal schema NAME``: print the JSON Schema of one of dualcal's files."""

from __future__ import annotations

import click

from . import cli
from .common import echo


@cli.command("schema")
@click.argument("name", metavar="NAME")
def schema_command(name: str) -> None:
    """Print the JSON Schema (draft 2020-12) of NAME.json: corners, calib, eval, measure, points,
    rectify, advise or intrinsics.

    Every file dualcal reads is checked against its schema; unknown keys are admitted (the
    contract is extended only by adding).
    """
    from ..files.schemas import schema_text

    echo(schema_text(name.removesuffix(".json")), nl=False)
