"""``--flatten``, ``--target-um`` and ``--tradeoff`` of ``scanqa decode`` and ``scanqa
annotate`` (parsing only: :func:`scanqa.annotation.flattening.flatten` does the work)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from scanqa.cli.common import calibration_from_args, config_from_args, emit, number
from scanqa.decoding.coding import PatternDescription
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError


def add_flatten_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--flatten``, ``--target-um S`` and ``--tradeoff FILE.png``."""
    parser.add_argument("--flatten", action="store_true",
                        help="filter the finest phase set with a range-dependent disc so the "
                             "random sigma is uniform over the scan's ranges (Sect. 5.2)")
    parser.add_argument("--target-um", type=number(float, gt=0), default=None, metavar="S",
                        help="with --flatten: the sigma to reach [um] (default: the lowest "
                             "over the scan's ranges)")
    parser.add_argument("--tradeoff", metavar="FILE.png", default=None,
                        help="with --flatten: write the trade-off figure (sigma and lateral "
                             "resolution against range)")


def check_flatten_args(args: argparse.Namespace) -> None:
    """Refuse --target-um/--tradeoff without --flatten, and --flatten without the
    calibration and config it needs."""
    if not args.flatten:
        if args.target_um is not None or args.tradeoff:
            raise InputError("--target-um and --tradeoff only apply with --flatten")
        return
    if not (getattr(args, "calibration", None) and getattr(args, "config", None)):
        raise InputError("--flatten needs each pixel's range and the noise model: give "
                         "--calibration FILE and --config FILE")


def flatten_from_args(args: argparse.Namespace, desc: PatternDescription,
                      stacks: Sequence[np.ndarray], phase_map: PhaseMap) -> PhaseMap:
    """The flattened map when ``--flatten`` is given (else ``phase_map``), with the
    trade-off printed and, with ``--tradeoff``, drawn."""
    check_flatten_args(args)
    if not args.flatten:
        return phase_map
    from scanqa.annotation.flattening import flatten
    from scanqa.report.flattening import plot_tradeoff, tradeoff_table

    config = config_from_args(args)
    calibration = calibration_from_args(args, config, phase_map)
    flat = flatten(desc, stacks, phase_map, calibration, config, args.target_um)
    emit(tradeoff_table(flat.curve))
    if args.tradeoff:
        emit(f"trade-off figure -> {plot_tradeoff(flat.curve, args.tradeoff)}")
    return flat.phase_map
