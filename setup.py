"""ament_python build for ekf_localization (also pip-installable for a venv)."""

import compileall
import os
import subprocess
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.install import install

PACKAGE = "ekf_localization"


class InstallWithKernels(install):
    """``install``, then byte-compile the packages and compile the numba kernels into the
    installed tree (colcon build).

    ekf_node's first start then loads machine code instead of compiling for about 30 s, also
    for a user who cannot write the tree (ekf_localization/core/kernel_cache.py). Skipped for a
    staged install (``--root``: a wheel or a package build, whose paths differ at run time) and
    with EKF_LOCALIZATION_SKIP_KERNELS=1. A failure only warns: the kernels compile at first use.
    """

    def run(self) -> None:
        super().run()
        if self.root:
            return
        # setuptools skips byte-compiling under PYTHONDONTWRITEBYTECODE; a read-only install
        # without .pyc files compiles ekf_node's modules from source at every start (~0.1 s)
        for package in ("ekf_localization", "sim_robot"):
            compileall.compile_dir(os.path.join(self.install_lib, package), quiet=1)
        if os.environ.get("EKF_LOCALIZATION_SKIP_KERNELS") == "1":
            return
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            p for p in (self.install_lib, os.environ.get("PYTHONPATH", "")) if p))
        env.pop("NUMBA_CACHE_DIR", None)
        config_dir = os.path.join(self.install_data, "share", PACKAGE, "config")
        done = subprocess.run([sys.executable, "-m", f"{PACKAGE}.tools.warm_kernels", config_dir],
                              env=env, cwd=self.install_lib, check=False)
        if done.returncode != 0:
            print(f"warning: {PACKAGE} kernels not compiled at install (ekf_node compiles them at its "
                  "first start)", file=sys.stderr)

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=["ekf_localization", "ekf_localization.*", "sim_robot", "sim_robot.*"]),
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
    zip_safe=True,
    maintainer="ekf_localization maintainers",
    maintainer_email="maintainers@ekf-localization.invalid",
    description="EKF localization, simulator and pure pursuit for FTC/FRC-style robots",
    license="Apache-2.0",
    tests_require=["pytest"],
    cmdclass={"install": InstallWithKernels},
    entry_points={
        "console_scripts": [
            "ekf_node = ekf_localization.nodes.ekf_node:main",
            "sim_node = sim_robot.ros.sim_node:main",
            "pure_pursuit_node = ekf_localization.nodes.pure_pursuit_node:main",
            "bag_recorder = ekf_localization.tools.bag_recorder:main",
            "bag_replay = ekf_localization.tools.bag_replay:main",
            "ekf_tune = ekf_localization.tools.ekf_tune:main",
            "ekf_demo = ekf_localization.tools.demo:main",
            "field_view = ekf_localization.tools.field_view:main",
            "ekf_experiments = ekf_localization.research.experiments.cli:main",
        ],
    },
)
