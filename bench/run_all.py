"""All benchmarks in one run, side by side: ``python bench/run_all.py``.

1. batch solve time and peak memory at 21, 200 and 1000 poses against the two-stage baselines
   (``bench_batch.py``);
2. online per-pose latency at 1000 poses (``bench_online.py``);
3. study throughput on 1 and 2 local processes and a Dask LocalCluster (``bench_study.py``).
"""
import platform
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    import os
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    for script in ("bench_batch.py", "bench_online.py", "bench_study.py"):
        print(f"\n== {script}")
        sys.stdout.flush()
        subprocess.run([sys.executable, str(HERE / script)], check=True)
