#!/usr/bin/env python3
"""The README's `semmap export` picture: the exported cleaned map, the static-only map and the keepout
mask of a map folder, side by side, each drawn from the image file a robot loads.

Usage::

    semmap build --demo --out maps/demo
    python tools/export_figure.py maps/demo --out docs/images/export_demo.png
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import semmap
from semmap.io.yamlio import read_yaml


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "images" / "export_demo.png")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "export"
        semmap.export(args.session, out, semmap.ExportSettings(crop_margin=0.3))
        panels = [("cleaned.yaml", "cleaned: people gone, furniture kept"),
                  ("static.yaml", "static only: furniture unknown"),
                  ("keepout_mask.yaml", "nav2 keepout mask")]
        fig, axes = plt.subplots(1, 3, figsize=(13.5, 3.9), dpi=100)
        for ax, (name, title) in zip(axes, panels, strict=True):
            meta = read_yaml(out / name, "map")
            img = cv2.imread(str(out / str(meta["image"])), cv2.IMREAD_UNCHANGED)
            res = float(meta["resolution"])
            ox, oy = float(meta["origin"][0]), float(meta["origin"][1])
            h, w = img.shape[:2]
            ax.imshow(img, cmap="gray", vmin=0, vmax=255, interpolation="nearest",
                      extent=(ox, ox + w * res, oy, oy + h * res))
            ax.set_title(f"{title}\n{name.replace('.yaml', '.pgm')}", fontsize=10)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.add_artist(AnchoredSizeBar(ax.transData, 2.0, "2 m", "lower right", pad=0.3, frameon=True,
                                          size_vertical=res))
        fig.suptitle("semmap export of the demo tour (black: occupied, grey: unknown, white: free)", fontsize=11)
        fig.tight_layout()
        args.out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.out)
        plt.close(fig)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
