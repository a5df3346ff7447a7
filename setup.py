"""For colcon (ament_python), which runs setup.py; the project's configuration is pyproject.toml.

The data files are the ROS 2 package face: the ament index marker, package.xml, the launch file
and the parameters YAML, installed under share/ where ``ros2 launch mps_ros ...`` finds them.
"""

from pathlib import Path

from setuptools import find_packages, setup

DATA_FILES = [
    ("share/ament_index/resource_index/packages", ["resource/mps_ros"]),
    ("share/mps_ros", ["package.xml"]),
    ("share/mps_ros/launch", ["launch/press_twin.launch.py"]),
    ("share/mps_ros/config", ["config/press_twin.yaml"]),
]

here = Path(__file__).parent
kwargs = {}
if not (here / "pyproject.toml").exists():
    # `colcon build --symlink-install` runs this from a folder of links without pyproject.toml:
    # take the project's table from the source folder's
    import tomllib

    project = tomllib.loads((Path(__file__).resolve().parent / "pyproject.toml").read_text())
    p = project["project"]
    kwargs = dict(
        name=p["name"],
        version=p["version"],
        description=p["description"],
        python_requires=p["requires-python"],
        install_requires=p["dependencies"],
        packages=find_packages(str(here), include=["mps_core*", "mps_ros*"]),
        package_data={k: list(v) for k, v in project["tool"]["setuptools"]["package-data"].items()},
        entry_points={
            "console_scripts": [f"{k} = {v}" for k, v in p["scripts"].items()],
            **{g: [f"{k} = {v}" for k, v in eps.items()] for g, eps in p.get("entry-points", {}).items()},
        },
    )

dist = setup(data_files=DATA_FILES, **kwargs)

# colcon reads the configured distribution back as Python literals (ast.literal_eval of its
# repr): the requirement on Python from pyproject.toml must be a plain string for that.
for obj in (dist, getattr(dist, "metadata", None)):
    if obj is not None and getattr(obj, "python_requires", None) is not None:
        obj.python_requires = str(obj.python_requires)
