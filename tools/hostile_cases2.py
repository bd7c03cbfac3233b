"""The hostile sweep's round-2 cases (issue 26): every numeric option of every command with NaN,
infinity and a value out of its range (walked from the parser, so a new option is swept too),
outputs over the inputs of a run, edited results, corrupted checkpoints, pose ids beyond 64 bits,
URDF limits, model files, bounded provenance, and the cases the second sweep found."""
from __future__ import annotations

import argparse
import json
import shutil

from hostile_workspace import REPO, Case, chain, edit, fgcal, json_edit, line, write

DS_YAML = "ds/dataset.yaml"
PUMA = (REPO / "datasets/robots/puma560.yaml").read_text()

# the least each command needs before its options are parsed (files need not exist for an option error)
_POSITIONAL = {
    ("simulate",): ["sim-out"], ("measure",): ["ds"], ("calibrate",): ["ds", "--out", "x.json"],
    ("report",): ["result.json", "--out", "rep"], ("compensate",): ["result.json", "targets.csv"],
    ("online",): ["ds"], ("study",): ["fig13"], ("design",): ["--out", "p.csv"],
    ("import", "csv"): ["series.csv", "imp", "--robot", "ur10", "--joints", "a", "--joint-unit", "deg",
                        "--point", "x,y,z"],
    ("import", "tum"): ["t.txt", "imp", "--robot", "ur10", "--joint-log", "j.csv", "--joints", "a"],
    ("import", "landgraf"): ["series.csv", "imp"],
    ("import", "mukca"): ["mk", "imp", "--robot", "mk.urdf"],
}


def _numeric_options():
    """``(command words, option, Checked type)`` of every checked option of the parser."""
    import sys

    sys.path.insert(0, str(REPO))
    from fgcal.cli import build_parser
    from fgcal.cli.commands.options import Checked

    def walk(parser, prefix=()):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from walk(sub, prefix + (name,))
            elif isinstance(a.type, Checked) and a.option_strings:
                yield prefix, a.option_strings[-1], a.type, a.nargs

    return list(walk(build_parser()))


def option_cases() -> list[Case]:
    C = []
    for words, opt, kind, nargs in _numeric_options():
        base = [*words, *_POSITIONAL.get(words, [])]
        bad = ["nan", "inf"] + ([repr(kind.high * 10 + 1)] if kind.high is not None else []) \
            + ([repr(kind.low - 1)] if kind.low is not None else [])
        if kind.kind == "int":
            bad.append("2.5")
        for value in bad:
            vals = [value] * (nargs if isinstance(nargs, int) else 1)
            C.append(Case(f"option {' '.join(words)} {opt} {value}", [*base, opt, *vals], guard=("ds", "result.json")))
    for words, opt, value in [(("calibrate",), "--payload", "1e300"), (("calibrate",), "--payload", "nan"),
                              (("calibrate",), "--payload", "1,2,inf,3"), (("study",), "--scheduler", "not a url"),
                              (("online",), "--drift", "nan")]:
        extra = ["nan"] if opt == "--drift" else []
        C.append(Case(f"option {' '.join(words)} {opt} {value}", [*words, *_POSITIONAL[words], opt, value, *extra]))
    return C


def _own_robot(name="arm.yaml", ref=None):
    """ds names its own model file ``name`` (``robot: ref``)."""
    return chain(write(f"ds/{name}", PUMA), edit(DS_YAML, "robot: puma560", f"robot: {ref or name}"))


def _result(fn):
    return json_edit(fn, "result.json")


def _set_cov(d, k, v):
    d["covariance"][k][k] = v


def _ids(rel, old, new):
    """Pose id ``old`` replaced by ``new`` in the first column of a dataset file."""
    def f(w):
        p = w / rel
        ls = p.read_text().splitlines()
        p.write_text("\n".join([ls[0]] + [(new + r[len(old):]) if r.startswith(old + ",") else r for r in ls[1:]])
                     + "\n")
    return f


def _checkpoint(entry_fn):
    """A checkpoint ck of ds (ekf) whose journal has one entry edited by ``entry_fn``."""
    def f(w):
        header = {"format": "fgcal-online-checkpoint/3", "engine": "ekf", "dataset": str((w / "ds").resolve())}
        e = {"pose": 1, "accepted": True, "reason": "ok", "f": 1.0,
             "history": {"pose": 1, "n": 1, "estimate": [0.0] * 30, "sigma": [1.0] * 30}}
        entry_fn(e)
        (w / "ck").write_text(json.dumps(header) + "\n" + json.dumps(e) + "\n")
    return f


def _urdf_limit(attr):
    def f(w):
        import re
        t = (w / "mk.urdf").read_text()
        (w / "mk2.urdf").write_text(re.sub(r'lower="[^"]*"', attr, t, count=1))
        y = w / "cds" / "dataset.yaml"
        y.write_text(y.read_text().replace("robot: robot.urdf", "robot: ../mk2.urdf"))
    return f


def _urdf_entities():
    """mk2.urdf: 2 MB of entity text referenced 83 times (the 18 MB / 83x case, scaled down)."""
    def f(w):
        t = (w / "mk.urdf").read_text()
        head, body = t.split("?>", 1)
        ent = '<!DOCTYPE robot [<!ENTITY e "' + "x" * (2 << 20) + '">]>'
        body = body.replace("<robot ", "<!-- " + "&e;" * 0 + " -->\n<robot ", 1).replace(
            'name="panda"', 'name="' + "&e;" * 83 + '"', 1)
        (w / "mk2.urdf").write_text(head + "?>\n" + ent + body)
        y = w / "cds" / "dataset.yaml"
        y.write_text(y.read_text().replace("robot: robot.urdf", "robot: ../mk2.urdf"))
    return f


def _unusable_rows(n):
    def f(w):
        good = (w / "series.csv").read_text().splitlines()
        bad = ",".join(["x"] * len(good[0].split(",")))
        (w / "mixed.csv").write_text("\n".join(good + [bad] * n) + "\n")
    return f


def _model(extra):
    import yaml
    d = yaml.safe_load((REPO / "datasets/robots/ur10.yaml").read_text())
    d.update(extra)
    return yaml.safe_dump(d)


def _simulate(args):
    def f(w):
        code, out, err = fgcal(args, w)
        assert code == 0, err
    return f


def _study_once(w):
    code, out, err = fgcal(["study", "fig13", "--out", "st", "--trials", "1", "--poses", "8", "--seed", "0",
                            "--workers", "1"], w)
    assert code == 0, err


def special_cases() -> list[Case]:
    R = "result.json"
    import sys

    sys.path.insert(0, str(REPO))
    from fgcal.robots.robot_file import load_model

    names = ",".join(load_model("puma560").identifiable_names())  # every parameter ds estimates
    C = [
        # outputs over the inputs of a run (the robot file its dataset.yaml names, any suffix case)
        Case("calibrate out over own robot", ["calibrate", "ds", "--out", "ds/arm.yaml"], _own_robot()),
        Case("verify out over own robot", ["verify", R, "ds", "--out", "ds/arm.yaml"], _own_robot()),
        Case("online out over own robot", ["online", "ds", "--out", "ds/arm.yaml"], _own_robot()),
        Case("online checkpoint over own robot", ["online", "ds", "--checkpoint", "ds/arm.yaml"], _own_robot()),
        Case("online checkpoint over joints", ["online", "ds", "--checkpoint", "ds/joints.csv"]),
        Case("calibrate out over ARM.YAML", ["calibrate", "ds", "--out", "ds/ARM.YAML"], _own_robot("ARM.YAML")),
        *[Case(f"{cmd[0]} out over own URDF robot", cmd, chain(lambda w: shutil.copy(w / "mk.urdf", w / "ds" / "arm.urdf"),
                                                                edit(DS_YAML, "robot: puma560", "robot: arm.urdf")),
               tags=["contacts"])
          for cmd in (["calibrate", "ds", "--out", "ds/arm.urdf"], ["verify", R, "ds", "--out", "ds/arm.urdf"],
                      ["online", "ds", "--out", "ds/ARM.URDF"])],
        Case("check robot ARM.YAML in the dataset's folder", ["check", "ds"], _own_robot("ARM.YAML"), expect="ok"),
        Case("calibrate two datasets out over the second's joints", ["calibrate", "ds", "full", "--out",
                                                                    "full/joints.csv"], guard=("ds", "full")),
        Case("calibrate verification out over its joints", ["calibrate", "ds", "--verification", "full", "--out",
                                                           "full/joints.csv"], guard=("ds", "full")),
        Case("import csv force --robot OUT/myrobot.yaml", ["import", "csv", "series.csv", "OUT", "--force", "--robot",
                                                          "OUT/myrobot.yaml", "--joints", "a", "--joint-unit", "deg",
                                                          "--point", "x,y,z"],
             chain(lambda w: (w / "OUT").mkdir(), write("OUT/myrobot.yaml", PUMA)), guard=("OUT",)),
        # one validation of a loaded result
        *[Case(f"result {n} {cmd[0]}", cmd, _result(fn), guard=("ds", "full"))
          for n, fn in {"sigma null": lambda d: d["parameters"][0].update(sigma=None),
                        "sigma nan": lambda d: d["parameters"][0].update(sigma=float("nan")),
                        "sigma negative": lambda d: d["parameters"][0].update(sigma=-1),
                        "sigma string": lambda d: d["parameters"][0].update(sigma="x"),
                        "variance nan": lambda d: _set_cov(d, 0, float("nan")),
                        "variance negative": lambda d: _set_cov(d, 0, -1.0),
                        "parameter renamed": lambda d: d["parameters"][3].update(name="j9.theta")}.items()
          for cmd in (["report", R, "--out", "rep", "--tolerance", "1", "--verify", "verify.json"],
                      ["verify", R, "full"], ["export", R, "--model", "m.yaml"],
                      ["compensate", R, "targets.csv"])],
        # corrupted checkpoints
        *[Case(f"checkpoint {n}", ["online", "ds", "--engine", "ekf", "--checkpoint", "ck"], _checkpoint(fn),
               guard=("ds", "ck"))
          for n, fn in {"no accepted": lambda e: e.pop("accepted"), "no history": lambda e: e.pop("history"),
                        "pose 2^64": lambda e: e.update(pose=2**64), "pose -1": lambda e: e.update(pose=-1),
                        "history nan": lambda e: e["history"]["estimate"].__setitem__(0, float("nan")),
                        "record broken": lambda e: e.update(record={"pose": 1})}.items()],
        Case("checkpoint snapshot short", ["online", "ds", "--engine", "ekf", "--checkpoint", "ck"],
             chain(_checkpoint(lambda e: None), write("ck.snapshot", '{"n": 1, "state": {"x": [1, 2], "P": [[1]]}}')),
             guard=("ds",)),
        # pose ids
        Case("pose id 2^64 calibrate", ["calibrate", "ds", "--out", "x.json"],
             chain(_ids("ds/joints.csv", "1", str(2**64)), _ids("ds/probes.csv", "1", str(2**64)))),
        Case("pose id 2^70 check", ["check", "ds"], _ids("ds/joints.csv", "1", str(2**70))),
        Case("pose id -1 online isam2", ["online", "ds"],
             chain(_ids("ds/joints.csv", "1", "-1"), _ids("ds/probes.csv", "1", "-1"))),
        # a stream of no usable pose: each line named, then no result (a result from no pose is refused)
        Case("pose id 2^64 stdin", ["online", "ds", "--stdin", "--engine", "ekf"], expect="error",
             words=("out of range",), stdin=f"joints,{2**64},1,2,3,4,5,6\nend,{2**64}\n".encode()),
        Case("stream line of 10 MB", ["online", "ds", "--stdin", "--engine", "ekf"], expect="error",
             words=("characters)",), stdin=b"x" * (10 << 20) + b",1\n"),
        # numbers and names
        Case("exclude every parameter", ["calibrate", "ds", "--out", "x.json", "--exclude", names]),
        Case("noise cmm_sigma 1e308", ["calibrate", "ds", "--out", "x.json"],
             edit(DS_YAML, "cmm_sigma: 0.01", "cmm_sigma: 1e308")),
        Case("design candidates 5 columns", ["design", "--dataset", "ds", "--candidates", "c5.csv", "--out", "p.csv"],
             write("c5.csv", "pose,q1,q2,q3,q4,q5\n1,0,0,0,0,0\n")),
        Case("import csv holdout 0.01 of few rows", ["import", "landgraf", "series.csv", "imp", "--holdout", "0.01"]),
        Case("import csv 100000 unusable rows", ["import", "landgraf", "mixed.csv", "imp"], _unusable_rows(100_000),
             expect="warn", words=("more row(s)",)),
        # URDF and model files
        Case("urdf limit abc", ["check", "cds"], _urdf_limit('lower="abc"'), guard=("cds",), tags=["contacts"]),
        Case("urdf limit -inf", ["check", "cds"], _urdf_limit('lower="-inf"'), guard=("cds",), tags=["contacts"]),
        Case("urdf limit -1e300", ["check", "cds"], _urdf_limit('lower="-1e300"'), guard=("cds",), expect="warn",
             words=("taken as",), tags=["contacts"]),
        Case("urdf entity expanded 83x", ["check", "cds"], _urdf_entities(), guard=("cds",), tags=["contacts"]),
        Case("model urdf: hello", ["check", "ds"], chain(write("ds/m.yaml", _model({"urdf": "hello"})),
                                                         edit(DS_YAML, "robot: puma560", "robot: m.yaml"))),
        Case("model gearbox coupling 1/125", ["simulate", "gear", "--robot", "g.yaml", "--poses", "8"],
             write("g.yaml", _model({"coupling": {"matrix": [[1 / 125 if i == j else 0 for j in range(6)]
                                                             for i in range(6)]}})), expect="ok"),
        Case("robot /dev/stdin", ["check", "ds"], edit(DS_YAML, "robot: puma560", "robot: /dev/stdin"),
             stdin=b""),
        Case("robot /dev/stdin.yaml link", ["check", "ds"],
             chain(lambda w: (w / "ds" / "s.yaml").symlink_to("/dev/stdin"),
                   edit(DS_YAML, "robot: puma560", "robot: s.yaml")), stdin=b"format: fgcal-robot/1\n"),
        # export
        Case("export deltas", ["export", R, "--deltas", "d.csv"], expect="ok"),
        Case("cres export deltas", ["export", "cres.json", "--deltas", "d.csv"], expect="ok", tags=["contacts"]),
        # design of a reflector dataset (KeyError 'R' before)
        Case("design dataset reflector", ["design", "--dataset", "rds", "--out", "p.csv", "--poses", "10"],
             _simulate(["simulate", "rds", "--poses", "30", "--reflector", "0,0,100"]), expect="ok", guard=()),
        # study
        Case("study resumed with another seed", ["study", "fig13", "--out", "st", "--trials", "1", "--poses", "8",
                                                 "--seed", "1", "--workers", "1"], _study_once, guard=("st",)),
        Case("joints row 2^64 in the middle", ["check", "ds"], line("ds/joints.csv", 4, f"{2**64},1,2,3,4,5,6")),
    ]
    return C


def cases() -> list[Case]:
    out = option_cases() + special_cases()
    for c in out:
        c.tags.append("round2")
    return out
