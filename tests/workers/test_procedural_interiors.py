"""The held-out interiors of the fidelity benchmark (workers/procedural_interiors.py): closed solids, the rooms and
lights the module doc states, kept out of the scene lists the other tests iterate."""
from __future__ import annotations

import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from workers.gltf import ingest_file
from workers.procedural import ALL_SCENES
from workers.procedural_interiors import CONFIGS, INTERIOR_SCENES, make_interior
from workers.raycast import caster_for_scene


def _ingest(name: str):
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / f"{name}.glb"
        p.write_bytes(make_interior(name))
        return ingest_file(p)


def test_kept_out_of_the_procedural_scene_lists():
    assert set(INTERIOR_SCENES) == {"rooms-unequal", "sun-window", "corridor-l", "thick-wall", "plane-wall",
                                     "two-storey", "apartments", "open-floor"}
    assert not set(INTERIOR_SCENES) & set(ALL_SCENES)
    assert set(CONFIGS) <= set(INTERIOR_SCENES)
    with pytest.raises(ValueError, match="unknown interior"):
        make_interior("two-rooms")


@pytest.mark.parametrize("name", sorted(INTERIOR_SCENES))
def test_closed_deterministic_and_lit(name):
    assert make_interior(name) == make_interior(name)
    sc = _ingest(name)
    assert not sc.warnings
    double = np.array([bool(m.get("double_sided")) for m in sc.materials])[np.asarray(sc.material)]
    assert double.any() == (name == "plane-wall")          # plane-wall's divider: one double-sided plane
    tris = np.round(np.asarray(sc.triangles, np.float64)[~double], 6)
    edges = Counter((tuple(t[a]), tuple(t[b])) for t in tris for a, b in ((0, 1), (1, 2), (2, 0)))
    # watertight and consistently oriented: every directed edge once, its reverse once (open-floor: one lone quad,
    # a surface without an inside, facing up)
    if name == "open-floor":
        assert len(tris) == 2 and np.allclose(tris[:, :, 1], 0.0) and (face_up(tris) > 0).all()
    else:
        assert all(n == 1 and edges.get((b, a)) == 1 for (a, b), n in edges.items())
    assert len(sc.lights) == 1


def face_up(tris):
    return np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, 1]


# a point in each room, the light's room first: the rooms are joined only through their door
ROOMS = {"rooms-unequal": [(3.0, 1.5, 2.5), (7.5, 1.3, 1.5)], "thick-wall": [(2.0, 1.5, 2.0), (6.4, 1.5, 2.0)],
         "sun-window": [(2.5, 1.5, 2.0), (6.8, 1.5, 2.0)], "plane-wall": [(2.0, 1.5, 2.0), (6.3, 1.4, 2.0)],
         # upstairs, and downstairs under the stairwell's edge (the slab hides the lamp)
         "two-storey": [(2.5, 3.8, 2.0), (4.4, 2.0, 0.8)],
         # the lit room (2, 1, 1) and the dark one through the door beside it (3, 1, 1)
         "apartments": [(10.3, 4.4, 6.2), (14.4, 4.4, 5.2)]}


@pytest.mark.parametrize("name", sorted(ROOMS))
def test_the_dark_room_sees_no_light_directly(name):
    sc = _ingest(name)
    caster = caster_for_scene(sc)
    dark = np.asarray([ROOMS[name][1]], np.float64)
    lt = sc.lights[0]
    if lt["type"] == "point":
        to = np.asarray(lt["position"], np.float64) - dark[0]
        hit = caster.intersect(dark, to[None] / np.linalg.norm(to))
        assert hit.t[0] < np.linalg.norm(to)            # the shared wall is in the way
    else:
        d = -np.asarray(lt["direction"], np.float64)
        assert caster.occluded(dark, (d / np.linalg.norm(d))[None])[0]
    assert not caster.inside_parity(np.asarray(ROOMS[name], np.float64)).any()
