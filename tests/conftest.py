import numpy as np
import pytest

from fgcal.robot_file import load_model


@pytest.fixture(scope="session")
def puma():
    return load_model("puma560")


@pytest.fixture(scope="session")
def ur10():
    return load_model("ur10")


def random_joints(model, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(model.joint_limits[:, 0], model.joint_limits[:, 1], size=(n, 6))
