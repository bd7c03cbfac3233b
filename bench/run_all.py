"""All benchmarks in one run, side by side: ``python bench/run_all.py``.

1. batch CPU and peak memory at 21, 1000 and 10000 poses against a plain scipy joint solve
   (``bench_batch.py`` runs ``../shared/bench/sparse_joint_solve.py``; skipped when it is absent);
2. online: the whole CLI step per pose and total CPU against one batch calibration, 1000 poses
   (``bench_online.py``);
3. studies: a trial against its calibration, and the 2-worker study against bare calibrations
   (``bench_study.py``);
4. the GTSAM engine and ``gtsam.Marginals`` against the batched solve and its covariance
   (``bench_engines.py``);
5. one joint set's kinematics: the scan of operation matrices against the operation walk
   (``bench_kinematics.py``).
"""
import platform
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    import os
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    for script in ("bench_batch.py", "bench_online.py", "bench_study.py", "bench_engines.py",
                   "bench_kinematics.py"):
        print(f"\n== {script}")
        sys.stdout.flush()
        subprocess.run([sys.executable, str(HERE / script)], check=True)
