#!/bin/sh
# A headless-browser screenshot of the demo's report page, to look at what a person sees.
# Usage: tests/screenshot_report.sh [out/index.html] [report.png] [height]   (needs chromium: apt-get install chromium)
# Prints the PNG's path.
set -eu
page=$(realpath "${1:-out/index.html}")
png=$(realpath -m "${2:-$(dirname "$page")/report.png}")
height=${3:-3000}
browser=$(command -v chromium || command -v chromium-browser || command -v google-chrome || true)
if [ -z "$browser" ]; then
    echo "screenshot_report: no chromium found (apt-get install chromium)" >&2
    exit 1
fi
"$browser" --headless --no-sandbox --disable-gpu --hide-scrollbars --window-size="1400,$height" \
    --screenshot="$png" "file://$page" >/dev/null 2>&1
echo "$png"
