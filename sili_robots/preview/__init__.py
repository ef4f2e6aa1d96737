"""meshcat previews of every task: a rollout animated in a self-contained HTML page, a PNG
rendered in headless Chromium, or a live meshcat server (``sili preview``)."""

from sili_robots.preview.api import POLICIES, Preview, PreviewResult, make_env_and_policy, preview
from sili_robots.preview.browser import Browser, BrowserError, find_chromium
from sili_robots.preview.server import LiveServer

__all__ = [
    "POLICIES",
    "Browser",
    "BrowserError",
    "LiveServer",
    "Preview",
    "PreviewResult",
    "find_chromium",
    "make_env_and_policy",
    "preview",
]
