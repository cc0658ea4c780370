# Environment of the project's scripts (sourced by scripts/setup, scripts/test, scripts/demo).
# Not needed for `.venv/bin/python ...`: scripts/setup installs .venv/lib/python3.11/site-packages/
# biped_ros_env.pth, which puts .venv on AMENT_PREFIX_PATH for every Python started from the venv,
# and the ros-wheels-bootstrapper .pth (from the ROS wheels) sets LD_LIBRARY_PATH by re-executing
# the interpreter once. What this file adds is for shells and CMake:
#   AMENT_PREFIX_PATH, CMAKE_PREFIX_PATH  the venv (ament index: share/ament_index, lib/<pkg>/<exe>)
#   PATH                                  .venv/bin first
# Safe to source more than once; works from any directory.
BIPED_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BIPED_VENV="$BIPED_ROOT/.venv"
export BIPED_ROOT BIPED_VENV

_biped_prepend() {  # _biped_prepend VAR DIR: put DIR first in the ':'-list VAR, once
  local var="$1" dir="$2" cur
  cur="${!var:-}"
  cur=":${cur}:"
  cur="${cur//:${dir}:/:}"
  cur="${cur#:}"; cur="${cur%:}"
  export "$var=${dir}${cur:+:${cur}}"
}
_biped_prepend AMENT_PREFIX_PATH "$BIPED_VENV"
_biped_prepend CMAKE_PREFIX_PATH "$BIPED_VENV"
_biped_prepend PATH "$BIPED_VENV/bin"
unset -f _biped_prepend
# The ROS wheels' bootstrapper re-executes Python once with LD_LIBRARY_PATH set and marks that with
# _ROS_WHEELS_BOOTSTRAP_COMPLETE, which children inherit. If we were started from another venv's
# Python (guard set, but not for this venv's lib/), let this venv's Python bootstrap itself again.
if [[ -n "${_ROS_WHEELS_BOOTSTRAP_COMPLETE:-}" && ":${LD_LIBRARY_PATH:-}:" != *":$BIPED_VENV/lib:"* ]]; then
  unset _ROS_WHEELS_BOOTSTRAP_COMPLETE
fi
