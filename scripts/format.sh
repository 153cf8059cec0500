#!/usr/bin/env bash
# The tree's C++ formatting (.clang-format) and lint (.clang-tidy).
#   scripts/format.sh --check [FILES...]   list files clang-format would change; exit 1 if any
#   scripts/format.sh --apply [FILES...]   reformat them in place
#   scripts/format.sh --tidy  [FILES...]   run .clang-tidy's checks (needs build/compile_commands.json;
#                                          BUILD_DIR=... for another build folder); exit 1 on a finding
# Without FILES: every tracked *.cc and *.h file.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:-}
shift || true
CLANG_FORMAT=${CLANG_FORMAT:-clang-format}
CLANG_TIDY=${CLANG_TIDY:-clang-tidy}
BUILD_DIR=${BUILD_DIR:-build}
if [ "$#" -gt 0 ]; then files=("$@"); else mapfile -t files < <(git ls-files '*.cc' '*.h'); fi

case "$mode" in
  --check)
    bad=()
    for f in "${files[@]}"; do
      if ! "$CLANG_FORMAT" --style=file --dry-run --Werror "$f" >/dev/null 2>&1; then bad+=("$f"); fi
    done
    if [ "${#bad[@]}" -gt 0 ]; then
      printf '%s\n' "${bad[@]}"
      echo "format.sh: ${#bad[@]} of ${#files[@]} files are not formatted (scripts/format.sh --apply)" >&2
      exit 1
    fi
    echo "format.sh: ${#files[@]} files formatted"
    ;;
  --apply)
    "$CLANG_FORMAT" --style=file -i "${files[@]}"
    ;;
  --tidy)
    [ -f "$BUILD_DIR/compile_commands.json" ] || { echo "format.sh: $BUILD_DIR/compile_commands.json: missing (configure with cmake first)" >&2; exit 2; }
    status=0
    for f in "${files[@]}"; do
      case "$f" in *.cc) ;; *) continue ;; esac
      "$CLANG_TIDY" -p "$BUILD_DIR" --quiet "$f" || status=1
    done
    exit "$status"
    ;;
  *)
    echo "usage: scripts/format.sh --check|--apply|--tidy [FILES...]" >&2
    exit 2
    ;;
esac
