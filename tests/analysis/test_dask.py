"""``--scheduler``: the same analysis on a Dask cluster started on the loopback interface."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from shapely.geometry import box

from printability.analysis import analyze
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack

distributed = pytest.importorskip(
    "dask.distributed", reason="Dask is not installed (optional extra: pip install "
    "'printability[dask]')")


@pytest.fixture(scope="module")
def cluster():
    # one worker process with one thread, on 127.0.0.1 only; closed by the context manager
    with distributed.LocalCluster(host="127.0.0.1", n_workers=1, threads_per_worker=1,
                                  processes=True, dashboard_address=None,
                                  death_timeout=60) as c:
        yield c


def _stack():
    regions = (box(0, 0, 8, 5), box(0, 0, 8, 0.5).union(box(0, 2, 8, 5)), box(1, 1, 6, 4))
    return LayerStack(tuple(Layer(z=0.2 * (i + 1), height=0.2, region=as_region(r), index=i)
                            for i, r in enumerate(regions)), source="synthetic")


def _numbers(doc):
    return [{k: v for k, v in n.items() if k != "build_time_estimate_s"} | {"layers": [
        {k: v for k, v in lay.items()} for lay in n["layers"]]} for n in doc["nozzles"]]


@pytest.mark.parametrize("machine", ["xy", "ttr"])
def test_cluster_equals_local(cluster, machine):
    stack = _stack()
    nozzles = ["circle:d=0.6", "ellipse:major=0.8,minor=0.3"]
    local = analyze(stack, nozzles, machine).to_json()
    remote = analyze(stack, nozzles, machine, scheduler=cluster.scheduler_address).to_json()
    assert _numbers(remote) == _numbers(local)
    assert remote["engine"] == local["engine"]


def test_cli_scheduler_option(cluster, shared_data, tmp_path):
    src = shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"
    docs = []
    for extra in ([], ["--scheduler", cluster.scheduler_address]):
        out = tmp_path / f"r{len(docs)}.json"
        p = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src), "-n",
                            "circle:d=0.4", "-n", "circle:d=1", "--no-progress", "--json",
                            str(out), *extra], capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stderr
        docs.append(json.loads(out.read_text()))
    assert _numbers(docs[0]) == _numbers(docs[1])


@pytest.mark.slow   # waits for the connection timeout (analysis.SCHEDULER_TIMEOUT)
def test_unreachable_scheduler_is_a_clear_error(shared_data):
    src = shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"
    p = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src),
                        "--no-progress", "--scheduler", "tcp://127.0.0.1:9"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 1, p.stderr
    assert "Traceback" not in p.stderr
    assert "tcp://127.0.0.1:9" in p.stderr and "scheduler" in p.stderr
