"""The hostile sweep's cases (see ``tools/hostile_sweep.py``): how each corrupts a copy of the
workspace, what it runs, and what a good outcome is. The contact cases are
``tools/hostile_contact_cases.py``, the second round's ``tools/hostile_cases2.py``."""
from __future__ import annotations

from hostile_workspace import (
    DS_YAML,
    LAUGHS,
    MUKCA,
    REPO,
    Case,
    chain,
    edit,
    fgcal,
    line,
    model_file,
    replace_with,
    scale_joints,
    scale_probes,
    write,
)


def cases() -> list[Case]:
    C = []
    # --- dataset.yaml, checked by `check` (and some by other readers)
    yaml_bad = {
        "yaml missing": replace_with(DS_YAML, "missing"),
        "yaml empty": write(DS_YAML, ""),
        "yaml binary": write(DS_YAML, bytes(range(256)) * 4),
        "yaml latin1": write(DS_YAML, b"format: fgcal-dataset/1\nrobot: \xe9\n"),
        "yaml laughs in provenance": lambda w: (w / DS_YAML).write_text(
            (w / DS_YAML).read_text().replace("provenance:", LAUGHS + "provenance: [*l9]\nold:")),
        "yaml duplicate key": lambda w: (w / DS_YAML).write_text((w / DS_YAML).read_text() + "robot: ur10\n"),
        "yaml deep nesting": lambda w: (w / DS_YAML).write_text(
            (w / DS_YAML).read_text() + "deep: " + "[" * 5000 + "]" * 5000 + "\n"),
        "yaml python tag": edit(DS_YAML, "robot: puma560", "robot: !!python/object/apply:os.system [ls]"),
        "yaml top-level list": write(DS_YAML, "- a\n- b\n"),
        "yaml wrong format": edit(DS_YAML, "format: fgcal-dataset/1", "format: fgcal-dataset/9"),
        "yaml robot number": edit(DS_YAML, "robot: puma560", "robot: 5"),
        "yaml robot unknown": edit(DS_YAML, "robot: puma560", "robot: puma999"),
        "yaml robot /dev/zero": edit(DS_YAML, "robot: puma560", "robot: /dev/zero"),
        "yaml robot etc/passwd": edit(DS_YAML, "robot: puma560", "robot: ../../../../../../etc/passwd"),
        "yaml robot abs passwd": edit(DS_YAML, "robot: puma560", "robot: /etc/passwd"),
        "yaml robot fifo.yaml": chain(replace_with("ds/m.yaml", "fifo"), edit(DS_YAML, "robot: puma560", "robot: m.yaml")),
        "yaml robot dir.yaml": chain(replace_with("ds/m.yaml", "dir"), edit(DS_YAML, "robot: puma560", "robot: m.yaml")),
        "yaml robot loop.yaml": chain(replace_with("ds/m.yaml", "loop"), edit(DS_YAML, "robot: puma560", "robot: m.yaml")),
        "yaml robot zero.yaml": chain(replace_with("ds/m.yaml", "devzero"), edit(DS_YAML, "robot: puma560", "robot: m.yaml")),
        "yaml robot sparse.yaml": chain(replace_with("ds/m.yaml", "sparse"), edit(DS_YAML, "robot: puma560", "robot: m.yaml")),
        "yaml robot dangling": chain(replace_with("ds/m.yaml", "dangling"), edit(DS_YAML, "robot: puma560", "robot: m.yaml")),
        "model laughs in description": model_file("m.yaml", (REPO / "datasets/robots/puma560.yaml").read_text()
                                                  + LAUGHS + "description: [*l9]\n"),
        "model secret mapping": model_file("m.yaml", "password: hunter2\nhunter2: 1\n"),
        "model secret text": model_file("m.yaml", "root:x:0:0:hunter2:/root:/bin/bash\n"),
        "model 4 links": model_file("m.yaml", "format: fgcal-robot/1\nbase: {}\ntool: {}\nlinks: [{}, {}, {}, {}]\n"
                                    "joint_limits: []\n"),
        "model links not list": model_file("m.yaml", "format: fgcal-robot/1\nbase: {}\ntool: {}\nlinks: 5\n"
                                           "joint_limits: []\n"),
        "model limit min>max": lambda w: (model_file("m.yaml", (REPO / "datasets/robots/puma560.yaml").read_text()
                                                     .replace("[-160, 160]", "[160, -160]", 1))(w)),
        "model nan": model_file("m.yaml", (REPO / "datasets/robots/puma560.yaml").read_text().replace(
            "tool:", "tool_old:", 1).replace("tool_old:", "tool: {pz: .nan}\nx_tool:", 1)),
        "tool radius negative": edit(DS_YAML, "radius: 6.35", "radius: -1"),
        "tool radius string": edit(DS_YAML, "radius: 6.35", "radius: big"),
        "tool balls empty": lambda w: (w / DS_YAML).write_text("\n".join(
            ln if not ln.startswith("  balls:") else "  balls: {}" for ln in (w / DS_YAML).read_text().splitlines()
            if not ln.startswith("    ")) + "\n"),
        "noise unknown key": edit(DS_YAML, "cmm_sigma: 0.01", "cmm_sigmaa: 0.01"),
        "noise nan": edit(DS_YAML, "cmm_sigma: 0.01", "cmm_sigma: .nan"),
        "noise negative": edit(DS_YAML, "cmm_sigma: 0.01", "cmm_sigma: -0.01"),
    }
    for name, f in yaml_bad.items():
        C.append(Case(name, ["check", "ds"], f))
    C.append(Case("yaml sci notation 1e-2", ["check", "ds"], edit(DS_YAML, "cmm_sigma: 0.01", "cmm_sigma: 1e-2"),
                  expect="ok"))
    C.append(Case("yaml sci notation 5e2 radius", ["check", "ds"], edit(DS_YAML, "radius: 6.35", "radius: 635e-2"),
                  expect="ok"))
    C.append(Case("check good dataset", ["check", "ds"], expect="ok"))

    # --- joints.csv
    J = "ds/joints.csv"
    joints_bad = {
        "joints missing": replace_with(J, "missing"),
        "joints empty": write(J, ""),
        "joints header only": write(J, "pose,q1,q2,q3,q4,q5,q6\n"),
        "joints bad header": line(J, 1, "pose,q1,q2,q3,q4,q5,q7"),
        "joints extra column": line(J, 1, "pose,q1,q2,q3,q4,q5,q6,q7"),
        "joints not a number": line(J, 3, "2,1,2,x,4,5,6"),
        "joints nan": line(J, 3, "2,1,2,nan,4,5,6"),
        "joints inf": line(J, 3, "2,1,2,inf,4,5,6"),
        "joints 1e308": line(J, 3, "2,1,2,1e308,4,5,6"),
        "joints duplicate id": line(J, 3, "1,1,2,3,4,5,6"),
        "joints float id": line(J, 3, "2.5,1,2,3,4,5,6"),
        "joints field count": line(J, 3, "2,1,2,3"),
        "joints non-utf8": lambda w: (w / J).write_bytes((w / J).read_bytes() + b"9,\xff\xfe,1,1,1,1,1\n"),
        "joints NUL byte": lambda w: (w / J).write_bytes((w / J).read_bytes() + b"9,1\x00,1,1,1,1,1\n"),
        "joints huge field": lambda w: (w / J).write_text((w / J).read_text() + "9," + "1" * 300000 + ",1,1,1,1,1\n"),
        "joints unterminated quote": lambda w: (w / J).write_text((w / J).read_text() + '9,"1,1,1,1,1,1\n'),
        "joints fifo": replace_with(J, "fifo"),
        "joints dir": replace_with(J, "dir"),
        "joints loop": replace_with(J, "loop"),
        "joints /dev/zero": replace_with(J, "devzero"),
        "joints sparse 200MB": replace_with(J, "sparse"),
    }
    for name, f in joints_bad.items():
        C.append(Case(name, ["check", "ds"], f))
    C.append(Case("joints in radians", ["check", "ds"], scale_joints(3.141592653589793 / 180), expect="warn",
                  words=("radians",)))
    C.append(Case("joints crlf", ["check", "ds"], lambda w: (w / J).write_bytes(
        (w / J).read_bytes().replace(b"\n", b"\r\n")), expect="ok"))
    C.append(Case("joints outside limits", ["check", "ds"], line(J, 2, "1,170,2,3,4,5,6"), expect="warn",
                  words=("outside the joint limits",)))

    # --- probes.csv and friends
    P = "ds/probes.csv"
    probes_bad = {
        "probes unknown ball": line(P, 2, "1,Z,1,2,3"),
        "probes unknown pose": line(P, 2, "99,A,1,2,3"),
        "probes not a number": line(P, 2, "1,A,1,two,3"),
        "probes 1e308": line(P, 2, "1,A,1e308,2,3"),
        "probes fifo": replace_with(P, "fifo"),
        "probes dir": replace_with(P, "dir"),
        "probes loop": replace_with(P, "loop"),
        "probes dangling": replace_with(P, "dangling"),
        "probes non-utf8": lambda w: (w / P).write_bytes((w / P).read_bytes() + b"1,\xe9,1,2,3\n"),
        "truth unknown parameter": edit("ds/truth.yaml", "parameters: {", "parameters: {j9.zz: 1, "),
        "truth outliers malformed": lambda w: (w / "ds/truth.yaml").write_text(
            (w / "ds/truth.yaml").read_text() + "outliers: [[a, A, b]]\n"),
        "truth fifo": replace_with("ds/truth.yaml", "fifo"),
        "truth laughs": lambda w: (w / "ds/truth.yaml").write_text(LAUGHS + (w / "ds/truth.yaml").read_text()),
    }
    for name, f in probes_bad.items():
        C.append(Case(name, ["check", "ds"], f))
    C.append(Case("probes in metres", ["check", "ds"], scale_probes(1e-3), expect="warn", words=("metres",)))
    C.append(Case("centres duplicate", ["check", "full"], lambda w: (w / "full/centres.csv").write_text(
        (w / "full/centres.csv").read_text() + (w / "full/centres.csv").read_text().splitlines()[1] + "\n"),
        guard=("full",)))
    C.append(Case("poses bad quaternion", ["check", "full"], line("full/poses.csv", 2, "1,1,2,3,2,0,0,0"),
                  guard=("full",)))
    C.append(Case("dataset is a file", ["check", "targets.csv"]))
    C.append(Case("dataset is a fifo", ["check", "fifo"], replace_with("fifo", "fifo")))
    C.append(Case("dataset missing", ["check", "nothing"]))
    C.append(Case("dataset loop", ["check", "loop"], replace_with("loop", "loop")))

    # --- calibrate
    C += [
        Case("calibrate ok", ["calibrate", "ds", "--out", "r.json"], expect="ok"),
        Case("calibrate out missing folder", ["calibrate", "ds", "--out", "nodir/r.json"]),
        Case("calibrate out is folder", ["calibrate", "ds", "--out", "ds"]),
        Case("calibrate out over joints", ["calibrate", "ds", "--out", "ds/joints.csv"]),
        Case("calibrate out over dataset.yaml", ["calibrate", "ds", "--out", "ds/dataset.yaml"]),
        Case("calibrate out parent is file", ["calibrate", "ds", "--out", "targets.csv/r.json"]),
        Case("calibrate out /proc", ["calibrate", "ds", "--out", "/proc/r.json"]),
        Case("calibrate out fifo", ["calibrate", "ds", "--out", "f.json"], replace_with("f.json", "fifo")),
        Case("calibrate out /dev/full", ["calibrate", "ds", "--out", "/dev/full"]),
        Case("calibrate full disk", ["calibrate", "ds", "--out", "r.json"], fsize=3000),
        Case("calibrate exclude unknown", ["calibrate", "ds", "--out", "r.json", "--exclude", "j9.a"]),
        Case("calibrate exclude not estimated", ["calibrate", "ds", "--out", "r.json", "--exclude", "j1.theta"]),
        Case("calibrate exclude empty", ["calibrate", "ds", "--out", "r.json", "--exclude", ","]),
        Case("calibrate extra unknown", ["calibrate", "ds", "--out", "r.json", "--extra", "x.y"]),
        Case("calibrate poses first:-3", ["calibrate", "ds", "--out", "r.json", "--poses", "first:-3"]),
        Case("calibrate poses last:0", ["calibrate", "ds", "--out", "r.json", "--poses", "last:0"]),
        Case("calibrate poses first:x", ["calibrate", "ds", "--out", "r.json", "--poses", "first:x"]),
        Case("calibrate poses huge range", ["calibrate", "ds", "--out", "r.json", "--poses", "1-9999999999999"]),
        Case("calibrate poses reversed", ["calibrate", "ds", "--out", "r.json", "--poses", "5-2"]),
        Case("calibrate poses missing id", ["calibrate", "ds", "--out", "r.json", "--poses", "1,99"]),
        Case("calibrate poses garbage", ["calibrate", "ds", "--out", "r.json", "--poses", "a-b"]),
        Case("calibrate too few poses", ["calibrate", "ds", "--out", "r.json", "--poses", "1-2"]),
        Case("calibrate levels unknown", ["calibrate", "ds", "--out", "r.json", "--levels", "stars"]),
        Case("calibrate levels absent", ["calibrate", "ds", "--out", "r.json", "--levels", "poses"]),
        Case("calibrate robust unknown", ["calibrate", "ds", "--out", "r.json", "--robust", "tukey"]),
        Case("calibrate no measurements", ["calibrate", "ds", "--out", "r.json"],
             write("ds/probes.csv", "pose,ball,x,y,z\n")),
        Case("calibrate poses without probes", ["calibrate", "ds", "--out", "r.json"],
             lambda w: (w / J).write_text((w / J).read_text() + "77,10,20,30,40,50,60\n"), expect="warn",
             words=("not used", "77")),
        Case("calibrate radians", ["calibrate", "ds", "--out", "r.json"], scale_joints(3.141592653589793 / 180),
             expect="either", words=("radians",)),
        Case("calibrate 1e308 probe", ["calibrate", "ds", "--out", "r.json"], line(P, 2, "1,A,1e308,2,3")),
        Case("calibrate missing dataset arg", ["calibrate", "--out", "r.json"]),
        Case("calibrate out empty name", ["calibrate", "ds", "--out", ""]),
    ]
    # --- measure
    C += [
        Case("measure ok", ["measure", "ds", "--out", "m"], expect="ok"),
        Case("measure out over input", ["measure", "ds", "--out", "ds", "--force"]),
        Case("measure out inside input", ["measure", "ds", "--out", "ds/m", "--force"]),
        Case("measure out exists", ["measure", "ds", "--out", "full"], guard=("ds", "full")),
        Case("measure out is file", ["measure", "ds", "--out", "targets.csv", "--force"]),
        Case("measure out parent file", ["measure", "ds", "--out", "targets.csv/m"]),
        Case("measure tolerance nan", ["measure", "ds", "--tolerance", "nan", "--method", "paper"]),
        Case("measure tolerance without paper", ["measure", "ds", "--tolerance", "0.1"]),
        Case("measure threshold negative", ["measure", "ds", "--threshold", "-1"]),
        Case("measure threshold inf", ["measure", "ds", "--threshold", "inf"]),
        Case("measure show negative", ["measure", "ds", "--show", "-1"]),
        Case("measure no probes", ["measure", "ur10ds"], guard=("ur10ds",)),
        Case("measure too few points", ["measure", "ds", "--out", "m"], lambda w: (w / P).write_text(
            "\n".join(ln for i, ln in enumerate((w / P).read_text().splitlines()) if i == 0 or i % 4 in (1, 2)) + "\n")),
        Case("measure full disk", ["measure", "ds", "--out", "m"], fsize=400),
        Case("measure metres", ["measure", "ds", "--out", "m"], scale_probes(1e-3), expect="either",
             words=("metres",)),
    ]
    # --- verify
    R = "result.json"
    C += [
        Case("verify ok", ["verify", R, "full", "--out", "v.json"], expect="ok", guard=("full",)),
        Case("verify another robot", ["verify", R, "ur10ds"], guard=("ur10ds",)),
        Case("verify out missing folder", ["verify", R, "full", "--out", "no/v.json"]),
        Case("verify out over result", ["verify", R, "full", "--out", R]),
        Case("verify out over input", ["verify", R, "full", "--out", "full/poses.csv"], guard=("full",)),
        Case("verify result missing", ["verify", "nothing.json", "full"]),
        Case("verify result empty", ["verify", R, "full"], write(R, "")),
        Case("verify result binary", ["verify", R, "full"], write(R, bytes(range(256)))),
        Case("verify result list", ["verify", R, "full"], write(R, "[1, 2]")),
        Case("verify result wrong format", ["verify", R, "full"], edit(R, "fgcal-result/1", "fgcal-result/7")),
        Case("verify result no slots", ["verify", R, "full"], edit(R, '"slots"', '"slotz"')),
        Case("verify result bad covariance", ["verify", R, "full"], edit(R, '"covariance": [', '"covariance": [[1], ')),
        Case("verify result slot string", ["verify", R, "full"], lambda w: (w / R).write_text(
            __import__("re").sub(r'("base.px": )[^,]+', r'\1"abc"', (w / R).read_text(), count=1))),
        Case("verify result slot 1e999", ["verify", R, "full"], lambda w: (w / R).write_text(
            __import__("re").sub(r'("j2.a": )[^,]+', r'\g<1>1e999', (w / R).read_text(), count=1))),
        Case("verify result robot_model broken", ["verify", R, "full"], edit(R, '"robot_model": {', '"robot_model": {"x": 1, ')),
        Case("verify result fifo", ["verify", R, "full"], replace_with(R, "fifo")),
        Case("verify result dir", ["verify", R, "full"], replace_with(R, "dir")),
        Case("verify result sparse", ["verify", R, "full"], replace_with(R, "sparse")),
        Case("verify result deep json", ["verify", R, "full"], write(R, "[" * 100000 + "]" * 100000)),
        Case("verify poses first:0", ["verify", R, "full", "--poses", "first:0"]),
        Case("verify no measurements", ["verify", R, "ds"], write("ds/probes.csv", "pose,ball,x,y,z\n")),
        Case("verify full disk", ["verify", R, "full", "--out", "v.json"], fsize=1000, guard=("full",)),
    ]
    # --- report
    V = "verify.json"
    C += [
        Case("report ok", ["report", R, "--verify", V, "--out", "rep"], expect="ok"),
        Case("report out is file", ["report", R, "--out", "targets.csv"]),
        Case("report out parent file", ["report", R, "--out", "targets.csv/rep"]),
        Case("report verify missing", ["report", R, "--verify", "none.json", "--out", "rep"]),
        Case("report verify not json", ["report", R, "--verify", V, "--out", "rep"], write(V, "{nope")),
        Case("report verify wrong format", ["report", R, "--verify", V, "--out", "rep"], write(V, '{"format": 1}')),
        Case("report verify fifo", ["report", R, "--verify", V, "--out", "rep"], replace_with(V, "fifo")),
        Case("report verify non-utf8", ["report", R, "--verify", V, "--out", "rep"], write(V, b"\xff\xfe{}")),
        Case("report verify other robot", ["report", R, "--verify", V, "--out", "rep"],
             edit(V, '"robot": "puma560"', '"robot": "ur10"')),
        Case("report verify poses garbage", ["report", R, "--verify", V, "--out", "rep"],
             edit(V, '"poses": [', '"poses": ["x", ')),
        Case("report result broken", ["report", R, "--out", "rep"], write(R, "{}")),
        Case("report full disk", ["report", R, "--out", "rep"], fsize=5000),
    ]
    # --- import
    S = "series.csv"
    C += [
        Case("import ok", ["import", "landgraf", S, "imp"], expect="ok"),
        Case("import missing", ["import", "landgraf", "none.csv", "imp"]),
        Case("import fifo", ["import", "landgraf", S, "imp"], replace_with(S, "fifo")),
        Case("import dir", ["import", "landgraf", S, "imp"], replace_with(S, "dir")),
        Case("import non-utf8", ["import", "landgraf", S, "imp"], lambda w: (w / S).write_bytes(
            (w / S).read_bytes() + b"\xff\xfe;;\n")),
        Case("import empty", ["import", "landgraf", S, "imp"], write(S, "")),
        Case("import wrong header", ["import", "landgraf", S, "imp"], write(S, "a;b;c\n1;2;3\n")),
        Case("import header only", ["import", "landgraf", S, "imp"], lambda w: (w / S).write_text(
            (w / S).read_text().splitlines()[0] + "\n")),
        Case("import out exists", ["import", "landgraf", S, "ds"]),
        Case("import out over input folder", ["import", "landgraf", "ds/joints.csv", "ds", "--force"]),
        Case("import holdout nan", ["import", "landgraf", S, "imp", "--holdout", "nan"]),
        Case("import holdout 1", ["import", "landgraf", S, "imp", "--holdout", "1"]),
        Case("import quote garbage", ["import", "landgraf", S, "imp"], lambda w: (w / S).write_text(
            (w / S).read_text() + '"' + "x" * 200000 + "\n")),
        Case("import full disk", ["import", "landgraf", S, "imp"], fsize=1000),
    ]
    # --- compensate
    T = "targets.csv"
    C += [
        Case("compensate ok", ["compensate", R, T, "--out", "cmd.csv"], expect="ok"),
        Case("compensate targets missing", ["compensate", R, "none.csv"]),
        Case("compensate targets fifo", ["compensate", R, T], replace_with(T, "fifo")),
        Case("compensate targets empty", ["compensate", R, T], write(T, "")),
        Case("compensate targets header only", ["compensate", R, T], write(T, "pose,x,y,z,qw,qx,qy,qz\n")),
        Case("compensate bad quaternion", ["compensate", R, T], line(T, 2, "1,1,2,3,0,0,0,0")),
        Case("compensate partial seeds", ["compensate", R, T], write(T, "pose,x,y,z,qw,qx,qy,qz,q1\n1,1,2,3,1,0,0,0,5\n")),
        Case("compensate 1e308 target", ["compensate", R, T], line(T, 2, "1,1e308,2,3,1,0,0,0")),
        Case("compensate out over targets", ["compensate", R, T, "--out", T]),
        Case("compensate out over result", ["compensate", R, T, "--out", R]),
        Case("compensate out missing folder", ["compensate", R, T, "--out", "no/c.csv"]),
        Case("compensate unreachable", ["compensate", R, T], line(T, 2, "1,90000,2,3,1,0,0,0"), expect="partial",
             words=("pose 1", "reach")),
    ]
    # --- export
    C += [
        Case("export ok", ["export", R, "--model", "m.yaml", "--urdf", "m.urdf"], expect="ok"),
        Case("export nothing", ["export", R]),
        Case("export same file twice", ["export", R, "--model", "m.x", "--urdf", "m.x"]),
        Case("export over result", ["export", R, "--model", R]),
        Case("export missing folder", ["export", R, "--urdf", "no/m.urdf"]),
        Case("export result fifo", ["export", R, "--urdf", "m.urdf"], replace_with(R, "fifo")),
        Case("export full disk", ["export", R, "--urdf", "m.urdf"], fsize=500),
    ]
    # --- online (checkpoint handling belongs to another helper; these probe inputs and outputs)
    C += [
        Case("online out missing folder", ["online", "ds", "--out", "no/r.json", "--checkpoint", "c.json"]),
        Case("online plot over input", ["online", "ds", "--plot", "ds/joints.csv", "--checkpoint", "c.json"]),
        Case("online interval nan", ["online", "ds", "--interval", "nan"]),
        Case("online drift negative", ["online", "ds", "--engine", "ekf", "--drift", "-1", "0"]),
        Case("online drift nan", ["online", "ds", "--engine", "ekf", "--drift", "nan", "0"]),
        Case("online drift isam2", ["online", "ds", "--drift", "1", "1"]),
        Case("online stdin and follow", ["online", "ds", "--stdin", "--follow"]),
        Case("online dataset broken", ["online", "ds", "--checkpoint", "c.json"], line(J, 3, "2,x,2,3,4,5,6")),
        Case("online checkpoint is dir", ["online", "ds", "--checkpoint", "cdir"], replace_with("cdir", "dir")),
        Case("online checkpoint garbage", ["online", "ds", "--checkpoint", "c.json"], write("c.json", "{garbage")),
    ]
    # --- study
    C += [
        Case("study trials 0", ["study", "fig13", "--trials", "0"]),
        Case("study workers -2", ["study", "fig13", "--workers", "-2"]),
        Case("study seed negative", ["study", "fig13", "--seed", "-1"]),
        Case("study out is file", ["study", "fig13", "--out", "targets.csv", "--trials", "1"]),
        Case("study out parent file", ["study", "fig13", "--out", "targets.csv/s", "--trials", "1"]),
        Case("study trials.csv garbage", ["study", "fig13", "--out", "st", "--trials", "1"],
             chain(replace_with("st", "dir"), write("st/trials.csv", "a,b\n1,2\n"))),
        Case("study trials.csv non-utf8", ["study", "fig13", "--out", "st", "--trials", "1"],
             chain(replace_with("st", "dir"), write("st/trials.csv", b"study,trial\n\xff,1\n"))),
        Case("study trials.csv bad trial", ["study", "fig13", "--out", "st", "--trials", "1"],
             chain(replace_with("st", "dir"), write("st/trials.csv", "study,trial,seed\nfig13,x,0\n"))),
        Case("study trials.csv fifo", ["study", "fig13", "--out", "st", "--trials", "1"],
             chain(replace_with("st", "dir"), replace_with("st/trials.csv", "fifo"))),
        Case("study resume other seed", ["study", "fig13", "--out", "st", "--trials", "1", "--poses", "8",
                                         "--seed", "5", "--workers", "1"], lambda w: _study_once(w)),
        Case("study scheduler unreachable", ["study", "fig13", "--trials", "1", "--scheduler", "tcp://127.0.0.1:9"]),
    ]
    # --- design
    C += [
        Case("design poses 2", ["design", "--out", "p.csv", "--poses", "2"]),
        Case("design candidates 0", ["design", "--out", "p.csv", "--candidates", "0"]),
        Case("design cmm nan", ["design", "--out", "p.csv", "--cmm-sigma", "nan"]),
        Case("design robot unknown", ["design", "--out", "p.csv", "--robot", "r2d2"]),
        Case("design robot fifo", ["design", "--out", "p.csv", "--robot", "m.yaml"], replace_with("m.yaml", "fifo")),
        Case("design out missing folder", ["design", "--out", "no/p.csv"]),
        Case("design out is dir", ["design", "--out", "ds"]),
        Case("design index unknown", ["design", "--out", "p.csv", "--index", "O9"]),
    ]
    # --- simulate
    C += [
        Case("simulate ok", ["simulate", "s", "--poses", "6"], expect="ok"),
        Case("simulate exists", ["simulate", "ds"]),
        Case("simulate over input truth", ["simulate", "ds", "--force", "--truth", "ds/truth.yaml"]),
        Case("simulate parent file", ["simulate", "targets.csv/s"]),
        Case("simulate cmm nan", ["simulate", "s", "--cmm-sigma", "nan"]),
        Case("simulate cmm -1", ["simulate", "s", "--cmm-sigma", "-1"]),
        Case("simulate poses 0", ["simulate", "s", "--poses", "0"]),
        Case("simulate poses 3", ["simulate", "s", "--poses", "3"], expect="either"),
        Case("simulate balls 0", ["simulate", "s", "--balls", "0"]),
        Case("simulate balls 9", ["simulate", "s", "--balls", "9"]),
        Case("simulate probes per ball 1", ["simulate", "s", "--probes-per-ball", "1"], expect="either",
             words=("probe",)),
        Case("simulate outliers 1", ["simulate", "s", "--outliers", "1"]),
        Case("simulate levels unknown", ["simulate", "s", "--levels", "stars"]),
        Case("simulate seed negative", ["simulate", "s", "--seed", "-1"]),
        Case("simulate truth missing", ["simulate", "s", "--truth", "none.yaml"]),
        Case("simulate truth garbage", ["simulate", "s", "--truth", "targets.csv"]),
        Case("simulate truth partial", ["simulate", "s", "--truth", "t.yaml"], write("t.yaml", "parameters: {j2.a: 431}\n")),
        Case("simulate robot passwd", ["simulate", "s", "--robot", "/etc/passwd"]),
        Case("simulate robot fifo", ["simulate", "s", "--robot", "m.yaml"], replace_with("m.yaml", "fifo")),
        Case("simulate full disk", ["simulate", "s", "--poses", "8"], fsize=2000),
        Case("simulate poses 10 million", ["simulate", "s", "--poses", "10000000"]),
    ]
    # --- demo and the top level
    C += [
        Case("demo out is file", ["demo", "--out", "targets.csv"]),
        Case("demo out parent file", ["demo", "--out", "targets.csv/d"]),
        Case("no command", []),
        Case("unknown command", ["frobnicate"]),
        Case("unknown option", ["check", "ds", "--frob"]),
    ]
    if (REPO / "tools").exists() and MUKCA.exists():
        from hostile_contact_cases import contact_cases  # MUKCa import, fixtures, contacts results

        C += [c for c in contact_cases() if not c.tags.append("contacts")]
    from hostile_cases2 import cases as round2  # issue 26: every numeric option, inputs, results, checkpoints

    C += [c for c in round2() if MUKCA.exists() or "contacts" not in c.tags]
    return C


def _study_once(w):
    code, out, err = fgcal(["study", "fig13", "--out", "st", "--trials", "1", "--poses", "8", "--seed", "0",
                            "--workers", "1"], w)
    assert code == 0, err
