"""A compiled MuJoCo model's visual geoms as meshcat objects, and body poses over time.

Everything comes from the model's own arrays: mesh vertices and faces (``mesh_vert``,
``mesh_face``), primitive sizes, geom and material colours (a textured material gets the mean
colour of its texture, since the preview draws no textures). Meshes are simplified by vertex
clustering (``cell`` metres; robosuite's meshes carry ~300k faces, mostly on parts a few
centimetres wide) so the HTML stays small; ``cell=0`` keeps every face. Geoms hang under their
body's node with their fixed offset, so animating a body moves all of its geoms.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import meshcat
import meshcat.geometry as g
import meshcat.transformations as tf
import mujoco
import numpy as np

from sili_robots.preview import shapes

DEFAULT_CELL = 0.004  # m


@dataclass(frozen=True)
class GeomShape:
    """One visual geom ready for meshcat: geometry, colour and pose relative to its body."""

    body_id: int
    name: str
    geometry: g.Geometry
    rgba: tuple[float, float, float, float]
    local: np.ndarray  # 4x4, geom frame in body frame (with any meshcat axis fix-up)


def visual_geom_ids(model: mujoco.MjModel) -> list[int]:
    """Geoms meant to be seen: group 1 (robosuite's visual group), else non-colliding ones."""
    ids = [i for i in range(model.ngeom) if model.geom_group[i] == 1]
    if not ids:
        ids = [
            i
            for i in range(model.ngeom)
            if model.geom_contype[i] == 0 and model.geom_conaffinity[i] == 0
        ]
    return [i for i in ids if geom_rgba(model, i)[3] > 0.0]


def geom_rgba(model: mujoco.MjModel, gid: int) -> tuple[float, float, float, float]:
    """The geom's colour: its material's (times the texture's mean colour), else its own."""
    mat = int(model.geom_matid[gid])
    if mat < 0:
        return tuple(float(c) for c in model.geom_rgba[gid])
    rgba = np.array(model.mat_rgba[mat], float)
    tex = int(np.max(model.mat_texid[mat]))
    if tex >= 0:
        rgba[:3] *= texture_mean(model, tex)
    return tuple(float(c) for c in rgba)


def texture_mean(model: mujoco.MjModel, tex: int) -> np.ndarray:
    """Mean RGB (0..1) of a texture in the model's ``tex_data``."""
    n = int(model.tex_width[tex] * model.tex_height[tex] * model.tex_nchannel[tex])
    start = int(model.tex_adr[tex])
    data = np.asarray(model.tex_data[start : start + n], float).reshape(-1, model.tex_nchannel[tex])
    return data[:, :3].mean(axis=0) / 255.0


def cluster_mesh(
    vertices: np.ndarray, faces: np.ndarray, cell: float
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: merge vertices in the same ``cell``-sized cube, drop faces that
    collapse. Keeps the silhouette of a part to within about one cell."""
    if cell <= 0:
        return vertices, faces
    keys = np.floor(vertices / cell).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(first), 3))
    np.add.at(sums, inverse, vertices)
    counts = np.bincount(inverse, minlength=len(first))[:, None]
    merged = sums / counts
    f = inverse[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, unique = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return merged, f[np.sort(unique)]  # each remaining face once, original winding


def capsule(radius: float, half_length: float, segments: int = 24) -> shapes.UVGeometry:
    """A z-axis capsule as a triangle mesh (meshcat has no capsule)."""
    rings = []
    n_cap = segments // 4
    for k in range(n_cap + 1):  # bottom hemisphere, pole to equator
        phi = -math.pi / 2 + (math.pi / 2) * k / n_cap
        rings.append((radius * math.cos(phi), -half_length + radius * math.sin(phi)))
    for k in range(n_cap + 1):  # top hemisphere, equator to pole
        phi = (math.pi / 2) * k / n_cap
        rings.append((radius * math.cos(phi), half_length + radius * math.sin(phi)))
    a = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    verts = np.array([[r * math.cos(t), r * math.sin(t), z] for r, z in rings for t in a])
    faces = []
    for i in range(len(rings) - 1):
        for j in range(segments):
            p, q = i * segments + j, i * segments + (j + 1) % segments
            faces += [[p, q, q + segments], [p, q + segments, p + segments]]
    return shapes.UVGeometry(verts, np.array(faces))


_Y_TO_Z = tf.rotation_matrix(math.pi / 2, [1, 0, 0])  # meshcat cylinders run along y


def geom_shape(model: mujoco.MjModel, gid: int, cell: float = DEFAULT_CELL) -> GeomShape | None:
    """meshcat geometry for one geom, or None for types a preview does not draw."""
    kind = mujoco.mjtGeom(model.geom_type[gid])
    size = model.geom_size[gid]
    local = tf.quaternion_matrix(model.geom_quat[gid])
    local[:3, 3] = model.geom_pos[gid]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mid = int(model.geom_dataid[gid])
        v0, nv = int(model.mesh_vertadr[mid]), int(model.mesh_vertnum[mid])
        f0, nf = int(model.mesh_faceadr[mid]), int(model.mesh_facenum[mid])
        verts, faces = cluster_mesh(
            np.asarray(model.mesh_vert[v0 : v0 + nv], float),
            np.asarray(model.mesh_face[f0 : f0 + nf], np.int64),
            cell,
        )
        geometry: g.Geometry = g.TriangularMeshGeometry(verts, faces)
    elif kind == mujoco.mjtGeom.mjGEOM_BOX:
        geometry = g.Box((2 * size).tolist())
    elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        geometry = g.Sphere(float(size[0]))
    elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        geometry = g.Ellipsoid(size.tolist())
    elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        geometry = g.Cylinder(2 * float(size[1]), float(size[0]))
        local = local @ _Y_TO_Z
    elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        geometry = capsule(float(size[0]), float(size[1]))
    elif kind == mujoco.mjtGeom.mjGEOM_PLANE:
        half_x = float(size[0]) if size[0] > 0 else 10.0
        half_y = float(size[1]) if size[1] > 0 else 10.0
        geometry = shapes.rectangle(2 * half_x, 2 * half_y)
    else:
        return None
    return GeomShape(
        int(model.geom_bodyid[gid]),
        model.geom(gid).name or f"geom{gid}",
        geometry,
        geom_rgba(model, gid),
        local,
    )


def draw_geoms(
    vis: meshcat.Visualizer,
    model: mujoco.MjModel,
    group_of: Callable[[str], str],
    cell: float = DEFAULT_CELL,
) -> dict[int, meshcat.Visualizer]:
    """Create every visual geom under ``vis[group_of(body name)/body name]``; return the body
    nodes by body id (animate those)."""
    nodes: dict[int, meshcat.Visualizer] = {}
    for gid in visual_geom_ids(model):
        shape = geom_shape(model, gid, cell)
        if shape is None:
            continue
        body = model.body(shape.body_id).name or f"body{shape.body_id}"
        node = nodes.get(shape.body_id)
        if node is None:
            node = nodes[shape.body_id] = vis[f"{group_of(body)}/{body}"]
        r, gr, b, a = shape.rgba
        material = shapes.shaded(shapes.rgb_hex((r, gr, b)), opacity=a)
        node[f"{gid:03d}"].set_object(shape.geometry, material)
        node[f"{gid:03d}"].set_transform(shape.local)
    return nodes


def body_poses(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """World poses (F x nbody x 4 x 4) of every body for each row of ``qpos``, computed on a
    private ``MjData`` (the simulation's own data is never touched)."""
    data = mujoco.MjData(model)
    out = np.zeros((len(qpos), model.nbody, 4, 4))
    for f, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        out[f, :, :3, :3] = data.xmat.reshape(-1, 3, 3)
        out[f, :, :3, 3] = data.xpos
        out[f, :, 3, 3] = 1.0
    return out
