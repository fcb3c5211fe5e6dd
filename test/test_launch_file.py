"""The launch file names executables and files that exist; it parses where `launch` is installed."""

from __future__ import annotations

import ast
import importlib.util
import re
from pathlib import Path

import pytest
from ros_helpers import REPO

LAUNCH = REPO / "launch" / "ekf_localization.launch.py"


def _string_constants() -> list[str]:
    tree = ast.parse(LAUNCH.read_text())
    return [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def test_launch_names_existing_executables_and_files() -> None:
    consts = _string_constants()
    entry_points = set(re.findall(r'"(\w+) = [\w.]+:main"', (REPO / "setup.py").read_text()))
    executables = {c for c in consts if c.endswith("_node") and " " not in c}
    assert executables == {"sim_node", "ekf_node", "pure_pursuit_node"}
    assert executables <= entry_points
    yamls = [c for c in consts if c.endswith(".yaml")]
    assert len(yamls) >= 4
    for name in yamls:
        path = REPO / "config" / name
        if not path.exists():  # os.path.join(config, "paths", "x.yaml") splits the name
            path = REPO / "config" / "paths" / name
        assert path.is_file(), f"launch file names missing config {name}"


def test_launch_description_builds(monkeypatch: pytest.MonkeyPatch) -> None:
    if importlib.util.find_spec("launch") is None or importlib.util.find_spec("launch_ros") is None:
        pytest.skip("launch/launch_ros are not on PyPI; this runs on a real ROS 2 install")
    import ament_index_python.packages as aip

    monkeypatch.setattr(aip, "get_package_share_directory", lambda _pkg: str(REPO))
    spec = importlib.util.spec_from_file_location("ekf_launch", LAUNCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    ld = mod.generate_launch_description()
    names = [a.name for a in ld.get_launch_arguments()]
    assert {"use_sim", "use_sim_time", "ekf_params", "path_file"} <= set(names)
    for arg in ld.get_launch_arguments():
        default = arg.default_value
        if default and str(default[0].text).endswith(".yaml"):
            assert Path(default[0].text).is_file()
