"""Job workers die with their driver: kill -9 of the driver leaves no local worker or resource tracker, and
no Ray task running on a cluster that outlives the driver."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path


DRIVER = textwrap.dedent('''
    import os, sys, time
    from pathlib import Path
    from nue.jobs import Job, run_jobs

    def hold(job):
        (Path(job.payload["dir"]) / f"{os.getpid()}.pid").write_text("")
        time.sleep(300)  # busy until the driver is killed; the test never waits for this
        return 0

    if __name__ == "__main__":
        jobs = [Job(f"j{i}", {"dir": sys.argv[1]}) for i in range(2)]
        ray_address = sys.argv[2] if len(sys.argv) > 2 else None
        run_jobs(jobs, hold, on_result=lambda job, result: None, workers=2, ray_address=ray_address, progress=False)
''')


def _alive(pid: int) -> bool:
    """Running (not gone, not a zombie waiting for a reaper)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _children(pid: int) -> set[int]:
    out = set()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if int((d / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.add(int(d.name))
            except (OSError, ValueError, IndexError):
                pass
    return out


def _poll(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_killing_the_driver_ends_its_workers_and_resource_tracker(tmp_path):
    script = tmp_path / "driver.py"
    script.write_text(DRIVER)
    pids = tmp_path / "pids"
    pids.mkdir()
    driver = subprocess.Popen([sys.executable, str(script), str(pids)], env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        _poll(lambda: len(list(pids.glob("*.pid"))) == 2 or driver.poll() is not None, 300, "two busy workers")
        assert driver.poll() is None, "the driver ended early"
        workers = {int(p.stem) for p in pids.glob("*.pid")}
        children = _children(driver.pid)
        assert workers <= children and len(children) >= 3, (workers, children)  # + the resource tracker
    finally:
        driver.send_signal(signal.SIGKILL)
        driver.wait()
    _poll(lambda: not any(_alive(p) for p in children), 30, f"processes {sorted(p for p in children if _alive(p))} to end")


def test_killing_the_driver_ends_its_ray_tasks(tmp_path, local_ray):
    """The driver connects to a Ray cluster that this test owns (as an existing cluster would be), starts two
    tasks that never finish, and is killed with -9: the cluster lives on, the tasks' processes end."""
    ray = local_ray
    script = tmp_path / "driver.py"
    script.write_text(DRIVER)
    pids = tmp_path / "pids"
    pids.mkdir()
    address = ray.get_runtime_context().gcs_address
    driver = subprocess.Popen([sys.executable, str(script), str(pids), address],
                              env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        _poll(lambda: len(list(pids.glob("*.pid"))) == 2 or driver.poll() is not None, 300, "two busy Ray tasks")
        assert driver.poll() is None, "the driver ended early"
        tasks = {int(p.stem) for p in pids.glob("*.pid")}
        assert all(_alive(p) for p in tasks)
    finally:
        driver.send_signal(signal.SIGKILL)
        driver.wait()
    _poll(lambda: not any(_alive(p) for p in tasks), 60, f"Ray tasks {sorted(p for p in tasks if _alive(p))} to end")
    assert ray.cluster_resources().get("CPU") == 2  # the cluster itself is still there


def _job_threads(job) -> int:
    import torch

    return torch.get_num_threads()


def test_every_job_runs_with_one_torch_thread_whatever_the_worker_count():
    """Records must not depend on --workers: a job run in this process gets one torch thread, as a pool
    worker's does, and the caller's thread count comes back afterwards."""
    import torch

    from nue.jobs import Job, run_jobs

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for workers in (1, 2):
            seen = {}
            run_jobs([Job(f"j{i}") for i in range(2)], _job_threads, workers=workers, progress=False,
                     on_result=lambda job, threads: seen.__setitem__(job.key, threads))
            assert seen == {"j0": 1, "j1": 1}, (workers, seen)
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
