"""Compile the numba kernels the shipped configurations use, into numba's cache.

    python -m ekf_localization.tools.warm_kernels [CONFIG_DIR]

Run by ``scripts/setup_env.sh`` (the venv) and by ``setup.py``'s install step (a colcon
install tree), so that ekf_node's first start loads machine code instead of compiling it
(see ``core/kernel_cache.py``). Cheap when the cache is warm.
"""

from __future__ import annotations

import sys
from pathlib import Path


def warm(config_dir: Path) -> int:
    """Build a Localizer for each ``ekf*.yaml`` in ``config_dir`` and run its kernels once."""
    from ekf_localization.models.registry import make_localizer
    from ekf_localization.ros.ekf_parameters import load_ekf_config

    configs = sorted(config_dir.glob("ekf*.yaml"))
    for yaml in configs:
        make_localizer(load_ekf_config(yaml)).warm_up()
    return len(configs)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    default = Path(__file__).resolve().parents[2] / "config"
    config_dir = Path(args[0]) if args else default
    if not config_dir.is_dir():
        print(f"warm_kernels: {config_dir} is not a folder of ekf*.yaml files", file=sys.stderr)
        return 2
    print(f"warm_kernels: {warm(config_dir)} configurations compiled or loaded from {config_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
