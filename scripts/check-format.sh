#!/usr/bin/env bash
# Fails when a tracked C++ file differs from .clang-format's style; prints the files and how to fix them.
set -euo pipefail
cd "$(dirname "$0")/.."
CLANG_FORMAT=${CLANG_FORMAT:-$(command -v clang-format-14 || command -v clang-format || true)}
if [ -z "$CLANG_FORMAT" ]; then
  echo "check-format: clang-format not found (scripts/install-deps.sh installs clang-format-14)" >&2
  exit 1
fi
bad=()
while IFS= read -r f; do
  if ! "$CLANG_FORMAT" --dry-run --Werror "$f" >/dev/null 2>&1; then bad+=("$f"); fi
done < <(git ls-files '*.cpp' '*.h' '*.hpp')
if [ ${#bad[@]} -ne 0 ]; then
  printf 'check-format: %d file(s) not formatted:\n' "${#bad[@]}" >&2
  printf '  %s\n' "${bad[@]}" >&2
  echo "fix with: git ls-files '*.cpp' '*.h' '*.hpp' | xargs $CLANG_FORMAT -i" >&2
  exit 1
fi
echo "check-format: all files formatted"
