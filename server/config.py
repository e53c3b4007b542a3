"""Server settings (pydantic-settings): environment variables prefixed ``KILN_``, validated at start-up.

| variable | default | meaning |
|---|---|---|
| ``KILN_DATA`` | ``./data`` | data directory: ``kiln.db`` (catalog), ``store/`` (artifacts), ``uploads/`` |
| ``REDIS_URL`` | (embedded) | external Redis; without it ``kiln serve`` starts an embedded one |
| ``KILN_API_KEYS`` | (none: open) | ``team:key,team2:key2``; with none the server runs open as team ``default`` |
| ``KILN_MAX_UPLOAD_MB`` | 512 | largest accepted upload (413 beyond) |
| ``KILN_MAX_TRIANGLES`` | 5000000 | largest accepted scene |
| ``KILN_MAX_SCENE_MB`` | 1024 | largest normalized scene (decoded images and geometry), 413 ``scene_too_large`` |
| ``KILN_MAX_BAKE_MEMORY_MB`` | 8192 | a bake's estimated peak memory (422 ``over_budget``); each stage's limit |
| ``KILN_MAX_BAKE_SECONDS`` | 14400 | a bake's estimated seconds (422 ``over_budget``) |
| ``KILN_MAX_BAKE_DISK_MB`` | 20480 | a bake's estimated artifact bytes (422 ``over_budget``) |
| ``KILN_MAX_JSON_KB`` | 1024 | JSON request bodies (413 beyond; read only after the key check) |
| ``KILN_INGEST_TIMEOUT_S`` | 300 | seconds one upload may take to parse (422 ``ingest_timeout``) |
| ``KILN_INGEST_PROCESSES`` | 2 | parser processes of the API |
| ``KILN_API_THREADS`` | 8 | threads running the API's sync routes |
| ``KILN_MAX_UPLOADS_PER_TEAM`` | 2 | a team's concurrent uploads (429 beyond) |
| ``KILN_QUOTA_STORED_MB`` | 51200 | a team's stored scenes and bake artifacts (429 ``quota_exceeded``) |
| ``KILN_QUOTA_SCENES`` | 1000 | a team's scenes (429 ``quota_exceeded``) |
| ``KILN_QUOTA_CONCURRENT_BAKES`` | 4 | a team's queued and running bakes (429 ``quota_exceeded``) |
"""
from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

OPEN_TEAM = "default"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="KILN_", extra="ignore", hide_input_in_errors=True)  # no keys in logs

    data: Path = Field(Path("data"), description="data directory")
    redis_url: str | None = Field(None, validation_alias="REDIS_URL")
    api_keys: str = Field("", description="team:key pairs, comma-separated")
    max_upload_mb: int = Field(512, ge=1, le=1 << 20)
    max_triangles: int = Field(5_000_000, ge=1)
    max_scene_mb: int = Field(1024, ge=1, le=1 << 20, description="largest normalized scene: decoded images "
                                                                    "and geometry")
    max_bake_memory_mb: int = Field(8192, ge=64, le=1 << 24, description="a bake's estimated peak memory; "
                                                                        "each stage's memory limit in the workers")
    max_bake_seconds: float = Field(14400.0, gt=0, description="a bake's estimated seconds")
    max_bake_disk_mb: int = Field(20480, ge=1, description="a bake's estimated artifact bytes")
    max_json_kb: int = Field(1024, ge=1, le=1 << 20, description="largest JSON request body")
    ingest_timeout_s: float = Field(300.0, gt=0, description="seconds one upload may take to parse")
    ingest_processes: int = Field(2, ge=1, le=64, description="parser processes of the API")
    api_threads: int = Field(8, ge=1, le=256, description="threads running the API's sync routes (fewer thrash "
                                                          "the GIL less under many clients)")
    max_uploads_per_team: int = Field(2, ge=1, description="a team's concurrent uploads")
    quota_stored_mb: int = Field(51200, ge=1, description="a team's stored scenes and artifacts")
    quota_scenes: int = Field(1000, ge=1, description="a team's scenes")
    quota_concurrent_bakes: int = Field(4, ge=1, description="a team's queued and running bakes")
    recover_interval_s: float = Field(5.0, gt=0, description="seconds between checks for lost bakes")
    ready_interval_s: float = Field(1.0, gt=0, description="seconds between drains of RQ's ready registry "
                                                            "(stage jobs whose dependencies are met)")

    @field_validator("api_keys")
    @classmethod
    def _keys_ok(cls, v: str) -> str:
        owner: dict[str, str] = {}
        for pair in filter(None, (p.strip() for p in v.split(","))):
            team, sep, key = pair.partition(":")
            if not sep or not team or len(key) < 8:
                raise ValueError("KILN_API_KEYS must be 'team:key,...' with keys of at least 8 characters")
            if key in owner and owner[key] != team:
                # one key for two teams would let one of them act as the other: refuse to start
                raise ValueError(f"KILN_API_KEYS gives one key to two teams ({owner[key]!r} and {team!r}); "
                                 "every team needs its own key")
            owner[key] = team
        return v

    @property
    def keys(self) -> dict[str, str]:
        """API key -> team."""
        out = {}
        for pair in filter(None, (p.strip() for p in self.api_keys.split(","))):
            team, _, key = pair.partition(":")
            out[key] = team
        return out

    @property
    def open(self) -> bool:
        return not self.keys

    @property
    def max_upload_bytes(self) -> int:
        return self.max_upload_mb * 2**20

    @property
    def max_json_bytes(self) -> int:
        return self.max_json_kb * 1024

    @property
    def max_scene_bytes(self) -> int:
        return self.max_scene_mb * 2**20

    @property
    def bake_memory_bytes(self) -> int:
        return self.max_bake_memory_mb * 2**20


@lru_cache
def get_settings() -> Settings:
    return Settings()


def is_loopback(host: str) -> bool:
    return host in ("127.0.0.1", "localhost", "::1") or host.startswith("127.")


def export_env(settings: Settings) -> None:
    """Put the settings into the environment so worker processes see the same ones."""
    os.environ["KILN_DATA"] = str(settings.data.resolve())
    os.environ.setdefault("KILN_MAX_BAKE_MEMORY_MB", str(settings.max_bake_memory_mb))   # the workers' limit
    if settings.redis_url:
        os.environ["REDIS_URL"] = settings.redis_url
