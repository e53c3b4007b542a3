"""The catalog: scenes, bakes, stage runs and metrics in one SQLite file.

Both the API process and the workers write it (WAL mode, a busy timeout), so it lives
beside the store in ``persist/`` rather than in ``server/``. Redis holds the queue and live
progress only; everything a user must not lose is here and survives restarts of the
server, the workers and Redis.

Times are UNIX seconds (float, UTC). JSON columns hold UTF-8 JSON text.
"""
from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

BAKE_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")
TERMINAL = ("succeeded", "failed", "cancelled")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS scenes (
    team      TEXT NOT NULL,
    id        TEXT NOT NULL,
    created   REAL NOT NULL,
    filename  TEXT,
    summary   TEXT NOT NULL,
    PRIMARY KEY (team, id)
);
CREATE TABLE IF NOT EXISTS bakes (
    id        TEXT PRIMARY KEY,
    team      TEXT NOT NULL,
    scene_id  TEXT NOT NULL,
    config    TEXT NOT NULL,
    status    TEXT NOT NULL,
    created   REAL NOT NULL,
    started   REAL,
    finished  REAL,
    error     TEXT,
    manifest  TEXT,
    attempt   INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS bakes_team_scene ON bakes (team, scene_id, created);
CREATE INDEX IF NOT EXISTS bakes_status ON bakes (status);
CREATE TABLE IF NOT EXISTS stage_runs (
    bake_id   TEXT NOT NULL,
    stage     TEXT NOT NULL,
    ord       INTEGER NOT NULL,
    cache_key TEXT NOT NULL,
    status    TEXT NOT NULL,
    progress  REAL NOT NULL DEFAULT 0,
    seconds   REAL,
    cached    INTEGER NOT NULL DEFAULT 0,
    stats     TEXT,
    pid       INTEGER,
    started   REAL,
    finished  REAL,
    PRIMARY KEY (bake_id, stage)
);
CREATE TABLE IF NOT EXISTS metrics (
    bake_id   TEXT NOT NULL,
    name      TEXT NOT NULL,
    value     REAL NOT NULL,
    PRIMARY KEY (bake_id, name)
);
"""


class Catalog:
    """Thin data access over SQLite. Every write opens its own short transaction.

    Reads reuse one connection per thread and process (autocommit: each statement sees the latest
    commit). Opening a connection costs more than a bake's reads (0.5 ms of a 0.9 ms ``get_bake``),
    and the API's request threads live long. A connection is never used across a fork.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()
        with self._read() as c:
            c.execute("PRAGMA journal_mode=WAL")
            c.executescript(_SCHEMA)

    @contextmanager
    def _conn(self) -> Iterator[sqlite3.Connection]:
        c = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
        c.row_factory = sqlite3.Row
        c.execute("PRAGMA busy_timeout=30000")
        c.execute("PRAGMA synchronous=NORMAL")
        try:
            c.execute("BEGIN IMMEDIATE")
            yield c
            c.execute("COMMIT")
        except BaseException:
            if c.in_transaction:
                c.execute("ROLLBACK")
            raise
        finally:
            c.close()

    @contextmanager
    def _read(self) -> Iterator[sqlite3.Connection]:
        c = getattr(self._local, "conn", None)
        if c is None or self._local.pid != os.getpid():
            c = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
            c.row_factory = sqlite3.Row
            c.execute("PRAGMA busy_timeout=30000")
            self._local.conn, self._local.pid = c, os.getpid()
        try:
            yield c
        except sqlite3.Error:
            self._local.conn = None     # a broken connection is not reused (the file replaced, say)
            c.close()
            raise

    # ------------------------------------------------------------------ scenes
    def add_scene(self, team: str, scene_id: str, summary: dict, filename: str | None) -> bool:
        """Record a scene for a team; returns False when the team already had it."""
        with self._conn() as c:
            cur = c.execute(
                "INSERT OR IGNORE INTO scenes (team, id, created, filename, summary) VALUES (?,?,?,?,?)",
                (team, scene_id, time.time(), filename, json.dumps(summary)),
            )
            return cur.rowcount == 1

    def get_scene(self, team: str, scene_id: str) -> dict | None:
        with self._read() as c:
            r = c.execute("SELECT * FROM scenes WHERE team=? AND id=?", (team, scene_id)).fetchone()
        return _scene(r) if r else None

    def list_scenes(self, team: str, limit: int, offset: int) -> tuple[list[dict], int]:
        with self._read() as c:
            rows = c.execute("SELECT * FROM scenes WHERE team=? ORDER BY created DESC, id LIMIT ? OFFSET ?",
                             (team, limit, offset)).fetchall()
            total = c.execute("SELECT COUNT(*) FROM scenes WHERE team=?", (team,)).fetchone()[0]
        return [_scene(r) for r in rows], total

    def delete_scene(self, team: str, scene_id: str) -> bool:
        with self._conn() as c:
            return c.execute("DELETE FROM scenes WHERE team=? AND id=?", (team, scene_id)).rowcount == 1

    def scene_referenced(self, scene_id: str) -> bool:
        """True when any team still has the scene (its blob must stay)."""
        with self._read() as c:
            return c.execute("SELECT 1 FROM scenes WHERE id=? LIMIT 1", (scene_id,)).fetchone() is not None

    def _set_summary_field(self, team: str, scene_id: str, field: str, value) -> bool:
        """Set (or, with ``None``, remove) ``summary.<field>`` of a team's scene; False when it has no such scene."""
        with self._conn() as c:
            if value is None:
                cur = c.execute(f"UPDATE scenes SET summary=json_remove(summary, '$.{field}') "
                                "WHERE team=? AND id=?", (team, scene_id))
            else:
                cur = c.execute(f"UPDATE scenes SET summary=json_set(summary, '$.{field}', json(?)) "
                                "WHERE team=? AND id=?", (json.dumps(value), team, scene_id))
            return cur.rowcount == 1

    def set_scene_cameras(self, team: str, scene_id: str, cameras: list[dict] | None) -> bool:
        """Store a scene's review cameras (``summary.review_cameras``; ``None`` removes them); False when the team
        has no such scene. The evaluate stage of the scene's later bakes uses them (server/api/routes/review.py)."""
        return self._set_summary_field(team, scene_id, "review_cameras", cameras)

    def set_scene_thresholds(self, team: str, scene_id: str, thresholds: list[str] | None) -> bool:
        """Store a scene's quality thresholds (``summary.thresholds``, gates of server/gates.py; ``None`` removes
        them); False when the team has no such scene (server/api/routes/thresholds.py)."""
        return self._set_summary_field(team, scene_id, "thresholds", thresholds)

    # ------------------------------------------------------------------ bakes
    def create_bake(self, team: str, scene_id: str, config: dict, stages: list[tuple[str, str]]) -> str:
        """Create a queued bake with its planned stages ``[(name, cache_key), ...]``; returns its id."""
        bake_id = uuid.uuid4().hex
        now = time.time()
        with self._conn() as c:
            c.execute("INSERT INTO bakes (id, team, scene_id, config, status, created) VALUES (?,?,?,?,?,?)",
                      (bake_id, team, scene_id, json.dumps(config), "queued", now))
            c.executemany(
                "INSERT INTO stage_runs (bake_id, stage, ord, cache_key, status) VALUES (?,?,?,?,?)",
                [(bake_id, name, i, key, "pending") for i, (name, key) in enumerate(stages)],
            )
        return bake_id

    def get_bake(self, bake_id: str, team: str | None = None) -> dict | None:
        with self._read() as c:
            if team is None:
                r = c.execute("SELECT * FROM bakes WHERE id=?", (bake_id,)).fetchone()
            else:
                r = c.execute("SELECT * FROM bakes WHERE id=? AND team=?", (bake_id, team)).fetchone()
            if r is None:
                return None
            stages = c.execute("SELECT * FROM stage_runs WHERE bake_id=? ORDER BY ord", (bake_id,)).fetchall()
            metrics = c.execute("SELECT name, value FROM metrics WHERE bake_id=?", (bake_id,)).fetchall()
        bake = _bake(r)
        bake["stages"] = [_stage(s) for s in stages]
        bake["metrics"] = {m["name"]: m["value"] for m in metrics}
        return bake

    def list_bakes(self, team: str, scene_id: str | None, status: str | None,
                   limit: int, offset: int) -> tuple[list[dict], int]:
        where, args = ["team=?"], [team]
        if scene_id:
            where.append("scene_id=?")
            args.append(scene_id)
        if status:
            where.append("status=?")
            args.append(status)
        w = " AND ".join(where)
        with self._read() as c:
            rows = c.execute(f"SELECT * FROM bakes WHERE {w} ORDER BY created DESC, id LIMIT ? OFFSET ?",
                             (*args, limit, offset)).fetchall()
            total = c.execute(f"SELECT COUNT(*) FROM bakes WHERE {w}", args).fetchone()[0]
        return [_bake(r) for r in rows], total

    def bakes_with_status(self, statuses: tuple[str, ...]) -> list[dict]:
        q = ",".join("?" * len(statuses))
        with self._read() as c:
            rows = c.execute(f"SELECT * FROM bakes WHERE status IN ({q}) ORDER BY created", statuses).fetchall()
        return [_bake(r) for r in rows]

    def count_bakes_by_status(self, team: str | None = None) -> dict[str, int]:
        """Bakes per status, of one team or (``None``) of all."""
        with self._read() as c:
            if team is None:
                rows = c.execute("SELECT status, COUNT(*) FROM bakes GROUP BY status").fetchall()
            else:
                rows = c.execute("SELECT status, COUNT(*) FROM bakes WHERE team=? GROUP BY status",
                                 (team,)).fetchall()
        out = {s: 0 for s in BAKE_STATUSES}
        out.update({r[0]: r[1] for r in rows})
        return out

    def stage_durations(self, team: str | None = None) -> list[tuple[str, float]]:
        """(stage, seconds) of the stages that ran (not cached), of one team's bakes or (``None``) all."""
        q = ("SELECT s.stage, s.seconds FROM stage_runs s JOIN bakes b ON b.id = s.bake_id WHERE s.status='succeeded' "
             "AND s.cached=0 AND s.seconds IS NOT NULL")
        with self._read() as c:
            rows = (c.execute(q).fetchall() if team is None else
                    c.execute(q + " AND b.team=?", (team,)).fetchall())
        return [(r[0], r[1]) for r in rows]

    def team_usage(self, team: str) -> dict[str, int]:
        """What a team holds, for its quotas: ``scenes``, ``scene_bytes`` (the normalized scenes' sizes;
        scenes stored before sizes were recorded count 0 and are listed in ``unsized``), ``artifact_bytes`` (the
        bundles of its succeeded bakes) and ``active_bakes`` (queued or running)."""
        with self._read() as c:
            n, nbytes = c.execute("SELECT COUNT(*), COALESCE(SUM(json_extract(summary, '$.bytes')), 0) FROM scenes "
                                  "WHERE team=?", (team,)).fetchone()
            unsized = [r[0] for r in c.execute("SELECT id FROM scenes WHERE team=? AND "
                                               "json_extract(summary, '$.bytes') IS NULL", (team,)).fetchall()]
            art = c.execute("SELECT COALESCE(SUM(m.value), 0) FROM metrics m JOIN bakes b ON b.id = m.bake_id "
                            "WHERE b.team=? AND m.name='artifact_bytes'", (team,)).fetchone()[0]
            active = c.execute("SELECT COUNT(*) FROM bakes WHERE team=? AND status IN ('queued', 'running')",
                               (team,)).fetchone()[0]
        return {"scenes": int(n), "scene_bytes": int(nbytes), "unsized": unsized, "artifact_bytes": int(art),
                "active_bakes": int(active)}

    def set_bake_status(self, bake_id: str, status: str, *, only_from: tuple[str, ...] | None = None,
                        error: dict | None = None, manifest: dict | None = None) -> bool:
        """Move a bake to ``status``; with ``only_from`` only when it is currently in one of those.

        Returns whether the row changed. Terminal states are never left.
        """
        assert status in BAKE_STATUSES
        now = time.time()
        sets, args = ["status=?"], [status]
        if status == "running":
            sets.append("started=COALESCE(started, ?)")
            args.append(now)
        if status in TERMINAL:
            sets.append("finished=?")
            args.append(now)
        if error is not None:
            sets.append("error=?")
            args.append(json.dumps(error))
        if manifest is not None:
            sets.append("manifest=?")
            args.append(json.dumps(manifest))
        allowed = only_from or tuple(s for s in BAKE_STATUSES if s not in TERMINAL)
        q = ",".join("?" * len(allowed))
        with self._conn() as c:
            cur = c.execute(f"UPDATE bakes SET {', '.join(sets)} WHERE id=? AND status IN ({q})",
                            (*args, bake_id, *allowed))
            return cur.rowcount == 1

    def mark_succeeded(self, bake_id: str, manifest: dict, metrics: dict[str, float]) -> bool:
        """Record a finished bake: its metrics, then its manifest and status ``succeeded`` (what
        ``proto.stages.finalize_bake`` computed). Returns whether the status changed (False: already terminal)."""
        self.set_metrics(bake_id, metrics)
        return self.set_bake_status(bake_id, "succeeded", manifest=manifest)

    def bump_attempt(self, bake_id: str) -> int:
        with self._conn() as c:
            c.execute("UPDATE bakes SET attempt=attempt+1 WHERE id=?", (bake_id,))
            return c.execute("SELECT attempt FROM bakes WHERE id=?", (bake_id,)).fetchone()[0]

    def delete_bake(self, bake_id: str) -> None:
        with self._conn() as c:
            for t in ("stage_runs", "metrics"):
                c.execute(f"DELETE FROM {t} WHERE bake_id=?", (bake_id,))
            c.execute("DELETE FROM bakes WHERE id=?", (bake_id,))

    # ------------------------------------------------------------------ stage runs
    def update_stage(self, bake_id: str, stage: str, **fields: Any) -> None:
        allowed = {"status", "progress", "seconds", "cached", "stats", "pid", "started", "finished"}
        bad = set(fields) - allowed
        if bad:
            raise ValueError(f"unknown stage fields {sorted(bad)}")
        if "stats" in fields and fields["stats"] is not None:
            fields["stats"] = json.dumps(fields["stats"])
        if "cached" in fields:
            fields["cached"] = int(bool(fields["cached"]))
        cols = ", ".join(f"{k}=?" for k in fields)
        with self._conn() as c:
            c.execute(f"UPDATE stage_runs SET {cols} WHERE bake_id=? AND stage=?", (*fields.values(), bake_id, stage))

    def set_metrics(self, bake_id: str, values: dict[str, float]) -> None:
        with self._conn() as c:
            c.executemany("INSERT OR REPLACE INTO metrics (bake_id, name, value) VALUES (?,?,?)",
                          [(bake_id, k, float(v)) for k, v in values.items()])


def _loads(s: str | None) -> Any:
    return json.loads(s) if s else None


def _scene(r: sqlite3.Row) -> dict:
    d = _loads(r["summary"])
    d.update(created=r["created"], filename=r["filename"])
    return d


def _bake(r: sqlite3.Row) -> dict:
    return {
        "id": r["id"], "team": r["team"], "scene_id": r["scene_id"], "config": _loads(r["config"]),
        "status": r["status"], "created": r["created"], "started": r["started"], "finished": r["finished"],
        "error": _loads(r["error"]), "manifest": _loads(r["manifest"]), "attempt": r["attempt"],
    }


def _stage(r: sqlite3.Row) -> dict:
    return {
        "name": r["stage"], "cache_key": r["cache_key"], "status": r["status"], "progress": r["progress"],
        "seconds": r["seconds"], "cached": bool(r["cached"]), "stats": _loads(r["stats"]) or {},
        "pid": r["pid"], "started": r["started"], "finished": r["finished"],
    }
