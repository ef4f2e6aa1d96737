"""One scene per task family, looked up by the unwrapped task's class."""

from __future__ import annotations

from typing import Any

from sili_robots.errors import ConfigError
from sili_robots.preview.scenes.base import Camera, Marker, TaskScene
from sili_robots.preview.scenes.circle import CircleScene
from sili_robots.preview.scenes.driving import DrivingScene
from sili_robots.preview.scenes.sawyer_reach import SawyerReachScene
from sili_robots.preview.scenes.speaker_listener import SpeakerListenerScene

SCENES: tuple[TaskScene, ...] = (
    CircleScene(),
    SpeakerListenerScene(),
    SawyerReachScene(),
    DrivingScene(),
)


def scene_for(env: Any) -> TaskScene:
    """The scene that draws ``env`` (wrappers are looked through)."""
    name = type(env.unwrapped).__name__
    for scene in SCENES:
        if name in scene.env_classes:
            return scene
    known = sorted(c for s in SCENES for c in s.env_classes)
    raise ConfigError(f"no preview scene for task class {name!r}; scenes exist for {known}")


__all__ = ["SCENES", "Camera", "Marker", "TaskScene", "scene_for"]
