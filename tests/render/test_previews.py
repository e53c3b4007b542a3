"""Preview pictures (workers/render/previews.py): encoding, and nothing rendered when nothing is asked."""
from __future__ import annotations

import numpy as np

from workers.render import previews as PV


def test_pictures_are_png_with_their_shape():
    assert PV.png_supported()
    name, data, fmt, desc, meta = PV._picture("eval_x", np.full((4, 6, 3), 0.5), "a picture", {"camera": "c"})
    assert (name, fmt, desc) == ("eval_x", "png", "a picture") and data[:8] == b"\x89PNG\r\n\x1a\n"
    assert meta == {"camera": "c", "shape": [4, 6, 3]}


def test_no_previews_asked_or_stored():
    summary = {"leaking.pass_ms": 1.0}
    rdoc = {"cameras": [{"name": "a", "position": [0, 0, 1], "target": [0, 0, 0]}], "previews": ["a"]}
    for previews, ref in ((0, {"reference_a_gbuffer": 1}), (1, {})):
        assert PV.mode_previews(ref, rdoc, ["direct"], {}, [], summary, previews=previews, repeats=1, flip=False,
                                report=None) == ([], {}, [])
    assert summary == {"leaking.pass_ms": 1.0}


def test_preview_summary_means_fetches_and_ratios():
    per_camera = [{"modes": {m: {"image_rmse": r, "flip": None, "image_leak": 0.0, "pass_ms": p, "pass_ms_min": p}
                             for m, r, p in (("mask", 0.1, 2.0), ("leaking", 0.3, 1.0))}},
                  {"modes": {m: {"image_rmse": r, "flip": None, "image_leak": 0.0, "pass_ms": p, "pass_ms_min": p}
                             for m, r, p in (("mask", 0.3, 4.0), ("leaking", 0.1, 1.0))}}]
    summary = {"mask.gi_fetches_per_pixel": 10.0}
    PV._preview_summary(["mask", "leaking"], per_camera, 5, summary)
    assert summary["mask.image_rmse"] == 0.2 and "mask.flip" not in summary
    assert summary["mask.pass_fetches_per_pixel"] == 10.0 + PV.GBUFFER_FETCHES + 2     # ceil(5 lights / 4)
    assert summary["ratio.mask_over_leaking.pass_ms"] == 3.0
