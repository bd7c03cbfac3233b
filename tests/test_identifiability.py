import numpy as np
import pytest
from conftest import random_joints

from fgcal.robots.identifiability import analyse, identification_jacobian


@pytest.mark.parametrize("robot", ["puma", "ur10"])
def test_full_pose_identifies_all_30(robot, request):
    model = request.getfixturevalue(robot)
    params = model.parameters()
    assert len(params) == 30
    result = analyse(identification_jacobian(params, random_joints(model, 20, seed=3)), params.names)
    assert result.rank == 30
    assert result.redundant == {}
    assert np.isfinite(result.condition_number)


def test_puma_parameter_names_follow_design(puma):
    assert puma.identifiable_names() == (
        "base.phi base.theta base.psi base.px base.py base.pz j1.a j1.alpha j2.theta j2.beta j2.a j2.alpha "
        "j3.theta j3.d j3.a j3.alpha j4.theta j4.d j4.a j4.alpha j5.theta j5.d j5.a j5.alpha "
        "tool.phi tool.theta tool.psi tool.px tool.py tool.pz").split()


def test_ur10_takes_beta_on_joints_2_and_3(ur10):
    names = ur10.identifiable_names()
    assert {"j2.beta", "j3.beta"} <= set(names) and not {"j2.d", "j3.d"} & set(names)


@pytest.mark.parametrize("extra, partners", [
    ("j1.theta", {"base.phi"}),
    ("j1.d", {"base.pz"}),
    ("j2.d", {"j3.d"}),
])
def test_redundant_parameter_is_named(puma, extra, partners):
    params = puma.parameters(extra=[extra])
    result = analyse(identification_jacobian(params, random_joints(puma, 20, seed=4)), params.names)
    assert result.rank == 30
    assert list(result.redundant) == [extra]
    assert partners <= set(result.redundant[extra])


def test_position_only_loses_tool_orientation(puma):
    params = puma.parameters()
    J = identification_jacobian(params, random_joints(puma, 30, seed=5), measurement="position")
    result = analyse(J, params.names)
    assert result.rank == 26
    assert len(result.redundant) == 4


def test_too_few_poses_is_rank_deficient(puma):
    params = puma.parameters()
    result = analyse(identification_jacobian(params, random_joints(puma, 4, seed=6)), params.names)
    assert result.rank == 24  # 4 poses x 6 rows
    assert len(result.redundant) == 6
