# Shared by scripts/run_node, launch, push, demo: set up quietly if needed (output shown only when
# setup fails), source the environment, default ROS isolation: ROS_DOMAIN_ID (42 if unset) and
# ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_setup_log="$(mktemp)"
if ! bash "$ROOT/scripts/setup" >"$_setup_log" 2>&1; then
  cat "$_setup_log" >&2; rm -f "$_setup_log"; echo "scripts/setup failed" >&2; exit 1
fi
rm -f "$_setup_log"
# shellcheck source=env.sh
source "$ROOT/scripts/env.sh"
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-42}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
