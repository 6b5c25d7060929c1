#!/usr/bin/env bash
# Head-to-head: collect races with the oracle predictor, train the opponent GPs, explore on the
# closed loop, race every predictor on a handful of random tracks and tabulate (the paper's
# Table "Head-to-Head racing results"). Tiny settings: 2 evaluation tracks, 3 collection runs,
# 12 s of exploration, short races, one calibration pass of 4 races per predictor (the defaults, up
# to 4 passes of 20, took two thirds of the example's time). The paper: --tracks 100 --runs 500
# --explore-minutes 10.
#
#   bash examples/head2head.sh [OUT_DIR]        (default: ./h2h_out)
set -euo pipefail
OUT=${1:-h2h_out}
mkdir -p "$OUT"

gprace eval head2head --tracks 2 --runs 3 --init-runs 2 --explore-minutes 0.2 --episode-seconds 6 \
    --dict-size 30 --stretches 2 --samples 10 --max-time 8 --calib-runs 4 --calib-passes 1 --out "$OUT/h2h"

gprace show "$OUT/h2h/table.json"
gprace report "$OUT" -o "$OUT/report.html"
