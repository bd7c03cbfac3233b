"""The ``fgcal`` command line: a thin layer over the library.

A user's mistake (a bad file, an impossible option) ends in one line on standard error and
exit status 2, with no traceback.
"""
from __future__ import annotations

import logging
import sys

from fgcal.cli.commands.checks import os_error_message
from fgcal.cli.parser import build_parser
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")

MAX_ERROR_LINE = 600  # characters of an error line


def _one_line(message: str) -> str:
    """An error message as one line of at most :data:`MAX_ERROR_LINE` characters."""
    text = " ".join(message.split())
    return text if len(text) <= MAX_ERROR_LINE else f"{text[:MAX_ERROR_LINE]}... ({len(text)} characters)"


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s: %(message)s")
    try:
        return args.func(args)
    except FgcalError as exc:  # one line, bounded: no message carries a file's content in bulk
        print(f"fgcal: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except NotImplementedError as exc:  # a combination not supported yet (an engine without a measurement type)
        print(f"fgcal: error: not supported yet by this command or engine: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgcal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head and the like
        sys.stderr.close()
        return 0
    except OSError as exc:
        print(f"fgcal: error: {os_error_message(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        print("fgcal: error: out of memory: the input is too large for this command on this machine",
              file=sys.stderr)
        return 2

