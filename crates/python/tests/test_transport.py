"""`sinkhorn_unbalanced` against POT itself (`ot.unbalanced.sinkhorn_unbalanced`,
reg_type="kl") on random problems: the same iterates for a fixed number of sweeps,
and the same converged plan."""

import numpy as np
import pytest

import transsplat

ot = pytest.importorskip("ot")


def problem(seed, n, m):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.1, 1.0, n)
    b = rng.uniform(0.1, 1.0, m)
    M = rng.uniform(0.0, 1.0, (n, m))
    return a / a.sum(), b / b.sum() * 1.3, M


@pytest.mark.parametrize("seed,n,m,reg,reg_m", [
    (0, 7, 5, 0.1, 1.0),
    (1, 40, 30, 0.05, (0.5, 2.0)),
    (2, 64, 16, 0.2, (float("inf"), 0.3)),
    (3, 3, 90, 0.5, 10.0),
])
def test_fixed_sweeps_match_pot(seed, n, m, reg, reg_m):
    a, b, M = problem(seed, n, m)
    want = ot.unbalanced.sinkhorn_unbalanced(a, b, M, reg, reg_m, reg_type="kl", numItermax=25, stopThr=0.0)
    got = transsplat.sinkhorn_unbalanced(a, b, M, reg, reg_m, numItermax=25, stopThr=0)
    assert got.dtype == np.float64 and got.shape == (n, m)
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-7 * want.max())


def test_converged_plan_log_and_uniform_masses_match_pot():
    a, b, M = problem(5, 30, 20)
    want, wlog = ot.unbalanced.sinkhorn_unbalanced([], [], M, 0.1, 0.7, numItermax=5000, stopThr=1e-12, log=True)
    got, log = transsplat.sinkhorn_unbalanced([], [], M, 0.1, 0.7, numItermax=5000, stopThr=1e-7, log=True)
    np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-8)
    np.testing.assert_allclose(log["logu"], wlog["logu"], atol=2e-3)
    np.testing.assert_allclose(log["logv"], wlog["logv"], atol=2e-3)
    assert log["converged"] and log["iterations"] < 5000
    np.testing.assert_allclose(log["cost"], (want * M).sum(), rtol=1e-3)


def test_top_k_matches_pot_on_the_masked_cost():
    a, b, M = problem(7, 50, 12)
    k = 6
    masked = np.full_like(M, np.inf)
    keep = np.argsort(M, axis=0, kind="stable")[:k]
    for j in range(M.shape[1]):
        masked[keep[:, j], j] = M[keep[:, j], j]
    # POT's scaling divides by zero on a source no target kept; such a source only adds
    # a constant to the objective, so POT solves the others and it transports nothing.
    rows = np.isfinite(masked).any(axis=1)
    assert not rows.all()
    want = ot.unbalanced.sinkhorn_unbalanced(a[rows], b, masked[rows], 0.1, 1.0, numItermax=30, stopThr=0.0)
    got = transsplat.sinkhorn_unbalanced_topk(a, b, M, 0.1, 1.0, k, numItermax=30, stopThr=0)
    np.testing.assert_allclose(got[rows], want, rtol=2e-4, atol=1e-9)
    assert (got[~rows] == 0).all()
    assert ((got > 0).sum(axis=0) <= k).all()


def test_float32_in_float32_out_and_bad_arguments():
    a, b, M = problem(9, 4, 3)
    got = transsplat.sinkhorn_unbalanced(a, b, M.astype(np.float32), 0.1, 1.0)
    assert got.dtype == np.float32
    with pytest.raises(ValueError, match=r"M: expected shape \(4, 5\)"):
        transsplat.sinkhorn_unbalanced(a, np.ones(5), M, 0.1, 1.0)
    with pytest.raises(ValueError, match="reg"):
        transsplat.sinkhorn_unbalanced(a, b, M, 0.0, 1.0)
    with pytest.raises(ValueError, match="reg_m"):
        transsplat.sinkhorn_unbalanced(a, b, M, 0.1, -1.0)
    with pytest.raises(ValueError, match="a: non-finite value NaN"):
        transsplat.sinkhorn_unbalanced(np.array([np.nan, 1, 1, 1]), b, M, 0.1, 1.0)
    with pytest.raises(ValueError, match="reg_type"):
        transsplat.sinkhorn_unbalanced(a, b, M, 0.1, 1.0, reg_type="l2")
    with pytest.raises(ValueError):
        transsplat.sinkhorn_unbalanced(-a, b, M, 0.1, 1.0)
