"""``dualcal app``: the local web app (:mod:`dualcal.app`)."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .common import echo


@cli.command("app")
@click.argument("workspace", required=False, type=click.Path(file_okay=False, path_type=Path))
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to serve on: 127.0.0.1 for this computer only, 0.0.0.0 for the local network "
                   "(a phone on the same Wi-Fi or the phone's hotspot).")
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="Port (0: any free one; the printed URL says which).")
@click.option("--no-browser", is_flag=True, help="Do not open a browser.")
@click.option("--certfile", type=click.Path(dir_okay=False, exists=True), default=None,
              help="TLS certificate (PEM) to serve https, with --keyfile.")
@click.option("--keyfile", type=click.Path(dir_okay=False, exists=True), default=None, help="TLS private key (PEM).")
def app_command(workspace, host, port, no_browser, certfile, keyfile) -> None:
    """Serve the local web app: calibrate from a phone's browser, no cable and no terminal.

    WORKSPACE (default: the current folder) holds one folder per project: its photos as uploaded
    and the files 'dualcal calibrate' writes for them (a folder the commands made opens too). The
    first line printed is 'dualcal app: URL': open it (it carries the access token).

    \b
    dualcal app                       this computer only: the browser opens by itself
    dualcal app calib/ --host 0.0.0.0  a phone on the same Wi-Fi (or this computer on the phone's
                                      hotspot) scans the QR code printed here and on the page

    Everything the page does is a JSON API call (GET /api lists them), with the token as
    'Authorization: Bearer TOKEN'; DUALCAL_APP_TOKEN sets the token.
    """
    from ..extras import require

    require("app")
    if (certfile is None) != (keyfile is None):
        raise InputError("--certfile and --keyfile go together (the certificate and its private key)")
    workspace = Path(workspace) if workspace is not None else Path.cwd()
    if not workspace.is_dir():
        if not workspace.parent.is_dir():
            raise InputError(f"{workspace}: no such folder, nor its parent")
        workspace.mkdir()
    from ..app.serve import serve

    serve(workspace, host, port, open_browser=not no_browser, certfile=certfile, keyfile=keyfile, echo=echo)
