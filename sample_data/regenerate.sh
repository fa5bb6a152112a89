#!/bin/sh
# Regenerates sample_data/ from scratch (deterministic: same seed, same bytes).
# Run from the repository root:  sh sample_data/regenerate.sh
# One camera throughout (profile 'sample' of sample_scanner.toml: the paper's scanner at
# f/11 with its sensor binned 8 x 8), so that the characterisation, the calibration table
# and the gauge-block scans describe the same scanner.
set -e
CFG=sample_data/sample_scanner.toml
SCANQA=${SCANQA:-.venv/bin/scanqa}
rm -rf sample_data/calibration_sweep sample_data/gauge_blocks sample_data/camera_sweep \
    sample_data/projector_sweep
$SCANQA simulate calibration-sweep --config "$CFG#sample" --positions 424:476:2 \
    --repeats 1 --out sample_data/calibration_sweep --quiet
$SCANQA simulate gauge-blocks --config "$CFG#sample" --repeats 3 \
    --out sample_data/gauge_blocks --quiet
$SCANQA simulate camera-sweep --config "$CFG#sample_roi64" --positions=-30:30:2 \
    --out sample_data/camera_sweep --quiet
# The projector sweep of the same camera: with the camera sweep it tells how the noise
# scales with each device's defocus (scanqa characterize with both folders).
$SCANQA simulate projector-sweep --config "$CFG#sample_roi64" --positions=-30:30:2 \
    --out sample_data/projector_sweep --quiet
# The sweep's per-position truth (float64 X, Y, Z maps) would double the size of the
# sample: drop it, so the table takes X, Y from the camera intrinsics (exact for the
# simulator's pinhole camera). The gauge-block and camera-sweep truth stay.
rm -rf sample_data/calibration_sweep/truth
sed -i '/^lateral = /d' sample_data/calibration_sweep/sweep.toml
# The evidence the "sample" profile's characterised_by names (then put the file's new
# sha256 into sample_scanner.toml, and the fitted values if they moved):
$SCANQA characterize sample_data/camera_sweep sample_data/projector_sweep \
    --config "$CFG#sample_roi64" --out sample_data/characterisation
rm -f sample_data/characterisation/*.png
