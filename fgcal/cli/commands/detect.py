"""``fgcal detect``: :func:`fgcal.api.detecting.detect`, printed (options: ``build_parser``)."""
from __future__ import annotations

from fgcal.api.detecting import detect
from fgcal.cli.commands.checks import check_output_file
from fgcal.cli.commands.common import call


def _cmd_detect(args) -> int:
    check_output_file(args.out, args.images)  # before the images are read
    print("\n".join(call(detect, args.images, args.grid, args.square, args.out, camera=args.camera).lines))
    return 0
