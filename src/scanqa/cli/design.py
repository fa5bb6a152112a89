"""``scanqa design``: ``dof``, ``curve``, ``volume``, ``flatten``, ``page`` and ``optimise``
(parsing only; :mod:`scanqa.design` does the work)."""

from __future__ import annotations

import argparse
import importlib.util
import json

import numpy as np

from scanqa.cli.common import (
    add_actions,
    add_config_argument,
    add_output_arguments,
    config_from_args,
    emit,
    flags,
    float_list,
    format_rows,
    number,
    output_path,
    warn,
)
from scanqa.design import tools
from scanqa.errors import InputError

_FMT = argparse.RawDescriptionHelpFormatter


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``scanqa design`` and its six tools."""
    group = sub.add_parser(
        "design", formatter_class=_FMT,
        help="design tools: depth of field, W curve, usable volume, flattening, the design "
             "page, the optimiser",
        description="What a scanner will do before it is built (Sect. 5 of the paper), "
                    "from its config alone.",
        epilog="examples:\n  scanqa design dof --config calib/paper_scanner.toml --json\n"
               "  scanqa design page --config calib/paper_scanner.toml")
    actions = add_actions(group)
    p = actions.add_parser("dof", formatter_class=_FMT,
                           help="depth of field per attenuation level and period (Tables 1, 2)",
                           epilog="example:\n  scanqa design dof --config "
                                  "calib/paper_scanner.toml --periods 5,7,10 --json")
    add_config_argument(p)
    p.add_argument("--levels", type=float_list, default=list(tools.TABLE_LEVELS),
                   help="attenuation levels [-] (default: the ten of Table 1)")
    p.add_argument("--periods", type=float_list, default=None,
                   help="fringe periods [projector px] (default: the config's)")
    add_output_arguments(p)
    p.set_defaults(func=run_dof)

    p = actions.add_parser("curve", formatter_class=_FMT,
                           help="attenuation, F_gamma and sigma over range on the camera axis",
                           epilog="example:\n  scanqa design curve --config "
                                  "calib/paper_scanner.toml --z-min 420 --z-max 480 --step 0.5 "
                                  "--plot w.png")
    _add_range(p)
    p.set_defaults(func=run_curve)

    p = actions.add_parser("volume", formatter_class=_FMT,
                           help="usable reconstruction volume at an attenuation level "
                                "(Sect. 5.1)",
                           epilog="example:\n  scanqa design volume --config "
                                  "calib/paper_scanner.toml --level 0.49 --plot volume.png")
    add_config_argument(p)
    p.add_argument("--level", type=number(), default=0.49,
                   help="combined attenuation threshold A_c*A_p [-] (default 0.49)")
    p.add_argument("--z-min", type=number(), default=None, help="near plane [mm]")
    p.add_argument("--z-max", type=number(), default=None, help="far plane [mm]")
    p.add_argument("--step", type=number(gt=0, unit="mm"), default=1.0,
                   help="voxel size [mm] (default 1)")
    p.add_argument("--coc-max", type=number(gt=0, unit="mm"), default=None,
                   help="also require the camera's image-side circle of confusion c_c "
                        "(Eq. 14) <= this [mm]; Fig. 6 draws 0.030 as a band (default: off)")
    add_output_arguments(p)
    p.set_defaults(func=run_volume)

    p = actions.add_parser("flatten", formatter_class=_FMT,
                           help="digital filter diameter that flattens the W curve (Sect. 5.2)",
                           epilog="example:\n  scanqa design flatten --config "
                                  "calib/paper_scanner.toml --plot flat.png --csv")
    _add_range(p)
    p.set_defaults(func=run_flatten)

    page = actions.add_parser("page", formatter_class=_FMT,
                              help="serve the design page locally (Sect. 5.1, Fig. 6)",
                              epilog="example:\n  scanqa design page --config "
                                     "calib/paper_scanner.toml --port 8765")
    add_config_argument(page)
    page.add_argument("--level", type=number(gt=0), default=0.49,
                      help="combined attenuation threshold A_c*A_p to start with [-] "
                           "(default 0.49, Fig. 6)")
    page.add_argument("--coc-max", type=number(gt=0, unit="mm"), default=0.030,
                      help="camera circle-of-confusion threshold to start with [mm] "
                           "(default 0.030, Fig. 6)")
    page.add_argument("--host", default="127.0.0.1",
                      help="interface to serve on (default 127.0.0.1: this machine only)")
    page.add_argument("--port", type=number(int, ge=0), default=8765,
                      help="TCP port (default 8765; 0: any free one)")
    page.add_argument("--no-browser", action="store_true",
                      help="do not open the page in the default browser")
    page.set_defaults(func=run_page)

    opt = actions.add_parser("optimise", formatter_class=_FMT,
                             help="search the settings for the largest usable volume that "
                                  "covers a box at a sigma, clear of obstacles",
                             epilog="example:\n  scanqa design optimise --config "
                                    "calib/paper_scanner.toml --spec "
                                    "benchmarks/design_specs/obstacle.toml --out best.toml")
    add_config_argument(opt)
    opt.add_argument("--spec", required=True, metavar="SPEC.toml",
                     help='design spec (format = "scanqa-design-spec/1": cover box, '
                          "sigma_max_um, [limits], [[obstacles]]; see docs/cli.rst)")
    opt.add_argument("--out", default=None, metavar="FILE.toml",
                     help="write the best configuration's scanner config here")
    opt.add_argument("--open", action="store_true",
                     help="then serve the best configuration in the design page")
    opt.add_argument("--port", type=number(int, ge=0), default=8765,
                     help="design page port with --open (default 8765)")
    add_output_arguments(opt)
    opt.set_defaults(func=run_optimise)



def _plots():
    """The pictures' module, loaded when a picture is drawn: matplotlib takes a second
    to import, and most runs print a table."""
    from scanqa.report import design as plots
    return plots

def _add_range(p: argparse.ArgumentParser) -> None:
    add_config_argument(p)
    p.add_argument("--z-min", type=number(), default=None,
                   help="first range [mm] (default: camera focus - 10 %%)")
    p.add_argument("--z-max", type=number(), default=None,
                   help="last range [mm] (default: camera focus + 10 %%)")
    p.add_argument("--step", type=number(gt=0, unit="mm"), default=None,
                   help="range step [mm] (default 0.5, or a 2000th of the range when "
                        "that is coarser)")
    p.add_argument("--period", type=number(gt=0, unit="px"), default=None,
                   help="fringe period [projector px] (default: the finest of the config)")
    add_output_arguments(p)


def _range(args: argparse.Namespace, focus: float) -> tuple[float, float, float]:
    z_min = 0.9 * focus if args.z_min is None else args.z_min
    z_max = 1.1 * focus if args.z_max is None else args.z_max
    step = args.step if args.step is not None else max(0.5, abs(z_max - z_min) / 2000.0)
    return z_min, z_max, step


def _columns_to_rows(columns: dict) -> list[dict]:
    keys = list(columns)
    n = len(columns[keys[0]])
    return [{k: _py(columns[k][i]) for k in keys} for i in range(n)]


def _py(value: object) -> object:
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    return float(value)


def _emit(args: argparse.Namespace, rows: list[dict], extra: str = "") -> None:
    emit(format_rows(rows, args.json, args.csv))
    if extra and not (args.json or args.csv):
        emit(extra)


def _tabular(args: argparse.Namespace, compute, rows, draw) -> int:
    """Load the config, compute, print the rows and (with --plot) draw the picture."""
    config = config_from_args(args)
    plot = output_path(args.plot)
    result = compute(config)
    if plot:  # the file first: a failed write leaves no printed result behind it
        draw(result, plot, config)
    _emit(args, rows(result))
    return 0


def run_dof(args: argparse.Namespace) -> int:
    return _tabular(args, lambda c: tools.dof_table(c, args.levels, args.periods),
                    lambda res: [r.as_row() for r in res],
                    lambda res, path, c: _plots().plot_dof(res, path))


def run_curve(args: argparse.Namespace) -> int:
    rows = _columns_to_rows  # the curve's columns, one row per depth
    return _tabular(args, lambda c: tools.axis_curve(c, *_range(args, c.camera.focus_mm),
                                                      args.period),
                    rows, lambda res, path, c: _plots().plot_curve(res, path, c.camera.focus_mm))


def run_volume(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    plot = output_path(args.plot)
    vol = tools.usable_volume(config, args.level, args.z_min, args.z_max, args.step,
                               coc_max_mm=args.coc_max)
    if vol.total_mm3 == 0:  # the library answers 0 (the optimiser ranks such designs last)
        raise InputError(
            f"the camera's and the projector's fields do not overlap from z = "
            f"{vol.z_min_mm:g} to {vol.z_max_mm:g} mm (no voxel of {vol.step_mm:g} mm lies in "
            f"both): check projector.position_mm and look_at_mm in {config.source} (the "
            "projector must aim into the camera's view) or the range (--z-min, --z-max)")
    row = {"level": vol.level, "coc_max_mm": vol.coc_max_mm, "z_min_mm": vol.z_min_mm,
           "z_max_mm": vol.z_max_mm,
           "step_mm": vol.step_mm, "total_mm3": vol.total_mm3, "usable_mm3": vol.usable_mm3,
           "fraction": vol.fraction}
    if plot:
        _plots().plot_volume(vol, plot)
    if args.json:
        emit(json.dumps(row, indent=1))
    else:
        emit(format_rows([row], False, args.csv))
    return 0


def run_flatten(args: argparse.Namespace) -> int:
    return _tabular(args, lambda c: tools.flatten_curve(c, *_range(args, c.camera.focus_mm),
                                                         args.period),
                    _columns_to_rows, lambda res, path, c: _plots().plot_flatten(res, path))


def run_page(args: argparse.Namespace) -> int:
    if importlib.util.find_spec("plotly") is None:  # before any work
        raise InputError("the design page needs plotly, which draws it: pip install "
                         "'scanqa[design]'")
    from scanqa.design import server as designapp  # plotly only when the page is served

    with flags({"host ": "--host ", "give host": "give --host"}):
        caution = designapp.check_host(args.host)  # refuses --host ''
    server = designapp.make_server(config_from_args(args), args.host, args.port,
                                   args.level, args.coc_max)
    if caution:
        warn(caution.replace("host ", "--host ", 1).replace("use host", "use --host"))
    return _serve(server, args.host, open_browser=not args.no_browser)


def _serve(server, host: str, open_browser: bool) -> int:
    """Say where the design page is, open it if asked, serve it until Ctrl-C."""
    name = f"[{host}]" if ":" in host else host  # an IPv6 address in a URL
    url = f"http://{name}:{server.server_address[1]}/"
    emit(f"scanqa design page: {url} (Ctrl-C stops it)")
    if open_browser:
        import webbrowser

        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


def run_optimise(args: argparse.Namespace) -> int:
    from scanqa.design import optimisation, rig
    from scanqa.io.atomic import write_text
    from scanqa.io.tomlfile import dumps_toml

    config = config_from_args(args)
    spec = optimisation.load_spec(args.spec)
    out, plot = output_path(args.out), output_path(args.plot)
    res = optimisation.optimise(config, spec)
    best = res.config
    focus = best.camera.focus_mm
    curve = tools.axis_curve(best, 0.9 * focus, 1.1 * focus, 0.5)
    if out:
        write_text(out, "# found by scanqa design optimise --spec " + args.spec + "\n"
                          + dumps_toml(rig.config_toml_dict(best)))
    if plot:
        _plots().plot_curve(curve, plot, focus)
    row = {**res.values, "usable_mm3": res.usable_mm3, "worst_sigma_um": res.worst_sigma_um,
           "evaluations": res.evaluations}
    if args.json:
        emit(json.dumps(row, indent=1))
    else:
        emit(format_rows([row], False, args.csv))
    if args.open:
        from scanqa.design import server as designapp

        server = designapp.make_server(best, "127.0.0.1", args.port, spec.level)
        return _serve(server, "127.0.0.1", open_browser=False)
    return 0
