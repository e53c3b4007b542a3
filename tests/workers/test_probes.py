"""Stages relocate and trace on the procedural known-answer scenes, through the real pipeline."""
from __future__ import annotations

import numpy as np
import pytest

from proto.models import BakeConfig
from proto.stages import plan
from persist.store import Store
from workers import pipeline
from workers.gltf import ingest_file
from workers.kernels.grid import ACTIVE, OFF, SLEEPING, base_positions, unpack_atlas
from workers.procedural import BAKE_BOXES
from workers.raycast import RayCaster


def bake_until(tmp_path, scene_path, config: dict, last: str):
    """Run the pipeline up to and including ``last``; returns (scene, {stage: LazyArtifacts})."""
    store = Store(tmp_path / "store")
    scene = ingest_file(scene_path)
    sid = store.put_bytes(scene.to_bytes())
    cfg = BakeConfig.model_validate(config)
    out = {}
    for st, _ in plan(sid, cfg):
        rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
        out[st.name] = pipeline._lazy(store, rec)
        if st.name == last:
            break
    return scene, out


def test_furnace_nothing_moves_depth_is_max_distance(tmp_path, scene_files):
    lo, hi = BAKE_BOXES["furnace"]
    cfg = {"place": {"counts": [3, 3, 3], "box": {"min": lo, "max": hi}}, "scene": {"sky": [1, 1, 1]},
           "trace": {"rays_per_probe": 64}}
    scene, s = bake_until(tmp_path, scene_files["furnace"], cfg, "trace")
    assert s["relocate"].stats["moved"] == 0
    assert np.all(s["relocate"]["probe_offsets"] == 0)
    states = s["trace"]["probe_states"].ravel()
    assert np.all(states == SLEEPING)
    dmax = s["trace"].stats["max_distance"]
    depth = unpack_atlas(s["trace"]["depth_moments_full"], [3, 3, 3], 18)
    assert np.allclose(depth[..., 0], dmax, rtol=1e-5)
    assert np.allclose(depth[..., 1], dmax ** 2, rtol=1e-4)
    # stored: every texel is beyond reach, so each probe's map is its reach, constant (depth_moments.clamp_far)
    stored = unpack_atlas(s["trace"]["depth_moments"], [3, 3, 3], 18).astype(np.float64)
    assert np.all(stored[..., 0] == stored[:, :1, :1, 0]) and np.all(stored[..., 0] < dmax)
    assert s["trace"].stats["depth_clamped_share"] == 1.0
    hits = s["trace"]["ray_hits"]
    assert hits.shape == (27, 64, 4) and np.all(np.isinf(hits[..., 0]))
    assert np.all(s["trace"]["ray_tri"] == -1)


def test_two_rooms_wall_probes_relocate_out_or_off(tmp_path, scene_files):
    # 9 probes along x put the middle column (x = 4.025 m) inside the 5 cm wall
    cfg = {"place": {"counts": [9, 4, 5]}, "trace": {"rays_per_probe": 256}}
    scene, s = bake_until(tmp_path, scene_files["two-rooms"], cfg, "trace")
    place = s["place"].stats
    counts, origin, spacing = place["counts"], np.array(place["origin"]), np.array(place["spacing"])
    base = base_positions(counts, origin, spacing)
    caster = RayCaster(scene.triangles)
    inside_before = caster.inside_parity(base.astype(np.float32))
    assert inside_before.sum() >= 4, "the grid should start with probes inside the wall"
    pos = s["relocate"]["probe_positions_relocated"].reshape(-1, 3)
    off = s["relocate"]["probe_offsets"].reshape(-1, 3)
    assert np.all(np.abs(off) <= 0.45 * spacing + 1e-5)  # within the offset limit
    states = s["trace"]["probe_states"].ravel()
    inside_after = caster.inside_parity(pos.astype(np.float32))
    # every probe that started in the wall now is outside geometry, or OFF
    wall = inside_before & (np.abs(base[:, 0] - 4.025) < 0.03) & (base[:, 1] > 0) & (base[:, 1] < 3)
    assert wall.sum() >= 4
    assert np.all(~inside_after[wall] | (states[wall] == OFF))
    moved_out = wall & ~inside_after
    assert moved_out.sum() >= 2
    # no probe left inside geometry is ACTIVE or SLEEPING
    assert np.all(states[inside_after] == OFF)
    # interior probes see walls within a cell: ACTIVE
    interior = (base[:, 1] > 0.5) & (base[:, 1] < 2.5) & (np.abs(base[:, 0] - 4.025) > 0.5)
    interior &= (base[:, 0] > 0.5) & (base[:, 0] < 7.5) & (base[:, 2] > 0.5) & (base[:, 2] < 3.5)
    assert interior.sum() > 0 and np.all(states[interior] == ACTIVE)


def test_settled_probes_are_not_traced_again_and_change_nothing(tmp_path, scene_files, monkeypatch):
    """The iterations after the first trace only the probes that can still move (kernels/relocation.py
    ``settled``): two-rooms at a grid with probes in its walls and in open air gets the offsets of tracing every
    probe every iteration, bit for bit, from fewer probe traces."""
    from workers.stages import relocate as stage

    cfg = {"place": {"counts": [12, 5, 6]}, "trace": {"rays_per_probe": 128}}
    _, s = bake_until(tmp_path / "a", scene_files["two-rooms"], cfg, "relocate")
    monkeypatch.setattr(stage, "settled", lambda offsets, *a: np.zeros(offsets.shape[0], bool))
    _, every = bake_until(tmp_path / "b", scene_files["two-rooms"], cfg, "relocate")
    P, iters = 12 * 5 * 6, 5
    assert every["relocate"].stats["traced"] == P * iters
    assert s["relocate"].stats["traced"] < 0.8 * P * iters
    assert s["relocate"].stats["moved"] > 0 and s["relocate"].stats["rescued"] > 0    # the rescue ran on both
    np.testing.assert_array_equal(s["relocate"]["probe_offsets"], every["relocate"]["probe_offsets"])
    assert s["relocate"].stats["inside"] == every["relocate"].stats["inside"]


def test_sealed_box_wall_probes_off(tmp_path, scene_files):
    # a grid inside the box's walls: probes at x = ±0.475 (inside the 5 cm walls) and inside the cavity; no
    # relocation (neither the Fig 7 iterations nor the rescue), so the classification alone is tested
    cfg = {"place": {"counts": [3, 3, 3], "box": {"min": [-0.475, 0.025, -0.475], "max": [0.475, 0.975, 0.475]}},
           "trace": {"rays_per_probe": 256, "relocate_iterations": 0, "rescue_offset": 0.0}}
    scene, s = bake_until(tmp_path, scene_files["sealed-box"], cfg, "trace")
    states = s["trace"]["probe_states"].ravel()
    base = base_positions([3, 3, 3], [-0.475, 0.025, -0.475], [0.475, 0.475, 0.475])
    in_wall = np.any(np.abs(np.abs(base - [0, 0.5, 0]) - 0.475) < 1e-6, axis=1)
    assert in_wall.sum() == 26
    assert np.all(states[in_wall] == OFF)
    assert states[~in_wall][0] == ACTIVE  # the centre of the cavity sees its walls within a cell


def test_trace_is_deterministic_and_seeded(tmp_path, scene_files):
    cfg = {"place": {"counts": [4, 3, 3]}, "trace": {"rays_per_probe": 64}}
    _, a = bake_until(tmp_path / "a", scene_files["two-rooms"], cfg, "trace")
    _, b = bake_until(tmp_path / "b", scene_files["two-rooms"], cfg, "trace")
    for name in ("ray_hits", "ray_tri", "ray_directions", "depth_moments", "probe_states"):
        assert np.array_equal(a["trace"][name], b["trace"][name], equal_nan=True)
    _, c = bake_until(tmp_path / "c", scene_files["two-rooms"], {**cfg, "seed": 7}, "trace")
    assert not np.array_equal(a["trace"]["ray_directions"], c["trace"]["ray_directions"])


@pytest.mark.parametrize("sharp", [1.0, 50.0])
def test_depth_moments_of_a_box_interior(tmp_path, scene_files, sharp):
    """From the centre of the sealed cavity (0.9 m wide), distances lie in [0.45, 0.45·√3]."""
    cfg = {"place": {"counts": [1, 1, 1], "box": {"min": [-0.1, 0.4, -0.1], "max": [0.1, 0.6, 0.1]}},
           "trace": {"rays_per_probe": 512, "relocate_iterations": 0, "depth_sharpness": sharp}}
    _, s = bake_until(tmp_path, scene_files["sealed-box"], cfg, "trace")
    depth = unpack_atlas(s["trace"]["depth_moments"], [1, 1, 1], 18)[0, 1:-1, 1:-1]
    assert np.all(depth[..., 0] > 0.44) and np.all(depth[..., 0] < 0.45 * np.sqrt(3) + 1e-3)
    assert np.all(depth[..., 1] >= depth[..., 0] ** 2 - 1e-5)  # E[d²] >= E[d]²


def test_stored_depth_far_clamp_leaves_ddgi_unchanged(tmp_path, scene_files):
    """Issue 17: the stored depth moments (far texels clamped to each probe's reach, workers/kernels/depth_moments.py)
    give the DDGI sampler exactly the irradiance the unclamped moments in the same half floats give, at surface
    points and at free points anywhere in the scene bounds, with view directions of all kinds (a sixth of the
    texels of this coarse grid clamped)."""
    from workers.kernels.ddgi import sample_irradiance
    from workers.kernels.surface_points import area_points

    lo, hi = BAKE_BOXES["two-rooms"]
    cfg = {"place": {"counts": [8, 4, 6], "box": {"min": lo, "max": hi}}, "trace": {"rays_per_probe": 128}}
    scene, s = bake_until(tmp_path, scene_files["two-rooms"], cfg, "light")
    counts = [8, 4, 6]
    place = s["place"].stats
    tr = s["trace"]
    stored = unpack_atlas(tr["depth_moments"], counts, 18)
    unclamped = unpack_atlas(tr["depth_moments_full"], counts, 18).astype(np.float16)
    assert stored.dtype == np.float16 and not np.array_equal(stored, unclamped)
    assert tr.stats["depth_clamped_share"] > 0.1
    irr = unpack_atlas(s["light"]["irradiance"], counts, 10)
    rng = np.random.default_rng(11)
    bounds = np.asarray(s["ingest"].stats["bounds"])
    sp = area_points(scene, 4000, seed=3)
    free = rng.uniform(bounds[0], bounds[1], (8000, 3))
    unit = rng.standard_normal((8000, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    pts = np.concatenate([sp["position"], free])
    nrm = np.concatenate([sp["normal"], unit])
    view = np.concatenate([sp["view"], unit[::-1]])
    args = (pts, nrm, view, counts, place["origin"], place["spacing"],
            s["relocate"]["probe_positions_relocated"].reshape(-1, 3), tr["probe_states"].ravel(), irr)
    got = sample_irradiance(*args, stored.astype(np.float32), 0.3)
    want = sample_irradiance(*args, unclamped.astype(np.float32), 0.3)
    assert np.abs(want).max() > 0 and np.array_equal(got, want)
