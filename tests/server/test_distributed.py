"""One bake spread over RQ workers: the visibility field's slabs run as separate jobs that any worker
takes, joined by a final job; 1 worker and 3 workers give bit-identical artifacts."""
from __future__ import annotations

from persist.catalog import Catalog
from tests.conftest import Service

CONFIG = {"place": {"counts": [9, 4, 5], "box": {"min": [0.2, 0.2, 0.2], "max": [7.85, 2.8, 3.8]}},
          "trace": {"rays_per_probe": 64}, "light": {"bounces": 2}, "visibility": {"samples_per_cell": 4, "slabs": 3},
          "evaluate": {"enabled": False}}   # the stages downstream of the split visibility field, not the reference


def _bake(tmp_path, scene, workers: int) -> tuple[dict, dict]:
    svc = Service(tmp_path / f"data{workers}", workers=workers)
    try:
        svc.start_workers()
        c = svc.start_app()
        sid = svc.upload(scene).json()["id"]
        bid = c.post("/v1/bakes", json={"scene_id": sid, "config": CONFIG}).json()["id"]
        b = svc.wait_bake(bid, timeout=180)
        assert b["status"] == "succeeded", b
        pids = {s["name"]: s["pid"] for s in Catalog(svc.data / "kiln.db").get_bake(bid)["stages"]}
        return b, pids
    finally:
        svc.close()


def test_one_and_three_workers_give_identical_artifacts(tmp_path, scene_files):
    one, _ = _bake(tmp_path, scene_files["two-rooms"], 1)
    three, pids = _bake(tmp_path, scene_files["two-rooms"], 3)
    names = [s["name"] for s in three["stages"]]
    i = names.index("visibility")
    assert names[i - 3:i + 1] == ["visibility.0", "visibility.1", "visibility.2", "visibility"]
    a = {x["name"]: x["sha256"] for x in one["artifacts"]}
    b = {x["name"]: x["sha256"] for x in three["artifacts"]}
    assert {"theta_0123", "theta_4567", "dont_care", "irradiance", "depth_moments", "probe_states"} <= set(a)
    assert a == b
    # the slabs were separate jobs (work-horse processes)
    assert len({pids[f"visibility.{i}"] for i in range(3)}) == 3
