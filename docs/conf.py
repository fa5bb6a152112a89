"""Sphinx configuration of the scanqa documentation (``make docs``).

The API reference documents the sources of this checkout (``src/`` comes first on the
path), so the docs never describe an older installed copy. ``api.rst`` lists every module
by layer; :func:`check_api_lists_every_module` makes the build fail (the build runs with
warnings as errors) when a module of the package is missing from it.
"""

from __future__ import annotations

import pkgutil
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
SRC = DOCS.parent / "src"
sys.path.insert(0, str(SRC))

import scanqa  # noqa: E402  (after the path: the checkout's sources, not an installed copy)

project = "scanqa"
author = "the scanqa authors"
copyright = "the scanqa authors, BSD-3-Clause"
release = scanqa.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.viewcode",
    "numpydoc",
]

exclude_patterns = ["_build", "api/generated/_*"]
templates_path = ["_templates"]
html_static_path = ["_static"]
html_theme = "alabaster"  # ships with Sphinx: no theme dependency
html_theme_options = {
    "description": "Calibration-aware uncertainty for phase-shift 3D scanners",
    "fixed_sidebar": True,
    "page_width": "1100px",
    "sidebar_width": "240px",
}
html_title = f"scanqa {release}"
default_role = "code"  # `x_p` renders as code, as in the docstrings

# API reference: one generated page per module, members in source order.
autosummary_generate = True
autosummary_imported_members = False
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the numpydoc Parameters sections carry types and units
autodoc_default_options = {"members": True, "show-inheritance": True}
numpydoc_show_class_members = False  # autodoc lists the members once
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()


def package_modules() -> list[str]:
    """Every public module and subpackage of scanqa (names without a leading _)."""
    out = ["scanqa"]
    for info in pkgutil.walk_packages(scanqa.__path__, "scanqa."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            out.append(info.name)
    return sorted(out)


def packages() -> set[str]:
    """The subpackages: their pages show the docstring and link the modules (no members,
    which their modules document)."""
    return {name for name in package_modules()
            if (SRC / name.replace(".", "/") / "__init__.py").exists()}


autosummary_context = {"packages": packages()}


def check_api_lists_every_module(app) -> None:
    """Warn (an error under -W) for any module of the package that api.rst does not list."""
    listed = set(re.findall(r"^\s+(scanqa(?:\.\w+)*)\s*$",
                            (DOCS / "api.rst").read_text(encoding="utf-8"), flags=re.M))
    from sphinx.util import logging
    log = logging.getLogger(__name__)
    for name in package_modules():
        if name not in listed:
            log.warning("module %s is not listed in docs/api.rst: add it under its layer",
                        name)
    for name in sorted(listed - set(package_modules())):
        log.warning("docs/api.rst lists %s, which is not a module of the package", name)


def write_public_table(app) -> None:
    """docs/api/public.inc: every name of ``scanqa.__all__``, linked to where it is defined,
    so that the table follows the package's face without being edited by hand."""
    rows = []
    for name in sorted(scanqa.__all__, key=str.lower):
        obj = getattr(scanqa, name)
        module = getattr(obj, "__module__", None)
        if name.startswith("_") or module is None:
            continue
        role = "class" if isinstance(obj, type) else "func"
        if role == "class" and issubclass(obj, Exception):
            role = "exc"
        summary = (obj.__doc__ or "").strip().splitlines()[0] if obj.__doc__ else ""
        # the summary's own references are relative to its module: show them as code
        summary = re.sub(r":\w+:`~?([^`]+)`", r"``\1``", summary)
        rows.append(f"   * - :{role}:`scanqa.{name} <{module}.{obj.__qualname__}>`\n"
                    f"     - {summary} (:mod:`{module}`)")
    text = (".. list-table::\n   :header-rows: 1\n   :widths: 30 70\n\n"
            "   * - name\n     - summary (defined in)\n" + "\n".join(rows) + "\n")
    out = DOCS / "api" / "public.inc"
    out.parent.mkdir(exist_ok=True)
    if not out.exists() or out.read_text(encoding="utf-8") != text:
        out.write_text(text, encoding="utf-8")


_LITERAL = re.compile(r"(``.*?``)")


def escape_bars(app, what, name, obj, options, lines) -> None:
    """Docstrings write absolute values as ``|x|`` so that ``help()`` reads like the
    formula; reStructuredText would take them for substitutions. Escape every bar outside
    inline literals."""
    for i, line in enumerate(lines):
        if "|" in line:
            parts = _LITERAL.split(line)
            lines[i] = "".join(p if p.startswith("``") else p.replace("|", "\\|")
                               for p in parts)


def public_names() -> dict[str, str]:
    """``scanqa.NAME`` -> the dotted path where NAME is defined and documented."""
    out = {}
    for name in scanqa.__all__:
        obj = getattr(scanqa, name)
        if getattr(obj, "__module__", None) and hasattr(obj, "__qualname__"):
            out[name] = f"{obj.__module__}.{obj.__qualname__}"
    return out


PUBLIC = public_names()


def resolve_public_names(app, env, node, contnode):
    """Let ``:func:`scanqa.load_config``` (and plain ``load_config`` inside the ``scanqa``
    module's own docstring) link to where the object is defined and documented."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"]
    if target.startswith("scanqa."):
        name = target[len("scanqa."):]
    elif node.get("py:module") == "scanqa":
        name = target
    else:
        return None
    if name not in PUBLIC:
        return None
    return env.get_domain("py").resolve_xref(env, node["refdoc"], app.builder,
                                             node["reftype"], PUBLIC[name], node, contnode)


def setup(app) -> None:
    app.connect("missing-reference", resolve_public_names)
    app.connect("autodoc-process-docstring", escape_bars, priority=100)
    app.connect("builder-inited", check_api_lists_every_module)
    app.connect("builder-inited", write_public_table)
