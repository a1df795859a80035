"""Faults are features: whatever happens to a process of `semmap build`, nothing hangs and nothing is left.

Each case runs the real command line in its own session, kills a worker or signals the
command at a given moment, and checks what a user (and their robot's disk) is left with:
the exit code, one error line without a traceback, no process of the build still running,
no shared memory of it in /dev/shm, and no output folder, hidden or not.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from semmap.config import GridConfig, RegistrationConfig, TopicSegmentation
from semmap.errors import InternalError
from semmap.workers import ImageWorker, MapperWorkers

WORKERS = ("semmap-images", "semmap-register", "semmap-fusion")
STAGE = {"semmap-images": "images", "semmap-register": "registration", "semmap-fusion": "fusion"}


@pytest.fixture(scope="module")
def tour(tmp_path_factory):
    """A 12 s demo tour, and the config that segments it in a frame worker: label PNGs written by
    `semmap segment` (the `folder` backend decodes every camera image in the worker)."""
    from semmap.segment.run import segment_source
    from semmap.sim.scenarios import demo
    from semmap.sim.tour import simulate

    root = tmp_path_factory.mktemp("faults")
    t = simulate(replace(demo().world, duration_s=12.0), root / "demo", seed=2)
    segment_source(t.out, root / "seg", TopicSegmentation(), overlays=False)
    cfg = root / "worker.yaml"
    cfg.write_text(f"segmentation:\n  backend: folder\n  folder: {root / 'seg' / 'labels'}\n")
    return t.out, cfg


def _children(pid: int) -> dict[int, str]:
    """Child processes of ``pid`` and their names (/proc)."""
    out = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids = (task / "children").read_text().split()
        except OSError:
            continue
        for k in kids:
            with contextlib.suppress(OSError):
                out[int(k)] = Path(f"/proc/{k}/comm").read_text().strip()
    return out


def _shm_mapped(pid: int) -> set[str]:
    """Shared-memory files a process has mapped."""
    try:
        lines = Path(f"/proc/{pid}/maps").read_text().splitlines()
    except OSError:
        return set()
    return {line.split()[-1] for line in lines if "/dev/shm/" in line}


def _has_open(pid: int, name: str) -> bool:
    """Whether a process has a file of this name open."""
    for fd in Path(f"/proc/{pid}/fd").glob("*"):
        try:
            if os.readlink(fd).endswith(name):
                return True
        except OSError:
            pass
    return False


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Run:
    """`semmap build` in its own session, watched from outside."""

    def __init__(self, args: list[str], cwd: Path) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        # as from a terminal: a test runner started in the background by a non-interactive shell
        # inherits SIGINT ignored, and so would the build, which would then rightly ignore Ctrl-C
        self.proc = subprocess.Popen([sys.executable, "-m", "semmap", *args], cwd=cwd, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True,
                                     preexec_fn=_default_sigint)  # noqa: PLW1509 - it only resets SIGINT
        self.seen: dict[int, str] = {}
        self.shm: set[str] = set()

    def watch(self) -> None:
        self.seen.update(_children(self.proc.pid))
        self.shm |= _shm_mapped(self.proc.pid)

    def wait_for(self, what, timeout: float = 60.0) -> None:
        """Poll until ``what()`` holds (the build is still running), recording its processes."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.watch()
            if what():
                return
            if self.proc.poll() is not None:
                raise AssertionError(f"the build ended first: {self.proc.returncode} {self.proc.stderr.read()}")
            time.sleep(0.02)
        raise AssertionError("timed out waiting for the build")

    def pause(self, seconds: float) -> None:
        """Let the build run on for a while, recording its processes."""
        end = time.monotonic() + seconds
        self.wait_for(lambda: time.monotonic() >= end)

    def wait_for_loop(self) -> None:
        """Until the scans stream: every worker started, and the build reads the bag for its loop."""
        self.wait_for(lambda: all(self.worker(w) is not None for w in WORKERS))
        self.wait_for(lambda: _has_open(self.proc.pid, ".bag"))
        self.pause(0.2)

    def worker(self, name: str) -> int | None:
        return next((pid for pid, comm in _children(self.proc.pid).items() if comm == name), None)

    def finish(self, timeout: float = 30.0) -> tuple[int, str]:
        try:
            _, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.communicate()
            raise AssertionError(f"the build hung: no exit {timeout} s after the fault") from None
        return self.proc.returncode, err


def _assert_clean(run: Run, out: Path) -> None:
    time.sleep(0.5)  # the resource tracker ends once its last user has
    alive = {pid: comm for pid, comm in run.seen.items() if _running(pid)}
    assert not alive, f"processes left running: {alive}"
    assert run.seen, "the build's processes were never seen"
    left = {p for p in run.shm if Path(p).exists()}
    assert not left, f"shared memory left: {left}"
    assert not out.exists(), f"{out} was written"
    assert not list(out.parent.glob(f".{out.name}.*")), "a hidden partial folder was left"


def _one_line(err: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, err


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSEGV])
@pytest.mark.parametrize("name", WORKERS)
def test_a_killed_worker_is_one_error_line_and_nothing_is_left(tour, tmp_path, name, sig):
    bag, cfg = tour
    out = tmp_path / "map"
    run = Run(["build", str(bag), "--config", str(cfg), "--out", str(out)], tmp_path)
    run.wait_for_loop()
    pid = run.worker(name)
    assert pid is not None
    t0 = time.monotonic()
    os.kill(pid, sig)
    code, err = run.finish()
    assert time.monotonic() - t0 < 10, "the failure took more than a few seconds to surface"
    assert code == 6, err
    _one_line(err, f"the {STAGE[name]} worker was killed by {signal.Signals(sig).name}")
    _assert_clean(run, out)


@pytest.mark.parametrize("moment", ["start-up", "mid-build", "writing"])
@pytest.mark.parametrize("sig,target", [(signal.SIGTERM, "main"), (signal.SIGINT, "main"), (signal.SIGINT, "group"),
                                        (signal.SIGHUP, "group")])
def test_signals_stop_everything_and_leave_nothing(tour, tmp_path, sig, target, moment):
    bag, cfg = tour
    out = tmp_path / "map"
    run = Run(["build", str(bag), "--config", str(cfg), "--out", str(out)], tmp_path)
    if moment == "start-up":  # the workers exist but are still loading their libraries
        run.wait_for(lambda: run.worker("semmap-images") is not None)
    elif moment == "mid-build":
        run.wait_for_loop()
    else:  # the map folder is being written into its hidden folder
        run.wait_for(lambda: any(tmp_path.glob(".map.*.partial/map.pgm")), timeout=120)
        # hold the build there, so the signal lands before the folder is renamed into place however
        # slowly this test is scheduled (on a loaded CI host the writing once ended between two polls)
        os.kill(run.proc.pid, signal.SIGSTOP)
        assert not out.exists() and not any(tmp_path.glob(".map.*.partial/summary.json")), \
            "the map folder was written before the build could be held"
    if target == "main":
        os.kill(run.proc.pid, sig)
    else:  # Ctrl-C in a terminal, a closed terminal: every process of the group gets it
        os.killpg(run.proc.pid, sig)
    if moment == "writing":
        os.kill(run.proc.pid, signal.SIGCONT)
    code, err = run.finish()
    assert code == 128 + sig, err
    _one_line(err, "interrupted" if sig == signal.SIGINT else "terminated", signal.Signals(sig).name)
    _assert_clean(run, out)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the half-closed ZipFile's __del__
def test_a_signal_that_cuts_the_grid_file_short_is_reported_as_the_signal(tour, tmp_path, monkeypatch, capsys):
    # Ctrl-C landing while np.savez closes one array of grid.npz leaves the ZipFile with an open writing
    # handle, and closing it raises ValueError("... open writing handle"), which replaced the signal: CI
    # saw "internal error" and exit 70 once. The error of the unwinding is the signal's: 130, one line
    import zipfile

    from semmap.cli.main import main

    bag, cfg = tour
    one = tmp_path / "one.yaml"
    one.write_text(cfg.read_text() + "workers: false\n")
    close = zipfile._ZipWriteFile.close

    def cut(self):
        if str(self._zipfile.filename).endswith("grid.npz") and self._zinfo.filename == "hits.npy":
            raise KeyboardInterrupt
        return close(self)

    monkeypatch.setattr(zipfile._ZipWriteFile, "close", cut)
    out = tmp_path / "map"
    code = main(["build", str(bag), "--config", str(one), "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert code == 128 + signal.SIGINT, err
    _one_line(err, "interrupted", "SIGINT")
    assert not out.exists() and not list(tmp_path.glob(".map.*")), "a partial map folder was left"
    # the half-closed ZipFile is finalised here (its __del__ raises once more, ignored), not during
    # some later compile, where CPython 3.11 takes an exception from a finaliser badly
    import gc

    gc.collect()


@pytest.mark.parametrize("at_end", [False, True], ids=["while the tour plays", "while the tour is fused at the end"])
@pytest.mark.parametrize("fault", ["kill the fusion worker", "SIGTERM"])
def test_with_loop_closure_a_fault_leaves_nothing(tour, tmp_path, fault, at_end):
    # with loop closure the fusion worker runs the loop closer while the tour plays, and at its end that
    # worker and this process each fuse part of the tour from the corrected poses (the registration
    # worker has ended): killing the worker, or stopping the build, at either moment is one error line
    # and leaves no process, shared memory or folder behind. A 1 cm grid makes the fusion at the end
    # last a second or two (during the tour the scans are only spooled)
    bag, cfg = tour
    lc = tmp_path / "lc.yaml"
    lc.write_text(cfg.read_text() + "registration:\n  loop_closure:\n    enabled: true\n"
                  + ("grid:\n  resolution: 0.01\n" if at_end else ""))
    out = tmp_path / "map"
    run = Run(["build", str(bag), "--config", str(lc), "--out", str(out)], tmp_path)
    run.wait_for_loop()  # the scans stream, the loop closer takes them in
    fusion = run.worker("semmap-fusion")
    assert fusion is not None
    if at_end:
        run.wait_for(lambda: run.worker("semmap-register") is None, timeout=120)  # the tour's end
        # hold both there, however slowly this test is scheduled
        os.kill(run.proc.pid, signal.SIGSTOP)
        os.kill(fusion, signal.SIGSTOP)
        assert _running(fusion) and not out.exists(), "the fusion worker had finished before it could be held"
    if fault == "SIGTERM":
        os.kill(run.proc.pid, signal.SIGTERM)
    else:
        os.kill(fusion, signal.SIGKILL)
    if at_end:
        with contextlib.suppress(ProcessLookupError):
            os.kill(fusion, signal.SIGCONT)
        os.kill(run.proc.pid, signal.SIGCONT)
    code, err = run.finish()
    if fault == "SIGTERM":
        assert code == 128 + signal.SIGTERM, err
        _one_line(err, "terminated", "SIGTERM")
    else:
        assert code == 6, err
        _one_line(err, "the fusion worker was killed by SIGKILL")
    _assert_clean(run, out)


def test_memory_exhausted_in_fusion_is_an_error_not_a_hang(tour, tmp_path):
    """The fusion worker's address space is capped once it has started: its grid cannot be handed over."""
    import resource

    bag, cfg = tour
    # one 100 m tile: the grid is allocated at the first scan (its tiles no longer grow as the robot
    # moves through a room), and the window handed over at the end (about 100 MB) needs memory the cap
    # below does not leave
    big = tmp_path / "big_tile.yaml"
    big.write_text(cfg.read_text() + "grid:\n  tile_margin: 100.0\n")
    out = tmp_path / "map"
    run = Run(["build", str(bag), "--config", str(big), "--out", str(out)], tmp_path)
    run.wait_for(lambda: run.worker("semmap-fusion") is not None and run.worker("semmap-images") is not None)
    time.sleep(0.3)
    pid = run.worker("semmap-fusion")
    vm = int(next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                  if line.startswith("VmSize")).split()[1]) * 1024
    resource.prlimit(pid, resource.RLIMIT_AS, (vm + (4 << 20), vm + (4 << 20)))
    code, err = run.finish()
    assert code == 6, err
    _one_line(err, "the fusion worker ran out of memory")
    _assert_clean(run, out)


def test_a_bug_in_a_worker_is_reported_as_a_bug_with_its_traceback():
    mapper = MapperWorkers(RegistrationConfig(mode="odometry"), GridConfig(), ())
    try:
        mapper.wait_ready()
        # the failure surfaces at the next push or at finish, whichever comes after the worker's report
        with pytest.raises(InternalError, match="in the registration worker: AttributeError") as info:
            for _ in range(20):
                mapper.push(object(), np.zeros(3))  # not a painted scan: the registrar fails on it
            mapper.finish()
        assert "registrar.py" in str(info.value.__cause__)  # the worker's own traceback travels with it
    finally:
        mapper.close()


def test_a_bug_in_the_frame_worker_is_reported_as_a_bug(tour):
    bag, _ = tour
    images = ImageWorker(bag / "demo.bag", "/scan", TopicSegmentation(), (480, 640))  # scans are not images
    try:
        with pytest.raises(InternalError, match="in the images worker: AttributeError"):
            images.wait_ready()
            images.next()
    finally:
        images.close()


def test_cli_exit_code_70_and_worker_traceback_with_debug(monkeypatch, capsys):
    from semmap.cli import build as build_cmd
    from semmap.cli.main import main

    def run(args):  # a command whose registration worker meets a bug
        mapper = MapperWorkers(RegistrationConfig(mode="odometry"), GridConfig(), ())
        try:
            mapper.wait_ready()
            mapper.push(object(), np.zeros(3))
            mapper.finish()
        finally:
            mapper.close()

    monkeypatch.setattr(build_cmd, "run", run)
    assert main(["build", "--demo", "--out", "unused"]) == 70
    err = capsys.readouterr().err
    _one_line(err, "internal error in the registration worker: AttributeError")
    with pytest.raises(InternalError) as info:
        main(["build", "--demo", "--out", "unused", "--debug"])
    assert "Traceback" in str(info.value.__cause__)


def test_worker_log_lines_reach_the_user(tour, tmp_path):
    """Log records of the registration worker appear on the command line's stderr with -v."""
    bag, _ = tour
    cfg = tmp_path / "c.yaml"
    # a filter that restarts at once: every rejected ICP result is logged by the registration worker
    cfg.write_text("registration:\n  ekf:\n    gate_chi2: 0.0001\n    reset_after: 1\n")
    res = subprocess.run([sys.executable, "-m", "semmap", "build", str(bag), "--config", str(cfg), "--out",
                          str(tmp_path / "m"), "-v"], capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    assert "restarting the filter" in res.stderr
    summary = json.loads((tmp_path / "m" / "summary.json").read_text())
    assert summary["registration"]["filter_resets"] > 0


def test_demo_interrupted_while_simulating_leaves_nothing(tmp_path):
    import tempfile

    before = set(Path(tempfile.gettempdir()).glob("semmap-demo-*"))
    out = tmp_path / "map"
    run = Run(["build", "--demo", "--out", str(out)], tmp_path)
    run.wait_for(lambda: any(Path(tempfile.gettempdir()).glob("semmap-demo-*/.demo.*.partial")))
    os.kill(run.proc.pid, signal.SIGTERM)
    code, err = run.finish()
    assert code == 143, err
    _one_line(err, "terminated (SIGTERM)")
    assert not out.exists()
    assert set(Path(tempfile.gettempdir()).glob("semmap-demo-*")) == before


def test_a_signal_after_the_output_is_complete_does_not_fail_the_command(monkeypatch, capsys, tmp_path):
    """Ctrl-C between the map folder's rename into place and the command's return: the map is there,
    so the command reports success, not an interruption that left a complete map behind."""
    from semmap.cli import build as build_cmd
    from semmap.cli.main import main
    from semmap.io.atomic import atomic_dir

    def run(args):
        with atomic_dir(args.out) as tmp:
            (tmp / "summary.json").write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(build_cmd, "run", run)
    assert main(["build", "--demo", "--out", str(tmp_path / "m")]) == 0
    assert "SIGINT arrived after" in capsys.readouterr().err
    assert (tmp_path / "m" / "summary.json").exists()


_HALF_BUILT = r"""
import os, signal, sys, time
from semmap.cli.main import _stop_signals_raise

# Ctrl-C as in a terminal (a background job of a non-interactive shell starts with SIGINT ignored)
signal.signal(signal.SIGINT, signal.default_int_handler)
from semmap.errors import Interrupted

class HalfBuilt:
    def __del__(self):
        raise AttributeError("'HalfBuilt' object has no attribute '_writing'")

def write():
    obj = HalfBuilt()  # dropped as the signal's exception unwinds this frame
    os.kill(os.getpid(), int(sys.argv[1]))
    time.sleep(5)  # the handler raises here

try:
    with _stop_signals_raise():
        write()
except (Interrupted, KeyboardInterrupt):
    print("stopped")
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_half_built_object_cut_short_by_a_signal_prints_no_traceback(sig):
    """A stop signal can land inside a constructor (``np.savez`` opening its ``ZipFile``); that object's
    ``__del__`` then fails while the stack unwinds. The command still says one line, not a traceback."""
    res = subprocess.run([sys.executable, "-c", _HALF_BUILT, str(int(sig))], capture_output=True, text=True,
                         timeout=60, check=False)
    assert res.stdout.strip() == "stopped"
    assert res.stderr == ""


_IN_A_FINALIZER = r"""
import gc, os, signal, sys
from pathlib import Path
from semmap.cli.main import _stop_signals_raise
from semmap.errors import Interrupted
from semmap.io.atomic import atomic_dir

signal.signal(signal.SIGINT, signal.default_int_handler)

class Dropped:
    def __del__(self):  # the garbage collector frees it mid-write, and the signal lands here
        os.kill(os.getpid(), int(sys.argv[1]))
        for _ in range(1000):  # the handler runs, and raises, at one of these steps
            pass

out = Path(sys.argv[2])
try:
    with _stop_signals_raise(), atomic_dir(out) as tmp:
        (tmp / "map.pgm").write_text("P5")
        d = Dropped()
        del d  # its __del__'s exception is unraisable: Python drops it
        (tmp / "summary.json").write_text("{}")  # the build writes on, as if nothing had come
    print("committed")
except (Interrupted, KeyboardInterrupt):
    print("stopped")
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_whose_exception_a_finalizer_dropped_still_leaves_no_output(sig, tmp_path):
    """A stop signal's handler raises wherever the main thread is; inside a finalizer (an object the
    garbage collector frees while the map folder's pictures are drawn) Python drops that exception, and
    the build used to write its folder and exit 0 (seen once on CI: a SIGHUP to the group while writing).
    The folder must not be committed, and the command stops."""
    out = tmp_path / "map"
    res = subprocess.run([sys.executable, "-c", _IN_A_FINALIZER, str(int(sig)), str(out)], capture_output=True,
                         text=True, timeout=60, check=False)
    assert res.stdout.strip() == "stopped", res.stderr
    assert not out.exists() and not list(tmp_path.glob(".map.*")), "the output was committed or left behind"
