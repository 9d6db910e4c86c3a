"""The package installs both ways and its executables resolve the way `ros2 run` resolves them."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
NODE_EXECUTABLES = ("corrector", "collector", "sim_cell")
ALGORITHM_PACKAGES = ("sim", "recordings", "training", "correction", "evaluation", "mismatch")
VIEWS = sorted((REPO / "views").glob("*.*"))  # RViz2 config and Foxglove layout
#: the reports' Jinja2 templates and stylesheet (package data of tof_mpd_ros.templates)
TEMPLATES = sorted(p.name for p in (REPO / "tof_mpd_ros" / "templates").iterdir()
                   if p.is_file() and p.suffix != ".py")


def check_installed_templates(site: Path) -> None:
    """The copy of the package installed under ``site`` finds every template through
    importlib.resources and renders a page from it (run with only ``site`` on the path)."""
    code = textwrap.dedent(f"""
        from pathlib import Path
        import tof_mpd_ros.templates as t
        assert Path(t.__file__).resolve().is_relative_to(Path({str(site)!r}).resolve()), t.__file__
        assert t.template_names() == {TEMPLATES!r}, t.template_names()
        for name in t.template_names():
            if not name.endswith(".css"):
                t.environment(prose=name.endswith(".txt")).get_template(name)
        page = t.render("components.html", title="x", plots=[], results={{
            "n_frames": 0, "seconds_per_frame": 0.0, "summary_5mm": {{}}, "edges": {{}}}})
        assert "border-collapse" in page
        """)
    done = subprocess.run([sys.executable, "-c", code], cwd=site.parent, capture_output=True,
                          text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(site), "PYTHONSAFEPATH": "1"})
    assert done.returncode == 0, done.stderr


def ros2_run_path(prefix_path: str, package: str, executable: str) -> Path:
    """Resolve an executable exactly as `ros2 run` does: ament index -> prefix -> lib/<pkg>/."""
    code = ("import sys; from ament_index_python.packages import get_package_prefix; "
            f"print(get_package_prefix({package!r}))")
    env = {**os.environ, "AMENT_PREFIX_PATH": prefix_path}
    prefix = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                            capture_output=True, text=True).stdout.strip()
    return Path(prefix) / "lib" / package / executable


def run_help(executable: Path, env: dict[str, str] | None = None) -> str:
    assert executable.is_file(), f"{executable} missing"
    assert os.access(executable, os.X_OK), f"{executable} is not executable"
    done = subprocess.run([str(executable), "--help"], env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_package_xml_declares_the_ros_dependencies() -> None:
    root = ET.parse(REPO / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == "tof_mpd_ros"
    exec_deps = {e.text for e in root.findall("exec_depend")}
    assert {"rclpy", "sensor_msgs", "std_msgs", "geometry_msgs", "diagnostic_msgs"} <= exec_deps
    assert root.find("export/build_type").text == "ament_python"


def test_algorithm_modules_import_without_ros() -> None:
    """Every algorithm package imports in an interpreter where rclpy cannot be imported."""
    blocker = ("import sys, importlib.abc\n"
               "class Block(importlib.abc.MetaPathFinder):\n"
               "    def find_spec(self, name, path, target=None):\n"
               "        if name.split('.')[0] in ('rclpy', 'sensor_msgs', 'rosidl_runtime_py'):\n"
               "            raise ImportError('ROS blocked: ' + name)\n"
               "sys.meta_path.insert(0, Block())\n"
               "import pkgutil, importlib, tof_mpd_ros\n"
               f"for sub in {ALGORITHM_PACKAGES!r}:\n"
               "    pkg = importlib.import_module('tof_mpd_ros.' + sub)\n"
               "    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
               "        importlib.import_module(m.name)\n"
               "import tof_mpd_ros.cli.main\n")
    done = subprocess.run([sys.executable, "-c", blocker], cwd=REPO, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr


#: import names of the third-party libraries the package loads; some edit os.environ on import
#: (cv2: LD_LIBRARY_PATH; scikit-learn: KMP_*), which is theirs to answer for
DEPENDENCIES = ("numpy", "scipy", "torch", "cv2", "numba", "sklearn", "mcap", "mcap_ros2", "yaml",
                "tqdm", "matplotlib", "matplotlib.pyplot")


def test_importing_the_package_leaves_the_environment_alone() -> None:
    """``import tof_mpd_ros`` changes no environment variable, and nor does any algorithm module
    or the CLI's (beyond what their third-party libraries do): the entry points choose thread
    policies (tof_mpd_ros.machine). Run in an interpreter started with a clean environment."""
    code = textwrap.dedent(f"""
        import importlib, os, pkgutil
        def changes(before):
            keys = before.keys() | os.environ.keys()
            return {{k: os.environ.get(k) for k in keys if before.get(k) != os.environ.get(k)}}
        before = dict(os.environ)
        import tof_mpd_ros
        assert not changes(before), ("import tof_mpd_ros", changes(before))
        for name in {DEPENDENCIES!r}:
            importlib.import_module(name)
        before = dict(os.environ)
        import tof_mpd_ros.machine, tof_mpd_ros.cli.main
        for sub in {ALGORITHM_PACKAGES!r}:
            pkg = importlib.import_module("tof_mpd_ros." + sub)
            for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
                importlib.import_module(m.name)
        assert not changes(before), ("the modules", changes(before))
        """)
    clean = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=clean, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr


@pytest.mark.skipif(shutil.which("colcon", path=str(Path(sys.executable).parent)) is None,
                    reason="colcon is installed by the 'test' extra")
def test_colcon_build_installs_resolvable_executables(tmp_path: Path) -> None:
    workspace = tmp_path / "ws"
    (workspace / "src").mkdir(parents=True)
    shutil.copytree(REPO, workspace / "src" / "tof_mpd_ros",
                    ignore=shutil.ignore_patterns(".git", ".venv*", "build", "install", "log",
                                                  "__pycache__", "*.egg-info", "out"))
    colcon = Path(sys.executable).parent / "colcon"
    done = subprocess.run([str(colcon), "build", "--packages-select", "tof_mpd_ros"],
                          cwd=workspace, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    prefix = workspace / "install" / "tof_mpd_ros"
    assert (prefix / "share/ament_index/resource_index/packages/tof_mpd_ros").is_file()
    assert (prefix / "share/tof_mpd_ros/config/corrector.yaml").is_file()
    assert (prefix / "share/tof_mpd_ros/config/fastdds_large_images.xml").is_file()
    for view in VIEWS:
        assert (prefix / "share/tof_mpd_ros/views" / view.name).is_file(), view.name
    site = next(prefix.glob("lib/python3*/site-packages"))
    for name in TEMPLATES:
        assert (site / "tof_mpd_ros" / "templates" / name).is_file(), name
    check_installed_templates(site)
    env = {**os.environ, "PYTHONPATH": str(site)}
    for exe in NODE_EXECUTABLES:
        path = ros2_run_path(str(prefix), "tof_mpd_ros", exe)
        assert path.parent == prefix / "lib" / "tof_mpd_ros"
        assert "usage:" in run_help(path, env)


def test_pip_install_resolves_executables_like_ros2_run() -> None:
    """In the virtual environment `pip install '.[ros]'` made, `ros2 run` finds every node."""
    prefix = Path(sys.prefix)
    marker = prefix / "share/ament_index/resource_index/packages/tof_mpd_ros"
    if not marker.is_file():
        pytest.skip("tof_mpd_ros is not pip-installed in this interpreter's prefix "
                    "(the README's test command installs it)")
    for exe in NODE_EXECUTABLES:
        path = ros2_run_path(str(prefix), "tof_mpd_ros", exe)
        assert path == prefix / "lib" / "tof_mpd_ros" / exe
        assert "usage:" in run_help(path)
    assert "usage: tof-mpd" in run_help(prefix / "bin" / "tof-mpd")


def test_wheel_installs_the_share_files(tmp_path: Path) -> None:
    """The wheel (what ``pip install .`` installs) carries the config files, launch files and
    views into ``<prefix>/share/tof_mpd_ros`` and the report templates into the package, where
    the installed package finds them (built from a copy: the checkout stays clean)."""
    import zipfile

    source = tmp_path / "src"
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(
        ".git", ".venv*", "build", "install", "log", "__pycache__", "*.egg-info", "out",
        "dist", ".pytest_cache", ".ruff_cache", ".hypothesis"))
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                           "--no-build-isolation", "-q", "-w", str(tmp_path / "dist"),
                           str(source)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    [wheel] = (tmp_path / "dist").glob("tof_mpd_ros-*.whl")
    version = wheel.name.split("-")[1]
    share = f"tof_mpd_ros-{version}.data/data/share/tof_mpd_ros/"
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = [f"config/{p.name}" for p in (REPO / "config").glob("*.yaml")]
    expected += [f"config/{p.name}" for p in (REPO / "config").glob("*.xml")]
    expected += [f"launch/{p.name}" for p in (REPO / "launch").glob("*.py")]
    expected += [f"views/{p.name}" for p in VIEWS]
    assert VIEWS and not [e for e in expected if share + e not in names], sorted(names)
    templates = [f"tof_mpd_ros/templates/{name}" for name in TEMPLATES]
    assert TEMPLATES and not [t for t in templates if t not in names], sorted(names)
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    check_installed_templates(site)
