"""A real policy server for the serving tests: stdlib HTTP on 127.0.0.1, JSON in and out.

Run as a script (``python policy_server.py --port 0 [options]``), it prints ``PORT <n>`` once it
listens. ``POST /act`` with ``{"step", "state", "instruction", "stream"}`` answers ``{"action": [7]}``
computed by :func:`served_action`; ``GET /stats`` answers what the server saw. Options make it
misbehave the ways a model server does: drop connections, answer errors, stall, die; ``--meet``
makes it answer only requests that arrive together (a check that a client really overlaps them).

:class:`PolicyServer` starts it in a subprocess for a test and always stops it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path


def served_action(step: int, state: list[float]) -> list[float]:
    """The deterministic policy behind the server: x sways with the step, y follows the state's x."""
    return [0.25 * math.sin(step / 2.0), -0.1 * state[0], 0.0, 0.0, 0.0, 0.0, -1.0]


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"  # keep-alive: one connection per client stream
    disable_nagle_algorithm = True  # headers and body go out in two writes: without this, +40 ms a reply

    def log_message(self, *args) -> None:  # quiet
        pass

    def _reply(self, status: int, payload) -> None:
        body = json.dumps(payload).encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self) -> None:
        with self.server.lock:
            self._reply(200, dict(self.server.stats))

    def do_POST(self) -> None:
        server, options = self.server, self.server.options
        request = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
        with server.lock:
            stats = server.stats
            stats["requests"] += 1
            number = stats["requests"]
            stats["overlapped"] += int(stats["in_flight"] > 0)  # arrived while another was being answered
            stats["in_flight"] += 1
            stats["max_in_flight"] = max(stats["max_in_flight"], stats["in_flight"])
            stats["streams"] = sorted(set(stats["streams"]) | {request.get("stream", 0)})
            drop = stats["dropped"] < options.drop_first
            stats["dropped"] += int(drop)
        try:
            if options.die_after is not None and number > options.die_after:
                os.kill(os.getpid(), signal.SIGKILL)  # a crash mid-run: no reply, no clean shutdown
            if drop:
                self.close_connection = True  # the connection dies with the request unanswered
                return
            if options.meet > 1:
                _meet(server, options)
            time.sleep(options.delay)
            if options.fail_instruction and options.fail_instruction in request.get("instruction", ""):
                with server.lock:
                    stats["errors"] += 1
                if options.error_body:
                    self._reply(200, {"error": "CUDA out of memory (test server)"})
                else:
                    self._reply(500, {"detail": "CUDA out of memory (test server)"})
                return
            self._reply(200, {"action": served_action(request["step"], request["state"])})
        finally:
            with server.lock:
                stats["in_flight"] -= 1


def _meet(server, options) -> None:
    """Hold this request until ``options.meet`` requests wait together (or ``meet_timeout_s`` passes).

    A client that sends one query only after the previous one is answered never makes a meeting:
    every request then waits out the timeout and counts as ``alone``."""
    with server.meeting:
        server.waiting += 1
        group = server.group
        if server.waiting >= options.meet:
            server.group, server.waiting = group + 1, 0
            server.meeting.notify_all()
            met = True
        else:
            met = server.meeting.wait_for(lambda: server.group != group, timeout=options.meet_timeout_s)
            if not met:
                server.waiting -= 1
        server.stats["met" if met else "alone"] += 1


def serve(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--drop-first", type=int, default=0, help="close the connection unanswered N times")
    parser.add_argument("--fail-instruction", default="", help="HTTP 500 when the instruction contains this")
    parser.add_argument("--error-body", action="store_true", help="answer failures with 200 {'error': ...}")
    parser.add_argument("--delay", type=float, default=0.0, help="seconds before each reply")
    parser.add_argument("--meet", type=int, default=0, help="answer only once N requests wait together")
    parser.add_argument("--meet-timeout-s", type=float, default=5.0, help="...or once this long has passed")
    parser.add_argument("--die-after", type=int, default=None, help="SIGKILL itself on request N+1")
    options = parser.parse_args(argv)
    server = ThreadingHTTPServer(("127.0.0.1", options.port), _Handler)
    server.daemon_threads = True
    server.options, server.lock = options, threading.Lock()
    server.meeting, server.waiting, server.group = threading.Condition(), 0, 0
    server.stats = {
        "requests": 0,
        "in_flight": 0,
        "max_in_flight": 0,
        "overlapped": 0,
        "dropped": 0,
        "errors": 0,
        "met": 0,
        "alone": 0,
        "streams": [],
    }
    print(f"PORT {server.server_address[1]}", flush=True)
    server.serve_forever()


class PolicyServer:
    """The server above in a subprocess on 127.0.0.1; a context manager that always stops it."""

    def __init__(self, *options: str, port: int = 0):
        self.process = subprocess.Popen(
            [sys.executable, str(Path(__file__)), "--port", str(port), *options],
            stdout=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            text=True,
        )
        line = self.process.stdout.readline()  # blocks until it listens (or dies: then the line is empty)
        if not line.startswith("PORT "):
            self.stop()
            raise RuntimeError(f"the test policy server did not start (exit code {self.process.returncode})")
        self.port = int(line.split()[1])
        self.url = f"http://127.0.0.1:{self.port}/act"

    def stats(self) -> dict:
        from urllib.request import urlopen

        with urlopen(f"http://127.0.0.1:{self.port}/stats", timeout=5) as response:
            return json.loads(response.read())

    def stop(self, grace_s: float = 5.0) -> None:
        """SIGTERM, then SIGKILL after ``grace_s`` (0: SIGKILL at once, a crash)."""
        if self.process.poll() is None:
            self.process.terminate() if grace_s > 0 else self.process.kill()
            try:
                self.process.wait(timeout=max(grace_s, 1))
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process.stdout.close()

    def __enter__(self) -> PolicyServer:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


if __name__ == "__main__":
    serve()
