"""Put a recorded rollout into a meshcat visualizer (a live server or an in-memory scene).

The same calls feed ``--serve`` and ``--out``: background, camera, hiding meshcat's default
grid and axes, then the task scene's objects and its animation. The scene's camera target is
moved to the world origin (the content is shifted by -target) because meshcat's orbit
controls always look at the origin; ``world_point`` applies the same shift for checks.
"""

from __future__ import annotations

import meshcat
import meshcat.geometry as g
import numpy as np
from meshcat.animation import Animation

from sili_robots.preview.html import Overlay
from sili_robots.preview.recording import Recording
from sili_robots.preview.scenes.base import TaskScene, translation
from sili_robots.preview.shapes import css


def populate(vis: meshcat.Visualizer, scene: TaskScene, rec: Recording) -> Animation:
    """Draw ``rec`` with ``scene`` into ``vis`` and start its animation; return the animation."""
    top, bottom = scene.background
    vis["/Background"].set_property("top_color", list(top))
    vis["/Background"].set_property("bottom_color", list(bottom))
    vis["/Grid"].set_property("visible", False)
    vis["/Axes"].set_property("visible", False)
    cam = scene.camera(rec)
    vis["/Cameras/default/rotated"].set_object(
        g.PerspectiveCamera(fov=cam.fov, near=cam.near, far=cam.far)
    )
    rel = np.subtract(cam.position, cam.target)
    # the camera sits in meshcat's "rotated" frame (y up): world (x, y, z) -> (x, z, -y)
    vis["/Cameras/default/rotated/<object>"].set_property(
        "position", [float(rel[0]), float(rel[2]), float(-rel[1])]
    )
    vis.set_transform(translation(-np.asarray(cam.target, float)))
    anim = Animation(default_framerate=scene.fps)
    scene.draw(vis, rec, anim)
    vis.set_animation(anim, play=True, repetitions=1)
    return anim


def world_point(
    scene: TaskScene, rec: Recording, p: tuple[float, ...], frame: int
) -> tuple[float, ...]:
    """Where a task-frame point ends up in the viewer's world in ``frame`` (after the camera
    target shift and any follow-the-action shift)."""
    shift = np.asarray(scene.camera(rec).target, float) + scene.view_shift(rec, frame)
    return tuple(float(a - b) for a, b in zip(p, shift, strict=True))


def overlay(scene: TaskScene, rec: Recording) -> Overlay:
    return Overlay(
        title=scene.title(rec),
        legend=[(css(c), label) for c, label in scene.legend(rec)],
        captions=[scene.caption(rec, f) for f in range(len(rec))],
        fps=scene.fps,
        extra={"task": rec.task, "policy": rec.policy, "frames": len(rec)},
    )
