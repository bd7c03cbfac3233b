"""``fgcal check``: :func:`fgcal.api.checking.check`, printed (options: ``build_parser``)."""
from __future__ import annotations

import logging

from fgcal.api.checking import check
from fgcal.cli.commands.common import call

log = logging.getLogger("fgcal")


def _cmd_check(args) -> int:
    print("\n".join(call(check, args.dataset).lines))
    return 0


def _warn_units(ds, model) -> None:
    """Print the unit warnings of ``ds`` on standard error (for the commands not yet on the library layer)."""
    import sys

    from fgcal.estimation.sanity import unit_warnings

    for w in unit_warnings(ds, model):
        print(f"warning: {w}", file=sys.stderr)
