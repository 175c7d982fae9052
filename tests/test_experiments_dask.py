"""Sweeps on a Dask cluster of separately started processes (``dask scheduler`` + ``dask worker``, as
on real machines): the same rows as the local pool, bit for bit; workers with other code refused.

The cluster runs from the ``dask`` command next to this Python (``python -m dask`` without it), on
127.0.0.1 with ports the OS picks; each process is started in its own process group and ended
(SIGTERM, then SIGKILL) however the test ends; were pytest itself killed, the scheduler stops after
5 idle minutes and the worker 60 s after it.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed")

from gendr.cli import main as gendr_main  # noqa: E402
from gendr_experiments import sweep  # noqa: E402
from gendr_experiments.sweep import OtherCodeError, execute, expand, load_rows  # noqa: E402

TINY = ["--set", "target=tetrahedron", "--set", "steps=2", "--set", "image_size=12", "--set", "views=2",
        "--set", "subdivisions=1"]


def _dask_command():
    exe = Path(sys.executable).parent / "dask"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "dask"]


def _env():
    """This process's environment with the directories gendr, its backends and gendr_experiments
    were imported from first on PYTHONPATH: the worker runs the code under test."""
    import gendr
    import gendr_experiments
    import gendr_torch
    roots = [str(Path(m.__file__).resolve().parent.parent) for m in (gendr, gendr_experiments, gendr_torch)]
    old = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return dict(os.environ, PYTHONPATH=os.pathsep.join(dict.fromkeys(roots + old)))


def _end(proc):
    try:
        os.killpg(proc.pid, signal.SIGTERM)  # the group of the process we started (a worker's nanny has a child)
    except ProcessLookupError:
        return
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=20)


@pytest.fixture(scope="module")
def dask_address(tmp_path_factory):
    """Address of a ``dask scheduler`` with one ``dask worker --nthreads 1``, separate processes."""
    tmp = tmp_path_factory.mktemp("dask")
    procs, logs = [], []

    def start(args, name):
        log = open(tmp / f"{name}.log", "w")
        logs.append(log)
        procs.append(subprocess.Popen(_dask_command() + args, stdout=log, stderr=subprocess.STDOUT, env=_env(),
                                      cwd=tmp, start_new_session=True))

    def fail(what):
        text = "".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(tmp.glob("*.log")))
        pytest.fail(f"{what}\n{text}")

    try:
        sched_file = tmp / "scheduler.json"
        start(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
               "--scheduler-file", str(sched_file), "--idle-timeout", "300"], "scheduler")  # gone even if pytest is killed
        t0 = time.monotonic()
        while not sched_file.exists() or not sched_file.read_text().strip():
            if procs[0].poll() is not None or time.monotonic() - t0 > 90:
                fail("the dask scheduler did not start")
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        start(["worker", address, "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1",
               "--local-directory", str(tmp / "worker"), "--death-timeout", "60", "--name", "gendr-test-worker"],
              "worker")
        with distributed.Client(address, timeout=60) as client:
            try:
                client.wait_for_workers(1, timeout=120)
            except Exception:  # noqa: BLE001 - any failure here is reported with the logs
                fail("the dask worker did not connect")
            assert all(w["nthreads"] == 1 for w in client.scheduler_info()["workers"].values())
        yield address
    finally:
        for p in reversed(procs):
            _end(p)
        for log in logs:
            log.close()


def _sweep_and_compare(tmp_path, address, local_args):
    """The paper's search (coarse grid, then the fine stage around each best τ) through the CLI, once
    locally and once on the cluster: the same rows."""
    here, there = tmp_path / "local.jsonl", tmp_path / "dask.jsonl"
    common = ["experiment", "sweep", "--instances", "5,40", "--taus", "0.1,0.02", "--fine-steps=-0.25", "-q", *TINY]
    assert gendr_main(common + local_args + ["-o", str(here)]) == 0
    assert gendr_main(common + ["--scheduler", address, "-o", str(there)]) == 0
    a = {r["key"]: r for r in load_rows(here)}
    b = {r["key"]: r for r in load_rows(there)}
    assert len(a) == 6 and set(a) == set(b)  # 2 instances × (2 coarse + 1 fine)
    assert all(r["status"] == "ok" for r in [*a.values(), *b.values()])
    assert {k: r["metric"] for k, r in a.items()} == {k: r["metric"] for k, r in b.items()}  # bit-identical
    assert {r["code_hash"] for r in b.values()} == {r["code_hash"] for r in a.values()}
    assert all(r["provenance"]["torch_threads"] == 1 for r in b.values())


def test_sweep_on_separate_dask_processes_matches_in_process_runs(tmp_path, dask_address):
    _sweep_and_compare(tmp_path, dask_address, ["--workers", "0"])


@pytest.mark.slow  # the spawned pool imports torch twice per stage: ~35 s on 2 shared cores
def test_sweep_on_separate_dask_processes_matches_the_pool(tmp_path, dask_address):
    _sweep_and_compare(tmp_path, dask_address, ["--workers", "2"])


def test_workers_with_other_code_are_refused(tmp_path, dask_address, monkeypatch):
    cfgs = expand("shape", dict(target="tetrahedron", steps=2, image_size=12, views=2, subdivisions=1), instances=[5])
    # this process now "runs other code" than the worker process (which imports sweep unpatched)
    monkeypatch.setattr(sweep, "source_hash", lambda backend="torch": "0" * 16)
    with pytest.raises(OtherCodeError, match="1 of 1 Dask workers run other code"):
        execute(cfgs, tmp_path / "r.jsonl", scheduler=dask_address, progress=False)
    assert not (tmp_path / "r.jsonl").exists()
