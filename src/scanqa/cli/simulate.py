"""``scanqa simulate`` and ``scanqa characterize`` (parsing only)."""

from __future__ import annotations

import argparse

from scanqa.cli.common import add_config_argument, config_from_args, emit, flags, float_list, number
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
    """Add the ``simulate`` and ``characterize`` subcommands."""
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

    p = sub.add_parser(
        "characterize", formatter_class=_FMT,
        help="fit the noise model to a simulated or measured sweep and say what the data "
             "identify",
        description="Decode a camera, projector or calibration sweep, fit a low-order "
                    "surface to the flat's x_p map per position, compare the residual std "
                    "and the attenuation with the model (Figs. 3/4), and fit every variant "
                    "of the model (the paper's readings and the two-source model). Each "
                    "parameter is reported as fitted, bounded or not identifiable with its "
                    "95 % profile-likelihood interval; the variant that predicts held-out "
                    "positions best is selected and compared with a constant. Several "
                    "sweeps are fitted together.",
        epilog="The scanner config defaults to the one recorded in the sweep's manifest; a "
               "--config given must have the same camera and projector.\n\n"
               "examples:\n  scanqa characterize cam --out cam/characterize\n"
               "  scanqa characterize cam proj --config calib/paper_scanner.toml --out both\n"
               "  scanqa characterize sweep/sweep.toml   # a rigid scanner's calibration sweep")
    p.add_argument("sweep", metavar="SWEEP", nargs="+",
                   help="folder(s) written by scanqa simulate camera-sweep/projector-sweep, "
                        "or a calibration sweep's sweep.toml (both devices defocus)")
    add_config_argument(p, required=False)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="folder for summary.json and plots (default: SWEEP_DIR/characterize)")
    p.add_argument("--min-attenuation", type=number(gt=0), default=0.49,
                   help="fit where the moving devices' model attenuation is at least this "
                        "[-] (default 0.49)")
    p.set_defaults(func=run_characterize)


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


def run_characterize(args: argparse.Namespace) -> int:
    from scanqa.model.characterization import characterize_sweeps, sweep_config, sweep_folder
    from scanqa.report.characterization import characterization_lines, write_characterization

    with flags({"leave the config out": "leave --config out",
                "give the config the sweep was made with":
                    "give the config the sweep was made with (--config)"}):
        config = config_from_args(args) if args.config else sweep_config(args.sweep[0])
        result = characterize_sweeps(args.sweep, config, min_attenuation=args.min_attenuation)
    default = sweep_folder(args.sweep[0]) / "characterize"
    out = write_characterization(result, args.out or default, config)
    summary = result.summary()
    emit(summary["verdict"])
    for line in characterization_lines(summary):
        emit(f"  {line}")
    emit(f"wrote {out}")
    return 0
