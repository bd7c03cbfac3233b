"""A wheel of fgcal, installed in a fresh virtual environment, runs ``fgcal demo`` from its own data.

The checkout is copied (as a git-URL install clones it) and built into a wheel: without build
isolation when this environment has the build backend, else with pip's isolated build (from its
cache or index). The virtual environment gets fgcal alone; its dependencies come from this
environment's site-packages through a ``.pth`` file, so no network is needed and the test stays
fast, while the editable install of this environment (if any) is not seen there.
"""
from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def _can_build_without_isolation() -> bool:
    if importlib.util.find_spec("wheel") is None:
        return False
    import setuptools

    return int(setuptools.__version__.split(".")[0]) >= 68


def _run(cmd, cwd, env=None, timeout=600):
    run = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert run.returncode == 0, f"{cmd} failed:\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    return run


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """``(python, fgcal script, clean environment)`` of a venv with only the wheel installed."""
    if not (ROOT / "pyproject.toml").exists():
        pytest.skip("not a source checkout: no pyproject.toml to build a wheel from")
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", "build", "dist", "*.egg-info", "__pycache__",
                                                             ".pytest_cache", ".venv*", "fgcal-demo"))
    build = [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", tmp / "dist", src]
    if _can_build_without_isolation():
        build.insert(4, "--no-build-isolation")
    _run(build, cwd=tmp)
    wheels = sorted((tmp / "dist").glob("fgcal-*.whl"))
    assert len(wheels) == 1
    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    bindir = env_dir / ("Scripts" if os.name == "nt" else "bin")
    python = bindir / ("python.exe" if os.name == "nt" else "python")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "FGCAL_DATASETS")}
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp, env)
                .stdout.strip())
    parents = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_fgcal_test_dependencies.pth").write_text("\n".join(sorted(parents)) + "\n")
    # pip sees the dependencies through the .pth file, so this also checks they are declared satisfiably.
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-index", "-q", wheels[0]], tmp, env)
    return python, bindir / ("fgcal.exe" if os.name == "nt" else "fgcal"), env, tmp, wheels[0]


def test_wheel_carries_the_data_and_no_top_level_datasets(installed):
    python, _, env, tmp, wheel = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "datasets" not in {n.split("/")[0] for n in names}
    shipped = {f"fgcal/_data/{p.relative_to(ROOT / 'datasets').as_posix()}" for p in (ROOT / "datasets").rglob("*")
               if p.is_file()}
    assert shipped <= names and "fgcal/_data/robots/ur10.yaml" in shipped
    code = ("import fgcal, importlib.util, json; from fgcal.util.resources import builtin_robot_names, default_dataset_dir;"
            "print(json.dumps([fgcal.__file__, builtin_robot_names(), str(default_dataset_dir()),"
            " importlib.util.find_spec('datasets') is not None and 'fgcal' in str(importlib.util.find_spec('datasets').origin)]))")
    fgcal_file, robots, demo_dir, datasets_from_fgcal = json.loads(_run([python, "-c", code], tmp, env).stdout)
    assert Path(fgcal_file).parent.parent.name == "site-packages" and str(tmp / "venv") in fgcal_file
    assert {"puma560", "ur10", "ur5"} <= set(robots)
    assert Path(demo_dir) == Path(fgcal_file).parent / "_data" / "puma560-paper"
    assert not datasets_from_fgcal


def test_fgcal_demo_runs_from_the_wheel(installed):
    _, fgcal, env, tmp, _ = installed
    run = _run([fgcal, "demo", "--out", tmp / "demo"], tmp, env)
    assert "_data" in run.stdout.splitlines()[0]
    assert "PASS: the calibrated position error is within 0.2 mm" in run.stdout  # the demo shows its verdict
    out = tmp / "demo"
    assert (out / "report" / "report.html").stat().st_size > 1000
    ver = json.loads((out / "verify.json").read_text())
    assert ver["n_poses"] == 24
    # The paper's experiment: ~4 mm nominal error, below 0.2 mm after calibration, at the unseen poses.
    assert ver["before"]["position_mm"]["rms"] > 2.0
    assert ver["truth"]["position_mm"]["rms"] < 0.15
    result = json.loads((out / "result.json").read_text())
    truth = yaml.safe_load((ROOT / "datasets" / "puma560-paper" / "truth.yaml").read_text())
    params = result["parameters"]
    z = np.array([(p["estimate"] - truth["parameters"][p["name"]]) / p["sigma"] for p in params])
    assert len(z) == 30 and np.sqrt(np.mean(z**2)) < 3.0
