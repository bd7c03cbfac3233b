"""Hostile sweep, round 3 (issue 26): every option and positional argument of every command, walked
from the parser (a new option is swept too), with hostile values by kind, and concurrent runs.

- numbers (every checked option): -1, 0, 1e308, an integer of 30 digits (NaN, infinity and the range
  bounds of each: tools/hostile_cases2.py);
- choices: a value not among them;
- text options: empty, 100,000 characters, ``-1``, seven commas;
- input paths (positional or option): missing, a folder, a FIFO, ``/dev/zero``, an empty file, a
  binary file, one line of 20 MB, the command's own input truncated to half;
- output paths: a folder of inputs, a FIFO, an input of the run (``ds/joints.csv``), below a
  file (``ds/joints.csv/x``), ``/dev/full``;
- concurrency: two runs of one command on one output (calibrate, online checkpoint, import, study,
  simulate, export, design, report) started together.

Each single case runs as :mod:`tools/hostile_sweep` runs them (a child with a time and memory limit,
classed ok / traceback / silent / hung / killed); a value may be taken (exit 0) or refused (exit 2,
one line), except where an error is due (an output over an input). A concurrent pair is ``ok`` when
one run wrote and the other ended in a one-line refusal (no output here may replace an existing
one without ``--force``), the output reads back, the inputs are unchanged and no temporary file is
left.

Usage: ``python tools/hostile_sweep3.py [--jobs 2] [--only TEXT] [--timeout 150] [--list]``.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from hostile_sweep import changes, run_case
from hostile_workspace import REPO, Case, build_base, files_digest

sys.path.insert(0, str(REPO))

# the least each command needs to reach the option under test (inputs of the base workspace)
BASE_ARGS = {
    ("simulate",): ["sim-out", "--poses", "8"],
    ("check",): ["ds"],
    ("measure",): ["ds", "--out", "m"],
    ("calibrate",): ["ds", "--out", "x.json"],
    ("verify",): ["result.json", "full"],
    ("report",): ["result.json", "--out", "rep"],
    ("import", "csv"): ["series.csv", "imp", "--robot", "ur10", "--delimiter", ";",
                        "--joints", "Joint 1,Joint 2,Joint 3,Joint 4,Joint 5,Joint 6", "--joint-unit", "deg",
                        "--point", "X,Y,Z"],
    ("import", "tum"): ["t.tum", "imp", "--robot", "ur10", "--joint-log", "jlog.csv", "--joints",
                        "q1,q2,q3,q4,q5,q6"],
    ("import", "landgraf"): ["series.csv", "imp"],
    ("import", "mukca"): ["mk", "imp", "--robot", "mk.urdf", "--chain", "panda_link0,ball_link"],
    ("import", "ur-kinematics"): ["ur.yaml", "imp.yaml"],
    ("compensate",): ["result.json", "targets.csv"],
    ("export",): ["result.json", "--model", "m.yaml"],
    ("online",): ["ds", "--engine", "ekf"],
    ("study",): ["fig13", "--out", "st", "--trials", "1", "--poses", "8", "--workers", "1"],
    ("design",): ["--out", "p.csv", "--poses", "6"],
    ("demo",): ["--out", "demo-out"],
}
# positional arguments: the value the base arguments give them (replaced by the hostile one)
POSITIONAL_INDEX = {"out": None, "dataset": 0, "result": 0, "file": 0, "targets": 1, "name": 0}
OUTPUT_DESTS = {"out", "checkpoint", "plot", "model", "urdf", "deltas", "ur_kinematics"}
INPUTS = ("ds", "full", "result.json", "targets.csv", "series.csv", "mk", "t.tum", "jlog.csv", "ur.yaml")

NUMBERS = ["-1", "0", "1e308", "1" * 30]  # nan and inf: tools/hostile_cases2.py
TEXTS = ["", "x" * 100_000, "-1", ",,,,,,,"]
INPUT_PATHS = ["missing", "folder", "fifo", "devzero", "empty", "binary", "hugeline", "truncated"]
OUTPUT_PATHS = ["inputs-folder", "fifo", "input-file", "below-a-file", "devfull"]


def _options():
    """``(command words, option or None for a positional, dest, action)`` of every argument."""
    from fgcal.cli import build_parser

    def walk(parser, prefix=()):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from walk(sub, prefix + (name,))
            elif a.help == argparse.SUPPRESS or "--help" in a.option_strings or a.nargs == 0:
                continue
            else:
                yield prefix, (a.option_strings[-1] if a.option_strings else None), a.dest, a

    return list(walk(build_parser()))


def _kind(dest, action) -> str:
    from fgcal.cli.commands.options import Checked

    if isinstance(action.type, Checked):
        return "number"
    if action.choices:
        return "choice"
    if action.type is Path or action.option_strings == [] or dest in OUTPUT_DESTS or dest in ("joint_log", "truth",
                                                                                               "candidates",
                                                                                               "verification",
                                                                                               "verify"):
        return "output" if dest in OUTPUT_DESTS else "input"
    return "text"


def _path_setup(value: str, default: str | None):
    """``(path text, setup)`` of a hostile path."""
    def setup(w: Path):
        if value == "fifo":
            os.mkfifo(w / "fifo")
        elif value == "empty":
            (w / "empty.txt").write_text("")
        elif value == "binary":
            (w / "bin.dat").write_bytes(bytes(range(256)) * 64)
        elif value == "hugeline":
            (w / "huge.txt").write_text("1," * (10 << 20) + "\n")
        elif value == "truncated" and default:
            src = w / default
            if src.is_file():
                data = src.read_bytes()
                (w / "trunc").write_bytes(data[: len(data) // 2])
            elif src.is_dir():  # a dataset folder: its tables cut to half
                shutil.copytree(src, w / "trunc")
                for f in (w / "trunc").glob("*.csv"):
                    data = f.read_bytes()
                    f.write_bytes(data[: len(data) // 2])
    text = {"missing": "nope/none", "folder": "ds", "fifo": "fifo", "devzero": "/dev/zero", "empty": "empty.txt",
            "binary": "bin.dat", "hugeline": "huge.txt", "truncated": "trunc", "inputs-folder": "ds",
            "input-file": "ds/joints.csv", "below-a-file": "ds/joints.csv/x", "devfull": "/dev/full"}[value]
    return text, setup


def _with(base: list, option, dest, value, words=()) -> list:
    """``base`` with the argument replaced (or added) by ``value``."""
    args = list(base)
    if option is None:
        positions = [i for i, a in enumerate(args) if not a.startswith("--") and (i == 0 or not
                                                                                   args[i - 1].startswith("--"))]
        k = {"targets": 1, "out": 1 if words and words[0] == "import" else 0}.get(dest, 0)
        if dest == "dataset" and args and args[0] == "result.json":
            k = 1
        if k < len(positions):
            args[positions[k]] = value
        else:
            args.append(value)
        return args
    if option in args:
        i = args.index(option)
        args[i + 1] = value
        return args
    return args + [option, value]


def single_cases() -> list[Case]:
    C = []
    for words, option, dest, action in _options():
        base = BASE_ARGS.get(words)
        if base is None:
            continue
        kind = _kind(dest, action)
        name = " ".join(words) + " " + (option or f"<{dest}>")
        nargs = action.nargs if isinstance(action.nargs, int) else 1
        if kind == "number":
            for v in NUMBERS:
                C.append(Case(f"{name} {v[:12]}", [*words, *_with(base, option, dest, v, words)] +
                              ([v] * (nargs - 1) if option else []), expect="either", guard=INPUTS))
        elif kind == "choice":
            C.append(Case(f"{name} bogus", [*words, *_with(base, option, dest, "bogus", words)], guard=INPUTS))
        elif kind == "text":
            for v in TEXTS:
                C.append(Case(f"{name} text[{len(v)}]{v[:6]}", [*words, *_with(base, option, dest, v, words)],
                              expect="either", guard=INPUTS))
        else:
            default = None
            if option is None:
                positions = [a for i, a in enumerate(base) if not a.startswith("--") and (i == 0 or not
                                                                                          base[i - 1].startswith("--"))]
                k = {"targets": 1, "out": 1 if words[0] == "import" else 0}.get(dest, 0)
                if dest == "dataset" and positions and positions[0] == "result.json":
                    k = 1
                default = positions[k] if k < len(positions) else None
            elif option in base:
                default = base[base.index(option) + 1]
            for v in (OUTPUT_PATHS if kind == "output" else INPUT_PATHS):
                text, setup = _path_setup(v, default)
                expect = "error" if v in ("input-file", "fifo", "below-a-file", "devfull", "missing", "devzero",
                                          "binary", "empty", "hugeline") else "either"
                if kind == "output" and v == "inputs-folder":
                    expect = "either"  # a folder given for a folder output: refused (exists) or written into
                if v == "missing" and kind == "input" and dest in ("out", "name"):
                    expect = "either"
                C.append(Case(f"{name} {v}", [*words, *_with(base, option, dest, text, words)], setup, expect=expect,
                              guard=INPUTS))
    return C


# ---------------------------------------------------------------- concurrency

PAIRS = [
    ("calibrate same --out", ["calibrate", "ds", "--out", "same.json"], "same.json"),
    ("online same --checkpoint", ["online", "ds", "--engine", "ekf", "--checkpoint", "ck", "--out", "o.json"],
     "o.json"),
    ("import landgraf same OUT", ["import", "landgraf", "series.csv", "imp"], "imp"),
    ("simulate same OUT", ["simulate", "s", "--poses", "8"], "s"),
    ("export same --model", ["export", "result.json", "--model", "m.yaml"], "m.yaml"),
    ("design same --out", ["design", "--out", "p.csv", "--poses", "6"], "p.csv"),
    ("report same --out", ["report", "result.json", "--out", "rep"], "rep"),
    ("study same --out, two seeds", ["study", "fig13", "--out", "st", "--trials", "1", "--poses", "8", "--workers",
                                     "1", "--seed", "SEED"], "st"),
]


def _spawn(args, cwd):
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg", OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "fgcal.cli", *args], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)


def _reads_back(path: Path) -> str | None:
    """None when the output is whole; else what is wrong."""
    if not path.exists():
        return "missing"
    if path.suffix == ".json":
        try:
            from fgcal.estimation.result import load_result
            load_result(path)
        except Exception as exc:  # any failure is the finding
            return f"unreadable: {str(exc)[:100]}"
    elif path.is_dir() and (path / "dataset.yaml").exists():
        try:
            from fgcal.io.dataset_io import load_dataset
            load_dataset(path)
        except Exception as exc:
            return f"unreadable: {str(exc)[:100]}"
    elif path.is_dir() and path.name == "st":
        trials = list(path.rglob("*.json"))
        seeds = set()
        for t in trials:
            try:
                seeds.add(json.loads(t.read_text()).get("seed"))
            except (OSError, ValueError, AttributeError):
                pass
        if len(seeds - {None}) > 1:
            return f"trials of seeds {sorted(seeds - {None})} mixed in one study folder"
    return None


def run_pair(name, args, output, base: Path, timeout: float) -> tuple[str, str, float]:
    with tempfile.TemporaryDirectory(prefix="sweep3-") as tmp:
        work = Path(tmp) / "w"
        shutil.copytree(base, work, symlinks=True)
        guard = {g: files_digest(work / g) for g in INPUTS}
        t0 = time.perf_counter()
        procs = [_spawn([a.replace("SEED", str(k)) for a in args], work) for k in range(2)]
        outs = []
        for p in procs:
            try:
                out, err = p.communicate(timeout=timeout)
                outs.append((p.returncode, err.decode(errors="replace")))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, 9)
                p.communicate()
                outs.append((None, ""))
        dt = time.perf_counter() - t0
        problems = []
        for code, err in outs:
            if code is None:
                return "hung", f"no end after {timeout:.0f} s", dt
            if "Traceback" in err:
                return "traceback", err.strip().splitlines()[-1][:200], dt
            progress = f"{args[0]}:"  # a command's progress lines on stderr (design: greedy start ...)
            lines = [ln for ln in err.splitlines() if ln.strip() and not ln.lower().startswith(("warning:", "note:"))
                     and not ln.startswith(progress)]
            if code not in (0, 2) or (code == 2 and len(lines) != 1):
                problems.append(f"exit {code}, {len(lines)} error lines: {err.strip()[-150:]}")
        if not any(code == 0 for code, _ in outs):
            problems.append("neither run wrote: " + " | ".join(e.strip()[-100:] for _, e in outs))
        # every output here is refused when it exists (no --force), but online's: a second run on one
        # checkpoint waits for none, is refused while the first holds it, or resumes after it and rewrites
        if all(code == 0 for code, _ in outs) and args[0] != "online":
            problems.append("both runs said they wrote one new output (the later replaced the earlier)")
        bad = _reads_back(work / output)
        if bad and any(code == 0 for code, _ in outs):
            problems.append(f"{output}: {bad}")
        problems += changes(work, guard)
        if problems:
            return "silent", "; ".join(problems), dt
        return "ok", " / ".join(f"{c}: {(e.strip().splitlines() or [''])[-1][:70]}" for c, e in outs), dt


def _extra_inputs(base: Path) -> None:
    """t.tum + jlog.csv (from full's poses), ur.yaml (a UR calibration file) for the import cases."""
    import numpy as np

    poses = np.loadtxt(base / "ur10ds" / "poses.csv", delimiter=",", skiprows=1)
    joints = np.loadtxt(base / "ur10ds" / "joints.csv", delimiter=",", skiprows=1)
    t = 100.0 + poses[:, 0]
    (base / "t.tum").write_text("".join(f"{ti} {x / 1000} {y / 1000} {z / 1000} {qx} {qy} {qz} {qw}\n"
                                        for ti, (x, y, z, qw, qx, qy, qz) in zip(t, poses[:, 1:8])))
    (base / "jlog.csv").write_text("time,q1,q2,q3,q4,q5,q6\n" + "".join(
        f"{ti}," + ",".join(str(np.radians(v)) for v in q) + "\n" for ti, q in zip(t, joints[:, 1:])))
    (base / "ur.yaml").write_text("kinematics:\n  shoulder:\n    x: 0\n    y: 0\n    z: 0.1273\n"
                                  "    roll: 0\n    pitch: 0\n    yaw: 0\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--only", default=None)
    p.add_argument("--timeout", type=float, default=150.0)
    p.add_argument("--base", type=Path, default=None, help="a workspace built before (else built here)")
    p.add_argument("--list", action="store_true")
    args = p.parse_args(argv)
    singles = [c for c in single_cases() if args.only is None or args.only in c.name]
    pairs = [x for x in PAIRS if args.only is None or args.only in x[0]]
    if args.list:
        for c in singles:
            print(c.name, "::", " ".join(map(str, c.args))[:160])
        for n, a, _ in pairs:
            print(n, ":: 2x", " ".join(a))
        print(len(singles) + len(pairs), "cases")
        return 0
    tmp = None
    if args.base is None:
        tmp = tempfile.mkdtemp(prefix="sweep3-base-")
        base = Path(tmp)
        build_base(base)
        _extra_inputs(base)
    else:
        base = args.base
    counts: dict[str, int] = {}
    try:
        with ThreadPoolExecutor(args.jobs) as pool:
            futures = [(c.name, pool.submit(run_case, c, base, args.timeout)) for c in singles]
            futures += [(n, pool.submit(run_pair, n, a, o, base, args.timeout)) for n, a, o in pairs]
            for name, fut in futures:
                try:
                    verdict, detail, dt = fut.result()
                except Exception as exc:  # a case that cannot be set up is reported
                    verdict, detail, dt = "setup-error", repr(exc)[:200], 0.0
                counts[verdict] = counts.get(verdict, 0) + 1
                print(f"{verdict:10s} {dt:6.1f}s  {name}: {detail[:220]}", flush=True)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    total = len(singles) + len(pairs)
    print(f"\n{total} cases ({len(singles)} single, {len(pairs)} concurrent pairs): " +
          ", ".join(f"{k} {counts.get(k, 0)}" for k in ("ok", "traceback", "silent", "hung", "killed", "setup-error")))
    return 0 if counts.get("ok", 0) == total else 1


if __name__ == "__main__":
    sys.exit(main())
