"""Study cost against its calibrations (issue 16), all in this one process and its workers.

1. In-process: ``--trials`` fig13 trials (12 poses, paper noise, verified at 50 poses), each
   trial's CPU (user + sys of this process) against the CPU of the calibration inside it; the
   rest (plans, simulation, verification) broken down.
   Each trial's identification dataset is also calibrated bare (no trial around it), right after it.
2. The whole study (``run_study``) on 2 local worker processes against the same calibrations run
   bare on 2 worker processes: wall time and CPU (this process and its workers, start-up and
   imports included), the CPU spent outside the trials (set-up), and the share of the wall time
   the workers spend inside trials.
3. Optionally (``--dask``), the study on a Dask LocalCluster of 2 workers.

And, as a reference, ``--before`` trials whose probing and verification go through the per-ball,
per-pose functions the trial used before issue 16 (``simulate.measure``, ``verify.measured_poses``;
the same numbers, as ``tests/test_study.py`` checks), interleaved with the same trials as they run now.

Single-threaded BLAS. Run: ``python bench/bench_study.py [--trials 100] [--before 40] [--dask]``.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import importlib
import resource
import tempfile
import time


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


class _Timed:
    """Wraps a module's function to add up its CPU time (and keep its first argument if asked)."""

    def __init__(self, module, name, keep_arg=False):
        self.module, self.name, self.real = module, name, getattr(module, name)
        self.cpu, self.calls, self.kept, self.keep = 0.0, 0, [], keep_arg

    def __enter__(self):
        def timed(*a, **k):  # a plain function, so that it binds as a method too
            t = time.process_time()
            out = self.real(*a, **k)
            self.cpu += time.process_time() - t
            self.calls += 1
            if self.keep:
                self.kept.append(a)
            return out

        setattr(self.module, self.name, timed)
        return self

    def __exit__(self, *exc):
        setattr(self.module, self.name, self.real)


class _SlowProbed:
    """A trial's probed poses held as the dataset ``simulate.measure`` writes, verified by ``verify.measured_poses``."""

    def __init__(self, ds):
        self.ds, self.pose_ids, self.joints_deg = ds, ds.pose_ids, ds.joints_deg

    def dataset(self, model, noise):
        return self.ds

    def measured_poses(self, tooling, sigma):
        from fgcal.estimation.verification import measured_poses

        ids, T, _ = measured_poses(self.ds)
        return self.ds.row_of(ids), T


def _slow_probes(model, slots, q, rng, tooling, noise, volume=None):
    from fgcal.measurements.dataset import Dataset
    from fgcal.studies.simulate import measure

    ids, joints, probes, *_ = measure(model, slots, q, rng, tooling, noise, volume)
    return _SlowProbed(Dataset(robot=model.name, tooling=model.tooling, noise=noise, provenance={}, pose_ids=ids,
                               joints_deg=joints, probes=probes))


def _before_after(trials, cal_mod, probing):
    """CPU of each trial the way it ran before and as it runs now (interleaved), and of its calibration."""
    import fgcal.studies.study as study

    cpu = {"before": 0.0, "now": 0.0}
    cal = {"before": 0.0, "now": 0.0}
    for t in trials:
        for label in ("before", "now"):
            with _Timed(cal_mod, "calibrate") as c:
                if label == "before":
                    probing.simulate_probes, real = _slow_probes, probing.simulate_probes
                try:
                    c0 = time.process_time()
                    study.run_trial(t)
                    cpu[label] += time.process_time() - c0
                finally:
                    if label == "before":
                        probing.simulate_probes = real
            cal[label] += c.cpu
    return {k: (cpu[k], cpu[k] / cal[k]) for k in cpu}


def _calibrate_cpu(ds):
    """CPU (s) of one bare calibration of ``ds`` in a worker."""
    from fgcal.estimation.calibrate import calibrate
    from fgcal.studies.study import _model

    c0 = time.process_time()
    calibrate(ds, _model(ds.robot))
    return time.process_time() - c0


def _trial_cpu(trial):
    """A study runner that also reports the trial's CPU (s), in the ``O1`` column (NaN in fig13's rows;
    these rows are only counted here). ``seconds`` is the trial's wall time, as always."""
    from fgcal.studies.study import run_trial

    c0 = time.process_time()
    row = run_trial(trial)
    row["O1"] = time.process_time() - c0
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--dask", action="store_true", help="also run the study on a Dask LocalCluster of 2 workers")
    ap.add_argument("--before", type=int, default=40, metavar="N",
                    help="trials run both the way they ran before issue 16 and now (0: skip)")
    args = ap.parse_args()
    from fgcal.studies.probing import ProbedPoses
    from fgcal.studies.study import run_trial, trials_for
    from fgcal.studies.study_run import run_study

    cal_mod, sim_mod, probing = (importlib.import_module(f"fgcal.{m}") for m in
                                 ("estimation.calibrate", "studies.simulate", "studies.probing"))
    trials = trials_for("fig13", trials=args.trials, poses=12, seed=7)
    run_trial(trials[0])  # warm: imports, the robot model, the paper's chi-square bounds

    if args.before:
        ba = _before_after(trials[:args.before], cal_mod, probing)
        m = min(args.before, len(trials))
        print(f"{m} trials, before issue 16 / now (interleaved): {1000 * ba['before'][0] / m:.1f} / "
              f"{1000 * ba['now'][0] / m:.1f} ms CPU a trial, {ba['before'][1]:.2f} / {ba['now'][1]:.2f}x its "
              "calibration")

    # 1. a trial against its calibration inside it, and against the same calibration bare (interleaved,
    # so that both see the same load on a shared machine)
    bare, datasets = 0.0, []
    with _Timed(cal_mod, "calibrate", keep_arg=True) as cal, _Timed(sim_mod, "random_plan") as plan, \
            _Timed(probing, "simulate_probes") as sim, _Timed(ProbedPoses, "measured_poses") as ver:
        trial_cpu = 0.0
        for t in trials:
            c0 = time.process_time()
            run_trial(t)
            c1 = time.process_time()
            ds, model = cal.kept.pop()
            datasets.append(ds)
            cal.real(ds, model)
            trial_cpu += c1 - c0
            bare += time.process_time() - c1
    n = len(trials)
    print(f"fig13 trials (12 poses, verified at 50), {n} in this process:")
    print(f"  a trial {1000 * trial_cpu / n:.1f} ms CPU; its calibration {1000 * cal.cpu / n:.1f} ms inside it, "
          f"{1000 * bare / n:.1f} ms bare: ratio {trial_cpu / cal.cpu:.2f} ({trial_cpu / bare:.2f} to the bare one)")
    other = trial_cpu - cal.cpu - plan.cpu - sim.cpu - ver.cpu
    print(f"  besides the calibration, per trial: plans {1000 * plan.cpu / n:.1f} ms, probe simulation "
          f"{1000 * sim.cpu / n:.1f} ms, verification fits {1000 * ver.cpu / n:.1f} ms, the rest "
          f"{1000 * other / n:.1f} ms")

    # 2. the study on 2 worker processes against the same calibrations, bare, on 2 worker processes
    from concurrent.futures import ProcessPoolExecutor

    from fgcal.studies.study_run import _worker_context

    c0, k0, w0 = time.process_time(), _cpu_children(), time.perf_counter()
    with ProcessPoolExecutor(max_workers=2, mp_context=_worker_context(trials)) as pool:
        cal_cpu = sum(pool.map(_calibrate_cpu, datasets))
    cal_wall = time.perf_counter() - w0
    cal_total = time.process_time() - c0 + _cpu_children() - k0
    with tempfile.TemporaryDirectory() as tmp:
        c0, k0, w0 = time.process_time(), _cpu_children(), time.perf_counter()
        rows = run_study(trials, tmp, workers=2, progress=False, runner=_trial_cpu)
        wall = time.perf_counter() - w0
        parent, workers = time.process_time() - c0, _cpu_children() - k0
    in_trials = sum(r["O1"] for r in rows)
    busy = sum(r["seconds"] for r in rows) / (2 * wall)
    total = parent + workers
    print(f"the same {n} calibrations bare on 2 local worker processes: {cal_wall:.2f} s wall, {cal_total:.2f} s CPU "
          f"({cal_cpu:.2f} s inside the calibrations)")
    print(f"the study on 2 local worker processes: {wall:.2f} s wall ({wall / cal_wall:.2f}x), {total:.2f} s CPU "
          f"({total / cal_total:.2f}x); set-up (start-up, imports, shipping trials and rows) {total - in_trials:.2f} s "
          f"({100 * (total - in_trials) / total:.0f}%); the 2 workers spent {100 * busy:.0f}% of the wall time inside "
          f"trials")

    if args.dask:
        from distributed import LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as cluster, tempfile.TemporaryDirectory() as tmp:
            w0 = time.perf_counter()
            run_study(trials, tmp, scheduler=cluster.scheduler_address, progress=False)
            print(f"the study on a Dask LocalCluster of 2 workers: {time.perf_counter() - w0:.2f} s wall")
    print(f"peak memory of this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB; "
          f"of a worker: {resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
