"""The node hierarchy: world transforms, the default scene's nodes, instancing, skins and morph targets.

:func:`world_matrices` composes every node's local transform (TRS or a column-major ``matrix``) with its
parents' ([glTF] 3.5.2), refusing cycles and nodes with two parents; :func:`scene_nodes` lists the default
scene's nodes depth first. :func:`instances` expands ``EXT_mesh_gpu_instancing``; :func:`skin_matrices` poses a
skinned primitive at its static pose ([glTF] 3.7.3) and :func:`morphed` applies morph targets at their
default weights ([glTF] 3.7.2.2). Normals follow positions by the cofactor matrix (:func:`cofactor`).
Frames: glTF's (+Y up, right-handed, metres). Consumer: :mod:`workers.gltf.reader`, :mod:`workers.gltf.lights`,
:mod:`workers.gltf.primitives`. Inverse: none.

References
----------
.. [glTF] Khronos, "glTF 2.0 Specification", sections 3.5 (nodes and hierarchy), 3.7.2.2 (morph targets),
   3.7.3 (skins).
.. [EXT_mesh_gpu_instancing] Khronos glTF extension: per-instance TRANSLATION, ROTATION, SCALE.
"""

from __future__ import annotations

import math

import numpy as np

from workers.gltf.accessors import Accessors
from workers.gltf.document import Document, vec
from workers.gltf.errors import invalid

__all__ = ["quat_to_matrix", "cofactor", "normalize_rows", "local_matrix", "world_matrices", "scene_nodes",
           "instances", "morphed", "skin_matrices"]


def quat_to_matrix(q: list[float]) -> np.ndarray:
    """Unit quaternion [x, y, z, w] (glTF order) -> (3, 3) rotation matrix."""
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def cofactor(m: np.ndarray) -> np.ndarray:
    """Cofactor matrices of (..., 3, 3) matrices: ``det(M) * inv(M).T``, defined for singular M too.

    With columns a, b, c of M the cofactor matrix has columns b x c, c x a, a x b. Normals transform
    by ``sign(det) * cofactor`` (proportional to the inverse transpose).
    """
    a, b, c = m[..., :, 0], m[..., :, 1], m[..., :, 2]
    return np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=-1)


def normalize_rows(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors along the last axis and a mask of rows that had a usable (finite, non-zero) length."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = np.isfinite(n[..., 0]) & (n[..., 0] > 1e-30)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(ok[..., None], v / np.where(ok[..., None], n, 1.0), 0.0)
    return out, ok


def local_matrix(node: dict, i: int) -> np.ndarray:
    """(4, 4) float64 local transform of ``nodes[i]``: its ``matrix`` (column-major), else T * R * S ([glTF] 3.5.2)."""
    what = f"nodes[{i}]"
    if "matrix" in node:
        m = np.array(vec(node["matrix"], 16, None, f"{what}.matrix")).reshape(4, 4).T  # column-major
        return m
    t = vec(node.get("translation"), 3, [0, 0, 0], f"{what}.translation")
    q = vec(node.get("rotation"), 4, [0, 0, 0, 1], f"{what}.rotation")
    s = vec(node.get("scale"), 3, [1, 1, 1], f"{what}.scale")
    norm = math.sqrt(sum(x * x for x in q))
    if norm < 1e-12:
        raise invalid(f"{what}.rotation is a zero quaternion")
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix([x / norm for x in q]) * np.array(s)[None, :]
    m[:3, 3] = t
    return m


def world_matrices(doc: Document) -> list[np.ndarray]:
    """(4, 4) float64 world matrix of every node; rejects cycles and nodes with two parents."""
    nodes = doc.array("nodes")
    parent = [-1] * len(nodes)
    for i, node in enumerate(nodes):
        if not isinstance(node, dict):
            raise invalid(f"nodes[{i}] is not an object")
        for c in doc.array("children", node):
            doc.item("nodes", c, f"nodes[{i}].children")
            if parent[c] != -1 or c == i:
                raise invalid(f"nodes[{c}] has more than one parent or is its own child")
            parent[c] = i
    world: list[np.ndarray | None] = [None] * len(nodes)
    for root in (i for i in range(len(nodes)) if parent[i] == -1):
        stack = [(root, np.eye(4))]
        while stack:
            i, pm = stack.pop()
            world[i] = pm @ local_matrix(nodes[i], i)
            stack.extend((c, world[i]) for c in nodes[i].get("children", []))
    if any(w is None for w in world):
        raise invalid("the node hierarchy has a cycle")
    return world  # type: ignore[return-value]


def scene_nodes(doc: Document) -> list[int]:
    """Nodes of the default scene (``scene``, else scene 0, else every root), depth-first pre-order."""
    nodes = doc.array("nodes")
    scenes = doc.array("scenes")
    if scenes:
        s_idx = doc.g.get("scene", 0)
        scene = doc.item("scenes", s_idx, "'scene'")
        roots = doc.array("nodes", scene)
        for r in roots:
            doc.item("nodes", r, f"scenes[{s_idx}].nodes")
    else:
        has_parent = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in has_parent]
    order: list[int] = []
    seen: set[int] = set()
    stack = list(reversed(roots))
    while stack:
        i = stack.pop()
        if i in seen:
            raise invalid(f"nodes[{i}] appears twice in the scene")
        seen.add(i)
        order.append(i)
        stack.extend(reversed(nodes[i].get("children", [])))
    return order


def instances(doc: Document, acc: Accessors, node: dict, i: int, world: np.ndarray) -> np.ndarray:
    """(K, 4, 4) world matrices of a node: its own, or one per EXT_mesh_gpu_instancing instance."""
    inst = doc.exts(node).get("EXT_mesh_gpu_instancing")
    if not isinstance(inst, dict):
        return world[None]
    attrs = inst.get("attributes")
    if not isinstance(attrs, dict) or not attrs:
        raise invalid(f"nodes[{i}] EXT_mesh_gpu_instancing needs attributes")
    what = f"nodes[{i}] EXT_mesh_gpu_instancing"
    arrays = {}
    for key, n in (("TRANSLATION", (3,)), ("ROTATION", (4,)), ("SCALE", (3,))):
        if key in attrs:
            arrays[key] = acc.accessor_float(attrs[key], what, n).astype(np.float64)
    counts = {a.shape[0] for a in arrays.values()}
    if len(counts) != 1:
        raise invalid(f"{what} attributes have different counts")
    k = counts.pop()
    t = arrays.get("TRANSLATION", np.zeros((k, 3)))
    q = arrays.get("ROTATION", np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)))
    s = arrays.get("SCALE", np.ones((k, 3)))
    qn = np.linalg.norm(q, axis=1, keepdims=True)
    if np.any(qn < 1e-12):
        raise invalid(f"{what} has a zero rotation quaternion")
    x, y, z, w = (q / qn).T
    r = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )
    m = np.tile(np.eye(4), (k, 1, 1))
    m[:, :3, :3] = r * s[:, None, :]
    m[:, :3, 3] = t
    return world[None] @ m


def morphed(
    doc: Document, acc: Accessors, prim: dict, base: np.ndarray, key: str, weights: list[float], n_vertices: int,
    sel, what: str
) -> np.ndarray:
    """Attribute ``key`` (already restricted to ``sel``) plus morph deltas at ``weights`` ([glTF] 3.7.2.2)."""
    targets = doc.array("targets", prim)
    if not targets or not any(weights):
        return base
    out = base.astype(np.float64)
    for t, w in zip(targets, weights, strict=True):
        if w and isinstance(t, dict) and key in t:
            out += w * acc.vertex_attr(t[key], n_vertices, sel, out.shape[1], f"{what} morph target {key}")
    return out


def skin_matrices(
    doc: Document, acc: Accessors, node: dict, node_idx: int, prim: dict, world: list[np.ndarray], n_vertices: int,
    sel, what: str
) -> np.ndarray | None:
    """(V, 4, 4) per-vertex skinning matrices at the static pose, or None when not skinned.

    ``sum_k w_k * world(joint_k) @ inverseBind_k`` ([glTF] 3.7.3); the mesh node's own transform
    is ignored, as the spec requires.
    """
    if "skin" not in node:
        return None
    attrs = prim["attributes"]
    if "JOINTS_0" not in attrs or "WEIGHTS_0" not in attrs:
        return None
    skin = doc.item("skins", node["skin"], f"nodes[{node_idx}].skin")
    joints = doc.array("joints", skin)
    if not joints:
        raise invalid(f"skins[{node['skin']}] has no joints")
    for j in joints:
        doc.item("nodes", j, f"skins[{node['skin']}].joints")
    if "inverseBindMatrices" in skin:
        ibm = acc.accessor_float(skin["inverseBindMatrices"], "inverseBindMatrices", (16,)).astype(np.float64)
        if ibm.shape[0] < len(joints):
            raise invalid(f"skins[{node['skin']}] has fewer inverseBindMatrices than joints")
        ibm = ibm[: len(joints)].reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    else:
        ibm = np.tile(np.eye(4), (len(joints), 1, 1))
    joint_m = np.stack([world[j] for j in joints]) @ ibm
    n_used = n_vertices if sel is None else sel.size
    skin_m = np.zeros((n_used, 4, 4))
    total_w = np.zeros(n_used)
    set_i = 0
    while f"JOINTS_{set_i}" in attrs and f"WEIGHTS_{set_i}" in attrs:
        jacc = acc.accessor(attrs[f"JOINTS_{set_i}"], what)
        if jacc.dtype.kind not in "ui" or jacc.shape != (n_vertices, 4):
            raise invalid(f"{what}: JOINTS_{set_i} must be VEC4 unsigned integers, one per vertex")
        wts = acc.vertex_attr(attrs[f"WEIGHTS_{set_i}"], n_vertices, sel, 4, f"{what} WEIGHTS_{set_i}")
        wts = wts.astype(np.float64)
        jidx = (jacc if sel is None else jacc[sel]).astype(np.int64)
        if int(jidx.max()) >= len(joints) or int(jidx.min()) < 0:
            raise invalid(f"{what}: JOINTS_{set_i} refers to a joint the skin does not have")
        for k in range(4):
            skin_m += wts[:, k, None, None] * joint_m[jidx[:, k]]
        total_w += wts.sum(axis=1)
        set_i += 1
    ok = total_w > 1e-12
    skin_m[ok] /= total_w[ok, None, None]
    skin_m[~ok] = world[node_idx]  # unweighted vertices keep the node transform
    return skin_m
