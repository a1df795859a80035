#!/usr/bin/env python3
"""semmap's import graph, and the two rules it must keep.

1. **Stages import only earlier stages.** Data flows one way through the pipeline, and so do
   imports: a stage may import its own stage and the stages before it, never a later one::

       base      errors, version, runtime, geometry, records, palette, io.yamlio, config, classes
       io        reading bags, calibration files, maps and trajectories
       segment   label images from a backend, one per camera image
       paint     the scan stream (pairing), painting, the occlusion filter
       register  KISS-ICP and the odometry EKF
       grid      fusion and cleaning
       mapfolder writing and reading the map folder
       compare   semmap diff: comparing sessions (alignment, changes, updated maps)
       robotmap  semmap export: maps, masks and object lists for a robot from a saved session
       tools     sim (the simulator and its scoring), calib (calibration)
       run       workers (the processes), pipeline (semmap build)
       cli       the command line, and the package's own lazy API (semmap/__init__.py)

2. **No module uses another module's private name** (a name starting with ``_``), imported or
   reached as an attribute. A package may share private *modules* among its own modules
   (``semmap.cli._progress`` within ``semmap.cli``).

Usage::

    python tools/import_graph.py            # the graph by stage, then the rules' violations
    python tools/import_graph.py --dot g.dot  # also a Graphviz file (dot -Tpng g.dot -o g.png)

Exit status 1 when a rule is broken (tests/test_layers.py runs it).
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: stage name, and the module prefixes it holds (the longest matching prefix decides)
STAGES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("semmap.errors", "semmap.version", "semmap.runtime", "semmap.geometry", "semmap.records",
              "semmap.palette", "semmap.io.yamlio", "semmap.config", "semmap.classes")),
    ("io", ("semmap.io",)),
    ("segment", ("semmap.segment",)),
    ("paint", ("semmap.paint",)),
    ("register", ("semmap.register",)),
    ("grid", ("semmap.grid",)),
    ("mapfolder", ("semmap.mapfolder",)),
    ("compare", ("semmap.compare",)),
    ("robotmap", ("semmap.robotmap",)),
    ("tools", ("semmap.sim", "semmap.calib")),
    ("run", ("semmap.workers", "semmap.pipeline")),
    ("cli", ("semmap.cli", "semmap.__main__", "semmap")),
)


def stage_of(module: str) -> int:
    best, best_len = -1, -1
    for i, (_, prefixes) in enumerate(STAGES):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best_len:
                best, best_len = i, len(p)
    return best


@dataclass
class Graph:
    modules: list[str] = field(default_factory=list)
    edges: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))
    layer_violations: list[str] = field(default_factory=list)
    private_violations: list[str] = field(default_factory=list)


def _module_name(path: Path, root: Path) -> tuple[str, str]:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    is_pkg = parts[-1] == "__init__"
    if is_pkg:
        parts = parts[:-1]
    mod = ".".join(parts)
    return mod, (mod if is_pkg else mod.rsplit(".", 1)[0])


def _resolve(pkg: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = pkg.split(".")
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _package(module: str, modules: set[str]) -> str:
    return module if module in modules and module + ".__init__" in modules else module.rsplit(".", 1)[0]


def analyse(root: Path) -> Graph:
    g = Graph()
    files = sorted(root.rglob("*.py"))
    names = {_module_name(f, root)[0] for f in files}
    for f in files:
        mod, pkg = _module_name(f, root)
        g.modules.append(mod)
        tree = ast.parse(f.read_text(encoding="utf-8"), filename=str(f))
        aliases: dict[str, str] = {}  # local name → semmap module it is bound to
        for node in ast.walk(tree):
            targets: list[tuple[str, str | None]] = []  # (module imported, name taken from it)
            if isinstance(node, ast.ImportFrom):
                target = _resolve(pkg, node)
                if not target.startswith("semmap"):
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    if sub in names:  # "from . import errors": a module
                        targets.append((sub, None))
                        aliases[a.asname or a.name] = sub
                    else:
                        targets.append((target, a.name))
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("semmap"):
                        targets.append((a.name, None))
                        if a.asname:
                            aliases[a.asname] = a.name
            for target, name in targets:
                if target == mod:
                    continue
                g.edges[mod].add(target)
                s_from, s_to = stage_of(mod), stage_of(target)
                if s_to > s_from and not (mod == "semmap" or mod.startswith("semmap.cli")):
                    g.layer_violations.append(f"{mod} ({STAGES[s_from][0]}) imports {target} "
                                              f"({STAGES[s_to][0]}), a later stage")
                leaf = target.rsplit(".", 1)[-1]
                if name is not None and name.startswith("_") and not name.startswith("__"):
                    g.private_violations.append(f"{mod} imports the private name {target}.{name}")
                elif name is None and leaf.startswith("_") and not leaf.startswith("__"):
                    owner = target.rsplit(".", 1)[0]
                    if not (mod == owner or mod.startswith(owner + ".")):
                        g.private_violations.append(f"{mod} imports the private module {target}")
        for node in ast.walk(tree):  # module._name
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                    and node.attr.startswith("_") and not node.attr.startswith("__")
                    and aliases[node.value.id] != mod):
                g.private_violations.append(f"{mod} uses the private name {aliases[node.value.id]}.{node.attr}")
    g.layer_violations = sorted(set(g.layer_violations))
    g.private_violations = sorted(set(g.private_violations))
    return g


def _short(m: str) -> str:
    return m.removeprefix("semmap.") if m != "semmap" else "semmap"


def report(g: Graph) -> str:
    lines = ["semmap's import graph, by stage (a module: the semmap modules it imports)", ""]
    by_stage: dict[int, list[str]] = defaultdict(list)
    for m in g.modules:
        by_stage[stage_of(m)].append(m)
    for i, (name, _) in enumerate(STAGES):
        lines.append(f"[{i}] {name}")
        for m in sorted(by_stage.get(i, [])):
            deps = sorted(_short(t) for t in g.edges.get(m, ()))
            lines.append(f"    {_short(m)}" + (f": {', '.join(deps)}" if deps else ""))
    lines += ["", f"imports of a later stage: {len(g.layer_violations)}", *[f"  {v}" for v in g.layer_violations],
              f"uses of another module's private name: {len(g.private_violations)}",
              *[f"  {v}" for v in g.private_violations]]
    return "\n".join(lines)


def dot(g: Graph) -> str:
    out = ["digraph semmap {", "  rankdir=LR; node [shape=box, fontsize=10];"]
    for i, (name, _) in enumerate(STAGES):
        mods = [m for m in g.modules if stage_of(m) == i]
        out.append(f'  subgraph cluster_{i} {{ label="{i} {name}"; ' + " ".join(f'"{_short(m)}";' for m in mods) + " }")
    for m, ts in sorted(g.edges.items()):
        for t in sorted(ts):
            out.append(f'  "{_short(m)}" -> "{_short(t)}";')
    out.append("}")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=REPO / "semmap", help="the package to analyse")
    ap.add_argument("--dot", type=Path, help="also write the graph as a Graphviz file")
    ap.add_argument("-q", "--quiet", action="store_true", help="print only the violations")
    args = ap.parse_args(argv)
    g = analyse(args.root)
    if args.quiet:
        print("\n".join(g.layer_violations + g.private_violations) or "no violations")
    else:
        print(report(g))
    if args.dot:
        args.dot.write_text(dot(g), encoding="utf-8")
    return 1 if g.layer_violations or g.private_violations else 0


if __name__ == "__main__":
    sys.exit(main())
