"""Detour Speaker-Listener: goals, the speaker with its visit radius and message, the listener.

The true goal of the interaction is ringed in gold; the speaker's visit radius turns green while
its code is locked (the listener visited it now or in the previous interaction) and orange while
the code may drift; a label next to the speaker shows the message it is uttering.
"""

from __future__ import annotations

from typing import Any

import meshcat
import meshcat.geometry as g
import numpy as np
from meshcat.animation import Animation

from sili_robots.preview import shapes
from sili_robots.preview.recording import Recording
from sili_robots.preview.scenes.base import (
    Camera,
    Marker,
    TaskScene,
    animate_position,
    animate_visible,
    translation,
)
from sili_robots.preview.scenes.circle import (
    EGO,
    EGO_RADIUS,
    LOCATION,
    LOCATION_RADIUS,
    Z_EGO,
    Z_LOC,
    Z_OPP,
    Z_RING,
    Z_TRAIL,
    draw_arena,
    draw_trail,
    free_point_on_circle,
    on_plane,
    trail_points,
)
from sili_robots.preview.scenes.circle import TRAIL as TRAIL_COLOR

SPEAKER = 0x7B3FA0
TRUE_GOAL = 0xE6A700
LOCKED = 0x2CA02C
UNLOCKED = 0xFF7F0E
TEXT = 0x000000
GOAL_NAMES = "ABC"
SPEAKER_SIZE = 0.2
HALO = (0.15, 0.23)  # inner, outer radius of the true-goal ring
LABEL_SIZE = 0.9
LABEL_OFFSET = np.array([0.75, 0.0])


class SpeakerListenerScene(TaskScene):
    env_classes = ("SpeakerListenerEnv",)

    def static(self, task: Any) -> dict[str, Any]:
        from sili_robots.tasks import speaker_listener as sl

        return {
            "goals": np.asarray(sl.GOALS, float),
            "speaker": np.asarray(task.speaker, float),
            "visit_radius": float(sl.VISIT_RADIUS),
            "mappings": [tuple(m) for m in sl.MAPPINGS],
            "arena": float(sl.ARENA),
        }

    def snapshot(self, task: Any) -> dict[str, Any]:
        return {
            "ego": np.asarray(task.position, float).copy(),
            "goal": int(task.goal),
            "mapping": int(task.mapping),
            "message": int(task.message),
            "visited": bool(task.visited_now),
            "locked": bool(task.locked),
        }

    # ------------------------------------------------------------------ drawing
    def draw(self, vis: meshcat.Visualizer, rec: Recording, anim: Animation) -> None:
        s = rec.static
        draw_arena(vis, s["arena"])
        for i, goal in enumerate(s["goals"]):
            vis[f"goals/{i}"].set_object(shapes.disc(LOCATION_RADIUS, 48), shapes.flat(LOCATION))
            vis[f"goals/{i}"].set_transform(translation(on_plane(goal, Z_LOC)[0]))
            vis[f"goal_names/{i}"].set_object(shapes.label(GOAL_NAMES[i], 0.6, 96))
            offset = np.array([0.36 if goal[0] >= 0 else -0.36, 0.0])
            vis[f"goal_names/{i}"].set_transform(translation(on_plane(goal + offset, Z_LOC)[0]))
        goals = rec.series("goal")
        vis["true_goal"].set_object(shapes.ring(*HALO, 64, 0.0), shapes.flat(TRUE_GOAL))
        animate_position(anim, vis["true_goal"], on_plane(s["goals"][goals], Z_LOC), True)
        speaker = s["speaker"]
        vis["speaker/body"].set_object(
            g.Box([SPEAKER_SIZE, SPEAKER_SIZE, 0.02]), shapes.flat(SPEAKER)
        )
        vis["speaker/body"].set_transform(translation(on_plane(speaker, Z_OPP)[0]))
        r = s["visit_radius"]
        locked = rec.series("locked")
        for name, color, shown in (("locked", LOCKED, locked), ("unlocked", UNLOCKED, ~locked)):
            node = vis[f"speaker/radius_{name}"]
            node.set_object(shapes.ring(r - 0.018, r + 0.018, 64, 0.0), shapes.flat(color))
            node.set_transform(translation(on_plane(speaker, Z_RING)[0]))
            animate_visible(anim, node, shown)
        messages = rec.series("message")
        for m in range(len(s["goals"])):
            node = vis[f"speaker/says_{m}"]
            node.set_object(shapes.label(f"says {m}", LABEL_SIZE, 64))
            node.set_transform(translation(on_plane(speaker + LABEL_OFFSET, Z_LOC)[0]))
            animate_visible(anim, node, messages == m)
        ego = rec.series("ego")
        draw_trail(vis, anim, rec, ego, Z_TRAIL)
        vis["listener"].set_object(g.Sphere(EGO_RADIUS), shapes.flat(EGO))
        animate_position(anim, vis["listener"], on_plane(ego, Z_EGO))

    def legend(self, rec: Recording) -> list[tuple[int, str]]:
        return [
            (EGO, "listener (ego)"),
            (TRAIL_COLOR, "path"),
            (LOCATION, "goals"),
            (TRUE_GOAL, "true goal"),
            (SPEAKER, "speaker"),
            (LOCKED, "code locked"),
            (UNLOCKED, "may change"),
        ]

    def caption(self, rec: Recording, frame: int) -> str:
        fr = rec.frames[frame]
        mapping = rec.static["mappings"][fr["mapping"]]
        code = " ".join(f"{GOAL_NAMES[g_]}→{m}" for g_, m in enumerate(mapping))
        state = "locked by a visit" if fr["locked"] else "unlocked"
        return (
            f"interaction {fr['interaction'] + 1}/{rec.interactions}, step {fr['t']}/"
            f"{rec.horizon}: true goal {GOAL_NAMES[fr['goal']]}, speaker says {fr['message']} "
            f"(code {code}, {state}); return{' so far' if fr['t'] < rec.horizon else ''} "
            f"{fr['interaction_return']:.2f}"
        )

    def camera(self, rec: Recording) -> Camera:
        return Camera(position=(0.0, -1.6, 6.0), target=(0.0, -0.22, 0.0), fov=40.0)

    # ------------------------------------------------------------------ checks
    def markers(self, rec: Recording, frame: int) -> list[Marker]:
        s = rec.static
        fr = rec.frames[frame]
        ego = fr["ego"]
        speaker = s["speaker"]
        goal = s["goals"][fr["goal"]]
        out = [Marker("listener", (*ego, Z_EGO), EGO, EGO_RADIUS * 0.8, 0.5)]
        if np.linalg.norm(ego - speaker) > EGO_RADIUS + SPEAKER_SIZE:
            out.append(Marker("speaker", (*speaker, Z_OPP), SPEAKER, SPEAKER_SIZE * 0.35, 0.5))
        for i, p in enumerate(s["goals"]):
            if np.linalg.norm(ego - p) > EGO_RADIUS + LOCATION_RADIUS:
                out.append(
                    Marker(
                        f"goal {GOAL_NAMES[i]}", (*p, Z_LOC), LOCATION, LOCATION_RADIUS * 0.6, 0.5
                    )
                )
        trail = trail_points(rec, rec.series("ego"), frame).reshape(-1, 2)
        avoid = np.vstack([trail, ego[None]])
        halo = goal + free_point_on_circle(sum(HALO) / 2, avoid - goal)
        out.append(Marker("true goal", (*halo, Z_LOC), TRUE_GOAL, 0.03, 0.3))
        rim = speaker + free_point_on_circle(s["visit_radius"], avoid - speaker)
        color = LOCKED if fr["locked"] else UNLOCKED
        out.append(Marker("visit radius", (*rim, Z_RING), color, 0.015, 0.3))
        text = speaker + LABEL_OFFSET
        out.append(Marker("message label", (*text, Z_LOC), TEXT, 0.25, 0.02, 110.0))
        return out
