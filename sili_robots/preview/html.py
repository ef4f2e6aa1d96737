"""A meshcat scene kept in memory and written out as one self-contained HTML file.

meshcat-python's ``Visualizer.static_html()`` asks a running meshcat server for the scene; for
``--out`` and ``--png`` a server process is not needed at all. ``SceneRecorder`` is a drop-in
meshcat window: it lowers every command exactly as ``ViewerWindow.send`` does and keeps the
scene tree exactly as meshcat's server does (same ``meshcat.servers.tree``), so the same scene
code drives a live server (``--serve``) or a file. The file inlines meshcat's ``main.min.js``
(three.js included) like ``static_html()`` does, decodes the commands synchronously (no
``fetch``) and adds a caption synced to the animation timeline and a legend.
"""

from __future__ import annotations

import base64
import html as html_lib
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import meshcat
import umsgpack
from meshcat.servers.tree import SceneTree, find_node

from sili_robots.atomic import write_text
from sili_robots.preview.meshcat_child import scene_messages

VIEWER_JS = Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"


class SceneRecorder:
    """Stands in for ``meshcat.visualizer.ViewerWindow``: collects commands, no server."""

    def __init__(self) -> None:
        self.tree = SceneTree()
        self.animation: bytes | None = None

    def send(self, command: Any) -> None:
        data = command.lower()
        packed = umsgpack.packb(data)
        kind = data["type"]
        path = [p for p in data["path"].split("/") if p]
        if kind == "set_animation":
            self.animation = packed
        elif kind == "set_object":
            node = find_node(self.tree, path)
            node.object = packed
            node.properties = []
        elif kind == "set_transform":
            find_node(self.tree, path).transform = packed
        elif kind == "set_property":
            find_node(self.tree, path).properties.append(packed)
        elif kind == "delete":
            if path:
                parent = find_node(self.tree, path[:-1])
                parent.pop(path[-1], None)
            else:
                self.tree = SceneTree()
        else:
            raise ValueError(f"meshcat command {kind!r} cannot be recorded")

    def commands(self) -> list[bytes]:
        """Packed commands in the order the live server replays a scene (``scene_messages``),
        the animation last."""
        out = scene_messages(self.tree)
        if self.animation is not None:
            out.append(self.animation)
        return out

    def close(self) -> None:
        """Nothing to stop: no server (meshcat's ``Visualizer.close`` calls this)."""


@dataclass
class Overlay:
    """Text shown over the 3D view: a title, a legend and one caption per animation frame."""

    title: str
    legend: Sequence[tuple[str, str]] = ()  # (css colour, label)
    captions: Sequence[str] = ()
    fps: float = 30.0
    extra: dict[str, Any] = field(default_factory=dict)  # exposed as window.previewInfo


#: the line every page written here ends its script with (``sili preview`` replaces only such)
PREVIEW_MARK = "window.previewReady = true;"
TEMPLATE = """<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
body {{ margin: 0; font-family: "DejaVu Sans", sans-serif; }}
#meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
.preview-box {{ position: absolute; left: 8px; pointer-events: none; color: #1a1a1a;
  font-size: 13px; line-height: 1.35; background: rgba(255,255,255,0.82); padding: 3px 8px;
  border-radius: 4px; max-width: calc(100vw - 190px); }}
#preview-overlay {{ top: 6px; }}
#preview-legend {{ bottom: 6px; max-width: calc(100vw - 32px); }}
#preview-overlay .title {{ font-weight: bold; font-size: 14px; }}
.swatch {{ display: inline-block; width: 10px; height: 10px; margin: 0 3px 0 8px;
  border-radius: 2px; }}
.item {{ white-space: nowrap; }}
body.still .preview-box {{ max-width: calc(100vw - 32px); }}
body.still .dg {{ display: none; }}
</style>
</head>
<body>
<div id="meshcat-pane"></div>
<div id="preview-overlay" class="preview-box"><div class="title">{title}</div>
<div id="preview-caption"></div></div>
<div id="preview-legend" class="preview-box">{legend}</div>
<script>
{viewer_js}
</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
window.previewInfo = {info};
(function () {{
  var commands = {commands};
  for (var i = 0; i < commands.length; i++) {{
    var raw = atob(commands[i]);
    var bytes = new Uint8Array(raw.length);
    for (var j = 0; j < raw.length; j++) bytes[j] = raw.charCodeAt(j);
    viewer.handle_command_bytearray(bytes);
  }}
  var captions = {captions};
  var fps = {fps};
  var caption = document.getElementById("preview-caption");
  function frameNow() {{
    var t = viewer.animator.time || 0;
    return Math.max(0, Math.min(captions.length - 1, Math.round(t * fps)));
  }}
  function tick() {{
    if (captions.length) caption.textContent = captions[frameNow()];
    requestAnimationFrame(tick);
  }}
  tick();
  // Show one frame, still (used for pictures): pause, seek, hide the controls.
  window.previewShowFrame = function (frame) {{
    document.body.classList.add("still");
    viewer.animator.pause();
    viewer.animator.seek(frame / fps);
    viewer.animator.display_progress(frame / fps);
    if (captions.length) caption.textContent = captions[frame];
    viewer.set_dirty();
  }};
  {mark}
}})();
</script>
</body>
</html>
"""


def scene_html(recorder: SceneRecorder, overlay: Overlay) -> str:
    """The whole page: meshcat's viewer inlined, the scene's commands, the overlay."""
    commands = [base64.b64encode(c).decode("ascii") for c in recorder.commands()]
    legend = "".join(
        f'<span class="item"><span class="swatch" style="background:{html_lib.escape(c)}">'
        f"</span>{html_lib.escape(label)}</span>"
        for c, label in overlay.legend
    )
    return TEMPLATE.format(
        mark=PREVIEW_MARK,
        title=html_lib.escape(overlay.title),
        legend=legend,
        viewer_js=VIEWER_JS.read_text(encoding="utf-8").replace("</script", "<\\/script"),
        info=_js(overlay.extra),
        commands=_js(commands),
        captions=_js(list(overlay.captions)),
        fps=float(overlay.fps),
    )


def _js(value: Any) -> str:
    """JSON that is safe inside a <script> element."""
    return json.dumps(value).replace("</", "<\\/")


def write_html(recorder: SceneRecorder, overlay: Overlay, out: str | Path) -> Path:
    """Write the page to ``out`` (parent folders created; replaced whole: a failed write keeps
    the page written before) and return its path."""
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, scene_html(recorder, overlay), encoding="utf-8")
    return path
