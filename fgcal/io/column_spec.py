"""What the columns of a measurement table hold, and in which units: a :class:`ColumnSpec` (read
by :func:`fgcal.io.table_io.read_measurements`), checked when it is made."""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from fgcal.errors import DatasetError

__all__ = ["AngleUnit", "ColumnSpec", "LengthUnit", "QuaternionOrder"]


class AngleUnit(Enum):
    DEG = "deg"
    RAD = "rad"


class LengthUnit(Enum):
    MM = "mm"
    M = "m"

    @property
    def to_mm(self) -> float:
        return 1000.0 if self is LengthUnit.M else 1.0


class QuaternionOrder(Enum):
    WXYZ = "wxyz"
    XYZW = "xyzw"


def _check_euler(convention: str) -> str:
    c = convention.strip()
    if (len(c) != 3 or not (c.isupper() or c.islower()) or set(c.lower()) - set("xyz")
            or c[0].lower() == c[1].lower() or c[1].lower() == c[2].lower()):
        raise DatasetError(f"--euler-convention {convention!r}: expected three axes such as XYZ (intrinsic, upper "
                           "case) or zyx (extrinsic, lower case), no axis twice in a row")
    return c


@dataclass(frozen=True)
class ColumnSpec:
    """Which columns of a table hold what, and in which units.

    Attributes
    ----------
    joints : tuple of str
        Joint reading columns in chain order.
    joint_unit : AngleUnit
    point : tuple of 3 str or None
        Columns of a measured point (a tracker reflector) x, y, z.
    pose : tuple of 6 or 7 str or None
        Columns of a measured pose: x, y, z then three Euler angles or a quaternion.
    quaternion_order : QuaternionOrder or None
        Order of the quaternion's four columns (7 pose columns); guessed from names ending in
        w, x, y, z when None.
    euler_convention : str or None
        Axes of the three angle columns (6 pose columns), as scipy names them: upper case intrinsic
        (``XYZ``), lower case extrinsic (``zyx``).
    rotation_unit : AngleUnit
        Unit of Euler angles.
    length_unit : LengthUnit
        Unit of positions (and of their standard deviations).
    group : tuple of str or None
        Optional columns whose equal values mark repeated measurements of one configuration.
    delimiter : str or None
        Field separator; detected when None (``" "`` means any whitespace).
    decimal_comma : bool or None
        Decimal separator is a comma; detected when None.
    label : str
        What the file is, for error messages (``"Landgraf series"``); empty for a generic table.
    """

    joints: tuple
    joint_unit: AngleUnit = AngleUnit.DEG
    point: tuple | None = None
    pose: tuple | None = None
    quaternion_order: QuaternionOrder | None = None
    euler_convention: str | None = None
    rotation_unit: AngleUnit = AngleUnit.DEG
    length_unit: LengthUnit = LengthUnit.MM
    position_std: tuple | None = None
    rotation_std: tuple | None = None
    group: tuple | None = None
    delimiter: str | None = None
    decimal_comma: bool | None = None
    label: str = ""

    def __post_init__(self):
        for name in ("joints", "point", "pose", "position_std", "rotation_std", "group"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, tuple(c.strip() for c in v))
        if (self.point is None) == (self.pose is None):
            raise DatasetError("give either point columns (--point X,Y,Z) or pose columns (--pose X,Y,Z,R1,R2,R3[,R4])")
        if not self.joints:
            raise DatasetError("--joints: give the joint columns in chain order")
        if self.point is not None and len(self.point) != 3:
            raise DatasetError(f"--point takes 3 columns (x, y, z), got {len(self.point)}")
        if self.pose is not None:
            if len(self.pose) not in (6, 7):
                raise DatasetError(f"--pose takes 6 columns (x, y, z and 3 Euler angles) or 7 (x, y, z and a "
                                   f"quaternion), got {len(self.pose)}")
            if len(self.pose) == 6:
                if self.euler_convention is None:
                    raise DatasetError("6 pose columns are Euler angles: give --euler-convention (e.g. XYZ intrinsic, "
                                       "zyx extrinsic)")
                object.__setattr__(self, "euler_convention", _check_euler(self.euler_convention))
            elif self.euler_convention is not None:
                raise DatasetError("7 pose columns are a quaternion: --euler-convention does not apply")
            elif self.quaternion_order is None:
                object.__setattr__(self, "quaternion_order", _guess_quaternion_order(self.pose[3:]))
        for name, enum in (("joint_unit", AngleUnit), ("rotation_unit", AngleUnit), ("length_unit", LengthUnit),
                           ("quaternion_order", QuaternionOrder)):
            v = getattr(self, name)
            if v is not None and not isinstance(v, enum):
                object.__setattr__(self, name, enum(v))

    def describe(self) -> dict:
        """The spec as plain values (for a dataset's provenance)."""
        out = {}
        for k, v in vars(self).items():
            if v is None or k == "label":
                continue
            out[k] = v.value if isinstance(v, Enum) else list(v) if isinstance(v, tuple) else v
        return out

    @property
    def required(self) -> tuple:
        return self.joints + (self.point or self.pose or ())


def _guess_quaternion_order(names) -> QuaternionOrder:
    last = "".join(n.strip().lower()[-1:] for n in names)
    for order in QuaternionOrder:
        if last == order.value:
            return order
    raise DatasetError(f"quaternion columns {', '.join(names)}: give --quaternion-order wxyz or xyzw")
