"""ament_python build for ekf_localization (also pip-installable for a venv)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "ekf_localization"


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=["ekf_localization", "ekf_localization.*", "sim_robot", "sim_robot.*",
                                    "seed_experiments", "seed_experiments.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.rviz") + glob("config/*.json")),
        (f"share/{PACKAGE}/config/paths", glob("config/paths/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/web", glob(f"{PACKAGE}/web/*")),  # field_view's page (also package data)
    ],
    package_data={PACKAGE: ["web/*.html", "web/*.js", "web/*.css"]},
    install_requires=["setuptools"],
    # optional extras, keys in package.xml (python3-rosbags-pip, python3-aiohttp; pyntcore has none):
    # pip install .[bags,view,frc]
    extras_require={"bags": ["rosbags"], "view": ["aiohttp"], "frc": ["pyntcore"]},
    zip_safe=True,
    maintainer="ekf_localization maintainers",
    maintainer_email="maintainers@ekf-localization.invalid",
    description="EKF localization, simulator and pure pursuit for FTC/FRC-style robots",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "ekf_node = ekf_localization.nodes.ekf_node:main",
            "sim_node = sim_robot.ros.sim_node:main",
            "pure_pursuit_node = ekf_localization.nodes.pure_pursuit_node:main",
            "tag_localizer = ekf_localization.nodes.tag_localizer_node:main",
            "nt_bridge = ekf_localization.nodes.nt_bridge_node:main",
            "bag_recorder = ekf_localization.tools.bag_recorder:main",
            "bag_replay = ekf_localization.tools.bag_replay:main",
            "ekf_tune = ekf_localization.tools.ekf_tune:main",
            "ekf_calibrate = ekf_localization.tools.ekf_calibrate:main",
            "ekf_demo = ekf_localization.tools.demo:main",
            "field_view = ekf_localization.tools.field_view:main",
            "tag_detect = ekf_localization.tools.tag_detect:main",
            "tag_layout_from_wpilib = ekf_localization.tools.tag_layout_from_wpilib:main",
            "ekf_experiments = seed_experiments.experiments.cli:main",
        ],
    },
)
