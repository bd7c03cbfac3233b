"""Peak memory of fgcal's readers against the size of what they read (issue 26: memory bounded by
the data with a small constant, or a clear refusal naming the size).

Each case runs the command line in a child process and takes that child's peak resident set
(``os.wait4``'s ``ru_maxrss``). The reference is measured in the same script: the peak of a child
that only imports fgcal's command line (numpy, scipy, gtsam ...) and exits. Printed per case:
the file size, the peak, ``peak / file`` and ``(peak - reference) / file`` (the memory the data
cost, per byte of data), against the goal.

Cases:

- ``import csv``: a tracker log of ``--rows`` rows (6 joints in rad, position in m, quaternion;
  1,000,000 rows are about 250 MB), every row usable, made from a UR10 seen by a tracker;
- ``import tum``: the same poses as a TUM trajectory with a joint log (two files);
- ``check`` and ``calibrate`` of the imported dataset (``poses.csv`` and ``joints.csv`` read in
  full; calibrate refuses a batch this size, naming it, after reading);
- ``check`` of a dataset whose robot is a URDF of ``--urdf-links`` links (a long chain file).

Usage: ``nice -n 5 python bench/bench_memory.py [--rows 1000000] [--keep DIR]``.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
GOAL = 3.0  # growth of the peak per byte of input: the typed arrays of a row plus a copy or two
JOINTS = ["q1", "q2", "q3", "q4", "q5", "q6"]
CHUNK = 100_000


def _ur10_poses(rng, n):
    """``(q (n, 6) rad, xyz (n, 3) m, quat xyzw (n, 4))`` of a nominal UR10 seen from a tracker 2.5 m away."""
    from scipy.spatial.transform import Rotation

    from fgcal.robots.kinematics import forward
    from fgcal.robots.model import slot
    from fgcal.robots.robot_file import load_model
    from fgcal.robots.transforms import to_euler_zyx_trans

    model = load_model("ur10")
    slots = model.nominal.copy()
    base = np.eye(4)
    base[:3, :3] = Rotation.from_euler("zyx", [120, 0.3, -0.2], degrees=True).as_matrix()
    base[:3, 3] = [-1250.0, 2165.0, -400.0]
    tool = np.eye(4)
    tool[:3, 3] = [25.0, -15.0, 180.0]
    for part, T in (("base", base), ("tool", tool)):
        slots[[slot(f"{part}.{f}") for f in ("phi", "theta", "psi", "px", "py", "pz")]] = to_euler_zyx_trans(T)
    lo = np.array([-np.pi, -2.6, -2.4, -np.pi, -np.pi, -np.pi])
    hi = np.array([np.pi, -0.5, 2.4, np.pi, np.pi, np.pi])
    q = rng.uniform(lo, hi, size=(n, 6))
    T = forward(slots, q)
    xyz = (T[:, :3, 3] + rng.normal(size=(n, 3)) * 0.02) / 1000.0
    return q, xyz, Rotation.from_matrix(T[:, :3, :3]).as_quat()


def make_files(folder: Path, rows: int, urdf_links: int, seed: int = 0) -> dict:
    """The big inputs: ``log.csv``, ``traj.tum`` + ``joints.csv``, ``chain.urdf``."""
    rng = np.random.default_rng(seed)
    with open(folder / "log.csv", "w") as csv_fh, open(folder / "traj.tum", "w") as tum_fh, \
            open(folder / "jlog.csv", "w") as log_fh:
        csv_fh.write(",".join(["stamp", *JOINTS, "x", "y", "z", "qx", "qy", "qz", "qw"]) + "\n")
        log_fh.write(",".join(["time", *JOINTS]) + "\n")
        for start in range(0, rows, CHUNK):
            n = min(CHUNK, rows - start)
            q, xyz, quat = _ur10_poses(rng, n)
            t = 1.7e9 + 0.5 * (start + np.arange(n))
            table = np.column_stack([t, q, xyz, quat])
            np.savetxt(csv_fh, table, fmt=["%.3f"] + ["%.12f"] * 6 + ["%.9f"] * 3 + ["%.12f"] * 4, delimiter=",")
            np.savetxt(tum_fh, np.column_stack([t, xyz, quat]), fmt=["%.3f"] + ["%.9f"] * 3 + ["%.12f"] * 4)
            np.savetxt(log_fh, np.column_stack([t, q]), fmt=["%.3f"] + ["%.12f"] * 6, delimiter=",")
    # A 6-joint chain l0..l6 and ``urdf_links`` fixed leaf frames on l0 (sensor mounts, as a robot
    # description with many frames has): the dataset names its chain.
    chain = "".join(f'<joint name="j{i + 1}" type="revolute"><parent link="l{i}"/><child link="l{i + 1}"/>'
                    f'<origin xyz="0 0 0.3" rpy="{0.5 * (i % 2)} 0 0"/><axis xyz="0 0 1"/>'
                    f'<limit lower="-3" upper="3" effort="1" velocity="1"/></joint>\n' for i in range(6))
    leaves = "".join(f'<link name="s{i}"/><joint name="m{i}" type="fixed"><parent link="l0"/><child link="s{i}"/>'
                     f'<origin xyz="0.{i} 0 0" rpy="0 0 0"/></joint>\n' for i in range(urdf_links))
    (folder / "chain.urdf").write_text('<?xml version="1.0"?>\n<robot name="long">'
                                       + "".join(f'<link name="l{i}"/>' for i in range(7)) + "\n" + chain + leaves
                                       + "</robot>\n")
    return {"log.csv": folder / "log.csv", "traj.tum": folder / "traj.tum", "chain.urdf": folder / "chain.urdf"}


def peak_rss(args, cwd) -> tuple[int, float, int, str]:
    """``(peak resident bytes, seconds, exit status, last stderr line)`` of ``python -m fgcal.cli ARGS``."""
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg", OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, *args], cwd=cwd, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    return usage.ru_maxrss * 1024, time.perf_counter() - t0, proc.returncode, (lines[-1][:150] if lines else "")


def _cases(folder: Path) -> list:
    (folder / "uds").mkdir(exist_ok=True)
    (folder / "uds" / "dataset.yaml").write_text("format: fgcal-dataset/1\nrobot: ../chain.urdf\n"
                                                 "chain: {base: l0, tip: l6}\ntool:\n  radius: 0\n  balls:\n"
                                                 "    P: [0, 0, 0]\nnoise: {cmm_sigma: 0.02}\nprovenance: {}\n")
    (folder / "uds" / "joints.csv").write_text("pose,q1,q2,q3,q4,q5,q6\n1,0,0,0,0,0,0\n")
    imp = ["-m", "fgcal.cli", "import"]
    return [
        ("import csv", ["log.csv"],
         [*imp, "csv", "log.csv", "imp", "--force", "--robot", "ur10", "--joints", ",".join(JOINTS),
          "--joint-unit", "rad", "--length-unit", "m", "--pose", "x,y,z,qx,qy,qz,qw"]),
        ("import tum", ["traj.tum", "jlog.csv"],
         [*imp, "tum", "traj.tum", "timp", "--force", "--robot", "ur10", "--joint-log", "jlog.csv",
          "--joints", ",".join(JOINTS)]),
        ("check (imported)", ["imp/poses.csv", "imp/joints.csv"], ["-m", "fgcal.cli", "check", "imp"]),
        ("calibrate (imported)", ["imp/poses.csv", "imp/joints.csv"],
         ["-m", "fgcal.cli", "calibrate", "imp", "--out", "r.json"]),
        ("check (URDF robot)", ["chain.urdf"], ["-m", "fgcal.cli", "check", "uds"]),
    ]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=1_000_000)
    p.add_argument("--urdf-links", type=int, default=100_000, help="fixed leaf frames in the URDF")
    p.add_argument("--keep", type=Path, default=None, help="make the files in this folder and keep them")
    args = p.parse_args(argv)
    tmp = None
    root = Path(tmp := tempfile.mkdtemp(prefix="bench-memory-")) if args.keep is None else args.keep
    try:
        sizes = {"small": (max(args.rows // 100, 1000), max(args.urdf_links // 100, 10)),
                 "big": (args.rows, args.urdf_links)}
        for name, (rows, links) in sizes.items():
            (root / name).mkdir(parents=True, exist_ok=True)
            if not (root / name / "log.csv").exists():
                t0 = time.perf_counter()
                make_files(root / name, rows, links)
                print(f"made the {name} inputs ({rows} rows, {links} URDF frames) in {time.perf_counter() - t0:.0f} s",
                      flush=True)
        ref, _, _, _ = peak_rss(["-c", "import fgcal.cli, fgcal.io.importer, fgcal.estimation.calibrate"], root)
        print(f"a child importing fgcal's command line: peak {ref / 2**20:.0f} MiB")
        print(f"{'case':22s} {'file MB':>8s} {'peak MiB':>9s} {'peak/file':>9s} {'growth/file':>11s} {'goal':>5s} "
              f"{'s':>5s}  exit: last line (growth: peak minus the small inputs' peak, over the added bytes)")
        worst = 0.0
        for (name, files, cmd), (_, _, cmd_small) in zip(_cases(root / "big"), _cases(root / "small"), strict=True):
            small_peak, _, small_code, small_last = peak_rss(cmd_small, root / "small")
            peak, dt, code, last = peak_rss(cmd, root / "big")
            size = sum((root / "big" / f).stat().st_size for f in files if (root / "big" / f).exists())
            small = sum((root / "small" / f).stat().st_size for f in files if (root / "small" / f).exists())
            growth = (peak - small_peak) / max(size - small, 1)
            worst = max(worst, growth)
            print(f"{name:22s} {size / 1e6:8.1f} {peak / 2**20:9.0f} {peak / size:9.2f} {growth:11.2f} {GOAL:5.1f} "
                  f"{dt:5.0f}  {code}: {last} (small: {small_peak / 2**20:.0f} MiB, {small_code}: {small_last[:60]})",
                  flush=True)
        print(f"\nworst growth of the peak per byte of input: {worst:.2f} (goal <= {GOAL:g}): "
              f"{'met' if worst <= GOAL else 'NOT met'}")
        return 0
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
