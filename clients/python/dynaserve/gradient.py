"""Gradients of a driven rollout's cost (a session's ``gradient`` call, on every client): the
cost document a call is scored by, and the :class:`Gradients` it answers with.

A call rolls each candidate path of the session's kinematic objects out from the session's
state (as ``predict`` would) and scores the rollout::

    cost = sum over targets of  position_weight * |p - position| + rotation_weight * (1 - cos angle)
         + smoothness * sum over kinematic objects and steps of |p(t+1) - 2 p(t) + p(t-1)|^2

with ``p`` an object's centre of mass (metres) after the target's step; the smoothness term runs
over the kinematic translations, the session's previous and current poses opening the path. The
gradients are with respect to every kinematic pose of the path: translation per metre, rotation
per radian of a small rotation about each world axis applied to the pose on the left.

>>> cost = gradient_cost([(0, 0, [0.3, 0.0, 0.1], 1.0)], smoothness=0.1)   # box 0 to x = 0.3 m
>>> g = session.gradient(16, kinematic=[{1: path_a}, {1: path_b}], cost=cost)
>>> g.cost.shape, g.translation.shape          # (2,), (2, 16, 1, 3)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, List, Mapping, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from .scene import actions_doc, array_arg, number

Target = Union[Tuple[Any, ...], Mapping[str, Any]]
"""One cost target: ``(object, step, position [3], position_weight)``, optionally followed by
``rotation [4]`` (``[x, y, z, w]``) and ``rotation_weight``, or a ``CostTarget`` JSON document
(``{"object": 0, "step": 0, "position": [...], "position_weight": 1.0, ...}``)."""


@dataclass
class Gradients:
    """The answer of a gradient call, one row per candidate in request order.

    Attributes:
        cost: ``[candidates]`` float64, each candidate's cost.
        translation: ``[candidates, steps, kinematic, 3]`` float32, d cost / d translation of
            every kinematic object's pose after every step, per metre (kinematic objects in
            index order).
        rotation: ``[candidates, steps, kinematic, 3]`` float32, d cost / d rotation of those
            poses, per radian of a small rotation about each world axis (applied on the left).
        poses: ``[candidates, frames, objects, 7]``, the rollout the cost was measured on at
            the returned steps (the last one only unless ``every`` was given).
        steps: ``[frames]``, the step index of each returned frame, counted from the session's
            start.
        model: the model that served the call.
    """

    cost: np.ndarray
    translation: np.ndarray
    rotation: np.ndarray
    poses: np.ndarray
    steps: np.ndarray
    model: str


_TARGET_KEYS = ("object", "step", "position", "position_weight", "rotation", "rotation_weight")


def _target_doc(t: Target, name: str) -> Dict[str, Any]:
    """A checked ``CostTarget`` document (numbers finite, shapes right; a ``ValueError`` names
    the field otherwise)."""
    if isinstance(t, Mapping):
        unknown = sorted(set(t) - set(_TARGET_KEYS))
        if unknown:
            raise ValueError(f"{name}: unknown keys {unknown}; expected some of {list(_TARGET_KEYS)}")
        if "object" not in t:
            raise ValueError(f"{name}.object: required")
        values = [t.get(k) for k in _TARGET_KEYS]
    elif len(t) in (4, 6):
        values = list(t) + [None, None][: 6 - len(t)]
    else:
        raise ValueError(
            f"{name}: expected (object, step, position, weight[, rotation, rotation_weight]), got {len(t)} items"
        )
    obj, step, position, weight, rotation, rotation_weight = values
    d: Dict[str, Any] = {
        "object": int(obj),
        "step": int(step or 0),
        "position": array_arg(position if position is not None else [0.0] * 3, f"{name}.position", (3,)).tolist(),
        "position_weight": number(weight or 0.0, f"{name}.position_weight"),
    }
    if rotation is not None:
        d["rotation"] = array_arg(rotation, f"{name}.rotation", (4,)).tolist()
        d["rotation_weight"] = number(rotation_weight or 0.0, f"{name}.rotation_weight")
    return d


def gradient_cost(targets: Sequence[Target] = (), smoothness: float = 0.0) -> Dict[str, Any]:
    """The ``GradientCost`` document of a gradient call.

    Args:
        targets: the distance terms, each ``(object, step, position, weight)`` (object index,
            step ``1..steps`` with 0 the last one, target centre of mass ``[3]`` in metres,
            weight per metre), optionally with ``rotation`` ``[4]`` and ``rotation_weight``
            appended, or a ``CostTarget`` document. Default ``()``: none.
        smoothness: weight of the kinematic path's squared second differences, per square
            metre. Default 0.
    """
    return {
        "targets": [_target_doc(t, f"cost.targets[{i}]") for i, t in enumerate(targets)],
        "smoothness": number(smoothness, "cost.smoothness"),
    }


def cost_arg(cost: Union[Mapping[str, Any], Sequence[Target], None]) -> Dict[str, Any]:
    """A call's ``cost`` argument as a ``GradientCost`` document: a document (e.g. from
    :func:`gradient_cost`), a sequence of targets (no smoothness term), or ``None`` (zero)."""
    if cost is None:
        return gradient_cost()
    if isinstance(cost, Mapping):
        return gradient_cost(cost.get("targets", ()), cost.get("smoothness", 0.0))
    return gradient_cost(cost)


def candidates_doc(kinematic: Sequence[Mapping[int, npt.ArrayLike]]) -> List[Dict[str, Any]]:
    """``GradientCandidate`` documents from candidate paths ``[{object index: [steps, 7]}]``
    (every kinematic object's pose after every step); errors name ``kinematic[i][j]``."""
    if not kinematic:
        raise ValueError("kinematic: at least one candidate path is needed")
    return [{"actions": actions_doc(k, f"kinematic[{i}]")} for i, k in enumerate(kinematic)]


def gradients_of(
    model: str, candidates: Sequence[Tuple[float, Sequence[Sequence[Any]], Sequence[Tuple[int, np.ndarray]]]]
) -> Gradients:
    """A :class:`Gradients` from each candidate's ``(cost, steps, frames)``: ``steps[s][k]`` a
    ``(translation [3], rotation [3])`` pair, ``frames`` ``(step, poses [objects, 7])`` pairs."""

    def grads(c: Any, which: int) -> np.ndarray:
        return np.array([[g[which] for g in step] for step in c[1]], dtype=np.float32).reshape(len(c[1]), -1, 3)

    frames = [c[2] for c in candidates]
    return Gradients(
        cost=np.array([c[0] for c in candidates], dtype=np.float64),
        translation=np.stack([grads(c, 0) for c in candidates]),
        rotation=np.stack([grads(c, 1) for c in candidates]),
        poses=np.stack([np.stack([p for _, p in f]) for f in frames]),
        steps=np.array([s for s, _ in frames[0]], dtype=np.int64),
        model=model,
    )


def gradients_from_doc(doc: Mapping[str, Any], poses_array: Any) -> Gradients:
    """A ``GradientResponse`` document of the HTTP API as :class:`Gradients` (``poses_array``
    reads a frame's poses)."""
    return gradients_of(
        doc["model"],
        [
            (
                float(c["cost"]),
                [[(g["translation"], g["rotation"]) for g in s["kinematic"]] for s in c["steps"]],
                [(int(f["step"]), poses_array(f["poses"])) for f in c["frames"]],
            )
            for c in doc["candidates"]
        ],
    )
