"""Uploads as a browser sends them: streamed to disk part by part, limited in size, told by their
content, named safely.

A request's body is parsed as it arrives (:class:`PhotoStream`, python-multipart's streaming parser):
each file of the field ``photos`` is written to a hidden temporary file inside the project as its
bytes come (never whole in memory) and handed over complete, with its size, its sha256 and its kind
read from its first bytes (:func:`photo_kind`), for the server to name (:func:`safe_photo_name`) and
move into ``photos/`` atomically. A file beyond the size limit is dropped as soon as it passes it.
"""

from __future__ import annotations

import hashlib
import os
import re
import secrets
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

__all__ = ["KINDS", "Part", "PhotoStream", "photo_kind", "safe_photo_name"]

#: A photo's kind by its content -> the suffixes a file of that kind may have (the first is given to a
#: name without one). DNG is a TIFF.
KINDS = {"jpeg": (".jpg", ".jpeg"), "png": (".png",), "tiff": (".tif", ".tiff", ".dng"),
         "heic": (".heic", ".heif")}
_HEIF_BRANDS = {b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1"}
_WINDOWS_DEVICES = re.compile(r"^(con|prn|aux|nul|com[0-9]|lpt[0-9]|conin\$|conout\$)$", re.IGNORECASE)
_FORBIDDEN = set('<>:"|?*[]\\')
_CAMERA = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,31}$")
MAX_NAME_CHARS = 120


def photo_kind(head: bytes) -> str | None:
    """``"jpeg"``, ``"png"``, ``"tiff"`` or ``"heic"`` from a file's first 16 bytes; None for anything else."""
    if head.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "tiff"
    if head[4:8] == b"ftyp" and head[8:12] in _HEIF_BRANDS:
        return "heic"
    return None


def _part_problem(part: str) -> str | None:
    if part in ("", ".", ".."):
        return "it is a path (only one folder, the camera's, may be named)"
    if any(unicodedata.category(ch) in ("Cc", "Cf", "Zl", "Zp") for ch in part):
        return "it holds control characters"
    if _FORBIDDEN & set(part):
        return "it holds one of < > : \" | ? * [ ] \\"
    if part.startswith(".") or part.endswith((" ", ".")):
        return "it starts with a dot or ends with a space or a dot"
    if _WINDOWS_DEVICES.match(part.split(".")[0].rstrip(" ")):
        return "it is a device name on Windows (con, nul, com1, ...)"
    if len(part) > MAX_NAME_CHARS:
        return f"it is longer than {MAX_NAME_CHARS} characters"
    return None


def safe_photo_name(raw: str, kind: str | None) -> tuple[str | None, str]:
    """The name a file lands under in ``photos/`` (``"IMG_0101.JPG"`` or ``"wide/IMG_01.jpg"``), or None
    with the reason it is refused.

    ``raw`` is the name the browser sent; it may carry one folder, the camera's (a dropped dataset
    folder). A name is data, never a path: ``..``, an absolute path, more than one folder, control
    characters, the characters Windows or a glob pattern reserve (``<>:"|?*[]\\``), a leading dot
    and Windows' device names (``con.jpg``) are refused, not repaired, so that no two files meet
    under one repaired name. ``kind`` is what the content is (:func:`photo_kind`): a file that is
    not a photo is refused, and a suffix that is not one of its kind's is replaced by its kind's
    (iOS sends HEIC photos converted to JPEG; the stem, which pairs and orders photos, is kept).
    """
    if kind is None:
        return None, "not a photo: its content is not JPEG, PNG, TIFF (DNG) or HEIC"
    name = unicodedata.normalize("NFC", raw or "").replace("\\", "/")
    if name.startswith("/"):
        return None, "it is an absolute path"
    parts = name.split("/")
    if len(parts) > 2:
        return None, "it is a path (only one folder, the camera's, may be named)"
    for part in parts:
        problem = _part_problem(part)
        if problem:
            return None, problem
    if len(parts) == 2 and not _CAMERA.match(parts[0]):
        return None, "its folder is not a camera's name (letters, digits, _ and -, up to 32)"
    path = PurePosixPath(*parts)
    if path.suffix.lower() not in KINDS[kind]:
        stem = path.stem if path.suffix.lower() in {s for ss in KINDS.values() for s in ss} else path.name
        path = path.with_name(stem + KINDS[kind][0])
    return str(path), ""


@dataclass
class Part:
    """One file of an upload, complete on disk at ``temp`` (or dropped, with ``problem``)."""

    raw_name: str
    temp: Path | None
    size: int = 0
    sha256: str = ""
    kind: str | None = None
    problem: str = ""


@dataclass
class _Open:
    raw_name: str
    temp: Path
    fh: object
    digest: object = field(default_factory=hashlib.sha256)
    head: bytes = b""
    size: int = 0
    too_large: bool = False


class PhotoStream:
    """Feed a multipart/form-data body chunk by chunk (:meth:`feed`); complete files come out of
    :meth:`take` as :class:`Part`, each already on disk in ``temp_dir``.

    Parts of other fields than ``field`` and parts without a file name are read and dropped. A file
    over ``max_bytes`` is dropped as soon as it passes it (``problem`` says so); more than
    ``max_files`` files end the upload (:class:`ValueError`).
    """

    def __init__(self, content_type: str, temp_dir: Path, max_bytes: int, max_files: int = 1000,
                 field_name: str = "photos"):
        from python_multipart.multipart import MultipartParser, parse_options_header

        kind, options = parse_options_header(content_type or "")
        boundary = options.get(b"boundary")
        if kind != b"multipart/form-data" or not boundary:
            raise ValueError("expected multipart/form-data with a boundary")
        self._parse_options = parse_options_header
        self.temp_dir, self.max_bytes, self.max_files, self.field_name = temp_dir, max_bytes, max_files, field_name
        self._done: list[Part] = []
        self._open: _Open | None = None
        self._headers: dict[bytes, bytes] = {}
        self._field, self._value = b"", b""
        self.files = 0
        self._parser = MultipartParser(boundary, callbacks={
            "on_part_begin": self._begin, "on_header_field": self._header_field,
            "on_header_value": self._header_value, "on_header_end": self._header_end,
            "on_headers_finished": self._headers_finished, "on_part_data": self._data, "on_part_end": self._end})

    # -- the parser's callbacks (synchronous)
    def _begin(self):
        self._headers, self._field, self._value, self._open = {}, b"", b"", None

    def _header_field(self, data, start, end):
        self._field += data[start:end]

    def _header_value(self, data, start, end):
        self._value += data[start:end]

    def _header_end(self):
        self._headers[self._field.lower()] = self._value
        self._field, self._value = b"", b""

    def _headers_finished(self):
        _, options = self._parse_options(self._headers.get(b"content-disposition", b""))
        name = options.get(b"name", b"").decode("utf-8", "replace")
        filename = options.get(b"filename")
        if name != self.field_name or filename is None:
            return
        self.files += 1
        if self.files > self.max_files:
            raise ValueError(f"more than {self.max_files} files in one upload")
        temp = self.temp_dir / f".upload-{secrets.token_hex(8)}.part"
        self._open = _Open(filename.decode("utf-8", "replace"), temp, open(temp, "wb"))

    def _data(self, data, start, end):
        part = self._open
        if part is None or part.too_large:
            return
        chunk = data[start:end]
        part.size += len(chunk)
        if part.size > self.max_bytes:
            part.too_large = True
            part.fh.close()
            part.temp.unlink(missing_ok=True)
            return
        if len(part.head) < 16:
            part.head += chunk[:16]
        part.digest.update(chunk)
        part.fh.write(chunk)

    def _end(self):
        part, self._open = self._open, None
        if part is None:
            return
        if part.too_large:
            self._done.append(Part(part.raw_name, None, part.size,
                                   problem=f"larger than the limit of {self.max_bytes / 1e6:.0f} MB"))
            return
        part.fh.flush()
        os.fsync(part.fh.fileno())
        part.fh.close()
        self._done.append(Part(part.raw_name, part.temp, part.size, part.digest.hexdigest(), photo_kind(part.head)))

    # -- the caller's side
    def feed(self, chunk: bytes) -> None:
        """Parse the next bytes of the body (writes to disk as a side effect)."""
        self._parser.write(chunk)

    def finish(self) -> None:
        self._parser.finalize()

    def take(self) -> list[Part]:
        """The files completed since the last call."""
        done, self._done = self._done, []
        return done

    def abandon(self) -> None:
        """Remove the temporary file of a part cut off by the end of the request (a dropped connection)."""
        part, self._open = self._open, None
        if part is not None and not part.too_large:
            part.fh.close()
            part.temp.unlink(missing_ok=True)
        for p in self.take():
            if p.temp is not None:
                p.temp.unlink(missing_ok=True)
