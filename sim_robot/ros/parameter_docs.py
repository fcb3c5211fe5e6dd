"""sim_node's parameter table in docs/simulator.md, rendered from its schema (a test fails when
they differ), as :mod:`ekf_localization.tools.parameter_docs` renders the other nodes' tables.

    python -m sim_robot.ros.parameter_docs          # check: exit 1 if the table is stale
    python -m sim_robot.ros.parameter_docs --write  # rewrite it
"""

from __future__ import annotations

import sys

from ekf_localization.tools import parameter_docs
from sim_robot.ros.sim_params import SIM_PARAMETERS

TABLES: parameter_docs.Tables = {"sim_node": ("simulator.md", [("", SIM_PARAMETERS)])}


def stale(write: bool = False) -> list[str]:
    """["simulator.md"] when its table differs from the schema (rewritten with ``write``), else []."""
    return parameter_docs.stale(write, TABLES)


def main(argv: list[str] | None = None) -> int:
    return parameter_docs.main(argv, TABLES, __doc__.splitlines()[0])


if __name__ == "__main__":
    sys.exit(main())
