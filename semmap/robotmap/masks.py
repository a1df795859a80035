"""nav2 costmap filter masks from the semantic layers, and the parameters that load them.

* **Keepout** (``keepout_mask.yaml``, trinary): the floor under movable furniture: each object's
  footprint (a table at LiDAR height is four legs a robot would try to drive between), grown by
  ``keepout_margin_m``. nav2's ``KeepoutFilter`` makes the mask's occupied cells lethal.
* **Speed** (``speed_mask.yaml``, raw): a speed limit in per cent of the robot's maximum within
  ``speed_margin_m`` of movable furniture and of where people were seen. Raw mode writes the limit
  itself as the cell value, which nav2's ``SpeedFilter`` turns into a limit with
  ``base + multiplier * value`` (``type: 1``, base 0, multiplier 1: the value is the per cent); 0 means
  no limit. Where both apply, the lower limit wins.
* ``costmap_filters.yaml``: the ``filter_mask_server`` and ``costmap_filter_info_server``
  parameters for both masks, and the costmap plugin entries, ready for nav2.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..geometry import dilate_mask
from ..io.yamlio import write_yaml
from ..records import GridSpec

__all__ = ["MaskSettings", "keepout_mask", "speed_mask", "write_filter_params", "write_speed_mask"]


@dataclass(frozen=True)
class MaskSettings:
    """What the filter masks hold (metres, per cent of the robot's maximum speed)."""

    keepout_margin_m: float = 0.10
    #: speed limit near movable furniture (per cent; 0: no speed zone there)
    speed_near_furniture: int = 50
    #: speed limit where people were seen (per cent; 0: no speed zone there)
    speed_near_people: int = 30
    speed_margin_m: float = 0.5


def _grow(mask: NDArray[np.bool_], metres: float, res: float) -> NDArray[np.bool_]:
    return dilate_mask(mask, metres / res)


def keepout_mask(spec: GridSpec, footprints: list[NDArray[np.float64]], semi: NDArray[np.bool_],
                 margin_m: float) -> NDArray[np.bool_]:
    """Cells to keep out of: every footprint polygon (x, y in the grid's frame) and every cell
    flagged movable, grown by ``margin_m``."""
    img = np.zeros(spec.shape, np.uint8)
    for fp in footprints:
        if fp.shape[0] >= 3:
            pts = np.round(((fp - [spec.origin_x, spec.origin_y]) / spec.resolution - 0.5) * 16).astype(np.int32)
            cv2.fillPoly(img, [pts], 1, lineType=cv2.LINE_8, shift=4)
    return _grow((img > 0) | semi, margin_m, spec.resolution)


def speed_mask(spec: GridSpec, furniture: NDArray[np.bool_], people: NDArray[np.bool_],
               st: MaskSettings) -> NDArray[np.uint8]:
    """Per cent of the maximum speed per cell (0: no limit)."""
    out = np.zeros(spec.shape, np.uint8)
    for cells, pct in ((furniture, st.speed_near_furniture), (people, st.speed_near_people)):
        if pct <= 0:
            continue
        zone = _grow(cells, st.speed_margin_m, spec.resolution)
        lower = zone & ((out == 0) | (out > pct))
        out[lower] = pct
    return out


def write_speed_mask(yaml_path: Path, spec: GridSpec, percent: NDArray[np.uint8]) -> Path:
    """The speed mask as a raw map_server map: the cell value is the limit in per cent, 0 no limit."""
    image = yaml_path.with_suffix(".png")
    if not cv2.imwrite(str(image), np.ascontiguousarray(np.flipud(percent))):
        raise OSError(0, "cannot write the mask image", str(image))
    return write_yaml(yaml_path, {"image": image.name, "mode": "raw", "resolution": float(spec.resolution),
                                  "origin": [float(spec.origin_x), float(spec.origin_y), 0.0], "negate": 0,
                                  "occupied_thresh": 0.65, "free_thresh": 0.196})


def write_filter_params(path: Path, keepout_yaml: str | None, speed_yaml: str | None) -> Path:
    """nav2 parameters for the masks: one filter_mask_server and costmap_filter_info_server per mask, and
    the filters to add to a costmap's plugins."""
    doc: dict[str, object] = {}
    filters: list[str] = []
    plugins: dict[str, object] = {}
    for name, yaml_name, ftype, base, mult, plugin in (
            ("keepout", keepout_yaml, 0, 0.0, 1.0, "nav2_costmap_2d::KeepoutFilter"),
            ("speed", speed_yaml, 1, 0.0, 1.0, "nav2_costmap_2d::SpeedFilter")):
        if yaml_name is None:
            continue
        doc[f"{name}_filter_mask_server"] = {"ros__parameters": {
            "frame_id": "map", "topic_name": f"/{name}_filter_mask", "yaml_filename": yaml_name}}
        doc[f"{name}_costmap_filter_info_server"] = {"ros__parameters": {
            "type": ftype, "filter_info_topic": f"/{name}_costmap_filter_info",
            "mask_topic": f"/{name}_filter_mask", "base": base, "multiplier": mult}}
        entry: dict[str, object] = {"plugin": plugin, "enabled": True,
                                    "filter_info_topic": f"/{name}_costmap_filter_info"}
        if name == "speed":
            entry["speed_limit_topic"] = "/speed_limit"
        plugins[f"{name}_filter"] = entry
        filters.append(f"{name}_filter")
    doc["global_costmap"] = {"global_costmap": {"ros__parameters": {"filters": filters, **plugins}}}
    return write_yaml(path, doc, "# nav2 parameters for semmap's costmap filter masks (yaml_filename: give the full "
                                 "path on the robot)\n")
