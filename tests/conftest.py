import os

# One BLAS thread per process: on a 2-core machine threaded OpenBLAS made a 400x400 solve 25 times
# slower under load (the joint-error map's normal equations), and subprocesses inherit this.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from fgcal.robots.robot_file import load_model


@pytest.fixture(scope="session")
def puma():
    return load_model("puma560")


@pytest.fixture(scope="session")
def ur10():
    return load_model("ur10")


def random_joints(model, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(model.joint_limits[:, 0], model.joint_limits[:, 1], size=(n, 6))
