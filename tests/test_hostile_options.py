"""Every numeric option of every command is a checked type (finite, in range, its unit in the help).

The mechanism (``fgcal.cli.commands.options``) is tested once here over the whole parser, so an option
added later with a bare ``type=float`` or ``type=int`` fails this test.
"""
import argparse
from pathlib import Path

import pytest
from hostile_util import call, one_line_error

from fgcal.cli import build_parser
from fgcal.cli.commands.options import Checked, payload_spec, scheduler_address

ALLOWED_TYPES = (Path, str, None)
FREE_TYPES = (payload_spec, scheduler_address)  # checked text options


def _all_actions(parser, prefix=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _all_actions(sub, prefix + (name,))
        else:
            yield prefix, action


def test_every_typed_option_is_checked():
    """No bare int/float: every option with a type converting to a number is a Checked one."""
    actions = list(_all_actions(build_parser()))
    checked = 0
    for where, a in actions:
        if a.type in ALLOWED_TYPES or a.type in FREE_TYPES:
            continue
        assert isinstance(a.type, Checked), (where, a.option_strings, a.type)
        checked += 1
        if a.type.unit and a.help:
            unit = a.type.unit.split(",")[0]
            assert unit in a.help, (where, a.option_strings, a.type.unit, a.help)
    assert checked >= 45  # simulate, measure, calibrate, ..., import: the numeric options counted today


@pytest.mark.parametrize("kind", [Checked("float", 0, 10), Checked("int", 1, 10)])
@pytest.mark.parametrize("word", ["nan", "inf", "-inf", "NaN", "1e309", "x", "", "1,5", "11", "-1"])
def test_checked_refuses(kind, word):
    with pytest.raises(argparse.ArgumentTypeError):
        kind(word)


def test_checked_bounds_and_values():
    assert Checked("float", 0, 1, low_open=True)("1") == 1.0
    with pytest.raises(argparse.ArgumentTypeError, match="> 0"):
        Checked("float", 0, 1, low_open=True)("0")
    assert Checked("int", 0, 5)("5") == 5
    with pytest.raises(argparse.ArgumentTypeError, match="not an integer"):
        Checked("int", 0, 5)("2.0")
    with pytest.raises(argparse.ArgumentTypeError, match=r"\.\.\."):  # long words quoted shortened
        Checked("int", 0, 5)("9" * 500)


@pytest.mark.parametrize("args,words", [
    (["online", "DS", "--drift", "nan", "nan"], ["--drift", "finite"]),
    (["study", "fig13", "--scheduler", "not a url"], ["--scheduler", "scheduler address"]),
    (["calibrate", "DS", "--out", "x.json", "--max-harmonics", "0"], ["--max-harmonics", ">= 1"]),
    (["calibrate", "DS", "--out", "x.json", "--max-harmonics", "-3"], ["--max-harmonics"]),
    (["calibrate", "DS", "--out", "x.json", "--payload", "1e300"], ["--payload", "kg"]),
    (["calibrate", "DS", "--out", "x.json", "--payload", "nan"], ["--payload"]),
    (["calibrate", "DS", "--out", "x.json", "--payload", "1,2,inf,3"], ["--payload"]),
    (["calibrate", "DS", "--out", "x.json", "--payload", "1,2"], ["--payload"]),
    (["calibrate", "DS", "--out", "x.json", "--seed", "-1"], ["--seed", ">= 0"]),
    (["calibrate", "DS", "--out", "x.json", "--folds", "1"], ["--folds", ">= 2"]),
    (["report", "r.json", "--out", "r", "--tolerance", "inf"], ["--tolerance"]),
    (["report", "r.json", "--out", "r", "--tolerance", "0"], ["--tolerance", "> 0"]),
    (["compensate", "r.json", "t.csv", "--max-change", "nan"], ["--max-change"]),
    (["compensate", "r.json", "t.csv", "--max-change", "-1"], ["--max-change"]),
    (["simulate", "o", "--outliers", "2"], ["--outliers", "<= 1"]),
    (["simulate", "o", "--seed", str(2**64)], ["--seed"]),
    (["online", "DS", "--interval", "1e300"], ["--interval", "s"]),
    (["import", "csv", "f.csv", "o", "--robot", "ur10", "--joints", "a", "--joint-unit", "deg", "--point", "a,b,c",
      "--holdout", "1"], ["--holdout", "< 1"]),
    (["import", "mukca", "d", "o", "--robot", "r.urdf", "--distance", "-50"], ["--distance", "mm"]),
])
def test_cli_refuses_before_work(args, words, capsys):
    """Each ends in argparse's one line, status 2, before any file is read."""
    code, _, err = call(args, capsys)
    one_line_error(code, err, *words)
