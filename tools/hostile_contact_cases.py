"""The hostile sweep's contact cases (see ``tools/hostile_sweep.py``; joined to the others by
``tools/hostile_cases.py`` when the MUKCa data are there): ``import mukca`` of corrupted placements,
fixtures, planes and distances in ``dataset.yaml``, and a contacts result corrupted before
``verify``, ``report`` and ``export``."""
from __future__ import annotations

from hostile_workspace import LAUGHS, REPO, Case, chain, edit, json_edit, line, replace_with, write

MK = "mk"  # the placements (a copy of the MUKCa data); mk.urdf its robot
H0 = "mk/back_left/hole_0.csv"
CDS = "cds/dataset.yaml"
CC = "cds/contacts.csv"
ROW = "0.1,0.2,0.3,-2.0,0.4,2.5,0.8"  # a plausible Panda joint set (rad)


def _imp(*extra, out="imp"):
    return ["import", "mukca", MK, out, "--robot", "mk.urdf", "--chain", "panda_link0,ball_link", *extra]


def _map_hole(rel, fn):
    """Every value of the hole file ``rel`` through ``fn``."""
    def f(w):
        p = w / rel
        rows = [",".join(repr(fn(float(v))) for v in ln.split(",")) for ln in p.read_text().splitlines() if ln.strip()]
        p.write_text("\n".join(rows) + "\n")
    return f


def _cut(rel, key, new):
    """``rel`` from ``key`` on replaced by ``new`` (the keys after it are gone)."""
    def f(w):
        p = w / rel
        t = p.read_text()
        assert key in t, (rel, key)
        p.write_text(t[:t.index(key)] + new)
    return f


def _rename(old, new):
    return lambda w: (w / old).rename(w / new)


def _urdf_edit(old_re, new, count=1):
    def f(w):
        import re
        p = w / "mk.urdf"
        t, n = re.subn(old_re, new, p.read_text(), count=count, flags=re.S)
        assert n, old_re
        p.write_text(t)
    return f


def _yaml_add(text, rel=CDS):
    """Append ``text`` under ``fixtures:`` (a line such as ``  table: {type: plane}``)."""
    return edit(rel, "fixtures:\n", "fixtures:\n" + text)


def _distance(item):
    return edit(CDS, "  distances:\n", f"  distances:\n  - {item}\n")


def _contacts_to(fixture, first, last):
    """Rows ``first``..``last`` (data rows, 1-based) of cds/contacts.csv moved to ``fixture``."""
    def f(w):
        p = w / CC
        ls = p.read_text().splitlines()
        for i in range(first, last + 1):
            pose, ball, _ = ls[i].split(",")
            ls[i] = f"{pose},{ball},{fixture}"
        p.write_text("\n".join(ls) + "\n")
    return f


def _result_edit(fn):
    return json_edit(fn, "cres.json")


def contact_cases() -> list[Case]:
    C = []
    g = ("mk", "mk.urdf")
    imp_bad = {
        "mukca DIR missing": (["import", "mukca", "none", "imp", "--robot", "mk.urdf", "--chain", "panda_link0,ball_link"], None),
        "mukca DIR is a file": (["import", "mukca", "mk.urdf", "imp", "--robot", "mk.urdf", "--chain", "panda_link0,ball_link"], None),
        "mukca DIR fifo": (["import", "mukca", "f", "imp", "--robot", "mk.urdf", "--chain", "panda_link0,ball_link"],
                           replace_with("f", "fifo")),
        "mukca DIR empty": (_imp(), lambda w: [__import__("shutil").rmtree(w / MK), (w / MK).mkdir()]),
        "mukca DIR empty folders": (_imp(), lambda w: [__import__("shutil").rmtree(w / MK), (w / MK / "a").mkdir(parents=True),
                                                        (w / MK / "b").mkdir()]),
        "mukca hole 6 columns": (_imp(), line(H0, 2, ROW.rsplit(",", 1)[0])),
        "mukca hole 8 columns": (_imp(), line(H0, 2, ROW + ",0.1")),
        "mukca hole nan": (_imp(), line(H0, 2, ROW.replace("0.2", "nan"))),
        "mukca hole inf": (_imp(), line(H0, 2, ROW.replace("0.2", "inf"))),
        "mukca hole 1e300": (_imp(), line(H0, 2, ROW.replace("0.2", "1e300"))),
        "mukca hole text": (_imp(), line(H0, 2, ROW.replace("0.2", "abc"))),
        "mukca hole empty field": (_imp(), line(H0, 2, ROW.replace("0.2", "") + ",0.3")),
        "mukca hole header": (_imp(), lambda w: (w / H0).write_text("q1,q2,q3,q4,q5,q6,q7\n" + (w / H0).read_text())),
        "mukca hole empty": (_imp(), write(H0, "")),
        "mukca hole blank lines": (_imp(), write(H0, "\n\n  \n")),
        "mukca hole degrees": (_imp(), _map_hole(H0, __import__("math").degrees)),
        "mukca hole one value 7 rad": (_imp(), line(H0, 2, ROW.replace("0.2", "7.0"))),
        "mukca hole non-utf8": (_imp(), lambda w: (w / H0).write_bytes((w / H0).read_bytes() + b"\xff\xfe,1\n")),
        "mukca hole NUL": (_imp(), lambda w: (w / H0).write_bytes((w / H0).read_bytes() + b"0.1\x00,1\n")),
        "mukca hole fifo": (_imp(), replace_with(H0, "fifo")),
        "mukca hole dir": (_imp(), replace_with(H0, "dir")),
        "mukca hole loop": (_imp(), replace_with(H0, "loop")),
        "mukca hole dangling": (_imp(), replace_with(H0, "dangling")),
        "mukca hole /dev/zero": (_imp(), replace_with(H0, "devzero")),
        "mukca hole sparse 200MB": (_imp(), replace_with(H0, "sparse")),
        "mukca hole 200k rows": (_imp(), write(H0, (ROW + "\n") * 200_000)),
        "mukca placement loop": (_imp(), replace_with("mk/back_left", "loop")),
        "mukca placement comma": (_imp(), _rename("mk/back_left", "mk/back,left")),
        "mukca placement newline": (_imp(), _rename("mk/back_left", "mk/back\nleft")),
        "mukca placement edge space": (_imp(), _rename("mk/back_left", "mk/back_left ")),
        "mukca out inside DIR": (_imp(out="mk/imp"), None),
        "mukca out is DIR": (_imp("--force", out="mk"), None),
        "mukca out contains DIR": (_imp("--force", out="."), None),
        "mukca out is robot file": (_imp("--force", out="mk.urdf"), None),
        "mukca out is robot folder": (["import", "mukca", MK, "rf", "--robot", "rf/panda.urdf", "--force", "--chain",
                                       "panda_link0,ball_link"],
                                      lambda w: [(w / "rf").mkdir(), (w / "rf/panda.urdf").write_bytes((w / "mk.urdf").read_bytes())]),
        "mukca out exists": (_imp(out="cds"), None),
        "mukca out-holdout is DIR": (["import", "mukca", "x-holdout", "x", "--robot", "mk.urdf", "--chain", "panda_link0,ball_link",
                                      "--holdout-placements", "high", "--force"], _rename("mk", "x-holdout")),
        "mukca out parent file": (_imp(out="mk.urdf/imp"), None),
        "mukca holdout unknown": (_imp("--holdout-placements", "nowhere"), None),
        "mukca holdout all": (_imp("--holdout-placements", "back_left,back_right,front_center,front_left,front_right,"
                                                              "high,mid-high,mid_left,mid_right"), None),
        "mukca holdout empty": (_imp("--holdout-placements", ","), None),
        "mukca chain one link": (["import", "mukca", MK, "imp", "--robot", "mk.urdf", "--chain", "ball_link"], None),
        "mukca chain three links": (["import", "mukca", MK, "imp", "--robot", "mk.urdf", "--chain", "a,b,c"], None),
        "mukca chain empty": (["import", "mukca", MK, "imp", "--robot", "mk.urdf", "--chain", ","], None),
        "mukca chain unknown link": (["import", "mukca", MK, "imp", "--robot", "mk.urdf", "--chain", "panda_link0,nowhere"], None),
        "mukca chain reversed": (["import", "mukca", MK, "imp", "--robot", "mk.urdf", "--chain", "ball_link,panda_link0"], None),
        "mukca chain wrong joints": (["import", "mukca", MK, "imp", "--robot", "mk.urdf", "--chain", "panda_link0,panda_link5"], None),
        "mukca no chain": (["import", "mukca", MK, "imp", "--robot", "mk.urdf"], None),
        "mukca urdf no ball_link": (_imp(), _urdf_edit(r'<link name="ball_link">.*?</link>', "")),
        "mukca robot missing": (["import", "mukca", MK, "imp", "--robot", "none.urdf"], None),
        "mukca robot fifo": (["import", "mukca", MK, "imp", "--robot", "f.urdf"], replace_with("f.urdf", "fifo")),
        "mukca robot garbage": (["import", "mukca", MK, "imp", "--robot", "g.urdf"], write("g.urdf", "<robot><link")),
        "mukca robot 6 joints": (["import", "mukca", MK, "imp", "--robot", "ur10"], None),
        "mukca robot 6 joints file": (["import", "mukca", MK, "imp", "--robot", str(REPO / "datasets/robots/ur10.yaml")],
                                      None),
        "mukca distance 0": (_imp("--distance", "0"), None),
        "mukca distance nan": (_imp("--distance", "nan"), None),
        "mukca distance-sigma -1": (_imp("--distance-sigma", "-1"), None),
        "mukca contact-sigma inf": (_imp("--contact-sigma", "inf"), None),
        "mukca full disk": (_imp(), None),
    }
    for name, (args, setup) in imp_bad.items():
        C.append(Case(name, args, setup, guard=g, fsize=3000 if name == "mukca full disk" else None))
    C += [
        Case("mukca ok", _imp(), expect="ok", guard=g),
        Case("mukca ok holdout", _imp("--holdout-placements", "high,mid_left"), expect="ok", guard=g),
        Case("mukca ok force", _imp("--force", out="cds"), expect="ok", guard=g),
        Case("mukca only hole_0", _imp(), replace_with("mk/back_left/hole_1.csv", "missing"), expect="warn",
             words=("back_left", "hole_1")),
        Case("mukca folder without holes", _imp(), lambda w: (w / MK / "notes").mkdir(), expect="warn",
             words=("notes",)),
        Case("mukca stray file", _imp(), write("mk/back_left/hole_2.csv", ROW + "\n"), expect="warn",
             words=("hole_2.csv",)),
        Case("mukca hole crlf", _imp(), lambda w: (w / H0).write_bytes((w / H0).read_bytes().replace(b"\n", b"\r\n")),
             expect="ok", guard=g),
        Case("mukca hole spaces", _imp(), lambda w: (w / H0).write_text((w / H0).read_text().replace(",", " ")),
             expect="ok", guard=g),
        Case("mukca hole one row", _imp(), write(H0, ROW + "\n"), expect="either", words=("1",), guard=g),
        Case("mukca placement unicode", _imp(), _rename("mk/back_left", "mk/hinten_links_ü"), expect="ok", guard=g),
        Case("mukca placement yaml chars", _imp(), _rename("mk/back_left", "mk/#&*! [x]: {y}"), expect="either",
             words=("#&*!",), guard=g),
    ]
    # --- fixtures: and constraints: of dataset.yaml (check), contacts.csv
    fx_bad = {
        "fixture type cone": edit(CDS, "back_left/hole_0: {type: point}", "back_left/hole_0: {type: cone}"),
        "fixture type missing": edit(CDS, "back_left/hole_0: {type: point}", "back_left/hole_0: {}"),
        "fixture not a mapping": edit(CDS, "back_left/hole_0: {type: point}", "back_left/hole_0: point"),
        "fixture position 2": edit(CDS, "back_left/hole_0: {type: point}", "back_left/hole_0: {type: point, position: [1, 2]}"),
        "fixture position 4": edit(CDS, "back_left/hole_0: {type: point}",
                                   "back_left/hole_0: {type: point, position: [1, 2, 3, 4]}"),
        "fixture position nan": edit(CDS, "back_left/hole_0: {type: point}",
                                     "back_left/hole_0: {type: point, position: [.nan, 2, 3], sigma: 1}"),
        "fixture position text": edit(CDS, "back_left/hole_0: {type: point}",
                                      "back_left/hole_0: {type: point, position: [a, 2, 3], sigma: 1}"),
        "fixture position string": edit(CDS, "back_left/hole_0: {type: point}",
                                        "back_left/hole_0: {type: point, position: '1, 2, 3', sigma: 1}"),
        "fixture sigma 0": edit(CDS, "back_left/hole_0: {type: point}",
                                "back_left/hole_0: {type: point, position: [1, 2, 3], sigma: 0}"),
        "fixture sigma negative": edit(CDS, "back_left/hole_0: {type: point}",
                                       "back_left/hole_0: {type: point, position: [1, 2, 3], sigma: -1}"),
        "fixture sigma inf": edit(CDS, "back_left/hole_0: {type: point}",
                                  "back_left/hole_0: {type: point, position: [1, 2, 3], sigma: .inf}"),
        "fixture sigma text": edit(CDS, "back_left/hole_0: {type: point}",
                                   "back_left/hole_0: {type: point, position: [1, 2, 3], sigma: big}"),
        "fixture fixed no position": edit(CDS, "back_left/hole_0: {type: point}", "back_left/hole_0: {type: point, fixed: true}"),
        "fixture sigma no position": edit(CDS, "back_left/hole_0: {type: point}", "back_left/hole_0: {type: point, sigma: 1}"),
        "fixture fixed text": edit(CDS, "back_left/hole_0: {type: point}",
                                   "back_left/hole_0: {type: point, position: [1, 2, 3], fixed: maybe}"),
        "fixture unknown key": edit(CDS, "back_left/hole_0: {type: point}", "back_left/hole_0: {type: point, radius: 3}"),
        "fixture point with normal": edit(CDS, "back_left/hole_0: {type: point}",
                                          "back_left/hole_0: {type: point, normal: [0, 0, 1]}"),
        "fixture name comma": edit(CDS, "back_left/hole_0: {type: point}", "'a,b': {type: point}"),
        "fixture name number": edit(CDS, "back_left/hole_0: {type: point}", "5: {type: point}"),
        "fixture name empty": edit(CDS, "back_left/hole_0: {type: point}", "'': {type: point}"),
        "fixture name edge space": edit(CDS, "back_left/hole_0: {type: point}", "' x': {type: point}"),
        "fixtures a list": _cut(CDS, "fixtures:", "fixtures: [a, b]\n"),
        "fixtures a string": _cut(CDS, "fixtures:", "fixtures: points\n"),
        "fixtures laughs": lambda w: (w / CDS).write_text(LAUGHS + (w / CDS).read_text().replace(
            "fixtures:\n", "fixtures:\n  lol: [*l9]\n")),
        "plane normal zero": _yaml_add("  table: {type: plane, normal: [0, 0, 0], offset: 1}\n"),
        "plane normal nan": _yaml_add("  table: {type: plane, normal: [0, .nan, 1], offset: 1}\n"),
        "plane normal 1e-200": _yaml_add("  table: {type: plane, normal: [1e-200, 0, 0], offset: 1, fixed: true}\n"),
        "plane normal 2": _yaml_add("  table: {type: plane, normal: [0, 1], offset: 1}\n"),
        "plane offset only": _yaml_add("  table: {type: plane, offset: 1}\n"),
        "plane normal only": _yaml_add("  table: {type: plane, normal: [0, 0, 1]}\n"),
        "plane offset inf": _yaml_add("  table: {type: plane, normal: [0, 0, 1], offset: .inf}\n"),
        "plane with position": _yaml_add("  table: {type: plane, position: [0, 0, 1]}\n"),
        "distance names plane": chain(_yaml_add("  table: {type: plane}\n"), _distance("[back_left/hole_0, table, 50, 0.1]")),
        "distance same twice": _distance("[back_left/hole_0, back_left/hole_0, 50, 0.1]"),
        "distance negative": _distance("[back_left/hole_0, back_right/hole_0, -50, 0.1]"),
        "distance zero": _distance("[back_left/hole_0, back_right/hole_0, 0, 0.1]"),
        "distance sigma 0": _distance("[back_left/hole_0, back_right/hole_0, 50, 0]"),
        "distance nan": _distance("[back_left/hole_0, back_right/hole_0, .nan, 0.1]"),
        "distance text": _distance("[back_left/hole_0, back_right/hole_0, far, 0.1]"),
        "distance bool": _distance("[back_left/hole_0, back_right/hole_0, true, 0.1]"),
        "distance unknown": _distance("[back_left/hole_0, nowhere, 50, 0.1]"),
        "distance 3 items": _distance("[back_left/hole_0, back_right/hole_0, 50]"),
        "distance not a list": _distance("back_left/hole_0"),
        "distance duplicate": _distance("[back_left/hole_0, back_left/hole_1, 50.0, 0.05]"),
        "distance duplicate reversed": _distance("[back_left/hole_1, back_left/hole_0, 49.0, 0.05]"),
        "constraints unknown key": edit(CDS, "constraints:\n", "constraints:\n  angles: []\n"),
        "constraints a list": _cut(CDS, "constraints:", "constraints: [1]\n"),
        "contact_sigma -1": edit(CDS, "contact_sigma: 0.05", "contact_sigma: -1"),
        "contact_sigma 0": edit(CDS, "contact_sigma: 0.05", "contact_sigma: 0"),
        "contact_sigma nan": edit(CDS, "contact_sigma: 0.05", "contact_sigma: .nan"),
        "contact_sigma text": edit(CDS, "contact_sigma: 0.05", "contact_sigma: small"),
        "contacts unknown fixture": line(CC, 3, "2,B,nowhere"),
        "contacts fixture empty": line(CC, 3, "2,B,"),
        "contacts duplicate": line(CC, 3, "1,B,back_left/hole_0"),
        "contacts duplicate other fixture": line(CC, 3, "1,B,back_left/hole_1"),
        "contacts unknown ball": line(CC, 3, "2,Z,back_left/hole_0"),
        "contacts unknown pose": line(CC, 3, "9999,B,back_left/hole_0"),
        "contacts pose text": line(CC, 3, "two,B,back_left/hole_0"),
        "contacts extra column": lambda w: (w / CC).write_text("\n".join(
            ln + (",note" if i == 0 else ",x") for i, ln in enumerate((w / CC).read_text().splitlines())) + "\n"),
        "contacts missing column": lambda w: (w / CC).write_text("\n".join(
            ln.rsplit(",", 1)[0] for ln in (w / CC).read_text().splitlines()) + "\n"),
        "contacts field count": line(CC, 3, "2,B"),
        "contacts non-utf8": lambda w: (w / CC).write_bytes((w / CC).read_bytes() + b"3,B,\xff\n"),
        "contacts fifo": replace_with(CC, "fifo"),
        "contacts dir": replace_with(CC, "dir"),
        "contacts loop": replace_with(CC, "loop"),
        "contacts /dev/zero": replace_with(CC, "devzero"),
        "contacts sparse 200MB": replace_with(CC, "sparse"),
        "contacts huge duplicate": lambda w: (w / CC).write_text((w / CC).read_text() + "1,B,back_left/hole_0\n" * 300_000),
        "contacts without fixtures": lambda w: (w / CDS).write_text(
            (w / CDS).read_text().split("fixtures:\n")[0]),
    }
    for name, f in fx_bad.items():
        C.append(Case(name, ["check", "cds"], f, guard=("cds",)))
    C += [
        Case("contacts check ok", ["check", "cds"], expect="ok", guard=("cds",)),
        Case("plane normal 1e300", ["check", "cds"],  # scaled before its norm: no overflow to a zero normal
             _yaml_add("  table: {type: plane, normal: [1e300, 0, 0], offset: 1, fixed: true}\n"), expect="ok",
             guard=("cds",)),
        Case("fixture in no contact", ["check", "cds"], _yaml_add("  spare: {type: point}\n"), expect="ok", guard=("cds",)),
        Case("fixture fixed sigma 0", ["check", "cds"], edit(CDS, "back_left/hole_0: {type: point}",
             "back_left/hole_0: {type: point, position: [0, 280, 20], sigma: 0, fixed: true}"), expect="ok", guard=("cds",)),
        Case("contacts missing file", ["check", "cds"], replace_with(CC, "missing"), expect="either",
             words=("contacts",), guard=("cds",)),
        Case("contacts header only", ["check", "cds"], write(CC, "pose,ball,fixture\n"), expect="either",
             words=("contact",), guard=("cds",)),
    ]
    # --- calibrate a contacts dataset
    cal = ["calibrate", "cds", "--out", "r.json"]
    C += [
        Case("contacts calibrate ok", cal, expect="ok", guard=("cds",)),
        Case("contacts calibrate spare fixture", cal, _yaml_add("  spare: {type: point}\n"), expect="ok", guard=("cds",)),
        Case("contacts calibrate spare in distance", cal, chain(
            _yaml_add("  spare: {type: point, position: [0, 300, 20], fixed: true}\n"),
            _distance("[back_left/hole_0, spare, 24, 0.1]")), expect="either", words=("spare",), guard=("cds",)),
        Case("contacts calibrate plane 2 contacts", cal, chain(_yaml_add("  table: {type: plane}\n"),
                                                                _contacts_to("table", 1, 2)), guard=("cds",)),
        Case("contacts calibrate plane one point", cal, chain(_yaml_add("  table: {type: plane}\n"),
                                                               _contacts_to("table", 1, 30)), guard=("cds",)),
        Case("contacts calibrate socket 1 contact", cal, _contacts_to("back_right/hole_0", 1, 29),
             expect="either", words=("back_left/hole_0",), guard=("cds",)),
        Case("contacts calibrate pose without contact", cal, lambda w: (w / "cds/joints.csv").write_text(
            (w / "cds/joints.csv").read_text() + "9999," + ",".join(["10"] * 7) + "\n"), expect="warn",
             words=("9999",), guard=("cds",)),
        Case("contacts calibrate header only", cal, write(CC, "pose,ball,fixture\n"), guard=("cds",)),
        Case("contacts calibrate contact_sigma -1", cal, edit(CDS, "contact_sigma: 0.05", "contact_sigma: -1"),
             guard=("cds",)),
        Case("contacts calibrate levels probes", cal + ["--levels", "probes"], guard=("cds",)),
        Case("contacts calibrate engine gtsam", cal + ["--engine", "gtsam"], expect="either", words=("contact",),
             guard=("cds",)),
        Case("contacts calibrate noise declared", cal + ["--noise", "declared"], expect="ok", guard=("cds",)),
        Case("contacts calibrate full disk", cal, fsize=4000, guard=("cds",)),
        Case("contacts calibrate out over contacts", ["calibrate", "cds", "--out", CC], guard=("cds",)),
    ]
    # --- the other commands on a contacts dataset
    C += [
        # the online engines and design take contacts since round 3 (these expected a refusal naming them)
        Case("contacts online isam2", ["online", "cds", "--out", "o.json", "--checkpoint", "c.json"], expect="ok",
             guard=("cds",)),
        Case("contacts online ekf", ["online", "cds", "--engine", "ekf", "--out", "o.json", "--checkpoint", "c.json"],
             expect="ok", guard=("cds",)),
        Case("contacts design dataset", ["design", "--dataset", "cds", "--out", "p.csv", "--poses", "25"],
             expect="ok", guard=("cds",)),
        Case("contacts simulate robot urdf", ["simulate", "s", "--robot", "cds/robot.urdf", "--chain",
                                              "panda_link0,ball_link", "--poses", "12"], expect="either",
             words=("tooling",), guard=("cds",)),
        Case("contacts simulate levels contacts", ["simulate", "s", "--robot", "cds/robot.urdf", "--chain",
                                                   "panda_link0,ball_link", "--levels", "contacts"],
             expect="either", words=("contact",), guard=("cds",)),
        Case("contacts measure", ["measure", "cds", "--out", "m"], guard=("cds",)),
        Case("contacts compensate", ["compensate", "cres.json", "targets.csv"], expect="partial",
             words=("not written",), guard=("cds",)),
    ]
    # --- a contacts result: verify, report, export, edited set-up
    R, V = "cres.json", "cver.json"
    C += [
        Case("cres verify holdout", ["verify", R, "cds-holdout", "--out", "v.json"], expect="ok", guard=("cds-holdout",)),
        Case("cres verify training", ["verify", R, "cds", "--out", "v.json"], expect="ok", guard=("cds",)),
        Case("cres verify other fixtures", ["verify", R, "cds-holdout"], chain(
            edit("cds-holdout/dataset.yaml", "high/hole_0: {type: point}", "other: {type: point}"),
            lambda w: (w / "cds-holdout/contacts.csv").write_text(
                (w / "cds-holdout/contacts.csv").read_text().replace("high/hole_0", "other")),
            edit("cds-holdout/dataset.yaml", "[high/hole_0,", "[other,")), expect="ok", guard=("cds-holdout",)),
        Case("cres verify fixed fixture", ["verify", R, "cds-holdout"], edit(
            "cds-holdout/dataset.yaml", "high/hole_0: {type: point}",
            "high/hole_0: {type: point, position: [300, 0, 300], fixed: true}"), expect="either",
             guard=("cds-holdout",)),
        Case("cres verify probes dataset", ["verify", R, "full"], guard=("full",)),
        Case("cres verify with plane", ["verify", R, "cds-holdout"], chain(
            _yaml_add("  table: {type: plane}\n", "cds-holdout/dataset.yaml"),
            lambda w: (w / "cds-holdout/contacts.csv").write_text(
                (w / "cds-holdout/contacts.csv").read_text().replace("high/hole_0", "table"))),
             expect="either", guard=("cds-holdout",)),
        Case("probes result verify contacts", ["verify", "result.json", "cds-holdout"], guard=("cds-holdout",)),
        Case("cres report", ["report", R, "--verify", V, "--out", "rep"], expect="ok"),
        Case("cres report no verify", ["report", R, "--out", "rep"], expect="ok"),
        Case("cres export", ["export", R, "--urdf", "c.urdf", "--model", "c.yaml"], expect="ok"),
        Case("cres export over robot", ["export", R, "--urdf", "cds/robot.urdf"], expect="ok", guard=()),  # not an input
    ]
    setup_bad = {
        "setup a list": lambda d: d.__setitem__("setup", [1, 2]),
        "setup a string": lambda d: d.__setitem__("setup", "abc"),
        "setup fixtures a list": lambda d: d["setup"].__setitem__("fixtures", [1]),
        "setup fixture type cone": lambda d: d["setup"]["fixtures"]["back_left/hole_0"].__setitem__("type", "cone"),
        "setup estimated nan": lambda d: d["setup"]["estimated"]["back_left/hole_0"].__setitem__(
            "position", [float("nan"), 0, 0]),
        "setup estimated 2 numbers": lambda d: d["setup"]["estimated"]["back_left/hole_0"].__setitem__("position", [1, 2]),
        "setup estimated text": lambda d: d["setup"]["estimated"]["back_left/hole_0"].__setitem__("position", "here"),
        "setup estimated unknown fixture": lambda d: d["setup"]["estimated"].__setitem__(
            "nowhere", {"type": "point", "position": [1, 2, 3]}),
        "setup estimated missing": lambda d: d["setup"].pop("estimated"),
        "setup distance garbage": lambda d: d["setup"]["constraints"].__setitem__("distances", [["a"]]),
        "setup unknown key": lambda d: d["setup"].__setitem__("surprise", 1),
        "setup gauge number": lambda d: d["setup"].__setitem__("gauge", 5),
        "setup fixture param orphan": lambda d: d["setup"]["fixtures"].pop("back_left/hole_0"),
    }
    for name, fn in setup_bad.items():
        for cmd in (["verify", R, "cds-holdout"], ["report", R, "--out", "rep"], ["export", R, "--urdf", "c.urdf"]):
            C.append(Case(f"{name} {cmd[0]}", cmd, _result_edit(fn), guard=("cds-holdout",)))
    C.append(Case("setup removed verify", ["verify", R, "cds-holdout"], _result_edit(lambda d: d.pop("setup")),
                  guard=("cds-holdout",)))
    return C
