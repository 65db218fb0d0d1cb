"""Run the app with uvicorn on a socket bound first, so that the URL printed names the port it got.

The first line on stdout is ``dualcal app: URL`` (CONTRACT.md, "app"); with ``--host 0.0.0.0`` the URL has
this machine's address on its network, and a QR code of it follows, for a phone's camera.
"""

from __future__ import annotations

import errno
import socket
import sys
from pathlib import Path

from ..errors import InputError
from .security import HostRule, lan_address, new_token
from .server import AppConfig, create_app

__all__ = ["bind", "serve"]


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (``InputError`` in one line when the port is taken)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if isinstance(exc, socket.gaierror) or exc.errno == errno.EADDRNOTAVAIL:
            raise InputError(f"--host {host}: not an address of this machine (127.0.0.1, or 0.0.0.0 for every "
                             "network)") from None
        raise InputError(f"cannot serve on {host}:{port} ({exc.strerror}): give another --port (0: any free one)") \
            from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


def serve(workspace: Path, host: str, port: int, open_browser: bool = True, certfile=None, keyfile=None,
          echo=print) -> None:
    """Serve ``workspace`` until Ctrl-C."""
    import uvicorn

    token = new_token()
    sock = bind(host, port)
    port = sock.getsockname()[1]
    scheme = "https" if certfile else "http"
    rule = HostRule(host)
    shown = (lan_address() or "127.0.0.1") if rule.wildcard else host
    if ":" in shown:
        shown = f"[{shown}]"
    url = f"{scheme}://{shown}:{port}/?token={token}"
    app = create_app(AppConfig(workspace=workspace, token=token, host=host, url=url))
    echo(f"dualcal app: {url}")
    if rule.wildcard:
        import segno
        echo("open it on a phone on the same network (Wi-Fi or the phone's hotspot): scan this code", err=True)
        segno.make(url, error="m").terminal(out=sys.stderr, compact=True)
    echo(f"serving {workspace.resolve()} (Ctrl-C stops)", err=True)
    sys.stdout.flush()
    if open_browser:
        import webbrowser
        local = url if not rule.wildcard else f"{scheme}://127.0.0.1:{port}/?token={token}"
        webbrowser.open(local)
    config = uvicorn.Config(app, log_level="warning", ssl_certfile=certfile, ssl_keyfile=keyfile,
                            timeout_graceful_shutdown=2, lifespan="on")
    server = uvicorn.Server(config)
    server.run(sockets=[sock])
