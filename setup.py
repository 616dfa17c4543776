from glob import glob

from setuptools import find_packages, setup

package_name = "sfs_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench"]),
    package_data={"sfs_ros.core.pictures": ["viewer.html", "viewer.js"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
        ("share/" + package_name + "/urdf", glob("urdf/*.urdf") + glob("urdf/*.urdf.xacro")),
    ],
    python_requires=">=3.10",
    # Lower bounds: the versions of requirements-min.txt, with which the tests pass
    # (Ubuntu 24.04's, the base of ROS 2 Jazzy and Kilted, where it has them; not OpenCV,
    # whose 4.6 there runs all but sfs-calibrate: see requirements-min.txt).
    install_requires=[
        "numpy>=1.26.4,<3",
        # OpenCV 5 has just been released; the 4.x API is what we test against.
        "opencv-python-headless>=4.10.0.84,<5",
        "scipy>=1.11.4",
        "scikit-image>=0.22.0",
        "numba>=0.59.1",
        "trimesh>=5.0.0",
        "pyyaml>=6.0.1",
        "pyserial>=3.5",
        "pillow>=10.2.0",
        "rosbags>=0.11.9",
    ],
    extras_require={"test": ["pytest>=8", "ruff>=0.6", "xacro>=2.1.1"]},
    zip_safe=True,
    maintainer="sfs_ros maintainers",
    maintainer_email="maintainers@sfs-ros.invalid",
    description="Turntable + C-arm camera cell as a 3-D scanner (shape from silhouette).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sfs-reconstruct = sfs_ros.cli.reconstruct:main",
            "sfs-demo = sfs_ros.cli.demo:main",
            "sfs-simulate = sfs_ros.cli.simulate:main",
            "sfs-warm-up = sfs_ros.cli.warm_up:main",
            "sfs-export = sfs_ros.cli.export:main",
            "sfs-texture = sfs_ros.cli.texture:main",
            "sfs-calibrate = sfs_ros.cli.calibrate:main",
            "sfs-cell = sfs_ros.cli.cell:main",
            "sfs-ctl = sfs_ros.cli.ctl:main",
            "sfs-camera = sfs_ros.nodes.camera_node:main",
            "sfs-scan = sfs_ros.nodes.scan_node:main",
            "sfs-recorder = sfs_ros.nodes.recorder_node:main",
            "sfs-replay = sfs_ros.cli.replay:main",
            "sfs-segmentation = sfs_ros.nodes.segmentation_node:main",
            "sfs-motor = sfs_ros.nodes.motor_node:main",
            "sfs-mock-hardware = sfs_ros.nodes.mock_hardware_node:main",
            "sfs-carving = sfs_ros.nodes.carving_node:main",
            "sfs-meshing = sfs_ros.nodes.meshing_node:main",
            "sfs-state-publisher = sfs_ros.nodes.tf_node:main",
            "sfs-calibration = sfs_ros.nodes.calibration_node:main",
            "sfs-lifecycle-manager = sfs_ros.nodes.lifecycle_manager_node:main",
        ],
    },
)
