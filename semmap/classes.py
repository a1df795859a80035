"""Class lists and the class → mobility table, read from ``config/classes.yaml``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, field_validator, model_validator

from .config import load_model
from .errors import ConfigError
from .records import Mobility

__all__ = ["ClassTable", "ClassTableFile", "config_dir", "load_class_table"]


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


def _mobility(v: Any) -> Mobility:
    return v if isinstance(v, Mobility) else Mobility.parse(str(v))


def _null_is_empty(v: Any) -> Any:
    return {} if v is None else v


class ClassTableFile(BaseModel):
    """The schema of ``classes.yaml``: named class lists, every class's mobility, typical sizes."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    class_lists: dict[str, tuple[str, ...]] = Field(default_factory=dict,
                                                    description="list name → class names (label value k: names[k-1])")
    mobility: dict[str, Annotated[Mobility, BeforeValidator(_mobility)]] = Field(
        default_factory=dict, description="class name → static, semi_static or dynamic")
    sizes: dict[str, Annotated[float, Field(gt=0, le=100, strict=True)]] = Field(
        default_factory=dict, description="class name → typical floor-level length of an object, m")

    _nulls = field_validator("class_lists", "mobility", "sizes", mode="before")(_null_is_empty)

    @model_validator(mode="after")
    def _classes_have_a_mobility(self) -> ClassTableFile:
        for list_name, names in self.class_lists.items():
            missing = [n for n in names if n not in self.mobility]
            if missing:
                raise ValueError(f"class_lists.{list_name}: no mobility for {missing[:5]}")
        for name in self.sizes:
            if name not in self.mobility:
                raise ValueError(f"sizes.{name}: not a class under 'mobility:'")
        return self


def _parse(data: object, source: str) -> ClassTable:
    f = load_model(ClassTableFile, data, source)
    return ClassTable(class_lists=f.class_lists, mobility=f.mobility, source=source, sizes=f.sizes)


def load_class_table(path: str | Path | None = None) -> ClassTable:
    """Load a class table; ``None`` loads the shipped ``config/classes.yaml``."""
    p = Path(path) if path is not None else config_dir() / "classes.yaml"
    return _load_cached(str(p.resolve()))


@lru_cache(maxsize=8)
def _load_cached(path: str) -> ClassTable:
    from .io.yamlio import read_yaml

    return _parse(read_yaml(path, "class table"), path)
