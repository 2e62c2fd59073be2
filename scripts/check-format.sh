#!/usr/bin/env bash
# Checks C++ files against .clang-format without changing them (clang-format --dry-run
# -Werror). With no arguments: the files changed against BASE (default: the upstream
# branch if there is one, else HEAD), staged, unstaged and untracked. With --all: every
# tracked C++ file. With --fix: rewrites them instead of checking.
# Usage: scripts/check-format.sh [--all] [--fix] [BASE]
set -euo pipefail
cd "$(dirname "$0")/.."
all=0 fix=0 base=""
for arg in "$@"; do
  case "$arg" in
    --all) all=1 ;;
    --fix) fix=1 ;;
    *) base="$arg" ;;
  esac
done
command -v clang-format >/dev/null || { echo "clang-format is missing: sudo apt-get install clang-format" >&2; exit 1; }
cxx=(':(glob)**/*.cpp' ':(glob)**/*.hpp' ':(glob)**/*.h')
if [ "$all" = 1 ]; then
  mapfile -t files < <(git ls-files -- "${cxx[@]}")
else
  [ -n "$base" ] || base="$(git rev-parse --abbrev-ref --symbolic-full-name '@{upstream}' 2>/dev/null || echo HEAD)"
  mapfile -t files < <({ git diff --name-only --diff-filter=d "$base" -- "${cxx[@]}"
                         git ls-files --others --exclude-standard -- "${cxx[@]}"; } | sort -u)
fi
[ "${#files[@]}" -gt 0 ] || { echo "format: no C++ files to check"; exit 0; }
if [ "$fix" = 1 ]; then
  clang-format -i "${files[@]}"
  echo "format: rewrote ${#files[@]} files"
else
  clang-format --dry-run -Werror "${files[@]}"
  echo "format: ${#files[@]} files follow .clang-format"
fi
