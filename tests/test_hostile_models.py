"""Robot model and URDF readers: limits, couplings, the urdf: block, names of exported URDFs."""
import re
from dataclasses import replace

import numpy as np
import pytest
import yaml
from hostile_util import REPO

from fgcal.errors import ModelError
from fgcal.robots.robot_file import load_model, model_from_dict
from fgcal.robots.urdf import export_urdf, to_urdf
from fgcal.robots.urdf_import import model_from_urdf, parse_urdf

PANDA = (REPO / "tests/data/urdf/panda.urdf").read_text()
CHAIN = {"base": "panda_link0", "tip": "panda_hand_tcp"}


def _with_first_limit(attr):
    return re.sub(r'lower="[^"]*"', attr, PANDA, count=1)


@pytest.mark.parametrize("attr, word", [('lower="abc"', "limit lower"), ('lower="-inf"', "finite"),
                                        ('lower="nan"', "finite"), ('lower=""', "limit lower")])
def test_urdf_bad_limit_is_one_error(attr, word):
    with pytest.raises(ModelError, match=word):
        model_from_urdf(_with_first_limit(attr), "p.urdf", **CHAIN)


def test_urdf_huge_limit_is_capped_not_dropping_parameters(caplog):
    """-1e300 rad: taken as two turns (a warning), the same model as with the file's own limit."""
    good = model_from_urdf(PANDA, "p.urdf", **CHAIN)
    huge = model_from_urdf(_with_first_limit('lower="-1e300"'), "p.urdf", **CHAIN)
    assert "taken as" in caplog.text
    assert huge.joint_limits[0, 0] == pytest.approx(-4 * np.pi)
    assert np.all(np.isfinite(huge.joint_limits))
    assert huge.identifiable_names() == good.identifiable_names()


def test_urdf_duplicate_names_refused():
    twice = PANDA.replace('<link name="panda_link8"', '<link name="panda_link7"', 1)
    with pytest.raises(ModelError, match="used twice"):
        parse_urdf(twice, "p.urdf")


def test_exported_urdf_names_never_clash():
    """A URDF whose links are called world (not the root), tool and fgcal_tool exports with unique
    names, and fgcal reads its export back."""
    text = (PANDA.replace('"panda_link3"', '"world"').replace('"panda_leftfinger"', '"tool"')
            .replace('"panda_rightfinger"', '"fgcal_tool"'))
    model = model_from_urdf(text, "p.urdf", **CHAIN)
    out = export_urdf(model, model.nominal)
    _, joints, links = parse_urdf(out, "export.urdf")  # raises on a name used twice
    assert len(links) == len(set(links)) and "world_2" in links and "fgcal_tool_2" in links
    back = model_from_urdf(out, "export.urdf", base="world_2", tip="fgcal_tool_2")
    assert back.n_joints == model.n_joints


def test_plain_urdf_names_never_clash(puma):
    m = replace(puma, joint_names=("base_mount", "tool_mount", "j3", "j4", "j5", "j6"))
    _, joints, links = parse_urdf(to_urdf(m, m.nominal), "x.urdf")
    assert len(joints) == len(set(joints)) == 8 and "base_mount_2" in joints and "tool_mount_2" in joints


def _ur10():
    return yaml.safe_load((REPO / "datasets/robots/ur10.yaml").read_text())


def test_gearbox_coupling_is_not_singular():
    """diag(1/125): det 1e-13, well conditioned: accepted (the test is relative); a rank-deficient one is not."""
    d = _ur10()
    d["coupling"] = {"matrix": (np.eye(6) / 125).tolist()}
    m = model_from_dict(d, "gear.yaml")
    assert np.allclose(m.joint_map, np.eye(6) / 125)
    d["coupling"] = {"matrix": [[1, 1, 0, 0, 0, 0], [2, 2, 0, 0, 0, 0]] + np.eye(6)[2:].tolist()}
    with pytest.raises(ModelError, match="singular"):
        model_from_dict(d, "bad.yaml")


@pytest.mark.parametrize("value", ["hello", {"text": 5}, {"text": "<robot/>", "frame_changes": [[1]]}, [1, 2]])
def test_model_urdf_block_checked(value):
    d = _ur10()
    d["urdf"] = value
    with pytest.raises(ModelError, match="urdf: expected the block"):
        model_from_dict(d, "m.yaml")


def test_builtin_models_still_load():
    for name in ("puma560", "ur10", "ur5"):
        assert load_model(name).n_joints == 6


def test_urdf_first_axis_removed_is_one_error():
    """Found by tests/test_properties.py: joint 1 without <axis> (x by default) put the base frame at
    the ZYX singularity: a ValueError traceback, now one ModelError line."""
    text = PANDA.replace('<axis xyz="0 0 1"/>', "", 1)
    try:
        model_from_urdf(text, "p.urdf", **CHAIN)
    except ModelError as exc:
        assert "\n" not in str(exc)


def test_urdf_entities_refused_before_expansion():
    """An entity expanded 83 times (below expat's 100x guard) made an 18 MB URDF a 1.5 GB document:
    any <!ENTITY is refused before parsing (URDFs use none); external ones are never fetched."""
    big = "x" * 1000
    doc = (f'<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY e "{big}">]>\n'
           + PANDA.split("?>", 1)[1].replace('name="panda"', 'name="&e;&e;&e;"', 1))
    with pytest.raises(ModelError, match="entities"):
        model_from_urdf(doc, "e.urdf", **CHAIN)
    xxe = '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY s SYSTEM "file:///etc/passwd">]>\n<robot name="&s;"/>'
    with pytest.raises(ModelError) as err:
        model_from_urdf(xxe, "x.urdf")
    assert "root:" not in str(err.value)
