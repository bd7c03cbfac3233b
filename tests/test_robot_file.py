import numpy as np
import pytest
from conftest import random_joints

from fgcal.errors import ModelError
from fgcal.robots.kinematics import forward
from fgcal.robots.model import SLOT_IS_ANGLE
from fgcal.robots.robot_file import load_model, save_model


@pytest.mark.parametrize("name", ["puma560", "ur10", "ur5"])
def test_save_load_round_trip_keeps_forward_kinematics(name, tmp_path):
    model = load_model(name)
    rng = np.random.default_rng(31)
    calibrated = model.nominal + np.where(SLOT_IS_ANGLE, np.radians(0.05), 0.5) * rng.normal(size=37)
    save_model(model, tmp_path / "m.yaml", slots=calibrated)
    back = load_model(tmp_path / "m.yaml")
    q = random_joints(model, 10, seed=32)
    np.testing.assert_allclose(forward(back.nominal, q), forward(calibrated, q), atol=1e-8)
    np.testing.assert_allclose(back.joint_limits, model.joint_limits)


def test_unknown_model_name():
    with pytest.raises(ModelError, match="unknown robot model 'puma999'.*puma560"):
        load_model("puma999")


@pytest.mark.parametrize("edit, pattern", [
    (("format: fgcal-robot/1", "format: fgcal-robot/2"), "format 'fgcal-robot/2' is not known"),
    (("a: 431.8", "a: long"), r"links\[1\]\.a: expected a finite number"),
    (("alpha: 90}", "alpha: 90, gamma: 1}"), r"links\[0\]: unknown key\(s\) gamma"),
    (("[-160, 160]", "[160, -160]"), r"joint_limits\[0\]: min must be below max"),
])
def test_bad_model_file(tmp_path, edit, pattern):
    from fgcal.util.resources import builtin_robot_path
    text = builtin_robot_path("puma560").read_text()
    assert edit[0] in text
    (tmp_path / "bad.yaml").write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(ModelError, match=pattern):
        load_model(tmp_path / "bad.yaml")
