#!/bin/sh
# Print the path of a Python interpreter of version $1 (e.g. 3.13), or nothing.
# Only an interpreter that can make a venv counts (some distributions split ensurepip off).
# Tries `python$1` on PATH (skipping a pyenv shim whose version is not selected), then pyenv,
# then pyenv's install folder directly (pyenv itself not on PATH).
v="$1"
if p=$(command -v "python$v") && "$p" -c 'import ensurepip, venv' 2>/dev/null; then
  "$p" -c 'import sys; print(sys.executable)'
elif command -v pyenv >/dev/null 2>&1 && p=$(PYENV_VERSION="$v" pyenv which python 2>/dev/null); then
  echo "$p"
else
  for p in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/"$v".*/bin/python"$v"; do
    [ -x "$p" ] && "$p" -c 'import ensurepip, venv' 2>/dev/null && { echo "$p"; break; }
  done
fi
