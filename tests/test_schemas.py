"""The JSON Schemas (issue 23) and the validation of every JSON input (issue 24, finding 3): a calib.json with
NaN, Inf, wrongly typed or absurd values, or edited checks, is refused by every command that reads it, in one
line naming the key, exit 2."""

from __future__ import annotations

import json
import re

import jsonschema
import pytest
from schema_check import assert_valid

from dualcal.synthetic import synth
from dualcal.errors import InputError
from dualcal.files.io import load_corners, load_rig, save_corners, save_rig
from dualcal.files.schemas import SCHEMA_NAMES, schema, validate


def _reference_validator(name: str) -> jsonschema.Draft202012Validator:
    """jsonschema's draft 2020-12 validator of ``NAME.json``, with the other schemas it refers to."""
    from referencing import Registry, Resource

    registry = Registry().with_resources(
        (f"dualcal:{n}.json", Resource.from_contents(schema(n))) for n in SCHEMA_NAMES)
    return jsonschema.Draft202012Validator(schema(name), registry=registry)


@pytest.mark.parametrize("name", SCHEMA_NAMES)
def test_every_schema_is_a_valid_draft_2020_12_schema(name):
    jsonschema.Draft202012Validator.check_schema(schema(name))


def test_the_schema_command_prints_each_schema(run_cli):
    for name in SCHEMA_NAMES:
        res = run_cli("schema", name)
        assert res.code == 0 and json.loads(res.out) == schema(name)
    res = run_cli("schema", "nope")
    assert res.code == 2 and "corners, calib" in res.err


@pytest.fixture(scope="module")
def stereo():
    truth = synth.make_truth("stereo", views=4, seed=2)
    return truth, synth.truth_rig_model(truth, synth.noisy_corner_set(truth, 0.1, seed=1))


@pytest.fixture
def calib_path(stereo, tmp_path):
    path = tmp_path / "calib.json"
    save_rig(path, stereo[1])
    return path


def test_what_dualcal_writes_is_valid_and_what_others_add_is_admitted(stereo, tmp_path):
    truth, rig = stereo
    save_rig(tmp_path / "calib.json", rig)
    save_corners(tmp_path / "corners.json", rig.corners)
    assert_valid(tmp_path / "calib.json")
    doc = assert_valid(tmp_path / "corners.json")
    # the keys other work adds: per-camera lens models, a fisheye k4, the square's sigma, the camera roll's keys
    doc["board"]["square_sigma_mm"] = 0.02
    doc["roll"] = {"instants": []}
    doc["cameras"]["left"]["meta"] = {"lens_model": "back camera 4.2mm"}
    validate(doc, "corners", "corners.json")
    calib = json.loads((tmp_path / "calib.json").read_text())
    calib["model"] = "mixed"
    calib["cameras"]["left"].update(model="kb4", k3=0.0, k4=0.001)
    validate(calib, "calib", "calib.json")


BAD_CALIBS = [
    # (what is edited, how, the key the message names)
    ("k1 NaN", lambda d: d["cameras"]["left"].update(k1=float("nan")), "cameras.left.k1 is NaN"),
    ("fx Infinity", lambda d: d["cameras"]["right"].update(fx=float("inf")), "cameras.right.fx is NaN or infinite"),
    ("fx true", lambda d: d["cameras"]["left"].update(fx=True), "cameras.left.fx: True must be number"),
    ("fx negative", lambda d: d["cameras"]["left"].update(fx=-900.0), "cameras.left.fx: -900.0 must be bigger than"),
    ("sigma NaN", lambda d: d["cameras"]["left"]["sigma"].update(fx=float("nan")), "cameras.left.sigma.fx is NaN"),
    ("sigma a string", lambda d: d["rig"]["right"]["sigma"].update(baseline_mm="0.1"), "rig.right.sigma.baseline_mm"),
    ("checks ok maybe", lambda d: d["checks"].setdefault("fit", {"message": "x"}).update(ok="maybe"), "checks.fit.ok"),
    ("checks edited", lambda d: d["checks"].update(fit={"ok": True, "message": "all fine, trust me"}),
     "checks were edited"),
    ("a folding lens", lambda d: d["cameras"]["left"].update(k1=-3.0, k2=0.0), "folds over"),
    ("R not a rotation", lambda d: d["rig"]["right"].update(R=[[2, 0, 0], [0, 1, 0], [0, 0, 1]]), "rotation"),
]


def _write_bad(calib_path, edit) -> None:
    doc = json.loads(calib_path.read_text())
    doc.setdefault("checks", {})
    edit(doc)
    calib_path.write_text(json.dumps(doc))       # Python writes NaN and Infinity as JSON allows it to


SCHEMA_FAULTS = [
    # (what is edited, how): each breaks calib.json's schema somewhere else
    ("a string", lambda d: d["cameras"]["left"].update(fx="900")),
    ("a bool", lambda d: d["rig"]["right"]["sigma"].update(baseline_mm=True)),
    ("negative", lambda d: d["cameras"]["left"].update(fy=-1.0)),
    ("a key missing", lambda d: d["cameras"]["right"].pop("cx")),
    ("top key missing", lambda d: d.pop("rig")),
    ("a short vector", lambda d: d["rig"]["right"].update(t_mm=[1.0, 2.0])),
    ("an image size of 0", lambda d: d["cameras"]["left"].update(image_size=[0, 480])),
    ("a bad board", lambda d: d["board"].update(rows="7")),
    ("a bad corner board", lambda d: d["corners"]["board"].update(square_mm=-3)),
    ("not a list of corners", lambda d: d["corners"]["cameras"]["left"].update(image_size="640x480")),
]


@pytest.mark.parametrize("what,edit", SCHEMA_FAULTS, ids=[f[0] for f in SCHEMA_FAULTS])
def test_the_fast_validator_refuses_what_the_draft_2020_12_reference_refuses(calib_path, what, edit):
    """dualcal validates with fastjsonschema (compiled, draft 7 semantics); jsonschema's draft 2020-12
    validator is the reference: both pass what dualcal writes and both refuse each fault."""
    doc = json.loads(calib_path.read_text())
    assert _reference_validator("calib").is_valid(doc)
    validate(doc, "calib", "calib.json")
    edit(doc)
    assert not _reference_validator("calib").is_valid(doc)
    with pytest.raises(InputError, match="calib.json: "):
        validate(doc, "calib", "calib.json")


@pytest.mark.parametrize("what,edit,key", BAD_CALIBS, ids=[b[0] for b in BAD_CALIBS])
def test_a_bad_calib_json_is_refused_by_the_loader(calib_path, what, edit, key):
    _write_bad(calib_path, edit)
    with pytest.raises(InputError, match=key):
        load_rig(calib_path)


COMMANDS = {
    "export": lambda c, t: ("export", c, "--format", "opencv", "-o", t / "rig.yml"),
    "undistort": lambda c, t: ("undistort", c, "--camera", "left", t / "x.jpg", "-o", t / "u"),
    "rectify": lambda c, t: ("rectify", c, "--pair", f"left={t / 'x.jpg'}", f"right={t / 'x.jpg'}", "-o", t / "r"),
    "measure": lambda c, t: ("measure", c, "--points", t / "points.json", "-o", t / "m.json"),
    "evaluate": lambda c, t: ("evaluate", c, "-o", t / "e.json"),
    "report": lambda c, t: ("report", c, "-o", t / "r.html"),
}


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("what,edit,key", [BAD_CALIBS[i] for i in (0, 1, 2, 7)], ids=["nan", "inf", "bool", "checks"])
def test_every_command_that_reads_calib_json_refuses_a_bad_one(calib_path, tmp_path, run_cli, command, what, edit,
                                                                key):
    _write_bad(calib_path, edit)
    (tmp_path / "points.json").write_text(json.dumps({"points": {"A": {"left": [1, 2], "right": [3, 4]}}}))
    res = run_cli(*COMMANDS[command](calib_path, tmp_path))
    assert res.code == 2 and key in res.err and len(res.err_lines) == 1, res.err
    assert not any(p.name in ("rig.yml", "u", "r", "m.json", "e.json", "r.html") for p in tmp_path.iterdir())


@pytest.mark.parametrize("text,message", [
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
    ('{"points": {"A": {"left": [1, NaN], "right": [3, 4]}}}', r"points.A.left\[1\] is NaN"),
    ('{"points": {"A": {"left": [1, 2], "right": [3, 4]}}, "pixel_sigma": NaN}', "pixel_sigma is NaN"),
    ('{"points": {"A": {"left": [1, 2], "right": [3, "4"]}}}', r"points.A.right\[1\]: '4' must be number"),
])
def test_json_input_errors_exit_2_not_1(calib_path, tmp_path, run_cli, text, message):
    """Finding 7: deep nesting, NaN sigmas and wrong types were internal errors (exit 1)."""
    (tmp_path / "points.json").write_text(text)
    res = run_cli("measure", calib_path, "--points", tmp_path / "points.json", "-o", tmp_path / "m.json")
    assert res.code == 2 and len(res.err_lines) == 1 and re.search(message, res.err), res.err


def test_a_corners_json_with_nan_or_a_wrong_type_is_refused(stereo, tmp_path):
    path = tmp_path / "corners.json"
    save_corners(path, stereo[1].corners)
    doc = json.loads(path.read_text())
    doc["board"]["square_mm"] = True
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="board.square_mm: True must be number"):
        load_corners(path)


@pytest.mark.parametrize("bad", [True, "1.5", [1.0, 2.0, 3.0], 5, {"u": 1}], ids=["bool", "str", "3", "int", "obj"])
def test_the_one_pass_corner_check_agrees_with_the_schema(stereo, tmp_path, bad):
    """validate() checks the corner lists in one pass of its own (the bulk of a file): it refuses what the
    full schema refuses, naming the corner."""
    save_rig(tmp_path / "calib.json", stereo[1])
    doc = json.loads((tmp_path / "calib.json").read_text())
    views = doc["corners"]["cameras"]["right"]["views"]
    if isinstance(bad, int) and not isinstance(bad, bool):
        views["IMG_02"] = bad
        where = "corners.cameras.right.views.IMG_02"
    elif isinstance(bad, list) or isinstance(bad, dict):
        views["IMG_02"][7] = bad
        where = r"corners.cameras.right.views.IMG_02\[7\]"
    else:
        views["IMG_02"][7] = [1.0, bad]
        where = r"corners.cameras.right.views.IMG_02\[7\]\[1\]"
    assert not _reference_validator("calib").is_valid(doc)
    with pytest.raises(InputError, match=where):
        validate(doc, "calib", "calib.json")


def _key_paths(doc, path=()):
    """Every key path of ``doc`` (lists: their first 3 items)."""
    yield path
    items = doc.items() if isinstance(doc, dict) else enumerate(doc[:3]) if isinstance(doc, list) else ()
    for key, value in items:
        yield from _key_paths(value, path + (key,))


@pytest.mark.parametrize("name", ["calib", "corners"])
def test_the_fast_validator_agrees_with_the_reference_on_random_edits(calib_path, name):
    """120 seeded edits of a calib.json (or its corners), each a value replaced by one of another type or
    range, or a key deleted: fastjsonschema and jsonschema's draft 2020-12 validator judge each alike."""
    import random

    doc = json.loads(calib_path.read_text())
    doc = doc["corners"] if name == "corners" else doc
    reference = _reference_validator(name)
    values = [None, True, 0, -1, 1.5, -2.5, 0.0, 3, "x", [], [1, 2], {}, {"a": 1}]
    rng = random.Random(7)
    paths = [p for p in _key_paths(doc) if p]
    refused = 0
    for _ in range(120):
        edited = json.loads(json.dumps(doc))
        *parents, key = rng.choice(paths)
        parent = edited
        for k in parents:
            parent = parent[k]
        if isinstance(parent, dict) and rng.random() < 0.15:
            del parent[key]
        else:
            parent[key] = json.loads(json.dumps(rng.choice(values)))
        expected = reference.is_valid(edited)
        try:
            validate(edited, name, f"{name}.json")
            valid = True
        except InputError as exc:
            valid = "schema" not in str(exc)          # the loaders' own checks are not the schema's
        assert valid == expected, (parents, key)
        refused += not expected
    assert refused > 40                                # the edits do break the schema, most of the time


def test_a_compiled_validator_is_kept_and_judges_as_a_fresh_one(tmp_path, monkeypatch):
    """The validators' compiled code is kept in the cache directory: a second process (here, the memo cleared)
    reads it instead of compiling, and refuses the same file with the same line; a cache file that is not one
    (truncated, written by another program) is compiled again and replaced; an unwritable cache is passed over."""
    import fastjsonschema

    from dualcal.files import schemas

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    bad = {"board": {"cols": "8", "rows": 5, "square_mm": 30.0}, "cameras": {}}

    def message():
        schemas._validator.cache_clear()
        with pytest.raises(InputError) as error:
            validate(bad, "corners", "c.json")
        return str(error.value)

    fresh = message()
    kept = sorted(schemas.validator_cache().iterdir())
    assert [p.name.split("-")[0] for p in kept] == ["corners", "corners"]          # the fast one and the detailed one
    monkeypatch.setattr(fastjsonschema, "compile_to_code", lambda *a, **k: pytest.fail("compiled again"))
    assert message() == fresh
    monkeypatch.undo()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    kept[0].write_bytes(b"\x00 not marshal")
    assert message() == fresh and kept[0].read_bytes() != b"\x00 not marshal"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "file"))
    (tmp_path / "file").write_text("a file where the folder would be")
    assert message() == fresh
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setattr(schemas.Path, "home", classmethod(lambda cls: (_ for _ in ()).throw(RuntimeError("no home"))))
    assert schemas.validator_cache() is None and message() == fresh
    schemas._validator.cache_clear()
