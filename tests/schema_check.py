"""Test helper: every file a test writes is checked against dualcal's JSON Schemas."""

from __future__ import annotations

import json
from pathlib import Path

from dualcal.files.io import json_kind
from dualcal.files.schemas import SCHEMA_NAMES, validate

_BY_FILE_NAME = {"rectify.json": "rectify", "advise.json": "advise"}


def assert_valid(path, name: str | None = None) -> dict:
    """Parse ``path`` and validate it against the schema ``name`` (default: found from the file name, else
    from its content); returns the document. Fails the test with the key that breaks the schema."""
    path = Path(path)
    doc = json.loads(path.read_text())
    name = name or _BY_FILE_NAME.get(path.name) or json_kind(doc)
    assert name in SCHEMA_NAMES, f"{path}: no schema for a file of kind {name!r}"
    validate(doc, name, str(path))
    return doc
