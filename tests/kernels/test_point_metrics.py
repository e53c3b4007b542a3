"""Point metrics (workers/kernels/point_metrics.py): the image metrics' definitions at points, and standard errors
that follow the reference's noise."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels import metrics as MT
from workers.kernels import point_metrics as PM


def _data(n=400, seed=0):
    rng = np.random.default_rng(seed)
    ref = rng.gamma(2.0, 1.0, (n, 1)) * np.array([1.0, 0.9, 0.8])
    ref[: n // 10] *= 0.01                                              # some dark points
    test = ref * rng.uniform(0.7, 1.4, (n, 1))
    return test, ref, rng.uniform(0, 3, (n, 3)), np.full((n, 3), 0.5), np.zeros((n, 3))


def test_metrics_match_the_image_metrics():
    test, ref, d, a, e = _data()
    img = lambda x: x.reshape(-1, 1, 3)  # noqa: E731
    k = MT.exposure_for(img(PM.radiance(d, ref, a, e)))
    m = PM.point_metrics(test, ref, d, a, e, k)
    lt, lr = MT.tonemap(img(PM.radiance(d, test, a, e)), k), MT.tonemap(img(PM.radiance(d, ref, a, e)), k)
    assert m["rmse"] == pytest.approx(MT.rmse(lt, lr), rel=1e-5)
    assert m["indirect_relative_rmse"] == pytest.approx(MT.relative_rmse(img(test), img(ref)), rel=1e-9)
    assert m["leak"] == pytest.approx(MT.leak_score(img(test), img(ref))["leak"], rel=1e-9)
    assert m["mean_ratio"] == pytest.approx(MT.luminance(test).mean() / MT.luminance(ref).mean())
    same = PM.point_metrics(ref, ref, d, a, e, k)
    assert same["rmse"] == 0 and same["leak"] == 0 and same["mean_ratio"] == pytest.approx(1.0)


def test_standard_errors_follow_the_reference_noise():
    test, ref, d, a, e = _data()
    none = PM.metrics_with_stderr(test, ref, np.zeros_like(ref), d, a, e)
    assert all(none[f"{k}_stderr"] < 1e-12 for k in PM.METRICS if none[k] is not None)
    lo = PM.metrics_with_stderr(test, ref, 0.01 * ref, d, a, e, seed=1)
    hi = PM.metrics_with_stderr(test, ref, 0.05 * ref, d, a, e, seed=1)
    for k in ("rmse", "indirect_relative_rmse", "mean_ratio"):
        assert 0 < lo[f"{k}_stderr"] < hi[f"{k}_stderr"], k
    # the mean ratio's error: about its value x the relative error of the reference's mean (independent points)
    rel = np.sqrt(np.sum((0.05 * MT.luminance(ref)) ** 2)) / MT.luminance(ref).sum()
    assert hi["mean_ratio_stderr"] == pytest.approx(hi["mean_ratio"] * rel, rel=0.35)
    r = PM.region_ratios(test.reshape(-1, 4, 3), ref.reshape(-1, 4, 3), 0.05 * ref.reshape(-1, 4, 3),
                         {"a": [0, 1, 2], "b": list(range(10, 60))})
    assert r["a"]["mean_ratio_stderr"] > r["b"]["mean_ratio_stderr"] > 0


def _points(n=200, seed=3):
    rng = np.random.default_rng(seed)
    ind = rng.gamma(2.0, 1.0, (n, 1)) * np.array([1.0, 0.9, 0.8])
    return {"position": rng.normal(size=(n, 3)), "e_direct": rng.uniform(0, 3, (n, 3)), "e_indirect": ind,
            "stderr": 0.01 * ind, "albedo": np.full((n, 3), 0.5), "emission": np.zeros((n, 3))}


def test_point_summary_of_the_reference_itself():
    pts = _points()
    recon = {"exact": pts["e_indirect"], "half": 0.5 * pts["e_indirect"]}
    summary, per_mode = PM.point_summary(["exact", "half"], recon, pts, seed=0)
    assert summary["exact.rmse"] == 0.0 and summary["exact.mean_ratio"] == pytest.approx(1.0)
    assert summary["half.mean_ratio"] == pytest.approx(0.5) and summary["half.rmse"] > 0
    assert summary["reference.mean_indirect"] == pytest.approx(MT.luminance(pts["e_indirect"]).mean())
    assert set(per_mode) == {"exact", "half"} and "rmse_stderr" in per_mode["half"]
    assert PM.point_summary(["exact"], {}, {"position": np.zeros((0, 3))}, 0) == ({}, {})


def test_check_point_report_modes_and_regions():
    """Each mode's values at the P·D check normals land as [point][normal] RGB; a region's mean ratio goes into
    the summary."""
    P, D = 2, 6
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.5, 1.0, (P, D, 3))
    doc = {"points": [[0, 0, 0], [1, 1, 1]], "normals": np.tile(np.eye(3).repeat(2, 0), (P, 1, 1)).tolist(),
           "reference_direct": np.zeros((P, D, 3)).tolist(), "reference_indirect": ref.tolist(),
           "reference_stderr": np.full((P, D, 3), 1e-3).tolist(), "regions": {"room": [0, 1]}}
    calls = []

    def values(mode, points, normals):
        calls.append((mode, points.shape, normals.shape))
        return ref.reshape(-1, 3) * (2.0 if mode == "double" else 1.0)

    summary = {}
    check = PM.check_point_report(doc, ["same", "double"], values, seed=0, summary=summary)
    assert calls == [("same", (P * D, 3), (P * D, 3)), ("double", (P * D, 3), (P * D, 3))]
    np.testing.assert_allclose(check["modes"]["double"], 2 * ref)
    assert summary["same.region.room.mean_ratio"] == pytest.approx(1.0)
    assert summary["double.region.room.mean_ratio"] == pytest.approx(2.0)
    assert check["regions"]["room"]["points"] == [0, 1]
    assert set(check["regions"]["room"]) == {"points", "same", "double"}


def test_leak_stderr_is_conditional_on_the_dark_set():
    """No dark point: the leak is 0 and so is its standard error, however noisy the points just above the
    threshold (a replica does not move them into the set); with dark points it follows their noise."""
    n = 400
    ref = np.ones((n, 3))
    ref[:100] = 0.06                                     # 6% of the mean (0.765): above tau = 5%, but noisy
    test = ref * 1.5
    d, a, e = np.zeros((n, 3)), np.full((n, 3), 0.5), np.zeros((n, 3))
    noisy = PM.metrics_with_stderr(test, ref, 0.5 * ref, d, a, e, seed=3)
    assert noisy["leak"] == 0.0 and noisy["leak_stderr"] == 0.0
    ref[:100] = 0.02                                     # now dark
    test = ref * 1.5
    lo = PM.metrics_with_stderr(test, ref, 0.05 * ref, d, a, e, seed=3)
    hi = PM.metrics_with_stderr(test, ref, 0.5 * ref, d, a, e, seed=3)
    assert lo["leak"] > 0 and 0 < lo["leak_stderr"] < hi["leak_stderr"]


def test_noise_bias_is_removed_from_the_squared_errors():
    """A noisy reference inflates every squared error by its own variance (E|T − R̂|² = |T − R|² + |s|²): at 10%
    noise on a mode 5% off, the plain estimate reads about twice the true error. With the bias removed the
    estimate is within a few % of the error against the exact reference, for both rmse metrics."""
    rng = np.random.default_rng(7)
    n = 20000
    truth = rng.gamma(2.0, 1.0, (n, 1)) * np.array([1.0, 0.9, 0.8])
    test = truth * rng.normal(1.0, 0.05, (n, 1))
    s = 0.1 * truth
    noisy = truth + s * rng.standard_normal((n, 1))
    d, a, e = rng.uniform(0, 3, (n, 3)), np.full((n, 3), 0.5), np.zeros((n, 3))
    k = MT.exposure_for(PM.radiance(d, truth, a, e).reshape(-1, 1, 3))
    exact = PM.point_metrics(test, truth, d, a, e, k)
    plain = PM.point_metrics(test, noisy, d, a, e, k)
    fixed = PM.point_metrics(test, noisy, d, a, e, k, err=s)
    for m in ("indirect_relative_rmse", "rmse"):
        assert plain[m] > 1.5 * exact[m], m                  # the bias the correction removes
        assert fixed[m] == pytest.approx(exact[m], rel=0.06), m
    assert PM.point_metrics(test, truth, d, a, e, k, err=np.zeros_like(s)) == exact
    with_se = PM.metrics_with_stderr(test, noisy, s, d, a, e, exposure=k)
    assert with_se["indirect_relative_rmse"] == fixed["indirect_relative_rmse"]


def test_debiased_rmse_standard_errors_match_their_spread():
    """The regime of an accurate mode (5% off) against a reference whose noise (10%) is larger than the error: many
    references drawn around one truth, each point's value the mean of NOISE_DOF + 1 independent sets and its
    standard error their spread (as the path tracer's). The reported standard errors of rmse and
    indirect_relative_rmse match the spread of the values across the references (within 20%; 150 draws: ±6%
    sampling noise). The parametric bootstrap around the noisy reference — what they were before — reads 0.6-0.8 of
    the spread (its replicas add their noise on top of the reference's, where the square root is flatter)."""
    rng = np.random.default_rng(11)
    n, G, draws = 2000, PM.NOISE_DOF + 1, 150
    truth = rng.gamma(2.0, 1.0, (n, 1)) * np.array([1.0, 0.9, 0.8])
    test = truth * rng.normal(1.0, 0.05, (n, 1))
    sigma = 0.1 * truth
    d, a, e = rng.uniform(0, 3, (n, 3)), np.full((n, 3), 0.5), np.zeros((n, 3))
    k = MT.exposure_for(PM.radiance(d, truth, a, e).reshape(-1, 1, 3))
    vals, errs, boot = ({m: [] for m in ("rmse", "indirect_relative_rmse")} for _ in range(3))
    for i in range(draws):
        sets = truth[:, None] + sigma[:, None] * np.sqrt(G) * rng.standard_normal((n, G, 1))
        ref, s = sets.mean(axis=1), np.sqrt(sets.var(axis=1, ddof=1) / G)
        r = PM.metrics_with_stderr(test, ref, s, d, a, e, exposure=k, replicas=32, seed=i)
        noise = PM._noise_variance(ref, s, d, a, e, k)
        reps = PM._metrics_batch(test, PM._replicas(ref, s, 32, i), d, a, e, k, noise=noise)
        for m in vals:
            vals[m].append(r[m])
            errs[m].append(r[f"{m}_stderr"])
            boot[m].append(np.std(reps[m], ddof=1))
    for m in vals:
        spread = np.std(vals[m], ddof=1)
        assert 0.8 < np.mean(errs[m]) / spread < 1.2, (m, np.mean(errs[m]), spread)
        assert np.mean(boot[m]) / spread < 0.85, (m, np.mean(boot[m]), spread)


def test_debiased_rmse_stderr_near_zero_and_without_noise():
    """No noise: 0. An rmse near 0 (the test equal to the truth): the fourth root of the variance, not a delta
    method that divides by 0."""
    u = np.full((100, 3), 0.1)
    assert PM._debiased_rmse_stderr(np.ones((100, 3)), np.zeros((100, 3)), 1.0) == 0.0
    v = PM._debiased_rmse_stderr(0.1 * np.ones((100, 3)), u, 0.0)
    assert 0 < v < 1 and np.isfinite(v)


def test_noise_dof_is_the_path_tracers():
    from workers.kernels.pathtrace import REPLICATES

    assert PM.NOISE_DOF == REPLICATES - 1


def test_paired_delta_stderr_matches_the_spread_of_deltas_against_one_reference():
    """Two accurate bakes (4% and 5% off the truth, independently) scored against the same noisy reference (10%
    noise), drawn 150 times: the paired standard error of each metric's delta B − A matches the spread of the deltas
    across the references (within 25%; measured 0.84-0.92), while ``sqrt(seA² + seB²)`` — the dashboard's estimate
    before, which counts the shared noise twice and in full — reads 1.7-1.8x the spread of the rmse deltas and 2000x
    that of mean_ratio's (whose reference noise cancels in the delta). The same test twice: a delta of exactly 0 ± 0."""
    rng = np.random.default_rng(5)
    n, G, draws = 2000, PM.NOISE_DOF + 1, 150
    truth = rng.gamma(2.0, 1.0, (n, 1)) * np.array([1.0, 0.9, 0.8])
    ta = truth * rng.normal(1.0, 0.04, (n, 1))
    tb = truth * rng.normal(1.0, 0.05, (n, 1))
    sigma = 0.1 * truth
    d, a, e = rng.uniform(0, 3, (n, 3)), np.full((n, 3), 0.5), np.zeros((n, 3))
    k = MT.exposure_for(PM.radiance(d, truth, a, e).reshape(-1, 1, 3))
    names = ("rmse", "indirect_relative_rmse", "mean_ratio", "indirect_excess")
    deltas, paired, quad = ({m: [] for m in names} for _ in range(3))
    for i in range(draws):
        sets = truth[:, None] + sigma[:, None] * np.sqrt(G) * rng.standard_normal((n, G, 1))
        ref, s = sets.mean(axis=1), np.sqrt(sets.var(axis=1, ddof=1) / G)
        ma = PM.metrics_with_stderr(ta, ref, s, d, a, e, exposure=k, replicas=32, seed=i)
        mb = PM.metrics_with_stderr(tb, ref, s, d, a, e, exposure=k, replicas=32, seed=i)
        p = PM.paired_delta_stderr(ta, tb, ref, s, d, a, e, exposure=k, replicas=32, seed=i)
        for m in names:
            deltas[m].append(mb[m] - ma[m])
            paired[m].append(p[m])
            quad[m].append(np.hypot(ma[f"{m}_stderr"], mb[f"{m}_stderr"]))
    spread = {m: np.std(deltas[m], ddof=1) for m in names}
    for m in names:
        assert 0.75 < np.mean(paired[m]) / spread[m] < 1.25, (m, np.mean(paired[m]), spread[m])
    for m in ("rmse", "indirect_relative_rmse"):            # measured 1.79 and 1.66 of the spread
        assert np.mean(quad[m]) > 1.5 * spread[m], (m, np.mean(quad[m]), spread[m])
    assert np.mean(quad["mean_ratio"]) > 100 * spread["mean_ratio"]         # measured 2000: the shared noise cancels
    same = PM.paired_delta_stderr(ta, ta, ref, s, d, a, e, exposure=k, replicas=32)
    assert all(same[m] == 0.0 for m in PM.METRICS), same


def test_paired_delta_stderr_without_points():
    z = np.zeros((0, 3))
    assert PM.paired_delta_stderr(z, z, z, z, z, z, z) == {m: None for m in PM.METRICS}


def test_paths_for_stderr_predicts_the_spread_at_that_many_paths():
    """paths_for_stderr: k times the reference's paths for a 2% standard error. References drawn around one truth
    at the predicted k (each point's noise s/√k, NOISE_DOF + 1 sets as the path tracer's) scatter the debiased rmse,
    the irradiance rmse and the mean ratio by about 2% of their values (within 35%: 60 draws, and the model's value
    is one noisy reference's estimate); the accurate mode (5% off under 10% noise) needs many times the paths, the
    coarse one (40% off) fewer than it has."""
    rng = np.random.default_rng(5)
    n, G = 2000, PM.NOISE_DOF + 1
    truth = rng.gamma(2.0, 1.0, (n, 1)) * np.array([1.0, 0.9, 0.8])
    d, a, e = rng.uniform(0, 3, (n, 3)), np.full((n, 3), 0.5), np.zeros((n, 3))
    k0 = MT.exposure_for(PM.radiance(d, truth, a, e).reshape(-1, 1, 3))

    def draw(sigma):
        sets = truth[:, None] + sigma[:, None] * np.sqrt(G) * rng.standard_normal((n, G, 1))
        return sets.mean(axis=1), np.sqrt(sets.var(axis=1, ddof=1) / G)

    accurate, coarse = truth * rng.normal(1.0, 0.05, (n, 1)), truth * rng.normal(1.0, 0.4, (n, 1))
    ref, s = draw(0.1 * truth)
    ka = PM.paths_for_stderr(accurate, ref, s, d, a, e, exposure=k0)
    kc = PM.paths_for_stderr(coarse, ref, s, d, a, e, exposure=k0)
    assert ka["rmse"] > 3 and ka["indirect_relative_rmse"] > 3
    assert kc["rmse"] < 1 and kc["indirect_relative_rmse"] < 1
    assert PM.paths_for_stderr(truth, truth, np.zeros_like(s), d, a, e, exposure=k0)["rmse"] is None   # value 0
    for m in ("rmse", "indirect_relative_rmse", "mean_ratio"):
        k = ka[m]
        vals = [PM.metrics_with_stderr(accurate, *draw(0.1 * truth / np.sqrt(k)), d, a, e, exposure=k0,
                                       replicas=8, seed=i)[m] for i in range(60)]
        rel = np.std(vals, ddof=1) / np.mean(vals)
        assert 0.65 * 0.02 < rel < 1.35 * 0.02, (m, k, rel)
