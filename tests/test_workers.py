"""The worker processes' set-up: what every stage's process is started with."""

from __future__ import annotations

import os
from multiprocessing.connection import Connection

import pytest

from semmap import workers


def _report_threads(out: Connection) -> None:
    import numpy as np
    from threadpoolctl import threadpool_info

    a = np.ones((400, 400))
    _ = a @ a  # large enough for OpenBLAS to use its threads, were it allowed
    out.send(("threads", [(i["user_api"], i["num_threads"]) for i in threadpool_info()]))


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: BLAS runs one thread anyway")
def test_worker_processes_run_one_blas_thread() -> None:
    # the registration, fusion and image workers share the cores: OpenBLAS's own threads spin while
    # they wait and took the other stages' CPU (the loop closer's registration worker used 2x its CPU)
    group = workers._Workers()
    try:
        w = group.add("semmap-test", "test", _report_threads)
        group.start()
        tag, info = group.recv(w)
    finally:
        group.close()
    assert tag == "threads"
    blas = [n for api, n in info if api == "blas"]
    assert blas, f"no BLAS library found in the worker: {info}"
    assert all(n == 1 for n in blas), info
