#!/usr/bin/env bash
# A newcomer's first hour: clone this repository's committed HEAD into a temporary folder and
# run the README's two lines there, each in its own new shell (.ci/readme_lines.sh).
#   .ci/fresh_clone.sh [--keep]      (--keep: leave the clone, its venv and demo.rrd in place)
# The real KITTI kit is found through $MCTRACK_KITTI_ROOT (exported here when the kit sits next
# to this checkout); without it the KITTI tests skip with a reason, as on any fresh clone.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
tmp="$(mktemp -d "${TMPDIR:-/tmp}/mctrack-fresh-clone.XXXXXX")"
if [ "${1:-}" != "--keep" ]; then
  trap 'rm -rf "$tmp"' EXIT
fi
git clone --quiet "$repo" "$tmp/mctrack"
if [ -z "${MCTRACK_KITTI_ROOT:-}" ] && [ -d "$repo/../shared/data/kitti/tracking" ]; then
  MCTRACK_KITTI_ROOT="$(cd "$repo/../shared/data/kitti/tracking" && pwd)"
  export MCTRACK_KITTI_ROOT
fi
start=$(date +%s)
"$tmp/mctrack/.ci/readme_lines.sh" "$tmp/mctrack"
echo "fresh_clone: both README lines succeeded in a clone at $tmp/mctrack ($(($(date +%s) - start)) s)"
if [ "${1:-}" = "--keep" ]; then
  echo "fresh_clone: kept $tmp (venv: $(du -sh "$tmp/mctrack/.venv" | cut -f1))"
fi
