"""JSON Schemas of dualcal's files, and the one validation every JSON input goes through.

``schemas/NAME.json`` (draft 2020-12) for each file of the contract: :data:`SCHEMA_NAMES`. They
describe the contract's keys and types; unknown keys are admitted everywhere ("extend only by
adding"). :func:`validate` checks a parsed document against one, and beyond what a schema can
say, that every number is finite (Python's JSON reader accepts ``NaN`` and ``Infinity``). What
needs the library (a lens model's name, a lens invertible over its image, rotations, checks that
were edited) is checked by the loaders in :mod:`dualcal.files.io`.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import marshal
import math
import os
import sys
import tempfile
import types
from pathlib import Path

from ...errors import InputError

#: The files that have a schema: ``dualcal schema NAME`` prints ``NAME.json``.
SCHEMA_NAMES = ("corners", "calib", "eval", "measure", "points", "rectify", "advise", "intrinsics")


def schema(name: str) -> dict:
    """The JSON Schema of ``NAME.json`` (:data:`SCHEMA_NAMES`) as a dict."""
    return json.loads(schema_text(name))


def schema_text(name: str) -> str:
    """The text of ``schemas/NAME.json``; :class:`InputError` for a name without one."""
    if name not in SCHEMA_NAMES:
        raise InputError(f"no schema named {name!r} (dualcal has {', '.join(SCHEMA_NAMES)})")
    return (Path(__file__).parent / f"{name}.json").read_text(encoding="utf-8")


def _inlined(name: str) -> dict:
    """``NAME.json`` with each reference into another of dualcal's schemas (``dualcal:FILE.json#/pointer``)
    replaced by the part it points to, itself with its references inlined, so that the schema stands alone
    (fastjsonschema cannot join the ``dualcal:`` identifiers)."""
    def pointed(doc: str, pointer: str):
        target = schema(doc)
        for part in filter(None, pointer.split("/")):
            target = target[part]
        return target

    def resolve(node, doc: str):
        if isinstance(node, list):
            return [resolve(v, doc) for v in node]
        if not isinstance(node, dict):
            return node
        ref = node.get("$ref", "")
        if ref.startswith("dualcal:"):
            other, _, pointer = ref.removeprefix("dualcal:").partition("#")
            return resolve(pointed(other.removesuffix(".json"), pointer), other.removesuffix(".json"))
        if ref.startswith("#") and doc != name:
            return resolve(pointed(doc, ref[1:]), doc)
        return {k: resolve(v, doc) for k, v in node.items() if not (k in ("$id", "$schema") and node is not root)}

    root = schema(name)
    alone = resolve(root, name)
    del alone["$id"]
    return alone


def validator_cache() -> Path | None:
    """Where compiled validators are kept between runs: ``$XDG_CACHE_HOME/dualcal/validators`` (by default
    ``~/.cache/dualcal/validators``); None where neither that variable nor a home directory is known."""
    try:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    except RuntimeError:                                   # no home directory (a service's account)
        return None
    return root / "dualcal" / "validators"


@functools.cache
def _validator(name: str, detailed: bool = False):
    """The compiled validator of ``NAME.json``: a function that raises
    ``fastjsonschema.JsonSchemaValueException`` at the first fault, naming its key where ``detailed``
    (a third of the compile time without: :func:`validate` compiles that one only for a file that fails).
    fastjsonschema reads the schemas as draft 7, which means the same as draft 2020-12 for the keywords
    they use (no ``$ref`` beside other keywords, no ``items`` lists); ``tests/test_schemas.py`` checks
    that it judges as jsonschema's draft 2020-12 validator does.

    Generating and compiling a validator's code takes 10-30 ms (corners.json's: 12 ms of the 0.4 s a process
    calibrating two cameras' corners takes), so the compiled code is kept in :func:`validator_cache`, under a key
    of every schema's text, fastjsonschema's version and Python's; a cache that cannot be read or written is
    passed over (the validator is compiled, as without one)."""
    import fastjsonschema

    key = hashlib.sha256("\0".join([fastjsonschema.VERSION, sys.version, name, str(detailed),
                                     *map(schema_text, SCHEMA_NAMES)]).encode()).hexdigest()[:32]
    folder = validator_cache()
    path = None if folder is None else folder / f"{name}-{key}.marshal"
    code = _kept_code(path)
    if code is None:
        source = fastjsonschema.compile_to_code(_inlined(name), use_default=False, use_formats=False,
                                                detailed_exceptions=detailed)
        code = compile(source, f"<validator of {name}.json>", "exec")
        if path is not None:
            _keep_code(path, code)
    namespace: dict = {}
    exec(code, namespace)
    return namespace["validate"]


def _kept_code(path: Path | None):
    """The code object kept at ``path``, or None (no cache, no such file, or not a code object)."""
    if path is None:
        return None
    try:
        code = marshal.loads(path.read_bytes())
    except (OSError, ValueError, EOFError, TypeError):
        return None
    return code if isinstance(code, types.CodeType) else None


def _keep_code(path: Path, code) -> None:
    """Write ``code`` to ``path`` atomically (a temporary file beside it, renamed); nothing where it cannot."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, delete=False) as f:
            tmp = f.name
            f.write(marshal.dumps(code))
        os.replace(tmp, path)
    except OSError:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def key_path(parts) -> str:
    """``["cameras", "wide", "fx"]`` -> ``cameras.wide.fx``; list indices as ``[3]``."""
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "(top level)"


def _all_finite(doc) -> bool:
    """Whether every number in ``doc`` is finite (iterative: any depth; no key paths kept)."""
    stack = [doc]
    while stack:
        value = stack.pop()
        if isinstance(value, dict):
            value = list(value.values())
        if isinstance(value, list):
            if not all(map(math.isfinite, (x for x in value if isinstance(x, float)))):
                return False
            stack.extend(x for x in value if isinstance(x, (dict, list)))
        elif isinstance(value, float) and not math.isfinite(value):
            return False
    return True


def _finite_corners(views) -> bool:
    """Whether every number among a camera's views of corners is finite: the corners ``[u, v]`` in one pass,
    anything else there (which the schema will refuse) by :func:`_all_finite`."""
    finite, number, odd = math.isfinite, (int, float), []
    for corners in views.values():
        if type(corners) is not list:
            odd.append(corners)
            continue
        for uv in corners:
            if type(uv) is list and len(uv) == 2 and type(uv[0]) in number and type(uv[1]) in number:
                if not (finite(uv[0]) and finite(uv[1])):
                    return False
            elif uv is not None:
                odd.append(uv)
    return _all_finite(odd)


def non_finite_key(doc) -> str | None:
    """The key path of the first NaN or infinite number in ``doc``, or None (iterative: any depth)."""
    if _all_finite(doc):
        return None
    stack = [((), doc)]
    while stack:
        path, value = stack.pop()
        if isinstance(value, float) and not math.isfinite(value):
            return key_path(path)
        if isinstance(value, dict):
            stack.extend((path + (k,), v) for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((path + (i,), v) for i, v in enumerate(value))
    return None


#: Where the files hold their corner lists (the bulk of a corners.json or calib.json).
_CORNER_LISTS = {"corners": (), "calib": ("corners",)}


def _corner_problem(views) -> tuple[tuple, str] | None:
    """The key path and the fault of the first view entry that is not ``null`` or a list of corners
    ``[u, v]`` / ``null`` (what the schema says of them, checked here in one pass: a generic
    validator takes ten times longer over thousands of corners)."""
    number = (int, float)
    for key, corners in views.items():
        if corners is None or (type(corners) is list and all(
                uv is None or (type(uv) is list and len(uv) == 2 and type(uv[0]) in number and type(uv[1]) in number)
                for uv in corners)):
            continue                            # (the common case, in one pass; a fault is found below)
        if not isinstance(corners, list):
            return (key,), f"{corners!r:.40} must be array or null"
        for i, uv in enumerate(corners):
            if uv is None:
                continue
            if not (isinstance(uv, list) and len(uv) == 2):
                return (key, i), f"{uv!r:.40} is not a corner [u, v] or null"
            for j, x in enumerate(uv):
                if type(x) not in number:
                    return (key, i, j), f"{x!r:.40} must be number"
    return None


def _split_corner_lists(doc, name: str):
    """``doc`` with every camera's ``views`` of its corners emptied (shallow copies), and the views taken
    out, by the key path of their camera: the schema checks the rest, :func:`_corner_problem` these."""
    if name not in _CORNER_LISTS or not isinstance(doc, dict):
        return doc, []
    taken = []
    outer = doc = dict(doc)
    parent_path = _CORNER_LISTS[name]
    for key in parent_path:
        if not isinstance(doc.get(key), dict):
            return outer, []
        doc[key] = dict(doc[key])
        doc = doc[key]
    cameras = doc.get("cameras")
    if not isinstance(cameras, dict):
        return outer, []
    doc["cameras"] = cameras = dict(cameras)
    for cam, entry in cameras.items():
        if isinstance(entry, dict) and isinstance(entry.get("views"), dict):
            taken.append((parent_path + ("cameras", cam, "views"), entry["views"]))
            cameras[cam] = {**entry, "views": {}}
    return outer, taken


def validate(doc, name: str, source: str) -> None:
    """Raise :class:`InputError` unless ``doc`` is a valid ``NAME.json``: one line naming ``source``
    and the key that breaks the schema, or that holds NaN or an infinite number."""
    stripped, corner_lists = _split_corner_lists(doc, name)
    if not (_all_finite(stripped) and all(_finite_corners(views) for _, views in corner_lists)):
        raise InputError(f"{source}: {non_finite_key(doc)} is NaN or infinite: every number must be finite")
    doc = stripped
    for path, views in corner_lists:
        problem = _corner_problem(views)
        if problem is not None:
            raise InputError(f"{source}: {key_path(path + problem[0])}: {problem[1]} (schema: dualcal schema {name})")
    from fastjsonschema import JsonSchemaValueException

    try:
        _validator(name)(doc)
        return
    except JsonSchemaValueException:
        pass
    try:
        _validator(name, detailed=True)(doc)
    except JsonSchemaValueException as error:
        key = error.name.removeprefix("data").removeprefix(".") or "(top level)"
        rule = error.message.removeprefix(error.name).strip()
        value = "" if isinstance(error.value, dict) else f"{error.value!r:.40} "
        raise InputError(f"{source}: {key}: {value}{rule} (schema: dualcal schema {name})") from None
    raise AssertionError(f"the validators of {name}.json disagree on {source}")     # pragma: no cover
