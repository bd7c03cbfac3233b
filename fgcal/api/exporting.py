"""``fgcal.export``: a calibrated model as a robot model file, a URDF and a table of deltas (``fgcal export``)."""
from __future__ import annotations

import re
from pathlib import Path

from fgcal.api.notes import note
from fgcal.api.selection import as_result
from fgcal.errors import FgcalError

__all__ = ["calibrated_model", "export", "export_camera_info", "export_deltas", "export_model", "export_ur_kinematics",
           "export_urdf"]


def _refuse_existing(path, force: bool) -> None:
    from fgcal.util.yamlio import must_be_new

    if path is not None and Path(path).exists() and not force:
        raise FgcalError(f"{path}: already exists (use --force to replace it)")
    if path is not None and not force:
        must_be_new(path)


def calibrated_model(result):
    """The nominal model of ``result`` renamed ``NAME-calibrated``, and its calibrated slots (mm, rad).

    Returns
    -------
    model : RobotModel
    slots : ndarray, shape (S,)
    """
    from dataclasses import replace

    result = as_result(result)
    model = result.model()
    calibrated = replace(model, name=f"{model.name}-calibrated",
                         description=f"{model.name} calibrated by fgcal from {result.n_poses} poses")
    return calibrated, result.slot_vector(model)


def export_urdf(result, path=None, *, force: bool = False) -> str:
    """The calibrated robot as URDF text (a calibrated copy of an imported URDF); written to ``path`` if given.

    For a contact calibration the link ``tool`` is at the centre of the ball that made the contacts.
    """
    from dataclasses import replace

    from fgcal.robots.urdf import export_urdf as to_text
    from fgcal.util.yamlio import atomic_write_text

    _refuse_existing(path, force)
    result = as_result(result)
    model, slots = calibrated_model(result)
    names = _dataset_joint_names(result, model)
    if names:  # the joint names the data were imported with, for a model without its own
        model = replace(model, joint_names=names)
    # a contact calibration: the link tool at the contact ball's centre (DESIGN.md 8.2)
    point = result.tool_point()
    text = to_text(model, slots, tool_point=point)
    cameras = _cameras(result)
    if cameras:  # each camera's mount as a link camera_NAME_optical (DESIGN.md 8.4)
        import numpy as np

        from fgcal.robots.camera_links import add_camera_links

        shift = np.eye(4)  # a camera on the tool, seen from a tool link moved to the ball's centre
        if point is not None:
            shift[:3, 3] = -np.asarray(point, dtype=float)
        text = add_camera_links(text, [(n, c["mount"], c["T"] if c["mount"] == "world" else shift @ c["T"])
                                       for n, c in cameras.items()])
    if path is not None:
        atomic_write_text(path, text)
    return text


def export_camera_info(result, urdf_path, *, force: bool = False) -> list[Path]:
    """Each camera's intrinsics as a ROS camera_info YAML beside the URDF: ``URDF.camera_NAME.yaml``."""
    from fgcal.robots.camera_links import camera_info_yaml
    from fgcal.util.yamlio import atomic_write_text

    written = []
    for n, c in _cameras(as_result(result)).items():
        info = Path(f"{urdf_path}.camera_{n}.yaml")
        _refuse_existing(info, force)
        atomic_write_text(info, camera_info_yaml(n, c["width"], c["height"], c["k"]))
        written.append(info)
    return written


def export_ur_kinematics(result, path, *, hash: str | None = None, result_name: str = "a result",
                         force: bool = False) -> tuple[Path, str]:
    """Write ur_description's ``kinematics:`` file of a calibrated Universal Robots arm (DESIGN.md 8.5).

    Parameters
    ----------
    hash : str, optional
        The file's ``hash`` (letters, digits, ``_-.``); default ``fgcal_`` and a digest of the values,
        which the driver reports as not the controller's own calibration (it is not).

    Returns
    -------
    path : Path
    hash : str
        The hash written.

    Warns
    -----
    FgcalNote
        The calibrated tool frame where no joint origin can hold it (the TCP to set on the
        controller), and a factory file's hash.
    """
    import numpy as np

    from fgcal.robots.transforms import so3_log
    from fgcal.robots.ur_kinematics import is_ur, kinematics_text, ur_kinematics
    from fgcal.util.yamlio import atomic_write_text

    if hash is not None and not re.fullmatch(r"[A-Za-z0-9_.-]{1,80}", hash):
        raise FgcalError(f"--ur-hash {hash[:40]!r}: letters, digits, '_', '-' and '.' only (e.g. calib_123)")
    _refuse_existing(path, force)
    result = as_result(result)
    model, slots = calibrated_model(result)
    if not is_ur(model):
        raise FgcalError(f"--ur-kinematics: {result_name}: robot {model.name} is not a Universal Robots arm (the "
                         "built-in ur10/ur5, a table with the UR's structure, or a URDF with ur_description's "
                         "joint names)")
    factory = model.extra.get("ur_kinematics", {}).get("hash")
    kin = ur_kinematics(model, slots, hash=hash)
    tcp = kin.tcp
    rv = so3_log(tcp[:3, :3])
    tcp_text = ", ".join(f"{v:.6f}" for v in (*(tcp[:3, 3] / 1000.0), *rv))
    why = ("as given" if hash else
           "fgcal_ and a digest of these values, not the controller's calibration checksum: the driver warns")
    comment = (f"UR kinematics calibrated by fgcal ({result_name}), for ur_description's kinematics_params_file:\n"
               "joint origins in metres and URDF rpy (R = Rz(yaw) Ry(pitch) Rx(roll)); base_link is the mounting "
               "face,\nbase_link_inertia = Rz(pi) the controller's Base frame; the chain ends at tool0 (the flange).\n"
               f"hash: {why}.\n"
               f"calibrated tool frame in tool0 (the TCP to set: x, y, z m, rx, ry, rz rotation vector rad): "
               f"[{tcp_text}]")
    atomic_write_text(path, kinematics_text(kin, comment))
    if factory and not hash:
        note(f"the factory file's hash was {factory}; --ur-hash {factory} silences the driver's check, but "
             "the controller still computes its own poses with its factory calibration")
    off = np.linalg.norm(tcp[:3, 3])
    if off > 1e-9 or np.linalg.norm(rv) > 1e-12:
        note(f"the calibrated tool frame is {off:.3g} mm and {np.degrees(np.linalg.norm(rv)):.3g} deg from "
             f"tool0, which no joint origin can hold: set it as the controller's TCP [{tcp_text}] "
             "(x, y, z m, rotation vector rad; in the file as fgcal.tool_in_tool0)")
    return Path(path), kin.hash


def export_model(result, path, *, force: bool = False) -> Path:
    """Write the calibrated robot as an ``fgcal-robot/1`` model file."""
    from fgcal.robots.robot_file import save_model

    _refuse_existing(path, force)
    model, slots = calibrated_model(result)
    save_model(model, path, slots=slots)
    return Path(path)


def _delta(unit: str, estimate: float, nominal: float) -> float:
    """``estimate - nominal``; an angle's wrapped to (-180, 180] deg (179.9 and -179.9 differ by 0.2)."""
    d = float(estimate) - float(nominal)
    if unit == "deg":
        d = 180.0 - (180.0 - d) % 360.0
    return d


def export_deltas(result, path, *, force: bool = False) -> Path:
    """Write the CSV ``name,unit,nominal,estimate,delta,sigma,status`` of the identified and the held parameters."""
    from fgcal.io.dataset_io import write_csv

    _refuse_existing(path, force)
    result = as_result(result)
    model = result.model()
    rows: list[list] = [[p.name, p.unit, p.nominal, p.estimate, _delta(p.unit, p.estimate, p.nominal), p.sigma,
                         "identified"] for p in result.parameters]
    nominal = model.slots_to_file_units(model.nominal)
    for h in result.held:
        k = model.slot(h["name"])
        unit = "deg" if model.slot_is_angle[k] else "mm"
        value = float(h["value"])
        rows.append([h["name"], unit, float(nominal[k]), value, _delta(unit, value, float(nominal[k])), "",
                     "held: " + h["reason"]])  # write_csv quotes a reason with a comma
    write_csv(path, ["name", "unit", "nominal", "estimate", "delta", "sigma", "status"], rows)
    return Path(path)


def export(result, *, model=None, urdf=None, deltas=None, ur_kinematics=None, ur_hash: str | None = None,
           force: bool = False) -> list[tuple[Path, str]]:
    """What ``fgcal export`` writes: any of a model file, a URDF, the deltas and a UR kinematics file
    (:func:`export_ur_kinematics`), and the joint-error table.

    A result with a joint-error block (compliance, map) also gets ``FILE.joint_errors.csv`` beside
    the first file, since neither format can hold it.

    Returns
    -------
    list of (Path, str)
        Each file written and what it is.

    Warns
    -----
    FgcalNote
        The region a joint error map is valid in.
    """
    from fgcal.io.dataset_io import write_csv

    if model is None and urdf is None and deltas is None and ur_kinematics is None:
        raise FgcalError("export: give --model FILE, --urdf FILE, --deltas FILE and/or --ur-kinematics FILE")
    if ur_hash is not None and ur_kinematics is None:  # it names a file that is not written: said, not dropped
        raise FgcalError("export: --ur-hash is the hash of the --ur-kinematics file; give --ur-kinematics FILE")
    outputs = [Path(p).absolute() for p in (model, urdf, deltas, ur_kinematics) if p is not None]
    if len(set(outputs)) < len(outputs):
        raise FgcalError("export: --model, --urdf, --deltas and --ur-kinematics must be different files")
    for path in (model, urdf, deltas, ur_kinematics):
        _refuse_existing(path, force)
    result_name = str(result) if isinstance(result, (str, Path)) else "the result"
    result = as_result(result)
    written = []
    if ur_kinematics is not None:  # first: it refuses a robot that is not a UR before anything is written
        path, digest = export_ur_kinematics(result, ur_kinematics, hash=ur_hash, result_name=result_name, force=True)
        written.append((path, f"UR kinematics, hash {digest}"))
    if model is not None:
        written.append((export_model(result, model, force=True), "fgcal-robot/1"))
    if urdf is not None:
        export_urdf(result, urdf, force=True)
        kind = "a calibrated copy of the imported URDF" if "urdf" in result.model().extra else "URDF"
        point = result.tool_point()
        if point is not None:
            kind += (f"; link tool at the centre of ball {result.tooling['tool_ball']} "
                     f"({', '.join(f'{v:g}' for v in point)} mm in the tool frame)")
        written.append((Path(urdf), kind))
        for info in export_camera_info(result, urdf, force=force):
            name = info.name.rsplit(".camera_", 1)[1][:-len(".yaml")]
            written.append((info, f"camera {name}'s intrinsics, ROS camera_info; its frame: link camera_{name}_optical"))
    if deltas is not None:
        export_deltas(result, deltas, force=True)
        written.append((Path(deltas), f"{len(result.parameters)} identified, {len(result.held)} held"))
    names = result.joint_errors.get("names")
    if names:  # what neither format can hold goes beside them as a table
        table = Path(str(urdf or model or deltas or ur_kinematics) + ".joint_errors.csv")
        write_csv(table, ["name", "unit", "estimate", "sigma"],
                  [[p.name, p.unit, p.estimate, p.sigma] for p in result.parameters if p.name in set(names)])
        written.append((table, f"the {len(names)} joint-error parameters, which a "
                               f"{'URDF' if urdf else 'model file'} cannot hold (joint = reading + correction, "
                               "see fgcal.estimation.joint_errors)"))
        if result.joint_errors.get("validity"):
            note(result.joint_errors["validity"])
    return written


def _cameras(result) -> dict:
    """The cameras a result found: name -> ``mount``, ``T`` (4, 4, mm), ``width``, ``height``, ``k`` (9,)."""
    import numpy as np

    from fgcal.measurements.camera import INTRINSICS, pose_matrix

    setup = result.setup or {}
    out = {}
    for n, f in setup.get("fixtures", {}).items():
        if f.get("type") != "camera":
            continue
        e = setup["estimated"][n]
        pose = np.concatenate([np.asarray(e["pose"][:3], float), np.radians(e["pose"][3:6])])
        out[n] = {"mount": f["mount"], "T": pose_matrix(pose), "width": f["width"], "height": f["height"],
                  "k": [e["intrinsics"][c] for c in INTRINSICS]}
    return out


def _dataset_joint_names(result, model) -> tuple[str, ...] | None:
    """The joint columns the result's dataset was imported with (``import csv --joints``, ``import tum``),
    for a model whose joints have only the default names ``q1..qn``; None when unknown."""
    if "urdf" in model.extra or model.joint_names != tuple(f"q{k}" for k in range(1, model.n_joints + 1)):
        return None
    if not isinstance(result.dataset, str):
        return None
    from fgcal.util.yamlio import read_yaml

    try:
        provenance = read_yaml(Path(result.dataset) / "dataset.yaml").get("provenance") or {}
    except (FgcalError, OSError, AttributeError):
        return None
    columns = provenance.get("columns") if isinstance(provenance.get("columns"), dict) else provenance
    names = columns.get("joints") if isinstance(columns, dict) else None
    if (not isinstance(names, list) or len(names) != model.n_joints or len(set(map(str, names))) != len(names)
            or not all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}", str(n)) for n in names)
            or {"base", "tool"} & set(map(str, names))):
        return None
    return tuple(str(n) for n in names)
