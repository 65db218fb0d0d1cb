"""A phone's camera roll (dualcal.files.roll): cameras by EXIF or by what the photos show, photos stored turned,
instants from every clue of the roll (shot in every messy way), retakes, sidecars, a roll without EXIF."""

import contextlib
import io
import json
from dataclasses import replace
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from dualcal.files import roll, roll_positions
from dualcal.synthetic import synth
from dualcal.errors import InputError
from dualcal.files.photos import Photo
from dualcal.synthetic.synth_roll import Shooting, equivalent_focal_of, shooting_script, strip_exif, write_camera_roll
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


def test_the_lens_key_holds_the_equivalent_focal_length_so_a_crop_is_its_own_camera():
    """An iPhone's "2x" is its main lens cropped: the same LensModel and size, another 35 mm equivalent."""
    photos = _session(positions=2, lenses=(("main 6.86mm", 24.0),)) + \
        [_photo(f"IMG_2{i}", 500 + i, "main 6.86mm", 48.0) for i in range(2)]
    cams, _, _ = roll.split_cameras(photos)
    assert {n: len(v) for n, v in cams.items()} == {"wide": 2, "tele": 2}


def test_a_photo_stored_turned_is_left_out_not_taken_for_a_camera():
    photos = [_photo(f"IMG_{i}", i, size=(2048, 1536)) for i in range(5)] + [_photo("IMG_9", 9, size=(1536, 2048))]
    kept, turned = roll.turned_photos(photos)
    assert len(kept) == 5 and not roll.is_camera_roll(kept)
    assert list(turned) == [Path("/roll/IMG_9.HEIC")] and turned[Path("/roll/IMG_9.HEIC")].startswith(
        "stored turned: 1536x2048, where 5 other photo(s) of the same camera are 2048x1536")
    with pytest.raises(InputError, match="as many 1536x2048"):      # which is turned? neither can be told
        roll.turned_photos(photos[:1] + photos[-1:])


# ---------------------------------------------------------------------------- the split, on shooting scripts

@pytest.fixture(scope="module")
def phone():
    """``phone3`` (a kb4 fisheye ultra-wide, a wide and a 3x tele) at quarter size, 12 board positions, some seen
    by the ultra-wide alone."""
    return synth.make_truth("phone3", views=12, seed=6, scale=0.25)


def _shot(truth, shooting, seed=6, exif=True, noise_px=0.1):
    """The script of a session, its photos' headers (as the phone writes them, or as a browser uploads them:
    without EXIF) and their corners (the truth's, with noise; None where the photo shows no board)."""
    rng = np.random.default_rng(seed)
    corners = synth.true_corners(truth)
    script = shooting_script(truth, shooting, seed)
    photos, uv = [], {}
    for s in script:
        cam = truth.cameras[s.camera or truth.reference]
        f35 = equivalent_focal_of(cam)
        facts = {"make": "dualcal", "model": "phone", "lens_model": f"lens {round(f35)} mm", "focal_length_mm": f35 / 5,
                 "focal_length_35mm_mm": float(round(f35)), "taken": s.taken} if exif else {}
        photos.append(Photo(Path("/roll") / s.name, tuple(cam.image_size), facts))
        seen = s.camera is not None and np.isfinite(corners[s.camera][s.view]).all()
        uv[photos[-1].path] = corners[s.camera][s.view] + rng.normal(0, noise_px, (truth.board.n_corners, 2)) \
            if seen else None
    return script, photos, uv


def _split(truth, photos, uv, exif=True, instant_gap_s=None):
    xy = truth.board.object_points_mm()[:, :2]
    if exif:
        (cams, facts, _), left_out, clues = roll.split_cameras(photos), {}, ("EXIF lens", "image size")
    else:
        cams, facts, _, left_out = roll.cameras_from_boards(photos, uv, xy)
        clues = ("image size", "focal length from the board")
    return roll.split_roll(cams, facts, uv, xy, "/roll", instant_gap_s, left_out, clues)


def _as_shot(script, uv):
    """The instants as shot: per board position, each camera's last photo showing the board (a retake replaces
    the first), keyed by the stem of the position's first photo with the board."""
    out, keys = {}, {}
    for s in script:
        if s.camera is not None and uv[Path("/roll") / s.name] is not None:
            out.setdefault(s.view, {})[s.camera] = s.name
            keys.setdefault(s.view, Path(s.name).stem)
    return {keys[v]: photos for v, photos in out.items()}


MESSY = {
    # one lens switch took 4.6 s, a retake, a stray photo 10 s after the last position, positions 20-40 s apart
    "as the issue found it": Shooting(lens_gap_s=(0.4, 3.0), position_gap_s=(20.0, 40.0), slow_switch_s=4.6,
                                      stray_after=(-1,), stray_gap_s=(10.0, 10.0)),
    "positions shot quickly, strays between": Shooting(lens_gap_s=(1.5, 5.0), position_gap_s=(3.0, 6.0),
                                                       stray_after=(0, 2, 4)),
    "slow switches, lenses that missed": Shooting(lens_gap_s=(5.0, 15.0), position_gap_s=(15.0, 30.0),
                                                  missed=(("tele", 2), ("ultra", 3), ("wide", 5), ("tele", 6))),
}


@pytest.mark.parametrize("exif", [True, False], ids=["EXIF", "no EXIF"])
@pytest.mark.parametrize("how", list(MESSY))
def test_a_roll_shot_as_people_shoot_splits_right_with_no_flag(phone, how, exif):
    script, photos, uv = _shot(phone, MESSY[how], exif=exif)
    result, warnings = _split(phone, photos, uv, exif)
    record = result.record
    assert {k: i["photos"] for k, i in record["instants"].items()} == _as_shot(script, uv)
    assert all(i["margin"] >= roll_positions.MIN_MARGIN for i in record["instants"].values())
    assert not [w for w in warnings if "unsure" in w]
    first, second = next((a.name, b.name) for a, b in zip(script, script[1:])
                         if a.camera is not None and (a.camera, a.view) == (b.camera, b.view))
    assert record["left_out"][first].startswith(f"retake: {second}")
    assert all(record["left_out"][s.name].startswith("no board found") for s in script if s.camera is None)
    assert record["order"] == ("capture time" if exif else "file name")
    assert set(record["clues"]["instants"]) == {"order", "board image", "board pose", "lens order"} | (
        {"capture time"} if exif else set())
    if not exif:                                  # the cameras told by field of view, named by the same rule
        assert record["clues"]["cameras"] == ["image size", "focal length from the board"]
        for name, cam in record["cameras"].items():
            assert cam["focal_length_35mm_mm"] == pytest.approx(equivalent_focal_of(phone.cameras[name]), rel=0.1)


def test_a_board_that_looks_the_same_turned_splits_whichever_way_each_photo_is_numbered():
    """An 8x6 board (9 x 7 squares) looks the same turned by 180 degrees: detection numbers each photo by the
    top-left rule, so photos of one position may be numbered either way round; the split does not care."""
    truth = synth.make_truth("triple", views=8, seed=2, scale=0.25, board=Board(8, 6, 30.0))
    script, photos, uv = _shot(truth, MESSY["as the issue found it"], seed=2, exif=False)
    rng = np.random.default_rng(2)
    uv = {k: v if v is None or rng.random() < 0.5 else v[::-1].copy() for k, v in uv.items()}
    xy = truth.board.object_points_mm()[:, :2]
    cams, facts, _, left_out = roll.cameras_from_boards(photos, uv, xy, symmetric=True)
    result, _ = roll.split_roll(cams, facts, uv, xy, "/roll", None, left_out, symmetric=True)
    assert {k: i["photos"] for k, i in result.record["instants"].items()} == _as_shot(script, uv)


def test_a_given_gap_decides_where_the_boards_allow(phone):
    script, photos, uv = _shot(phone, MESSY["as the issue found it"])
    result, _ = _split(phone, photos, uv, instant_gap_s=9.0)
    assert {k: i["photos"] for k, i in result.record["instants"].items()} == _as_shot(script, uv)
    assert result.record["instant_gap_s"] == 9.0 and not result.record["instant_gap_found"]


def test_a_position_whose_lenses_are_minutes_apart_follows_its_boards_less_surely(phone, monkeypatch):
    """A two-lens roll whose wide and tele of one position are five minutes apart, where positions are half a
    minute apart: the capture times say two positions, the boards one, and the boards are surer. Where the
    clues disagree and neither is sure, the split is refused, naming the photos and what each clue says."""
    two = replace(phone, cameras={n: c for n, c in phone.cameras.items() if n != "ultra"},
                  rig={n: r for n, r in phone.rig.items() if n != "ultra"})
    script, photos, uv = _shot(two, Shooting(lens_gap_s=(1.0, 2.0), position_gap_s=(25.0, 35.0), retake=False,
                                             stray_after=()))
    shown = [uv[p.path] is not None for p in photos]
    late = next(i for i in range(5, len(script)) if shown[i - 1] and shown[i] and script[i - 1].view == script[i].view)
    photos = photos[:late] + [replace(p, exif={**p.exif, "taken": p.exif["taken"] + timedelta(seconds=300)})
                              for p in photos[late:]]
    result, _ = _split(two, photos, uv)
    assert {k: i["photos"] for k, i in result.record["instants"].items()} == _as_shot(script, uv)
    slow = result.record["instants"][Path(script[late - 1].name).stem]
    assert slow["sure"] == "likely" and slow["margin"] < min(i["margin"] for i in result.record["instants"].values()
                                                              if i is not slow)
    real = roll_positions.split_positions

    def unsure(shots, *args):
        split = real(shots, *args)
        k = next(k for k in range(1, len(shots)) if shots[k].taken_s - shots[k - 1].taken_s > 200)
        split.margins[k - 1], split.board_log_odds[k - 1] = 1.0, 1.5
        return split

    monkeypatch.setattr(roll, "split_positions", unsure)
    with pytest.raises(InputError, match=rf"{script[late - 1].name} \(wide\) and {script[late].name} \(tele\) are one "
                                         r"board position: the capture times say no \(a gap of 30\d\.\d s\), the boards yes"):
        _split(two, photos, uv)


@pytest.fixture(scope="module")
def rendered_roll(tmp_path_factory):
    """A three-lens phone's tripod session in one folder: ``phone3`` (a kb4 fisheye ultra-wide, a wide and a
    3x tele) at quarter size, 12 board positions, some seen by the ultra-wide alone."""
    truth = synth.make_truth("phone3", views=12, seed=4, scale=0.25)
    folder = tmp_path_factory.mktemp("roll") / "DCIM"
    shot = write_camera_roll(truth, folder, seed=4, progress=False)
    return truth, folder, shot


@pytest.fixture(scope="module")
def calibrated_roll(rendered_roll, tmp_path_factory):
    """``dualcal calibrate DCIM/`` on the rendered roll, with no flag but the board: its exit code, output and
    calib.json."""
    from dualcal.cli import main

    truth, folder, shot = rendered_roll
    out = tmp_path_factory.mktemp("calibrated") / "calib.json"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr), pytest.raises(SystemExit) as exc:
        main(["calibrate", str(folder), "--board", "8x5", "--square", "30", "-o", str(out)])
    return exc.value.code, stdout.getvalue(), stderr.getvalue(), (json.loads(out.read_text()) if out.exists() else None)


def test_a_rendered_roll_is_split_as_it_was_shot(rendered_roll, calibrated_roll):
    truth, folder, shot = rendered_roll
    code, out, err, doc = calibrated_roll
    assert code == 0, err
    record = doc["corners"]["roll"]
    assert set(record["cameras"]) == {"ultra", "wide", "tele"} and doc["reference"] == "wide"
    for inst in record["instants"].values():       # each instant one board position, each photo its camera
        assert len({shot["photos"][f][1] for f in inst["photos"].values()}) == 1
        assert all(shot["photos"][f][0] == name for name, f in inst["photos"].items())
    first, second = shot["retake"]
    assert "retake" in record["left_out"][first] and second in json.dumps(record["instants"])
    assert all(record["left_out"][s].startswith("no board found") for s in shot["stray"])
    assert all(s in err for s in shot["sidecars"]), err
    assert "capture time" in record["clues"]["instants"] and record["split_margin"] >= roll_positions.MIN_MARGIN


def _assert_near_the_truth(doc, truth):
    """Every intrinsic of every camera (of the true lens model's, where the chosen model is another) and every
    baseline within 4 sigma of the truth."""
    for name, cam in doc["cameras"].items():
        true = truth.cameras[name]
        same_lens = cam["model"] == true.model or set(LENS_MODELS[cam["model"]]) <= set(LENS_MODELS[true.model])
        for p in ("fx", "fy", "cx", "cy") + (LENS_MODELS[cam["model"]] if same_lens else ()):
            assert abs(cam[p] - getattr(true, p)) < 4 * cam["sigma"][p], (name, p, cam[p], getattr(true, p))
    for name, rel in doc["rig"].items():
        t_true = truth.rig[name].t_mm
        assert np.all(np.abs(np.array(rel["t_mm"]) - t_true) < 4 * np.array(rel["sigma"]["t_mm"])), name


def test_a_rendered_roll_calibrates_with_no_flag_but_the_board(rendered_roll, calibrated_roll):
    truth, folder, shot = rendered_roll
    code, out, err, doc = calibrated_roll
    assert code == 0, err
    assert "Camera roll" in out and shot["retake"][0] in out and "capture time" in out
    assert doc["cameras"]["ultra"]["model"] == "kb4" and doc["cameras"]["tele"]["model"] == "k1k2"   # --model auto
    assert doc["cameras"]["ultra"]["rms_px"] < 0.06                     # at the renders' corner noise
    _assert_near_the_truth(doc, truth)


def test_a_roll_without_exif_gives_the_same_cameras_and_instants_and_calibrates(rendered_roll, calibrated_roll,
                                                                                  tmp_path):
    """The roll as a phone's browser uploads it (JPEGs re-encoded without EXIF), a tele photo left out by name:
    the cameras told by the boards' focal lengths, the instants by order and the boards, as with EXIF."""
    from dualcal.files.io import save_rig
    from dualcal.workflow import calibrate_corners

    truth, folder, shot = rendered_roll
    with_exif = calibrated_roll[3]["corners"]["roll"]
    strip_exif(folder, tmp_path / "upload")
    tele = sorted(f for f, (cam, view) in shot["photos"].items() if cam == "tele")[1]
    corners = read_corners(tmp_path / "upload", Board(8, 5, 30.0), exclude=[tele], progress=False)
    record = corners.roll
    assert record["clues"] == {"cameras": ["image size", "focal length from the board"],
                               "instants": ["order", "board image", "board pose", "lens order"]}
    assert {k: i["photos"] for k, i in record["instants"].items()} == \
        {k: i["photos"] for k, i in with_exif["instants"].items()}
    assert tele in json.dumps(corners.cameras["tele"].meta["excluded"])       # --exclude works on the roll
    assert all(Path(p).name != tele for p in corners.cameras["tele"].meta["photos"].values())
    rig = calibrate_corners(corners, model={"ultra": "kb4", "wide": "k1k2p1p2k3", "tele": "k1k2"}, compare_lens=False)
    save_rig(tmp_path / "calib.json", rig)
    _assert_near_the_truth(json.loads((tmp_path / "calib.json").read_text()), truth)


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


def test_choosing_a_board_needs_the_cameras_only_not_the_instants(tmp_path, run_cli):
    """``board --for`` on a roll whose capture times show no break between positions (and no boards): the
    cameras come from the photos' headers; the instants, which need the boards, are not asked for."""
    from PIL import Image

    photos = _session(positions=4, lenses=(("main 6.9mm", 24.0), ("tele 9mm", 77.0)), lens_gap=(3.0, 4.0),
                      position_gap=(5.0, 6.0))
    for p in photos:
        exif = Image.Exif()
        exif[0x010F], exif[0x0110] = "Apple", "iPhone"
        sub = exif.get_ifd(0x8769)
        sub[0x9003] = p.exif["taken"].strftime("%Y:%m:%d %H:%M:%S")
        sub[0x920A], sub[0xA405], sub[0xA434] = p.exif["focal_length_mm"], int(p.exif["focal_length_35mm_mm"]), \
            p.exif["lens_model"]
        Image.new("L", p.size, 128).save(tmp_path / f"{p.path.stem}.JPG", exif=exif.tobytes())
    res = run_cli("board", "--for", tmp_path, "-o", tmp_path / "board.pdf")
    assert res.code == 0, res.err
    assert "for wide, tele" in res.err and (tmp_path / "board.pdf").stat().st_size > 1000


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
    assert ds.identical["tele"] == {roll / "IMG_0999.JPG": roll / first}
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
