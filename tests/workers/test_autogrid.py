"""The default probe grid chosen from the scene (workers/kernels/autogrid.py through the place stage)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.gltf_build import GltfBuilder, box_inward, quad
from tests.workers.test_probes import bake_until
from workers.gltf import ingest_file
from workers.kernels.autogrid import analyze_free_space, choose_grid
from workers.kernels.materials import double_sided_triangles
from workers.raycast import caster_for_scene


def _room(tmp_path, size, name):
    b = GltfBuilder()
    pos, nrm, idx = box_inward([0, 0, 0], size)
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
    b.mesh(pos, idx, normals=nrm, material=m)
    b.point_light([s / 2 for s in size], 50.0)
    tmp_path.mkdir(parents=True, exist_ok=True)
    p = tmp_path / f"{name}.glb"
    p.write_bytes(b.glb())
    return p


def _plan(path):
    s = ingest_file(path)
    fs = analyze_free_space(caster_for_scene(s), s.bounds, double_sided_triangles(s))
    return s, choose_grid(s.bounds, fs)


def test_a_larger_room_gets_more_probes(tmp_path):
    _, (c_small, _, s_small, a_small) = _plan(_room(tmp_path, [4, 3, 4], "small"))
    _, (c_big, _, s_big, a_big) = _plan(_room(tmp_path, [12, 3, 12], "big"))
    assert a_small["kind"] == a_big["kind"] == "enclosed"
    assert np.prod(c_big) > 1.4 * np.prod(c_small)
    # the spacing follows the room scale (a taller, wider room: coarser), never the budget here
    assert 0.1 < s_small[0] < 0.5 and not a_small["budget_bound"] and not a_big["budget_bound"]
    # the grid covers the room
    for c, s in ((c_small, s_small), (c_big, s_big)):
        assert np.all((c - 1) * s >= np.array([4, 3, 4] if c is c_small else [12, 3, 12]) * 0.8)


@pytest.mark.parametrize("scale", [0.01, 100.0])
def test_the_grid_does_not_depend_on_the_unit(tmp_path, scale):
    """A 4 x 3 x 4 m room, and the same room modelled at 1:100 (a tabletop diorama at its real size, 4 x 3 x 4 cm)
    or in centimetres (400 x 300 x 400): the same probe counts, the spacing scaled with it. A floor of 0.05 m gave
    the small one a 4 x 3 x 3 grid (and 1.8x the reference's light in a bake of two-rooms)."""
    _, (c1, o1, s1, a1) = _plan(_room(tmp_path / "one", [4, 3, 4], "room"))
    _, (ck, ok, sk, ak) = _plan(_room(tmp_path / "k", [4 * scale, 3 * scale, 4 * scale], "room"))
    assert np.array_equal(c1, ck), (c1, ck)
    np.testing.assert_allclose(sk, s1 * scale, rtol=1e-4)
    np.testing.assert_allclose(ok, o1 * scale, rtol=1e-4, atol=1e-6 * scale)
    assert ak["samples_per_cell"] == a1["samples_per_cell"] and ak["kind"] == a1["kind"]


def test_a_lone_floor_gets_probes_above_it_not_in_its_plane(tmp_path):
    """A 10 x 10 m ground plane alone (an open lit floor, a flat terrain tile): the box had no extent along y and its
    one layer of probes lay in the plane (a bake under a sun and a sky read 0 in every mode but leaking). The box is
    grown to the room scale along y and the plane lies between two layers."""
    b = GltfBuilder()
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
    p, n, uv, ix = quad([-5, 0, 5], [10, 0, 0], [0, 0, -10], [0, 1, 0])
    b.mesh(p, ix, normals=n, material=m)
    (tmp_path / "floor.glb").write_bytes(b.glb())
    s, (counts, origin, spacing, auto) = _plan(tmp_path / "floor.glb")
    assert auto["kind"] == "open" and "grown to the room scale along y" in auto["reason"]
    layers = origin[1] + spacing[1] * np.arange(counts[1])
    above = layers[layers > 0]
    assert counts[1] >= 4 and spacing[1] > 0
    assert above.max() >= 0.45 * auto["room_scale"]                     # probes up to head height, not 0.2 m
    assert np.abs(layers).min() >= 0.25 * spacing[1]                      # none in the plane
    assert counts[0] == counts[2] and np.prod(counts) <= auto["budget"]


def test_budget_binds_and_says_so(tmp_path):
    s = ingest_file(_room(tmp_path, [12, 3, 12], "big"))
    fs = analyze_free_space(caster_for_scene(s), s.bounds, double_sided_triangles(s))
    counts, _, spacing, auto = choose_grid(s.bounds, fs, budget=500)
    assert np.prod(counts) <= 500 and auto["budget_bound"] and "budget" in auto["reason"]


def test_building_on_a_ground_slab_gets_a_box_around_the_building(tmp_path):
    # a closed 4 x 3 x 4 m building on a 40 x 40 m slab: the grid box is the building's, not the slab's
    b = GltfBuilder()
    pos, nrm, idx = box_inward([0, 0, 0], [4, 3, 4])
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
    b.mesh(pos, idx, normals=nrm, material=m)
    p, n, uv, ix = quad([-18, -0.01, 22], [40, 0, 0], [0, 0, -40], [0, 1, 0])
    b.mesh(p, ix, normals=n, material=m)
    (tmp_path / "slab.glb").write_bytes(b.glb())
    scene, (counts, origin, spacing, auto) = _plan(tmp_path / "slab.glb")
    lo, hi = np.array(auto["box"])
    assert auto["kind"] == "enclosed"
    # the building and a few metres around it (where the slab still sees it), not the 40 m slab
    assert np.all(hi - lo <= [12, 4, 12]) and np.all(lo <= 0.5) and np.all(hi >= [3.5, 2.5, 3.5]), auto["box"]
    assert spacing[0] < 0.5


def test_thin_wall_gets_visibility_samples_on_both_sides(tmp_path, scene_files):
    # two-rooms: a 5 cm shared wall. The automatic S puts samples at most w/2 apart, so every wall cell has
    # samples on both faces of the wall (and some inside it: don't-care)
    scene, (counts, origin, spacing, auto) = _plan(scene_files["two-rooms"])
    w = auto["wall_thickness_p5"]
    assert w is not None and 0.03 < w < 0.08
    S = auto["samples_per_cell"]
    assert spacing[0] / S <= w / 2 + 1e-9, (spacing, S, w)
    # and through the stage: the manifest's grid.auto, the visibility stage's S
    _, out = bake_until(tmp_path, scene_files["two-rooms"], {"trace": {"rays_per_probe": 64}}, "place")
    st = out["place"].stats
    assert st["auto"]["samples_per_cell"] == S and st["counts"] == counts.tolist()
    assert st["probes"] == int(np.prod(counts))


def test_explicit_counts_and_spacing_still_win(tmp_path, scene_files):
    _, out = bake_until(tmp_path / "c", scene_files["two-rooms"], {"place": {"counts": [4, 3, 2]}}, "place")
    assert out["place"].stats["counts"] == [4, 3, 2] and "auto" not in out["place"].stats
    _, out = bake_until(tmp_path / "s", scene_files["two-rooms"], {"place": {"spacing": 1.0}}, "place")
    assert out["place"].stats["spacing"][0] == 1.0 and "auto" not in out["place"].stats


def test_probe_layers_straddle_the_thin_wall(scene_files):
    # two-rooms' shared wall (x 4.00..4.05) lies between two probe layers, not inside one
    _, (counts, origin, spacing, auto) = _plan(scene_files["two-rooms"])
    layers = origin[0] + spacing[0] * np.arange(counts[0])
    gap = np.abs(layers - 4.025).min()
    assert gap > 0.3 * spacing[0], (layers, gap)
    assert auto["layer_score"][0] > 0.5
    # and the grid still covers the box
    lo, hi = np.array(auto["box"])
    assert np.all(origin <= lo + 1e-9) and np.all(origin + spacing * (counts - 1) >= hi - 1e-9)


def test_open_scene_gets_probes_everywhere(scene_files):
    # sealed-box: a closed box on a wide open floor -> "open": the grid spans the floor, not just the box
    s, (counts, origin, spacing, auto) = _plan(scene_files["sealed-box"])
    assert auto["kind"] == "open"
    np.testing.assert_allclose(auto["box"], s.bounds, atol=1e-9)


def test_the_budget_counts_the_whole_box_and_the_record_says_what_free_space_would_allow(tmp_path):
    """A 12 x 3 x 12 m room around a solid 8 x 2 x 8 m block (30% of the box): the budget bounds the whole grid,
    solid included (budget_volume "box"); grid.auto records the free fraction the planning points found and the
    finer spacing that spreading the budget over the free volume alone would give, with its larger probe count."""
    b = GltfBuilder()
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
    pos, nrm, idx = box_inward([0, 0, 0], [12, 3, 12])
    b.mesh(pos, idx, normals=nrm, material=m)
    pos, nrm, idx = box_inward([2, 0.5, 2], [10, 2.5, 10])
    b.mesh(pos, idx[:, [0, 2, 1]], normals=-nrm, material=m)         # the block: outward-facing, a solid
    (tmp_path / "block.glb").write_bytes(b.glb())
    s = ingest_file(tmp_path / "block.glb")
    fs = analyze_free_space(caster_for_scene(s), s.bounds, double_sided_triangles(s))
    counts, _, spacing, auto = choose_grid(s.bounds, fs, budget=500)
    assert auto["budget_bound"] and np.prod(counts) <= 500 and auto["budget_volume"] == "box"
    assert 0.6 < auto["free_fraction"] < 0.8                        # 1 - 128 / 432 = 0.70
    assert auto["spacing_free_volume"] < 0.95 * auto["spacing"] and auto["probes_free_volume"] > 500
    assert "solid" in auto["reason"] and f"{auto['probes_free_volume']} probes" in auto["reason"]
    # a box with no solid in it: the free volume is the box, nothing to add to the reason
    r = ingest_file(_room(tmp_path, [12, 3, 12], "open-room"))
    fs = analyze_free_space(caster_for_scene(r), r.bounds, double_sided_triangles(r))
    _, _, _, a_room = choose_grid(r.bounds, fs, budget=500)
    assert a_room["budget_bound"] and a_room["free_fraction"] > 0.99 and "solid" not in a_room["reason"]


def test_the_default_budget_binding_far_above_the_rooms_is_a_warning(tmp_path):
    """Right by default: where the default budget (24,000) holds the automatic grid far coarser than the rooms ask
    (truck-town, a 2 km town: 25 m where 1.39 m is wanted), the bake says so (``grid_coarse``,
    workers/stages/place.py) with what to do. So does an enclosed scene held above ENCLOSED_COARSE_FACTOR (rooms whose
    walls the light changes faster near than the grid resolves: apartments 2.5x, zdm2 3.0x). A budget the user chose,
    or a grid within the factor of what the rooms ask (an open scene: sealed-box 3.8x, whose light is right), gets no
    warning."""
    from tests.conftest import shared_path
    from workers.gltf.pack import pack_model
    from workers.stages.place import COARSE_FACTOR, ENCLOSED_COARSE_FACTOR, coarse_grid_warning

    auto = {"budget_bound": True, "spacing_wanted": 1.0, "spacing": COARSE_FACTOR * 1.01, "kind": "open"}
    w = coarse_grid_warning(auto, 24000)
    assert w["code"] == "grid_coarse" and "place.box" in w["message"] and "place.budget" in w["message"]
    assert "reads high" not in w["message"]
    assert coarse_grid_warning(auto, 5000) is None                           # the user's own budget
    assert coarse_grid_warning({**auto, "spacing": COARSE_FACTOR * 0.99}, 24000) is None
    assert coarse_grid_warning({**auto, "budget_bound": False}, 24000) is None
    rooms = {**auto, "kind": "enclosed", "spacing": ENCLOSED_COARSE_FACTOR * 1.01}
    w = coarse_grid_warning(rooms, 24000)
    assert w["code"] == "grid_coarse" and "reads high" in w["message"] and "place.budget" in w["message"]
    assert coarse_grid_warning({**rooms, "spacing": ENCLOSED_COARSE_FACTOR * 0.99}, 24000) is None
    assert coarse_grid_warning({**rooms, "kind": "open"}, 24000) is None     # an open scene at 2x: no warning
    town = shared_path("scenes", "truck-town", "town_model.gltf")
    assert pack_model(town, tmp_path / "town.zip")
    _, s = bake_until(tmp_path / "a", tmp_path / "town.zip", {}, "place")
    auto = s["place"].stats["auto"]
    assert auto["budget_bound"] and auto["spacing"] > COARSE_FACTOR * auto["spacing_wanted"]
    assert [w["code"] for w in s["place"].stats["warnings"]] == ["grid_coarse"]
    _, s = bake_until(tmp_path / "b", _room(tmp_path / "room", [4, 3, 4], "room"), {}, "place")
    assert not s["place"].stats["auto"]["budget_bound"] and "warnings" not in s["place"].stats


def test_layer_phase_takes_the_first_phase_of_a_plateau_on_every_float_rounding():
    """The score is piecewise linear in the phase: one thin wall midway gives a plateau of equal scores, which float
    rounding alone used to split (numpy 2.4 moved two-rooms' grid 3 cm). Rounded, the first phase of the plateau
    wins, and perturbing the planes by float noise does not move it."""
    from workers.kernels.autogrid import layer_phase

    s = 0.3
    pos = np.array([1.0, 1.0 + s / 2, 4.0])            # two walls half a spacing apart: a plateau of phases
    w = np.array([1.0, 1.0, 2.0])
    phases = (np.arange(48) + 0.5) / 48 * s
    frac = np.mod(pos[None, :] - phases[:, None], s)
    score = (np.minimum(frac, s - frac) * w).sum(axis=1) / (w.sum() * s / 2)
    plateau = np.flatnonzero(np.isclose(score, score.max(), rtol=0, atol=1e-9))
    assert plateau.size > 1                              # the case in point
    phi, sc = layer_phase(pos, w, s)
    assert phi == pytest.approx(phases[plateau[0]]) and sc == pytest.approx(score.max())
    rng = np.random.default_rng(5)
    for _ in range(20):
        jitter = pos * (1 + rng.uniform(-4e-16, 4e-16, pos.size))
        assert layer_phase(jitter, w, s)[0] == phi


def test_too_many_thin_walls_for_the_budget_keep_the_uniform_grid(scene_files):
    """Step 4b (a layer in front of both faces of every thin wall) gives up where the walls' layers alone would take
    the budget (here 80 thin walls across two-rooms' x at 400 probes): the uniform fit stays, within the budget —
    and at 400 probes with the real two-rooms, one thin wall, the grid turns rectilinear."""
    import dataclasses

    s = ingest_file(scene_files["two-rooms"])
    fs = analyze_free_space(caster_for_scene(s), s.bounds, double_sided_triangles(s))
    c0, _, _, a0 = choose_grid(s.bounds, fs, budget=400)
    assert a0["rectilinear"] and np.prod(c0) <= 400
    w = np.arange(80) * 0.1 + 0.02                                   # 80 walls 2 cm thick, 10 cm apart
    many = (np.concatenate([w, w + 0.02]), np.full(160, 12.0), np.concatenate([-np.ones(80), np.ones(80)]))
    fs2 = dataclasses.replace(fs, planes=(many, fs.planes[1], fs.planes[2]))
    counts, _, _, auto = choose_grid(s.bounds, fs2, budget=400)
    assert not auto["rectilinear"] and "layers" not in auto and np.prod(counts) <= 400
