"""The PDF of a report: the HTML page printed by WeasyPrint.

WeasyPrint renders HTML and CSS to PDF in Python (with Pango for text), so the PDF is
the very page the browser shows, laid out by the print rules of its style sheet
(:mod:`scanqa.report.html`): one content, two media. It needs Debian's pango libraries
(``tools/install_syslibs.sh`` installs them when missing).
"""

from __future__ import annotations

import os
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path


def write_pdf(page_html: str, path: str | os.PathLike) -> Path:
    """Print an HTML page to a PDF file, atomically.

    Parameters
    ----------
    page_html : str
        A self-contained page (images as data: URIs).
    path : str or PathLike
        The PDF file.

    Raises
    ------
    InputError
        When WeasyPrint or the pango libraries it needs are missing.
    """
    weasyprint = check_pdf(path)
    with atomic_path(path, suffix=".pdf") as tmp:
        weasyprint.HTML(string=page_html).write_pdf(tmp)
    return Path(path)


def check_pdf(path: str | os.PathLike):
    """Refuse, before any work, a PDF that cannot be written; the weasyprint module.

    Raises
    ------
    InputError
        WeasyPrint missing (the ``pdf`` extra), or the pango libraries it loads.
    """
    try:
        import weasyprint
    except ImportError:
        raise InputError(f"cannot write {path}: the PDF needs WeasyPrint (pip install "
                         "'scanqa[pdf]'), or write no PDF") from None
    except OSError as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError(f"cannot write {path}: WeasyPrint cannot load the pango libraries "
                         f"({first}); install them (Debian: tools/install_syslibs.sh), or "
                         "write no PDF") from None
    return weasyprint
