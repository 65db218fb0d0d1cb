"""The joint covariance of a calibration: one object for its names, its blocks and every derived sigma.

calib.json keeps the covariance of what a calibration reports (:func:`dualcal.estimation.rig_relations.parameter_covariance`)
as ``{"parameters": [names], "clustered": (k, k), "formal": (k, k)}``, the two kinds of
:mod:`dualcal.estimation.uncertainty`. The names are

* ``"<camera>.<intrinsic>"`` for every free intrinsic (``wide.fx``, ``tele.k1``, ...; :func:`intrinsic_name`),
* ``"<camera>.rig.rotation_rad.<x|y|z>"`` (the relative rotation's left increment, ``R <- exp([d]x) R``)
  and ``"<camera>.rig.t_mm.<x|y|z>"`` for every camera with a rig relation (:func:`rig_name`),
* ``"board.shape_mm.<term>"`` where the board's shape was estimated,
* ``"<camera>.breathing"`` for every camera whose focus is modelled (:func:`breathing_name`;
  :mod:`dualcal.geometry.focus`).

The sigma dualcal reports for any value is the larger of the two kinds' (the rule of
:mod:`dualcal.estimation.uncertainty`), so :meth:`JointCovariance.derived_sigma`
takes it; :meth:`JointCovariance.block` gives one kind's block for a caller that propagates it further
(a measurement's points, an advised photo's information).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["KINDS", "JointCovariance", "breathing_name", "intrinsic_name", "rig_name"]

#: The covariance kinds calib.json keeps (:data:`dualcal.estimation.adjust.COVARIANCE_KINDS`).
KINDS = ("clustered", "formal")


def intrinsic_name(camera: str, name: str) -> str:
    """The covariance's name of a camera's intrinsic, ``"<camera>.<name>"``."""
    return f"{camera}.{name}"


def breathing_name(camera: str) -> str:
    """The covariance's name of a camera's breathing coefficient, ``"<camera>.breathing"``."""
    return f"{camera}.breathing"


def rig_name(camera: str, what: str, axis: str) -> str:
    """The covariance's name of a rig relation's component: ``what`` is ``rotation_rad`` or ``t_mm``."""
    return f"{camera}.rig.{what}.{axis}"


@dataclass(frozen=True)
class JointCovariance:
    """``parameters`` (names, module docstring) and ``{kind: (k, k)}`` covariance matrices."""

    parameters: tuple[str, ...]
    matrices: dict

    @classmethod
    def from_dict(cls, doc: dict | None, source: str = "calib.json") -> "JointCovariance":
        """calib.json's ``covariance`` entry, checked (finite square matrices of the names' size).

        Raises
        ------
        InputError
            No covariance (a calib.json of an older dualcal), or one that is malformed.
        """
        if not doc or "parameters" not in doc:
            raise InputError(f"{source} holds no joint covariance of its parameters (written by an older dualcal?): "
                             "calibrate again")
        names = tuple(str(n) for n in doc["parameters"])
        mats = {}
        for kind in KINDS:
            m = np.asarray(doc.get(kind), float)
            if m.shape != (len(names), len(names)) or not np.all(np.isfinite(m)):
                raise InputError(f"{source}: covariance {kind!r} is not a finite {len(names)} x {len(names)} matrix")
            mats[kind] = m
        return cls(names, mats)

    def to_dict(self) -> dict:
        return {"parameters": list(self.parameters), **{k: np.asarray(m).tolist() for k, m in self.matrices.items()}}

    def has(self, names) -> bool:
        """Whether every one of ``names`` is a parameter of the covariance."""
        known = set(self.parameters)
        return all(n in known for n in names)

    def index(self, names) -> np.ndarray:
        """Positions of ``names`` among the parameters (KeyError for one that is not there)."""
        where = {n: i for i, n in enumerate(self.parameters)}
        return np.array([where[n] for n in names], int)

    def block(self, names, kind: str) -> np.ndarray:
        """One kind's covariance of ``names``."""
        idx = self.index(names)
        return np.asarray(self.matrices[kind])[np.ix_(idx, idx)]

    def derived_sigma(self, names, gradient) -> float:
        """The sigma of a value ``f`` of the parameters ``names`` with ``df/dnames = gradient``: the larger
        of the kinds' ``sqrt(g^T C g)``."""
        g = np.asarray(gradient, float)
        return float(np.sqrt(max(max(g @ self.block(names, k) @ g, 0.0) for k in KINDS)))
