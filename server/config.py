"""Server settings (pydantic-settings): environment variables prefixed ``KILN_``, validated at start-up.

| variable | default | meaning |
|---|---|---|
| ``KILN_DATA`` | ``./data`` | data directory: ``kiln.db`` (catalog), ``store/`` (artifacts), ``uploads/`` |
| ``REDIS_URL`` | (embedded) | external Redis; without it ``kiln serve`` starts an embedded one |
| ``KILN_API_KEYS`` | (none: open) | ``team:key,team2:key2``; with none the server runs open as team ``default`` |
| ``KILN_MAX_UPLOAD_MB`` | 512 | largest accepted upload (413 beyond) |
| ``KILN_MAX_TRIANGLES`` | 5000000 | largest accepted scene |
"""
from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

OPEN_TEAM = "default"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="KILN_", extra="ignore")

    data: Path = Field(Path("data"), description="data directory")
    redis_url: str | None = Field(None, validation_alias="REDIS_URL")
    api_keys: str = Field("", description="team:key pairs, comma-separated")
    max_upload_mb: int = Field(512, ge=1, le=1 << 20)
    max_triangles: int = Field(5_000_000, ge=1)
    recover_interval_s: float = Field(5.0, gt=0, description="seconds between checks for lost bakes")
    ready_interval_s: float = Field(1.0, gt=0, description="seconds between drains of RQ's ready registry "
                                                            "(stage jobs whose dependencies are met)")

    @field_validator("api_keys")
    @classmethod
    def _keys_ok(cls, v: str) -> str:
        for pair in filter(None, (p.strip() for p in v.split(","))):
            team, sep, key = pair.partition(":")
            if not sep or not team or len(key) < 8:
                raise ValueError("KILN_API_KEYS must be 'team:key,...' with keys of at least 8 characters")
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


@lru_cache
def get_settings() -> Settings:
    return Settings()


def is_loopback(host: str) -> bool:
    return host in ("127.0.0.1", "localhost", "::1") or host.startswith("127.")


def export_env(settings: Settings) -> None:
    """Put the settings into the environment so worker processes see the same ones."""
    os.environ["KILN_DATA"] = str(settings.data.resolve())
    if settings.redis_url:
        os.environ["REDIS_URL"] = settings.redis_url
