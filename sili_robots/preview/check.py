"""Does a rendered preview show what the scene says it shows? Checked like a person would.

The picture must not be blank (a meshcat page with an empty scene is just the background), and
each of the scene's ``Marker``s must be visible: around the pixel where the page's own camera
projects the marker's world point, enough pixels have the marker's colour (or change when its
body is hidden), in the picture or, for a marker that may be behind another body, with that body
hidden. A marker the camera need not always see is not looked for out of the picture; any other
out of the picture is a framing error. An empty scene, a scene drawn in the wrong place, a camera
pointed elsewhere or a page that failed to load fails the same test.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
from PIL import Image

from sili_robots.preview.scenes.base import Marker, hidden_set
from sili_robots.preview.shapes import hex_rgb


@dataclass
class MarkerResult:
    marker: Marker
    pixel: tuple[float, float]
    radius_px: float
    fraction: float  # share of pixels around ``pixel`` with the marker's colour
    #: the point projects into the picture
    in_view: bool = True

    @property
    def ok(self) -> bool:
        if not self.in_view:
            return self.marker.may_leave_view
        return self.fraction >= self.marker.min_fraction


def load_rgb(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def blank_problem(
    rgb: np.ndarray, covered: list[tuple[float, ...]] = (), min_share: float = 0.02
) -> str | None:
    """The 3D view is blank when (nearly) every pixel not under an HTML box (caption,
    legend, controls) is meshcat's smooth background gradient."""
    h, w, _ = rgb.shape
    view = np.ones((h, w), bool)
    for x0, y0, x1, y1 in covered:
        view[
            max(0, int(y0)) : max(0, int(np.ceil(y1))), max(0, int(x0)) : max(0, int(np.ceil(x1)))
        ] = False
    if view.sum() < 0.2 * h * w:
        return "picture is blank: the 3D view is covered by text boxes"
    # the background is a vertical gradient: each row is nearly one colour
    masked = np.where(view[..., None], rgb, np.nan)
    row_median = np.nanmedian(masked, axis=1, keepdims=True)
    off = (np.abs(rgb - row_median).sum(axis=2) > 30) & view
    share = float(off.sum() / view.sum())
    if share < min_share:
        return f"picture is blank: only {share:.1%} of pixels differ from the background"
    return None


def marker_results(
    rgb: np.ndarray,
    markers: list[Marker],
    centres: list[tuple[float, float]],
    edges: list[tuple[float, float]],
    hidden: dict[tuple[str, ...], np.ndarray] | None = None,
) -> list[MarkerResult]:
    """Share of matching pixels around each marker's projected centre (``edges``: centre +
    radius). A colour marker matches its colour; a toggle marker matches where the picture
    with its node hidden differs. ``hidden`` holds the pictures with nodes hidden, keyed by
    ``hidden_set`` of their paths (``Marker.views``)."""
    h, w, _ = rgb.shape
    yy, xx = np.mgrid[0:h, 0:w]
    shots = {(): rgb, **(hidden or {})}
    out = []
    for m, c, e in zip(markers, centres, edges, strict=True):
        behind = tuple(e) == (-1, -1)  # the edge point behind the camera: no size to go by
        r = 2.0 if behind else max(2.0, float(np.hypot(e[0] - c[0], e[1] - c[1])))
        if not (0 <= c[0] < w and 0 <= c[1] < h):
            out.append(MarkerResult(m, c, r, 0.0, in_view=False))
            continue
        inside = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= r * r
        frac = _matching(m, inside, shots, ())
        if frac < m.min_fraction and m.behind:
            frac = max(frac, _matching(m, inside, shots, m.behind))
        out.append(MarkerResult(m, c, r, frac))
    return out


def _matching(
    m: Marker, inside: np.ndarray, shots: dict[tuple[str, ...], np.ndarray], hide: tuple[str, ...]
) -> float:
    """Share of pixels in ``inside`` that show ``m`` in the picture with ``hide`` hidden."""
    base = shots.get(hidden_set(*hide))
    if base is None:
        return 0.0
    if m.toggle is not None:
        other = shots.get(hidden_set(*hide, m.toggle))
        if other is None:
            return 0.0
        dist = np.linalg.norm(base[inside] - other[inside], axis=1)
        return float((dist > m.tolerance).mean()) if dist.size else 0.0
    dist = np.linalg.norm(base[inside] - np.array(hex_rgb(m.color)), axis=1)
    return float((dist <= m.tolerance).mean()) if dist.size else 0.0


def problems(
    png: bytes,
    results_or_none: list[MarkerResult] | None = None,
    covered: list[tuple[float, ...]] = (),
) -> list[str]:
    """Everything a person would object to in the picture; empty when it looks right."""
    rgb = load_rgb(png)
    found = []
    blank = blank_problem(rgb, covered)
    if blank:
        found.append(blank)
    for r in results_or_none or []:
        if not r.in_view and not r.ok:
            found.append(
                f"{r.marker.name} is not in the camera's view (at pixel ({r.pixel[0]:.0f}, "
                f"{r.pixel[1]:.0f}) of {rgb.shape[1]} x {rgb.shape[0]})"
            )
        elif not r.ok:
            what = (
                f"change when '{r.marker.toggle}' is hidden"
                if r.marker.toggle is not None
                else f"have colour #{r.marker.color:06x}"
            )
            found.append(
                f"{r.marker.name} not seen at pixel ({r.pixel[0]:.0f}, {r.pixel[1]:.0f}): "
                f"{r.fraction:.0%} of pixels within {r.radius_px:.0f} px {what}, "
                f"need {r.marker.min_fraction:.0%}"
            )
    return found
