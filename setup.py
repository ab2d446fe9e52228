"""ament_python build script (the layout of ros2/demos ``demo_nodes_py``).

colcon installs the console scripts into ``lib/dcsms_ros`` (see ``setup.cfg``) so that
``ros2 run dcsms_ros <executable>`` finds them; the presets and launch files go to
``share/dcsms_ros``, where the nodes and ``ros2 launch`` look them up via the ament index.
"""

from glob import glob

from setuptools import find_packages, setup

package_name = "dcsms_ros"

#: Node executables: ``ros2 run dcsms_ros <name>`` runs ``dcsms_ros.nodes.<name>:main``.
NODES = (
    "plant_simulator",
    "sensor_decoupling",
    "feedback_controller",
    "feedforward_controller",
    "mode_switch",
    "recorder",
    "excitation",
)

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    # the Fast DDS profile of every process is read from the package directory (ros/transport.py)
    package_data={"dcsms_ros.ros": ["*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", sorted(glob("config/*.yaml"))),
        ("share/" + package_name + "/config/targets", sorted(glob("config/targets/*.yaml"))),
        ("share/" + package_name + "/launch", sorted(glob("launch/*.py"))),
        ("share/" + package_name + "/layouts", sorted(glob("layouts/*"))),
    ],
    install_requires=["setuptools"],
    # numba compiles the batch engine's fast path; without it the engine steps the objects
    extras_require={"fast": ["numba>=0.68"]},
    zip_safe=True,
    maintainer="dcsms_ros maintainers",
    maintainer_email="dcsms@example.com",
    description="Dual-stage cascade spring-mass vibration isolation: simulation, control, "
    "analysis",
    license="Apache-2.0",
    tests_require=["pytest"],
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [f"{n} = {package_name}.nodes.{n}:main" for n in NODES]
        + [f"dcsms = {package_name}.cli:main"],
    },
)
