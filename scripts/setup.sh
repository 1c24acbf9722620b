#!/usr/bin/env bash
# One-step set-up for PhyIR, then optionally the demo or the tests.
#   bash scripts/setup.sh            set up only
#   bash scripts/setup.sh --demo     set up, then open the demo scene in phyir-view
#   bash scripts/setup.sh --test     set up, then lint (ruff) and run the test suite
# Installs into the active virtualenv/conda env if there is one, else into ./.venv.
# Never replaces an installed torch; installs the CPU build (torch==2.13.0) only when torch is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
mode="${1:-}"

log() { printf '[setup] %s\n' "$*" >&2; }

# System packages: Xvfb for window tests, Mesa EGL for headless GL (only when missing; needs root/apt).
need_apt=()
command -v Xvfb >/dev/null 2>&1 || need_apt+=(xvfb xauth)
ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' || need_apt+=(libegl1 libegl-mesa0 libgl1-mesa-dri)
ldconfig -p 2>/dev/null | grep -q 'libGL.so.1' || need_apt+=(libgl1)
if [ ${#need_apt[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    log "installing system packages: ${need_apt[*]}"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_apt[@]}") >&2 \
      || log "warning: could not install ${need_apt[*]}; window/GL tests will be skipped"
  else
    log "warning: missing ${need_apt[*]} (install them with your package manager); window/GL tests will be skipped"
  fi
fi

if [ -n "${VIRTUAL_ENV:-}" ] || [ -n "${CONDA_PREFIX:-}" ]; then
  py=python
else
  if [ ! -x .venv/bin/python ]; then
    log "creating .venv"
    python3 -m venv .venv
  fi
  py=.venv/bin/python
fi

if ! "$py" -c 'import torch' >/dev/null 2>&1; then
  log "torch missing: installing the CPU build torch==2.13.0"
  "$py" -m pip install -q torch==2.13.0
else
  log "using installed torch $("$py" -c 'import torch; print(torch.__version__)')"
fi
# Only install our package (and what it needs) when pyproject changed, so repeat runs are fast.
stamp=.venv/.phyir-installed
hash=$(sha1sum pyproject.toml | cut -c1-40)
if [ "$py" != ".venv/bin/python" ] || [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$hash" ]; then
  log "installing phyir (editable) and its dependencies"
  "$py" -m pip install -q -e ".[dev,viewer]"
  [ "$py" = ".venv/bin/python" ] && echo "$hash" > "$stamp"
fi
# The package's bytecode: Python writes it on a module's first import, except where
# PYTHONDONTWRITEBYTECODE is set (containers, CI), and then every command compiles its modules from
# source again (0.2 s of a one-panorama `phyir predict`). Up-to-date files are skipped.
"$py" -m compileall -q -j 0 phyir viewer >/dev/null || log "could not write bytecode (read-only checkout?)"
bindir=$(dirname "$("$py" -c 'import sys; print(sys.executable)')")

case "$mode" in
  --demo)
    shift || true
    if [ -z "${DISPLAY:-}" ] && [ -z "${WAYLAND_DISPLAY:-}" ]; then
      out="${PHYIR_DEMO_PNG:-${TMPDIR:-/tmp}/phyir-demo.png}"  # not into the checkout
      log "no display: rendering the demo scene headlessly (EGL) to $out instead"
      log "(interactive use needs a display; see docs/viewer.md for --headless/--screenshot)"
      exec "$bindir/phyir-view" --headless --screenshot "$out" "$@"
    fi
    exec "$bindir/phyir-view" "$@"
    ;;
  --test)
    shift || true
    export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-PASSIVE}"
    "$py" -m ruff check . && log "ruff: clean"
    exec "$py" -m pytest -q "$@"
    ;;
  "") log "done. Run: $bindir/phyir-view  (or $bindir/phyir --help)";;
  *) log "unknown option $mode (use --demo or --test)"; exit 2;;
esac
