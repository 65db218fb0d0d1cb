"""A phone's camera roll (dualcal.files.roll): cameras by EXIF, instants by capture time, retakes, sidecars."""

import json
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from dualcal.files import roll
from dualcal.synthetic import synth
from dualcal.errors import InputError
from dualcal.files.photos import Photo
from dualcal.synthetic.synth_roll import equivalent_focal_of, write_camera_roll
from dualcal.workflow import read_corners
from dualcal.geometry.board import Board
from dualcal.geometry.camera import LENS_MODELS

T0 = datetime(2026, 11, 30, 9, 0, 0)


def _photo(name, seconds, lens="main 6.9mm", f35=24.0, size=(4032, 3024), f_mm=6.9, **exif):
    facts = {"make": "Apple", "model": "iPhone", "lens_model": lens, "focal_length_mm": f_mm,
             "focal_length_35mm_mm": f35, "taken": T0 + timedelta(seconds=seconds), **exif}
    return Photo(Path(f"/roll/{name}.HEIC"), size, facts)


def _session(positions=5, lenses=(("ultra 2.2mm", 13.0), ("main 6.9mm", 24.0), ("tele 9mm", 77.0)),
             lens_gap=(2.0, 7.0), position_gap=(20.0, 80.0), seed=0):
    rng = np.random.default_rng(seed)
    photos, t, n = [], 0.0, 101
    for _ in range(positions):
        t += rng.uniform(*position_gap)
        for i, (lens, f35) in enumerate(lenses):
            t += rng.uniform(*lens_gap) if i else 0.0
            photos.append(_photo(f"IMG_{n:04d}", t, lens, f35))
            n += 1
    return photos


def test_cameras_are_named_by_equivalent_focal_length():
    cams, facts, warnings = roll.split_cameras(_session())
    assert list(cams) == ["ultra", "wide", "tele"] and not warnings
    assert facts["tele"]["focal_length_35mm_mm"] == 77.0 and facts["wide"]["photos"] == 5


def test_a_second_tele_is_tele2_and_one_lens_at_two_sizes_is_two_cameras():
    photos = _session(lenses=(("main", 24.0), ("tele 3x", 77.0), ("tele 5x", 120.0)))
    photos.append(_photo("IMG_0900", 9999, "main", 24.0, size=(8064, 6048)))
    cams, _, _ = roll.split_cameras(photos)
    assert list(cams) == ["wide", "wide2", "tele", "tele2"]
    assert {p.size for p in cams["wide2"]} == {(8064, 6048)}


def test_without_equivalent_focal_lengths_the_cameras_are_named_by_rank_with_a_warning():
    photos = [Photo(p.path, p.size, {**p.exif, "focal_length_35mm_mm": None, "focal_length_mm": f})
              for p, f in zip(_session(positions=1), (2.2, 6.9, 9.0))]
    cams, _, warnings = roll.split_cameras(photos)
    assert list(cams) == ["ultra", "wide", "tele"] and "by rank" in warnings[0]


def test_equivalent_focal_length_is_derived_from_the_sensor_size():
    # 4032 x 3024 px at 1.0 um pitch: a 5.04 mm diagonal; 2.2 mm -> 2.2 * 43.27 / 5.04 = 18.9 mm
    p = _photo("a", 0, f35=None, f_mm=2.2, focal_plane_px_per_mm=1000.0)
    assert roll.equivalent_focal_mm(p) == pytest.approx(2.2 * np.hypot(36, 24) / 5.04, rel=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_instants_are_found_from_the_capture_times(seed):
    photos = _session(positions=6, seed=seed)
    cams, _, _ = roll.split_cameras(photos)
    instants, gap, found = roll.split_instants(cams)
    assert found and 7.0 < gap < 20.0
    assert [len(i) for i in instants] == [3] * 6
    assert all({name for name, _ in inst} == {"ultra", "wide", "tele"} for inst in instants)


def test_a_given_gap_overrides_and_no_break_is_refused():
    photos = _session(positions=4, lens_gap=(3, 4), position_gap=(5, 6))     # no clear break
    cams, _, _ = roll.split_cameras(photos)
    with pytest.raises(InputError, match="no break between board positions"):
        roll.split_instants(cams)
    instants, gap, found = roll.split_instants(cams, 4.5)
    assert not found and gap == 4.5 and [len(i) for i in instants] == [3] * 4


def test_a_retake_keeps_the_later_photo_and_says_so():
    photos = _session(positions=3)
    wide = photos[4]                                   # position 2's wide
    retake = _photo("IMG_0199", (wide.exif["taken"] - T0).total_seconds() + 1.5, wide.exif["lens_model"], 24.0)
    result, warnings = roll.open_camera_roll(photos + [retake], "/roll")
    key = photos[3].path.stem
    assert result.cameras["wide"][key].path.name == "IMG_0199.HEIC"
    assert "retake" in result.record["left_out"][wide.path.name]
    assert any(w.startswith(f"{wide.path.name}: left out (retake") for w in warnings)


def test_an_instant_one_lens_missed_is_kept():
    photos = _session(positions=4)
    del photos[5]                                      # position 2 has no tele
    result, _ = roll.open_camera_roll(photos, "/roll")
    assert len(result.cameras["wide"]) == 4 and len(result.cameras["tele"]) == 3


@pytest.fixture(scope="module")
def rendered_roll(tmp_path_factory):
    """A three-lens phone's tripod session in one folder: ``phone3`` (a kb4 fisheye ultra-wide, a wide and a
    3x tele) at quarter size, 12 board positions, some seen by the ultra-wide alone."""
    truth = synth.make_truth("phone3", views=12, seed=4, scale=0.25)
    folder = tmp_path_factory.mktemp("roll") / "DCIM"
    shot = write_camera_roll(truth, folder, seed=4, progress=False)
    return truth, folder, shot


def test_a_rendered_roll_is_split_as_it_was_shot(rendered_roll, capsys):
    truth, folder, shot = rendered_roll
    from dualcal.files.dataset import open_dataset

    ds = open_dataset(folder)
    err = capsys.readouterr().err
    assert set(ds.cameras) == {"ultra", "wide", "tele"} and ds.reference == "wide"
    for name, views in ds.cameras.items():
        assert all(shot["photos"][p.path.name][0] in (name, None) for p in views.values())   # None: the stray
    assert shot["stray"] in {p.path.name for p in ds.cameras["wide"].values()}
    # each instant holds the photos of one board position
    for key, inst in ds.roll["instants"].items():
        assert len({shot["photos"][f][1] for f in inst["photos"].values()}) == 1
    first, second = shot["retake"]
    assert ds.cameras["wide"][next(k for k, p in ds.cameras["wide"].items() if p.path.name == second)]
    assert "retake" in ds.roll["left_out"][first]
    assert all(s in err for s in shot["sidecars"]), err


def test_a_rendered_roll_calibrates_with_no_flag_but_the_board(rendered_roll, tmp_path, run_cli):
    truth, folder, shot = rendered_roll
    res = run_cli("calibrate", folder, "--board", "8x5", "--square", "30", "-o", tmp_path / "calib.json")
    assert res.code == 0, res.err
    assert "Camera roll" in res.out and shot["retake"][0] in res.out
    doc = json.loads((tmp_path / "calib.json").read_text())
    assert doc["reference"] == "wide" and set(doc["cameras"]) == {"ultra", "wide", "tele"}
    assert shot["stray"] in doc["corners"]["roll"]["left_out"]          # the photo without the board
    assert doc["cameras"]["ultra"]["model"] == "kb4" and doc["cameras"]["tele"]["model"] == "k1k2"   # --model auto
    assert doc["cameras"]["ultra"]["rms_px"] < 0.06                     # at the renders' corner noise
    for name, cam in doc["cameras"].items():
        true = truth.cameras[name]
        same_lens = cam["model"] == true.model or set(LENS_MODELS[cam["model"]]) <= set(LENS_MODELS[true.model])
        for p in ("fx", "fy", "cx", "cy") + (LENS_MODELS[cam["model"]] if same_lens else ()):
            assert abs(cam[p] - getattr(true, p)) < 4 * cam["sigma"][p], (name, p, cam[p], getattr(true, p))
    for name, rel in doc["rig"].items():
        t_true = truth.rig[name].t_mm
        assert np.all(np.abs(np.array(rel["t_mm"]) - t_true) < 4 * np.array(rel["sigma"]["t_mm"])), name


def test_exclude_works_on_the_roll(rendered_roll):
    truth, folder, shot = rendered_roll
    tele = next(f for f, (cam, view) in shot["photos"].items() if cam == "tele")
    corners = read_corners(folder, Board(8, 5, 30.0), exclude=[tele], progress=False)
    assert tele in json.dumps(corners.cameras["tele"].meta["excluded"])
    assert all(Path(p).name != tele for p in corners.cameras["tele"].meta["photos"].values())


@pytest.mark.parametrize("preset", ["triple", "phone3"])
def test_equivalent_focal_length_of_the_render_matches_its_class(preset):
    truth = synth.make_truth(preset, views=3, seed=0)
    assert {n: roll.camera_class(equivalent_focal_of(c)) for n, c in truth.cameras.items()} == \
        {"wide": "wide", "tele": "tele", "ultra": "ultra"}


def test_synth_writes_a_roll_and_board_suggests_a_board_for_its_cameras(tmp_path, run_cli):
    res = run_cli("synth", tmp_path / "s", "--preset", "triple", "--views", "3", "--scale", "0.2", "--roll")
    assert res.code == 0, res.err
    files = sorted(p.name for p in (tmp_path / "s" / "roll").iterdir())
    assert len([f for f in files if f.endswith(".JPG")]) == 3 * 3 + 2          # a retake and a stray photo
    assert any(f.endswith(".AAE") for f in files) and not (tmp_path / "s" / "photos").exists()
    res = run_cli("board", "--for", tmp_path / "s" / "roll", "-o", tmp_path / "board.pdf")
    assert res.code == 0, res.err
    assert "the tele sees it whole" in res.err and (tmp_path / "board.pdf").stat().st_size > 1000


def test_a_copied_photo_counts_once_in_a_roll_and_in_a_camera_folder(rendered_roll, tmp_path, capsys):
    import shutil

    from dualcal.files.dataset import open_dataset

    truth, folder, shot = rendered_roll
    roll = tmp_path / "roll"
    shutil.copytree(folder, roll)
    first = sorted(f for f, (cam, _) in shot["photos"].items() if cam == "tele")[0]
    shutil.copy(roll / first, roll / "IMG_0999.JPG")            # exported twice (a later number, the same bytes)
    ds = open_dataset(roll)
    assert "IMG_0999.JPG: the same file as" in capsys.readouterr().err
    assert all(p.path.name != "IMG_0999.JPG" for v in ds.cameras.values() for p in v.values())
    assert ds.roll["left_out"]["IMG_0999.JPG"] == f"the same file as {first}"
    assert ds.meta("tele")["identical_files"] == {str(roll / "IMG_0999.JPG"): str(roll / first)}
    # a camera folder of a dataset alike
    cam = tmp_path / "set" / "tele"
    cam.mkdir(parents=True)
    for f in sorted(f for f, (c, _) in shot["photos"].items() if c == "tele")[:4]:
        shutil.copy(folder / f, cam / f)
    shutil.copy(cam / first, cam / "copy.JPG")
    assert len(open_dataset(tmp_path / "set").cameras["tele"]) == 4


def test_a_folder_of_one_camera_keeps_the_copies_it_left_out(rendered_roll, tmp_path):
    """One camera's flat folder: its copies are found once and recorded (identical_files)."""
    import shutil

    from dualcal.files.dataset import open_dataset

    truth, folder, shot = rendered_roll
    cam = tmp_path / "tele"
    cam.mkdir()
    teles = sorted(f for f, (c, _) in shot["photos"].items() if c == "tele")[:4]
    for f in teles:
        shutil.copy(folder / f, cam / f)
    shutil.copy(cam / teles[0], cam / "copy.JPG")
    ds = open_dataset(cam)
    assert len(ds.cameras["tele"]) == 4
    assert ds.meta("tele")["identical_files"] == {str(cam / "copy.JPG"): str(cam / teles[0])}
