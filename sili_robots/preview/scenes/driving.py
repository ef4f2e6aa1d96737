"""Driving: the three-lane road, its markings, the hazard, the red line, both cars from SUMO.

Positions are SUMO's (front bumper, read by the task after every SUMO step) and are keyed at
every SUMO step (0.1 s) on meshcat's timeline, one animation frame per 1 s decision step played
at twice real time. The camera follows the ego: the road and everything on it slides under a
fixed chase camera. The lane the opponent intends to cut into (its hidden strategy) is tinted
ahead of it.
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
    frame_of,
    translation,
)

EGO = 0x1F6FD1
OPPONENT = 0xD62728
HAZARD = 0xF2C200
ROAD = 0x5F6366
MARKING = 0xF4F4F4
RED_LINE = 0xE0001B
GRASS = 0x9CC58A
INTENT = 0xF08080

ROAD_FROM, ROAD_TO = -80.0, 280.0  # metres from the ego's start
DASH, GAP = 3.0, 6.0
PASS_STEP = 6  # decision step at which the ego draws level with the opponent
HOLD = 0.02  # frames: the cars jump back to the start between interactions


class DrivingScene(TaskScene):
    env_classes = ("DrivingEnv",)
    fps = 2.0  # one decision step (1 s of SUMO time) per half second
    background = ((0.80, 0.89, 0.98), (0.60, 0.75, 0.92))

    def static(self, task: Any) -> dict[str, Any]:
        from sili_robots.tasks import driving
        from sili_robots.tasks import sumo_scenario as sc

        return {
            "lane_width": float(sc.LANE_WIDTH),
            "lanes": int(sc.NUM_LANES),
            "centre": int(sc.CENTRE_LANE),
            "length": float(sc.VEHICLE_LENGTH),
            "width": float(sc.VEHICLE_WIDTH),
            "hazard_x": float(sc.HAZARD_POSITION - sc.EGO_START),
            "red_line": float(driving.RED_LINE),
            "substeps": int(driving.DECISION_SUBSTEPS),
        }

    def snapshot(self, task: Any) -> dict[str, Any]:
        from sili_robots.tasks.driving import DECISION_SUBSTEPS  # SUMO steps per decision

        sub = task.substeps[-DECISION_SUBSTEPS:] if task.t > 0 else []
        return {
            "ego": np.array([task.ego_x, task.ego_y]),
            "opponent": np.array([task.opp_x, task.opp_y]),
            "sub_ego": np.array([[s[1], s[2]] for s in sub]).reshape(-1, 2),
            "sub_opponent": np.array([[s[3], s[4]] for s in sub]).reshape(-1, 2),
            "target_lane": int(task.target_lane),
            "collided": bool(task.collided),
            "red_line_crossed": bool(task.red_line_crossed),
            "left_before_red_line": bool(task.left_before_red_line),
            "passed": bool(task.passed),
        }

    # ------------------------------------------------------------------ timeline
    def _keys(self, rec: Recording, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(times in frames, xy) at every SUMO step, holding across interaction boundaries."""
        times, xy = [], []
        for f, fr in enumerate(rec.frames):
            sub = fr[f"sub_{key}"]
            if fr["t"] == 0:
                if f > 0:
                    times.append(f - HOLD)
                    xy.append(xy[-1])
                times.append(float(f))
                xy.append(fr[key])
                continue
            n = len(sub)
            for k, p in enumerate(sub):
                times.append(f - 1 + (k + 1) / n)
                xy.append(p)
        return np.array(times), np.array(xy)

    def view_shift(self, rec: Recording, frame: int) -> np.ndarray:
        return np.array([rec.frames[frame]["ego"][0], 0.0, 0.0])

    # ------------------------------------------------------------------ drawing
    def draw(self, vis: meshcat.Visualizer, rec: Recording, anim: Animation) -> None:
        s = rec.static
        w = s["lane_width"]
        half = w * s["lanes"] / 2
        length = ROAD_TO - ROAD_FROM
        mid = (ROAD_FROM + ROAD_TO) / 2
        vis["ground"].set_object(shapes.rectangle(length + 200, 120.0, -0.02), shapes.flat(GRASS))
        vis["ground"].set_transform(translation((mid, 0.0, 0.0)))
        vis["road"].set_object(shapes.rectangle(length, 2 * half, 0.0), shapes.flat(ROAD))
        vis["road"].set_transform(translation((mid, 0.0, 0.0)))
        for side in (-1, 1):
            edge = vis[f"markings/edge{side:+d}"]
            edge.set_object(shapes.rectangle(length, 0.15, 0.01), shapes.flat(MARKING))
            edge.set_transform(translation((mid, side * (half - 0.2), 0.0)))
        starts = np.arange(ROAD_FROM, ROAD_TO, DASH + GAP)
        for k in range(1, s["lanes"]):
            y = -half + k * w
            verts, faces = [], []
            for i, x0 in enumerate(starts):
                verts += [
                    [x0, y - 0.075, 0.01],
                    [x0 + DASH, y - 0.075, 0.01],
                    [x0 + DASH, y + 0.075, 0.01],
                    [x0, y + 0.075, 0.01],
                ]
                faces += [[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]]
            vis[f"markings/dashes{k}"].set_object(
                shapes.UVGeometry(np.array(verts), np.array(faces)), shapes.flat(MARKING)
            )
        vis["red_line"].set_object(shapes.rectangle(0.6, 2 * half, 0.015), shapes.flat(RED_LINE))
        vis["red_line"].set_transform(translation((s["red_line"], 0.0, 0.0)))
        self._car(vis["hazard"], HAZARD, s)
        vis["hazard"].set_transform(translation((s["hazard_x"], 0.0, 0.0)))
        for name, color in (("ego", EGO), ("opponent", OPPONENT)):
            node = vis[f"vehicles/{name}"]
            self._car(node, color, s)
            times, xy = self._keys(rec, name)
            for t, p in zip(times, xy, strict=True):
                anim.at_frame(node, t).set_property("position", "vector3", [p[0], p[1], 0.0])
            node.set_transform(translation((*xy[-1], 0.0)))
        # the opponent's hidden intent: its target lane, tinted ahead of it
        node = vis["intent"]
        node.set_object(shapes.rectangle(30.0, w * 0.9, 0.005), shapes.flat(INTENT, 0.55))
        times, xy = self._keys(rec, "opponent")
        lanes = {f: fr["target_lane"] for f, fr in enumerate(rec.frames)}
        for t, p in zip(times, xy, strict=True):
            lane = lanes[min(int(np.ceil(t)), len(rec) - 1)]
            y = (lane - s["centre"]) * w
            anim.at_frame(node, t).set_property("position", "vector3", [p[0] + 17.0, y, 0.0])
        # chase camera: the content slides so the ego stays in view
        target = np.asarray(self.camera(rec).target, float)
        times, xy = self._keys(rec, "ego")
        for t, p in zip(times, xy, strict=True):
            anim.at_frame(vis, t).set_property(
                "position", "vector3", (-target - [p[0], 0, 0]).tolist()
            )

    def _car(self, node: meshcat.Visualizer, color: int, s: dict[str, Any]) -> None:
        """A car whose front bumper is at the node's origin (SUMO's position convention)."""
        length, width = s["length"], s["width"]
        node["body"].set_object(g.Box([length, width, 0.8]), shapes.shaded(color))
        node["body"].set_transform(translation((-length / 2, 0.0, 0.55)))
        node["cabin"].set_object(g.Box([length * 0.5, width * 0.85, 0.6]), shapes.shaded(color))
        node["cabin"].set_transform(translation((-length * 0.55, 0.0, 0.55 + 0.4 + 0.3)))

    def legend(self, rec: Recording) -> list[tuple[int, str]]:
        return [
            (EGO, "ego"),
            (OPPONENT, "opponent"),
            (INTENT, "lane it will cut into (hidden)"),
            (HAZARD, "stopped hazard"),
            (RED_LINE, "red line"),
        ]

    def caption(self, rec: Recording, frame: int) -> str:
        fr = rec.frames[frame]
        lanes = ("right", "centre", "left")
        w = rec.static["lane_width"]
        ego_lane = lanes[int(np.clip(np.round(fr["ego"][1] / w), -1, 1)) + 1]
        head = (
            f"interaction {fr['interaction'] + 1}/{rec.interactions}, step {fr['t']}/"
            f"{rec.horizon}: opponent will cut into the {lanes[fr['target_lane']]} lane; "
            f"ego in the {ego_lane} lane"
        )
        notes = []
        if fr["red_line_crossed"]:
            notes.append(
                "was left at the red line"
                if fr["left_before_red_line"]
                else "was not left at the red line"
            )
        if fr["collided"]:
            notes.append("COLLISION")
        elif fr["passed"]:
            notes.append("passed safely")
        return head + ("; " + ", ".join(notes) if notes else "")

    def camera(self, rec: Recording) -> Camera:
        return Camera(position=(-21.0, -5.0, 12.0), target=(14.0, 0.0, 0.0), fov=40.0)

    def picture_frame(self, rec: Recording) -> int:
        last = rec.frames[-1]["interaction"]
        return frame_of(rec, last, min(PASS_STEP, rec.horizon))

    # ------------------------------------------------------------------ checks
    def markers(self, rec: Recording, frame: int) -> list[Marker]:
        s = rec.static
        fr = rec.frames[frame]
        ego, opp = fr["ego"], fr["opponent"]
        length = s["length"]
        ego_node, opp_node = "vehicles/ego", "vehicles/opponent"
        cars = (ego_node, opp_node)  # either may stand in front of the other (a collision)

        def car(name: str, at: np.ndarray, node: str, other: str, leaves: bool) -> Marker:
            return Marker(
                name,
                (at[0] - length / 2, at[1], 1.0),
                0,
                0.6,
                0.6,
                toggle=node,
                behind=(other,),
                may_leave_view=leaves,
            )

        # the camera follows the ego; the rest may be out of its view (far ahead, or passed)
        out = [
            car("ego", ego, ego_node, opp_node, False),
            car("opponent", opp, opp_node, ego_node, True),
        ]
        w = s["lane_width"]
        ahead = ego[0] + 12.0
        intent_y = (fr["target_lane"] - s["centre"]) * w
        for lane_y in (-w, 0.0, w):  # bare road: a lane no car (or tint) is in, a little ahead
            if lane_y == intent_y:
                continue
            if all(abs(c[1] - lane_y) > w / 2 or abs(c[0] - ahead) > 8 for c in (ego, opp)):
                out.append(Marker("road", (ahead, lane_y, 0.0), ROAD, 0.5, 0.6))
                break
        if -25.0 < s["hazard_x"] - ego[0] < 70.0:
            out.append(
                Marker(
                    "hazard",
                    (s["hazard_x"] - length / 2, 0.0, 1.0),
                    0,
                    0.6,
                    0.6,
                    toggle="hazard",
                    behind=cars,
                    may_leave_view=True,
                )
            )
        if -12.0 < s["red_line"] - ego[0] < 70.0:
            out.append(
                Marker(
                    "red line",
                    (s["red_line"], 2 * w / 3 + 0.5, 0.015),
                    RED_LINE,
                    0.25,
                    0.3,
                    behind=cars,
                    may_leave_view=True,
                )
            )
        return out
