"""Reading a skinned character from binary glTF 2.0 (``.glb``) with pygltflib.

trimesh loads glTF geometry but not skins (joints, inverse bind matrices, JOINTS_0 / WEIGHTS_0)
or animations, so this module reads them with pygltflib (a pure-Python glTF reader).  Everything
here is NumPy I/O; the skinning itself is :func:`jaxgfx.skin.linear_blend_skinning`.

glTF skinning (spec 3.7.3): ``v_world = Σ_i w_i G(joint_i) IBM_i v`` with ``G`` the joint's global
node transform and ``IBM`` its inverse bind matrix; the skinned mesh node's own transform is
ignored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "GltfSkin",
    "GltfMesh",
    "load_gltf_skin",
    "load_gltf_meshes",
    "trs_matrix",
    "sample_animation",
    "joint_globals",
    "joint_matrices",
]

_COMPONENT: dict[int, type[np.number[Any]]] = {
    5120: np.int8,
    5121: np.uint8,
    5122: np.int16,
    5123: np.uint16,
    5125: np.uint32,
    5126: np.float32,
}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class GltfSkin(NamedTuple):
    """A skinned mesh, its skeleton and one animation clip (J joints, V vertices)."""

    vertices: np.ndarray  # shape=(V, 3), float32, mesh-space bind positions
    normals: np.ndarray  # shape=(V, 3), float32
    faces: np.ndarray  # shape=(F, 3), int32
    joints: np.ndarray  # shape=(V, 4), int32, indices into the skin's joint list
    weights: np.ndarray  # shape=(V, 4), float32, renormalized to sum to one
    joint_names: tuple  # J names
    parents: np.ndarray  # shape=(J,), int32, parent joint index or -1
    rest_trs: np.ndarray  # shape=(J, 10), float64, local translation (3), quaternion xyzw, scale
    inverse_bind: np.ndarray  # shape=(J, 4, 4), float64
    root_parent: np.ndarray  # shape=(J, 4, 4), float64, global transform of each joint's non-joint
    #   ancestors (identity unless the joint's parent is not a joint, e.g. the armature node)
    anim_times: tuple  # per joint and path ('translation', 'rotation', 'scale'): key times or None
    anim_values: tuple  # the matching key values
    duration: float  # clip length in seconds
    uvs: np.ndarray | None = None  # shape=(V, 2), float32, TEXCOORD of the base colour texture
    texture: np.ndarray | None = None  # shape=(H, W, C), uint8, the base colour texture


class GltfMesh(NamedTuple):
    """One unskinned triangle primitive of a glTF scene, in world space (its node transform)."""

    vertices: np.ndarray  # shape=(V, 3), float32, world positions
    faces: np.ndarray  # shape=(F, 3), int32
    colors: np.ndarray  # shape=(V, 3), float32 in [0, 1]: COLOR_0, else the base colour factor
    name: str  # the node's name
    uvs: np.ndarray | None = None  # shape=(V, 2), float32, TEXCOORD of the base colour texture
    texture: np.ndarray | None = None  # shape=(H, W, C), uint8, the base colour texture


def _read_accessor(gltf, blob: bytes, index: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = np.dtype(_COMPONENT[acc.componentType])
    width = _WIDTH[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    stride = view.byteStride or dtype.itemsize * width
    if stride == dtype.itemsize * width:
        data = np.frombuffer(blob, dtype, acc.count * width, start).reshape(acc.count, width)
    else:
        rows = [np.frombuffer(blob, dtype, width, start + i * stride) for i in range(acc.count)]
        data = np.stack(rows)
    if acc.normalized and np.issubdtype(dtype, np.integer):
        data = data.astype(np.float32) / np.iinfo(dtype).max
    return data


def trs_matrix(trs: np.ndarray) -> np.ndarray:
    """4x4 matrix ``T R S`` of a (10,) translation, quaternion (x, y, z, w), scale."""
    t, q, s = trs[:3], trs[3:7], trs[7:10]
    x, y, z, w = q / np.linalg.norm(q)
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = rot * s[None, :]
    m[:3, 3] = t
    return m


def _node_trs(node) -> np.ndarray:
    if node.matrix is not None:
        raise ValueError("nodes with a matrix instead of TRS are not supported for joints")
    t = node.translation or [0.0, 0.0, 0.0]
    r = node.rotation or [0.0, 0.0, 0.0, 1.0]
    s = node.scale or [1.0, 1.0, 1.0]
    return np.asarray([*t, *r, *s], np.float64)


def _node_matrix(node) -> np.ndarray:
    if node.matrix is not None:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T  # column-major in glTF
    return trs_matrix(_node_trs(node))


def _node_parents(gltf) -> dict[int, int]:
    return {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}


def _node_global(gltf, node_parent: dict[int, int], n: int) -> np.ndarray:
    """Global transform (4, 4) of node ``n`` (identity for ``n == -1``)."""
    m = np.eye(4)
    while n != -1:
        m = _node_matrix(gltf.nodes[n]) @ m
        n = node_parent.get(n, -1)
    return m


def _load_glb(path):
    """(pygltflib document, binary blob) of a ``.glb`` file, with the errors naming ``path``."""
    import pygltflib

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no such file {path}")
    try:
        gltf = pygltflib.GLTF2().load(str(path))
    except Exception as exc:  # pygltflib raises many types for broken files
        raise ValueError(
            f"path: {path} is not a readable glTF: {type(exc).__name__}: {exc}"
        ) from exc
    blob = gltf.binary_blob() if gltf is not None else None
    if blob is None:
        raise ValueError(f"path: {path} has no binary buffer (only .glb is supported)")
    return gltf, blob


def _base_color_texture(gltf, blob: bytes, prim) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(uvs (V, 2), image (H, W, C) uint8)`` of a primitive's base colour texture, or Nones.

    The image is decoded from the ``.glb``'s buffer (PNG or JPEG, by imageio); glTF's UVs
    already count from the image's top-left corner, as :func:`jaxgfx.raster.texture` does.
    """
    if prim.material is None:
        return None, None
    pbr = gltf.materials[prim.material].pbrMetallicRoughness
    info = pbr.baseColorTexture if pbr is not None else None
    if info is None or info.index is None:
        return None, None
    source = gltf.textures[info.index].source
    coord = getattr(prim.attributes, f"TEXCOORD_{info.texCoord or 0}", None)
    if source is None or coord is None:
        return None, None
    image = gltf.images[source]
    if image.bufferView is None:
        return None, None  # an external image file: only what the .glb holds is read
    import imageio.v3 as iio

    view = gltf.bufferViews[image.bufferView]
    start = view.byteOffset or 0
    pixels = np.asarray(iio.imread(blob[start : start + view.byteLength]))
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    uvs = _read_accessor(gltf, blob, coord).astype(np.float32)
    return uvs, pixels.astype(np.uint8)


def load_gltf_meshes(path) -> list[GltfMesh]:
    """Every unskinned triangle primitive of a ``.glb`` placed by its node transform.

    The props that ride along with a character (the Fox's stand); skinned nodes are left out
    (pose them with :func:`load_gltf_skin`).  A primitive is coloured by its ``COLOR_0`` or
    its material's base colour factor (white without a material), times its base colour
    texture where the ``.glb`` holds one (``uvs`` and ``texture``).

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: the file is not a binary glTF.
    """
    gltf, blob = _load_glb(path)
    parents = _node_parents(gltf)
    out = []
    for i, node in enumerate(gltf.nodes):
        if node.mesh is None or node.skin is not None:
            continue
        world = _node_global(gltf, parents, i)
        for prim in gltf.meshes[node.mesh].primitives:
            if prim.mode not in (None, 4) or prim.attributes.POSITION is None:
                continue  # points and lines are not drawn
            v = _read_accessor(gltf, blob, prim.attributes.POSITION).astype(np.float64)
            if prim.indices is None:
                f = np.arange(len(v), dtype=np.int32).reshape(-1, 3)
            else:
                f = _read_accessor(gltf, blob, prim.indices).reshape(-1, 3).astype(np.int32)
            if prim.attributes.COLOR_0 is not None:
                c = _read_accessor(gltf, blob, prim.attributes.COLOR_0)[:, :3].astype(np.float32)
            else:
                base = [1.0, 1.0, 1.0, 1.0]
                if prim.material is not None:
                    pbr = gltf.materials[prim.material].pbrMetallicRoughness
                    base = (pbr.baseColorFactor if pbr is not None else None) or base
                c = np.tile(np.asarray(base[:3], np.float32), (len(v), 1))
            wv = v @ world[:3, :3].T + world[:3, 3]
            uvs, image = _base_color_texture(gltf, blob, prim)
            name = node.name or f"node {i}"
            out.append(GltfMesh(wv.astype(np.float32), f, c, name, uvs, image))
    return out


def load_gltf_skin(path, mesh_index: int | None = None) -> GltfSkin:
    """Read the first skinned mesh (or ``mesh_index``), its skin and its first animation.

    Args:
        path: a ``.glb`` file.
        mesh_index: which mesh to read (default: the first mesh used by a skinned node).

    Returns:
        :class:`GltfSkin`.  Weights are renormalized to sum to one (the glTF spec asks for that
        and exporters round), all other data are as stored; ``uvs`` and ``texture`` are the
        mesh's base colour texture where the ``.glb`` holds one.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: the file has no skinned mesh or the mesh lacks JOINTS_0 / WEIGHTS_0.
    """
    gltf, blob = _load_glb(path)
    skinned = [i for i, n in enumerate(gltf.nodes) if n.skin is not None and n.mesh is not None]
    if not skinned:
        raise ValueError(f"path: {path} has no skinned mesh node")
    node = gltf.nodes[skinned[0]]
    mesh = gltf.meshes[node.mesh if mesh_index is None else mesh_index]
    prim = mesh.primitives[0]
    attrs = prim.attributes
    if attrs.JOINTS_0 is None or attrs.WEIGHTS_0 is None:
        raise ValueError(f"path: mesh {mesh.name!r} has no JOINTS_0 / WEIGHTS_0")
    vertices = _read_accessor(gltf, blob, attrs.POSITION).astype(np.float32)
    normals = _read_accessor(gltf, blob, attrs.NORMAL).astype(np.float32)
    faces = _read_accessor(gltf, blob, prim.indices).reshape(-1, 3).astype(np.int32)
    joints = _read_accessor(gltf, blob, attrs.JOINTS_0).astype(np.int32)
    weights = _read_accessor(gltf, blob, attrs.WEIGHTS_0).astype(np.float64)
    sums = weights.sum(axis=1, keepdims=True)
    if np.any(sums <= 0):
        raise ValueError(f"path: {path} has vertices with all-zero skin weights")
    weights = (weights / sums).astype(np.float32)
    uvs, image = _base_color_texture(gltf, blob, prim)

    skin = gltf.skins[node.skin]
    joint_nodes = list(skin.joints)
    ibm = _read_accessor(gltf, blob, skin.inverseBindMatrices).astype(np.float64)
    ibm = ibm.reshape(-1, 4, 4).transpose(0, 2, 1)  # glTF matrices are column-major
    node_parent = _node_parents(gltf)
    index_of = {n: j for j, n in enumerate(joint_nodes)}
    parents = np.array([index_of.get(node_parent.get(n, -1), -1) for n in joint_nodes], np.int32)
    for j, p in enumerate(parents):
        if p >= j:
            raise ValueError("path: skin joints are not listed parents-first (unsupported)")

    root_parent = np.stack(
        [
            np.eye(4)
            if parents[j] >= 0
            else _node_global(gltf, node_parent, node_parent.get(n, -1))
            for j, n in enumerate(joint_nodes)
        ]
    )
    rest = np.stack([_node_trs(gltf.nodes[n]) for n in joint_nodes])

    times: list[list[np.ndarray | None]] = [[None, None, None] for _ in joint_nodes]
    values: list[list[np.ndarray | None]] = [[None, None, None] for _ in joint_nodes]
    duration = 0.0
    if gltf.animations:
        anim = gltf.animations[0]
        for ch in anim.channels:
            if ch.target.node not in index_of or ch.target.path not in (
                "translation",
                "rotation",
                "scale",
            ):
                continue
            sampler = anim.samplers[ch.sampler]
            k = ("translation", "rotation", "scale").index(ch.target.path)
            j = index_of[ch.target.node]
            t = _read_accessor(gltf, blob, sampler.input)[:, 0].astype(np.float64)
            times[j][k] = t
            values[j][k] = _read_accessor(gltf, blob, sampler.output).astype(np.float64)
            duration = max(duration, float(t[-1]))
    return GltfSkin(
        vertices=vertices,
        normals=normals,
        faces=faces,
        joints=joints,
        weights=weights,
        joint_names=tuple(gltf.nodes[n].name for n in joint_nodes),
        parents=parents,
        rest_trs=rest,
        inverse_bind=ibm,
        root_parent=root_parent,
        anim_times=tuple(tuple(t) for t in times),
        anim_values=tuple(tuple(v) for v in values),
        duration=duration,
        uvs=uvs,
        texture=image,
    )


def _slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    if np.dot(q0, q1) < 0:
        q1 = -q1
    d = np.clip(np.dot(q0, q1), -1.0, 1.0)
    if d > 0.9995:
        q = q0 + t * (q1 - q0)
    else:
        th = np.arccos(d)
        q = (np.sin((1 - t) * th) * q0 + np.sin(t * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


def sample_animation(skin: GltfSkin, time: float) -> np.ndarray:
    """Local TRS (J, 10) of every joint at ``time`` (linear keys, slerp for rotations).

    Joints or paths without a channel keep their rest value; ``time`` is wrapped into the clip.
    """
    out = skin.rest_trs.copy()
    if skin.duration > 0:
        time = float(time) % skin.duration
    for j in range(len(out)):
        for k, sl in enumerate((slice(0, 3), slice(3, 7), slice(7, 10))):
            t = skin.anim_times[j][k]
            if t is None:
                continue
            v = skin.anim_values[j][k]
            i = int(np.clip(np.searchsorted(t, time) - 1, 0, len(t) - 2)) if len(t) > 1 else 0
            if len(t) == 1:
                out[j, sl] = v[0]
                continue
            a = float(np.clip((time - t[i]) / max(t[i + 1] - t[i], 1e-12), 0.0, 1.0))
            out[j, sl] = _slerp(v[i], v[i + 1], a) if k == 1 else (1 - a) * v[i] + a * v[i + 1]
    return out


def joint_globals(skin: GltfSkin, local_trs: np.ndarray) -> np.ndarray:
    """Global transforms (J, 4, 4) of the joints for local TRS (J, 10)."""
    out = np.empty((len(local_trs), 4, 4))
    for j, p in enumerate(skin.parents):
        parent = out[p] if p >= 0 else skin.root_parent[j]
        out[j] = parent @ trs_matrix(local_trs[j])
    return out


def joint_matrices(skin: GltfSkin, local_trs: np.ndarray) -> np.ndarray:
    """Skinning matrices ``G(joint) IBM`` (J, 3, 4) float32 for :func:`~jaxgfx.skin.lbs_vertex`."""
    m = joint_globals(skin, local_trs) @ skin.inverse_bind
    return m[:, :3, :].astype(np.float32)
