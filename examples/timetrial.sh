#!/usr/bin/env bash
# Time trial in three commands: plan a lap, drive it with the tracking MPC on the "real car"
# (the audi_hidden plant: physics the nominal model leaves out), then let the iterative
# double-GP loop learn the mismatch and explore. Tiny settings: the 628 m circle, one GP
# iteration, one trial. For the paper's experiment drop the --track/--iterations/--trials/
# --dictionary-size options (gprace iterate --alpha 0.857,0.714,0).
#
#   bash examples/timetrial.sh [OUT_DIR]        (default: ./timetrial_out)
set -euo pipefail
OUT=${1:-timetrial_out}
TRACK=${GPRACE_EXAMPLE_TRACK:-circle_100}
mkdir -p "$OUT"

gprace plan --track "$TRACK" -o "$OUT/plan.h5"
gprace run --plan "$OUT/plan.h5" --plant audi_hidden -o "$OUT/run.h5"
gprace iterate --track "$TRACK" --alpha 0.857,0 --iterations 1 --trials 1 --dictionary-size 60 \
    --workers 1 --out "$OUT/exploration"

# look at the results: one file, then everything as one HTML page
gprace show "$OUT/run.h5" --plot "$OUT/run.png"
gprace report "$OUT" -o "$OUT/report.html"
