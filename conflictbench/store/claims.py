"""Who holds a claim (``<store>/claims/<episode id>.claim``): the process that wrote it, named so that no other can
pass for it.

A claim reads ``host pid token/nonce/place``: the host name and process id; a new random token at every renewal
(what tells another machine the owner is alive); a random nonce made once per process (:func:`process_nonce`); and
the place where that process id names one process (:func:`pid_place`: this kernel's boot and pid namespace). Two
containers may share a host name and run their jobs under the same process id: the nonce tells their claims and
temporaries apart, and the place says that the other's process cannot be checked from here (it waits as another
machine's does). Claims of the older ``host pid token`` form are still read; an older reader still parses these.
"""

from __future__ import annotations

import functools
import hashlib
import os
import uuid
from pathlib import Path

_nonce: tuple[int, str] | None = None


def process_nonce() -> str:
    """A random name for this process, made once (and again in a forked child): what tells this process's claims
    and temporaries from those of another container that shares its host name and process id."""
    global _nonce
    if _nonce is None or _nonce[0] != os.getpid():
        _nonce = (os.getpid(), uuid.uuid4().hex[:12])
    return _nonce[1]


@functools.cache
def pid_place() -> str:
    """Where a process id names one process: this kernel's boot and this pid namespace, as a short digest. Two
    containers of one machine share the boot, not the namespace; two machines never share a boot. A process whose
    claim says another place cannot be checked from here, whatever its host name says."""
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        namespace = os.stat("/proc/self/ns/pid").st_ino
    except OSError:  # no /proc (not Linux): the host name alone says where
        boot, namespace = "", 0
    return hashlib.sha256(f"{boot}:{namespace}".encode()).hexdigest()[:10]


def read_claim(path: Path) -> tuple[str, str, str, str | None, str | None] | None:
    """(host, pid, renewal token, nonce, place) of a claim; the older ``host pid token`` form has no nonce or place
    (both None). None where there is no claim or it cannot be read."""
    try:
        host, pid, token = path.read_text().split()
    except (OSError, ValueError):
        return None
    if not pid.isdigit():
        return None
    renewal, _, rest = token.partition("/")
    nonce, _, place = rest.partition("/")
    return host, pid, renewal, (nonce or None), (place or None)


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True
