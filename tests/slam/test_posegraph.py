"""The pose graph's Laplace uncertainty: marginal covariances against a dense inverse of a numerically
differentiated information matrix and against the closed form of a chain of edges; perturb-and-solve draws against
those covariances within Monte Carlo error; the log pipeline's combination of the chain's and the graph's spread;
and the scans of a loop candidate's local map against the travel they may span; the sequential edges tied to the
front end's local maps against a numerically differentiated information matrix and the plain edges."""

import numpy as np
import pytest
import scipy.sparse
from hypothesis import given, settings
from hypothesis import strategies as st

from bayesmap.errors import BayesmapError
from bayesmap.slam.joint import pose_summary
from bayesmap.slam.pipeline import graph_uncertainty, hypothesis_counts
from bayesmap.slam.posegraph import (
    Edges,
    LocalMaps,
    LoopHypotheses,
    concat_edges,
    edge_jacobians,
    edge_residuals,
    local_map_neighbours,
    marginal_covariances,
    optimize_pose_graph,
    relative,
    sample_deviations,
    whitening_matrices,
    with_covariances,
    with_step_covariances,
)


def _graph(seed=0, count=9):
    """A wandering path of ``count`` poses, its sequential edges plus two loop edges, measured with noise, each edge
    with its own standard deviations."""
    rng = np.random.default_rng(seed)
    steps = np.column_stack([rng.uniform(0.3, 1.0, count - 1), rng.normal(0, 0.2, count - 1),
                             rng.normal(0, 0.5, count - 1)])
    path = np.zeros((count, 3))
    for t, (dx, dy, dth) in enumerate(steps, start=1):
        c, s = np.cos(path[t - 1, 2]), np.sin(path[t - 1, 2])
        path[t] = path[t - 1] + [c * dx - s * dy, s * dx + c * dy, dth]
    i = np.concatenate([np.arange(count - 1), [0, 2]])
    j = np.concatenate([np.arange(1, count), [count - 1, count - 2]])
    z = relative(path[i], path[j]) + rng.normal(0, 0.02, (len(i), 3))
    std = rng.uniform(0.02, 0.1, (len(i), 3))
    return path, Edges(i, j, z, std)


def _covariances(rng, count):
    """``count`` random correlated covariances ``(count, 3, 3)``: standard deviations 0.02-0.1, correlations
    from a random factor."""
    factor = rng.normal(0, 1, (count, 3, 3)) + 2 * np.eye(3)
    cov = factor @ np.swapaxes(factor, 1, 2)
    sd = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    correlation = cov / (sd[:, :, None] * sd[:, None, :])
    wanted = rng.uniform(0.02, 0.1, (count, 3))
    return correlation * wanted[:, :, None] * wanted[:, None, :]


@pytest.mark.parametrize("full", [False, True])
def test_marginal_covariances_are_the_inverse_of_the_numerical_information(full):
    """Independent edge components (``std``), or full covariances on every sequential edge (the front end's step
    posteriors: ``W e`` whitened by the Cholesky factor's inverse)."""
    path, edges = _graph()
    if full:
        edges = with_step_covariances(edges, _covariances(np.random.default_rng(3), len(path) - 1))
    count = len(path)

    def residuals(x):
        return edge_residuals(np.concatenate([path[:1], x.reshape(count - 1, 3)]), edges).reshape(-1)

    x0, h = path[1:].reshape(-1), 1e-6
    jac = np.column_stack([(residuals(x0 + h * e) - residuals(x0 - h * e)) / (2 * h) for e in np.eye(len(x0))])
    dense = np.linalg.inv(jac.T @ jac)
    cov = marginal_covariances(path, edges)
    assert np.all(cov[0] == 0.0)
    for k in range(1, count):  # central differences: relative error ~1e-9; 1e-6 leaves room for the inverse
        np.testing.assert_allclose(cov[k], dense[3 * k - 3:3 * k, 3 * k - 3:3 * k], rtol=1e-6, atol=1e-12)
    first, second = edge_jacobians(path, edges)  # the analytic blocks are the numerical Jacobian's
    e = 3  # an edge between poses 3 and 4
    np.testing.assert_allclose(first[e], jac[3 * e:3 * e + 3, 3 * 2:3 * 3], atol=1e-6)
    np.testing.assert_allclose(second[e], jac[3 * e:3 * e + 3, 3 * 3:3 * 4], atol=1e-6)


def test_a_straight_chain_adds_the_edges_variances():
    """Poses 1 m apart along x, heading 0: the x error of pose k is the sum of k edges' x errors (a heading error
    moves it in y only, to first order), so Var(x_k) = k sx^2 and Var(theta_k) = k st^2, exactly."""
    count, sx, sy, st = 7, 0.03, 0.05, 0.01
    path = np.column_stack([np.arange(count, dtype=float), np.zeros(count), np.zeros(count)])
    i, j = np.arange(count - 1), np.arange(1, count)
    edges = Edges(i, j, relative(path[i], path[j]), np.tile([sx, sy, st], (count - 1, 1)))
    cov = marginal_covariances(path, edges)
    k = np.arange(count)
    np.testing.assert_allclose(cov[:, 0, 0], k * sx**2, rtol=1e-9)
    np.testing.assert_allclose(cov[:, 2, 2], k * st**2, rtol=1e-9)
    # y: each edge's own sy^2, plus edge m's heading error swinging the n - m metres after it
    expected_y = k * sy**2 + np.array([sum((n - m) ** 2 for m in range(1, n + 1)) for n in k]) * st**2
    np.testing.assert_allclose(cov[:, 1, 1], expected_y, rtol=1e-9)


def _compose(a, b):
    """Pose ``b`` ``(..., 3)`` (in ``a``'s frame) carried into the world by pose ``a`` ``(..., 3)``."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     a[..., 2] + b[..., 2]], axis=-1)


def _local_maps(count, rng):
    """Shares of each step's local map: step 1 on scan 0, step 2 on scans 0-1, later steps on the three scans before
    them, random weights summing to 1."""
    rows, cols, vals = [], [], []
    for t in range(1, count):
        members = np.arange(max(0, t - 3), t)
        rows += [t - 1] * len(members)
        cols += list(members)
        vals += list(rng.dirichlet(np.ones(len(members))))
    return scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(count - 1, count))


def test_local_maps_are_the_inverse_of_the_numerical_information():
    """LocalMaps: each step's information split between its motion model (on the step from pose ``t - 1``) and its
    scan (on pose ``t`` against its local map's scans: where scan ``t`` lies if it keeps its place relative to scan
    ``s``, averaged by the shares). The motion covariances are chosen so that the split is known: twice the step's
    (half the information each), zero (a step the odometry fixes: all of it the scan's) and half the step's (the
    motion model's information capped at the step's: none of it the scan's). The marginal covariances are those of a
    dense inverse of the numerically differentiated residuals' information, as for the plain graph."""
    path, edges = _graph(seed=4, count=10)
    count = len(path)
    step_cov = _covariances(np.random.default_rng(6), count - 1)
    edges = with_step_covariances(edges, step_cov)
    shares = _local_maps(count, np.random.default_rng(7))
    motion_cov = 2 * step_cov
    motion_cov[3] = 0.0
    motion_cov[5] = step_cov[5] / 2
    motion_part = np.full(count - 1, 0.5)
    motion_part[3], motion_part[5] = 0.0, 1.0
    whitening = whitening_matrices(edges)[: count - 1]
    loops = edges.take(slice(count - 1, None))
    dense_shares = shares.toarray()

    def residuals(x):
        x = np.concatenate([path[:1], x.reshape(count - 1, 3)])
        out = [edge_residuals(x, loops).reshape(-1)]
        for t in range(1, count):
            motion = relative(x[t - 1], x[t]) - edges.z[t - 1]
            s = np.flatnonzero(dense_shares[t - 1])
            kept = _compose(x[s], relative(path[s], path[t]))  # scan t carried by each local-map scan
            seen = (dense_shares[t - 1, s, None] * kept).sum(axis=0)
            c, sn = np.cos(path[t - 1, 2]), np.sin(path[t - 1, 2])  # the step covariance's frame, held
            d = x[t] - seen
            scan = np.array([c * d[0] + sn * d[1], -sn * d[0] + c * d[1], d[2]])
            out += [np.sqrt(motion_part[t - 1]) * whitening[t - 1] @ motion,
                    np.sqrt(1 - motion_part[t - 1]) * whitening[t - 1] @ scan]
        return np.concatenate(out)

    x0, h = path[1:].reshape(-1), 1e-6
    jac = np.column_stack([(residuals(x0 + h * e) - residuals(x0 - h * e)) / (2 * h) for e in np.eye(len(x0))])
    dense = np.linalg.inv(jac.T @ jac)
    cov = marginal_covariances(path, edges, LocalMaps(shares, motion_cov))
    for k in range(1, count):
        np.testing.assert_allclose(cov[k], dense[3 * k - 3:3 * k, 3 * k - 3:3 * k], rtol=1e-6, atol=1e-12)
    assert not np.allclose(cov, marginal_covariances(path, edges), rtol=1e-2)


def test_local_maps_of_the_previous_scan_alone_are_the_plain_graph():
    """Every share on scan ``t - 1``: the motion model's part and the scan's sum to the step's information on the
    same edge, so the covariances and the draws' spread are the plain graph's, whatever the motion covariances."""
    path, edges = _graph(seed=5, count=12)
    count = len(path)
    rng = np.random.default_rng(8)
    edges = with_step_covariances(edges, _covariances(rng, count - 1))
    previous = scipy.sparse.csr_matrix((np.ones(count - 1), (np.arange(count - 1), np.arange(count - 1))),
                                       shape=(count - 1, count))
    local_maps = LocalMaps(previous, _covariances(rng, count - 1) * rng.uniform(0.3, 3.0, (count - 1, 1, 1)))
    np.testing.assert_allclose(marginal_covariances(path, edges, local_maps), marginal_covariances(path, edges),
                               rtol=1e-9, atol=1e-15)
    draws = sample_deviations(3, path, edges, 4000, local_maps)
    var = marginal_covariances(path, edges)[1:, [0, 1, 2], [0, 1, 2]]
    np.testing.assert_allclose((draws[:, 1:] ** 2).mean(axis=0) / var, 1.0, atol=5 * np.sqrt(2 / 4000))


def test_a_corridor_matched_against_three_scans_drifts_less():
    """Thirty poses a meter apart along x, each step's information all the scan's (the odometry fixes nothing):
    matched against scan ``t - 1`` alone the x variance grows by a step's each pose (a random walk); against the
    mean of the three scans before, the last pose's is at most a third of that (a random walk whose steps average
    a lag of 2 grows at a quarter of the rate, plus what the first poses add)."""
    count, sd = 30, np.array([0.03, 0.03, 0.01])
    path = np.column_stack([np.arange(count, dtype=float), np.zeros(count), np.zeros(count)])
    i, j = np.arange(count - 1), np.arange(1, count)
    edges = with_step_covariances(Edges(i, j, relative(path[i], path[j]), np.tile(sd, (count - 1, 1))),
                                  np.tile(np.diag(sd**2), (count - 1, 1, 1)))
    rows = [t - 1 for t in range(1, count) for _ in range(min(t, 3))]
    cols = [s for t in range(1, count) for s in range(max(0, t - 3), t)]
    vals = [1.0 / min(t, 3) for t in range(1, count) for _ in range(min(t, 3))]
    shares = scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(count - 1, count))
    plain = marginal_covariances(path, edges)
    three = marginal_covariances(path, edges, LocalMaps(shares, np.zeros((count - 1, 3, 3))))
    np.testing.assert_allclose(plain[-1, 0, 0], (count - 1) * sd[0] ** 2, rtol=1e-9)
    assert three[-1, 0, 0] <= plain[-1, 0, 0] / 3
    assert np.all(np.diff(three[:, 0, 0]) > 0)  # still growing along the corridor


def test_local_maps_that_do_not_fit_the_graph_are_named():
    path, edges = _graph(seed=5)
    count = len(path)
    shares = _local_maps(count, np.random.default_rng(0))
    with pytest.raises(BayesmapError, match="must be"):
        marginal_covariances(path, edges, LocalMaps(shares[:-1], np.zeros((count - 1, 3, 3))))
    later = scipy.sparse.csr_matrix(([1.0], ([2], [5])), shape=(count - 1, count))
    with pytest.raises(BayesmapError, match="only the scans before it"):
        marginal_covariances(path, edges, LocalMaps(later, np.zeros((count - 1, 3, 3))))
    swapped = edges._replace(i=edges.j, j=edges.i)
    with pytest.raises(BayesmapError, match="sequential edges"):
        marginal_covariances(path, swapped, LocalMaps(shares, np.zeros((count - 1, 3, 3))))


def test_perturb_and_solve_draws_have_the_marginal_covariances():
    """4000 draws: a variance estimate's relative standard error is sqrt(2 / 4000) = 2.2 %; allow 5 of them (11 %)
    per pose and component, and the mean within 5 standard errors of zero."""
    path, edges = _graph(seed=1)
    num = 4000
    draws = sample_deviations(3, path, edges, num)
    assert draws.shape == (num, len(path), 3) and np.all(draws[:, 0] == 0.0)
    cov = marginal_covariances(path, edges)
    var = cov[1:, [0, 1, 2], [0, 1, 2]]
    emp = (draws[:, 1:] ** 2).mean(axis=0)
    np.testing.assert_allclose(emp / var, 1.0, atol=5 * np.sqrt(2 / num))
    assert np.all(np.abs(draws[:, 1:].mean(axis=0)) <= 5 * np.sqrt(var / num))
    np.testing.assert_array_equal(sample_deviations(3, path, edges, 5), sample_deviations(3, path, edges, 5))


def test_graph_errors_name_the_value():
    path, edges = _graph()
    with pytest.raises(BayesmapError, match="pose 4 has no edge"):
        keep = (edges.i != 4) & (edges.j != 4)
        marginal_covariances(path, edges.take(keep))
    with pytest.raises(BayesmapError, match="positive and finite"):
        marginal_covariances(path, edges._replace(std=np.where(np.arange(len(edges.i))[:, None] == 2, 0.0, edges.std)))
    pieces = Edges(np.array([0, 2, 3]), np.array([1, 3, 4]), np.zeros((3, 3)), np.full((3, 3), 0.1))
    with pytest.raises(BayesmapError, match="does not tie every pose to pose 0"):
        marginal_covariances(path[:5], pieces)  # poses 2-4 float free of 0 and 1
    with pytest.raises(BayesmapError, match="num must be a positive integer, got 0"):
        sample_deviations(0, path, edges, 0)
    with pytest.raises(BayesmapError, match=r"path must have shape \(S, 3\)"):
        marginal_covariances(path[:, :2], edges)


def test_full_covariances_whiten_as_their_inverse():
    """with_covariances: ``W^T W = Sigma^-1`` for each edge, ``std`` the diagonal's roots; a diagonal covariance
    gives the same residuals, Jacobians and marginal covariances as ``std`` itself (to rounding); the loop edges of
    with_step_covariances keep their ``std``; a covariance that is not positive definite is named."""
    path, edges = _graph(seed=1)
    cov = _covariances(np.random.default_rng(5), len(edges.i))
    full = with_covariances(edges, cov)
    w = whitening_matrices(full)
    np.testing.assert_allclose(np.swapaxes(w, 1, 2) @ w, np.linalg.inv(cov), rtol=1e-9)
    np.testing.assert_allclose(full.std, np.sqrt(np.diagonal(cov, axis1=1, axis2=2)), rtol=1e-12)
    diagonal = with_covariances(edges, np.einsum("ei,ij->eij", np.square(edges.std), np.eye(3)))
    np.testing.assert_allclose(edge_residuals(path, diagonal), edge_residuals(path, edges), rtol=1e-12)
    for got, want in zip(edge_jacobians(path, diagonal), edge_jacobians(path, edges)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(marginal_covariances(path, diagonal), marginal_covariances(path, edges), rtol=1e-9)
    steps = with_step_covariances(edges, cov[: len(path) - 1])
    assert steps.whitening.shape == (len(edges.i), 3, 3)
    np.testing.assert_array_equal(steps.std[len(path) - 1:], edges.std[len(path) - 1:])
    np.testing.assert_allclose(whitening_matrices(steps)[len(path) - 1:],
                               np.eye(3) / edges.std[len(path) - 1:, :, None], rtol=1e-12)
    bad = cov.copy()
    bad[4] = np.diag([0.01, -0.01, 0.01])
    with pytest.raises(BayesmapError, match="edge 4's covariance is not positive definite"):
        with_covariances(edges, bad)
    with pytest.raises(BayesmapError, match="cov must have shape"):
        with_covariances(edges, cov[:3])


def test_reported_uncertainty_is_the_chains_plus_the_graphs():
    """graph_uncertainty keeps the chain's mean path (antithetic deviations), adds the graph's covariance to the
    chain's, and its samples spread as that sum: 2000 samples are 1000 antithetic pairs, so a
    variance estimate's relative standard error is sqrt(2 / 1000) = 4.5 %; allow 4 of them."""
    path, edges = _graph(seed=2)
    rng = np.random.default_rng(0)
    chain = path + rng.normal(0, 0.001, (2000, len(path), 3))
    chain[:, 0] = path[0]
    mean, cov, samples, graph_cov = graph_uncertainty(5, chain, edges)
    chain_mean, chain_cov = pose_summary(chain)
    np.testing.assert_allclose(mean, chain_mean, atol=1e-12)
    np.testing.assert_allclose(pose_summary(samples)[0][:, :2], chain_mean[:, :2], atol=1e-9)
    np.testing.assert_allclose(graph_cov, marginal_covariances(chain_mean, edges), rtol=1e-12)
    np.testing.assert_allclose(cov, chain_cov + graph_cov, rtol=1e-12)
    emp = pose_summary(samples)[1][1:, [0, 1, 2], [0, 1, 2]]
    np.testing.assert_allclose(emp / cov[1:, [0, 1, 2], [0, 1, 2]], 1.0, atol=4 * np.sqrt(2 / 1000))


@pytest.mark.parametrize("seed", range(3))
def test_optimizer_reaches_the_robust_minimum_of_a_reference_solver(seed):
    """optimize_pose_graph (Levenberg-Marquardt on reweighted least squares) against scipy.optimize.least_squares
    with the same robust cost (loss "cauchy", f_scale = the scale), both from a path knocked 0.3 m / 0.2 rad off
    the graph's solution, on a 30-pose graph with two loops and one false loop edge (1.5 m off, so the robust loss
    matters). Its cost must not exceed scipy's converged one by more than 1e-6 of it, and its gradient must vanish
    (the sum of squared whitened gradient entries below 1e-8 of the cost): a stop before the minimum, or a wrong
    weight or Jacobian, leaves a gradient orders of magnitude above that."""
    scipy_optimize = pytest.importorskip("scipy.optimize")
    from bayesmap.slam.posegraph import CAUCHY_SCALE, optimize_pose_graph, robust_cost

    path, edges = _graph(seed, count=30)
    i = np.concatenate([edges.i, [5]])
    j = np.concatenate([edges.j, [25]])
    z = np.concatenate([edges.z, relative(path[5:6], path[25:26]) + [[1.5, 0.0, 0.0]]])
    edges = Edges(i, j, z, np.concatenate([edges.std, [[0.05, 0.05, 0.02]]]))
    rng = np.random.default_rng(seed + 10)
    start = path + np.concatenate([[[0, 0, 0]], rng.normal(0, [0.3, 0.3, 0.2], (len(path) - 1, 3))])
    ours = optimize_pose_graph(start, edges)
    fit = scipy_optimize.least_squares(lambda x: edge_residuals(np.vstack([start[:1], x.reshape(-1, 3)]),
                                                                edges).reshape(-1),
                                       start[1:].reshape(-1), loss="cauchy", f_scale=CAUCHY_SCALE, xtol=1e-12,
                                       ftol=1e-12, gtol=1e-12, max_nfev=5000)
    reference = np.vstack([start[:1], fit.x.reshape(-1, 3)])
    cost, reference_cost = robust_cost(ours, edges), robust_cost(reference, edges)
    assert cost <= reference_cost * (1 + 1e-6), (cost, reference_cost)
    first, second = edge_jacobians(ours, edges)
    f = edge_residuals(ours, edges)
    weight = 1.0 / (1.0 + (f / CAUCHY_SCALE) ** 2)
    gradient = np.zeros_like(ours)
    np.add.at(gradient, edges.i, np.einsum("eab,ea->eb", first, weight * f))
    np.add.at(gradient, edges.j, np.einsum("eab,ea->eb", second, weight * f))
    assert np.sum(gradient[1:] ** 2) < 1e-8 * cost, np.sum(gradient[1:] ** 2)


def test_a_second_loop_hypothesis_gets_its_share_of_the_samples():
    """graph_uncertainty with two loop hypotheses weighing 0.75 and 0.25: the first keeps the graph's edges, the
    second swaps a true loop edge for one a meter off. The samples split 1500 / 500 (``hypothesis_counts``); the
    second's are its own graph's optimum plus the chain's local deviations and its antithetic graph deviations (so
    each draw and its negative average to that optimum plus the chain's local mean); and the reported mean and
    covariance are the mixture's, which the 2,000 samples' own moments match within Monte Carlo error (4 standard
    errors of a variance from 1,000 antithetic pairs, as above; the mean within 4 standard errors of the samples'
    spread). A second hypothesis without any weight changes nothing, to the bit."""
    path, edges = _graph(seed=2)
    edges = with_step_covariances(edges, _covariances(np.random.default_rng(4), len(path) - 1))
    rng = np.random.default_rng(1)
    chain = path + rng.normal(0, 0.001, (2000, len(path), 3))
    chain[:, 0] = path[0]
    loops = edges.take(slice(len(path) - 1, None))
    false = relative(path[2:3], path[7:8]) + np.array([[1.0, 0.0, 0.0]])
    loops = Edges(np.append(loops.i, 2), np.append(loops.j, 7), np.concatenate([loops.z, false]),
                  np.concatenate([loops.std, loops.std[1:]]))
    two = LoopHypotheses([np.array([0, 1]), np.array([0, 2])], np.array([0.75, 0.25]), 2, loops)
    assert hypothesis_counts(2000, two.weights).tolist() == [1500, 500]
    assert hypothesis_counts(7, [0.5, 0.3, 0.2]).tolist() == [4, 2, 1]
    mean, cov, samples, graph_cov = graph_uncertainty(5, chain, edges, hypotheses=two)
    chain_mean, chain_cov = pose_summary(chain)
    sequential = edges.take(slice(0, len(path) - 1))  # the step covariances: the second graph's sequential edges
    second = optimize_pose_graph(chain_mean, concat_edges(sequential, loops.take([0, 2])))
    assert np.abs(second[:, :2] - chain_mean[:, :2]).max() > 0.3  # the false edge bends the path
    pairs = (samples[1500:1750] + samples[1750:]) / 2 - (chain[1500:1750] + chain[1750:]) / 2 + chain_mean
    np.testing.assert_allclose(pairs, np.broadcast_to(second, pairs.shape), atol=1e-9)
    np.testing.assert_allclose(mean[:, :2], 0.75 * chain_mean[:, :2] + 0.25 * second[:, :2], atol=1e-9)
    np.testing.assert_allclose(graph_cov, marginal_covariances(chain_mean, edges), rtol=1e-12)
    sample_mean, sample_cov = pose_summary(samples)
    spread = np.sqrt(cov[1:, [0, 1], [0, 1]] / 2000)
    assert np.all(np.abs(sample_mean[1:, :2] - mean[1:, :2]) <= 4 * spread)
    np.testing.assert_allclose(sample_cov[1:, [0, 1, 2], [0, 1, 2]] / cov[1:, [0, 1, 2], [0, 1, 2]], 1.0,
                               atol=4 * np.sqrt(2 / 1000))
    nothing = LoopHypotheses([np.array([0, 1]), np.array([0, 2])], np.array([1.0, 0.0]), 2, loops)
    for got, want in zip(graph_uncertainty(5, chain, edges, nothing), graph_uncertainty(5, chain, edges)):
        np.testing.assert_array_equal(got, want)


def _steps(lengths):
    """Odometry increments ``(S - 1, 3)`` straight ahead with the given lengths (meters)."""
    lengths = np.asarray(lengths, np.float64)
    return np.column_stack([lengths, np.zeros_like(lengths), np.zeros_like(lengths)])


def test_a_local_map_is_every_other_scan_of_ten_either_side_where_they_lie_within_travel():
    centers = np.array([0, 3, 15, 29])
    unlimited = np.clip(centers[:, None] + np.arange(-10, 11, 2), 0, 29)
    np.testing.assert_array_equal(local_map_neighbours(centers, _steps(np.full(29, 0.9)), 10.0), unlimited)
    np.testing.assert_array_equal(local_map_neighbours(centers, _steps(np.full(29, 2.0)), np.inf), unlimited)


def test_a_side_that_reaches_past_travel_spreads_its_scans_over_those_within_it():
    np.testing.assert_array_equal(local_map_neighbours([15], _steps(np.full(39, 2.0)), 10.0)[0], np.arange(10, 21))
    # 1 m steps before scan 15 (ten scans within 10 m), 3 m after it (three within 10 m: 3, 6, 9 m)
    lengths = np.concatenate([np.full(15, 1.0), np.full(20, 3.0)])
    row = local_map_neighbours([15], _steps(lengths), 10.0)[0]
    np.testing.assert_array_equal(row, [5, 7, 9, 11, 13, 15, 16, 16, 17, 17, 18])  # rint of 0.6, 1.2, ..., 3
    # the next scan already beyond travel: that side repeats the scan itself
    np.testing.assert_array_equal(local_map_neighbours([15], _steps(np.full(39, 12.0)), 10.0)[0], np.full(11, 15))


@settings(max_examples=200, deadline=None)
@given(lengths=st.lists(st.floats(0.0, 3.0), min_size=1, max_size=60), travel=st.floats(0.1, 30.0),
       where=st.floats(0.0, 1.0))
def test_every_local_map_scan_lies_within_travel_or_the_side_is_the_unlimited_one(lengths, travel, where):
    steps = _steps(lengths)
    last = len(lengths)
    s = int(round(where * last))
    row = local_map_neighbours([s], steps, travel)[0]
    along = np.concatenate([[0.0], np.cumsum(lengths)])
    assert row.shape == (11,) and row[5] == s and np.all(np.diff(row) >= 0)
    for side, sign in ((row[:5][::-1], -1), (row[6:], 1)):
        unlimited = np.clip(s + sign * np.arange(2, 11, 2), 0, last)
        reach = np.clip(s + sign * np.arange(11), 0, last)
        if np.all(np.abs(along[reach] - along[s]) <= travel):
            np.testing.assert_array_equal(side, unlimited)
            continue
        assert np.all(np.abs(along[side] - along[s]) <= travel)
        farthest = side[-1]  # the farthest scan within travel: the next one along is beyond it
        assert abs(along[farthest + sign] - along[s]) > travel


@pytest.mark.parametrize("travel", [0.0, -1.0, True, "10"])
def test_local_map_neighbours_refuse_a_bad_travel(travel):
    with pytest.raises(BayesmapError, match="travel"):
        local_map_neighbours([0], _steps([1.0, 1.0]), travel)


@pytest.mark.parametrize("center", [-1, 3])
def test_local_map_neighbours_refuse_a_scan_outside_the_log(center):
    with pytest.raises(BayesmapError, match="centers"):
        local_map_neighbours([center], _steps([1.0, 1.0]), 10.0)


def test_the_laplace_approximation_reads_the_loop_edges_posteriors():
    """graph_uncertainty's loop_posterior: the graph's covariance is that of the sequential edges and the loop edges
    with the covariances it returns (here 1 cm and 0.003 rad, against the graph's 2-10 cm), narrower than with the
    edges' own deviations; the mean path stays the chain's."""
    path, edges = _graph(seed=2)
    count = len(path)
    rng = np.random.default_rng(0)
    chain = path + rng.normal(0, 0.001, (200, count, 3))
    chain[:, 0] = path[0]

    def narrow(loops):
        return with_covariances(loops, np.tile(np.diag([1e-4, 1e-4, 9e-6]), (len(loops.i), 1, 1)))

    mean, _, _, graph_cov = graph_uncertainty(5, chain, edges, loop_posterior=narrow)
    chain_mean = pose_summary(chain)[0]
    np.testing.assert_allclose(mean, chain_mean, atol=1e-12)
    expected = marginal_covariances(chain_mean, concat_edges(edges.take(slice(0, count - 1)),
                                                             narrow(edges.take(slice(count - 1, None)))))
    np.testing.assert_allclose(graph_cov, expected, rtol=1e-12)
    plain = marginal_covariances(chain_mean, edges)
    assert np.trace(graph_cov[count // 2, :2, :2]) < 0.9 * np.trace(plain[count // 2, :2, :2])
