#!/usr/bin/env python3
"""Benchmark the segmentation backends: speed at 640×480, SAM 3's prompt scaling, and mapping
throughput while a backend runs in the build's frame worker.

1. **FPS per backend at 640×480** (the ACFR camera images when ../shared/data is present, else a
   synthetic frame): each backend's ``segment`` call, after a warm-up, median of the runs.
   - ``mediapipe-selfie``: the real pretrained model from ../shared/data/models.
   - ``onnx``: a YOLO11n-seg exported to ONNX (``--yolo-onnx`` or ``$SEMMAP_YOLO_ONNX``; weights are
     random unless you pass a trained export: speed does not depend on them, except that random
     weights detect nothing, so mask assembly costs nothing). Export one with Ultralytics:
     ``YOLO('yolo11n-seg.yaml').export(format='onnx', opset=17, dynamic=True)``.
   - ``sam3``: a random-weight SAM 3 of the ``small`` preset (``tests/sam3_helpers.py``: SAM 3 with
     widths and queries / 4 and the token grid / 2, so its FLOP split between the image embedding and
     a prompt's decoder run is SAM 3's at twice the side), 1 and 80 prompts.
   **SAM 3 prompt cost**: time(10 prompts) / time(1 prompt), the 1- and 10-prompt segmenters
   timed on alternate frames (median of each, and median of the per-frame-pair ratios, the figure
   least disturbed by other work on the machine), and each prompt's cost beyond the first, (a) at
   the default conf (random weights score every query ~0.25, so about half the queries of *every*
   prompt are kept and every prompt runs its mask head: the worst case), the prompts' decoder
   passes batched as the backend does and one call per prompt, (b) with conf 1 (no prompt keeps a
   query, so no mask head runs: the best case, a frame where none of the classes is present), (c)
   both at half the native side. Beside each ratio its floor, the ratio if time followed the FLOPs
   torch counts (``flop_split``: E + 10 D over E + D), and the FLOP split of SAM 3 itself.
   - ``ultralytics``: only where the package imports (it does not beside torch 2.13.0).
2. **Mapping throughput with a backend in its worker**: ``semmap build`` of a simulated tour
   (default ``demo``) with (a) the ``topic`` backend (labels from the bag: mapping alone), (b) the
   model backend in the frame worker (``workers: true``) and (c) everything in one process
   (``workers: false``), whose frame source also reports segmentation's own time (decoding and
   model). Reported: how close (b) comes to max(mapping, segmentation) rather than their sum.

    python tools/bench_segment.py --yolo-onnx /path/yolo11n-seg.onnx --json seg.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
sys.path.insert(0, str(REPO / "tests"))  # sam3_helpers: the random-weight SAM 3 models
from benchlib import machine

#: FPS targets at 640×480 per backend (label prefix): the selfie model ran at 4-7 ms per image when
#: tests/test_segment_selfie.py asserted > 20 FPS; YOLO11n-seg's is the one docs/benchmarks.md gives
FPS_TARGETS = {"mediapipe-selfie": 20.0, "onnx": 15.0}

BUILD_CHILD = r"""
import json, sys
from semmap.pipeline import build
r = build(sys.argv[1], sys.argv[2], overrides=json.loads(sys.argv[3]), force=True)
s = r.summary.model_dump(mode="json")
print(json.dumps({"loop_s": s["timings_s"]["loop"], "total_s": s["timings_s"]["total"],
                  "scans": s["counts"]["scans"], "images": s["counts"].get("images", 0),
                  "segmentation_busy_s": s["timings_s"]["segmentation_busy"],
                  "scans_per_s": s["throughput"]["scans_per_s"]}))
"""



def frame_640x480(data: Path) -> np.ndarray:
    import cv2

    imgs = sorted((data / "acfr_calib" / "examples" / "images").glob("*.png"))
    if imgs:
        img = cv2.imread(str(imgs[0]))
        if img is not None and img.shape[:2] == (480, 640):
            return np.ascontiguousarray(img[:, :, ::-1])
    rng = np.random.default_rng(0)
    return rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)


def time_backend(cfg, rgb: np.ndarray, runs: int) -> dict:
    from semmap.records import Image
    from semmap.segment.base import create_segmenter

    seg = create_segmenter(cfg, cache=False)
    try:
        t0 = time.perf_counter()
        seg.segment(Image(0, "cam", rgb, "rgb8"))
        load_s = time.perf_counter() - t0
        times = []
        for i in range(runs):
            # a new stamp and a changed pixel each run: no cached embedding is reused across frames
            frame = rgb.copy()
            frame[0, 0, 0] = i % 256
            t0 = time.perf_counter()
            seg.segment(Image(i + 1, "cam", frame, "rgb8"))
            times.append(time.perf_counter() - t0)
        extra = {}
        if cfg.backend == "sam3":
            extra["input_side"] = seg.input_side
    finally:
        seg.close()
    med = statistics.median(times)
    return {"fps": 1.0 / med, "ms": med * 1e3, "first_call_s": load_s, "runs": runs, **extra}


def sam3_ratio(cfg1, cfg10, rgb: np.ndarray, runs: int, one_at_a_time: bool = False) -> dict:
    """time(10 prompts) / time(1 prompt), the two segmenters timed on alternate frames
    (``one_at_a_time``: each prompt's decoder pass in a call of its own, not batched)."""
    from semmap.records import Image
    from semmap.segment.base import create_segmenter

    segs = {1: create_segmenter(cfg1, cache=False), 10: create_segmenter(cfg10, cache=False)}
    try:
        for seg in segs.values():
            if one_at_a_time:
                seg.prompt_batch = lambda: 1
            seg.segment(Image(0, "cam", rgb, "rgb8"))  # load, warm up
            seg.stats.update(decoder_runs=0, mask_heads=0, decoder_calls=0)
        times: dict[int, list[float]] = {1: [], 10: []}
        for i in range(runs):
            frame = rgb.copy()
            frame[0, 0, 0] ^= (i % 255) + 1  # a new frame each run: no embedding reused
            for n, seg in segs.items():
                t0 = time.perf_counter()
                seg.segment(Image(i + 1, "cam", frame, "rgb8"))
                times[n].append(time.perf_counter() - t0)
        m1, m10 = statistics.median(times[1]), statistics.median(times[10])
        st = segs[10].stats
        return {"side": segs[1].input_side, "ms_1": m1 * 1e3, "ms_10": m10 * 1e3, "ratio": m10 / m1,
                "ratio_pairs": statistics.median(b / a for a, b in zip(times[1], times[10])), "runs": runs,
                "ms_per_extra_prompt": (m10 - m1) * 1e3 / 9,
                "mask_heads_per_prompt": st["mask_heads"] / max(1, st["decoder_runs"]),
                "prompts_per_call": st["decoder_runs"] / max(1, st["decoder_calls"])}
    finally:
        for seg in segs.values():
            seg.close()


def sam3_kept(sam3_dir: Path, rgb: np.ndarray, conf: float) -> tuple[float, int]:
    """Random weights: how many of a prompt's queries pass conf (mean over 10 prompts), of how many."""
    import torch

    from semmap.classes import load_class_table
    from semmap.config import Sam3Segmentation
    from semmap.segment.sam3 import Sam3Segmenter

    seg = Sam3Segmenter(Sam3Segmentation(model=sam3_dir,
                                         prompts=load_class_table(None).names("coco")[:10], conf=conf))
    try:
        with torch.inference_mode():
            embed = seg.image_embedding(rgb)
            kept = [int(seg._decode(embed, text, mask)[1].numel()) for text, mask, _ in seg._text]
        return statistics.mean(kept), seg._queries
    finally:
        seg.close()


def sam3_scaling(sam3_dir: Path, rgb: np.ndarray, args, results: dict) -> None:
    from sam3_helpers import PRESETS, flop_split, random_config

    from semmap.classes import load_class_table
    from semmap.config import Sam3Segmentation

    coco = load_class_table(None).names("coco")
    native = PRESETS["small"]["side"]
    kept, queries = sam3_kept(sam3_dir, rgb, Sam3Segmentation().conf)
    settings = [("default conf, every prompt keeps queries", {}, False),
                ("the same, one prompt per decoder call", {}, True),
                ("conf 1: no prompt keeps a query", {"conf": 1.0}, False),
                (f"half side ({native // 2} px), default conf", {"imgsz": native // 2}, False),
                (f"half side ({native // 2} px), conf 1", {"imgsz": native // 2, "conf": 1.0}, False)]
    # the floor: the ratio time(10)/time(1) would be if time followed FLOPs, E + 10 D over E + D
    floors: dict[int, float] = {}
    results["flops"] = []
    if not args.skip_flops:
        for name, cfg, side in (("SAM 3", None, 1008), ("SAM 3", None, 504),
                                ("small preset", random_config("small"), native),
                                ("small preset", random_config("small"), native // 2)):
            f = flop_split(cfg, side)
            f["floor"] = (f["vision"] + 10 * f["decoder"]) / (f["vision"] + f["decoder"])
            results["flops"].append({"model": name, **f})
            if cfg is not None:
                floors[side] = f["floor"]
    runs = max(5, args.runs // 5)
    print(f"\nSAM 3 prompt cost, `small` preset, 1 vs 10 prompts on alternate frames ({runs} pairs; random "
          f"weights keep {kept:.1f} of {queries} queries per prompt at the default conf "
          f"{Sam3Segmentation().conf}). The floor is the ratio if time followed FLOPs:\n")
    print("| setting | input | prompts per call | 1 prompt, ms | 10 prompts, ms | each prompt beyond the first, ms "
          "| **ratio, median of the pairs** | floor from FLOPs | mask heads run per prompt |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    results["sam3_scaling"] = []
    for label, extra, one in settings:
        cfgs = [Sam3Segmentation(model=sam3_dir, prompts=coco[:n], threads=args.threads, **extra)
                for n in (1, 10)]
        r = sam3_ratio(cfgs[0], cfgs[1], rgb, runs, one_at_a_time=one)
        r["setting"] = label
        r["floor"] = floors.get(r["side"])
        results["sam3_scaling"].append(r)
        floor = f"{r['floor']:.2f}" if r["floor"] else "-"
        print(f"| {label} | {r['side']}² | {r['prompts_per_call']:.0f} | {r['ms_1']:.0f} | {r['ms_10']:.0f} | "
              f"{r['ms_per_extra_prompt']:.0f} | **{r['ratio_pairs']:.2f}** | {floor} | "
              f"{r['mask_heads_per_prompt']:.2f} |")
    # the per-pair ratio: both timings of a pair ran back to back, so load from other work cancels best
    results["sam3_ratio_10_over_1"] = results["sam3_scaling"][0]["ratio_pairs"]
    results["sam3_kept_queries_per_prompt"] = kept
    if not results["flops"]:
        return
    print("\nFLOPs (torch's FlopCounterMode, attention included) of the image embedding and of one prompt's "
          "decoder run; the last column is the ratio time(10)/time(1) would be if time followed FLOPs:\n")
    print("| model | input | embedding, GFLOP | decoder / prompt, GFLOP | of which mask head | embedding / decoder "
          "| (E + 10 D) / (E + D) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for f in results["flops"]:
        e, d = f["vision"], f["decoder"]
        print(f"| {f['model']} | {f['side']}² | {e:.1f} | {d:.2f} | {f['decoder_parts']['mask_decoder'] / d:.0%} | "
              f"{e / d:.1f} | {f['floor']:.2f} |")


def run_child(code: str, *args: str) -> dict:
    res = subprocess.run([sys.executable, "-c", code, *args], check=False, capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(res.stderr[-3000:])
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("SEMMAP_DATA", REPO.parent / "shared" / "data")))
    ap.add_argument("--yolo-onnx", type=Path, default=os.environ.get("SEMMAP_YOLO_ONNX"),
                    help="a YOLO11n-seg ONNX export (default $SEMMAP_YOLO_ONNX)")
    ap.add_argument("--ultralytics-pt", type=Path, help="a .pt model for the ultralytics backend")
    ap.add_argument("--runs", type=int, default=30, help="timed frames per backend (SAM 3: a fifth)")
    ap.add_argument("--scenario", default="demo", help="simulated tour for the mapping throughput")
    ap.add_argument("--pipeline-backend", nargs="+", default=None,
                    help="backends for the mapping-throughput runs (default: mediapipe-selfie, and onnx if given)")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads per model (0: the runtime's default)")
    ap.add_argument("--pipeline-threads", type=int, default=1,
                    help="model threads in the build's frame worker (default 1: the mapping workers get the "
                         "other core)")
    ap.add_argument("--skip-pipeline", action="store_true")
    ap.add_argument("--skip-sam3-scaling", action="store_true", help="skip SAM 3's prompt-scaling section")
    ap.add_argument("--skip-flops", action="store_true", help="skip counting SAM 3's FLOPs (a few seconds)")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()

    from semmap.config import (
        OnnxSegmentation,
        Sam3Segmentation,
        SegmentationConfig,
        SelfieSegmentation,
        UltralyticsSegmentation,
    )

    rgb = frame_640x480(args.data)
    results: dict = {"date": date.today().isoformat(), "machine": machine(), "fps": {}, "notes": []}
    print(f"# semmap segmentation benchmark, {results['date']}, {results['machine']}\n")

    candidates: list[tuple[str, SegmentationConfig, int]] = []
    selfie = args.data / "models" / "selfie_segmentation.tflite"
    if selfie.is_file():
        candidates.append(("mediapipe-selfie", SelfieSegmentation(model=selfie, threads=args.threads),
                           args.runs * 3))
    if args.yolo_onnx:
        candidates.append((f"onnx ({args.yolo_onnx.name})", OnnxSegmentation(model=args.yolo_onnx,
                                                                           threads=args.threads),
                           args.runs))
    else:
        results["notes"].append("onnx: no --yolo-onnx / $SEMMAP_YOLO_ONNX given")
    sam3_dir = None
    try:
        from sam3_helpers import save_random_model

        sam3_dir = save_random_model(Path(tempfile.mkdtemp(prefix="semmap-sam3-")) / "small", "small")
        from semmap.classes import load_class_table

        coco = load_class_table(None).names("coco")
        for n in (1, 80):
            candidates.append((f"sam3 (small, {n} prompt{'s' if n > 1 else ''})",
                               Sam3Segmentation(model=sam3_dir, prompts=coco[:n],
                                                threads=args.threads),
                               max(3, args.runs // 5)))
    except Exception as exc:
        results["notes"].append(f"sam3: {type(exc).__name__}: {exc}")
    if args.ultralytics_pt:
        candidates.append(("ultralytics", UltralyticsSegmentation(model=args.ultralytics_pt),
                           args.runs))
    else:
        try:
            import ultralytics  # noqa: F401
        except Exception as exc:
            results["notes"].append(f"ultralytics: does not import here ({type(exc).__name__}: "
                                    f"{str(exc).splitlines()[0][:120]})")

    print(f"load average before: {os.getloadavg()[0]:.2f}\n")
    print("| backend | ms / frame (median) | FPS at 640×480 | first call (load), s |")
    print("|---|---:|---:|---:|")
    for label, cfg, runs in candidates:
        try:
            r = time_backend(cfg, rgb, runs)
        except Exception as exc:
            results["notes"].append(f"{label}: {type(exc).__name__}: {exc}")
            continue
        results["fps"][label] = r
        side = f" (input {r['input_side']}²)" if "input_side" in r else ""
        print(f"| {label}{side} | {r['ms']:.1f} | {r['fps']:.1f} | {r['first_call_s']:.2f} |")
    for label, r in results["fps"].items():  # the speed targets (each once a unit test's assert)
        target = next((fps for name, fps in FPS_TARGETS.items() if label.startswith(name)), None)
        if target is not None:
            r["target_fps"], r["target_met"] = target, r["fps"] >= target
            print(f"target: {label} ≥ {target:.0f} FPS at 640×480: {'met' if r['target_met'] else 'NOT met'} "
                  f"({r['fps']:.1f})")
    if sam3_dir is not None and not args.skip_sam3_scaling:
        try:
            sam3_scaling(sam3_dir, rgb, args, results)
        except Exception as exc:
            results["notes"].append(f"sam3 scaling: {type(exc).__name__}: {exc}")

    if not args.skip_pipeline:
        from semmap.sim.tour import simulate

        work = Path(tempfile.mkdtemp(prefix="semmap-bench-seg-"))
        tour = simulate(args.scenario, work / "tour", seed=0, force=True).out
        mapping = run_child(BUILD_CHILD, str(tour), str(work / "m_topic"), json.dumps({}))
        backends = args.pipeline_backend or (["mediapipe-selfie"] + (["onnx"] if args.yolo_onnx else []))
        results["pipeline"] = []
        print(f"\nMapping throughput, `{args.scenario}` tour ({mapping['scans']} scans), the model in the frame "
              f"worker with {args.pipeline_threads} thread(s):\n")
        print("| backend | mapping alone, s | segmentation alone, s | **build, model in its worker**, s "
              "| all in one process, s | max / sum, s | gained of (sum − max) | scans/s alone → with model |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        for backend in backends:
            seg = {"backend": backend, "threads": args.pipeline_threads}
            if backend == "onnx":
                seg["model"] = str(args.yolo_onnx)
            elif backend == "mediapipe-selfie":
                seg["model"] = str(selfie)
            both = run_child(BUILD_CHILD, str(tour), str(work / "m_worker"), json.dumps({"segmentation": seg}))
            serial = run_child(BUILD_CHILD, str(tour), str(work / "m_serial"),
                               json.dumps({"segmentation": seg, "workers": False}))
            # segmentation's own time: decoding + segment calls, as the frame source counts it in the
            # one-process build (there it never runs beside mapping, so it is not slowed by it)
            t_map, t_seg, t_both = mapping["loop_s"], serial["segmentation_busy_s"], both["loop_s"]
            best, worst = max(t_map, t_seg), t_map + t_seg
            frac = (worst - t_both) / (worst - best) if worst > best else float("nan")
            row = {"scenario": args.scenario, "backend": backend, "scans": mapping["scans"],
                   "images": serial["images"], "mapping_alone_s": t_map, "segmentation_alone_s": t_seg,
                   "with_worker_s": t_both, "in_one_process_s": serial["loop_s"], "max_s": best, "sum_s": worst,
                   "share_of_overlap_gained": frac, "scans_per_s_mapping_alone": mapping["scans_per_s"],
                   "scans_per_s_with_worker": both["scans_per_s"]}
            results["pipeline"].append(row)
            print(f"| {backend} ({serial['images']} images) | {t_map:.2f} | {t_seg:.2f} | **{t_both:.2f}** | "
                  f"{serial['loop_s']:.2f} | {best:.2f} / {worst:.2f} | {100 * frac:.0f} % | "
                  f"{mapping['scans_per_s']} → {both['scans_per_s']} |")
    results["load_average_after"] = os.getloadavg()[0]
    print(f"\nload average after: {results['load_average_after']:.2f}")
    for n in results["notes"]:
        print(f"note: {n}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
