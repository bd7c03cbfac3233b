import numpy as np
import pytest
import yaml
from conftest import random_joints
from plain_dh import fk

from fgcal.robots.kinematics import forward, jacobians
from fgcal.robots.model import SLOT_IS_ANGLE, SLOT_NAMES
from fgcal.robots.transforms import so3_log
from fgcal.util.resources import builtin_robot_path


def test_puma_tool_origin_at_zero(puma):
    T = forward(puma.nominal, np.zeros(6))[0]
    np.testing.assert_allclose(T[:3, 3], [750.05, 52.1, 1038.05], atol=1e-9)


@pytest.mark.parametrize("name", ["puma560", "ur10", "ur5"])
def test_fk_matches_plain_dh_table(name):
    """The model file's raw table (6-link UR tables before folding) through plain 4x4 DH."""
    from fgcal.robots.robot_file import load_model

    model = load_model(name)
    raw = yaml.safe_load(builtin_robot_path(name).read_text())
    q = random_joints(model, 25, seed=1)
    T = forward(model.nominal, q)
    for i in range(len(q)):
        expected = fk(raw["base"], raw["links"], raw["tool"], np.degrees(q[i]))
        np.testing.assert_allclose(T[i], expected, atol=1e-9)


def _perturbed(model, seed):
    rng = np.random.default_rng(seed)
    x = model.nominal.copy()
    x += np.where(SLOT_IS_ANGLE, np.radians(0.5), 2.0) * rng.normal(size=x.shape)
    return x


def _pose_vector_diff(Ta, Tb):
    return np.concatenate([Ta[:3, 3] - Tb[:3, 3], so3_log(Ta[:3, :3] @ Tb[:3, :3].T)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_slot_and_joint_jacobians_match_finite_differences(puma, seed):
    x = _perturbed(puma, seed)  # every slot, betas included, away from nominal
    q = random_joints(puma, 4, seed=10 + seed)
    offsets = np.array([[60.0, 0, 0], [0, -90.0, 0], [0, 0, 40.0]])
    jac = jacobians(x, q, offsets=offsets)
    h = 1e-6
    for k in range(len(SLOT_NAMES)):
        e = np.zeros_like(x)
        e[k] = h
        Tp, Tm = forward(x + e, q), forward(x - e, q)
        jp, jm = jacobians(x + e, q, offsets), jacobians(x - e, q, offsets)
        for i in range(len(q)):
            num = (_pose_vector_diff(Tp[i], Tm[i])) / (2 * h)
            np.testing.assert_allclose(jac.pose_slots[i, :, k], num, atol=1e-5, rtol=1e-6, err_msg=SLOT_NAMES[k])
        np.testing.assert_allclose(jac.point_slots[..., k], (jp.points - jm.points) / (2 * h), atol=1e-5,
                                   err_msg=SLOT_NAMES[k])
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        Tp, Tm = forward(x, q + e), forward(x, q - e)
        jp, jm = jacobians(x, q + e, offsets), jacobians(x, q - e, offsets)
        for i in range(len(q)):
            num = _pose_vector_diff(Tp[i], Tm[i]) / (2 * h)
            np.testing.assert_allclose(jac.pose_joints[i, :, j], num, atol=1e-5, rtol=1e-6)
        np.testing.assert_allclose(jac.point_joints[..., j], (jp.points - jm.points) / (2 * h), atol=1e-5)


def test_jacobian_detects_a_wrong_sign(puma):
    """The finite-difference comparison is sharp: a flipped column would fail it."""
    x = _perturbed(puma, 5)
    q = random_joints(puma, 1, seed=5)
    col = jacobians(x, q).pose_slots[0, :3, SLOT_NAMES.index("j3.a")]
    e = np.zeros_like(x)
    e[SLOT_NAMES.index("j3.a")] = 1e-6
    num = (forward(x + e, q)[0, :3, 3] - forward(x - e, q)[0, :3, 3]) / 2e-6
    assert np.linalg.norm(col - num) < 1e-6 < np.linalg.norm(-col - num)


def test_forward_checks_shapes(puma):
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        forward(puma.nominal, np.zeros((3, 5)))
    with pytest.raises(ValueError, match=r"\(37,\)"):
        forward(puma.nominal[:30], np.zeros(6))
