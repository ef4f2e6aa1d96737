"""Render a preview's HTML to PNG in headless Chromium and check what the picture shows."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from sili_robots.preview.browser import Browser, PageResult
from sili_robots.preview.check import MarkerResult, marker_results, problems
from sili_robots.preview.scenes.base import Marker

WIDTH, HEIGHT = 640, 480
PAGE_READY = "window.previewReady === true"
# a live server's page is ready once the scene (animation included) has arrived over its socket
LIVE_READY = "typeof viewer !== 'undefined' && viewer.animator.actions.length > 0"
LIVE_SEEK = "viewer.animator.pause(); viewer.animator.seek({time}); viewer.set_dirty()"


@dataclass
class Rendered:
    """A screenshot of one frame and what the checks made of it."""

    page: PageResult
    frame: int
    markers: list[MarkerResult] = field(default_factory=list)
    #: URL prefixes the page may request (a live server's own address)
    allowed: tuple[str, ...] = ("file:", "data:", "about:")

    @property
    def png(self) -> bytes:
        return self.page.png

    def seen_summary(self) -> str:
        """What the check saw, e.g. "7 scene elements seen, 1 out of view"."""
        seen = sum(r.in_view and r.ok for r in self.markers)
        away = sum(not r.in_view for r in self.markers)
        return f"{seen} scene elements seen" + (f", {away} out of view" if away else "")

    def problems(self) -> list[str]:
        """What a person would object to: blank picture, missing things, page errors, and
        any request that left the file (the page must work offline)."""
        found = problems(self.page.png, self.markers, self.page.covered)
        found += [f"page error: {e}" for e in self.page.errors]
        found += [
            f"network request: {u[:80]}"
            for u in self.page.requests
            if not u.startswith(self.allowed) and not u.endswith("/favicon.ico")
        ]
        return found


def render_html(
    html: str | Path,
    frame: int,
    markers: list[tuple[Marker, tuple[float, float, float]]] = (),
    browser: Browser | None = None,
    width: int = WIDTH,
    height: int = HEIGHT,
    live_fps: float | None = None,
    evaluate: str | None = None,
) -> Rendered:
    """Screenshot ``frame`` of a preview page; ``markers`` pair each marker with its world
    point (already in the viewer's frame) to be projected and checked. ``live_fps`` means
    ``html`` is a live meshcat server's URL (plain viewer page, animation at that rate);
    ``evaluate`` is a JavaScript expression whose value lands in ``page.value``."""
    points = [p for _, p in markers]
    edges = [(p[0] + m.radius, p[1], p[2]) for m, p in markers]
    own = browser is None
    b = Browser().start() if own else browser
    try:
        page = b.render(
            html,
            width,
            height,
            ready=PAGE_READY if live_fps is None else LIVE_READY,
            setup=f"previewShowFrame({int(frame)})"
            if live_fps is None
            else LIVE_SEEK.format(time=int(frame) / live_fps),
            points=points + edges,
            evaluate=evaluate,
            hide=[
                tuple(f"/meshcat/{path}" for path in view) for m, _ in markers for view in m.views()
            ],
        )
    finally:
        if own:
            b.close()
    n = len(points)
    hidden = {
        tuple(p.removeprefix("/meshcat/") for p in paths): _rgb(png)
        for paths, png in page.hidden.items()
    }
    results = marker_results(
        _rgb(page.png),
        [m for m, _ in markers],
        page.projections[:n],
        page.projections[n:],
        hidden,
    )
    out = Rendered(page, frame, results)
    if live_fps is not None:
        out.allowed = (*out.allowed, str(html).split("/static/")[0] + "/")
    return out


def _rgb(png: bytes):
    from sili_robots.preview.check import load_rgb

    return load_rgb(png)
