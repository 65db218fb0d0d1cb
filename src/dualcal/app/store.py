"""The workspace and its projects: the project folder is the state.

::

    WORKSPACE/<id>/
      project.json          the app's settings: name, board (as the commands' flags), the photos left out,
                            and the version, which every change raises before it is acknowledged
      photos/               each upload, byte for byte (a camera roll, or one folder per camera)
      corners.json  calib.json  eval.json  report.html  advise.json  advise.html  exports/...
                            the commands' files, as ``dualcal detect`` / ``calibrate`` / ``evaluate`` /
                            ``report`` / ``advise`` / ``export`` write them for those photos
      .dualcal-app/         what the app keeps beside them: results.json (the version the files are of:
                            a restart queues the work from there to project.json's version, so the
                            version is the journal of work to do), summary.json (what the page shows of
                            the calibration), the detections of each photo, thumbnails

A folder the commands made (``photos/`` with a ``calib.json`` or ``corners.json``) is a project too: its
board and the photos left out are read from those files. A project's id is the folder's name, from
``[A-Za-z0-9._-]``; a project's *name* is data (shown, never a path).
"""

from __future__ import annotations

import json
import re
import secrets
import unicodedata
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ..files.io import read_json, write_json_atomic

__all__ = ["APP_DIR", "EXPORTS", "FILES", "Project", "Settings", "Workspace", "exclude_pattern", "is_project_id",
           "photo_of"]

APP_DIR = ".dualcal-app"
PROJECT_FILE = "project.json"
#: The commands' files a project holds, as ``GET /api/projects/{id}/files/NAME`` serves them.
FILES = ("corners.json", "calib.json", "eval.json", "report.html", "advise.json", "advise.html")
#: ``dualcal export`` formats -> the file (or folder, for mrcal) written under ``exports/``.
EXPORTS = {"opencv": "rig-opencv.yml", "kalibr": "kalibr-camchain.yaml", "colmap": "colmap-cameras.txt",
           "mrcal": "mrcal"}
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
_GLOB_SPECIAL = re.compile(r"([*?\[])")


def is_project_id(text: str) -> bool:
    return bool(_ID.match(text)) and not text.endswith(".")


def exclude_pattern(photo: str) -> str:
    """The ``--exclude`` pattern that leaves out exactly this photo (a name in ``photos/``): its file name
    in a camera roll (``IMG_0107.JPG``), ``CAMERA/STEM`` in a dataset of camera folders
    (``tele/IMG_07``); glob characters escaped (:func:`dualcal.files.dataset.is_excluded`)."""
    path = Path(photo)
    text = path.name if len(path.parts) == 1 else f"{path.parts[0]}/{path.stem}"
    return _GLOB_SPECIAL.sub(r"[\1]", text)


@dataclass(frozen=True)
class Settings:
    """What ``dualcal calibrate`` is given besides the photos: ``--board``, ``--square``, ``--marker``,
    ``--dictionary``, ``--square-sigma`` (CONTRACT.md's ``POST /api/projects`` body)."""

    board: str
    square_mm: float
    square_sigma_mm: float | None = None
    marker_mm: float | None = None
    dictionary: str | None = None

    def make_board(self):
        """The :class:`~dualcal.geometry.board.Board` the flags give (:func:`~dualcal.geometry.board.board_from_spec`;
        its :class:`InputError` says what is wrong)."""
        from ..geometry.board import board_from_spec
        return board_from_spec(self.board, self.square_mm, self.marker_mm, self.dictionary)

    def flags(self) -> list[str]:
        """The same as command-line flags (``["--board", "8x5", "--square", "30", ...]``)."""
        out = ["--board", self.board, "--square", f"{self.square_mm:g}"]
        for flag, value in (("--marker", self.marker_mm), ("--dictionary", self.dictionary),
                            ("--square-sigma", self.square_sigma_mm)):
            if value is not None:
                out += [flag, value if isinstance(value, str) else f"{value:g}"]
        return out

    def to_dict(self) -> dict:
        return {k: v for k, v in vars(self).items() if v is not None}

    @classmethod
    def from_request(cls, doc: dict) -> "Settings":
        """From the JSON body of ``POST /api/projects``; ``printed``, the options ``dualcal board`` printed in
        the board's margin (``--board charuco:11x8 --square 25 --marker 18 --dictionary DICT_5X5_50``),
        stands for the board's keys. Raises :class:`InputError` naming what is wrong."""
        doc = dict(doc)
        if doc.get("printed"):
            doc.update(_printed_options(str(doc["printed"])))
        def number(key, required=False):
            value = doc.get(key)
            if value in (None, ""):
                if required:
                    raise InputError(f"{key} is missing")
                return None
            try:
                x = float(value)
            except (TypeError, ValueError):
                raise InputError(f"{key} {value!r}: expected a number") from None
            if not x == x or x in (float("inf"), float("-inf")):
                raise InputError(f"{key} {value!r}: expected a finite number")
            return x
        board = doc.get("board")
        if not isinstance(board, str) or not board.strip():
            raise InputError("board is missing: the inner corners COLSxROWS (8x5 for 9 x 6 squares) or charuco:SXxSY")
        dictionary = doc.get("dictionary") or None
        settings = cls(board.strip(), number("square_mm", True), number("square_sigma_mm"), number("marker_mm"),
                       str(dictionary) if dictionary is not None else None)
        settings.checked()
        return settings

    def checked(self) -> "Settings":
        """These settings, after the board's own checks (:class:`InputError` says what is wrong)."""
        from ..geometry.board import board_from_spec
        board_from_spec(self.board, self.square_mm, self.marker_mm, self.dictionary, self.square_sigma_mm or 0.0)
        return self

    @classmethod
    def from_board(cls, board) -> "Settings":
        """The flags that give ``board`` (a corners.json's or calib.json's)."""
        ch = board.charuco
        return cls(board.spec(), board.square_mm, board.square_sigma_mm or None,
                   ch.marker_mm if ch else None, ch.dictionary if ch else None)


def _printed_options(text: str) -> dict:
    import shlex
    keys = {"--board": "board", "--square": "square_mm", "--marker": "marker_mm", "--dictionary": "dictionary",
            "--square-sigma": "square_sigma_mm"}
    try:
        words = shlex.split(text)
    except ValueError:
        raise InputError(f"printed {text!r}: not the options dualcal board printed") from None
    out = {}
    while words:
        flag = words.pop(0)
        if flag not in keys or not words:
            raise InputError(f"printed {text!r}: {flag!r} is not one of {', '.join(keys)} with its value")
        out[keys[flag]] = words.pop(0)
    return out


def photo_of(path: str) -> str:
    """A corners.json photo path (``photos/IMG_01.JPG``, ``photos/tele/IMG_01.jpg``) as the app names the
    photo (``IMG_01.JPG``, ``tele/IMG_01.jpg``): what follows ``photos/``."""
    parts = Path(path).parts
    if "photos" in parts:
        i = len(parts) - 1 - parts[::-1].index("photos")
        return "/".join(parts[i + 1:])
    return Path(path).name


def _slug(name: str) -> str:
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode()
    return re.sub(r"[^a-z0-9]+", "-", ascii_name.lower()).strip("-")[:32] or "project"


class Project:
    """One project folder (module docstring). Reading it never writes; :meth:`save` writes project.json."""

    def __init__(self, folder: Path):
        self.folder = Path(folder).absolute()
        self.id = self.folder.name
        self.photos_dir = self.folder / "photos"
        self.app_dir = self.folder / APP_DIR

    # -- settings and the journal
    def read(self) -> dict:
        """project.json, or what a folder the commands made says (name, board, photos left out; version 0).
        ``settings`` is None where nothing names the board."""
        path = self.folder / PROJECT_FILE
        if path.is_file():
            doc = read_json(path)
            settings = Settings(**doc["settings"]) if doc.get("settings") else None
            return {"name": str(doc.get("name") or self.id), "settings": settings, "version": int(doc.get("version", 0)),
                    "left_out": list(doc.get("left_out", []))}
        return {"name": self.id, "settings": self._settings_from_files(), "version": 0,
                "left_out": self._left_out_from_files()}

    def save(self, name: str, settings: Settings | None, version: int, left_out) -> None:
        write_json_atomic(self.folder / PROJECT_FILE, {
            "dualcal_app": 1, "name": name, "settings": settings.to_dict() if settings else None,
            "version": int(version), "left_out": sorted(set(left_out))})

    def _corners_doc(self) -> dict | None:
        for name in ("calib.json", "corners.json"):
            try:
                doc = read_json(self.folder / name)
            except (InputError, OSError):
                continue
            return doc.get("corners", doc) if name == "calib.json" else doc
        return None

    def _settings_from_files(self) -> Settings | None:
        doc = self._corners_doc()
        if doc is None:
            return None
        from ..files.io import board_from_dict
        try:
            return Settings.from_board(board_from_dict(doc.get("board"), "corners"))
        except InputError:
            return None

    def _left_out_from_files(self) -> list[str]:
        doc = self._corners_doc() or {}
        out = []
        for cam in (doc.get("cameras") or {}).values():
            for path in (cam.get("excluded") or {}).values():
                if path and "photos" in Path(path).parts:
                    out.append(photo_of(path))
        return out

    # -- photos
    def photo_names(self) -> list[str]:
        """Every photo of ``photos/`` as ``NAME`` or ``CAMERA/NAME`` (hidden and partial files not), sorted."""
        from ..files.photos import PHOTO_SUFFIXES
        if not self.photos_dir.is_dir():
            return []
        out = []
        for p in self.photos_dir.iterdir():
            if p.name.startswith("."):
                continue
            if p.is_dir():
                out += [f"{p.name}/{q.name}" for q in p.iterdir()
                        if q.is_file() and not q.name.startswith(".") and q.suffix.lower() in PHOTO_SUFFIXES]
            elif p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES:
                out.append(p.name)
        return sorted(out)

    def photo_path(self, name: str) -> Path | None:
        """The file of a photo named as :meth:`photo_names` names it, or None (never outside ``photos/``)."""
        if name not in self.photo_names():
            return None
        return self.photos_dir / name

    def layout(self) -> str | None:
        """``"roll"`` (photos directly in ``photos/``), ``"cameras"`` (a folder per camera) or None (empty)."""
        names = self.photo_names()
        if not names:
            return None
        return "cameras" if "/" in names[0] else "roll"

    # -- what the app keeps beside the files
    def app_file(self, name: str) -> Path:
        return self.app_dir / name

    def read_app_json(self, name: str) -> dict | None:
        try:
            return read_json(self.app_file(name))
        except (InputError, OSError, json.JSONDecodeError):
            return None

    def preview(self, kind: str, photo: str) -> Path:
        """``.dualcal-app/<kind>/<photo>.jpg``: a thumbnail (``thumbs``, the detected corners drawn) or a
        photo reduced for the screen (``screen``)."""
        return self.app_dir / kind / f"{photo}.jpg"


class Workspace:
    """The folder of projects ``dualcal app`` serves."""

    def __init__(self, root: Path):
        self.root = Path(root).absolute()

    def projects(self) -> list[Project]:
        """Every project folder, by id: a folder with project.json, or with ``photos/``, calib.json or corners.json."""
        out = []
        for p in sorted(self.root.iterdir()) if self.root.is_dir() else ():
            project = self.get(p.name)
            if project is not None:
                out.append(project)
        return out

    def get(self, project_id: str) -> Project | None:
        """The project of that id, or None (an id that is not one, or no such project folder)."""
        if not is_project_id(project_id):
            return None
        folder = self.root / project_id
        if folder.is_dir() and any((folder / n).exists() for n in (PROJECT_FILE, "photos", "calib.json", "corners.json")):
            return Project(folder)
        return None

    def create(self, name: str, settings: Settings) -> Project:
        """A new project folder named after ``name`` (a slug and a random suffix: the name itself is data)."""
        name = "".join(ch for ch in str(name) if unicodedata.category(ch)[0] != "C").strip()[:200]
        if not name:
            raise InputError("name is missing: give the project a name")
        for _ in range(100):
            folder = self.root / f"{_slug(name)}-{secrets.token_hex(3)}"
            try:
                folder.mkdir()
            except FileExistsError:
                continue
            (folder / "photos").mkdir()
            project = Project(folder)
            project.save(name, settings, 0, [])
            return project
        raise InputError("no free project folder name")  # pragma: no cover
