#!/usr/bin/env bash
# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
#
# Build the ROS 2 interface package tf2_msgs (its message tf2_msgs/msg/TFMessage, which /tf
# and /tf_static carry) into a virtual environment that holds the ROS 2 Jazzy wheels.
#
#   tools/build_tf2_msgs.sh [VENV]      (default: .venv)
#
# tf2_msgs has no wheel on PyPI. The message is one line (as in ROS 2 Jazzy's geometry2):
#   geometry_msgs/TransformStamped[] transforms
# and the standard generators (rosidl_generate_interfaces through ament_cmake, wheels pinned in
# requirements-build.txt) give the same C, C++ and Python type support, the same CDR bytes and
# the same type hash as a robot's tf2_msgs. The services and the action of the real package
# are left out. Idempotent: a build made by this very script is kept (about 1 s to check).
# Without cmake, make or a C/C++ compiler it builds nothing, says so in one line and exits 0.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$(cd "${1:-$REPO/.venv}" && pwd)"
PY="$VENV/bin/python"
STAMP="$VENV/share/tf2_msgs/robot_calib_build.sha256"
HASH="$(sha256sum "${BASH_SOURCE[0]}" "$REPO/requirements-build.txt" | sha256sum | cut -c1-64)"

if [[ -f "$STAMP" && "$(cat "$STAMP")" == "$HASH" ]] \
    && "$PY" -c 'from tf2_msgs.msg import TFMessage' 2>/dev/null; then
  echo "tf2_msgs: already built in $VENV"
  exit 0
fi

# Without the build tools (an analyst's laptop, a slim container) everything else is set up all
# the same: the offline tools (simulate, replay, mismatch, ideal, fleet) never need tf2_msgs; the
# live nodes and replay --live say, where they would use /tf or /tf_static, that it is missing.
missing=()
for tool in cmake make cc c++; do
  command -v "$tool" >/dev/null || missing+=("$tool")
done
if (( ${#missing[@]} )); then
  if "$PY" -c 'from tf2_msgs.msg import TFMessage' 2>/dev/null; then
    echo "tf2_msgs: not rebuilt (no ${missing[*]}); the one importable in $VENV is used"
    exit 0
  fi
  echo "tf2_msgs: not built (${missing[*]} not found); everything else is set up, but the live" \
       "nodes and replay --live cannot use /tf or /tf_static until it is: install" \
       "${missing[*]}, then run tools/build_tf2_msgs.sh $VENV" >&2
  exit 0
fi
"$PY" -m pip install --quiet -r "$REPO/requirements-build.txt"

WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
SRC="$WORK/src"
mkdir -p "$SRC/msg" "$WORK/build"
echo 'geometry_msgs/TransformStamped[] transforms' > "$SRC/msg/TFMessage.msg"
cat > "$SRC/package.xml" <<'XML'
<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.36.0</version>
  <description>tf2_msgs/msg/TFMessage (the message of ROS 2 Jazzy's tf2_msgs), built by
    robot_calib's set-up where no ROS 2 installation provides it.</description>
  <maintainer email="robot_calib@example.com">robot_calib contributors</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export>
    <build_type>ament_cmake</build_type>
  </export>
</package>
XML
cat > "$SRC/CMakeLists.txt" <<'CMAKE'
cmake_minimum_required(VERSION 3.8)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(geometry_msgs REQUIRED)
find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
# The message wheels export the Python headers of the machine they were built on; point their
# Python targets at this interpreter's headers instead.
foreach(dep geometry_msgs std_msgs builtin_interfaces)
  if(TARGET ${dep}::${dep}__rosidl_generator_py)
    set_target_properties(${dep}::${dep}__rosidl_generator_py PROPERTIES
      INTERFACE_INCLUDE_DIRECTORIES "${Python3_INCLUDE_DIRS};${Python3_NumPy_INCLUDE_DIRS}")
  endif()
endforeach()
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TFMessage.msg" DEPENDENCIES geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
CMAKE

cd "$WORK/build"
export PATH="$VENV/bin:$PATH"
if ! { cmake "$SRC" -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$VENV" \
         -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$PY" -DBUILD_TESTING=OFF \
       && cmake --build . -j "$(nproc)" && cmake --install . ; } > "$WORK/build.log" 2>&1; then
  tail -40 "$WORK/build.log" >&2
  echo "tf2_msgs: build failed (log above)" >&2
  exit 1
fi
"$PY" -c 'from tf2_msgs.msg import TFMessage' \
  || { echo "tf2_msgs: built but cannot be imported" >&2; exit 1; }
echo "$HASH" > "$STAMP"
echo "tf2_msgs: built into $VENV"
