"""``ramps ros build-interfaces``: build ``ramps_interfaces`` (the RunProgram action) into this environment.

How this works: the ROS 2 wheels of the ``ros`` extra carry rosidl's
generators, their templates, headers and CMake packages under
``sys.prefix`` (``include/``, ``share/``, ``lib/``). This writes a standard
interface package (package.xml, CMakeLists.txt, ``action/RunProgram.action``)
into a temporary directory and runs CMake on it with ``sys.prefix`` as the
prefix, then installs it there: ``ramps_interfaces`` becomes importable and
``ramps ros`` serves ``/<robot>/ramps/run`` as a real ROS 2 action beside its
topics. Needs ``cmake`` and a C/C++ compiler (about 20 s of CPU; the wall
time depends on the machine's load: docs/ros2.md).

Two gaps of the wheels are bridged here, without touching them: their ament
index lacks the ``rosidl_typesupport_c``/``_cpp`` entries that tell CMake
which type supports exist (given in a private prefix), and their exported
CMake targets name the Python headers of the machine that built them
(``/opt/python/...``; replaced by this interpreter's).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

PACKAGE = "ramps_interfaces"
ACTION = Path(__file__).resolve().parent / "interfaces" / "RunProgram.action"

PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>ramps_interfaces</name>
  <version>0.1.0</version>
  <description>ramps: run a registered program on the robot team as a ROS 2 action</description>
  <maintainer email="ramps@example.org">ramps</maintainer>
  <license>MIT</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>action_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""

CMAKELISTS = """cmake_minimum_required(VERSION 3.8)
project(ramps_interfaces)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(action_msgs REQUIRED)
# the wheels' exported targets name the Python headers of the machine that
# built them (/opt/python/...): drop those, this interpreter's come with rosidl
get_property(_imported DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(_t ${_imported})
  get_target_property(_inc ${_t} INTERFACE_INCLUDE_DIRECTORIES)
  if(_inc)
    list(FILTER _inc EXCLUDE REGEX "^/opt/python/")
    set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_inc}")
  endif()
endforeach()
rosidl_generate_interfaces(${PROJECT_NAME} "action/RunProgram.action" DEPENDENCIES action_msgs)
ament_package()
"""

#: ament index entries the wheels leave out (CMake picks type supports from them)
TYPESUPPORTS = {"rosidl_typesupport_c": ["rosidl_typesupport_fastrtps_c", "rosidl_typesupport_introspection_c"],
                "rosidl_typesupport_cpp": ["rosidl_typesupport_fastrtps_cpp", "rosidl_typesupport_introspection_cpp"]}


class BuildError(RuntimeError):
    pass


def missing_tools() -> list[str]:
    return [t for t in ("cmake", "make", "cc", "c++") if shutil.which(t) is None]


def build(prefix: str | None = None, *, jobs: int = 2, log=print) -> Path:
    """Build and install ramps_interfaces into ``prefix`` (default: this environment)."""
    prefix = prefix or sys.prefix
    if missing_tools():
        raise BuildError(f"building ROS interfaces needs {', '.join(missing_tools())} (e.g. apt install cmake "
                         "build-essential)")
    if not (Path(prefix) / "share" / "rosidl_default_generators").is_dir():
        raise BuildError(f"no rosidl generators under {prefix}: pip install 'ramps-robotics[ros]'")
    with tempfile.TemporaryDirectory(prefix="ramps-interfaces-") as tmp:
        src, build_dir, index = Path(tmp) / PACKAGE, Path(tmp) / "build", Path(tmp) / "index"
        (src / "action").mkdir(parents=True)
        (src / "package.xml").write_text(PACKAGE_XML)
        (src / "CMakeLists.txt").write_text(CMAKELISTS)
        shutil.copy(ACTION, src / "action" / "RunProgram.action")
        for kind, names in TYPESUPPORTS.items():
            d = index / "share" / "ament_index" / "resource_index" / kind
            d.mkdir(parents=True)
            for name in names:
                (d / name).touch()
        env = {**__import__("os").environ, "AMENT_PREFIX_PATH": f"{index}:{prefix}",
               "PATH": f"{Path(sys.executable).parent}:{__import__('os').environ.get('PATH', '')}"}
        build_dir.mkdir()
        steps = [
            ["cmake", str(src), f"-DCMAKE_PREFIX_PATH={index};{prefix}", f"-DCMAKE_INSTALL_PREFIX={prefix}",
             f"-DPython3_EXECUTABLE={sys.executable}", f"-DPython3_INCLUDE_DIR={sysconfig.get_paths()['include']}",
             "-DBUILD_TESTING=OFF"],
            ["cmake", "--build", ".", "--", f"-j{jobs}"],
            ["cmake", "--install", "."],
        ]
        for argv in steps:
            log(f"$ {' '.join(argv[:3])} ...")
            p = subprocess.run(argv, cwd=build_dir, env=env, capture_output=True, text=True)
            if p.returncode != 0:
                tail = (p.stdout + p.stderr)[-4000:]
                raise BuildError(f"{' '.join(argv[:2])} failed (exit {p.returncode}):\n{tail}")
    where = Path(prefix) / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages" / PACKAGE
    log(f"installed {PACKAGE} (action RunProgram) into {prefix}")
    return where


if __name__ == "__main__":  # pragma: no cover
    try:
        build()
    except BuildError as exc:
        print(f"ramps ros build-interfaces: {exc}", file=sys.stderr)
        sys.exit(2)
