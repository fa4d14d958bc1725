"""SLURM accounting for the test cluster (``conftest.slurm_accounting_cluster``): a private MariaDB and slurmdbd.

``Accounting.start`` runs after munged and before the controller: it initialises a MariaDB data folder,
starts ``mariadbd`` on a free port of 127.0.0.1 (as root, everything in the cluster's folder), gives
slurmdbd a database user, starts ``slurmdbd`` in the foreground on it, and registers the cluster, the
account ``ACCOUNT`` and user root in it. The controller, started next with
``AccountingStorageEnforce=associations``, then refuses a job charged to any other account.
"""

from __future__ import annotations

import shutil
import socket
import subprocess

ACCOUNT = "benchacct"
#: MariaDB's programs, each with its older name (Debian's mariadb-server ships both)
SERVER, INSTALL_DB, CLIENT = ("mariadbd", "mysqld"), ("mariadb-install-db", "mysql_install_db"), ("mariadb", "mysql")
PROGRAMS = (("slurmdbd",), ("sacctmgr",), SERVER, INSTALL_DB, CLIENT)
DB_USER, DB_PASSWORD, DB_NAME = "slurm", "bench", "slurm_acct_db"


def missing() -> list[str]:
    """The programs of ``PROGRAMS`` not on PATH (as ``a or b`` where either will do)."""
    return [" or ".join(names) for names in PROGRAMS if not any(shutil.which(n) for n in names)]


def _program(names: tuple[str, ...]) -> str:
    return next(path for path in map(shutil.which, names) if path)


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


class Accounting:
    """The accounting side of one test cluster: MariaDB on ``db_port``, slurmdbd on ``dbd_port``."""

    LOGS = ("mariadbd.log", "slurmdbd.log")

    def __init__(self, db_port: int, dbd_port: int) -> None:
        self.db_port, self.dbd_port = db_port, dbd_port

    def start(self, cluster, cluster_name: str) -> None:
        self._start_mariadb(cluster)
        self._start_slurmdbd(cluster)
        self._register(cluster, cluster_name)

    def _start_mariadb(self, cluster) -> None:
        f = cluster.folder
        # --no-defaults: nothing from /etc/mysql (a system server's datadir, socket or port); --user=root: we are root
        # an 8 MB redo log, not 100 MB: the folder is 26 MB, not 114 MB
        base = ["--no-defaults", "--user=root", f"--datadir={f}/mariadb", "--innodb-log-file-size=8M"]
        init = subprocess.run([_program(INSTALL_DB), *base, "--skip-test-db"], capture_output=True, text=True,
                              timeout=120)
        if init.returncode != 0:
            raise RuntimeError(f"mariadb-install-db failed: {init.stderr.strip()[-500:]}")
        cluster.procs.append(subprocess.Popen(
            [_program(SERVER), *base, f"--socket={f}/mariadb.sock", f"--port={self.db_port}",
             "--bind-address=127.0.0.1", "--skip-name-resolve", f"--pid-file={f}/mariadbd.pid",
             f"--log-error={f}/mariadbd.log"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        # root logs in through the socket (unix_socket authentication); slurmdbd comes over TCP with a password.
        # Idempotent, so it is simply retried until the server answers.
        sql = (f"CREATE USER IF NOT EXISTS '{DB_USER}'@'127.0.0.1' IDENTIFIED BY '{DB_PASSWORD}'; "
               f"GRANT ALL ON {DB_NAME}.* TO '{DB_USER}'@'127.0.0.1';")
        client = [_program(CLIENT), "--no-defaults", f"--socket={f}/mariadb.sock", "-uroot", "-e", sql]
        cluster.wait_for(lambda: subprocess.run(client, capture_output=True, timeout=10).returncode == 0, 30,
                         "MariaDB did not take slurmdbd's user")

    def _slurmdbd_conf(self, cluster) -> str:
        """slurmdbd.conf: its port on 127.0.0.1, the database's, every path in the cluster's folder."""
        f = cluster.folder
        return "\n".join([
            "AuthType=auth/munge", f"AuthInfo=socket={f}/munge.sock", "DbdHost=localhost", "DbdAddr=127.0.0.1",
            f"DbdPort={self.dbd_port}", "SlurmUser=root", f"PidFile={f}/slurmdbd.pid", f"LogFile={f}/slurmdbd.log",
            "StorageType=accounting_storage/mysql", "StorageHost=127.0.0.1", f"StoragePort={self.db_port}",
            f"StorageUser={DB_USER}", f"StoragePass={DB_PASSWORD}", f"StorageLoc={DB_NAME}", "",
        ])

    def _start_slurmdbd(self, cluster) -> None:
        # slurmdbd reads slurmdbd.conf beside $SLURM_CONF, and refuses one that others may read (the password)
        conf = cluster.folder / "slurmdbd.conf"
        conf.write_text(self._slurmdbd_conf(cluster))
        conf.chmod(0o600)
        cluster.procs.append(subprocess.Popen(["slurmdbd", "-D"], env=cluster.env, stdout=subprocess.DEVNULL,
                                              stderr=subprocess.DEVNULL))
        # it listens once it has made its tables
        cluster.wait_for(lambda: _listening(self.dbd_port), 60, "slurmdbd did not listen")

    def _register(self, cluster, cluster_name: str) -> None:
        # adding the cluster gives root an association with account "root" (its default); ACCOUNT is added beside it
        for entity in (["cluster", cluster_name], ["account", ACCOUNT], ["user", "root", f"account={ACCOUNT}"]):
            proc = cluster.run("sacctmgr", "-i", "add", *entity)
            if proc.returncode != 0:
                raise RuntimeError(f"sacctmgr add {' '.join(entity)}: {(proc.stderr or proc.stdout).strip()}")
