"""What a stage function takes and returns.

A stage is a plain function ``run(ctx: StageContext) -> StageOutput``: arrays in, arrays
out. It never touches Redis, HTTP or the catalog; the pipeline stores what it returns.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from proto.models import BakeConfig
from workers.scene import NormalizedScene


class StageError(Exception):
    """A deterministic failure of a stage caused by its input (bad scene, impossible config).

    Retrying cannot help, so jobs record it on the bake and do not retry.
    """

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


class Cancelled(Exception):
    """Raised from ``report`` when the bake was cancelled; the stage unwinds without storing."""


@dataclass
class Artifact:
    """One output array (or JSON dict) of a stage, in the bundle format (proto/bundle.md)."""

    name: str
    data: np.ndarray | dict | bytes
    format: str = "ktx2"           # "ktx2" | "npy" | "json" | "png" (PNG-encoded bytes) | "glb" (glTF binary bytes)
    vk_format: int | str | None = None  # KTX2 only; inferred from dtype/channels when None
    zstd_level: int | None = None  # KTX2 only: Zstandard level, None = proto.bundle.DEFAULT_ZSTD_LEVEL, 0 = none
    table: bool = False            # KTX2 only: any-shape array as a one-channel 2D table (proto/bundle.md 3)
    description: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def write(self, folder, stage: str):
        """Write it into bundle folder ``folder`` (:func:`proto.bundle.write_artifact`); returns its ``ArtifactInfo``."""
        from proto.bundle import write_artifact

        ktx2 = self.format == "ktx2"
        return write_artifact(folder, self.name, self.data, stage, format=self.format, description=self.description,
                              meta=self.meta, vk_format=self.vk_format, zstd_level=self.zstd_level,
                              table=self.table if ktx2 else False)


@dataclass
class StageOutput:
    artifacts: list[Artifact]
    stats: dict[str, Any] = field(default_factory=dict)


@dataclass
class StageContext:
    """What a stage sees: the scene, the config, its upstream stages' outputs, a progress callback.

    ``inputs[stage][artifact]`` loads lazily; ``report(fraction)`` takes 0..1 and may raise
    :class:`Cancelled`.
    """

    config: BakeConfig
    scene_loader: Callable[[], NormalizedScene]
    inputs: dict[str, "LazyArtifacts"]
    report: Callable[[float], None]
    shard: int | None = None          # for a shard of a sharded stage: its index and the shard count
    shard_count: int | None = None
    #: The bake frame (:func:`workers.kernels.frame.choose_frame`'s record) the pipeline turned ``scene`` into for a
    #: probe stage that reads ``ingest``; None: the world frame, or not known to this stage.
    frame: dict | None = None
    _scene: NormalizedScene | None = None

    @property
    def scene(self) -> NormalizedScene:
        if self._scene is None:
            self._scene = self.scene_loader()
        return self._scene


class LazyArtifacts:
    """Mapping artifact name -> array/dict, loaded from the store on first access."""

    def __init__(self, stats: dict, loaders: dict[str, Callable[[], Any]]):
        self.stats = stats
        self._loaders = loaders
        self._cache: dict[str, Any] = {}

    def __getitem__(self, name: str) -> Any:
        if name not in self._cache:
            self._cache[name] = self._loaders[name]()
        return self._cache[name]

    def __contains__(self, name: str) -> bool:
        return name in self._loaders

    def release(self, *names: str) -> None:
        """Drop the loaded copies of ``names`` (loaded again on a later access): a stage frees what it is done with."""
        for name in names:
            self._cache.pop(name, None)

    def names(self) -> list[str]:
        return sorted(self._loaders)


def probe_sh_l1(light) -> np.ndarray:
    """The light stage's float32 L1 volumes (nz, ny, nx, 4, 3) from its outputs ``light`` (``sh_l1_full``; older
    bakes: the stored ``sh_l1_{r,g,b}``): what the masks' light-aware fit and the cluster volumes read."""
    if "sh_l1_full" in light:
        return np.asarray(light["sh_l1_full"], np.float32)
    return np.stack([light[f"sh_l1_{c}"] for c in "rgb"], axis=-1).astype(np.float32)


def samples_per_cell(config: BakeConfig, place_stats: dict) -> int:
    """The visibility field's samples per cell axis S (MD §3.4): the config's, else the automatic grid's
    choice (``grid.auto.samples_per_cell``: both sides of the thinnest walls), else 8."""
    if config.visibility.samples_per_cell is not None:
        return int(config.visibility.samples_per_cell)
    auto = place_stats.get("auto") or {}
    return int(auto.get("samples_per_cell", 8))


def jsonable(x):
    """``x`` with numpy scalars and arrays as Python values and non-finite floats as None (stage stats are JSON)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    return x
