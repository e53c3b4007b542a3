"""``GET /v1/compare`` (server/api/routes/compare.py) on a catalog with hand-made bakes.

The route reads only the catalog (bake records, their manifests' evaluate stats, the metrics table), so the
test builds a minimal app — the router, the error handlers, a catalog and API-key settings — with no Redis
or workers; the full service includes the router once the lead adds it to server/main.py.
"""
from __future__ import annotations

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from persist.catalog import Catalog
from persist.store import Store
from server.api import errors
from server.api.routes import compare
from server.config import Settings

KEYS = "teama:key-aaaaaaaa,teamb:key-bbbbbbbb"
A = {"Authorization": "Bearer key-aaaaaaaa"}
B = {"Authorization": "Bearer key-bbbbbbbb"}


def _bake(cat: Catalog, team: str, metrics: dict | None, seconds: float = 1.0) -> str:
    bid = cat.create_bake(team, "scene1", {}, [("ingest", "k1")])
    stages = [{"name": "ingest", "seconds": seconds, "cached": False, "cache_key": "k1", "stats": {}}]
    if metrics is not None:
        stages.append({"name": "evaluate", "seconds": 2.0, "cached": False, "cache_key": "k2",
                       "stats": {"metrics": metrics, "modes": ["leaking", "mask"]}})
    cat.set_bake_status(bid, "succeeded", manifest={"stages": stages, "artifacts": []})
    cat.set_metrics(bid, {"stage_seconds.ingest": seconds, "artifact_bytes": 1000.0})
    return bid


@pytest.fixture
def client(tmp_path):
    app = FastAPI()
    errors.install(app)
    app.state.settings = Settings(data=tmp_path, api_keys=KEYS)
    app.state.catalog = Catalog(tmp_path / "kiln.db")
    app.state.store = Store(tmp_path / "store")
    app.include_router(compare.router)
    with TestClient(app) as c:
        yield c


def test_compare_deltas_and_errors(client):
    cat = client.app.state.catalog
    a = _bake(cat, "teama", {"leaking.rmse": 0.2, "mask.rmse": 0.05, "mask.pass_ms": 2.0, "leaking.leak": 0.5})
    b = _bake(cat, "teama", {"leaking.rmse": 0.2, "mask.rmse": 0.04, "mask.pass_ms": 3.0, "ddgi.rmse": 0.06},
              seconds=3.0)
    r = client.get(f"/v1/compare?a={a}&b={b}", headers=A)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["a"]["id"] == a and body["b"]["id"] == b
    m = body["metrics"]
    assert m["mask.rmse"]["delta"] == pytest.approx(-0.01) and m["mask.rmse"]["ratio"] == pytest.approx(0.8)
    assert m["mask.pass_ms"] == {"a": 2.0, "b": 3.0, "delta": 1.0, "ratio": 1.5, "delta_stderr": None}
    # hand-made bakes have no reference stage on record: no paired standard errors, and the reason why
    assert body["paired"]["paired"] is False and "reference" in body["paired"]["reason"]
    assert m["leaking.rmse"]["delta"] == 0
    assert m["stage_seconds.ingest"]["delta"] == pytest.approx(2.0)     # catalog metrics too
    assert body["only_a"] == ["leaking.leak"] and body["only_b"] == ["ddgi.rmse"]

    # another team's bake and unknown bakes: 404; a bake without evaluate metrics: 409; missing param: 422
    other = _bake(cat, "teamb", {"mask.rmse": 0.1})
    r = client.get(f"/v1/compare?a={a}&b={other}", headers=A)
    assert r.status_code == 404 and r.json()["error"]["code"] == "bake_not_found"
    assert client.get(f"/v1/compare?a=nope&b={b}", headers=A).status_code == 404
    plain = _bake(cat, "teama", None)
    r = client.get(f"/v1/compare?a={a}&b={plain}", headers=A)
    assert r.status_code == 409 and r.json()["error"]["code"] == "no_metrics"
    assert client.get(f"/v1/compare?a={a}", headers=A).status_code == 422
    assert client.get(f"/v1/compare?a={a}&b={b}").status_code == 401
    r = client.get(f"/v1/compare?a={other}&b={other}", headers=B)
    assert r.status_code == 200 and r.json()["metrics"]["mask.rmse"]["delta"] == 0
