#!/usr/bin/env bash
# Two versions of the package baking the same .blend through the CLI, alternated (issue 55's
# timing A/B: "no slowdown over 3%, same run, alternated").
#
#   bench/ab_cli.sh OLD_PKG NEW_PKG FILE.blend ROUNDS -- BAKE OPTIONS...
#
# OLD_PKG / NEW_PKG: folders holding a symlink `hhd_lightmapper` to each version's checkout
# (e.g. `git worktree add /work/old <commit>`; `ln -s /work/old /tmp/old_pkg/hhd_lightmapper`).
# The .blend must already carry its lightmap UVs (`cli FILE unwrap ... --save`), so both versions
# bake the same atlases. Each round bakes a fresh copy with each version (which goes first swaps
# every round) and prints: version, wall, user and system seconds (GNU time), and the sidecars'
# timings_seconds summed over the atlases ("bake_points" is in every atlas's sidecar: the bake
# points of all atlases, counted once per atlas). Run one untimed round first: each checkout
# compiles its numba kernels on its first bake.
set -euo pipefail
old=$1 new=$2 blend=$3 rounds=$4
shift 4
[ "${1:-}" = "--" ] && shift
work=$(mktemp -d)
py=${PYTHON:-python}
for r in $(seq 1 "$rounds"); do
  if [ $((r % 2)) = 1 ]; then order="old new"; else order="new old"; fi
  for v in $order; do
    if [ "$v" = old ]; then pkg=$old; else pkg=$new; fi
    rm -rf "$work/out"; cp "$blend" "$work/scene.blend"
    /usr/bin/time -f "%e %U %S" -o "$work/time" env PYTHONPATH="$pkg" "$py" -m hhd_lightmapper.cli \
      "$work/scene.blend" bake --out "$work/out" "$@" > "$work/log" 2>&1
    "$py" - "$v" "$work" <<'PY'
import glob, json, sys
v, work = sys.argv[1], sys.argv[2]
total = {}
for path in glob.glob(f"{work}/out/*.json"):
    for k, s in (json.load(open(path)).get("timings_seconds") or {}).items():
        total[k] = total.get(k, 0.0) + s
wall, user, system = open(f"{work}/time").read().split()
print(v, wall, user, system, {k: round(s, 2) for k, s in total.items()}, flush=True)
PY
  done
done
rm -rf "$work"
