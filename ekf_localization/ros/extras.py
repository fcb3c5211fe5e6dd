"""The optional Python packages some tools need, and the one line that says what to install.

package.xml declares every runtime dependency with its rosdep key (``rosdep install`` installs
it; pyntcore has no key and is named in a comment there); these are optional all the same: a
robot without them still runs ekf_node, sim_node and pure_pursuit_node, and the tools that need
them say what to install.
"""

from __future__ import annotations

import importlib.util
import sys

# module -> (what needs it, how to install it)
EXTRAS: dict[str, tuple[str, str]] = {
    "aiohttp": ("the field view's web server",
                "sudo apt install python3-aiohttp (rosdep key python3-aiohttp), or pip install aiohttp"),
    "ntcore": ("nt_bridge's NetworkTables 4 client",
               "pip install pyntcore (no rosdep key; on Ubuntu 24.04 outside a venv: "
               "python3 -m pip install --user --break-system-packages pyntcore)"),
    "rosbags": ("reading and writing bags",
                "pip install rosbags (rosdep key python3-rosbags-pip; on Ubuntu 24.04 outside a venv: "
                "python3 -m pip install --user --break-system-packages rosbags)"),
}


def missing(module: str) -> bool:
    """Whether ``module`` cannot be imported here."""
    try:
        return importlib.util.find_spec(module) is None
    except (ImportError, ValueError):  # a parent package missing, or sys.modules[module] = None
        return True


def install_hint(tool: str, module: str) -> str:
    """``tool: needs ...: <how to install>`` for the extra ``module``."""
    what, how = EXTRAS[module]
    return f"{tool}: needs the Python package '{module}' ({what}), which is not installed: {how}"


def check(tool: str, *modules: str) -> int:
    """0 when every extra in ``modules`` is installed; else print the first one's hint on stderr
    and return 2 (a tool's exit status)."""
    for module in modules:
        if missing(module):
            print(install_hint(tool, module), file=sys.stderr, flush=True)
            return 2
    return 0
