"""Does a rendered preview show what the scene says it shows? Checked like a person would.

The picture must not be blank (a meshcat page with an empty scene is just the background), and
each of the scene's ``Marker``s in the camera's view must be visible: around the pixel where the
page's own camera projects the marker's world point, enough pixels have the marker's colour
(or change when its body is hidden), in the picture or, for a marker that may be behind another
body, with that body hidden. An empty scene, a scene drawn in the wrong place or a page that
failed to load fails the same test; so does a picture in which no marker is in view.
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
    #: the point projects into the picture; one outside the camera's view is not asked for
    in_view: bool = True

    @property
    def ok(self) -> bool:
        return not self.in_view or self.fraction >= self.marker.min_fraction


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
        r = max(2.0, float(np.hypot(e[0] - c[0], e[1] - c[1])))
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
    results = results_or_none or []
    if results and not any(r.in_view for r in results):
        found.append(f"no scene element is in the camera's view ({len(results)} looked for)")
    for r in results:
        if not r.ok:
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
