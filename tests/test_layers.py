"""semmap's import graph keeps its two rules (tools/import_graph.py): stages import only earlier stages,
and no module uses another module's private name."""

import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("import_graph", REPO / "tools" / "import_graph.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["import_graph"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_no_stage_imports_a_later_one_and_no_private_names_are_shared():
    g = _tool().analyse(REPO / "semmap")
    assert g.layer_violations == []
    assert g.private_violations == []
    assert len(g.modules) > 60


def test_the_rules_catch_what_they_forbid(tmp_path):
    """A painter importing the pipeline, and a grid module reaching into another's private name, are
    both reported (so an empty report means something)."""
    tool = _tool()
    pkg = tmp_path / "semmap"
    for sub in ("", "paint", "grid"):
        (pkg / sub).mkdir(parents=True, exist_ok=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "pipeline.py").write_text("def build(): pass\n")
    (pkg / "paint" / "painter.py").write_text("from ..pipeline import build\n")
    (pkg / "grid" / "fusion.py").write_text("_SECRET = 1\n")
    (pkg / "grid" / "clean.py").write_text("from . import fusion\nx = fusion._SECRET\nfrom .fusion import _SECRET\n")
    g = tool.analyse(pkg)
    assert g.layer_violations == ["semmap.paint.painter (paint) imports semmap.pipeline (run), a later stage"]
    assert g.private_violations == ["semmap.grid.clean imports the private name semmap.grid.fusion._SECRET",
                                    "semmap.grid.clean uses the private name semmap.grid.fusion._SECRET"]
