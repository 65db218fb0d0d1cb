"""What the project page shows of a calibration, as one JSON document (``.dualcal-app/summary.json``).

Made in the worker from the files the job wrote (the calibration, its corners, the advice), so that
the server only reads it: the verdict and every check in words with the photos or instants it
blames, every camera's parameters with sigma, the rig's baseline and angles with sigma, every
photo's camera, instant, RMS and status (the per-photo chart), the camera roll's split and the
clues it used, the instants a length can be measured in, and the advice (the board's outline in
each camera's frame, the sigmas now and predicted).
"""

from __future__ import annotations


from pathlib import PurePosixPath

from ..geometry.camera import intrinsic_names
from .store import photo_of

__all__ = ["advice_summary", "calibration_summary", "chart_labels", "split_warnings"]

#: Why a photo was left out, in a few words (for one photo, for more), from the words of its warning (the first
#: that matches): the page counts the photos of each kind ("8 photos left out: 5 show part of the board, 3 show
#: no board").
LEFT_OUT_KINDS = ((("shows part of the board", "show part of the board"),
                   ("part of the", "frame's edge", "corners passed their checks")),
                  (("shows no board", "show no board"), ("no board", "chessboard found", "board found", "not found")),
                  (("retake", "retakes"), ("retake",)), (("copy", "copies"), ("the same file",)),
                  (("of an unclear camera", "of an unclear camera"), ("camera is unclear", "fit none of the lenses")))
_OTHER_KIND = ("for another reason", "for other reasons")


def _photo_map(corners) -> dict[tuple[str, str], str]:
    """``(camera, view) -> photo`` for every photo of the corners, left out ones too."""
    out = {}
    for cam, cc in corners.cameras.items():
        for view, path in {**cc.meta.get("photos", {}), **cc.meta.get("excluded", {})}.items():
            if path:
                out[(cam, view)] = photo_of(path)
    return out


def _blamed(check: dict, photos: dict[tuple[str, str], str]) -> list[str]:
    """The photos a check names (in ``flagged``, ``views`` or ``instants`` lists): an instant stands for
    every photo of it."""
    names = []
    for key in ("flagged", "views"):
        for item in check.get(key) or ():
            if isinstance(item, dict):
                cam, view = item.get("camera"), item.get("view") or item.get("instant")
            else:
                cam, view = None, str(item)
            names += [p for (c, v), p in photos.items() if v == view and cam in (None, c)]
    return sorted(set(names))


def _roll_clues(roll: dict | None) -> dict | None:
    """Which clues split the camera roll into cameras and instants (corners.json's ``roll``, as
    :func:`dualcal.files.roll.split_roll` records them), in words, and how sure the split is."""
    if not roll:
        return None
    cams = roll.get("cameras", {})
    clues = roll.get("clues") or {}
    return {"cameras": ", ".join(clues.get("cameras") or ()) or "-",
            "instants": ", ".join(clues.get("instants") or ()) or "-",
            "sure": roll.get("split_sure"), "cameras_sure": roll.get("cameras_sure"),
            "cameras_separation_sigma": roll.get("cameras_separation_sigma"),
            "found": [{"camera": n, "lens": c.get("lens_model") or "", "focal_35mm": c.get("focal_length_35mm_mm"),
                       "focal_board_px": c.get("focal_length_board_px"),
                       "focal_board_sigma_px": c.get("focal_length_board_sigma_px"),
                       "nearest": c.get("nearest_lens"), "separation_sigma": c.get("separation_sigma"),
                       "told_by": c.get("told_by"), "image_size": c.get("image_size"), "photos": c.get("photos")}
                      for n, c in cams.items()],
            "left_out": roll.get("left_out", {})}


def calibration_summary(rig, calib: dict, version: int) -> dict:
    """The page's view of a calibration: ``rig`` (:class:`~dualcal.geometry.model.RigModel`) and its calib.json
    document ``calib``, made for the project's ``version``."""
    from ..estimation.checks import failed_checks, verdict
    from ..pages.photos import photo_status

    photos = _photo_map(rig.corners)
    status = photo_status(rig)
    per_photo = {}
    for view, per in status.items():
        for cam, (rms, what) in per.items():
            name = photos.get((cam, view))
            if name:
                per_photo[name] = {"camera": cam, "view": view, "rms_px": rms, "status": what}
    checks = [{"name": n, "ok": bool(c.get("ok", True)), "message": str(c.get("message", "")),
               "blames": _blamed(c, photos)} for n, c in rig.checks.items()]
    cameras = []
    for name in rig.camera_order():
        cam = calib["cameras"][name]
        names = [p for p in intrinsic_names(cam.get("model", "k1k2")) if p in cam and (p != "skew" or calib["skew"])]
        cameras.append({"name": name, "model": cam.get("model", calib.get("model")), "image_size": cam["image_size"],
                        "rms_px": cam.get("rms_px"),
                        "parameters": [{"name": p, "value": cam[p], "sigma": cam["sigma"].get(p)} for p in names]})
    relations = [{"camera": name, "baseline_mm": r["baseline_mm"], "baseline_sigma_mm": r["sigma"]["baseline_mm"],
                  "opk_arcmin": r["opk_arcmin"], "opk_sigma_arcmin": r["sigma"]["opk_arcmin"], "t_mm": r["t_mm"]}
                 for name, r in calib.get("rig", {}).items()]
    instants = {}
    for (cam, view), name in photos.items():
        if view in rig.camera_poses.get(cam, {}):
            instants.setdefault(view, {})[cam] = name
    failed = failed_checks(rig.checks)
    return {"version": version, "verdict": verdict(rig.checks).removeprefix("verdict: "), "ok": not failed,
            "checks": checks, "cameras": cameras, "rig": relations, "reference": rig.reference,
            "rms_px": rig.rms_px, "photos": per_photo, "roll": _roll_clues(rig.corners.roll),
            "instants": {v: c for v, c in sorted(instants.items()) if len(c) >= 2},
            "image_sizes": {n: list(c.image_size) for n, c in rig.corners.cameras.items()}}


def advice_summary(advice_doc: dict, previous: dict | None, current_sigma: dict) -> dict:
    """The advice as the page shows it: advise.json's poses (description, cameras, gain, outline in each
    camera's frame, predicted sigmas) and, where an earlier advice predicted the sigmas after one more
    photo (``previous``: ``{"version", "predicted_sigma"}``), that prediction against the sigmas now."""
    from ..estimation.advise import key_targets

    shown = [n for group in key_targets(current_sigma).values() for n in group]
    poses = [{"description": p.get("description", ""), "cameras": p["cameras"], "gain": p.get("gain"),
              "outline_px": p.get("outline_px", {}), "predicted_sigma": {n: p["predicted_sigma"].get(n) for n in shown}}
             for p in advice_doc["poses"]]
    out = {"done": advice_doc["done"], "next_gain": advice_doc.get("next_gain"), "poses": poses,
           "current_sigma": {n: current_sigma[n] for n in shown}, "goals": advice_doc.get("goals", {})}
    if previous and previous.get("predicted_sigma"):
        out["predicted_vs_actual"] = [{"name": n, "predicted": previous["predicted_sigma"].get(n), "actual": current_sigma[n]}
                                      for n in shown if n in previous["predicted_sigma"]]
        out["predicted_from_version"] = previous.get("version")
    return out


def split_warnings(warnings: list[str], photos: list[str]) -> tuple[list[str], dict | None]:
    """A job's warnings as the page shows them: those that leave one of the project's ``photos`` out (skipped by
    the detection, left out by the camera roll's split: ``NAME: skipped: WHY``, ``NAME: left out (WHY)``), one per
    photo, counted by kind (:data:`LEFT_OUT_KINDS`), apart from the rest.

    Returns ``(rest, left_out)``; ``left_out`` is ``{"count", "kinds": [{"kind", "count"}], "photos": [{"photo",
    "why", "kind"}]}``, or None where no photo was left out.
    """
    by_name = {PurePosixPath(p).name: p for p in photos}
    why_of: dict[str, str] = {}
    rest = []
    for w in warnings:
        head, _, why = w.partition(": ")
        photo = by_name.get(PurePosixPath(head).name)
        if photo is not None and why.startswith(("skipped: ", "left out (")):
            why_of.setdefault(photo, why.removeprefix("skipped: ").removeprefix("left out (").removesuffix(")"))
        else:
            rest.append(w)
    if not why_of:
        return rest, None
    kinds = [_left_out_kind(why) for why in why_of.values()]
    items = [{"photo": p, "why": why, "kind": kind[1]} for (p, why), kind in sorted(zip(why_of.items(), kinds))]
    order = [kind for kind, _ in LEFT_OUT_KINDS] + [_OTHER_KIND]
    counted = [{"kind": kind[kinds.count(kind) > 1], "count": kinds.count(kind)} for kind in order if kind in kinds]
    return rest, {"count": len(items), "kinds": counted, "photos": items}


def _left_out_kind(why: str) -> tuple[str, str]:
    lower = why.lower()
    return next((kind for kind, words in LEFT_OUT_KINDS if any(w in lower for w in words)), _OTHER_KIND)


def chart_labels(names: list[str], width: int = 14) -> list[str]:
    """Labels for the per-photo chart that tell the photos apart in ``width`` characters: what all the names share
    at their start (up to a separator) and end is left out ("IMG_20210417_010329.jpg" among photos of that day:
    "…010329"), and a label still too long loses its middle ("wide/IMG_…0107.JPG")."""
    def shared(texts):
        prefix = texts[0]
        for t in texts[1:]:
            while not t.startswith(prefix):
                prefix = prefix[:-1]
        return prefix

    if len(names) < 2:
        return [_middle_cut(n, width) for n in names]
    head = shared(names)
    cut = max((head.rfind(c) + 1 for c in "_-/. "), default=0)          # at a separator, so whole parts remain
    head = head[:cut] if cut < len(head) else head
    tail = shared([n[::-1] for n in names])[::-1]
    tail = tail[tail.find("."):] if "." in tail else ""                   # the suffix only (".jpg"), not digits
    labels = []
    for n in names:
        core = n[len(head):len(n) - len(tail)] if len(n) > len(head) + len(tail) else n
        labels.append(_middle_cut(("…" if head else "") + core, width))
    return labels


def _middle_cut(text: str, width: int) -> str:
    if len(text) <= width:
        return text
    keep = width - 1
    return text[:keep // 2] + "…" + text[len(text) - (keep - keep // 2):]
