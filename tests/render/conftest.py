"""Shared by the render tests: one headless OpenGL context per module, and the probe arrays and grid of a
bake run stage by stage (tests.workers.test_probes.bake_until) as the shading pass's inputs take them."""
from __future__ import annotations

import pytest

from workers.render.context import RenderUnavailable, create_context


@pytest.fixture(scope="module")
def ctx():
    """A headless moderngl context (EGL); the test is skipped, saying why, where there is none."""
    try:
        c = create_context()
    except RenderUnavailable as e:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL here: {e}")
    yield c
    c.release()


def bake_arrays(s: dict) -> dict:
    """{artifact name: array} of the stages a GI mode reads (light, masks, clusters, compress, relocate, trace) that ran; with
    ``masks_0123`` / ``masks_4567`` the masks the compressed atlas stands for (what the runtime samples: the
    compression may be lossy, ``masks.compress_tolerance``)."""
    out = {}
    for st in ("light", "masks", "clusters", "compress", "relocate", "trace"):
        if st in s:
            for n in s[st].names():
                out[n] = s[st][n]
    if "mask_atlas" in out:
        from workers.kernels.mask_atlas import decompress_channels

        meta = {"samples_per_cell": s["compress"].stats["block_size"], "clusters": s["compress"].stats["clusters"]}
        for n, v in zip(("masks_0123", "masks_4567"), decompress_channels(out["mask_atlas"], out["mask_indirection"],
                                                                           meta)):
            out[n] = v
    return out


def bake_grid(s: dict) -> dict:
    """The probe grid of the place stage: counts (nx, ny, nz), origin and spacing (metres, world space), and the
    layers of a rectilinear grid."""
    p = s["place"].stats
    return {k: p[k] for k in ("counts", "origin", "spacing", "layers") if k in p}


def mask_meta(s: dict) -> dict:
    """What the mask modes read beside the arrays: samples per cell S, the compressed block size T and its
    low border, from the visibility and compress stages' stats."""
    return {"samples_per_cell": s["visibility"].stats["samples_per_cell"],
            "block_size": s["compress"].stats["block_size"], "border_lo": s["compress"].stats["border_lo"]}
