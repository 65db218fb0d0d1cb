"""Focus as part of the lens: how a camera's principal distance changes with the distance it is focused at.

A phone lens focuses by moving away from the sensor. A thin lens of focal length ``f`` (mm, EXIF ``FocalLength``)
focused on an object at ``d`` (mm, object to lens) forms its image at ``f d / (d - f)`` (Gauss's lens equation
``1/f = 1/d + 1/d'``), so its principal distance, and every focal length in pixels with it, is
``fx(d) = fx_inf (1 + f / (d - f))``. A phone's lens is not thin (several elements, some moving apart, the image
plane itself tilted by the actuator), so the growth is scaled by a *breathing coefficient* ``b`` (1: the thin
lens; 0: a lens whose focal length does not change with focus)::

    fx(d) = fx_inf (1 + b f / (d - f)),    fy(d) = fy_inf (1 + b f / (d - f))

(S. F. Ray, *Applied Photographic Optics*; "focus breathing" in cinematography). The skew, like
``fx``, is a length on the sensor and scales alike; the principal point and the lens's distortion in normalised
coordinates stay as they are. A calibration gives its camera at a reference focus ``d0`` (its photos' median),
so the camera focused at ``d`` has every focal length times::

    g(d) = (1 + b f / (d - f)) / (1 + b f / (d0 - f))

:class:`FocusModel` holds ``f``, ``d0``, ``b`` (and the focus range its calibration photos spanned), and
:func:`camera_at_focus` gives the camera at another focus. The estimate of ``b`` is the adjustment's
(:mod:`dualcal.estimation.adjust`, ``breathing``); its sigma and the extrapolation beyond the photos' range are the
measurement's (:mod:`dualcal.estimation.focus_model`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .camera import CameraModel

__all__ = ["FOCUS_MODEL", "FocusModel", "PhotoFocus", "camera_at_focus", "focal_scale", "focal_scale_per_breathing"]

#: The name of the focus model (calib.json's ``cameras.<c>.focus_model.model``).
FOCUS_MODEL = "thin lens with breathing"


def _growth(focus_mm, focal_mm: float, breathing: float):
    """``1 + b f / (d - f)`` (module docstring)."""
    return 1.0 + breathing * focal_mm / (np.asarray(focus_mm, float) - focal_mm)


def focal_scale(focus_mm, focal_mm: float, breathing: float, reference_mm: float):
    """``g(d)``: the focal lengths at focus ``focus_mm`` over those at ``reference_mm`` (module docstring).

    Parameters
    ----------
    focus_mm : float or (n,) array
        Focus distances, mm (object to lens; beyond ``focal_mm``).
    focal_mm : float
        The lens's focal length, mm.
    breathing : float
        The breathing coefficient ``b`` (1: a thin lens).
    reference_mm : float
        The focus at which the focal lengths are given, mm.

    Returns
    -------
    float or (n,) array
    """
    return _growth(focus_mm, focal_mm, breathing) / _growth(reference_mm, focal_mm, breathing)


def focal_scale_per_breathing(focus_mm, focal_mm: float, breathing: float, reference_mm: float):
    """``dg/db`` at ``focus_mm`` (:func:`focal_scale`'s arguments): ``(f/(d - f) - f/(d0 - f)) / (1 + b f/(d0 - f))^2``."""
    at = focal_mm / (np.asarray(focus_mm, float) - focal_mm)
    ref = focal_mm / (reference_mm - focal_mm)
    return (at - ref) / (1.0 + breathing * ref) ** 2


@dataclass(frozen=True)
class FocusModel:
    """How one camera's intrinsics change with its focus (module docstring).

    ``focal_length_mm`` the lens's focal length (EXIF), ``focus_m`` the reference focus ``d0`` at which the
    calibration gives the camera (m), ``breathing`` the coefficient ``b``, ``focus_range_m`` the nearest and
    farthest focus of the calibration's photos (m): a focus outside it is an extrapolation; ``breathing_sigma``
    and ``breathing_sigma_formal`` the coefficient's 1-sigmas as calib.json reports them (``sigma``, ``sigma_formal``).
    """

    focal_length_mm: float
    focus_m: float
    breathing: float
    focus_range_m: tuple[float, float]
    breathing_sigma: float = 0.0
    breathing_sigma_formal: float = 0.0

    def to_dict(self) -> dict:
        """calib.json's ``cameras.<c>.focus_model``."""
        return {"model": FOCUS_MODEL, "focal_length_mm": self.focal_length_mm, "breathing": self.breathing,
                "sigma": {"breathing": self.breathing_sigma},
                "sigma_formal": {"breathing": self.breathing_sigma_formal},
                "focus_range_m": [float(x) for x in self.focus_range_m]}

    @classmethod
    def from_dict(cls, doc: dict, focus_m: float) -> "FocusModel":
        """The model :meth:`to_dict` wrote, its camera given at ``focus_m`` (calib.json's ``cameras.<c>.focus_m``)."""
        lo, hi = doc["focus_range_m"]
        return cls(float(doc["focal_length_mm"]), float(focus_m), float(doc["breathing"]), (float(lo), float(hi)),
                   float(doc.get("sigma", {}).get("breathing", 0.0)),
                   float(doc.get("sigma_formal", {}).get("breathing", 0.0)))

    def scale(self, focus_m):
        """``g``: the focal lengths at ``focus_m`` (m) over those at :attr:`focus_m`."""
        return focal_scale(np.asarray(focus_m, float) * 1000.0, self.focal_length_mm, self.breathing,
                           self.focus_m * 1000.0)

    def scale_per_breathing(self, focus_m):
        """``dg/db`` at ``focus_m`` (m)."""
        return focal_scale_per_breathing(np.asarray(focus_m, float) * 1000.0, self.focal_length_mm, self.breathing,
                                         self.focus_m * 1000.0)

    def outside(self, focus_m: float) -> bool:
        """Whether ``focus_m`` lies outside the calibration photos' focus range."""
        lo, hi = self.focus_range_m
        return not lo <= focus_m <= hi


@dataclass(frozen=True)
class PhotoFocus:
    """Where each calibration photo focused, for the breathing term of the adjustment.

    ``focal_mm`` ``{camera: f}`` the lenses' focal lengths (mm, EXIF), ``reference_mm`` ``{camera: d0}`` the focus
    each camera's intrinsics are given at (mm), ``focus_mm`` ``{(camera, view): d}`` each photo's focus (mm) and
    ``source`` ``{(camera, view): "metadata" | "board"}`` where it came from (the photo's metadata, or the board's
    distance along the camera's axis in it: autofocus focuses there).
    """

    focal_mm: dict
    reference_mm: dict
    focus_mm: dict
    source: dict

    def model(self, camera: str, breathing: float, views=None, sigma: float = 0.0,
              sigma_formal: float = 0.0) -> FocusModel:
        """Camera ``camera``'s :class:`FocusModel` with coefficient ``breathing`` (and its sigmas), its focus range
        that of its photos of ``views`` (default: all)."""
        seen = [d for (c, v), d in self.focus_mm.items() if c == camera and (views is None or v in views)]
        return FocusModel(float(self.focal_mm[camera]), self.reference_mm[camera] / 1000.0, float(breathing),
                          (min(seen) / 1000.0, max(seen) / 1000.0), float(sigma), float(sigma_formal))


def camera_at_focus(camera: CameraModel, model: FocusModel, focus_m: float) -> CameraModel:
    """``camera`` (at ``model.focus_m``) focused at ``focus_m`` metres: ``fx``, ``fy`` and ``skew`` times
    :meth:`FocusModel.scale`."""
    g = float(model.scale(focus_m))
    return replace(camera, fx=camera.fx * g, fy=camera.fy * g, skew=camera.skew * g)
