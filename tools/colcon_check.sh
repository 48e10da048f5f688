#!/usr/bin/env bash
# Build the package with Debian's colcon (colcon-ros: the ament_python build of package.xml and
# setup.py) in a fresh workspace, then start the installed node from / with default parameters
# and stop it once it publishes. Installs colcon from Debian when it is missing (root).
#   bash tools/colcon_check.sh [WORKSPACE]      (default: a new folder under /tmp)
# The node runs on the Python environment given by PYTHON (default: the checkout's .venv), which
# holds rclpy and the solver's dependencies; colcon itself only copies files and writes scripts.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
ws=${1:-$(mktemp -d /tmp/tensegrity-colcon-XXXX)}
python=${PYTHON:-$root/.venv/bin/python}
if ! command -v colcon >/dev/null; then
  apt-get install -y -qq colcon python3-colcon-ros >/dev/null
fi
mkdir -p "$ws/src"
rm -rf "$ws/src/tensegrity_ros"
mkdir -p "$ws/src/tensegrity_ros"
(cd "$root" && git ls-files -z | xargs -0 -I{} cp --parents {} "$ws/src/tensegrity_ros/")
cd "$ws"
start=$(date +%s.%N)
colcon build --base-paths src --event-handlers console_cohesion- 2>&1 | tail -5
echo "colcon build: $(echo "$(date +%s.%N) - $start" | bc) s"
share="$ws/install/tensegrity_ros/share/tensegrity_ros"
ls "$share/config/scenes/fb_column.yaml" "$share/config/paper/fb_target.yaml" \
   "$share/launch/tensegrity.launch.py" "$share/config/tensegrity.rviz" >/dev/null
site=$(ls -d "$ws"/install/tensegrity_ros/lib/python3*/site-packages)
export PYTHONPATH="$site" AMENT_PREFIX_PATH="$ws/install/tensegrity_ros"
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-57} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
script="$ws/install/tensegrity_ros/lib/tensegrity_ros/tensegrity_node"
log="$ws/node.log"
(cd / && exec "$python" "$script") >"$log" 2>&1 &
pid=$!
for _ in $(seq 1 600); do
  grep -q 'activated: stepping' "$log" && break
  kill -0 "$pid" 2>/dev/null || break
  sleep 1
done
sleep 2
kill -INT "$pid" 2>/dev/null || true
wait "$pid"; code=$?
cat "$log"
echo "installed node from /: exit code $code"
grep -q 'activated: stepping' "$log" && [ "$code" = 0 ]
