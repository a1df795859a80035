"""The world file and the tour manifest that ``semmap simulate`` writes: they read back as written, and a
bad field is one line naming the file and the field (the calibration file: test_calib_conventions.py)."""

from __future__ import annotations

import copy
from dataclasses import replace

import pytest
import yaml
from file_errors import DROP, assert_one_line_error, set_key

from semmap.io.tour import read_tour_manifest
from semmap.sim.world import load_world, world_to_dict


@pytest.fixture(scope="module")
def tour(tmp_path_factory, short_demo_world):
    from semmap.sim.tour import simulate

    out = tmp_path_factory.mktemp("schemas") / "demo"
    return simulate(replace(short_demo_world, duration_s=3.0), out, seed=5)




def test_a_world_file_written_by_simulate_reads_back_and_replays(tour, tmp_path):
    """Replaying it writes the same world file. (Not the same bag as the tour the file came from: the
    file keeps 5 decimals, so parts move by up to 1e-5 m and the ray casts differ in the last bits.)"""
    from semmap.sim.tour import simulate

    path = tour.out / "ground_truth" / "world.yaml"
    world = load_world(path)
    assert world_to_dict(world) == yaml.safe_load(path.read_text())
    again = simulate(path, tmp_path / "again", seed=5)
    assert (again.out / "ground_truth" / "world.yaml").read_text() == path.read_text()
    assert yaml.safe_load((again.out / "tour.yaml").read_text())["scenario"] == world.name == "demo"


@pytest.mark.parametrize("key, value, message", [
    ("colour", "red", "colour: unknown key"),
    ("ceiling_height", 0, "ceiling_height: Input should be greater than 0"),
    ("duration_s", float("nan"), "duration_s: Input should be a finite number"),
    ("laps", True, "laps: must be a whole number of at least 1, got True"),
    ("laps", 1.5, "laps: Input should be a valid integer"),
    ("route", [0.0, 0.0, 1.0, 1.0], "route.0: Input should be a valid tuple"),
    ("objects.0.class", DROP, "objects.0.class: Field required"),
    ("objects.0.mobility", "sometimes", "objects.0.mobility: unknown mobility 'sometimes'"),
    ("objects.0.id", 0, r"world demo: ids must be positive \(0 means 'nothing'\)"),
    ("objects.1.parts.0.z", [1.0, 0.5], "objects.1.parts.0: part heights must satisfy z_min < z_max"),
    ("objects.1.parts.0.polygon", [[0, 0], [1, 1]], "objects.1.parts.0: a part polygon needs at least 3"),
    ("objects.1.parts.0.color", [200, 10], "objects.1.parts.0.color.2: Field required"),
    ("objects.1.parts.0.color", [200, 10, 300], "objects.1.parts.0.color.2: Input should be less than or equal to 255"),
    ("people.0.speed", -1.0, "people.0.speed: Input should be greater than 0"),
    ("people.0.waypoints", [], "people.0: person .*: needs at least one finite waypoint"),
    ("people.0.shirt", [1], "people.0.shirt.1: Field required"),
    ("people.0.hat", "red", "people.0.hat: unknown key"),
])
def test_a_bad_field_of_a_world_file_is_one_line_naming_the_file_and_the_field(tour, tmp_path, key, value, message):
    data = yaml.safe_load((tour.out / "ground_truth" / "world.yaml").read_text())
    set_key(data, key, value)
    assert_one_line_error(load_world, tmp_path / "world.yaml", message, data)


def _manifest_folder(tour, tmp_path, manifest):
    """A tour folder holding ``manifest`` as its tour.yaml beside the tour's bag."""
    folder = tmp_path / "tour"
    folder.mkdir()
    (folder / tour.bag.name).symlink_to(tour.bag)
    (folder / "tour.yaml").write_text(yaml.safe_dump(manifest))
    return folder


def test_the_manifest_written_by_simulate_reads_back(tour):
    bag, folder, manifest = read_tour_manifest(tour.out)
    assert (bag, folder) == (tour.bag, tour.out)
    assert manifest == yaml.safe_load((tour.out / "tour.yaml").read_text())
    assert manifest["scenario"] == "demo" and manifest["label_classes"] == "coco"
    assert manifest["topics"]["scan"] == "/scan"


@pytest.mark.parametrize("key, value, message", [
    ("topics", ["/scan", "/odom"], "topics: Input should be a valid dictionary"),
    ("topics.scan", ["/scan"], "topics.scan: Input should be a valid string"),
    ("label_classes", 17, "label_classes: Input should be a valid string"),
    ("scenario", {"name": "demo"}, "scenario: Input should be a valid string"),
])
def test_a_bad_field_of_a_tour_manifest_is_one_line_naming_the_file_and_the_field(tour, tmp_path, key, value,
                                                                                   message):
    manifest = copy.deepcopy(yaml.safe_load((tour.out / "tour.yaml").read_text()))
    set_key(manifest, key, value)
    folder = _manifest_folder(tour, tmp_path, manifest)
    assert_one_line_error(lambda f: read_tour_manifest(f.parent), folder / "tour.yaml", message)


def test_a_manifest_keeps_the_keys_semmap_does_not_read(tour, tmp_path):
    """Counts, clearances and a newer semmap's keys stay in the manifest; only those read are checked."""
    manifest = yaml.safe_load((tour.out / "tour.yaml").read_text())
    manifest["written_by"] = {"semmap": "9.9", 3: "three"}
    manifest["topics"] = None
    folder = _manifest_folder(tour, tmp_path, manifest)
    assert read_tour_manifest(folder)[2] == manifest
