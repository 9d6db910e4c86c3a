"""ament_python package setup for tof_mpd_ros.

Two install paths are supported and tested:

* ``colcon build`` (ament_python): setup.cfg sends the console scripts to
  ``<prefix>/lib/tof_mpd_ros``, where ``ros2 run`` looks for them;
* ``pip install '.[ros]'`` in a virtual environment: pip puts console scripts in ``<prefix>/bin``
  and ignores setup.cfg's script directory, so wheel builds also install small launchers into
  ``<prefix>/lib/tof_mpd_ros`` that forward to ``bin``. They are left out of colcon builds, where
  they would overwrite the real console scripts.
"""

import sys
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "tof_mpd_ros"
NODE_EXECUTABLES = ("corrector", "collector", "sim_cell")

data_files = [
    ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
    (f"share/{PACKAGE}", ["package.xml"]),
    (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml") + glob("config/*.xml"))),
    (f"share/{PACKAGE}/launch", sorted(glob("launch/*.py"))),
    # Ready-made RViz2 config and Foxglove layout of the live stream (README, "Viewing").
    (f"share/{PACKAGE}/views", sorted(glob("views/*.rviz") + glob("views/*.json"))),
]
if any(command in sys.argv for command in ("bdist_wheel", "editable_wheel")):
    data_files.append((f"lib/{PACKAGE}", [f"resource/launchers/{exe}" for exe in NODE_EXECUTABLES]))

ROS_WHEELS = [
    "ros-jazzy-rclpy",
    "ros-jazzy-std-msgs",
    "ros-jazzy-sensor-msgs",
    "ros-jazzy-geometry-msgs",
    "ros-jazzy-diagnostic-msgs",
    "ros-jazzy-common-interfaces",
    "ros-jazzy-rmw-fastrtps-cpp",
    "ros-jazzy-ament-index-python",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    # templates/: the reports' Jinja2 pages, stylesheet and prose (tof_mpd_ros.templates)
    package_data={PACKAGE: ["py.typed", "data/*.npz", "data/*.json", "data/*.yaml",
                            "templates/*.html", "templates/*.css", "templates/*.txt"]},
    data_files=data_files,
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.26",
        "scipy>=1.11",
        # the CPU wheel (any looser pin pulls a multi-GB CUDA build); also the version whose
        # private torch.ops.mkldnn._linear_pointwise and Tensor._version are tested
        "torch==2.13.0",
        "opencv-contrib-python-headless>=4.8",
        "numba>=0.59",
        "scikit-learn>=1.4",
        "mcap>=1.2",
        # pinned: recordings/writer.py uses its private mcap_ros2._dynamic (test_private_apis)
        "mcap-ros2-support==0.6.0",
        "ur-rtde>=1.5",
        "pyyaml>=6",
        "tqdm>=4.66",
        "matplotlib>=3.8",
        "jinja2>=3.1",
        # the fcn kind's U-Net on 2+ CPU threads (correction/fcn_onnx.py; torch is the
        # fallback and the reference); onnx builds its graph from the weights
        "onnxruntime>=1.20",
        "onnx>=1.16",
    ],
    extras_require={
        "ros": ROS_WHEELS,
        # path-tracer reference (tof_mpd_ros.sim.pathtrace, benchmarks/render_golden_frames.py);
        # its CPU variant needs a system LLVM library (Debian: libllvm19). Tests do not need it.
        "pathtrace": ["mitsuba==3.9.1", "mitransient==1.3.1", "drjit==1.5.0"],
        "test": [
            "pytest>=8",
            "pytest-timeout>=2.3",
            "hypothesis>=6",
            "rosbags>=0.10",
            "colcon-common-extensions>=0.3",
            "ruff>=0.5",
        ],
    },
    zip_safe=False,
    maintainer="tof_mpd_ros developers",
    maintainer_email="tof-mpd-ros@example.com",
    description="Multipath distortion removal for ToF range images on a robot arm (ROS 2).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "tof-mpd = tof_mpd_ros.cli.main:main",
            "corrector = tof_mpd_ros.nodes.corrector:main",
            "collector = tof_mpd_ros.nodes.collector:main",
            "sim_cell = tof_mpd_ros.nodes.sim_cell:main",
        ],
    },
)
