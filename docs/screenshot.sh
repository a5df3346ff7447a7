#!/usr/bin/env bash
# Remakes docs/viewer.png: the Rerun viewer on the default recording (press-cycle at 1 kHz,
# the scene and step of `mps demo`), drawn by Mesa's software Vulkan driver (lavapipe) in a
# virtual X server (Xvfb): no GPU and no screen needed.
#
#   apt-get install xvfb mesa-vulkan-drivers imagemagick     # once
#   make venv && bash docs/screenshot.sh
#
# The viewer listens on 127.0.0.1 only, its usage analytics are turned off first, and the
# virtual X server and the viewer are ended (by their process ids) when the script ends.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=.venv/bin
SIZE=${SIZE:-1920x1080}
work=$(mktemp -d)
xpid=""
cleanup() { if [ -n "$xpid" ]; then kill "$xpid" 2>/dev/null || true; fi; rm -rf "$work"; }
trap cleanup EXIT

"$BIN/mps" record press-cycle --dt 0.001 --out "$work/press-cycle.mcap" >/dev/null
"$BIN/mps" view "$work/press-cycle.mcap" --save "$work/press-cycle.rrd" --no-spawn
"$BIN/rerun" analytics disable >/dev/null

# a virtual X server on the first free display (it writes the display number to fd 3)
Xvfb -displayfd 3 -screen 0 "${SIZE}x24" -nolisten tcp 3>"$work/display" 2>"$work/xvfb.log" &
xpid=$!
for _ in $(seq 50); do [ -s "$work/display" ] && break; sleep 0.1; done
display=":$(cat "$work/display")"

DISPLAY=$display VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json \
    timeout 300 "$BIN/rerun" --bind 127.0.0.1 --port auto --renderer vulkan \
    --window-size "$SIZE" --screenshot-to "$work/shot.png" "$work/press-cycle.rrd" \
    >"$work/rerun.log" 2>&1

# the viewer renders at twice the logical size: back to SIZE, 64 colours (< 500 kB)
convert "$work/shot.png" -resize "$SIZE" -dither None -colors 64 PNG8:docs/viewer.png
echo "wrote docs/viewer.png ($(stat -c %s docs/viewer.png) bytes)"
