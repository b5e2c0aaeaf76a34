"""The ``campaign`` command line.

Exit codes: 0 success, 1 a run finished but something failed (e.g. a sweep regression),
2 usage or configuration error (one clear line on stderr, nothing written).
"""
from __future__ import annotations

import argparse
import sys

from simulator.tomlfields import ConfigError

USAGE_ERROR = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, exit code 2
        self.exit(USAGE_ERROR, f"{self.prog}: error: {message}\n")


def _cmd_camera(args) -> int:
    from simulator.camera_config import load_camera

    camera = load_camera(args.file)
    horizontal, vertical = camera.fov_deg()
    print(f"{camera.name}: {camera.width_px}x{camera.height_px} px, binned {camera.binned_shape[0]}x"
          f"{camera.binned_shape[1]}, FOV {horizontal:.2f} x {vertical:.2f} deg, "
          f"focal {camera.model.hs:.1f} px, response {camera.responsivity_e_per_s:.4g} e-/s per W m^-2 sr^-1 um^-1, "
          f"dark {camera.electronics.dark_current_e_per_s():.4g} e-/s at {camera.electronics.ccd_temperature_k - 273.15:.1f} C")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="campaign", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    camera = commands.add_parser("camera", help="validate a camera TOML and print its derived numbers")
    camera.add_argument("file")
    camera.set_defaults(handler=_cmd_camera)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except ConfigError as exc:
        print(f"campaign: error: {exc}", file=sys.stderr)
        return USAGE_ERROR


if __name__ == "__main__":
    sys.exit(main())
