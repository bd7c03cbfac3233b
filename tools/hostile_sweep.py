"""A hostile sweep over the fgcal command line: corrupted files, OS faults, bad options, odd inputs.

Every case runs ``python -m fgcal.cli ...`` in a fresh copy of a small workspace, in a child with
a time limit and an address-space limit (``resource.setrlimit``), and is classed as

- ``ok``: handled well (a bad input ended in one line on stderr and exit status 2; a documented
  partial success (compensate: exit 3) named what it left out; a good or
  doubtful one ended in status 0, with the warning or note it called for),
- ``traceback``: a Python traceback on stderr,
- ``silent``: status 0 where an error or warning was due, a multi-line or empty error, an input
  changed, or a temporary file left behind,
- ``hung``: the time limit passed,
- ``killed``: ended by a signal, or out of memory.

Usage: ``python tools/hostile_sweep.py [--jobs 2] [--only SUBSTRING] [--tag contacts] [--timeout 150]``.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from hostile_cases import cases
from hostile_workspace import COMMANDS, Case, build_base, fgcal, files_digest

# ---------------------------------------------------------------- running and classing

def leftovers(work: Path) -> list[str]:
    return [str(p.relative_to(work)) for p in work.rglob("*")
            if p.name.endswith(".tmp") or (p.name.startswith(".") and p.is_dir())]


def changes(work: Path, guard: dict) -> list[str]:
    """Inputs whose digest changed and temporary files left behind, as findings."""
    problems = [f"input {g} changed" for g, digest in guard.items() if files_digest(work / g) != digest]
    left = leftovers(work)
    if left:
        problems.append(f"left behind: {', '.join(left[:3])}")
    return problems


def run_case(case: Case, base: Path, timeout: float) -> tuple[str, str, float]:
    with tempfile.TemporaryDirectory(prefix="sweep-") as tmp:
        work = Path(tmp) / "w"
        shutil.copytree(base, work, symlinks=True)
        if case.setup:
            case.setup(work)
        guard = {g: files_digest(work / g) for g in case.guard}
        stdin = case.stdin
        t0 = time.perf_counter()
        code, out, err = fgcal(case.args, work, timeout=timeout, stdin=stdin, fsize=case.fsize)
        dt = time.perf_counter() - t0
        text = out + err
        if code is None:
            return "hung", f"no end after {timeout:.0f} s", dt
        if "Traceback" in err:
            return "traceback", err.strip().splitlines()[-1][:200], dt
        if code < 0 or "out of memory" in err or "MemoryError" in err:
            return "killed", f"status {code}: {err.strip()[-200:]}", dt
        problems = changes(work, guard)
        err_lines = [ln for ln in err.splitlines()  # warnings before an error are lines of their own
                     if ln.strip() and not ln.lower().startswith(("warning:", "note:"))]
        if case.expect == "error" or (case.expect == "either" and code != 0):
            if code == 0:
                problems.append("exit 0 where an error was due")
            elif code != 2:
                problems.append(f"exit {code}")
            elif len(err_lines) != 1:
                problems.append(f"{len(err_lines)} lines on stderr")
        elif case.expect == "partial":  # documented partial success: exit 3, what was left out named
            if code != 3 or not all(w in text for w in case.words):
                problems.append(f"exit {code} (partial success is 3) or no word of {case.words}")
        elif case.expect in ("ok", "warn") and code != 0:
            problems.append(f"exit {code}: {err.strip()[-200:]}")
        if code == 0 and case.expect in ("warn", "either") and not all(w in text for w in case.words):
            problems.append(f"no word of {case.words}")
        if problems:
            return "silent", "; ".join(problems) + f" | {err.strip()[-160:]}", dt
        return "ok", (err_lines[-1][:160] if err_lines else out.strip().splitlines()[-1][:160] if out.strip() else ""), dt


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--only", default=None, help="run the cases whose name holds this text")
    p.add_argument("--timeout", type=float, default=150.0)
    p.add_argument("--tag", default=None, help="run the cases with this tag (contacts)")
    p.add_argument("--list", action="store_true")
    args = p.parse_args(argv)
    todo = [c for c in cases() if (args.only is None or args.only in c.name) and (args.tag is None or args.tag in c.tags)]
    if args.list:
        for c in todo:
            print(c.name, "::", " ".join(map(str, c.args)))
        print(len(todo), "cases")
        return 0
    with tempfile.TemporaryDirectory(prefix="sweep-base-") as tmp:
        base = Path(tmp)
        build_base(base)
        if not (base / "series.csv").exists():
            todo = [c for c in todo if "series.csv" not in map(str, c.args)]
        counts: dict[str, int] = {}
        commands = set()
        with ThreadPoolExecutor(args.jobs) as pool:
            futures = [(c, pool.submit(run_case, c, base, args.timeout)) for c in todo]
            for c, fut in futures:
                try:
                    verdict, detail, dt = fut.result()
                except Exception as exc:
                    verdict, detail, dt = "setup-error", repr(exc)[:200], 0.0
                counts[verdict] = counts.get(verdict, 0) + 1
                if c.args and c.args[0] in COMMANDS:
                    commands.add(c.args[0])
                print(f"{verdict:10s} {dt:6.1f}s  {c.name}: {detail}", flush=True)
    print(f"\n{len(todo)} cases over {len(commands)} commands: " +
          ", ".join(f"{k} {counts.get(k, 0)}" for k in ("ok", "traceback", "silent", "hung", "killed", "setup-error")))
    return 0 if counts.get("ok", 0) == len(todo) else 1


if __name__ == "__main__":
    sys.exit(main())
