"""``scanqa simulate`` (parsing only)."""

from __future__ import annotations

import argparse

from scanqa.cli.common import add_config_argument, config_from_args, emit, float_list, number
from scanqa.numeric import parse_range

_FMT = argparse.RawDescriptionHelpFormatter


def _positions(text: str) -> list[float]:
    """argparse type: 'START:STOP:STEP' (inclusive) or a comma-separated list [mm]."""
    if ":" not in text:
        return float_list(text)
    try:
        return parse_range(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{err} (or give a comma-separated list)") from None


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` command."""
    from scanqa.simulator.experiments import EXPERIMENTS

    p = sub.add_parser(
        "simulate", formatter_class=_FMT,
        help="virtual scanner: write the images and ground truth of an experiment",
        description="Simulate an experiment with the virtual phase-shift scanner: images "
                    "+ patterns.toml per scan, ground truth per position, manifest.toml.",
        epilog="examples:\n"
               "  scanqa simulate camera-sweep --config calib/paper_scanner.toml --out cam\n"
               "  scanqa simulate calibration-sweep --config calib/paper_scanner.toml "
               "--positions 420:480:2 --repeats 2 --out sweep\n"
               "  scanqa simulate ball-bar --config sample_data/sample_scanner.toml#sample "
               "--repeats 5 --out bar   # the 7 positions\n"
               "  scanqa simulate mesh --mesh part.stl --config calib/paper_scanner.toml "
               "--out part")
    p.add_argument("experiment", metavar="EXPERIMENT",
                   help=f"one of: {', '.join(EXPERIMENTS)}")
    add_config_argument(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--positions", type=_positions, default=None, metavar="LIST",
                   help="stage positions or device offsets [mm]: START:STOP:STEP or a,b,c "
                        "(write --positions=-30:30:2 when it starts with -); sphere and "
                        "flat: Z of the centre [mm]; ball-bar: position numbers 1-7")
    p.add_argument("--repeats", type=number(int, ge=1), default=None,
                   help="scans per position")
    p.add_argument("--periods", type=float_list, default=None,
                   help="fine fringe periods [projector px] (default: the working period)")
    p.add_argument("--mesh", default=None, metavar="FILE", help="STL/PLY/OBJ for 'mesh'")
    p.add_argument("--seed", type=number(int, ge=0), default=None,
                   help="override simulator.seed")
    p.set_defaults(func=run_simulate)


def run_simulate(args: argparse.Namespace) -> int:
    from scanqa.simulator.experiments import run_experiment

    config = config_from_args(args)
    if args.seed is not None:
        config = config.replace_simulator(seed=args.seed)
    manifest = run_experiment(args.experiment, config, args.out, positions=args.positions,
                              repeats=args.repeats, periods=args.periods, mesh=args.mesh,
                              progress=True)
    emit(f"wrote {manifest}")
    return 0
