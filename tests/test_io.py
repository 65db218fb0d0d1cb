"""JSON formats of the contract: loaders, kinds, atomic writes."""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.errors import InputError
from dualcal.files.io import (_corner_list, corners_from_dict, corners_to_dict, dumps_indented, json_kind, load_corners,
                              load_rig, rig_from_dict, rig_to_dict, save_corners, save_rig, write_text_atomic)
from dualcal.synthetic.synth import make_truth, noisy_corner_set


@pytest.fixture(scope="module")
def rig():
    return calibrate_rig(noisy_corner_set(make_truth("note8", 6, seed=3), 0.1, seed=3))


def test_corners_round_trip(tmp_path):
    cs = noisy_corner_set(make_truth("stereo", 4, seed=1), 0.1)
    cs.cameras["left"].views["IMG_02"] = None
    cs.cameras["left"].meta["exif"] = {"make": "X"}
    save_corners(tmp_path / "c.json", cs)
    back = load_corners(tmp_path / "c.json")
    assert back.board == cs.board and back.cameras["left"].views["IMG_02"] is None
    assert back.cameras["left"].meta == {"exif": {"make": "X"}}
    np.testing.assert_allclose(back.cameras["right"].views["IMG_03"], cs.cameras["right"].views["IMG_03"], atol=1e-5)


def test_null_corners_keep_their_place(tmp_path):
    """A corner that was not measured is ``null`` in corners.json and a NaN row in memory: index k is corner k."""
    cs = noisy_corner_set(make_truth("stereo", 4, seed=1), 0.1)
    uv = cs.cameras["left"].views["IMG_01"]
    uv[[0, 7, 53]] = np.nan
    save_corners(tmp_path / "c.json", cs)
    doc = json.loads((tmp_path / "c.json").read_text())
    listed = doc["cameras"]["left"]["views"]["IMG_01"]
    assert len(listed) == 54 and [k for k, p in enumerate(listed) if p is None] == [0, 7, 53]
    back = load_corners(tmp_path / "c.json").cameras["left"].views["IMG_01"]
    assert back.shape == (54, 2)
    np.testing.assert_array_equal(np.isnan(back[:, 0]), np.isnan(uv[:, 0]))
    np.testing.assert_allclose(back[1:7], uv[1:7], atol=1e-5)
    assert "IMG_01" in load_corners(tmp_path / "c.json").cameras["left"].found()


@pytest.mark.parametrize("views, message", [
    ({"a": [None, None, None, None]}, "every corner is null"),
    ({"a": [[1, 2], None, [3, float("nan")], [4, 5]]}, "NaN"),
    ({"a": [[1, 2], None, [3], [4, 5]]}, "expected numbers"),
])
def test_malformed_null_corners_are_clear_errors(views, message):
    doc = {"board": {"cols": 2, "rows": 2, "square_mm": 30}, "cameras": {"w": {"image_size": [9, 9], "views": views}}}
    with pytest.raises(InputError, match=message):
        corners_from_dict(doc)


def test_calib_json_has_the_contract_keys_and_round_trips(tmp_path, rig):
    save_rig(tmp_path / "calib.json", rig)
    doc = json.loads((tmp_path / "calib.json").read_text())
    for key in ("dualcal_version", "board", "reference", "skew", "rig_mode", "cameras", "rig", "views",
                "rms_px", "corners"):
        assert key in doc
    wide = doc["cameras"]["wide"]
    assert set(wide) >= {"image_size", "fx", "fy", "skew", "cx", "cy", "k1", "k2", "sigma", "rms_px"}
    tele = doc["rig"]["tele"]
    assert set(tele) >= {"R", "t_mm", "baseline_mm", "opk_arcmin", "sigma"}
    assert set(tele["sigma"]) == {"baseline_mm", "opk_arcmin", "t_mm"}
    assert tele["baseline_mm"] == pytest.approx(np.linalg.norm(tele["t_mm"]))
    view = next(iter(doc["views"].values()))
    assert set(view) >= {"R", "t_mm", "rms_px"} and set(view["rms_px"]) == {"wide", "tele"}
    back = load_rig(tmp_path / "calib.json")
    assert back.cameras == rig.cameras
    np.testing.assert_allclose(back.rig["tele"].pose.t_mm, rig.rig["tele"].pose.t_mm)
    assert back.camera_sigma == rig.camera_sigma


@pytest.fixture(scope="module")
def rig5():
    return calibrate_rig(noisy_corner_set(make_truth("stereo5", 6, seed=3), 0.1, seed=3), model="k1k2p1p2k3")


def test_calib_json_of_the_paper_model_keeps_the_keys_of_before(rig):
    """k1k2: the camera entries are those of the contract (no p1, p2, k3), ``model`` names the model."""
    doc = rig_to_dict(rig)
    assert doc["model"] == "k1k2"
    for entry in doc["cameras"].values():
        names = {"fx", "fy", "skew", "cx", "cy", "k1", "k2"}
        assert set(entry) == names | {"image_size", "model", "sigma", "sigma_formal", "rms_px"}
        assert set(entry["sigma"]) == set(entry["sigma_formal"]) == names


def test_calib_json_of_opencvs_model_has_its_coefficients_and_round_trips(tmp_path, rig5):
    save_rig(tmp_path / "calib.json", rig5)
    doc = json.loads((tmp_path / "calib.json").read_text())
    assert doc["model"] == "k1k2p1p2k3"
    for name, entry in doc["cameras"].items():
        assert {"p1", "p2", "k3"} <= set(entry) and {"p1", "p2", "k3"} <= set(entry["sigma"])
        assert entry["p1"] == rig5.cameras[name].p1 and entry["sigma"]["k3"] == rig5.camera_sigma[name]["k3"] > 0
    back = load_rig(tmp_path / "calib.json")
    assert back.cameras == rig5.cameras and back.model == "k1k2p1p2k3"
    assert back.camera_sigma == rig5.camera_sigma


def test_a_calib_json_written_before_lens_models_reads_as_k1k2(rig):
    """A calib.json of main before this change: no ``model``, cameras with k1 k2 only."""
    doc = rig_to_dict(rig)
    del doc["model"]
    back = rig_from_dict(doc)
    assert back.model == "k1k2" and back.cameras == rig.cameras
    assert all((cam.p1, cam.p2, cam.k3) == (0.0, 0.0, 0.0) for cam in back.cameras.values())


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["cameras"]["left"].update(p1=0.001), "camera 'left' has p1, which its lens model k1k2 does not"),
    (lambda d: [d.update(model="k1k2p1p2")] + [c.pop("model") for c in d["cameras"].values()],
     "camera 'left' lacks p1, p2 of its lens model k1k2p1p2"),      # a file of before cameras had a model
    (lambda d: d.update(model="k1k2p1p2"), "camera 'left' has lens model k1k2, the file's 'model' says k1k2p1p2"),
    (lambda d: d["cameras"]["left"].update(model="kb4"), "camera 'left' has lens model kb4, the file's 'model' says k1k2"),
    (lambda d: d.update(model="fisheye"), "lens model 'fisheye' is unknown"),
])
def test_camera_keys_must_fit_the_lens_model(edit, message):
    doc = rig_to_dict(calibrate_rig(noisy_corner_set(make_truth("stereo", 4, seed=1), 0.0), rig_mode="none"))
    edit(doc)
    with pytest.raises(InputError, match=message):
        rig_from_dict(doc)


def test_minimal_calib_json_derives_camera_poses(rig):
    doc = rig_to_dict(rig)
    for key in ("camera_poses", "adjustment", "dropped_views"):
        del doc[key]
    back = rig_from_dict(doc)
    for view, pose in rig.camera_poses["tele"].items():
        np.testing.assert_allclose(back.camera_poses["tele"][view].t_mm, pose.t_mm, atol=1e-9)


def test_file_kinds_are_told_apart(tmp_path, rig):
    save_rig(tmp_path / "calib.json", rig)
    save_corners(tmp_path / "corners.json", rig.corners)
    with pytest.raises(InputError, match="this is a calib.json, expected a corners.json"):
        load_corners(tmp_path / "calib.json")
    with pytest.raises(InputError, match="this is a corners.json, expected a calib.json"):
        load_rig(tmp_path / "corners.json")
    assert json_kind({"cases": {}}) == "eval"


@pytest.mark.parametrize("text,message", [
    ('{"board": {"cols": 8, "rows": 5, "square_mm": 30}, "cameras": {"wide": {"image_size": [10', "truncated"),
    ("[1, 2]", "top level"),
    ('{"board": {"cols": 8}, "cameras": {}}', r"board: must contain \['rows', 'square_mm'\] properties"),
    ('{"board": {"cols": 8, "rows": 5, "square_mm": 30}, "cameras": {}}', "cameras: must contain at least 1 properties"),
    ('{"board": {"cols": 8, "rows": 5, "square_mm": 30}, "cameras": {"w": {"image_size": [0, 5], "views": {}}}}',
     r"cameras.w.image_size\[0\]: 0 must be bigger than or equal to 1"),
    ('{"board": {"cols": 2, "rows": 2, "square_mm": 30}, "cameras": {"w": {"image_size": [9, 9], '
     '"views": {"a": [[1, 2], [3, 4], [5, 6]]}}}}', "4 corners"),
])
def test_malformed_corners_are_clear_errors(tmp_path, text, message):
    p = tmp_path / "c.json"
    p.write_text(text)
    with pytest.raises(InputError, match=message):
        load_corners(p)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_corners(tmp_path / "nope.json")
    with pytest.raises(InputError, match="is a folder"):
        load_corners(tmp_path)


_json = st.recursive(st.none() | st.booleans() | st.floats(allow_nan=False) | st.integers() | st.text(max_size=5),
                     lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children,
                                                                                     max_size=4), max_leaves=20)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(doc=st.dictionaries(st.sampled_from(["board", "cameras", "views", "rig", "x"]), _json, max_size=4))
def test_loaders_fail_only_with_input_error(doc):
    for loader in (corners_from_dict, rig_from_dict):
        try:
            loader(doc)
        except InputError:
            pass


@settings(max_examples=40, deadline=None)
@given(cols=st.integers(2, 9), rows=st.integers(2, 9), data=st.data())
def test_valid_corner_documents_round_trip(cols, rows, data):
    n = cols * rows
    pts = data.draw(st.lists(st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4)), min_size=n, max_size=n))
    doc = {"board": {"cols": cols, "rows": rows, "square_mm": 25.0},
           "cameras": {"c": {"image_size": [100, 80], "views": {"v1": [list(p) for p in pts], "v2": None}}}}
    back = corners_to_dict(corners_from_dict(doc))
    np.testing.assert_allclose(back["cameras"]["c"]["views"]["v1"], np.round(pts, 5))
    assert back["cameras"]["c"]["views"]["v2"] is None


def test_a_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    import dualcal.files.io as io_module
    target = tmp_path / "out.json"
    target.write_text("old")

    def crash(fd, data):
        raise RuntimeError("crash while writing")
    monkeypatch.setattr(io_module, "_write_all", crash)
    with pytest.raises(RuntimeError):
        write_text_atomic(target, "half")
    monkeypatch.undo()
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]
    write_text_atomic(target, "new")
    assert target.read_text() == "new"


def test_output_into_a_missing_folder_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        write_text_atomic(tmp_path / "no" / "out.json", "x")


def test_atomic_outputs_get_ordinary_permissions(tmp_path):
    import os
    target = tmp_path / "out.json"
    write_text_atomic(target, "x")
    mask = os.umask(0)
    os.umask(mask)
    assert (target.stat().st_mode & 0o777) == (0o666 & ~mask)


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.update(reference="nope"), "reference 'nope'"),
    (lambda d: d["corners"]["cameras"].pop("tele"), "its corners are of cameras"),
    (lambda d: d["cameras"]["wide"].update(fx=-3.0), "focal lengths must be positive"),
    (lambda d: d["rig"]["tele"].update(R=[[1, 0, 0], [0, 2, 0], [0, 0, 1]]), "not orthonormal"),
    (lambda d: d["board"].update(cols=9), "'board' and 'corners.board' differ"),
])
def test_inconsistent_calib_json_is_a_clear_error(rig, edit, message):
    doc = json.loads(json.dumps(rig_to_dict(rig)))
    edit(doc)
    with pytest.raises(InputError, match=message):
        rig_from_dict(doc)


def test_a_rig_of_mixed_lens_models_round_trips_with_each_cameras_model(tmp_path):
    """phone3: a kb4 ultra-wide (with k4) beside k1k2p1p2k3 and k1k2 cameras; top-level model "mixed"."""
    rig = calibrate_rig(noisy_corner_set(make_truth("phone3", 8, seed=2), 0.05, seed=2),
                        model={"wide": "k1k2", "ultra": "kb4", "tele": "k1k2"}, board_shape="flat")
    doc = rig_to_dict(rig)
    assert doc["model"] == "mixed" and doc["cameras"]["ultra"]["model"] == "kb4" and "k4" in doc["cameras"]["ultra"]
    assert "k4" not in doc["cameras"]["wide"] and "k4" in doc["cameras"]["ultra"]["sigma"]
    save_rig(tmp_path / "calib.json", rig)
    back = load_rig(tmp_path / "calib.json")
    assert back.cameras == rig.cameras and back.models == rig.models
    assert back.calibration_options()["model"] == {"tele": "k1k2", "ultra": "kb4", "wide": "k1k2"}


json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.text(max_size=5)
                           | st.floats(allow_nan=False, allow_infinity=False),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=3), inner, max_size=4),
                           max_leaves=30)


@settings(max_examples=60, deadline=None)
@given(json_values)
def test_the_indented_json_is_json_dumps_text_byte_for_byte(doc):
    """calib.json is written by dualcal's own indent-1 encoder (faster on thousands of corners): its text is
    ``json.dumps(doc, indent=1, allow_nan=False)``'s for any document, and it refuses what json refuses."""
    assert dumps_indented(doc) == json.dumps(doc, indent=1, allow_nan=False)


def test_a_calib_json_is_json_dumps_text_and_refuses_nan(rig):
    doc = rig_to_dict(rig)
    assert dumps_indented(doc) == json.dumps(doc, indent=1, allow_nan=False)
    for bad in ({"a": [1.0, float("nan")]}, {"a": [[1.0, float("inf")], None]}, {"a": float("-inf")}):
        with pytest.raises(ValueError):
            dumps_indented(bad)
    with pytest.raises(TypeError):
        dumps_indented({"a": np.float32(1.0)})


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.floats(-1e12, 1e12) | st.just(float("nan")), st.floats(-1e12, 1e12)), min_size=1,
                max_size=12), st.booleans())
def test_a_views_corners_are_written_rounded_to_5_decimals_whether_or_not_they_were(pairs, rounded):
    """corners.json (and calib.json's corners) keep 5 decimals: corners already rounded (read from a corners.json)
    are taken as they are, the others rounded by Python's ``round``; either way every number is ``round(x, 5)``."""
    from dualcal.files.io import _corner_list

    uv = np.array(pairs, float)
    if rounded:
        uv = np.array([[round(u, 5), round(v, 5)] for u, v in uv.tolist()])
    expected = [[round(u, 5), round(v, 5)] if np.isfinite(u) and np.isfinite(v) else None for u, v in uv.tolist()]
    assert _corner_list(uv) == expected
