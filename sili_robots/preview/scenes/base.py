"""What every task scene provides, and the animation helpers they share.

A scene turns a ``Recording`` into meshcat objects animated with meshcat's timeline (one
animation frame per recorded step), names the colours it uses (legend), writes a caption per
frame, says where the camera goes, and lists ``Marker``s: world points with the colour a person
should see there in a given frame. The visual checks look for exactly those.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, TypeVar

import meshcat
import meshcat.transformations as tf
import numpy as np
from meshcat.animation import Animation

from sili_robots.preview.recording import Recording

#: a frame index, or an array of them
IntOrArray = TypeVar("IntOrArray", int, np.ndarray)

#: scale used to hide an animated object (three.js dislikes an exact zero scale)
HIDDEN = 1e-4


@dataclass(frozen=True)
class Marker:
    """Something a person should see: ``color`` around world point ``position``."""

    name: str
    position: tuple[float, float, float]
    color: int  # 0xRRGGBB as drawn (flat colour) or the base colour of a shaded body
    radius: float  # world size around the point to look in
    min_fraction: float = 0.25  # share of pixels within ``radius`` that must match
    tolerance: float = 40.0  # max RGB distance counted as a match
    #: for shaded bodies: instead of a colour, the pixels must change when the scene node at
    #: this path (under the scene root) is hidden, i.e. the body is what is seen there
    toggle: str | None = None
    #: scene nodes that may stand between the camera and this marker (one car in front of the
    #: other, the arm over a goal): where the marker is not seen, it is looked for again with
    #: them hidden, so a body drawn where it belongs but behind another still counts as drawn
    behind: tuple[str, ...] = ()
    #: the camera need not see it in every frame (a car far ahead, a hazard passed): out of the
    #: picture it is not looked for; any other marker out of the picture is a framing error
    may_leave_view: bool = False

    def views(self) -> list[tuple[str, ...]]:
        """The sets of nodes hidden in the extra screenshots this marker is checked with."""
        out = [] if self.toggle is None else [hidden_set(self.toggle)]
        if self.behind:
            out.append(hidden_set(*self.behind))
            if self.toggle is not None:
                out.append(hidden_set(*self.behind, self.toggle))
        return out


def hidden_set(*paths: str) -> tuple[str, ...]:
    """One key per set of hidden nodes, whatever order they were named in."""
    return tuple(sorted(set(paths)))


@dataclass(frozen=True)
class Camera:
    """A perspective camera at ``position`` looking at ``target`` (world, z up)."""

    position: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fov: float = 40.0
    near: float = 0.05
    far: float = 100.0


class TaskScene(ABC):
    """One task's preview. Subclasses fill in the task-specific parts."""

    #: ``type(env.unwrapped).__name__`` values this scene draws
    env_classes: tuple[str, ...] = ()
    fps: float = 20.0
    background: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.93, 0.95, 0.97),
        (0.80, 0.84, 0.89),
    )

    @abstractmethod
    def snapshot(self, task: Any) -> dict[str, Any]:
        """The state drawn in one frame, read from the unwrapped task."""

    def static(self, task: Any) -> dict[str, Any]:
        """Layout that does not change during the rollout (read once)."""
        return {}

    @abstractmethod
    def draw(self, vis: meshcat.Visualizer, rec: Recording, anim: Animation) -> None:
        """Create the objects under ``vis`` and add their tracks to ``anim``."""

    @abstractmethod
    def legend(self, rec: Recording) -> list[tuple[int, str]]:
        """(colour, what it is) pairs shown over the picture."""

    @abstractmethod
    def caption(self, rec: Recording, frame: int) -> str:
        """One line saying what is going on in ``frame``."""

    @abstractmethod
    def camera(self, rec: Recording) -> Camera:
        """A default camera that frames the scene."""

    @abstractmethod
    def markers(self, rec: Recording, frame: int) -> list[Marker]:
        """What must be visible, and where, when ``frame`` is shown."""

    def picture_frame(self, rec: Recording) -> int:
        """The frame a still picture shows by default (the end of the rollout)."""
        return rec.last

    def view_shift(self, rec: Recording, frame: int) -> np.ndarray:
        """How far the scene content is moved in ``frame`` so the camera follows the action
        (a scene that animates its root by ``-(target + shift)`` overrides this)."""
        return np.zeros(3)

    def title(self, rec: Recording) -> str:
        n, s = rec.interactions, "s" if rec.interactions > 1 else ""
        return f"{rec.task} · {rec.policy} · {n} interaction{s}, H = {rec.horizon}"


# ---------------------------------------------------------------------- animation helpers
def translation(p: np.ndarray | tuple[float, ...]) -> np.ndarray:
    return tf.translation_matrix(np.asarray(p, float)[:3])


def animate_position(
    anim: Animation, vis: meshcat.Visualizer, positions: np.ndarray, steps: bool = False
) -> None:
    """Key the node's position at every frame, or only around changes when ``steps``."""
    positions = np.asarray(positions, float)
    frames = change_frames(positions) if steps else range(len(positions))
    for f in frames:
        anim.at_frame(vis, f).set_property("position", "vector3", positions[f].tolist())
    vis.set_transform(translation(positions[-1]))


def animate_visible(anim: Animation, vis: meshcat.Visualizer, visible: np.ndarray) -> None:
    """Show/hide the node over time (by scale, keyed only where it switches)."""
    scales = np.where(np.asarray(visible, bool)[:, None], 1.0, HIDDEN) * np.ones((1, 3))
    for f in change_frames(scales):
        anim.at_frame(vis, f).set_property("scale", "vector3", scales[f].tolist())


def animate_pose(
    anim: Animation, vis: meshcat.Visualizer, matrices: np.ndarray, steps: bool = False
) -> None:
    """Key full 4x4 poses (position and orientation)."""
    matrices = np.asarray(matrices, float)
    flat_m = matrices.reshape(len(matrices), -1)
    frames = change_frames(flat_m) if steps else range(len(matrices))
    for f in frames:
        anim.at_frame(vis, f).set_transform(matrices[f])
    vis.set_transform(matrices[-1])


def change_frames(values: np.ndarray) -> list[int]:
    """Frames where a value differs from its neighbour, plus the ends: enough keys for
    step changes under linear interpolation (the old value is held up to the frame before)."""
    values = np.asarray(values, float)
    n = len(values)
    if n == 0:
        return []
    flat = values.reshape(n, -1)  # np.allclose(values[f], values[f - 1]) for all f at once
    changed = np.flatnonzero(~np.isclose(flat[1:], flat[:-1]).all(axis=1)) + 1
    return sorted({0, n - 1, *changed.tolist(), *(changed - 1).tolist()})


def frame_of(rec: Recording, interaction: IntOrArray, t: int) -> IntOrArray:
    """Frame index of step ``t`` of ``interaction`` (H + 1 frames per interaction; an array of
    interactions gives an array of frames)."""
    return interaction * (rec.horizon + 1) + t
