"""Checked option types: every numeric command-line option is one of these.

Each factory returns an argparse ``type=`` callable (a :class:`Checked`) that parses one word,
refuses NaN, infinities and values outside the option's range with one line naming the value and
the range, and carries the option's unit so that a test can hold the help texts to it.

>>> positive_mm("0.5")
0.5
"""
from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass

__all__ = [
    "ANGLE_DEG_MAX",
    "COUNT_MAX",
    "LENGTH_MM_MAX",
    "MASS_KG_MAX",
    "SEED_MAX",
    "Checked",
    "RenamedOption",
    "count",
    "finite",
    "fraction",
    "nonnegative",
    "nonnegative_deg",
    "nonnegative_mm",
    "number",
    "positive",
    "positive_deg",
    "positive_mm",
    "probability",
    "scheduler_address",
    "seed",
]

LENGTH_MM_MAX = 1e6  # 1 km: no arm, tracker or fixture is larger
ANGLE_DEG_MAX = 360.0
MASS_KG_MAX = 1e5  # a payload heavier than 100 t is a unit mistake
SEED_MAX = 2**63 - 1
COUNT_MAX = 10**9
_SHOW = 40  # characters of a refused word that an error quotes


def _quote(text: str) -> str:
    return repr(text[:_SHOW] + ("..." if len(text) > _SHOW else ""))


@dataclass(frozen=True)
class Checked:
    """An argparse type: a number of ``kind`` ("float" or "int") in a range, in ``unit``.

    ``low``/``high`` bound the value (None: no bound); ``low_open``/``high_open`` make a bound strict.
    """

    kind: str = "float"
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    unit: str = ""

    @property
    def __name__(self) -> str:  # argparse names the type in some of its messages
        return "integer" if self.kind == "int" else "number"

    def range_text(self) -> str:
        def fmt(v: float) -> str:
            return str(int(v)) if self.kind == "int" else f"{v:g}"

        lo = "" if self.low is None else (f"> {fmt(self.low)}" if self.low_open else f">= {fmt(self.low)}")
        hi = "" if self.high is None else (f"< {fmt(self.high)}" if self.high_open else f"<= {fmt(self.high)}")
        both = " and ".join(t for t in (lo, hi) if t)
        return (both + (f" {self.unit}" if self.unit else "")) if both else "finite"

    def __call__(self, text: str) -> float | int:
        text = str(text).strip()
        value: float | int
        if self.kind == "int":
            if not re.fullmatch(r"[+-]?\d{1,30}", text):
                raise argparse.ArgumentTypeError(f"not an integer: {_quote(text)}")
            value = int(text)
        else:
            try:
                value = float(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"not a number: {_quote(text)}") from None
            if not math.isfinite(value):
                raise argparse.ArgumentTypeError(f"not a finite number: {_quote(text)}")
        bad = ((self.low is not None and (value < self.low or (self.low_open and value == self.low)))
               or (self.high is not None and (value > self.high or (self.high_open and value == self.high))))
        if bad:
            raise argparse.ArgumentTypeError(f"{_quote(text)} out of range: must be {self.range_text()}")
        return value


def number(low=None, high=None, *, low_open=False, high_open=False, unit="") -> Checked:
    """A finite float in ``[low, high]`` (open ends with ``low_open``/``high_open``)."""
    return Checked("float", low, high, low_open, high_open, unit)


def finite(unit: str = "", bound: float = LENGTH_MM_MAX) -> Checked:
    """A finite float of magnitude at most ``bound``."""
    return number(-bound, bound, unit=unit)


def positive(unit: str = "", high: float = LENGTH_MM_MAX) -> Checked:
    """A finite float > 0 and <= ``high``."""
    return number(0.0, high, low_open=True, unit=unit)


def nonnegative(unit: str = "", high: float = LENGTH_MM_MAX) -> Checked:
    """A finite float >= 0 and <= ``high``."""
    return number(0.0, high, unit=unit)


def probability() -> Checked:
    """A fraction in [0, 1]."""
    return number(0.0, 1.0)


def fraction() -> Checked:
    """A fraction in [0, 1) (a share of rows held out: 1 would leave nothing to fit)."""
    return number(0.0, 1.0, high_open=True)


def count(min: int = 1, max: int = COUNT_MAX) -> Checked:
    """An integer in ``[min, max]``."""
    return Checked("int", min, max)


seed = Checked("int", 0, SEED_MAX)
positive_mm = positive("mm")
nonnegative_mm = nonnegative("mm")
positive_deg = positive("deg", ANGLE_DEG_MAX)
nonnegative_deg = nonnegative("deg", ANGLE_DEG_MAX)

_ADDRESS = re.compile(r"(?:(tcp|tls|inproc|ucx|ws|wss)://)?([A-Za-z0-9_.\-]+|\[[0-9A-Fa-f:.]+\])(?::(\d{1,5}))?")


def scheduler_address(text: str) -> str:
    """An argparse type: a Dask scheduler address ``[PROTOCOL://]HOST[:PORT]``."""
    m = _ADDRESS.fullmatch(text.strip())
    if m and m.group(3) is None and m.group(1) != "inproc":  # Dask's client needs the port of a host
        raise argparse.ArgumentTypeError(f"not a scheduler address: {_quote(text)} has no port (expected "
                                         "tcp://HOST:PORT)")
    if not m or (m.group(3) is not None and not 0 < int(m.group(3)) < 65536):
        raise argparse.ArgumentTypeError(f"not a scheduler address: {_quote(text)} (expected tcp://HOST:PORT)")
    return text.strip()


def payload_spec(text: str) -> str:
    """An argparse type: ``KG`` or ``KG,X,Y,Z`` (kg, mm in the tool frame), each finite and in range.

    Returns the text as given (the command parses it into a payload).
    """
    parts = str(text).split(",")
    if len(parts) not in (1, 4):
        raise argparse.ArgumentTypeError(f"expected KG or KG,X,Y,Z (kg, mm in the tool frame), got {_quote(text)}")
    try:
        nonnegative("kg", MASS_KG_MAX)(parts[0])
        for p in parts[1:]:
            finite("mm")(p)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"KG or KG,X,Y,Z (kg, mm): {exc}") from None
    return str(text)


class RenamedOption(argparse.Action):
    """The old spelling of an option renamed so that one name means one thing across the commands
    (``calibrate --poses`` selected poses where ``simulate --poses`` counts them): still read, with a
    warning on standard error that names the new spelling. Its help is hidden."""

    def __init__(self, option_strings, dest, new: str, **kwargs):
        kwargs.setdefault("help", argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kwargs)
        self.new = new

    def __call__(self, parser, namespace, values, option_string=None):
        import sys

        print(f"warning: {option_string} is now {self.new} ({parser.prog}); the old name will go", file=sys.stderr)
        setattr(namespace, self.dest, values)
