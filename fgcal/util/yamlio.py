"""Safe YAML reading, guarded file opening and atomic file writing shared by every file format.

Reading is defensive: only regular files of a sane size are opened (never a device, FIFO or
folder), YAML aliases are refused (a few hundred bytes of nested aliases expand to gigabytes),
duplicate keys are refused, nesting depth is bounded, and an error message never quotes the
file's content. Writing is atomic (a temporary file in the same folder is renamed), leaves no
temporary file behind on any error or interruption, and gives files and folders the
permissions the umask allows.
"""
from __future__ import annotations

import contextlib
import os
import re
import stat
import tempfile
from pathlib import Path

import yaml

from fgcal.errors import FgcalError

__all__ = [
    "MAX_LINE_BYTES",
    "MAX_YAML_BYTES",
    "MAX_YAML_DEPTH",
    "atomic_write_bytes",
    "atomic_write_chunks",
    "atomic_write_text",
    "check_regular_file",
    "dump_yaml",
    "make_dir",
    "may_replace",
    "must_be_new",
    "read_text_file",
    "read_yaml",
    "short_repr",
    "text_lines",
]

MAX_YAML_BYTES = 16 * 1024 * 1024  # model files and dataset.yaml are a few kB
MAX_YAML_DEPTH = 64


def short_repr(value, limit: int = 24) -> str:
    """``value`` for an error message: a short scalar as it is, otherwise only its type and size.

    A long text is not quoted, so that a message never carries a file's content.
    """
    if isinstance(value, dict):
        return f"a mapping of {len(value)} key(s)"
    if isinstance(value, (list, tuple)):
        return f"a list of {len(value)} item(s)"
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"a text of {len(value)} characters" if isinstance(value, str) else f"a {type(value).__name__}"


def check_regular_file(path, error=FgcalError, max_bytes: int | None = None) -> int:
    """Raise ``error`` unless ``path`` is an existing regular file (of at most ``max_bytes``); its size."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a folder, expected a file")
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: not a regular file (a device, FIFO or socket); refusing to read it")
    if max_bytes is not None and st.st_size > max_bytes:
        raise error(f"{path}: {st.st_size} bytes, more than the {max_bytes} bytes such a file can be")
    return st.st_size


def _open_regular(path: Path, error, max_bytes: int | None):
    """A binary file object of the regular file ``path`` (a FIFO or device is refused without blocking)."""
    check_regular_file(path, error, max_bytes)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    fh = os.fdopen(fd, "rb")
    if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # replaced since the check
        fh.close()
        raise error(f"{path}: not a regular file; refusing to read it")
    return fh


def read_text_file(path, error=FgcalError, max_bytes: int | None = None) -> str:
    """The UTF-8 text of a regular file; every problem raises ``error`` naming the file (not its content)."""
    path = Path(path)
    with _open_regular(path, error, max_bytes) as fh:
        try:
            data = fh.read() if max_bytes is None else fh.read(max_bytes + 1)
        except OSError as exc:
            raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    if max_bytes is not None and len(data) > max_bytes:
        raise error(f"{path}: more than the {max_bytes} bytes such a file can be")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise error(f"{path}: line {line}: not UTF-8 text") from None


MAX_LINE_BYTES = 1 << 20  # a line of a table or trajectory: a few kB; beyond this it is not one


def text_lines(path, error=FgcalError, max_bytes: int | None = None, max_line: int = MAX_LINE_BYTES):
    """The lines of a regular UTF-8 file (line ends and a byte-order mark removed), read as they are
    used: memory of one line, not of the file. Problems raise ``error`` naming the file and line (not
    its content), as :func:`read_text_file`'s do; the checks before the first line are made at the call.
    A line longer than ``max_line`` bytes is an error (it is not read whole).
    """
    path = Path(path)
    return _lines_of(_open_regular(path, error, max_bytes), path, error, max_bytes, max_line)


def _lines_of(fh, path, error, max_bytes, max_line):
    with fh:
        read = 0
        n = 0
        while True:
            try:
                raw = fh.readline(max_line + 1)
            except OSError as exc:
                raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
            if not raw:
                return
            n += 1
            if len(raw) > max_line:
                raise error(f"{path}: line {n}: longer than {max_line} bytes; not a line of text such a file has")
            read += len(raw)
            if max_bytes is not None and read > max_bytes:  # grown since the check
                raise error(f"{path}: more than the {max_bytes} bytes such a file can be")
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError:
                raise error(f"{path}: line {n}: not UTF-8 text") from None
            if n == 1:
                text = text.removeprefix("\ufeff")
            yield from text.splitlines()  # as str.splitlines of the whole text: old Mac line ends too


# YAML 1.1 wants a dot in a float ("1.0e-2"); people write 1e-2 and 5e2. Accept them as numbers.
_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", re.X)


class _SafeLoader(yaml.SafeLoader):
    """The safe loader without aliases, without duplicate keys, with a bounded depth."""

    yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.MarkedYAMLError(None, None, f"YAML aliases (*{event.anchor}) are not accepted",
                                       event.start_mark)
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.MarkedYAMLError(None, None, f"nested more than {MAX_YAML_DEPTH} levels deep",
                                           self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = {}
            for key_node, _ in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    key = key_node.value
                    if key in seen:
                        raise yaml.MarkedYAMLError(
                            None, None, f"duplicate key {short_repr(key)} (first on line {seen[key] + 1})",
                            key_node.start_mark)
                    seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)


for _first in list("-+0123456789."):
    _SafeLoader.yaml_implicit_resolvers[_first] = [
        (tag, regexp) for tag, regexp in _SafeLoader.yaml_implicit_resolvers.get(_first, [])
        if tag != "tag:yaml.org,2002:float"]
    _SafeLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, [_first])
_SafeLoader.add_constructor("tag:yaml.org,2002:map", _SafeLoader.construct_yaml_map)


def read_yaml(path, error=FgcalError):
    """Read a YAML file safely; any problem raises ``error`` naming the file and line, never its content."""
    path = Path(path)
    text = read_text_file(path, error, MAX_YAML_BYTES)
    try:
        return yaml.load(text, Loader=_SafeLoader)
    except yaml.constructor.ConstructorError as exc:
        where = f"line {exc.problem_mark.line + 1}: " if exc.problem_mark else ""
        raise error(f"{path}: {where}refusing a YAML tag that builds objects") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}: " if mark else ""
        raise error(f"{path}: {where}invalid YAML: {exc.problem or exc.context}") from None
    except yaml.YAMLError:
        raise error(f"{path}: invalid YAML") from None
    except RecursionError:
        raise error(f"{path}: invalid YAML: nested too deep") from None


class _Dumper(yaml.SafeDumper):
    """Safe YAML whose floats are spelled by :func:`fgcal.util.numbers.clean_number` (no ``-0.0``, no float noise)."""


def _float(dumper, value):
    from fgcal.util.numbers import clean_number

    return yaml.SafeDumper.represent_float(dumper, clean_number(value))


_Dumper.add_representer(float, _float)


def dump_yaml(data) -> str:
    """YAML text of ``data`` (safe types only), keys in their order, numbers as every written file spells them."""
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False, default_flow_style=None, width=100)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def make_dir(path) -> Path:
    """A new temporary-named folder beside ``path`` with the permissions the umask gives."""
    path = Path(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_umask())
    return tmp


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` so that the file is either the old one or complete, never half."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (a temporary file in the same folder is renamed).

    The file gets the permissions the umask gives (as ``open`` would); on any error or
    interruption the temporary file is removed and ``path`` is left as it was.
    """
    atomic_write_chunks(path, (data,))


_NEW_FILES: set[str] = set()  # outputs checked absent (no --force): written only if still absent


def must_be_new(path) -> None:
    """Mark the output ``path`` (checked absent, no ``--force``) so that its atomic write creates it
    and never replaces a file another run wrote meanwhile (two runs on one output, started together:
    the later one fails naming it, instead of both saying they wrote)."""
    _NEW_FILES.add(os.path.abspath(path))


def may_replace(path) -> None:
    """Undo :func:`must_be_new` (``--force``)."""
    _NEW_FILES.discard(os.path.abspath(path))


def _publish(tmp, path: Path) -> None:
    key = os.path.abspath(path)
    if key not in _NEW_FILES:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)  # fails if path exists: create-if-absent, atomically
    except FileExistsError:
        raise FgcalError(f"{path}: already exists (written meanwhile by another run; use --force to replace "
                         "it)") from None
    except OSError:  # a file system without hard links: the check, then the rename
        if os.path.lexists(path):
            raise FgcalError(f"{path}: already exists (written meanwhile by another run; use --force to "
                             "replace it)") from None
        os.replace(tmp, path)
    else:
        os.unlink(tmp)
    _NEW_FILES.discard(key)


def atomic_write_chunks(path, chunks) -> None:
    """Write the byte strings of the iterable ``chunks`` to ``path`` atomically, as :func:`atomic_write_bytes`
    does, holding one chunk at a time (a large table is written in bounded memory)."""
    path = Path(path)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), 0o666 & ~_umask())
            for data in chunks:
                fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        _publish(tmp, path)
        tmp = None
    except OSError as exc:
        if exc.filename is None:  # a failed write names no file: name the one being written
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        raise
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
