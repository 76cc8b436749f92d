"""Running processes seen through /proc (psutil is in neither environment): peak memory of a process tree and of
one process, sampled, the kernel's own high-water mark, and the machine's load meanwhile (other jobs on a shared
machine slow every variant down, unevenly)."""

from __future__ import annotations

import os
import threading
from collections import defaultdict


def _process_tree(root: int) -> list[int]:
    children: dict[int, list[int]] = defaultdict(list)
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stat:
                    ppid = int(stat.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children[ppid].append(int(entry))
    tree, todo = [], [root]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo.extend(children.get(pid, ()))
    return tree


def _memory_kib(pid: int, fields: tuple[str, ...] = ("Rss:", "Pss:")) -> dict[str, int]:
    """RSS and PSS (shared pages divided among their users, so sums over processes stay honest)."""
    found = {}
    try:
        with open(f"/proc/{pid}/smaps_rollup") as rollup:
            for line in rollup:
                name, value, *_ = line.split()
                if name in fields:
                    found[name.rstrip(":").lower()] = int(value)
    except (OSError, ValueError):
        pass
    return found


def peak_rss_kib(pid: int) -> int:
    """The kernel's high-water mark of ``pid``'s resident memory (VmHWM), since it started."""
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))


class ProcessSampler:
    """Peak summed RSS/PSS of a process and all its descendants, and of the server, sampled every 0.25 s."""

    def __init__(self, client_root: int, server_pid: int):
        self.client_root, self.server_pid = client_root, server_pid
        self.peaks = {"client_rss": 0, "client_pss": 0, "server_rss": 0, "client_processes": 0}
        self._loads: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.25):
            self._loads.append(os.getloadavg()[0])
            tree = _process_tree(self.client_root)
            sizes = [_memory_kib(pid) for pid in tree]
            self.peaks["client_rss"] = max(self.peaks["client_rss"], sum(s.get("rss", 0) for s in sizes))
            self.peaks["client_pss"] = max(self.peaks["client_pss"], sum(s.get("pss", 0) for s in sizes))
            self.peaks["client_processes"] = max(self.peaks["client_processes"], sum(1 for s in sizes if s))
            server = _memory_kib(self.server_pid, ("Rss:",)).get("rss", 0)
            self.peaks["server_rss"] = max(self.peaks["server_rss"], server)

    def stop(self) -> tuple[dict[str, int], dict[str, float]]:
        """Peak memory (KiB) and the 1-minute load average's mean and max while sampling."""
        self._stop.set()
        self._thread.join()
        loads = self._loads or [os.getloadavg()[0]]
        return self.peaks, {"mean": sum(loads) / len(loads), "max": max(loads)}
