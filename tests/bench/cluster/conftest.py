"""A real single-node SLURM cluster for the tests: munged, slurmctld and slurmd from Debian's ``slurm-wlm``.

``slurm_cluster`` (session scope) writes a ``slurm.conf`` into a temporary folder (free ports, this
machine's CPUs and memory, one partition ``debug`` with a 60-minute limit), starts the three daemons
on it in the foreground, waits for the node to be idle, and gives the environment (``SLURM_CONF``,
``PATH``) the tests run ``python -m bench`` and ``sinfo``/``scancel`` with. Everything it started is
stopped at the end. Without the binaries, or when they cannot start (not root, no munge, ...), every
test that uses it is skipped with one reason. No accounting database (``slurmdbd``) runs there: ``sacct``
answers "accounting storage is disabled", submitit warns and reads results from their files, and an
account is not checked by the controller.

``slurm_accounting_cluster`` (session scope) is the same cluster with accounting: a private MariaDB
server and ``slurmdbd`` (``slurm_accounting.py``, from Debian's ``slurmdbd`` and ``mariadb-server``),
the cluster, account ``benchacct`` and user root registered, and ``AccountingStorageEnforce=associations``,
so the controller refuses a job charged to an account root has no association with. It takes 4 to 8 s
to start on 2 cores (~1 s without accounting), so only the tests that need accounting use it. Without
the programs, or when they cannot start, its tests are skipped with one reason.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import pytest
from slurm_accounting import Accounting, missing  # beside this file (pytest puts the folder on sys.path)

BINARIES = ("munged", "slurmctld", "slurmd", "sbatch", "sinfo", "squeue", "scancel")
CLUSTER_NAME = "benchtest"
PARTITION = "debug"
MAX_TIME_MIN = 60
MAX_ARRAY_SIZE = 1001


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _memory_mb() -> int:
    pages, size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
    return int(pages * size / 2**20 * 0.8)


def slurm_conf(folder: Path, node: str, dbd_port: int | None = None) -> str:
    """The cluster's slurm.conf: every path under ``folder``, one node named ``node`` on 127.0.0.1; with
    ``dbd_port``, accounting through the slurmdbd there, associations enforced."""
    ctld, d = _free_port(), _free_port()
    # with slurmdbd, AccountingStoragePass is the munge socket its clients (sacctmgr, the controller) use
    accounting = ["AccountingStorageType=accounting_storage/none"] if dbd_port is None else [
        "AccountingStorageType=accounting_storage/slurmdbd", "AccountingStorageHost=127.0.0.1",
        f"AccountingStoragePort={dbd_port}", f"AccountingStoragePass={folder}/munge.sock",
        "AccountingStorageEnforce=associations"]
    return "\n".join([
        f"ClusterName={CLUSTER_NAME}", f"SlurmctldHost={node}(127.0.0.1)", "SlurmUser=root", "SlurmdUser=root",
        "AuthType=auth/munge", "CredType=cred/munge", f"AuthInfo=socket={folder}/munge.sock",
        f"StateSaveLocation={folder}/state", f"SlurmdSpoolDir={folder}/spool",
        f"SlurmctldPidFile={folder}/slurmctld.pid", f"SlurmdPidFile={folder}/slurmd.pid",
        f"SlurmctldPort={ctld}", f"SlurmdPort={d}", f"SlurmctldLogFile={folder}/slurmctld.log",
        f"SlurmdLogFile={folder}/slurmd.log",
        # no cgroups in a container: processes tracked by process group, no task binding
        "ProctrackType=proctrack/pgid", "TaskPlugin=task/none", "JobAcctGatherType=jobacct_gather/none",
        *accounting, "SchedulerType=sched/backfill",
        "SelectType=select/cons_tres", "SelectTypeParameters=CR_CPU", "ReturnToService=2", "MpiDefault=none",
        "EnforcePartLimits=ALL", f"MaxArraySize={MAX_ARRAY_SIZE}", "MinJobAge=600",
        "SchedulerParameters=sched_interval=1", "KillWait=1",
        f"NodeName={node} NodeAddr=127.0.0.1 CPUs={os.cpu_count()} RealMemory={_memory_mb()} State=UNKNOWN",
        f"PartitionName={PARTITION} Nodes={node} Default=YES MaxTime={MAX_TIME_MIN} State=UP",
        "",
    ])


class Cluster:
    """The running cluster: its folder, the environment to reach it, and the daemons' processes."""

    def __init__(self, folder: Path, accounting: Accounting | None = None) -> None:
        self.folder = folder
        self.accounting = accounting
        self.env = {**os.environ, "SLURM_CONF": str(folder / "slurm.conf")}
        self.procs: list[subprocess.Popen] = []

    def run(self, *cmd: str, **kwargs) -> subprocess.CompletedProcess:
        return subprocess.run(list(cmd), env=self.env, capture_output=True, text=True, timeout=60, **kwargs)

    def logs(self) -> str:
        tails = []
        accounting = self.accounting.LOGS if self.accounting else ()
        for name in ("munged.out", *accounting, "slurmctld.log", "slurmd.log"):
            path = self.folder / name
            if path.exists():
                tails.append(f"--- {name}\n" + "\n".join(path.read_text(errors="replace").splitlines()[-8:]))
        return "\n".join(tails)

    def start(self, node: str) -> None:
        f = self.folder
        (f / "state").mkdir()
        (f / "spool").mkdir()
        key = f / "munge.key"
        key.write_bytes(os.urandom(1024))
        key.chmod(0o600)
        (f / "slurm.conf").write_text(slurm_conf(f, node, self.accounting and self.accounting.dbd_port))
        out = open(f / "munged.out", "w")
        self.procs.append(subprocess.Popen(
            ["munged", "-F", "-f", f"--key-file={key}", f"--socket={f}/munge.sock", f"--pid-file={f}/munged.pid",
             f"--seed-file={f}/munged.seed", f"--log-file={f}/munged.log"], stdout=out, stderr=out))
        self.wait_for(lambda: (f / "munge.sock").exists(), 10, "munged did not create its socket")
        if self.accounting:  # slurmdbd authenticates through munge; the controller wants it up, cluster registered
            self.accounting.start(self, CLUSTER_NAME)
        conf = str(f / "slurm.conf")
        for cmd in (["slurmctld", "-D", "-i", "-f", conf], ["slurmd", "-D", "-N", node, "-f", conf]):
            self.procs.append(subprocess.Popen(cmd, env=self.env, stdout=subprocess.DEVNULL,
                                               stderr=subprocess.DEVNULL))
        self.wait_for(lambda: self.run("sinfo", "-h", "-o", "%t").stdout.strip() == "idle", 30,
                      "the node did not become idle")

    def wait_for(self, ready, seconds: float, what: str) -> None:
        deadline = time.time() + seconds
        while time.time() < deadline:
            if any(p.poll() is not None for p in self.procs):
                raise RuntimeError(f"a daemon exited: {what}")
            try:
                if ready():
                    return
            except (OSError, subprocess.SubprocessError):
                pass
            time.sleep(0.2)
        raise RuntimeError(what)

    def stop(self) -> None:
        if any(p.poll() is None for p in self.procs[1:]):
            self.run("scancel", "--user", os.environ.get("USER", "root"))
        for proc in reversed(self.procs):
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()

    def idle(self, timeout: float = 120) -> None:
        """Wait until no job of the cluster is pending or running."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            if not self.run("squeue", "-h").stdout.strip():
                return
            time.sleep(0.3)
        raise AssertionError(f"jobs still queued after {timeout} s:\n{self.run('squeue').stdout}")


def _why_not() -> str | None:
    missing_binaries = [b for b in BINARIES if shutil.which(b) is None]
    if missing_binaries:
        return (f"no SLURM here ({', '.join(missing_binaries)} not on PATH): apt-get install slurm-wlm munge "
                "(.ci/run does where apt is available)")
    if os.geteuid() != 0:
        return "SLURM test cluster needs root (slurmd runs jobs as their user)"
    return None


def _why_no_accounting() -> str | None:
    absent = missing()
    if absent:
        return (f"no SLURM accounting here ({', '.join(absent)} not on PATH): apt-get install slurmdbd "
                "mariadb-server (.ci/run does where apt is available)")
    return None


def _running(what: str, accounting: Accounting | None = None):
    """Start a cluster in a new temporary folder, yield it, stop it; skip (one reason) where it cannot run."""
    reason = _why_not() or (accounting and _why_no_accounting())
    if reason:
        pytest.skip(reason)
    folder = Path(tempfile.mkdtemp(prefix="bench-slurm-"))
    cluster = Cluster(folder, accounting)
    try:
        cluster.start(socket.gethostname().split(".")[0])
    except (RuntimeError, OSError, subprocess.SubprocessError) as err:
        cluster.stop()
        logs = cluster.logs()
        shutil.rmtree(folder, ignore_errors=True)
        pytest.skip(f"{what} did not start: {err}\n{logs}")
    try:
        yield cluster
    finally:
        cluster.stop()
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="session")
def slurm_cluster():
    """A running single-node SLURM cluster (see the module doc); skips with one reason where it cannot run."""
    yield from _running("the SLURM test cluster")


@pytest.fixture(scope="session")
def slurm_accounting_cluster():
    """The same cluster with slurmdbd on a private MariaDB, associations enforced, account ``benchacct``."""
    yield from _running("the SLURM accounting cluster", Accounting(db_port=_free_port(), dbd_port=_free_port()))
