#!/bin/sh
# Regenerates sample_data/ from scratch (deterministic: same seed, same bytes).
# Run from the repository root:  sh sample_data/regenerate.sh
set -e
CFG=sample_data/sample_scanner.toml
SCANQA=${SCANQA:-.venv/bin/scanqa}
rm -rf sample_data/calibration_sweep sample_data/gauge_blocks sample_data/camera_sweep
$SCANQA simulate calibration-sweep --config "$CFG#binned8_roi" --positions 436:464:2 \
    --repeats 2 --out sample_data/calibration_sweep --quiet
$SCANQA simulate gauge-blocks --config "$CFG#binned8" --repeats 3 \
    --out sample_data/gauge_blocks --quiet
$SCANQA simulate camera-sweep --config "$CFG#roi96" --positions=-30:30:3 \
    --out sample_data/camera_sweep --quiet
