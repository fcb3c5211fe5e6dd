"""The parameter tables in docs/, rendered from the schemas (a test fails when they differ).

Each table sits between ``<!-- parameters:KEY begin -->`` and ``<!-- parameters:KEY end -->``
in its document; everything outside the markers is written by hand. This module renders
ekf_localization's nodes' tables; the simulator's (docs/simulator.md) are sim_robot's own,
rendered the same way by :mod:`sim_robot.ros.parameter_docs` (ekf_localization never imports
sim_robot).

    python -m ekf_localization.tools.parameter_docs          # check: exit 1 if a table is stale
    python -m ekf_localization.tools.parameter_docs --write  # rewrite the tables
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from ekf_localization.ros.ekf_parameters import EKF_PARAMETERS
from ekf_localization.ros.field_view_parameters import FIELD_VIEW_PARAMETERS
from ekf_localization.ros.input_parameters import INPUT_PARAMETERS, KIND_PARAMETERS
from ekf_localization.ros.nt_bridge_parameters import NT_BRIDGE_PARAMETERS
from ekf_localization.ros.parameters import REQUIRED, Entry, Schema
from ekf_localization.ros.pure_pursuit_parameters import PURE_PURSUIT_PARAMETERS
from ekf_localization.ros.tag_localizer_parameters import TAG_LOCALIZER_PARAMETERS

DOCS = Path(__file__).resolve().parents[2] / "docs"

# key -> (document, [(how a name is shown: prefix, schema), ...])
Tables = dict[str, tuple[str, list[tuple[str, Schema]]]]
TABLES: Tables = {
    "ekf_node": ("ekf_node.md", [("", EKF_PARAMETERS)]),
    "ekf_node_inputs": ("ekf_node.md", [("<input>_", INPUT_PARAMETERS)]
                        + [(f"{kind}N_", schema) for kind, schema in KIND_PARAMETERS.items()]),
    "pure_pursuit_node": ("pure_pursuit.md", [("", PURE_PURSUIT_PARAMETERS)]),
    "field_view": ("field_view.md", [("", FIELD_VIEW_PARAMETERS)]),
    "tag_localizer": ("tag_localizer.md", [("", TAG_LOCALIZER_PARAMETERS)]),
    "nt_bridge": ("frc_bridge.md", [("", NT_BRIDGE_PARAMETERS)]),
}


def _value(v: Any) -> str:
    if v is REQUIRED:
        return "**required**"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "∞" if math.isinf(v) else f"{v:.6g}" + ("" if "." in f"{v:.6g}" or "e" in f"{v:.6g}" else ".0")
    if isinstance(v, str):
        return f"`{v}`"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x).strip("`") for x in v) + "]"
    return str(v)


def _row(prefix: str, e: Entry) -> str:
    default = e.default_doc if e.default_doc is not None else _value(e.default)
    cells = [f"`{prefix}{e.name}`", e.type, default, e.unit or "–", e.doc]
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


def render_table(parts: list[tuple[str, Schema]]) -> str:
    lines = ["| parameter | type | default | unit | meaning |", "|---|---|---|---|---|"]
    for prefix, schema in parts:
        lines += [_row(prefix, e) for e in schema.entries]
    return "\n".join(lines)


def _markers(key: str) -> tuple[str, str]:
    return f"<!-- parameters:{key} begin -->", f"<!-- parameters:{key} end -->"


def rendered(text: str, key: str, tables: Tables | None = None) -> str:
    """``text`` with table ``key`` of ``tables`` (default :data:`TABLES`) replaced by the schema's."""
    begin, end = _markers(key)
    start, stop = text.find(begin), text.find(end)
    if start < 0 or stop < start:
        raise ValueError(f"no '{begin}' ... '{end}' markers")
    parts = (TABLES if tables is None else tables)[key][1]
    return text[:start + len(begin)] + "\n" + render_table(parts) + "\n" + text[stop:]


def stale(write: bool = False, tables: Tables | None = None) -> list[str]:
    """The documents whose ``tables`` (default :data:`TABLES`) differ from their schemas
    (rewritten with ``write``)."""
    tables = TABLES if tables is None else tables
    out = []
    for doc in sorted({d for d, _ in tables.values()}):
        path = DOCS / doc
        text = path.read_text()
        new = text
        for key, (d, _) in tables.items():
            if d == doc:
                new = rendered(new, key, tables)
        if new != text:
            out.append(doc)
            if write:
                path.write_text(new)
    return out


def main(argv: list[str] | None = None, tables: Tables | None = None, description: str | None = None) -> int:
    parser = argparse.ArgumentParser(description=description or __doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="rewrite the stale tables")
    args = parser.parse_args(argv)
    docs = stale(write=args.write, tables=tables)
    for doc in docs:
        print(f"docs/{doc}: parameter tables {'rewritten' if args.write else 'differ from the schemas'}")
    return 1 if docs and not args.write else 0


if __name__ == "__main__":
    sys.exit(main())
