"""``scanqa qa``: gauge-block QA or VDI/VDE 2634-2 acceptance tests of annotated clouds
(or scans + a calibration); the layout's format says which."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from scanqa.annotation.points import annotate
from scanqa.calibration.sweep import geometry_covariance
from scanqa.cli.common import (
    add_calibration_argument,
    add_config_argument,
    add_model_argument,
    calibration_from_args,
    config_from_args,
    emit,
    flags,
    number,
    warn_sigma,
)
from scanqa.decoding.decoder import decode
from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud, read_cloud
from scanqa.io.artefacts import FORMAT as ARTEFACT_FORMAT
from scanqa.io.artefacts import layout_format
from scanqa.io.spec import read_spec
from scanqa.model.config import ScannerConfig
from scanqa.provenance import build_header, certificate_text, describe_paths
from scanqa.qa.artefacts import Options, auto_layout, load_artefact_layout, run_artefact_qa
from scanqa.qa.blocks import run_qa
from scanqa.qa.budget import load_budget
from scanqa.qa.detect import detect_blocks
from scanqa.qa.layout import load_layout
from scanqa.qa.verdict import EXIT_STATUS
from scanqa.report import artefacts as artefact_report
from scanqa.report import qa as qa_report
from scanqa.report.pdf import check_pdf

_EPILOG = """examples:
  scanqa qa cloud.ply --layout calib/gauge_blocks_paper.toml --out qa/
  scanqa qa scan/phase.npz --calibration table.npz --config calib/paper_scanner.toml \\
      --layout calib/gauge_blocks_paper.toml --out qa/
  scanqa qa bar/p00*_r0 --calibration table.npz --config CFG --layout bar/artefacts.toml \\
      --spec bar/spec.toml --operator "A. Smith" --pdf --out qa/
  scanqa qa sphere.ply --auto --artefact sphere --spec spec.toml --out qa/

a gauge-block layout (scanqa-gauge-layout/1) runs the gauge-block QA: report.html,
blocks.csv, steps.csv, summary.json, cloud_qa.ply; an artefact layout
(scanqa-artefact-layout/1) or --artefact runs the VDI/VDE 2634-2 tests (PF, PS, SD, F):
report.html, quantities.csv, budget.csv, selection.csv, summary.json; --pdf adds
report.pdf"""


#: The PDF writer's words for leaving the PDF out, in this command's.
_PDF = {"or write no PDF": "or leave out --pdf"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "qa", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=_EPILOG,
        help="gauge-block QA, or VDI/VDE 2634-2 tests on spheres, ball bars and flats")
    p.add_argument("cloud", metavar="CLOUD", nargs="+",
                   help="annotated cloud(s) (.ply/.las/.csv) or, with --calibration, "
                        "scan(s); an artefact layout's 'scan' keys match their names")
    p.add_argument("--layout", help="gauge-block or artefact layout TOML")
    p.add_argument("--auto", action="store_true",
                   help="find the blocks by plane segmentation (nominal heights from "
                        "--layout or --heights), or with --artefact the artefact by RANSAC")
    p.add_argument("--artefact", choices=("sphere", "ball-bar", "flat"), default=None,
                   help="with --auto: the VDI/VDE 2634-2 artefact in the scan(s)")
    p.add_argument("--diameter", type=number(gt=0, unit="mm"), default=None, metavar="MM",
                   help="with --artefact: nominal ball diameter (default: the spec's)")
    p.add_argument("--distance", type=number(gt=0, unit="mm"), default=None, metavar="MM",
                   help="with --artefact ball-bar: nominal centre distance (default: the "
                        "spec's)")
    p.add_argument("--heights", default=None,
                   help="with --auto and no --layout: id=height_mm pairs, e.g. 1=50.8,2=25.4")
    p.add_argument("--spec", metavar="FILE",
                   help="acceptance spec (scanqa-spec/1: MPEs and artefact certificates)")
    add_calibration_argument(p, required=False, when=", when CLOUD is a scan")
    add_config_argument(p, required=False)
    add_model_argument(p)
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--operator", default=None, help="operator's name for the report header")
    p.add_argument("--notes", default=None, help="notes for the report header")
    p.add_argument("--pdf", action="store_true", help="also write report.pdf")
    p.add_argument("--margin", type=number(ge=0, unit="mm"), default=1.0,
                   help="edge margin of blocks and flats [mm] (default 1)")
    p.add_argument("--outliers", type=number(gt=0), default=None, metavar="K",
                   help="gauge blocks: reject points beyond K robust std of the first plane "
                        "fit (default: no rejection)")
    p.add_argument("--tolerance", type=number(ge=0, unit="um"), default=None,
                   help="gauge blocks: tolerance T on each height difference [um] (default "
                        "20, and the verdict line says it was the default)")
    p.add_argument("--strict", action="store_true",
                   help="exit status from the verdict: 0 PASS, 1 FAIL, 3 UNDECIDED, "
                        "INCOMPLETE or NOT EVALUATED (2 stays an error of the input); "
                        "without it a QA that ran exits 0 whatever its verdict")
    p.add_argument("--k", type=_coverage, default=None,
                   help="coverage factor: a number, or welch-satterthwaite for k from each "
                        "step's effective degrees of freedom (default: the budget file's, "
                        "else 2; artefacts: 2)")
    p.add_argument("--budget", default=None, metavar="FILE",
                   help="gauge blocks: uncertainty budget TOML with the Type B inputs "
                        "(certificates, temperature, stage scale, flatness of the "
                        "calibration flat); without it the report says Type B is not "
                        "included")
    p.add_argument("--tile", type=number(gt=0, unit="mm"), default=2.0, metavar="MM",
                   help="tile size [mm] over which the noise correlation is measured; at "
                        "least twice the noise's correlation length (default 2)")
    p.add_argument("--max-incidence", type=number(gt=0, unit="deg"), default=70.0,
                   metavar="DEG",
                   help="artefacts: drop points seen at more than DEG from their normal "
                        "(default 70; 90 keeps all)")
    p.add_argument("--decide-with", choices=("test", "total"), default="test",
                   help="artefacts: decide with the test uncertainty (artefact only, "
                        "default) or with U (adds the scanner's own spread)")
    p.set_defaults(func=run)


def _coverage(text: str) -> float | str:
    if text == "welch-satterthwaite":
        return text
    return number(gt=0)(text)


def _load(args: argparse.Namespace) -> tuple[list[tuple[str, AnnotatedCloud]],
                                             ScannerConfig | None, object]:
    """The clouds, the config and the calibration's geometry covariance (None without
    --calibration, or when the calibration carries none)."""
    config = config_from_args(args) if args.config else None
    geometry = None
    if args.calibration:
        if config is None:
            raise InputError("--calibration needs --config (the config the table was built "
                             "with, or that describes the calibrated scanner)")
        out = []
        for c in args.cloud:
            scan = decode(c)
            cal = calibration_from_args(args, config, scan)
            geometry = geometry_covariance(cal) if geometry is None else geometry
            out.append((Path(c).name, annotate(scan, cal, config, keep_invalid=True,
                                               source=c)))
    else:
        out = [(Path(c).stem, read_cloud(c)) for c in args.cloud]
    warn_sigma([c for _, c in out])
    return out, config, geometry


def _heights(args: argparse.Namespace) -> dict[int, float]:
    if args.layout:
        return {b.block_id: b.nominal_height_mm for b in load_layout(args.layout).blocks}
    if not args.heights:
        raise InputError("--auto needs nominal heights: give --layout or --heights")
    try:
        pairs = [item.split("=") for item in args.heights.split(",")]
        heights = {int(k): float(v) for k, v in pairs}
    except ValueError:
        heights = {}
    if len(heights) != len(pairs) or not all(math.isfinite(h) and h > 0
                                              for h in heights.values()):
        raise InputError(f"--heights must look like 1=50.8,2=25.4 (distinct ids, heights "
                         f"> 0 mm), got {args.heights!r}")
    return heights


def _header(args, clouds, config, spec):
    meta = clouds[0][1].metadata
    cfg = config.to_dict() if config is not None else meta.get("config")
    source = (args.config + (f"#{args.profile}" if args.profile else "")) if config \
        else meta.get("config_source", "the cloud's metadata")
    return build_header(cfg, source, args.calibration, meta.get("table"),
                        certificate_text(spec),
                        args.spec, describe_paths(args.cloud), args.operator, args.notes)


def run(args: argparse.Namespace) -> int:
    if args.artefact and not args.auto:
        raise InputError("--artefact finds the artefact by RANSAC: add --auto, or give an "
                         "artefact layout with --layout instead")
    if not args.layout and not args.auto:
        raise InputError("give --layout FILE, or --auto to find the blocks (or, with "
                         "--artefact, the artefact)")
    if args.pdf:  # before any work: the optional dependency, then the run
        with flags(_PDF):
            check_pdf(Path(args.out) / "report.pdf")
    spec = read_spec(args.spec) if args.spec else None
    artefacts = bool(args.artefact) or (
        bool(args.layout) and not args.auto and layout_format(args.layout) == ARTEFACT_FORMAT)
    out = Path(args.out)
    clouds, config, geometry = _load(args)
    header = _header(args, clouds, config, spec)
    if artefacts:
        return _run_artefacts(args, clouds, spec, header, out)
    if len(clouds) > 1:
        raise InputError(f"gauge-block QA takes one cloud, got {len(clouds)}; run it once "
                         "per scan")
    return _run_blocks(args, clouds[0][1], config, header, out, geometry)


def _auto_layout(args, spec):
    """:func:`auto_layout` with the library's parameter names turned into the flags."""
    try:
        return auto_layout(args.artefact, spec, args.diameter, args.distance)
    except InputError as err:
        text = str(err).replace("kind must", "--artefact must").replace(
            "give diameter_mm or", "give --diameter or").replace(
            "give distance_mm", "give --distance")
        raise InputError(text) from None


def _run_artefacts(args, clouds, spec, header, out) -> int:
    layout = _auto_layout(args, spec) if args.auto else load_artefact_layout(args.layout)
    if args.k == "welch-satterthwaite" or args.budget:
        raise InputError("--k welch-satterthwaite and --budget apply to gauge blocks; the "
                         "artefact tests take a number for --k (default 2)")
    options = Options(k=2.0 if args.k is None else args.k, margin_mm=args.margin, tile_mm=args.tile,
                      max_incidence_deg=args.max_incidence, decide_with=args.decide_with)
    result = run_artefact_qa(clouds, layout, spec, options)
    with flags(_PDF):
        artefact_report.write_outputs(result, out, header, pdf=args.pdf)
    for row in result.rows():
        emit(artefact_line(row))
    for note in result.notes:
        emit(f"note: {note}")
    v = result.verdict()
    emit(f"verdict: {v['verdict']} ({v['pass']} pass, {v['fail']} fail, {v['undecided']} "
         f"undecided, {v['not evaluated']} not evaluated)")
    emit(f"report: {out / 'report.html'}" + (f" and {out / 'report.pdf'}" if args.pdf else ""))
    return EXIT_STATUS[v["verdict"]] if args.strict else 0


def artefact_line(row: dict) -> str:
    """One printed line of a VDI/VDE 2634-2 quantity: E, U, MPE and the decision, the
    fitted size it rests on (PS: the diameter), and why it was not evaluated."""
    head = f"{row['scan']} {row['artefact']} {row['quantity']}: "
    size = (f"fitted diameter {row['measured_mm']:.4f} mm"
            if row["quantity"] == "PS" and math.isfinite(row["measured_mm"]) else "")
    if row["decision"] == "not evaluated":
        parts = [f"E {row['value_um']:+.1f} um (U {row['U_um']:.1f} um)"
                 if math.isfinite(row["value_um"]) else "", size,
                 row["note"] or "not evaluated"]
        return head + "; ".join(p for p in parts if p)
    return head + (f"E {row['value_um']:+.1f} um, U test {row['U_test_um']:.1f} um, MPE "
                   f"{row['mpe_um']:.1f} um, {row['decision']} (U {row['U_um']:.1f} um)"
                   + (f"; {size}" if size else ""))


def _run_blocks(args, cloud, config, header, out, geometry=None) -> int:
    layout = detect_blocks(cloud.xyz, _heights(args)) if args.auto else load_layout(args.layout)
    result = run_qa(cloud, layout, config=config, margin_mm=args.margin,
                    outlier_k=args.outliers, tolerance_um=args.tolerance, k=args.k,
                    tile_mm=args.tile,
                    budget=load_budget(args.budget) if args.budget else None,
                    calibration=geometry)
    with flags(_PDF):
        info = qa_report.write_outputs(result, out, header, pdf=args.pdf)
    for b in result.blocks:
        emit(f"block {b.block_id}: {b.n_points} points, measured {b.measured_std_um:.1f} um, "
             f"predicted {b.predicted_std_um:.1f} um, {b.status}")
    for s in result.steps:
        within = ("|error| <= U" if s.within_u else "|error| > U") if s.evaluated else ""
        emit(f"step {s.block_a}-{s.block_b}: error {s.error_um:+.1f} um, U {s.expanded_um:.1f}"
             f" um, T {s.tolerance_um:g} um: {s.decision}" + (f"; {within}" if within else ""))
    for note in result.notes:
        emit(f"note: {note}")
    frac = info["fraction_within_U"]
    v = qa_report.step_verdict(result)
    source = "" if result.settings["tolerance_source"] == "given" else \
        " (the default: give --tolerance)"
    emit(f"verdict: {v['verdict']} ({v['pass']} pass, {v['fail']} fail, {v['undecided']} "
         f"undecided, {v['not evaluated']} not evaluated; ISO 14253-1 against T = "
         f"{result.settings['tolerance_um']:g} um{source})")
    emit(f"report: {out / 'report.html'}" + (f" ({100 * frac:.0f} % of the evaluated steps "
                                             "within U)" if frac is not None else ""))
    return EXIT_STATUS[v["verdict"]] if args.strict else 0
