"""WPILib's packed struct serialization (wpiutil's "Packed Struct Serialization Specification" 1.0).

A struct's schema is a text list of C-like declarations separated by ``;`` (``double speed;
Rotation2d angle``); its data are the members in schema order, each little-endian, with no
padding, a nested struct in place. NetworkTables names a struct topic's type ``struct:<Name>``
(an array of them ``struct:<Name>[]``: the structs back to back) and publishes each schema on
``/.schema/struct:<Name>``. :func:`struct_dtype` turns a schema into a packed numpy structured
dtype, so ``np.frombuffer`` decodes a value by the member names the schema gives.

Bit-field members are refused (none of the structs read here has one); an enum specification
is read as its integer type.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import numpy as np

STRUCT_PREFIX = "struct:"
SCHEMA_TOPIC_PREFIX = "/.schema/"
SCHEMA_TYPE = "structschema"  # the type string of a schema topic

# the spec's built-in types -> numpy (little-endian)
_BASIC: dict[str, str] = {
    "bool": "?", "char": "S1", "int8": "i1", "int16": "<i2", "int32": "<i4", "int64": "<i8",
    "uint8": "u1", "uint16": "<u2", "uint32": "<u4", "uint64": "<u8",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}
_ENUM = re.compile(r"^(?:enum\s*)?\{[^}]*\}\s*|^enum\s+")
_DECL = re.compile(r"^(?P<type>\S+)\s+(?P<name>[^\s\[:]+)\s*(?:\[\s*(?P<count>\d+)\s*\])?\s*(?P<bits>:.*)?$")
MAX_NESTING = 16

# WPILib's schemas of the structs the bridge reads (wpimath's Struct definitions), used when the
# robot has not published its own on /.schema/
WPILIB_SCHEMAS: dict[str, str] = {
    "SwerveModuleState": "double speed;Rotation2d angle",
    "SwerveModulePosition": "double distance;Rotation2d angle",
    "Rotation2d": "double value",
    "Rotation3d": "Quaternion q",
    "Quaternion": "double w;double x;double y;double z",
}


class StructError(ValueError):
    """A schema that cannot be read, or data that do not fit it."""


def struct_dtype(name: str, schemas: Mapping[str, str], _depth: int = 0) -> np.dtype:
    """The packed numpy dtype of struct ``name``, its schema and its nested structs' from ``schemas``."""
    if _depth > MAX_NESTING:
        raise StructError(f"struct {name}: nested more than {MAX_NESTING} deep (a cycle?)")
    if name not in schemas:
        raise StructError(f"no schema for struct {name}")
    fields: list[tuple] = []
    for decl in schemas[name].split(";"):
        decl = _ENUM.sub("", decl.strip()).strip()
        if not decl:
            continue  # empty declarations are allowed
        m = _DECL.match(decl)
        if m is None:
            raise StructError(f"struct {name}: cannot read the declaration '{decl}'")
        if m["bits"] is not None:
            raise StructError(f"struct {name}: bit-field '{decl}' not supported")
        type_name = m["type"]
        base = (np.dtype(_BASIC[type_name]) if type_name in _BASIC
                else struct_dtype(type_name, schemas, _depth + 1))
        count = m["count"]
        if count is None:
            fields.append((m["name"], base))
        elif type_name == "char":
            fields.append((m["name"], np.dtype(f"S{int(count)}")))
        else:
            fields.append((m["name"], base, (int(count),)))
    if not fields:
        raise StructError(f"struct {name}: empty schema")
    try:
        return np.dtype(fields)  # packed: numpy adds no padding unless align=True
    except (TypeError, ValueError) as exc:  # e.g. a member named twice
        raise StructError(f"struct {name}: {exc}") from exc


def struct_name(type_string: str) -> tuple[str, bool] | None:
    """(struct name, is an array) of a NetworkTables type string ``struct:Name`` / ``struct:Name[]``."""
    if not type_string.startswith(STRUCT_PREFIX):
        return None
    name = type_string[len(STRUCT_PREFIX):]
    return (name[:-2], True) if name.endswith("[]") else (name, False)


def decode(data: bytes, dtype: np.dtype) -> np.ndarray:
    """The structs packed back to back in ``data`` (a 1-D structured array); raises StructError
    when the size is not a whole number of structs."""
    if len(data) % dtype.itemsize:
        raise StructError(f"{len(data)} bytes is not a whole number of {dtype.itemsize}-byte structs")
    return np.frombuffer(bytes(data), dtype=dtype)


def float_field(values: np.ndarray, path: str) -> np.ndarray:
    """Member ``path`` ("angle.value") of decoded structs as float64; StructError when the schema
    has no such floating-point member."""
    out = values
    for part in path.split("."):
        names = out.dtype.names or ()
        if part not in names:
            raise StructError(f"the struct has no member '{path}' (members: {', '.join(names) or 'none'})")
        out = out[part]
    if not np.issubdtype(out.dtype, np.floating) or out.ndim != values.ndim:
        raise StructError(f"member '{path}' is {out.dtype}, not a floating-point number")
    return np.asarray(out, dtype=float)

