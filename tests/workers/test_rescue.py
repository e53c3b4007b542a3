"""Probes stuck in walls (workers/kernels/relocation.py ``rescue``, stage relocate), through the real pipeline.

The scene: a 4 x 3 x 4 m room carved out of a solid block (an outward-facing box from -8 to 12 m around an
inward-facing room box): everything between the two boxes is solid, every ray from there hits a back face. A grid of
1 m spacing puts a column of probes 0.5 m inside the room's x = 0 wall (DDGI-P §5's limit of 0.45 spacing cannot get
them out), one 1.5 m inside it and two deeper. And two-rooms at 8 x 8 x 8, whose outer layer sits on the exterior
walls' outer faces.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.gltf_build import GltfBuilder, box_inward
from tests.workers.test_probes import bake_until
from workers.kernels.grid import OFF, base_positions
from workers.raycast import RayCaster

ROOM = ([0.0, 0.0, 0.0], [4.0, 3.0, 4.0])
# probes at x = -3.5 .. 1.5 (1 m apart), y = 0.5 .. 2.5, z = 0.5 .. 3.5
GRID = {"counts": [6, 3, 4], "box": {"min": [-3.5, 0.5, 0.5], "max": [1.5, 2.5, 3.5]}}


@pytest.fixture(scope="module")
def carved_room(tmp_path_factory):
    b = GltfBuilder()
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
    pos, nrm, idx = box_inward(*ROOM)
    b.mesh(pos, idx, normals=nrm, material=m)
    pos, nrm, idx = box_inward([-8.0, -5.0, -8.0], [12.0, 8.0, 12.0])
    b.mesh(pos, idx[:, [0, 2, 1]], normals=-nrm, material=m)        # the block's outside: outward-facing
    b.point_light([2.0, 2.5, 2.0], 20.0)
    path = tmp_path_factory.mktemp("rescue") / "carved.glb"
    path.write_bytes(b.glb())
    return path


def _bake(tmp_path, path, **trace):
    scene, s = bake_until(tmp_path, path, {"place": GRID, "trace": {"rays_per_probe": 128, **trace}}, "trace")
    place = s["place"].stats
    spacing = np.asarray(place["spacing"])
    base = base_positions(place["counts"], place["origin"], spacing)
    pos = np.asarray(s["relocate"]["probe_positions_relocated"], np.float64).reshape(-1, 3)
    states = np.asarray(s["trace"]["probe_states"]).ravel()
    return scene, s, spacing, base, pos, states


def test_a_probe_in_a_thick_wall_next_to_a_room_moves_into_the_room(tmp_path, carved_room):
    scene, s, spacing, base, pos, states = _bake(tmp_path, carved_room)
    np.testing.assert_allclose(spacing, [1.0, 1.0, 1.0])
    wall = np.isclose(base[:, 0], -0.5)
    assert wall.sum() == 12
    caster = RayCaster(scene.triangles)
    assert np.all(caster.inside_parity(base[wall].astype(np.float32), n_dirs=5))      # they start in the wall
    # relocated into the room, not OFF: inside its box, clear of the wall they left (0.1 x spacing)
    assert np.all(states[wall] != OFF)
    lo, hi = np.asarray(ROOM[0]), np.asarray(ROOM[1])
    assert np.all((pos[wall] > lo) & (pos[wall] < hi))
    assert np.all(pos[wall, 0] >= 0.1 - 1e-4)
    assert not np.any(caster.inside_parity(pos[wall].astype(np.float32), n_dirs=5))
    # the nearest free space: through the x = 0 face (0.5 m away), not across the room
    assert np.all(pos[wall, 0] < 0.2)
    off = pos - base
    assert np.all(np.abs(off) <= 0.95 * spacing + 1e-6)                     # within the rescue limit
    assert s["relocate"].stats["rescued"] == 12 and s["relocate"].stats["inside"] >= 12
    # the room's own probes are live and did not take a rescue step
    room = base[:, 0] > 0
    assert np.all(states[room] != OFF) and np.all(np.abs(off[room]) <= 0.45 * spacing + 1e-6)


def test_probes_deep_inside_the_solid_stay_off(tmp_path, carved_room):
    _, s, spacing, base, pos, states = _bake(tmp_path, carved_room)
    deep = base[:, 0] <= -1.5                # 1.5 m or more from any free space: nothing within its 8 cells
    assert deep.sum() == 36
    assert np.all(states[deep] == OFF)
    np.testing.assert_array_equal(pos[deep], base[deep])                     # not moved


def test_without_the_rescue_the_wall_probes_are_off(tmp_path, carved_room):
    """DDGI-P §5 alone (``rescue_offset = 0``): 0.5 m deep is beyond its 0.45 m reach, so the column is OFF."""
    _, s, spacing, base, pos, states = _bake(tmp_path, carved_room, rescue_offset=0.0)
    wall = np.isclose(base[:, 0], -0.5)
    assert np.all(states[wall] == OFF)
    assert s["relocate"].stats["rescued"] == 0
