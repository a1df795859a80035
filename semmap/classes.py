"""Class lists and the class → mobility table, read from ``config/classes.yaml``."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Mapping

from .errors import ConfigError
from .records import Mobility

__all__ = ["ClassTable", "config_dir", "load_class_table"]


def config_dir() -> Path:
    """The directory holding semmap's shipped configuration (``classes.yaml``...).

    In a wheel it is packaged as ``semmap/_config``; in a source checkout it is
    the repository's ``config/``.
    """
    here = Path(__file__).resolve().parent
    for candidate in (here / "_config", here.parent / "config"):
        if (candidate / "classes.yaml").is_file():
            return candidate
    raise ConfigError(f"semmap's configuration folder is missing (looked in {here / '_config'})")


@dataclass(frozen=True)
class ClassTable:
    """Named class lists and the mobility of every known class name."""

    class_lists: Mapping[str, tuple[str, ...]]
    mobility: Mapping[str, Mobility]
    source: str = "<memory>"
    #: typical length of an object of the class at floor level, m (the legs of a table span
    #: its top): cleaning joins a class's cells into objects up to about this size
    sizes: Mapping[str, float] = field(default_factory=dict)

    def size_of(self, name: str, default: float = 1.0) -> float:
        """Typical floor-level length of an object of class ``name`` (``default`` when not listed), m."""
        return float(self.sizes.get(name, default))

    def names(self, list_name: str) -> tuple[str, ...]:
        try:
            return self.class_lists[list_name]
        except KeyError:
            known = ", ".join(sorted(self.class_lists))
            raise ConfigError(
                f"{self.source}: unknown class list {list_name!r} (known: {known})"
            ) from None

    def mobility_of(self, name: str) -> Mobility:
        try:
            return self.mobility[name]
        except KeyError:
            raise ConfigError(
                f"{self.source}: class {name!r} has no mobility; add it under 'mobility:'"
            ) from None


def _parse(data: object, source: str) -> ClassTable:
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping with 'class_lists' and 'mobility'")
    unknown = set(data) - {"class_lists", "mobility", "sizes"}
    if unknown:
        raise ConfigError(f"{source}: unknown key(s) {sorted(unknown)}")
    lists_raw = data.get("class_lists") or {}
    mob_raw = data.get("mobility") or {}
    if not isinstance(lists_raw, dict) or not isinstance(mob_raw, dict):
        raise ConfigError(f"{source}: 'class_lists' and 'mobility' must be mappings")
    mobility: dict[str, Mobility] = {}
    for name, value in mob_raw.items():
        try:
            mobility[str(name)] = Mobility.parse(str(value))
        except ValueError as exc:
            raise ConfigError(f"{source}: mobility.{name}: {exc}") from None
    lists: dict[str, tuple[str, ...]] = {}
    for list_name, names in lists_raw.items():
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise ConfigError(f"{source}: class_lists.{list_name} must be a list of names")
        missing = [n for n in names if n not in mobility]
        if missing:
            raise ConfigError(
                f"{source}: class_lists.{list_name}: no mobility for {missing[:5]}"
            )
        lists[str(list_name)] = tuple(names)
    sizes_raw = data.get("sizes") or {}
    if not isinstance(sizes_raw, dict):
        raise ConfigError(f"{source}: 'sizes' must be a mapping of class name to metres")
    sizes: dict[str, float] = {}
    for name, value in sizes_raw.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < float(value) <= 100:
            raise ConfigError(f"{source}: sizes.{name}: expected a length in metres in (0, 100], got {value!r}")
        if str(name) not in mobility:
            raise ConfigError(f"{source}: sizes.{name}: not a class under 'mobility:'")
        sizes[str(name)] = float(value)
    return ClassTable(class_lists=lists, mobility=mobility, source=source, sizes=sizes)


def load_class_table(path: str | Path | None = None) -> ClassTable:
    """Load a class table; ``None`` loads the shipped ``config/classes.yaml``."""
    p = Path(path) if path is not None else config_dir() / "classes.yaml"
    return _load_cached(str(p.resolve()))


@lru_cache(maxsize=8)
def _load_cached(path: str) -> ClassTable:
    from .io.yamlio import read_yaml

    return _parse(read_yaml(path, "class table"), path)
