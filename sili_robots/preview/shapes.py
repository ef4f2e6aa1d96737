"""Small meshcat geometry and material helpers shared by the task scenes.

meshcat-python 0.3.2 has boxes, spheres and cylinders but no flat discs, rings, planes with
UVs or text; these build them as plain three.js ``BufferGeometry`` so the viewer needs nothing
extra. Flat (unlit) materials keep the diagram colours exact, which the visual checks rely on.
"""

from __future__ import annotations

import math

import meshcat.geometry as g
import numpy as np


def rgb_hex(rgb: tuple[float, float, float] | np.ndarray) -> int:
    """0xRRGGBB from an (r, g, b) triple in [0, 1]."""
    r, gr, b = (round(255 * float(np.clip(c, 0.0, 1.0))) for c in rgb[:3])
    return (r << 16) | (gr << 8) | b


def hex_rgb(color: int) -> tuple[int, int, int]:
    """(r, g, b) bytes of 0xRRGGBB."""
    return (color >> 16) & 255, (color >> 8) & 255, color & 255


def css(color: int) -> str:
    return f"#{color:06x}"


def flat(color: int, opacity: float = 1.0) -> g.MeshBasicMaterial:
    """Unlit material: the picture shows exactly this colour."""
    return g.MeshBasicMaterial(color=color, opacity=opacity, transparent=opacity < 1.0)


def shaded(color: int, opacity: float = 1.0) -> g.MeshPhongMaterial:
    """Lit material for solid 3D bodies."""
    return g.MeshPhongMaterial(color=color, opacity=opacity, transparent=opacity < 1.0)


class UVGeometry(g.Geometry):
    """Triangles with texture coordinates (meshcat's TriangularMeshGeometry has none)."""

    def __init__(
        self, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray | None = None
    ) -> None:
        super().__init__()
        self.vertices = np.asarray(vertices, np.float32)
        self.faces = np.asarray(faces, np.uint32)
        self.uvs = None if uvs is None else np.asarray(uvs, np.float32)

    def lower(self, object_data: dict) -> dict:
        attrs = {"position": g.pack_numpy_array(self.vertices.T)}
        if self.uvs is not None:
            attrs["uv"] = g.pack_numpy_array(self.uvs.T)
        return {
            "uuid": self.uuid,
            "type": "BufferGeometry",
            "data": {"attributes": attrs, "index": g.pack_numpy_array(self.faces.T)},
        }


def ring(inner: float, outer: float, segments: int = 96, z: float = 0.0) -> UVGeometry:
    """Flat annulus in the xy-plane (a disc when ``inner`` is 0)."""
    a = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    cos, sin = np.cos(a), np.sin(a)
    if inner <= 0.0:
        verts = np.vstack([[0.0, 0.0, z], np.column_stack([outer * cos, outer * sin, z + 0 * a])])
        faces = [[0, 1 + i, 1 + (i + 1) % segments] for i in range(segments)]
        return UVGeometry(verts, np.array(faces))
    verts = np.vstack(
        [
            np.column_stack([inner * cos, inner * sin, z + 0 * a]),
            np.column_stack([outer * cos, outer * sin, z + 0 * a]),
        ]
    )
    faces = []
    for i in range(segments):
        j = (i + 1) % segments
        faces += [[i, segments + i, segments + j], [i, segments + j, j]]
    return UVGeometry(verts, np.array(faces))


def disc(radius: float, segments: int = 64, z: float = 0.0) -> UVGeometry:
    return ring(0.0, radius, segments, z)


def rectangle(width: float, height: float, z: float = 0.0) -> UVGeometry:
    """Axis-aligned flat rectangle centred at the origin, with UVs (for textures)."""
    w, h = width / 2, height / 2
    verts = np.array([[-w, -h, z], [w, -h, z], [w, h, z], [-w, h, z]])
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
    return UVGeometry(verts, np.array([[0, 1, 2], [0, 2, 3]]), uvs)


def polyline(points: np.ndarray, width: float, z: float = 0.0) -> UVGeometry:
    """A flat strip of ``width`` along a 2D polyline (WebGL draws lines 1 px wide)."""
    pts = np.asarray(points, float)[:, :2]
    d = np.gradient(pts, axis=0)
    n = np.column_stack([-d[:, 1], d[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    left, right = pts + n * width / 2, pts - n * width / 2
    k = len(pts)
    verts = np.vstack(
        [np.column_stack([left, np.full(k, z)]), np.column_stack([right, np.full(k, z)])]
    )
    faces = []
    for i in range(k - 1):
        faces += [[i, k + i, k + i + 1], [i, k + i + 1, i + 1]]
    return UVGeometry(verts, np.array(faces))


class TextTexture(g.Texture):
    """meshcat's viewer draws ``_text`` textures on a 256x256 canvas (black text)."""

    def __init__(self, text: str, font_size: int = 64, font_face: str = "sans-serif") -> None:
        super().__init__()
        self.text = text
        self.font_size = font_size
        self.font_face = font_face

    def lower(self, object_data: dict) -> dict:
        return {
            "uuid": self.uuid,
            "type": "_text",
            "text": self.text,
            "font_size": self.font_size,
            "font_face": self.font_face,
        }


def label(text: str, size: float, font_size: int = 64) -> g.Mesh:
    """A square flat label of side ``size`` in the xy-plane, text centred on it."""
    material = g.MeshBasicMaterial(
        color=0xFFFFFF, map=TextTexture(text, font_size), transparent=True, opacity=1.0
    )
    return g.Mesh(rectangle(size, size), material)
