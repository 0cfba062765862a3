#!/usr/bin/env bash
# Run the README's two command lines (the first ```bash block) in DIR, each in a new shell that
# has no virtual environment active, as a newcomer would: line 1 (install + demo), then line 2
# (tests). Prints each line's wall time; fails if either fails.
#   .ci/readme_lines.sh [DIR]          (default: the repository holding this script)
#   .ci/readme_lines.sh --print [DIR]  (only print the two lines, one per line)
set -euo pipefail
print_only=0
if [ "${1:-}" = "--print" ]; then
  print_only=1
  shift
fi
dir="$(cd "${1:-$(dirname "$0")/..}" && pwd)"
mapfile -t lines < <(awk '/^```bash$/ {on = 1; next} on && /^```/ {exit} on && NF' "$dir/README.md")
if [ "${#lines[@]}" -lt 2 ]; then
  echo "readme_lines: no two-line \`\`\`bash block in $dir/README.md" >&2
  exit 1
fi
if [ "$print_only" = 1 ]; then
  printf '%s\n' "${lines[0]}" "${lines[1]}"
  exit 0
fi
# A new shell: no activated venv, no venv bin folder on PATH, no startup files.
clean_path="$(printf '%s' "$PATH" | tr ':' '\n' | grep -v -e '/\.venv/bin$' -e "^${VIRTUAL_ENV:-/nonexistent}/bin$" | paste -sd: -)"
for i in 0 1; do
  echo "readme_lines: line $((i + 1)): ${lines[$i]}"
  start=$(date +%s)
  if ! (cd "$dir" && env -u VIRTUAL_ENV -u PYTHONPATH -u PYTHONHOME PATH="$clean_path" \
    bash --noprofile --norc -c "${lines[$i]}"); then
    echo "readme_lines: line $((i + 1)) FAILED after $(($(date +%s) - start)) s" >&2
    exit 1
  fi
  echo "readme_lines: line $((i + 1)) succeeded in $(($(date +%s) - start)) s"
done
