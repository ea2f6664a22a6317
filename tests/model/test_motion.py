"""The odometry motion model (bayesmap.model.motion): controls, composition, sampling against the density."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64
from scipy import stats

from bayesmap.errors import BayesmapError
from bayesmap.model import motion


def test_controls_of_a_known_path():
    """PR Table 5.5 on hand-made steps: a pure rotation (rot1 = 0), a forward move, a move to the left and back."""
    with enable_x64():
        odo = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [2.0 * np.cos(0.5), 2.0 * np.sin(0.5), 0.5],
                        [2.0 * np.cos(0.5) - 3 * np.sin(0.5), 2.0 * np.sin(0.5) + 3 * np.cos(0.5), np.pi - 0.1]])
        parts = np.asarray(motion.odometry_decomposition(jnp.asarray(odo)))
        np.testing.assert_allclose(parts[0], [0.0, 0.0, 0.5], atol=1e-12)
        np.testing.assert_allclose(parts[1], [0.0, 2.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(parts[2], [np.pi / 2, 3.0, np.pi - 0.1 - 0.5 - np.pi / 2], atol=1e-12)
        inc, cov = motion.odometry_controls(odo)
        np.testing.assert_allclose(np.asarray(inc), [[0, 0, 0.5], [2, 0, 0], [0, 3, np.pi - 0.6]], atol=1e-12)
        # composing the increments from the first odometry pose gives the odometry back
        path = [odo[0]]
        for d in np.asarray(inc):
            path.append(np.asarray(motion.compose(path[-1], d)))
        np.testing.assert_allclose(np.array(path), odo, atol=1e-12)
        # Sigma of the pure rotation: std(rot2) = a1 * 0.5, std(trans) = a4 * 0.5, plus the floors
        p = motion.MotionParams()
        v = np.array([[0, 1, 0], [0, 0, 0], [1, 0, 1]])  # V at rot1 = 0, trans = 0
        m = np.diag([0.0, (p.a4 * 0.5) ** 2, (p.a1 * 0.5) ** 2])
        want = v @ m @ v.T + np.diag([p.floor_xy ** 2, p.floor_xy ** 2, p.floor_theta ** 2])
        np.testing.assert_allclose(np.asarray(cov[0]), want, atol=1e-15)


def test_heading_wraps_in_controls_not_in_state():
    """A turn across +-pi is a small rotation in the control; the composed heading keeps counting (no wrap)."""
    with enable_x64():
        odo = np.array([[0.0, 0.0, np.pi - 0.05], [0.0, 0.0, -np.pi + 0.05]])
        inc, _ = motion.odometry_controls(odo)
        np.testing.assert_allclose(np.asarray(inc[0]), [0, 0, 0.1], atol=1e-12)
        assert float(motion.compose(odo[0], inc[0])[2]) == pytest.approx(np.pi + 0.05)


def test_motion_logpdf_equals_scipy_multivariate_normal():
    with enable_x64():
        rng = np.random.default_rng(0)
        odo = np.cumsum(rng.normal(0, 0.5, (6, 3)), axis=0)
        inc, cov = motion.odometry_controls(odo, motion.make_motion_params((0.2, 0.1, 0.15, 0.05), 0.02, 0.01))
        for t in range(5):
            prev = rng.normal(0, 2, 3)
            cands = prev + rng.normal(0, 0.7, (20, 3))
            got = np.asarray(motion.motion_logpdf(prev, cands, inc[t], cov[t]))
            c, s = np.cos(prev[2]), np.sin(prev[2])
            d = cands - prev
            err = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], -1) - np.asarray(inc[t])
            want = stats.multivariate_normal(np.zeros(3), np.asarray(cov[t])).logpdf(err)
            np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10)


def test_one_step_samples_match_the_density():
    """Mean and covariance of 20,000 one-step errors against the increment and Sigma. Monte Carlo error of a sample
    mean is sigma / sqrt(n) (5 standard errors allowed); of a sample covariance entry about
    sqrt((S_ii S_jj + S_ij^2) / n) (Wishart), also 5 standard errors."""
    with enable_x64():
        odo = np.array([[1.0, 2.0, 0.3], [1.8, 2.9, 1.1]])
        inc, cov = motion.odometry_controls(odo, motion.make_motion_params((0.2, 0.1, 0.2, 0.1), 0.02, 0.01))
        n = 20000
        keys = jax.random.split(jax.random.key(3), n)
        poses = np.asarray(jax.vmap(lambda k: motion.sample_path(k, odo[0], inc, cov)[1])(keys))
        err = np.asarray(motion.motion_error(odo[0], poses, inc[0]))
        sigma = np.asarray(cov[0])
        sd = np.sqrt(np.diag(sigma))
        assert np.all(np.abs(err.mean(0)) < 5 * sd / np.sqrt(n))
        se_cov = np.sqrt((np.outer(np.diag(sigma), np.diag(sigma)) + sigma ** 2) / n)
        assert np.all(np.abs(np.cov(err.T) - sigma) < 5 * se_cov)
        # and the path's density is the density of these errors (unit Jacobian)
        got = float(motion.path_logpdf(np.stack([odo[0], poses[0]]), odo[0], inc, cov))
        assert got == pytest.approx(stats.multivariate_normal(np.zeros(3), sigma).logpdf(err[0]), abs=1e-9)


def test_zero_noise_is_the_odometry_path():
    zero = motion.make_motion_params((0, 0, 0, 0), 0, 0)
    odo = np.array([[1.0, 2.0, 0.3], [1.8, 2.9, 1.1], [1.8, 2.9, 1.1], [0.5, 3.5, 2.9]])
    inc, cov = motion.odometry_controls(odo, zero)
    assert np.all(np.asarray(cov) == 0)
    path = motion.sample_path(jax.random.key(0), odo[0], inc, cov)
    np.testing.assert_allclose(np.asarray(path[:, :2]), odo[:, :2], atol=1e-5)
    np.testing.assert_allclose(np.asarray(path[:, 2]), odo[:, 2], atol=1e-5)
    assert float(motion.path_logpdf(path, odo[0], inc, cov)) == 0.0
    moved = path.at[2, 0].add(0.01)
    assert float(motion.path_logpdf(moved, odo[0], inc, cov)) == -np.inf
    assert float(motion.path_logpdf(path.at[0, 1].add(0.01), odo[0], inc, cov)) == -np.inf  # pose 0 is fixed


def test_odometry_path_distribution_is_sample_and_logpdf():
    inc, cov = motion.odometry_controls(np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.1], [1.5, 1.0, 0.9]]))
    first = jnp.zeros(3)
    trace = motion.odometry_path.simulate(jax.random.key(1), (first, inc, cov))
    later = trace.get_retval()
    assert later.shape == (2, 3)
    want = motion.path_logpdf(jnp.concatenate([first[None], later]), first, inc, cov)
    assert float(trace.get_score()) == pytest.approx(float(want), abs=1e-5)


@pytest.mark.parametrize("kwargs, word", [({"alphas": (0.1, 0.1, 0.1)}, "alphas"),
                                          ({"alphas": (0.1, -0.1, 0.1, 0.1)}, "a2"),
                                          ({"floor_xy": float("nan")}, "floor_xy"),
                                          ({"floor_theta": 0.0}, "floor_theta=0.0")])
def test_bad_motion_params_name_the_value(kwargs, word):
    with pytest.raises(BayesmapError, match=word):
        motion.make_motion_params(**kwargs)


def test_bad_odometry_is_an_error():
    with pytest.raises(BayesmapError, match=r"\(4,\)"):
        motion.odometry_controls(np.zeros(4))


def test_composed_steps_are_the_odometrys_relative_poses_and_one_step_is_odometry_controls():
    """The composed increment from scan a to scan b is b's odometry pose in a's frame; a single step is the
    step of ``odometry_controls``, its increment and covariance; no step is zero."""
    from bayesmap.slam.posegraph import relative

    odometry = np.array([[0, 0, 0.1], [0.1, 0.02, 0.3], [0.2, 0.1, 0.2], [0.25, 0.2, 0.9], [0.2, 0.3, 1.6]])
    inc, cov = motion.composed_steps(odometry, [0, 1, 2, 3], [4, 2, 2, 4])
    np.testing.assert_allclose(inc[0, :2], relative(odometry[0], odometry[4])[:2], atol=1e-6)
    np.testing.assert_allclose(inc[0, 2], odometry[4, 2] - odometry[0, 2], atol=1e-6)
    one_inc, one_cov = motion.odometry_controls(odometry)
    np.testing.assert_allclose(inc[1], np.asarray(one_inc)[1], atol=1e-6)
    np.testing.assert_allclose(cov[1], np.asarray(one_cov)[1], rtol=1e-5, atol=1e-12)
    assert np.all(inc[2] == 0) and np.all(cov[2] == 0)


def test_composed_steps_covariance_is_that_of_the_composed_noisy_steps():
    """Drawing each step's error from its covariance (in the frame of the pose it starts from) and composing the
    noisy steps exactly, the composed step's error has the propagated covariance: within 6 % on the diagonal
    (20,000 draws: the standard error of a variance estimate is sqrt(2 / 20000) = 1 %; first-order propagation
    of errors of a few centimeters and hundredths of a radian adds at most a few percent), and the heading's
    lever arm shows as a position variance far above the sum of the steps' own."""
    t = np.linspace(0, 1.5, 16)
    odometry = np.stack([np.cos(t), np.sin(t), t + np.pi / 2], axis=1)
    params = motion.make_motion_params((0.2, 0.1, 0.1, 0.05), floor_xy=0.005, floor_theta=0.01)
    inc, cov = (np.asarray(a, np.float64) for a in motion.odometry_controls(odometry, params))
    want_inc, want_cov = motion.composed_steps(odometry, [0], [15], params)
    rng = np.random.default_rng(0)
    n = 20000
    pose = np.zeros((n, 3))
    for u, q in zip(inc, cov):
        e = rng.multivariate_normal(np.zeros(3), q, size=n)
        du = u + e
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        pose = pose + np.stack([c * du[:, 0] - s * du[:, 1], s * du[:, 0] + c * du[:, 1], du[:, 2]], axis=1)
    err = pose - want_inc[0]
    np.testing.assert_allclose(err.mean(axis=0), 0, atol=0.01)
    np.testing.assert_allclose(np.diag(np.cov(err.T)), np.diag(want_cov[0]), rtol=0.06)
    assert want_cov[0, 0, 0] + want_cov[0, 1, 1] > 2 * (cov[:, 0, 0] + cov[:, 1, 1]).sum()


def test_a_step_shorter_than_the_floor_radius_has_no_direction():
    """A step of 2 cm (below UNDIRECTED_RADIUS floors: 3.03 cm at the default 1 cm floor) gets, on its heading, the
    variance of PR's two rotation noises for a direction uniform on the circle, 2 a1^2 pi^2 / 3, on top of PR's own
    covariance; a 4 cm step and a standing robot (no translation: PR's rot1 = 0) keep PR's. Forward or backward,
    the same 2 cm step gets the same addition. That addition is the variance PR's sampling model (Table 5.6, as
    tools/noisy_odometry.py applies it to the true motion) gives a jitter step of uniform direction: its heading
    error n1 + n2, n_i ~ N(0, a1 |rot_i|), rot1 ~ U(-pi, pi), rot2 = -rot1, over 200,000 draws, within 5 standard
    errors of the sample variance."""
    p = motion.MotionParams()
    assert motion.UNDIRECTED_RADIUS * p.floor_xy == pytest.approx(0.0303, abs=1e-4)
    extra = 2.0 * (p.a1 * np.pi) ** 2 / 3.0
    with enable_x64():
        for heading in (0.0, np.pi):  # forward and backward
            for dist, added in ((0.02, extra), (0.04, 0.0), (0.0, 0.0)):
                end = [1.0 + dist * np.cos(0.3 + heading), 2.0 + dist * np.sin(0.3 + heading), 0.5]
                odo = np.array([[1.0, 2.0, 0.3], end])
                _, cov = motion.odometry_controls(odo, p)
                rot1, trans, rot2 = np.asarray(motion.odometry_decomposition(jnp.asarray(odo)))[0]
                std = np.array([p.a1 * abs(rot1) + p.a2 * trans, p.a3 * trans + p.a4 * (abs(rot1) + abs(rot2)),
                                p.a1 * abs(rot2) + p.a2 * trans])
                v = np.array([[-trans * np.sin(rot1), np.cos(rot1), 0], [trans * np.cos(rot1), np.sin(rot1), 0],
                              [1, 0, 1]])
                pr = v @ np.diag(std ** 2) @ v.T + np.diag([p.floor_xy ** 2, p.floor_xy ** 2, p.floor_theta ** 2])
                np.testing.assert_allclose(np.asarray(cov[0]), pr + np.diag([0.0, 0.0, added]), rtol=1e-12,
                                           atol=1e-15)
    rng = np.random.default_rng(0)
    rot1 = rng.uniform(-np.pi, np.pi, 200_000)
    error = rng.normal(0.0, p.a1 * np.abs(rot1)) + rng.normal(0.0, p.a1 * np.abs(rot1))
    sample = np.mean(error ** 2)
    assert abs(sample - extra) < 5 * np.std(error ** 2) / np.sqrt(error.size)


def test_the_tailed_motion_density_is_the_two_normals_mixture():
    """``tailed_motion_logpdf`` is ``log((1 - w) N(e; Sigma) + w N(e; Sigma + T))`` of the motion error, as scipy's
    Normals give it (1e-10); at ``w = 0``, and on a deterministic (zero-covariance) step, it is ``motion_logpdf``
    bit for bit; far from the odometry's step the tail, not the Normal, sets it."""
    tail = motion.backward_step_covariance()
    with enable_x64():
        rng = np.random.default_rng(1)
        odo = np.cumsum(rng.normal(0, 0.5, (4, 3)), axis=0)
        inc, cov = motion.odometry_controls(odo, motion.MotionParams())
        for t in range(3):
            prev = rng.normal(0, 2, 3)
            cands = np.asarray(motion.compose(jnp.asarray(prev), jnp.asarray(inc[t]))) + rng.normal(0, 0.3, (30, 3))
            err = np.asarray(motion.motion_error(prev, cands, inc[t]))
            for w in (0.01, 0.3):
                got = np.asarray(motion.tailed_motion_logpdf(prev, cands, inc[t], cov[t], w, tail))
                narrow = stats.multivariate_normal(np.zeros(3), np.asarray(cov[t])).pdf(err)
                wide = stats.multivariate_normal(np.zeros(3), np.asarray(cov[t]) + tail).pdf(err)
                np.testing.assert_allclose(got, np.log((1 - w) * narrow + w * wide), rtol=1e-10, atol=1e-10)
            plain = motion.motion_logpdf(prev, cands, inc[t], cov[t])
            assert np.array_equal(motion.tailed_motion_logpdf(prev, cands, inc[t], cov[t], 0.0, tail), plain)
        far = np.asarray(motion.compose(jnp.asarray(prev), jnp.asarray(inc[2]))) + np.array([0.0, 0.0, 1.0])
        assert (motion.tailed_motion_logpdf(prev, far, inc[2], cov[2], 0.01, tail)
                > motion.motion_logpdf(prev, far, inc[2], cov[2]) + 20)
        zero = jnp.zeros((3, 3))
        on = motion.compose(jnp.asarray(prev), jnp.asarray(inc[0]))
        for pose in (on, on + 0.1):
            assert (motion.tailed_motion_logpdf(prev, pose, inc[0], zero, 0.01, tail)
                    == motion.motion_logpdf(prev, pose, inc[0], zero))


def test_the_backward_steps_covariance_is_what_pr_gives_a_step_back():
    """A robot that backs up 1 cm, as ``simulate_odometry`` (PR Table 5.6, as tools/noisy_odometry.py) reports it
    under the default alphas: two half turns, so the heading errs with variance 2 (a1 pi)^2 and the translation along
    the step with (2 pi a4)^2, the diagonal of ``backward_step_covariance``. The heading's noise (0.31 rad on the
    first turn) turns part of the translation's error across the step, so the position error's total variance is
    the translation's and neither axis exceeds the claimed (isotropic) one. 40,000 draws: a variance's standard
    error is sqrt(2 / 40000) = 0.7 %; the terms the covariance leaves out (a2 and a3 times 1 cm) add 0.3-0.6 %: 4 %."""
    p = motion.MotionParams()
    alphas = (p.a1, p.a2, p.a3, p.a4)
    want = motion.backward_step_covariance(p)
    np.testing.assert_allclose(np.diag(want), [(2 * np.pi * p.a4) ** 2] * 2 + [2 * (np.pi * p.a1) ** 2])
    truth = np.array([[0.0, 0.0, 0.0], [-0.01, 0.0, 0.0]])
    from bayesmap.slam.problem import simulate_odometry

    ends = np.array([simulate_odometry(truth, alphas, seed)[1] for seed in range(40_000)])
    error = np.stack([ends[:, 0] + 0.01, ends[:, 1], motion.wrap_angle(ends[:, 2])], axis=1)
    var = error.var(axis=0)
    np.testing.assert_allclose(var[2], want[2, 2], rtol=0.04)
    np.testing.assert_allclose(var[0] + var[1], want[0, 0], rtol=0.04)
    assert np.all(var[:2] < 1.04 * np.diag(want)[:2])
