"""Every factor's analytic Jacobian against gtsam.utils.numerical_derivative at seeded random points."""
import gtsam
import numpy as np
import pytest
from conftest import random_joints
from gtsam.utils.numerical_derivative import numericalDerivative11

import factors
from fgcal.robots.kinematics import forward
from fgcal.robots.model import SLOT_IS_ANGLE
from fgcal.robots.transforms import quaternion_to_matrix


def _setup(puma, seed):
    rng = np.random.default_rng(seed)
    params = puma.parameters()
    held = puma.nominal + np.where(SLOT_IS_ANGLE, np.radians(0.3), 1.0) * rng.normal(size=37)
    theta = params.take(held)
    q = random_joints(puma, 1, seed=seed)[0]
    return rng, params.index, held, theta, q


def _check(factor, values, delta=1e-6, atol=1e-6):
    """Compare the factor's whitened Jacobian blocks with numerical derivatives of its whitened error."""
    jf = factor.linearize(values)
    A, _ = jf.jacobian()
    col = 0
    for key in factor.keys():
        x0 = values.atVector(key)

        def h(x, key=key):
            v = gtsam.Values(values)
            v.update(key, x)
            return factor.whitenedError(v)

        num = numericalDerivative11(h, x0, delta)
        analytic = A[:, col:col + len(x0)]
        np.testing.assert_allclose(analytic, num, atol=atol * max(1.0, np.abs(num).max()), rtol=1e-5)
        col += len(x0)
    assert col == A.shape[1]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_probe_factor(seed):
    rng = np.random.default_rng(seed)
    c = rng.uniform(0, 1000, 3)
    p = c + 6.35 * rng.normal(size=3) / 2
    f = factors.probe_factor(factors.centre_key(0), p, 6.35, 0.01)
    v = gtsam.Values()
    v.insert(factors.centre_key(0), c)
    _check(f, v)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("variant", ["variables", "measured centre, fixed joints"])
def test_ball_centre_factor(puma, seed, variant):
    rng, index, held, theta, q = _setup(puma, seed)
    offset = np.array([0.0, -90.0, 0.0])
    T = forward(held, q)[0]
    c = T[:3, :3] @ offset + T[:3, 3] + rng.normal(size=3)
    v = gtsam.Values()
    v.insert(factors.theta_key(), theta)
    if variant == "variables":
        v.insert(factors.joint_key(0), q)
        v.insert(factors.centre_key(0), c)
        f = factors.ball_centre_factor(index, held, offset, 0.01, t_key=factors.theta_key(),
                                       q_key=factors.joint_key(0), c_key=factors.centre_key(0))
    else:
        f = factors.ball_centre_factor(index, held, offset, 0.01, t_key=factors.theta_key(), q_fixed=q, c_measured=c)
    _check(f, v)
    # the unwhitened error is exactly FK * offset - centre
    np.testing.assert_allclose(f.unwhitenedError(v), T[:3, :3] @ offset + T[:3, 3] - c, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pose_factor(puma, seed):
    rng, index, held, theta, q = _setup(puma, seed)
    T = forward(held, q)[0]
    T_meas = np.eye(4)
    T_meas[:3, :3] = quaternion_to_matrix(np.r_[1.0, 0.2 * rng.normal(size=3)]) @ T[:3, :3]  # ~20 deg off
    T_meas[:3, 3] = T[:3, 3] + rng.normal(size=3)
    v = gtsam.Values()
    v.insert(factors.theta_key(), theta)
    v.insert(factors.joint_key(0), q)
    f = factors.pose_factor(index, held, T_meas, 1e-4, 0.01, t_key=factors.theta_key(), q_key=factors.joint_key(0))
    _check(f, v)


def test_priors(puma):
    rng, index, held, theta, q = _setup(puma, 3)
    v = gtsam.Values()
    v.insert(factors.theta_key(), theta)
    v.insert(factors.joint_key(0), q)
    _check(factors.joint_prior(factors.joint_key(0), q + 1e-4, 5e-5), v)
    _check(factors.parameter_prior(factors.theta_key(), theta * 0.99, np.full(len(theta), 0.1)), v)


def test_the_check_catches_a_wrong_jacobian():
    """A deliberately wrong analytic Jacobian fails the same comparison."""
    key = factors.centre_key(0)
    p = np.array([1.0, 2.0, 3.0])

    def error(this, values, H):
        c = values.atVector(key)
        if H is not None:
            H[0] = ((p - c) / np.linalg.norm(p - c))[None]  # sign flipped
        return np.array([np.linalg.norm(p - c) - 1.0])

    f = gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, 0.1), [key], error)
    v = gtsam.Values()
    v.insert(key, np.array([0.5, 0.5, 0.5]))
    with pytest.raises(AssertionError):
        _check(f, v)


def test_robust_noise_models():
    assert isinstance(factors.noise_model([1.0], "huber"), gtsam.noiseModel.Robust)
    assert isinstance(factors.noise_model([1.0], "cauchy"), gtsam.noiseModel.Robust)
    with pytest.raises(ValueError, match="unknown robust"):
        factors.noise_model([1.0], "tukey-ish")


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("robot", ["puma", "prismatic"])
def test_distance_factor(puma, seed, robot):
    """A ballbar length: both blocks (parameters, joint variables), on the PUMA and on a chain with a
    prismatic joint and a coupling."""
    from test_chains import PRISMATIC

    from fgcal.robots.robot_file import model_from_dict

    model = puma if robot == "puma" else model_from_dict(dict(PRISMATIC, coupling={
        "matrix": [[1, 0, 0, 0, 0, 0], [0.5, 1, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0], [0, 0, 0, 1, 0, 0],
                   [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]]}))
    rng = np.random.default_rng(seed)
    params = model.parameters()
    held = model.nominal + np.where(model.slot_is_angle, np.radians(0.3), 1.0) * rng.normal(size=len(model.nominal))
    theta = params.take(held)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    q = rng.uniform(lo, hi)
    offset = np.array([60.0, 0.0, 30.0])
    f = factors.distance_factor(params.index, held, offset, 800.0, 0.01, t_key=factors.theta_key(),
                                q_key=factors.joint_key(0), chain=model.chain)
    v = gtsam.Values()
    v.insert(factors.theta_key(), theta)
    v.insert(factors.joint_key(0), q)
    _check(f, v)


@pytest.mark.parametrize("seed", [0, 1])
def test_pose_centres_factor_is_its_ball_centre_factors(puma, seed):
    """The grouped factor of a pose's ball centres: analytic Jacobians against numerical ones, and
    the same whitened rows as one ball_centre_factor per ball."""
    rng, index, held, theta, q = _setup(puma, seed)
    offsets = np.array([[60.0, 0, 0], [0, 60.0, 0], [0, -90.0, 0]])
    T = forward(held, q)[0]
    v = gtsam.Values()
    v.insert(factors.theta_key(), theta)
    v.insert(factors.joint_key(0), q)
    keys = [factors.centre_key(b) for b in range(3)]
    for k, o in zip(keys, offsets, strict=True):
        v.insert(k, T[:3, :3] @ o + T[:3, 3] + rng.normal(size=3))
    f = factors.pose_centres_factor(index, held, offsets, 1e-2, t_key=factors.theta_key(), c_keys=keys,
                                    q_key=factors.joint_key(0))
    _check(f, v)
    one = [factors.ball_centre_factor(index, held, o, 1e-2, t_key=factors.theta_key(), q_key=factors.joint_key(0),
                                      c_key=k) for k, o in zip(keys, offsets, strict=True)]
    np.testing.assert_allclose(f.whitenedError(v), np.concatenate([g.whitenedError(v) for g in one]), rtol=1e-12)
    assert f.error(v) == pytest.approx(sum(g.error(v) for g in one), rel=1e-12)


def test_pose_probes_factor_is_its_probe_factors():
    rng = np.random.default_rng(4)
    centres = rng.uniform(0, 1000, (3, 3))
    owner = np.array([0, 0, 1, 2, 1, 2, 0])
    points = centres[owner] + 6.35 * rng.normal(size=(7, 3)) / 2
    keys = [factors.centre_key(b) for b in range(3)]
    v = gtsam.Values()
    for k, c in zip(keys, centres, strict=True):
        v.insert(k, c)
    f = factors.pose_probes_factor(keys, owner, points, 6.35, 0.01)
    _check(f, v)
    one = [factors.probe_factor(keys[b], p, 6.35, 0.01) for b, p in zip(owner, points, strict=True)]
    np.testing.assert_allclose(f.whitenedError(v), np.concatenate([g.whitenedError(v) for g in one]), rtol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("variant", ["joint variables", "fixed joints, one centre's rows excluded"])
def test_pose_balls_factor_is_its_probe_and_centre_factors(puma, seed, variant):
    """One pose's balls in one factor: analytic Jacobians against numerical ones, and the same
    whitened rows (and error) as its probe_factors followed by its ball_centre_factors."""
    rng, index, held, theta, q = _setup(puma, seed)
    offsets = np.array([[60.0, 0, 0], [0, 60.0, 0], [0, -90.0, 0]])
    T = forward(held, q)[0]
    centres = offsets @ T[:3, :3].T + T[:3, 3] + rng.normal(size=(3, 3))
    owner = np.array([0, 1, 2, 0, 1, 2, 2, 0, 1, 1])
    d = rng.normal(size=(len(owner), 3))
    points = centres[owner] + 6.35 * d / np.linalg.norm(d, axis=1, keepdims=True) + 0.01 * rng.normal(size=(len(owner), 3))
    keys = [factors.centre_key(b) for b in range(3)]
    v = gtsam.Values()
    v.insert(factors.theta_key(), theta)
    for k, c in zip(keys, centres, strict=True):
        v.insert(k, c)
    kinematic = np.array([True, True, True]) if variant == "joint variables" else np.array([True, False, True])
    if variant == "joint variables":
        v.insert(factors.joint_key(0), q)
        qargs = {"q_key": factors.joint_key(0)}
    else:
        qargs = {"q_fixed": q}
    f = factors.pose_balls_factor(index, held, keys, offsets, points, owner, 6.35, 0.01, 0.02,
                                  t_key=factors.theta_key(), kinematic=kinematic, **qargs)
    _check(f, v)
    one = [factors.probe_factor(keys[b], p, 6.35, 0.01) for b, p in zip(owner, points, strict=True)]
    one += [factors.ball_centre_factor(index, held, offsets[b], 0.02, t_key=factors.theta_key(), c_key=keys[b], **qargs)
            for b in np.flatnonzero(kinematic)]
    np.testing.assert_allclose(f.whitenedError(v), np.concatenate([g.whitenedError(v) for g in one]), rtol=1e-12)
    assert f.error(v) == pytest.approx(sum(g.error(v) for g in one), rel=1e-12)


def test_ball_centre_along_is_the_ball_centre_error_projected(puma):
    """factors.errors.ball_centre_along (a plane contact's kinematics): the ball centre of
    ball_centre_error and its Jacobians along the directions, to rounding."""
    from factors.errors import ball_centre_along, ball_centre_error

    rng, index, held, theta, _ = _setup(puma, 4)
    q = random_joints(puma, 9, seed=4)
    offset = rng.normal(size=(9, 3)) * 50
    u = rng.normal(size=(9, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    c, J_t, J_q = ball_centre_along(theta, q, offset, u, index, held, puma.chain)
    e, J_t3, J_q3 = ball_centre_error(theta, q, offset, np.zeros((9, 3)), index, held, puma.chain)
    np.testing.assert_allclose(c, e, rtol=0, atol=1e-9)
    np.testing.assert_allclose(J_t, u[:, None, :] @ J_t3, rtol=0, atol=1e-9)
    np.testing.assert_allclose(J_q, u[:, None, :] @ J_q3, rtol=0, atol=1e-9)
    assert J_t.shape == (9, 1, len(index)) and J_q.shape == (9, 1, puma.n_joints)
