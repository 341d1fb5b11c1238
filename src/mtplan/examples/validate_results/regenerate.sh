#!/bin/sh
# Regenerate the validate example from the current model: readings, then results.
#
# Eight measurements of one ring gauge by circle_centre at its default set-up: each is one
# simulated measurement at the default truth (centre (350, -200) um, radius 15 um above the
# nominal) with seed 101 to 108, written in the readings format and evaluated as a measured
# file is. The readings come from the same model whose uncertainty is then checked, so the
# example shows how 'mtplan validate' works; it says nothing about whether the model is right
# for a real machine (that takes measurements of a real calibrated artefact).
#
# Run from anywhere, with mtplan installed: sh examples/validate_results/regenerate.sh
# A test (tests/evaluation/test_validation.py) fails when the model has moved away from
# these files.
set -e
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$here/readings"
for n in 1 2 3 4 5 6 7 8; do
    seed=$((100 + n))
    mtplan simulate circle_centre --trials 1 --seed "$seed" \
        --readings-out "$here/readings/ring_gauge_$n.csv" > /dev/null
    mtplan estimate circle_centre "$here/readings/ring_gauge_$n.csv" --json \
        > "$here/ring_gauge_$n.json.tmp"
    mv "$here/ring_gauge_$n.json.tmp" "$here/ring_gauge_$n.json"
done
