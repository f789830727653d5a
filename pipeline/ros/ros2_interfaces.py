"""ROS 2 interface packages for rclpy: which distribution is installed, and the pipeline's own packages built for it.

rclpy sends a message type only where the type's package is built for the running distribution (its type support:
the C libraries rclpy and the RMW load, and the Python module that holds them). The standard packages come with the
ROS 2 installation: the PyPI wheels of the ``ros2`` extra (Jazzy) or ``ros2-kilted``, or a sourced
``/opt/ros/<distro>``.
The pipeline's own types (``mrl_msgs``) and the standard ones the wheels lack (``tf2_msgs``) are built from
``schemas/`` the way colcon builds a ROS 2 interface package: CMake runs the package's ``CMakeLists.txt`` with
``ament_cmake`` and ``rosidl_default_generators`` of that installation, and installs into a prefix of its own (a
workspace's ``install/`` folder). The prefix lives in the user's cache, one per distribution, installation and schema
digest, and is built once, at the first use of a type that needs it (about 10 s per package); a sourced workspace
that already has the package is used as it is. :func:`environment` is that prefix's ``setup.bash``: the variables a
child process needs to import the packages.

Nothing here imports rclpy; :func:`check_distribution` reads the installed wheels' versions, so a Jazzy/Kilted mix is
named before rclpy loads a library of the other distribution.
"""

from __future__ import annotations

import ctypes
import fcntl
import hashlib
import importlib
import importlib.metadata
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from pipeline.messages.store import SCHEMAS_DIR as SCHEMA_ROOT
from pipeline.ros.errors import BackendUnavailableError

CACHE_VARIABLE = "MRL_ROS2_INTERFACES"
"""Environment variable naming the folder that holds the built prefixes (default ``~/.cache/multirobot-sim2real``)."""

INSTALL_HINT = (
    "pip install -e '.[ros2]' (ROS 2 Jazzy from PyPI; '.[ros2-kilted]' for Kilted) or "
    "source /opt/ros/jazzy/setup.bash; or use the 'dds' transport, which needs no ROS 2"
)

# distribution -> the wheels that tell it, with the major.minor their versions start with
_WHEELS: dict[str, dict[str, str]] = {
    "jazzy": {
        "ros-rclpy": "7.",
        "ros-rcl": "9.",
        "ros-rmw-fastrtps-cpp": "8.",
        "ros-std-msgs": "5.3.",
        "ros-rmw": "7.3.",
    },
    "kilted": {
        "ros-rclpy": "9.",
        "ros-rcl": "10.",
        "ros-rmw-fastrtps-cpp": "9.",
        "ros-std-msgs": "5.5.",
        "ros-rmw": "7.8.",
    },
}

BUILT_PACKAGES = ("mrl_msgs", "tf2_msgs")
"""The interface packages built from ``schemas/`` where the ROS 2 installation lacks them."""

# the wheels' exported CMake targets name the include folder of the Python they were built with (manylinux's
# /opt/python/...), which CMake refuses at generation; the fix drops such folders from imported targets
_CMAKE_FIX = """
function(_mrl_drop_foreign_python_includes)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _targets)
    get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(_dirs)
      list(FILTER _dirs EXCLUDE REGEX "^/opt/python/")
      set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_dirs}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _mrl_drop_foreign_python_includes)
"""


@dataclass(frozen=True)
class Installation:
    """A ROS 2 installation: its distribution and the prefixes (``AMENT_PREFIX_PATH``) that hold its packages."""

    distribution: str
    prefixes: tuple[str, ...]
    source: str
    """'wheels' (the PyPI wheels in this Python's environment) or 'sourced' (a setup.bash, e.g. /opt/ros/jazzy)."""


def _wheel_versions() -> dict[str, str]:
    names = {name for wheels in _WHEELS.values() for name in wheels}
    found = {}
    for name in names:
        try:
            found[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return found


def check_distribution() -> Installation:
    """The ROS 2 installation this Python uses; BackendUnavailableError naming what is wrong (none, or two mixed)."""
    versions = _wheel_versions()
    if versions:
        seen: dict[str, list[str]] = {}
        for name, version in sorted(versions.items()):
            distro = next((d for d, wheels in _WHEELS.items() if version.startswith(wheels[name])), "unknown")
            seen.setdefault(distro, []).append(f"{name} {version}")
        if len(seen) > 1 or "unknown" in seen:
            parts = "; ".join(f"{distro}: {', '.join(names)}" for distro, names in sorted(seen.items()))
            raise BackendUnavailableError(
                "transport 'rclpy'",
                f"the ROS 2 wheels in {sys.prefix} mix distributions ({parts}); one environment holds one: "
                "pip uninstall the ros-* wheels, then pip install -e '.[ros2]' (Jazzy) or -e '.[ros2-kilted]' (Kilted)",
            )
        (distro,) = seen
        return Installation(distro, (sys.prefix,), "wheels")
    sourced = os.environ.get("ROS_DISTRO", "")
    prefixes = tuple(p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p)
    if sourced and prefixes:
        return Installation(sourced, prefixes, "sourced")
    raise BackendUnavailableError("transport 'rclpy'", f"no ROS 2 installation in this Python: {INSTALL_HINT}")


def has_type_support(package: str) -> bool:
    """Whether ``<package>.msg`` is importable as a ROS 2 interface package (rosidl's Python, not ROS 1's genpy)."""
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        return False
    if spec is None or not spec.submodule_search_locations:
        return False
    folder = Path(next(iter(spec.submodule_search_locations)))
    return any(folder.glob(f"{package}_s__rosidl_typesupport_c*.so"))


def schema_digest() -> str:
    """SHA-256 over the .msg files, CMakeLists.txt and package.xml of the built packages' schemas."""
    digest = hashlib.sha256()
    for package in BUILT_PACKAGES:
        for path in sorted((SCHEMA_ROOT / package).rglob("*")):
            if path.is_file() and path.suffix in (".msg", ".txt", ".xml"):
                digest.update(str(path.relative_to(SCHEMA_ROOT)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def prefix_for(installation: Installation) -> Path:
    """The install prefix of the built packages for `installation` (not necessarily built yet)."""
    root = Path(os.environ.get(CACHE_VARIABLE) or Path.home() / ".cache" / "multirobot-sim2real") / "ros2-interfaces"
    key = hashlib.sha256(
        "\0".join(
            [installation.distribution, *installation.prefixes, sys.version, schema_digest(), _CMAKE_FIX]
        ).encode()
    ).hexdigest()[:16]
    return root / f"{installation.distribution}-{key}"


def _site_packages(prefix: Path) -> Path:
    relative = Path(sysconfig.get_paths()["purelib"]).relative_to(sys.prefix)
    return prefix / relative


def environment(prefix: Path) -> dict[str, str]:
    """The variables a process needs to use `prefix` (what its ``setup.bash`` would set), prepended to today's."""
    wanted = {
        "AMENT_PREFIX_PATH": str(prefix),
        "PYTHONPATH": str(_site_packages(prefix)),
        "LD_LIBRARY_PATH": str(prefix / "lib"),
    }
    env = {}
    for key, value in wanted.items():
        parts = [p for p in os.environ.get(key, "").split(os.pathsep) if p]
        env[key] = os.pathsep.join([value, *[p for p in parts if p != value]])
    return env


def _missing(packages: tuple[str, ...]) -> list[str]:
    return [p for p in packages if not has_type_support(p)]


@contextmanager
def _locked(folder: Path) -> Iterator[None]:
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _build_tools() -> tuple[str, str]:
    cmake = shutil.which("cmake", path=os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]))
    compiler = shutil.which("c++") or shutil.which("g++")
    if not cmake or not compiler:
        missing = " and ".join(n for n, found in (("cmake", cmake), ("a C++ compiler", compiler)) if not found)
        raise BackendUnavailableError(
            "ROS 2 interface packages",
            f"building {', '.join(BUILT_PACKAGES)} needs {missing}: pip install cmake, apt-get install g++",
        )
    return cmake, compiler


def package_sources(package: str, into: Path) -> Path:
    """The package folder to build: schemas/<package> as it is where it has a CMakeLists.txt, else one written."""
    source = SCHEMA_ROOT / package
    if (source / "CMakeLists.txt").is_file():
        return source
    folder = into / package
    shutil.copytree(source, folder)
    messages = sorted(p.name for p in (source / "msg").glob("*.msg"))
    text = "\n".join((source / "msg" / m).read_text(encoding="utf-8") for m in messages)
    depends = sorted({m for m in re.findall(r"^\s*([a-z][a-z0-9_]*)/[A-Z]", text, re.MULTILINE) if m != package})
    (folder / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.8)\n"
        f"project({package})\n"
        "find_package(ament_cmake REQUIRED)\n"
        "find_package(rosidl_default_generators REQUIRED)\n"
        + "".join(f"find_package({d} REQUIRED)\n" for d in depends)
        + "rosidl_generate_interfaces(${PROJECT_NAME}\n"
        + "".join(f'  "msg/{m}"\n' for m in messages)
        + (f"  DEPENDENCIES {' '.join(depends)}\n" if depends else "")
        + ")\nament_export_dependencies(rosidl_default_runtime)\nament_package()\n",
        encoding="utf-8",
    )
    (folder / "package.xml").write_text(
        '<?xml version="1.0"?>\n<package format="3">\n'
        f"  <name>{package}</name>\n  <version>0.0.0</version>\n"
        f"  <description>{package} messages from the pipeline's schemas/</description>\n"
        '  <maintainer email="maintainers@multirobot-sim2real.invalid">multirobot-sim2real</maintainer>\n'
        "  <license>Apache-2.0</license>\n"
        "  <buildtool_depend>ament_cmake</buildtool_depend>\n"
        "  <buildtool_depend>rosidl_default_generators</buildtool_depend>\n"
        + "".join(f"  <depend>{d}</depend>\n" for d in depends)
        + "  <exec_depend>rosidl_default_runtime</exec_depend>\n"
        "  <member_of_group>rosidl_interface_packages</member_of_group>\n"
        "  <export><build_type>ament_cmake</build_type></export>\n</package>\n",
        encoding="utf-8",
    )
    return folder


def build(installation: Installation, prefix: Path, packages: tuple[str, ...], log: Path) -> None:
    """Builds `packages` from ``schemas/`` into `prefix` with CMake and the installation's rosidl generators."""
    cmake, _ = _build_tools()
    env = dict(os.environ)
    search = os.pathsep.join([str(prefix), *installation.prefixes])
    env.update(AMENT_PREFIX_PATH=search, CMAKE_PREFIX_PATH=search)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(_site_packages(prefix)), os.environ.get("PYTHONPATH", "")) if p)
    libraries = [str(prefix / "lib"), *(str(Path(p) / "lib") for p in installation.prefixes)]
    with tempfile.TemporaryDirectory(prefix="mrl-ros2-build-") as scratch, open(log, "a") as out:
        fix = Path(scratch) / "fix.cmake"
        fix.write_text(_CMAKE_FIX, encoding="utf-8")
        for package in packages:
            source = package_sources(package, Path(scratch))
            build_dir = Path(scratch) / f"build-{package}"
            steps = [
                [
                    cmake,
                    "-S",
                    str(source),
                    "-B",
                    str(build_dir),
                    f"-DCMAKE_INSTALL_PREFIX={prefix}",
                    f"-DCMAKE_PROJECT_INCLUDE={fix}",
                    f"-DPython3_EXECUTABLE={sys.executable}",
                    f"-DCMAKE_INSTALL_RPATH={';'.join(libraries)}",
                    "-DCMAKE_BUILD_TYPE=Release",
                    "-DBUILD_TESTING=OFF",
                ],
                [cmake, "--build", str(build_dir), "--parallel", str(os.cpu_count() or 1)],
                [cmake, "--install", str(build_dir)],
            ]
            for step in steps:
                out.write(f"$ {' '.join(step)}\n")
                out.flush()
                done = subprocess.run(step, env=env, stdout=out, stderr=subprocess.STDOUT, check=False)
                if done.returncode != 0:
                    raise BackendUnavailableError(
                        f"ROS 2 interface package {package}",
                        f"building it from schemas/{package} for ROS 2 {installation.distribution} failed "
                        f"(exit {done.returncode}; the build's output is in {log})",
                    )


def _use(prefix: Path) -> None:
    """Makes this process see the packages of `prefix`, like sourcing its setup.bash before the start."""
    for key, value in environment(prefix).items():
        os.environ[key] = value  # rosidl's type support dispatch looks for libraries on LD_LIBRARY_PATH when it loads
    # ... but reads that variable when the process starts, so a library loaded by name later is found only where one
    # of that name is loaded already: load the prefix's libraries now (their RUNPATH names their own dependencies)
    for library in sorted((prefix / "lib").glob("lib*.so")):
        ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
    site = str(_site_packages(prefix))
    if site not in sys.path:
        sys.path.insert(0, site)
    importlib.invalidate_caches()


@cache
def ensure_interfaces() -> Path | None:
    """Makes every package of `BUILT_PACKAGES` importable with its type support, building what is missing once.

    Returns the prefix used (None where the installation has all of them). Raises BackendUnavailableError naming the
    installation problem or the package that would not build."""
    installation = check_distribution()
    if not _missing(BUILT_PACKAGES):
        return None
    prefix = prefix_for(installation)
    with _locked(prefix.parent):
        if not (prefix / ".complete").is_file():
            shutil.rmtree(prefix, ignore_errors=True)
            prefix.mkdir(parents=True)
            log = prefix / "build.log"
            build(installation, prefix, tuple(_missing(BUILT_PACKAGES)), log)
            (prefix / ".complete").write_text(schema_digest() + "\n", encoding="utf-8")
    _use(prefix)
    still = _missing(BUILT_PACKAGES)
    if still:
        raise BackendUnavailableError(
            f"ROS 2 interface package {still[0]}",
            f"built into {prefix} but not importable with its type support; remove that folder to build it again",
        )
    return prefix
