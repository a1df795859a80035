"""The manifest of ``semmap batch``: sites, their tours, and what each is built and compared with.

A manifest is YAML (read with ``yaml.safe_load``)::

    defaults:                      # optional: for every site that does not say otherwise
      config: config/build.yaml
      calibration: calib/robot7.yaml
    sites:
      - name: st-marys-ward-3
        previous: /maps/2026-11-20/st-marys-ward-3/maps   # last week's map folders, by tour name
        tours:
          - tours/ward3_night.bag                        # named after the file: ward3_night
          - {tour: tours/ward3_corridor, name: corridor, config: config/corridor.yaml}
      - name: depot-north
        tours: [tours/depot.bag]

Relative paths are taken from the manifest's folder. A tour's map folder is written to
``OUT/<site>/maps/<tour>``; with a previous session (the tour's ``previous``, a map folder, or
the site's ``previous``, a folder of map folders named like the tours) its diff goes to
``OUT/<site>/diffs/<tour>``. So next week's manifest can point ``previous`` at this week's
``OUT/<site>/maps``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from ..config import load_model
from ..errors import ConfigError
from ..io.yamlio import read_yaml

__all__ = ["BuildJob", "Manifest", "load_manifest"]

#: site and tour names become folder names: letters, digits, '.', '_' and '-', not starting with '.'
_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _check_name(v: str | None) -> str | None:
    if v is not None and not _NAME.match(v):
        raise ValueError(f"{v!r} is not a usable folder name (letters, digits, '.', '_', '-'; at most 128)")
    return v


class TourEntry(_Model):
    """One tour of a site."""

    tour: Path = Field(description="a ROS1 .bag, a ROS2 bag folder, or a folder holding one")
    name: str | None = Field(None, description="the map folder's name (default: the bag's file name without "
                                               "its suffix)")
    config: Path | None = Field(None, description="build configuration (default: the site's)")
    calibration: Path | None = Field(None, description="calibration file (default: the site's)")
    previous: Path | None = Field(None, description="the previous session's map folder to diff against")

    _name = field_validator("name")(_check_name)


class SiteEntry(_Model):
    """A building (or a floor): its tours and their settings."""

    name: str
    tours: list[TourEntry] = Field(min_length=1)
    config: Path | None = None
    calibration: Path | None = None
    previous: Path | None = Field(None, description="a folder of the previous session's map folders, one per tour, "
                                                    "named like the tours (e.g. last run's OUT/<site>/maps)")

    _name = field_validator("name")(_check_name)

    @field_validator("tours", mode="before")
    @classmethod
    def _paths_are_tours(cls, v: Any) -> Any:
        if isinstance(v, list):
            return [{"tour": t} if isinstance(t, str) else t for t in v]
        return v


class Defaults(_Model):
    config: Path | None = None
    calibration: Path | None = None


class Manifest(_Model):
    """A ``semmap batch`` manifest (see the module's documentation)."""

    version: int = Field(1, ge=1, le=1)
    defaults: Defaults = Defaults()
    sites: list[SiteEntry] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique(self) -> Manifest:
        seen: set[str] = set()
        for i, site in enumerate(self.sites):
            if site.name in seen:
                raise ValueError(f"sites.{i}.name: {site.name!r} is listed twice")
            seen.add(site.name)
        return self


@dataclass(frozen=True)
class BuildJob:
    """One tour to build, with everything resolved: where it comes from and where it goes."""

    site: str
    name: str
    tour: Path
    config: Path | None
    calibration: Path | None
    #: the previous session's map folder to diff the new map against, if any
    previous: Path | None
    out: Path
    diff_out: Path

    @property
    def key(self) -> str:
        return f"{self.site}/{self.name}"


def _tour_name(path: Path) -> str:
    stem = path.name
    for suffix in (".bag", ".mcap", ".db3"):
        stem = stem.removesuffix(suffix)
    return stem


def load_manifest(path: str | Path, out: str | Path) -> tuple[Manifest, list[BuildJob]]:
    """Read and check a manifest; its jobs, paths resolved, outputs under ``out``.

    Errors name the manifest and the field. A tour or config that does not exist is not an error
    here: that job fails on its own, and the others run.
    """
    path = Path(path).expanduser()
    data = read_yaml(path, "manifest")
    man: Manifest = load_model(Manifest, data, str(path))
    base = Path(os.path.abspath(path)).parent
    out = Path(out).expanduser().resolve()

    def resolve(p: Path | None) -> Path | None:  # absolute, symbolic links kept (a tour is named after its link)
        return None if p is None else Path(os.path.abspath(base / p.expanduser()))

    jobs: list[BuildJob] = []
    for i, site in enumerate(man.sites):
        names: set[str] = set()
        for j, entry in enumerate(site.tours):
            tour = resolve(entry.tour)
            assert tour is not None
            name = entry.name or _tour_name(tour)
            if not _NAME.match(name):
                raise ConfigError(f"{path}: sites.{i}.tours.{j}: the tour's name {name!r} is not a usable folder "
                                  "name; give it a 'name'")
            if name in names:
                raise ConfigError(f"{path}: sites.{i}.tours.{j}: two tours of site {site.name!r} are named "
                                  f"{name!r}; give one a 'name'")
            names.add(name)
            previous = resolve(entry.previous)
            if previous is None and site.previous is not None:
                candidate = resolve(site.previous / name)
                previous = candidate if candidate is not None and candidate.exists() else None
            jobs.append(BuildJob(
                site=site.name, name=name, tour=tour,
                config=resolve(entry.config or site.config or man.defaults.config),
                calibration=resolve(entry.calibration or site.calibration or man.defaults.calibration),
                previous=previous, out=out / site.name / "maps" / name, diff_out=out / site.name / "diffs" / name))
    outs = {job.out for job in jobs}
    for job in jobs:
        for p in (job.tour, job.config, job.calibration):
            if p is not None and (p.resolve() == out or out in p.resolve().parents):
                raise ConfigError(f"{path}: {job.key}: {p} lies inside the output folder {out}")
        if job.previous is not None and job.previous.resolve() in outs:
            raise ConfigError(f"{path}: {job.key}: its previous session {job.previous} is a map folder this batch "
                              "writes; point 'previous' at another run's output")
    return man, jobs
