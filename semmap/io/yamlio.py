"""YAML out: readable, safe, and short lists of numbers on one line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ..errors import ConfigError

__all__ = ["dump_yaml", "read_yaml", "write_yaml"]


def read_yaml(path: str | Path, what: str = "file") -> Any:
    """Read YAML with ``yaml.safe_load``; errors name the file (and the line, if YAML is malformed)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read {what} ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not a YAML {what} (not UTF-8 text: byte {exc.start})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}:" if mark is not None else ""
        raise ConfigError(f"{p}:{where} malformed YAML in {what}") from None
    except RecursionError:
        raise ConfigError(f"{p}: malformed YAML in {what} (nested too deep)") from None


class _Dumper(yaml.SafeDumper):
    pass


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    # numbers on one line; lists of 2D points on one line; matrices one row per line
    flat = all(isinstance(v, (int, float, bool)) or v is None for v in data)
    points = all(isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=bool(data) and (flat or points))


def _represent_float(dumper: yaml.SafeDumper, data: float) -> yaml.Node:
    return yaml.SafeDumper.represent_float(dumper, data + 0.0)  # no "-0.0"


_Dumper.add_representer(list, _represent_list)
_Dumper.add_representer(float, _represent_float)


def dump_yaml(data: Any) -> str:
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False, allow_unicode=True, width=110)


def write_yaml(path: str | Path, data: Any, header: str = "") -> Path:
    p = Path(path)
    p.write_text(header + dump_yaml(data), encoding="utf-8")
    return p
