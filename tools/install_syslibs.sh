#!/bin/sh
# Installs the system packages scanqa needs when they are missing.
#   install_syslibs.sh        libusb-1.0-0 (open3d's wheel links against libusb-1.0) and
#                             pango (WeasyPrint prints the reports' PDF with it)
#   install_syslibs.sh test   also the real clients the tests read our files with:
#                             CloudCompare (command line, headless under xvfb-run),
#                             chromium (the HTML reports, and the design page, which
#                             Playwright drives through this very binary: no browser
#                             download), poppler-utils (the PDF reports), and PDAL
#                             (tests/test_pdal.py) where the archive packages it
#                             (Debian 12 does not: those tests are then skipped)
set -e
missing=""
lib() {  # lib SONAME PACKAGE: add PACKAGE when the shared library SONAME is missing
    ldconfig -p 2>/dev/null | grep -q "$1" || missing="$missing $2"
}
lib 'libusb-1.0.so.0' libusb-1.0-0
lib 'libpango-1.0.so.0' libpango-1.0-0
lib 'libpangoft2-1.0.so.0' libpangoft2-1.0-0
lib 'libharfbuzz-subset.so.0' libharfbuzz-subset0
if [ "${1:-}" = "test" ]; then
    command -v CloudCompare >/dev/null 2>&1 || missing="$missing cloudcompare"
    command -v xvfb-run >/dev/null 2>&1 || missing="$missing xvfb"
    command -v xauth >/dev/null 2>&1 || missing="$missing xauth"
    command -v chromium >/dev/null 2>&1 || missing="$missing chromium"
    command -v pdftoppm >/dev/null 2>&1 || missing="$missing poppler-utils"
    # PDAL where the archive has it (the package lists as they are: no update for it alone)
    if ! command -v pdal >/dev/null 2>&1; then
        optional="pdal"
        apt-cache show pdal >/dev/null 2>&1 && missing="$missing pdal" && optional=""
    fi
fi
[ -z "$missing" ] && exit 0
if command -v apt-get >/dev/null 2>&1; then
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq >/dev/null
    for pkg in ${optional:-}; do  # only where the archive has it (not in Debian 12)
        apt-cache show "$pkg" >/dev/null 2>&1 && missing="$missing $pkg"
    done
    echo "scanqa setup: installing system packages:$missing (apt-get)"
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq \
        $missing >/dev/null
else
    echo "scanqa setup: please install these system packages with your package manager:$missing" >&2
    echo "  (open3d needs libusb-1.0, the PDF reports pango; the tests read exported clouds" >&2
    echo "  with CloudCompare under xvfb, reports with chromium and poppler-utils)" >&2
    exit 1
fi
