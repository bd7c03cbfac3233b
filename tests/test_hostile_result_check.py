"""One validation of a loaded result (``fgcal.estimation.result_check``), used by every reader.

Each edit of a real result file is refused in one line by verify, report, export and compensate,
where it passed (NaN or negative variances gave a PASS report) or crashed before.
"""
import json

import numpy as np
import pytest
from hostile_util import call, one_line_error, small_dataset

from fgcal.errors import FgcalError
from fgcal.estimation.result import load_result


@pytest.fixture(scope="module")
def work(puma, tmp_path_factory):
    d = tmp_path_factory.mktemp("rescheck")
    small_dataset(puma, d / "ds", n_poses=8, seed=7)
    from fgcal.cli import main
    assert main(["calibrate", str(d / "ds"), "--out", str(d / "r.json")]) == 0
    return d


def _edit(src, dst, f):
    d = json.loads(src.read_text())
    f(d)
    dst.write_text(json.dumps(d))
    return dst


def _set_cov(d, k, v):
    d["covariance"][k][k] = v


def _non_psd(d):
    n = len(d["covariance"])
    c = np.array(d["covariance"])
    s = np.sqrt(np.diag(c))
    c = np.outer(s, s) * 0.999  # correlations of 0.999 everywhere ...
    c[0, 1] = c[1, 0] = -c[0, 1]  # ... but 0,1 anti-correlated: not PSD for n >= 3
    np.fill_diagonal(c, s**2)
    d["covariance"] = c.tolist()
    assert n >= 3


EDITS = {
    "sigma null": (lambda d: d["parameters"][0].update(sigma=None), "sigma"),
    "sigma nan": (lambda d: d["parameters"][0].update(sigma=float("nan")), "sigma"),
    "sigma negative": (lambda d: d["parameters"][0].update(sigma=-0.1), "sigma"),
    "sigma string": (lambda d: d["parameters"][0].update(sigma="small"), "sigma"),
    "nominal nan": (lambda d: d["parameters"][2].update(nominal=float("nan")), "nominal"),
    "variance nan": (lambda d: _set_cov(d, 0, float("nan")), "covariance"),
    "variance negative": (lambda d: _set_cov(d, 0, -1.0), "covariance"),
    "covariance not psd": (_non_psd, "positive semi-definite"),
    "covariance asymmetric": (lambda d: d["covariance"][0].__setitem__(1, 5.0), "symmetric"),
    "parameter renamed": (lambda d: d["parameters"][3].update(name="j9.theta"), "not a parameter of the robot"),
    "parameter twice": (lambda d: d["parameters"][4].update(name=d["parameters"][5]["name"]), "twice"),
    "joint error of joint 9": (lambda d: d["parameters"][3].update(name="j9.compliance"), "not a parameter"),
    "level sigma negative": (lambda d: next(iter(d["levels"].values())).update(sigma=-1), "levels."),
}


@pytest.mark.parametrize("name", EDITS)
def test_load_result_refuses(work, tmp_path, name):
    f, word = EDITS[name]
    path = _edit(work / "r.json", tmp_path / "bad.json", f)
    with pytest.raises(FgcalError, match="malformed result") as err:
        load_result(path)
    assert word in str(err.value) and "\n" not in str(err.value) and len(str(err.value)) < 400


@pytest.mark.parametrize("name", ["sigma nan", "variance negative", "parameter renamed", "covariance not psd"])
def test_every_reader_refuses(work, tmp_path, capsys, name):
    """verify, report (with a tolerance: a PASS before), export and compensate: one line each."""
    f, word = EDITS[name]
    bad = _edit(work / "r.json", tmp_path / "bad.json", f)
    targets = tmp_path / "t.csv"
    targets.write_text("pose,x,y,z,qw,qx,qy,qz\n1,500,100,300,1,0,0,0\n")
    for args in (["verify", bad, work / "ds"], ["report", bad, "--out", tmp_path / "rep"],
                 ["export", bad, "--model", tmp_path / "m.yaml"], ["compensate", bad, targets]):
        code, out, err = call(args, capsys)
        one_line_error(code, err, "malformed result", word)
        assert "PASS" not in out
    assert not (tmp_path / "rep").exists() and not (tmp_path / "m.yaml").exists()


def test_good_result_still_loads(work):
    r = load_result(work / "r.json")
    assert np.allclose(np.sqrt(np.diag(r.covariance)), r.sigma)
    assert np.linalg.eigvalsh(r.covariance)[0] > 0
