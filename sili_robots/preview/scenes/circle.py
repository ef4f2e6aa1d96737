"""Circle point mass: the circle, the opponent's locations, the opponent, the ego and its trail.

Drawn flat in the xy-plane (the task is 2D) and seen from slightly south of straight above, so
the circle reads as a circle and "inside/outside" is obvious. The trail shows the ego's path in
the current interaction; the caption says where the interaction ended and what the opponent did.
"""

from __future__ import annotations

import math
from typing import Any

import meshcat
import meshcat.geometry as g
import meshcat.transformations as tf
import numpy as np
from meshcat.animation import Animation

from sili_robots.preview import shapes
from sili_robots.preview.recording import Recording
from sili_robots.preview.scenes.base import (
    HIDDEN,
    Camera,
    Marker,
    TaskScene,
    animate_position,
    animate_visible,
    change_frames,
    frame_of,
    translation,
)

EGO = 0x1F6FD1
TRAIL = 0x8EC3F0
OPPONENT = 0xD62728
LOCATION = 0xA9A9A9
HOLDABLE = 0x2CA02C
CIRCLE = 0x404040
ARENA = 0xFCFCFC

EGO_RADIUS = 0.07
OPPONENT_RADIUS = 0.13
LOCATION_RADIUS = 0.11
TRAIL_RADIUS = 0.022
TRAIL_WIDTH = 0.012
RING_WIDTH = 0.035
HOLD_RING = (0.16, 0.21)  # around the location the opponent can be held at (Unequal)
# heights keep flat layers apart in depth
Z_ARENA, Z_RING, Z_LOC, Z_TRAIL, Z_OPP = 0.0, 0.004, 0.008, 0.012, 0.016
PUCK = 0.04  # the opponent is a flat puck this tall; the ego ball rolls on top of it
Z_EGO = Z_OPP + PUCK + EGO_RADIUS


def on_plane(xy: np.ndarray, z: float = 0.0) -> np.ndarray:
    xy = np.atleast_2d(np.asarray(xy, float))
    return np.column_stack([xy[:, :2], np.full(len(xy), z)])


def free_point_on_circle(radius: float, avoid: np.ndarray, n: int = 360) -> np.ndarray:
    """The point of the circle farthest from every point in ``avoid`` (for a clean look)."""
    a = np.linspace(0, 2 * math.pi, n, endpoint=False)
    pts = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    if len(avoid) == 0:
        return pts[0]
    d = np.linalg.norm(pts[:, None, :] - np.asarray(avoid)[None, :, :2], axis=2).min(axis=1)
    return pts[int(np.argmax(d))]


def draw_trail(
    vis: meshcat.Visualizer, anim: Animation, rec: Recording, positions: np.ndarray, z: float
) -> None:
    """H dots joined by strips; dot k sits where the ego was after step k of the current
    interaction, strip k joins it to step k - 1. Hidden until the ego gets there."""
    interaction, t = rec.series("interaction"), rec.series("t")  # per frame
    height = np.full((len(rec), 1), z)
    for k in range(1, rec.horizon + 1):
        dot, seg = vis[f"trail/dot{k:03d}"], vis[f"trail/seg{k:03d}"]
        dot.set_object(shapes.disc(TRAIL_RADIUS, 16), shapes.flat(TRAIL))
        seg.set_object(shapes.rectangle(1.0, TRAIL_WIDTH), shapes.flat(TRAIL))
        a = positions[frame_of(rec, interaction, k - 1)]  # where each frame's interaction was
        b = positions[frame_of(rec, interaction, k)]  # before and after step k
        where = np.hstack([b, height])
        mid = np.hstack([(a + b) / 2, height])
        d = b - a
        half = np.arctan2(d[:, 1], d[:, 0]) / 2
        zero = np.zeros(len(rec))
        quat = np.column_stack([zero, zero, np.sin(half), np.cos(half)])  # three.js: x y z w
        length = np.linalg.norm(d, axis=1)
        shown = t >= k
        animate_position(anim, dot, where, steps=True)
        animate_visible(anim, dot, shown)
        animate_position(anim, seg, mid, steps=True)
        for f in change_frames(quat):
            anim.at_frame(seg, f).set_property("quaternion", "quaternion", quat[f].tolist())
        scale = np.where(shown & (length > 1e-6), length, HIDDEN)
        scales = np.column_stack([scale, np.where(shown, 1.0, HIDDEN), np.ones(len(rec))])
        for f in change_frames(scales):
            anim.at_frame(seg, f).set_property("scale", "vector3", scales[f].tolist())


def trail_points(rec: Recording, positions: np.ndarray, frame: int) -> np.ndarray:
    fr = rec.frames[frame]
    first = frame_of(rec, fr["interaction"], 1)
    return positions[first : frame + 1] if fr["t"] >= 1 else np.empty((0, 2))


def puck(radius: float, height: float) -> g.Cylinder:
    """A short upright cylinder standing on the plane (meshcat cylinders are y-aligned)."""

    class Puck(g.Cylinder):
        def intrinsic_transform(self) -> np.ndarray:
            return tf.translation_matrix([0, 0, height / 2]) @ tf.rotation_matrix(
                math.pi / 2, [1, 0, 0]
            )

    return Puck(height, radius)


def draw_arena(vis: meshcat.Visualizer, half: float) -> None:
    vis["arena"].set_object(shapes.rectangle(2 * half, 2 * half, Z_ARENA), shapes.flat(ARENA))
    edge = np.array([[-half, -half], [half, -half], [half, half], [-half, half], [-half, -half]])
    vis["arena_edge"].set_object(shapes.polyline(edge, 0.015, Z_RING), shapes.flat(0x9A9A9A))


class CircleScene(TaskScene):
    env_classes = ("CircleEnv",)

    def static(self, task: Any) -> dict[str, Any]:
        from sili_robots.tasks import circle

        locations = np.column_stack([np.cos(task.angles), np.sin(task.angles)]) * circle.RADIUS
        return {
            "variant": task.variant,
            "radius": circle.RADIUS,
            "arena": circle.ARENA,
            "locations": locations,
            "holdable": sorted(task.stable_locations),
            "start": np.asarray(task.start, float),
        }

    def snapshot(self, task: Any) -> dict[str, Any]:
        return {
            "ego": np.asarray(task.position, float).copy(),
            "opponent": np.asarray(task.opponent_position, float).copy(),
            "location": int(task.location),
            "angle": float(task.opponent_angle),
            "inside": bool(task.ends_inside(task.position)),
        }

    # ------------------------------------------------------------------ drawing
    def draw(self, vis: meshcat.Visualizer, rec: Recording, anim: Animation) -> None:
        s = rec.static
        radius = s["radius"]
        draw_arena(vis, s["arena"])
        vis["circle"].set_object(
            shapes.ring(radius - RING_WIDTH / 2, radius + RING_WIDTH / 2, 128, Z_RING),
            shapes.flat(CIRCLE),
        )
        unequal = s["variant"] == "unequal"
        for i, loc in enumerate(s["locations"]):
            node = vis[f"locations/{i}"]
            node.set_object(shapes.disc(LOCATION_RADIUS, 48), shapes.flat(LOCATION))
            node.set_transform(translation(on_plane(loc, Z_LOC)[0]))
            if unequal and i in s["holdable"]:
                # a ring, so it still shows while the opponent stands on the location
                vis[f"holdable/{i}"].set_object(shapes.ring(*HOLD_RING, 64), shapes.flat(HOLDABLE))
                vis[f"holdable/{i}"].set_transform(translation(on_plane(loc, Z_LOC)[0]))
        ego = rec.series("ego")
        draw_trail(vis, anim, rec, ego, Z_TRAIL)
        vis["opponent"].set_object(puck(OPPONENT_RADIUS, PUCK), shapes.flat(OPPONENT))
        animate_position(anim, vis["opponent"], on_plane(rec.series("opponent"), Z_OPP), True)
        vis["ego"].set_object(g.Sphere(EGO_RADIUS), shapes.flat(EGO))
        animate_position(anim, vis["ego"], on_plane(ego, Z_EGO))

    def legend(self, rec: Recording) -> list[tuple[int, str]]:
        items = [(EGO, "ego"), (TRAIL, "ego's path"), (OPPONENT, "opponent (hidden from ego)")]
        if rec.static["variant"] == "unequal":
            items += [(LOCATION, "opponent's locations"), (HOLDABLE, "the one it can be held at")]
        elif rec.static["variant"] != "continuous":
            items.append((LOCATION, "opponent's locations"))
        items.append((CIRCLE, "circle"))
        return items

    def caption(self, rec: Recording, frame: int) -> str:
        fr = rec.frames[frame]
        j, t, h = fr["interaction"], fr["t"], rec.horizon
        where = f"{math.degrees(fr['angle']) % 360:.0f}°"
        head = f"interaction {j + 1}/{rec.interactions}, step {t}/{h}: opponent at {where}"
        tail = f"return so far {fr['interaction_return']:.2f}"
        if t == h:
            nxt = rec.frames[frame + 1] if frame + 1 < len(rec) else None
            side = "inside" if fr["inside"] else "outside"  # by the version's rule (v1: >= 1.1)
            if nxt is None:
                moved = ""
            elif np.allclose(nxt["opponent"], fr["opponent"]):
                moved = " → opponent stays"
            else:
                moved = " → opponent moves on"
            return f"{head}; ended {side} the circle{moved}; return {fr['interaction_return']:.2f}"
        return f"{head}; {tail}"

    def camera(self, rec: Recording) -> Camera:
        # the whole arena, between the title and the legend: an agent may run to its walls
        return Camera(position=(0.0, -2.0, 6.6), target=(0.0, -0.1, 0.0), fov=40.0)

    # ------------------------------------------------------------------ checks
    def markers(self, rec: Recording, frame: int) -> list[Marker]:
        s = rec.static
        fr = rec.frames[frame]
        ego, opp = fr["ego"], fr["opponent"]
        out = [
            Marker("ego", (*ego, Z_EGO), EGO, EGO_RADIUS * 0.8, 0.5),
            # the ego may sit on top of the opponent: some red must still show around it
            Marker("opponent", (*opp, Z_OPP + PUCK), OPPONENT, OPPONENT_RADIUS, 0.15),
        ]
        busy = [ego, opp]
        trail = trail_points(rec, rec.series("ego"), frame).reshape(-1, 2)
        for i, loc in enumerate(s["locations"]):
            if s["variant"] == "unequal" and i in s["holdable"]:
                rim = loc + free_point_on_circle(sum(HOLD_RING) / 2, np.vstack([trail, ego]) - loc)
                out.append(Marker(f"holdable ring {i}", (*rim, Z_LOC), HOLDABLE, 0.02, 0.3))
            if min(np.linalg.norm(loc - b) for b in busy) < LOCATION_RADIUS + OPPONENT_RADIUS:
                continue
            out.append(Marker(f"location {i}", (*loc, Z_LOC), LOCATION, LOCATION_RADIUS * 0.7, 0.5))
        avoid = np.vstack([np.atleast_2d(busy), s["locations"].reshape(-1, 2), trail])
        point = free_point_on_circle(s["radius"], avoid)
        out.append(Marker("circle", (*point, Z_RING), CIRCLE, RING_WIDTH, 0.2))
        return out
