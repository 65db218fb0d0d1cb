"""Who may talk to the app: the access token, the ``Host`` header and the ``Origin`` of a change.

The rules (CONTRACT.md, "app"), in the order :class:`Guard` applies them to every request:

1. **Host** (DNS rebinding: a page of ``evil.example`` whose name was pointed at this machine sends
   ``Host: evil.example``): the host must be the served host, ``localhost``, a loopback address or,
   when serving every interface (``0.0.0.0``, ``::``), one of this machine's names or an IP address
   (an attacker's page cannot make a browser send an address as its Host). Otherwise 400.
2. **Token**, as Jupyter's: random (or ``DUALCAL_APP_TOKEN``), in the printed URL; a page opened with
   ``?token=TOKEN`` sets it as a cookie (HttpOnly, SameSite=Strict) and is redirected to the same URL
   without it. Every ``/api/`` request and every page needs it, as ``Authorization: Bearer TOKEN`` or
   the cookie, compared in constant time (:func:`hmac.compare_digest`); without it: 401. The static
   assets (style sheet, script) need none: they hold no data.
3. **Origin** (CSRF: a page on another port of localhost is the same *site*, so a SameSite cookie
   alone does not stop it): a state-changing request (not GET, HEAD or OPTIONS) authorised by the
   cookie alone must name the app's own origin in ``Origin`` (or, where a browser sends none, in
   ``Referer``); another, or none: 403. A request with the bearer token is a program's, not a page's.
"""

from __future__ import annotations

import hmac
import ipaddress
import os
import re
import secrets
import socket
from dataclasses import dataclass, field
from http.cookies import SimpleCookie
from urllib.parse import parse_qsl, urlencode, urlsplit

from ..errors import InputError

__all__ = ["COOKIE", "TOKEN_ENV", "Guard", "HostRule", "lan_address", "new_token", "same_origin"]

#: The environment variable that sets the token (else a random one).
TOKEN_ENV = "DUALCAL_APP_TOKEN"
#: The cookie that carries the token after the first page.
COOKIE = "dualcal_token"
_SAFE_METHODS = {"GET", "HEAD", "OPTIONS"}


_TOKEN_CHARS = re.compile(r"^[A-Za-z0-9._~-]{8,256}$")


def new_token() -> str:
    """``DUALCAL_APP_TOKEN`` if set (and not empty), else 32 random bytes, URL-safe (43 characters).

    Raises
    ------
    InputError
        ``DUALCAL_APP_TOKEN`` is shorter than 8 characters or holds one a URL or a cookie cannot carry as it is.
    """
    token = os.environ.get(TOKEN_ENV)
    if not token:
        return secrets.token_urlsafe(32)
    if not _TOKEN_CHARS.match(token):
        raise InputError(f"{TOKEN_ENV}: give 8-256 characters of A-Z, a-z, 0-9 and ._~- (it goes into a URL "
                         "and a cookie as it is)")
    return token


def _ip(text: str):
    try:
        return ipaddress.ip_address(text.strip("[]").split("%")[0])
    except ValueError:
        return None


def lan_address() -> str | None:
    """This machine's address on its local network (the interface of the default route), or None.

    A UDP socket "connected" to an outside address picks that interface; no packet is sent.
    """
    for probe in ("192.0.2.1", "10.255.255.255"):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.connect((probe, 9))
                address = s.getsockname()[0]
            except OSError:
                continue
        if address and not _ip(address).is_loopback:
            return address
    return None


def _machine_names() -> set[str]:
    name = socket.gethostname().lower()
    return {name, f"{name}.local", socket.getfqdn().lower()} - {""}


@dataclass
class HostRule:
    """Which ``Host`` headers the app answers (module docstring, rule 1)."""

    served: str
    names: set[str] = field(default_factory=set)

    def __post_init__(self):
        self.names = {self.served.lower().strip("[]"), "localhost"} | {n.lower() for n in self.names}
        address = _ip(self.served)
        self.wildcard = address is not None and address.is_unspecified
        if self.wildcard:
            self.names |= _machine_names()

    def allows(self, host_header: str | None) -> bool:
        """Whether a request with this ``Host`` header (``name``, ``name:port``, ``[v6]:port``) is answered."""
        if not host_header:
            return False
        host = host_header.strip().lower()
        if host.startswith("["):
            host = host[1:host.find("]")] if "]" in host else host
        elif host.count(":") == 1:
            host = host.split(":")[0]
        if host in self.names:
            return True
        address = _ip(host)
        return address is not None and (address.is_loopback or self.wildcard)


def same_origin(origin: str, scheme: str, host_header: str) -> bool:
    """Whether ``origin`` (``scheme://host[:port]``) is the app's own, as the browser reached it."""
    parts = urlsplit(origin)
    if parts.scheme != scheme or not parts.netloc:
        return False
    default = {"http": 80, "https": 443}.get(scheme)
    def norm(netloc: str) -> tuple[str, int | None]:
        p = urlsplit(f"//{netloc}")
        try:
            port = p.port
        except ValueError:
            return ("", -1)
        return (p.hostname or "", port or default)
    return norm(parts.netloc) == norm(host_header)


def _header(scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", ()):
        if key == name:
            return value.decode("latin-1")
    return None


def _cookie_token(scope) -> str | None:
    raw = _header(scope, b"cookie")
    if not raw:
        return None
    jar = SimpleCookie()
    try:
        jar.load(raw)
    except Exception:       # a malformed Cookie header carries no token
        return None
    morsel = jar.get(COOKIE)
    return morsel.value if morsel else None


def _bearer(scope) -> str | None:
    raw = _header(scope, b"authorization")
    if raw and raw[:7].lower() == "bearer ":
        return raw[7:].strip()
    return None


class Guard:
    """ASGI middleware applying the rules of the module docstring before ``app`` sees a request.

    ``public`` are path prefixes served without the token (the static assets).
    """

    def __init__(self, app, token: str, hosts: HostRule, public=("/static/",)):
        self.app, self.token, self.hosts, self.public = app, token, hosts, tuple(public)

    def _valid(self, candidate: str | None) -> bool:
        return candidate is not None and hmac.compare_digest(candidate.encode(), self.token.encode())

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        if not self.hosts.allows(_header(scope, b"host")):
            return await _plain(send, 400, "this server answers only its own host name (DNS rebinding guard)")
        path = scope.get("path", "")
        if path.startswith(self.public):
            return await self.app(scope, receive, send)
        query = dict(parse_qsl(scope.get("query_string", b"").decode("latin-1")))
        method = scope.get("method", "GET")
        if "token" in query and not path.startswith("/api/") and method == "GET":
            if not self._valid(query["token"]):
                return await _plain(send, 401, "wrong token: open the URL that 'dualcal app' printed")
            rest = urlencode([(k, v) for k, v in parse_qsl(scope["query_string"].decode("latin-1")) if k != "token"])
            location = "/" + scope.get("raw_path", path.encode()).decode("latin-1").lstrip("/")  # never //host
            return await _redirect(send, location + (f"?{rest}" if rest else ""), self.token,
                                   secure=scope.get("scheme") == "https")
        bearer = _bearer(scope)
        if self._valid(bearer):
            return await self.app(scope, receive, send)
        if not self._valid(_cookie_token(scope)):
            if path.startswith("/api/"):
                return await _plain(send, 401, "the access token is missing or wrong: send 'Authorization: Bearer "
                                               "TOKEN' or open the URL that 'dualcal app' printed")
            return await _plain(send, 401, "open the URL that 'dualcal app' printed (it carries the access token)",
                                html=True)
        if method not in _SAFE_METHODS:
            origin = _header(scope, b"origin") or _header(scope, b"referer")
            if not origin or not same_origin(origin, scope.get("scheme", "http"), _header(scope, b"host")):
                return await _plain(send, 403, "a change must come from the app's own page (Origin check)")
        return await self.app(scope, receive, send)


_SECURITY_HEADERS = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"),
                     (b"cache-control", b"no-store")]


async def _plain(send, status: int, text: str, html: bool = False) -> None:
    if html:
        body = (f"<!doctype html><meta charset=utf-8><meta name=viewport content='width=device-width'>"
                f"<title>dualcal app</title><h1>dualcal app</h1><p role=alert>{text}</p>").encode()
        kind = b"text/html; charset=utf-8"
    else:
        import json
        body, kind = json.dumps({"error": text}).encode(), b"application/json"
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", kind), (b"content-length", str(len(body)).encode()),
                            *_SECURITY_HEADERS]})
    await send({"type": "http.response.body", "body": body})


async def _redirect(send, location: str, token: str, secure: bool) -> None:
    cookie = f"{COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict" + ("; Secure" if secure else "")
    await send({"type": "http.response.start", "status": 303,
                "headers": [(b"location", location.encode("latin-1")), (b"set-cookie", cookie.encode("latin-1")),
                            (b"content-length", b"0"), *_SECURITY_HEADERS]})
    await send({"type": "http.response.body", "body": b""})
