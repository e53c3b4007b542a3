"""Preview pictures (workers/render/previews.py): encoding, and nothing rendered when nothing is asked."""
from __future__ import annotations

import numpy as np
import pytest

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


def _synthetic_preview(seed: int = 0):
    """A 60 x 80 preview: two albedos, two facings, an emissive patch, a hard shadow edge in the direct light, a
    smooth true indirect field and a 4-spp-like noisy estimate of it (gamma noise, coefficient of variation 1.4)."""
    rng = np.random.default_rng(seed)
    h, w = 60, 80
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    shaded = np.ones((h, w), bool)
    shaded[:4] = False                                          # a strip of sky
    albedo = np.where((x < 40)[..., None], [0.8, 0.8, 0.8], [0.6, 0.25, 0.2]).astype(np.float32)
    normal = np.where((y < 30)[..., None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]).astype(np.float32)
    emission = np.zeros((h, w, 3), np.float32)
    emission[40:44, 60:70] = 5.0
    e_dir = np.where((x < 50)[..., None], 6.0, 0.0).astype(np.float32) * np.ones(3, np.float32)
    e_true = (1.0 + 0.8 * np.sin(x / 25.0) * np.cos(y / 30.0))[..., None] * np.array([1.0, 0.9, 0.8], np.float32)
    e_noisy = (e_true * rng.gamma(0.5, 2.0, (h, w, 1))).astype(np.float32)
    for a in (albedo, normal, e_dir, e_true, e_noisy):
        a[~shaded] = 0.0
    radiance = np.where(shaded[..., None], emission + albedo / np.pi * (e_dir + e_noisy), 0.0).astype(np.float32)
    gb = {"albedo": albedo, "normal": normal, "emission": emission, "shaded": shaded}
    image = np.concatenate([e_dir, e_noisy, radiance], axis=-1).astype(np.float32)
    truth = np.where(shaded[..., None], emission + albedo / np.pi * (e_dir + e_true), 0.0)
    return image, gb, truth


def test_denoised_reference_is_near_the_truth_and_keeps_the_exact_terms():
    """The preview reference's indirect term goes through Intel Open Image Denoise (pictures only): far closer to
    the noise-free image than the noisy one, the same mean, and the exact terms (emission, the direct light with
    its hard shadow edge) and the unshaded pixels untouched."""
    pytest.importorskip("pyoidn", reason="pyoidn ships x86-64 Linux wheels only; elsewhere previews are not denoised")
    image, gb, truth = _synthetic_preview()
    out = PV.denoised_radiance(image, gb)
    assert out is not None and out.shape == truth.shape and out.dtype == np.float32
    sel = gb["shaded"]
    err_noisy = np.sqrt(np.mean((image[..., 6:9][sel] - truth[sel]) ** 2))
    err_clean = np.sqrt(np.mean((out[sel] - truth[sel]) ** 2))
    assert err_clean < 0.25 * err_noisy, (err_clean, err_noisy)
    assert abs(out[sel].mean() / truth[sel].mean() - 1.0) < 0.05
    assert np.array_equal(out[~sel], image[..., 6:9][~sel])
    # no indirect light: what is left is exact, shadow edge and emissive patch included
    dark = image.copy()
    dark[..., 3:6] = 0.0
    exact = gb["emission"] + gb["albedo"] / np.pi * image[..., 0:3]
    np.testing.assert_allclose(PV.denoised_radiance(dark, gb)[sel], exact[sel], atol=1e-4)   # OIDN: 7e-5 of 5
