"""Sawyer-Reach: the robot and table from the compiled MuJoCo model, the goals, the plane.

The arm is drawn from the model's own visual geoms (``mujoco_geoms``) and moved by the recorded
joint positions (forward kinematics on a private ``MjData``). The opponent's current goal is the
red ball, the other goals grey; the translucent blue sheet is the height plane of the strategy
rule (ending above it keeps the goal); light-blue dots trace the gripper in this interaction.
"""

from __future__ import annotations

from typing import Any

import meshcat
import meshcat.geometry as g
import numpy as np
from meshcat.animation import Animation

from sili_robots.preview import mujoco_geoms, shapes
from sili_robots.preview.recording import Recording
from sili_robots.preview.scenes.base import (
    Camera,
    Marker,
    TaskScene,
    animate_pose,
    animate_position,
    animate_visible,
    frame_of,
    translation,
)
from sili_robots.preview.scenes.circle import LOCATION, OPPONENT, TRAIL

PLANE = 0x4A90D9
GOAL_RADIUS = 0.022
CHOSEN_RADIUS = 0.03
TRAIL_RADIUS = 0.006
PLANE_EDGE = 0.006
ROBOT_PREFIXES = ("robot0_", "gripper0_", "fixed_mount0_")
#: bodies whose projected origins the check looks at (hiding the robot must change them)
CHECKED_BODIES = ("robot0_right_l1", "robot0_right_l3", "robot0_right_l5", "robot0_right_hand")
#: goals sit under the translucent plane, which tints them
SEEN_THROUGH_PLANE = 75.0


def visual_model(task: Any) -> Any:
    """The scene compiled with its render-only geoms (the physics model may leave them out),
    checked to share the physics model's joints so recorded ``qpos`` drive it."""
    import inspect

    from sili_robots.tasks import sawyer_scene as ss

    physics = task.scene.model
    if "visual" not in inspect.signature(ss.scene_model).parameters:
        return physics
    model = ss.scene_model(task.scene.actuation, visual=True)
    joints = [model.joint(i).name for i in range(model.njnt)]
    if model.nq != physics.nq or joints != [physics.joint(i).name for i in range(physics.njnt)]:
        raise RuntimeError("the visual Sawyer model's joints differ from the simulated one's")
    return model


def group_of(body: str) -> str:
    return "robot" if body.startswith(ROBOT_PREFIXES) else "arena"


class SawyerReachScene(TaskScene):
    env_classes = ("SawyerReachEnv",)
    fps = 20.0  # the control rate: real time

    def static(self, task: Any) -> dict[str, Any]:
        from sili_robots.tasks import sawyer_scene as ss

        return {
            "model": visual_model(task),
            "goals": np.asarray(ss.GOALS, float),
            "plane_z": float(task.plane_z),
            "table_top": float(ss.TABLE_TOP_Z),
            "table_half": float(ss.TABLE_SIZE[0]) / 2,
        }

    def snapshot(self, task: Any) -> dict[str, Any]:
        return {
            "qpos": np.array(task.scene.data.qpos, float),
            "ee": np.array(task.scene.ee_pos, float),
            "goal": int(task.goal),
        }

    # ------------------------------------------------------------------ drawing
    def draw(self, vis: meshcat.Visualizer, rec: Recording, anim: Animation) -> None:
        s = rec.static
        model = s["model"]
        nodes = mujoco_geoms.draw_geoms(vis, model, group_of)
        poses = mujoco_geoms.body_poses(model, rec.series("qpos"))
        for body, node in nodes.items():
            animate_pose(anim, node, poses[:, body], steps=True)
        for i, goal in enumerate(s["goals"]):
            vis[f"goals/{i}"].set_object(g.Sphere(GOAL_RADIUS), shapes.flat(LOCATION))
            vis[f"goals/{i}"].set_transform(translation(goal))
        vis["chosen_goal"].set_object(g.Sphere(CHOSEN_RADIUS), shapes.flat(OPPONENT))
        animate_position(anim, vis["chosen_goal"], s["goals"][rec.series("goal")], steps=True)
        self._draw_plane(vis, s)
        ee = rec.series("ee")
        for k in range(1, rec.horizon + 1):
            dot = vis[f"trail/{k:03d}"]
            dot.set_object(g.Sphere(TRAIL_RADIUS), shapes.flat(TRAIL))
            where = np.array([ee[frame_of(rec, fr["interaction"], k)] for fr in rec.frames])
            animate_position(anim, dot, where, steps=True)
            animate_visible(anim, dot, np.array([fr["t"] >= k for fr in rec.frames]))

    def _draw_plane(self, vis: meshcat.Visualizer, s: dict[str, Any]) -> None:
        half, z = s["table_half"], s["plane_z"]
        vis["plane/sheet"].set_object(
            shapes.rectangle(2 * half, 2 * half), shapes.flat(PLANE, 0.18)
        )
        vis["plane/sheet"].set_transform(translation((0.0, 0.0, z)))
        for i, (cx, cy, lx, ly) in enumerate(
            [
                (0, -half, 2 * half, PLANE_EDGE),
                (0, half, 2 * half, PLANE_EDGE),
                (-half, 0, PLANE_EDGE, 2 * half),
                (half, 0, PLANE_EDGE, 2 * half),
            ]
        ):
            vis[f"plane/edge{i}"].set_object(g.Box([lx, ly, PLANE_EDGE]), shapes.flat(PLANE))
            vis[f"plane/edge{i}"].set_transform(translation((cx, cy, z)))

    def legend(self, rec: Recording) -> list[tuple[int, str]]:
        return [
            (OPPONENT, "opponent's goal (hidden from ego)"),
            (LOCATION, "other goals"),
            (PLANE, "height plane"),
            (TRAIL, "gripper path"),
        ]

    def caption(self, rec: Recording, frame: int) -> str:
        fr = rec.frames[frame]
        z = fr["ee"][2]
        side = "above" if z > rec.static["plane_z"] else "below"
        head = (
            f"interaction {fr['interaction'] + 1}/{rec.interactions}, step {fr['t']}/"
            f"{rec.horizon}: opponent's goal {fr['goal']}, gripper {z:.2f} m ({side} the plane)"
        )
        if fr["t"] < rec.horizon:
            return f"{head}; return so far {fr['interaction_return']:.2f}"
        if frame + 1 < len(rec):  # the last interaction's next goal was never drawn
            moved = rec.frames[frame + 1]["goal"] != fr["goal"]
            head += f" → goal {'moves' if moved else 'stays'}"
        return f"{head}; return {fr['interaction_return']:.2f}"

    def camera(self, rec: Recording) -> Camera:
        return Camera(position=(1.45, -1.25, 1.9), target=(-0.22, 0.0, 1.0), fov=45.0)

    # ------------------------------------------------------------------ checks
    def markers(self, rec: Recording, frame: int) -> list[Marker]:
        s = rec.static
        fr = rec.frames[frame]
        model = s["model"]
        pose = mujoco_geoms.body_poses(model, fr["qpos"][None])[0]
        out = []
        for name in CHECKED_BODIES:
            p = pose[model.body(name).id, :3, 3]
            out.append(Marker(f"robot {name}", tuple(p), 0, 0.02, 0.5, toggle="robot"))
        # the arm may stand between the camera and a goal or the plane's edge: those are looked
        # for again with the robot hidden
        out.append(
            Marker(
                "opponent's goal",
                tuple(s["goals"][fr["goal"]]),
                OPPONENT,
                CHOSEN_RADIUS * 0.7,
                0.3,
                SEEN_THROUGH_PLANE,
                behind=("robot",),
            )
        )
        for i, goal in enumerate(s["goals"]):
            if i != fr["goal"]:
                out.append(
                    Marker(
                        f"goal {i}",
                        tuple(goal),
                        LOCATION,
                        GOAL_RADIUS * 0.7,
                        0.3,
                        SEEN_THROUGH_PLANE,
                        behind=("robot",),
                    )
                )
        half, z = s["table_half"], s["plane_z"]
        out.append(
            Marker(
                "height plane edge",
                (half, -half * 0.5, z),
                PLANE,
                PLANE_EDGE,
                0.3,
                behind=("robot",),
            )
        )
        return out
