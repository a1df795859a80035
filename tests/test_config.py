"""The build config as a user writes it: one model per segmentation backend, the occlusion filter's
own section, and files written for the older flat layout (including every map folder's
config.yaml, which dumps every key) loading to the same settings."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import yaml

from semmap.config import (
    SEGMENTATION_BACKENDS,
    BuildConfig,
    OcclusionConfig,
    OnnxSegmentation,
    PaintConfig,
    Sam3Segmentation,
    SelfieSegmentation,
    TopicSegmentation,
    UltralyticsSegmentation,
    load_model,
    segmentation_config,
)
from semmap.errors import ConfigError
from semmap.io.tour import load_build_config

DATA = Path(__file__).parent / "data"

#: the frame selection's options, which every backend takes (segmentation.select)
SELECT = {"select", "select_distance", "select_angle", "select_interval", "max_rate", "max_frames", "max_seconds",
          "transfer_window",
          "need_frames", "need_cells", "need_cell"}

#: the options each backend takes besides ``backend``, ``classes_file`` and the frame selection's
OPTIONS = {
    "topic": {"class_list"},
    "folder": {"class_list", "folder"},
    "onnx": {"class_list", "model", "device", "threads", "cache_dir", "conf", "iou", "mask_threshold", "max_det",
             "imgsz"},
    "ultralytics": {"model", "device", "cache_dir", "conf", "iou", "max_det", "imgsz"},
    "sam3": {"class_list", "model", "device", "threads", "cache_dir", "conf", "mask_threshold", "max_det", "imgsz",
             "prompts", "memory_budget_mb"},
    "mediapipe-selfie": {"model", "device", "threads", "cache_dir", "mask_threshold"},
}


def _load(tmp_path: Path, text: str) -> BuildConfig:
    (tmp_path / "build.yaml").write_text(text)
    return load_build_config(tmp_path / "build.yaml")[0]


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_an_old_map_folders_config_loads_to_the_same_settings(caplog):
    """config.yaml of a map folder written before one model per backend: every backend's key, flat
    paint.occlusion_* keys. It loads quietly to the defaults it was dumped from."""
    with caplog.at_level(logging.WARNING):
        cfg, _ = load_build_config(DATA / "map_config_flat.yaml")
    assert _warnings(caplog) == []
    assert cfg.segmentation == TopicSegmentation()
    assert cfg.paint == PaintConfig()
    assert cfg.paint.occlusion.filter and cfg.paint.occlusion.max_gap == 2.2
    assert cfg.topics.labels == "/camera/labels" and cfg.frames.lidar == "laser"
    assert cfg.registration == BuildConfig().registration and cfg.cleaning == BuildConfig().cleaning
    # what a build writes now reads back as itself
    again = load_model(BuildConfig, yaml.safe_load(yaml.safe_dump(cfg.model_dump(mode="json"))), "dump")
    assert again == cfg


def test_flat_keys_mean_what_the_nested_ones_do(tmp_path, caplog):
    old = _load(tmp_path, """\
segmentation: {backend: onnx, model: /m/yolo.onnx, conf: 0.4, iou: 0.6, threads: 2, prompts: null,
               memory_budget_mb: 4096.0, folder: null}
paint: {min_depth: 0.2, occlusion_filter: false, occlusion_max_gap: 1.5, occlusion_ray_width_deg: 1.0}
""")
    new = _load(tmp_path, """\
segmentation: {backend: onnx, model: /m/yolo.onnx, conf: 0.4, iou: 0.6, threads: 2}
paint: {min_depth: 0.2, occlusion: {filter: false, max_gap: 1.5, ray_width_deg: 1.0}}
""")
    assert old == new
    assert isinstance(new.segmentation, OnnxSegmentation) and new.segmentation.conf == 0.4
    assert new.paint.occlusion == OcclusionConfig(filter=False, max_gap=1.5, ray_width_deg=1.0)
    assert _warnings(caplog) == []  # the other backends' keys held their defaults


def test_an_override_of_a_nested_key_wins_over_the_files_flat_key(tmp_path):
    (tmp_path / "build.yaml").write_text("paint: {occlusion_filter: true, occlusion_max_gap: 1.5}\n")
    cfg, _ = load_build_config(tmp_path / "build.yaml", {"paint": {"occlusion": {"filter": False}}})
    assert cfg.paint.occlusion.filter is False and cfg.paint.occlusion.max_gap == 1.5


def test_a_key_of_another_backend_is_ignored_with_one_warning(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        cfg = _load(tmp_path, "segmentation: {backend: topic, class_list: coco, conf: 0.5, model: yolo.onnx}\n")
    assert cfg.segmentation == TopicSegmentation()
    warned = _warnings(caplog)
    assert len(warned) == 1 and "conf, model" in warned[0] and "'topic'" in warned[0]
    # a command-line option another backend has (here: --threads for ultralytics) is ignored the same way
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        cfg, _ = load_build_config(None, {"segmentation": {"backend": "ultralytics", "model": "m.pt", "threads": 4}})
    assert cfg.segmentation == UltralyticsSegmentation(model=Path("m.pt"))
    assert len(_warnings(caplog)) == 1 and "threads" in _warnings(caplog)[0]


@pytest.mark.parametrize(("text", "message"), [
    ("segmentation: {backend: onnx, conff: 0.5}\n", "segmentation.conff: unknown key"),
    ("segmentation: {backend: onnx, conf: high}\n", "segmentation.conf: Input should be a valid number"),
    ("segmentation: {backend: sam3, conf: 1.5}\n", "segmentation.conf: Input should be less than or equal to 1"),
    ("segmentation: {class_list: 3}\n", "segmentation.class_list: Input should be a valid string"),
    ("segmentation: {backend: yolo}\n", "segmentation.backend: unknown backend 'yolo' (available: folder, "
                                        "mediapipe-selfie, onnx, sam3, topic, ultralytics)"),
    ("segmentation: onnx\n", "segmentation: expected a mapping"),
    ("paint: {occlusion: {max_gapp: 1}}\n", "paint.occlusion.max_gapp: unknown key"),
    ("paint: {occlusion_max_gapp: 1}\n", "paint.occlusion_max_gapp: unknown key"),
    ("paint: {occlusion_max_gap: -1}\n", "paint.occlusion.max_gap: Input should be greater than or equal to 0"),
    ("paint: {occlusion: {filter: maybe}}\n", "paint.occlusion.filter: Input should be a valid boolean"),
])
def test_a_misspelt_key_or_a_wrong_value_is_one_line_naming_the_field(tmp_path, text, message):
    with pytest.raises(ConfigError) as e:
        _load(tmp_path, text)
    assert str(e.value).startswith(f"{tmp_path / 'build.yaml'}: {message}")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("backend", sorted(OPTIONS))
def test_each_backend_has_only_its_options(backend, tmp_path, caplog):
    model = SEGMENTATION_BACKENDS[backend]
    assert set(model.model_fields) - {"backend", "classes_file", *SELECT} == OPTIONS[backend]
    others = set().union(*OPTIONS.values()) - OPTIONS[backend]
    for key in sorted(others):
        # in Python, an option the backend does not have is an error...
        with pytest.raises(ValueError, match="Extra inputs are not permitted"):
            model(**{key: "x"})
        # ...in a config file, another backend's option is ignored (and said so), so older files load
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            cfg = _load(tmp_path, yaml.safe_dump({"segmentation": {"backend": backend, key: "x"}}))
        assert cfg.segmentation == model()
        assert key in _warnings(caplog)[0]


def test_a_dump_of_a_backends_options_reads_back_as_that_backend():
    """How the build hands the options to its frame worker process, and how a BuildConfig given to
    build() with overrides is re-read (only the fields that were set)."""
    for cfg in (TopicSegmentation(class_list="ade20k"), OnnxSegmentation(model=Path("m.onnx"), conf=0.1),
                Sam3Segmentation(prompts=("person", "chair")), SelfieSegmentation()):
        assert segmentation_config(cfg.model_dump(mode="json")) == cfg
        assert segmentation_config(cfg.model_dump(exclude_unset=True)) == cfg
    assert segmentation_config(None) == TopicSegmentation()


def test_the_mask_cache_keys_of_earlier_versions_still_hold(tmp_path):
    """A cache filled before one model per backend is still used: the keys are those the flat config
    gave (computed with semmap before issue 19 for these weights and options)."""
    from semmap.segment.cache import model_identity, model_key

    w = tmp_path / "m.onnx"
    w.write_bytes(b"one")
    keys = [model_key(model_identity(c, tmp_path)) for c in (
        OnnxSegmentation(model=w),
        Sam3Segmentation(model=w, prompts=("person", "chair"), conf=0.1),
        SelfieSegmentation(model=w, mask_threshold=0.6),
        UltralyticsSegmentation(model=w, iou=0.5))]
    assert keys == ["onnx-6cd92fcc2b5ffacf", "sam3-faccee7a97f3f70a", "mediapipe-selfie-898d3e42c6960377",
                    "ultralytics-46d6fb33108f3152"]


@pytest.mark.parametrize(("text", "message"), [
    ("class_lists: {mine: [person, robot]}\nmobility: {person: dynamic}\n",
     "class_lists.mine: no mobility for ['robot']"),
    ("mobility: {robot: flying}\n", "mobility.robot: unknown mobility 'flying' (expected one of unknown, static, "
                                    "semi_static, dynamic)"),
    ("mobility: {robot: dynamic}\nsizes: {robot: -1}\n", "sizes.robot: Input should be greater than 0"),
    ("mobility: {robot: dynamic}\nsizes: {chair: 0.5}\n", "sizes.chair: not a class under 'mobility:'"),
    ("mobility: {robot: dynamic}\nsize: {robot: 0.5}\n", "size: unknown key"),
])
def test_a_class_table_error_is_one_line_naming_the_file_and_the_field(tmp_path, text, message):
    from semmap.classes import load_class_table

    (tmp_path / "classes.yaml").write_text(text)
    with pytest.raises(ConfigError) as e:
        load_class_table(tmp_path / "classes.yaml")
    assert str(e.value) == f"{(tmp_path / 'classes.yaml').resolve()}: {message}"


def test_a_class_table_of_ones_own_names_the_label_values(tmp_path):
    from semmap.classes import load_class_table
    from semmap.records import Mobility

    (tmp_path / "classes.yaml").write_text("class_lists: {site: [robot, cart]}\n"
                                           "mobility: {robot: dynamic, cart: semi_static}\nsizes: {cart: 1.2}\n")
    table = load_class_table(tmp_path / "classes.yaml")
    assert table.names("site") == ("robot", "cart")
    assert table.mobility_of("robot") is Mobility.DYNAMIC and table.size_of("cart") == 1.2


def test_a_plugin_backend_is_named_in_a_config_file_and_its_options_checked(tmp_path):
    """A backend registered by a plugin (segment.base.register) can be chosen in YAML like a built-in one;
    its own options model validates its keys, and without one any key is kept for the plugin."""
    from typing import Literal

    from semmap.config import PLUGIN_SEGMENTATION, ModelSegmentationConfig, PluginSegmentation
    from semmap.errors import ConfigError
    from semmap.io.tour import load_build_config
    from semmap.segment import base

    class DepthNetOptions(ModelSegmentationConfig):
        backend: Literal["depthnet"] = "depthnet"
        levels: int = 3

    try:
        base.register("depthnet", options=DepthNetOptions)(lambda cfg: None)
        base.register("anynet")(lambda cfg: None)
        f = tmp_path / "c.yaml"
        f.write_text("segmentation: {backend: depthnet, levels: 5, device: cpu}\n")
        cfg, _ = load_build_config(f)
        assert isinstance(cfg.segmentation, DepthNetOptions) and cfg.segmentation.levels == 5
        f.write_text("segmentation: {backend: depthnet, levels: many}\n")
        with pytest.raises(ConfigError, match="segmentation.levels"):
            load_build_config(f)
        f.write_text("segmentation: {backend: anynet, stride: 8}\n")
        cfg, _ = load_build_config(f)
        assert isinstance(cfg.segmentation, PluginSegmentation) and cfg.segmentation.stride == 8
        f.write_text("segmentation: {backend: nonet}\n")
        with pytest.raises(ConfigError, match="unknown backend 'nonet'"):
            load_build_config(f)
    finally:
        for name in ("depthnet", "anynet"):
            base.SEGMENTERS.pop(name, None)
            base.CONSUMES.pop(name, None)
            PLUGIN_SEGMENTATION.pop(name, None)
