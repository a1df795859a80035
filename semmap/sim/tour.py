"""``semmap simulate``: write a simulated tour as a real bag, with exact ground truth beside it.

Output folder (written to a temporary folder, then moved into place)::

    OUT/
      tour.yaml                 what is where: topics, frames, rates, seed, files
      config.yaml               the effective simulator configuration
      calibration.yaml          camera intrinsics and T_cam_lidar
      <name>.bag | <name>/      the bag (ROS1 file, or ROS2 folder with mcap / sqlite3)
      ground_truth/
        world.yaml              the world, reloadable with --scenario world.yaml
        occupancy.{pgm,yaml}    static ∪ semi-static at LiDAR height (map_server)
        static.{pgm,yaml}       static structure only
        semi_static.{pgm,yaml}  movable furniture only
        people_swept.{pgm,yaml} cells people's bodies covered at some time
        people_standing.{pgm,yaml} cells people's legs covered at LiDAR height while standing still 5 s or more
        objects.json            per object and person: class, cells, LiDAR hits, camera images, standing time
        trajectory.tum          true base_link poses in the world frame
        odometry.tum            the wheel odometry as published (odom frame)
        beams.npz               true range, instance, class and mobility of every beam
        changes.{pgm,yaml,json} for change scenarios: what differs from the base world
      preview/
        world.png               top-down world, trajectory and odometry
        camera.png              one camera image, its labels, and the scan projected
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..classes import load_class_table
from ..config import SimConfig, load_model, load_yaml, merge_overrides
from ..errors import ConfigError, SemmapError
from ..geometry import se2_compose, se2_to_se3, se3_from_xyz_rpy, se3_inverse
from ..io.atomic import atomic_dir
from ..io.bag import BAG_FORMATS, BagFormat, BagWriter
from ..io.calibration import write_calibration
from ..io.mapserver import write_map
from ..io.tum import write_tum
from ..io.yamlio import write_yaml
from ..records import Calibration, CameraIntrinsics, Image, Mobility, Scan
from .groundtruth import (
    MIN_STANDING_S,
    change_mask,
    grid_for_world,
    object_cells,
    occupancy_layers,
    people_standing,
    people_swept,
    standing_stretches,
)
from .procedural import person_role
from .raycast import PartSet
from .robot import check_clearance, people_clearance, plan_tour, simulate_odometry
from .scenarios import Scenario, get_scenario
from .sensors import CameraSim, LidarSim
from .world import World, load_world, world_to_dict

__all__ = ["SimulationResult", "effective_config", "resolve_scenario", "simulate"]

log = logging.getLogger(__name__)

#: an object counts as seen in a camera image when this many label pixels are its own
_MIN_VISIBLE_PX = 20
#: a scan is painted by the camera image nearest it when that frame is stamped within this, s
_PAINT_WINDOW_S = 0.1

ProgressFn = Callable[[int, int], None]


@dataclass(frozen=True)
class SimulationResult:
    """What :func:`simulate` wrote."""

    out: Path
    bag: Path
    format: str
    scenario: str
    seed: int
    duration_s: float
    topics: dict[str, int] = field(default_factory=dict)
    elapsed_s: float = 0.0


def resolve_scenario(scenario: str | Path | Scenario | World) -> Scenario:
    """A built-in scenario name, a world YAML path, or a ready world."""
    if isinstance(scenario, Scenario):
        return scenario
    if isinstance(scenario, World):
        return Scenario(scenario)
    text = str(scenario)
    if text.endswith((".yaml", ".yml")) or Path(text).is_file():
        return Scenario(load_world(text))
    return get_scenario(text)


def effective_config(scenario: Scenario, config: SimConfig | dict[str, Any] | str | Path | None) -> SimConfig:
    """Defaults, then the scenario's overrides, then the user's (file or dict)."""
    if isinstance(config, SimConfig):
        user, source = config.model_dump(exclude_unset=True), "config"
    elif isinstance(config, (str, Path)):
        user, source = load_yaml(config) or {}, str(config)
        if not isinstance(user, dict):
            raise ConfigError(f"{config}: expected a mapping at the top level")
    else:
        user, source = dict(config or {}), "config"
    merged = merge_overrides(scenario.overrides, user)
    return load_model(SimConfig, merged, source)


def _check_world(world: World) -> None:
    table = load_class_table()
    for o in world.objects:
        if o.cls not in table.mobility:
            raise ConfigError(f"world {world.name}: object {o.name} has class {o.cls!r}, "
                              f"unknown to {table.source}")
    if not world.objects:
        raise ConfigError(f"world {world.name}: has no objects")


def _transform_list(cfg: SimConfig) -> tuple[np.ndarray, np.ndarray]:
    t_base_lidar = se3_from_xyz_rpy(cfg.lidar.mount.xyz, cfg.lidar.mount.rpy)
    t_base_cam = se3_from_xyz_rpy(cfg.camera.mount.xyz, cfg.camera.mount.rpy)
    return t_base_lidar, t_base_cam


def simulate(
    scenario: str | Path | Scenario | World,
    out: str | Path,
    fmt: BagFormat = "ros1",
    seed: int = 0,
    config: SimConfig | dict[str, Any] | str | Path | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> SimulationResult:
    """Simulate a tour and write it as a bag plus ground truth into the folder ``out``.

    ``out`` must not exist unless ``force`` is set; nothing appears there until the
    whole tour is written.
    """
    t_start = time.perf_counter()
    if fmt not in BAG_FORMATS:
        raise ConfigError(f"unknown bag format {fmt!r} (expected one of {', '.join(BAG_FORMATS)})")
    sc = resolve_scenario(scenario)
    cfg = effective_config(sc, config)
    out = Path(out)
    inputs = [x for x in (scenario, config) if isinstance(x, str | Path) and Path(x).exists()]
    with atomic_dir(out, force, marker="tour.yaml", inputs=inputs, what="semmap tour folder") as tmp:
        result = _simulate_into(sc, cfg, tmp, fmt, seed, progress)
    bag = out / result.bag.relative_to(tmp)
    return SimulationResult(out, bag, fmt, sc.world.name, seed, result.duration_s, result.topics,
                            time.perf_counter() - t_start)


def _simulate_into(sc: Scenario, cfg: SimConfig, out: Path, fmt: BagFormat, seed: int,
                   progress: ProgressFn | None) -> SimulationResult:
    world = sc.world
    table = load_class_table()
    label_names = table.names(cfg.camera.label_classes)
    _check_world(world)
    if cfg.camera.label_encoding == "mono8" and len(label_names) > 255:
        raise ConfigError(f"camera.label_encoding mono8 cannot hold {len(label_names)} classes")

    traj = plan_tour(world, cfg.robot)
    clearance = check_clearance(world, traj, cfg.robot)
    log.info("tour %s: %.1f s, %.1f m, clearance %.2f m", world.name, traj.duration, traj.length(), clearance)
    people_gap, people_t, who = people_clearance(world, traj, cfg.robot)
    if people_gap < 0.05:
        log.warning("world %s: %s comes within %.2f m of the robot at t = %.1f s (people do not yield)",
                    world.name, who, people_gap, people_t)

    rng = np.random.default_rng(seed)
    rng_odom, rng_lidar, rng_cam, rng_cam_noise = rng.spawn(4)
    odom = simulate_odometry(traj, cfg.odometry, rng_odom)

    # object table: world objects, then people; rows index instance id, class and mobility
    rows = ([(o.id, o.cls, o.mobility) for o in world.objects]
            + [(p.id, "person", Mobility.DYNAMIC) for p in world.people])
    class_names = sorted({c for _, c, _ in rows})
    row_instance = np.array([r[0] for r in rows], np.int32)
    row_class = np.array([class_names.index(r[1]) for r in rows], np.int16)
    row_mobility = np.array([int(r[2]) for r in rows], np.uint8)
    label_of_row = np.array([label_names.index(r[1]) + 1 if r[1] in label_names else 0 for r in rows], np.uint16)
    person_rows = {p.id: len(world.objects) + i for i, p in enumerate(world.people)}

    static_parts = [p for o in world.objects for p in o.parts]
    static_owner = [i for i, o in enumerate(world.objects) for _ in o.parts]
    static_set = PartSet.build(static_parts, static_owner)

    lidar = LidarSim(cfg.lidar)
    camera = CameraSim(cfg.camera, world.ceiling_height, rng_cam_noise)
    static_lidar = static_set.at_height(lidar.height)

    def people_set(t: float) -> PartSet:
        parts, owners = [], []
        for p in world.people:
            body = p.body(t)
            parts += body
            owners += [person_rows[p.id]] * len(body)
        return PartSet.from_raw(parts, owners)

    t_base_lidar, t_base_cam = _transform_list(cfg)
    intr = CameraIntrinsics(cfg.camera.width, cfg.camera.height, np.asarray(cfg.camera.K), np.zeros(5), "pinhole")
    calib = Calibration(intr, se3_inverse(t_base_cam) @ t_base_lidar, cfg.camera.frame_id, cfg.lidar.frame_id)

    # ---- schedule every message; render lazily in bag-time order ------------------------
    t0 = cfg.start_time_ns
    ns = 1_000_000_000
    duration = traj.duration
    scan_period = 1.0 / cfg.lidar.rate_hz
    sweep_s = float(lidar.beam_dt[-1])
    scan_times = np.arange(0.013, duration - sweep_s, scan_period)
    cam_times = np.arange(0.047, duration, 1.0 / cfg.camera.rate_hz)
    events: list[tuple[int, int, str, int]] = []  # (bag time, order, kind, index)
    events.append((t0, 0, "tf_static", 0))
    for i, t in enumerate(odom.t):
        stamp = t0 + int(round(t * ns))
        events.append((stamp + int(cfg.odometry.latency_s * ns), 1, "odom", i))
    gt_times = np.arange(0.0, duration + 1e-9, 1.0 / cfg.ground_truth.rate_hz)
    for i, t in enumerate(gt_times):
        events.append((t0 + int(round(t * ns)), 2, "gt", i))
    for i, t in enumerate(scan_times):
        events.append((t0 + int(round(t * ns)) + int(cfg.lidar.latency_s * ns), 3, "scan", i))
    for i, t in enumerate(cam_times):
        events.append((t0 + int(round(t * ns)) + int(cfg.camera.latency_s * ns), 4, "camera", i))
    events.sort()

    n_scans, n_beams = len(scan_times), lidar.angles.size
    gt_range = np.full((n_scans, n_beams), np.inf, np.float32)
    gt_row = np.full((n_scans, n_beams), -1, np.int32)
    n_rows = len(rows)
    cam_visible = np.zeros((len(cam_times), n_rows), bool)  # object-table rows each camera image shows
    scan_pose = np.zeros((n_scans, 3))
    # beams whose end point lands on the object's own labelled pixels in the camera image nearest
    # the scan (within _PAINT_WINDOW_S, as semmap build pairs them): what the camera labelled
    painted = np.zeros(n_rows, np.int64)
    painter = _PaintedHits(camera, cfg.camera, lidar, cam_times, traj, painted)
    best: dict[str, Any] = {"score": -1.0}
    counts: dict[str, int] = {}

    bag_path = out / (f"{world.name}.bag" if fmt == "ros1" else world.name)
    c = cfg
    with BagWriter(bag_path, fmt) as bag:
        for done, (t_bag, _, kind, i) in enumerate(events):
            if kind == "tf_static":
                bag.transforms(c.tf_static_topic, t_bag, [
                    (t0, c.robot.base_frame, c.lidar.frame_id, t_base_lidar),
                    (t0, c.robot.base_frame, c.camera.frame_id, t_base_cam),
                ], static=True)
                topics = [c.tf_static_topic]
            elif kind == "odom":
                stamp = t0 + int(round(odom.t[i] * ns))
                pose, tw = odom.pose[i], odom.twist[i]
                bag.odometry(c.odometry.topic, t_bag, stamp, c.odometry.frame_id, c.robot.base_frame,
                             pose, tw, pose_cov_diag=(1e-3, 1e-3, 1e6, 1e6, 1e6, 1e-2),
                             twist_cov_diag=(1e-3, 1e-3, 1e6, 1e6, 1e6, 1e-2))
                topics = [c.odometry.topic]
                if c.odometry.publish_tf:
                    bag.transforms(c.tf_topic, t_bag, [(stamp, c.odometry.frame_id, c.robot.base_frame,
                                                        se2_to_se3(pose))])
                    topics.append(c.tf_topic)
            elif kind == "gt":
                t = gt_times[i]
                bag.odometry(c.ground_truth.pose_topic, t_bag, t_bag, world.frame_id, c.robot.base_frame,
                             traj.pose(t), traj.velocity(t))
                topics = [c.ground_truth.pose_topic]
            elif kind == "scan":
                t = scan_times[i]
                poses = traj.pose(t + lidar.beam_dt)
                parts = PartSet.concat([static_lidar, people_set(t + 0.5 * sweep_s).at_height(lidar.height)])
                sweep = lidar.cast(poses, parts)
                ranges = lidar.measure(sweep, rng_lidar)
                stamp = t0 + int(round(t * ns))
                bag.scan(c.lidar.topic, t_bag, Scan(
                    stamp_ns=stamp, frame_id=c.lidar.frame_id, angle_min=lidar.angle_min,
                    angle_increment=lidar.angle_increment, ranges=ranges, range_min=c.lidar.range_min,
                    range_max=c.lidar.range_max, time_increment=lidar.time_increment, scan_time=scan_period))
                gt_range[i] = sweep.ranges
                gt_row[i] = np.where(sweep.part >= 0, sweep.parts.owner[np.maximum(sweep.part, 0)], -1)
                scan_pose[i] = poses[0]
                painter.scan(t, poses, sweep.ranges, gt_row[i])
                topics = [c.lidar.topic]
            else:  # camera
                t = cam_times[i]
                stamp = t0 + int(round(t * ns))
                parts = PartSet.concat([static_set, people_set(t)])
                shot = camera.render(traj.pose(t), parts, label_of_row, rng_cam)
                if c.camera.image_format == "jpeg":
                    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(shot.rgb, cv2.COLOR_RGB2BGR),
                                           [cv2.IMWRITE_JPEG_QUALITY, c.camera.jpeg_quality])
                    if not ok:
                        raise SemmapError("JPEG encoding failed")
                    image_topic = c.camera.image_topic.rstrip("/") + "/compressed"
                    bag.compressed_image(image_topic, t_bag, stamp, c.camera.frame_id, "rgb8; jpeg compressed bgr8",
                                         buf.tobytes())
                else:
                    image_topic = c.camera.image_topic
                    bag.image(image_topic, t_bag, Image(stamp, c.camera.frame_id, shot.rgb, "rgb8"))
                if c.camera.label_encoding == "mono8":
                    lab = Image(stamp, c.camera.frame_id, shot.label.astype(np.uint8), "mono8")
                else:
                    lab = Image(stamp, c.camera.frame_id, shot.label, "mono16")
                bag.image(c.camera.label_topic, t_bag, lab)
                # labelled pixels per object-table row (row + 1; 0 collects floor, ceiling, unlabelled)
                px = np.bincount(((shot.owner + 1) * (shot.label > 0)).ravel(), minlength=n_rows + 1)
                cam_visible[i] = px[1:] >= _MIN_VISIBLE_PX
                painter.image(i, shot)
                bag.camera_info(c.camera.info_topic, t_bag, stamp, c.camera.frame_id, intr)
                topics = [image_topic, c.camera.label_topic, c.camera.info_topic]
                score = _preview_score(shot.label)
                if score > best["score"]:
                    best = {"score": score, "t": t, "stamp": stamp, "rgb": shot.rgb.copy(),
                            "label": shot.label.copy()}
            for tp in topics:
                counts[tp] = counts.get(tp, 0) + 1
            if progress is not None and (done % 200 == 0 or done == len(events) - 1):
                progress(done + 1, len(events))

    # ---- ground truth -----------------------------------------------------------------------
    gt = out / "ground_truth"
    gt.mkdir()
    write_yaml(gt / "world.yaml", world_to_dict(world),
               "# semmap world: reload with `semmap simulate --scenario world.yaml`\n")
    spec = grid_for_world(world, cfg.ground_truth.map_resolution, cfg.ground_truth.map_margin)
    layers = occupancy_layers(world, spec, lidar.height)
    for name, occ in layers.items():
        write_map(gt / f"{name}.yaml", spec, occ)
    swept = people_swept(world, spec, duration, cfg.ground_truth.people_radius) & ~layers["occupancy"]
    write_map(gt / "people_swept.yaml", spec, swept)
    standing = people_standing(world, spec, duration, lidar.height) & ~layers["occupancy"]
    write_map(gt / "people_standing.yaml", spec, standing)
    truth = _object_truth(world, spec, lidar.height, duration, gt_row, cam_visible, painted)
    (gt / "objects.json").write_text(_json_rows(truth), encoding="utf-8")
    write_tum(gt / "trajectory.tum", t0 + np.round(gt_times * ns).astype(np.int64), traj.pose(gt_times))
    write_tum(gt / "odometry.tum", t0 + np.round(odom.t * ns).astype(np.int64), odom.pose)
    np.savez_compressed(
        gt / "beams.npz",
        stamp_ns=t0 + np.round(scan_times * ns).astype(np.int64),
        angles=lidar.angles,
        time_offset_s=lidar.beam_dt,
        range=gt_range,
        instance=np.where(gt_row >= 0, row_instance[np.maximum(gt_row, 0)], 0).astype(np.int32),
        class_index=np.where(gt_row >= 0, row_class[np.maximum(gt_row, 0)], -1).astype(np.int16),
        mobility=np.where(gt_row >= 0, row_mobility[np.maximum(gt_row, 0)], 0).astype(np.uint8),
        class_names=np.array(class_names),
        base_pose=scan_pose,
    )
    changes = None
    if sc.base is not None:
        base_spec = grid_for_world(sc.base, cfg.ground_truth.map_resolution, cfg.ground_truth.map_margin)
        base_layers = occupancy_layers(sc.base, base_spec, lidar.height)
        if base_spec != spec:
            raise SemmapError(f"world {world.name}: its grid differs from its base world's")
        mask = change_mask(base_layers["occupancy"], layers["occupancy"])
        cv2.imwrite(str(gt / "changes.png"), np.flipud(mask))
        write_yaml(gt / "changes.yaml", {
            "image": "changes.png", "resolution": spec.resolution, "origin": [spec.origin_x, spec.origin_y, 0.0],
            "values": {0: "no change", 1: "added", 2: "removed"}, "base_world": sc.base.name,
        })
        changes = _change_list(sc.base, world)
        (gt / "changes.json").write_text(json.dumps(changes, indent=2), encoding="utf-8")

    calib_extra = {"source": f"semmap simulate (scenario {world.name}); exact by construction"}
    write_calibration(out / "calibration.yaml", calib, calib_extra)
    write_yaml(out / "config.yaml", cfg.model_dump(mode="json"), "# effective simulator configuration\n")
    manifest = {
        "semmap_tour": 1,
        "scenario": world.name,
        "description": world.description,
        "seed": seed,
        "bag": bag_path.name,
        "format": fmt,
        "duration_s": round(duration, 3),
        "path_length_m": round(traj.length(), 3),
        "start_time_ns": t0,
        "frames": {"world": world.frame_id, "odom": c.odometry.frame_id, "base": c.robot.base_frame,
                   "lidar": c.lidar.frame_id, "camera": c.camera.frame_id},
        "topics": {
            "scan": c.lidar.topic,
            "image": (c.camera.image_topic.rstrip("/") + "/compressed") if c.camera.image_format == "jpeg"
            else c.camera.image_topic,
            "labels": c.camera.label_topic,
            "camera_info": c.camera.info_topic,
            "odometry": c.odometry.topic,
            "ground_truth_pose": c.ground_truth.pose_topic,
            "tf": c.tf_topic,
            "tf_static": c.tf_static_topic,
        },
        "label_classes": cfg.camera.label_classes,
        "message_counts": counts,
        "odometry_error": {"scale": round(float(odom.scale_error), 5),
                           "yaw_scale": round(float(odom.yaw_scale_error), 5),
                           "yaw_drift_deg_per_m": round(math.degrees(float(odom.yaw_drift_rad_per_m)), 4)},
        "min_clearance_m": round(clearance, 3),
        "min_people_clearance_m": round(people_gap, 3) if math.isfinite(people_gap) else None,
        "ground_truth": {
            "world": "ground_truth/world.yaml",
            "occupancy": "ground_truth/occupancy.yaml",
            "static": "ground_truth/static.yaml",
            "semi_static": "ground_truth/semi_static.yaml",
            "people_swept": "ground_truth/people_swept.yaml",
            "people_standing": "ground_truth/people_standing.yaml",
            "objects": "ground_truth/objects.json",
            "trajectory": "ground_truth/trajectory.tum",
            "odometry": "ground_truth/odometry.tum",
            "beams": "ground_truth/beams.npz",
            **({"changes": "ground_truth/changes.yaml", "change_list": "ground_truth/changes.json"}
               if changes is not None else {}),
        },
        "calibration": "calibration.yaml",
    }
    write_yaml(out / "tour.yaml", manifest)

    from .preview import camera_preview, world_preview  # matplotlib is slow to import

    prev = out / "preview"
    prev.mkdir()
    world_preview(prev / "world.png", world, spec, layers, traj, odom, swept)
    if "rgb" in best:
        k = int(np.argmin(np.abs(scan_times - best["t"])))
        camera_preview(prev / "camera.png", best["rgb"], best["label"], label_names, calib,
                       lidar.angles, gt_range[k], gt_row[k], row_mobility,
                       title=f"{world.name}: camera at t = {best['t']:.1f} s")
    return SimulationResult(out, bag_path, fmt, world.name, seed, duration, counts)


class _PaintedHits:
    """Counts, per object-table row, the true beams that land on that object's own labelled pixels in
    the camera image nearest their scan (within ``_PAINT_WINDOW_S``): the hits the camera labelled.

    Scans and images arrive in bag order; a scan waits for its image, and the last images are
    kept (their owner images only) for scans that come after them.
    """

    def __init__(self, camera: CameraSim, cam_cfg: Any, lidar: LidarSim, cam_times: np.ndarray, traj: Any,
                 out: np.ndarray) -> None:
        self.camera, self.lidar, self.cam_times, self.traj, self.out = camera, lidar, cam_times, traj, out
        k = np.asarray(cam_cfg.K, dtype=np.float64)
        self.fx, self.fy, self.cx, self.cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        self.size = (cam_cfg.width, cam_cfg.height)
        self.images: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # index -> (owner & labelled, camera pose)
        self.pending: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}  # index -> [(end points, rows)]

    def scan(self, t: float, poses: np.ndarray, ranges: np.ndarray, rows: np.ndarray) -> None:
        if self.cam_times.size == 0:
            return
        k = int(np.argmin(np.abs(self.cam_times - t)))
        if abs(self.cam_times[k] - t) > _PAINT_WINDOW_S + 1e-9:
            return
        ok = (rows >= 0) & np.isfinite(ranges)
        if not ok.any():
            return
        mount = se2_compose(poses[ok], self.lidar.mount)
        head = mount[:, 2] + self.lidar.base_angles[ok]
        ends = mount[:, :2] + ranges[ok, None] * np.column_stack([np.cos(head), np.sin(head)])
        item = (ends, rows[ok])
        if k in self.images:
            self._count(k, *item)
        else:
            self.pending.setdefault(k, []).append(item)

    def image(self, k: int, image: Any) -> None:
        owner = np.where(image.label > 0, image.owner, -1).astype(np.int32)
        cam = se2_compose(self.traj.pose(float(self.cam_times[k])), self.camera.mount)
        self.images[k] = (owner, cam)
        for item in self.pending.pop(k, []):
            self._count(k, *item)
        for old in [j for j in self.images if j < k - 2]:  # later scans pair with recent images only
            del self.images[old]

    def _count(self, k: int, ends: np.ndarray, rows: np.ndarray) -> None:
        owner, cam = self.images[k]
        c, s = math.cos(cam[2]), math.sin(cam[2])
        dx, dy = ends[:, 0] - cam[0], ends[:, 1] - cam[1]
        fwd, left = c * dx + s * dy, -s * dx + c * dy
        z = np.maximum(fwd, 1e-9)
        u = np.floor(self.fx * (-left) / z + self.cx).astype(np.int64)
        v = np.floor(self.fy * (self.camera.height - self.lidar.height) / z + self.cy).astype(np.int64)
        w, h = self.size
        inside = (fwd > 0.05) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        on = np.zeros(rows.size, bool)
        on[inside] = owner[v[inside], u[inside]] == rows[inside]
        self.out += np.bincount(rows[on], minlength=self.out.size)


def _object_truth(world: World, spec: Any, height: float, duration: float, gt_row: np.ndarray,
                  cam_visible: np.ndarray, painted: np.ndarray) -> dict[str, Any]:
    """``objects.json``: what every object and person is, and how much of it the sensors saw.

    Rows of ``gt_row``, ``cam_visible`` and ``painted`` index the object table: world objects, then
    people.
    """
    n_rows = cam_visible.shape[1]
    hits = gt_row[gt_row >= 0]
    lidar_hits = np.bincount(hits, minlength=n_rows)
    cam_images = cam_visible.sum(axis=0)
    cells = object_cells(world, spec, height)
    objects = []
    for i, o in enumerate(world.objects):
        objects.append({
            "id": o.id, "name": o.name, "class": o.cls, "mobility": o.mobility.label,
            "centroid": [round(float(v), 3) for v in o.centroid()], "cells": int(cells[i]),
            "lidar_hits": int(lidar_hits[i]), "camera_images": int(cam_images[i]), "painted_hits": int(painted[i]),
        })
    people = []
    for j, p in enumerate(world.people):
        row = len(world.objects) + j
        stood = sum(t1 - t0 for t0, t1, _, _ in standing_stretches(p, duration))
        people.append({
            "id": p.id, "name": p.name, "role": person_role(p.name), "standing_s": round(float(stood), 2),
            "lidar_hits": int(lidar_hits[row]), "camera_images": int(cam_images[row]),
            "painted_hits": int(painted[row]),
        })
    return {"min_standing_s": MIN_STANDING_S, "min_visible_px": _MIN_VISIBLE_PX, "objects": objects, "people": people}


def _json_rows(data: dict[str, Any]) -> str:
    """JSON with every entry of a list on its own line (a person reads it; ``json.load`` too)."""
    lines = []
    for key, value in data.items():
        if isinstance(value, list):
            rows = ",\n".join(f"    {json.dumps(v)}" for v in value)
            lines.append(f"  {json.dumps(key)}: [\n{rows}\n  ]" if value else f"  {json.dumps(key)}: []")
        else:
            lines.append(f"  {json.dumps(key)}: {json.dumps(value)}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def _preview_score(label: np.ndarray) -> float:
    """Prefer images showing many classes, none of them filling the view (people score double)."""
    values, counts = np.unique(label, return_counts=True)
    if counts[values > 0].max(initial=0) > 0.25 * label.size:
        return 0.0
    return float(sum(min(int(n), 8000) * (2 if v == 1 else 1) for v, n in zip(values, counts) if v > 0))


def _change_list(before: World, after: World) -> list[dict[str, Any]]:
    """Objects moved, removed or added between two worlds (by object id)."""
    a = {o.id: o for o in before.objects}
    b = {o.id: o for o in after.objects}
    out: list[dict[str, Any]] = []
    for oid, o in a.items():
        if oid not in b:
            out.append({"type": "removed", "id": oid, "name": o.name, "class": o.cls,
                        "mobility": o.mobility.label, "centroid": [round(float(v), 3) for v in o.centroid()]})
        else:
            pa = np.concatenate([p.polygon for p in o.parts])
            pb = np.concatenate([p.polygon for p in b[oid].parts])
            if pa.shape != pb.shape or not np.allclose(pa, pb):
                ca, cb = o.centroid(), b[oid].centroid()
                entry = {"type": "moved", "id": oid, "name": o.name, "class": o.cls,
                         "mobility": o.mobility.label, "from": [round(float(v), 3) for v in ca],
                         "to": [round(float(v), 3) for v in cb],
                         "displacement_m": round(float(np.linalg.norm(cb - ca)), 3)}
                if pa.shape == pb.shape:  # the turn, from the parts' vertices (2D Kabsch)
                    h = (pa - pa.mean(axis=0)).T @ (pb - pb.mean(axis=0))
                    entry["rotation_deg"] = round(math.degrees(math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])), 2)
                out.append(entry)
    for oid, o in b.items():
        if oid not in a:
            out.append({"type": "added", "id": oid, "name": o.name, "class": o.cls,
                        "mobility": o.mobility.label, "centroid": [round(float(v), 3) for v in o.centroid()]})
    return out
