"""The hostile sweep's workspace (see ``tools/hostile_sweep.py``): a case, running one fgcal
command in a limited child, the small workspace every case copies, and the mutations cases apply."""
from __future__ import annotations

import hashlib
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
LANDGRAF = Path("/work/shared/data/landgraf-ur10/Series_B/measurements_joint_configurations.csv")
MUKCA = Path("/work/shared/data/mukca-panda")  # the two-socket tool's placements (a Panda)
MEMORY = 2 << 30  # bytes of address space for a child
COMMANDS = {"simulate", "check", "measure", "calibrate", "verify", "report", "import", "compensate", "export",
            "online", "study", "design", "demo"}


@dataclass
class Case:
    name: str
    args: list
    setup: object = None  # callable(work: Path)
    expect: str = "error"  # error | ok | warn | either
    words: tuple = ()  # must appear in the output
    stdin: bytes | None = None
    fsize: int | None = None  # a file-size limit: a full disk
    guard: tuple = ("ds",)  # folders that must not change
    tags: list = field(default_factory=list)


def fgcal(args, cwd, timeout=600, stdin=None, fsize=None):
    def limits():
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))
        if fsize is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
        os.setsid()

    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg", OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "fgcal.cli", *map(str, args)], cwd=cwd, env=env,
                            stdin=subprocess.PIPE if stdin is not None else subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=limits)
    try:
        out, err = proc.communicate(stdin, timeout=timeout)
        return proc.returncode, out.decode(errors="replace"), err.decode(errors="replace")
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return None, "", ""


# ---------------------------------------------------------------- the workspace

def build_base(base: Path) -> None:
    """ds (8 poses, probes), full (probes, centres, poses), ur10ds, result.json, verify.json, targets.csv."""
    steps = [["simulate", "ds", "--poses", "8", "--seed", "1"],
             ["simulate", "full", "--poses", "6", "--seed", "2", "--levels", "probes,centres,poses"],
             ["simulate", "ur10ds", "--robot", "ur10", "--poses", "6", "--seed", "3", "--levels", "poses"],
             ["calibrate", "ds", "--out", "result.json"],
             ["verify", "result.json", "full", "--out", "verify.json"]]
    for s in steps:
        code, out, err = fgcal(s, base)
        if code != 0:
            raise SystemExit(f"workspace step {s} failed: {err}")
    lines = (base / "full" / "poses.csv").read_text().splitlines()
    (base / "targets.csv").write_text("\n".join(lines[:4]) + "\n")
    if LANDGRAF.exists():
        lines = LANDGRAF.read_text(encoding="utf-8-sig").splitlines()
        (base / "series.csv").write_text("\n".join(lines[:60]) + "\n")
    if MUKCA.exists():
        build_contacts(base)


def build_contacts(base: Path) -> None:
    """mk (the MUKCa placements, writable), mk.urdf, cds and cds-holdout (imported, placement high held
    out), cres.json (a contacts calibration) and cver.json (its verification)."""
    shutil.copytree(MUKCA / "panda_2", base / "mk")
    shutil.copy(MUKCA / "panda.urdf", base / "mk.urdf")
    for p in [base / "mk", *(base / "mk").rglob("*")]:
        p.chmod(0o755 if p.is_dir() else 0o644)
    steps = [["import", "mukca", "mk", "cds", "--robot", "mk.urdf", "--chain", "panda_link0,ball_link",
              "--holdout-placements", "high"],
             ["calibrate", "cds", "--out", "cres.json"],
             ["verify", "cres.json", "cds-holdout", "--out", "cver.json"]]
    for s in steps:
        code, out, err = fgcal(s, base)
        if code != 0:
            raise SystemExit(f"workspace step {s} failed: {err}")


def files_digest(folder: Path) -> str:
    h = hashlib.sha256()
    if not folder.exists():
        return "absent"
    if folder.is_file():
        return hashlib.sha256(folder.read_bytes()).hexdigest()
    for p in sorted(folder.rglob("*")):
        h.update(str(p.relative_to(folder)).encode())
        if p.is_file() and not p.is_symlink():
            h.update(p.read_bytes())
    return h.hexdigest()


# ---------------------------------------------------------------- mutations

def _remove(p) -> None:
    """Whatever is at ``p`` (file, link or folder) gone."""
    if p.is_symlink() or p.is_file():
        p.unlink()
    elif p.is_dir():
        shutil.rmtree(p)


def write(rel, text):
    def f(w):
        p = w / rel
        _remove(p)
        p.write_bytes(text) if isinstance(text, bytes) else p.write_text(text)
    return f


def edit(rel, old, new):
    def f(w):
        p = w / rel
        t = p.read_text()
        assert old in t, (rel, old)
        p.write_text(t.replace(old, new, 1))
    return f


def json_edit(fn, rel):
    """An edit of the JSON file ``rel``: ``fn`` changes its parsed content in place."""
    def f(w):
        p = w / rel
        d = json.loads(p.read_text())
        fn(d)
        p.write_text(json.dumps(d))
    return f


def line(rel, n, new):
    def f(w):
        p = w / rel
        ls = p.read_text().splitlines()
        ls[n - 1] = new
        p.write_text("\n".join(ls) + "\n")
    return f


def scale_columns(rel, first, factor):
    """Multiply the columns from ``first`` on of every data row of a CSV file by ``factor``."""
    def f(w):
        p = w / rel
        ls = p.read_text().splitlines()
        out = [ls[0]] + [",".join([*r.split(",")[:first], *[repr(float(v) * factor) for v in r.split(",")[first:]]])
                         for r in ls[1:]]
        p.write_text("\n".join(out) + "\n")
    return f


def scale_joints(factor):
    return scale_columns("ds/joints.csv", 1, factor)


def scale_probes(factor):
    return scale_columns("ds/probes.csv", 2, factor)


def replace_with(rel, kind):
    def f(w):
        p = w / rel
        _remove(p)
        if kind == "fifo":
            os.mkfifo(p)
        elif kind == "dir":
            p.mkdir()
        elif kind == "loop":
            os.symlink(p.name, p)
        elif kind == "dangling":
            os.symlink("nowhere-" + p.name, p)
        elif kind == "devzero":
            os.symlink("/dev/zero", p)
        elif kind == "sparse":
            with open(p, "wb") as fh:
                fh.truncate(200 * 1024 * 1024)
        elif kind == "missing":
            pass
    return f


def chain(*fs):
    def f(w):
        for g in fs:
            g(w)
    return f


def model_file(name, text):
    return chain(write(f"ds/{name}", text), edit("ds/dataset.yaml", "robot: puma560", f"robot: {name}"))


LAUGHS = "l0: &l0 [lol]\n" + "".join(f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]\n" for i in range(1, 10))
DS_YAML = "ds/dataset.yaml"
